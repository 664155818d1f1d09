"""Ramp tracking: pixels -> observations (Galileo section 3.1, splash abstract's bottom-up model).

Pipeline, for a video and a scene file whose camera describes it:

0. Stabilisation (`galileo.vision.stabilise`): every frame registered to frame 0 against the
   background (the objects' starts left out) and brought to its exposure and white balance, so
   that a phone on a table, a webcam or a phone in a hand look bolted down and evenly lit to
   what follows; what it removed goes in `Tracks.camera` and, where it is much, in a note.
1. Background model: OpenCV MOG2 with five mixture components, learned from the video
   itself. Backwards over the last third at half resolution, it gives the scene as it
   ends: at frame 0 that shows every object that later leaves its start (a forward model
   cannot, it starts from frame 0). Forwards over all frames at quarter resolution, it
   gives the scene as it starts, against which the last frame shows whether anything moved.
   (Bounded for any video, `galileo.vision.background`: the end's model learns from at
   most MODEL_MAX_FRAMES frames of the last third, evenly spaced, and a video larger than
   1080p runs both at less than half resolution.) A frame most of which differs from frame
   0 (noise, a cut, a hand over the lens: `not_the_scene`) shows something else: it is
   left out of both models, no object is seen in it, and tracking goes on from the last
   frame that showed the scene (the constant-velocity prediction spanning the gap).
2. Detection and roles: the ramp object is the uphill-most foreground component at frame 0
   within the band of start positions its offset prior allows that reaches the ramp's surface
   (the frame-0 foreground also holds "ghosts" where objects come to rest later, and a shadow
   that the end's background shows above the ramp); the target is where the scene file puts
   it, with the size it states.
3. Bottom-up recognition: from the frame-0 silhouette, the shape type from the object's
   appearance (a small CNN, `galileo.vision.shapenet`; side views of boxes and cylinders have the
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
   `visible: false` with null position and velocity, never invented, and never held: an
   object tracked where frame 0 shows the empty scene (nothing there at the start or the end,
   and no object's start) and nothing differs from it (`_absent`: features that slid onto the
   ramp or the ground hold a still track where nothing is) is lost since it began to be, those
   frames not seen, and searched for again. Each track's own position noise
   (`ObjectTrack.position_sd_m`, `galileo.vision.velocity.position_noise`: from its third
   differences where it moves) tells the likelihood how far to trust it.

Where the objects can be (`object_region`: on the ramp and the ground, up to 1.5 times the
largest size above them) bounds what counts as motion: something that moves elsewhere (a
person walking by, a shadow on the wall, a hand at the frame's edge) is left out, with a
note (`DISTRACTOR_NOTE`); a video is still when nothing differs between its start and end
where the objects start (`_start_band`, the target's place) and nothing in that region
differs at its end from its start (in a piece at least STILL_MIN_SHARE of the smaller object's
silhouette: a shaken frame's edges leave slivers). Frame 0 differs from the end only where it differs from the
scene as it ends and from each of its last END_AGREE_FRAMES frames: a shadow that passes a still
object while the end is learned leaves its ghost in the end's model, but not in every one of
those frames, while an object that has left its start is gone from all of them.

The video is streamed (`galileo.video.VideoStream`): one pass learns the background models,
a second tracks, holding the frame before; memory does not grow with the video's length.
Before any of it, a scene whose camera sees none of it (ramp, object, target) is refused.
The tracks carry notes for a video whose frames are unevenly timed (a variable frame rate)
and for an object seen in few of its frames.

A video in which nothing moves (no foreground at its start or its end) is evidence, not an
error: every object is reported where the scene file puts it, at rest in every frame, with
a note (`held_still`); inference then finds the ramp object's friction at least tan of the
ramp angle and the masses unidentified.

The steps' general parts live in `galileo.vision` (background, silhouette, klt, pose,
tracker, velocity, shapenet); this module holds what is the ramp's own: where objects
rest (the ramp or the ground), where the ramp object may start, and the orchestration.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...progress import tqdm
from ...camera import backproject_to_plane, check_sees
from ...datatypes import ObjectTrack, Tracks
from ...errors import GalileoError
from ...shapes import SHAPE_TYPES, Shape, shape_class
from ...video import VideoStream, yuv_to_rgb
from ...vision import shapenet
from ...vision.background import (MIN_BLOB_PX, MODEL_MAX_FRAMES, MOG_SCALE, blobs, clean, dilate, erode, foreground,
                                  frames_at, full_res, largest_area, largest_component, mask_at, mog2, mog2_background,
                                  mostly_within, noise_sd, not_the_scene, resize_to, scaled, spread, touching, work_scale,
                                  yuv_image)
from ...vision.draw import draw_tracks
from ...vision.klt import flow
from ...vision.pose import rot_y
from ...vision.silhouette import fill_polygon, fit_silhouette, project_silhouette, slide_silhouette
from ...vision.stabilise import Stabilised
from ...vision.tracker import ObjectTracker, rarely_seen_notes
from ...vision.velocity import position_noise, velocity_from_positions
from .scene import Scene

END_MODEL_MIN_FRAMES = 10  # the end's background model: the last third of the video, at least this many frames
END_MODEL_PART = 3
END_AGREE_FRAMES = 3       # a still video: frame 0 differs from the end where it differs from each of these last frames,
STILL_MIN_SHARE = 0.2      # ... and moves when the largest piece of that difference at the objects' starts is at least
                           # this share of the smaller object's silhouette as the scene file puts it (an object that has
                           # left uncovers most of its own; a shaken frame's edges leave slivers)
START_MODEL_SCALE = 0.5    # the start's background model runs at this scale of MOG_SCALE (quarter resolution)
NEAR_MODEL_PX = 1          # full-resolution frame-0 foreground: within this many pixels of the models' (a square of
# 2 x 1 / scale + 1 px: 5 at half resolution, 9 at a 4K video's quarter)
BAND_FLOOR_M = 0.002       # the band of start positions begins this far above the ramp's surface
MIN_AREA_FRACTION = 0.25   # detection: components smaller than this fraction of the largest are noise
CONTACT_M = 0.02           # detection: the ramp object at its start reaches the strip this high above the ramp ...
CONTACT_PX = 6             # ... to within this many pixels (a scene from clicks is a few pixels off)
ON_RAMP_SHARE = 0.5        # ... and is preferred among frame 0's differences that lie at least this much (by area,
ON_RAMP_JOIN_PX = 5        # pieces within this many pixels taken as one) on the ramp, up to the largest size the prior
                           # allows above it
MIN_INIT_M = 0.005         # silhouette fit: sizes start at least this large
MIN_HEIGHT_M = 1e-3        # measured height floored at this
FIT_PAD_PX = 30            # silhouette fit: margin around the observed silhouette
RELOCATE_PAD_PX = 20       # re-acquisition: margin around the blob ...
RELOCATE_RANGE_M = 0.05    # ... and how far along its support the object may be from the blob's centre
OTHERS_MARGIN_PX = 9       # features keep off other objects' predicted silhouettes grown by this
REACQUIRE_PX = 31          # a lost object is searched for in its predicted silhouette grown by this
RESEED_ERODE_PX = 5        # re-seeding stays this far inside the predicted silhouette
REACQUIRE_AREA_RATIO = 4.0 # ... among blobs at most four times the area of its silhouette
REACQUIRE_G_MPS2 = 9.81    # ... grown by how far from its constant-velocity prediction an object accelerated at
REACQUIRE_MAX_M = 0.15     # up to g can be after the frames it has been lost (1/2 g t^2, at most this; in pixels at
# the ramp's foot), and no further back (up the ramp, or back along the ground) than
REACQUIRE_BACK_M = 0.03    # this from where it was last seen
PRESENT_MIN_FRACTION = 0.1 # a tracked object is there when at least this share of its silhouette (outside every
# object's start) differs from the empty scene ...
ABSENT_FRAMES = 2          # ... and lost when it is not, this many frames running: those frames are marked not
# seen (features that slid onto the ramp or the ground would otherwise hold a still track where nothing is)
JUDGED_MIN_FRACTION = 0.5  # judged only when at least this share of its silhouette lies outside the starts
REGION_HEIGHT_FACTOR = 1.5 # where the objects can be: up to this times the largest size their prior allows above the
REGION_GROUND_M = 3.0      # ramp (downhill of the highest start) and the ground (this far beyond the ramp's foot);
# what moves elsewhere (a person walking by, a shadow on the wall, a hand at the frame's edge) is not an object
STABILISE_MARGIN_PX = 15  # stabilisation registers on the background away from the objects' starts by this
NEAR_DEPTH_M = 0.01       # points nearer the camera than this (or behind it) do not project
ROLE_COLORS = {"ramp": (255, 80, 40), "target": (40, 160, 255)}  # debug video


# -- the ramp's geometry ------------------------------------------------------------------------

@dataclass
class _Frame0:
    """An object's silhouette at frame 0, measured in its support frame."""
    mask: np.ndarray
    shape: Shape
    center_xz: np.ndarray     # object centre (world x, z)
    phi0: float               # orientation of the object x axis in the x-z plane
    s_along_m: float | None   # ramp object: distance of its centre up the ramp


