"""Scene data: JSON round trip, field-named errors, priors, latents, camera, initial pose."""
import copy
import json
import math

import numpy as np
import pytest

from galileo.errors import GalileoError, SceneError
from galileo.scenarios.ramp.scene import (DEFAULT_BOUNDS, LATENTS, Priors, Scene, default_camera, default_scene,
                           look_at_camera, scene_from_json)
from galileo.shapes import Shape


def round_trip(scene):
    # through real JSON text, not just the dict
    return scene_from_json(json.loads(json.dumps(scene.to_json())))


# -- round trip ---------------------------------------------------------------------------

@pytest.mark.parametrize("kwargs", [
    dict(angle_deg=20.0),
    dict(angle_deg=10.0, target=None),
    dict(angle_deg=35.0, mass_kg=0.07, friction=0.45, target="foam", offset_units=-4, distance_m=0.25,
         shape=Shape("torus", (0.08, 0.08, 0.02))),
    dict(angle_deg=15.0, shape=Shape("cylinder", (0.1, 0.03, 0.03)), offset_units=5),
])
def test_round_trip_equal(kwargs):
    s = default_scene(**kwargs)
    t = round_trip(s)
    assert t == s
    assert t.to_json() == s.to_json()


def test_round_trip_with_camera():
    s = default_scene(20, camera=default_camera(fps=60, n_frames=120))
    t = round_trip(s)
    assert t.camera is not None
    np.testing.assert_array_equal(t.camera.K, s.camera.K)
    np.testing.assert_array_equal(t.camera.world_to_camera, s.camera.world_to_camera)
    assert (t.camera.fps, t.camera.n_frames, t.camera.width_px, t.camera.height_px) == (60, 120, 640, 480)
    assert t == s
    assert t != default_scene(20, camera=default_camera(fps=30, n_frames=120))
    assert t != default_scene(20)


def test_round_trip_changed_priors():
    s = default_scene(20)
    s = Scene(s.ramp, s.objects, priors=s.priors.with_bounds(m1_kg=(0.01, 0.5), k2=(0.1, 0.9)))
    t = round_trip(s)
    assert t.priors.bounds["m1_kg"] == (0.01, 0.5)
    assert t.priors.bounds["k2"] == (0.1, 0.9)
    assert t == s


def test_save_load(tmp_path):
    s = default_scene(25, camera=default_camera(), target="foam")
    p = tmp_path / "scene.json"
    s.save(p)
    assert Scene.load(p) == s


# -- malformed fields ------------------------------------------------------------------------

BASE = default_scene(20, camera=default_camera()).to_json()


def _set(path, value):
    def f(d):
        *head, last = path
        for k in head:
            d = d[k]
        d[last] = value
    return f


def _pop(path):
    def f(d):
        *head, last = path
        for k in head:
            d = d[k]
        del d[last]
    return f


MALFORMED = [
    # (mutation, field the message must name)
    (_set(["objects", 0, "mass_kg"], -1), "objects[0].mass_kg"),
    (_set(["objects", 0, "mass_kg"], 0), "objects[0].mass_kg"),
    (_set(["objects", 0, "mass_kg"], "heavy"), "objects[0].mass_kg"),
    (_pop(["objects", 0, "mass_kg"]), "objects[0].mass_kg"),
    (_set(["objects", 1, "mass_kg"], None), "objects[1].mass_kg"),
    (_set(["objects", 0, "friction"], True), "objects[0].friction"),
    (_set(["objects", 1, "friction"], -0.1), "objects[1].friction"),
    (_set(["objects", 0, "restitution"], 1.5), "objects[0].restitution"),
    (_set(["objects", 0, "offset_units"], 2.5), "objects[0].offset_units"),
    (_set(["ramp", "angle_deg"], 75), "ramp.angle_deg"),
    (_set(["ramp", "angle_deg"], -5), "ramp.angle_deg"),
    (_set(["ramp", "angle_deg"], float("nan")), "ramp.angle_deg"),
    (_pop(["ramp", "angle_deg"]), "ramp.angle_deg"),
    (_set(["ramp", "length_m"], 0), "ramp.length_m"),
    (_set(["camera", "K"], [[1, 2], [3, 4]]), "camera.K"),
    (_set(["camera", "K"], "identity"), "camera.K"),
    (_set(["camera", "K"], [[0, 0, 320], [0, 560, 240], [0, 0, 1]]), "camera.K"),
    (_set(["camera", "world_to_camera"], np.diag([2.0, 1, 1, 1]).tolist()), "camera.world_to_camera"),
    (_set(["camera", "n_frames"], 0), "camera.n_frames"),
    (_set(["objects", 1, "kind"], "plastic"), "objects[1].kind"),
    (_set(["objects", 1, "kind"], "plastic\nfoam"), "objects[1].kind"),
    (_set(["objects", 1, "role"], "ramp"), "objects[1].role"),
    (_set(["objects", 0, "shape", "type"], "sphere"), "objects[0].shape"),
    (_set(["objects", 0, "shape", "size_m"], [0.1, 0.1]), "objects[0].shape.size_m"),
    (_set(["objects", 0, "shape"], {"type": "cylinder", "size_m": [0.1, 0.04, 0.05]}), "objects[0].shape"),
    (_set(["objects", 0, "shape"], {"type": "torus", "size_m": [0.04, 0.04, 0.02]}), "objects[0].shape"),
    (_set(["objects", 0, "name"], ""), "objects[0].name"),
    (_set(["objects", 0], "box"), "objects[0]"),
    (_set(["priors", "k1"], [1, 0]), "priors.k1"),
    (_set(["priors", "k1"], [-1, 0.5]), "priors.k1"),
    (_set(["priors", "m2_kg"], [0, 1]), "priors.m2_kg"),
    (_set(["priors", "m1_kg"], "wide"), "priors.m1_kg"),
    (_set(["priors", "shape_types"], ["sphere"]), "priors.shape_types"),
    (_pop(["objects"]), "objects"),
    (_set(["objects"], []), "objects"),
    (_pop(["ramp"]), "ramp"),
    (_set(["version"], 3), "version"),
    (_set(["unit_m"], -0.02), "unit_m"),
]


