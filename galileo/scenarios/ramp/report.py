"""The ramp's sections of the experiments report (`galileo.report`), each beside the figure
or table of Galileo (NIPS 2015) it reproduces:

* mass ratio m1/m2, inferred against true, on collision videos (Table 1: Spearman 0.52);
* friction k1, inferred against true (the paper gives no number);
* which is heavier (section 6.2, Fig. 7), overall and by how close the two masses are;
* will it move (section 6.3, Fig. 7 and Table 1: at chance, Pearson 0.20);
* outcome prediction (section 6.1, Fig. 5): where the target comes to rest, in metres, against
  two baselines that know only the dataset's true outcomes.

Each number is computed by a function of the records (`mass_ratio`, `friction`, `heavier`,
`will_it_move`, `outcome`) and drawn by `sections`.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ...report import (NA, Section, correlation, diagonal, finite, fitted, fmt, fmt_share, get, interval_points,
                       md_table, new_figure, no_data, paper_bars, plain_log_axes, save_figure, share)

# which is heavier: bins of the true ratio heavier/lighter (edges; the last bin is open)
HEAVIER_RATIO_EDGES = (1.0, 2.0, 4.0)
CHANCE = 0.5
PAPER_SPEARMAN = 0.52        # Table 1: Galileo's mass ratio against the truth
PAPER_MOVE_PEARSON = 0.20    # Table 1: Galileo's will-it-move answers against the truth
# how report.md and the summary (report.json, the terminal) count, in the same words
HEAVIER_RULE = ("collision videos with two different true masses; right when the posterior median of "
                "log(m1/m2) has the true sign (right_map: when the MAP ratio does)")
MOVE_RULE = ("20 degree videos whose object has a 10 degree video; right when the 20 degree MAP simulated on "
             "the 10 degree ramp moves exactly when the 10 degree video's object does")
PAPER = {
    "mass": "Table 1 (section 6.2): Spearman's coefficient between Galileo's estimated mass ratio and the truth "
            "is **0.52** (human vs truth 0.68, human vs Galileo 0.51).",
    "friction": "no number: the paper fits k1 per video (Fig. 2f shows which object it finds the more "
                "frictional) but reports no friction accuracy; this section checks the fit against the truth a "
                "rendered dataset knows.",
    "heavier": "Fig. 7 (section 6.2), a plot only: \"human and our model achieve about the same accuracy on this "
               "task\"; Table 1: Spearman **0.52** between Galileo's mass ratio and the truth.",
    "move": "Fig. 7 and Table 1 (section 6.3): \"both humans and the model are at chance on this task\"; Pearson's "
            "coefficient Galileo vs truth **0.20** (human vs truth 0.42, human vs Galileo 0.56); \"both subjects "
            "and the model show a bias towards saying 'it will move'\".",
    "outcome": "Fig. 5 (section 6.1), in pixels and as a plot only: \"human predictions are much better than the "
               "uniform estimate [the average of the true ending points], but still far from perfect. Galileo "
               "performs similar to human in the average on this task.\" Here in metres along the ground.",
}


def _collisions(records: list[dict]) -> list[dict]:
    return [r for r in fitted(records) if r.get("collision") is True
            and finite(get(r, "truth.m1_kg")) and finite(get(r, "truth.m2_kg"))]


def _true_log_ratio(r: dict) -> float:
    return math.log(r["truth"]["m1_kg"] / r["truth"]["m2_kg"])


# -- the numbers ---------------------------------------------------------------------------------------------

def mass_ratio(records: list[dict]) -> dict:
    """Inferred against true m1/m2 on fitted collision videos: the posterior median of the log
    ratio and the MAP ratio, each with Pearson (of log ratios) and Spearman."""
    col = _collisions(records)
    post = [r for r in col if finite(get(r, "posterior_derived.log_mass_ratio.q50"))]
    mp = [r for r in col if finite(r.get("mass_ratio")) and r["mass_ratio"] > 0]
    return {"collision_videos": len(col),
            "posterior_median": correlation([_true_log_ratio(r) for r in post],
                                            [r["posterior_derived"]["log_mass_ratio"]["q50"] for r in post]),
            "map": correlation([_true_log_ratio(r) for r in mp], [math.log(r["mass_ratio"]) for r in mp])}


def friction(records: list[dict]) -> dict:
    """Inferred against true k1 on fitted videos (MAP and posterior median): correlations and median |error|."""
    out = {}
    for key, path in (("map", "map.k1"), ("posterior_median", "posterior.k1.q50")):
        rs = [r for r in fitted(records) if finite(get(r, path)) and finite(get(r, "truth.k1"))]
        t, p = np.array([r["truth"]["k1"] for r in rs]), np.array([get(r, path) for r in rs])
        out[key] = {**correlation(t, p), "median_abs_error": float(np.median(np.abs(p - t))) if rs else None}
    return out


def _bin_label(j: int) -> str:
    e = HEAVIER_RATIO_EDGES
    return f"ratio {e[j]:g}-{e[j + 1]:g}" if j + 1 < len(e) else f"ratio >= {e[j]:g}"


def heavier(records: list[dict]) -> dict:
    """Which of the two objects of a collision video is heavier: right when the posterior median
    log ratio has the true sign (and, beside it, the MAP ratio); overall and per bin of the true
    ratio heavier/lighter. Videos with two equal true masses are left out."""
    bins = {_bin_label(j): {"right": 0, "right_map": 0, "n": 0} for j in range(len(HEAVIER_RATIO_EDGES))}
    total = {"right": 0, "right_map": 0, "n": 0}
    for r in _collisions(records):
        q50, t = get(r, "posterior_derived.log_mass_ratio.q50"), _true_log_ratio(r)
        if not finite(q50) or t == 0:
            continue
        j = int(np.searchsorted(HEAVIER_RATIO_EDGES, math.exp(abs(t)), side="right")) - 1
        ok = math.copysign(1, t) == math.copysign(1, q50) and q50 != 0
        ok_map = finite(r.get("mass_ratio")) and (r["mass_ratio"] > 1) == (t > 0) and r["mass_ratio"] != 1
        for d in (bins[_bin_label(j)], total):
            d["n"] += 1
            d["right"] += ok
            d["right_map"] += ok_map
    def pack(d: dict) -> dict:
        return {"accuracy": share(d["right"], d["n"]), "accuracy_map": share(d["right_map"], d["n"])}

    return {"overall": pack(total), "bins": {k: pack(d) for k, d in bins.items()}}


def _scored_text(what: str, acc: dict) -> str:
    """"right k of n scored, accuracy a, 95% CI [lo, hi]": how report.md states a score, in the
    words of the summary's keys (scored, right, accuracy, ci95)."""
    if not acc["n"]:
        return f"{what}: right 0 of 0 scored, accuracy {NA}"
    lo, hi = acc["ci95"]
    return f"{what}: right {acc['k']} of {acc['n']} scored, accuracy {acc['share']:.2f}, 95% CI [{lo:.2f}, {hi:.2f}]"


