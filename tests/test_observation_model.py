"""Model mismatch in the ramp's likelihood: the Student-t observation model, sigma as a latent
(log10_sigma_mps) and the collision's restitution as a latent (e_collision).

(a) the log-likelihood against scipy's densities of the motion it scored; (b) the exact
speed-ups against the plain path (sigma-only, mass-only and k1 proposals); (c) the scene
file's new fields; (d) sigma recovered by inference from tracks with known noise."""
import copy
import dataclasses
import json
import math

import numpy as np
import pytest
from scipy import stats

from galileo.datatypes import ObjectTrack, Tracks
from galileo.errors import SceneError
from galileo.runner import RunConfig, infer
from galileo.scenarios.ramp.likelihood import VelocityLikelihood
from galileo.scenarios.ramp.scene import Priors, default_scene, scene_from_json

from conftest import DATA, assert_same_decisions

SIGMA = "log10_sigma_mps"


def with_priors(scene, **kw):
    return dataclasses.replace(scene, priors=dataclasses.replace(scene.priors, **kw))


def latent_vector(lik, physical, sigma=None, e=None):
    """The likelihood's latent vector from the four physical latents (or two without a
    target) and, where they are latents, sigma (m/s) and e_collision."""
    x = list(physical[:len(lik.names) - (SIGMA in lik.names) - ("e_collision" in lik.names)])
    if "e_collision" in lik.names:
        x.append(e)
    if SIGMA in lik.names:
        x.append(math.log10(sigma))
    return np.array(x, float)


def scipy_loglik(scene, tracks, motion, sigma):
    """sum over visible frames and objects of log N or log t of (vx, vz), by scipy."""
    total = 0.0
    for i, obj in enumerate(scene.objects):
        track = tracks.by_role(obj.role)
        seen = track.visible
        obs = track.velocity_mps[seen][:, [0, 2]]
        sim = motion.velocity_mps[i][seen][:, [0, 2]]
        if scene.priors.observation == "student_t":
            total += stats.t.logpdf(obs, df=scene.priors.student_t_dof, loc=sim, scale=sigma).sum()
        else:
            total += stats.norm.logpdf(obs, loc=sim, scale=sigma).sum()
    return float(total)


# -- (a) the densities ---------------------------------------------------------------------------

OPTIONS = [
    dict(),
    dict(observation="student_t"),
    dict(observation="student_t", student_t_dof=1.5),
    dict(infer_sigma=True),
    dict(observation="student_t", student_t_dof=3.0, infer_sigma=True, infer_restitution=True),
]


@pytest.mark.parametrize("options", OPTIONS, ids=lambda o: ",".join(f"{k}={v}" for k, v in o.items()) or "default")
def test_loglik_is_the_scipy_density_of_the_scored_motion(demo_frozen, options):
    scene, tracks, x0 = demo_frozen
    scene = with_priors(scene, **options)
    sigmas = (0.03, 0.2) if options.get("infer_sigma") else (0.07,)
    held_still = False
    for speedups in (True, False):
        for sigma in sigmas:
            lik = VelocityLikelihood(scene, tracks, sigma_mps=0.05 if options.get("infer_sigma") else sigma,
                                     speedups=speedups)
            # the truth (it comes to rest: the rest rule's terms count), one far from it, a
            # heavy rough target
            for phys, e in ((x0, 0.0), (x0 * [1.4, 0.8, 0.7, 1.2], 0.6), ([x0[0], 0.15, 1.0, 1.0], 0.3)):
                x = latent_vector(lik, phys, sigma, e)
                value, early = lik(x)
                motion = lik.motion(x)
                held_still |= bool(np.all(motion.velocity_mps[:, -5:] == 0.0))
                want = scipy_loglik(lik.scene, tracks, motion, sigma)
                assert not early
                assert value == pytest.approx(want, rel=1e-11, abs=1e-9)
                assert lik(x)[0] == value     # again (from the caches): the same
    assert held_still


def test_student_t_normaliser_and_heavy_tails(demo_frozen):
    """One component by hand, and what the t is for: an outlier costs far less than under
    the normal."""
    scene, tracks, x0 = demo_frozen
    nu, sigma = 4.0, 0.05
    lik = VelocityLikelihood(with_priors(scene, observation="student_t", student_t_dof=nu), tracks, sigma)
    const = math.lgamma((nu + 1) / 2) - math.lgamma(nu / 2) - 0.5 * math.log(nu * math.pi) - math.log(sigma)
    assert lik.log_norm == pytest.approx(2 * lik.seen.sum() * const, rel=1e-13)
    noise = lik.noise_of({})
    r = 0.5   # a 10-sigma residual
    assert lik._term((r * r,), noise) == pytest.approx(-(nu + 1) / 2 * math.log1p(r * r / (nu * sigma ** 2)))
    assert lik._term((r * r,), noise) > -0.5 * r * r / sigma ** 2 + 40


