"""The fall's own-video calibration on the Physics 101 clips (`galileo scene --scenario fall`): the
focal length the table's four corners give under assumed table sizes, how much where the
rounded corners are clicked moves it, and the camera it gives; writes the chosen corners and
size to bench/fall_real_clicks.json for the fall benchmarks.

Usage (from the repository root):
    python bench/bench_fall_clicks.py [--data DIR] [--overlay DIR] [--json]

The corners (CORNERS_PX, frame 0 of each clip, 1920x1080; both clips share the camera and the
table, their corners agree within 0.2 px): the folding table's rounded corners are clicked where
its straight edges would meet. Its left, right and far edges were fitted as lines (sub-pixel
peaks of the smoothed image's gradient along 65-110 rows or columns of each straight part, RMS
0.2-0.5 px from the line); the far corners are the far edge's intersections with the side
edges. The near edge lies just below the frame (the rim's inner line turns level at the frame's
last rows, at both near corners), so the near corners are clicked where the side edges leave the
frame (v = 1079): the rectangle clicked is the table less the strip below the frame (about 1 cm).

Reported per assumed size: the focal length estimated from the corners (principal point at the
image centre, square pixels), how much a pixel's error moves it (`focal_spread_per_px`), the
camera's height, distance and tilt; the aspect ratio (length / width) whose estimate is a Kinect
v2 colour camera's focal length (KINECT_FOCAL_PX: its 84 deg horizontal field of view at 1920
px); the reprojection error with that focal length given; and the focal length's change when
the near corners are taken 10-40 px lower (the near edge's true place below the frame) or the
far corners clicked on the rounded corners' arcs (ARC_PX inward along the corner's diagonal)
instead of where the edges meet. Deterministic: no random draws.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from galileo.clicks import calibration_of, focal_spread_per_px
from galileo.errors import GalileoError
from galileo.jsonio import write_json
from galileo.scenarios.fall.clicks import estimate_focal_px, tilt_deg
from galileo.scenarios.fall.scene import FallScene, surface_corners_m
from galileo.video import VideoInfo

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "phys101" / "fall"
CLIPS = ("w_block_05-table-01-Kinect_RGB_1.mp4", "w_block_05-table-02-Kinect_RGB_1.mp4")
CORNERS_PX = {   # near left, near right, far right, far left (see the module)
    CLIPS[0]: ((52.2, 1079.0), (1653.6, 1079.0), (1236.4, 411.5), (625.1, 421.1)),
    CLIPS[1]: ((52.2, 1079.0), (1653.7, 1079.0), (1236.2, 411.6), (625.2, 421.0)),
}
INFO = VideoInfo(1920, 1080, 30.0, 33)
FT = 0.3048
SIZES_M = {"4 ft x 2 ft": (4 * FT, 2 * FT), "5 ft x 2.5 ft": (5 * FT, 2.5 * FT), "6 ft x 2.5 ft": (6 * FT, 2.5 * FT),
           "3 ft x 2.5 ft": (3 * FT, 2.5 * FT), "30 in x 24 in": (2.5 * FT, 2 * FT)}
KINECT_FOCAL_PX = 1060.0     # a Kinect v2 colour camera: 1920 / (2 tan(84.1 deg / 2)) = 1063; calibrations 1050-1080
CHOSEN = "3 ft x 2.5 ft"     # the size written for the fall benchmarks (see the report)
NEAR_LOWER_PX = (10, 20, 40)
ARC_PX = 6.0                 # the far corners' arcs pass about this far inside where the edges meet (frame 0, by eye)


def focal_px(uv, size_m) -> float | None:
    return estimate_focal_px(np.asarray(uv, float), surface_corners_m(FallScene(surface_size_m=size_m)), 1920, 1080)


def near_lower(uv, d_px: float) -> np.ndarray:
    """The near corners moved d_px down their side edges (the far corners kept)."""
    uv = np.array(uv, float)
    for near, far in ((0, 3), (1, 2)):
        step = (uv[near] - uv[far]) / (uv[near] - uv[far])[1]
        uv[near] = uv[near] + d_px * step
    return uv


def far_on_arc(uv, d_px: float) -> np.ndarray:
    """The far corners moved d_px into the table along their corners' diagonals."""
    uv = np.array(uv, float)
    for corner, a, b in ((2, 1, 3), (3, 0, 2)):
        inward = (uv[a] - uv[corner]) / np.linalg.norm(uv[a] - uv[corner]) + \
            (uv[b] - uv[corner]) / np.linalg.norm(uv[b] - uv[corner])
        uv[corner] = uv[corner] + d_px * inward / np.linalg.norm(inward)
    return uv


