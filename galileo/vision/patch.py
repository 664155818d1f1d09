"""Scale-normalised object patches for the recognition model (Galileo section 4).

A patch is a square of `side_m` metres centred on the object's tracked centre, in the plane
through that centre facing the camera (spanned by the camera's x and y axes), resampled to
`size_px` x `size_px` RGB. Unlike a crop to the object's bounding box, the patch keeps the
object's size in metres: a 4 cm coin and a 12 cm block fill different shares of it, whatever
the camera's distance or focal length.
"""
from __future__ import annotations

import cv2
import numpy as np

from ..camera import Camera

SIDE_M = 0.20        # the square's side in the world (the largest catalogue object is 0.16 m long)
SIZE_PX = 32         # LeNet's input: 32 x 32 (LeCun et al. 1998)
MIN_INSIDE = 0.6     # at least this share of the square must fall inside the frame


def patch_corners_px(cam: Camera, centre_in_world: np.ndarray, side_m: float = SIDE_M) -> np.ndarray:
    """Pixel coordinates (4, 2) of the square's corners: top-left, top-right, bottom-right,
    bottom-left as the camera sees them (through the lens: `Camera.project`). The patch is the
    perspective warp between them: inside the square the lens's bending is left out, at most a
    frame pixel (a third of a patch pixel) for a 20 cm square in the frame's corner 1 m away
    at k1 = -0.2."""
    r = cam.world_to_camera[:3, :3]
    right, down = r[0], r[1]   # the camera's x and y axes in world coordinates
    h = side_m / 2
    c = np.asarray(centre_in_world, float)
    corners = np.stack([c - h * right - h * down, c + h * right - h * down, c + h * right + h * down,
                        c - h * right + h * down])
    return cam.project(corners)


def object_patch(rgb: np.ndarray, cam: Camera, centre_in_world: np.ndarray, side_m: float = SIDE_M,
                 size_px: int = SIZE_PX) -> np.ndarray | None:
    """The patch (size_px, size_px, 3) uint8, or None when the square falls mostly outside the
    frame or behind the camera."""
    pc = cam.world_to_camera[:3, :3] @ np.asarray(centre_in_world, float) + cam.world_to_camera[:3, 3]
    if not np.isfinite(pc).all() or pc[2] <= side_m:
        return None
    src = patch_corners_px(cam, centre_in_world, side_m).astype(np.float32)
    h, w = rgb.shape[:2]
    x0, y0 = src.min(0)
    x1, y1 = src.max(0)
    area = max((x1 - x0) * (y1 - y0), 1e-9)
    inside = max(0.0, min(x1, w) - max(x0, 0)) * max(0.0, min(y1, h) - max(y0, 0)) / area
    if inside < MIN_INSIDE:
        return None
    dst = np.array([[0, 0], [size_px, 0], [size_px, size_px], [0, size_px]], np.float32)
    m = cv2.getPerspectiveTransform(src, dst)
    # area-average a large square down (a plain bilinear warp would alias the texture)
    scale = max((x1 - x0) / size_px, 1.0)
    src_img = rgb
    if scale > 1.5:
        k = int(round(scale)) | 1
        src_img = cv2.GaussianBlur(rgb, (k, k), 0)
    return cv2.warpPerspective(src_img, m, (size_px, size_px), flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_REPLICATE)
