"""What the experiments report's figures and its terminal summary say (issue 31): the terminal
summary's which-is-heavier count is report.md's; the paper's reference numbers are drawn on the
figures; quantities the videos do not identify are greyed and labelled so in the coverage
figure; the memory plot starts at 0 MiB with workers named "worker N"; log axes label no minor
tick. The figures are caught as matplotlib objects where the report saves them."""
import contextlib
import itertools
import json
import math
import re

import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg

import galileo.report as report_mod
from galileo import batch, cli
from galileo.report import build_report, new_figure, plain_log_axes
from galileo.scenarios.ramp import experiments as ramp_experiments
from galileo.scenarios.ramp import report as ramp_report
from galileo.scenarios.splash import report as splash_report

# true m1/m2 of ten collision videos: five within [0.5, 2] (the close cases), five outside
RATIOS = [0.3, 0.6, 0.8, 1.25, 1.5, 1.9, 2.5, 3.0, 0.25, 6.0]
MOVES = [True, False, True, False, True, False, True, False, True, False]
NOT_IDENTIFIED = {"m1_kg": "only the ratio m1/m2 is identified", "m2_kg": "only the ratio m1/m2 is identified"}


def ramp_record(i: int, ratio: float, inferred: float, map_ratio: float) -> dict:
    """A fitted collision video whose posterior median ratio is `inferred` and MAP ratio `map_ratio`;
    its masses' 90% intervals miss the truth (the prior's), its ratio's and k1's hold it."""
    m2, k1 = 0.1, 0.2 + 0.02 * i
    lr = math.log(inferred)
    return {
        "video": f"{i:03d}_obj{i}_20deg_foam", "scenario": "ramp", "object": f"obj{i}", "status": "fitted",
        "angle_deg": 20.0, "target": "foam", "moves": True, "tracked_moves": True, "collision": True,
        "truth": {"m1_kg": ratio * m2, "k1": k1, "m2_kg": m2, "k2": 0.4, "log_mass_ratio": math.log(ratio)},
        "map": {"m1_kg": map_ratio * m2, "k1": k1, "m2_kg": m2, "k2": 0.4}, "mass_ratio": map_ratio,
        "posterior": {"k1": {"q05": k1 - 0.01, "q25": k1 - 0.005, "q50": k1, "q75": k1 + 0.005, "q95": k1 + 0.01},
                      "m1_kg": {"q05": 5.0, "q25": 6.0, "q50": 7.0, "q75": 8.0, "q95": 9.0},
                      "m2_kg": {"q05": 5.0, "q25": 6.0, "q50": 7.0, "q75": 8.0, "q95": 9.0}},
        "posterior_derived": {"log_mass_ratio": {"q05": lr - 2, "q25": lr - 1, "q50": lr, "q75": lr + 1,
                                                 "q95": lr + 2}},
        "not_identified": dict(NOT_IDENTIFIED),
        "converged": False, "r_hat": {"k1": 1.3, "m1_kg": 1.02}, "ess_bulk": {"k1": 50.0, "m1_kg": 300.0},
        "will_it_move": {"angle_deg": 10.0, "partner": f"obj{i}_10deg", "predicted_moves": MOVES[i],
                         "true_moves": MOVES[i] if i != 3 else not MOVES[i]},
        "outcome": {"target_start_x_m": 0.5, "true_final_x_m": 0.5 + 0.02 * i, "predicted_final_x_m": 0.51 + 0.02 * i},
        "timing": {"track_s": 1.0, "infer_s": 4.0 + i, "total_s": 5.0 + i},
        # two workers, each finishing its videos in record order: w1's first video finishes first
        "worker": {"address": f"tcp://127.0.0.1:{4000 + i % 2}", "pid": 100 + i % 2, "rss_mb": 400.0 + i,
                   "finished_unix_s": 1000.0 + i + (0.5 if i % 2 == 0 else 0.0)},
    }


def ramp_records() -> list[dict]:
    """The ten videos: posterior medians all on the true side of 1; MAP ratios wrong on the
    close video 1.25 (a MAP of 0.9) and right elsewhere."""
    recs = []
    for i, t in enumerate(RATIOS):
        inferred = t * 1.1
        recs.append(ramp_record(i, t, inferred, 0.9 if t == 1.25 else inferred))
    return recs


@pytest.fixture
def figures(monkeypatch):
    """{file name: matplotlib Figure} of every figure a report saves while the test runs."""
    caught = {}
    original = report_mod.save_figure

    def keep(fig, path):
        caught[path.name] = fig
        return original(fig, path)

    for module in (report_mod, ramp_report, splash_report):
        monkeypatch.setattr(module, "save_figure", keep)
    return caught


def paper_lines(fig) -> dict[str, float]:
    """{label: its y value} of the lines of a figure labelled "paper: ..."."""
    out = {}
    for ax in fig.axes:
        for line in ax.get_lines():
            if line.get_label().startswith("paper:"):
                ys = set(map(float, line.get_ydata()))
                assert len(ys) == 1, "a paper line is horizontal"
                out[line.get_label()] = ys.pop()
    return out


