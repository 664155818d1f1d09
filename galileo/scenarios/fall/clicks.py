"""The fall's own-video calibration (`galileo scene --scenario fall`, the upload page): a fall
scene for a user's video of an object dropped onto a flat surface, from the four corners of a
rectangle of known size on that surface (a table's top) clicked on the video's first frame.

The user marks the rectangle's corners in this order: near left, near right, far right, far
left ("near": the camera's end, lower in the image; "left" as the camera sees it), and gives
its length (near edge to far edge) and width (left to right). In the scene's world frame (z up,
the surface z = 0, the origin at the rectangle's centre, x away from the camera's end) these
corners are `scene.surface_corners_m`, so the camera follows from them
(`galileo.clicks.camera_from_plane`, the pose by OpenCV's planar PnP):

* the focal length, where not given, from the rectangle's homography (principal point at the
  image centre, square pixels): with both sides known, the image of a rectangle fixes it. It
  depends on the rectangle's aspect ratio (length over width), not its scale: a wrong ratio
  gives a wrong focal length, and the same ratio at another size only scales the world. Where
  the rectangle is seen so nearly face-on (camera straight above it) that a pixel's error in
  the clicks moves the estimate by more than `galileo.clicks.MAX_FOCAL_SPREAD_PER_PX`, or no
  focal length fits at all, the focal length is that of a DEFAULT_HFOV_DEG horizontal field of
  view instead, and `describe` says so (give --focal-px);
* the clicks are 8 numbers, the camera with an estimated focal length 7 (its pose and focal
  length): the one left over is what the reprojection error (pixels) checks, how well a centred
  principal point and square pixels fit the clicks (exact clicks: 0 up to rounding; the
  Physics 101 clips: 1.3 px). It checks little else; the overlay (the rectangle, the world
  axes and a 10 cm grid on the surface) is the check. With a given focal length the error says
  how well the clicks agree with the stated rectangle.

Rounded corners (a folding table's): click where the straight edges would meet, not the
rounded corner itself. A corner out of the frame (a near edge just below the image) cannot be
clicked: click the side edge where it leaves the frame and give the length of the rectangle
that these points span (`bench/bench_fall_clicks.py` measures what such choices do to the focal
length on the Physics 101 clips).
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ...camera import FOCAL_PX, physics_hz
from ...clicks import (
    DISTORTION,
    MAX_FOCAL_SPREAD_PER_PX,
    MAX_REPROJECTION_PX,
    MIN_CORNER_SINE,
    Calibration,
    Field,
    NameField,
    Point,
    camera_from_plane,
    check_quad,
    draw_clicks,
    draw_lines,
    focal_from_homography,
    focal_spread_per_px,
    focal_through_lens,
    rms_px,
)
from ...errors import GalileoError
from ...fields import Bound
from ...shapes import SHAPE_CLASSES, Shape
from .scene import SIM_HZ, SURFACE_KINDS, SURFACE_SIZE, FallScene, surface_corners_m

DEFAULT_HFOV_DEG = 65.0      # where the rectangle does not fix the focal length: the image width / (2 tan(this /
# 2)), a phone's main camera (26 mm equivalent: 69 deg) or a webcam's (60-78 deg); a Kinect v2's colour camera
# (Physics 101) sees 84 deg
MAX_CAMERA_DISTANCE_M = 50.0  # the camera at most this far from the rectangle's centre: a drop onto a table is
# filmed from a few metres; farther, the size (metres?) or the focal length is wrong
OBJECT_SIZE = Bound(0.0, 5.0, lo_open=True)   # each of the object's sizes, as a fall scene file's shape allows
SURFACE = "the surface's rectangle"

POINTS = (Point("near left", "the rectangle's corner at the camera's end, on the left (lower left in the image); "
                             "a rounded corner: where its two straight edges would meet"),
          Point("near right", "the corner at the camera's end, on the right (lower right)"),
          Point("far right", "the far corner on the right (upper right)"),
          Point("far left", "the far corner on the left (upper left)"))
ORDER = tuple(p.name for p in POINTS)


NAMED = "the latents e_<object>_<surface>, mu_<object>_<surface>"   # what the name fields name

FIELDS = (
    Field("length_m", "Length", "m", FallScene.surface_size_m[0], "the rectangle's length, from its near edge (the "
          "camera's end) to its far edge", SURFACE_SIZE, required=True),
    Field("width_m", "Width", "m", FallScene.surface_size_m[1], "the rectangle's width, left to right",
          SURFACE_SIZE, required=True),
    Field("focal_px", "Focal", "px", None, "the camera's focal length in pixels; not given: estimated from the "
          "rectangle (principal point at the image centre, square pixels), or where it is seen too nearly face-on, "
          f"a {DEFAULT_HFOV_DEG:g} deg horizontal field of view", FOCAL_PX),
    DISTORTION,
    NameField("object", "Object", "id", FallScene.object, "the object's name: videos of the same object on the same "
              "surface share its restitution and friction there", names=NAMED),
    NameField("surface", "Surface", "id", FallScene.surface, "the surface's name (this table, this foam mat): "
              "videos of the same object on it share their restitution and friction", names=NAMED),
    Field("surface_kind", "Surface kind", "", FallScene.surface_kind, "what the surface is",
          choices=SURFACE_KINDS),
    Field("object_shape", "Shape", "", FallScene().shape.name, "the object's shape (a cylinder lies on its side, "
          "its axis along x; a torus lies flat)", choices=tuple(SHAPE_CLASSES)),
    Field("object_size_m", "Size", "m", FallScene().shape.size_m, "the object's size x, y, z: a box's sides, a "
          "cylinder's length and diameter twice, a torus's outer diameter twice and tube diameter", OBJECT_SIZE,
          size=3),
)


def default_focal_px(width_px: int) -> float:
    return width_px / (2 * math.tan(math.radians(DEFAULT_HFOV_DEG) / 2))


def check_corners(uv: np.ndarray) -> None:
    """A GalileoError unless the four clicks are the rectangle's corners in ORDER as a camera at
    its near end sees them: a convex quadrilateral (not crossing itself, no corner inside the
    other three, no three on a line), the near edge (clicks 1-2) below the far edge (3-4), left
    to the left (anticlockwise on the screen: near left, near right, far right, far left)."""
    order = ", ".join(ORDER)
    sides = [uv[(i + 1) % 4] - uv[i] for i in range(4)]
    turns = [float(a[0] * b[1] - a[1] * b[0]) for a, b in zip(sides, sides[1:] + sides[:1])]
    positive = [t > 0 for t in turns]
    if sum(positive) in (1, 3):     # (a quadrilateral crossing itself turns two ways twice)
        i = positive.index(sum(positive) == 1)      # the corner turning against the other three (more than a
        # straight line's noise: else check_quad's "on one line") lies inside their triangle
        if abs(turns[i]) > MIN_CORNER_SINE * np.linalg.norm(sides[i]) * np.linalg.norm(sides[(i + 1) % 4]):
            raise GalileoError(f"the four points are not the corners of a convex quadrilateral (one is inside the "
                               f"triangle of the other three): click the corners of {SURFACE}, in the order {order}")
    check_quad(uv, ORDER, SURFACE)
    if uv[:2, 1].mean() <= uv[2:, 1].mean():
        raise GalileoError("the near edge (points 1-2) is above the far edge (points 3-4) in the image: click the "
                           f"near corners first (the camera's end, lower in the image), in the order {order}")
    if turns[0] > 0:
        raise GalileoError(f"the left and right corners are swapped: click them in the order {order} (left as the "
                           "camera sees it)")


def estimate_focal_px(uv: np.ndarray, corners_m: np.ndarray, width_px: int, height_px: int) -> float | None:
    """The focal length (pixels) that makes the clicks the image of the rectangle (principal
    point at the image centre, square pixels); None where the rectangle does not fix it: no
    focal length fits, or a pixel's error in the clicks moves it by more than
    MAX_FOCAL_SPREAD_PER_PX (seen nearly face-on)."""
    import cv2

    cx, cy = width_px / 2, height_px / 2
    plane = np.ascontiguousarray(corners_m[:, :2])      # the surface's own x, y: orthonormal plane coordinates
    hom, _ = cv2.findHomography(plane, uv)
    if hom is None:
        return None
    try:
        focal = focal_from_homography(hom, cx, cy, SURFACE)
        spread = focal_spread_per_px(plane, uv, cx, cy, SURFACE)
    except GalileoError:
        return None
    return focal if spread <= MAX_FOCAL_SPREAD_PER_PX and FOCAL_PX.contains(focal) else None


def solve(uv: np.ndarray, v: dict, video_info, frames):
    """The calibration's solver: the camera from the four corners (see the module), the scene
    around it with the numbers (nothing is looked for in the frames). The error: the RMS
    distance (pixels) of the clicks from the rectangle's projected corners."""
    shape = Shape(v["object_shape"], tuple(float(s) for s in v["object_size_m"]))
    problem = shape.problem()
    if problem:
        raise GalileoError(f"--object-size-m: {problem}")
    check_corners(uv)
    fps = float(video_info.fps)
    scene = FallScene(object=v["object"], surface=v["surface"], surface_kind=v["surface_kind"],
                      surface_size_m=(float(v["length_m"]), float(v["width_m"])), shape=shape, fps=fps,
                      n_frames=int(video_info.n_frames), sim_hz=physics_hz(FallScene.sim_hz, fps, SIM_HZ))
    corners = surface_corners_m(scene)
    focal, k1 = v["focal_px"], v["distortion"]
    if focal is None:
        focal = focal_through_lens(lambda c: estimate_focal_px(c, corners, video_info.width_px, video_info.height_px),
                                   uv, video_info, k1)
        focal = default_focal_px(video_info.width_px) if focal is None else focal
    cam = camera_from_plane(uv, corners, video_info, facing=np.array([0.0, 0.0, 1.0]), focal_px=focal, what=SURFACE,
                            k1=k1)
    distance = float(np.linalg.norm(cam.position_in_world))
    if distance > MAX_CAMERA_DISTANCE_M:
        raise GalileoError(f"a {scene.surface_size_m[0]:g} x {scene.surface_size_m[1]:g} m rectangle seen so puts "
                           f"the camera {distance:.0f} m from it (more than {MAX_CAMERA_DISTANCE_M:g}): check "
                           "--length-m and --width-m (in metres) and --focal-px")
    err = rms_px(cam.project(corners) - uv)
    if err > MAX_REPROJECTION_PX:
        raise GalileoError(f"the points disagree with a {scene.surface_size_m[0]:g} x {scene.surface_size_m[1]:g} m "
                           f"rectangle by {err:.1f} px (more than {MAX_REPROJECTION_PX:g}): check their order, "
                           "--length-m, --width-m and --focal-px")
    scene = replace(scene, camera=cam)
    scene.validate()
    return scene, err


