"""Fall tracking: pixels -> the dropped object's image track, its release and its rest.

The video shows an object held by a hand above a surface; the hand lets go; the object falls
(blurred), hits the surface, bounces, tumbles, slides and comes to rest; the hand (and its
arm) stays in view and keeps moving. The camera stands still. Nothing about the scene is
needed: the surface's outline, where given, only chooses where the object may come to rest.
One pass over the video (`galileo.video.VideoStream`; a second for the debug video), memory
bounded by DETECT_MAX_FRAMES small frames; everything runs at the detection scale (at most
DETECT_MAX_PX a frame) and centroids are carried to full-frame pixels:

1. Change: a pixel of frame f has changed from the start where it differs from the first
   frame by more than the noise, from the end where it differs from the last: in luma by more
   than CHANGE_MIN_DIFF, or lighter or in chroma by more than HUE_MIN_DIFF (a shadow only
   darkens, keeping the hue, so an object a little lighter than the surface, or of another
   hue, is caught where a shadow as faint is not).
   At the start the object is in the hand, at the end it lies on the surface: a moving object
   differs from both, its empty starting place (the hand gone) from neither. What touches the
   image's border (an arm reaching in) is dropped.
2. The resting place: the lowest in the image (inside the surface's outline where given) of
   what differs between the last and the first frame: the object fell below the hand.
3. Back-tracking: from there, frame by frame back in time, the object's blob is the component
   of (changed from the start) and (changed from the end, or on the resting place), opened,
   whose centroid lies within LINK_GATE sizes plus its last step of the later blob's and
   whose area is nearest that blob's (at most AREA_GROW times it: more is the hand); LINK_GAP
   frames may miss it. Going back past the release it ends, or picks up pieces of the hand.
4. The outline: the blob with its soft shadow trimmed (`_trim_shadow`: its lighter or re-hued
   part where that is at least HUED_SHARE of it, else what lies in the convex hull of its sharp
   edges), holes filled. A blurred object's streak is symmetric about its mean position
   over the exposure, so the outline's centroid is that mean; its extent is the minimum-area
   rectangle's two sides.
5. Release: from the frame in which the object has fallen RELEASE_FALLEN_SHARE of its drop
   (image rows), back in time while its blob lies higher than the later one and covers at most
   RELEASE_AREA_GROW times its area (a blurred fall's streak shortens back in time; a blob that
   grows is the object merged with the hand, or held).
6. Rest: the first frame from which the object's outline looks as in the last frame (at most
   REST_CHANGED_FRACTION of it changed from the end) in every frame up to the end, over at
   least REST_MIN_FRAMES frames; None if it still moves at the end.

Known limits: the release found is the first frame in which the object's blob has parted from
the hand's, 1-2 frames after the hand opens (while they touch in the image the blob is theirs
together), and in that first frame the grip the hand lifts off may still count (4 px on the
test's clip). A face within HUE_MIN_DIFF of the surface's colour is lost, and one just above it
is lost where the fall's blur spreads it (the Physics 101 block's top face against the cream
table: its centroid lies ~6 px low there); where most of the blob is lighter or re-hued, a dark
face of the surface's own hue is taken for shadow and dropped.

Pixels are the full frame's, u right, v down; frames count from 0.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ...errors import GalileoError, StillVideo
from ...progress import tqdm
from ...video import VideoStream, write_video, yuv_to_rgb
from ...vision.background import noise_sd, yuv_image

DETECT_MAX_PX = 480 * 270      # everything runs at most at this many pixels a frame
DETECT_MAX_FRAMES = 450        # ... over at most this many first frames (15 s at 30 fps), kept at that size
MIN_FRAMES = 8                 # a video shorter than this cannot show a fall and a rest
CHANGE_MIN_DIFF = 12.0         # a pixel has changed when its luma differs by more than this (levels) ...
HUE_MIN_DIFF = 4.0             # ... or it got lighter, or its chroma (U or V) differs, by more than this (a shadow
                               # only darkens, keeping the hue) ...
CHANGE_NOISE_SDS = 5.0         # ... and either by more than this many noise SDs
MIN_BLOB_PX = 6                # a moving blob covers at least this many pixels (detection scale)
LINK_GATE = 1.0                # the object's blob in an earlier frame: within this many of its sizes of the prediction ...
LINK_MIN_PX = 4                # ... or this many pixels (detection scale)
AREA_GROW = 3.0                # ... covering at most this many times its area (more: merged with the hand)
LINK_GAP = 2                   # the back-tracking may miss this many frames (the object too faint in its blur)
DESCENT_MIN_PX = 8.0           # the object falls at least this far down the image (detection scale)
RELEASE_FALLEN_SHARE = 0.5     # the release: back in time from where the object has fallen this share of its drop ...
RELEASE_AREA_GROW = 1.3        # ... while its blob grows at most this much a frame (more: merged with the hand)
EDGE_SMOOTH_PX = 0.7           # the shadow test: luma smoothed by a Gaussian of this SD (detection scale) ...
EDGE_MIN_SHARE = 0.5           # ... a sharp edge's gradient exceeds this share of the change threshold per pixel ...
EDGE_MIN_PIXELS = 20           # ... (at least this many of them, else no trimming) ...
EDGE_GROW_PX = 1               # ... and the outline keeps what lies within this of their convex hull ...
HUED_SHARE = 0.5               # ... unless this share of the blob got lighter or changed chroma: then that part
REST_CHANGED_FRACTION = 0.03   # at rest: at most this share of the outline's pixels differ from the last frame
REST_MIN_FRAMES = 3            # ... over at least this many frames up to the end
DEBUG_MAX_WIDTH_PX = 960       # the debug video's width at most
DEBUG_FREE, DEBUG_HELD, DEBUG_TEXT = (255, 200, 0), (160, 160, 160), (255, 40, 40)   # debug video (RGB)


@dataclass
class FallPixelTrack:
    fps: float
    center_px: np.ndarray     # (F, 2) the object's silhouette centroid (u right, v down), NaN where not seen
    size_px: np.ndarray       # (F, 2) the silhouette's minimum-area rectangle's long and short sides (px), NaN where not seen
    visible: np.ndarray       # (F,) bool: the object is seen and the hand has let go of it
    release_frame: int        # the first frame in which the object is free of the hand
    rest_frame: int | None    # the first frame from which the object no longer moves (None: still moving at the end)
    method: str               # a short word on how it was found
    notes: list[str] = field(default_factory=list)   # what the user should know, one line each


def _no_fall(video_path, why: str) -> GalileoError:
    return GalileoError(f"no object falls in {video_path}: {why}; is this a fall video (an object dropped by hand "
                        f"onto a surface, filmed by a still camera)?")


def track_pixels(video_path: str | Path, *, region_px=None, progress: bool = True,
                 debug_video: str | Path | None = None) -> FallPixelTrack:
    """The dropped object's silhouette centroid and extent in every frame, its release and rest
    frames (module docstring).

    `region_px`: (N, 2) the surface's outline (pixels) where known: the object comes to rest
    inside it. `debug_video`: an MP4 path for the frames (at most DEBUG_MAX_WIDTH_PX wide) with
    the centroid, the outline's rectangle and held/free drawn (a third pass)."""
    video = VideoStream(video_path, min_frames=MIN_FRAMES)
    region = None
    if region_px is not None:
        region = np.asarray(region_px, float).reshape(-1, 2)
        if len(region) < 3 or not np.isfinite(region).all():
            raise GalileoError(f"the surface's outline needs at least 3 finite corners (pixels), got {len(region)}")
    bar = tqdm(desc="tracking", unit="frame", disable=not progress)
    try:
        return _track(video, video_path, region, bar, debug_video)
    finally:
        bar.close()


