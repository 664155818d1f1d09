"""The fall scenario of Physics 101 (section 2): an object dropped by hand onto a surface (a table,
foam, carpet, cloth); it falls, hits, bounces, tumbles, slides and comes to rest. The
object-surface pair's coefficient of restitution and friction, from the object's tracked
silhouette centroid.

This folder holds all of it: the scene and priors (`scene.py`), Bullet with Poisson's
restitution (`physics.py`), the pixel likelihood (`likelihood.py`), the lift to 3-D and the
chains' starts (`tracks.py`), the tracker for real footage (`tracking.py`), the calibration
from four corners of the surface (`clicks.py`), the rendered dataset (`dataset.py`,
`render.py`, `materials.py`) and the experiments (`experiments.py`). `FallScenario` is its face
to the rest of Galileo.

Mass does not change a rigid fall: it is never inferred, and `result.json` says so
(`not_identified`).
"""
from __future__ import annotations

import numpy as np

from ...latents import Noise
from ...model import Drawing, Mesh, Scenario
from .scene import NOISE_LATENTS, object_mass_latent

SURFACE_COLORS = {"table": (225, 220, 200), "foam": (90, 140, 200), "carpet": (150, 60, 60), "cloth": (120, 160, 110)}
OBJECT_COLOR = (200, 160, 110)
SURFACE_THICKNESS_M = 0.01
SURFACE_OPACITY = 0.45      # half transparent: in the camera view the video's table and object show through


class FallScenario(Scenario):
    name = "fall"
    description = ("an object dropped onto a surface (Physics 101, fall): the object-surface pair's coefficient of "
                   "restitution and friction, from the tracked silhouette")
    noise = Noise("sigma_px", "px", 1.0, "the tracker's precision (px): the least SD the likelihood assumes (the "
                  "per-video noise latent adds to it)", limits=(1e-3, 1e3))
    starts_doc = ("from the fits of a staged search with Bullet (a fall from rest fitted to the fall's frames, then "
                  "3,000 draws polished on ever more of the track): two chains each")

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
        try:
            from .dataset import DATASET
        except ImportError:      # not built yet
            return None
        return DATASET

    @property
    def experiments(self):
        from ...capabilities import Experiments
        from . import experiments

        return Experiments(experiments.run_video, experiments.summarise, experiments.sections)

    @property
    def calibration(self):
        try:
            from .clicks import CALIBRATION
        except ImportError:      # not built yet
            return None
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
        """An object-surface pair's coefficients wherever two videos have them: one value for all."""
        seen: dict[str, int] = {}
        for s in prepared_scenes:
            for name in s.names():
                seen[name] = seen.get(name, 0) + 1
        return tuple(n for n, c in seen.items() if c > 1 and n.startswith(("e_", "mu_")))

    def not_identified(self, prepared_scenes, fixed, tracks=None, share=()):
        out = {}
        for s in prepared_scenes:
            out[object_mass_latent(s.object)] = ("not a latent: a rigid object's fall, bounce and slide on a fixed "
                                                 "surface do not depend on its mass (gravity, contact and friction "
                                                 "forces all scale with it)")
        return out

    # -- physics and likelihood -----------------------------------------------------------------
    def simulate(self, scene, n_frames, values=None, fps=None):
        from .physics import simulate

        return simulate(scene, n_frames, {k: v for k, v in (values or {}).items() if k not in NOISE_LATENTS}, fps)

    def likelihood(self, prepared_scene, tracks, noise, speedups=True):
        from .likelihood import FallLikelihood

        names = [lat.name for lat in self.latents(prepared_scene)]
        return FallLikelihood(prepared_scene, tracks, names, noise, speedups)

    def initial_positions(self, prepared_scene, latents, bounds, n_chains, seed):
        from .tracks import starts

        return starts(prepared_scene, latents, bounds, n_chains, seed)

    # -- what the UI draws, and derived answers ---------------------------------------------------
    def drawing(self, scene) -> Drawing:
        import trimesh

        from ...shapes import mesh

        length, width = scene.surface_size_m
        top = trimesh.creation.box(extents=(length, width, SURFACE_THICKNESS_M))
        top.apply_translation((0.0, 0.0, -SURFACE_THICKNESS_M / 2))
        obj = mesh(scene.shape)
        color = SURFACE_COLORS.get(scene.surface_kind, SURFACE_COLORS["table"])
        return Drawing(static=(Mesh(f"surface ({scene.surface_kind})", np.asarray(top.vertices), np.asarray(top.faces),
                                    color, SURFACE_OPACITY),),
                       objects=(Mesh(scene.object, np.asarray(obj.vertices), np.asarray(obj.faces), OBJECT_COLOR),),
                       ground_z_m=None)     # (the surface is drawn; a grid at its height would cross walls and stands)

    def derived(self, scene, values) -> dict:
        """The first bounce's height over the drop's, e^2 (landing flat), and how far a block sliding
        at 1 m/s goes, 1 / (2 mu g)."""
        s = scene.with_values({k: v for k, v in values.items() if k not in NOISE_LATENTS})
        return {"bounce_ratio": s.restitution ** 2,
                "slide_m_at_1mps": (1.0 / (2 * s.friction * s.gravity_mps2)) if s.friction > 0 else None}

    def video_timing(self, scene):
        return scene.fps, scene.n_frames