def tilt_deg(cam) -> float:
    """How far the camera's optical axis points below the horizontal, degrees (90: straight down)."""
    return math.degrees(math.asin(float(np.clip(-cam.world_to_camera[2, 2], -1.0, 1.0))))


def describe(scene, v: dict) -> str:
    cam = scene.camera
    f = float(cam.K[0, 0])
    if v["focal_px"] is not None:
        focal = f"focal {f:.0f} px"
    elif f == default_focal_px(cam.width_px):
        focal = (f"focal {f:.0f} px (default: a {DEFAULT_HFOV_DEG:g} deg field of view; the rectangle is seen too "
                 "nearly face-on, or its points are too far off, to estimate it: give --focal-px)")
    else:
        focal = f"focal {f:.0f} px (estimated from the rectangle)"
    pos = cam.position_in_world
    L, W = scene.surface_size_m
    size = " x ".join(f"{100 * s:g}" for s in scene.shape.size_m)
    return (f"{focal}; camera {pos[2]:.2f} m above the surface, {np.linalg.norm(pos):.2f} m from the rectangle's "
            f"centre, looking {tilt_deg(cam):.0f} deg down; surface {scene.surface} ({scene.surface_kind}, its "
            f"rectangle {L:g} x {W:g} m), object {scene.object} ({scene.shape.name} {size} cm)")


