"""The ramp's own-video calibration (`galileo scene --scenario ramp`, the upload page): a ramp
scene from four points clicked on the video's first frame and the ramp's measurements.

The user marks four points of the ramp board's top surface, in this order: upper near, upper
far, foot far, foot near ("near": the side edge closer to the camera). The foot points are the
foot's corners; the upper points lie on the two side edges `upper_at_m` up the ramp from the
foot (by default the ramp's length: its upper corners). With the ramp's length, width and
angle these four points are known in the world frame (the foot's centre at the origin, the
ramp rising towards -x, the camera on the -y side), so the camera follows from them
(`galileo.clicks.camera_from_plane`: the focal length from the plane's homography unless
given, the pose by planar PnP). The reprojection error (pixels) says how well the clicks agree
with the stated geometry.

Without a stated start (`--start-m`), `find_start_m` finds the ramp object in the first frame:
the per-pixel median of the video's last third is the scene without the object at its start
(it has slid away), and the object is where the first frame differs from that, over the ramp.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from ...camera import FOCAL_PX
from ...clicks import (DISTORTION, MAX_REPROJECTION_PX, Calibration, Field, NotFound, Point, camera_from_plane,
                       check_quad, draw_clicks, draw_lines, rms_px)
from ...errors import GalileoError
from ...video import VideoInfo
from .scene import ANGLE_DEG, DISTANCE_M, OBJECT_SIZE_M, RAMP_SIZE_M, TARGET_DEFAULTS, Ramp

DEFAULT_TARGET_DISTANCE_M = 0.1   # from the ramp's foot to the target's near face

POINTS = (Point("upper near", "the top of the near side edge (closer to the camera), or the point on it "
                              "upper_at_m up from the foot"),
          Point("upper far", "the top of the far side edge, or the point on it upper_at_m up from the foot"),
          Point("foot far", "the far corner of the ramp's foot"),
          Point("foot near", "the near corner of the ramp's foot"))
ORDER = tuple(p.name for p in POINTS)
FIELDS = (
    Field("ramp_length_m", "Length", "m", Ramp.length_m, "the ramp board's length along the slope, foot to top",
          RAMP_SIZE_M, required=True),
    Field("ramp_width_m", "Width", "m", Ramp.width_m, "the board's width", RAMP_SIZE_M, required=True),
    Field("angle_deg", "Angle", "deg", Ramp.angle_deg, "the ramp's angle to the ground", ANGLE_DEG, required=True),
    Field("upper_at_m", "Upper at", "m", None, "how far up the ramp (from the foot, along the side edges) the "
          "upper points are; not given: the ramp's length (its upper corners)", RAMP_SIZE_M),
    Field("focal_px", "Focal", "px", None, "the camera's focal length in pixels; not given: estimated from the "
          "points (principal point at the image centre, square pixels)", FOCAL_PX),
    DISTORTION,
    Field("start_m", "Start", "m", None, "how far up the ramp the object starts, from the foot to its centre; not "
          "given: found in the video (where the first frame differs from its end; a video in which it never moves "
          "needs this)", RAMP_SIZE_M),
    Field("target", "Target", "", "none", "the box the object slides into, if there is one",
          choices=("none", *TARGET_DEFAULTS)),
    Field("target_distance_m", "Target dist", "m", DEFAULT_TARGET_DISTANCE_M,
          "from the ramp's foot to the target's near face", DISTANCE_M),
    Field("target_size_m", "Target size", "m", None, "the target box's size x, y, z (along the ground, across, up); "
          "not given: the kind's usual size", OBJECT_SIZE_M, size=3),
)


def ramp_points_in_world(length_m: float, width_m: float, angle_deg: float,
                         upper_at_m: float | None = None) -> np.ndarray:
    """The four points (ORDER) of the ramp's top surface in the world frame, (4, 3) metres."""
    d = length_m if upper_at_m is None else upper_at_m
    a = math.radians(angle_deg)
    up = np.array([-math.cos(a), 0.0, math.sin(a)])      # up the ramp, along the surface
    near, far = np.array([0.0, -width_m / 2, 0.0]), np.array([0.0, width_m / 2, 0.0])
    return np.array([d * up + near, d * up + far, far, near])


