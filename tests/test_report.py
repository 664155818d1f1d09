"""The results table (flatten, parquet, CSV) and the experiments report (galileo.report and the
scenarios' report sections), on hand-made records whose right numbers are worked out by hand."""
import math
import re

import pytest

from galileo.errors import GalileoError
from galileo.report import build_report, coverage, flatten, read_table, unflatten, write_table
from galileo.scenarios.ramp import report as ramp_report

NAN_WORD = re.compile(r"\bnan\b", re.IGNORECASE)


def nested_record(video="v1", **extra):
    return {"video": video, "scenario": "ramp", "object": "wood|box|0.1", "status": "fitted", "angle_deg": 20.0,
            "truth": {"m1_kg": 0.1, "k1": 0.3, "m2_kg": 0.05, "k2": 0.4}, "moves": True, "collision": True,
            "posterior": {"k1": {"q05": 0.29, "q25": 0.295, "q50": 0.3, "q75": 0.305, "q95": 0.31}},
            "will_it_move": {"angle_deg": 10.0, "partner": "v0", "predicted_moves": False, "true_moves": True},
            "final_density_g_cm3": [0.5, 0.25, 1.0],
            "timing": {"track_s": 1.5, "infer_s": 10.25, "total_s": 12.0},
            "worker": {"address": "tcp://127.0.0.1:1", "pid": 4242, "rss_mb": 310.5}, **extra}


def test_flatten_names_columns_by_dotted_paths_and_unflatten_inverts_it():
    rec = nested_record()
    row = flatten(rec)
    assert row["truth.m1_kg"] == 0.1
    assert row["posterior.k1.q05"] == 0.29
    assert row["will_it_move.predicted_moves"] is False
    assert row["final_density_g_cm3"] == [0.5, 0.25, 1.0]
    assert "truth" not in row and "posterior.k1" not in row
    assert unflatten(row) == rec
    assert unflatten({"video": "v", "a.b": None, "a.c": float("nan"), "d": 1}) == {"video": "v", "d": 1}


def table_records():
    """Three records with a mixed int/float column, a list column, a bool column with a gap, a
    column with text in one row and a number in another, a failed record with few fields."""
    a = nested_record("b_video")
    b = nested_record("a_video", extra_note="text")
    b["timing"]["total_s"] = 7            # an int where the other rows hold floats
    b["worker"]["pid"] = 17
    del b["will_it_move"]
    c = {"video": "c_video", "scenario": "ramp", "status": "failed", "error": "tracking: no object found",
         "timing": {"total_s": 0.5}, "worker": {"address": "tcp://127.0.0.1:2", "pid": 9, "rss_mb": 200.0}}
    return [a, b, c]


def test_parquet_and_csv_round_trip_give_back_the_records_sorted_by_video(tmp_path):
    recs = table_records()
    pq_path, csv_path = write_table(recs, tmp_path)
    assert (pq_path.name, csv_path.name) == ("results.parquet", "results.csv")
    expected = sorted(recs, key=lambda r: r["video"])
    assert read_table(pq_path) == expected
    assert read_table(csv_path) == expected
    assert read_table(tmp_path) == expected           # a folder: parquet first
    back = read_table(csv_path)
    assert isinstance(back[0]["worker"]["pid"], int) and isinstance(back[0]["timing"]["total_s"], int)
    assert isinstance(back[1]["timing"]["total_s"], float)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]   # no temp files left


def test_parquet_keeps_a_column_of_mixed_types_exactly(tmp_path):
    recs = [{"video": "a", "x": "text", "y": [1, "two"]}, {"video": "b", "x": 3, "y": [2.5]}]
    write_table(recs, tmp_path)
    assert read_table(tmp_path / "results.parquet") == recs


def test_nan_and_none_cells_are_dropped_on_reading(tmp_path):
    recs = [{"video": "a", "r_hat": {"k1": float("nan"), "m1_kg": 1.2}, "note": None}]
    write_table(recs, tmp_path)
    for name in ("results.parquet", "results.csv"):
        assert read_table(tmp_path / name) == [{"video": "a", "r_hat": {"m1_kg": 1.2}}]


