"""Bad inputs (issue 15): a sweep of wrong flags, --out paths, scene, camera, tracks, video,
result, dataset-index and session files, and app.py options, each run as its own process.

Usage (from the repository root):
    python bench/bench_bad_inputs.py [-j 2] [--timeout 60] [--only KIND[,KIND]] [--skip-slow] [--json] [--keep]

Every input is generated here from the demo's frozen files in tests/data/ (scene.json,
tracks.json), a tiny video rendered from that scene (320x240, 61 frames), a result and a
session made from them. Each case runs `python -m galileo ...` (or app.py with --rerun off,
a free port and a private sessions folder; stopped once it prints its viewer URL) with a
time limit and is classified:

    clean      exit 2 and exactly one stderr line `galileo: error: ...` (`app: error: ...`)
    accepted   run (exit 0; the app: served) where that is what a careful user would expect: a
               stray temporary file in a session is cleaned on reopen, a result without its
               redundant latents list, a scene without the optional camera, an experiment that
               records a missing video as failed and goes on (README)
    traceback  a Python traceback on stderr
    hang       still running at the time limit (killed)
    wrong      any other ending: another exit code, or exit 2 with more than one line
    garbage    accepted: exit 0 (the app: serving), or a NaN / infinity in an output file, or an
               output a case checks holds what the input cannot support (a position tracked
               in frames of noise; no note on an object seen in few frames)

A case sent SIGTERM once its first record is written is clean when it ends with exit 143 and
the one line `galileo: terminated`. A case may have its own time limit (the experiment on
1,000 missing videos must answer in seconds) and may be slow (`--skip-slow` leaves those out).
The issue-24 kinds hold item 15 of issue 24 ("the first fifteen minutes"); its `app --session`
on a session without video.mp4 is the session kind's "video.mp4 missing".

A few controls (valid inputs) must run and exit 0, so that a case is refused for its flaw,
not for its setting. Prints a table by kind and every failing case with the command that
reproduces it (in the work folder, kept with --keep or on failures); --json instead prints
every case's record. Exit code 0 when every bad input is refused cleanly.
"""
from __future__ import annotations

import argparse
import copy
import glob
import json
import os
import shlex
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

DATA = ROOT / "tests" / "data"
CLASSES = ("clean", "accepted", "traceback", "hang", "wrong", "garbage")
APP_LAUNCH = """
import pathlib, sys
sys.path.insert(0, sys.argv[1])
import app
app.SESSIONS = pathlib.Path(sys.argv[2])
raise SystemExit(app.main(sys.argv[3:]))
"""
DELETE = object()
NOISE_FROM = 30          # tiny-noise.mp4: frames from this one on are noise
LONG_FRAMES = 20_000     # tiny-20000.mp4
MISSING_VIDEOS = 1000    # dataset-missing/index.json lists this many videos, none there
MISSING_TIMEOUT_S = 30   # ... and must be refused within this (it took 100-322 s to fail them one by one)


@dataclass
class Case:
    kind: str
    name: str
    args: list[str]              # after `galileo` (or app.py); {W}: the assets folder, {O}: this case's own folder
    prog: str = "galileo"        # or "app"
    expect: str = "refuse"       # "accept": a valid input that must run (exit 0; the app: serve);
    #                              "either": accepting it is documented behaviour, refusing it cleanly is fine too
    outputs: list[str] = field(default_factory=list)   # files checked for NaN / infinity
    gone: list[str] = field(default_factory=list)      # files that must be gone afterwards (expect "accept")
    timeout: float | None = None   # its own time limit (default: --timeout)
    slow: bool = False             # minutes, not seconds (left out by --skip-slow)
    sigterm_after: str | None = None   # a glob under {O}: once it matches, SIGTERM goes to the command
    check: Callable[[Path, str], str | None] | None = None   # (its folder, stdout) -> what is wrong with an
    #                                                           accepted run's outputs, or None


# -- assets ------------------------------------------------------------------------------------------

def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def make_assets(w: Path) -> dict:
    """The valid inputs every case mutates: scene (frozen demo, and its camera at 320x240),
    tracks, a rendered video and its variants, a result, a session, a dataset folder."""
    import numpy as np

    from galileo import registry
    from galileo.datatypes import Tracks
    from galileo.scenarios.ramp.render import render_to_video
    from galileo.video import read_video, write_video

    w.mkdir(parents=True, exist_ok=True)
    scene = json.loads((DATA / "scene.json").read_text())
    tracks = json.loads((DATA / "tracks.json").read_text())
    tiny = copy.deepcopy(scene)
    cam = tiny["camera"]
    cam["K"] = [[280.0, 0.0, 160.0], [0.0, 280.0, 120.0], [0.0, 0.0, 1.0]]
    cam["width_px"], cam["height_px"] = 320, 240
    (w / "scene.json").write_text(json.dumps(scene, indent=1))
    (w / "tiny-scene.json").write_text(json.dumps(tiny, indent=1))
    (w / "tracks.json").write_text(json.dumps(tracks))
    traj = render_to_video(registry.scene_from_json(tiny), w / "tiny.mp4", cam["n_frames"])
    frames, _ = read_video(w / "tiny.mp4")
    write_video(w / "tiny-15fps.mp4", frames, 15.0)
    write_video(w / "tiny-60fps.mp4", frames, 60.0)
    write_video(w / "tiny-short.mp4", frames[:30], 30.0)
    write_video(w / "tiny-long.mp4", np.concatenate([frames, frames[-1:].repeat(60, 0)]), 30.0)
    write_video(w / "tiny-small.mp4", frames[:, ::2, ::2], 30.0)
    write_video(w / "tiny-one.mp4", frames[:1], 30.0)
    # issue 24: the second half noise; 20,000 frames (the motion, then the last frame held) at 160x120
    noise = np.random.default_rng(0).integers(0, 256, frames[NOISE_FROM:].shape, dtype=np.uint8)
    write_video(w / "tiny-noise.mp4", np.concatenate([frames[:NOISE_FROM], noise]), 30.0)
    small = frames[:, ::2, ::2]
    write_video(w / "tiny-20000.mp4", (small[min(i, len(small) - 1)] for i in range(LONG_FRAMES)), 30.0)
    long_scene = copy.deepcopy(tiny)
    long_scene["camera"]["K"] = [[140.0, 0.0, 80.0], [0.0, 140.0, 60.0], [0.0, 0.0, 1.0]]
    long_scene["camera"].update(width_px=160, height_px=120, n_frames=LONG_FRAMES)
    (w / "tiny-20000-scene.json").write_text(json.dumps(long_scene, indent=1))
    (w / "not-a-video.mp4").write_text("this is text, not a video\n")
    (w / "empty.mp4").write_bytes(b"")
    (w / "a-folder").mkdir(exist_ok=True)
    (w / "afile.txt").write_text("keep me\n")
    (w / "deep.json").write_text("[" * 100_000 + "]" * 100_000)

    # a result, and a session (two chains, two sweeps) on the frozen scene and tracks
    from galileo.cli import main as galileo_main

    rc = galileo_main(["infer", str(w / "tiny.mp4"), "--scene", str(w / "scene.json"), "--tracks",
                       str(w / "tracks.json"), "--chains", "2", "--sweeps", "4", "--workers", "1", "--quiet",
                       "--out", str(w / "result.json")])
    assert rc == 0, "the valid result could not be made"
    from ui.controller import Controller

    sess = w / "session"
    sess.mkdir(exist_ok=True)
    ctrl = Controller(registry.scene_from_json(scene), Tracks.from_json(tracks), chains=2, seed=0, workers=1,
                      session_dir=sess)
    ctrl.run_sweeps(2)
    ctrl.close()
    import shutil

    shutil.copyfile(w / "tiny.mp4", sess / "video.mp4")

    # a dataset folder whose index points at the tiny video, with its truth (for experiment's checks)
    ds = w / "dataset"
    (ds / "v1").mkdir(parents=True, exist_ok=True)
    shutil.copyfile(w / "tiny.mp4", ds / "v1" / "video.mp4")
    (ds / "v1" / "scene.json").write_text(json.dumps(tiny, indent=1))
    truth = {**json.loads((DATA / "truth.json").read_text()), "trajectory": traj.to_json()}
    (ds / "v1" / "truth.json").write_text(json.dumps(truth))
    (ds / "index.json").write_text(json.dumps({"preset": "demo", "seed": 0, "videos": [{"name": "v1"}]}))
    # three videos (to stop a run between them), and an index of 1,000 videos that are not there
    ds3 = w / "dataset3"
    for name in ("v1", "v2", "v3"):
        shutil.copytree(ds / "v1", ds3 / name, dirs_exist_ok=True)
    (ds3 / "index.json").write_text(json.dumps({"videos": [{"name": n} for n in ("v1", "v2", "v3")]}))
    (w / "dataset-missing").mkdir(exist_ok=True)
    (w / "dataset-missing" / "index.json").write_text(json.dumps({"videos": [{"name": f"v{i:04d}"}
                                                                            for i in range(MISSING_VIDEOS)]}))
    splash = registry.get("splash").default_scene().to_json()
    (w / "splash-scene.json").write_text(json.dumps(splash, indent=1))
    return {"scene": scene, "tiny": tiny, "tracks": tracks, "result": json.loads((w / "result.json").read_text()),
            "splash": splash}


