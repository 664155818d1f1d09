"""Real-browser tests of `python app.py --upload` (issue 14, "bring your own video"): headless
Chromium (Debian's, driven by Playwright) uploads a small rendered ramp video through the page's
file input, clicks the ramp's four points on the canvas where the true camera projects them,
enters the numbers, sees the reprojection error, starts, and the same page then shows the
viewer (its viser client reconnects by itself) with the chains' samples coming in; the session
folder is one like any other, its camera the true one. Wrong clicks, a file that is not a video,
one over the size cap and one that does not decode give a visible message in the page."""
import html
import json
import os
import re
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT, free_port, launch_chromium, needs_chromium, wait_until

browser_test = needs_chromium

W, H, N_FRAMES = 320, 240, 30
LENGTH_M, WIDTH_M, ANGLE_DEG, UPPER_AT_M = 0.9, 0.3, 20.0, 0.7   # the upper corners are out of this frame
TEST_CAP_BYTES = 100_000     # the error test's upload cap (the app's is 500 MB)


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """(video path, true scene): 1 s of the demo's block sliding down the ramp at 320x240."""
    from galileo.camera import look_at_camera
    from galileo.render import Look
    from galileo.scenarios.ramp.render import render_to_video
    from galileo.scenarios.ramp.scene import default_scene

    cam = look_at_camera((-0.2, -1.2, 0.3), (-0.2, 0.0, 0.16), focal_px=280.0, width_px=W, height_px=H,
                         n_frames=N_FRAMES)
    scene = default_scene(ANGLE_DEG, friction=0.2, target="none", camera=cam)
    path = tmp_path_factory.mktemp("clip") / "ramp-clip.mp4"
    render_to_video(scene, path, N_FRAMES, look=Look.random(np.random.default_rng(1)))
    return path, scene


def true_points(scene) -> np.ndarray:
    from galileo.scenarios.ramp.clicks import ramp_points_in_world

    return scene.camera.project(ramp_points_in_world(LENGTH_M, WIDTH_M, ANGLE_DEG, UPPER_AT_M))


# -- the app in a subprocess (its own main thread: signals; sessions under tmp) ---------------------

LAUNCH = """
import pathlib, sys
sys.path.insert(0, sys.argv[1])
import app, ui.calibrate
app.SESSIONS = pathlib.Path(sys.argv[2])
ui.calibrate.MAX_UPLOAD_BYTES = int(sys.argv[3])
raise SystemExit(app.main(sys.argv[4:]))
"""


class App:
    def __init__(self, tmp: Path, cap_bytes: int = 500 * 1024 * 1024):
        self.sessions = tmp / "sessions"
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.log = tmp / "app.log"
        self.proc = subprocess.Popen(
            [sys.executable, "-c", LAUNCH, str(ROOT), str(self.sessions), str(cap_bytes), "--upload", "--port",
             str(self.port), "--rerun", "off", "--chains", "2", "--sweeps", "3", "--workers", "1"],
            stdout=self.log.open("w"), stderr=subprocess.STDOUT, cwd=tmp)
        deadline = time.monotonic() + 60
        while not self._listening():
            assert self.proc.poll() is None, f"the app exited: {self.output()}"
            assert time.monotonic() < deadline, f"the app never listened: {self.output()}"
            time.sleep(0.2)

    def _listening(self) -> bool:
        # a full HTTP request: a bare TCP probe makes the websocket server log a failed handshake
        try:
            with urllib.request.urlopen(self.url, timeout=2) as r:
                return r.status == 200
        except OSError:
            return False

    def output(self) -> str:
        return self.log.read_text()

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(60)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.proc.returncode


def open_page(browser, app):
    page = browser.new_page(viewport={"width": 1024, "height": 768})
    page.goto(app.url)
    page.get_by_role("button", name="Upload video").wait_for(timeout=60000)
    return page


