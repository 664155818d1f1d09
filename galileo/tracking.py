"""Tracking: pixels -> observations (Galileo section 3.1, splash abstract's bottom-up model).

Pipeline, for a video and a scene file whose camera describes it:

1. Background model: OpenCV MOG2 with five mixture components, learned from the video
   itself. Backwards over the last third at half resolution, it gives the scene as it
   ends: at frame 0 that shows every object that later leaves its start (a forward model
   cannot, it starts from frame 0). Forwards over all frames at quarter resolution, it
   gives the scene as it starts, against which the last frame shows whether anything moved.
2. Detection and roles: the ramp object is the uphill-most foreground component at frame 0
   within the band of start positions its offset prior allows (the frame-0 foreground also
   holds "ghosts" where objects come to rest later); the target is where the scene file
   puts it, with the size it states.
3. Bottom-up recognition: from the frame-0 silhouette, the shape type from the object's
   appearance (a small CNN, `galileo.shapenet`; side views of boxes and cylinders have the
   same silhouette) and per-axis size in metres and the ramp object's offset in units from
   fitting the projected 3-D shape to the silhouette. These fix those latents during MCMC.
4. KLT per object: good features inside the object's silhouette, pyramidal Lucas-Kanade
   started from a constant-velocity prediction, a forward-backward check, re-seeding
   inside the object's predicted silhouette (away from the other object) when fewer than
   half the features survive, and re-acquisition among moving pixels when it is lost.
5. Pose per frame: every feature is ray-cast at seeding into the estimated 3-D shape; the
   planar pose (centre in the fall-line plane and rotation about y) minimises the
   reprojection error of those points (Gauss-Newton with iterative outlier rejection:
   features that slid onto the other object or the background drop out). This is robust
   to lost and wrong features, to perspective and to the object tipping at the ramp's
   foot, where a median of displacements is not.
6. Positions in metres (world frame), velocities by central differences (one-sided at the
   ends of a visible run), no smoothing. Frames where an object is not seen are marked
   `visible: false` with null position and velocity, never invented.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import trimesh
from tqdm import tqdm

from .errors import GalileoError
from .jsonio import read_json, write_json
from .camera import Camera, backproject_to_plane
from .datatypes import ObjectTrack, Tracks
from .scenarios.ramp.scene import Scene
from .shapes import Shape
from .video import read_video_yuv, yuv_to_rgb

MOG_SCALE = 0.5
MIN_BLOB_PX = 60           # at full resolution
FB_MAX_PX = 0.7            # forward-backward error allowed
MAX_FEATURES = 48
MIN_INLIERS = 4
INLIER_PX = 1.0            # reprojection residual that always keeps a feature in the pose fit


# -- background subtraction ---------------------------------------------------------------

def _mog2_background(frames: np.ndarray, reverse: bool) -> np.ndarray:
    """Background image of a MOG2 model (five components) learned over the frames,
    forwards or backwards in time."""
    mog = cv2.createBackgroundSubtractorMOG2(history=max(len(frames), 2), varThreshold=16, detectShadows=False)
    mog.setNMixtures(5)
    for i in (range(len(frames) - 1, -1, -1) if reverse else range(len(frames))):
        mog.apply(frames[i])
    return mog.getBackgroundImage()


def _foreground(frame_small: np.ndarray, background_small: np.ndarray, noise_sd: float) -> np.ndarray:
    """Pixels that differ from the background by more than the noise allows (any channel)."""
    d = np.abs(frame_small.astype(np.int16) - background_small.astype(np.int16)).max(axis=2)
    return (d > max(12.0, 5.0 * noise_sd)).astype(np.uint8) * 255


def _noise_sd(frames_small: np.ndarray) -> float:
    """Sensor noise estimate: robust spread of frame-to-frame differences, per channel."""
    if len(frames_small) < 2:
        return 2.0
    d = frames_small[1].astype(np.float32) - frames_small[0].astype(np.float32)
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / math.sqrt(2) + 0.5)


def _clean(mask: np.ndarray) -> np.ndarray:
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
    m = cv2.morphologyEx(mask, cv2.MORPH_OPEN, k)
    return cv2.morphologyEx(m, cv2.MORPH_CLOSE, k, iterations=2)


def _full_res(mask_small: np.ndarray, full_shape: tuple[int, int]) -> np.ndarray:
    m = cv2.resize(_clean(mask_small), (full_shape[1], full_shape[0]), interpolation=cv2.INTER_NEAREST)
    return m > 0


# -- bottom-up recognition ------------------------------------------------------------------

@dataclass
class _Frame0:
    """An object's silhouette at frame 0, measured in its support frame."""
    mask: np.ndarray
    shape: Shape
    center_xz: np.ndarray     # object centre (world x, z)
    phi0: float               # orientation of the object x axis in the x-z plane
    s_along_m: float | None   # ramp object: distance of its centre up the ramp


def _support_frame(scene: Scene, role: str) -> tuple[np.ndarray, np.ndarray, float]:
    """Unit vectors (x-z) along the support surface (downhill) and its normal, and phi."""
    if role == "ramp":
        a = scene.ramp.angle_rad
        return np.array([math.cos(a), -math.sin(a)]), np.array([math.sin(a), math.cos(a)]), -a
    return np.array([1.0, 0.0]), np.array([0.0, 1.0]), 0.0


