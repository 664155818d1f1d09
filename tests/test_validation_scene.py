"""Scene validation (issue 15): every rule family refuses a bad scene in one line naming the
field and the bound, the same through `registry.load_scene`, `galileo simulate --scene` (exit
code 2, one stderr line), scenes built in code and `with_values` (so `simulate --set` and the
quick form); every value at a bound's valid edge simulates to finite numbers."""
import contextlib
import copy
import dataclasses
import io
import json
import math

import numpy as np
import pytest

from galileo import registry
from galileo.cli import main
from galileo.errors import GalileoError, SceneError
from galileo.scenarios.ramp import scene as ramp
from galileo.scenarios.splash import scene as splash
from galileo.shapes import Shape

from conftest import DATA

RAMP = json.loads((DATA / "scene.json").read_text())
SPLASH = splash.default_scene("box", 27.0, 1.3, 1.05, area_cm2=9.0, release_s=-5 / 240).to_json()


def run_cli(args):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(args)
    return rc, out.getvalue(), err.getvalue()


def mutated(base, *changes):
    """A copy of `base` with (path, value) changes; value DELETE removes the key."""
    d = copy.deepcopy(base)
    for path, value in changes:
        parent = d
        for k in path[:-1]:
            parent = parent[k]
        if value is DELETE:
            del parent[path[-1]]
        else:
            parent[path[-1]] = value
    return d


DELETE = object()


def assert_refused(tmp_path, doc, message):
    """`doc` as a scene file is refused with exactly `message` (after the file's path) by the
    loader and by `galileo simulate` (exit 2, that one line on stderr, no output file)."""
    p = tmp_path / "scene.json"
    p.write_text(json.dumps(doc) if not isinstance(doc, str) else doc)
    with pytest.raises(SceneError) as info:
        registry.load_scene(p)
    assert str(info.value) == f"{p}: {message}"
    out = tmp_path / "traj.json"
    rc, _, err = run_cli(["simulate", "--scene", str(p), "--frames", "3", "--out", str(out)])
    assert (rc, err) == (2, f"galileo: error: {p}: {message}\n")
    assert not out.exists()


# -- types and finite values ------------------------------------------------------------------------

@pytest.mark.parametrize("change, message", [
    ((("objects", 0, "mass_kg"), "heavy"), "objects[0].mass_kg: expected a number, got 'heavy'"),
    ((("objects", 0, "friction"), True), "objects[0].friction: expected a number, got True"),
    ((("objects", 0, "mass_kg"), float("nan")), "objects[0].mass_kg: expected a finite number, got nan"),
    ((("gravity_mps2",), float("inf")), "gravity_mps2: expected a finite number, got inf"),
    ((("objects", 1, "distance_m"), "nan"), "objects[1].distance_m: expected a number, got 'nan'"),
    ((("camera", "K"), [["560", "0", "320"], ["0", "560", "240"], ["0", "0", "1"]]),
     "camera.K: expected a 3x3 matrix (a list of 3 rows of 3 numbers), got [['560', '0', '320'], ['0', '560', "
     "'240'], ['0', '0', '1']]"),
    ((("camera", "world_to_camera"), [[1, 0, 0, 0]] * 3), "camera.world_to_camera: expected a 4x4 matrix (a list "
     "of 4 rows of 4 numbers), got [[1, 0, 0, 0], [1, 0, 0, 0], [1, 0, 0, 0]]"),
    ((("objects", 0, "name"), 7), "objects[0].name: expected a non-empty string, got 7"),
    ((("priors", "shape_types"), ["box", 3]),
     "priors.shape_types: expected a non-empty list from box, cylinder, torus, got ['box', 3]"),
])
def test_types_and_finite_values(tmp_path, change, message):
    assert_refused(tmp_path, mutated(RAMP, change), message)


# -- ranges: every bound named with the field ----------------------------------------------------------

