"""The spring from the command line: a problem of two videos with a reference end to end, and bad
input refused in one line with exit code 2 (a reference mass of -1, a video where nothing is
released)."""
from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import numpy as np

from galileo import registry
from galileo.scenarios.spring.scene import default_scene


def _galileo(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "galileo", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=600)


def _pair(tmp_path):
    """Two videos' scene and synthetic tracks files: a 110.3 g reference and a 160 g object."""
    sc = registry.get("spring")
    base = dataclasses.replace(default_scene(), n_frames=120, release_frame=2)
    base = dataclasses.replace(base, camera=dataclasses.replace(base.camera, n_frames=120))
    rng = np.random.default_rng(3)
    files = []
    for obj, m, z0 in (("ref", 0.1103, -0.42), ("obj", 0.16, -0.47)):
        s = dataclasses.replace(base, object=obj, mass_kg=m, z0_m=z0)
        s.save(tmp_path / f"{obj}.json")
        sc.synthetic.tracks(s, {"log10_sigma_x_px": 0.0, "log10_sigma_z_px": 0.0, "rho": 0.5}, rng, 0.0).save(
            tmp_path / f"{obj}-tracks.json")
        (tmp_path / f"{obj}.mp4").write_bytes(b"")   # (tracks are given: the video is not read)
        files.append(obj)
    return files


def test_a_reference_mass_of_minus_one_is_refused_in_one_line(tmp_path):
    _pair(tmp_path)
    r = _galileo("infer", "ref.mp4", "obj.mp4", "--scene", "ref.json", "obj.json", "--tracks", "ref-tracks.json",
                 "obj-tracks.json", "--fix", "m_ref_kg=-1", "--out", "r.json", cwd=tmp_path)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "m_ref_kg" in lines[0] and "Traceback" not in r.stderr
    assert not (tmp_path / "r.json").exists()


def test_two_videos_and_a_reference_give_the_mass_and_say_what_is_not_identified(tmp_path):
    _pair(tmp_path)
    r = _galileo("infer", "ref.mp4", "obj.mp4", "--scene", "ref.json", "obj.json", "--tracks", "ref-tracks.json",
                 "obj-tracks.json", "--fix", "m_ref_kg=0.1103", "--chains", "4", "--sweeps", "20", "--workers", "1",
                 "--out", "r.json", "--quiet", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "r.json").read_text())
    # known up to the spring's own mass ms ~ U(0, 0.1): m = r m_ref + (r - 1) ms / 3 with r the squared
    # period ratio, (0.16 + ms_true / 3) / (0.1103 + ms_true / 3)
    ms_true = default_scene().spring_mass_kg
    r_true = (0.16 + ms_true / 3) / (0.1103 + ms_true / 3)
    lo, hi = (r_true * 0.1103 + (r_true - 1) * ms / 3 for ms in (0.0, 0.1))
    assert lo <= doc["posterior"]["m_obj_kg@2"]["q50"] <= hi
    assert set(doc["not_identified"]) == {"ms_spring_kg", "m_obj_kg@2"}


def test_a_video_where_nothing_is_released_is_refused_in_one_line(tmp_path):
    from galileo.video import write_video

    frames = np.full((40, 120, 160, 3), 200, np.uint8)
    frames[:, 50:70, 70:90] = (40, 90, 160)     # a block that never moves
    write_video(tmp_path / "still.mp4", frames, 30.0)
    default_scene().save(tmp_path / "scene.json")
    r = _galileo("track", "still.mp4", "--scene", "scene.json", "--out", "t.json", "--quiet", cwd=tmp_path)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr and "released" in lines[0]
