"""Single-site Metropolis-Hastings (Galileo section 3.2) as a pure kernel.

`sweep(rng, state)` proposes each latent in turn from U(-w, w) around its value, with
w = `narrow` (0.05) and every `broad_every`-th sweep (the 20th, 40th, ...) w = `broad`
(0.5). A proposal outside the prior's support is rejected without evaluating the
target. The target is a callable `logdensity(position, threshold=None)` returning a float or
(value, stopped_early). When the kernel passes a threshold the target may stop evaluating
as soon as it knows its value is below it and return (an upper bound, True): exact early
rejection, since the uniform of the MH test is drawn before the evaluation and the
decision is the same as with the full value.

An optional independence move (`Independence`, `step_independence`) proposes the whole latent
vector from a fixed product distribution q (normal, lognormal or uniform per latent) and
accepts with the Hastings ratio p(x')q(x) / (p(x)q(x')); `sweep(..., independence=q)` makes one
such move after the single-site updates of every `q.every`-th sweep (without it, sweeps and
their random streams are unchanged). It uses the same drawn-first uniform and threshold, so
early rejection stays exact.

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
    site: int              # which latent was proposed (-1: a joint independence move)
    proposal: np.ndarray   # the proposed position (all latents)
    logdensity: float      # target at the proposal; -inf outside the prior; if early_stop, a bound below the threshold
    accepted: bool
    width: float           # half-width of the uniform proposal used (nan for an independence move)
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


_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)
_KINDS = ("normal", "lognormal", "uniform")


class Independence(NamedTuple):
    """A product proposal over all latents for the independence move, one component a latent:
    "normal" (loc, scale of the value), "lognormal" (loc, scale of the log of the value; the
    value is > 0) or "uniform" (loc = low, scale = high). Used every `every`-th sweep."""
    kinds: tuple[str, ...]
    loc: tuple[float, ...]
    scale: tuple[float, ...]
    every: int = 1
    name = "independence"   # a class attribute, not a field

    def propose(self, rng: np.random.Generator, position) -> tuple[np.ndarray, float]:
        """x' ~ q and log Hastings log q(x) - log q(x') (a joint move, see `step_move`)."""
        x = self.sample(rng)
        lq_new = self.logpdf(x)
        if not lq_new > -math.inf:  # a draw on the edge of q's support (probability zero)
            return x, -math.inf
        return x, self.logpdf(position) - lq_new   # -inf when x is outside q's support: no move

    def check(self, n_latents: int | None = None) -> Independence:
        """Raise ValueError (one line) on a bad spec; return self."""
        n = len(self.kinds)
        if len(self.loc) != n or len(self.scale) != n:
            raise ValueError(f"Independence: kinds, loc and scale differ in length ({n}, {len(self.loc)}, {len(self.scale)})")
        if n == 0:
            raise ValueError("Independence: no components")
        if n_latents is not None and n != n_latents:
            raise ValueError(f"Independence: {n} components for {n_latents} latents")
        if isinstance(self.every, bool) or not isinstance(self.every, (int, np.integer)) or self.every < 1:
            raise ValueError(f"Independence: every must be an integer >= 1, got {self.every!r}")
        for i, (kind, a, b) in enumerate(zip(self.kinds, self.loc, self.scale)):
            if kind not in _KINDS:
                raise ValueError(f"Independence: component {i}: unknown kind {kind!r} (one of {', '.join(_KINDS)})")
            try:
                a, b = float(a), float(b)
            except (TypeError, ValueError):
                raise ValueError(f"Independence: component {i}: loc and scale must be numbers, got {a!r}, {b!r}") from None
            if not (math.isfinite(a) and math.isfinite(b)):
                raise ValueError(f"Independence: component {i}: loc and scale must be finite, got {a}, {b}")
            if kind == "uniform":
                if not a < b:
                    raise ValueError(f"Independence: component {i}: uniform needs low < high, got {a}, {b}")
            elif not b > 0:
                raise ValueError(f"Independence: component {i}: {kind} needs scale > 0, got {b}")
        return self

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """One draw x ~ q (one random number per component, in order)."""
        x = np.empty(len(self.kinds))
        for i, (kind, a, b) in enumerate(zip(self.kinds, self.loc, self.scale)):
            if kind == "normal":
                x[i] = rng.normal(a, b)
            elif kind == "lognormal":
                x[i] = math.exp(rng.normal(a, b))
            else:
                x[i] = rng.uniform(a, b)
        return x

    def logpdf(self, x: Sequence[float]) -> float:
        """log q(x), normalised (with the lognormal's Jacobian -log x); -inf outside the support."""
        total = 0.0
        for v, kind, a, b in zip(x, self.kinds, self.loc, self.scale):
            v = float(v)
            if kind == "normal":
                z = (v - a) / b
                total += -0.5 * z * z - math.log(b) - _LOG_SQRT_2PI
            elif kind == "lognormal":
                if not v > 0.0:
                    return -math.inf
                lv = math.log(v)
                z = (lv - a) / b
                total += -0.5 * z * z - math.log(b) - _LOG_SQRT_2PI - lv
            else:
                if not a <= v <= b:
                    return -math.inf
                total += -math.log(b - a)
        return total


def step_move(rng: np.random.Generator, state: MHState, move, logdensity: LogDensity, bounds: np.ndarray,
              early_rejection: bool = True, site_code: int = -1, hastings: bool = True) -> tuple[MHState, MHInfo]:
    """One MH update by a joint `move` (anything with `propose(rng, position) -> (proposal,
    log_hastings)`, log_hastings = log q(x | x') - log q(x' | x) plus any Jacobian): accepted
    with probability min(1, p(x') / p(x) * exp(log_hastings)). The uniform is drawn after the
    proposal and before the evaluation, so early rejection is exact (threshold = log p(x) +
    log u - log_hastings). Out-of-bounds proposals are rejected without evaluating the target.
    `hastings=False` drops the factor (a wrong sampler, for negative-control tests only)."""
    proposal, log_h = move.propose(rng, state.position)
    log_u = math.log(rng.uniform())  # drawn before the evaluation (and always: same stream either way)
    bounds = np.asarray(bounds, float)
    if not np.all((bounds[:, 0] <= proposal) & (proposal <= bounds[:, 1])) or not log_h > -math.inf:
        return state, MHInfo(site_code, proposal, -math.inf, False, math.nan, False)
    threshold = state.logdensity + log_u - (float(log_h) if hastings else 0.0)
    result = logdensity(proposal, threshold) if early_rejection else logdensity(proposal)
    value, early = (float(result[0]), bool(result[1])) if isinstance(result, tuple) else (float(result), False)
    accepted = (not early) and value >= threshold and value > -math.inf
    new = MHState(proposal, value, state.sweep) if accepted else state
    return new, MHInfo(site_code, proposal, value, accepted, math.nan, early)


def step_independence(rng: np.random.Generator, state: MHState, q: Independence, logdensity: LogDensity,
                      bounds: np.ndarray, early_rejection: bool = True, hastings: bool = True) -> tuple[MHState, MHInfo]:
    """One independence MH update of all latents: x' ~ q, accepted with probability
    min(1, p(x') q(x) / (p(x) q(x'))). `hastings=False` drops the q terms (a wrong sampler, for
    tests only). Out-of-bounds proposals are rejected without evaluating the target."""
    q.check(len(state.position))
    return step_move(rng, state, q, logdensity, bounds, early_rejection, -1, hastings)


# -- joint moves: each proposes and returns its own log Hastings factor ---------------------------



class SiteMixture(NamedTuple):
    """Propose one latent (`site`) afresh from a fixed mixture, the others unchanged: with
    probability `weight` from N(loc, scale), else uniformly on [low, high] (a defensive
    component, e.g. the prior's support). An independence move within one coordinate:
    log Hastings = log q(x_site) - log q(x'_site)."""
    site: int
    weight: float
    loc: float
    scale: float
    low: float
    high: float
    every: int = 1
    name: str = "site_mixture"

    def logq(self, v: float) -> float:
        z = (v - self.loc) / self.scale
        dens = self.weight * math.exp(-0.5 * z * z) / (self.scale * math.sqrt(2 * math.pi))
        if self.low <= v <= self.high:
            dens += (1.0 - self.weight) / (self.high - self.low)
        return math.log(dens) if dens > 0 else -math.inf

    def propose(self, rng: np.random.Generator, position) -> tuple[np.ndarray, float]:
        x = np.asarray(position, float).copy()
        if rng.uniform() < self.weight:
            v = rng.normal(self.loc, self.scale)
        else:
            v = rng.uniform(self.low, self.high)
        old = float(x[self.site])
        x[self.site] = v
        lq_new = self.logq(v)
        return x, (self.logq(old) - lq_new) if lq_new > -math.inf else -math.inf


class LogScale(NamedTuple):
    """Scale some latents together: u ~ U(-width, width), x'_i = x_i * exp(sign_i * u) for
    i in `sites`. For two masses, signs (1, 1) change their product and keep their ratio;
    (1, -1) change their ratio and keep their product. The map is symmetric in log space; in
    the latents' own (linear) space its Jacobian gives log Hastings = u * sum(signs). The
    latents must be > 0 (a proposal from x_i <= 0 is refused)."""
    sites: tuple[int, ...]
    signs: tuple[float, ...]
    width: float
    every: int = 1
    name: str = "log_scale"

    def propose(self, rng: np.random.Generator, position) -> tuple[np.ndarray, float]:
        x = np.asarray(position, float).copy()
        u = rng.uniform(-self.width, self.width)
        if any(x[i] <= 0 for i in self.sites):
            return x, -math.inf
        for i, s in zip(self.sites, self.signs):
            x[i] = x[i] * math.exp(s * u)
        return x, u * float(sum(self.signs))

    def adapted(self, accepted: bool, eta: float) -> "LogScale":
        """The width after one warm-up update towards acceptance TARGET_ACCEPTANCE."""
        return self._replace(width=float(min(5.0, max(1e-4, self.width * math.exp(eta * (accepted - TARGET_ACCEPTANCE))))))


class RayMove(NamedTuple):
    """Redraw two positive latents along the ray through the origin they lie on: with
    r = x_i / x_j fixed, x_j' is drawn from the density proportional to x_j' on the part of
    the ray inside the box prior [lo_i, hi_i] x [lo_j, hi_j], and x_i' = r x_j'. For a uniform
    prior on the box that density is the prior's own conditional along the ray (in
    coordinates (r, x_j) the prior's density is proportional to x_j, the Jacobian), so the
    Hastings factor is exactly 1 and the move is accepted with probability
    min(1, L(x') / L(x)): always, for a likelihood that depends only on the ratio (the ramp's
    masses in a collision). `bounds` are the two latents' prior bounds; the move is exact only
    for a uniform prior on them (the default's)."""
    sites: tuple[int, int]
    bounds: tuple[tuple[float, float], tuple[float, float]]
    every: int = 1
    name: str = "ray"

    def propose(self, rng: np.random.Generator, position) -> tuple[np.ndarray, float]:
        x = np.asarray(position, float).copy()
        i, j = self.sites
        (lo_i, hi_i), (lo_j, hi_j) = self.bounds
        u = rng.uniform()
        if not (x[i] > 0 and x[j] > 0):
            return x, -math.inf
        r = x[i] / x[j]
        a, b = max(lo_j, lo_i / r), min(hi_j, hi_i / r)
        if not a < b:
            return x, -math.inf
        xj = math.sqrt(a * a + u * (b * b - a * a))
        x[j], x[i] = xj, r * xj
        return x, 0.0


FITTED_DF = 5.0          # the fitted independence move: a multivariate Student-t of this many degrees of freedom ...
FITTED_INFLATE = 1.5     # ... its scale this many times the warm-up draws' covariance's (a heavier, wider q
                         # than the posterior: the Hastings ratio is bounded where q's tails cover p's)
FITTED_TRIM_LEVEL = 0.975  # ... fitted to the draws within this chi-square quantile of a first fit (twice):
FITTED_TRIM_ROUNDS = 2     # a chain the warm-up left 10 nats below the rest widened q, and cut its acceptance by half
FITTED_WEIGHT = 0.8      # ... the rest of its mass the prior's box (a defensive uniform: q covers all of it)


class FittedIndependence(NamedTuple):
    """An independence move over the latents `sites` (the others unchanged), from a proposal q
    fitted to where the chains are: with probability `weight` a multivariate Student-t (`df`
    degrees of freedom, centre `loc`, scale factor `chol`) in a transformed space (the log of
    the latents in `log_sites`, the others as they are), else uniform on the box `bounds` of
    those sites (a defensive component: q is positive wherever the prior is). It carries its
    Hastings factor, log q(x) - log q(x') with the log map's Jacobian in q's density in the
    latents' own space, so it is exact for any fixed q (Robert & Casella 7.4; a mixture with a
    heavy-tailed, defensive part, Hesterberg 1995). Fitted once, to every chain's warm-up draws
    (`fit_independence`), and then frozen: the kept draws come from one fixed kernel. A proposal
    draws from the whole posterior at once, so chains that a jagged likelihood holds in
    different places (the ramp's k1, its target's friction against the mass ratio) meet."""
    sites: tuple[int, ...]
    log_sites: tuple[int, ...]   # a subset of sites
    loc: tuple[float, ...]
    chol: tuple                  # lower-triangular scale factor, rows as tuples
    bounds: tuple                # ((lo, hi), ...) of the sites
    df: float = FITTED_DF
    weight: float = FITTED_WEIGHT
    every: int = 1
    name: str = "fitted"

    def _y(self, v: np.ndarray) -> np.ndarray:
        return np.array([math.log(v[k]) if i in self.log_sites else float(v[k]) for k, i in enumerate(self.sites)])

    def logq(self, v: Sequence[float]) -> float:
        """log q of the sites' values `v` (in the latents' own space); -inf outside the box."""
        v = np.asarray(v, float)
        box = np.asarray(self.bounds, float)
        if not np.all((box[:, 0] <= v) & (v <= box[:, 1])):
            return -math.inf
        log_u = -float(np.log(box[:, 1] - box[:, 0]).sum())
        if any(v[k] <= 0 for k, i in enumerate(self.sites) if i in self.log_sites):
            return math.log1p(-self.weight) + log_u if self.weight < 1 else -math.inf
        chol = np.asarray(self.chol, float)
        d = len(self.sites)
        z = np.linalg.solve(chol, self._y(v) - np.asarray(self.loc, float))
        log_t = (math.lgamma((self.df + d) / 2) - math.lgamma(self.df / 2) - 0.5 * d * math.log(self.df * math.pi)
                 - float(np.log(np.diag(chol)).sum()) - 0.5 * (self.df + d) * math.log1p(float(z @ z) / self.df))
        log_t -= sum(math.log(v[k]) for k, i in enumerate(self.sites) if i in self.log_sites)   # dy/dv
        parts = [math.log(self.weight) + log_t] if self.weight > 0 else []
        if self.weight < 1:
            parts.append(math.log1p(-self.weight) + log_u)
        return float(np.logaddexp.reduce(parts))

    def propose(self, rng: np.random.Generator, position) -> tuple[np.ndarray, float]:
        return _propose_t_or_box(self, rng, position, lambda: _t_draw(rng, self.loc, self.chol, self.df))


class FittedConditional(NamedTuple):
    """An independence move of one latent given the others, from the fitted move's q
    (`FittedIndependence`, the defensive part left out). With y the sites in q's transformed
    space and q's t part of centre m, scale S and df degrees of freedom, the conditional of y_k
    given y_-k is the univariate t of df + d - 1 degrees of freedom, centre m_k + b (y_-k - m_-k),
    squared scale (df + delta^2) / (df + d - 1) s^2 (b and s^2 the normal's regression and
    conditional variance under S, delta^2 = (y_-k - m_-k)' S_-k^-1 (y_-k - m_-k)). The others are
    unchanged, so this is a fixed proposal for the coordinate: log Hastings = log q(x_k | rest) -
    log q(x'_k | rest), with the log map's Jacobian for a log site; exact (Metropolis within
    Gibbs). Where the joint q must match the posterior in every latent at once to be accepted,
    this one must match it in one: the ramp's jagged k1 is redrawn from its conditional often."""
    site: int                    # the latent moved
    log: bool                    # it is moved in log (a log site of q)
    others: tuple[int, ...]      # the sites conditioned on
    others_log: tuple[bool, ...]
    loc: float                   # q's centre of y_k ...
    others_loc: tuple[float, ...]  # ... and of y_-k
    coef: tuple[float, ...]      # the regression on y_-k - m_-k
    var: float                   # the conditional variance (normal) under q's scale
    prec: tuple                  # S_-k^-1, rows as tuples (for delta^2)
    df: float                    # q's degrees of freedom
    every: int = 1
    name: str = "fitted_conditional"

    def check(self, n_latents: int) -> "FittedConditional":
        """ValueError (one line) unless the fields fit together (the sites within the latents,
        the others' fields of their length, a positive variance and df); self otherwise."""
        p = len(self.others)
        if not all(0 <= i < n_latents for i in (self.site, *self.others)) or self.site in self.others:
            raise ValueError(f"FittedConditional: sites {self.site}, {self.others} outside 0..{n_latents - 1} or repeated")
        if (len(self.others_log), len(self.others_loc), len(self.coef)) != (p, p, p) or np.shape(
                np.asarray(self.prec, float).reshape(-1)) != (p * p,):
            raise ValueError(f"FittedConditional: the others' fields are not of {p} latents")
        if not (self.var > 0 and self.df > 0):
            raise ValueError("FittedConditional: the variance and df must be positive")
        return self

    def _given(self, x: np.ndarray) -> tuple[float, float, float]:
        """(centre, scale, degrees of freedom) of the conditional at the others' values in x."""
        r = np.array([math.log(x[i]) if lg else float(x[i]) for i, lg in zip(self.others, self.others_log)])
        p = len(self.others)
        if not p:
            return self.loc, math.sqrt(self.var), self.df
        r -= np.asarray(self.others_loc, float)
        delta2 = float(r @ np.asarray(self.prec, float) @ r)
        return (self.loc + float(np.dot(self.coef, r)), math.sqrt((self.df + delta2) / (self.df + p) * self.var),
                self.df + p)

    def _logq(self, v: float, centre: float, scale: float, dof: float) -> float:
        if self.log:
            if not v > 0:
                return -math.inf
            y, jac = math.log(v), -math.log(v)
        else:
            y, jac = v, 0.0
        z = (y - centre) / scale
        return (math.lgamma((dof + 1) / 2) - math.lgamma(dof / 2) - 0.5 * math.log(dof * math.pi) - math.log(scale)
                - 0.5 * (dof + 1) * math.log1p(z * z / dof) + jac)

    def propose(self, rng: np.random.Generator, position) -> tuple[np.ndarray, float]:
        x = np.asarray(position, float).copy()
        if any(not x[i] > 0 for i, lg in zip(self.others, self.others_log) if lg):
            return x, -math.inf
        centre, scale, dof = self._given(x)
        y = centre + scale * rng.standard_t(dof)
        old = float(x[self.site])
        x[self.site] = math.exp(y) if self.log else y
        lq_old = self._logq(old, centre, scale, dof)
        if not lq_old > -math.inf or not math.isfinite(x[self.site]):
            return x, -math.inf
        return x, lq_old - self._logq(float(x[self.site]), centre, scale, dof)


MARGINAL_CENTRES = 400   # the marginal move's kernel density estimate: at most this many of the warm-up draws ...
MARGINAL_WEIGHT = 0.95   # ... the rest of its mass uniform on the latent's prior range (defensive)


class FittedMarginal(NamedTuple):
    """An independence move of one latent (`site`) alone, the others unchanged, from a kernel
    density estimate of the chains' warm-up draws of it: with probability `weight` a normal of
    sd `bandwidth` around one of `centres` picked uniformly (in log for a log site), else
    uniform on the latent's prior range `bounds`. Fixed once fitted, so log Hastings =
    log q(x_site) - log q(x'_site) (with the log map's Jacobian) makes it exact (Metropolis
    within Gibbs). Unlike q's conditional (`FittedConditional`), a t around where the others
    put the latent, this proposes every region the warm-up visited as often as it did: a
    narrow mode a few scales from the bulk (the ramp's k1 just below the friction at which
    the collision changes) is proposed into, and left, many times a sweep, not once in tens."""
    site: int
    log: bool
    centres: tuple[float, ...]   # kernel centres, in log for a log site
    bandwidth: float
    bounds: tuple[float, float]
    weight: float = MARGINAL_WEIGHT
    every: int = 1
    name: str = "fitted_marginal"

    def check(self, n_latents: int) -> "FittedMarginal":
        """ValueError (one line) unless the fields fit together; self otherwise."""
        lo, hi = self.bounds
        if not 0 <= self.site < n_latents:
            raise ValueError(f"FittedMarginal: site {self.site} outside 0..{n_latents - 1}")
        if not (len(self.centres) and self.bandwidth > 0 and lo < hi and 0 <= self.weight <= 1):
            raise ValueError("FittedMarginal: needs centres, a positive bandwidth, low < high and a weight in [0, 1]")
        if self.log and not lo >= 0:
            raise ValueError("FittedMarginal: a log site's range must not reach below 0")
        return self

    def logq(self, v: float) -> float:
        lo, hi = self.bounds
        if not lo <= v <= hi:
            return -math.inf
        parts = [math.log1p(-self.weight) - math.log(hi - lo)] if self.weight < 1 else []
        if self.weight > 0 and (v > 0 or not self.log):
            y, jac = (math.log(v), -math.log(v)) if self.log else (v, 0.0)
            z = (y - np.asarray(self.centres, float)) / self.bandwidth
            log_k = float(np.logaddexp.reduce(-0.5 * z * z)) - math.log(len(self.centres))
            parts.append(math.log(self.weight) + log_k - math.log(self.bandwidth * math.sqrt(2 * math.pi)) + jac)
        return float(np.logaddexp.reduce(parts)) if parts else -math.inf

    def propose(self, rng: np.random.Generator, position) -> tuple[np.ndarray, float]:
        x = np.asarray(position, float).copy()
        if rng.uniform() < self.weight:
            y = self.centres[rng.integers(len(self.centres))] + self.bandwidth * rng.normal()
            v = math.exp(y) if self.log else y
        else:
            v = rng.uniform(*self.bounds)
        old = float(x[self.site])
        x[self.site] = v
        lq_new = self.logq(v)
        if not lq_new > -math.inf:   # (a kernel's draw outside the prior: refused by the kernel)
            return x, -math.inf
        return x, self.logq(old) - lq_new


KERNEL_CENTRES = 400      # the joint kernel move: at most this many of the warm-up draws as centres ...
KERNEL_WEIGHT = 0.95      # ... the rest of its mass uniform on the prior's box (defensive)


class FittedKernel(NamedTuple):
    """An independence move over the latents `sites` (the others unchanged) from a kernel
    density estimate of every chain's warm-up draws: with probability `weight` a multivariate
    Student-t (`df`) around one of `centres` picked uniformly, of the scale factor
    `chols[groups[i]]` for centre i, in q's transformed space (the log of the latents in
    `log_sites`), else uniform on the box `bounds` of those sites. Fixed once fitted, so log
    Hastings = log q(x) - log q(x') (with the log map's Jacobian) makes it exact. Its kernels
    have the shape of the chains' own spread (each chain's covariance, or theirs pooled), not
    of the spread between chains: where chains sit in separate modes, along a curved ridge, or
    a narrow mode lies beside the bulk, it proposes where the warm-up went, as often as it went
    there, and not into the empty space between."""
    sites: tuple[int, ...]
    log_sites: tuple[int, ...]
    centres: tuple               # rows, in q's space
    chols: tuple                 # lower-triangular scale factors, each rows as tuples
    groups: tuple[int, ...]      # centre i's scale factor: chols[groups[i]]
    bounds: tuple                # ((lo, hi), ...) of the sites
    df: float = FITTED_DF
    weight: float = KERNEL_WEIGHT
    every: int = 1
    name: str = "fitted_kernel"

    def check(self, n_latents: int) -> "FittedKernel":
        """ValueError (one line) unless the fields fit together; self otherwise."""
        d = len(self.sites)
        if not d or not all(0 <= i < n_latents for i in self.sites) or len(set(self.sites)) != d:
            raise ValueError(f"FittedKernel: sites {self.sites} outside 0..{n_latents - 1} or repeated")
        if (np.shape(np.asarray(self.centres, float))[1:] != (d,)
                or np.shape(np.asarray(self.chols, float))[1:] != (d, d)):
            raise ValueError(f"FittedKernel: centres and scales must be of {d} latents")
        if len(self.groups) != len(self.centres) or not all(
                isinstance(g, int) and 0 <= g < len(self.chols) for g in self.groups):
            raise ValueError("FittedKernel: every centre needs the index of its scale")
        if not (len(self.centres) and self.df > 0 and 0 <= self.weight <= 1 and len(self.bounds) == d):
            raise ValueError("FittedKernel: needs centres, a positive df, a weight in [0, 1] and a box")
        if not all(np.all(np.diag(np.asarray(c, float)) > 0) for c in self.chols):
            raise ValueError("FittedKernel: its scales' diagonals must be positive")
        return self

    def logq(self, v: Sequence[float]) -> float:
        """log q of the sites' values `v` (in the latents' own space); -inf outside the box."""
        v = np.asarray(v, float)
        box = np.asarray(self.bounds, float)
        if not np.all((box[:, 0] <= v) & (v <= box[:, 1])):
            return -math.inf
        parts = [math.log1p(-self.weight) - float(np.log(box[:, 1] - box[:, 0]).sum())] if self.weight < 1 else []
        logs = [k for k, i in enumerate(self.sites) if i in self.log_sites]
        if self.weight > 0 and all(v[k] > 0 for k in logs):
            y = v.copy()
            y[logs] = np.log(v[logs])
            d = len(self.sites)
            terms = []
            for inv, white, log_det in _kernel_arrays(self):   # z = L^-1 (y - c) = L^-1 y - L^-1 c
                z = inv @ y - white
                terms.append(-log_det - 0.5 * (self.df + d) * np.log1p(np.einsum("ij,ij->i", z, z) / self.df))
            t = np.concatenate(terms)
            top = float(t.max())
            log_k = (top + math.log(float(np.exp(t - top).sum())) - math.log(len(self.centres))
                     + math.lgamma((self.df + d) / 2) - math.lgamma(self.df / 2) - 0.5 * d * math.log(self.df * math.pi))
            parts.append(math.log(self.weight) + log_k - float(np.log(v[logs]).sum()))
        return float(np.logaddexp.reduce(parts)) if parts else -math.inf

    def propose(self, rng: np.random.Generator, position) -> tuple[np.ndarray, float]:
        def draw():
            i = int(rng.integers(len(self.centres)))
            return _t_draw(rng, self.centres[i], self.chols[self.groups[i]], self.df)

        return _propose_t_or_box(self, rng, position, draw)


def _t_draw(rng: np.random.Generator, centre, chol, df: float) -> np.ndarray:
    """A multivariate Student-t draw: `centre` + `chol` z / sqrt(chi2_df / df)."""
    chol = np.asarray(chol, float)
    return np.asarray(centre, float) + (chol @ rng.normal(size=len(chol))) / math.sqrt(rng.chisquare(df) / df)


def _propose_t_or_box(move, rng: np.random.Generator, position, draw) -> tuple[np.ndarray, float]:
    """The fitted independence moves' proposal of their `sites`: with probability `weight` the
    point `draw()` of q's transformed space (exp on the log sites), else uniform on the box; log
    Hastings = log q(old) - log q(new) (-inf for a draw outside the box: out of the prior)."""
    x = np.asarray(position, float).copy()
    old = x[list(move.sites)].copy()
    if rng.uniform() < move.weight:
        y = draw()
        new = np.array([math.exp(y[k]) if i in move.log_sites else y[k] for k, i in enumerate(move.sites)])
    else:
        box = np.asarray(move.bounds, float)
        new = rng.uniform(box[:, 0], box[:, 1])
    x[list(move.sites)] = new
    lq_new = move.logq(new)
    if not lq_new > -math.inf:
        return x, -math.inf
    return x, move.logq(old) - lq_new


def _in_q_space(draws: np.ndarray, sites: Sequence[int], log_sites: Sequence[int]) -> np.ndarray | None:
    """The `sites` columns of `draws` (N, D) in a fitted move's space: the log of the
    `log_sites`; None if one of those is at or below 0."""
    y = np.asarray(draws, float)[:, list(sites)].copy()
    for k, i in enumerate(sites):
        if i in log_sites:
            if np.any(y[:, k] <= 0):
                return None
            y[:, k] = np.log(y[:, k])
    return y


def _width_floor(bounds: np.ndarray, sites: Sequence[int], log_sites: Sequence[int]) -> np.ndarray:
    """A fitted move's covariance floor: a hundred-thousandth of each site's prior range (in
    log for the log sites), squared, on the diagonal."""
    span = np.array([math.log(bounds[i, 1] / bounds[i, 0]) if i in log_sites and bounds[i, 0] > 0
                     else bounds[i, 1] - bounds[i, 0] for i in sites])
    return np.diag((1e-5 * span) ** 2)


_KERNEL_ARRAYS: dict = {}   # id(FittedKernel) -> (the kernel, its arrays): logq is called twice a proposal


def _kernel_arrays(q: FittedKernel) -> list:
    """Per scale factor L of `q`: (L^-1, its centres whitened (L^-1 c as rows), log det L),
    computed once per kernel object (its tuples made arrays a thousand times a sweep cost more
    than the proposal's simulation saves)."""
    hit = _KERNEL_ARRAYS.get(id(q))
    if hit is not None and hit[0] is q:
        return hit[1]
    if len(_KERNEL_ARRAYS) >= 64:   # (a worker sees a new copy of the move in every task)
        _KERNEL_ARRAYS.clear()
    centres, groups = np.asarray(q.centres, float), np.asarray(q.groups)
    out = []
    for g, chol in enumerate(np.asarray(q.chols, float)):
        mine = groups == g
        if mine.any():
            inv = np.linalg.inv(chol)
            out.append((inv, centres[mine] @ inv.T, float(np.log(np.diag(chol)).sum())))
    _KERNEL_ARRAYS[id(q)] = (q, out)
    return out


def fit_kernel(chains: Sequence[np.ndarray], sites: Sequence[int], log_sites: Sequence[int], bounds: np.ndarray,
               local: bool = False) -> FittedKernel | None:
    """The `FittedKernel` of the chains' draws (`chains`: each chain's (n_i, D) warm-up draws):
    at most KERNEL_CENTRES of the pooled draws (an even thinning) as centres; the kernels'
    scale Scott's factor n^(-1/(d+4)) times the chains' covariance within a chain, pooled (with
    `local`, each centre's its own chain's), in q's transformed space, with a floor of a
    hundred-thousandth of each prior range's width; None with fewer than two chains of two
    draws (with `local`: a chain of no more draws than latents), any draw not finite, or not
    above 0 in a log site. (On the ramp demo
    the pooled scale converged in 172 and 156 sweeps on seeds 0 and 4, each chain's own in 410
    and 230: 37 warm-up draws a chain make a noisy covariance in five latents.)"""
    sites = tuple(int(i) for i in sites)
    log_sites = tuple(int(i) for i in log_sites if i in sites)
    bounds = np.asarray(bounds, float)
    d = len(sites)
    ys = []
    for c in chains:
        y = np.asarray(c, float)
        if y.ndim != 2 or len(y) < 2:
            continue
        if local and len(y) <= d:   # (too few for a chain's own covariance)
            return None
        y = _in_q_space(y, sites, log_sites)
        if y is None or not np.all(np.isfinite(y)):
            return None
        ys.append(y)
    if len(ys) < 2 or not d:
        return None
    floor = _width_floor(bounds, sites, log_sites)
    covs = [np.atleast_2d(np.cov(y.T)) for y in ys]
    if not local:
        covs = [sum(c * (len(y) - 1) for c, y in zip(covs, ys)) / sum(len(y) - 1 for y in ys)]
    pooled = np.concatenate(ys)
    owner = np.concatenate([np.full(len(y), g if local else 0) for g, y in enumerate(ys)])
    pick = np.linspace(0, len(pooled) - 1, min(len(pooled), KERNEL_CENTRES)).round().astype(int)
    h = len(pick) ** (-1.0 / (d + 4))
    try:
        chols = [np.linalg.cholesky(c + floor) * h for c in covs]
    except np.linalg.LinAlgError:
        return None
    if not all(np.all(np.isfinite(c)) for c in chols):
        return None
    return FittedKernel(sites, log_sites, _rows(pooled[pick]), tuple(_rows(c) for c in chols),
                        tuple(int(g) for g in owner[pick]), tuple((float(bounds[i, 0]), float(bounds[i, 1])) for i in sites))


def fit_marginal(values: np.ndarray, site: int, log: bool, bounds: Sequence[float]) -> FittedMarginal | None:
    """The `FittedMarginal` of one latent from its pooled warm-up draws `values`: at most
    MARGINAL_CENTRES of them (an even thinning) as centres, the bandwidth Silverman's rule
    (0.9 min(sd, IQR / 1.34) n^-1/5 in q's space; a floor of a hundred-thousandth of the
    prior range's); None for fewer than 10 draws or any not finite (or not above 0 in log)."""
    v = np.asarray(values, float).ravel()
    if len(v) < 10 or not np.all(np.isfinite(v)) or (log and np.any(v <= 0)):
        return None
    y = np.log(v) if log else v
    lo, hi = float(bounds[0]), float(bounds[1])
    span = (math.log(hi / lo) if log and lo > 0 else hi - lo)
    q75, q25 = np.percentile(y, [75, 25])
    spread = min(float(np.std(y)), float(q75 - q25) / 1.34) or float(np.std(y))
    h = max(0.9 * spread * len(y) ** -0.2, 1e-5 * span)
    centres = y[np.linspace(0, len(y) - 1, min(len(y), MARGINAL_CENTRES)).round().astype(int)]
    return FittedMarginal(int(site), bool(log), tuple(map(float, centres)), float(h), (lo, hi))


def conditionals_of(q: FittedIndependence) -> tuple[FittedConditional, ...]:
    """One `FittedConditional` per site of q (its t part, of scale S = chol chol')."""
    loc, chol = np.asarray(q.loc, float), np.asarray(q.chol, float)
    cov = chol @ chol.T
    sites = list(q.sites)
    out = []
    for k, site in enumerate(sites):
        rest = [j for j in range(len(sites)) if j != k]
        if rest:
            prec = np.linalg.inv(cov[np.ix_(rest, rest)])
            coef = cov[k, rest] @ prec
            var = float(cov[k, k] - coef @ cov[rest, k])
        else:
            prec, coef, var = np.zeros((0, 0)), np.zeros(0), float(cov[k, k])
        out.append(FittedConditional(site, site in q.log_sites, tuple(sites[j] for j in rest),
                                     tuple(sites[j] in q.log_sites for j in rest), float(loc[k]),
                                     tuple(float(loc[j]) for j in rest), tuple(map(float, coef)), max(var, 1e-300),
                                     _rows(prec), float(q.df)))
    return tuple(out)


def _chi2_quantile(p: float, dof: int) -> float:
    from scipy.stats import chi2

    return float(chi2.ppf(p, dof))


def _trim_consistency(p: float, dof: int) -> float:
    """The factor that makes the covariance of normal draws within their `p` ellipsoid that
    of all of them (the reweighted MCD's: p / P(chi2 with dof + 2 <= the p quantile))."""
    from scipy.stats import chi2

    return p / float(chi2.cdf(chi2.ppf(p, dof), dof + 2))


def fit_independence(draws: np.ndarray, sites: Sequence[int], log_sites: Sequence[int], bounds: np.ndarray,
                     inflate: float = FITTED_INFLATE) -> FittedIndependence | None:
    """The move's q fitted to `draws` (N, D: every chain's warm-up draws, pooled): the t's
    centre the draws' mean and its scale `inflate` times their covariance's Cholesky factor in
    the transformed space (a latent whose draws do not vary gets a floor of
    width: a hundred-thousandth of its prior's, for the factor only), both taken over the draws
    within the FITTED_TRIM_LEVEL ellipsoid of the fit before (FITTED_TRIM_ROUNDS times; the
    covariance scaled back by the normal's consistency factor), so a chain the warm-up left
    far from the others does not widen q (its region stays covered by the t's tails and the
    box); None with fewer draws than twice the sites or a non-finite fit."""
    draws = np.asarray(draws, float)
    sites = tuple(int(i) for i in sites)
    log_sites = tuple(int(i) for i in log_sites if i in sites)
    bounds = np.asarray(bounds, float)
    if len(sites) == 0 or len(draws) < 2 * len(sites):
        return None
    y = _in_q_space(draws, sites, log_sites)
    if y is None:
        return None
    floor = _width_floor(bounds, sites, log_sites)
    loc, cov = y.mean(axis=0), np.atleast_2d(np.cov(y.T)) + floor
    for _ in range(FITTED_TRIM_ROUNDS):   # without the draws of chains that the warm-up left far from the rest
        try:
            d2 = np.sum(np.linalg.solve(np.linalg.cholesky(cov), (y - loc).T) ** 2, axis=0)
        except np.linalg.LinAlgError:
            return None
        keep = d2 <= _chi2_quantile(FITTED_TRIM_LEVEL, len(sites))
        if keep.sum() < 2 * len(sites):
            break
        loc = y[keep].mean(axis=0)
        cov = np.atleast_2d(np.cov(y[keep].T)) * _trim_consistency(FITTED_TRIM_LEVEL, len(sites)) + floor
    try:
        chol = np.linalg.cholesky(cov) * inflate
    except np.linalg.LinAlgError:
        return None
    if not (np.all(np.isfinite(chol)) and np.all(np.isfinite(loc))):
        return None
    return FittedIndependence(sites, log_sites, tuple(map(float, loc)), _rows(chol),
                              tuple((float(bounds[i, 0]), float(bounds[i, 1])) for i in sites))


TARGET_ACCEPTANCE = 0.44   # warm-up adapts random-walk widths towards this (1-D optimum, Roberts & Rosenthal)


def adapt_rate(sweep_number: int) -> float:
    """The Robbins-Monro step of warm-up sweep `sweep_number` (1-based): diminishing."""
    return 1.0 / sweep_number ** 0.6


def adapt_proposal(proposal: Proposal, infos: Sequence[MHInfo], sweep_number: int, bounds: np.ndarray) -> Proposal:
    """Warm-up: each continuous latent's narrow half-width multiplied by exp(eta (a - 0.44)),
    a its proposal's acceptance in this sweep (broad sweeps leave widths alone). Kept between
    1e-6 and 1 times the prior's width. After warm-up the widths are frozen, so the kept draws
    come from one fixed, exact kernel."""
    if proposal.broad_every and sweep_number % proposal.broad_every == 0:
        return proposal
    n = len(bounds)
    w = list(proposal.narrow) if isinstance(proposal.narrow, (list, tuple, np.ndarray)) else [float(proposal.narrow)] * n
    eta = adapt_rate(sweep_number)
    for info in infos:
        j = info.site
        if j < 0 or j in proposal.integer_sites:
            continue
        span = float(bounds[j, 1] - bounds[j, 0])
        w[j] = float(min(span, max(1e-6 * span, w[j] * math.exp(eta * (float(info.accepted) - TARGET_ACCEPTANCE)))))
    return proposal._replace(narrow=tuple(w))


def sweep(rng: np.random.Generator, state: MHState, logdensity: LogDensity, bounds: np.ndarray,
          proposal: Proposal = Proposal(), early_rejection: bool = True,
          sites: Sequence[int] | None = None, *,
          independence: Independence | None = None, moves: Sequence = ()) -> tuple[MHState, list[MHInfo]]:
    """One sweep: each latent (or each of `sites`) proposed once, in order; then, if
    `independence` is given and this sweep's number is a multiple of its `every`, one
    independence move of all latents (its info's site -1); then each of `moves` whose `every`
    divides the sweep's number, in order (move k's info has site -(k + 2))."""
    number = state.sweep + 1
    infos = []
    for site in (range(len(state.position)) if sites is None else sites):
        state, info = step_site(rng, state, site, proposal.width(number, site), logdensity, bounds,
                                early_rejection, site in proposal.integer_sites)
        infos.append(info)
    if independence is not None and number % independence.every == 0:
        state, info = step_independence(rng, state, independence, logdensity, bounds, early_rejection)
        infos.append(info)
    for k, move in enumerate(moves):
        if number % move.every == 0:
            state, info = step_move(rng, state, move, logdensity, bounds, early_rejection, move_code(k))
            infos.append(info)
    return state._replace(sweep=number), infos


def move_code(k: int) -> int:
    """The `site` an info of joint move k (of a sweep's `moves`) is recorded under."""
    return -(k + 2)


def chain_rng(seed: int, chain: int) -> np.random.Generator:
    """The random stream of chain `chain` of a run seeded with `seed` (independent of workers)."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(chain,)))


def run_chain(seed: int, chain: int, init_position: Sequence[float], logdensity: LogDensity, bounds,
              n_sweeps: int, proposal: Proposal = Proposal(), early_rejection: bool = True, *,
              independence: Independence | None = None, moves: Sequence = (), warmup: int = 0):
    """A whole chain: returns (positions after each sweep (S, D), logdensities (S,), infos).
    During the first `warmup` sweeps the narrow widths (and moves' widths) adapt."""
    rng = chain_rng(seed, chain)
    bounds = np.asarray(bounds, float)
    state = init(init_position, logdensity)
    if independence is not None:
        independence.check(len(state.position))
    positions, values, infos = [], [], []
    for _ in range(n_sweeps):
        state, inf = sweep(rng, state, logdensity, bounds, proposal, early_rejection, independence=independence,
                           moves=moves)
        if state.sweep <= warmup:
            proposal, moves = adapt(proposal, moves, inf, state.sweep, bounds, state.position)
        positions.append(state.position.copy())
        values.append(state.logdensity)
        infos.extend(inf)
    return np.array(positions), np.array(values), infos


def adapt(proposal: Proposal, moves: Sequence, infos: Sequence[MHInfo], sweep_number: int,
          bounds: np.ndarray, position: np.ndarray | None = None) -> tuple[Proposal, tuple]:
    """One warm-up update of the single-site widths and of every move that can adapt (a move's
    `adapted(accepted, eta)`; a move that also learns from where the chain is has `observe`)."""
    proposal = adapt_proposal(proposal, infos, sweep_number, bounds)
    moves = list(moves)
    eta = adapt_rate(sweep_number)
    for info in infos:
        k = -info.site - 2
        if 0 <= k < len(moves) and hasattr(moves[k], "adapted"):
            moves[k] = moves[k].adapted(bool(info.accepted), eta)
    if position is not None:
        moves = [m.observe(position) if hasattr(m, "observe") else m for m in moves]
    return proposal, tuple(moves)


JOINT_TARGET_ACCEPTANCE = 0.25   # a joint random walk in a few dimensions (Roberts, Gelman & Gilks 1997: 0.234)
JOINT_FORGET = 0.95              # the covariance's memory in warm-up sweeps: about 1 / (1 - this)


class JointRW(NamedTuple):
    """A joint Gaussian random walk over `sites` with a covariance learned in warm-up (adaptive
    Metropolis, Haario et al. 2001), in a transformed space: the log of the latents in
    `log_sites` (positive ones whose scale matters, e.g. masses), the others as they are.
    y' = y + scale L z, z ~ N(0, I), symmetric in y; in the latents' own space the Jacobian
    gives log Hastings = sum over log sites of (y'_i - y_i). It follows correlated posteriors
    (the ramp's target friction against the mass ratio) that single-site moves cross slowly.
    During warm-up `observe` updates an exponentially weighted covariance of the chain's
    positions and `adapted` the scale towards acceptance 0.25; after warm-up both are frozen."""
    sites: tuple[int, ...]
    log_sites: tuple[int, ...]
    chol: tuple            # lower-triangular factor of the covariance, rows as tuples
    scale: float
    mean: tuple | None = None
    cov: tuple | None = None
    every: int = 1
    name: str = "joint_rw"

    @classmethod
    def initial(cls, sites: Sequence[int], log_sites: Sequence[int], sd: Sequence[float], **kw) -> "JointRW":
        """Start with independent components of SD `sd` (in the transformed space)."""
        c = np.diag(np.asarray(sd, float) ** 2)
        return cls(tuple(int(i) for i in sites), tuple(int(i) for i in log_sites), _rows(np.linalg.cholesky(c)),
                   2.38 / math.sqrt(len(sites)), None, _rows(c), **kw)

    def _y(self, x: np.ndarray) -> np.ndarray:
        return np.array([math.log(x[i]) if i in self.log_sites else float(x[i]) for i in self.sites])

    def propose(self, rng: np.random.Generator, position) -> tuple[np.ndarray, float]:
        x = np.asarray(position, float).copy()
        z = rng.normal(size=len(self.sites))
        if any(x[i] <= 0 for i in self.log_sites):
            return x, -math.inf
        step = self.scale * (np.asarray(self.chol, float) @ z)
        log_h = 0.0
        for k, i in enumerate(self.sites):
            if i in self.log_sites:
                x[i] = x[i] * math.exp(step[k])
                log_h += float(step[k])
            else:
                x[i] = x[i] + float(step[k])
        return x, log_h

    def adapted(self, accepted: bool, eta: float) -> "JointRW":
        s = self.scale * math.exp(eta * (float(accepted) - JOINT_TARGET_ACCEPTANCE))
        return self._replace(scale=float(min(10.0, max(1e-3, s))))

    def observe(self, position) -> "JointRW":
        x = np.asarray(position, float)
        if any(x[i] <= 0 for i in self.log_sites):
            return self
        y = self._y(x)
        if self.mean is None:
            return self._replace(mean=tuple(map(float, y)))
        m0 = np.asarray(self.mean, float)
        m1 = JOINT_FORGET * m0 + (1 - JOINT_FORGET) * y
        c = JOINT_FORGET * np.asarray(self.cov, float) + (1 - JOINT_FORGET) * np.outer(y - m0, y - m1)
        c = 0.5 * (c + c.T)
        jitter = 1e-12 + 1e-6 * float(np.trace(c)) / len(y)
        try:
            chol = np.linalg.cholesky(c + jitter * np.eye(len(y)))
        except np.linalg.LinAlgError:
            return self._replace(mean=tuple(map(float, m1)))
        return self._replace(mean=tuple(map(float, m1)), cov=_rows(c), chol=_rows(chol))


def _rows(a: np.ndarray) -> tuple:
    return tuple(tuple(float(v) for v in row) for row in np.asarray(a))
