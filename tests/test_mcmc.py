"""The single-site MH kernel (galileo.mcmc) on targets with known posteriors; pure numpy.

The samplers' draws are compared with the exact distributions by Kolmogorov-Smirnov tests.
KS assumes independent draws; MH draws are autocorrelated, which makes the KS statistic
larger than it is for independent draws (too small p-values), so the chains are thinned to
a lag of several integrated autocorrelation times (IAT) first. The numbers below were
chosen by measuring the IAT and by rerunning each test over many seeds (the rejection
rate at p < 0.01 has to stay near 1%, i.e. the thinned draws behave like independent ones).
"""
import math

import numpy as np
import pytest
from arviz_stats.base import array_stats
from scipy import integrate, stats

from galileo.mcmc import MHState, Proposal, chain_rng, run_chain, sweep

SEED = 20240601


def beta_logpdf(a: float, b: float):
    """Unnormalised log density of Beta(a, b) as a kernel target (float in, float out)."""
    def logdensity(x, threshold=None):
        v = x[0]
        if not 0.0 < v < 1.0:
            return -math.inf
        return (a - 1) * math.log(v) + (b - 1) * math.log1p(-v)
    return logdensity


def sample_chains(logdensity, bounds, n_chains, n_sweeps, seed, proposal=Proposal(), starts=None):
    """(chains, sweeps, latents) positions after every sweep."""
    bounds = np.asarray(bounds, float)
    if starts is None:  # overdispersed starts drawn uniformly over the box
        rng = np.random.default_rng([seed, 99])
        starts = bounds[:, 0] + (bounds[:, 1] - bounds[:, 0]) * rng.uniform(0.05, 0.95, (n_chains, len(bounds)))
    return np.stack([run_chain(seed, c, starts[c], logdensity, bounds, n_sweeps, proposal)[0]
                     for c in range(n_chains)])


# -- 1-D: Beta(2, 5) on [0, 1] with the paper's proposal ----------------------------------------
# With the default proposal (U(-0.05, 0.05), every 20th sweep U(-0.5, 0.5)) the chain on
# Beta(2, 5) (sd 0.16) has an IAT of ~48 sweeps (ESS 1500 of 72000 draws). 8 chains x
# 40 000 sweeps (~2 s), the first 2 000 dropped as burn-in, thinned every 200 sweeps (> 4 IAT,
# lag-200 autocorrelation ~ e^-8) leave 8 x 190 = 1520 nearly independent draws: enough
# for the KS test to see a wrong distribution (the negative control below fails with
# p ~ 1e-200) while the right one passes at the nominal rate (over 100 seeds: 1 p-value below
# 0.01, 7 below 0.05).
N_CHAINS_1D, SWEEPS_1D, BURN_1D, THIN_1D = 8, 40_000, 2_000, 200


@pytest.fixture(scope="module")
def beta25_draws():
    pos = sample_chains(beta_logpdf(2, 5), [[0.0, 1.0]], N_CHAINS_1D, SWEEPS_1D, SEED)
    return pos[:, BURN_1D::THIN_1D, 0]


