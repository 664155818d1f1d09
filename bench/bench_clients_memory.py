"""The app server's memory with 8 browsers scrubbing, over a long run (issue 15).

Usage (from the repository root):

    python bench/bench_clients_memory.py [--minutes 60] [--clients 8] [--chains 16] [--sweeps 75]
        [--warmup-min 5] [--scrub-every 2] [--fps 5] [--rerun save] [--no-tracemalloc] [--out FILE.json]

Wires the app as `app.py` does, on the built-in demo (rendered and cached on first run under
.cache/demo/): a Controller with `--chains` chains in its worker processes (default: the
app's, 16 on all cores) recording a session (in a temporary folder), rerun logging
(`--rerun`, default save: session.rrd, fed by a ControllerFeed and every selected sample) and
the viser viewer. `--clients` pages of one headless Chromium (Debian's /usr/bin/chromium
through Playwright, each page its own browser context, so its own viser client; 640x480,
animation frames throttled to `--fps` so that 8 pages drawing on the CPU leave the 2 cores
some room) open the viewer; then the chains start (they pause at `--sweeps`, as in the app)
and every `--scrub-every` seconds each page presses an arrow key: even pages on the Sample
slider (a re-simulation, new poses and lines, the sample's text, rerun's sim/selected), odd
pages on the Frame slider (a video frame sent to every page's camera frustum). Each press is
a client message and an update broadcast to every page.

Every `--sample-every` s: this process's resident memory (the app server; the chain workers
and Chromium are other processes: the workers' memory is noted apart), Python's traced
memory and tracemalloc's own (tracemalloc keeps 5 frames a trace), glibc's heap in use and
free (mallinfo2; rerun's Rust code has its own allocator, mimalloc, outside it), resident
memory by kind of mapping (/proc/self/smaps: glibc's main heap, anonymous mappings, files; and
each anonymous mapping of 1 MB or more, so that the one that grows names its allocator:
mimalloc reserves 1 GiB arenas), viser's buffered messages. A tracemalloc snapshot at the end of the warm-up and one after the last
sample (more with `--snap-every-min`), compared: the top growing allocation sites. A
snapshot costs tens of MB for a moment (a step in RSS at the warm-up's, which the server
then reuses); growth is measured from the first sample after the warm-up's snapshot.

Prints a JSON summary on stdout (and to --out, rewritten as the run goes): RSS at start
(server up, before any client), after the warm-up, at the end; the least-squares growth per
hour after the warm-up, and the end less the warm-up's sample (RSS, RSS net of tracemalloc's
own tables, glibc's heap in use, Python's traced memory); the top tracemalloc growth sites.
"""
from __future__ import annotations

import argparse
import asyncio
import contextlib
import gc
import json
import math
import os
import sys
import tempfile
import threading
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run", "--disable-quic", "--mute-audio"]
MB = 1024 * 1024
# requestAnimationFrame at a fixed rate: a page still receives, decodes and applies every
# message (the websocket lives in a worker; viser applies scene messages at the next frame)
THROTTLE_RAF = """
(() => {
  const every = %f;
  let last = 0;
  window.requestAnimationFrame = (cb) => {
    const now = performance.now();
    const wait = Math.max(0, last + every - now);
    last = now + wait;
    return setTimeout(() => cb(performance.now()), wait);
  };
  window.cancelAnimationFrame = (id) => clearTimeout(id);
})();
"""


def say(*a) -> None:
    print(f"[{time.strftime('%H:%M:%S')}]", *a, file=sys.stderr, flush=True)


def rss_mb(pid: int | None = None) -> float:
    import psutil

    return psutil.Process(pid).memory_info().rss / MB


def children_rss_mb(pids: list[int]) -> dict[str, float]:
    import psutil

    out = {}
    for pid in pids:
        with contextlib.suppress(psutil.Error):
            out[str(pid)] = round(psutil.Process(pid).memory_info().rss / MB, 1)
    return out


def viser_buffers(viewer) -> dict:
    """How many messages viser holds: the persistent (broadcast) buffer and each client's."""
    ws = viewer.server._websock_server
    out = {"broadcast": len(ws._broadcast_buffer.message_from_id)}
    per = [len(s.message_buffer.message_from_id) for s in list(ws._client_state_from_id.values())
           if hasattr(s, "message_buffer")]
    out["clients"] = len(ws._client_state_from_id)
    out["client_buffers"] = sum(per)
    return out


