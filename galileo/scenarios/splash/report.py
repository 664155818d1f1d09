"""The splash's sections of the experiments report (`galileo.report`), each beside the figure
of the splash abstract (Physics 101 splash, section 4, Fig. 3) it reproduces: predicted
against true mass (the seed's r = 0.85 over 33 of 36 objects) and which of two objects is
heavier per band of mass ratio (the seed: "highly accurate even with the hardest set of
tasks"). The numbers are `experiments.summarise`'s and `experiments.which_is_heavier`'s.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ...report import (NA, Section, diagonal, finite, fmt, get, interval_points, md_table, new_figure, no_data,
                       paper_bars, plain_log_axes, save_figure)
from .experiments import SEED, chains_agree, summarise, which_is_heavier

CHANCE = 0.5
PAPER = {
    "mass": f"Fig. 3 right (section 4): predicted against actual mass of the {SEED['converged_objects']} objects "
            f"(of {SEED['objects']}) whose chains converged, Pearson **r = {SEED['pearson_r']}**.",
    "heavier": "Fig. 3 left (section 4), a plot only: 30 pairs per band with median mass ratios 22.01 (easy), 5.3 "
               "(medium) and 1.5 (hard); \"our model performed highly accurately even with the hardest set of "
               "tasks\".",
}


def _scored(records: list[dict]) -> list[dict]:
    """The records the summary can use (a failed task may have no truth)."""
    return [r for r in records if finite(get(r, "truth.mass_kg")) and isinstance(r.get("object"), str)]


def _mass_section(records: list[dict], summary: dict, fig_dir: Path) -> Section:
    title = "Mass: predicted against true"
    mc = summary["mass_correlation"]
    pred = [r for r in records if finite(r.get("mass_kg"))]
    if not pred:
        return Section(title, PAPER["mass"], None, "No data: no video has a predicted mass.", mc)
    fig, (ax, ax_p) = new_figure(2, (8.8, 4.6), width_ratios=[4.0, 1.4])
    for conv, style, label in ((True, dict(fmt="o"), "chains agree"),
                               (False, dict(fmt="o", mfc="none"), "chains disagree")):
        rs = [r for r in pred if chains_agree(r)[0] == conv]
        if not rs:
            continue
        t = np.array([r["truth"]["mass_kg"] for r in rs])
        m = np.array([r["mass_kg"] for r in rs])
        q = np.array([r.get("mass_kg_quartiles") or [mi, mi] for r, mi in zip(rs, m)], float)
        interval_points(ax, t, q[:, 0], m, q[:, 1], f"{label} ({len(rs)} videos)", **style)
    plain_log_axes(ax)
    diagonal(ax, "predicted = true")
    ax.set(xlabel="true mass (kg)", ylabel="predicted mass (kg)", title="Mass: median over chains")
    ax.legend(fontsize=8)
    obj = mc["objects"]
    paper_bars(ax_p, [("objects,\nchains\nagree", obj["pearson_r"], SEED["pearson_r"], f"{SEED['pearson_r']:.2f}"),
                      ("videos,\nchains\nagree", mc["videos"]["pearson_r"], None, None)],
               "Pearson r, predicted vs true mass", "Pearson vs paper")
    png = save_figure(fig, fig_dir / "splash_mass.png")
    seed = f"{SEED['pearson_r']} ({SEED['converged_objects']} of {SEED['objects']} objects)"
    rows = [[f"objects whose chains agree ({obj['converged_objects']} of {obj['objects']})", obj["n"],
             obj["pearson_r"], obj["spearman_rho"], seed],
            ["videos whose chains agree", mc["videos"]["n"], mc["videos"]["pearson_r"], mc["videos"]["spearman_rho"],
             NA],
            ["videos whose chains agree, MAP mass", mc["videos_map_mass"]["n"], mc["videos_map_mass"]["pearson_r"],
             mc["videos_map_mass"]["spearman_rho"], NA],
            ["videos, all predicted", mc["all_predicted"]["n"], mc["all_predicted"]["pearson_r"],
             mc["all_predicted"]["spearman_rho"], NA]]
    body = "\n\n".join([
        md_table(["over", "n", "Pearson r", "Spearman rho", "seed's Pearson r"], rows),
        f"Median relative error of the mass over videos whose chains agree: {fmt(mc['median_relative_error'])}. "
        f"Chains agree (the seed's \"converged\"): {summary['chains_agree']} of {summary['predicted']} predicted "
        f"videos ({summary['agreement_rule']}). Converged ({summary['converged_rule']}): {summary['converged']} of "
        f"{summary['predicted']}.",
        "A predicted mass is the posterior median of density x volume (the bottom-up volume times the inferred "
        "volume factor) over all chains' kept draws; bars span its interquartile range. On the dashed diagonal the "
        "prediction is exact; hollow points are videos whose chains disagree, left out of the seed's correlation. "
        f"The right panel sets the Pearson coefficients beside the seed's ({SEED['pearson_r']:.2f}, dashed, over "
        "the objects whose chains agree: the seed's own measure)."])
    return Section(title, PAPER["mass"], png, body, mc)


def _heavier_section(heavier: dict, fig_dir: Path) -> Section:
    title = "Which is heavier, per band of mass ratio"
    numbers = {b: {k: v for k, v in d.items() if k != "scored"} for b, d in heavier.items()}
    if not any(d["pairs"] for d in heavier.values()):
        return Section(title, PAPER["heavier"], None, "No data: no pair of videos of different objects falls in a "
                       "band.", numbers)
    bands = list(heavier)
    fig, ax = new_figure()
    x = np.arange(len(bands))
    for offset, key, color, label in ((-0.2, "accuracy", "tab:blue", "median-over-chains mass"),
                                      (0.2, "accuracy_map_mass", "tab:red", "MAP mass")):
        ax.bar(x + offset, [heavier[b][key] or 0.0 for b in bands], 0.4, color=color, alpha=0.8, label=label)
    for j, b in enumerate(bands):
        ax.text(j, 1.03, f"{heavier[b]['pairs']} pairs", ha="center", fontsize=8)
    ax.axhline(CHANCE, color="0.4", ls="--", lw=1, label="chance")
    ax.set_xticks(x, [f"{b}\n(seed median {SEED['band_median_ratio'][b]:g}x)" for b in bands])
    ax.set_ylim(0, 1.1)
    ax.set(xlabel="band of true mass ratio", ylabel="accuracy (share of pairs)", title="Which object is heavier")
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.22), ncol=3)
    png = save_figure(fig, fig_dir / "splash_which_is_heavier.png")
    rows = [[b, SEED["band_median_ratio"][b], d["median_true_ratio"],
             f"{d['pairs']} ({d['distinct_pairs']} distinct)", d["unanswered"], d["accuracy"],
             d["accuracy_map_mass"], "highly accurate"] for b, d in heavier.items()]
    body = "\n\n".join([
        md_table(["band", "seed's median ratio", "our median ratio", "pairs", "unanswered", "accuracy",
                  "accuracy, MAP mass", "seed"], rows),
        "Pairs of videos of different objects, chosen from the truth alone, closest to the band's median ratio; "
        "right when the heavier object's predicted mass is the larger (a video without a prediction counts as "
        "wrong). The hard band (ratio near 1.5) is the test: the seed stays highly accurate there."])
    return Section(title, PAPER["heavier"], png, body, numbers)


def sections(records: list[dict], fig_dir: Path) -> list[Section]:
    """The splash's sections of report.md, with their figures written into `fig_dir`."""
    fig_dir = Path(fig_dir)
    scored = _scored(records)
    if not scored:
        return [no_data("Mass: predicted against true", PAPER["mass"], "no record with a true mass"),
                no_data("Which is heavier, per band of mass ratio", PAPER["heavier"], "no record with a true mass")]
    heavier = which_is_heavier(scored)
    summary = summarise(scored, heavier)
    return [_mass_section(scored, summary, fig_dir), _heavier_section(heavier, fig_dir), _honesty_section(summary)]