CROP_HW = (32, 64)


def support_direction_px(scene: Scene, role: str, at_world: np.ndarray) -> float:
    """Angle (radians, image frame) of the support surface's downhill direction at a point."""
    along, _, _ = _support_frame(scene, role)
    p0 = np.asarray(at_world, float)
    p1 = p0 + 0.05 * np.array([along[0], 0.0, along[1]])
    uv = scene.camera.project(np.stack([p0, p1]))
    d = uv[1] - uv[0]
    return math.atan2(d[1], d[0])


def shape_crop(rgb: np.ndarray, mask: np.ndarray, scene: Scene, role: str) -> np.ndarray:
    """The object's appearance normalised for the shape classifier: (2, 32, 64) float32.

    The frame is rotated about the silhouette's centre so the support surface runs
    horizontally, cropped to the silhouette's box (3 px margin) and resized; channel 0 is
    grey level standardised inside the silhouette, channel 1 the silhouette.
    """
    ys, xs = np.nonzero(mask)
    cx, cy = float(xs.mean()), float(ys.mean())
    centre_w = backproject_to_plane(scene.camera, np.array([[cx, cy]]), 0.0)[0]
    ang = math.degrees(support_direction_px(scene, role, centre_w))
    rot = cv2.getRotationMatrix2D((cx, cy), ang, 1.0)
    h, w = mask.shape
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
    g = cv2.warpAffine(gray, rot, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    m = cv2.warpAffine(mask.astype(np.float32), rot, (w, h), flags=cv2.INTER_LINEAR)
    ys, xs = np.nonzero(m > 0.5)
    pad = 3
    x0, x1 = max(xs.min() - pad, 0), min(xs.max() + pad + 1, w)
    y0, y1 = max(ys.min() - pad, 0), min(ys.max() + pad + 1, h)
    g = cv2.resize(g[y0:y1, x0:x1], CROP_HW[::-1], interpolation=cv2.INTER_AREA)
    m = cv2.resize(m[y0:y1, x0:x1], CROP_HW[::-1], interpolation=cv2.INTER_AREA)
    inside = g[m > 0.5]
    mu, sd = (float(inside.mean()), float(inside.std()) + 1.0) if inside.size else (float(g.mean()), 1.0)
    return np.stack([(g - mu) / sd, m]).astype(np.float32)


def classify_shape(scene: Scene, role: str, mask: np.ndarray, rgb: np.ndarray, length_m: float,
                   height_m: float) -> str:
    """box / cylinder / torus from the object's appearance (`galileo.shapenet`); "" without
    its weights (the caller then takes the shape whose projected silhouette fits best)."""
    from . import shapenet

    if shapenet.available():
        crop = shape_crop(rgb, mask, scene, role)
        return shapenet.predict(crop, shapenet.scalars_of(max(length_m, 1e-3), max(height_m, 1e-3)))[0]
    return ""


def _outline_points(shape: Shape) -> np.ndarray:
    """Points on the shape's surface whose projected convex hull is its silhouette."""
    sx, sy, sz = shape.size_m
    if shape.type == "box":
        return np.array([[x, y, z] for x in (-sx / 2, sx / 2) for y in (-sy / 2, sy / 2) for z in (-sz / 2, sz / 2)])
    t = np.linspace(0, 2 * math.pi, 24, endpoint=False)
    if shape.type == "cylinder":
        r = sy / 2
        ring = np.c_[np.zeros_like(t), r * np.cos(t), r * np.sin(t)]
        return np.concatenate([ring + [-sx / 2, 0, 0], ring + [sx / 2, 0, 0]])
    big_r, r = (sx - sz) / 2, sz / 2
    a, b = np.meshgrid(t, t[::2], indexing="ij")
    rho = big_r + r * np.cos(b)
    return np.stack([rho * np.cos(a), rho * np.sin(a), r * np.sin(b)], -1).reshape(-1, 3)


def _shape_of(kind: str, length: float, depth: float, height: float) -> Shape:
    if kind == "cylinder":
        return Shape("cylinder", (length, height, height))
    if kind == "torus":
        return Shape("torus", (length, length, min(height, 0.45 * length)))
    return Shape("box", (length, depth, height))


def _pose_on_support(scene: Scene, role: str, along_m: float, height_m: float):
    """Centre (world) and rotation of an object resting on its support, `along_m` along it."""
    if role == "ramp":
        r = scene.ramp
        a = r.angle_rad
        rot = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
        return -along_m * r.downhill + (height_m / 2) * r.normal, rot
    return np.array([along_m, 0.0, height_m / 2]), np.eye(3)


def _silhouette(scene: Scene, role: str, shape: Shape, along_m: float, roi) -> np.ndarray:
    x0, y0, w, h = roi
    centre, rot = _pose_on_support(scene, role, along_m, shape.height_m)
    uv = scene.camera.project(_outline_points(shape) @ rot.T + centre) - [x0, y0]
    m = np.zeros((h, w), np.uint8)
    if np.all(np.isfinite(uv)):
        cv2.fillConvexPoly(m, np.round(cv2.convexHull(uv.astype(np.float32))).astype(np.int32).reshape(-1, 2), 1)
    return m


def _fit_silhouette(scene: Scene, role: str, mask: np.ndarray, kind: str, init: tuple[float, float, float, float]):
    """Least 1 - IoU between the observed silhouette and the projected 3-D shape.

    Unknowns: position along the support, and sizes (length, depth, height); the depth is
    seen through perspective (the end face of an object off the camera axis).
    """
    from scipy.optimize import minimize

    ys, xs = np.nonzero(mask)
    pad = 30
    x0, y0 = max(xs.min() - pad, 0), max(ys.min() - pad, 0)
    x1, y1 = min(xs.max() + pad, mask.shape[1]), min(ys.max() + pad, mask.shape[0])
    roi = (int(x0), int(y0), int(x1 - x0), int(y1 - y0))
    obs = mask[y0:y1, x0:x1].astype(bool)

    def shape_of(p):
        length, depth, height = np.exp(p[1:4])
        return _shape_of(kind, length, depth, height)

    def loss(p):
        sil = _silhouette(scene, role, shape_of(p), p[0], roi).astype(bool)
        inter = np.logical_and(sil, obs).sum()
        return 1.0 - inter / max(np.logical_or(sil, obs).sum(), 1)

    p0 = np.array([init[0], *np.log(init[1:])])
    res = minimize(loss, p0, method="Nelder-Mead",
                   options={"xatol": 1e-4, "fatol": 1e-4, "maxiter": 400})
    return float(res.x[0]), shape_of(res.x), float(res.fun)


def _measure(scene: Scene, role: str, mask: np.ndarray, rgb: np.ndarray) -> _Frame0:
    cam = scene.camera
    along, normal, phi0 = _support_frame(scene, role)
    ys, xs = np.nonzero(mask)
    w = backproject_to_plane(cam, np.c_[xs, ys].astype(float), 0.0)[:, [0, 2]]
    a, n = w @ along, w @ normal
    length, height = float(np.ptp(a)), float(max(n.max(), 1e-3))
    mid = float((a.max() + a.min()) / 2)
    along0 = -mid if role == "ramp" else mid
    init = (along0, max(length, 0.005), max(math.sqrt(length * height), 0.005), max(height, 0.005))
    kind = classify_shape(scene, role, mask, rgb, length, height)
    if kind:
        along_m, shape, _ = _fit_silhouette(scene, role, mask, kind, init)
    else:
        fits = {k: _fit_silhouette(scene, role, mask, k, init) for k in ("box", "cylinder", "torus")}
        along_m, shape, _ = min(fits.values(), key=lambda f: f[2])
    centre, _ = _pose_on_support(scene, role, along_m, shape.height_m)
    return _Frame0(mask, shape, centre[[0, 2]], phi0, along_m if role == "ramp" else None)


def _scene_mask(scene: Scene, index: int) -> np.ndarray:
    """Silhouette of object `index` where the scene file puts it (its box hull)."""
    cam = scene.camera
    obj = scene.objects[index]
    pos, orn = scene.initial_pose(index)
    sx, sy, sz = obj.shape.size_m
    corners = np.array([[x, y, z] for x in (-sx / 2, sx / 2) for y in (-sy / 2, sy / 2) for z in (-sz / 2, sz / 2)])
    q = orn
    # rotation about y by the ramp angle (the only rotation initial poses use)
    ang = 2 * math.atan2(q[1], q[3])
    c, s = math.cos(ang), math.sin(ang)
    r = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    uv = cam.project(corners @ r.T + pos)
    hull = cv2.convexHull(uv.astype(np.float32))
    mask = np.zeros((cam.height_px, cam.width_px), np.uint8)
    cv2.fillConvexPoly(mask, np.round(hull).astype(np.int32).reshape(-1, 2), 1)
    return mask > 0


def _ramp_band_mask(scene: Scene, lo_m: float, hi_m: float, height_m: float) -> np.ndarray:
    """Image region above the ramp surface between lo_m and hi_m up the ramp."""
    cam, r = scene.camera, scene.ramp
    pts = []
    for s, h in ((lo_m, 0.002), (hi_m, 0.002), (hi_m, height_m), (lo_m, height_m)):
        p = -s * r.downhill + h * r.normal
        pts.append(cam.project(p))
    mask = np.zeros((cam.height_px, cam.width_px), np.uint8)
    cv2.fillConvexPoly(mask, np.round(np.array(pts)).astype(np.int32), 1)
    return mask > 0


def _largest_component(mask: np.ndarray) -> np.ndarray | None:
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if n <= 1:
        return None
    best = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    if stats[best, cv2.CC_STAT_AREA] < MIN_BLOB_PX:
        return None
    ys, xs = np.nonzero(labels == best)
    out = np.zeros(mask.shape, np.uint8)
    cv2.fillConvexPoly(out, cv2.convexHull(np.c_[xs, ys].astype(np.int32)), 1)
    return out > 0


def _uphill_component(scene: Scene, mask: np.ndarray) -> np.ndarray | None:
    """The foreground component furthest up the ramp, as a convex silhouette.

    A slow object's resting place can lie inside its band of start positions; its ghost
    there is always downhill of where it started, since objects only slide down.
    """
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    big = [i for i in range(1, n) if stats[i, cv2.CC_STAT_AREA] >= MIN_BLOB_PX]
    if not big:
        return None
    biggest = max(stats[i, cv2.CC_STAT_AREA] for i in big)
    big = [i for i in big if stats[i, cv2.CC_STAT_AREA] >= 0.25 * biggest]

    def up_the_ramp(i):
        ys, xs = np.nonzero(labels == i)
        w = backproject_to_plane(scene.camera, np.c_[xs.mean(), ys.mean()], 0.0)[0]
        return -float(w[[0, 2]] @ _support_frame(scene, "ramp")[0])

    best = max(big, key=up_the_ramp)
    return _largest_component(labels == best)


def _detect_start(scene: Scene, fg0: np.ndarray) -> dict[str, tuple[np.ndarray, str]]:
    """Frame-0 silhouettes by role.

    The ramp object is searched in the band of start positions its offset prior allows:
    the foreground at frame 0 (against the background the video ends with) also holds
    "ghosts" where objects come to rest later, and these lie elsewhere. The target is
    where the scene file puts it, with the size it states (its silhouette would merge
    with the ghost of a ramp object that stops against it).
    """
    found: dict[str, tuple[np.ndarray, str]] = {}
    pri, unit = scene.priors, scene.unit_m
    lo = (scene.start_units + pri.offset_units[0]) * unit - pri.size_m[1] / 2
    hi = (scene.start_units + pri.offset_units[1]) * unit + pri.size_m[1] / 2
    band = _ramp_band_mask(scene, max(lo, 0.0), min(hi, scene.ramp.length_m), pri.size_m[1])
    blob = _uphill_component(scene, fg0 & band)
    found["ramp"] = (blob, "motion") if blob is not None else (_scene_mask(scene, 0), "scene")
    if scene.target is not None:
        # the scene file states the target's kind, size and place: take them
        found["target"] = (_scene_mask(scene, 1), "scene")
    return found


# -- KLT ------------------------------------------------------------------------------------

_LK = dict(maxLevel=3, criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03))


