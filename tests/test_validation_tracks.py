"""Issue 15: one validation layer for tracks files, result files and the video against the
scene's camera. Every refusal is a GalileoError of one line naming the field and the bound,
the same through the loaders (the library, the app) and the command line (exit code 2)."""
import copy
import json
import math
import shutil

import numpy as np
import pytest

from conftest import DATA
from galileo.cli import main
from galileo.datatypes import Tracks, TracksError
from galileo.errors import GalileoError

SCENE = DATA / "scene.json"
BASE = json.loads((DATA / "tracks.json").read_text())


def cli(capsys, *args):
    rc = main([str(a) for a in args])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def assert_one_line(rc, err, needle):
    lines = err.strip().splitlines()
    assert rc == 2, (rc, err)
    assert len(lines) == 1 and lines[0].startswith("galileo: error: ") and needle in lines[0], err


def infer_argv(tracks_path, out):
    return ["infer", "unused.mp4", "--scene", SCENE, "--tracks", tracks_path, "--chains", 1, "--sweeps", 1,
            "--workers", 1, "--out", out, "--quiet"]


def obj(i):
    return lambda d: d["objects"][i]


def setter(path, value):
    """A mutation: d[path[0]][path[1]]... = value."""
    def mutate(d):
        node = d
        for k in path[:-1]:
            node = node[k]
        node[path[-1]] = value
    return mutate


def deleter(path):
    def mutate(d):
        node = d
        for k in path[:-1]:
            node = node[k]
        del node[path[-1]]
    return mutate


def truncate(path, n):
    def mutate(d):
        node = d
        for k in path[:-1]:
            node = node[k]
        node[path[-1]] = node[path[-1]][:n]
    return mutate


