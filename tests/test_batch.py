"""The dataset engine on Dask (galileo.batch): a local cluster of worker processes, records
kept per video, resumable after a kill, a dying worker retried once, bad videos reported
and the run going on, SLURM built from its documented settings."""
import json
import math
import os
import shutil
import signal
import subprocess
import sys

import pytest

from conftest import wait_until
from galileo import batch
from galileo.cli import main
from galileo.runner import RunConfig

CFG = RunConfig(chains=2, sweeps=4, workers=1)
ARGS = ["--chains", "2", "--sweeps", "4"]


@pytest.fixture(scope="module")
def dataset(demo_dir, tmp_path_factory):
    """The rendered demo video as a 3-video ramp dataset: `a` (20 degrees, its object also in
    `b`, listed as its 10 degree video), `b`, `c`."""
    root = tmp_path_factory.mktemp("ds")
    entries = []
    for name, angle in (("a", 20.0), ("b", 10.0), ("c", 20.0)):
        shutil.copytree(demo_dir, root / name)
        entries.append({"name": name, "object": "X" if name in "ab" else "Y", "angle_deg": angle})
    (root / "index.json").write_text(json.dumps({"preset": "test", "videos": entries}))
    return root


@pytest.fixture(scope="module")
def client():
    with batch.open_client(2) as c:
        yield c


def timeless(report: dict) -> dict:
    """A report without what differs between runs of the same work (times, memory, the run's bookkeeping)."""
    s = dict(report["summary"])
    s.pop("seconds_per_video")
    return {**report, "summary": s, "run": None}


def record_without_run(rec: dict) -> dict:
    return {k: v for k, v in rec.items() if k not in ("timing", "worker")}


def test_dataset_runs_on_worker_processes_with_records_tables_and_report(dataset, client, tmp_path):
    out = tmp_path / "out"
    report = batch.run_experiments(dataset, CFG, out, client, progress=False)
    recs = {p.stem: json.loads(p.read_text()) for p in (out / "records").glob("*.json")}
    assert set(recs) == {"a", "b", "c"} and all(r["status"] == "fitted" for r in recs.values())
    # the work ran in the workers, not here, and both workers took some
    assert all(r["worker"]["pid"] != os.getpid() for r in recs.values())
    assert len({r["worker"]["pid"] for r in recs.values()}) == 2
    # the will-it-move question goes to a's 10 degree partner, whose truth it carries
    objs = json.loads((dataset / "b" / "truth.json").read_text())["trajectory"]["objects"]
    moved = abs(objs[0]["position_m"][-1][0] - objs[0]["position_m"][0][0]) > 0.005
    assert recs["a"]["will_it_move"]["partner"] == "b" and recs["a"]["will_it_move"]["true_moves"] == moved
    assert "will_it_move" not in recs["b"] and "will_it_move" not in recs["c"]
    # outcome: the target's true resting place is the truth file's last frame
    assert recs["b"]["outcome"]["true_final_x_m"] == objs[1]["position_m"][-1][0]
    # the objects collide: the log mass ratio is scored like a latent, its truth from truth.json
    lat = json.loads((dataset / "b" / "truth.json").read_text())["latents"]
    assert recs["b"]["collision"] and recs["b"]["truth"]["log_mass_ratio"] == pytest.approx(
        math.log(lat["m1_kg"] / lat["m2_kg"]), rel=1e-12)
    assert set(recs["b"]["posterior_derived"]["log_mass_ratio"]) >= {"q05", "q50", "q95"}
    assert report["summary"]["fitted"] == 3 and report["run"]["resumed_videos"] == 0
    for f in ("report.json", "results.parquet", "results.csv", "report.md"):
        assert (out / f).is_file(), f
    # the same work with every chain a Dask task of its own: the same numbers, bit for bit
    again = batch.run_experiments(dataset, CFG, tmp_path / "chains", client, granularity="chains", progress=False)
    assert timeless(again) == {**timeless(report), "granularity": "chains"}


