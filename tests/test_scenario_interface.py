"""The scenario interface works for a scenario other than the ramp: a ball dropped onto the
ground (tests/scenarios/drop, one latent: its restitution e), registered at run time only,
runs through `galileo infer`, `galileo scenarios` and `galileo simulate`, the app's
controller (steering, save, reload), the viewer's server side and rerun logging."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from conftest import free_port
from galileo import registry
from galileo.cli import main
from scenarios.drop import DropScenario, DropScene, newton_rebound_mps, physics, tracks_from

TRUE_E = 0.6
OBS_NOISE_MPS = 0.05      # SD of the synthetic tracked velocities: the likelihood's default sigma
# 0.5 s: the fall (0.29 s) and the first rebound; with e near the truth the second bounce
# comes after the video ends, so near its mode the likelihood is smooth in e (several
# bounces, each one's frame shifting with e, make it rugged)
SCENE = DropScene(height_m=0.4, radius_m=0.02, restitution=0.5, fps=60.0, n_frames=30)
# How well the observations pin e down: after the first bounce the ball's vertical velocity
# moves by d v / d e = sqrt(2 g h) ~ 2.8 m/s per unit of e in each of the 12 frames left, so
# the posterior SD of e is about 0.05 / (2.8 sqrt(12)) ~ 0.005; MAP_TOL is 6 of those.
MAP_TOL = 0.03


@pytest.fixture(scope="module", autouse=True)
def drop():
    """The drop scenario, registered for this module only (the registry is restored after)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(registry, "_loaded", dict(registry._loaded))
        yield registry.register(DropScenario())


@pytest.fixture(scope="module")
def observed():
    """(scene, tracks): a drop with e = 0.6 simulated, its velocities with N(0, 0.05^2) noise."""
    traj = DropScenario().simulate(SCENE, SCENE.n_frames, {"e": TRUE_E})
    return SCENE, tracks_from(traj, SCENE, noise_mps=OBS_NOISE_MPS, seed=0)


# -- the scenario itself ------------------------------------------------------------------------------------

@pytest.mark.parametrize("e", [0.3, 0.6, 0.9])
@pytest.mark.parametrize("height_m", [0.15, 0.4, 0.73])
def test_first_rebound_matches_newton(e, height_m):
    """Right after the first bounce the ball rises at e sqrt(2 g h) (Newton's restitution).
    Bullet steps dt = 1/240 s: the bounce is solved at the start of the first step that begins
    with the ball in the ground, after that step's gravity kick, so the approach speed is
    sqrt(2 g h) plus between g dt / 2 and 3 g dt / 2 (see physics.py): |error| <= 1.5 e g dt
    (0.037 m/s for e = 0.6)."""
    scene = DropScene(height_m=height_m)
    dt = 1.0 / scene.sim_hz
    traj = physics.simulate(scene, scene.sim_hz, e, fps=scene.sim_hz)   # one frame per step, 1 s
    vz = traj.velocity_mps[0, :, 2]
    up = int(np.argmax(vz > 0))
    assert up > 0 and np.all(vz[:up] <= 0)
    newton = newton_rebound_mps(scene, e)
    assert abs(vz[up] - newton) <= 1.5 * e * scene.gravity_mps2 * dt + 1e-9
    # ... and it falls freely until then, with no damping: v = -g t (semi-implicit Euler)
    np.testing.assert_allclose(vz[1:up - 1], -scene.gravity_mps2 * dt * np.arange(1, up - 1), rtol=1e-9)
    # never deeper in the ground than one step's travel
    assert traj.position_m[0, :, 2].min() > scene.radius_m - math.sqrt(2 * scene.gravity_mps2 * height_m) * dt


def test_runs_are_repeatable_and_likelihood_scores_its_motion(observed):
    scene, tracks = observed
    scenario = registry.get("drop")
    a = scenario.simulate(scene, scene.n_frames, {"e": 0.7})
    scenario.simulate(scene, scene.n_frames, {"e": 0.2})
    b = scenario.simulate(scene, scene.n_frames, {"e": 0.7})
    np.testing.assert_array_equal(a.position_m, b.position_m)
    lik = scenario.likelihood(scenario.prepare(scene, tracks), tracks, 0.05)
    assert lik.names == ("e",) and lik.steps == 0
    np.testing.assert_array_equal(lik.motion([0.7]).velocity_mps, a.velocity_mps)
    full, early = lik([TRUE_E])
    assert not early and lik.steps == (tracks.n_frames - 1) * 4
    # the truth scores best; far from it the evaluation stops early below the threshold
    assert full > lik([TRUE_E - 0.05])[0] and full > lik([TRUE_E + 0.05])[0]
    bound, early = lik([0.1], threshold=full - 10)
    assert early and bound < full - 10
    assert lik([0.1], threshold=None)[0] <= bound


