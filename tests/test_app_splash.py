"""The app runs the splash demo (`python app.py --scenario splash`), server side: the demo is
rendered where the app caches it, tracked, run by the controller and drawn by the viewer with
the object where the likelihood's motion puts it, and GUI inputs for the splash latents and
its noise, sigma_px; the command line picks the demo and its chains."""
import numpy as np
import pytest

import app
from conftest import free_port


@pytest.fixture(scope="module")
def splash_viewer(tmp_path_factory):
    from galileo import registry
    from galileo.video import read_video
    from ui.controller import Controller
    from ui.viewer import Viewer

    demo = app.DEMOS["splash"]
    with pytest.MonkeyPatch.context() as mp:   # render into a temporary cache, as the app would
        mp.setitem(app.DEMOS, "splash", app.Demo(demo.scenario, tmp_path_factory.mktemp("cache"), demo.name))
        folder = app.ensure_demo(progress=False, scenario="splash")
    scene = registry.load_scene(folder / "scene.json")
    assert registry.of(scene).name == "splash"
    tracks = registry.of(scene).track(folder / "video.mp4", scene, progress=False)
    ctrl = Controller(scene, tracks, chains=2, seed=0, workers=1, session_dir=tmp_path_factory.mktemp("session"))
    ctrl.run_sweeps(2)
    video, _ = read_video(folder / "video.mp4")
    v = Viewer(ctrl, ctrl.likelihood_scene, tracks, video, port=free_port())
    yield ctrl, v
    v.close()
    ctrl.close()


def test_the_object_stands_where_the_scored_motion_puts_it(splash_viewer):
    ctrl, v = splash_viewer
    chain = ctrl.chain_ids()[1]
    frame = v.n_frames // 2            # the object in the water
    v.set_frame(frame)
    v.select_sample(chain, 1)
    assert (v.selection.chain, v.selection.index) == (chain, 1)
    motion = v.model.motion(ctrl.samples(chain)[1])
    assert v.traj.names == motion.names and len(v.object_handles) == 1
    np.testing.assert_array_equal(np.asarray(v.object_handles[0].position, float), motion.position_m[0, frame])
    tank = ctrl.likelihood_scene.tank
    assert 0 < motion.position_m[0, frame, 2] < tank.size_m[2]      # inside the tank, drawn there
    assert {"water", "tank/floor"} <= {m.name for m in v.scenario.drawing(v.scene).static}
    # the readouts and plots hold numbers (uPlot draws nothing for a NaN)
    v.refresh()
    assert "nan" not in v.sample_text.content and "start_step = " in v.sample_text.content
    for plot in (v.trace_plot, *v.hist_plots.values()):
        assert all(np.all(np.isfinite(np.asarray(d, float))) for d in plot.data)


def test_gui_has_inputs_for_each_splash_latent_and_sigma_px(splash_viewer):
    ctrl, v = splash_viewer
    names = ("area_cm2", "density_g_cm3", "drag_water", "start_step")
    assert ctrl.names == names
    st = ctrl.settings
    for n in names:
        assert tuple(v.bound_inputs[n].value) == pytest.approx(st.bounds[n])
        lo, hi = st.bounds[n]
        assert lo <= v.set_inputs[n].value <= hi      # "set chain's latents" starts inside the prior
    assert set(v.hist_plots) == set(names)
    # the splash's proposal widths differ per latent: one (narrow, broad) pair each
    assert isinstance(st.narrow, tuple) and v.narrow_input is None
    for j, n in enumerate(names):
        assert tuple(v.width_inputs[n].value) == pytest.approx((st.narrow[j], st.broad[j]))
    assert v.sigma_input.label == "sigma_px (px)" and v.sigma_input.value == st.noise == 1.0


def test_command_line_picks_the_demo_and_its_chains():
    args = app.parse_args(["--scenario", "splash"])
    assert args.scenario == "splash" and args.chains == 50 and args.sweeps == 75
    assert app.DEMOS["splash"].name == "splash-demo" and app.DEMOS["splash"].cache.name == "demo-splash"
    args = app.parse_args([])
    assert args.scenario == "ramp" and args.chains == 16 and args.sweeps == 75
    assert app.DEMOS["ramp"].cache == app.DEMO_DIR and app.DEMOS["ramp"].name == "demo"
    assert app.parse_args(["--scenario", "splash", "--chains", "3"]).chains == 3
    with pytest.raises(SystemExit) as e:
        app.parse_args(["--scenario", "bowling"])
    assert e.value.code == 2
