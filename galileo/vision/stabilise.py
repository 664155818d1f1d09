"""Stabilisation: each frame registered to the video's first and normalised to its brightness.

Galileo's trackers compare frames with frame 0 and with background models learned from the
video, which assumes a camera bolted to the world at fixed exposure. A phone on a table, a
webcam or a phone in a hand shakes by a pixel or three with a little roll, and its exposure,
flicker and white balance drift by a few percent a frame. `Stabilised` wraps a
`galileo.video.VideoStream` and yields every frame as frame 0 would have shown it:

1. Registration: good features of frame 0 (the reference: the scene file's camera describes
   it) on the static background (away from an `exclude` mask the caller gives: the objects'
   start silhouettes, where they move), tracked reference -> frame by pyramidal KLT started
   from the previous frame's transform, forward-backward checked (backwards from the
   previous transform's inverse, not from the start point), then a similarity (translation,
   roll, scale: a camera's small rotation) by RANSAC (`cv2.estimateAffinePartial2D`), so that
   features on moving objects, a passing shadow or a hand are outliers. Features missed
   MISS_DROP_FRAMES frames running are dropped; when fewer than REFRESH_FRACTION of
   FEATURES_MAX remain, more are taken from the reference away from the failing ones.
   The luma is brought to the reference's exposure first (KLT matches levels: 5% of
   flicker pulls features by 0.2 px).
2. Photometric normalisation: per channel (Y, U, V at the chroma's half resolution, where
   the background models run) a gain and offset mapping the registered frame onto the
   reference, by orthogonal regression (both frames are noisy) trimmed of samples that
   differ (in any channel) by more than TRIM_SDS robust deviations, on a sparse grid of the
   smoothed planes: exposure drift, flicker and white-balance drift go, a moving object or
   a shadow over a fifth of the frame does not bias it.
3. A frame less than SCENE_FRACTION of whose samples agree with the reference after
   normalisation (a hand over the lens, a cut) does not show the scene: `shown` is False
   for it, and it is yielded as decoded. One that does but cannot be registered (a
   background too plain or too blurred: too few features survive) is taken where the
   camera last was.

The fits of the first pass are kept (a few numbers a frame) and replayed by later passes.
A transform within IDENTITY_PX of the identity (or not significantly better than it) and a
channel within IDENTITY_GAIN or IDENTITY_LEVELS of its reference are left alone, so a still
camera's video comes out bit-identical. `motion()` says what was
removed, `notes()` says it to a user, `noise_sd()` is the sensor noise of registered frames
against the reference (on the footing of `background.noise_sd`), `sharpness` each frame's
against the reference's (a blurred video).

Tunables after OpenCV's samples/python/lk_track.py.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Iterator

import cv2
import numpy as np

from . import MAD_TO_SD
from .background import HIDDEN_FRACTION, NOISE_SD_FLOOR, yuv_image

FEATURES_MAX = 300          # reference features tracked (a few hundred: enough for 0.05 px, cheap)
FEATURE_PARAMS = dict(qualityLevel=0.001, minDistance=12, blockSize=7)   # (low quality: a rendered scene's
# background has weak corners next to the objects' strong ones)
BORDER_PX = 16              # features keep this far inside the frame (shake carries the edge out)
LK_WIN_PX = 21
LK_LEVELS = 3
LK_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)
COARSE_SCALE = 0.5          # a coarse similarity first: phase correlation of the left and right halves' detail
COARSE_GATE_PX = 2.0        # at this scale (shift: their mean; roll: their vertical difference); features KLT
COARSE_MIN_RESPONSE = 0.05  # puts further than this from it are outliers (an object moving: the target pushed, a
# hand), when the correlation's peak is at least this strong (else the last frame's transform is the guess)
COARSE_JUMP_PX = 3.0        # ... and when it moves no corner of the frame further than this from the last transform
DETAIL_SIGMA_PX = 4.0       # registration runs on the luma less its blur at this sd (`_detail`)
FB_MAX_PX = 0.5             # forward-backward error allowed
RANSAC_PX = 1.0             # a feature further than this from the similarity is an outlier
REFINE_ITERATIONS = 10      # Levenberg-Marquardt on the inliers
MIN_INLIERS = 12            # fewer: registration failed
MIN_SAMPLES = 30            # photometric samples of the background at least (fewer: frames are left as they are)
MAX_ROLL_DEG = 5.0          # a transform rolling or zooming further is a failed registration, not shake
MAX_ZOOM = 0.1
MISS_DROP_FRAMES = 15       # a feature that is not an inlier this many frames running is dropped
REFRESH_FRACTION = 0.5      # fewer features than this fraction of FEATURES_MAX: take more from the reference
FAILED_AVOID_PX = 24        # ... this far from the features that fail (occluded there)
GRID_STEP_PX = 6            # photometric fit: every 6th pixel each way of the half-resolution planes
PHOTO_BLUR_PX = 2.0         # ... smoothed by a Gaussian of this sd (half-resolution pixels)
REFIT_PX = 0.25             # the fit at the last frame's transform is made again if this one is further off (a
# pixel of misregistration tilts the gain by ~1%)
TRIM_SDS = 3.0              # a sample whose residual exceeds this many robust deviations is trimmed
TRIM_MIN_LEVELS = 2.0       # ... or at least this many levels
TRIM_ITERATIONS = 3
GAIN_PRIOR_VAR = 4.0        # levels^2: a channel spread less than this keeps its gain near 1 (ridge)
MAX_GAIN = 1.5              # a frame whose levels map to the reference's by a larger gain (or its inverse)
# shows something else (a hand over the lens: flat, it fits the reference at some huge gain)
SCENE_FRACTION = 1 - HIDDEN_FRACTION   # at least this fraction of the samples agree with the reference
IDENTITY_FIT_PX = RANSAC_PX  # the identity stands where at least as many features stay within this of where they
# were as the similarity explains within it (a still camera's background stays put; an object moving through the
# frame, a long pole sliding, does not, and tilted the fit to it by 0.13 deg on a clean render)
IDENTITY_PX = 0.05          # a transform moving no corner of the frame further than this is the identity
IDENTITY_NOISE_PX = 0.25    # ... or up to this far, if no better than the identity at ...
IDENTITY_F = 3.5            # ... this F ratio (F(4, 80) at 1%)
IDENTITY_GAIN = 0.01        # a channel the identity matches (median difference in its darker and brighter half)
IDENTITY_LEVELS = 1.0       # within this fraction of the level, or this many levels, is left alone (H.264 drifts
# a still scene's levels by about one: the demo's by up to 0.7%)
NOTE_SHAKE_PX = 0.5         # notes: camera motion beyond this
NOTE_EXPOSURE = 0.05        # ... exposure changes beyond this fraction
NOTE_CHROMA_LEVELS = 2.0    # ... white balance drifting by more than this many chroma levels
NOTE_BLUR = 0.5             # ... frames sharper than this fraction of the reference: blurred


@dataclass
class FrameFit:
    """One frame against the reference. `transform` maps reference pixels to the frame's
    (2 x 3, full resolution); `photo` (3, 2) the gain and offset per channel (Y, U, V)
    mapping the registered frame's levels onto the reference's; `features` the reference
    features tracked into it, `inliers` those the transform fits, `residual_px` their RMS
    distance from it; `noise` the robust spread (levels) of the normalised frame against
    the reference at half resolution; `sharpness` the Laplacian's variance against the
    reference's (gain removed); `shown` whether the frame
    shows the scene (at least SCENE_FRACTION of it matches the reference: a background too
    plain or too blurred to register against still does); `reason` why it is not
    registered (then `transform` is the last registered frame's) or not shown."""
    transform: np.ndarray
    photo: np.ndarray
    features: int
    inliers: int
    residual_px: float
    noise: float
    sharpness: float
    shown: bool = True
    reason: str | None = None


@dataclass(frozen=True)
class CameraMotion:
    """What stabilisation removed: the frame centre's shift (max, RMS, px), the largest roll
    (deg), the registration's residual (RMS over frames, px), the range of exposure (a frame's
    level at the reference's mean luma, as a fraction of it), the largest chroma drift
    (levels), the frames that do not show the scene and those that do but were not
    registered (taken where the camera last was)."""
    max_shift_px: float
    rms_shift_px: float
    max_roll_deg: float
    residual_px: float
    exposure_range: tuple[float, float]
    max_chroma_levels: float
    failed_frames: tuple[int, ...]
    unregistered_frames: tuple[int, ...]
    min_sharpness: float = 1.0

    def to_json(self) -> dict:
        """As `Tracks.camera` keeps it (finite JSON numbers and lists)."""
        d = dataclasses.asdict(self)
        d["exposure_range"] = list(self.exposure_range)
        d["failed_frames"], d["unregistered_frames"] = list(self.failed_frames), list(self.unregistered_frames)
        return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in d.items()}


