"""ui.rerun_log: what RerunLogger writes, read back with rerun's own .rrd reader."""
from __future__ import annotations

import socket
import subprocess
import sys
import textwrap
import time
import urllib.request
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

rr = pytest.importorskip("rerun")
chunk = pytest.importorskip("rerun.chunk")   # needs rerun-sdk[catalog]

from ui import rerun_log  # noqa: E402
from ui.rerun_log import RRD_NAME, RerunLogger  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
LATENTS = ("m1_kg", "k1", "m2_kg", "k2")


def read_rrd(path: Path) -> dict[str, list[tuple[set[str], dict]]]:
    """entity path (without the leading '/') -> [(timeline names, columns as lists)] per chunk."""
    out = defaultdict(list)
    for ch in chunk.RrdReader(path).stream().to_chunks():
        out[ch.entity_path.lstrip("/")].append((set(ch.timeline_names), ch.to_record_batch().to_pydict()))
    return dict(out)


def series(entities, entity: str, timeline: str, column: str) -> list:
    """(time, value) rows of one component on one timeline, in time order."""
    rows = []
    for timelines, cols in entities.get(entity, []):
        if timeline in timelines and column in cols:
            rows += zip(cols[timeline], cols[column])
    return sorted(rows, key=lambda r: r[0])


def blueprint_queries(path: Path) -> list[list[str]]:
    """The view-content queries of every blueprint stored in the file."""
    reader = chunk.RrdReader(path)
    out = []
    for bp in reader.blueprints():
        qs = []
        for ch in reader.stream(store=bp).to_chunks():
            cols = ch.to_record_batch().to_pydict()
            for q in cols.get("ViewContents:query", []):
                qs += q or []
        out.append(qs)
    return out


def blueprint_views(path: Path) -> list[tuple[str | None, dict[str, str]]]:
    """Per stored blueprint: (the time panel's timeline, {view name: its origin})."""
    reader = chunk.RrdReader(path)
    out = []
    for bp in reader.blueprints():
        timeline, views = None, {}
        for ch in reader.stream(store=bp).to_chunks():
            cols = ch.to_record_batch().to_pydict()
            if cols.get("TimePanelBlueprint:timeline"):
                timeline = cols["TimePanelBlueprint:timeline"][-1][0]
            for name, origin in zip(cols.get("ViewBlueprint:display_name", []),
                                    cols.get("ViewBlueprint:space_origin", [])):
                if name and origin:
                    views[name[0]] = origin[0].lstrip("/")
        out.append((timeline, views))
    return out


IMAGE_COLUMNS = ("VideoFrameReference:timestamp", "EncodedImage:blob", "Image:buffer")


def shows_an_image(entities, origin: str, timeline: str) -> bool:
    """Whether a 2-D view at `origin` has a picture to draw on `timeline`: an image or video
    frame row under it, static or on that timeline (rows on other timelines do not show)."""
    for entity, chunks in entities.items():
        if entity == origin or entity.startswith(origin + "/"):
            for timelines, cols in chunks:
                if (not timelines or timeline in timelines) and any(cols.get(c) for c in IMAGE_COLUMNS):
                    return True
    return False


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def demo_tracks(demo_dir):
    """Live tracking of the rendered demo (the frozen tracks hold no image features, which
    the video overlay draws); the tests compare the log with these very tracks."""
    from galileo.scenarios.ramp.scene import Scene
    from galileo.scenarios.ramp.tracking import track

    return track(demo_dir / "video.mp4", Scene.load(demo_dir / "scene.json"), progress=False)