def _cover(c: dict) -> str:
    if not c or c.get("coverage") is None:
        return NA
    lo, hi = c["ci95"]
    return f"{c['coverage']:.0%} ({c['covered']}/{c['n']}; 95% CI {lo:.0%}-{hi:.0%})"


def _honesty_section(summary: dict) -> Section:
    """How far a video's numbers can be trusted: coverage, the volume's error, the kind's confusion."""
    title = "Intervals, volume and shape: how far to trust a video's numbers"
    cov, vol = summary["coverage_90"], summary["volume"]
    rows = [["90% interval holds the true mass", _cover(cov["mass_kg"]), "85-95%"],
            ["90% interval holds the true density", _cover(cov["density_g_cm3"]), "85-95%"],
            ["bottom-up volume, median error", fmt(vol["bottom_up_median_error"]), "<= 15%"],
            ["bottom-up volume, median log(estimate / true)", fmt(vol["bottom_up_median_log_ratio"]), "0"],
            ["posterior volume (median), median error", fmt(vol["posterior_median_error"]), NA],
            ["shape kind right", f"{summary['kind_right']}/{summary['kind_n']}", NA],
            ["MAPs at a prior's edge (any latent)", f"{summary['map_at_any_prior_edge']}/{summary['predicted']}",
             "< 10%"]]
    kinds = sorted({k for row in summary["kind_confusion"].values() for k in row} | set(summary["kind_confusion"]))
    confusion = [[t] + [summary["kind_confusion"].get(t, {}).get(k, 0) for k in kinds]
                 for t in kinds if t in summary["kind_confusion"]]
    edges = ", ".join(f"{k}: {n}" for k, n in sorted(summary["map_at_prior_edge"].items())) or "none"
    body = "\n\n".join([
        md_table(["figure", "value", "target"], rows),
        "Shape kind, true (rows) against bottom-up (columns):\n\n"
        + (md_table(["true \\ bottom-up"] + kinds, confusion) if confusion else "no data"),
        f"MAPs at a prior's edge, per latent: {edges}. A MAP at an edge means the data pull past the prior: the "
        "latent is bending to absorb something (a prior too narrow, or what the model leaves out)."])
    numbers = {k: summary[k] for k in ("coverage_90", "volume", "kind_confusion", "kind_right", "kind_n",
                                       "map_at_prior_edge", "map_at_any_prior_edge")}
    return Section(title, "The seed reports no intervals, volumes or kinds; the targets are this project's.", None,
                   body, numbers)
