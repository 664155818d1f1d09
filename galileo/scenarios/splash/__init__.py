"""The splash scenario of Physics 101 (the splash abstract): an object dropped into a tank of
water; its density, bottom area, water drag, volume (around the bottom-up estimate) and
release (time and push) from the tracked positions and velocities, mass = density x volume.

This folder holds all of it: the scene and priors (`scene.py`), buoyancy and drag in Bullet
(`physics.py`), the position-and-velocity likelihood with its exact speed-ups
(`likelihood.py`), what the recognition model reads and learns from (`recognition.py`: the
object's mass from one frame, as a density start). `SplashScenario` is its face to the rest
of Galileo.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from ...errors import GalileoError
from ...latents import Noise
from ...model import Drawing, Mesh, Scenario
from .scene import CM2, CM3, KINDS, VOLUME_RANGE_CM3, equal_area

WATER_COLOR = (90, 150, 230)
GLASS_COLOR = (200, 220, 235)
OBJECT_COLOR = (220, 90, 50)
START_DENSITY_G_CM3 = 0.5     # the seed: chains start at half the density of water ...
SINKER_START_G_CM3 = 1.5      # ... this for an object the video shows under water at its end (it sank)


def _box_mesh(centre, size, color, opacity, name) -> Mesh:
    import trimesh

    m = trimesh.creation.box(extents=size)
    m.apply_translation(centre)
    return Mesh(name, np.asarray(m.vertices), np.asarray(m.faces), color, opacity)


class SplashScenario(Scenario):
    name = "splash"
    description = ("an object dropped into a tank of water (Physics 101, splash): density, bottom area, "
                   "water drag, volume and release from tracked positions and velocities; mass = density x volume")
    protocol = {"chains": 50, "sweeps": 75}   # the seed: 50 chains per video (75 sweeps: Galileo's)
    noise = Noise("sigma_px", "px", 1.0, "SD of tracked positions (px) and velocities (px/frame), the seed's Sigma = 1",
                  limits=(1e-3, 1e4))   # a thousandth of a pixel to more than any frame is wide
    # the recognition model's mass scale (recognition.py: readouts, labels, examples, features):
    # the catalogue's lightest (1.9 g, foam) and heaviest (54.9 g, porcelain) objects, rounded outward
    recognition_mass_range_kg = (0.001, 0.06)
    # the object falls from frame 0: patches from its first 10 cm of fall, in air (1 cm keeps frame 0 only)
    recognition_patch_motion_m = 0.10

    # -- scene and observations ---------------------------------------------------------------------
    def scene_from_json(self, data):
        from .scene import scene_from_json

        return scene_from_json(data)

    def default_scene(self):
        from .scene import default_scene

        return default_scene()

    def track(self, video_path, scene, *, progress=True, debug_video=None):
        from .tracking import track

        return track(video_path, scene, progress=progress, debug_video=debug_video)

    # -- capabilities (their modules are imported when asked) --------------------------------------------
    @property
    def dataset(self):
        from .dataset import DATASET

        return DATASET

    @property
    def experiments(self):
        from ...capabilities import Experiments
        from . import experiments, report

        return Experiments(experiments.run_video, experiments.summarise, report.sections,
                           coverage=("density_g_cm3", "log_mass_kg"))

    @property
    def synthetic(self):
        from ...capabilities import Synthetic
        from .synthetic import synthetic_tracks

        return Synthetic(synthetic_tracks)

    @property
    def recognition(self):
        from ...capabilities import Recognition
        from . import recognition as r

        return Recognition(r.readouts, r.examples, r.features, r.label)

    @property
    def calibration(self):
        from .clicks import CALIBRATION

        return CALIBRATION

    # -- inference -------------------------------------------------------------------------------------
    def prepare(self, scene, tracks):
        """The scene with the bottom-up shape kind and volume from the tracks (when they carry
        them; a volume estimated past the prior's 0.01-100 cm^3 is clipped into it, where a
        scene file's is refused), and the priors left at their defaults set from the video
        (`priors_from_tracks`); checks that the tracks hold one object at the camera's rate,
        seen in some frame."""
        tracks.check().require_visible()     # before any chain starts
        if len(tracks.objects) != 1:
            raise GalileoError(f"splash tracks hold one object, got {len(tracks.objects)}")
        if scene.camera is None:
            raise GalileoError("the splash scene needs a camera (the likelihood measures in pixels)")
        if abs(tracks.fps - scene.fps) > 1e-9:
            raise GalileoError(f"tracks at {tracks.fps:g} fps but the scene camera at {scene.fps:g} fps")
        found = tracks.objects[0].bottom_up
        obj = scene.obj
        if "volume_cm3" in found:
            v = found["volume_cm3"]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise GalileoError(f"tracks: bottom_up.volume_cm3 must be a positive number, got {v!r}")
        if "kind" in found:
            if found["kind"] not in KINDS:
                raise GalileoError(f"tracks: bottom_up.kind must be one of {', '.join(KINDS)}, got {found['kind']!r}")
            obj = dataclasses.replace(obj, kind=found["kind"])
        if "volume_cm3" in found:   # a bottom-up estimate past the prior's range is clipped into it
            lo, hi = VOLUME_RANGE_CM3
            obj = dataclasses.replace(obj, volume_cm3=float(np.clip(float(found["volume_cm3"]), lo, hi)))
        if obj is not scene.obj:
            obj = dataclasses.replace(obj, area_cm2=equal_area(obj.kind, obj.volume_m3) / CM2)
        bounds = priors_from_tracks(scene, obj, found, tracks)
        release_s, push_mps = release_start(scene, tracks, bounds)
        obj = dataclasses.replace(obj, density_g_cm3=density_start(scene, tracks))
        if (obj == scene.obj and bounds == scene.bounds and release_s == scene.release_s
                and push_mps == scene.push_mps):
            return scene
        new = dataclasses.replace(scene, obj=obj, bounds=bounds, release_s=release_s, log_volume_factor=0.0,
                                  push_mps=push_mps)
        new.validate()
        return new

    def simulate(self, scene, n_frames, values=None, fps=None):
        """The video's frames, in video time: held still at the release point until release_s."""
        from .physics import Simulator

        return Simulator(scene).run(n_frames, values, fps=fps)

    def likelihood(self, prepared_scene, tracks, noise, speedups=True):
        from .likelihood import SplashLikelihood

        return SplashLikelihood(prepared_scene, tracks, noise, speedups)

    # the seed's water-drag widths, U(-0.0005, 0.0005) and every 20th sweep U(-0.002, 0.002), for
    # `--moves paper`; the default moves start from 0.05 / 0.5 (as area and density) and adapt: from
    # the seed's, 37 warm-up sweeps grow a width at most about 100-fold, and drag never left its
    # start (R-hat 22 on the demo at 50 x 75; 9 with these)
    paper_widths = {"drag_water": (0.0005, 0.002)}
    starts_doc = ("as the seed starts them: the bottom area at which the object's dimensions are equal and "
                  "density 0.5 g/cm^3 (1.5 for an object the video shows sunk; every chain alike); the release "
                  "time and push of a free fall fitted to the frames in the air; water drag and the log "
                  "volume factor drawn from the prior")

    def initial_positions(self, prepared_scene, latents, bounds, n_chains, seed):
        """The seed's start: the bottom area at which the object's dimensions are equal, density
        0.5 g/cm^3 (1.5 for an object that sank: `density_start`); the release and push of a free fall fitted
        to the frames in the air (`release_start`, the prepared scene's); water drag and the
        log volume factor drawn from the prior (each clipped into the bounds): the video hardly
        measures the volume, so chains started across its prior end across it, and a short
        run's mass interval carries the volume's uncertainty (all started at the bottom-up
        volume, they stay near it)."""
        starts = super().initial_positions(prepared_scene, latents, bounds, n_chains, seed)
        o = prepared_scene.obj
        names = [lat.name for lat in latents]
        for name, value in (("area_cm2", equal_area(o.kind, o.volume_m3) / CM2),
                            ("density_g_cm3", o.density_g_cm3),
                            ("release_s", prepared_scene.release_s), ("push_mps", prepared_scene.push_mps)):
            if name not in names:   # fixed
                continue
            j = names.index(name)
            starts[:, j] = float(np.clip(value, bounds[j, 0], bounds[j, 1]))
        return starts

    def drawing(self, scene) -> Drawing:
        from .physics import Body

        t = scene.tank
        (sx, sy, sz), w = t.size_m, t.wall_m
        static = [
            _box_mesh((0, 0, t.water_level_m / 2), (sx, sy, t.water_level_m), WATER_COLOR, 0.25, "water"),
            _box_mesh((0, 0, -w / 2), (sx + 2 * w, sy + 2 * w, w), GLASS_COLOR, 0.5, "tank/floor"),
            _box_mesh((-(sx + w) / 2, 0, sz / 2), (w, sy + 2 * w, sz), GLASS_COLOR, 0.2, "tank/left"),
            _box_mesh(((sx + w) / 2, 0, sz / 2), (w, sy + 2 * w, sz), GLASS_COLOR, 0.2, "tank/right"),
            _box_mesh((0, (sy + w) / 2, sz / 2), (sx, w, sz), GLASS_COLOR, 0.2, "tank/back"),
        ]
        o = scene.obj
        body = Body.of(o.kind, scene.volume_m3, o.area_cm2 * CM2, scene.max_dim_m())
        m = body.shape.make_mesh(32)
        obj = Mesh(o.name, np.asarray(m.vertices), np.asarray(m.faces), OBJECT_COLOR)
        return Drawing(static=tuple(static), objects=(obj,), ground_z_m=None)

    def derived(self, scene, values) -> dict:
        """Volume (cm^3) = the bottom-up volume x exp(log_volume_factor); mass (kg) = density x volume."""
        volume_cm3 = scene.obj.volume_cm3 * math.exp(values.get("log_volume_factor", scene.log_volume_factor))
        return {"mass_kg": values["density_g_cm3"] * volume_cm3 * CM3 * 1000.0, "volume_cm3": volume_cm3}

    def summary(self, scene, values, omit=()):
        d = self.derived(scene, values)
        return (", ".join(f"{k} = {v:.4g}" for k, v in values.items() if k not in omit)
                + f"; mass {1000 * d['mass_kg']:.4g} g from a volume of {d['volume_cm3']:.4g} cm^3")


# -- priors from the video ----------------------------------------------------------------------------
AREA_PRIOR_FACTOR = 4.0     # the area prior U(A / 4, 4 A) around the equal-sided area A (scene.py)
VOLUME_PRIOR_SDS = 2.0      # the log volume factor's prior: U(-2 SD, 2 SD)
RELEASE_BEFORE_FRAMES = 1.5     # the release prior: from 1.5 frames before the last frame seen held ...
RELEASE_AFTER_FRAMES = 2.0      # ... to 2 frames after it (the first centimetre of a fall from rest takes 45 ms)
IN_WATER_S = 0.25           # seen falling from the first frame: released at most the fall to the water + this before


def priors_from_tracks(scene, obj, found: dict, tracks) -> dict:
    """The prepared scene's bounds: the priors left at their defaults (scene.py's
    LATENT_SPECS) set from what a tracker measured (`found`: the track's bottom_up; tracks
    without these keys, as synthetic ones, keep the scene's priors): with `volume_log_sd`, the
    area prior U(A / 4, 4 A) around the bottom-up object's equal-sided area A and the log
    volume factor's U(-2 sd, 2 sd); with `release_s` (the last frame the tracker saw the object held),
    the release from 1.5 frames before to 2 after it, or, null (falling in the first frame it
    is seen), before the next frame and after the first by at most the time a free fall takes
    from the release point to the water, plus IN_WATER_S (seen first in the water). Bounds given
    by hand are kept."""
    from .scene import AREA_CM2, LATENT_SPECS, LOG_VOLUME_FACTOR, RELEASE_S, VOLUME_CM3

    bounds = dict(scene.bounds)

    def default(name):
        return tuple(bounds[name]) == tuple(LATENT_SPECS[name].bounds)

    measured = "volume_log_sd" in found
    if measured and default("area_cm2"):
        a = equal_area(obj.kind, obj.volume_m3) / CM2
        bounds["area_cm2"] = (max(a / AREA_PRIOR_FACTOR, 1e-6), min(a * AREA_PRIOR_FACTOR, AREA_CM2.hi))
    if measured and default("log_volume_factor"):
        sd = found["volume_log_sd"]
        if isinstance(sd, bool) or not isinstance(sd, (int, float)) or not math.isfinite(sd) or sd < 0:
            raise GalileoError(f"tracks: bottom_up.volume_log_sd must be a number >= 0, got {sd!r}")
        sd = max(float(sd), 0.02)
        vmin, vmax = math.log(VOLUME_CM3.lo / obj.volume_cm3), math.log(VOLUME_CM3.hi / obj.volume_cm3)  # its bounds
        bounds["log_volume_factor"] = (max(-VOLUME_PRIOR_SDS * sd, vmin, LOG_VOLUME_FACTOR.lo),
                                       min(VOLUME_PRIOR_SDS * sd, vmax, LOG_VOLUME_FACTOR.hi))
    if "release_s" in found and default("release_s"):
        seen = found.get("release_s")
        if seen is not None and (isinstance(seen, bool) or not isinstance(seen, (int, float))
                                 or not math.isfinite(seen)):
            raise GalileoError(f"tracks: bottom_up.release_s must be a number or null, got {seen!r}")
        if seen is None:   # falling in the first frame it is seen: let go before the next one
            fall_s = math.sqrt(2 * (scene.release_m[2] - scene.tank.water_level_m) / scene.gravity_mps2)
            o = tracks.objects[0]
            first_s = float(np.flatnonzero(o.visible)[0]) / tracks.fps
            lo, hi = first_s - (fall_s + IN_WATER_S), first_s + 1.0 / tracks.fps
        else:
            lo, hi = seen - RELEASE_BEFORE_FRAMES / tracks.fps, seen + RELEASE_AFTER_FRAMES / tracks.fps
        bounds["release_s"] = (max(lo, RELEASE_S.lo), min(hi, RELEASE_S.hi))
    return bounds


def density_start(scene, tracks) -> float:
    """The density the chains start at: the seed's 0.5 g/cm^3, or SINKER_START_G_CM3 where the
    object's last tracked centre lies more than its size (from the bottom-up volume) under the
    water line: it sank, and a chain started at half water's density would first have to cross
    1 g/cm^3, where floating turns into sinking (the likelihood's deepest valley)."""
    o = tracks.objects[0]
    seen = np.flatnonzero(o.visible & np.isfinite(o.position_m[:, 2]))
    if not len(seen):
        return START_DENSITY_G_CM3
    size_m = scene.volume_m3 ** (1 / 3)
    sank = float(o.position_m[seen[-1], 2]) < scene.tank.water_level_m - size_m
    return SINKER_START_G_CM3 if sank else START_DENSITY_G_CM3


def release_start(scene, tracks, bounds: dict) -> tuple[float, float]:
    """(release_s, push_mps) where the chains start: the free fall from the release point
    (gravity alone: air drag is a thousandth of the water's) that best fits the tracked
    heights of the frames in the air (the object's centre more than its size, from the
    bottom-up volume, above the water) and their vertical speeds where a central difference
    measures one (the frames before and after in the air too, and falling already: a one-sided
    difference at a run's end, or one across the release, is off by about g / (2 fps)), held
    still before the release, each weighed as the likelihood weighs it (a speed's SD is fps
    times a position's): for every
    release on a grid of physics steps over the release prior, the push by least squares
    (clipped into its prior), the pair with the smallest weighted squared error. The release and push trade off along a
    ridge (a later, harder push looks alike) that single-site moves climb slowly from a start
    drawn from the prior; this start lies on it near the truth. Without frames in the air, the
    scene's own release and push."""
    o = tracks.objects[0]
    t = np.arange(len(o.visible)) / tracks.fps
    size_m = (scene.volume_m3 ** (1 / 3)) if scene.volume_m3 > 0 else 0.0
    z = o.position_m[:, 2]
    air = o.visible & np.isfinite(z) & (z > scene.tank.water_level_m + size_m)
    (r_lo, r_hi), (p_lo, p_hi) = bounds["release_s"], bounds["push_mps"]
    if not air.any() or p_hi < p_lo:
        return float(np.clip(scene.release_s, r_lo, r_hi)), float(np.clip(scene.push_mps, p_lo, p_hi))
    inner = air.copy()   # a central difference: both neighbours in the air
    inner[0] = inner[-1] = False
    inner[1:-1] &= air[:-2] & air[2:]
    inner = inner[air]
    t, drop, down = t[air], scene.release_m[2] - z[air], -o.velocity_mps[air, 2]
    g, w, dt = scene.gravity_mps2, 1.0 / tracks.fps ** 2, 1.0 / tracks.fps   # a speed's weight against a position's
    speed_ok = inner & np.isfinite(down)
    down = np.where(speed_ok, down, 0.0)
    best = (math.inf, scene.release_s, scene.push_mps)
    for release in np.arange(r_lo, r_hi + 0.5 / scene.sim_hz, 1.0 / scene.sim_hz):
        tau = np.maximum(t - release, 0.0)
        falling = (t - dt > release) & speed_ok
        fall, fast = drop - 0.5 * g * tau ** 2, np.where(falling, down - g * tau, 0.0)   # what the push explains
        denom = float(tau @ tau + w * falling.sum())
        push = float(np.clip((tau @ fall + w * fast.sum()) / denom, p_lo, p_hi)) if denom > 0 else p_lo
        err = float(np.sum((fall - push * tau) ** 2) + w * np.sum(np.where(speed_ok, fast - push * falling, 0.0) ** 2))
        if err < best[0]:
            best = (err, float(release), push)
    return float(np.clip(best[1], r_lo, r_hi)), best[2]
