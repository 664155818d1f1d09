"""KLT: good features to track inside a silhouette, the Lucas-Kanade window that fits it,
and pyramidal Lucas-Kanade flow started from predicted positions with a forward-backward
check (after OpenCV's samples/python/lk_track.py).
"""
from __future__ import annotations

import cv2
import numpy as np

LK_PARAMS = dict(maxLevel=3, criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03))
FB_MAX_PX = 0.7            # forward-backward error allowed
WIN_MIN, WIN_MAX = 5, 9    # KLT window (odd, pixels)
WIN_EDGE_PX = 3            # the window stays this much thinner than the silhouette
FEATURE_PARAMS = dict(qualityLevel=0.005, minDistance=3, blockSize=3)
MIN_SEED_AREA_PX = 20      # seeding area left after keeping win/2 inside the outline, else 1 px inside
MIN_CORNERS = 8            # fewer corners than this: fill up with a grid of points
GRID_STEP_PX = 2
AVOID_RADIUS_PX = 3        # new features keep this far from the ones already tracked


def klt_window(mask: np.ndarray) -> int:
    """KLT window (odd, 5-9 px) that fits inside the silhouette's thickness.

    A window reaching over the object's edge tracks the background behind it too; on a
    thin object (a pole 9 px tall) that makes features stick and the track lag.
    """
    pts = np.c_[np.nonzero(mask)[::-1]].astype(np.float32)
    if len(pts) < 3:
        return WIN_MIN
    (_, _), (w, h), _ = cv2.minAreaRect(pts)
    win = int(min(WIN_MAX, max(WIN_MIN, min(w, h) - WIN_EDGE_PX)))
    return win if win % 2 else win - 1


def seed_features(gray: np.ndarray, mask: np.ndarray, n: int, win: int = WIN_MAX,
                  avoid: np.ndarray | None = None) -> np.ndarray:
    """Up to n good features to track inside the mask (away from the points `avoid`); a
    grid of points where corners are too few."""
    if avoid is not None and len(avoid):
        m = mask.astype(np.uint8)
        for x, y in np.round(avoid).astype(int):
            cv2.circle(m, (int(x), int(y)), AVOID_RADIUS_PX, 0, -1)
        mask = m > 0
    # keep the KLT window on the object: seed at least win/2 inside its outline
    m = cv2.erode(mask.astype(np.uint8) * 255, np.ones((win, win), np.uint8))
    if cv2.countNonZero(m) < MIN_SEED_AREA_PX:
        m = cv2.erode(mask.astype(np.uint8) * 255, np.ones((3, 3), np.uint8))
    p = cv2.goodFeaturesToTrack(gray, maxCorners=n, mask=m, **FEATURE_PARAMS)
    p = np.zeros((0, 2), np.float32) if p is None else p.reshape(-1, 2)
    if len(p) < MIN_CORNERS:
        ys, xs = np.nonzero(m[::GRID_STEP_PX, ::GRID_STEP_PX])
        grid = np.c_[xs * GRID_STEP_PX, ys * GRID_STEP_PX].astype(np.float32)
        if len(grid):
            step = max(1, len(grid) // max(n - len(p), 1))
            p = np.concatenate([p, grid[::step]])[:n]
    return p.astype(np.float32)


def flow(prev: np.ndarray, cur: np.ndarray, pts: np.ndarray, guess: np.ndarray | None = None,
         win: int = WIN_MAX) -> tuple[np.ndarray, np.ndarray]:
    """KLT from a predicted position, with a forward-backward check; new points and kept mask."""
    if len(pts) == 0:
        return pts, np.zeros(0, bool)
    p0 = pts.reshape(-1, 1, 2).astype(np.float32)
    flags = 0
    p1 = None
    if guess is not None and np.all(np.isfinite(guess)):
        p1 = guess.reshape(-1, 1, 2).astype(np.float32)
        flags = cv2.OPTFLOW_USE_INITIAL_FLOW
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(prev, cur, p0, p1, winSize=(win, win), flags=flags, **LK_PARAMS)
    # the check tracks back from scratch: started at p0 it would find p0 whatever p1 is
    back, st2, _ = cv2.calcOpticalFlowPyrLK(cur, prev, p1, None, winSize=(win, win), **LK_PARAMS)
    fb = np.linalg.norm((back - p0).reshape(-1, 2), axis=1)
    ok = (st1.ravel() == 1) & (st2.ravel() == 1) & (fb < FB_MAX_PX)
    return p1.reshape(-1, 2), ok