def test_read_table_refuses_what_is_not_a_results_table_with_one_line(tmp_path):
    (tmp_path / "notes.txt").write_text("hello, this is not a table\n")
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "results.csv").write_text("just,some\nwords,here\n")
    (tmp_path / "worse").mkdir()
    (tmp_path / "worse" / "results.parquet").write_bytes(b"PAR1 not really parquet")
    (tmp_path / "empty_folder").mkdir()
    for path in (tmp_path / "missing.parquet", tmp_path / "notes.txt", tmp_path / "bad", tmp_path / "worse",
                 tmp_path / "bad" / "results.csv", tmp_path / "empty_folder"):
        with pytest.raises(GalileoError) as e:
            read_table(path)
        assert "\n" not in str(e.value)


# -- the ramp's numbers ----------------------------------------------------------------------------------

# eight collision videos at 20 degrees, ordered by true mass ratio m1/m2; each with a 10 degree
# partner and a target that travels TRAVEL_M after the collision
RATIOS = [0.2, 0.3, 0.6, 0.8, 1.5, 2.5, 3.0, 6.0]
K1 = [0.10, 0.15, 0.20, 0.25, 0.30, 0.35, 0.40, 0.45]
MOVES_10 = [True, False, True, False, True, False, True, False]
TRAVEL_M = [0.0, 0.05, 0.10, 0.15, 0.20, 0.25, 0.30, 0.35]


def ramp_records(pred):
    """Video i's predictions are video pred[i]'s truth (pred = identity: perfect)."""
    recs = []
    for i, j in enumerate(pred):
        m2 = 0.1
        start = 0.5 + 0.01 * i          # targets start at different places
        recs.append({
            "video": f"{i:03d}_obj{i}_20deg_foam", "scenario": "ramp", "object": f"obj{i}", "material": "wood",
            "status": "fitted", "angle_deg": 20.0, "target": "foam", "moves": True, "collision": True,
            "truth": {"m1_kg": RATIOS[i] * m2, "k1": K1[i], "m2_kg": m2, "k2": 0.5},
            "map": {"m1_kg": RATIOS[j] * m2, "k1": K1[j], "m2_kg": m2, "k2": 0.5},
            "mass_ratio": RATIOS[j],
            "posterior": {"k1": {"q05": K1[j] - 0.01, "q50": K1[j], "q95": K1[j] + 0.01}},
            "posterior_derived": {"log_mass_ratio": {"q05": math.log(RATIOS[j]) - 0.1, "q50": math.log(RATIOS[j]),
                                                     "q95": math.log(RATIOS[j]) + 0.1}},
            "converged": True, "r_hat": {"k1": 1.001}, "ess_bulk": {"k1": 500.0},
            "will_it_move": {"angle_deg": 10.0, "partner": f"obj{i}_10deg", "predicted_moves": MOVES_10[j],
                             "true_moves": MOVES_10[i]},
            "outcome": {"target_start_x_m": start, "true_final_x_m": start + TRAVEL_M[i],
                        "predicted_final_x_m": start + TRAVEL_M[j]},
        })
    return recs


def numbers_of(section_list):
    return {s.title.split(":")[0].split(" (")[0]: s.numbers for s in section_list}


