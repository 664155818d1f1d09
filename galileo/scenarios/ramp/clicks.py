"""A ramp scene from four points clicked on the video's first frame (`galileo scene`).

The user marks four points of the ramp board's top surface, in this order: upper near, upper
far, foot far, foot near ("near": the side edge closer to the camera). The foot points are the
foot's corners; the upper points lie on the two side edges `upper_at_m` up the ramp from the
foot (by default the ramp's length: its upper corners). With the ramp's length, width and
angle these four points are known in the world frame (the foot's centre at the origin, the
ramp rising towards -x, the camera on the -y side), so:

* without a focal length: the plane's homography gives it, from the two constraints that its
  first two columns, mapped back through K, are orthogonal and of equal length (principal
  point at the image centre, square pixels);
* the camera's pose: OpenCV's planar PnP (IPPE) with that K.

The reprojection error (pixels) says how well the clicks agree with the stated geometry.

Without a stated start (`--start-m`), `find_start_m` finds the ramp object in the first frame:
the per-pixel median of the video's last third is the scene without the object at its start
(it has slid away), and the object is where the first frame differs from that, over the ramp.
"""
from __future__ import annotations

import math

import numpy as np

from ...camera import Camera
from ...errors import GalileoError
from .scene import RAMP_SIZE_M

ORDER = ("upper near", "upper far", "foot far", "foot near")
MIN_SIDE_PX = 4.0          # two clicks closer than this are one point
MIN_AREA_PX2 = 100.0       # a quadrilateral thinner than this is a line, not a ramp
MIN_CORNER_SINE = 0.02     # a corner straighter than this (about 1 degree off a line) is no corner
MAX_REPROJECTION_PX = 25.0  # clicks farther than this from the stated geometry are refused


def ramp_points_in_world(length_m: float, width_m: float, angle_deg: float, upper_at_m: float | None = None) -> np.ndarray:
    """The four points (ORDER) of the ramp's top surface in the world frame, (4, 3) metres."""
    d = length_m if upper_at_m is None else upper_at_m
    a = math.radians(angle_deg)
    up = np.array([-math.cos(a), 0.0, math.sin(a)])      # up the ramp, along the surface
    near, far = np.array([0.0, -width_m / 2, 0.0]), np.array([0.0, width_m / 2, 0.0])
    return np.array([d * up + near, d * up + far, far, near])


def _cross(a, b) -> float:
    """The z component of the cross product of two image vectors."""
    return float(a[0] * b[1] - a[1] * b[0])


def check_clicks(uv: np.ndarray, width_px: int, height_px: int) -> np.ndarray:
    """The four clicks as a (4, 2) array, or a GalileoError saying what is wrong with them."""
    uv = np.asarray(uv, float)
    if uv.shape != (4, 2) or not np.isfinite(uv).all():
        raise GalileoError("give four points u,v (pixels): upper near, upper far, foot far, foot near")
    for name, (u, v) in zip(ORDER, uv):
        if not (0 <= u < width_px and 0 <= v < height_px):
            raise GalileoError(f"the {name} point ({u:g}, {v:g}) is outside the {width_px}x{height_px} frame")
    for i in range(4):
        for j in range(i + 1, 4):
            if np.linalg.norm(uv[i] - uv[j]) < MIN_SIDE_PX:
                raise GalileoError(f"the {ORDER[i]} and {ORDER[j]} points are the same point")
    # a convex quadrilateral in the stated order: every turn the same way, and its area not nil
    turns = [_cross(uv[(i + 1) % 4] - uv[i], uv[(i + 2) % 4] - uv[(i + 1) % 4]) for i in range(4)]
    area = 0.5 * abs(sum(_cross(uv[i], uv[(i + 1) % 4]) for i in range(4)))
    # |turn| / (the two sides' lengths) is the sine of the angle at a corner
    sines = [abs(t) / (np.linalg.norm(uv[(i + 1) % 4] - uv[i]) * np.linalg.norm(uv[(i + 2) % 4] - uv[(i + 1) % 4]))
             for i, t in enumerate(turns)]
    if min(sines) > MIN_CORNER_SINE and not (all(t > 0 for t in turns) or all(t < 0 for t in turns)):
        raise GalileoError("the four points cross over: give them in the order upper near, upper far, foot far, "
                           "foot near (going round the ramp's top surface)")
    if area < MIN_AREA_PX2 or min(sines) <= MIN_CORNER_SINE:
        raise GalileoError("three of the four points are on one line: click the ramp's four corners (or the "
                           "points on its side edges), in the order upper near, upper far, foot far, foot near")
    return uv


