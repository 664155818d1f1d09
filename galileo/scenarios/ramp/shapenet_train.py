"""Training data for the shape CNN (`galileo.vision.shapenet`) from the ramp's own renders,
and its training and scoring (Helmholtz-style: random shapes with the materials' sizes
widened, colours, ramp angles, offsets and lighting, rendered through the dataset camera,
the silhouette perturbed as background subtraction perturbs it):

    python -m galileo.scenarios.ramp.shapenet_train train --n 3000 --seed 0 --out galileo/data/shapenet.npz
    python -m galileo.scenarios.ramp.shapenet_train eval --n 300 --seed 123
"""
from __future__ import annotations

import argparse
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from ...shapes import Shape, shape_class
from ...vision.background import dilate, erode
from ...vision.shapenet import LABELS, WEIGHTS, _loaded, _net, predict, scalars_of, shape_crop
from ...vision.silhouette import pixel_hull

WIDEN = 0.2                # size ranges of the training shapes: the materials' ranges widened by 20%
MIN_TRAIN_SIZE_M = 0.008   # ... but no training size below this


# -- training data from the generative model ------------------------------------------------------

def _random_shape(rng: np.random.Generator, kind: str) -> Shape:
    from .materials import MATERIALS

    options = [(m, r) for m in MATERIALS for k, r in m.shapes if k == kind]
    mat, ranges = options[int(rng.integers(len(options)))]

    def draw(axis):
        lo, hi = ranges[axis]
        span = hi - lo
        return float(rng.uniform(max(lo - WIDEN * span, MIN_TRAIN_SIZE_M), hi + WIDEN * span))

    return shape_class(kind).sample(draw)


def _example(seed: int):
    """One rendered training example: (crop, scalars, label)."""
    from ...render import Look
    from .render import Renderer
    from .scene import Ramp, Scene, SceneObject, default_camera

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
        mask = dilate(mask, 3).astype(np.uint8)
    elif k == 2:
        mask = erode(mask, 3).astype(np.uint8)
    if np.count_nonzero(mask) < 10:
        return None
    noise = rng.normal(1.0, 0.08, 2)
    sc = scalars_of(shape.size_m[0] * noise[0], shape.size_m[2] * noise[1])
    return shape_crop(rgb, pixel_hull(mask), scene.camera, scene.ramp.downhill[[0, 2]]), sc, label


def make_examples(n: int, seed: int, workers: int | None = None, progress: bool = True):
    from ...progress import tqdm

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

    from ...jsonio import atomic_write_bytes

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
    ap = argparse.ArgumentParser(prog="python -m galileo.scenarios.ramp.shapenet_train", description=__doc__.splitlines()[0])
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
