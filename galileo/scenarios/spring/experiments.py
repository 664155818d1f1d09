"""The spring's experiments on a rendered spring dataset (`galileo experiment`, issue 26).

For every video (the *unknown*): up to three other videos of other objects on the same spring
are its *references* (per band of mass ratio, 1.5, 5 and 20, the one nearest it), each in
turn with its mass given; the two videos are one problem (the spring's latents shared,
`galileo.joint`), both tracked by the tracker, the reference's mass fixed at its truth. Each pair
records the unknown's posterior mass (median, 90% interval), the spring's stiffness, and the
run's diagnostics. Then:

* **mass from a reference**: the median relative error of the unknown's posterior median over
  all pairs, and how often the 90% interval covers the truth (target: 3% and 85-95%);
* **which is heavier**: per band of true mass ratio (heavier / lighter) around 1.5, 5 and 20
  (edges at the geometric midpoints), the share of pairs where the unknown's posterior median
  puts it on the right side of the reference's known mass;
* **the spring's stiffness**: the median relative error and 90% coverage of k per spring, and
  the ratio of the tight spring's stiffness to the loose one's (the medians over pairs) against
  its truth.

A failure (tracking, inference) goes into the pair's record as one line; it does not stop the
experiment. `galileo.batch` runs `run_video` for every video and calls `summarise`.
"""
from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np

from ... import registry
from ...errors import GalileoError
from ...jsonio import read_json
from ...runner import RunConfig, infer
from .scene import object_latent, spring_latents

# band: (its median ratio, low edge (inclusive), high edge (exclusive)); inner edges are the
# geometric midpoints of 1.5, 5 and 20
BANDS = {"hard": (1.5, 1.2, 2.74), "medium": (5.0, 2.74, 10.0), "easy": (20.0, 10.0, 40.0)}
TARGETS = {"median_relative_error": 0.03, "coverage_90": (0.85, 0.95)}
REF, UNKNOWN = "ref", "unknown"     # the objects' names inside a pair's problem


def default_config() -> RunConfig:
    from . import SpringScenario

    return RunConfig(**SpringScenario.protocol)


def config_json(cfg: RunConfig) -> dict:
    return {"chains": cfg.chains, "sweeps": cfg.sweeps, "seed": cfg.seed}


def _one_line(e: BaseException) -> str:
    text = str(e).strip().splitlines()
    return text[0] if text else type(e).__name__


def _scene(folder: Path):
    scene = registry.load_scene(folder / "scene.json")
    if scene.scenario != "spring":
        raise GalileoError(f"{folder / 'scene.json'} is a {scene.scenario} scene, not a spring one")
    return scene


def references(folder: Path) -> list[Path]:
    """The references of `folder`'s video: among the dataset's videos (its index.json's, else
    its sibling folders) of another object on the same spring, for each band's median ratio
    (1.5, 5, 20) the one whose true mass ratio to this video's is nearest it in log ratio
    (either way up), each video at most once."""
    scene = _scene(folder)
    index = folder.parent / "index.json"
    if index.is_file():
        names = [v["name"] for v in read_json(index, "dataset index")["videos"]]
        others = [folder.parent / n for n in names if n != folder.name]
    else:
        others = sorted(p for p in folder.parent.iterdir() if p.is_dir() and p != folder)
    cands = []
    for other in others:
        if (other / "scene.json").is_file():
            s = _scene(other)
            if s.spring == scene.spring and s.object != scene.object:
                cands.append((abs(math.log(scene.mass_kg / s.mass_kg)), other))
    out: list[Path] = []
    for median, _, _ in BANDS.values():
        left = [(abs(d - math.log(median)), o.name, o) for d, o in cands if o not in out]
        if left:
            out.append(min(left)[2])
    return out


