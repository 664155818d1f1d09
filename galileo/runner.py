"""The one chain runner: single-site MH chains over any scenario's likelihood, on any executor.

`galileo infer`, `galileo experiment` and the app's controller all run chains through
`run_task`: a pure function of a `ChainTask` (the problem as plain JSON, the chain's state
and random-stream state, how many sweeps, the settings) that returns the sweeps' record.
So a chain's samples depend only on (seed, chain index, settings), never on which process
ran which sweeps: the batch runner sends each chain once for all its sweeps, the controller
sends one sweep at a time and steers in between, and both give the same chains bit for bit.

Chain c draws its random numbers from SeedSequence(seed, spawn_key=(c,)) (`mcmc.chain_rng`)
and starts where its scenario says (`Scenario.initial_positions`: by default drawn from the
prior, `initial_positions(bounds, c + 1, seed)[c]`; the splash starts as its seed says).

Move sets (`RunConfig.moves`): "paper" is Galileo 3.2 as published; "default" adds warm-up
adaptation of the widths and joint moves (`default_moves`: the scenario's own and an
adaptive joint random walk); "fitted" adds, after the warm-up, moves fitted to every
chain's warm-up draws: a kernel move (a kernel density estimate of them), and a t's
conditional moves and marginal moves (`fitted_kernel`, `fitted_move`, `fitted_marginals`,
`fitted_moves`; `infer`, and the app's controller
once every chain is past the warm-up): from then on a chain depends on
the others' warm-ups too (still only on the seed and the settings). A task carries its chain's adapted widths and moves, so a
chain continued in another task (`next_task`: the batch runner's blocks when it runs until
converged, the controller's rounds) is the same chain.

Executors: anything with `map(fn, iterable)` (results in order). `LocalPool` (forked worker
processes, each with its own pybullet client; a likelihood is built once per worker and
problem) is the default; `workers=1` runs in this process. A Dask client fits the same slot.
A LocalPool worker that dies raises `WorkerDied`; one that stops answering, `WorkerHung` once a
map's deadline (`timeout_s`) has passed (its workers are then killed).
"""
from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import math
import multiprocessing as mp
import os
import time
from collections.abc import Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from . import registry
from .datatypes import Tracks
from .errors import GalileoError
from .joint import tracks_from_json, tracks_to_json
from .latents import (
    Latent,
    Noise,
    by_name,
    check_bounds,
    check_noise,
    check_widths,
    default_widths,
)
from .mcmc import JointRW, MHState, Proposal, adapt, chain_rng, fit_independence, sweep
from .progress import tqdm
from .results import MIN_ESS, RHAT_TARGET, InferenceResult, convergence, kept_draws

MOVE_SETS = ("default", "paper", "fitted")  # what `infer` and the app's controller run
FITTED_PER_SWEEP = 12                       # "fitted": its joint proposals a sweep after the warm-up (the demo converged
                                            # in 757, 337, 225 sweeps with 3, 6, 12 from the t: each accepted one is a
                                            # fresh draw; from the kernel, seeds 0 and 4: 230 with 6, 172 and 156 with
                                            # 12; with 20, 156 on seed 0, no sooner in seconds)
FITTED_CONDITIONALS = 1                     # "fitted": proposals a sweep of each latent from q's conditional (the demo
                                            # converged in a median 209 sweeps over 5 seeds, 141-279; without, 372, 279-1071)
FITTED_MARGINALS = 2                        # "fitted": proposals a sweep of each latent the others barely determine
                                            # from its warm-up draws' density (the demo: k1 and e_collision; it
                                            # converged in a median 279 sweeps over 5 seeds, 156-803; without,
                                            # 497-547 over 3: k1's narrow second mode; 4 a sweep: 410 on seeds 0, 4)
MARGINAL_MIN_SD_RATIO = 0.5                 # ... "barely determine": its conditional sd under q at least this of its own
FITTED_MIN_WARMUP = 10                      # "fitted": fewer warm-up sweeps than this fit nothing
UNTIL_WARMUP_SWEEPS = 100
PROGRESS_PIECE_S = 2.0   # with a progress bar, `infer` runs each chain in pieces of about this long
SHUTDOWN_GRACE_S = 10.0  # how long LocalPool.shutdown waits for a worker to exit before it kills it

# -- settings: what a user may change, checked in one place ---------------------------------------

