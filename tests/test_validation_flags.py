"""Issue 15, flags and paths: every bad flag, --out or app option is refused in one line
`galileo: error: ...` (the app: `app: error: ...`) with exit code 2, before anything slow and
before any file is written; never a traceback, a hang or a silently changed value."""
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

import app
from conftest import DATA, free_port
from galileo.cli import MAX_FRAMES, main

ROOT = Path(__file__).resolve().parents[1]
SCENE, TRACKS = str(DATA / "scene.json"), str(DATA / "tracks.json")


def refused(capsys, argv, *needles, prog="galileo"):
    """Run galileo (or app.py) in-process: exit code 2 and exactly one stderr line naming the problem."""
    rc = (main if prog == "galileo" else app.main)(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2, (argv, err)
    assert len(err) == 1 and err[0].startswith(f"{prog}: error: "), (argv, err)
    for needle in needles:
        assert needle in err[0], (argv, err[0], needle)
    return err[0]


def infer_args(tmp_path, *extra):
    return ["infer", "video.mp4", "--scene", SCENE, "--tracks", TRACKS, "--chains", "2", "--sweeps", "2", "--quiet",
            "--out", str(tmp_path / "r.json"), *extra]


# -- numbers ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("flag, value, needle", [
    ("--narrow", "-1", "must be above 0"), ("--narrow", "0", "must be above 0"), ("--broad", "nan", "finite"),
    ("--sigma", "nan", "finite"), ("--sigma", "inf", "finite"), ("--sigma", "-0.1", "above 0"),
    ("--seed", "-1", "at least 0"), ("--seed", "1.5", "an integer"), ("--seed", str(2**40), "at most"),
    ("--chains", "0", "at least 1"), ("--chains", "many", "an integer"), ("--sweeps", "1e9", "an integer"),
    ("--sweeps", "1000000000", "at most"), ("--workers", "0", "at least 1"), ("--broad-every", "-2", "at least 0"),
    ("--until-rhat", "1", "above 1"), ("--until-rhat", "nan", "finite"), ("--min-ess", "-5", "at least 0"),
    ("--recognition-move", "0", "at least 1"), ("--warmup", "-1", "at least 0"),
])
def test_infer_numeric_flags_are_refused_while_parsing(tmp_path, capsys, flag, value, needle):
    refused(capsys, infer_args(tmp_path, flag, value), flag, needle)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("extra, needle", [
    (["--sigma", "1e-300"], "sigma_mps must be >"),     # the library's check_noise, before any tracking
    (["--sigma", "1e300"], "sigma_mps must be <="),
    (["--narrow", "1e9"], "prior range"),                # chains that would never move
    (["--broad", "1e300"], "prior range"),
    (["--priors", '{"k1": [1, 0]}'], "k1"),
    (["--priors", '{"a":' * 5000 + "1" + "}" * 5000], "--priors: nested too deeply"),
])
def test_infer_settings_use_the_librarys_checks_before_tracking(tmp_path, capsys, extra, needle):
    refused(capsys, infer_args(tmp_path, *extra), needle)
    assert not (tmp_path / "r.json").exists()


@pytest.mark.parametrize("argv, needle", [
    (["--fps", "0"], "--fps must be above 0"),           # was: silently 30
    (["--fps", "-30"], "--fps must be above 0"),         # was: negative times
    (["--fps", "nan"], "--fps: expected a finite number"),
    (["--duration-s", "inf"], "--duration-s: expected a finite number"),
    (["--duration-s", "-1"], "--duration-s must be above 0"),
    (["--duration-s", "1e6"], f"at most {MAX_FRAMES}"),            # 3e7 frames at 30 fps
    (["--duration-s", "100", "--fps", "1000"], f"at most {MAX_FRAMES}"),
    (["--frames", "1000000000"], f"--frames must be at most {MAX_FRAMES}"),   # was: 44 GiB
    (["--frames", "0"], "--frames must be at least 1"),
    (["--frames", "10", "--duration-s", "1"], "not both"),
    (["--set", "offset_units=nan"], "finite"), (["--set", "k1=inf"], "finite"), (["--set", "k1"], "NAME=VALUE"),
    (["--set", "=3"], "NAME=VALUE"), (["--set", "m1_kg=-1"], "m1_kg"), (["--set", "k1=nan"], "finite"),
    (["--set", "angle_deg=inf"], "finite"), (["--scenario", "nope"], "unknown scenario 'nope'"),
])
def test_simulate_numbers_and_frame_budget(tmp_path, capsys, argv, needle):
    refused(capsys, ["simulate", "--scenario", "ramp", *argv, "--out", str(tmp_path / "t.json")], needle)
    assert not (tmp_path / "t.json").exists()