@pytest.mark.parametrize("base, change, message", [
    (RAMP, (("objects", 0, "mass_kg"), 1e308), "objects[0].mass_kg: 1e+308 is outside [1e-06, 100]"),
    (RAMP, (("objects", 1, "mass_kg"), -1), "objects[1].mass_kg: -1 is outside [1e-06, 100]"),
    (RAMP, (("objects", 0, "mass_kg"), 0), "objects[0].mass_kg: 0 is outside [1e-06, 100]"),
    (RAMP, (("objects", 0, "mass_kg"), 1e-18), "objects[0].mass_kg: 1e-18 is outside [1e-06, 100]"),
    (RAMP, (("objects", 1, "mass_kg"), 1e-9), "objects[1].mass_kg: 1e-09 is outside [1e-06, 100]"),
    (RAMP, (("objects", 0, "friction"), -0.1), "objects[0].friction: -0.1 is outside [0, 10]"),
    (RAMP, (("objects", 1, "friction"), 11), "objects[1].friction: 11 is outside [0, 10]"),
    (RAMP, (("objects", 0, "restitution"), 5), "objects[0].restitution: 5 is outside [0, 1]"),
    (RAMP, (("collision_restitution",), 1.5), "collision_restitution: 1.5 is outside [0, 1]"),
    (RAMP, (("objects", 0, "shape", "size_m"), [5, 0.05, 0.05]), "objects[0].shape.size_m[0]: 5 is outside [0.001, 2]"),
    (RAMP, (("objects", 1, "shape", "size_m"), [0.1, 0.0001, 0.1]),
     "objects[1].shape.size_m[1]: 0.0001 is outside [0.001, 2]"),
    (RAMP, (("objects", 1, "distance_m"), 1e9), "objects[1].distance_m: 1000000000.0 is outside [0, 2]"),
    (RAMP, (("gravity_mps2",), 1e9), "gravity_mps2: 1000000000.0 is outside (0, 100]"),
    (RAMP, (("gravity_mps2",), -9.81), "gravity_mps2: -9.81 is outside (0, 100]"),
    (RAMP, (("gravity_mps2",), 0), "gravity_mps2: 0 is outside (0, 100]"),
    (RAMP, (("sim_hz",), 2.4e8), "sim_hz: 240000000.0 is outside [60, 10000]"),
    (RAMP, (("sim_hz",), 30), "sim_hz: 30 is outside [60, 10000]"),
    (RAMP, (("camera", "n_frames"), 10_000_000), "camera.n_frames: 10000000 is outside [1, 100000]"),
    (RAMP, (("camera", "fps"), 0), "camera.fps: 0 is outside [1, 1000]"),
    (RAMP, (("camera", "fps"), 2000), "camera.fps: 2000 is outside [1, 1000]"),
    (RAMP, (("camera", "width_px"), 0), "camera.width_px: 0 is outside [16, 16384]"),
    (RAMP, (("camera", "height_px"), 100000), "camera.height_px: 100000 is outside [16, 16384]"),
    (RAMP, (("ramp", "angle_deg"), 60), "ramp.angle_deg: 60 is outside [0, 60)"),
    (RAMP, (("ramp", "length_m"), 100), "ramp.length_m: 100 is outside (0, 10]"),
    (RAMP, (("ramp", "thickness_m"), 0), "ramp.thickness_m: 0 is outside (0, 1]"),
    (RAMP, (("unit_m",), 0), "unit_m: 0 is outside [0.001, 1]"),
    (RAMP, (("priors", "student_t_dof"), 1e308), "priors.student_t_dof: 1e+308 is outside (0, 1000]"),
    (SPLASH, (("object", "density_g_cm3"), 30), "object.density_g_cm3: 30 is outside [0.001, 25]"),
    (SPLASH, (("object", "density_g_cm3"), 1e-300), "object.density_g_cm3: 1e-300 is outside [0.001, 25]"),
    (SPLASH, (("object", "drag_water"), -1), "object.drag_water: -1 is outside [0, 100]"),
    (SPLASH, (("object", "volume_cm3"), 500), "object.volume_cm3: 500 is outside [0.01, 100]"),
    (SPLASH, (("object", "area_cm2"), 1e308), "object.area_cm2: 1e+308 is outside (0, 1000]"),
    (SPLASH, (("release_s",), 61), "release_s: 61 is outside [-4, 60]"),
    (SPLASH, (("release_s",), -5), "release_s: -5 is outside [-4, 60]"),
    (SPLASH, (("release_s",), "x"), "release_s: expected a number, got 'x'"),
    (SPLASH, (("release_s",), math.nan), "release_s: expected a finite number, got nan"),
    (SPLASH, (("push_mps",), -0.1), "push_mps: -0.1 is outside [0, 5]"),
    (SPLASH, (("push_mps",), 6), "push_mps: 6 is outside [0, 5]"),
    (SPLASH, (("log_volume_factor",), -5.1), "log_volume_factor: -5.1 is outside [-5, 5]"),
    (SPLASH, (("log_volume_factor",), 5.1), "log_volume_factor: 5.1 is outside [-5, 5]"),
    (SPLASH, (("log_volume_factor",), 1.4), "object.volume_cm3 x exp(log_volume_factor): 109.49039910480622 is outside [0.01, 100]"),
    (SPLASH, (("tank", "size_m"), [5, 0.16, 0.3]), "tank.size_m[0]: 5 is outside [0.02, 3]"),
    (SPLASH, (("tank", "water_level_m"), 0.3), "tank.water_level_m: 0.3 is outside (0, 0.3)"),
    (SPLASH, (("tank", "water_density_kg_m3"), 1e5), "tank.water_density_kg_m3: 100000.0 is outside [1, 5000]"),
    (SPLASH, (("sim_hz",), 2.4e8), "sim_hz: 240000000.0 is outside [60, 10000]"),
    (SPLASH, (("gravity_mps2",), 1000), "gravity_mps2: 1000 is outside (0, 100]"),
    (SPLASH, (("gravity_mps2",), 0.0), "gravity_mps2: 0.0 is outside (0, 100]"),
    (SPLASH, (("release_m",), [0, 0, 5]), "release_m: z = 5 m is more than 1 m above the water (at 0.2 m)"),
    (SPLASH, (("release_m",), [0, 0, 0.1]), "release_m: the object must be let go above the water (z > 0.2 m)"),
])
def test_ranges_name_the_field_and_the_bound(tmp_path, base, change, message):
    assert_refused(tmp_path, mutated(base, change), message)


