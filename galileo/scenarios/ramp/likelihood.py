"""Likelihood: tracked velocities against Bullet simulations (Galileo eq. 1).

    log p(v_obs | m1, k1, m2, k2) = sum over visible frames f and objects o of
        log N(v_obs[o, f] | v_sim[o, f], sigma^2 I)

on the x and z velocity components (the fall-line plane; the tracker reports y = 0).
`sigma_mps` is the paper's Sigma = 0.05, read as a standard deviation in m/s (so the
variance is 0.0025 m^2/s^2), or more: the velocity noise the tracker measured on its own
tracks (`Tracks.velocity_noise_mps`, from their roughness: a shaken, noisy, compressed or
blurred video's) where that is larger. The simulation runs as many frames as the video; frames
where an object was not seen are left out. Shapes and the ramp object's offset are fixed
from tracking (section 3.1).

Model mismatch (the scene's priors). `observation = "student_t"` (the default since issue
12: it measured better on interval coverage and accuracy; "gaussian" is the paper's, above,
and what `--moves paper` uses) replaces each component's normal by a Student-t of
`student_t_dof` (nu, default 4) degrees of freedom and scale sigma:

    log t(r; nu, sigma) = log G((nu+1)/2) - log G(nu/2) - 1/2 log(nu pi) - log sigma
                          - (nu+1)/2 log(1 + r^2 / (nu sigma^2)),    r = v_obs - v_sim.

`infer_sigma` makes sigma a latent (log10_sigma_mps, the last one; the fixed `sigma_mps` is
then unused); `infer_restitution` adds e_collision (the collision's restitution, see
`Scene.collision_restitution`), which only phase B (below) uses: phase A runs with the
scene's own restitutions (the slide's combined restitutions are the same either way), so
the world at the switch still depends on k1 alone. Either model's value is the normaliser
(n components times the t's first line, or times -log sigma - 1/2 log(2 pi) for the
normal: it depends on sigma alone) plus a sum of per-frame terms, each <= 0, that depend
on sigma only through a factor applied to sigma-free per-frame residuals (gaussian: the
frame's sum of squared residuals r^2, times -1/(2 sigma^2); student_t: the frame's r^2 per
component, each through log1p(r^2 / (nu sigma^2)), times -(nu+1)/2).

The model treats a world at rest as staying at rest (`galileo.framelik`'s rest rule, checked
every frame): once, for two consecutive frames, every object moves slower than REST_MPS
(1 mm/s, sigma / 50), turns slower than REST_RADPS (0.02 rad/s: 1 mm/s at 5 cm from the
centre) and is not speeding up (by more than REST_CREEP_MPS per frame), later frames hold
the last positions with zero velocity (a deterministic version of Bullet's sleeping). Both
paths below apply it. Bullet's resting contacts relax (the speed halves every frame) and
often leave a slow yaw drift behind a collision (~1e-3 rad/s, 1e-4 m/s); the rule ends
those runs. An object on the verge of sliding (friction within ~2e-4 of tan of the ramp
angle) creeps slower than the rule sees and counts as at rest: it would move about 3 mm in
2 s.

The model runs in two phases. Phase A, until the objects come within reach of each other
(closest distance <= what their speeds, spins and g could close in one physics step, plus
SWITCH_MARGIN_M; tested each frame for one frame's reach, then step by step): they cannot
interact yet, so the ramp object slides alone with unit mass and the target's motion alone
(at rest on the ground, with unit mass and friction PHASE_A_TARGET_FRICTION) is simulated
once per likelihood. Phase B, from that physics step on: the world restarts from both
objects' poses and velocities (`Simulator.resume`: contacts start cold) with the
proposal's values. Masses and the target's friction change nothing before the objects
meet (sliding is mass-independent; the target rests), so the world at the switch depends
on k1 alone. Against one uninterrupted Bullet run with the proposal's own values, the
differences are: rounding before contact (masses change the solver's rounding by ~1e-15),
which a collision amplifies to about what a one-ulp nudge of the inputs does; the cold
contacts (a few millimetres in a collision, the size of Bullet's own solver tolerance);
when the bounding boxes overlap a few steps before the switch, Bullet solves the two
bodies as one island, which changes the resting target's spin by ~1e-3 rad/s; and a target
with friction below ~0.27 slips ~1e-5 m while settling, so its resting motion depends
slightly on its friction. tests/test_inference.py checks the motion bit for bit against
Bullet runs with phase A's own values, and within the one-ulp bound against the
proposal's.

The simulator reads the ramp object's friction to K1_DECIMALS (5) decimal places: the
likelihood at k1 is the one at round(k1, 5), in every path (the MH kernel's, `motion`'s), so
the posterior density is constant on cells 1e-5 wide. That is 100 times finer than k1's
posterior sd on a video (about 1e-3; a narrow mode's about 1e-4) and 20 times finer than the
jaggedness Bullet's collisions put into the likelihood (10-16 nats between k1 values 2e-4
apart), so it changes no posterior (BENCHMARKS.md: quantiles, SBC) while it lets the
slide before the collision, which depends on k1 alone, be simulated once per cell and
reused: a proposal to a k1 visited recently (K1_PREFIXES kept per process) resumes at the
switch. A k1 given to 5 decimals or fewer (0.25, 0.21865) is used as given.

The likelihood stands on `galileo.framelik.FrameLikelihood` (a tick is a video frame; the
phases are its run, phase A branching into phase B at the switch), which owns the frame
loop, the lock, `motion` and the exact speed-ups (`speedups=True`; each gives the same
accept/reject decisions as the plain path, `speedups=False`, which simulates every frame of
every proposal):

* early rejection: every frame adds a term <= 0 (either model), so the normaliser plus the
  partial sum is an upper bound of the final value; the simulation stops once it falls
  below the MH threshold.
* at-rest cut-off: once the world is at rest, the remaining frames are known without
  stepping: their terms at zero simulated velocity, summed from the observations for the
  proposal's sigma (`rest_sum`; gaussian: -1/(2 sigma^2) times a sigma-free sum; student_t:
  computed once per sigma).
* prefix reuse: a proposal with the k1 of a recent one (every proposal of m1, m2, k2,
  e_collision and sigma, and one of k1 to a cell visited before) resumes from the snapshot
  at the switch, with the sigma-free residuals of the frames up to there kept (each frame's
  state holds its residual) and turned into terms for the proposal's sigma exactly as the
  plain path does at its switch.
  Without a switch (no target, or the object stops short of it) the whole result depends
  only on k1 (and sigma): its residuals are reused whole.
* run reuse (with the sigma latent): a proposal whose latents other than sigma are those of
  a recent full evaluation (every proposal of sigma) takes its residuals and needs no
  physics at all; the terms are summed whole, in the plain path's order.

Both paths evaluate the terms and sums by the same code in the same order (the frames
before the switch summed by numpy, those after one by one), so they give the same value
bit for bit.
"""
from __future__ import annotations

