"""The spring's likelihood: the simulated centre against the tracked centre, in the spring's
plane (the tracker's pixels back-projected through the video's camera), frame by frame from the
release on; residuals counted in pixels (metres times the camera's pixels per metre at the
hanging point).

Residuals r_f = (across, up-down) follow an AR(1) process: r_f = rho r_(f-1) + e_f, with e_f's
components N(0, sigma_a^2 (1 - rho^2)), so each r_f component is N(0, sigma_a^2) and neighbouring
frames are correlated by rho. A tracker's error and a model's small misfits (a bag that swings, a
spring that bends) are smooth over a few frames; treating them as independent would count each
misfit many times and make intervals too narrow. The tracked centre may sit a constant few
pixels from the body's (ox_px, oz_px: a bag's outline, the tracker's idea of a centre). The sway and the bounce get their own sigma
(log10_sigma_x_px, log10_sigma_z_px): the sway is the least faithful part of the model (a coil
spring bends, a bag swings about its knot), and its misfit must not widen the bounce's. The
noise latents and rho are per video and do not enter the simulation (a proposal that changes only
them is scored from the kept run, `galileo.framelik`). A frame whose predecessor was not seen
starts afresh. The scenario's noise (`sigma_px`, the tracker's precision) is a floor: each SD is
sqrt(sigma_px^2 + (10 ** log10_sigma_a_px)^2).

Each term is -e^2 / (2 var) <= 0 and the normaliser is
    -n/2 (log 2 pi sigma_x^2 + log 2 pi sigma_z^2) - m log(1 - rho^2)
(n frames seen, m of them after a seen frame), so early rejection applies.
"""
from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from ...datatypes import Tracks
from ...errors import GalileoError
from ...framelik import FrameLikelihood, RestRule, Run
from . import physics
from .scene import NOISE_LATENTS, SpringScene, px_per_m

# the spring never rests inside a clip (its damping is small): the rest rule is off (checked at tick 0 only)
NO_REST = RestRule(speed_mps=0.0, every=1 << 40)
_STILL_W = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class _Noise:
    log_norm: float
    ox: float    # the tracker's constant offset (metres in the plane), across and up
    oz: float
    x0: float    # -1 / (2 sigma_x^2): a frame after an unseen one
    z0: float
    x1: float    # -1 / (2 sigma_x^2 (1 - rho^2)): the innovation's
    z1: float
    rho: float


class _SpringRun(Run):
    def __init__(self, run: physics.Run, top, scale: float, lik: SpringLikelihood):
        self.run = run
        self.top = top
        self.inv_scale = 1.0 / scale
        self.pos = None
        self.lik = lik     # its `steps` counts the physics steps taken

    def tick(self, k: int) -> tuple:
        if k > self.run.release:
            self.lik.steps += self.run.spf
        pos, vel = self.run.frame(k)
        tx, ty, tz = self.top
        s = self.inv_scale
        self.pos = (tx + s * (pos[0] - tx), ty + s * (pos[1] - ty), tz + s * (pos[2] - tz))
        return (((s * vel[0], s * vel[1], s * vel[2]), _STILL_W),), self.pos

    def poses(self) -> list:
        return [(self.pos, physics.IDENTITY)]


class SpringLikelihood(FrameLikelihood):
    """log p(tracked centres | latents) for one video (see the module docstring); positions the
    motion shows are in the scene's units (where the camera sees them)."""

    def __init__(self, scene: SpringScene, tracks: Tracks, names, floor_px: float, speedups: bool = True):
        names = tuple(names)
        super().__init__(names, tracks.fps, tracks.n_frames, [physics.BODY], speedups=speedups,
                         sim_latents=[n for n in names if n not in NOISE_LATENTS], rest=NO_REST)
        if scene.camera is None:
            raise GalileoError("the spring scene has no camera: make one with `galileo scene VIDEO --scenario "
                               "spring` (clicks) or give \"camera\" in the scene file")
        self.scene = scene
        obj = tracks.objects[0]
        self.seen = np.asarray(obj.visible, bool).copy()
        self.seen[: scene.release_frame] = False
        cam = scene.camera
        self.px_per_m = px_per_m(cam, scene.top_in_world_m)     # residuals in pixels
        pos = np.nan_to_num(np.asarray(obj.position_m, float))
        self.obs = [(float(p[0]), float(p[2])) for p in pos]
        n = int(self.seen.sum())
        after = int((self.seen[1:] & self.seen[:-1]).sum())
        if n < 3:
            raise GalileoError(f"the object is seen in {n} frames after the release (frame {scene.release_frame}): "
                               f"too few to infer from")
        self.n_seen, self.n_after = n, after
        self._prev = None
        self._noises: OrderedDict[tuple, _Noise] = OrderedDict()
        self.floor2 = float(floor_px) ** 2

    # -- the noise --------------------------------------------------------------------------
    def noise_of(self, values: dict) -> _Noise:
        key = (values["log10_sigma_x_px"], values["log10_sigma_z_px"], values["rho"], values["ox_px"], values["oz_px"])
        noise = self._noises.get(key)
        if noise is None:
            sx2 = (self.floor2 + 10.0 ** (2 * key[0])) / self.px_per_m ** 2   # in metres^2
            sz2 = (self.floor2 + 10.0 ** (2 * key[1])) / self.px_per_m ** 2
            rho = key[2]
            one_m = 1.0 - rho * rho
            log_norm = (-0.5 * self.n_seen * (math.log(2 * math.pi * sx2) + math.log(2 * math.pi * sz2))
                        - self.n_after * math.log(one_m))
            noise = self._noises[key] = _Noise(log_norm, key[3] / self.px_per_m, key[4] / self.px_per_m, -0.5 / sx2,
                                               -0.5 / sz2, -0.5 / (sx2 * one_m), -0.5 / (sz2 * one_m), rho)
            while len(self._noises) > 16:
                self._noises.popitem(last=False)
        return noise

    # -- the run -------------------------------------------------------------------------------
    def start(self, values: dict):
        scene = self.scene
        p = physics.params(scene, {k: v for k, v in values.items() if k not in NOISE_LATENTS}, checked=False)
        if p.inertial_kg <= 0 or p.k_Npm <= 0:
            return None
        run = physics.Run(p, scene.sim_hz, self.fps, scene.release_frame)
        self._prev = None
        return _SpringRun(run, scene.top_in_world_m, values.get("scale", scene.scale), self)

    def observe(self, f: int, state, noise: _Noise) -> float:
        if not self.seen[f]:
            self._prev = None
            return 0.0
        pos = state[1]
        ox, oz = self.obs[f]
        rx, rz = ox - pos[0] - noise.ox, oz - pos[2] - noise.oz
        prev = self._prev if (f and self.seen[f - 1]) else None
        self._prev = (rx, rz)
        if prev is None:
            return noise.x0 * rx * rx + noise.z0 * rz * rz
        ex, ez = rx - noise.rho * prev[0], rz - noise.rho * prev[1]
        return noise.x1 * ex * ex + noise.z1 * ez * ez

    def residuals_px(self, position) -> np.ndarray:
        """(F, 2) tracked minus simulated centre and offset (across, up), pixels at the hanging
        point's scale, NaN where not seen (for plots and tests)."""
        traj = self.motion(position)
        noise = self.noise_of(self.values_of(position))
        out = (np.asarray(self.obs) - traj.position_m[0][:, [0, 2]] - (noise.ox, noise.oz)) * self.px_per_m
        out[~self.seen] = np.nan
        return out
