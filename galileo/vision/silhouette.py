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


def fill_polygon_centres(points: np.ndarray, hw: tuple[int, int]) -> np.ndarray:
    """(h, w) boolean mask of the pixels whose centres (integer coordinates: pixel (x, y) is
    centred on (x, y), as `Camera.project` and a renderer's rasteriser take it) lie inside the
    convex polygon of float points. `fill_polygon` of rounded points (OpenCV's fill) also takes
    every pixel the outline touches: a shape a pixel wider and higher than it is."""
    h, w = hw
    p = np.asarray(points, float).reshape(-1, 2)
    x0, y0 = max(int(np.floor(p[:, 0].min())), 0), max(int(np.floor(p[:, 1].min())), 0)
    x1, y1 = min(int(np.ceil(p[:, 0].max())) + 1, w), min(int(np.ceil(p[:, 1].max())) + 1, h)
    out = np.zeros((h, w), bool)
    if x1 <= x0 or y1 <= y0 or len(p) < 3:
        return out
    a, b = p, np.roll(p, -1, axis=0)
    turn = float(np.sum(a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1]))       # the polygon's orientation
    ys, xs = np.mgrid[y0:y1, x0:x1].astype(float)
    cross = ((b[:, 0] - a[:, 0])[:, None, None] * (ys[None] - a[:, 1, None, None])
             - (b[:, 1] - a[:, 1])[:, None, None] * (xs[None] - a[:, 0, None, None]))
    out[y0:y1, x0:x1] = np.all(cross >= 0, axis=0) if turn > 0 else np.all(cross <= 0, axis=0)
    return out


def pixel_hull(mask: np.ndarray) -> np.ndarray:
    """The convex hull of the mask's pixels, filled (boolean)."""
    ys, xs = np.nonzero(mask)
    return fill_polygon(cv2.convexHull(np.c_[xs, ys].astype(np.int32)), mask.shape) > 0


def project_silhouette(cam: Camera, points_obj: np.ndarray, rot: np.ndarray, centre: np.ndarray,
                       roi: tuple[int, int, int, int] | None = None, centres: bool = False) -> np.ndarray:
    """uint8 mask (1 inside) of the convex hull of object-frame points posed at (rot, centre)
    and projected (through the lens: `Camera.project`), over the region of interest (x0, y0,
    w, h) or the whole image; empty where a point does not project. The hull of the distorted
    points: a lens bends the outline's edges between them by k1 r^2 of a shape's few pixels,
    well under a pixel at the bound a camera allows. `centres`: the pixels whose centres lie in
    the hull (`fill_polygon_centres`, as a renderer draws it), not every pixel it touches."""
    x0, y0, w, h = (0, 0, cam.width_px, cam.height_px) if roi is None else roi
    uv = cam.project(points_obj @ rot.T + centre)
    if roi is not None:
        uv = uv - [x0, y0]
    if not np.all(np.isfinite(uv)):
        return np.zeros((h, w), np.uint8)
    if centres:
        return fill_polygon_centres(cv2.convexHull(uv.astype(np.float32)).reshape(-1, 2), (h, w)).astype(np.uint8)
    return fill_polygon(np.round(cv2.convexHull(uv.astype(np.float32))).astype(np.int32).reshape(-1, 2), (h, w))


def shape_silhouette(cam: Camera, shape: Shape, rot: np.ndarray, centre: np.ndarray, roi=None,
                     centres: bool = False) -> np.ndarray:
    """uint8 mask of the shape at a pose (see `project_silhouette`)."""
    return project_silhouette(cam, shape.outline_points(), rot, centre, roi, centres)


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


def _loss(cam: Camera, mask: np.ndarray, posed: Posed, pad: int, centres: bool = False):
    roi, obs = crop(mask, pad)

    def loss(p):
        return iou_loss(shape_silhouette(cam, *posed(p), roi, centres).astype(bool), obs)

    return loss


def fit_silhouette(cam: Camera, mask: np.ndarray, posed: Posed, p0: np.ndarray, pad: int, centres: bool = False):
    """Parameters whose posed shape's silhouette best overlaps the observed one (least
    1 - IoU, Nelder-Mead from p0; the silhouette's pixels those it touches, or with `centres`
    those whose centres it holds); scipy's result (x, fun)."""
    from scipy.optimize import minimize

    return minimize(_loss(cam, mask, posed, pad, centres), p0, method="Nelder-Mead",
                    options={"xatol": FIT_XATOL, "fatol": FIT_FATOL, "maxiter": FIT_MAXITER})


def slide_silhouette(cam: Camera, mask: np.ndarray, posed: Posed, bounds: tuple[float, float], pad: int) -> float:
    """The one parameter within bounds whose posed shape's silhouette best overlaps the
    observed one (bounded scalar search)."""
    from scipy.optimize import minimize_scalar

    return minimize_scalar(_loss(cam, mask, posed, pad), bounds=bounds, method="bounded",
                           options={"xatol": SLIDE_XATOL}).x
