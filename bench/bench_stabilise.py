"""Stabilisation speed: `galileo.vision.stabilise.Stabilised` against the bare OpenCV calls it makes.

Usage (from the repository root):
    python bench/bench_stabilise.py [--video V] [--repeats 5] [--json]

Without --video it renders the demo preset (640x480, 61 frames) into a temporary folder
first. Two clips are timed, both decoded beforehand (decoding is the same with or without
stabilisation): the video as it is (a still camera: every frame comes out untouched) and
the video shaken by a known similarity per frame (up to ~3 px and 0.3 deg, smooth) with
a flickering exposure (a few % a frame), encoded again as H.264. "Bare" is, per frame,
the OpenCV calls the stabiliser makes (`bare_calls`: the detail, the coarse phase correlation, the
forward-backward pyramidal Lucas-Kanade from the reference on as many of its good features as the
stabiliser tracked in that frame, `cv2.estimateAffinePartial2D`, the photometric samples' blur and
`cv2.warpAffine` of the luma and of the chroma), with nothing else: no feature bookkeeping,
photometric fit, sharpness or gating.
Target (issue 29): the stabiliser at >= 0.5x the bare calls' frames per second.
"""
from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from galileo.video import VideoStream, write_video, yuv_to_rgb  # noqa: E402
from galileo.vision import stabilise  # noqa: E402
from galileo.vision.stabilise import Stabilised, similarity_matrix  # noqa: E402


class Planes:
    """Decoded frames replayed as a VideoStream's `.yuv()` (the timing leaves decoding out)."""

    def __init__(self, frames, fps):
        self.frames, self.fps = frames, fps
        self.height_px, self.width_px = frames[0][0].shape
        self.n_frames = len(frames)

    def yuv(self):
        yield from self.frames


