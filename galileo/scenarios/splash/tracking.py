"""Splash tracking: pixels -> the object's positions, velocities, shape kind and volume.

0. Stabilisation (`galileo.vision.stabilise`): every frame registered to frame 0 against the
   tank and the wall (the column the object falls through, `fall_column`, left out) and brought
   to its exposure and white balance; what it removed goes in `Tracks.camera` and, where it is
   much, in a note. The object is looked for in that column only: what moves elsewhere (a
   person walking by, a shadow, a hand) is left out, with a note (`DISTRACTOR_NOTE`).
1. Background: MOG2 (five components, `galileo.vision.background`) learned backwards over
   the whole video gives the tank as the video ends, with the object where it comes to
   rest. Frame 0 against the median of the last frames (`_start_and_rest`) shows where the
   object starts (the highest region that moved: falling, or held at its release point) and
   where it comes to rest (the others; a lone region reaching below the water line is the
   resting place); the start's place takes the last frames' background, the resting
   place's, grown by END_ZONE_PX, the median of the first frames in which it still looks as
   in frame 0: a background without the object (a held object is not learnt into it).
   (Bounded for any video, `galileo.vision.background`: learned from at most
   MODEL_MAX_FRAMES frames, evenly spaced, at most 0.5 Mpx each.) A frame most of which
   differs from frame 0 (noise, a cut: `not_the_scene`) is left out of it, no object is
   seen in it, and tracking goes on from the last frame that showed the tank.
2. Foreground per frame against it, in air or water (the water's tint is in the background
   too): the object is one of its MAX_CANDIDATES largest components, the usable one nearest
   the centre predicted from its last (`_choose`; step 4 says what is usable). The largest
   would be a passer-by's shadow on the wall below a floater or beside a sinker.
3. KLT (`galileo.vision.klt`): good features inside the frame-0 silhouette, Lucas-Kanade
   from a constant-velocity guess with a forward-backward check, features that leave the
   foreground dropped, re-seeded inside the foreground when fewer than half survive (the
   tint changes the object's look as it enters the water).
4. The object's centre per frame: the centre of its silhouette's bounding box, corrected
   by the offset between the fitted 3-D shape's projected centre and its silhouette's
   box centre (the camera sees the top face too); where the silhouette is not usable
   (too small against the fitted shape's, or too large against it swept over the frame's
   travel, at most the last speed plus MAX_ACCEL_G x g since: a motion-blurred silhouette is
   a streak; or missing) the KLT motion of the
   features carries the last centre on. A centre farther from the last one than the
   object could move in the time between them (MAX_SPEED_MPS on the release plane) is
   dropped, the frame left without one. Back-projected onto the plane y = release_m[1]
   (the object falls straight down) it gives positions in metres; velocities by central
   differences (`galileo.vision.velocity`). Frames without either are `visible: false`. The
   track's own position noise (`position_sd_m`, from its third differences where it moves: a
   blurred, compressed or shaken video's is larger) is the likelihood's least noise.
5. Bottom-up kind and volume (`bottom_up`), measured on the BOTTOM_UP_MAX_FRAMES sharpest
   silhouettes: those whose centre moves least over a frame (`travel_px`), in the air (its
   bottom, and its streak's, AIR_MARGIN_PX above the water line) or wholly under the water (its
   top AIR_MARGIN_PX below the line) before it reaches the floor (landing, it may tip over);
   evenly spaced in time where more are as sharp (a falling object may turn). A thin object dropped from high streaks
   through the air to several times its own height and its corners are lost to the streak (a
   lying pole and a flat disc look alike); slowed by the water it shows its own outline. Each
   fitted (least 1 - IoU) by each kind at
   the release plane, sizes w (across) and H (high). The camera sees width and height, never
   depth: the depth assumption per kind, with its uncertainty (DEPTH_LOG_SD, the SD of the
   log of depth over its assumed value): a box's bottom is square (depth w; everyday blocks
   run from half to twice as deep as wide: log 2 / 1.645), a vertical cylinder round (depth
   w; a slightly oval one: log 1.2 / 1.645), a horizontal cylinder's depth its diameter H
   (it may lie turned: log 1.5 / 1.645). Volumes: box w^2 H, vcyl pi/4 w^2 H, hcyl pi/4 H^2 w.
   Motion blur: a silhouette of a moving object is a streak, its extent along each image axis
   the object's own plus the shutter's open share of the distance its centre moves in a frame
   there (`travel_px`, from the track); the share is measured from how the extents grow with
   that distance over the frames (`exposure_share`: uniform on [0, 1], each extent known to
   EXTENT_SD_PX) and each fitted size shortened by its streak (at most halved); the share's
   uncertainty goes into the volume's.
   `kind_probs`: a softmax of the kinds' mean losses, at a temperature of the frame-to-frame
   spread of the loss differences, and at least the IoU's own resolution (the outline moved
   by BOUNDARY_PX: from a side view a box, an upright and a lying cylinder differ by a few
   outline pixels, so the kinds are often nearly equally probable, and said so). `kind`: the
   most probable; `volume_cm3`: its median per-frame volume; `volume_log_sd`: the depth
   assumption's, the frames' spread, a pixel on each size, the blur's share and the other kinds' volumes
   weighed by their probabilities, added in quadrature (inference's prior on the log of the
   volume over it is U(-2 sd, 2 sd)). The first BOTTOM_UP_FRAMES silhouettes give the
   shape the tracker centres silhouettes on (`first_guess`, its blur taken off alike).
6. The release (`_release`): the last frame at which the object's centre is within HOLD_PX
   of where it was first seen (`release_s`: its time; `held_frames`); null where it moves
   from its first frame (let go before the video starts). Inference puts the release's
   prior around it.

The video is streamed (`galileo.video.VideoStream`), never held; a scene whose camera sees
none of it (the tank, the release point) is refused before any of it. The tracks carry
notes for unevenly timed frames (a variable frame rate) and an object seen in few frames.

Note: the rendered videos open with the object held at its release point or already
falling through the air (released 12-20 cm above the water); either way its first
silhouettes are in the air. Under water the renderer draws no refraction. A real flat-walled
tank magnifies what is under water, which this does not correct: seen from a distance D
through water d deep behind the glass, by D / (D - d (1 - 1/1.33)) (2% for an object 8 cm
behind the glass filmed from a metre; up to 1.33 from close by), so sizes measured under the
water (item 5) read that much large.
"""
from __future__ import annotations

