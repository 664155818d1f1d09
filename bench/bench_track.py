"""Tracking speed: `galileo.scenarios.ramp.tracking.track` end to end against the bare OpenCV calls it makes.

Usage (from the repository root):
    python bench/bench_track.py [--video V --scene S] [--repeats 5] [--json]

Without --video it renders the demo preset into a temporary folder first. "Bare" is the
same decode (PyAV, yuv420p planes), the two MOG2 passes (backwards over the last third
at half resolution, forwards over all frames at quarter resolution) and the
forward-backward pyramidal Lucas-Kanade on the same number of points per object per
frame (all objects' points in one call per direction, as the tracker does), and the
stabiliser's calls once per frame (`bench_stabilise.bare_calls`, on its full 300 features), with
nothing else: no detection, recognition, pose fitting or bookkeeping.
Targets: >= 300 frames per second end to end at 640x480 (before stabilisation, issue 29); the tracker
at >= 0.5x the bare calls it makes, stabilisation included (issue 29).
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from galileo.scenarios.ramp.scene import Scene  # noqa: E402
from galileo.scenarios.ramp.tracking import track  # noqa: E402
from galileo.vision.background import MOG_SCALE  # noqa: E402
from galileo.video import read_video_yuv  # noqa: E402
from galileo.vision import stabilise  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_stabilise import bare_calls  # noqa: E402


def bare(video: Path, n_points: list[int]) -> float:
    t0 = time.perf_counter()
    y, uv, info = read_video_yuv(video)
    small = np.concatenate([np.stack([cv2.resize(g, None, fx=MOG_SCALE, fy=MOG_SCALE, interpolation=cv2.INTER_AREA)
                                      for g in y])[..., None], uv], axis=-1)
    tiny = np.stack([cv2.resize(f, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA) for f in small])
    tail = max(min(10, len(small)), len(small) // 3)
    for frames, order in ((small[len(small) - tail:], range(tail - 1, -1, -1)), (tiny, range(len(tiny)))):
        mog = cv2.createBackgroundSubtractorMOG2(history=len(frames), varThreshold=16, detectShadows=False)
        mog.setNMixtures(5)
        for i in order:
            mog.apply(frames[i])
    rng = np.random.default_rng(0)
    pts = [rng.uniform([200, 150], [440, 330], (k, 1, 2)).astype(np.float32) for k in n_points]
    lk = dict(winSize=(9, 9), maxLevel=3, criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03))
    p = np.concatenate(pts)
    for f in range(1, len(y)):
        q, _, _ = cv2.calcOpticalFlowPyrLK(y[f - 1], y[f], p, None, **lk)
        cv2.calcOpticalFlowPyrLK(y[f], y[f - 1], q, None, **lk)
    elapsed = time.perf_counter() - t0
    # the stabiliser's (once: its first pass fits, later passes replay the fits)
    frames = list(zip(y, uv))
    return elapsed + bare_calls(y[0], frames[1:], [stabilise.FEATURES_MAX] * (len(frames) - 1))()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--video")
    ap.add_argument("--scene")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    tmp = None
    if args.video:
        video, scene_path = Path(args.video), Path(args.scene)
    else:
        from galileo.scenarios.ramp.dataset import build

        tmp = tempfile.TemporaryDirectory()
        build("demo", tmp.name, progress=False, workers=1)
        video, scene_path = Path(tmp.name) / "demo" / "video.mp4", Path(tmp.name) / "demo" / "scene.json"
    scene = Scene.load(scene_path)
    tracks = track(video, scene, progress=False)  # warm-up; also gives the feature counts
    n_frames = tracks.n_frames
    n_points = [max(8, int(np.median([len(f) for f in o.features_px]))) for o in tracks.objects]
    ends, bares = [], []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        track(video, scene, progress=False)
        ends.append(time.perf_counter() - t0)
        bares.append(bare(video, n_points))
    end_fps = n_frames / statistics.median(ends)
    bare_fps = n_frames / statistics.median(bares)
    out = {"video": str(video), "frames": n_frames, "size": [scene.camera.width_px, scene.camera.height_px],
           "points_per_object": n_points, "track_fps": end_fps, "bare_opencv_fps": bare_fps,
           "ratio": end_fps / bare_fps}
    if args.json:
        print(json.dumps(out))
    else:
        print(f"video: {n_frames} frames {scene.camera.width_px}x{scene.camera.height_px}, "
              f"features per object {n_points}, median of {args.repeats}")
        print(f"track (end to end) : {end_fps:7.1f} frames/s")
        print(f"bare OpenCV calls  : {bare_fps:7.1f} frames/s")
        print(f"ratio              : {end_fps / bare_fps:7.3f}  (target >= 0.5)")
    return 0


if __name__ == "__main__":
    from galileo.errors import run_reporting_errors

    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
