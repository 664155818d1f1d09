"""The camera of a video (OpenCV convention: x right, y down, z forward), shared by every
scenario: projection, back-projection, JSON, whether it sees a scene, and the physics rate its
frame rate steps evenly.

**Lens distortion.** A pinhole camera, optionally with one radial distortion coefficient k1
(OpenCV's model with k2 = p1 = p2 = k3 = 0): a point at normalised pinhole coordinates
(x_u, y_u) = K^-1 (u, v, 1) is seen at (x_u, y_u) (1 + k1 r_u^2), r_u^2 = x_u^2 + y_u^2.
k1 < 0 is barrel distortion (a phone's or webcam's wide lens: straight lines near the frame's
edges bow outwards), k1 > 0 pincushion. For k1 < 0 the polynomial turns back beyond
r_u^2 = -1 / (3 k1); there the factor is held at its value at that radius, so points far
outside the view stay outside the image instead of folding back into it (OpenCV folds them).
`check_camera` refuses a k1 whose model turns back (or nearly) inside the image. Every
conversion between pixels and the world goes through `Camera.project` (distorted pixels),
`Camera.pixel_rays` and `backproject_to_plane` (which undistort first); renders are pinhole
(`galileo.render`) and are remapped through `Camera.undistort_px` where a lens is wanted."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable

import numpy as np

from .errors import GalileoError, SceneError
from .fields import Bound, matrix, number, show, unknown_fields


@dataclass(frozen=True)
class Camera:
    """Pinhole camera, OpenCV convention (x right, y down, z forward), with radial lens
    distortion k1 (0: none; see the module)."""
    K: np.ndarray               # (3, 3) intrinsics in pixels
    world_to_camera: np.ndarray  # (4, 4) rigid transform
    width_px: int = 640
    height_px: int = 480
    fps: float = 30.0
    n_frames: int = 90
    k1: float = 0.0             # radial lens distortion (OpenCV's k1) on normalised coordinates

    def __eq__(self, other: object) -> bool:
        # the generated __eq__ compares the arrays with `==` and raises on their truth value
        if not isinstance(other, Camera):
            return NotImplemented
        return (np.array_equal(self.K, other.K) and np.array_equal(self.world_to_camera, other.world_to_camera)
                and (self.width_px, self.height_px, self.fps, self.n_frames, self.k1)
                == (other.width_px, other.height_px, other.fps, other.n_frames, other.k1))

    def project(self, pos_in_world: np.ndarray) -> np.ndarray:
        """World points (..., 3) -> pixel coordinates (..., 2), through the lens (`distort_px`)."""
        p = np.asarray(pos_in_world, float)
        pc = p @ self.world_to_camera[:3, :3].T + self.world_to_camera[:3, 3]
        uv = pc @ self.K.T
        return self.distort_px(uv[..., :2] / uv[..., 2:3])

    def _radius2(self, uv: np.ndarray) -> np.ndarray:
        """Squared radius (...) of pixels (..., 2) in normalised coordinates (K^-1, skew included)."""
        (fx, s, cx), (_, fy, cy), _ = self.K
        y = (uv[..., 1] - cy) / fy
        x = (uv[..., 0] - cx - s * y) / fx
        return x * x + y * y

    def _fold_r2(self) -> float:
        """The squared normalised radius beyond which the factor is held (see the module): where
        r (1 + k1 r^2) turns back for k1 < 0, infinite otherwise."""
        return -1.0 / (3.0 * self.k1) if self.k1 < 0 else math.inf

    def distort_px(self, uv_pinhole: np.ndarray) -> np.ndarray:
        """Pixels (..., 2) of a pinhole camera with this K -> where the lens puts them: scaled
        about the principal point by 1 + k1 r_u^2 (the same scaling of normalised coordinates,
        K being linear about it). The pixels themselves, unchanged, where k1 = 0."""
        uv = np.asarray(uv_pinhole, float)
        if self.k1 == 0.0:
            return uv
        c = self.K[:2, 2]
        r2 = np.minimum(self._radius2(uv), self._fold_r2())
        return c + (uv - c) * (1.0 + self.k1 * r2)[..., None]

    def undistort_px(self, uv: np.ndarray) -> np.ndarray:
        """The lens's pixels (..., 2) -> where a pinhole camera with this K sees them (the
        inverse of `distort_px`): the normalised radius r_u solving r_u (1 + k1 r_u^2) = r_d by
        Newton's method from r_u = r_d, which approaches the root from one side without
        overshooting (r (1 + k1 r^2) is concave for k1 < 0, convex for k1 > 0), to
        UNDISTORT_TOL. Unchanged where k1 = 0."""
        uv = np.asarray(uv, float)
        if self.k1 == 0.0:
            return uv
        k1, fold2 = self.k1, self._fold_r2()
        rd = np.sqrt(self._radius2(uv))
        # beyond the image of the fold the factor is held at its value there (1 + k1 fold2 = 2 / 3)
        held = rd >= math.sqrt(fold2) * (1.0 + k1 * fold2) if k1 < 0 else np.zeros(rd.shape, bool)
        ru = np.where(held, rd / (1.0 + k1 * fold2), rd)
        for _ in range(UNDISTORT_ITERATIONS):
            step = np.where(held, 0.0, (ru * (1.0 + k1 * ru * ru) - rd) / (1.0 + 3.0 * k1 * ru * ru))
            ru = ru - step
            if not np.abs(step).max(initial=0.0) > UNDISTORT_TOL:
                break
        c = self.K[:2, 2]
        scale = np.where(rd > 0, ru / np.where(rd > 0, rd, 1.0), 1.0)
        return c + (uv - c) * scale[..., None]

    def pixel_rays(self, uv: np.ndarray) -> np.ndarray:
        """Directions (N, 3), world frame, of the rays from the camera's centre
        (`position_in_world`) through pixels uv (N, 2), undistorted first: R^T K^-1 (u, v, 1),
        each with unit depth along the optical axis (not unit length)."""
        uv = self.undistort_px(np.asarray(uv, float).reshape(-1, 2))
        return np.c_[uv, np.ones(len(uv))] @ np.linalg.inv(self.K).T @ self.world_to_camera[:3, :3]

    @property
    def position_in_world(self) -> np.ndarray:
        r, t = self.world_to_camera[:3, :3], self.world_to_camera[:3, 3]
        return -r.T @ t

    def to_json(self) -> dict:
        """The scene file's `camera` object; "k1" only where there is distortion (files of
        pinhole cameras stay as they were)."""
        d = {"K": self.K.tolist(), "world_to_camera": self.world_to_camera.tolist(),
             "width_px": self.width_px, "height_px": self.height_px,
             "fps": self.fps, "n_frames": self.n_frames}
        if self.k1 != 0.0:
            d["k1"] = self.k1
        return d


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



def backproject_to_plane(cam: Camera, uv: np.ndarray, y_plane_m: float) -> np.ndarray:
    """Pixels (N, 2) -> world points (N, 3) on the plane y = y_plane_m (through the lens:
    `Camera.pixel_rays`)."""
    rays = cam.pixel_rays(uv)
    origin = cam.position_in_world
    s = (y_plane_m - origin[1]) / rays[:, 1]
    return origin + s[:, None] * rays



# -- what a camera may be: every bound in one place, each with its reason -----------------------

IMAGE_SIDE_PX = Bound(16, 16384, integer=True)   # width and height: 16 px (less shows no object to track) to
# 16384 px (about twice 8K video's width; the tracker holds whole frames in memory)
FPS = Bound(1.0, 1000.0)                        # frames a second: at least 1 (frames further apart show no motion
# to take a velocity from, and a frame would be up to sim_hz physics steps), at most 1000 (a high-speed camera;
# the physics rate is a multiple of it: physics_hz)
N_FRAMES = Bound(1, 100_000, integer=True)       # 100000 frames: 55 min at 30 fps (an experiment lasts seconds);
# the trajectories and tracks hold every frame in memory
FOCAL_PX = Bound(1.0, 1e5)                       # a focal length below 1 px sees more than 179 degrees (no
# pinhole camera); above 1e5 px a 640 px wide image sees 0.4 degrees (beyond any telephoto lens)
MAX_SKEW = 0.01                                  # |K[0][1]| at most this x fx: real cameras have square pixels
# (OpenCV calibrates skew 0); a little is tolerated for calibrations that fit it
PRINCIPAL_POINT_MARGIN = 0.5                     # the principal point lies in the image or at most half its
# width (height) outside it (a crop of a larger frame), never far beyond
ROTATION_TOL = 1e-6                              # R R^T = I and det R = +1 within this (what 7 printed digits keep)
CAMERA_DISTANCE_M = 1000.0                       # the camera at most 1 km from the world's origin: a tabletop
# experiment is filmed from metres away (from 1 km a 10 cm object is 10 px even at the longest focal length)
K1 = Bound(-1.0, 1.0)                            # radial distortion k1: phones and webcams calibrate to
# |k1| < 0.5 (OpenCV's samples: -0.2 to -0.4); beyond 1 the one-coefficient model is no lens (it turns back
# inside any usual field of view)
MIN_DISTORTION_SLOPE = 0.2                       # d r_d / d r_u at least this out to the image's corners: where
# the lens's radius stops growing with the ray's, a pixel holds ever more rays and undistortion's error grows
# as 1 / slope (0 is the fold, beyond which two rays share a pixel)
UNDISTORT_ITERATIONS = 50                        # Newton steps at most (a few reach UNDISTORT_TOL inside the image)
UNDISTORT_TOL = 1e-12                            # normalised radius: 1e-7 px at the largest focal length (FOCAL_PX)
CAMERA_FIELDS = ("K", "world_to_camera", "width_px", "height_px", "fps", "n_frames", "k1")


def _entry(bound: Bound, v: float, where: str, what: str) -> None:
    if not bound.contains(v):
        raise SceneError(f"{where}: {what} = {show(v)} is outside {bound}")


def check_camera(cam: Camera, path: str = "camera") -> None:
    """SceneError naming the field if `cam` is no proper pinhole camera: K an intrinsic matrix
    (fx, fy in FOCAL_PX, skew small, K[1][0] = 0, last row [0, 0, 1], principal point in or near
    the image), world_to_camera a rigid transform (R orthonormal with det +1, last row
    [0, 0, 0, 1], the camera within CAMERA_DISTANCE_M), image size, fps and n_frames in range,
    k1 in K1 with its model increasing (slope at least MIN_DISTORTION_SLOPE) out to the
    image's corners."""
    w = IMAGE_SIDE_PX.check(cam.width_px, f"{path}.width_px")
    h = IMAGE_SIDE_PX.check(cam.height_px, f"{path}.height_px")
    FPS.check(cam.fps, f"{path}.fps")
    N_FRAMES.check(cam.n_frames, f"{path}.n_frames")
    k = np.asarray(cam.K, dtype=float)
    if k.shape != (3, 3) or not np.all(np.isfinite(k)):
        raise SceneError(f"{path}.K: expected a 3x3 matrix of finite numbers")
    _entry(FOCAL_PX, k[0, 0], f"{path}.K", "fx = K[0][0]")
    _entry(FOCAL_PX, k[1, 1], f"{path}.K", "fy = K[1][1]")
    if abs(k[0, 1]) > MAX_SKEW * k[0, 0]:
        raise SceneError(f"{path}.K: the skew K[0][1] = {show(k[0, 1])} is outside [-{MAX_SKEW:g}, {MAX_SKEW:g}] x fx")
    if abs(k[1, 0]) > 1e-9 * k[1, 1] or np.abs(k[2] - (0.0, 0.0, 1.0)).max() > 1e-9:
        raise SceneError(f"{path}.K: expected an intrinsic matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]], "
                         f"got rows {show(k[1].tolist())} and {show(k[2].tolist())}")
    for i, (name, side) in enumerate((("cx", w), ("cy", h))):
        _entry(Bound(-PRINCIPAL_POINT_MARGIN * side, (1 + PRINCIPAL_POINT_MARGIN) * side), k[i, 2], f"{path}.K",
               f"the principal point's {name} = K[{i}][2]")
    m = np.asarray(cam.world_to_camera, dtype=float)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise SceneError(f"{path}.world_to_camera: expected a 4x4 matrix of finite numbers")
    if np.abs(m[3] - (0.0, 0.0, 0.0, 1.0)).max() > 1e-9:
        raise SceneError(f"{path}.world_to_camera: expected a rigid transform, its last row [0, 0, 0, 1], "
                         f"got {show(m[3].tolist())}")
    r = m[:3, :3]
    if np.abs(r @ r.T - np.eye(3)).max() > ROTATION_TOL:
        raise SceneError(f"{path}.world_to_camera: expected a rigid transform, its 3x3 rotation orthonormal "
                         f"(R R^T = I within {ROTATION_TOL:g})")
    det = float(np.linalg.det(r))
    if not abs(det - 1.0) <= ROTATION_TOL * 10:
        raise SceneError(f"{path}.world_to_camera: expected a rotation with determinant +1, got {det:.6g} "
                         f"(a mirror image)")
    dist = float(np.linalg.norm(r.T @ m[:3, 3]))
    if dist > CAMERA_DISTANCE_M:
        raise SceneError(f"{path}.world_to_camera: the camera is {dist:g} m from the world's origin, beyond "
                         f"{CAMERA_DISTANCE_M:g} m")
    check_distortion(cam, f"{path}.k1")


