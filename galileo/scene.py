"""Scene & priors: the ramp world of Galileo (NIPS 2015, section 3) as data.

World frame (metres, z up): the ramp's foot is the origin, the ramp rises towards -x,
the ground is the plane z = 0 and x points from the ramp towards the target; y is the
horizontal axis across the ramp (the camera looks along +y).

The ramp object starts `start_units + offset_units` units up the ramp (measured along
the surface from the foot to the object's centre). One unit is `unit_m` (default 2 cm,
so the paper's "30 units up, offset in {0, ±1, ..., ±5}" is 60 cm ± 10 cm).
The target stands on the ground with its near face `distance_m` from the foot.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from .errors import SceneError
from .jsonio import read_json, write_json
from .shapes import SHAPE_TYPES, Shape

SCENE_VERSION = 1
ROLES = ("ramp", "target")
TARGET_KINDS = ("cardboard", "foam")
# latent name -> (object index, attribute)
LATENTS = {"m1_kg": (0, "mass_kg"), "k1": (0, "friction"), "m2_kg": (1, "mass_kg"), "k2": (1, "friction")}
# names `--set` accepts besides the latents
SCENE_KNOBS = ("offset_units", "angle_deg", "e1", "e2")


# -- priors --------------------------------------------------------------------

DEFAULT_BOUNDS = {"m1_kg": (0.001, 1.0), "k1": (0.0, 1.0), "m2_kg": (0.001, 1.0), "k2": (0.0, 1.0)}


@dataclass(frozen=True)
class Priors:
    """The paper's priors as data: uniform bounds you may change at run time.

    mass ~ U(0.001, 1) kg, friction ~ U(0, 1), shape type uniform over box / cylinder /
    torus, per-axis size uniform over `size_m`, offset uniform over the integers in
    `offset_units`.
    """
    bounds: dict = field(default_factory=lambda: dict(DEFAULT_BOUNDS))
    offset_units: tuple[int, int] = (-5, 5)
    shape_types: tuple[str, ...] = SHAPE_TYPES
    size_m: tuple[float, float] = (0.01, 0.2)

    def log_prob(self, latents: dict[str, float]) -> float:
        """Log density of the continuous latents (uniform): a constant inside, -inf outside."""
        lp = 0.0
        for name, value in latents.items():
            lo, hi = self.bounds[name]
            if not lo <= value <= hi:
                return -math.inf
            lp -= math.log(hi - lo)
        return lp

    def sample(self, rng: np.random.Generator, names: Iterable[str]) -> dict[str, float]:
        return {n: float(rng.uniform(*self.bounds[n])) for n in names}

    def sample_offset(self, rng: np.random.Generator) -> int:
        return int(rng.integers(self.offset_units[0], self.offset_units[1] + 1))

    def sample_shape(self, rng: np.random.Generator) -> Shape:
        kind = self.shape_types[int(rng.integers(len(self.shape_types)))]
        lo, hi = self.size_m
        sx, sy, sz = rng.uniform(lo, hi, 3)
        if kind == "cylinder":
            sz = sy
        elif kind == "torus":
            sy = sx = max(sx, sy)
            sz = min(sz, 0.45 * sx)
        return Shape(kind, (sx, sy, sz))

    def with_bounds(self, **bounds: tuple[float, float]) -> "Priors":
        new = dict(self.bounds)
        for k, v in bounds.items():
            if k not in new:
                raise KeyError(k)
            new[k] = (float(v[0]), float(v[1]))
        return replace(self, bounds=new)

    def to_json(self) -> dict:
        return {**{k: list(v) for k, v in self.bounds.items()},
                "offset_units": list(self.offset_units), "shape_types": list(self.shape_types),
                "size_m": list(self.size_m)}


# -- scene parts ------------------------------------------------------------------

@dataclass(frozen=True)
class Ramp:
    angle_deg: float = 20.0
    length_m: float = 0.9
    width_m: float = 0.3
    thickness_m: float = 0.02

    @property
    def angle_rad(self) -> float:
        return math.radians(self.angle_deg)

    @property
    def downhill(self) -> np.ndarray:
        """Unit vector along the fall line, pointing down the slope (world frame)."""
        a = self.angle_rad
        return np.array([math.cos(a), 0.0, -math.sin(a)])

    @property
    def normal(self) -> np.ndarray:
        a = self.angle_rad
        return np.array([math.sin(a), 0.0, math.cos(a)])

    @property
    def orientation_xyzw(self) -> tuple[float, float, float, float]:
        """Rotation taking object axes to ramp axes: +angle about world y."""
        h = self.angle_rad / 2
        return (0.0, math.sin(h), 0.0, math.cos(h))


@dataclass(frozen=True)
class SceneObject:
    name: str
    role: str  # "ramp" | "target"
    shape: Shape
    mass_kg: float
    friction: float
    restitution: float = 0.0
    material: str | None = None
    offset_units: int = 0           # ramp object only
    kind: str | None = None         # target only: cardboard | foam
    distance_m: float = 0.1         # target only: foot of ramp -> near face of target

    def to_json(self) -> dict:
        d: dict[str, Any] = {"name": self.name, "role": self.role, "shape": self.shape.to_json(),
                             "mass_kg": self.mass_kg, "friction": self.friction,
                             "restitution": self.restitution}
        if self.material is not None:
            d["material"] = self.material
        if self.role == "ramp":
            d["offset_units"] = self.offset_units
        else:
            d["kind"] = self.kind
            d["distance_m"] = self.distance_m
        return d


@dataclass(frozen=True)
class Camera:
    """Pinhole camera, OpenCV convention (x right, y down, z forward)."""
    K: np.ndarray               # (3, 3) intrinsics in pixels
    world_to_camera: np.ndarray  # (4, 4) rigid transform
    width_px: int = 640
    height_px: int = 480
    fps: float = 30.0
    n_frames: int = 90

    def __eq__(self, other: object) -> bool:
        # the generated __eq__ compares the arrays with `==` and raises on their truth value
        if not isinstance(other, Camera):
            return NotImplemented
        return (np.array_equal(self.K, other.K) and np.array_equal(self.world_to_camera, other.world_to_camera)
                and (self.width_px, self.height_px, self.fps, self.n_frames)
                == (other.width_px, other.height_px, other.fps, other.n_frames))

    def project(self, pos_in_world: np.ndarray) -> np.ndarray:
        """World points (..., 3) -> pixel coordinates (..., 2)."""
        p = np.asarray(pos_in_world, float)
        pc = p @ self.world_to_camera[:3, :3].T + self.world_to_camera[:3, 3]
        uv = pc @ self.K.T
        return uv[..., :2] / uv[..., 2:3]

    @property
    def position_in_world(self) -> np.ndarray:
        r, t = self.world_to_camera[:3, :3], self.world_to_camera[:3, 3]
        return -r.T @ t

    def to_json(self) -> dict:
        return {"K": self.K.tolist(), "world_to_camera": self.world_to_camera.tolist(),
                "width_px": self.width_px, "height_px": self.height_px,
                "fps": self.fps, "n_frames": self.n_frames}


def look_at_camera(eye: Iterable[float], target: Iterable[float], *, focal_px: float = 560.0,
                   width_px: int = 640, height_px: int = 480, fps: float = 30.0,
                   n_frames: int = 90) -> Camera:
    """A camera at `eye` looking at `target` with the world's z axis up in the image."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    fwd = target - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    r = np.stack([right, down, fwd])  # rows: camera axes in world
    m = np.eye(4)
    m[:3, :3] = r
    m[:3, 3] = -r @ eye
    k = np.array([[focal_px, 0, width_px / 2], [0, focal_px, height_px / 2], [0, 0, 1.0]])
    return Camera(k, m, width_px, height_px, fps, n_frames)


