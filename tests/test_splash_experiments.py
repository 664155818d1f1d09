"""The splash experiments (`galileo experiment` on a splash dataset): the summary's maths on
hand-made records against numbers worked out independently, the pair bands, the convergence
rule, the CLI's dispatch and defaults, and one end-to-end run on the demo (2 chains x 2 sweeps)."""
import json
import math
import shutil

import numpy as np
import pytest
from scipy import stats

from galileo.cli import main
from galileo.scenarios.splash import experiments as ex


def rec(video, obj, true_g, pred_g=None, spread=0.1, r_hat=3.0, map_g=None, error=None, chains=16, sweeps=40):
    """A hand-made video record (masses in grams): the chains' final densities 1 +- spread/2 at
    their quartiles (numpy's linear quantiles of 5 equally spaced values: q25 and q75 are the
    2nd and 4th), so their relative interquartile range is `spread`."""
    r = {"video": video, "object": obj, "material": "x", "truth": {"mass_kg": true_g / 1000}}
    if error is not None:
        r["error"] = error
        return r
    dens = [1 - spread, 1 - spread / 2, 1.0, 1 + spread / 2, 1 + spread]
    r.update({"mass_kg": pred_g / 1000, "map_mass_kg": (pred_g if map_g is None else map_g) / 1000,
              "final_density_g_cm3": dens, "r_hat": {"density_g_cm3": r_hat}, "seconds": 1.0,
              "chains": chains, "sweeps": sweeps})
    return r


# -- correlation ---------------------------------------------------------------------------------------

def test_correlation_matches_scipy_and_hand_values():
    rng = np.random.default_rng(3)
    x = rng.uniform(1, 50, 20)
    y = x + rng.normal(0, 8, 20)
    c = ex.correlation(x, y)
    assert c["n"] == 20
    assert c["pearson_r"] == pytest.approx(stats.pearsonr(x, y)[0], abs=1e-12)
    assert c["spearman_rho"] == pytest.approx(stats.spearmanr(x, y)[0], abs=1e-12)
    # by hand: x = 1..5, y = 2, 1, 4, 3, 5: Pearson = Spearman (ranks are the values) = 0.8
    # (sum of squared rank differences 4: 1 - 6 * 4 / (5 * 24) = 0.8)
    c = ex.correlation([1, 2, 3, 4, 5], [2, 1, 4, 3, 5])
    assert c["pearson_r"] == pytest.approx(0.8) and c["spearman_rho"] == pytest.approx(0.8)
    # monotone but not linear: rho 1, r below 1
    c = ex.correlation([1, 2, 3, 4], [1, 8, 27, 640])
    assert c["spearman_rho"] == pytest.approx(1.0) and c["pearson_r"] < 0.9
    # undefined: too few points, or a constant side
    assert ex.correlation([1, 2], [1, 2])["pearson_r"] is None
    assert ex.correlation([1, 2, 3], [4, 4, 4])["spearman_rho"] is None


# -- convergence ---------------------------------------------------------------------------------------

def test_relative_iqr():
    assert ex.relative_iqr([1, 2, 3, 4, 5]) == pytest.approx(2 / 3)   # q25 = 2, q75 = 4, median 3
    assert ex.relative_iqr([0.5, 0.5, 0.5]) == 0.0
    assert ex.relative_iqr([0.0, 0.0, 1.0]) == math.inf


def test_convergence_rule():
    assert ex.chains_agree(rec("a", "a", 10, 10, spread=0.25)) == (True, "")     # the bound is inclusive
    assert ex.chains_agree(rec("a", "a", 10, 10, spread=0.0)) == (True, "")
    ok, why = ex.chains_agree(rec("a", "a", 10, 10, spread=0.26))
    assert not ok and why.startswith("chains disagree") and "0.26 of the median" in why
    # R-hat is not the rule (chains that agree, R-hat 3: converged; R-hat 1.01, chains apart: not)
    assert ex.chains_agree(rec("a", "a", 10, 10, spread=0.1, r_hat=3.0))[0]
    assert not ex.chains_agree(rec("a", "a", 10, 10, spread=0.6, r_hat=1.01))[0]
    assert ex.rhat_converged(rec("a", "a", 10, 10, r_hat=1.09)) and not ex.rhat_converged(rec("a", "a", 10, 10, r_hat=1.1))
    assert not ex.rhat_converged(rec("a", "a", 10, 10, r_hat=None))
    for chains, sweeps in ((1, 40), (16, 7)):
        ok, why = ex.chains_agree(rec("a", "a", 10, 10, chains=chains, sweeps=sweeps))
        assert not ok and why.startswith("too short a run")
    assert ex.chains_agree(rec("a", "a", 10, 10, chains=2, sweeps=8))[0]
    ok, why = ex.chains_agree(rec("a", "a", 10, error="tracking: nothing moves"))
    assert (ok, why) == (False, "tracking: nothing moves")