def similarity_matrix(shift_px, roll_deg: float = 0.0, zoom: float = 1.0, centre_px=(0.0, 0.0)) -> np.ndarray:
    """The 2 x 3 similarity that rolls by `roll_deg` and zooms by `zoom` about `centre_px`,
    then shifts by `shift_px` (pixels, x right, y down)."""
    a = math.radians(roll_deg)
    lin = zoom * np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    c = np.asarray(centre_px, float)
    return np.c_[lin, c - lin @ c + np.asarray(shift_px, float)]


def half_res(transform: np.ndarray) -> np.ndarray:
    """A full-resolution transform for the half-resolution (chroma) planes: half-resolution
    pixel u is centred on full-resolution 2u + 0.5."""
    lin, t = transform[:, :2], transform[:, 2]
    return np.c_[lin, (lin @ [0.5, 0.5] + t - 0.5) / 2]


def apply(transform: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Points (n, 2) through a 2 x 3 transform."""
    return pts @ transform[:, :2].T + transform[:, 2]


def frame_ranges(frames) -> str:
    """'3-5, 9' for [3, 4, 5, 9]."""
    frames = [int(f) for f in frames]
    parts, s = [], frames[0]
    for a, b in zip(frames, frames[1:] + [None]):
        if b != a + 1:
            parts.append(f"{s}-{a}" if a > s else f"{s}")
            s = b
    return ", ".join(parts)


def _lut(gain: float, offset: float) -> np.ndarray:
    return np.clip(np.round(gain * np.arange(256) + offset), 0, 255).astype(np.uint8)


def _rigid(m: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """The similarity `m` without its zoom: its roll, and the shift that best carries p0 onto p1 so
    rolled. A camera on a table or in a hand turns (a shift and a roll of the picture) but hardly
    moves to or from the scene; a fitted zoom is noise (up to 0.8% a frame on the rendered phone
    videos, a pixel at the frame's edge), and a zoom kept would scale every position about the
    frame's centre."""
    a = math.atan2(m[1, 0], m[0, 0])
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    return np.c_[rot, np.mean(p1 - p0 @ rot.T, axis=0)]


def _median(a: np.ndarray) -> np.ndarray | float:
    """`np.median(a, axis=-1)` by one partition (the same numbers; the photometric fit takes
    about 20 medians a frame, and np.median's own overhead was a tenth of the stabiliser's
    time on a shaken video)."""
    n = a.shape[-1]
    k = n // 2
    if n % 2:
        return np.partition(a, k, axis=-1)[..., k]
    part = np.partition(a, (k - 1, k), axis=-1)
    return (part[..., k - 1] + part[..., k]) / 2


def _detail(y: np.ndarray) -> np.ndarray:
    """The luma's detail: itself less its Gaussian blur (sd DETAIL_SIGMA_PX), about mid-grey (uint8).
    Edges and texture stay; what changes slowly across the frame goes (a shadow passing over the
    background, vignetting, what is left of exposure and flicker), so that KLT matches the
    scene's structure, not its light: on a rendered ramp video with a passing shadow and motion
    blur this took the registration's error from 0.66 to 0.18 px RMS, and the frames that could
    not be registered from 28 of 61 to none."""
    f = y.astype(np.float32)
    return cv2.addWeighted(f, 1.0, cv2.GaussianBlur(f, (0, 0), DETAIL_SIGMA_PX), -1.0, 128.0, dtype=cv2.CV_8U)


def _moved_px(a: np.ndarray, b: np.ndarray, hw: tuple[int, int]) -> float:
    """How far apart two transforms put the frame's corners (px, the furthest)."""
    h, w = hw
    corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]], float)
    return float(np.linalg.norm(apply(a, corners) - apply(b, corners), axis=1).max())