# (mutation of the frozen demo tracks, what the one-line error must say)
BAD_TRACKS = {
    "lists_of_different_lengths": (truncate(["objects", 1, "visible"], 60),
                                   "objects[1].visible: 60 frames but objects[0] has 61"),
    "rows_fewer_than_frames": (truncate(["objects", 0, "velocity_mps"], 50),
                               "objects[0].velocity_mps: 50 rows but visible has 61 frames"),
    "visible_yes": (setter(["objects", 0, "visible"], "yes"),
                    "objects[0].visible: expected a list of true/false, one per frame, got 'yes'"),
    "visible_string_false": (setter(["objects", 0, "visible", 3], "false"),
                             "objects[0].visible[3]: expected true or false, got 'false'"),
    "visible_one": (setter(["objects", 1, "visible", 0], 1), "objects[1].visible[0]: expected true or false, got 1"),
    "shape_type_a_number": (setter(["objects", 0, "shape", "type"], 3),
                            "objects[0].shape.type: expected a shape type's name (box, cylinder, torus, or a "
                            "scenario's own), got 3"),
    "two_element_size": (setter(["objects", 0, "shape", "size_m"], [0.05, 0.05]),
                         "objects[0].shape.size_m: expected three numbers in (0, 10] (metres), got [0.05, 0.05]"),
    "negative_size": (setter(["objects", 1, "shape", "size_m"], [0.05, -0.05, 0.05]),
                      "objects[1].shape.size_m: expected three numbers in (0, 10]"),
    "invalid_torus": (setter(["objects", 0, "shape"], {"type": "torus", "size_m": [0.05, 0.05, 0.05]}),
                      "objects[0].shape: a torus needs outer diameter x > 2 * tube diameter z"),
    "non_integer_offset": (setter(["objects", 0, "offset_units"], 1.5),
                           "objects[0].offset_units: expected null or an integer in [-10000, 10000], got 1.5"),
    "string_offset": (setter(["objects", 0, "offset_units"], "4"),
                      "objects[0].offset_units: expected null or an integer"),
    "nan_velocity": (setter(["objects", 0, "velocity_mps", 5], [math.nan, 0.0, 0.0]),
                     "objects[0].velocity_mps[5]: visible frame 5 of 'ramp_object' has velocity [nan, 0.0, 0.0], not "
                     "three finite numbers (m/s)"),
    "string_nan_velocity": (setter(["objects", 1, "velocity_mps", 7, 2], "NaN"),
                            "objects[1].velocity_mps[7]: visible frame 7 of 'target' has velocity ["),
    "infinite_position": (setter(["objects", 0, "position_m", 2, 0], math.inf),
                          "objects[0].position_m[2]: visible frame 2 of 'ramp_object' has position [inf, "),
    "null_velocity_in_a_visible_frame": (setter(["objects", 0, "velocity_mps", 9], None),
                                         "objects[0].velocity_mps[9]: visible frame 9 of 'ramp_object' has "
                                         "velocity None, not three finite numbers"),
    "huge_velocity": (setter(["objects", 0, "velocity_mps", 4], [1e300, 0.0, 0.0]),
                      "objects[0].velocity_mps[4]: [1e+300, 0.0, 0.0] is outside [-1000, 1000] m/s"),
    "integer_too_long_for_a_float": (setter(["objects", 0, "velocity_mps", 3, 0], 10**400),
                                     "objects[0].velocity_mps[3]: visible frame 3 of 'ramp_object' has velocity [1000"),
    "offset_too_long_for_a_float": (setter(["objects", 0, "offset_units"], -10**400),
                                    "objects[0].offset_units: expected null or an integer in [-10000, 10000], got -1000"),
    "fps_string": (setter(["fps"], "30"), "fps: expected a number in (0, 10000], got '30'"),
    "fps_zero": (setter(["fps"], 0), "fps: expected a number in (0, 10000], got 0"),
    "fps_nan": (setter(["fps"], math.nan), "fps: expected a number in (0, 10000], got nan"),
    "fps_edited_without_times": (setter(["fps"], 60.0), "time_s[1]: expected frame 1 at 0.0166667 s (fps 60)"),
    "times_truncated": (truncate(["time_s"], 10), "time_s: expected 61 times (one per frame), got 10 of them"),
    "no_objects_key": (deleter(["objects"]), "objects: missing"),
    "empty_objects": (setter(["objects"], []), "objects: expected a non-empty list of objects, got []"),
    "object_not_an_object": (setter(["objects", 1], [1, 2]), "objects[1]: expected an object, got [1, 2]"),
    "no_name": (deleter(["objects", 0, "name"]), "objects[0].name: missing"),
    "no_shape": (deleter(["objects", 1, "shape"]), "objects[1].shape: missing"),
    "same_name_twice": (setter(["objects", 1, "name"], "ramp_object"),
                        "objects[1].name: 'ramp_object' is used by an earlier object (each name once)"),
    "same_role_twice": (setter(["objects", 1, "role"], "ramp"),
                        "objects[1].role: 'ramp' is used by an earlier object (each role once)"),
    "bottom_up_nan": (setter(["objects", 0, "bottom_up"], {"volume_cm3": math.nan}),
                      "objects[0].bottom_up.volume_cm3: expected a finite number, got nan"),
    "notes_not_strings": (setter(["notes"], [1]), "notes: expected a list of strings, got [1]"),
    "top_level_list": (lambda d: [d], "expected a JSON object at the top level, got [{"),
}


def write_tracks(tmp_path, mutate):
    d = copy.deepcopy(BASE)
    replaced = mutate(d)
    d = d if replaced is None else replaced
    path = tmp_path / "tracks.json"
    path.write_text(json.dumps(d))   # (Python's json writes NaN and Infinity as such)
    return path


@pytest.mark.parametrize("case", sorted(BAD_TRACKS))
def test_bad_tracks_file_is_refused_by_the_loader_in_one_line(tmp_path, case):
    mutate, needle = BAD_TRACKS[case]
    path = write_tracks(tmp_path, mutate)
    with pytest.raises(TracksError) as e:
        Tracks.load(path)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"{path}: malformed tracks JSON: ") and needle in msg, msg


