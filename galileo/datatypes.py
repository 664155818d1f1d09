"""Observations and simulated motion as plain data: `Tracks` (what tracking measured in a
video) and `Trajectory` (what a simulation produced). No OpenCV, no pybullet: the
likelihood, the viewer and the controller read these without importing either."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import GalileoError
from .jsonio import read_json, write_json
from .shapes import SHAPE_CLASSES, Shape


# -- output -----------------------------------------------------------------------------

@dataclass
class ObjectTrack:
    name: str
    role: str
    position_m: np.ndarray      # (F, 3), NaN where not visible
    velocity_mps: np.ndarray    # (F, 3), NaN where not visible
    visible: np.ndarray         # (F,) bool
    shape: Shape
    offset_units: int | None = None
    detected_by: str = "motion"  # motion (ramp object) | scene (target, from the scene file)
    bottom_up: dict = field(default_factory=dict)   # a scenario's other bottom-up estimates (JSON values)
    # for drawing (not saved): image centre and features per frame
    center_px: np.ndarray | None = None
    features_px: list = field(default_factory=list)
    position_sd_m: float | None = None   # the tracker's own position noise (its roughness, the camera's residual
    # motion): the observation model's noise is at least what this implies

    def to_json(self) -> dict:
        def rows(a):
            return [None if not v else [float(x) for x in row] for row, v in zip(a, self.visible)]
        d = {"name": self.name, "role": self.role, "position_m": rows(self.position_m),
             "velocity_mps": rows(self.velocity_mps), "visible": [bool(v) for v in self.visible],
             "shape": {"type": self.shape.type, "size_m": list(self.shape.size_m)},
             "offset_units": self.offset_units, "detected_by": self.detected_by}
        if self.bottom_up:
            d["bottom_up"] = dict(self.bottom_up)
        if self.position_sd_m is not None:
            d["position_sd_m"] = float(self.position_sd_m)
        return d


@dataclass
class Tracks:
    fps: float
    objects: list[ObjectTrack]
    notes: list[str] = field(default_factory=list)   # what the tracker wants the user to know (one line each)
    camera: dict = field(default_factory=dict)       # what the camera did, as the tracker measured and removed it
    # (galileo.vision.stabilise: motion in px and deg, exposure gains, blur; JSON values)

    @property
    def n_frames(self) -> int:
        return len(self.objects[0].visible) if self.objects else 0

    @property
    def time_s(self) -> np.ndarray:
        return np.arange(self.n_frames) / self.fps

    def position_noise_m(self) -> float:
        """The largest position noise the tracker measured on any object (`ObjectTrack.position_sd_m`;
        0 where it measured none): an observation model's noise should be at least this."""
        return max((o.position_sd_m or 0.0 for o in self.objects), default=0.0)

    def velocity_noise_mps(self) -> float:
        """What `position_noise_m` makes of velocities by central differences: sd * fps / sqrt(2)."""
        return self.position_noise_m() * self.fps / math.sqrt(2)

    def by_role(self, role: str) -> ObjectTrack | None:
        return next((o for o in self.objects if o.role == role), None)

    def to_json(self) -> dict:
        d = {"fps": self.fps, "time_s": self.time_s.tolist(), "objects": [o.to_json() for o in self.objects]}
        if self.notes:
            d["notes"] = [str(n) for n in self.notes]
        if self.camera:
            d["camera"] = dict(self.camera)
        return d

    def save(self, path: str | Path) -> None:
        write_json(path, self.to_json(), indent=None)

    # -- validation (one rule for files, the trackers' output and library users) ------------
    def check(self) -> "Tracks":
        """These tracks, if they hold together (TracksError naming the object, field and frame
        otherwise): a frame rate in (0, MAX_FPS], at least one object, every object with the
        same number of frames (at most MAX_FRAMES), a boolean `visible` per frame, finite
        positions and velocities within MAX_POSITION_M / MAX_SPEED_MPS in every visible frame,
        a valid shape, an integer (or no) offset, and names and roles each used once.
        Frames not visible are not looked at (NaN there is the tracker's "not seen")."""
        fps = self.fps
        try:
            ok = not isinstance(fps, (bool, np.bool_)) and isinstance(fps, (int, float, np.integer, np.floating)) \
                and math.isfinite(float(fps)) and 0 < fps <= MAX_FPS
        except OverflowError:
            ok = False
        if not ok:
            raise TracksError(f"tracks: fps: expected a number in (0, {MAX_FPS:g}], got {_show(fps)}")
        if not self.objects:
            raise TracksError("tracks: objects: expected at least one object")
        first = np.asarray(self.objects[0].visible)
        if first.ndim != 1:
            raise TracksError(f"tracks: objects[0].visible: expected one boolean per frame, got an array of shape "
                              f"{first.shape}")
        n = len(first)
        if n > MAX_FRAMES:
            raise TracksError(f"tracks: {n} frames is more than the {MAX_FRAMES} allowed")
        names, roles = set(), set()
        for i, o in enumerate(self.objects):
            where = f"tracks: objects[{i}]"
            if not isinstance(o.name, str) or not o.name:
                raise TracksError(f"{where}.name: expected a non-empty string, got {_show(o.name)}")
            if not isinstance(o.role, str) or not o.role:
                raise TracksError(f"{where}.role: expected a non-empty string, got {_show(o.role)}")
            if o.name in names:
                raise TracksError(f"{where}.name: {o.name!r} is used by an earlier object (each name once)")
            if o.role in roles:
                raise TracksError(f"{where}.role: {o.role!r} is used by an earlier object (each role once)")
            names.add(o.name)
            roles.add(o.role)
            where = f"tracks: objects[{i}] ({o.name!r})"
            vis = np.asarray(o.visible)
            if vis.dtype != bool or vis.shape != (n,):
                raise TracksError(f"{where}.visible: expected {n} booleans (as objects[0] has), got an array of "
                                  f"{vis.dtype} with shape {vis.shape}")
            arrays = {}
            for key in ("position_m", "velocity_mps"):
                try:
                    a = np.asarray(getattr(o, key), float)
                except (TypeError, ValueError, OverflowError):
                    raise TracksError(f"{where}.{key}: expected {n} x 3 numbers") from None
                if a.shape != (n, 3):
                    raise TracksError(f"{where}.{key}: expected {n} x 3 numbers, got shape {a.shape}")
                arrays[key] = a
            for key, what, limit, unit in (("position_m", "position", MAX_POSITION_M, "m"),
                                           ("velocity_mps", "velocity", MAX_SPEED_MPS, "m/s")):
                a = arrays[key]
                bad = vis & ~np.isfinite(a).all(axis=1)
                if bad.any():
                    f = int(np.flatnonzero(bad)[0])
                    raise TracksError(f"{where}.{key}[{f}]: visible frame {f} has a {what} that is not finite "
                                      f"({', '.join(f'{x:g}' for x in a[f])})")
                big = vis & (np.abs(np.where(np.isfinite(a), a, 0.0)) > limit).any(axis=1)
                if big.any():
                    f = int(np.flatnonzero(big)[0])
                    raise TracksError(f"{where}.{key}[{f}]: ({', '.join(f'{x:g}' for x in a[f])}) is outside "
                                      f"[-{limit:g}, {limit:g}] {unit}")
            problem = _shape_problem(o.shape)
            if problem:
                raise TracksError(f"{where}.shape: {problem}")
            off = o.offset_units
            if off is not None and (isinstance(off, (bool, np.bool_)) or not isinstance(off, (int, np.integer))
                                    or not -MAX_OFFSET_UNITS <= off <= MAX_OFFSET_UNITS):
                raise TracksError(f"{where}.offset_units: expected null or an integer in "
                                  f"[-{MAX_OFFSET_UNITS}, {MAX_OFFSET_UNITS}], got {_show(off)}")
        if not isinstance(self.notes, (list, tuple)) or not all(isinstance(x, str) for x in self.notes):
            raise TracksError("tracks: notes: expected a list of strings")
        return self

    def visible_frames(self) -> int:
        """Frames, summed over the objects, in which an object was seen."""
        return int(sum(np.count_nonzero(o.visible) for o in self.objects))

    def require_visible(self) -> "Tracks":
        """These tracks, if any object was seen in any frame: inference on tracks that saw
        nothing would return the prior with a log-likelihood of 0, as if it had learnt
        something (a still video's tracks, objects held at rest in every frame, are seen)."""
        if not self.visible_frames():
            raise TracksError(f"nothing to infer from: no visible frames (the tracks hold {self.n_frames} frame(s) "
                              f"of {len(self.objects)} object(s), none seen)")
        return self

    @classmethod
    def from_json(cls, d: dict) -> "Tracks":
        """Tracks from their JSON (`to_json`), every field checked (`_parse_tracks`);
        TracksError "malformed tracks JSON: <field>: <why>" otherwise."""
        try:
            return _parse_tracks(d).check()
        except TracksError as e:
            msg = str(e)
            msg = msg[len("tracks: "):] if msg.startswith("tracks: ") else msg
            raise TracksError(f"malformed tracks JSON: {msg}") from None

    @classmethod
    def load(cls, path: str | Path) -> "Tracks":
        data = read_json(path, "tracks file")
        try:
            return cls.from_json(data)
        except TracksError as e:
            raise TracksError(f"{path}: {e}") from None


