"""Spring tracking: pixels -> the hanging object's image position in every frame.

The video shows an object hanging from a spring; a hand holds it away from rest (pulled down
or lifted) and lets go; it bounces (and sways) until the video ends, freely over the clip's last
FREE_PART at least. Nothing about the scene is needed: the hanging point and a click on the
object, where given, only choose among moving things. Three passes over the video
(`galileo.video.VideoStream`), memory bounded by DETECT_MAX_FRAMES small frames and a few dozen
crops around the object:

1. Where (at most DETECT_MAX_PX a frame): the share of frames in which each pixel changes by
   more than the noise. The object and the spring's lower coils keep moving all clip long; a
   hand passes a pixel in a few frames. Regions moving in at least PERSIST_MIN of the frames
   are the candidates, most moving first (nearest `object_px` first, where given).
2. Rough track: KLT features (`galileo.vision.klt`) seeded in a candidate at a late frame and
   followed frame to frame both ways. The object's are the largest group that moves together
   (within GROUP_TOL_PX) with a large vertical amplitude: the background stands still, each of a
   spring's coils moves its own share of the object's motion. The group's median displacement
   is the rough track; its vertical part must be a damped oscillation (`fit_oscillation`: R^2
   at least OSC_MIN_R2 over OSC_MIN_PERIODS periods), else the candidate is not the object.
3. The object's outline (at most TRACK_MAX_PX a frame), at SEG_REFS reference frames (turning
   points, spread over the free bounce), each from SEG_FRAMES frames around it moved back by the
   object's displacement (its features' KLT from the reference):
   a. pixels that look alike in those frames (they move with the object) and unlike the scene
      where it then is (the median frame, shifted) vote for the object;
   b. GrabCut from the votes (sure background: still in the frames and unlike the object);
   c. Fisher's discriminant in (Y, U, V) between the thickest part of what GrabCut found and a
      ring around it, split halfway, holes filled, thin parts cut off (opening with a disc of
      OBJECT_FRACTION of its inscribed one): the object without the spring, a knot or a bag's
      neck, corners kept;
   d. its centre: the centre of symmetry of that outline (a box, a cylinder, a ball are point
      symmetric; what hangs on one side has no counterpart); its size: the symmetric part's box.
   The reference whose centre (carried to a common frame by the rough track) is the middle one
   is kept: one that caught the spring or a hand is outvoted.
4. Matching (third pass): that reference's patch, masked by the outline grown MATCH_EDGE_PX,
   matched by normalised cross-correlation around the rough track's prediction in every frame,
   the peak refined to sub-pixel; a frame whose best match scores below MATCH_MIN (a hand in
   front, out of view) has no centre.
5. Release: from a frame on, the vertical motion is a damped oscillation: the one fitted to
   the RELEASE_FIT_PERIODS period after each frame predicts it within max(RELEASE_TOL_SDS x the
   prediction noise, RELEASE_TOL_AMP x its amplitude, RELEASE_TOL_MIN_PX); the release frame is
   the first of RELEASE_RUN such frames in a row. A held object stands still (or follows the
   hand) where a free one would turn back: tens of pixels off.

Pixels are the full frame's, x right, y down; frames count from 0.
"""
from __future__ import annotations

import math
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ...errors import GalileoError, StillVideo
from ...progress import tqdm
from ...video import VideoStream
from ...vision import MAD_TO_SD
from ...vision.background import noise_sd, resize_to, spread
from ...vision.klt import flow, seed_features
from ...vision.silhouette import pixel_hull

DETECT_MAX_PX = 480 * 270      # detection and the rough track run at most at this many pixels a frame
DETECT_MAX_FRAMES = 900        # ... over at most this many first frames (30 s at 30 fps), kept at that size
TRACK_MAX_PX = 960 * 540       # the silhouette and the matching run at most at this many pixels a frame
MIN_FRAMES = 10                # a video shorter than this cannot show a bounce
MOVE_MIN_DIFF = 12.0           # a pixel moves between frames when its luma changes by more than this ...
MOVE_NOISE_SDS = 5.0           # ... and this many noise SDs
PERSIST_MIN = 0.1              # the oscillator's region: pixels moving in at least this share of the frames
CANDIDATES = 3                 # moving regions tried, largest (summed share) first
N_FEATURES = 200               # KLT features seeded in a candidate region (detection scale)
GROUP_TOL_PX = 1.0             # features move together: median distance of their displacements (detection px)
GROUP_AMP_FRACTION = 0.3       # the object's features move at least this fraction of the most moving ones' amplitude
MIN_GROUP = 3                  # fewer features than this in a frame: no rough position there
OSC_MIN_R2 = 0.8               # a damped oscillation explains at least this share of the vertical motion's variance
OSC_MIN_PERIODS = 1.5          # ... over at least this many periods
OSC_MIN_AMP_PX = 2.0           # ... of at least this amplitude (detection px)
SEG_FRAMES = 32                # frames the silhouette is found from ...
SEG_PERIODS = 1.5              # ... within this many periods of the reference frame
SEG_REFS = 3                   # reference frames the object is found in (the middle finding is kept)
NOISE_UNKNOWN = 2.0            # the noise (levels) assumed where the video has a single frame to measure it
SEG_MIN_DIFF = 10.0            # a pixel looks alike when it differs by less than this (any of Y, U, V) ...
SEG_NOISE_SDS = 4.0            # ... and this many noise SDs
SEG_VOTES = 0.3                # moving with the object: like it and unlike the scene in this share of the frames ...
SEG_SURE = 0.5                 # ... surely the object in this share
SEG_STILL = 0.5                # surely the scene: like the reference and unlike the object in this share
ALLOW_PX = 9                   # the object lies within what moves with it, grown by this (track px)
GRABCUT_ITERATIONS = 5
GRABCUT_SEED = 0        # GrabCut starts its colour models by k-means from OpenCV's process-wide random state:
                        # seeded before each call, the outline does not depend on what ran before
