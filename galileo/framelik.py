"""Step-by-step likelihoods: the scaffold under every scenario's likelihood.

A scenario's log-likelihood is a normaliser plus a sum over the video's frames of terms
<= 0, each read off a simulation that runs tick by tick. `FrameLikelihood` owns everything
around the physics; a scenario's subclass supplies the physics and what it observes:

    start(values) -> Run | None      a run at tick 0 from the latent values (by name); None where
                                     they describe nothing that can be simulated (prior density 0:
                                     the value is -inf, `motion` raises `no_motion`)
    Run.tick(k) -> state             advance the run to tick k (nothing to step at its first tick)
                                     and return its state: a tuple whose first item is each body's
                                     twist ((vx, vy, vz) m/s, (wx, wy, wz) rad/s, world frame), the
                                     rest the scenario's own (ticks come one after the other)
    Run.poses() -> [(pos, orn)]      each body's pose now (m; quaternion xyzw), for `motion`
    observe(f, state, noise)         video frame f's term (<= 0) from the state of its tick

and where it needs them:

    noise_of(values)                 the noise the values imply: an object with `log_norm`, passed
                                     to `observe` and `rest_sum` (default: a fixed noise, the
                                     likelihood's own `log_norm`)
    alignment(values)                (offset, stride): frame f is tick offset + f * stride (default
                                     (0, 1): a tick is a video frame)
    sim_latents, prefix_latents      (constructor) the latents the run depends on (default: all),
                                     and those it depends on until it branches (default: none, it
                                     never branches)
    Run.branch(k, state)             after tick k of a run from tick 0: None, or a `Kept` (a
                                     subclass may carry more) whose `snapshot` restarts the run at
                                     tick k + 1 with all of sim_latents (`resume(kept, values)`);
                                     the ticks before depend on prefix_latents alone
    rest_sum(f0, noise)              the terms of frames f0.. at rest in closed form (None: each
                                     such frame is observed at the state held still)
    horizon(values)                  the last tick a kept run goes on to (default: the last one
                                     observed), so that other alignments can reuse it
    at_frame(state, values)          the state a video frame sees from its tick's (default: that
                                     state; frames that fall between ticks interpolate here)
    frame_poses(seen, run)           each body's pose in that state (default: run.poses())
    before_start(values)             where an alignment puts frames before tick 0 (a negative
                                     offset: the run has not begun, e.g. an object still held):
                                     (state, poses) they are observed at, summed first as a block
    held(state)                      the state the rest rule holds still (default: zero twists,
                                     the rest unchanged)
    Run.skip(first, last)            step through ticks first..last unread (the plain path pays
                                     for the frames the rest rule holds still)

The scaffold owns `names`, `steps` (the physics steps taken; runs add theirs),
`__call__(position, threshold=None) -> (value, stopped_early)` and `motion(position)`,
both holding `galileo.sim.bullet.client_lock` for the whole evaluation (one Bullet client per
process), and these rules:

* The rest rule (a deterministic version of Bullet's sleeping): once, for two consecutive
  checked ticks (every `RestRule.every`-th tick, not tick 0), every body moves slower than
  REST_MPS, turns slower than REST_RADPS and is not speeding up (by more than
  REST_CREEP_MPS since the tick checked before), that tick and all later ones hold the
  bodies still: the poses of that tick, zero velocity. A run restarted at a branch starts
  the rule afresh.
* Exact speed-ups (`speedups=True`; the plain path, `speedups=False`, simulates every tick
  of every proposal and gives the same accept/reject decisions, and bit for bit the same
  values where it does not stop early):
  - early rejection: each term is <= 0, so the normaliser plus the partial sum bounds the
    value from above; after every frame scored from a simulation the evaluation stops once
    it falls below the MH threshold (returning the bound and True);
  - at-rest cut-off: once the rule holds, no more steps: the rest is `rest_sum` or each
    frame observed at the held state;
  - prefix reuse: a run that branches is kept (an LRU of `prefixes` entries, keyed on
    prefix_latents) with its states up to the branch and the snapshot there; a proposal
    with the same prefix_latents scores those states (no physics) and resumes from the
    snapshot. A run that never branched depends on prefix_latents alone and is kept whole;
  - run reuse: where some latent does not enter the simulation (a noise level, a start
    time), complete runs are kept (an LRU of `motions` entries, keyed on sim_latents; they
    go on to `horizon`), and a proposal that changes only such latents is scored from
    them without physics: stopping at the threshold frame by frame, or summed whole with
    `whole_replays` (then it reports its exact value, not a bound).
  The frames before a branch are summed as one block (numpy's sum) when the run passes the
  branch, and again when a later run resumes there or replays a kept run, so that every
  path sums the same numbers in the same order; the frames after it one by one.
* `motion(position)` is the motion exactly as scored (the same branch, the same rest rule),
  simulated from tick 0 and shown per video frame: positions, velocities and orientations.
"""
from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .datatypes import Trajectory
from .errors import GalileoError
from .sim.bullet import client_lock

