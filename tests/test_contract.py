"""The scenario contract: every registered scenario (and the test-only `drop`) passes these,
so a new scenario gets them for free by its registry line.

The truth each test holds a scenario to is its own declared physics, used independently of
the code under test: observations simulated at known values (`synthetic.tracks`, with no noise)
are fit best at those values; a scene written and read back is the same scene; a session
saved and reopened goes on as one never interrupted; each declared capability does what it
says on a real input (a dataset's demo video rendered, tracked, inferred on)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scenarios.drop import DropScenario

from galileo import registry
from galileo.model import CAPABILITIES

NAMES = sorted(set(registry.names()) | {"drop"})
PERTURB = 0.1     # each latent moved by this share of its prior range for the peak test
PEAK_NATS = 1.0   # at least one latent's move costs this many nats on noise-free observations


@pytest.fixture(scope="module", autouse=True)
def drop():
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(registry, "_loaded", dict(registry._loaded))
        yield registry.register(DropScenario())


def _truth(s, scene) -> dict[str, float]:
    names = [lat.name for lat in s.latents(scene)]
    values = s.values(scene)
    return {n: values[n] for n in names}


@pytest.fixture(scope="module")
def observed(drop):
    """Per scenario: (scenario, default scene, noise-free synthetic tracks at its truth, the truth)."""
    out = {}
    for name in NAMES:
        s = registry.get(name)
        scene = s.default_scene()
        if s.synthetic is None:
            out[name] = (s, scene, None, None)
            continue
        truth = _truth(s, scene)
        tracks = s.synthetic.tracks(scene, truth, np.random.default_rng(0), 0.0)
        out[name] = (s, scene, tracks, truth)
    return out


def _need_tracks(entry):
    s, scene, tracks, truth = entry
    if tracks is None:
        pytest.skip(f"the {s.name} scenario declares no synthetic observations")
    return entry


@pytest.mark.parametrize("name", NAMES)
def test_declares_its_face(name):
    s = registry.get(name)
    assert s.name == name and s.description and s.noise.default > 0
    d = s.describe()
    assert d["latents"] and set(d["capabilities"]) == set(CAPABILITIES)
    for cap in CAPABILITIES:
        assert d["capabilities"][cap] == (getattr(s, cap) is not None)
    from galileo.runner import MOVE_SETS

    assert s.converge_moves in MOVE_SETS     # what runs until converged without --moves


@pytest.mark.parametrize("name", NAMES)
def test_scene_round_trips(name, tmp_path):
    s = registry.get(name)
    scene = s.default_scene()
    assert registry.scene_from_json(scene.to_json()) == scene
    path = tmp_path / "scene.json"
    scene.save(path)
    assert registry.load_scene(path) == scene == type(scene).load(path)
    assert registry.of(scene) is s


@pytest.mark.parametrize("name", NAMES)
def test_simulation_is_finite(name):
    s = registry.get(name)
    scene = s.default_scene()
    timing = s.video_timing(scene)
    n = min(timing[1], 60) if timing else 30
    traj = s.simulate(scene, n)
    assert traj.position_m.shape[:2] == (len(traj.names), n)
    assert np.isfinite(traj.position_m).all() and np.isfinite(traj.velocity_mps).all()
    assert len(s.drawing(scene).objects) == len(traj.names)


@pytest.mark.parametrize("name", NAMES)
def test_noise_free_observations_are_fit_best_at_the_truth(name, observed):
    """Observations made from the likelihood's own motion at the truth, without noise: no latent
    moved off the truth fits them better, and some move costs at least PEAK_NATS. (If `motion`
    drew something other than what is scored, the truth would not be the peak.)"""
    s, scene, tracks, truth = _need_tracks(observed[name])
    prepared = s.prepare(scene, tracks)
    lats = s.latents(prepared)
    lik = s.likelihood(prepared, tracks, s.noise.default)
    assert tuple(lik.names) == tuple(lat.name for lat in lats)
    x0 = np.array([truth[lat.name] for lat in lats], float)
    best, _ = lik(x0)
    assert math.isfinite(best)
    costs = []
    for j, lat in enumerate(lats):
        if lat.observation:   # less noise always fits noise-free observations better
            continue
        lo, hi = lat.bounds
        step = max(1.0, round(PERTURB * (hi - lo))) if lat.integer else PERTURB * (hi - lo)
        for sign in (-1, 1):
            x = x0.copy()
            x[j] = min(max(x0[j] + sign * step, lo), hi)
            if x[j] == x0[j]:
                continue
            value, _ = lik(x)
            assert value <= best + 1e-6 * abs(best), f"{lat.name} = {x[j]:g} fits better than the truth {x0[j]:g}"
            costs.append(best - value)
    assert max(costs) >= PEAK_NATS


@pytest.mark.parametrize("name", NAMES)
def test_motion_does_not_depend_on_what_was_evaluated_before(name, observed):
    """`motion` is a function of the position: caches of earlier evaluations leave it unchanged."""
    s, scene, tracks, truth = _need_tracks(observed[name])
    prepared = s.prepare(scene, tracks)
    lats = s.latents(prepared)
    x0 = np.array([truth[lat.name] for lat in lats], float)
    fresh = s.likelihood(prepared, tracks, s.noise.default).motion(x0)
    lik = s.likelihood(prepared, tracks, s.noise.default)
    rng = np.random.default_rng(1)
    for _ in range(5):
        x = np.array([rng.uniform(*lat.bounds) for lat in lats])
        for j, lat in enumerate(lats):
            if lat.integer:
                x[j] = round(x[j])
        lik(x, lik(x0)[0] - 5.0)
    again = lik.motion(x0)
    np.testing.assert_array_equal(again.position_m, fresh.position_m)
    np.testing.assert_array_equal(again.velocity_mps, fresh.velocity_mps)


@pytest.mark.parametrize("name", NAMES)
def test_inference_result_round_trips(name, observed, tmp_path):
    from galileo.results import load_result
    from galileo.runner import RunConfig, infer

    s, scene, tracks, truth = _need_tracks(observed[name])
    res = infer(scene, tracks, RunConfig(chains=2, sweeps=3, seed=0, workers=1), progress=False)
    assert res.samples.shape == (2, 3, len(res.names)) and np.isfinite(res.logliks).all()
    res.save(tmp_path / "result.json")
    back = load_result(tmp_path / "result.json")
    assert back.map == pytest.approx(res.map) and back.scene == res.scene


@pytest.mark.parametrize("name", NAMES)
def test_a_session_reopens_and_goes_on_as_if_never_closed(name, observed, tmp_path):
    from ui.controller import Controller

    s, scene, tracks, truth = _need_tracks(observed[name])
    ctrl = Controller(scene, tracks, chains=2, seed=0, workers=1, session_dir=tmp_path / "a")
    ctrl.run_sweeps(2)
    ctrl.close()
    again = Controller.load(tmp_path / "a", workers=1)
    whole = Controller(scene, tracks, chains=2, seed=0, workers=1, session_dir=tmp_path / "b")
    try:
        again.run_sweeps(1)
        whole.run_sweeps(3)
        for c in whole.chain_ids():
            np.testing.assert_array_equal(again.samples(c), whole.samples(c))
    finally:
        again.close()
        whole.close()


@pytest.mark.parametrize("name", NAMES)
def test_a_problem_of_two_of_its_videos_shares_a_latent(name, observed):
    """Two copies of the same video sharing their first latent (and any the scenario shares by
    itself, `shared_latents`): one value of each, the others per video, and the log-likelihood
    twice one video's."""
    s, scene, tracks, truth = _need_tracks(observed[name])
    prepared_one = s.prepare(scene, tracks)
    lats = s.latents(prepared_one)
    shared = lats[0].name
    both = {shared} | set(s.shared_latents([prepared_one, prepared_one]))
    prob = registry.problem([scene, scene], share=[shared])
    js = registry.of(prob)
    prepared = js.prepare(prob, [tracks, tracks])
    names = [lat.name for lat in js.latents(prepared)]
    assert all(names.count(n) == 1 for n in both) and len(names) == 2 * len(lats) - len(both)
    joint = js.likelihood(prepared, [tracks, tracks], s.noise.default)
    x = np.array([js.values(prob)[n] for n in names])
    one, _ = s.likelihood(s.prepare(scene, tracks), tracks, s.noise.default)([truth[lat.name] for lat in lats])
    assert joint(x)[0] == pytest.approx(2 * one, rel=1e-9)