import math
from collections import deque
from pathlib import Path

import numpy as np

from ...camera import backproject_to_plane, check_sees
from ...datatypes import ObjectTrack, Tracks
from ...errors import GalileoError, StillVideo
from ...progress import tqdm
from ...shapes import Box, Cylinder
from ...video import VideoStream, write_video, yuv_to_rgb
from ...vision.background import (MIN_BLOB_PX, MODEL_MAX_FRAMES, blobs, clean, dilate, erode, foreground, frames_at, full_res,
                                  components, largest_component, mog2_background, noise_sd, not_the_scene, spread, work_scale,
                                  yuv_image)
from ...vision.draw import draw_tracks
from ...vision.klt import flow, klt_window, seed_features
from ...vision.pose import rot_y
from ...vision.silhouette import crop, fit_silhouette, project_silhouette, shape_silhouette
from ...vision.stabilise import Stabilised
from ...vision.tracker import rarely_seen_notes
from ...vision.velocity import position_noise, velocity_from_positions
from .scene import CM3, KINDS

EARLY_FRAMES = 4           # the resting place's background: median of at most this many first frames
END_ZONE_PX = 9            # the object's resting place, grown by this, takes the early background
GHOST_MIN_FRACTION = 0.2   # frame 0's foreground components this fraction of the largest's area count
N_FEATURES = 40
MIN_FEATURES = 4
BOTTOM_UP_FRAMES = 3       # the first silhouettes, fitted for the shape the tracker centres silhouettes on
BOTTOM_UP_MAX_FRAMES = 8   # silhouettes in the air fitted for kind and volume at most (evenly spaced; each
                           # costs three Nelder-Mead fits, ~0.1 s)
FIT_PAD_PX = 20
AIR_MARGIN_PX = 3          # in the air: the object's bottom this many pixels above the water line at least
                           # (the surface's sheen and the waterline are a band a few pixels high)
ENTRY_PX = 3               # it has entered the water when its bottom comes within this of the water line
                           # (a floater with a 2 mm draft: its bottom is a few pixels below it, the surface's
                           # band hides them)
HOLD_PX = 2.0              # held: the centre within this of where it was first seen (the silhouette's box
                           # centre is good to about a pixel; a fall from rest moves it ~5 px in the first
                           # frame at 30 fps, 1 mm/px)
# the depth the camera cannot see, per kind: the SD of the log volume its assumption leaves (module docstring)
BOUNDARY_PX = 0.5          # a silhouette's outline is known to this (px): the kinds' fits resolve no finer
DEPTH_LOG_SD = {"box": math.log(2.0) / 1.645, "vcyl": math.log(1.2) / 1.645, "hcyl": math.log(1.5) / 1.645}
EXTENT_SD_PX = 1.0         # a silhouette's box extent is known to this (px): half a pixel at each end
EXPOSURE_GRID = np.linspace(0.0, 1.0, 41)   # the shutter's share of the frame interval: uniform prior, this grid
TRAVEL_WINDOW = 1          # a frame's travel from the centres seen within this many frames of it (a parabola
                           # through three: the water, a few frames on, slows the object)
DEBUG_COLORS = {"object": (255, 200, 0)}   # debug video (RGB)
FALL_HALF_WIDTH_M = 0.1    # the object falls within this of the release point's x (either side) ...
FALL_ABOVE_M = 0.1         # ... from up to this above it to the tank's floor: it is looked for there only (what
# moves elsewhere, a person walking by, a shadow on the wall, a hand at the frame's edge, is not the object), and
# stabilisation registers on the rest
DISTRACTOR_NOTE = ("something moved where the object cannot be (a person walking by, a shadow, a hand at the frame's "
                   "edge?): it was left out of the tracking")
AREA_OK = (0.6, 1.6)       # a silhouette is usable within these ratios of the fitted shape's area
MAX_SPEED_MPS = 3.0        # a centre farther than this x the time since the last one from it is dropped
                           # (free fall from the highest release reaches ~2 m/s at the water)
MAX_CANDIDATES = 4         # the largest components in the fall column a frame, tried nearest the predicted centre
                           # first (a passer-by's shadow on the wall below a floater is larger than it)
MAX_ACCEL_G = 2.0          # a silhouette's travel over a frame, for its swept area, at most the last speed plus
                           # this x g x the frames since (a floater's buoyancy lifts it at up to ~2 g) ...
TRAVEL_SLACK_PX = 2.0      # ... plus this (the centre's own error, the camera's residual shake)


def _shape(kind: str, w: float, h: float):
    """(galileo shape in its object frame, rotation object -> world) of a `kind` object w wide and h high."""
    if kind == "box":
        return Box((w, w, h)), np.eye(3)
    if kind == "vcyl":
        return Cylinder((h, w, w)), rot_y(-math.pi / 2)
    return Cylinder((w, h, h)), np.eye(3)


def volume_cm3(kind: str, w: float, h: float) -> float:
    if kind == "box":
        return w * w * h / CM3
    if kind == "vcyl":
        return math.pi / 4 * w * w * h / CM3
    return math.pi / 4 * h * h * w / CM3


def _bbox_centre(mask: np.ndarray) -> np.ndarray:
    ys, xs = np.nonzero(mask)
    return np.array([(xs.min() + xs.max()) / 2.0, (ys.min() + ys.max()) / 2.0])


