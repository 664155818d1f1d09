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
    assert v.trace_plot.title.endswith(f"; edits at sweep {edit}")
    assert "chains" in v.status_text.content and "R-hat" in v.status_text.content


def test_chains_panel_says_not_converged_and_the_bar_is_not_full(setup):
    """5 sweeps of 2 chains (all still in warm-up, sweeps 1-37): the verdict says so ("warming
    up", issue 24: not "Not converged: 0 of 4 latents", nor "the latent never moved"), every
    latent in orange, and the progress bar neither full nor done."""
    ctrl, v = setup
    v.refresh()
    st = ctrl.status()
    assert not st["convergence"]["converged"]
    box = v.convergence_box.content
    longest = max(c["sweeps"] for c in st["chains"].values())
    assert f"Warming up (sweep {longest} of 37): no verdict before the kept draws" in box
    for n in ctrl.names:
        assert f'data-latent="{n}" data-converged="false" style="color:{ESS_COLOR}"' in box
    assert box.count(": warming up</div>") == len(ctrl.names) and "never moved" not in box
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
               "volume_cm3": {"q05": 12.0, "q50": 12.0, "q95": 12.0, "fixed": True}}
    box = convergence_html(conv, derived)
    assert "Not converged: 1 of 3 latents converged so far (R-hat &le; 1.01, ESS &ge; 400)" in box
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
    # a quantity the scene fixes (the splash's volume) is not shown as a posterior (issue 24)
    assert "<b>volume_cm3</b>: 12 (fixed by the scene, not inferred)" in box and "volume_cm3</b>: median" not in box
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


# -- issue 14: the viewer's defects, server side (tests/test_viewer_browser.py drives a browser) --

def test_log_likelihood_traces_are_below_the_best_on_an_asinh_scale(setup):
    """Defect 1: the traces are each chain's log-likelihood less the best so far (every value
    <= 0, the best exactly 0), on uPlot's asinh scale, and the axis is wide enough for the
    lowest value's label with its minus sign."""
    from ui.viewer import TRACE_ASINH_NATS, Y_AXIS_CHAR_PX, Y_AXIS_PAD_PX

    ctrl, v = setup
    v.refresh()
    ids = ctrl.chain_ids()
    ys = [np.asarray(d) for d in v.trace_plot.data[1:1 + len(ids)]]
    best = max(float(np.max(ctrl.logliks(c))) for c in ids)
    for c, y in zip(ids, ys):
        ll = np.asarray(ctrl.logliks(c))
        np.testing.assert_array_equal(y[:len(ll)], ll - best)
    assert max(float(y.max()) for y in ys) == 0.0
    # both scales' ranges are the server's (issue 24: left to the page, x drifted to [0, 1] and
    # the asinh y range cut the traces at -10): every sweep, every value and 0 inside
    lowest = min(float(y.min()) for y in ys)
    n = len(v.trace_plot.data[0])
    y = v.trace_plot.scales["y"]
    assert (y["distr"], y["asinh"]) == (4, TRACE_ASINH_NATS)
    assert y["range"][0] < lowest and y["range"][1] > 0
    assert v.trace_plot.scales["x"]["range"] == (1.0, float(max(n, 2)))
    # ticks at 0, -10, -100, ... down to the lowest trace, and the axis wide enough for their labels
    splits = v.trace_plot.axes[1]["splits"]
    assert splits[0] == 0 and all(b == 10 * a for a, b in zip(splits[1:], splits[2:])) and splits[-1] >= y["range"][0]
    widest = max(len(t) for t in v.trace_plot.axes[1]["values"])
    assert v.trace_plot.axes[1]["size"] == Y_AXIS_CHAR_PX * widest + Y_AXIS_PAD_PX


