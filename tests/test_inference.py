"""Inference on the demo video: the speed-ups against the plain path, reproducibility across
workers, the saved record, and the `infer` / `predict` command line."""
import json
import math
import subprocess
import sys

import numpy as np
import pytest

from galileo import api
from galileo.results import InferenceResult, load_samples
from galileo.runner import RunConfig as InferenceConfig
from galileo.runner import infer
from galileo.scenarios.ramp.likelihood import VelocityLikelihood
from galileo.scenarios.ramp.scene import scene_from_json

from conftest import DATA, LATENT_NAMES, assert_same_decisions

# the demo's latents as the default model infers them (the collision's restitution a latent)
NAMES = (*LATENT_NAMES, "e_collision")



@pytest.fixture(scope="module")
def demo(demo_frozen):
    """(scene, tracks, true latent vector) of the demo video: the frozen inputs (tests/data),
    since the comparisons below are exact or tight."""
    return demo_frozen


@pytest.fixture(scope="module")
def tracks_file():
    return DATA / "tracks.json"


@pytest.fixture(scope="module")
def small_result(demo):
    scene, tracks, _ = demo
    return infer(scene, tracks, InferenceConfig(chains=2, sweeps=6, seed=0, workers=1), progress=False)


def _no_prefix_reuse(monkeypatch):
    """Make infer's (in-process, workers=1) likelihood keep no prefixes: only early rejection
    and the at-rest cut-off stay on."""
    class NoReuse(VelocityLikelihood):
        def __init__(self, *a, **k):
            super().__init__(*a, **{**k, "cache_size": 0})
    import galileo.scenarios.ramp.likelihood as ramp_likelihood

    monkeypatch.setattr(ramp_likelihood, "VelocityLikelihood", NoReuse)


# -- the speed-ups give the plain path's decisions ----------------------------------------------

def test_early_rejection_and_rest_cutoff_are_bit_exact(demo, monkeypatch):
    """Without prefix reuse the fast path computes the very same numbers, only fewer of them:
    samples, decisions and log-likelihoods are identical bit for bit."""
    scene, tracks, _ = demo
    _no_prefix_reuse(monkeypatch)
    cfg = dict(chains=2, sweeps=6, seed=1, workers=1)
    fast = infer(scene, tracks, InferenceConfig(speedups=True, **cfg), progress=False)
    plain = infer(scene, tracks, InferenceConfig(speedups=False, **cfg), progress=False)
    assert_same_decisions(fast, plain)
    # an early stop reports a bound above the true value (and it was a rejection)
    stopped = fast.proposals["early_stop"]
    assert stopped.sum() >= 5 and not fast.proposals["accepted"][stopped].any()
    assert np.all(fast.proposals["proposal_loglik"][stopped] >= plain.proposals["proposal_loglik"][stopped])
    assert not plain.proposals["early_stop"].any()
    assert fast.steps < 0.8 * plain.steps
    assert 0 < plain.proposals["accepted"].mean() < 1


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4])
def test_all_speedups_give_the_plain_decisions(demo, seed):
    """With prefix reuse on as well: the same samples, decisions and log-likelihoods, bit for
    bit. (Before the model ran the pre-contact phase with unit masses, the masses changed the
    rounding of the pre-contact motion and resumed values differed by up to a nat far from
    the mode; seeds 1, 3 and 4 also made decisions differ when the prefix was keyed on k1
    alone, since the target's friction changes its settling on the ground.)"""
    scene, tracks, _ = demo
    cfg = dict(chains=2, sweeps=6, seed=seed, workers=1)
    fast = infer(scene, tracks, InferenceConfig(speedups=True, **cfg), progress=False)
    plain = infer(scene, tracks, InferenceConfig(speedups=False, **cfg), progress=False)
    assert np.array_equal(fast.proposals["accepted"], plain.proposals["accepted"])
    assert np.array_equal(fast.samples, plain.samples)
    assert np.array_equal(fast.proposals["proposal"], plain.proposals["proposal"])
    assert np.array_equal(fast.logliks, plain.logliks)
    assert fast.steps < plain.steps


