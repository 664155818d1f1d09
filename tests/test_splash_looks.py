"""The splash's second look (the looks presets, issue 28): deterministic, drawn over the ranges
it promises and unlike the default look, scenes that validate and leak no truth into
inference, the object drawn where the camera projects its true position."""
import dataclasses
import json
import math

import numpy as np
import pytest

from galileo.scenarios.splash.dataset import FLOATERS, SINKERS, plan, render_one, scene_for, scene_for_look
from galileo.scenarios.splash.scene import DEFAULT_BOUNDS, Tank, default_camera, dimensions, equal_area

LOOKS = plan("looks", 0)
DRAWN = [scene_for_look(s) for s in LOOKS]
SHORT = min(range(len(LOOKS)), key=lambda i: DRAWN[i][0].camera.n_frames)   # a sinker of 30 frames


def _first_frame(path):
    from galileo.video import read_frames

    return next(iter(read_frames(path)))


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """One looks video rendered twice into separate folders."""
    outs = [tmp_path_factory.mktemp(f"looks{k}") for k in range(2)]
    for out in outs:
        render_one(LOOKS[SHORT], str(out))
    return [out / LOOKS[SHORT].name for out in outs]


def test_the_presets_objects():
    """looks: the catalogue's 36 objects once each; looks-small: 12 of the same videos, 6
    sinking and 6 floating materials."""
    assert len(LOOKS) == 36 and len({s.obj.name for s in LOOKS}) == 36
    small = plan("looks-small", 0)
    assert len(small) == 12 and set(small) <= set(LOOKS)
    materials = [s.obj.material for s in small]
    assert len(set(materials)) == 12
    assert sum(m in SINKERS for m in materials) == 6 and sum(m in FLOATERS for m in materials) == 6


def test_same_seed_same_files_and_first_frame(rendered):
    a, b = rendered
    for name in ("scene.json", "truth.json"):
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    assert np.array_equal(_first_frame(a / "video.mp4"), _first_frame(b / "video.mp4"))
    # another seed draws another video
    other = scene_for_look(plan("looks", 1)[SHORT])[0]
    assert other.camera != DRAWN[SHORT][0].camera


def test_draws_cover_the_promised_ranges_and_differ_from_the_default_look():
    """Every camera, tank, yaw and release inside the ranges the preset promises (the brief's
    numbers, written here independently), spread over them, none the default look's."""
    eyes, focals, yaws, heights, held = [], [], [], [], []
    for scene, style, _ in DRAWN:
        t, cam = scene.tank, scene.camera
        assert t != Tank() and cam != default_camera(t, cam.fps, cam.n_frames)
        assert 0.30 <= t.size_m[0] <= 0.60 and 0.12 <= t.size_m[1] and 0.12 <= t.water_level_m <= 0.25
        eye = cam.position_in_world
        aim = cam.world_to_camera[2, :3]      # the optical axis in the world
        focals.append(cam.K[0, 0])
        heights.append(eye[2] - t.water_level_m)
        yaws.append(math.degrees(math.atan2(-aim[0], aim[1])))
        eyes.append(math.hypot(eye[0] - scene.release_m[0], eye[1]))
        assert -45 <= scene.yaw_deg <= 45
        held.append(scene.release_s > 0)
        assert (0 <= scene.release_s <= 0.5 and 0 <= scene.push_mps <= 0.3) or (
            -30 / 240 - 1e-12 <= scene.release_s <= -5 / 240 and scene.push_mps == 0)
    assert 700 <= min(focals) and max(focals) <= 1100 and np.ptp(focals) > 200
    assert -0.05 <= min(heights) and max(heights) <= 0.15 and np.ptp(heights) > 0.1
    assert max(abs(y) for y in yaws) <= 20 + 1e-6 and np.ptp(yaws) > 20
    assert 0.6 <= min(eyes) - 0.05 and max(eyes) <= 1.3 + 0.05 and np.ptp(eyes) > 0.2
    assert 8 <= sum(held) <= 28            # half held (Binomial(36, 0.5): 99.9% within 8-28)
    styles = [s for _, s, _ in DRAWN]
    assert {s.object_pattern for s in styles} == {"plain", "stripes", "wood", "label"}
    white = [s for s in styles if min(s.object_rgb) >= 200]
    light_walls = [s for s in styles if min(s.wall_rgb) >= 200]
    assert white and light_walls
    lights = [lk for _, _, lk in DRAWN]
    assert np.ptp([lk.light_dir[0] for lk in lights]) > 1.0 and np.ptp([lk.noise_sd for lk in lights]) > 1.0
    assert np.ptp([s.rgb_gain[0] / s.rgb_gain[2] for s in styles]) > 0.2      # colour temperature


