"""Likelihood: tracked velocities against Bullet simulations (Galileo eq. 1).

    log p(v_obs | m1, k1, m2, k2) = sum over visible frames f and objects o of
        log N(v_obs[o, f] | v_sim[o, f], sigma^2 I)

on the x and z velocity components (the fall-line plane; the tracker reports y = 0).
`sigma_mps` is the paper's Sigma = 0.05, read as a standard deviation in m/s (so the
variance is 0.0025 m^2/s^2). The simulation runs as many frames as the video; frames
where an object was not seen are left out. Shapes and the ramp object's offset are fixed
from tracking (section 3.1).

The model treats a world at rest as staying at rest: once every object moves slower
than REST_MPS (and turns slower than REST_RADPS) for two consecutive frames, later frames
hold the last positions with zero velocity (a deterministic version of Bullet's
sleeping). Both paths below apply it. (An object whose friction is within ~1e-3 of tan of
the ramp angle creeps slower than that and counts as at rest.)

Exact speed-ups (`speedups=True`; each gives the same accept/reject decisions as the
plain path, `speedups=False`, which simulates every frame of every proposal):

* early rejection: every frame adds a term <= 0, so the partial sum is an upper bound of
  the final value; the simulation stops once it falls below the MH threshold.
* at-rest cut-off: once the world is at rest, the remaining frames are known without
  stepping.
* prefix reuse: before the objects first touch, the masses do not matter (sliding is
  mass-independent). The model makes this exact: both paths simulate with unit masses
  until first contact, go back to the frame before it, drop the contacts, set the
  proposal's masses and go on. The world at that frame then depends only on (k1, k2), and
  a proposal with the same frictions resumes from a saved copy of it, with the per-frame
  terms up to there already summed. (k2 matters before contact: the target settles on the
  ground depending on its friction.) Without contact (no target, or the object stops short
  of it) the whole result depends only on (k1, k2) and is reused whole.
"""
from __future__ import annotations

import dataclasses
import math
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from .bullet import pb
from .errors import GalileoError
from .physics import Simulator
from .scene import Scene
from .tracking import Tracks

REST_MPS = 1e-4      # linear speed below which an object counts as at rest
REST_RADPS = 1e-3    # and angular speed
SIGMA_MPS = 0.05
UNIT_MASS_KG = 1.0   # the masses phase A runs with (see VelocityLikelihood._evaluate)


def scene_for_inference(scene: Scene, tracks: Tracks) -> Scene:
    """The scene with the shapes and offset that tracking measured (fixed during MCMC)."""
    objs = list(scene.objects)
    for i, obj in enumerate(objs):
        tr = next((t for t in tracks.objects if t.role == obj.role), None)
        if tr is None:
            raise GalileoError(f"the tracks have no {obj.role} object for scene object {obj.name!r}")
        change = {"shape": tr.shape}
        if obj.role == "ramp" and tr.offset_units is not None:
            change["offset_units"] = int(tr.offset_units)
        objs[i] = dataclasses.replace(obj, **change)
    new = dataclasses.replace(scene, objects=tuple(objs))
    new.validate()
    return new


@dataclass
class _Prefix:
    contact_frame: int | None          # first frame in contact (None: never, in the full run)
    state_id: int | None = None        # world saved at frame contact_frame - 1
    terms: np.ndarray | None = None    # per-frame log-likelihood terms of frames < contact_frame
    full: tuple | None = None          # without contact: the whole result (loglik, terms)