def test_scene_files_round_trip_and_errors_name_the_field(tmp_path):
    from galileo.errors import SceneError

    d = SCENE.to_json()
    assert d["scenario"] == "drop"
    again = registry.scene_from_json(json.loads(json.dumps(d)))
    assert isinstance(again, DropScene) and again == SCENE
    assert registry.of(again).name == "drop"
    for change, needle in [({"restitution": 1.5}, "restitution"), ({"fps": 70}, "multiple of fps"),
                           ({"n_frames": 1}, "n_frames"), ({"colour": "red"}, "unknown field(s) colour"),
                           ({"priors": {"e": [0.5, 1.2]}}, "priors.e"), ({"height_m": None}, "height_m")]:
        with pytest.raises(SceneError, match=needle.replace("(", r"\(").replace(")", r"\)")):
            registry.scene_from_json({**d, **change})
    with pytest.raises(SceneError, match="height_m: missing"):
        registry.scene_from_json({"scenario": "drop", "fps": 60, "n_frames": 10})


# -- the command line --------------------------------------------------------------------------------------

def test_cli_scenarios_lists_drop(capsys):
    assert main(["scenarios"]) == 0
    out = capsys.readouterr().out
    block = out[out.index("drop:"):]
    assert "sigma_vz_mps = 0.05 m/s" in block
    assert "e        [1]  prior U(0, 1)" in block
    assert main(["scenarios", "--json"]) == 0
    described = {d["name"]: d for d in json.loads(capsys.readouterr().out)}
    assert {"ramp", "drop"} <= set(described)
    (lat,) = described["drop"]["latents"]
    assert (lat["name"], lat["unit"], lat["bounds"], lat["limits"]) == ("e", "1", [0.0, 1.0], [0.0, 1.0])


def test_cli_infer_recovers_the_restitution(observed, tmp_path, capsys):
    scene, tracks = observed
    scene_path, tracks_path, out = tmp_path / "scene.json", tmp_path / "observed.json", tmp_path / "result.json"
    scene_path.write_text(json.dumps(scene.to_json()))
    tracks.save(tracks_path)
    video = tmp_path / "video.mp4"
    video.write_bytes(b"")          # never read: the tracks are given
    rc = main(["infer", str(video), "--scene", str(scene_path), "--tracks", str(tracks_path), "--out", str(out),
               "--chains", "4", "--sweeps", "30", "--workers", "1", "--quiet"])
    assert rc == 0
    assert "MAP: e = " in capsys.readouterr().out
    d = json.loads(out.read_text())
    assert d["scenario"] == "drop" and d["latents"] == ["e"]
    assert abs(d["map"]["e"] - TRUE_E) <= MAP_TOL
    assert d["energy_kept"] == pytest.approx(d["map"]["e"] ** 2)
    assert d["config"]["sigma_vz_mps"] == 0.05 and d["config"]["bounds"] == {"e": [0.0, 1.0]}
    assert d["scene"]["scenario"] == "drop"
    assert (tmp_path / d["samples_file"]).is_file()
    assert set(d["posterior"]) == {"e"} and set(d["diagnostics"]["r_hat"]) == {"e"}
    # without tracks the drop scenario tracks nothing: one line, exit code 2
    rc = main(["infer", str(video), "--scene", str(scene_path), "--out", str(out), "--quiet"])
    assert rc == 2 and "the drop scenario is for tests" in capsys.readouterr().err


def test_cli_simulate_uses_the_scenes_timing(tmp_path, capsys):
    scene_path, out = tmp_path / "scene.json", tmp_path / "traj.json"
    scene_path.write_text(json.dumps(SCENE.to_json()))
    assert main(["simulate", "--scene", str(scene_path), "--set", "e=0.6", "--out", str(out)]) == 0
    d = json.loads(out.read_text())
    assert d["fps"] == 60.0 and len(d["time_s"]) == SCENE.n_frames and [o["name"] for o in d["objects"]] == ["ball"]
    assert main(["simulate", "--scene", str(scene_path), "--set", "mass=1", "--out", str(out)]) == 2
    assert "unknown value(s) mass" in capsys.readouterr().err


# -- the app: controller, viewer, rerun ----------------------------------------------------------------------