def pair_record(ref_scene, ref_tracks, unk_scene, unk_tracks, config: RunConfig, executor=None) -> dict:
    """One problem of two videos on a spring, the reference's mass fixed at its scene's value."""
    ref = dataclasses.replace(ref_scene, object=REF)
    unk = dataclasses.replace(unk_scene, object=UNKNOWN)
    prob = registry.problem([ref, unk], fixed={object_latent(REF): ref_scene.mass_kg})
    t0 = time.perf_counter()
    res = infer(prob, [ref_tracks, unk_tracks], config, executor=executor, progress=False)
    names = res.names
    m_name = next(n for n in names if n.startswith(object_latent(UNKNOWN)))
    k_name = spring_latents(unk.spring)["k"]
    post = res.posterior()
    diag = res.diagnostics()
    keep = ("q05", "q50", "q95", "sd")
    return {"mass_kg": {k: post[m_name][k] for k in keep}, "map_mass_kg": res.map[m_name],
            "k_Npm": {k: post[k_name][k] for k in keep},
            "r_hat": {m_name: diag["r_hat"][m_name], k_name: diag["r_hat"][k_name]},
            "not_identified": registry.of(res.scene).unidentified(res.scene), "seconds": time.perf_counter() - t0}


def run_video(folder: Path, config: RunConfig, executor=None) -> dict:
    """This video as the unknown against every reference on its spring (see the module)."""
    folder = Path(folder)
    unk = _scene(folder)
    rec = {"video": folder.name, "scenario": "spring", "object": unk.object, "spring": unk.spring,
           "truth": {"mass_kg": unk.mass_kg, "k_Npm": unk.k_Npm}, "pairs": []}
    scenario = registry.of(unk)
    try:
        unk_tracks = scenario.track(folder / "video.mp4", unk, progress=False)
    except Exception as e:  # noqa: BLE001 - any tracking failure is a result of the experiment
        return {**rec, "status": "failed", "error": f"tracking: {_one_line(e)}"}
    for other in references(folder):
        ref = _scene(other)
        pair = {"reference": other.name, "reference_object": ref.object, "reference_mass_kg": ref.mass_kg,
                "true_ratio": unk.mass_kg / ref.mass_kg}
        try:
            ref_tracks = scenario.track(other / "video.mp4", ref, progress=False)
            pair.update(pair_record(ref, ref_tracks, unk, unk_tracks, config, executor))
            pair["status"] = "fitted"
        except Exception as e:  # noqa: BLE001 - a failed pair is a result too
            pair.update({"status": "failed", "error": _one_line(e)})
        rec["pairs"].append(pair)
    rec["status"] = "fitted"
    return rec


# -- the summary ---------------------------------------------------------------------------------------

def band_of(ratio: float) -> str | None:
    r = max(ratio, 1 / ratio) if ratio > 0 else math.nan
    for name, (_, lo, hi) in BANDS.items():
        if lo <= r < hi:
            return name
    return None


def _pairs(records: list[dict]) -> list[dict]:
    out = []
    for r in records:
        for p in r.get("pairs", []):
            if p.get("status") == "fitted":
                out.append({**p, "video": r["video"], "spring": r["spring"], "truth": r["truth"]})
    return out