# -- detection scale -------------------------------------------------------------------------------

def _changed(a: np.ndarray, b: np.ndarray, tau: tuple[float, float]) -> np.ndarray:
    """Pixels of Y, U, V image a that differ from b's by more than tau = (luma, hue) thresholds:
    in luma by more than the first, or lighter or in either chroma channel by more than the
    second (boolean)."""
    return (cv2.absdiff(a[..., 0], b[..., 0]) > tau[0]) | _own(a, b, tau)


def _own(a: np.ndarray, b: np.ndarray, tau: tuple[float, float]) -> np.ndarray:
    """Pixels of a lighter than b's, or of another chroma, by more than tau's hue threshold
    (boolean): what an object brings that the shadow it casts (only darker, of the same hue)
    does not."""
    return (cv2.subtract(a[..., 0], b[..., 0]) > tau[1]) | (cv2.absdiff(a[..., 1:], b[..., 1:]).max(axis=-1) > tau[1])


def _off_border(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The mask's 8-connected components that do not touch the image's border and cover at
    least MIN_BLOB_PX: (labels, with the others set to 0; their stats; their centroids)."""
    _, labels, stats, cents = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    h, w = mask.shape
    x, y, bw, bh, area = (stats[:, i] for i in range(5))
    keep = (x > 0) & (y > 0) & (x + bw < w) & (y + bh < h) & (area >= MIN_BLOB_PX)
    keep[0] = False
    labels[~keep[labels]] = 0
    return labels, stats, cents


def _inside(region_det: np.ndarray | None, pt: np.ndarray) -> bool:
    """Whether a point lies inside the surface's outline (True where none is given)."""
    return region_det is None or cv2.pointPolygonTest(region_det.astype(np.float32), (float(pt[0]), float(pt[1])),
                                                      False) >= 0


def _rest_place(small: list[np.ndarray], tau: float, region_det) -> np.ndarray | None:
    """Where the object is in the last frame (boolean, detection scale): the lowest in the image
    of what differs between the last and the first frame, off the border, opened (inside the
    surface's outline where given): the object fell below the hand that held it. None if
    nothing differs."""
    opened = cv2.morphologyEx(_changed(small[-1], small[0], tau).astype(np.uint8), cv2.MORPH_OPEN,
                              np.ones((3, 3), np.uint8))
    labels, stats, cents = _off_border(opened)
    ids = [i for i in np.unique(labels) if i and _inside(region_det, cents[i])]
    if not ids:
        return None
    return labels == max(ids, key=lambda i: stats[i, cv2.CC_STAT_TOP] + stats[i, cv2.CC_STAT_HEIGHT])


def _back_track(small: list[np.ndarray], tau: float, rest: np.ndarray) -> dict[int, np.ndarray]:
    """The object's blob per frame (detection scale), followed from its place in the last frame
    back to where it leaves the hand: in each earlier frame, the opened components of what
    differs from the first frame and (from the last frame, or lies on the resting place) that
    touch the later blob moved by its velocity and grown by LINK_GATE times its size plus its
    step; up to LINK_GAP frames may miss it."""
    first, last = small[0], small[-1]
    blobs = {len(small) - 1: rest}
    prev, vel, missed = rest, np.zeros(2), 0
    centre = lambda m: np.array([np.nonzero(m)[1].mean(), np.nonzero(m)[0].mean()])
    for f in range(len(small) - 2, 0, -1):
        obj = _changed(small[f], first, tau) & (_changed(small[f], last, tau) | rest)
        labels, stats, cents = _off_border(cv2.morphologyEx(obj.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)))
        ys, xs = np.nonzero(prev)
        size = math.hypot(np.ptp(xs) + 1, np.ptp(ys) + 1)
        shift = vel * (missed + 1)
        gate = max(LINK_MIN_PX, LINK_GATE * size + float(np.linalg.norm(shift)))
        area = float(prev.sum())
        cost = {i: float(np.linalg.norm(cents[i] - centre(prev))) / gate + abs(math.log(stats[i, cv2.CC_STAT_AREA] / area))
                for i in np.unique(labels) if i and np.linalg.norm(cents[i] - centre(prev)) <= gate}
        ids = [min(cost, key=cost.get)] if cost else []
        if not ids:
            missed += 1
            if missed > LINK_GAP:
                break
            continue
        m = np.isin(labels, ids)
        vel = (centre(m) - centre(prev)) / (missed + 1)
        blobs[f], prev, missed = m, m, 0
    return blobs


