"""Connectors (`galileo.drawing`): the polyline of a line or a helix between two anchors, each
fixed in the world or on a body, checked against rigid transforms worked by hand (and by
scipy's rotations); drawn by the viewer and logged by rerun for the test-only drop scenario,
whose drawing has a spring from a fixed hook to the falling ball."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from conftest import free_port
from galileo import registry
from galileo.drawing import HELIX_POINTS_PER_COIL, Anchor, Connector, Drawing, connector_points
from scenarios.drop import HOOK_ABOVE_M, SPRING_COILS, SPRING_RADIUS_PER_BALL_RADIUS, DropScenario, DropScene

S45 = math.sqrt(0.5)
SCENE = DropScene(height_m=0.4, radius_m=0.02, restitution=0.5, fps=60.0, n_frames=30)
HOOK_M = np.array([0.0, 0.0, 0.4 + 2 * 0.02 + HOOK_ABOVE_M])    # the drop's hook, by hand
FLOAT32_M = 1e-6     # viser keeps points as float32: ~6e-8 relative on coordinates under 1 m


def polyline_of(handle) -> np.ndarray:
    """A line-segments handle's (N - 1, 2, 3) points as the (N, 3) polyline they join."""
    seg = np.asarray(handle.points, float)
    np.testing.assert_allclose(seg[1:, 0], seg[:-1, 1])    # consecutive segments share their ends
    return np.vstack([seg[:, 0], seg[-1:, 1]])


def assert_helix(points: np.ndarray, a: np.ndarray, b: np.ndarray, coils: int, radius_m: float, atol: float):
    """The anchors a and b at the ends, and between them `coils` turns at `radius_m` from the line
    a-b, from a's end of the axis to b's (so the axis is exactly as long as the anchors are apart)."""
    assert points.shape == (coils * HELIX_POINTS_PER_COIL + 3, 3)
    np.testing.assert_allclose(points[0], a, atol=atol)
    np.testing.assert_allclose(points[-1], b, atol=atol)
    length = np.linalg.norm(b - a)
    d = (b - a) / length
    coil = points[1:-1] - a
    along = coil @ d
    radial = coil - along[:, None] * d
    np.testing.assert_allclose(np.linalg.norm(radial, axis=1), radius_m, atol=atol)
    assert along[0] == pytest.approx(0.0, abs=atol) and along[-1] == pytest.approx(length, abs=atol)
    assert np.all(np.diff(along) > 0)
    # the turns: the radial direction's angle about the axis winds `coils` times round
    u = radial[0] / np.linalg.norm(radial[0])
    angle = np.unwrap(np.arctan2(radial @ np.cross(d, u), radial @ u))
    assert abs(angle[-1] - angle[0]) == pytest.approx(2 * math.pi * coils, abs=1e-6)


# -- the polyline ------------------------------------------------------------------------------------------

def test_anchors_on_bodies_follow_their_rigid_transforms():
    """A point in a body's frame lands where the body's pose puts it: a quarter turn about z takes
    (0.1, 0, 0) to (0, 0.1, 0); a half turn about x takes (0, 0, 0.2) to (0, 0, -0.2); a fixed
    anchor ignores the bodies; no orientations: the bodies are not turned."""
    pos = np.array([[1.0, 2.0, 3.0], [-0.5, 0.0, 0.25]])
    orn = np.array([[0.0, 0.0, S45, S45], [1.0, 0.0, 0.0, 0.0]])    # x, y, z, w
    line = Connector("string", Anchor.on(0, (0.1, 0.0, 0.0)), Anchor.on(1, (0.0, 0.0, 0.2)))
    np.testing.assert_allclose(connector_points(line, pos, orn), [[1.0, 2.1, 3.0], [-0.5, 0.0, 0.05]], atol=1e-12)
    np.testing.assert_allclose(connector_points(line, pos), [[1.1, 2.0, 3.0], [-0.5, 0.0, 0.45]], atol=1e-12)
    hook = Connector("rope", Anchor.fixed((0.3, -0.2, 1.5)), Anchor.on(1))
    np.testing.assert_allclose(connector_points(hook, pos, orn), [[0.3, -0.2, 1.5], [-0.5, 0.0, 0.25]], atol=1e-12)
    # any rotation: as scipy turns the point
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = Rotation.random(random_state=rng)
        p_body = rng.normal(size=3)
        p = rng.normal(size=(2, 3))
        c = Connector("c", Anchor.fixed((0.0, 0.0, 0.0)), Anchor.on(1, p_body))
        got = connector_points(c, p, np.stack([np.array([0, 0, 0, 1.0]), q.as_quat()]))[1]
        np.testing.assert_allclose(got, p[1] + q.apply(p_body), atol=1e-12)


