"""Single-site Metropolis-Hastings (Galileo section 3.2) as a pure kernel.

`sweep(rng, state)` proposes each latent in turn from U(-w, w) around its value, with
w = `narrow` (0.05) and every `broad_every`-th sweep (the 20th, 40th, ...) w = `broad`
(0.5). A proposal outside the prior's support is rejected without evaluating the
target. The target is a callable `logdensity(position, threshold=None)` returning a float or
(value, stopped_early). When the kernel passes a threshold the target may stop evaluating
as soon as it knows its value is below it and return (an upper bound, True): exact early
rejection, since the uniform of the MH test is drawn before the evaluation and the
decision is the same as with the full value.

State and per-proposal information are NamedTuples over numpy values; the kernel keeps no
state of its own, so chains are reproducible from (seed, chain index) whatever process
runs them.
"""
from __future__ import annotations

import math
from typing import Callable, NamedTuple, Sequence

import numpy as np


class MHState(NamedTuple):
    position: np.ndarray   # (n_latents,)
    logdensity: float
    sweep: int             # sweeps done so far


class MHInfo(NamedTuple):
    site: int              # which latent was proposed
    proposal: np.ndarray   # the proposed position (all latents)
    logdensity: float      # target at the proposal; -inf outside the prior; if early_stop, a bound below the threshold
    accepted: bool
    width: float           # half-width of the uniform proposal used
    early_stop: bool       # the evaluation stopped early (a guaranteed rejection)


class Proposal(NamedTuple):
    """Proposal widths: U(-narrow, narrow), and U(-broad, broad) every broad_every-th sweep;
    a latent in `integer_sites` moves by -w or +w with equal odds instead (symmetric, so no
    Hastings factor either way)."""
    narrow: float | Sequence[float] = 0.05
    broad: float | Sequence[float] = 0.5
    broad_every: int = 20
    integer_sites: tuple[int, ...] = ()

    def width(self, sweep_number: int, site: int) -> float:
        """Half-width for sweep `sweep_number` (1-based) and latent `site` (an integer site's
        step: a whole number, at least 1)."""
        broad = self.broad_every and sweep_number % self.broad_every == 0
        w = self.broad if broad else self.narrow
        w = float(w[site] if isinstance(w, (list, tuple, np.ndarray)) else w)
        return float(max(1, round(w))) if site in self.integer_sites else w


LogDensity = Callable[..., float]


def init(position: Sequence[float], logdensity: LogDensity) -> MHState:
    pos = np.asarray(position, float).copy()
    value = logdensity(pos)
    return MHState(pos, float(value[0] if isinstance(value, tuple) else value), 0)


def step_site(rng: np.random.Generator, state: MHState, site: int, width: float, logdensity: LogDensity,
              bounds: np.ndarray, early_rejection: bool = True, integer: bool = False) -> tuple[MHState, MHInfo]:
    """One single-site MH update of latent `site` (`integer`: a step of -width or +width)."""
    proposal = state.position.copy()
    if integer:
        proposal[site] += width if rng.uniform() < 0.5 else -width
    else:
        proposal[site] += rng.uniform(-width, width)
    log_u = math.log(rng.uniform())  # drawn before the evaluation (and always: same stream either way)
    lo, hi = bounds[site]
    if not lo <= proposal[site] <= hi:
        return state, MHInfo(site, proposal, -math.inf, False, width, False)
    threshold = state.logdensity + log_u
    result = logdensity(proposal, threshold) if early_rejection else logdensity(proposal)
    value, early = (float(result[0]), bool(result[1])) if isinstance(result, tuple) else (float(result), False)
    accepted = (not early) and value >= threshold and value > -math.inf
    new = MHState(proposal, value, state.sweep) if accepted else state
    return new, MHInfo(site, proposal, value, accepted, width, early)


def sweep(rng: np.random.Generator, state: MHState, logdensity: LogDensity, bounds: np.ndarray,
          proposal: Proposal = Proposal(), early_rejection: bool = True,
          sites: Sequence[int] | None = None) -> tuple[MHState, list[MHInfo]]:
    """One sweep: each latent (or each of `sites`) proposed once, in order."""
    number = state.sweep + 1
    infos = []
    for site in (range(len(state.position)) if sites is None else sites):
        state, info = step_site(rng, state, site, proposal.width(number, site), logdensity, bounds,
                                early_rejection, site in proposal.integer_sites)
        infos.append(info)
    return state._replace(sweep=number), infos


def chain_rng(seed: int, chain: int) -> np.random.Generator:
    """The random stream of chain `chain` of a run seeded with `seed` (independent of workers)."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(chain,)))


def run_chain(seed: int, chain: int, init_position: Sequence[float], logdensity: LogDensity, bounds,
              n_sweeps: int, proposal: Proposal = Proposal(), early_rejection: bool = True):
    """A whole chain: returns (positions after each sweep (S, D), logdensities (S,), infos)."""
    rng = chain_rng(seed, chain)
    bounds = np.asarray(bounds, float)
    state = init(init_position, logdensity)
    positions, values, infos = [], [], []
    for _ in range(n_sweeps):
        state, inf = sweep(rng, state, logdensity, bounds, proposal, early_rejection)
        positions.append(state.position.copy())
        values.append(state.logdensity)
        infos.extend(inf)
    return np.array(positions), np.array(values), infos