# -- pairs -----------------------------------------------------------------------------------------------

# masses (g) 1, 1.5, 5.3, 22 of four objects, and object A filmed a second time ("a2", 1 g).
# The pairs of different objects, heavier / lighter: b/a = b/a2 = 1.5 (hard); c/a = c/a2 = 5.3,
# c/b = 3.53, d/c = 4.15 (medium); d/a = d/a2 = 22, d/b = 14.7 (easy); a/a2 is one object.
ITEMS = [("a", "A", 1.0), ("a2", "A", 1.0), ("b", "B", 1.5), ("c", "C", 5.3), ("d", "D", 22.0)]


def test_pairs_per_band_cycled_when_few():
    made = ex.make_pairs(ITEMS)
    hard, medium, easy = made["hard"], made["medium"], made["easy"]
    assert [m["candidates"] for m in (hard, medium, easy)] == [2, 4, 3]
    for m in made.values():
        assert len(m["pairs"]) == 30 and m["with_replacement"]
    # closest to the band's ratio first, then cycled: the medium band's 30 are 8 x c/a, 8 x c/a2,
    # 7 x d/c (4.15) and 7 x c/b (3.53)
    from collections import Counter
    counts = Counter((h, lt) for h, lt, _ in medium["pairs"])
    assert counts == {("c", "a"): 8, ("c", "a2"): 8, ("d", "c"): 7, ("c", "b"): 7}
    assert set((h, lt) for h, lt, _ in hard["pairs"]) == {("b", "a"), ("b", "a2")}
    assert set((h, lt) for h, lt, _ in easy["pairs"]) == {("d", "a"), ("d", "a2"), ("d", "b")}
    assert all(lt != "a2" or h != "a" for h, lt, _ in hard["pairs"])
    mass = {v: m for v, _, m in ITEMS}
    for m in made.values():
        assert all(r == pytest.approx(mass[h] / mass[lt]) for h, lt, r in m["pairs"])


def test_pairs_without_replacement_take_the_closest():
    # 60 objects of masses 1.07^k: many candidates in every band
    items = [(f"v{k:02d}", f"o{k}", 1.07 ** k) for k in range(60)]
    made = ex.make_pairs(items)
    for band, (target, lo, hi) in ex.BANDS.items():
        m = made[band]
        assert not m["with_replacement"] and m["candidates"] > 30 and len(set(m["pairs"])) == 30
        chosen = {(h, lt) for h, lt, _ in m["pairs"]}
        worst = max(abs(math.log(r / target)) for _, _, r in m["pairs"])
        # brute force over every pair: all in the band; none left out is closer than the worst chosen
        for (va, _, ma), (vb, _, mb) in ((p, q) for p in items for q in items if p[2] > q[2]):
            r = ma / mb
            if lo <= r < hi and (va, vb) not in chosen:
                assert abs(math.log(r / target)) >= worst - 1e-12
        assert all(lo <= r < hi for _, _, r in m["pairs"])
        assert np.median([r for *_, r in m["pairs"]]) == pytest.approx(target, rel=0.08)