@pytest.mark.parametrize("mutate,field", MALFORMED, ids=[f"{i}-{f}" for i, (_, f) in enumerate(MALFORMED)])
def test_malformed_names_field(mutate, field):
    d = copy.deepcopy(BASE)
    mutate(d)
    with pytest.raises(SceneError) as info:
        scene_from_json(d)
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.startswith(field + ":") or msg.startswith(field + "."), msg


def test_unmodified_base_parses():
    # the malformed cases fail because of their mutation, not because BASE is broken
    assert scene_from_json(copy.deepcopy(BASE)) == default_scene(20, camera=default_camera())


def test_top_level_not_an_object():
    with pytest.raises(SceneError):
        scene_from_json([BASE])


def test_start_beyond_ramp_is_rejected():
    d = copy.deepcopy(BASE)
    d["objects"][0]["offset_units"] = 20  # 1.0 m up a 0.9 m ramp
    with pytest.raises(SceneError, match=r"^objects\[0\]"):
        scene_from_json(d)


def test_load_missing_file_names_path(tmp_path):
    p = tmp_path / "nope.json"
    with pytest.raises(GalileoError) as info:
        Scene.load(p)
    assert str(p) in str(info.value)
    assert "\n" not in str(info.value)


def test_load_invalid_json_names_path(tmp_path):
    p = tmp_path / "broken.json"
    p.write_text('{"version": 1, "ramp": ')
    with pytest.raises(GalileoError) as info:
        Scene.load(p)
    assert str(p) in str(info.value)
    assert "\n" not in str(info.value)


def test_load_malformed_names_path_and_field(tmp_path):
    d = copy.deepcopy(BASE)
    d["objects"][0]["mass_kg"] = -2
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(d))
    with pytest.raises(SceneError) as info:
        Scene.load(p)
    msg = str(info.value)
    assert str(p) in msg and "objects[0].mass_kg" in msg and "\n" not in msg


# -- priors ---------------------------------------------------------------------------------

def test_log_prob_inside_is_minus_sum_log_width():
    pr = Priors().with_bounds(m1_kg=(0.1, 0.6), k1=(0.0, 0.25))
    lp = pr.log_prob({"m1_kg": 0.3, "k1": 0.2})
    assert lp == pytest.approx(-(math.log(0.5) + math.log(0.25)))
    # constant inside: a different interior point has the same density
    assert pr.log_prob({"m1_kg": 0.59, "k1": 0.01}) == lp
    # bounds are inclusive
    assert pr.log_prob({"m1_kg": 0.1, "k1": 0.25}) == lp
    # default priors: widths 0.999 and 1
    assert Priors().log_prob({"m1_kg": 0.5, "k1": 0.5, "m2_kg": 0.5, "k2": 0.5}) == pytest.approx(
        -2 * math.log(0.999))