def close_notifications(page) -> None:
    """Notifications float over the canvas's top left: close them before clicking there."""
    for _ in range(10):
        buttons = page.locator(".mantine-Notification-root button")
        if buttons.count() == 0:
            return
        try:
            buttons.first.click(timeout=2000)
        except Exception:   # noqa: BLE001 - it closed by itself meanwhile
            pass
        page.wait_for_timeout(300)


def upload(page, files) -> None:
    page.locator("input[type=file]").set_input_files(files)


def click_pixel(page, u: float, v: float) -> None:
    """Click the frame's pixel (u, v): the page letterboxes the frame (drawn `display_scale`
    times enlarged) into the canvas, stretched to it; viser reports a click at canvas pixel x
    as (x + 0.5) / width."""
    from ui.calibrate import display_scale, letterbox

    box = page.locator("canvas").first.bounding_box()
    s = display_scale(W, H)
    pw, ph, left, top = letterbox(W * s, H * s, box["width"] / box["height"])
    x = (u * s + left) / pw * box["width"] - 0.5
    y = (v * s + top) / ph * box["height"] - 0.5
    page.mouse.click(box["x"] + x, box["y"] + y)


def wait_text(locator, pattern: str, timeout_s: float = 30) -> str:
    deadline = time.monotonic() + timeout_s
    text = ""
    while time.monotonic() < deadline:
        try:
            text = locator.inner_text(timeout=1000)
        except Exception:   # noqa: BLE001 - not there yet (the viewer reconnecting)
            text = ""
        if re.search(pattern, text):
            return text
        time.sleep(0.2)
    raise AssertionError(f"never matched {pattern!r}; last text {text!r}")


def field(page, label: str):
    """The input beside a label (viser's text inputs are not tied to their label's `for`)."""
    return page.locator(f'xpath=//label[normalize-space()="{label}"]/ancestor::*[.//input][1]//input').first


def fill(page, label: str, value) -> None:
    field(page, label).fill(str(value))
    field(page, label).press("Tab")


@browser_test
def test_upload_calibrate_and_infer_in_the_browser(clip, tmp_path):
    from playwright.sync_api import expect, sync_playwright

    from galileo.registry import load_scene

    video, truth = clip
    uv = true_points(truth)
    app = App(tmp_path)
    t0 = time.monotonic()
    try:
        with sync_playwright() as p:
            browser = launch_chromium(p)
            try:
                page = open_page(browser, app)
                upload(page, str(video))
                info = wait_text(page.locator(".galileo-upload"), r"ramp-clip\.mp4: 320x240")
                assert f"{N_FRAMES} frames at 30 fps" in info
                guide = page.locator(".galileo-guide")
                wait_text(guide, "Click point 1 of 4: upper near")
                close_notifications(page)
                for i, (u, v) in enumerate(uv):
                    click_pixel(page, u, v)
                    wait_text(guide, f"Click point {i + 2} of 4" if i < 3 else "All 4 points placed")
                fill(page, "Length (m)", LENGTH_M)
                fill(page, "Width (m)", WIDTH_M)
                fill(page, "Angle (deg)", ANGLE_DEG)
                fill(page, "Upper at (m)", UPPER_AT_M)
                result = wait_text(page.locator(".galileo-calib"),
                                   r"reprojection error [\d.]+ px.*object found in the first frame")
                err_px = float(re.search(r"reprojection error ([\d.]+) px", result).group(1))
                assert err_px < 1.0, result           # clicks land within a CSS pixel of the truth
                page.screenshot(path=str(tmp_path / "calibration.png"))
                start = page.get_by_role("button", name="Start inference")
                expect(start).to_be_enabled(timeout=30000)
                start.click()
                # the same page reconnects to the viewer; the chains' samples come in
                status = page.get_by_text(re.compile(r"running / 2 chains"))
                wait_text(status.first, r"/ 2 chains, [1-9]\d* sweeps", timeout_s=240)
                page.screenshot(path=str(tmp_path / "viewer.png"))
            finally:
                browser.close()
        sessions = [d for d in app.sessions.iterdir() if not d.name.startswith(".")]
        assert len(sessions) == 1 and sessions[0].name.endswith("-ramp-clip"), sessions
        session = sessions[0]
        for f in ("video.mp4", "scene.json", "tracks.json", "chains.json", "record.npz"):
            assert (session / f).exists(), f
        chains = json.loads((session / "chains.json").read_text())
        assert chains, "no chains recorded"
        # the scene calibrated in the browser is the camera the video was rendered with
        mine = load_scene(session / "scene.json")
        assert np.linalg.norm(mine.camera.position_in_world - truth.camera.position_in_world) < 0.02
        assert mine.camera.K[0, 0] == pytest.approx(truth.camera.K[0, 0], rel=0.03)
        assert (mine.camera.width_px, mine.camera.height_px, mine.camera.n_frames) == (W, H, N_FRAMES)
        assert mine.start_distance_m() == pytest.approx(truth.start_distance_m(), abs=0.03)
        assert not (app.sessions / ".uploads").exists() or not any((app.sessions / ".uploads").iterdir())
    finally:
        code = app.stop()
        print(f"upload flow: {time.monotonic() - t0:.1f} s")
    assert code == 0, app.output()
    assert "Traceback" not in app.output(), app.output()


