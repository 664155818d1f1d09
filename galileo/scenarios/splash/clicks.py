"""The splash's own-video calibration (`galileo scene --scenario splash`, the upload page): a
splash scene from six points clicked on the video's first frame and the tank's inner size.

The user marks the four corners of the tank's front face, inside the glass (where the front
glass meets the side walls, at the top edge and at the floor), in this order: top left, top
right, bottom right, bottom left; then two points on the water line along the front glass,
one towards each side. In the scene's world frame (the origin at the centre of the tank's
floor, inside; x to the right along the front glass, y away from the camera, z up) the four
corners are (-+w/2, -d/2, h or 0) for the tank's inner width w, depth d and height h, so:

* the camera follows from them (`galileo.clicks.camera_from_plane`: the focal length from the
  front face's homography unless given, the pose by planar PnP). A tank filmed straight from
  the front (as Physics 101 films it) shows no perspective to take a focal length from: the
  user gives it (`--focal-px`: the image width over 2 tan(half the horizontal field of view));
* the water level: the two water-line points, back-projected onto the front glass (the
  plane y = -d/2), are this high above the floor (their mean), unless given.

The reprojection error (pixels) is the RMS over the corners' distances from their projections
and the water-line points' distances from the projected water line.

Without a stated release point (`--release-x-m`, `--release-height-m`), `find_release` finds
the object in the video's first two frames, falling through the air: where it is (its x) and
how fast it falls give where it was let go (at rest) before frame 0.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from ...camera import FOCAL_PX, backproject_to_plane
from ...clicks import (DISTORTION, MAX_REPROJECTION_PX, Calibration, Field, NotFound, Point, camera_from_plane,
                       check_quad, draw_clicks, draw_lines)
from ...errors import GalileoError
from ...fields import Bound
from .scene import MAX_DROP_M, RELEASE_ABOVE_WATER_M, TANK_SIZE_M, Tank, default_scene

FRONT = "the tank's front face"
POINTS = (Point("top left", "the top left corner of the tank's front face, inside the glass"),
          Point("top right", "the top right corner of the tank's front face, inside the glass"),
          Point("bottom right", "where the front glass meets the floor and the right wall, inside"),
          Point("bottom left", "where the front glass meets the floor and the left wall, inside"),
          Point("water left", "a point on the water line along the front glass, towards the left"),
          Point("water right", "a point on the water line along the front glass, towards the right"))
ORDER = tuple(p.name for p in POINTS)
WATER_MARGIN = 0.05        # a water-line point at most this fraction of the tank's width beyond a side wall
FIELDS = (
    Field("tank_width_m", "Tank width", "m", Tank.size_m[0], "the tank's inner width, left to right along its "
          "front glass", TANK_SIZE_M, required=True),
    Field("tank_depth_m", "Tank depth", "m", Tank.size_m[1], "the tank's inner depth, front glass to back glass",
          TANK_SIZE_M, required=True),
    Field("tank_height_m", "Tank height", "m", Tank.size_m[2], "the tank's inner height, floor to the top corners "
          "clicked", TANK_SIZE_M, required=True),
    Field("water_level_m", "Water level", "m", None, "how deep the water is, above the tank's floor; not given: "
          "measured from the two water-line points", Bound(0.0, TANK_SIZE_M.hi, lo_open=True)),
    Field("focal_px", "Focal", "px", None, "the camera's focal length in pixels; not given: estimated from the four "
          "corners (principal point at the image centre, square pixels; a tank seen straight from the front needs "
          "it: image width / (2 tan(horizontal field of view / 2)))", FOCAL_PX),
    DISTORTION,
    Field("release_x_m", "Release x", "m", None, "where the object is let go (its centre), from the tank's middle "
          "towards the right; not given: found in the first frame", Bound(-TANK_SIZE_M.hi / 2, TANK_SIZE_M.hi / 2)),
    Field("release_height_m", "Release height", "m", None, "how far above the water the object's centre is let go "
          "(at rest); not given: found from its fall over the video's first two frames",
          Bound(0.0, MAX_DROP_M, lo_open=True)),
)


def front_corners(width_m: float, depth_m: float, height_m: float) -> np.ndarray:
    """The front face's four inner corners (ORDER) in the world frame, (4, 3) metres."""
    x, y = width_m / 2, -depth_m / 2
    return np.array([[-x, y, height_m], [x, y, height_m], [x, y, 0.0], [-x, y, 0.0]])


