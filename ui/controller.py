"""Live, steerable inference: the API the browser app's viewer and rerun logger call.

The chains are those of the one chain runner, `galileo.runner` (the same task function,
`run_task`, the same random streams and starts, for any scenario), run round by round so
that they can be watched and steered:

* A round sends one sweep of every running chain to the executor (`galileo.runner.LocalPool`
  by default: forked workers, each building the scenario's likelihood once). The parent holds
  every chain's state (position, logdensity, sweep count, numpy bit-generator state) and sends
  it with the task, so a chain's random stream is the same whatever worker runs it, and a seed
  gives the batch runner's chains bit for bit, for any number of workers.
* `start()` runs rounds in a background thread, `run_sweeps(n)` runs n rounds synchronously.
* Steering (`set_bounds`, `set_noise`, `set_widths`, `pause`, `resume`, `add_chains`,
  `remove_chain`, `reset_chain`, `set_chain`) is thread-safe and applies between rounds: a
  round in flight finishes with the old settings, and the change, queued, applies right after
  it. Each change is recorded as an event

      {"sweep": rounds completed when it took effect (the global sweep count),
       "time": unix time, "kind": ..., "detail": {...},
       "chain_sweeps": {"<chain>": that chain's sweep count then, for every active chain}}

  so a chain's samples from index chain_sweeps[c] on were drawn under the change.
* A chain whose position or target changed (noise changed, a bound shrank past it, reset or
  set by hand) has its logdensity recomputed in the worker at the start of its next sweep,
  before proposing; a new chain's is computed there too (as `galileo.mcmc.init` does).
* Listeners `fn(kind, payload)` are called from the thread that runs the rounds (outside the
  controller's lock): "sweeps" after each round with {"round", "results": [(chain, sweep,
  loglik, values), ...]} where `sweep` is the chain's sweep count (its sample index + 1), and
  "event" with each event dict, in the order things happened. Without a background thread
  an event is delivered by the steering call itself. "error" with {"message"} if a round fails
  in the background thread (the thread then stops). "session" with {"text", "saving"} when
  the session folder was lost (see below).
* A worker process that dies (killed, out of memory) breaks the pool: the round's results,
  none committed, are dropped, the pool is made anew (spawned: other threads exist by then)
  and the round runs again from the chains' committed state and random streams, so the
  chains are those of a run in which nothing died. A "worker_died" event records it (the
  sweep, which workers and how, the restarts so far), a line on stderr says it, and
  `status()["workers"]` carries it for the viewer. A worker that stops answering (stopped,
  stuck) is handled the same way: a round whose results have not all come within its deadline
  (ROUND_DEADLINE_FLOOR_S plus ROUND_DEADLINE_FACTOR times the slowest sweep so far times the
  sweeps a worker runs in the round) kills the pool's workers and runs again on a new pool (the
  event's `cause` is "hung"). After WORKER_DEATHS_IN_A_ROW deaths or hangs with no round
  completed between them (deaths within WORKER_DEATHS_WINDOW_S; a hang takes its deadline to
  notice, so hangs count however far apart), every running chain pauses instead (a "pause"
  event with the reason); resuming starts a new pool. `resume` also restarts the background
  thread when an error stopped it.
* With a `session_dir` the state is saved there (see `ui.session`) at most every
  `save_every_s` while rounds run, on `stop()`, `close()` and `save()`; `Controller.load`
  restores it exactly and the chains go on as if never interrupted (with `paused=True`, as
  the app reopens a session, they wait for Resume). The controller holds the session's lock
  (`ui.session.SessionLock`) until `close()`: a second controller or app on the folder is
  refused. A folder deleted, moved or replaced while the controller runs is noticed at the
  next save (checked at least every `save_every_s` while the background thread runs): nothing
  more is written there; the whole session is written to `<name>-recovered-<time>/` beside it
  and saved there from then on (`ui.session.recover`), or, if that fails, nothing is saved.
  Either way a line on stderr and `status()["session"]` say so.
* Moves (`moves`, as `galileo infer --moves`): "default" gives every chain the default move
  set's exact joint moves (`galileo.runner.default_moves`: the scenario's own and an adaptive
  joint random walk) and adapts its narrow widths (and the moves' widths)
  during the chain's own first `warmup` sweeps (default: half the sweep target), carrying each
  chain's adapted proposal and moves from round to round as `galileo.runner.next_task` does;
  "paper" is Galileo section 3.2 as published. Either way a seed gives `galileo infer`'s
  chains bit for bit. A width edit (`set_widths`) replaces every chain's adapted widths from
  that sweep on and ends adaptation; steering a chain (`set_chain`, `reset_chain`) keeps them.
* Sweep target and run until converged: a running chain pauses ("held") when it reaches the
  `sweeps` target. With `until_rhat` (or `run_until`), once every active chain has stopped,
  the kept draws (after max(warm-up, half)) are checked with `galileo.results.convergence`;
  unless every latent's R-hat <= until_rhat and its bulk and tail ESS >= min_ess, or the
  target has reached `max_sweeps`, the target grows as the batch runner's blocks do and the
  held chains run on (an "until_check" event records each verdict).
* `status()` carries the convergence verdict per latent (why not), the scenario's derived
  quantities' posterior (e.g. the ramp's mass ratio) on the same kept draws, and the MAP;
  the MAP compares only samples scored under the noise in force (a sigma edit changes every
  log-likelihood's scale): until a sample under a new sigma exists it is pending (None).
"""
from __future__ import annotations

import copy
import json
import logging
import math
import os
import sys
import threading
import time
from collections import deque
from pathlib import Path
from typing import Callable

import numpy as np

from galileo import registry
from galileo.datatypes import Tracks
from galileo.errors import GalileoError
from galileo.joint import tracks_from_json, tracks_to_json
from galileo.latents import as_number, by_name, check_bounds, check_noise, check_widths
from galileo.mcmc import chain_rng, move_code
from galileo.results import MIN_ESS, RHAT_TARGET, burn_in, convergence, derived_summaries, identified
from galileo.runner import (FITTED_CONDITIONALS, FITTED_MARGINALS, FITTED_MIN_WARMUP, FITTED_PER_SWEEP,
                            MIN_BLOCK_SWEEPS, MOVE_SETS, PROPOSAL_FIELDS, ChainTask, LocalPool,
                            Problem, RunConfig, Settings, WorkerDied, WorkerHung, block_after, default_moves,
                            fitted_kernel, fitted_marginals, fitted_move, fitted_moves, run_task,
                            scene_for_moves)

from . import session as sess

log = logging.getLogger(__name__)

Listener = Callable[[str, dict], None]
PAPER_SWEEPS = 75          # the paper's sweeps per chain (the sweep target's and warm-up's default)
# worker deaths: the pool is made anew and the round run again, unless this many died in a row
# (no round completed between them) within this many seconds: then every chain pauses
WORKER_DEATHS_IN_A_ROW = 3
SAVE_RETRIES = 3           # periodic saves failing in a row, the folder still there, before inference stops
WORKER_DEATHS_WINDOW_S = 60.0
# a round's deadline (then its workers count as hung): this floor (a new pool's first round builds
# its likelihoods; a busy machine) plus this many times the slowest sweep so far, per sweep a worker runs
ROUND_DEADLINE_FLOOR_S = 60.0
ROUND_DEADLINE_FACTOR = 10.0


# -- chain state -----------------------------------------------------------------------------------------

class _Buf:
    """A growable array (amortised appends; `get` copies the filled part)."""

    def __init__(self, dtype, width: int | None = None, data: np.ndarray | None = None):
        self.width = width
        if data is not None:
            self.a = np.array(data, dtype=dtype).reshape((-1,) if width is None else (-1, width))
            self.n = len(self.a)
        else:
            self.a = np.empty((16,) if width is None else (16, width), dtype)
            self.n = 0

    def extend(self, rows) -> None:
        rows = np.asarray(rows, self.a.dtype)
        k = len(rows)
        if self.n + k > len(self.a):
            new = np.empty((max(2 * len(self.a), self.n + k, 16),) + self.a.shape[1:], self.a.dtype)
            new[:self.n] = self.a[:self.n]
            self.a = new
        self.a[self.n:self.n + k] = rows
        self.n += k

    def get(self) -> np.ndarray:
        return self.a[:self.n].copy()

    def __len__(self) -> int:
        return self.n


class _Chain:
    def __init__(self, cid: int, start: np.ndarray, rng_state: dict, dim: int, proposal=None, moves: tuple = ()):
        self.id = cid
        self.start = np.asarray(start, float).copy()
        self.position = self.start.copy()
        self.logdensity: float | None = None   # None: evaluate at the start of the next sweep
        self.sweep = 0
        self.paused = False
        self.held = False      # paused by the sweep target (not by a user); run until converged resumes it
        self.removed = False
        self.rng_state = rng_state
        self.proposal = proposal   # galileo.mcmc.Proposal: the widths of its next sweep (adapted in warm-up)
        self.moves = tuple(moves)  # its joint moves (widths adapted in warm-up)
        self.samples = _Buf(float, dim)
        self.logliks = _Buf(float)
        self.noise = _Buf(float)   # the noise (sigma) each sample's loglik was computed under
        self.proposals = {k: _Buf(t, dim if wide else None) for k, (t, wide) in PROPOSAL_FIELDS.items()}
        self.best: dict[float, tuple[int, float]] = {}   # noise -> (sample index, loglik) of the best sample under it

    def note_best(self, first: int = 0) -> None:
        ll = self.logliks.a[:self.logliks.n]
        noise = self.noise.a[:self.noise.n]
        for i in range(first, len(ll)):
            b = self.best.get(float(noise[i]))
            if b is None or ll[i] > b[1]:
                self.best[float(noise[i])] = (i, float(ll[i]))

    def to_json(self, table: dict | None = None) -> dict:
        """The chain as chains.json records it; with a `table` (move -> index, shared by every
        chain of a save), its joint moves as indices into that table (the fitted moves, the
        same in every chain and each many times a sweep, are then written once)."""
        moves = ([sess.move_to_json(m) for m in self.moves] if table is None
                 else [_table_index(table, m) for m in self.moves])
        return {"id": self.id, "start": self.start.tolist(), "position": self.position.tolist(),
                # (-inf, a position outside the model's support, is stored as "evaluate again")
                "logdensity": self.logdensity if self.logdensity is not None and math.isfinite(self.logdensity)
                else None, "sweep": self.sweep, "paused": self.paused, "held": self.held,
                "removed": self.removed, "rng": self.rng_state, "n_samples": len(self.samples),
                "n_proposals": len(self.proposals["site"]),
                "proposal": sess.proposal_to_json(self.proposal), "moves": moves}


