"""In-browser scrub latency: a sample change in the page -> the redrawn 3-D scene (issue 14).

Usage (from the repository root):

    python bench/bench_browser_scrub.py [--samples 60] [--json] [--width 1600 --height 1000]
        [--input slider|number] [--alternate none|input|shadows] [--no-shadows]
        [--gpu-wait readpixels|fence|none] [--raw] [--verbose]

Renders and tracks the demo, runs 3 chains for 20 sweeps (then they stand still: nothing else
is sent while it measures), starts the viewer with the objects posed at the last frame (where
the samples differ most), opens it in headless Chromium (Debian's /usr/bin/chromium driven by
Playwright with the flags of tests/test_app_browser.py: `--disable-gpu`, so WebGL is ANGLE on
SwiftShader, on the CPU) and changes the sample from the page, one key press per scrub, back
and forth over the chain's samples, waiting for the page to go quiet between presses:
`--input slider` (default) presses ArrowRight / ArrowLeft on the focused Sample slider, as a
user does; `--input number` presses ArrowUp / ArrowDown in the number box beside it.
`--alternate input` (or `shadows`) alternates the two inputs (or shadows on and off) scrub by
scrub, so that both see the same machine load (the machine may be shared), a column each.

Each scrub is timed on one clock (the page's `performance.timeOrigin + performance.now()`,
aligned to Python's `time.time()` by round trips) from the keydown event to the moment the
browser is done with the frame that holds the new sample (drawn by SwiftShader, read back by
Chrome for its software compositor and committed; the compositor's own draw, about 2 ms in a
trace, is not included), split into parts that add up to the total:

  keydown -> update sent   the slider's GuiUpdateMessage handed to viser's websocket worker
  page -> server           ... decoded on the server's event loop (websocket, msgpack)
  server queue             ... the slider callback starting (viser's thread pool)
  server callback          Viewer.select_sample: re-simulation, poses, sim lines, text queued
  server -> worker         ... the websocket frame holding the last scene message arriving in
                           the page's websocket worker (viser's 1/60 s send window, the socket)
  earlier frames           from then on, the time covered by frames rendered before the
                           scrub's own (each from its callback to its GPU end)
  to main, wait            the rest: decode, hand-over to the main thread, wait for a frame
  draw (callback)          the scrub's frame callback: messages applied, three.js render calls
  draw (GPU)               SwiftShader finishing that frame
  draw (finish)            Chrome's own work on it: the canvas read back for the software
                           compositor, paint, commit (to the first task after the frame)

"Drawn" is read from the page, not guessed. A probe (page.add_init_script) wraps
requestAnimationFrame and notes after every frame callback whether three.js rendered
(renderer.info.render.frame moved), which received message batches have left viser's message
queue (it drains at the start of a rendered frame), the objects' poses as three.js holds them,
the camera, and the identity of the simulated trajectories' line geometry; after a rendered
frame's callback it reads one pixel back (waits for the GPU: Chrome's software compositing
makes the main thread wait there anyway, reading the whole canvas back a moment later; see
--gpu-wait) and posts itself a message, whose arrival is the frame's end. The scrub is drawn
when the first rendered frame after the batch holding the server's last scene message left
the queue is done; the poses that frame drew are checked against the server's. The new
simulated lines are React components mounted a frame or more later: timed separately
("keydown -> new simulated lines drawn"). Websocket frames are timed inside viser's worker
(its WebSocket wrapped by a prelude prepended to the worker's source), the server side by
wrapping select_sample, viser's message decoding and its broadcast buffer (nothing in ui/ is
changed).

Also reported: the idle requestAnimationFrame interval (nothing drawn), the interval of frames
while viser renders continuously, the Event Timing API's keydown duration (keydown to the next
paint, of the slider itself), whether the camera moved, and the messages and bytes a scrub
sends. `--no-shadows` is a what-if: viser's default lights casting no shadows
(`server.scene.configure_default_lights(cast_shadow=False)`, sent by this script).
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import socket
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run", "--disable-quic"]

# viser's client drains these without a frame (messageQueue.ts): they never wait for a draw
GUI_ONLY = {"GuiUpdateMessage", "GuiRemoveMessage", "GuiModalMessage", "GuiCloseModalMessage", "GuiPanelMessage",
            "GuiPanelRemoveMessage", "GuiSetPanelCollapsedMessage", "GuiSetPanelHeightMessage",
            "GuiSetPanelPositionMessage", "GuiSetPanelWidthMessage", "SetGuiPanelLabelMessage",
            "NotificationShowMessage", "NotificationUpdateMessage", "RemoveNotificationMessage"}

# Runs inside viser's websocket worker, before its code: every websocket frame's arrival time and
# size, handed to the main thread on the message_batch it becomes (one batch per frame, in order).
WORKER_PRELUDE = r"""
(() => {
  const T = () => performance.timeOrigin + performance.now();
  const q = [];
  const OWS = self.WebSocket;
  function WS(url, protocols) {
    const ws = new OWS(url, protocols);
    ws.addEventListener("message", (ev) => {
      const d = ev.data;
      q.push({t: T(), bytes: d && d.byteLength !== undefined ? d.byteLength : -1});
    });
    return ws;
  }
  WS.prototype = OWS.prototype;
  Object.setPrototypeOf(WS, OWS);
  self.WebSocket = WS;
  const post = self.postMessage.bind(self);
  self.postMessage = function (data, transfer) {
    if (data && data.type === "message_batch") {
      const a = q.shift();
      data.__bench = a ? {t_ws: a.t, bytes: a.bytes, t_post: T()} : null;
    }
    return post(data, transfer);
  };
})();
"""

PAGE_PROBE = r"""
(() => {
  const T = () => performance.timeOrigin + performance.now();
  const B = window.__bench = {
    watching: false, sync: "readpixels", pendingFences: 0, pendingAfter: 0, objectNames: [], lineNames: [],
    keys: [], sends: [], batches: [], frames: [], eventTiming: [], errors: [],
    pending: [], lastCb: 0, lastBatch: 0, prelude: false, px: new Uint8Array(4), nextId: 1,
  };
  const info = () => (window.__viserTestpoints ? window.__viserTestpoints.rendererInfo : null);
  const mutable = () => window.__viserMutable || null;
  B.gl = () => {
    const m = mutable();
    return m && m.canvas ? (m.canvas.getContext("webgl2") || m.canvas.getContext("webgl")) : null;
  };
  B.uid = (o) => (o ? (o.__benchId || (o.__benchId = B.nextId++)) : 0);
  B.poses = () => {
    const m = mutable();
    if (!m) return null;
    return B.objectNames.map((n) => {
      const o = m.nodeRefFromName[n];
      return o ? [...o.position.toArray(), ...o.quaternion.toArray()] : null;
    });
  };
  // the simulated trajectories: the identity of each one's line geometry (0: not in the scene)
  B.lineIds = () => {
    const m = mutable();
    if (!m) return [];
    return B.lineNames.map((n) => {
      const o = m.nodeRefFromName[n];
      let g = null;
      if (o) o.traverse((c) => { if (g === null && c.geometry) g = c.geometry; });
      return B.uid(g);
    });
  };
  B.camera = () => {
    const m = mutable();
    return m && m.camera ? [...m.camera.position.toArray(), ...m.camera.quaternion.toArray()] : null;
  };

  window.addEventListener("keydown", (e) => {
    if (B.watching) B.keys.push({t_event: performance.timeOrigin + e.timeStamp, t_listener: T(), key: e.key});
  }, true);
  try {
    new PerformanceObserver((list) => {
      for (const en of list.getEntries()) {
        if (B.watching && en.name === "keydown")
          B.eventTiming.push({start: performance.timeOrigin + en.startTime, duration: en.duration,
                              processing: en.processingEnd - en.processingStart});
      }
    }).observe({type: "event", durationThreshold: 16, buffered: false});
  } catch (e) { B.errors.push("event timing: " + e); }

  // viser's websocket lives in a worker: prepend the prelude to its (blob) source, and watch
  // what the main thread sends to it and gets from it.
  const OW = window.Worker;
  function BW(url, opts) {
    let u = url;
    try {
      const s = String(url);
      if (s.startsWith("blob:")) {
        const x = new XMLHttpRequest();
        x.open("GET", s, false);
        x.send();
        if (x.responseText.includes("WebSocket")) {
          u = URL.createObjectURL(new Blob([WORKER_PRELUDE + "\n" + x.responseText], {type: "text/javascript"}));
          B.prelude = true;
        }
      }
    } catch (e) { B.errors.push("worker prelude: " + e); u = url; }
    const w = new OW(u, opts);
    const post = w.postMessage.bind(w);
    w.postMessage = function (data, transfer) {
      if (B.watching && data && data.type === "send" && data.message && data.message.type === "GuiUpdateMessage")
        B.sends.push({t: T(), uuid: data.message.uuid, updates: JSON.stringify(data.message.updates)});
      return transfer === undefined ? post(data) : post(data, transfer);
    };
    w.addEventListener("message", (ev) => {   // registered before viser's onmessage: runs first
      const d = ev.data;
      if (!d || d.type !== "message_batch") return;
      const t = T();
      B.lastBatch = t;
      if (!B.watching) return;
      const rec = {t_main: t, ws: d.__bench || null, drained_in: null,
                   msgs: d.messages.map((m) => [m.type, m.name !== undefined ? m.name
                                                          : (m.uuid !== undefined ? m.uuid : null)])};
      B.batches.push(rec);
      if (d.messages.length) B.pending.push({rec, ref: d.messages[d.messages.length - 1]});
    });
    return w;
  }
  BW.prototype = OW.prototype;
  window.Worker = BW;

  // every animation-frame callback, timed; while watching, what each one drew
  const oraf = window.requestAnimationFrame.bind(window);
  B.oraf = oraf;
  function after(ts, t0, f0) {
    const t1 = T();
    B.lastCb = t1;
    if (!B.watching) return;
    const inf = info();
    const rendered = inf !== null && inf.render.frame !== f0;
    let tg = null;
    let fence = null;
    if (rendered && B.sync !== "none") {
      const gl = B.gl();
      if (gl && B.sync === "readpixels") {          // block until SwiftShader has drawn it
        gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, B.px);
        tg = T();
      } else if (gl && gl.fenceSync) {              // or ask, without blocking, when it has
        fence = gl.fenceSync(gl.SYNC_GPU_COMMANDS_COMPLETE, 0);
        gl.flush();
      }
    }
    const idx = B.frames.length;
    const m = mutable();
    const q = m ? m.messageQueue : [];
    for (const p of B.pending) if (p.rec.drained_in === null && q.indexOf(p.ref) === -1) p.rec.drained_in = idx;
    B.frames.push({ts: performance.timeOrigin + ts, t0, t1, tg, rendered,
                   calls: inf ? inf.render.calls : null, triangles: inf ? inf.render.triangles : null,
                   poses: rendered ? B.poses() : null, lines: rendered ? B.lineIds() : null,
                   camera: rendered ? B.camera() : null});
    if (fence !== null) {
      const gl = B.gl();
      const rec = B.frames[idx];
      B.pendingFences += 1;
      const poll = () => {
        if (gl.getSyncParameter(fence, gl.SYNC_STATUS) === gl.SIGNALED) {
          rec.tg = T();
          gl.deleteSync(fence);
          B.pendingFences -= 1;
        } else setTimeout(poll, 1);
      };
      setTimeout(poll, 0);
    }
    if (rendered) {   // the first task after this frame: Chrome's own work on it (the canvas read back
                      // for the software compositor, the commit) is done by then
      const rec = B.frames[idx];
      const ch = new MessageChannel();
      B.pendingAfter += 1;
      ch.port1.onmessage = () => { rec.ta = T(); B.pendingAfter -= 1; ch.port1.close(); };
      ch.port2.postMessage(0);
    }
    if (rendered) oraf((ts2) => {
      if (B.watching) B.frames.push({ts: performance.timeOrigin + ts2, t0: T(), probe: true});
    });
  }
  window.requestAnimationFrame = function (cb) {
    return oraf((ts) => {
      const inf = info();
      const f0 = inf ? inf.render.frame : -1;
      const t0 = T();
      try { cb(ts); } finally { after(ts, t0, f0); }
    });
  };

  B.startWatch = () => {
    B.keys = []; B.sends = []; B.batches = []; B.frames = []; B.eventTiming = []; B.pending = [];
    B.linesAtStart = B.lineIds();
    B.posesAtStart = B.poses();
    B.cameraAtStart = B.camera();
    B.watching = true;
    return T();
  };
  B.stopWatch = () => {
    B.watching = false;
    return {keys: B.keys, sends: B.sends, batches: B.batches, frames: B.frames, eventTiming: B.eventTiming,
            linesAtStart: B.linesAtStart, posesAtStart: B.posesAtStart, cameraAtStart: B.cameraAtStart,
            errors: B.errors};
  };
  B.state = () => ({now: T(), lastCb: B.lastCb, lastBatch: B.lastBatch,
                    pending: B.pendingFences + B.pendingAfter});
  // frame intervals for `ms`: a bare rAF loop (nothing invalidated), or asking viser to render every frame
  B.frameLoop = (ms, render) => new Promise((resolve) => {
    const out = [];
    const end = T() + ms;
    const step = (ts) => {
      const inf = info();
      out.push({ts: performance.timeOrigin + ts, t: T(), frame: inf ? inf.render.frame : -1});
      if (render && mutable()) mutable().requestRender();
      if (T() < end) oraf(step); else resolve(out);
    };
    oraf(step);
  });
})();
""".replace("WORKER_PRELUDE + ", json.dumps(WORKER_PRELUDE) + " + ")


def pct(values, q):
    v = [x for x in values if x is not None and np.isfinite(x)]
    return float(np.percentile(v, q)) if v else float("nan")


class ServerProbe:
    """Server-side timestamps (time.time()): the slider's GuiUpdateMessage decoded by viser,
    Viewer.select_sample entered / left, and every message queued for the browsers."""

    def __init__(self, viewer, slider_uuid: str):
        from viser import _messages as vm

        self.viewer = viewer
        self.uuid = slider_uuid
        self.lock = threading.Lock()
        self.recv: list[tuple[float, object]] = []
        self.calls: list[dict] = []
        self.pushed: list[tuple[float, object]] = []
        self._vm = vm
        self._had_deser = "deserialize" in vm.Message.__dict__
        self._orig_deser = vm.Message.__dict__.get("deserialize")
        base = vm.Message.deserialize.__func__
        probe = self

        def deserialize(cls, raw):
            t = time.time()
            m = base(cls, raw)
            if getattr(m, "uuid", None) == probe.uuid:
                with probe.lock:
                    probe.recv.append((t, m))
            return m

        vm.Message.deserialize = classmethod(deserialize)
        self._orig_select = viewer.select_sample
        orig_select = self._orig_select

        def select_sample(chain, index, force=False):
            t0 = time.time()
            out = orig_select(chain, index, force)
            t1 = time.time()
            with probe.lock:
                probe.calls.append({"t_in": t0, "t_out": t1, "chain": chain, "index": index,
                                    "resim_s": float(viewer.last_resim_s), "server_s": float(out),
                                    "poses": [np.concatenate([h.position, h.wxyz]) for h in viewer.object_handles]})
            return out

        viewer.select_sample = select_sample   # the slider's callback looks it up on the instance
        self._buf = viewer.server._websock_server._broadcast_buffer
        orig_push = self._buf.push

        def push(message):
            with probe.lock:
                probe.pushed.append((time.time(), message))
            return orig_push(message)

        self._buf.push = push

    def clear(self) -> None:
        with self.lock:
            self.recv.clear()
            self.calls.clear()
            self.pushed.clear()

    def snapshot(self):
        with self.lock:
            return list(self.recv), list(self.calls), list(self.pushed)

    def restore(self) -> None:
        vm = self._vm
        if self._had_deser:
            vm.Message.deserialize = self._orig_deser
        else:
            with contextlib.suppress(AttributeError):
                del vm.Message.deserialize
        self.viewer.__dict__.pop("select_sample", None)
        self._buf.__dict__.pop("push", None)


def message_bytes(message) -> int:
    """Bytes one message takes on the wire (msgpack, before zstd, plus its raw arrays)."""
    import msgspec

    bufs: list = []
    d = message.as_serializable_dict(bufs)
    return len(msgspec.msgpack.encode(d)) + sum(b.nbytes for b in bufs)


def message_key(message) -> tuple[str, str | None]:
    name = getattr(message, "name", None)
    return type(message).__name__, name if name is not None else getattr(message, "uuid", None)


def clock_offset(page, rounds: int = 40) -> tuple[float, float]:
    """(page clock - time.time() in seconds, half the best round trip): the page's
    timeOrigin + now() read between two time.time() calls; the tightest round trip wins."""
    best = None
    for _ in range(rounds):
        a = time.time()
        p = page.evaluate("performance.timeOrigin + performance.now()") / 1e3
        b = time.time()
        if best is None or b - a < best[1]:
            best = (p - (a + b) / 2, b - a)
    return best[0], best[1] / 2


def union(intervals: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Overlapping intervals merged (sorted)."""
    out: list[list[float]] = []
    for a, b in sorted(intervals):
        if out and a <= out[-1][1]:
            out[-1][1] = max(out[-1][1], b)
        else:
            out.append([a, b])
    return [(a, b) for a, b in out]