def heavier_sentence(n: dict) -> str:
    """report.md's statement of the overall which-is-heavier score: the summary's
    `which_is_heavier` (report.json, `galileo experiment`'s terminal summary) in words."""
    acc_map = n["overall"]["accuracy_map"]
    return (f"**{_scored_text('Which is heavier', n['overall']['accuracy'])}** (MAP ratio: right "
            f"{acc_map['k']} of {acc_map['n']}). Scored: {HEAVIER_RULE}. The summary's `which_is_heavier` "
            "(report.json, the terminal) gives these numbers.")


def will_it_move(records: list[dict]) -> dict:
    """The 20 degree fits' predictions on the 10 degree ramp against the 10 degree videos' truth:
    accuracy, the confusion counts, Pearson of the 0/1 answers (phi), and how often each says "moves"."""
    w = [r["will_it_move"] for r in fitted(records)
         if all(isinstance(get(r, f"will_it_move.{k}"), bool) for k in ("predicted_moves", "true_moves"))]
    p = [x["predicted_moves"] for x in w]
    t = [x["true_moves"] for x in w]
    word = {True: "moves", False: "stays"}
    confusion = {f"{word[a]}|{word[b]}": sum(pi == a and ti == b for pi, ti in zip(p, t))
                 for a in (True, False) for b in (True, False)}   # "predicted|true"
    return {"accuracy": share(sum(pi == ti for pi, ti in zip(p, t)), len(w)),
            "phi": correlation(np.array(t, float), np.array(p, float))["pearson_r"],
            "confusion": confusion,
            "predicted_moves": share(sum(p), len(w)), "true_moves": share(sum(t), len(w))}


def uniform_guess_error(x: np.ndarray, a: float, b: float) -> np.ndarray:
    """Expected |guess - x| for a guess uniform on [a, b] (a <= x <= b): ((x-a)^2 + (b-x)^2) / (2(b-a))."""
    x = np.asarray(x, float)
    if b <= a:
        return np.abs(x - a)
    return ((x - a) ** 2 + (b - x) ** 2) / (2 * (b - a))


