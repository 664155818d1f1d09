"""The viewer's server side without a browser: plots and readouts follow the controller,
edits are marked on the traces, the camera view matches the video camera."""
import math

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


def sigma_of(ctrl, chain: int, index: int) -> float:
    """The noise sample `index` of `chain` was scored under: the initial one, then each
    sigma event's from the chain's sweep it happened at (sample i is sweep i + 1)."""
    sig = [e for e in ctrl.events if e["kind"] == "sigma"]
    sigma = sig[0]["detail"]["old"] if sig else ctrl.settings.noise
    for e in sig:
        if index >= e["chain_sweeps"][str(chain)]:
            sigma = e["detail"]["sigma_mps"]
    return sigma


def loglik_of_drawn_motion(v, sigma: float) -> float:
    """Galileo eq. 1 recomputed here from what the viewer drew: the sum over visible frames f
    and objects o of log N(v_obs[o, f, (x, z)] | v_drawn[o, f, (x, z)], sigma^2 I), the
    observed velocities and visibility from the tracks (matched to the drawn objects by
    role), with the normaliser -n log(sigma sqrt(2 pi)) for n terms."""
    roles = [o.role for o in v.scene.objects]
    assert v.traj.names == [o.name for o in v.scene.objects]
    sq, n = 0.0, 0
    for i, role in enumerate(roles):
        obs = v.tracks.by_role(role)
        seen = obs.visible
        d = obs.velocity_mps[seen][:, [0, 2]] - v.traj.velocity_mps[i, seen][:, [0, 2]]
        sq += float((d ** 2).sum())
        n += d.size
    assert n > 0
    return -0.5 * sq / sigma ** 2 - n * math.log(sigma * math.sqrt(2 * math.pi))


def assert_draws_the_scored_motion(ctrl, v):
    """The selected sample's drawn motion scores, under the likelihood's formula computed
    independently, the log-likelihood the chain recorded for it; the objects stand where
    that motion puts them in the current frame."""
    chain, index = v.selection.chain, v.selection.index
    recorded = ctrl.logliks(chain)[index]
    # 1e-9 relative: the same terms summed in another order (the likelihood adds per frame in
    # Python floats, here numpy sums per object); rounding is ~1e-16 per term over ~240 terms
    assert loglik_of_drawn_motion(v, sigma_of(ctrl, chain, index)) == pytest.approx(recorded, rel=1e-9, abs=0)
    for i, h in enumerate(v.object_handles):
        assert np.array_equal(np.asarray(h.position, float), v.traj.position_m[i, v.frame])


def test_jump_to_map_draws_the_motion_the_map_sample_scored(setup):
    ctrl, v = setup
    v.set_frame(v.n_frames - 1)   # where the objects end up: after the collision
    v.jump_to_map()
    chain, index, values, ll = ctrl.map()
    assert (v.selection.chain, v.selection.index) == (chain, index)
    assert ctrl.logliks(chain)[index] == ll
    assert_draws_the_scored_motion(ctrl, v)
    # and other samples: each chain's first and last, under either sigma (the first test
    # changed it after sweep 3)
    for c in ctrl.chain_ids():
        for i in (0, len(ctrl.samples(c)) - 1):
            v.select_sample(c, i)
            assert (v.selection.chain, v.selection.index) == (c, i)
            assert_draws_the_scored_motion(ctrl, v)
    v.set_frame(v.n_frames // 2)
    assert_draws_the_scored_motion(ctrl, v)


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
