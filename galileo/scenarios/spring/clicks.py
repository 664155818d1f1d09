"""The spring's own-video calibration (`galileo scene --scenario spring`, the upload page): a
spring scene for a user's side view of an object on a spring, from four points clicked on the
video's first frame and, where known, one measured length.

The user marks, in this order: the hanging point (where the spring meets the stand's arm); a
point on the hanging line straight below it (the spring's lower end or the object's centre at
rest, or any point of the plumb line through the hanging point); and the two ends of a segment
of known length in the spring's plane (the object's width, a ruler held beside the spring).
The numbers: that length, the object's and the spring's names (videos of the same object or
spring share its latents by name), `hang_m` where known, and the focal length where known. The
frame rate and frame count are the video's.

The model: a pinhole camera fronto-parallel to the spring's plane (its optical axis along the
plane's normal, world +y; principal point at the image centre, square pixels), rolled so that
the image direction from the first click to the second is the world's -z, standing at the
distance D = f L / l at which the segment's l pixels are L metres, and placed so that the
hanging point (`top_in_world_m`, the scene's default) projects onto the first click. Such a
camera maps the plane to the image by a similarity, which the four clicks fix exactly (the
second click's distance along the line and the segment's place and direction are free): its
reprojection error is 0 up to rounding and checks nothing, the overlay is the check. The focal
length sets only how far away the camera stands (what is out of the plane); not given, it is
the image width over 2 tan(DEFAULT_HFOV_DEG / 2).

Its error (mild perspective): a real camera turned by a small angle a (yaw or pitch) from the
plane's normal sees the plane in perspective, its scale changing across the image (along the
turn twice as fast as across it: foreshortening adds to depth). To first order in a, a point r
from the hanging point comes out misplaced by at most 4 r rho sin(a) / D, rho the largest
distance in the plane between it, the hanging point, the scale segment and the point the
camera looks at (the image's centre), D the camera's distance from the plane; the hanging point
and the hanging line's direction at it are exact. From 1.5 m, turned by 3 degrees, points up to
60 cm below the hanging point are off by 3-13 mm, depending on where the camera looks. The
period (stiffness over mass) needs no scale at all.

Without the length the scene is not metric (`metric: false`): the camera stands
NOMINAL_DISTANCE_M from the plane at the focal length given or the default (so at the default
1 m in the plane is about 0.8 image widths), the scale points are drawn but not used, and the
scenario infers `scale` (true length / the scene's; its prior 0.25-4 holds a camera 0.25-4 m
away at that focal length).
"""
from __future__ import annotations

import math

import numpy as np

from ...camera import (
    CAMERA_DISTANCE_M,
    FOCAL_PX,
    Camera,
    backproject_to_plane,
    physics_hz,
)
from ...clicks import (
    DISTORTION,
    Calibration,
    Field,
    NameField,
    Point,
    centred_intrinsics,
    draw_clicks,
    draw_lines,
    line_width,
    pinhole_clicks,
    rms_px,
)
from ...errors import GalileoError
from ...fields import Bound
from .scene import LENGTH, SIM_HZ, SpringScene, px_per_m

DEFAULT_HFOV_DEG = 65.0      # not given, the focal length is the image width / (2 tan(this / 2)): a phone's main
# camera (26 mm equivalent: 69 deg) or a webcam's (60-78 deg); it moves only where the camera stands, not the plane
NOMINAL_DISTANCE_M = 1.0     # without a length: the camera this far from the spring's plane (a bench-top stand)
MAX_ROLL_DEG = 30.0          # the hanging line at most this far from the image's vertical: a camera on a tripod or
# in a hand is rolled a few degrees; beyond this the points are out of order or the video is on its side
MIN_LINE_PX = 10.0           # the hanging line's two clicks and the scale's at least this far apart: a pixel's error
# in them is then at most 10% of the scale (6 degrees of the vertical)
SEGMENT = Bound(0.0, LENGTH.hi, lo_open=True)   # the scale segment's length, metres

