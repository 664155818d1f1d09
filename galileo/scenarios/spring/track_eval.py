"""A spring pixel track against another made for the same video (the Physics 101 clips come with
tracks made by earlier work, one row per frame from near the video's start, their alignment not
documented): the frame offset that aligns them and how far apart they are."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import GalileoError

MAX_OFFSET = 30    # frames either way


@dataclass
class Agreement:
    offset: int                  # the given track's row j is frame j + offset
    diff_px: np.ndarray          # (rows, 2) the centre in row j's frame less row j; NaN where either is unknown

    @property
    def distances_px(self) -> np.ndarray:
        return np.linalg.norm(self.diff_px, axis=1)

    @property
    def median_px(self) -> float:
        return float(np.nanmedian(self.distances_px))

    @property
    def constant_px(self) -> np.ndarray:
        """(2,) the median difference: where the two tracks put the centre on the object."""
        return np.nanmedian(self.diff_px, axis=0)

    @property
    def median_after_constant_px(self) -> float:
        """The median distance once the constant difference is taken out (how the two move)."""
        return float(np.nanmedian(np.linalg.norm(self.diff_px - self.constant_px, axis=1)))


def align(center_px: np.ndarray, given_px: np.ndarray, max_offset: int = MAX_OFFSET) -> Agreement:
    """The offset within +-max_offset frames that brings the given track (rows (x, y)) closest to
    the centres (frames (x, y), NaN where unknown): least median distance over the rows whose
    frame has a centre."""
    center_px, given_px = np.asarray(center_px, float), np.asarray(given_px, float)
    best = None
    rows = np.arange(len(given_px))
    for off in range(-max_offset, max_offset + 1):
        frames = rows + off
        inside = (frames >= 0) & (frames < len(center_px))
        diff = np.full((len(given_px), 2), np.nan)
        diff[inside] = center_px[frames[inside]] - given_px[inside]
        dist = np.linalg.norm(diff, axis=1)
        if not np.isfinite(dist).any():
            continue
        if best is None or np.nanmedian(dist) < best[0]:
            best = (float(np.nanmedian(dist)), Agreement(off, diff))
    if best is None:
        raise GalileoError("the two tracks share no frame with a centre at any offset")
    return best[1]