def support_frame(scene: Scene, role: str) -> tuple[np.ndarray, np.ndarray, float]:
    """Unit vectors (x-z) along the support surface (downhill) and its normal, and phi."""
    if role == "ramp":
        a = scene.ramp.angle_rad
        return np.array([math.cos(a), -math.sin(a)]), np.array([math.sin(a), math.cos(a)]), -a
    return np.array([1.0, 0.0]), np.array([0.0, 1.0]), 0.0


def _pose_on_support(scene: Scene, role: str, along_m: float, height_m: float):
    """Centre (world) and rotation of an object resting on its support, `along_m` along it."""
    if role == "ramp":
        r = scene.ramp
        return -along_m * r.downhill + (height_m / 2) * r.normal, rot_y(r.angle_rad)
    return np.array([along_m, 0.0, height_m / 2]), np.eye(3)


def _resting(scene: Scene, role: str, shape_of, along_of):
    """posed(p) for the silhouette fits: the shape `shape_of(p)` resting on the support,
    `along_of(p)` along it."""
    def posed(p):
        shape = shape_of(p)
        centre, rot = _pose_on_support(scene, role, along_of(p), shape.height_m)
        return shape, rot, centre

    return posed


# -- bottom-up recognition ------------------------------------------------------------------

def _fit_silhouette(scene: Scene, role: str, mask: np.ndarray, kind: str, init: tuple[float, float, float, float]):
    """Least 1 - IoU between the observed silhouette and the projected 3-D shape.

    Unknowns: position along the support, and sizes (length, depth, height); the depth is
    seen through perspective (the end face of an object off the camera axis), so a silhouette
    can say little of it: each size is held within the scene's prior (`priors.size_m`; a
    shaken, blurred start's silhouette fitted a depth of 0.4 mm, which no scene holds).
    """
    cls = shape_class(kind)
    lo, hi = scene.priors.size_m

    def shape_of(p):
        length, depth, height = np.clip(np.exp(p[1:4]), lo, hi)
        return cls.from_measured(length, depth, height)

    p0 = np.array([init[0], *np.log(init[1:])])
    res = fit_silhouette(scene.camera, mask, _resting(scene, role, shape_of, lambda p: p[0]), p0, FIT_PAD_PX)
    return float(res.x[0]), shape_of(res.x), float(res.fun)