def check_distortion(cam: Camera, name: str = "camera.k1") -> None:
    """SceneError naming `name` (the field or flag that gave k1) unless k1 is in K1 and the lens's radius r_d = r_u (1 + k1
    r_u^2) grows with the ray's at a slope of at least MIN_DISTORTION_SLOPE out to the image's
    farthest corner: for k1 < 0 the slope 1 + 3 k1 r_u^2 falls to it at r_u^2 = (1 - slope) /
    (-3 k1), where r_d = r_u (2 + slope) / 3; the corner's r_d must be within that."""
    K1.check(cam.k1, name)
    if cam.k1 >= 0:
        return
    corners = np.array([[0.0, 0.0], [cam.width_px, 0.0], [0.0, cam.height_px], [cam.width_px, cam.height_px]])
    corner_rd = float(np.sqrt(cam._radius2(corners).max()))
    ru = math.sqrt((1.0 - MIN_DISTORTION_SLOPE) / (-3.0 * cam.k1))
    if corner_rd > ru * (2.0 + MIN_DISTORTION_SLOPE) / 3.0:
        raise SceneError(f"{name}: {show(cam.k1)} bends the image back on itself before its corners (the "
                         f"lens's radius must grow with the ray's out to the corners, here {corner_rd:.3g} focal "
                         f"lengths from the principal point; barrel distortion this strong is beyond the "
                         f"one-coefficient model): check its sign and that it is OpenCV's k1 for this K")


