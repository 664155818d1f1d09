"""The drop scene: a ball released at rest `height_m` above the ground plane (z = 0).

Scene file (JSON):

    {"scenario": "drop",
     "height_m": 0.4,          ball's lowest point above the ground at release, (0, 10] m
     "radius_m": 0.02,         (0, 1] m
     "restitution": 0.6,       the ball's restitution e, [0, 1] (the latent)
     "fps": 60, "n_frames": 60 the video's frame rate (sim_hz a multiple of it) and length
     "sim_hz": 240,            optional, Bullet steps per second
     "gravity_mps2": 9.81,     optional
     "priors": {"e": [0, 1]},  optional, the prior U(low, high) of e
     "camera": {...}}          optional, as the ramp's (`galileo.camera`)
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, ClassVar

from galileo.camera import Camera, camera_from_json
from galileo.errors import SceneError
from galileo.fields import field_value, number, pair
from galileo.latents import Latent, check_bounds
from galileo.scenefile import SceneFile

BALL = "ball"
E_LIMITS = (0.0, 1.0)
FIELDS = ("scenario", "height_m", "radius_m", "restitution", "fps", "n_frames", "sim_hz", "gravity_mps2",
          "priors", "camera")


def e_latent(bounds: tuple[float, float] = E_LIMITS) -> Latent:
    return Latent("e", "1", tuple(bounds), "restitution of the ball (the ground's is 1: Bullet multiplies them)",
                  limits=E_LIMITS, narrow=0.1, broad=0.3)


@dataclass(frozen=True)
class DropScene(SceneFile):
    scenario: ClassVar[str] = "drop"
    height_m: float = 0.4
    radius_m: float = 0.02
    restitution: float = 0.6
    fps: float = 60.0
    n_frames: int = 60
    sim_hz: int = 240
    gravity_mps2: float = 9.81
    e_bounds: tuple[float, float] = E_LIMITS
    camera: Camera | None = None

    @property
    def mass_kg(self) -> float:
        """Irrelevant to the motion (nothing but the ground touches the ball): a rubber ball's."""
        return 0.05

    def validate(self) -> None:
        spf = self.sim_hz / self.fps
        if abs(spf - round(spf)) > 1e-9:
            raise SceneError(f"sim_hz ({self.sim_hz}) must be a multiple of fps ({self.fps:g})")
        if self.camera is not None and (self.camera.fps, self.camera.n_frames) != (self.fps, self.n_frames):
            raise SceneError(f"camera: its fps and n_frames ({self.camera.fps:g}, {self.camera.n_frames}) "
                             f"differ from the scene's ({self.fps:g}, {self.n_frames})")

    def latents(self) -> dict[str, float]:
        """The latent's value in this scene (its truth when the scene made the observations)."""
        return {"e": self.restitution}

    def with_values(self, values: dict[str, float]) -> "DropScene":
        known = {"e": "restitution", "restitution": "restitution", "height_m": "height_m"}
        unknown = sorted(set(values) - set(known))
        if unknown:
            raise SceneError(f"unknown value(s) {', '.join(unknown)}; the drop scene takes e and height_m")
        changes = {known[k]: float(v) for k, v in values.items()}
        if "restitution" in changes and not E_LIMITS[0] <= changes["restitution"] <= E_LIMITS[1]:
            raise SceneError(f"e: {changes['restitution']:g} is outside [0, 1]")
        if "height_m" in changes and not changes["height_m"] > 0:
            raise SceneError(f"height_m: {changes['height_m']:g} must be > 0")
        return replace(self, **changes)

    def to_json(self) -> dict:
        d = {"scenario": self.scenario, "height_m": self.height_m, "radius_m": self.radius_m,
             "restitution": self.restitution, "fps": self.fps, "n_frames": self.n_frames, "sim_hz": self.sim_hz,
             "gravity_mps2": self.gravity_mps2, "priors": {"e": list(self.e_bounds)}}
        if self.camera is not None:
            d["camera"] = self.camera.to_json()
        return d


def scene_from_json(data: Any) -> DropScene:
    if not isinstance(data, dict):
        raise SceneError("expected a JSON object at the top level")
    scenario = field_value(data, "scenario", "")
    if scenario != "drop":
        raise SceneError(f"scenario: this is the drop scenario's parser, got {scenario!r}")
    unknown = sorted(set(data) - set(FIELDS))
    if unknown:
        raise SceneError(f"unknown field(s) {', '.join(unknown)}; a drop scene has {', '.join(FIELDS)}")
    pd = field_value(data, "priors", "", {})
    lo, hi = pair(pd, "e", "priors", list(E_LIMITS))
    try:
        e_bounds = check_bounds(e_latent(), lo, hi)
    except ValueError as err:
        raise SceneError(f"priors.{err}") from None
    cam = field_value(data, "camera", "", None)
    scene = DropScene(
        height_m=number(data, "height_m", "", lo=0, hi=10, lo_open=True),
        radius_m=number(data, "radius_m", "", 0.02, lo=0, hi=1, lo_open=True),
        restitution=number(data, "restitution", "", 0.6, lo=0, hi=1),
        fps=number(data, "fps", "", lo=0, hi=10000, lo_open=True),
        n_frames=number(data, "n_frames", "", lo=2, hi=100000, integer=True),
        sim_hz=number(data, "sim_hz", "", 240, lo=1, hi=100000, integer=True),
        gravity_mps2=number(data, "gravity_mps2", "", 9.81, lo=0, lo_open=True),
        e_bounds=e_bounds,
        camera=camera_from_json(cam) if cam is not None else None)
    scene.validate()
    return scene


def newton_rebound_mps(scene: DropScene, e: float) -> float:
    """Newton's rebound speed right after the first bounce: e * sqrt(2 g h)."""
    return e * math.sqrt(2 * scene.gravity_mps2 * scene.height_m)
