"""`galileo scene` (issue 14): a ramp scene for your own video from four clicked points. The
truth is a camera the video was rendered with (the demo's) or built by look_at."""
import json
import subprocess
import sys

import numpy as np
import pytest

from galileo.camera import look_at_camera
from galileo.cli import main
from galileo.errors import GalileoError
from galileo.registry import load_scene
from galileo.scenarios.ramp.clicks import camera_from_clicks, ramp_points_in_world


def rotation_deg(a, b) -> float:
    r = a.world_to_camera[:3, :3].T @ b.world_to_camera[:3, :3]
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1))))


@pytest.mark.parametrize("eye, target, focal", [((-0.2, -1.2, 0.3), (-0.2, 0.0, 0.16), 560.0),
                                                ((-0.5, -1.0, 0.6), (-0.3, 0.0, 0.1), 700.0),
                                                ((0.2, -1.5, 0.4), (-0.2, 0.0, 0.1), 500.0)])
@pytest.mark.parametrize("upper_at_m", [0.5, 0.3])
def test_the_camera_is_recovered_from_four_exact_points(eye, target, focal, upper_at_m):
    true = look_at_camera(eye, target, focal_px=focal)
    uv = true.project(ramp_points_in_world(0.9, 0.3, 20.0, upper_at_m))
    for given in (None, focal):
        cam, err = camera_from_clicks(uv, width_px=640, height_px=480, fps=30, n_frames=90, length_m=0.9,
                                      width_m=0.3, angle_deg=20.0, upper_at_m=upper_at_m, focal_px=given)
        assert err < 0.01
        assert cam.K[0, 0] == pytest.approx(focal, rel=1e-4)
        assert np.linalg.norm(cam.position_in_world - true.position_in_world) < 1e-4
        assert rotation_deg(cam, true) < 0.01


def test_galileo_scene_on_the_rendered_demo_recovers_its_camera_and_tracks_like_it(demo_dir, tmp_path, capsys):
    from galileo.scenarios.ramp.tracking import track

    truth = load_scene(demo_dir / "scene.json")
    uv = truth.camera.project(ramp_points_in_world(truth.ramp.length_m, truth.ramp.width_m, truth.ramp.angle_deg, 0.5))
    t = truth.target
    out = tmp_path / "scene.json"
    assert main(["scene", str(demo_dir / "video.mp4"), "--ramp-px", " ".join(f"{u:.2f},{v:.2f}" for u, v in uv),
                 "--upper-at-m", "0.5", "--ramp-length-m", str(truth.ramp.length_m), "--ramp-width-m",
                 str(truth.ramp.width_m), "--angle-deg", str(truth.ramp.angle_deg),
                 "--start-m", str(truth.start_distance_m()), "--target", "cardboard",
                 "--target-distance-m", str(t.distance_m), "--target-size-m", ",".join(map(str, t.shape.size_m)),
                 "--out", str(out)]) == 0
    assert "reprojection error" in capsys.readouterr().out
    mine = load_scene(out)
    # the tolerances: 1 cm, 1 degree, 3% (the clicks are rounded to 0.01 px here)
    assert np.linalg.norm(mine.camera.position_in_world - truth.camera.position_in_world) < 0.01
    assert rotation_deg(mine.camera, truth.camera) < 1.0
    assert mine.camera.K[0, 0] == pytest.approx(truth.camera.K[0, 0], rel=0.03)
    assert (mine.camera.n_frames, mine.camera.fps) == (truth.camera.n_frames, truth.camera.fps)
    assert mine.start_distance_m() == pytest.approx(truth.start_distance_m())
    # and tracking with it finds the objects where tracking with the true scene does
    a, b = (track(demo_dir / "video.mp4", s, progress=False) for s in (truth, mine))
    for oa, ob in zip(a.objects, b.objects):
        seen = oa.visible & ob.visible
        assert seen.sum() >= 0.9 * len(seen)
        assert np.median(np.linalg.norm(oa.position_m[seen] - ob.position_m[seen], axis=1)) < 0.005


@pytest.mark.parametrize("edit, needle", [
    (lambda uv: uv[[1, 0, 2, 3]], "cross over"),                         # upper near and far swapped
    (lambda uv: np.array([uv[0], uv[0] * 0.5 + uv[2] * 0.5, uv[2], uv[3]]), "on one line"),
    (lambda uv: np.array([[-5.0, 10.0], *uv[1:]]), "outside the 640x480 frame"),
    (lambda uv: np.array([uv[0], uv[0], uv[2], uv[3]]), "the same point"),
])
def test_wrong_clicks_are_refused_in_one_line(demo_dir, tmp_path, capsys, edit, needle):
    truth = load_scene(demo_dir / "scene.json")
    uv = edit(truth.camera.project(ramp_points_in_world(0.9, 0.3, 20.0, 0.5)))
    code = main(["scene", str(demo_dir / "video.mp4"), "--ramp-px", " ".join(f"{u:.2f},{v:.2f}" for u, v in uv),
                 "--upper-at-m", "0.5", "--ramp-length-m", "0.9", "--ramp-width-m", "0.3", "--angle-deg", "20",
                 "--out", str(tmp_path / "s.json")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.startswith("galileo: error:") and needle in err and "\n" not in err
    assert not (tmp_path / "s.json").exists()


@pytest.mark.parametrize("flags, needle", [
    (["--ramp-px", "1,2 3,4"], "expected 8 numbers"),
    (["--ramp-px", "a,b c,d e,f g,h"], "expected 8 numbers"),
    (["--angle-deg", "75"], "--angle-deg must be in (0, 60)"),
    (["--upper-at-m", "2"], "beyond the ramp's length"),
    (["--ramp-width-m", "-0.3"], "--ramp-width-m must be a positive number"),
])
def test_bad_numbers_are_refused_in_one_line(demo_dir, tmp_path, capsys, flags, needle):
    truth = load_scene(demo_dir / "scene.json")
    uv = truth.camera.project(ramp_points_in_world(0.9, 0.3, 20.0, 0.5))
    base = {"--ramp-px": " ".join(f"{u:.2f},{v:.2f}" for u, v in uv), "--upper-at-m": "0.5", "--ramp-length-m": "0.9",
            "--ramp-width-m": "0.3", "--angle-deg": "20"}
    base.update(dict(zip(flags[::2], flags[1::2])))
    argv = ["scene", str(demo_dir / "video.mp4"), *[x for kv in base.items() for x in kv], "--out", str(tmp_path / "s")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("galileo: error:") and needle in err and "\n" not in err
