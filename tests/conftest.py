import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


@pytest.fixture(scope="session")
def demo_dir(tmp_path_factory):
    """The rendered demo preset (one video), shared by the tests of a session."""
    from galileo.scenarios.ramp.dataset import build

    out = tmp_path_factory.mktemp("demo")
    build("demo", out, seed=0, workers=1, progress=False)
    return out / "demo"


def free_port() -> int:
    """A free TCP port on 127.0.0.1 (for servers the tests start)."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def demo_viewer(demo_dir, session_dir, *, chains: int, seed: int, sweeps: int):
    """A controller with `sweeps` rounds done and a viewer on it, for the demo video."""
    from galileo.scenarios.ramp.scene import Scene
    from galileo.tracking import track
    from galileo.video import read_video
    from ui.controller import Controller
    from ui.viewer import Viewer

    scene = Scene.load(demo_dir / "scene.json")
    tracks = track(demo_dir / "video.mp4", scene, progress=False)
    ctrl = Controller(scene, tracks, chains=chains, seed=seed, workers=1, session_dir=session_dir)
    ctrl.run_sweeps(sweeps)
    video, _ = read_video(demo_dir / "video.mp4")
    return ctrl, Viewer(ctrl, ctrl.likelihood_scene, tracks, video, port=free_port())