# -- reading a tracks file ---------------------------------------------------------------------
# What the file must hold (`Tracks.to_json` writes it; `_parse_tracks` reads it):
#   fps            a number in (0, MAX_FPS]
#   time_s         optional; if given, one time per frame, frame f at f / fps (within 1 us)
#   objects        a non-empty list; each object:
#     name, role   non-empty strings, each used once
#     visible      one JSON boolean per frame (true/false: not "yes", 1 or "false"); every
#                  object has the same number of frames (at most MAX_FRAMES)
#     position_m,  one row per frame: three finite numbers within MAX_POSITION_M (m) /
#     velocity_mps MAX_SPEED_MPS (m/s) where visible; null (or three numbers, ignored)
#                  where not
#     shape        {"type": a shape type's name, "size_m": three numbers in (0, MAX_SIZE_M]}; a
#                  registered type's sizes must make one (a cylinder's y == z, ...); another
#                  name is a scenario's own, for it to check (the ramp refuses any but its own)
#     offset_units optional: null or an integer (2 or 2.0; not 1.5)
#     detected_by  optional string; bottom_up optional object of JSON values (finite numbers)
#     position_sd_m optional: null or a finite number >= 0 (metres)
#   notes          optional list of strings
#   camera         optional object of JSON values (finite numbers)
# Unknown keys are ignored (a later version's additions).

