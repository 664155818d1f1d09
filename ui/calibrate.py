"""Bring your own video, in the browser (issue 14): `python app.py --upload`.

A small viser app that runs before the viewer, on the same address. It knows no scenario: it
draws what the chosen scenario's calibration declares (`galileo.clicks.Calibration`: its
points, its numbers, its solver and overlay), for every registered scenario that has one.

1. "Upload video": a video file of at most MAX_UPLOAD_BYTES (500 MB). Its type (the file's
   extension or the browser's MIME type) and size are checked when the transfer starts, before
   a byte of it is kept; then it is written (atomically) to a folder of its own under the
   sessions folder and decoded once: at least two frames, even width and height (tracking
   needs them), its frame rate and count, and a sample of frames for finding the object
   (`galileo.clicks.sample_video`).
2. "Scenario": what the video shows (the scenarios with a calibration). Its first frame becomes
   the scene's background: clicks on it place the scenario's points in their order (the guide
   line says which comes next and where it is). "Undo last point" and "Clear points", or edit
   "Points (px)" directly.
3. The scenario's numbers, one input each (`label (unit)`, the field's help as its hint; blank:
   the field's "not given", found in the video or estimated). Every change solves the scene
   again (`Calibration.solve`), redraws the frame with the scenario's overlay and shows the
   reprojection error in pixels and what was estimated and found, or, in red, what is wrong (and
   "Start inference" stays disabled). The library names the command line's flags; the panel
   says its own fields' names instead (`for_panel`).
4. "Start inference" writes scene.json next to the upload and hands (video, scene, name) to
   the caller's `start` in the main thread (app.py: tracking, a new session, the chains;
   progress shown in the panel). A GalileoError there is shown and the user may adjust and
   start again. On success the caller closes this server and opens the viewer on the same
   port; the browser's viser client reconnects by itself.

What viser forced:
* viser's upload sends the file in 512 KB parts and holds them all in memory until the last
  arrives; it has no size limit of its own and no hook before the parts come. The cap and
  the type are checked in a handler of viser's "transfer starts" message (`_UploadGate`,
  viser internals): a refused transfer is dropped at once (its parts are ignored as they
  arrive), its progress notification in that browser removed and the upload button
  replaced (the browser would keep the old one disabled). Without those internals the same
  checks run once the file has arrived.
* The background image is stretched over the whole 3-D canvas. The frame is letterboxed to
  each browser's canvas aspect (`letterbox`), so it is not distorted and a click's pixel is
  `screen_pos * padded size - padding`, divided by the display scale (small videos are
  drawn enlarged so the overlay's lines stay sharp).
"""
from __future__ import annotations

import html
import math
import os
import queue
import re
import shutil
import signal
import tempfile
import threading
import time
import traceback
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np

from galileo import registry
from galileo.clicks import Calibration, NotFound, calibrations, draw_clicks, parse_points, sample_video
from galileo.errors import GalileoError
from galileo.video import VideoInfo

MAX_UPLOAD_MB = 500
MAX_UPLOAD_BYTES = MAX_UPLOAD_MB * 1024 * 1024   # read at run time (tests lower it)
VIDEO_SUFFIXES = (".mp4", ".m4v", ".mov", ".avi", ".mkv", ".webm", ".mpg", ".mpeg", ".ogv", ".wmv", ".3gp",
                  ".flv", ".ts", ".mts", ".m2ts")
MIN_FRAMES = 2
DISPLAY_MIN_PX = 960      # small videos are drawn enlarged (integer factor) to at least this on their long side
UPLOADS_DIR = ".uploads"  # under the sessions folder: one temporary folder per upload
ERROR_COLOR = "#c92a2a"
OK_COLOR = "#2b8a3e"
BUSY_COLOR = "#1c7ed6"
POINTS_FIELD = "Points (px)"


# -- pure helpers (tested without a browser) -----------------------------------------------------

