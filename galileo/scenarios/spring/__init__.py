"""The spring scenario of Physics 101 (section 2): an object hanging from a spring, pulled down
(or lifted) by hand and released; it bounces and sways. Its mass, the spring's stiffness, own
mass, damping and unloaded length, from the object's tracked centre in the image.

This folder holds all of it: the scene and priors (`scene.py`), Hooke's law in Bullet
(`physics.py`), the AR(1) pixel likelihood (`likelihood.py`), what a problem of several videos
identifies (`identify.py`), the tracker for real footage (`tracking.py`). `SpringScenario` is its
face to the rest of Galileo.

One video identifies stiffness over mass only; a mass needs a reference of known mass on the
same spring (several videos, one problem: latents of the same object or spring are shared by
name, `galileo.joint`). See `identify.py`.
"""
from __future__ import annotations

import math

import numpy as np

from ...latents import Noise
from ...model import Anchor, Connector, Drawing, Mesh, Scenario
from .scene import NOISE_LATENTS

STAND_COLOR = (60, 60, 60)
OBJECT_COLOR = (190, 140, 80)
SPRING_COLOR = (150, 150, 160)
SPRING_COILS = 24
SPRING_RADIUS_M = 0.012


class SpringScenario(Scenario):
    name = "spring"
    description = ("an object bouncing on a spring (Physics 101, spring): its mass given a reference on the same "
                   "spring, the spring's stiffness, own mass and damping, from the tracked centre")
    noise = Noise("sigma_px", "px", 0.5, "the tracker's precision (px): the least SD the likelihood assumes (the "
                  "per-video noise latents add to it)", limits=(1e-3, 1e3))
    # its posterior's ridges are followed exactly by its own moves (moves.py); the adaptive walk over
    # 10-20 latents learnt nothing in 75 sweeps (accepted 0-4%) and cost a whole simulation a sweep
    adaptive_walk = False
    starts_doc = ("a damped sine fitted to the track (period, decay, rest position), the masses drawn from the prior "
                  "and the stiffness and damping that match them")

    # -- scene and observations ---------------------------------------------------------------------
    def scene_from_json(self, data):
        from .scene import scene_from_json

        return scene_from_json(data)

    def default_scene(self):
        from .scene import default_scene

        return default_scene()

    def values(self, scene):
        """The scene's latents and a nominal noise (1 px, white: a scene has no noise of its own)."""
        from .scene import NOISE_VALUES

        return {**scene.latents(), **NOISE_VALUES}

    def track(self, video_path, scene, *, progress=True, debug_video=None):
        from .tracks import track

        return track(video_path, scene, progress=progress, debug_video=debug_video)

    @property
    def dataset(self):
        from .dataset import DATASET

        return DATASET

    @property
    def experiments(self):
        from ...capabilities import Experiments
        from . import experiments

        return Experiments(experiments.run_video, experiments.summarise, experiments.sections)

    @property
    def calibration(self):
        from .clicks import CALIBRATION

        return CALIBRATION

    @property
    def synthetic(self):
        from ...capabilities import Synthetic
        from .tracks import synthetic_tracks

        return Synthetic(synthetic_tracks)

    def prepare(self, scene, tracks):
        from .tracks import prepare

        return prepare(scene, tracks)

    def shared_latents(self, prepared_scenes):
        """An object's or spring's latents wherever two videos have them (the same object, the same
        spring): one value for all."""
        seen: dict[str, int] = {}
        for s in prepared_scenes:
            for name in s.names():
                seen[name] = seen.get(name, 0) + 1
        return tuple(n for n, c in seen.items() if c > 1 and n not in ("x0_m", "z0_m", "vx0_mps", "vz0_mps", "scale"))

    def not_identified(self, prepared_scenes, fixed, tracks=None, share=()):
        from .identify import not_identified

        return not_identified(prepared_scenes, fixed)

    # -- physics and likelihood -----------------------------------------------------------------
    def simulate(self, scene, n_frames, values=None, fps=None):
        from .physics import simulate

        return simulate(scene, n_frames, {k: v for k, v in (values or {}).items() if k not in NOISE_LATENTS}, fps)

    def likelihood(self, prepared_scene, tracks, noise, speedups=True):
        from .likelihood import SpringLikelihood

        names = [lat.name for lat in self.latents(prepared_scene)]
        return SpringLikelihood(prepared_scene, tracks, names, noise, speedups)

    def moves(self, prepared_scene, tracks, latents, bounds):
        """One video alone: its problem's moves (`moves.py`); in a problem of several videos
        `problem_moves` makes them over all the videos at once."""
        from .moves import one_video, problem_moves

        return problem_moves([prepared_scene], one_video(latents), [lat.name for lat in latents], bounds)

    def problem_moves(self, prepared_scenes, lay, bounds):
        from .moves import problem_moves

        return problem_moves(list(prepared_scenes), lay.sources, lay.names, bounds)

    def initial_positions(self, prepared_scene, latents, bounds, n_chains, seed):
        from .tracks import starts

        return starts(prepared_scene, latents, bounds, n_chains, seed)

    def problem_starts(self, prepared_scenes, lay, n_chains, seed):
        from .tracks import problem_starts

        return problem_starts(prepared_scenes, lay, n_chains, seed)

    # -- what the UI draws, and derived answers ---------------------------------------------------
    def drawing(self, scene) -> Drawing:
        import trimesh

        tx, ty, tz = scene.top_in_world_m
        arm = trimesh.creation.box(extents=(0.02, 0.02, 0.02))
        arm.apply_translation((tx, ty, tz + 0.01))
        obj = trimesh.creation.box(extents=scene.size_m)
        spring = Connector("spring", Anchor.fixed((tx, ty, tz)), Anchor.on(0, (0.0, 0.0, scene.hang_m)),
                           SPRING_COLOR, coils=SPRING_COILS, radius_m=SPRING_RADIUS_M)
        return Drawing(static=(Mesh("hanging point", np.asarray(arm.vertices), np.asarray(arm.faces), STAND_COLOR),),
                       objects=(Mesh(scene.object, np.asarray(obj.vertices), np.asarray(obj.faces), OBJECT_COLOR),),
                       ground_z_m=None, connectors=(spring,))

    def derived(self, scene, values) -> dict:
        """The bounce's period, its damping ratio and the static extension (the scene's values
        where a latent is fixed elsewhere)."""
        s = scene.with_values({k: v for k, v in values.items() if k not in NOISE_LATENTS})
        m_eff = s.mass_kg + s.spring_mass_kg / 3
        if m_eff <= 0 or s.k_Npm <= 0:
            return {"period_s": None, "damping_ratio": None, "extension_m": None}
        return {"period_s": 2 * math.pi * math.sqrt(m_eff / s.k_Npm),
                "damping_ratio": s.damping_Nspm / (2 * math.sqrt(s.k_Npm * m_eff)),
                "extension_m": (s.mass_kg + s.spring_mass_kg / 2) * s.gravity_mps2 / s.k_Npm}

    def video_timing(self, scene):
        return scene.fps, scene.n_frames

