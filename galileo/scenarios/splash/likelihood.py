"""Likelihood of the splash (the seed's eq. 2): tracked positions and velocities against Bullet.

    log p(x_o, v_o | s, rho, D_w, t) = sum over frames f where the object was seen of
        log N(x_o[f] | x_s(t + f spf), sigma_x^2 I) + log N(v_o[f] | v_s(t + f spf), sigma_v^2 I)

on the x and z components (the image plane of the side camera; depth is not observed).
The simulation starts with the object at rest at the scene's release point; frame f of the
video is physics step t + f * spf of the simulation (t: the observation start, a latent, in
physics steps; spf = sim_hz / fps steps per frame).

Units: the seed fixes Sigma = 1 without units. Here it is 1 in the video's own units: one
pixel for positions and one pixel per frame for velocities (the tracker's resolution), so
sigma_x = sigma_px * m_per_px and sigma_v = sigma_px * m_per_px * fps, where m_per_px is the
size of a pixel at the release point's depth (depth / focal length). `sigma_px` = 1.

The likelihood stands on `galileo.framelik.FrameLikelihood`, with a tick of one physics step
(t, in physics steps, shifts which steps the frames show). Its rest rule (as the ramp's) is
checked on the simulation's own frames (every spf steps from the release, whatever t): once,
for two consecutive such frames, the object moves slower than REST_MPS, turns slower than
REST_RADPS and is not speeding up, later steps hold its last position at zero velocity. A
(s, h) pair with no object that fits the tank (`scene.dimensions`) has prior density 0: -inf
without simulating.

Exact speed-ups (`speedups=True`; the same accept/reject decisions and values as the plain
path, which simulates every frame of every proposal from the release):

* early rejection: every frame adds a term <= 0; the run stops once the partial sum falls
  below the MH threshold.
* at-rest cut-off: after the rest rule holds, the remaining frames are known without stepping.
* reuse of what does not change with a latent: the simulation does not depend on t, only the
  alignment does. A run that completes goes on to the horizon (the start's prior upper
  bound in the scene file + the video's length; a start beyond it, under bounds widened
  at run time, simulates afresh unless the run came to rest) and its every step is kept
  (keyed on s, rho, D_w); a proposal of t is then scored from the kept steps without
  simulating (frame by frame, stopping at the threshold).
"""
from __future__ import annotations

import math

import numpy as np

from ...datatypes import Tracks
from ...errors import GalileoError
from ...framelik import KEPT_MOTIONS, FrameLikelihood, RestRule, Run
from .physics import FrameStepper, Simulator
from .scene import LATENT_NAMES, SplashScene

SIGMA_PX = 1.0


def metres_per_pixel(scene: SplashScene) -> float:
    """The size of a pixel at the release point (depth / focal length)."""
    cam = scene.camera
    if cam is None:
        raise GalileoError("the splash likelihood measures in pixels: the scene needs a camera")
    p = cam.world_to_camera[:3, :3] @ np.asarray(scene.release_m) + cam.world_to_camera[:3, 3]
    if not p[2] > 0:
        raise GalileoError("the release point is behind the scene's camera")
    return float(p[2] / math.sqrt(cam.K[0, 0] * cam.K[1, 1]))


def check_sigma(sigma) -> float:
    """The sigma (px) as a float: finite and within the scenario's noise limits (GalileoError
    otherwise: a NaN, infinite, zero or underflowing sigma makes every log-likelihood NaN
    or infinite)."""
    from ...latents import check_noise
    from . import SplashScenario

    try:
        return check_noise(SplashScenario.noise, sigma)
    except ValueError as e:
        raise GalileoError(f"likelihood: {e}") from None


class _Run(Run):
    """One run from the release, a physics step a tick; its state: the object's twist, position
    and orientation."""

    def __init__(self, lik: SplashLikelihood, stepper: FrameStepper):
        self.lik, self.stepper = lik, stepper
        self.state = None   # (position, orientation, linear, angular velocity) now

    def tick(self, k: int) -> tuple:
        if self.state is None:
            self.state = self.stepper.state()
        else:
            self._step()
        p, q, lin, ang = self.state
        return ((lin, ang),), p, q

    def _step(self) -> None:
        self.state = self.stepper.step(self.state)
        self.lik.steps += 1

    def poses(self) -> list:
        return [self.state[:2]]

    def skip(self, first: int, last: int) -> None:
        for _ in range(first, last + 1):
            self._step()


class SplashLikelihood(FrameLikelihood):
    """Callable log-likelihood over (area_cm2, density_g_cm3, drag_water, start_step)."""
    no_motion = "no object of this volume shows that area from below and fits the tank"

    def __init__(self, scene: SplashScene, tracks: Tracks, sigma_px: float = SIGMA_PX, speedups: bool = True,
                 cache_size: int = KEPT_MOTIONS):
        self.sigma_px = check_sigma(sigma_px)
        tracks.check()
        tracks.require_visible()
        if len(tracks.objects) != 1:
            raise GalileoError(f"splash tracks hold one object, got {len(tracks.objects)}")
        if abs(tracks.fps - scene.fps) > 1e-9:
            raise GalileoError(f"tracks at {tracks.fps:g} fps but the scene camera at {scene.fps:g} fps")
        self.scene = scene
        self.spf = int(round(scene.sim_hz / tracks.fps))
        # the simulation does not depend on the start step: its runs are kept for start proposals
        super().__init__(LATENT_NAMES, tracks.fps, tracks.n_frames, [scene.obj.name], speedups=speedups,
                         sim_latents=[n for n in LATENT_NAMES if n != "start_step"],
                         rest=RestRule(every=self.spf), motions=cache_size)
        mpp = metres_per_pixel(scene)
        self.sigma_x_m = self.sigma_px * mpp
        self.sigma_v_mps = self.sigma_px * mpp * self.fps
        obj = tracks.objects[0]
        self._obs = [(f, float(obj.position_m[f, 0]), float(obj.position_m[f, 2]), float(obj.velocity_mps[f, 0]),
                      float(obj.velocity_mps[f, 2])) for f in range(self.n_frames) if obj.visible[f]]
        self._by_frame = {o[0]: o[1:] for o in self._obs}
        self._hx = -0.5 / self.sigma_x_m ** 2
        self._hv = -0.5 / self.sigma_v_mps ** 2
        n = len(self._obs)
        self.log_norm = -2 * n * math.log(self.sigma_x_m * math.sqrt(2 * math.pi)) \
            - 2 * n * math.log(self.sigma_v_mps * math.sqrt(2 * math.pi))
        self.sim = Simulator(scene)
        self.horizon_start = int(scene.bounds["start_step"][1])

    def start(self, values: dict) -> _Run | None:
        stepper = self.sim.frames(values)
        return None if stepper is None else _Run(self, stepper)   # None: no object of this volume fits

    def alignment(self, values: dict) -> tuple[int, int]:
        """Frame f is physics step t + f spf."""
        return int(round(values["start_step"])), self.spf

    def horizon(self, values: dict) -> int:
        return self.horizon_start + (self.n_frames - 1) * self.spf

    def observe(self, f: int, state, noise) -> float:
        o = self._by_frame.get(f)
        if o is None:
            return 0.0
        p, v = state[1], state[0][0][0]
        dx, dz, du, dw = o[0] - p[0], o[1] - p[2], o[2] - v[0], o[3] - v[2]
        return (dx * dx + dz * dz) * self._hx + (du * du + dw * dw) * self._hv