REST_MPS = 1e-3        # linear speed below which a body counts as at rest (m/s)
REST_RADPS = 0.02      # and angular speed (rad/s): 1 mm/s at 5 cm from the centre
REST_CREEP_MPS = 5e-5  # ... as long as its speed grew by no more than this since the tick checked before
KEPT_PREFIXES = 4      # runs kept for prefix reuse (LRU), by default
KEPT_MOTIONS = 4       # complete runs kept for reuse (LRU), by default
_STILL = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))


@dataclass(frozen=True)
class RestRule:
    """When a run counts as at rest (see the module docstring); a scenario may differ."""
    speed_mps: float = REST_MPS
    spin_radps: float = REST_RADPS
    creep_mps: float = REST_CREEP_MPS
    every: int = 1         # checked on the ticks that are multiples of this (a tick that is a physics
                           # step: the steps of the simulation's own frames)


@dataclass
class Kept:
    """A kept run (an LRU entry): the state each tick gave, and how the run goes on."""
    terms: list = field(default_factory=list)   # per tick from 0, the state its term is scored from
    first_b: int | None = None    # the run branched before this tick (None: it never did)
    rest: int | None = None       # the tick the rest rule held still from (None: it did not)
    snapshot: Any = None          # where the branch starts (`resume`); None: the run is complete


class Run:
    """One simulation run, tick by tick (see the module docstring); a scenario subclasses it."""

    def tick(self, k: int) -> tuple:
        raise NotImplementedError

    def poses(self) -> list:
        raise NotImplementedError

    def branch(self, k: int, state) -> Kept | None:
        return None

    def skip(self, first: int, last: int) -> None:
        for k in range(first, last + 1):
            self.tick(k)


class _Replay(Run):
    """A complete kept run, tick by tick (no physics)."""

    def __init__(self, states: list):
        self.states = states

    def tick(self, k: int) -> tuple:
        return self.states[k]


