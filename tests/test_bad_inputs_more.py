"""SIGTERM (issue 24): `kill PID`, a batch system's time limit or `timeout` stops a command as
Ctrl-C does, in one line `galileo: terminated` with exit code 143 (128 + 15), its workers shut
down, instead of the signal's default: exit -15, silently. (`galileo experiment`: tests/test_batch.py.)"""
import os
import signal
import subprocess
import sys

import pytest

from conftest import DATA, ROOT, wait_until


SIGNALLED = """
import os, signal, sys
sys.path.insert(0, sys.argv[1])
from galileo.errors import run_reporting_errors

before = signal.getsignal(signal.SIGTERM)

def work():
    os.kill(os.getpid(), signal.SIGTERM)
    print("after the signal")      # never: the signal stops the work here
    return 0

code = run_reporting_errors("galileo", work)
print("restored" if signal.getsignal(signal.SIGTERM) is before else "not restored")
sys.exit(code)
"""


def test_sigterm_is_one_line_exit_143_and_the_handler_is_restored():
    """(In a process of its own: without the handler, SIGTERM ends the process that gets it.)"""
    r = subprocess.run([sys.executable, "-c", SIGNALLED, str(ROOT)], capture_output=True, text=True, timeout=60)
    assert (r.returncode, r.stdout, r.stderr) == (143, "restored\n", "galileo: terminated\n")


def processes(pid: int) -> list[str]:
    """The processes of the group `pid` leads (the command and its workers)."""
    out = subprocess.run(["ps", "-g", str(pid), "-o", "pid=,args="], capture_output=True, text=True).stdout
    return [line for line in out.splitlines() if line.strip()]


def cpu_s(pid: int) -> float:
    """CPU seconds process `pid` has used (0 once it is gone)."""
    import psutil

    try:
        t = psutil.Process(pid).cpu_times()
    except psutil.Error:
        return 0.0
    return t.user + t.system


@pytest.mark.parametrize("workers", [1, 2])
def test_sigterm_stops_infer_in_one_line_with_exit_143(tmp_path, workers):
    out = tmp_path / "r.json"
    p = subprocess.Popen([sys.executable, "-m", "galileo", "infer", str(DATA / "none.mp4"), "--scene",
                          str(DATA / "scene.json"), "--tracks", str(DATA / "tracks.json"), "--chains", "2",
                          "--sweeps", "2000", "--workers", str(workers), "--quiet", "--out", str(out)],
                         start_new_session=True, cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(ROOT)},
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    if workers > 1:       # the chains have started in the worker processes
        assert wait_until(lambda: len(processes(p.pid)) > workers or p.poll() is not None, 120), processes(p.pid)
    else:                 # the command has read its inputs and samples (one process busy)
        assert wait_until(lambda: p.poll() is not None or cpu_s(p.pid) > 2.0, 120)
    assert p.poll() is None, p.communicate()
    os.kill(p.pid, signal.SIGTERM)
    stdout, stderr = p.communicate(timeout=120)
    assert (p.returncode, stderr) == (128 + signal.SIGTERM, "galileo: terminated\n"), stderr
    assert stdout == "" and not out.exists()                       # nothing half written
    assert wait_until(lambda: not processes(p.pid), 60), processes(p.pid)
