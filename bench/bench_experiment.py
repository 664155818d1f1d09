"""The paper's experiments at dataset scale on Dask: `galileo experiment` end to end (issue 13).

Usage (from the repository root):
    python bench/bench_experiment.py --dataset DIR [--workers 2 1] [--granularity videos]
                                     [--chains C --sweeps S] [--moves default] --out DIR

For each worker count (and granularity) it runs, as a user would, the command

    galileo experiment DATASET --out OUT/run-<granularity>-<workers>w --workers N --quiet [...]

in a new process, timed from process start to exit (cluster start, every video tracked and
inferred, the report and its figures written). While it runs, the machine's CPU busy time is
read from /proc/stat, so "every core busy" is measured over the whole command. From the
run's records (each carries its worker's resident and peak memory after its video), per
worker: memory after its first fitted video and after its last, the peak, and the growth
per video (a least squares slope over its videos in completion order: flat means no leak).

Reported: wall seconds, videos per minute, CPU utilisation of the cores given (the CPU-seconds
of the whole machine over the run / (wall x workers)), scaling efficiency against the
smallest worker count (T_small x n_small / (T_n x n)), memory per worker. Written to
OUT/experiment_bench.json and OUT/experiment_bench.md.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from galileo.errors import GalileoError, run_reporting_errors  # noqa: E402
from galileo.jsonio import write_json  # noqa: E402


def cpu_busy_s() -> float:
    """CPU-seconds spent busy by the whole machine since boot (all cores, /proc/stat)."""
    fields = Path("/proc/stat").read_text().splitlines()[0].split()[1:]
    user, nice, system, idle, iowait, irq, softirq, steal = (int(x) for x in fields[:8])
    return (user + nice + system + irq + softirq + steal) / os.sysconf("SC_CLK_TCK")


def worker_memory(records: list[dict]) -> list[dict]:
    """Per worker process, from its first fitted video on (before it, the worker has not yet
    loaded tracking and inference): memory after that video and after its last, the peak,
    and the growth per video (least squares slope in completion order)."""
    import numpy as np

    by: dict[tuple, list[dict]] = {}
    for r in records:
        w = r.get("worker")
        if isinstance(w, dict) and "rss_mb" in w:
            by.setdefault((w.get("address"), w.get("pid")), []).append({**w, "fitted": r.get("status") == "fitted"})
    out = []
    for (address, pid), ws in sorted(by.items(), key=lambda kv: str(kv[0])):
        ws.sort(key=lambda w: w.get("finished_unix_s", 0.0))
        first = next((i for i, w in enumerate(ws) if w["fitted"]), 0)
        rss = np.array([w["rss_mb"] for w in ws[first:]], float)
        slope = float(np.polyfit(np.arange(len(rss)), rss, 1)[0]) if len(rss) >= 3 else None
        out.append({"worker": address, "pid": pid, "videos": len(ws), "rss_first_mb": float(rss[0]),
                    "rss_last_mb": float(rss[-1]), "peak_rss_mb": float(max(w["peak_rss_mb"] for w in ws)),
                    "growth_mb_per_video": slope})
    return out


def run_once(args, workers: int, granularity: str, out: Path) -> dict:
    run_dir = out / f"run-{granularity}-{workers}w"
    if run_dir.exists():
        raise GalileoError(f"{run_dir} exists: give a new --out (a run left there would be resumed, not timed)")
    cmd = [sys.executable, "-m", "galileo", "experiment", str(args.dataset), "--out", str(run_dir),
           "--workers", str(workers), "--granularity", granularity, "--moves", args.moves, "--quiet"]
    if args.chains:
        cmd += ["--chains", str(args.chains)]
    if args.sweeps:
        cmd += ["--sweeps", str(args.sweeps)]
    print("$", " ".join(cmd), flush=True)
    c0, t0 = cpu_busy_s(), time.perf_counter()
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    busy = cpu_busy_s() - c0
    if proc.returncode != 0:
        raise GalileoError(f"galileo experiment failed ({proc.returncode}): {proc.stderr.strip().splitlines()[-1:]}")
    report = json.loads((run_dir / "report.json").read_text())
    records = [json.loads(p.read_text()) for p in (run_dir / "records").glob("*.json")]
    s = report["summary"]
    return {"workers": workers, "granularity": granularity, "wall_s": wall, "videos": len(records),
            "videos_per_min": 60 * len(records) / wall, "cpu_utilisation": busy / (wall * workers),
            "engine_wall_s": report["run"]["wall_s"], "failed": len(report["run"]["failed_videos"]),
            "memory": worker_memory(records),
            "summary": {k: s.get(k) for k in ("fitted", "k1_median_abs_error", "k1_coverage_90", "converged",
                                              "which_is_heavier", "will_it_move", "outcome_median_abs_error_m")}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dataset", required=True, help="folder from `galileo dataset`")
    ap.add_argument("--workers", type=int, nargs="+", default=[2])
    ap.add_argument("--granularity", nargs="+", default=["videos"], choices=["videos", "chains"])
    ap.add_argument("--chains", type=int)
    ap.add_argument("--sweeps", type=int)
    ap.add_argument("--moves", default="default", choices=["default", "paper"])
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    runs = [run_once(args, w, g, out) for g in args.granularity for w in sorted(args.workers)]
    for g in args.granularity:
        mine = [r for r in runs if r["granularity"] == g]
        base = mine[0]
        for r in mine:
            r["efficiency"] = base["wall_s"] * base["workers"] / (r["wall_s"] * r["workers"])
    doc = {"dataset": str(args.dataset), "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                                                     "processor": platform.processor() or platform.machine()},
           "chains": args.chains, "sweeps": args.sweeps, "moves": args.moves, "runs": runs}
    write_json(out / "experiment_bench.json", doc)
    lines = ["| granularity | workers | videos | wall (s) | videos/min | CPU busy | efficiency | peak RSS/worker (MB) "
             "| RSS growth (MB/video) |", "|---|---|---|---|---|---|---|---|---|"]
    for r in runs:
        peak = max((m["peak_rss_mb"] for m in r["memory"]), default=float("nan"))
        growth = [m["growth_mb_per_video"] for m in r["memory"] if m["growth_mb_per_video"] is not None]
        lines.append(f"| {r['granularity']} | {r['workers']} | {r['videos']} | {r['wall_s']:.0f} | "
                     f"{r['videos_per_min']:.1f} | {100 * r['cpu_utilisation']:.0f}% | {r['efficiency']:.2f} | "
                     f"{peak:.0f} | {', '.join(f'{g:+.2f}' for g in growth) or '-'} |")
    text = "\n".join(lines) + "\n"
    (out / "experiment_bench.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(run_reporting_errors("bench_experiment", main))
