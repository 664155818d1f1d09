"""The splash abstract's experiments (section 4) on a rendered splash dataset.

For every video: track it (the object's positions and velocities, its bottom-up kind and
volume), run the chains (the seed's 50 x 75 by default), and record the truth, the
bottom-up kind and volume, the MAP, the predicted mass and R-hat. Then:

* **mass**: the predicted mass of a video (its one point estimate) is the posterior median of
  density x volume over the kept draws of all chains, the volume being the bottom-up one
  times the inferred volume factor (the seed: "final density results for the MCMC chain
  were multiplied by the volume"; its median over chains of the final draws is recorded
  too, `chain_median_mass_kg`); the MAP's mass (result.json's `mass_kg`, the best single
  draw) is recorded beside it and not used. Pearson r
  (the seed's figure: r = 0.85 over 33 of 36 objects) and Spearman rho of predicted against
  true mass over the videos whose chains agree (the seed's "converged"), and over objects (an
  object's prediction: the median over those videos).
* **converged**: one verdict, `galileo infer`'s (`InferenceResult.convergence`: rank-normalised
  split R-hat <= 1.01 and bulk and tail ESS >= 400 for every latent), recorded per video as
  `converged` with its reasons. The seed's selection is a weaker test, named for what it is:
  **chains agree** (`chains_agree`): the interquartile range of the chains' final densities is
  at most AGREE_IQR = 25% of their median, in a run of at least 2 chains of at least 8 sweeps
  (4 after burn-in); where it fails, the reason is recorded (tracking or inference failed; too
  short a run; the chains disagree). At the seed's 75 sweeps chains can agree long before
  they converge (a wooden block whose 16 chains end within 0.41-0.64 g/cm^3 around the true
  0.62, R-hat 6.7): the seed's correlation is over videos whose chains agree.
* **which is heavier**: three bands of true mass ratio (heavier / lighter) around the seed's
  medians 22, 5.3 and 1.5 (edges at the geometric midpoints, `BANDS`); per band 30 pairs of
  videos of different objects, chosen from the dataset's truth alone: the candidate pairs
  closest to the band's ratio in log ratio (ties by name). Where a band has fewer than 30
  candidates, they are cycled to 30 (with replacement: `with_replacement` says so, and
  `distinct_pairs` how many). A pair is right when the heavier object's predicted mass is
  strictly the larger; a pair with a video that has no prediction (tracking or inference
  failed) counts as wrong (`unanswered`). Convergence is not required here.

`galileo.batch` runs `run_video` for every video (on Dask workers), keeps each record as it
comes, and calls `summarise`.
"""
from __future__ import annotations

import itertools
import math
import time
from pathlib import Path

import numpy as np
from ... import registry
from ...errors import GalileoError
from ...jsonio import read_json
from ...report import correlation
from ...runner import RunConfig, infer
from .scene import CM3

AGREE_IQR = 0.25        # converged: (q75 - q25) / median of the chains' final densities <= this
MIN_CHAINS, MIN_SWEEPS = 2, 8   # and a run long enough to judge (8 sweeps: 4 after burn-in, as R-hat needs)
RHAT_MAX = 1.1          # reported beside the rule
PAIRS_PER_BAND = 30
# band: (the seed's median ratio, low edge (inclusive), high edge (exclusive)); the edges between
# bands are the geometric midpoints of the seed's medians (sqrt(1.5 x 5.3) = 2.82, sqrt(5.3 x 22) = 10.8),
# the outer ones as far out in log ratio from the median, except the hard band's low edge (1.2:
# pairs within 20% are left out, which also drops an object filmed twice)
BANDS = {"easy": (22.0, 10.8, 44.8), "medium": (5.3, 2.82, 10.8), "hard": (1.5, 1.2, 2.82)}
SEED = {"pearson_r": 0.85, "converged_objects": 33, "objects": 36,
        "which_is_heavier": {"easy": "high", "medium": "high", "hard": "high"},
        "band_median_ratio": {"easy": 22.01, "medium": 5.3, "hard": 1.5},
        "note": "the seed's figure 3 gives the which-is-heavier accuracy only as a plot: 'highly accurate "
                "even with the hardest set of tasks'"}


def default_config() -> RunConfig:
    from . import SplashScenario

    return RunConfig(**SplashScenario.protocol)


def _one_line(e: BaseException) -> str:
    text = str(e).strip().splitlines()
    return text[0] if text else type(e).__name__


def config_json(cfg: RunConfig) -> dict:
    return {"chains": cfg.chains, "sweeps": cfg.sweeps, "seed": cfg.seed}


# -- one video ---------------------------------------------------------------------------------------