def test_save_sweeps_posterior_event_simulation(tmp_path):
    from galileo.scenarios.ramp.physics import Simulator
    from galileo.scenarios.ramp.scene import default_scene

    traj = Simulator(default_scene(20, target="cardboard")).run(20)
    rng = np.random.default_rng(1)
    logged = {c: {"loglik": [], **{n: [] for n in LATENTS}} for c in range(3)}
    log = RerunLogger("save", session_dir=tmp_path, recording_id="test-save")
    # a simulation first: its frame cursor must not leak onto the sweep rows
    log.log_simulation(traj)
    for sweep in range(6):
        for c in range(3):
            values = {n: float(v) for n, v in zip(LATENTS, rng.uniform(0.1, 5.0, 4))}
            ll = float(-rng.uniform(10, 1000))
            log.log_sweep(c, sweep, ll, values)
            logged[c]["loglik"].append(ll)
            for n, v in values.items():
                logged[c][n].append(v)
        if sweep == 3:
            log.log_event(sweep, "prior edit: k1 in [0.2, 0.6]")
    samples = rng.uniform(0.1, 5.0, (3, 6, 4))
    bounds = {n: (0.0, 5.0) for n in LATENTS}
    log.log_posterior(LATENTS, samples, bounds, bins=10)
    log.close()
    log.close()   # idempotent

    path = tmp_path / RRD_NAME
    assert path.is_file() and path.stat().st_size > 0
    ents = read_rrd(path)
    for c in range(3):
        for leaf, values in logged[c].items():
            rows = series(ents, f"chains/{c}/{leaf}", "sweep", "Scalars:scalars")
            assert [t for t, _ in rows] == list(range(6))
            assert [v[0] for _, v in rows] == values          # exact float64 round trip, in order
        for timelines, cols in ents[f"chains/{c}/loglik"]:
            assert "frame" not in timelines
    for n in LATENTS:
        (timelines, cols), = [e for e in ents[f"posterior/{n}"] if "BarChart:values" in e[1]]
        assert not timelines                                  # static
        hist = cols["BarChart:values"][0][0]
        assert hist["shape"] == [10] and sum(hist["buffer"]) == samples.size // 4
        assert len(cols["BarChart:abscissa"][0][0]["buffer"]) == 10
    events = series(ents, "events", "sweep", "TextLog:text")
    assert events == [(3, ["prior edit: k1 in [0.2, 0.6]"])]
    for name in traj.names:
        pts = series(ents, f"sim/selected/{name}", "frame", "Points3D:positions")
        assert [t for t, _ in pts] == list(range(20))
        np.testing.assert_allclose(np.array([p[0] for _, p in pts]), traj.position_m[traj.names.index(name)],
                                   rtol=1e-6, atol=1e-6)
        assert any(not tl and "LineStrips3D:strips" in cols for tl, cols in ents[f"sim/selected/{name}"])
    # the default blueprint was extended to the chains and latents seen
    queries = blueprint_queries(path)
    assert any({"/chains/2/loglik", "/chains/0/k2", "/chains/2/m1_kg"} <= set(q) for q in queries)


def test_r_hat_per_latent_when_it_changes(tmp_path):
    """diagnostics/r_hat/<latent> and diagnostics/converged on the sweep timeline: a latent
    without an R-hat (warm-up) is left out, an unchanged status is not logged again."""
    log = RerunLogger("save", session_dir=tmp_path, latents=LATENTS, n_chains=2)
    log.log_convergence(2, dict.fromkeys(LATENTS), False)                       # warm-up: no R-hat yet
    log.log_convergence(5, {"m1_kg": 1.31, "k1": 1.02, "m2_kg": 1.25, "k2": None}, False)
    log.log_convergence(6, {"m1_kg": 1.31, "k1": 1.02, "m2_kg": 1.25, "k2": None}, False)   # unchanged
    log.log_convergence(9, {"m1_kg": 1.004, "k1": 1.001, "m2_kg": 1.006, "k2": 1.009}, True)
    log.close()
    ents = read_rrd(tmp_path / RRD_NAME)
    rows = {n: [(t, v[0]) for t, v in series(ents, f"diagnostics/r_hat/{n}", "sweep", "Scalars:scalars")]
            for n in LATENTS}
    assert rows == {"m1_kg": [(5, 1.31), (9, 1.004)], "k1": [(5, 1.02), (9, 1.001)],
                    "m2_kg": [(5, 1.25), (9, 1.006)], "k2": [(9, 1.009)]}
    conv = series(ents, "diagnostics/converged", "sweep", "Scalars:scalars")
    assert [(t, v[0]) for t, v in conv] == [(2, 0.0), (5, 0.0), (9, 1.0)]
    queries = blueprint_queries(tmp_path / RRD_NAME)
    assert len(queries) == 1


