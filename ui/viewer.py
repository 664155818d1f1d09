"""The browser viewer (viser): the video over the simulated scene, samples, plots, steering.

It only draws and forwards the user's edits to the controller (ui/controller.py); the
one computation it does itself is re-simulating the selected sample (Bullet, in this
process) with the scenario's likelihood (`Likelihood.motion`), so the 3-D scene shows the
very motion that sample was scored on (same phases, same rest rule).

* 3-D: what the scenario draws (`Scenario.drawing`: for the ramp, the ground grid, the ramp
  and the objects with their tracked shapes; connectors such as a spring between their
  anchors) posed from the selected sample's motion at the current frame; the observed
  tracks (orange) and the simulated trajectory (blue) as polylines; the video camera as a
  frustum showing the current frame.
* "Camera view" snaps each browser's camera to the video camera's pose and field of view
  and puts the frame behind the scene, so simulation and video overlap (exactly when the
  browser's viewport has the video's aspect ratio, 4:3; otherwise the background image is
  stretched to the viewport); "Free view" undoes it.
* GUI: frame slider with play; chain / sample scrubber and "jump to MAP"; log-likelihood
  traces (uPlot) and posterior histograms; acceptance; per latent whether it converged
  (R-hat and ESS, green or red / orange with the reason) and the derived quantities'
  posterior (the ramp's mass ratio); progress (never full while not converged); prior bounds,
  sigma and proposal widths; pause / resume / add / remove / reset / set chains, run until
  converged.
Several tabs share one state: the GUI lives on the server, so an edit shows everywhere.
"""
from __future__ import annotations

import html
import logging
import threading
import time
from dataclasses import dataclass

import numpy as np
import trimesh
import viser
from viser import uplot

from galileo import registry
from galileo.camera import Camera
from galileo.datatypes import Tracks, Trajectory
from galileo.drawing import connector_points, frame_pose
from galileo.errors import GalileoError
from galileo.joint import JointScene, tracks_list
from galileo.latents import as_number, check_bounds, check_noise, check_widths
from galileo.results import MIN_KEPT_DRAWS, burn_in

log = logging.getLogger(__name__)

OBJECT_COLORS = [(220, 90, 50), (70, 130, 220)]
NOT_EDITS = ("init", "pause", "resume", "run_until", "until_check", "worker_died")   # change no chain's target or state
CONVERGED_COLOR = "#2b8a3e"     # a latent whose R-hat and ESS hold
RHAT_COLOR = "#c92a2a"          # R-hat above the target, or not computable yet
ESS_COLOR = "#e8590c"           # R-hat holds, too few effective draws
FIRST_VIEW_FOV_DEG = 50.0    # the first view: this wide, the scene filling FIRST_VIEW_FILL of it
FIRST_VIEW_FILL = 0.7
FIRST_VIEW_ASPECT = 4 / 3    # the narrowest window the first view plans for
FRUSTUM_SCALE = 0.2          # the video camera's frustum: this much of the scene's radius deep
FRUSTUM_LINE_PX = 2.0        # its lines, in screen pixels (world-thick lines filled a close view)
# the log-likelihood traces: each chain's log-likelihood minus the best so far, on an asinh
# scale linear within this many nats of the best (converged chains' spread) and logarithmic
# beyond it (a chain stuck 1,000 nats below does not flatten the others into one line)
TRACE_ASINH_NATS = 10.0
TRACE_TITLE = "log-likelihood minus the best so far (nats; asinh scale)"
Y_AXIS_CHAR_PX, Y_AXIS_PAD_PX = 9, 30   # uPlot's 12 px axis font: digits and "-" about 7 px, ticks 10 px
HIST_BINS = 30               # a posterior histogram's bins (over the kept draws' range)
BACKGROUND_MAX_PX = 1920     # the letterboxed camera-view background, at most this wide
CHAIN_COLORS = ["#e6194b", "#3cb44b", "#4363d8", "#f58231", "#911eb4", "#42d4f4", "#f032e6", "#bfef45",
                "#469990", "#9a6324", "#800000", "#808000", "#000075", "#a9a9a9", "#e6beff", "#fabebe"]


def fit_distance(pts: np.ndarray, centre: np.ndarray, direction: np.ndarray, fov: float, aspect: float,
                 fill: float) -> float:
    """How far from `centre` along `direction` (unit, pointing from the scene to the camera) a
    camera looking at `centre` with vertical `fov` must stand for `pts` to span `fill` of the
    view (of its height or, at `aspect`, its width, whichever is reached first)."""
    fwd = -direction
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right) or 1.0
    down = np.cross(fwd, right)
    t = np.tan(fov / 2)

    def extent(d: float) -> float:
        rel = pts - (centre + d * direction)
        z = rel @ fwd
        if (z <= 1e-6).any():
            return np.inf
        x, y = (rel @ right) / z / (t * aspect), (rel @ down) / z / t
        return max(float(np.abs(x).max()), float(np.abs(y).max()))

    lo, hi = 1e-3, 1e3
    for _ in range(60):         # the extent falls as the camera backs off: bisect on log distance
        mid = np.sqrt(lo * hi)
        lo, hi = (mid, hi) if extent(mid) > fill else (lo, mid)
    return float(hi)


def in_front_of(eye: np.ndarray, look_at: np.ndarray, point: np.ndarray, pts: np.ndarray, fov: float,
                aspect: float) -> bool:
    """Whether `point` lies inside the view from `eye` towards `look_at` (vertical `fov`, at
    `aspect`) and nearer the eye than every one of `pts`: in the way of what the view frames."""
    fwd = (look_at - eye) / np.linalg.norm(look_at - eye)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right) or 1.0
    down = np.cross(fwd, right)
    rel = point - eye
    z = float(rel @ fwd)
    if z <= 0:
        return False
    t = np.tan(fov / 2)
    inside = abs(rel @ right) / z <= t * aspect and abs(rel @ down) / z <= t
    return bool(inside and z < float(((pts - eye) @ fwd).min()))


def edit_sweep(event: dict) -> int:
    """The sweep an edit is marked at: the last sweep the most advanced chain ran before it
    (the chains' own count, which a session's rounds outrun when only some chains run)."""
    sweeps = [v for v in (event.get("chain_sweeps") or {}).values() if isinstance(v, (int, float))]
    return int(max(sweeps)) if sweeps else int(event["sweep"])


def _wxyz_from_matrix(r: np.ndarray) -> np.ndarray:
    """Quaternion (w, x, y, z) of a rotation matrix."""
    q = trimesh.transformations.quaternion_from_matrix(np.block([[r, np.zeros((3, 1))], [np.zeros((1, 3)), 1]]))
    return np.asarray(q)  # trimesh returns (w, x, y, z)


def _wxyz_from_xyzw(q) -> np.ndarray:
    return np.array([q[3], q[0], q[1], q[2]])


def init_markdown(info: dict, names, starts_doc: str = "drawn from the prior") -> str:
    """How the chains started, for the Chains panel: as the scenario starts them
    (`Scenario.starts_doc`: the prior, or the splash's seed start), or what the recognition model
    read (per object: mass and friction with 90% intervals)."""
    if info.get("starts") != "recognition":
        return f"Chains started {starts_doc}."
    parts = [f"Chains started from the recognition model ({info.get('kind') or 'lenet'}, "
             f"{info.get('labels') or '?'} labels):"]
    for role, r in (info.get("readings") or {}).items():
        if isinstance(r, dict) and "mass_kg" in r:
            fr = (f", friction {r['friction']:.3f} ({r['friction_90'][0]:.3f}-{r['friction_90'][1]:.3f})"
                  if "friction" in r else "")
            parts.append(f"{role}: mass {r['mass_kg']:.3g} kg (90% {r['mass_kg_90'][0]:.3g}-{r['mass_kg_90'][1]:.3g})"
                         + fr)
    return "  \n".join(parts)


def unidentified_markdown(unidentified: dict[str, str]) -> str:
    """What the videos leave to the prior or cannot tell (`Scenario.unidentified`, result.json's
    "not_identified": a mass that does not change a fall), for the Chains panel; "" when none."""
    return "  \n".join(["**Not identified:**"] + [f"{name}: {why}" for name, why in unidentified.items()]
                       ) if unidentified else ""


def tracking_markdown(tracks) -> str:
    """What tracking wants the user to know (each video's `Tracks.notes`: the camera moved, the exposure
    drifted, the video is blurred, a distractor was left out, nothing moves ...), for the Chains panel;
    "" when it says nothing."""
    many = isinstance(tracks, (list, tuple)) and len(tracks) > 1
    notes = [f"video {v + 1}: {n}" if many else n
             for v, t in enumerate(tracks if isinstance(tracks, (list, tuple)) else [tracks])
             for n in (getattr(t, "notes", None) or ())]
    return "  \n".join(["**Tracking:**"] + notes) if notes else ""