def test_controller_steers_saves_and_goes_on(observed, tmp_path):
    from ui.controller import Controller

    scene, tracks = observed

    def steered(session_dir):
        ctrl = Controller(scene, tracks, chains=2, seed=0, workers=1, session_dir=session_dir)
        ctrl.run_sweeps(3)
        ctrl.set_bounds("e", 0.1, 0.9)
        ctrl.set_noise(0.06)
        ctrl.run_sweeps(2)
        return ctrl

    ctrl = steered(tmp_path / "a")
    assert ctrl.names == ("e",)
    st = ctrl.status()
    assert st["settings"]["bounds"] == {"e": [0.1, 0.9]} and st["settings"]["sigma_vz_mps"] == 0.06
    assert [e["kind"] for e in ctrl.events] == ["init", "bounds", "sigma"]
    for c in ctrl.chain_ids():
        s = ctrl.samples(c)
        assert s.shape == (5, 1) and np.all((s[3:] >= 0.1) & (s[3:] <= 0.9))
    before = {c: ctrl.samples(c) for c in ctrl.chain_ids()}
    ctrl.close()

    again = Controller.load(tmp_path / "a", workers=1)
    try:
        assert again.settings.noise == 0.06 and again.settings.bounds == {"e": (0.1, 0.9)}
        assert again.run_sweeps(2) == 2
        # the reopened chains go on exactly as chains never interrupted do
        uninterrupted = steered(tmp_path / "b")
        uninterrupted.run_sweeps(2)
        for c in again.chain_ids():
            s = again.samples(c)
            np.testing.assert_array_equal(s[:5], before[c])
            np.testing.assert_array_equal(s, uninterrupted.samples(c))
        uninterrupted.close()
    finally:
        again.close()


def test_viewer_and_rerun(observed, tmp_path):
    chunk = pytest.importorskip("rerun.chunk")
    from ui.controller import Controller
    from ui.rerun_log import RRD_NAME, RerunLogger
    from ui.viewer import Viewer
    from galileo.video import read_video, write_video

    scene, tracks = observed
    ctrl = Controller(scene, tracks, chains=2, seed=0, workers=1, session_dir=tmp_path / "s")
    logger = RerunLogger("save", session_dir=tmp_path / "s", latents=list(ctrl.names), n_chains=2)
    ctrl.add_listener(lambda kind, p: [logger.log_sweep(*r) for r in p["results"]] if kind == "sweeps" else None)
    ctrl.run_sweeps(3)
    video_path = tmp_path / "video.mp4"     # a black video (the scene has no camera to film it)
    write_video(video_path, np.zeros((scene.n_frames, 48, 64, 3), np.uint8), scene.fps)
    video, _ = read_video(video_path)
    logger.log_video(video_path, tracks, tracks.fps)
    v = Viewer(ctrl, ctrl.likelihood_scene, tracks, video, port=free_port())
    try:
        assert v.camera is None and [h.name for h in v.object_handles] == ["/objects/ball"]
        v.select_sample(1, 2)
        v.jump_to_map()
        chain, index, values, _ = ctrl.map()
        assert (v.selection.chain, v.selection.index) == (chain, index)
        v.set_frame(25)
        motion = ctrl.scenario.likelihood(ctrl.likelihood_scene, tracks, ctrl.settings.noise).motion([values["e"]])
        np.testing.assert_allclose(v.object_handles[0].position, motion.position_m[0, 25], atol=1e-6)
        np.testing.assert_allclose(v.traj.position_m, motion.position_m)
        v.snap_camera()     # no camera: a notice, no error
        v.refresh()
        assert set(v.hist_plots) == {"e"} and "e = " in v.status_text.content
        logger.log_posterior(ctrl.names, np.concatenate([ctrl.samples(c) for c in ctrl.chain_ids()]),
                             ctrl.settings.bounds)
        logger.log_simulation(v.traj)
    finally:
        v.close()
        ctrl.close()
        logger.close()
    ents = {}
    for ch in chunk.RrdReader(tmp_path / "s" / RRD_NAME).stream().to_chunks():
        ents.setdefault(ch.entity_path.lstrip("/"), []).append(ch.to_record_batch().to_pydict())
    assert {"chains/0/e", "chains/1/e", "chains/0/loglik", "posterior/e", "sim/selected/ball", "video",
            "observed/ball"} <= set(ents)
    es = [x for cols in ents["chains/0/e"] for x in cols.get("Scalars:scalars", [])]
    np.testing.assert_allclose([x[0] for x in es], ctrl.samples(0)[:, 0])
