"""The splash on videos it was not built on (issue 28): `galileo experiment` end to end over a
rendered splash dataset, and the issue's table of figures from its records and summary.

Usage (from the repository root):
    python -m galileo dataset --scenario splash --preset looks-small --out /tmp/looks_small
    python bench/bench_splash_generalise.py /tmp/looks_small --out /tmp/looks_small_bench
                                            [--max-videos N] [--chains C --sweeps S] [--workers W]
                                            [--seed S] [--json]

It runs, as a user would, in a new process, timed from start to exit,

    galileo experiment DATASET --out OUT/run --quiet [--chains C --sweeps S --workers W --seed S]

(every video tracked and inferred; the records, report.json and report.md written), then
prints a markdown table ready for BENCHMARKS.md with the issue's targets beside the figures.
The chains and sweeps default to the splash's protocol (50 x 75); `--chains 16 --sweeps 40`
is a smoke run. `--max-videos N` runs the first N videos of the dataset's index (a dataset
folder of links to them under OUT). A rerun with the same --out resumes the experiment (its
records are kept), so the timing is then that of the rest only: give a new --out to time one.

Figures (over the videos with a prediction unless said; the predicted mass is the
experiment's point estimate, the posterior median of density x volume; see
galileo/scenarios/splash/experiments.py):
* mass Pearson / Spearman of predicted against true mass (and over the videos whose chains agree);
* mass median |relative error| (with the MAP's mass; and of a constant guess, the median true
  mass), share of videos within a factor of 2;
* which is heavier, easy / medium / hard (the experiment's pairs, unanswered counted wrong);
* bottom-up volume median |error| and its bias (the median ratio - 1), the posterior volume's;
* shape kind right (bottom-up; against the majority class's count);
* density median |relative error| and bias (posterior median density against the truth);
  floats or sinks right (posterior median density below 1 g/cm^3 or not);
* 90% interval coverage of mass and density (with Clopper-Pearson 95% intervals);
* MAPs at a prior edge, per latent and any;
* converged (`galileo infer`'s verdict: R-hat and ESS), chains agree (the experiment's IQR
  rule; the correlation's "chains agree only" is over those), failed videos;
* seconds per video: tracking and inference from the records, and the command's wall time
  over the videos (on this machine's workers).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from galileo.errors import GalileoError, run_reporting_errors  # noqa: E402
from galileo.jsonio import read_json, write_json  # noqa: E402

# the targets (issue 28, "Targets")
TARGETS = {"pearson": "≥ 0.9", "median_error": "≤ 25%", "volume_error": "≤ 15%", "coverage": "85–95%",
           "hard": "≥ 0.85", "edge": "< 10% of MAPs"}
LATENT_ORDER = ("area_cm2", "density_g_cm3", "drag_water", "release_s", "push_mps", "log_volume_factor")
EDGE_LABELS = ("area", "density", "drag", "release", "push", "volume")


def subset(dataset: Path, n: int, out: Path) -> Path:
    """A dataset folder under `out` of links to the first `n` videos of `dataset`'s index."""
    index = read_json(dataset / "index.json", "dataset index")
    videos = index.get("videos") if isinstance(index, dict) else None
    if not isinstance(videos, list) or not videos:
        raise GalileoError(f"{dataset / 'index.json'}: expected an index with a list of videos")
    folder = out / f"dataset-first-{n}"
    folder.mkdir(parents=True, exist_ok=True)
    for v in videos[:n]:
        link = folder / v["name"]
        if not link.exists():
            link.symlink_to((dataset / v["name"]).resolve(), target_is_directory=True)
    write_json(folder / "index.json", {**index, "videos": videos[:n]})
    return folder


def run_experiment(args, dataset: Path, run_dir: Path) -> float:
    """`galileo experiment` in a new process (its output to OUT/experiment.log); its wall seconds."""
    cmd = [sys.executable, "-m", "galileo", "experiment", str(dataset), "--out", str(run_dir), "--quiet"]
    for flag, value in (("--chains", args.chains), ("--sweeps", args.sweeps), ("--workers", args.workers),
                        ("--seed", args.seed)):
        if value is not None:
            cmd += [flag, str(value)]
    log = run_dir.parent / "experiment.log"
    print("running:", " ".join(cmd), f"(output: {log})", file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    with open(log, "w") as f:
        done = subprocess.run(cmd, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)}, stdout=f,
                              stderr=subprocess.STDOUT)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        tail = log.read_text().strip().splitlines()[-1:] or [""]
        raise GalileoError(f"galileo experiment exited with {done.returncode}: {tail[0]} (see {log})")
    return wall