def _distance_to_line_px(uv: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distances (pixels) of points uv (N, 2) from the image line through a and b."""
    d = (b - a) / np.linalg.norm(b - a)
    r = uv - a
    return np.abs(r[:, 0] * d[1] - r[:, 1] * d[0])


def solve(uv: np.ndarray, v: dict, video_info, frames):
    """The calibration's solver: the camera from the four corners, the water level from the
    water-line points (unless given), the release point found in the frames (unless given)."""
    sx, sy, sz = v["tank_width_m"], v["tank_depth_m"], v["tank_height_m"]
    corners = front_corners(sx, sy, sz)
    check_quad(uv[:4], ORDER[:4], FRONT)
    cam = camera_from_plane(uv[:4], corners, video_info, facing=np.array([0.0, -1.0, 0.0]), focal_px=v["focal_px"],
                            what=FRONT, k1=v["distortion"])
    on_glass = backproject_to_plane(cam, uv[4:], -sy / 2)
    for p, (x, _, _) in zip(POINTS[4:], on_glass):
        if abs(x) > sx / 2 * (1 + WATER_MARGIN):
            side = "right" if x > 0 else "left"
            raise GalileoError(f"the {p.name} point is {abs(x) - sx / 2:.3f} m beyond the tank's {side} wall: click "
                               "the water line along the front glass, between the side walls")
    level = v["water_level_m"]
    if level is None:
        level = float(on_glass[:, 2].mean())
        if not 0 < level < sz:
            raise GalileoError(f"the water-line points are {level:.3f} m above the tank's floor, outside the tank (0 "
                               f"to {sz:g} m): click the water line along the front glass, after the four corners")
    elif level >= sz:
        raise GalileoError(f"--water-level-m {level:g} is not below the tank's height {sz:g} m")
    # the water line is a line in the pinhole's image (a lens bends it): its points undistorted there
    ends = cam.undistort_px(cam.project(np.array([[-sx / 2, -sy / 2, level], [sx / 2, -sy / 2, level]])))
    residuals = np.concatenate([np.linalg.norm(cam.project(corners) - uv[:4], axis=1),
                                _distance_to_line_px(cam.undistort_px(uv[4:]), *ends)])
    err = float(np.sqrt(np.mean(residuals ** 2)))
    if err > MAX_REPROJECTION_PX:
        raise GalileoError(f"the points disagree with the stated tank by {err:.1f} px (more than "
                           f"{MAX_REPROJECTION_PX:g}): check the order, the tank's inner width, depth and height"
                           f"{' and --water-level-m' if v['water_level_m'] is not None else ''}")
    x, height = v["release_x_m"], v["release_height_m"]
    if x is not None and not abs(x) < sx / 2:
        raise GalileoError(f"--release-x-m {x:g} is outside the tank (from {-sx / 2:g} to {sx / 2:g} m)")
    scene = dataclasses.replace(default_scene(camera=cam), tank=Tank((sx, sy, sz), water_level_m=level),
                                release_m=(0.0 if x is None else x, 0.0,
                                           level + (RELEASE_ABOVE_WATER_M if height is None else height)))
    scene.validate()
    if x is not None and height is not None:
        return scene, err
    if frames is None:
        raise NotFound("give --release-x-m and --release-height-m (where the object is let go)", scene)
    try:
        found_x, found_height = find_release(frames, scene)
    except GalileoError as e:
        raise NotFound(str(e), scene) from None
    scene = dataclasses.replace(scene, release_m=(found_x if x is None else x, 0.0,
                                                  level + (found_height if height is None else height)))
    try:
        scene.validate()
    except GalileoError as e:
        raise NotFound(f"the release point found in the first frames is not in the tank ({e}): give --release-x-m "
                       "and --release-height-m", scene) from None
    return scene, err


def describe(scene, v: dict) -> str:
    cam, t = scene.camera, scene.tank
    glass = np.array([0.0, -t.size_m[1] / 2, t.size_m[2] / 2])
    x, _, z = scene.release_m
    text = (f"focal {cam.K[0, 0]:.1f} px{' (estimated)' if v['focal_px'] is None else ''}; camera "
            f"{np.linalg.norm(cam.position_in_world - glass):.2f} m from the front glass's centre; water "
            f"{t.water_level_m:.3f} m deep{' (measured)' if v['water_level_m'] is None else ''}; object let go at "
            f"x = {x:.3f} m, {z - t.water_level_m:.3f} m above the water")
    found = [f.flag for f in FIELDS[-2:] if v[f.name] is None]
    return text + (f" (found in the first frames; give {' and '.join(found)} to override)" if found else "")


# -- the release point, found in the first two frames ---------------------------------------------------

RELEASE_BACKGROUND_PART = 3   # the background: the median of the last third of the frames (the object at rest) ...
RELEASE_MIN_BACKGROUND = 3    # ... at least this many
RELEASE_MIN_AREA = 0.25       # components smaller than this fraction of the largest are noise


def _air_region(scene, hw: tuple[int, int], scale: float) -> np.ndarray:
    """Boolean mask (frame pixels) of the tank's inside from the water up to MAX_DROP_M above
    it, projected by the scene's camera (pixel coordinates scaled by `scale` to the frames')."""
    import cv2

    (sx, sy, _), level, cam = scene.tank.size_m, scene.tank.water_level_m, scene.camera
    box = np.array([[x, y, z] for x in (-sx / 2, sx / 2) for y in (-sy / 2, sy / 2)
                    for z in (level, level + MAX_DROP_M)])
    depth = (box @ cam.world_to_camera[:3, :3].T + cam.world_to_camera[:3, 3])[:, 2]
    if (depth <= 1e-3).any():
        raise GalileoError("the space above the water is partly behind the camera: cannot look for the object "
                           "there; give --release-x-m and --release-height-m")
    uv = (cam.project(box) + 0.5) * scale - 0.5
    m = np.zeros(hw, np.uint8)
    cv2.fillConvexPoly(m, cv2.convexHull(np.round(uv * 16).astype(np.int32)), 1, cv2.LINE_8, 4)
    return m > 0


def find_release(frames, scene) -> tuple[float, float]:
    """(x, height above the water) in metres of the object's centre when it was let go, from
    `frames` ((T, H, W, 3) uint8 RGB, the video's frames 0 and 1 first, then frames to its
    end: `galileo.clicks.sample_video`'s; shrunk frames are fine) and the scene's camera.

    The object comes to rest in the video, so the per-pixel median of the last third of the
    frames (at least 3) is the tank without it where it falls; in frames 0 and 1 it is where
    they differ from that by more than the sensor noise allows (`vision.background.foreground`),
    inside the tank above the water, cleaned: in frame 0 the highest component (of at least a
    quarter of the largest one's area; the others are where it comes to rest), in frame 1 the
    one nearest below it. Back-projected onto the release plane (y = 0), frame 0's centroid is
    its place (x0, z0), and its top edge, which must still be above the water in frame 1 (the
    rest of it may be in the water already), falls by s between the frames; falling freely
    (the air's drag is a thousandth of the water's) from rest t0 before frame 0,
    s = g (t0 dt + dt^2 / 2), and it was let go g t0^2 / 2 above z0, at x0.
    Nothing found, or an object wholly in the water by frame 1, is a GalileoError asking for
    the numbers."""
    import cv2

    from ...vision.background import MIN_BLOB_PX, clean, foreground, noise_sd

    ask = "give --release-x-m and --release-height-m"
    frames = np.asarray(frames)[..., :3]
    if frames.ndim != 4 or len(frames) < 3:
        raise GalileoError(f"finding where the object is let go needs at least three RGB frames: {ask}")
    cam, level, g = scene.camera, scene.tank.water_level_m, scene.gravity_mps2
    hw = frames.shape[1:3]
    scale = hw[1] / cam.width_px
    n = len(frames)
    later = frames[max(2, n - max(RELEASE_MIN_BACKGROUND, n // RELEASE_BACKGROUND_PART)):]
    background = np.median(later, axis=0).round().astype(np.uint8)
    region = _air_region(scene, hw, scale)
    noise = noise_sd(frames[-2:])      # (two frames with the object at rest: only the sensor's noise differs)

    def blobs(frame):
        """(centroid x, centroid z, top z) on the release plane of each component, the largest first."""
        fg = clean(((foreground(frame, background, noise) > 0) & region).astype(np.uint8) * 255) > 0
        _, labels, stats, _ = cv2.connectedComponentsWithStats(fg.astype(np.uint8), connectivity=8)
        area = stats[1:, cv2.CC_STAT_AREA]
        out = []
        for i in np.argsort(-area):
            if area[i] < max(MIN_BLOB_PX * scale ** 2, RELEASE_MIN_AREA * area.max(initial=0)):
                break
            ys, xs = np.nonzero(labels == 1 + i)
            px = (np.array([[xs.mean(), ys.mean()], [xs.mean(), ys.min() - 0.5]]) + 0.5) / scale - 0.5
            (x, _, z), (_, _, top) = backproject_to_plane(cam, px, 0.0)
            out.append((x, z, top))
        return out

    first = blobs(frames[0])
    if not first:
        raise GalileoError(f"no object found above the water in the first frame (it is let go later, or does not "
                           f"fall into the tank): {ask}")
    x0, z0, top0 = max(first, key=lambda b: b[1])
    below = [b for b in blobs(frames[1]) if b[2] <= top0 + 0.005]   # (it falls: half a centimetre's leeway)
    if not below:
        raise GalileoError(f"the object found in the first frame is not found above the water in the second "
                           f"(it is in the water already): give --release-height-m (found at x = {x0:.3f} m)")
    top1 = min(below, key=lambda b: math.hypot(b[0] - x0, b[2] - top0))[2]
    if top1 <= level + 0.002:
        raise GalileoError(f"the object is in the water by the video's second frame: give --release-height-m "
                           f"(found at x = {x0:.3f} m)")
    dt = 1.0 / cam.fps
    t0 = max((top0 - top1) / (g * dt) - dt / 2, 0.0)
    return float(x0), float(z0 + g * t0 ** 2 / 2 - level)


# -- the overlay --------------------------------------------------------------------------------------

TANK_RGB, BACK_RGB, WATER_RGB, RELEASE_RGB = (255, 220, 0), (200, 170, 60), (0, 200, 230), (40, 220, 60)
RELEASE_MARK_M = 0.01     # the release point's cross: this far each way


def draw_overlay(frame_rgb: np.ndarray, scene, clicks=None) -> np.ndarray:
    """The frame with the scene's tank (front face yellow, the rest of its inside darker), the
    water's surface (cyan), the release point and its fall line to the water (green) projected
    by the scene's camera, and the clicks (red, numbered 1-6)."""
    img = np.ascontiguousarray(frame_rgb[..., :3]).copy()
    cam, t = scene.camera, scene.tank
    sx, sy, sz = t.size_m
    front = front_corners(sx, sy, sz)
    back = front + [0.0, sy, 0.0]
    draw_lines(img, cam, back, BACK_RGB)
    for a, b in zip(front, back):
        draw_lines(img, cam, [a, b], BACK_RGB, closed=False)
    draw_lines(img, cam, front, TANK_RGB)
    x, y = sx / 2, sy / 2
    draw_lines(img, cam, [[-x, -y, t.water_level_m], [x, -y, t.water_level_m], [x, y, t.water_level_m],
                          [-x, y, t.water_level_m]], WATER_RGB)
    r = np.asarray(scene.release_m, float)
    d = RELEASE_MARK_M
    for axis in np.eye(3):
        draw_lines(img, cam, [r - d * axis, r + d * axis], RELEASE_RGB, closed=False)
    draw_lines(img, cam, [r, [r[0], r[1], t.water_level_m]], RELEASE_RGB, closed=False)
    if clicks is not None:
        draw_clicks(img, clicks)
    return img


EXAMPLE_WATER_X = (-0.25, 0.25)   # the example's water-line points: at these fractions of the width from the middle


def example(scene) -> tuple[np.ndarray, dict]:
    """The world points a user would click in a video of `scene` (the front face's inner corners,
    two points on the water line along the front glass), and the numbers they would give (the
    focal length too: a tank filmed face-on, as the dataset's, does not show it)."""
    t = scene.tank
    (sx, sy, sz), level = t.size_m, t.water_level_m
    water = [[f * sx, -sy / 2, level] for f in EXAMPLE_WATER_X]
    rx, _, rz = scene.release_m
    return (np.concatenate([front_corners(sx, sy, sz), water]),
            {"tank_width_m": sx, "tank_depth_m": sy, "tank_height_m": sz, "focal_px": float(scene.camera.K[0, 0]),
             "release_x_m": rx,
             "release_height_m": rz - level})


CALIBRATION = Calibration("an object dropped into a tank of water", POINTS, FIELDS, solve, draw_overlay, describe,
                          example)