def _measure(scene: Scene, role: str, mask: np.ndarray, rgb: np.ndarray) -> _Frame0:
    cam = scene.camera
    along, normal, phi0 = support_frame(scene, role)
    ys, xs = np.nonzero(mask)
    w = backproject_to_plane(cam, np.c_[xs, ys].astype(float), 0.0)[:, [0, 2]]
    a, n = w @ along, w @ normal
    length, height = float(np.ptp(a)), float(max(n.max(), MIN_HEIGHT_M))
    mid = float((a.max() + a.min()) / 2)
    along0 = -mid if role == "ramp" else mid
    init = (along0, max(length, MIN_INIT_M), max(math.sqrt(length * height), MIN_INIT_M), max(height, MIN_INIT_M))
    kind = shapenet.classify(rgb, mask, cam, along, length, height)
    # without the classifier's weights: the shape whose projected silhouette fits best
    fits = [_fit_silhouette(scene, role, mask, k, init) for k in ((kind,) if kind else SHAPE_TYPES)]
    along_m, shape, _ = min(fits, key=lambda f: f[2])
    centre, _ = _pose_on_support(scene, role, along_m, shape.height_m)
    return _Frame0(mask, shape, centre[[0, 2]], phi0, along_m if role == "ramp" else None)


# -- detection ------------------------------------------------------------------------------

def _scene_mask(scene: Scene, index: int) -> np.ndarray:
    """Silhouette of object `index` where the scene file puts it (its box hull)."""
    pos, orn = scene.initial_pose(index)
    # rotation about y by the ramp angle (the only rotation initial poses use)
    ang = 2 * math.atan2(orn[1], orn[3])
    return project_silhouette(scene.camera, scene.objects[index].shape.box_corners(), rot_y(ang), pos) > 0


def _ramp_band_mask(scene: Scene, lo_m: float, hi_m: float, height_m: float) -> np.ndarray:
    """Image region above the ramp surface between lo_m and hi_m up the ramp."""
    cam, r = scene.camera, scene.ramp
    pts = []
    for s, h in ((lo_m, BAND_FLOOR_M), (hi_m, BAND_FLOOR_M), (hi_m, height_m), (lo_m, height_m)):
        p = -s * r.downhill + h * r.normal
        pts.append(cam.project(p))
    return fill_polygon(np.round(np.array(pts)).astype(np.int32), (cam.height_px, cam.width_px)) > 0


def _uphill_component(scene: Scene, mask: np.ndarray, contact: np.ndarray | None = None) -> np.ndarray | None:
    """The foreground component furthest up the ramp, as a convex silhouette; with `contact` (the
    strip just above the ramp's surface), among those that reach it (within CONTACT_PX) if any
    does: an object at rest on the ramp touches it, something in the air above it (a shadow on the
    wall behind) does not.

    A slow object's resting place can lie inside its band of start positions; its ghost
    there is always downhill of where it started, since objects only slide down.
    """
    if contact is not None:
        reach = touching(mask, dilate(contact, 2 * CONTACT_PX + 1))
        if blobs(reach, MIN_AREA_FRACTION):   # (none: a scene whose ramp is drawn off the video's, as it was)
            mask = reach
    big = blobs(mask, MIN_AREA_FRACTION)
    if not big:
        return None

    def up_the_ramp(blob):
        ys, xs = np.nonzero(blob)
        w = backproject_to_plane(scene.camera, np.c_[xs.mean(), ys.mean()], 0.0)[0]
        return -float(w[[0, 2]] @ support_frame(scene, "ramp")[0])

    return largest_component(max(big, key=up_the_ramp))

