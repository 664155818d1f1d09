"""Radial lens distortion k1 in the camera (issue 29): projection and back-projection against
OpenCV's model (cv2.projectPoints, cv2.undistortPoints with distCoeffs (k1, 0, 0, 0)), the
inverse to 1e-6 px over the whole image up to the bound, k1 = 0 exactly the pinhole, straight
lines bowing the way the lens bends them, a pose recovered from features seen through the
lens, calibrations from clicks through it, and a bad k1 refused in one line."""
import contextlib
import dataclasses
import io
import json

import cv2
import numpy as np
import pytest
from conftest import DATA

from galileo import registry
from galileo.camera import (
    Camera,
    backproject_to_plane,
    camera_from_json,
    check_camera,
    look_at_camera,
)
from galileo.cli import main
from galileo.errors import GalileoError, SceneError
from galileo.shapes import Shape
from galileo.vision.pose import fit_pose, rot_y
from galileo.vision.tracker import ObjectTracker

ROUND_TRIP_PX = 1e-6         # the inverse's promise
OPENCV_PX = 1e-6             # OpenCV's float64 arithmetic differs from ours in the last bits only


def camera(k1: float = 0.0, **kw) -> Camera:
    return dataclasses.replace(look_at_camera((0.3, -1.0, 0.45), (0.0, 0.0, 0.05), **kw), k1=k1)


def largest_barrel_k1(cam: Camera) -> float:
    """The most negative k1 the camera accepts (bisection on check_camera)."""
    ok, bad = 0.0, -1.0
    for _ in range(60):
        mid = (ok + bad) / 2
        try:
            check_camera(dataclasses.replace(cam, k1=mid))
            ok = mid
        except SceneError:
            bad = mid
    return ok


def opencv_project(cam: Camera, pts: np.ndarray) -> np.ndarray:
    rvec, _ = cv2.Rodrigues(cam.world_to_camera[:3, :3])
    uv, _ = cv2.projectPoints(pts, rvec, cam.world_to_camera[:3, 3], cam.K, np.array([cam.k1, 0.0, 0.0, 0.0]))
    return uv.reshape(-1, 2)


def image_grid(cam: Camera, n: int = 41) -> np.ndarray:
    """Pixels over the whole image, its edges and corners included."""
    u, v = np.meshgrid(np.linspace(0, cam.width_px, n), np.linspace(0, cam.height_px, n))
    return np.c_[u.ravel(), v.ravel()]


@pytest.mark.parametrize("k1", [-0.25, -0.1, 0.05, 0.3, 1.0])
def test_projection_is_opencvs(k1):
    cam = camera(k1)
    pts = np.random.default_rng(1).uniform((-0.4, -0.3, -0.1), (0.4, 0.3, 0.4), (200, 3))
    uv = cam.project(pts)
    assert np.abs(uv - opencv_project(cam, pts)).max() < OPENCV_PX
    # and it is distortion: points away from the centre move
    assert np.abs(uv - camera().project(pts)).max() > 1.0


@pytest.mark.parametrize("k1", [-0.2, -0.05, 0.1, 0.4])
def test_undistortion_is_opencvs(k1):
    cam = camera(k1)
    uv = image_grid(cam)
    ref = cv2.undistortPoints(uv.reshape(-1, 1, 2), cam.K, np.array([k1, 0.0, 0.0, 0.0]), P=cam.K,
                              criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 500, 1e-15)).reshape(-1, 2)
    assert np.abs(cam.undistort_px(uv) - ref).max() < OPENCV_PX


@pytest.mark.parametrize("which", ["barrel bound", "barrel", "pincushion", "pincushion bound"])
@pytest.mark.parametrize("focal_px", [300.0, 560.0, 2000.0])
def test_undistortion_inverts_the_lens_to_a_micropixel_over_the_whole_image(which, focal_px):
    pinhole = camera(focal_px=focal_px)
    bound = largest_barrel_k1(pinhole)
    k1 = {"barrel bound": bound, "barrel": bound / 3, "pincushion": 0.2, "pincushion bound": 1.0}[which]
    cam = dataclasses.replace(pinhole, k1=k1)
    check_camera(cam)
    uv = image_grid(cam)
    flat = cam.undistort_px(uv)
    assert np.isfinite(flat).all() and np.abs(flat - uv).max() > 1.0     # (the corners move)
    assert np.abs(cam.distort_px(flat) - uv).max() < ROUND_TRIP_PX
    # and the other way round, from pinhole pixels over the undistorted image
    assert np.abs(cam.undistort_px(cam.distort_px(flat[::7])) - flat[::7]).max() < ROUND_TRIP_PX


