"""The paper's experiments at dataset scale (Galileo section 6) on a rendered ramp dataset.

`run_video` is one video's whole share of the work, run where the data are (a Dask worker,
`galileo.batch`): track, infer (16 x 75 by default), and the two predictions that need the
physics engine, each against ground truth:

* will it move (6.3): on a 20 degree video whose object also has a 10 degree video, the
  20 degree fit (the MAP) is simulated on the 10 degree ramp, alone; the record carries the
  prediction and the 10 degree video's truth;
* outcome (section 6.1, Fig. 5, in metres): on a video with a target, where the target comes
  to rest along the ground's x axis, the MAP simulated to the video's end against the truth.

`summarise` then scores the records: friction (|k1_MAP - k1_true|, the posterior median's
error, 90% coverage), which is heavier (6.2) and will it move (6.3) counted exactly as
report.md counts them (`report.heavier`, `report.will_it_move`: the same videos, the same rule,
"right" of "scored" with the 95% interval report.md prints), the mass ratio's Spearman
correlation with the truth (collision videos, MAP ratio: report.md's "MAP" row), convergence,
and what tracking made of motion: every video is tracked (a still one too, then skipped), and
moving objects read as still (the tracker's `still_note`) and still ones read as moving are
counted.
"""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

from ...datatypes import Trajectory
from ...errors import GalileoError
from ...jsonio import read_json
from ...runner import RunConfig, infer
from .predict import slides
from .scene import Scene
from .tracking import still_note, track

MOVED_M = 0.005          # a ground-truth object "moved" when its centre travelled more than this
FIT_ANGLE_DEG, PREDICT_ANGLE_DEG = 20.0, 10.0   # will it move: fit on one, predict the other
LATENTS = ("m1_kg", "k1", "m2_kg", "k2")


def default_config() -> RunConfig:
    from ... import registry

    return RunConfig(**registry.get("ramp").protocol)


def truth_moves(traj: Trajectory) -> bool:
    """Whether the ramp object of a ground-truth trajectory moved."""
    return bool(np.linalg.norm(traj.position_m[0, -1] - traj.position_m[0, 0]) > MOVED_M)


def _truth(folder: Path) -> tuple[dict, Trajectory]:
    d = read_json(folder / "truth.json", "truth file")
    try:
        return d["latents"], Trajectory.from_json(d["trajectory"])
    except (KeyError, TypeError, ValueError) as e:
        raise GalileoError(f"{folder / 'truth.json'}: not a ramp truth file ({type(e).__name__}: {e})") from None


def partner(folder: Path, lat: dict) -> Path | None:
    """The 10 degree video of the object a 20 degree video shows (from the dataset's index)."""
    from ...batch import dataset_index

    try:
        _, entries = dataset_index(folder.parent)
    except GalileoError:
        return None
    me = next((v for v in entries if v["name"] == folder.name), None)
    if me is None or "object" not in me or me.get("angle_deg", lat.get("angle_deg")) != FIT_ANGLE_DEG:
        return None
    other = next((v for v in entries if v is not me and v.get("object") == me["object"]
                  and v.get("angle_deg") == PREDICT_ANGLE_DEG), None)
    return folder.parent / other["name"] if other else None


def run_video(folder: Path, config: RunConfig, executor=None) -> dict:
    """One video's record (see the module). A still video is skipped (`status` "skipped");
    a missing or broken file raises GalileoError (the batch engine records it)."""
    folder = Path(folder)
    scene = Scene.load(folder / "scene.json")
    lat, traj = _truth(folder)
    rec = {"video": folder.name, "scenario": "ramp", "angle_deg": lat["angle_deg"], "material": lat["material"],
           "object": f"{lat['material']}|{lat['shape1']['type']}|{lat['m1_kg']:.6f}",
           "target": lat.get("target") or "none",
           "truth": {k: lat[k] for k in LATENTS if k in lat}, "moves": truth_moves(traj)}
    if scene.target is not None:
        # did the objects touch? (otherwise the video says nothing about the masses)
        rec["collision"] = bool(np.ptp(traj.position_m[1, :, 0]) > MOVED_M)
        if rec["collision"]:   # the one mass quantity a collision identifies: scored like a latent
            rec["truth"]["log_mass_ratio"] = float(np.log(lat["m1_kg"] / lat["m2_kg"]))
    t0 = time.perf_counter()
    tracks = track(folder / "video.mp4", scene, progress=False)
    t1 = time.perf_counter()
    # what the tracker saw: did anything move (a still video's tracks hold every object at rest, with a note),
    # and what it said of the camera
    rec["tracked_moves"] = still_note(scene) not in tracks.notes
    rec["track_notes"] = list(tracks.notes)
    if tracks.camera:
        rec["camera"] = dict(tracks.camera)
    if not rec["moves"]:
        # the tracker holds a still object at rest; a fit would only bound k1 from below
        return {**rec, "status": "skipped", "skip_reason": "nothing moves in the video"}
    res = infer(scene, tracks, config, executor=executor, progress=False)
    t2 = time.perf_counter()
    doc = res.to_json()
    diag = doc["diagnostics"]
    derived = doc["posterior_derived"]
    rec.update({"status": "fitted", "map": res.map, "map_loglik": res.map_loglik, "mass_ratio": res.mass_ratio(),
                "not_identified": dict(doc["not_identified"]),
                "posterior": {k: {q: v[q] for q in ("q05", "q25", "q50", "q75", "q95")}
                              for k, v in doc["posterior"].items()},
                "posterior_derived": {k: {q: v[q] for q in ("q05", "q25", "q50", "q75", "q95") if q in v}
                                      for k, v in derived.items()},
                "converged": bool(diag["converged"]), "why_not": list(diag["why_not"]),
                "r_hat": diag["r_hat"], "ess_bulk": diag["ess"], "sweeps": diag["sweeps"], "stopped": doc["stopped"],
                "shape_found": tracks.objects[0].shape.type, "offset_found": tracks.objects[0].offset_units})
    other = partner(folder, lat)
    if other is not None:
        try:
            scene10 = Scene.load(other / "scene.json")
            _, traj10 = _truth(other)
        except GalileoError as e:   # the partner's files are its own failure, not this video's
            rec["will_it_move_error"] = f"{other.name}: {e}"
        else:
            # the fitted object (the shape its 20 degree scene file gives) on the 10 degree ramp, alone
            alone = dataclasses.replace(scene10, objects=(dataclasses.replace(scene10.ramp_object,
                                                                              shape=scene.ramp_object.shape),))
            rec["will_it_move"] = {"angle_deg": PREDICT_ANGLE_DEG, "partner": other.name,
                                   "predicted_moves": slides(alone, res.map, threshold_m=MOVED_M),
                                   "true_moves": truth_moves(traj10)}
    if scene.target is not None:
        from ... import registry

        sim = registry.get("ramp").simulate(res.scene, traj.n_frames, res.map, fps=traj.fps)
        rec["outcome"] = {"target_start_x_m": float(traj.position_m[1, 0, 0]),
                          "true_final_x_m": float(traj.position_m[1, -1, 0]),
                          "predicted_final_x_m": float(sim.position_m[1, -1, 0])}
    rec["timing"] = {"track_s": t1 - t0, "infer_s": t2 - t1, "chains_cpu_s": res.timing_s["chains_cpu"]}
    return rec


