"""Bottom-up shape recognition: box / cylinder / torus from an object's first frame.

Side views of a box and of a cylinder lying along the fall line have the same silhouette,
so the tracker's shape type comes from appearance: a small CNN over the object's crop
(`shape_crop`: grey level standardised inside the silhouette, and the silhouette,
rotated so the support runs horizontally) plus two scalars measured from the
silhouette (log of length / height and log of height in metres).

It is trained on the generative model's own renders (Helmholtz-style: random shapes,
sizes, materials' colours, ramp angles, offsets and lighting, rendered through the
dataset camera), with the silhouette perturbed as background subtraction perturbs it.
Weights ship as a plain NPZ (no pickle); the ramp scenario, whose renders it learns from,
trains and scores it (`galileo/scenarios/ramp/shapenet_train.py`):

    python -m galileo.scenarios.ramp.shapenet_train train --n 3000 --seed 0 --out galileo/data/shapenet.npz
    python -m galileo.scenarios.ramp.shapenet_train eval --n 300 --seed 123
"""
from __future__ import annotations

import functools
import math
from pathlib import Path

import cv2
import numpy as np

from ..camera import Camera, backproject_to_plane

WEIGHTS = Path(__file__).resolve().parents[1] / "data" / "shapenet.npz"
LABELS = ("box", "cylinder", "torus")  # the network's outputs, in order (the weights fix them)
CROP_HW = (32, 64)         # the crop the network reads (height, width)
CROP_PAD_PX = 3            # margin around the silhouette's box
MIN_LENGTH_M = 1e-3        # scalars: lengths and heights floored at this
HEIGHT_SCALE_M = 0.03      # scalars: log height relative to this


# -- the network's input --------------------------------------------------------------------

def support_direction_px(cam: Camera, along_xz: np.ndarray, at_world: np.ndarray) -> float:
    """Angle (radians, image frame) of a support surface's direction `along_xz` (world x, z)
    at a point."""
    p0 = np.asarray(at_world, float)
    p1 = p0 + 0.05 * np.array([along_xz[0], 0.0, along_xz[1]])
    uv = cam.project(np.stack([p0, p1]))
    d = uv[1] - uv[0]
    return math.atan2(d[1], d[0])


def shape_crop(rgb: np.ndarray, mask: np.ndarray, cam: Camera, along_xz: np.ndarray) -> np.ndarray:
    """The object's appearance normalised for the shape classifier: (2, 32, 64) float32.

    The frame is rotated about the silhouette's centre so the support surface (direction
    `along_xz` in world x, z) runs horizontally, cropped to the silhouette's box (3 px
    margin) and resized; channel 0 is grey level standardised inside the silhouette,
    channel 1 the silhouette.
    """
    ys, xs = np.nonzero(mask)
    cx, cy = float(xs.mean()), float(ys.mean())
    centre_w = backproject_to_plane(cam, np.array([[cx, cy]]), 0.0)[0]
    ang = math.degrees(support_direction_px(cam, along_xz, centre_w))
    rot = cv2.getRotationMatrix2D((cx, cy), ang, 1.0)
    h, w = mask.shape
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
    g = cv2.warpAffine(gray, rot, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    m = cv2.warpAffine(mask.astype(np.float32), rot, (w, h), flags=cv2.INTER_LINEAR)
    ys, xs = np.nonzero(m > 0.5)
    pad = CROP_PAD_PX
    x0, x1 = max(xs.min() - pad, 0), min(xs.max() + pad + 1, w)
    y0, y1 = max(ys.min() - pad, 0), min(ys.max() + pad + 1, h)
    g = cv2.resize(g[y0:y1, x0:x1], CROP_HW[::-1], interpolation=cv2.INTER_AREA)
    m = cv2.resize(m[y0:y1, x0:x1], CROP_HW[::-1], interpolation=cv2.INTER_AREA)
    inside = g[m > 0.5]
    mu, sd = (float(inside.mean()), float(inside.std()) + 1.0) if inside.size else (float(g.mean()), 1.0)
    return np.stack([(g - mu) / sd, m]).astype(np.float32)


# -- the network -------------------------------------------------------------------------------

def _net():
    import torch
    from torch import nn

    class ShapeNet(nn.Module):
        def __init__(self):
            super().__init__()
            self.features = nn.Sequential(
                nn.Conv2d(2, 16, 3, padding=1), nn.ReLU(), nn.MaxPool2d(2),
                nn.Conv2d(16, 32, 3, padding=1), nn.ReLU(), nn.MaxPool2d(2),
                nn.Conv2d(32, 32, 3, padding=1), nn.ReLU(), nn.AdaptiveAvgPool2d((2, 4)))
            self.head = nn.Sequential(nn.Linear(32 * 8 + 2, 48), nn.ReLU(), nn.Linear(48, len(LABELS)))

        def forward(self, crop, scalars):
            return self.head(torch.cat([self.features(crop).flatten(1), scalars], 1))

    return ShapeNet()


@functools.lru_cache(maxsize=1)
def _loaded():
    import torch

    if not WEIGHTS.exists():
        return None
    net = _net()
    with np.load(WEIGHTS, allow_pickle=False) as z:
        net.load_state_dict({k: torch.from_numpy(z[k]) for k in z.files})
    net.eval()
    return net


def available() -> bool:
    return _loaded() is not None


def scalars_of(length_m: float, height_m: float) -> np.ndarray:
    return np.array([math.log(length_m / height_m), math.log(height_m / HEIGHT_SCALE_M)], np.float32)


def predict(crop: np.ndarray, scalars: np.ndarray) -> tuple[str, dict[str, float]]:
    """Shape type and class probabilities for one crop (2, 32, 64) and its scalars (2,)."""
    import torch

    net = _loaded()
    if net is None:
        raise FileNotFoundError(f"no shape-recognition weights at {WEIGHTS}")
    with torch.no_grad():
        logits = net(torch.from_numpy(crop[None].astype(np.float32)), torch.from_numpy(scalars[None]))
        p = torch.softmax(logits, 1)[0].numpy()
    return LABELS[int(p.argmax())], {t: float(v) for t, v in zip(LABELS, p)}


def classify(rgb: np.ndarray, mask: np.ndarray, cam: Camera, along_xz: np.ndarray, length_m: float,
             height_m: float) -> str:
    """box / cylinder / torus from the object's appearance; "" without the weights (the
    caller then takes the shape whose projected silhouette fits best)."""
    if available():
        crop = shape_crop(rgb, mask, cam, along_xz)
        return predict(crop, scalars_of(max(length_m, MIN_LENGTH_M), max(height_m, MIN_LENGTH_M)))[0]
    return ""
