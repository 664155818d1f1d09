"""`galileo scene --scenario spring` (issue 26): a spring scene for your own side view from four
clicked points (the hanging point, a point straight below it, the ends of a segment of known
length) and the segment's length. The truth is a camera built here (`look_at_camera`, rolled
about its axis where a test needs it) whose projections are the clicks: square to the spring's
plane, the calibration's model, it must come back exactly; turned a few degrees, within the
module's first-order bound; clicks with Gaussian noise move the scale as their statistics say."""
import dataclasses
import itertools
import math

import numpy as np
import pytest

from galileo.camera import backproject_to_plane, look_at_camera
from galileo.cli import main
from galileo.clicks import calibration_of
from galileo.errors import GalileoError
from galileo.registry import load_scene
from galileo.scenarios.spring.clicks import (
    DEFAULT_HFOV_DEG,
    LINE_RGB,
    NOMINAL_DISTANCE_M,
    SCALE_RGB,
)
from galileo.scenarios.spring.scene import SpringScene
from galileo.video import VideoInfo

TOP = np.asarray(SpringScene.top_in_world_m, float)
W, H = 640, 480
INFO = VideoInfo(W, H, 30.0, 90)
# points of the spring's plane (y = the hanging point's) where an object bounces and sways: up to 30 cm either
# side of the hanging line, from 5 to 60 cm below the hanging point
PLANE = np.array([[x, TOP[1], TOP[2] - d] for x in np.linspace(-0.3, 0.3, 13) for d in np.linspace(0.05, 0.6, 12)])


def square_camera(distance_m: float, roll_deg: float, focal_px: float, aim=(0.0, -0.3), size=(W, H)):
    """A camera `distance_m` in front of the spring's plane looking straight at it (at the point
    `aim` (x, z) from the hanging point), rolled by `roll_deg` about its axis."""
    target = TOP + (aim[0], 0.0, aim[1])
    cam = look_at_camera(target - (0.0, distance_m, 0.0), target, focal_px=focal_px, width_px=size[0],
                         height_px=size[1], fps=30.0, n_frames=90)
    c, s = math.cos(math.radians(roll_deg)), math.sin(math.radians(roll_deg))
    m = cam.world_to_camera.copy()
    m[:3] = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]) @ m[:3]
    return dataclasses.replace(cam, world_to_camera=m)


def turned_camera(distance_m: float, yaw_deg: float, pitch_deg: float, aim=(0.0, -0.3)):
    """A camera `distance_m` from the point `aim` of the plane, turned by yaw and pitch from the
    plane's normal (mild perspective)."""
    a, b = math.radians(yaw_deg), math.radians(pitch_deg)
    target = TOP + (aim[0], 0.0, aim[1])
    eye = target + distance_m * np.array([-math.sin(a) * math.cos(b), -math.cos(a) * math.cos(b), math.sin(b)])
    return look_at_camera(eye, target, focal_px=600.0, width_px=1280, height_px=720, fps=30.0, n_frames=90)


def scene_seen_by(cam, **kw) -> SpringScene:
    return dataclasses.replace(SpringScene(), camera=cam, fps=cam.fps, n_frames=cam.n_frames, **kw)


def points_arg(uv) -> str:
    return " ".join(f"{u:.3f},{v:.3f}" for u, v in uv)


# -- the model's own views: the camera comes back exactly -------------------------------------------------

@pytest.mark.parametrize("distance_m, roll_deg, focal_px, aim", [
    (1.5, 0.0, 700.0, (0.0, -0.3)), (0.8, 4.0, 560.0, (0.1, -0.2)), (2.5, -12.0, 1100.0, (-0.15, -0.45)),
    (1.5, 25.0, 900.0, (0.05, -0.25))])
