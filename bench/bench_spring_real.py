"""The spring on real Physics 101 footage: a 110.3 g wooden block on a loose and a tight spring, two
trials each (`../shared/data/phys101/spring`, or $GALILEO_PHYS101/spring; skipped when absent).

As a user would: `galileo scene` from clicks on each clip (the hanging point where the spring meets
the stand's arm, a point on the hanging line, two points across the block; no length: the scenes
are not metric), then `galileo infer` end to end (tracking both clips and the paper's 16 x 75 chains):

* each trial as the unknown, the other trial on the same spring as the reference (the same block:
  the answer is 110.3 g), the posterior median and 90% interval and the wall time;
* the four clips as one problem, the block's mass fixed: both springs' stiffness and the ratio of
  the tight one's to the loose one's (from the samples), and what the problem does not identify.

    python bench/bench_spring_real.py [--chains 16] [--sweeps 75] [--workers 2] [--out /tmp/bench_spring_real]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BLOCK_KG = 0.1103
# per clip: the hanging point (pixels) a user clicks on frame 0; the hanging line's second point is
# 310 px below it, the scale segment (unused without a length) across the block
CLIPS = {"loose-02": (1000, 150), "loose-03": (1003, 150), "tight-01": (995, 136), "tight-04": (994, 138)}


def data_dir() -> Path | None:
    env = os.environ.get("GALILEO_PHYS101")
    d = Path(env) if env else ROOT.parent / "shared" / "data" / "phys101"
    return d / "spring" if (d / "spring").is_dir() else None


def clip(d: Path, name: str) -> Path:
    return d / f"w_block_05-{name}-Kinect_RGB_1.mp4"


def galileo(*args: str) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "galileo", *args], check=True, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def scene(d: Path, out: Path, name: str, obj: str) -> Path:
    x, y = CLIPS[name]
    path = out / f"{name}-{obj}.json"
    if not path.is_file():
        pts = f"{x},{y} {x - 3},{y + 310} {x - 40},{y + 440} {x + 40},{y + 440}"
        galileo("scene", str(clip(d, name)), "--scenario", "spring", "--points", pts, "--object", obj,
                "--spring", name.split("-")[0], "--out", str(path))
    return path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--chains", type=int, default=16)
    ap.add_argument("--sweeps", type=int, default=75)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default="/tmp/bench_spring_real")
    args = ap.parse_args()
    d = data_dir()
    if d is None:
        print("bench_spring_real: no Physics 101 clips (../shared/data/phys101/spring or $GALILEO_PHYS101): skipped")
        return 0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    run = ["--chains", str(args.chains), "--sweeps", str(args.sweeps), "--workers", str(args.workers), "--quiet"]
    print("| unknown | reference | m (g): median | 90% | error | covers 110.3 g | wall, end to end (s) |")
    print("|---|---|---|---|---|---|---|")
    for unknown, ref in (("tight-01", "tight-04"), ("tight-04", "tight-01"), ("loose-02", "loose-03"),
                         ("loose-03", "loose-02")):
        res = out / f"{unknown}-given-{ref}.json"
        wall = galileo("infer", str(clip(d, ref)), str(clip(d, unknown)), "--scene", str(scene(d, out, ref, "ref")),
                       str(scene(d, out, unknown, "unknown")), "--fix", f"m_ref_kg={BLOCK_KG}", "--out", str(res), *run)
        q = json.loads(res.read_text())["posterior"]["m_unknown_kg@2"]
        print(f"| {unknown} | {ref} | {1000 * q['q50']:.1f} | {1000 * q['q05']:.1f}-{1000 * q['q95']:.1f} | "
              f"{100 * (q['q50'] / BLOCK_KG - 1):+.1f}% | {'yes' if q['q05'] <= BLOCK_KG <= q['q95'] else 'no'} | "
              f"{wall:.1f} |")
    names = list(CLIPS)
    res = out / "four-clips.json"
    wall = galileo("infer", *[str(clip(d, n)) for n in names], "--scene", *[str(scene(d, out, n, "block")) for n in names],
                   "--fix", f"m_block_kg={BLOCK_KG}", "--out", str(res), *run)
    doc = json.loads(res.read_text())
    from galileo.results import load_samples

    draws = load_samples(res.with_name(res.stem + ".samples.npz"))
    kept = slice(draws["samples"].shape[1] // 2, None)
    kl = draws["samples"][:, kept, list(draws["names"]).index("k_loose_Npm")].ravel()
    kt = draws["samples"][:, kept, list(draws["names"]).index("k_tight_Npm")].ravel()
    ratio = np.quantile(kt / kl, [0.05, 0.5, 0.95])
    post = doc["posterior"]
    print(f"\nfour clips, block fixed at {BLOCK_KG * 1000:.1f} g ({wall:.1f} s end to end):")
    for k in ("k_loose_Npm", "k_tight_Npm", "ms_loose_kg", "ms_tight_kg"):
        print(f"  {k}: {post[k]['q50']:.4g} (90%: {post[k]['q05']:.4g}-{post[k]['q95']:.4g})")
    print(f"  k_tight / k_loose: {ratio[1]:.4f} (90%: {ratio[0]:.4f}-{ratio[2]:.4f})")
    print(f"  not identified: {', '.join(doc['not_identified'])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