def mutated(doc, path: tuple, value):
    d = copy.deepcopy(doc)
    node = d
    for k in path[:-1]:
        node = node[k]
    if value is DELETE:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return d


def write(w: Path, name: str, doc=None, text: str | None = None) -> str:
    p = w / "gen" / name
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(text if text is not None else json.dumps(doc, indent=1, allow_nan=True))
    return str(p)


# -- the cases ---------------------------------------------------------------------------------------

def cases(w: Path, a: dict) -> list[Case]:
    out: list[Case] = []

    def add(kind, name, args, **kw):
        out.append(Case(kind, name, [str(x) for x in args], **kw))

    S, T, V, TS = "{W}/scene.json", "{W}/tracks.json", "{W}/tiny.mp4", "{W}/tiny-scene.json"
    R = "{W}/result.json"
    sim = ["simulate", "--target", "none", "--frames", "5", "--out", "{O}/t.json"]
    infer = ["infer", V, "--scene", S, "--tracks", T, "--chains", "2", "--sweeps", "2", "--workers", "1", "--quiet",
             "--out", "{O}/r.json"]

    # controls: valid inputs that must run
    add("control", "simulate quick form", sim, expect="accept", outputs=["{O}/t.json"])
    add("control", "simulate a scene file", ["simulate", "--scene", S, "--frames", "5", "--out", "{O}/t.json"],
        expect="accept", outputs=["{O}/t.json"])
    add("control", "track the tiny video", ["track", V, "--scene", TS, "--quiet", "--out", "{O}/t.json"], expect="accept",
        outputs=["{O}/t.json"])
    add("control", "infer on frozen tracks", infer, expect="accept", outputs=["{O}/r.json"])
    add("control", "predict", ["predict", "--result", R, "--angle-deg", "30", "--target-outcome", "--out", "{O}/p.json"],
        expect="accept", outputs=["{O}/p.json"])
    add("control", "app reopens the session", ["--session", "{W}/session"], prog="app", expect="accept")

    # -- flags of every subcommand --
    for flag, vals in (("--fps", ["0", "-30", "nan", "inf", "1e9"]), ("--duration-s", ["inf", "nan", "-1", "0", "1e7"]),
                       ("--frames", ["0", "-5", "1000000000", "1.5", "x"])):
        for v in vals:
            args = [x for x in sim if x not in ("--frames", "5")] + [flag, v]
            add("flags:simulate", f"{flag} {v}", args)
    for flag, v in (("--mass", "-1"), ("--mass", "nan"), ("--mass", "0"), ("--mass", "1e308"), ("--friction", "-0.1"),
                    ("--friction", "nan"), ("--friction", "1e9"), ("--angle-deg", "95"), ("--angle-deg", "-10"),
                    ("--angle-deg", "nan"), ("--target", "bogus")):
        add("flags:simulate", f"quick form {flag} {v}", sim + [flag, v])
    for v in ("m1_kg=1e308", "m1_kg=-1", "m1_kg=nan", "k1=-1", "k1=nan", "k1=1e9", "e1=5", "offset_units=nan",
              "offset_units=1.5", "offset_units=1e9", "angle_deg=89", "bogus=1", "k1", "=1", "k1=abc"):
        add("flags:simulate", f"--set {v}", ["simulate", "--scene", S, "--frames", "5", "--set", v, "--out", "{O}/t.json"],
            outputs=["{O}/t.json"])
    add("flags:simulate", "--frames with --duration-s", sim + ["--duration-s", "1"])
    add("flags:simulate", "quick flags with --scene", ["simulate", "--scene", S, "--mass", "1", "--out", "{O}/t.json"])

    for flag, vals in (("--chains", ["0", "-1", "x", "1e9", "1000000000"]), ("--sweeps", ["0", "1000000000"]),
                       ("--seed", ["-1", "1.5", str(2**64)]), ("--workers", ["0", "-1", "1000000"]),
                       ("--sigma", ["nan", "inf", "0", "-1", "1e-300", "1e300"]),
                       ("--narrow", ["-1", "0", "nan", "1e300"]), ("--broad", ["nan", "0", "-1", "1e300"]),
                       ("--broad-every", ["-1", "1.5"]), ("--warmup", ["-1", "1000"]),
                       ("--until-rhat", ["1", "0.5", "nan"]), ("--min-ess", ["-1", "nan"]),
                       ("--recognition-move", ["0"]), ("--init", ["bogus"]), ("--moves", ["bogus"]),
                       ("--priors", ["not json", "[1]", '{"k1": [1, 0]}', '{"k1": "x"}', '{"m1_kg": [0, 1e9]}',
                                     '{"bogus": [0, 1]}', '{"a":' * 5000 + "1" + "}" * 5000])):
        for v in vals:
            add("flags:infer", f"{flag} {v if len(v) < 40 else v[:12] + ' ... (nested 5000 deep)'}", infer + [flag, v],
                outputs=["{O}/r.json"])
    add("flags:infer", "--max-sweeps without --until-rhat", infer + ["--max-sweeps", "10"])
    add("flags:infer", "--max-sweeps below --sweeps", infer + ["--until-rhat", "1.01", "--max-sweeps", "1"])
    add("flags:infer", "--model without --init recognition", infer + ["--model", "{W}/afile.txt"])
    add("flags:infer", "--scheduler for one video", infer + ["--scheduler", "tcp://127.0.0.1:1"])
    add("flags:infer", "no --scene", ["infer", V, "--out", "{O}/r.json"])
    add("flags:infer", "a folder without videos", ["infer", "{W}/a-folder", "--quiet", "--out", "{O}/x"])
    add("flags:infer", "a folder, --out a file", ["infer", "{W}/dataset", "--quiet", "--out", "{W}/afile.txt"])
    add("flags:infer", "a folder, --tracks", ["infer", "{W}/dataset", "--tracks", T, "--quiet", "--out", "{O}/x"])
    add("flags:infer", "a folder, --chains 0", ["infer", "{W}/dataset", "--chains", "0", "--quiet", "--out", "{O}/x"])
    add("flags:infer", "a folder, --sigma 1e-300", ["infer", "{W}/dataset", "--sigma", "1e-300", "--quiet", "--out",
                                                     "{O}/x"])

    for flag, v in (("--seed", "-1"), ("--seed", "x"), ("--workers", "0"), ("--preset", "bogus"), ("--scenario", "bogus")):
        add("flags:dataset", f"{flag} {v}", ["dataset", "--out", "{O}/ds", flag, v])
    for name, args in (("missing video", ["track", "{W}/none.mp4", "--scene", TS]),
                       ("video is a folder", ["track", "{W}/a-folder", "--scene", TS]),
                       ("missing scene", ["track", V, "--scene", "{W}/none.json"]),
                       ("scene is a folder", ["track", V, "--scene", "{W}/a-folder"])):
        add("flags:track", name, args + ["--quiet", "--out", "{O}/t.json"])
    for flag, v in (("--angle-deg", "nan"), ("--angle-deg", "95"), ("--angle-deg", "-1"), ("--angle-deg", "inf")):
        add("flags:predict", f"{flag} {v}", ["predict", "--result", R, flag, v])
    add("flags:predict", "no question", ["predict", "--result", R])
    add("flags:predict", "missing result", ["predict", "--result", "{W}/none.json", "--target-outcome"])
    add("flags:predict", "--scene bad file", ["predict", "--result", R, "--scene", "{W}/afile.txt"])
    ex = ["experiment", "{W}/dataset", "--out", "{O}/x", "--quiet"]
    for flag, v in (("--chains", "0"), ("--sweeps", "0"), ("--seed", "-1"), ("--workers", "0"), ("--moves", "x"),
                    ("--slurm", "{W}/afile.txt"), ("--priors", "[1]")):
        add("flags:experiment", f"{flag} {v}", ex + [flag, v])
    add("flags:experiment", "missing dataset", ["experiment", "{W}/none", "--out", "{O}/x"])
    add("flags:report", "missing table", ["report", "{W}/none.csv", "--out", "{O}/rep"])
    add("flags:report", "table is text", ["report", "{W}/afile.txt", "--out", "{O}/rep"])
    cb = ["calibrate", "--out", "{O}/c", "--quiet"]
    for extra in (["--n", "0"], ["--n", "-1"], ["--n", "2", "--chains", "0"], ["--n", "2", "--draws", "0"],
                  ["--n", "2", "--seed", "-1"], ["--n", "2", "--workers", "0"], ["--n", "2", "--scenario", "bogus"],
                  ["--n", "2", "--max-sweeps", "5"], ["--videos", "{W}/none"], ["--n", "2", "--scenes", "{W}/afile.txt"],
                  ["--n", "2", "--sweeps", "0"], ["--n", "2", "--until-rhat", "0.9"]):
        add("flags:calibrate", " ".join(extra), cb + extra)
    for name, args in (("train --holdout-fold 9", ["recognize", "train", "--dataset", "{W}/dataset", "--holdout-fold",
                                                     "9", "--out", "{O}/m.npz"]),
                       ("train --holdout-fold -2", ["recognize", "train", "--dataset", "{W}/dataset", "--holdout-fold",
                                                      "-2", "--out", "{O}/m.npz"]),
                       ("eval --splits 1", ["recognize", "eval", "--dataset", "{W}/dataset", "--splits", "1", "--out",
                                            "{O}/e"]),
                       ("label --chains 0", ["recognize", "label", "--dataset", "{W}/dataset", "--chains", "0"]),
                       ("label missing dataset", ["recognize", "label", "--dataset", "{W}/none"]),
                       ("predict missing scene", ["recognize", "predict", V, "--scene", "{W}/none.json"]),
                       ("predict model is text", ["recognize", "predict", V, "--scene", TS, "--model", "{W}/afile.txt"]),
                       ("no step", ["recognize"])):
        add("flags:recognize", name, args)
    scn = ["scene", V, "--ramp-px", "100,60 220,60 260,200 60,200", "--ramp-length-m", "0.9", "--ramp-width-m", "0.3",
           "--angle-deg", "20"]
    add("flags:scene", "--angle-deg nan", scn + ["--angle-deg", "nan", "--out", "{O}/s.json"])
    add("flags:scene", "--ramp-px two numbers", scn + ["--ramp-px", "1,2", "--out", "{O}/s.json"])
    add("flags:scene", "--ramp-length-m -1", scn + ["--ramp-length-m", "-1", "--out", "{O}/s.json"])
    add("flags:scene", "--out a folder", scn + ["--start-m", "0.5", "--out", "{W}/a-folder"])
    add("flags:scene", "--out its own video", scn[:1] + ["{O}/v.mp4"] + scn[2:] + ["--out", "{O}/v.mp4"])
    for name, args in (("no command", []), ("unknown command", ["bogus"]), ("unknown flag", ["simulate", "--bogus"]),
                       ("missing --out", ["simulate"]), ("choice", ["dataset", "--preset", "huge", "--out", "{O}/d"]),
                       ("scenarios extra", ["scenarios", "extra"])):
        add("flags:argparse", name, args)

    # -- --out paths --
    bad_files = {"a folder": "{W}/a-folder", "empty": "", "unwritable": "/proc/none/x.json",
                 "under a file": "{W}/afile.txt/x.json", "trailing slash": "{O}/new/", "dot": "."}
    for name, o in bad_files.items():
        add("out", f"infer --out {name}", infer[:-1] + [o])
        add("out", f"simulate --out {name}", sim[:-1] + [o])
        add("out", f"track --out {name}", ["track", V, "--scene", TS, "--quiet", "--out", o])
        add("out", f"track --debug-video {name}", ["track", V, "--scene", TS, "--quiet", "--out", "{O}/t.json",
                                                   "--debug-video", o])
        add("out", f"predict --out {name}", ["predict", "--result", R, "--target-outcome", "--out", o])
    for name, o in (("an existing file", "{W}/afile.txt"), ("empty", ""), ("unwritable", "/proc/none/d")):
        add("out", f"dataset --out {name}", ["dataset", "--out", o, "--quiet"])
        add("out", f"experiment --out {name}", ["experiment", "{W}/dataset", "--out", o, "--quiet"])
        add("out", f"report --out {name}", ["report", "{W}/dataset", "--out", o])
        add("out", f"calibrate --out {name}", ["calibrate", "--n", "1", "--out", o])
    for name, o in (("a folder", "{W}/a-folder"), ("unwritable", "/proc/none/m.npz")):
        add("out", f"recognize train --out {name}", ["recognize", "train", "--dataset", "{W}/dataset", "--labels",
                                                     "oracle", "--quiet", "--out", o])
        add("out", f"recognize predict --out {name}", ["recognize", "predict", V, "--scene", TS, "--out", o])
    add("out", "recognize eval --out a file", ["recognize", "eval", "--dataset", "{W}/dataset", "--quiet", "--out",
                                               "{W}/afile.txt"])
    add("out", "track --out its own --scene", ["track", V, "--scene", "{O}/scene.json", "--quiet", "--out",
                                               "{O}/scene.json"], outputs=[])
    add("out", "infer --out its own --tracks", infer[:-1] + ["{W}/tracks.json"])
    add("out", "predict --out its own --result", ["predict", "--result", "{O}/result.json", "--target-outcome", "--out",
                                                   "{O}/result.json"])

    # -- scene files (loaded by simulate; the same loader serves track, infer, the app) --
    sc = a["scene"]
    for name, path, v in (
            ("mass -1", ("objects", 0, "mass_kg"), -1), ("mass NaN", ("objects", 0, "mass_kg"), float("nan")),
            ("mass 1e308", ("objects", 0, "mass_kg"), 1e308), ("mass string", ("objects", 0, "mass_kg"), "heavy"),
            ("friction -0.5", ("objects", 0, "friction"), -0.5), ("friction 1e9", ("objects", 0, "friction"), 1e9),
            ("restitution 5", ("objects", 0, "restitution"), 5), ("restitution -1", ("objects", 0, "restitution"), -1),
            ("size 2 elements", ("objects", 0, "shape", "size_m"), [0.1, 0.1]),
            ("size negative", ("objects", 0, "shape", "size_m"), [0.1, -0.1, 0.1]),
            ("size 1e6", ("objects", 0, "shape", "size_m"), [1e6, 1e6, 1e6]),
            ("shape cone", ("objects", 0, "shape", "type"), "cone"), ("shape missing", ("objects", 0, "shape"), DELETE),
            ("offset 1.5", ("objects", 0, "offset_units"), 1.5), ("offset 1e9", ("objects", 0, "offset_units"), 10**9),
            ("distance 1e9", ("objects", 1, "distance_m"), 1e9), ("distance -1", ("objects", 1, "distance_m"), -1),
            ("gravity 1e9", ("gravity_mps2",), 1e9), ("gravity NaN", ("gravity_mps2",), float("nan")),
            ("gravity negative", ("gravity_mps2",), -9.81),
            ("sim_hz 2.4e8", ("sim_hz",), 2.4e8), ("sim_hz 0", ("sim_hz",), 0), ("sim_hz 1.5", ("sim_hz",), 1.5),
            ("angle 95", ("ramp", "angle_deg"), 95), ("angle NaN", ("ramp", "angle_deg"), float("nan")),
            ("ramp length 0", ("ramp", "length_m"), 0), ("ramp length 1e9", ("ramp", "length_m"), 1e9),
            ("unit_m 0", ("unit_m",), 0), ("start_units -5", ("start_units",), -5), ("start_units 1e9", ("start_units",), 1e9),
            ("duplicate names", ("objects", 1, "name"), "ramp_object"), ("no objects", ("objects",), []),
            ("objects not a list", ("objects",), {"a": 1}), ("role bogus", ("objects", 0, "role"), "bogus"),
            ("prior low >= high", ("priors", "k1"), [1.0, 0.0]), ("prior wrong type", ("priors", "k1"), "wide"),
            ("prior NaN", ("priors", "m1_kg"), [float("nan"), 1.0]), ("prior unknown latent", ("priors", "bogus"), [0, 1]),
            ("priors shape_types bogus", ("priors", "shape_types"), ["cone"]),
            ("scenario bogus", ("scenario",), "bowling"), ("scenario number", ("scenario",), 3),
            ("version 99", ("version",), 99)):
        add("scene", name, ["simulate", "--scene", write(w, f"scene/{name}.json", mutated(sc, path, v)), "--frames", "5",
                            "--out", "{O}/t.json"], outputs=["{O}/t.json"])
    for name, text in (("empty file", ""), ("not JSON", "{not json"), ("a list", "[1, 2]"), ("a number", "3"),
                       ("binary", "\x00\x01\x02"), ("nested 100000 deep", None)):
        p = "{W}/deep.json" if text is None else write(w, f"scene/{name}.json", text=text)
        add("scene", name, ["simulate", "--scene", p, "--frames", "5", "--out", "{O}/t.json"])
    sp = a["splash"]
    for key in [k for k, v in sp.items() if isinstance(v, (int, float)) and not isinstance(v, bool)][:6]:
        add("scene", f"splash {key} NaN", ["simulate", "--scene", write(w, f"scene/splash-{key}-nan.json",
                                                                           mutated(sp, (key,), float("nan"))),
                                           "--frames", "5", "--out", "{O}/t.json"], outputs=["{O}/t.json"])
        add("scene", f"splash {key} -1", ["simulate", "--scene", write(w, f"scene/splash-{key}-neg.json",
                                                                          mutated(sp, (key,), -1)),
                                          "--frames", "5", "--out", "{O}/t.json"], outputs=["{O}/t.json"])

    # -- camera (loaded with the scene; tracking is where it matters) --
    ti = a["tiny"]
    mirror = copy.deepcopy(ti["camera"]["world_to_camera"])
    mirror[0] = [-x for x in mirror[0][:3]] + [mirror[0][3]]
    stretched = copy.deepcopy(ti["camera"]["world_to_camera"])
    stretched[0] = [2 * x for x in stretched[0][:3]] + [stretched[0][3]]
    for name, path, v in (
            ("K singular", ("camera", "K"), [[280, 0, 160], [0, 0, 120], [0, 0, 1]]),
            ("K strings", ("camera", "K"), [["280", "0", "160"], ["0", "280", "120"], ["0", "0", "1"]]),
            ("K 2x2", ("camera", "K"), [[280, 0], [0, 280]]), ("K negative focal", ("camera", "K"),
                                                                 [[-280, 0, 160], [0, -280, 120], [0, 0, 1]]),
            ("K NaN", ("camera", "K"), [[float("nan"), 0, 160], [0, 280, 120], [0, 0, 1]]),
            ("world_to_camera mirrored", ("camera", "world_to_camera"), mirror),
            ("world_to_camera stretched", ("camera", "world_to_camera"), stretched),
            ("width 0", ("camera", "width_px"), 0), ("width 1e9", ("camera", "width_px"), 10**9),
            ("fps 0", ("camera", "fps"), 0), ("fps NaN", ("camera", "fps"), float("nan")), ("fps -30", ("camera", "fps"), -30),
            ("n_frames 0", ("camera", "n_frames"), 0), ("n_frames 1e7", ("camera", "n_frames"), 10**7),
            ("n_frames 1.5", ("camera", "n_frames"), 1.5), ("camera missing", ("camera",), DELETE)):
        add("camera", name, ["track", V, "--scene", write(w, f"camera/{name}.json", mutated(ti, path, v)), "--quiet",
                             "--out", "{O}/t.json"], outputs=["{O}/t.json"])

    # -- videos against the scene's camera --
    for name, vid in (("15 fps against 30", "tiny-15fps.mp4"), ("60 fps against 30", "tiny-60fps.mp4"),
                      ("30 frames against 61", "tiny-short.mp4"), ("121 frames against 61", "tiny-long.mp4"),
                      ("160x120 against 320x240", "tiny-small.mp4"), ("one frame", "tiny-one.mp4"),
                      ("text named .mp4", "not-a-video.mp4"), ("empty file", "empty.mp4")):
        add("video", f"track: {name}", ["track", "{W}/" + vid, "--scene", TS, "--quiet", "--out", "{O}/t.json"],
            outputs=["{O}/t.json"])
    add("video", "infer (tracks it): 15 fps against 30", ["infer", "{W}/tiny-15fps.mp4", "--scene", TS, "--chains", "2",
                                                          "--sweeps", "2", "--workers", "1", "--quiet", "--out",
                                                          "{O}/r.json"], outputs=["{O}/r.json"])

    # -- tracks files (infer --tracks) --
    tr = a["tracks"]
    n = len(tr["time_s"])
    o0 = ("objects", 0)
    nan_vel = copy.deepcopy(tr)
    nan_vel["objects"][0]["velocity_mps"][5] = [float("nan")] * 3
    short = copy.deepcopy(tr)
    short["objects"][0]["position_m"] = short["objects"][0]["position_m"][:10]
    zero = copy.deepcopy(tr)
    zero["time_s"] = []
    for o in zero["objects"]:
        o["position_m"], o["velocity_mps"], o["visible"] = [], [], []
    unseen = copy.deepcopy(tr)
    for o in unseen["objects"]:
        o["visible"] = [False] * n
        o["position_m"] = o["velocity_mps"] = [None] * n
    tracks_cases = [
        ("lists of different lengths", short), ("0 frames", zero), ("nothing visible", unseen),
        ("NaN velocity in a visible frame", nan_vel),
        ("visible 'yes'", mutated(tr, o0 + ("visible",), "yes")),
        ("visible ['false', ...]", mutated(tr, o0 + ("visible",), ["false"] * n)),
        ("visible numbers", mutated(tr, o0 + ("visible",), [2] * n)),
        ("shape cone", mutated(tr, o0 + ("shape", "type"), "cone")),
        ("size 2 elements", mutated(tr, o0 + ("shape", "size_m"), [0.05, 0.05])),
        ("size negative", mutated(tr, o0 + ("shape", "size_m"), [0.05, -0.05, 0.05])),
        ("offset 1.5", mutated(tr, o0 + ("offset_units",), 1.5)),
        ("offset 'four'", mutated(tr, o0 + ("offset_units",), "four")),
        ("fps 0", mutated(tr, ("fps",), 0)), ("fps NaN", mutated(tr, ("fps",), float("nan"))),
        ("fps -30", mutated(tr, ("fps",), -30)), ("fps '30'", mutated(tr, ("fps",), "30")),
        ("fps 15 against the scene's 30", mutated(tr, ("fps",), 15.0)),
        ("no objects", mutated(tr, ("objects",), [])), ("objects missing", mutated(tr, ("objects",), DELETE)),
        ("role bogus", mutated(tr, o0 + ("role",), "bogus")),
        ("duplicate names", mutated(tr, ("objects", 1, "name"), "ramp_object")),
        ("position string", mutated(tr, o0 + ("position_m", 3), "here")),
        ("position 2 numbers", mutated(tr, o0 + ("position_m", 3), [0.1, 0.2])),
        ("position 1e300", mutated(tr, o0 + ("position_m", 3), [1e300, 0, 0])),
        ("notes a number", mutated(tr, ("notes",), 3)),
    ]
    for name, doc in tracks_cases:
        add("tracks", name, infer[:5] + [write(w, f"tracks/{name}.json", doc)] + infer[6:], outputs=["{O}/r.json"])
    for name, text in (("empty file", ""), ("not JSON", "{"), ("a list", "[]")):
        add("tracks", name, infer[:5] + [write(w, f"tracks/{name}.json", text=text)] + infer[6:])
    add("tracks", "nested 100000 deep", infer[:5] + ["{W}/deep.json"] + infer[6:])
    add("tracks", "a trajectory instead", infer[:5] + [write(w, "tracks/trajectory.json", {"fps": 30, "time_s": [0],
                                                                                        "objects": [{"name": "x"}]})]
        + infer[6:])

    # -- result files (predict) --
    res = a["result"]
    other = copy.deepcopy(res)
    other["samples_file"] = "../elsewhere/none.samples.npz"
    for name, doc in (("samples file elsewhere", other), ("samples file absolute", mutated(res, ("samples_file",),
                                                                                             "/etc/passwd")),
                      ("map lacks a latent", mutated(res, ("map", "k1"), DELETE)),
                      ("map NaN", mutated(res, ("map", "k1"), float("nan"))), ("map string", mutated(res, ("map", "k1"), "x")),
                      ("no scene", mutated(res, ("scene",), DELETE)), ("scene broken", mutated(res, ("scene", "objects"), 3)),
                      ("scenario bogus", mutated(res, ("scenario",), "bowling")), ("latents missing", mutated(res, ("latents",),
                                                                                                             DELETE)),
                      ("a list", [1, 2])):
        p = write(w, f"result/{name}/result.json", doc)
        src = w / "result.samples.npz"
        (Path(p).parent / "result.samples.npz").write_bytes(src.read_bytes())
        add("result", name, ["predict", "--result", p, "--angle-deg", "30", "--target-outcome"])
    p = write(w, "result/truncated npz/result.json", res)
    (Path(p).parent / "result.samples.npz").write_bytes((w / "result.samples.npz").read_bytes()[:100])
    add("result", "truncated samples npz", ["predict", "--result", p, "--angle-deg", "30", "--target-outcome"])
    p = write(w, "result/npz is text/result.json", res)
    (Path(p).parent / "result.samples.npz").write_text("not an npz")
    add("result", "samples npz is text", ["predict", "--result", p, "--angle-deg", "30", "--target-outcome"])
    add("result", "nested 100000 deep", ["predict", "--result", "{W}/deep.json", "--target-outcome"])

    # -- dataset index (experiment) --
    for name, text in (("not JSON", "{"), ("a list", "[]"), ("videos missing", '{"preset": "demo"}'),
                       ("videos a number", '{"videos": 3}'), ("no videos", '{"videos": []}'),
                       ("entry without a name", '{"videos": [{}]}'), ("entry a number", '{"videos": [3]}'),
                       ("video that does not exist", '{"videos": [{"name": "none"}]}'),
                       ("name climbs out", '{"videos": [{"name": "../../etc"}]}'),
                       ("scenario bogus", '{"scenario": "bowling", "videos": [{"name": "v1"}]}')):
        d = w / "gen" / "index" / name
        (d / "v1").mkdir(parents=True, exist_ok=True)
        for f in ("video.mp4", "scene.json", "truth.json"):
            (d / "v1" / f).write_bytes((w / "dataset" / "v1" / f).read_bytes())
        (d / "index.json").write_text(text)
        add("dataset-index", name, ["experiment", str(d), "--chains", "2", "--sweeps", "2", "--workers", "1",
                                    "--quiet", "--out", "{O}/x"])

    # -- app.py options --
    for name, args in (("--port -1", ["--port", "-1"]), ("--port 99999", ["--port", "99999"]), ("--port 0", ["--port", "0"]),
                       ("--port http", ["--port", "http"]), ("--host invalid address", ["--host", "300.1.2.3"]),
                       ("--host unknown name", ["--host", "no-such-host.invalid"]),
                       ("--host not this machine", ["--host", "192.0.2.1"]), ("--host empty", ["--host", ""]),
                       ("--chains 0", ["--chains", "0"]), ("--chains -1", ["--chains", "-1"]),
                       ("--sweeps 0", ["--sweeps", "0"]), ("--seed -1", ["--seed", "-1"]), ("--workers 0", ["--workers", "0"]),
                       ("--rerun bogus", ["--rerun", "bogus"]), ("--rerun connect without URL", ["--rerun", "connect"]),
                       ("--rerun off extra", ["--rerun", "off", "extra"]), ("--until-rhat 0.5", ["--until-rhat", "0.5"]),
                       ("--min-ess -1", ["--until-rhat", "1.01", "--min-ess", "-1"]),
                       ("--max-sweeps without --until-rhat", ["--max-sweeps", "100"]), ("--name 500 chars", ["--name", "x" * 500]),
                       ("--video missing", ["--video", "{W}/none.mp4", "--scene", TS]),
                       ("--scene missing", ["--video", V, "--scene", "{W}/none.json"]), ("--video without --scene", ["--video", V]),
                       ("--scene bad", ["--video", V, "--scene", "{W}/afile.txt"]),
                       ("--upload with --video", ["--upload", "--video", V, "--scene", TS]),
                       ("--model without --init", ["--model", "{W}/afile.txt"]),
                       ("--init recognition, model is text", ["--init", "recognition", "--model", "{W}/afile.txt"]),
                       ("--session with --moves", ["--session", "{W}/session", "--moves", "paper"]),
                       ("--scenario bogus", ["--scenario", "bowling"]), ("unknown flag", ["--bogus"])):
        add("app", name, args, prog="app")

    # -- damaged sessions (app.py --session) --
    import shutil

    from ui import session as sess

    def damaged(name, fn):
        d = w / "gen" / "sessions" / name
        if d.exists():
            shutil.rmtree(d)
        shutil.copytree(w / "session", d)
        fn(d)
        add("session", name, ["--session", str(d)], prog="app")

    for f in sess.FILES + ("video.mp4",):
        damaged(f"{f} missing", lambda d, f=f: (d / f).unlink())
    for f in (sess.SCENE_FILE, sess.TRACKS_FILE, sess.SETTINGS_FILE, sess.EVENTS_FILE, sess.CHAINS_FILE):
        damaged(f"{f} not JSON", lambda d, f=f: (d / f).write_text("{"))
        damaged(f"{f} a list", lambda d, f=f: (d / f).write_text("[]"))
    damaged("record.npz truncated", lambda d: (d / sess.RECORD_FILE).write_bytes((d / sess.RECORD_FILE).read_bytes()[:200]))
    damaged("video.mp4 is text", lambda d: (d / "video.mp4").write_text("not a video"))

    def edit(f, fn):
        def go(d):
            doc = json.loads((d / f).read_text())
            fn(doc)
            (d / f).write_text(json.dumps(doc, allow_nan=True))
        return go

    damaged("scene without a camera", edit(sess.SCENE_FILE, lambda s: s.pop("camera")))
    damaged("scene mass NaN", edit(sess.SCENE_FILE, lambda s: s["objects"][0].__setitem__("mass_kg", float("nan"))))
    damaged("chains names differ", edit(sess.CHAINS_FILE, lambda s: s.__setitem__("names", ["a", "b"])))
    damaged("chains n_events too many", edit(sess.CHAINS_FILE, lambda s: s.__setitem__("n_events", 10**6)))
    damaged("chains seed -1", edit(sess.CHAINS_FILE, lambda s: s.__setitem__("seed", -1)))
    damaged("chains empty list", edit(sess.CHAINS_FILE, lambda s: s.__setitem__("chains", [])))
    damaged("settings sigma NaN", edit(sess.SETTINGS_FILE, lambda s: s.update({k: float("nan") for k in s
                                                                               if k.startswith("sigma")})))
    damaged("settings narrow 0", edit(sess.SETTINGS_FILE, lambda s: s.__setitem__("narrow", 0)))
    damaged("events not a list", edit(sess.EVENTS_FILE, lambda s: s.__setitem__("events", 3)))
    damaged("tracks fps 0", edit(sess.TRACKS_FILE, lambda s: s.__setitem__("fps", 0)))
    damaged("a stray .tmp file", lambda d: (d / ".events.json.k2j4h5x_.tmp").write_text("{"))
    add("session", "a file, not a folder", ["--session", "{W}/afile.txt"], prog="app")
    add("session", "an empty folder", ["--session", "{W}/a-folder"], prog="app")
    out[[c.name for c in out].index("a stray .tmp file")].expect = "accept"
    out[[c.name for c in out].index("a stray .tmp file")].gone = ["{W}/gen/sessions/a stray .tmp file/.events.json.k2j4h5x_.tmp"]
    for kind, name in (("session", "scene without a camera"), ("result", "latents missing"),
                       ("dataset-index", "video that does not exist")):
        out[[(c.kind, c.name) for c in out].index((kind, name))].expect = "either"
    add("session", "missing", ["--session", "{W}/none"], prog="app")

    # -- issue 24, item 15 (its `app --session` without video.mp4 is the session kind's "video.mp4 missing";
    #    its `infer --chains 1 --sweeps 100000` progress is no bad input) --
    g0 = write(w, "issue24/gravity 0.json", mutated(sc, ("gravity_mps2",), 0))
    add("issue24:infer", "scene gravity_mps2 0", infer[:3] + [g0] + infer[4:], outputs=["{O}/r.json"])
    light = write(w, "issue24/mass 1e-18.json", mutated(sc, ("objects", 0, "mass_kg"), 1e-18))
    add("issue24:infer", "scene mass 1e-18 kg", infer[:3] + [light] + infer[4:], outputs=["{O}/r.json"])
    add("issue24:simulate", "scene mass 1e-18 kg", ["simulate", "--scene", light, "--frames", "5", "--out", "{O}/t.json"],
        outputs=["{O}/t.json"])
    add("issue24:simulate", "scene target mass 1e-20 kg",
        ["simulate", "--scene", write(w, "issue24/target mass 1e-20.json", mutated(sc, ("objects", 1, "mass_kg"), 1e-20)),
         "--frames", "5", "--out", "{O}/t.json"], outputs=["{O}/t.json"])
    add("issue24:simulate", "--set m1_kg=1e-18", ["simulate", "--scene", S, "--frames", "5", "--set", "m1_kg=1e-18",
                                                  "--out", "{O}/t.json"], outputs=["{O}/t.json"])
    add("issue24:simulate", "splash density 1e-300 g/cm^3",
        ["simulate", "--scene", write(w, "issue24/splash density.json", mutated(sp, ("object", "density_g_cm3"), 1e-300)),
         "--frames", "5", "--out", "{O}/t.json"], outputs=["{O}/t.json"])
    identity = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
    add("issue24:track", "world_to_camera the identity",
        ["track", V, "--scene", write(w, "issue24/identity camera.json", mutated(ti, ("camera", "world_to_camera"), identity)),
         "--quiet", "--out", "{O}/t.json"], outputs=["{O}/t.json"])

    def seen_in_noise(o: Path, stdout: str) -> str | None:
        """Frames of noise (from NOISE_FROM on) tracked as visible: positions invented."""
        tracks = json.loads((o / "t.json").read_text())
        seen = {t["name"]: sum(t["visible"][NOISE_FROM:]) for t in tracks["objects"]}
        invented = {k: v for k, v in seen.items() if v}
        return f"positions in frames of noise: {invented}" if invented else None

    add("issue24:track", "second half of the video noise", ["track", "{W}/tiny-noise.mp4", "--scene", TS, "--quiet",
                                                            "--out", "{O}/t.json"],
        expect="either", outputs=["{O}/t.json"], check=seen_in_noise)

    def noted(o: Path, stdout: str) -> str | None:
        """An object seen in few of 20,000 frames must come with a note (printed, and in the tracks)."""
        tracks = json.loads((o / "t.json").read_text())
        if "note: " in stdout and tracks.get("notes"):
            return None
        return "no note: " + stdout.strip().splitlines()[0][:200] if stdout.strip() else "no note"

    add("issue24:track", f"{LONG_FRAMES} frames, the object seen in few",
        ["track", "{W}/tiny-20000.mp4", "--scene", "{W}/tiny-20000-scene.json", "--quiet", "--out", "{O}/t.json"],
        expect="either", outputs=["{O}/t.json"], check=noted, timeout=600, slow=True)
    add("issue24:experiment", f"index listing {MISSING_VIDEOS} missing videos",
        ["experiment", "{W}/dataset-missing", "--chains", "2", "--sweeps", "2", "--quiet", "--out", "{O}/x"],
        timeout=MISSING_TIMEOUT_S)
    add("issue24:experiment", "SIGTERM after the first record",
        ["experiment", "{W}/dataset3", "--chains", "2", "--sweeps", "2", "--workers", "1", "--quiet", "--out", "{O}/x"],
        sigterm_after="{O}/x/records/*.json", timeout=300)
    return out