MAX_FPS = 10_000.0          # frames per second of any video
MAX_FRAMES = 100_000        # about 55 minutes at 30 fps
MAX_POSITION_M = 1_000.0    # every tracked position within a kilometre of the world origin
MAX_SPEED_MPS = 1_000.0     # and every velocity component below 1 km/s
MAX_SIZE_M = 10.0           # an object's size along any axis
MAX_OFFSET_UNITS = 10_000   # the ramp object's start offset (the scene's prior bounds it further)
TIME_TOLERANCE_S = 1e-6     # time_s against f / fps


class TracksError(GalileoError):
    """A tracks file or `Tracks` that does not hold together (one line, naming the field)."""


def _shape_problem(shape) -> str | None:
    """Why `shape` is no shape, or None. A registered type (box, cylinder, torus, ...) must
    make a valid one of its kind; another name is a scenario's own (a test scenario's
    sphere), which the scenario that reads it checks (the ramp's `scene_for_inference`
    refuses it), so here it needs only three sizes."""
    if not isinstance(shape, Shape):
        return f"expected a shape, got {_show(shape)}"
    if not isinstance(shape.type, str) or not shape.type:
        return f"type: expected a shape type's name, got {_show(shape.type)}"
    size = shape.size_m
    if len(size) != 3 or not all(math.isfinite(x) and 0 < x <= MAX_SIZE_M for x in size):
        return f"size_m: expected three numbers in (0, {MAX_SIZE_M:g}] (metres), got {_show(list(size))}"
    return shape.problem() if shape.type in SHAPE_CLASSES else None


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _is_finite(x) -> bool:
    """A JSON number that is finite as a float (an integer too long for one is not: the
    arithmetic would overflow)."""
    if isinstance(x, float):
        return math.isfinite(x)
    return _is_number(x) and abs(x) <= 1e300


def _show(x) -> str:
    text = repr(x)
    return text if len(text) <= 60 else text[:57] + "..."


def _finite_json(x, where: str) -> None:
    """x is JSON with finite numbers only (TracksError naming where otherwise)."""
    if _is_number(x) and not _is_finite(x):
        raise TracksError(f"{where}: expected a finite number, got {_show(x)}")
    if isinstance(x, dict):
        for k, v in x.items():
            _finite_json(v, f"{where}.{k}")
    elif isinstance(x, list):
        for j, v in enumerate(x):
            _finite_json(v, f"{where}[{j}]")
    elif not (x is None or isinstance(x, (str, bool, int, float))):
        raise TracksError(f"{where}: expected a JSON value, got {_show(x)}")