def _table_index(table: dict, move) -> int:
    """The index of `move` in a save's move table (key -> (index, move)), added if new. Moves
    are keyed by type and value (two NamedTuples of different types compare equal as tuples);
    one that cannot be hashed (a field holding a list) by its JSON."""
    key = (type(move), move)
    try:
        hash(key)
    except TypeError:
        key = json.dumps(sess.move_to_json(move), sort_keys=True)
    if key not in table:
        table[key] = (len(table), move)
    return table[key][0]


def _recorded_move(m, table: list, tabled: dict, dim: int):
    """A chain's recorded joint move: an index into chains.json's move table (read once, then
    shared), or the move itself (a session recorded before the table); ValueError if damaged."""
    if isinstance(m, dict):
        return sess.move_from_json(m, dim)
    if isinstance(m, bool) or not isinstance(m, int) or not 0 <= m < len(table):
        raise ValueError(f"joint move {m!r:.40} is neither a move nor an index into the move table of {len(table)}")
    if m not in tabled:
        tabled[m] = sess.move_from_json(table[m], dim)
    return tabled[m]


def _inside(x: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """Whether latent vectors (..., D) lie inside prior bounds (D, 2), per vector."""
    return np.all((x >= bounds[:, 0]) & (x <= bounds[:, 1]), axis=-1)


def _checked_init(info: dict, dim: int) -> dict:
    """A session's recorded init, its proposal checked (a damaged one starts later chains
    from the prior instead)."""
    q = info.get("proposal")
    if q is not None:
        from galileo.mcmc import Independence

        try:
            Independence(tuple(q["kinds"]), tuple(float(x) for x in q["loc"]),
                         tuple(float(x) for x in q["scale"])).check()
            if len(q["kinds"]) != dim:
                raise ValueError("length")
        except (KeyError, TypeError, ValueError):
            log.warning("the session's recorded recognition proposal is damaged; new chains start from the prior")
            return {k: v for k, v in info.items() if k != "proposal"}
    return info


# -- the controller ------------------------------------------------------------------------------------------

class Controller:
    """Live multi-chain MH over Bullet with steering, listeners and recorded sessions."""

    def __init__(self, scene, tracks: Tracks, *, chains: int = 16, seed: int = 0,
                 workers: int | None = None, settings: Settings | None = None,
                 session_dir: str | Path | None = None, save_every_s: float = 1.0, executor=None, init=None,
                 moves: str = "default", sweeps: int | None = PAPER_SWEEPS, warmup: int | None = None,
                 until_rhat: float | None = None, min_ess: float = MIN_ESS, max_sweeps: int | None = None,
                 session_lock: sess.SessionLock | None = None):
        """`executor`: anything with `map` (default: a `galileo.runner.LocalPool` of `workers`
        processes, always separate processes: the viewer simulates in this one). `session_lock`:
        the lock of `session_dir` when the caller took it as it made the folder (else it is
        taken here; GalileoError if another app holds it). `init`: as
        `galileo.runner.infer`'s (e.g. `galileo.recognition.model.recognition_init`): its
        proposal decides where this and every later chain starts (recorded in the session).

        `moves`: "default", "paper" or "fitted" (see the module docstring; "fitted": `_maybe_fit`); `sweeps`: the sweep target at
        which each chain pauses (None: never); `warmup`: sweeps of width adaptation (default:
        `galileo infer`'s for these sweeps (`RunConfig.warmup_sweeps`: half of them, with
        until_rhat at least 100 or all; 75's without a target); always 0 with "paper");
        `until_rhat`, `min_ess`, `max_sweeps` (default 20 x sweeps): run until converged, as
        `galileo infer --until-rhat` (`min_ess` also says what "converged" means without it)."""
        if isinstance(chains, bool) or int(chains) != chains or chains < 0:
            raise ValueError(f"chains must be an integer >= 0, got {chains!r}")
        if isinstance(seed, bool) or int(seed) != seed or seed < 0:
            raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
        if moves not in MOVE_SETS:
            raise ValueError(f"moves must be one of {', '.join(MOVE_SETS)}, got {moves!r}")
        if sweeps is not None:
            sweeps = _whole(sweeps, "sweeps", 1)
        if warmup is not None:
            warmup = _whole(warmup, "warmup", 0)
        if until_rhat is not None and sweeps is None:
            raise ValueError("until_rhat needs a sweep target (sweeps) to run on from")
        until = _until(until_rhat, min_ess, max_sweeps, sweeps)
        scene = scene_for_moves(scene, moves)          # "paper": the paper's own likelihood too
        scenario = registry.of(scene)
        lik_scene = scenario.prepare(scene, tracks)   # checks scene against tracks
        latents = scenario.latents(lik_scene)
        settings = (settings or Settings.default(latents, scenario.noise, scenario.paper_widths if moves == "paper"
                                                 else None)).checked(latents, scenario.noise)
        if session_dir is not None:
            session_dir = Path(session_dir)
            if (session_dir / sess.CHAINS_FILE).exists():
                raise GalileoError(f"{session_dir} already holds a session; open it with Controller.load")
        self._setup(scene, tracks, latents, int(seed), workers, settings, session_dir, save_every_s, executor)
        self._likelihood_scene = lik_scene
        self.moves_set = moves
        # the warm-up as `galileo infer` takes it for these sweeps (none with "paper")
        self._warmup = RunConfig(sweeps=sweeps or PAPER_SWEEPS, moves=moves, warmup=warmup,
                                 until_rhat=until_rhat, max_sweeps=max_sweeps).warmup_sweeps()
        if moves == "fitted" and self._warmup < FITTED_MIN_WARMUP:
            raise GalileoError(f"moves fitted needs a warm-up of at least {FITTED_MIN_WARMUP} sweeps to fit its move to "
                               f"(this session's: {self._warmup}; more sweeps)")
        if moves in ("default", "fitted"):
            self._moves0 = default_moves(scenario, lik_scene, tracks, latents, self._bounds_array(), self._settings)
        self._adapt_until = self._warmup
        self._target = sweeps
        self._block = sweeps     # a resume past the target runs this many more sweeps
        self._until = until
        self._min_ess = until["min_ess"] if until else _check_min_ess(min_ess)
        if init is not None:
            chosen = init(lik_scene, self.names, self._bounds_array(), max(int(chains), 1), self.seed,
                          self._settings.integer_sites)
            self.init_info = dict(chosen.info)
        with self._lock:
            ids = list(range(int(chains)))
            self._create_chains(ids)
            self._event("init", {"seed": self.seed, "chains": ids, "settings": self._settings.to_json(),
                                 "starts": {str(c): self._chains[c].start.tolist() for c in ids},
                                 "init": self.init_info, "moves": self.moves_set, "warmup": self._warmup,
                                 "joint_moves": [sess.move_to_json(m) for m in self._moves0],
                                 "sweeps": self._target, "until": copy.deepcopy(self._until)})
        if self.session_dir is None:
            self._start_pool()
            return
        self.session_dir.mkdir(parents=True, exist_ok=True)
        self._session_lock = session_lock or sess.SessionLock(self.session_dir)
        try:
            sess.write_static(self.session_dir, self._scene_json, self._tracks_json)
            for name in sess.video_files(self.session_dir):
                self._session_lock.keep(name)
            self.save()
            self._start_pool()
        except BaseException:
            if session_lock is None:
                self._session_lock.release()
            raise

    def _setup(self, scene, tracks, latents, seed, workers, settings, session_dir, save_every_s, executor) -> None:
        self.scene, self.tracks = scene, tracks
        self.scenario = registry.of(scene)
        self._likelihood_scene = None
        self.latents = tuple(latents)
        self._specs = by_name(latents)
        self.names: tuple[str, ...] = tuple(lat.name for lat in latents)
        self.seed = seed
        self.workers = max(1, int(workers or os.cpu_count() or 1))
        self.session_dir = session_dir
        self.save_every_s = float(save_every_s)
        self._scene_json, self._tracks_json = scene.to_json(), tracks_to_json(tracks)
        self._problem = Problem.of(scene, tracks)
        self._settings = settings
        self._chains: dict[int, _Chain] = {}
        self._next_id = 0
        self._rounds = 0
        self._steps = 0
        self._acc_n = np.zeros(len(self.names), int)
        self._acc_k = np.zeros(len(self.names), int)
        self._events: list[dict] = []
        self._lock = threading.RLock()
        self._cond = threading.Condition(self._lock)
        self._round_lock = threading.Lock()
        self._save_lock = threading.Lock()
        self._deliver_lock = threading.RLock()
        self._in_flight = False
        self._pending: list[Callable[[], None]] = []
        self._notices: deque = deque()
        self._listeners: list[Listener] = []
        self._thread: threading.Thread | None = None
        self._stop_evt = threading.Event()
        self._executor = executor
        self._own_executor = executor is None
        self._closed = False
        self._error: str | None = None
        self._dirty = True
        self._last_save = -math.inf
        self.init_info: dict = {"starts": "prior"}   # how chains start (recognition: its readings and proposal)
        # moves, warm-up, sweep target, run until converged (a session recorded before them: the paper's kernel)
        self.moves_set = "paper"
        self._moves0: tuple = ()          # every new chain's joint moves (as built, before adaptation)
        self._fitted = False              # "fitted": whether the move was fitted (`_maybe_fit`)
        self._warmup = 0                  # sweeps of width adaptation (dropped with the burn-in)
        self._adapt_until = 0             # chains adapt in their sweeps 1..this (0 once a user set the widths)
        self._target: int | None = None   # each running chain pauses (held) when it reaches this sweep
        self._block: int | None = None    # sweeps a resume past the target runs on (None: on and on)
        self._until: dict | None = None   # {"until_rhat", "min_ess", "max_sweeps"}: run until converged
        self._min_ess = float(MIN_ESS)
        self._mv_n: np.ndarray = np.zeros(0, int)   # joint moves' proposals and acceptances, by move
        self._mv_k: np.ndarray = np.zeros(0, int)
        self._conv_cache: tuple | None = None
        self._deaths: list[float] = []     # when workers died since the last completed round
        self._restarts = 0                 # pools made anew after a worker died
        self._workers_note: dict | None = None   # the last worker death: {"text", "sweep", "restarted", ...}
        self._want_running = False         # start() called and no stop() since
        self._pools_made = 0
        self._slowest_sweep_s = 0.0        # the slowest one-sweep task so far (worker seconds): the round deadline
        self._session_lock: sess.SessionLock | None = None
        self._session_note: str | None = None   # the session folder was lost: what happened, where it is saved now
        self._saving = session_dir is not None  # False once the folder is lost and could not be recovered
        self._save_failures = 0                 # saves failed in a row in a folder still there (SAVE_RETRIES)

    # -- workers ------------------------------------------------------------------------------------------
    def _start_pool(self):
        """The executor. The first LocalPool is forked, from the constructor's thread, before
        any runner or server thread exists; a later one (after a worker died) is spawned: by
        then a fork would copy the viewer's sockets and whatever locks other threads hold."""
        if self._executor is None:
            self._executor = LocalPool(self.workers, context="spawn" if self._pools_made else "fork")
            self._pools_made += 1
        return self._executor

    def _worker_died(self, error: Exception, tasks: list) -> bool:
        """A worker of the controller's own pool died during a round (killed, out of memory) or
        stopped answering (`WorkerHung`: no results by the round's deadline; its workers were
        killed): the broken pool is shut down and the round's results, none of which were
        committed, are dropped. Records a "worker_died" event (`cause` "died" or "hung"), says so
        on stderr, and returns True to run the round again on a new pool (the chains' committed
        state and random streams are where they were, so the chains are those of a run in which
        no worker failed), or, after WORKER_DEATHS_IN_A_ROW failures with no round completed
        between them (deaths within WORKER_DEATHS_WINDOW_S), pauses every running chain and
        returns False."""
        old, self._executor = self._executor, None   # (None: the new pool's workers failed to start)
        if old is not None:
            try:
                old.shutdown()
            except Exception:  # noqa: BLE001 - a broken pool's shutdown must not hide the death
                log.exception("shutting a broken worker pool down failed")
        dead = old.dead_workers() if hasattr(old, "dead_workers") else []
        hung = isinstance(error, WorkerHung)
        now = time.monotonic()
        sweep = max((int(t.sweep) for t in tasks), default=0) + 1   # the sweep the running chains were on
        who = ", ".join(f"pid {w['pid']} {w['how']}" for w in dead) or " ".join(str(error).split())
        if hung:
            who += f"; no result in {error.timeout_s:.0f} s"
        what = "stopped responding" if hung else "died"
        with self._lock:
            # (a hang takes its deadline to notice: hangs in a row count however far apart)
            self._deaths = [(t, h) for t, h in self._deaths if h or now - t <= WORKER_DEATHS_WINDOW_S] + [(now, hung)]
            give_up = len(self._deaths) >= WORKER_DEATHS_IN_A_ROW
            detail = {"sweep": sweep, "cause": "hung" if hung else "died", "workers": dead,
                      "message": " ".join(str(error).split()), "in_a_row": len(self._deaths)}
            if give_up:
                ids = [c for c, ch in sorted(self._chains.items()) if not ch.removed and not ch.paused]
                for c in ids:
                    self._chains[c].paused = True
                    self._chains[c].held = False
                hangs = any(h for _, h in self._deaths)
                text = (f"inference workers {'died or stopped responding' if hangs else 'died'} {len(self._deaths)} "
                        f"times in a row{'' if hangs else f' within {WORKER_DEATHS_WINDOW_S:g} s'} (last during sweep "
                        f"{sweep}: {who}): every chain is paused; Resume all starts a new pool")
                detail.update(restarted=False, restarts=self._restarts, outcome=text)
                self._event("worker_died", detail)
                self._event("pause", {"chains": ids, "reason": "inference workers keep dying"
                                      + (" or stopping" if hangs else "")})
            else:
                self._restarts += 1
                text = (f"an inference worker {what} during sweep {sweep} ({who}); the worker pool was restarted "
                        f"({self._restarts} time{'s' if self._restarts > 1 else ''}) and sweep {sweep} runs again")
                detail.update(restarted=True, restarts=self._restarts)
                self._event("worker_died", detail)
            self._workers_note = {"text": text, "sweep": sweep, "restarted": not give_up, "restarts": self._restarts,
                                  "gave_up": give_up, "time": time.time()}
            if give_up:
                self._deaths = []
        print(f"galileo: {'error' if give_up else 'warning'}: {text}", file=sys.stderr, flush=True)
        log.info("%s", text)
        return not give_up

    # -- rounds ----------------------------------------------------------------------------------------------
    def _round(self) -> bool:
        """One sweep of every running chain; False if none is running."""
        with self._round_lock:
            with self._lock:
                if self._closed:
                    raise GalileoError("the controller is closed")
                run = [ch for _, ch in sorted(self._chains.items()) if not ch.paused and not ch.removed]
                if not run:
                    return False
                s = self._settings
                bounds = self._bounds_array()
                tasks = [ChainTask(self._problem, ch.id, ch.position.copy(), ch.logdensity, ch.sweep,
                                   copy.deepcopy(ch.rng_state), 1, bounds, ch.proposal, s.noise, True,
                                   moves=ch.moves, adapt_until=self._adapt_until) for ch in run]
                self._in_flight = True
            while True:
                try:
                    ex = self._start_pool()
                    deadline = {"timeout_s": self._round_deadline_s(len(tasks))} if isinstance(ex, LocalPool) else {}
                    results = list(ex.map(run_task, tasks, **deadline))
                    break
                except BaseException as e:
                    if isinstance(e, WorkerDied) and self._own_executor:
                        again = self._worker_died(e, tasks)
                        stopping = self._stop_evt.is_set() and threading.current_thread() is self._thread
                        if again and not stopping:
                            continue   # the same tasks on a new pool: nothing of this round was committed
                        with self._lock:   # paused (or stopping): the round is not run, nothing changed
                            self._in_flight = False
                            self._apply_pending()
                            self._cond.notify_all()
                        return False
                    with self._lock:
                        self._in_flight = False
                        self._apply_pending()
                    if isinstance(e, GalileoError):
                        raise
                    if isinstance(e, Exception):
                        raise GalileoError(f"an inference worker failed: {type(e).__name__}: {e}") from e
                    raise
            with self._lock:
                self._deaths = []
                self._slowest_sweep_s = max([self._slowest_sweep_s] + [float(r["seconds"]) for r in results])
                out, held = [], []
                noise = {t.chain: t.noise for t in tasks}
                for r in results:
                    ch = self._chains[r["chain"]]
                    before = ch.sweep
                    ch.position = np.asarray(r["position"], float)
                    ch.logdensity = r["logdensity"]
                    ch.sweep = r["sweep"]
                    ch.rng_state = r["rng"]
                    ch.proposal, ch.moves = r["proposal_state"], tuple(r["moves"])
                    ch.samples.extend(ch.position[None])
                    ch.logliks.extend([ch.logdensity])
                    ch.noise.extend([noise[ch.id]])
                    for k in PROPOSAL_FIELDS:
                        ch.proposals[k].extend(r[k])
                    ch.note_best(len(ch.logliks) - 1)
                    self._count(r["site"], r["accepted"])
                    self._steps += int(r["steps"])
                    out.append((ch.id, ch.sweep, ch.logdensity, self._values(ch.position)))
                    if self._target is not None and before < self._target <= ch.sweep and not ch.paused:
                        ch.paused = ch.held = True
                        held.append(ch.id)
                self._maybe_fit()
                self._rounds += 1
                self._in_flight = False
                self._dirty = True
                self._notices.append(("sweeps", {"round": self._rounds, "results": out}))
                if held:
                    self._event("pause", {"chains": held, "reason": f"sweep target {self._target}"})
                self._apply_pending()
                self._until_step()
                self._cond.notify_all()
            return True

    def _maybe_fit(self) -> None:
        """The "fitted" move set (under the lock, after a round): once every running chain is past
        the warm-up (two at least; a chain the user paused in its warm-up is not waited for), the
        moves fitted to those chains' warm-ups' second halves (`galileo.runner.fitted_moves`:
        the kernel move, FITTED_PER_SWEEP proposals a sweep, the t's conditionals and the
        marginals, as `galileo infer --moves fitted`) join every chain's moves, and every
        chain made later; once (recorded as a "fitted" event, the t, the kernel and the
        marginals in full; a reopened session has them in its chains' moves)."""
        if self.moves_set != "fitted" or self._fitted:
            return
        active = [ch for _, ch in sorted(self._chains.items()) if not ch.removed]
        ready = [ch for ch in active if ch.sweep >= self._warmup]
        if len(ready) < 2 or any(ch.sweep < self._warmup and not ch.paused for ch in active):
            return
        self._fitted = True
        warm = [ch.samples.get() for ch in ready]
        q = fitted_move(self.latents, self._bounds_array(), warm, self._warmup)
        marginals = fitted_marginals(self.latents, self._bounds_array(), warm, self._warmup, q)
        kernel = fitted_kernel(self.latents, self._bounds_array(), warm, self._warmup) if q is not None else None
        if q is not None:
            more = fitted_moves(q, marginals=marginals, kernel=kernel)
            for ch in active:
                ch.moves = tuple(ch.moves) + more
            self._moves0 = tuple(self._moves0) + more
        self._event("fitted", {"chains": [ch.id for ch in ready], "sweep": self._warmup,
                               "move": None if q is None else sess.move_to_json(q),
                               "per_sweep": FITTED_PER_SWEEP, "conditionals": FITTED_CONDITIONALS,
                               "marginals": [sess.move_to_json(m) for m in marginals],
                               "marginals_per_sweep": FITTED_MARGINALS,
                               "kernel": None if kernel is None else sess.move_to_json(kernel)})

    def _round_deadline_s(self, n_tasks: int) -> float:
        """How long a round of `n_tasks` one-sweep tasks may take before its workers count as
        hung: generous (a busy machine, a chain in a slow corner of the prior), yet minutes less
        than waiting for ever."""
        per_worker = math.ceil(n_tasks / max(1, getattr(self._executor, "workers", self.workers)))
        return ROUND_DEADLINE_FLOOR_S + ROUND_DEADLINE_FACTOR * self._slowest_sweep_s * per_worker

    def _count(self, site: np.ndarray, accepted: np.ndarray) -> None:
        """Acceptance counts: per latent (single-site proposals) and per joint move."""
        site, acc = np.asarray(site, int), np.asarray(accepted, int)
        own = site >= 0
        np.add.at(self._acc_n, site[own], 1)
        np.add.at(self._acc_k, site[own], acc[own])
        k = -site[~own] - 2                  # move k's code is -(k + 2) (-1, an independence move: not counted)
        keep = k >= 0
        if keep.any():
            n = max(len(self._mv_n), int(k[keep].max()) + 1)
            if n > len(self._mv_n):
                self._mv_n = np.concatenate([self._mv_n, np.zeros(n - len(self._mv_n), int)])
                self._mv_k = np.concatenate([self._mv_k, np.zeros(n - len(self._mv_k), int)])
            np.add.at(self._mv_n, k[keep], 1)
            np.add.at(self._mv_k, k[keep], acc[~own][keep])

    def _until_step(self, base_from_paused: bool = False) -> None:
        """Run until converged (under the lock, after a round): once no active chain runs and
        some are held at the target, the verdict on the kept draws; unless converged or the
        budget is spent, the target grows like the batch runner's blocks (`block_after`: a
        tenth of what is done, at least 10, up to the budget) and the held chains run on. `base_from_paused` (turning the
        mode on with every chain stopped) treats every paused chain at or past the target as held."""
        u = self._until
        if u is None:
            return
        active = [ch for _, ch in sorted(self._chains.items()) if not ch.removed]
        if not active or any(not ch.paused for ch in active):
            return
        held = [ch for ch in active if ch.held or (base_from_paused and self._target is not None
                                                      and ch.sweep >= self._target)]
        if not held:
            return
        conv = self._convergence_of(self._kept_locked(), u["until_rhat"], u["min_ess"])
        base = max([self._target or 0] + [ch.sweep for ch in held])
        detail = {"converged": conv["converged"], "summary": conv["summary"], "why_not": conv["why_not"],
                  "sweeps": base, "max_sweeps": u["max_sweeps"], "until_rhat": u["until_rhat"],
                  "min_ess": u["min_ess"]}
        if conv["converged"]:
            detail["outcome"] = "converged: the chains stay paused"
        elif base >= u["max_sweeps"]:
            detail["outcome"] = f"not converged, the budget of {u['max_sweeps']} sweeps is spent: the chains stay paused"
        else:
            self._target = base + block_after(base, u["max_sweeps"])
            for ch in held:
                ch.paused = ch.held = False
            detail.update(outcome=f"not converged: run on to sweep {self._target}", target=self._target,
                          resumed=[ch.id for ch in held])
        self._event("until_check", detail)

    def run_sweeps(self, n: int) -> int:
        """Run n rounds synchronously (rounds with no running chain do nothing); returns rounds run."""
        done = 0
        for _ in range(int(n)):
            done += self._round()
            self._deliver()
            self._maybe_save()
        return done

    def start(self) -> None:
        """Run rounds in a background thread until `stop`."""
        with self._lock:
            if self._closed:
                raise GalileoError("the controller is closed")
            if self._thread is not None and self._thread.is_alive():
                return
            self._error = None
            self._stop_evt.clear()
            self._want_running = True
            self._start_pool()
            self._thread = threading.Thread(target=self._loop, name="galileo-controller", daemon=True)
            self._thread.start()

    def _loop(self) -> None:
        try:
            while not self._stop_evt.is_set():
                self._deliver()
                if not self._round():
                    with self._cond:
                        if not self._stop_evt.is_set() and not self._pending:
                            self._cond.wait(0.2)
                self._deliver()
                self._maybe_save()
        except Exception as e:  # noqa: BLE001 - reported, not raised, from the background
            msg = " ".join(str(e).split())
            log.error("inference stopped: %s", msg)
            with self._lock:
                self._error = msg
                self._notices.append(("error", {"message": msg}))
            self._deliver()

    def stop(self) -> None:
        """Stop the background thread (the round in flight finishes) and save the session."""
        t = self._thread
        self._want_running = False
        if t is not None and t is threading.current_thread():   # from a listener: just ask
            self._stop_evt.set()
            return
        if t is not None:
            self._stop_evt.set()
            with self._cond:
                self._cond.notify_all()
            t.join()
            self._thread = None
        self._deliver()
        self.save()

    def close(self) -> None:
        """Stop, save, and shut the worker processes down."""
        if self._closed:
            return
        self.stop()
        with self._round_lock:
            self._closed = True
            if self._executor is not None and self._own_executor:
                self._executor.shutdown()
            self._executor = None
        if self._session_lock is not None:   # (after the workers: another app may open the session now)
            self._session_lock.release()

    def __enter__(self) -> "Controller":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def running(self) -> bool:
        t = self._thread
        return t is not None and t.is_alive()

    # -- listeners ------------------------------------------------------------------------------------------
    def add_listener(self, fn: Listener) -> None:
        with self._lock:
            self._listeners.append(fn)

    def remove_listener(self, fn: Listener) -> None:
        with self._lock:
            if fn in self._listeners:
                self._listeners.remove(fn)

    def _deliver(self) -> None:
        with self._deliver_lock:
            while True:
                with self._lock:
                    if not self._notices:
                        return
                    kind, payload = self._notices.popleft()
                    listeners = list(self._listeners)
                for fn in listeners:
                    try:
                        fn(kind, payload)
                    except Exception:  # noqa: BLE001 - a listener must not stop the chains
                        log.exception("controller listener %r failed on %s", fn, kind)

    # -- steering ---------------------------------------------------------------------------------------------
    def _steer(self, apply: Callable[[], None]) -> None:
        """Apply now, or right after the round in flight (which keeps the old settings)."""
        with self._lock:
            if self._in_flight:
                self._pending.append(apply)
            else:
                apply()
            self._cond.notify_all()
        if not self.running:
            self._deliver()

    def _apply_pending(self) -> None:
        pending, self._pending = self._pending, []
        for fn in pending:
            fn()

    def _event(self, kind: str, detail: dict) -> dict:
        ev = {"sweep": self._rounds, "time": time.time(), "kind": kind, "detail": detail,
              "chain_sweeps": {str(c): ch.sweep for c, ch in sorted(self._chains.items()) if not ch.removed}}
        self._events.append(ev)
        self._dirty = True
        self._notices.append(("event", copy.deepcopy(ev)))
        return ev

    def set_bounds(self, name: str, lo: float, hi: float) -> None:
        """Uniform prior bounds of one latent; chains outside move to the nearest point inside."""
        if name not in self._specs:
            raise ValueError(f"unknown latent {name!r}; expected one of {', '.join(self.names)}")
        lo, hi = check_bounds(self._specs[name], lo, hi)
        j = self.names.index(name)

        def apply():
            old = self._settings.bounds[name]
            if old == (lo, hi):
                return
            self._settings.bounds[name] = (lo, hi)
            moved = {}
            for c, ch in sorted(self._chains.items()):
                if ch.removed:
                    continue
                x = float(ch.position[j])
                y = min(max(x, lo), hi)
                if self._specs[name].integer:
                    y = float(min(max(round(y), math.ceil(lo)), math.floor(hi)))
                if y != x:
                    ch.position = ch.position.copy()
                    ch.position[j] = y
                    ch.logdensity = None
                    moved[str(c)] = {"from": x, "to": y}
            self._event("bounds", {"name": name, "lo": lo, "hi": hi, "old": [old[0], old[1]], "moved": moved})
        self._steer(apply)

    def set_noise(self, value: float) -> None:
        """The likelihood's noise (an SD, in the scenario's unit: m/s for the ramp); chains'
        logdensities are recomputed before their next proposals. Recorded as a "sigma" event."""
        spec = self.scenario.noise
        sigma = check_noise(spec, value)

        def apply():
            old = self._settings.noise
            if old == sigma:
                return
            self._settings.noise = sigma
            for ch in self._chains.values():
                if not ch.removed:
                    ch.logdensity = None
            self._event("sigma", {spec.name: sigma, "old": old})
        self._steer(apply)

    set_sigma = set_noise

    def set_widths(self, narrow: float, broad: float, broad_every: int) -> None:
        """Proposal half-widths: U(-narrow, narrow), U(-broad, broad) every broad_every-th sweep (0: never)."""
        n, b, e = check_widths(narrow, broad, broad_every)
        for w, what in ((n, "narrow"), (b, "broad")):
            if isinstance(w, tuple) and len(w) != len(self.names):
                raise ValueError(f"{what}: {len(w)} widths for {len(self.names)} latents ({', '.join(self.names)})")

        def apply():
            s = self._settings
            old = {"narrow": s.narrow, "broad": s.broad, "broad_every": s.broad_every}
            if old == {"narrow": n, "broad": b, "broad_every": e}:
                return
            s.narrow, s.broad, s.broad_every = n, b, e
            detail = {"narrow": n, "broad": b, "broad_every": e, "old": old}
            if self.moves_set == "default":
                # the user's widths replace every chain's adapted ones from this sweep on
                detail["replaced_adapted_narrow"] = {str(c): sess.proposal_to_json(ch.proposal)["narrow"]
                                                     for c, ch in sorted(self._chains.items()) if not ch.removed}
                if self._adapt_until:
                    detail["adaptation"] = (f"ended: the chains' narrow widths adapted in warm-up (sweeps 1-"
                                            f"{self._adapt_until}) are replaced by these from this sweep on")
                    self._adapt_until = 0
            for ch in self._chains.values():
                ch.proposal = s.proposal()
            self._event("widths", detail)
        self._steer(apply)

    def run_until(self, until_rhat: float | None, min_ess: float = MIN_ESS, max_sweeps: int | None = None,
                  verdict: bool = True) -> None:
        """Turn run-until-converged on (or off with None): chains held at the sweep target run
        on in blocks until every latent's R-hat <= until_rhat and its ESS >= min_ess, or the
        target reaches max_sweeps (default: 20 x the target). With every chain stopped, the
        verdict comes at once, unless `verdict` is False (a reopened session: the criteria only;
        nothing runs until Resume). Recorded as a "run_until" event."""
        with self._lock:
            target = self._target
            if target is None:   # no target yet: the running chains stop for a verdict a block from now
                target = max((ch.sweep for ch in self._chains.values() if not ch.removed), default=0) + MIN_BLOCK_SWEEPS
        until = _until(until_rhat, min_ess, max_sweeps, target)

        def apply():
            if self._target is None:
                self._target = target
            self._until = until
            if until is not None:
                self._min_ess = until["min_ess"]
            self._event("run_until", {"until": copy.deepcopy(until), "sweeps": self._target})
            if verdict:
                self._until_step(base_from_paused=True)
        self._steer(apply)

    def _check_active(self, chain: int) -> None:
        with self._lock:
            ch = self._chains.get(chain)
            if ch is None:
                raise ValueError(f"no chain {chain!r}; chains are {self.chain_ids()}")
            if ch.removed:
                raise ValueError(f"chain {chain} was removed")

    def _set_paused(self, chain: int | None, paused: bool) -> None:
        if chain is not None:
            self._check_active(chain)

        def apply():
            ids = [chain] if chain is not None else sorted(self._chains)
            changed = [c for c in ids if not self._chains[c].removed and self._chains[c].paused != paused]
            for c in changed:
                self._chains[c].paused = paused
                self._chains[c].held = False   # the user's pause, or running on past the target
            detail = {"chains": changed}
            if changed and not paused and self._target is not None:
                # chains resumed at or past the sweep target run one more block and pause again, so
                # the target (and the progress towards it) always lies ahead of them: --sweeps, or
                # running until converged the batch runner's next block (then the verdict)
                top = max(self._chains[c].sweep for c in changed)
                u = self._until
                step = self._block if u is None else block_after(top, max(u["max_sweeps"], top + MIN_BLOCK_SWEEPS))
                if top >= self._target and step:
                    self._target = top + step
                    detail["target"] = self._target
            if changed:
                self._event("pause" if paused else "resume", detail)
                if paused:
                    self._until_step()   # the last running chain stopped: the others may wait for a verdict
        self._steer(apply)

    def pause(self, chain: int | None = None) -> None:
        """Pause one chain (or all): it keeps its state and samples but stops sweeping."""
        self._set_paused(chain, True)

    def resume(self, chain: int | None = None) -> None:
        """Resume one chain (or all). When the background thread was started and has stopped on
        an error, it starts again (a new worker pool if the old one is gone)."""
        self._set_paused(chain, False)
        if self._want_running and not self.running and not self._closed:
            self.start()

    def add_chains(self, n: int = 1) -> list[int]:
        """New chains, started like the batch runner's chains with those indices (under the
        bounds in force); returns their ids."""
        if int(n) != n or n < 1:
            raise ValueError(f"add_chains needs n >= 1, got {n!r}")
        with self._lock:
            ids = list(range(self._next_id, self._next_id + int(n)))
            self._next_id += int(n)

        def apply():
            self._create_chains(ids)
            self._event("add_chains", {"chains": ids, "starts": {str(c): self._chains[c].start.tolist()
                                                                  for c in ids}})
        self._steer(apply)
        return ids

    def _create_chains(self, ids: list[int]) -> None:
        if not ids:
            return
        bounds = self._bounds_array()
        q = self.init_info.get("proposal")
        if q:   # started from a recognition model's reading: chain c's start is its own draw from it
            from galileo.mcmc import Independence
            from galileo.recognition.model import chain_starts

            starts = chain_starts(Independence(tuple(q["kinds"]), tuple(q["loc"]), tuple(q["scale"])), bounds,
                                  max(ids) + 1, self.seed, self._settings.integer_sites)
        else:
            starts = self.scenario.initial_positions(self.likelihood_scene, self.latents, bounds, max(ids) + 1,
                                                     self.seed)
        for c in ids:
            self._chains[c] = _Chain(c, starts[c], chain_rng(self.seed, c).bit_generator.state, len(self.names),
                                     self._settings.proposal(), self._moves0)
        self._next_id = max(self._next_id, max(ids) + 1)

    def remove_chain(self, chain: int) -> None:
        """Stop a chain for good; its samples stay (and count for the MAP)."""
        self._check_active(chain)

        def apply():
            ch = self._chains[chain]
            if not ch.removed:
                ch.removed = True
                self._event("remove_chain", {"chains": [chain]})
                self._until_step()
        self._steer(apply)

    def reset_chain(self, chain: int, to: str = "map", sample: tuple[int, int] | None = None) -> None:
        """Move a chain to the MAP (to="map") or to a recorded sample (to="sample", sample=(chain, index))."""
        self._check_active(chain)
        if to == "map":
            best = self.map()
            if best is None:
                raise ValueError(self.map_note() or "no samples yet: there is no MAP to reset to")
            src = (best[0], best[1])
        elif to == "sample":
            if sample is None or len(sample) != 2:
                raise ValueError("reset_chain(to='sample') needs sample=(chain, index)")
            src = (int(sample[0]), int(sample[1]))
        else:
            raise ValueError(f"reset_chain: to must be 'map' or 'sample', got {to!r}")
        values = self.sample(*src)
        self._move(chain, values, "reset_chain", {"to": to, "sample": list(src)}, clamp=True)

    def set_chain(self, chain: int, values: dict[str, float]) -> None:
        """Set (some of) a chain's latents by hand; they must lie inside the prior bounds."""
        self._check_active(chain)
        if not isinstance(values, dict) or not values:
            raise ValueError("set_chain needs a dict of latent values")
        vals = {}
        with self._lock:
            for k, v in values.items():
                if k not in self.names:
                    raise ValueError(f"unknown latent {k!r}; expected one of {', '.join(self.names)}")
                x = as_number(v, k)
                lo, hi = self._settings.bounds[k]
                if not lo <= x <= hi:
                    raise ValueError(f"{k}={x:g} is outside its prior bounds [{lo:g}, {hi:g}]")
                vals[k] = x
        self._move(chain, vals, "set_chain", {}, clamp=True)

    def _move(self, chain: int, values: dict[str, float], kind: str, detail: dict, clamp: bool) -> None:
        def apply():
            ch = self._chains[chain]
            if ch.removed:
                return
            pos = ch.position.copy()
            clamped = {}
            for k, x in values.items():
                j = self.names.index(k)
                lo, hi = self._settings.bounds[k]
                y = min(max(float(x), lo), hi) if clamp else float(x)
                if self._specs[k].integer:   # an integer latent stays on its grid
                    y = float(min(max(round(y), math.ceil(lo)), math.floor(hi)))
                if y != x:
                    clamped[k] = {"from": float(x), "to": y}
                pos[j] = y
            ch.position = pos
            ch.logdensity = None
            self._event(kind, {"chain": chain, **detail, "values": self._values(pos), "clamped": clamped})
        self._steer(apply)

    # -- queries ------------------------------------------------------------------------------------------------
    @property
    def settings(self) -> Settings:
        with self._lock:
            return self._settings.copy()

    @property
    def likelihood_scene(self):
        """The scene the likelihood simulates (what tracking fixed put in)."""
        if self._likelihood_scene is None:
            self._likelihood_scene = self.scenario.prepare(self.scene, self.tracks)
        return self._likelihood_scene

    @property
    def events(self) -> list[dict]:
        with self._lock:
            return copy.deepcopy(self._events)

    def chain_ids(self) -> list[int]:
        """Active (not removed) chains."""
        with self._lock:
            return [c for c, ch in sorted(self._chains.items()) if not ch.removed]

    def all_chain_ids(self) -> list[int]:
        """Every chain, removed ones included."""
        with self._lock:
            return sorted(self._chains)

    def _get(self, chain: int) -> _Chain | None:
        ch = self._chains.get(chain)
        if ch is None and not (isinstance(chain, (int, np.integer)) and 0 <= chain < self._next_id):
            raise ValueError(f"no chain {chain!r}")
        return ch   # None: added, created after the round in flight

    def starts(self) -> dict[int, np.ndarray]:
        """Where each chain (removed ones too) started."""
        with self._lock:
            return {c: ch.start.copy() for c, ch in sorted(self._chains.items())}

    def samples(self, chain: int) -> np.ndarray:
        """(S, D): the chain's state after each of its sweeps."""
        with self._lock:
            ch = self._get(chain)
            return ch.samples.get() if ch else np.empty((0, len(self.names)))

    def logliks(self, chain: int) -> np.ndarray:
        """(S,): the log-likelihood of each sample (under the sigma in force when it was drawn)."""
        with self._lock:
            ch = self._get(chain)
            return ch.logliks.get() if ch else np.empty(0)

    def proposals(self, chain: int) -> dict[str, np.ndarray]:
        """The chain's proposals in order (D per sweep): site, proposal (P, D), proposal_loglik
        (a bound below the threshold if early_stop), accepted, early_stop, width."""
        with self._lock:
            ch = self._get(chain)
            if ch is None:
                return {k: np.empty((0, len(self.names)) if w else 0, t) for k, (t, w) in PROPOSAL_FIELDS.items()}
            return {k: b.get() for k, b in ch.proposals.items()}

    def position(self, chain: int) -> dict[str, float]:
        """The chain's current state (where its next sweep starts)."""
        with self._lock:
            ch = self._get(chain)
            if ch is None:
                raise ValueError(f"chain {chain} starts after the round in flight")
            return self._values(ch.position)

    def sample(self, chain: int, index: int) -> dict[str, float]:
        with self._lock:
            ch = self._get(chain)
            n = len(ch.samples) if ch else 0
            if not -n <= index < n:
                raise IndexError(f"chain {chain} has {n} samples, no index {index}")
            return self._values(ch.samples.a[index % n])

    def sample_noise(self, chain: int) -> np.ndarray:
        """(S,): the noise (sigma) each sample's log-likelihood was computed under."""
        with self._lock:
            ch = self._get(chain)
            return ch.noise.get() if ch else np.empty(0)

    def proposal_state(self, chain: int) -> tuple:
        """(galileo.mcmc.Proposal, joint moves): the widths and moves of the chain's next sweep."""
        with self._lock:
            ch = self._get(chain)
            if ch is None:
                raise ValueError(f"chain {chain} starts after the round in flight")
            return ch.proposal, ch.moves

    @property
    def warmup(self) -> int:
        """Sweeps of width adaptation at the start of each chain (dropped with the burn-in)."""
        return self._warmup

    @property
    def target_sweeps(self) -> int | None:
        with self._lock:
            return self._target

    def map(self) -> tuple[int, int, dict[str, float], float] | None:
        """(chain, index, values, loglik) of the best sample of all chains (removed ones too)
        among those scored under the noise in force and inside the prior in force:
        log-likelihoods under another sigma are on another scale and are not compared, and a
        sample a prior edit has left out is not a posterior mode. None before any such sample
        (pending)."""
        with self._lock:
            best = None
            noise = float(self._settings.noise)
            bounds = self._settings.bounds_array(self.names)
            for c, ch in sorted(self._chains.items()):
                b = ch.best.get(noise)
                if b is None:
                    continue
                if not _inside(ch.samples.a[b[0]], bounds):   # after a prior edit: the best inside it
                    n = ch.samples.n
                    ok = (ch.noise.a[:n] == noise) & _inside(ch.samples.a[:n], bounds)
                    if not ok.any():
                        continue
                    i = int(np.argmax(np.where(ok, ch.logliks.a[:n], -np.inf)))
                    b = (i, float(ch.logliks.a[i]))
                if best is None or b[1] > best[2]:
                    best = (c, b[0], b[1])
            if best is None:
                return None
            c, i, ll = best
            return c, i, self._values(self._chains[c].samples.a[i]), ll

    def map_note(self) -> str | None:
        """Why there is no MAP now (None when there is one, or no sample at all yet)."""
        with self._lock:
            if self.map() is not None or not any(len(ch.samples) for ch in self._chains.values()):
                return None
            spec = self.scenario.noise
            noise = float(self._settings.noise)
            if any(noise in ch.best for ch in self._chains.values()):
                return "MAP pending: no sample inside the prior in force yet (a prior edit left them all out)"
            return (f"MAP pending: no sample scored under {spec.name} = {self._settings.noise:g} {spec.unit} yet "
                    "(earlier log-likelihoods are under another sigma)")

    def status(self) -> dict:
        """{"running" (background thread), "rounds" (global sweep count), "sweeps" (chain sweeps,
        all chains), "proposals", "accepted", "physics_steps", "chains": {id: {"sweeps", "state"
        ("running" | "paused"), "running", "paused", "held" (paused at the sweep target), "loglik"
        (last sample's), "values" (current position), "narrow" (its next narrow widths)}} for
        active chains, "removed": [ids], "acceptance": {latent: rate | None} (single-site
        proposals), "moves": {"set", "joint": [names], "acceptance": {move: rate | None},
        "warmup", "adapting" (some chain still adapts its widths)}, "target_sweeps", "until"
        (run until converged: {"until_rhat", "min_ess", "max_sweeps"} | None),
        "convergence": `galileo.results.convergence` of the active chains' kept draws (burn-in
        max(warm-up, half), and none from before the last prior edit) against until_rhat (or
        1.01) and min_ess, plus "kept_draws" and
        "burn_in" (of the longest chain), "r_hat": {latent: R-hat | None} (the same),
        "derived": the scenario's derived quantities' posterior summaries on the same kept
        draws (as `InferenceResult.derived_posterior`), "settings", "map": {"chain", "index",
        "values", "loglik", "noise"} | None, "map_note" (why no MAP: pending after a sigma
        edit) | None, "error": why the background thread stopped | None, "workers": {"restarts" (pools
        made anew after a worker died or hung), "last_death": {"text", "sweep", "restarted", "restarts",
        "gave_up" (every chain paused instead), "time"} | None}, "session": {"folder" (where the
        session is saved; None: nowhere), "saving" (False once the folder was lost and could not
        be recovered), "note" (what happened to the folder) | None}}."""
        with self._lock:
            chains = {}
            for c, ch in sorted(self._chains.items()):
                if ch.removed:
                    continue
                last = float(ch.logliks.a[ch.logliks.n - 1]) if ch.logliks.n else None
                chains[c] = {"sweeps": ch.sweep, "state": "paused" if ch.paused else "running",
                             "running": not ch.paused, "paused": ch.paused, "held": ch.held, "loglik": last,
                             "values": self._values(ch.position),
                             "narrow": sess.proposal_to_json(ch.proposal)["narrow"]}
            acc = {n: (float(self._acc_k[j] / self._acc_n[j]) if self._acc_n[j] else None)
                   for j, n in enumerate(self.names)}
            counts: dict[str, list[int]] = {}   # by name (the fitted move is made several times a sweep)
            for k, m in enumerate(self._moves0):
                n_k = counts.setdefault(m.name, [0, 0])
                if k < len(self._mv_n):
                    n_k[0] += int(self._mv_n[k])
                    n_k[1] += int(self._mv_k[k])
            move_acc = {name: (k / n if n else None) for name, (n, k) in counts.items()}
            best = self.map()
            rhat_target = self._until["until_rhat"] if self._until else RHAT_TARGET
            key = (self._rounds, len(self._events), rhat_target, self._min_ess,
                   tuple((c, len(ch.samples)) for c, ch in sorted(self._chains.items()) if not ch.removed))
            cached = self._conv_cache
            kept = None if cached is not None and cached[0] == key else self._kept_locked()
            longest = max((ch.sweep for ch in self._chains.values() if not ch.removed), default=0)
            out = {"running": self.running, "rounds": self._rounds,
                   "sweeps": int(sum(ch.sweep for ch in self._chains.values())),
                   "proposals": int(self._acc_n.sum() + self._mv_n.sum()),
                   "accepted": int(self._acc_k.sum() + self._mv_k.sum()),
                   "physics_steps": self._steps, "chains": chains,
                   "removed": [c for c, ch in sorted(self._chains.items()) if ch.removed],
                   "acceptance": acc,
                   "moves": {"set": self.moves_set, "joint": list(counts), "acceptance": move_acc,
                             "warmup": self._warmup,
                             "adapting": any(ch.sweep < self._adapt_until for ch in self._chains.values()
                                             if not ch.removed and not ch.paused)},
                   "target_sweeps": self._target, "until": copy.deepcopy(self._until),
                   "settings": self._settings.to_json(),
                   "map": None if best is None else {"chain": best[0], "index": best[1], "values": best[2],
                                                     "loglik": best[3], "noise": float(self._settings.noise)},
                   "map_note": self.map_note(), "error": self._error,
                   "workers": {"restarts": self._restarts, "last_death": copy.deepcopy(self._workers_note)},
                   "session": {"folder": None if self.session_dir is None else str(self.session_dir),
                               "saving": self._saving, "note": self._session_note}}
        if kept is not None:   # outside the lock: arviz takes some milliseconds
            conv = self._convergence_of(kept, rhat_target, self._min_ess)
            conv["kept_draws"] = int(sum(len(k) for k in kept))
            conv["burn_in"] = burn_in(longest, self._warmup)
            derived = identified(derived_summaries(self.scenario, self.likelihood_scene, self.names,
                                                   [r for k in kept for r in k]),
                                 self.scenario.unidentified(self.likelihood_scene, self.tracks))
            self._conv_cache = cached = (key, conv, derived)
        out["convergence"] = copy.deepcopy(cached[1])
        out["r_hat"] = dict(cached[1]["r_hat"])
        out["derived"] = copy.deepcopy(cached[2])
        return out

    def _kept_locked(self) -> list[np.ndarray]:
        """The active chains' kept draws (copies): after max(warm-up, half) of each, and after
        the last prior (bounds) edit: draws before it sample another posterior."""
        since = {}
        for e in self._events:
            if e["kind"] == "bounds":
                since.update({int(c): int(k) for c, k in (e.get("chain_sweeps") or {}).items()})
        out = []
        for c, ch in sorted(self._chains.items()):
            if not ch.removed:
                n = ch.samples.n
                out.append(ch.samples.a[max(burn_in(n, self._warmup), min(since.get(c, 0), n)):n].copy())
        return out

    def _convergence_of(self, kept: list[np.ndarray], rhat_target: float, min_ess: float) -> dict:
        return convergence(kept, self.names, rhat_target, min_ess)

    # -- helpers -----------------------------------------------------------------------------------------------
    def _values(self, position) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.names, position)}

    def _bounds_array(self) -> np.ndarray:
        return np.array([self._settings.bounds[n] for n in self.names], float)

    # -- sessions ------------------------------------------------------------------------------------------------
    def _maybe_save(self) -> None:
        """Save if something changed, at most every save_every_s; as often, check that the
        folder is still the session's (a folder lost while the chains are paused is noticed too)."""
        if (self.session_dir is not None and self._saving and time.monotonic() - self._last_save >= self.save_every_s
                and (self._dirty or self._session_lock.lost())):
            self.save(retry=True)

    def save(self, retry: bool = False) -> None:
        """Write the session now (no-op without a session_dir, or once its folder was lost and
        could not be recovered). Never into a folder deleted, moved or replaced since it was
        opened: the whole session goes to a new folder beside it instead (`_session_lost`).
        `retry` (the periodic saves): a write that fails in a folder still there (one being
        deleted fails it first) is tried again at the next save, SAVE_RETRIES times in a row."""
        if self.session_dir is None or not self._saving:
            return
        with self._save_lock:
            with self._lock:
                record = {"names": np.array(self.names), "chain_ids": np.array(sorted(self._chains), np.int64)}
                for c, ch in sorted(self._chains.items()):
                    record[f"c{c}_start"] = ch.start.copy()
                    record[f"c{c}_samples"] = ch.samples.get()
                    record[f"c{c}_logliks"] = ch.logliks.get()
                    record[f"c{c}_noise"] = ch.noise.get()
                    for k, b in ch.proposals.items():
                        record[f"c{c}_{k}"] = b.get()
                events = copy.deepcopy(self._events)
                settings = self._settings.to_json()
                table: dict = {}      # every chain's joint moves, each distinct one once (`_table_index`)
                chains = {"version": sess.SESSION_VERSION, "names": list(self.names), "seed": self.seed,
                          "rounds": self._rounds, "next_id": self._next_id, "physics_steps": self._steps,
                          "n_events": len(self._events), "settings": settings,
                          "moves": self.moves_set, "warmup": self._warmup, "adapt_until": self._adapt_until,
                          "target_sweeps": self._target, "until": copy.deepcopy(self._until),
                          "chains": [copy.deepcopy(ch.to_json(table)) for _, ch in sorted(self._chains.items())]}
                chains["move_table"] = [sess.move_to_json(m) for _, m in table.values()]
                self._dirty = False
            state = {"settings": settings, "events": events, "chains": chains, "record": record}
            try:
                sess.write_state(self.session_dir, **state, lock=self._session_lock)
                self._save_failures = 0
            except (OSError, GalileoError):
                why = self._session_lock.lost() if self._session_lock is not None else None
                if why is None:
                    # a folder being deleted fails the write before it is gone: the next save looks again
                    # (the session stays dirty); a write that keeps failing in a folder still there is the error
                    self._dirty = True
                    self._save_failures += 1
                    if not retry or self._save_failures >= SAVE_RETRIES:
                        raise
                    return
                self._session_lost(why, state)
            self._last_save = time.monotonic()

    def _session_lost(self, why: str, state: dict) -> None:
        """The session folder is gone (deleted, moved, replaced: `why`): write the whole session
        to a new folder beside it and save there from now on, or, if that fails, stop saving.
        Says which on stderr, in status()["session"] and to the listeners ("session")."""
        old = self.session_dir
        try:
            lock = sess.recover(self._session_lock, scene_json=self._scene_json, tracks_json=self._tracks_json,
                                **state)
        except (OSError, GalileoError) as e:
            lock, failed = None, " ".join(str(e).split())
        self._session_lock.release()    # (a moved folder may be opened by another app now)
        if lock is None:
            self._saving = False
            level, text = "error", (f"the session folder {old} {why}: nothing more is saved (no new folder could be "
                                    f"written beside it: {failed}); the chains go on in this app")
        else:
            self._session_lock, self.session_dir = lock, lock.folder
            level, text = "warning", (f"the session folder {old} {why}: the whole session is saved in {lock.folder} "
                                      "from now on")
        with self._lock:
            self._session_note = text
            self._notices.append(("session", {"text": text, "saving": self._saving}))
        print(f"galileo: {level}: {text}", file=sys.stderr, flush=True)
        log.info("%s", text)

    @classmethod
    def load(cls, session_dir: str | Path, *, workers: int | None = None, save_every_s: float = 1.0, executor=None,
             sweeps: int | None = None, paused: bool = False) -> "Controller":
        """Restore a saved session exactly; its chains go on from where they stopped (with
        their adapted widths and moves), or, with `paused`, every chain that was running pauses
        (a "pause" event) until `resume`. `sweeps`: the sweep target of a session recorded
        before the controller kept one (a session's own target wins). The session's lock is
        taken first: a session another app (or controller) has open is refused (GalileoError)
        before anything is read or started."""
        lock = sess.SessionLock(session_dir)
        try:
            self = cls._restore(lock, workers, save_every_s, executor, sweeps)
        except BaseException:
            lock.release()
            raise
        if paused:
            with self._lock:
                ids = [c for c, ch in sorted(self._chains.items()) if not ch.removed and not ch.paused]
                for c in ids:
                    self._chains[c].paused = True
                if ids:
                    self._event("pause", {"chains": ids, "reason": "session reopened: Resume runs them on"})
        return self

    @classmethod
    def _restore(cls, lock: sess.SessionLock, workers, save_every_s, executor, sweeps) -> "Controller":
        folder = sess.check_folder(lock.folder)
        path = folder / sess.SCENE_FILE
        scene_json = sess.read_json_file(folder, sess.SCENE_FILE)
        with sess.reading(path):
            scene = registry.scene_from_json(scene_json)
            scenario = registry.of(scene)
        path = folder / sess.TRACKS_FILE
        tracks_json = sess.read_json_file(folder, sess.TRACKS_FILE)
        with sess.reading(path):
            tracks = tracks_from_json(tracks_json)
            latents = scenario.latents(scenario.prepare(scene, tracks))
            names = tuple(lat.name for lat in latents)
        path = folder / sess.SETTINGS_FILE
        raw = sess.read_json_file(folder, sess.SETTINGS_FILE)
        with sess.reading(path):
            Settings.from_json(raw, latents, scenario.noise)
        path = folder / sess.EVENTS_FILE
        raw_events = sess.read_json_file(folder, sess.EVENTS_FILE)
        with sess.reading(path):
            events = raw_events["events"]
            keys = {"sweep", "time", "kind", "detail"}
            if not isinstance(events, list) or not all(isinstance(e, dict) and keys <= set(e) for e in events):
                raise ValueError("expected a list of events {sweep, time, kind, detail}")
        path = folder / sess.CHAINS_FILE
        doc = sess.read_json_file(folder, sess.CHAINS_FILE)
        with sess.reading(path):
            if list(doc["names"]) != list(names):
                raise ValueError(f"latents {doc['names']} differ from the scene's {list(names)}")
            settings = Settings.from_json(doc["settings"], latents, scenario.noise)
            n_events = int(doc["n_events"])
            if not 0 <= n_events <= len(events):
                raise ValueError(f"{n_events} events committed but events.json holds {len(events)}")
            chain_docs = list(doc["chains"])
            if not chain_docs:
                raise ValueError("no chains listed")
            table = doc.get("move_table", [])    # (recorded before the table: every move inline)
            if not isinstance(table, list):
                raise ValueError("move_table must be a list of moves")
            seed, rounds = _whole(doc["seed"], "seed", 0), _whole(doc["rounds"], "rounds", 0)
            next_id, steps = int(doc["next_id"]), int(doc["physics_steps"])
            adapt_until = _whole(doc.get("adapt_until", 0), "adapt_until", 0)
            target = doc.get("target_sweeps", sweeps)
            target = None if target is None else _whole(target, "target_sweeps", 1)
            until = doc.get("until")
            if until is not None:
                until = _until(until["until_rhat"], until["min_ess"], until["max_sweeps"], target)
        dim = len(names)
        with sess.reading(folder / sess.EVENTS_FILE):
            # the move set, warm-up and joint moves as the init event recorded them (none: the paper's kernel)
            first = next((e for e in events[:n_events] if e["kind"] == "init"), None)
            detail = first["detail"] if first is not None and isinstance(first.get("detail"), dict) else {}
            moves_set = detail.get("moves", "paper")
            if moves_set not in MOVE_SETS:
                raise ValueError(f"init: unknown moves {moves_set!r}")
            warmup = _whole(detail.get("warmup", 0), "init: warmup", 0)
            moves0 = tuple(sess.move_from_json(m, dim) for m in detail.get("joint_moves", []))
            fit = next((e for e in events[:n_events] if e["kind"] == "fitted"), None)   # ("fitted": the move, once)
            if fit is not None and isinstance(fit.get("detail"), dict) and fit["detail"].get("move") is not None:
                # (a session recorded before the conditional moves: 12 joint proposals and none; before
                # the marginal moves, none; before the kernel move, its joint proposals from q)
                marginals = fit["detail"].get("marginals", [])
                if not isinstance(marginals, list):
                    raise ValueError("fitted: marginals must be a list of moves")
                moves0 += fitted_moves(sess.move_from_json(fit["detail"]["move"], dim),
                                       _whole(fit["detail"].get("per_sweep", 12), "fitted: per_sweep", 1),
                                       _whole(fit["detail"].get("conditionals", 0), "fitted: conditionals", 0),
                                       tuple(sess.move_from_json(m, dim) for m in marginals),
                                       _whole(fit["detail"].get("marginals_per_sweep", 0), "fitted: marginals_per_sweep",
                                              0),
                                       None if fit["detail"].get("kernel") is None
                                       else sess.move_from_json(fit["detail"]["kernel"], dim))
            if moves_set == "paper" and (moves0 or warmup):
                raise ValueError("init: the paper's moves with joint moves or a warm-up")
        record = sess.read_record(folder)
        if moves_set == "paper":   # sessions recorded before the default likelihood changed replay as they ran
            with sess.reading(folder / sess.SCENE_FILE):
                scene = scene_for_moves(scene, "paper")
        self = cls.__new__(cls)
        self._setup(scene, tracks, latents, seed, workers, settings, folder, save_every_s, executor)
        self._rounds, self._next_id, self._steps = rounds, next_id, steps
        self._events = events[:n_events]
        self.moves_set, self._warmup, self._moves0, self._adapt_until = moves_set, warmup, moves0, adapt_until
        self._fitted = fit is not None
        self._target, self._until = target, until
        block = sweeps if sweeps is not None else detail.get("sweeps")
        self._block = block if isinstance(block, int) and block >= 1 else None
        if until is not None:
            self._min_ess = until["min_ess"]
        if isinstance(detail.get("init"), dict):
            self.init_info = _checked_init(detail["init"], dim)
        valid_sites = set(range(dim)) | {move_code(k) for k in range(len(moves0))}
        tabled: dict = {}     # the move table's entries read so far, by index
        for d in chain_docs:
            with sess.reading(folder / sess.CHAINS_FILE):
                c = int(d["id"])
                if not 0 <= c < next_id or c in self._chains:
                    raise ValueError(f"bad chain id {c}")
                rng_state = d["rng"]
                bit_gen = getattr(np.random, rng_state["bit_generator"])()
                bit_gen.state = rng_state
                proposal = (sess.proposal_from_json(d["proposal"], dim) if "proposal" in d
                            else settings.proposal())   # (recorded before adaptation: the settings' widths)
                if proposal.integer_sites != settings.integer_sites:
                    raise ValueError(f"chain {c}: integer sites {list(proposal.integer_sites)} differ from the "
                                     f"latents' {list(settings.integer_sites)}")
                chain_moves = (tuple(_recorded_move(m, table, tabled, dim) for m in d["moves"]) if "moves" in d
                               else moves0)
                if [type(m) for m in chain_moves] != [type(m) for m in moves0]:
                    raise ValueError(f"chain {c}: its joint moves differ from the session's")
                ch = _Chain(c, _vector(d["start"], dim), bit_gen.state, dim, proposal, chain_moves)
                ch.position = _vector(d["position"], dim)
                ch.logdensity = None if d["logdensity"] is None else float(d["logdensity"])
                ch.sweep, ch.paused, ch.removed = int(d["sweep"]), bool(d["paused"]), bool(d["removed"])
                ch.held = bool(d.get("held", False))
                n_s, n_p = int(d["n_samples"]), int(d["n_proposals"])
                if n_s != ch.sweep:
                    raise ValueError(f"chain {c}: {n_s} samples after {ch.sweep} sweeps")
            with sess.reading(folder / sess.RECORD_FILE):
                samples = record[f"c{c}_samples"]
                logliks = record[f"c{c}_logliks"]
                if samples.ndim != 2 or samples.shape[1] != dim or len(samples) < n_s or len(logliks) < n_s:
                    raise ValueError(f"chain {c}: fewer than the {n_s} committed samples")
                ch.samples = _Buf(float, dim, samples[:n_s])
                ch.logliks = _Buf(float, None, logliks[:n_s])
                if f"c{c}_noise" in record:
                    noise = record[f"c{c}_noise"]
                    if noise.ndim != 1 or len(noise) < n_s or not np.all(np.isfinite(noise[:n_s]) & (noise[:n_s] > 0)):
                        raise ValueError(f"chain {c}: fewer than the {n_s} committed samples' noise, or a bad one")
                    ch.noise = _Buf(float, None, noise[:n_s])
                else:   # recorded before per-sample noise: read from the sigma events
                    ch.noise = _Buf(float, None, _noise_from_events(self._events, c, n_s, settings.noise,
                                                                     scenario.noise.name))
                for k, (t, wide) in PROPOSAL_FIELDS.items():
                    a = record[f"c{c}_{k}"]
                    if len(a) < n_p:
                        raise ValueError(f"chain {c}: fewer than the {n_p} committed proposals")
                    ch.proposals[k] = _Buf(t, dim if wide else None, a[:n_p])
                site = ch.proposals["site"].get().astype(int)
                bad = sorted(set(np.unique(site).tolist()) - valid_sites)
                if bad:
                    raise ValueError(f"chain {c}: proposal sites {bad[:5]} are neither latents 0..{dim - 1} nor the "
                                     f"session's {len(moves0)} joint moves")
                self._count(site, ch.proposals["accepted"].get())
                ch.note_best()
            self._chains[c] = ch
        self._dirty = False
        self._last_save = time.monotonic()
        self._session_lock = lock
        for name in sess.video_files(folder):
            lock.keep(name)
        self._start_pool()
        return self