def test_which_is_heavier_scores_and_unanswered():
    # predictions: c looks lighter than b (wrong for c/b), d failed tracking (unanswered)
    records = [rec("a", "A", 1.0, 1.2), rec("a2", "A", 1.0, 0.9), rec("b", "B", 1.5, 2.0),
               rec("c", "C", 5.3, 1.9, map_g=6.0), rec("d", "D", 22.0, error="tracking: lost")]
    h = ex.which_is_heavier(records)
    # hard: b (2.0) > a (1.2) and > a2 (0.9): 30 of 30
    assert h["hard"]["accuracy"] == 1.0 and h["hard"]["median_true_ratio"] == pytest.approx(1.5)
    # medium: c/a x8, c/a2 x8 right; c/b x7 wrong (1.9 < 2.0); d/c x7 unanswered
    assert h["medium"]["accuracy"] == pytest.approx(16 / 30)
    assert h["medium"]["unanswered"] == 7 and h["medium"]["accuracy_answered"] == pytest.approx(16 / 23)
    assert h["medium"]["median_true_ratio"] == pytest.approx(5.3)
    # with the MAP masses c (6.0) beats b too: 23 of 30
    assert h["medium"]["accuracy_map_mass"] == pytest.approx(23 / 30)
    # easy: every pair holds d
    assert h["easy"]["accuracy"] == 0.0 and h["easy"]["unanswered"] == 30 and h["easy"]["accuracy_answered"] is None
    # a tie is not a right answer
    tie = [rec("a", "A", 1.0, 3.0), rec("b", "B", 1.5, 3.0)]
    assert ex.which_is_heavier(tie)["hard"]["accuracy"] == 0.0
    # an empty band
    assert ex.which_is_heavier(tie)["easy"]["pairs"] == 0 and ex.which_is_heavier(tie)["easy"]["accuracy"] is None


# -- the summary -----------------------------------------------------------------------------------------

def test_summary_over_converged_only():
    records = [rec("v1", "A", 10, 12), rec("v2", "A", 10, 8, r_hat=1.02), rec("v3", "B", 20, 25),
               rec("v4", "C", 40, 33), rec("v5", "D", 5, 4), rec("v6", "E", 30, 1, spread=0.7, r_hat=1.05),
               rec("v7", "F", 7, error="tracking: lost"), rec("v8", "G", 3, 2, sweeps=4)]
    s = ex.summarise(records)
    assert (s["videos"], s["predicted"], s["chains_agree"], s["r_hat_below_1_1"]) == (8, 7, 5, 2)
    reasons = {d["video"]: d["reason"] for d in s["chains_disagree"]}
    assert set(reasons) == {"v6", "v7", "v8"}
    assert reasons["v7"] == "tracking: lost" and "disagree" in reasons["v6"] and "too short" in reasons["v8"]
    true, pred = [10, 10, 20, 40, 5], [12, 8, 25, 33, 4]
    v = s["mass_correlation"]["videos"]
    assert v["n"] == 5 and v["pearson_r"] == pytest.approx(stats.pearsonr(true, pred)[0])
    assert v["spearman_rho"] == pytest.approx(stats.spearmanr(true, pred)[0])
    # objects: A's two videos give the median 10 g
    o = s["mass_correlation"]["objects"]
    assert (o["n"], o["converged_objects"], o["objects"]) == (4, 4, 7)
    assert o["pearson_r"] == pytest.approx(stats.pearsonr([10, 20, 40, 5], [10, 25, 33, 4])[0])
    # relative errors 0.2, 0.2, 0.25, 0.175, 0.2 -> median 0.2
    assert s["mass_correlation"]["median_relative_error"] == pytest.approx(0.2)
    assert s["seed"]["pearson_r"] == 0.85
    json.dumps(s)


# -- the command line ------------------------------------------------------------------------------------