@pytest.mark.parametrize("case", sorted(BAD_TRACKS))
def test_bad_tracks_file_is_one_line_exit_2_from_galileo_infer(tmp_path, capsys, case):
    mutate, needle = BAD_TRACKS[case]
    path = write_tracks(tmp_path, mutate)
    rc, out, err = cli(capsys, *infer_argv(path, tmp_path / "r.json"))
    assert_one_line(rc, err, needle)
    assert not (tmp_path / "r.json").exists()


def test_the_frozen_tracks_and_their_round_trip_load(tmp_path):
    tracks = Tracks.load(DATA / "tracks.json")
    assert tracks.objects[0].offset_units == 4 and isinstance(tracks.objects[0].offset_units, int)
    tracks.save(tmp_path / "t.json")
    again = Tracks.load(tmp_path / "t.json")
    for a, b in zip(tracks.objects, again.objects):
        assert np.array_equal(a.visible, b.visible) and np.array_equal(a.velocity_mps, b.velocity_mps)


def test_integral_offset_and_frames_not_seen_are_accepted(tmp_path):
    d = copy.deepcopy(BASE)
    d["objects"][0]["offset_units"] = 4.0                  # an integer written as 4.0
    d["objects"][1]["visible"][3] = False                  # a frame not seen: its rows are ignored
    d["objects"][1]["velocity_mps"][3] = None
    d["objects"][1]["visible"][4] = False
    d["objects"][1]["velocity_mps"][4] = [math.nan, math.nan, math.nan]
    (tmp_path / "t.json").write_text(json.dumps(d))
    tracks = Tracks.load(tmp_path / "t.json")
    assert tracks.objects[0].offset_units == 4 and np.isnan(tracks.objects[1].velocity_mps[3:5]).all()


def test_an_unknown_shape_type_is_refused_by_the_ramp(tmp_path, capsys):
    """The loader takes any type's name (a scenario may have shapes of its own: the test
    scenario's sphere); the ramp, which simulates the shape, refuses one it does not know."""
    path = write_tracks(tmp_path, setter(["objects", 0, "shape", "type"], "cone"))
    assert Tracks.load(path).objects[0].shape.type == "cone"
    rc, _, err = cli(capsys, *infer_argv(path, tmp_path / "r.json"))
    assert_one_line(rc, err, "tracks: object 'ramp_object': shape: type must be one of box, cylinder, torus, got 'cone'")
    assert not (tmp_path / "r.json").exists()


def test_a_missing_role_is_refused(tmp_path, capsys):
    path = write_tracks(tmp_path, setter(["objects", 1, "role"], "ball"))
    rc, _, err = cli(capsys, *infer_argv(path, tmp_path / "r.json"))
    assert_one_line(rc, err, "the tracks have no target object for scene object 'target'")


def test_an_offset_outside_the_scene_prior_is_refused(tmp_path, capsys):
    path = write_tracks(tmp_path, setter(["objects", 0, "offset_units"], 9))
    rc, _, err = cli(capsys, *infer_argv(path, tmp_path / "r.json"))
    assert_one_line(rc, err, "offset_units 9 is outside the scene's priors.offset_units [-5, 5]")


def test_a_shape_too_big_for_the_ramp_is_refused(tmp_path, capsys):
    path = write_tracks(tmp_path, setter(["objects", 0, "shape", "size_m"], [2.0, 0.05, 0.05]))
    rc, _, err = cli(capsys, *infer_argv(path, tmp_path / "r.json"))
    assert_one_line(rc, err, "the tracked shapes and offset do not fit the scene: objects[0]")


# -- nothing to infer from ---------------------------------------------------------------------

def nothing_seen(d):
    for o in d["objects"]:
        o["visible"] = [False] * len(o["visible"])
        o["position_m"] = [None] * len(o["visible"])
        o["velocity_mps"] = [None] * len(o["visible"])


def no_frames(d):
    d["time_s"] = []
    for o in d["objects"]:
        o["visible"], o["position_m"], o["velocity_mps"] = [], [], []