def test_perfect_predictions_score_perfectly_and_reversed_ones_badly(tmp_path):
    perfect = numbers_of(ramp_report.sections(ramp_records(range(8)), tmp_path))
    reversed_ = numbers_of(ramp_report.sections(ramp_records(range(7, -1, -1)), tmp_path / "r"))

    assert perfect["Mass ratio m1/m2"]["posterior_median"]["spearman_rho"] == pytest.approx(1.0)
    assert perfect["Mass ratio m1/m2"]["map"]["pearson_r"] == pytest.approx(1.0)
    assert perfect["Friction k1"]["map"]["median_abs_error"] == 0.0
    assert perfect["Which is heavier"]["overall"]["accuracy"]["share"] == 1.0
    assert perfect["Will it move"]["accuracy"]["share"] == 1.0
    assert perfect["Will it move"]["phi"] == pytest.approx(1.0)
    out = perfect["Outcome prediction"]
    assert out["mean_abs_error_m"] == pytest.approx(0.0, abs=1e-12)
    # uniform guess over [0, 0.35] m: sum over the eight x of (x^2 + (0.35 - x)^2) / 0.7 is 1
    assert out["uniform_range_mean_abs_error_m"] == pytest.approx(1 / 8)
    # the mean true travel is 0.175 m: |x - 0.175| sums to 2 x (0.175 + 0.125 + 0.075 + 0.025) = 0.8
    assert out["mean_guess_mean_abs_error_m"] == pytest.approx(0.1)

    # reversed predictions: the true ratios are in increasing order, so the ranks are reversed
    assert reversed_["Mass ratio m1/m2"]["posterior_median"]["spearman_rho"] == pytest.approx(-1.0)
    assert reversed_["Which is heavier"]["overall"]["accuracy"]["share"] == 0.0   # every sign flips
    assert reversed_["Will it move"]["accuracy"]["share"] == 0.0
    assert reversed_["Will it move"]["phi"] == pytest.approx(-1.0)
    # errors |x_(7-i) - x_i|: 0.35, 0.25, 0.15, 0.05 twice each: mean 0.2, above the baseline's 0.125
    assert reversed_["Outcome prediction"]["mean_abs_error_m"] == pytest.approx(0.2)
    assert reversed_["Friction k1"]["map"]["spearman_rho"] == pytest.approx(-1.0)


def test_which_is_heavier_bins_by_the_true_ratio_of_heavier_to_lighter(tmp_path):
    bins = ramp_report.heavier(ramp_records(range(8)))["bins"]
    # heavier/lighter: 5, 3.33, 1.67, 1.25, 1.5, 2.5, 3, 6
    assert {k: v["accuracy"]["n"] for k, v in bins.items()} == {"ratio 1-2": 3, "ratio 2-4": 3, "ratio >= 4": 2}


def test_spearman_and_accuracy_on_four_hand_worked_videos():
    recs = ramp_records(range(4))
    true_ratio = [0.25, 0.5, 2.0, 4.0]
    predicted = [0.6, 0.3, 5.0, 3.0]     # ranks 2, 1, 4, 3 against 1, 2, 3, 4
    for r, t, p in zip(recs, true_ratio, predicted):
        r["truth"]["m1_kg"] = t * r["truth"]["m2_kg"]
        r["posterior_derived"]["log_mass_ratio"] = {"q05": math.log(p) - 1, "q50": math.log(p), "q95": math.log(p) + 1}
    # rho = 1 - 6 sum d^2 / (n (n^2 - 1)) = 1 - 6 x 4 / 60
    assert ramp_report.mass_ratio(recs)["posterior_median"]["spearman_rho"] == pytest.approx(0.6)
    acc = ramp_report.heavier(recs)
    assert acc["overall"]["accuracy"]["share"] == 1.0       # every predicted ratio is on the true side of 1
    assert {k: v["accuracy"]["n"] for k, v in acc["bins"].items()} == {"ratio 1-2": 0, "ratio 2-4": 2,
                                                                       "ratio >= 4": 2}


def test_will_it_move_phi_on_a_hand_worked_confusion_matrix():
    recs = ramp_records(range(4))
    for r, p, t in zip(recs, [True, True, False, False], [True, False, False, False]):
        r["will_it_move"].update(predicted_moves=p, true_moves=t)
    n = ramp_report.will_it_move(recs)
    assert n["accuracy"]["share"] == 0.75
    assert n["confusion"] == {"moves|moves": 1, "moves|stays": 1, "stays|moves": 0, "stays|stays": 2}
    # phi = (TP TN - FP FN) / sqrt((TP+FP)(FN+TN)(TP+FN)(FP+TN)) = (1 x 2 - 1 x 0) / sqrt(2 x 2 x 1 x 3)
    assert n["phi"] == pytest.approx(2 / math.sqrt(12))