# -- the overlay ---------------------------------------------------------------------------------------

RECT_RGB, GRID_RGB = (255, 220, 0), (235, 235, 235)
AXIS_RGB = ((230, 40, 40), (40, 200, 60), (60, 120, 255))   # x, y, z
GRID_STEP_M = 0.1            # the grid on the surface
AXIS_M = 0.2                 # the world axes' length, from the rectangle's centre


def draw_overlay(frame_rgb: np.ndarray, scene, clicks=None) -> np.ndarray:
    """The frame with the scene's rectangle (yellow), a 10 cm grid on the surface inside it
    (white, from its centre), the world axes at its centre (x red, y green, z blue, 20 cm) as
    the scene's camera sees them, and the clicks (red circles, numbered 1-4)."""
    img = np.ascontiguousarray(frame_rgb[..., :3]).copy()
    cam = scene.camera
    L, W = scene.surface_size_m
    for x in np.arange(-math.floor(L / 2 / GRID_STEP_M), math.floor(L / 2 / GRID_STEP_M) + 1) * GRID_STEP_M:
        draw_lines(img, cam, [[x, -W / 2, 0.0], [x, W / 2, 0.0]], GRID_RGB, closed=False)
    for y in np.arange(-math.floor(W / 2 / GRID_STEP_M), math.floor(W / 2 / GRID_STEP_M) + 1) * GRID_STEP_M:
        draw_lines(img, cam, [[-L / 2, y, 0.0], [L / 2, y, 0.0]], GRID_RGB, closed=False)
    draw_lines(img, cam, surface_corners_m(scene), RECT_RGB)
    for axis, rgb in zip(np.eye(3), AXIS_RGB):
        draw_lines(img, cam, [np.zeros(3), AXIS_M * axis], rgb, closed=False)
    if clicks is not None:
        draw_clicks(img, clicks)
    return img


def example(scene) -> tuple[np.ndarray, dict]:
    """The world points a user would click in a video of `scene` (the surface rectangle's
    corners) and the numbers they would give (its size, the names, the object; the focal length
    left to be estimated)."""
    numbers = {"length_m": scene.surface_size_m[0], "width_m": scene.surface_size_m[1], "object": scene.object,
               "surface": scene.surface, "surface_kind": scene.surface_kind, "object_shape": scene.shape.name,
               "object_size_m": tuple(scene.shape.size_m)}
    return surface_corners_m(scene), numbers


CALIBRATION = Calibration("an object dropped onto a flat surface, filmed from above one end", POINTS, FIELDS, solve,
                          draw_overlay, describe, example)