@pytest.mark.parametrize("mutate, frames", [(nothing_seen, 61), (no_frames, 0)])
def test_tracks_that_saw_nothing_are_refused_not_answered_by_the_prior(tmp_path, capsys, mutate, frames, demo_frozen):
    from galileo.runner import RunConfig, infer

    path = write_tracks(tmp_path, mutate)
    tracks = Tracks.load(path)               # a valid file: it says the tracker saw nothing
    with pytest.raises(GalileoError, match=f"nothing to infer from: no visible frames \\(the tracks hold {frames} "):
        infer(demo_frozen[0], tracks, RunConfig(chains=1, sweeps=1, workers=1), progress=False)
    rc, _, err = cli(capsys, *infer_argv(path, tmp_path / "r.json"))
    assert_one_line(rc, err, "nothing to infer from: no visible frames")
    assert not (tmp_path / "r.json").exists()


def test_a_still_videos_tracks_are_evidence_not_nothing(demo_frozen):
    """A still video's tracks (objects held at rest where the scene puts them, seen in every
    frame at zero velocity, with a note) pass every check and infer."""
    from galileo.runner import RunConfig, infer
    from galileo.scenarios.ramp.tracking import held_still

    scene = demo_frozen[0]
    tracks = held_still(scene, 31)
    assert tracks.check() is tracks and tracks.require_visible() is tracks
    again = Tracks.from_json(json.loads(json.dumps(tracks.to_json())))
    assert again.notes == tracks.notes and again.notes[0].startswith("nothing moves")
    res = infer(scene, again, RunConfig(chains=1, sweeps=2, workers=1), progress=False)
    assert np.isfinite(res.logliks).all() and res.map_loglik != 0.0


def test_nan_velocity_in_memory_is_refused_naming_object_and_frame(demo_frozen):
    """Library users who build Tracks themselves get the same rule: the likelihood used to
    read a NaN velocity in a visible frame as 0."""
    from galileo.runner import RunConfig, infer
    from galileo.scenarios.ramp.likelihood import VelocityLikelihood

    scene, frozen, _ = demo_frozen
    tracks = Tracks.from_json(frozen.to_json())
    tracks.objects[1].velocity_mps[7, 2] = math.nan
    needle = "tracks: objects[1] ('target').velocity_mps[7]: visible frame 7 has a velocity that is not finite"
    with pytest.raises(TracksError) as e:
        VelocityLikelihood(scene, tracks)
    assert needle in str(e.value)
    with pytest.raises(TracksError, match=r"objects\[1\] \('target'\)\.velocity_mps\[7\]"):
        infer(scene, tracks, RunConfig(chains=1, sweeps=1, workers=1), progress=False)


def test_in_memory_tracks_checks(demo_frozen):
    _, frozen, _ = demo_frozen
    tracks = Tracks.from_json(frozen.to_json())
    tracks.objects[0].visible = tracks.objects[0].visible.astype(int)
    with pytest.raises(TracksError, match=r"objects\[0\] \('ramp_object'\)\.visible: expected 61 booleans"):
        tracks.check()
    tracks = Tracks.from_json(frozen.to_json())
    tracks.objects[1].position_m = tracks.objects[1].position_m[:-1]
    with pytest.raises(TracksError, match=r"position_m: expected 61 x 3 numbers, got shape \(60, 3\)"):
        tracks.check()
    tracks = Tracks.from_json(frozen.to_json())
    tracks.objects[0].offset_units = 1.5
    with pytest.raises(TracksError, match="offset_units: expected null or an integer"):
        tracks.check()
    with pytest.raises(TracksError, match="fps: expected a number"):
        Tracks(math.inf, frozen.objects).check()


# -- sigma ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("sigma", [math.nan, math.inf, -math.inf, 0.0, -0.05, 1e-300, 1e308])
def test_the_ramp_likelihood_refuses_a_sigma_that_is_no_noise(demo_frozen, sigma):
    from galileo.scenarios.ramp.likelihood import VelocityLikelihood

    scene, tracks, _ = demo_frozen
    with pytest.raises(GalileoError, match="likelihood: sigma_mps") as e:
        VelocityLikelihood(scene, tracks, sigma_mps=sigma)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("sigma", [math.nan, math.inf, 0.0, -1.0, 1e-300])
