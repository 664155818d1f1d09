"""The ramp scenario of Galileo (NIPS 2015): an object slides down a ramp, maybe into a target.

Everything the ramp knows lives in this folder: the scene and its priors (`scene.py`), the
Bullet world (`physics.py`), detection and tracking of its objects (`tracking.py`), the
two-phase velocity likelihood with its exact speed-ups (`likelihood.py`), the paper's
questions (`predict.py`), its dataset and renderer (`dataset.py`, `render.py`,
`materials.py`), experiments (`experiments.py`) and what the recognition model reads and
learns from (`recognition.py`). `RampScenario` is its face to the rest of Galileo
(`galileo.model.Scenario`).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ...latents import Noise
from ...model import Drawing, Mesh, Scenario

RAMP_COLOR = (196, 170, 130)
OBJECT_COLORS = [(220, 90, 50), (70, 130, 220)]


class RampScenario(Scenario):
    name = "ramp"
    description = ("an object slides down a ramp and maybe hits a target on the ground "
                   "(Galileo, NIPS 2015): masses and frictions from tracked velocities")
    noise = Noise("sigma_mps", "m/s", 0.05, "scale of each tracked velocity component's noise (x, z): the paper's "
                  "Sigma, a standard deviation for its Gaussian likelihood, the scale of the default Student-t",
                  limits=(1e-4, 10.0))   # 0.1 mm/s (a pixel's jitter is more) to 10 m/s (no ramp is that fast)
    # the default observation model is Student-t (it measured better on coverage and accuracy,
    # BENCHMARKS.md, issue 12), and the collision's restitution a latent (issue 30); the paper's
    # is Gaussian, its restitution fixed
    paper_priors = {"observation": "gaussian", "infer_restitution": False}
    # running until converged: the move fitted to the warm-up joins, with its conditional and
    # marginal moves (BENCHMARKS.md, issue 30: the demo converges in a median 279 sweeps over 5
    # seeds, 156-803, with the restitution latent; the default moves had not after 1,200)
    converge_moves = "fitted"

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
                           coverage=("k1", "log_mass_ratio"))

    @property
    def synthetic(self):
        from ...capabilities import Synthetic
        from . import synthetic

        return Synthetic(synthetic.synthetic_tracks, synthetic.random_scene, synthetic.describe)

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
        from .likelihood import scene_for_inference

        return scene_for_inference(scene, tracks)

    def simulate(self, scene, n_frames, values=None, fps=None):
        from .physics import Simulator

        return Simulator(scene).run(n_frames, values, fps=fps, with_orientation=True)

    def likelihood(self, prepared_scene, tracks, noise, speedups=True):
        from .likelihood import VelocityLikelihood

        return VelocityLikelihood(prepared_scene, tracks, noise, speedups)

    def moves(self, prepared_scene, tracks, latents, bounds):
        from .moves import ramp_moves

        return ramp_moves(prepared_scene, tracks, [lat.name for lat in latents], bounds)

    def drawing(self, scene) -> Drawing:
        import trimesh

        from ...shapes import mesh as shape_mesh

        r = scene.ramp
        box = trimesh.creation.box(extents=(r.length_m, r.width_m, r.thickness_m))
        centre = -(r.length_m / 2) * r.downhill - (r.thickness_m / 2) * r.normal
        x, y, z, w = r.orientation_xyzw
        box.apply_transform(trimesh.transformations.quaternion_matrix([w, x, y, z]))
        box.apply_translation(centre)
        # half transparent, so that in camera view the video's ramp shows through
        ramp = Mesh("ramp", np.asarray(box.vertices), np.asarray(box.faces), RAMP_COLOR, 0.45)
        objects = []
        for i, obj in enumerate(scene.objects):
            m = shape_mesh(obj.shape)
            objects.append(Mesh(obj.name, np.asarray(m.vertices), np.asarray(m.faces), OBJECT_COLORS[i % 2]))
        return Drawing(static=(ramp,), objects=tuple(objects), ground_z_m=0.0)

    def not_identified(self, prepared_scenes, fixed, tracks=None, share=()):
        from .identify import not_identified

        return not_identified(prepared_scenes, fixed, tracks, share)

    def derived(self, scene, values):
        if "m2_kg" in values:
            return {"mass_ratio": values["m1_kg"] / values["m2_kg"]}
        return {"mass_ratio": None}

    def summary(self, scene, values, omit=()):
        ratio = None if "mass_ratio" in omit else self.derived(scene, values)["mass_ratio"]
        return ", ".join([f"{k} = {v:.3f}" for k, v in values.items() if k not in omit]
                         + ([f"m1/m2 = {ratio:.2f}"] if ratio is not None else []))

    @property
    def questions(self):
        from ...capabilities import Question
        from ...fields import Bound

        return (Question("angle_deg", "will the ramp object move on a ramp of this angle (degrees)?", "number",
                         Bound(0.0, 90.0, hi_open=True)),
                Question("target", "where does the target end up (the video's scene)?", "yes"),
                Question("scene", "where does the target end up in this scene file instead?", "file"))

    def predict(self, result_path: str | Path, questions: dict) -> dict:
        from ...errors import GalileoError
        from .predict import Prediction

        pred = Prediction(result_path)
        out: dict = {}
        if questions.get("angle_deg") is not None:
            out["will_it_move"] = pred.will_it_move(questions["angle_deg"])
        if questions.get("target") or questions.get("scene"):
            out["target"] = pred.target_outcome(self.load_scene(questions["scene"]) if questions.get("scene")
                                                else None)
        if not out:
            raise GalileoError("nothing to predict: ask angle_deg (--angle-deg), target (--target-outcome) or scene (--scene)")
        return out
