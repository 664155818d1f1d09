"""Sessions that cannot lose work (issue 24, items 7, 12, 13 and 15): a session's lock refuses a
second controller or app in one line naming the holder, and goes with its holder's process
(not with a forked worker's copy); a folder deleted or moved while the app runs is never
written to again, the whole session going to a new folder beside it (or, when that cannot be
made, the app says at exit that nothing is saved); a reopened session's chains wait for
Resume; a reopened session without its video is refused before anything starts."""
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT, free_port, wait_until
from galileo.errors import GalileoError
from galileo.runner import MIN_BLOCK_SWEEPS, LocalPool, RunConfig, infer
from ui import session as sess
from ui.controller import Controller

VIDEO_BYTES = b"\x00\x00\x00\x18ftypmp42 not really a video, but its bytes must survive"


@pytest.fixture(scope="module")
def demo(demo_frozen):
    return demo_frozen[:2]


def same_chains(a: Controller, b: Controller) -> None:
    assert a.all_chain_ids() == b.all_chain_ids()
    for c in a.all_chain_ids():
        assert np.array_equal(a.samples(c), b.samples(c)), c
        assert np.array_equal(a.logliks(c), b.logliks(c)), c
        assert np.array_equal(a.proposals(c)["proposal"], b.proposals(c)["proposal"]), c


def rounds_on_disk(folder: Path) -> int:
    return json.loads((folder / sess.CHAINS_FILE).read_text())["rounds"]


def remove(folder: Path) -> None:
    """rm -rf, again if a save of the app's slipped a file in while it ran (as a user would)."""
    assert wait_until(lambda: shutil.rmtree(folder, ignore_errors=True) or not folder.exists(), 30)


# -- one app at a time ------------------------------------------------------------------------------------

def test_a_second_opener_is_refused_in_one_line_and_the_first_keeps_saving(demo, tmp_path):
    """The issue's lost work (rounds 105 -> 102): a second controller on an open session is
    refused, naming this process and host, before it reads or removes anything (not even the
    temporary file of a save in progress); the first saves on, and once it has closed the
    session reopens with every round."""
    folder = tmp_path / "s"
    first = Controller(*demo, chains=2, seed=1, workers=1, sweeps=None, session_dir=folder)
    try:
        first.run_sweeps(2)
        first.save()
        in_progress = folder / ".events.json.k3j9x.tmp"   # as a save of the first's under way leaves it
        in_progress.write_bytes(b'{"half": ')
        with pytest.raises(GalileoError) as e:
            Controller.load(folder, workers=1)
        msg = str(e.value)
        assert "\n" not in msg
        assert f"session {folder} is open in another app (pid {os.getpid()} on {socket.gethostname()}, since" in msg
        assert in_progress.exists()
        first.run_sweeps(3)
        first.save()
        assert rounds_on_disk(folder) == 5
    finally:
        first.close()
    back = Controller.load(folder, workers=1)
    try:
        assert back.status()["rounds"] == 5 and not in_progress.exists()
        same_chains(first, back)
    finally:
        back.close()


def test_a_new_session_folder_is_locked_from_its_creation(demo, tmp_path):
    """The app locks a new folder as it makes it (before the video is copied and the chains
    start); the controller it then makes adopts that lock, and anyone else is refused."""
    folder = sess.new_session_dir(tmp_path, "demo")
    lock = sess.SessionLock(folder)
    with pytest.raises(GalileoError, match="is open in another app"):
        sess.SessionLock(folder)
    with pytest.raises(GalileoError, match="is open in another app"):
        Controller(*demo, chains=1, workers=1, session_dir=folder)
    assert not (folder / sess.CHAINS_FILE).exists()      # the refused one wrote nothing
    ctl = Controller(*demo, chains=1, workers=1, session_dir=folder, session_lock=lock)
    with pytest.raises(GalileoError, match="is open in another app"):
        Controller.load(folder, workers=1)
    ctl.close()
    sess.SessionLock(folder).release()