def test_a_helix_winds_round_the_axis_between_its_anchors_as_the_body_moves():
    """A spring from a fixed hook to a point on a body that falls, swings and turns: at every pose
    its ends are the anchors, its coil points are `radius` from the axis, the coil spans the whole
    axis (stretched or compressed to the anchors' distance) in `coils` turns."""
    spring = Connector("spring", Anchor.fixed((0.1, 0.0, 1.0)), Anchor.on(0, (0.0, 0.0, 0.05)),
                       coils=7, radius_m=0.015)
    assert spring.n_points == 7 * HELIX_POINTS_PER_COIL + 3 and spring.bodies == (0,)
    rng = np.random.default_rng(0)
    lengths = []
    for t in np.linspace(0.0, 1.0, 12):
        body = np.array([[0.3 * math.sin(4 * t), 0.1 * t, 0.9 - 0.6 * t]])
        q = Rotation.from_rotvec(rng.normal(size=3) * t)
        pts = connector_points(spring, body, q.as_quat()[None])
        b = body[0] + q.apply([0.0, 0.0, 0.05])
        assert_helix(pts, np.array([0.1, 0.0, 1.0]), b, 7, 0.015, atol=1e-12)
        lengths.append(np.linalg.norm(b - [0.1, 0.0, 1.0]))
    assert max(lengths) > 1.5 * min(lengths)      # it did stretch
    # a horizontal spring (the axis along x: the coil starts off +y), and anchors that coincide
    flat = Connector("flat", Anchor.fixed((0.0, 0.0, 0.0)), Anchor.fixed((0.4, 0.0, 0.0)), coils=3, radius_m=0.02)
    assert_helix(connector_points(flat, np.zeros((0, 3))), np.zeros(3), np.array([0.4, 0.0, 0.0]), 3, 0.02,
                 atol=1e-12)
    squashed = Connector("s", Anchor.fixed((1.0, 1.0, 1.0)), Anchor.fixed((1.0, 1.0, 1.0)), coils=2, radius_m=0.01)
    pts = connector_points(squashed, np.zeros((0, 3)))
    assert np.all(np.isfinite(pts)) and np.allclose(np.linalg.norm(pts[1:-1] - 1.0, axis=1), 0.01)


def test_a_line_is_its_two_anchors_and_a_helix_needs_turns_and_a_radius():
    line = Connector("l", Anchor.fixed((0.0, 0.0, 1.0)), Anchor.fixed((0.0, 1.0, 1.0)))
    assert line.n_points == 2 and line.bodies == ()
    with pytest.raises(ValueError, match="a helix needs coils > 0 and radius_m > 0"):
        Connector("h", line.start, line.end, coils=4)
    for coils in (-1, 2.5):
        with pytest.raises(ValueError, match="a helix needs"):
            Connector("h", line.start, line.end, coils=coils, radius_m=0.1)
    assert Drawing().connectors == ()


# -- the viewer and rerun ------------------------------------------------------------------------------------

@pytest.fixture(scope="module", autouse=True)
def drop():
    """The drop scenario, registered for this module only (the registry is restored after)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(registry, "_loaded", dict(registry._loaded))
        yield registry.register(DropScenario())


def ball_top(traj, frame: int) -> np.ndarray:
    """Where the spring meets the ball: its top, (0, 0, r) in the ball's frame, turned (scipy) and
    moved by the ball's pose in the trajectory."""
    q = Rotation.from_quat(traj.orientation_xyzw[0, frame])
    return traj.position_m[0, frame] + q.apply([0.0, 0.0, SCENE.radius_m])