import dataclasses
import math
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from ...datatypes import Tracks
from ...errors import GalileoError
from ...framelik import KEPT_PREFIXES, FrameLikelihood, Kept, Run
from ...sim.bullet import client_lock, pb
from .physics import Simulator
from .scene import Scene

SIGMA_MPS = 0.05
SIGMA_LATENT = "log10_sigma_mps"   # the sigma latent (`Priors.infer_sigma`): sigma = 10 ** it
UNIT_MASS_KG = 1.0   # the masses phase A runs with (see VelocityLikelihood._phase_a_values)
PHASE_A_TARGET_FRICTION = 1.0   # and the target's friction (it rests on the ground until hit)
SWITCH_MARGIN_M = 0.01          # phase A ends this much before one frame's reach
K1_DECIMALS = 5                 # the simulator reads k1 to this many decimals (see the module docstring)
K1_PREFIXES = 2048              # slides (phase A, one per k1 cell) kept per process for prefix reuse (about 21 kB
                                # each, 43 MB in all). On the demo a worker's 8 chains propose 1,400-3,000 cells after
                                # the warm-up; a slide is simulated anew for 7% of proposals (10% with 1,024 kept,
                                # 6% with 4,096)


def scene_for_inference(scene: Scene, tracks: Tracks) -> Scene:
    """The scene with the shapes and offset that tracking measured (fixed during MCMC);
    checks that the tracks hold together (`Tracks.check`), saw something
    (`Tracks.require_visible`) and fit the scene: the camera's frame rate, a track per
    scene object (by role; tracks of other roles are not used), the ramp's shape types, an
    offset within the scene's prior, shapes that the scene can hold (the ramp object on the
    ramp)."""
    tracks.check()
    tracks.require_visible()
    if scene.camera is not None and abs(tracks.fps - scene.camera.fps) > 1e-9 * scene.camera.fps:
        raise GalileoError(f"tracks at {tracks.fps:g} fps but the scene camera at {scene.camera.fps:g} fps")
    objs = list(scene.objects)
    for i, obj in enumerate(objs):
        tr = next((t for t in tracks.objects if t.role == obj.role), None)
        if tr is None:
            raise GalileoError(f"the tracks have no {obj.role} object for scene object {obj.name!r}")
        problem = tr.shape.problem()   # (the tracks may name a type no scenario has registered)
        if problem:
            raise GalileoError(f"tracks: object {tr.name!r}: shape: {problem}")
        change = {"shape": tr.shape}
        if obj.role == "ramp" and tr.offset_units is not None:
            lo, hi = scene.priors.offset_units
            if not lo <= tr.offset_units <= hi and tr.offset_units != obj.offset_units:   # (held still: the scene's)
                raise GalileoError(f"tracks: object {tr.name!r}: offset_units {tr.offset_units} is outside the scene's "
                                   f"priors.offset_units [{lo}, {hi}]")
            change["offset_units"] = int(tr.offset_units)
        objs[i] = dataclasses.replace(obj, **change)
    new = dataclasses.replace(scene, objects=tuple(objs))
    try:
        new.validate()
    except GalileoError as e:   # the scene itself was valid: what the tracks put in is not
        raise GalileoError(f"the tracked shapes and offset do not fit the scene: {e}") from None
    return new