def _orthogonal_slope(xc: np.ndarray, yc: np.ndarray) -> np.ndarray:
    """Per row (channel), the slope of y on x (centred samples along the last axis) by
    orthogonal regression: both frames are noisy, and least squares of one on the other would
    shrink the gain towards 0 by their noise over their spread (half a level at the ends of
    the range). Moments get GAIN_PRIOR_VAR along the identity added, so a channel of little
    spread keeps gain ~1."""
    prior = xc.shape[-1] * GAIN_PRIOR_VAR
    sxx, syy, sxy = (np.einsum("ij,ij->i", xc, xc) + prior, np.einsum("ij,ij->i", yc, yc) + prior,
                     np.einsum("ij,ij->i", xc, yc) + prior)
    return (syy - sxx + np.sqrt((syy - sxx) ** 2 + 4 * sxy ** 2)) / (2 * sxy)


def _smoothed(small: np.ndarray) -> np.ndarray:
    """A half-resolution Y, U, V image smoothed for the photometric fit (float)."""
    return cv2.GaussianBlur(small.astype(np.float32), (0, 0), PHOTO_BLUR_PX)


def _sharpness(small: np.ndarray) -> float:
    """Variance of the Laplacian of a half-resolution Y, U, V image's luma (blur lowers it)."""
    _, sd = cv2.meanStdDev(cv2.Laplacian(np.ascontiguousarray(small[..., 0]), cv2.CV_16S, ksize=1))
    return float(sd[0, 0]) ** 2