def read_truth(folder: Path) -> dict:
    d = read_json(folder / "truth.json", "truth file")
    lat = d.get("latents") if isinstance(d, dict) else None
    need = ("kind", "volume_cm3", "density_g_cm3", "mass_kg", "material")
    if not isinstance(lat, dict) or any(k not in lat for k in need):
        raise GalileoError(f"{folder / 'truth.json'}: expected latents with {', '.join(need)}")
    return {k: lat[k] for k in ("kind", "volume_cm3", "area_cm2", "density_g_cm3", "drag_water", "release_s",
                                "push_mps", "mass_kg", "material") if k in lat}


def result_record(res) -> dict:
    """What a video's `InferenceResult` contributes to its record."""
    j = res.names.index("density_g_cm3")
    final_density = res.samples[:, -1, j].astype(float)
    factor = (np.exp(res.samples[:, -1, res.names.index("log_volume_factor")].astype(float))
              if "log_volume_factor" in res.names else np.ones_like(final_density))
    final_volume_cm3 = float(res.scene.obj.volume_cm3) * factor   # the bottom-up volume x the chain's factor
    chain_mass_kg = final_density * final_volume_cm3 * CM3 * 1000.0
    diag = res.diagnostics()
    derived = res.derived_posterior()
    mass = derived["mass_kg"]
    return {"map": res.map, "map_mass_kg": float(res.derived()["mass_kg"]),
            "volume_cm3": float(derived["volume_cm3"]["q50"]),
            "derived_posterior": {k: {q: derived[k][q] for q in ("q05", "q25", "q50", "q75", "q95")}
                                  for k in ("mass_kg", "volume_cm3")},
            "map_at_prior_edge": res.at_prior_edge(),
            "mass_kg": float(mass["q50"]), "chain_median_mass_kg": float(np.median(chain_mass_kg)),
            "mass_kg_quartiles": [float(mass["q25"]), float(mass["q75"])],
            "final_density_g_cm3": [float(x) for x in final_density],
            "r_hat": diag["r_hat"], "ess_bulk": diag["ess"], "converged": bool(diag["converged"]),
            "why_not": list(diag["why_not"]),
            "posterior": {k: {q: v[q] for q in ("q05", "q25", "q50", "q75", "q95")} for k, v in res.posterior().items()},
            "chains": int(res.samples.shape[0]), "sweeps": int(res.samples.shape[1]),
            "seconds": float(res.timing_s["wall"])}


def run_video(folder: Path, config: RunConfig, executor=None) -> dict:
    """Track and infer one video folder; a tracking or inference failure goes into the record
    (`error`, one line), it does not stop the experiment."""
    folder = Path(folder)
    scene = registry.load_scene(folder / "scene.json")
    if scene.scenario != "splash":
        raise GalileoError(f"{folder / 'scene.json'} is a {scene.scenario} scene, not a splash one")
    truth = read_truth(folder)
    rec = {"video": folder.name, "scenario": "splash", "object": scene.obj.name, "material": truth["material"],
           "truth": truth}
    scenario = registry.of(scene)
    t0 = time.perf_counter()
    try:
        tracks = scenario.track(folder / "video.mp4", scene, progress=False)
    except Exception as e:  # noqa: BLE001 - any tracking failure is a result of the experiment
        return {**rec, "status": "failed", "error": f"tracking: {_one_line(e)}"}
    t1 = time.perf_counter()
    found = tracks.objects[0].bottom_up if tracks.objects else {}
    rec["bottom_up"] = {k: found.get(k) for k in ("kind", "volume_cm3", "volume_log_sd", "kind_probs", "release_s")}
    rec["track_notes"] = list(tracks.notes)   # what tracking wants known (the camera moved, a distractor, ...)
    if tracks.camera:
        rec["camera"] = dict(tracks.camera)
    try:
        res = infer(scene, tracks, config, executor=executor, progress=False)
    except GalileoError as e:
        return {**rec, "status": "failed", "error": f"inference: {_one_line(e)}"}
    rec.update(result_record(res))
    rec["status"] = "fitted"
    rec["chains_agree"] = chains_agree(rec)[0]
    rec["timing"] = {"track_s": t1 - t0, "infer_s": time.perf_counter() - t1}
    return rec


# -- the summary ---------------------------------------------------------------------------------------

def chains_agree(rec: dict) -> tuple[bool, str]:
    """(agree, why not): the chains' final densities agree (the seed's "converged"; see module
    and AGREE_IQR)."""
    if "error" in rec:
        return False, rec["error"]
    if "mass_kg" not in rec:
        return False, "no prediction"
    if rec["chains"] < MIN_CHAINS or rec["sweeps"] < MIN_SWEEPS:
        return False, (f"too short a run to judge ({rec['chains']} chains x {rec['sweeps']} sweeps; needs "
                       f">= {MIN_CHAINS} x {MIN_SWEEPS})")
    spread = relative_iqr(rec["final_density_g_cm3"])
    if not spread <= AGREE_IQR:
        return False, (f"chains disagree: the interquartile range of their final densities is {spread:.3g} "
                       f"of the median (> {AGREE_IQR:g})")
    return True, ""