def drawn(fig):
    FigureCanvasAgg(fig).draw()
    return fig


# -- (1) the terminal summary counts as report.md counts ----------------------------------------------------

def report_md_heavier(text: str) -> tuple[int, int]:
    """(right, scored) of which is heavier as report.md states it: its sentence and its table's "all" row,
    which must agree."""
    sentence = re.search(r"Which is heavier: right (\d+) of (\d+) scored", text)
    row = re.search(r"^\| all \| (\d+) \| (\d+)/(\d+) = ", text, re.MULTILINE)
    assert sentence and row, text
    assert (int(row.group(2)), int(row.group(1))) == (int(sentence.group(1)), int(sentence.group(2)))
    return int(sentence.group(1)), int(sentence.group(2))


def test_the_summary_counts_which_is_heavier_and_will_it_move_as_report_md(tmp_path):
    recs = ramp_records()
    s = ramp_experiments.summarise(recs)
    text = build_report(recs, tmp_path).read_text()
    h = s["which_is_heavier"]
    # every collision video is scored, the close ones (ratio within 2) too, by the posterior median's sign
    assert (h["right"], h["scored"]) == report_md_heavier(text) == (10, 10)
    assert (h["right_map"], h["accuracy_map"]) == (9, 0.9)       # the MAP's slip on the 1.25 video
    lo, hi = h["ci95"]
    assert f"accuracy {h['accuracy']:.2f}, 95% CI [{lo:.2f}, {hi:.2f}]" in text
    assert h["rule"] in text
    m = s["will_it_move"]
    assert (m["right"], m["scored"]) == (9, 10)
    assert "Will it move: right 9 of 10 scored" in text and "| accuracy [95% CI] | 9/10 = 0.90" in text


def test_galileo_experiment_prints_the_which_is_heavier_count_report_md_gives(tmp_path, monkeypatch, capsys):
    """`galileo experiment` end to end but for the videos' work: the records come back from a
    stand-in for the cluster, the summary, tables and report are the real ones."""
    recs = ramp_records()
    ds = tmp_path / "ds"
    ds.mkdir()
    (ds / "index.json").write_text(json.dumps({"scenario": "ramp", "videos": [{"name": r["video"]} for r in recs]}))
    monkeypatch.setattr(batch, "missing_videos", lambda folder, entries: {})
    monkeypatch.setattr(batch, "open_client", lambda *a, **k: contextlib.nullcontext(None))
    monkeypatch.setattr(batch, "experiment_jobs", lambda *a, **k: [])
    monkeypatch.setattr(batch, "run_jobs", lambda *a, **k: batch.Outcome(recs, 0, 1.0, 2))
    out = tmp_path / "out"
    assert cli.main(["experiment", str(ds), "--out", str(out), "--chains", "2", "--sweeps", "4", "--quiet"]) == 0
    printed = capsys.readouterr().out
    summary = json.loads(printed[:printed.index("\n}\n") + 2])
    h = summary["which_is_heavier"]
    assert (h["right"], h["scored"]) == report_md_heavier((out / "report.md").read_text()) == (10, 10)


# -- (2) the paper's numbers on the figures ---------------------------------------------------------------

def test_the_paper_s_numbers_are_drawn_on_the_figures_that_show_them(tmp_path, figures):
    build_report(ramp_records(), tmp_path)
    assert paper_lines(figures["ramp_mass_ratio.png"]) == {"paper: 0.52": pytest.approx(ramp_report.PAPER_SPEARMAN)}
    assert ramp_report.PAPER_SPEARMAN == 0.52
    assert paper_lines(figures["ramp_will_it_move.png"]) == {"paper: 0.5 (chance)": 0.5,
                                                             "paper: 0.20": pytest.approx(0.20)}
    # the label is written on the figure too, not only in a legend
    texts = {t.get_text() for ax in figures["ramp_mass_ratio.png"].axes for t in ax.texts}
    assert "paper: 0.52" in texts


def test_the_splash_mass_figure_draws_the_seed_s_pearson_r(tmp_path, figures):
    recs = []
    for i in range(6):
        kg = 0.002 * 2 ** i
        recs.append({"video": f"{i:03d}_obj{i}", "scenario": "splash", "object": f"obj{i}", "status": "fitted",
                     "truth": {"mass_kg": kg, "density_g_cm3": 0.5}, "map": {"density_g_cm3": 0.5},
                     "map_mass_kg": kg, "mass_kg": kg, "mass_kg_quartiles": [kg * 0.9, kg * 1.1],
                     "final_density_g_cm3": [0.5] * 4, "chains": 4, "sweeps": 20, "seconds": 1.0})
    build_report(recs, tmp_path)
    assert paper_lines(figures["splash_mass.png"]) == {"paper: 0.85": pytest.approx(0.85)}


# -- (3) what is not identified -------------------------------------------------------------------------