def recognition_curves(info: dict, names) -> dict:
    """Latent name -> the recognition proposal's density (a function of the latent's value),
    for the latents it reads (its uniform components are the prior's and are not drawn)."""
    q = info.get("proposal") if info.get("starts") == "recognition" else None
    out = {}
    if not q:
        return out
    for n, kind, loc, scale in zip(names, q["kinds"], q["loc"], q["scale"]):
        if kind == "normal":
            out[n] = lambda x, m=loc, s=scale: np.exp(-0.5 * ((x - m) / s) ** 2)
        elif kind == "lognormal":
            out[n] = lambda x, m=loc, s=scale: np.where(
                x > 0, np.exp(-0.5 * ((np.log(np.maximum(x, 1e-300)) - m) / s) ** 2) / np.maximum(x, 1e-300), 0.0)
    return out


def convergence_html(conv: dict, derived: dict, fmt=lambda name, v: f"{v:.3g}", warming: str | None = None) -> str:
    """The Chains panel's verdict: an overall line ("Converged: all n latents", or "Not
    converged: k of n latents converged so far"), then per latent one coloured line (green:
    converged; red: R-hat above the target or not computable; orange: R-hat holds, ESS too
    low) with R-hat, ESS (the lower of bulk and tail) and "converged" or "not converged: why";
    then the posterior median and 90% interval of each derived quantity (as
    `InferenceResult.derived_posterior` gives them; a log_<x> beside its <x> is left out).
    `warming` (e.g. "sweep 12 of 37"): the chains are still in warm-up, so there is no verdict
    yet, and each latent says so. A derived quantity marked fixed (the same in every draw: the
    scene's) is shown as fixed, never as a posterior."""
    e = html.escape
    per = conv.get("per_latent") or {}
    why = {}
    for line in conv.get("why_not") or []:
        name, _, reason = line.partition(": ")
        why[name] = reason
    n_ok = sum(1 for ok in per.values() if ok)
    criteria = f"R-hat &le; {conv.get('rhat_target', 1.01):g}, ESS &ge; {conv.get('min_ess', 400):g}"
    if warming:
        head = (f'<div class="galileo-verdict" style="font-weight:600;color:{ESS_COLOR}">'
                f"Warming up ({e(warming)}): no verdict before the kept draws ({criteria})</div>")
    elif conv.get("converged"):
        head = (f'<div class="galileo-verdict" style="font-weight:600;color:{CONVERGED_COLOR}">'
                f"Converged: all {len(per)} latents ({criteria})</div>")
    else:
        head = (f'<div class="galileo-verdict" style="font-weight:600;color:{RHAT_COLOR}">'
                f"Not converged: {n_ok} of {len(per)} latents converged so far ({criteria})</div>")
    rows = []
    for name, ok in per.items():
        r = (conv.get("r_hat") or {}).get(name)
        ess = [x for x in ((conv.get("ess_bulk") or {}).get(name), (conv.get("ess_tail") or {}).get(name))
               if x is not None]
        if warming:
            color, state = ESS_COLOR, "warming up"
        elif ok:
            color, state = CONVERGED_COLOR, "converged"
        else:
            color = ESS_COLOR if (r is not None and r <= conv.get("rhat_target", 1.01)) else RHAT_COLOR
            state = "not converged: " + why.get(name, "?")
        rows.append(f'<div class="galileo-latent" data-latent="{e(name)}" data-converged="{str(bool(ok)).lower()}" '
                    f'style="color:{color}"><b>{e(name)}</b> R-hat {"-" if r is None else f"{r:.3f}"}, '
                    f'ESS {"-" if not ess else f"{min(ess):.0f}"}: {e(state)}</div>')
    fixed = {k: fmt(k, v["q50"]) for k, v in derived.items() if v.get("fixed")}
    shown = [k for k in derived if not (k.startswith("log_") and k[4:] in derived) and k not in fixed]
    der = [f'<div class="galileo-derived"><b>{e(k)}</b>: median {fmt(k, derived[k]["q50"])} '
           f'(90% {fmt(k, derived[k]["q05"])} &ndash; {fmt(k, derived[k]["q95"])})</div>' for k in shown]
    if der:
        der.insert(0, '<div style="margin-top:4px">Posterior (kept draws):</div>')
    fix = [f'<div class="galileo-fixed"><b>{e(k)}</b>: {e(v)} (fixed by the scene, not inferred)</div>'
           for k, v in fixed.items()]
    return f'<div class="galileo-convergence" style="font-size:13px;line-height:1.45;padding:0 0.75em 0.5em 0.75em">{head}{"".join(rows)}{"".join(der)}{"".join(fix)}</div>'


def camera_pose(cam: Camera) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Viser camera pose for the video camera: (wxyz, position, vertical fov, aspect).

    Viser's cameras follow the OpenCV convention (+z forward, +y down), as ours do, so the
    camera-to-world rotation is the transpose of world_to_camera's."""
    r, t = cam.world_to_camera[:3, :3], cam.world_to_camera[:3, 3]
    fov = 2 * np.arctan2(cam.height_px / 2, cam.K[1, 1])
    return _wxyz_from_matrix(r.T), -r.T @ t, float(fov), cam.width_px / cam.height_px


def _segments(points: np.ndarray) -> np.ndarray:
    """(N, 3) polyline -> (N-1, 2, 3) segments, skipping NaN points."""
    pts = points[~np.isnan(points).any(axis=1)]
    if len(pts) < 2:
        return np.zeros((1, 2, 3))
    return np.stack([pts[:-1], pts[1:]], axis=1)


def _per_latent(width, k: int) -> tuple[float, ...]:
    """Proposal widths (a number, or one per latent) as one per latent."""
    return tuple(float(w) for w in width) if isinstance(width, tuple) else (float(width),) * k


def _num(x: float) -> str:
    """A number as the text fields show it: every digit it has (0.05, 1e-05, 30), no more."""
    x = float(x)
    return str(int(x)) if x.is_integer() and abs(x) < 1e15 else repr(x)


def parse_numbers(text, n: int, what: str) -> tuple[float, ...]:
    """`n` finite numbers from a text field ("0.001, 1" or "0.001 1"), exactly as typed; a
    ValueError naming the field otherwise (never a silently changed value)."""
    parts = str(text).replace(",", " ").split()
    if len(parts) != n:
        want = "a number" if n == 1 else f"{n} numbers separated by a comma"
        raise ValueError(f"{what}: expected {want}, got {str(text).strip()!r}")
    return tuple(as_number(p, what) for p in parts)


def _message(text: str, ok: bool) -> str:
    """A one-line message under a panel's buttons: green when done, red when refused."""
    color = CONVERGED_COLOR if ok else RHAT_COLOR
    return (f'<div class="galileo-message" data-ok="{str(ok).lower()}" style="color:{color};font-size:13px;'
            f'padding:0 0.75em 0.25em 0.75em">{html.escape(text)}</div>')


def letterbox(image: np.ndarray, cam: Camera, aspect: float, max_px: int = BACKGROUND_MAX_PX) -> tuple[np.ndarray, float]:
    """The video frame padded (black) to a viewport's aspect ratio with the camera's principal
    point at its centre, and the vertical field of view that then makes a pinhole view of the
    viewport match the video pixel for pixel: (padded image, vertical fov in radians).
    A browser stretches the background image over its canvas; padded like this, the stretch
    is uniform and the scene drawn with that fov lands on the video's pixels."""
    h, w = image.shape[:2]
    fx, fy, cx, cy = cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]
    sx = w / cam.width_px     # the video may be stored at another size than the camera's
    sy = h / cam.height_px
    fx, fy, cx, cy = fx * sx, fy * sy, cx * sx, cy * sy
    half_w, half_h = max(cx, w - cx), max(cy, h - cy)    # in pixels, around the principal point
    # in units of the focal length: the viewport covers +-half_w/fx horizontally, +-half_h/fy vertically
    tw, th = half_w / fx, half_h / fy
    if tw / th < aspect:
        tw = th * aspect
    else:
        th = tw / aspect
    out_w, out_h = 2 * tw * fx, 2 * th * fy
    scale = min(1.0, max_px / out_w)
    W, H = max(int(round(out_w * scale)), 1), max(int(round(out_h * scale)), 1)
    import cv2

    # the affine map from the frame into the padded canvas: the principal point to the centre
    kx, ky = W / out_w, H / out_h
    m = np.array([[kx, 0.0, W / 2 - kx * cx], [0.0, ky, H / 2 - ky * cy]])
    canvas = cv2.warpAffine(np.ascontiguousarray(image[..., :3]), m, (W, H), flags=cv2.INTER_AREA,
                            borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0))
    return canvas, float(2 * np.arctan(th))


