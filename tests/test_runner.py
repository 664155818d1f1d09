"""The scenario registry, latents checked in one place, and the one chain runner with an
injected executor (on the ramp scenario, with the committed demo scene and a tiny run)."""
import json
import math
import os

import numpy as np
import pytest

from galileo import registry
from galileo.errors import GalileoError, SceneError
from galileo.latents import Latent, check_bounds
from galileo.runner import RunConfig, Settings, infer
from galileo.scenarios.ramp.scene import default_scene


def test_scene_files_name_their_scenario_and_old_files_are_ramp():
    d = default_scene().to_json()
    assert d["scenario"] == "ramp"
    assert registry.scene_from_json(d).scenario == "ramp"
    del d["scenario"]   # a file written before scenarios had names
    assert registry.scene_from_json(d) == default_scene()
    d["scenario"] = "no-such"
    with pytest.raises(SceneError, match="unknown scenario 'no-such'"):
        registry.scene_from_json(d)


MASS = Latent("m_kg", "kg", (0.1, 1.0), limits=(0.0, math.inf), limits_open_low=True)
FRICTION = Latent("k", "1", (0.0, 1.0), limits=(0.0, math.inf))


@pytest.mark.parametrize("latent, lo, hi, needle", [
    (FRICTION, 0.4, 0.4, "must be below"),          # the bound that once loaded and then broke its session
    (FRICTION, 0.5, 0.4, "must be below"),
    (FRICTION, -0.1, 0.4, ">= 0"),
    (MASS, 0.0, 1.0, "> 0"),
    (MASS, float("nan"), 1.0, "finite"),
    (MASS, "a", 1.0, "expected a number"),
    (MASS, True, 1.0, "expected a number"),
])
def test_check_bounds_refuses(latent, lo, hi, needle):
    with pytest.raises(ValueError, match=needle):
        check_bounds(latent, lo, hi)


def test_check_bounds_accepts_and_returns_floats():
    assert check_bounds(MASS, 1, 2) == (1.0, 2.0) and check_bounds(FRICTION, 0, 0.5) == (0.0, 0.5)


def test_one_rule_for_scene_files_sessions_and_live_edits(tmp_path):
    """A prior the scene loader accepts is one the app's settings accept, and vice versa: the
    degenerate k2 [0.4, 0.4] is refused at load time, with the field named."""
    d = default_scene(target="cardboard").to_json()
    d["priors"]["k2"] = [0.4, 0.4]
    with pytest.raises(SceneError, match=r"priors\.k2: the low bound \(0.4\) must be below"):
        registry.scene_from_json(d)
    d["priors"]["k2"] = [0.4, 0.41]
    scene = registry.scene_from_json(d)
    scenario = registry.of(scene)
    latents = scenario.latents(scene)
    s = Settings.default(latents, scenario.noise).checked(latents)
    assert s.bounds["k2"] == (0.4, 0.41)
    back = Settings.from_json(json.loads(json.dumps(s.to_json())), latents, scenario.noise)
    assert back == s


def test_settings_refuse_unknown_latents_and_bad_noise():
    scenario = registry.get("ramp")
    latents = scenario.latents(default_scene())
    with pytest.raises(ValueError, match="unknown latents"):
        Settings({"m1_kg": (0.1, 1.0), "q": (0, 1)}).checked(latents, scenario.noise)
    with pytest.raises(ValueError, match="sigma_mps must be > 0"):
        Settings({}, noise=0.0).checked(latents, scenario.noise)
    with pytest.raises(ValueError, match="broad_every"):
        Settings({}, broad_every=1.5).checked(latents, scenario.noise)


def test_scenarios_command_lists_the_ramp(capsys):
    from galileo.cli import main

    assert main(["scenarios", "--json"]) == 0
    listed = {d["name"]: d for d in json.loads(capsys.readouterr().out)}
    ramp = listed["ramp"]
    assert ramp["noise"] == {"name": "sigma_mps", "unit": "m/s", "default": 0.05}
    lat = {x["name"]: x for x in ramp["latents"]}
    assert lat["m1_kg"]["unit"] == "kg" and lat["m1_kg"]["bounds"] == [0.001, 1.0]
    assert lat["k1"]["unit"] == "1" and lat["k1"]["narrow"] == 0.05 and lat["k1"]["broad"] == 0.5


class CountingExecutor:
    """The smallest executor the runner accepts: anything with `map`."""

    def __init__(self):
        self.tasks = 0

    def map(self, fn, iterable):
        for task in iterable:
            self.tasks += 1
            yield fn(task)


@pytest.fixture(scope="module")
def frozen(demo_frozen):
    scene, tracks = demo_frozen[:2]
    return scene, tracks


def test_an_injected_executor_runs_the_same_chains(frozen):
    scene, tracks = frozen
    cfg = RunConfig(chains=2, sweeps=3, seed=4, workers=1)
    ex = CountingExecutor()
    mine = infer(scene, tracks, cfg, executor=ex, progress=False)
    default = infer(scene, tracks, cfg, progress=False)
    assert ex.tasks == 2   # one task a chain
    assert np.array_equal(mine.samples, default.samples) and np.array_equal(mine.logliks, default.logliks)


def test_run_config_is_checked_before_any_work(frozen):
    scene, tracks = frozen
    for bad in (dict(chains=0), dict(sweeps=-1), dict(seed=-1), dict(workers=0), dict(chains=1.5)):
        with pytest.raises(GalileoError):
            infer(scene, tracks, RunConfig(**bad), progress=False)
    with pytest.raises(GalileoError, match="m1_kg"):
        infer(scene, tracks, RunConfig(chains=1, sweeps=1, bounds={"m1_kg": (0.5, 0.5)}), progress=False)


