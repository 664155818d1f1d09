"""A ramp video in which nothing moves is evidence, not an error: `galileo track` reports the
objects at rest where the scene file puts them, with a note, and inference on those tracks
finds the ramp object's friction at least tan(angle) and the masses not identified."""
import json
import math

import numpy as np
import pytest

from galileo.cli import main
from galileo.datatypes import Tracks
from galileo.errors import GalileoError
from galileo.scenarios.ramp.likelihood import SIGMA_MPS
from galileo.scenarios.ramp.scene import Scene, default_camera, default_scene
from galileo.scenarios.ramp.tracking import track

ANGLE_DEG = 20.0
FRICTION = 0.6          # > tan 20 deg = 0.364: the block holds on the ramp
N_FRAMES = 31           # 1 s at 30 fps


@pytest.fixture(scope="module")
def still_video(tmp_path_factory):
    """(folder, true trajectory) of a rendered 20 degree video in which nothing moves: a
    block that holds on the ramp and a cardboard box that is never hit (about 3 s)."""
    from galileo.render import Look
    from galileo.scenarios.ramp.render import render_to_video

    scene = default_scene(ANGLE_DEG, friction=FRICTION, target="cardboard", distance_m=0.1,
                          camera=default_camera(n_frames=N_FRAMES), offset_units=2)
    folder = tmp_path_factory.mktemp("still")
    traj = render_to_video(scene, folder / "video.mp4", N_FRAMES, look=Look.random(np.random.default_rng(5)))
    scene.save(folder / "scene.json")
    assert np.ptp(traj.position_m, axis=1).max() < 1e-4   # truly still
    return folder, traj


@pytest.fixture(scope="module")
def still_tracks(still_video):
    folder, _ = still_video
    scene = Scene.load(folder / "scene.json")
    return scene, track(folder / "video.mp4", scene, progress=False)


def test_track_holds_the_objects_where_the_scene_puts_them(still_video, still_tracks):
    _, traj = still_video
    scene, tracks = still_tracks
    assert len(tracks.notes) == 1
    note = tracks.notes[0]
    assert "nothing moves" in note and f"{math.tan(math.radians(ANGLE_DEG)):.3f}" in note
    assert "not identified" in note and "scene file" in note
    assert tracks.n_frames == N_FRAMES and tracks.fps == scene.camera.fps
    assert [o.role for o in tracks.objects] == ["ramp", "target"]
    for i, (o, obj) in enumerate(zip(tracks.objects, scene.objects)):
        assert o.visible.all()
        assert (o.velocity_mps == 0).all()
        assert o.detected_by == "scene" and o.shape == obj.shape
        centre, _ = scene.initial_pose(i)
        np.testing.assert_array_equal(o.position_m, np.tile([centre[0], 0.0, centre[2]], (N_FRAMES, 1)))
        # the rendered truth (centres of mass) agrees: Bullet's settling moves them < 0.1 mm
        np.testing.assert_allclose(o.position_m[:, [0, 2]], traj.position_m[i][:, [0, 2]], atol=1e-4)
    assert tracks.objects[0].offset_units == scene.ramp_object.offset_units == 2
    assert tracks.objects[1].offset_units is None


def test_cli_track_accepts_a_still_video_and_prints_the_note(still_video, still_tracks, tmp_path, capsys):
    folder, _ = still_video
    out, debug = tmp_path / "tracks.json", tmp_path / "debug.mp4"
    rc = main(["track", str(folder / "video.mp4"), "--scene", str(folder / "scene.json"), "--out", str(out),
               "--debug-video", str(debug), "--quiet"])
    cap = capsys.readouterr()
    assert rc == 0 and cap.err == ""
    assert f"note: {still_tracks[1].notes[0]}" in cap.out.splitlines()
    assert json.loads(out.read_text())["notes"] == still_tracks[1].notes
    loaded = Tracks.load(out)
    assert loaded.notes == still_tracks[1].notes and loaded.objects[0].visible.all()
    assert debug.stat().st_size > 0


def _k1_tolerance(n_frames: int, fps: float, angle_deg: float, g: float = 9.81) -> float:
    """How far below tan(angle) the likelihood cannot rule k1 out on a still video.

    The likelihood counts k1 within ~2e-4 of tan(angle) as at rest (likelihood.py's
    docstring). Below that the block slides from frame 0 with acceleration
    g cos(angle) (tan(angle) - k1), so frame f's velocity misfit is a f / fps, and the
    whole video costs sum_f (a f / fps)^2 / (2 sigma^2) nats against staying put. A k1
    costing 3 nats or more is (e^-3 = 5%) as unlikely as a 5% quantile can tolerate."""
    a_per_dk = g * math.cos(math.radians(angle_deg))
    nats_per_dk2 = (a_per_dk / (fps * SIGMA_MPS)) ** 2 / 2 * sum(f * f for f in range(n_frames))
    return 2e-4 + math.sqrt(3.0 / nats_per_dk2)