def aspect_for_focal(uv, target_px: float, width_m: float = 0.61) -> float:
    """The length / width whose estimated focal length is `target_px` (bisection: the estimate
    grows with the aspect ratio for these corners)."""
    lo, hi = 1.0, 3.0
    for _ in range(60):
        mid = (lo + hi) / 2
        f = focal_px(uv, (mid * width_m, width_m))
        lo, hi = (mid, hi) if f is None or f < target_px else (lo, mid)
    return (lo + hi) / 2


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(DATA), help="the folder of the Physics 101 fall clips")
    ap.add_argument("--overlay", default=None, help="write each clip's overlay (PNG) for the chosen size here")
    ap.add_argument("--json", action="store_true", help="print the numbers as JSON")
    args = ap.parse_args(argv)
    cal = calibration_of("fall")
    out: dict = {}
    for clip, uv in CORNERS_PX.items():
        uv = np.asarray(uv, float)
        rows = {}
        for name, size in SIZES_M.items():
            numbers = {"length_m": size[0], "width_m": size[1]}
            scene, _ = cal.solve(uv, numbers, INFO)
            cam = scene.camera
            spread = focal_spread_per_px(surface_corners_m(scene)[:, :2], uv, 960, 540, "the table")
            try:
                err = cal.solve(uv, {**numbers, "focal_px": KINECT_FOCAL_PX}, INFO)[1]
                kinect = f"{err:.1f} px"
            except GalileoError as e:
                kinect = f"refused: {e}"
            rows[name] = {"size_m": size, "focal_px": round(float(cam.K[0, 0]), 1),
                          "focal_per_px_pct": round(100 * spread, 2),
                          "height_m": round(float(cam.position_in_world[2]), 3),
                          "distance_m": round(float(np.linalg.norm(cam.position_in_world)), 3),
                          "tilt_deg": round(tilt_deg(cam), 1), "kinect_focal_reprojection": kinect,
                          "near_lower_pct": {d: round(100 * (focal_px(near_lower(uv, d), size) / cam.K[0, 0] - 1), 2)
                                             for d in NEAR_LOWER_PX},
                          "far_on_arc_pct": round(100 * (focal_px(far_on_arc(uv, ARC_PX), size) / cam.K[0, 0] - 1),
                                                  2)}
        out[clip] = {"sizes": rows, "aspect_for_kinect": round(aspect_for_focal(uv, KINECT_FOCAL_PX), 3)}
        if args.overlay:
            import cv2

            from galileo.clicks import sample_video
            from galileo.jsonio import atomic_write_bytes

            size = SIZES_M[CHOSEN]
            scene, _ = cal.solve(uv, {"length_m": size[0], "width_m": size[1]}, INFO)
            _, first, _ = sample_video(Path(args.data) / clip)
            Path(args.overlay).mkdir(parents=True, exist_ok=True)
            png = cv2.imencode(".png", cal.draw_overlay(first, scene, uv)[..., ::-1])[1].tobytes()
            atomic_write_bytes(Path(args.overlay) / (Path(clip).stem + ".png"), png)
    chosen = SIZES_M[CHOSEN]
    write_json(ROOT / "bench" / "fall_real_clicks.json", {
        "about": "the Physics 101 fall clips' table corners (frame 0; near left, near right, far right, far left; "
                 "where the straight edges meet, the near ones where the side edges leave the frame) and the size "
                 f"assumed ({CHOSEN}: its aspect ratio makes the estimated focal length a Kinect v2's); written by "
                 "bench/bench_fall_clicks.py",
        "clips": {clip: {"points": " ".join(f"{u:g},{v:g}" for u, v in uv)} for clip, uv in CORNERS_PX.items()},
        "length_m": round(chosen[0], 4), "width_m": round(chosen[1], 4), "surface": "table", "surface_kind": "table",
        "object": "block"})
    if args.json:
        print(json.dumps(out, indent=1))
        return 0
    for clip, r in out.items():
        print(clip)
        for name, row in r["sizes"].items():
            print(f"  {name:14s} focal {row['focal_px']:7.1f} px ({row['focal_per_px_pct']:.2f}%/px); camera "
                  f"{row['height_m']:.2f} m up, {row['distance_m']:.2f} m away, {row['tilt_deg']:.0f} deg down; "
                  f"near corners 10/20/40 px lower: {', '.join(f'{v:+.1f}%' for v in row['near_lower_pct'].values())};"
                  f" far on the arcs: {row['far_on_arc_pct']:+.1f}%; with f {KINECT_FOCAL_PX:g}: "
                  f"{row['kinect_focal_reprojection']}")
        print(f"  the aspect ratio (length / width) whose focal length is {KINECT_FOCAL_PX:g} px: "
              f"{r['aspect_for_kinect']:.3f}")
    print(f"wrote {ROOT / 'bench' / 'fall_real_clicks.json'} ({CHOSEN})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
