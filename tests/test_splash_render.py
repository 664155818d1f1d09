"""The splash renderer and dataset: determinism, the object where the truth puts it, the
water's tint, scene files that load, truth that adds up."""
import json

import numpy as np
import pytest

from galileo.scenarios.splash.dataset import build, plan, scene_for


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("splash_demo")
    build("demo", out, seed=0, workers=1, progress=False)
    return out


def _renderer(seed=0):
    from galileo.render import Look
    from galileo.scenarios.splash.render import Renderer

    spec = plan("demo", seed)[0]
    scene = scene_for(spec)
    return scene, Renderer(scene, Look.random(np.random.default_rng([spec.seed, 1])), texture_seed=spec.seed)


def test_demo_renders_deterministically():
    frames = []
    for _ in range(2):
        scene, r = _renderer()
        imgs = []
        traj = r.render(6, on_image=lambda f, rgb: imgs.append(rgb))
        frames.append((np.stack(imgs), traj.position_m))
    assert frames[0][0].shape == (6, 480, 640, 3)
    assert np.array_equal(frames[0][0], frames[1][0])
    assert np.array_equal(frames[0][1], frames[1][1])


def test_object_where_truth_puts_it_and_water_tinted():
    from galileo.scenarios.splash.physics import Simulator

    scene, r = _renderer()
    shots = {}
    traj = r.render(20, on_image=lambda f, rgb, seg: shots.__setitem__(f, (rgb, seg)), with_segmentation=True)
    # the same video frames from a separate, non-visual simulation
    sim = Simulator(scene).run(20)
    np.testing.assert_allclose(traj.position_m[0], sim.position_m[0], atol=1e-9)
    cam = scene.camera
    for f in (0, 3, 8, 19):       # falling through the air and the water, then on the floor
        u, v = np.round(cam.project(traj.position_m[0, f])).astype(int)
        rgb, seg = shots[f]
        # the projected centre lies on the object's pixels, not at their edge (3x3 around it)
        assert np.all(seg[v - 1:v + 2, u - 1:u + 2] == r.body_id), f
    # the room's wall seen through the water is tinted blue-green; seen above the water, not
    t = scene.tank
    rgb = shots[19][0].astype(float)

    def patch(z):
        u, v = np.round(cam.project(np.array([0.1, t.size_m[1] / 2, z]))).astype(int)
        return rgb[v - 3:v + 4, u - 3:u + 4].reshape(-1, 3).mean(axis=0)

    wet, dry = patch(t.water_level_m - 0.05), patch(t.water_level_m + 0.05)
    # Beer-Lambert over ~0.17 m of water (extinction 0.35 m): alpha ~ 0.38, so the wall
    # (222, 220, 212) turns to about (162, 187, 194): blue exceeds red by ~30 levels
    assert wet[2] - wet[0] > 20 and dry[2] - dry[0] < 5
    assert dry.mean() - wet.mean() > 20


def test_dataset_files(demo):
    from galileo.registry import load_scene

    index = json.loads((demo / "index.json").read_text())
    assert index["scenario"] == "splash" and len(index["videos"]) == 1
    folder = demo / "demo"
    scene = load_scene(folder / "scene.json")
    assert type(scene).__name__ == "SplashScene"
    assert scene == scene_for(plan("demo", 0)[0])
    truth = json.loads((folder / "truth.json").read_text())
    lat = truth["latents"]
    assert lat["mass_kg"] == pytest.approx(lat["density_g_cm3"] * lat["volume_cm3"] * 1e-3, rel=1e-12)
    # the demo: let go at rest 5 physics steps (at 240 Hz) before frame 0, the seed's earliest start
    assert lat["release_s"] == scene.release_s == pytest.approx(-5 / 240) and lat["push_mps"] == scene.push_mps == 0
    assert len(truth["trajectory"]["objects"][0]["position_m"]) == scene.camera.n_frames == 60
    from galileo.video import read_video

    frames, info = read_video(folder / "video.mp4")
    assert (info.width_px, info.height_px, info.fps, info.n_frames) == (640, 480, 30.0, 60)