def check_sigma(sigma) -> float:
    """The fixed sigma (m/s) as a float: finite and within the scenario's noise limits
    (GalileoError otherwise: a NaN, infinite, zero or underflowing sigma makes every
    log-likelihood NaN or infinite)."""
    from ...latents import check_noise
    from . import RampScenario

    try:
        return check_noise(RampScenario.noise, sigma)
    except ValueError as e:
        raise GalileoError(f"likelihood: {e}") from None


@dataclass
class _Switch(Kept):
    """Where phase A ended (a `Kept` prefix): `snapshot` holds both objects' poses and
    velocities `substeps` physics steps after frame first_b - 1."""
    substeps: int = 0


class _Noise:
    """What the terms need of one sigma: the normaliser, the factor on the residuals and
    (computed when first needed) the rest rule's sums."""
    __slots__ = ("sigma", "log_norm", "scale", "rest")

    def __init__(self, sigma: float, log_norm: float, scale: float):
        self.sigma, self.log_norm, self.scale = sigma, log_norm, scale
        self.rest: list | None = None


class _Run(Run):
    """One run of the two phases (a tick is a video frame; its state: the objects' twists and
    the frame's sigma-free residual). Phase A (`phase_a`, with a target): the ramp object
    slides alone, the target's motion is the likelihood's `_target_alone`; it branches where
    the objects come within one frame's reach of each other. Phase B: both objects, the
    proposal's values, resumed `substeps` physics steps into its first frame."""

    def __init__(self, lik: VelocityLikelihood, w, phase_a: bool, substeps: int = 0):
        self.lik, self.w, self.phase_a, self.substeps = lik, w, phase_a, substeps
        self.k = 0

    def tick(self, k: int) -> tuple:
        lik, cid, bodies = self.lik, self.w.cid, self.w.bodies
        if k:
            todo = lik.spf - self.substeps
            self.substeps = 0
            for _ in range(todo):
                pb.stepSimulation(physicsClientId=cid)
            lik.steps += todo
        self.k = k
        if self.phase_a:
            twists = [pb.getBaseVelocity(bodies[0], physicsClientId=cid), lik._target_alone[k * lik.spf][1]]
        else:
            twists = [pb.getBaseVelocity(b, physicsClientId=cid) for b in bodies]
        return twists, lik._residual(k, [t[0] for t in twists])

    def poses(self) -> list:
        lik, cid = self.lik, self.w.cid
        out = [pb.getBasePositionAndOrientation(b, physicsClientId=cid) for b in self.w.bodies]
        if self.phase_a:
            out[1] = lik._target_alone[self.k * lik.spf][0]
        return out

    def branch(self, k: int, state) -> _Switch | None:
        lik = self.lik
        if not self.phase_a or k >= lik.n_frames - 1 or not lik._within(self.w, state[0], k * lik.spf,
                                                                        1.0 / lik.fps):
            return None
        substeps = lik._refine_switch(self.w, k)
        pose, twist = lik._target_alone[k * lik.spf + substeps]
        return _Switch(snapshot=(lik.sim.snapshot()[0], pose + twist), substeps=substeps)

    def skip(self, first: int, last: int) -> None:
        todo = self.lik.spf * (last - first + 1)
        for _ in range(todo):
            pb.stepSimulation(physicsClientId=self.w.cid)
        self.lik.steps += todo