def top_growth(snap, base, n: int = 15) -> list[dict]:
    """The allocation sites (their innermost frame in our code or a library's) that grew most."""
    stats = snap.compare_to(base, "traceback")
    out = []
    for s in stats[:n]:
        frames = [f"{Path(f.filename).name}:{f.lineno}" for f in s.traceback][:4]
        out.append({"size_diff_kb": round(s.size_diff / 1024, 1), "size_kb": round(s.size / 1024, 1),
                    "count_diff": s.count_diff, "where": frames})
    return out


class Scrubbers:
    """`n` pages in one Chromium, each its own context (own websocket, own viser client): even
    pages scrub the Sample slider, odd ones the Frame slider, one arrow key a page every
    `every_s` (turning at the ends; the pages press concurrently, each on its own clock). The
    slider a page scrubs is focused once; the direction is read from the server's slider
    (viser's GUI state is one for every client). Runs an asyncio loop in its own thread."""

    def __init__(self, viewer, n: int, every_s: float, stop: threading.Event, fps: float = 0.0):
        self.viewer, self.n, self.every_s, self.stop, self.fps = viewer, n, every_s, stop, fps
        self.ready = threading.Event()
        self.presses = 0
        self.errors: list[str] = []
        self.thread = threading.Thread(target=lambda: asyncio.run(self._main()), name="scrubbers", daemon=True)

    async def _main(self) -> None:
        from playwright.async_api import async_playwright

        v = self.viewer
        sliders = [v.sample_slider, v.frame_slider]
        try:
            async with async_playwright() as pw:
                browser = await pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
                try:
                    pages = []
                    for i in range(self.n):
                        ctx = await browser.new_context(viewport={"width": 640, "height": 480})
                        page = await ctx.new_page()
                        page.set_default_timeout(300000)   # 8 pages loading on 2 busy cores
                        if self.fps:   # frames at this rate (8 pages drawing at 60 fps on the CPU starve 2 cores)
                            await page.add_init_script(THROTTLE_RAF % (1000.0 / self.fps))
                        await page.goto(v.url)
                        pages.append(page)
                    for i, page in enumerate(pages):
                        thumb = page.locator(f'[id="{sliders[i % 2]._impl.uuid}"]').locator('[role="slider"]')
                        await thumb.wait_for()
                        await thumb.evaluate("e => e.focus()")
                    say(f"{len(pages)} pages connected")
                    self.ready.set()
                    direction = [1, 1]

                    async def scrub(i: int, page) -> None:
                        k = i % 2
                        s = sliders[k]
                        await asyncio.sleep(self.every_s * i / len(pages))   # spread over the period
                        while not self.stop.is_set():
                            t0 = time.monotonic()
                            if direction[k] > 0 and s.value >= s.max:
                                direction[k] = -1
                            elif direction[k] < 0 and s.value <= s.min:
                                direction[k] = 1
                            try:
                                await page.keyboard.press("ArrowRight" if direction[k] > 0 else "ArrowLeft")
                                self.presses += 1
                            except Exception as e:  # noqa: BLE001 - noted, the run goes on
                                if len(self.errors) < 20:
                                    self.errors.append(f"{type(e).__name__}: {str(e)[:200]}")
                            await asyncio.sleep(max(0.0, self.every_s - (time.monotonic() - t0)))
                    await asyncio.gather(*(scrub(i, page) for i, page in enumerate(pages)))
                finally:
                    await browser.close()
        except Exception as e:  # noqa: BLE001
            self.errors.append(f"scrubbers stopped: {type(e).__name__}: {e}")
            say(self.errors[-1])
            self.ready.set()