def test_known_layout_sends_one_blueprint(tmp_path):
    log = RerunLogger("save", session_dir=tmp_path, latents=LATENTS, n_chains=2)
    for sweep in range(3):
        for c in range(2):
            log.log_sweep(c, sweep, -1.0, dict.fromkeys(LATENTS, 1.0))
    log.close()
    queries = blueprint_queries(tmp_path / RRD_NAME)
    assert len(queries) == 1 and "/chains/1/k2" in queries[0]


def test_log_video_demo(demo_dir, demo_tracks, tmp_path):
    tracks = demo_tracks
    log = RerunLogger("save", session_dir=tmp_path)
    log.log_video(demo_dir / "video.mp4", tracks, tracks.fps)
    log.close()
    path = tmp_path / RRD_NAME
    ents = read_rrd(path)
    n = tracks.n_frames
    video = ents["video"]
    assert any(not tl and "AssetVideo:blob" in cols for tl, cols in video)
    refs = series(ents, "video", "frame", "VideoFrameReference:timestamp")
    assert [t for t, _ in refs] == list(range(n))
    assert [r[0] for _, r in refs] == sorted(r[0] for _, r in refs)     # presentation order
    for o in tracks.objects:
        pts = series(ents, f"video/tracks/{o.name}", "frame", "Points2D:positions")
        assert [t for t, _ in pts] == list(range(n))
        assert len(pts[0][1]) == len(o.features_px[0]) > 0
        np.testing.assert_allclose(np.array(pts[0][1]), o.features_px[0], atol=1e-3)
        centre = series(ents, f"video/tracks/{o.name}/center", "frame", "Points2D:positions")
        assert len(centre) == int(o.visible.sum())
        assert series(ents, f"observed/{o.name}", "frame", "Points3D:positions")
    print(f"demo video session .rrd: {path.stat().st_size} bytes "
          f"(video.mp4 {(demo_dir / 'video.mp4').stat().st_size} bytes)")


def test_video_panel_shows_a_frame_on_the_blueprints_timeline(demo_dir, tmp_path):
    """Issue 14, defect 9: rerun's web viewer showed no video frame. The blueprint opens on
    timeline "sweep" (the traces'), and the frame references were on timeline "frame" only,
    so the video view read "No data available" (seen in Chromium: the H.264 asset decodes
    there once "frame" is picked). Frame 0 is referenced at sweep 0 too; every reference
    falls on a frame of the video as rerun reads it."""
    log = RerunLogger("save", session_dir=tmp_path, latents=LATENTS, n_chains=1)
    log.log_video(demo_dir / "video.mp4")
    log.log_sweep(0, 1, -3.0, dict.fromkeys(LATENTS, 1.0))
    log.close()
    path = tmp_path / RRD_NAME
    ents = read_rrd(path)
    for timeline, views in blueprint_views(path):
        assert timeline == "sweep" and views["video + tracks"] == "video"
        assert shows_an_image(ents, views["video + tracks"], timeline)
    # the references' timestamps are frames of the asset, within its duration
    (blob,), = [cols["AssetVideo:blob"] for tl, cols in ents["video"] if "AssetVideo:blob" in cols]
    asset_ts = rr.AssetVideo(contents=bytes(blob[0]), media_type="video/mp4").read_frame_timestamps_nanos()
    import av

    with av.open(str(demo_dir / "video.mp4")) as box:
        s = box.streams.video[0]
        duration_ns = float(s.duration * s.time_base) * 1e9
    refs = [r[0] for _, r in series(ents, "video", "frame", "VideoFrameReference:timestamp")]
    poster = [r[0] for _, r in series(ents, "video", "sweep", "VideoFrameReference:timestamp")]
    assert refs == list(asset_ts) and poster == [asset_ts[0]]
    assert 0 <= min(refs) and max(refs) < duration_ns