def klt_window(mask: np.ndarray) -> int:
    """KLT window (odd, 5-9 px) that fits inside the silhouette's thickness.

    A window reaching over the object's edge tracks the background behind it too; on a
    thin object (a pole 9 px tall) that makes features stick and the track lag.
    """
    pts = np.c_[np.nonzero(mask)[::-1]].astype(np.float32)
    if len(pts) < 3:
        return 5
    (_, _), (w, h), _ = cv2.minAreaRect(pts)
    win = int(min(9, max(5, min(w, h) - 3)))
    return win if win % 2 else win - 1


def _seed(gray: np.ndarray, mask: np.ndarray, n: int, win: int = 9) -> np.ndarray:
    """Good features to track inside the mask; a grid of points where corners are too few."""
    # keep the KLT window on the object: seed at least win/2 inside its outline
    m = cv2.erode(mask.astype(np.uint8) * 255, np.ones((win, win), np.uint8))
    if cv2.countNonZero(m) < 20:
        m = cv2.erode(mask.astype(np.uint8) * 255, np.ones((3, 3), np.uint8))
    p = cv2.goodFeaturesToTrack(gray, maxCorners=n, qualityLevel=0.005, minDistance=3, mask=m, blockSize=3)
    p = np.zeros((0, 2), np.float32) if p is None else p.reshape(-1, 2)
    if len(p) < 8:
        ys, xs = np.nonzero(m[::2, ::2])
        grid = np.c_[xs * 2, ys * 2].astype(np.float32)
        if len(grid):
            step = max(1, len(grid) // max(n - len(p), 1))
            p = np.concatenate([p, grid[::step]])[:n]
    return p.astype(np.float32)


def _rot_y(psi: float) -> np.ndarray:
    """Rotation about the world y axis (the object's x axis goes to (cos, 0, -sin))."""
    c, s = math.cos(psi), math.sin(psi)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


@functools.lru_cache(maxsize=64)
def _coarse_triangles(shape: Shape) -> np.ndarray:
    """(T, 3, 3) triangles of a coarse mesh of the shape (object frame), for ray casting."""
    sx, sy, sz = shape.size_m
    if shape.type == "box":
        m = trimesh.creation.box(extents=(sx, sy, sz))
    elif shape.type == "cylinder":
        m = trimesh.creation.cylinder(radius=sy / 2, height=sx, sections=32)
        m.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, (0, 1, 0)))
    else:
        m = trimesh.creation.torus(major_radius=(sx - sz) / 2, minor_radius=sz / 2, major_sections=32,
                                   minor_sections=12)
    return np.asarray(m.triangles)


