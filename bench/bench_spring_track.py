"""Spring tracking on the real Physics 101 clips against the tracks made for them by earlier work.

Usage (from the repository root):
    python bench/bench_spring_track.py [--data DIR] [--json]
    python bench/bench_spring_track.py --renders DATASET     # rendered videos against their truth.json

With --renders (a folder from `galileo dataset --scenario spring`): per video, the median and 95th
percentile pixel distance of the tracked centre from truth.json's `center_px` over the frames
tracked after the release, and the tracker's release frame against the true one and the frame
the hand has gone (`hand_gone_frame`).

DIR holds spring/*.mp4 and their *-disc.npy tracks (default: $GALILEO_PHYS101, else
shared/data/phys101 beside the repository). For each clip: `track_pixels` end to end (wall time,
three passes over the 1920x1080 video), the frame offset within +-30 that aligns the provided
track with ours (`track_eval.align`), the median distance there, the constant difference
(where each puts the centre on the block in its bag) and the median distance without it, the
frames tracked and the release frame. Targets: <= 3 px median on every clip; well under 10 s a
clip. Exits 0 with a message where the clips are absent.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from galileo.scenarios.spring.track_eval import align
from galileo.scenarios.spring.tracking import track_pixels

DEFAULT_DATA = Path(os.environ.get("GALILEO_PHYS101", ROOT.parent / "shared" / "data" / "phys101"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--renders", type=Path, help="a rendered spring dataset: measure against its truth instead")
    args = ap.parse_args()
    if args.renders is not None:
        return renders(args.renders)
    clips = sorted((args.data / "spring").glob("*.mp4"))
    if not clips:
        print(f"no Physics 101 spring clips in {args.data / 'spring'}: nothing to measure (set GALILEO_PHYS101)")
        return 0
    rows = []
    for video in clips:
        given = np.load(video.with_name(video.stem + "-disc.npy"))
        t0 = time.perf_counter()
        pt = track_pixels(video, progress=False)
        wall = time.perf_counter() - t0
        a = align(pt.center_px, given)
        rows.append({"clip": video.stem.replace("-Kinect_RGB_1", ""), "frames": len(pt.center_px),
                     "tracked": int(np.isfinite(pt.center_px[:, 0]).sum()), "release_frame": pt.release_frame,
                     "offset_frames": a.offset, "median_px": a.median_px,
                     "constant_px": [float(v) for v in a.constant_px],
                     "median_without_constant_px": a.median_after_constant_px,
                     "wall_s": wall})
    if args.json:
        print(json.dumps(rows))
        return 0
    print("| clip | frames | tracked | release | offset (frames) | median (px) | constant dx, dy (px) "
          "| median without it (px) | wall (s) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['clip']} | {r['frames']} | {r['tracked']} | {r['release_frame']} | {r['offset_frames']:+d} "
              f"| {r['median_px']:.2f} | {r['constant_px'][0]:+.1f}, {r['constant_px'][1]:+.1f} "
              f"| {r['median_without_constant_px']:.2f} | {r['wall_s']:.1f} |")
    print("target: <= 3 px median on every clip; well under 10 s a clip")
    return 0


def renders(folder: Path) -> int:
    from galileo.jsonio import read_json

    index = read_json(folder / "index.json", "dataset index")
    print("| video | mass (g) | release: tracked / true / hand gone | median px | p95 px | frames tracked after release |")
    print("|---|---|---|---|---|---|")
    medians = []
    for v in index["videos"]:
        truth = read_json(folder / v["name"] / "truth.json", "truth")
        pt = track_pixels(folder / v["name"] / "video.mp4", progress=False)
        true_px = np.asarray(truth["center_px"], float)
        seen = pt.visible & np.isfinite(pt.center_px).all(axis=1)
        d = np.linalg.norm(pt.center_px[seen] - true_px[seen], axis=1)
        medians.append(float(np.median(d)))
        print(f"| {v['name']} | {1000 * v['mass_kg']:.1f} | {pt.release_frame} / {truth['release_frame']} / "
              f"{truth['hand_gone_frame']} | {np.median(d):.2f} | {np.percentile(d, 95):.2f} | {int(seen.sum())} |")
    print(f"median of the videos' medians: {np.median(medians):.2f} px")
    return 0


if __name__ == "__main__":
    from galileo.errors import run_reporting_errors

    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