def test_settings_apply_exactly_what_was_typed_or_nothing(setup):
    """Defect 2: a field's text is read as typed; a wrong one (with the reason and the bound) is
    refused and nothing at all is applied, a right one applied exactly; the fields then show
    the values in force."""
    ctrl, v = setup
    before = (dict(ctrl.settings.bounds), ctrl.settings.noise, ctrl.settings.narrow, ctrl.settings.broad,
              ctrl.settings.broad_every)
    wrong = [(v.sigma_input, "1e308", "sigma_mps must be <= 10 m/s"),
             (v.sigma_input, "-1", "sigma_mps must be > 0.0001 m/s"),
             (v.sigma_input, "nan", "sigma_mps: expected a finite number"),
             (v.every_input, "2.5", "broad_every must be an integer >= 0"),
             (v.narrow_input, "-0.5", "proposal widths must be > 0"),
             (v.bound_inputs["m1_kg"], "abc", "m1_kg bounds (low, high): expected 2 numbers"),
             (v.bound_inputs["m1_kg"], "0.001, 1e20", "m1_kg: bounds must be <= 100 kg")]
    for field, text, reason in wrong:
        old = field.value
        field.value = text
        msg = v.apply_settings()
        assert msg.startswith("Not applied: ") and reason in msg, (text, msg)
        assert 'data-ok="false"' in v.settings_message.content
        field.value = old
    # a valid edit beside a wrong one: neither applied
    v.bound_inputs["m1_kg"].value = "0.002, 0.9"
    v.bound_inputs["k1"].value = "0.5, 0.1"
    msg = v.apply_settings()
    assert "k1: the low bound (0.5) must be below the high bound (0.1)" in msg
    assert (dict(ctrl.settings.bounds), ctrl.settings.noise, ctrl.settings.narrow, ctrl.settings.broad,
            ctrl.settings.broad_every) == before
    v.bound_inputs["k1"].value = "0, 0.95"
    v.sigma_input.value = "5e-2"
    msg = v.apply_settings()
    assert msg.startswith("Applied: ") and 'data-ok="true"' in v.settings_message.content
    assert ctrl.settings.bounds["m1_kg"] == (0.002, 0.9) and ctrl.settings.bounds["k1"] == (0.0, 0.95)
    assert ctrl.settings.noise == 0.05
    assert v.bound_inputs["m1_kg"].value == "0.002, 0.9" and v.sigma_input.value == "0.05"
    assert "m1_kg [0.002, 0.9] kg" in v.settings_in_force.content
    for n, (lo, hi) in before[0].items():     # put the priors back for the other tests
        v.bound_inputs[n].value = f"{lo!r}, {hi!r}"
    v.apply_settings()
    assert dict(ctrl.settings.bounds) == before[0]


def test_remove_chain_asks_and_keeps_the_selection_on_a_remaining_chain(demo_dir, tmp_path):
    """Defect 3: Remove asks first (Confirm / Cancel); after removing the last chain the selection
    moves to its neighbour, never to chain 0, and a second click does not remove another chain."""
    ctrl, v = demo_viewer(demo_dir, tmp_path / "s", chains=4, seed=2, sweeps=2)
    try:
        v.follow_map.value = False
        v.chain_dropdown.value = "3"
        v._ask_remove()
        assert v.remove_confirm.visible and v.remove_confirm.label == "Confirm: remove chain 3"
        assert v._cancel_remove() == "nothing removed" and ctrl.chain_ids() == [0, 1, 2, 3]
        v._ask_remove()
        v.chain_dropdown.value = "1"     # the user looks at another chain before confirming
        assert v._confirm_remove() == "removed chain 3 (its samples stay)"
        assert ctrl.chain_ids() == [0, 1, 2] and v.chain_dropdown.value == "1"
        v.chain_dropdown.value = "2"
        v._ask_remove()
        v._confirm_remove()
        assert ctrl.chain_ids() == [0, 1] and v.chain_dropdown.value == "1"
        v.refresh()
        assert v.chain_dropdown.value == "1" and tuple(v.chain_dropdown.options) == ("0", "1")
        assert v._confirm_remove() == "nothing removed" and ctrl.chain_ids() == [0, 1]
    finally:
        v.close()
        ctrl.close()


