"""The spring's experiments: which references a video gets, and the summary's numbers from records
whose answers are known; and, on the real Physics 101 clips when they are here, the same block's
mass from its other trial (slow)."""
from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from galileo.scenarios.spring.experiments import band_of, references, summarise
from galileo.scenarios.spring.scene import default_scene

ROOT = Path(__file__).resolve().parents[1]


def _dataset(folder: Path, videos: list[tuple[str, str, float]]) -> None:
    for name, spring, mass in videos:
        (folder / name).mkdir(parents=True)
        dataclasses.replace(default_scene(), object=name.replace("_", ""), spring=spring, mass_kg=mass).save(
            folder / name / "scene.json")


def test_references_are_the_nearest_to_each_bands_ratio_on_the_same_spring(tmp_path):
    _dataset(tmp_path, [("a", "tight", 0.100), ("b", "tight", 0.140), ("c", "tight", 0.520), ("d", "tight", 0.005),
                        ("e", "loose", 0.150), ("f", "tight", 0.100 * 21)])
    got = [p.name for p in references(tmp_path / "a")]
    # ratios to a: b 1.4 (nearest 1.5), c 5.2 (nearest 5), d 1/20 and f 21 (20: d is 20 exactly); e: another spring
    assert got == ["b", "c", "d"]


def test_band_edges_and_either_way_up():
    assert band_of(1.5) == band_of(1 / 1.5) == "hard"
    assert band_of(5.0) == band_of(0.2) == "medium"
    assert band_of(20.0) == "easy" and band_of(1.1) is None and band_of(50.0) is None


def _pair(true_kg, ref_kg, q05, q50, q95, spring="tight", k=(9.0, 9.1, 9.2), k_true=9.0):
    return {"truth": {"mass_kg": true_kg, "k_Npm": k_true}, "spring": spring, "video": f"v{true_kg}",
            "pairs": [{"status": "fitted", "reference": "r", "reference_mass_kg": ref_kg, "true_ratio": true_kg / ref_kg,
                       "mass_kg": {"q05": q05, "q50": q50, "q95": q95}, "seconds": 10.0,
                       "k_Npm": {"q05": k[0], "q50": k[1], "q95": k[2]}}]}


def test_summary_counts_errors_coverage_and_sides():
    records = [_pair(0.10, 0.15, 0.095, 0.102, 0.105),        # 2% off, covered, right side (lighter)
               _pair(0.20, 0.04, 0.205, 0.21, 0.22),          # 5% off, not covered, right side (heavier)
               _pair(0.06, 0.05, 0.040, 0.049, 0.061, k=(8.0, 8.5, 8.9))]   # 18% off, covered, wrong side
    s = summarise(records)
    assert s["pairs"] == 3
    assert s["mass_from_reference"]["median_relative_error"] == pytest.approx(0.05)
    assert s["mass_from_reference"]["coverage_90"] == pytest.approx(2 / 3)
    assert s["which_is_heavier"]["hard"] == {"pairs": 2, "accuracy": 0.5, "ratio_from": 1.2, "ratio_below": 2.74,
                                             "median_true_ratio": pytest.approx((1.5 + 1.2) / 2)}
    assert s["which_is_heavier"]["medium"]["accuracy"] == 1.0
    assert s["stiffness"]["tight"]["coverage_90"] == pytest.approx(2 / 3)


def _phys101() -> Path | None:
    env = os.environ.get("GALILEO_PHYS101")
    d = Path(env) if env else ROOT.parent / "shared" / "data" / "phys101"
    return d / "spring" if (d / "spring").is_dir() else None


@pytest.mark.slow
@pytest.mark.skipif(_phys101() is None, reason="the Physics 101 clips are not here")
def test_the_real_block_weighs_what_its_other_trial_says(tmp_path):
    """tight-01 given tight-04 (the same 110.3 g block): the posterior median within 5% of 110.3 g."""
    d = _phys101()
    scenes = []
    for clip, (x, y), obj in (("tight-04", (994, 138), "ref"), ("tight-01", (995, 136), "unknown")):
        out = tmp_path / f"{clip}.json"
        pts = f"{x},{y} {x - 3},{y + 310} {x - 40},{y + 440} {x + 40},{y + 440}"
        subprocess.run([sys.executable, "-m", "galileo", "scene", str(d / f"w_block_05-{clip}-Kinect_RGB_1.mp4"),
                        "--scenario", "spring", "--points", pts, "--object", obj, "--spring", "tight", "--out", str(out)],
                       check=True, capture_output=True)
        scenes.append(out)
    res = tmp_path / "r.json"
    subprocess.run([sys.executable, "-m", "galileo", "infer", str(d / "w_block_05-tight-04-Kinect_RGB_1.mp4"),
                    str(d / "w_block_05-tight-01-Kinect_RGB_1.mp4"), "--scene", *map(str, scenes), "--fix",
                    "m_ref_kg=0.1103", "--chains", "8", "--sweeps", "40", "--out", str(res), "--quiet"],
                   check=True, capture_output=True)
    q = json.loads(res.read_text())["posterior"]["m_unknown_kg@2"]
    assert q["q50"] == pytest.approx(0.1103, rel=0.05)
