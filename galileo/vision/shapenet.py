"""Bottom-up shape recognition: box / cylinder / torus from an object's first frame.

Side views of a box and of a cylinder lying along the fall line have the same silhouette,
so the tracker's shape type comes from appearance: a small CNN over the object's crop
(`shape_crop`: grey level standardised inside the silhouette, and the silhouette,
rotated so the support runs horizontally) plus two scalars measured from the
silhouette (log of length / height and log of height in metres).

It is trained on the generative model's own renders (Helmholtz-style: random shapes,
sizes, materials' colours, ramp angles, offsets and lighting, rendered through the
dataset camera), with the silhouette perturbed as background subtraction perturbs it.
Weights ship as a plain NPZ (no pickle):

    python -m galileo.vision.shapenet train --n 3000 --seed 0 --out galileo/data/shapenet.npz
    python -m galileo.vision.shapenet eval --n 300 --seed 123
"""
from __future__ import annotations

import argparse
import functools
import math
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import cv2
import numpy as np

from ..camera import Camera, backproject_to_plane
from ..shapes import Shape, shape_class
from .silhouette import pixel_hull

WEIGHTS = Path(__file__).resolve().parents[1] / "data" / "shapenet.npz"
LABELS = ("box", "cylinder", "torus")  # the network's outputs, in order (the weights fix them)
CROP_HW = (32, 64)         # the crop the network reads (height, width)
CROP_PAD_PX = 3            # margin around the silhouette's box
MIN_LENGTH_M = 1e-3        # scalars: lengths and heights floored at this
HEIGHT_SCALE_M = 0.03      # scalars: log height relative to this
WIDEN = 0.2                # size ranges of the training shapes: the materials' ranges widened by 20%
MIN_TRAIN_SIZE_M = 0.008   # ... but no training size below this


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


# -- training data from the generative model ------------------------------------------------------

def _random_shape(rng: np.random.Generator, kind: str) -> Shape:
    from ..scenarios.ramp.materials import MATERIALS

    options = [(m, r) for m in MATERIALS for k, r in m.shapes if k == kind]
    mat, ranges = options[int(rng.integers(len(options)))]

    def draw(axis):
        lo, hi = ranges[axis]
        span = hi - lo
        return float(rng.uniform(max(lo - WIDEN * span, MIN_TRAIN_SIZE_M), hi + WIDEN * span))

    return shape_class(kind).sample(draw)


def _example(seed: int):
    """One rendered training example: (crop, scalars, label)."""
    from ..scenarios.ramp.render import Look, Renderer
    from ..scenarios.ramp.scene import Ramp, Scene, SceneObject, default_camera

    rng = np.random.default_rng(seed)
    label = int(rng.integers(len(LABELS)))
    shape = _random_shape(rng, LABELS[label])
    color = tuple(int(c) for c in rng.integers(30, 250, 3))
    obj = SceneObject("ramp_object", "ramp", shape, 0.1, 0.2, offset_units=int(rng.integers(-5, 6)))
    scene = Scene(Ramp(angle_deg=float(rng.uniform(8, 25))), (obj,), camera=default_camera())
    r = Renderer(scene, Look.random(rng), texture_seed=int(rng.integers(2**31)), colors={0: color})
    r.sim.reset()
    rgb, seg = r.render_current(0, with_segmentation=True)
    mask = (seg == r.body_ids[0]).astype(np.uint8)
    k = int(rng.integers(0, 3))  # background subtraction's mask: a pixel more, a pixel less, or as is
    if k == 1:
        mask = cv2.dilate(mask, np.ones((3, 3), np.uint8))
    elif k == 2:
        mask = cv2.erode(mask, np.ones((3, 3), np.uint8))
    if np.count_nonzero(mask) < 10:
        return None
    noise = rng.normal(1.0, 0.08, 2)
    sc = scalars_of(shape.size_m[0] * noise[0], shape.size_m[2] * noise[1])
    return shape_crop(rgb, pixel_hull(mask), scene.camera, scene.ramp.downhill[[0, 2]]), sc, label


def make_examples(n: int, seed: int, workers: int | None = None, progress: bool = True):
    from tqdm import tqdm

    seeds = [int(s) for s in np.random.SeedSequence(seed).generate_state(n)]
    workers = max(1, min(workers or os.cpu_count() or 1, n))
    out = []
    bar = tqdm(total=n, desc="rendering examples", disable=not progress)
    if workers == 1:
        for s in seeds:
            out.append(_example(s))
            bar.update()
    else:
        import multiprocessing as mp

        with ProcessPoolExecutor(workers, mp_context=mp.get_context("fork")) as pool:
            for e in pool.map(_example, seeds, chunksize=8):
                out.append(e)
                bar.update()
    bar.close()
    out = [e for e in out if e is not None]
    return (np.stack([e[0] for e in out]), np.stack([e[1] for e in out]), np.array([e[2] for e in out]))


def train(out_path: str | Path, n: int = 3000, seed: int = 0, epochs: int = 40, progress: bool = True) -> dict:
    import torch

    from ..jsonio import atomic_write_bytes

    crops, scalars, labels = make_examples(n, seed, progress=progress)
    torch.manual_seed(seed)
    net = _net()
    opt = torch.optim.Adam(net.parameters(), lr=2e-3, weight_decay=1e-4)
    x, s, y = torch.from_numpy(crops), torch.from_numpy(scalars), torch.from_numpy(labels).long()
    gen = torch.Generator().manual_seed(seed)
    for _ in range(epochs):
        perm = torch.randperm(len(y), generator=gen)
        for i in range(0, len(y), 64):
            idx = perm[i:i + 64]
            xb = x[idx]
            if torch.rand(1, generator=gen).item() < 0.5:  # mirror: the ramp's direction is not a cue
                xb = torch.flip(xb, dims=[3])
            loss = torch.nn.functional.cross_entropy(net(xb, s[idx]), y[idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
    net.eval()
    with torch.no_grad():
        train_acc = float((net(x, s).argmax(1) == y).float().mean())
    import io

    buf = io.BytesIO()
    np.savez_compressed(buf, **{k: v.detach().numpy() for k, v in net.state_dict().items()})
    atomic_write_bytes(out_path, buf.getvalue())
    _loaded.cache_clear()
    return {"examples": int(len(y)), "train_accuracy": train_acc,
            "parameters": int(sum(p.numel() for p in net.parameters()))}


def evaluate(n: int = 300, seed: int = 123, progress: bool = True) -> dict:
    crops, scalars, labels = make_examples(n, seed, progress=progress)
    pred = np.array([LABELS.index(predict(c, s)[0]) for c, s in zip(crops, scalars)])
    confusion = np.zeros((len(LABELS), len(LABELS)), int)
    for t, p in zip(labels, pred):
        confusion[t, p] += 1
    return {"n": int(len(labels)), "accuracy": float((pred == labels).mean()),
            "confusion(rows=true box,cylinder,torus)": confusion.tolist()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m galileo.vision.shapenet", description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    t = sub.add_parser("train")
    t.add_argument("--n", type=int, default=3000)
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--epochs", type=int, default=40)
    t.add_argument("--out", default=str(WEIGHTS))
    e = sub.add_parser("eval")
    e.add_argument("--n", type=int, default=300)
    e.add_argument("--seed", type=int, default=123)
    args = ap.parse_args(argv)
    if args.cmd == "train":
        print(train(args.out, args.n, args.seed, args.epochs))
    else:
        print(evaluate(args.n, args.seed))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