@browser_test
def test_wrong_clicks_and_wrong_files_say_so_in_the_browser(clip, tmp_path):
    from playwright.sync_api import expect, sync_playwright

    video, truth = clip
    uv = true_points(truth)
    app = App(tmp_path, cap_bytes=TEST_CAP_BYTES)
    try:
        with sync_playwright() as p:
            browser = launch_chromium(p)
            try:
                page = open_page(browser, app)
                line = page.locator(".galileo-upload")
                start = page.get_by_role("button", name="Start inference")
                red = "rgb(201, 42, 42)"
                # not a video: refused by its type before it is received
                upload(page, {"name": "notes.txt", "mimeType": "text/plain", "buffer": b"mass and friction\n"})
                text = wait_text(line, "is not a video")
                assert text.startswith("notes.txt (text/plain) is not a video")
                assert line.evaluate("e => getComputedStyle(e).color") == red
                page.locator(".mantine-Notification-root", has_text="is not a video").first.wait_for(state="attached", timeout=30000)
                # over the cap: refused when the transfer starts, and the button works again
                upload(page, {"name": "big.mp4", "mimeType": "video/mp4", "buffer": os.urandom(2 * TEST_CAP_BYTES)})
                wait_text(line, r"big\.mp4 is 195\.3 KB, over the 97\.7 KB cap")
                page.screenshot(path=str(tmp_path / "refused.png"))
                expect(page.get_by_role("button", name="Upload video")).to_be_enabled(timeout=30000)
                # a video's name and type but not a video inside
                upload(page, {"name": "broken.mp4", "mimeType": "video/mp4", "buffer": b"\x00" * 5000})
                wait_text(line, r"cannot read video broken\.mp4")
                expect(start).to_be_disabled(timeout=30000)
                # a real one, then clicks out of order: upper far first
                upload(page, str(video))
                wait_text(line, r"ramp-clip\.mp4: 320x240")
                guide = page.locator(".galileo-guide")
                wait_text(guide, "Click point 1 of 4")
                fill(page, "Upper at (m)", UPPER_AT_M)
                close_notifications(page)
                for i, (u, v) in enumerate(uv[[1, 0, 2, 3]]):
                    click_pixel(page, u, v)
                    wait_text(guide, f"Click point {i + 2} of 4" if i < 3 else "All 4 points placed")
                calib = page.locator(".galileo-calib")
                text = wait_text(calib, "cross over")
                assert "upper near, upper far, foot far, foot near" in text
                assert calib.evaluate("e => getComputedStyle(e).color") == red
                page.screenshot(path=str(tmp_path / "wrong-order.png"))
                expect(start).to_be_disabled(timeout=30000)
                # Undo twice, then a click in the letterbox beside the frame: refused, said so
                for _ in range(2):
                    page.get_by_role("button", name="Undo last point").click()
                wait_text(guide, "Click point 3 of 4: foot far")
                close_notifications(page)
                box = page.locator("canvas").first.bounding_box()
                if box["width"] / box["height"] < W / H:    # bars above and below the frame
                    click_pixel(page, W / 2, -10)
                else:                                        # bars beside it
                    click_pixel(page, -10, H / 2)
                wait_text(guide, r"outside the 320x240 frame")
                assert wait_until(lambda: len(field(page, "Points (px)").input_value().split()) == 2, 30)
                # three on a line
                page.get_by_role("button", name="Clear points").click()
                wait_text(guide, "Click point 1 of 4")
                pts = " ".join(f"{u:.1f},{v:.1f}" for u, v in [uv[0], (uv[0] + uv[2]) / 2, uv[2], uv[3]])
                fill(page, "Points (px)", pts)
                wait_text(calib, "on one line")
                expect(start).to_be_disabled(timeout=30000)
                # and right again: Start becomes enabled
                fill(page, "Points (px)", " ".join(f"{u:.2f},{v:.2f}" for u, v in uv))
                wait_text(calib, r"reprojection error")
                expect(start).to_be_enabled(timeout=30000)
                page.screenshot(path=str(tmp_path / "errors.png"))
            finally:
                browser.close()
    finally:
        code = app.stop()
    assert code == 130, app.output()       # stopped while calibrating: "app: interrupted"
    assert "Traceback" not in app.output(), app.output()
    assert not any(d for d in app.sessions.iterdir() if not d.name.startswith(".")), "no session without a start"


