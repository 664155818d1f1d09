"""Problems over several videos and latents fixed at known values (galileo.joint).

Truth here is independent of the joining code: each video's own likelihood, built alone; the
ramp's friction, which the block's acceleration a = g (sin t - k cos t) fixes in each video; a
known reference mass, which makes the other mass (seen only through the ratio of a collision)
identifiable."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from galileo import registry
from galileo.errors import GalileoError
from galileo.joint import JointScene, split_name, video_name
from galileo.runner import RunConfig, infer
from galileo.scenarios.ramp.scene import default_scene

RAMP = registry.get("ramp")
K1 = 0.1     # slides at 10 degrees too: tan(10 deg) = 0.176
M1 = 0.3


def _observed(angle_deg: float, seed: int, target: str = "none", **values):
    """A ramp scene at `angle_deg` and tracks simulated at the truth with the likelihood's own noise."""
    scene = default_scene(angle_deg, mass_kg=M1, friction=K1, target=target)
    truth = {"m1_kg": M1, "k1": K1, **values}
    tracks = RAMP.synthetic.tracks(scene, truth, np.random.default_rng(seed), RAMP.noise.default)
    return scene, tracks


@pytest.fixture(scope="module")
def two_ramps():
    return [_observed(20.0, 1), _observed(10.0, 2)]


def test_names_per_video_shared_and_fixed(two_ramps):
    scenes = [s for s, _ in two_ramps]
    tracks = [t for _, t in two_ramps]
    shared = registry.problem(scenes, share=["k1"])
    assert isinstance(shared, JointScene)
    scen = registry.of(shared)
    assert [lat.name for lat in scen.latents(scen.prepare(shared, tracks))] == ["m1_kg@1", "k1", "m1_kg@2"]
    fixed = registry.problem(scenes, share=["k1"], fixed={"m1_kg@2": 0.3})
    assert [lat.name for lat in scen.latents(scen.prepare(fixed, tracks))] == ["m1_kg@1", "k1"]
    everywhere = registry.problem(scenes, fixed={"m1_kg": 0.3})
    assert [lat.name for lat in scen.latents(scen.prepare(everywhere, tracks))] == ["k1@1", "k1@2"]
    # one video, nothing to join: the scene itself
    one = registry.problem(scenes[:1], share=["k1"])
    assert not isinstance(one, JointScene) and one == scenes[0]
    assert split_name("m1_kg@2") == ("m1_kg", 1) and split_name("k1") == ("k1", None)
    assert video_name("k1", 0, 1) == "k1" and video_name("k1", 1, 2) == "k1@2"


def test_the_joint_loglik_is_each_videos_own_at_its_values(two_ramps):
    """The sum of the two videos' likelihoods, each built alone, at the values the layout gives them."""
    scenes = [s for s, _ in two_ramps]
    tracks = [t for _, t in two_ramps]
    prob = registry.problem(scenes, share=["k1"], fixed={"m1_kg@2": 0.25})
    scen = registry.of(prob)
    lik = scen.likelihood(scen.prepare(prob, tracks), tracks, RAMP.noise.default)
    alone = [RAMP.likelihood(RAMP.prepare(s, t), t, RAMP.noise.default) for s, t in two_ramps]
    rng = np.random.default_rng(0)
    for _ in range(8):
        m1, k1 = rng.uniform(0.05, 1.0), rng.uniform(0.0, 0.3)
        want = alone[0]([m1, k1])[0] + alone[1]([0.25, k1])[0]
        assert lik([m1, k1])[0] == pytest.approx(want, rel=1e-12, abs=1e-9)


