"""Silhouettes: a 3-D shape at a pose projected into a filled image mask (project, hull,
fill), the IoU loss against an observed silhouette, and the fits of shape and pose to an
observed silhouette (Nelder-Mead over several parameters, bounded search over one).
"""
from __future__ import annotations

from typing import Callable

import cv2
import numpy as np

from ..camera import Camera
from ..shapes import Shape

FIT_XATOL = 1e-4      # Nelder-Mead: parameter tolerance
FIT_FATOL = 1e-4      # ... and loss tolerance
FIT_MAXITER = 400
SLIDE_XATOL = 2e-4    # bounded one-parameter search: tolerance (metres)

# posed(p) -> (shape, rotation object -> world, centre in world): a shape and its pose from parameters
Posed = Callable[..., tuple[Shape, np.ndarray, np.ndarray]]


def fill_polygon(points: np.ndarray, hw: tuple[int, int]) -> np.ndarray:
    """(h, w) uint8 mask, 1 inside the convex polygon of integer pixel points."""
    m = np.zeros(hw, np.uint8)
    cv2.fillConvexPoly(m, points, 1)
    return m


def pixel_hull(mask: np.ndarray) -> np.ndarray:
    """The convex hull of the mask's pixels, filled (boolean)."""
    ys, xs = np.nonzero(mask)
    return fill_polygon(cv2.convexHull(np.c_[xs, ys].astype(np.int32)), mask.shape) > 0


def project_silhouette(cam: Camera, points_obj: np.ndarray, rot: np.ndarray, centre: np.ndarray,
                       roi: tuple[int, int, int, int] | None = None) -> np.ndarray:
    """uint8 mask (1 inside) of the convex hull of object-frame points posed at (rot, centre)
    and projected (through the lens: `Camera.project`), over the region of interest (x0, y0,
    w, h) or the whole image; empty where a point does not project. The hull of the distorted
    points: a lens bends the outline's edges between them by k1 r^2 of a shape's few pixels,
    well under a pixel at the bound a camera allows."""
    x0, y0, w, h = (0, 0, cam.width_px, cam.height_px) if roi is None else roi
    uv = cam.project(points_obj @ rot.T + centre)
    if roi is not None:
        uv = uv - [x0, y0]
    if not np.all(np.isfinite(uv)):
        return np.zeros((h, w), np.uint8)
    return fill_polygon(np.round(cv2.convexHull(uv.astype(np.float32))).astype(np.int32).reshape(-1, 2), (h, w))


def shape_silhouette(cam: Camera, shape: Shape, rot: np.ndarray, centre: np.ndarray, roi=None) -> np.ndarray:
    """uint8 mask of the shape at a pose (see `project_silhouette`)."""
    return project_silhouette(cam, shape.outline_points(), rot, centre, roi)


def iou_loss(sil: np.ndarray, obs: np.ndarray) -> float:
    """1 - intersection over union of two boolean masks (1 when both are empty)."""
    inter = np.logical_and(sil, obs).sum()
    return 1.0 - inter / max(np.logical_or(sil, obs).sum(), 1)


def crop(mask: np.ndarray, pad: int) -> tuple[tuple[int, int, int, int], np.ndarray]:
    """Region (x0, y0, w, h) around the mask's pixels with `pad` pixels to spare (inside the
    image), and the mask over it (boolean)."""
    ys, xs = np.nonzero(mask)
    x0, y0 = max(xs.min() - pad, 0), max(ys.min() - pad, 0)
    x1, y1 = min(xs.max() + pad, mask.shape[1]), min(ys.max() + pad, mask.shape[0])
    return (int(x0), int(y0), int(x1 - x0), int(y1 - y0)), mask[y0:y1, x0:x1].astype(bool)


def _loss(cam: Camera, mask: np.ndarray, posed: Posed, pad: int):
    roi, obs = crop(mask, pad)

    def loss(p):
        return iou_loss(shape_silhouette(cam, *posed(p), roi).astype(bool), obs)

    return loss


def fit_silhouette(cam: Camera, mask: np.ndarray, posed: Posed, p0: np.ndarray, pad: int):
    """Parameters whose posed shape's silhouette best overlaps the observed one (least
    1 - IoU, Nelder-Mead from p0); scipy's result (x, fun)."""
    from scipy.optimize import minimize

    return minimize(_loss(cam, mask, posed, pad), p0, method="Nelder-Mead",
                    options={"xatol": FIT_XATOL, "fatol": FIT_FATOL, "maxiter": FIT_MAXITER})


def slide_silhouette(cam: Camera, mask: np.ndarray, posed: Posed, bounds: tuple[float, float], pad: int) -> float:
    """The one parameter within bounds whose posed shape's silhouette best overlaps the
    observed one (bounded scalar search)."""
    from scipy.optimize import minimize_scalar

    return minimize_scalar(_loss(cam, mask, posed, pad), bounds=bounds, method="bounded",
                           options={"xatol": SLIDE_XATOL}).x
