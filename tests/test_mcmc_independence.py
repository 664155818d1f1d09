"""The independence Metropolis-Hastings move of galileo.mcmc (Independence, step_independence,
sweep(..., independence=q)) on a target with known marginals; pure numpy.

The target is a Dirichlet(2, 3, 4) density over (x1, x2) (x3 = 1 - x1 - x2): correlated, its
support a triangle inside the prior box [0, 1]^2 (so -inf is returned inside the bounds too),
with exact marginals Beta(2, 7) and Beta(3, 6). The independence proposals are deliberately
mismatched (a lognormal centred at 0.4 for x1, whose mean is 0.22; a normal at 0.6 for x2,
whose mean is 0.33 and which often proposes outside the box), so the Hastings factor
q(x) / q(x') matters: without it the chain targets p(x) q(x) instead, and the negative
control shows the KS test sees that.

As in test_mcmc.py, the chains are thinned to several integrated autocorrelation times (IAT)
before the KS test, and the sizes were picked by rerunning each test over many seeds.
"""
import math

import numpy as np
import pytest
from scipy import integrate, stats

from galileo.mcmc import (Independence, MHState, Proposal, chain_rng, init, run_chain, step_independence,
                          step_site, sweep)

SEED = 20240601
ALPHA = (2.0, 3.0, 4.0)
MARGINALS = [stats.beta(ALPHA[0], ALPHA[1] + ALPHA[2]), stats.beta(ALPHA[1], ALPHA[0] + ALPHA[2])]
BOX = np.array([[0.0, 1.0], [0.0, 1.0]])
START = [0.3, 0.3]


def dirichlet_terms(x):
    """The three terms (a_k - 1) log x_k of the unnormalised log density, each <= 0; None
    outside the triangle."""
    a, b = float(x[0]), float(x[1])
    c = 1.0 - a - b
    if not (a > 0.0 and b > 0.0 and c > 0.0):
        return None
    return [(ALPHA[0] - 1) * math.log(a), (ALPHA[1] - 1) * math.log(b), (ALPHA[2] - 1) * math.log(c)]


def dirichlet_logpdf(x, threshold=None):
    """Plain target: a float, no early stopping."""
    terms = dirichlet_terms(x)
    return -math.inf if terms is None else math.fsum(terms)


class EarlyStopDirichlet:
    """The same target summed term by term; with a threshold it stops as soon as the partial
    sum (an upper bound of the full value, as every term is <= 0) is below it and returns
    (partial sum, True)."""

    def __init__(self):
        self.stops = 0
        self.terms = 0

    def __call__(self, x, threshold=None):
        terms = dirichlet_terms(x)
        if terms is None:
            return -math.inf, False
        partial = []
        for t in terms:
            partial.append(t)
            self.terms += 1
            value = math.fsum(partial)
            if threshold is not None and value < threshold:
                self.stops += 1
                return value, True
        return math.fsum(terms), False


# the mismatched proposals: Q_IND (lognormal x normal) drives the independence-only chains;
# Q_MIX (normal x uniform on (0.1, 0.9)) is used with single-site moves, which reach the x2 < 0.1
# the uniform cannot propose (from there the move can never be accepted: q(x) = 0)
Q_IND = Independence(("lognormal", "normal"), (math.log(0.4), 0.6), (1.0, 0.35))
Q_MIX = Independence(("normal", "uniform"), (0.5, 0.1), (0.3, 0.9))


def independence_chain(seed, chain, n_steps, q, logdensity=dirichlet_logpdf, hastings=True, early_rejection=True):
    """(positions (n_steps, 2), infos) of a chain of independence moves only."""
    rng = chain_rng(seed, chain)
    state = init(START, logdensity)
    out, infos = np.empty((n_steps, 2)), []
    for k in range(n_steps):
        state, info = step_independence(rng, state, q, logdensity, BOX, early_rejection, hastings)
        out[k] = state.position
        infos.append(info)
    return out, infos