def test_the_splash_likelihood_refuses_a_sigma_that_is_no_noise(sigma):
    from galileo.datatypes import ObjectTrack
    from galileo.scenarios.splash.likelihood import SplashLikelihood
    from galileo.scenarios.splash.scene import default_scene
    from galileo.shapes import Box

    scene = default_scene("vcyl", 20.0, 2.0, 0.7, release_s=-12 / 240)
    n = 5
    track = ObjectTrack("object", "object", np.zeros((n, 3)), np.zeros((n, 3)), np.ones(n, bool),
                        Box((0.01, 0.01, 0.01)))
    with pytest.raises(GalileoError, match="likelihood: sigma_px"):
        SplashLikelihood(scene, Tracks(scene.fps, [track]), sigma)
    track.visible[:] = False
    with pytest.raises(GalileoError, match="nothing to infer from: no visible frames"):
        SplashLikelihood(scene, Tracks(scene.fps, [track]), 1.0)


@pytest.mark.parametrize("value", ["nan", "inf", "0", "1e-300"])
def test_cli_sigma_that_is_no_noise_is_one_line_exit_2(tmp_path, capsys, value):
    rc, _, err = cli(capsys, *infer_argv(DATA / "tracks.json", tmp_path / "r.json"), "--sigma", value)
    assert_one_line(rc, err, "sigma")
    assert not (tmp_path / "r.json").exists()


# -- result files (galileo predict) -------------------------------------------------------------------

@pytest.fixture(scope="module")
def result_dir(tmp_path_factory, demo_frozen):
    from galileo.runner import RunConfig, infer

    scene, tracks, _ = demo_frozen
    folder = tmp_path_factory.mktemp("result")
    res = infer(scene, tracks, RunConfig(chains=2, sweeps=2, workers=1), progress=False)
    res.save(folder / "result.json")
    return folder


def edited_result(result_dir, tmp_path, edit, keep_samples=True):
    d = json.loads((result_dir / "result.json").read_text())
    edit(d)
    path = tmp_path / "result.json"
    path.write_text(json.dumps(d))
    if keep_samples:
        shutil.copy(result_dir / "result.samples.npz", tmp_path / "result.samples.npz")
    return path


BAD_RESULTS = {
    "samples_path_elsewhere": (setter(["samples_file"], "/elsewhere/result.samples.npz"),
                               "samples_file: expected the name of a file beside the result file (no folder), got "
                               "'/elsewhere/result.samples.npz'"),
    "samples_path_up": (setter(["samples_file"], "../result.samples.npz"), "samples_file: expected the name of a file"),
    "samples_file_missing": (setter(["samples_file"], "other.samples.npz"),
                             "samples_file: other.samples.npz is not beside it in"),
    "samples_file_a_number": (setter(["samples_file"], 3), "samples_file: expected the name of a file"),
    "map_lacks_a_latent": (deleter(["map", "k1"]),
                           "map: lacks latent 'k1' (the result's latents: m1_kg, k1, m2_kg, k2, e_collision)"),
    "map_lacks_a_latent_without_latents": (lambda d: (d["map"].pop("k2"), d.pop("latents")),
                                           "map: lacks latent 'k2'"),
    "map_value_a_string": (setter(["map", "m1_kg"], "0.3"), "map.m1_kg: expected a finite number, got '0.3'"),
    "map_value_negative_mass": (setter(["map", "m2_kg"], -1.0), "map.m2_kg: -1 is outside [1e-06, "),
    "map_extra": (setter(["map", "zeta"], 1.0), "map.zeta: not a latent of this result"),
    "latents_of_another_scene": (setter(["latents"], ["m1_kg", "k1"]),
                                 "latents: ['m1_kg', 'k1'] are not the latents its scene infers"),
    "scene_broken": (setter(["scene", "ramp", "angle_deg"], "steep"), "scene: ramp.angle_deg"),
    "scene_missing": (deleter(["scene"]), "is not a galileo result file: missing 'scene'"),
    "converged_a_string": (setter(["converged"], "no"), "converged: expected true or false, got 'no'"),
    "why_not_a_number": (setter(["why_not"], 5), "why_not: expected a list of strings, got 5"),
    "warmup_negative": (setter(["diagnostics", "warmup_sweeps"], -3),
                        "diagnostics.warmup_sweeps: expected an integer >= 0, got -3"),
}