def _bbox_extent(mask: np.ndarray) -> np.ndarray:
    """The mask's box extent (across u, along v; px)."""
    ys, xs = np.nonzero(mask)
    return np.array([np.ptp(xs) + 1, np.ptp(ys) + 1], float)


def _fit(cam, mask: np.ndarray, y_plane: float, kind: str):
    """(loss, centre (x, z), w, h) of the `kind` shape whose silhouette best fits the mask."""
    ys, xs = np.nonzero(mask)
    pts = backproject_to_plane(cam, np.c_[xs, ys].astype(float), y_plane)
    w0, h0 = max(float(np.ptp(pts[:, 0])), 0.004), max(float(np.ptp(pts[:, 2])), 0.004)
    c0 = pts.mean(axis=0)

    def posed(p):
        shape, rot = _shape(kind, math.exp(p[2]), math.exp(p[3]))
        return shape, rot, np.array([p[0], y_plane, p[1]])

    res = fit_silhouette(cam, mask, posed, np.array([c0[0], c0[2], math.log(w0), math.log(h0)]), FIT_PAD_PX,
                         centres=True)
    return float(res.fun), np.array(res.x[:2]), math.exp(res.x[2]), math.exp(res.x[3])


def _kind_sizes(cam, masks: list[np.ndarray], y_plane: float):
    """Per kind: the per-frame fit losses (1 - IoU) and sizes (w, h) of the masks."""
    losses = {k: [] for k in KINDS}
    sizes = {k: [] for k in KINDS}
    for m in masks:
        for k in KINDS:
            loss, _, w, h = _fit(cam, m, y_plane, k)
            losses[k].append(loss)
            sizes[k].append((w, h))
    return {k: np.array(v) for k, v in losses.items()}, {k: np.array(v) for k, v in sizes.items()}


def first_velocity(masks: list[np.ndarray], frames: list[int]):
    """velocity(f) -> (n, 2) du, dv px a frame at frames f: the slope of a curve (a parabola
    through three or more, a line through two) through the silhouettes' box centres at their
    frames (a streak's centre is the object's at the frame's time); None from fewer than two."""
    if len(set(frames)) != len(frames) or len(frames) < 2:
        return None
    f = np.asarray(frames, float)
    coef = np.polyfit(f, np.array([_bbox_centre(m) for m in masks]), min(len(f) - 1, 2))   # (deg + 1, 2)
    slope = [np.polyder(coef[:, a]) for a in range(2)]
    return lambda at: np.stack([np.polyval(slope[a], at) for a in range(2)], axis=-1)


def first_guess(cam, masks: list[np.ndarray], y_plane: float, m_per_px: float,
                frames: list[int] | None = None) -> tuple[str, float, float]:
    """Kind, width and height (m) from a few silhouettes (of video frames `frames`): the
    shape the tracker takes to centre the silhouettes on (`bottom_up` measures the object
    once it is tracked). Their motion blur is taken off as `bottom_up` does, each one's
    travel from a curve through their box centres (a streak's centre is the object's at the
    frame's time): a blurred first guess is taller than the object, and the object, slowed
    in the water, would look too small against it to be taken for itself."""
    losses, sizes = _kind_sizes(cam, masks, y_plane)
    if frames is not None:
        velocity = first_velocity(masks, frames)
        if velocity is not None:
            sizes = _unblurred(sizes, masks, np.abs(velocity(np.asarray(frames, float))), m_per_px)[0]
    kind = min(KINDS, key=lambda k: float(losses[k].mean()))
    w, h = np.median(sizes[kind], axis=0)
    return kind, float(w), float(h)


def exposure_share(extent_px: np.ndarray, travel_px: np.ndarray) -> tuple[float, float]:
    """The shutter's open share of the frame interval (mean, SD) from silhouettes of a moving
    object: frame j's box extent along each image axis (`extent_px` (n, 2): across u, along v)
    is the object's own, the same in every frame, plus the share times the distance its centre
    moves over a frame interval there (`travel_px` (n, 2)): a streak, the silhouette swept over
    the exposure. Each axis's own extent free (a flat prior); the share uniform on [0, 1]
    (a shutter opens at most for the whole interval), each extent known to EXTENT_SD_PX, or
    to the best fit's residual SD where that is larger (an object that turns, a silhouette
    that a splash or the frame's edge cuts: the share is then less sure): the posterior on
    EXPOSURE_GRID. Frames that all move alike (or one frame) leave it as the prior says:
    0.5 +- 0.29."""
    e = np.asarray(extent_px, float)
    t = np.asarray(travel_px, float)
    r = e[None] - EXPOSURE_GRID[:, None, None] * t[None]              # (grid, n, 2): the extent left
    ss = ((r - r.mean(axis=1, keepdims=True)) ** 2).sum(axis=(1, 2))
    var = max(EXTENT_SD_PX ** 2, float(ss.min()) / max(e.size - 3, 1))   # (two extents and the share fitted)
    w = np.exp(-(ss - ss.min()) / (2 * var))
    w /= w.sum()
    mean = float(w @ EXPOSURE_GRID)
    return mean, float(math.sqrt(max(float(w @ (EXPOSURE_GRID - mean) ** 2), 0.0)))