def default_camera(fps: float = 30.0, n_frames: int = 90) -> Camera:
    """The dataset's camera: at the side of the ramp, 1.2 m away, slightly above."""
    return look_at_camera((-0.2, -1.2, 0.3), (-0.2, 0.0, 0.16), fps=fps, n_frames=n_frames)


@dataclass(frozen=True)
class Scene:
    ramp: Ramp
    objects: tuple[SceneObject, ...]
    camera: Camera | None = None
    unit_m: float = 0.02
    start_units: float = 30.0
    sim_hz: int = 240
    gravity_mps2: float = 9.81
    priors: Priors = field(default_factory=Priors)

    # -- access ---------------------------------------------------------------
    @property
    def ramp_object(self) -> SceneObject:
        return self.objects[0]

    @property
    def target(self) -> SceneObject | None:
        return self.objects[1] if len(self.objects) > 1 else None

    @property
    def latent_names(self) -> tuple[str, ...]:
        return tuple(n for n, (i, _) in LATENTS.items() if i < len(self.objects))

    def latents(self) -> dict[str, float]:
        return {n: float(getattr(self.objects[i], a)) for n, (i, a) in LATENTS.items() if i < len(self.objects)}

    def with_values(self, values: dict[str, float]) -> "Scene":
        """A copy with latents (m1_kg, k1, m2_kg, k2) and knobs (offset_units, angle_deg, e1, e2) set."""
        objs = list(self.objects)
        ramp = self.ramp
        for name, value in values.items():
            if name in LATENTS:
                i, attr = LATENTS[name]
                if i >= len(objs):
                    raise SceneError(f"{name}: this scene has no target object")
                objs[i] = replace(objs[i], **{attr: float(value)})
            elif name == "offset_units":
                objs[0] = replace(objs[0], offset_units=int(round(value)))
            elif name in ("e1", "e2"):
                i = int(name[1]) - 1
                if i >= len(objs):
                    raise SceneError(f"{name}: this scene has no target object")
                objs[i] = replace(objs[i], restitution=float(value))
            elif name == "angle_deg":
                ramp = replace(ramp, angle_deg=float(value))
            else:
                raise SceneError(f"unknown name {name!r}; expected one of {', '.join([*LATENTS, *SCENE_KNOBS])}")
        new = replace(self, objects=tuple(objs), ramp=ramp)
        new.validate()
        return new

    # -- geometry ---------------------------------------------------------------
    def start_distance_m(self, obj: SceneObject | None = None) -> float:
        obj = obj or self.ramp_object
        return (self.start_units + obj.offset_units) * self.unit_m

    def initial_pose(self, index: int) -> tuple[np.ndarray, tuple[float, float, float, float]]:
        """Centre position (world) and orientation (x, y, z, w) of object `index` at t = 0."""
        obj = self.objects[index]
        if obj.role == "ramp":
            s = self.start_distance_m(obj)
            pos = -s * self.ramp.downhill + (obj.shape.height_m / 2) * self.ramp.normal
            return pos, self.ramp.orientation_xyzw
        return np.array([obj.distance_m + obj.shape.size_m[0] / 2, 0.0, obj.shape.height_m / 2]), (0.0, 0.0, 0.0, 1.0)

    def geometry_key(self) -> tuple:
        """What a physics world must be rebuilt for (everything except latents, offset, restitution)."""
        return (self.ramp, self.sim_hz, self.gravity_mps2,
                tuple((o.role, o.shape, o.distance_m if o.role == "target" else None) for o in self.objects))

    # -- validation & IO --------------------------------------------------------------
    def validate(self) -> None:
        r = self.ramp
        if not 0 <= r.angle_deg < 60:
            raise SceneError(f"ramp.angle_deg must be in [0, 60), got {r.angle_deg}")
        ramp_obj = self.ramp_object
        top = self.start_distance_m(ramp_obj) + ramp_obj.shape.size_m[0] / 2
        if top > r.length_m:
            raise SceneError(f"objects[0]: starts {top:.3f} m up the ramp, beyond its length_m {r.length_m}")
        if self.start_distance_m(ramp_obj) - ramp_obj.shape.size_m[0] / 2 < 0:
            raise SceneError("objects[0]: start position puts the object past the ramp's foot")
        if self.camera is not None and self.sim_hz % self.camera.fps:
            raise SceneError(f"sim_hz ({self.sim_hz}) must be a multiple of camera.fps ({self.camera.fps})")

    def to_json(self) -> dict:
        d: dict[str, Any] = {
            "version": SCENE_VERSION,
            "ramp": {"angle_deg": self.ramp.angle_deg, "length_m": self.ramp.length_m,
                     "width_m": self.ramp.width_m, "thickness_m": self.ramp.thickness_m},
            "unit_m": self.unit_m, "start_units": self.start_units,
            "sim_hz": self.sim_hz, "gravity_mps2": self.gravity_mps2,
            "objects": [o.to_json() for o in self.objects],
            "priors": self.priors.to_json(),
        }
        if self.camera is not None:
            d["camera"] = self.camera.to_json()
        return d

    def save(self, path: str | Path) -> None:
        write_json(path, self.to_json())

    @classmethod
    def load(cls, path: str | Path) -> "Scene":
        data = read_json(path, "scene file")
        try:
            return scene_from_json(data)
        except SceneError as e:
            raise SceneError(f"{path}: {e}") from None


