"""`galileo scene --scenario fall` (issue 27): a fall scene for your own video from the four
clicked corners of a rectangle of known size on the surface. The truth is a camera built here
(`look_at_camera`, the scenario's `default_camera`) whose projections of the rectangle's corners
are the clicks: the solved camera must see the surface (and the space above it) as the true
one does, its focal length estimated from the rectangle alone; clicks with Gaussian noise
spread that estimate as linear error propagation says; bad clicks and sizes get one line."""
import dataclasses
import math

import numpy as np
import pytest

from galileo.camera import look_at_camera
from galileo.cli import main
from galileo.clicks import calibration_of, focal_spread_per_px
from galileo.errors import GalileoError
from galileo.registry import load_scene
from galileo.scenarios.fall.clicks import AXIS_RGB, DEFAULT_HFOV_DEG, GRID_RGB, RECT_RGB
from galileo.scenarios.fall.scene import (
    default_camera,
    default_scene,
    surface_corners_m,
)
from galileo.video import VideoInfo

W, H = 640, 360
SIZE = (1.22, 0.61)
# the surface and the space an object falls through: a grid over the rectangle, at the surface and 30 cm up
SPACE = np.array([[x, y, z] for x in np.linspace(-0.6, 0.6, 7) for y in np.linspace(-0.3, 0.3, 5) for z in (0, 0.3)])

VIEWS = {   # name -> the true camera: above the near end looking along the surface, as Physics 101 films it
    "default": default_camera(SIZE, width_px=W, height_px=H),
    "high, 1080p": look_at_camera((-1.3, 0.0, 1.2), (0.0, 0.0, 0.0), focal_px=1400.0, width_px=1920, height_px=1080),
    "from the side, rolled": look_at_camera((-1.2, 0.25, 0.9), (0.05, -0.05, 0.0), focal_px=1000.0, width_px=1920,
                                            height_px=1080),
    "low, wide": look_at_camera((-1.3, 0.0, 0.45), (0.1, 0.0, 0.0), focal_px=380.0, width_px=W, height_px=H),
}


def scene_seen_by(cam):
    return dataclasses.replace(default_scene(), camera=cam, fps=cam.fps, n_frames=cam.n_frames,
                               surface_size_m=SIZE)


def info_of(cam) -> VideoInfo:
    return VideoInfo(cam.width_px, cam.height_px, cam.fps, cam.n_frames)


def points_arg(uv) -> str:
    return " ".join(f"{u:.3f},{v:.3f}" for u, v in uv)


@pytest.mark.parametrize("view", VIEWS)
def test_the_camera_comes_back_from_the_rectangles_corners_with_its_focal_length_estimated(view):
    """The corners `example` says a user clicks, projected by the true camera: without a focal
    length the solved one has the true focal length and sees the surface and the space above
    it where the true one does; given the true focal length, the same."""
    truth = scene_seen_by(VIEWS[view])
    cal = calibration_of("fall")
    world, numbers = cal.example(truth)
    np.testing.assert_array_equal(world, surface_corners_m(truth))
    uv = truth.camera.project(world)
    assert "focal_px" not in numbers
    for given in (numbers, {**numbers, "focal_px": float(truth.camera.K[0, 0])}):
        scene, err = cal.solve(uv, given, info_of(truth.camera))
        assert err < 1e-3
        assert scene.camera.K[0, 0] == pytest.approx(truth.camera.K[0, 0], rel=1e-6)
        np.testing.assert_allclose(scene.camera.position_in_world, truth.camera.position_in_world, atol=1e-5)
        assert np.abs(scene.camera.project(SPACE) - truth.camera.project(SPACE)).max() < 1e-3
    assert (scene.surface_size_m, scene.object, scene.surface, scene.shape) == (SIZE, truth.object, truth.surface,
                                                                               truth.shape)
    text = cal.describe(scene, numbers)
    pos = truth.camera.position_in_world
    assert text.startswith(f"focal {truth.camera.K[0, 0]:.0f} px (estimated from the rectangle); camera "
                           f"{pos[2]:.2f} m above the surface, {np.linalg.norm(pos):.2f} m from the rectangle's centre")