def test_failed_videos_are_recorded_and_the_run_goes_on(dataset, client, tmp_path):
    ds = tmp_path / "ds"
    shutil.copytree(dataset, ds)
    (ds / "b" / "truth.json").write_text("{ not json")
    (ds / "c" / "video.mp4").unlink()
    report = batch.run_experiments(ds, CFG, tmp_path / "out", client, progress=False)
    failed = {f["video"]: f["error"] for f in report["summary"]["failed"]}
    assert set(failed) == {"b", "c"} and report["summary"]["fitted"] == 1
    assert "not valid JSON" in failed["b"] and "video.mp4" in failed["c"]
    assert all("\n" not in e for e in failed.values())
    assert sorted(report["run"]["failed_videos"]) == ["b", "c"]
    # a's will-it-move partner is b, whose truth is broken: a is fitted, the question left open
    a = json.loads((tmp_path / "out" / "records" / "a.json").read_text())
    assert "will_it_move" not in a and "not valid JSON" in a["will_it_move_error"]


def test_a_dying_worker_is_retried_once_then_its_video_is_failed(client, tmp_path):
    marker = tmp_path / "died-once"

    def dies_once(executor=None):
        if not marker.exists():
            marker.write_text("x")
            os._exit(1)            # the worker process dies, as killed or out of memory
        return {"video": "once", "status": "fitted", "pid": os.getpid()}

    def dies_always(executor=None):
        os._exit(1)

    def fine(executor=None):
        return {"video": "fine", "status": "fitted"}

    jobs = [batch.Job("once", dies_once, (), "k1"), batch.Job("always", dies_always, (), "k2"),
            batch.Job("fine", fine, (), "k3")]
    done = batch.run_jobs(client, jobs, batch.RecordStore(tmp_path / "records"), progress=False)
    once, always, ok = done.records
    assert once["status"] == "fitted" and marker.exists()          # ran again on a fresh worker
    assert always["status"] == "failed" and "worker died 2 times" in always["error"]
    assert ok["status"] == "fitted" and done.failed == ["always"]
    # the nannies bring the workers back: waited for on the scheduler's own view of its running
    # workers (a nanny restarting a killed worker on a busy machine takes its time)
    client.wait_for_workers(2, timeout=300)
    assert len(client.run(os.getpid)) == 2          # both answer


def _watch_semaphores():
    """In a worker: record every named semaphore registered with the resource tracker from now on."""
    from multiprocessing import resource_tracker

    made = []
    original = resource_tracker.register

    def register(name, rtype):
        made.append((name, rtype))
        return original(name, rtype)

    resource_tracker.register = register
    resource_tracker._galileo_made = made      # read back by _semaphores_made


def _semaphores_made():
    from multiprocessing import resource_tracker

    return list(resource_tracker._galileo_made)


def test_a_worker_running_a_video_makes_no_named_semaphore(dataset, tmp_path):
    """Ctrl-C on a busy machine: the cluster kills a worker that does not exit in time, and a
    named semaphore that worker made is never unlinked (the resource tracker then prints a
    second line after `galileo: interrupted`). A fresh worker running a whole video
    (tracking, chains, questions, with their progress bars) registers none."""
    with batch.open_client(1) as fresh:
        fresh.run(_watch_semaphores)
        one = tmp_path / "one"
        shutil.copytree(dataset / "c", one / "c")
        (one / "index.json").write_text(json.dumps({"preset": "test", "videos": [{"name": "c", "object": "Y"}]}))
        report = batch.run_experiments(one, CFG, tmp_path / "out", fresh, progress=False)
        assert report["summary"]["fitted"] == 1
        made = fresh.run(_semaphores_made)
    assert len(made) == 1 and list(made.values()) == [[]], made