RING_PX = 15                   # the object's surroundings: what lies within this of the region GrabCut finds (track px)
CORE_FRACTION = 0.9            # the object's thickest part: covered by discs of this fraction of its inscribed one
OBJECT_FRACTION = 0.3          # the object: what discs of this fraction cover (thinner attachments are cut off)
MATCH_EDGE_PX = 1              # the matched part reaches this far beyond the object's outline (its edges)
ROI_GROW = 1.0                 # the region searched: grown by this times the group's size or the track's range
MATCH_MIN = 0.5                # a frame's best match must score at least this (normalised cross-correlation)
SEARCH_PX = 12                 # matches are searched this far around the prediction (track scale) ...
SEARCH_LOST_PX = 40            # ... and this far where the rough track has no position
RELEASE_FIT_PERIODS = 1.0      # the release: the oscillation fitted to this many periods after a frame ...
RELEASE_OMEGA_SPAN = 0.06      # ... (its frequency within this fraction of the clip's) ...
RELEASE_TOL_SDS = 4.0          # ... predicts it within this many SDs of the prediction noise ...
RELEASE_TOL_AMP = 0.1          # ... or this fraction of its amplitude (the model is rougher on large bounces) ...
RELEASE_TOL_MIN_PX = 1.5       # ... or this many pixels ...
RELEASE_RUN = 3                # ... in this many frames in a row: the first is the release
FREE_PART = 0.5                # the clip's last half shows the object bouncing freely (the hand has let go before)
DEBUG_FREE, DEBUG_HELD, DEBUG_TEXT = (255, 200, 0), (160, 160, 160), (255, 40, 40)   # debug video (RGB)


@dataclass
class PixelTrack:
    fps: float
    center_px: np.ndarray      # (F, 2) the object's centre (x right, y down) in every frame, NaN where unknown
    visible: np.ndarray        # (F,) tracked and free (from release_frame on)
    release_frame: int         # the first frame in which the object moves freely
    top_px: tuple[float, float] | None   # the spring's top (the hanging point) if given, else None
    size_px: tuple[float, float]         # the object's width, height in pixels (its outline's symmetric part)
    method: str                # one line: how it tracked
    notes: list[str] = field(default_factory=list)   # what the user should know, one line each


# -- a damped oscillation -----------------------------------------------------------------------

@dataclass
class Oscillation:
    """y(t) = c + exp(-gamma (t - t0)) (a cos(omega (t - t0)) + b sin(omega (t - t0))), t in frames."""
    omega: float          # rad per frame
    gamma: float          # per frame
    coef: np.ndarray      # c, a, b
    t0: float
    rms: float            # residual RMS
    r2: float             # share of the variance explained

    @property
    def period(self) -> float:
        return 2 * math.pi / self.omega


def _basis(t: np.ndarray, omega: float, gamma: float) -> np.ndarray:
    e = np.exp(-gamma * t)
    return np.stack([np.ones_like(t), e * np.cos(omega * t), e * np.sin(omega * t)], axis=-1)


def _lsq(t: np.ndarray, y: np.ndarray, omega: float, gamma: float) -> tuple[np.ndarray, float]:
    a = _basis(t, omega, gamma)
    coef = np.linalg.lstsq(a, y, rcond=None)[0]
    return coef, float(np.sum((a @ coef - y) ** 2))


def _spectral_omega(t: np.ndarray, y: np.ndarray) -> float | None:
    """The angular frequency (rad per frame) of the highest peak of y's spectrum (gaps filled
    linearly), between a period of 3 frames and the span over OSC_MIN_PERIODS; None if the span
    is too short."""
    n = int(t[-1] - t[0]) + 1
    if n < 8:
        return None
    yy = np.interp(np.arange(n) + t[0], t, y)
    yy = (yy - yy.mean()) * np.hanning(n)
    pad = 8 * n
    p = np.abs(np.fft.rfft(yy, pad)) ** 2
    f = np.fft.rfftfreq(pad)          # cycles per frame
    ok = (f >= OSC_MIN_PERIODS / n) & (f <= 1 / 3)
    if not ok.any():
        return None
    return float(2 * math.pi * f[ok][np.argmax(p[ok])])