def focal_from_homography(h: np.ndarray, cx: float, cy: float) -> float:
    """The focal length (pixels) for which the plane homography `h` (plane coordinates along
    and across the ramp -> pixels) has orthogonal columns of equal length through K."""
    g = np.array([[1, 0, -cx], [0, 1, -cy], [0, 0, 1.0]]) @ h
    h1, h2 = g[:, 0], g[:, 1]
    # (h1x h2x + h1y h2y) w + h1z h2z = 0;  (|h1xy|^2 - |h2xy|^2) w + (h1z^2 - h2z^2) = 0;  w = 1/f^2
    a = np.array([h1[0] * h2[0] + h1[1] * h2[1], h1[0] ** 2 + h1[1] ** 2 - h2[0] ** 2 - h2[1] ** 2])
    b = np.array([h1[2] * h2[2], h1[2] ** 2 - h2[2] ** 2])
    w = -float(a @ b) / float(a @ a)
    if not w > 0 or abs(float(b @ b)) < 1e-12 * float(a @ a) * w * w:
        raise GalileoError("cannot estimate the focal length from these points (the ramp is seen face-on or the "
                           "points disagree with its size): give --focal-px")
    return 1.0 / math.sqrt(w)


def camera_from_clicks(uv, *, width_px: int, height_px: int, fps: float, n_frames: int, length_m: float,
                       width_m: float, angle_deg: float, upper_at_m: float | None = None,
                       focal_px: float | None = None) -> tuple[Camera, float]:
    """(camera, RMS reprojection error in pixels) from the four clicks (see the module)."""
    import cv2

    uv = check_clicks(uv, width_px, height_px)
    world = ramp_points_in_world(length_m, width_m, angle_deg, upper_at_m)
    cx, cy = width_px / 2, height_px / 2
    if focal_px is None:
        d = length_m if upper_at_m is None else upper_at_m
        plane = np.array([[d, -width_m / 2], [d, width_m / 2], [0, width_m / 2], [0, -width_m / 2]], float)
        h, _ = cv2.findHomography(plane, uv)
        if h is None:
            raise GalileoError("these four points give no perspective view of a rectangle: check their order")
        focal_px = focal_from_homography(h, cx, cy)
    k = np.array([[focal_px, 0, cx], [0, focal_px, cy], [0, 0, 1.0]])
    ok, rvec, tvec = cv2.solvePnP(world, uv, k, None, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise GalileoError("no camera pose fits these points")
    r, _ = cv2.Rodrigues(rvec)
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, tvec.ravel()
    cam = Camera(k, m, int(width_px), int(height_px), float(fps), int(n_frames))
    if not (world @ r.T + tvec.ravel())[:, 2].min() > 0:
        raise GalileoError("the fitted camera sees the ramp from behind: check the points' order")
    err = float(np.sqrt(np.mean(np.sum((cam.project(world) - uv) ** 2, axis=1))))
    if err > MAX_REPROJECTION_PX:
        raise GalileoError(f"the points disagree with the stated ramp by {err:.1f} px (more than "
                           f"{MAX_REPROJECTION_PX:g}): check the order, the length, width, angle and --upper-at-m")
    return cam, err


DEFAULT_TARGET_DISTANCE_M = 0.1   # from the ramp's foot to the target's near face
MAX_RAMP_M = RAMP_SIZE_M.hi      # a ramp's length and width at most (the scenario is a tabletop ramp)


def scene_from_clicks(uv, *, width_px: int, height_px: int, fps: float, n_frames: int, length_m: float,
                      width_m: float, angle_deg: float, upper_at_m: float | None = None,
                      focal_px: float | None = None, start_m: float | None = None, target: str = "none",
                      target_distance_m: float | None = None, target_size_m=None):
    """(scene, RMS reprojection error in pixels) for a user's video from the four clicks and
    the ramp's measurements: the camera from `camera_from_clicks`, the ramp's size and angle,
    the object starting `start_m` up the ramp (foot to centre; None: the paper's 30 units, or the
    ramp's middle on a ramp too short for them),
    and the target if any. `galileo scene` and the browser's calibration both build it here.
    Every number is checked; a wrong one is a GalileoError naming it."""
    import dataclasses

    from ...shapes import Shape
    from .scene import Ramp, Scene, default_scene

    for what, v in (("ramp length (m)", length_m), ("ramp width (m)", width_m), ("upper points' distance (m)",
                    upper_at_m), ("focal length (px)", focal_px), ("start (m)", start_m),
                    ("target distance (m)", target_distance_m)):
        if v is not None and not (math.isfinite(v) and v > 0):
            raise GalileoError(f"{what} must be a positive number, got {v}")
    for what, v in (("ramp length (m)", length_m), ("ramp width (m)", width_m)):
        if v > MAX_RAMP_M:
            raise GalileoError(f"{what} must be at most {MAX_RAMP_M:g} m (a tabletop ramp), got {v:g}")
    if not (math.isfinite(angle_deg) and 0 < angle_deg < 60):
        raise GalileoError(f"the ramp's angle must be in (0, 60) degrees, got {angle_deg}")
    if upper_at_m is not None and upper_at_m > length_m:
        raise GalileoError(f"the upper points' distance {upper_at_m} m is beyond the ramp's length {length_m} m")
    if start_m is not None and start_m >= length_m:
        raise GalileoError(f"the start {start_m} m up the ramp is beyond its length {length_m} m")
    cam, err = camera_from_clicks(uv, width_px=width_px, height_px=height_px, fps=fps, n_frames=n_frames,
                                  length_m=length_m, width_m=width_m, angle_deg=angle_deg, upper_at_m=upper_at_m,
                                  focal_px=focal_px)
    scene = default_scene(angle_deg, target=target, camera=cam,
                          distance_m=DEFAULT_TARGET_DISTANCE_M if target_distance_m is None else target_distance_m)
    half_m = scene.ramp_object.shape.size_m[0] / 2
    if start_m is None:   # the paper's 30 units where the ramp is long enough; else its middle
        start_m = min(Scene.start_units * Scene.unit_m, length_m / 2)
    elif not half_m <= start_m <= length_m - half_m:
        raise GalileoError(f"the start {start_m:g} m up the ramp puts the object ({2 * half_m:g} m long) past the "
                           f"ramp's {'foot' if start_m < half_m else 'top'}: give --start-m from {half_m:g} to "
                           f"{length_m - half_m:g} m (foot to the object's centre)")
    scene = dataclasses.replace(scene, ramp=Ramp(angle_deg, length_m, width_m), start_units=start_m / scene.unit_m)
    if target_size_m is not None:
        if scene.target is None:
            raise GalileoError("a target size needs a target (cardboard or foam)")
        size = np.asarray(target_size_m, float)
        if size.shape != (3,) or not (np.isfinite(size).all() and (size > 0).all()):
            raise GalileoError(f"the target's size must be three positive numbers x,y,z in metres, got {target_size_m}")
        tgt = dataclasses.replace(scene.target, shape=Shape("box", tuple(float(v) for v in size)))
        scene = dataclasses.replace(scene, objects=(scene.ramp_object, tgt))
    scene.validate()
    return scene, err


GRID_STEP_M = 0.1          # the ground grid drawn over the frame
GRID_HALF_M = 0.6


def draw_overlay(frame_rgb: np.ndarray, scene, clicks=None) -> np.ndarray:
    """The frame with the scene's ramp (top surface, yellow), the ground grid (white, 10 cm),
    the object's start band (green: the object's length along the ramp at its start) and the
    target (cyan) projected by the scene's camera, and the clicks (red, numbered 1-4)."""
    import cv2

    img = np.ascontiguousarray(frame_rgb[..., :3]).copy()
    cam = scene.camera
    h, w = img.shape[:2]
    lw = max(1, round(max(w, h) / 400))

    def poly(points_in_world, color, closed=True):
        p = np.asarray(points_in_world, float)
        depth = (p @ cam.world_to_camera[:3, :3].T + cam.world_to_camera[:3, 3])[:, 2]
        if (depth <= 1e-3).any():
            return
        uv = np.round(cam.project(p) * 16).astype(np.int32)   # 4 bits of sub-pixel precision
        cv2.polylines(img, [uv.reshape(-1, 1, 2)], closed, color, lw, cv2.LINE_AA, shift=4)

    for x in np.arange(-GRID_HALF_M, GRID_HALF_M + 1e-9, GRID_STEP_M):
        poly([[x, -GRID_HALF_M, 0], [x, GRID_HALF_M, 0]], (235, 235, 235), closed=False)
        poly([[-GRID_HALF_M, x, 0], [GRID_HALF_M, x, 0]], (235, 235, 235), closed=False)
    r = scene.ramp
    poly(ramp_points_in_world(r.length_m, r.width_m, r.angle_deg), (255, 220, 0))
    obj = scene.ramp_object
    s, half = scene.start_distance_m(obj), obj.shape.size_m[0] / 2
    band = ramp_points_in_world(s + half, r.width_m, r.angle_deg)[:2].tolist() + \
        ramp_points_in_world(max(s - half, 0.0), r.width_m, r.angle_deg)[:2][::-1].tolist()
    poly(band, (40, 220, 60))
    tgt = scene.target
    if tgt is not None:
        x0, (sx, sy, sz) = tgt.distance_m, tgt.shape.size_m
        for z in (0.0, sz):
            poly([[x0, -sy / 2, z], [x0 + sx, -sy / 2, z], [x0 + sx, sy / 2, z], [x0, sy / 2, z]], (0, 200, 230))
    if clicks is not None:
        for i, (u, v) in enumerate(np.asarray(clicks, float)):
            c = (int(round(u)), int(round(v)))
            cv2.circle(img, c, 3 * lw + 2, (230, 30, 30), lw, cv2.LINE_AA)
            cv2.putText(img, str(i + 1), (c[0] + 4 * lw, c[1] - 4 * lw), cv2.FONT_HERSHEY_SIMPLEX, 0.4 * lw,
                        (230, 30, 30), lw, cv2.LINE_AA)
    return img


# -- the object's start, found in the first frame ------------------------------------------------

START_MAX_FRAMES = 60      # find_start_m reads at most this many frames, evenly spaced ...
START_MAX_SIDE_PX = 640    # ... at most this many pixels on their long side
START_BACKGROUND_PART = 3  # the background: the median of the last third of the frames ...
START_MIN_BACKGROUND = 3   # ... at least this many
START_MIN_AREA = 0.25      # components smaller than this fraction of the largest are noise


def sample_frames(frames, max_frames: int = START_MAX_FRAMES,
                  max_side_px: int = START_MAX_SIDE_PX) -> tuple[np.ndarray | None, int, tuple[int, int] | None]:
    """(frames kept, frames seen, (width, height) of a frame) from an iterable of RGB frames,
    in one pass: at most `max_frames` frames (the first always; evenly spaced over the whole,
    the spacing doubling as the video turns out longer), each shrunk (area averaging) to at most
    `max_side_px` on its long side. `max_frames` 0 keeps none (counting only). Memory: at most
    2 max_frames shrunk frames at a time."""
    import cv2

    kept: list[np.ndarray] = []
    stride, n, size, scale = 1, 0, None, 1.0
    for frame in frames:
        if size is None:
            size = (int(frame.shape[1]), int(frame.shape[0]))
            scale = min(1.0, max_side_px / max(size))
        if max_frames and n % stride == 0:
            f = np.ascontiguousarray(frame[..., :3])
            if scale < 1.0:
                f = cv2.resize(f, (max(1, round(size[0] * scale)), max(1, round(size[1] * scale))),
                               interpolation=cv2.INTER_AREA)
            kept.append(f)
            if len(kept) >= 2 * max_frames:     # every other one: the spacing doubles
                kept, stride = kept[::2], stride * 2
        n += 1
    if not kept:
        return None, n, size
    if len(kept) > max_frames:
        kept = [kept[i] for i in np.unique(np.linspace(0, len(kept) - 1, max_frames).round().astype(int))]
    return np.stack(kept), n, size


def _start_region(scene, height_m: float, hw: tuple[int, int], scale: float) -> np.ndarray:
    """Boolean mask (frame pixels) of the ramp's top surface and the space `height_m` above it,
    projected by the scene's camera (pixel coordinates scaled by `scale` to the frames')."""
    import cv2

    r, cam = scene.ramp, scene.camera
    top = ramp_points_in_world(r.length_m, r.width_m, r.angle_deg)
    pts = np.concatenate([top, top + height_m * r.normal])
    depth = (pts @ cam.world_to_camera[:3, :3].T + cam.world_to_camera[:3, 3])[:, 2]
    if (depth <= 1e-3).any():
        raise GalileoError("the ramp is partly behind the camera: cannot look for the object on it; give --start-m")
    uv = (cam.project(pts) + 0.5) * scale - 0.5     # pixel centres at integer coordinates, at either scale
    hull = cv2.convexHull(np.round(uv * 16).astype(np.int32))
    m = np.zeros(hw, np.uint8)
    cv2.fillConvexPoly(m, hull, 1, cv2.LINE_8, 4)
    return m > 0


def _along_ramp(scene, uv: np.ndarray, height_m: float) -> float:
    """The distance s up the ramp whose point s up, `height_m` above the surface on the fall
    line (y = 0), projects nearest to pixel `uv`: the image of that line is a line; the foot of
    the perpendicular from `uv` on it, mapped back to s."""
    cam, r = scene.camera, scene.ramp
    p = cam.K @ cam.world_to_camera[:3]                     # 3 x 4 projection
    up = np.array([-math.cos(r.angle_rad), 0.0, math.sin(r.angle_rad)])
    a = p @ np.r_[height_m * r.normal, 1.0]                 # the line's point at s = 0, homogeneous
    b = p @ np.r_[up, 0.0]                                  # its direction
    line = np.cross(a, b)
    n = line[:2] / np.linalg.norm(line[:2])
    q = np.asarray(uv, float) - (n @ uv + line[2] / np.linalg.norm(line[:2])) * n   # foot of the perpendicular
    # a_xy + s b_xy = q (a_z + s b_z)  ->  s (b_xy - q b_z) = q a_z - a_xy
    g, h = b[:2] - q * b[2], q * a[2] - a[:2]
    return float(g @ h / (g @ g))


def find_start_m(frames, scene) -> float:
    """How far up the ramp (metres, from the foot to the object's centre) the ramp object is
    in the first of `frames` ((T, H, W, 3) uint8 RGB, or an iterable of them; shrunk frames
    are fine: pixels are scaled by the camera's width over theirs), for `scene`'s camera.

    The object moves in the video, so the per-pixel median of the last third of the frames
    (at least 3) is the scene without it at its start (also when it is held there for much of
    the video before it is let go, as long as it is gone from there for most of the last
    third); it is where the first frame differs from that by more than the sensor noise allows
    (`vision.background.foreground`), over the ramp's top surface and the space above it (as
    high as the priors' largest object size), cleaned (open, close); of the components (of at
    least a quarter of the largest one's area) the one furthest up the ramp (the others are
    where it comes to rest: objects only slide down).
    Its centroid's pixel, mapped to the distance up the ramp of the object's centre line
    (half the scene's object height above the surface, on the fall line; `_along_ramp`).

    The centroid is that of the silhouette, not the projected centre: it is off by the
    perspective of the object's near half (and the scene's object height need not be the
    object's), about a millimetre along the ramp for the dataset's camera; measured on renders
    the found start is within 1.3 mm of the truth, a pixel being about 2 mm there (the tests).
    Nothing found (a video in which the object never moves) or a place off the ramp is a
    GalileoError asking for --start-m. An object that never moves could be told from the
    ramp by its colour; that is not attempted (a clear error is better than a guess).
    """
    import cv2

    from ...vision.background import MIN_BLOB_PX, clean, foreground, noise_sd

    if scene.camera is None:
        raise GalileoError("finding the object's start needs the scene's camera")
    frames = frames if isinstance(frames, np.ndarray) else np.stack(list(frames))
    if frames.ndim != 4 or frames.shape[-1] < 3 or len(frames) < 2:
        raise GalileoError("finding the object's start needs at least two RGB frames: give --start-m")
    frames = frames[..., :3]
    cam, r = scene.camera, scene.ramp
    hw = frames.shape[1:3]
    scale = hw[1] / cam.width_px
    n = len(frames)
    later = frames[max(1, n - max(START_MIN_BACKGROUND, n // START_BACKGROUND_PART)):]
    background = np.median(later, axis=0).round().astype(np.uint8)
    region = _start_region(scene, scene.priors.size_m[1], hw, scale)
    fg = (foreground(frames[0], background, noise_sd(frames[:2])) > 0) & region
    fg = clean(fg.astype(np.uint8) * 255) > 0
    # components: at least MIN_BLOB_PX at the camera's resolution, a quarter of the largest one
    _, labels, stats, _ = cv2.connectedComponentsWithStats(fg.astype(np.uint8), connectivity=8)
    area = stats[1:, cv2.CC_STAT_AREA]
    keep = area >= max(MIN_BLOB_PX * scale ** 2, START_MIN_AREA * area.max(initial=0))
    found = [labels == 1 + i for i in np.nonzero(keep)[0]]
    if not found:
        raise GalileoError("no object found on the ramp in the first frame (it does not move in the video, or the "
                           "clicks miss the ramp): give --start-m, from the ramp's foot to the object's centre")
    half_h = scene.ramp_object.shape.height_m / 2

    def start_of(blob):
        ys, xs = np.nonzero(blob)
        uv = (np.array([xs.mean(), ys.mean()]) + 0.5) / scale - 0.5
        return _along_ramp(scene, uv, half_h)

    s = max(start_of(b) for b in found)
    if not (math.isfinite(s) and 0 < s < r.length_m):
        raise GalileoError(f"the object found in the first frame is {s:.2f} m up the ramp, off the ramp "
                           f"(0 to {r.length_m:g} m): give --start-m, from the ramp's foot to the object's centre")
    return s