def test_catalogue_inside_priors():
    from galileo.scenarios.splash.materials import FLOATERS, MATERIALS, SINKERS, catalogue
    from galileo.scenarios.splash.scene import LATENT_SPECS

    assert len(MATERIALS) == 13 and FLOATERS and SINKERS
    objs = catalogue(0)
    assert len(objs) == 36
    for o in objs:
        assert LATENT_SPECS["density_g_cm3"].bounds[0] <= o.density_g_cm3 <= LATENT_SPECS["density_g_cm3"].bounds[1]
        assert LATENT_SPECS["area_cm2"].bounds[0] <= o.area_cm2 <= LATENT_SPECS["area_cm2"].bounds[1]
        assert 1.0 <= o.volume_cm3 <= 100.0 and 0.5 <= o.drag_water <= 1.2
    assert len(plan("full", 0)) == 72 and len(plan("small", 0)) == 8


def test_a_blurred_frame_streaks_by_its_travel_over_the_exposure_frame_0_included():
    """Motion blur over half a frame's interval, the object let go 0.1 s before the video
    starts: in frame 0 as in a later frame in the air, the object's streak along the image's
    v is longer than its sharp silhouette (the segmentation at the frame's time) by the
    projected distance it falls while the shutter is open (Newton: v t_e about the frame's
    time, from the release's speed g t). A camera's first frame is exposed like any other."""
    from galileo.render import blur_offsets
    from galileo.scenarios.splash.render import Renderer

    spec = plan("demo", 0)[0]
    scene = scene_for(spec)
    r = Renderer(scene)                       # the default look: no drift, no noise
    release_s, exposure = -0.1, 0.5           # (24 steps of 1/240 s before the video)
    n = round(scene.sim_hz / scene.fps)
    shots = {}
    traj = r.render(12, values={"release_s": release_s}, blur=blur_offsets(exposure, n // 2 + 1),
                    on_image=lambda f, rgb, seg: shots.__setitem__(f, (rgb.astype(float), seg)), with_segmentation=True)
    cam = scene.camera
    empty = shots[11][0]                      # the object deep in the water by then: the wall behind it, empty
    rows = lambda m: np.flatnonzero(m.any(axis=1))
    for f in (0, 1):
        t = f / scene.fps - release_s
        p, v = traj.position_m[0, f], np.array([0.0, 0.0, -9.81 * t])
        assert p[2] - 0.03 > scene.tank.water_level_m, f        # in the air, whole
        rgb, seg = shots[f]
        still = seg == r.body_id
        u, v_px = cam.project(p)
        vv, uu = np.indices(still.shape)
        near = (np.abs(uu - u) < 60) & (np.abs(vv - v_px) < 60)   # (the rest of the frame: the wall, lit alike)
        streak = (np.abs(rgb - empty).max(axis=2) > 3) & near
        half = v * exposure / scene.fps / 2
        travel = abs(cam.project(p + half)[1] - cam.project(p - half)[1])
        assert np.ptp(rows(streak)) - np.ptp(rows(still)) == pytest.approx(travel, abs=1.5), f


@pytest.mark.parametrize("kind", ["box", "vcyl", "hcyl"])
def test_the_renderers_object_pixels_are_those_whose_centres_its_outline_holds(kind):
    """The object held at its release point, drawn by Bullet's TinyRenderer (the segmentation:
    exactly the object's pixels): its projected outline filled by pixel centres
    (`shape_silhouette(..., centres=True)`, what the splash's kind fits compare with a
    silhouette) is those pixels, to within the outline's rounding (IoU loss under 3%); filled
    as OpenCV fills rounded corners, every pixel the outline touches, it is a pixel too wide on
    every side (a loss twice as large or more)."""
    from galileo.render import Look
    from galileo.scenarios.splash.render import Renderer
    from galileo.scenarios.splash.scene import CM2, CM3, body_shape, default_scene, dimensions
    from galileo.sim.bullet import pb
    from galileo.vision.silhouette import iou_loss, shape_silhouette

    scene = default_scene(kind, 30.0, 0.5, release_s=0.5)
    r = Renderer(scene, Look.random(np.random.default_rng(0)))
    shots = {}
    r.render(1, on_image=lambda f, rgb, seg: shots.__setitem__(f, seg), with_segmentation=True)
    seen = shots[0] == r.body_id
    shape, q = body_shape(kind, dimensions(kind, scene.obj.volume_cm3 * CM3, scene.obj.area_cm2 * CM2))
    rot = np.array(pb.getMatrixFromQuaternion(q)).reshape(3, 3)   # (Bullet's, as it drops the body)
    centre = np.asarray(scene.release_m, float)
    exact = iou_loss(shape_silhouette(scene.camera, shape, rot, centre, centres=True) > 0, seen)
    touched = iou_loss(shape_silhouette(scene.camera, shape, rot, centre) > 0, seen)
    assert exact < 0.03 and touched > 2 * exact, (exact, touched)