def _start_band(scene: Scene, height_m: float | None = None) -> np.ndarray:
    """Where the ramp object may start (the image region its offset prior allows), up to `height_m`
    above the ramp (default: the largest size its prior allows)."""
    pri, unit = scene.priors, scene.unit_m
    lo = (scene.start_units + pri.offset_units[0]) * unit - pri.size_m[1] / 2
    hi = (scene.start_units + pri.offset_units[1]) * unit + pri.size_m[1] / 2
    return _ramp_band_mask(scene, max(lo, 0.0), min(hi, scene.ramp.length_m),
                           pri.size_m[1] if height_m is None else height_m)


def object_region(scene: Scene, size_m: float | None = None) -> np.ndarray:
    """Where in the image the objects can be (boolean): on the ramp downhill of the highest start its
    prior allows and on the ground up to REGION_GROUND_M beyond the foot, up to REGION_HEIGHT_FACTOR
    times the largest object's size (`size_m`, default the largest the prior allows) above them and
    as far to either side. The whole image where that region reaches behind the camera."""
    cam, r, pri = scene.camera, scene.ramp, scene.priors
    size = pri.size_m[1] if size_m is None else size_m
    h, side = REGION_HEIGHT_FACTOR * size, size
    top = min(r.length_m, (scene.start_units + pri.offset_units[1]) * scene.unit_m + size)
    ramp = [-s * r.downhill + (0.0, y, 0.0) + up * r.normal for s in (0.0, top) for y in (-side, side) for up in (0.0, h)]
    ground = [np.array([x, y, z]) for x in (-side, REGION_GROUND_M) for y in (-side, side) for z in (0.0, h)]
    hw = (cam.height_px, cam.width_px)
    out = np.zeros(hw, bool)
    rot, t = cam.world_to_camera[:3, :3], cam.world_to_camera[:3, 3]
    for box in (np.array(ramp), np.array(ground)):
        if np.any(box @ rot.T[:, 2] + t[2] <= NEAR_DEPTH_M):
            return np.ones(hw, bool)
        out |= project_silhouette(cam, box, np.eye(3), np.zeros(3)) > 0
    return out


def _detect_start(scene: Scene, fg0: np.ndarray) -> dict[str, tuple[np.ndarray, str]]:
    """Frame-0 silhouettes by role.

    The ramp object is searched in the band of start positions its offset prior allows:
    the foreground at frame 0 (against the background the video ends with) also holds
    "ghosts" where objects come to rest later, and these lie elsewhere, and whatever the end's
    background shows that frame 0 does not (a shadow passing): of what lies in the band, only what
    reaches the ramp's surface can be an object resting on it. The target is where the scene file
    puts it, with the size it states (its silhouette would merge with the ghost of a ramp object
    that stops against it).
    """
    found: dict[str, tuple[np.ndarray, str]] = {}
    band, contact = _start_band(scene), _start_band(scene, CONTACT_M)
    blob = _uphill_component(scene, _mostly_on_ramp(scene, fg0) & band, contact)
    if blob is None:   # (nothing that lies on the ramp: what reaches into the band, as before)
        blob = _uphill_component(scene, fg0 & band, contact)
    found["ramp"] = (blob, "motion") if blob is not None else (_scene_mask(scene, 0), "scene")
    if scene.target is not None:
        # the scene file states the target's kind, size and place: take them
        found["target"] = (_target_start(scene), "scene")
    return found


def _mostly_on_ramp(scene: Scene, fg0: np.ndarray) -> np.ndarray:
    """The parts of frame 0's foreground of which at least ON_RAMP_SHARE lies on the ramp, up to the
    largest size the prior allows above it (`mostly_within`). An object resting there lies there
    whole; the shadow of a person walking by the ramp's top reaches into the band of start
    positions with a small part of itself."""
    on_ramp = _ramp_band_mask(scene, 0.0, scene.ramp.length_m, scene.priors.size_m[1])
    return mostly_within(fg0, on_ramp, ON_RAMP_SHARE, ON_RAMP_JOIN_PX)


def _nothing_leaves(scene: Scene, differs: np.ndarray) -> bool:
    """Whether nothing left the objects' starts, given where the video's start and end differ
    (full resolution): objects that move leave where they start (what moves elsewhere is no object
    of the scene), uncovering most of their silhouettes; no piece of the difference there is as
    large as STILL_MIN_SHARE of the smaller object's silhouette (as the scene file puts it)."""
    leaving = dilate(_start_band(scene) | _target_start(scene), REACQUIRE_PX)
    smallest = min(np.count_nonzero(_scene_mask(scene, i)) for i in range(len(scene.objects)))
    return largest_area(differs & leaving) < max(STILL_MIN_SHARE * smallest, MIN_BLOB_PX)


