"""Scrub latency: choose a sample -> re-simulate -> viewer handles updated (server side).

Usage (from the repository root): python bench/bench_scrub.py [--samples 200] [--json]

Renders and tracks the demo, runs 4 chains for 10 sweeps, starts the viewer (no browser
needed: the server side is what is timed) and selects samples in random order. Target:
within 50 ms.
"""
from __future__ import annotations

import argparse
import json
import socket
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=200)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    from galileo.scenarios.ramp.dataset import build
    from galileo import registry
    from galileo.video import read_video
    from ui.controller import Controller
    from ui.viewer import Viewer

    with tempfile.TemporaryDirectory() as tmp:
        build("demo", tmp, workers=1, progress=False)
        folder = Path(tmp) / "demo"
        scene = registry.load_scene(folder / "scene.json")
        tracks = registry.of(scene).track(folder / "video.mp4", scene, progress=False)
        ctrl = Controller(scene, tracks, chains=4, seed=0, workers=1, session_dir=Path(tmp) / "session")
        ctrl.run_sweeps(10)
        video, _ = read_video(folder / "video.mp4")
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        viewer = Viewer(ctrl, ctrl.likelihood_scene, tracks, video, port=port)
        viewer.set_frame(viewer.n_frames // 2)
        rng = np.random.default_rng(0)
        times = []
        for _ in range(args.samples):
            chain = int(rng.choice(ctrl.chain_ids()))
            times.append(viewer.select_sample(chain, int(rng.integers(len(ctrl.samples(chain)))), force=True))
        viewer.close()
        ctrl.close()
    ms = np.array(times) * 1e3
    out = {"samples": args.samples, "frames": int(viewer.n_frames), "p50_ms": float(np.median(ms)),
           "p95_ms": float(np.percentile(ms, 95)), "max_ms": float(ms.max())}
    if args.json:
        print(json.dumps(out))
    else:
        print(f"scrub latency over {args.samples} samples ({out['frames']} frames each): "
              f"p50 {out['p50_ms']:.1f} ms, p95 {out['p95_ms']:.1f} ms, max {out['max_ms']:.1f} ms (target <= 50 ms)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