def check_upload(filename: str, mime_type: str, size_bytes: int, max_bytes: int | None = None) -> None:
    """A GalileoError unless the file looks like a video (by its extension or MIME type) and
    is not over the cap: what can be checked before any of it is received."""
    cap = MAX_UPLOAD_BYTES if max_bytes is None else max_bytes
    suffix = Path(filename).suffix.lower()
    if not (suffix in VIDEO_SUFFIXES or (mime_type or "").lower().startswith("video/")):
        kind = f" ({mime_type})" if mime_type else ""
        raise GalileoError(f"{filename}{kind} is not a video: upload an MP4, MOV, AVI, MKV or WebM file")
    if size_bytes > cap:
        raise GalileoError(f"{filename} is {_size(size_bytes)}, over the {_size(cap)} cap for uploads")
    if size_bytes == 0:
        raise GalileoError(f"{filename} is empty (0 bytes)")


def _size(n: int) -> str:
    for unit in ("bytes", "KB", "MB", "GB"):
        if n < 1024 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}".replace(".0 ", " ")
        n /= 1024
    return f"{n} bytes"


def safe_name(filename: str) -> str:
    """The uploaded file's name, made safe for a file name here (its extension kept)."""
    base = Path(filename.replace("\\", "/")).name
    safe = re.sub(r"[^A-Za-z0-9._-]+", "-", base).strip("-.")
    return safe or "video"


def for_panel(message: str, cal: Calibration) -> str:
    """A library message with the command line's flags (the calibration's fields', --points)
    named as this panel's fields ("give --start-m" reads "enter Start (m)")."""
    names = {f.flag: f.title for f in cal.fields}
    names["--points"] = POINTS_FIELD
    for flag in sorted(names, key=len, reverse=True):   # (--target-size-m before --target)
        message = message.replace(f"give {flag}", f"enter {names[flag]}").replace(flag, names[flag])
    return message


@dataclass(frozen=True)
class Clip:
    """An uploaded video that decodes: where it is, its name as uploaded, its first frame and
    a sample of its frames (where the solvers find the objects)."""
    path: Path
    name: str
    first: np.ndarray
    frames: np.ndarray
    width_px: int
    height_px: int
    fps: float
    n_frames: int

    @property
    def info(self) -> VideoInfo:
        return VideoInfo(self.width_px, self.height_px, self.fps, self.n_frames)


def probe_video(path: str | Path, name: str | None = None) -> Clip:
    """Decode the whole video once (a GalileoError, naming the file as uploaded, if it does not
    decode): the first frame, the frame count, and the sample the solvers read."""
    path = Path(path)
    name = name or path.name
    info, first, kept = sample_video(path, name)
    n = info.n_frames
    if n < MIN_FRAMES:
        raise GalileoError(f"{name} is not a video this app can use: {n} decodable frame{'s' * (n != 1)}, "
                           f"need at least {MIN_FRAMES} to see motion")
    w, h = info.width_px, info.height_px
    if w % 2 or h % 2:
        raise GalileoError(f"{name} is {w}x{h}: tracking needs an even width and height (re-encode it, e.g. "
                           "ffmpeg -vf scale=trunc(iw/2)*2:trunc(ih/2)*2)")
    return Clip(path, name, first, kept, w, h, info.fps, n)


def letterbox(width: int, height: int, aspect: float | None) -> tuple[int, int, int, int]:
    """(padded width, padded height, left, top): a width x height picture centred in the
    smallest picture of the canvas's aspect (width / height) that holds it."""
    if aspect is None or not (math.isfinite(aspect) and aspect > 0):
        return width, height, 0, 0
    if aspect > width / height:
        pw, ph = max(width, round(height * aspect)), height
    else:
        pw, ph = width, max(height, round(width / aspect))
    return pw, ph, (pw - width) // 2, (ph - height) // 2


def display_scale(width: int, height: int) -> int:
    """The integer factor a frame is drawn enlarged by (1 for frames of DISPLAY_MIN_PX or more)."""
    return max(1, math.ceil(DISPLAY_MIN_PX / max(width, height)))


def format_points(points) -> str:
    return " ".join(f"{u:.1f},{v:.1f}" for u, v in points)


def solve(clip: Clip, points, cal: Calibration, numbers: dict):
    """(scene, reprojection error px) for the clip, the points clicked and the numbers (name ->
    text, as typed); a GalileoError (one line, in the panel's words) if they do not make a
    scene, NotFound (with its scene) if only a quantity to be found in the video is missing."""
    n = len(cal.points)
    if len(points) != n:
        raise GalileoError(f"click {n - len(points)} more point{'s' * (n - len(points) != 1)} on the frame")
    try:
        return cal.solve(np.asarray(points, float), numbers, clip.info, clip.frames)
    except NotFound as e:
        raise NotFound(for_panel(str(e), cal), e.scene) from None
    except GalileoError as e:
        raise GalileoError(for_panel(str(e), cal)) from None