def run(args) -> dict:
    import app
    from galileo import registry
    from galileo.video import read_video
    from ui.controller import Controller
    from ui.rerun_log import ControllerFeed, RerunLogger
    from ui.viewer import Viewer

    t_start = time.monotonic()
    folder = app.ensure_demo(progress=False)
    scene = registry.load_scene(folder / "scene.json")
    tracks = registry.of(scene).track(folder / "video.mp4", scene, progress=False)
    samples: list[dict] = []
    result: dict = {"args": vars(args), "samples": samples}
    with contextlib.ExitStack() as stack:
        tmp = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="bench-mem-")))
        session = tmp / "session"
        # the app's wiring (app.run): the controller first (its workers forked before any thread)
        ctrl = Controller(scene, tracks, chains=args.chains, seed=0, workers=args.workers, session_dir=session,
                          sweeps=args.sweeps)
        stack.callback(ctrl.close)
        worker_pids = sorted(getattr(ctrl._executor, "pids", lambda: [])())
        video, _ = read_video(folder / "video.mp4")
        logger = RerunLogger(args.rerun, session_dir=session, host="127.0.0.1", latents=list(ctrl.names),
                             n_chains=len(ctrl.all_chain_ids()))
        stack.callback(logger.close)
        logger.log_video(folder / "video.mp4", tracks, tracks.fps)
        feed = ControllerFeed(logger, ctrl)
        ctrl.add_listener(feed.on_controller)
        port = app_free_port()
        viewer = Viewer(ctrl, ctrl.likelihood_scene, tracks, video, port=port, target_sweeps=args.sweeps)
        stack.callback(viewer.close)
        logger.log_selected(viewer.traj)
        if args.log_selected and args.flush_selected:   # what-if: rerun flushed after each selection
            def log_and_flush(traj, chain, index):
                logger.log_selected(traj, chain, index)
                logger.flush()
            viewer.add_selection_listener(log_and_flush)
        elif args.log_selected:
            viewer.add_selection_listener(logger.log_selected)
        if args.tracemalloc:
            tracemalloc.start(args.frames)
        gc.collect()
        result["rss_start_mb"] = round(rss_mb(), 1)
        say(f"viewer {viewer.url}, {args.chains} chains to {args.sweeps} sweeps, workers {worker_pids}, "
            f"RSS {result['rss_start_mb']} MB")

        stop = threading.Event()
        scrub = Scrubbers(viewer, args.clients, args.scrub_every, stop, args.fps)
        scrub.thread.start()
        scrub.ready.wait(600)
        ctrl.start()   # the chains run while the pages watch (and pause at --sweeps, as in the app)
        t0 = time.monotonic()
        end = t0 + 60 * args.minutes
        next_snap = t0 + 60 * args.warmup_min
        base = None
        snaps: list[dict] = []
        last = False
        while True:
            now = time.monotonic()
            last = now >= end
            row = sample_row(now - t0, viewer, ctrl, scrub, worker_pids, args.count_objects)
            samples.append(row)
            say(json.dumps({k: v for k, v in row.items() if k != "workers_mb"}))
            if now >= next_snap or (last and base is not None):
                # the warm-up's snapshot, any every --snap-every-min, the last one (after the last
                # sample: a snapshot's own memory, tens of MB for a moment, stays out of the samples;
                # what it freed the server reuses, so the warm-up's step does not grow later)
                row["snapshot"] = True
                if args.tracemalloc:
                    gc.collect()
                    snap = tracemalloc.take_snapshot().filter_traces(
                        [tracemalloc.Filter(False, tracemalloc.__file__)])
                    if base is None:
                        base = snap
                    else:
                        top = top_growth(snap, base)
                        snaps.append({"t_min": row["t_min"], "rss_mb": row["rss_mb"], "traced_mb": row["traced_mb"],
                                      "top": top})
                        say("top growth since the warm-up:", json.dumps(top[:6]))
                    snap = None
                    gc.collect()
                    if args.trim:
                        trim()
                else:
                    base = True
                next_snap = (time.monotonic() + 60 * args.snap_every_min) if args.snap_every_min else math.inf
            if args.out:
                write_out(args.out, result, snaps)
            if last:
                break
            stop.wait(min(args.sample_every, max(0.0, end - now)))
        stop.set()
        scrub.thread.join(60)
        summarize(result, samples, args)
        result["presses"] = scrub.presses
        result["resimulations"] = viewer.resimulations
        result["scrub_errors"] = scrub.errors
        result["wall_min"] = round((time.monotonic() - t_start) / 60, 2)
        result["load_avg"] = os.getloadavg()
        if snaps:
            result["top_growth_at_end"] = snaps[-1]["top"]
        result["snapshots"] = snaps
    if args.out:
        write_out(args.out, result, result.get("snapshots", []))
    return result


