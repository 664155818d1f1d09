"""Fall tracking on the real Physics 101 clips (and on rendered fall videos with --renders).

Usage (from the repository root):
    python bench/bench_fall_track.py [--data DIR] [--json]
    python bench/bench_fall_track.py --renders DATASET   # each DATASET/*/video.mp4 beside a truth.json

Per real clip: `track_pixels` end to end (wall time), the release and rest frames, the frames
seen, and, against bench/fall_labels.json (centroids labelled by eye, {clip: {frame: [u, v]}},
full-resolution pixels; its "note" says how, its "events" the labelled release and rest frames),
the median and max distance from the labels. With --renders DATASET (the folders of a rendered
fall dataset, `galileo dataset --scenario fall`, that hold video.mp4, scene.json and truth.json;
others, still being written, are skipped): per video the median and 90th-percentile distance
from truth.json's per-frame SIL_KEY (what a perfect tracker sees) and CENTER_KEY (the projected
3-D centre) from the true release on, the release frame's error, the share of the frames the
object is drawn free in that are tracked, and a row pooling them; a video the tracker refuses
is a row with its error. Exits 0 with a message where the real clips are absent.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from galileo.errors import GalileoError
from galileo.scenarios.fall.tracking import track_pixels

DEFAULT_DATA = Path(os.environ.get("GALILEO_PHYS101", ROOT.parent / "shared" / "data" / "phys101"))
LABELS = Path(__file__).with_name("fall_labels.json")
SIL_KEY = "silhouette_center_px"   # truth.json: the drawn (blurred) object mask's centroid per frame (px; null: not drawn)
CENTER_KEY = "center_px"           # ... the projected 3-D centre per frame (px)


def _errors(track, truth: dict[int, list[float]], free_from: int = 0) -> np.ndarray:
    """Distances (px) between the tracked and the given centroids over the frames from free_from
    on that both have."""
    fs = [f for f, c in truth.items() if c is not None and free_from <= f < len(track.center_px)
          and np.isfinite(track.center_px[f]).all()]
    return np.array([np.linalg.norm(track.center_px[f] - np.asarray(truth[f], float)) for f in fs])


def _row(name: str, video: Path, truth: dict | None) -> dict:
    t0 = time.perf_counter()
    tr = track_pixels(video, progress=False)
    row = {"clip": name, "wall_s": round(time.perf_counter() - t0, 2), "frames": len(tr.center_px),
           "seen": int(tr.visible.sum()), "release_frame": tr.release_frame, "rest_frame": tr.rest_frame,
           "notes": tr.notes, "track": tr}
    if truth:
        e = _errors(tr, truth)
        row.update(median_px=round(float(np.median(e)), 2) if len(e) else None,
                   max_px=round(float(e.max()), 2) if len(e) else None, compared=len(e))
    return row


def renders(folder: Path) -> list[dict]:
    """One row per rendered video (a folder holding video.mp4, scene.json and truth.json: a
    dataset still being written has folders without them, skipped): the distances from
    truth.json's SIL_KEY and CENTER_KEY over the frames both it and the tracker have, the
    release frame's error, and the share of the frames the object is drawn free that the
    tracker sees; then a row pooling every frame."""
    rows, pooled = [], {SIL_KEY: [], CENTER_KEY: []}
    for video in sorted(folder.glob("*/video.mp4")):
        if not all(video.with_name(n).exists() for n in ("truth.json", "scene.json")):
            continue
        truth = json.loads(video.with_name("truth.json").read_text())
        try:
            row = _row(video.parent.name, video, None)
        except GalileoError as e:          # a failure is a result here: count it, go on
            rows.append({"clip": video.parent.name, "error": str(e), "notes": []})
            continue
        tr = row.pop("track")
        for key in (SIL_KEY, CENTER_KEY):
            e = _errors(tr, dict(enumerate(truth[key])), free_from=truth["release_frame"])
            pooled[key].append(e)
            row[f"{key}_median_px"] = round(float(np.median(e)), 2) if len(e) else None
            row[f"{key}_p90_px"] = round(float(np.percentile(e, 90)), 2) if len(e) else None
        drawn = np.asarray([v and c is not None for v, c in zip(truth["visible"], truth[SIL_KEY])])
        drawn &= np.arange(len(drawn)) >= truth["release_frame"]
        row["release_error"] = tr.release_frame - truth["release_frame"]
        row["seen_share"] = round(float(tr.visible[drawn].mean()), 3) if drawn.any() else None
        rows.append(row)
    done = [r for r in rows if "error" not in r]
    if done:
        total = {"clip": f"all {len(done)} tracked of {len(rows)}",
                 "wall_s": round(sum(r["wall_s"] for r in done) / len(done), 2), "notes": []}
        for key, es in pooled.items():
            e = np.concatenate(es)
            total[f"{key}_median_px"] = round(float(np.median(e)), 2)
            total[f"{key}_p90_px"] = round(float(np.percentile(e, 90)), 2)
        rel = np.abs([r["release_error"] for r in done])
        total["release_abs_error_median"] = float(np.median(rel))
        total["release_abs_error_max"] = int(rel.max())
        total["seen_share_median"] = float(np.median([r["seen_share"] for r in done if r["seen_share"] is not None]))
        rows.append(total)
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--renders", type=Path, help="a rendered fall dataset: measure against its truth instead")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    if args.renders is not None:
        rows = renders(args.renders)
    else:
        clips = sorted((args.data / "fall").glob("*.mp4"))
        if not clips:
            print(f"no Physics 101 fall clips in {args.data / 'fall'}: nothing to measure (set GALILEO_PHYS101)")
            return 0
        labels = json.loads(LABELS.read_text()) if LABELS.exists() else {}
        rows = []
        for video in clips:
            name = video.stem.replace("-Kinect_RGB_1", "")
            truth = {int(f): c for f, c in labels.get(name, {}).items()}
            row = _row(name, video, truth)
            row.update({f"labelled_{k}": v for k, v in labels.get("events", {}).get(name, {}).items()})
            rows.append(row)
    for r in rows:
        r.pop("track", None)
    if args.json:
        print(json.dumps(rows, indent=1))
    else:
        for r in rows:
            print(" ".join(f"{k}={v}" for k, v in r.items() if k != "notes"))
            for n in r["notes"]:
                print("   note:", n)
    return 0


if __name__ == "__main__":
    from galileo.errors import run_reporting_errors

    sys.exit(run_reporting_errors("bench_fall_track", main))