def _target_start(scene: Scene) -> np.ndarray:
    """The target's silhouette where the scene file puts it (nothing without a target)."""
    hw = (scene.camera.height_px, scene.camera.width_px)
    return _scene_mask(scene, 1) if scene.target is not None else np.zeros(hw, bool)


def _x_in_plane(cam) -> np.ndarray:
    """Each pixel's x in the fall-line plane (y = 0; metres, (H, W)): where its ray meets it."""
    ys, xs = np.mgrid[0:cam.height_px, 0:cam.width_px]
    return backproject_to_plane(cam, np.c_[xs.ravel(), ys.ravel()].astype(float), 0.0)[:, 0].reshape(xs.shape)


def _of_its_size(mask: np.ndarray, near: np.ndarray, area_px: int) -> np.ndarray | None:
    """The largest component of `mask` whose centre lies in `near` and whose whole area is at most
    REACQUIRE_AREA_RATIO times `area_px`, as a convex silhouette (None if none is): a person walking
    by, a shadow or a hand reaching into the search window is larger than the object, however much
    of it the window holds (a smaller one may be the part of a slow object that has left its start)."""
    ok = [b for b in blobs(mask, 0.0) if np.count_nonzero(b) <= REACQUIRE_AREA_RATIO * area_px
          and near[tuple(np.round(np.argwhere(b).mean(axis=0)).astype(int))]]
    return largest_component(max(ok, key=np.count_nonzero)) if ok else None


def _relocate(scene: Scene, t: ObjectTracker, blob: np.ndarray) -> None:
    """Find a lost object again: its shape, resting on the ramp or the ground (whichever the
    blob is over), slid along that surface to fit the blob."""
    ys, xs = np.nonzero(blob)
    w = backproject_to_plane(scene.camera, np.array([[xs.mean(), ys.mean()]]), 0.0)[0]
    role = "ramp" if w[0] < 0 else "target"
    along, _, phi = support_frame(scene, role)
    a0 = float(w[[0, 2]] @ along) * (-1 if role == "ramp" else 1)
    a = slide_silhouette(scene.camera, blob, _resting(scene, role, lambda a: t.shape, lambda a: a),
                         (a0 - RELOCATE_RANGE_M, a0 + RELOCATE_RANGE_M), RELOCATE_PAD_PX)
    centre, _ = _pose_on_support(scene, role, a, t.shape.height_m)
    t.reset(np.array([centre[0], centre[2], -phi]))


def _agreed(models: "_SceneModels", starts: list[np.ndarray]) -> np.ndarray:
    """Where frame 0 shows the empty scene (at the models' scale): where it agrees with the scene as it
    ends (nothing there at either time; disagreement grown by a model pixel), outside the objects'
    start silhouettes (`starts`, full resolution: an object that never moves is in both)."""
    hw = models.small0.shape[:2]
    at_start = np.zeros(hw, bool)
    for mask in starts:
        at_start |= mask_at(mask, hw)
    return ~dilate((foreground(models.small0, models.bg_end, models.noise) > 0) | at_start, 3)


def _absent(t: ObjectTracker, occupied: np.ndarray, agreed: np.ndarray) -> bool:
    """Whether the empty scene shows where object `t` is tracked: fewer than PRESENT_MIN_FRACTION of
    its silhouette's pixels where the start and the end agree (`_agreed`; at the models' scale)
    differ from frame 0 there (`occupied`). Not judged (False) while less than JUDGED_MIN_FRACTION
    of the silhouette lies there (an object still at its start or already where it comes to rest)."""
    sil = mask_at(t.predicted_mask(), occupied.shape)
    judged = sil & agreed
    n = int(np.count_nonzero(judged))
    if n == 0 or n < JUDGED_MIN_FRACTION * np.count_nonzero(sil):
        return False
    return np.count_nonzero(occupied[judged]) < PRESENT_MIN_FRACTION * n


def _drop(t: ObjectTracker, first: int, last: int) -> None:
    """Object `t` was not where its track says in frames first..last: those frames not seen, and it
    lost (re-acquisition looks for it)."""
    t.visible[first:last + 1] = False
    t.center[first:last + 1] = np.nan
    t.lost = True
    t.pts, t.obj = np.zeros((0, 2), np.float32), np.zeros((0, 3))


DISTRACTOR_NOTE = ("something moved where the objects cannot be (a person walking by, a shadow, a hand at the frame's "
                   "edge?): it was left out of the tracking")


# -- a video in which nothing moves --------------------------------------------------------------

def still_note(scene: Scene) -> str:
    """What a video in which nothing moves says, for `Tracks.notes`."""
    angle = scene.ramp.angle_deg
    unknown = "the masses and the target's friction are" if scene.target is not None else "its mass is"
    return (f"nothing moves in this video: the objects are placed where the scene file puts them and held still "
            f"(their shapes and the ramp object's start are the scene file's: an object that never moves shows no "
            f"silhouette against the background); the ramp object's friction is at least tan({angle:g} deg) = "
            f"{math.tan(math.radians(angle)):.3f} and {unknown} not identified")


