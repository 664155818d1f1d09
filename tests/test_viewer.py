"""The viewer's server side without a browser: plots and readouts follow the controller,
edits are marked on the traces, the camera view matches the video camera."""
import math

import numpy as np
import pytest

from conftest import demo_viewer
from ui.viewer import CONVERGED_COLOR, ESS_COLOR, RHAT_COLOR, convergence_html


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


def test_chains_panel_says_not_converged_and_the_bar_is_not_full(setup):
    """5 sweeps of 2 chains (all still in warm-up): every latent is shown not converged, in red,
    with the reason, and the progress bar neither full nor done."""
    ctrl, v = setup
    v.refresh()
    st = ctrl.status()
    assert not st["convergence"]["converged"]
    box = v.convergence_box.content
    assert "Not converged: 0 of 4 latents" in box
    for n in ctrl.names:
        assert f'data-latent="{n}" data-converged="false" style="color:{RHAT_COLOR}"' in box
    assert box.count("not converged: R-hat cannot be computed") == 4
    assert v.progress.value < 99.0 and v.progress.color is None
    assert "not converged yet (sweep target 75)" in v.status_text.content
    assert "moves: default, widths adapting (warm-up: sweeps 1-37)" in v.status_text.content


def test_convergence_html_colours_each_latent_and_shows_derived_quantities():
    from galileo.results import convergence

    rng = np.random.default_rng(0)
    names = ("a", "b", "c")
    mixed = [np.column_stack([rng.normal(size=800), rng.normal(size=800) + 3 * c,
                              np.cumsum(rng.normal(size=800)) * 0.01 + rng.normal(size=800)]) for c in range(4)]
    conv = convergence(mixed, names)
    assert conv["per_latent"] == {"a": True, "b": False, "c": False}
    derived = {"ratio": {"q05": 0.5, "q50": 1.25, "q95": 2.0}, "log_ratio": {"q05": -0.7, "q50": 0.22, "q95": 0.69},
               "volume_cm3": {"q05": 10.0, "q50": 12.0, "q95": 14.0}}
    box = convergence_html(conv, derived)
    assert "Not converged: 1 of 3 latents (R-hat &le; 1.01, ESS &ge; 400)" in box
    assert f'data-latent="a" data-converged="true" style="color:{CONVERGED_COLOR}"' in box
    assert f'data-latent="b" data-converged="false" style="color:{RHAT_COLOR}"' in box
    assert "<b>a</b> R-hat 1.00" in box and ": converged</div>" in box
    assert "b</b> R-hat" in box and "not converged: R-hat" in box
    # R-hat holds but the ESS does not: orange
    ess_only = {**conv, "per_latent": {"c": False}, "r_hat": {"c": 1.004}, "ess_bulk": {"c": 161.4},
                "ess_tail": {"c": 2175.0}, "why_not": ["c: ESS 161 < 400"]}
    line = convergence_html(ess_only, {})
    assert (f'data-latent="c" data-converged="false" style="color:{ESS_COLOR}"><b>c</b> R-hat 1.004, ESS 161: '
            "not converged: ESS 161 &lt; 400</div>") in line
    assert "<b>ratio</b>: median 1.25 (90% 0.5 &ndash; 2)" in box and "log_ratio" not in box
    assert "<b>volume_cm3</b>: median 12" in box
    good = convergence([m[:, :1] for m in mixed], names[:1])
    assert "Converged: all 1 latents" in convergence_html(good, {}) and "Posterior" not in convergence_html(good, {})


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
    and objects o of log N(v_obs[o, f, (x, z)] | v_drawn[o, f, (x, z)], sigma^2 I) (or, with
    the scene's Student-t observation model, scipy's log t density of each component with
    scale sigma), the observed velocities and visibility from the tracks (matched to the
    drawn objects by role)."""
    from scipy import stats

    roles = [o.role for o in v.scene.objects]
    assert v.traj.names == [o.name for o in v.scene.objects]
    d = []
    for i, role in enumerate(roles):
        obs = v.tracks.by_role(role)
        seen = obs.visible
        d.append((obs.velocity_mps[seen][:, [0, 2]] - v.traj.velocity_mps[i, seen][:, [0, 2]]).ravel())
    d = np.concatenate(d)
    assert d.size > 0
    priors = v.scene.priors
    if priors.observation == "student_t":
        return float(stats.t.logpdf(d, priors.student_t_dof, scale=sigma).sum())
    return -0.5 * float((d ** 2).sum()) / sigma ** 2 - d.size * math.log(sigma * math.sqrt(2 * math.pi))


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


def test_a_taken_port_is_refused_not_silently_replaced(setup, capsys):
    """Issue 14, defect 10: viser moves to the next free port without a word; the viewer and
    app.py refuse instead (one line, exit 2)."""
    import socket

    from galileo.errors import GalileoError
    from ui.viewer import Viewer

    ctrl, v = setup
    taken = int(v.url.rsplit(":", 1)[1])
    with pytest.raises(GalileoError, match=f"port {taken} on 127.0.0.1 is taken"):
        Viewer(ctrl, ctrl.likelihood_scene, v.tracks, v.video, port=taken)
    import app

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        busy = s.getsockname()[1]
        assert app.main(["--port", str(busy)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("app: error: port") and "is taken" in err[-1]
