"""Peak memory of `galileo track` on a long, large video (issue 24): a 60 s 1080p clip.

Usage (from the repository root):
    python bench/bench_video_memory.py [--seconds 60] [--work DIR] [--before DIR] [--cap-gb 12] [--json]

The clip: the demo preset's video (640x480, 61 frames at 30 fps: a block slides into a box),
scaled by 2.25 to 1440x1080 and padded with black to 1920x1080, then held on its last frame
(the objects at rest) up to --seconds at 30 fps; its scene is the demo's with the camera
scaled and shifted to match (fx, fy, cx, cy x 2.25, then cx + 240) and n_frames the clip's.
Both are made once in --work (default: a folder under the system's temporary one) and
reused. The clip is tracked end to end by `python -m galileo track` in a child process, and
its peak resident memory is what the kernel reports when it exits (wait4's ru_maxrss); the
wall time is the child's. --before DIR runs the tracker of another checkout too (DIR first
on PYTHONPATH), e.g. the commit before the change: `git worktree add /tmp/before HEAD~1`. A
run whose resident memory passes --cap-gb is stopped there and reported as more than it.
Target: peak RSS <= 1 GB.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

FPS = 30.0
SCALE = 2.25                 # 640x480 -> 1440x1080
SIZE = (1920, 1080)          # width, height: the scaled frame padded with black left and right
PAD_X = (SIZE[0] - round(640 * SCALE)) // 2


def make_clip(work: Path, seconds: float) -> tuple[Path, Path]:
    """(video, scene) of the clip (see the module docstring), made once."""
    import cv2

    from galileo.registry import load_scene
    from galileo.video import read_video, write_video

    n = int(round(seconds * FPS))
    video, scene_path = work / f"clip_{n}.mp4", work / f"clip_{n}.json"
    if video.exists() and scene_path.exists():
        return video, scene_path
    demo = work / "demo"
    if not (demo / "video.mp4").exists():
        from galileo.scenarios.ramp.dataset import build

        build("demo", work, seed=0, workers=1, progress=False)
    small, _ = read_video(demo / "video.mp4")

    def frames():
        for f in range(n):
            big = np.zeros((SIZE[1], SIZE[0], 3), np.uint8)
            big[:, PAD_X:PAD_X + round(640 * SCALE)] = cv2.resize(small[min(f, len(small) - 1)], None, fx=SCALE,
                                                                  fy=SCALE, interpolation=cv2.INTER_LINEAR)
            yield big

    print(f"writing {video} ({n} frames at {SIZE[0]}x{SIZE[1]})", file=sys.stderr)
    write_video(video, frames(), FPS)
    d = json.loads((demo / "scene.json").read_text())
    cam = d["camera"]
    k = np.array(cam["K"], float)
    k[:2] *= SCALE
    k[0, 2] += PAD_X
    cam.update(K=k.tolist(), width_px=SIZE[0], height_px=SIZE[1], n_frames=n)
    scene_path.write_text(json.dumps(d))
    load_scene(scene_path)   # (checked)
    return video, scene_path


def measure(video: Path, scene: Path, out: Path, pythonpath: str | None, cap_bytes: float) -> dict:
    """Peak RSS (bytes), wall time (s) and what `galileo track` printed, run in a child process."""
    env = dict(os.environ)
    if pythonpath:
        env["PYTHONPATH"] = pythonpath + os.pathsep + env.get("PYTHONPATH", "")
    argv = [sys.executable, "-m", "galileo", "track", str(video), "--scene", str(scene), "--out", str(out), "--quiet"]
    t0 = time.perf_counter()
    proc = subprocess.Popen(argv, env=env, cwd=pythonpath or ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    capped = threading.Event()

    def watch():   # stop a run past the cap (before the machine runs out of memory)
        import psutil

        try:
            p = psutil.Process(proc.pid)
            while proc.returncode is None:
                if p.memory_info().rss > cap_bytes:
                    capped.set()
                    p.kill()
                    return
                time.sleep(0.1)
        except psutil.NoSuchProcess:
            pass

    threading.Thread(target=watch, daemon=True).start()
    printed = proc.stdout.read()
    _, status, usage = os.wait4(proc.pid, 0)   # (the child's own peak, which Popen.wait would not give)
    proc.returncode = os.waitstatus_to_exitcode(status)
    return {"peak_rss_bytes": usage.ru_maxrss * 1024, "capped": capped.is_set(), "wall_s": time.perf_counter() - t0,
            "rc": proc.returncode, "printed": printed.strip()[-500:]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--work", default=str(Path(tempfile.gettempdir()) / "galileo-bench-video-memory"))
    ap.add_argument("--before", help="another checkout to measure too (put first on PYTHONPATH)")
    ap.add_argument("--cap-gb", type=float, default=12.0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    work = Path(args.work).resolve()
    work.mkdir(parents=True, exist_ok=True)
    video, scene = make_clip(work, args.seconds)
    runs = {"after": measure(video, scene, work / "tracks.json", None, args.cap_gb * 1e9)}
    if args.before:
        runs["before"] = measure(video, scene, work / "tracks_before.json", args.before, args.cap_gb * 1e9)
    out = {"video": str(video), "frames": int(round(args.seconds * FPS)), "size": list(SIZE),
           "decoded_bytes": int(round(args.seconds * FPS)) * SIZE[0] * SIZE[1] * 3 // 2, "runs": runs}
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"clip: {out['frames']} frames {SIZE[0]}x{SIZE[1]} at {FPS:g} fps "
          f"({out['decoded_bytes'] / 1e9:.2f} GB decoded as yuv420p)")
    for name, r in runs.items():
        peak = f"> {args.cap_gb:g} GB (stopped at the cap)" if r["capped"] else f"{r['peak_rss_bytes'] / 1e9:.3f} GB"
        print(f"{name:6s}: peak RSS {peak}, {r['wall_s']:.1f} s, exit {r['rc']}: {r['printed']}")
    print("target: peak RSS <= 1 GB")
    return 0


if __name__ == "__main__":
    from galileo.errors import run_reporting_errors

    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