@pytest.mark.parametrize("latents", [
    {"m1_kg": 0.0005, "k1": 0.5},
    {"m1_kg": 1.0001, "k1": 0.5},
    {"m1_kg": 0.5, "k1": -1e-9},
    {"m1_kg": 0.5, "k2": 1.5},
])
def test_log_prob_outside_is_minus_inf(latents):
    assert Priors().log_prob(latents) == -math.inf


def test_sample_within_bounds():
    pr = Priors().with_bounds(m2_kg=(0.2, 0.3))
    rng = np.random.default_rng(0)
    for _ in range(50):
        v = pr.sample(rng, ["m1_kg", "k1", "m2_kg", "k2"])
        assert math.isfinite(pr.log_prob(v))
        assert 0.2 <= v["m2_kg"] <= 0.3
        s = pr.sample_shape(rng)
        assert s.problem() is None, s
        assert -5 <= pr.sample_offset(rng) <= 5


# -- with_values --------------------------------------------------------------------------------

@pytest.mark.parametrize("name,value", [("m1_kg", 0.33), ("k1", 0.07), ("m2_kg", 0.9), ("k2", 0.61)])
def test_with_values_changes_exactly_the_named_latent(name, value):
    s = default_scene(20, target="cardboard")
    t = s.with_values({name: value})
    before, after = s.latents(), t.latents()
    assert after[name] == value
    assert before[name] != value
    assert {k: v for k, v in after.items() if k != name} == {k: v for k, v in before.items() if k != name}
    i, attr = LATENTS[name]
    other = 1 - i
    assert t.objects[other] == s.objects[other]
    assert t.ramp == s.ramp and t.camera == s.camera and t.priors == s.priors
    assert t.geometry_key() == s.geometry_key()
    assert s.latents()[name] != value  # the original is untouched (frozen copy)


def test_with_values_knobs():
    s = default_scene(20, target="cardboard")
    t = s.with_values({"offset_units": 3, "e1": 0.5, "e2": 0.25, "angle_deg": 25})
    assert t.ramp_object.offset_units == 3
    assert (t.objects[0].restitution, t.objects[1].restitution) == (0.5, 0.25)
    assert t.ramp.angle_deg == 25
    # the masses and frictions stay; the collision's restitution is the pair's, as Bullet multiplies them
    assert {k: v for k, v in t.latents().items() if k != "e_collision"} == \
        {k: v for k, v in s.latents().items() if k != "e_collision"}
    assert (s.latents()["e_collision"], t.latents()["e_collision"]) == (0.0, 0.5 * 0.25)


def test_with_values_rejects_unknown_and_missing_target():
    s = default_scene(20, target="cardboard")
    with pytest.raises(SceneError, match="mass"):
        s.with_values({"mass": 0.3})
    with pytest.raises(SceneError, match="m2_kg"):
        default_scene(20, target=None).with_values({"m2_kg": 0.3})
    with pytest.raises(SceneError, match=r"objects\[0\]"):
        s.with_values({"offset_units": 30})  # beyond the ramp's top


# -- camera ------------------------------------------------------------------------------------

@pytest.mark.parametrize("cam", [
    default_camera(),
    look_at_camera((0.5, -1.0, 0.8), (0.0, 0.2, 0.0), focal_px=800, width_px=1280, height_px=720),
])
def test_optical_axis_projects_to_principal_point(cam):
    fwd = cam.world_to_camera[2, :3]
    eye = cam.position_in_world
    for t in (0.3, 1.0, 7.0):
        uv = cam.project(eye + t * fwd)
        np.testing.assert_allclose(uv, cam.K[:2, 2], atol=1e-9)
    # and the look-at target of the default camera is on that axis
    pts = cam.project(np.stack([eye + 1.0 * fwd, eye + 2.0 * fwd]))
    assert pts.shape == (2, 2)


def test_default_camera_sees_the_scene_upright():
    cam = default_camera()
    np.testing.assert_allclose(cam.position_in_world, [-0.2, -1.2, 0.3], atol=1e-12)
    np.testing.assert_allclose(cam.project(np.array([-0.2, 0.0, 0.16])), cam.K[:2, 2], atol=1e-9)
    # world up is image up (smaller v); world +x is image right (larger u)
    base = cam.project(np.array([0.0, 0.0, 0.1]))
    assert cam.project(np.array([0.0, 0.0, 0.2]))[1] < base[1]
    assert cam.project(np.array([0.1, 0.0, 0.1]))[0] > base[0]


# -- the physics rate: whole steps a video frame (issue 24) -------------------------------------