def relative_iqr(values) -> float:
    """(q75 - q25) / median (numpy's linear quantiles; inf for a median <= 0)."""
    q25, q50, q75 = np.quantile(np.asarray(values, float), [0.25, 0.5, 0.75])
    return float((q75 - q25) / q50) if q50 > 0 else math.inf


def rhat_converged(rec: dict) -> bool:
    """The textbook test, reported beside the rule: split R-hat of density < RHAT_MAX."""
    r = (rec.get("r_hat") or {}).get("density_g_cm3")
    return r is not None and r < RHAT_MAX


def band_of(ratio: float) -> str | None:
    for name, (_, lo, hi) in BANDS.items():
        if lo <= ratio < hi:
            return name
    return None


def make_pairs(items: list[tuple[str, str, float]], n: int = PAIRS_PER_BAND) -> dict:
    """Per band, `n` pairs (heavier video, lighter video, true ratio) from (video, object,
    true mass) items: the candidates of different objects in the band, closest to its median
    ratio first; cycled when there are fewer than `n` (see module)."""
    cands: dict[str, list] = {b: [] for b in BANDS}
    for (va, oa, ma), (vb, ob, mb) in itertools.combinations(items, 2):
        if oa == ob or not (ma > 0 and mb > 0) or ma == mb:
            continue
        heavy, light = ((va, ma), (vb, mb)) if ma > mb else ((vb, mb), (va, ma))
        ratio = heavy[1] / light[1]
        band = band_of(ratio)
        if band is not None:
            cands[band].append((abs(math.log(ratio / BANDS[band][0])), heavy[0], light[0], ratio))
    out = {}
    for band, cs in cands.items():
        cs.sort()
        chosen = cs[:n] if len(cs) >= n else [cs[k % len(cs)] for k in range(n)] if cs else []
        out[band] = {"pairs": [(h, lt, r) for _, h, lt, r in chosen], "distinct_pairs": min(len(cs), n),
                     "candidates": len(cs), "with_replacement": 0 < len(cs) < n}
    return out


def which_is_heavier(records: list[dict], n: int = PAIRS_PER_BAND) -> dict:
    """Accuracy per band with the median-over-chains mass (and with the MAP mass)."""
    items = [(r["video"], r["object"], float(r["truth"]["mass_kg"])) for r in records if "truth" in r]
    by_video = {r["video"]: r for r in records}
    out = {}
    for band, made in make_pairs(items, n).items():
        pairs = made["pairs"]
        right = right_map = unanswered = 0
        scored = []
        for heavy, light, ratio in pairs:
            h, lt = by_video[heavy], by_video[light]
            if "mass_kg" not in h or "mass_kg" not in lt:
                unanswered += 1
                ok = ok_map = False
            else:
                ok = h["mass_kg"] > lt["mass_kg"]
                ok_map = h["map_mass_kg"] > lt["map_mass_kg"]
            right += ok
            right_map += ok_map
            scored.append({"heavier": heavy, "lighter": light, "true_ratio": ratio, "right": bool(ok)})
        k = len(pairs)
        out[band] = {"pairs": k, "distinct_pairs": made["distinct_pairs"], "candidates": made["candidates"],
                     "with_replacement": made["with_replacement"], "unanswered": unanswered,
                     "accuracy": right / k if k else None, "accuracy_map_mass": right_map / k if k else None,
                     "accuracy_answered": right / (k - unanswered) if k > unanswered else None,
                     "median_true_ratio": float(np.median([p[2] for p in pairs])) if k else None,
                     "band": {"seed_median": BANDS[band][0], "ratio_from": BANDS[band][1], "ratio_below": BANDS[band][2]},
                     "scored": scored}
    return out


