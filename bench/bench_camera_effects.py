"""Render time per frame of the demo video through each camera preset (`galileo dataset --camera`).

Usage (from the repository root):
    python bench/bench_camera_effects.py [--scenario ramp|splash] [--cameras clean,phone,webcam,handheld]
                                         [--repeats 3] [--json]

Each camera renders the scenario's demo video end to end as `galileo dataset --preset demo
--camera NAME` does (the scenario's `render_one`: simulation, TinyRenderer at 640x480 - five
renders a frame with motion blur -, the camera's effects, H.264 encoding, the files), in this
process, `--repeats` times into a fresh folder each; the table gives the median wall time over
the video's frames, and what the camera adds to clean's. Names may carry levels (shake:0.5)
or be single effects (noise, blur, ...). Target: the effects other than blur add well under
the 85 ms a frame TinyRenderer takes.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="ramp", choices=("ramp", "splash"))
    ap.add_argument("--cameras", default="clean,phone,webcam,handheld")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()

    from galileo import registry
    from galileo.footage import effects_from_name

    spec = registry.get(args.scenario).dataset
    rows = []
    for camera in args.cameras.split(","):
        effects_from_name(camera)                 # a bad name: its one-line error before any rendering
        video = spec.plan("demo", 0, camera)[0]
        times = []
        for _ in range(args.repeats):
            with tempfile.TemporaryDirectory() as out:
                t0 = time.perf_counter()
                entry = spec.render_one(video, out)
                times.append(time.perf_counter() - t0)
        rows.append({"camera": camera, "n_frames": entry["n_frames"], "video_s": statistics.median(times),
                     "ms_per_frame": 1000 * statistics.median(times) / entry["n_frames"]})
    clean = next((r["ms_per_frame"] for r in rows if r["camera"] == "clean"), None)
    for r in rows:
        r["added_ms_per_frame"] = None if clean is None else r["ms_per_frame"] - clean
    if args.json:
        print(json.dumps({"scenario": args.scenario, "repeats": args.repeats, "rows": rows}, indent=1))
        return 0
    print(f"{args.scenario} demo, median of {args.repeats}")
    print(f"{'camera':<14}{'frames':>7}{'video s':>9}{'ms/frame':>10}{'added':>8}")
    for r in rows:
        added = "" if r["added_ms_per_frame"] is None else f"{r['added_ms_per_frame']:+.0f}"
        print(f"{r['camera']:<14}{r['n_frames']:>7}{r['video_s']:>9.2f}{r['ms_per_frame']:>10.0f}{added:>8}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
