"""Tracks drawn over video frames: each object's features, centre, trail and role."""
from __future__ import annotations

import cv2
import numpy as np

from ..datatypes import Tracks

FEATURE_RADIUS_PX = 2
MARKER_PX = 10
TEXT_COLOR = (0, 0, 0)
DEFAULT_COLOR = (255, 255, 0)


def draw_tracks(frame: np.ndarray, tracks: Tracks, f: int, colors: dict[str, tuple[int, int, int]]) -> np.ndarray:
    """A copy of frame `f` with every object's features, trail, centre and role drawn in
    its role's colour (`colors`), and the frame number."""
    img = frame.copy()
    for o in tracks.objects:
        c = colors.get(o.role, DEFAULT_COLOR)
        if o.features_px and f < len(o.features_px):
            for x, y in o.features_px[f]:
                cv2.circle(img, (int(round(x)), int(round(y))), FEATURE_RADIUS_PX, c, -1)
        if o.center_px is not None:
            trail = o.center_px[: f + 1]
            trail = trail[~np.isnan(trail[:, 0])]
            if len(trail) > 1:
                cv2.polylines(img, [np.round(trail).astype(np.int32)], False, c, 1)
            if o.visible[f]:
                x, y = np.round(o.center_px[f]).astype(int)
                cv2.drawMarker(img, (int(x), int(y)), c, cv2.MARKER_CROSS, MARKER_PX, 2)
                cv2.putText(img, o.role, (int(x) + 6, int(y) - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.4, c, 1)
    cv2.putText(img, f"frame {f}", (8, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, TEXT_COLOR, 1)
    return img