# -- whole numbers: refused, never truncated --------------------------------------------------------

@pytest.mark.parametrize("base, change, message", [
    (RAMP, (("objects", 0, "offset_units"), 1.5), "objects[0].offset_units: expected an integer, got 1.5"),
    (RAMP, (("camera", "n_frames"), 60.5), "camera.n_frames: expected an integer, got 60.5"),
    (RAMP, (("priors", "offset_units"), [-5.5, 5]), "priors.offset_units: expected [low, high], two integers, got "
     "[-5.5, 5]"),
])
def test_whole_numbers_are_refused_not_truncated(tmp_path, base, change, message):
    assert_refused(tmp_path, mutated(base, change), message)


def test_whole_numbers_written_as_floats_are_whole():
    d = mutated(RAMP, (("objects", 0, "offset_units"), 2.0), (("camera", "n_frames"), 61.0))
    s = registry.scene_from_json(d)
    assert s.ramp_object.offset_units == 2 and type(s.ramp_object.offset_units) is int
    assert s.camera.n_frames == 61 and type(s.camera.n_frames) is int


# -- the camera: a proper intrinsic matrix and a rigid transform -------------------------------------------

def _mirrored():
    m = np.array(RAMP["camera"]["world_to_camera"])
    m[:3, 0] *= -1
    return m.tolist()


def _far():
    m = np.array(RAMP["camera"]["world_to_camera"])
    m[:3, 3] = [0, 0, 5000]
    return m.tolist()


@pytest.mark.parametrize("key, value, message", [
    ("K", [[0, 0, 0], [0, 0, 0], [0, 0, 1]], "camera.K: fx = K[0][0] = 0.0 is outside [1, 100000]"),
    ("K", [[560, 0, 320], [0, -560, 240], [0, 0, 1]], "camera.K: fy = K[1][1] = -560.0 is outside [1, 100000]"),
    ("K", [[560, 50, 320], [0, 560, 240], [0, 0, 1]],
     "camera.K: the skew K[0][1] = 50.0 is outside [-0.01, 0.01] x fx"),
    ("K", [[560, 0, 320], [0, 560, 240], [0, 0, 2]], "camera.K: expected an intrinsic matrix [[fx, s, cx], [0, fy, "
     "cy], [0, 0, 1]], got rows [0.0, 560.0, 240.0] and [0.0, 0.0, 2.0]"),
    ("K", [[560, 0, 5000], [0, 560, 240], [0, 0, 1]],
     "camera.K: the principal point's cx = K[0][2] = 5000.0 is outside [-320, 960]"),
    ("world_to_camera", _mirrored(), "camera.world_to_camera: expected a rotation with determinant +1, got -1 "
     "(a mirror image)"),
    ("world_to_camera", np.diag([2.0, 1, 1, 1]).tolist(), "camera.world_to_camera: expected a rigid transform, its "
     "3x3 rotation orthonormal (R R^T = I within 1e-06)"),
    ("world_to_camera", [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]], "camera.world_to_camera: expected "
     "a rigid transform, its last row [0, 0, 0, 1], got [0.0, 0.0, 1.0, 1.0]"),
    ("world_to_camera", _far(), "camera.world_to_camera: the camera is 5000 m from the world's origin, beyond "
     "1000 m"),
])
def test_camera_is_a_proper_pinhole_camera(tmp_path, key, value, message):
    assert_refused(tmp_path, mutated(RAMP, (("camera", key), value)), message)