def camera_from_json(d: dict, path: str = "camera") -> Camera:
    """Parse and check a scene file's `camera` object (SceneError naming the field)."""
    p = path
    if not isinstance(d, dict):
        raise SceneError(f"{p}: expected an object, got {show(d)}")
    unknown_fields(d, CAMERA_FIELDS, p)
    k = matrix(d, "K", p, (3, 3))
    m = matrix(d, "world_to_camera", p, (4, 4))
    cam = Camera(k, m, number(d, "width_px", p, bound=IMAGE_SIDE_PX), number(d, "height_px", p, bound=IMAGE_SIDE_PX),
                 number(d, "fps", p, bound=FPS), number(d, "n_frames", p, bound=N_FRAMES),
                 number(d, "k1", p, 0.0, bound=K1))
    check_camera(cam, p)
    return cam


# -- the physics rate a video's frame rate steps evenly ---------------------------------------------
# Physics runs a whole number of steps per video frame everywhere (the simulation is sampled at
# frame f = step f x steps_per_frame), so the rate must be a multiple of the camera's fps. A
# scene asks for `sim_hz` (240 by default); a scene with a camera steps at physics_hz(sim_hz,
# fps), the multiple of fps nearest it: 240 Hz stays 240 at 30, 60 or 120 fps and becomes
# 250 Hz at 25 fps (PAL, 10 steps a frame), 239.76 Hz at 29.97 fps (NTSC, 8 steps) and
# 237.6 Hz at 29.7 fps (a phone clip of Physics 101). The rate moves by at most fps / 2 (steps
# 4% shorter at 25 fps), which Bullet's contacts take as they take 240 Hz. The scenes apply it
# where they are validated, so old scene files load as they did and a loaded scene's sim_hz is
# the rate it runs at (and is written back as such).

