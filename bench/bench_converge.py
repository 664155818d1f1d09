"""Time to a converged posterior: `galileo infer --until-rhat` end to end, the move sets against each
other: the paper's, the default, and "fitted" (the default plus an independence move fitted to the
warm-up, issue 30).

Usage (from the repository root):
    python bench/bench_converge.py [--dataset DIR] [--videos N] [--chains 16] [--sweeps 75]
                                   [--max-sweeps 1500] [--max-seconds 3600] [--rhat 1.01] [--min-ess 400]
                                   [--moves default paper fitted] [--seeds 0 1 2] [--workers N] --out DIR

For each video it runs, as a user would, the command

    galileo infer VIDEO --scene SCENE --tracks TRACKS --moves M --until-rhat R --min-ess E
                  --max-sweeps N --chains C --sweeps S --max-seconds T --out OUT/<video>-<M>.json --quiet

in a new process and times it from process start to result.json written (the tracks are
made once beforehand with `galileo track`, whose time is not counted: it is the same for
both move sets). Videos: the dataset's in which the ramp object moves (its true k1 below
tan of the angle; in a still video the masses are not identified and convergence is about
the prior); without --dataset, the demo preset is rendered into OUT/data.

Each video and move set runs once per seed (`--seeds`: the time to converge varies from seed to
seed by a factor of two on the demo, so a claim needs several). Reported per video, move set and
seed: wall seconds, sweeps run, converged or not, the largest
R-hat and the smallest bulk/tail ESS, the MAP's k1 error, and per latent the time it first met
the targets (R-hat <= R, bulk and tail ESS >= E) at one of the checks the run made (after its
first block and each block after it: `galileo.runner.infer`), from result.json's samples file: the
run's wall seconds times the share of its sweeps done by then ("never": not within the budget).
Written to OUT/converge.json and OUT/converge.md. Targets: R-hat <= 1.01 and ESS >= 400 for every
latent within 5 s per video on 2 cores (issue 12); the demo within 30 s (issue 30).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from galileo.errors import GalileoError, run_reporting_errors  # noqa: E402
from galileo.jsonio import read_json, write_json  # noqa: E402
from galileo.results import convergence, kept_draws  # noqa: E402
from galileo.runner import block_after  # noqa: E402

TARGET_S = {"demo": 30.0, "dataset": 60.0}   # issue 30: the demo within 30 s; a dataset's videos within 60 s each


def galileo(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "galileo.cli", *args], capture_output=True, text=True, cwd=ROOT)


def videos_of(dataset: Path) -> list[dict]:
    index = read_json(dataset / "index.json", "dataset index")
    out = []
    for v in index["videos"]:
        folder = dataset / v["name"]
        truth = read_json(folder / "truth.json", "truth")["latents"]
        moving = truth["k1"] < math.tan(math.radians(truth["angle_deg"]))
        out.append({"name": v["name"], "folder": folder, "truth": truth, "moving": moving})
    return out


def checkpoints(first: int, total: int) -> list[int]:
    """The sweeps after which `galileo.runner.infer --until-rhat` looked: its first block, then
    its blocks (`block_after`), up to the sweeps the run made."""
    out, n = [], first
    while n < total:
        out.append(n)
        n += block_after(n, total)
    return out + [total]


def per_latent_s(result_path: Path, doc: dict, wall_s: float, args) -> dict:
    """Per latent, the wall seconds at the first check at which it met the targets (None: never)."""
    with np.load(result_path.with_name(doc["samples_file"])) as z:
        samples, names = z["samples"], [str(n) for n in z["names"]]
    total = samples.shape[1]
    warmup = doc["diagnostics"]["warmup_sweeps"]
    out: dict = {n: None for n in names}
    for n_done in checkpoints(args.sweeps, total):
        verdict = convergence(kept_draws(list(samples[:, :n_done]), warmup), names, args.rhat, args.min_ess)
        for name in names:
            if out[name] is None and verdict["per_latent"][name]:
                out[name] = wall_s * n_done / total
    return out


def run(args) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.dataset:
        dataset = Path(args.dataset)
    else:
        dataset = out / "data"
        if not (dataset / "index.json").exists():
            r = galileo("dataset", "--preset", "demo", "--out", str(dataset), "--quiet")
            if r.returncode:
                raise GalileoError(r.stderr.strip())
    vids = [v for v in videos_of(dataset) if v["moving"]][: args.videos]
    rows = []
    for v in vids:
        tracks = v["folder"] / "tracks.json"
        if not tracks.exists():
            r = galileo("track", str(v["folder"] / "video.mp4"), "--scene", str(v["folder"] / "scene.json"),
                        "--out", str(tracks), "--quiet")
            if r.returncode:
                rows.append({"video": v["name"], "error": r.stderr.strip()})
                continue
        for moves, seed in [(m, s) for m in args.moves for s in args.seeds]:
            res = out / f"{v['name']}-{moves}-seed{seed}.json"
            cmd = ["infer", str(v["folder"] / "video.mp4"), "--scene", str(v["folder"] / "scene.json"),
                   "--tracks", str(tracks), "--moves", moves, "--until-rhat", str(args.rhat),
                   "--min-ess", str(args.min_ess), "--max-sweeps", str(args.max_sweeps), "--chains", str(args.chains),
                   "--sweeps", str(args.sweeps), "--seed", str(seed), "--max-seconds", str(args.max_seconds),
                   "--out", str(res), "--quiet"]
            if args.workers:
                cmd += ["--workers", str(args.workers)]
            t0 = time.perf_counter()
            r = galileo(*cmd)
            wall = time.perf_counter() - t0
            if r.returncode:
                rows.append({"video": v["name"], "moves": moves, "seed": seed, "error": r.stderr.strip()})
                continue
            d = read_json(res, "result")
            diag = d["diagnostics"]
            rs = [x for x in diag["r_hat"].values() if x is not None]
            es = [x for k in ("ess", "ess_tail") for x in diag[k].values() if x is not None]
            rows.append({"video": v["name"], "moves": moves, "seed": seed, "wall_s": wall, "chains_s": d["timing_s"]["wall"],
                         "sweeps": diag["sweeps"], "converged": d["converged"],
                         "latent_s": per_latent_s(res, d, wall, args),
                         "rhat_max": max(rs) if rs else None, "ess_min": min(es) if es else None,
                         "k1_error": abs(d["map"]["k1"] - v["truth"]["k1"]), "why_not": d["why_not"][:2]})
            print(f"{v['name']:40s} {moves:8s} seed {seed:<3d} {wall:6.1f} s  {diag['sweeps']:5d} sweeps  "
                  f"{'converged' if d['converged'] else 'NOT converged':14s} R-hat max {rows[-1]['rhat_max']:.3f}  "
                  f"ESS min {rows[-1]['ess_min']:.0f}", flush=True)
    summary = {}
    target_s = TARGET_S["dataset" if args.dataset else "demo"]
    for moves in args.moves:
        mine = [r for r in rows if r.get("moves") == moves and "error" not in r]
        conv = [r for r in mine if r["converged"]]
        walls = sorted(r["wall_s"] for r in conv)
        every = sorted(r["wall_s"] if r["converged"] else math.inf for r in mine)
        summary[moves] = {"runs": len(mine), "converged": len(conv),
                          "median_wall_s_converged": walls[len(walls) // 2] if walls else None,
                          "median_wall_s": (None if not every or not math.isfinite(every[len(every) // 2])
                                            else float(np.median(every))),
                          "median_sweeps": float(np.median([r["sweeps"] for r in mine])) if mine else None,
                          "within_target": sum(w <= target_s for w in walls)}
    doc = {"command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]), "machine": platform.processor() or
           platform.machine(), "cores": os.cpu_count(), "settings": vars(args) | {"dataset": str(dataset)},
           "rows": rows, "summary": summary, "target_s": target_s}
    write_json(out / "converge.json", doc)
    lines = ["| video | moves | seed | wall s | sweeps | converged | R-hat max | ESS min | k1 error | each latent converged at (s) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['video']} | {r.get('moves', '')} | {r.get('seed', '')} | error: {r['error']} | | | | | | |")
        else:
            at = ", ".join(f"{k} {'never' if t is None else f'{t:.0f}'}" for k, t in r["latent_s"].items())
            lines.append(f"| {r['video']} | {r['moves']} | {r['seed']} | {r['wall_s']:.1f} | {r['sweeps']} | {r['converged']} | "
                         f"{r['rhat_max']:.3f} | {r['ess_min']:.0f} | {r['k1_error']:.4f} | {at} |")
    (out / "converge.md").write_text("\n".join(lines) + "\n")
    print(json.dumps(summary, indent=1))
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", help="a rendered ramp dataset (default: render the demo preset)")
    ap.add_argument("--videos", type=int, default=None, help="at most this many moving videos")
    ap.add_argument("--chains", type=int, default=16)
    ap.add_argument("--sweeps", type=int, default=75, help="the first block (warm-up: half of it)")
    ap.add_argument("--max-sweeps", type=int, default=1500)
    ap.add_argument("--max-seconds", type=float, default=3600.0,
                    help="galileo infer's wall-clock budget (default: an hour, so that the sweeps decide)")
    ap.add_argument("--rhat", type=float, default=1.01)
    ap.add_argument("--min-ess", type=float, default=400)
    ap.add_argument("--moves", nargs="+", choices=["default", "paper", "fitted"], default=["default", "paper"])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0], help="one run per seed (default: 0)")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)
    return run_reporting_errors("bench_converge", lambda: run(args))


if __name__ == "__main__":
    raise SystemExit(main())