def _die_in_worker(code: int) -> int:
    import os
    import signal

    if code == 0:
        return os.getpid()
    os.kill(os.getpid(), signal.SIGKILL)
    return -1


def test_a_worker_that_dies_is_named_in_one_error():
    """A worker killed mid-task (as the out-of-memory killer does) ends the map with WorkerDied
    naming its pid and signal, and a hint (what `galileo infer` prints in one line)."""
    from galileo.runner import LocalPool, WorkerDied

    pool = LocalPool(2)
    try:
        with pytest.raises(WorkerDied) as e:
            list(pool.map(_die_in_worker, [0, 9, 0, 0]))
    finally:
        pool.shutdown()
    msg = str(e.value)
    assert "\n" not in msg
    killed = [w for w in pool.dead_workers() if w["how"] == "killed by SIGKILL"]
    assert len(killed) == 1 and f"pid {killed[0]['pid']} killed by SIGKILL" in msg and "--workers" in msg


def test_a_worker_that_stops_answering_is_named_and_killed():
    """A map whose worker was stopped (SIGSTOP) ends at its deadline with WorkerHung naming the
    worker as stopped, and the worker is killed rather than left holding the pool."""
    import os
    import signal

    import psutil

    from galileo.runner import LocalPool, WorkerHung

    pool = LocalPool(1)
    (pid,) = pool.pids()
    os.kill(pid, signal.SIGSTOP)
    try:
        with pytest.raises(WorkerHung) as e:
            list(pool.map(_die_in_worker, [0, 0], timeout_s=2.0))
        assert pool.dead_workers() == [{"pid": pid, "exitcode": None, "how": "stopped"}]
        assert f"pid {pid} stopped" in str(e.value) and "\n" not in str(e.value) and e.value.timeout_s == 2.0
        assert not psutil.pid_exists(pid) or psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
    finally:
        if psutil.pid_exists(pid):
            os.kill(pid, signal.SIGKILL)
        pool.shutdown()


def test_infer_progress_moves_per_sweep_and_the_chains_stay_the_same(frozen, monkeypatch):
    """With a progress bar, one long chain advances the bar sweep by sweep (a piece per round,
    here one sweep: the bar's steps of 1, not one step of the whole chain at its end), and the
    chains are those of a run without the bar, bit for bit."""
    from galileo import runner

    updates = []

    class Bar(runner.tqdm):
        def update(self, n=1):
            updates.append(n)
            return super().update(n)
    cfg = RunConfig(chains=1, sweeps=6, seed=5, workers=1)
    plain = infer(*frozen, cfg, progress=False)
    monkeypatch.setattr(runner, "tqdm", Bar)
    monkeypatch.setattr(runner, "PROGRESS_PIECE_S", 1e-9)    # every piece one sweep
    shown = infer(*frozen, cfg, progress=True)
    assert updates == [1] * 6
    for k in ("samples", "logliks", "starts"):
        assert np.array_equal(getattr(shown, k), getattr(plain, k)), k
    for k, v in plain.proposals.items():
        assert np.array_equal(shown.proposals[k], v, equal_nan=v.dtype.kind == "f"), k


def test_a_worker_is_born_with_sigterm_at_the_default(monkeypatch, tmp_path):
    """Before its initializer runs (it may wait while another worker answers every ping), a forked
    worker must already have SIGTERM at the system's default: with the parent's raising handler a
    SIGTERM then left it hung on its way out (a CI run's worker outlived a 60 s join)."""
    import signal

    from galileo import runner
    from galileo.errors import _terminated

    real = runner._ignore_sigint

    def born(_real=real, _dir=str(tmp_path)):
        with open(os.path.join(_dir, str(os.getpid())), "w") as f:
            f.write("default" if signal.getsignal(signal.SIGTERM) == signal.SIG_DFL else "other")
        _real()

    monkeypatch.setattr(runner, "_ignore_sigint", born)
    before = signal.signal(signal.SIGTERM, _terminated)
    try:
        pool = runner.LocalPool(2)
        assert signal.getsignal(signal.SIGTERM) is _terminated   # the parent's own is back
    finally:
        signal.signal(signal.SIGTERM, before)
    try:
        pids = pool.pids()
    finally:
        pool.shutdown()
    assert sorted(os.listdir(tmp_path)) == sorted(map(str, pids))
    assert {(tmp_path / str(p)).read_text() for p in pids} == {"default"}


def test_a_worker_sent_sigterm_ends_at_once_without_the_parents_handler(capfd):
    """The CLI's SIGTERM handler (`galileo.errors`: raise, then one line) is the parent's: a forked
    worker must not inherit it, or the pool's SIGTERM to its workers raises in them and their
    shutdown prints onto the parent's stderr (it broke the parent's one-line 'terminated')."""
    import signal

    from galileo.errors import _terminated
    from galileo.runner import LocalPool

    before = signal.signal(signal.SIGTERM, _terminated)
    try:
        pool = LocalPool(2)
    finally:
        signal.signal(signal.SIGTERM, before)
    try:
        pid = pool.pids()[0]
        proc = pool._procs[pid]
        os.kill(pid, signal.SIGTERM)
        proc.join(60)
        assert proc.exitcode == -signal.SIGTERM      # the default action: ended by the signal, nothing raised
    finally:
        pool.shutdown()
    assert "Terminated" not in capfd.readouterr().err