POINTS = (Point("top", "the hanging point: where the spring hangs from (its top, at the stand's arm)"),
          Point("hanging line", "a point straight below the hanging point: the spring's lower end or the object's "
                                "centre at rest, or any point of the plumb line through the hanging point"),
          Point("scale start", "one end of a segment of known length in the spring's plane (the object's width, a "
                               "ruler held beside the spring)"),
          Point("scale end", "the segment's other end"))


NAMED = "the latents, e.g. m_<object>_kg, k_<spring>_Npm"   # what the name fields name

FIELDS = (
    Field("length_m", "Length", "m", None, "the length of the segment between the two scale points (the object's "
          "width, a ruler); not given: the scene is not metric (a nominal scale, the camera "
          f"{NOMINAL_DISTANCE_M:g} m away; the scenario infers the scale)", SEGMENT),
    NameField("object", "Object", "id", SpringScene.object, "the object's name: videos of the same object share "
              "its mass", names=NAMED),
    NameField("spring", "Spring", "id", SpringScene.spring, "the spring's name: videos of the same spring share its "
              "stiffness, own mass, damping and unloaded length", names=NAMED),
    Field("hang_m", "Hang", "m", SpringScene.hang_m, "from the spring's lower end to the object's centre (a hook, a "
          "bag's knot, half the object); an error in it moves the spring's unloaded length by as much", LENGTH),
    Field("focal_px", "Focal", "px", None, "the camera's focal length in pixels; not given: the image width / "
          f"(2 tan({DEFAULT_HFOV_DEG / 2:g} deg)), a {DEFAULT_HFOV_DEG:g} deg horizontal field of view (it sets only "
          "how far away the camera stands)", FOCAL_PX),
    DISTORTION,
)


def default_focal_px(width_px: int) -> float:
    return width_px / (2 * math.tan(math.radians(DEFAULT_HFOV_DEG) / 2))


def roll_deg(top_px, below_px) -> float:
    """The hanging line's angle from the image's vertical, degrees (positive: it leans right
    going down)."""
    dx, dy = np.subtract(below_px, top_px)
    return math.degrees(math.atan2(dx, dy))


def camera_from_clicks(uv, video_info, *, length_m: float | None = None, focal_px: float | None = None,
                       k1: float = 0.0) -> Camera:
    """The fronto-parallel camera of the module's model from the four clicks (their count,
    place in the frame and distinctness are `Calibration.check_clicks`'), the hanging point at
    the scene's default `top_in_world_m`; `length_m` None: at NOMINAL_DISTANCE_M; through a
    lens of distortion k1 (the clicks undistorted first: `pinhole_clicks`)."""
    w, h = video_info.width_px, video_info.height_px
    f = default_focal_px(w) if focal_px is None else float(focal_px)
    top_px, below_px, start_px, end_px = pinhole_clicks(np.asarray(uv, float), video_info, f, k1)
    line_px, seg_px = np.linalg.norm(below_px - top_px), np.linalg.norm(end_px - start_px)
    for what, n in (("top and hanging line points", line_px), ("two scale points", seg_px)):
        if n < MIN_LINE_PX:
            raise GalileoError(f"the {what} are {n:.1f} px apart, less than {MIN_LINE_PX:g}: a pixel's error in them "
                               f"would be {100 / n:.0f}% of the scale; click points farther apart")
    roll = roll_deg(top_px, below_px)
    if abs(roll) >= 180 - MAX_ROLL_DEG:
        raise GalileoError("the hanging line point is above the top: click a point straight below the hanging point "
                           "(the spring's lower end, the object's centre at rest)")
    if abs(roll) > MAX_ROLL_DEG:
        raise GalileoError(f"the hanging line is {abs(roll):.0f} deg from the image's vertical (more than "
                           f"{MAX_ROLL_DEG:g}): click a point straight below the hanging point (a video on its side "
                           "must be turned upright first)")
    distance_m = NOMINAL_DISTANCE_M if length_m is None else f * length_m / seg_px
    dx, dy = (below_px - top_px) / line_px              # the image of the world's -z
    # rows: the camera's x (image right), y (image down) and z (forward) axes in the world frame
    r = np.array([[dy, 0.0, -dx], [-dx, 0.0, -dy], [0.0, 1.0, 0.0]])
    k = centred_intrinsics(f, w, h)
    top = np.asarray(SpringScene.top_in_world_m, float)
    top_in_camera = np.r_[(top_px - k[:2, 2]) * distance_m / f, distance_m]
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, top_in_camera - r @ top
    cam = Camera(k, m, int(w), int(h), float(video_info.fps), int(video_info.n_frames), float(k1))
    if np.linalg.norm(cam.position_in_world) > CAMERA_DISTANCE_M:
        raise GalileoError(f"a {length_m:g} m segment {seg_px:.0f} px long puts the camera {distance_m:.0f} m from "
                           "the spring: check --length-m (in metres) and --focal-px")
    return cam