def summarise(records: list[dict], heavier: dict | None = None) -> dict:
    """The report's summary of the video records (`heavier`: `which_is_heavier(records)`,
    computed when not given)."""
    predicted = [r for r in records if "mass_kg" in r]
    verdicts = {r["video"]: chains_agree(r) for r in records}
    conv = [r for r in predicted if verdicts[r["video"]][0]]
    not_conv = [{"video": r["video"], "reason": verdicts[r["video"]][1]} for r in records if not verdicts[r["video"]][0]]
    objects: dict[str, list] = {}
    for r in conv:
        objects.setdefault(r["object"], []).append(r)
    obj_true = [float(rs[0]["truth"]["mass_kg"]) for rs in objects.values()]
    obj_pred = [float(np.median([r["mass_kg"] for r in rs])) for rs in objects.values()]
    rel = [abs(r["mass_kg"] / r["truth"]["mass_kg"] - 1) for r in conv]
    heavier = which_is_heavier(records) if heavier is None else heavier
    return {
        "videos": len(records), "predicted": len(predicted), "chains_agree": len(conv),
        "converged": sum(bool(r.get("converged")) for r in predicted),
        "converged_rule": "galileo infer's: R-hat <= 1.01 and bulk and tail ESS >= 400 for every latent",
        "agreement_rule": (f"(q75 - q25) / median of the chains' final densities <= {AGREE_IQR:g}, with >= "
                             f"{MIN_CHAINS} chains of >= {MIN_SWEEPS} sweeps"),
        "chains_disagree": not_conv,
        "r_hat_below_1_1": sum(rhat_converged(r) for r in predicted),
        "mass_correlation": {
            "videos": correlation([r["truth"]["mass_kg"] for r in conv], [r["mass_kg"] for r in conv]),
            "videos_map_mass": correlation([r["truth"]["mass_kg"] for r in conv], [r["map_mass_kg"] for r in conv]),
            # every video with a prediction, converged or not (the rule keeps few of the
            # lightest and heaviest, which the correlation depends on)
            "all_predicted": correlation([r["truth"]["mass_kg"] for r in predicted],
                                         [r["mass_kg"] for r in predicted]),
            "objects": {**correlation(obj_true, obj_pred), "converged_objects": len(objects),
                        "objects": len({r["object"] for r in records if "object" in r})},
            "median_relative_error": float(np.median(rel)) if rel else None},
        "which_is_heavier": {b: {k: v for k, v in d.items() if k != "scored"} for b, d in heavier.items()},
        **honesty(predicted, records),
        "seconds_per_video": float(np.mean([r["seconds"] for r in predicted])) if predicted else None,
        "failed": [{"video": r["video"], "error": r.get("error", "")} for r in records if r.get("status") == "failed"],
        "seed": SEED,
        "pairs": {b: d["scored"] for b, d in heavier.items()},
    }


# -- what the numbers can be trusted for ---------------------------------------------------------------

def inside(interval: dict | None, truth) -> bool | None:
    """Whether a posterior summary's 90% interval (q05-q95) holds the truth (None: no interval)."""
    if not isinstance(interval, dict) or truth is None or "q05" not in interval:
        return None
    return bool(interval["q05"] <= float(truth) <= interval["q95"])


def honesty(predicted: list[dict], records: list[dict]) -> dict:
    """The figures that say how far to trust a video's numbers: the 90% intervals' coverage of
    the true mass and density (with Clopper-Pearson 95% intervals), the bottom-up volume's and
    the posterior volume's errors, the shape kind's confusion (true kind -> bottom-up kind),
    how many MAPs lie at each prior's edge."""
    from ...calibrate import coverage_summary

    mass_in = [inside(r.get("derived_posterior", {}).get("mass_kg"), r["truth"].get("mass_kg")) for r in predicted]
    dens_in = [inside(r.get("posterior", {}).get("density_g_cm3"), r["truth"].get("density_g_cm3")) for r in predicted]
    vol_err, vol_log, post_err = [], [], []
    kinds: dict[str, dict[str, int]] = {}
    for r in records:
        bu, truth = r.get("bottom_up") or {}, r.get("truth") or {}
        v, tv = bu.get("volume_cm3"), truth.get("volume_cm3")
        if isinstance(v, (int, float)) and isinstance(tv, (int, float)) and v > 0 and tv > 0:
            vol_err.append(abs(v / tv - 1))
            vol_log.append(math.log(v / tv))
        if isinstance(r.get("volume_cm3"), (int, float)) and isinstance(tv, (int, float)) and tv > 0:
            post_err.append(abs(r["volume_cm3"] / tv - 1))
        if truth.get("kind") and bu.get("kind"):
            row = kinds.setdefault(truth["kind"], {})
            row[bu["kind"]] = row.get(bu["kind"], 0) + 1
    edges: dict[str, int] = {}
    for r in predicted:
        for k in r.get("map_at_prior_edge", []):
            edges[k] = edges.get(k, 0) + 1
    return {"coverage_90": {"mass_kg": coverage_summary([x for x in mass_in if x is not None]),
                            "density_g_cm3": coverage_summary([x for x in dens_in if x is not None])},
            "volume": {"n": len(vol_err), "bottom_up_median_error": float(np.median(vol_err)) if vol_err else None,
                       "bottom_up_median_log_ratio": float(np.median(vol_log)) if vol_log else None,
                       "posterior_median_error": float(np.median(post_err)) if post_err else None},
            "kind_confusion": kinds, "kind_right": sum(row.get(k, 0) for k, row in kinds.items()),
            "kind_n": sum(sum(row.values()) for row in kinds.values()),
            "map_at_prior_edge": edges, "map_at_any_prior_edge": sum(bool(r.get("map_at_prior_edge"))
                                                                    for r in predicted)}