class FrameLikelihood:
    """Callable log-likelihood over the latent vector (in `names` order), for the MH kernel;
    a scenario subclasses it (see the module docstring)."""
    no_motion = "nothing can be simulated at these latent values"   # `motion` where `start` gives None

    def __init__(self, names: Sequence[str], fps: float, n_frames: int, body_names: Sequence[str], *,
                 speedups: bool = True, sim_latents: Sequence[str] | None = None,
                 prefix_latents: Sequence[str] | None = None, rest: RestRule = RestRule(),
                 prefixes: int = KEPT_PREFIXES, motions: int = KEPT_MOTIONS, whole_replays: bool = False):
        self.names = tuple(names)
        self.fps = fps
        self.n_frames = n_frames
        self.body_names = tuple(body_names)
        self.speedups = speedups
        self.rest_rule = rest
        self.whole_replays = whole_replays
        self.sim_latents = self.names if sim_latents is None else tuple(sim_latents)
        self.prefix_latents = None if prefix_latents is None else tuple(prefix_latents)
        self.steps = 0          # physics steps taken (for benchmarks)
        self._prefixes: OrderedDict[tuple, Kept] | None = None if prefix_latents is None else OrderedDict()
        self._n_prefixes = prefixes
        # complete runs are worth keeping only where a proposal can repeat the simulation
        keep = set(self.sim_latents) != set(self.names)
        self._motions: OrderedDict[tuple, Kept] | None = OrderedDict() if keep else None
        self._n_motions = motions

    # -- what a scenario supplies (see the module docstring) ------------------------------------
    def start(self, values: dict) -> Run | None:
        raise NotImplementedError

    def resume(self, kept: Kept, values: dict) -> Run:
        raise NotImplementedError

    def observe(self, f: int, state, noise) -> float:
        raise NotImplementedError

    def noise_of(self, values: dict):
        return self

    def alignment(self, values: dict) -> tuple[int, int]:
        return 0, 1

    def horizon(self, values: dict) -> int:
        offset, stride = self.alignment(values)
        return offset + (self.n_frames - 1) * stride

    def rest_sum(self, f0: int, noise) -> float | None:
        return None

    def at_frame(self, state, values: dict):
        return state

    def frame_poses(self, seen, run: Run) -> list:
        return run.poses()

    def before_start(self, values: dict) -> tuple:
        raise NotImplementedError(f"{type(self).__name__} has frames before its runs start: give before_start")

    def held(self, state) -> tuple:
        """The state held still by the rest rule: zero twists, the rest as it was."""
        return (tuple(_STILL for _ in state[0]),) + tuple(state[1:])

    # -- the target ---------------------------------------------------------------------------
    def values_of(self, position) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.names, position)}

    def __call__(self, position, threshold: float | None = None) -> tuple[float, bool]:
        """(log-likelihood, stopped_early). With a threshold and speed-ups, may stop early and
        return an upper bound below the threshold. Thread-safe, as `motion`."""
        values = self.values_of(position)
        limit = -math.inf if (threshold is None or not self.speedups) else threshold
        with client_lock:
            noise = self.noise_of(values)
            total, early, _ = self._evaluate(values, limit, noise=noise)
        return noise.log_norm + total, early

    def motion(self, position) -> Trajectory:
        """The simulated motion exactly as the likelihood scores it, per video frame: positions,
        velocities and orientations. Thread-safe (the process's Bullet client is held)."""
        with client_lock:
            _, _, rec = self._evaluate(self.values_of(position), -math.inf, record=True, reuse=False)
        if rec is None:
            raise GalileoError(self.no_motion)
        return Trajectory(self.fps, list(self.body_names), *rec)

    # -- the frame loop -------------------------------------------------------------------------
    def _evaluate(self, values: dict, limit: float, record: bool = False, reuse: bool = True, noise=None):
        """Sum of the frames' terms (without the normaliser): (sum or partial sum, stopped early,
        record). Stops once normaliser + partial sum < `limit` (the kernel's own test: value <
        threshold). With `record`, per frame (positions, velocities, orientations) of each body,
        NaN in the frames this evaluation did not simulate (a reused prefix's); `reuse=False`
        simulates from tick 0."""
        noise = self.noise_of(values) if noise is None else noise
        log_norm = noise.log_norm
        n = self.n_frames
        offset, stride = self.alignment(values)
        last = offset + (n - 1) * stride
        fast = self.speedups
        rec = None
        if record:
            shape = (len(self.body_names), n)
            rec = (np.full(shape + (3,), np.nan), np.full(shape + (3,), np.nan), np.full(shape + (4,), np.nan))
        kept = self._kept_for(values, last, record) if (fast and reuse) else None
        first, total = 0, 0.0
        before = self._frames_before(0, offset, stride)   # frames before the run starts
        if before:
            state, poses = self.before_start(values)
            state = self.at_frame(state, values)
            pre = float(np.array([self.observe(f, state, noise) for f in range(before)]).sum())
            if rec is not None:
                self._record(rec, slice(0, before), None, poses)
            if log_norm + pre < limit:
                return pre, True, rec
        states: list | None = None     # the run's states per tick from 0, to keep
        if kept is None:
            run = self.start(values)
            if run is None:
                return -math.inf, False, None
            if fast:
                states = []
        else:
            if kept.snapshot is None and self.whole_replays:   # no physics: summed whole
                limit = -math.inf
            first = kept.first_b or 0
            if first:   # the frames before the branch, as one block
                total = float(np.array([self.observe(f, self.at_frame(kept.terms[offset + f * stride], values), noise)
                                        for f in range(before, self._frames_before(first, offset, stride))]).sum())
                if log_norm + total < limit:
                    return total, True, rec
            if kept.snapshot is not None:
                run = self.resume(kept, values)
                states = list(kept.terms)
            else:
                run = _Replay(kept.terms)
        end = max(last, self.horizon(values)) if (states is not None and self._motions is not None) else last
        branched = first or None
        block = [] if (kept is None and self._prefixes is not None) else None   # terms before a branch
        rule = self.rest_rule
        every, rest_mps, rest_w2, creep = rule.every, rule.speed_mps, rule.spin_radps ** 2, rule.creep_mps
        speeds: list | None = None
        rest_run = 0
        if before:
            total += pre
        f = self._frames_before(first, offset, stride)   # the next frame to score, at tick `due`
        due = offset + f * stride if f < n else -1
        observe = self.observe
        for k in range(first, end + 1):
            state = run.tick(k)
            if states is not None:
                states.append(state)
            if k % every == 0:   # the rest rule
                twists = state[0]
                if speeds is None:
                    speeds = [math.inf] * len(twists)
                slow = True   # every body slower than the rule's speed, turning slowly, not speeding up
                for i, (lin, ang) in enumerate(twists):
                    speed = math.sqrt(lin[0] * lin[0] + lin[1] * lin[1] + lin[2] * lin[2])
                    if slow and (speed >= rest_mps or speed > speeds[i] + creep
                                 or ang[0] * ang[0] + ang[1] * ang[1] + ang[2] * ang[2] >= rest_w2):
                        slow = False
                    speeds[i] = speed
                rest_run = rest_run + 1 if (k and slow) else 0
                if rest_run >= 2:
                    return self._at_rest(values, run, state, k, end, f, total, limit, noise, rec, states, branched)
            if k == due:
                seen = self.at_frame(state, values)
                term = observe(f, seen, noise)
                total += term
                if block is not None:
                    block.append(term)
                if rec is not None:
                    self._record(rec, f, seen[0], self.frame_poses(seen, run))
                if log_norm + total < limit:
                    return total, True, rec
                f += 1
                due = offset + f * stride if f < n else -1
            if block is not None:
                switch = run.branch(k, state)
                if switch is not None:   # from tick k + 1 on, the run depends on all of sim_latents
                    total = float(np.array(block).sum()) + (pre if before else 0.0)   # as a resumed run sums
                    block = None
                    switch.first_b = branched = k + 1
                    if states is not None:
                        switch.terms, states = states, list(states)
                        self._remember(self._prefixes, self._key(values, self.prefix_latents), switch,
                                       self._n_prefixes)
                    run = self.resume(switch, values)
                    speeds, rest_run = None, 0
        self._keep(values, states, branched, None)
        return total, False, rec

    def _at_rest(self, values, run: Run, state, k: int, end: int, f: int, total: float, limit: float, noise, rec,
                 states, branched):
        """The rest rule held at tick k: frames f.. (all at ticks >= k) at the held state."""
        n = self.n_frames
        poses = run.poses() if rec is not None else None
        if not self.speedups:   # the plain path steps through the rest all the same
            run.skip(k + 1, end)
        rest = self.rest_sum(f, noise)
        if rest is not None:
            total += rest
        else:
            held = self.at_frame(self.held(state), values)
            log_norm = noise.log_norm
            for g in range(f, n):
                total += self.observe(g, held, noise)
                if log_norm + total < limit:
                    if rec is not None:
                        self._record(rec, slice(f, g + 1), None, poses)
                    return total, True, rec
        if rec is not None:
            self._record(rec, slice(f, n), None, poses)
        self._keep(values, states, branched, k)
        return total, False, rec

    @staticmethod
    def _record(rec, f, twists, poses) -> None:
        """Frame(s) f of the record: the bodies' poses and velocities (twists None: held still)."""
        pos, vel, orn = rec
        for i, (p, q) in enumerate(poses):
            pos[i, f], orn[i, f] = p, q
            vel[i, f] = 0.0 if twists is None else twists[i][0]

    def _frames_before(self, tick: int, offset: int, stride: int) -> int:
        """How many frames are observed before `tick`."""
        return min(self.n_frames, max(0, -(-(tick - offset) // stride)))

    # -- kept runs -------------------------------------------------------------------------------
    @staticmethod
    def _key(values: dict, latents: tuple) -> tuple:
        return tuple(values[k] for k in latents)

    @staticmethod
    def _covers(kept: Kept, last: int) -> bool:
        """Whether a kept run is complete up to tick `last`."""
        return kept.snapshot is None and (kept.rest is not None or len(kept.terms) > last)

    def _kept_for(self, values: dict, last: int, record: bool) -> Kept | None:
        """What a kept run gives these values: a complete run of their sim_latents, or (as it
        would show nothing to record, a complete run only without `record`) a run of their
        prefix_latents."""
        if self._motions is not None and not record:
            key = self._key(values, self.sim_latents)
            kept = self._motions.get(key)
            if kept is not None and self._covers(kept, last):
                self._motions.move_to_end(key)
                return kept
        if self._prefixes is not None:
            key = self._key(values, self.prefix_latents)
            kept = self._prefixes.get(key)
            if kept is not None and (kept.snapshot is not None or (not record and self._covers(kept, last))):
                self._prefixes.move_to_end(key)
                return kept
        return None

    def _keep(self, values: dict, states: list | None, branched: int | None, rest: int | None) -> None:
        """Keep a complete run: by its prefix_latents if it never branched, else by its sim_latents."""
        if states is None:
            return
        kept = Kept(states, branched, rest)
        if branched is None and self._prefixes is not None:
            self._remember(self._prefixes, self._key(values, self.prefix_latents), kept, self._n_prefixes)
        elif self._motions is not None:
            self._remember(self._motions, self._key(values, self.sim_latents), kept, self._n_motions)

    @staticmethod
    def _remember(cache: OrderedDict, key: tuple, kept: Kept, size: int) -> None:
        cache[key] = kept
        cache.move_to_end(key)
        while len(cache) > size:
            cache.popitem(last=False)


def ar1_residuals(rng: np.random.Generator, shape: tuple, sigma, rho: float) -> np.ndarray:
    """Residuals (F, ...) of the AR(1) process the scenarios' likelihoods assume: r_0 = e_0,
    r_f = rho r_(f-1) + sqrt(1 - rho^2) e_f, e_f ~ N(0, sigma^2) (sigma a number or one per
    column): each r_f is N(0, sigma^2), neighbours correlated by rho (synthetic observations)."""
    e = rng.standard_normal(shape) * sigma
    r = np.empty_like(e)
    r[0] = e[0]
    for f in range(1, len(e)):
        r[f] = rho * r[f - 1] + math.sqrt(1 - rho * rho) * e[f]
    return r