def test_simulate_values_set_pass_the_scene_files_checks(tmp_path, capsys):
    out = tmp_path / "t.json"
    for argv in (["--set", "m1_kg=1e308"], ["--set", "k1=-3"], ["--set", "angle_deg=95"]):
        refused(capsys, ["simulate", "--scenario", "ramp", *argv, "--out", str(out)])
        assert not out.exists()
    # a valid run still runs, at the rate asked, with times that grow
    assert main(["simulate", "--scenario", "ramp", "--frames", "5", "--fps", "60", "--out", str(out)]) == 0
    d = json.loads(out.read_text())
    assert d["fps"] == 60 and d["time_s"] == pytest.approx([i / 60 for i in range(5)])


@pytest.mark.parametrize("argv, needle", [
    (["dataset", "--seed", "-1", "--out", "{tmp}/ds"], "--seed"),
    (["dataset", "--workers", "0", "--out", "{tmp}/ds"], "--workers"),
    (["experiment", "{tmp}", "--chains", "0", "--out", "{tmp}/x"], "--chains"),
    (["calibrate", "--n", "0", "--out", "{tmp}/c"], "--n"),
    (["calibrate", "--n", "3", "--draws", "-1", "--out", "{tmp}/c"], "--draws"),
    (["recognize", "train", "--dataset", "{tmp}", "--holdout-fold", "9", "--out", "{tmp}/m.npz"],
     "--holdout-fold"),
    (["recognize", "eval", "--dataset", "{tmp}", "--splits", "1", "--out", "{tmp}/e"], "--splits"),
    (["recognize", "label", "--dataset", "{tmp}", "--seed", "x"], "--seed"),
    (["predict", "--result", "{tmp}/r.json", "--angle-deg", "nan"], "--angle-deg"),
    (["predict", "--result", "{tmp}/r.json", "--angle-deg", "95"], "--angle-deg must be in [0, 90)"),
])
def test_every_subcommands_flags(tmp_path, capsys, argv, needle):
    refused(capsys, [a.format(tmp=tmp_path) for a in argv], needle)


# -- paths --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("cmd", ["infer", "simulate", "track", "track-debug"])
@pytest.mark.parametrize("where, needle", [("folder", "is a folder"), ("empty", "empty"),
                                           ("unwritable", "takes no new file"), ("under-a-file", "is not a folder"),
                                           ("trailing-slash", "names a folder")])
def test_out_that_cannot_be_written_is_refused_first(tmp_path, capsys, cmd, where, needle):
    (tmp_path / "afile").write_text("keep me")
    out = {"folder": str(tmp_path), "empty": "", "unwritable": "/proc/no/r.json",
           "under-a-file": str(tmp_path / "afile" / "r.json"), "trailing-slash": str(tmp_path / "new") + "/"}[where]
    argv = {"infer": infer_args(tmp_path)[:-1] + [out],
            "simulate": ["simulate", "--frames", "3", "--out", out],
            "track": ["track", "video.mp4", "--scene", SCENE, "--out", out],
            "track-debug": ["track", "video.mp4", "--scene", SCENE, "--out", str(tmp_path / "t.json"),
                            "--debug-video", out]}[cmd]
    refused(capsys, argv, needle)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]     # nothing written, no probe left behind
    assert (tmp_path / "afile").read_text() == "keep me"


def test_folder_outputs_and_outputs_that_are_inputs(tmp_path, capsys):
    afile = tmp_path / "afile.json"
    afile.write_text("{}")
    refused(capsys, ["dataset", "--out", str(afile)], "is a file; expected a folder")
    refused(capsys, ["report", str(tmp_path), "--out", str(afile)], "is a file")
    refused(capsys, ["calibrate", "--n", "2", "--out", ""], "empty")
    refused(capsys, ["experiment", str(tmp_path), "--out", "/proc/no/x"], "takes no new file")
    # an output that names an input of the same command would destroy it
    scene = tmp_path / "scene.json"
    scene.write_text(Path(SCENE).read_text())
    before = scene.read_text()
    refused(capsys, ["track", "video.mp4", "--scene", str(scene), "--out", str(scene)], "refusing to overwrite")
    refused(capsys, ["simulate", "--scene", str(scene), "--frames", "3", "--out", str(scene)], "refusing to overwrite")
    refused(capsys, ["track", "v.mp4", "--scene", str(scene), "--out", str(tmp_path / "t.json"), "--debug-video",
                     str(tmp_path / "t.json")], "the same file")
    assert scene.read_text() == before