def solve(uv: np.ndarray, v: dict, video_info, frames):
    """The calibration's solver: the camera from the clicks, the scene around it (nothing is
    looked for in the frames). The error: the RMS distance (pixels) of the hanging point's
    click from where the camera puts it and of the hanging line's from that line's image (a
    line in the pinhole's image: measured there, the click undistorted), 0 up to rounding (see
    the module)."""
    cam = camera_from_clicks(uv, video_info, length_m=v["length_m"], focal_px=v["focal_px"], k1=v["distortion"])
    fps = float(video_info.fps)
    scene = SpringScene(object=v["object"], spring=v["spring"], hang_m=v["hang_m"], metric=v["length_m"] is not None,
                        fps=fps, n_frames=int(video_info.n_frames), sim_hz=physics_hz(SpringScene.sim_hz, fps, SIM_HZ),
                        camera=cam)
    scene.validate()
    top = np.asarray(scene.top_in_world_m, float)
    a, b = cam.undistort_px(cam.project(np.array([top, top - (0.0, 0.0, 1.0)])))
    (dx, dy), (wx, wy) = (b - a) / np.linalg.norm(b - a), cam.undistort_px(uv[1]) - a
    off_line = abs(float(dx * wy - dy * wx))
    return scene, rms_px(np.array([np.linalg.norm(cam.project(top) - uv[0]), off_line]))


def describe(scene, v: dict) -> str:
    cam = scene.camera
    top = np.asarray(scene.top_in_world_m, float)
    a, b = cam.project(np.array([top, top - (0.0, 0.0, 1.0)]))
    scale = px_per_m(cam, top)
    focal = f"focal {cam.K[0, 0]:.0f} px" + (f" (default: a {DEFAULT_HFOV_DEG:g} deg field of view)"
                                             if v["focal_px"] is None else "")
    roll = roll_deg(a, b)
    lean = f"leans {abs(roll):.1f} deg {'right' if roll > 0 else 'left'} of" if round(abs(roll), 1) else "is"
    text = (f"camera square to the spring's plane, the hanging line {lean} the image's vertical; {focal}; object "
            f"{scene.object} on spring {scene.spring}, hang {scene.hang_m:g} m; ")
    if scene.metric:
        return text + f"{cam.K[0, 0] / scale:.2f} m from the spring's plane: 1 cm is {scale / 100:.1f} px"
    return text + (f"not metric: a nominal scale (the camera {NOMINAL_DISTANCE_M:g} m away: 1 cm is {scale / 100:.1f} "
                   "px) that the scenario infers; give --length-m for a metric scene")


# -- the overlay ---------------------------------------------------------------------------------------

LINE_RGB, SCALE_RGB = (255, 220, 0), (40, 220, 60)
TICK_M = 0.1                 # ticks along the hanging line every this many (scene) metres