def test_a_camera_square_to_the_plane_comes_back_from_the_examples_clicks(distance_m, roll_deg, focal_px, aim):
    """The points `example` says a user clicks, projected by a camera of the calibration's
    model: with the focal length, the camera itself; without it (the default), another camera
    that sees the spring's plane exactly as the true one does."""
    truth = scene_seen_by(square_camera(distance_m, roll_deg, focal_px, aim))
    cal = calibration_of("spring")
    world, numbers = cal.example(truth)
    uv = truth.camera.project(world)
    scene, err = cal.solve(uv, numbers, INFO)
    assert err < 1e-9 and scene.metric
    assert np.linalg.norm(scene.camera.position_in_world - truth.camera.position_in_world) < 1e-9
    assert np.abs(scene.camera.project(PLANE) - truth.camera.project(PLANE)).max() < 1e-6
    default_focal = W / (2 * math.tan(math.radians(DEFAULT_HFOV_DEG) / 2))
    scene, err = cal.solve(uv, {**numbers, "focal_px": None}, INFO)
    assert scene.camera.K[0, 0] == pytest.approx(default_focal)
    assert np.abs(scene.camera.project(PLANE) - truth.camera.project(PLANE)).max() < 1e-6
    # the camera stands where that focal length sees the plane at the same scale
    depth = scene.camera.world_to_camera[:3, :3] @ TOP + scene.camera.world_to_camera[:3, 3]
    assert depth[2] == pytest.approx(distance_m * default_focal / focal_px)


def test_a_known_length_comes_back_and_noisy_clicks_spread_it_as_their_statistics_say():
    """A 30 cm ruler lying anywhere in the plane, measured through the solved camera: exact from
    exact clicks; with Gaussian noise of 1 px on the clicks, over 400 draws, its relative error
    is unbiased (within 3 standard errors) and spreads as the scale segment's length does (its
    component along the segment has variance 2 sigma^2: SD sqrt(2) sigma / l for a segment l
    pixels long), within the 3 standard errors of an SD from 400 draws (SD / sqrt(2 n))."""
    truth = scene_seen_by(square_camera(1.0, 3.0, 700.0), size_m=(0.12, 0.05, 0.05))
    cal = calibration_of("spring")
    world, numbers = cal.example(truth)
    uv0 = truth.camera.project(world)
    ruler = TOP + np.array([[-0.2, 0.0, -0.5], [0.2 * math.cos(1.0) - 0.2, 0.0, -0.5 + 0.3 * math.sin(1.0)]])
    ruler[1] = ruler[0] + 0.3 * (ruler[1] - ruler[0]) / np.linalg.norm(ruler[1] - ruler[0])

    def measured(scene) -> float:
        a, b = backproject_to_plane(scene.camera, truth.camera.project(ruler), TOP[1])
        return float(np.linalg.norm(b - a))

    assert measured(cal.solve(uv0, numbers, INFO)[0]) == pytest.approx(0.3, abs=1e-9)
    rng = np.random.default_rng(0)
    n, sigma = 400, 1.0
    rel = np.array([measured(cal.solve(uv0 + rng.normal(0.0, sigma, uv0.shape), numbers, INFO)[0]) / 0.3 - 1
                    for _ in range(n)])
    stated = math.sqrt(2) * sigma / np.linalg.norm(uv0[3] - uv0[2])
    print(f"ruler: mean {rel.mean():+.5f}, SD {rel.std():.5f}; stated {stated:.5f}")
    assert abs(rel.mean()) < 3 * rel.std() / math.sqrt(n)
    assert abs(rel.std() / stated - 1) < 3 / math.sqrt(2 * n)


@pytest.mark.parametrize("distance_m", [0.8, 1.5, 2.5])
def test_a_camera_turned_a_few_degrees_misplaces_the_plane_within_the_stated_bound(distance_m):
    """The module's first-order bound for mild perspective: a point r from the hanging point is
    off by at most 4 r rho sin(a) / D (rho: the largest distance between it, the hanging point,
    the scale segment and where the camera looks; D: the camera's distance from the plane), for
    cameras turned up to 5 degrees, aimed at several places; and the hanging point is exact."""
    cal = calibration_of("spring")
    info = VideoInfo(1280, 720, 30.0, 90)
    worst = 0.0
    for (yaw, pitch), aim in itertools.product([(3, 0), (0, 3), (2, -2), (5, 0), (0, -5), (-4, 3)],
                                               [(0.0, -0.3), (0.2, -0.2), (-0.2, -0.45)]):
        truth = scene_seen_by(turned_camera(distance_m, yaw, pitch, aim))
        world, numbers = cal.example(truth)
        scene, _ = cal.solve(truth.camera.project(world), numbers, info)
        back = backproject_to_plane(scene.camera, truth.camera.project(PLANE), TOP[1])
        err = np.linalg.norm(back - PLANE, axis=1)
        looked_at = backproject_to_plane(truth.camera, np.array([[640.0, 360.0]]), TOP[1])[0]
        marks = [TOP, (world[2] + world[3]) / 2, looked_at]
        rho = np.max([np.linalg.norm(PLANE - q, axis=1) for q in marks]
                     + [np.full(len(PLANE), np.linalg.norm(p - q)) for p, q in itertools.combinations(marks, 2)],
                     axis=0)
        r = truth.camera.world_to_camera[:3, :3]
        tilt = math.acos(abs(r[2, 1]))                           # the optical axis from the plane's normal
        depth = abs(truth.camera.position_in_world[1] - TOP[1])
        bound = 4 * np.linalg.norm(PLANE - TOP, axis=1) * rho * math.sin(tilt) / depth
        worst = max(worst, float((err / bound).max()))
        top_back = backproject_to_plane(scene.camera, truth.camera.project(TOP[None]), TOP[1])[0]
        assert np.linalg.norm(top_back - TOP) < 1e-9
    print(f"at {distance_m} m: the largest error is {worst:.2f} of the bound")
    assert worst <= 1.0


