"""How well own-video calibration recovers a known camera from clicks with pixel noise (the
splash's six points, the ramp's four): `galileo.clicks.Calibration.solve` on the true points'
projections plus Gaussian noise of SD sigma (pixels, each coordinate), over many draws.

Usage (from the repository root):
    python bench/bench_clicks.py [--draws 300] [--sigmas 1 1.5 2] [--seed 0] [--json]

Cameras: the splash dataset's (`splash.scene.default_camera`: 640x480, f 900 px, straight at
the tank's front, which gives no focal length: it is given), a view of the tank from above and
to its left (640x480, f 560 px; focal estimated and given) and the ramp dataset's camera
(`ramp.scene.default_camera`, focal estimated; its upper points 0.5 m up the ramp). Per
camera and sigma: the focal length's relative error (SD, mean), the camera's position error
(median, 95th and 99th percentile, mm), its rotation error (median, degrees), the water level's
error (SD, mm; splash) and the largest error over a grid of points on the plane the trackers
back-project onto (median, 95th, 99th percentile, mm: the splash's release plane y = 0, the
ramp's top surface), as a pixel there maps back to the world through the solved camera
rather than the true one; and the milliseconds a solve takes. Seeded: the same numbers each run.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from galileo.camera import backproject_to_plane, look_at_camera  # noqa: E402
from galileo.clicks import calibration_of  # noqa: E402
from galileo.errors import GalileoError  # noqa: E402
from galileo.video import VideoInfo  # noqa: E402

WATER_X_M = (-0.1, 0.12)      # where along the water line the two water points are clicked


def rotation_deg(a, b) -> float:
    r = a.world_to_camera[:3, :3].T @ b.world_to_camera[:3, :3]
    return math.degrees(math.acos(np.clip((np.trace(r) - 1) / 2, -1, 1)))


def splash_case(cam, focal_given: bool):
    from galileo.scenarios.splash.clicks import front_corners
    from galileo.scenarios.splash.scene import Tank

    t = Tank()
    (sx, sy, sz), level = t.size_m, t.water_level_m
    pts = np.concatenate([front_corners(sx, sy, sz), [[x, -sy / 2, level] for x in WATER_X_M]])
    nums = {"tank_width_m": sx, "tank_depth_m": sy, "tank_height_m": sz, "release_x_m": 0.0,
            "release_height_m": 0.15, "focal_px": cam.K[0, 0] if focal_given else None}
    grid = np.array([[x, 0.0, z] for x in np.linspace(-0.15, 0.15, 7) for z in np.linspace(0.02, 0.4, 8)])
    return "splash", pts, nums, grid, (lambda c, uv: backproject_to_plane(c, uv, 0.0)), level


def ramp_case(cam):
    from galileo.scenarios.ramp.clicks import ramp_points_in_world
    from galileo.scenarios.ramp.scene import Ramp

    r = Ramp()
    pts = ramp_points_in_world(r.length_m, r.width_m, r.angle_deg, 0.5)
    nums = {"ramp_length_m": r.length_m, "ramp_width_m": r.width_m, "angle_deg": r.angle_deg, "upper_at_m": 0.5,
            "start_m": 0.3}
    a = math.radians(r.angle_deg)
    up, across = np.array([-math.cos(a), 0.0, math.sin(a)]), np.array([0.0, 1.0, 0.0])
    grid = np.array([s * up + w * across for s in np.linspace(0.05, 0.85, 9) for w in np.linspace(-0.1, 0.1, 5)])
    normal = np.array([math.sin(a), 0.0, math.cos(a)])

    def on_surface(c, uv):   # back-project onto the ramp's top surface (a plane through the foot)
        r_, t_ = c.world_to_camera[:3, :3], c.world_to_camera[:3, 3]
        rays = np.c_[uv, np.ones(len(uv))] @ np.linalg.inv(c.K).T @ r_
        o = -r_.T @ t_
        return o + (-(o @ normal) / (rays @ normal))[:, None] * rays

    return "ramp", pts, nums, grid, on_surface, None


def run(case, cam, sigma: float, draws: int, seed: int) -> dict:
    scenario, pts, nums, grid, back, level = case
    cal = calibration_of(scenario)
    info = VideoInfo(cam.width_px, cam.height_px, cam.fps, cam.n_frames)
    uv0, guv = cam.project(pts), cam.project(grid)
    rng = np.random.default_rng(seed)
    rows, refused, t0 = [], 0, time.perf_counter()
    for _ in range(draws):
        uv = np.clip(uv0 + rng.normal(0.0, sigma, uv0.shape), 0, [cam.width_px - 1e-3, cam.height_px - 1e-3])
        try:
            scene, _ = cal.solve(uv, {k: v for k, v in nums.items() if v is not None}, info)
        except GalileoError:
            refused += 1
            continue
        c = scene.camera
        rows.append((c.K[0, 0] / cam.K[0, 0] - 1, np.linalg.norm(c.position_in_world - cam.position_in_world),
                     rotation_deg(c, cam), (scene.tank.water_level_m - level) if level is not None else 0.0,
                     np.linalg.norm(back(c, guv) - grid, axis=1).max()))
    ms = (time.perf_counter() - t0) / draws * 1000
    a = np.array(rows)
    pct = lambda col, q: float(np.percentile(a[:, col], q) * 1000)   # noqa: E731
    return {"sigma_px": sigma, "draws": draws, "refused": refused, "focal_sd": float(a[:, 0].std()),
            "focal_mean": float(a[:, 0].mean()), "position_mm": [pct(1, 50), pct(1, 95), pct(1, 99)],
            "rotation_deg_median": float(np.median(a[:, 2])), "water_level_sd_mm": float(a[:, 3].std() * 1000),
            "plane_max_mm": [pct(4, 50), pct(4, 95), pct(4, 99)], "ms_per_solve": ms}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=300)
    ap.add_argument("--sigmas", type=float, nargs="+", default=[1.0, 1.5, 2.0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    from galileo.scenarios.ramp.scene import default_camera as ramp_camera
    from galileo.scenarios.splash.scene import Tank, default_camera

    above = look_at_camera((-0.35, -0.6, 0.55), (0.0, 0.0, 0.15), focal_px=560.0)
    cases = {"splash front view, focal given": (splash_case(default_camera(Tank()), True), default_camera(Tank())),
             "splash from above left, focal estimated": (splash_case(above, False), above),
             "splash from above left, focal given": (splash_case(above, True), above),
             "ramp dataset view, focal estimated": (ramp_case(ramp_camera()), ramp_camera())}
    out = {name: [run(case, cam, s, args.draws, args.seed) for s in args.sigmas] for name, (case, cam) in cases.items()}
    if args.json:
        print(json.dumps(out, indent=1))
        return 0
    for name, rows in out.items():
        print(name)
        for r in rows:
            p, g = r["position_mm"], r["plane_max_mm"]
            print(f"  sigma {r['sigma_px']:g} px: focal SD {100 * r['focal_sd']:.1f}% "
                  f"(mean {100 * r['focal_mean']:+.1f}%), camera position {p[0]:.0f}/{p[1]:.0f}/{p[2]:.0f} mm "
                  f"(median/95%/99%), rotation "
                  f"{r['rotation_deg_median']:.2f} deg, water level SD {r['water_level_sd_mm']:.1f} mm, on the "
                  f"tracking plane {g[0]:.1f}/{g[1]:.1f}/{g[2]:.1f} mm; {r['refused']} refused; "
                  f"{r['ms_per_solve']:.1f} ms a solve")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
