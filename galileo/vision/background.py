"""Background models and foreground masks.

MOG2 background images learned from the video itself (forwards or backwards in time),
pixels that differ from a background by more than the sensor noise allows, the noise
estimate, mask cleaning (open, then close), resolution changes, and connected components
of a mask (blobs) as filled convex silhouettes.

Memory: the trackers stream a video (galileo.video.VideoStream) and keep what these models
need, so both are bounded for any video. Models and masks run at most at WORK_MAX_PX pixels
a frame (a 1080p video's half resolution; a larger video is shrunk further: a 4K one to a
quarter), and a model learned over a stretch of frames that must be replayed (backwards in
time) learns from at most MODEL_MAX_FRAMES of them, evenly spaced (every frame of a stretch
up to that long, as before). Together they hold at most 120 x 0.5 Mpx x 3 = 187 MB of frames.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from . import MAD_TO_SD
from .silhouette import pixel_hull

MOG_SCALE = 0.5            # background models run at this scale of the full frame (chroma's resolution)
MOG_MIXTURES = 5           # Gaussian components per pixel
MOG_VAR_THRESHOLD = 16     # squared Mahalanobis distance for a pixel to match a component
FG_MIN_DIFF = 12.0         # foreground: differs (any channel) by more than max(this, FG_NOISE_SDS x noise)
FG_NOISE_SDS = 5.0
NOISE_SD_ONE_FRAME = 2.0   # noise assumed when there is a single frame
NOISE_SD_FLOOR = 0.5       # added to the estimate (quantisation)
CLEAN_KERNEL_PX = 3        # ellipse for opening and closing foreground masks
CLOSE_ITERATIONS = 2
MIN_BLOB_PX = 60           # smallest component that counts as an object (full resolution)
WORK_MAX_PX = 960 * 540    # background models and foreground masks: at most this many pixels a frame
MODEL_MAX_FRAMES = 120     # a replayed model learns from at most this many frames (4 s at 30 fps: every frame of
# the videos Galileo renders; a scene's end looks the same over a longer stretch, sampled)
HIDDEN_FRACTION = 0.5      # a frame more than this fraction of which differs from the video's first shows something
# else (noise, a cut, a hand over the lens, the light switched; the objects cover far less): nothing in it is tracked
HIDDEN_STEP_PX = 4         # ... judged on every 4th pixel each way (4800 of a 640x480 video's half resolution)


def mog2(history: int):
    """An OpenCV MOG2 model (five components) for `history` frames: feed it frames with
    `.apply`, read its background with `.getBackgroundImage()`."""
    mog = cv2.createBackgroundSubtractorMOG2(history=max(history, 2), varThreshold=MOG_VAR_THRESHOLD,
                                             detectShadows=False)
    mog.setNMixtures(MOG_MIXTURES)
    return mog


def mog2_background(frames: np.ndarray, reverse: bool) -> np.ndarray:
    """Background image of a MOG2 model (five components) learned over the frames,
    forwards or backwards in time."""
    mog = mog2(len(frames))
    for i in (range(len(frames) - 1, -1, -1) if reverse else range(len(frames))):
        mog.apply(frames[i])
    return mog.getBackgroundImage()


def foreground(frame: np.ndarray, background: np.ndarray, noise_sd: float, shift_px: int = 0) -> np.ndarray:
    """Pixels that differ from the background by more than the noise allows (any channel); with
    `shift_px`, from every background pixel within that many pixels (brighter than the brightest
    of them or darker than the darkest: the background's edges shifted by up to that much, as a
    camera stabilised to a fraction of a pixel leaves them, differ nowhere)."""
    if shift_px:
        k = np.ones((2 * shift_px + 1,) * 2, np.uint8)
        d = cv2.max(cv2.subtract(frame, cv2.dilate(background, k)), cv2.subtract(cv2.erode(background, k), frame))
    else:
        d = cv2.absdiff(frame, background)   # (uint8: |a - b| exactly; numpy's int16 round trip cost 4x as much)
    d = cv2.max(cv2.max(d[..., 0], d[..., 1]), d[..., 2]) if d.ndim == 3 else d
    return (d > max(FG_MIN_DIFF, FG_NOISE_SDS * noise_sd)).astype(np.uint8) * 255


def noise_sd(frames: np.ndarray) -> float:
    """Sensor noise estimate: robust spread of frame-to-frame differences, per channel."""
    if len(frames) < 2:
        return NOISE_SD_ONE_FRAME
    d = frames[1].astype(np.float32) - frames[0].astype(np.float32)
    return float(MAD_TO_SD * np.median(np.abs(d - np.median(d))) / math.sqrt(2) + NOISE_SD_FLOOR)


def clean(mask: np.ndarray) -> np.ndarray:
    """A foreground mask opened (specks off) and closed (holes filled)."""
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (CLEAN_KERNEL_PX, CLEAN_KERNEL_PX))
    m = cv2.morphologyEx(mask, cv2.MORPH_OPEN, k)
    return cv2.morphologyEx(m, cv2.MORPH_CLOSE, k, iterations=CLOSE_ITERATIONS)


def not_the_scene(frame: np.ndarray, first: np.ndarray, noise_sd: float) -> bool:
    """Whether a frame shows something else than the scene: more than HIDDEN_FRACTION of its
    pixels differ from the video's first frame `first` (at the same scale; every
    HIDDEN_STEP_PX-th pixel each way looked at)."""
    k = HIDDEN_STEP_PX
    fg = foreground(frame[::k, ::k], first[::k, ::k], noise_sd)
    return np.count_nonzero(fg) > HIDDEN_FRACTION * fg.size


def spread(indices: np.ndarray, k: int) -> np.ndarray:
    """At most k of the (ascending) frame indices, evenly spaced from the first to the last
    (all of them if there are no more than k)."""
    if len(indices) <= k:
        return indices
    return indices[np.unique(np.round(np.linspace(0, len(indices) - 1, k)).astype(int))]


def frames_at(video, indices: np.ndarray, scale: float) -> list[np.ndarray]:
    """The frames at the (ascending) indices of a video (`galileo.video.VideoStream`) as Y, U,
    V images at `scale` (`yuv_image`): one more pass, ended after the last of them."""
    want, out = set(int(i) for i in indices), []
    for f, (y, uv) in enumerate(video.yuv()):
        if f in want:
            out.append(yuv_image(y, uv, scale))
            if len(out) == len(want):
                break
    return out


def work_scale(hw: tuple[int, int], most: float) -> float:
    """The scale of a full frame (height, width `hw`) that models and masks run at: `most`,
    or less where that would leave more than WORK_MAX_PX pixels."""
    return min(most, math.sqrt(WORK_MAX_PX / (hw[0] * hw[1])))


def scaled(image: np.ndarray, scale: float) -> np.ndarray:
    """The image resized by `scale` (area averaging)."""
    return cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)


def yuv_image(y: np.ndarray, uv: np.ndarray, scale: float) -> np.ndarray:
    """One frame's luma (H, W) and half-resolution chroma (H/2, W/2, 2) as a Y, U, V image at
    `scale` of the full frame (chroma area-averaged when shrunk, bilinear when enlarged;
    untouched at 0.5, its own resolution)."""
    g = y if scale == 1.0 else scaled(y, scale)
    hw = g.shape[:2]
    if uv.shape[:2] != hw:
        uv = resize_to(uv, hw, cv2.INTER_AREA if uv.shape[0] > hw[0] else cv2.INTER_LINEAR)
    return np.concatenate([g[..., None], uv], axis=-1)


def resize_to(image: np.ndarray, hw: tuple[int, int], interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
    """The image resized to height, width `hw` (bilinear unless told)."""
    return cv2.resize(image, (hw[1], hw[0]), interpolation=interpolation)


def mask_at(mask: np.ndarray, hw: tuple[int, int]) -> np.ndarray:
    """A boolean mask resized to height, width `hw` (nearest pixel)."""
    return resize_to(mask.astype(np.uint8), hw, cv2.INTER_NEAREST) > 0


def full_res(mask_small: np.ndarray, full_shape: tuple[int, int]) -> np.ndarray:
    """A small foreground mask, cleaned, at full resolution (boolean)."""
    return resize_to(clean(mask_small), full_shape, cv2.INTER_NEAREST) > 0


def dilate(mask: np.ndarray, px: int) -> np.ndarray:
    """The mask grown by a px x px square (boolean)."""
    return cv2.dilate(mask.astype(np.uint8), np.ones((px, px), np.uint8)) > 0


def erode(mask: np.ndarray, px: int) -> np.ndarray:
    """The mask shrunk by a px x px square (boolean)."""
    return cv2.erode(mask.astype(np.uint8), np.ones((px, px), np.uint8)) > 0


def _components(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Labels of the mask's 8-connected components (0: background) and each label's area."""
    _, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    return labels, stats[:, cv2.CC_STAT_AREA]


