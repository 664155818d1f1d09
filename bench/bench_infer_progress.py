"""What `galileo infer`'s per-sweep progress costs: wall time with the bar against without it.

Usage (from the repository root):
    python bench/bench_infer_progress.py [--shape 16x75 --shape 16x600 --shape 1x2000] [--workers N]
                                         [--repeat 3] [--json]

With a bar, `galileo.runner.infer` runs each chain's sweeps in pieces of about
PROGRESS_PIECE_S (the first piece one sweep), so that the bar moves as the pieces end rather
than when a whole chain does; without one (`--quiet`, `galileo experiment`) each chain
is one task as before. The chains are the same bit for bit either way (checked here too). The
frozen demo scene and tracks (tests/data) are used, `--moves default`; the two runs alternate
--repeat times per shape (CHAINSxSWEEPS) and the medians are compared. Reported per shape:
wall time without and with the bar, the overhead, how many times the bar moved (its updates,
one per chain per piece) and the longest time between two of them. Target: overhead at most
2 % (on a quiet machine: a loaded one delays every piece's hand-over), and the bar moving at
least every 2 x PROGRESS_PIECE_S after its first piece.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from galileo import registry, runner  # noqa: E402
from galileo.datatypes import Tracks  # noqa: E402
from galileo.runner import RunConfig, infer  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / "tests" / "data"


class TimedBar(runner.tqdm):
    """The runner's bar, noting when it moves."""
    moves: list = []

    def update(self, n=1):
        TimedBar.moves.append(time.perf_counter())
        return super().update(n)


def run(scene, tracks, cfg: RunConfig, bar: bool):
    TimedBar.moves = []
    t0 = time.perf_counter()
    with contextlib.redirect_stderr(io.StringIO()):
        res = infer(scene, tracks, cfg, progress=bar)
    wall = time.perf_counter() - t0
    gaps = np.diff([t0] + TimedBar.moves) if TimedBar.moves else np.array([wall])
    return res, wall, len(TimedBar.moves), float(gaps[1:].max()) if len(gaps) > 1 else float(gaps.max())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shape", action="append", help="CHAINSxSWEEPS (default: 16x75, 16x600, 1x2000)")
    ap.add_argument("--workers", type=int, default=None, help="worker processes (default: all cores)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    shapes = [tuple(int(x) for x in s.split("x")) for s in (args.shape or ["16x75", "16x600", "1x2000"])]
    scene = registry.load_scene(DATA / "scene.json")
    tracks = Tracks.load(DATA / "tracks.json")
    runner.tqdm = TimedBar
    rows = []
    for chains, sweeps in shapes:
        cfg = RunConfig(chains=chains, sweeps=sweeps, seed=0, workers=args.workers)
        plain_s, bar_s, same = [], [], True
        for _ in range(args.repeat):
            plain, wall, _, _ = run(scene, tracks, cfg, bar=False)
            plain_s.append(wall)
            shown, wall, moves, gap = run(scene, tracks, cfg, bar=True)
            bar_s.append(wall)
            same &= bool(np.array_equal(plain.samples, shown.samples) and np.array_equal(plain.logliks, shown.logliks))
        p, b = statistics.median(plain_s), statistics.median(bar_s)
        r = {"chains": chains, "sweeps": sweeps, "without_bar_s": p, "with_bar_s": b,
             "overhead_pct": 100 * (b / p - 1), "runs_without": plain_s, "runs_with": bar_s,
             "bar_moves": moves, "longest_gap_s": gap, "same_chains": same}
        rows.append(r)
        if not args.json:
            print(f"{r['chains']} x {r['sweeps']}: without the bar {r['without_bar_s']:.2f} s "
                  f"(runs {min(r['runs_without']):.2f}-{max(r['runs_without']):.2f}), with it {r['with_bar_s']:.2f} s "
                  f"(runs {min(r['runs_with']):.2f}-{max(r['runs_with']):.2f}): {r['overhead_pct']:+.1f} %; "
                  f"the bar moved {r['bar_moves']} times, at most {r['longest_gap_s']:.2f} s apart; "
                  f"same chains: {r['same_chains']}", flush=True)
    if args.json:
        print(json.dumps({"workers": args.workers, "progress_piece_s": runner.PROGRESS_PIECE_S, "shapes": rows}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