def _unblurred(sizes: dict, masks: list[np.ndarray], travel_px: np.ndarray | None, m_per_px: float,
               share: tuple[float, float] | None = None):
    """(sizes, share, share SD, per kind the variance it adds to the log volume): each kind's
    per-frame sizes (w, h) less motion blur's streak, the shutter's share (`share`, (mean, SD);
    None: `exposure_share` of the masks) times the frame's travel (`travel_px` (n, 2), |du| and
    |dv| px; None or no motion: as they are)."""
    blur_var = {k: 0.0 for k in KINDS}
    moving = travel_px is not None and np.max(travel_px) > EXTENT_SD_PX
    if share is None:
        if not moving:
            return sizes, 0.0, 0.0, blur_var
        share = exposure_share(np.array([_bbox_extent(m) for m in masks]), np.asarray(travel_px, float))
    share, share_sd = share
    if not moving:
        return sizes, share, share_sd, blur_var
    travel_px = np.asarray(travel_px, float)
    streak_m = share * travel_px * m_per_px                          # (n, 2): across, along v
    su, sv = share_sd * np.median(travel_px, axis=0) * m_per_px      # the share's uncertainty, in m
    out = {}
    for k in KINDS:
        # each size less its streak, at least half what was measured and a pixel
        out[k] = np.maximum(sizes[k] - streak_m, np.maximum(0.5 * sizes[k], m_per_px))
        # the share's uncertainty on the log volume: d log V / d size over the median streak
        w_k, h_k = np.median(out[k], axis=0)
        dw, dh = (1.0, 2.0) if k == "hcyl" else (2.0, 1.0)
        blur_var[k] = float((dw * su / w_k) ** 2 + (dh * sv / h_k) ** 2)
    return out, share, share_sd, blur_var


def bottom_up(cam, masks: list[np.ndarray], y_plane: float, m_per_px: float,
              travel_px: np.ndarray | None = None,
              share: tuple[float, float] | None = None) -> tuple[str, float, float, dict]:
    """Kind, width and height (m) and the track's `bottom_up` dict from silhouettes of the
    object as dropped, in the air or under the water (each fitted by every kind; see the module
    docstring). `travel_px` (n, 2):
    how far the object's centre moves over a frame interval at each mask's frame (|du|, |dv|
    px); given, motion blur's streak is taken off the sizes: the shutter's share `share`
    (mean, SD), or measured from these masks (`exposure_share`)."""
    losses, sizes = _kind_sizes(cam, masks, y_plane)
    n = len(masks)
    sizes, share, share_sd, blur_var = _unblurred(sizes, masks, travel_px, m_per_px, share)
    mean = np.array([losses[k].mean() for k in KINDS])
    # the temperature: how much a kind's loss lead moves from frame to frame (the SD of the
    # per-frame loss differences, pooled over kinds; not divided by sqrt(n): the frames show
    # one object from one side, they are not independent views), at least the IoU's own
    # resolution: the silhouette's outline moved by BOUNDARY_PX (a blurred, compressed edge
    # is not sharper than that) changes 1 - IoU by about that many outline pixels over the
    # area; fits closer than that cannot tell the kinds apart (frames that copy each other,
    # a held object, cannot sharpen it)
    diff = np.array([losses[k] - losses[KINDS[int(np.argmin(mean))]] for k in KINDS])
    area_px = float(np.mean([m.sum() for m in masks]))
    outline_px = float(np.mean([(m & ~erode(m, 3)).sum() for m in masks]))
    spread_sd = float(np.sqrt(np.mean(np.var(diff, axis=1, ddof=1)) * len(KINDS) / (len(KINDS) - 1))) if n > 1 else 0.0
    tau = max(spread_sd, BOUNDARY_PX * outline_px / max(area_px, 1.0))
    z = -(mean - mean.min()) / tau
    p = np.exp(z) / np.exp(z).sum()
    kind = KINDS[int(np.argmax(p))]
    log_v = {k: np.log([volume_cm3(k, w, h) for w, h in sizes[k]]) for k in KINDS}
    centre = {k: float(np.median(log_v[k])) for k in KINDS}
    w, h = np.median(sizes[kind], axis=0)
    # the log volume's variance: the depth assumption, the frame-to-frame spread, a pixel
    # on each measured size (w twice: the depth is taken from it), the other kinds' volumes
    # as likely as the kinds
    w_px, hh_px = max(w / m_per_px, 1.0), max(h / m_per_px, 1.0)
    var = (DEPTH_LOG_SD[kind] ** 2 + (float(np.var(log_v[kind], ddof=1)) if n > 1 else 0.0)
           + 2.0 / w_px ** 2 + 1.0 / hh_px ** 2 + blur_var[kind]
           + sum(pk * (centre[k] - centre[kind]) ** 2 for k, pk in zip(KINDS, p)))
    info = {"kind": kind, "volume_cm3": float(math.exp(centre[kind])), "volume_log_sd": float(math.sqrt(var)),
            "kind_probs": {k: float(pk) for k, pk in zip(KINDS, p)}, "frames_measured": n,
            "exposure_share": round(share, 3), "exposure_share_sd": round(share_sd, 3)}
    return kind, float(w), float(h), info


def plausible(cam, y_plane: float, c: np.ndarray, c_prev: np.ndarray | None, dt_s: float) -> bool:
    """Whether the object can have moved from image centre c_prev to c (pixels) in dt_s:
    at most MAX_SPEED_MPS on the release plane. Always, without a previous centre."""
    if c_prev is None:
        return True
    p = backproject_to_plane(cam, np.array([c, c_prev], float), y_plane)
    return float(np.linalg.norm(p[0] - p[1])) <= MAX_SPEED_MPS * dt_s