def sample_row(t_s: float, viewer, ctrl, scrub, worker_pids: list[int], count_objects: bool) -> dict:
    tracing = tracemalloc.is_tracing()
    st = ctrl.status()
    return {"t_min": round(t_s / 60, 3), "rss_mb": round(rss_mb(), 1),
            "traced_mb": round(tracemalloc.get_traced_memory()[0] / MB, 1) if tracing else None,
            "tracemalloc_overhead_mb": round(tracemalloc.get_tracemalloc_memory() / MB, 1) if tracing else None,
            "workers_mb": children_rss_mb(worker_pids), "presses": scrub.presses,
            "resimulations": viewer.resimulations, "rounds": st["rounds"], "sweeps": st["sweeps"],
            "running": sum(1 for c in st["chains"].values() if c["running"]),
            "threads": threading.active_count(), "viser": viser_buffers(viewer),
            "malloc_mb": malloc_mb(), "maps_mb": maps_mb(detail=MAPS_DETAIL),
            "gc_objects": len(gc.get_objects()) if count_objects else None}


MAPS_DETAIL = False   # --maps-detail: each big mapping in every sample (about 3 MB of this process's own an hour)


def maps_mb(detail: bool = True) -> dict | None:
    """This process's resident memory by kind of mapping (/proc/self/smaps): "heap" (glibc's
    main arena, brk), "anon" (anonymous mappings: glibc's thread arenas and large blocks,
    Rust's allocator, numpy's large arrays, thread stacks), "file" (code and mapped files); and
    "anon_big": the resident MB of each anonymous mapping of 1 MB or more, by its start address
    (which one grows names the allocator that holds the growth)."""
    try:
        text = Path("/proc/self/smaps").read_text()
    except OSError:
        return None
    out = {"heap": 0.0, "anon": 0.0, "file": 0.0, "stack": 0.0}
    big: dict[str, float] = {}
    kind, start = "anon", ""
    for line in text.splitlines():
        head = line.split()
        if not head:
            continue
        if "-" in head[0] and len(head) >= 5 and not head[0].endswith(":"):
            start = head[0].split("-")[0]
            path = head[5] if len(head) > 5 else ""
            kind = ("heap" if path == "[heap]" else "stack" if path.startswith("[stack") else
                    "anon" if not path or path.startswith("[anon") else "file")
        elif head[0] == "Rss:":
            mb = int(head[1]) / 1024
            out[kind] += mb
            if kind == "anon" and mb >= 1.0:
                big[start] = round(mb, 1)
    out = {k: round(v, 1) for k, v in out.items()}
    if detail:
        out["anon_big"] = big
    return out


def summarize(result: dict, samples: list[dict], args) -> None:
    """RSS at the end; growth after the warm-up (from the first sample after its snapshot to
    the last sample): the least-squares slope per hour, and the end less that sample; the
    same net of tracemalloc's own tables, glibc's heap in use, Python's traced memory."""
    result["rss_end_mb"] = samples[-1]["rss_mb"]
    i0 = next((i + 1 for i, s in enumerate(samples) if s.get("snapshot")), None)
    after = samples[i0:] if i0 is not None else []
    if len(after) < 2:
        return
    result["rss_after_warmup_mb"] = after[0]["rss_mb"]
    result["warmup_at_min"] = after[0]["t_min"]
    t = np.array([s["t_min"] for s in after]) / 60.0
    for key, name in (("rss_mb", "rss"), ("traced_mb", "traced")):
        if after[0].get(key) is None:
            continue
        y = np.array([s[key] for s in after], float)
        result[f"{name}_growth_mb_per_hour_after_warmup"] = round(float(np.polyfit(t, y, 1)[0]), 2)
        result[f"{name}_growth_mb_after_warmup"] = round(float(y[-1] - y[0]), 1)
    if after[0].get("malloc_mb"):
        y = np.array([s["malloc_mb"]["in_use"] for s in after], float)
        result["malloc_in_use_growth_mb_after_warmup"] = round(float(y[-1] - y[0]), 1)
        result["malloc_in_use_growth_mb_per_hour_after_warmup"] = round(float(np.polyfit(t, y, 1)[0]), 2)
    if after[0].get("tracemalloc_overhead_mb") is not None:
        y = np.array([s["rss_mb"] - s["tracemalloc_overhead_mb"] for s in after], float)
        result["rss_net_of_tracemalloc_growth_mb_after_warmup"] = round(float(y[-1] - y[0]), 1)
        result["rss_net_of_tracemalloc_growth_mb_per_hour_after_warmup"] = round(float(np.polyfit(t, y, 1)[0]), 2)
    result["fit_minutes"] = [after[0]["t_min"], after[-1]["t_min"]]