# -- the page's pieces without a browser ---------------------------------------------------------

def test_uploads_are_checked_by_type_and_size_before_they_are_received():
    from galileo.errors import GalileoError
    from ui.calibrate import MAX_UPLOAD_BYTES, check_upload

    check_upload("ramp.MOV", "", 10)                         # by its extension
    check_upload("clip", "video/mp4", MAX_UPLOAD_BYTES)      # or its type; the cap itself is allowed
    for args, needle in ((("notes.txt", "text/plain", 10), "notes.txt (text/plain) is not a video"),
                         (("ramp.mp4", "video/mp4", MAX_UPLOAD_BYTES + 1), "over the 500 MB cap"),
                         (("ramp.mp4", "video/mp4", 0), "is empty")):
        with pytest.raises(GalileoError, match=re.escape(needle)):
            check_upload(*args)


def test_a_click_maps_back_to_its_pixel_through_the_letterbox():
    from ui.calibrate import display_scale, letterbox

    for w, h, aspect in ((320, 240, 700 / 768), (640, 480, 2.0), (1920, 1080, 16 / 9), (320, 240, None)):
        s = display_scale(w, h)
        pw, ph, left, top = letterbox(w * s, h * s, aspect)
        assert pw >= w * s and ph >= h * s and (aspect is None or abs(pw / ph - aspect) < 0.01)
        for u, v in ((0.0, 0.0), (w - 0.5, h / 3), (w / 2, h - 1)):
            sx, sy = (u * s + left) / pw, (v * s + top) / ph        # where the canvas shows it (0..1)
            assert ((sx * pw - left) / s, (sy * ph - top) / s) == pytest.approx((u, v))