def test_without_a_length_the_scene_is_not_metric_and_its_scale_is_the_nominal_camera_distance():
    """No length: `metric: false`, the scale a latent, and the scene's plane is the true one
    shrunk about the hanging point by the scale's truth, true length / scene length: the true
    camera's distance over NOMINAL_DISTANCE_M (at the true focal length)."""
    truth = scene_seen_by(square_camera(1.7, -6.0, 800.0))
    cal = calibration_of("spring")
    world, numbers = cal.example(truth)
    scene, _ = cal.solve(truth.camera.project(world), {**numbers, "length_m": None}, INFO)
    assert not scene.metric and "scale" in [lat.name for lat in scene.latent_specs()]
    back = backproject_to_plane(scene.camera, truth.camera.project(PLANE), TOP[1])
    np.testing.assert_allclose(TOP + (back - TOP) * 1.7 / NOMINAL_DISTANCE_M, PLANE, atol=1e-9)


# -- the command line: a video's scene, and bad input in one line ------------------------------------------

@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """A 3-frame 640x480 video (what `galileo scene` reads of it: its size, frame rate and length)."""
    from galileo.video import write_video

    path = tmp_path_factory.mktemp("spring_clicks") / "clip.mp4"
    rng = np.random.default_rng(0)
    write_video(path, (rng.integers(0, 255, (H, W, 3), dtype=np.uint8) for _ in range(3)), 25.0)
    return path