LINE_STYLE = "padding:0.15em 0.75em;font-size:0.875em"


def _red(text: str, cls: str) -> str:
    return (f'<div class="{cls} galileo-error" style="{LINE_STYLE};color:{ERROR_COLOR};font-weight:600">'
            f"{html.escape(text)}</div>")


def _line(text: str, cls: str, color: str | None = None) -> str:
    return f'<div class="{cls}" style="{LINE_STYLE}{f";color:{color}" if color else ""}">{html.escape(text)}</div>'


def draw(clip: Clip, points, cal: Calibration, scene=None) -> tuple[np.ndarray, int]:
    """(picture, its scale): the first frame enlarged by `display_scale`, with the scenario's
    overlay of the scene when there is one, else the clicks so far (red, numbered)."""
    import cv2

    s = display_scale(clip.width_px, clip.height_px)
    frame = clip.first if s == 1 else cv2.resize(clip.first, (clip.width_px * s, clip.height_px * s),
                                                  interpolation=cv2.INTER_LINEAR)
    pts = np.asarray(points, float).reshape(-1, 2) * s
    if scene is not None:
        cam = scene.camera
        big = replace(cam, K=np.diag([s, s, 1.0]) @ cam.K, width_px=cam.width_px * s, height_px=cam.height_px * s)
        return cal.draw_overlay(frame, replace(scene, camera=big), pts), s
    img = np.ascontiguousarray(frame).copy()
    draw_clicks(img, pts)
    return img, s