def ray_cast(shape: Shape, origin_obj: np.ndarray, dirs_obj: np.ndarray) -> np.ndarray:
    """First hit (object frame) of each ray with the shape, NaN where it misses (Moller-Trumbore)."""
    tri = _coarse_triangles(shape)
    v0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    d = dirs_obj[:, None, :]                                  # (R, 1, 3)
    pvec = np.cross(d, e2[None])                              # (R, T, 3)
    det = np.einsum("rtk,tk->rt", pvec, e1)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    tvec = origin_obj[None, :] - v0                           # (T, 3)
    u = np.einsum("rtk,tk->rt", pvec, tvec) * inv
    qvec = np.cross(tvec[None], e1[None])                     # (1, T, 3)
    v = np.einsum("rk,tk->rt", dirs_obj, qvec[0]) * inv
    t = np.einsum("tk,tk->t", e2, qvec[0])[None] * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9)
    t = np.where(hit, t, np.inf)
    best = t.min(axis=1)
    out = origin_obj[None] + best[:, None] * dirs_obj
    out[~np.isfinite(best)] = np.nan
    return out


class _ObjectTracker:
    """One object's KLT features, their 3-D points on the object, and its planar pose.

    Pose: centre (x, z) in the fall-line plane y = 0 and rotation psi about y. Each feature
    is a point on the object's estimated 3-D shape (found by casting the pixel's ray into
    the shape at the pose when the feature was seeded); the pose per frame minimises the
    features' reprojection error (Gauss-Newton, iterative outlier rejection). Features on
    the front, top and end faces thus each move by their own perspective.
    """

    def __init__(self, name: str, role: str, f0: _Frame0, cam: Camera, n_frames: int, detected_by: str):
        self.name, self.role, self.f0, self.cam, self.detected_by = name, role, f0, cam, detected_by
        self.shape = f0.shape
        self.pts = np.zeros((0, 2), np.float32)    # current image positions
        self.obj = np.zeros((0, 3))                 # the features' points in the object frame, metres
        self.pose = np.array([f0.center_xz[0], f0.center_xz[1], -f0.phi0])   # x, z, psi
        self.center = np.full((n_frames, 2), np.nan)
        self.visible = np.zeros(n_frames, bool)
        self.features: list[np.ndarray] = [np.zeros((0, 2))] * n_frames
        self.n_seeded = 0
        self.lost = False
        self.velocity = np.zeros(3)                 # pose change per frame, for prediction
        self.win = klt_window(f0.mask)
        r, t = cam.world_to_camera[:3, :3], cam.world_to_camera[:3, 3]
        self._eye = -r.T @ t
        self._kinv_rt = np.linalg.inv(cam.K).T @ r   # pixel (homogeneous) -> world direction
        self._hull = _coarse_triangles(self.shape).reshape(-1, 3)

    def to_world(self, p_obj: np.ndarray, pose: np.ndarray) -> np.ndarray:
        return p_obj @ _rot_y(pose[2]).T + np.array([pose[0], 0.0, pose[1]])

    def project(self, p_obj: np.ndarray, pose: np.ndarray) -> np.ndarray:
        return self.cam.project(self.to_world(p_obj, pose))

    def predicted_mask(self, pose: np.ndarray | None = None) -> np.ndarray:
        uv = self.project(self._hull, self.pose if pose is None else pose)
        mask = np.zeros((self.cam.height_px, self.cam.width_px), np.uint8)
        if np.all(np.isfinite(uv)):
            cv2.fillConvexPoly(mask, np.round(cv2.convexHull(uv.astype(np.float32))).astype(np.int32).reshape(-1, 2), 1)
        return mask > 0

    def _unproject(self, uv: np.ndarray) -> np.ndarray:
        """Object-frame points where the pixels' rays meet the shape at the current pose."""
        dirs_w = np.c_[uv, np.ones(len(uv))] @ self._kinv_rt
        rot = _rot_y(self.pose[2])
        c = np.array([self.pose[0], 0.0, self.pose[1]])
        return ray_cast(self.shape, (self._eye - c) @ rot, dirs_w @ rot)

    def add_features(self, gray: np.ndarray, mask: np.ndarray) -> None:
        want = MAX_FEATURES - len(self.pts)
        if want <= 0:
            return
        if len(self.pts):
            m = mask.astype(np.uint8)
            for x, y in np.round(self.pts).astype(int):
                cv2.circle(m, (int(x), int(y)), 3, 0, -1)
            mask = m > 0
        new = _seed(gray, mask, want, self.win)
        if len(new):
            p = self._unproject(new.astype(float))
            hit = np.all(np.isfinite(p), axis=1)
            self.pts = np.concatenate([self.pts, new[hit]]).astype(np.float32)
            self.obj = np.concatenate([self.obj, p[hit]])
            self.n_seeded = max(self.n_seeded, len(self.pts))

    def _solve(self, pose: np.ndarray, keep: np.ndarray) -> np.ndarray:
        steps = np.array([1e-4, 1e-4, 1e-3])
        obj, pts = self.obj[keep], self.pts[keep]
        for _ in range(6):
            r0 = (self.project(obj, pose) - pts).ravel()
            jac = np.empty((len(r0), 3))
            for k in range(3):
                dp = pose.copy()
                dp[k] += steps[k]
                jac[:, k] = ((self.project(obj, dp) - pts).ravel() - r0) / steps[k]
            delta = np.linalg.lstsq(jac, -r0, rcond=None)[0]
            pose = pose + delta
            if abs(delta[0]) + abs(delta[1]) < 1e-6 and abs(delta[2]) < 1e-5:
                break
        return pose

    def predict(self) -> np.ndarray:
        """The pose expected in the next frame (constant velocity)."""
        return self.pose + self.velocity

    def relocate(self, scene: Scene, blob: np.ndarray) -> None:
        """Find the object again after it was lost: its shape, resting on the ramp or the
        ground (whichever the blob is over), slid along that surface to fit the blob."""
        from scipy.optimize import minimize_scalar

        ys, xs = np.nonzero(blob)
        w = backproject_to_plane(self.cam, np.array([[xs.mean(), ys.mean()]]), 0.0)[0]
        role = "ramp" if w[0] < 0 else "target"
        along, _, phi = _support_frame(scene, role)
        a0 = float(w[[0, 2]] @ along) * (-1 if role == "ramp" else 1)
        pad = 20
        x0, y0 = max(xs.min() - pad, 0), max(ys.min() - pad, 0)
        x1, y1 = min(xs.max() + pad, blob.shape[1]), min(ys.max() + pad, blob.shape[0])
        roi = (int(x0), int(y0), int(x1 - x0), int(y1 - y0))
        obs = blob[y0:y1, x0:x1]

        def loss(a):
            sil = _silhouette(scene, role, self.shape, a, roi).astype(bool)
            return 1.0 - np.logical_and(sil, obs).sum() / max(np.logical_or(sil, obs).sum(), 1)

        a = minimize_scalar(loss, bounds=(a0 - 0.05, a0 + 0.05), method="bounded",
                            options={"xatol": 2e-4}).x
        centre, _ = _pose_on_support(scene, role, a, self.shape.height_m)
        self.pose = np.array([centre[0], centre[2], -phi])
        self.velocity = np.zeros(3)
        self.lost = False

    def fit(self, frame: int, start: np.ndarray | None = None) -> None:
        if len(self.pts) >= MIN_INLIERS:
            keep = np.ones(len(self.pts), bool)
            pose = (self.pose if start is None else start).copy()
            for _ in range(3):
                pose = self._solve(pose, keep)
                res = np.linalg.norm(self.project(self.obj, pose) - self.pts, axis=1)
                mad = float(np.median(res[keep]))
                new = res < max(INLIER_PX, 3.0 * 1.4826 * mad)
                if np.array_equal(new, keep) or new.sum() < MIN_INLIERS:
                    break
                keep = new
            if keep.sum() >= MIN_INLIERS:
                if frame > 0 and self.visible[frame - 1]:
                    self.velocity = pose - self.pose
                self.pose = pose
                self.pts, self.obj = self.pts[keep], self.obj[keep]
                self.center[frame] = pose[:2]
                self.visible[frame] = self._in_view()
                self.features[frame] = self.pts.copy()
                return
        self.lost = True
        if start is not None:  # coast on the prediction until re-acquired
            self.pose = start
        self.pts, self.obj = np.zeros((0, 2), np.float32), np.zeros((0, 3))

    def _in_view(self) -> bool:
        uv = self.project(np.zeros((1, 3)), self.pose)[0]
        return 0 <= uv[0] < self.cam.width_px and 0 <= uv[1] < self.cam.height_px