def shaken(video: Path, out: Path) -> Path:
    """The video shaken and flickering (module docstring), as H.264."""
    frames = [yuv_to_rgb(y, uv) for y, uv in VideoStream(video).yuv()]
    h, w = frames[0].shape[:2]
    rgb = []
    for f, img in enumerate(frames):
        m = similarity_matrix((2.5 * math.sin(0.5 * f), 1.5 * math.cos(0.35 * f) - 1.5), 0.3 * math.sin(0.27 * f),
                              1.0, ((w - 1) / 2, (h - 1) / 2))
        g = 1.0 + 0.04 * math.sin(0.2 * f) + 0.02 * (-1) ** f
        warped = cv2.warpAffine(img, m, (w, h), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
        rgb.append(np.clip(np.round(warped * g), 0, 255).astype(np.uint8))
    write_video(out, rgb, 30.0)
    return out


def run_stabiliser(frames) -> tuple[float, Stabilised]:
    stab = Stabilised(Planes(frames, 30.0))
    t0 = time.perf_counter()
    for _ in stab.yuv():
        pass
    return time.perf_counter() - t0, stab


def bare_calls(y0: np.ndarray, frames, n_points: list[int]):
    """A function timing the stabiliser's bare OpenCV calls over `frames` (after frame 0, whose
    features it takes first): per frame, the detail (Gaussian blur, weighted subtraction) of the
    frame, the coarse registration (shrink, two phase correlations of its halves), the forward-
    backward pyramidal Lucas-Kanade from the reference on as many features as the stabiliser
    tracked in that frame, `cv2.estimateAffinePartial2D` (RANSAC) on them, the photometric samples
    (a Gaussian blur of the half-resolution planes) and `cv2.warpAffine` of the luma and the chroma."""
    h, w = y0.shape
    mask = np.zeros((h, w), np.uint8)
    b = stabilise.BORDER_PX
    mask[b:h - b, b:w - b] = 255
    d0 = stabilise._detail(y0)
    feats = cv2.goodFeaturesToTrack(d0, max(n_points), mask=mask, **stabilise.FEATURE_PARAMS)
    lk = dict(winSize=(stabilise.LK_WIN_PX,) * 2, maxLevel=stabilise.LK_LEVELS, criteria=stabilise.LK_CRITERIA)
    m = similarity_matrix((0.5, 0.5))
    small0 = cv2.resize(d0, None, fx=stabilise.COARSE_SCALE, fy=stabilise.COARSE_SCALE,
                        interpolation=cv2.INTER_AREA).astype(np.float32)
    half = small0.shape[1] // 2
    win = cv2.createHanningWindow((half, small0.shape[0]), cv2.CV_32F)
    refs = [np.ascontiguousarray(small0[:, :half]), np.ascontiguousarray(small0[:, half:2 * half])]

    def run() -> float:
        t0 = time.perf_counter()
        for (y, uv), n in zip(frames, n_points):
            d = stabilise._detail(y)
            small = cv2.resize(d, None, fx=stabilise.COARSE_SCALE, fy=stabilise.COARSE_SCALE,
                               interpolation=cv2.INTER_AREA).astype(np.float32)
            for ref, part in zip(refs, (small[:, :half], small[:, half:2 * half])):
                cv2.phaseCorrelate(ref.copy(), np.ascontiguousarray(part), win)
            p0 = feats[:max(n, 3)]
            p1, _, _ = cv2.calcOpticalFlowPyrLK(d0, d, p0, None, **lk)
            cv2.calcOpticalFlowPyrLK(d, d0, p1, None, **lk)
            cv2.estimateAffinePartial2D(p0, p1, method=cv2.RANSAC, ransacReprojThreshold=stabilise.RANSAC_PX)
            cv2.GaussianBlur(cv2.resize(y, (uv.shape[1], uv.shape[0]), interpolation=cv2.INTER_AREA), (0, 0),
                             stabilise.PHOTO_BLUR_PX)
            cv2.GaussianBlur(uv, (0, 0), stabilise.PHOTO_BLUR_PX)
            cv2.warpAffine(y, m, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
            cv2.warpAffine(uv, m, (uv.shape[1], uv.shape[0]), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                           borderMode=cv2.BORDER_REPLICATE)
        return time.perf_counter() - t0

    return run


def bare(frames, n_points: list[int]) -> float:
    return bare_calls(frames[0][0], frames[1:], n_points[1:])()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--video", help="an H.264 video (default: the demo preset, rendered)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench_stabilise_"))
    video = Path(args.video) if args.video else None
    if video is None:
        from galileo.scenarios.ramp.dataset import build

        build("demo", tmp, seed=0, workers=1, progress=False)
        video = tmp / "demo" / "video.mp4"
    results = {}
    for name, path in (("still", video), ("shaken", shaken(video, tmp / "shaken.mp4"))):
        frames = [(y.copy(), uv.copy()) for y, uv in VideoStream(path).yuv()]
        n = len(frames)
        runs = [run_stabiliser(frames) for _ in range(args.repeats)]
        stab = runs[0][1]
        points = [fit.features for fit in stab.fits]
        t_stab = statistics.median(t for t, _ in runs)
        t_bare = statistics.median(bare(frames, points) for _ in range(args.repeats))
        mo = stab.motion()
        results[name] = {"frames": n, "size": f"{frames[0][0].shape[1]}x{frames[0][0].shape[0]}",
                         "points": round(statistics.mean(points[1:])), "stabiliser_fps": (n - 1) / t_stab, "bare_fps": (n - 1) / t_bare,
                         "ratio": t_bare / t_stab, "max_shift_px": mo.max_shift_px, "residual_px": mo.residual_px,
                         "unregistered": len(mo.unregistered_frames), "left_out": len(mo.failed_frames),
                         "notes": stab.notes()}
    if args.json:
        print(json.dumps(results, indent=2))
    else:
        for name, r in results.items():
            print(f"{name:7s} {r['size']} x {r['frames']}: stabiliser {r['stabiliser_fps']:7.1f} frames/s, bare OpenCV "
                  f"{r['bare_fps']:7.1f} frames/s ({r['points']} points a frame): ratio {r['ratio']:.2f} (target >= 0.5); "
                  f"camera moved up to {r['max_shift_px']:.2f} px, residual {r['residual_px']:.3f} px, "
                  f"{r['unregistered']} frames not registered, {r['left_out']} left out")
            for note in r["notes"]:
                print(f"        note: {note}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