def test_early_rejection_makes_the_same_decisions(two_ramps):
    """With a threshold the joint likelihood may stop early; it must never change an MH decision."""
    scenes = [s for s, _ in two_ramps]
    tracks = [t for _, t in two_ramps]
    prob = registry.problem(scenes, share=["k1"])
    scen = registry.of(prob)
    prepared = scen.prepare(prob, tracks)
    # two likelihoods: one evaluates in full, the other with thresholds (a likelihood keeps the
    # motions it evaluated whole, and would answer a repeated position from them)
    lik, plain = (scen.likelihood(prepared, tracks, RAMP.noise.default) for _ in range(2))
    rng = np.random.default_rng(1)
    truth = plain([M1, K1, M1])[0]
    stopped = 0
    for _ in range(20):
        pos = [rng.uniform(0.05, 1.0), rng.uniform(0.0, 0.3), rng.uniform(0.05, 1.0)]
        full, _ = plain(pos)
        threshold = truth - rng.exponential(50.0)
        value, early = lik(pos, threshold)
        assert (value >= threshold) == (full >= threshold)
        if early:
            stopped += 1
            assert value < threshold and value >= full - 1e-9
        else:
            assert value == pytest.approx(full, rel=1e-12)
    assert stopped > 0   # the speed-up is used


K_GRID = np.linspace(0.09, 0.11, 401)   # k1 around the truth, finer than any video's posterior SD


def _grid_posterior(logliks: np.ndarray) -> tuple[float, float]:
    """(mean, SD) of k1 under a flat prior from log-likelihoods on K_GRID."""
    w = np.exp(logliks - logliks.max())
    w /= w.sum()
    mean = float((w * K_GRID).sum())
    return mean, math.sqrt(float((w * (K_GRID - mean) ** 2).sum()))


def test_one_friction_shared_by_a_20_and_a_10_degree_video(two_ramps):
    """Both videos measure the same k1 (the block's acceleration a = g (sin t - k1 cos t) in each):
    the joint posterior is narrower than either video's alone, as two independent measurements'
    are (for Gaussians 1/sd^2 adds), and the chains find it."""
    alone = [RAMP.likelihood(RAMP.prepare(s, t), t, RAMP.noise.default) for s, t in two_ramps]
    ll = np.array([[lik([M1, k])[0] for k in K_GRID] for lik in alone])
    (_, s1), (_, s2), (mj, sj) = _grid_posterior(ll[0]), _grid_posterior(ll[1]), _grid_posterior(ll.sum(axis=0))
    assert sj < min(s1, s2)
    # no information lost: at least as narrow as two independent Gaussian measurements would
    # give (the Student-t likelihoods' joint is a little narrower still)
    assert sj < 1.1 / math.sqrt(1 / s1 ** 2 + 1 / s2 ** 2)
    assert abs(mj - K1) < 4 * sj       # the noise the videos were made with moves it this little
    scenes = [s for s, _ in two_ramps]
    res = infer(registry.problem(scenes, share=["k1"]), [t for _, t in two_ramps],
                RunConfig(chains=4, sweeps=60, seed=0, workers=1), progress=False)
    assert res.names == ("m1_kg@1", "k1", "m1_kg@2")
    k = res.kept()[..., 1].ravel()
    # the chains sit on the joint mode (8 data and chain seeds: within 0.0012 of the truth)
    assert abs(float(np.median(k)) - mj) < 0.01
    doc = res.to_json()
    assert doc["latents"] == ["m1_kg@1", "k1", "m1_kg@2"] and doc["scene"]["share"] == ["k1"]