def test_the_bound_is_where_the_lens_would_fold_inside_the_image():
    """The most barrel k1 accepted keeps r_d = r_u (1 + k1 r_u^2) increasing out to the corner
    (the corner's ray is inside the fold, sampled densely); a k1 a third stronger folds there:
    no ray reaches the corner at all."""
    cam = camera()
    k1 = largest_barrel_k1(cam)
    assert -1.0 < k1 < -0.05
    corner = np.hypot(cam.width_px / 2, cam.height_px / 2) / cam.K[0, 0]       # r_d of the corners
    r = np.linspace(0, 2, 20001)
    rd = r * (1 + k1 * r * r)
    reach = r[np.argmax(rd >= corner)]
    assert rd.max() >= corner and np.all(np.diff(rd[r <= reach]) > 0)
    strong = 4 / 3 * k1
    assert (r * (1 + strong * r * r)).max() < corner


def test_k1_zero_is_exactly_the_pinhole():
    cam = camera()
    pts = np.random.default_rng(2).uniform(-0.3, 0.3, (50, 3))
    r, t = cam.world_to_camera[:3, :3], cam.world_to_camera[:3, 3]
    uvw = (pts @ r.T + t) @ cam.K.T
    assert np.array_equal(cam.project(pts), uvw[:, :2] / uvw[:, 2:])
    uv = image_grid(cam, 9)
    assert np.array_equal(cam.undistort_px(uv), uv) and np.array_equal(cam.distort_px(uv), uv)
    rays = np.c_[uv, np.ones(len(uv))] @ np.linalg.inv(cam.K).T @ r
    s = (0.0 - cam.position_in_world[1]) / rays[:, 1]
    assert np.array_equal(backproject_to_plane(cam, uv, 0.0), cam.position_in_world + s[:, None] * rays)
    assert "k1" not in cam.to_json()


@pytest.mark.parametrize("k1", [-0.15, 0.15])
def test_a_straight_line_bows_outwards_through_barrel_and_inwards_through_pincushion(k1):
    """A 3-D line across the upper part of the view: its middle's image is farther from the
    principal point than the chord through its ends' images for barrel (k1 < 0), nearer for
    pincushion; through the pinhole it is straight."""
    for lens, sign in ((k1, -np.sign(k1)), (0.0, 0.0)):
        cam = camera(lens)
        ends_px = np.array([[40.0, 60.0], [600.0, 60.0]])
        a, b = backproject_to_plane(camera(), ends_px, 0.0)            # the line in the world (y = 0)
        uv = cam.project(np.linspace(a, b, 3))
        along = (uv[2] - uv[0]) / np.linalg.norm(uv[2] - uv[0])
        normal = np.array([-along[1], along[0]])
        towards_centre = np.sign(normal @ (cam.K[:2, 2] - uv[0]))
        bow_px = -towards_centre * (normal @ (uv[1] - uv[0]))     # > 0: the middle is off the chord, outwards
        if sign:
            assert np.sign(bow_px) == sign and abs(bow_px) > 1.0
        else:
            assert abs(bow_px) < 1e-9


def test_back_projection_undoes_projection_through_the_lens():
    cam = camera(-0.2)
    pts = np.c_[np.random.default_rng(3).uniform(-0.3, 0.3, 30), np.zeros(30), np.random.default_rng(4).uniform(
        -0.1, 0.3, 30)]
    uv = opencv_project(cam, pts)
    assert np.abs(backproject_to_plane(cam, uv, 0.0) - pts).max() < 1e-9
    d = cam.pixel_rays(uv)
    off = (pts - cam.position_in_world) - ((pts - cam.position_in_world) * d).sum(1, keepdims=True) * d / (
        d * d).sum(1, keepdims=True)
    assert np.abs(off).max() < 1e-9          # each point on its pixel's ray


