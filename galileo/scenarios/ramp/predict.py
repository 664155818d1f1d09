"""Predictions from an inference result (Galileo section 6): will the ramp object move on a
ramp of another angle; where does the target end up.

Each answer comes from simulating the MAP estimate, with the share of posterior samples
(the kept draws of every chain) that agree, so the user sees how sure the model is. Every
answer carries the result's `posterior_converged` flag: a share from chains that disagree
is not a probability to trust.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ...errors import GalileoError
from ...results import burn_in, load_result
from .physics import Simulator
from .scene import Scene

MOVE_THRESHOLD_M = 0.01   # "it moves": its centre travels more than this in MOVE_WINDOW_S
MOVE_WINDOW_S = 2.0
SETTLE_S = 4.0            # time allowed for the target to come to rest


def slides(scene: Scene, values: dict[str, float], threshold_m: float = MOVE_THRESHOLD_M,
           sim: Simulator | None = None) -> bool:
    """Whether the ramp object of `scene`, alone (any target removed), moves its centre more
    than `threshold_m` in MOVE_WINDOW_S with `values` (m1_kg, k1)."""
    fps = 30.0
    if sim is None:
        sim = Simulator(dataclasses.replace(scene, objects=scene.objects[:1]))
    t = sim.run(int(MOVE_WINDOW_S * fps) + 1, {k: v for k, v in values.items() if k in ("m1_kg", "k1")}, fps=fps)
    return bool(np.linalg.norm(t.position_m[0, -1] - t.position_m[0, 0]) > threshold_m)


class Prediction:
    """A loaded result: its scene, MAP and posterior samples."""

    def __init__(self, result_path: str | Path, max_samples: int = 64):
        res = load_result(result_path)   # every field checked (galileo.results.load_result)
        if res.scenario != "ramp":
            raise GalileoError(f"result file {result_path}: a {res.scenario!r} result, not the ramp's")
        self.scene: Scene = res.scene
        self.map: dict[str, float] = res.map
        self.names = res.names
        self.samples = np.zeros((0, len(self.names)))
        self.converged = res.converged
        self.why_not = res.why_not
        s = res.samples()
        if s is not None:
            kept = s[:, burn_in(s.shape[1], res.warmup):].reshape(-1, s.shape[2])
            if len(kept):
                idx = np.linspace(0, len(kept) - 1, min(max_samples, len(kept))).astype(int)
                self.samples = kept[idx]

    def _values(self, row) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.names, row)}

    def will_it_move(self, angle_deg: float) -> dict:
        """Does the ramp object slide on a ramp of `angle_deg` (target removed)?"""
        scene = dataclasses.replace(self.scene.with_values({"angle_deg": angle_deg}), objects=self.scene.objects[:1])
        sim = Simulator(scene)
        answer = slides(scene, self.map, sim=sim)
        share = (float(np.mean([slides(scene, self._values(r), sim=sim) for r in self.samples]))
                 if len(self.samples) else None)
        return {"angle_deg": angle_deg, "moves": answer, "posterior_share_moving": share,
                "k1_map": self.map["k1"], "tan_angle": float(np.tan(np.radians(angle_deg))), **self.flag()}

    def flag(self) -> dict:
        """Whether the shares come from a converged posterior (None: the result predates the flag)."""
        return {"posterior_converged": self.converged, **({"why_not": self.why_not} if self.converged is False else {})}

    def target_outcome(self, scene: Scene | None = None) -> dict:
        """Where the target comes to rest (x of its centre, m), for the inferred scene or `scene`."""
        scene = scene or self.scene
        if scene.target is None:
            raise GalileoError("this scene has no target")
        fps = 30.0
        n = int(SETTLE_S * fps) + 1
        sim = Simulator(scene)

        def final_x(values) -> float:
            return float(sim.run(n, values, fps=fps).position_m[1, -1, 0])

        x = final_x(self.map)
        xs = np.array([final_x(self._values(r)) for r in self.samples]) if len(self.samples) else np.zeros(0)
        out = {"target_final_x_m": x, "target_moved_m": x - float(scene.initial_pose(1)[0][0])}
        if len(xs):
            out.update({"posterior_q05_x_m": float(np.quantile(xs, 0.05)),
                        "posterior_q95_x_m": float(np.quantile(xs, 0.95))})
        out.update(self.flag())
        return out