class VelocityLikelihood:
    """Callable log-likelihood over the latent vector (in `names` order), for the MH kernel."""

    def __init__(self, scene: Scene, tracks: Tracks, sigma_mps: float = SIGMA_MPS, speedups: bool = True,
                 cache_size: int = 4):
        if tracks.fps != (scene.camera.fps if scene.camera else tracks.fps):
            raise GalileoError(f"tracks at {tracks.fps} fps but the scene camera at {scene.camera.fps} fps")
        self.scene = scene_for_inference(scene, tracks)
        self.names = self.scene.latent_names
        self.fps = tracks.fps
        self.n_frames = tracks.n_frames
        self.sigma_mps = float(sigma_mps)
        self.speedups = speedups
        order = [next(t for t in tracks.objects if t.role == o.role) for o in self.scene.objects]
        self.v_obs = np.stack([np.nan_to_num(t.velocity_mps[:, [0, 2]]) for t in order])   # (O, F, 2)
        self.seen = np.stack([t.visible for t in order]).astype(float)                     # (O, F)
        n_terms = 2 * self.seen.sum()
        self.log_norm = -n_terms * math.log(self.sigma_mps * math.sqrt(2 * math.pi))
        self.sim = Simulator(self.scene)
        self.spf = int(round(self.scene.sim_hz / self.fps))
        self._prefixes: OrderedDict[tuple, _Prefix] = OrderedDict()
        self._prefix_world = None  # the world the prefixes' states were saved in
        self._cache_size = cache_size
        self.steps = 0          # physics steps taken (for benchmarks)
        self.evaluations = 0

    # -- pieces --------------------------------------------------------------------------
    def values_of(self, position) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.names, position)}

    def _frame_term(self, f: int, vel: np.ndarray) -> float:
        d = self.v_obs[:, f] - vel[:, [0, 2]]
        return float(-0.5 * np.sum((d * d).sum(axis=1) * self.seen[:, f]) / self.sigma_mps ** 2)

    @staticmethod
    def _read(bodies, cid: int, vel: np.ndarray) -> bool:
        """Linear velocities into `vel`; whether every object is at rest."""
        rest = True
        for i, b in enumerate(bodies):
            lin, ang = pb.getBaseVelocity(b, physicsClientId=cid)
            vel[i] = lin
            if rest and (max(abs(lin[0]), abs(lin[1]), abs(lin[2])) >= REST_MPS
                         or max(abs(ang[0]), abs(ang[1]), abs(ang[2])) >= REST_RADPS):
                rest = False
        return rest

    def _rest_term(self, f0: int) -> float:
        """Sum of the terms of frames f0.. with zero simulated velocity."""
        if f0 >= self.n_frames:
            return 0.0
        d = self.v_obs[:, f0:]
        return float(-0.5 * np.sum((d * d).sum(axis=2) * self.seen[:, f0:]) / self.sigma_mps ** 2)

    # -- the target --------------------------------------------------------------------------
    def __call__(self, position, threshold: float | None = None):
        """(log-likelihood, stopped_early). With a threshold and speed-ups, may stop early and
        return an upper bound below the threshold."""
        self.evaluations += 1
        values = self.values_of(position)
        limit = -math.inf if (threshold is None or not self.speedups) else threshold - self.log_norm
        total, early, _ = self._evaluate(values, limit)
        return self.log_norm + total, early

    def _evaluate(self, values: dict, limit: float, record: bool = False):
        """Sum of the per-frame terms; (sum or partial sum, stopped early, positions/velocities).

        Phase A runs with unit masses until the objects first touch (frame c); the world is
        then taken back to frame c - 1, the contacts are dropped, the proposal's masses set,
        and phase B runs on. Both paths do exactly this, so the state at c - 1 depends only
        on (k1, k2) and a saved copy of it serves every proposal with the same frictions.
        """
        fast = self.speedups
        if fast and self.sim.world is not self._prefix_world:
            # The process's world was rebuilt (another scene simulated) and the saved states
            # went with it: restoring their ids would fail or restore another world's state.
            self._prefixes.clear()
            self._prefix_world = self.sim.world
        key = (values["k1"], values.get("k2"))  # all that phase A depends on
        prefix = self._prefixes.get(key) if fast else None
        n = self.n_frames
        n_obj = len(self.scene.objects)
        rec = (np.full((n_obj, n, 3), np.nan), np.full((n_obj, n, 3), np.nan)) if record else None
        sim = self.sim
        if prefix is not None:
            self._prefixes.move_to_end(key)
            if prefix.full is not None and not record:
                return prefix.full, False, None
            if prefix.state_id is not None:
                c = prefix.contact_frame
                total = float(prefix.terms.sum())
                if total < limit:
                    return total, True, None
                pb.restoreState(prefix.state_id, physicsClientId=sim.world.cid)
                return self._phase_b(values, c, total, limit, rec)
        canonical = {**values, **{k: UNIT_MASS_KG for k in values if k.endswith("_kg")}}
        two = n_obj == 2
        w = sim.reset(canonical)
        terms = np.zeros(n)
        status, f, total = self._frames(w, 0, 0.0, limit, terms, rec, detect_contact=two)
        if status == "early":
            return total, True, rec
        if status != "contact":
            if fast:
                self._remember(key, _Prefix(None, full=total))
            return total, False, rec
        c = f
        if c == 0:  # touching from the start: no phase A
            sim.reset(values)
            return self._phase_b(values, 0, 0.0, limit, rec, restored=False)
        total = float(terms[:c].sum())
        w = sim.reset(canonical)  # back to frame c - 1
        steps = self.spf * (c - 1)
        for _ in range(steps):
            pb.stepSimulation(physicsClientId=w.cid)
        self.steps += steps
        if fast:
            self._remember(key, _Prefix(c, pb.saveState(physicsClientId=w.cid), terms[:c].copy()))
        return self._phase_b(values, c, total, limit, rec)

    def _phase_b(self, values: dict, c: int, total: float, limit: float, rec, restored: bool = True):
        """From frame c on, with the proposal's masses (the world is at frame c - 1)."""
        sim = self.sim
        if restored:
            sim.drop_contacts()
            sim.apply_values(values)
        terms = np.zeros(self.n_frames)
        status, _, total = self._frames(sim.world, c, total, limit, terms, rec, detect_contact=False)
        return total, status == "early", rec

    def _frames(self, w, first: int, total: float, limit: float, terms: np.ndarray, rec, detect_contact: bool):
        """Step through frames first.. (stepping into `first` unless it is 0), adding terms.

        Returns (status, frame, total): "done", "early" (partial sum below the limit),
        "rest" (the world came to rest; the rest of the frames added at zero velocity) or
        "contact" (the objects touched at `frame`; its term is not added)."""
        fast = self.speedups
        cid, bodies = w.cid, w.bodies
        spf, n = self.spf, self.n_frames
        vel = np.empty((len(bodies), 3))
        rest_run = 0
        for f in range(first, n):
            if f:
                for _ in range(spf):
                    pb.stepSimulation(physicsClientId=cid)
                self.steps += spf
            at_rest = self._read(bodies, cid, vel)
            if record := rec is not None:
                rec[1][:, f] = vel
                rec[0][:, f] = [pb.getBasePositionAndOrientation(b, physicsClientId=cid)[0] for b in bodies]
            if detect_contact and pb.getContactPoints(bodies[0], bodies[1], physicsClientId=cid):
                return "contact", f, total
            rest_run = rest_run + 1 if (f and at_rest) else 0
            if rest_run >= 2:  # at rest: this frame and all later ones hold still
                if record:
                    rec[0][:, f:] = rec[0][:, f:f + 1]
                    rec[1][:, f:] = 0.0
                if not fast:  # the plain path steps through the rest all the same
                    for _ in range(spf * (n - 1 - f)):
                        pb.stepSimulation(physicsClientId=cid)
                    self.steps += spf * (n - 1 - f)
                return "rest", f, total + self._rest_term(f)
            terms[f] = self._frame_term(f, vel)
            total += terms[f]
            if total < limit:
                return "early", f, total
        return "done", n - 1, total

    def _remember(self, key: tuple, entry: _Prefix) -> None:
        self._prefixes[key] = entry
        while len(self._prefixes) > self._cache_size:
            _, old = self._prefixes.popitem(last=False)
            if old.state_id is not None:
                pb.removeState(old.state_id, physicsClientId=self.sim.world.cid)

    # -- trajectories (for predictions, the viewer) ------------------------------------------
    def simulated_motion(self, position) -> tuple[np.ndarray, np.ndarray]:
        """Positions and velocities (O, F, 3) as the likelihood sees them (rest rule and
        prefix reuse included), for tests and the viewer."""
        _, _, rec = self._evaluate(self.values_of(position), -math.inf, record=True)
        return rec

