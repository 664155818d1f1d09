"""The command line: the simulate forms, its JSON, one-line errors with exit code 2."""
import json
import math
import subprocess
import sys

import numpy as np
import pytest

from galileo.cli import main


def run_cli(*args):
    p = subprocess.run([sys.executable, "-m", "galileo", *args], capture_output=True, text=True)
    return p.returncode, p.stdout, p.stderr


def test_simulate_a_scenarios_default_scene_writes_documented_trajectory(tmp_path):
    out = tmp_path / "traj.json"
    assert main(["simulate", "--scenario", "ramp", "--set", "angle_deg=20", "--set", "k1=0.2", "--set", "m1_kg=0.5",
                 "--duration-s", "1.0", "--fps", "30", "--out", str(out)]) == 0
    d = json.loads(out.read_text())
    assert d["fps"] == 30.0 and len(d["time_s"]) == 31 and d["time_s"][1] == pytest.approx(1 / 30)
    obj = d["objects"][0]
    assert obj["name"] == "ramp_object"
    pos, vel = np.array(obj["position_m"]), np.array(obj["velocity_mps"])
    assert pos.shape == vel.shape == (31, 3)
    # Newton: along the fall line a = g (sin - mu cos); x grows, z falls
    th = math.radians(20)
    downhill = np.array([math.cos(th), 0, -math.sin(th)])
    speed = vel @ downhill
    a = np.polyfit(np.array(d["time_s"])[2:12], speed[2:12], 1)[0]
    assert a == pytest.approx(9.81 * (math.sin(th) - 0.2 * math.cos(th)), rel=0.01)


def test_simulate_scene_with_set(tmp_path):
    from galileo.scenarios.ramp.scene import default_scene

    scene_path = tmp_path / "scene.json"
    default_scene(20, target="foam").save(scene_path)
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    assert main(["simulate", "--scene", str(scene_path), "--frames", "40", "--out", str(a)]) == 0
    assert main(["simulate", "--scene", str(scene_path), "--set", "k1=0.34", "--frames", "40", "--out", str(b)]) == 0
    pa = np.array(json.loads(a.read_text())["objects"][0]["position_m"])
    pb = np.array(json.loads(b.read_text())["objects"][0]["position_m"])
    assert len(json.loads(a.read_text())["objects"]) == 2
    assert pa[-1, 0] - pa[0, 0] > pb[-1, 0] - pb[0, 0]  # more friction, less travel


@pytest.mark.parametrize("content, needle", [
    (None, "not found"),
    ("{not json", "not valid JSON"),
    ('{"ramp": {"angle_deg": 20}, "objects": [{"shape": {"type": "box", "size_m": [0.1, 0.1, 0.1]}, '
     '"mass_kg": 0.2, "friction": "high"}]}', "objects[0].friction"),
    ('{"ramp": {"angle_deg": 95}, "objects": []}', "ramp.angle_deg"),
    ('{"ramp": {"angle_deg": 20}, "objects": [{"shape": {"type": "cone", "size_m": [0.1, 0.1, 0.1]}, '
     '"mass_kg": 0.2, "friction": 0.2}]}', "objects[0].shape"),
])
def test_bad_scene_file_is_one_line_exit_2(tmp_path, content, needle):
    path = tmp_path / "scene.json"
    if content is not None:
        path.write_text(content)
    rc, out, err = run_cli("simulate", "--scene", str(path), "--out", str(tmp_path / "t.json"))
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("galileo: error:") and needle in lines[0], err
    assert not (tmp_path / "t.json").exists()


def test_unknown_set_name_is_an_error(tmp_path):
    rc, _, err = run_cli("simulate", "--scenario", "ramp", "--set", "mass=3", "--out", str(tmp_path / "t.json"))
    assert rc == 2 and "unknown name 'mass'" in err and len(err.strip().splitlines()) == 1