def covered(merged: list[tuple[float, float]], lo: float, hi: float) -> float:
    """How much of [lo, hi] the merged intervals cover."""
    return sum(max(0.0, min(b, hi) - max(a, lo)) for a, b in merged)


def done(frame: dict) -> float:
    """When a rendered frame is done (page ms): the latest of its callback's end, its GPU end
    and the first task after it."""
    return max(t for t in (frame["t1"], frame.get("tg"), frame.get("ta")) if t is not None)


def analyse(rec: dict, server, off: float) -> dict:
    """One scrub's records -> its times (ms) and checks."""
    recv, calls, pushed = server
    P = lambda t: None if t is None else t / 1e3 - off   # page ms -> time.time() seconds
    ms = lambda a, b: None if a is None or b is None else (b - a) * 1e3
    out: dict = {"ok": False}
    if not rec["keys"]:
        out["why"] = "no keydown seen"
        return out
    t_key = P(rec["keys"][0]["t_event"])
    sends = rec["sends"]
    t_send = P(sends[0]["t"]) if sends else None
    if not calls:
        out["why"] = "the server's slider callback never ran"
        return out
    call = calls[0]
    t_recv = recv[0][0] if recv else None
    in_call = [(t, m) for t, m in pushed if call["t_in"] <= t <= call["t_out"] + 1e-3]
    out["messages"] = [(*message_key(m), message_bytes(m)) for _, m in in_call]
    scene_msgs = [(t, m) for t, m in in_call if type(m).__name__ not in GUI_ONLY]
    if not scene_msgs:
        out["why"] = "the server queued no scene message"
        return out
    last = message_key(scene_msgs[-1][1])
    batches = rec["batches"]
    hit = next((b for b in batches if any(tuple(x) == last for x in b["msgs"])), None)
    if hit is None or hit["drained_in"] is None:
        out["why"] = f"the batch with {last} was not {'seen' if hit is None else 'applied'} in the page"
        return out
    frames = rec["frames"]
    fi = hit["drained_in"]
    if not frames[fi].get("rendered"):   # applied outside a rendered frame: the next one draws it
        fi = next((i for i in range(fi + 1, len(frames)) if frames[i].get("rendered")), None)
        if fi is None:
            out["why"] = "no frame was rendered after the scene messages were applied"
            return out
    fr = frames[fi]
    # the poses three.js drew in that frame against the server's
    want = np.array(call["poses"], float)          # (objects, 7): x y z, w x y z
    got = fr["poses"]
    if got is None or any(g is None for g in got):
        out["poses_match"] = False
    else:
        g = np.array(got, float)                   # x y z, qx qy qz qw
        g = np.concatenate([g[:, :3], g[:, 6:7], g[:, 3:6]], axis=1)
        dq = np.minimum(np.abs(g[:, 3:] - want[:, 3:]).max(axis=1), np.abs(g[:, 3:] + want[:, 3:]).max(axis=1))
        out["poses_match"] = bool(np.abs(g[:, :3] - want[:, :3]).max() < 1e-6 and dq.max() < 1e-6)
    start = rec["posesAtStart"]
    out["pose_changed"] = bool(start is not None and fr["poses"] is not None
                               and not np.allclose(np.array(start, float), np.array(fr["poses"], float)))
    cam0, cam1 = rec.get("cameraAtStart"), fr.get("camera")
    out["camera_moved"] = bool(cam0 is not None and cam1 is not None
                               and not np.allclose(np.array(cam0), np.array(cam1), atol=1e-9))
    cam_last = next((f["camera"] for f in reversed(frames) if f.get("rendered") and f.get("camera")), None)
    if cam0 is not None and cam_last is not None:   # how far the view turned by the scrub's end
        dot = abs(float(np.dot(np.array(cam0[3:]), np.array(cam_last[3:]))))
        out["camera_turn_deg"] = float(np.degrees(2 * np.arccos(min(1.0, dot))))
    lines0 = rec["linesAtStart"]
    out["lines_missing_in_drawn_frame"] = bool(fr["lines"] is not None and 0 in fr["lines"])
    line_frame = next((f for f in frames if f.get("rendered") and f["lines"] is not None and 0 not in f["lines"]
                       and all(a != b for a, b in zip(f["lines"], lines0))), None)
    ws = hit["ws"] or {}
    t_ws, t_post, t_main = P(ws.get("t_ws")), P(ws.get("t_post")), P(hit["t_main"])
    t_f0, t_f1 = P(fr["t0"]), P(fr["t1"])
    t_gpu = P(fr["tg"]) if fr["tg"] is not None else t_f1
    t_drawn = P(done(fr))
    # From the scene update's arrival in the page (its websocket frame in the worker) to the
    # scrub's frame drawn, on one timeline: the time covered by earlier frames (from their
    # callback to their GPU end: they hold the main thread and SwiftShader), then what is left
    # of the scrub's own frame (its callback; its GPU work), the rest being the hand-over to
    # the main thread and the wait for an animation frame.
    earlier = [f for f in frames[:fi] if f.get("rendered")]
    lo = t_ws if t_ws is not None else t_main
    busy = union([(P(f["t0"]), P(done(f))) for f in earlier])
    page_total = t_drawn - lo
    blocked = covered(busy, lo, t_drawn)
    t_gpu = min(t_gpu, t_drawn)
    draw_main = (t_f1 - t_f0) - covered(busy, t_f0, t_f1)
    draw_gpu = (t_gpu - t_f1) - covered(busy, t_f1, t_gpu)
    draw_finish = (t_drawn - t_gpu) - covered(busy, t_gpu, t_drawn)
    after_key = [f for f in earlier if P(f["t0"]) >= t_key]
    nxt = next(iter(frames[fi + 1:]), None)
    first_scene = next((b for b in batches if any(x[0] not in GUI_ONLY for x in b["msgs"])), None)
    out.update({
        "ok": True,
        "input_to_send": ms(t_key, t_send),
        "send_to_server": ms(t_send, t_recv),
        "server_queue": ms(t_recv, call["t_in"]),
        "server_callback": ms(call["t_in"], call["t_out"]),
        "resim": call["resim_s"] * 1e3,
        "server_to_worker": ms(call["t_out"], t_ws),
        "earlier_frames": blocked * 1e3,
        "handover_wait": (page_total - blocked - draw_main - draw_gpu - draw_finish) * 1e3,
        "draw_main": draw_main * 1e3,
        "draw_gpu": draw_gpu * 1e3,
        "draw_finish": draw_finish * 1e3,
        "total": ms(t_key, t_drawn),
        "to_next_frame": ms(t_key, P(nxt["t0"])) if nxt else None,
        "to_lines_drawn": ms(t_key, P(done(line_frame))) if line_frame else None,
        "event_timing": rec["eventTiming"][0]["duration"] if rec["eventTiming"] else None,
        "worker_decode": ms(t_ws, t_post),
        "worker_to_main": ms(t_ws, t_main),
        "wait_for_frame": ms(t_main, t_f0),
        "frames_before": len(after_key),
        "frame_cost": [ms(P(f["t0"]), P(done(f))) for f in frames if f.get("rendered")],
        "draw_calls": fr["calls"], "triangles": fr["triangles"],
        "ws_frames": sum(1 for b in batches if b["ws"]), "ws_bytes": sum(b["ws"]["bytes"] for b in batches if b["ws"]),
        "first_scene_batch": ms(t_key, P(first_scene["t_main"])) if first_scene else None,
    })
    return out


