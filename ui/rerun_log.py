"""Rerun logging for a Galileo session: one module, one recording, stable entity paths.

Entity layout (timelines in brackets):

    video                      AssetVideo (static) + VideoFrameReference [frame], and frame 0's
                               reference at [sweep 0] too, so the panel shows a frame on the
                               blueprint's own timeline ("sweep"), not only on "frame"
                               (JPEG frames instead, see below)
    video/tracks/<object>      Points2D: KLT features, else the projected centre [frame]
    video/tracks/<object>/center   Points2D: projected centre, labelled [frame]
    video/tracks/<object>/path     LineStrips2D: the centre's whole path (static)
    scene/<mesh>               Mesh3D (static): the scene's geometry (ramp, tank, water; ControllerFeed)
    observed/<object>          LineStrips3D (static) + Points3D [frame]: tracked positions, metres
    chains/<c>/loglik          Scalars [sweep]   (sweep s = the chain's sample s - 1, from 1)
    chains/<c>/<latent>        Scalars [sweep]   (the scenario's latents, by name)
    posterior/<latent>         BarChart histogram (static, replaced on each call)
    diagnostics/r_hat/<latent> Scalars [sweep]   (R-hat of the kept draws, logged when it changes)
    diagnostics/converged      Scalars [sweep]   (1: every latent converged, 0: not)
    events                     TextLog [sweep]   (prior edits etc.)
    sim/map/<object>           LineStrips3D [sweep, frame 0] + Points3D [frame]: the MAP sample's
                               simulated motion, logged when the MAP changes (scrub "sweep" to see
                               it change; on "frame" the latest MAP moves)
    sim/selected/<object>      LineStrips3D (static) + Points3D [frame]: the sample selected in
                               the viewer (`log_selected`, replaced on each call)
    sim/<kind>/connectors/<connector>   LineStrips3D [frame]: the drawing's connectors (a spring,
                               a string; `Drawing.connectors`, known from `log_scene`) where
                               that motion puts their anchors, beside its objects

Video: the browser's WebCodecs decodes the H.264 asset, and a browser offers WebCodecs only
in a secure context (https, or http on localhost). The web viewer served on a non-loopback
host is opened over plain http from elsewhere, where rerun shows "Failed to decode ...
VideoDecoder is not defined"; there (mode "web", host not loopback) the frames are logged
as JPEG images instead, as for a codec rerun does not play.

`ControllerFeed` wires a `ui.controller.Controller` to a logger: its listener, the whole
history of a reopened session (so its new recording continues the old one), and the MAP's
motion, simulated off the controller's thread.

Every method is a no-op in mode "off". The logger uses its own `rr.RecordingStream`,
never the global one, and sends a default blueprint (see `_blueprint`) that is extended
(re-sent once) when chains or latents it did not know about show up.

Time: a stream's time cursor is per thread and sticky, so every method resets it and
sets only its own timeline before logging (a sweep row never inherits a stale frame).
"""
from __future__ import annotations

import bisect
import logging
import os
import socket
import threading
import urllib.parse
import uuid
from pathlib import Path
from typing import Sequence

import numpy as np

# session.rrd is written without rerun's footer (below, `write_footer=False`), and rerun warns
# about that on stderr each time a file sink opens; its channels warn, many times a minute and in
# colour, when a viewer reads slower than the app logs ("Sender has been blocked for over ...":
# nothing for a user to do); read by rerun's Rust logging when the SDK is first imported (a
# RUST_LOG the user set is kept)
os.environ.setdefault("RUST_LOG", "warn,re_log_encoding::rrd::file_sink=error,re_quota_channel=error,"
                                  "re_log_channel=error")
import rerun as rr  # noqa: E402
import rerun.blueprint as rrb

from galileo.drawing import connector_points, frame_pose  # noqa: E402

log = logging.getLogger(__name__)

MODES = ("off", "save", "web", "connect")
RRD_NAME = "session.rrd"
DEFAULT_CONNECT_URL = "rerun+http://127.0.0.1:9876/proxy"

# H.264 is what PyAV writes for us; the others are what the rerun viewer also decodes.
VIDEO_CODECS = {"h264", "hevc", "h265", "av1", "vp9"}
# fallback (decoded frames as images): at most this many frames, JPEG quality
FALLBACK_MAX_FRAMES = 120
FALLBACK_JPEG_QUALITY = 80

TRACK_COLORS = [(255, 80, 40), (40, 160, 255), (255, 220, 0)]   # tracked objects, in the tracks' order
SIM_COLORS = [(230, 60, 60), (60, 120, 230), (60, 180, 90), (200, 120, 220)]   # the selected sample
MAP_COLORS = [(255, 170, 0), (0, 200, 200), (170, 230, 40), (255, 110, 180)]     # the MAP sample
SIM_KINDS = {"selected": "selected", "map": "MAP"}     # sim/<kind>/<object>: legend word
OBSERVED_COLOR = (150, 150, 150)
LOOPBACK_HOSTS = {"127.0.0.1", "localhost", "::1"}
# a reopened session's convergence history: R-hat recomputed at most at this many sweeps
HISTORY_CHECKS = 40

WEB_VIEWER_START_S = 30.0   # how long the web viewer's process may take to listen


def _part(name: str) -> str:
    """One entity-path part, escaped when it needs to be (object names come from scene files)."""
    return rr.escape_entity_path_part(str(name))


