"""`galileo scene --scenario splash` (issue 25): a splash scene for your own video from six
clicked points (the tank's front corners, two points on the water line) and the tank's inner
size. The truth is the camera a video was rendered with (the splash demo's, or one built by
look_at), its tank, water level and release point; the clicks are the true points' projections,
exact or with Gaussian noise of 1.5 px. Tolerances at that noise are those measured over 300
draws by bench/bench_clicks.py (the numbers are quoted where they are used)."""
import dataclasses
import json
import re

import numpy as np
import pytest

from galileo.camera import look_at_camera
from galileo.cli import main
from galileo.clicks import calibration_of
from galileo.errors import GalileoError
from galileo.registry import load_scene
from galileo.scenarios.splash.clicks import find_release, front_corners
from galileo.video import VideoInfo

NOISE_PX = 1.5
WATER_X_M = (-0.1, 0.12)     # where along the water line the two water points are clicked
# bench/bench_clicks.py at 1.5 px on the demo's view (focal given), 300 draws: the water level's SD and the 99th
# percentile of the largest error over the tank's release plane (y = 0, x within 15 cm of the middle, z from
# 2 to 40 cm): a pixel there back-projected through the solved camera rather than the true one
WATER_LEVEL_SD_M = 0.0017
PLANE_P99_M = 0.0194


def true_points(scene) -> np.ndarray:
    """The six points (the calibration's order) of a splash scene, in the world frame."""
    t = scene.tank
    (sx, sy, sz), level = t.size_m, t.water_level_m
    return np.concatenate([front_corners(sx, sy, sz), [[x, -sy / 2, level] for x in WATER_X_M]])


def tank_numbers(scene) -> dict:
    sx, sy, sz = scene.tank.size_m
    return {"tank_width_m": sx, "tank_depth_m": sy, "tank_height_m": sz}


def rotation_deg(a, b) -> float:
    r = a.world_to_camera[:3, :3].T @ b.world_to_camera[:3, :3]
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1))))


def points_arg(uv) -> str:
    return " ".join(f"{u:.2f},{v:.2f}" for u, v in uv)


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """(folder, true scene) of the splash dataset's demo: a 3 cm plastic block dropped 15 cm
    into the water, filmed straight from the front (640x480, 60 frames)."""
    from galileo.scenarios.splash.dataset import build

    out = tmp_path_factory.mktemp("splash_clicks")
    build("demo", out, seed=0, workers=1, progress=False)
    return out / "demo", load_scene(out / "demo" / "scene.json")


# -- the geometry, from exact clicks -------------------------------------------------------------------

ABOVE_LEFT = dict(eye=(-0.35, -0.6, 0.55), target=(0.0, 0.0, 0.15), focal_px=560.0)


@pytest.mark.parametrize("view", [ABOVE_LEFT, dict(eye=(0.3, -0.5, 0.5), target=(0.05, 0.0, 0.1), focal_px=700.0),
                                  dict(eye=(0.0, -0.95, 0.26), target=(0.0, 0.0, 0.22), focal_px=900.0)])
@pytest.mark.parametrize("level_m, size_m", [(0.2, (0.4, 0.16, 0.3)), (0.12, (0.3, 0.2, 0.25))])
def test_the_camera_and_the_water_level_are_recovered_from_exact_clicks(view, level_m, size_m):
    from galileo.scenarios.splash.scene import Tank, default_scene

    cam = look_at_camera(view["eye"], view["target"], focal_px=view["focal_px"])
    truth = dataclasses.replace(default_scene(camera=cam), tank=Tank(size_m, water_level_m=level_m))
    cal = calibration_of("splash")
    info = VideoInfo(640, 480, 30.0, 60)
    uv = cam.project(true_points(truth))
    face_on = view["eye"][0] == 0.0
    for focal in ((view["focal_px"],) if face_on else (None, view["focal_px"])):
        scene, err = cal.solve(uv, {**tank_numbers(truth), "focal_px": focal, "release_x_m": 0.0,
                                    "release_height_m": 0.05}, info)
        # (exact but for OpenCV's homography, good to some 1e-6 px)
        assert err < 1e-5
        assert scene.camera.K[0, 0] == pytest.approx(view["focal_px"], rel=1e-6)
        assert np.linalg.norm(scene.camera.position_in_world - cam.position_in_world) < 1e-6
        assert rotation_deg(scene.camera, cam) < 1e-4
        assert scene.tank.water_level_m == pytest.approx(level_m, abs=1e-8)
        assert scene.tank.size_m == size_m and scene.release_m == pytest.approx((0.0, 0.0, level_m + 0.05), abs=1e-8)