def test_the_lock_goes_with_its_process_and_not_with_a_forked_worker(tmp_path):
    """A holder killed with SIGKILL holds nothing (the operating system lets its lock go: never
    a stale lock to clear by hand); a worker forked while the lock is held does not keep it."""
    folder = tmp_path / "s"
    folder.mkdir()
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time\nfrom ui.session import SessionLock\nlock = SessionLock(sys.argv[1])\n"
         "print('locked', flush=True)\ntime.sleep(600)", str(folder)],
        stdout=subprocess.PIPE, text=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(GalileoError, match=f"open in another app \\(pid {holder.pid} on "):
            sess.SessionLock(folder)
    finally:
        holder.kill()
        holder.wait()
    lock = sess.SessionLock(folder)
    pool = LocalPool(1)     # forked now, with the lock file open
    try:
        lock.release()
        assert all(psutil_alive(p) for p in pool.pids())
        sess.SessionLock(folder).release()
    finally:
        pool.shutdown()


def psutil_alive(pid: int) -> bool:
    import psutil

    return psutil.pid_exists(pid) and psutil.Process(pid).status() != psutil.STATUS_ZOMBIE


# -- a folder lost while the app runs ----------------------------------------------------------------------

@pytest.mark.timeout(300)
def test_a_save_that_fails_once_in_a_folder_still_there_is_made_again(demo, tmp_path, monkeypatch):
    """A folder being deleted fails a save before it is gone (the race that stopped inference
    under load): a periodic save that fails once, the folder still there, keeps the session
    dirty and the chains running, and the next save writes everything; one that keeps failing
    stops inference (SAVE_RETRIES) rather than pretend."""
    import ui.controller as controller_module

    real, failures = sess.write_state, {"left": 0}

    def flaky(*a, **k):
        if failures["left"]:
            failures["left"] -= 1
            raise OSError("No such file or directory: a save's temporary file (the folder is being deleted)")
        return real(*a, **k)

    monkeypatch.setattr(sess, "write_state", flaky)
    folder = tmp_path / "s"
    ctl = Controller(*demo, chains=2, seed=3, workers=1, sweeps=None, session_dir=folder, save_every_s=0.05)
    failures["left"] = 1    # the first periodic save fails
    try:
        ctl.start()
        assert wait_until(lambda: failures["left"] == 0 and rounds_on_disk(folder) >= 3 if (folder / sess.CHAINS_FILE).exists()
                          else False, 120)
        assert ctl.status()["session"]["note"] is None      # nothing was lost, nothing to say
        ctl.stop()
        ctl.save()
    finally:
        ctl.close()
    assert rounds_on_disk(folder) == ctl.status()["rounds"]
    failures["left"] = controller_module.SAVE_RETRIES       # and a folder that keeps refusing: the error
    back = Controller.load(folder, workers=1, save_every_s=0.05)
    try:
        back._dirty = True
        for _ in range(controller_module.SAVE_RETRIES - 1):
            back.save(retry=True)
        with pytest.raises(OSError):
            back.save(retry=True)
    finally:
        failures["left"] = 0
        back.close()


@pytest.mark.timeout(300)
@pytest.mark.parametrize("how", ["deleted", "renamed"])
def test_a_lost_folder_is_never_written_again_and_the_session_goes_to_a_new_one(demo, tmp_path, capfd, how):
    """The folder deleted (or renamed) while chains run: nothing is written under its old name
    again (the issue's half session), one line on stderr and the status say what happened and
    where the session is saved now: a new folder beside it, with the video and every round up
    to the end, reopenable as the same chains. A renamed folder keeps its last complete save."""
    root = tmp_path / "sessions"
    folder = sess.new_session_dir(root, "demo")
    (folder / "video.mp4").write_bytes(VIDEO_BYTES)
    ctl = Controller(*demo, chains=2, seed=2, workers=1, sweeps=None, session_dir=folder, save_every_s=0.05)
    moved = root / "renamed-by-hand"
    try:
        ctl.start()
        assert wait_until(lambda: ctl.status()["rounds"] >= 3, 120)
        if how == "deleted":
            remove(folder)
        else:
            os.rename(folder, moved)
        assert wait_until(lambda: ctl.status()["session"]["note"] is not None, 60)
        st = ctl.status()["session"]
        recovered = Path(st["folder"])
        assert st["saving"] and recovered.parent == root and recovered.name.startswith(f"{folder.name}-recovered-")
        said = "was deleted" if how == "deleted" else f"was moved or renamed (now {moved})"
        assert st["note"] == (f"the session folder {folder} {said}: the whole session is saved in {recovered} "
                              "from now on")
        at_loss = ctl.status()["rounds"]
        assert wait_until(lambda: ctl.status()["rounds"] >= at_loss + 3, 120)   # and on it goes
        ctl.stop()
        assert not folder.exists()
    finally:
        ctl.close()
    assert not folder.exists() and sorted(p.name for p in root.iterdir()) == sorted(
        [recovered.name] + ([moved.name] if how == "renamed" else []))
    assert (recovered / "video.mp4").read_bytes() == VIDEO_BYTES
    err = capfd.readouterr().err
    assert err.count("\n") == 1 and f"galileo: warning: {st['note']}" in err
    back = Controller.load(recovered, workers=1)
    try:
        same_chains(ctl, back)
        assert back.events == ctl.events and back.status()["rounds"] == ctl.status()["rounds"]
    finally:
        back.close()
    if how == "renamed":   # what was saved before the rename is whole there
        old = Controller.load(moved, workers=1)
        try:
            n = old.status()["rounds"]
            assert 1 <= n <= at_loss
            for c in old.all_chain_ids():
                assert np.array_equal(old.samples(c), ctl.samples(c)[:n])
        finally:
            old.close()


