"""Likelihood of the splash (the seed's eq. 2): tracked positions and velocities against Bullet.

    log p(x_o, v_o | s, rho, D_w, k, t_r, u) = sum over frames f where the object was seen of
        log N(x_o[f] | x_s(f spf - r), sigma_x^2 I) + log N(v_o[f] | v_s(f spf - r), sigma_v^2 I)

on the x and z components (the image plane of the side camera; depth is not observed).
The simulation starts at the scene's release point moving down at the push u; frame f of
the video is physics step f * spf - r of it (r = round(t_r sim_hz): the release t_r, a
latent in seconds of video time; spf = sim_hz / fps steps per frame); frames before the
release (a negative step) show the object held still at the release point.

Units: the seed fixes Sigma = 1 without units. Here it is 1 in the video's own units: one
pixel for positions and one pixel per frame for velocities (the tracker's resolution), so
sigma_x = sigma_px * m_per_px and sigma_v = sigma_px * m_per_px * fps, where m_per_px is the
size of a pixel at the release point's depth (depth / focal length). `sigma_px` = 1, or more: the
tracker's own measure of its position noise (`Tracks.position_noise_m`, from the track's
roughness: a shaken, noisy, compressed or blurred video's) in pixels where that is larger.

The likelihood stands on `galileo.framelik.FrameLikelihood`, with a tick of one physics step
(the release shifts which steps the frames show; frames before it are its `before_start`;
frames between two steps are interpolated, `at_frame`). Its rest rule (as the ramp's) is
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
* reuse of what does not change with a latent: the simulation does not depend on the
  release time, only the alignment does. A run that completes goes on to the horizon (the
  earliest release the scene's prior allows + the video's length; a release before it, under
  bounds widened at run time, simulates afresh unless the run came to rest) and its every
  step is kept (keyed on the other latents); a proposal of the release time is then scored
  from the kept steps without simulating (frame by frame, stopping at the threshold).
"""
from __future__ import annotations

import math

import numpy as np

from ...datatypes import Tracks
from ...errors import GalileoError
from ...framelik import KEPT_MOTIONS, FrameLikelihood, RestRule, Run
from .physics import FrameStepper, Simulator, between
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


_ZERO = (0.0, 0.0, 0.0)


class _Run(Run):
    """One run from the release, a physics step a tick; its state: the object's twist, position
    and orientation, and the raw state of the tick before (None at tick 0), for the frames
    that fall between two ticks (`SplashLikelihood.at_frame`)."""

    def __init__(self, lik: SplashLikelihood, stepper: FrameStepper):
        self.lik, self.stepper = lik, stepper
        self.state = None   # (position, orientation, linear, angular velocity) now

    def tick(self, k: int) -> tuple:
        before = self.state
        if before is None:
            self.state = self.stepper.state()
        else:
            self._step()
        p, q, lin, ang = self.state
        return ((lin, ang),), p, q, before

    def _step(self) -> None:
        self.state = self.stepper.step(self.state)
        self.lik.steps += 1

    def poses(self) -> list:
        return [self.state[:2]]

    def skip(self, first: int, last: int) -> None:
        for _ in range(first, last + 1):
            self._step()


class SplashLikelihood(FrameLikelihood):
    """Callable log-likelihood over the splash's latents (scene.LATENT_NAMES)."""
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
        # the simulation does not depend on the release time: its runs are kept for its proposals
        super().__init__(LATENT_NAMES, tracks.fps, tracks.n_frames, [scene.obj.name], speedups=speedups,
                         sim_latents=[n for n in LATENT_NAMES if n != "release_s"],
                         rest=RestRule(every=self.spf), motions=cache_size)
        mpp = metres_per_pixel(scene)
        # at least the noise the tracker measured on its own track (a shaken, noisy or compressed video's), so
        # that intervals widen instead of lying
        self.sigma_px = max(self.sigma_px, tracks.position_noise_m() / mpp)
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
        self.horizon_start = max(0, scene.frame_ticks(scene.bounds["release_s"][0])[0])
        pose = (tuple(float(x) for x in scene.release_m), scene.release_orientation())
        # before the release: held still at the release point, as placed (one body's twist)
        self._held = ((((0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),),) + pose + ((pose[0], pose[1], _ZERO, _ZERO),)
        self._ticks = (math.nan, 0.0)   # (release_s, a) of the last `at_frame`

    def start(self, values: dict) -> _Run | None:
        stepper = self.sim.frames(values)
        return None if stepper is None else _Run(self, stepper)   # None: no object of this volume fits

    def alignment(self, values: dict) -> tuple[int, int]:
        """Frame f is seen at tick k + f spf of the run (`scene.frame_ticks`: it falls a
        fraction a of a step before it, `at_frame` interpolates)."""
        return self.scene.frame_ticks(values["release_s"])[0], self.spf

    def before_start(self, values: dict) -> tuple:
        """Frames before the release: the object held still at the release point, as placed."""
        return self._held, [self._held[1:3]]

    def held(self, state) -> tuple:
        """At rest: zero twist, the pose of that tick (the tick before it too)."""
        p, q = state[1], state[2]
        return (((_ZERO, _ZERO),), p, q, (p, q, _ZERO, _ZERO))

    def at_frame(self, state, values: dict) -> tuple:
        """The frame's state: a fraction a of a step before the tick's (`scene.frame_ticks`),
        linear between the two ticks around it (`physics.between`); before the release (tick 0
        with a > 0), held still."""
        release_s = values["release_s"]
        if release_s != self._ticks[0]:   # once an evaluation, not once a frame
            self._ticks = (release_s, self.scene.frame_ticks(release_s)[1])
        a = self._ticks[1]
        if a == 0.0:
            return state
        if state[3] is None:
            return self._held
        (lin, ang), = state[0]
        p, q, lin, ang = between(a, (state[1], state[2], lin, ang), state[3])
        return ((lin, ang),), p, q, state[3]

    def frame_poses(self, seen, run) -> list:
        return [(seen[1], seen[2])]

    def horizon(self, values: dict) -> int:
        return max(0, self.horizon_start + (self.n_frames - 1) * self.spf)

    def observe(self, f: int, state, noise) -> float:
        o = self._by_frame.get(f)
        if o is None:
            return 0.0
        p, v = state[1], state[0][0][0]
        dx, dz, du, dw = o[0] - p[0], o[1] - p[2], o[2] - v[0], o[3] - v[2]
        return (dx * dx + dz * dz) * self._hx + (du * du + dw * dw) * self._hv