@dataclass
class Settings:
    """Prior bounds per latent, the likelihood's noise (None: the scenario's default) and
    the proposal widths (a number, or one per latent)."""
    bounds: dict[str, tuple[float, float]]
    noise: float | None = None
    narrow: float | tuple = 0.05
    broad: float | tuple = 0.5
    broad_every: int = 20
    noise_spec: Noise | None = field(default=None, compare=False)
    integer_sites: tuple[int, ...] = ()   # which latents take integer values (set by `checked`)

    @classmethod
    def default(cls, latents: Sequence[Latent], noise: Noise, widths: dict | None = None) -> Settings:
        """The latents' bounds and widths and the noise's default; `widths` {latent: (narrow,
        broad)} replaces some latents' widths (a scenario's `paper_widths` under `--moves paper`)."""
        if widths:
            latents = [dataclasses.replace(lat, narrow=widths[lat.name][0], broad=widths[lat.name][1])
                       if lat.name in widths else lat for lat in latents]
        narrow, broad = default_widths(latents)
        return cls({lat.name: tuple(lat.bounds) for lat in latents}, noise.default, narrow, broad, 20, noise)

    def checked(self, latents: Sequence[Latent], noise: Noise | None = None) -> Settings:
        """A validated copy (ValueError with a one-line reason): bounds for exactly these
        latents (any missing taken from the latents' own), each by `latents.check_bounds`;
        the noise (named by `noise`, default this one's spec) and widths likewise."""
        spec = noise or self.noise_spec
        if spec is None:
            raise ValueError("settings need the scenario's noise to be checked")
        specs = by_name(latents)
        unknown = set(self.bounds) - set(specs)
        if unknown:
            raise ValueError(f"bounds for unknown latents {sorted(unknown)}; expected {', '.join(specs)}")
        bounds = {n: check_bounds(specs[n], *self.bounds.get(n, specs[n].bounds)) for n in specs}
        narrow, broad, every = check_widths(self.narrow, self.broad, self.broad_every)
        for w, what in ((narrow, "narrow"), (broad, "broad")):
            if isinstance(w, tuple) and len(w) != len(specs):
                raise ValueError(f"{what}: {len(w)} widths for {len(specs)} latents")
        value = spec.default if self.noise is None else check_noise(spec, self.noise)
        integer = tuple(i for i, lat in enumerate(latents) if lat.integer)
        return Settings(bounds, value, narrow, broad, every, spec, integer)

    def copy(self) -> Settings:
        return Settings({k: (float(v[0]), float(v[1])) for k, v in self.bounds.items()}, self.noise,
                        self.narrow, self.broad, int(self.broad_every), self.noise_spec, self.integer_sites)

    def bounds_array(self, names: Sequence[str]) -> np.ndarray:
        return np.array([self.bounds[n] for n in names], float)

    def proposal(self) -> Proposal:
        return Proposal(self.narrow, self.broad, int(self.broad_every), self.integer_sites)

    def to_json(self) -> dict:
        def w(x):
            return list(x) if isinstance(x, tuple) else float(x)
        name, unit = (self.noise_spec.name, self.noise_spec.unit) if self.noise_spec else ("noise", "?")
        return {"bounds": {k: [float(v[0]), float(v[1])] for k, v in self.bounds.items()},
                name: float(self.noise), "sigma_is": f"standard deviation ({unit})",
                "narrow": w(self.narrow), "broad": w(self.broad), "broad_every": int(self.broad_every)}

    @classmethod
    def from_json(cls, d: dict, latents: Sequence[Latent], noise: Noise) -> Settings:
        """Parse and check (ValueError on a bad or missing value; every latent needs bounds)."""
        if not isinstance(d, dict) or not isinstance(d.get("bounds"), dict):
            raise ValueError("expected an object with bounds")
        missing = {lat.name for lat in latents} - set(d["bounds"])
        if missing:
            raise ValueError(f"no bounds for {sorted(missing)}")
        try:
            bounds = {k: tuple(v) for k, v in d["bounds"].items()}
            narrow, broad = (tuple(x) if isinstance(x, list) else x for x in (d["narrow"], d["broad"]))
            s = cls(bounds, d[noise.name], narrow, broad, d["broad_every"], noise)
        except (KeyError, TypeError) as e:
            raise ValueError(f"missing or malformed {e}") from None
        if s.noise is None:
            raise ValueError(f"{noise.name}: expected a number, got None")
        return s.checked(latents, noise)