# -- parsing with field-named errors ---------------------------------------------------

def _get(d: dict, key: str, path: str, default: Any = ...) -> Any:
    if not isinstance(d, dict):
        raise SceneError(f"{path}: expected an object")
    if key not in d:
        if default is ...:
            raise SceneError(f"{path}.{key}: missing".lstrip("."))
        return default
    return d[key]


def _num(d: dict, key: str, path: str, default: Any = ..., lo: float = -math.inf, hi: float = math.inf,
         lo_open: bool = False, integer: bool = False) -> float:
    v = _get(d, key, path, default)
    where = f"{path}.{key}".lstrip(".")
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise SceneError(f"{where}: expected a number, got {v!r}")
    if integer and int(v) != v:
        raise SceneError(f"{where}: expected an integer, got {v!r}")
    if v < lo or v > hi or (lo_open and v == lo):
        bound = f"({lo}, {hi}]" if lo_open else f"[{lo}, {hi}]"
        raise SceneError(f"{where}: {v} is outside {bound}")
    return int(v) if integer else float(v)


def _pair(d: dict, key: str, path: str, default: Any) -> tuple[float, float]:
    v = _get(d, key, path, default)
    where = f"{path}.{key}".lstrip(".")
    if (not isinstance(v, (list, tuple)) or len(v) != 2
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)
            or v[0] > v[1]):
        raise SceneError(f"{where}: expected [low, high] with low <= high, got {v!r}")
    return float(v[0]), float(v[1])