def test_interval_coverage_counts_closed_intervals_with_exact_binomial_bounds():
    def rec(video, truth, post, status="fitted"):
        return {"video": video, "status": status, "truth": truth, "posterior": post}

    def q(lo, hi):
        return {"q05": lo, "q50": (lo + hi) / 2, "q95": hi}

    recs = [rec("v1", {"a": 1.0, "b": 5.0}, {"a": q(0.5, 1.5), "b": q(4, 6)}),
            rec("v2", {"a": 2.0, "b": 5.0}, {"a": q(2.0, 3.0), "b": q(4, 6)}),    # on the lower end: inside
            rec("v3", {"a": 3.0, "b": 5.0}, {"a": q(3.5, 4.0), "b": q(4, 6)}),    # outside
            rec("v4", {"a": 4.0, "b": 5.0, "c": 1.0}, {"a": q(3.0, 5.0), "b": q(4, 6)}),
            rec("v5", {"a": 9.0}, {"a": q(0.0, 1.0)}, status="skipped")]         # not fitted: not counted
    cov = coverage(recs)
    assert set(cov) == {"a", "b"}                   # c has no posterior
    assert (cov["a"]["k"], cov["a"]["n"], cov["a"]["share"]) == (3, 4, 0.75)
    # Clopper-Pearson: for k = n - 1 the upper bound is 0.975^(1/n); for k = n the lower is 0.025^(1/n)
    assert cov["a"]["ci95"][1] == pytest.approx(0.975 ** 0.25)
    assert cov["b"]["share"] == 1.0 and cov["b"]["ci95"][0] == pytest.approx(0.025 ** 0.25)
    # a derived quantity (posterior_derived) is scored where the record has its truth
    recs[0]["posterior_derived"] = {"d": q(0.0, 1.0)}
    recs[1]["posterior_derived"] = {"d": q(0.0, 1.0)}
    recs[0]["truth"]["d"] = 2.0                      # outside; v2 has no truth of d: not counted
    assert (coverage(recs)["d"]["k"], coverage(recs)["d"]["n"]) == (0, 1)


# -- whole reports ---------------------------------------------------------------------------------------

def read_report(path):
    text = path.read_text()
    assert not NAN_WORD.search(text), "report.md must say n/a, not nan"
    return text


def test_a_full_ramp_report_has_every_section_and_its_figures(tmp_path):
    recs = ramp_records(range(8))
    for i, r in enumerate(recs):
        r["timing"] = {"track_s": 1.0, "infer_s": 5.0 + i, "total_s": 6.0 + i}
        # worker w0 finishes its videos in the order 3, 1, 2, 0 of its list: memory 100, 120, 130, 160
        r["worker"] = {"address": f"tcp://w{i % 2}", "pid": 10 + i % 2,
                       "rss_mb": [160, 200, 120, 200, 130, 200, 100, 200][i],
                       "finished_unix_s": [4.0, 1, 2.0, 2, 3.0, 3, 1.0, 4][i]}
    recs.append({"video": "zzz_failed", "status": "failed", "error": "its worker died 2 times running it"})
    recs.append({**ramp_records(range(1))[0], "video": "zzz_still", "status": "skipped",
                 "skip_reason": "nothing moves in the video"})
    path = build_report(recs, tmp_path, {"dataset": "/data/full", "config": {"chains": 16, "sweeps": 75}})
    text = read_report(path)
    for title in ("Mass ratio m1/m2", "Friction k1", "Which is heavier", "Will it move", "Outcome prediction",
                  "Convergence", "Interval coverage", "Time and memory"):
        assert f". {title}" in text
    assert "its worker died 2 times running it" in text and "nothing moves in the video" in text
    assert "0.52" in text and "0.20" in text                      # the paper's numbers beside ours
    figs = {p.name for p in (tmp_path / "figures").iterdir()}
    assert {"ramp_mass_ratio.png", "ramp_friction.png", "ramp_which_is_heavier.png", "ramp_will_it_move.png",
            "ramp_outcome.png", "convergence.png", "coverage.png", "timing.png"} <= figs
    for name in re.findall(r"\(figures/([^)]+)\)", text):
        assert (tmp_path / "figures" / name).read_bytes()[:4] == b"\x89PNG"
    # memory in completion order: 100 -> 160 on w0 (pid 10), flat 200 on w1
    # (workers named in the order of their first finished video; both first finish at 1.0 s: by address)
    growth = re.search(r"\| worker 1 \| tcp://w0 pid 10 \| 4 \| 100 \| 160 \| 160 \| 60 \|", text)
    assert growth, text[text.index("Time and memory"):]
    assert re.search(r"\| worker 2 \| tcp://w1 pid 11 \| 4 \| 200 \| 200 \| 200 \| 0 \|", text)