# -- the passes --------------------------------------------------------------------------------------

def _to_scale(px, s_from: float, s_to: float) -> np.ndarray:
    """Pixel coordinates in an image resized by s_from (of the full frame) -> by s_to
    (area resizing: pixel centres at (x + 0.5) s - 0.5)."""
    return (np.asarray(px, float) + 0.5) * (s_to / s_from) - 0.5


def _track(video: VideoStream, video_path, region, bar, debug_video) -> FallPixelTrack:
    hw = (video.height_px, video.width_px)
    det = min(1.0, math.sqrt(DETECT_MAX_PX / (hw[0] * hw[1])))
    # the pass: the small frames
    small = []
    for f, (y, uv) in enumerate(video.yuv()):
        bar.update()
        if f < DETECT_MAX_FRAMES:
            small.append(yuv_image(y, uv, det))
    n = len(small)
    bar.total = video.n_frames   # (a bar a pass: this one, and the debug video's)
    bar.refresh()
    noise_det = noise_sd(np.stack(small[:2]).astype(np.float32))
    tau_det = (max(CHANGE_MIN_DIFF, CHANGE_NOISE_SDS * noise_det), max(HUE_MIN_DIFF, CHANGE_NOISE_SDS * noise_det))
    region_det = None if region is None else _to_scale(region, 1.0, det)

    rest_det = _rest_place(small, tau_det, region_det)
    if rest_det is None:
        raise StillVideo(str(_no_fall(video_path, "nothing in its last frame differs from its first apart from what "
                                                   "reaches in from the frame's edge")))
    rough = _back_track(small, tau_det, rest_det)
    ys = [np.nonzero(m)[0].mean() for m in (rough[min(rough)], rest_det)]
    if ys[1] - ys[0] < DESCENT_MIN_PX:
        raise _no_fall(video_path, f"nothing that moves apart from what reaches in from the frame's edge falls "
                                   f"{DESCENT_MIN_PX / det:.0f} px or more down the image")

    # the outline per frame: the blob, its soft shadow trimmed, holes filled
    centre = np.full((video.n_frames, 2), np.nan)
    size = np.full((video.n_frames, 2), np.nan)
    boxes: dict[int, np.ndarray] = {}
    still = np.zeros(video.n_frames, bool)
    for f, m in rough.items():
        sil = _trim_shadow(m.astype(np.uint8), small[f][..., 0], tau_det[0], _own(small[f], small[0], tau_det))
        contours, _ = cv2.findContours(sil, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        filled = np.zeros(sil.shape, np.uint8)
        cv2.drawContours(filled, contours, -1, 1, -1)
        ys, xs = np.nonzero(filled)
        if len(xs) < MIN_BLOB_PX:
            continue
        centre[f] = _to_scale([xs.mean(), ys.mean()], det, 1.0)
        (cx, cy), (a, b), ang = cv2.minAreaRect(np.c_[xs, ys].astype(np.float32))
        a, b = (a + 1) / det, (b + 1) / det        # (pixel areas, not centres)
        size[f] = [max(a, b), min(a, b)]
        boxes[f] = cv2.boxPoints((tuple(_to_scale([cx, cy], det, 1.0)), (a, b), ang))
        still[f] = np.count_nonzero(_changed(small[f], small[-1], tau_det) & (filled > 0)) <= \
            REST_CHANGED_FRACTION * len(xs)

    release = _release(rough)
    visible = np.isfinite(centre[:, 0]) & (np.arange(video.n_frames) >= release)
    centre[~visible], size[~visible] = np.nan, np.nan
    rest = None
    if still[n - 1]:
        r = n - 1
        while r > release and still[r - 1]:
            r -= 1
        rest = r if n - r >= REST_MIN_FRAMES else None
    notes = []
    lost = [f for f in range(release, video.n_frames) if not visible[f]]
    if lost:
        notes.append(f"the object is not found in {len(lost)} of the {video.n_frames - release} frames from its "
                     f"release (frame {release}) on ({_ranges(lost)}): too faint in its blur, or hidden")
    if rest is None:
        notes.append("the object still moves at the clip's end: no rest frame")
    if video.n_frames > DETECT_MAX_FRAMES:
        notes.append(f"only the first {DETECT_MAX_FRAMES} frames are tracked")
    if video.timing_note():
        notes.append(video.timing_note())
    method = "change (luma, lighter, hue) from first and last frames, back-tracked from rest, outline centroid"
    track = FallPixelTrack(float(video.fps), centre, size, visible, int(release), rest, method, notes)
    if debug_video is not None:
        bar.set_description("tracking: writing the debug video", refresh=False)
        bar.reset(total=video.n_frames)
        _write_debug(debug_video, video, bar, track, boxes)
    return track


def _trim_shadow(obj: np.ndarray, luma: np.ndarray, tau: float, hued: np.ndarray) -> np.ndarray:
    """The blob `obj` without the soft shadow the object casts on the surface (that darkens it,
    keeping its hue): where at least HUED_SHARE of the blob got lighter or changed chroma
    (`hued`: `_own`), that part, closed; else the blob's pixels within EDGE_GROW_PX of the
    convex hull of the sharp edges among them (luma gradient above EDGE_MIN_SHARE of the luma
    change threshold tau per pixel: an object's outline is sharp, a shadow's is not), or hued.
    Unchanged where fewer than EDGE_MIN_PIXELS edge pixels are found."""
    own = obj & hued.astype(np.uint8)
    if np.count_nonzero(own) >= HUED_SHARE * np.count_nonzero(obj):
        return cv2.morphologyEx(own, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    g = cv2.GaussianBlur(luma.astype(np.float32), (0, 0), EDGE_SMOOTH_PX)
    grad = np.hypot(cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3)) / 8.0
    grown = cv2.dilate(obj, np.ones((3, 3), np.uint8)) > 0
    ys, xs = np.nonzero(grown & (grad > EDGE_MIN_SHARE * tau))
    if len(xs) < EDGE_MIN_PIXELS:
        return obj
    hull = np.zeros(obj.shape, np.uint8)
    cv2.fillConvexPoly(hull, cv2.convexHull(np.c_[xs, ys].astype(np.int32)), 1)
    hull = cv2.dilate(hull, np.ones((2 * EDGE_GROW_PX + 1,) * 2, np.uint8))
    return obj & (hull | own)


def _ranges(frames: list[int]) -> str:
    """'frames 3-5, 9' for [3, 4, 5, 9]."""
    parts, s = [], frames[0]
    for a, b in zip(frames, frames[1:] + [None]):
        if b != a + 1:
            parts.append(f"{s}-{a}" if a > s else f"{s}")
            s = b
    return "frames " + ", ".join(parts)


def _release(rough: dict[int, np.ndarray]) -> int:
    """The release frame (module docstring, step 5) from the object's blobs per frame
    (detection scale), followed back from its end."""
    frames = sorted(rough)
    area = np.array([float(rough[f].sum()) for f in frames])
    v = np.array([np.nonzero(rough[f])[0].mean() for f in frames])
    i = int(np.argmax(v >= v[0] + RELEASE_FALLEN_SHARE * (v.max() - v[0])))
    while i > 0 and v[i - 1] < v[i] and area[i - 1] <= RELEASE_AREA_GROW * area[i]:
        i -= 1
    return frames[i]


def _write_debug(path, video: VideoStream, bar, track: FallPixelTrack, boxes: dict) -> None:
    """The frames (at most DEBUG_MAX_WIDTH_PX wide) with the centroid, the outline's rectangle
    and whether the object is held or free drawn (another pass)."""
    s = min(1.0, DEBUG_MAX_WIDTH_PX / video.width_px)
    size = (round(video.width_px * s) // 2 * 2, round(video.height_px * s) // 2 * 2)

    def drawn():
        for f, (y, uv) in enumerate(video.yuv()):
            bar.update()
            img = cv2.resize(yuv_to_rgb(y, uv), size, interpolation=cv2.INTER_AREA)
            if track.visible[f]:
                cv2.polylines(img, [np.round(_to_scale(boxes[f], 1.0, s)).astype(np.int32)], True, DEBUG_FREE, 1)
                c = np.round(_to_scale(track.center_px[f], 1.0, s)).astype(int)
                cv2.drawMarker(img, (int(c[0]), int(c[1])), DEBUG_FREE, cv2.MARKER_CROSS, 10, 1)
            state = "held" if f < track.release_frame else ("rest" if track.rest_frame is not None
                                                             and f >= track.rest_frame else "free")
            cv2.putText(img, f"frame {f} {state}", (8, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, DEBUG_TEXT, 1)
            yield img

    write_video(path, drawn(), track.fps)