def outcome(records: list[dict]) -> dict:
    """Where the target comes to rest, MAP simulation against truth, on fitted collision
    videos: |predicted - true| final x, beside two baselines over the target's travel
    (final - start x, as targets start at different distances): a guess uniform over the
    dataset's [min, max] true travel (its expected error), and the paper's "uniform estimate",
    the mean true travel."""
    keys = ("target_start_x_m", "true_final_x_m", "predicted_final_x_m")
    rs = [r for r in _collisions(records) if all(finite(get(r, f"outcome.{k}")) for k in keys)]
    if not rs:
        return {"videos": 0, "mean_abs_error_m": None, "median_abs_error_m": None,
                "uniform_range_mean_abs_error_m": None, "mean_guess_mean_abs_error_m": None, "per_video": []}
    start = np.array([r["outcome"]["target_start_x_m"] for r in rs])
    true_travel = np.array([r["outcome"]["true_final_x_m"] for r in rs]) - start
    pred_travel = np.array([r["outcome"]["predicted_final_x_m"] for r in rs]) - start
    err = np.abs(pred_travel - true_travel)
    uni = uniform_guess_error(true_travel, true_travel.min(), true_travel.max())
    mean_guess = np.abs(true_travel - true_travel.mean())
    return {"videos": len(rs), "mean_abs_error_m": float(err.mean()), "median_abs_error_m": float(np.median(err)),
            "uniform_range_mean_abs_error_m": float(uni.mean()),
            "mean_guess_mean_abs_error_m": float(mean_guess.mean()),
            "travel_range_m": [float(true_travel.min()), float(true_travel.max())],
            "per_video": [{"video": r["video"], "true_travel_m": float(tt), "abs_error_m": float(e),
                           "uniform_expected_abs_error_m": float(u)} for r, tt, e, u in zip(rs, true_travel, err, uni)]}


# -- the sections --------------------------------------------------------------------------------------------

def _mass_ratio_section(records: list[dict], fig_dir: Path) -> Section:
    title = "Mass ratio m1/m2: inferred against true"
    n = mass_ratio(records)
    col = _collisions(records)
    if not col:
        return no_data(title, PAPER["mass"], "no fitted video in which the two objects collided")
    fig, (ax, ax_p) = new_figure(2, (8.8, 4.6), width_ratios=[4.0, 1.4])
    post = [r for r in col if all(finite(get(r, f"posterior_derived.log_mass_ratio.{k}")) for k in ("q05", "q50", "q95"))]
    if post:
        t = np.array([math.exp(_true_log_ratio(r)) for r in post])
        q = {k: np.exp([r["posterior_derived"]["log_mass_ratio"][k] for r in post]) for k in ("q05", "q50", "q95")}
        interval_points(ax, t, q["q05"], q["q50"], q["q95"], "posterior median, 90% interval")
    mp = [r for r in col if finite(r.get("mass_ratio")) and r["mass_ratio"] > 0]
    if mp:
        ax.plot([math.exp(_true_log_ratio(r)) for r in mp], [r["mass_ratio"] for r in mp], "x", color="tab:red",
                label="MAP")
    plain_log_axes(ax)
    diagonal(ax, "inferred = true")
    ax.axhline(1, color="0.8", lw=0.8)
    ax.axvline(1, color="0.8", lw=0.8)
    ax.set(xlabel="true m1/m2 (dimensionless)", ylabel="inferred m1/m2 (dimensionless)",
           title="Mass ratio, collision videos")
    ax.legend(fontsize=8)
    paper_bars(ax_p, [("posterior\nmedian", n["posterior_median"]["spearman_rho"], PAPER_SPEARMAN, None),
                      ("MAP", n["map"]["spearman_rho"], PAPER_SPEARMAN, None)],
               "Spearman rho, inferred vs true ratio", "Spearman vs paper")
    png = save_figure(fig, fig_dir / "ramp_mass_ratio.png")
    rows = [[label, c["n"], c["spearman_rho"], c["pearson_r"], f"{PAPER_SPEARMAN:.2f}"]
            for label, c in (("posterior median", n["posterior_median"]), ("MAP", n["map"]))]
    body = "\n\n".join([
        md_table(["estimate", "videos", "Spearman rho", "Pearson r (log ratios)", "paper's Spearman"], rows),
        f"{n['collision_videos']} fitted videos in which the objects collided (only those say anything about the "
        "masses). On the dashed diagonal the inferred ratio equals the true one; a point in the upper-right or "
        "lower-left quadrant (split at 1) names the heavier object rightly. Bars span the 90% posterior interval. "
        f"The right panel sets the Spearman coefficients beside the paper's ({PAPER_SPEARMAN:.2f}, dashed)."])
    return Section(title, PAPER["mass"], png, body, n)