@pytest.mark.parametrize("case", sorted(BAD_RESULTS))
def test_bad_result_file_is_one_line_exit_2_from_galileo_predict(result_dir, tmp_path, capsys, case):
    from galileo.results import ResultError, load_result

    edit, needle = BAD_RESULTS[case]
    path = edited_result(result_dir, tmp_path, edit)
    with pytest.raises(ResultError) as e:
        load_result(path)
    assert "\n" not in str(e.value) and needle in str(e.value), str(e.value)
    rc, out, err = cli(capsys, "predict", "--result", path, "--angle-deg", 10)
    assert_one_line(rc, err, needle)
    assert out == ""


def test_a_result_without_its_record_predicts_from_the_map_when_told(result_dir, tmp_path, capsys):
    path = edited_result(result_dir, tmp_path, setter(["samples_file"], None), keep_samples=False)
    rc, out, err = cli(capsys, "predict", "--result", path, "--angle-deg", 10)
    assert rc == 0, err
    assert json.loads(out)["will_it_move"]["posterior_share_moving"] is None


def test_a_record_of_another_result_is_refused(result_dir, tmp_path, capsys):
    path = edited_result(result_dir, tmp_path, lambda d: None, keep_samples=False)
    np.savez(tmp_path / "result.samples.npz", names=np.array(["a", "b"]), samples=np.zeros((1, 2, 2)))
    rc, _, err = cli(capsys, "predict", "--result", path, "--angle-deg", 10)
    assert_one_line(rc, err, "samples of shape (1, 2, 2), expected (chains, sweeps, 5)")
    np.savez(tmp_path / "result.samples.npz", names=np.array(["m1_kg", "k1", "m2_kg", "k2", "e_collision"]),
             samples=np.full((1, 2, 5), np.nan))
    rc, _, err = cli(capsys, "predict", "--result", path, "--angle-deg", 10)
    assert_one_line(rc, err, "samples are not all finite numbers")