class VelocityLikelihood(FrameLikelihood):
    """Callable log-likelihood over the latent vector (in `names` order), for the MH kernel."""

    def __init__(self, scene: Scene, tracks: Tracks, sigma_mps: float = SIGMA_MPS, speedups: bool = True,
                 cache_size: int = K1_PREFIXES):
        # the fixed sigma (unused with the sigma latent): at least the noise the tracker measured on its own
        # tracks (a shaken, noisy or compressed video's), so that intervals widen instead of lying
        self.sigma_mps = max(check_sigma(sigma_mps), tracks.velocity_noise_mps())
        self.scene = scene_for_inference(scene, tracks)
        names = self.scene.latent_names
        # the physics depends on every latent but sigma, up to the switch on k1 alone; a sigma
        # proposal repeats the physics of a recent one (runs kept: 4 per prefix). A proposal
        # answered without physics is summed whole: its exact value, not a bound
        super().__init__(names, tracks.fps, tracks.n_frames, [o.name for o in self.scene.objects],
                         speedups=speedups, sim_latents=[n for n in names if n != SIGMA_LATENT],
                         prefix_latents=["k1"], prefixes=cache_size, motions=4 * min(cache_size, KEPT_PREFIXES),
                         whole_replays=True)
        priors = self.scene.priors
        self.observation = priors.observation
        self.dof = priors.student_t_dof
        self.infer_sigma = SIGMA_LATENT in self.names
        order = [next(t for t in tracks.objects if t.role == o.role) for o in self.scene.objects]
        self.v_obs = np.stack([np.nan_to_num(t.velocity_mps[:, [0, 2]]) for t in order])   # (O, F, 2)
        self.seen = np.stack([t.visible for t in order]).astype(float)                     # (O, F)
        # per frame, the (vx, vz) of each object seen in it, as Python floats (the per-frame
        # term is a handful of multiplications: numpy's call overhead would dominate it)
        self._obs = [[(i, float(self.v_obs[i, f, 0]), float(self.v_obs[i, f, 1]))
                      for i in range(len(order)) if self.seen[i, f]] for f in range(self.n_frames)]
        self.n_terms = 2 * self.seen.sum()
        if self.observation == "student_t":
            nu = self.dof
            self._t_coef = -0.5 * (nu + 1.0)
            self._t_const = math.lgamma(0.5 * (nu + 1.0)) - math.lgamma(0.5 * nu) - 0.5 * math.log(nu * math.pi)
            self._residual, self._term = self._residual_t, self._term_t
        else:
            # the rest rule's sigma-free sums: squared observed speeds of frames f.., f = 0..F
            d2 = (self.v_obs ** 2).sum(axis=2) * self.seen
            self._rest_d2 = [float(d2[:, f:].sum()) for f in range(self.n_frames + 1)]
            self._residual, self._term = self._residual_g, self._term_g
        self._noises: OrderedDict[float, _Noise] = OrderedDict()   # log10 sigma -> _Noise (sigma latent)
        self._fixed = self._make_noise(self.sigma_mps)
        self.log_norm = self._fixed.log_norm    # the normaliser at the fixed sigma
        self.spf = int(round(self.scene.sim_hz / self.fps))
        # each object's farthest surface point from its centre (a bound for `_reach_m`)
        self._radius_m = [0.5 * float(np.linalg.norm(o.shape.size_m)) for o in self.scene.objects]
        with client_lock:    # another thread's simulation (the viewer's, rerun's) must not step this world
            self.sim = Simulator(self.scene)
            self._target_alone = self._simulate_target_alone() if len(self.scene.objects) == 2 else None

    # -- the noise and the terms ---------------------------------------------------------------
    def _make_noise(self, sigma: float) -> _Noise:
        if self.observation == "student_t":
            return _Noise(sigma, self.n_terms * (self._t_const - math.log(sigma)), 1.0 / (self.dof * sigma * sigma))
        return _Noise(sigma, -self.n_terms * math.log(sigma * math.sqrt(2 * math.pi)), -0.5 / sigma ** 2)

    def noise_of(self, values: dict) -> _Noise:
        """The noise the values imply: the fixed sigma, or 10 ** log10_sigma_mps."""
        if not self.infer_sigma:
            return self._fixed
        key = values[SIGMA_LATENT]
        noise = self._noises.get(key)
        if noise is None:
            noise = self._noises[key] = self._make_noise(10.0 ** key)
            while len(self._noises) > 8:
                self._noises.popitem(last=False)
        return noise

    def values_of(self, position) -> dict[str, float]:
        """The latents by name, k1 as the simulator reads it: to K1_DECIMALS decimals."""
        values = super().values_of(position)
        values["k1"] = round(values["k1"], K1_DECIMALS)
        return values

    def sigma_of(self, position) -> float:
        """The sigma (m/s) the likelihood uses at this latent vector."""
        return self.noise_of(self.values_of(position)).sigma

    def _residual_g(self, f: int, vel) -> float:
        """Gaussian: frame f's sum of squared residuals (vel: per object (vx, vy, vz))."""
        acc = 0.0
        for i, ox, oz in self._obs[f]:
            v = vel[i]
            dx, dz = ox - v[0], oz - v[2]
            acc += dx * dx + dz * dz
        return acc

    def _term_g(self, r: float, noise: _Noise) -> float:
        """log N of a frame without the normaliser: -r / (2 sigma^2)."""
        return r * noise.scale

    def _residual_t(self, f: int, vel) -> tuple:
        """Student-t: frame f's squared residuals, one per component seen."""
        out = []
        for i, ox, oz in self._obs[f]:
            v = vel[i]
            dx, dz = ox - v[0], oz - v[2]
            out.append(dx * dx)
            out.append(dz * dz)
        return tuple(out)

    def _term_t(self, r: tuple, noise: _Noise) -> float:
        """log t of a frame without the normaliser: -(nu+1)/2 sum log1p(r^2 / (nu sigma^2))."""
        acc = 0.0
        inv = noise.scale
        for r2 in r:
            acc += math.log1p(r2 * inv)
        return acc * self._t_coef

    def observe(self, f: int, state, noise: _Noise) -> float:
        return self._term(state[1], noise)

    def rest_sum(self, f0: int, noise: _Noise) -> float:
        """Sum of the terms of frames f0.. with zero simulated velocity."""
        if self.observation != "student_t":
            return noise.scale * self._rest_d2[f0]
        if noise.rest is None:
            per_frame = (np.log1p(self.v_obs ** 2 * noise.scale).sum(axis=2) * self.seen).sum(axis=0) * self._t_coef
            noise.rest = np.concatenate([np.cumsum(per_frame[::-1])[::-1], [0.0]]).tolist()
        return noise.rest[f0]

    # -- the two phases ------------------------------------------------------------------------
    def _phase_a_values(self, values: dict) -> dict:
        """The proposal's values as phase A uses them: unit masses, the target's friction
        fixed, no collision restitution or sigma (the scene's restitutions)."""
        out = {}
        for k, v in values.items():
            if k.endswith("_kg"):
                out[k] = UNIT_MASS_KG
            elif k.startswith("k") and k != "k1":
                out[k] = PHASE_A_TARGET_FRICTION
            elif k not in ("e_collision", SIGMA_LATENT):
                out[k] = v
        return out

    def start(self, values: dict) -> _Run:
        """Phase A from t = 0: the ramp object slides with unit mass; the target takes no part in
        the simulation (its motion alone is known)."""
        w = self.sim.reset(self._phase_a_values(values))
        two = len(self.scene.objects) == 2
        if two:
            pb.setCollisionFilterGroupMask(w.bodies[1], -1, 0, 0, physicsClientId=w.cid)
        return _Run(self, w, phase_a=two)

    def resume(self, kept: _Switch, values: dict) -> _Run:
        """Phase B: the world restarted from both objects' poses and velocities where phase A
        ended, with the proposal's values."""
        return _Run(self, self.sim.resume(kept.snapshot, values), phase_a=False, substeps=kept.substeps)

    def _reach_m(self, twists, dt: float) -> float:
        """How far the objects could close in on each other within dt: each point moves at
        most (|v| + |w| r + g dt) dt; plus SWITCH_MARGIN_M (Bullet's speculative contacts act
        a step ahead)."""
        reach = self.scene.gravity_mps2 * dt * dt + SWITCH_MARGIN_M
        for (lin, ang), r in zip(twists, self._radius_m):
            reach += (math.sqrt(lin[0] * lin[0] + lin[1] * lin[1] + lin[2] * lin[2])
                      + math.sqrt(ang[0] * ang[0] + ang[1] * ang[1] + ang[2] * ang[2]) * r) * dt
        return reach

    def _within(self, w, twists, k: int, dt: float) -> bool:
        """Whether the objects are within `_reach_m(dt)` of each other at physics step k
        (the target moved to where it is alone at step k first)."""
        cid, (ramp_object, target) = w.cid, w.bodies
        pos, orn = self._target_alone[k][0]
        pb.resetBasePositionAndOrientation(target, pos, orn, physicsClientId=cid)
        return bool(pb.getClosestPoints(ramp_object, target, self._reach_m(twists, dt), physicsClientId=cid))

    def _refine_switch(self, w, f: int) -> int:
        """Phase A reached frame f within one frame's reach: step on one physics step at a
        time while the objects stay out of one step's reach (at most spf - 1 steps).
        Returns the steps taken; the world is then where phase A ends."""
        cid, spf = w.cid, self.spf
        dt = 1.0 / self.scene.sim_hz
        j = 0
        while j < spf - 1:
            k = f * spf + j
            twists = [pb.getBaseVelocity(w.bodies[0], physicsClientId=cid), self._target_alone[k][1]]
            if self._within(w, twists, k, dt):
                break
            pb.stepSimulation(physicsClientId=cid)
            self.steps += 1
            j += 1
        return j

    def _simulate_target_alone(self) -> list:
        """Per physics step (frame f is step f * spf), the target's ((position, orientation),
        (linear, angular velocity)) when it is simulated alone with phase A's values (the
        ramp object takes no part)."""
        sim = self.sim
        values = self._phase_a_values({n: 0.5 for n in self.names})  # (k1 is moot: the ramp object is masked)
        w = sim.reset(values)
        cid, target = w.cid, w.bodies[1]
        pb.setCollisionFilterGroupMask(w.bodies[0], -1, 0, 0, physicsClientId=cid)
        out = []
        for k in range((self.n_frames - 1) * self.spf + 1):
            if k:
                pb.stepSimulation(physicsClientId=cid)
            out.append((pb.getBasePositionAndOrientation(target, physicsClientId=cid),
                        pb.getBaseVelocity(target, physicsClientId=cid)))
        sim.drop_contacts()  # the filters back to normal
        return out
