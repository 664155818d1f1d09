"""How well the spring's click calibration (`galileo/scenarios/spring/clicks.py`: a camera square
to the spring's plane) places the object on the spring dataset's cameras, which are turned from
the plane by up to 8 degrees of yaw and 6 of pitch (mild perspective; the demo's is square).

Usage (from the repository root):
    python bench/bench_spring_clicks.py [--preset full] [--seed 0] [--sigma 1.5] [--draws 50] [--json]

Per planned video (no rendering: the planned scene and its camera, the object's simulated
centre): the clicks the calibration's `example` asks for (the hanging point, the object's
centre at rest, the ends of its width there) projected by the true camera, exact and with
Gaussian noise of SD sigma pixels (each coordinate, `--draws` draws); the scene solved from them
with the true focal length; each frame's true centre pixel back-projected onto the spring's
plane through the solved camera. Reported: the camera's tilt from the plane's normal, the
centre's error over the video (median and largest, mm) and the error of the bounce's
peak-to-peak height (percent), from exact clicks, and the median over draws of the largest
error and of the height's absolute error with noisy clicks. Seeded: the same numbers each run.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from galileo.camera import backproject_to_plane
from galileo.clicks import calibration_of
from galileo.errors import GalileoError
from galileo.video import VideoInfo


def errors(cal, scene, uv, numbers, centre_px, truth) -> tuple[float, float, float]:
    """(median, largest centre error in mm, relative error of the bounce's height) of a solve."""
    solved, _ = cal.solve(uv, numbers, VideoInfo(scene.camera.width_px, scene.camera.height_px, scene.fps,
                                                 scene.n_frames))
    back = backproject_to_plane(solved.camera, centre_px, scene.top_in_world_m[1])
    err = np.linalg.norm(back - truth, axis=1) * 1000
    height = np.ptp(back[:, 2]) / np.ptp(truth[:, 2]) - 1
    return float(np.median(err)), float(err.max()), float(height)


def run(preset: str, seed: int, sigma: float, draws: int) -> list[dict]:
    from galileo.scenarios.spring.dataset import plan, scene_for
    from galileo.scenarios.spring.physics import simulate

    cal = calibration_of("spring")
    rows = []
    for spec in plan(preset, seed):
        scene, _ = scene_for(spec)
        truth = simulate(scene, scene.n_frames).position_m[0][scene.release_frame:]
        centre_px = scene.camera.project(truth)
        world, numbers = cal.example(scene)
        uv0 = scene.camera.project(world)
        tilt = math.degrees(math.acos(abs(scene.camera.world_to_camera[2, 1])))
        depth = abs(scene.camera.position_in_world[1] - scene.top_in_world_m[1])
        row = {"video": spec.name, "tilt_deg": tilt, "distance_m": depth, "width_px": float(np.linalg.norm(
            uv0[3] - uv0[2]))}
        rows.append(row)
        try:
            med, worst, height = errors(cal, scene, uv0, numbers, centre_px, truth)
        except GalileoError as e:     # (an object too small in the picture to be the scale)
            row["refused"] = str(e)
            continue
        rng = np.random.default_rng([seed, len(rows)])
        noisy, refused = [], 0
        for _ in range(draws):
            try:
                noisy.append(errors(cal, scene, uv0 + rng.normal(0.0, sigma, uv0.shape), numbers, centre_px, truth))
            except GalileoError:
                refused += 1
        noisy = np.array(noisy)
        row.update({"median_mm": med, "max_mm": worst, "height_pct": 100 * height, "noisy_refused": refused,
                    "noisy_max_mm": float(np.median(noisy[:, 1])),
                    "noisy_height_pct": float(100 * np.median(np.abs(noisy[:, 2])))})
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="full")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--sigma", type=float, default=1.5)
    ap.add_argument("--draws", type=int, default=50)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    rows = run(args.preset, args.seed, args.sigma, args.draws)
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    print(f"| video | tilt (deg) | distance (m) | width (px) | centre error median / max (mm) | bounce height error | "
          f"sigma {args.sigma:g} px: max (mm), height error (medians; refused) |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        head = f"| {r['video']} | {r['tilt_deg']:.1f} | {r['distance_m']:.2f} | {r['width_px']:.0f} |"
        if "refused" in r:
            print(f"{head} refused: {r['refused']} | | |")
            continue
        print(f"{head} {r['median_mm']:.1f} / {r['max_mm']:.1f} | {r['height_pct']:+.2f}% | {r['noisy_max_mm']:.1f}, "
              f"{r['noisy_height_pct']:.2f}%; {r['noisy_refused']} |")
    solved = [r for r in rows if "refused" not in r]
    a = {k: np.array([r[k] for r in solved]) for k in solved[0] if k != "video"}
    print(f"\n{len(rows)} videos, {len(rows) - len(solved)} refused from exact clicks; of the {len(solved)}: largest "
          f"centre error median {np.median(a['max_mm']):.1f} mm (worst "
          f"{a['max_mm'].max():.1f}); bounce height error median {np.median(np.abs(a['height_pct'])):.2f}% (worst "
          f"{np.abs(a['height_pct']).max():.2f}%); with sigma {args.sigma:g} px clicks: largest error median "
          f"{np.median(a['noisy_max_mm']):.1f} mm, height error median {np.median(a['noisy_height_pct']):.2f}%")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