def test_a_tank_seen_straight_from_the_front_needs_its_focal_length():
    """The demo's view shows the front face with no perspective: a pixel's error in the
    corners would move a focal length estimated from them by more than 1000%."""
    from galileo.scenarios.splash.scene import default_scene

    truth = default_scene()
    with pytest.raises(GalileoError, match=r"moves it by more than 1000% .*seen too nearly face-on.*give --focal-px"):
        calibration_of("splash").solve(truth.camera.project(true_points(truth)), tank_numbers(truth),
                                       VideoInfo(640, 480, 30.0, 60))


def test_the_focal_length_from_clicks_off_by_a_pixel_is_unbiased_and_spreads_as_the_solver_says():
    """Over 300 draws of clicks with 1 px noise, from above and to the left of the tank: the
    estimated focal length's mean is the true one within 3 standard errors, and its spread is
    what `focal_spread_per_px` (the solver's refusal rule) says, within the 3 standard errors of
    an SD from 300 draws (SD / sqrt(2 n), 12%)."""
    from galileo.clicks import _plane_coordinates, focal_spread_per_px
    from galileo.scenarios.splash.scene import default_scene

    cam = look_at_camera(ABOVE_LEFT["eye"], ABOVE_LEFT["target"], focal_px=ABOVE_LEFT["focal_px"])
    truth = default_scene(camera=cam)
    cal = calibration_of("splash")
    pts = true_points(truth)
    uv0 = cam.project(pts)
    rng = np.random.default_rng(0)
    rel = []
    for _ in range(300):
        scene, _ = cal.solve(uv0 + rng.normal(0.0, 1.0, uv0.shape),
                             {**tank_numbers(truth), "release_x_m": 0.0, "release_height_m": 0.05},
                             VideoInfo(640, 480, 30.0, 60))
        rel.append(scene.camera.K[0, 0] / ABOVE_LEFT["focal_px"] - 1)
    rel = np.array(rel)
    stated = focal_spread_per_px(_plane_coordinates(pts[:4]), uv0[:4], 320, 240, "the tank's front face")
    print(f"focal: mean {rel.mean():+.4f}, SD {rel.std():.4f}; stated SD {stated:.4f} a pixel")
    assert abs(rel.mean()) < 3 * rel.std() / np.sqrt(len(rel))
    assert abs(rel.std() / stated - 1) < 3 / np.sqrt(2 * len(rel))


# -- on the rendered demo, with noisy clicks: the command, tracking ----------------------------------------