def test_prefix_reuse_equals_a_full_simulation(demo):
    """A proposal that keeps k1 resumes from the world saved where phase A ended (the
    objects within one frame's reach); its value equals the plain path's (every frame
    stepped from t = 0) exactly, and its motion within 1e-6 m. Masses and the target's
    friction may all differ from the run that saved the prefix."""
    scene, tracks, x0 = demo
    fast = VelocityLikelihood(scene, tracks, speedups=True)
    plain = VelocityLikelihood(scene, tracks, speedups=False)
    assert fast(x0)[0] == plain(x0)[0]          # 1st: runs phase A, saves the switch frame
    prefix = fast._prefixes[(x0[1],)]
    assert prefix.first_b is not None and 2 <= prefix.first_b < fast.n_frames - 5
    assert prefix.snapshot is not None and len(prefix.terms) == prefix.first_b
    spf = int(round(fast.scene.sim_hz / fast.fps))
    for x in (x0 * [1.0, 1.0, 0.8, 1.0], x0 * [1.3, 1.0, 1.25, 1.0], x0 * [0.2, 1.0, 3.0, 1.0],
              x0 * [1.0, 1.0, 1.0, 0.5], x0 * [1.0, 1.0, 1.0, 2.0]):
        steps0 = fast.steps
        v_fast, early = fast(x)                 # resumes
        assert not early and fast.steps - steps0 <= spf * (fast.n_frames - prefix.first_b)
        assert v_fast == plain(x)[0]            # bit for bit

    x2 = x0 * [1.3, 1.0, 1.25, 0.7]
    pos_f, vel_f, _ = fast._evaluate(fast.values_of(x2), -np.inf, record=True)[2]   # resumes: phase A NaN
    pos_p, vel_p = plain.motion(x2).position_m, plain.motion(x2).velocity_mps
    missing = np.isnan(pos_f).any(axis=(0, 2))
    assert np.array_equal(np.nonzero(missing)[0], np.arange(prefix.first_b))
    assert not np.isnan(pos_p).any()
    assert np.abs(pos_f[:, ~missing] - pos_p[:, ~missing]).max() < 1e-6
    assert np.abs(vel_f[:, ~missing] - vel_p[:, ~missing]).max() < 1e-6
    # the collision happened in the resumed part: the target was pushed
    assert pos_p[1, -1, 0] - pos_p[1, 0, 0] > 0.01


def test_k1_is_read_to_five_decimals_and_a_revisited_cell_resumes(demo):
    """The simulator reads k1 to K1_DECIMALS (5) decimals: two k1 in one cell 1e-5 wide give
    the same value, the next cell another, a k1 of five decimals is used as given (phase A's
    prefix is keyed on it). A proposal to a cell visited before, with dozens of other cells
    visited since (more than the 4 prefixes once kept), resumes where phase A ended instead of
    sliding again, with the plain path's value bit for bit."""
    from galileo.scenarios.ramp.likelihood import K1_DECIMALS, K1_PREFIXES

    assert K1_DECIMALS == 5 and K1_PREFIXES >= 256
    scene, tracks, x0 = demo
    k1 = round(float(x0[1]), 5)
    fast = VelocityLikelihood(scene, tracks, speedups=True)
    plain = VelocityLikelihood(scene, tracks, speedups=False)

    def at(k, masses=(1.0, 1.0, 1.0, 1.0)):
        x = np.array(x0, float)
        x[:4] *= masses
        x[1] = k
        return x

    base = plain(at(k1))[0]
    assert plain(at(k1 + 4.9e-6))[0] == base and plain(at(k1 - 4.9e-6))[0] == base
    assert plain(at(k1 + 5.1e-6))[0] != base        # the next cell: another slide

    assert fast(at(k1))[0] == base
    assert (k1,) in fast._prefixes
    first_b = fast._prefixes[(k1,)].first_b
    for j in range(1, 41):                         # 40 other cells, each a slide of its own
        fast(at(k1 + j * 1e-5))
    spf = int(round(fast.scene.sim_hz / fast.fps))
    x = at(k1 + 3e-6, (1.2, 1.0, 0.9, 1.1))
    steps0 = fast.steps
    assert fast(x)[0] == plain(x)[0]
    assert fast.steps - steps0 <= spf * (fast.n_frames - first_b)   # resumed at the switch, no slide