def held_still(scene: Scene, n_frames: int, shown: np.ndarray | None = None) -> Tracks:
    """Tracks of a video in which nothing moves: every object where the scene file puts it
    (`Scene.initial_pose`; the ramp object's offset the scene's own), seen in every frame
    (every frame `shown`: that shows the scene) at zero velocity, with the scene file's
    shapes and a note (`still_note`).

    The bottom-up recognition is not attempted: the background models hold the still
    objects themselves, so there is no silhouette to fit sizes and offset to (and the
    shape CNN reads the appearance inside one); the scene file's statement is all there is.
    Positions are the object centres in the fall-line plane (y = 0), as tracking reports.
    """
    cam = scene.camera
    objects = []
    for i, obj in enumerate(scene.objects):
        centre, _ = scene.initial_pose(i)
        vis = np.ones(n_frames, bool) if shown is None else shown.copy()
        pos = np.where(vis[:, None], [float(centre[0]), 0.0, float(centre[2])], np.nan)
        vel = np.where(vis[:, None], np.zeros(3), np.nan)
        objects.append(ObjectTrack(obj.name, obj.role, pos, vel, vis, obj.shape,
                                   obj.offset_units if obj.role == "ramp" else None, "scene",
                                   center_px=np.where(vis[:, None], cam.project(pos[0]), np.nan)))
    return Tracks(cam.fps, objects, [still_note(scene)]).check()


# -- the whole pipeline ------------------------------------------------------------------------

def scene_points(scene: Scene) -> dict[str, np.ndarray]:
    """What the camera should see of the scene (world points by name): the ramp's top surface's
    corners, the ramp object where it starts, the target where it stands."""
    r = scene.ramp
    parts = {"the ramp": np.array([-s * r.downhill + (0.0, y, 0.0) for s in (0.0, r.length_m)
                                   for y in (-r.width_m / 2, r.width_m / 2)]),
             "the ramp object's start": scene.initial_pose(0)[0]}
    if scene.target is not None:
        parts["the target"] = scene.initial_pose(1)[0]
    return parts


@dataclass
class _SceneModels:
    """What the first pass over a video keeps (see `_learn_scene`)."""
    y0: np.ndarray          # frame 0's luma and chroma planes
    uv0: np.ndarray
    small0: np.ndarray      # frame 0 at the models' scale (Y, U, V)
    noise: float            # sensor noise (levels), from frames 0 and 1
    bg_end: np.ndarray      # the scene as it ends (the models' scale)
    last: list[np.ndarray]  # the last END_AGREE_FRAMES frames the end is learned from (the models' scale)
    fg_last: np.ndarray     # the last frame against the scene as it starts (a mask, quarter of the models' scale;
                            # what a pixel's shift would explain left out: `foreground`'s shift_px)
    shown: np.ndarray       # (n,) whether each frame shows the scene (`not_the_scene`)


