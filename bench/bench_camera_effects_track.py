"""Each camera effect alone (issue 29): what tracking makes of videos filmed through it, against the
same videos filmed clean, and which figure breaks first.

Usage (from the repository root):
    python bench/bench_camera_effects_track.py --scenario ramp --out /tmp/bce [--videos 10] [--levels 0.5 1]
                                               [--effects noise h264 ...] [--workers 2]

For each effect of `galileo.footage.EFFECTS` (default: all twelve) at each level (of its strongest
documented one) it renders `--videos` videos of the scenario's `small` preset (spread over the
preset, so still and moving ones, with and without a target), through that camera alone, with
`galileo.dataset`'s own render (kept in OUT/<scenario>-<camera>/: a rerun reuses them), tracks each
(`galileo track`'s function) and scores it against the render's truth:

* ramp: median position error of the objects over the frames where they move faster than 2 cm/s
  and are seen, velocity RMSE there, the share of those frames seen, and whether the tracker's
  verdict on motion (its "nothing moves" note) is the truth's;
* splash: median position error over the frames seen, the share of frames seen, the bottom-up
  volume's median |error|;
* both: the seconds tracking took (median a video) and how many videos' tracks carry a note about
  the camera.

A figure "breaks" where it passes its limit against the clean videos' (BREAKS: position error
twice clean's, velocity RMSE 1.5 times, the seen share 10 points lower, any more motion misread,
the volume error 10 points higher); the table marks each.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from galileo import registry  # noqa: E402
from galileo.datatypes import Trajectory  # noqa: E402
from galileo.errors import run_reporting_errors  # noqa: E402
from galileo.footage import EFFECTS  # noqa: E402
from galileo.jsonio import read_json  # noqa: E402

MOVING_MPS = 0.02
BREAKS = {"position_mm": ("times", 2.0), "velocity_rmse_mps": ("times", 1.5), "seen": ("drop", 0.1),
          "motion_misread": ("plus", 0), "volume_error": ("plus", 0.1)}   # against the clean videos
CAMERA_NOTE_WORDS = ("camera moved", "exposure", "white balance", "blurred", "cannot be", "registration failed")


def _render(args) -> None:
    scenario, video, folder = args
    if not (Path(folder) / video.name / "truth.json").exists():
        registry.get(scenario).dataset.render_one(video, folder)


def videos(scenario: str, camera: str, n: int, seed: int) -> list:
    plan = registry.get(scenario).dataset.plan("small", seed, camera=camera)
    pick = np.unique(np.round(np.linspace(0, len(plan) - 1, min(n, len(plan)))).astype(int))
    return [plan[i] for i in pick]


def score(scenario: str, folder: Path) -> dict:
    scene = registry.load_scene(folder / "scene.json")
    truth = read_json(folder / "truth.json", "truth")
    traj = Trajectory.from_json(truth["trajectory"])
    t0 = time.perf_counter()
    tracks = registry.of(scene).track(folder / "video.mp4", scene, progress=False)
    out = {"track_s": time.perf_counter() - t0,
           "noted": any(w in note for note in tracks.notes for w in CAMERA_NOTE_WORDS)}
    pos_err, vel_err, seen = [], [], []
    for i, o in enumerate(tracks.objects):
        p, v = traj.position_m[i], traj.velocity_mps[i]
        moving = np.linalg.norm(v, axis=1) > MOVING_MPS if scenario == "ramp" else np.ones(len(p), bool)
        seen += list(o.visible[moving])
        sel = moving & o.visible
        pos_err += list(np.linalg.norm((o.position_m - p)[sel][:, [0, 2]], axis=1))
        vel_err += list(np.linalg.norm((o.velocity_mps - v)[sel][:, [0, 2]], axis=1))
    out.update({"position_mm": 1000 * float(np.median(pos_err)) if pos_err else None,
                "velocity_rmse_mps": float(np.sqrt(np.mean(np.square(vel_err)))) if vel_err else None,
                "seen": float(np.mean(seen)) if seen else None})
    if scenario == "ramp":
        from galileo.scenarios.ramp.tracking import still_note

        moved = bool(np.linalg.norm(traj.position_m[0, -1] - traj.position_m[0, 0]) > 0.005)
        out["motion_misread"] = int(moved == (still_note(scene) in tracks.notes))
    else:
        vol = tracks.objects[0].bottom_up.get("volume_cm3")
        out["volume_error"] = abs(vol / truth["latents"]["volume_cm3"] - 1) if vol else None
    return out


def row(scenario: str, scores: list[dict]) -> dict:
    def med(k):
        xs = [s[k] for s in scores if s.get(k) is not None]
        return float(np.median(xs)) if xs else None

    r = {"videos": len(scores), "noted": sum(s["noted"] for s in scores), "track_s": med("track_s"),
         "position_mm": med("position_mm"), "seen": float(np.mean([s["seen"] for s in scores if s["seen"] is not None]))}
    if scenario == "ramp":
        r["velocity_rmse_mps"] = float(np.sqrt(np.mean([s["velocity_rmse_mps"] ** 2 for s in scores
                                                        if s["velocity_rmse_mps"] is not None])))
        r["motion_misread"] = sum(s["motion_misread"] for s in scores)
    else:
        r["volume_error"] = med("volume_error")
    return r


def broken(r: dict, clean: dict) -> list[str]:
    """The figures of row `r` past their limit against the clean videos' (`BREAKS`)."""
    out = []
    for k, (how, limit) in BREAKS.items():
        x, c = r.get(k), clean.get(k)
        if x is None or c is None:
            continue
        if {"times": x > limit * max(c, 1e-9), "drop": x < c - limit, "plus": x > c + limit}[how]:
            out.append(k)
    return out