def _matrix(d: dict, key: str, path: str, shape: tuple[int, int]) -> np.ndarray:
    v = _get(d, key, path)
    where = f"{path}.{key}".lstrip(".")
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        a = None
    if a is None or a.shape != shape or not np.all(np.isfinite(a)):
        raise SceneError(f"{where}: expected a {shape[0]}x{shape[1]} matrix of numbers")
    return a


def _shape(d: dict, path: str) -> Shape:
    t = _get(d, "type", path)
    size = _get(d, "size_m", path)
    if not isinstance(size, list) or len(size) != 3 or not all(
            isinstance(x, (int, float)) and not isinstance(x, bool) for x in size):
        raise SceneError(f"{path}.size_m: expected three numbers (metres), got {size!r}")
    shape = Shape(str(t), tuple(size))
    problem = shape.problem()
    if problem:
        raise SceneError(f"{path}: {problem}")
    return shape


def _object(d: dict, i: int) -> SceneObject:
    path = f"objects[{i}]"
    role = _get(d, "role", path, "ramp" if i == 0 else "target")
    want = "ramp" if i == 0 else "target"
    if role != want:
        raise SceneError(f"{path}.role: object {i} must be the {want} object, got {role!r}")
    name = _get(d, "name", path, "ramp_object" if i == 0 else "target")
    if not isinstance(name, str) or not name:
        raise SceneError(f"{path}.name: expected a non-empty string")
    material = _get(d, "material", path, None)
    if material is not None and not isinstance(material, str):
        raise SceneError(f"{path}.material: expected a string")
    common = dict(
        name=name, role=role, shape=_shape(_get(d, "shape", path), f"{path}.shape"),
        mass_kg=_num(d, "mass_kg", path, lo=0, lo_open=True),
        friction=_num(d, "friction", path, lo=0, hi=10),
        restitution=_num(d, "restitution", path, 0.0, lo=0, hi=1),
        material=material)
    if role == "ramp":
        return SceneObject(**common, offset_units=_num(d, "offset_units", path, 0, integer=True))
    kind = _get(d, "kind", path, "cardboard")
    if kind not in TARGET_KINDS:
        raise SceneError(f"{path}.kind: expected one of {', '.join(TARGET_KINDS)}, got {kind!r}")
    return SceneObject(**common, kind=kind, distance_m=_num(d, "distance_m", path, lo=0))


def _camera(d: dict) -> Camera:
    p = "camera"
    k = _matrix(d, "K", p, (3, 3))
    m = _matrix(d, "world_to_camera", p, (4, 4))
    r = m[:3, :3]
    if not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or not np.allclose(m[3], [0, 0, 0, 1]):
        raise SceneError("camera.world_to_camera: expected a rigid transform (rotation + translation)")
    if k[0, 0] <= 0 or k[1, 1] <= 0:
        raise SceneError("camera.K: focal lengths must be positive")
    return Camera(k, m, _num(d, "width_px", p, lo=1, integer=True), _num(d, "height_px", p, lo=1, integer=True),
                  _num(d, "fps", p, lo=0, lo_open=True), _num(d, "n_frames", p, lo=1, integer=True))