def test_a_killed_run_resumes_with_the_same_report(dataset, tmp_path):
    def start(out):
        return subprocess.Popen([sys.executable, "-m", "galileo", "experiment", str(dataset), "--out", str(out),
                                 "--workers", "1", "--quiet", *ARGS], start_new_session=True,
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)

    whole = tmp_path / "whole"
    assert start(whole).wait(timeout=300) == 0
    out = tmp_path / "killed"
    p = start(out)
    assert wait_until(lambda: list((out / "records").glob("*.json")), 300), "no video was ever recorded"
    os.killpg(p.pid, signal.SIGKILL)          # the whole run: the command and its workers
    p.wait()
    kept = {f.name for f in (out / "records").glob("*.json")}
    assert 1 <= len(kept) < 3 and not (out / "report.json").exists()
    assert not list((out / "records").glob("*.tmp*"))     # every record is whole or absent
    p = start(out)
    assert p.wait(timeout=300) == 0, p.stderr.read().decode()
    a, b = (json.loads((d / "report.json").read_text()) for d in (whole, out))
    assert b["run"]["resumed_videos"] == len(kept)
    assert timeless(a) == timeless(b)
    for name in ("a", "b", "c"):
        ra, rb = (json.loads((d / "records" / f"{name}.json").read_text()) for d in (whole, out))
        assert record_without_run(ra) == record_without_run(rb)


def test_another_config_is_run_again_not_resumed(dataset, client, tmp_path):
    out = tmp_path / "out"
    batch.run_experiments(dataset, CFG, out, client, progress=False)
    again = batch.run_experiments(dataset, CFG, out, client, progress=False)
    assert again["run"]["resumed_videos"] == 3
    other = batch.run_experiments(dataset, RunConfig(chains=2, sweeps=5, workers=1), out, client, progress=False)
    assert other["run"]["resumed_videos"] == 0
    # running each video until converged: an R-hat no run reaches, the sweep budget spent, said per record
    until = batch.run_experiments(dataset, RunConfig(chains=2, sweeps=4, workers=1, until_rhat=1.000001,
                                                     max_sweeps=14, max_seconds=600.0), out, client, progress=False)
    assert until["run"]["resumed_videos"] == 0
    fitted = [r for r in (json.loads(p.read_text()) for p in (out / "records").glob("*.json"))
              if r.get("status") == "fitted"]
    assert fitted and all(r["stopped"] == "max_sweeps" and r["sweeps"] == 14 for r in fitted)