def _end_part(indices: np.ndarray) -> np.ndarray:
    """The frames the scene's end is learned from: the last third of `indices` (at least
    END_MODEL_MIN_FRAMES), at most MODEL_MAX_FRAMES of them. The last third only, so that a
    slow object's start is clear of it even if it lingered there for much of the video."""
    return spread(indices[-max(min(END_MODEL_MIN_FRAMES, len(indices)), len(indices) // END_MODEL_PART):],
                  MODEL_MAX_FRAMES)


def _learn_scene(video: Stabilised, n: int, scale: float, bar) -> _SceneModels:
    """The first pass: the background models (module docstring, step 1), frame 0, the noise,
    and which frames show the scene (frames that do not are left out of both models).

    The scene as it ends is learned backwards over the last third, from at most
    MODEL_MAX_FRAMES of its frames (kept in this pass; taken in another from the frames that
    show the scene, if some do not), the scene as it starts forwards over every frame as it
    comes (at START_MODEL_SCALE of the models' scale).
    """
    planned = set(_end_part(np.arange(n)).tolist())
    ends = []
    start_model = mog2(n)
    shown = np.ones(n, bool)
    first = noise = tiny = None
    for f, (y, uv) in enumerate(video.yuv()):
        bar.update()
        small = yuv_image(y, uv, scale)
        if f == 0:
            first = (y, uv, small)
        else:
            if f == 1:
                noise = noise_sd([first[2], small])
            if not video.fits[f].shown or not_the_scene(small, first[2], noise):
                shown[f] = False
                continue
        if f in planned:
            ends.append(small)
        tiny = scaled(small, START_MODEL_SCALE)
        start_model.apply(tiny)
    if not shown.all():
        ends = frames_at(video, _end_part(np.flatnonzero(shown)), scale)
    bg_end = mog2_background(ends, reverse=True)
    fg_last = foreground(tiny, start_model.getBackgroundImage(), noise, shift_px=1)
    return _SceneModels(*first, noise, bg_end, ends[-END_AGREE_FRAMES:], fg_last, shown)


def track(video_path: str | Path, scene: Scene, *, progress: bool = True,
          debug_video: str | Path | None = None) -> Tracks:
    """Track the scene's objects in a video; see the module docstring for the method.

    The video is decoded twice (three times with a debug video) and never held: the first
    pass learns the background models, the second tracks, keeping the frame before."""
    if scene.camera is None:
        raise GalileoError("the scene file has no camera: tracking needs one that describes the video")
    cam = scene.camera
    check_sees(cam, scene_points(scene))
    # the video must be the one the camera describes: its size, frame rate and length
    # (galileo.video.check_stream / check_length say why each is checked as it is)
    # registered to frame 0 against the background (the objects' starts left out) and to its exposure
    video = Stabilised(VideoStream(video_path, cam, min_frames=2),
                       exclude=dilate(_start_band(scene) | _target_start(scene), STABILISE_MARGIN_PX))
    n = int(cam.n_frames)   # the video's length (the first pass checks it)
    fps = cam.fps
    full_hw = (cam.height_px, cam.width_px)
    scale = work_scale(full_hw, MOG_SCALE)
    bar = tqdm(total=n, desc="tracking 1/2: learning the scene", unit="frame", disable=not progress)  # (a bar a pass)
    models = _learn_scene(video, n, scale, bar)
    notes = [note for note in (video.timing_note(),) if note] + video.notes()
    noise, bg_end, small0 = models.noise, models.bg_end, models.small0
    fg0_small = full_res(foreground(small0, bg_end, noise), full_hw)
    # (where it also differs from each of the last frames: a passing shadow's ghost in the end's model is not in all)
    fg0_end = fg0_small.copy()
    for frame in models.last:
        fg0_end &= full_res(foreground(small0, frame, noise), full_hw)
    # (the last frame against the start: less what a pixel's misregistration explains, since a stabilised
    # shaking camera leaves edges a fraction of a pixel off, and a still video read as moving on them)
    fg_last = full_res(models.fg_last, full_hw)
    region = object_region(scene)
    if largest_component((fg0_small | fg_last) & ~region) is not None:
        notes.append(DISTRACTOR_NOTE)
    if _nothing_leaves(scene, fg0_end | fg_last):
        bar.close()   # nothing moves: evidence in itself (the ramp object holds on the ramp)
        tracks = held_still(scene, n, models.shown)
        tracks.notes.extend(notes + rarely_seen_notes(tracks.objects))
        tracks.camera = video.motion().to_json()
        if debug_video is not None:
            write_debug_video(debug_video, (yuv_to_rgb(y, uv) for y, uv in video.yuv()), tracks, fps)
        return tracks

    # frame-0 foreground at full resolution, within a model pixel of the robust (half-resolution) one
    near = dilate(fg0_small, 2 * round(NEAR_MODEL_PX / scale) + 1)
    bg_full = resize_to(bg_end, full_hw)
    fg0 = near & (clean(foreground(yuv_image(models.y0, models.uv0, 1.0), bg_full, noise)) > 0)
    found = _detect_start(scene, fg0)
    first_rgb = yuv_to_rgb(models.y0, models.uv0)

    trackers: list[ObjectTracker] = []
    starts: list[tuple[_Frame0, str]] = []
    offsets: dict[str, int | None] = {}
    for i, obj in enumerate(scene.objects):
        mask, how = found[obj.role]
        if how == "scene":  # not seen apart from the background: where and what the scene file says
            pos, _ = scene.initial_pose(i)
            phi0 = support_frame(scene, obj.role)[2]
            f0 = _Frame0(mask, obj.shape, pos[[0, 2]], phi0, scene.start_distance_m(obj) if obj.role == "ramp" else None)
        else:
            f0 = _measure(scene, obj.role, mask, first_rgb)
        tr = ObjectTracker(f0.shape, f0.mask, np.array([f0.center_xz[0], f0.center_xz[1], -f0.phi0]), cam, n)
        tr.add_features(models.y0, mask)
        tr.fit(0)
        trackers.append(tr)
        starts.append((f0, how))
        if obj.role == "ramp":
            lo, hi = scene.priors.offset_units
            off = round(f0.s_along_m / scene.unit_m - scene.start_units)
            offsets[obj.name] = int(min(max(off, lo), hi))
    agreed = _agreed(models, [m for m, _ in found.values()])
    m_per_px = float(np.linalg.norm(cam.position_in_world) / cam.K[0, 0])   # a pixel's size at the ramp's foot
    # re-acquisition looks where objects of the sizes measured can be
    region = mask_at(object_region(scene, max(max(t.shape.size_m) for t in trackers)), small0.shape[:2])
    x_in_plane = None              # each pixel's x in the fall-line plane (made when an object is first lost)
    absent = [0] * len(trackers)   # frames running each object's track showed the empty scene
    frames = video.yuv()
    prev, _ = next(frames)   # (frame 0: done above)
    last = 0                 # the frame prev is: the last that shows the scene
    bar.set_description("tracking 2/2: following the objects", refresh=False)
    bar.reset(total=n)
    bar.update()
    for f, (gray, chroma) in enumerate(frames, start=1):
        bar.update()
        if not models.shown[f]:   # not the scene: nothing seen in it; tracking goes on from the last that was
            continue
        preds = [t.predict(f - last) for t in trackers]
        masks: dict[int, np.ndarray] = {}

        def predicted(j):  # computed only when a tracker needs to look around
            if j not in masks:
                masks[j] = trackers[j].predicted_mask(preds[j])
            return masks[j]

        def others_of(k):
            out = np.zeros(full_hw, bool)
            for j in range(len(trackers)):
                if j != k:
                    out |= dilate(predicted(j), OTHERS_MARGIN_PX)
            return out

        moving = None
        # one KLT call per window size for all objects' features (each call builds pyramids)
        live = [k for k, t in enumerate(trackers) if not t.lost]
        for win in sorted({trackers[k].win for k in live}):
            group = [k for k in live if trackers[k].win == win]
            pts = np.concatenate([trackers[k].pts for k in group])
            guess = np.concatenate([trackers[k].project(trackers[k].obj, preds[k]) for k in group])
            new, ok = flow(prev, gray, pts, guess, win)
            start = 0
            for k in group:
                t = trackers[k]
                m = len(t.pts)
                t.pts, t.obj = new[start:start + m][ok[start:start + m]], t.obj[ok[start:start + m]]
                start += m
        small = yuv_image(gray, chroma, scale)
        new_vs_start = foreground(small, small0, noise) > 0
        # something is there: it differs from frame 0 where frame 0 shows the empty scene, from both frame 0
        # and the scene's end elsewhere (where the objects start and end), and it is where objects can be
        occupied = new_vs_start & (agreed | (foreground(small, bg_end, noise) > 0)) & region
        for k, t in enumerate(trackers):
            if not t.lost:
                t.fit(f, preds[k])
                absent[k] = absent[k] + 1 if t.visible[f] and _absent(t, occupied, agreed) else 0
                if absent[k] >= ABSENT_FRAMES:   # tracked where nothing is: lost since the streak began
                    _drop(t, f - absent[k] + 1, f)
                    absent[k] = 0
            if t.lost:  # re-acquire it among the pixels where something is, near where it should be
                if moving is None:
                    moving = full_res(occupied.astype(np.uint8) * 255, full_hw)
                seen = np.flatnonzero(t.visible[:f])
                lost_s = (f - (seen[-1] if len(seen) else 0)) / fps
                grow = min(0.5 * REACQUIRE_G_MPS2 * lost_s ** 2, REACQUIRE_MAX_M) / m_per_px
                near = dilate(predicted(k), REACQUIRE_PX + round(grow))
                if len(seen):   # objects go down the ramp and on along the ground, never back
                    if x_in_plane is None:
                        x_in_plane = _x_in_plane(cam)
                    near &= x_in_plane >= t.center[seen[-1]][0] - REACQUIRE_BACK_M
                blob = _of_its_size(moving & ~others_of(k), near, np.count_nonzero(predicted(k)))
                if blob is not None:
                    _relocate(scene, t, blob)
                    t.add_features(gray, blob)
                    t.fit(f, t.pose)
            elif t.needs_features():
                t.add_features(gray, erode(t.predicted_mask(), RESEED_ERODE_PX) & ~others_of(k))
        prev, last = gray, f
    bar.close()

    objects = []
    for obj, t, (f0, how) in zip(scene.objects, trackers, starts):
        pos = np.full((n, 3), np.nan)
        vis = t.visible
        pos[vis, 0] = t.center[vis, 0]
        pos[vis, 1] = 0.0
        pos[vis, 2] = t.center[vis, 1]
        vel = velocity_from_positions(pos, vis, fps)
        centre_px = np.full((n, 2), np.nan)
        centre_px[vis] = cam.project(pos[vis])
        objects.append(ObjectTrack(obj.name, obj.role, pos, vel, vis.copy(), f0.shape, offsets.get(obj.name),
                                   how, position_sd_m=position_noise(pos, vis, fps), center_px=centre_px,
                                   features_px=t.features))
    tracks = Tracks(fps, objects, notes + rarely_seen_notes(objects),   # what `galileo track` writes
                    video.motion().to_json()).check()
    if debug_video is not None:
        write_debug_video(debug_video, (yuv_to_rgb(y, uv) for y, uv in video.yuv()), tracks, fps)
    return tracks


def write_debug_video(path: str | Path, frames_rgb, tracks: Tracks, fps: float) -> None:
    """The video with each object's features, centre, trail and role drawn over it (H.264)."""
    from ...video import write_video

    write_video(path, (draw_tracks(frame, tracks, f, ROLE_COLORS) for f, frame in enumerate(frames_rgb)), fps)
