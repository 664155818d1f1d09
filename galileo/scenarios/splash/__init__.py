"""The splash scenario of Physics 101 (the splash abstract): an object dropped into a tank of
water; its density, bottom area and water drag (and the observation start frame) from the
tracked positions and velocities, mass = density x the bottom-up volume.

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
START_DENSITY_G_CM3 = 0.5     # the seed: chains start at half the density of water


def _box_mesh(centre, size, color, opacity, name) -> Mesh:
    import trimesh

    m = trimesh.creation.box(extents=size)
    m.apply_translation(centre)
    return Mesh(name, np.asarray(m.vertices), np.asarray(m.faces), color, opacity)


class SplashScenario(Scenario):
    name = "splash"
    description = ("an object dropped into a tank of water (Physics 101, splash): density, bottom area, "
                   "water drag and start frame from tracked positions and velocities; mass = density x volume")
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
        scene file's is refused); checks that the tracks hold one object at the camera's rate,
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
        if obj is scene.obj:
            return scene
        new = dataclasses.replace(scene, obj=dataclasses.replace(
            obj, area_cm2=equal_area(obj.kind, obj.volume_m3) / CM2))
        new.validate()
        return new

    def simulate(self, scene, n_frames, values=None, fps=None):
        """The video's frames: frame 0 at physics step start_step after the release."""
        from .physics import Simulator

        start = int(round((values or {}).get("start_step", scene.start_step)))
        return Simulator(scene).run(n_frames, values, fps=fps, start_step=start)

    def likelihood(self, prepared_scene, tracks, noise, speedups=True):
        from .likelihood import SplashLikelihood

        return SplashLikelihood(prepared_scene, tracks, noise, speedups)

    # the seed's water-drag widths, U(-0.0005, 0.0005) and every 20th sweep U(-0.002, 0.002), for
    # `--moves paper`; the default moves start from 0.05 / 0.5 (as area and density) and adapt: from
    # the seed's, 37 warm-up sweeps grow a width at most about 100-fold, and drag never left its
    # start (R-hat 22 on the demo at 50 x 75; 9 with these)
    paper_widths = {"drag_water": (0.0005, 0.002)}
    starts_doc = ("as the seed starts them: the bottom area at which the object's dimensions are equal and "
                  "density 0.5 g/cm^3 (every chain alike); water drag and start step drawn from the prior")

    def initial_positions(self, prepared_scene, latents, bounds, n_chains, seed):
        """The seed's start: the bottom area at which the object's dimensions are equal, density
        0.5 g/cm^3; water drag and start frame drawn from the prior (clipped into the bounds)."""
        starts = super().initial_positions(prepared_scene, latents, bounds, n_chains, seed)
        o = prepared_scene.obj
        names = [lat.name for lat in latents]
        for name, value in (("area_cm2", equal_area(o.kind, o.volume_m3) / CM2),
                            ("density_g_cm3", START_DENSITY_G_CM3)):
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
        body = Body.of(o.kind, o.volume_m3, o.area_cm2 * CM2, scene.max_dim_m())
        m = body.shape.make_mesh(32)
        obj = Mesh(o.name, np.asarray(m.vertices), np.asarray(m.faces), OBJECT_COLOR)
        return Drawing(static=tuple(static), objects=(obj,), ground_z_m=None)

    def derived(self, scene, values) -> dict:
        """Mass (kg) = density x the bottom-up volume, and that volume (cm^3)."""
        volume_cm3 = scene.obj.volume_cm3
        return {"mass_kg": values["density_g_cm3"] * volume_cm3 * CM3 * 1000.0, "volume_cm3": volume_cm3}

    def summary(self, scene, values):
        d = self.derived(scene, values)
        return (", ".join(f"{k} = {v:.4g}" for k, v in values.items())
                + f"; mass {1000 * d['mass_kg']:.4g} g from a volume of {d['volume_cm3']:.4g} cm^3")