def _spearman(pairs: list[tuple[float, float]]) -> float | None:
    """Spearman's correlation of the (predicted, true) pairs; None with fewer than three or where
    either side is constant (it is undefined there)."""
    if len(pairs) < 3 or any(len(set(side)) < 2 for side in zip(*pairs)):
        return None
    return float(spearmanr(*zip(*pairs)).statistic)


def _scored(acc: dict, acc_map: dict | None = None) -> dict:
    """A report share ({k, n, share, ci95}) as the summary states it: right of scored."""
    out = {"scored": acc["n"], "right": acc["k"], "accuracy": acc["share"], "ci95": acc["ci95"]}
    if acc_map is not None:
        out |= {"right_map": acc_map["k"], "accuracy_map": acc_map["share"]}
    return out


def summarise(records: list[dict]) -> dict:
    """The paper's numbers over the records (see the module)."""
    from .report import HEAVIER_RULE, MOVE_RULE, heavier, will_it_move

    fitted = [r for r in records if r.get("status") == "fitted"]
    k_err = [abs(r["map"]["k1"] - r["truth"]["k1"]) for r in fitted]
    k_err_med = [abs(r["posterior"]["k1"]["q50"] - r["truth"]["k1"]) for r in fitted]
    k_cover = [r["posterior"]["k1"]["q05"] <= r["truth"]["k1"] <= r["posterior"]["k1"]["q95"] for r in fitted]
    lr = [r for r in fitted if "log_mass_ratio" in r["truth"] and "log_mass_ratio" in r.get("posterior_derived", {})]
    lr_cover = [r["posterior_derived"]["log_mass_ratio"]["q05"] <= r["truth"]["log_mass_ratio"]
                <= r["posterior_derived"]["log_mass_ratio"]["q95"] for r in lr]
    heavy = heavier(records)["overall"]
    move = will_it_move(records)
    out = [r["outcome"] for r in fitted if r.get("outcome") and r.get("collision")]
    ratio = [(r["mass_ratio"], r["truth"]["m1_kg"] / r["truth"]["m2_kg"]) for r in fitted
             if r.get("collision") and r.get("mass_ratio")]
    tracked = [r for r in records if "tracked_moves" in r]
    return {"videos": len(records), "fitted": len(fitted),
            "skipped": sum(r.get("status") == "skipped" for r in records),
            "failed": [{"video": r["video"], "error": r.get("error", "")} for r in records if r.get("status") == "failed"],
            "k1_median_abs_error": float(np.median(k_err)) if k_err else None,
            "k1_median_abs_error_posterior_median": float(np.median(k_err_med)) if k_err_med else None,
            "k1_coverage_90": float(np.mean(k_cover)) if k_cover else None,
            "log_mass_ratio_coverage_90": float(np.mean(lr_cover)) if lr_cover else None,
            "converged": int(sum(bool(r.get("converged")) for r in fitted)),
            "which_is_heavier": {**_scored(heavy["accuracy"], heavy["accuracy_map"]), "rule": HEAVIER_RULE},
            "mass_ratio_spearman": _spearman(ratio),
            "moving_read_as_still": sum(r["moves"] and not r["tracked_moves"] for r in tracked),
            "still_read_as_moving": sum(not r["moves"] and r["tracked_moves"] for r in tracked),
            "will_it_move": {**_scored(move["accuracy"]), "rule": MOVE_RULE},
            "outcome_median_abs_error_m": (float(np.median([abs(o["predicted_final_x_m"] - o["true_final_x_m"])
                                                            for o in out])) if out else None),
            "seconds_per_video": (float(np.mean([r["timing"]["total_s"] for r in fitted if "total_s" in r.get("timing", {})]))
                                  if any("total_s" in r.get("timing", {}) for r in fitted) else None)}