def test_singular_camera_no_longer_reaches_tracking(tmp_path):
    """The reported case: a singular K loaded, then `track` failed deep inside."""
    d = mutated(RAMP, (("camera", "K"), [[560, 0, 320], [0, 0, 240], [0, 0, 1]]))
    assert_refused(tmp_path, d, "camera.K: fy = K[1][1] = 0.0 is outside [1, 100000]")


# -- the simulated video's length -----------------------------------------------------------------------------

@pytest.mark.parametrize("base, changes, message", [
    (RAMP, [(("sim_hz",), 9990), (("camera", "n_frames"), 100000)],
     "camera.n_frames: 100000 frames at 30 fps are 33299667 physics steps at sim_hz 9990, more than 2000000 "
     "(shorten the video or lower sim_hz)"),
    # 299 frames x 9000 steps + the release 5/240 s before frame 0 (187.5 steps at 9000 Hz, rounded to 188)
    (SPLASH, [(("sim_hz",), 9000), (("camera", "fps"), 1), (("camera", "n_frames"), 300)],
     "camera.n_frames: 300 frames at 1 fps are 2691188 physics steps at sim_hz 9000, more than 2000000 (shorten "
     "the video or lower sim_hz)"),
])
def test_total_physics_steps_are_bounded(tmp_path, base, changes, message):
    assert_refused(tmp_path, mutated(base, *changes), message)


# -- objects: unique names, proper shapes ---------------------------------------------------------------------

@pytest.mark.parametrize("changes, message", [
    ([(("objects", 1, "name"), "ramp_object")], "objects[1].name: 'ramp_object' is also the name of objects[0] "
     "(names must differ: tracks and trajectories are keyed by them)"),
    ([(("objects", 0, "shape"), {"type": "torus", "size_m": [0.04, 0.04, 0.02]})],
     "objects[0].shape: a torus needs outer diameter x > 2 * tube diameter z, got 0.04 and 0.02"),
    ([(("objects", 0, "shape"), {"type": "cylinder", "size_m": [0.1, 0.04, 0.05]})],
     "objects[0].shape: a cylinder needs size_m y == z (its diameter), got 0.04 and 0.05"),
    ([(("objects", 0, "shape", "type"), "sphere")], "objects[0].shape.type: expected one of box, cylinder, torus, "
     "got 'sphere'"),
])
def test_objects_have_unique_names_and_proper_shapes(tmp_path, changes, message):
    assert_refused(tmp_path, mutated(RAMP, *changes), message)


def test_a_duplicated_object_is_refused(tmp_path):
    d = mutated(RAMP)
    d["objects"].append(copy.deepcopy(d["objects"][1]))
    assert_refused(tmp_path, d, "objects: expected a list of one (ramp object) or two (ramp object, target) objects")


# -- priors -------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("base, change, message", [
    (RAMP, (("priors", "m1_kg"), [0.5, 0.5]), "priors.m1_kg: the low bound (0.5) must be below the high bound (0.5)"),
    (RAMP, (("priors", "k1"), [1, 0]), "priors.k1: expected [low, high] with low <= high, got [1, 0]"),
    (RAMP, (("priors", "m1_kg"), ["0.1", 1]), "priors.m1_kg: expected [low, high], two numbers, got ['0.1', 1]"),
    (RAMP, (("priors", "m2_kg"), [0.1, 1000]), "priors.m2_kg: bounds must be <= 100 kg, got a high bound of 1000"),
    (RAMP, (("priors", "m2_kg"), [0, 1]), "priors.m2_kg: bounds must be >= 1e-06 kg, got a low bound of 0"),
    (RAMP, (("priors", "m1_kg"), [1e-18, 1]), "priors.m1_kg: bounds must be >= 1e-06 kg, got a low bound of 1e-18"),
    (RAMP, (("priors", "log10_sigma_mps"), [-300, 300]),
     "priors.log10_sigma_mps: bounds must be >= -4 log10 m/s, got a low bound of -300"),
    (RAMP, (("priors", "size_m"), [0.001, 5]), "priors.size_m: 0.001 is outside [0.005, 2]"),
    (RAMP, (("priors", "offset_units"), [-5, 100000]), "priors.offset_units: 100000 is outside [-10000, 10000]"),
    (RAMP, (("priors", "shape_types"), ["box", "box"]), "priors.shape_types: each type at most once, got "
     "['box', 'box']"),
    (SPLASH, (("priors", "density_g_cm3"), [2, 1]), "priors.density_g_cm3: expected [low, high] with low <= high, "
     "got [2, 1]"),
    (SPLASH, (("priors", "drag_water"), [0, 2]), "priors.drag_water: bounds must be > 0, got a low bound of 0"),
    (SPLASH, (("priors", "density_g_cm3"), [1e-4, 2]),
     "priors.density_g_cm3: bounds must be >= 0.001 g/cm^3, got a low bound of 0.0001"),
    (SPLASH, (("priors", "release_s"), [0.1, 0.1]),
     "priors.release_s: the low bound (0.1) must be below the high bound (0.1)"),
    (SPLASH, (("priors", "release_s"), [-5, 1]), "priors.release_s: bounds must be >= -4 s, got a low bound of -5"),
    (SPLASH, (("priors", "push_mps"), [0, 6]), "priors.push_mps: bounds must be <= 5 m/s, got a high bound of 6"),
    (SPLASH, (("priors", "log_volume_factor"), [-6, 1]),
     "priors.log_volume_factor: bounds must be >= -5, got a low bound of -6"),
    (SPLASH, (("priors", "start_step"), [5, 30]), "priors.start_step: unknown field; expected one of area_cm2, "
     "density_g_cm3, drag_water, release_s, push_mps, log_volume_factor"),
])
def test_priors_are_proper(tmp_path, base, change, message):
    assert_refused(tmp_path, mutated(base, change), message)