def _friction_section(records: list[dict], fig_dir: Path) -> Section:
    title = "Friction k1: inferred against true"
    n = friction(records)
    rs = [r for r in fitted(records) if finite(get(r, "truth.k1")) and finite(get(r, "map.k1"))]
    if not rs:
        return no_data(title, PAPER["friction"], "no fitted video with a true and an inferred k1")
    fig, ax = new_figure()
    post = [r for r in rs if all(finite(get(r, f"posterior.k1.{k}")) for k in ("q05", "q50", "q95"))]
    if post:
        t = np.array([r["truth"]["k1"] for r in post])
        q = {k: np.array([r["posterior"]["k1"][k] for r in post]) for k in ("q05", "q50", "q95")}
        interval_points(ax, t, q["q05"], q["q50"], q["q95"], "posterior median, 90% interval")
    ax.plot([r["truth"]["k1"] for r in rs], [r["map"]["k1"] for r in rs], "x", color="tab:red", label="MAP")
    diagonal(ax, "inferred = true")
    ax.set(xlabel="true k1 (dimensionless)", ylabel="inferred k1 (dimensionless)", title="Friction of the ramp object")
    ax.legend(fontsize=8)
    png = save_figure(fig, fig_dir / "ramp_friction.png")
    rows = [[label, c["n"], c["pearson_r"], c["spearman_rho"], c["median_abs_error"]]
            for label, c in (("MAP", n["map"]), ("posterior median", n["posterior_median"]))]
    body = "\n\n".join([
        md_table(["estimate", "videos", "Pearson r", "Spearman rho", "median abs error"], rows),
        "Every fitted video (the object slid). Points on the dashed diagonal are exact; the spread around it "
        "is the error in k1, and a bar that misses the diagonal is a 90% interval that misses the truth."])
    return Section(title, PAPER["friction"], png, body, n)


def _heavier_section(records: list[dict], fig_dir: Path) -> Section:
    title = "Which is heavier"
    n = heavier(records)
    if not n["overall"]["accuracy"]["n"]:
        return Section(title, PAPER["heavier"], None, "No data: no fitted collision video with a posterior "
                       "mass ratio and two different true masses.", n)
    groups = {**n["bins"], "all": n["overall"]}
    fig, ax = new_figure()
    x = np.arange(len(groups))
    for offset, key, color, label in ((-0.2, "accuracy", "tab:blue", "posterior median"),
                                      (0.2, "accuracy_map", "tab:red", "MAP")):
        s = [g[key] for g in groups.values()]
        y = np.array([c["share"] if c["n"] else np.nan for c in s])
        err = np.array([[c["share"] - c["ci95"][0], c["ci95"][1] - c["share"]] if c["n"] else [0, 0] for c in s]).T
        ax.bar(x + offset, np.nan_to_num(y), 0.4, yerr=err, capsize=3, color=color, alpha=0.8, label=label)
    for j, g in enumerate(groups.values()):
        ax.text(j, 1.03, f"n={g['accuracy']['n']}", ha="center", fontsize=8)
    ax.axhline(CHANCE, color="0.4", ls="--", lw=1, label="chance")
    ax.set_xticks(x, list(groups))
    ax.set_ylim(0, 1.1)
    ax.set(xlabel="true mass ratio, heavier / lighter", ylabel="accuracy (share of videos)",
           title="Which object is heavier (95% CI)")
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.15), ncol=3)
    png = save_figure(fig, fig_dir / "ramp_which_is_heavier.png")
    rows = [[k, g["accuracy"]["n"], fmt_share(g["accuracy"]), fmt_share(g["accuracy_map"])] for k, g in groups.items()]
    body = "\n\n".join([
        heavier_sentence(n),
        md_table(["true ratio", "scored", "right, posterior median [95% CI]", "right, MAP [95% CI]"], rows),
        "One pair per collision video (its two objects). Close masses (ratio near 1) are the hard cases: accuracy "
        "should fall towards chance (dashed) as the ratio nears 1."])
    return Section(title, PAPER["heavier"], png, body, n)