def test_jpeg_frames_for_a_browser_without_webcodecs(demo_dir, demo_tracks, tmp_path, monkeypatch):
    """A web viewer opened from another machine over http has no WebCodecs (secure contexts
    only): mode "web" on a non-loopback host logs JPEG frames, shown on "sweep" too."""
    assert rerun_log._is_loopback("127.0.0.1") and rerun_log._is_loopback("localhost")
    assert not rerun_log._is_loopback("0.0.0.0") and not rerun_log._is_loopback("192.168.1.20")
    monkeypatch.setattr(rerun_log, "FALLBACK_MAX_FRAMES", 10)
    log = RerunLogger("save", session_dir=tmp_path)
    assert not log.video_as_images
    log.video_as_images = True       # what RerunLogger("web", host="0.0.0.0") sets
    log.log_video(demo_dir / "video.mp4", demo_tracks)
    log.close()
    path = tmp_path / RRD_NAME
    ents = read_rrd(path)
    assert not any("AssetVideo:blob" in cols for _, cols in ents["video"])
    assert len(series(ents, "video", "frame", "EncodedImage:blob")) <= 10
    assert [t for t, _ in series(ents, "video", "sweep", "EncodedImage:blob")] == [0]
    assert shows_an_image(ents, "video", "sweep")


def test_map_and_selected_simulations(tmp_path):
    """sim/map/<object>: the MAP's path at the sweep it was found (history on "sweep", the
    latest on "frame"); sim/selected/<object>: the viewer's sample, static."""
    from galileo.scenarios.ramp.physics import Simulator
    from galileo.scenarios.ramp.scene import default_scene

    first = Simulator(default_scene(20, target="cardboard")).run(12)
    second = Simulator(default_scene(20, target="foam")).run(12)
    log = RerunLogger("save", session_dir=tmp_path)
    log.log_map(first, 3, chain=0, index=2)
    log.log_map(second, 7, chain=1, index=6)
    log.log_selected(first, 1, 4)
    log.close()
    ents = read_rrd(tmp_path / RRD_NAME)
    for j, name in enumerate(first.names):
        strips = series(ents, f"sim/map/{name}", "sweep", "LineStrips3D:strips")
        assert [t for t, _ in strips] == [3, 7]
        np.testing.assert_allclose(np.array(strips[1][1][0]), second.position_m[j], rtol=1e-6, atol=1e-6)
        assert not any(not tl for tl, cols in ents[f"sim/map/{name}"] if "LineStrips3D:strips" in cols)
        on_frames = series(ents, f"sim/map/{name}", "frame", "LineStrips3D:strips")
        assert [t for t, _ in on_frames] == [0, 0]      # (the latest logged wins on "frame")
        pts = series(ents, f"sim/map/{name}", "frame", "Points3D:positions")
        assert [t for t, _ in pts] == sorted(list(range(12)) * 2)
        np.testing.assert_allclose(np.array([p[0] for _, p in pts[1::2]]), second.position_m[j], atol=1e-6)
        labels = series(ents, f"sim/map/{name}", "sweep", "LineStrips3D:labels")
        assert labels[1][1] == [f"{name} (MAP, chain 1 sample 6)"]
        (tl, cols), = [e for e in ents[f"sim/selected/{name}"] if "LineStrips3D:strips" in e[1]]
        assert not tl and cols["LineStrips3D:labels"][0] == [f"{name} (selected, chain 1 sample 4)"]
    queries = blueprint_queries(tmp_path / RRD_NAME)
    assert all("/sim/**" in q for q in queries)


