"""The fall's likelihood: the simulated centre, projected through the video's camera, against
the tracked silhouette centroid, in pixels, frame by frame from the release on.

Why pixels: the tracker measures pixels, and a point lifted to 3-D (`tracks.py`) needs an
assumption about its depth (on the surface, or on the line of the fall) that the simulation
does not; projecting the simulated centre needs none. The tracks' 3-D points lie on the
pixels' rays, so projecting them back gives the tracked pixels exactly.

Motion blur: a frame integrates over its exposure (half a frame interval, centred on the
frame's time in the rendered dataset); the blurred silhouette's centroid is the mean position
over the exposure, which differs from the position at the frame's time by g T^2 / 24 (0.01 mm
for T = 1/60 s) in free fall; at an impact the difference is a few pixels for a frame or two,
which the noise model takes.

Residuals r_f = (u, v) follow an AR(1) process: r_f = rho r_(f-1) + e_f, with e_f's components
N(0, sigma^2 (1 - rho^2)), so each component is N(0, sigma^2) and neighbouring frames are
correlated by rho (a tracker's error and a model's small misfits are smooth over a few frames;
treating them as independent would count each misfit many times and make intervals too narrow).
The centroid may sit a constant few pixels from the projected centre (ox_px, oy_px: a
silhouette's centroid is not its 3-D centre's image; a shadow). sigma = sqrt(sigma_px^2 +
10^(2 log10_sigma_px)), the scenario's noise (the tracker's precision) a floor. A frame whose
predecessor was not seen starts afresh. The noise latents do not enter the simulation (a
proposal that changes only them is scored from the kept run, `galileo.framelik`).

The object comes to rest: the kit's rest rule holds it still from then on (no more physics).
"""
from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from ...datatypes import Tracks
from ...errors import GalileoError
from ...framelik import FrameLikelihood, Run
from . import physics
from .scene import NOISE_LATENTS, FallScene


@dataclass(frozen=True)
class _Noise:
    log_norm: float
    ox: float
    oy: float
    a0: float    # -1 / (2 sigma^2): a frame after an unseen one
    a1: float    # -1 / (2 sigma^2 (1 - rho^2)): the innovation's
    rho: float


class _FallRun(Run):
    def __init__(self, run: physics.Run, lik: FallLikelihood):
        self.run = run
        self.lik = lik

    def tick(self, k: int) -> tuple:
        if k > self.run.release:
            self.lik.steps += self.run.spf
        pos, orn, vel, spin = self.run.frame(k)
        return ((vel, spin),), pos, orn

    def poses(self) -> list:
        return [(self.run.pos, self.run.orn)]


def camera_rows(camera) -> np.ndarray:
    """The camera's 3 x 4 projection matrix K [R | t] (pinhole: `FallLikelihood.project`
    applies the lens's distortion after it)."""
    return camera.K @ camera.world_to_camera[:3, :]


class FallLikelihood(FrameLikelihood):
    """log p(tracked centroids | latents) for one video (see the module docstring)."""

    def __init__(self, scene: FallScene, tracks: Tracks, names, floor_px: float, speedups: bool = True):
        names = tuple(names)
        super().__init__(names, tracks.fps, tracks.n_frames, [physics.BODY], speedups=speedups,
                         sim_latents=[n for n in names if n not in NOISE_LATENTS])
        if scene.camera is None:
            raise GalileoError("the fall scene has no camera: make one with `galileo scene VIDEO --scenario fall` "
                               "(four corners of the surface) or give \"camera\" in the scene file")
        self.scene = scene
        obj = tracks.objects[0]
        self.seen = np.asarray(obj.visible, bool).copy()
        self.seen[: scene.release_frame] = False
        self.P = camera_rows(scene.camera)
        self.camera = scene.camera
        pos = np.nan_to_num(np.asarray(obj.position_m, float))
        uv = scene.camera.project(pos)
        self.obs = [(float(a), float(b)) for a, b in uv]
        n = int(self.seen.sum())
        if n < 3:
            raise GalileoError(f"the object is seen in {n} frames after the release (frame {scene.release_frame}): "
                               "too few to infer from")
        self.n_seen = n
        self.n_after = int((self.seen[1:] & self.seen[:-1]).sum())
        self._prev = None
        self._noises: OrderedDict[tuple, _Noise] = OrderedDict()
        self.floor2 = float(floor_px) ** 2

    def noise_of(self, values: dict) -> _Noise:
        key = (values["log10_sigma_px"], values["rho"], values["ox_px"], values["oy_px"])
        noise = self._noises.get(key)
        if noise is None:
            s2 = self.floor2 + 10.0 ** (2 * key[0])
            rho = key[1]
            one_m = 1.0 - rho * rho
            log_norm = -self.n_seen * math.log(2 * math.pi * s2) - self.n_after * math.log(one_m)
            noise = self._noises[key] = _Noise(log_norm, key[2], key[3], -0.5 / s2, -0.5 / (s2 * one_m), rho)
            while len(self._noises) > 16:
                self._noises.popitem(last=False)
        return noise

    def start(self, values: dict):
        scene = self.scene
        p = physics.params(scene, {k: v for k, v in values.items() if k not in NOISE_LATENTS}, checked=False)
        if physics.start_problem(p, scene.shape):
            return None
        self._prev = None
        return _FallRun(physics.Run(p, scene.shape, scene.sim_hz, self.fps, scene.release_frame), self)

    def project(self, pos) -> tuple[float, float]:
        """The pixel of a world point: `Camera.project`, unrolled for one point (a pinhole's
        pixel in plain floats, then the lens's distortion where there is one)."""
        P = self.P
        x, y, z = pos
        w = P[2, 0] * x + P[2, 1] * y + P[2, 2] * z + P[2, 3]
        uv = ((P[0, 0] * x + P[0, 1] * y + P[0, 2] * z + P[0, 3]) / w,
              (P[1, 0] * x + P[1, 1] * y + P[1, 2] * z + P[1, 3]) / w)
        if self.camera.k1 == 0.0:
            return uv
        u, v = self.camera.distort_px(uv)
        return float(u), float(v)

    def observe(self, f: int, state, noise: _Noise) -> float:
        if not self.seen[f]:
            self._prev = None
            return 0.0
        u, v = self.project(state[1])
        ou, ov = self.obs[f]
        ru, rv = ou - u - noise.ox, ov - v - noise.oy
        prev = self._prev if (f and self.seen[f - 1]) else None
        self._prev = (ru, rv)
        if prev is None:
            return noise.a0 * (ru * ru + rv * rv)
        eu, ev = ru - noise.rho * prev[0], rv - noise.rho * prev[1]
        return noise.a1 * (eu * eu + ev * ev)

    def residuals_px(self, position) -> np.ndarray:
        """(F, 2) tracked minus simulated centre and offset, pixels, NaN where not seen."""
        traj = self.motion(position)
        noise = self.noise_of(self.values_of(position))
        sim = np.array([self.project(p) for p in traj.position_m[0]])
        out = np.asarray(self.obs) - sim - (noise.ox, noise.oy)
        out[~self.seen] = np.nan
        return out