def _finite_runs(points: np.ndarray) -> list[np.ndarray]:
    """Split a polyline (N, D) at non-finite rows; runs of at least two points."""
    ok = np.all(np.isfinite(points), axis=1)
    runs, start = [], None
    for i, good in enumerate(np.r_[ok, False]):
        if good and start is None:
            start = i
        elif not good and start is not None:
            if i - start >= 2:
                runs.append(points[start:i])
            start = None
    return runs


def _is_loopback(host: str) -> bool:
    return host in LOOPBACK_HOSTS or host.startswith("127.")


EVENT_ITEMS_SHOWN = 6      # a list or mapping longer than this in an event reads as its length


def _short(v) -> str:
    """A value of an event's detail in a few words: numbers to 4 digits, long lists counted."""
    if isinstance(v, bool) or v is None:
        return {True: "yes", False: "no", None: "none"}[v]
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, dict):
        if len(v) > EVENT_ITEMS_SHOWN:
            return f"({len(v)} entries)"
        return ", ".join(f"{k} {_short(x)}" for k, x in v.items()) or "none"
    if isinstance(v, (list, tuple)):
        if len(v) > EVENT_ITEMS_SHOWN:
            return f"({len(v)} values)"
        return "[" + ", ".join(_short(x) for x in v) + "]"
    return str(v)


def event_text(ev: dict) -> str:
    """How a controller event reads in the `events` log: its kind, then each detail as
    "name value" (e.g. "sigma: sigma 0.08; chain sweeps (16 entries)"), never a Python dict."""
    detail = ev.get("detail")
    parts = ([f"{str(k).replace('_', ' ')} {_short(v)}" for k, v in detail.items()] if isinstance(detail, dict)
             else [_short(detail)] if detail not in (None, {}) else [])
    return f"{ev['kind']}" + (": " + "; ".join(parts) if parts else "")


def _check_reachable(url: str, timeout_s: float = 2.0) -> None:
    """Fail fast when nothing listens at a rerun gRPC url (rerun itself would block 5 s on
    the first log call, then raise on every flush)."""
    parts = urllib.parse.urlsplit(url.replace("rerun+http", "http", 1).replace("rerun+https", "https", 1)
                                  .replace("rerun://", "https://", 1))
    port = parts.port or (443 if parts.scheme == "https" else 80)
    try:
        socket.create_connection((parts.hostname or "127.0.0.1", port), timeout=timeout_s).close()
    except OSError as e:
        raise RuntimeError(f"no rerun viewer or server reachable at {url}: {e}") from None


def _check_port_free(host: str, port: int, what: str = "rerun's gRPC") -> None:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError as e:
            raise RuntimeError(f"cannot serve {what} on {host}:{port}: {e}") from None


def _bind_address(host: str) -> str:
    """The IP address `host` names (rerun's --bind takes an address, not a name)."""
    if host in ("", "0.0.0.0"):
        return "0.0.0.0"
    try:
        return socket.getaddrinfo(host, None, type=socket.SOCK_STREAM)[0][4][0]
    except OSError as e:
        raise RuntimeError(f"cannot serve rerun's web viewer on {host!r}: {e}") from None


def _rerun_binary() -> str:
    """The rerun viewer/server program the rerun-sdk wheel ships (rerun_cli/rerun)."""
    import shutil

    try:
        import rerun_cli

        path = Path(rerun_cli.__file__).parent / "rerun"
        if path.is_file():
            return str(path)
    except ImportError:
        pass
    found = shutil.which("rerun")
    if found is None:
        raise RuntimeError("cannot serve rerun's web viewer: the rerun program is not installed (pip install rerun-sdk)")
    return found


def _parent_death_signal():
    """A function for a child process to call between fork and exec so that it gets SIGTERM
    when the app ends, however it ends (Linux; None elsewhere). prctl is looked up here, in
    the parent: the child, a copy of a threaded process, must take no lock (dlopen's, the
    import lock) another thread may have held. The thread that starts the child counts as its
    parent: in the app, the main thread."""
    import sys

    if not sys.platform.startswith("linux"):
        return None
    try:
        import ctypes

        prctl = ctypes.CDLL("libc.so.6", use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    return lambda: prctl(1, 15)   # PR_SET_PDEATHSIG, SIGTERM


class _WebViewer:
    """Rerun's web viewer (HTML, JS, Wasm) served by the `rerun` program in a child process,
    bound to `host` (`rerun --serve-web --bind HOST --web-viewer-port PORT URL`): the SDK's
    own `serve_web_viewer` listens on every interface and can never be stopped (rerun 0.41).
    The page connects to `grpc_url`, the logger's own gRPC server."""

    def __init__(self, host: str, port: int, grpc_url: str):
        import subprocess
        import tempfile
        import time

        bind = _bind_address(host)
        _check_port_free(bind, port, "rerun's web viewer")
        self._log = tempfile.TemporaryFile()
        cmd = [_rerun_binary(), "--serve-web", "--bind", bind, "--web-viewer-port", str(int(port)), grpc_url]
        try:
            self.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=self._log, stderr=subprocess.STDOUT,
                                         preexec_fn=_parent_death_signal())
        except OSError as e:
            self._log.close()
            raise RuntimeError(f"cannot start rerun's web viewer ({cmd[0]}): {e}") from None
        probe = {"0.0.0.0": "127.0.0.1", "::": "::1"}.get(bind, bind)
        deadline = time.monotonic() + WEB_VIEWER_START_S
        while True:
            if self.proc.poll() is not None:
                tail = self._tail()
                self._log.close()
                raise RuntimeError(f"rerun's web viewer did not start on {bind}:{port}: {tail}")
            try:
                socket.create_connection((probe, port), timeout=1.0).close()
                return
            except OSError:
                if time.monotonic() > deadline:
                    tail = self._tail()
                    self.stop()
                    raise RuntimeError(f"rerun's web viewer did not listen on {bind}:{port} within "
                                       f"{WEB_VIEWER_START_S:g} s: {tail}") from None
                time.sleep(0.1)

    def _tail(self) -> str:
        self._log.seek(0)
        lines = [ln for ln in self._log.read().decode(errors="replace").splitlines() if ln.strip()]
        return " ".join(" ".join(lines[-3:]).split())[-400:] or "(no output)"

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=5)
            except Exception:  # noqa: BLE001 - subprocess.TimeoutExpired
                self.proc.kill()
                self.proc.wait()
        self._log.close()