def test_log_video_falls_back_to_images(demo_dir, demo_tracks, tmp_path, monkeypatch):
    def broken(*a, **k):
        raise RuntimeError("no video support")

    monkeypatch.setattr(rerun_log.rr, "AssetVideo", broken)
    monkeypatch.setattr(rerun_log, "FALLBACK_MAX_FRAMES", 20)
    log = RerunLogger("save", session_dir=tmp_path)
    log.log_video(demo_dir / "video.mp4", demo_tracks, demo_tracks.fps)
    log.close()
    ents = read_rrd(tmp_path / RRD_NAME)
    frames = [t for t, _ in series(ents, "video", "frame", "EncodedImage:blob")]
    n = demo_tracks.n_frames
    step = -(-n // 20)
    assert frames == list(range(0, n, step)) and len(frames) <= 20
    assert not series(ents, "video", "frame", "VideoFrameReference:timestamp")
    assert series(ents, f"video/tracks/{demo_tracks.objects[0].name}", "frame", "Points2D:positions")


def test_off_is_a_no_op(tmp_path):
    from galileo.datatypes import Trajectory

    log = RerunLogger("off", session_dir=tmp_path)
    assert log.web_url is None and not log.enabled
    log.log_video(tmp_path / "missing.mp4", None, 30.0)
    log.log_sweep(0, 0, -1.0, {"k1": 0.3})
    log.log_posterior(["k1"], np.ones((5, 1)), {"k1": (0.0, 1.0)})
    log.log_event(0, "x")
    log.log_simulation(Trajectory(30.0, ["a"], np.zeros((1, 3, 3)), np.zeros((1, 3, 3))))
    log.flush()
    log.close()
    assert list(tmp_path.iterdir()) == []


@pytest.mark.timeout(120)   # connecting to nobody fails, it does not hang (a hang fails here)
def test_bad_arguments(tmp_path):
    with pytest.raises(ValueError):
        RerunLogger("loud", session_dir=tmp_path)
    with pytest.raises(ValueError):
        RerunLogger("save")
    port = free_port()
    with pytest.raises(RuntimeError, match="no rerun viewer"):
        RerunLogger("connect", connect_url=f"rerun+http://127.0.0.1:{port}/proxy")


@pytest.mark.timeout(120)   # connecting, streaming and closing do not hang (a hang fails here)
def test_connect_streams_to_a_server(tmp_path):
    server = rr.RecordingStream("viewer-stand-in", recording_id="server")
    sink = rr.GrpcServerSink("127.0.0.1", free_port())
    server.set_sinks(sink)
    try:
        log = RerunLogger("connect", connect_url=sink.uri, session_dir=tmp_path)
        for sweep in range(3):
            log.log_sweep(0, sweep, -float(sweep), {"k1": 0.5})
        log.close()
    finally:
        server.disconnect()
    rows = series(read_rrd(tmp_path / RRD_NAME), "chains/0/loglik", "sweep", "Scalars:scalars")
    assert [v[0] for _, v in rows] == [0.0, -1.0, -2.0]


def test_web_mode_serves_viewer(tmp_path):
    """In a child process: rerun's web viewer cannot be stopped, the child's exit does it."""
    web_port, grpc_port = free_port("0.0.0.0"), free_port()
    script = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(ROOT)!r})
        from ui.rerun_log import RerunLogger
        log = RerunLogger("web", session_dir={str(tmp_path)!r}, web_port={web_port}, grpc_port={grpc_port})
        log.log_sweep(0, 0, -5.0, {{"k1": 0.5}})
        log.flush()
        print(log.web_url, flush=True)
        sys.stdin.readline()
        log.close()
    """)
    child = subprocess.Popen([sys.executable, "-c", script], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                             text=True)
    try:
        url = child.stdout.readline().strip()
        assert url.startswith(f"http://127.0.0.1:{web_port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc_port}")
        with urllib.request.urlopen(url, timeout=10) as page:
            assert page.status == 200 and b"<html" in page.read(4096).lower()
        with socket.create_connection(("127.0.0.1", grpc_port), timeout=2):
            pass
        child.stdin.write("\n")
        child.stdin.flush()
        assert child.wait(timeout=20) == 0
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    rows = series(read_rrd(tmp_path / RRD_NAME), "chains/0/loglik", "sweep", "Scalars:scalars")
    assert [v[0] for _, v in rows] == [-5.0]


CHROMIUM = "/usr/bin/chromium"


def wood_fraction(png: bytes) -> float:
    """The share of a screenshot's pixels in the demo video's wood colours (its ramp and
    blocks): rerun's own interface has next to none."""
    import io

    from PIL import Image

    a = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    r, g, b = a[..., 0], a[..., 1], a[..., 2]
    return float(((r > 120) & (r > g) & (g > b) & (r - b > 60)).mean())