# -- (b) the speed-ups give the plain path's decisions ----------------------------------------------

def _walk(scene, tracks, start, moves, seed):
    """Run the same proposals (site, step) through a fast and a plain likelihood with the MH
    kernel's threshold (current value + log u); both make the same decisions and, where the
    fast one did not stop early, return the same value bit for bit. Returns the fast
    likelihood and per move (proposal, physics steps the fast path took, stopped early)."""
    fast = VelocityLikelihood(scene, tracks, speedups=True)
    plain = VelocityLikelihood(scene, tracks, speedups=False)
    rng = np.random.default_rng(seed)
    x = np.array(start, float)
    current = fast(x)[0]
    assert current == plain(x)[0]
    record, accepted = [], 0
    for site, step in moves:
        prop = x.copy()
        prop[site] += step
        threshold = current + math.log(rng.uniform())
        s0 = fast.steps
        v_fast, early = fast(prop, threshold)
        record.append((prop, fast.steps - s0, early))
        v_plain, plain_early = plain(prop, threshold)
        assert not plain_early
        assert (not early and v_fast >= threshold) == (v_plain >= threshold), (site, step)
        if early:
            assert v_fast < threshold and v_fast >= v_plain
        else:
            assert v_fast == v_plain, (site, step)
        if v_plain >= threshold:
            x, current = prop, v_plain
            accepted += 1
    assert 0 < accepted < len(moves)
    return fast, record


@pytest.mark.parametrize("observation", ["gaussian", "student_t"])
def test_speedups_give_the_plain_decisions(demo_frozen, observation):
    scene, tracks, x0 = demo_frozen
    scene = with_priors(scene, observation=observation, infer_sigma=True, infer_restitution=True)
    # latents: m1_kg, k1, m2_kg, k2, e_collision, log10_sigma_mps
    start = np.r_[x0, 0.1, math.log10(0.08)]
    moves = []
    rng = np.random.default_rng(3)
    for _ in range(4):
        moves += [(5, rng.uniform(-0.15, 0.15)), (5, rng.uniform(-0.15, 0.15)),   # sigma only
                  (0, rng.uniform(-0.05, 0.05)), (2, rng.uniform(-0.05, 0.05)),   # masses only
                  (5, rng.uniform(-0.15, 0.15)),
                  (3, rng.uniform(-0.05, 0.05)), (4, rng.uniform(-0.1, 0.1)),     # k2, e_collision
                  (1, rng.uniform(-0.03, 0.03)), (5, rng.uniform(-0.15, 0.15))]   # k1, sigma
    moves += [(0, 0.4), (5, 0.5), (5, -0.6)]   # far: early stops
    fast, record = _walk(scene, tracks, start, moves, seed=4)
    for (site, _), (prop, steps, early) in zip(moves, record):
        if site == 5:     # sigma only: the physics of the current state, reused whole
            assert steps == 0
        elif site != 1:   # masses, k2, e_collision: resumed where phase A ended
            prefix = fast._prefixes[(prop[1],)]
            assert prefix.first_b is not None and steps <= fast.spf * (fast.n_frames - prefix.first_b)
    stops = [early for _, _, early in record]
    assert any(stops) and not all(stops)


def test_speedups_without_a_target(demo_frozen):
    """No switch: the whole result depends on k1 (and sigma); reused whole for other sigmas."""
    scene, tracks, x0 = demo_frozen
    scene = with_priors(dataclasses.replace(scene, objects=scene.objects[:1]), observation="student_t",
                        infer_sigma=True)
    start = [x0[0], x0[1], math.log10(0.04)]
    moves = [(2, 0.1), (0, 0.05), (2, -0.2), (1, 0.02), (2, 0.05), (0, -0.03), (1, -0.04), (2, 0.02), (2, 0.7)]
    _, record = _walk(scene, tracks, start, moves, seed=0)
    assert all(steps == 0 for (site, _), (_, steps, _) in zip(moves, record) if site != 1)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_infer_with_every_option_matches_the_plain_path(demo_frozen, seed):
    scene, tracks, _ = demo_frozen
    scene = with_priors(scene, observation="student_t", infer_sigma=True, infer_restitution=True)
    cfg = dict(chains=2, sweeps=6, seed=seed, workers=1)
    fast = infer(scene, tracks, RunConfig(speedups=True, **cfg), progress=False)
    plain = infer(scene, tracks, RunConfig(speedups=False, **cfg), progress=False)
    assert fast.names == ("m1_kg", "k1", "m2_kg", "k2", "e_collision", SIGMA)
    assert_same_decisions(fast, plain)
    assert fast.steps < plain.steps


# -- (c) the scene file ----------------------------------------------------------------------------

def round_trip(scene):
    return scene_from_json(json.loads(json.dumps(scene.to_json())))