def _rows(o: dict, key: str, where: str, visible: list[bool], name: str, what: str, limit: float,
          unit: str) -> np.ndarray:
    rows = o.get(key, ...)
    if rows is ...:
        raise TracksError(f"{where}.{key}: missing")
    n = len(visible)
    if not isinstance(rows, list):
        raise TracksError(f"{where}.{key}: expected a list of {n} rows (one per frame), got {_show(rows)}")
    if len(rows) != n:
        raise TracksError(f"{where}.{key}: {len(rows)} rows but visible has {n} frames (one row per frame)")
    out = np.full((n, 3), math.nan)
    for f, (row, seen) in enumerate(zip(rows, visible)):
        three = isinstance(row, list) and len(row) == 3 and all(_is_number(x) for x in row)
        if not seen:
            if row is not None and not three:
                raise TracksError(f"{where}.{key}[{f}]: frame {f} is not visible: expected null (or three numbers), "
                                  f"got {_show(row)}")
            continue
        if not three or not all(_is_finite(x) for x in row):
            raise TracksError(f"{where}.{key}[{f}]: visible frame {f} of {name!r} has {what} {_show(row)}, not "
                              f"three finite numbers ({unit})")
        if any(abs(x) > limit for x in row):
            raise TracksError(f"{where}.{key}[{f}]: {_show(row)} is outside [-{limit:g}, {limit:g}] {unit}")
        out[f] = row
    return out


def _parse_object(o, i: int, n: int | None) -> ObjectTrack:
    where = f"objects[{i}]"
    if not isinstance(o, dict):
        raise TracksError(f"{where}: expected an object, got {_show(o)}")
    for key in ("name", "role"):
        if key not in o:
            raise TracksError(f"{where}.{key}: missing")
        if not isinstance(o[key], str) or not o[key]:
            raise TracksError(f"{where}.{key}: expected a non-empty string, got {_show(o[key])}")
    name = o["name"]
    if "visible" not in o:
        raise TracksError(f"{where}.visible: missing")
    visible = o["visible"]
    if not isinstance(visible, list):
        raise TracksError(f"{where}.visible: expected a list of true/false, one per frame, got {_show(visible)}")
    for f, v in enumerate(visible):
        if not isinstance(v, bool):
            raise TracksError(f"{where}.visible[{f}]: expected true or false, got {_show(v)}")
    if n is not None and len(visible) != n:
        raise TracksError(f"{where}.visible: {len(visible)} frames but objects[0] has {n} (every object one entry "
                          "per frame)")
    if len(visible) > MAX_FRAMES:
        raise TracksError(f"{where}.visible: {len(visible)} frames is more than the {MAX_FRAMES} allowed")
    pos = _rows(o, "position_m", where, visible, name, "position", MAX_POSITION_M, "m")
    vel = _rows(o, "velocity_mps", where, visible, name, "velocity", MAX_SPEED_MPS, "m/s")
    shape = _parse_shape(o.get("shape", ...), f"{where}.shape")
    off = o.get("offset_units")
    if off is not None:
        if (not _is_finite(off) or off != int(off)
                or not -MAX_OFFSET_UNITS <= off <= MAX_OFFSET_UNITS):
            raise TracksError(f"{where}.offset_units: expected null or an integer in [-{MAX_OFFSET_UNITS}, "
                              f"{MAX_OFFSET_UNITS}], got {_show(off)}")
        off = int(off)
    detected_by = o.get("detected_by", "motion")
    if not isinstance(detected_by, str):
        raise TracksError(f"{where}.detected_by: expected a string, got {_show(detected_by)}")
    bottom_up = o.get("bottom_up", {})
    if not isinstance(bottom_up, dict):
        raise TracksError(f"{where}.bottom_up: expected an object, got {_show(bottom_up)}")
    _finite_json(bottom_up, f"{where}.bottom_up")
    sd = o.get("position_sd_m")
    if sd is not None and (not _is_finite(sd) or not 0 <= sd <= MAX_POSITION_M):
        raise TracksError(f"{where}.position_sd_m: expected null or a number in [0, {MAX_POSITION_M:g}] (metres), "
                          f"got {_show(sd)}")
    return ObjectTrack(name, o["role"], pos, vel, np.array(visible, bool).reshape(-1), shape, off, detected_by,
                       bottom_up, position_sd_m=None if sd is None else float(sd))