def test_the_likelihood_of_a_still_video_ignores_the_masses_and_punishes_sliding(still_tracks):
    """Deterministic: every mass and target friction explains stillness equally; a k1 below
    tan(angle) costs what the sliding block's velocities predict (`_k1_tolerance`)."""
    from galileo.scenarios.ramp.likelihood import VelocityLikelihood

    from galileo.runner import scene_for_moves

    scene, tracks = still_tracks
    # the cost below is the Gaussian's (the paper's likelihood)
    ll = VelocityLikelihood(scene_for_moves(scene, "paper"), tracks, speedups=False)
    assert ll.names == ("m1_kg", "k1", "m2_kg", "k2")
    tan = math.tan(math.radians(ANGLE_DEG))
    for k1 in (0.5, 1.0, tan - 0.02):
        vals = {ll(np.array([m1, k1, m2, k2]))[0] for m1 in (0.01, 0.3, 1.0) for m2 in (0.01, 1.0) for k2 in (0.1, 0.9)}
        assert max(vals) - min(vals) < 1e-9, k1
    at_rest = ll(np.array([0.3, 0.5, 0.3, 0.5]))[0]
    # no misfit but Bullet settling the objects onto their supports (~1e-5 m/s in the first frames)
    assert at_rest == pytest.approx(ll.log_norm, abs=1e-3)
    tol = _k1_tolerance(N_FRAMES, tracks.fps, ANGLE_DEG)
    cost = at_rest - ll(np.array([0.3, tan - tol, 0.3, 0.5]))[0]
    assert 3.0 <= cost < 4.0


def test_inference_on_a_still_video_bounds_k1_below_and_leaves_the_masses_open(still_tracks):
    """MCMC on the still tracks (8 chains x the paper's 75 sweeps, about 1 s): chains that
    start below tan(angle) climb out of it during burn-in; above it the posterior is flat."""
    from galileo.runner import RunConfig, infer

    scene, tracks = still_tracks
    res = infer(scene, tracks, RunConfig(chains=8, sweeps=75, workers=1), progress=False)
    tan = math.tan(math.radians(ANGLE_DEG))
    tol = _k1_tolerance(N_FRAMES, tracks.fps, ANGLE_DEG)
    assert tol < 0.006
    post = res.posterior()
    assert post["k1"]["q05"] >= tan - tol
    assert post["k1"]["q95"] > tan + 0.25          # anything above tan(angle) explains the video
    kept = res.kept()
    names = list(res.names)
    for m in ("m1_kg", "m2_kg"):                   # not identified: spread over U(0.001, 1) (IQR 0.5)
        x = kept[..., names.index(m)].ravel()
        q25, q75 = np.quantile(x, [0.25, 0.75])
        assert q75 - q25 > 0.25, (m, q25, q75)


def test_a_still_ramp_object_gives_no_galileo_label(still_tracks):
    from galileo import registry

    scene, tracks = still_tracks
    ramp = registry.get("ramp")
    prepared = ramp.prepare(scene, tracks)
    lab = ramp.recognition_label(prepared, tracks, {"m1_kg": 0.3, "k1": 0.7, "m2_kg": 0.6, "k2": 0.3})
    assert lab["ramp"] == {"mass_kg": None, "friction": None}   # k1 only bounded below, no collision
    assert lab["target"] == {"mass_kg": None, "friction": None}


def test_recognition_tracks_a_still_video_and_caches_its_note(still_video, tmp_path):
    import shutil

    from galileo.recognition.data import TRACKS_FILE, Example, tracks_for

    folder = tmp_path / "v"
    shutil.copytree(still_video[0], folder)
    ex = Example("v", folder, "block", "wood", "ramp")
    tracks = tracks_for(ex)
    assert tracks is not None and tracks.notes and (folder / TRACKS_FILE).is_file()
    assert tracks_for(ex).notes == tracks.notes   # from the cache


# -- Tracks.notes in the tracks JSON ---------------------------------------------------------------

def test_tracks_notes_round_trip_and_only_when_present(still_tracks, tmp_path):
    _, tracks = still_tracks
    path = tmp_path / "t.json"
    tracks.save(path)
    assert Tracks.load(path).notes == tracks.notes
    plain = Tracks(tracks.fps, tracks.objects)
    assert "notes" not in plain.to_json()
    assert Tracks.from_json(plain.to_json()).notes == []


def test_old_tracks_file_without_notes_loads():
    from conftest import DATA

    d = json.loads((DATA / "tracks.json").read_text())
    assert "notes" not in d
    tracks = Tracks.from_json(d)
    assert tracks.notes == [] and len(tracks.objects) == 2


@pytest.mark.parametrize("bad", ["a note", [1, 2], {"a": "b"}, ["ok", None]])
def test_malformed_notes_are_refused(still_tracks, bad):
    d = still_tracks[1].to_json()
    d["notes"] = bad
    with pytest.raises(GalileoError, match="malformed tracks JSON: notes"):
        Tracks.from_json(d)
