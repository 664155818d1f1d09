"""The fall on real Physics 101 footage: a 110.3 g wooden block dropped by hand onto a table, two
trials (`../shared/data/phys101/fall`, or $GALILEO_PHYS101/fall; skipped when absent).

As a user would: `galileo scene` from the table's four corners on each clip (`bench/fall_real_clicks.json`,
the table taken as 3 ft x 2.5 ft: see that file), then `galileo infer` end to end (tracking included,
the paper's 16 x 75 chains):

* each trial alone: the block-table pair's restitution e and friction mu (posterior median and 90%
  interval) and the wall time;
* both trials as one problem (e and mu shared by name): the same;
* whether the two trials agree (their 90% intervals overlap);
* prediction: each clip's track cut after its first two thirds, inferred, and `PREDICT_DRAWS` kept
  draws simulated to the clip's end; the mean predicted resting place against where the tracker sees
  the block stop (its last seen centroid lifted onto the table), in cm.

    python bench/bench_fall_real.py [--chains 16] [--sweeps 75] [--workers 2] [--out /tmp/bench_fall_real]
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
CLICKS = ROOT / "bench" / "fall_real_clicks.json"
CLIPS = ("table-01", "table-02")


def data_dir() -> Path | None:
    env = os.environ.get("GALILEO_PHYS101")
    d = Path(env) if env else ROOT.parent / "shared" / "data" / "phys101"
    return d / "fall" if (d / "fall").is_dir() else None


def clip(d: Path, name: str) -> Path:
    return d / f"w_block_05-{name}-Kinect_RGB_1.mp4"


def galileo(*args: str) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "galileo", *args], check=True, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def scene(d: Path, out: Path, name: str) -> tuple[Path, float]:
    c = json.loads(CLICKS.read_text())
    path = out / f"{name}.scene.json"
    seconds = galileo("scene", str(clip(d, name)), "--scenario", "fall", "--points",
                      c["clips"][clip(d, name).name]["points"], "--length-m", str(c["length_m"]),
                      "--width-m", str(c["width_m"]), "--object", c["object"], "--surface", c["surface"],
                      "--out", str(path))
    return path, seconds


def interval(result: dict, name: str) -> dict:
    p = result["posterior"][name]
    return {k: p[k] for k in ("q05", "q50", "q95")}


def show(q: dict) -> str:
    return f"{q['q50']:.2f} ({q['q05']:.2f}-{q['q95']:.2f})"


def predict_rest(scene_path: Path, video: Path, args) -> dict:
    """The clip's track cut after two thirds, inferred; the predicted resting place against the tracked one."""
    from galileo import registry
    from galileo.runner import RunConfig, infer
    from galileo.scenarios.fall.experiments import cut_tracks, predict

    sc = registry.load_scene(scene_path)
    scenario = registry.of(sc)
    tracks = scenario.track(video, sc, progress=False)
    obj = tracks.objects[0]
    seen = np.flatnonzero(obj.visible)
    cut = int(round(tracks.n_frames * 2 / 3))
    res = infer(sc, cut_tracks(tracks, cut), RunConfig(chains=args.chains, sweeps=args.sweeps, seed=0,
                                                       workers=args.workers), progress=False)
    pred = predict(res, tracks, res.scene, tracks.n_frames)
    actual = np.asarray(obj.position_m, float)[seen[-1], :2]
    return {"cut_frame": cut, "last_seen_frame": int(seen[-1]), "predicted_m": pred["rest_pos_m"],
            "spread_m": pred["rest_spread_m"], "actual_m": actual.tolist(),
            "error_cm": 100 * float(np.linalg.norm(np.subtract(pred["rest_pos_m"], actual)))}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--chains", type=int, default=16)
    ap.add_argument("--sweeps", type=int, default=75)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default="/tmp/bench_fall_real")
    args = ap.parse_args()
    d = data_dir()
    if d is None:
        print("skipped: no Physics 101 fall clips (../shared/data/phys101/fall or $GALILEO_PHYS101)")
        return 0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    run = ["--chains", str(args.chains), "--sweeps", str(args.sweeps), "--workers", str(args.workers), "--quiet"]
    scenes, rows, results = {}, [], {}
    for name in CLIPS:
        scenes[name], t_scene = scene(d, out, name)
        res = out / f"{name}.result.json"
        t = galileo("infer", str(clip(d, name)), "--scene", str(scenes[name]), "--out", str(res), *run)
        results[name] = json.loads(res.read_text())
        rows.append((name, results[name], t_scene + t))
    both = out / "both.result.json"
    t = galileo("infer", *(str(clip(d, n)) for n in CLIPS), "--scene", *(str(scenes[n]) for n in CLIPS),
                "--out", str(both), *run)
    rows.append(("both (shared e, mu)", json.loads(both.read_text()), t))
    print(f"{args.chains} x {args.sweeps} chains, {args.workers} workers; times end to end (scene, tracking, inference)\n")
    print("| clips | e | mu | R-hat e | time |")
    print("|---|---|---|---|---|")
    for name, r, secs in rows:
        print(f"| {name} | {show(interval(r, 'e_block_table'))} | {show(interval(r, 'mu_block_table'))} | "
              f"{r['diagnostics']['r_hat']['e_block_table']:.2f} | {secs:.1f} s |")
    a, b = (interval(results[n], "e_block_table") for n in CLIPS)
    ma, mb = (interval(results[n], "mu_block_table") for n in CLIPS)
    print(f"\ntrials agree (90% intervals overlap): e {a['q05'] <= b['q95'] and b['q05'] <= a['q95']}, "
          f"mu {ma['q05'] <= mb['q95'] and mb['q05'] <= ma['q95']}")
    print("\n| clip | cut after frame | predicted resting place (m) | tracked (m) | error |")
    print("|---|---|---|---|---|")
    for name in CLIPS:
        p = predict_rest(scenes[name], clip(d, name), args)
        print(f"| {name} | {p['cut_frame']} of the last seen {p['last_seen_frame']} | "
              f"({p['predicted_m'][0]:.3f}, {p['predicted_m'][1]:.3f}) +- {p['spread_m']:.3f} | "
              f"({p['actual_m'][0]:.3f}, {p['actual_m'][1]:.3f}) | {p['error_cm']:.1f} cm |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