def test_a_system_error_no_check_caught_is_still_one_line(capsys):
    from galileo.errors import run_reporting_errors

    def fails():
        raise IsADirectoryError(21, "Is a directory", "/some/where")

    assert run_reporting_errors("galileo", fails) == 2
    assert capsys.readouterr().err.strip().splitlines() == ["galileo: error: /some/where: Is a directory"]


def test_an_atomic_write_onto_a_folder_names_the_folder_and_leaves_nothing(tmp_path, capsys):
    """`galileo scene --out FOLDER` (its --out is checked only when written): the rename's error
    names the target, not the temporary file, which is gone."""
    from galileo.errors import run_reporting_errors
    from galileo.jsonio import write_json

    (tmp_path / "d").mkdir()
    assert run_reporting_errors("galileo", lambda: write_json(tmp_path / "d", {})) == 2
    assert capsys.readouterr().err.strip().splitlines() == [f"galileo: error: cannot write {tmp_path / 'd'}: "
                                                           "Is a directory"]
    assert [p.name for p in tmp_path.iterdir()] == ["d"] and not list((tmp_path / "d").iterdir())


# -- app.py -------------------------------------------------------------------------------------------

@pytest.mark.parametrize("argv, needle", [
    (["--port", "-1"], "--port must be at least 1"),          # was: a hang
    (["--port", "99999"], "--port must be at most 65535"),    # was: a hang
    (["--port", "http"], "--port: expected an integer"),
    (["--chains", "0"], "--chains"), (["--sweeps", "0"], "--sweeps"),   # was: never pause
    (["--seed", "-1"], "--seed"), (["--workers", "0"], "--workers"),
    (["--until-rhat", "nan"], "--until-rhat"), (["--min-ess", "-1"], "--min-ess"),
    (["--rerun", "bogus"], "--rerun must be off, save, web or connect"),   # was: exit 1
    (["--rerun", "connect"], "--rerun connect needs one URL"),             # was: exit 1
    (["--rerun", "off", "extra"], "takes no URL"),
    (["--name", "x" * 500], "--name"), (["--scenario", "bowling"], "invalid choice"), (["--bogus"], "unrecognized"),
    (["--host", "no-such-host.invalid"], "not an address or a known name"),   # was: a hang
    (["--host", "300.1.2.3"], "not an address or a known name"),
    (["--host", ""], "empty"),
    (["--host", "192.0.2.1"], "not an address of this machine"),       # TEST-NET-1: never this machine's
    (["--video", "{tmp}/none.mp4", "--scene", "{tmp}/none.json"], "--video"),
    (["--session", "{tmp}/no-session"], "--session"),
])
def test_app_refuses_bad_options_before_starting_anything(tmp_path, capsys, monkeypatch, argv, needle):
    def never(args):
        raise AssertionError("run() must not start")

    monkeypatch.setattr(app, "run", never)
    argv = [a.format(tmp=tmp_path) for a in argv]
    refused(capsys, [*argv, "--port", str(free_port())] if "--port" not in argv else argv, needle, prog="app")


def test_app_port_taken_and_host_checks(capsys, monkeypatch):
    from galileo.errors import GalileoError

    monkeypatch.setattr(app, "run", lambda args: 0)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        busy = s.getsockname()[1]
        refused(capsys, ["--port", str(busy)], f"port {busy} on 127.0.0.1 is taken", prog="app")
        with pytest.raises(GalileoError, match="is taken"):
            app.port_is_free("127.0.0.1", busy)
    port = free_port()
    app.port_is_free("127.0.0.1", port)         # free, and a name that resolves to this machine
    app.port_is_free("localhost", port)
    assert app.main(["--port", str(port), "--rerun", "off"]) == 0     # every check passed: run() reached
    args = app.parse_args(["--rerun", "connect", "rerun+http://127.0.0.1:9876/proxy"])
    assert app._rerun_mode(args) == ("connect", "rerun+http://127.0.0.1:9876/proxy")


# -- one line, from the outside ------------------------------------------------------------------------

def test_argparse_errors_are_one_line_exit_2_from_a_shell(tmp_path):
    for cmd in ([sys.executable, "-m", "galileo", "infer", "v.mp4", "--out", "r.json", "--chains", "x"],
                [sys.executable, "-m", "galileo", "recognize", "train", "--dataset", "d"],
                [sys.executable, str(ROOT / "app.py"), "--port", "99999"]):
        p = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path, timeout=60,
                           env={**os.environ, "PYTHONPATH": str(ROOT)})
        lines = p.stderr.strip().splitlines()
        prog = "app" if cmd[1].endswith("app.py") else "galileo"
        assert p.returncode == 2 and len(lines) == 1 and lines[0].startswith(f"{prog}: error: "), (cmd, p.stderr)
        assert p.stdout == ""