def box_front_points(size_m, n: int = 5) -> np.ndarray:
    """Points (object frame) on the box's face towards the camera (y = -sy / 2)."""
    sx, sy, sz = size_m
    x, z = np.meshgrid(np.linspace(-0.4, 0.4, n) * sx, np.linspace(-0.4, 0.4, n) * sz)
    return np.c_[x.ravel(), np.full(x.size, -sy / 2), z.ravel()]


def test_a_tracker_through_the_lens_ties_features_to_the_shape_and_recovers_the_pose():
    """Features of a box near the image's corner, seen through a barrel lens (cv2.projectPoints
    of known points on its front face): the tracker's rays tie them to those very points, and
    the pose fit on them at a second pose finds that pose; a tracker that took the lens for a
    pinhole is millimetres off."""
    shape = Shape("box", (0.12, 0.06, 0.05))
    truth_obj = box_front_points(shape.size_m)
    pose0, pose1 = np.array([-0.38, 0.28, 0.1]), np.array([-0.34, 0.25, 0.3])
    for lens, expect in ((-0.2, "exact"), (0.0, "off")):
        cam = camera(lens)
        seen = camera(-0.2)      # the video's lens

        def pixels(pose, seen=seen):
            return opencv_project(seen, truth_obj @ rot_y(pose[2]).T + np.array([pose[0], 0.0, pose[1]]))

        px0 = pixels(pose0)
        assert np.linalg.norm(px0 - cam.K[:2, 2], axis=1).min() > 150      # near the corner: the lens matters
        mask = np.zeros((cam.height_px, cam.width_px), bool)
        mask[10:40, 10:40] = True
        tr = ObjectTracker(shape, mask, pose0, cam, 2)
        obj = tr._unproject(px0)
        if expect == "exact":
            assert np.abs(obj - truth_obj).max() < 1e-9
            found = fit_pose(cam, obj, pixels(pose1), pose0.copy())
            assert found is not None and found[1].all()
            assert np.abs(found[0] - pose1).max() < 1e-6
        else:       # (rays that miss the box altogether are NaN)
            assert not np.nanmax(np.abs(obj - truth_obj)) < 2e-3


def test_camera_json_round_trips_k1_and_pinhole_files_stay_as_they_were():
    doc = json.loads((DATA / "scene.json").read_text())
    pinhole = camera_from_json(doc["camera"])
    assert pinhole.k1 == 0.0 and pinhole.to_json() == doc["camera"]
    lens = dataclasses.replace(pinhole, k1=-0.12)
    back = camera_from_json(json.loads(json.dumps(lens.to_json())))
    assert back == lens and back.k1 == -0.12 and back != pinhole


def run_cli(args):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(args)
    return rc, out.getvalue(), err.getvalue()


@pytest.mark.parametrize("k1, needle", [(2, "camera.k1: 2 is outside [-1, 1]"),
                                        ("-0.1", "camera.k1: expected a number"),
                                        (-0.6, "camera.k1: -0.6 bends the image back on itself")])
def test_a_bad_k1_is_refused_in_one_line(tmp_path, k1, needle):
    doc = json.loads((DATA / "scene.json").read_text())
    doc["camera"]["k1"] = k1
    p = tmp_path / "scene.json"
    p.write_text(json.dumps(doc))
    with pytest.raises(SceneError, match=needle.replace("[", r"\[")):
        registry.load_scene(p)
    out = tmp_path / "traj.json"
    rc, _, err = run_cli(["simulate", "--scene", str(p), "--frames", "3", "--out", str(out)])
    assert rc == 2 and err.startswith(f"galileo: error: {p}: {needle}") and err.count("\n") == 1
    assert not out.exists()


# -- calibrations from clicks through the lens --------------------------------------------------------

K1_CLICKS = -0.12


