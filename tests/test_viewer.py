"""The viewer's server side without a browser: plots and readouts follow the controller,
edits are marked on the traces, the camera view matches the video camera."""
import numpy as np
import pytest

from conftest import demo_viewer


@pytest.fixture(scope="module")
def setup(demo_dir, tmp_path_factory):
    ctrl, v = demo_viewer(demo_dir, tmp_path_factory.mktemp("s"), chains=2, seed=1, sweeps=3)
    yield ctrl, v
    v.close()
    ctrl.close()


def test_edits_are_marked_on_the_traces(setup):
    ctrl, v = setup
    ctrl.set_sigma(0.06)
    ctrl.run_sweeps(2)
    v.refresh()
    data = v.trace_plot.data
    assert len(data) == 1 + len(ctrl.chain_ids()) + 1       # sweeps, one trace per chain, edit markers
    marks = np.asarray(data[-1])
    edit = [e for e in ctrl.events if e["kind"] == "sigma"][0]["sweep"]
    # a spike at the edit's sweep, the floor elsewhere; no NaN anywhere (uPlot draws nothing then)
    others = np.delete(marks, edit - 1)
    assert np.all(np.isfinite(np.concatenate([np.asarray(d) for d in data])))
    assert marks[edit - 1] > others.max() and np.all(others == others[0])
    assert "edits at sweeps" in v.trace_plot.title
    assert "chains" in v.status_text.content and "R-hat" in v.status_text.content


def test_jump_to_map_selects_the_map_sample(setup):
    ctrl, v = setup
    v.jump_to_map()
    chain, index, values, _ = ctrl.map()
    assert (v.selection.chain, v.selection.index) == (chain, index)
    # the objects stand where the MAP sample's simulation puts them at the current frame
    from galileo.scenarios.ramp.physics import Simulator

    traj = Simulator(v.scene).run(v.n_frames, values, fps=v.fps)
    np.testing.assert_allclose(v.object_handles[0].position, traj.position_m[0, v.frame], atol=1e-9)


def test_camera_pose_reprojects_like_the_video_camera(setup):
    """The viser camera pose derived from the scene camera maps a world point to the same pixel."""
    import trimesh

    from ui.viewer import camera_pose

    _, v = setup
    cam = v.scene.camera
    wxyz, pos, fov, aspect = camera_pose(cam)
    r = trimesh.transformations.quaternion_matrix(wxyz)[:3, :3]   # camera -> world (OpenCV axes)
    p_world = np.array([-0.3, 0.02, 0.1])
    p_cam = r.T @ (p_world - pos)
    f = (cam.height_px / 2) / np.tan(fov / 2)
    uv = np.array([f * p_cam[0] / p_cam[2] + cam.width_px / 2, f * p_cam[1] / p_cam[2] + cam.height_px / 2])
    np.testing.assert_allclose(uv, cam.project(p_world), atol=1e-6)
    assert aspect == pytest.approx(4 / 3)