def _flow(prev: np.ndarray, cur: np.ndarray, pts: np.ndarray, guess: np.ndarray | None = None, win: int = 9):
    """KLT from a predicted position, with a forward-backward check; new points and kept mask."""
    if len(pts) == 0:
        return pts, np.zeros(0, bool)
    p0 = pts.reshape(-1, 1, 2).astype(np.float32)
    flags = 0
    p1 = None
    if guess is not None and np.all(np.isfinite(guess)):
        p1 = guess.reshape(-1, 1, 2).astype(np.float32)
        flags = cv2.OPTFLOW_USE_INITIAL_FLOW
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(prev, cur, p0, p1, winSize=(win, win), flags=flags, **_LK)
    # the check tracks back from scratch: started at p0 it would find p0 whatever p1 is
    back, st2, _ = cv2.calcOpticalFlowPyrLK(cur, prev, p1, None, winSize=(win, win), **_LK)
    fb = np.linalg.norm((back - p0).reshape(-1, 2), axis=1)
    ok = (st1.ravel() == 1) & (st2.ravel() == 1) & (fb < FB_MAX_PX)
    return p1.reshape(-1, 2), ok


JUMP_MPS = 0.1  # one-sided velocity estimates that disagree by more than this mark a jump


def velocity_from_positions(pos: np.ndarray, visible: np.ndarray, fps: float) -> np.ndarray:
    """Velocities from positions: central differences, except across a velocity jump.

    A collision or the landing at the ramp's foot changes velocity within one frame;
    a central difference there averages the velocities before and after. Where the
    velocities extrapolated to the frame from each side (leaving out the two adjacent
    intervals) disagree by more than max(JUMP_MPS, 6 x the noise), the jump is placed in
    the adjacent interval whose difference strays further from its own side's trend, and
    the frame takes the extrapolation from the other side. One-sided differences at
    the ends of visible runs; NaN where the object is not visible.
    """
    n = len(pos)
    vel = np.full_like(pos, np.nan)
    step = np.full_like(pos, np.nan)               # step[i]: velocity over (i-1, i)
    ok_step = np.zeros(n, bool)
    ok_step[1:] = visible[1:] & visible[:-1]
    step[1:][ok_step[1:]] = (pos[1:] - pos[:-1])[ok_step[1:]] * fps

    def s(i):
        return step[i] if 0 <= i < n and ok_step[i] else None

    # noise of the step velocities, from their second differences (robust to the jumps)
    good = ok_step[1:-1] & ok_step[2:] & ok_step[:-2]
    dd = (step[2:] - 2 * step[1:-1] + step[:-2])[good]
    noise = 1.4826 * float(np.median(np.linalg.norm(dd, axis=1))) / math.sqrt(6) if len(dd) else 0.0
    threshold = max(JUMP_MPS, 6.0 * noise)

    def extrapolate(a, b_, k):  # velocity at the frame from steps a (nearer) and b_ (further), k steps away
        return a + k * (a - b_)

    for i in range(n):
        if not visible[i]:
            continue
        b, f = s(i), s(i + 1)
        if b is None and f is None:
            vel[i] = 0.0
            continue
        if b is None or f is None:
            vel[i] = b if f is None else f
            continue
        bb, ff, bbb, fff = s(i - 1), s(i + 2), s(i - 2), s(i + 3)
        central = (b + f) / 2
        if bb is None or ff is None or bbb is None or fff is None:
            vel[i] = central
            continue
        # velocities at the frame from each side, leaving out the two adjacent intervals
        if np.linalg.norm(extrapolate(bb, bbb, 1.5) - extrapolate(ff, fff, 1.5)) <= threshold:
            vel[i] = central
            continue
        # the jump lies in the interval whose difference strays further from its own
        # side's trend (it mixes the velocities before and after); the frame takes the other side
        b_off = np.linalg.norm(b - extrapolate(bb, bbb, 1.0))
        f_off = np.linalg.norm(f - extrapolate(ff, fff, 1.0))
        vel[i] = extrapolate(b, bb, 0.5) if f_off > b_off else extrapolate(f, ff, 0.5)
    return vel