STEPS_EXACT = 1e-9   # sim_hz / fps within this of a whole number is a whole number of steps a frame


def steps_per_frame(sim_hz: float, fps: float) -> int:
    """Physics steps per video frame: sim_hz / fps, a whole number at the rate physics_hz gives."""
    return max(1, round(sim_hz / fps))


def physics_hz(sim_hz: float, fps: float, bound: Bound | None = None) -> float:
    """The physics rate for a video at `fps`: `sim_hz` itself when it is a multiple of fps,
    else the multiple of fps nearest it (inside `bound`, the scenario's sim_hz bound, where one
    of the two nearest is). See above."""
    ratio = sim_hz / fps
    if abs(ratio - round(ratio)) <= STEPS_EXACT:
        return sim_hz
    below = max(1, math.floor(ratio))
    for k in sorted((below, below + 1), key=lambda k: abs(k * fps - sim_hz)):
        if bound is None or bound.contains(k * fps):
            return k * fps
    return below * fps


def check_run(sim_hz: float, fps: float, n_frames: int, max_steps: int, start_step: int = 0,
              names: tuple[str, str] = ("camera.fps", "camera.n_frames")) -> None:
    """SceneError unless a video of `n_frames` at `fps` can be simulated at `sim_hz`: fps in
    FPS, n_frames in N_FRAMES, sim_hz a multiple of fps (a scene's own camera always is, at
    physics_hz; a run at another fps need not be), and at most `max_steps` physics steps in all
    (`start_step` of them before frame 0). `names` name fps and n_frames in messages (the scene
    file's fields, or a command's flags)."""
    fps_name, frames_name = names
    FPS.check(fps, fps_name)
    N_FRAMES.check(n_frames, frames_name)
    spf = sim_hz / fps
    if abs(spf - round(spf)) > STEPS_EXACT:
        raise SceneError(f"sim_hz ({sim_hz:g}) must be a multiple of {fps_name} ({fps:g})")
    steps = int(start_step + (n_frames - 1) * round(spf))
    if steps > max_steps:
        raise SceneError(f"{frames_name}: {n_frames} frames at {fps:g} fps are {steps} physics steps at "
                         f"sim_hz {sim_hz:g}, more than {max_steps} (shorten the video or lower sim_hz)")