@pytest.mark.parametrize("content", [b"PK\x03\x04" + b"x" * 100, b"not a zip at all", None])
def test_a_corrupt_record_is_one_line_exit_2(result_dir, tmp_path, capsys, content):
    path = edited_result(result_dir, tmp_path, lambda d: None)
    npz = tmp_path / "result.samples.npz"
    if content is None:      # half of the real record (a copy cut short)
        data = npz.read_bytes()
        npz.write_bytes(data[:len(data) // 2])
    else:
        npz.write_bytes(content)
    rc, out, err = cli(capsys, "predict", "--result", path, "--angle-deg", 10)
    assert_one_line(rc, err, f"cannot read sample record {npz}")
    assert out == ""


def test_an_unknown_scenario_in_a_result_is_refused(result_dir, tmp_path):
    from galileo.results import ResultError, load_result

    for value, needle in (("cannon", "scenario: unknown scenario 'cannon'"), (["ramp"], "scenario: expected a name")):
        path = edited_result(result_dir, tmp_path, setter(["scenario"], value))
        with pytest.raises(ResultError) as e:
            load_result(path)
        assert needle in str(e.value)


def test_the_saved_result_predicts(result_dir, capsys):
    rc, out, err = cli(capsys, "predict", "--result", result_dir / "result.json", "--angle-deg", 10)
    assert rc == 0, err
    assert 0.0 <= json.loads(out)["will_it_move"]["posterior_share_moving"] <= 1.0


# -- the video against the scene's camera -----------------------------------------------------------

W, H, N = 64, 48, 10


@pytest.fixture(scope="module")
def small_scene(tmp_path_factory):
    """A ramp scene whose camera describes a 64x48, 30 fps, 10-frame video, saved."""
    from galileo.camera import look_at_camera
    from galileo.scenarios.ramp.scene import default_scene

    cam = look_at_camera((-0.2, -1.2, 0.3), (-0.2, 0.0, 0.16), focal_px=56.0, width_px=W, height_px=H, n_frames=N)
    scene = default_scene(20, camera=cam)
    path = tmp_path_factory.mktemp("scene") / "scene.json"
    scene.save(path)
    return scene, path


def video(path, fps=30.0, n=N, size=(W, H)):
    from galileo.video import write_video

    rng = np.random.default_rng(0)
    write_video(path, [rng.integers(0, 255, (size[1], size[0], 3), dtype=np.uint8) for _ in range(n)], fps)
    return path


@pytest.mark.parametrize("kwargs, needle", [
    (dict(fps=15.0), "is at 15 fps but the scene's camera.fps is 30 (they must agree within 1%)"),
    (dict(fps=60.0), "is at 60 fps but the scene's camera.fps is 30 (they must agree within 1%)"),
    (dict(fps=30.6), "is at 30.6 fps but the scene's camera.fps is 30"),
    (dict(n=N - 3), f"has {N - 3} frames but the scene's camera.n_frames is {N} (the scene file describes another "
                    f"cut of the video; if you trimmed it, set camera.n_frames to {N - 3})"),
    (dict(n=N + 5), f"has {N + 5} frames but the scene's camera.n_frames is {N}"),
    (dict(size=(2 * W, 2 * H)), f"is {2 * W}x{2 * H} but the scene's camera is {W}x{H}"),
    (dict(size=(W, H + 2)), f"is {W}x{H + 2} but the scene's camera is {W}x{H}"),
])
def test_a_video_the_camera_does_not_describe_is_refused(small_scene, tmp_path, capsys, kwargs, needle):
    from galileo import registry
    from galileo.video import VideoMismatch

    scene, scene_path = small_scene
    path = video(tmp_path / "v.mp4", **kwargs)
    with pytest.raises(VideoMismatch) as e:
        registry.of(scene).track(path, scene, progress=False)
    assert needle in str(e.value) and "\n" not in str(e.value)
    rc, _, err = cli(capsys, "track", path, "--scene", scene_path, "--out", tmp_path / "t.json", "--quiet")
    assert_one_line(rc, err, needle)
    assert not (tmp_path / "t.json").exists()


def test_a_video_the_camera_describes_passes(small_scene, tmp_path):
    from galileo.video import read_video_yuv

    scene, _ = small_scene
    for fps in (30.0, 29.97, 30.25):     # within 1%
        y, uv, info = read_video_yuv(video(tmp_path / f"v{fps}.mp4", fps=fps), scene.camera, min_frames=2)
        assert y.shape == (N, H, W) and info.n_frames == N


def test_the_splash_tracker_checks_the_video_too(tmp_path):
    from galileo import registry
    from galileo.camera import look_at_camera
    from galileo.scenarios.splash.scene import default_scene
    from galileo.video import VideoMismatch
    import dataclasses

    scene = default_scene("vcyl", 20.0, 2.0, 0.7, release_s=-12 / 240)
    cam = scene.camera
    scene = dataclasses.replace(scene, camera=look_at_camera((0, -1, 0.2), (0, 0, 0.2), width_px=W, height_px=H,
                                                             fps=cam.fps, n_frames=N))
    with pytest.raises(VideoMismatch, match=f"is at 15 fps but the scene's camera.fps is {cam.fps:g}"):
        registry.of(scene).track(video(tmp_path / "v.mp4", fps=15.0), scene, progress=False)
    with pytest.raises(VideoMismatch, match=f"has {N + 1} frames but the scene's camera.n_frames is {N}"):
        registry.of(scene).track(video(tmp_path / "w.mp4", fps=cam.fps, n=N + 1), scene, progress=False)