# -- declared capabilities ----------------------------------------------------------------------------------

def _with(name: str, capability: str):
    s = registry.get(name)
    if getattr(s, capability) is None:
        pytest.skip(f"the {name} scenario declares no {capability}")
    return s


@pytest.mark.parametrize("name", NAMES)
def test_dataset_renders_a_demo_video_its_tracker_reads(name, tmp_path):
    """The dataset capability's first planned video of its first preset renders to a folder the
    rest of Galileo reads: the scene loads, the truth names the latents, the tracker follows the
    video, and (with experiments) one video's record is made; with a calibration, the points it
    asks for, clicked exactly on the first frame, give back the video's camera; with recognition,
    its examples are found."""
    from galileo.dataset import build
    from galileo.runner import RunConfig

    s = _with(name, "dataset")
    spec = s.dataset
    assert spec.presets
    preset = "demo" if "demo" in spec.presets else spec.presets[0]
    entries = build(spec, preset, tmp_path, seed=0, workers=1, progress=False)
    folder = tmp_path / entries[0]["name"]
    scene = registry.load_scene(folder / "scene.json")
    from galileo.jsonio import read_json

    truth = read_json(folder / "truth.json", "truth")["latents"]
    lat_names = [lat.name for lat in s.latents(scene)]
    assert set(lat_names) <= set(truth)
    tracks = s.track(folder / "video.mp4", scene, progress=False)
    assert tracks.n_frames > 1
    if s.experiments is not None:
        rec = s.experiments.run_video(folder, RunConfig(chains=2, sweeps=2, seed=0, workers=1))
        assert isinstance(rec, dict) and rec
    if s.calibration is not None and s.calibration.example is not None:
        # the points a user would click on the first frame, exactly: the camera comes back
        from galileo.clicks import sample_video

        cal = s.calibration
        info, _, frames = sample_video(folder / "video.mp4")
        world, numbers = cal.example(scene)
        solved, err = cal.solve(scene.camera.project(world), numbers, info, frames)
        assert err < 0.1
        np.testing.assert_allclose(solved.camera.position_in_world, scene.camera.position_in_world, atol=1e-3)
        np.testing.assert_allclose(solved.camera.project(world), scene.camera.project(world), atol=0.1)
    if s.recognition is not None and s.recognition.examples is not None:
        examples = s.recognition.examples(tmp_path)
        assert examples and all(ex.folder.is_dir() for ex in examples)
        roles = {o.role for o in tracks.objects}
        assert {r.role for r in s.recognition.readouts(s.prepare(scene, tracks))} <= roles