def _median(xs) -> float | None:
    return float(np.median(xs)) if len(xs) else None


def figures(records: list[dict], summary: dict, wall_s: float | None) -> dict:
    """The issue's figures from the experiment's records and summary (see the module)."""
    pred = [r for r in records if "mass_kg" in r]
    true_m = np.array([r["truth"]["mass_kg"] for r in pred], float)
    mass = np.array([r["mass_kg"] for r in pred], float)
    map_mass = np.array([r["map_mass_kg"] for r in pred], float)
    all_true = np.array([r["truth"]["mass_kg"] for r in records if "truth" in r], float)
    constant = float(np.median(all_true)) if len(all_true) else math.nan
    dens_true = np.array([r["truth"]["density_g_cm3"] for r in pred], float)
    dens = np.array([r["posterior"]["density_g_cm3"]["q50"] for r in pred], float)
    kinds = [r["truth"]["kind"] for r in records if "truth" in r]
    majority = max((kinds.count(k) for k in set(kinds)), default=0)
    edges = summary.get("map_at_prior_edge", {})
    secs = [r["timing"]["track_s"] + r["timing"]["infer_s"] for r in pred if "timing" in r]
    vol = summary.get("volume", {})
    bias_log = vol.get("bottom_up_median_log_ratio")
    mc = summary.get("mass_correlation", {})
    return {
        "videos": len(records), "predicted": len(pred), "converged": summary.get("converged"),
        "chains_agree": summary.get("chains_agree"),
        "failed": summary.get("failed", []),
        "pearson": (mc.get("all_predicted") or {}).get("pearson_r"),
        "spearman": (mc.get("all_predicted") or {}).get("spearman_rho"),
        "pearson_agree": (mc.get("videos") or {}).get("pearson_r"),
        "median_error": _median(np.abs(mass / true_m - 1)),
        "median_error_map": _median(np.abs(map_mass / true_m - 1)),
        "median_error_constant": _median(np.abs(constant / all_true - 1)) if len(all_true) else None,
        "within_factor_2": float(np.mean(np.abs(np.log(mass / true_m)) <= math.log(2))) if len(pred) else None,
        "which_is_heavier": {b: {k: d.get(k) for k in ("accuracy", "pairs", "distinct_pairs", "unanswered",
                                                      "median_true_ratio")}
                             for b, d in summary.get("which_is_heavier", {}).items()},
        "volume_error": vol.get("bottom_up_median_error"),
        "volume_bias": math.exp(bias_log) - 1 if bias_log is not None else None,
        "posterior_volume_error": vol.get("posterior_median_error"),
        "kind_right": summary.get("kind_right"), "kind_n": summary.get("kind_n"), "kind_majority": majority,
        "kind_confusion": summary.get("kind_confusion"),
        "density_error": _median(np.abs(dens / dens_true - 1)),
        "density_bias": math.exp(_median(np.log(dens / dens_true))) - 1 if len(pred) else None,
        "floats_or_sinks_right": int(np.sum((dens < 1.0) == (dens_true < 1.0))),
        "coverage_90": summary.get("coverage_90", {}),
        "map_at_prior_edge": {k: edges.get(k, 0) for k in LATENT_ORDER},
        "map_at_any_prior_edge": summary.get("map_at_any_prior_edge"),
        "seconds_per_video": _median(secs),
        "wall_s_per_video": wall_s / len(records) if wall_s and records else None,
    }


def _pct(x, signed=False) -> str:
    if x is None:
        return "–"
    return f"{x * 100:+.0f}%" if signed else f"{x * 100:.0f}%"


def _num(x, digits=2) -> str:
    return "–" if x is None else f"{x:.{digits}f}"