@pytest.mark.timeout(300)     # gives up (after batch.CONNECT_TIMEOUT_S), never hangs
def test_unreachable_scheduler_is_one_line_and_exit_2(dataset, tmp_path, capsys, monkeypatch):
    from conftest import free_port

    monkeypatch.setattr(batch, "CONNECT_TIMEOUT_S", 1)      # (10 s by default: only waiting)
    code = main(["experiment", str(dataset), "--out", str(tmp_path / "o"), "--quiet", *ARGS,
                 "--scheduler", f"tcp://127.0.0.1:{free_port()}"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.startswith("galileo: error: cannot reach the Dask scheduler") and "\n" not in err


@pytest.mark.parametrize("what, needle", [
    ({"videos": []}, "no videos"), ({"videos": [{"name": "a"}, {"name": "a"}]}, "listed twice"),
    ({"scenario": "nope", "videos": [{"name": "a"}]}, "unknown scenario"), ([1], "expected an object"),
])
def test_bad_dataset_index_is_one_line(tmp_path, capsys, what, needle):
    (tmp_path / "index.json").write_text(json.dumps(what))
    assert main(["experiment", str(tmp_path), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("galileo: error:") and needle in err and "\n" not in err


def test_slurm_cluster_is_built_from_the_documented_settings():
    settings = {"queue": "normal", "account": "lab", "cores": 8, "memory": "16GB", "walltime": "01:30:00",
                "jobs": 3, "job_extra_directives": ["--exclusive"]}
    import warnings

    with warnings.catch_warnings():     # its scheduler's dashboard may find 8787 taken by another test's cluster
        warnings.filterwarnings("ignore", message="Port .* is already in use", category=UserWarning)
        cluster, jobs = batch.slurm_cluster(settings)
    try:
        script = cluster.job_script()
    finally:
        cluster.close()
    assert jobs == 3
    for line in ("#SBATCH -p normal", "#SBATCH -A lab", "#SBATCH --cpus-per-task=8", "#SBATCH -t 01:30:00",
                 "#SBATCH --exclusive"):
        assert line in script, line
    # one single-threaded worker process per core: one pybullet client each
    assert "--nworkers 8" in script and "--nthreads 1" in script
    with pytest.raises(batch.GalileoError, match="unknown SLURM setting"):
        batch.slurm_cluster({"queues": "x"})


def test_infer_over_a_folder_of_videos_filmed_in_one_scene(demo_dir, tmp_path, capsys):
    videos = tmp_path / "videos"
    videos.mkdir()
    for name in ("x", "y"):
        shutil.copy(demo_dir / "video.mp4", videos / f"{name}.mp4")
    (videos / "notes.txt").write_text("not a video")
    out = tmp_path / "out"
    assert main(["infer", str(videos), "--scene", str(demo_dir / "scene.json"), "--out", str(out), "--workers", "1",
                 "--chains", "2", "--sweeps", "3", "--quiet"]) == 0
    from galileo.report import read_table

    rows = {r["video"]: r for r in read_table(out / "results.csv")}
    assert set(rows) == {"x", "y"} and all(r["status"] == "fitted" for r in rows.values())
    # one video twice, one seed: the same result, each in its own result file
    results = [json.loads((out / f"{n}.result.json").read_text()) for n in ("x", "y")]
    assert results[0]["map"] == results[1]["map"] == rows["x"]["map"] == rows["y"]["map"]
    assert (out / "x.result.samples.npz").is_file() and "x: " in capsys.readouterr().out


@pytest.mark.parametrize("setup, flags, needle", [
    ("empty", [], "no subfolders"), ("empty", ["--scene", "S"], "no video files"),
    ("videos", ["--tracks", "t.json"], "--tracks is for one video"),
])
def test_infer_folder_refusals_are_one_line(demo_dir, tmp_path, capsys, setup, flags, needle):
    folder = tmp_path / "f"
    folder.mkdir()
    if setup == "videos":
        shutil.copy(demo_dir / "video.mp4", folder / "x.mp4")
    flags = [str(demo_dir / "scene.json") if f == "S" else f for f in flags]
    assert main(["infer", str(folder), "--out", str(tmp_path / "o"), "--quiet", *flags]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("galileo: error:") and needle in err and "\n" not in err


def test_out_must_name_a_folder(dataset, tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    for out, needle in ((tmp_path / "report.json", "names the results folder"), (tmp_path / "file", "is a file; expected a folder")):
        assert main(["experiment", str(dataset), "--out", str(out), "--quiet", *ARGS]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("galileo: error:") and needle in err and "\n" not in err


def test_ctrl_c_stops_the_run_in_one_line_and_keeps_its_records(dataset, tmp_path):
    out = tmp_path / "out"
    p = subprocess.Popen([sys.executable, "-m", "galileo", "experiment", str(dataset), "--out", str(out),
                          "--workers", "1", "--quiet", *ARGS], start_new_session=True,
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    assert wait_until(lambda: list((out / "records").glob("*.json")), 300), "no video was ever recorded"
    os.killpg(p.pid, signal.SIGINT)          # a terminal's Ctrl-C: the command and its workers
    err = p.communicate(timeout=120)[1].decode()
    assert p.returncode == 130 and err.strip() == "galileo: interrupted", err
    assert list((out / "records").glob("*.json")) and not (out / "report.json").exists()
    def left() -> str:
        return subprocess.run(["ps", "-g", str(p.pid), "-o", "pid=,args="], capture_output=True, text=True).stdout.strip()
    # the workers end on their own (the cluster's shutdown): waited for, generously on a busy machine
    assert wait_until(lambda: not left(), 180), f"processes outlived the run: {left()}"


@pytest.mark.parametrize("to", ["the command", "its process group"])
def test_sigterm_stops_the_run_like_ctrl_c_in_one_line_with_exit_143(dataset, tmp_path, to):
    """`kill PID` (the command alone) or a batch system's time limit (every process of the job):
    the records written are kept, the workers shut down, one line, exit 128 + 15."""
    out = tmp_path / "out"
    p = subprocess.Popen([sys.executable, "-m", "galileo", "experiment", str(dataset), "--out", str(out),
                          "--workers", "1", "--quiet", *ARGS], start_new_session=True,
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    assert wait_until(lambda: list((out / "records").glob("*.json")), 300), "no video was ever recorded"
    if to == "the command":
        os.kill(p.pid, signal.SIGTERM)
    else:
        os.killpg(p.pid, signal.SIGTERM)
    err = p.communicate(timeout=120)[1].decode()
    assert p.returncode == 128 + signal.SIGTERM and err.strip() == "galileo: terminated", (p.returncode, err)
    kept = list((out / "records").glob("*.json"))
    assert kept and not (out / "report.json").exists()
    assert all(json.loads(f.read_text())["status"] == "fitted" for f in kept)     # whole records, as written

    def left() -> str:
        return subprocess.run(["ps", "-g", str(p.pid), "-o", "pid=,args="], capture_output=True, text=True).stdout.strip()
    assert wait_until(lambda: not left(), 180), f"processes outlived the run: {left()}"


def test_a_dataset_whose_videos_all_lack_files_is_refused_before_any_cluster(tmp_path, capsys, monkeypatch):
    """1000 listed videos, none there: refused in one line naming how many and the first few,
    without starting a cluster (it took minutes to fail each video on one)."""
    (tmp_path / "index.json").write_text(json.dumps({"videos": [{"name": f"v{i:04d}"} for i in range(1000)]}))
    (tmp_path / "v0001").mkdir()
    (tmp_path / "v0001" / "scene.json").mkdir()           # a folder where a file belongs

    def no_cluster(*a, **k):
        raise AssertionError("a cluster was started")
    monkeypatch.setattr(batch, "open_client", no_cluster)
    assert main(["experiment", str(tmp_path), "--out", str(tmp_path / "o"), "--quiet", *ARGS]) == 2
    err = capsys.readouterr().err
    assert err == (f"galileo: error: {tmp_path}: none of the 1000 videos its index.json lists can run: "
                   "v0000/scene.json not found; v0001/scene.json is not a file; v0002/scene.json not found; "
                   "and 997 more\n")
    assert not (tmp_path / "o").exists()


def test_videos_lacking_files_are_recorded_failed_without_running_and_the_rest_run(dataset, tmp_path, capsys):
    ds = tmp_path / "ds"
    shutil.copytree(dataset, ds)
    (ds / "a" / "truth.json").unlink()
    shutil.rmtree(ds / "c")
    out = tmp_path / "out"
    assert main(["experiment", str(ds), "--out", str(out), "--workers", "1", "--quiet", *ARGS]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err[0] == ("galileo: warning: 2 of 3 videos lack a file and are recorded as failed without running: "
                      "a/truth.json not found; c/scene.json not found")
    recs = {n: json.loads((out / "records" / f"{n}.json").read_text()) for n in "abc"}
    assert recs["b"]["status"] == "fitted"
    for name, error in (("a", "a/truth.json not found"), ("c", "c/scene.json not found")):
        assert recs[name]["status"] == "failed" and recs[name]["error"] == error
        assert "worker" not in recs[name]                   # never sent to a worker
    report = json.loads((out / "report.json").read_text())
    assert sorted(report["run"]["failed_videos"]) == ["a", "c"] and report["summary"]["fitted"] == 1


def test_the_api_experiment_on_a_client_passed_in_is_the_batch_run(dataset, client, tmp_path):
    """galileo.experiment(dataset, out, client=...) runs the same work as `galileo experiment` (its
    defaults, the scenario's protocol where not given): the same report."""
    import galileo

    report = batch.run_experiments(dataset, CFG, tmp_path / "batch", client, progress=False)
    mine = galileo.experiment(dataset, tmp_path / "api", client=client, chains=2, sweeps=4, progress=False)
    assert timeless(mine) == timeless(report)
    with pytest.raises(galileo.GalileoError, match="max_seconds is a budget of until_rhat"):
        galileo.experiment(dataset, tmp_path / "x", client=client, max_seconds=3)
