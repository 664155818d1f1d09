"""Recovery on the rendered small preset, pixels in, numbers out (slow: ~4 minutes)."""
import pytest


@pytest.mark.slow
def test_small_preset_recovery(tmp_path):
    from galileo.scenarios.ramp.dataset import build
    from galileo.scenarios.ramp.experiments import run_experiments

    build("small", tmp_path, seed=0, progress=False)
    report = run_experiments(tmp_path, progress=False, out=tmp_path / "report.json")
    s = report["summary"]
    print({k: v for k, v in s.items() if k != "k1_errors"})
    assert s["fitted"] >= 10
    # guessing k1 = 0.2 for every video would score 0.035 here; measured: 0.0005
    assert s["k1_median_abs_error"] <= 0.01
    heavy = s["which_is_heavier"]
    assert heavy["scored"] >= 3 and heavy["accuracy"] >= 0.8
    move = s["will_it_move"]
    assert move["scored"] >= 8 and move["accuracy"] >= 0.8
    # and better than always giving the more common answer
    truths = [w["true_moves"] for w in report["will_it_move"]]
    majority = max(sum(truths), len(truths) - sum(truths)) / len(truths)
    assert move["accuracy"] > majority