class _Registrar:
    """Fits frames to the reference (frame 0), one after another (steps 1 to 3 of the
    module docstring); keeps the features and the last good transform between frames."""

    def __init__(self, y0: np.ndarray, uv0: np.ndarray, exclude: np.ndarray | None):
        self.hw = y0.shape
        h, w = self.hw
        self.y0 = _detail(y0)   # registration matches the reference's detail (`_detail`)
        allowed = np.zeros(self.hw, np.uint8)
        allowed[BORDER_PX:h - BORDER_PX, BORDER_PX:w - BORDER_PX] = 255
        if exclude is not None:
            if exclude.shape != self.hw:
                raise ValueError(f"exclude mask is {exclude.shape}, frames are {self.hw}")
            allowed[exclude.astype(bool)] = 0
        self.allowed = allowed
        # the coarse registration's reference: the detail's halves at COARSE_SCALE, where features may be taken
        weight = cv2.GaussianBlur(cv2.resize(allowed.astype(np.float32) / 255, None, fx=COARSE_SCALE, fy=COARSE_SCALE,
                                             interpolation=cv2.INTER_AREA), (0, 0), 3.0)
        self._weight, self._half = weight, weight.shape[1] // 2
        self._window = cv2.createHanningWindow((self._half, weight.shape[0]), cv2.CV_32F)
        self._coarse_ref = self._halves(self.y0)
        self.pts = np.zeros((0, 2), np.float32)
        self.misses = np.zeros(0, int)
        self.frame = self.seeded = 0   # the frame fitted last, the frame features were last taken at
        self._seed(FEATURES_MAX, np.zeros((0, 2)))
        self.last = similarity_matrix((0, 0))
        # photometric samples: a grid over the half-resolution planes, luma 2 x 2 averaged
        hh, hw2 = uv0.shape[:2]
        gy, gx = np.mgrid[GRID_STEP_PX // 2:hh:GRID_STEP_PX, GRID_STEP_PX // 2:hw2:GRID_STEP_PX]
        keep = np.ones(gx.shape, bool)
        if exclude is not None:
            keep = cv2.resize(exclude.astype(np.uint8), (hw2, hh), interpolation=cv2.INTER_AREA)[gy, gx] == 0
        self.grid = np.c_[gx[keep], gy[keep]].astype(np.float64)          # half-resolution pixels
        small0 = yuv_image(y0, uv0, 0.5)
        self.ref_raw = small0[gy[keep], gx[keep]].astype(np.float64)
        self.ref_smooth = _smoothed(small0)[gy[keep], gx[keep]].astype(np.float64)
        self._ref_smooth_rows = np.ascontiguousarray(self.ref_smooth.T)   # (3, samples): the fit works by channel
        # (no samples: nothing to normalise by; `fit` leaves such frames as they are)
        self.ref_mean_y = float(self.ref_raw[:, 0].mean()) if len(self.ref_raw) else 128.0
        self.ref_sharpness = max(_sharpness(small0), 1e-9)

    def _seed(self, n: int, failed: np.ndarray) -> None:
        """Up to n more reference features, away from those held and from those failing."""
        mask = self.allowed.copy()
        near = [(p, FEATURE_PARAMS["minDistance"]) for p in self.pts] + [(p, FAILED_AVOID_PX) for p in failed]
        for (x, y), r in near:
            cv2.circle(mask, (round(x), round(y)), r, 0, -1)
        p = cv2.goodFeaturesToTrack(self.y0, maxCorners=n, mask=mask, **FEATURE_PARAMS) if n > 0 else None
        p = np.zeros((0, 2), np.float32) if p is None else p.reshape(-1, 2)
        self.seeded = self.frame
        self.pts = np.concatenate([self.pts, p]).astype(np.float32)
        self.misses = np.concatenate([self.misses, np.zeros(len(p), int)])

    def fit(self, y: np.ndarray, uv: np.ndarray) -> FrameFit:
        self.frame += 1
        if len(self.grid) < MIN_SAMPLES:   # no background left to register or normalise by: as it is
            return FrameFit(similarity_matrix((0, 0)), np.c_[np.ones(3), np.zeros(3)], 0, 0, math.nan, math.nan, 1.0)
        # KLT matches levels: a frame a few % brighter pulls features by tenths of a pixel, so
        # its luma is first brought to the reference's, sampled where the last transform puts it
        small = yuv_image(y, uv, 0.5)
        smooth = _smoothed(small)
        photo, tol = self._photometric(self.last, smooth)
        features = len(self.pts)
        transform, inliers, residual, reason = self._register(_detail(cv2.LUT(y, _lut(*photo[0]))))
        if reason is not None:   # not registered: taken where the last frame was
            transform = self.last
        if _moved_px(transform, self.last, self.hw) > REFIT_PX:   # (the first fit was made too far off)
            photo, tol = self._photometric(transform, smooth)
        agree, noise = self._agreement(transform, photo, tol, smooth, y, uv)
        shown = agree >= SCENE_FRACTION
        if not shown:
            reason = "less than half of it matches the first frame"
        sharp = _sharpness(small) * photo[0, 0] ** 2 / self.ref_sharpness
        if shown and reason is None:
            self.last = transform
        return FrameFit(transform, photo, features, inliers, residual, noise, sharp, shown, reason)

    def _halves(self, detail: np.ndarray) -> list[np.ndarray]:
        """The detail image (full resolution, about 128) at COARSE_SCALE, weighted to where features may be
        taken, as its left and right halves."""
        small = cv2.resize(detail, None, fx=COARSE_SCALE, fy=COARSE_SCALE, interpolation=cv2.INTER_AREA)
        d = (small.astype(np.float32) - 128.0) * self._weight
        return [np.ascontiguousarray(d[:, :self._half]), np.ascontiguousarray(d[:, self._half:2 * self._half])]

    def _coarse(self, detail: np.ndarray) -> np.ndarray | None:
        """A coarse similarity reference -> frame: phase correlation of each half of the frame's detail
        with the reference's (shift: their mean; roll: their vertical shifts' difference over the
        halves' distance), or None where a correlation's peak is weaker than COARSE_MIN_RESPONSE."""
        # (phaseCorrelate applies the window to its inputs in place: the reference goes in as a copy)
        (lx, ly), rl, (rx, ry), rr = (x for ref, half in zip(self._coarse_ref, self._halves(detail))
                                      for x in cv2.phaseCorrelate(ref.copy(), half, self._window))
        if min(rl, rr) < COARSE_MIN_RESPONSE:
            return None
        h, w = self.hw
        roll = math.degrees(math.atan2((ry - ly) / COARSE_SCALE, self._half / COARSE_SCALE))
        return similarity_matrix(((lx + rx) / 2 / COARSE_SCALE, (ly + ry) / 2 / COARSE_SCALE), roll, 1.0,
                                 ((w - 1) / 2, (h - 1) / 2))

    def _register(self, y: np.ndarray) -> tuple[np.ndarray, int, float, str | None]:
        """The similarity reference -> frame, its inlier count and residual, or why it failed."""
        n = len(self.pts)
        if n < MIN_INLIERS:
            return self.last, 0, math.nan, "too few background features"
        lk = dict(winSize=(LK_WIN_PX, LK_WIN_PX), maxLevel=LK_LEVELS, criteria=LK_CRITERIA)
        p0 = self.pts.reshape(-1, 1, 2)
        coarse = self._coarse(y)
        if coarse is not None and _moved_px(coarse, self.last, self.hw) > COARSE_JUMP_PX:
            coarse = None   # the camera does not jump between frames: the correlation followed something else
        guess = apply(self.last if coarse is None else coarse, self.pts).astype(np.float32).reshape(-1, 1, 2)
        p1, st1, _ = cv2.calcOpticalFlowPyrLK(self.y0, y, p0, guess, flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **lk)
        back_guess = apply(cv2.invertAffineTransform(self.last), p1.reshape(-1, 2)).astype(np.float32)
        back, st2, _ = cv2.calcOpticalFlowPyrLK(y, self.y0, p1, back_guess.reshape(-1, 1, 2),
                                                flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **lk)
        p1 = p1.reshape(-1, 2)
        fb_px = np.linalg.norm(back.reshape(-1, 2) - self.pts, axis=1)
        ok = (st1.ravel() == 1) & (st2.ravel() == 1) & (fb_px < FB_MAX_PX)
        if coarse is not None:   # features that moved otherwise than the background as a whole did
            ok &= np.linalg.norm(p1 - apply(coarse, self.pts), axis=1) < COARSE_GATE_PX
        inlier = np.zeros(n, bool)
        transform, reason = self.last, "too few background features"
        if ok.sum() >= MIN_INLIERS:
            m, inl = cv2.estimateAffinePartial2D(self.pts[ok], p1[ok], method=cv2.RANSAC,
                                                 ransacReprojThreshold=RANSAC_PX, refineIters=REFINE_ITERATIONS)
            if m is not None:
                inlier[np.flatnonzero(ok)[inl.ravel() == 1]] = True
                roll = math.degrees(math.atan2(m[1, 0], m[0, 0]))
                zoom = math.hypot(m[0, 0], m[1, 0])
                if inlier.sum() >= MIN_INLIERS:
                    transform, reason = _rigid(m, self.pts[inlier], p1[inlier]), None
                    if abs(roll) > MAX_ROLL_DEG or abs(zoom - 1) > MAX_ZOOM:
                        reason = "the camera turned or zoomed too far"
        residual = math.nan
        if reason == "too few background features" and coarse is not None:
            # too few features agree (a plain background, blur): the coarse similarity stands, its residual that of
            # the features it gated in (or unknown)
            transform, reason = coarse, None
            if ok.any():
                residual = float(np.sqrt(np.mean(np.sum((apply(coarse, self.pts[ok]) - p1[ok]) ** 2, axis=1))))
        elif reason is None:
            near = ok & (np.linalg.norm(p1 - self.pts, axis=1) < IDENTITY_FIT_PX)
            if near.sum() >= inlier.sum():   # the camera did not move: as many features stayed put as the fit explains
                transform, inlier = similarity_matrix((0, 0)), near
            elif self._still(transform, self.pts[inlier], p1[inlier]):
                transform = similarity_matrix((0, 0))
            residual = float(np.sqrt(np.mean(np.sum((apply(transform, self.pts[inlier]) - p1[inlier]) ** 2, axis=1))))
        self._keep_features(inlier)
        return transform, int(inlier.sum()), residual, reason

    def _still(self, transform: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> bool:
        """Whether the camera did not move: the similarity moves no corner of the frame by
        IDENTITY_PX, or (up to IDENTITY_NOISE_PX) explains the features no better than the
        identity does (an F test of its 4 parameters at IDENTITY_F: a still camera's weak
        features give a roll of their noise, levered to the corners)."""
        moved = _moved_px(transform, similarity_matrix((0, 0)), self.hw)
        if moved < IDENTITY_PX:
            return True
        ss_fit = np.sum((apply(transform, p0) - p1) ** 2)
        ss_still = np.sum((p1 - p0) ** 2)
        return moved < IDENTITY_NOISE_PX and (ss_still - ss_fit) / 4 <= IDENTITY_F * ss_fit / (2 * len(p0) - 4)

    def _keep_features(self, inlier: np.ndarray) -> None:
        """Count each feature's misses; drop those missed too long; take more when few are left."""
        self.misses = np.where(inlier, 0, self.misses + 1)
        failed = self.pts[~inlier]
        keep = self.misses < MISS_DROP_FRAMES
        self.pts, self.misses = self.pts[keep], self.misses[keep]
        if (inlier.sum() < REFRESH_FRACTION * FEATURES_MAX and len(self.pts) < FEATURES_MAX
                and self.frame >= self.seeded + MISS_DROP_FRAMES):   # (new features get as long to prove themselves)
            self._seed(FEATURES_MAX - len(self.pts), failed)

    def _samples(self, transform: np.ndarray, smooth: np.ndarray):
        """Where the grid falls in the frame (half-resolution x, y of those inside it, and
        which those are) and the smoothed frame's levels there."""
        at = apply(half_res(transform), self.grid).astype(np.float32)
        hh, hw2 = smooth.shape[:2]
        inside = (at[:, 0] >= 0) & (at[:, 0] <= hw2 - 1) & (at[:, 1] >= 0) & (at[:, 1] <= hh - 1)
        mx, my = at[inside, 0].reshape(1, -1), at[inside, 1].reshape(1, -1)
        return mx, my, inside, cv2.remap(smooth, mx, my, cv2.INTER_LINEAR).reshape(-1, 3).astype(np.float64)

    def _photometric(self, transform: np.ndarray, smooth: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Gain and offset per channel (Y, U, V) mapping the frame registered by `transform`
        onto the reference, and the residual (levels, per channel) beyond which a sample does
        not agree; None for that if the frame shows something else.

        Trimmed orthogonal regression on the grid in the frame's half-resolution planes
        smoothed by PHOTO_BLUR_PX (`smooth`: the warp's interpolation smooths fine texture,
        which would read as a change of contrast; smoothed, half a pixel of misregistration
        changes little)."""
        identity = np.c_[np.ones(3), np.zeros(3)]
        _, _, inside, x = self._samples(transform, smooth)
        x, r0 = np.ascontiguousarray(x.T), self._ref_smooth_rows[:, inside]   # (channel, sample)
        gain, offset = np.ones(3), _median(r0 - x)
        good = np.ones(x.shape[1], bool)
        for _ in range(TRIM_ITERATIONS):
            res = r0 - (gain[:, None] * x + offset[:, None])
            kept = res[:, good]
            mid = _median(kept)
            tol = np.maximum(TRIM_SDS * MAD_TO_SD * _median(np.abs(kept - mid[:, None])), TRIM_MIN_LEVELS)
            good = (np.abs(res - mid[:, None]) <= tol[:, None]).all(axis=0)
            if good.sum() < 3:
                return identity, None
            xg, rg = x[:, good], r0[:, good]
            xm, rm = xg.mean(axis=1), rg.mean(axis=1)
            gain = _orthogonal_slope(xg - xm[:, None], rg - rm[:, None])
            offset = rm - gain * xm
        if (gain * MAX_GAIN < 1).any() or (gain > MAX_GAIN).any():   # not the scene (a flat frame fits it at some gain)
            return identity, None
        # a channel the identity explains is left as it is: a still camera's compressed frames
        # copy the reference within a level, and a fit to the few samples that differ more (an
        # object's soft shadow) would change every pixel
        for c, (rc, dc) in enumerate(zip(rg, rg - xg)):
            lower = rc <= _median(rc)
            if all(abs(_median(dc[half])) <= max(IDENTITY_GAIN * _median(rc[half]), IDENTITY_LEVELS)
                   for half in (lower, ~lower) if half.any()):
                gain[c], offset[c] = 1.0, 0.0
        return np.c_[gain, offset], tol

    def _agreement(self, transform: np.ndarray, photo: np.ndarray, tol: np.ndarray | None, smooth: np.ndarray,
                   y: np.ndarray, uv: np.ndarray) -> tuple[float, float]:
        """The fraction of the grid's samples that agree with the reference, the frame
        registered by `transform` and normalised by `photo` (within `tol`, per channel), and
        the spread of those (levels, per frame) in the unsmoothed planes, as the trackers see
        them (warped at full resolution, then 2 x 2 averaged)."""
        if tol is None:
            return 0.0, math.nan
        mx, my, inside, x = self._samples(transform, smooth)
        res = self.ref_smooth[inside] - (photo[:, 0] * x + photo[:, 1])
        good = (np.abs(res - _median(res.T)) <= tol).all(axis=1)
        if not good.any():
            return 0.0, math.nan
        raw = np.c_[cv2.remap(y, 2 * mx + 0.5, 2 * my + 0.5, cv2.INTER_LINEAR).reshape(-1, 1),
                    cv2.remap(uv, mx, my, cv2.INTER_LINEAR).reshape(-1, 2)].astype(np.float64)
        res = (self.ref_raw[inside] - (photo[:, 0] * raw + photo[:, 1]))[good]
        noise = float(MAD_TO_SD * np.median(np.abs(res - np.median(res))) / math.sqrt(2))
        return float(good.sum() / max(len(self.grid), 1)), noise


class Stabilised:
    """A `galileo.video.VideoStream` whose frames come registered to its first and
    normalised to its brightness (module docstring). `yuv()` is the stream's, frame for
    frame; every other attribute (fps, n_frames, timing_note, ...) is the stream's.

    `exclude`: full-resolution mask of pixels not to register or normalise by (the objects'
    start silhouettes, where they move). The first pass fits each frame (`fits`), later
    passes replay the fits; `shown` says which frames show the scene."""

    def __init__(self, video, exclude: np.ndarray | None = None):
        self.video, self.exclude = video, exclude
        self.fits: list[FrameFit] = []
        self._registrar: _Registrar | None = None

    def __getattr__(self, name):
        if name == "video":   # (not set yet: copying, unpickling)
            raise AttributeError(name)
        return getattr(self.video, name)

    def yuv(self) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """One pass: each frame's luma and chroma planes (read-only), registered and
        normalised; a frame that needs neither, or does not show the scene, as decoded."""
        for f, (y, uv) in enumerate(self.video.yuv()):
            if f == len(self.fits):   # not fitted yet (the first pass, or one run beyond an interrupted one)
                if f == 0:
                    self._registrar = _Registrar(y, uv, self.exclude)
                    self.fits.append(FrameFit(similarity_matrix((0, 0)), np.c_[np.ones(3), np.zeros(3)], 0, 0, 0.0,
                                              math.nan, 1.0))
                else:
                    self.fits.append(self._registrar.fit(y, uv))
            yield self._apply(self.fits[f], y, uv)

    def _apply(self, fit: FrameFit, y: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if not fit.shown:
            return y, uv
        hw = y.shape
        if (fit.transform != similarity_matrix((0, 0))).any():
            flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
            y = cv2.warpAffine(y, fit.transform, (hw[1], hw[0]), flags=flags, borderMode=cv2.BORDER_REPLICATE)
            uv = cv2.warpAffine(uv, half_res(fit.transform), (uv.shape[1], uv.shape[0]), flags=flags,
                                borderMode=cv2.BORDER_REPLICATE)
        changed = [g != 1 or b != 0 for g, b in fit.photo]
        if changed[0]:
            y = cv2.LUT(y, _lut(*fit.photo[0]))
        if changed[1] or changed[2]:
            uv = cv2.LUT(np.ascontiguousarray(uv), np.stack([_lut(*fit.photo[1]), _lut(*fit.photo[2])], axis=-1)[None])
        for a in (y, uv):
            if a.flags.writeable:
                a.flags.writeable = False
        return y, uv

    @property
    def shown(self) -> np.ndarray:
        """(n,) whether each fitted frame shows the scene (registered)."""
        return np.array([fit.shown for fit in self.fits], bool)

    @property
    def sharpness(self) -> np.ndarray:
        """(n,) each fitted frame's sharpness as a fraction of the reference's (below 1: blurred)."""
        return np.array([fit.sharpness for fit in self.fits])

    def noise_sd(self) -> float:
        """Sensor noise (levels, at half resolution, as `background.noise_sd` of two frames):
        the median over the registered frames of their robust spread against the reference
        (frames 0 and 1 of a compressed video share most of their noise; these do not)."""
        noise = [fit.noise for fit in self.fits[1:] if fit.shown and math.isfinite(fit.noise)]
        return float(np.median(noise)) + NOISE_SD_FLOOR if noise else math.nan

    def motion(self) -> CameraMotion:
        """What stabilisation removed, over the frames fitted so far."""
        shown = [fit for fit in self.fits if fit.shown]
        registered = [fit for fit in shown[1:] if fit.reason is None]
        h, w = self.video.height_px, self.video.width_px
        centre = np.array([[(w - 1) / 2, (h - 1) / 2]])
        shift = np.array([0.0] + [np.linalg.norm(apply(fit.transform, centre) - centre) for fit in registered])
        roll = [abs(math.degrees(math.atan2(fit.transform[1, 0], fit.transform[0, 0]))) for fit in registered]
        residual = np.array([fit.residual_px for fit in registered])
        m = self._registrar.ref_mean_y if self._registrar else 128.0
        exposure = np.array([(m - fit.photo[0, 1]) / (fit.photo[0, 0] * m) for fit in shown])
        chroma = np.array([np.abs((fit.photo[1:, 0] - 1) * 128 + fit.photo[1:, 1]).max() for fit in shown])
        return CameraMotion(float(shift.max()), float(np.sqrt(np.mean(shift ** 2))), max(roll, default=0.0),
                            float(np.sqrt(np.mean(residual ** 2))) if len(residual) else 0.0,
                            (float(exposure.min()), float(exposure.max())), float(chroma.max()),
                            tuple(f for f, fit in enumerate(self.fits) if not fit.shown),
                            tuple(f for f, fit in enumerate(self.fits) if fit.shown and fit.reason is not None),
                            float(min((fit.sharpness for fit in shown if math.isfinite(fit.sharpness)), default=1.0)))

    def notes(self) -> list[str]:
        """One line for each thing a user should know: the camera moved, the exposure or the
        white balance drifted, frames that could not be registered, blurred frames."""
        mo, out = self.motion(), []
        roll_px = math.radians(mo.max_roll_deg) * self.video.width_px / 2   # (at the frame's edge)
        if mo.max_shift_px > NOTE_SHAKE_PX or roll_px > NOTE_SHAKE_PX:
            out.append(f"the camera moved up to {mo.max_shift_px:.1f} px (RMS {mo.rms_shift_px:.1f} px, roll up to "
                       f"{mo.max_roll_deg:.2f} deg): stabilised against the background; residual "
                       f"{mo.residual_px:.2f} px")
        change = max(abs(mo.exposure_range[0] - 1), abs(mo.exposure_range[1] - 1))
        if change > NOTE_EXPOSURE:
            out.append(f"the exposure changed by up to {change:.0%} (flicker or auto-exposure): normalised")
        if mo.max_chroma_levels > NOTE_CHROMA_LEVELS:
            out.append(f"the white balance drifted by up to {mo.max_chroma_levels:.1f} chroma levels: normalised")
        # (frames that do not show the scene, `shown`, are the tracker's to report: it sees nothing in them)
        reasons: dict[str, list[int]] = {}
        for f, fit in enumerate(self.fits):
            if fit.reason is not None and fit.shown:
                reasons.setdefault(fit.reason, []).append(f)
        for reason, frames in reasons.items():
            many = len(frames) > 1
            out.append(f"registration failed in frame{'s' if many else ''} {frame_ranges(frames)} ({reason}): "
                       f"{'those frames are' if many else 'it is'} not stabilised (the scene is there: taken where "
                       "the camera last was)")
        sharp = self.sharpness
        blurred = np.flatnonzero((sharp < NOTE_BLUR) & self.shown)   # (not a hand over the lens)
        if len(blurred):
            out.append(f"the video is blurred in frame{'s' if len(blurred) > 1 else ''} {frame_ranges(blurred)} "
                       f"(sharpness down to {sharp[blurred].min():.0%} of the first frame's): positions there are "
                       "less precise")
        return out