def _start_and_rest(fg: np.ndarray, water_row: float) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(where the object starts, where it comes to rest): the sizeable components of a
    foreground that shows the object at both (an early frame against a late one, or against
    a background that holds one of them). The object starts at or near its release point,
    above the water (held there, or falling through the air), and comes to rest in the water:
    the highest component is the start, with those above the water beside it (sharing its rows:
    a motion-blurred streak breaks into pieces), the others are the resting place. A lone component
    (the other did not show: a light object against a light wall) is the resting place if it
    reaches below the water line (image row `water_row` at the release point), else the start.
    None for either that does not show."""
    comps = blobs(fg, GHOST_MIN_FRACTION)
    if not comps:
        return None, None
    rows = [np.nonzero(c.any(axis=1))[0] for c in comps]
    if len(comps) == 1:
        return (None, comps[0]) if rows[0][-1] > water_row else (comps[0], None)
    k = int(np.argmin([r[0] for r in rows]))
    top = rows[k]
    # the start: the highest, with the pieces beside it above the water (a blurred streak breaks up)
    start = [j for j, r in enumerate(rows)
             if j == k or (r[-1] < water_row and r[0] <= top[-1] and r[-1] >= top[0])]
    rest = [c for j, c in enumerate(comps) if j not in start]
    return np.any([comps[j] for j in start], axis=0), (np.any(rest, axis=0) if rest else None)


def background(sample: list[np.ndarray], early: list[np.ndarray], late: list[np.ndarray], noise: float,
               water_row: float) -> np.ndarray:
    """The tank without the object: MOG2 learned backwards over the video (`sample`: its frames,
    or at most MODEL_MAX_FRAMES of them evenly spaced), with the two places it may keep the
    object replaced (`_start_and_rest`, from the first frame against the last):
    * where the object starts, by the median of the last frames (`late`: the last
      EARLY_FRAMES), which show it empty. A backwards MOG2 weighs the first frames most: an
      object held still at its release point for a third of the video stays in it, and
      after the release that place shows a ghost of it, larger than the falling object;
    * where it comes to rest, by the median of the first frames (`early`: the first
      EARLY_FRAMES) in which that place still looks as in frame 0 (before the object got
      there). MOG2 learned forwards over the first frames is no substitute: it keeps frame
      0's object, and an object that stops within those frames."""
    bg = mog2_background(sample, reverse=True)
    first, last = early[0], np.median(np.stack(late), axis=0).astype(bg.dtype)
    start, rest = _start_and_rest(clean(foreground(first, last, noise)) > 0, water_row)
    if start is not None:   # (the resting place may not show against the last frames: a coin on the floor)
        zone = dilate(start, END_ZONE_PX) & (~dilate(rest, END_ZONE_PX) if rest is not None else True)
        bg[zone] = last[zone]
    rest = _start_and_rest(clean(foreground(first, bg, noise)) > 0, water_row)[1]
    if rest is None:
        return bg
    zone = dilate(rest, END_ZONE_PX)
    k = 1
    while k < len(early) and not (clean(foreground(early[k], first, noise)) > 0)[zone].any():
        k += 1
    bg[zone] = np.median(np.stack(early[:k])[:, zone], axis=0).astype(bg.dtype)
    return bg


def _learn_tank(video: Stabilised, n: int, scale: float, bar, water_row: float):
    """The first pass: (the background, the noise, which frames show the scene). Frames that
    show something else (`not_the_scene`) are left out of the background; the frames it is
    learned from are kept in this pass (taken in another from the frames that show the scene,
    if some do not)."""
    planned = set(spread(np.arange(n), MODEL_MAX_FRAMES).tolist())
    sample, early, late = [], [], deque(maxlen=EARLY_FRAMES)
    shown = np.ones(n, bool)
    noise = None
    for f, (y, uv) in enumerate(video.yuv()):
        bar.update()
        img = yuv_image(y, uv, scale)
        if f == 1:
            noise = noise_sd([early[0], img])
        if f and (not video.fits[f].shown or not_the_scene(img, early[0], noise)):
            shown[f] = False
            continue
        if len(early) < EARLY_FRAMES:
            early.append(img)
        late.append(img)
        if f in planned:
            sample.append(img)
    if not shown.all():
        sample = frames_at(video, spread(np.flatnonzero(shown), MODEL_MAX_FRAMES), scale)
    return background(sample, early, list(late), noise, water_row), noise, shown