def test_galileo_scene_on_the_rendered_splash_demo_tracks_the_object_as_the_truth_does(demo, tmp_path, capsys):
    from galileo.camera import backproject_to_plane

    folder, truth = demo
    uv = truth.camera.project(true_points(truth)) + np.random.default_rng(1).normal(0.0, NOISE_PX, (6, 2))
    out = tmp_path / "scene.json"
    sx, sy, sz = truth.tank.size_m
    assert main(["scene", str(folder / "video.mp4"), "--scenario", "splash", "--points", points_arg(uv),
                 "--tank-width-m", str(sx), "--tank-depth-m", str(sy), "--tank-height-m", str(sz),
                 "--focal-px", str(truth.camera.K[0, 0]), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert re.search(r"reprojection error [\d.]+ px; focal 900\.0 px; .* water 0\.\d+ m deep \(measured\); object "
                     r"let go at .* \(found in the first frames; give --release-x-m and --release-height-m", printed)
    mine = load_scene(out)
    assert mine.scenario == "splash" and mine.tank.size_m == truth.tank.size_m
    assert (mine.camera.width_px, mine.camera.height_px, mine.camera.n_frames, mine.camera.fps) == \
        (truth.camera.width_px, truth.camera.height_px, truth.camera.n_frames, truth.camera.fps)
    assert abs(mine.tank.water_level_m - truth.tank.water_level_m) < 4 * WATER_LEVEL_SD_M
    # where tracking puts the object: a pixel of the release plane maps back to the world within the bound
    grid = np.array([[x, 0.0, z] for x in np.linspace(-0.15, 0.15, 7) for z in np.linspace(0.02, 0.4, 8)])
    back = backproject_to_plane(mine.camera, truth.camera.project(grid), 0.0)
    assert np.linalg.norm(back - grid, axis=1).max() < PLANE_P99_M
    # the release point found in the first two frames (the truth: 15 cm above the water, in the middle)
    assert np.linalg.norm(np.subtract(mine.release_m, truth.release_m)) < PLANE_P99_M
    # and `galileo track` with the written scene follows the object where it does with the true scene
    tracked = []
    for scene in (folder / "scene.json", out):
        tracks = tmp_path / f"tracks-{len(tracked)}.json"
        assert main(["track", str(folder / "video.mp4"), "--scene", str(scene), "--out", str(tracks), "--quiet"]) == 0
        tracked.append(json.loads(tracks.read_text())["objects"][0])
    a, b = tracked
    seen = np.array(a["visible"]) & np.array(b["visible"])
    assert seen.sum() >= 0.9 * len(seen)
    diff = np.linalg.norm(np.array(a["position_m"])[seen] - np.array(b["position_m"])[seen], axis=1)
    print(f"tracked with the solved scene: median {1000 * np.median(diff):.1f} mm from the truth's tracks")
    assert np.median(diff) < PLANE_P99_M


def test_the_release_point_is_found_from_the_first_two_frames(tmp_path):
    """A block let go 13 cm above the water, 6 cm left of the middle, 0.125 s before frame 0
    (30 physics steps: at 1.2 m/s, by frame 1 nearly in the water), rendered;
    `find_release` with the true camera. The bound is what the pixels allow: the centroid's
    place within a pixel's footprint on the release plane (1.1 mm here), and the fall between
    frames 0 and 1 within two (its top edge in each within one), which the drop before frame 0
    takes times t0 / dt (g t0^2 / 2 with t0 = fall / (g dt) - dt / 2)."""
    from galileo.clicks import sample_video
    from galileo.render import Look
    from galileo.scenarios.splash.render import render_to_video
    from galileo.scenarios.splash.scene import Tank, default_camera, default_scene

    release_s, release = -30 / 240, (-0.06, 0.0, 0.33)
    cam = dataclasses.replace(default_camera(Tank()), n_frames=30)
    truth = dataclasses.replace(default_scene(density_g_cm3=1.3, camera=cam, release_s=release_s), release_m=release)
    truth.validate()
    render_to_video(truth, tmp_path / "drop.mp4", 30, look=Look.random(np.random.default_rng(3)), texture_seed=3)
    _, _, frames = sample_video(tmp_path / "drop.mp4")
    x, height = find_release(frames, truth)
    depth_m = (cam.world_to_camera[:3, :3] @ np.asarray(release) + cam.world_to_camera[:3, 3])[2]
    px_m = depth_m / cam.K[0, 0]                      # a pixel's footprint on the release plane
    t0_over_dt = -release_s * cam.fps
    print(f"found x {x:.4f} m, {height:.4f} m above the water; a pixel is {1000 * px_m:.2f} mm")
    assert abs(x - release[0]) < px_m
    assert abs(height - (release[2] - truth.tank.water_level_m)) < px_m * (1 + 2 * t0_over_dt)


# -- bad clicks and numbers: one line, exit code 2, nothing written ---------------------------------------

@pytest.mark.parametrize("edit, extra, needle", [
    (lambda uv: uv[[1, 0, 2, 3, 4, 5]], [], "the four points cross over: give them in the order top left, top right, "
                                            "bottom right, bottom left"),
    (lambda uv: uv[[4, 5, 0, 1, 2, 3]], [], "cross over"),                         # the water line first
    (lambda uv: uv[[3, 2, 1, 0, 4, 5]], [], "sees the tank's front face from behind: check the points' order"),
    (lambda uv: np.array([uv[0], (uv[0] + uv[2]) / 2, *uv[2:]]), [], "three of the four points are on one line"),
    (lambda uv: np.array([[-5.0, 100.0], *uv[1:]]), [], "the top left point (-5, 100) is outside the 640x480 frame"),
    (lambda uv: np.array([*uv[:5], uv[4] + 1]), [], "the water left and water right points are the same point"),
    (lambda uv: np.array([*uv[:4], uv[4] - (0, 150), uv[5] - (0, 150)]), [], "outside the tank (0 to 0.3 m)"),
    (lambda uv: np.array([*uv[:4], (20.0, uv[4][1]), uv[5]]), [], "beyond the tank's left wall"),
    (lambda uv: uv[:5], [], "--points: give 6 points u,v (pixels): top left, top right, bottom right, bottom left, "
                            "water left, water right; got 5"),
    (lambda uv: uv, ["--tank-width-m", "0.6"], "the points disagree with the stated tank by"),
    (lambda uv: uv, ["--water-level-m", "0.35"], "--water-level-m 0.35 is not below the tank's height 0.3 m"),
    (lambda uv: uv, ["--tank-depth-m", ""], "--tank-depth-m is needed: the tank's inner depth"),
    (lambda uv: uv, ["--tank-height-m", "-1"], "--tank-height-m: -1 is outside [0.02, 3]"),
    (lambda uv: uv, ["--angle-deg", "20"], "--angle-deg: not for --scenario splash"),
    (lambda uv: uv, ["--focal-px", ""], "give --focal-px"),
])
def test_wrong_clicks_and_numbers_are_refused_in_one_line(demo, tmp_path, capsys, edit, extra, needle):
    folder, truth = demo
    uv = edit(truth.camera.project(true_points(truth)))
    base = {"--tank-width-m": "0.4", "--tank-depth-m": "0.16", "--tank-height-m": "0.3", "--focal-px": "900"}
    base.update(dict(zip(extra[::2], extra[1::2])))
    code = main(["scene", str(folder / "video.mp4"), "--scenario", "splash", "--points", points_arg(uv),
                 *[x for kv in base.items() for x in kv], "--out", str(tmp_path / "s.json")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.startswith("galileo: error:") and needle in err and "\n" not in err, err
    assert not (tmp_path / "s.json").exists()


def test_the_upload_page_solves_a_splash_scene_in_its_own_words(demo):
    """The page's solver with the splash's calibration: the demo's clicks solve with the focal
    length entered; without it the page asks for its field by name."""
    from ui.calibrate import draw, probe_video, solve

    folder, truth = demo
    splash = calibration_of("splash")
    clip = probe_video(folder / "video.mp4")
    uv = truth.camera.project(true_points(truth))
    texts = {"tank_width_m": "0.4", "tank_depth_m": "0.16", "tank_height_m": "0.3", "focal_px": "900"}
    scene, err = solve(clip, uv, splash, texts)
    assert err < 0.01 and scene.tank.water_level_m == pytest.approx(truth.tank.water_level_m, abs=1e-6)
    img, s = draw(clip, uv, splash, scene)
    assert img.shape == (480 * s, 640 * s, 3)
    with pytest.raises(GalileoError, match=re.escape("enter Focal (px), or click them again more exactly")):
        solve(clip, uv, splash, {**texts, "focal_px": ""})
    with pytest.raises(GalileoError, match="click 2 more points on the frame"):
        solve(clip, uv[:4], splash, texts)