def _parse_shape(d, where: str) -> Shape:
    if d is ...:
        raise TracksError(f"{where}: missing")
    if not isinstance(d, dict):
        raise TracksError(f"{where}: expected {{\"type\": ..., \"size_m\": [x, y, z]}}, got {_show(d)}")
    t = d.get("type", ...)
    if t is ...:
        raise TracksError(f"{where}.type: missing")
    if not isinstance(t, str) or not t.strip():
        raise TracksError(f"{where}.type: expected a shape type's name ({', '.join(SHAPE_CLASSES)}, or a scenario's "
                          f"own), got {_show(t)}")
    size = d.get("size_m", ...)
    if size is ...:
        raise TracksError(f"{where}.size_m: missing")
    if (not isinstance(size, list) or len(size) != 3 or not all(_is_finite(x) for x in size)
            or not all(0 < x <= MAX_SIZE_M for x in size)):
        raise TracksError(f"{where}.size_m: expected three numbers in (0, {MAX_SIZE_M:g}] (metres), got {_show(size)}")
    shape = Shape(t, tuple(float(x) for x in size))
    problem = shape.problem() if t in SHAPE_CLASSES else None   # (another type: the scenario's to check)
    if problem:
        raise TracksError(f"{where}: {problem}")
    return shape


def _parse_tracks(d) -> Tracks:
    if not isinstance(d, dict):
        raise TracksError(f"expected a JSON object at the top level, got {_show(d)}")
    fps = d.get("fps", ...)
    if fps is ...:
        raise TracksError("fps: missing")
    if not _is_finite(fps) or not 0 < fps <= MAX_FPS:
        raise TracksError(f"fps: expected a number in (0, {MAX_FPS:g}], got {_show(fps)}")
    fps = float(fps)
    objs = d.get("objects", ...)
    if objs is ...:
        raise TracksError("objects: missing")
    if not isinstance(objs, list) or not objs:
        raise TracksError(f"objects: expected a non-empty list of objects, got {_show(objs)}")
    objects: list[ObjectTrack] = []
    for i, o in enumerate(objs):
        objects.append(_parse_object(o, i, len(objects[0].visible) if objects else None))
    n = len(objects[0].visible)
    if "time_s" in d:
        t = d["time_s"]
        if not isinstance(t, list) or len(t) != n:
            raise TracksError(f"time_s: expected {n} times (one per frame), got "
                              f"{f'{len(t)} of them' if isinstance(t, list) else _show(t)}")
        for f, x in enumerate(t):
            if not _is_finite(x) or abs(x - f / fps) > TIME_TOLERANCE_S:
                raise TracksError(f"time_s[{f}]: expected frame {f} at {f / fps:.6g} s (fps {fps:g}), got {_show(x)}")
    notes = d.get("notes", [])
    if not isinstance(notes, list) or not all(isinstance(x, str) for x in notes):
        raise TracksError(f"notes: expected a list of strings, got {_show(notes)}")
    camera = d.get("camera", {})
    if not isinstance(camera, dict):
        raise TracksError(f"camera: expected an object, got {_show(camera)}")
    _finite_json(camera, "camera")
    return Tracks(fps, objects, list(notes), dict(camera))



@dataclass
class Trajectory:
    """Per-frame centre-of-mass positions (m) and velocities (m/s) in the world frame."""
    fps: float
    names: list[str]
    position_m: np.ndarray    # (n_objects, n_frames, 3)
    velocity_mps: np.ndarray  # (n_objects, n_frames, 3)
    orientation_xyzw: np.ndarray | None = None  # (n_objects, n_frames, 4), when asked for (not saved)

    @property
    def n_frames(self) -> int:
        return self.position_m.shape[1]

    @property
    def time_s(self) -> np.ndarray:
        return np.arange(self.n_frames) / self.fps

    def to_json(self) -> dict:
        return {"fps": self.fps, "time_s": self.time_s.tolist(),
                "objects": [{"name": n, "position_m": self.position_m[i].tolist(),
                             "velocity_mps": self.velocity_mps[i].tolist()} for i, n in enumerate(self.names)]}

    @classmethod
    def from_json(cls, d: dict) -> "Trajectory":
        try:
            objs = d["objects"]
            return cls(float(d["fps"]), [o["name"] for o in objs],
                       np.array([o["position_m"] for o in objs], float).reshape(len(objs), -1, 3),
                       np.array([o["velocity_mps"] for o in objs], float).reshape(len(objs), -1, 3))
        except (KeyError, TypeError, ValueError) as e:
            raise GalileoError(f"malformed trajectory JSON: {e}") from None

    def save(self, path: str | Path) -> None:
        write_json(path, self.to_json(), indent=None)

    @classmethod
    def load(cls, path: str | Path) -> "Trajectory":
        return cls.from_json(read_json(path, "trajectory file"))