# -- independence moves alone ---------------------------------------------------------------------
# Q_IND accepts ~21% of its proposals; the IAT is ~10 steps on x1 and ~8 on x2 (ESS 7300 and 9600
# of 76 000). 8 chains x 15 000 steps (~1 s), burn-in 500, thinned every 60 steps: 8 x 242 = 1936
# draws per marginal. Over 300 seeds: 2 of the 600 p-values below 0.01 (35 below 0.05). The same
# chains without the Hastings factor fail, over 160 seeds, with p < 3e-9 on x1 and < 1e-23 on x2.
N_CHAINS_IND, STEPS_IND, BURN_IND, THIN_IND = 8, 15_000, 500, 60


def independence_draws(hastings):
    x = np.stack([independence_chain(SEED, c, STEPS_IND, Q_IND, hastings=hastings)[0]
                  for c in range(N_CHAINS_IND)])
    return x[:, BURN_IND::THIN_IND]


@pytest.fixture(scope="module")
def ind_draws():
    return independence_draws(hastings=True)


@pytest.mark.parametrize("i", [0, 1])
def test_independence_only_matches_exact_marginals(ind_draws, i):
    x = ind_draws[..., i].ravel()
    assert x.size == N_CHAINS_IND * math.ceil((STEPS_IND - BURN_IND) / THIN_IND)
    res = stats.kstest(x, MARGINALS[i].cdf)
    assert res.pvalue > 0.01, res
    assert x.mean() == pytest.approx(MARGINALS[i].mean(), abs=0.015)


def test_independence_only_keeps_the_support_and_correlation(ind_draws):
    x = ind_draws.reshape(-1, 2)
    assert np.all(x > 0) and np.all(x.sum(1) < 1)
    # Dirichlet: corr(x1, x2) = -sqrt(a1 a2 / ((a0 - a1)(a0 - a2))), a0 = 9
    a0 = sum(ALPHA)
    exact = -math.sqrt(ALPHA[0] * ALPHA[1] / ((a0 - ALPHA[0]) * (a0 - ALPHA[1])))
    r = np.corrcoef(x.T)[0, 1]
    assert abs(math.atanh(r) - math.atanh(exact)) < 4 / math.sqrt(len(x) - 3), (r, exact)


def test_negative_control_without_hastings_factor_fails():
    """Same chains, same seed, the q terms left out of the acceptance ratio: the draws follow
    p(x) q(x) and must fail the KS test above (so the passing test is not automatic)."""
    x = independence_draws(hastings=False)
    for i in range(2):
        assert stats.kstest(x[..., i].ravel(), MARGINALS[i].cdf).pvalue < 1e-3, i


# -- independence moves mixed with single-site moves -----------------------------------------------
# Each sweep: two single-site moves (U(-0.05, 0.05), U(-0.5, 0.5) every 20th sweep), then one
# Q_MIX move (17% accepted). IAT ~9 sweeps on x1, ~10 on x2. 6 chains x 14 000 sweeps (~2 s),
# burn-in 500, thinned every 60 sweeps: 6 x 225 = 1350 draws per marginal. Over 300 seeds: 8 of
# the 600 p-values below 0.01 (31 below 0.05). (Thinning every 50 sweeps gave 8 of 496 and ~7%
# below 0.05: a trace of leftover autocorrelation.)
N_CHAINS_MIX, SWEEPS_MIX, BURN_MIX, THIN_MIX = 6, 14_000, 500, 60


@pytest.fixture(scope="module")
def mixed_runs():
    return [run_chain(SEED, c, START, dirichlet_logpdf, BOX, SWEEPS_MIX, Proposal(), independence=Q_MIX)
            for c in range(N_CHAINS_MIX)]


@pytest.mark.parametrize("i", [0, 1])
def test_mixed_chain_matches_exact_marginals(mixed_runs, i):
    x = np.stack([r[0] for r in mixed_runs])[:, BURN_MIX::THIN_MIX, i].ravel()
    res = stats.kstest(x, MARGINALS[i].cdf)
    assert res.pvalue > 0.01, res