def test_the_viewer_draws_the_spring_where_the_selected_motion_puts_the_ball(tmp_path):
    """The viewer's spring handle ends at the hook and at the ball's top in the selected sample's
    motion (simulated here again, independently of the viewer) at the frame shown, and follows
    the ball when the frame or the sample changes; it keeps its one handle."""
    from galileo.video import read_video, write_video
    from scenarios.drop import tracks_from
    from ui.controller import Controller
    from ui.viewer import Viewer

    scenario = DropScenario()
    tracks = tracks_from(scenario.simulate(SCENE, SCENE.n_frames, {"e": 0.6}), SCENE, noise_mps=0.05, seed=0)
    ctrl = Controller(SCENE, tracks, chains=2, seed=0, workers=1, session_dir=tmp_path / "s")
    ctrl.run_sweeps(4)
    video_path = tmp_path / "video.mp4"
    write_video(video_path, np.zeros((SCENE.n_frames, 48, 64, 3), np.uint8), SCENE.fps)
    video, _ = read_video(video_path)
    v = Viewer(ctrl, ctrl.likelihood_scene, tracks, video, port=free_port())
    try:
        (handle,) = v.connector_handles
        assert handle.name == "/connectors/spring"
        model = scenario.likelihood(ctrl.likelihood_scene, tracks, ctrl.settings.noise)
        radius = SPRING_RADIUS_PER_BALL_RADIUS * SCENE.radius_m
        shown = []
        for chain, index in ((0, 3), (1, 1)):
            v.select_sample(chain, index)
            motion = model.motion(ctrl.samples(chain)[index])
            for frame in (0, 12, 25):
                v.set_frame(frame)
                pts = polyline_of(handle)
                assert_helix(pts, HOOK_M, ball_top(motion, frame), SPRING_COILS, radius, atol=FLOAT32_M)
                shown.append(pts[-1])
            assert v.connector_handles[0] is handle
        # the ball fell between the frames shown: the spring's end went with it
        assert shown[0][2] - shown[1][2] > 0.1
    finally:
        v.close()
        ctrl.close()


def test_rerun_logs_the_spring_per_frame_beside_the_objects(tmp_path):
    """sim/<kind>/connectors/spring holds, per frame, the spring's polyline between the hook and the
    ball's top in that motion (read back from the .rrd), its colour and width static; a drawing
    without connectors logs none."""
    chunk = pytest.importorskip("rerun.chunk")
    from ui.rerun_log import RRD_NAME, RerunLogger

    scenario = DropScenario()
    selected = scenario.simulate(SCENE, SCENE.n_frames, {"e": 0.6})
    best = scenario.simulate(SCENE, SCENE.n_frames, {"e": 0.3})
    log = RerunLogger("save", session_dir=tmp_path, recording_id="test-connectors")
    log.log_scene(scenario.drawing(SCENE))
    log.log_selected(selected, 0, 2)
    log.log_map(best, 4, 1, 3)
    log.close()
    ents: dict[str, list] = {}
    for ch in chunk.RrdReader(tmp_path / RRD_NAME).stream().to_chunks():
        ents.setdefault(ch.entity_path.lstrip("/"), []).append((set(ch.timeline_names), ch.to_record_batch().to_pydict()))
    radius = SPRING_RADIUS_PER_BALL_RADIUS * SCENE.radius_m
    for kind, traj in (("selected", selected), ("map", best)):
        assert f"sim/{kind}/ball" in ents
        rows = ents[f"sim/{kind}/connectors/spring"]
        (static,) = [cols for tl, cols in rows if not tl]
        assert static["LineStrips3D:colors"] == [[0x282828FF]] and static["LineStrips3D:radii"] == [[-1.0]]
        (per_frame,) = [cols for tl, cols in rows if tl == {"frame"}]
        assert per_frame["frame"] == list(range(SCENE.n_frames))
        for frame, strips in zip(per_frame["frame"], per_frame["LineStrips3D:strips"]):
            (strip,) = strips
            assert_helix(np.array(strip, float), HOOK_M, ball_top(traj, frame), SPRING_COILS, radius,
                         atol=FLOAT32_M)
    # without connectors: nothing under connectors/
    bare = RerunLogger("save", session_dir=tmp_path / "bare", recording_id="test-no-connectors")
    bare.log_scene(Drawing())
    bare.log_selected(selected)
    bare.close()
    paths = {ch.entity_path for ch in chunk.RrdReader(tmp_path / "bare" / RRD_NAME).stream().to_chunks()}
    assert "/sim/selected/ball" in paths and not any("connectors" in p for p in paths)