@pytest.mark.parametrize("content, needle", [
    (None, "no index.json"),
    ("{not json", "not valid JSON"),
    ('{"scenario": "pool", "videos": []}', "unknown scenario 'pool'"),
    ('[1, 2]', "expected an object"),
    ('{"scenario": "splash", "videos": []}', "no videos"),
    ('{"scenario": "splash", "videos": [{"nom": "x"}]}', "videos[0] has no valid name"),
])
def test_bad_index_is_one_line_error(tmp_path, capsys, content, needle):
    if content is not None:
        (tmp_path / "index.json").write_text(content)
    assert main(["experiment", str(tmp_path), "--out", str(tmp_path / "r.json"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("galileo: error:") and needle in err and "\n" not in err


@pytest.mark.parametrize("scenario, flags, expected", [
    ("splash", [], (50, 75)), (None, [], (16, 75)), ("ramp", [], (16, 75)),
    ("splash", ["--chains", "3", "--sweeps", "4"], (3, 4)), ("ramp", ["--sweeps", "9"], (16, 9)),
])
def test_cli_dispatches_on_index_scenario_with_its_protocol(tmp_path, monkeypatch, capsys, scenario, flags, expected):
    import contextlib

    from galileo import batch

    seen = {}

    def run(folder, cfg, out, client, granularity="videos", progress=True, recognition=None):
        seen.update(chains=cfg.chains, sweeps=cfg.sweeps)
        return {"videos": 1, "summary": {"ok": batch.dataset_index(folder)[0]},
                "run": {"resumed_videos": 0, "failed_videos": [], "wall_s": 0.0, "workers": 1}}

    monkeypatch.setattr(batch, "run_experiments", run)
    monkeypatch.setattr(batch, "open_client", lambda *a, **k: contextlib.nullcontext())
    index = {"videos": [{"name": "v"}]} if scenario is None else {"scenario": scenario, "videos": [{"name": "v"}]}
    (tmp_path / "index.json").write_text(json.dumps(index))
    (tmp_path / "v").mkdir()           # the video's files (checked before a cluster starts)
    for f in batch.VIDEO_FILES:
        (tmp_path / "v" / f).write_text("")
    assert main(["experiment", str(tmp_path), "--out", str(tmp_path / "r"), "--quiet", *flags]) == 0
    assert seen == {"chains": expected[0], "sweeps": expected[1]}
    assert json.loads(capsys.readouterr().out.split("\n}")[0] + "}") == {"ok": scenario or "ramp"}


# -- end to end ------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def demo_dataset(tmp_path_factory):
    """The splash demo, plus a copy of it whose video is not a video (tracking must fail)."""
    from galileo.scenarios.splash.dataset import build

    out = tmp_path_factory.mktemp("splash_exp")
    build("demo", out, seed=0, workers=1, progress=False)
    broken = out / "broken"
    broken.mkdir()
    for f in ("scene.json", "truth.json"):
        shutil.copy(out / "demo" / f, broken / f)
    (broken / "video.mp4").write_bytes(b"not a video")
    index = json.loads((out / "index.json").read_text())
    index["videos"].append({**index["videos"][0], "name": "broken"})
    (out / "index.json").write_text(json.dumps(index))
    return out


def test_experiment_end_to_end_on_the_demo(demo_dataset, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["experiment", str(demo_dataset), "--chains", "2", "--sweeps", "2", "--workers", "1",
                 "--quiet", "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["scenario"] == "splash" and report["config"]["chains"] == 2 and report["config"]["sweeps"] == 2
    s = report["summary"]
    for key in ("videos", "predicted", "converged", "chains_agree", "agreement_rule", "chains_disagree",
                "mass_correlation",
                "which_is_heavier", "seconds_per_video", "seed"):
        assert key in s
    assert set(s["which_is_heavier"]) == {"easy", "medium", "hard"}
    assert (s["videos"], s["predicted"]) == (2, 1)
    demo, broken = (json.loads((out / "records" / f"{n}.json").read_text()) for n in ("demo", "broken"))
    assert broken["status"] == "failed" and broken["error"].startswith("tracking: ") and "\n" not in broken["error"]
    # 2 chains x 2 sweeps is too short a run to judge: nothing converged
    assert s["chains_agree"] == 0 and s["mass_correlation"]["videos"]["pearson_r"] is None
    assert s["converged"] == 0     # galileo infer's verdict: 2 x 2 is no converged posterior either
    assert "too short" in next(d["reason"] for d in s["chains_disagree"] if d["video"] == "demo")
    assert {d["video"] for d in s["chains_disagree"]} == {"demo", "broken"}
    truth = json.loads((demo_dataset / "demo" / "truth.json").read_text())["latents"]
    assert demo["truth"]["mass_kg"] == truth["mass_kg"] and demo["bottom_up"]["kind"] in ("box", "vcyl", "hcyl")
    # the MAP's mass: density x volume, the bottom-up volume x the volume factor (g -> kg); the
    # prediction (the median over chains of the same product) needs each chain's final factor,
    # which the record does not hold
    dens = np.array(demo["final_density_g_cm3"])
    assert len(dens) == 2 and demo["chains"] == 2 and demo["sweeps"] == 2
    v0 = demo["bottom_up"]["volume_cm3"]
    assert demo["map_mass_kg"] == pytest.approx(demo["map"]["density_g_cm3"] * math.exp(demo["map"]["log_volume_factor"]) * v0 / 1000)
    # the report and its figures, and `galileo report` rebuilding them from the table alone
    md = (out / "report.md").read_text()
    assert "which is heavier" in md.lower() and "nan" not in md
    assert main(["report", str(out / "results.parquet"), "--out", str(tmp_path / "again")]) == 0
    assert (tmp_path / "again" / "report.md").read_text() == md
