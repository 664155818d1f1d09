"""Failures at run time (issue 15): a worker process killed mid-run (the pool restarted, the
round run again, the chains those of a run in which nothing died), one stopped mid-run (issue
24: noticed at the round's deadline, then the same), workers that keep dying
(every chain paused, resumable), an interrupted save's temporary files (removed on reopen),
and rerun's web viewer bound to the app's host."""
import os
import signal
import socket
import threading
import time

import numpy as np
import pytest

from conftest import free_port
from ui import controller as controller_module
from ui import session as sess
from ui.controller import Controller

SWEEPS = 16


@pytest.fixture(scope="module")
def demo(demo_frozen):
    return demo_frozen[:2]


@pytest.fixture(scope="module")
def reference(demo):
    """The chains of an uninterrupted run (one worker, rounds run here)."""
    ctl = Controller(*demo, chains=3, seed=7, workers=1, sweeps=SWEEPS)
    try:
        ctl.run_sweeps(SWEEPS)
        return {c: (ctl.samples(c), ctl.logliks(c), ctl.proposals(c)) for c in ctl.all_chain_ids()}
    finally:
        ctl.close()


def same_as(reference, ctl):
    assert ctl.all_chain_ids() == sorted(reference)
    for c, (samples, logliks, proposals) in reference.items():
        assert np.array_equal(ctl.samples(c), samples), c
        assert np.array_equal(ctl.logliks(c), logliks), c
        got = ctl.proposals(c)
        for k in ("site", "proposal", "accepted", "early_stop"):
            assert np.array_equal(got[k], proposals[k]), (c, k)