def test_every_scene_validates_and_fits_its_object():
    from galileo.scenarios.splash.scene import scene_from_json

    for (scene, _, _), spec in zip(DRAWN, LOOKS):
        again = scene_from_json(json.loads(json.dumps(scene.to_json())))
        assert again == scene
        assert scene_for(spec) == scene
        o = scene.obj
        lx, ly, _ = dimensions(o.kind, o.volume_cm3 * 1e-6, o.area_cm2 * 1e-4)
        yaw = math.radians(scene.yaw_deg)    # the turned object clears the front and back glass
        half_y = (lx * abs(math.sin(yaw)) + ly * abs(math.cos(yaw))) / 2
        assert abs(scene.release_m[1]) + half_y < scene.tank.size_m[1] / 2


def test_scene_file_is_what_a_user_writes(rendered):
    """scene.json: default priors, the object unturned (yaw 0: the truth's yaw in truth.json),
    the rendered camera, tank and release point; truth.json holds every latent."""
    from galileo.registry import load_scene

    folder = rendered[0]
    scene = load_scene(folder / "scene.json")
    drawn = DRAWN[SHORT][0]
    assert scene.bounds == DEFAULT_BOUNDS and scene.yaw_deg == 0.0
    assert scene == dataclasses.replace(drawn, yaw_deg=0.0)
    lat = json.loads((folder / "truth.json").read_text())["latents"]
    assert {"kind", "volume_cm3", "density_g_cm3", "mass_kg", "material", "release_s", "push_mps",
            "yaw_deg"} <= set(lat)
    assert lat["yaw_deg"] == drawn.yaw_deg != 0.0
    assert lat["mass_kg"] == pytest.approx(lat["density_g_cm3"] * lat["volume_cm3"] * 1e-3, rel=1e-12)


def test_held_object_is_drawn_where_the_camera_projects_its_release_point():
    """In frame 0 of a held video the object is at rest at release_m (the scene's own truth):
    its projection lies on the object's pixels (3x3 around it) in the segmentation, and the
    pixels there show the look's object texture, not the block texture."""
    from galileo.scenarios.splash.render import Renderer

    held = [i for i, (s, _, _) in enumerate(DRAWN) if s.release_s > 1 / 30][:3]
    assert len(held) == 3
    for i in held:
        scene, style, look = DRAWN[i]
        r = Renderer(scene, look, texture_seed=LOOKS[i].seed, style=style)
        shots = []
        r.render(1, on_image=lambda f, rgb, seg: shots.append((rgb, seg)), with_segmentation=True)
        rgb, seg = shots[0]
        u, v = np.round(scene.camera.project(np.asarray(scene.release_m, float))).astype(int)
        assert np.all(seg[v - 1:v + 2, u - 1:u + 2] == r.body_id), LOOKS[i].name


def test_truth_never_reaches_inference(rendered):
    """The object (kind, volume, area, density, drag), release and volume factor in scene.json
    are the truth; inference must not read them: a scene file with them all changed gives
    the same chains, draw for draw."""
    from galileo import registry
    from galileo.runner import RunConfig, infer

    folder = rendered[0]
    scene = registry.load_scene(folder / "scene.json")
    o = scene.obj
    kind, volume_cm3 = ("hcyl" if o.kind != "hcyl" else "box"), min(o.volume_cm3 * 2.5, 70.0)
    wrong = dataclasses.replace(
        scene, obj=dataclasses.replace(o, kind=kind, volume_cm3=volume_cm3, density_g_cm3=0.3, drag_water=1.9,
                                       area_cm2=equal_area(kind, volume_cm3 * 1e-6) * 1e4 * 1.2),
        release_s=0.7, push_mps=0.4, log_volume_factor=0.26)
    wrong.validate()
    scenario = registry.of(scene)
    tracks = scenario.track(folder / "video.mp4", scene, progress=False)
    cfg = RunConfig(chains=2, sweeps=3, seed=3, workers=1)
    a = infer(scene, tracks, cfg, progress=False)
    b = infer(wrong, tracks, cfg, progress=False)
    assert np.array_equal(a.samples, b.samples)
    # the prepared scenes: the tracker's object, the video's priors and release
    assert a.map == b.map

    def seen(p):
        return p.obj.kind, p.obj.volume_cm3, p.obj.area_cm2, p.bounds, p.release_s, p.log_volume_factor

    assert seen(a.scene) == seen(b.scene)
