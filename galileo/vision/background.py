"""Background models and foreground masks.

MOG2 background images learned from the video itself (forwards or backwards in time),
pixels that differ from a background by more than the sensor noise allows, the noise
estimate, mask cleaning (open, then close), resolution changes, and connected components
of a mask (blobs) as filled convex silhouettes.
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


def mog2_background(frames: np.ndarray, reverse: bool) -> np.ndarray:
    """Background image of a MOG2 model (five components) learned over the frames,
    forwards or backwards in time."""
    mog = cv2.createBackgroundSubtractorMOG2(history=max(len(frames), 2), varThreshold=MOG_VAR_THRESHOLD,
                                             detectShadows=False)
    mog.setNMixtures(MOG_MIXTURES)
    for i in (range(len(frames) - 1, -1, -1) if reverse else range(len(frames))):
        mog.apply(frames[i])
    return mog.getBackgroundImage()


def foreground(frame: np.ndarray, background: np.ndarray, noise_sd: float) -> np.ndarray:
    """Pixels that differ from the background by more than the noise allows (any channel)."""
    d = np.abs(frame.astype(np.int16) - background.astype(np.int16)).max(axis=2)
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


def shrink(frames, scale: float) -> np.ndarray:
    """The frames resized by `scale` (area averaging), stacked."""
    return np.stack([cv2.resize(f, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA) for f in frames])


def resize_to(image: np.ndarray, hw: tuple[int, int], interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
    """The image resized to height, width `hw` (bilinear unless told)."""
    return cv2.resize(image, (hw[1], hw[0]), interpolation=interpolation)


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


def largest_component(mask: np.ndarray) -> np.ndarray | None:
    """The largest component as a filled convex silhouette; None if smaller than MIN_BLOB_PX."""
    labels, area = _components(mask)
    if len(area) <= 1:
        return None
    best = 1 + int(np.argmax(area[1:]))
    if area[best] < MIN_BLOB_PX:
        return None
    return pixel_hull(labels == best)


def blobs(mask: np.ndarray, min_fraction: float) -> list[np.ndarray]:
    """Masks of the components of at least MIN_BLOB_PX pixels and `min_fraction` of the
    largest one's area, in label order."""
    labels, area = _components(mask)
    big = [i for i in range(1, len(area)) if area[i] >= MIN_BLOB_PX]
    if not big:
        return []
    biggest = max(area[i] for i in big)
    return [labels == i for i in big if area[i] >= min_fraction * biggest]