def test_coverage_greys_and_labels_what_the_videos_do_not_identify(tmp_path, figures):
    section = report_mod.coverage_section(ramp_records(), tmp_path)
    n = section.numbers
    assert n["not_identified"] == ["m1_kg", "m2_kg"]
    assert set(n["coverage_90"]) == {"k1", "log_mass_ratio"}            # counted where identified only
    assert n["not_identified_90"]["m1_kg"]["n"] == 10 and n["not_identified_90"]["m1_kg"]["k"] == 0
    ax = figures["coverage.png"].axes[0]
    ticks = {t.get_text(): t for t in ax.get_xticklabels()}
    assert set(ticks) == {"k1", "log_mass_ratio", "m1_kg\n(not identified)", "m2_kg\n(not identified)"}
    for name in ("m1_kg\n(not identified)", "m2_kg\n(not identified)"):
        assert ticks[name].get_color() not in ("black", "k")
    # no coloured point sits at a position of a quantity not identified
    at = {round(t.get_position()[0]) for name, t in ticks.items() if "not identified" in name}
    points = [line for line in ax.get_lines() if line.get_linestyle() == "None"]   # not the nominal lines
    coloured = {round(float(x)) for line in points if line.get_color() in ("tab:blue", "tab:orange")
                for x in line.get_xdata()}
    grey = {round(float(x)) for line in points if line.get_color() not in ("tab:blue", "tab:orange")
            for x in line.get_xdata()}
    assert coloured and not coloured & at and grey == at
    assert "not identified: only the ratio m1/m2 is identified" in section.body
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any("not identified" in t for t in legend)


def test_a_record_without_not_identified_is_counted_as_before(tmp_path):
    recs = ramp_records()
    for r in recs:
        del r["not_identified"]
    n = report_mod.coverage_section(recs, tmp_path).numbers
    assert n["not_identified"] == [] and n["coverage_90"]["m1_kg"]["n"] == 10


# -- (4) the memory plot ----------------------------------------------------------------------------------

def test_the_memory_axis_starts_at_zero_and_names_workers_worker_n(tmp_path, figures):
    section = report_mod.timing_section(ramp_records(), tmp_path)
    ax_m = figures["timing.png"].axes[1]
    assert ax_m.get_ylim()[0] == 0
    assert ax_m.get_ylim()[1] >= 409                                   # the largest RSS is on the axis
    assert [t.get_text() for t in ax_m.get_legend().get_texts()] == ["worker 1", "worker 2"]
    # worker 1 is the one whose first video finished first: video 0 (pid 100) at 1000.5 s, video 1 (pid 101) at 1001
    assert section.numbers["worker_processes"] == {"worker 1": "tcp://127.0.0.1:4000 pid 100",
                                                   "worker 2": "tcp://127.0.0.1:4001 pid 101"}
    assert "| worker 1 | tcp://127.0.0.1:4000 pid 100 | 5 | 400 | 408 | 408 | 8 |" in section.body


# -- (5) log axes -----------------------------------------------------------------------------------------

def tick_texts(axis, minor: bool) -> list[str]:
    lo, hi = sorted(axis.get_view_interval())
    ticks = axis.get_minor_ticks() if minor else axis.get_major_ticks()
    return [t.label1.get_text() for t in ticks if lo <= t.get_loc() <= hi]


def no_overlap(fig, axis) -> None:
    renderer = fig.canvas.get_renderer()
    boxes = [t.get_window_extent(renderer) for t in axis.get_ticklabels(which="both")
             if t.get_visible() and t.get_text()]
    for a, b in itertools.pairwise(boxes):
        assert not a.overlaps(b), "two tick labels overlap"


@pytest.mark.parametrize("lo, hi", [(0.2, 6.0), (0.6, 1.0), (1.0, 1.4), (0.03, 30.0), (1e-3, 1e3)])
def test_log_axes_label_no_minor_tick_and_no_two_labels_overlap(lo, hi):
    fig, ax = new_figure()
    ax.plot([lo, hi], [lo, hi], "o")
    plain_log_axes(ax)
    drawn(fig)
    for axis in (ax.xaxis, ax.yaxis):
        assert all(t == "" for t in tick_texts(axis, minor=True))
        majors = [t for t in tick_texts(axis, minor=False) if t]
        assert len(majors) >= 2, f"an axis from {lo} to {hi} needs at least two numbers: {majors}"
        assert all(float(t) > 0 for t in majors)
        no_overlap(fig, axis)


def test_the_report_s_log_axes_label_no_minor_tick(tmp_path, figures):
    build_report(ramp_records(), tmp_path)
    fig = drawn(figures["ramp_mass_ratio.png"])
    ax = fig.axes[0]
    assert ax.get_xscale() == ax.get_yscale() == "log"
    for axis in (ax.xaxis, ax.yaxis):
        assert tick_texts(axis, minor=True) and all(t == "" for t in tick_texts(axis, minor=True))
        no_overlap(fig, axis)