@pytest.mark.parametrize("scenario", ["ramp", "fall", "splash", "spring"])
def test_a_calibration_through_the_lens_finds_the_camera_the_pinhole_finds_without_it(scenario):
    """Each scenario's example points, clicked in a video through a barrel lens (projected
    with OpenCV's model), solved with its k1 (`--distortion`): the camera the same points give
    clicked through a pinhole (the focal length estimated where the scenario estimates it),
    carrying the k1, the clicks reprojecting as well; solved as a pinhole the lens's clicks
    leave pixels of error or put the camera elsewhere."""
    from galileo.clicks import calibration_of
    from galileo.video import VideoInfo

    scene = registry.load_scene(DATA / "scene.json") if scenario == "ramp" else registry.get(scenario).default_scene()
    cal = calibration_of(scenario)
    world, numbers = cal.example(scene)
    pinhole = scene.camera
    lens = dataclasses.replace(pinhole, k1=K1_CLICKS)
    check_camera(lens)
    info = VideoInfo(pinhole.width_px, pinhole.height_px, pinhole.fps, pinhole.n_frames)
    reference, reference_err = cal.solve(pinhole.project(world), numbers, info)
    uv = opencv_project(lens, world)
    mine, err = cal.solve(uv, {**numbers, "distortion": K1_CLICKS}, info)
    assert mine.camera.k1 == K1_CLICKS and abs(err - reference_err) < 1e-6
    assert np.abs(mine.camera.K - reference.camera.K).max() < 1e-6 * pinhole.K[0, 0]
    assert np.abs(mine.camera.world_to_camera - reference.camera.world_to_camera).max() < 1e-8
    try:
        plain, plain_err = cal.solve(uv, numbers, info)
    except GalileoError:      # (a pinhole cannot fit them at all: also a miss)
        return
    moved = np.linalg.norm(plain.camera.position_in_world - reference.camera.position_in_world)
    assert plain_err > 0.5 or moved > 1e-3


def test_the_fall_scenarios_lift_and_likelihood_see_through_the_lens():
    """The fall's own pixel <-> world paths: its likelihood's unrolled projection is OpenCV's,
    and its lift puts pixels of points on a plane (OpenCV's projection) back on them."""
    from types import SimpleNamespace

    from galileo.scenarios.fall.likelihood import FallLikelihood, camera_rows
    from galileo.scenarios.fall.tracks import on_plane

    cam = dataclasses.replace(registry.get("fall").default_scene().camera, k1=-0.15)
    check_camera(cam)
    rng = np.random.default_rng(5)
    pts = np.c_[rng.uniform(-0.2, 0.2, (40, 2)), np.full(40, 0.03)]
    truth = opencv_project(cam, pts)
    lik = SimpleNamespace(P=camera_rows(cam), camera=cam)
    assert np.abs(np.array([FallLikelihood.project(lik, p) for p in pts]) - truth).max() < OPENCV_PX
    assert np.abs(on_plane(cam, truth, 0.03) - pts).max() < 1e-9


def test_galileo_scene_distortion_writes_the_lens_into_the_scene_file(tmp_path):
    """`galileo scene --distortion K1` on clicks through that lens: the scene file's camera has
    "k1" and sees the ramp's points at the clicks; a k1 that folds the image at the solved
    focal length is refused in one line, no file written."""
    from galileo.scenarios.ramp.clicks import ramp_points_in_world
    from galileo.video import write_video

    truth = registry.load_scene(DATA / "scene.json")
    lens = dataclasses.replace(truth.camera, k1=-0.1)
    r = truth.ramp
    world = ramp_points_in_world(r.length_m, r.width_m, r.angle_deg, 0.5)
    uv = opencv_project(lens, world)
    video = tmp_path / "video.mp4"
    write_video(video, [np.full((lens.height_px, lens.width_px, 3), 128, np.uint8)] * 3, lens.fps)
    out = tmp_path / "scene.json"
    argv = ["scene", str(video), "--points", " ".join(f"{u:.4f},{v:.4f}" for u, v in uv), "--upper-at-m", "0.5",
            "--ramp-length-m", str(r.length_m), "--ramp-width-m", str(r.width_m), "--angle-deg", str(r.angle_deg),
            "--start-m", "0.4", "--out", str(out)]
    rc, _, err = run_cli([*argv, "--distortion", "-0.1"])
    assert rc == 0, err
    assert json.loads(out.read_text())["camera"]["k1"] == -0.1
    mine = registry.load_scene(out).camera
    assert np.abs(mine.project(world) - uv).max() < 0.01          # (the clicks are rounded to 1e-4 px)
    assert np.linalg.norm(mine.position_in_world - truth.camera.position_in_world) < 1e-3
    out.unlink()
    rc, _, err = run_cli([*argv, "--distortion", "-0.9"])
    assert rc == 2 and err.startswith("galileo: error: --distortion") and err.count("\n") == 1 and not out.exists()