def test_a_fixed_reference_mass_identifies_the_other_mass():
    """A collision shows only the ratio m1/m2: every force in the world scales with mass (Newton),
    so doubling both masses changes no motion. With the target's mass known, m1 is known too."""
    m2 = 0.15
    scene, tracks = _observed(20.0, 3, target="cardboard", m2_kg=m2, k2=0.35)
    lik = RAMP.likelihood(RAMP.prepare(scene, tracks), tracks, RAMP.noise.default)
    assert lik.names == ("m1_kg", "k1", "m2_kg", "k2", "e_collision")   # (the objects' restitution: 0)
    at_truth = lik([M1, K1, m2, 0.35, 0.0])[0]
    for f in (0.5, 2.0, 3.0):
        assert lik([f * M1, K1, f * m2, 0.35, 0.0])[0] == pytest.approx(at_truth, abs=1e-6)
    # (the collision's restitution fixed too, at the scene's 0: the masses are the question here)
    prob = registry.problem([scene], fixed={"m2_kg": m2, "e_collision": 0.0})
    scen = registry.of(prob)
    fixed = scen.likelihood(scen.prepare(prob, tracks), tracks, RAMP.noise.default)
    assert fixed.names == ("m1_kg", "k1", "k2")
    grid = np.linspace(0.5 * M1, 2.0 * M1, 61)
    profile = np.array([fixed([m, K1, 0.35])[0] for m in grid])
    assert abs(grid[int(np.argmax(profile))] - M1) <= 0.05 * M1
    assert profile.max() - fixed([2 * M1, K1, 0.35])[0] > 100      # nats: the ridge is gone
    res = infer(prob, tracks, RunConfig(chains=4, sweeps=50, seed=0, workers=1), progress=False)
    assert res.names == ("m1_kg", "k1", "k2")
    # the chains' best sample: within 40% (8 data and chain seeds gave -21% to +20%); unfixed, the
    # ridge lets it lie anywhere from 0 to the prior's 1 kg
    assert res.map["m1_kg"] == pytest.approx(M1, rel=0.4)
    assert res.to_json()["scene"]["fixed"] == {"m2_kg": m2, "e_collision": 0.0}


def test_bad_layouts_are_one_line_errors(two_ramps):
    scenes = [s for s, _ in two_ramps]
    tracks = [t for _, t in two_ramps]

    def latents(**kw):
        prob = registry.problem(scenes, **kw)
        scen = registry.of(prob)
        return scen.latents(scen.prepare(prob, tracks))

    with pytest.raises(GalileoError, match="--share m9: no video has that latent"):
        latents(share=["m9"])
    with pytest.raises(GalileoError, match="fixed m9: no such latent"):
        latents(fixed={"m9": 1.0})
    with pytest.raises(GalileoError, match="fixed k1@3: there are 2 videos"):
        latents(fixed={"k1@3": 0.1})
    with pytest.raises(GalileoError, match="every latent is fixed"):
        latents(fixed={"k1": 0.1, "m1_kg": 0.3})
    with pytest.raises(GalileoError, match="outside its limits"):
        latents(fixed={"m1_kg": -1.0})
    with pytest.raises(GalileoError, match="2 video"):
        registry.of(registry.problem(scenes)).prepare(registry.problem(scenes), tracks[:1])


def test_a_scene_files_fixed_section_round_trips(tmp_path):
    scene = default_scene(20.0, target="cardboard")
    d = scene.to_json()
    d["fixed"] = {"m2_kg": 0.15}
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(d))
    loaded = registry.load_scene(path)
    assert isinstance(loaded, JointScene) and loaded.fixed == {"m2_kg": 0.15}
    assert registry.scene_from_json(loaded.to_json()) == loaded
    d["fixed"] = {"m2_kg": "heavy"}
    path.write_text(json.dumps(d))
    with pytest.raises(GalileoError, match="fixed.m2_kg: expected a finite number"):
        registry.load_scene(path)