def camera_from_clicks(uv, *, width_px: int, height_px: int, fps: float, n_frames: int, length_m: float,
                       width_m: float, angle_deg: float, upper_at_m: float | None = None,
                       focal_px: float | None = None, k1: float = 0.0):
    """(camera, RMS reprojection error in pixels) from the four clicks (see the module; the
    clicks' count, place in the frame and distinctness are `Calibration.check_clicks`'), seen
    through a lens of distortion k1."""
    uv = np.asarray(uv, float)
    check_quad(uv, ORDER, "the ramp's top surface")
    world = ramp_points_in_world(length_m, width_m, angle_deg, upper_at_m)
    a = math.radians(angle_deg)
    cam = camera_from_plane(uv, world, VideoInfo(width_px, height_px, fps, n_frames), focal_px=focal_px,
                            facing=np.array([math.sin(a), 0.0, math.cos(a)]), what="the ramp's top surface", k1=k1)
    err = rms_px(cam.project(world) - uv)
    if err > MAX_REPROJECTION_PX:
        raise GalileoError(f"the points disagree with the stated ramp by {err:.1f} px (more than "
                           f"{MAX_REPROJECTION_PX:g}): check the order, the length, width, angle and --upper-at-m")
    return cam, err


def scene_from_clicks(uv, video_info, *, length_m: float, width_m: float, angle_deg: float,
                      upper_at_m: float | None = None, focal_px: float | None = None, start_m: float | None = None,
                      target: str = "none", target_distance_m: float = DEFAULT_TARGET_DISTANCE_M,
                      target_size_m=None, k1: float = 0.0):
    """(scene, RMS reprojection error in pixels) for a user's video from the four clicks and
    the ramp's measurements (each already checked against its field): the camera from
    `camera_from_clicks` (through a lens of distortion k1), the ramp's size and angle, the object starting `start_m` up the ramp
    (foot to centre; None: the paper's 30 units, or the ramp's middle on a ramp too short for
    them), and the target if any. What the numbers say together is checked here; a wrong one
    is a GalileoError naming its flag."""
    from ...shapes import Shape
    from .scene import Scene, default_scene

    if upper_at_m is not None and upper_at_m > length_m:
        raise GalileoError(f"--upper-at-m {upper_at_m:g} is beyond the ramp's length {length_m:g} m")
    if start_m is not None and start_m >= length_m:
        raise GalileoError(f"the start {start_m:g} m up the ramp is beyond its length {length_m:g} m")
    if target_size_m is not None and target == "none":
        raise GalileoError("--target-size-m needs a target: give --target " + " or ".join(TARGET_DEFAULTS))
    cam, err = camera_from_clicks(uv, width_px=video_info.width_px, height_px=video_info.height_px,
                                  fps=video_info.fps, n_frames=video_info.n_frames, length_m=length_m,
                                  width_m=width_m, angle_deg=angle_deg, upper_at_m=upper_at_m, focal_px=focal_px,
                                  k1=k1)
    scene = default_scene(angle_deg, target=target, camera=cam, distance_m=target_distance_m)
    half_m = scene.ramp_object.shape.size_m[0] / 2
    if start_m is None:   # the paper's 30 units where the ramp is long enough; else its middle
        start_m = min(Scene.start_units * Scene.unit_m, length_m / 2)
    elif not half_m <= start_m <= length_m - half_m:
        raise GalileoError(f"the start {start_m:g} m up the ramp puts the object ({2 * half_m:g} m long) past the "
                           f"ramp's {'foot' if start_m < half_m else 'top'}: give --start-m from {half_m:g} to "
                           f"{length_m - half_m:g} m (foot to the object's centre)")
    scene = dataclasses.replace(scene, ramp=Ramp(angle_deg, length_m, width_m), start_units=start_m / scene.unit_m)
    if target_size_m is not None:
        tgt = dataclasses.replace(scene.target, shape=Shape("box", tuple(float(v) for v in target_size_m)))
        scene = dataclasses.replace(scene, objects=(scene.ramp_object, tgt))
    scene.validate()
    return scene, err


def solve(uv: np.ndarray, v: dict, video_info, frames):
    """The calibration's solver: the scene from the clicks and the numbers, the object's start
    found in the frames where not given (`find_start_m`)."""
    common = dict(length_m=v["ramp_length_m"], width_m=v["ramp_width_m"], angle_deg=v["angle_deg"],
                  upper_at_m=v["upper_at_m"], focal_px=v["focal_px"], target=v["target"],
                  target_distance_m=v["target_distance_m"], target_size_m=v["target_size_m"], k1=v["distortion"])
    scene, err = scene_from_clicks(uv, video_info, start_m=v["start_m"], **common)
    if v["start_m"] is not None:
        return scene, err
    if frames is None:
        raise NotFound("give --start-m, from the ramp's foot to the object's centre", scene)
    try:   # the camera first (any start on the ramp will do for it), then the start it sees
        start_m = find_start_m(frames, scene)
    except GalileoError as e:
        raise NotFound(str(e), scene) from None
    try:
        return scene_from_clicks(uv, video_info, start_m=start_m, **common)
    except GalileoError as e:
        raise NotFound(f"{e} (the object was found in the first frame {start_m:.2f} m up the ramp): give "
                       "--start-m, from the ramp's foot to the object's centre", scene) from None