def track(video_path: str | Path, scene, *, progress: bool = True, debug_video=None) -> Tracks:
    """Track the splash scene's object in a video; see the module docstring.

    The video is streamed, never held (`galileo.video.VideoStream`): a pass learns the
    background, a second finds the first silhouettes (it stops there), a third tracks."""
    cam = scene.camera
    if cam is None:
        raise GalileoError("the scene file has no camera: tracking needs one that describes the video")
    check_sees(cam, scene_points(scene))
    (sx, sy, sz), eye = scene.tank.size_m, cam.position_in_world
    if abs(eye[0]) < sx / 2 and abs(eye[1]) < sy / 2 and 0 <= eye[2] < sz:   # (an identity world_to_camera: its floor)
        raise GalileoError(f"the camera stands inside the tank, at ({eye[0]:.2f}, {eye[1]:.2f}, {eye[2]:.2f}) m: "
                           "check camera.world_to_camera, the transform from world to camera (x right, y down, "
                           "z forward)")
    # the video must be the one the camera describes: its size, frame rate and length
    # (galileo.video.check_stream / check_length say why each is checked as it is)
    region = fall_column(scene)
    video = Stabilised(VideoStream(video_path, cam, min_frames=3), exclude=region)
    n = int(cam.n_frames)
    hw = (cam.height_px, cam.width_px)
    scale = work_scale(hw, 1.0)
    y_plane = float(scene.release_m[1])
    water = scene.tank.water_level_m
    release = np.asarray(scene.release_m, float)
    m_per_px = float((cam.world_to_camera[:3, :3] @ release + cam.world_to_camera[:3, 3])[2] / cam.K[0, 0])
    water_px = float(cam.project(np.array([release[0], y_plane, water]))[1])   # the water line's row there
    water_row = water_px * scale
    bar = tqdm(total=n, desc="tracking 1/2: learning the tank", unit="frame", disable=not progress)  # (a bar a pass)
    bg, noise, shown = _learn_tank(video, n, scale, bar, water_row)
    elsewhere = [False]   # whether something moved outside the region

    def silhouettes():
        """Per frame: (luma, the object's silhouette at full resolution or None), looked for where the
        object can be."""
        for i, (y, uv) in enumerate(video.yuv()):
            fg = full_res(foreground(yuv_image(y, uv, scale), bg, noise), hw) if shown[i] else None
            if fg is not None and not elsewhere[0]:
                outside = fg & ~region
                # (components only where enough is there: most frames of most videos have nothing outside)
                elsewhere[0] = np.count_nonzero(outside) >= MIN_BLOB_PX and largest_component(outside) is not None
            yield y, None if fg is None else components(fg & region, MAX_CANDIDATES)

    # the shape to centre silhouettes on: the first usable silhouettes
    first, first_frames = [], []
    for f, (_, blobs_f) in enumerate(silhouettes()):
        if blobs_f:
            first.append(blobs_f[0])
            first_frames.append(f)
            if len(first) == BOTTOM_UP_FRAMES:
                break
    if len(first) < 2:
        bar.close()
        raise StillVideo(f"nothing moves in {video_path}: no object against the tank's background")
    kind, w, h = first_guess(cam, first, y_plane, m_per_px, first_frames)
    early_velocity = first_velocity(first, first_frames)
    shape, rot = _shape(kind, w, h)

    def expected(uv):
        """Silhouette area, (projected centre - silhouette box centre) and box extent (u, v px)
        of the fitted shape whose centre projects to uv."""
        c = backproject_to_plane(cam, uv[None], y_plane)[0]
        sil = shape_silhouette(cam, shape, rot, c, centres=True) > 0
        if not sil.any():
            return 0, np.zeros(2), np.zeros(2)
        return int(sil.sum()), cam.project(c) - _bbox_centre(sil), _bbox_extent(sil)

    centre = np.full((n, 2), np.nan)
    pts = np.zeros((0, 2), np.float32)
    c_prev, v_prev, i_prev = None, np.zeros(2), -1   # the last centre, its velocity (px/frame), its frame
    v_known = False                                  # whether v_prev was measured (two centres), else the
                                                     # first silhouettes' curve gives the velocity
    shift = np.zeros(2)                              # the features' motion since frame i_prev
    features = []
    prev, last = None, 0                             # the last frame that shows the scene
    in_air, in_water = [], []                        # (frame, region, silhouette there) of the object in the air,
                                                     # and wholly under the water
    wet, jumps = False, 0                            # whether it reached the water; silhouettes dropped as jumps
    landed = False                                   # whether it reached the tank's floor (where it may tip over)
    bar.set_description("tracking 2/2: following the object", refresh=False)
    bar.reset(total=n)
    accel_px = MAX_ACCEL_G * float(scene.gravity_mps2) / cam.fps ** 2 / m_per_px   # px / frame^2
    for i, (gray, candidates) in enumerate(silhouettes()):
        bar.update()
        if not shown[i]:   # not the scene: nothing seen in it; tracking goes on from the last that was
            features.append(np.zeros((0, 2), np.float32))
            continue
        dt = (i - i_prev) / cam.fps if c_prev is not None else 0.0
        v_guess = (v_prev if v_known else early_velocity(float(i)) if early_velocity is not None
                   else np.zeros(2))
        blob, c, extent, travel, jumped = _choose(candidates, expected, c_prev, v_guess, i - i_prev, accel_px,
                                                  lambda c_new: plausible(cam, y_plane, c_new, c_prev, dt))
        jumps += jumped
        c_klt = None
        if i and len(pts) and c_prev is not None:
            win = klt_window(blob) if blob is not None else 9
            new, ok = flow(prev, gray, pts, pts + ((i - last) * v_guess).astype(np.float32), win)
            if blob is not None:
                inside = dilate(blob, 5)
                ij = np.round(new).astype(int)
                good = (ij[:, 0] >= 0) & (ij[:, 0] < hw[1]) & (ij[:, 1] >= 0) & (ij[:, 1] < hw[0])
                ok &= good
                ok[good] &= inside[ij[good, 1], ij[good, 0]]
            if ok.sum() >= MIN_FEATURES and shift is not None:
                shift = shift + np.median(new[ok] - pts[ok], axis=0)
                c_klt = c_prev + shift
            else:
                shift = None
            pts = new[ok]
        from_silhouette = c is not None
        if c is None and c_klt is not None and plausible(cam, y_plane, c_klt, c_prev, dt):
            c = c_klt
        if c is not None:
            if c_prev is not None:
                v_prev, v_known = (c - c_prev) / (i - i_prev), True
            centre[i] = c_prev = c
            i_prev, shift = i, np.zeros(2)
            bottom_m = backproject_to_plane(cam, c[None], y_plane)[0, 2] - h / 2
            wet = wet or bottom_m < water + AIR_MARGIN_PX * m_per_px
            landed = landed or bottom_m < AIR_MARGIN_PX * m_per_px
            if from_silhouette:   # a blurred silhouette's streak reaches lower than the shape, by up to half
                # the frame's travel (the water's part of it, tinted, may be cut off the silhouette)
                rows = np.flatnonzero(blob.any(axis=1))
                wet = wet or max(float(rows[-1]), c[1] + (extent[1] + travel[1]) / 2) > water_px - AIR_MARGIN_PX
                if not wet:
                    in_air.append((i, *crop(blob, FIT_PAD_PX)))
                elif not landed and rows[0] > water_px + AIR_MARGIN_PX:
                    in_water.append((i, *crop(blob, FIT_PAD_PX)))
        if blob is not None and len(pts) < max(MIN_FEATURES, N_FEATURES // 2):
            pts = np.concatenate([pts, seed_features(gray, blob, N_FEATURES - len(pts), avoid=pts)])
        features.append(pts.copy())
        prev, last = gray, i
    visible = np.all(np.isfinite(centre), axis=1)
    pos = np.full((n, 3), np.nan)
    pos[visible] = backproject_to_plane(cam, centre[visible], y_plane)
    lowest = pos[visible, 2] - h / 2
    if not np.any(lowest < water + ENTRY_PX * m_per_px):
        bar.close()
        raise GalileoError(f"nothing enters the water in {video_path}: the object stays above the water line")
    kind_sizes, notes = _measure(cam, in_air, in_water, hw, y_plane, m_per_px, first, centre)
    kind, w, h, found = kind_sizes
    found.update(_release(centre, visible, cam.fps))
    shape, _ = _shape(kind, w, h)
    vel = velocity_from_positions(pos, visible, cam.fps)
    obj = ObjectTrack(scene.obj.name, "object", pos, vel, visible, shape, None, "motion", found, centre, features,
                      position_sd_m=position_noise(pos, visible, cam.fps))
    notes = [note for note in (video.timing_note(),) if note] + video.notes() + notes + rarely_seen_notes([obj])
    if elsewhere[0]:
        notes.append(DISTRACTOR_NOTE)
    notes += _track_notes(obj, pos, visible, release, water, h, jumps, m_per_px)
    tracks = Tracks(cam.fps, [obj], notes, video.motion().to_json()).check()   # what `galileo track` writes
    if debug_video is not None:
        bar.set_description("tracking: writing the debug video", refresh=False)
        bar.reset(total=n)
        write_video(debug_video, (draw_tracks(yuv_to_rgb(y, uv), tracks, f, DEBUG_COLORS)
                                  for f, (y, uv) in enumerate(_counted(video.yuv(), bar))), cam.fps)
    bar.close()
    return tracks


def _choose(candidates, expected, c_prev, v_prev, frames_since: int, accel_px: float, plausible) -> tuple:
    """The object's silhouette among a frame's `candidates` (the largest components in the fall
    column): (the silhouette, its centre, its box extent, its travel over a frame (u, v px),
    1 if one was dropped as a jump else 0); (the candidate nearest the prediction or None, None,
    ...) where none is usable. Tried nearest the centre predicted at constant velocity first
    (the last centre without one); usable: its area within AREA_OK of the fitted shape's, the
    upper bound swept over its travel (motion blur: a streak), and `plausible(centre)`. Its travel
    is its own jump from the last centre, per frame, at most the last speed plus MAX_ACCEL_G x g
    over the frames since, plus TRAVEL_SLACK_PX (a shadow's or a merged blob's jump would
    otherwise excuse its size); |v_prev| without a last centre. `v_prev` is the last velocity
    measured, or before two centres the first silhouettes' (`first_velocity`). A candidate that is not
    usable but whose box holds the last centre or the predicted one is the object, unusable
    here: no candidate farther away is tried (a floor-hidden sinker's small silhouette, with a
    shadow on the wall above it that its size and a long gap since would let pass)."""
    if not candidates:
        return None, None, None, None, 0
    boxed = [(blob, _bbox_centre(blob)) for blob in candidates]
    if c_prev is not None:
        pred = c_prev + frames_since * v_prev
        boxed.sort(key=lambda bc: float(np.linalg.norm(bc[1] - pred)))
    jumped = 0
    for blob, box_centre in boxed:
        area, off, extent = expected(box_centre)
        c_box = box_centre + off
        here = c_prev is not None and any(_covers(blob, box_centre, p) for p in (c_prev, pred))
        if c_prev is not None:
            most = np.abs(v_prev) + accel_px * frames_since + TRAVEL_SLACK_PX
            travel = np.minimum(np.abs(c_box - c_prev) / frames_since, most)
        else:
            travel = np.abs(v_prev)
        swept = area + travel[1] * extent[0] + travel[0] * extent[1]
        if not (area and AREA_OK[0] * area <= blob.sum() <= AREA_OK[1] * swept):
            if here:   # the object is there, its silhouette unusable: no other is it
                break
            continue
        if not plausible(c_box):
            jumped = 1
            continue
        return blob, c_box, extent, travel, 0
    return boxed[0][0], None, None, None, jumped


def _covers(blob: np.ndarray, box_centre: np.ndarray, uv: np.ndarray) -> bool:
    """Whether the silhouette's bounding box (centred at `box_centre`), grown by TRAVEL_SLACK_PX,
    holds image point uv."""
    half = (_bbox_extent(blob) - 1) / 2 + TRAVEL_SLACK_PX
    return bool(np.all(np.abs(np.asarray(uv, float) - box_centre) <= half))


def _counted(frames, bar):
    """The frames, each counted on the progress bar."""
    for f in frames:
        bar.update()
        yield f


def travel_px(centre: np.ndarray, f: int) -> np.ndarray | None:
    """How far the image centre moves over a frame interval at frame f (|du|, |dv| px): the
    slope at f of a parabola (a line, through two) through f's centre and the nearest seen
    within 2 TRAVEL_WINDOW frames on either side, or two on one side where the other has none
    (a fall's constant acceleration is a parabola: a central difference, or a second-order
    one-sided one); None where fewer than two are seen, or f is neither seen nor between seen ones."""
    seen = lambda j: 0 <= j < len(centre) and bool(np.isfinite(centre[j]).all())
    before = [j for j in range(f - 1, f - 1 - 2 * TRAVEL_WINDOW, -1) if seen(j)]
    after = [j for j in range(f + 1, f + 1 + 2 * TRAVEL_WINDOW) if seen(j)]
    if before and after:
        js = [before[0], *([f] if seen(f) else []), after[0]]
    else:
        js = ([f] if seen(f) else []) + (before or after)[:2]
    if len(js) < 2 or not (seen(f) or (before and after)):
        return None
    js = np.array(sorted(js))
    coef = np.polyfit(js - f, centre[js], min(len(js) - 1, 2))          # (deg + 1, 2): at f, the slope is coef[-2]
    return np.abs(coef[-2])


def sharpest(seen: list, travel: list, n: int) -> tuple[list, np.ndarray | None]:
    """(up to n of the silhouettes `seen` ((frame, ...) tuples, in time order), their travel
    (k, 2) px a frame, or None): the n whose centre moves least over a frame (`travel`, each
    one's `travel_px` or None: the shortest streaks), in time order; where more move as little
    as the n-th, n evenly spread over those in time. Those whose travel is unknown (too few
    centres near them) only where none is known: all of them spread evenly, and no travel."""
    known = [(j, t) for j, t in enumerate(travel) if t is not None]
    if not known:
        return [seen[int(j)] for j in spread(np.arange(len(seen)), n)], None
    speed = np.array([float(np.hypot(*t)) for _, t in known])
    order = np.argsort(speed, kind="stable")
    cut = speed[order[min(n, len(order)) - 1]]            # the n-th smallest travel: all as sharp as it
    tied = [k for k in range(len(known)) if speed[k] <= cut]
    tied.sort(key=lambda k: seen[known[k][0]][0])
    picked = [tied[int(j)] for j in spread(np.arange(len(tied)), n)]
    return [seen[known[k][0]] for k in picked], np.array([known[k][1] for k in picked])


def _measure(cam, in_air: list, in_water: list, hw: tuple[int, int], y_plane: float, m_per_px: float,
             first: list, centre: np.ndarray):
    """((kind, w, h, the bottom_up dict), notes) from the sharpest silhouettes in the air or
    under the water (`sharpest`; their motion blur taken off where the centre's track says how
    fast each moves); from the first silhouettes, with a note, when the object was never seen
    whole in either."""
    notes = []
    if in_air or in_water:
        seen = in_air + in_water
        travel_all = [travel_px(centre, s[0]) for s in seen]
        picked, travel = sharpest(seen, travel_all, BOTTOM_UP_MAX_FRAMES)
        masks = []
        for f, (x0, y0, cw, ch), sil in picked:
            m = np.zeros(hw, bool)
            m[y0:y0 + ch, x0:x0 + cw] = sil
            masks.append(m)
        # the shutter's share from the silhouettes in the air whose travel is known (the streaks say
        # it, the sharp ones measured hardly do; in free fall a parabola gives each frame's travel,
        # where the water's sudden drag does not), from all of them where fewer than two are
        moved = [(_bbox_extent(s[2]), t) for s, t in zip(seen, travel_all) if t is not None]
        n_air = sum(t is not None for t in travel_all[:len(in_air)])   # (seen: the air's first)
        if n_air >= 2:
            moved = moved[:n_air]
        share = (exposure_share(np.array([e for e, _ in moved]), np.array([t for _, t in moved]))
                 if moved and max(float(np.max(t)) for _, t in moved) > EXTENT_SD_PX else None)
        kind_sizes = bottom_up(cam, masks, y_plane, m_per_px, travel, share)
        air_frames = {s[0] for s in in_air}
        kind_sizes[3]["frames_in_water"] = sum(1 for s in picked if s[0] not in air_frames)
        return kind_sizes, notes
    masks = first
    notes.append("the object is never seen whole above or below the water line: its shape kind and volume are "
                 "measured on its first silhouettes, which may be cut by the water's surface")
    return bottom_up(cam, masks, y_plane, m_per_px, None), notes


def _release(centre: np.ndarray, visible: np.ndarray, fps: float) -> dict:
    """The release seen in the track: `release_s`, the video time of the last frame at which
    the object is still where it was first seen (within HOLD_PX), None if it moves from the
    first frame it is seen; `held_frames`, how many frames it is seen there."""
    seen = np.flatnonzero(visible)
    if len(seen) < 2:
        return {"release_s": None, "held_frames": 0}
    still = np.linalg.norm(centre[seen] - centre[seen[0]], axis=1) <= HOLD_PX
    k = int(np.argmin(still)) if not still.all() else len(seen)   # the first seen frame that has moved
    if k < 2:
        return {"release_s": None, "held_frames": 0}
    return {"release_s": float(seen[k - 1] / fps), "held_frames": k}


def _track_notes(obj, pos: np.ndarray, visible: np.ndarray, release: np.ndarray, water: float, h: float,
                 jumps: int, m_per_px: float) -> list[str]:
    """Notes on a track that does not look like a drop: first seen in the water (as a ghost
    of where it comes to rest is); silhouettes left out as jumps."""
    notes = []
    seen = np.flatnonzero(visible)
    if len(seen):
        f = int(seen[0])
        p = pos[f]
        off_m = float(np.hypot(p[0] - release[0], p[2] - release[2]))
        if p[2] - h / 2 < water:
            notes.append(f"{obj.name} is first seen in the water (frame {f}, {off_m * 100:.1f} cm from its release "
                         f"point): the video should open with it above the water; check the scene's release point "
                         f"and water level, and that the object shows against the wall behind it")
    if jumps:
        notes.append(f"{obj.name}'s silhouette jumped farther than it can move ({MAX_SPEED_MPS} m/s) in {jumps} "
                     f"frame{'s' if jumps > 1 else ''}: those were left out (another moving thing, or a ghost "
                     f"of the object in the background)")
    return notes


def _box_mask(cam, lo, hi) -> np.ndarray:
    """The image region (boolean) of the world box lo..hi (its corners' projected hull)."""
    corners = np.array([(x, y, z) for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    return project_silhouette(cam, corners, np.eye(3), np.zeros(3)) > 0


def fall_column(scene) -> np.ndarray:
    """Where the object falls (boolean image): within FALL_HALF_WIDTH_M of the release point's x, from
    FALL_ABOVE_M above it down to the tank's floor, across the tank's depth."""
    (rx, _, rz), sy = scene.release_m, scene.tank.size_m[1]
    return _box_mask(scene.camera, (rx - FALL_HALF_WIDTH_M, -sy / 2, 0.0), (rx + FALL_HALF_WIDTH_M, sy / 2, rz + FALL_ABOVE_M))


def scene_points(scene) -> dict[str, np.ndarray]:
    """What the camera should see of the scene (world points by name): the tank's inner
    corners and the object where it is released."""
    sx, sy, sz = scene.tank.size_m
    corners = np.array([(x, y, z) for x in (-sx / 2, sx / 2) for y in (-sy / 2, sy / 2) for z in (0.0, sz)])
    return {"the tank": corners, "the object's release": np.asarray(scene.release_m, float)}