# -- what the camera sees ----------------------------------------------------------------------

def check_sees(cam: Camera, parts: dict[str, np.ndarray]) -> None:
    """GalileoError, before any tracking, when the camera sees none of the scene: of no part
    (name -> world points (N, 3): the corners of the ramp's surface or of the tank, where the
    objects start) does the box around the image points of those in front of the camera overlap
    the image. Such a camera (an identity world_to_camera stands at the world's origin looking
    along +z, straight up) would track nothing and report every object unseen."""
    r, t = cam.world_to_camera[:3, :3], cam.world_to_camera[:3, 3]
    for pts in parts.values():
        pc = np.reshape(pts, (-1, 3)) @ r.T + t
        pc = pc[pc[:, 2] > 0]          # (behind the camera or level with it: nowhere in the image)
        if len(pc):
            uvw = pc @ cam.K.T
            uv = cam.distort_px(uvw[:, :2] / uvw[:, 2:])
            if (uv.max(axis=0) >= 0).all() and uv[:, 0].min() < cam.width_px and uv[:, 1].min() < cam.height_px:
                return
    pos, ahead = cam.position_in_world, r[2]
    raise GalileoError(f"the camera sees none of the scene ({', '.join(parts)}: all behind it or outside its "
                       f"{cam.width_px}x{cam.height_px} image; it stands at {_xyz(pos)} m looking along "
                       f"{_xyz(ahead)}): check camera.world_to_camera, the transform from world to camera "
                       "(x right, y down, z forward)")


def _xyz(v: np.ndarray) -> str:
    return "(" + ", ".join(f"{x:.2f}" for x in v) + ")"
