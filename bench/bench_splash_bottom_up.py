"""Splash bottom-up measures against ground truth: volume error, kind, the 90% volume interval's
coverage and the detected release, over a rendered preset.

Usage (from the repository root):
    python bench/bench_splash_bottom_up.py [--data FOLDER] [--preset small] [--json]

Without --data it renders the preset into a temporary folder first (`galileo dataset`). Each
video: the true kind and volume (truth.json) against the track's bottom_up; the release
against the scene's release_s (a release before frame 0: the track should say null). A video
whose tracking fails is listed with the reason and counted, not measured.
"""
from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from galileo import registry  # noqa: E402
from galileo.errors import GalileoError  # noqa: E402
from galileo.scenarios.splash.dataset import build  # noqa: E402


def measure(folder: Path) -> dict:
    """The video's row; {"name", "failed": why} where tracking refuses it (counted, not measured)."""
    scene = registry.load_scene(folder / "scene.json")
    try:
        (obj,) = registry.of(scene).track(folder / "video.mp4", scene, progress=False).objects
    except GalileoError as e:
        return {"name": folder.name, "failed": str(e)}
    truth = json.loads((folder / "truth.json").read_text())["latents"]
    bu = obj.bottom_up
    log_err = math.log(bu["volume_cm3"] / truth["volume_cm3"])
    fps = scene.camera.fps
    true_release = getattr(scene, "release_s", None)
    return {"name": folder.name, "kind": truth["kind"], "kind_found": bu["kind"],
            "p_true_kind": bu["kind_probs"][truth["kind"]], "volume_cm3": truth["volume_cm3"],
            "volume_found_cm3": bu["volume_cm3"], "error": math.exp(log_err) - 1, "log_sd": bu["volume_log_sd"],
            "covered": abs(log_err) <= 1.645 * bu["volume_log_sd"], "release_s": true_release,
            "release_found_s": bu["release_s"],
            "release_error_frames": (None if bu["release_s"] is None or true_release is None or true_release < 0
                                     else (bu["release_s"] - true_release) * fps)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", help="a rendered splash dataset folder (default: render --preset)")
    ap.add_argument("--preset", default="small")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(a.data) if a.data else Path(tmp)
        if not a.data:
            build(a.preset, data, seed=0, progress=False)
        rows = [measure(d) for d in sorted(data.iterdir()) if (d / "scene.json").exists()]
    if a.json:
        print(json.dumps(rows, indent=1))
        return 0
    failed = [r for r in rows if "failed" in r]
    rows = [r for r in rows if "failed" not in r]
    for r in failed:
        print(f"{r['name']}: tracking failed: {r['failed']}")
    print(f"{'video':24s} {'kind':5s} {'found':5s} {'p(true)':>7s} {'V true':>7s} {'V found':>7s} {'error':>7s} "
          f"{'log sd':>6s} {'in 90%':>6s} {'release':>8s} {'found':>8s}")
    for r in rows:
        rel = "-" if r["release_s"] is None else f"{r['release_s']:.3f}"
        found = "null" if r["release_found_s"] is None else f"{r['release_found_s']:.3f}"
        print(f"{r['name']:24s} {r['kind']:5s} {r['kind_found']:5s} {r['p_true_kind']:7.2f} {r['volume_cm3']:7.1f} "
              f"{r['volume_found_cm3']:7.1f} {r['error']:+7.1%} {r['log_sd']:6.3f} {str(r['covered']):>6s} "
              f"{rel:>8s} {found:>8s}")
    errs = [r["error"] for r in rows]
    print(f"\nvolume: median |error| {statistics.median(abs(e) for e in errs):.1%}, bias (median error) "
          f"{statistics.median(errs):+.1%}; 90% interval covers the truth in {sum(r['covered'] for r in rows)}"
          f"/{len(rows)}; {len(failed)} video(s) not tracked")
    print(f"kind right {sum(r['kind'] == r['kind_found'] for r in rows)}/{len(rows)}, mean p(true kind) "
          f"{statistics.mean(r['p_true_kind'] for r in rows):.2f}")
    rel = [r["release_error_frames"] for r in rows if r["release_error_frames"] is not None]
    if rel:
        print(f"release (held videos): |error| median {statistics.median(abs(e) for e in rel):.2f} frames, "
              f"max {max(abs(e) for e in rel):.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