# -- file structure: unknown fields, the JSON reader ---------------------------------------------------------

@pytest.mark.parametrize("base, changes, message", [
    (RAMP, [(("objects", 0, "restitutoin"), 0.5)], "objects[0].restitutoin: unknown field; expected one of name, "
     "role, shape, mass_kg, friction, restitution, material, offset_units"),
    (RAMP, [(("camera", ""), 1)], "camera['']: unknown field; expected one of K, world_to_camera, width_px, "
     "height_px, fps, n_frames, k1"),
    (SPLASH, [(("scenario",), DELETE)], "tank: unknown field; expected one of scenario, version, ramp, unit_m, "
     "start_units, sim_hz, gravity_mps2, objects, priors, collision_restitution, camera (a file without "
     "\"scenario\" is read as a ramp scene)"),
])
def test_unknown_fields_are_named(tmp_path, base, changes, message):
    assert_refused(tmp_path, mutated(base, *changes), message)


def test_deeply_nested_json_is_one_line(tmp_path):
    p = tmp_path / "scene.json"
    p.write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(GalileoError, match=r"nested too deeply") as info:
        registry.load_scene(p)
    assert "\n" not in str(info.value)
    rc, _, err = run_cli(["simulate", "--scene", str(p), "--frames", "3", "--out", str(tmp_path / "t.json")])
    assert rc == 2 and err.startswith("galileo: error: scene file ") and "nested too deeply" in err
    assert len(err.splitlines()) == 1


def test_integer_too_long_to_read_is_one_line(tmp_path):
    p = tmp_path / "scene.json"
    p.write_text('{"sim_hz": ' + "9" * 5000 + "}")
    rc, _, err = run_cli(["simulate", "--scene", str(p), "--frames", "3", "--out", str(tmp_path / "t.json")])
    assert rc == 2 and err.startswith(f"galileo: error: scene file {p} cannot be read: ") and len(err.splitlines()) == 1


def test_huge_integers_are_refused_by_bound():
    d = mutated(RAMP, (("objects", 0, "offset_units"), 10 ** 400))
    with pytest.raises(SceneError, match=r"^objects\[0\]\.offset_units: 1000.*0 is outside \[-10000, 10000\]$"):
        registry.scene_from_json(d)
    d = mutated(RAMP, (("gravity_mps2",), 10 ** 400))
    with pytest.raises(SceneError, match=r"^gravity_mps2: 1000.*0 is outside \(0, 100\]$"):
        registry.scene_from_json(d)


# -- the library: scenes built in code and with_values (simulate --set, the quick form) ---------------------

def test_scenes_built_in_code_are_validated():
    with pytest.raises(SceneError, match=r"^objects\[0\]\.mass_kg: -1 is outside \[1e-06, 100\]$"):
        ramp.default_scene(20, mass_kg=-1)
    with pytest.raises(SceneError, match=r"^objects\[0\]\.shape: a torus needs"):
        ramp.default_scene(20, shape=Shape("torus", (0.04, 0.04, 0.02)))
    with pytest.raises(SceneError, match=r"^objects\[0\]\.shape\.type: expected one of box, cylinder, torus"):
        ramp.default_scene(20, shape=Shape("sphere", (0.04, 0.04, 0.04)))
    cam = ramp.default_camera()
    mirrored = dataclasses.replace(cam, world_to_camera=np.diag([-1.0, 1, 1, 1]) @ cam.world_to_camera)
    with pytest.raises(SceneError, match=r"^camera\.world_to_camera: expected a rotation with determinant \+1"):
        ramp.default_scene(20, camera=mirrored)
    with pytest.raises(SceneError, match=r"^object\.density_g_cm3: 30 is outside \[0\.001, 25\]$"):
        splash.default_scene("box", density_g_cm3=30)