def _whole(x, what: str, low: int) -> int:
    """An integer >= low (ValueError otherwise)."""
    if isinstance(x, bool) or not isinstance(x, (int, np.integer, float)) or int(x) != x or x < low:
        raise ValueError(f"{what} must be an integer >= {low}, got {x!r}")
    return int(x)


def _check_min_ess(min_ess) -> float:
    if isinstance(min_ess, bool) or not isinstance(min_ess, (int, float)) or not math.isfinite(min_ess) or min_ess < 0:
        raise ValueError(f"min_ess must be a number >= 0, got {min_ess!r}")
    return float(min_ess)


def _until(until_rhat, min_ess, max_sweeps, sweeps: int | None) -> dict | None:
    """Run-until-converged criteria checked as `galileo.runner.RunConfig.check` does (None:
    off); max_sweeps defaults to 20 x the sweep target."""
    if until_rhat is None:
        return None
    if (isinstance(until_rhat, bool) or not isinstance(until_rhat, (int, float)) or not math.isfinite(until_rhat)
            or until_rhat <= 1.0):
        raise ValueError(f"until_rhat must be a number above 1, got {until_rhat!r}")
    base = int(sweeps or 1)
    budget = (RunConfig(sweeps=base).sweep_budget() if max_sweeps is None   # 20 x the sweeps, as galileo infer's
              else _whole(max_sweeps, "max_sweeps", 1))
    if budget < base:
        raise ValueError(f"max_sweeps must be >= the sweep target ({base}), got {max_sweeps!r}")
    return {"until_rhat": float(until_rhat), "min_ess": _check_min_ess(min_ess), "max_sweeps": int(budget)}


def _noise_from_events(events: list[dict], chain: int, n: int, current: float, name: str) -> np.ndarray:
    """The noise each of a chain's first n samples was scored under, from the sigma events
    (sessions recorded before per-sample noise): the first event's old value, then each event's
    from the chain's sweep count at it (a chain created after an event: all of its samples)."""
    sig = [e for e in events if e["kind"] == "sigma"]
    out = np.full(n, float(sig[0]["detail"]["old"]) if sig else float(current))
    created = False
    for e in events:
        if e["kind"] in ("init", "add_chains") and chain in e["detail"].get("chains", []):
            created = True
        elif e["kind"] == "sigma":
            k = e.get("chain_sweeps", {}).get(str(chain))
            if k is not None:
                out[int(k):] = float(e["detail"][name])
            elif not created:   # the chain came later: all its samples under this sigma (or a later one)
                out[:] = float(e["detail"][name])
    return out


def _vector(x, dim: int) -> np.ndarray:
    v = np.asarray(x, float)
    if v.shape != (dim,) or not np.all(np.isfinite(v)):
        raise ValueError(f"expected {dim} finite numbers, got {x!r}")
    return v