def _move_section(records: list[dict], fig_dir: Path) -> Section:
    title = "Will it move (fit at 20 degrees, predict at 10 degrees)"
    n = will_it_move(records)
    if not n["accuracy"]["n"]:
        return Section(title, PAPER["move"], None, "No data: no fitted 20 degree video whose object has a 10 "
                       "degree video.", n)
    c = n["confusion"]
    m = np.array([[c["moves|moves"], c["moves|stays"]], [c["stays|moves"], c["stays|stays"]]])
    fig, (ax, ax_p) = new_figure(2, (8.0, 4.2), width_ratios=[3.0, 2.0])
    ax.imshow(m, cmap="Blues", vmin=0)
    for (i, j), v in np.ndenumerate(m):
        ax.text(j, i, str(v), ha="center", va="center", fontsize=14, color="white" if v > m.max() / 2 else "black")
    ax.set_xticks([0, 1], ["moves", "stays"])
    ax.set_yticks([0, 1], ["moves", "stays"])
    ax.set(xlabel="truth (10 degree video)", ylabel="predicted (20 degree fit on 10 degrees)",
           title=f"Will it move: accuracy {fmt(n['accuracy']['share'], 2)}")
    paper_bars(ax_p, [("accuracy", n["accuracy"]["share"], CHANCE, f"{CHANCE:g} (chance)"),
                      ("phi\n(Pearson r)", n["phi"], PAPER_MOVE_PEARSON, f"{PAPER_MOVE_PEARSON:.2f}")],
               "share right / correlation with the truth", "Ours vs paper")
    png = save_figure(fig, fig_dir / "ramp_will_it_move.png")
    rows = [["accuracy [95% CI]", fmt_share(n["accuracy"]), "at chance"],
            ["Pearson r of 0/1 answers (phi)", fmt(n["phi"]), f"{PAPER_MOVE_PEARSON:.2f}"],
            ["share predicted to move", fmt_share(n["predicted_moves"]), "biased towards 'moves'"],
            ["share that truly move", fmt_share(n["true_moves"]), NA]]
    body = "\n\n".join([
        f"**{_scored_text('Will it move', n['accuracy'])}.** Scored: {MOVE_RULE}. The summary's `will_it_move` "
        "(report.json, the terminal) gives these numbers.",
        md_table(["measure", "ours", "paper (Galileo)"], rows),
        "Rows are the prediction, columns the truth: the diagonal is right. More predicted 'moves' than true "
        "'moves' is the paper's bias; phi near 0 is chance, 1 perfect. The right panel sets accuracy and phi "
        "beside the paper's (dashed: at chance, and its Pearson coefficient)."])
    return Section(title, PAPER["move"], png, body, n)


def _outcome_section(records: list[dict], fig_dir: Path) -> Section:
    title = "Outcome prediction: where the target comes to rest"
    n = outcome(records)
    if not n["videos"]:
        return Section(title, PAPER["outcome"], None, "No data: no fitted collision video with an outcome.", n)
    per = n["per_video"]
    tt = np.array([p["true_travel_m"] for p in per])
    fig, ax = new_figure()
    ax.plot(tt, [p["abs_error_m"] for p in per], "o", ms=4, label=f"Galileo (MAP), mean {fmt(n['mean_abs_error_m'])} m")
    a, b = n["travel_range_m"]
    grid = np.linspace(a, b, 200)
    ax.plot(grid, uniform_guess_error(grid, a, b), color="tab:orange",
            label=f"uniform guess over [min, max], mean {fmt(n['uniform_range_mean_abs_error_m'])} m")
    ax.plot(grid, np.abs(grid - tt.mean()), color="tab:green", ls="--",
            label=f"mean true travel (paper's baseline), mean {fmt(n['mean_guess_mean_abs_error_m'])} m")
    ax.set(xlabel="true travel of the target (m)", ylabel="absolute error of its final x (m)",
           title="Where the target comes to rest")
    ax.legend(fontsize=8)
    png = save_figure(fig, fig_dir / "ramp_outcome.png")
    rows = [["Galileo (MAP simulated)", n["mean_abs_error_m"], n["median_abs_error_m"]],
            ["uniform guess over the true range", n["uniform_range_mean_abs_error_m"], NA],
            ["mean true travel (the paper's 'uniform estimate')", n["mean_guess_mean_abs_error_m"], NA]]
    body = "\n\n".join([
        md_table(["prediction", "mean abs error (m)", "median abs error (m)"], rows),
        f"{n['videos']} fitted collision videos. Each point is one video's error; the lines are the baselines' "
        "errors at that true travel (they know only the dataset's outcomes). Points below the lines beat them."])
    return Section(title, PAPER["outcome"], png, body, n)


def sections(records: list[dict], fig_dir: Path) -> list[Section]:
    """The ramp's sections of report.md, with their figures written into `fig_dir`."""
    fig_dir = Path(fig_dir)
    return [f(records, fig_dir) for f in (_mass_ratio_section, _friction_section, _heavier_section,
                                         _move_section, _outcome_section)]
