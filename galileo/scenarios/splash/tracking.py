"""Splash tracking: pixels -> the object's positions, velocities, shape kind and volume.

1. Background: MOG2 (five components, `galileo.vision.background`) learned backwards over
   the whole video gives the tank as the video ends, with the object where it comes to
   rest. Frame 0 against it shows the object falling through the air (the highest
   component) and a ghost of the resting object below it; the ghost's place, grown by
   END_ZONE_PX, takes the median of the first frames in which it still looks as in frame 0:
   a background without the object. (Bounded for any video, `galileo.vision.background`:
   learned from at most MODEL_MAX_FRAMES frames, evenly spaced, at most 0.5 Mpx each.) A
   frame most of which differs from frame 0 (noise, a cut: `not_the_scene`) is left out of
   it, no object is seen in it, and tracking goes on from the last frame that showed the tank.
2. Foreground per frame against it: the object (its largest component), in air or water
   (the water's tint is in the background too).
3. KLT (`galileo.vision.klt`): good features inside the frame-0 silhouette, Lucas-Kanade
   from a constant-velocity guess with a forward-backward check, features that leave the
   foreground dropped, re-seeded inside the foreground when fewer than half survive (the
   tint changes the object's look as it enters the water).
4. The object's centre per frame: the centre of its silhouette's bounding box, corrected
   by the offset between the fitted 3-D shape's projected centre and its silhouette's
   box centre (the camera sees the top face too); where the silhouette is not usable
   (too small or large against the fitted shape's, or missing) the KLT motion of the
   features carries the last centre on. A centre farther from the last one than the
   object could move in the time between them (MAX_SPEED_MPS on the release plane) is
   dropped, the frame left without one. Back-projected onto the plane y = release_m[1]
   (the object falls straight down) it gives positions in metres; velocities by central
   differences (`galileo.vision.velocity`). Frames without either are `visible: false`.
5. Bottom-up kind and volume: the silhouette in the first BOTTOM_UP_FRAMES frames fitted
   (least 1 - IoU) by each kind at the release plane, sizes w (across) and H (high); an
   hcyl needs a silhouette HCYL_ASPECT times wider than high and a better fit than a box; the
   depth assumption: a box has a square bottom (depth w), a vertical cylinder is round
   (depth w), a horizontal cylinder's depth is its diameter H. Volumes: box w^2 H,
   vcyl pi/4 w^2 H, hcyl pi/4 H^2 w. A box and a vertical cylinder differ only in how
   the top face's outline curves, a few pixels: the vcyl wins only when its fit is
   better by KIND_MARGIN, else box.

The video is streamed (`galileo.video.VideoStream`), never held; a scene whose camera sees
none of it (the tank, the release point) is refused before any of it. The tracks carry
notes for unevenly timed frames (a variable frame rate) and an object seen in few frames.

Note: the rendered videos open with the object falling through the air (released 12-20 cm
above the water, shown from physics step 5-30 on), so the first silhouettes are measured in
air. Under water the renderer draws no refraction (a real flat-walled tank magnifies what is
under water by up to the water's index, 1.33, which this does not correct).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ...camera import backproject_to_plane, check_sees
from ...datatypes import ObjectTrack, Tracks
from ...errors import GalileoError, StillVideo
from ...progress import tqdm
from ...shapes import Box, Cylinder
from ...video import VideoStream
from ...vision.background import (MODEL_MAX_FRAMES, blobs, clean, dilate, foreground, frames_at, full_res,
                                  largest_component, mog2_background, noise_sd, not_the_scene, spread, work_scale,
                                  yuv_image)
from ...vision.klt import flow, klt_window, seed_features
from ...vision.pose import rot_y
from ...vision.silhouette import fit_silhouette, shape_silhouette
from ...vision.tracker import rarely_seen_notes
from ...vision.velocity import velocity_from_positions
from .scene import CM3, KINDS

EARLY_FRAMES = 4           # the resting place's background: median of at most this many first frames
END_ZONE_PX = 9            # the object's resting place, grown by this, takes the early background
GHOST_MIN_FRACTION = 0.2   # frame 0's foreground components this fraction of the largest's area count
N_FEATURES = 40
MIN_FEATURES = 4
BOTTOM_UP_FRAMES = 3       # silhouettes fitted for kind and size
FIT_PAD_PX = 20
HCYL_ASPECT = 1.5          # a horizontal cylinder's silhouette is at least this much wider than high
KIND_MARGIN = 0.01         # 1 - IoU by which a vcyl must beat a box
AREA_OK = (0.6, 1.6)       # a silhouette is usable within these ratios of the fitted shape's area
MAX_SPEED_MPS = 3.0        # a centre farther than this x the time since the last one from it is dropped
                           # (free fall from the highest release reaches ~2 m/s at the water)


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


def _fit(cam, mask: np.ndarray, y_plane: float, kind: str):
    """(loss, centre (x, z), w, h) of the `kind` shape whose silhouette best fits the mask."""
    ys, xs = np.nonzero(mask)
    pts = backproject_to_plane(cam, np.c_[xs, ys].astype(float), y_plane)
    w0, h0 = max(float(np.ptp(pts[:, 0])), 0.004), max(float(np.ptp(pts[:, 2])), 0.004)
    c0 = pts.mean(axis=0)

    def posed(p):
        shape, rot = _shape(kind, math.exp(p[2]), math.exp(p[3]))
        return shape, rot, np.array([p[0], y_plane, p[1]])

    res = fit_silhouette(cam, mask, posed, np.array([c0[0], c0[2], math.log(w0), math.log(h0)]), FIT_PAD_PX)
    return float(res.fun), np.array(res.x[:2]), math.exp(res.x[2]), math.exp(res.x[3])


def bottom_up(cam, masks: list[np.ndarray], y_plane: float) -> tuple[str, float, float]:
    """Kind, width and height (m) from a few silhouettes (median over them)."""
    losses = {k: [] for k in KINDS}
    sizes = {k: [] for k in KINDS}
    for m in masks:
        for k in KINDS:
            loss, _, w, h = _fit(cam, m, y_plane, k)
            losses[k].append(loss)
            sizes[k].append((w, h))
    mean = {k: float(np.mean(v)) for k, v in losses.items()}
    med = {k: np.median(np.array(v), axis=0) for k, v in sizes.items()}
    # a lying cylinder: a wide-and-short silhouette that it fits better than a box (a cube
    # fits both about as well: its depth is its height either way)
    wide = med["hcyl"][0] > HCYL_ASPECT * med["hcyl"][1]
    kind = "hcyl" if wide and mean["hcyl"] < mean["box"] else "box"
    if kind == "box" and mean["vcyl"] < mean["box"] - KIND_MARGIN:
        kind = "vcyl"
    w, h = med[kind]
    return kind, float(w), float(h)


def plausible(cam, y_plane: float, c: np.ndarray, c_prev: np.ndarray | None, dt_s: float) -> bool:
    """Whether the object can have moved from image centre c_prev to c (pixels) in dt_s:
    at most MAX_SPEED_MPS on the release plane. Always, without a previous centre."""
    if c_prev is None:
        return True
    p = backproject_to_plane(cam, np.array([c, c_prev], float), y_plane)
    return float(np.linalg.norm(p[0] - p[1])) <= MAX_SPEED_MPS * dt_s


def _resting_ghost(fg0: np.ndarray) -> np.ndarray | None:
    """Where the object comes to rest, from frame 0's foreground against the late background:
    every sizeable component but the highest one (the object falling through the air at
    frame 0; the late background holds the object at rest, which shows as a ghost where
    frame 0 sees the empty tank). None without one."""
    comps = blobs(fg0, GHOST_MIN_FRACTION)
    if len(comps) < 2:
        return None
    tops = [int(np.nonzero(c.any(axis=1))[0][0]) for c in comps]
    falling = int(np.argmin(tops))
    return np.any([c for j, c in enumerate(comps) if j != falling], axis=0)


def background(sample: list[np.ndarray], early: list[np.ndarray], noise: float) -> np.ndarray:
    """The tank without the object: MOG2 learned backwards over the video (`sample`: its frames,
    or at most MODEL_MAX_FRAMES of them evenly spaced; the tank as the video ends, the object at
    rest in it), its resting place replaced by the median of the first frames (`early`: the
    first EARLY_FRAMES) in which that place still looks as in frame 0 (before the object got
    there). MOG2 learned forwards over the first frames is no substitute: it keeps frame 0's
    object, and an object that stops within those frames."""
    bg = mog2_background(sample, reverse=True)
    first = early[0]
    ghost = _resting_ghost(clean(foreground(first, bg, noise)) > 0)
    if ghost is None:
        return bg
    zone = dilate(ghost, END_ZONE_PX)
    k = 1
    while k < len(early) and not (clean(foreground(early[k], first, noise)) > 0)[zone].any():
        k += 1
    bg[zone] = np.median(np.stack(early[:k])[:, zone], axis=0).astype(bg.dtype)
    return bg


def _learn_tank(video: VideoStream, n: int, scale: float, bar):
    """The first pass: (the background, the noise, which frames show the scene). Frames that
    show something else (`not_the_scene`) are left out of the background; the frames it is
    learned from are kept in this pass (taken in another from the frames that show the scene,
    if some do not)."""
    planned = set(spread(np.arange(n), MODEL_MAX_FRAMES).tolist())
    sample, early = [], []
    shown = np.ones(n, bool)
    noise = None
    for f, (y, uv) in enumerate(video.yuv()):
        bar.update()
        img = yuv_image(y, uv, scale)
        if f == 1:
            noise = noise_sd([early[0], img])
        if f and not_the_scene(img, early[0], noise):
            shown[f] = False
            continue
        if len(early) < EARLY_FRAMES:
            early.append(img)
        if f in planned:
            sample.append(img)
    if not shown.all():
        sample = frames_at(video, spread(np.flatnonzero(shown), MODEL_MAX_FRAMES), scale)
    return background(sample, early, noise), noise, shown


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
    video = VideoStream(video_path, cam, min_frames=3)
    n = int(cam.n_frames)
    hw = (cam.height_px, cam.width_px)
    scale = work_scale(hw, 1.0)
    bar = tqdm(total=2 * n, desc="tracking", unit="frame", disable=not progress)
    bg, noise, shown = _learn_tank(video, n, scale, bar)

    def silhouettes():
        """Per frame: (luma, the object's silhouette at full resolution or None)."""
        for i, (y, uv) in enumerate(video.yuv()):
            fg = full_res(foreground(yuv_image(y, uv, scale), bg, noise), hw) if shown[i] else None
            yield y, None if fg is None else largest_component(fg)

    # bottom-up: the first usable silhouettes
    first = []
    for _, blob in silhouettes():
        if blob is not None:
            first.append(blob)
            if len(first) == BOTTOM_UP_FRAMES:
                break
    if len(first) < 2:
        bar.close()
        raise StillVideo(f"nothing moves in {video_path}: no object against the tank's background")
    y_plane = float(scene.release_m[1])
    kind, w, h = bottom_up(cam, first, y_plane)
    shape, rot = _shape(kind, w, h)

    def expected(uv):
        """Silhouette area and (projected centre - silhouette box centre) of the fitted
        shape whose centre projects to uv."""
        c = backproject_to_plane(cam, uv[None], y_plane)[0]
        sil = shape_silhouette(cam, shape, rot, c) > 0
        if not sil.any():
            return 0, np.zeros(2)
        return int(sil.sum()), cam.project(c) - _bbox_centre(sil)

    centre = np.full((n, 2), np.nan)
    pts = np.zeros((0, 2), np.float32)
    c_prev, v_prev, i_prev = None, np.zeros(2), -1   # the last centre, its velocity (px/frame), its frame
    shift = np.zeros(2)                              # the features' motion since frame i_prev
    features = []
    prev, last = None, 0                             # the last frame that shows the scene
    for i, (gray, blob) in enumerate(silhouettes()):
        bar.update()
        if not shown[i]:   # not the scene: nothing seen in it; tracking goes on from the last that was
            features.append(np.zeros((0, 2), np.float32))
            continue
        c_klt = None
        if i and len(pts) and c_prev is not None:
            win = klt_window(blob) if blob is not None else 9
            new, ok = flow(prev, gray, pts, pts + ((i - last) * v_prev).astype(np.float32), win)
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
        c = None
        if blob is not None:
            c_box = _bbox_centre(blob)
            area, off = expected(c_box)
            c_box = c_box + off
            if area and AREA_OK[0] <= blob.sum() / area <= AREA_OK[1]:
                c = c_box
        dt = (i - i_prev) / cam.fps if c_prev is not None else 0.0
        if c is not None and not plausible(cam, y_plane, c, c_prev, dt):
            c = None
        if c is None and c_klt is not None and plausible(cam, y_plane, c_klt, c_prev, dt):
            c = c_klt
        if c is not None:
            if c_prev is not None:
                v_prev = (c - c_prev) / (i - i_prev)
            centre[i] = c_prev = c
            i_prev, shift = i, np.zeros(2)
        if blob is not None and len(pts) < max(MIN_FEATURES, N_FEATURES // 2):
            pts = np.concatenate([pts, seed_features(gray, blob, N_FEATURES - len(pts), avoid=pts)])
        features.append(pts.copy())
        prev, last = gray, i
    bar.close()
    visible = np.all(np.isfinite(centre), axis=1)
    pos = np.full((n, 3), np.nan)
    pos[visible] = backproject_to_plane(cam, centre[visible], y_plane)
    lowest = pos[visible, 2] - h / 2
    if not np.any(lowest < scene.tank.water_level_m):
        raise GalileoError(f"nothing enters the water in {video_path}: the object stays above the water line")
    vel = velocity_from_positions(pos, visible, cam.fps)
    obj = ObjectTrack(scene.obj.name, "object", pos, vel, visible, shape, None, "motion",
                      {"kind": kind, "volume_cm3": volume_cm3(kind, w, h)}, centre, features)
    notes = [note for note in (video.timing_note(),) if note] + rarely_seen_notes([obj])
    return Tracks(cam.fps, [obj], notes).check()   # what `galileo track` writes, `Tracks.load` reads


def scene_points(scene) -> dict[str, np.ndarray]:
    """What the camera should see of the scene (world points by name): the tank's inner
    corners and the object where it is released."""
    sx, sy, sz = scene.tank.size_m
    corners = np.array([(x, y, z) for x in (-sx / 2, sx / 2) for y in (-sy / 2, sy / 2) for z in (0.0, sz)])
    return {"the tank": corners, "the object's release": np.asarray(scene.release_m, float)}