@pytest.mark.parametrize("base, values, message", [(RAMP, v, m) for v, m in [
    ({"m1_kg": 1e308}, "m1_kg: 1e+308 is outside [1e-06, 100]"),
    ({"m2_kg": -1.0}, "m2_kg: -1.0 is outside [1e-06, 100]"),
    ({"m1_kg": 1e-18}, "m1_kg: 1e-18 is outside [1e-06, 100]"),
    ({"k1": math.nan}, "k1: expected a finite number, got nan"),
    ({"k2": 11.0}, "k2: 11.0 is outside [0, 10]"),
    ({"e1": 5.0}, "e1: 5.0 is outside [0, 1]"),
    ({"e_collision": -0.5}, "e_collision: -0.5 is outside [0, 1]"),
    ({"offset_units": 1.5}, "offset_units: expected an integer, got 1.5"),
    ({"angle_deg": math.inf}, "angle_deg: expected a finite number, got inf"),
    ({"log10_sigma_mps": 1e308}, "log10_sigma_mps: 1e+308 is outside [-4, 1]"),
    ({"offset_units": 30.0}, "objects[0]: starts 1.235 m up the ramp, beyond its length_m 0.9"),
]] + [(SPLASH, v, m) for v, m in [
    ({"release_s": 61.0}, "release_s: 61.0 is outside [-4, 60]"),
    ({"release_s": math.nan}, "release_s: expected a finite number, got nan"),
    ({"release_s": "x"}, "release_s: expected a number, got 'x'"),
    ({"push_mps": -0.5}, "push_mps: -0.5 is outside [0, 5]"),
    ({"log_volume_factor": 5.5}, "log_volume_factor: 5.5 is outside [-5, 5]"),
    ({"start_step": 5}, "unknown name 'start_step'; expected one of area_cm2, density_g_cm3, drag_water, release_s, "
     "push_mps, log_volume_factor, volume_cm3"),
    ({"density_g_cm3": 1e308}, "density_g_cm3: 1e+308 is outside [0.001, 25]"),
    ({"volume_cm3": 0.0}, "volume_cm3: 0.0 is outside [0.01, 100]"),
    ({"drag_water": -1.0}, "drag_water: -1.0 is outside [0, 100]"),
]])
def test_with_values_checks_every_value(base, values, message):
    scene = registry.scene_from_json(copy.deepcopy(base))
    with pytest.raises(SceneError) as info:
        scene.with_values(values)
    assert str(info.value) == message


@pytest.mark.parametrize("setting, message", [
    ("m1_kg=1e308", "m1_kg: 1e+308 is outside [1e-06, 100]"),
    ("m2_kg=1e-18", "m2_kg: 1e-18 is outside [1e-06, 100]"),
    ("k1=-1", "k1: -1.0 is outside [0, 10]"),
    ("e1=5", "e1: 5.0 is outside [0, 1]"),
    ("offset_units=1.5", "offset_units: expected an integer, got 1.5"),
])
def test_simulate_set_is_validated(tmp_path, setting, message):
    p = tmp_path / "scene.json"
    p.write_text(json.dumps(RAMP))
    out = tmp_path / "t.json"
    for args in (["--scene", str(p)], ["--scenario", "ramp"]):   # a scene file and the scenario's default scene
        rc, _, err = run_cli(["simulate", *args, "--set", setting, "--frames", "3", "--out", str(out)])
        assert (rc, err) == (2, f"galileo: error: {message}\n")
        assert not out.exists()


@pytest.mark.parametrize("change, message", [
    ((("gravity_mps2",), 0), "gravity_mps2: 0 is outside (0, 100]"),       # was a ZeroDivisionError in moves.py
    ((("objects", 0, "mass_kg"), 1e-18), "objects[0].mass_kg: 1e-18 is outside [1e-06, 100]"),   # was frozen, exit 0
])
def test_infer_refuses_a_scene_without_gravity_or_with_a_weightless_object(tmp_path, change, message):
    p = tmp_path / "scene.json"
    p.write_text(json.dumps(mutated(RAMP, change)))
    out = tmp_path / "r.json"
    rc, _, err = run_cli(["infer", str(DATA / "none.mp4"), "--scene", str(p), "--tracks", str(DATA / "tracks.json"),
                          "--chains", "2", "--sweeps", "2", "--workers", "1", "--quiet", "--out", str(out)])
    assert (rc, err) == (2, f"galileo: error: {p}: {message}\n")
    assert not out.exists()


# -- consistency: one rule in one place ------------------------------------------------------------------------