@dataclass
class RunConfig:
    """How to run a batch of chains (the paper's protocol by default: 16 x 75)."""
    chains: int = 16
    sweeps: int = 75
    seed: int = 0
    workers: int | None = None          # None: all cores
    speedups: bool = True               # the scenario's exact speed-ups (same decisions either way)
    noise: float | None = None          # None: the scenario's default
    narrow: float | None = None         # proposal half-widths; None: the latents' own
    broad: float | None = None
    broad_every: int | None = None      # None: every 20th sweep is broad
    bounds: dict | None = None          # prior bounds overriding the scene's, per latent
    moves: str = "default"              # "default": warm-up adaptation + the scenario's moves; "paper": section 3.2 as is;
                                        # "fitted": "default" + an independence move fitted to the warm-up (`infer`)
    warmup: int | None = None           # sweeps of width adaptation (None: half of `sweeps`; never with "paper")
    until_rhat: float | None = None     # run on until every latent's R-hat <= this (and ESS >= min_ess) ...
    min_ess: float = MIN_ESS
    max_sweeps: int | None = None       # ... or this many sweeps (None: 20 x sweeps)
    max_seconds: float | None = None    # ... or this many wall seconds since the run began (checked between blocks)
    rhat_target: float = RHAT_TARGET    # what `converged` in a result means (also without until_rhat)
    priors: dict | None = None          # merged into the scene file's "priors" section (e.g. the ramp's
                                        # observation model: {"observation": "student_t", "infer_sigma": true})

    def warmup_sweeps(self) -> int:
        """Sweeps of width adaptation: none with the paper's moves; else `warmup`, by default
        half of `sweeps` (with `until_rhat`: at least 100 sweeps or all of the first block,
        since adaptation needs about that long and the run goes on anyway)."""
        if self.moves == "paper":
            return 0
        if self.warmup is not None:
            return int(self.warmup)
        if self.until_rhat and self.sweep_budget() > self.sweeps:
            return int(max(self.sweeps // 2, min(UNTIL_WARMUP_SWEEPS, self.sweeps)))
        return int(self.sweeps // 2)    # (a budget of the first block alone: a fixed run's, draws kept)

    def sweep_budget(self) -> int:
        return int(self.max_sweeps if self.max_sweeps is not None else max(self.sweeps, 20 * self.sweeps))

    def settings(self, latents: Sequence[Latent], noise: Noise, paper_widths: dict | None = None) -> Settings:
        """The settings the chains start under: the latents' own, with `paper_widths` (the
        scenario's) under the paper's moves, then this config's overrides."""
        s = Settings.default(latents, noise, paper_widths if self.moves == "paper" else None)
        if self.noise is not None:
            s.noise = self.noise
        for name in ("narrow", "broad", "broad_every"):
            if getattr(self, name) is not None:
                setattr(s, name, getattr(self, name))
        if self.bounds:
            s.bounds.update(self.bounds)
        return s.checked(latents, noise)

    def check(self) -> None:
        for what, v in (("chains", self.chains), ("sweeps", self.sweeps)):
            if isinstance(v, bool) or int(v) != v or v < 1:
                raise GalileoError(f"{what} must be an integer >= 1, got {v!r}")
        if self.workers is not None and (int(self.workers) != self.workers or self.workers < 1):
            raise GalileoError(f"workers must be an integer >= 1, got {self.workers!r}")
        if int(self.seed) != self.seed or self.seed < 0:
            raise GalileoError(f"seed must be an integer >= 0, got {self.seed!r}")
        if self.moves not in MOVE_SETS:
            raise GalileoError(f"moves must be one of {', '.join(MOVE_SETS)}, got {self.moves!r}")
        # (a run that keeps no draw after its warm-up has no posterior: a fixed run's warm-up ends
        # before its last sweep; one run until converged may end with its first block)
        most = self.sweeps if self.until_rhat and self.sweep_budget() > self.sweeps else self.sweeps - 1
        if self.warmup is not None and (isinstance(self.warmup, bool) or int(self.warmup) != self.warmup
                                        or not 0 <= self.warmup <= most):
            raise GalileoError(f"warmup must be an integer from 0 to {most} (a run of {self.sweeps} sweeps keeps "
                               f"the draws after it), got {self.warmup!r}")
        if self.moves == "fitted" and self.warmup_sweeps() < FITTED_MIN_WARMUP:
            raise GalileoError(f"moves fitted needs a warm-up of at least {FITTED_MIN_WARMUP} sweeps to fit its move to "
                               f"(this run's: {self.warmup_sweeps()}; --warmup, or more --sweeps)")
        for what, v, lo in (("until_rhat", self.until_rhat, 1.0), ("rhat_target", self.rhat_target, 1.0)):
            if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v) and v > lo):
                raise GalileoError(f"{what} must be a number above {lo:g}, got {v!r}")
        if not (isinstance(self.min_ess, (int, float)) and math.isfinite(self.min_ess) and self.min_ess >= 0):
            raise GalileoError(f"min_ess must be a number >= 0, got {self.min_ess!r}")
        if self.max_sweeps is not None and (isinstance(self.max_sweeps, bool) or int(self.max_sweeps) != self.max_sweeps
                                            or self.max_sweeps < self.sweeps):
            raise GalileoError(f"max_sweeps must be an integer >= the sweeps ({self.sweeps}), got {self.max_sweeps!r}")
        if self.max_seconds is not None:
            if isinstance(self.max_seconds, bool) or not isinstance(self.max_seconds, (int, float)) or not (
                    math.isfinite(self.max_seconds) and self.max_seconds > 0):
                raise GalileoError(f"max_seconds must be a number of seconds above 0, got {self.max_seconds!r}")
            if not self.until_rhat:
                raise GalileoError("max_seconds is a budget of running until converged (until_rhat)")


# -- the problem and the task ----------------------------------------------------------------------

@dataclass(frozen=True)
class Problem:
    """What a worker needs to build a likelihood, as plain JSON (crosses process boundaries;
    no pybullet client ever does), and a key naming it."""
    scenario: str
    scene_json: dict
    tracks_json: dict | list    # a list: the tracks of each video of a problem of several
    key: str

    @classmethod
    def of(cls, scene, tracks) -> Problem:
        """One video's (scene, Tracks), or a problem's (`galileo.joint.JointScene`, [Tracks per video])."""
        scene_json = scene.to_json()
        tracks_json = tracks_to_json(tracks)
        text = json.dumps([scene.scenario, scene_json, tracks_json], sort_keys=True)
        return cls(scene.scenario, scene_json, tracks_json, hashlib.sha1(text.encode()).hexdigest())


class ChainTask(NamedTuple):
    problem: Problem
    chain: int
    position: np.ndarray
    logdensity: float | None    # None: evaluate at the position first (a new or moved chain)
    sweep: int                  # sweeps done so far
    rng_state: dict             # the chain's bit-generator state
    n_sweeps: int
    bounds: np.ndarray          # (D, 2)
    proposal: Proposal
    noise: float
    speedups: bool = True
    independence: object = None   # a galileo.mcmc.Independence: an extra joint move (e.g. from a recognition model)
    moves: tuple = ()             # joint moves (galileo.mcmc: SiteMixture, LogScale, ...) after each sweep's updates
    adapt_until: int = 0          # sweeps 1..adapt_until adapt the narrow widths and the moves' widths (warm-up)


# per-proposal record fields: name -> (dtype, one row of D values per proposal)
PROPOSAL_FIELDS = {"site": (np.int8, False), "proposal": (float, True), "proposal_loglik": (float, False),
                   "accepted": (bool, False), "early_stop": (bool, False), "width": (float, False)}

_likelihoods: dict = {}   # this process's likelihoods: (problem key, noise, speedups) -> likelihood


def likelihood_for(problem: Problem, noise: float, speedups: bool):
    """This process's likelihood for the problem (built once; a new noise builds anew, since
    saved prefixes hold terms scaled by the old one)."""
    key = (problem.key, noise, speedups)
    lik = _likelihoods.get(key)
    if lik is None:
        scene = registry.scene_from_json(problem.scene_json)
        scenario = registry.of(scene)
        tracks = tracks_from_json(problem.tracks_json)
        lik = scenario.likelihood(scenario.prepare(scene, tracks), tracks, noise, speedups)
        _likelihoods.clear()   # one at a time: a worker serves one problem (its worlds are cached too)
        _likelihoods[key] = lik
    return lik


def run_task(task: ChainTask) -> dict:
    """Run `task.n_sweeps` sweeps of one chain; the record of every sweep and proposal."""
    t0 = time.perf_counter()
    lik = likelihood_for(task.problem, task.noise, task.speedups)
    steps0 = lik.steps
    pos = np.asarray(task.position, float).copy()
    logdensity = task.logdensity
    evaluated = logdensity is None
    if evaluated:
        logdensity = float(lik(pos)[0])
    bit_gen = getattr(np.random, task.rng_state["bit_generator"])()
    bit_gen.state = task.rng_state
    rng = np.random.Generator(bit_gen)
    state = MHState(pos, float(logdensity), int(task.sweep))
    positions, logliks, infos = [], [], []
    proposal, moves = task.proposal, tuple(task.moves)
    for _ in range(task.n_sweeps):
        state, inf = sweep(rng, state, lik, task.bounds, proposal, task.speedups,
                           independence=task.independence, moves=moves)
        if state.sweep <= task.adapt_until:
            proposal, moves = adapt(proposal, moves, inf, state.sweep, task.bounds, state.position)
        positions.append(state.position.copy())
        logliks.append(state.logdensity)
        infos.extend(inf)
    dim = len(pos)
    return {"chain": task.chain, "positions": np.array(positions, float).reshape(-1, dim),
            "logliks": np.array(logliks, float), "position": state.position, "logdensity": float(state.logdensity),
            "sweep": int(state.sweep), "rng": bit_gen.state, "evaluated": evaluated,
            "proposal_state": proposal, "moves": moves,
            "site": np.array([i.site for i in infos], np.int8),
            "proposal": np.array([i.proposal for i in infos], float).reshape(-1, dim),
            "proposal_loglik": np.array([i.logdensity for i in infos], float),
            "accepted": np.array([i.accepted for i in infos], bool),
            "early_stop": np.array([i.early_stop for i in infos], bool),
            "width": np.array([i.width for i in infos], float),
            "steps": lik.steps - steps0, "seconds": time.perf_counter() - t0}


def first_task(problem: Problem, chain: int, start, seed: int, n_sweeps: int, settings: Settings,
               names: Sequence[str], speedups: bool = True, independence=None, moves: tuple = (),
               adapt_until: int = 0) -> ChainTask:
    """The task that starts chain `chain` of a run seeded with `seed` at `start`."""
    return ChainTask(problem, chain, np.asarray(start, float), None, 0, chain_rng(seed, chain).bit_generator.state,
                     n_sweeps, settings.bounds_array(names), settings.proposal(), settings.noise, speedups,
                     independence, tuple(moves), int(adapt_until))


def next_task(task: ChainTask, result: dict, n_sweeps: int) -> ChainTask:
    """The task that runs `n_sweeps` more sweeps of the chain `result` left (its position,
    random stream and adapted widths carried on)."""
    return task._replace(position=np.asarray(result["position"], float), logdensity=float(result["logdensity"]),
                         sweep=int(result["sweep"]), rng_state=result["rng"], n_sweeps=int(n_sweeps),
                         proposal=result["proposal_state"], moves=tuple(result["moves"]))


# -- executors ---------------------------------------------------------------------------------------

def _ignore_sigint() -> None:
    import signal

    if mp.parent_process() is not None:  # in a worker: Ctrl-C is the parent's to handle
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        # and a SIGTERM (the pool ending its workers) ends it at once: a forked worker inherits the
        # parent's handler (`galileo.errors`), which would raise in it and print from its shutdown
        # onto the parent's stderr
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


@contextlib.contextmanager
def _workers_born_deaf_to_sigterm():
    """While the pool forks its workers: SIGTERM at the system's default in this process (the
    main thread's to set; elsewhere nothing is changed), so that a forked worker is born with it.
    The initializer sets it too, but a worker may wait its turn to run that while another answers
    every ping, and a SIGTERM meanwhile ran the parent's raising handler in it (it then hung on
    its way out). The parent's own handler is back as soon as the forks are made."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, before)


def _ping(_=None) -> int:
    return os.getpid()


class WorkerDied(GalileoError):
    """A worker process of a LocalPool died (the pool is broken and must be made anew)."""


class WorkerHung(WorkerDied):
    """No result from a LocalPool's workers within a map's deadline (a worker stopped, or stuck):
    its workers were killed, so the pool is broken like a dead worker's. `timeout_s`: the deadline."""

    def __init__(self, message: str, timeout_s: float):
        super().__init__(message)
        self.timeout_s = timeout_s


class InProcess:
    """The executor of `workers=1`: tasks run here, one after another (starting, like a new
    pool, without likelihoods kept from earlier runs)."""

    workers = 1

    def __init__(self):
        _likelihoods.clear()

    def map(self, fn, iterable: Iterable):
        return map(fn, iterable)

    def shutdown(self) -> None:
        pass


class LocalPool:
    """Worker processes (each with its own pybullet client and likelihood cache), all started
    at once. `context` "fork" (the default) copies this process as it is: make such a pool from
    the calling thread before any other thread exists (a fork copies only the calling thread,
    and every open socket). "spawn" starts each worker afresh (a few seconds): what a pool made
    later, with threads and sockets about (the app's viewer), must use; its workers know the
    built-in scenarios, not ones `registry.register`ed at run time."""

    def __init__(self, workers: int, context: str = "fork"):
        self.workers = int(workers)
        self.context = context
        self._pool = ProcessPoolExecutor(self.workers, mp_context=mp.get_context(context), initializer=_ignore_sigint)
        try:
            with _workers_born_deaf_to_sigterm():
                futures = [self._pool.submit(_ping) for _ in range(self.workers)]   # forks them all
            for f in futures:
                f.result()
        except BrokenProcessPool as e:
            self._pool.shutdown(wait=True, cancel_futures=True)
            raise WorkerDied(f"inference workers failed to start: {e}") from None
        self._procs = dict(self._pool._processes)   # pid -> Process (kept: a broken pool forgets them)
        self._hung: list[dict] | None = None           # the workers blamed when a map passed its deadline

    def pids(self) -> list[int]:
        """The worker processes' ids."""
        return sorted(self._procs)

    def map(self, fn, iterable: Iterable, timeout_s: float | None = None):
        """`fn` over `iterable` in the workers, results in order. WorkerDied when a worker dies;
        WorkerHung when not every result has come `timeout_s` after the first is asked for (the
        workers are then killed: one that stopped or is stuck would otherwise hold the pool)."""
        try:
            yield from self._pool.map(fn, iterable, timeout=timeout_s)
        except BrokenProcessPool:
            self._pool.shutdown(wait=True, cancel_futures=True)   # the others are stopped; states known
            dead = self.dead_workers()
            said = "; ".join(f"pid {w['pid']} {w['how']}" for w in dead)
            if any(w["how"] == "killed by SIGKILL" for w in dead):
                said += " (the system's out-of-memory killer sends SIGKILL: fewer --workers use less memory)"
            raise WorkerDied(f"an inference worker died: {said}") from None
        except TimeoutError:
            self._hung = self._unresponsive()
            self._kill()
            said = "; ".join(f"pid {w['pid']} {w['how']}" for w in self._hung)
            raise WorkerHung(f"no result from the inference workers in {timeout_s:.0f} s ({said}): "
                             "they were killed", timeout_s) from None

    def _unresponsive(self) -> list[dict]:
        """The workers to blame for a map past its deadline, as `dead_workers` lists them: those
        stopped (SIGSTOP, a debugger), else those busy, else every one."""
        import psutil

        def state(pid):
            try:
                return psutil.Process(pid).status()
            except psutil.Error:
                return "gone"
        states = {pid: state(pid) for pid in sorted(self._procs)}
        stopped = [pid for pid, st in states.items() if st in (psutil.STATUS_STOPPED, psutil.STATUS_TRACING_STOP)]
        busy = [pid for pid, st in states.items() if st in (psutil.STATUS_RUNNING, psutil.STATUS_DISK_SLEEP)]
        how = "stopped" if stopped else "not answering"
        return [{"pid": pid, "exitcode": None, "how": how} for pid in (stopped or busy or sorted(states))]

    def _kill(self) -> None:
        """SIGKILL every worker (a stopped one too) and shut the broken pool down."""
        for p in self._procs.values():
            if p.exitcode is None:
                p.kill()
        self._pool.shutdown(wait=True, cancel_futures=True)

    def dead_workers(self) -> list[dict]:
        """After a `WorkerDied` and `shutdown`: the workers that died of their own, as
        {"pid", "exitcode", "how"} (the pool terminates the others with SIGTERM; a worker that
        was itself sent SIGTERM is among them, so with none found every worker is listed);
        after a `WorkerHung`, those blamed for it ("stopped" or "not answering")."""
        import signal

        if self._hung is not None:
            return list(self._hung)

        def how(code):
            if code is None:
                return "still running"
            if code < 0:
                try:
                    return f"killed by {signal.Signals(-code).name}"
                except ValueError:
                    return f"killed by signal {-code}"
            return f"exited with code {code}"
        every = [{"pid": pid, "exitcode": p.exitcode, "how": how(p.exitcode)} for pid, p in sorted(self._procs.items())]
        own = [w for w in every if w["exitcode"] not in (None, -signal.SIGTERM)]
        return own or every

    def shutdown(self) -> None:
        """Let the workers finish and exit; any that has not within SHUTDOWN_GRACE_S (stopped,
        stuck) is killed, so closing never hangs on one."""
        self._pool.shutdown(wait=False, cancel_futures=True)
        deadline = time.monotonic() + SHUTDOWN_GRACE_S
        for p in self._procs.values():
            p.join(max(0.0, deadline - time.monotonic()))
            if p.exitcode is None:
                p.kill()
        self._pool.shutdown(wait=True)


def local_executor(workers: int | None, n_tasks: int | None = None):
    """LocalPool with `workers` processes (None: all cores; no more than the tasks), or
    InProcess for one."""
    n = max(1, int(workers or os.cpu_count() or 1))
    if n_tasks is not None:
        n = max(1, min(n, n_tasks))
    return InProcess() if n == 1 else LocalPool(n)


# -- the batch run -----------------------------------------------------------------------------------

def infer(scene, tracks: Tracks, config: RunConfig | None = None, *, executor=None, progress: bool = True,
          init=None):
    """Run `config.chains` chains on a video's tracks; an `InferenceResult` (MAP, posterior,
    diagnostics, every proposal).

    Moves (`config.moves`): "paper" is section 3.2 as published (single-site uniform proposals,
    a broad sweep every 20th). "default" adds, during the first `warmup` sweeps, adaptation of
    each latent's narrow width towards acceptance 0.44, and the scenario's own joint moves
    (`Scenario.moves`, e.g. the ramp's k1 from the tracked acceleration and its mass-ratio
    moves), each exact; the kept draws (after max(warm-up, half the chain)) come from one
    fixed kernel. "fitted" runs the warm-up alone first, then adds to every chain
    FITTED_PER_SWEEP proposals a sweep from a kernel density estimate of all chains' warm-up
    draws (`fitted_kernel`), FITTED_CONDITIONALS of each latent from its conditional given the
    others under a t fitted to them (`fitted_move`) and FITTED_MARGINALS of each latent the
    others barely determine from its warm-up draws' density (`fitted_marginals`,
    `fitted_moves`), frozen from then on.

    With `config.until_rhat`, chains run `config.sweeps` sweeps and then on, in blocks of a
    tenth of what they have done (at least 10: `block_after`), until every latent's rank-normalised split R-hat is at
    most `until_rhat` and its bulk and tail ESS at least `min_ess`, or until `max_sweeps`.
    A chain's draws depend only on (seed, chain, settings): how the sweeps are cut into blocks
    does not change them. With `progress`, the bar counts sweeps as they are done: each chain's
    sweeps run in pieces of about PROGRESS_PIECE_S (`_run_block`), the same chains.

    `init(prepared_scene, names, bounds, n_chains, seed, integer_sites) -> Init` may choose
    where the chains start and add an independence move (`galileo.recognition.model.recognition_init`);
    by default chains start where the scenario says (drawn from the prior)."""
    cfg = config or RunConfig()
    cfg.check()
    t0 = time.perf_counter()
    scene = scene_for_moves(scene, cfg.moves, cfg.priors)
    scenario = registry.of(scene)
    prepared = scenario.prepare(scene, tracks)
    latents = scenario.latents(prepared)
    names = tuple(lat.name for lat in latents)
    try:
        settings = cfg.settings(latents, scenario.noise, scenario.paper_widths)
    except ValueError as e:
        raise GalileoError(str(e)) from None
    bounds = settings.bounds_array(names)
    chosen = init(prepared, names, bounds, cfg.chains, cfg.seed, settings.integer_sites) if init is not None else None
    if chosen is not None and chosen.starts is not None:
        starts = np.asarray(chosen.starts, float)
        if starts.shape != (cfg.chains, len(names)) or not np.all((starts >= bounds[:, 0]) & (starts <= bounds[:, 1])):
            raise GalileoError("chain starts must be one point per chain inside the prior's bounds")
    else:
        starts = scenario.initial_positions(prepared, latents, bounds, cfg.chains, cfg.seed)
    independence = chosen.independence if chosen is not None else None
    moves = default_moves(scenario, prepared, tracks, latents, bounds, settings) if cfg.moves != "paper" else ()
    warmup = cfg.warmup_sweeps()
    # "fitted": the warm-up first, alone, then the move fitted to it joins every chain's moves
    fit_at = (warmup if cfg.moves == "fitted" and FITTED_MIN_WARMUP <= warmup
              and (warmup < cfg.sweeps or cfg.until_rhat) else None)
    problem = Problem.of(scene, tracks)
    tasks = [first_task(problem, c, starts[c], cfg.seed, fit_at or cfg.sweeps, settings, names, cfg.speedups,
                        independence, moves, warmup) for c in range(cfg.chains)]
    own = executor is None
    if own:
        executor = local_executor(cfg.workers, cfg.chains)
    workers = getattr(executor, "workers", 1)
    done: list[list[dict]] = [[] for _ in range(cfg.chains)]
    budget = cfg.sweep_budget() if cfg.until_rhat else cfg.sweeps
    status = None
    stopped = None                        # why running until converged stopped (result's "stopped")
    t_first, first_done = t0, 0           # the pace of the blocks after the first (with max_seconds)
    try:
        with tqdm(total=cfg.chains * cfg.sweeps, desc="sweeps" if cfg.until_rhat else "chains",
                  unit="sweep", unit_scale=False, disable=not progress) as bar:
            while True:
                _run_block(executor, tasks, done, bar, piecewise=progress)
                n_done = int(done[0][-1]["sweep"])
                if n_done == fit_at:
                    warm = [np.concatenate([r["positions"] for r in rs]) for rs in done]
                    q = fitted_move(latents, bounds, warm, warmup)
                    moves = moves + fitted_moves(q, marginals=fitted_marginals(latents, bounds, warm, warmup, q),
                                                 kernel=fitted_kernel(latents, bounds, warm, warmup))
                    if n_done < cfg.sweeps:
                        tasks = _joined([next_task(tasks[c], done[c][-1], cfg.sweeps - n_done)
                                         for c in range(cfg.chains)], moves)
                        continue
                if not cfg.until_rhat:
                    break
                samples = [np.concatenate([r["positions"] for r in rs]) for rs in done]
                status = convergence(kept_draws(samples, warmup), names, cfg.until_rhat, cfg.min_ess)
                bar.set_postfix_str(status["summary"], refresh=False)
                stopped = ("converged" if status["converged"] else "max_sweeps" if n_done >= budget else None)
                more = block_after(n_done, budget)
                if stopped is None and cfg.max_seconds is not None:
                    # the time left allows so many sweeps at the pace so far (at least one block of MIN_BLOCK_SWEEPS)
                    left_s = cfg.max_seconds - (time.perf_counter() - t0)
                    pace = (time.perf_counter() - t_first) / max(n_done - first_done, 1) if first_done else None
                    if left_s <= 0 or (pace and left_s < pace * min(MIN_BLOCK_SWEEPS, more)):
                        if n_done > warmup:
                            stopped = "max_seconds"
                        else:   # no draw kept yet (the warm-up outlasted the budget): one short block more
                            more = min(MIN_BLOCK_SWEEPS, more)
                    elif pace:
                        more = max(min(more, int(left_s / pace)), min(MIN_BLOCK_SWEEPS, more))
                if stopped:
                    break
                if not first_done:
                    t_first, first_done = time.perf_counter(), n_done
                bar.total += cfg.chains * more
                bar.refresh()
                tasks = _joined([next_task(tasks[c], done[c][-1], more) for c in range(cfg.chains)], moves)
    finally:
        if own:
            executor.shutdown()
    merged = [_merge(rs) for rs in done]
    proposals = {k: np.stack([r[k] for r in merged]) for k in PROPOSAL_FIELDS}
    wall = time.perf_counter() - t0
    info = dict(chosen.info) if chosen is not None else {"starts": "prior"}
    move_names = (["independence"] if independence is not None else []) + list(dict.fromkeys(m.name for m in moves))
    adapted = {"narrow": [_plain_widths(r["proposal_state"].narrow) for r in merged],
               "moves": [{m.name: float(m.width) for m in r["moves"] if hasattr(m, "width")} for r in merged]}
    return InferenceResult(
        scenario=scenario.name, names=names, samples=np.stack([r["positions"] for r in merged]),
        logliks=np.stack([r["logliks"] for r in merged]), starts=starts, proposals=proposals, config=cfg,
        settings=settings, timing_s={"wall": wall, "chains_cpu": float(sum(r["seconds"] for r in merged)),
                                     "workers": workers},
        steps=int(sum(r["steps"] for r in merged)), scene=prepared, init=info, warmup=warmup,
        moves={"set": cfg.moves, "joint": move_names, "codes": _move_codes(independence, moves),
               "adapted": adapted if warmup else None}, tracks=tracks, stopped=stopped)


MIN_BLOCK_SWEEPS = 10
BLOCK_FRACTION = 0.1   # running until converged checks after each tenth more of the sweeps done


def block_after(n_done: int, budget: int) -> int:
    """How many sweeps running until converged adds after `n_done` (BLOCK_FRACTION of them, at
    least MIN_BLOCK_SWEEPS, within the `budget`): `infer`'s blocks and the app's. A check costs
    a few tens of ms (R-hat and ESS over the kept draws); with blocks of half the sweeps done
    (before), the demo with the fitted move converged at sweep 160 and was told so at 225."""
    return min(max(MIN_BLOCK_SWEEPS, math.ceil(n_done * BLOCK_FRACTION)), budget - n_done)


JOINT_LOG_SD = 0.3


def _run_block(executor, tasks: list[ChainTask], done: list[list[dict]], bar, piecewise: bool) -> None:
    """Run the tasks (one per chain, the same sweeps each), appending each chain's records to
    done[chain] and moving the bar. `piecewise` (a bar is shown): in pieces of sweeps, the first
    one sweep, then each sized to take about PROGRESS_PIECE_S by the last piece's slowest sweep,
    so that the bar moves (as each piece ends) however long a chain is. A chain's draws do not
    depend on how its sweeps are cut (`next_task`): the chains are the same bit for bit."""
    left = tasks[0].n_sweeps
    n = 1 if piecewise else left
    current = list(tasks)
    while True:
        n = min(n, left)
        slowest_s = 0.0
        for r in executor.map(run_task, [t._replace(n_sweeps=n) for t in current]):
            done[r["chain"]].append(r)
            bar.update(len(r["logliks"]))
            slowest_s = max(slowest_s, float(r["seconds"]) / n)
        left -= n
        if not left:
            return
        current = [next_task(t, done[t.chain][-1], n) for t in current]
        n = max(1, int(PROGRESS_PIECE_S / slowest_s)) if slowest_s > 0 else left


def scene_for_moves(scene, moves: str, priors: dict | None = None):
    """The scene a move set infers on: with "paper", the scenario's `paper_priors` (its
    paper's own likelihood, e.g. the ramp's Gaussian) merged into its priors; then `priors`."""
    overrides = {**(registry.of(scene).paper_priors if moves == "paper" else {}), **(priors or {})}
    return with_priors(scene, overrides) if overrides else scene


def with_priors(scene, overrides: dict):
    """The scene with `overrides` merged into its scene file's "priors" section, parsed and
    checked by its scenario (GalileoError naming the field)."""
    from .errors import SceneError

    if not isinstance(overrides, dict):
        raise GalileoError(f"priors overrides must be a JSON object, got {overrides!r}")
    d = scene.to_json()
    merged = dict(d.get("priors") or {})
    merged.update(overrides)
    d["priors"] = merged
    try:
        return registry.scene_from_json(d)
    except SceneError as e:
        raise GalileoError(f"--priors: {e}") from None


def _joined(tasks: list[ChainTask], moves: tuple) -> list[ChainTask]:
    """The tasks with the moves they lack of `moves` (the fitted move, after the warm-up) appended."""
    return [t._replace(moves=tuple(t.moves) + tuple(moves[len(t.moves):])) for t in tasks]


def fitted_move(latents: Sequence[Latent], bounds: np.ndarray, chains: Sequence[np.ndarray], warmup: int):
    """The "fitted" move set's independence move (`galileo.mcmc.FittedIndependence`) over every
    continuous latent (in log for those the adaptive walk takes in log), fitted to the second half
    of every chain's warm-up draws pooled; None if it cannot be fitted."""
    sites = [j for j, lat in enumerate(latents) if not lat.integer]
    return fit_independence(_warm_draws(chains, warmup), sites, _log_sites(latents, bounds, sites), bounds)


def _warm_chains(chains: Sequence[np.ndarray], warmup: int) -> list[np.ndarray]:
    """The second half of every chain's warm-up draws, a chain each: what the fitted moves are fitted to."""
    return [np.asarray(c, float)[warmup // 2:warmup] for c in chains]


def _warm_draws(chains: Sequence[np.ndarray], warmup: int) -> np.ndarray:
    """`_warm_chains`, pooled."""
    return np.concatenate(_warm_chains(chains, warmup))


def fitted_kernel(latents: Sequence[Latent], bounds: np.ndarray, chains: Sequence[np.ndarray], warmup: int):
    """The "fitted" move set's joint move (`galileo.mcmc.FittedKernel`): a kernel density
    estimate over every continuous latent (in log where `fitted_move` takes it) of the second
    half of every chain's warm-up draws, its kernels of the chains' own spread; None if it
    cannot be fitted."""
    from .mcmc import fit_kernel

    sites = [j for j, lat in enumerate(latents) if not lat.integer]
    return fit_kernel(_warm_chains(chains, warmup), sites, _log_sites(latents, bounds, sites), bounds)


def fitted_marginals(latents: Sequence[Latent], bounds: np.ndarray, chains: Sequence[np.ndarray], warmup: int,
                     q) -> tuple:
    """The "fitted" move set's marginal moves (`galileo.mcmc.FittedMarginal`): one for each
    latent of q that the others barely determine (under q's scale, its conditional sd given
    them at least MARGINAL_MIN_SD_RATIO of its own: a proposal from its marginal is then about
    as likely accepted as one from its conditional, and it proposes every region the warm-up
    visited), fitted to the second half of every chain's warm-up draws pooled (`fitted_move`'s
    draws); none without q."""
    from .mcmc import conditionals_of, fit_marginal

    if q is None:
        return ()
    scale = np.asarray(q.chol, float)
    sd = np.sqrt(np.diag(scale @ scale.T))
    draws = _warm_draws(chains, warmup)
    out = []
    for k, cond in enumerate(conditionals_of(q)):
        if math.sqrt(cond.var) >= MARGINAL_MIN_SD_RATIO * sd[k]:
            out.append(fit_marginal(draws[:, cond.site], cond.site, cond.log, bounds[cond.site]))
    return tuple(m for m in out if m is not None)


def fitted_moves(q, per_sweep: int | None = None, conditionals: int | None = None, marginals: tuple = (),
                 marginals_per_sweep: int | None = None, kernel=None) -> tuple:
    """The moves the fitted q adds to every chain after the warm-up: `per_sweep`
    (FITTED_PER_SWEEP) joint proposals from the `kernel` (`fitted_kernel`; without one, from q),
    then `conditionals` (FITTED_CONDITIONALS) of each latent from q's conditional given the
    others (`galileo.mcmc.FittedConditional`), then `marginals_per_sweep` (FITTED_MARGINALS) of
    each of the `marginals` (`fitted_marginals`); none without a q. (The app records the counts,
    the kernel and the marginals with q: a session keeps the moves it ran.)"""
    from .mcmc import conditionals_of

    per_sweep = FITTED_PER_SWEEP if per_sweep is None else int(per_sweep)
    conditionals = FITTED_CONDITIONALS if conditionals is None else int(conditionals)
    marginals_per_sweep = FITTED_MARGINALS if marginals_per_sweep is None else int(marginals_per_sweep)
    if q is None:
        return ()
    joint = q if kernel is None else kernel
    return (joint,) * per_sweep + conditionals_of(q) * conditionals + tuple(marginals) * marginals_per_sweep


def _log_sites(latents: Sequence[Latent], bounds: np.ndarray, sites: Sequence[int]) -> list[int]:
    """The sites moved in log: bounded away from 0 above 0 and not dimensionless (masses)."""
    return [j for j in sites if latents[j].limits[0] >= 0 and bounds[j, 0] > 0 and latents[j].unit != "1"]


def default_moves(scenario, prepared, tracks: Tracks, latents: Sequence[Latent], bounds: np.ndarray,
                  settings: Settings) -> tuple:
    """The default move set's joint moves: the scenario's own, then an adaptive joint random
    walk over every continuous latent (log scale for those bounded away from 0 above 0, like
    masses) that learns the posterior's correlations in warm-up."""
    moves = list(scenario.moves(prepared, tracks, latents, bounds))
    sites = [j for j, lat in enumerate(latents) if not lat.integer]
    if len(sites) >= 2 and scenario.adaptive_walk:
        log_sites = _log_sites(latents, bounds, sites)
        narrow = settings.narrow
        # the first covariance: the narrow widths, and 0.3 in log (a 35 % step) for log sites
        sd = [JOINT_LOG_SD if j in log_sites else float(narrow[j] if isinstance(narrow, tuple) else narrow)
              for j in sites]
        moves.append(JointRW.initial(sites, log_sites, sd))
    return tuple(moves)


def _merge(results: list[dict]) -> dict:
    """One chain's block records joined into one (the last block's state)."""
    out = dict(results[-1])
    for k in ("positions", "logliks", *PROPOSAL_FIELDS):
        out[k] = np.concatenate([r[k] for r in results])
    out["steps"] = sum(r["steps"] for r in results)
    out["seconds"] = sum(r["seconds"] for r in results)
    return out


def _plain_widths(w):
    return [float(x) for x in w] if isinstance(w, (tuple, list, np.ndarray)) else float(w)


def _move_codes(independence, moves) -> dict:
    """The proposal record's site code of each joint move (see `galileo.mcmc.sweep`)."""
    from .mcmc import move_code

    codes: dict = {"independence": -1} if independence is not None else {}
    for k, m in enumerate(moves):   # (a move made several times a sweep: all its codes)
        codes[m.name] = [*np.atleast_1d(codes[m.name]).tolist(), move_code(k)] if m.name in codes else move_code(k)
    return codes


@dataclass
class Init:
    """Where chains start and an optional extra move, chosen for a run (see `infer`'s `init`)."""
    starts: np.ndarray | None = None      # (chains, D), inside the prior's bounds
    independence: object = None          # a galileo.mcmc.Independence used every `every` sweeps
    info: dict = field(default_factory=dict)   # what result.json records about it