def fit_oscillation(t: np.ndarray, y: np.ndarray, omega0: float | None = None) -> Oscillation | None:
    """The damped oscillation closest (least squares) to samples y at frames t: the frequency
    from the spectrum's peak (or omega0), then frequency and decay by a grid narrowed three
    times, the offset and the two amplitudes linear. None with fewer than 6 samples or no peak."""
    t, y = np.asarray(t, float), np.asarray(y, float)
    if len(t) < 6:
        return None
    omega0 = omega0 if omega0 is not None else _spectral_omega(t, y)
    if omega0 is None:
        return None
    t0 = float(t[0])
    tt = t - t0
    span = max(float(tt[-1]), 1.0)
    w_lo, w_hi, g_lo, g_hi = 0.8 * omega0, 1.2 * omega0, 0.0, 5.0 / span
    for _ in range(3):
        best = None
        for w in np.linspace(w_lo, w_hi, 21):
            for g in np.linspace(g_lo, g_hi, 11):
                coef, sse = _lsq(tt, y, w, g)
                if best is None or sse < best[0]:
                    best = (sse, w, g, coef)
        sse, w, g, coef = best
        dw, dg = (w_hi - w_lo) / 10, (g_hi - g_lo) / 5
        w_lo, w_hi, g_lo, g_hi = w - dw, w + dw, max(g - dg, 0.0), g + dg
    sst = float(np.sum((y - y.mean()) ** 2))
    return Oscillation(float(w), float(g), coef, t0, math.sqrt(sse / len(y)), 1 - sse / sst if sst > 0 else 0.0)


def _oscillates(osc: Oscillation | None, t: np.ndarray, min_amp: float) -> bool:
    """Whether the fit shows a clear bounce: see OSC_MIN_R2, OSC_MIN_PERIODS, OSC_MIN_AMP_PX."""
    if osc is None:
        return False
    amp = math.hypot(osc.coef[1], osc.coef[2])
    return osc.r2 >= OSC_MIN_R2 and (t[-1] - t[0]) >= OSC_MIN_PERIODS * osc.period and amp >= min_amp


# -- 1 and 2: where, and the rough track (detection scale) ---------------------------------------

def _scale(hw: tuple[int, int], most_px: int) -> float:
    """The scale of a frame (height, width `hw`) at which it has at most `most_px` pixels (at most 1)."""
    return min(1.0, math.sqrt(most_px / (hw[0] * hw[1])))