def test_latent_limits_are_the_scene_bounds():
    for name in ("m1_kg", "m2_kg"):
        lat = ramp.LATENT_SPECS[name]
        assert (lat.limits, lat.limits_open_low) == ((ramp.MASS_KG.lo, ramp.MASS_KG.hi), ramp.MASS_KG.lo_open)
    for name in ("k1", "k2"):
        assert ramp.LATENT_SPECS[name].limits == (ramp.FRICTION.lo, ramp.FRICTION.hi)
    assert ramp.OPTIONAL_SPECS["e_collision"].limits == (ramp.RESTITUTION.lo, ramp.RESTITUTION.hi)
    assert 10 ** np.array(ramp.OPTIONAL_SPECS["log10_sigma_mps"].limits) == pytest.approx(ramp.SIGMA_LIMITS_MPS)
    from galileo.scenarios.ramp import RampScenario
    assert RampScenario.noise.limits == ramp.SIGMA_LIMITS_MPS
    for name, bound in (("area_cm2", splash.AREA_CM2), ("density_g_cm3", splash.DENSITY_G_CM3),
                        ("drag_water", splash.DRAG_WATER), ("release_s", splash.RELEASE_S),
                        ("push_mps", splash.PUSH_MPS), ("log_volume_factor", splash.LOG_VOLUME_FACTOR)):
        assert splash.LATENT_SPECS[name].limits == (bound.lo, bound.hi)


# -- valid edges simulate to finite numbers ---------------------------------------------------------------------

RAMP_EDGES = [
    [(("objects", 0, "mass_kg"), 100), (("objects", 1, "mass_kg"), 1e-6)],
    [(("objects", 0, "mass_kg"), 1e-6), (("objects", 1, "mass_kg"), 100)],
    [(("objects", 0, "friction"), 10), (("objects", 1, "friction"), 0), (("objects", 0, "restitution"), 1),
     (("objects", 1, "restitution"), 1)],
    [(("gravity_mps2",), 100), (("ramp", "angle_deg"), 59.99), (("objects", 0, "friction"), 0),
     (("collision_restitution",), 1)],
    [(("gravity_mps2",), 5e-324), (("ramp", "angle_deg"), 0)],
    [(("objects", 0, "shape", "size_m"), [0.001, 0.001, 0.001]), (("objects", 1, "distance_m"), 2),
     (("objects", 1, "shape", "size_m"), [2, 2, 2])],
    [(("ramp", "length_m"), 10), (("ramp", "width_m"), 10), (("ramp", "thickness_m"), 1),
     (("objects", 0, "shape", "size_m"), [2, 2, 2]), (("objects", 1, "distance_m"), 0),
     (("objects", 0, "offset_units"), 0), (("start_units",), 100)],
    [(("sim_hz",), 10000), (("camera", "fps"), 1000), (("camera", "n_frames"), 200)],
    [(("sim_hz",), 60), (("camera", "fps"), 60), (("ramp", "angle_deg"), 45)],
]
SPLASH_EDGES = [
    [(("object", "density_g_cm3"), 25), (("object", "drag_water"), 100), (("gravity_mps2",), 100)],
    [(("object", "density_g_cm3"), 0.001), (("object", "drag_water"), 0), (("gravity_mps2",), 5e-324)],
    [(("object", "volume_cm3"), 100), (("object", "area_cm2"), 25), (("release_m",), [0, 0, 1.2]),
     (("release_s",), -4), (("push_mps",), 5)],
    [(("release_s",), 60), (("camera", "n_frames"), 20), (("log_volume_factor",), -5), (("object", "area_cm2"), 0.05)],
    [(("object", "volume_cm3"), 0.01), (("object", "area_cm2"), 0.05), (("tank", "water_density_kg_m3"), 5000)],
    [(("sim_hz",), 60), (("camera", "fps"), 60), (("tank", "water_density_kg_m3"), 1)],
]


@pytest.mark.parametrize("base, changes", [(RAMP, c) for c in RAMP_EDGES] + [(SPLASH, c) for c in SPLASH_EDGES])
def test_values_at_the_bounds_simulate_to_finite_numbers(tmp_path, base, changes):
    p = tmp_path / "scene.json"
    p.write_text(json.dumps(mutated(base, *changes)))
    registry.load_scene(p)
    out = tmp_path / "traj.json"
    rc, _, err = run_cli(["simulate", "--scene", str(p), "--frames", "20", "--out", str(out)])
    assert rc == 0, err
    traj = json.loads(out.read_text())
    for o in traj["objects"]:
        for key in ("position_m", "velocity_mps"):
            assert np.all(np.isfinite(np.array(o[key], float))), (changes, key)