def mostly_within(mask: np.ndarray, region: np.ndarray, share: float, join_px: int) -> np.ndarray:
    """The parts of a mask (its pieces within `join_px` pixels of one another taken together: a
    compressed shadow breaks into many) of which at least `share` of the area lies in `region`."""
    labels, _ = _components(dilate(mask, 2 * join_px + 1))
    lab = labels[mask]
    n = int(labels.max()) + 1
    keep = np.bincount(lab[region[mask]], minlength=n) >= share * np.maximum(np.bincount(lab, minlength=n), 1)
    keep[0] = False
    return mask & keep[labels]


def largest_area(mask: np.ndarray) -> int:
    """The area (pixels) of the mask's largest 8-connected component (0 for an empty mask)."""
    _, area = _components(mask)
    return int(area[1:].max()) if len(area) > 1 else 0


def largest_component(mask: np.ndarray) -> np.ndarray | None:
    """The largest component as a filled convex silhouette; None if smaller than MIN_BLOB_PX."""
    found = components(mask, 1)
    return found[0] if found else None


def components(mask: np.ndarray, most: int) -> list[np.ndarray]:
    """The `most` largest components of at least MIN_BLOB_PX pixels, each as a filled convex
    silhouette, largest first."""
    labels, area = _components(mask)
    order = 1 + np.argsort(-area[1:], kind="stable")
    return [pixel_hull(labels == k) for k in order[:most] if area[k] >= MIN_BLOB_PX]


def touching(mask: np.ndarray, where: np.ndarray) -> np.ndarray:
    """The mask's 8-connected components that reach `where` (boolean)."""
    labels, _ = _components(mask)
    keep = np.unique(labels[where & (labels > 0)])
    return np.isin(labels, keep) if len(keep) else np.zeros(mask.shape, bool)


def blobs(mask: np.ndarray, min_fraction: float) -> list[np.ndarray]:
    """Masks of the components of at least MIN_BLOB_PX pixels and `min_fraction` of the
    largest one's area, in label order."""
    labels, area = _components(mask)
    big = [i for i in range(1, len(area)) if area[i] >= MIN_BLOB_PX]
    if not big:
        return []
    biggest = max(area[i] for i in big)
    return [labels == i for i in big if area[i] >= min_fraction * biggest]