def test_noisy_clicks_spread_the_focal_length_as_linear_error_propagation_says():
    """Gaussian noise of 1 px on each click coordinate, 400 draws: the focal length's relative
    error is unbiased (within 3 standard errors) and its SD is the root sum of squares of its
    derivatives by the click coordinates (`focal_spread_per_px`), within the 3 standard errors
    of an SD from 400 draws (SD / sqrt(2 n)); about 1% here, a few % at most."""
    cam = VIEWS["high, 1080p"]
    truth = scene_seen_by(cam)
    cal = calibration_of("fall")
    world, numbers = cal.example(truth)
    uv0 = cam.project(world)
    rng = np.random.default_rng(0)
    n, sigma = 400, 1.0
    rel = np.array([cal.solve(uv0 + rng.normal(0.0, sigma, uv0.shape), numbers, info_of(cam))[0].camera.K[0, 0]
                    / cam.K[0, 0] - 1 for _ in range(n)])
    stated = sigma * focal_spread_per_px(world[:, :2], uv0, cam.width_px / 2, cam.height_px / 2, "the rectangle")
    print(f"focal: mean {rel.mean():+.5f}, SD {rel.std():.5f}; stated {stated:.5f}")
    assert abs(rel.mean()) < 3 * rel.std() / math.sqrt(n)
    assert abs(rel.std() / stated - 1) < 3 / math.sqrt(2 * n)
    assert stated < 0.03


def test_a_rectangle_seen_face_on_falls_back_to_the_default_field_of_view_and_says_so():
    """A camera 1.5 m straight above the rectangle (0.8 deg off): no focal length can be told
    from it, so the default's is used; a face-on camera sees the plane at the scale focal /
    height, so the solved camera stands higher by the focal lengths' ratio."""
    cam = look_at_camera((-0.02, 0.0, 1.5), (0.0, 0.0, 0.0), focal_px=800.0, width_px=1280, height_px=720)
    truth = scene_seen_by(cam)
    cal = calibration_of("fall")
    world, numbers = cal.example(truth)
    scene, _ = cal.solve(cam.project(world), numbers, info_of(cam))
    default = 1280 / (2 * math.tan(math.radians(DEFAULT_HFOV_DEG) / 2))
    assert scene.camera.K[0, 0] == pytest.approx(default)
    assert scene.camera.position_in_world[2] == pytest.approx(1.5 * default / 800.0, rel=1e-2)
    assert f"(default: a {DEFAULT_HFOV_DEG:g} deg field of view;" in cal.describe(scene, numbers)


CORNERS = VIEWS["default"].project(surface_corners_m(scene_seen_by(VIEWS["default"])))   # NL, NR, FR, FL
NL, NR, FR, FL = (tuple(p) for p in CORNERS)


@pytest.mark.parametrize("points, needle", [
    ([NL, NR, FL, FR], "the four points cross over: give them in the order near left, near right, far right, far left"),
    ([NL, NR, FR, (320.0, 300.0)], "are not the corners of a convex quadrilateral (one is inside the triangle"),
    ([NL, (320.0, NL[1]), NR, FL], "three of the four points are on one line"),
    ([FR, FL, NL, NR], "the near edge (points 1-2) is above the far edge (points 3-4) in the image"),
    ([FL, FR, NR, NL], "the near edge (points 1-2) is above the far edge (points 3-4) in the image"),
    ([NR, NL, FL, FR], "the left and right corners are swapped"),
])
def test_corners_out_of_order_or_shape_are_refused_in_one_line(points, needle):
    cal = calibration_of("fall")
    with pytest.raises(GalileoError) as e:
        cal.solve(points, {"length_m": 1.22, "width_m": 0.61}, VideoInfo(W, H, 30.0, 36))
    assert needle in str(e.value) and "\n" not in str(e.value), str(e.value)


# -- the command line: a video's scene, and bad input in one line ------------------------------------------

@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """A 3-frame 640x360 video (what `galileo scene` reads of it: its size, frame rate and length)."""
    from galileo.video import write_video

    path = tmp_path_factory.mktemp("fall_clicks") / "clip.mp4"
    rng = np.random.default_rng(0)
    write_video(path, (rng.integers(0, 255, (H, W, 3), dtype=np.uint8) for _ in range(3)), 25.0)
    return path