def _text(img: np.ndarray, text: str, at, color) -> None:
    """Text at pixel `at` (its lower left) on a dark box, to read on any background."""
    import cv2

    lw = line_width(img)
    x, y = round(float(at[0])), round(float(at[1]))
    font, size, thick = cv2.FONT_HERSHEY_SIMPLEX, 0.3 * lw, max(1, lw // 2)
    (w, h), base = cv2.getTextSize(text, font, size, thick)
    cv2.rectangle(img, (x - lw, y - h - lw), (x + w + lw, y + base + lw), (30, 30, 30), -1)
    cv2.putText(img, text, (x, y), font, size, color, thick, cv2.LINE_AA)


def draw_overlay(frame_rgb: np.ndarray, scene, clicks=None) -> np.ndarray:
    """The frame with the hanging point and the hanging line with ticks every 10 cm (yellow;
    every fifth longer) as the scene's camera sees them, the scale segment (green; the clicks back-projected
    onto the spring's plane) with its length, and the clicks (red, numbered 1-4)."""
    import cv2

    img = np.ascontiguousarray(frame_rgb[..., :3]).copy()
    cam = scene.camera
    lw = line_width(img)
    top = np.asarray(scene.top_in_world_m, float)
    scale = px_per_m(cam, top)
    down = np.array([0.0, 0.0, -1.0])
    reach_m = math.hypot(cam.width_px, cam.height_px) / scale       # to the frame's edge from anywhere in it
    draw_lines(img, cam, [top, top + reach_m * down], LINE_RGB, closed=False)
    ticks = cam.project(top + np.arange(1, int(reach_m / TICK_M) + 1)[:, None] * TICK_M * down)
    a, b = cam.project(np.array([top, top + down]))
    across = np.array([a[1] - b[1], b[0] - a[0]]) / np.linalg.norm(b - a) * 4 * lw
    for i, p in enumerate(ticks):
        h = across * (2 if (i + 1) % 5 == 0 else 1)
        for color, t in (((0, 0, 0), lw + 2), (LINE_RGB, lw)):
            cv2.line(img, tuple(np.round(p - h).astype(int)), tuple(np.round(p + h).astype(int)), color, t,
                     cv2.LINE_AA)
    cv2.drawMarker(img, tuple(np.round(a).astype(int)), LINE_RGB, cv2.MARKER_CROSS, 12 * lw, lw, cv2.LINE_AA)
    nominal = "" if scene.metric else " (nominal: no length given)"
    _text(img, f"hanging point and line, ticks every {100 * TICK_M:g} cm{nominal}", (8 * lw, 12 * lw), LINE_RGB)
    if clicks is not None and len(clicks) == len(POINTS):
        ends = backproject_to_plane(cam, np.asarray(clicks, float)[2:], top[1])
        draw_lines(img, cam, ends, SCALE_RGB, closed=False)
        length = 100 * np.linalg.norm(ends[1] - ends[0])
        label = f"{length:.1f} cm" if scene.metric else f"{length:.1f} cm (nominal)"
        uv = cam.project(ends)
        _text(img, label, (uv[:, 0].min(), uv[:, 1].max() + 14 * lw), SCALE_RGB)
    if clicks is not None:
        draw_clicks(img, clicks)
    return img


def example(scene) -> tuple[np.ndarray, dict]:
    """The world points a user would click in a video of `scene`: the hanging point, the
    spring's lower end with the object at rest, the ends of the object's width at its centre
    there; and the numbers they would give (its width as the length where the scene is metric,
    the focal length)."""
    from .physics import equilibrium_below_top_m, params

    top = np.asarray(scene.top_in_world_m, float)
    centre = top - (0.0, 0.0, equilibrium_below_top_m(params(scene)) / scene.scale)
    half = np.array([scene.size_m[0] / 2, 0.0, 0.0])
    numbers = {"length_m": scene.size_m[0] if scene.metric else None, "object": scene.object,
               "spring": scene.spring, "hang_m": scene.hang_m, "focal_px": float(scene.camera.K[0, 0])}
    return np.array([top, centre + (0.0, 0.0, scene.hang_m / scene.scale), centre - half, centre + half]), numbers


CALIBRATION = Calibration("an object bouncing on a spring, seen from the side", POINTS, FIELDS, solve, draw_overlay,
                          describe, example)
