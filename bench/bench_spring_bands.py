"""Mass from a reference across the ratio bands 1.5, 5 and 20: seven videos of the spring's `full`
plan on the tight spring, masses spread 20-500 g (the `small` preset's 27-67 g give the 1.5 band
only), rendered into one folder with its index, then `galileo experiment` on them.

    python bench/bench_spring_bands.py [--out /tmp/bench_spring_bands] [--workers 2]
"""
from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

MASSES_KG = (0.022, 0.035, 0.06, 0.11, 0.2, 0.33, 0.5)   # each the nearest planned object's


def main() -> int:
    from galileo.jsonio import write_json
    from galileo.scenarios.spring.dataset import DATASET

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="/tmp/bench_spring_bands")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    videos = Path(args.out) / "videos"
    videos.mkdir(parents=True, exist_ok=True)
    tight = [v for v in DATASET.plan("full", 0) if v.spring.name == "tight"]
    chosen: list = []
    for m in MASSES_KG:
        chosen.append(min((v for v in tight if v not in chosen), key=lambda v: abs(math.log(v.obj.mass_kg / m))))
    entries = [DATASET.render_one(v, str(videos)) for v in chosen]
    write_json(videos / "index.json", {"scenario": "spring", "preset": "full (7 on the tight spring)", "seed": 0,
                                       "videos": entries})
    results = Path(args.out) / "results"
    subprocess.run([sys.executable, "-m", "galileo", "experiment", str(videos), "--out", str(results), "--workers",
                    str(args.workers), "--quiet"], check=True)
    summary = json.loads((results / "report.json").read_text())["summary"]
    print(json.dumps({k: summary[k] for k in ("pairs", "mass_from_reference", "which_is_heavier", "stiffness")},
                     indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
