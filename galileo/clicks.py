"""Own-video calibration: a scene file from points clicked on a video's first frame and a few
measured numbers (`galileo scene`, and the upload page of `python app.py --upload`).

A scenario that can be calibrated declares a `Calibration` (its class's `calibration`; None
where it cannot):

* `points`: what to click, in order, each with a one-line instruction;
* `fields`: its numbers (name with its unit, default, bounds, help), from which both the
  command line's flags (`--name-with-dashes`) and the upload page's inputs (`label (unit)`)
  are made: the scenario declares its controls, the command line and the page only draw them.
  A default of None means "found in the video or estimated" (the help says how);
* `solve(clicks_px, numbers, video_info, frames) -> (scene, RMS reprojection error in pixels)`,
  a one-line GalileoError naming what to fix otherwise (`NotFound`, with the scene so far,
  where only a quantity to be found in the video was not); every number is checked against its
  field first, every click against the frame;
* `draw_overlay(frame, scene, clicks)`: the scene projected over the frame, to check by eye;
* `describe(scene, numbers)`: one line of what was solved, estimated and found.

Every calibration takes the lens's distortion (`DISTORTION`, `--distortion`: OpenCV's k1, 0
for none; see `galileo.camera`): the clicks are where the lens put the points, so the solvers
undistort them (`pinhole_clicks`) before they fit a pinhole camera, estimating the focal length
again from clicks undistorted with the last estimate (`focal_through_lens`), and the camera
they write carries the k1.

Shared here: the checks every set of clicks gets, the corners of a quadrilateral in order
(`check_quad`), the camera from points on a plane of known shape (`camera_from_plane`: the
focal length from the plane's homography unless given, the pose by planar PnP), the clicks
through the lens (`pinhole_clicks`, `focal_through_lens`), drawing, and
the frames a solver looks for the objects in (`sample_video`).
"""
from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from .camera import K1
from .errors import GalileoError
from .fields import Bound, show

MIN_SIDE_PX = 4.0            # two clicks closer than this are one point
MIN_AREA_PX2 = 100.0         # a quadrilateral thinner than this is a line
MIN_CORNER_SINE = 0.02       # a corner straighter than this (about 1 degree off a line) is no corner
MAX_REPROJECTION_PX = 25.0   # clicks farther than this from the stated geometry are refused
MAX_FOCAL_SPREAD_PER_PX = 0.2   # a focal length that one pixel of error in the clicks moves by more than this
# fraction is not estimated (the plane is seen nearly face-on, or the clicks are off): the user gives it. The
# ramp's views move it by 4-8% a pixel, a tank seen straight from the front by thousands; of clicks 1.5 px off
# the ramp dataset's view (bench/bench_clicks.py) it refuses 4%, whose estimates were 39% off (median)
SAMPLE_MAX_FRAMES = 60       # the solvers look for objects in at most this many frames: the first two, then
SAMPLE_MAX_SIDE_PX = 640     # ... evenly spaced over the video, at most this many pixels on their long side
SAMPLE_FIRST = 2             # the video's first frames always kept (the object's speed at the start)
FOCAL_ROUNDS = 20            # through a lens, the focal length is estimated again at most this many times ...
FOCAL_ROUNDS_TOL = 1e-9      # ... until it moves by less than this fraction (a few rounds for |k1| < 0.3)
CLICK_RGB = (230, 30, 30)


class NotFound(GalileoError):
    """The clicks and numbers make a scene, but a quantity to be found in the video was not
    found: `scene` has a stand-in for it (to draw), the message says which number to give."""

    def __init__(self, message: str, scene):
        super().__init__(message)
        self.scene = scene


@dataclass(frozen=True)
class Point:
    """A point to click: its name (in the order and in messages) and where it is."""
    name: str
    hint: str