def test_beta_1d_matches_exact_cdf(beta25_draws):
    x = beta25_draws.ravel()
    assert x.size == N_CHAINS_1D * ((SWEEPS_1D - BURN_1D) // THIN_1D)
    assert x.min() > 0 and x.max() < 1
    res = stats.kstest(x, stats.beta(2, 5).cdf)
    assert res.pvalue > 0.01, res
    # and the moments, as a second look
    assert x.mean() == pytest.approx(2 / 7, abs=0.015)
    assert x.std() == pytest.approx(math.sqrt(10 / (49 * 8)), abs=0.015)


def test_ks_negative_control_wrong_target_fails():
    """Draws of the same sampler on Beta(5, 2) must fail the KS test against Beta(2, 5):
    the test above can fail."""
    pos = sample_chains(beta_logpdf(5, 2), [[0.0, 1.0]], N_CHAINS_1D, SWEEPS_1D // 4, SEED)
    x = pos[:, BURN_1D::THIN_1D, 0].ravel()
    assert stats.kstest(x, stats.beta(2, 5).cdf).pvalue < 1e-6
    # ... while they pass against their own target (the control is not just "any sample fails")
    assert stats.kstest(x, stats.beta(5, 2).cdf).pvalue > 0.01


# -- 2-D: a correlated bivariate normal truncated to the unit square ---------------------------
MU = np.array([0.3, 0.55])
SD = np.array([0.25, 0.2])
RHO = 0.6
_PREC = np.linalg.inv(np.array([[SD[0] ** 2, RHO * SD[0] * SD[1]], [RHO * SD[0] * SD[1], SD[1] ** 2]]))
BOX = [[0.0, 1.0], [0.0, 1.0]]


def trunc_bvn_logpdf(x, threshold=None):
    if not (0.0 <= x[0] <= 1.0 and 0.0 <= x[1] <= 1.0):
        return -math.inf
    d = x - MU
    return -0.5 * float(d @ _PREC @ d)


def exact_marginal(i: int):
    """(cdf, mean) of latent i's marginal, by quadrature of the conditional's mass in the box:
    p(x_i) ~ N(x_i; mu_i, sd_i) * P(0 <= x_j <= 1 | x_i)."""
    j = 1 - i
    g = np.linspace(0.0, 1.0, 4001)
    mc = MU[j] + RHO * SD[j] / SD[i] * (g - MU[i])
    sc = SD[j] * math.sqrt(1 - RHO ** 2)
    dens = stats.norm.pdf(g, MU[i], SD[i]) * (stats.norm.cdf((1 - mc) / sc) - stats.norm.cdf(-mc / sc))
    cum = integrate.cumulative_trapezoid(dens, g, initial=0.0)
    z = cum[-1]
    mean = integrate.trapezoid(g * dens, g) / z
    return (lambda x: np.interp(x, g, cum / z)), mean


# Per-site proposal widths (0.35, 0.3 ~ 2 conditional sds; broad 0.5 every 20th sweep) exercise
# the sequence form of Proposal; the IAT is ~9 sweeps on both latents (ESS ~7400 of 66 000).
# 6 chains x 12 000 sweeps (~1.5 s), burn-in 1 000, thinned every 40 sweeps (> 4 IAT):
# 6 x 275 = 1650 draws per marginal. Over 100 seeds: 3 of the 200 marginal KS p-values below
# 0.01 (10 below 0.05), and the mean's error never above 3.1 MCSE (the test allows 4).
N_CHAINS_2D, SWEEPS_2D, BURN_2D, THIN_2D = 6, 12_000, 1_000, 40
PROPOSAL_2D = Proposal(narrow=(0.35, 0.3), broad=0.5)


@pytest.fixture(scope="module")
def bvn_chains():
    return sample_chains(trunc_bvn_logpdf, BOX, N_CHAINS_2D, SWEEPS_2D, SEED, PROPOSAL_2D)


@pytest.mark.parametrize("i", [0, 1])
def test_truncated_bvn_marginals_match(bvn_chains, i):
    cdf, _ = exact_marginal(i)
    x = bvn_chains[:, BURN_2D::THIN_2D, i].ravel()
    res = stats.kstest(x, cdf)
    assert res.pvalue > 0.01, res


@pytest.mark.parametrize("i", [0, 1])
def test_truncated_bvn_mean_within_mc_error(bvn_chains, i):
    _, mean = exact_marginal(i)
    kept = bvn_chains[:, BURN_2D:, i]                        # (chains, draws), unthinned
    ess = float(array_stats.ess(kept, chain_axis=0, draw_axis=1))
    assert 500 < ess < kept.size                              # the chains do mix, and draws are correlated
    mcse = kept.std(ddof=1) / math.sqrt(ess)
    assert abs(kept.mean() - mean) < 4 * mcse, (kept.mean(), mean, mcse, ess)
    # the mean is not trivially close: the truncation moved it away from MU by several MCSE
    assert abs(mean - MU[i]) > 4 * mcse


def test_truncated_bvn_correlation_is_kept(bvn_chains):
    """Single-site updates must still reproduce the dependence between the latents."""
    x = bvn_chains[:, BURN_2D::THIN_2D].reshape(-1, 2)
    g = np.linspace(0, 1, 801)
    X, Y = np.meshgrid(g, g, indexing="ij")
    d = np.stack([X - MU[0], Y - MU[1]], -1)
    p = np.exp(-0.5 * np.einsum("...i,ij,...j->...", d, _PREC, d))
    z = integrate.trapezoid(integrate.trapezoid(p, g, axis=1), g)
    m = [integrate.trapezoid(integrate.trapezoid(p * v, g, axis=1), g) / z for v in (X, Y)]
    cov = integrate.trapezoid(integrate.trapezoid(p * (X - m[0]) * (Y - m[1]), g, axis=1), g) / z
    sx = math.sqrt(integrate.trapezoid(integrate.trapezoid(p * (X - m[0]) ** 2, g, axis=1), g) / z)
    sy = math.sqrt(integrate.trapezoid(integrate.trapezoid(p * (Y - m[1]) ** 2, g, axis=1), g) / z)
    exact = cov / (sx * sy)
    r = np.corrcoef(x.T)[0, 1]
    assert 0.3 < exact < RHO
    # Fisher z: sd of atanh(r) ~ 1/sqrt(n - 3)
    assert abs(math.atanh(r) - math.atanh(exact)) < 4 / math.sqrt(len(x) - 3), (r, exact)


# -- proposal widths and the prior's support -----------------------------------------------------

def test_proposal_widths_default():
    p = Proposal()
    for n in range(1, 101):
        for site in range(4):
            assert p.width(n, site) == (0.5 if n % 20 == 0 else 0.05), (n, site)


def test_proposal_widths_per_site():
    p = Proposal(narrow=(0.1, 0.2), broad=[1.0, 2.0], broad_every=3)
    assert [p.width(n, 0) for n in range(1, 7)] == [0.1, 0.1, 1.0, 0.1, 0.1, 1.0]
    assert [p.width(n, 1) for n in range(1, 7)] == [0.2, 0.2, 2.0, 0.2, 0.2, 2.0]


def test_sweeps_use_the_scheduled_widths():
    """The kernel draws each proposal from U(-w, w) with w from the schedule (sweeps are 1-based)."""
    target = lambda x, threshold=None: -0.5 * float(x @ x)  # noqa: E731
    pos, _, infos = run_chain(SEED, 0, [0.0, 0.0], target, [[-5, 5], [-5, 5]], 60)
    assert len(pos) == 60 and len(infos) == 120
    widths = np.array([i.width for i in infos]).reshape(60, 2)
    expect = np.where((np.arange(1, 61) % 20 == 0)[:, None], 0.5, 0.05) * np.ones((1, 2))
    assert np.array_equal(widths, expect)
    # each proposal moves only its own site, by at most its width
    prev = np.zeros(2)
    broad_steps = []
    for k, info in enumerate(infos):
        moved = info.proposal - prev
        other = 1 - info.site
        assert info.site == k % 2 and moved[other] == 0 and abs(moved[info.site]) <= info.width
        if info.width == 0.5:
            broad_steps.append(abs(moved[info.site]))
        if info.accepted:
            prev = info.proposal
    assert np.array_equal(prev, pos[-1])
    assert max(broad_steps) > 0.05  # the broad sweeps really do propose further than narrow ones could


def test_out_of_bounds_proposal_is_rejected_without_evaluating():
    calls = []

    def target(x, threshold=None):
        calls.append(x.copy())
        assert 0.0 <= x[0] <= 1.0, "the target was evaluated outside the prior's support"
        return 0.0  # flat: every in-bounds proposal is accepted

    # a broad proposal on a flat target: the chain is uniform on [0, 1] and a quarter of the
    # U(-0.5, 0.5) proposals land outside (400 proposals: mean 100, sd ~ 10; +-4 sd)
    pos, _, infos = run_chain(SEED, 0, [0.97], target, [[0.0, 1.0]], 400, Proposal(narrow=0.5))
    outside = [i for i in infos if not 0.0 <= i.proposal[0] <= 1.0]
    inside = [i for i in infos if 0.0 <= i.proposal[0] <= 1.0]
    assert 60 < len(outside) < 140
    assert len(calls) == 1 + len(inside)  # init + every in-bounds proposal, no more
    assert all(i.logdensity == -math.inf and not i.accepted and not i.early_stop for i in outside)
    assert all(i.accepted for i in inside)
    assert np.all((pos >= 0) & (pos <= 1))


def test_minus_inf_inside_the_bounds_is_rejected():
    target = lambda x, threshold=None: -math.inf if x[0] > 0.5 else 0.0  # noqa: E731
    pos, _, infos = run_chain(SEED, 0, [0.4], target, [[0.0, 1.0]], 300, Proposal(narrow=0.2))
    assert pos.max() <= 0.5
    assert any(i.proposal[0] > 0.5 for i in infos)


# -- early rejection is exact --------------------------------------------------------------------

class SummedTarget:
    """Log density = sum of N terms <= 0 (a Gaussian split into pieces). With a threshold it
    stops once the partial sum falls below it and returns (partial sum, True): the partial
    sum is an upper bound of the full value, as with the per-frame terms of the likelihood."""

    def __init__(self, n_terms=40, dim=3, seed=1):
        rng = np.random.default_rng(seed)
        self.centres = rng.normal(0.0, 0.3, (n_terms, dim))
        # weights falling off along the sum (the first terms say most), summing to 1
        w = 0.85 ** np.arange(n_terms)
        self.weights = w / w.sum()
        self.terms = 0
        self.stops = 0

    def __call__(self, x, threshold=None):
        total = 0.0
        for w, c in zip(self.weights, self.centres):
            d = x - c
            total += -0.5 * w * float(d @ d) / 0.05 ** 2
            self.terms += 1
            if threshold is not None and total < threshold:
                self.stops += 1
                return total, True
        return total, False


def test_early_rejection_is_bit_identical():
    bounds = [[-1.0, 1.0]] * 3
    fast, plain = SummedTarget(), SummedTarget()
    # proposals of width 0.2 on a target of sd 0.05: many are clearly bad and stop early
    prop = Proposal(narrow=0.2)
    pf, vf, inf_f = run_chain(SEED, 3, [0.5, -0.5, 0.2], fast, bounds, 300, prop, early_rejection=True)
    pp, vp, inf_p = run_chain(SEED, 3, [0.5, -0.5, 0.2], plain, bounds, 300, prop, early_rejection=False)
    assert np.array_equal(pf, pp) and np.array_equal(vf, vp)  # bit for bit, not approx
    assert [i.accepted for i in inf_f] == [i.accepted for i in inf_p]
    assert all(np.array_equal(a.proposal, b.proposal) for a, b in zip(inf_f, inf_p))
    # the full values of proposals evaluated in full agree; stopped ones report a bound below
    for a, b in zip(inf_f, inf_p):
        if a.early_stop:
            assert not a.accepted and a.logdensity >= b.logdensity and not b.accepted
        else:
            assert a.logdensity == b.logdensity
    # and the speed-up happened: stops, fewer terms; the plain path never stops
    n_stops = sum(i.early_stop for i in inf_f)
    assert n_stops == fast.stops > 300 and plain.stops == 0 and not any(i.early_stop for i in inf_p)
    assert fast.terms < 0.8 * plain.terms
    # the chain moved (the test would be vacuous on a stuck chain)
    assert 0.2 < np.mean([i.accepted for i in inf_p]) < 0.95


def test_early_rejection_with_a_lying_target_is_detected():
    """Control: a target that stops early without a valid bound (it returns the threshold
    + 1 as "partial sum", i.e. above the threshold) is still treated as a rejection, so
    chains differ from the plain path: the identity above is not automatic."""
    class Lying(SummedTarget):
        def __call__(self, x, threshold=None):
            value, _ = super().__call__(x)
            if threshold is not None and value > threshold - 2.0:
                return threshold + 1.0, True  # "stopped" although the proposal would be accepted
            return value, False

    bounds = [[-1.0, 1.0]] * 3
    pf = run_chain(SEED, 3, [0.5, -0.5, 0.2], Lying(), bounds, 100, early_rejection=True)[0]
    pp = run_chain(SEED, 3, [0.5, -0.5, 0.2], Lying(), bounds, 100, early_rejection=False)[0]
    assert not np.array_equal(pf, pp)


# -- reproducibility -----------------------------------------------------------------------------

def test_same_seed_same_chain_and_chain_index_picks_the_stream():
    target = SummedTarget()
    bounds = [[-1.0, 1.0]] * 3
    a = run_chain(7, 0, [0.0, 0.0, 0.0], target, bounds, 50)
    b = run_chain(7, 0, [0.0, 0.0, 0.0], target, bounds, 50)
    c = run_chain(7, 1, [0.0, 0.0, 0.0], target, bounds, 50)
    d = run_chain(8, 0, [0.0, 0.0, 0.0], target, bounds, 50)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert [i.accepted for i in a[2]] == [i.accepted for i in b[2]]
    assert not np.array_equal(a[0], c[0]) and not np.array_equal(a[0], d[0])
    # the streams themselves: reproducible from (seed, chain) and distinct across chains
    assert np.array_equal(chain_rng(7, 0).random(5), chain_rng(7, 0).random(5))
    assert not np.array_equal(chain_rng(7, 0).random(5), chain_rng(7, 1).random(5))


def test_sweep_is_pure_and_counts_sweeps():
    target = SummedTarget()
    bounds = np.array([[-1.0, 1.0]] * 3)
    state = MHState(np.zeros(3), target(np.zeros(3))[0], 19)
    s1, infos1 = sweep(chain_rng(0, 0), state, target, bounds)
    s2, infos2 = sweep(chain_rng(0, 0), state, target, bounds)
    assert s1.sweep == s2.sweep == 20 and np.array_equal(s1.position, s2.position)
    assert np.array_equal(state.position, np.zeros(3))  # the input state is not modified
    assert [i.width for i in infos1] == [0.5] * 3  # sweep 20 is a broad one
    _, infos3 = sweep(chain_rng(0, 0), state, target, bounds, sites=[2])
    assert [i.site for i in infos3] == [2]


def test_an_integer_site_moves_by_whole_steps():
    """An integer latent's proposal is +-w with w a whole number >= 1, whatever width it is
    given (0.05 would leave the integers); others keep their widths."""
    from galileo.mcmc import Proposal

    p = Proposal(0.05, 0.5, 20, integer_sites=(1,))
    assert p.width(1, 0) == 0.05 and p.width(1, 1) == 1.0 and p.width(20, 1) == 1.0
    assert Proposal((0.05, 3.0), 0.5, 20, (1,)).width(1, 1) == 3.0