def wait_until(cond, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return
        time.sleep(0.02)
    raise AssertionError(f"timed out waiting for {what}")


def all_held(ctl) -> bool:
    st = ctl.status()
    return all(c["sweeps"] >= SWEEPS and c["paused"] for c in st["chains"].values())


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


@pytest.mark.timeout(300)
def test_a_killed_worker_is_replaced_and_the_chains_go_on_unchanged(demo, reference, tmp_path, capfd):
    """SIGKILL one of the pool's two workers while a round is in flight: the round runs again on
    a new pool, sampling goes on to the sweep target, the death is an event, a status entry
    and a line on stderr, and the chains equal an uninterrupted run's bit for bit (no sweep
    lost or run twice)."""
    ctl = Controller(*demo, chains=3, seed=7, workers=2, sweeps=SWEEPS, session_dir=tmp_path / "s")
    try:
        pids = ctl._executor.pids()
        assert len(pids) == 2 and all(alive(p) for p in pids)
        killed = []

        def killer():   # the moment a round after the second is in flight
            wait_until(lambda: ctl.status()["rounds"] >= 2 and ctl._in_flight, 120, "a round in flight")
            os.kill(pids[0], signal.SIGKILL)
            killed.append(pids[0])
        t = threading.Thread(target=killer, daemon=True)
        t.start()
        ctl.start()
        t.join(130)
        assert killed == [pids[0]]
        wait_until(lambda: all_held(ctl), 240, "the chains to reach the sweep target")
        assert ctl.running and ctl.status()["error"] is None

        died = [e for e in ctl.events if e["kind"] == "worker_died"]
        assert len(died) == 1, died
        d = died[0]["detail"]
        assert d["restarted"] and d["restarts"] == 1
        assert 3 <= d["sweep"] <= SWEEPS
        assert [w["pid"] for w in d["workers"]] == [pids[0]] and d["workers"][0]["how"] == "killed by SIGKILL"
        st = ctl.status()["workers"]
        assert st["restarts"] == 1 and not st["last_death"]["gave_up"]
        assert f"died during sweep {d['sweep']}" in st["last_death"]["text"]
        assert "restarted (1 time)" in st["last_death"]["text"]
        new = ctl._executor.pids()
        assert len(new) == 2 and not set(new) & set(pids) and all(alive(p) for p in new)
        assert ctl._executor.context == "spawn"   # threads exist by now: a fork would copy their state
        wait_until(lambda: not alive(pids[1]), 20, "the broken pool's other worker to end")
        same_as(reference, ctl)
        ctl.close()     # (saved, and its lock let go)
        err = capfd.readouterr().err
        assert "galileo: warning: an inference worker died during sweep" in err and f"pid {pids[0]}" in err
        # the session holds the event, and reopens as the same chains
        back = Controller.load(tmp_path / "s", workers=1)
        try:
            same_as(reference, back)
            assert [e["kind"] for e in back.events].count("worker_died") == 1
        finally:
            back.close()
    finally:
        ctl.close()


@pytest.mark.timeout(300)
def test_a_stopped_worker_is_killed_and_replaced_and_the_chains_go_on_unchanged(demo, reference, monkeypatch,
                                                                               capfd):
    """SIGSTOP the pool's worker while a round is in flight (a worker that stops answering, as
    one stuck would): past the round's deadline (a 5 s floor here, 60 s in the app) its pool is
    killed and made anew and the round runs again; sampling goes on to the sweep target, the
    hang is an event, a status entry and a line on stderr, and the chains equal an
    uninterrupted run's bit for bit."""
    monkeypatch.setattr(controller_module, "ROUND_DEADLINE_FLOOR_S", 5.0)
    ctl = Controller(*demo, chains=3, seed=7, workers=1, sweeps=SWEEPS)
    (pid,) = ctl._executor.pids()
    try:
        stopped = []

        def stopper():   # the moment a round after the second is in flight
            wait_until(lambda: ctl.status()["rounds"] >= 2 and ctl._in_flight, 120, "a round in flight")
            os.kill(pid, signal.SIGSTOP)
            stopped.append(pid)
        t = threading.Thread(target=stopper, daemon=True)
        t.start()
        ctl.start()
        t.join(130)
        assert stopped == [pid]
        wait_until(lambda: all_held(ctl), 240, "the chains to reach the sweep target")
        assert ctl.running and ctl.status()["error"] is None

        hung = [e["detail"] for e in ctl.events if e["kind"] == "worker_died"]
        assert len(hung) == 1, hung
        d = hung[0]
        assert d["cause"] == "hung" and d["restarted"] and d["restarts"] == 1 and 3 <= d["sweep"] <= SWEEPS
        assert d["workers"] == [{"pid": pid, "exitcode": None, "how": "stopped"}]
        note = ctl.status()["workers"]["last_death"]
        assert f"an inference worker stopped responding during sweep {d['sweep']} (pid {pid} stopped" in note["text"]
        assert "restarted (1 time)" in note["text"] and not note["gave_up"]
        assert not alive(pid)                      # killed, not left stopped
        (new,) = ctl._executor.pids()
        assert new != pid and alive(new) and ctl._executor.context == "spawn"
        same_as(reference, ctl)
        err = capfd.readouterr().err
        assert f"galileo: warning: an inference worker stopped responding during sweep {d['sweep']}" in err
    finally:
        if alive(pid):
            os.kill(pid, signal.SIGCONT)
            os.kill(pid, signal.SIGKILL)
        ctl.close()


@pytest.mark.timeout(300)
def test_workers_that_keep_dying_pause_every_chain_and_resume_starts_a_new_pool(demo, reference, monkeypatch,
                                                                               capfd):
    """Every pool's workers killed as soon as it is made: after the third death in a row the
    chains pause (an event says why; no endless restarts), and Resume all starts a new pool
    that runs them on to the target, as if nothing had happened."""
    monkeypatch.setattr(controller_module, "WORKER_DEATHS_WINDOW_S", 3600.0)   # however slow the machine
    ctl = Controller(*demo, chains=3, seed=7, workers=2, sweeps=SWEEPS)
    try:
        stop = threading.Event()
        pools = []

        def killer():
            while not stop.is_set():
                ex = ctl._executor
                if ex is not None and ex not in pools and ctl._in_flight:
                    pools.append(ex)
                    for pid in ex.pids():
                        os.kill(pid, signal.SIGKILL)
                time.sleep(0.01)
        t = threading.Thread(target=killer, daemon=True)
        t.start()
        try:
            ctl.start()
            wait_until(lambda: any(e["kind"] == "pause" and "dying" in e["detail"].get("reason", "")
                                   for e in ctl.events), 240, "the chains to pause")
        finally:
            stop.set()
            t.join(5)
        died = [e["detail"] for e in ctl.events if e["kind"] == "worker_died"]
        assert [d["restarted"] for d in died] == [True, True, False]
        assert [d["in_a_row"] for d in died] == [1, 2, 3]
        st = ctl.status()
        assert all(c["paused"] and not c["held"] for c in st["chains"].values())
        assert st["workers"]["last_death"]["gave_up"] and "every chain is paused" in st["workers"]["last_death"]["text"]
        assert ctl.running and st["error"] is None and ctl._executor is None
        assert "galileo: error: inference workers died 3 times in a row" in capfd.readouterr().err
        ctl.resume()
        wait_until(lambda: all_held(ctl), 240, "the resumed chains to reach the sweep target")
        same_as(reference, ctl)
        assert len(pools) == 3 and ctl._executor not in pools
    finally:
        ctl.close()


@pytest.mark.timeout(120)
def test_resume_restarts_a_background_thread_an_error_stopped(demo, monkeypatch):
    """A round that fails for another reason stops the thread with the error in status(); the
    chains were running, so Resume all has nothing to unpause: it starts the thread again."""
    ctl = Controller(*demo, chains=2, seed=1, workers=1, sweeps=SWEEPS)
    try:
        real = ctl._executor

        class Failing:
            workers = 1

            def map(self, fn, tasks):
                raise RuntimeError("disk on fire")

            def shutdown(self):
                pass
        ctl._executor = Failing()
        ctl.start()
        wait_until(lambda: not ctl.running, 60, "the thread to stop")
        assert "disk on fire" in ctl.status()["error"]
        ctl._executor = real
        ctl.resume()
        wait_until(lambda: all_held(ctl), 120, "the chains to reach the target")
        assert ctl.status()["error"] is None
    finally:
        ctl.close()


@pytest.mark.timeout(300)
def test_the_viewer_says_a_worker_died_and_that_inference_stopped(demo_dir, tmp_path, capfd):
    """The Chains panel's status: the death and the restart; an error that stopped the
    background thread, with nothing counted as running."""
    from conftest import demo_viewer

    ctrl, v = demo_viewer(demo_dir, tmp_path / "s", chains=2, seed=3, sweeps=2)
    try:
        v.refresh()
        assert "worker died" not in v.status_text.content and "2 running" in v.status_text.content
        (pid,) = ctrl._executor.pids()
        os.kill(pid, signal.SIGKILL)
        wait_until(lambda: not alive(pid), 20, "the worker to die")
        assert ctrl.run_sweeps(1) == 1 and ctrl.samples(0).shape[0] == 3
        v.refresh()
        text = v.status_text.content
        assert "an inference worker died during sweep 3" in text and f"pid {pid} killed by SIGKILL" in text
        assert "restarted (1 time)" in text and "2 running" in text
        assert "galileo: warning: an inference worker died during sweep 3" in capfd.readouterr().err

        class Failing:
            def map(self, fn, tasks):
                raise RuntimeError("disk on fire")
        real, ctrl._executor = ctrl._executor, Failing()
        ctrl.start()
        wait_until(lambda: not ctrl.running, 60, "the thread to stop")
        ctrl._executor = real
        v.refresh()
        text = v.status_text.content
        assert "inference stopped: an inference worker failed: RuntimeError: disk on fire" in text
        assert "0 running" in text
    finally:
        v.close()
        ctrl.close()


def test_an_interrupted_saves_temporary_files_are_removed_on_reopen(demo, tmp_path):
    folder = tmp_path / "s"
    ctl = Controller(*demo, chains=2, seed=0, workers=1, session_dir=folder)
    ctl.run_sweeps(2)
    ctl.close()
    stale = [".events.json.k3j_x9a2.tmp", ".record.npz.abcd1234.tmp", ".chains.json.q.tmp", ".settings.json.zz.tmp"]
    kept = [".notes.txt.abcd.tmp", "events.json.abcd.tmp", ".events.json.tmp", "mine.tmp", ".events.json.a.b.tmp"]
    for name in stale + kept:
        (folder / name).write_bytes(b'{"half": ')
    assert sorted(p.name for p in sess.stale_temp_files(folder)) == sorted(stale)
    back = Controller.load(folder, workers=1)
    try:
        names = {p.name for p in folder.iterdir()}
        assert not names & set(stale) and set(kept) <= names and set(sess.FILES) <= names
        assert back.samples(0).shape == (2, len(back.names))
    finally:
        back.close()


def _listening(port: int) -> list[str]:
    import psutil

    return sorted({c.laddr.ip for c in psutil.net_connections(kind="inet")
                   if c.status == psutil.CONN_LISTEN and c.laddr.port == port})


def _other_address() -> str | None:
    """An address of this machine other than loopback (None when it has none)."""
    import psutil

    for addrs in psutil.net_if_addrs().values():
        for a in addrs:
            if a.family == socket.AF_INET and not a.address.startswith("127."):
                return a.address
    return None


@pytest.mark.timeout(120)
def test_rerun_web_listens_only_on_the_apps_host(tmp_path):
    """--rerun web with the app on 127.0.0.1: the web viewer's HTTP server and the gRPC server
    listen on 127.0.0.1 only (nothing on 0.0.0.0, nothing reachable at another address of this
    machine); the page is served and closing the logger stops it."""
    import urllib.request

    from ui.rerun_log import RerunLogger

    web_port, grpc_port = free_port(), free_port()
    log = RerunLogger("web", session_dir=tmp_path, web_port=web_port, grpc_port=grpc_port, host="127.0.0.1")
    try:
        log.log_sweep(0, 1, -3.0, {"k1": 0.5})
        log.flush()
        for port in (web_port, grpc_port):     # (rerun may bind its servers from its own threads)
            wait_until(lambda: _listening(port), 60, f"port {port} to listen")
            assert _listening(port) == ["127.0.0.1"], port
        with urllib.request.urlopen(log.web_url, timeout=10) as page:
            assert page.status == 200 and b"<html" in page.read(4096).lower()
        other = _other_address()
        if other is not None:
            for port in (web_port, grpc_port):
                with pytest.raises(OSError):
                    socket.create_connection((other, port), timeout=2).close()
    finally:
        log.close()
    wait_until(lambda: not _listening(web_port), 20, "the web viewer to stop")


@pytest.mark.parametrize("change, reason", [({"seed": -1}, "seed must be an integer >= 0"),
                                            ({"chains": []}, "no chains listed"),
                                            ({"rounds": 2.5}, "rounds must be an integer >= 0")])
def test_a_damaged_session_is_refused_in_one_line(tmp_path, change, reason):
    """chains.json with a negative seed or no chains (while record.npz holds two) is refused when
    the session is reopened, naming what is wrong, not served."""
    import json

    from galileo.errors import GalileoError
    from conftest import load_demo_frozen
    from ui.controller import Controller

    scene, tracks, _ = load_demo_frozen()
    ctrl = Controller(scene, tracks, chains=2, seed=0, workers=1, session_dir=tmp_path / "s", sweeps=2)
    ctrl.run_sweeps(2)
    ctrl.close()
    path = tmp_path / "s" / "chains.json"
    doc = json.loads(path.read_text())
    doc.update(change)
    path.write_text(json.dumps(doc))
    with pytest.raises((ValueError, GalileoError), match=reason):
        Controller.load(tmp_path / "s", workers=1)


def test_rerun_web_ports_are_flags_checked_before_anything_starts(capsys):
    """Issue 24, item 9: the rerun web viewer's ports (9090, 9876) can be set; they are for --rerun
    web only, must differ, and a taken one is refused in one line before anything is tracked."""
    import socket

    import app

    def refused(argv, needle):
        assert app.main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("app: error:") and needle in err[0], err

    refused(["--rerun-web-port", "9191"], "are for --rerun web")
    refused(["--rerun", "web", "--rerun-web-port", "9191", "--rerun-grpc-port", "9191"], "must differ (both 9191)")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        taken = s.getsockname()[1]
        refused(["--rerun", "web", "--rerun-grpc-port", str(taken), "--port", str(free_port())],
                f"port {taken} on 127.0.0.1 is taken (another app running?); choose another with --rerun-grpc-port")
    assert app.parse_args(["--rerun", "web", "--rerun-web-port", "9191", "--rerun-grpc-port", "9292"]).rerun_web_port == 9191
