"""The browser viewer (viser): the video over the simulated scene, samples, plots, steering.

It only draws and forwards the user's edits to the controller (ui/controller.py); the
one computation it does itself is re-simulating the selected sample (Bullet, in this
process) with the scenario's likelihood (`Likelihood.motion`), so the 3-D scene shows the
very motion that sample was scored on (same phases, same rest rule).

* 3-D: what the scenario draws (`Scenario.drawing`: for the ramp, the ground grid, the ramp
  and the objects with their tracked shapes) posed from the selected sample's motion at
  the current frame; the observed tracks (orange) and the
  simulated trajectory (blue) as polylines; the video camera as a frustum showing the
  current frame.
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
from galileo.results import burn_in

log = logging.getLogger(__name__)

OBJECT_COLORS = [(220, 90, 50), (70, 130, 220)]
NOT_EDITS = ("init", "pause", "resume", "run_until", "until_check")   # change no chain's target or state
CONVERGED_COLOR = "#2b8a3e"     # a latent whose R-hat and ESS hold
RHAT_COLOR = "#c92a2a"          # R-hat above the target, or not computable yet
ESS_COLOR = "#e8590c"           # R-hat holds, too few effective draws
SMALL_SCENE_M = 0.5    # scenes smaller than this get an initial view close enough to see them
CHAIN_COLORS = ["#e6194b", "#3cb44b", "#4363d8", "#f58231", "#911eb4", "#42d4f4", "#f032e6", "#bfef45",
                "#469990", "#9a6324", "#800000", "#808000", "#000075", "#a9a9a9", "#e6beff", "#fabebe"]


def _wxyz_from_matrix(r: np.ndarray) -> np.ndarray:
    """Quaternion (w, x, y, z) of a rotation matrix."""
    q = trimesh.transformations.quaternion_from_matrix(np.block([[r, np.zeros((3, 1))], [np.zeros((1, 3)), 1]]))
    return np.asarray(q)  # trimesh returns (w, x, y, z)


def _wxyz_from_xyzw(q) -> np.ndarray:
    return np.array([q[3], q[0], q[1], q[2]])


def init_markdown(info: dict, names) -> str:
    """How the chains started, for the Chains panel: the prior, or what the recognition model
    read (per object: mass and friction with 90% intervals)."""
    if info.get("starts") != "recognition":
        return "Chains started from the prior."
    parts = [f"Chains started from the recognition model ({info.get('kind') or 'lenet'}, "
             f"{info.get('labels') or '?'} labels):"]
    for role, r in (info.get("readings") or {}).items():
        if isinstance(r, dict) and "mass_kg" in r:
            fr = (f", friction {r['friction']:.3f} ({r['friction_90'][0]:.3f}-{r['friction_90'][1]:.3f})"
                  if "friction" in r else "")
            parts.append(f"{role}: mass {r['mass_kg']:.3g} kg (90% {r['mass_kg_90'][0]:.3g}-{r['mass_kg_90'][1]:.3g})"
                         + fr)
    return "  \n".join(parts)


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


def convergence_html(conv: dict, derived: dict, fmt=lambda name, v: f"{v:.3g}") -> str:
    """The Chains panel's verdict: an overall line, then per latent one coloured line (green:
    converged; red: R-hat above the target or not computable; orange: R-hat holds, ESS too
    low) with R-hat, ESS (the lower of bulk and tail) and "converged" or "not converged: why";
    then the posterior median and 90% interval of each derived quantity (as
    `InferenceResult.derived_posterior` gives them; a log_<x> beside its <x> is left out)."""
    e = html.escape
    per = conv.get("per_latent") or {}
    why = {}
    for line in conv.get("why_not") or []:
        name, _, reason = line.partition(": ")
        why[name] = reason
    n_ok = sum(1 for ok in per.values() if ok)
    criteria = f"R-hat &le; {conv.get('rhat_target', 1.01):g}, ESS &ge; {conv.get('min_ess', 400):g}"
    if conv.get("converged"):
        head = (f'<div class="galileo-verdict" style="font-weight:600;color:{CONVERGED_COLOR}">'
                f"Converged: all {len(per)} latents ({criteria})</div>")
    else:
        head = (f'<div class="galileo-verdict" style="font-weight:600;color:{RHAT_COLOR}">'
                f"Not converged: {n_ok} of {len(per)} latents ({criteria})</div>")
    rows = []
    for name, ok in per.items():
        r = (conv.get("r_hat") or {}).get(name)
        ess = [x for x in ((conv.get("ess_bulk") or {}).get(name), (conv.get("ess_tail") or {}).get(name))
               if x is not None]
        if ok:
            color, state = CONVERGED_COLOR, "converged"
        else:
            color = ESS_COLOR if (r is not None and r <= conv.get("rhat_target", 1.01)) else RHAT_COLOR
            state = "not converged: " + why.get(name, "?")
        rows.append(f'<div class="galileo-latent" data-latent="{e(name)}" data-converged="{str(bool(ok)).lower()}" '
                    f'style="color:{color}"><b>{e(name)}</b> R-hat {"-" if r is None else f"{r:.3f}"}, '
                    f'ESS {"-" if not ess else f"{min(ess):.0f}"}: {e(state)}</div>')
    shown = [k for k in derived if not (k.startswith("log_") and k[4:] in derived)]
    der = [f'<div class="galileo-derived"><b>{e(k)}</b>: median {fmt(k, derived[k]["q50"])} '
           f'(90% {fmt(k, derived[k]["q05"])} &ndash; {fmt(k, derived[k]["q95"])})</div>' for k in shown]
    if der:
        der.insert(0, '<div style="margin-top:4px">Posterior (kept draws):</div>')
    return f'<div class="galileo-convergence" style="font-size:13px;line-height:1.45;padding:0 0.75em 0.5em 0.75em">{head}{"".join(rows)}{"".join(der)}</div>'


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


def _step(width: float) -> float:
    """An input step that shows a proposal width to its first digit (0.0005 -> 0.0001)."""
    return float(10.0 ** np.floor(np.log10(width))) if width > 0 else 0.001


@dataclass
class Selection:
    chain: int
    index: int


class Viewer:
    def __init__(self, controller, scene, tracks: Tracks, video_rgb: np.ndarray, *,
                 host: str = "127.0.0.1", port: int = 8080, target_sweeps: int = 75):
        self.ctrl = controller
        self.scene = scene
        self.tracks = tracks
        self.video = video_rgb
        self.n_frames = min(len(video_rgb), tracks.n_frames)
        self.fps = tracks.fps
        self.target_sweeps = target_sweeps
        self.scenario = registry.of(scene)
        self.model = self.scenario.likelihood(scene, tracks, controller.settings.noise)   # draws its `motion`
        self.traj: Trajectory | None = None
        self.resimulations = 0
        self.last_resim_s = 0.0
        self.frame = 0
        self.selection = Selection(0, 0)
        self.selection_empty = True   # nothing simulated yet
        self._lock = threading.RLock()
        self._dirty = threading.Event()
        self._stop = threading.Event()
        self.camera_view = False
        st = controller.settings
        narrow = _per_latent(st.narrow, len(controller.names))
        # decimals a latent is shown with: integers none, others down to their narrow width's first digit (3 at least)
        self._integer = {j for j, lat in enumerate(controller.latents) if lat.integer}
        self._decimals = {n: 0 if j in self._integer else max(3, int(np.ceil(-np.log10(narrow[j]))))
                          for j, n in enumerate(controller.names)}
        self._y_axis_px = 0
        self._legend = True
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        if port and self.server.get_port() != port:
            # viser moves on to the next free port without a word: a user's bookmark, firewall rule
            # or tunnel would then reach another program, or nothing
            self.server.stop()
            from galileo.errors import GalileoError

            raise GalileoError(f"port {port} on {host} is taken (another app running?); choose another with --port")
        self.url = f"http://{host}:{self.server.get_port()}"
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

    # -- 3-D scene -------------------------------------------------------------------------
    def _build_scene(self) -> None:
        s, sc = self.server.scene, self.scene
        s.set_up_direction("+z")
        drawing = self.scenario.drawing(sc)
        if drawing.ground_z_m is not None:
            s.add_grid("/ground", width=3.0, height=2.0, plane="xy", position=(0.0, 0.0, drawing.ground_z_m))
        for m in drawing.static:
            s.add_mesh_simple(f"/{m.name}", m.vertices, m.faces, color=m.color, opacity=m.opacity)
        self.object_handles = [s.add_mesh_simple(f"/objects/{m.name}", m.vertices, m.faces, color=m.color,
                                                 opacity=m.opacity) for m in drawing.objects]
        for o in self.tracks.objects:
            s.add_line_segments(f"/tracks/observed/{o.name}", _segments(o.position_m), (255, 140, 0),
                                thickness=3, thickness_units="screen")
        self.camera = self.scenario.camera(sc)   # None: no video camera, so no frustum and no camera view
        self.frustum = None
        if self.camera is not None:
            wxyz, pos, fov, aspect = camera_pose(self.camera)
            self.frustum = s.add_camera_frustum("/video_camera", fov=fov, aspect=aspect, scale=0.15,
                                                image=self.video[0], format="jpeg", jpeg_quality=80,
                                                wxyz=wxyz, position=pos)
        self.sim_lines = []
        self._frame_small_scene(drawing)
        self.server.on_client_connect(self._on_connect)

    def _frame_small_scene(self, drawing) -> None:
        """Viser's default view (from (3, 3, 3) m, 75 degrees wide) suits scenes a metre or so
        across; a smaller one (the splash tank, 0.4 m) would be a speck in it, so new browsers
        start on the video camera's side of the scene, nearer than the camera (its frustum
        behind), turned 40 degrees and raised (a view the camera view does not give), looking
        at the scene's centre."""
        pts = [m.vertices for m in drawing.static] + [o.position_m[np.isfinite(o.position_m).all(axis=1)]
                                                      for o in self.tracks.objects]
        pts = [p for p in pts if len(p)]
        if not pts:
            return
        pts = np.concatenate(pts)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        size = float(np.max(hi - lo))
        if not 0 < size < SMALL_SCENE_M:
            return
        centre = (lo + hi) / 2
        back = (np.array([0.8, -1.4, 0.0]) * size if self.camera is None
                else 0.6 * (camera_pose(self.camera)[1] - centre))
        a = np.deg2rad(40.0)
        rot = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
        self.server.initial_camera.fov = np.deg2rad(60.0)
        self.server.initial_camera.look_at = centre
        self.server.initial_camera.position = centre + rot @ back + np.array([0.0, 0.0, 0.9 * size])

    def _on_connect(self, client) -> None:
        """A browser that joins while the camera view is on (the background is the scene's, for
        every browser) gets the camera view too, not the video behind a free view."""
        if self.camera_view:
            self.snap_camera(client)

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
            self.frame_slider = g.add_slider("Frame", 0, self.n_frames - 1, 1, 0)
            self.play = g.add_checkbox("Play", False)
            self.view_button = g.add_button("Camera view")
            self.free_button = g.add_button("Free view")
        with g.add_folder("Samples"):
            self.chain_dropdown = g.add_dropdown("Chain", [str(c) for c in ctrl.chain_ids()] or ["0"])
            self.sample_slider = g.add_slider("Sample", 0, 1, 1, 0)
            self.map_button = g.add_button("Jump to MAP")
            self.sample_text = g.add_markdown("")
        with g.add_folder("Chains"):
            self.progress = g.add_progress_bar(0.0, animated=True)
            self.status_text = g.add_markdown("")
            self.convergence_box = g.add_html("")
            self.trace_plot = g.add_uplot((np.zeros(1), np.zeros(1)), (uplot.Series(label="sweep"),
                                                                       uplot.Series(label="chain 0")),
                                          title="log-likelihood per chain", aspect=1.6,
                                          scales={"x": uplot.Scale(time=False)})
            self.init_text = g.add_markdown(init_markdown(ctrl.init_info, ctrl.names))
            self._recognized = recognition_curves(ctrl.init_info, ctrl.names)
            self.hist_plots = {}
            for n in ctrl.names:
                series = [uplot.Series(label=n), uplot.Series(label="count", stroke="#444", fill="#4363d855"),
                          uplot.Series(label="chain starts (x 10)", stroke="#e6194b", width=2)]
                if n in self._recognized:
                    series.append(uplot.Series(label="recognition (scaled)", stroke="#f58231", width=2))
                zeros = (np.zeros(1),) * len(series)
                self.hist_plots[n] = g.add_uplot(zeros, tuple(series), title=f"posterior {n}", aspect=2.5,
                                                 scales={"x": uplot.Scale(time=False)})
        specs = {lat.name: lat for lat in ctrl.latents}
        with g.add_folder("Priors and settings", expand_by_default=False):
            st = ctrl.settings
            self.bound_inputs = {}
            for n in ctrl.names:
                lo, hi = st.bounds[n]
                lat = specs[n]
                self.bound_inputs[n] = g.add_vector2(f"{n} bounds", (lo, hi), step=1 if lat.integer else 0.001,
                                                     hint=f"uniform prior (low, high) in {lat.unit}: {lat.doc}")
            noise = ctrl.scenario.noise
            self.sigma_input = g.add_number(f"{noise.name} ({noise.unit})", st.noise, min=1e-4, step=0.001,
                                            hint=noise.doc or None)
            if isinstance(st.narrow, tuple) or isinstance(st.broad, tuple):
                # one (narrow, broad) pair per latent, in its own unit
                self.narrow_input = self.broad_input = None
                narrow, broad = _per_latent(st.narrow, len(ctrl.names)), _per_latent(st.broad, len(ctrl.names))
                self.width_inputs = {
                    n: g.add_vector2(f"{n} widths", (narrow[j], broad[j]), min=(1e-6, 1e-6),
                                     step=_step(min(narrow[j], broad[j])),
                                     hint=f"proposal half-widths (narrow, broad) in {specs[n].unit}")
                    for j, n in enumerate(ctrl.names)}
            else:
                self.width_inputs = {}
                self.narrow_input = g.add_number("narrow width", st.narrow, min=1e-4, step=0.001)
                self.broad_input = g.add_number("broad width", st.broad, min=1e-4, step=0.01)
            self.every_input = g.add_number("broad every", st.broad_every, min=0, step=1)
            self.apply_button = g.add_button("Apply")
        with g.add_folder("Steering", expand_by_default=False):
            self.pause_all = g.add_button("Pause all")
            self.resume_all = g.add_button("Resume all")
            self.pause_one = g.add_button("Pause chain")
            self.resume_one = g.add_button("Resume chain")
            self.add_button = g.add_button("Add chain")
            self.remove_button = g.add_button("Remove chain")
            self.reset_map = g.add_button("Reset chain to MAP")
            self.reset_sel = g.add_button("Reset chain to selected sample")
            start = self._start_values()
            self.set_inputs = {n: g.add_number(n, start[n], step=1 if specs[n].integer else 0.001,
                                               hint=f"{specs[n].unit}: {specs[n].doc}") for n in ctrl.names}
            self.set_button = g.add_button("Set chain's latents")
            until = ctrl.status().get("until") or {}
            self.until_input = g.add_number("until R-hat", until.get("until_rhat", 1.01), min=1.0001, step=0.001,
                                            hint="run on past the sweep target until every latent's R-hat is at "
                                                 "most this and its ESS large enough (or the budget is spent)")
            self.until_button = g.add_button("Run until converged")
        self._wire()

    def _chain(self) -> int:
        return int(self.chain_dropdown.value)

    def _wire(self) -> None:
        ctrl = self.ctrl
        self.frame_slider.on_update(lambda _: self.set_frame(int(self.frame_slider.value)))
        self.view_button.on_click(lambda ev: self.snap_camera(ev.client))
        self.free_button.on_click(lambda ev: self.free_view())
        self.chain_dropdown.on_update(lambda _: self._on_chain_changed())
        self.sample_slider.on_update(lambda _: self.select_sample(self._chain(), int(self.sample_slider.value)))
        self.map_button.on_click(lambda _: self.jump_to_map())

        def apply(_):
            try:
                for n, h in self.bound_inputs.items():
                    lo, hi = (float(v) for v in h.value)
                    if (lo, hi) != tuple(ctrl.settings.bounds[n]):
                        ctrl.set_bounds(n, lo, hi)
                if float(self.sigma_input.value) != ctrl.settings.noise:
                    ctrl.set_noise(float(self.sigma_input.value))
                st = ctrl.settings
                if self.width_inputs:
                    pairs = [tuple(float(v) for v in h.value) for h in self.width_inputs.values()]
                    widths = (tuple(p[0] for p in pairs), tuple(p[1] for p in pairs), int(self.every_input.value))
                    k = len(ctrl.names)
                    current = (_per_latent(st.narrow, k), _per_latent(st.broad, k), st.broad_every)
                else:
                    widths = (float(self.narrow_input.value), float(self.broad_input.value),
                              int(self.every_input.value))
                    current = (st.narrow, st.broad, st.broad_every)
                if widths != current:
                    ctrl.set_widths(*widths)
            except ValueError as e:
                self._notify(str(e))

        self.apply_button.on_click(apply)

        def steer(fn):
            """A steering call from a button: its ValueError (e.g. a value outside the prior)
            shown to the user, not lost in the server's log."""
            def call(_):
                try:
                    fn()
                except ValueError as e:
                    self._notify(str(e))
            return call

        self.pause_all.on_click(steer(lambda: ctrl.pause()))
        self.resume_all.on_click(steer(lambda: ctrl.resume()))
        self.pause_one.on_click(steer(lambda: ctrl.pause(self._chain())))
        self.resume_one.on_click(steer(lambda: ctrl.resume(self._chain())))
        self.add_button.on_click(steer(lambda: ctrl.add_chains(1)))
        self.remove_button.on_click(steer(lambda: ctrl.remove_chain(self._chain())))
        self.reset_map.on_click(steer(lambda: ctrl.reset_chain(self._chain(), "map")))
        self.reset_sel.on_click(steer(lambda: ctrl.reset_chain(self._chain(), "sample",
                                                               (self.selection.chain, self.selection.index))))
        self.set_button.on_click(steer(lambda: ctrl.set_chain(
            self._chain(), {n: float(h.value) for n, h in self.set_inputs.items()})))

        def run_until():
            st = ctrl.status()
            u = st.get("until") or {}
            ctrl.run_until(float(self.until_input.value), u.get("min_ess", st["convergence"]["min_ess"]),
                           u.get("max_sweeps"))
        self.until_button.on_click(steer(run_until))

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
            self.traj = self.model.motion(position)
            self.resimulations += 1
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
            self.sample_text.content = (f"chain {chain}, sample {index}: " + ", ".join(
                f"{k} = {self._fmt(k, v)}" for k, v in (values or {}).items()) + f"; log-lik {ll:.1f}{under}" + started)
            self.last_resim_s = time.perf_counter() - t0
        return self.last_resim_s

    def jump_to_map(self) -> None:
        m = self.ctrl.map()
        if m is None:
            return
        chain, index = m[0], m[1]
        if str(chain) in self.chain_dropdown.options:
            self.chain_dropdown.value = str(chain)
        self.sample_slider.max = max(len(self.ctrl.samples(chain)) - 1, 1)
        self.sample_slider.value = index
        self.select_sample(chain, index)

    def _on_chain_changed(self) -> None:
        chain = self._chain()
        n = len(self.ctrl.samples(chain))
        self.sample_slider.max = max(n - 1, 1)
        self.sample_slider.value = max(n - 1, 0)
        self.select_sample(chain, max(n - 1, 0))

    def _pose_objects(self, frame: int) -> None:
        traj = self.traj
        f = int(np.clip(frame, 0, traj.n_frames - 1))
        for i, h in enumerate(self.object_handles):
            h.position = traj.position_m[i, f]
            h.wxyz = _wxyz_from_xyzw(traj.orientation_xyzw[i, f])

    def set_frame(self, frame: int) -> None:
        with self._lock:
            self.frame = int(np.clip(frame, 0, self.n_frames - 1))
            self._pose_objects(self.frame)
            img = self.video[self.frame]
            if self.frustum is not None:
                self.frustum.image = img
            if self.camera_view:
                self.server.scene.set_background_image(img, format="jpeg", jpeg_quality=85)

    def snap_camera(self, client=None) -> None:
        if self.camera is None:
            self._notify("this scene has no video camera")
            return
        wxyz, pos, fov, _ = camera_pose(self.camera)
        clients = [client] if client is not None else list(self.server.get_clients().values())
        fwd = np.array(trimesh.transformations.quaternion_matrix(wxyz))[:3, 2]
        for c in clients:
            with c.atomic():
                c.camera.fov = fov
                c.camera.wxyz = wxyz
                c.camera.position = pos
                c.camera.look_at = pos + 1.2 * fwd
        self.camera_view = True
        self.server.scene.set_background_image(self.video[self.frame], format="jpeg", jpeg_quality=85)
        self.frustum.visible = False

    def free_view(self) -> None:
        self.camera_view = False
        self.server.scene.set_background_image(None)
        if self.frustum is not None:
            self.frustum.visible = True

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
        opts = [str(c) for c in ids] or ["0"]
        if tuple(opts) != tuple(self.chain_dropdown.options):
            self.chain_dropdown.options = opts
        chain = self._chain()
        n = len(ctrl.samples(chain))
        if n > 1 and self.sample_slider.max != n - 1:
            self.sample_slider.max = n - 1
        if n and self.selection_empty:  # the first samples arrived: show the latest
            self.sample_slider.value = n - 1
            self.select_sample(chain, n - 1)
        st = ctrl.status()
        conv = st["convergence"]
        target = st.get("target_sweeps") or self.target_sweeps
        until = st.get("until")
        total = until["max_sweeps"] if until else target     # run until converged: towards the budget
        running = sum(1 for c in st["chains"].values() if c.get("running"))
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
        elif until:
            state = (f"running until converged (R-hat <= {until['until_rhat']:g}, ESS >= {until['min_ess']:g}; "
                     f"this block to sweep {target}, budget {until['max_sweeps']})")
        else:
            state = f"not converged yet (sweep target {target})"
        moves_txt = f"moves: {mv.get('set', '?')}"
        if mv.get("warmup"):
            moves_txt += (f", widths adapting (warm-up: sweeps 1-{mv['warmup']})" if mv.get("adapting")
                          else f", widths adapted in warm-up (sweeps 1-{mv['warmup']}, dropped)")
        if macc:
            moves_txt += f"; joint moves' acceptance: {macc}"
        self.status_text.content = (f"{running} running / {len(ids)} chains, {st.get('sweeps', 0)} sweeps: {state}  \n"
                                    f"{moves_txt}  \nacceptance: {acc or '-'}  \n"
                                    f"convergence ({conv.get('kept_draws', 0)} kept draws): {conv['summary']}  \n"
                                    f"{map_txt}")
        box = convergence_html(conv, st.get("derived") or {})
        if self.convergence_box.content != box:
            self.convergence_box.content = box
        self._update_plots(ids)

    def _update_plots(self, ids: list[int]) -> None:
        ctrl = self.ctrl
        traces = [ctrl.logliks(c) for c in ids]
        length = max((len(t) for t in traces), default=0)
        if length == 0:
            return
        x = np.arange(1, length + 1, dtype=float)
        # uPlot draws nothing if a series holds NaN: a shorter (paused, removed) chain's trace is
        # held at its last value
        ys = [np.concatenate([t, np.full(length - len(t), t[-1] if len(t) else 0.0)]) for t in traces]
        series = [uplot.Series(label="sweep")] + [
            uplot.Series(label=f"chain {c}", stroke=CHAIN_COLORS[c % len(CHAIN_COLORS)], width=1) for c in ids]
        data = [x, *ys]
        # edits (priors, sigma, widths, steering) as spikes from the bottom at the sweep they took effect
        # (pausing and resuming change no chain's target or state: not edits; the app pauses every
        # chain at its target sweeps, which would otherwise mark a spike there)
        edits = sorted({e["sweep"] for e in ctrl.events
                        if e["kind"] not in NOT_EDITS and 1 <= e["sweep"] <= length})
        if edits:
            stack = np.stack(ys)
            marks = np.full(length, float(stack.min()))
            for sw in edits:
                marks[sw - 1] = float(stack[:, sw - 1].max())
            series.append(uplot.Series(label="edit", stroke="#000", width=1))
            data.append(marks)
        # the y axis wide enough for its labels (a splash chain starts near -1e6)
        width = 8 * len(f"{-max(abs(float(np.min(ys))), abs(float(np.max(ys)))):,.0f}") + 20
        if width != self._y_axis_px:
            self._y_axis_px = width
            self.trace_plot.axes = (uplot.Axis(), uplot.Axis(size=width))
        legend = len(ids) <= len(CHAIN_COLORS)   # more chains (the splash's 50) than colours: a legend taller than the plot
        if legend != self._legend:
            self._legend = legend
            self.trace_plot.legend = uplot.Legend(show=legend)
        self.trace_plot.series = tuple(series)
        self.trace_plot.data = tuple(data)
        self.trace_plot.title = "log-likelihood per chain" + (f" (edits at sweeps {edits})" if edits else "")
        samples = [ctrl.samples(c) for c in ids]
        w = ctrl.warmup   # the kept draws: after max(warm-up, half) of each chain (none yet in warm-up)
        kept = np.concatenate([s[burn_in(len(s), w):] for s in samples] + [np.empty((0, len(ctrl.names)))])
        bounds = ctrl.settings.bounds
        starts = np.array(list(ctrl.starts().values()), float).reshape(-1, len(ctrl.names))
        for j, n in enumerate(ctrl.names):
            lo, hi = bounds[n]
            if j in self._integer:   # one bin per integer, at the integer (30 bins over 5..30 leave gaps)
                ks = np.arange(np.ceil(lo), np.floor(hi) + 1)
                edges = np.append(ks - 0.5, ks[-1] + 0.5) if len(ks) else np.array([lo, hi])
                x = ks.astype(float) if len(ks) else np.array([lo])
            else:
                edges = np.linspace(lo, hi, 31)
                x = edges[:-1].astype(float)
            counts = np.histogram(kept[:, j], bins=edges)[0].astype(float)
            # where the chains started (counts x 10, so 16 chains show beside thousands of draws)
            started = 10.0 * np.histogram(starts[:, j], bins=edges)[0].astype(float)
            data = [x, counts, started]
            if n in self._recognized:   # the recognition model's density, its peak at the posterior's
                dens = self._recognized[n](x + (edges[1] - edges[0]) / 2)
                data.append(dens / max(float(dens.max()), 1e-300) * max(float(counts.max()), 1.0))
            self.hist_plots[n].data = tuple(data)

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