def test_new_fields_round_trip():
    s = default_scene(20, target="cardboard")
    priors = dataclasses.replace(s.priors, observation="student_t", student_t_dof=2.5, infer_sigma=True,
                                 infer_restitution=True).with_bounds(log10_sigma_mps=(-2.0, -1.0))
    s = dataclasses.replace(s, priors=priors, collision_restitution=0.4)
    t = round_trip(s)
    assert t == s and t.to_json() == s.to_json()
    d = t.to_json()
    assert d["priors"]["observation"] == "student_t" and d["priors"]["student_t_dof"] == 2.5
    # the restitution latent is the default (scene version 2): a file says so only when it is off
    assert d["priors"]["infer_sigma"] is True and "infer_restitution" not in d["priors"]
    assert d["priors"][SIGMA] == [-2.0, -1.0] and d["priors"]["e_collision"] == [0.0, 1.0]
    assert d["collision_restitution"] == 0.4
    assert t.latent_names == ("m1_kg", "k1", "m2_kg", "k2", "e_collision", SIGMA)
    specs = {lat.name: lat for lat in t.latent_specs()}
    assert specs[SIGMA].bounds == (-2.0, -1.0) and specs["e_collision"].bounds == (0.0, 1.0)
    # the defaults: sigma log-uniform over 0.005..0.5 m/s; no target, no e_collision
    on = with_priors(default_scene(20, target=None), infer_sigma=True, infer_restitution=True)
    assert on.latent_names == ("m1_kg", "k1", SIGMA)
    assert on.latent_specs()[-1].bounds == pytest.approx((math.log10(0.005), math.log10(0.5)))
    assert round_trip(on) == on


def test_old_scene_files_load_unchanged():
    d = json.loads((DATA / "scene.json").read_text())
    s = scene_from_json(d)
    p = s.priors
    # a file without the field gets today's default, Student-t (the paper's Gaussian must be named)
    assert (p.observation, p.student_t_dof, p.infer_sigma, p.infer_restitution) == ("student_t", 4.0, False, True)
    assert s.collision_restitution is None
    assert s.latent_names == ("m1_kg", "k1", "m2_kg", "k2", "e_collision")
    assert s.to_json()["priors"] == d["priors"] and "collision_restitution" not in s.to_json()


def test_version_1_scene_files_keep_the_restitution_fixed():
    """A scene file of version 1 (before the restitution latent was the default) means what it
    meant: no e_collision unless it says infer_restitution; written again (version 2) it says
    false, so it reads the same model back."""
    d = json.loads((DATA / "scene.json").read_text())
    d["version"] = 1
    del d["priors"]["e_collision"]
    s = scene_from_json(d)
    assert s.priors.infer_restitution is False and s.latent_names == ("m1_kg", "k1", "m2_kg", "k2")
    out = s.to_json()
    assert out["version"] == 2 and out["priors"]["infer_restitution"] is False and "e_collision" not in out["priors"]
    assert scene_from_json(out) == s
    on = scene_from_json({**d, "priors": {**d["priors"], "infer_restitution": True}})
    assert on.latent_names[-1] == "e_collision"
    # version 2 without the field: the latent; with false: not
    d2 = {**d, "version": 2}
    assert scene_from_json(d2).latent_names[-1] == "e_collision"
    assert scene_from_json({**d2, "priors": {**d["priors"], "infer_restitution": False}}).latent_names[-1] == "k2"


BASE = default_scene(20, target="cardboard").to_json()


@pytest.mark.parametrize("priors, top, field", [
    ({"observation": "cauchy"}, {}, "priors.observation"),
    ({"observation": 1}, {}, "priors.observation"),
    ({"observation": "student_t", "student_t_dof": 0}, {}, "priors.student_t_dof"),
    ({"student_t_dof": -2}, {}, "priors.student_t_dof"),
    ({"student_t_dof": float("inf")}, {}, "priors.student_t_dof"),
    ({"student_t_dof": "four"}, {}, "priors.student_t_dof"),
    ({"infer_sigma": "yes"}, {}, "priors.infer_sigma"),
    ({"infer_sigma": 1}, {}, "priors.infer_sigma"),
    ({"infer_restitution": None}, {}, "priors.infer_restitution"),
    ({"infer_sigma": True, SIGMA: [-1.0, -2.0]}, {}, "priors.log10_sigma_mps"),
    ({"e_collision": [0.0, 1.5]}, {}, "priors.e_collision"),
    ({}, {"collision_restitution": 1.5}, "collision_restitution"),
    ({}, {"collision_restitution": "bouncy"}, "collision_restitution"),
])
def test_bad_values_name_the_field(priors, top, field):
    d = copy.deepcopy(BASE)
    d["priors"].update(priors)
    d.update(top)
    with pytest.raises(SceneError, match=field.replace(".", r"\.")):
        scene_from_json(d)


