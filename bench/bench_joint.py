"""One problem over two videos: the same block slid down a 20 and a 10 degree ramp, its friction shared.

Renders the two videos from the demo's scene (the demo's camera and target, the block's friction
set to K1 so that it slides at 10 degrees too), tracks them, then times `galileo infer` end to end
(the command a user runs) on each video alone and on both with `--share k1`, and reports each
run's k1 posterior (median, SD, 90% interval) against the truth.

    python bench/bench_joint.py [--chains 16] [--sweeps 75] [--workers 2] [--out /tmp/bench_joint]
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

K1 = 0.1        # the block's friction: it slides at 10 degrees (tan 10 deg = 0.176) and at 20
M1_KG = 0.3


def videos(out: Path) -> list[tuple[Path, Path]]:
    """The two videos and their scene files (rendered once into `out`)."""
    import app
    from galileo import registry
    from galileo.scenarios.ramp.render import render_to_video

    demo = registry.load_scene(app.ensure_demo(progress=False) / "scene.json")
    made = []
    for angle in (20.0, 10.0):
        video, scene_path = out / f"slide{angle:.0f}.mp4", out / f"slide{angle:.0f}.json"
        if not video.is_file():
            scene = demo.with_values({"angle_deg": angle, "k1": K1, "m1_kg": M1_KG})
            render_to_video(scene, video, scene.camera.n_frames)
            scene.save(scene_path)
        made.append((video, scene_path))
    return made


def run(args: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "galileo", "infer", *args, "--quiet"], check=True,
                   stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def k1_of(result: Path) -> dict:
    d = json.loads(result.read_text())
    return d["posterior"]["k1"]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--chains", type=int, default=16)
    ap.add_argument("--sweeps", type=int, default=75)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default="/tmp/bench_joint")
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    (v20, s20), (v10, s10) = videos(out)
    common = ["--chains", str(a.chains), "--sweeps", str(a.sweeps), "--workers", str(a.workers), "--seed", "0"]
    for video, scene in ((v20, s20), (v10, s10)):   # tracks once, outside the timings below
        tracks = video.with_suffix(".tracks.json")
        if not tracks.is_file():
            subprocess.run([sys.executable, "-m", "galileo", "track", str(video), "--scene", str(scene), "--out",
                            str(tracks), "--quiet"], check=True, stdout=subprocess.DEVNULL)
    rows = []
    for name, args in (
            ("20 deg alone", [str(v20), "--scene", str(s20), "--tracks", str(v20.with_suffix(".tracks.json"))]),
            ("10 deg alone", [str(v10), "--scene", str(s10), "--tracks", str(v10.with_suffix(".tracks.json"))]),
            ("both, --share k1", [str(v20), str(v10), "--scene", str(s20), str(s10), "--tracks",
                                  str(v20.with_suffix(".tracks.json")), str(v10.with_suffix(".tracks.json")),
                                  "--share", "k1"])):
        result = out / f"{name.split()[0]}.result.json"
        wall = run([*args, *common, "--out", str(result)])
        k = k1_of(result)
        rows.append((name, wall, k))
        print(f"{name:18s} {wall:6.1f} s   k1 median {k['q50']:.4f}  SD {k['sd']:.4f}  90% {k['q05']:.4f}-"
              f"{k['q95']:.4f}  (truth {K1})", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