def _assign(plot, spec: dict, sent: dict) -> None:
    """Set a uPlot handle's props from `spec`, only those that changed since last sent (viser
    sends every assignment of a dict or tuple prop; a new `scales` also rebuilds the chart)."""
    for key in ("series", "axes", "legend", "scales", "title", "data"):
        if key not in spec:
            continue
        value = spec[key]
        token = repr(value) if key != "data" else [np.asarray(d).tobytes() for d in value]
        if sent.get(key) != token:
            setattr(plot, key, value)
            sent[key] = token


def _axis_px(labels) -> int:
    """A y axis wide enough for its widest tick label (uPlot's 12 px font)."""
    return Y_AXIS_CHAR_PX * max((len(t) for t in labels), default=1) + Y_AXIS_PAD_PX


def _unit(unit: str) -> str:
    """A unit for an axis or a label: nothing for a dimensionless quantity (not "(1)")."""
    return "" if unit in ("", "1") else f" ({unit})"


def trace_plot_spec(traces: list[np.ndarray], labels: list[str], colors: list[str], edits: list[int]) -> dict:
    """The log-likelihood traces' uPlot props: each chain's log-likelihood less the best so far
    (<= 0; TRACE_TITLE) per sweep, a shorter (paused, removed) chain held at its last value
    (uPlot draws nothing if a series holds NaN), edits as spikes at the sweep they took effect,
    and both scales' ranges set here: left to itself, viser's client let the x range drift to
    [0, 1] as data came in (the traces one column of dots at x = 1), and uPlot's asinh
    auto-range cut the y axis at -10, hiding every chain within 10 nats of the best."""
    length = max(len(t) for t in traces)
    x = np.arange(1, length + 1, dtype=float)
    best = max(float(np.max(t)) for t in traces if len(t))
    ys = [np.concatenate([t, np.full(length - len(t), t[-1] if len(t) else best)]) - best for t in traces]
    series = [uplot.Series(label="sweep")] + [uplot.Series(label=lab, stroke=col, width=1)
                                              for lab, col in zip(labels, colors)]
    data = [x, *ys]
    lowest = min(float(y.min()) for y in ys)
    marks_at = sorted({sw for sw in edits if 1 <= sw <= length})
    if marks_at:
        stack = np.stack(ys)
        marks = np.full(length, lowest)
        for sw in marks_at:
            marks[sw - 1] = float(stack[:, sw - 1].max())
        series.append(uplot.Series(label="edit", stroke="#000", width=1))
        data.append(marks)
    # y: from a little below the lowest trace (asinh: a tenth further, at least a nat) to a little
    # above 0; ticks at 0, -10, -100, ... (uPlot's own asinh ticks crowded out their labels)
    y_lo = lowest - max(1.0, 0.1 * abs(lowest))
    splits = [0.0] + [-(10.0 ** k) for k in range(1, 12) if -(10.0 ** k) >= y_lo]
    title = TRACE_TITLE + (f"; edits at sweep{'s' if len(marks_at) > 1 else ''} "
                           f"{', '.join(str(e) for e in marks_at)}" if marks_at else "")
    return {"series": tuple(series), "data": tuple(data), "title": title,
            "legend": uplot.Legend(show=len(labels) <= len(CHAIN_COLORS)),   # the splash's 50: taller than the plot
            "scales": {"x": uplot.Scale(time=False, range=(1.0, float(max(length, 2)))),
                       "y": uplot.Scale(distr=4, asinh=TRACE_ASINH_NATS, range=(float(y_lo), 3.0))},
            "axes": (uplot.Axis(label="sweep"),
                     uplot.Axis(size=_axis_px([f"{v:,.0f}" for v in splits]), splits=tuple(splits),
                                values=tuple(f"{v:,.0f}" for v in splits)))}


def histogram_spec(kept: np.ndarray, starts: np.ndarray, bounds, latent, *, integer: bool = False,
                   recognized=None) -> dict:
    """A latent's posterior histogram's uPlot props: HIST_BINS bins over where the kept draws are
    (their range widened by a tenth each side, inside the prior), so a posterior far narrower
    than its prior is a histogram, not one spike; over the whole prior before there are kept
    draws (warm-up). The chains' starts inside that range (counted x 10, so 16 chains show
    beside thousands of draws); the recognition model's density, scaled to the histogram's peak.
    An integer latent gets a bin per integer. Axes titled, with the latent's unit."""
    lo, hi = (float(b) for b in bounds)
    kept = kept[np.isfinite(kept) & (kept >= lo) & (kept <= hi)]    # (draws before a prior edit may lie outside)
    if len(kept):
        a, b = float(kept.min()), float(kept.max())
        pad = 0.1 * (b - a) if b > a else max(abs(a) * 0.01, (hi - lo) * 1e-3)
        lo, hi = max(lo, a - pad), min(hi, b + pad)
    if integer:   # one bin per integer, at the integer
        ks = np.arange(np.ceil(lo), np.floor(hi) + 1)
        edges = np.append(ks - 0.5, ks[-1] + 0.5) if len(ks) else np.array([lo, hi])
        x = ks.astype(float) if len(ks) else np.array([lo])
    else:
        edges = np.linspace(lo, hi, HIST_BINS + 1)
        x = ((edges[:-1] + edges[1:]) / 2).astype(float)
    counts = np.histogram(kept, bins=edges)[0].astype(float)
    started = 10.0 * np.histogram(starts[(starts >= edges[0]) & (starts <= edges[-1])], bins=edges)[0].astype(float)
    series = [uplot.Series(label=f"{latent.name}{_unit(latent.unit)}"),
              uplot.Series(label="kept draws", stroke="#444", fill="#4363d855"),
              uplot.Series(label="chain starts (x 10)", stroke="#e6194b", width=2)]
    data = [x, counts, started]
    if recognized is not None:   # the recognition model's density, its peak at the posterior's
        dens = recognized(x)
        data.append(dens / max(float(dens.max()), 1e-300) * max(float(counts.max()), 1.0))
        series.append(uplot.Series(label="recognition (scaled)", stroke="#f58231", width=2))
    top = max(float(np.max(d)) for d in data[1:])
    span = (float(x[0]) - 0.5, float(x[-1]) + 0.5) if integer else (float(edges[0]), float(edges[-1]))
    return {"series": tuple(series), "data": tuple(data),
            "title": f"posterior {latent.name}" + ("" if len(kept) else " (no kept draws in the prior yet)"),
            "scales": {"x": uplot.Scale(time=False, range=span)},
            "axes": (uplot.Axis(label=f"{latent.name}{_unit(latent.unit)}"),
                     uplot.Axis(label="draws", size=_axis_px([f"{top:,.0f}"]) + 14))}


@dataclass
class Selection:
    chain: int
    index: int