PARTS = [("input_to_send", "page: keydown -> update sent"),
         ("send_to_server", "page -> server (websocket, decode)"),
         ("server_queue", "server: viser thread pool -> callback"),
         ("server_callback", "server: select_sample (re-simulate, queue)"),
         ("server_to_worker", "server -> page's websocket worker"),
         ("earlier_frames", "page: earlier frames in the way"),
         ("handover_wait", "page: to the main thread, wait for a frame"),
         ("draw_main", "draw: frame callback (three.js, main)"),
         ("draw_gpu", "draw: SwiftShader finishes the frame"),
         ("draw_finish", "draw: Chrome reads it back, commits"),
         ("total", "TOTAL keydown -> scene drawn"),
         ("to_lines_drawn", "keydown -> new simulated lines drawn"),
         ("event_timing", "Event Timing: keydown -> next paint")]
EXTRA = ["camera_turn_deg", "to_next_frame", "resim", "worker_decode", "worker_to_main", "wait_for_frame",
         "first_scene_batch", "frames_before"]


def run(args) -> dict:
    from playwright.sync_api import sync_playwright

    from galileo import registry
    from galileo.scenarios.ramp.dataset import build
    from galileo.video import read_video
    from ui.controller import Controller
    from ui.viewer import Viewer

    log = lambda *a: print(*a, file=sys.stderr, flush=True)
    result: dict = {}
    with contextlib.ExitStack() as stack:
        tmp = stack.enter_context(tempfile.TemporaryDirectory())
        build("demo", tmp, workers=1, progress=False)
        folder = Path(tmp) / "demo"
        scene = registry.load_scene(folder / "scene.json")
        tracks = registry.of(scene).track(folder / "video.mp4", scene, progress=False)
        ctrl = Controller(scene, tracks, chains=args.chains, seed=0, workers=1, session_dir=Path(tmp) / "session")
        stack.callback(ctrl.close)
        ctrl.run_sweeps(args.sweeps)
        video, _ = read_video(folder / "video.mp4")
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        viewer = Viewer(ctrl, ctrl.likelihood_scene, tracks, video, port=port)
        stack.callback(viewer.close)
        viewer.set_frame(viewer.n_frames - 1)   # the end poses: where the samples differ
        if args.no_shadows:   # what-if: viser's default lights without their shadow maps
            viewer.server.scene.configure_default_lights(enabled=True, cast_shadow=False)
        load_before = os.getloadavg()
        object_names = [h.name for h in viewer.object_handles]
        line_names = [f"/tracks/simulated/{n}" for n in viewer.traj.names]
        probe = ServerProbe(viewer, viewer.sample_slider._impl.uuid)
        stack.callback(probe.restore)
        pw = stack.enter_context(sync_playwright())
        browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        stack.callback(browser.close)
        page = browser.new_page(viewport={"width": args.width, "height": args.height})
        page.add_init_script(PAGE_PROBE)
        page.goto(viewer.url)
        sliders = page.get_by_role("slider")
        sliders.first.wait_for(timeout=60000)
        page.wait_for_function("() => window.__viserMutable && window.__viserTestpoints && "
                               "window.__viserMutable.nodeRefFromName[%s]" % json.dumps(object_names[0]),
                               timeout=60000)
        page.evaluate("([o, l, g]) => { __bench.objectNames = o; __bench.lineNames = l; __bench.sync = g; }",
                      [object_names, line_names, args.gpu_wait])
        gl_info = page.evaluate("""() => {
            const gl = __bench.gl();
            const e = gl && gl.getExtension('WEBGL_debug_renderer_info');
            const c = __viserMutable.canvas;
            return {renderer: gl ? gl.getParameter(e ? e.UNMASKED_RENDERER_WEBGL : gl.RENDERER) : null,
                    canvas: [c.width, c.height], dpr: devicePixelRatio, prelude: __bench.prelude,
                    attrs: gl ? gl.getContextAttributes() : null, errors: __bench.errors}; }""")
        if not gl_info["prelude"]:
            log("warning: the websocket worker could not be instrumented; server -> worker is not split off")
        time.sleep(args.settle_s)   # first scene, plots, the initial camera settle
        off, off_err = clock_offset(page)
        log(f"page clock - time.time() = {off * 1e3:+.2f} ms (+/- {off_err * 1e3:.2f} ms); "
            f"WebGL: {gl_info['renderer']}, canvas {gl_info['canvas']}")

        # idle frame interval, and frames while viser renders continuously
        bare = page.evaluate("() => __bench.frameLoop(2000, false)")
        busy = page.evaluate("() => __bench.frameLoop(3000, true)")
        time.sleep(0.5)
        bare_iv = np.diff([f["ts"] for f in bare])
        rendered_ts = [f["ts"] for f, g in zip(busy, busy[1:]) if g["frame"] != f["frame"]]
        busy_iv = np.diff(rendered_ts)

        # the Sample slider's thumb, found by the id viser gives the slider (its uuid), not by position;
        # or the number box beside it (an <input>: viser's keyboard camera controls leave it alone)
        root = page.locator(f'[id="{viewer.sample_slider._impl.uuid}"]')
        thumb = root.locator('[role="slider"]')
        targets = {"slider": thumb, "number": root.locator("xpath=..").locator('input:not([type="hidden"])')}
        keys = {"slider": {1: "ArrowRight", -1: "ArrowLeft"}, "number": {1: "ArrowUp", -1: "ArrowDown"}}
        shadows = not args.no_shadows
        conditions = {"none": [f"{args.input}, shadows {'on' if shadows else 'off'}"],
                      "input": [f"slider, shadows {'on' if shadows else 'off'}",
                                f"number, shadows {'on' if shadows else 'off'}"],
                      "shadows": [f"{args.input}, shadows on", f"{args.input}, shadows off"]}[args.alternate]

        def wait_quiet(since: float, need_call: bool) -> None:
            deadline = since + args.timeout_s
            while time.time() < deadline:
                time.sleep(0.05)
                calls = probe.snapshot()[1]
                st = page.evaluate("() => __bench.state()")
                quiet = st["now"] - max(st["lastCb"], st["lastBatch"])
                if (calls or not need_call) and (not calls or time.time() - calls[-1]["t_out"] > 0.05) \
                        and quiet > args.quiet_ms and time.time() - since > 0.3 and st["pending"] == 0:
                    return

        scrubs = []
        direction = 1
        focused = None
        for i in range(args.samples):
            cond = conditions[i % len(conditions)]
            inp, sh = cond.split(", shadows ")
            if (sh == "on") != shadows:
                shadows = sh == "on"
                viewer.server.scene.configure_default_lights(enabled=True, cast_shadow=shadows)
                wait_quiet(time.time(), False)
            if focused != inp:
                targets[inp].focus()
                focused = inp
            vnow = int(float(thumb.get_attribute("aria-valuenow")))
            vmax = int(float(thumb.get_attribute("aria-valuemax")))
            vmin = int(float(thumb.get_attribute("aria-valuemin")))
            if not vmin <= vnow + direction <= vmax:
                direction = -direction
            probe.clear()
            page.evaluate("() => __bench.startWatch()")
            page.keyboard.press(keys[inp][direction])
            wait_quiet(time.time(), True)
            rec = page.evaluate("() => __bench.stopWatch()")
            a = analyse(rec, probe.snapshot(), off)
            a["condition"] = cond
            scrubs.append(a)
            if not a["ok"]:
                log(f"scrub {i} ({cond}): {a['why']}")
            elif args.verbose:
                log(f"scrub {i} ({cond}): total {a['total']:.0f} ms: server {a['server_callback']:.1f}, earlier "
                    f"frames {a['earlier_frames']:.0f} ({a['frames_before']}), draw {a['draw_main']:.0f}+"
                    f"{a['draw_gpu']:.0f}+{a['draw_finish']:.0f}, lines {a['to_lines_drawn'] or float('nan'):.0f}")
            time.sleep(args.gap_ms / 1e3)

        def stats(vals) -> dict:
            v = [x for x in vals if x is not None and np.isfinite(x)]
            return {"p50": pct(v, 50), "p95": pct(v, 95), "mean": float(np.mean(v)) if v else float("nan")}

        handles = {h._impl.uuid: f"viewer.{attr}" for attr, h in vars(viewer).items()
                   if isinstance(getattr(getattr(h, "_impl", None), "uuid", None), str)}

        def summarize(cond: str) -> dict:
            mine = [s for s in scrubs if s["condition"] == cond]
            ok = [s for s in mine if s["ok"]]
            parts = {key: stats([s.get(key) for s in ok]) for key in [k for k, _ in PARTS] + EXTRA}
            parts["frame_cost"] = stats([c for s in ok for c in s["frame_cost"]])
            parts["camera_turn_deg_when_moved"] = stats([s.get("camera_turn_deg") for s in ok
                                                         if s.get("camera_moved")])
            msgs: dict = {}
            for s in ok:
                for typ, name, size in s["messages"]:
                    m = msgs.setdefault(f"{typ} {handles.get(name, name)}", {"count": 0, "bytes": []})
                    m["count"] += 1
                    m["bytes"].append(size)
            return {
                "scrubs": len(mine), "measured": len(ok),
                "poses_verified": sum(1 for s in ok if s.get("poses_match")),
                "pose_changed": sum(1 for s in ok if s.get("pose_changed")),
                "camera_moved": sum(1 for s in ok if s.get("camera_moved")),
                "lines_missing_in_drawn_frame": sum(1 for s in ok if s.get("lines_missing_in_drawn_frame")),
                "draw_calls": int(np.median([s["draw_calls"] for s in ok])) if ok else None,
                "triangles": int(np.median([s["triangles"] for s in ok])) if ok else None,
                "ws_frames_per_scrub": float(np.mean([s["ws_frames"] for s in ok])) if ok else float("nan"),
                "ws_bytes_per_scrub": float(np.median([s["ws_bytes"] for s in ok])) if ok else float("nan"),
                "parts_ms": parts,
                "messages": {k: {"per_scrub": v["count"] / max(len(ok), 1), "bytes_p50": float(np.median(v["bytes"]))}
                             for k, v in msgs.items()},
            }

        result = {
            "viewport": [args.width, args.height], "canvas": gl_info["canvas"], "dpr": gl_info["dpr"],
            "webgl": gl_info["renderer"],
            "preserve_drawing_buffer": (gl_info["attrs"] or {}).get("preserveDrawingBuffer"),
            "antialias": (gl_info["attrs"] or {}).get("antialias"),
            "chromium": browser.version, "cpus": os.cpu_count(), "python": platform.python_version(),
            "gpu_wait": args.gpu_wait, "samples": args.samples, "alternate": args.alternate,
            "clock_offset_ms": off * 1e3, "clock_uncertainty_ms": off_err * 1e3,
            "load_average": [round(load_before[0], 2), round(os.getloadavg()[0], 2)],
            "idle_raf_interval_ms": {"p50": pct(bare_iv, 50), "p95": pct(bare_iv, 95)},
            "render_interval_ms": {"p50": pct(busy_iv, 50), "p95": pct(busy_iv, 95), "frames": int(len(rendered_ts)),
                                   "shadows": not args.no_shadows},
            "conditions": {c: summarize(c) for c in conditions},
        }
        if args.raw:
            result["scrubs"] = scrubs
    return result