def test_points_and_numbers_typed_in_the_panel():
    from galileo.clicks import calibration_of, parse_points
    from galileo.errors import GalileoError
    from ui.calibrate import format_points, for_panel

    pts = parse_points(" 37.9,103.6  64.9,100 (200.7,148.8); 212,165.8 ", 4, "Points (px)")
    assert pts == [(37.9, 103.6), (64.9, 100.0), (200.7, 148.8), (212.0, 165.8)]
    assert parse_points(format_points(pts), 4) == pts and parse_points("", 4) == []
    for bad in ("1,2 3", "a,b", "1,2 " * 5):
        with pytest.raises(GalileoError, match=re.escape("Points (px)")):
            parse_points(bad, 4, "Points (px)")
    # the target's size: three numbers, blank for the kind's own; its message in the panel's words
    ramp = calibration_of("ramp")
    given = {"ramp_length_m": "0.9", "ramp_width_m": "0.3", "angle_deg": "20"}
    assert ramp.values({**given, "target_size_m": " "})["target_size_m"] is None
    assert ramp.values({**given, "target_size_m": "0.1, 0.08 0.07"})["target_size_m"] == (0.1, 0.08, 0.07)
    with pytest.raises(GalileoError) as e:
        ramp.values({**given, "target_size_m": "0.1, 0.08"})
    assert for_panel(str(e.value), ramp) == "Target size (m): expected 3 numbers x, y, z, got '0.1, 0.08'"


def test_the_panel_solves_the_scene_and_finds_the_start(clip):
    from galileo.clicks import NotFound, calibration_of
    from galileo.errors import GalileoError
    from ui.calibrate import draw, probe_video, solve

    video, truth = clip
    ramp = calibration_of("ramp")
    c = probe_video(video, "ramp-clip.mp4")
    assert (c.width_px, c.height_px, c.n_frames, c.fps) == (W, H, N_FRAMES, 30.0)
    nums = {"ramp_length_m": str(LENGTH_M), "ramp_width_m": str(WIDTH_M), "angle_deg": str(ANGLE_DEG),
            "upper_at_m": str(UPPER_AT_M), "target": "cardboard", "target_distance_m": "0.2",
            "target_size_m": "0.12, 0.1, 0.08"}
    scene, err = solve(c, true_points(truth), ramp, nums)
    assert err < 0.01 and scene.start_distance_m() == pytest.approx(truth.start_distance_m(), abs=0.02)
    assert "object found in the first frame" in ramp.describe(scene, nums)
    assert scene.target.distance_m == 0.2 and scene.target.shape.size_m == (0.12, 0.1, 0.08)
    img, s = draw(c, true_points(truth), ramp, scene)
    assert img.shape == (H * s, W * s, 3)
    with pytest.raises(GalileoError, match="cross over"):
        solve(c, true_points(truth)[[1, 0, 2, 3]], ramp, nums)
    with pytest.raises(GalileoError, match="click 2 more points"):
        solve(c, true_points(truth)[:2], ramp, nums)
    # an object that never moves: the start cannot be found, and the panel asks for it by name
    still = np.repeat(c.frames[:1], 4, axis=0)
    with pytest.raises(NotFound, match=re.escape("enter Start (m)")) as e:
        solve(type(c)(**{**c.__dict__, "frames": still}), true_points(truth), ramp, nums)
    assert e.value.scene.camera is not None


def test_a_failed_start_is_shown_in_the_page_and_start_can_be_pressed_again(clip, tmp_path):
    from galileo.errors import GalileoError
    from galileo.clicks import calibration_of
    from ui.calibrate import Calibrator, probe_video, solve

    video, truth = clip
    calls = []

    def start(video_path, scene_path, name, say):
        calls.append((video_path, scene_path, name))
        say(f"tracking {video_path} ...")
        raise GalileoError("the tracker lost the object at frame 12: give --start-m")

    cal = Calibrator("127.0.0.1", free_port(), tmp_path / "sessions", start)
    try:
        c = probe_video(video, "ramp-clip.mp4")
        nums = {"ramp_length_m": LENGTH_M, "ramp_width_m": WIDTH_M, "angle_deg": ANGLE_DEG, "upper_at_m": UPPER_AT_M}
        scene = solve(c, true_points(truth), calibration_of("ramp"), nums)[0]
        cal.clip, cal.solved, cal.busy = c, (scene, 0.0), True
        assert cal._run_start(c, scene) is None
        (video_path, scene_path, name), = calls
        assert video_path == video and name == "ramp-clip" and scene_path.exists()
        assert "galileo-error" in cal.progress.content
        assert "the tracker lost the object at frame 12: enter Start (m)" in cal.progress.content
        assert not cal.busy and not cal.start_button.disabled
    finally:
        cal.close()
    assert not (tmp_path / "sessions" / ".uploads").exists()