# -- the whole pipeline ------------------------------------------------------------------------

def track(video_path: str | Path, scene: Scene, *, progress: bool = True,
          debug_video: str | Path | None = None) -> Tracks:
    """Track the scene's objects in a video; see the module docstring for the method."""
    if scene.camera is None:
        raise GalileoError("the scene file has no camera: tracking needs one that describes the video")
    cam = scene.camera
    gray, chroma, info = read_video_yuv(video_path)
    if info.n_frames < 2:
        raise GalileoError(f"video {video_path} has only {info.n_frames} frame: need at least 2 to see motion")
    if (info.width_px, info.height_px) != (cam.width_px, cam.height_px):
        raise GalileoError(f"video {video_path} is {info.width_px}x{info.height_px} but the scene's camera is "
                           f"{cam.width_px}x{cam.height_px}")
    n = len(gray)
    fps = cam.fps
    bar = tqdm(total=3 * n, desc="tracking", unit="frame", disable=not progress)
    # half resolution Y, U, V for the background model (chroma is stored at half resolution)
    small = np.concatenate([np.stack([cv2.resize(g, None, fx=MOG_SCALE, fy=MOG_SCALE, interpolation=cv2.INTER_AREA)
                                      for g in gray])[..., None], chroma], axis=-1)
    first_rgb = yuv_to_rgb(gray[0], chroma[0])
    noise = _noise_sd(small)
    # the scene as it ends: learned from the last third only, so that a slow object's
    # start is clear of it even if it lingered there for much of the video
    tail = max(min(10, n), n // 3)
    bg_end = _mog2_background(small[n - tail:], reverse=True)
    bar.update(n)
    # the scene as it starts (forwards over all frames; quarter resolution is enough here)
    tiny = np.stack([cv2.resize(f, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA) for f in small])
    bg_start = _mog2_background(tiny, reverse=False)
    bar.update(n)
    full_hw = (gray.shape[2], gray.shape[1])
    fg0_small = _full_res(_foreground(small[0], bg_end, noise), gray.shape[1:])
    fg_last = _full_res(_foreground(tiny[-1], bg_start, noise), gray.shape[1:])
    if _largest_component(fg0_small) is None and _largest_component(fg_last) is None:
        bar.close()
        raise GalileoError(f"nothing moves in {video_path}: no foreground at the start or the end of the video")

    # frame-0 foreground at full resolution, within 2 px of the robust half-resolution one
    near = cv2.dilate(fg0_small.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    bg_full = cv2.resize(bg_end, full_hw, interpolation=cv2.INTER_LINEAR)
    first_yuv = np.concatenate([gray[0][..., None], cv2.resize(chroma[0], full_hw, interpolation=cv2.INTER_LINEAR)], -1)
    fg0 = near & (_clean(_foreground(first_yuv, bg_full, noise)) > 0)
    found = _detect_start(scene, fg0)

    trackers: list[_ObjectTracker] = []
    offsets: dict[str, int | None] = {}
    for i, obj in enumerate(scene.objects):
        mask, how = found[obj.role]
        if how == "scene":  # not seen apart from the background: where and what the scene file says
            pos, _ = scene.initial_pose(i)
            phi0 = _support_frame(scene, obj.role)[2]
            f0 = _Frame0(mask, obj.shape, pos[[0, 2]], phi0, scene.start_distance_m(obj) if obj.role == "ramp" else None)
        else:
            f0 = _measure(scene, obj.role, mask, first_rgb)
        tr = _ObjectTracker(obj.name, obj.role, f0, cam, n, how)
        tr.add_features(gray[0], mask)
        tr.fit(0)
        trackers.append(tr)
        if obj.role == "ramp":
            lo, hi = scene.priors.offset_units
            off = round(f0.s_along_m / scene.unit_m - scene.start_units)
            offsets[obj.name] = int(min(max(off, lo), hi))
    for f in range(1, n):
        preds = [t.predict() for t in trackers]
        masks: dict[int, np.ndarray] = {}

        def predicted(j):  # computed only when a tracker needs to look around
            if j not in masks:
                masks[j] = trackers[j].predicted_mask(preds[j])
            return masks[j]

        def others_of(k):
            out = np.zeros((cam.height_px, cam.width_px), bool)
            for j in range(len(trackers)):
                if j != k:
                    out |= cv2.dilate(predicted(j).astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
            return out

        moving = None
        # one KLT call per window size for all objects' features (each call builds pyramids)
        live = [k for k, t in enumerate(trackers) if not t.lost]
        for win in sorted({trackers[k].win for k in live}):
            group = [k for k in live if trackers[k].win == win]
            pts = np.concatenate([trackers[k].pts for k in group])
            guess = np.concatenate([trackers[k].project(trackers[k].obj, preds[k]) for k in group])
            new, ok = _flow(gray[f - 1], gray[f], pts, guess, win)
            start = 0
            for k in group:
                t = trackers[k]
                m = len(t.pts)
                t.pts, t.obj = new[start:start + m][ok[start:start + m]], t.obj[ok[start:start + m]]
                start += m
        for k, t in enumerate(trackers):
            if not t.lost:
                t.fit(f, preds[k])
            if t.lost:  # re-acquire it among the moving pixels near where it should be
                if moving is None:
                    # pixels that differ both from the scene's end and from its start
                    moving = _full_res(_foreground(small[f], bg_end, noise) & _foreground(small[f], small[0], noise),
                                       gray.shape[1:])
                near = cv2.dilate(predicted(k).astype(np.uint8), np.ones((31, 31), np.uint8)) > 0
                blob = _largest_component(moving & near & ~others_of(k))
                if blob is not None:
                    t.relocate(scene, blob)
                    t.add_features(gray[f], blob)
                    t.fit(f, t.pose)
            elif len(t.pts) < max(MIN_INLIERS * 2, t.n_seeded // 2):
                mask = cv2.erode(t.predicted_mask().astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
                t.add_features(gray[f], mask & ~others_of(k))
        bar.update()
    bar.close()

    objects = []
    for t in trackers:
        pos = np.full((n, 3), np.nan)
        vis = t.visible
        pos[vis, 0] = t.center[vis, 0]
        pos[vis, 1] = 0.0
        pos[vis, 2] = t.center[vis, 1]
        vel = velocity_from_positions(pos, vis, fps)
        centre_px = np.full((n, 2), np.nan)
        centre_px[vis] = cam.project(pos[vis])
        objects.append(ObjectTrack(t.name, t.role, pos, vel, vis.copy(), t.f0.shape, offsets.get(t.name),
                                   t.detected_by, centre_px, t.features))
    tracks = Tracks(fps, objects)
    if debug_video is not None:
        write_debug_video(debug_video, (yuv_to_rgb(g, c) for g, c in zip(gray, chroma)), tracks, fps)
    return tracks


def write_debug_video(path: str | Path, frames_rgb, tracks: Tracks, fps: float) -> None:
    """The video with each object's features, centre, trail and role drawn over it (H.264)."""
    from .video import write_video

    colors = {"ramp": (255, 80, 40), "target": (40, 160, 255)}
    out = []
    for f, frame in enumerate(frames_rgb):
        img = frame.copy()
        for o in tracks.objects:
            c = colors.get(o.role, (255, 255, 0))
            if o.features_px and f < len(o.features_px):
                for x, y in o.features_px[f]:
                    cv2.circle(img, (int(round(x)), int(round(y))), 2, c, -1)
            if o.center_px is not None:
                trail = o.center_px[: f + 1]
                trail = trail[~np.isnan(trail[:, 0])]
                if len(trail) > 1:
                    cv2.polylines(img, [np.round(trail).astype(np.int32)], False, c, 1)
                if o.visible[f]:
                    x, y = np.round(o.center_px[f]).astype(int)
                    cv2.drawMarker(img, (int(x), int(y)), c, cv2.MARKER_CROSS, 10, 2)
                    cv2.putText(img, o.role, (int(x) + 6, int(y) - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.4, c, 1)
        cv2.putText(img, f"frame {f}", (8, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1)
        out.append(img)
    write_video(path, out, fps)