def test_steering_errors_are_shown_in_the_panel(setup):
    """Defect 4: setting a latent outside its prior is refused with the reason in the Steering
    panel (and nothing changes), not a server-side traceback."""
    ctrl, v = setup
    chain = v._chain()
    before = ctrl.position(chain)
    v.set_inputs["m1_kg"].value = "5"
    v.set_button.value = True      # a click, from code
    assert "Not done: m1_kg=5 is outside its prior bounds" in v.steer_message.content
    assert 'data-ok="false"' in v.steer_message.content and ctrl.position(chain) == before
    v.set_inputs["m1_kg"].value = "1e-3x"
    v.set_button.value = True
    assert "m1_kg: expected a number, got &#x27;1e-3x&#x27;" in v.steer_message.content


def test_a_reopened_session_shows_its_chains(demo_dir, tmp_path):
    """Defect 5: a session reopened (its chains paused) shows its status, traces, histograms and
    progress at once, and the chain dropdown agrees with the sample shown (the MAP's)."""
    from galileo.video import read_video
    from conftest import free_port, load_demo_frozen
    from ui.controller import Controller
    from ui.viewer import Viewer

    scene, tracks, _ = load_demo_frozen()
    ctrl = Controller(scene, tracks, chains=2, seed=3, workers=1, session_dir=tmp_path / "s", sweeps=4)
    ctrl.run_sweeps(4)
    ctrl.close()
    again = Controller.load(tmp_path / "s", workers=1, sweeps=4)
    video, _ = read_video(demo_dir / "video.mp4")
    v = Viewer(again, again.likelihood_scene, tracks, video, port=free_port())
    try:
        v.refresh()
        chain, index, _, _ = again.map()
        assert v.chain_dropdown.value == str(chain) and v.sample_text.content.startswith(
            f"chain {chain}, sample {index}:")
        assert "0 running / 2 chains, 8 sweeps" in v.status_text.content   # 2 x 4
        assert "MAP (chain" in v.status_text.content
        assert len(v.trace_plot.data[0]) == 4 and v.progress.value > 0
        assert all(np.asarray(p.data[1]).sum() > 0 for p in v.hist_plots.values())
    finally:
        v.close()
        again.close()