def test_a_problems_session_reopens_and_the_viewer_shows_each_video(two_ramps, tmp_path):
    """A session over two videos saves both tracks and the problem, reopens as it was and goes on
    as an uninterrupted one; the viewer shows either video with the motion that video scored."""
    from conftest import free_port
    from ui.controller import Controller
    from ui.viewer import Viewer

    scenes = [s for s, _ in two_ramps]
    tracks = [t for _, t in two_ramps]
    prob = registry.problem(scenes, share=["k1"])
    ctrl = Controller(prob, tracks, chains=2, seed=0, workers=1, session_dir=tmp_path / "a")
    ctrl.run_sweeps(2)
    ctrl.close()
    again = Controller.load(tmp_path / "a", workers=1)
    whole = Controller(prob, tracks, chains=2, seed=0, workers=1, session_dir=tmp_path / "b")
    videos = [np.zeros((t.n_frames, 48, 64, 3), np.uint8) for t in tracks]
    viewer = None
    try:
        assert isinstance(again.scene, JointScene) and again.names == ("m1_kg@1", "k1", "m1_kg@2")
        again.run_sweeps(1)
        whole.run_sweeps(3)
        for c in whole.chain_ids():
            np.testing.assert_array_equal(again.samples(c), whole.samples(c))
        viewer = Viewer(again, again.likelihood_scene, again.tracks, videos, port=free_port())
        assert viewer.video_dropdown is not None
        for v in (1, 0):
            viewer.show_video(v)
            viewer.select_sample(1, 2)
            viewer.set_frame(20)
            m1, k1, m2 = again.samples(1)[2]
            scene, t = two_ramps[v]
            own = RAMP.likelihood(RAMP.prepare(scene, t), t, again.settings.noise).motion([(m1, m2)[v], k1])
            np.testing.assert_allclose(viewer.object_handles[0].position, own.position_m[0, 20], atol=1e-9)
            assert viewer.tracks is tracks[v] or viewer.tracks.to_json() == t.to_json()
    finally:
        if viewer is not None:
            viewer.close()
        again.close()
        whole.close()


@pytest.mark.parametrize("extra, message", [
    (["a.mp4", "b.mp4", "--scene", "A"], "2 video(s) need 2 scene file(s)"),
    (["a.mp4", "--scene", "A", "--share", "k1"], "--share is for several videos"),
    (["a.mp4", "b.mp4", "--scene", "A", "B", "--share", "k9"], "--share k9: no video has that latent"),
    (["a.mp4", "--scene", "A", "--fix", "m1_kg"], "--fix m1_kg: expected NAME=VALUE"),
    (["a.mp4", "--scene", "A", "--fix", "m1_kg=nan"], "--fix m1_kg=nan: expected NAME=VALUE"),
    (["a.mp4", "--scene", "A", "--fix", "m1_kg=0.3", "--fix", "k1=0.1"], "every latent is fixed"),
    (["a.mp4", "b.mp4", "--scene", "A", "B", "--tracks", "t.json"], "--tracks: one tracks file per video"),
])
def test_infer_refuses_a_bad_problem_in_one_line_before_tracking(extra, message, tmp_path, capsys):
    from galileo.cli import main

    for name in ("A", "B"):
        default_scene(20.0, target="none").save(tmp_path / f"{name}.json")
    files = {"A": "A.json", "B": "B.json", "a.mp4": "a.mp4", "b.mp4": "b.mp4", "t.json": "t.json"}
    args = [str(tmp_path / files[a]) if a in files else a for a in extra]
    assert main(["infer", *args, "--out", str(tmp_path / "r.json"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]


def test_a_problem_runs_on_dask_as_in_process(two_ramps):
    """A problem crosses process boundaries as plain JSON (each worker builds the summed
    likelihood): on a Dask worker its chains are the in-process chains bit for bit."""
    from galileo import batch

    scenes = [s for s, _ in two_ramps]
    tracks = [t for _, t in two_ramps]
    prob = registry.problem(scenes, share=["k1"], fixed={"m1_kg@2": 0.3})
    cfg = RunConfig(chains=2, sweeps=3, seed=5, workers=1)
    here = infer(prob, tracks, cfg, progress=False)
    class OnDask:   # the runner's executor slot: anything with `map` (each chain a Dask task)
        workers = 1

        def __init__(self, client):
            self.client = client

        def map(self, fn, items):
            return self.client.gather(self.client.map(fn, list(items), pure=False))

        def shutdown(self):
            pass

    with batch.open_client(1) as client:
        there = infer(prob, tracks, cfg, progress=False, executor=OnDask(client))
    assert there.names == here.names == ("m1_kg@1", "k1")
    np.testing.assert_array_equal(there.samples, here.samples)
    np.testing.assert_array_equal(there.logliks, here.logliks)