class RerunLogger:
    """Logs a session to rerun. `mode`:

    - "off": every method is a no-op, nothing is written;
    - "save": write `session_dir/session.rrd`;
    - "web": save too, and host a gRPC server plus rerun's web viewer (`web_port`), both
      bound to `host` only (the viewer is served by the `rerun` program in a child process,
      stopped by `close`); `web_url` is the page that opens this recording;
    - "connect": stream to a running viewer/server at `connect_url` (and save too when a
      `session_dir` is given).

    `latents` / `n_chains` (optional) let the first blueprint hold every view at once;
    without them the blueprint is re-sent once when the chains and latents are first seen.
    """

    def __init__(self, mode: str = "save", *, session_dir: Path | str | None = None, app_id: str = "galileo",
                 connect_url: str | None = None, web_port: int = 9090, grpc_port: int = 9876,
                 host: str = "127.0.0.1", recording_id: str | None = None,
                 latents: Sequence[str] | None = None, n_chains: int | None = None):
        if mode not in MODES:
            raise ValueError(f"rerun mode must be one of {', '.join(MODES)}, not {mode!r}")
        self.mode = mode
        self.web_url: str | None = None
        self.grpc_url: str | None = None
        self.rrd_path: Path | None = None
        self._lock = threading.Lock()
        self._chains: list[int] = []
        self._latents: list[str] = list(latents or [])
        self._dirty_sweep: int | None = None     # sweep in which new chains/latents were first seen
        self._named: set[str] = set()             # series given a legend name
        self._last_convergence: tuple | None = None   # what log_convergence logged last
        self._closed = False
        self._connectors: tuple = ()              # the drawing's (log_scene), drawn with each motion
        self._before_close: list = []             # callables run first by close() (a feed's thread)
        self._web: _WebViewer | None = None
        # frames as JPEG images, not the H.264 asset: a browser opening the web viewer from
        # another machine over http has no WebCodecs (secure contexts only), so no decoder
        self.video_as_images = mode == "web" and not _is_loopback(host)
        self.stream: rr.RecordingStream | None = None
        if mode == "off":
            return
        if n_chains:
            self._chains = list(range(int(n_chains)))
        if mode in ("save", "web") and session_dir is None:
            raise ValueError(f"rerun mode {mode!r} needs a session_dir to write {RRD_NAME} into")
        if mode == "web":
            _check_port_free(host, grpc_port)
        elif mode == "connect":
            self.grpc_url = connect_url or DEFAULT_CONNECT_URL
            _check_reachable(self.grpc_url)

        self.stream = rr.RecordingStream(app_id, recording_id=recording_id or uuid.uuid4().hex)
        blueprint = self._blueprint()
        sinks: list = []
        if session_dir is not None:
            session_dir = Path(session_dir)
            session_dir.mkdir(parents=True, exist_ok=True)
            self.rrd_path = session_dir / RRD_NAME
            # No footer: to write one, rerun keeps every chunk's metadata in memory until the
            # file closes (rerun issue 12623), which grew the app by 2-3 MB per 1,000 samples
            # logged, without bound. The file is a whole recording without it (`rerun rrd
            # optimize` writes a copy with one).
            sinks.append(rr.FileSink(self.rrd_path, write_footer=False))
        if mode == "web":
            server = rr.GrpcServerSink(host, grpc_port)   # rr.serve_grpc, but bindable and teed with the file
            sinks.append(server)
            self.grpc_url = server.uri
        elif mode == "connect":
            sinks.append(rr.GrpcSink(self.grpc_url))
        self.stream.set_sinks(*sinks, default_blueprint=blueprint)
        if session_dir is not None:
            self.stream.send_recording_name(Path(session_dir).name)
        if mode == "web":
            try:
                self._web = _WebViewer(host, web_port, self.grpc_url)
            except RuntimeError:
                self.stream.disconnect()
                self.stream = None
                raise
            page_host = "127.0.0.1" if host in ("0.0.0.0", "") else host
            page_host = f"[{page_host}]" if ":" in page_host else page_host   # an IPv6 address
            self.web_url = (f"http://{page_host}:{web_port}/?url="
                            f"{urllib.parse.quote(self.grpc_url, safe='')}")

    # -- state -----------------------------------------------------------------------

    @property
    def enabled(self) -> bool:
        return self.stream is not None and not self._closed

    def _at(self, timeline: str | None = None, value: int | None = None) -> None:
        self.stream.reset_time()
        if timeline is not None:
            self.stream.set_time(timeline, sequence=int(value))

    # -- blueprint -------------------------------------------------------------------

    def _blueprint(self) -> rrb.Blueprint:
        chains = self._chains
        latents = self._latents

        def series(name: str, leaf: str) -> rrb.TimeSeriesView:
            # no legend: 16 (or the splash's 50) chains' names covered the plots
            contents = [f"/chains/{c}/{leaf}" for c in chains] or [f"/chains/0/{leaf}"]
            return rrb.TimeSeriesView(name=name, origin="/chains", contents=contents,
                                      plot_legend=rrb.PlotLegend(visible=False))

        traces: list = [series("log-likelihood", "loglik")]
        shares = [2]
        if latents:
            traces.append(rrb.Grid(*[series(n, _part(n)) for n in latents], name="latents"))
            shares.append(3)
            posterior = rrb.Grid(*[rrb.BarChartView(name=f"posterior {n}", origin=f"/posterior/{_part(n)}")
                                   for n in latents], name="posterior")
        else:
            posterior = rrb.BarChartView(name="posterior", origin="/posterior")
        traces.append(rrb.TimeSeriesView(name="R-hat per latent", origin="/diagnostics/r_hat"))
        shares.append(1)
        traces.append(posterior)
        shares.append(3)
        left = rrb.Vertical(
            rrb.Spatial2DView(name="video + tracks", origin="/video"),
            rrb.Spatial3DView(name="simulation", origin="/", contents=["/scene/**", "/sim/**", "/observed/**"]),
            rrb.TextLogView(name="events", origin="/events"),
            row_shares=[3, 3, 1],
        )
        right = rrb.Vertical(*traces, row_shares=shares)
        return rrb.Blueprint(rrb.Horizontal(left, right, column_shares=[2, 3]),
                             rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"),
                             rrb.TimePanel(timeline="sweep", state="expanded"))

    def _resend_blueprint(self) -> None:
        self._dirty_sweep = None
        self.stream.send_blueprint(self._blueprint(), make_active=True, make_default=True)

    # -- inference -------------------------------------------------------------------

    def log_sweep(self, chain: int, sweep: int, loglik: float, values: dict[str, float]) -> None:
        """One chain's state after a sweep: chains/<chain>/loglik and chains/<chain>/<latent>."""
        if not self.enabled:
            return
        chain, sweep = int(chain), int(sweep)
        with self._lock:
            if self._dirty_sweep is not None and sweep > self._dirty_sweep:
                self._resend_blueprint()
            new_chain = chain not in self._chains
            new_latents = [n for n in values if n not in self._latents]
            if new_chain or new_latents:
                if new_chain:
                    self._chains.append(chain)
                    self._chains.sort()
                self._latents.extend(new_latents)
                if self._dirty_sweep is None:
                    self._dirty_sweep = sweep
        base = f"chains/{chain}"
        paths = [(f"{base}/loglik", loglik), *((f"{base}/{_part(n)}", v) for n, v in values.items())]
        for path, _ in paths:
            self._name_series(path, f"chain {chain}")
        self._at("sweep", sweep)
        for path, v in paths:
            self.stream.log(path, rr.Scalars(float(v)))

    def _name_series(self, path: str, name: str) -> None:
        """A series' legend name, once per series (static)."""
        if path not in self._named:
            self._named.add(path)
            self.stream.log(path, rr.SeriesLines(names=name), static=True)

    def _see(self, chains: Sequence[int], latents: Sequence[str]) -> None:
        """Make the blueprint hold these chains and latents (re-sent at once if it did not)."""
        with self._lock:
            new_chains = [int(c) for c in chains if int(c) not in self._chains]
            new_latents = [n for n in latents if n not in self._latents]
            if new_chains or new_latents:
                self._chains = sorted(self._chains + new_chains)
                self._latents.extend(new_latents)
                self._resend_blueprint()

    def log_trace(self, chain: int, names: Sequence[str], samples: np.ndarray, logliks: np.ndarray,
                  first_sweep: int = 1) -> None:
        """A chain's whole trace at once (`send_columns`, one call per series): sample i
        (samples (S, len(names)), logliks (S,)) at sweep first_sweep + i, the rows `log_sweep`
        writes one sweep at a time."""
        if not self.enabled:
            return
        chain = int(chain)
        names = list(names)
        logliks = np.asarray(logliks, np.float64).reshape(-1)
        samples = np.asarray(samples, np.float64).reshape(len(logliks), len(names))
        self._see([chain], names)
        if len(logliks) == 0:
            return
        sweeps = [rr.TimeColumn("sweep", sequence=np.arange(first_sweep, first_sweep + len(logliks)))]
        base = f"chains/{chain}"
        for path, col in [(f"{base}/loglik", logliks),
                          *((f"{base}/{_part(n)}", samples[:, j]) for j, n in enumerate(names))]:
            self._name_series(path, f"chain {chain}")
            self.stream.send_columns(path, indexes=sweeps, columns=rr.Scalars.columns(scalars=col))

    def log_events(self, events: Sequence[dict]) -> None:
        """Controller events ({"sweep", "kind", "detail", ...}) at `events`, in one call."""
        if not self.enabled or not events:
            return
        self.stream.send_columns("events", indexes=[rr.TimeColumn("sweep", sequence=[int(e["sweep"]) for e in events])],
                                 columns=rr.TextLog.columns(text=[event_text(e) for e in events],
                                                            level=["INFO"] * len(events)))

    def log_posterior(self, names: Sequence[str], samples: np.ndarray,
                      bounds: dict[str, tuple[float, float]], bins: int = 30) -> None:
        """Histograms of samples (..., len(names)) at posterior/<latent>, over the prior's bounds.

        Static: each call replaces the previous histogram (visible on every timeline)."""
        if not self.enabled:
            return
        names = list(names)
        samples = np.asarray(samples, float).reshape(-1, len(names))
        with self._lock:
            new = [n for n in names if n not in self._latents]
            if new:
                self._latents.extend(new)
                self._resend_blueprint()
        for j, name in enumerate(names):
            col = samples[:, j]
            col = col[np.isfinite(col)]
            lo, hi = bounds.get(name, (None, None)) if bounds else (None, None)
            if lo is None or hi is None:
                lo, hi = (float(col.min()), float(col.max())) if len(col) else (0.0, 1.0)
            if not hi > lo:
                hi = lo + 1e-9
            counts, edges = np.histogram(col, bins=int(bins), range=(float(lo), float(hi)))
            self.stream.log(f"posterior/{_part(name)}",
                            rr.BarChart(counts.astype(np.float64), abscissa=0.5 * (edges[1:] + edges[:-1]),
                                        widths=np.diff(edges).astype(np.float32)),
                            static=True)

    def log_convergence(self, sweep: int, r_hat: dict[str, float | None], converged: bool | None = None) -> None:
        """Per-latent R-hat at diagnostics/r_hat/<latent> (a latent without one, e.g. in warm-up,
        is left out) and diagnostics/converged (1/0) on the sweep timeline, when they changed
        since the last call."""
        if not self.enabled:
            return
        state = (tuple(sorted((str(k), v) for k, v in r_hat.items())), converged)
        with self._lock:
            if state == self._last_convergence:
                return
            self._last_convergence = state
        for name in r_hat:
            path = f"diagnostics/r_hat/{_part(name)}"
            if path not in self._named:          # legend name, once per series
                self._named.add(path)
                self.stream.log(path, rr.SeriesLines(names=str(name)), static=True)
        self._at("sweep", sweep)
        for name, v in r_hat.items():
            if v is not None and np.isfinite(v):
                self.stream.log(f"diagnostics/r_hat/{_part(name)}", rr.Scalars(float(v)))
        if converged is not None:
            self.stream.log("diagnostics/converged", rr.Scalars(float(bool(converged))))

    def log_event(self, sweep: int, text: str, level: str = "INFO") -> None:
        """A text event (prior edit, restart, ...) on the sweep timeline at `events`."""
        if not self.enabled:
            return
        self._at("sweep", sweep)
        self.stream.log("events", rr.TextLog(str(text), level=level))

    # -- the scene ---------------------------------------------------------------------

    def log_scene(self, drawing) -> None:
        """The scene's static geometry (`Scenario.drawing(scene).static`: the ramp, the tank, the
        water) at scene/<name>, static, so the simulation view shows where the paths run; its
        connectors are logged with every simulated motion from then on (`log_simulation`)."""
        if not self.enabled:
            return
        self._connectors = tuple(drawing.connectors)
        self._at()
        for m in drawing.static:
            rgba = [*m.color, int(round(255 * float(m.opacity)))]
            self.stream.log(f"scene/{'/'.join(_part(x) for x in m.name.split('/'))}",
                            rr.Mesh3D(vertex_positions=np.asarray(m.vertices, np.float32),
                                      triangle_indices=np.asarray(m.faces, np.uint32), albedo_factor=rgba),
                            static=True)

    # -- video and tracks ------------------------------------------------------------

    def log_video(self, video_path: str | Path, tracks=None, fps: float | None = None) -> None:
        """The video at `video` (H.264 asset + a frame reference per frame on timeline `frame`)
        and the tracks over it (video/tracks/<object>) and in 3-D (observed/<object>).
        Frames are indexed by number (frame i = the i-th decoded frame), so `fps` is
        informational only."""
        if not self.enabled:
            return
        video_path = Path(video_path)
        n_track_frames = tracks.n_frames if tracks is not None else None
        n_frames = None
        if not self.video_as_images:
            try:
                n_frames = self._log_video_asset(video_path)
            except Exception as e:     # unreadable by rerun, or a codec its viewer does not play
                log.info("rerun: %s not logged as a video asset (%s); logging decoded frames", video_path, e)
        if n_frames is None:
            n_frames = self._log_video_images(video_path, n_track_frames)
        if tracks is not None:
            self._log_tracks(tracks, n_frames)

    def _log_video_asset(self, video_path: Path) -> int:
        import av
        with av.open(str(video_path)) as box:
            codec = box.streams.video[0].codec_context.name
        if codec not in VIDEO_CODECS:
            raise ValueError(f"codec {codec} is not played by rerun")
        asset = rr.AssetVideo(path=video_path)
        ts_ns = np.asarray(asset.read_frame_timestamps_nanos(), np.int64)
        if len(ts_ns) == 0:
            raise ValueError("no frames")
        self._at()
        self.stream.log("video", asset, static=True)
        self.stream.send_columns("video", indexes=[rr.TimeColumn("frame", sequence=np.arange(len(ts_ns)))],
                                 columns=rr.VideoFrameReference.columns_nanos(ts_ns))
        # the blueprint opens on timeline "sweep", where the frame references above do not
        # exist: without this row the panel reads "No data available" until one picks "frame"
        self._at("sweep", 0)
        self.stream.log("video", rr.VideoFrameReference(nanoseconds=int(ts_ns[0])))
        return len(ts_ns)

    def _log_video_images(self, video_path: Path, n_hint: int | None) -> int:
        from galileo.video import read_frames
        n = 0
        step = None
        if n_hint:
            step = max(1, -(-n_hint // FALLBACK_MAX_FRAMES))
        for i, frame in enumerate(read_frames(video_path)):
            n = i + 1
            if step is None:
                step = 1 if i < FALLBACK_MAX_FRAMES else 2   # unknown length: thin out late frames
            if i % step:
                continue
            image = rr.Image(frame).compress(jpeg_quality=FALLBACK_JPEG_QUALITY)
            self._at("frame", i)
            self.stream.log("video", image)
            if i == 0:      # on the blueprint's timeline too (see _log_video_asset)
                self._at("sweep", 0)
                self.stream.log("video", image)
        return n

    def _log_tracks(self, tracks, n_video_frames: int | None) -> None:
        n = tracks.n_frames if n_video_frames is None else min(tracks.n_frames, n_video_frames)
        if n == 0:
            return
        frames = rr.TimeColumn("frame", sequence=np.arange(n))
        self._at()
        for i, o in enumerate(tracks.objects):
            color = TRACK_COLORS[i % len(TRACK_COLORS)]
            base = f"video/tracks/{_part(o.name)}"
            centre = None
            if o.center_px is not None:
                centre = np.asarray(o.center_px, float).reshape(-1, 2)[:n]
            feats = list(o.features_px[:n]) if o.features_px else []
            if feats:
                per_frame = [np.asarray(f, float).reshape(-1, 2) if f is not None else np.zeros((0, 2))
                             for f in feats] + [np.zeros((0, 2))] * (n - len(feats))
            elif centre is not None:
                per_frame = [c[None] if np.all(np.isfinite(c)) else np.zeros((0, 2)) for c in centre]
            else:
                per_frame = []
            if per_frame:
                self._send_points2d(base, frames, per_frame, color, radius=2.0)
            if centre is not None:
                ok = np.all(np.isfinite(centre), axis=1)
                cframes = rr.TimeColumn("frame", sequence=np.flatnonzero(ok))
                if ok.any():
                    self.stream.log(f"{base}/center", rr.Points2D.from_fields(
                        colors=[color], radii=[5.0], labels=[o.name], show_labels=True), static=True)
                    self.stream.send_columns(f"{base}/center", indexes=[cframes],
                                             columns=rr.Points2D.columns(positions=centre[ok]))
                    self.stream.log(f"{base}/path", rr.LineStrips2D(_finite_runs(centre), colors=[color],
                                                                    radii=[1.0]), static=True)
            # tracked positions in metres, next to the simulation
            pos = np.asarray(o.position_m, float).reshape(-1, 3)[:n]
            ok = np.all(np.isfinite(pos), axis=1)
            if ok.any():
                obase = f"observed/{_part(o.name)}"
                self.stream.log(obase, rr.LineStrips3D(_finite_runs(pos), colors=[OBSERVED_COLOR],
                                                       radii=[0.002], labels=[f"{o.name} (observed)"],
                                                       show_labels=False), static=True)
                self.stream.log(obase, rr.Points3D.from_fields(colors=[OBSERVED_COLOR], radii=[0.01]), static=True)
                self.stream.send_columns(obase, indexes=[rr.TimeColumn("frame", sequence=np.flatnonzero(ok))],
                                         columns=rr.Points3D.columns(positions=pos[ok]))

    def _send_points2d(self, entity: str, frames: rr.TimeColumn, per_frame: list[np.ndarray],
                       color, radius: float) -> None:
        """Points per frame in one chunk (an empty batch where a frame has none, so none linger)."""
        self.stream.log(entity, rr.Points2D.from_fields(colors=[color], radii=[radius]), static=True)
        lengths = [len(p) for p in per_frame]
        flat = np.concatenate(per_frame) if sum(lengths) else np.zeros((0, 2))
        self.stream.send_columns(entity, indexes=[frames],
                                 columns=rr.Points2D.columns(positions=flat).partition(lengths))

    # -- simulation ------------------------------------------------------------------

    def log_simulation(self, traj, kind: str = "selected", sweep: int | None = None, note: str = "") -> None:
        """A simulated trajectory at sim/<kind>/<object> (kind "selected" or "map"): its path
        and the object's position per frame on timeline `frame` (replacing the previous
        trajectory of that kind). The path is static, or with `sweep` logged at that sweep
        (and at frame 0, so "frame" shows the latest), which keeps the MAP's history."""
        if not self.enabled:
            return
        if kind not in SIM_KINDS:
            raise ValueError(f"kind must be one of {', '.join(SIM_KINDS)}, not {kind!r}")
        pos_all = np.asarray(traj.position_m, float)
        n = pos_all.shape[1]
        if n == 0:
            return
        palette = MAP_COLORS if kind == "map" else SIM_COLORS
        for i, name in enumerate(traj.names):
            color = palette[i % len(palette)]
            entity = f"sim/{kind}/{_part(name)}"
            pos = pos_all[i]
            ok = np.all(np.isfinite(pos), axis=1)
            # (labels on hover: drawn, the observed, MAP and selected paths' labels lay on each other)
            path = rr.LineStrips3D(_finite_runs(pos), colors=[color], radii=[0.003],
                                   labels=[f"{name} ({SIM_KINDS[kind]}{note})"], show_labels=False)
            self._at()
            if sweep is None:
                self.stream.log(entity, path, static=True)
            else:
                self.stream.set_time("sweep", sequence=int(sweep))
                self.stream.set_time("frame", sequence=0)
                self.stream.log(entity, path)
                self._at()
            self.stream.log(entity, rr.Points3D.from_fields(colors=[color], radii=[0.015]), static=True)
            lengths = ok.astype(int)
            self.stream.send_columns(entity, indexes=[rr.TimeColumn("frame", sequence=np.arange(n))],
                                     columns=rr.Points3D.columns(positions=pos[ok]).partition(lengths))
        for c in self._connectors:
            entity = f"sim/{kind}/connectors/{_part(c.name)}"
            self.stream.log(entity, rr.LineStrips3D.from_fields(colors=[c.color],
                                                                radii=rr.Radius.ui_points(c.width_px / 2)), static=True)
            strips = [connector_points(c, *frame_pose(traj, f)) for f in range(n)]
            self.stream.send_columns(entity, indexes=[rr.TimeColumn("frame", sequence=np.arange(n))],
                                     columns=rr.LineStrips3D.columns(strips=strips).partition([1] * n))

    def log_selected(self, traj, chain: int | None = None, index: int | None = None) -> None:
        """The sample the viewer shows (its re-simulated Trajectory) at sim/selected/<object>:
        the callable to hand the viewer, called on each new selection."""
        note = "" if chain is None else f", chain {chain}" + ("" if index is None else f" sample {index}")
        self.log_simulation(traj, "selected", note=note)

    def log_map(self, traj, sweep: int, chain: int | None = None, index: int | None = None) -> None:
        """The MAP sample's simulated motion at sim/map/<object>, as found at `sweep`."""
        note = "" if chain is None else f", chain {chain}" + ("" if index is None else f" sample {index}")
        self.log_simulation(traj, "map", sweep=sweep, note=note)

    # -- lifetime --------------------------------------------------------------------

    def flush(self) -> None:
        if not self.enabled:
            return
        with self._lock:
            if self._dirty_sweep is not None:
                self._resend_blueprint()
        try:
            self.stream.flush()
        except RuntimeError as e:    # a viewer that went away: never fatal to the caller
            log.warning("rerun flush failed: %s", e)

    def close(self) -> None:
        """Flush and close every sink (finishes the .rrd; in mode "web" stops the gRPC server
        and the web viewer's process). Idempotent, never raises for a sink that went away."""
        if not self.enabled:
            return
        for fn in list(self._before_close):
            try:
                fn()
            except Exception:  # noqa: BLE001 - closing goes on
                log.exception("rerun: closing %r failed", fn)
        self.flush()
        self._closed = True
        try:
            self.stream.disconnect()
        except RuntimeError as e:
            log.warning("rerun disconnect failed: %s", e)
        if self._web is not None:
            self._web.stop()

    def __enter__(self) -> "RerunLogger":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# -- a controller's session ----------------------------------------------------------

def _sweeps_at(events: Sequence[dict], rounds: int, counts: dict[int, int]):
    """Chain sweeps at a past round, from the events' "chain_sweeps" snapshots (each pause,
    resume, addition and removal is an event, so between two snapshots holding a chain it
    runs every round or none: its count grows by one a round until the later one's).
    `counts`: every chain's sweeps now (removed ones too), the last snapshot; before a
    chain's first snapshot it counts from 0 at round 0 (a session recorded without them:
    the chains ran together). Returns f(round) -> {chain: sweeps}."""
    snaps = [(int(ev["sweep"]), {int(c): int(n) for c, n in ev["chain_sweeps"].items()})
             for ev in events if isinstance(ev.get("chain_sweeps"), dict)]
    snaps.append((int(rounds), dict(counts)))
    snaps.sort(key=lambda s: s[0])    # stable: snapshots of one round keep their order

    per_chain = {c: [(rs, snap[c]) for rs, snap in snaps if c in snap] for c in counts}

    def at(r: int) -> dict[int, int]:
        out = {}
        for c, seen in per_chain.items():
            i = bisect.bisect_right([rs for rs, _ in seen], r)    # seen[:i]: at or before r
            ra, a = seen[i - 1] if i else (0, 0)
            out[c] = a if i == len(seen) else int(a + np.clip(r - ra, 0, max(seen[i][1] - a, 0)))
        return out
    return at


class ControllerFeed:
    """Feeds a `RerunLogger` from a `ui.controller.Controller`.

    - `on_controller`: the listener (`ctrl.add_listener(feed.on_controller)`): each chain's
      sweep, every `every` rounds (default: the number of chains) the posterior of the kept
      draws, the convergence verdict and the MAP's motion, and the events;
    - `log_history()`: a reopened session's whole past before it goes on: every chain's trace
      from sweep 1 (sample i at sweep i + 1, as the listener logs it live), the events, the
      R-hat history (recomputed from the samples at the rounds a live run logs it, at most
      HISTORY_CHECKS of them), the posterior and the MAP; the listener then skips what it
      logged, so nothing is logged twice;
    - the MAP's motion (sim/map/<object>) is simulated in a thread of its own, and only when
      the MAP (chain, index) changed; `motion_model`: a zero-argument factory of an object
      with `motion(position) -> Trajectory` (default: the scenario's likelihood, which the
      viewer draws with too), built in that thread.

    The logger's close() stops the thread (after the MAP asked for last is logged)."""

    def __init__(self, logger: RerunLogger, ctrl, *, every: int | None = None, motion_model=None):
        self.logger = logger
        self.ctrl = ctrl
        self.every = max(1, int(every if every is not None else len(ctrl.chain_ids())))
        self._motion_model = motion_model
        self._history_upto: dict[int, int] = {}   # chain -> last sweep log_history logged
        self._history_events: set = set()         # (sweep, time, kind) of the events it logged
        self._map_key: tuple | None = None        # (chain, index) of the MAP logged last
        self._want: int | None = None             # a MAP check asked for, at this sweep
        self._cv = threading.Condition()
        self._stop = False
        self._thread: threading.Thread | None = None
        if logger.enabled:
            logger._before_close.append(self.close)
            logger.log_scene(ctrl.scenario.drawing(ctrl.likelihood_scene))

    # -- the listener ----------------------------------------------------------------

    def on_controller(self, kind: str, payload: dict) -> None:
        log_ = self.logger
        if not log_.enabled:
            return
        if kind == "sweeps":
            for chain, sweep, loglik, values in payload["results"]:
                if sweep > self._history_upto.get(chain, 0):
                    log_.log_sweep(chain, sweep, loglik, values)
            if payload["round"] % self.every == 0:
                self.log_posterior()
                self.log_convergence(payload["round"])
                self.request_map(payload["round"])
        elif kind == "event":
            key = (payload["sweep"], payload.get("time"), payload["kind"])
            if key not in self._history_events:
                log_.log_event(payload["sweep"], event_text(payload))
            if payload["kind"] == "until_check":
                self.log_convergence(payload["sweep"])
            if payload["kind"] in ("until_check", "pause"):   # (chains stopped: where they got to)
                self.request_map(payload["sweep"])

    def log_posterior(self) -> None:
        from galileo.results import burn_in

        ctrl = self.ctrl
        kept = [s[burn_in(len(s), ctrl.warmup):] for s in (ctrl.samples(c) for c in ctrl.chain_ids()) if len(s)]
        if kept and sum(len(k) for k in kept):
            self.logger.log_posterior(ctrl.names, np.concatenate(kept), ctrl.settings.bounds)

    def log_convergence(self, sweep: int) -> None:
        conv = self.ctrl.status()["convergence"]
        self.logger.log_convergence(sweep, conv["r_hat"], conv["converged"])

    # -- a reopened session ----------------------------------------------------------

    def log_history(self) -> None:
        """Everything the controller holds, logged as a live run would have (call it before
        the controller runs on)."""
        log_, ctrl = self.logger, self.ctrl
        if not log_.enabled:
            return
        from galileo.results import burn_in, convergence

        names = list(ctrl.names)
        ids = ctrl.all_chain_ids()
        log_._see(ids, names)           # (one blueprint for them all)
        samples = {c: ctrl.samples(c) for c in ids}
        for c in ids:
            log_.log_trace(c, names, samples[c], ctrl.logliks(c), first_sweep=1)
            self._history_upto[c] = len(samples[c])
        events = ctrl.events
        log_.log_events(events)
        self._history_events = {(e["sweep"], e.get("time"), e["kind"]) for e in events}
        status = ctrl.status()
        rounds = int(status["rounds"])
        conv_now = status["convergence"]
        # R-hat as the listener logged it: every `every` rounds and at each until_check,
        # from the draws the chains had then (thinned to HISTORY_CHECKS, the last kept)
        checks = set(range(self.every, rounds + 1, self.every))
        until = {int(e["sweep"]) for e in events if e["kind"] == "until_check"}
        regular = sorted(checks - until)
        if len(regular) > HISTORY_CHECKS:
            pick = np.unique(np.linspace(0, len(regular) - 1, HISTORY_CHECKS).round().astype(int))
            regular = [regular[i] for i in pick]
        checks = sorted(set(regular) | until)
        removed_at = {}
        for e in events:
            if e["kind"] == "remove_chain":
                for c in e["detail"].get("chains", []):
                    removed_at[int(c)] = int(e["sweep"])
        at = _sweeps_at(events, rounds, {c: len(s) for c, s in samples.items()})
        for r in checks:
            if r == rounds:     # (now's: the controller's own verdict, below)
                continue
            counts = at(r)
            kept = [samples[c][burn_in(n, ctrl.warmup):n] for c, n in sorted(counts.items())
                    if n and removed_at.get(c, r) >= r]
            conv = convergence(kept, names, conv_now["rhat_target"], conv_now["min_ess"])
            log_.log_convergence(r, conv["r_hat"], conv["converged"])
        if rounds:
            log_.log_convergence(rounds, conv_now["r_hat"], conv_now["converged"])
        self.log_posterior()
        self.request_map(rounds)

    # -- the MAP's motion ----------------------------------------------------------------

    def request_map(self, sweep: int) -> None:
        """Ask for the MAP's motion to be logged at `sweep` if the MAP changed (never blocks)."""
        if not self.logger.enabled:
            return
        with self._cv:
            if self._stop:
                return
            self._want = int(sweep)
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="rerun-map", daemon=True)
                self._thread.start()
            self._cv.notify_all()

    def _run(self) -> None:
        model = None
        while True:
            with self._cv:
                while self._want is None and not self._stop:
                    self._cv.wait()
                if self._want is None:
                    return
                sweep, self._want = self._want, None
            try:
                best = self.ctrl.map()
                if best is None or (best[0], best[1]) == self._map_key:
                    continue
                if model is None:
                    model = self._make_model()
                chain, index, values = best[0], best[1], best[2]
                traj = model.motion(np.array([values[n] for n in self.ctrl.names], float))
                self.logger.log_map(traj, sweep, chain, index)
                self._map_key = (chain, index)
            except Exception:  # noqa: BLE001 - a failed simulation must not end the feed
                log.exception("rerun: logging the MAP's motion failed")

    def _make_model(self):
        if self._motion_model is not None:
            return self._motion_model()
        from galileo import registry

        ctrl = self.ctrl
        scene = ctrl.likelihood_scene
        return registry.of(scene).likelihood(scene, ctrl.tracks, ctrl.settings.noise)

    def close(self) -> None:
        """Stop the MAP thread once it logged what was asked for (idempotent)."""
        with self._cv:
            self._stop = True
            self._cv.notify_all()
            thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=60)
