"""The Python API (issue 31): `galileo.infer` is `galileo infer` (same defaults, same file, bit for
bit), its result opens in ArviZ (posterior with chain and draw dims and units, sample stats with the
log-likelihood and acceptance, the tracks as observed data), saves and reopens as netCDF with the
same draws, and ArviZ's R-hat on it is result.json's; bad input is a one-line GalileoError."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import galileo
from galileo.errors import GalileoError

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"
RUN = dict(chains=4, sweeps=24, workers=1, seed=3)   # (a small run; the defaults are the CLI's either way)


@pytest.fixture(scope="module")
def demo_result():
    scene = galileo.load_scene(DATA / "scene.json")
    tracks = galileo.load_tracks(DATA / "tracks.json")
    return galileo.infer(scene, tracks, progress=False, **RUN)


def _cli_infer(tmp_path, *extra):
    out = tmp_path / "cli.json"
    done = subprocess.run([sys.executable, "-m", "galileo", "infer", str(DATA / "video.mp4"), "--scene",
                           str(DATA / "scene.json"), "--tracks", str(DATA / "tracks.json"), "--chains",
                           str(RUN["chains"]), "--sweeps", str(RUN["sweeps"]), "--workers", "1", "--seed",
                           str(RUN["seed"]), "--quiet", "--out", str(out), *extra],
                          capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert done.returncode == 0, done.stderr
    return out, done.stdout


def _same_but_timing(a: dict, b: dict) -> None:
    a, b = dict(a), dict(b)
    for d in (a, b):
        d.pop("timing_s"), d.pop("samples_file")
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def test_infer_is_the_cli_bit_for_bit(demo_result, tmp_path):
    """The API's result.json and sample record equal the CLI's for the same settings (all else the
    defaults), to the last bit; and what `print(result)` says is what the CLI prints."""
    cli_json, stdout = _cli_infer(tmp_path)
    api_json = tmp_path / "api.json"
    npz = demo_result.save(api_json)
    _same_but_timing(json.loads(api_json.read_text()), json.loads(cli_json.read_text()))
    with np.load(npz) as a, np.load(cli_json.with_name("cli.samples.npz")) as b:
        assert sorted(a.files) == sorted(b.files)
        for k in a.files:
            assert np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind == "f"), k
    for line in demo_result.summary().splitlines()[:-1]:   # (the last line words the verdict a little differently)
        assert line in stdout, (line, stdout)


def test_a_saved_result_reads_back_whole(demo_result, tmp_path):
    """load_result on `galileo infer --out`'s files gives the same Result (its doc, its draws)."""
    cli_json, _ = _cli_infer(tmp_path)
    back = galileo.load_result(cli_json, tracks=DATA / "tracks.json")
    _same_but_timing({**back.doc, "samples_file": None}, {**demo_result.doc, "samples_file": None})
    assert np.array_equal(back.samples, demo_result.samples)
    assert back.map == demo_result.map and back.converged == demo_result.converged


def test_to_arviz_holds_the_draws_units_stats_and_tracks(demo_result):
    import arviz_base  # noqa: F401  (the DataTree is ArviZ's layout)

    dt = demo_result.to_arviz()
    post = dt["posterior"]
    kept = demo_result.samples[:, demo_result.burn_in:]
    for j, n in enumerate(demo_result.names):
        assert post[n].dims == ("chain", "draw")
        assert np.array_equal(post[n].values, kept[..., j])
    assert post["m1_kg"].attrs["units"] == "kg" and post["k1"].attrs["units"] == "1"
    # the demo's collision identifies the ratio, not the masses: ArviZ users are told so
    assert post["m1_kg"].attrs["identified"].startswith("no: ")
    assert post["k1"].attrs["identified"] == "yes"
    ratio = kept[..., 0] / kept[..., 2]   # (m1_kg / m2_kg, computed here from the draws)
    np.testing.assert_allclose(post["mass_ratio"].values, ratio, rtol=1e-12)
    warm = dt["warmup_posterior"]
    assert warm["k1"].shape == (RUN["chains"], demo_result.burn_in)
    stats = dt["sample_stats"]
    np.testing.assert_array_equal(stats["lp"].values, demo_result.record["logliks"][:, demo_result.burn_in:])
    # acceptance per sweep, weighted by its proposals over warm-up and kept sweeps, is the record's overall share
    all_stats = [dt["warmup_sample_stats"], stats]
    n = sum(s["n_proposals"].values.sum() for s in all_stats)
    accepted = sum((s["acceptance_rate"].values * s["n_proposals"].values).sum() for s in all_stats)
    assert n == demo_result.record["proposal_accepted"].size
    assert accepted / n == pytest.approx(demo_result.record["proposal_accepted"].mean(), rel=1e-12)
    moves = list(stats["move_acceptance"].coords["move"].values)
    assert moves[:len(demo_result.names)] == list(demo_result.names) and len(moves) > len(demo_result.names)   # (and the joint moves)
    obs = dt["observed_data"]
    assert obs["position_m"].dims == ("object", "frame", "axis")
    tr = galileo.load_tracks(DATA / "tracks.json")
    np.testing.assert_array_equal(obs["visible"].values[0], tr.objects[0].visible)


