"""Galileo through a real camera (issue 29): the paper's figures on videos rendered with camera effects
(`galileo dataset --camera NAME`), against the same videos filmed clean.

Usage (from the repository root):
    python bench/bench_camera.py --scenario ramp --preset small --cameras clean phone handheld --out /tmp/bc
    python bench/bench_camera.py --scenario splash --preset small --cameras clean phone handheld --out /tmp/bc
    python bench/bench_camera.py --scenario ramp --preset small --cameras clean noise h264 ... --max-videos 10 \
                                 --out /tmp/bc                 # each effect alone (galileo.footage.EFFECTS)

For each camera it renders the preset (`galileo dataset --scenario S --preset P --camera C`, kept in
OUT/<scenario>-<preset>-<camera>: a rerun reuses it) and runs, as a user would, in a new process
timed from start to exit,

    galileo experiment DATASET --out OUT/run-<scenario>-<preset>-<camera> --quiet [--chains --sweeps --workers]

(every video tracked and inferred; a rerun resumes), then prints a markdown table of the issue's
figures with each camera's ratio to the first camera's (clean):

* ramp: k1's median |error| (the MAP's and the posterior median's), moving objects read as still and
  still ones read as moving (the tracker's "nothing moves" note against the truth), the mass ratio's
  Spearman correlation with the truth (collision videos), k1's 90% interval coverage;
* splash: mass Pearson (posterior medians, every video with a prediction), bottom-up volume median
  |error|, mass 90% coverage;
* both: the share of videos whose tracks carry a note about the camera (moved, exposure, blur,
  a distractor), and the seconds the experiment took.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from galileo.errors import GalileoError, run_reporting_errors  # noqa: E402
from galileo.jsonio import read_json, write_json  # noqa: E402

CAMERA_NOTE_WORDS = ("camera moved", "exposure", "white balance", "blurred", "where the objects cannot be",
                     "registration failed")


def _galileo(*args: str) -> float:
    """Run `python -m galileo ARGS` in a new process; its wall time (GalileoError if it fails)."""
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "galileo", *args], cwd=ROOT,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    if done.returncode != 0:
        raise GalileoError(f"galileo {' '.join(args)} failed (exit {done.returncode})")
    return time.perf_counter() - t0


def subset(dataset: Path, n: int | None) -> Path:
    """`dataset`, or a folder of links to its first n videos."""
    if n is None:
        return dataset
    index = read_json(dataset / "index.json", "dataset index")
    folder = dataset.with_name(dataset.name + f"-first-{n}")
    folder.mkdir(parents=True, exist_ok=True)
    for v in index["videos"][:n]:
        link = folder / v["name"]
        if not link.exists():
            link.symlink_to((dataset / v["name"]).resolve(), target_is_directory=True)
    write_json(folder / "index.json", {**index, "videos": index["videos"][:n]})
    return folder


def figures(scenario: str, run: Path) -> dict:
    report = read_json(run / "report.json", "experiment report")
    s = report["summary"]
    records = [read_json(p, "record") for p in sorted((run / "records").glob("*.json"))]
    noted = [r for r in records if any(w in n for n in r.get("track_notes", []) for w in CAMERA_NOTE_WORDS)]
    out = {"videos": len(records), "camera_noted": len(noted)}
    if scenario == "ramp":
        out.update({"k1_error_map": s["k1_median_abs_error"], "k1_error": s["k1_median_abs_error_posterior_median"],
                    "moving_read_as_still": s.get("moving_read_as_still"),
                    "still_read_as_moving": s.get("still_read_as_moving"),
                    "moving": sum(bool(r.get("moves")) for r in records),
                    "still": sum(not r.get("moves") for r in records),
                    "ratio_spearman": s.get("mass_ratio_spearman"), "k1_coverage": s["k1_coverage_90"]})
    else:
        out.update({"pearson": (s["mass_correlation"].get("all_predicted") or {}).get("pearson_r"),
                    "volume_error": s["volume"].get("bottom_up_median_error"),
                    "mass_coverage": (s.get("coverage_90") or {}).get("mass_kg", {}).get("coverage")})
    return out


def _f(x, fmt="{:.3g}") -> str:
    return "–" if x is None else fmt.format(x)


def markdown(scenario: str, rows: dict[str, dict]) -> str:
    base = next(iter(rows.values()))

    def ratio(row, key):
        return f" ({row[key] / base[key]:.2f}×)" if row.get(key) is not None and base.get(key) else ""

    if scenario == "ramp":
        head = ("| camera | k1 median \\|error\\| (posterior median; MAP) | moving read as still | still read as moving "
                "| mass ratio Spearman | k1 90% coverage | camera noted | experiment s |\n|---|---|---|---|---|---|---|---|")
        lines = [f"| {name} | {_f(r['k1_error'], '{:.4f}')}{ratio(r, 'k1_error')}; {_f(r['k1_error_map'], '{:.4f}')} "
                 f"| {r['moving_read_as_still']}/{r['moving']} | {r['still_read_as_moving']}/{r['still']} "
                 f"| {_f(r['ratio_spearman'], '{:.2f}')}{ratio(r, 'ratio_spearman')} "
                 f"| {_f(r['k1_coverage'], '{:.0%}')} | {r['camera_noted']}/{r['videos']} | {r['wall_s']:.0f} |"
                 for name, r in rows.items()]
    else:
        head = ("| camera | mass Pearson | bottom-up volume median \\|error\\| | mass 90% coverage | camera noted "
                "| experiment s |\n|---|---|---|---|---|---|")
        lines = [f"| {name} | {_f(r['pearson'], '{:.2f}')} | {_f(r['volume_error'], '{:.0%}')} "
                 f"| {_f(r['mass_coverage'], '{:.0%}')} | {r['camera_noted']}/{r['videos']} | {r['wall_s']:.0f} |"
                 for name, r in rows.items()]
    return "\n".join([head, *lines])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="ramp", choices=("ramp", "splash"))
    ap.add_argument("--preset", default="small")
    ap.add_argument("--cameras", nargs="+", default=["clean", "phone", "handheld"])
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--max-videos", type=int, default=None)
    ap.add_argument("--chains", type=int, default=None)
    ap.add_argument("--sweeps", type=int, default=None)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true", help="print the figures as JSON too")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    rows = {}
    for cam in args.cameras:
        tag = f"{args.scenario}-{args.preset}-{cam.replace(':', '_')}"
        data = args.out / tag
        if not (data / "index.json").exists():
            _galileo("dataset", "--scenario", args.scenario, "--preset", args.preset, "--camera", cam,
                     "--out", str(data), "--seed", str(args.seed), "--quiet")
        data = subset(data, args.max_videos)
        run = args.out / (f"run-{tag}" + ("" if args.max_videos is None else f"-first-{args.max_videos}"))
        extra = [x for k, v in (("--chains", args.chains), ("--sweeps", args.sweeps), ("--workers", args.workers))
                 if v is not None for x in (k, str(v))]
        wall = _galileo("experiment", str(data), "--out", str(run), "--quiet", "--seed", str(args.seed), *extra)
        rows[cam] = {**figures(args.scenario, run), "wall_s": wall}
        print(f"{cam}: {json.dumps(rows[cam])}", flush=True)
    print(markdown(args.scenario, rows))
    if args.json:
        print(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(run_reporting_errors("bench_camera", main))