def test_galileo_scene_writes_the_spring_scene_of_a_video(clip, tmp_path, capsys):
    truth = scene_seen_by(square_camera(1.5, 2.0, 700.0))
    world, _ = calibration_of("spring").example(truth)
    out = tmp_path / "scene.json"
    assert main(["scene", str(clip), "--scenario", "spring", "--points", points_arg(truth.camera.project(world)),
                 "--length-m", "0.05", "--object", "woodblock1", "--spring", "tight", "--hang-m", "0.04",
                 "--focal-px", "700", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    # (the camera turned +2 degrees about its axis: the image's down, (0, 1), is (-sin 2, cos 2) of the world's)
    # (700 px / 1.5 m: 4.7 px a centimetre)
    assert ("reprojection error 0.00 px; camera square to the spring's plane, the hanging line leans 2.0 deg left of "
            "the image's vertical; focal 700 px; object woodblock1 on spring tight, hang 0.04 m; 1.50 m from the "
            "spring's plane: 1 cm is 4.7 px") in printed
    mine = load_scene(out)
    assert (mine.scenario, mine.object, mine.spring, mine.hang_m, mine.metric) == ("spring", "woodblock1", "tight",
                                                                                 0.04, True)
    assert (mine.fps, mine.n_frames, mine.camera.fps, mine.camera.n_frames) == (25.0, 3, 25.0, 3)
    assert mine.sim_hz % 25.0 == 0
    # (the clicks written to 0.001 px: the scale segment's 40 px, levered over the plane's 300 px, make 0.01 px)
    np.testing.assert_allclose(mine.camera.project(PLANE), truth.camera.project(PLANE), atol=0.01)


RIGHT = [(320.0, 40.0), (322.0, 300.0), (300.0, 320.0), (340.0, 321.0)]   # hanging point, line, scale ends


@pytest.mark.parametrize("points, flags, needle", [
    (RIGHT, ["--length-m", "0"], "--length-m: 0 is outside (0, 20]"),
    (RIGHT, ["--length-m", "-0.05"], "--length-m: -0.05 is outside (0, 20]"),
    ([RIGHT[0], (321.0, 41.0), *RIGHT[2:]], [], "the top and hanging line points are the same point"),
    ([RIGHT[0], (323.0, 45.0), *RIGHT[2:]], [], ("the top and hanging line points are 5.8 px apart, less than 10: a "
                                                 "pixel's error in them would be 17% of the scale")),
    ([RIGHT[0], (520.0, 60.0), *RIGHT[2:]], [], ("the hanging line is 84 deg from the image's vertical (more than 30): "
                                                 "click a point straight below the hanging point")),
    ([(320.0, 300.0), (322.0, 40.0), *RIGHT[2:]], [], "the hanging line point is above the top: click a point"),
    ([*RIGHT[:3], (301.0, 322.0)], [], "the scale start and scale end points are the same point"),
    ([*RIGHT[:3], (306.0, 320.0)], [], "the two scale points are 6.0 px apart, less than 10"),
    (RIGHT, ["--object", "Wood Block"], "--object: 'Wood Block' is not a name: 1-24 lowercase letters and digits"),
    (RIGHT, ["--spring", "3springs"], "--spring: '3springs' is not a name"),
    (RIGHT, ["--hang-m", "-0.01"], "--hang-m: -0.01 is outside [0, 20]"),
    (RIGHT, ["--length-m", "20", "--focal-px", "90000"], "a 20 m segment 40 px long puts the camera 44986 m from"),
    (RIGHT[:3], [], "--points: give 4 points u,v (pixels): top, hanging line, scale start, scale end; got 3"),
    (RIGHT, ["--angle-deg", "20"], "--angle-deg: not for --scenario spring"),
])
def test_bad_clicks_and_numbers_are_refused_in_one_line(clip, tmp_path, capsys, points, flags, needle):
    out = tmp_path / "s.json"
    code = main(["scene", str(clip), "--scenario", "spring", "--points", points_arg(points), "--length-m", "0.04",
                 *flags, "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.startswith("galileo: error:") and needle in err and "\n" not in err, err
    assert not out.exists()


def test_a_name_is_checked_before_the_scene_is_made():
    cal = calibration_of("spring")
    with pytest.raises(GalileoError, match=r"^--object: 'a-b' is not a name"):
        cal.values({"object": "a-b"})
    v = cal.values({"object": " cube2 ", "spring": ""})
    assert (v["object"], v["spring"], v["length_m"]) == ("cube2", "spring", None)


# -- the upload page's pieces, with the spring's calibration -----------------------------------------------

def test_the_upload_page_solves_and_draws_a_spring_scene_in_its_own_words(clip):
    """The page's solver and picture: its messages name its inputs; the overlay draws the
    hanging line through the two clicks on it and the scale segment between its clicks."""
    from ui.calibrate import draw, for_panel, probe_video, solve

    spring = calibration_of("spring")
    c = probe_video(clip)
    c = dataclasses.replace(c, first=np.zeros_like(c.first))       # a black frame: only the overlay shows
    scene, _ = solve(c, RIGHT, spring, {"length_m": ""})
    assert "not metric: a nominal scale" in for_panel(spring.describe(scene, {}), spring)
    assert for_panel(spring.describe(scene, {}), spring).endswith("; enter Length (m) for a metric scene")
    with pytest.raises(GalileoError, match=r"^Object \(id\): 'Big Ball' is not a name"):
        solve(c, RIGHT, spring, {"object": "Big Ball"})
    with pytest.raises(GalileoError, match=r"^Length \(m\): 0 is outside"):
        solve(c, RIGHT, spring, {"length_m": "0"})
    scene, _ = solve(c, RIGHT, spring, {"length_m": "0.04"})
    img, s = draw(c, RIGHT, spring, scene)
    assert img.shape == (H * s, W * s, 3)
    pts = np.asarray(RIGHT) * s
    for (a, b), rgb in (((pts[0], pts[1]), LINE_RGB), ((pts[2], pts[3]), SCALE_RGB)):
        for f in (0.3, 0.45, 0.6):
            u, v = np.round(a + f * (b - a)).astype(int)
            patch = img[v - 1:v + 2, u - 1:u + 2].reshape(-1, 3).astype(int)
            assert np.abs(patch - rgb).sum(axis=1).min() < 60, (rgb, patch)
