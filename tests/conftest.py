import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

DATA = Path(__file__).resolve().parent / "data"
LATENT_NAMES = ("m1_kg", "k1", "m2_kg", "k2")


@pytest.fixture(scope="session")
def demo_dir(tmp_path_factory):
    """The rendered demo preset (one video), shared by the tests of a session."""
    from galileo.scenarios.ramp.dataset import build

    out = tmp_path_factory.mktemp("demo")
    build("demo", out, seed=0, workers=1, progress=False)
    return out / "demo"


def load_demo_frozen():
    """(scene, tracks, true latent vector in LATENT_NAMES order) of the demo, from the files
    committed under tests/data (see tests/data/README.md): the same numbers on every
    machine. Live tracking of the rendered video differs in the last bits with the OpenBLAS
    kernels NumPy picks for the CPU, and a collision amplifies those bits; tests whose
    assertions are exact or tight physics/likelihood comparisons start from these files."""
    from galileo.datatypes import Tracks
    from galileo.registry import load_scene

    scene = load_scene(DATA / "scene.json")
    tracks = Tracks.load(DATA / "tracks.json")
    truth = json.loads((DATA / "truth.json").read_text())["latents"]
    return scene, tracks, np.array([truth[n] for n in LATENT_NAMES], float)


@pytest.fixture(scope="session")
def demo_frozen():
    """load_demo_frozen(), once per session (treat as read-only)."""
    return load_demo_frozen()


def free_port() -> int:
    """A free TCP port on 127.0.0.1 (for servers the tests start)."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def demo_viewer(demo_dir, session_dir, *, chains: int, seed: int, sweeps: int, target: int | None = None):
    """A controller with `sweeps` rounds done (its sweep target `target`, None: the default)
    and a viewer on it: the frozen demo scene and tracks, the rendered demo video for the
    pictures."""
    from galileo.video import read_video
    from ui.controller import Controller
    from ui.viewer import Viewer

    scene, tracks, _ = load_demo_frozen()
    ctrl = Controller(scene, tracks, chains=chains, seed=seed, workers=1, session_dir=session_dir, sweeps=target)
    if sweeps:
        ctrl.run_sweeps(sweeps)
    video, _ = read_video(demo_dir / "video.mp4")
    return ctrl, Viewer(ctrl, ctrl.likelihood_scene, tracks, video, port=free_port())


def view_basis(initial_camera) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(eye, forward, right, down) of a viser initial camera (world frame, +z up): a pinhole
    view's axes, to project points into a browser's first view."""
    eye, look = np.asarray(initial_camera.position, float), np.asarray(initial_camera.look_at, float)
    fwd = (look - eye) / np.linalg.norm(look - eye)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    return eye, fwd, right, np.cross(fwd, right)


def assert_same_decisions(fast, plain) -> None:
    """Two inference results made the same accept/reject decisions on the same proposals, and
    every fully evaluated proposal has the same log-likelihood (the speed-ups' exactness)."""
    assert np.array_equal(fast.proposals["accepted"], plain.proposals["accepted"])
    assert np.array_equal(fast.samples, plain.samples)
    assert np.array_equal(fast.logliks, plain.logliks)
    assert np.array_equal(fast.proposals["proposal"], plain.proposals["proposal"])
    full = ~fast.proposals["early_stop"]
    assert np.array_equal(fast.proposals["proposal_loglik"][full], plain.proposals["proposal_loglik"][full])


# -- real-browser tests (Debian's chromium driven by Playwright; never `playwright install`) --
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run", "--disable-quic"]
needs_chromium = pytest.mark.skipif(not Path(CHROMIUM).exists(),
                                    reason="Debian chromium not installed (.ci/run installs it)")


def launch_chromium(playwright):
    """Headless Debian chromium (software WebGL)."""
    return playwright.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)


def wait_until(condition, timeout_s: float) -> bool:
    """Poll `condition` (state a server's threads or a page update) until true or timeout."""
    import time

    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True