def test_mixed_chain_uses_the_independence_move(mixed_runs):
    infos = [i for r in mixed_runs for i in r[2]]
    assert len(infos) == N_CHAINS_MIX * SWEEPS_MIX * 3
    assert np.stack([r[0] for r in mixed_runs])[:, BURN_MIX::THIN_MIX, 0].size == N_CHAINS_MIX * 225
    joint = infos[2::3]
    assert all(i.site == -1 and math.isnan(i.width) for i in joint)
    assert [i.site for i in infos[:6]] == [0, 1, -1, 0, 1, -1]
    rate = np.mean([i.accepted for i in joint])
    assert 0.1 < rate < 0.3, rate
    # the moves are big jumps, unlike the single-site ones
    assert any(i.accepted and np.max(np.abs(i.proposal - START)) > 0.3 for i in joint)
    # x2 < 0.1 (below Q_MIX's support) is reached by the single-site moves (the marginal puts
    # ~4% there), and from there no independence move is accepted
    x = np.stack([r[0] for r in mixed_runs]).reshape(-1, 2)
    assert 0.01 < np.mean(x[:, 1] < 0.1) < 0.1


def test_no_independence_move_accepted_from_outside_q_support():
    """q(x) = 0 at the current x: the Hastings ratio is 0, even on a flat target."""
    flat = lambda x, threshold=None: 0.0  # noqa: E731
    state = MHState(np.array([0.5, 0.05]), 0.0, 0)  # x2 = 0.05 is outside Q_MIX's U(0.1, 0.9)
    rng = chain_rng(SEED, 0)
    infos = [step_independence(rng, state, Q_MIX, flat, BOX)[1] for _ in range(300)]
    assert not any(i.accepted for i in infos)
    # ... while from q's mode (x1 = 0.5) q(x) / q(x') >= 1: every in-bounds proposal is accepted
    state = MHState(np.array([0.5, 0.5]), 0.0, 0)
    infos = [step_independence(rng, state, Q_MIX, flat, BOX)[1] for _ in range(300)]
    inside = [np.all((i.proposal >= 0) & (i.proposal <= 1)) for i in infos]
    assert [i.accepted for i in infos] == inside and 0.8 < np.mean(inside) < 1


# -- the acceptance protocol and early rejection ---------------------------------------------------

def test_threshold_and_decision_follow_the_hastings_rule():
    """Replay the stream: x' ~ q, then log u; the target is asked with threshold
    L(x) + log u - (log q(x) - log q(x')) and the move is accepted iff L(x') >= threshold."""
    seen = []

    def target(x, threshold=None):
        seen.append(threshold)
        return dirichlet_logpdf(x)

    state = init(START, dirichlet_logpdf)
    rng, replay = chain_rng(SEED, 5), chain_rng(SEED, 5)
    checked = 0
    for _ in range(400):
        seen.clear()
        new, info = step_independence(rng, state, Q_IND, target, BOX)
        xp = Q_IND.sample(replay)
        log_u = math.log(replay.uniform())
        assert np.array_equal(xp, info.proposal) and info.site == -1 and math.isnan(info.width)
        if not (0 <= xp[0] <= 1 and 0 <= xp[1] <= 1):
            assert seen == [] and not info.accepted and info.logdensity == -math.inf
        else:
            lq = lambda v: sum(stats.lognorm(s=1.0, scale=0.4).logpdf(v[0]) if k == 0 else  # noqa: E731
                               stats.norm(0.6, 0.35).logpdf(v[1]) for k in range(2))
            expect = state.logdensity + log_u - (lq(state.position) - lq(xp))
            assert seen[0] == pytest.approx(expect, rel=1e-12, abs=1e-12)
            lp = dirichlet_logpdf(xp)
            assert info.accepted == (lp >= expect and lp > -math.inf)
            checked += 1
        assert np.array_equal(new.position, xp if info.accepted else state.position)
        state = new
    assert checked > 200