def test_letterbox_puts_every_pixel_where_the_pinhole_view_of_the_window_does(setup):
    """Defect 6: in a window of any shape, the padded frame stretched over the window and a
    pinhole camera with the returned vertical fov and the window's aspect map every world point
    to the same place: the video camera's projection, letterboxed."""
    import trimesh

    from ui.viewer import camera_pose, letterbox

    _, v = setup
    cam = v.scene.camera
    frame = v.video[0]
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-0.8, 0.3, 50), rng.uniform(-0.2, 0.2, 50), rng.uniform(0, 0.3, 50)])
    uv = cam.project(pts)
    wxyz, pos, _, _ = camera_pose(cam)
    r = trimesh.transformations.quaternion_matrix(wxyz)[:3, :3]
    for w, h in ((1600, 1000), (1024, 768), (800, 1000), (640, 480)):
        img, fov = letterbox(frame, cam, w / h)
        H, W = img.shape[:2]
        assert abs(W / H - w / h) < 2.0 / min(W, H)      # the window's shape, to a pixel
        # the pinhole view of the window (viser's camera: vertical fov, OpenCV axes)
        pc = (pts - pos) @ r
        f = (h / 2) / np.tan(fov / 2)
        screen = np.column_stack([f * pc[:, 0] / pc[:, 2] + w / 2, f * pc[:, 1] / pc[:, 2] + h / 2])
        # the video's pixel, through the padding (principal point at the centre) and the stretch
        s = W / w
        scale = H / (2 * np.tan(fov / 2) * cam.K[1, 1])     # canvas pixels per video pixel
        canvas = np.column_stack([W / 2 + scale * (uv[:, 0] - cam.K[0, 2]), H / 2 + scale * (uv[:, 1] - cam.K[1, 2])])
        np.testing.assert_allclose(canvas / [W, H] * [w, h], screen, atol=0.05 * max(1.0, s))
        # and the frame's own pixels are there: its centre pixel's colour at that place
        c = (int(round(W / 2 + scale * (frame.shape[1] / 2 - cam.K[0, 2]))),
             int(round(H / 2 + scale * (frame.shape[0] / 2 - cam.K[1, 2]))))
        assert np.abs(img[c[1], c[0]].astype(int) - frame[frame.shape[0] // 2, frame.shape[1] // 2]).max() <= 12
    img, fov = letterbox(frame, cam, 1600 / 1000)      # wider than 4:3: black bars left and right
    assert img[:, :5].max() == 0 and img[:, -5:].max() == 0
    assert fov == pytest.approx(camera_pose(cam)[2], rel=1e-9)      # the video's own vertical fov


def test_the_first_view_frames_the_scene(setup):
    """Defect 7: a new browser's first view shows the whole ramp large (at least 40% of a
    1600 x 1000 window's width), and the first sample shown is the MAP."""
    from conftest import view_basis

    ctrl, v = setup
    ic = v.server.initial_camera
    pos, fwd, right, down = view_basis(ic)
    ramp = np.concatenate([m.vertices for m in v.scenario.drawing(v.scene).static])
    pc = np.column_stack([(ramp - pos) @ right, (ramp - pos) @ down, (ramp - pos) @ fwd])
    assert (pc[:, 2] > 0).all()
    f = (1000 / 2) / np.tan(ic.fov / 2)
    u, w = f * pc[:, 0] / pc[:, 2] + 800, f * pc[:, 1] / pc[:, 2] + 500
    assert u.min() >= 0 and u.max() <= 1600 and w.min() >= 0 and w.max() <= 1000   # all of it in view
    assert u.max() - u.min() >= 0.4 * 1600
    v.follow_map.value = True
    v.refresh()
    chain, index, _, _ = ctrl.map()
    assert (v.selection.chain, v.selection.index) == (chain, index)


def test_progress_is_never_full_while_chains_run_and_edits_are_marked_where_they_took_effect(demo_dir, tmp_path):
    """Defect 8: Resume past the sweep target runs one more block (--sweeps) towards a new
    target, so the bar shows progress towards it; an edit made while a late-added chain runs
    alone is marked at the chains' sweep, not at the session's round count."""
    from galileo.video import read_video
    from conftest import free_port, load_demo_frozen
    from ui.controller import Controller
    from ui.viewer import Viewer, edit_sweep

    scene, tracks, _ = load_demo_frozen()
    ctrl = Controller(scene, tracks, chains=2, seed=4, workers=1, session_dir=tmp_path / "s", sweeps=3)
    v = Viewer(ctrl, ctrl.likelihood_scene, tracks, read_video(demo_dir / "video.mp4")[0], port=free_port())
    try:
        v.follow_map.value = False
        ctrl.run_sweeps(3)
        assert ctrl.target_sweeps == 3 and all(not c["running"] for c in ctrl.status()["chains"].values())
        ctrl.resume()
        assert ctrl.target_sweeps == 6 and ctrl.events[-1]["detail"]["target"] == 6
        ctrl.run_sweeps(1)
        v.refresh()
        assert 0 < v.progress.value < 100       # 4 of 6 sweeps
        assert v.progress.value == pytest.approx(100 * 4 / 6, abs=0.5)
        ctrl.run_sweeps(2)
        ctrl.add_chains(1)        # a new chain runs its sweeps alone: the rounds outrun the sweeps
        ctrl.run_sweeps(3)
        ctrl.set_sigma(0.07)
        ev = ctrl.events[-1]
        assert ev["sweep"] == 9 and edit_sweep(ev) == 6
        v.refresh()
        assert v.trace_plot.title.endswith("; edits at sweep 6")
    finally:
        v.close()
        ctrl.close()


def test_one_chain_resumed_the_others_held_is_explained_and_set_follows_the_chain(demo_dir, tmp_path):
    """Issue 24, item 8: after Resume chain on one chain (it ran a new block and was held) the
    panel says why nothing runs ("paused; 1 of 2 chains below the sweep target 6"), not a bare
    "0 running / 2 chains ... sweep target 6"; "Set chain's latents" shows the selected chain's
    position (not chain 0's start with 16 digits), and a dimensionless latent's field has no
    "(1)"."""
    ctrl, v = demo_viewer(demo_dir, tmp_path / "s", chains=2, seed=4, sweeps=0, target=3)
    try:
        v.follow_map.value = False
        ctrl.run_sweeps(3)
        ctrl.resume(1)
        ctrl.run_sweeps(3)             # chain 1 alone, to the new target 6, then held
        st = ctrl.status()
        assert st["target_sweeps"] == 6 and [c["sweeps"] for c in st["chains"].values()] == [3, 6]
        v.refresh()
        assert "0 running / 2 chains" in v.status_text.content
        assert ("paused; 1 of 2 chains below the sweep target 6: Resume all (or Resume chain) runs them on to it"
                in v.status_text.content)
        v.chain_dropdown.value = "1"
        pos = ctrl.position(1)
        assert {n: float(h.value) for n, h in v.set_inputs.items()} == pytest.approx(pos, rel=1e-5)
        assert all(len(h.value) <= 12 for h in v.set_inputs.values())
        assert v.set_inputs["k1"].label == "k1" and v.set_inputs["m1_kg"].label == "m1_kg (kg)"
    finally:
        v.close()
        ctrl.close()


def test_histograms_bin_where_the_draws_are_inside_the_prior():
    """Issue 24, item 8: 30 bins over the whole prior made a narrow posterior one spike (k1's
    on [0, 1]); the bins now span the kept draws inside the prior, a tenth wider each side; the
    axes name the latent and its unit (none for a dimensionless one); draws a prior edit left
    outside are not counted, and without any the bins span the prior."""
    from galileo.latents import Latent
    from ui.viewer import HIST_BINS, histogram_spec

    k1 = Latent("k1", "1", (0.0, 1.0), "friction")
    rng = np.random.default_rng(0)
    kept = rng.normal(0.2185, 0.0004, 4000)
    spec = histogram_spec(kept, np.array([0.1, 0.5, 0.9]), (0.0, 1.0), k1)
    x, counts = spec["data"][0], spec["data"][1]
    span = kept.max() - kept.min()
    lo, hi = spec["scales"]["x"]["range"]
    assert lo == pytest.approx(kept.min() - 0.1 * span) and hi == pytest.approx(kept.max() + 0.1 * span)
    assert len(x) == HIST_BINS and counts.sum() == len(kept) and (counts > 0).sum() >= HIST_BINS // 2
    assert spec["axes"][0]["label"] == "k1" and spec["axes"][1]["label"] == "draws"
    mass = Latent("m1_kg", "kg", (0.001, 1.0), "mass")
    assert histogram_spec(kept, kept[:3], (0.001, 1.0), mass)["axes"][0]["label"] == "m1_kg (kg)"
    # after k1's prior became [0.3, 0.6]: none of these draws count, and the bins span the prior
    moved = histogram_spec(kept, np.array([0.3]), (0.3, 0.6), k1)
    assert moved["scales"]["x"]["range"] == (0.3, 0.6) and np.asarray(moved["data"][1]).sum() == 0
    assert "no kept draws in the prior yet" in moved["title"]
