"""`galileo calibrate` (issue 12): simulation-based calibration on observations simulated
from the prior, its negative control, the ramp's synthetic observations and the CLI's errors.

The SBC here runs on a cheap scene: the standard ramp at 20 degrees without a target (latents
m1_kg, which nothing observed depends on, and k1), 16 frames (0.5 s: the object is still on
the ramp, so the likelihood is smooth in k1 and a short chain mixes), k1's prior narrowed to
0..0.3 (every object slides, so every simulation says something about k1)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from galileo import registry
from galileo.calibrate import binomial_range, ecdf_uniformity, sbc
from galileo.cli import main
from galileo.errors import GalileoError
from galileo.scenarios.ramp.scene import default_camera, default_scene

N_SIM = 40


def with_observation(scene, observation: str):
    return dataclasses.replace(scene, priors=dataclasses.replace(scene.priors, observation=observation))


def sbc_scene(frames: int = 16):
    # the paper's Gaussian observation model, named (whatever the default): the quadrature
    # check quoted below was made with it
    scene = with_observation(default_scene(20.0, target=None, camera=default_camera(30.0, frames)), "gaussian")
    return dataclasses.replace(scene, priors=scene.priors.with_bounds(k1=(0.0, 0.3)))


def run_sbc(tmp_path, **kw):
    # 4 chains x 100 sweeps (50 kept each), the truth ranked among 99 of the 200 kept draws.
    # Seed 1: the exact posterior of its 40 simulations (by quadrature over a fine k1 grid, no
    # MCMC) is typical for a calibrated posterior (ECDF p = 1.0; 37/40 inside the 90%
    # intervals, 18/40 inside the 50% ones). Seed 0's is not, by the luck of its noise draws
    # (p = 0.0009, 32/40; the quadrature PITs follow a noise-only statistic with correlation
    # 0.97): a test on it would test the seed, not the sampler.
    return sbc("ramp", N_SIM, tmp_path, seed=1, chains=4, sweeps=100, workers=2, draws=99, scene=sbc_scene(),
               progress=False, **kw)


def test_sbc_passes_and_an_overconfident_posterior_fails(tmp_path):
    """The right posterior: ranks uniform, intervals covering at their rate. The negative
    control (the same simulations inferred with sigma four times smaller than the noise that
    made them: posteriors four times too narrow) must fail both.

    Thresholds, with margin for another CPU (Bullet amplifies last bits, so chains differ from
    machine to machine while their statistics do not): uniformity p > 0.001 (here m1_kg 0.74,
    k1 1.0; per simulation, the MCMC's fractional rank of k1 is within 0.04 on average of the
    exact posterior's by quadrature, with no bias); the coverage counts within the central
    99.9% range of Binomial(40, 0.9) (29..40; here 35 and 37) and of Binomial(40, 0.5) (10..30;
    here 15 and 21). The overconfident run covers about a quarter (expected P(|Z| < 1.645 / 4)
    = 0.32; here 11 of 40) and its k1 ranks pile at both ends (p = 1e-4, the smallest the
    test gives): far outside either threshold."""
    good = run_sbc(tmp_path / "good")
    lo, hi = binomial_range(N_SIM, 0.9)
    lo50, hi50 = binomial_range(N_SIM, 0.5)
    for name in ("m1_kg", "k1"):
        q = good["quantities"][name]
        assert q["n"] == N_SIM
        assert q["p_value"] > 0.001, (name, q)
        assert lo <= q["coverage"]["0.9"]["covered"] <= hi, (name, q["coverage"])
        assert lo50 <= q["coverage"]["0.5"]["covered"] <= hi50, (name, q["coverage"])
        assert (tmp_path / "good" / f"ranks_{name}.png").stat().st_size > 1000
        assert (tmp_path / "good" / f"ecdf_{name}.png").stat().st_size > 1000
    assert (tmp_path / "good" / "sbc.md").read_text().count("|") > 10
    assert not good["failed"]

    bad = run_sbc(tmp_path / "bad", infer_noise=0.05 / 4)
    k1 = bad["quantities"]["k1"]
    assert k1["coverage"]["0.9"]["covered"] < lo - 5, k1["coverage"]
    assert k1["p_value"] < 0.001, k1
    # the same simulations (truths and observations): only the inference differs
    assert [s["truth"] for s in bad["simulations"]] == [s["truth"] for s in good["simulations"]]


def test_ecdf_test_accepts_uniform_and_rejects_piled_up_values():
    rng = np.random.default_rng(0)
    assert ecdf_uniformity(rng.uniform(size=100))["p"] > 0.01
    ends = np.concatenate([rng.uniform(0, 0.1, 30), rng.uniform(0.9, 1, 30), rng.uniform(size=40)])
    assert ecdf_uniformity(ends)["p"] < 0.001
    middle = rng.uniform(0.3, 0.7, 100)
    test = ecdf_uniformity(middle)
    assert test["p"] < 0.001
    assert np.any(test["ecdf"] < test["lower"]) or np.any(test["ecdf"] > test["upper"])


# -- the ramp's synthetic observations ---------------------------------------------------------------

VALUES = {"m1_kg": 0.3, "k1": 0.2, "m2_kg": 0.12, "k2": 0.4, "e_collision": 0.3}   # (a collision that bounces)


@pytest.fixture(scope="module")
def target_scene():
    return default_scene(20.0, target="cardboard", camera=default_camera(30.0, 40))


def test_noise_free_synthetic_tracks_are_the_likelihoods_motion(target_scene):
    sc = registry.get("ramp")
    tracks = sc.synthetic.tracks(target_scene, VALUES, np.random.default_rng(0), 0.0)
    lik = sc.likelihood(sc.prepare(target_scene, tracks), tracks, 0.05)
    assert np.array_equal(lik.v_obs, np.stack([t.velocity_mps[:, [0, 2]] for t in tracks.objects]))
    motion = lik.motion([VALUES[n] for n in lik.names])
    assert tracks.fps == 30.0 and tracks.n_frames == 40
    for i, tr in enumerate(tracks.objects):
        assert tr.visible.all()
        assert np.array_equal(tr.velocity_mps[:, [0, 2]], motion.velocity_mps[i][:, [0, 2]])
        assert np.all(tr.velocity_mps[:, 1] == 0)
        assert np.array_equal(tr.position_m, motion.position_m[i])
        assert tr.shape == target_scene.objects[i].shape
    assert tracks.by_role("ramp").offset_units == target_scene.ramp_object.offset_units
    # the object moved and hit the target (the test says something)
    assert np.ptp(motion.position_m[0, :, 0]) > 0.3 and np.ptp(motion.position_m[1, :, 0]) > 0.005


@pytest.mark.parametrize("observation", ["gaussian", "student_t"])
def test_noisy_synthetic_tracks_score_as_the_noise_model_says(target_scene, observation):
    """At the true values the residuals are the noise alone, so the log-likelihood is a sum of
    n iid log densities of the scene's observation model, whose mean and SD are known:
    Gaussian: mean -n (log(sigma sqrt(2 pi)) + 1/2), SD sqrt(n / 2); Student-t (nu, scale
    sigma): each log density is c - log sigma - (nu + 1)/2 log(1 + T^2 / nu), and
    1 / (1 + T^2 / nu) ~ Beta(nu / 2, 1 / 2), so the log term has mean psi((nu+1)/2) - psi(nu/2)
    and variance psi'(nu/2) - psi'((nu+1)/2)."""
    from scipy.special import digamma, gammaln, polygamma

    sc = registry.get("ramp")
    scene = with_observation(target_scene, observation)
    sigma, nu = 0.05, scene.priors.student_t_dof
    zs = []
    for seed in range(6):
        tracks = sc.synthetic.tracks(scene, VALUES, np.random.default_rng(seed), sigma)
        lik = sc.likelihood(sc.prepare(scene, tracks), tracks, sigma)
        n = 2 * sum(int(t.visible.sum()) for t in tracks.objects)
        if observation == "gaussian":
            mean, sd = -n * (math.log(sigma * math.sqrt(2 * math.pi)) + 0.5), math.sqrt(n / 2)
        else:
            c = gammaln((nu + 1) / 2) - gammaln(nu / 2) - 0.5 * math.log(nu * math.pi)
            k = (nu + 1) / 2
            mean = n * (c - math.log(sigma) - k * (digamma((nu + 1) / 2) - digamma(nu / 2)))
            sd = math.sqrt(n * k * k * (polygamma(1, nu / 2) - polygamma(1, (nu + 1) / 2)))
        zs.append((lik([VALUES[k] for k in lik.names])[0] - mean) / sd)
    zs = np.array(zs)
    assert np.all(np.abs(zs) < 4), zs
    assert abs(zs.mean()) < 4 / math.sqrt(len(zs)), zs
    # and the other model's noise would not pass: t noise scored as Gaussian has heavy tails
    if observation == "student_t":
        tracks = sc.synthetic.tracks(scene, VALUES, np.random.default_rng(0), sigma)
        gauss = with_observation(target_scene, "gaussian")
        lik = sc.likelihood(sc.prepare(gauss, tracks), tracks, sigma)
        n = 2 * sum(int(t.visible.sum()) for t in tracks.objects)
        z = (lik([VALUES[k] for k in lik.names])[0] + n * (math.log(sigma * math.sqrt(2 * math.pi)) + 0.5)) \
            / math.sqrt(n / 2)
        assert z < -4, z


def test_a_scenario_without_synthetic_observations_says_so(tmp_path, monkeypatch):
    from scenarios.drop import DropScenario

    class Unsimulated(DropScenario):
        name = "unsimulated"
        synthetic = None

    monkeypatch.setattr(registry, "_loaded", dict(registry._loaded))
    registry.register(Unsimulated())
    with pytest.raises(GalileoError, match="the unsimulated scenario cannot simulate observations"):
        sbc("unsimulated", 1, tmp_path)


# -- the command line ----------------------------------------------------------------------------------

@pytest.mark.parametrize("args, needle", [
    (["--n", "0"], "--n must be at least 1"),
    (["--videos", "/nonexistent/dataset"], "dataset folder not found"),
    ([], "give either --n (simulations from the prior) or --videos (a rendered dataset)"),
    (["--n", "3", "--videos", "."], "or --videos (a rendered dataset), not both"),
    (["--n", "3", "--max-sweeps", "50"], "--max-sweeps is the budget of --until-rhat"),
    (["--n", "3", "--chains", "0"], "--chains must be at least 1"),
    (["--n", "3", "--scenes", "nowhere.json"], "not found"),
])
def test_calibrate_cli_errors_are_one_line_exit_2(tmp_path, capsys, args, needle):
    assert main(["calibrate", *args, "--out", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("galileo: error:") and needle in err, err
    assert not (tmp_path / "out").exists()