def test_early_rejection_is_bit_identical_for_the_independence_move():
    fast, plain = EarlyStopDirichlet(), EarlyStopDirichlet()
    pf, inf_f = independence_chain(SEED, 1, 3000, Q_IND, fast, early_rejection=True)
    pp, inf_p = independence_chain(SEED, 1, 3000, Q_IND, plain, early_rejection=False)
    assert np.array_equal(pf, pp)
    assert [i.accepted for i in inf_f] == [i.accepted for i in inf_p]
    assert all(np.array_equal(a.proposal, b.proposal) for a, b in zip(inf_f, inf_p))
    for a, b in zip(inf_f, inf_p):
        if a.early_stop:
            assert not a.accepted and not b.accepted and a.logdensity >= b.logdensity
        else:
            assert a.logdensity == b.logdensity or (math.isnan(a.logdensity) and math.isnan(b.logdensity))
    assert fast.stops > 300 and plain.stops == 0 and fast.terms < plain.terms
    # the plain float target gives the same chain too
    assert np.array_equal(independence_chain(SEED, 1, 3000, Q_IND)[0], pp)
    # and the chain moved
    assert 0.1 < np.mean([i.accepted for i in inf_p]) < 0.4


def test_early_rejection_is_bit_identical_in_mixed_chains():
    fast, plain = EarlyStopDirichlet(), EarlyStopDirichlet()
    a = run_chain(SEED, 2, START, fast, BOX, 1500, Proposal(narrow=0.2), True, independence=Q_MIX)
    b = run_chain(SEED, 2, START, plain, BOX, 1500, Proposal(narrow=0.2), False, independence=Q_MIX)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert [i.accepted for i in a[2]] == [i.accepted for i in b[2]]
    assert sum(i.early_stop for i in a[2] if i.site == -1) > 100 and plain.stops == 0


def test_a_lying_early_stop_changes_the_chain():
    """Control: a target that claims an early stop for proposals that would be accepted gives
    a different chain, so the identity above is not automatic."""
    def lying(x, threshold=None):
        value = dirichlet_logpdf(x)
        if threshold is not None and value > -math.inf and value >= threshold:
            return threshold - 1.0, True
        return value, False

    pf = independence_chain(SEED, 1, 300, Q_IND, lying, early_rejection=True)[0]
    pp = independence_chain(SEED, 1, 300, Q_IND, lying, early_rejection=False)[0]
    assert not np.array_equal(pf, pp)


def test_out_of_bounds_proposals_are_not_evaluated():
    calls = []

    def target(x, threshold=None):
        calls.append(x.copy())
        assert np.all((x >= 0) & (x <= 1)), "the target was evaluated outside the prior's support"
        return 0.0

    q = Independence(("normal", "normal"), (0.5, 0.5), (0.5, 0.5))  # P(inside the box) = 0.683^2 = 0.47
    _, infos = independence_chain(SEED, 0, 500, q, target)
    outside = [i for i in infos if not np.all((i.proposal >= 0) & (i.proposal <= 1))]
    assert 200 < len(outside) < 330
    assert len(calls) == 1 + len(infos) - len(outside)
    assert all(i.logdensity == -math.inf and not i.accepted and not i.early_stop for i in outside)


# -- the sweep schedule; sweeps without the move are unchanged ------------------------------------

def gaussian3(x, threshold=None):
    return -0.5 * float(((x - np.array([0.1, -0.2, 0.3])) / 0.3) @ ((x - np.array([0.1, -0.2, 0.3])) / 0.3))


def manual_chain(seed, chain, start, logdensity, bounds, n_sweeps):
    """The paper's schedule written out with step_site: widths 0.05, 0.5 every 20th sweep."""
    rng = chain_rng(seed, chain)
    bounds = np.asarray(bounds, float)
    state = MHState(np.asarray(start, float).copy(), logdensity(np.asarray(start, float)), 0)
    positions, infos = [], []
    for n in range(1, n_sweeps + 1):
        for site in range(len(start)):
            state, info = step_site(rng, state, site, 0.5 if n % 20 == 0 else 0.05, logdensity, bounds)
            infos.append(info)
        state = state._replace(sweep=n)
        positions.append(state.position.copy())
    return np.array(positions), infos