def markdown(scenario: str, rows: dict[str, dict]) -> str:
    cols = (["position_mm", "velocity_rmse_mps", "seen", "motion_misread"] if scenario == "ramp"
            else ["position_mm", "seen", "volume_error"])
    fmt = {"position_mm": "{:.1f}", "velocity_rmse_mps": "{:.3f}", "seen": "{:.0%}", "motion_misread": "{}",
           "volume_error": "{:.0%}"}
    head = "| camera | " + " | ".join(cols) + " | camera noted | track s/video | breaks |\n|" + "---|" * (len(cols) + 4)
    lines = []
    for name, r in rows.items():
        bad = broken(r, rows["clean"])
        cells = [("**" if c in bad else "") + ("–" if r.get(c) is None else fmt[c].format(r[c])) + ("**" if c in bad else "")
                 for c in cols]
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {r['noted']}/{r['videos']} | {r['track_s']:.1f} | "
                     + (", ".join(bad) or "–") + " |")
    return "\n".join([head, *lines])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="ramp", choices=("ramp", "splash"))
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--videos", type=int, default=10)
    ap.add_argument("--effects", nargs="+", default=list(EFFECTS))
    ap.add_argument("--levels", nargs="+", type=float, default=[1.0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    cameras = ["clean"] + [e if lv == 1 else f"{e}:{lv:g}" for e in args.effects for lv in args.levels]
    rows = {}
    with ProcessPoolExecutor(args.workers) as pool:
        for cam in cameras:
            folder = args.out / f"{args.scenario}-{cam.replace(':', '_')}"
            folder.mkdir(parents=True, exist_ok=True)
            vids = videos(args.scenario, cam, args.videos, args.seed)
            list(pool.map(_render, [(args.scenario, v, str(folder)) for v in vids]))
            scores = list(pool.map(score, [args.scenario] * len(vids), [folder / v.name for v in vids]))
            rows[cam] = row(args.scenario, scores)
            print(f"{cam}: {json.dumps(rows[cam])}", flush=True)
    print(markdown(args.scenario, rows))
    if args.json:
        print(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(run_reporting_errors("bench_camera_effects_track", main))