@pytest.mark.parametrize("name", NAMES)
def test_synthetic_observations_carry_the_declared_noise(name, observed):
    """At noise sigma, synthetic tracks differ from the noise-free ones by about sigma in the
    likelihood's units: the log-likelihood at the truth drops, and more for more noise."""
    s, scene, tracks, truth = _need_tracks(observed[name])
    lls = []
    for k in (0.0, 1.0, 3.0):
        t = s.synthetic.tracks(scene, truth, np.random.default_rng(2), k * s.noise.default)
        p = s.prepare(scene, t)
        lik = s.likelihood(p, t, s.noise.default)
        lls.append(lik([truth[lat.name] for lat in s.latents(p)])[0])
    assert lls[0] > lls[1] > lls[2]


@pytest.mark.parametrize("name", NAMES)
def test_predict_asks_a_result_only_its_own_scenarios_questions(name, observed, tmp_path, capsys):
    """`galileo predict`'s flags are every scenario's declared questions; a result is asked only its
    own scenario's, another's is refused in one line naming the flag."""
    from galileo.cli import all_questions, main
    from galileo.runner import RunConfig, infer

    s, scene, tracks, truth = _need_tracks(observed[name])
    own = {q.name for q in s.questions}
    foreign = [q for q in all_questions() if q.name not in own]
    if not foreign:
        pytest.skip(f"every question is the {name} scenario's own")
    infer(scene, tracks, RunConfig(chains=2, sweeps=2, seed=0, workers=1), progress=False).save(tmp_path / "r.json")
    for q in foreign:
        value = [] if q.kind == "yes" else ["1" if q.kind == "number" else str(tmp_path / "r.json")]
        assert main(["predict", "--result", str(tmp_path / "r.json"), q.flag, *value]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"{q.flag} is no question of the {name} scenario" in err[-1]