def _bullet_run(scene, values, n_frames, spf, switch_step=None, after=None, apart=False):
    """One Bullet run of the scene from t = 0 with `values`, driven step by step here (not
    through the likelihood): per frame, positions and velocities (O, F, 3), and at physics
    step `switch_step` the objects' state (`Simulator.snapshot`) and the gap between them (m).

    apart: the two objects do not collide with each other before `switch_step` (each still
    rests on the ramp and the ground). Before they come within reach of each other that
    changes no force, but keeps Bullet from merging them into one simulation island once
    their bounding boxes overlap: a merged island is solved as one batch whose iteration
    count follows the batch's residual, which moves the resting target by ~1e-3 rad/s.
    after: at `switch_step`, a cold restart (`Simulator.resume`) from the objects' state
    there with the values `after`."""
    from galileo.scenarios.ramp.physics import Simulator
    from galileo.sim.bullet import pb

    sim = Simulator(scene)
    w = sim.reset(values)
    cid, bodies = w.cid, w.bodies
    pos, vel = np.empty((2, len(bodies), n_frames, 3))
    snap = gap = None
    try:
        if apart:
            pb.setCollisionFilterPair(bodies[0], bodies[1], -1, -1, 0, physicsClientId=cid)
        for k in range((n_frames - 1) * spf + 1):
            if k:
                pb.stepSimulation(physicsClientId=cid)
            if k == switch_step:
                snap = sim.snapshot()
                gap = min(c[8] for c in pb.getClosestPoints(bodies[0], bodies[1], 1.0, physicsClientId=cid))
                if after is not None:
                    sim.resume(snap, after)
                if apart:
                    pb.setCollisionFilterPair(bodies[0], bodies[1], -1, -1, 1, physicsClientId=cid)
            if k % spf == 0:
                for i, b in enumerate(bodies):
                    pos[i, k // spf] = pb.getBasePositionAndOrientation(b, physicsClientId=cid)[0]
                    vel[i, k // spf] = pb.getBaseVelocity(b, physicsClientId=cid)[0]
    finally:  # the world is shared with every later simulation in this process
        pb.setCollisionFilterPair(bodies[0], bodies[1], -1, -1, 1, physicsClientId=cid)
    return pos, vel, snap, gap


def _max_abs(a, b) -> float:
    return float(np.abs(np.asarray(a) - np.asarray(b)).max())


def test_phase_a_values_change_nothing_against_bullet(demo):
    """The likelihood's two phases against Bullet runs driven step by step here, on the
    frozen demo inputs, for the truth and a latent vector far from it.

    1. Exactly: the likelihood's motion is, bit for bit in every frame the rest rule does
       not hold still, one Bullet run from t = 0 with phase A's values as documented (unit
       masses, the target's friction PHASE_A_TARGET_FRICTION, the proposal's k1; the two
       objects kept from colliding with each other), restarted cold (`Simulator.resume`)
       at the physics step where phase A ended with the proposal's values. This checks the
       bookkeeping: the target simulated alone, the switch found step by step, the snapshot.
    2. Phase A's values change nothing before the objects meet: the same run with the
       proposal's own masses and target friction from t = 0 differs, up to the switch, only
       by rounding (sliding is mass-independent and the target rests; with its friction
       below ~0.27 it slips ~1e-5 m while settling, and both vectors here have k2 >= 0.39,
       like the truth: PHASE_A_TARGET_FRICTION = 0.05 fails this). Not bit for bit: the
       masses enter the solver's arithmetic. Bound: one rounding (eps, relative) per physics
       step, accumulated linearly over the steps, at the scale of the values compared.
    3. After the switch a collision amplifies last-bit differences (in one of eight random
       proposals around the truth, latents scaled by 0.5-1.5, to 0.3 m/s), so the own-values run (cold restart at the
       same step) is bounded by what last bits do there: twice the largest effect of six
       one-ulp nudges (np.nextafter) of phase A's inputs (its unit masses, k1) on the
       likelihood's own run, each nudged run being another last-bit variant of it (the
       factor 2: six nudges sample the effect of last bits, they need not find its maximum).
    The rest rule holds positions still (within 0.5 mm), and without the cold restart and
    with the objects in one island from t = 0 a run moves by a few millimetres at most, the
    size of Bullet's solver tolerance (10 against 5 iterations moves a run by ~1 mm)."""
    import galileo.scenarios.ramp.likelihood as model

    scene, tracks, x0 = demo
    plain = VelocityLikelihood(scene, tracks, speedups=False)
    fast = VelocityLikelihood(scene, tracks, speedups=True)
    spf, n = plain.spf, plain.n_frames
    eps = np.finfo(float).eps
    for x in (x0, x0 * [2.0, 0.9, 0.5, 1.5]):
        m = plain.motion(x)
        pos_l, vel_l = m.position_m, m.velocity_mps
        fast(x)
        prefix = fast._prefixes[(x[1],)]
        first_b = prefix.first_b
        assert first_b is not None and 2 <= first_b < n - 5
        switch = (first_b - 1) * spf + prefix.substeps
        values = plain.values_of(x)
        phase_a = {"m1_kg": model.UNIT_MASS_KG, "m2_kg": model.UNIT_MASS_KG, "k1": values["k1"],
                   "k2": model.PHASE_A_TARGET_FRICTION}
        moving = ~np.all(vel_l == 0.0, axis=(0, 2))   # frames the rest rule does not hold still
        assert moving[1:first_b].all() and moving[first_b:].any()   # (frame 0: at rest, v = 0)

        # 1. bit for bit
        pos_a, vel_a, _, gap = _bullet_run(plain.scene, phase_a, n, spf, switch, after=values, apart=True)
        assert np.array_equal(pos_a[:, moving], pos_l[:, moving])
        assert np.array_equal(vel_a[:, moving], vel_l[:, moving])
        # rest rule: Bullet's relaxing contacts (speed halving per frame from < 1 mm/s) and the
        # slow yaw drift after a collision (~1e-4 m/s over the rest of the video) stay < 0.5 mm
        assert _max_abs(pos_a, pos_l) < 5e-4
        # the collision happens in phase B: apart at the switch, the target at rest until then,
        # pushed after it
        assert gap > 0
        assert _max_abs(pos_l[1, :first_b], pos_l[1, 0]) < 1e-4
        assert pos_l[1, -1, 0] - pos_l[1, 0, 0] > 0.01

        # 2. the proposal's own values before the switch: rounding only
        pos_o, vel_o, _, _ = _bullet_run(plain.scene, values, n, spf, switch, after=values, apart=True)
        pre = slice(0, first_b)
        assert _max_abs(pos_o[:, pre], pos_a[:, pre]) <= switch * eps * np.abs(pos_a[:, pre]).max()
        assert _max_abs(vel_o[:, pre], vel_a[:, pre]) <= switch * eps * np.abs(vel_a[:, pre]).max()

        # 3. after the switch: within twice what one-ulp nudges of phase A's inputs do (on the
        # frozen inputs the truth's own-values run is 1.6e-4 m/s off, its nudged runs as much;
        # the other vector's 1.5e-14 m/s off, its nudged runs up to 2.4e-2 m/s)
        post = moving.copy()
        post[:first_b] = False
        amp_p = amp_v = 0.0
        for key in ("m1_kg", "m2_kg", "k1"):
            for toward in (-np.inf, np.inf):
                nudged = {**phase_a, key: float(np.nextafter(phase_a[key], toward))}
                after = {**values, "k1": nudged["k1"]}
                pos_n, vel_n, _, _ = _bullet_run(plain.scene, nudged, n, spf, switch, after=after, apart=True)
                amp_p = max(amp_p, _max_abs(pos_n[:, post], pos_l[:, post]))
                amp_v = max(amp_v, _max_abs(vel_n[:, post], vel_l[:, post]))
        assert _max_abs(pos_o[:, post], pos_l[:, post]) <= 2 * amp_p
        assert _max_abs(vel_o[:, post], vel_l[:, post]) <= 2 * amp_v

        # one island and warm contacts all the way: Bullet's solver tolerance
        pos_u, _, _, _ = _bullet_run(plain.scene, values, n, spf)
        assert _max_abs(pos_u, pos_l) < 3e-3


@pytest.mark.parametrize("in_between", ["other scene", "in-process infer"])
def test_saved_prefixes_survive_a_rebuilt_world(demo, in_between):
    """Prefixes used to be pybullet saveState ids, which died with the world when another
    scene was simulated in the process (resuming failed, or silently restored another
    world's state, 21 nats off). They are snapshots of plain numbers now: after another
    scene rebuilt the world, or an in-process `infer` on the same scene used it, resuming
    still gives the plain path's value."""
    import dataclasses

    from galileo.scenarios.ramp.physics import Simulator

    scene, tracks, x0 = demo
    fast = VelocityLikelihood(scene, tracks, speedups=True)
    plain = VelocityLikelihood(scene, tracks, speedups=False)
    x2 = x0 * [1.0, 1.0, 1.25, 1.0]
    want = plain(x2)[0]
    fast(x0)
    fast(x0 * [1.0, 1.0, 0.8, 1.0])
    assert fast._prefixes[(x0[1],)].snapshot is not None
    first_b = fast._prefixes[(x0[1],)].first_b
    spf = int(round(fast.scene.sim_hz / fast.fps))
    if in_between == "other scene":
        Simulator(dataclasses.replace(scene, objects=scene.objects[:1])).run(10)
    else:  # same scene, same process: the world is shared with the chains
        infer(scene, tracks, InferenceConfig(chains=1, sweeps=3, seed=0, workers=1), progress=False)
    steps0 = fast.steps
    assert fast(x2)[0] == want
    assert fast.steps - steps0 <= spf * (fast.n_frames - first_b)   # resumed, not rerun


def test_rest_cutoff_takes_fewer_steps_with_the_same_value(demo):
    scene, tracks, x0 = demo
    # a heavy, rough target stops the block: the world comes to rest before the video ends
    for k1 in (0.15, 0.2, 0.1, 0.25):
        x = np.array([x0[0], k1, 1.0, 1.0])
        plain = VelocityLikelihood(scene, tracks, speedups=False)
        m = plain.motion(x)
        pos, vel = m.position_m, m.velocity_mps
        still = np.all(vel == 0.0, axis=(0, 2))
        rest = next((f for f in range(1, plain.n_frames) if still[f:].all()), None)
        if rest is not None and rest < plain.n_frames - 5 and pos[0, rest, 0] - pos[0, 0, 0] > 0.2:
            break
    else:
        pytest.fail("no candidate latent vector comes to rest before the end of the video")
    spf = int(round(plain.scene.sim_hz / plain.fps))
    fast = VelocityLikelihood(scene, tracks, speedups=True)
    plain = VelocityLikelihood(scene, tracks, speedups=False)
    v_fast, v_plain = fast(x), plain(x)
    assert v_fast == v_plain                            # exactly: (value, stopped_early=False)
    # both step up to the rest frame (and back to the frame before first contact, if any);
    # only the plain path steps through the frames after it
    assert plain.steps - fast.steps == spf * (plain.n_frames - 1 - rest)


# -- reproducibility -------------------------------------------------------------------------------

def test_same_seed_same_result_for_one_and_two_workers(demo):
    scene, tracks, _ = demo
    one = infer(scene, tracks, InferenceConfig(chains=2, sweeps=4, seed=5, workers=1), progress=False)
    two = infer(scene, tracks, InferenceConfig(chains=2, sweeps=4, seed=5, workers=2), progress=False)
    assert one.timing_s["workers"] == 1 and two.timing_s["workers"] == 2
    assert np.array_equal(one.samples, two.samples)
    assert np.array_equal(one.logliks, two.logliks)
    assert np.array_equal(one.starts, two.starts)
    assert one.proposals.keys() == two.proposals.keys()
    for k in one.proposals:
        assert np.array_equal(one.proposals[k], two.proposals[k], equal_nan=k == "width"), k
    # (physics steps may differ: each process keeps its own cache of phase-A prefixes, which
    # saves work without changing a single decision)
    # and another seed gives other chains
    other = infer(scene, tracks, InferenceConfig(chains=2, sweeps=1, seed=6, workers=1), progress=False)
    assert not np.array_equal(other.starts, one.starts)


# -- the saved record ----------------------------------------------------------------------------------

def test_save_writes_documented_result_and_npz(small_result: InferenceResult, tmp_path):
    res = small_result
    path = tmp_path / "result.json"
    npz = res.save(path)
    assert npz == tmp_path / "result.samples.npz" and npz.exists()
    d = json.loads(path.read_text())
    assert d["samples_file"] == "result.samples.npz"
    assert set(d["map"]) == set(NAMES) == set(d["latents"])
    c, s = res.map_index
    assert d["map"] == pytest.approx(dict(zip(NAMES, res.samples[c, s].tolist())))
    assert d["map_loglik"] == pytest.approx(res.logliks.max())
    assert d["mass_ratio"] == pytest.approx(d["map"]["m1_kg"] / d["map"]["m2_kg"])
    kept = res.samples[:, 3:]  # second half of 6 sweeps
    for j, n in enumerate(NAMES):
        p = d["posterior"][n]
        assert set(p) == {"mean", "sd", "q05", "q25", "q50", "q75", "q95"}
        assert p["q05"] <= p["q50"] <= p["q95"]
        assert p["mean"] == pytest.approx(kept[..., j].mean())
        assert p["q50"] == pytest.approx(np.median(kept[..., j]))
    diag = d["diagnostics"]
    for k in ("r_hat", "ess", "ess_tail"):
        assert set(diag[k]) == set(NAMES), k
    assert set(diag["acceptance"]) == set(NAMES) | {
        "k1_from_acceleration_move", "mass_ray_move", "mass_ratio_move", "joint_rw_move"}
    for j, n in enumerate(NAMES):
        sel = res.proposals["site"] == j
        assert diag["acceptance"][n] == pytest.approx(res.proposals["accepted"][sel].mean())
    assert diag["physics_steps"] == res.steps > 0
    assert d["timing_s"]["wall"] > 0 and d["timing_s"]["workers"] == 1
    assert d["config"]["chains"] == 2 and d["config"]["sweeps"] == 6 and d["config"]["speedups"] is True
    assert d["scene"]["objects"][0]["shape"]["type"] == res.scene.objects[0].shape.type
    assert scene_from_json(d["scene"]).latent_names == NAMES  # the scene round-trips

    with np.load(npz, allow_pickle=False) as z:  # no pickled objects inside
        files = set(z.files)
        assert {"names", "samples", "logliks", "starts"} <= files
        assert [str(x) for x in z["names"]] == list(NAMES)


def test_saved_run_equals_live_run(small_result: InferenceResult, tmp_path):
    res = small_result
    npz = res.save(tmp_path / "r.json")
    rec = load_samples(npz)
    assert np.array_equal(rec["samples"], res.samples)
    assert np.array_equal(rec["logliks"], res.logliks)
    assert np.array_equal(rec["starts"], res.starts)
    assert set(k for k in rec if k.startswith("proposal_")) == {f"proposal_{k}" for k in res.proposals}
    for k, v in res.proposals.items():
        assert rec[f"proposal_{k}"].dtype == v.dtype
        assert np.array_equal(rec[f"proposal_{k}"], v, equal_nan=v.dtype.kind == "f"), k
    # one proposal per latent per sweep, then one per joint move (the ramp's three and the joint walk)
    assert res.samples.shape == (2, 6, len(NAMES)) and res.proposals["accepted"].shape == (2, 6 * (len(NAMES) + 4))


def test_load_samples_rejects_garbage(tmp_path):
    from galileo.errors import GalileoError

    bad = tmp_path / "bad.samples.npz"
    bad.write_bytes(b"not a zip file")
    with pytest.raises(GalileoError, match="cannot read sample record"):
        load_samples(bad)


# -- command line --------------------------------------------------------------------------------------

def run_cli(*args):
    p = subprocess.run([sys.executable, "-m", "galileo", *map(str, args)], capture_output=True, text=True)
    return p.returncode, p.stdout, p.stderr


def one_line_error(rc, err, needle=""):
    lines = err.strip().splitlines()
    return rc == 2 and len(lines) == 1 and lines[0].startswith("galileo: error:") and needle in lines[0]


@pytest.fixture(scope="module")
def cli_result(demo_dir, tracks_file, tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "result.json"
    rc, stdout, err = run_cli("infer", demo_dir / "video.mp4", "--scene", DATA / "scene.json",
                              "--tracks", tracks_file, "--chains", 2, "--sweeps", 2, "--workers", 1,
                              "--out", out, "--quiet")
    assert rc == 0, err
    return out, stdout


def test_cli_infer_writes_result(cli_result):
    out, stdout = cli_result
    d = json.loads(out.read_text())
    assert d["config"]["chains"] == 2 and d["config"]["sweeps"] == 2
    assert set(d["map"]) == set(NAMES)
    assert (out.parent / d["samples_file"]).exists()
    assert load_samples(out.parent / d["samples_file"])["samples"].shape == (2, 2, len(NAMES))
    # the headline leads with what a collision identifies, and says what it does not
    assert stdout.startswith("MAP: k1 = ") and "m1/m2 = " in stdout and f"wrote {out}" in stdout
    assert "not identified: m1_kg, m2_kg: only the ratio" in stdout and "m1_kg = " not in stdout


def test_cli_infer_until_converged_says_which_budget_stopped_it(demo_dir, tracks_file, tmp_path):
    out = tmp_path / "r.json"
    rc, stdout, err = run_cli("infer", demo_dir / "video.mp4", "--scene", DATA / "scene.json", "--tracks", tracks_file,
                              "--chains", 2, "--sweeps", 4, "--until-rhat", "1.000001", "--max-sweeps", 6,
                              "--workers", 1, "--out", out, "--quiet")
    assert rc == 0, err
    assert "NOT converged after 6 sweeps: the sweep budget (6) is spent" in stdout
    assert json.loads(out.read_text())["stopped"] == "max_sweeps"
    # which moves ran: a warm-up of 4 sweeps fits nothing, so the default moves; with 20 the ramp's
    # move set for running until converged, the fitted one
    assert "; moves default)" in stdout
    rc, stdout, err = run_cli("infer", demo_dir / "video.mp4", "--scene", DATA / "scene.json", "--tracks", tracks_file,
                              "--chains", 2, "--sweeps", 20, "--until-rhat", "1.000001", "--max-sweeps", 22,
                              "--workers", 1, "--out", out, "--quiet")
    assert rc == 0, err
    assert "NOT converged after 22 sweeps" in stdout and "; moves fitted)" in stdout
    assert json.loads(out.read_text())["config"]["moves"]["set"] == "fitted"


def test_the_cli_help_states_the_apis_default_budget():
    """`galileo infer --help` writes the default wall-clock budget as a literal (the CLI does not
    import the API to parse): it must be the API's."""
    import argparse

    from galileo.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices["infer"]
    act = next(a for a in sub._actions if "--max-seconds" in a.option_strings)
    assert f"(default: {api.DEFAULT_MAX_SECONDS:g})" in act.help


def test_cli_infer_runs_until_converged_by_default_and_sweeps_alone_is_a_fixed_run(demo_dir, tracks_file, tmp_path):
    out = tmp_path / "r.json"
    base = ("infer", demo_dir / "video.mp4", "--scene", DATA / "scene.json", "--tracks", tracks_file, "--chains", 2,
            "--workers", 1, "--out", out, "--quiet")
    # no --sweeps: the protocol's first block (75), then on towards R-hat <= 1.01 within the budgets
    rc, stdout, err = run_cli(*base, "--max-sweeps", 85)
    assert rc == 0, err
    d = json.loads(out.read_text())
    assert d["config"]["until_rhat"] == 1.01 and d["config"]["max_seconds"] == api.DEFAULT_MAX_SECONDS == 300.0
    assert d["config"]["moves"]["set"] == "fitted" and "; moves fitted)" in stdout
    assert d["stopped"] in ("converged", "max_sweeps") and 75 <= d["diagnostics"]["sweeps"] <= 85
    # --sweeps alone: exactly that many sweeps, the default moves, no target
    rc, stdout, err = run_cli(*base, "--sweeps", 3)
    assert rc == 0, err
    d = json.loads(out.read_text())
    assert d["config"]["until_rhat"] is None and d["diagnostics"]["sweeps"] == 3 and d["stopped"] is None
    assert d["config"]["moves"]["set"] == "default"
    # a budget for a fixed run is refused, naming both flags
    for flag, value in (("--max-seconds", 5), ("--max-sweeps", 9)):
        rc, _, err = run_cli(*base, "--sweeps", 3, flag, value)
        assert one_line_error(rc, err, flag) and "--sweeps 3 alone is a fixed run" in err, err


@pytest.mark.parametrize("change, needle", [
    ({"--tracks": "missing.json"}, "tracks file not found"),
    ({"--chains": "0"}, "--chains"),
    ({"--sweeps": "0"}, "--sweeps"),
    ({"--sigma": "-1"}, "--sigma"),
])
def test_cli_infer_bad_input_is_one_line_exit_2(demo_dir, tracks_file, tmp_path, change, needle):
    opts = {"--scene": str(DATA / "scene.json"), "--tracks": str(tracks_file), "--chains": "2",
            "--sweeps": "2", "--workers": "1", "--out": str(tmp_path / "r.json")}
    opts.update({k: (str(tmp_path / v) if k == "--tracks" else v) for k, v in change.items()})
    rc, _, err = run_cli("infer", demo_dir / "video.mp4", *[x for kv in opts.items() for x in kv], "--quiet")
    assert one_line_error(rc, err, needle), (rc, err)
    assert not (tmp_path / "r.json").exists()


def test_cli_predict_will_it_move(cli_result):
    out, _ = cli_result
    rc, stdout, err = run_cli("predict", "--result", out, "--angle-deg", 10)
    assert rc == 0, err
    d = json.loads(stdout)
    w = d["will_it_move"]
    assert w["angle_deg"] == 10 and isinstance(w["moves"], bool)
    assert w["tan_angle"] == pytest.approx(math.tan(math.radians(10)))
    assert w["k1_map"] == pytest.approx(json.loads(out.read_text())["map"]["k1"])
    assert 0.0 <= w["posterior_share_moving"] <= 1.0
    # Coulomb friction: it slides iff k1 < tan(angle) (unless right at the edge)
    if abs(w["k1_map"] - w["tan_angle"]) > 0.02:
        assert w["moves"] == (w["k1_map"] < w["tan_angle"])


@pytest.mark.parametrize("content, needle", [
    (None, "not found"),
    ("{not json", "not valid JSON"),
    ('{"map": {"k1": 0.2}}', "not a galileo result file"),
])
def test_cli_predict_bad_result_is_one_line_exit_2(tmp_path, content, needle):
    path = tmp_path / "result.json"
    if content is not None:
        path.write_text(content)
    rc, stdout, err = run_cli("predict", "--result", path, "--angle-deg", 10)
    assert one_line_error(rc, err, needle), (rc, err)
    assert stdout == ""