@pytest.mark.timeout(300)
def test_a_folder_lost_with_nowhere_to_recover_to_is_said_and_nothing_is_written(demo, tmp_path, capfd):
    """The sessions folder itself deleted: no new folder can be made beside the session's, so
    nothing more is saved, which the status and one stderr line say; nothing is made again,
    not at the next saves nor at close."""
    root = tmp_path / "sessions"
    folder = sess.new_session_dir(root, "demo")
    ctl = Controller(*demo, chains=2, seed=2, workers=1, sweeps=None, session_dir=folder, save_every_s=0.05)
    try:
        ctl.start()
        assert wait_until(lambda: ctl.status()["rounds"] >= 2, 120)
        remove(root)
        assert wait_until(lambda: ctl.status()["session"]["note"] is not None, 60)
        st = ctl.status()["session"]
        assert not st["saving"] and st["note"].startswith(f"the session folder {folder} was deleted: nothing more "
                                                          "is saved")
        n = ctl.status()["rounds"]
        assert wait_until(lambda: ctl.status()["rounds"] >= n + 3, 120)   # the chains go on in the app
    finally:
        ctl.close()
    assert not root.exists()
    err = capfd.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"galileo: error: the session folder {folder} was deleted")


# -- reopening ---------------------------------------------------------------------------------------------

def test_a_session_saved_while_running_until_converged_waits_for_resume(demo, tmp_path):
    """Saved mid-block while running until converged, reopened as the app does (paused, the
    criteria given again): nothing runs and no verdict is given until Resume; then the chains
    go on as `galileo infer --until-rhat`'s, bit for bit, to the budget. A Resume past the
    budget runs one more block of the batch runner's (25 sweeps) and pauses again."""
    folder = tmp_path / "s"
    ctl = Controller(*demo, chains=2, seed=3, workers=1, sweeps=4, until_rhat=1.01, max_sweeps=6, session_dir=folder)
    ctl.run_sweeps(2)
    ctl.close()
    back = Controller.load(folder, workers=1, paused=True)
    try:
        back.run_until(1.01, max_sweeps=6, verdict=False)
        assert back.run_sweeps(5) == 0
        st = back.status()
        assert all(c["paused"] and not c["held"] and c["sweeps"] == 2 for c in st["chains"].values())
        assert st["until"] == {"until_rhat": 1.01, "min_ess": 400.0, "max_sweeps": 6}
        pause = [e for e in back.events if e["kind"] == "pause"][-1]
        assert pause["detail"] == {"chains": [0, 1], "reason": "session reopened: Resume runs them on"}
        assert not [e for e in back.events if e["kind"] == "until_check"]
        back.resume()
        assert back.run_sweeps(10) == 4
        res = infer(*demo, RunConfig(chains=2, sweeps=4, seed=3, workers=1, until_rhat=1.01, max_sweeps=6),
                    progress=False)
        for c in (0, 1):
            assert np.array_equal(back.samples(c), res.samples[c]) and np.array_equal(back.logliks(c), res.logliks[c])
        assert "budget" in back.events[-1]["detail"]["outcome"]
        back.resume()
        assert back.run_sweeps(100) == MIN_BLOCK_SWEEPS
        last = back.events[-1]
        assert last["kind"] == "until_check" and last["detail"]["sweeps"] == 6 + MIN_BLOCK_SWEEPS
    finally:
        back.close()


