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

The rest rule (as the ramp's), checked on the simulation's own frames (every spf steps from
the release, whatever t): once, for two consecutive such frames, the object moves slower
than REST_MPS, turns slower than REST_RADPS and is not speeding up, later steps hold its
last position at zero velocity. A (s, h) pair with no object that fits the tank
(`scene.dimensions`) has prior density 0: -inf without simulating.

Exact speed-ups (`speedups=True`; the same accept/reject decisions and values as the plain
path, which simulates every frame of every proposal from the release):

* early rejection: every frame adds a term <= 0; the run stops once the partial sum falls
  below the MH threshold.
* at-rest cut-off: after the rest rule holds, the remaining frames are known without stepping.
* reuse of what does not change with a latent: the simulation does not depend on t, only the
  alignment does. A run that completes goes on to the horizon (the start's prior upper
  bound in the scene file + the video's length; a start beyond it, under bounds widened
  at run time, simulates afresh) and its every step is kept (keyed on s, rho, D_w); a proposal
  of t is then scored from the kept steps without simulating.
"""
from __future__ import annotations

import math
from collections import OrderedDict

import numpy as np

from ...datatypes import Tracks, Trajectory
from ...errors import GalileoError
from ...sim.bullet import client_lock
from .physics import Simulator
from .scene import LATENT_NAMES, SplashScene

REST_MPS = 1e-3        # linear speed below which the object counts as at rest (m/s)
REST_RADPS = 0.02      # and angular speed (rad/s)
REST_CREEP_MPS = 5e-5  # ... as long as its speed grew by no more than this since the frame before
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


class SplashLikelihood:
    """Callable log-likelihood over (area_cm2, density_g_cm3, drag_water, start_step)."""

    def __init__(self, scene: SplashScene, tracks: Tracks, sigma_px: float = SIGMA_PX, speedups: bool = True,
                 cache_size: int = 4):
        self.sigma_px = check_sigma(sigma_px)
        tracks.check()
        tracks.require_visible()
        if len(tracks.objects) != 1:
            raise GalileoError(f"splash tracks hold one object, got {len(tracks.objects)}")
        self.scene = scene
        self.names = LATENT_NAMES
        self.fps = tracks.fps
        if abs(self.fps - scene.fps) > 1e-9:
            raise GalileoError(f"tracks at {tracks.fps:g} fps but the scene camera at {scene.fps:g} fps")
        self.n_frames = tracks.n_frames
        self.speedups = speedups
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
        self.spf = int(round(scene.sim_hz / self.fps))
        self.horizon_start = int(scene.bounds["start_step"][1])
        self._kept: OrderedDict[tuple, tuple] = OrderedDict()
        self._cache_size = cache_size

    @property
    def steps(self) -> int:
        return self.sim.steps

    def values_of(self, position) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.names, position)}

    def _term(self, f: int, p, v) -> float:
        o = self._by_frame.get(f)
        if o is None:
            return 0.0
        dx, dz, du, dw = o[0] - p[0], o[1] - p[2], o[2] - v[0], o[3] - v[2]
        return (dx * dx + dz * dz) * self._hx + (du * du + dw * dw) * self._hv

    def __call__(self, position, threshold: float | None = None):
        """(log-likelihood, stopped_early); see the module docstring. Thread-safe, as `motion`."""
        values = self.values_of(position)
        limit = -math.inf if (threshold is None or not self.speedups) else threshold
        with client_lock:
            total, early, _ = self._evaluate(values, limit)
        return self.log_norm + total, early

    def _evaluate(self, values: dict, limit: float, record: bool = False):
        """Sum of the per-frame terms (without the normaliser); stops early once the value
        (normaliser + partial sum, an upper bound) falls below `limit`, the MH threshold."""
        t = int(round(values["start_step"]))
        key = (values["area_cm2"], values["density_g_cm3"], values["drag_water"])
        n, spf = self.n_frames, self.spf
        last = t + (n - 1) * spf                  # the step shown as the video's last frame
        kept = self._kept.get(key) if self.speedups else None
        if kept is not None and kept[0].shape[0] > last:
            self._kept.move_to_end(key)
            pos, vel, orn = kept
            total = 0.0
            for f in range(n):
                k = t + f * spf
                total += self._term(f, pos[k], vel[k])
                if self.log_norm + total < limit:   # the kernel's own test: value < threshold
                    return total, True, None
            return total, False, self._shown(kept, t) if record else None
        stepper = self.sim.frames(values)
        if stepper is None:   # no object of this volume shows that area and fits: prior 0
            return -math.inf, False, None
        horizon = max(last, self.horizon_start + (n - 1) * spf) if self.speedups else last
        pos, vel, orn = np.empty((horizon + 1, 3)), np.empty((horizon + 1, 3)), np.empty((horizon + 1, 4))
        total = 0.0
        rest_run, speed_before, rest_at = 0, math.inf, None
        state = stepper.state()
        f = 0                                     # the next video frame to score
        for k in range(horizon + 1):
            if rest_at is None:
                if k:
                    state = stepper.step(state)
                p, q, lin, ang = state
                pos[k], orn[k], vel[k] = p, q, lin
                if k % spf == 0:                  # the rest rule on the simulation's own frames
                    speed = math.sqrt(lin[0] * lin[0] + lin[1] * lin[1] + lin[2] * lin[2])
                    slow = (speed < REST_MPS and speed <= speed_before + REST_CREEP_MPS
                            and ang[0] * ang[0] + ang[1] * ang[1] + ang[2] * ang[2] < REST_RADPS ** 2)
                    speed_before = speed
                    rest_run = rest_run + 1 if (k and slow) else 0
                    if rest_run >= 2:             # at rest: this step and all later ones hold still
                        rest_at = k
                        vel[k] = 0.0
            else:
                pos[k], orn[k], vel[k] = pos[rest_at], orn[rest_at], 0.0
                if not self.speedups:             # the plain path steps through the rest all the same
                    state = stepper.step(state)
            if k == t + f * spf and f < n:
                total += self._term(f, pos[k], vel[k])
                f += 1
                if self.log_norm + total < limit:   # the kernel's own test: value < threshold
                    return total, True, None
        if self.speedups:
            self._kept[key] = (pos, vel, orn)
            while len(self._kept) > self._cache_size:
                self._kept.popitem(last=False)
        return total, False, self._shown((pos, vel, orn), t) if record else None

    def _shown(self, kept, t: int):
        """The kept steps shown as video frames 0..F-1 with start step t."""
        idx = t + np.arange(self.n_frames) * self.spf
        return tuple(a[idx] for a in kept)

    def motion(self, position) -> Trajectory:
        """The simulated motion as scored: video frames 0..F-1 (physics steps t + f spf).
        Thread-safe (the process's Bullet client is held for the simulation)."""
        values = self.values_of(position)
        with client_lock:
            _, _, rec = self._evaluate(values, -math.inf, record=True)
        if rec is None:
            raise GalileoError("no object of this volume shows that area from below and fits the tank")
        pos, vel, orn = rec
        return Trajectory(self.fps, [self.scene.obj.name], pos[None].copy(), vel[None].copy(), orn[None].copy())