def print_table(r: dict) -> None:
    conds = r["conditions"]
    names = list(conds)
    print(f"In-browser scrub latency: viewport {r['viewport'][0]}x{r['viewport'][1]} (canvas {r['canvas'][0]}x"
          f"{r['canvas'][1]}, dpr {r['dpr']}); WebGL: {r['webgl']}")
    print(f"chromium {r['chromium']}, {r['cpus']} CPUs, load average {r['load_average'][0]} before, "
          f"{r['load_average'][1]} after; GPU wait: {r['gpu_wait']}; page clock aligned within "
          f"+/- {r['clock_uncertainty_ms']:.2f} ms")
    print(f"{'ms, p50 / p95':42s}" + "".join(f"{n:>24s}" for n in names))
    for key, label in PARTS:
        if key == "total":
            print("-" * (42 + 24 * len(names)))
        cells = [conds[n]["parts_ms"][key] for n in names]
        print(f"{label:42s}" + "".join(f"{c['p50']:15.1f} /{c['p95']:7.1f}" for c in cells))
    for n in names:
        c = conds[n]
        p = c["parts_ms"]
        k = c["measured"]
        print(f"[{n}] {k} of {c['scrubs']} scrubs measured; drawn poses equal the server's in {c['poses_verified']}"
              f" (changed in {c['pose_changed']}); the drawn frame lacked the simulated lines in "
              f"{c['lines_missing_in_drawn_frame']}; the camera moved in {c['camera_moved']}"
              + (f" (median {p['camera_turn_deg_when_moved']['p50']:.0f} deg)" if c["camera_moved"] else "")
              + f"; frames drawn before the scrub's: mean {p['frames_before']['mean']:.2f}; a rendered frame "
              f"takes p50 {p['frame_cost']['p50']:.0f} ms; re-simulation p50 {p['resim']['p50']:.1f} ms")
    c = conds[names[0]]
    print(f"idle requestAnimationFrame interval p50 {r['idle_raf_interval_ms']['p50']:.1f} ms; rendering "
          f"continuously (shadows {'on' if r['render_interval_ms']['shadows'] else 'off'}): a frame every "
          f"{r['render_interval_ms']['p50']:.0f} ms (p95 {r['render_interval_ms']['p95']:.0f}); "
          f"{c['draw_calls']} draw calls, {c['triangles']} triangles a frame")
    print(f"per scrub: {c['ws_frames_per_scrub']:.1f} websocket frames, {c['ws_bytes_per_scrub']:.0f} bytes; "
          f"messages queued by select_sample:")
    for k, v in sorted(c["messages"].items(), key=lambda kv: -kv[1]["bytes_p50"]):
        print(f"  {v['per_scrub']:4.2f} x {k} ({v['bytes_p50']:.0f} B)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=60, help="sample changes to time")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--width", type=int, default=1600)
    ap.add_argument("--height", type=int, default=1000)
    ap.add_argument("--input", choices=("slider", "number"), default="slider",
                    help="slider: arrow keys on the focused slider (as a user, and tests/test_app_browser.py); "
                         "number: ArrowUp/ArrowDown in the number box beside it")
    ap.add_argument("--chains", type=int, default=3)
    ap.add_argument("--sweeps", type=int, default=20)
    ap.add_argument("--gap-ms", type=float, default=200.0,
                    help="pause after the page goes quiet, before the next press")
    ap.add_argument("--quiet-ms", type=float, default=300.0,
                    help="a scrub is over when no frame or message came for this long")
    ap.add_argument("--timeout-s", type=float, default=10.0)
    ap.add_argument("--settle-s", type=float, default=3.0)
    ap.add_argument("--gpu-wait", choices=("readpixels", "fence", "none"), default="readpixels",
                    help="how a frame's end on the GPU is found: readpixels (a 1-pixel read in the frame "
                         "that waits for it: where Chrome's software compositing waits anyway, reading the "
                         "canvas back), fence (a WebGL2 fenceSync polled from timers: never blocks, but "
                         "late when frames follow each other), none (not split off)")
    ap.add_argument("--alternate", choices=("none", "input", "shadows"), default="none",
                    help="alternate, scrub by scrub (the same machine load for both): the slider and the "
                         "number box, or shadows on and off; a column each")
    ap.add_argument("--no-shadows", action="store_true",
                    help="what-if: the viewer's scene with viser's default lights casting no shadows "
                         "(server.scene.configure_default_lights(cast_shadow=False))")
    ap.add_argument("--raw", action="store_true", help="with --json: every scrub's numbers too")
    ap.add_argument("--verbose", action="store_true")
    args = ap.parse_args()
    if not Path(CHROMIUM).exists():
        print(f"{CHROMIUM} not found (Debian's chromium package)", file=sys.stderr)
        return 2
    with contextlib.redirect_stdout(sys.stderr):   # viser's banner
        r = run(args)
    if args.json:
        print(json.dumps(r, default=float))
    else:
        print_table(r)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