@pytest.mark.parametrize("shape", [Shape("box", (0.001, 0.001, 0.001)), Shape("cylinder", (0.001, 0.001, 0.001)),
                                   Shape("torus", (0.01, 0.01, 0.001)), Shape("box", (0.06, 0.05, 0.04))])
def test_the_lightest_mass_a_scene_may_hold_slides_as_a_heavy_one(shape):
    """Newton: an object sliding alone down a ramp accelerates at g (sin a - k cos a) whatever
    its mass. Bullet takes a mass or an inertia below its epsilon (2.2e-16) for none: a 1e-18 kg
    object never moved, a 1e-9 kg millimetre cylinder slid 18 mm off its path. At the lowest
    mass the bound admits, the smallest shapes slide as they do at 1 kg to well within a
    pixel (10 um; what separates them is Bullet's rounding: under 1 um)."""
    from galileo.scenarios.ramp.physics import Simulator
    from galileo.sim.bullet import client_lock

    runs = []
    for mass_kg in (1.0, ramp.MASS_KG.lo):
        scene = ramp.default_scene(20.0, mass_kg=mass_kg, friction=0.2, target=None, shape=shape)
        with client_lock:
            runs.append(Simulator(scene).run(31, fps=30).position_m[0])
    heavy, light = runs
    assert np.linalg.norm(heavy[-1] - heavy[0]) > 0.5           # it slid (0.71 m in the second)
    assert np.abs(light - heavy).max() < 1e-5


# -- a run's length (what `simulate --frames/--fps` should check: Scene.check_simulation) ------------------

@pytest.mark.parametrize("base, n_frames, fps, message", [
    (RAMP, 10 ** 9, 30, "--frames: 1000000000 is outside [1, 100000]"),
    (RAMP, 10, 0.5, "--fps: 0.5 is outside [1, 1000]"),
    (RAMP, 10, 7, "sim_hz (240) must be a multiple of --fps (7)"),
    (SPLASH, 100_000, 1, "--frames: 100000 frames at 1 fps are 23999765 physics steps at sim_hz 240, more "
     "than 2000000 (shorten the video or lower sim_hz)"),
])
def test_check_simulation_bounds_a_run(base, n_frames, fps, message):
    scene = registry.scene_from_json(copy.deepcopy(base))
    with pytest.raises(SceneError) as info:
        scene.check_simulation(n_frames, fps, ("--fps", "--frames"))
    assert str(info.value) == message
    scene.check_simulation(100, 30, ("--fps", "--frames"))   # a usual run passes


def test_priors_built_in_code_are_checked():
    with pytest.raises(SceneError, match=r"^priors\.student_t_dof: 1e\+308 is outside \(0, 1000\]$"):
        ramp.Priors(student_t_dof=1e308)
    s = ramp.default_scene(20)
    bad = dataclasses.replace(s, priors=dataclasses.replace(s.priors, offset_units=(-5.5, 5)))
    with pytest.raises(SceneError, match=r"^priors\.offset_units: expected an integer, got -5\.5$"):
        bad.validate()
    bad = dataclasses.replace(s, priors=dataclasses.replace(s.priors, bounds={**s.priors.bounds, "k1": (1.0, 0.5)}))
    with pytest.raises(SceneError, match=r"^priors\.k1: the low bound \(1\) must be below the high bound \(0\.5\)$"):
        bad.validate()


@pytest.mark.parametrize("shape, volume_m3", [
    (Shape("cylinder", (0.05, 0.001, 0.001)), math.pi * 0.0005 ** 2 * 0.05),
    (Shape("cylinder", (2.0, 0.001, 0.001)), math.pi * 0.0005 ** 2 * 2.0),
    (Shape("torus", (0.01, 0.01, 0.001)), 2 * math.pi ** 2 * 0.0045 * 0.0005 ** 2),
    (Shape("torus", (0.0126, 0.0126, 0.0035)), 2 * math.pi ** 2 * 0.00455 * 0.00175 ** 2),
    (Shape("box", (0.001, 2.0, 0.001)), 0.001 * 2.0 * 0.001),
])
def test_the_smallest_valid_shapes_have_their_volume_and_positive_inertia(shape, volume_m3):
    """trimesh's primitives at millimetre sizes: a negative volume and inertia, or volume 0
    (shapes.mesh now builds them at unit scale)."""
    from galileo.shapes import coarse_triangles, mesh

    m = mesh(shape)
    assert m.is_watertight and m.volume == pytest.approx(volume_m3, rel=0.01)
    assert np.all(shape.inertia_per_kg() > 0)
    assert np.isfinite(coarse_triangles(shape)).all()