@dataclass(frozen=True)
class Field:
    """One number (or choice) a calibration needs. Its flag is --name (dashes for underscores),
    its input on the page `label (unit)`."""
    name: str                       # with its unit (ramp_length_m): the key in solve's `numbers`
    label: str                      # the page's words (Length)
    unit: str                       # m, deg, px; "" for a choice
    default: Any                    # when not given: a number, a choice, or None (found or estimated)
    help: str                       # one line: what it is, and what None means
    bound: Bound | None = None      # each number's range
    choices: tuple[str, ...] = ()   # a choice among these instead of a number
    size: int = 1                   # numbers in one value (3: a size x, y, z)
    required: bool = False          # must be given (a measurement only the user has; the page starts from default)

    @property
    def flag(self) -> str:
        return "--" + self.name.replace("_", "-")

    @property
    def title(self) -> str:
        return f"{self.label} ({self.unit})" if self.unit else self.label

    def text(self, value: Any) -> str:
        """A value as the page's input shows it (None: blank)."""
        if value is None:
            return ""
        if isinstance(value, str):
            return value
        return ", ".join(f"{float(v):g}" for v in np.atleast_1d(value))

    def parse(self, value: Any) -> Any:
        """A value given as text (the command line's, the page's) or as itself, checked; None
        for blank (not given). A GalileoError naming the flag otherwise."""
        if value is None or (isinstance(value, str) and not value.strip()):
            return None
        if self.choices:
            if value not in self.choices:
                raise GalileoError(f"{self.flag}: expected one of {', '.join(self.choices)}, got {value!r}")
            return value
        parts = re.split(r"[\s,]+", value.strip()) if isinstance(value, str) else list(np.atleast_1d(value))
        if len(parts) != self.size:
            want = "a number" if self.size == 1 else f"{self.size} numbers x, y, z" if self.size == 3 else \
                f"{self.size} numbers"
            raise GalileoError(f"{self.flag}: expected {want}, got {value!r}")
        nums = []
        for p in parts:
            try:
                v = float(p)
            except (TypeError, ValueError):
                raise GalileoError(f"{self.flag}: expected a number, got {p!r}") from None
            typed = p if isinstance(p, str) else show(p)
            if not math.isfinite(v):
                raise GalileoError(f"{self.flag}: expected a finite number, got {typed}")
            if self.bound is not None and not self.bound.contains(v):
                raise GalileoError(f"{self.flag}: {typed} is outside {self.bound}")
            nums.append(v)
        return nums[0] if self.size == 1 else tuple(nums)


DISTORTION = Field("distortion", "Lens distortion k1", "", 0.0, "the lens's radial distortion: OpenCV's k1 for "
                   "the video's resolution (calibrated, or from the camera's specification); negative for barrel "
                   "distortion (straight lines near the frame's edges bow outwards: phones, webcams), 0 for none",
                   K1)   # every calibration has it (in each scenario's FIELDS after focal_px)


NAME_ID = re.compile(r"^[a-z][a-z0-9]{0,23}$")   # a name that goes into latent names (m_<object>_kg)


@dataclass(frozen=True)
class NameField(Field):
    """A field whose value is a name (an id: 1-24 lowercase letters and digits, starting with a
    letter: an object's, a spring's, a surface's), not a number; `names` says which latents it
    names (for the message)."""
    names: str = "the latents"

    def parse(self, value):
        if value is None or (isinstance(value, str) and not value.strip()):
            return None
        if not (isinstance(value, str) and NAME_ID.match(value.strip())):
            raise GalileoError(f"{self.flag}: {show(value)} is not a name: 1-24 lowercase letters and digits, "
                               f"starting with a letter (it names {self.names})")
        return value.strip()


