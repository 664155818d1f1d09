"""The examples (issue 31): notebooks kept as plain .py files in jupytext's percent format, run here
as scripts on small inputs (GALILEO_EXAMPLES_SMALL=1) so that they cannot rot. Each runs in a
subprocess from an empty folder, writes only into GALILEO_EXAMPLES_OUT, and leaves the files it
promises: the posterior as netCDF that reopens with the run's draws, the ArviZ plots, the scene
file from four clicks and its predictions, the splash report, the multi-video results.

The examples share one output folder here, so the ramp demo is rendered once (by whichever runs
first; each renders what it lacks)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
SCRIPTS = sorted(p.name for p in EXAMPLES.glob("[0-9][0-9]_*.py"))
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def out(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("examples-out")


def run_example(name: str, out: Path, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "GALILEO_EXAMPLES_SMALL": "1", "GALILEO_EXAMPLES_OUT": str(out), "MPLBACKEND": "Agg",
           "PYTHONPATH": os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}
    env.pop("GALILEO_EXAMPLES_DEMO", None)
    done = subprocess.run([sys.executable, str(EXAMPLES / name)], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, f"{name} exited {done.returncode}:\n{done.stdout[-3000:]}\n{done.stderr[-5000:]}"
    # everything went to GALILEO_EXAMPLES_OUT: nothing in the folder it ran from (nor in the repository's)
    assert not list(cwd.iterdir()), sorted(p.name for p in cwd.iterdir())
    return done


def png(path: Path) -> None:
    assert path.is_file() and path.stat().st_size > 1000, path
    assert path.read_bytes()[:8] == PNG_MAGIC, path


def test_the_four_examples_are_there():
    assert SCRIPTS == ["01_demo_to_posterior.py", "02_your_own_ramp_video.py", "03_splash_dataset_report.py",
                       "04_several_videos_one_problem.py"]


@pytest.mark.parametrize("name", SCRIPTS)
def test_example_is_a_jupytext_percent_notebook(name):
    """jupytext reads each as a percent-format notebook: a markdown title first, prose and code
    cells, and writing it back keeps every cell."""
    jupytext = pytest.importorskip("jupytext")
    nb = jupytext.read(EXAMPLES / name)
    assert nb.metadata["jupytext"]["text_representation"]["format_name"] == "percent"
    kinds = [c.cell_type for c in nb.cells]
    assert kinds[0] == "markdown" and nb.cells[0].source.startswith("# "), nb.cells[0].source[:80]
    assert kinds.count("markdown") >= 4 and kinds.count("code") >= 4, kinds
    back = jupytext.reads(jupytext.writes(nb, fmt="py:percent"), fmt="py:percent")
    assert [(c.cell_type, c.source) for c in back.cells] == [(c.cell_type, c.source) for c in nb.cells]


def test_01_demo_to_posterior(out, tmp_path):
    import xarray as xr

    import galileo

    done = run_example("01_demo_to_posterior.py", out, tmp_path)
    here = out / "01_demo_to_posterior"
    assert "not identified: m1_kg" in done.stdout and "converged: False" in done.stdout
    result = galileo.load_result(here / "result.json")
    chains, sweeps = result.doc["config"]["chains"], result.doc["config"]["sweeps"]
    assert (chains, sweeps) == (4, 12)
    back = xr.open_datatree(here / "posterior.nc")
    post = back["posterior"]
    assert dict(post.sizes) == {"chain": chains, "draw": sweeps - result.burn_in}
    for name, draws in result.draws().items():
        np.testing.assert_array_equal(post[name].values, draws)
    assert post["m1_kg"].attrs["units"] == "kg" and "mass_ratio" in post
    assert {"sample_stats", "observed_data", "warmup_posterior"} <= set(back.children)
    for plot in ("trace.png", "rank.png", "pair_masses.png", "ess.png"):
        png(here / plot)
    summary = (here / "summary.csv").read_text()
    assert "r_hat" in summary.splitlines()[0] and "mass_ratio" in summary
    assert galileo.load_tracks(here / "tracks.json").n_frames == back["observed_data"].sizes["frame"]


def test_02_your_own_ramp_video(out, tmp_path):
    import galileo

    done = run_example("02_your_own_ramp_video.py", out, tmp_path)
    here = out / "02_your_own_ramp_video"
    assert "reprojection error" in done.stdout
    scene = galileo.load_scene(here / "scene.json")
    assert scene.scenario == "ramp" and scene.target is not None and scene.ramp.angle_deg == 20
    truth = galileo.load_scene(out / "datasets" / "ramp-demo-seed0" / "demo" / "scene.json")
    assert abs(scene.start_distance_m() - truth.start_distance_m()) < 0.01     # found in the first frame
    assert np.linalg.norm(scene.camera.position_in_world - truth.camera.position_in_world) < 0.1
    for image in ("first_frame.png", "overlay.png"):
        png(here / image)
    result = galileo.load_result(here / "result.json")
    assert result.names == ("m1_kg", "k1", "m2_kg", "k2", "e_collision")   # (the restitution: a latent by default)
    answers = json.loads((here / "predictions.json").read_text())
    assert answers["will_it_move"]["angle_deg"] == 10.0 and "target_final_x_m" in answers["target"]


def test_03_splash_dataset_report(out, tmp_path):
    done = run_example("03_splash_dataset_report.py", out, tmp_path)
    report = out / "03_splash_dataset_report" / "report"
    text = (report / "report.md").read_text()
    assert text.startswith("# Experiments report: splash") and "figures/" in text
    for figure in (report / "figures").glob("*.png"):
        png(figure)
    assert len(list((report / "figures").glob("*.png"))) >= 3
    assert (report / "results.csv").is_file() and (report / "results.parquet").is_file()
    summary = json.loads((out / "03_splash_dataset_report" / "summary.json").read_text())
    assert summary["videos"] == 1 and summary["predicted"] == 1 and not summary["failed"]
    assert f"report: {report / 'report.md'}" in done.stdout


def test_04_several_videos_one_problem(out, tmp_path):
    import xarray as xr

    import galileo

    run_example("04_several_videos_one_problem.py", out, tmp_path)
    here = out / "04_several_videos_one_problem"
    shared = galileo.load_result(here / "shared_friction.json")
    assert "k1" in shared.names and {"m1_kg@1", "m1_kg@2", "k2@2"} <= set(shared.names)
    weighed = galileo.load_result(here / "weighed.json")
    assert {"m1_kg", "k1", "m2_kg@2"} <= set(weighed.names) and "m2_kg@1" not in weighed.names   # fixed
    assert "m1_kg" not in weighed.not_identified    # weighed against the reference box
    back = xr.open_datatree(here / "weighed.nc")
    assert dict(back["posterior"].sizes) == {"chain": 4, "draw": 12 - weighed.burn_in}
    assert {"position_m_video1", "position_m_video2"} <= set(back["observed_data"].data_vars)
    for v in (1, 2):
        assert galileo.load_tracks(here / f"tracks_video{v}.json").n_frames > 0