def test_typed_numbers_are_read_exactly_or_refused(clip, tmp_path):
    """The panel's numbers are text read as typed (issue 14, defect 2's rule for every field):
    "1e308", "abc" or a negative length are refused in red with Start disabled, never
    silently rewritten; "0.9" again solves."""
    from ui.calibrate import Calibrator, probe_video

    video, truth = clip
    cal = Calibrator("127.0.0.1", free_port(), tmp_path / "sessions", lambda *a: None)
    try:
        assert cal.scenario == "ramp"
        cal.clip = probe_video(video, "ramp-clip.mp4")
        cal.points = [tuple(p) for p in true_points(truth)]
        inputs = cal.inputs
        inputs["ramp_width_m"].value, inputs["angle_deg"].value = str(WIDTH_M), str(ANGLE_DEG)
        inputs["upper_at_m"].value, inputs["ramp_length_m"].value = str(UPPER_AT_M), str(LENGTH_M)
        cal._recompute()
        assert cal.solved is not None and not cal.start_button.disabled
        for text, reason in (("1e308", "Length (m): 1e308 is outside (0, 10]"),
                             ("abc", "Length (m): expected a number, got 'abc'"),
                             ("-0.9", "Length (m): -0.9 is outside (0, 10]"), ("nan", "expected a finite number"),
                             ("", "Length (m) is needed: the ramp board's length")):
            inputs["ramp_length_m"].value = text
            cal._recompute()
            assert cal.solved is None and cal.start_button.disabled, text
            assert "galileo-error" in cal.result.content and html.escape(reason, quote=True) in cal.result.content, (
                text, cal.result.content)
        inputs["ramp_length_m"].value = str(LENGTH_M)
        cal._recompute()
        assert cal.solved is not None and not cal.start_button.disabled
    finally:
        cal.close()


def test_the_scenario_chooser_offers_the_calibrated_scenarios_and_draws_their_own_numbers(clip, tmp_path):
    """The page names no scenario: its chooser holds the registered scenarios that declare a
    calibration, and choosing one shows that calibration's numbers and points (each field's
    label and unit, its default) and keeps what was typed for the other."""
    from galileo.clicks import calibration_of
    from ui.calibrate import Calibrator, probe_video

    video, _ = clip
    cal = Calibrator("127.0.0.1", free_port(), tmp_path / "sessions", lambda *a: None)
    try:
        assert cal.scenario_input.options == ("fall", "ramp", "splash", "spring")
        cal.clip = probe_video(video, "ramp-clip.mp4")
        cal.inputs["angle_deg"].value = "12.5"
        cal.scenario_input.value = "splash"       # (as a browser's change does: its callback runs)
        splash = calibration_of("splash")
        assert wait_until(lambda: cal.scenario == "splash", 30)
        assert [h.label for h in cal.inputs.values()] == [f.title for f in splash.fields]
        assert cal.inputs["tank_width_m"].value == "0.4" and cal.inputs["water_level_m"].value == ""
        assert "Click point 1 of 6: top left" in cal.guide.content
        cal.scenario_input.value = "ramp"
        assert wait_until(lambda: cal.scenario == "ramp", 30)
        assert cal.inputs["angle_deg"].value == "12.5"
    finally:
        cal.close()