@dataclass(frozen=True)
class Calibration:
    """A scenario's own-video calibration (see the module)."""
    subject: str                      # what its videos show ("an object sliding down a ramp")
    points: tuple[Point, ...]
    fields: tuple[Field, ...]
    solver: Callable[..., tuple[Any, float]]      # (clicks (N, 2), checked numbers, VideoInfo, frames)
    overlay: Callable[..., np.ndarray]            # (frame, scene, clicks or None) -> picture
    describer: Callable[[Any, dict], str]         # (scene, checked numbers) -> one line
    # (scene) -> (the points' world positions (N, 3) in the clicks' order, the numbers that describe
    # the scene): what a user would click in a video of that scene and type (tests, the contract suite)
    example: Callable[[Any], tuple[np.ndarray, dict]] | None = None

    @property
    def order(self) -> str:
        return ", ".join(p.name for p in self.points)

    def values(self, numbers: Mapping[str, Any]) -> dict:
        """Every field's value from `numbers` (name -> text or value; missing or blank: the
        default), each checked against its field; a GalileoError naming the flag otherwise."""
        known = {f.name for f in self.fields}
        for name in numbers:
            if name not in known:
                raise GalileoError(f"unknown number {name!r}; expected one of {', '.join(sorted(known))}")
        out = {}
        for f in self.fields:
            v = f.parse(numbers.get(f.name))
            if v is None and f.required:
                raise GalileoError(f"{f.flag} is needed: {f.help}")
            out[f.name] = f.default if v is None else v
        return out

    def check_clicks(self, clicks_px, width_px: int, height_px: int) -> np.ndarray:
        """The clicks as an (N, 2) array: as many as the points, inside the frame, distinct."""
        n = len(self.points)
        uv = np.asarray(clicks_px, float)
        if uv.shape != (n, 2) or not np.isfinite(uv).all():
            raise GalileoError(f"give {n} points u,v (pixels): {self.order}")
        for p, (u, v) in zip(self.points, uv):
            if not (0 <= u < width_px and 0 <= v < height_px):
                raise GalileoError(f"the {p.name} point ({u:g}, {v:g}) is outside the {width_px}x{height_px} frame")
        for i in range(n):
            for j in range(i + 1, n):
                if np.linalg.norm(uv[i] - uv[j]) < MIN_SIDE_PX:
                    raise GalileoError(f"the {self.points[i].name} and {self.points[j].name} points are the same point")
        return uv

    def solve(self, clicks_px, numbers: Mapping[str, Any], video_info, frames=None):
        """(scene, RMS reprojection error in pixels) for a video (`galileo.video.VideoInfo`)
        from the clicks and the numbers; `frames`: `sample_video`'s, where the solver looks
        for the objects (None: nothing is found, every such number must be given)."""
        uv = self.check_clicks(clicks_px, video_info.width_px, video_info.height_px)
        return self.solver(uv, self.values(numbers), video_info, frames)

    def draw_overlay(self, frame_rgb: np.ndarray, scene, clicks=None) -> np.ndarray:
        return self.overlay(frame_rgb, scene, clicks)

    def describe(self, scene, numbers: Mapping[str, Any]) -> str:
        return self.describer(scene, self.values(numbers))


def calibrations() -> dict[str, Calibration]:
    """The registered scenarios that can be calibrated, by name."""
    from . import registry

    return {name: registry.get(name).calibration for name in registry.with_capability("calibration")}


def calibration_of(name: str) -> Calibration:
    """The scenario's calibration; a GalileoError naming those that have one otherwise."""
    from . import registry

    cal = registry.get(name).calibration
    if cal is None:
        raise GalileoError(f"the {name} scenario has no own-video calibration; these have: "
                           f"{', '.join(calibrations())}")
    return cal


def parse_points(text: str, most: int, where: str = "--points") -> list[tuple[float, float]]:
    """'u,v u,v ...' (or 'u v u v', '(u, v); ...'; pixels) -> at most `most` points; a
    GalileoError naming `where` if malformed."""
    parts = [p for p in re.split(r"[\s,;()\[\]]+", text) if p]
    try:
        nums = [float(p) for p in parts]
    except ValueError:
        bad = next(p for p in parts if not _is_float(p))
        raise GalileoError(f"{where}: expected u,v pairs like '120.5,88 300,90', got {bad!r}") from None
    if len(nums) % 2:
        raise GalileoError(f"{where}: expected u,v pairs like '120.5,88 300,90', got {len(nums)} numbers")
    if not all(math.isfinite(v) for v in nums):
        raise GalileoError(f"{where}: the points must be finite numbers, got {text.strip()!r}")
    if len(nums) // 2 > most:
        raise GalileoError(f"{where}: {most} points at most, got {len(nums) // 2}")
    return list(zip(nums[::2], nums[1::2]))


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


# -- geometry shared by the solvers -------------------------------------------------------------

def _cross(a, b) -> float:
    """The z component of the cross product of two image vectors."""
    return float(a[0] * b[1] - a[1] * b[0])


def check_quad(uv: np.ndarray, names, what: str) -> None:
    """A GalileoError unless four clicks are the corners of a convex quadrilateral in the order
    named (either way round): `what` says what it is ("the ramp's top surface")."""
    order = ", ".join(names)
    turns = [_cross(uv[(i + 1) % 4] - uv[i], uv[(i + 2) % 4] - uv[(i + 1) % 4]) for i in range(4)]
    area = 0.5 * abs(sum(_cross(uv[i], uv[(i + 1) % 4]) for i in range(4)))
    # |turn| / (the two sides' lengths) is the sine of the angle at a corner
    sines = [abs(t) / (np.linalg.norm(uv[(i + 1) % 4] - uv[i]) * np.linalg.norm(uv[(i + 2) % 4] - uv[(i + 1) % 4]))
             for i, t in enumerate(turns)]
    if min(sines) > MIN_CORNER_SINE and not (all(t > 0 for t in turns) or all(t < 0 for t in turns)):
        raise GalileoError(f"the four points cross over: give them in the order {order} (going round {what})")
    if area < MIN_AREA_PX2 or min(sines) <= MIN_CORNER_SINE:
        raise GalileoError(f"three of the four points are on one line: click the four corners of {what}, in the "
                           f"order {order}")