def test_netcdf_round_trip_and_arviz_rhat_is_the_results(demo_result, tmp_path):
    import xarray as xr
    from arviz_stats.base import array_stats

    dt = demo_result.to_arviz()
    path = tmp_path / "demo.nc"
    dt.to_netcdf(path, engine="h5netcdf")
    back = xr.open_datatree(path, engine="h5netcdf")
    for n in demo_result.names:
        np.testing.assert_array_equal(back["posterior"][n].values, dt["posterior"][n].values)
        assert back["posterior"][n].attrs["units"] == dt["posterior"][n].attrs["units"]
        r = demo_result.diagnostics["r_hat"][n]
        if r is not None:
            mine = float(array_stats.rhat(back["posterior"][n].values, chain_axis=0, draw_axis=1))
            assert mine == pytest.approx(r, rel=1e-12)
    assert json.loads(back.attrs["r_hat"]) == demo_result.diagnostics["r_hat"]


def test_arviz_plots_draw_it_without_glue(demo_result):
    pytest.importorskip("arviz_plots")
    import matplotlib

    matplotlib.use("Agg")
    import arviz_plots as azp

    dt = demo_result.to_arviz()
    for plot in (azp.plot_trace, azp.plot_rank, lambda d: azp.plot_pair(d, var_names=["k1", "k2", "mass_ratio"]),
                 azp.plot_ess):
        pc = plot(dt)
        assert pc is not None


def test_predict_answers_as_the_cli_does(demo_result, tmp_path):
    """galileo.predict on a Result is `galileo predict` on its file."""
    path = tmp_path / "r.json"
    demo_result.save(path)
    done = subprocess.run([sys.executable, "-m", "galileo", "predict", "--result", str(path), "--angle-deg", "30", "--target-outcome"],
                          capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert done.returncode == 0, done.stderr
    with pytest.warns(UserWarning, match="not converged"):   # (24 sweeps: the CLI says so on stderr)
        assert galileo.predict(demo_result, angle_deg=30.0, target=True) == json.loads(done.stdout)
    with pytest.raises(GalileoError, match="depth_m is no question of the ramp scenario"):
        galileo.predict(demo_result, depth_m=1.0)


def test_several_videos_as_one_problem(tmp_path):
    """Two videos sharing k1: latents named per video, both tracks in observed_data."""
    scene = galileo.load_scene(DATA / "scene.json")
    tracks = galileo.load_tracks(DATA / "tracks.json")
    r = galileo.infer([scene, scene], [tracks, tracks], share=["k1"], chains=2, sweeps=6, workers=1, progress=False)
    assert "k1" in r.names and "m1_kg@1" in r.names and "m1_kg@2" in r.names
    dt = r.to_arviz()
    assert "position_m_video2" in dt["observed_data"]
    assert dt["posterior"]["m1_kg@2"].attrs["units"] == "kg"


@pytest.mark.parametrize("call, words", [
    (lambda s, t: galileo.infer(s, t, chains=0), "chains must be an integer >= 1"),
    (lambda s, t: galileo.infer(s, t, fix={"k1": float("nan")}), "fix k1: expected a finite number"),
    (lambda s, t: galileo.infer(s, t, share=["k1"]), "share is for several videos"),
    (lambda s, t: galileo.infer(s, t, sweeps=5, max_seconds=5), "max_seconds is a budget of running until converged"),
    (lambda s, t: galileo.infer(s, t, moves="fast"), "moves must be one of"),
    (lambda s, t: galileo.infer([s, s], [t]), "2 scene(s) need as many videos or tracks, got 1"),
    (lambda s, t: galileo.infer(s, t, fix={"nope": 1.0}), "nope"),
    (lambda s, t: galileo.load_scene(DATA / "missing.json"), "missing.json"),
    (lambda s, t: galileo.predict(DATA / "scene.json"), "not a galileo result file"),
])
def test_bad_input_is_one_line_galileo_error(call, words):
    scene = galileo.load_scene(DATA / "scene.json")
    tracks = galileo.load_tracks(DATA / "tracks.json")
    with pytest.raises(GalileoError) as e:
        call(scene, tracks)
    assert words in str(e.value) and "\n" not in str(e.value)


def test_import_galileo_stays_light():
    """`import galileo` loads neither torch nor pybullet (the API loads them when used)."""
    code = "import sys, galileo; print('torch' in sys.modules, 'pybullet' in sys.modules, galileo.__version__)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                         env={**os.environ, "PYTHONPATH": str(ROOT)}).stdout.split()
    assert out[:2] == ["False", "False"], out



def test_tracks_made_already_with_chains_started_by_recognition(demo_dir):
    """`tracks=` stands for `galileo infer --tracks`: the video is not tracked again, and is still
    what the recognition model reads to start the chains."""
    scene = galileo.load_scene(demo_dir / "scene.json")
    tracks = galileo.load_tracks(DATA / "tracks.json")
    r = galileo.infer(scene, demo_dir / "video.mp4", tracks=tracks, init="recognition", chains=2, sweeps=4,
                      workers=1, progress=False)
    assert r.doc["init"]["starts"] == "recognition", r.doc["init"]
    assert r.tracks is tracks
    with pytest.raises(GalileoError, match="give its file, not its tracks"):
        galileo.infer(scene, tracks, init="recognition", chains=2, sweeps=4, workers=1, progress=False)
