"""The fall from the command line: two videos of one object on one surface as one problem (the pair's
restitution and friction shared by name) end to end, mass named as not identified; bad input refused
in one line with exit code 2 (a video where nothing falls, a release inside the table)."""
from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest

from galileo import registry
from galileo.scenarios.fall.scene import default_scene


def _galileo(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "galileo", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=600)


def _one_line(r) -> str:
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2, r.stderr
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    return lines[0]


@pytest.mark.slow
def test_two_drops_of_one_pair_share_e_and_mu_end_to_end(tmp_path):
    """Synthetic tracks of two drops of one block on one table: one problem; e and mu are shared (one
    latent each, with an answer inside their priors), the release states are per video, and the mass
    is named as not identified. (How well e is found: bench/, BENCHMARKS.md.)"""
    sc = registry.get("fall")
    rng = np.random.default_rng(2)
    for i, (z0, x0) in enumerate(((0.30, -0.15), (0.22, -0.05))):
        s = dataclasses.replace(default_scene(), restitution=0.5, friction=0.4, z0_m=z0, x0_m=x0, roll0_rad=0.03,
                                pitch0_rad=0.0, wy0_radps=0.3)
        s.save(tmp_path / f"s{i}.json")
        sc.synthetic.tracks(s, {"log10_sigma_px": 0.3, "rho": 0.5}, rng, 0.0).save(tmp_path / f"t{i}.json")
        (tmp_path / f"v{i}.mp4").write_bytes(b"")    # (tracks are given: the video is not read)
    r = _galileo("infer", "v0.mp4", "v1.mp4", "--scene", "s0.json", "s1.json", "--tracks", "t0.json", "t1.json",
                 "--chains", "4", "--sweeps", "20", "--workers", "1", "--out", "r.json", "--quiet", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "r.json").read_text())
    names = doc["latents"]
    assert "e_block_table" in names and "mu_block_table" in names and "e_block_table@2" not in names
    assert "z0_m@1" in names and "z0_m@2" in names
    post = doc["posterior"]["e_block_table"]
    assert 0.02 <= post["q05"] <= post["q50"] <= post["q95"] <= 0.95
    assert list(doc["not_identified"]) == ["m_block_kg"]


def test_a_video_where_nothing_falls_is_refused_in_one_line(tmp_path):
    from galileo.video import write_video

    frames = np.full((40, 180, 320, 3), 200, np.uint8)
    frames[:, 80:100, 140:170] = (40, 90, 160)     # a block that never moves
    write_video(tmp_path / "still.mp4", frames, 30.0)
    s = default_scene()
    s = dataclasses.replace(s, camera=dataclasses.replace(s.camera, width_px=320, height_px=180))
    s.save(tmp_path / "scene.json")
    r = _galileo("infer", "still.mp4", "--scene", "scene.json", "--out", "r.json", "--quiet", cwd=tmp_path)
    assert "falls" in _one_line(r)
    assert not (tmp_path / "r.json").exists()


def test_a_release_inside_the_table_is_refused_in_one_line(tmp_path):
    r = _galileo("simulate", "--scenario", "fall", "--set", "z0_m=0.005", "--out", "t.json", cwd=tmp_path)
    assert "inside the surface" in _one_line(r)