def focal_from_homography(h: np.ndarray, cx: float, cy: float, what: str = "the plane") -> float:
    """The focal length (pixels) for which the plane homography `h` (orthonormal plane
    coordinates -> pixels) has orthogonal columns of equal length through K."""
    g = np.array([[1, 0, -cx], [0, 1, -cy], [0, 0, 1.0]]) @ h
    h1, h2 = g[:, 0], g[:, 1]
    # (h1x h2x + h1y h2y) w + h1z h2z = 0;  (|h1xy|^2 - |h2xy|^2) w + (h1z^2 - h2z^2) = 0;  w = 1/f^2
    a = np.array([h1[0] * h2[0] + h1[1] * h2[1], h1[0] ** 2 + h1[1] ** 2 - h2[0] ** 2 - h2[1] ** 2])
    b = np.array([h1[2] * h2[2], h1[2] ** 2 - h2[2] ** 2])
    w = -float(a @ b) / float(a @ a)
    if not w > 0 or abs(float(b @ b)) < 1e-12 * float(a @ a) * w * w:
        raise GalileoError(f"cannot estimate the focal length from these points ({what} is seen face-on or the "
                           "points disagree with its size): give --focal-px")
    return 1.0 / math.sqrt(w)


def _plane_coordinates(points_in_world: np.ndarray) -> np.ndarray:
    """(N, 2) orthonormal coordinates of coplanar points in their plane."""
    p = points_in_world - points_in_world.mean(axis=0)
    _, _, vt = np.linalg.svd(p)
    return p @ vt[:2].T


def focal_spread_per_px(plane_xy: np.ndarray, uv: np.ndarray, cx: float, cy: float, what: str) -> float:
    """How much (a fraction of it) the focal length estimated from the clicks moves for an
    error of one pixel in each of their coordinates, independent: the root sum of squares of
    its derivatives (central differences of half a pixel)."""
    import cv2

    f = focal_from_homography(cv2.findHomography(plane_xy, uv)[0], cx, cy, what)
    grads = []
    for i in range(uv.size):
        d = np.zeros(uv.size)
        d[i] = 0.5
        d = d.reshape(uv.shape)
        hi, lo = (cv2.findHomography(plane_xy, uv + s * d)[0] for s in (1, -1))
        try:
            grads.append(focal_from_homography(hi, cx, cy, what) - focal_from_homography(lo, cx, cy, what))
        except GalileoError:     # half a pixel away there is no focal length at all
            return math.inf
    return float(np.sqrt(np.sum(np.square(grads)))) / f


def centred_intrinsics(focal_px: float, width_px: int, height_px: int) -> np.ndarray:
    """K of square pixels with the principal point at the image's centre (what the solvers assume)."""
    return np.array([[focal_px, 0.0, width_px / 2], [0.0, focal_px, height_px / 2], [0.0, 0.0, 1.0]])


def pinhole_clicks(uv: np.ndarray, video_info, focal_px: float, k1: float) -> np.ndarray:
    """Where a pinhole camera of this focal length (`centred_intrinsics`) sees the clicked
    points that a lens of distortion k1 put at `uv` (`Camera.undistort_px`); `uv` itself for
    k1 = 0. A GalileoError naming --distortion where the lens folds inside the image."""
    from .camera import Camera, check_distortion

    if k1 == 0.0:
        return uv
    w, h = int(video_info.width_px), int(video_info.height_px)
    cam = Camera(centred_intrinsics(focal_px, w, h), np.eye(4), w, h, k1=float(k1))
    check_distortion(cam, f"--distortion (with a focal length of {focal_px:.0f} px)")
    return cam.undistort_px(uv)


def focal_through_lens(estimate: Callable[[np.ndarray], float | None], uv: np.ndarray, video_info,
                       k1: float) -> float | None:
    """`estimate(clicks)`'s focal length (pixels; None: none) for clicks seen through a lens of
    distortion k1: undistorting them needs the focal length (k1 acts on normalised
    coordinates), so it is estimated from the clicks as they are, then again from the clicks
    undistorted with the last estimate (`pinhole_clicks`) until it moves by less than
    FOCAL_ROUNDS_TOL (at most FOCAL_ROUNDS rounds). Just `estimate(uv)` for k1 = 0."""
    f = estimate(uv)
    for _ in range(FOCAL_ROUNDS if k1 else 0):
        if f is None:
            break
        last, f = f, estimate(pinhole_clicks(uv, video_info, f, k1))
        if f is not None and abs(f - last) <= FOCAL_ROUNDS_TOL * last:
            break
    return f