def test_galileo_scene_writes_the_fall_scene_of_a_video(clip, tmp_path, capsys):
    cam = VIEWS["default"]
    out = tmp_path / "scene.json"
    assert main(["scene", str(clip), "--scenario", "fall", "--points", points_arg(CORNERS), "--length-m", "1.22",
                 "--width-m", "0.61", "--object", "woodblock", "--surface", "foammat", "--surface-kind", "foam",
                 "--object-shape", "cylinder", "--object-size-m", "0.1,0.04,0.04", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert ("reprojection error 0.00 px; focal 533 px (estimated from the rectangle); camera 0.75 m above the "
            "surface, 1.30 m from the rectangle's centre, looking 41 deg down; surface foammat (foam, its rectangle "
            "1.22 x 0.61 m), object woodblock (cylinder 10 x 4 x 4 cm)") in printed
    mine = load_scene(out)
    assert (mine.scenario, mine.object, mine.surface, mine.surface_kind, mine.surface_size_m) == (
        "fall", "woodblock", "foammat", "foam", (1.22, 0.61))
    assert (mine.shape.name, mine.shape.size_m) == ("cylinder", (0.1, 0.04, 0.04))
    assert (mine.fps, mine.n_frames, mine.camera.fps, mine.camera.n_frames) == (25.0, 3, 25.0, 3)
    assert mine.sim_hz % 25.0 == 0
    # (the clicks written to 0.001 px)
    np.testing.assert_allclose(mine.camera.project(SPACE), cam.project(SPACE), atol=0.01)


@pytest.mark.parametrize("points, flags, needle", [
    (CORNERS, ["--length-m", "-1.22"], "--length-m: -1.22 is outside (0, 20]"),
    (CORNERS, ["--length-m", "0"], "--length-m: 0 is outside (0, 20]"),
    (CORNERS, ["--width-m", "-0.61"], "--width-m: -0.61 is outside (0, 20]"),
    (CORNERS, ["--width-m", ""], "--width-m is needed: the rectangle's width"),
    ([NL, NR, FL, FR], [], "the four points cross over"),
    (CORNERS, ["--surface-kind", "ice"], "--surface-kind: expected one of table, foam, carpet, cloth, got 'ice'"),
    (CORNERS, ["--object", "Wood Block"], "--object: 'Wood Block' is not a name"),
    (CORNERS, ["--object-shape", "torus"], "--object-size-m: a torus needs size_m x == y"),
    (CORNERS, ["--object-size-m", "0.1,0,0.04"], "--object-size-m: 0 is outside (0, 5]"),
    (CORNERS, ["--length-m", "20", "--width-m", "10", "--focal-px", "20000"], "puts the camera"),
    (CORNERS[:3], [], "--points: give 4 points u,v (pixels): near left, near right, far right, far left; got 3"),
    (CORNERS, ["--angle-deg", "20"], "--angle-deg: not for --scenario fall"),
])
def test_bad_clicks_and_numbers_are_refused_in_one_line(clip, tmp_path, capsys, points, flags, needle):
    out = tmp_path / "s.json"
    code = main(["scene", str(clip), "--scenario", "fall", "--points", points_arg(points), "--length-m", "1.22",
                 "--width-m", "0.61", *flags, "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.startswith("galileo: error:") and needle in err and "\n" not in err, err
    assert not out.exists()


# -- the overlay and the upload page ------------------------------------------------------------------------

def _near(img, uv, rgb) -> bool:
    u, v = np.round(uv).astype(int)
    patch = img[v - 1:v + 2, u - 1:u + 2].reshape(-1, 3).astype(int)
    return bool(np.abs(patch - rgb).sum(axis=1).min() < 60)


def test_the_upload_page_solves_and_draws_a_fall_scene_in_its_own_words(clip):
    """The page's solver and picture: its messages name its inputs; the overlay draws the
    rectangle through the clicks, the 10 cm grid where the true camera sees the surface's
    lines x = 0.3 m and y = -0.2 m, and the world's y axis from the rectangle's centre."""
    from ui.calibrate import draw, probe_video, solve

    fall = calibration_of("fall")
    c = probe_video(clip)
    c = dataclasses.replace(c, first=np.zeros_like(c.first))       # a black frame: only the overlay shows
    with pytest.raises(GalileoError, match=r"^Width \(m\): -1 is outside"):
        solve(c, CORNERS, fall, {"length_m": "1.22", "width_m": "-1"})
    with pytest.raises(GalileoError, match=r"^Surface \(id\): 'My Table' is not a name"):
        solve(c, CORNERS, fall, {"length_m": "1.22", "width_m": "0.61", "surface": "My Table"})
    with pytest.raises(GalileoError, match=r"^Length \(m\) is needed"):
        solve(c, CORNERS, fall, {"width_m": "0.61"})
    scene, _ = solve(c, CORNERS, fall, {"length_m": "1.22", "width_m": "0.61"})
    img, s = draw(c, CORNERS, fall, scene)
    assert img.shape == (H * s, W * s, 3)
    cam = VIEWS["default"]
    for a, b in zip(CORNERS, np.roll(CORNERS, -1, axis=0)):
        for f in (0.3, 0.45, 0.6):
            assert _near(img, (a + f * (b - a)) * s, RECT_RGB)
    for p in ((0.3, 0.15, 0.0), (0.3, -0.1, 0.0), (-0.45, -0.2, 0.0), (0.05, -0.2, 0.0)):
        assert _near(img, cam.project(np.array(p)) * s, GRID_RGB), p
    assert _near(img, cam.project(np.array([0.0, 0.15, 0.0])) * s, AXIS_RGB[1])
    assert not _near(img, cam.project(np.array([0.25, 0.05, 0.0])) * s, GRID_RGB)   # between grid lines
