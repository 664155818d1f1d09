"""The paper's experiments at dataset scale (Galileo section 6) on a rendered dataset.

For every video in which something moves: track, infer (the paper protocol by default),
and compare with ground truth:

* friction: |k1_MAP - k1_true| for the ramp object (and, beside it, the error of the
  posterior median, and whether the 90% interval of k1 holds the truth);
* which is heavier (6.2): in collision videos, is m1/m2 on the right side of 1 (scored
  where the true ratio is >= 2 or <= 0.5, as in the easy/moderate cases);
* will it move (6.3): from the fit of an object's 20 degree video, predict whether it
  slides on the 10 degree ramp, against the 10 degree video's ground truth.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ...errors import GalileoError
from ...runner import RunConfig, infer
from ...jsonio import write_json
from ...datatypes import Trajectory
from .predict import slides
from .scene import Scene
from .tracking import track

MOVED_M = 0.005


def truth_moves(traj: Trajectory) -> bool:
    """Whether the ramp object of a ground-truth trajectory moved."""
    return bool(np.linalg.norm(traj.position_m[0, -1] - traj.position_m[0, 0]) > MOVED_M)


def run_video(folder: Path, config: RunConfig, executor=None) -> dict:
    scene = Scene.load(folder / "scene.json")
    truth = json.loads((folder / "truth.json").read_text())
    lat = truth["latents"]
    traj = Trajectory.from_json(truth["trajectory"])
    rec = {"video": folder.name, "angle_deg": lat["angle_deg"], "material": lat["material"],
           "object": f"{lat['material']}|{lat['shape1']['type']}|{lat['m1_kg']:.6f}",
           "truth": {k: lat[k] for k in ("m1_kg", "k1", "m2_kg", "k2") if k in lat},
           "moves": truth_moves(traj)}
    if not rec["moves"]:
        return rec  # nothing to track (the tracker refuses a still video)
    tracks = track(folder / "video.mp4", scene, progress=False)
    res = infer(scene, tracks, config, executor=executor, progress=False)
    post = res.posterior()
    derived = res.derived_posterior()
    rec.update({"map": res.map, "map_loglik": res.map_loglik, "mass_ratio": res.mass_ratio(),
                "posterior": {k: {q: v[q] for q in ("q05", "q50", "q95")} for k, v in post.items()},
                "posterior_log_mass_ratio": ({q: derived["log_mass_ratio"][q] for q in ("q05", "q50", "q95")}
                                             if "log_mass_ratio" in derived else None),
                "converged": res.convergence()["converged"], "seconds": res.timing_s["wall"],
                "shape_found": tracks.objects[0].shape.type, "offset_found": tracks.objects[0].offset_units})
    if res.scene.target is not None:
        # did the objects touch? (otherwise the video says nothing about the masses)
        rec["collision"] = bool(np.ptp(traj.position_m[1, :, 0]) > MOVED_M)
    return rec


def will_it_move(records: list[dict], folder: Path) -> list[dict]:
    """Pair each object's 20 degree fit with its 10 degree video's truth."""
    by_obj: dict[str, dict] = {}
    for r in records:
        by_obj.setdefault(r["object"], {})[r["angle_deg"]] = r
    out = []
    for obj, pair in by_obj.items():
        if 20.0 not in pair or 10.0 not in pair or "map" not in pair[20.0]:
            continue
        r20 = pair[20.0]
        scene10 = Scene.load(folder / pair[10.0]["video"] / "scene.json")
        # the fitted object (the shape its 20 degree scene file gives) on the 10 degree ramp, alone
        scene20 = Scene.load(folder / r20["video"] / "scene.json")
        ramp_obj = dataclasses.replace(scene10.ramp_object, shape=scene20.ramp_object.shape)
        alone = dataclasses.replace(scene10, objects=(ramp_obj,))
        predicted = slides(alone, r20["map"], threshold_m=MOVED_M)
        out.append({"object": obj, "predicted_moves": predicted, "true_moves": pair[10.0]["moves"],
                    "k1_map": r20["map"]["k1"], "k1_true": r20["truth"]["k1"]})
    return out


def summarise(records: list[dict], wim: list[dict]) -> dict:
    fitted = [r for r in records if "map" in r]
    k_err = [abs(r["map"]["k1"] - r["truth"]["k1"]) for r in fitted]
    with_post = [r for r in fitted if "posterior" in r]
    k_err_med = [abs(r["posterior"]["k1"]["q50"] - r["truth"]["k1"]) for r in with_post]
    k_cover = [r["posterior"]["k1"]["q05"] <= r["truth"]["k1"] <= r["posterior"]["k1"]["q95"] for r in with_post]
    heavy = [r for r in fitted if r.get("collision") and r.get("mass_ratio")
             and (r["truth"]["m1_kg"] / r["truth"]["m2_kg"] >= 2 or r["truth"]["m1_kg"] / r["truth"]["m2_kg"] <= 0.5)]
    heavy_ok = [(r["mass_ratio"] > 1) == (r["truth"]["m1_kg"] > r["truth"]["m2_kg"]) for r in heavy]
    return {"videos": len(records), "fitted": len(fitted),
            "k1_median_abs_error": float(np.median(k_err)) if k_err else None,
            "k1_errors": k_err,
            "k1_median_abs_error_posterior_median": float(np.median(k_err_med)) if k_err_med else None,
            "k1_coverage_90": float(np.mean(k_cover)) if k_cover else None,
            "converged": int(sum(bool(r.get("converged")) for r in fitted)),
            "which_is_heavier": {"scored": len(heavy), "right": int(sum(heavy_ok)),
                                 "accuracy": float(np.mean(heavy_ok)) if heavy_ok else None},
            "will_it_move": {"scored": len(wim), "right": int(sum(w["predicted_moves"] == w["true_moves"] for w in wim)),
                             "accuracy": float(np.mean([w["predicted_moves"] == w["true_moves"] for w in wim]))
                             if wim else None},
            "seconds_per_video": float(np.mean([r["seconds"] for r in fitted])) if fitted else None}


def run_experiments(folder: str | Path, config: RunConfig | None = None, progress: bool = True,
                    out: str | Path | None = None, executor=None) -> dict:
    """Every video of a dataset folder through tracking and the chain runner (on `executor`,
    default: a local pool per video), then the three experiments; the report as a dict."""
    folder = Path(folder)
    index = folder / "index.json"
    if not index.exists():
        raise GalileoError(f"{folder} is not a dataset folder (no index.json; make one with `galileo dataset`)")
    names = [v["name"] for v in json.loads(index.read_text())["videos"]]
    cfg = config or RunConfig()
    records = []
    for name in tqdm(names, desc="videos", unit="video", disable=not progress):
        records.append(run_video(folder / name, cfg, executor))
        if out is not None:  # keep what is done so far
            write_json(out, {"partial": True, "records": records})
    wim = will_it_move(records, folder)
    report = {"summary": summarise(records, wim), "records": records, "will_it_move": wim}
    if out is not None:
        write_json(out, report)
    return report