def write_out(path: str, result: dict, snaps: list) -> None:
    p = Path(path)
    tmp = p.with_suffix(p.suffix + ".part")
    tmp.write_text(json.dumps({**result, "snapshots": snaps}, indent=1))
    os.replace(tmp, p)


class _Mallinfo2(__import__("ctypes").Structure):
    _fields_ = [(n, __import__("ctypes").c_size_t) for n in
                ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks",
                 "keepcost")]


def malloc_mb() -> dict | None:
    """glibc's view of its heap (every arena): "in_use" (allocated and not freed: Python's
    large objects and arenas, numpy, pybullet, rerun's Rust heap, ...; mmapped blocks included)
    and "free_held" (freed, kept by malloc, part of RSS until reused or trimmed)."""
    import ctypes

    try:
        f = ctypes.CDLL("libc.so.6").mallinfo2
    except (OSError, AttributeError):
        return None
    f.restype = _Mallinfo2
    m = f()
    return {"in_use": round((m.uordblks + m.hblkhd) / MB, 1), "free_held": round(m.fordblks / MB, 1)}


def trim() -> None:
    """glibc's malloc_trim: freed heap memory back to the system."""
    import ctypes

    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6").malloc_trim(0)


def app_free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--minutes", type=float, default=60.0)
    p.add_argument("--clients", type=int, default=8)
    p.add_argument("--chains", type=int, default=16, help="chains (default: the app's, 16)")
    p.add_argument("--sweeps", type=int, default=75, help="the chains' sweep target (they pause there, as in the app)")
    p.add_argument("--workers", type=int, default=None, help="worker processes (default: the app's, all cores)")
    p.add_argument("--warmup-min", type=float, default=5.0)
    p.add_argument("--scrub-every", type=float, default=2.0, help="seconds between a page's key presses")
    p.add_argument("--fps", type=float, default=5.0,
                   help="the pages' animation frames a second (requestAnimationFrame throttled; 0: as the browser "
                        "does, 60)")
    p.add_argument("--sample-every", type=float, default=10.0, help="seconds between memory samples")
    p.add_argument("--snap-every-min", type=float, default=0.0,
                   help="minutes between tracemalloc snapshots after the warm-up's (0: only the warm-up's and the "
                        "last; each costs RSS a step of a few MB, tracemalloc's own tables)")
    p.add_argument("--frames", type=int, default=5, help="frames tracemalloc keeps a trace")
    p.add_argument("--rerun", choices=["off", "save"], default="save")
    p.add_argument("--no-log-selected", dest="log_selected", action="store_false",
                   help="do not log each selected sample to rerun (the app does)")
    p.add_argument("--flush-selected", action="store_true",
                   help="what-if: flush the rerun stream after logging each selected sample (the app does not)")
    p.add_argument("--no-tracemalloc", dest="tracemalloc", action="store_false")
    p.add_argument("--trim", action="store_true",
                   help="malloc_trim after each snapshot (hands its freed memory back; RSS then climbs back)")
    p.add_argument("--count-objects", action="store_true", help="also count the garbage collector's objects")
    p.add_argument("--maps-detail", action="store_true",
                   help="record every anonymous mapping of 1 MB or more in each sample (which one grows)")
    p.add_argument("--out", help="write the JSON here too (rewritten as the run goes)")
    args = p.parse_args()
    global MAPS_DETAIL
    MAPS_DETAIL = args.maps_detail
    result = run(args)
    summary = {k: v for k, v in result.items() if k not in ("samples", "snapshots")}
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