def test_sweeps_without_independence_are_unchanged():
    bounds = [[-1.0, 1.0]] * 3
    start = [0.5, -0.5, 0.0]
    truth, truth_infos = manual_chain(SEED, 4, start, gaussian3, bounds, 100)
    never = Independence(("normal",) * 3, (0.0,) * 3, (1.0,) * 3, every=1000)  # not due in 100 sweeps
    for kw in ({}, {"independence": None}, {"independence": never}):
        pos, _, infos = run_chain(SEED, 4, start, gaussian3, bounds, 100, **kw)
        assert np.array_equal(pos, truth), kw
        assert len(infos) == len(truth_infos)
        assert all(np.array_equal(a.proposal, b.proposal) and a.accepted == b.accepted and a.site == b.site
                   for a, b in zip(infos, truth_infos))
    # sweep itself, from one state
    state = MHState(np.array(start), gaussian3(np.array(start)), 0)
    s1, i1 = sweep(chain_rng(SEED, 4), state, gaussian3, np.array(bounds))
    s2, i2 = sweep(chain_rng(SEED, 4), state, gaussian3, np.array(bounds), independence=None)
    assert np.array_equal(s1.position, truth[0]) and np.array_equal(s2.position, truth[0])
    assert len(i1) == len(i2) == 3


def test_independence_every_kth_sweep_at_the_end():
    bounds = [[-1.0, 1.0]] * 3
    start = [0.5, -0.5, 0.0]
    q = Independence(("normal", "uniform", "normal"), (0.0, -0.8, 0.3), (0.5, 0.6, 0.4), every=3)
    pos, _, infos = run_chain(SEED, 4, start, gaussian3, bounds, 30, independence=q)
    assert len(infos) == 3 * 30 + 10
    k, per_sweep = 0, []
    for n in range(1, 31):
        m = 4 if n % 3 == 0 else 3
        per_sweep.append([i.site for i in infos[k:k + m]])
        k += m
    assert all(s == ([0, 1, 2, -1] if n % 3 == 0 else [0, 1, 2]) for n, s in zip(range(1, 31), per_sweep))
    # before the first independence move the chain is the plain one
    truth, _ = manual_chain(SEED, 4, start, gaussian3, bounds, 30)
    assert np.array_equal(pos[:2], truth[:2]) and not np.array_equal(pos, truth)
    # the sweep counter counts sweeps, not moves
    state = MHState(np.array(start), gaussian3(np.array(start)), 5)
    s, inf = sweep(chain_rng(0, 0), state, gaussian3, np.array(bounds), independence=q)
    assert s.sweep == 6 and [i.site for i in inf] == [0, 1, 2, -1]
    s, inf = sweep(chain_rng(0, 0), s, gaussian3, np.array(bounds), sites=[], independence=q)
    assert s.sweep == 7 and inf == []


# -- the proposal distribution itself -------------------------------------------------------------

@pytest.mark.parametrize("spec, match", [
    ((("normal",), (0.0, 1.0), (1.0,)), "length"),
    ((("normal", "normal"), (0.0, 1.0), (1.0,)), "length"),
    (((), (), ()), "no components"),
    ((("gamma",), (0.0,), (1.0,)), "unknown kind"),
    ((("normal",), (math.nan,), (1.0,)), "finite"),
    ((("lognormal",), (0.0,), (math.inf,)), "finite"),
    ((("normal",), (0.0,), (0.0,)), "scale > 0"),
    ((("lognormal",), (0.0,), (-1.0,)), "scale > 0"),
    ((("uniform",), (1.0,), (1.0,)), "low < high"),
    ((("uniform",), (2.0,), (1.0,)), "low < high"),
    ((("normal",), ("a",), (1.0,)), "numbers"),
    ((("normal",), (0.0,), (1.0,), 0), "every"),
    ((("normal",), (0.0,), (1.0,), 1.5), "every"),
])
def test_check_rejects_bad_specs(spec, match):
    with pytest.raises(ValueError, match=match) as e:
        Independence(*spec).check()
    assert "\n" not in str(e.value)