def _candidates(persist: np.ndarray, object_px_det, top_px_det) -> list[np.ndarray]:
    """Regions moving in at least PERSIST_MIN of the frames, most moving first (nearest the
    click first, where given; those reaching below the hanging point only, where given)."""
    m = cv2.morphologyEx((persist >= PERSIST_MIN).astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    regions = []
    for i in range(1, n):
        if top_px_det is not None and stats[i, cv2.CC_STAT_TOP] + stats[i, cv2.CC_STAT_HEIGHT] <= top_px_det[1]:
            continue
        r = labels == i
        key = -float(persist[r].sum())
        if object_px_det is not None:
            ys, xs = np.nonzero(r)
            key = float(np.min(np.hypot(xs - object_px_det[0], ys - object_px_det[1])))
        regions.append((key, r))
    regions.sort(key=lambda kr: kr[0])
    return [r for _, r in regions[:CANDIDATES]]


@dataclass
class _Rough:
    disp: np.ndarray       # (T, 2) the object's displacement from frame `ta` (detection px), NaN where unknown
    pts: np.ndarray        # (K, 2) its features at frame `ta`
    ta: int
    osc: Oscillation       # the vertical motion's fit (frames from the free part)
    region: np.ndarray     # the moving region it was found in


@contextmanager
def _quiet():
    """numpy's nan-reductions over all-NaN slices (features lost there) warn; NaN is what is meant."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        yield


def _klt_tracks(small: list[np.ndarray], ta: int, pts: np.ndarray) -> np.ndarray:
    """(T, K, 2) positions of the features `pts` seeded at frame ta, followed frame to frame
    forwards and backwards (KLT from a constant-velocity guess, forward-backward checked);
    NaN from where each is lost."""
    tracks = np.full((len(small), len(pts), 2), np.nan, np.float32)
    tracks[ta] = pts
    for step in (1, -1):
        cur, vel, idx, prev = pts.copy(), np.zeros_like(pts), np.arange(len(pts)), ta
        for i in range(ta + step, len(small) if step > 0 else -1, step):
            new, ok = flow(small[prev], small[i], cur, cur + vel)
            vel, cur, idx = (new - cur)[ok], new[ok], idx[ok]
            if not len(idx):
                break
            tracks[i, idx] = cur
            prev = i
    return tracks


def _group(tracks: np.ndarray, ta: int) -> np.ndarray:
    """Indices of the object's features: the largest group of features that move together
    (within GROUP_TOL_PX) with a large vertical amplitude (GROUP_AMP_FRACTION)."""
    disp = tracks - tracks[ta][None]
    with _quiet():
        amp = np.nanstd(disp[..., 1], axis=0)
    amp = np.nan_to_num(amp)
    best = np.zeros(0, int)
    for j in np.flatnonzero(amp >= GROUP_AMP_FRACTION * np.percentile(amp, 90)):
        with _quiet():
            d = np.nanmedian(np.linalg.norm(disp - disp[:, j:j + 1], axis=2), axis=0)
        g = np.flatnonzero(np.nan_to_num(d, nan=np.inf) <= GROUP_TOL_PX)
        if len(g) > len(best):
            best = g
    return best


def _rough_track(small: list[np.ndarray], region: np.ndarray) -> _Rough | None:
    """The rough track of the object in a moving region (module docstring, step 2); None where
    no group of features bounces."""
    t_n = len(small)
    ta = (2 * t_n) // 3   # late: the hand has let go and left by then
    seeds = seed_features(small[ta], cv2.dilate(region.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0,
                          N_FEATURES, win=3)
    if len(seeds) < MIN_GROUP:
        return None
    tracks = _klt_tracks(small, ta, seeds)
    g = _group(tracks, ta)
    if len(g) < MIN_GROUP:
        return None
    disp = tracks[:, g] - tracks[ta, g][None]
    with _quiet():
        d = np.nanmedian(disp, axis=1)
    d[np.isfinite(disp[..., 0]).sum(axis=1) < MIN_GROUP] = np.nan
    t = np.flatnonzero(np.isfinite(d[:, 1]) & (np.arange(t_n) >= int((1 - FREE_PART) * t_n)))
    if len(t) < 6:
        return None
    osc = fit_oscillation(t, d[t, 1])
    if not _oscillates(osc, t, OSC_MIN_AMP_PX):
        return None
    return _Rough(d, tracks[ta, g], ta, osc, region)


# -- 3: the object's outline at a reference frame (the matching's scale) ---------------------------

def _to_scale(px, s_from: float, s_to: float) -> np.ndarray:
    """Pixel coordinates in an image resized by s_from (of the full frame) -> by s_to
    (area resizing: pixel centres at (x + 0.5) s - 0.5)."""
    return (np.asarray(px, float) + 0.5) * (s_to / s_from) - 0.5


def _fill_holes(mask: np.ndarray) -> np.ndarray:
    """The mask with its holes filled (each outer outline filled)."""
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    out = np.zeros(mask.shape, np.uint8)
    cv2.drawContours(out, contours, -1, 1, -1)
    return out > 0


def _component_with(mask: np.ndarray, pts: np.ndarray) -> np.ndarray | None:
    """The 8-connected component of the mask holding most of the points (None if none does)."""
    _, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    ij = np.round(pts).astype(int)
    inside = (ij[:, 0] >= 0) & (ij[:, 0] < mask.shape[1]) & (ij[:, 1] >= 0) & (ij[:, 1] < mask.shape[0])
    hits = labels[ij[inside, 1], ij[inside, 0]]
    hits = hits[hits > 0]
    if not len(hits):
        return None
    return labels == np.bincount(hits).argmax()


def silhouette(ref: np.ndarray, samples: list[tuple[np.ndarray, np.ndarray]],
               noise: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The object and the part of the image matched to follow it (boolean, (H, W) each) in the
    reference image `ref` (H, W, 3: Y, U, V), from `samples` (image, the object's displacement
    since the reference) (module docstring, step 3 a-c); None if none is found."""
    h, w = ref.shape[:2]

    def back(img, d):   # img moved back by d: the object where it is in the reference
        return cv2.warpAffine(img, np.float32([[1, 0, d[0]], [0, 1, d[1]]]), (w, h),
                              flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)

    tau = max(SEG_MIN_DIFF, SEG_NOISE_SDS * noise)
    ref_f = ref.astype(np.float32)
    imgs = [img.astype(np.float32) for img, _ in samples]
    steady = [back(img, d) for img, (_, d) in zip(imgs, samples)]
    look = np.median(np.stack(steady), axis=0)             # the object's look where it is in the reference
    scene = np.median(np.stack(imgs), axis=0)              # the scene, where the object mostly is not
    votes, unlike_obj, like_ref = (np.zeros((h, w), np.float32) for _ in range(3))
    for img, b, (_, d) in zip(imgs, steady, samples):
        like_object = np.abs(b - look).max(axis=-1) < tau
        votes += like_object & (np.abs(b - back(scene, d)).max(axis=-1) > tau)
        unlike_obj += ~like_object
        like_ref += np.abs(img - ref_f).max(axis=-1) < tau
    n = len(samples)
    moving = _fill_holes(cv2.morphologyEx((votes >= SEG_VOTES * n).astype(np.uint8), cv2.MORPH_CLOSE,
                                          np.ones((3, 3), np.uint8)) > 0)
    if not moving.any():
        return None
    # GrabCut (colour models and the image's edges) from the votes: sure object where most
    # frames vote for it, sure background where the scene stands still and does not move
    # with the object (and away from where anything moves with it)
    allowed = cv2.dilate(pixel_hull(moving).astype(np.uint8), np.ones((ALLOW_PX, ALLOW_PX), np.uint8)) > 0
    sure_bg = ((like_ref >= SEG_STILL * n) & (unlike_obj >= SEG_STILL * n)) | ~allowed
    region = _grabcut(ref, sure_bg, moving, votes >= SEG_SURE * n)
    if region is None:
        return None
    # the object's colours against its surroundings': the direction in (Y, U, V) that best
    # separates the thickest part of that region from a ring around it (Fisher's discriminant),
    # split halfway between the two; GrabCut's smoothing rounds off corners and keeps what clings
    # to the object (a bag), a pixel-wise split keeps the object's outline
    thickest = _thick_part(region, CORE_FRACTION)
    inner = cv2.erode(thickest.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    near = cv2.dilate(region.astype(np.uint8), np.ones((RING_PX, RING_PX), np.uint8)) > 0
    ring = near & ~(cv2.dilate(region.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0)
    obj = thickest
    coverage = thickest.astype(np.float32)
    if inner.sum() > 3 and ring.sum() > 3:
        yuv = ref.reshape(-1, 3).astype(np.float64)
        a, b = yuv[inner.ravel()], yuv[ring.ravel()]
        w_dir = np.linalg.solve(np.cov(a.T) + np.cov(b.T) + np.eye(3), a.mean(axis=0) - b.mean(axis=0))
        score = (yuv @ w_dir).reshape(h, w)
        split = (a.mean(axis=0) + b.mean(axis=0)) @ w_dir / 2
        found = _component_with((score > split) & near, _thickest_point(thickest))
        if found is not None:
            obj = _thick_part(_fill_holes(found), OBJECT_FRACTION)
            coverage = _coverage(obj, score, b.mean(axis=0) @ w_dir, a.mean(axis=0) @ w_dir)
    # what is matched: the object and its outline (where the edges are)
    return coverage, cv2.dilate(obj.astype(np.uint8), np.ones((2 * MATCH_EDGE_PX + 1,) * 2, np.uint8)) > 0


def _coverage(obj: np.ndarray, score: np.ndarray, outside: float, inside: float) -> np.ndarray:
    """The share of each pixel the object covers (float32, (H, W)): 1 inside its outline, 0
    away from it, and on the outline's two rows of pixels, one each side, where it is read from
    the discriminant's score. A pixel the edge crosses blends the two sides' colours in
    proportion, and so does its score; a whole-pixel outline would put each edge on one side or
    the other of such a pixel, and the centre up to half a pixel off, by a coin's toss."""
    o = obj.astype(np.uint8)
    band = (cv2.dilate(o, np.ones((3, 3), np.uint8)) > 0) & ~(cv2.erode(o, np.ones((3, 3), np.uint8)) > 0)
    cov = obj.astype(np.float32)
    if inside != outside:
        cov[band] = np.clip((score[band] - outside) / (inside - outside), 0.0, 1.0)
    return cov


def _grabcut(img: np.ndarray, sure_bg: np.ndarray, maybe_fg: np.ndarray, sure_fg: np.ndarray) -> np.ndarray | None:
    """The object's region (holes filled) by GrabCut from the seeds (the rest: maybe background);
    None where it finds none."""
    gc = np.full(img.shape[:2], cv2.GC_PR_BGD, np.uint8)
    gc[maybe_fg] = cv2.GC_PR_FGD
    gc[sure_fg] = cv2.GC_FGD
    gc[sure_bg] = cv2.GC_BGD
    if not (np.isin(gc, (cv2.GC_BGD, cv2.GC_PR_BGD)).any() and np.isin(gc, (cv2.GC_FGD, cv2.GC_PR_FGD)).any()):
        return None
    cv2.setRNGSeed(GRABCUT_SEED)
    cv2.grabCut(np.ascontiguousarray(img), gc, None, np.zeros((1, 65)), np.zeros((1, 65)), GRABCUT_ITERATIONS,
                cv2.GC_INIT_WITH_MASK)
    region = _fill_holes(np.isin(gc, (cv2.GC_FGD, cv2.GC_PR_FGD)))
    return region if region.any() else None


def _thickest_point(region: np.ndarray) -> np.ndarray:
    """(1, 2) the point farthest inside the region."""
    dist = cv2.distanceTransform(region.astype(np.uint8), cv2.DIST_L2, 5)
    return np.array(np.unravel_index(np.argmax(dist), dist.shape)[::-1], float)[None]


def _thick_part(region: np.ndarray, fraction: float) -> np.ndarray:
    """The region's part that discs of `fraction` of its largest inscribed one cover, around the
    thickest point: what is thinner (a spring, a bag's neck, a string) is cut off."""
    radius = float(cv2.distanceTransform(region.astype(np.uint8), cv2.DIST_L2, 5).max())
    k = 2 * max(1, int(fraction * radius)) + 1
    opened = cv2.morphologyEx(region.astype(np.uint8), cv2.MORPH_OPEN,
                              cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))) > 0
    part = _component_with(opened, _thickest_point(region))
    return part if part is not None else region


def centre_and_size(mask: np.ndarray) -> tuple[np.ndarray, tuple[float, float]]:
    """The object's centre (x, y) and size (width, height) in a mask of it (pixels; boolean, or
    the share of each pixel it covers, `_coverage`, whose outline is half covered): the centre
    of symmetry (the point reflection about it overlaps the mask most: the peak of the mask's
    self-convolution, at twice the centre, refined to sub-pixel) and the box of the symmetric
    part. A box, a cylinder, a ball look symmetric about their centre; what hangs on one side
    (the spring's end, a hook, a bag's neck) has no counterpart and barely moves the peak."""
    m = mask.astype(np.float32)
    shape = (2 * m.shape[0], 2 * m.shape[1])
    f = np.fft.rfft2(m, shape)
    conv = np.fft.irfft2(f * f, shape).astype(np.float32)
    x2, y2, _ = _peak(conv)
    c = np.array([x2, y2]) / 2.0
    flipped = cv2.warpAffine(m, np.float32([[-1, 0, 2 * c[0]], [0, -1, 2 * c[1]]]), (m.shape[1], m.shape[0]),
                             flags=cv2.INTER_NEAREST)
    ys, xs = np.nonzero((m >= 0.5) & (flipped >= 0.5))
    return c, (float(xs.max() - xs.min() + 1), float(ys.max() - ys.min() + 1))


# -- 4: matching --------------------------------------------------------------------------------------

def _peak(score: np.ndarray) -> tuple[float, float, float]:
    """The best score's position (x, y), refined to sub-pixel by a parabola through its
    neighbours along each axis, and the score."""
    _, best, _, (x, y) = cv2.minMaxLoc(score)

    def vertex(a, b, c):
        den = a - 2 * b + c
        return 0.5 * (a - c) / den if den < 0 else 0.0

    dx = vertex(score[y, x - 1], score[y, x], score[y, x + 1]) if 0 < x < score.shape[1] - 1 else 0.0
    dy = vertex(score[y - 1, x], score[y, x], score[y + 1, x]) if 0 < y < score.shape[0] - 1 else 0.0
    return x + dx, y + dy, float(best)


def match(img: np.ndarray, templ: np.ndarray, mask: np.ndarray, guess_tl: np.ndarray,
          radius: int) -> tuple[np.ndarray, float] | None:
    """Where the masked template's top-left corner matches best within `radius` of `guess_tl`
    (normalised cross-correlation), and the score; None where the window leaves the image."""
    th, tw = templ.shape
    x0, y0 = round(guess_tl[0]) - radius, round(guess_tl[1]) - radius
    x0c, y0c = max(x0, 0), max(y0, 0)
    x1c, y1c = min(x0 + tw + 2 * radius, img.shape[1]), min(y0 + th + 2 * radius, img.shape[0])
    if x1c - x0c < tw + 2 or y1c - y0c < th + 2:
        return None
    score = cv2.matchTemplate(img[y0c:y1c, x0c:x1c], templ, cv2.TM_CCOEFF_NORMED, mask=mask)
    score[~np.isfinite(score)] = -1.0
    x, y, best = _peak(score)
    return np.array([x0c + x, y0c + y]), best


# -- 5: the release ---------------------------------------------------------------------------------

def find_release(y: np.ndarray) -> int:
    """The first frame of the free bounce (module docstring, step 5). `y`: the vertical position
    per frame, NaN where unknown; the clip's last FREE_PART must bounce freely."""
    n = len(y)
    free = int((1 - FREE_PART) * n)
    t = np.flatnonzero(np.isfinite(y[free:])) + free
    osc = fit_oscillation(t, y[t])
    if osc is None:
        return free
    win = max(round(RELEASE_FIT_PERIODS * osc.period), 6)
    omegas = osc.omega * np.linspace(1 - RELEASE_OMEGA_SPAN, 1 + RELEASE_OMEGA_SPAN, 9)
    gammas = np.linspace(0.0, 3 * osc.gamma + 1e-3, 3)

    def predicted(r: int) -> tuple[float, float]:
        """y[r] less the damped oscillation fitted to the `win` known frames after r (its own
        frequency and decay near the global ones), and that oscillation's amplitude at r."""
        after = np.flatnonzero(np.isfinite(y[r + 1:]))[:win] + r + 1
        if len(after) < 6 or not np.isfinite(y[r]):
            return math.nan, 0.0
        best = min((_lsq(after - float(r), y[after], w, g) for w in omegas for g in gammas), key=lambda cs: cs[1])
        c = best[0]
        return float(y[r] - c[0] - c[1]), math.hypot(c[1], c[2])   # the fit at r: basis (1, 1, 0)

    late = [predicted(r)[0] for r in range(free, n - win, 3)]
    late = np.abs([e for e in late if np.isfinite(e)])
    sd = MAD_TO_SD * float(np.median(late)) if len(late) else 0.0
    errs: dict[int, tuple[float, float]] = {}
    for r in range(n - win):
        ok = True
        for q in range(r, min(r + RELEASE_RUN, n - win)):
            if q not in errs:
                errs[q] = predicted(q)
            e, amp = errs[q]
            if not abs(e) <= max(RELEASE_TOL_MIN_PX, RELEASE_TOL_SDS * sd, RELEASE_TOL_AMP * amp):
                ok = False
                break
        if ok:
            return r
    return free


# -- the passes -----------------------------------------------------------------------------------------

def _not_found(video_path, why: str) -> GalileoError:
    return GalileoError(f"no object released below the spring found in {video_path}: {why}")


def track_pixels(video_path: str | Path, *, top_px=None, object_px=None, progress: bool = True,
                 debug_video: str | Path | None = None) -> PixelTrack:
    """The object's centre in every frame, its release frame and size (module docstring).

    `top_px`: the hanging point (x, y) where known (calibration clicks): only moving regions
    reaching below it are candidates. `object_px`: a click on the object where known: the moving
    region nearest it is tried first. `debug_video`: an MP4 path for the frames (at the matching's
    scale) with the centre, the object's box and held/free drawn (a fourth pass)."""
    video = VideoStream(video_path, min_frames=MIN_FRAMES)
    bar = tqdm(desc="tracking 1/3: finding what moves", unit="frame", disable=not progress)  # (a bar a pass)
    try:
        return _track(video, video_path, top_px, object_px, bar, debug_video)
    finally:
        bar.close()


@dataclass
class _Scales:
    """The video's size and the two working scales, and the matching's frames (a pass)."""
    video: VideoStream
    bar: object
    det: float            # detection and the rough track
    trk: float            # the outline and the matching

    @property
    def trk_hw(self) -> tuple[int, int]:
        return round(self.video.height_px * self.trk), round(self.video.width_px * self.trk)

    def frames(self, colour: bool = False, only: set[int] | None = None):
        """A pass at the matching's scale: (frame, its luma (H, W), or Y, U, V (H, W, 3) with
        `colour`), every frame or those in `only` (the pass ends after the last)."""
        th, tw = self.trk_hw
        for f, (y, uv) in enumerate(self.video.yuv()):
            self.bar.update()
            if only is not None and f not in only:
                continue
            g = cv2.resize(y, (tw, th), interpolation=cv2.INTER_AREA) if self.trk < 1 else y
            if colour:
                g = np.dstack([g, resize_to(uv, (th, tw), cv2.INTER_AREA if uv.shape[0] > th else cv2.INTER_LINEAR)])
            yield f, g
            if only is not None and f == max(only):
                self.bar.update(self.video.n_frames - 1 - f)
                return


def _track(video: VideoStream, video_path, top_px, object_px, bar, debug_video) -> PixelTrack:
    hw = (video.height_px, video.width_px)
    sc = _Scales(video, bar, _scale(hw, DETECT_MAX_PX), _scale(hw, TRACK_MAX_PX))
    small, persist, noise = _first_pass(sc)
    n = video.n_frames
    bar.set_description("tracking 2/3: the object's outline", refresh=False)
    bar.reset(total=n)
    regions = _candidates(persist, *(None if p is None else _to_scale(p, 1.0, sc.det) for p in (object_px, top_px)))
    if not regions:
        raise StillVideo(str(_not_found(video_path, "nothing in it keeps moving")))
    rough = None
    for region in regions:
        rough = _rough_track(small, region)
        if rough is not None:
            break
    if rough is None:
        raise _not_found(video_path, f"nothing in it bounces (moves up and down with a clear period over the "
                                     f"clip's last {FREE_PART:.0%})")
    ref, centre_in_templ, templ, tmask, tl_ref, size = _outline(sc, rough, noise, video_path)

    # pass 3: matching in every frame, around the rough track's prediction
    bar.set_description("tracking 3/3: matching the object", refresh=False)
    bar.reset(total=n)
    centre = np.full((n, 2), np.nan)
    k = sc.trk / sc.det
    last, vel = None, np.zeros(2)
    for f, g in sc.frames():
        if f < len(rough.disp) and np.isfinite(rough.disp[f, 0]):
            guess, radius = tl_ref + (rough.disp[f] - rough.disp[ref]) * k, SEARCH_PX
        elif last is not None:
            guess, radius = last + vel, SEARCH_PX + int(np.abs(vel).max())
        else:
            guess, radius = tl_ref, SEARCH_LOST_PX
        found = match(g, templ, tmask, guess, radius)
        if found is None or found[1] < MATCH_MIN:
            last, vel = (None, np.zeros(2)) if found is None else (last, vel)
            continue
        tl = found[0]
        vel = tl - last if last is not None and np.isfinite(centre[f - 1, 0]) else np.zeros(2)
        last = tl
        centre[f] = _to_scale(tl + centre_in_templ, sc.trk, 1.0)

    release = find_release(centre[:, 1])
    visible = np.isfinite(centre[:, 0]) & (np.arange(n) >= release)
    notes = []
    lost = int(np.count_nonzero(~np.isfinite(centre[release:, 0])))
    if lost:
        notes.append(f"the object is not found in {lost} of the {n - release} frames from its release (frame "
                     f"{release}) on: a hand or something else in front of it, or out of view")
    if n > DETECT_MAX_FRAMES:
        notes.append(f"the object was found in the first {DETECT_MAX_FRAMES} frames; later ones are matched frame "
                     f"to frame only")
    if video.timing_note():
        notes.append(video.timing_note())
    method = (f"moving regions ({sc.det:.2g} scale) -> KLT group's rough track -> outline at frame {ref} (rigid-motion "
              f"votes, GrabCut, colour discriminant) -> masked normalised cross-correlation ({sc.trk:.2g} scale, "
              f"sub-pixel) -> release where a damped bounce starts")
    track = PixelTrack(float(video.fps), centre, visible, int(release),
                       None if top_px is None else (float(top_px[0]), float(top_px[1])),
                       (size[0] / sc.trk, size[1] / sc.trk), method, notes)
    if debug_video is not None:
        bar.set_description("tracking: writing the debug video", refresh=False)
        bar.reset(total=n)
        _write_debug(debug_video, sc, track)
    return track


def _first_pass(sc: _Scales) -> tuple[list[np.ndarray], np.ndarray, float]:
    """The first DETECT_MAX_FRAMES frames at the detection scale (luma), the share of frames in
    which each pixel moves, and the noise (levels; from frames 0 and 1)."""
    small, persist, noise = [], None, NOISE_UNKNOWN
    for f, (y, _) in enumerate(sc.video.yuv()):
        sc.bar.update()
        if f >= DETECT_MAX_FRAMES:
            continue
        g = cv2.resize(y, None, fx=sc.det, fy=sc.det, interpolation=cv2.INTER_AREA) if sc.det < 1 else np.array(y)
        if persist is None:
            persist = np.zeros(g.shape, np.float32)
        else:
            if f == 1:
                noise = noise_sd(np.stack([small[0], g])[..., None].astype(np.float32))
            persist += cv2.absdiff(g, small[-1]) > max(MOVE_MIN_DIFF, MOVE_NOISE_SDS * noise)
        small.append(g)
    return small, persist / max(len(small) - 1, 1), noise


def _outline(sc: _Scales, rough: _Rough, noise: float, video_path):
    """Step 3 and the second pass: (the reference frame, the centre in the template, the
    template (luma), its mask (uint8), the template's top-left in the reference frame, the
    object's size (w, h)), at the matching's scale."""
    t_det, period = len(rough.disp), rough.osc.period
    free0 = min(find_release(rough.disp[:, 1]) + math.ceil(period), t_det - 1)
    known = np.isfinite(rough.disp[:, 1])
    speed = np.full(t_det, np.inf)
    speed[1:-1] = np.abs(rough.disp[2:, 1] - rough.disp[:-2, 1])
    refs = set()
    for when in np.linspace(free0, t_det - 1, SEG_REFS + 2)[1:-1]:    # turning points: slowest, sharpest
        near = np.arange(max(free0, int(when - period)), min(t_det, int(when + period) + 1))
        near = near[known[near] & np.isfinite(speed[near])]
        if len(near):
            refs.add(int(near[np.argmin(speed[near])]))
    if not refs:
        raise _not_found(video_path, "the object is lost in its free bounce")
    span = math.ceil(SEG_PERIODS * period)   # (near the reference: the object turns and sways slowly)
    plan = {r: spread(np.flatnonzero(known & (np.arange(t_det) >= max(free0, r - span))
                                     & (np.arange(t_det) <= r + span)), SEG_FRAMES) for r in sorted(refs)}

    # where the object is looked for: the moving region and the group's box swept by the rough
    # track, grown each way by the group's size and the track's range (the moving region leaves
    # out what the object passes only at its farthest reach)
    with _quiet():
        d_lo, d_hi = np.nanmin(rough.disp, axis=0), np.nanmax(rough.disp, axis=0)
    ry, rx = np.nonzero(rough.region)
    lo = np.minimum(rough.pts.min(axis=0) + d_lo, [rx.min(), ry.min()])
    hi = np.maximum(rough.pts.max(axis=0) + d_hi, [rx.max(), ry.max()])
    grow = ROI_GROW * max(float(np.ptp(rough.pts, axis=0).max()), float((d_hi - d_lo).max()), 4.0)
    th, tw = sc.trk_hw
    x0, y0 = np.maximum(np.floor(_to_scale(lo - grow, sc.det, sc.trk)).astype(int), 0)
    x1, y1 = np.minimum(np.ceil(_to_scale(hi + grow, sc.det, sc.trk)).astype(int), [tw, th])

    # pass 2: those frames' crops
    want = set(plan) | {int(f) for fs in plan.values() for f in fs}
    crops = {f: np.array(g[y0:y1, x0:x1]) for f, g in sc.frames(colour=True, only=want)}
    k = sc.trk / sc.det
    findings = []
    for ref, sample_at in plan.items():
        found = _find_object(crops, ref, sample_at, rough, sc, (x0, y0), noise)
        if found is not None:    # (its centre where the object is in frame ta)
            findings.append((found[0] + [x0, y0] - (rough.disp[ref] - rough.disp[rough.ta]) * k, ref, found))
    if not findings:
        raise _not_found(video_path, "its bouncing object's outline could not be told from the background")
    middle = np.median([f[0] for f in findings], axis=0)
    _, ref, (centre, size, matched) = min(findings, key=lambda f: float(np.linalg.norm(f[0] - middle)))
    ys, xs = np.nonzero(matched)
    mx0, my0 = xs.min(), ys.min()
    templ = np.ascontiguousarray(crops[ref][my0:ys.max() + 1, mx0:xs.max() + 1, 0])
    tmask = matched[my0:ys.max() + 1, mx0:xs.max() + 1].astype(np.uint8)
    return ref, centre - [mx0, my0], templ, tmask, np.array([x0 + mx0, y0 + my0], float), size


def _find_object(crops: dict, ref: int, sample_at, rough: _Rough, sc: _Scales, origin, noise: float):
    """The object in frame `ref`'s crop: (its centre, its size (w, h), the part matched to follow
    it), in the crop's pixels; None if not found. Its displacement to each sample frame: its
    features' KLT from the reference, started from the rough track's."""
    k = sc.trk / sc.det
    ref_y = np.ascontiguousarray(crops[ref][..., 0])
    pts = (_to_scale(rough.pts + (rough.disp[ref] - rough.disp[rough.ta]), sc.det, sc.trk) - origin)
    pts = pts.astype(np.float32)
    samples = []
    for f in (int(f) for f in sample_at if f != ref):
        guess = (rough.disp[f] - rough.disp[ref]) * k
        new, ok = flow(ref_y, np.ascontiguousarray(crops[f][..., 0]), pts, (pts + guess).astype(np.float32))
        samples.append((crops[f], np.median(new[ok] - pts[ok], axis=0) if ok.sum() >= MIN_GROUP else guess))
    found = silhouette(crops[ref], samples, noise)
    if found is None:
        return None
    obj, matched = found
    centre, size = centre_and_size(obj)
    return centre, size, matched


def _write_debug(path, sc: _Scales, track: PixelTrack) -> None:
    """The frames at the matching's scale with the centre, the object's box and whether the
    object is held or free drawn (another pass)."""
    from ...video import write_video

    half = np.array(track.size_px) * sc.trk / 2

    def drawn():
        for f, yuv in sc.frames(colour=True):
            img = cv2.cvtColor(yuv, cv2.COLOR_YUV2RGB)
            c = track.center_px[f]
            if np.isfinite(c).all():
                ct = _to_scale(c, 1.0, sc.trk)
                color = DEBUG_FREE if track.visible[f] else DEBUG_HELD
                cv2.rectangle(img, tuple(np.round(ct - half).astype(int)), tuple(np.round(ct + half).astype(int)),
                              color, 1)
                cv2.drawMarker(img, tuple(np.round(ct).astype(int)), color, cv2.MARKER_CROSS, 10, 1)
            state = "free" if f >= track.release_frame else "held"
            cv2.putText(img, f"frame {f} {state}", (8, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, DEBUG_TEXT, 1)
            yield img

    write_video(path, drawn(), track.fps)
