"""Running until converged, and the default moves on the ramp (issue 12).

The physics is the frozen demo's (tests/data): a block slides down a 20 degree ramp
(true k1 = 0.22) and hits a cardboard box (true m1/m2 = 1.17)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from galileo.errors import GalileoError
from galileo.runner import RunConfig, infer


@pytest.fixture(scope="module")
def frozen(demo_frozen):
    return demo_frozen


def test_chains_do_not_depend_on_how_their_sweeps_are_cut_into_blocks(frozen):
    scene, tracks, _ = frozen
    # an R-hat target no run reaches: 20 sweeps, then blocks of 10 (runner.block_after) up to the budget of 45
    grown = infer(scene, tracks, RunConfig(chains=2, sweeps=20, seed=3, workers=1, until_rhat=1.000001,
                                           max_sweeps=45, warmup=10), progress=False)
    whole = infer(scene, tracks, RunConfig(chains=2, sweeps=45, seed=3, workers=1, warmup=10), progress=False)
    assert grown.samples.shape == whole.samples.shape == (2, 45, 5)   # (m1, k1, m2, k2, e_collision)
    assert np.array_equal(grown.samples, whole.samples) and np.array_equal(grown.logliks, whole.logliks)
    for k in grown.proposals:
        assert np.array_equal(grown.proposals[k], whole.proposals[k], equal_nan=True)
    assert not grown.diagnostics()["converged"]


def test_a_wall_clock_budget_stops_between_blocks_says_so_and_reruns_exactly(frozen):
    """--max-seconds: an R-hat target never reached and a sweep budget never spent; the time
    budget stops the run between blocks, the result says why ("stopped"), and a fixed run of as
    many sweeps is the same chains (the budget picks where to stop, not what the chains do).
    A target met first says "converged"."""
    scene, tracks, _ = frozen
    cfg = dict(chains=2, sweeps=10, seed=4, workers=1, warmup=5)
    timed = infer(scene, tracks, RunConfig(until_rhat=1.000001, max_sweeps=100_000, max_seconds=1.0, **cfg),
                  progress=False)
    n = timed.samples.shape[1]
    assert timed.stopped == "max_seconds" and 10 <= n < 100_000
    assert timed.to_json()["stopped"] == "max_seconds" and timed.to_json()["config"]["max_seconds"] == 1.0
    fixed = infer(scene, tracks, RunConfig(**{**cfg, "sweeps": n}), progress=False)
    assert np.array_equal(timed.samples, fixed.samples) and fixed.stopped is None
    easy = infer(scene, tracks, RunConfig(until_rhat=10.0, min_ess=0, max_seconds=600.0, **cfg), progress=False)
    assert easy.stopped == "converged" and easy.diagnostics()["converged"]


def test_a_budget_spent_within_the_warm_up_still_keeps_draws(frozen):
    """A found bug: on `full`, a video whose first block (all warm-up) outlasted --max-seconds
    stopped with no draw kept and failed with an IndexError. Now a time budget spent within
    the warm-up runs one short block more (MIN_BLOCK_SWEEPS) and says "max_seconds"; a sweep
    budget of the first block alone warms up over half of it, as a fixed run does; and a fixed
    run whose warm-up is all of it is refused in one line."""
    from galileo.runner import MIN_BLOCK_SWEEPS

    scene, tracks, _ = frozen
    cfg = dict(chains=2, sweeps=12, seed=5, workers=1, until_rhat=1.000001)
    late = infer(scene, tracks, RunConfig(max_seconds=1e-6, **cfg), progress=False)
    assert late.stopped == "max_seconds" and late.warmup == 12
    assert late.samples.shape[1] == 12 + MIN_BLOCK_SWEEPS
    assert late.posterior()["k1"]["q50"] == pytest.approx(np.median(late.samples[:, 12:, 1]))
    short = infer(scene, tracks, RunConfig(max_sweeps=12, **cfg), progress=False)
    assert short.stopped == "max_sweeps" and short.warmup == 6 and short.samples.shape[1] == 12
    assert np.isfinite(short.posterior()["k1"]["q50"])
    with pytest.raises(GalileoError, match="warmup must be an integer from 0 to 11"):
        infer(scene, tracks, RunConfig(chains=2, sweeps=12, workers=1, warmup=12), progress=False)


def test_default_moves_bring_every_chain_off_the_at_rest_plateau(frozen):
    """The paper's moves leave chains far below the MAP after 40 sweeps (some with k1 > tan 20
    deg, on the plateau where the block never moves); the k1 move from the tracked
    acceleration brings them all to the mode within the run."""
    scene, tracks, truth = frozen
    cfg = dict(chains=8, sweeps=40, seed=0, workers=1)
    paper = infer(scene, tracks, RunConfig(moves="paper", **cfg), progress=False)
    mine = infer(scene, tracks, RunConfig(**cfg), progress=False)
    tan = math.tan(math.radians(scene.ramp.angle_deg))
    for res, stuck_expected in ((paper, True), (mine, False)):
        last_ll = res.logliks[:, -1]
        stuck = last_ll < res.map_loglik - 100
        assert stuck.any() == stuck_expected
        if stuck_expected:   # the negative control: some are on the plateau, others far from k1's mode
            assert np.any(res.samples[stuck, -1, 1] > tan)
    # every chain of the default run ends near the true friction, and the ratio's interval holds the truth
    assert np.all(np.abs(mine.samples[:, -1, 1] - truth[1]) < 0.01)
    ratio = mine.derived_posterior()["mass_ratio"]
    assert ratio["q05"] < truth[0] / truth[2] < ratio["q95"]
    acc = mine.diagnostics()["acceptance"]
    assert {"k1_from_acceleration_move", "mass_ray_move", "mass_ratio_move"} <= set(acc)


def test_result_json_says_whether_and_why_not_converged(frozen, tmp_path):
    from galileo.jsonio import read_json

    scene, tracks, _ = frozen
    res = infer(scene, tracks, RunConfig(chains=4, sweeps=20, workers=1), progress=False)
    res.save(tmp_path / "r.json")
    d = read_json(tmp_path / "r.json", "result")
    assert d["converged"] is False and d["why_not"] and d["diagnostics"]["per_latent_converged"]
    assert len(d["diagnostics"]["per_chain"]) == 4
    assert set(d["posterior_derived"]) == {"mass_ratio", "log_mass_ratio"}
    assert d["config"]["moves"]["set"] == "default"
    assert res.warning() and "not converged" in res.warning()


@pytest.mark.parametrize("bad", [dict(moves="fast"), dict(until_rhat=1.0), dict(until_rhat=float("nan")),
                                 dict(min_ess=-1), dict(max_sweeps=10, until_rhat=1.01), dict(warmup=99),
                                 dict(moves="fitted", warmup=5), dict(moves="fitted", warmup=9),
                                 dict(max_seconds=10.0), dict(until_rhat=1.01, max_seconds=0.0),
                                 dict(until_rhat=1.01, max_seconds=float("inf"))])
def test_bad_convergence_settings_are_refused(frozen, bad):
    scene, tracks, _ = frozen
    with pytest.raises(GalileoError):
        infer(scene, tracks, RunConfig(chains=2, sweeps=20, workers=1, **bad), progress=False)


def test_priors_overrides_reach_the_likelihood_and_bad_ones_are_refused(frozen):
    scene, tracks, _ = frozen
    res = infer(scene, tracks, RunConfig(chains=2, sweeps=4, workers=1, priors={"infer_sigma": True}), progress=False)
    assert res.names[-1] == "log10_sigma_mps" and res.scene.to_json()["priors"]["infer_sigma"] is True
    with pytest.raises(GalileoError, match="priors.observation"):
        infer(scene, tracks, RunConfig(chains=2, sweeps=4, workers=1, priors={"observation": "cauchy"}), progress=False)


def test_the_fitted_move_lets_chains_that_the_jagged_likelihood_holds_apart_meet(frozen):
    """Issue 30: after a warm-up of 40 sweeps, an independence move fitted to every chain's warm-up
    draws joins each chain. On the demo's 8 x 80 the default moves leave k1 and the target's friction
    k2 unmixed (bulk ESS 44 and 16, k2's R-hat 1.6: Bullet's collisions make the likelihood jagged,
    and each chain sits on its own ridges); with the fitted moves each accepted joint proposal (from
    the kernel density estimate of the warm-up draws) is a fresh draw from the whole posterior
    (ESS 337 and 232, every R-hat below 1.05; with the joint proposals from the t, 243 and 261). (The four latents of
    the paper's model, the collision's restitution fixed: with it a latent, 40 warm-up sweeps
    leave its draws spread over the prior, and q, fitted to them, is accepted 1.4% of the time.)"""
    scene, tracks, _ = frozen
    cfg = dict(chains=8, sweeps=80, seed=0, workers=2, warmup=40, priors={"infer_restitution": False})
    fitted = infer(scene, tracks, RunConfig(moves="fitted", **cfg), progress=False)
    default = infer(scene, tracks, RunConfig(moves="default", **cfg), progress=False)
    f, d = fitted.diagnostics(), default.diagnostics()
    assert "fitted_kernel" in fitted.moves["joint"] and 0.05 < f["acceptance"]["fitted_kernel_move"] < 0.6
    assert f["ess"]["k1"] >= 3 * d["ess"]["k1"] and f["ess"]["k2"] >= 3 * d["ess"]["k2"]
    assert max(f["r_hat"].values()) < 1.1 < d["r_hat"]["k2"]
    # the warm-up is the default's, sweep for sweep (the move joins after it)
    assert np.array_equal(fitted.samples[:, :40], default.samples[:, :40])


def test_running_until_converged_uses_the_scenarios_converging_moves_unless_told(frozen):
    """Issue 30's "the good path the default the user meets": `galileo infer --until-rhat` (and
    the API, experiments, calibration, the app) on the ramp runs the fitted move set unless
    `--moves` says otherwise; a fixed number of sweeps keeps the default moves (the paper's
    protocol's budget); a warm-up too short to fit to keeps them too; the splash, whose modes a
    fitted move does not join (BENCHMARKS.md), keeps its default moves."""
    from galileo import api, registry

    ramp, splash = registry.get("ramp"), registry.get("splash")
    assert api.run_config(ramp, until_rhat=1.01).moves == "fitted"
    assert api.run_config(ramp).moves == "default"
    assert api.run_config(ramp, until_rhat=1.01, moves="default").moves == "default"
    assert api.run_config(ramp, until_rhat=1.01, sweeps=8).moves == "default"      # a warm-up of 8 fits nothing
    assert api.run_config(ramp, until_rhat=1.01, sweeps=40, warmup=6).moves == "default"
    assert api.run_config(splash, until_rhat=1.01).moves == "default"
    # the app's sessions, which can always be run until converged; its warm-up is half the sweep
    # target unless it is told to run until converged (then at least 100 or all of them)
    assert api.moves_for(ramp, None, None, 75, converging=True) == "fitted"
    assert api.moves_for(ramp, None, None, 12, converging=True) == "default"        # a warm-up of 6
    assert api.moves_for(ramp, None, 1.01, 12, converging=True) == "fitted"         # a warm-up of 12
    assert api.moves_for(ramp, "paper", None, 75, converging=True) == "paper"
    # it reaches the run: the fitted move joins every chain after the warm-up and is recorded
    scene, tracks, _ = frozen
    res = api.infer(scene, tracks, chains=2, sweeps=20, until_rhat=1.000001, max_sweeps=30, workers=1,
                    progress=False)
    assert res.doc["config"]["moves"]["set"] == "fitted"
    assert "fitted_kernel" in res.doc["config"]["moves"]["joint"] and res.diagnostics["acceptance"]["fitted_kernel_move"] > 0
    fixed = api.infer(scene, tracks, chains=2, sweeps=20, workers=1, progress=False)
    assert fixed.doc["config"]["moves"]["set"] == "default"