def camera_from_plane(uv: np.ndarray, points_in_world: np.ndarray, video_info, *, facing: np.ndarray,
                      focal_px: float | None, what: str, k1: float = 0.0):
    """The camera that sees the coplanar world points at the clicks through a lens of
    distortion k1: the focal length from the plane's homography where not given (principal
    point at the image centre, square pixels; through the lens `focal_through_lens`; refused
    where the plane is seen so nearly face-on that a pixel's error moves it by more than
    MAX_FOCAL_SPREAD_PER_PX), the pose by OpenCV's planar PnP (IPPE) on the undistorted
    clicks. The camera must see the points in front of it, on the side of the plane `facing`
    points to (a mirrored order puts it behind)."""
    import cv2

    from .camera import Camera

    w, h = video_info.width_px, video_info.height_px
    cx, cy = w / 2, h / 2
    world = np.asarray(points_in_world, float)
    if focal_px is None:
        plane = _plane_coordinates(world)

        def estimate(clicks: np.ndarray) -> float:
            hom, _ = cv2.findHomography(plane, clicks)
            if hom is None:
                raise GalileoError(f"these points give no perspective view of {what}: check their order")
            return focal_from_homography(hom, cx, cy, what)

        focal_px = focal_through_lens(estimate, uv, video_info, k1)
        spread = focal_spread_per_px(plane, pinhole_clicks(uv, video_info, focal_px, k1), cx, cy, what)
        if spread > MAX_FOCAL_SPREAD_PER_PX:
            raise GalileoError(f"these points do not fix the focal length: a pixel's error in them moves it by "
                               f"{_percent(spread)} ({what} is seen too nearly face-on, or the points are off): give "
                               "--focal-px, or click them again more exactly")
    k = centred_intrinsics(focal_px, w, h)
    ok, rvec, tvec = cv2.solvePnP(world, pinhole_clicks(uv, video_info, focal_px, k1), k, None,
                                  flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise GalileoError("no camera pose fits these points")
    r, _ = cv2.Rodrigues(rvec)
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, tvec.ravel()
    cam = Camera(k, m, int(w), int(h), float(video_info.fps), int(video_info.n_frames), float(k1))
    if not ((world @ r.T + tvec.ravel())[:, 2].min() > 0
            and (cam.position_in_world - world.mean(axis=0)) @ np.asarray(facing, float) > 0):
        raise GalileoError(f"the fitted camera sees {what} from behind: check the points' order")
    return cam


def _percent(x: float) -> str:
    return "more than 1000%" if not x < 10 else f"{100 * x:.0f}%"


def rms_px(residuals_px: np.ndarray) -> float:
    """The RMS length of (N, 2) pixel residuals (or of N distances)."""
    r = np.asarray(residuals_px, float).reshape(len(residuals_px), -1)
    return float(np.sqrt(np.mean(np.sum(r ** 2, axis=1))))


# -- drawing ----------------------------------------------------------------------------------

def line_width(img: np.ndarray) -> int:
    return max(1, round(max(img.shape[:2]) / 400))


def draw_lines(img: np.ndarray, cam, points_in_world, color, closed: bool = True) -> None:
    """The world points joined in order, projected by `cam` into `img` (in place); nothing
    where one of them is behind the camera."""
    import cv2

    p = np.asarray(points_in_world, float)
    depth = (p @ cam.world_to_camera[:3, :3].T + cam.world_to_camera[:3, 3])[:, 2]
    if (depth <= 1e-3).any():
        return
    uv = np.round(cam.project(p) * 16).astype(np.int32)   # 4 bits of sub-pixel precision
    cv2.polylines(img, [uv.reshape(-1, 1, 2)], closed, color, line_width(img), cv2.LINE_AA, shift=4)


def draw_clicks(img: np.ndarray, clicks) -> None:
    """The clicks as red circles numbered from 1 (in place)."""
    import cv2

    lw = line_width(img)
    pts = np.asarray(clicks, float).reshape(-1, 2)
    for i, (u, v) in enumerate(pts):
        c = (int(round(u)), int(round(v)))
        cv2.circle(img, c, 3 * lw + 2, CLICK_RGB, lw, cv2.LINE_AA)
        cv2.putText(img, str(i + 1), (c[0] + 4 * lw, c[1] - 4 * lw), cv2.FONT_HERSHEY_SIMPLEX, 0.4 * lw, CLICK_RGB,
                    lw, cv2.LINE_AA)


# -- the frames the solvers look in -----------------------------------------------------------------

def sample_frames(frames, max_frames: int = SAMPLE_MAX_FRAMES, max_side_px: int = SAMPLE_MAX_SIDE_PX,
                  first: int = SAMPLE_FIRST) -> tuple[np.ndarray | None, int, tuple[int, int] | None]:
    """(frames kept, frames seen, (width, height) of a frame) from an iterable of RGB frames,
    in one pass: at most `max_frames` frames (and at least `first`): the video's first `first`
    frames, and frames evenly spaced over the whole (the spacing doubling as the video turns
    out longer), in the video's order, each shrunk (area averaging) to at most `max_side_px`
    on its long side. `max_frames` 0 keeps none (counting only). Memory: at most
    2 max_frames + first shrunk frames at a time."""
    import cv2

    head: list[np.ndarray] = []                    # frames 0 .. first - 1
    kept: list[np.ndarray] = []                    # frames 0, stride, 2 stride, ...
    index: list[int] = []
    stride, n, size, scale = 1, 0, None, 1.0
    for frame in frames:
        if size is None:
            size = (int(frame.shape[1]), int(frame.shape[0]))
            scale = min(1.0, max_side_px / max(size))
        if max_frames and (n < first or n % stride == 0):
            f = np.ascontiguousarray(frame[..., :3])
            if scale < 1.0:
                f = cv2.resize(f, (max(1, round(size[0] * scale)), max(1, round(size[1] * scale))),
                               interpolation=cv2.INTER_AREA)
            if n < first:
                head.append(f)
            if n % stride == 0:
                kept.append(f)
                index.append(n)
                if len(kept) >= 2 * max_frames:     # every other one: the spacing doubles
                    kept, index, stride = kept[::2], index[::2], stride * 2
        n += 1
    if not kept:
        return None, n, size
    room = max(max_frames - len(head), 1)           # the evenly spaced ones (frame 0 among them)
    picks = np.unique(np.linspace(0, len(kept) - 1, room).round().astype(int)) if len(kept) > room else \
        range(len(kept))
    chosen = dict(enumerate(head))                  # frame index -> frame
    for j in picks:
        chosen.setdefault(index[j], kept[j])
    return np.stack([chosen[i] for i in sorted(chosen)]), n, size


def sample_video(path, name: str | None = None):
    """(VideoInfo, first frame (full size, RGB), `sample_frames`' frames) of a video file, in
    one pass over it; a GalileoError naming it (as `name`, e.g. as uploaded) if it does not
    decode."""
    from .video import VideoInfo, _stream_info, read_frames

    name = name or str(path)
    try:
        fps = _stream_info(path)[0]
        first: list[np.ndarray] = []

        def frames():
            for f in read_frames(path):
                if not first:
                    first.append(f[..., :3])
                yield f

        kept, n, size = sample_frames(frames())
    except GalileoError as e:
        raise GalileoError(str(e).replace(str(path), name)) from None
    if not n:
        raise GalileoError(f"video {name} has no decodable frames")
    return VideoInfo(size[0], size[1], float(fps), n), first[0], kept


# -- the command line: every calibration's numbers as flags of `galileo scene` --------------------------

def add_flags(parser) -> None:
    """A flag per field of every scenario's calibration (type str: each is checked against the
    chosen scenario's field), grouped by scenario; a flag two scenarios share is listed under
    the first."""
    seen: set[str] = set()
    for name, cal in calibrations().items():
        own = [f for f in cal.fields if f.flag not in seen]
        shared = [f.flag for f in cal.fields if f.flag in seen]
        g = parser.add_argument_group(f"--scenario {name} ({cal.subject}); points: {cal.order}",
                                      f"also {', '.join(shared)}" if shared else None)
        for f in own:
            seen.add(f.flag)
            meta = "|".join(f.choices) if f.choices else "X,Y,Z" if f.size == 3 else f.unit.upper() or "VALUE"
            default = "" if f.default is None or f.required else f" (default: {f.text(f.default)})"
            g.add_argument(f.flag, dest=f.name, metavar=meta, default=None,
                           help=f"{f.help}{' (needed)' if f.required else default}".replace("%", "%%"))