def test_the_recognition_evaluation_is_a_section_with_its_table_and_figures(tmp_path):
    import shutil

    evald = tmp_path / "eval"
    evald.mkdir()
    (evald / "table.md").write_text("# Recognition (Fig. 3): DS\n\n| model | mass MSE |\n|---|---|\n| galileo | 0.039 |\n")
    build_report(ramp_records(range(4)), tmp_path / "r0")
    for name in ("fig4.png", "mass_scatter.png"):
        shutil.copy(tmp_path / "r0" / "figures" / "coverage.png", evald / name)
    text = read_report(build_report(ramp_records(range(4)), tmp_path / "r1", recognition=evald))
    assert ". Recognition from one frame" in text and "| galileo | 0.039 |" in text and "# Recognition (Fig. 3)" not in text
    for name in ("recognition_fig4.png", "recognition_mass_scatter.png"):
        assert f"(figures/{name})" in text and (tmp_path / "r1" / "figures" / name).is_file()
    with pytest.raises(GalileoError, match="no table.md"):
        build_report(ramp_records(range(4)), tmp_path / "r2", recognition=tmp_path)


def test_reports_without_fitted_videos_or_with_one_say_no_data_or_na(tmp_path):
    failed = {"video": "a", "status": "failed", "error": "tracking: no object found"}
    skipped = {"video": "b", "scenario": "ramp", "status": "skipped", "skip_reason": "nothing moves in the video",
               "truth": {"m1_kg": 0.1, "k1": 0.6}, "moves": False}
    text = read_report(build_report([failed, skipped], tmp_path / "none"))
    assert "No data" in text and "tracking: no object found" in text
    assert "| 2 | 0 | 1 | 1 |" in text                        # videos, fitted, skipped, failed

    one = ramp_records(range(1))
    text = read_report(build_report(one, tmp_path / "one", {"scenario": "ramp"}))
    assert "n/a" in text                                       # correlations of one point

    splash_failed = {"video": "s", "scenario": "splash", "object": "foam0", "status": "failed",
                     "error": "inference: no chain finished", "truth": {"mass_kg": 0.01, "kind": "box"}}
    text = read_report(build_report([splash_failed], tmp_path / "splash"))
    assert "Mass: predicted against true" in text and "No data" in text


def test_a_splash_report_draws_mass_and_which_is_heavier(tmp_path):
    recs = []
    for i in range(6):
        true_kg = 0.002 * 2 ** i
        recs.append({"video": f"{i:03d}_obj{i}", "scenario": "splash", "object": f"obj{i}", "status": "fitted",
                     "truth": {"mass_kg": true_kg, "density_g_cm3": 0.5}, "map": {"density_g_cm3": 0.5},
                     "map_mass_kg": true_kg, "mass_kg": true_kg, "mass_kg_quartiles": [true_kg * 0.9, true_kg * 1.1],
                     "final_density_g_cm3": [0.5, 0.5, 0.5, 0.5], "chains": 4, "sweeps": 20, "seconds": 1.0,
                     "r_hat": {"density_g_cm3": 1.2}})
    text = read_report(build_report(recs, tmp_path))
    assert "splash_mass.png" in text and "splash_which_is_heavier.png" in text
    # predictions equal to the truth: the correlations of log-spaced masses are 1 by rank
    assert re.search(r"\| videos whose chains agree \| 6 \| [0-9.]+ \| 1 \| n/a \|", text)