class Viewer:
    def __init__(self, controller, scene, tracks: Tracks, video_rgb: np.ndarray, *,
                 host: str = "127.0.0.1", port: int = 8080, target_sweeps: int = 75):
        self.ctrl = controller
        self.scene = scene
        # a problem of several videos (galileo.joint): tracks and video_rgb are lists, one per video;
        # the viewer shows one video at a time (the Video folder's chooser)
        self._joint = isinstance(scene, JointScene)
        self._scenes = list(scene.scenes) if self._joint else [scene]
        self._all_tracks = tracks_list(tracks)
        self._videos = list(video_rgb) if self._joint else [video_rgb]
        if not (len(self._scenes) == len(self._all_tracks) == len(self._videos)):
            raise ValueError("a problem's viewer needs one scene, tracks and video per video")
        self.target_sweeps = target_sweeps
        self.scenario = registry.of(scene)
        self._view_scenario = getattr(self.scenario, "base", self.scenario)   # one video's scenario
        self.model = self.scenario.likelihood(scene, tracks, controller.settings.noise)   # draws its `motion`
        self._use_video(0)
        self.traj: Trajectory | None = None
        self.resimulations = 0
        self.last_resim_s = 0.0
        self.frame = 0
        self.selection = Selection(0, 0)
        self.selection_empty = True   # nothing simulated yet
        self._lock = threading.RLock()
        self._selection_listeners: list = []
        self._dirty = threading.Event()
        self._stop = threading.Event()
        st = controller.settings
        narrow = _per_latent(st.narrow, len(controller.names))
        # decimals a latent is shown with: integers none, others down to their narrow width's first digit (3 at least)
        self._integer = {j for j, lat in enumerate(controller.latents) if lat.integer}
        self._decimals = {n: 0 if j in self._integer else max(3, int(np.ceil(-np.log10(narrow[j]))))
                          for j, n in enumerate(controller.names)}
        self._sent: dict[str, dict] = {}   # per plot, the props last sent (see _assign)
        self._set_inputs_chain: int | None = None   # the chain "Set chain's latents" was filled from
        self._excluded: list[int] = []    # chains the last prior edit left outside (Restart them inside)
        self._frustum_scale_m = 0.15     # (the first view sets it from the scene's size)
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        if port and self.server.get_port() != port:
            # viser moves on to the next free port without a word: a user's bookmark, firewall rule
            # or tunnel would then reach another program, or nothing
            self.server.stop()
            from galileo.errors import GalileoError

            raise GalileoError(f"port {port} on {host} is taken (another app running?); choose another with --port")
        self.url = f"http://{host}:{self.server.get_port()}"
        # the panel docked beside the 3-D view, not floating over it (it covered the target and the
        # collision at 1280 x 720, and the camera view's right side)
        self.server.gui.main_panel.dock_right()
        self._build_scene()
        self._build_gui()
        self.select_sample(*self._first_selection())
        if self.ctrl.map() is not None:   # a reopened session: the chain and sample inputs show the MAP too
            self.jump_to_map()
        self._threads = [threading.Thread(target=self._refresh_loop, daemon=True),
                         threading.Thread(target=self._play_loop, daemon=True)]
        controller.add_listener(self._on_controller)
        self._dirty.set()   # plots and status at once (a reopened session's paused chains send nothing)
        for t in self._threads:
            t.start()

    def _use_video(self, v: int) -> None:
        """Show video v of the problem (its frames, tracks, scene; the motion it scored)."""
        self.video_index = int(v)
        self.tracks = self._all_tracks[v]
        self.video = self._videos[v]
        self.view_scene = self._scenes[v]
        self.n_frames = min(len(self.video), self.tracks.n_frames)
        self.fps = self.tracks.fps

    def _motion(self, position) -> Trajectory:
        """The motion the shown video scored at `position`."""
        if self._joint:
            return self.model.motion(position, video=self.video_index)
        return self.model.motion(position)

    def show_video(self, v: int) -> None:
        """Switch the viewer to video v of a problem of several: its frames, its world (static
        meshes, objects, connectors, observed tracks, camera) and the selected sample's motion in it."""
        if not 0 <= v < len(self._videos):
            raise ValueError(f"video {v + 1}: the problem has {len(self._videos)}")
        with self._lock, self.server.atomic():
            for h in self._world_handles + self.sim_lines + list(self._frustums.values()):
                h.remove()
            self.sim_lines, self._frustums = [], {}
            self._use_video(v)
            self._build_world()
            self._set_opacity(float(self.opacity_slider.value))
            self.frame = min(self.frame, self.n_frames - 1)
            self.frame_slider.max = self.n_frames - 1
            self.frame_slider.value = self.frame
            clients = self.server.get_clients()
            for cid, client in clients.items():
                if self.camera is not None and cid not in self._camera_clients:
                    self._add_frustum(client)
                elif cid in self._camera_clients:
                    if self.camera is None:
                        self._camera_clients.pop(cid)
                        client.scene.set_background_image(None)
                    else:
                        self._send_camera_view(client)
            self.select_sample(self.selection.chain, self.selection.index, force=True)

    # -- 3-D scene -------------------------------------------------------------------------
    def _build_scene(self) -> None:
        self.server.scene.set_up_direction("+z")
        self._frustums: dict[int, object] = {}        # per browser (client id), while in free view
        self._camera_clients: dict[int, dict] = {}    # browsers in the camera view: their earlier view
        self.sim_lines = []
        drawing = self._build_world()
        self._first_view(drawing)
        self.server.on_client_connect(self._on_connect)
        self.server.on_client_disconnect(lambda c: (self._frustums.pop(c.client_id, None),
                                                    self._camera_clients.pop(c.client_id, None)))

    def _build_world(self):
        """The shown video's world: static meshes, objects, connectors, observed tracks, its camera
        (the handles kept to remove on a switch of video); its drawing."""
        s, sc = self.server.scene, self.view_scene
        drawing = self._view_scenario.drawing(sc)
        self._world_handles = []
        if drawing.ground_z_m is not None:
            self._world_handles.append(s.add_grid("/ground", width=3.0, height=2.0, plane="xy",
                                                  position=(0.0, 0.0, drawing.ground_z_m)))
        for m in drawing.static:
            self._world_handles.append(s.add_mesh_simple(f"/{m.name}", m.vertices, m.faces, color=m.color,
                                                         opacity=m.opacity))
        self.object_handles = [s.add_mesh_simple(f"/objects/{m.name}", m.vertices, m.faces, color=m.color,
                                                 opacity=m.opacity) for m in drawing.objects]
        # connectors (springs, strings): one line-segments handle each, its points moved per frame
        self.connectors = tuple(drawing.connectors)
        self.connector_handles = [s.add_line_segments(f"/connectors/{c.name}", np.zeros((c.n_points - 1, 2, 3)),
                                                      c.color, thickness=c.width_px, thickness_units="screen")
                                  for c in self.connectors]
        for o in self.tracks.objects:
            self._world_handles.append(s.add_line_segments(f"/tracks/observed/{o.name}", _segments(o.position_m),
                                                           (255, 140, 0), thickness=3, thickness_units="screen"))
        self._world_handles += self.object_handles + self.connector_handles
        self.camera = self._view_scenario.camera(sc)   # None: no video camera, so no frustum and no camera view
        return drawing

    def _first_view(self, drawing) -> None:
        """New browsers start looking at the whole scene (the ramp, the tank) filling most of a
        FIRST_VIEW_FOV_DEG-wide view, from the video camera's side, turned 40 degrees and
        raised (a view the camera view does not give); viser's default view (from (3, 3, 3) m,
        75 degrees wide) showed a 0.9 m ramp about 80 px wide in a 1600 px window."""
        pts = [m.vertices for m in drawing.static] + [o.position_m[np.isfinite(o.position_m).all(axis=1)]
                                                      for o in self.tracks.objects]
        pts = [p for p in pts if len(p)]
        if not pts:
            return
        pts = np.concatenate(pts)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        centre = (lo + hi) / 2
        radius = float(np.linalg.norm(hi - lo)) / 2
        if not radius > 0:
            return
        self._frustum_scale_m = FRUSTUM_SCALE * radius
        back = (np.array([0.5, -0.87, 0.0]) if self.camera is None else camera_pose(self.camera)[1] - centre)
        back[2] = 0.0
        back = back / (np.linalg.norm(back) or 1.0)
        a = np.deg2rad(40.0)
        rot = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
        direction = rot @ back + np.array([0.0, 0.0, 0.6])
        direction /= np.linalg.norm(direction)
        fov = np.deg2rad(FIRST_VIEW_FOV_DEG)
        dist = fit_distance(pts, centre, direction, fov, FIRST_VIEW_ASPECT, FIRST_VIEW_FILL)
        if self.camera is not None:
            # the video camera's frustum must not stand between the view and the scene (the
            # splash's camera is close to its tank): if it would, frame it with the scene
            eye, cam_pos = centre + dist * direction, camera_pose(self.camera)[1]
            if in_front_of(eye, centre, cam_pos, pts, fov, FIRST_VIEW_ASPECT):
                pts = np.vstack([pts, cam_pos + self._frustum_scale_m * (cam_pos - eye) / np.linalg.norm(cam_pos - eye)])
                dist = fit_distance(pts, centre, direction, fov, FIRST_VIEW_ASPECT, FIRST_VIEW_FILL)
        self.server.initial_camera.fov = fov
        self.server.initial_camera.look_at = centre
        self.server.initial_camera.position = centre + dist * direction

    def _on_connect(self, client) -> None:
        """Each browser's own camera state: a frustum showing the current frame while in free
        view (the camera view hides it: it would cover the view); a camera view that follows the
        browser's window shape (the letterboxed background is the browser's own)."""
        if self.camera is not None:
            self._add_frustum(client)
            client.camera.on_update(lambda cam: self._on_camera_update(cam.client))

    def _add_frustum(self, client) -> None:
        wxyz, pos, fov, aspect = camera_pose(self.camera)
        with self._lock:
            self._frustums[client.client_id] = client.scene.add_camera_frustum(
                "/video_camera", fov=fov, aspect=aspect, scale=self._frustum_scale_m, thickness=FRUSTUM_LINE_PX,
                thickness_units="screen", image=self.video[self.frame], format="jpeg",
                jpeg_quality=80, wxyz=wxyz, position=pos)

    def _on_camera_update(self, client) -> None:
        """A browser in the camera view whose window changed shape gets its letterbox again."""
        state = self._camera_clients.get(client.client_id)
        if state is None:
            return
        aspect = client.camera.aspect if client.camera.image_height else None
        if aspect and abs(aspect - state["aspect"]) > 1e-3:
            self._send_camera_view(client)

    def _set_opacity(self, value: float) -> None:
        for h in self.object_handles:
            h.opacity = float(value)

    def _update_sim_lines(self) -> None:
        for h in self.sim_lines:
            h.remove()
        self.sim_lines = [self.server.scene.add_line_segments(
            f"/tracks/simulated/{name}", _segments(self.traj.position_m[i]), (40, 90, 230), thickness=3,
            thickness_units="screen") for i, name in enumerate(self.traj.names)]

    # -- GUI ----------------------------------------------------------------------------------
    def _build_gui(self) -> None:
        g = self.server.gui
        ctrl = self.ctrl
        with g.add_folder("Video"):
            self.video_dropdown = None
            if len(self._videos) > 1:
                self.video_dropdown = g.add_dropdown("Video", [f"video {v + 1}" for v in range(len(self._videos))],
                                                     hint="which of the problem's videos to show (the chains "
                                                          "fit them all)")
            self.frame_slider = g.add_slider("Frame", 0, self.n_frames - 1, 1, 0)
            self.play = g.add_checkbox("Play", False)
            self.view_button = g.add_button("Camera view")
            self.free_button = g.add_button("Free view")
            self.opacity_slider = g.add_slider("Simulated opacity", 0.0, 1.0, 0.05, 1.0,
                                               hint="see the video's objects through the simulated ones")
        with g.add_folder("Samples"):
            self.chain_dropdown = g.add_dropdown("Chain", [str(c) for c in ctrl.chain_ids()] or ["0"])
            self.sample_slider = g.add_slider("Sample", 0, 1, 1, 0)
            self.map_button = g.add_button("Jump to MAP")
            self.follow_map = g.add_checkbox("Follow the MAP", True,
                                             hint="show the best sample so far as it changes (scrubbing turns it off)")
            self.sample_text = g.add_markdown("")
        with g.add_folder("Chains"):
            self.progress = g.add_progress_bar(0.0, animated=True)
            self.status_text = g.add_markdown("")
            self.convergence_box = g.add_html("")
            # (its series, scales and axes come with the first traces: trace_plot_spec)
            self.trace_plot = g.add_uplot((np.zeros(1), np.zeros(1)), (uplot.Series(label="sweep"),
                                                                       uplot.Series(label="chain 0")),
                                          title=TRACE_TITLE, aspect=1.4)
            self.init_text = g.add_markdown(init_markdown(ctrl.init_info, ctrl.names, ctrl.scenario.starts_doc))
            self.unidentified_text = g.add_markdown(unidentified_markdown(
                ctrl.scenario.unidentified(ctrl.likelihood_scene, ctrl.tracks)))
            self.tracking_text = g.add_markdown(tracking_markdown(ctrl.tracks))
            self._recognized = recognition_curves(ctrl.init_info, ctrl.names)
            self.hist_plots = {}
            for n in ctrl.names:
                series = [uplot.Series(label=n), uplot.Series(label="kept draws")]
                self.hist_plots[n] = g.add_uplot((np.zeros(1),) * len(series), tuple(series),
                                                 title=f"posterior {n}", aspect=2.2)
        specs = self._specs = {lat.name: lat for lat in ctrl.latents}
        # Every number is a text field, read by the server exactly as typed (a browser's number
        # input rewrites what it cannot parse: "1e308" became 1308, -1 became the minimum)
        with g.add_folder("Priors and settings", expand_by_default=False):
            self.settings_in_force = g.add_markdown("")
            self.bound_inputs = {n: g.add_text(f"{n} bounds{_unit(specs[n].unit)}", "",
                                               hint=f"uniform prior: low, high in {specs[n].unit}: {specs[n].doc}")
                                 for n in ctrl.names}
            noise = ctrl.scenario.noise
            self.sigma_input = g.add_text(f"{noise.name} ({noise.unit})", "", hint=noise.doc or None)
            st = ctrl.settings
            if isinstance(st.narrow, tuple) or isinstance(st.broad, tuple):
                # one (narrow, broad) pair per latent, in its own unit
                self.narrow_input = self.broad_input = None
                self.width_inputs = {n: g.add_text(f"{n} widths", "", hint=f"proposal half-widths: narrow, broad "
                                                   f"in {specs[n].unit}") for n in ctrl.names}
            else:
                self.width_inputs = {}
                self.narrow_input = g.add_text("narrow width", "", hint="proposal half-width of the usual sweep")
                self.broad_input = g.add_text("broad width", "", hint="proposal half-width of the broad sweep")
            self.every_input = g.add_text("broad every", "", hint="every this many sweeps a broad one (0: never)")
            self.apply_button = g.add_button("Apply")
            self.settings_message = g.add_html("")
            self.restart_inside = g.add_button("Restart those chains inside the new prior", color="orange",
                                               visible=False)
            self._show_settings_in_force()
        with g.add_folder("Steering", expand_by_default=False):
            self.steer_message = g.add_html("")
            self.pause_all = g.add_button("Pause all")
            self.resume_all = g.add_button("Resume all")
            self.pause_one = g.add_button("Pause chain")
            self.resume_one = g.add_button("Resume chain")
            self.add_button = g.add_button("Add chain")
            self.remove_button = g.add_button("Remove chain")
            self.remove_confirm = g.add_button("Confirm", color="red", visible=False)
            self.remove_cancel = g.add_button("Cancel", visible=False)
            self._remove_pending: int | None = None
            self.reset_map = g.add_button("Reset chain to MAP")
            self.reset_sel = g.add_button("Reset chain to selected sample")
            start = self._start_values()
            self.set_inputs = {n: g.add_text(f"{n}{_unit(specs[n].unit)}", f"{start[n]:.6g}",
                                             hint=f"{specs[n].unit}: {specs[n].doc}") for n in ctrl.names}
            self.set_button = g.add_button("Set chain's latents")
            until = ctrl.status().get("until") or {}
            self.until_input = g.add_text("until R-hat", _num(until.get("until_rhat", 1.01)),
                                          hint="run on past the sweep target until every latent's R-hat is at "
                                               "most this and its ESS large enough (or the budget is spent)")
            self.until_button = g.add_button("Run until converged")
        self._wire()

    def _show_settings_in_force(self) -> None:
        """The text fields and the "in force" line show the settings the chains run under."""
        st, names = self.ctrl.settings, self.ctrl.names
        for n in names:
            lo, hi = st.bounds[n]
            self.bound_inputs[n].value = f"{_num(lo)}, {_num(hi)}"
        self.sigma_input.value = _num(st.noise)
        k = len(names)
        if self.width_inputs:
            narrow, broad = _per_latent(st.narrow, k), _per_latent(st.broad, k)
            for j, n in enumerate(names):
                self.width_inputs[n].value = f"{_num(narrow[j])}, {_num(broad[j])}"
        else:
            self.narrow_input.value, self.broad_input.value = _num(st.narrow), _num(st.broad)
        self.every_input.value = str(st.broad_every)
        noise = self.ctrl.scenario.noise
        parts = [f"{n} [{_num(st.bounds[n][0])}, {_num(st.bounds[n][1])}] {self._specs[n].unit}" for n in names]
        widths = (f"narrow {_num(st.narrow)}, broad {_num(st.broad)}" if not self.width_inputs else
                  "widths " + ", ".join(f"{n} {_num(a)}/{_num(b)}" for n, a, b in
                                        zip(names, _per_latent(st.narrow, k), _per_latent(st.broad, k))))
        self.settings_in_force.content = (f"**In force:** priors {'; '.join(parts)}; {noise.name} "
                                          f"{_num(st.noise)} {noise.unit}; {widths}; broad every {st.broad_every}")

    def read_settings(self) -> dict:
        """What the Priors and settings fields say, checked by the rules the controller applies
        (the latents' limits, a positive noise, positive widths, a whole broad period); a
        ValueError naming every wrong field, and nothing applied, otherwise."""
        ctrl, names = self.ctrl, self.ctrl.names
        errors, bounds = [], {}
        for n in names:
            try:
                lo, hi = parse_numbers(self.bound_inputs[n].value, 2, f"{n} bounds (low, high)")
                bounds[n] = check_bounds(self._specs[n], lo, hi)
            except ValueError as e:
                errors.append(str(e))
        noise = None
        try:
            noise = check_noise(ctrl.scenario.noise, parse_numbers(self.sigma_input.value, 1,
                                                                   ctrl.scenario.noise.name)[0])
        except ValueError as e:
            errors.append(str(e))
        widths = None
        try:
            every = parse_numbers(self.every_input.value, 1, "broad every")[0]
            if self.width_inputs:
                pairs = [parse_numbers(self.width_inputs[n].value, 2, f"{n} widths (narrow, broad)") for n in names]
                widths = check_widths(tuple(p[0] for p in pairs), tuple(p[1] for p in pairs), every)
            else:
                widths = check_widths(parse_numbers(self.narrow_input.value, 1, "narrow width")[0],
                                      parse_numbers(self.broad_input.value, 1, "broad width")[0], every)
        except ValueError as e:
            errors.append(str(e))
        if errors:
            raise ValueError("; ".join(errors))
        return {"bounds": bounds, "noise": noise, "widths": widths}

    def apply_settings(self) -> str:
        """Apply every field exactly as typed, or nothing (the message says which field is wrong
        and why); returns the message shown under Apply."""
        ctrl = self.ctrl
        try:
            new = self.read_settings()
        except ValueError as e:
            msg = f"Not applied: {e}"
            self.settings_message.content = _message(msg, ok=False)
            return msg
        st = ctrl.settings
        changed = []
        outside = self._outside(new["bounds"])    # chains the new prior leaves out (set_bounds moves them in)
        for n, (lo, hi) in new["bounds"].items():
            if (lo, hi) != tuple(st.bounds[n]):
                ctrl.set_bounds(n, lo, hi)
                changed.append(f"{n} bounds")
        if new["noise"] != st.noise:
            ctrl.set_noise(new["noise"])
            changed.append(ctrl.scenario.noise.name)
        n, b, e = new["widths"]
        k = len(ctrl.names)
        if self.width_inputs:
            same = (_per_latent(n, k), _per_latent(b, k), e) == (_per_latent(st.narrow, k), _per_latent(st.broad, k),
                                                                 st.broad_every)
        else:
            same = (n, b, e) == (st.narrow, st.broad, st.broad_every)
        if not same:
            ctrl.set_widths(n, b, e)
            changed.append("proposal widths")
        msg = ("Applied: " + ", ".join(changed)) if changed else "Nothing changed"
        self._excluded = sorted(outside)
        if outside:
            ids = ctrl.chain_ids()
            where = "; ".join(f"{n} {self._fmt(n, x)} outside [{_num(new['bounds'][n][0])}, {_num(new['bounds'][n][1])}]"
                              for n, x in next(iter(outside.values())).items())
            msg += (f". {len(outside)} of {len(ids)} chains stood outside the new prior (e.g. {where}) and were moved "
                    "to its nearest edge: if the video favours values outside it, their log-likelihood falls far. "
                    "Restart them inside the new prior (fresh starts drawn from it) with the button below.")
        self.settings_message.content = _message(msg, ok=not outside)
        self.restart_inside.visible = bool(outside)
        self._show_settings_in_force()
        return msg

    def _outside(self, bounds: dict) -> dict[int, dict[str, float]]:
        """Per active chain whose position lies outside `bounds`: {latent: value} of the latents
        outside."""
        out = {}
        for c in self.ctrl.chain_ids():
            try:
                pos = self.ctrl.position(c)
            except ValueError:   # created after the round in flight
                continue
            bad = {n: x for n, x in pos.items() if not bounds[n][0] <= x <= bounds[n][1]}
            if bad:
                out[c] = bad
        return out

    def restart_inside_prior(self) -> str:
        """The chains the last prior edit left out start afresh: each latent drawn uniformly from
        the prior in force (integers on their grid), seeded by the chain and its sweep so a
        session replays it (each is a set_chain event)."""
        ctrl, bounds = self.ctrl, self.ctrl.settings.bounds
        done = []
        for c in self._excluded:
            if c not in ctrl.chain_ids():
                continue
            rng = np.random.default_rng([c, len(ctrl.samples(c)), 24])
            values = {}
            for j, n in enumerate(ctrl.names):
                lo, hi = bounds[n]
                x = float(rng.uniform(lo, hi))
                values[n] = float(min(max(round(x), np.ceil(lo)), np.floor(hi))) if j in self._integer else x
            ctrl.set_chain(c, values)
            done.append(c)
        self._excluded = []
        self.restart_inside.visible = False
        self.settings_message.content = _message(
            f"restarted {len(done)} chain{'s' * (len(done) != 1)} inside the new prior" if done else "no chain to restart",
            ok=True)
        return self.settings_message.content

    def _chain(self) -> int:
        return int(self.chain_dropdown.value)

    def _wire(self) -> None:
        ctrl = self.ctrl
        self.frame_slider.on_update(lambda _: self.set_frame(int(self.frame_slider.value)))
        if self.video_dropdown is not None:
            self.video_dropdown.on_update(lambda _: self.show_video(int(self.video_dropdown.value.split()[-1]) - 1))
        self.view_button.on_click(lambda ev: self.snap_camera(ev.client))
        self.free_button.on_click(lambda ev: self.free_view(ev.client))
        self.opacity_slider.on_update(lambda _: self._set_opacity(float(self.opacity_slider.value)))
        self.chain_dropdown.on_update(self._on_chain_changed)
        self.sample_slider.on_update(lambda ev: self._on_sample_moved(ev))
        self.map_button.on_click(lambda _: self._follow_and_jump())
        self.follow_map.on_update(lambda _: self._follow_and_jump() if self.follow_map.value else None)
        self.apply_button.on_click(lambda _: self.apply_settings())
        self.restart_inside.on_click(lambda _: self.restart_inside_prior())

        def steer(fn):
            """A steering call from a button: what it did, or why it could not (e.g. a value
            outside the prior), shown in the Steering panel and as a notification."""
            def call(_):
                try:
                    done = fn()
                except (ValueError, GalileoError) as e:
                    self.steer_message.content = _message(f"Not done: {e}", ok=False)
                    self._notify(str(e))
                except Exception as e:   # never a traceback the user cannot see
                    log.exception("steering failed")
                    self.steer_message.content = _message(f"Failed: {type(e).__name__}: {e}", ok=False)
                    self._notify(f"{type(e).__name__}: {e}")
                else:
                    self.steer_message.content = _message(done, ok=True) if done else ""
                self._dirty.set()
            return call

        def each(action, what):
            def run():
                c = self._chain()
                action(c)
                return f"{what} chain {c}"
            return run

        self.pause_all.on_click(steer(lambda: ctrl.pause() or "paused every chain"))
        self.resume_all.on_click(steer(lambda: ctrl.resume() or "resumed every chain"))
        self.pause_one.on_click(steer(each(ctrl.pause, "paused")))
        self.resume_one.on_click(steer(each(ctrl.resume, "resumed")))
        self.add_button.on_click(steer(lambda: f"added chain {ctrl.add_chains(1)[0]}"))
        self.remove_button.on_click(steer(self._ask_remove))
        self.remove_confirm.on_click(steer(self._confirm_remove))
        self.remove_cancel.on_click(steer(self._cancel_remove))
        self.reset_map.on_click(steer(each(lambda c: ctrl.reset_chain(c, "map"), "moved to the MAP:")))
        self.reset_sel.on_click(steer(each(lambda c: ctrl.reset_chain(
            c, "sample", (self.selection.chain, self.selection.index)), "moved to the selected sample:")))

        def set_latents():
            values = {}
            errors = []
            for n, h in self.set_inputs.items():
                try:
                    values[n] = parse_numbers(h.value, 1, n)[0]
                except ValueError as e:
                    errors.append(str(e))
            if errors:
                raise ValueError("; ".join(errors))
            c = self._chain()
            ctrl.set_chain(c, values)
            return f"set chain {c}'s latents"
        self.set_button.on_click(steer(set_latents))

        def run_until():
            r = parse_numbers(self.until_input.value, 1, "until R-hat")[0]
            if not r > 1.0:
                raise ValueError(f"until R-hat must be above 1 (e.g. 1.01), got {_num(r)}")
            st = ctrl.status()
            u = st.get("until") or {}
            ctrl.run_until(r, u.get("min_ess", st["convergence"]["min_ess"]), u.get("max_sweeps"))
            return f"running until R-hat <= {_num(r)}"
        self.until_button.on_click(steer(run_until))

    # -- removing a chain: asked, confirmed, the selection kept on a chain that remains ----------
    def _ask_remove(self) -> str:
        c = self._chain()
        if c not in self.ctrl.chain_ids():
            raise ValueError(f"chain {c} was removed already")
        self._remove_pending = c
        self.remove_confirm.label = f"Confirm: remove chain {c}"
        self.remove_confirm.visible = self.remove_cancel.visible = True
        return f"remove chain {c} for good? Its samples stay (and count for the MAP). Confirm or Cancel."

    def _cancel_remove(self) -> str:
        self._remove_pending = None
        self.remove_confirm.visible = self.remove_cancel.visible = False
        return "nothing removed"

    def _confirm_remove(self) -> str:
        c, self._remove_pending = self._remove_pending, None
        self.remove_confirm.visible = self.remove_cancel.visible = False
        if c is None:
            return "nothing removed"
        self.ctrl.remove_chain(c)
        if self._chain() == c:     # the selection moves to a neighbour, never silently to chain 0
            ids = [i for i in self.ctrl.chain_ids() if i != c]
            if ids:
                nxt = min(ids, key=lambda i: (abs(i - c), -i))
                self._set_chain_options(ids, nxt)
        return f"removed chain {c} (its samples stay)"

    def _set_chain_options(self, ids: list[int], value: int | None = None) -> None:
        """New chain options, keeping the selected chain if it remains, else its nearest neighbour."""
        opts = [str(c) for c in ids] or ["0"]
        current = self.chain_dropdown.value
        if value is None:
            value = int(current) if current in opts else (
                min(ids, key=lambda i: (abs(i - int(current)), -i)) if ids else 0)
        with self.server.atomic():
            self.chain_dropdown.options = opts
            if self.chain_dropdown.value != str(value):
                self.chain_dropdown.value = str(value)

    def _notify(self, text: str) -> None:
        for client in self.server.get_clients().values():
            client.add_notification("Galileo", text, color="red", auto_close_seconds=5.0)

    # -- actions --------------------------------------------------------------------------------
    def _fmt(self, name: str, value: float) -> str:
        return f"{value:.{self._decimals.get(name, 3)}f}"

    def _start_values(self) -> dict[str, float]:
        """Where the first chain stands now (the priors' middle without one): the "set chain's
        latents" inputs start there, inside the bounds."""
        ids = self.ctrl.chain_ids()
        if ids:
            try:
                return self.ctrl.position(ids[0])
            except ValueError:   # created after the round in flight
                pass
        mid = self.ctrl.settings.bounds_array(self.ctrl.names).mean(axis=1)
        return {n: float(v) for n, v in zip(self.ctrl.names, mid)}

    def _first_selection(self) -> tuple[int, int]:
        m = self.ctrl.map()
        if m is not None:
            return m[0], m[1]
        ids = self.ctrl.chain_ids()
        return (ids[0] if ids else 0), 0

    def select_sample(self, chain: int, index: int, force: bool = False) -> float:
        """Re-simulate sample `index` of `chain` and redraw; returns the server-side seconds.
        The sample shown already is not simulated again unless `force` (samples are only ever
        appended, so a (chain, index) always means the same values; moving the slider from code
        calls this through its callback as well)."""
        t0 = time.perf_counter()
        with self._lock:
            samples = self.ctrl.samples(chain)
            if len(samples) == 0:   # nothing drawn yet: where the chain starts (or the priors' middle)
                values = None
                index = 0
                try:
                    position = np.array(list(self.ctrl.position(chain).values()))
                except ValueError:
                    position = self.ctrl.settings.bounds_array(self.ctrl.names).mean(axis=1)
            else:
                index = int(np.clip(index, 0, len(samples) - 1))
                if not (force or self.selection_empty) and self.selection == Selection(chain, index):
                    return 0.0
                position = samples[index]
                values = {n: float(v) for n, v in zip(self.ctrl.names, position)}
            self.selection_empty = len(samples) == 0
            self.selection = Selection(chain, index)
            self.traj = self._motion(position)
            self.resimulations += 1
            for fn in list(self._selection_listeners):
                try:
                    fn(self.traj, chain, None if values is None else index)
                except Exception:    # a logger's failure never stops the viewer
                    log.exception("selection listener failed")
            self._pose_objects(self.frame)
            self._update_sim_lines()
            ll = self.ctrl.logliks(chain)[index] if len(samples) else float("nan")
            noise = self.ctrl.sample_noise(chain)[index] if len(samples) else None
            spec = self.scenario.noise
            under = ("" if noise is None or noise == self.ctrl.settings.noise
                     else f" (under {spec.name} = {noise:g})")
            start = self.ctrl.starts().get(chain)
            started = ("" if start is None else "; started at " + ", ".join(
                f"{k} = {self._fmt(k, v)}" for k, v in zip(self.ctrl.names, start)))
            removed = "" if chain in self.ctrl.chain_ids() else " (a removed chain: not in the Chain list)"
            if chain != self._set_inputs_chain and chain in self.ctrl.chain_ids():
                self._prefill_set_inputs(chain)
            self.sample_text.content = (f"chain {chain}{removed}, sample {index}: " + ", ".join(
                f"{k} = {self._fmt(k, v)}" for k, v in (values or {}).items()) + f"; log-lik {ll:.1f}{under}" + started)
            self.last_resim_s = time.perf_counter() - t0
        return self.last_resim_s

    def _prefill_set_inputs(self, chain: int) -> None:
        """"Set chain's latents" starts from where the selected chain stands now."""
        self._set_inputs_chain = chain
        try:
            position = self.ctrl.position(chain)
        except ValueError:   # created after the round in flight
            return
        for n, h in getattr(self, "set_inputs", {}).items():
            h.value = f"{position[n]:.6g}"

    def add_selection_listener(self, fn) -> None:
        """Call fn(trajectory, chain, index) whenever the selected sample is simulated (index None:
        a chain with no sample yet, shown where it starts); e.g. rerun's sim/selected."""
        self._selection_listeners.append(fn)

    def jump_to_map(self) -> None:
        # the dropdown, the slider and the sample text change together: one batch of messages
        # (a busy page drew the new chain beside the old sample's text between two batches)
        with self._lock, self.server.atomic():
            m = self.ctrl.map()
            if m is None:
                return
            chain, index = m[0], m[1]
            if str(chain) in self.chain_dropdown.options:
                self.chain_dropdown.value = str(chain)
            self.sample_slider.max = max(len(self.ctrl.samples(chain)) - 1, 1)
            self.sample_slider.value = index
            self.select_sample(chain, index)

    def _on_chain_changed(self, ev=None) -> None:
        if ev is not None and ev.client is not None:    # the user picked a chain: stop following the MAP
            self.follow_map.value = False
        chain = self._chain()
        n = len(self.ctrl.samples(chain))
        self.sample_slider.max = max(n - 1, 1)
        self.sample_slider.value = max(n - 1, 0)
        self.select_sample(chain, max(n - 1, 0))

    def _on_sample_moved(self, ev) -> None:
        if ev.client is not None:      # the user scrubs: stop following the MAP
            self.follow_map.value = False
        self.select_sample(self._chain(), int(self.sample_slider.value))

    def _follow_and_jump(self) -> None:
        if not self.follow_map.value:
            self.follow_map.value = True   # its callback jumps
            return
        self.jump_to_map()

    def _pose_objects(self, frame: int) -> None:
        """The objects' meshes and the connectors between them where the selected motion has
        them at `frame`."""
        traj = self.traj
        f = int(np.clip(frame, 0, traj.n_frames - 1))
        for i, h in enumerate(self.object_handles):
            h.position = traj.position_m[i, f]
            h.wxyz = _wxyz_from_xyzw(traj.orientation_xyzw[i, f])
        if self.connectors:
            pose = frame_pose(traj, f)
            for c, h in zip(self.connectors, self.connector_handles):
                h.points = _segments(connector_points(c, *pose))

    def set_frame(self, frame: int) -> None:
        with self._lock:
            self.frame = int(np.clip(frame, 0, self.n_frames - 1))
            self._pose_objects(self.frame)
            img = self.video[self.frame]
            for f in list(self._frustums.values()):
                f.image = img
            clients = self.server.get_clients()
            for cid in list(self._camera_clients):
                if cid in clients:
                    self._send_camera_view(clients[cid], pose=False)

    @property
    def camera_view(self) -> bool:
        """Whether some browser is in the camera view."""
        return bool(self._camera_clients)

    def _send_camera_view(self, client, pose: bool = True) -> None:
        """This browser's letterboxed background (the current frame) and, with `pose`, its camera
        on the video camera with the fov the letterbox needs."""
        cam = self.camera
        w, h = client.camera.image_width, client.camera.image_height
        aspect = w / h if w and h else cam.width_px / cam.height_px   # until the browser says its size
        img, fov = letterbox(self.video[self.frame], cam, aspect)
        if pose:
            wxyz, pos, _, _ = camera_pose(cam)
            fwd = np.array(trimesh.transformations.quaternion_matrix(wxyz))[:3, 2]
            with client.atomic():
                client.camera.fov = fov
                client.camera.wxyz = wxyz
                client.camera.position = pos
                client.camera.look_at = pos + 1.2 * fwd
        client.scene.set_background_image(img, format="jpeg", jpeg_quality=85)
        self._camera_clients[client.client_id]["aspect"] = aspect

    def snap_camera(self, client=None) -> None:
        """The camera view, in this browser (every browser without one): the browser's camera on
        the video camera, the frame behind the scene, letterboxed to the window's shape so the
        two agree pixel for pixel in any window; its free view is kept for Free view."""
        if self.camera is None:
            self._notify("this scene has no video camera")
            return
        clients = [client] if client is not None else list(self.server.get_clients().values())
        with self._lock:
            for c in clients:
                if c.client_id not in self._camera_clients:
                    cam = c.camera
                    self._camera_clients[c.client_id] = {
                        "free": (cam.fov, np.array(cam.wxyz), np.array(cam.position), np.array(cam.look_at)),
                        "aspect": 0.0}
                fr = self._frustums.pop(c.client_id, None)
                if fr is not None:
                    fr.remove()
                self._send_camera_view(c)

    def free_view(self, client=None) -> None:
        """Back to the view this browser had before the camera view (every browser without one)."""
        clients = [client] if client is not None else list(self.server.get_clients().values())
        with self._lock:
            for c in clients:
                state = self._camera_clients.pop(c.client_id, None)
                if state is None:
                    continue
                c.scene.set_background_image(None)
                fov, wxyz, pos, look_at = state["free"]
                with c.atomic():
                    c.camera.fov = fov
                    c.camera.wxyz = wxyz
                    c.camera.position = pos
                    c.camera.look_at = look_at
                if self.camera is not None:
                    self._add_frustum(c)

    # -- live updates --------------------------------------------------------------------------
    def _on_controller(self, kind: str, payload: dict) -> None:
        self._dirty.set()

    def _refresh_loop(self) -> None:
        while not self._stop.is_set():
            if self._dirty.wait(0.5):
                self._dirty.clear()
                try:
                    self.refresh()
                except Exception:  # a closing server must not kill the thread with a traceback storm
                    if self._stop.is_set():
                        return
                    log.exception("viewer refresh failed")
            self._stop.wait(0.5)  # at most 2 refreshes a second

    def refresh(self) -> None:
        ctrl = self.ctrl
        ids = ctrl.chain_ids()
        if tuple(str(c) for c in ids) != tuple(self.chain_dropdown.options):
            self._set_chain_options(ids)     # the selected chain kept, or its nearest neighbour
        chain = self._chain()
        n = len(ctrl.samples(chain))
        if n > 1 and self.sample_slider.max != n - 1:
            self.sample_slider.max = n - 1
        m = ctrl.map()
        if self.follow_map.value and m is not None:
            if self.selection_empty or (self.selection.chain, self.selection.index) != (m[0], m[1]):
                self.jump_to_map()       # the best sample so far, as it changes
        elif n and self.selection_empty:  # the first samples arrived: show the latest
            self.sample_slider.value = n - 1
            self.select_sample(chain, n - 1)
        st = ctrl.status()
        conv = st["convergence"]
        target = st.get("target_sweeps") or self.target_sweeps
        until = st.get("until")
        total = until["max_sweeps"] if until else target     # run until converged: towards the budget
        # (a background thread stopped on an error runs nothing, whatever the chains' state)
        running = 0 if st.get("error") else sum(1 for c in st["chains"].values() if c.get("running"))
        done = sum(min(c["sweeps"], total) for c in st["chains"].values())
        frac = done / max(total * max(len(ids), 1), 1)
        reached = bool(st["chains"]) and all(c["sweeps"] >= target for c in st["chains"].values())
        if conv["converged"]:
            value, color = (100.0 if running == 0 else 100.0 * frac), "green"
        else:   # never full, never "done", while not converged
            value, color = min(100.0 * frac, 99.0), ("red" if reached and running == 0 else None)
        if self.progress.value != value:
            self.progress.value = value
        if self.progress.color != color:
            self.progress.color = color
        if self.progress.animated != (running > 0):
            self.progress.animated = running > 0
        acc = ", ".join(f"{k} {v:.2f}" for k, v in (st.get("acceptance") or {}).items() if v is not None)
        mv = st.get("moves") or {}
        macc = ", ".join(f"{k} {v:.2f}" for k, v in (mv.get("acceptance") or {}).items() if v is not None)
        m = st["map"]
        map_txt = (st.get("map_note") or "") if m is None else (
            f"MAP (chain {m['chain']}, sample {m['index']}): " +
            ", ".join(f"{k} = {self._fmt(k, v)}" for k, v in m["values"].items()) + f", log-lik {m['loglik']:.1f}")
        if conv["converged"]:
            state = "converged" + (": the chains stay paused" if until and running == 0 else "")
        elif reached and running == 0:
            state = ("not converged, the budget is spent" if until and target >= until["max_sweeps"]
                     else "sweep target reached, NOT converged: Resume or Run until converged to go on")
        elif until and running == 0:
            state = (f"paused, to run until converged (R-hat <= {until['until_rhat']:g}, ESS >= {until['min_ess']:g}; "
                     f"budget {until['max_sweeps']}): Resume all to go on")
        elif until:
            state = (f"running until converged (R-hat <= {until['until_rhat']:g}, ESS >= {until['min_ess']:g}; "
                     f"this block to sweep {target}, budget {until['max_sweeps']})")
        elif running == 0:   # e.g. one chain resumed past the others' target, then held
            behind = sum(1 for c in st["chains"].values() if c["sweeps"] < target)
            state = (f"paused; {behind} of {len(ids)} chains below the sweep target {target}: "
                     "Resume all (or Resume chain) runs them on to it")
        else:
            state = f"not converged yet (sweep target {target})"
        moves_txt = f"moves: {mv.get('set', '?')}"
        if mv.get("warmup"):
            moves_txt += (f", widths adapting (warm-up: sweeps 1-{mv['warmup']})" if mv.get("adapting")
                          else f", widths adapted in warm-up (sweeps 1-{mv['warmup']}, dropped)")
        if macc:
            moves_txt += f"; joint moves' acceptance: {macc}"
        # a worker that died (the pool restarted, or every chain paused), a thread stopped on an error
        death = (st.get("workers") or {}).get("last_death")
        alert = "".join(f"**{t}**  \n" for t in ((st.get("session") or {}).get("note"), death and death["text"],
                                                  st.get("error") and
                                                  f"inference stopped: {st['error']} (Resume all to retry)") if t)
        self.status_text.content = (f"{alert}{running} running / {len(ids)} chains, {st.get('sweeps', 0)} sweeps: {state}  \n"
                                    f"{moves_txt}  \nacceptance: {acc or '-'}  \n"
                                    f"convergence ({conv.get('kept_draws', 0)} kept draws): {conv['summary']}  \n"
                                    f"{map_txt}")
        longest = max((c["sweeps"] for c in st["chains"].values()), default=0)
        warm = mv.get("warmup") or 0
        warming = (f"sweep {longest} of {warm}" if longest <= warm else
                   f"sweep {longest}: too few kept draws yet" if conv.get("kept_draws", 0) < 2 * MIN_KEPT_DRAWS
                   else None)
        box = convergence_html(conv, st.get("derived") or {}, warming=warming)
        if self.convergence_box.content != box:
            self.convergence_box.content = box
        self._update_plots(ids)

    def _update_plots(self, ids: list[int]) -> None:
        ctrl = self.ctrl
        traces = [ctrl.logliks(c) for c in ids]
        if max((len(t) for t in traces), default=0) == 0:
            return
        edits = [edit_sweep(e) for e in ctrl.events if e["kind"] not in NOT_EDITS]
        spec = trace_plot_spec(traces, [f"chain {c}" for c in ids],
                               [CHAIN_COLORS[c % len(CHAIN_COLORS)] for c in ids], edits)
        _assign(self.trace_plot, spec, self._sent.setdefault("trace", {}))
        samples = [ctrl.samples(c) for c in ids]
        w = ctrl.warmup   # the kept draws: after max(warm-up, half) of each chain (none yet in warm-up)
        kept = np.concatenate([s[burn_in(len(s), w):] for s in samples] + [np.empty((0, len(ctrl.names)))])
        starts = np.array(list(ctrl.starts().values()), float).reshape(-1, len(ctrl.names))
        for j, n in enumerate(ctrl.names):
            spec = histogram_spec(kept[:, j], starts[:, j], ctrl.settings.bounds[n], self._specs[n],
                                  integer=j in self._integer, recognized=self._recognized.get(n))
            _assign(self.hist_plots[n], spec, self._sent.setdefault(n, {}))

    def _play_loop(self) -> None:
        while not self._stop.is_set():
            if self.play.value:
                f = (self.frame + 1) % self.n_frames
                self.frame_slider.value = f  # its callback poses the objects
                self._stop.wait(1.0 / self.fps)
            else:
                self._stop.wait(0.1)

    def close(self) -> None:
        self._stop.set()
        self._dirty.set()
        for t in self._threads:
            t.join(timeout=2)
        self.server.stop()
