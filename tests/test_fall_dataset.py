"""The fall's rendered dataset against independent truth: the object's pixels (the renderer's
segmentation) centre on the camera's projection of the simulated centre; a frame during the
fall is the average of renders over its exposure (the object's streak is longer than the still
object by the projected distance it travels while the shutter is open); the hand touches the
object until the release frame and is clear of it after; the bounce apexes of a ball dropped
by Newton's law are e^2 h and e^4 h; the folders hold what the kit's layout says; a rebuild
keeps finished videos and renders what was deleted."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

import galileo.scenarios.fall.dataset as fd
from galileo.dataset import build
from galileo.datatypes import Trajectory
from galileo.scenarios.fall.scene import scene_from_json

G = 9.81
TINY = (320, 180)           # the tests render at a quarter of the dataset's pixels
# the object's mask centroid against the projected centre: the pixel grid scatters a mask's
# centroid by ~0.2 px (SD), perspective moves a box's outline's centroid off its projected centre
# by (size / 2)^2 / distance x focal / distance < 0.3 px for the demo's 9 cm block at 1.1 m (f
# 230 px), and a blurred frame averages 5 such masks: within 3 SD plus that
CENTRE_TOL_PX = 0.9
HAND_TOUCH_PX = 2           # a holding hand's pixels lie this close to the object's
STREAK_TOL_PX = 1.5         # a streak's length: the mask's extent measured to a pixel at each end
TRUTH_KEYS = {"latents", "release_frame", "object", "surface", "center_px", "silhouette_center_px", "visible",
              "rest_pos_m", "rest_height_m", "first_bounce_apex_m", "second_bounce_apex_m", "trajectory",
              "orientation_xyzw"}


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """The demo preset at TINY resolution built into a folder (one worker: the resolution is
    this process's), and each video rendered again with its masks."""
    mp = pytest.MonkeyPatch()
    mp.setattr(fd, "WIDTH_PX", TINY[0])
    mp.setattr(fd, "HEIGHT_PX", TINY[1])
    out = tmp_path_factory.mktemp("fall_demo")
    entries = build(fd.DATASET, "demo", out, seed=0, workers=1, progress=False)
    videos = []
    for spec in fd.plan("demo", 0):
        scene, motion, renderer = fd.renderer_for(spec)
        masks, seen = renderer.render(motion.position_m[0], motion.orientation_xyzw[0])
        videos.append((spec, scene, motion, renderer, masks, seen))
    yield out, entries, videos
    mp.undo()


def _centroid(mask: np.ndarray) -> np.ndarray:
    v, u = np.indices(mask.shape)
    return np.array([(u * mask).sum(), (v * mask).sum()]) / mask.sum()


def _sub_index(scene, frame: int, k: int) -> int:
    n, _ = fd.blur_offsets()
    return max(0, n * frame + k)


def test_object_pixels_centre_on_the_projected_truth(tiny):
    """At rest and in every visible frame of the fall, the blurred mask's centroid is the mean of
    the sub-frame centres as the camera projects them."""
    _, _, videos = tiny
    _, ks = fd.blur_offsets()
    for spec, scene, motion, _, masks, seen in videos:
        checked = 0
        for f in range(scene.n_frames):
            if not seen[f]:
                continue
            centres = scene.camera.project(motion.position_m[0, [_sub_index(scene, f, int(k)) for k in ks]])
            err = np.abs(_centroid(masks[f]) - centres.mean(axis=0))
            assert (err < CENTRE_TOL_PX).all(), (spec.name, f, err)
            checked += 1
        assert checked >= scene.n_frames - scene.release_frame - 6, spec.name


def test_a_falling_frame_is_the_average_over_its_exposure(tiny):
    """Mid-fall, the object's streak along the image's v is longer than the still object (its
    render at the frame's time) by the projected distance its centre travels over the exposure."""
    _, _, videos = tiny
    n, ks = fd.blur_offsets()
    for spec, scene, motion, renderer, masks, seen in videos:
        vz = motion.velocity_mps[0, :, 2]
        f = next(f for f in range(scene.release_frame + 1, scene.n_frames)
                 if seen[f] and vz[n * f + ks[-1]] < -1.5 and vz[n * f + ks[0]] < -1.5)   # falling, no impact
        j = n * f
        _, still, _ = renderer.render_pose(j / (n * scene.fps), motion.position_m[0, j], motion.orientation_xyzw[0, j])
        rows = lambda m: np.flatnonzero(m.any(axis=1))
        blurred_len, still_len = np.ptp(rows(masks[f] > 0)), np.ptp(rows(still))
        travel = scene.camera.project(motion.position_m[0, [j + ks[0], j + ks[-1]]])
        assert blurred_len - still_len == pytest.approx(abs(travel[1, 1] - travel[0, 1]), abs=STREAK_TOL_PX), spec.name
        partial = (masks[f] > 0) & (masks[f] < 1)          # pixels the object covers for part of the exposure
        assert partial.sum() > 0.2 * (masks[f] > 0).sum(), spec.name


def test_the_hand_holds_the_object_until_the_release_frame(tiny):
    """Up to the release frame the object is still where it is let go and the hand's pixels touch
    it; from the release on it falls, the hand pulls away and, a few frames later, is clear of it
    to the end."""
    _, _, videos = tiny
    n, _ = fd.blur_offsets()
    for spec, scene, motion, renderer, masks, seen in videos:
        rel = scene.release_frame
        pos = motion.position_m[0]
        assert np.allclose(pos[:n * rel + 1], [scene.x0_m, scene.y0_m, scene.z0_m]), spec.name
        assert pos[n * (rel + 1), 2] < scene.z0_m - 0.5 * G * (1 / scene.fps) ** 2 * 0.99, spec.name
        for f in range(scene.n_frames):
            j = n * f
            _, obj, hand = renderer.render_pose(j / (n * scene.fps), pos[j], motion.orientation_xyzw[0, j])
            touching = bool(obj.any()) and _touches(obj, hand, HAND_TOUCH_PX)
            assert touching == (f <= rel) or f in range(rel + 1, rel + 3), (spec.name, f, touching)
        assert not any(seen[:rel + 1]) and all(seen[rel + 4:]), (spec.name, seen)


def _touches(a: np.ndarray, b: np.ndarray, px: int) -> bool:
    """Whether a pixel of mask b lies within `px` (chessboard) of one of mask a."""
    import cv2

    grown = cv2.dilate(a.astype(np.uint8), np.ones((2 * px + 1, 2 * px + 1), np.uint8)) > 0
    return bool((grown & b).any())


def test_bounce_apexes_of_a_ball_are_e2_h_and_e4_h():
    """A ball dropped from h by Newton's law with restitution e (sampled at 240 Hz): its centre
    rises e^2 h after the first impact and e^4 h after the second, above where it lies."""
    h, e, r, hz = 0.3, 0.6, 0.02, 240.0
    t = np.arange(int(1.5 * hz)) / hz
    z, vz = np.empty_like(t), np.empty_like(t)
    t0, v0, z0 = 0.0, 0.0, h + r                    # each flight's start: time, upward speed, height
    for i, ti in enumerate(t):
        s = ti - t0
        zi = z0 + v0 * s - 0.5 * G * s * s
        if zi < r:                                  # an impact: the next flight leaves at e times the speed
            v_in = math.sqrt(v0 * v0 + 2 * G * (z0 - r))
            t0, v0, z0 = t0 + (v0 + v_in) / G, e * v_in, r
            s = ti - t0
            zi = z0 + v0 * s - 0.5 * G * s * s
        z[i], vz[i] = zi, v0 - G * s
    pos = np.zeros((1, len(t), 3))
    vel = np.zeros_like(pos)
    pos[0, :, 2], vel[0, :, 2] = z, vz
    first, second = fd.bounce_apexes_m(Trajectory(hz, ["object"], pos, vel), r)
    # sampled at 240 Hz, an apex is missed by at most g (dt / 2)^2 / 2 = 0.02 mm
    assert first == pytest.approx(e ** 2 * h, abs=1e-4)
    assert second == pytest.approx(e ** 4 * h, abs=1e-4)


def test_demo_files(tiny):
    """The kit's layout: index.json, per video a video of n_frames frames at the scene's size, a
    scene file whose values are the truth's latents, truth.json with its keys, one value per
    frame; videos of one object on one surface share its e and mu by name."""
    from galileo.video import read_frames

    out, _, videos = tiny
    index = json.loads((out / "index.json").read_text())
    assert index["scenario"] == "fall" and [e["name"] for e in index["videos"]] == [v[0].name for v in videos]
    latents = {}
    for spec, scene, motion, _, masks, seen in videos:
        folder = out / spec.name
        truth = json.loads((folder / "truth.json").read_text())
        assert set(truth) == TRUTH_KEYS
        saved = scene_from_json(json.loads((folder / "scene.json").read_text()))
        assert saved.latents() == {k: v for k, v in truth["latents"].items() if v is not None}
        assert saved.camera.width_px == TINY[0] and saved.surface_kind == spec.surface.kind
        frames = list(read_frames(folder / "video.mp4"))
        assert len(frames) == saved.n_frames and frames[0].shape == (TINY[1], TINY[0], 3)
        for key in ("center_px", "silhouette_center_px", "visible", "orientation_xyzw"):
            assert len(truth[key]) == saved.n_frames, key
        assert np.allclose(truth["rest_pos_m"], motion.position_m[0, -1, :2], atol=1e-3)
        latents[spec.name] = saved.latents()
    table = [v for k, v in latents.items() if k.endswith("_table")]
    assert len(table) == 2 and {k: table[0][k] for k in table[0] if k.startswith(("e_", "mu_"))} == \
        {k: table[1][k] for k in table[1] if k.startswith(("e_", "mu_"))}
    foam = next(v for k, v in latents.items() if k.endswith("_foam"))
    assert "e_woodenblock0_foam" in foam and "e_woodenblock0_table" in table[0]


def test_rebuild_keeps_finished_videos_and_renders_deleted_ones(tiny, monkeypatch):
    """A second build into the same folder renders nothing; after one video's truth is deleted,
    only that video is rendered again (the others' files untouched)."""
    out, _, videos = tiny
    monkeypatch.setattr(fd, "WIDTH_PX", TINY[0])
    monkeypatch.setattr(fd, "HEIGHT_PX", TINY[1])
    stamp = {v[0].name: (out / v[0].name / "video.mp4").stat().st_mtime_ns for v in videos}
    build(fd.DATASET, "demo", out, seed=0, workers=1, progress=False)
    assert {n: (out / n / "video.mp4").stat().st_mtime_ns for n in stamp} == stamp
    gone = videos[1][0].name
    (out / gone / "truth.json").unlink()
    build(fd.DATASET, "demo", out, seed=0, workers=1, progress=False)
    assert (out / gone / "truth.json").exists()
    after = {n: (out / n / "video.mp4").stat().st_mtime_ns for n in stamp}
    assert after[gone] != stamp[gone] and all(after[n] == stamp[n] for n in stamp if n != gone)


def test_plan_spans_surfaces_shapes_and_pairs():
    """The small preset: 24 videos, every surface kind, boxes, cylinders and a torus, each object
    once per surface; deterministic per seed; the table bounces more than foam on average."""
    small = fd.plan("small", 0)
    assert len(small) == 24 and small == fd.plan("small", 0) and small != fd.plan("small", 1)
    assert {s.surface.kind for s in small} == {"table", "foam", "carpet", "cloth"}
    assert {s.obj.shape.type for s in small} == {"box", "cylinder", "torus"}
    e = {kind: np.mean([fd.pair_truth(s.obj, s.surface, 0)[0] for s in small if s.surface.kind == kind])
         for kind in ("table", "foam")}
    assert e["table"] > e["foam"]
    assert len(fd.plan("full", 0)) == 26 * 4 * fd.TAKES