def describe(scene, v: dict) -> str:
    cam = scene.camera
    text = (f"focal {cam.K[0, 0]:.1f} px{' (estimated)' if v['focal_px'] is None else ''}; camera "
            f"{np.linalg.norm(cam.position_in_world):.2f} m from the ramp's foot; ")
    if v["start_m"] is None:
        return text + (f"object found in the first frame, {scene.start_distance_m():.2f} m up the ramp (give "
                       "--start-m to override)")
    return text + f"start {scene.start_distance_m():.3f} m up the ramp"


GRID_STEP_M = 0.1          # the ground grid drawn over the frame
GRID_HALF_M = 0.6


def draw_overlay(frame_rgb: np.ndarray, scene, clicks=None) -> np.ndarray:
    """The frame with the scene's ramp (top surface, yellow), the ground grid (white, 10 cm),
    the object's start band (green: the object's length along the ramp at its start) and the
    target (cyan) projected by the scene's camera, and the clicks (red, numbered 1-4)."""
    img = np.ascontiguousarray(frame_rgb[..., :3]).copy()
    cam = scene.camera
    for x in np.arange(-GRID_HALF_M, GRID_HALF_M + 1e-9, GRID_STEP_M):
        draw_lines(img, cam, [[x, -GRID_HALF_M, 0], [x, GRID_HALF_M, 0]], (235, 235, 235), closed=False)
        draw_lines(img, cam, [[-GRID_HALF_M, x, 0], [GRID_HALF_M, x, 0]], (235, 235, 235), closed=False)
    r = scene.ramp
    draw_lines(img, cam, ramp_points_in_world(r.length_m, r.width_m, r.angle_deg), (255, 220, 0))
    obj = scene.ramp_object
    s, half = scene.start_distance_m(obj), obj.shape.size_m[0] / 2
    band = ramp_points_in_world(s + half, r.width_m, r.angle_deg)[:2].tolist() + \
        ramp_points_in_world(max(s - half, 0.0), r.width_m, r.angle_deg)[:2][::-1].tolist()
    draw_lines(img, cam, band, (40, 220, 60))
    tgt = scene.target
    if tgt is not None:
        x0, (sx, sy, sz) = tgt.distance_m, tgt.shape.size_m
        for z in (0.0, sz):
            draw_lines(img, cam, [[x0, -sy / 2, z], [x0 + sx, -sy / 2, z], [x0 + sx, sy / 2, z], [x0, sy / 2, z]],
                       (0, 200, 230))
    if clicks is not None:
        draw_clicks(img, clicks)
    return img


EXAMPLE_UPPER_AT_M = 0.5   # the example's upper points: this far up the side edges (the top is often out of frame)


def example(scene) -> tuple[np.ndarray, dict]:
    """The world points a user would click in a video of `scene`, and the numbers they would give."""
    r = scene.ramp
    upper = min(EXAMPLE_UPPER_AT_M, r.length_m)
    numbers = {"ramp_length_m": r.length_m, "ramp_width_m": r.width_m, "angle_deg": r.angle_deg,
               "upper_at_m": upper, "start_m": scene.start_distance_m()}
    if scene.target is not None:
        numbers.update(target=scene.target.kind, target_distance_m=scene.target.distance_m)
    return ramp_points_in_world(r.length_m, r.width_m, r.angle_deg, upper), numbers


CALIBRATION = Calibration("an object sliding down a ramp", POINTS, FIELDS, solve, draw_overlay, describe, example)


# -- the object's start, found in the first frame ------------------------------------------------

START_BACKGROUND_PART = 3  # the background: the median of the last third of the frames ...
START_MIN_BACKGROUND = 3   # ... at least this many
START_MIN_AREA = 0.25      # components smaller than this fraction of the largest are noise


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
    line (y = 0), projects nearest to pixel `uv`: the pinhole image of that line is a line; the
    foot of the perpendicular from `uv` (undistorted) on it, mapped back to s."""
    cam, r = scene.camera, scene.ramp
    uv = cam.undistort_px(uv)
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