# -- running and classifying -------------------------------------------------------------------------

class _NonFinite(Exception):
    pass


def _refuse_constant(name: str):
    raise _NonFinite(name)


def has_nonfinite(path: Path) -> bool:
    """A JSON output holding NaN or +-Infinity (json.loads accepts them; JSON has none)."""
    if not path.is_file():
        return False
    try:
        json.loads(path.read_text(), parse_constant=_refuse_constant)
    except _NonFinite:
        return True
    except (OSError, ValueError, RecursionError):
        return False
    return False


def fill(s: str, w: Path, o: Path) -> str:
    return s.replace("{W}", str(w)).replace("{O}", str(o))


def kill_group(p: subprocess.Popen, sig=signal.SIGKILL) -> None:
    try:
        os.killpg(p.pid, sig)     # the process started here and its workers (a group of its own)
    except ProcessLookupError:
        pass


def run_case(i: int, c: Case, w: Path, timeout: float) -> dict:
    o = w / "out" / f"{i:03d}"
    o.mkdir(parents=True, exist_ok=True)
    if "{O}/scene.json" in " ".join(c.args):
        (o / "scene.json").write_bytes((w / "tiny-scene.json").read_bytes())
    if "{O}/v.mp4" in " ".join(c.args):
        (o / "v.mp4").write_bytes((w / "tiny.mp4").read_bytes())
    if "{O}/result.json" in " ".join(c.args):
        (o / "result.json").write_bytes((w / "result.json").read_bytes())
        (o / "result.samples.npz").write_bytes((w / "result.samples.npz").read_bytes())
    args = [fill(x, w, o) for x in c.args]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}
    if c.prog == "app":
        port = free_port()
        full = [sys.executable, "-c", APP_LAUNCH, str(ROOT), str(o / "sessions"), "--rerun", "off", "--port", str(port),
                "--workers", "1", *args]
        shown = ["python", str(ROOT / "app.py"), "--rerun", "off", "--port", str(port), "--workers", "1", *args]
    else:
        full = [sys.executable, "-m", "galileo", *args]
        shown = ["galileo", *args]
    t0 = time.monotonic()
    p = subprocess.Popen(full, cwd=o, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         start_new_session=True)
    out_lines: list[str] = []
    err_chunks: list[str] = []
    serving = threading.Event()

    def read_out():
        for line in p.stdout:
            out_lines.append(line)
            if line.startswith("viewer: "):
                serving.set()

    def read_err():
        err_chunks.append(p.stderr.read())

    readers = [threading.Thread(target=read_out, daemon=True), threading.Thread(target=read_err, daemon=True)]
    for t in readers:
        t.start()
    hung = False
    timeout = c.timeout or timeout
    signalled = False
    while True:
        if p.poll() is not None:
            break
        if c.sigterm_after and not signalled and glob.glob(fill(c.sigterm_after, w, o)):
            p.send_signal(signal.SIGTERM)     # the command alone, as `kill PID` does
            signalled = True
        if serving.is_set():         # the app accepted its options and serves: stop it as Ctrl-C would
            p.send_signal(signal.SIGINT)
            try:
                p.wait(30)
            except subprocess.TimeoutExpired:
                kill_group(p)
                p.wait()
            break
        if time.monotonic() - t0 > timeout:
            hung = True
            kill_group(p)
            p.wait()
            break
        time.sleep(0.05)
    for t in readers:
        t.join(5)
    kill_group(p)                    # any worker left behind
    wall = time.monotonic() - t0
    err = "".join(err_chunks)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    # the one right way to end: refused (exit 2, one line), or stopped by the SIGTERM sent (exit 143, one line)
    code, prefix = (143, f"{c.prog}: terminated") if c.sigterm_after else (2, f"{c.prog}: error: ")
    nonfinite = [fill(f, w, o) for f in c.outputs if has_nonfinite(Path(fill(f, w, o)))]
    accepted = serving.is_set() or (p.returncode == 0 and not hung)
    left = [fill(f, w, o) for f in c.gone if Path(fill(f, w, o)).exists()]
    problem = None
    if c.check is not None and accepted and not nonfinite:
        try:
            problem = c.check(o, "".join(out_lines))
        except (OSError, ValueError, KeyError, TypeError) as e:
            problem = f"its output cannot be checked ({type(e).__name__}: {e})"
    if hung and not serving.is_set():
        cls = "hang"
    elif "Traceback (most recent call last)" in err:
        cls = "traceback"
    elif nonfinite or problem:
        cls = "garbage"
    elif accepted:
        cls = "accepted" if c.expect in ("accept", "either") and not left and not c.sigterm_after else "garbage"
    elif p.returncode == code and len(lines) == 1 and lines[0].startswith(prefix):
        cls = "clean" if c.expect != "accept" else "wrong"
    else:
        cls = "wrong"
    if c.kind == "control":
        cls = "ok" if cls == "accepted" else f"control failed ({cls})"
    last = lines[-1] if lines else ""
    return {"kind": c.kind, "name": c.name, "class": cls, "rc": p.returncode, "serving": serving.is_set(),
            "wall_s": round(wall, 2), "stderr_lines": len(lines), "stderr_last": last[:300],
            "nonfinite_outputs": nonfinite, "left_behind": left, "problem": problem,
            "command": f"cd {o} && " + shlex.join(shown)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-j", "--jobs", type=int, default=2, help="cases run at once (default 2)")
    ap.add_argument("--timeout", type=float, default=60.0, help="seconds before a case counts as a hang")
    ap.add_argument("--only", help="comma-separated kinds (e.g. flags:infer,out,app)")
    ap.add_argument("--skip-slow", action="store_true", help="leave out the cases that take minutes")
    ap.add_argument("--workdir", help="work folder (default: a new temporary one)")
    ap.add_argument("--keep", action="store_true", help="keep the work folder even when every case passes")
    ap.add_argument("--json", action="store_true", help="every case's record as JSON")
    args = ap.parse_args()
    w = Path(args.workdir) if args.workdir else Path(tempfile.mkdtemp(prefix="galileo-bad-inputs-"))
    t0 = time.monotonic()
    import contextlib
    import io

    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assets = make_assets(w / "assets")     # (what the setup's inference prints)
    all_cases = cases(w / "assets", assets)
    if args.only:
        kinds = set(args.only.split(","))
        all_cases = [c for c in all_cases if c.kind in kinds or c.kind.split(":")[0] in kinds or c.kind == "control"]
    if args.skip_slow:
        all_cases = [c for c in all_cases if not c.slow]
    setup_s = time.monotonic() - t0
    with ThreadPoolExecutor(args.jobs) as pool:
        results = list(pool.map(lambda ic: run_case(ic[0], ic[1], w / "assets", args.timeout), enumerate(all_cases)))
    wall = time.monotonic() - t0
    bad = [r for r in results if r["kind"] != "control"]
    failing = [r for r in results if r["class"] not in ("clean", "accepted", "ok")]
    if args.json:
        print(json.dumps({"workdir": str(w), "setup_s": round(setup_s, 1), "wall_s": round(wall, 1),
                          "counts": {k: sum(r["class"] == k for r in bad) for k in CLASSES},
                          "controls_failed": sum(r["kind"] == "control" and r["class"] != "ok" for r in results),
                          "cases": results}, indent=1))
    else:
        kinds = sorted({r["kind"] for r in bad}, key=lambda k: [c.kind for c in all_cases].index(k))
        print(f"{len(bad)} bad inputs in {wall:.0f} s (setup {setup_s:.0f} s, {args.jobs} at once, time limit "
              f"{args.timeout:g} s); work folder {w}")
        print(f"{'kind':<18}{'cases':>6}" + "".join(f"{k:>10}" for k in CLASSES))
        for k in kinds + ["total"]:
            rs = bad if k == "total" else [r for r in bad if r["kind"] == k]
            print(f"{k:<18}{len(rs):>6}" + "".join(f"{sum(r['class'] == c for r in rs):>10}" for c in CLASSES))
        controls = [r for r in results if r["kind"] == "control"]
        print(f"controls: {sum(r['class'] == 'ok' for r in controls)}/{len(controls)} ran")
        if failing:
            print("\nfailing cases:")
            for r in failing:
                print(f"- [{r['class']}] {r['kind']}: {r['name']} (exit {r['rc']}, {r['wall_s']} s)\n    {r['command']}"
                      f"\n    stderr: {r['stderr_last']}"
                      + (f"\n    NaN/infinity in: {', '.join(r['nonfinite_outputs'])}" if r["nonfinite_outputs"] else "")
                      + (f"\n    wrong output: {r['problem']}" if r["problem"] else "")
                      + (f"\n    left behind: {', '.join(r['left_behind'])}" if r["left_behind"] else ""))
    if not failing and not args.keep and not args.workdir:
        import shutil

        shutil.rmtree(w, ignore_errors=True)
    return 0 if not failing else 1


if __name__ == "__main__":
    raise SystemExit(main())