def test_priors_and_with_values_check_too():
    with pytest.raises(SceneError, match=r"priors\.observation"):
        Priors(observation="laplace")
    with pytest.raises(SceneError, match=r"priors\.student_t_dof"):
        Priors(student_t_dof=0.0)
    with pytest.raises(SceneError, match=r"priors\.infer_sigma"):
        Priors(infer_sigma="true")
    s = default_scene(20, target="cardboard")
    t = s.with_values({"e_collision": 0.7, SIGMA: -1.5, "m1_kg": 0.2})
    assert t.collision_restitution == 0.7 and t.ramp_object.mass_kg == 0.2
    assert dataclasses.replace(t, collision_restitution=None, objects=s.objects) == s   # sigma: no physics
    with pytest.raises(SceneError, match="e_collision"):
        default_scene(20, target=None).with_values({"e_collision": 0.5})
    no_target = dataclasses.replace(s, objects=s.objects[:1]).to_json()
    no_target["collision_restitution"] = 0.5
    with pytest.raises(SceneError, match="collision_restitution"):
        scene_from_json(no_target)


def test_collision_restitution_changes_only_the_collision(demo_frozen):
    """e_collision = 0 is the scene's own (restitution 0) motion bit for bit; a bouncy
    collision pushes the target farther and leaves phase A (the slide) as it was."""
    scene, tracks, x0 = demo_frozen
    base = VelocityLikelihood(scene, tracks, speedups=False)
    lik = VelocityLikelihood(with_priors(scene, infer_restitution=True), tracks, speedups=True)
    m0 = base.motion(x0)
    assert np.array_equal(lik.motion(np.r_[x0, 0.0]).velocity_mps, m0.velocity_mps)
    lik(np.r_[x0, 0.0])
    first_b = lik._prefixes[(x0[1],)].first_b
    bouncy = lik.motion(np.r_[x0, 0.9])
    assert np.array_equal(bouncy.position_m[:, :first_b], m0.position_m[:, :first_b])
    assert bouncy.position_m[1, -1, 0] > m0.position_m[1, -1, 0] + 0.02
    # a simulation of the scene with the value set (what `galileo simulate --set` runs) agrees
    from galileo.scenarios.ramp.physics import Simulator
    sim = Simulator(scene.with_values({"e_collision": 0.9})).run(tracks.n_frames, dict(zip(base.names, x0)))
    assert abs(sim.position_m[1, -1, 0] - bouncy.position_m[1, -1, 0]) < 0.01


# -- (d) sigma recovered ------------------------------------------------------------------------------

def test_inference_recovers_sigma(demo_frozen):
    """Tracks = the model's own motion at known latents + N(0, 0.03^2) per component (the
    draw's RMS is 0.0302 over the 244 components): the posterior of sigma (infer_sigma on)
    covers 0.03 with its 90% interval. The priors are narrowed (the physical latents around
    the truth, sigma to 0.01..0.1 m/s) so that 4 chains x 40 sweeps burn in: a chain that
    starts at a small sigma climbs out slowly (the likelihood is steep there)."""
    scene, template, x0 = demo_frozen
    sigma_true = 0.03
    # the noise below is Gaussian; the physical latents the four of x0 (the restitution fixed)
    scene = with_priors(scene, infer_sigma=True, observation="gaussian", infer_restitution=False)
    scene = dataclasses.replace(scene, priors=scene.priors.with_bounds(
        m1_kg=(0.08, 0.3), k1=(0.15, 0.3), m2_kg=(0.07, 0.25), k2=(0.3, 0.5), log10_sigma_mps=(-2.0, -1.0)))
    lik = VelocityLikelihood(scene, template, speedups=False)
    motion = lik.motion(np.r_[x0, math.log10(sigma_true)])
    rng = np.random.default_rng(0)
    objs = []
    for i, obj in enumerate(lik.scene.objects):
        t = template.by_role(obj.role)
        vel = motion.velocity_mps[i].copy()
        vel[:, [0, 2]] += rng.normal(0.0, sigma_true, (len(vel), 2))
        objs.append(ObjectTrack(t.name, t.role, motion.position_m[i].copy(), vel, np.ones(len(vel), bool), t.shape,
                                t.offset_units, t.detected_by))
    tracks = Tracks(template.fps, objs)
    res = infer(scene, tracks, RunConfig(chains=4, sweeps=40, workers=1, seed=0), progress=False)
    j = res.names.index(SIGMA)
    kept = 10 ** res.samples[:, res.samples.shape[1] // 2:, j].ravel()
    lo, median, hi = np.quantile(kept, [0.05, 0.5, 0.95])
    assert lo <= sigma_true <= hi, (lo, hi)
    assert abs(median - sigma_true) < 0.003, median