def placeholder(width: int = 960, height: int = 540) -> np.ndarray:
    import cv2

    img = np.full((height, width, 3), 60, np.uint8)
    for i, text in enumerate(("Upload your video", "(the \"Upload video\" button in the panel)")):
        cv2.putText(img, text, (40, height // 2 - 20 + 44 * i), cv2.FONT_HERSHEY_SIMPLEX, 0.9, (225, 225, 225), 2,
                    cv2.LINE_AA)
    return img


# -- the browser app --------------------------------------------------------------------------------

class _UploadGate:
    """Checks an upload's type and size when its transfer starts, before viser buffers it (see
    the module docstring: viser internals, each use guarded; `available` is False without them)."""

    def __init__(self, server, on_refused: Callable[[int, str, str], None], max_bytes: Callable[[], int]):
        self.server = server
        self.on_refused = on_refused
        self.max_bytes = max_bytes
        try:
            from viser import _messages

            self._start_cls = _messages.FileTransferStartUpload
            self._remove_cls = _messages.RemoveNotificationMessage
            self._states = server.gui._current_file_upload_states
            server._websock_server.register_handler(self._start_cls, self._on_start)
            self.available = True
        except (AttributeError, ImportError):
            self.available = False

    def _on_start(self, client_id, message) -> None:
        # runs in viser's event loop, after viser's own handler made the transfer's state and
        # before any of its parts are handled: dropping the state makes viser ignore them
        try:
            check_upload(message.filename, message.mime_type, message.size_bytes, self.max_bytes())
        except GalileoError as e:
            self._states.pop(message.transfer_uuid, None)
            threading.Thread(target=self.on_refused, args=(client_id, message.transfer_uuid, str(e)),
                             daemon=True).start()

    def hide_progress(self, client_id: int, transfer_uuid: str) -> None:
        """Remove the browser's "Uploading ..." notification of a refused transfer (the
        client names it "upload-<transfer uuid>")."""
        client = self.server.get_clients().get(client_id)
        conn = getattr(client, "_websock_connection", None)
        if conn is not None:
            conn.queue_message(self._remove_cls(f"upload-{transfer_uuid}"))


class Calibrator:
    """The upload-and-calibrate page on host:port. `wait()` blocks (in the main thread) until a
    session has been started with `start(video, scene_json, name, say)` and returns what it
    returned; `close()` stops the server and removes the upload folder."""

    def __init__(self, host: str, port: int, sessions: str | Path,
                 start: Callable[[Path, Path, str, Callable[[str], None]], object], *, name: str | None = None,
                 max_bytes: int | None = None, scenario: str | None = None):
        import viser

        self.calibrations = calibrations()
        if not self.calibrations:
            raise GalileoError("no scenario can be calibrated from a video (none declares a calibration)")
        if scenario is not None and scenario not in self.calibrations:
            raise GalileoError(f"the {scenario} scenario has no own-video calibration; these have: "
                               f"{', '.join(self.calibrations)}")
        # opens on --scenario, else the default scenario (not the first by name: a new one sorts before it)
        self.scenario = scenario or (registry.DEFAULT if registry.DEFAULT in self.calibrations
                                     else next(iter(self.calibrations)))
        self._texts = {n: {f.name: f.text(f.default) for f in c.fields} for n, c in self.calibrations.items()}
        self._start = start
        self._name = name
        self._max_bytes = max_bytes
        root = Path(sessions) / UPLOADS_DIR
        root.mkdir(parents=True, exist_ok=True)
        self.workdir = Path(tempfile.mkdtemp(prefix="upload-", dir=root))
        self._lock = threading.RLock()
        self._requests: queue.Queue = queue.Queue()
        self.clip: Clip | None = None
        self.points: list[tuple[float, float]] = []
        self.solved = None            # (scene, err) for the current points and numbers
        self.busy = False             # a session is being started
        self._generation = 0          # uploads so far (a late probe of an older upload is dropped)
        self._picture: tuple[np.ndarray, int] = (placeholder(), 1)
        self._boxes: dict[int, tuple[int, int, int, int, int]] = {}   # client: letterbox and scale sent
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        if port and self.server.get_port() != port:
            self.server.stop()
            shutil.rmtree(self.workdir, ignore_errors=True)
            raise GalileoError(f"port {port} on {host} is taken (another app running?); choose another with --port")
        self.host, self.port = host, self.server.get_port()
        self.url = f"http://{host}:{self.port}"
        self._build_gui()
        self._gate = _UploadGate(self.server, self._refused, self._cap)
        self.server.on_client_connect(self._on_connect)
        self.server.on_client_disconnect(lambda c: self._boxes.pop(c.client_id, None))
        self.server.scene.on_click()(self._on_click)
        self._show()

    def _cap(self) -> int:
        return MAX_UPLOAD_BYTES if self._max_bytes is None else self._max_bytes

    # -- GUI --------------------------------------------------------------------------------------
    @property
    def cal(self) -> Calibration:
        return self.calibrations[self.scenario]

    def _build_gui(self) -> None:
        import viser

        g = self.server.gui
        g.main_panel.dock_right()      # the canvas (the frame) beside the panel, not under it
        g.add_markdown(f"### Your video\nAt most {_size(self._cap())}: "
                       + "; or ".join(c.subject for c in self.calibrations.values())
                       + ". Choose its scenario, click its points on the frame, enter its numbers, check the overlay, "
                         "start.")
        self.upload = self._add_upload_button()
        self.file_line = g.add_html(_line("No video yet.", "galileo-upload"))
        self.result = g.add_html(_line("", "galileo-calib"))
        self.start_button = g.add_button("Start inference", disabled=True, color="green", icon=viser.Icon.PLAYER_PLAY)
        self.progress = g.add_html(_line("", "galileo-progress"))
        self.scenario_input = g.add_dropdown("Scenario", tuple(self.calibrations), initial_value=self.scenario,
                                             hint="what the video shows: its points and numbers follow")
        with g.add_folder("Points (click the frame)"):
            self.guide = g.add_html("")
            self.points_text = g.add_text(POINTS_FIELD, "", hint="u,v of the points clicked, in order; editable")
            self.undo = g.add_button("Undo last point", icon=viser.Icon.ARROW_BACK_UP)
            self.clear = g.add_button("Clear points", icon=viser.Icon.TRASH)
        self.numbers_folder = None
        self.inputs: dict = {}        # field name -> its input
        self._add_inputs()

        @self.scenario_input.on_update
        def _(_e):
            with self._lock:
                if self.scenario_input.value == self.scenario:
                    return
                self._texts[self.scenario] = self._numbers()
                self.scenario, self.points = self.scenario_input.value, []
                self._add_inputs()
                self._recompute()

        @self.points_text.on_update
        def _(e):
            if e.client is None:    # set here, from the clicks
                return
            with self._lock:
                try:
                    pts = parse_points(self.points_text.value, len(self.cal.points), POINTS_FIELD)
                except GalileoError as err:
                    self._set_result(_red(str(err), "galileo-calib"), ok=False)
                    return
                self.points = pts
                self._recompute()

        @self.undo.on_click
        def _(_e):
            with self._lock:
                self.points = self.points[:-1]
                self._recompute()

        @self.clear.on_click
        def _(_e):
            with self._lock:
                self.points = []
                self._recompute()

        self.start_button.on_click(self._on_start)
        self._recompute()

    def _add_inputs(self) -> None:
        """The chosen scenario's numbers, one input each (a choice: a dropdown), in a folder of
        their own (the last one: it is replaced when the scenario changes)."""
        g = self.server.gui
        if self.numbers_folder is not None:
            self.numbers_folder.remove()
        texts = self._texts[self.scenario]
        self.inputs = {}
        with g.add_folder(f"Numbers ({self.scenario})") as self.numbers_folder:
            for f in self.cal.fields:
                if f.choices:
                    h = g.add_dropdown(f.title, f.choices, initial_value=texts[f.name], hint=f.help)
                else:
                    h = g.add_text(f.title, texts[f.name], hint=f.help)
                h.on_update(lambda _e: self._recompute())
                self.inputs[f.name] = h

    def _add_upload_button(self):
        import viser

        order = getattr(self, "_upload_order", None)
        b = self.server.gui.add_upload_button("Upload video", mime_type="video/*", icon=viser.Icon.UPLOAD,
                                              hint=f"a video file, at most {_size(self._cap())}", order=order)
        self._upload_order = b.order
        b.on_upload(self._on_upload)
        return b

    def _numbers(self) -> dict:
        """The inputs' values, as typed (text fields: a browser's number input rewrites what it
        cannot parse); each is checked by its field when the scene is solved."""
        return {name: str(h.value) for name, h in self.inputs.items()}

    def _set_result(self, content: str, ok: bool) -> None:
        self.result.content = content
        self.start_button.disabled = not ok or self.busy

    def _say_file(self, text: str, error: bool = False) -> None:
        self.file_line.content = _red(text, "galileo-upload") if error else _line(text, "galileo-upload")

    def _say(self, text: str, color: str | None = BUSY_COLOR, error: bool = False) -> None:
        self.progress.content = _red(text, "galileo-progress") if error else _line(text, "galileo-progress", color)

    def _notify(self, client_id: int | None, text: str) -> None:
        clients = self.server.get_clients()
        targets = [clients[client_id]] if client_id in clients else list(clients.values())
        for c in targets:
            c.add_notification("Galileo", text, color="red", auto_close_seconds=8.0)

    # -- state -> picture ------------------------------------------------------------------------------
    def _recompute(self) -> None:
        with self._lock:
            clip, pts, cal = self.clip, list(self.points), self.cal
            n, total = len(pts), len(cal.points)
            self.points_text.value = format_points(pts)
            if clip is None:
                self.guide.content = _line("Upload a video first.", "galileo-guide")
                self.solved = None
                self._set_result(_line("", "galileo-calib"), ok=False)
                return
            point = cal.points[n] if n < total else None
            self.guide.content = _line(f"Click point {n + 1} of {total}: {point.name} ({point.hint})" if point else
                                       f"All {total} points placed (Undo or Clear to move them).", "galileo-guide")
            numbers = self._numbers()
            try:
                scene, err = solve(clip, pts, cal, numbers)
            except GalileoError as e:
                self.solved = None
                self._set_result((_line if n < total else _red)(str(e), "galileo-calib"), ok=False)
                # the scene is still worth seeing when only what is found in the video is missing
                self._picture = draw(clip, pts, cal, e.scene if isinstance(e, NotFound) else None)
            else:
                self.solved = (scene, err)
                text = f"reprojection error {err:.2f} px; {for_panel(cal.describe(scene, numbers), cal)}"
                self._set_result(_line(text, "galileo-calib", OK_COLOR), ok=True)
                self._picture = draw(clip, pts, cal, scene)
            self._show()

    def _show(self, client=None) -> None:
        """Send the picture to every browser (or one), letterboxed to its canvas."""
        img, s = self._picture
        clients = [client] if client is not None else list(self.server.get_clients().values())
        for c in clients:
            try:
                aspect = c.camera.aspect
            except (AssertionError, ZeroDivisionError):   # no camera message from it yet
                aspect = None
            h, w = img.shape[:2]
            pw, ph, left, top = letterbox(w, h, aspect)
            padded = img
            if (pw, ph) != (w, h):
                padded = np.full((ph, pw, 3), 40, np.uint8)
                padded[top:top + h, left:left + w] = img
            self._boxes[c.client_id] = (pw, ph, left, top, s)
            c.scene.set_background_image(padded, format="jpeg", jpeg_quality=90)

    def _on_connect(self, client) -> None:
        @client.camera.on_update
        def _(cam):
            with self._lock:
                try:
                    aspect = cam.aspect
                except (AssertionError, ZeroDivisionError):
                    return
                img, s = self._picture
                box = letterbox(img.shape[1], img.shape[0], aspect)
                if self._boxes.get(client.client_id, (None,))[:4] != box:
                    self._show(client)

        with self._lock:
            self._show(client)

    # -- clicks --------------------------------------------------------------------------------------
    def _on_click(self, event) -> None:
        with self._lock:
            if self.clip is None or self.busy:
                return
            box = self._boxes.get(event.client_id)
            if box is None:
                return
            pw, ph, left, top, s = box
            sx, sy = event.screen_pos
            u, v = (sx * pw - left) / s, (sy * ph - top) / s
            w, h = self.clip.width_px, self.clip.height_px
            if not (0 <= u < w and 0 <= v < h):
                self._refuse_click(event.client_id, f"that click ({u:.0f}, {v:.0f}) is outside the {w}x{h} frame: "
                                                    "click on the picture")
                return
            if len(self.points) >= len(self.cal.points):
                self._refuse_click(event.client_id, f"all {len(self.cal.points)} points are placed: Undo last point "
                                                    "or Clear points to place one again")
                return
            self.points.append((u, v))
            self._recompute()

    def _refuse_click(self, client_id: int, message: str) -> None:
        self.guide.content = _red(message, "galileo-guide")
        self._notify(client_id, message)

    # -- uploads ---------------------------------------------------------------------------------------
    def _refused(self, client_id: int, transfer_uuid: str, message: str) -> None:
        """A transfer refused when it started (`_UploadGate`): say why, and give that browser a
        fresh upload button and no stale progress notification."""
        with self._lock:
            old, self.upload = self.upload, None
            old.remove()
            self.upload = self._add_upload_button()
            self._gate.hide_progress(client_id, transfer_uuid)
            self._say_file(message, error=True)
            self._notify(client_id, message)

    def _on_upload(self, event) -> None:
        handle = event.target
        f = handle.value
        name, content = f.name, f.content
        try:   # viser keeps the last upload in memory: let it go
            handle._impl.value = type(f)("", b"")
        except AttributeError:
            pass
        del f
        with self._lock:
            if self.busy:
                return
            self._generation += 1
            gen = self._generation
        try:
            check_upload(name, "", len(content), self._cap())    # (checked at the start too, where viser allows)
            folder = Path(tempfile.mkdtemp(prefix="clip-", dir=self.workdir))
            path = folder / safe_name(name)
            tmp = folder / f".{path.name}.part"
            tmp.write_bytes(content)
            os.replace(tmp, path)
            del content
            self._say_file(f"checking {name} ({_size(path.stat().st_size)}) ...")
            clip = probe_video(path, name)
        except GalileoError as e:
            with self._lock:
                if gen == self._generation:
                    self._say_file(str(e), error=True)
            self._notify(event.client_id, str(e))
            return
        except Exception as e:    # noqa: BLE001 - a bad file must not leave the page without a word
            traceback.print_exc()
            self._say_file(f"cannot use {name}: {type(e).__name__}: {e}", error=True)
            return
        with self._lock:
            if gen != self._generation:
                shutil.rmtree(clip.path.parent, ignore_errors=True)
                return
            old = self.clip
            self.clip, self.points = clip, []
            if old is not None:
                shutil.rmtree(old.path.parent, ignore_errors=True)
            self._say_file(f"{name}: {clip.width_px}x{clip.height_px}, {clip.n_frames} frames at {clip.fps:g} fps")
            self._say("", None)
            self._recompute()

    # -- start ---------------------------------------------------------------------------------------
    def _on_start(self, _event) -> None:
        with self._lock:
            if self.busy or self.solved is None or self.clip is None:
                return
            self.busy = True
            for h in (self.start_button, self.undo, self.clear, self.scenario_input):
                h.disabled = True
            if self.upload is not None:
                self.upload.disabled = True
            self._requests.put((self.clip, self.solved[0]))

    def _ready_again(self) -> None:
        with self._lock:
            self.busy = False
            for h in (self.undo, self.clear, self.scenario_input):
                h.disabled = False
            if self.upload is not None:
                self.upload.disabled = False
            self.start_button.disabled = self.solved is None

    def wait(self):
        """Serve until a session has started; its `start(...)` result. Ctrl-C (or SIGTERM)
        raises KeyboardInterrupt."""
        old = None
        if threading.current_thread() is threading.main_thread():
            def _term(*_):
                raise KeyboardInterrupt
            old = signal.signal(signal.SIGTERM, _term)
        try:
            print(f"upload your video: {self.url}")
            while True:
                try:
                    clip, scene = self._requests.get(timeout=0.5)
                except queue.Empty:
                    continue
                result = self._run_start(clip, scene)
                if result is not None:
                    return result[0]
        finally:
            if old is not None:
                signal.signal(signal.SIGTERM, old)

    def _run_start(self, clip: Clip, scene):
        scene_path = clip.path.parent / "scene.json"
        name = self._name or Path(clip.name).stem
        t0 = time.monotonic()
        stage = [f"tracking {clip.n_frames} frames of {clip.name} ..."]
        done = threading.Event()

        def say(text: str) -> None:
            print(text)
            if not text.startswith("tracking "):    # (that one is said here already, with the frame count)
                stage[0] = text.replace(str(clip.path), clip.name)
                self._say(stage[0])

        def tick():   # the elapsed time, so a long tracking run visibly goes on
            while not done.wait(1.0):
                self._say(f"{stage[0]} ({time.monotonic() - t0:.0f} s)")

        self._say(stage[0])
        ticker = threading.Thread(target=tick, daemon=True)
        ticker.start()
        failure = None
        try:
            scene.save(scene_path)
            result = self._start(clip.path, scene_path, name, say)
        except GalileoError as e:
            failure = for_panel(str(e), self.cal)
        except Exception as e:   # noqa: BLE001 - shown in the page, the traceback in the terminal
            traceback.print_exc()
            failure = f"could not start: {type(e).__name__}: {e}"
        finally:
            done.set()
            ticker.join(timeout=5)
        if failure is not None:
            self._say(failure, error=True)
            self._ready_again()
            return None
        self._say("tracked: starting the chains and opening the viewer (this page reconnects by itself) ...",
                  OK_COLOR)
        return (result,)

    def close(self) -> None:
        """Clear the background (the browser keeps it across the reconnect to the viewer), stop
        the server, remove the uploads."""
        try:
            self.server.scene.set_background_image(None)
            self.server.flush()
            time.sleep(0.2)
        finally:
            self.server.stop()
            _wait_until_free(self.host, self.port)   # the viewer comes next, on this port
            shutil.rmtree(self.workdir, ignore_errors=True)
            try:
                self.workdir.parent.rmdir()    # the uploads folder, if no other app's uploads are in it
            except OSError:
                pass


def _wait_until_free(host: str, port: int, timeout_s: float = 15.0) -> None:
    """Until the stopped server's port can be bound again as viser binds it (SO_REUSEADDR: the
    closed connections' TIME_WAIT does not count): viser's stop may return before its event
    loop has closed the listening socket, and the viewer's server would move to another port."""
    import socket

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with socket.socket() as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                s.bind((host, port))
                return
            except OSError:
                pass
        time.sleep(0.1)


def calibrate_in_browser(host: str, port: int, sessions: str | Path, start, *, name: str | None = None,
                         scenario: str | None = None):
    """Serve the upload-and-calibrate page until a session has started; `start`'s result.
    `scenario`: the one chosen at first (default: the first that has a calibration)."""
    cal = Calibrator(host, port, sessions, start, name=name, scenario=scenario)
    try:
        return cal.wait()
    finally:
        cal.close()