@pytest.mark.timeout(180)
@pytest.mark.skipif(not Path(CHROMIUM).exists(), reason="Debian chromium not installed (.ci/run installs it)")
def test_web_viewer_shows_a_video_frame_in_chromium(demo_dir, tmp_path):
    """Rerun's web viewer in headless Chromium (WebCodecs decodes the H.264 asset on
    localhost) shows a video frame as it opens, on the blueprint's timeline "sweep".
    (WebGL: Chromium's software WebGPU cannot make the buffers rerun asks for.)"""
    sync_api = pytest.importorskip("playwright.sync_api")
    web_port, grpc_port = free_port("0.0.0.0"), free_port()
    script = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(ROOT)!r})
        from ui.rerun_log import RerunLogger
        log = RerunLogger("web", session_dir={str(tmp_path)!r}, web_port={web_port}, grpc_port={grpc_port},
                          latents=["k1"], n_chains=1)
        log.log_video({str(demo_dir / "video.mp4")!r})
        for s in range(1, 4):
            log.log_sweep(0, s, -float(s), {{"k1": 0.5}})
        log.flush()
        print(log.web_url, flush=True)
        sys.stdin.readline()
        log.close()
    """)
    child = subprocess.Popen([sys.executable, "-c", script], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                             text=True)
    try:
        url = child.stdout.readline().strip() + "&renderer=webgl"
        with sync_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, headless=True,
                                        args=["--no-sandbox", "--ignore-gpu-blocklist", "--disable-sync",
                                              "--no-first-run", "--disable-background-networking"])
            try:
                page = browser.new_page(viewport={"width": 1600, "height": 1000})
                page.goto(url)
                shown, deadline = 0.0, time.monotonic() + 90
                while time.monotonic() < deadline:
                    page.wait_for_timeout(2000)
                    shown = wood_fraction(page.screenshot())
                    if shown > 0.002:
                        break
                (tmp_path / "rerun-web.png").write_bytes(page.screenshot())
            finally:
                browser.close()
        assert shown > 0.002, f"no video frame in the rerun web viewer (see {tmp_path / 'rerun-web.png'})"
        child.stdin.write("\n")
        child.stdin.flush()
        assert child.wait(timeout=20) == 0
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()


def test_events_read_as_words_and_the_scene_is_drawn_without_legends(tmp_path):
    """Issue 24, item 9: an event reads "kind: name value; ..." (never a Python dict or list of
    sixteen starts); the scene's ramp is in the 3-D view (it held only the paths); the chains'
    plots have no legend (16 names covered them); the side panels start folded."""
    from galileo import registry
    from galileo.scenarios.ramp.scene import default_scene
    from ui.rerun_log import event_text

    ev = {"kind": "init", "sweep": 0, "detail": {"seed": 0, "chains": list(range(16)), "moves": "default",
                                                 "noise": 0.05, "starts": {str(c): [0.1, 0.2] for c in range(16)},
                                                 "adapting": True}}
    text = event_text(ev)
    assert text == "init: seed 0; chains (16 values); moves default; noise 0.05; starts (16 entries); adapting yes"
    assert not set("{}'") & set(text)
    scene = default_scene(20, target="cardboard")
    drawing = registry.of(scene).drawing(scene)
    log = RerunLogger("save", session_dir=tmp_path, latents=LATENTS, n_chains=16)
    log.log_scene(drawing)
    log.close()
    ents = read_rrd(tmp_path / RRD_NAME)
    for m in drawing.static:
        (tl, cols), = [e for e in ents[f"scene/{m.name}"] if "Mesh3D:vertex_positions" in e[1]]
        assert not tl and len(cols["Mesh3D:vertex_positions"][0]) == len(m.vertices)
    reader = chunk.RrdReader(tmp_path / RRD_NAME)
    legends, panels = [], {}
    for bp in reader.blueprints():
        for ch in reader.stream(store=bp).to_chunks():
            cols = ch.to_record_batch().to_pydict()
            legends += [v for v in cols.get("PlotLegend:visible", []) if v is not None]
            for k, v in cols.items():
                if k.endswith("PanelBlueprint:state") and v:
                    panels[ch.entity_path] = v[-1]
        assert any("/scene/**" in q for q in blueprint_queries(tmp_path / RRD_NAME)[0])
    assert legends and all(v == [False] for v in legends), legends
    # rerun's PanelState: 1 hidden, 2 collapsed, 3 expanded
    assert panels == {"/blueprint_panel": [2], "/selection_panel": [2], "/time_panel": [3]}, panels