def scene_from_json(data: Any) -> Scene:
    if not isinstance(data, dict):
        raise SceneError("expected a JSON object at the top level")
    version = _get(data, "version", "", SCENE_VERSION)
    if version != SCENE_VERSION:
        raise SceneError(f"version: this Galileo reads scene version {SCENE_VERSION}, got {version!r}")
    rd = _get(data, "ramp", "")
    ramp = Ramp(angle_deg=_num(rd, "angle_deg", "ramp", lo=0, hi=59.9),
                length_m=_num(rd, "length_m", "ramp", 0.9, lo=0, lo_open=True),
                width_m=_num(rd, "width_m", "ramp", 0.3, lo=0, lo_open=True),
                thickness_m=_num(rd, "thickness_m", "ramp", 0.02, lo=0, lo_open=True))
    objs = _get(data, "objects", "")
    if not isinstance(objs, list) or not 1 <= len(objs) <= 2:
        raise SceneError("objects: expected a list of one (ramp object) or two (ramp object, target) objects")
    objects = tuple(_object(o, i) for i, o in enumerate(objs))
    pd = _get(data, "priors", "", {})
    base = Priors()
    bounds = {k: _pair(pd, k, "priors", list(v)) for k, v in base.bounds.items()}
    for k, (lo, hi) in bounds.items():
        if k.startswith("m") and lo <= 0:
            raise SceneError(f"priors.{k}: mass bounds must be positive")
        if k.startswith("k") and lo < 0:
            raise SceneError(f"priors.{k}: friction bounds must be >= 0")
    off = _pair(pd, "offset_units", "priors", list(base.offset_units))
    types = _get(pd, "shape_types", "priors", list(base.shape_types))
    if not isinstance(types, list) or not types or any(t not in SHAPE_TYPES for t in types):
        raise SceneError(f"priors.shape_types: expected a non-empty list from {', '.join(SHAPE_TYPES)}")
    priors = Priors(bounds=bounds, offset_units=(int(off[0]), int(off[1])), shape_types=tuple(types),
                    size_m=_pair(pd, "size_m", "priors", list(base.size_m)))
    cam = _get(data, "camera", "", None)
    scene = Scene(
        ramp=ramp, objects=objects, camera=_camera(cam) if cam is not None else None,
        unit_m=_num(data, "unit_m", "", 0.02, lo=0, lo_open=True),
        start_units=_num(data, "start_units", "", 30.0, lo=0),
        sim_hz=_num(data, "sim_hz", "", 240, lo=1, integer=True),
        gravity_mps2=_num(data, "gravity_mps2", "", 9.81, lo=0),
        priors=priors)
    scene.validate()
    return scene


# -- the default scene ------------------------------------------------------------------

TARGET_DEFAULTS = {
    # kind: (shape, mass_kg, friction)
    "cardboard": (Shape("box", (0.10, 0.08, 0.07)), 0.12, 0.35),
    "foam": (Shape("box", (0.08, 0.08, 0.06)), 0.03, 0.55),
}


def default_scene(angle_deg: float = 20.0, *, mass_kg: float = 0.5, friction: float = 0.2,
                  target: str | None = "cardboard", shape: Shape | None = None,
                  offset_units: int = 0, distance_m: float = 0.1, camera: Camera | None = None) -> Scene:
    """The dataset's standard geometry with the given ramp object and target (or none)."""
    objs = [SceneObject("ramp_object", "ramp", shape or Shape("box", (0.06, 0.05, 0.04)),
                        mass_kg, friction, offset_units=offset_units)]
    if target not in (None, "none"):
        if target not in TARGET_DEFAULTS:
            raise SceneError(f"target: expected none, {', '.join(TARGET_DEFAULTS)}; got {target!r}")
        tshape, tm, tk = TARGET_DEFAULTS[target]
        objs.append(SceneObject("target", "target", tshape, tm, tk, material=target, kind=target,
                                distance_m=distance_m))
    scene = Scene(Ramp(angle_deg=angle_deg), tuple(objs), camera=camera)
    scene.validate()
    return scene