def markdown(f: dict, title: str) -> str:
    n = f["predicted"]
    cov = f["coverage_90"]

    def coverage(name):
        c = cov.get(name) or {}
        if not c.get("n"):
            return "–"
        lo, hi = c["ci95"]
        return f"{c['covered']}/{c['n']} ({c['coverage'] * 100:.0f}%, 95% CI {lo * 100:.0f}–{hi * 100:.0f}%)"

    wh = f["which_is_heavier"]
    heavier = ", ".join(
        f"{wh[b]['accuracy'] * wh[b]['pairs']:.0f}/{wh[b]['pairs']}" if wh.get(b, {}).get("accuracy") is not None
        else "–" for b in ("easy", "medium", "hard"))
    distinct = ", ".join(str(wh.get(b, {}).get("distinct_pairs", "–")) for b in ("easy", "medium", "hard"))
    edges = " / ".join(f"{f['map_at_prior_edge'][k]}" for k in LATENT_ORDER)
    rows = [
        ("videos with a prediction / converged (R-hat, ESS) / chains agree (IQR rule)",
         f"{n}/{f['videos']} / {f['converged']} / {f['chains_agree']}", "–"),
        ("mass (median) Pearson / Spearman", f"{_num(f['pearson'])} / {_num(f['spearman'])} "
                                             f"(chains agree only: {_num(f['pearson_agree'])})", TARGETS["pearson"]),
        ("mass median \\|relative error\\|", f"{_pct(f['median_error'])} (MAP: {_pct(f['median_error_map'])}; "
                                             f"constant median true mass: {_pct(f['median_error_constant'])})",
         TARGETS["median_error"]),
        ("within a factor of 2", _pct(f["within_factor_2"]), "–"),
        ("which is heavier: easy / medium / hard", f"{heavier} (distinct pairs {distinct})", f"hard {TARGETS['hard']}"),
        ("bottom-up volume median \\|error\\| (bias)", f"{_pct(f['volume_error'])} "
                                                      f"({_pct(f['volume_bias'], signed=True)})", TARGETS["volume_error"]),
        ("posterior volume median \\|error\\|", _pct(f["posterior_volume_error"]), "–"),
        ("shape kind right (majority class alone)", f"{f['kind_right']}/{f['kind_n']} ({f['kind_majority']})", "–"),
        ("density median \\|relative error\\| (bias)", f"{_pct(f['density_error'])} "
                                                       f"({_pct(f['density_bias'], signed=True)})", "–"),
        ("floats or sinks, right", f"{f['floats_or_sinks_right']}/{n}", "–"),
        ("90% interval covers the true mass", coverage("mass_kg"), TARGETS["coverage"]),
        ("90% interval covers the true density", coverage("density_g_cm3"), TARGETS["coverage"]),
        ("MAP at a prior edge: " + " / ".join(EDGE_LABELS) + " (any)",
         f"{edges} ({f['map_at_any_prior_edge']} of {n})", TARGETS["edge"]),
        ("seconds per video: tracking + inference (median) / command wall ÷ videos",
         f"{_num(f['seconds_per_video'], 0)} / {_num(f['wall_s_per_video'], 0)}", "–"),
    ]
    lines = [f"**{title}**", "", "| figure | value | target |", "|---|---|---|"]
    lines += [f"| {a} | {b} | {c} |" for a, b, c in rows]
    if f["failed"]:
        lines += ["", "Failed: " + "; ".join(f"{x['video']}: {x['error']}" for x in f["failed"])]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", help="a splash dataset folder (galileo dataset --scenario splash ...)")
    ap.add_argument("--out", required=True, help="results folder (the experiment's in OUT/run)")
    ap.add_argument("--max-videos", type=int, help="run the first N videos of the index only")
    ap.add_argument("--chains", type=int, help="chains per video (default: the protocol's 50)")
    ap.add_argument("--sweeps", type=int, help="sweeps per chain (default: the protocol's 75)")
    ap.add_argument("--workers", type=int, help="worker processes (default: all cores)")
    ap.add_argument("--seed", type=int)
    ap.add_argument("--json", action="store_true", help="print the figures as JSON too")
    args = ap.parse_args(argv)
    dataset, out = Path(args.dataset), Path(args.out)
    if not (dataset / "index.json").is_file():
        raise GalileoError(f"{dataset} is not a dataset folder (no index.json; make one with `galileo dataset`)")
    if args.max_videos is not None and args.max_videos < 1:
        raise GalileoError(f"--max-videos must be at least 1, got {args.max_videos}")
    out.mkdir(parents=True, exist_ok=True)
    if args.max_videos is not None:
        dataset = subset(dataset, args.max_videos, out)
    run_dir = out / "run"
    wall = run_experiment(args, dataset, run_dir)
    report = read_json(run_dir / "report.json", "experiment report")
    records = [json.loads(p.read_text()) for p in sorted((run_dir / "records").glob("*.json"))]
    records = [r for r in records if isinstance(r, dict) and "video" in r]
    f = figures(records, report["summary"], wall)
    cfg = report.get("config", {})
    title = (f"splash, {Path(args.dataset).name}: {len(records)} videos, {cfg.get('chains')} chains x "
             f"{cfg.get('sweeps')} sweeps, seed {cfg.get('seed')}, {report.get('run', {}).get('workers')} workers")
    f["title"] = title
    write_json(out / "generalise.json", f)
    text = markdown(f, title)
    (out / "generalise.md").write_text(text + "\n")
    print(text)
    if args.json:
        print(json.dumps(f, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(run_reporting_errors("bench_splash_generalise", main))