def summarise(records: list[dict]) -> dict:
    pairs = _pairs(records)
    rel = [abs(p["mass_kg"]["q50"] / p["truth"]["mass_kg"] - 1) for p in pairs]
    cover = [p["mass_kg"]["q05"] <= p["truth"]["mass_kg"] <= p["mass_kg"]["q95"] for p in pairs]
    heavier = {}
    for band, (median, lo, hi) in BANDS.items():
        inside = [p for p in pairs if band_of(p["true_ratio"]) == band]
        right = [(p["mass_kg"]["q50"] > p["reference_mass_kg"]) == (p["truth"]["mass_kg"] > p["reference_mass_kg"])
                 for p in inside]
        heavier[band] = {"pairs": len(inside), "accuracy": float(np.mean(right)) if right else None,
                         "ratio_from": lo, "ratio_below": hi,
                         "median_true_ratio": float(np.median([max(p["true_ratio"], 1 / p["true_ratio"])
                                                              for p in inside])) if inside else None}
    springs = {}
    for spring in sorted({p["spring"] for p in pairs}):
        ps = [p for p in pairs if p["spring"] == spring]
        springs[spring] = {
            "pairs": len(ps), "true_k_Npm": ps[0]["truth"]["k_Npm"],
            "median_k_Npm": float(np.median([p["k_Npm"]["q50"] for p in ps])),
            "median_relative_error": float(np.median([abs(p["k_Npm"]["q50"] / p["truth"]["k_Npm"] - 1) for p in ps])),
            "coverage_90": float(np.mean([p["k_Npm"]["q05"] <= p["truth"]["k_Npm"] <= p["k_Npm"]["q95"] for p in ps]))}
    ratio = None
    if {"loose", "tight"} <= set(springs):
        ratio = {"estimated": springs["tight"]["median_k_Npm"] / springs["loose"]["median_k_Npm"],
                 "true": springs["tight"]["true_k_Npm"] / springs["loose"]["true_k_Npm"]}
    failed = [{"video": r["video"], "error": r["error"]} for r in records if r.get("status") == "failed"]
    failed += [{"video": r["video"], "reference": p["reference"], "error": p["error"]}
               for r in records for p in r.get("pairs", []) if p.get("status") == "failed"]
    return {"videos": len(records), "pairs": len(pairs),
            "mass_from_reference": {"median_relative_error": float(np.median(rel)) if rel else None,
                                    "coverage_90": float(np.mean(cover)) if cover else None,
                                    "targets": TARGETS},
            "which_is_heavier": heavier, "stiffness": springs, "tight_over_loose_k": ratio,
            "seconds_per_pair": float(np.mean([p["seconds"] for p in pairs])) if pairs else None,
            "failed": failed}


def sections(records: list[dict], fig_dir: Path) -> list:
    """The report's section: the unknown's posterior mass against its truth, with the numbers."""
    from ...report import (
        Section,
        diagonal,
        md_table,
        new_figure,
        plain_log_axes,
        save_figure,
    )

    summary = summarise(records)
    pairs = _pairs(records)
    title = "Mass from a reference on the same spring"
    paper = ("Physics 101 section 2 films every object on two springs; this experiment asks each object's mass "
             "given another object's on the same spring (issue 26's targets: 3% median error, 90% intervals "
             "covering 85-95%).")
    m = summary["mass_from_reference"]
    rows = [["median relative error", f"{m['median_relative_error']:.3g}" if m["median_relative_error"] is not None
             else "-"], ["90% coverage", f"{m['coverage_90']:.2f}" if m["coverage_90"] is not None else "-"]]
    rows += [[f"which is heavier, {b} (ratio {d['ratio_from']:g}-{d['ratio_below']:g})",
              f"{d['accuracy']:.2f} of {d['pairs']}" if d["accuracy"] is not None else "no pairs"]
             for b, d in summary["which_is_heavier"].items()]
    for spring, d in summary["stiffness"].items():
        rows.append([f"k of the {spring} spring", f"{d['median_k_Npm']:.3g} N/m (true {d['true_k_Npm']:.3g}; "
                                                  f"coverage {d['coverage_90']:.2f})"])
    body = md_table(["quantity", "value"], rows)
    if not pairs:
        return [Section(title, paper, None, "No data: no pair was fitted.\n\n" + body, summary)]
    fig, ax = new_figure()
    t = np.array([p["truth"]["mass_kg"] for p in pairs])
    q = np.array([[p["mass_kg"]["q05"], p["mass_kg"]["q50"], p["mass_kg"]["q95"]] for p in pairs])
    ax.errorbar(t, q[:, 1], yerr=[q[:, 1] - q[:, 0], q[:, 2] - q[:, 1]], fmt="o", ms=3)
    plain_log_axes(ax)
    diagonal(ax, "inferred = true")
    ax.set_xlabel("true mass (kg)")
    ax.set_ylabel("posterior mass, median and 90% (kg)")
    png = save_figure(fig, Path(fig_dir) / "spring_mass.png")
    return [Section(title, paper, png, body, summary)]
