"""Inference speed: the paper's protocol on one video, naive against default.

Usage (from the repository root):
    python bench/bench_infer.py [--scenario ramp|splash] [--video V --scene S [--tracks T]]
                                [--chains N] [--sweeps 75] [--seed 0] [--workers N] [--repeat 3] [--json]

Without --video it renders the scenario's demo preset into a temporary folder first; without
--tracks it tracks the video (tracking time is reported but not part of the inference
times). Chains default to the paper's: 16 for the ramp (Galileo), 50 for splash (Physics 101).
Both runs use the same scene, tracks, seed and chains, in this process:

* naive:   speedups=False, workers=1 - every proposal simulates every frame, one process;
* default: speedups=True (early rejection, at-rest cut-off, prefix reuse), all cores
           (or --workers).

Wall times are of `galileo.runner.infer` (process start-up of the workers included);
the two runs alternate --repeat times and the medians are compared (this VM's speed drifts
by up to 30% between identical runs; the range is printed too).
Physics steps are the stepSimulation calls of all chains. Also reported: whether the two
runs made the same decisions (they should: the speed-ups are exact up to rounding).
Targets (the ramp's): default <= 2 s per video, and >= 10x faster than naive; splash has none yet.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from galileo import registry  # noqa: E402
from galileo.datatypes import Tracks  # noqa: E402
from galileo.runner import RunConfig, infer  # noqa: E402

TARGET_DEFAULT_S = 2.0
TARGET_SPEEDUP = 10.0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--video", help="video file (default: render the demo preset into a temp dir)")
    ap.add_argument("--scene", help="scene JSON of the video (required with --video)")
    ap.add_argument("--tracks", help="tracks JSON of the video (default: track it)")
    ap.add_argument("--scenario", choices=["ramp", "splash"], default="ramp", help="whose demo to render (default ramp)")
    ap.add_argument("--chains", type=int, default=None, help="chains (default: the paper's, 16 ramp / 50 splash)")
    ap.add_argument("--sweeps", type=int, default=75, help="sweeps per chain (default 75, the paper's)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=None, help="workers of the default run (default: all cores)")
    ap.add_argument("--repeat", type=int, default=3, help="runs of each path, alternating (default 3; medians)")
    ap.add_argument("--moves", choices=["paper", "default"], default="paper",
                    help="move set of both runs (default paper: the speed-ups are measured on the paper's protocol)")
    ap.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    args = ap.parse_args(argv)
    if args.chains is None:
        args.chains = 50 if args.scenario == "splash" else 16
    if args.chains < 1 or args.sweeps < 1 or args.repeat < 1:
        ap.error("--chains, --sweeps and --repeat must be >= 1")
    if bool(args.video) != bool(args.scene):
        ap.error("--video and --scene go together")
    if args.tracks and not args.video:
        ap.error("--tracks needs --video and --scene")

    tmp = None
    t0 = time.perf_counter()
    if args.video:
        video, scene_path, source = Path(args.video), Path(args.scene), args.video
    else:
        if args.scenario == "splash":
            from galileo.scenarios.splash.dataset import build
        else:
            from galileo.scenarios.ramp.dataset import build

        tmp = tempfile.TemporaryDirectory(prefix="bench-infer-")
        build("demo", tmp.name, workers=1, progress=False)
        video, scene_path, source = (Path(tmp.name) / "demo" / "video.mp4", Path(tmp.name) / "demo" / "scene.json",
                                     f"{args.scenario} demo preset")
    render_s = time.perf_counter() - t0
    scene = registry.load_scene(scene_path)
    t0 = time.perf_counter()
    tracks = Tracks.load(args.tracks) if args.tracks else registry.of(scene).track(video, scene, progress=False)
    track_s = time.perf_counter() - t0

    base = dict(chains=args.chains, sweeps=args.sweeps, seed=args.seed, moves=args.moves)
    walls_naive, walls_default = [], []
    for _ in range(args.repeat):
        naive = infer(scene, tracks, RunConfig(speedups=False, workers=1, **base), progress=False)
        default = infer(scene, tracks, RunConfig(speedups=True, workers=args.workers, **base), progress=False)
        walls_naive.append(naive.timing_s["wall"])
        walls_default.append(default.timing_s["wall"])

    t_naive, t_default = float(np.median(walls_naive)), float(np.median(walls_default))
    targets = args.scenario == "ramp"
    speedup = t_naive / t_default
    same = bool(np.array_equal(naive.samples, default.samples)
                and np.array_equal(naive.proposals["accepted"], default.proposals["accepted"]))
    result = {
        "video": str(source), "n_frames": tracks.n_frames, "latents": list(default.names),
        "chains": args.chains, "sweeps": args.sweeps, "seed": args.seed,
        "proposals": int(default.proposals["accepted"].size),
        "repeat": args.repeat,
        "naive": {"wall_s": t_naive, "wall_s_runs": walls_naive, "physics_steps": naive.steps, "workers": naive.timing_s["workers"],
                  "chains_cpu_s": naive.timing_s["chains_cpu"], "map": naive.map, "map_loglik": naive.map_loglik},
        "default": {"wall_s": t_default, "wall_s_runs": walls_default, "physics_steps": default.steps, "workers": default.timing_s["workers"],
                    "chains_cpu_s": default.timing_s["chains_cpu"], "map": default.map,
                    "map_loglik": default.map_loglik,
                    "early_stopped": float(default.proposals["early_stop"].mean())},
        "speedup_wall": speedup, "steps_ratio": naive.steps / max(default.steps, 1),
        "cpu_ratio": naive.timing_s["chains_cpu"] / default.timing_s["chains_cpu"],
        "same_decisions": same,
        "max_abs_loglik_diff": float(np.abs(naive.logliks - default.logliks).max()),
        "target_default_s": targets and TARGET_DEFAULT_S, "target_speedup": targets and TARGET_SPEEDUP,
        "ok_default_s": (t_default <= TARGET_DEFAULT_S) if targets else None,
        "ok_speedup": (speedup >= TARGET_SPEEDUP) if targets else None,
        "render_s": render_s if tmp else None, "track_s": track_s,
        "cpu_count": os.cpu_count(), "python": platform.python_version(), "machine": platform.machine(),
    }
    if tmp is not None:
        tmp.cleanup()
    if args.json:
        print(json.dumps(result))
        return 0

    def ok(flag):
        return "ok" if flag else "MISSED"

    print(f"video: {source}, {tracks.n_frames} frames; {args.chains} chains x {args.sweeps} sweeps x "
          f"{len(default.names)} latents = {result['proposals']} proposals, seed {args.seed}; "
          f"{os.cpu_count()} cores" + (f"; tracking {track_s:.2f} s (not counted)" if not args.tracks else ""))
    def spread(walls):
        return f" (runs {min(walls):.2f}-{max(walls):.2f})" if len(walls) > 1 else ""

    print(f"wall times: median of {args.repeat} alternating run(s) of each path")
    print(f"naive   (no speed-ups, 1 worker)    : {t_naive:7.2f} s{spread(walls_naive)}  {naive.steps:>10,d} physics steps  "
          f"(chain CPU {naive.timing_s['chains_cpu']:.2f} s)")
    print(f"default (speed-ups, {default.timing_s['workers']:>2d} worker(s))   : {t_default:7.2f} s{spread(walls_default)}  "
          f"{default.steps:>10,d} physics steps  (chain CPU {default.timing_s['chains_cpu']:.2f} s; "
          f"{100 * result['default']['early_stopped']:.0f}% of proposals stopped early)")
    target_x = f" (target >= {TARGET_SPEEDUP:g}x: {ok(result['ok_speedup'])})" if targets else ""
    print(f"speed-up: {speedup:.1f}x wall{target_x}, "
          f"{result['steps_ratio']:.1f}x fewer steps, {result['cpu_ratio']:.1f}x less chain CPU")
    target_s = f" (target <= {TARGET_DEFAULT_S:g} s: {ok(result['ok_default_s'])})" if targets else ""
    print(f"default per video: {t_default:.2f} s{target_s}")
    print(f"same decisions as naive: {'yes' if same else 'NO'} (max |log-lik difference| "
          f"{result['max_abs_loglik_diff']:.2g}); MAP {', '.join(f'{k} = {v:.3f}' for k, v in default.map.items())}")
    return 0


if __name__ == "__main__":
    from galileo.errors import run_reporting_errors

    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