def test_check_accepts_good_specs_and_counts_latents():
    q = Independence(("normal", "lognormal", "uniform"), (0.0, -1.0, 2.0), (1.0, 0.5, 3.0), every=4)
    assert q.check() is q and q.check(3) is q
    with pytest.raises(ValueError, match="3 components for 2 latents"):
        q.check(2)
    # the kernel checks too, before using the spec
    with pytest.raises(ValueError):
        run_chain(SEED, 0, [0.1, 0.2], dirichlet_logpdf, BOX, 3, independence=q)
    with pytest.raises(ValueError):
        step_independence(chain_rng(0, 0), init(START, dirichlet_logpdf), Independence(("normal",) * 2, (0, 0), (1, -1)),
                          dirichlet_logpdf, BOX)


ONE_D = {
    "normal": (Independence(("normal",), (0.7,), (0.4,)), stats.norm(0.7, 0.4), (-math.inf, math.inf)),
    "lognormal": (Independence(("lognormal",), (0.3,), (0.7,)), stats.lognorm(s=0.7, scale=math.exp(0.3)),
                  (0.0, math.inf)),
    "uniform": (Independence(("uniform",), (-0.5,), (2.0,)), stats.uniform(-0.5, 2.5), (-0.5, 2.0)),
}


@pytest.mark.parametrize("kind", list(ONE_D))
def test_logpdf_integrates_to_one(kind):
    q, _, (lo, hi) = ONE_D[kind]
    total, err = integrate.quad(lambda v: math.exp(q.logpdf([v])), lo, hi, limit=200)
    assert total == pytest.approx(1.0, abs=1e-7), (total, err)
    # the mean too (the lognormal's would be off without the Jacobian's -log x)
    mean, _ = integrate.quad(lambda v: v * math.exp(q.logpdf([v])), lo, hi, limit=200)
    assert mean == pytest.approx(ONE_D[kind][1].mean(), rel=1e-6)


@pytest.mark.parametrize("kind", list(ONE_D))
def test_logpdf_and_sample_match_scipy(kind):
    q, ref, (lo, hi) = ONE_D[kind]
    grid = np.linspace(max(lo, -3.0) + 1e-3, min(hi, 8.0) - 1e-3, 57)
    assert np.allclose([q.logpdf([v]) for v in grid], ref.logpdf(grid), rtol=1e-12, atol=1e-12)
    if kind != "normal":
        assert q.logpdf([lo - 0.1]) == -math.inf
        assert q.logpdf([lo]) == (-math.inf if kind == "lognormal" else -math.log(2.5))
    if kind == "uniform":
        assert q.logpdf([hi + 1e-9]) == -math.inf
    rng = np.random.default_rng(SEED)
    draws = np.array([q.sample(rng)[0] for _ in range(4000)])
    assert stats.kstest(draws, ref.cdf).pvalue > 0.01


def test_logpdf_of_a_product_is_the_sum_and_sampling_is_reproducible():
    q = Independence(("normal", "lognormal", "uniform"), (0.0, -1.0, 2.0), (1.0, 0.5, 3.0))
    x = [0.3, 0.6, 2.5]
    parts = [Independence((k,), (a,), (b,)).logpdf([v]) for k, a, b, v in zip(q.kinds, q.loc, q.scale, x)]
    assert q.logpdf(x) == pytest.approx(sum(parts), rel=1e-14)
    assert q.logpdf([0.3, -0.6, 2.5]) == -math.inf and q.logpdf([0.3, 0.6, 3.5]) == -math.inf
    # exactly one random number per component: a draw leaves the stream where 3 draws would
    a, b = chain_rng(1, 0), chain_rng(1, 0)
    s = q.sample(a)
    assert s.shape == (3,) and np.array_equal(s, q.sample(chain_rng(1, 0)))
    b.normal(), b.normal(), b.uniform()
    assert a.uniform() == b.uniform()
    # a 2-D product integrates to one as well
    q2 = Independence(("lognormal", "uniform"), (0.0, 0.0), (0.5, 1.5))
    total, _ = integrate.dblquad(lambda y, v: math.exp(q2.logpdf([v, y])), 0.0, 30.0, 0.0, 1.5)
    assert total == pytest.approx(1.0, abs=1e-6)