def test_a_reopened_session_without_its_video_is_refused_before_anything_starts(demo, tmp_path, capsys):
    """`app --session` on a folder without video.mp4: one line, exit 2, and no worker process
    started (the issue's "Bad file descriptor" came from one left behind), nor the session
    left locked."""
    import psutil

    import app

    folder = tmp_path / "s"
    Controller(*demo, chains=1, workers=1, session_dir=folder).close()
    before = {p.pid for p in psutil.Process().children(recursive=True)}
    assert app.main(["--session", str(folder), "--port", str(free_port()), "--rerun", "off"]) == 2
    assert {p.pid for p in psutil.Process().children(recursive=True)} <= before
    err = capsys.readouterr().err
    assert err == f"app: error: session {folder} has no video.mp4\n"
    sess.SessionLock(folder).release()


# -- apps --------------------------------------------------------------------------------------------------

@pytest.fixture
def saved(demo, demo_dir, tmp_path):
    """A session saved with its 2 chains running (3 sweeps of a target of 10), its video beside."""
    folder = tmp_path / "sessions" / "s"
    ctl = Controller(*demo, chains=2, seed=4, workers=1, sweeps=10, session_dir=folder)
    ctl.run_sweeps(3)
    ctl.close()
    shutil.copyfile(demo_dir / "video.mp4", folder / "video.mp4")
    return folder


class App:
    """`python app.py --session FOLDER` in a process of its own, its output in a log file."""

    def __init__(self, folder: Path, log: Path):
        self.log = log
        self.proc = subprocess.Popen([sys.executable, str(ROOT / "app.py"), "--session", str(folder), "--port",
                                      str(free_port()), "--rerun", "off", "--workers", "1"],
                                     stdout=log.open("w"), stderr=subprocess.STDOUT, cwd=folder.parent,
                                     env={**os.environ, "PYTHONPATH": str(ROOT)})
        assert wait_until(lambda: "session: " in log.read_text() or self.proc.poll() is not None, 120)
        assert self.proc.poll() is None, log.read_text()

    def stop(self) -> int:
        """Ctrl-C's way out (SIGTERM does the same): its exit code."""
        self.proc.send_signal(signal.SIGTERM)
        return self.proc.wait(120)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


@pytest.mark.timeout(400)
def test_a_second_app_is_refused_and_the_session_reopens_once_the_first_has_exited(saved, tmp_path):
    """The issue's two apps on one session: the second is refused in one line, exit 2, naming
    the first's pid and host; the first, whose reopened chains wait for Resume (saved running,
    they are not run on), exits saying where it saved; then the session reopens."""
    first = App(saved, tmp_path / "first.log")
    try:
        second = subprocess.run([sys.executable, str(ROOT / "app.py"), "--session", str(saved), "--port",
                                 str(free_port()), "--rerun", "off"], capture_output=True, text=True, timeout=120,
                                cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(ROOT)})
        assert second.returncode == 2 and second.stdout == "" and second.stderr.count("\n") == 1
        assert second.stderr.startswith(f"app: error: session {saved} is open in another app (pid {first.proc.pid} "
                                        f"on {socket.gethostname()}, since ")
        assert first.stop() == 0
    finally:
        first.kill()
    assert f"saved {saved}\n" in first.log.read_text()
    back = Controller.load(saved, workers=1)
    try:
        st = back.status()
        assert st["rounds"] == 3 and all(c["sweeps"] == 3 and c["paused"] for c in st["chains"].values())
        assert back.events[-1]["detail"]["reason"] == "session reopened: Resume runs them on"
    finally:
        back.close()


@pytest.mark.timeout(400)
def test_an_app_whose_sessions_folder_is_deleted_says_at_exit_that_nothing_is_saved(saved, tmp_path):
    """The issue's folder deleted under a running app (here with the sessions folder around it,
    so that there is nowhere to recover to): at Ctrl-C (SIGTERM) it says the session is NOT
    saved, exit 1, where it used to make a half folder again and print "saved"."""
    root = saved.parent
    app = App(saved, tmp_path / "app.log")
    try:
        remove(root)
        assert app.stop() == 1
    finally:
        app.kill()
    out = app.log.read_text()
    assert (f"app: error: the session is NOT saved: the session folder {saved} was deleted: nothing more is "
            "saved") in out
    assert f"saved {saved}" not in out and not root.exists()