@pytest.mark.parametrize("fps, hz", [
    (30.0, 240), (60.0, 240), (24.0, 240),        # 240 Hz steps these evenly: unchanged
    (25.0, 250.0),                                # PAL: 10 steps a frame
    (30000 / 1001, 8 * 30000 / 1001),             # NTSC 29.97: 8 steps, 239.76 Hz
    (29.7, 8 * 29.7),                             # a phone clip of Physics 101: 237.6 Hz
    (50.0, 250.0), (7.0, 238.0), (1000.0, 1000.0),
])
def test_a_scene_steps_the_multiple_of_its_frame_rate_nearest_sim_hz(fps, hz):
    from galileo.camera import steps_per_frame

    s = default_scene(20, camera=default_camera(fps=fps))
    assert s.sim_hz == pytest.approx(hz, rel=1e-12)
    assert steps_per_frame(s.sim_hz, fps) * fps == pytest.approx(s.sim_hz, rel=1e-12)
    back = round_trip(s)                           # written as the rate it runs at, read back as is
    assert back.sim_hz == s.sim_hz and back == s


def test_the_physics_rate_stays_inside_sim_hz_bounds():
    from galileo.camera import physics_hz
    from galileo.scenarios.ramp.scene import SIM_HZ

    assert physics_hz(60, 25.0) == 50.0 and physics_hz(60, 25.0, SIM_HZ) == 75.0   # nearest, then inside [60, 10000]
    assert physics_hz(10_000, 600.0) == 10_200.0 and physics_hz(10_000, 600.0, SIM_HZ) == 9600.0
    s = scene_from_json({**default_scene(20).to_json(), "sim_hz": 60,
                         "camera": default_camera(fps=25.0).to_json()})
    assert s.sim_hz == 75.0


def test_old_scene_files_load_as_they_did():
    """A scene file written before issue 24 (the demo's, 30 fps) runs at its 240 Hz, exactly,
    and so does the same file without its camera (no frame rate to step evenly)."""
    from pathlib import Path

    from galileo.camera import steps_per_frame

    d = json.loads((Path(__file__).parent / "data" / "scene.json").read_text())
    s = scene_from_json(d)
    assert d["sim_hz"] == 240 and s.sim_hz == 240 and steps_per_frame(s.sim_hz, s.camera.fps) == 8
    assert scene_from_json({k: v for k, v in d.items() if k != "camera"}).sim_hz == 240


# -- initial pose -------------------------------------------------------------------------------

@pytest.mark.parametrize("angle", [0.0, 10.0, 20.0, 45.0])
@pytest.mark.parametrize("offset", [-5, 0, 4])
@pytest.mark.parametrize("shape", [None, Shape("cylinder", (0.08, 0.03, 0.03)), Shape("torus", (0.08, 0.08, 0.02))],
                         ids=["box", "cylinder", "torus"])
def test_initial_pose_on_ramp_surface(angle, offset, shape):
    s = default_scene(angle, offset_units=offset, target=None, shape=shape)
    pos, orn = s.initial_pose(0)
    a = math.radians(angle)
    normal = np.array([math.sin(a), 0.0, math.cos(a)])
    downhill = np.array([math.cos(a), 0.0, -math.sin(a)])
    h = s.ramp_object.shape.height_m
    # the ramp's top surface is the plane through the foot (origin) with this normal
    assert pos @ normal == pytest.approx(h / 2, abs=1e-12)
    assert -(pos @ downhill) == pytest.approx((s.start_units + offset) * s.unit_m, abs=1e-12)
    assert pos[1] == 0.0
    # the orientation turns object z into the ramp normal and object x downhill
    q = np.array(orn)
    assert np.linalg.norm(q) == pytest.approx(1.0)
    x, y, z, w = q
    rot = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                    [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                    [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    np.testing.assert_allclose(rot[:, 2], normal, atol=1e-12)
    np.testing.assert_allclose(rot[:, 0], downhill, atol=1e-12)


def test_target_rests_on_ground_at_distance():
    s = default_scene(20, target="cardboard", distance_m=0.25)
    pos, orn = s.initial_pose(1)
    sx, _, sz = s.target.shape.size_m
    np.testing.assert_allclose(pos, [0.25 + sx / 2, 0.0, sz / 2])
    assert tuple(orn) == (0.0, 0.0, 0.0, 1.0)


def test_default_bounds_are_the_papers():
    assert DEFAULT_BOUNDS == {"m1_kg": (0.001, 1.0), "k1": (0.0, 1.0), "m2_kg": (0.001, 1.0), "k2": (0.0, 1.0)}
