"""One real-browser test: headless Chromium (Debian's, driven by Playwright) loads the
viewer, the viser client connects, the sample slider is moved in the page, and the server
re-simulates and poses the objects differently."""
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import demo_viewer

CHROMIUM = "/usr/bin/chromium"
pytestmark = pytest.mark.skipif(not Path(CHROMIUM).exists() or shutil.which("chromium") is None,
                                reason="Debian chromium not installed (.ci/run installs it)")


@pytest.fixture(scope="module")
def viewer(demo_dir, tmp_path_factory):
    ctrl, v = demo_viewer(demo_dir, tmp_path_factory.mktemp("session"), chains=2, seed=0, sweeps=4)
    yield v
    v.close()
    ctrl.close()


def test_browser_scrubs_samples_and_the_scene_changes(viewer):
    from playwright.sync_api import sync_playwright

    viewer.set_frame(viewer.n_frames - 1)  # poses at the end show where each sample leads
    chain = int(viewer.chain_dropdown.value)
    viewer.sample_slider.value = 0
    viewer.select_sample(chain, 0)
    with sync_playwright() as p:
        browser = p.chromium.launch(
            executable_path=CHROMIUM, headless=True,
            args=["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                  "--disable-sync", "--no-first-run", "--disable-quic"])
        try:
            page = browser.new_page(viewport={"width": 1024, "height": 768})
            page.goto(viewer.url)
            deadline = time.time() + 60
            while not viewer.server.get_clients() and time.time() < deadline:  # mounted and connected
                time.sleep(0.1)
            assert viewer.server.get_clients(), "the viser client never connected"
            sliders = page.get_by_role("slider")
            sliders.first.wait_for(timeout=30000)
            assert sliders.count() == 2  # Frame, Sample
            before_n, before_pos = viewer.resimulations, np.array(viewer.object_handles[0].position)
            before_sel = viewer.selection.index
            sliders.nth(1).focus()
            for _ in range(3):
                page.keyboard.press("ArrowRight")
            deadline = time.time() + 20
            while viewer.resimulations == before_n and time.time() < deadline:
                time.sleep(0.05)
            time.sleep(0.5)
            assert viewer.resimulations > before_n, "moving the slider did not re-simulate"
            assert viewer.selection.index > before_sel
            after = np.array(viewer.object_handles[0].position)
            samples = viewer.ctrl.samples(chain)
            assert not np.array_equal(samples[before_sel], samples[viewer.selection.index])
            assert np.abs(after - before_pos).max() > 1e-6, "the scene did not change"
        finally:
            browser.close()
