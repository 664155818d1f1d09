"""The step-by-step likelihood scaffold (`galileo.framelik`) on a toy world whose motion is
known in closed form, no Bullet: a point mass slides along x at u m/s on ice until it is
first seen past the edge of a rough patch (x >= PATCH_M: the run branches there), then
decelerates at mu g (Coulomb friction) until it stops. A tick is a quarter of a video
frame; frame f is tick start + f * SPF (the splash's alignment); the tracked velocity is
observed with Gaussian noise of sigma. Latents: u_mps, mu (the simulation; the run up to the
patch depends on u alone), start_tick and log10_sigma_mps (the alignment and the noise: no
physics)."""
import math
import threading

import numpy as np
import pytest

from galileo.errors import GalileoError
from galileo.framelik import FrameLikelihood, Kept, RestRule, Run
from galileo.sim.bullet import client_lock

G_MPS2 = 9.81
PATCH_M = 0.5
FPS = 10.0
SPF = 4                      # ticks per frame
DT_S = 1.0 / (FPS * SPF)
N_FRAMES = 24
UNSEEN = (2, 9, 15)          # frames where the mass was not seen
TRUTH = {"u_mps": 2.0, "mu": 0.3, "start_tick": 3.0, "log10_sigma_mps": math.log10(0.02)}
NAMES = tuple(TRUTH)


def branch_tick(u: float) -> int:
    """The first tick at which the mass, sliding on ice, is past the patch's edge."""
    return next(k for k in range(10 ** 6) if u * (k * DT_S) >= PATCH_M)


def newton(values: dict, ticks) -> tuple[np.ndarray, np.ndarray]:
    """Position and velocity (m, m/s) at the given ticks, in closed form; before tick 0 the
    mass is held at rest at x = 0."""
    u, a = values["u_mps"], values["mu"] * G_MPS2
    kb = branch_tick(u)
    x_b = u * (kb * DT_S)
    t = np.asarray(ticks, float) * DT_S - kb * DT_S
    t_stop = u / a
    on_ice = np.asarray(ticks) <= kb
    ts = np.clip(t, 0.0, t_stop)
    x = np.where(on_ice, u * np.asarray(ticks, float) * DT_S, x_b + u * ts - 0.5 * a * ts ** 2)
    v = np.where(on_ice, u, np.maximum(u - a * ts, 0.0))
    held = np.asarray(ticks) < 0
    return np.where(held, 0.0, x), np.where(held, 0.0, v)


def observed(values: dict = TRUTH) -> tuple[np.ndarray, np.ndarray]:
    """Exact tracked velocities at the truth, and which frames were seen."""
    ticks = int(values["start_tick"]) + np.arange(N_FRAMES) * SPF
    _, v = newton(values, ticks)
    seen = np.ones(N_FRAMES, bool)
    seen[list(UNSEEN)] = False
    return np.where(seen, v, np.nan), seen


class _Noise:
    def __init__(self, sigma: float, n_seen: int):
        self.sigma = sigma
        self.log_norm = -n_seen * math.log(sigma * math.sqrt(2 * math.pi))
        self.half_prec = -0.5 / sigma ** 2


class _Run(Run):
    """The slide, a tick at a time: on ice (exact: x = u t) or, from a snapshot, with friction
    (exact for constant deceleration, and where the mass stops within a tick)."""

    def __init__(self, lik, u: float, a: float | None, snapshot=None):
        self.lik, self.u, self.a = lik, u, a
        self.x, self.v = (0.0, u) if snapshot is None else snapshot
        self.first = True

    def tick(self, k: int) -> tuple:
        if self.lik.probe_lock:   # can another thread take the Bullet lock now?
            got = []

            def probe():
                free = client_lock.acquire(blocking=False)
                if free:
                    client_lock.release()
                got.append(free)

            t = threading.Thread(target=probe)
            t.start()
            t.join(10)
            self.lik.lock_seen_free.append(got[0])
        if self.first and self.a is None:
            self.first = False    # tick 0 of a fresh run: the start
        else:
            self.first = False
            if self.a is None:    # on ice
                self.x = self.u * (k * DT_S)
            elif self.v - self.a * DT_S > 0.0:
                v1 = self.v - self.a * DT_S
                self.x += 0.5 * (self.v + v1) * DT_S
                self.v = v1
            else:                 # stops within this tick
                self.x += self.v * self.v / (2 * self.a)
                self.v = 0.0
            self.lik.steps += 1
        twist = ((self.v, 0.0, 0.0), (0.0, 0.0, 0.0))
        return ((twist,),)   # the state: the bodies' twists (one body), nothing more

    def poses(self) -> list:
        return [((self.x, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))]

    def branch(self, k: int, state):
        return Kept(snapshot=(self.x, self.v)) if self.a is None and self.x >= PATCH_M else None


class Slide(FrameLikelihood):
    def __init__(self, v_obs, seen, speedups=True, closed_rest=False, whole_replays=False):
        super().__init__(NAMES, FPS, N_FRAMES, ["mass"], speedups=speedups, sim_latents=["u_mps", "mu"],
                         prefix_latents=["u_mps"], rest=RestRule(every=SPF), whole_replays=whole_replays)
        self.v_obs, self.seen, self.closed_rest = np.nan_to_num(v_obs), seen, closed_rest
        self.probe_lock, self.lock_seen_free = False, []

    def start(self, values):
        return None if values["u_mps"] <= 0 else _Run(self, values["u_mps"], None)

    def resume(self, kept, values):
        return _Run(self, values["u_mps"], values["mu"] * G_MPS2, kept.snapshot)

    def alignment(self, values):
        return int(round(values["start_tick"])), SPF

    def horizon(self, values):
        return 10 + (N_FRAMES - 1) * SPF

    def noise_of(self, values):
        return _Noise(10.0 ** values["log10_sigma_mps"], int(self.seen.sum()))

    def observe(self, f, state, noise):
        if not self.seen[f]:
            return 0.0
        r = state[0][0][0][0] - self.v_obs[f]   # (the one body's linear velocity, x)
        return noise.half_prec * r * r

    def rest_sum(self, f0, noise):
        if not self.closed_rest:
            return None
        return noise.half_prec * float((self.v_obs[f0:] ** 2 * self.seen[f0:]).sum())


def gaussian_loglik(values: dict, v_obs, seen) -> float:
    """log N(v_obs | Newton's velocities, sigma^2), summed over the frames seen."""
    sigma = 10.0 ** values["log10_sigma_mps"]
    ticks = int(values["start_tick"]) + np.arange(N_FRAMES) * SPF
    _, v = newton(values, ticks)
    r = (np.nan_to_num(v_obs) - v)[seen]
    return float(np.sum(-0.5 * (r / sigma) ** 2 - math.log(sigma * math.sqrt(2 * math.pi))))


def vec(values: dict) -> np.ndarray:
    return np.array([values[n] for n in NAMES], float)


@pytest.fixture
def obs():
    return observed()


def test_the_truth_scores_the_gaussian_normaliser_and_moves_as_newton_says(obs):
    """Exact observations: at the truth every residual is zero (to rounding), so the value is
    the normaliser -n log(sigma sqrt(2 pi)); `motion` is Newton's slide, stop included."""
    for lik in (Slide(*obs), Slide(*obs, speedups=False), Slide(*obs, closed_rest=True)):
        value, early = lik(vec(TRUTH))
        n_seen = N_FRAMES - len(UNSEEN)
        assert not early
        assert value == pytest.approx(-n_seen * math.log(0.02 * math.sqrt(2 * math.pi)), rel=0, abs=1e-12)
        m = lik.motion(vec(TRUTH))
        x, v = newton(TRUTH, 3 + np.arange(N_FRAMES) * SPF)
        assert m.names == ["mass"] and m.position_m.shape == (1, N_FRAMES, 3)
        assert np.abs(m.position_m[0, :, 0] - x).max() < 1e-12
        assert np.abs(m.velocity_mps[0, :, 0] - v).max() < 1e-12
        assert (m.velocity_mps[0, 9:, 0] == 0.0).all() and (m.velocity_mps[0, :9, 0] > 0).all()   # stops at 0.93 s


def test_early_rejection_gives_the_plain_decisions_over_a_grid_of_thresholds(obs):
    """The MH test (accept iff value >= threshold) decides alike on the fast and the plain
    path for every threshold; a fast value that did not stop early is the plain one bit for
    bit, one that did is a bound: below the threshold, at or above the plain value."""
    rng = np.random.default_rng(0)
    fast, plain = Slide(*obs), Slide(*obs, speedups=False)
    stops = decided = 0
    for _ in range(40):
        values = {"u_mps": rng.uniform(0.8, 3.0), "mu": rng.uniform(0.05, 1.0),
                  "start_tick": float(rng.integers(0, 10)), "log10_sigma_mps": rng.uniform(-2.5, -0.5)}
        x = vec(values)
        want = plain(x)[0]
        assert want == pytest.approx(gaussian_loglik(values, *obs), rel=1e-9)
        for d in (-300.0, -10.0, -1.0, -1e-6, 1e-6, 1.0, 10.0, 300.0):
            threshold = want + d
            v_fast, early = fast(x, threshold)
            v_plain, plain_early = plain(x, threshold)
            assert not plain_early and v_plain == want
            assert (not early and v_fast >= threshold) == (v_plain >= threshold)
            if early:
                assert v_plain <= v_fast < threshold
                stops += 1
            else:
                assert v_fast == v_plain
            decided += 1
    assert 0 < stops < decided


def test_early_rejection_stops_at_the_first_frame_below_the_threshold(obs):
    """From the truth (the MH threshold a little below its value), a proposal 40 sigma off in
    the first frame seen (0.8 m/s) stops there: after the start's 3 ticks, not the video's 95."""
    threshold = Slide(*obs)(vec(TRUTH))[0] - 5.0
    fast = Slide(*obs)
    value, early = fast(vec({**TRUTH, "u_mps": 1.2}), threshold)
    assert early and value < threshold and fast.steps == 3


@pytest.mark.parametrize("closed_rest", [False, True])
def test_the_rest_cutoff_equals_stepping_on(obs, closed_rest):
    """A slide that stops a fifth of the way in: the fast path stops stepping there and scores
    the rest at the held state (or `rest_sum`), the plain path steps on to the end; both
    equal Newton's loglik, and each other bit for bit."""
    values = {**TRUTH, "mu": 0.9}            # stops at 0.48 s (tick 19.1); the video runs to tick 95
    x = vec(values)
    fast, plain = Slide(*obs, closed_rest=closed_rest), Slide(*obs, speedups=False, closed_rest=closed_rest)
    v_fast, v_plain = fast(x)[0], plain(x)[0]
    assert v_fast == v_plain
    assert v_fast == pytest.approx(gaussian_loglik(values, *obs), rel=1e-12)
    last = 3 + (N_FRAMES - 1) * SPF
    assert plain.steps == last
    # at rest from the second checked tick (multiples of SPF) after the stop
    t_stop = branch_tick(2.0) * DT_S + 2.0 / (0.9 * G_MPS2)
    rest_tick = (math.ceil(t_stop / DT_S / SPF) + 1) * SPF
    assert fast.steps == rest_tick < plain.steps
    m_fast, m_plain = fast.motion(x), plain.motion(x)
    assert np.array_equal(m_fast.position_m, m_plain.position_m)
    assert np.array_equal(m_fast.velocity_mps, m_plain.velocity_mps)


@pytest.mark.parametrize("u", [TRUTH["u_mps"], 0.35])
def test_prefix_reuse_returns_the_same_value_and_steps_only_after_the_branch(obs, u):
    """A proposal that keeps u resumes where the mass reached the patch (the ice depends on u
    alone) with its own mu: the plain value bit for bit (at u = 0.35 m/s, 14 frames before the
    branch: numpy sums them in another order than one by one), Newton's loglik, and exactly
    the steps of a run from scratch less the ice's; a new u simulates from tick 0."""
    base = {**TRUTH, "u_mps": u}
    fast, plain = Slide(*obs), Slide(*obs, speedups=False)
    x0 = vec(base)
    assert fast(x0)[0] == plain(x0)[0]
    kb = branch_tick(u)
    prefix = fast._prefixes[(u,)]
    assert prefix.first_b == kb + 1 and len(prefix.terms) == kb + 1 and prefix.snapshot is not None
    assert prefix.snapshot[0] == pytest.approx(u * kb * DT_S)
    for mu in (0.2, 0.35, 0.6, 1.5):
        values = {**base, "mu": mu}
        x = vec(values)
        s0 = fast.steps
        v_fast, early = fast(x)
        assert not early and v_fast == plain(x)[0]
        assert v_fast == pytest.approx(gaussian_loglik(values, *obs), rel=1e-12)
        scratch = Slide(*obs)
        scratch(x)
        assert fast.steps - s0 == scratch.steps - kb    # the ice not simulated again
        assert np.array_equal(fast.motion(x).position_m, plain.motion(x).position_m)
    s0 = fast.steps
    fast(vec({**base, "u_mps": 1.7}))
    assert fast.steps - s0 >= branch_tick(1.7)


@pytest.mark.parametrize("whole", [False, True])
def test_latents_outside_the_simulation_need_no_physics(obs, whole):
    """Start and sigma proposals are scored from the kept run: no steps, the plain value. With
    a threshold above it, the replay stops at the threshold (a bound), or with
    `whole_replays` reports the exact value."""
    fast, plain = Slide(*obs, whole_replays=whole), Slide(*obs, speedups=False)
    fast(vec(TRUTH))
    steps = fast.steps
    for change in ({"start_tick": 0.0}, {"start_tick": 9.0}, {"log10_sigma_mps": -1.0},
                   {"start_tick": 5.0, "log10_sigma_mps": -2.2}):
        values = {**TRUTH, **change}
        x = vec(values)
        want = plain(x)[0]
        assert fast(x) == (want, False)
        assert want == pytest.approx(gaussian_loglik(values, *obs), rel=1e-12)
        v, early = fast(x, want + 1.0)
        assert early != whole and (v == want if whole else want <= v < want + 1.0)
    assert fast.steps == steps


def test_nothing_to_simulate_is_minus_infinity(obs):
    lik = Slide(*obs)
    assert lik(vec({**TRUTH, "u_mps": 0.0})) == (-math.inf, False) and lik.steps == 0
    with pytest.raises(GalileoError, match="nothing can be simulated"):
        lik.motion(vec({**TRUTH, "u_mps": 0.0}))


def test_the_bullet_lock_is_held_while_simulating(obs):
    """Another thread cannot take `client_lock` during any tick of a call or a motion."""
    lik = Slide(*obs)
    lik.probe_lock = True
    lik(vec(TRUTH))
    lik.motion(vec({**TRUTH, "mu": 0.5}))
    assert lik.lock_seen_free and not any(lik.lock_seen_free)


class HeldSlide(Slide):
    """The slide filmed from before it starts: frames before tick 0 see the mass held at rest
    at x = 0 (`before_start`), as the splash's frames before its drop see the object held."""

    def before_start(self, values):
        still = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
        return ((still,),), [((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))]


def test_frames_before_the_run_starts_count_once_the_run_branches():
    """A video that starts before the run: its first frames score the held state, and they
    still count after the run passes the branch (where the terms before it are summed as one
    block) on every path: fresh, plain, resumed at a kept branch, replayed whole. Against
    Gaussian noise on Newton's slide, velocity 0 before tick 0."""
    values = dict(TRUTH, start_tick=-6.0)    # frames 0 and 1 at ticks -6 and -2: before the start
    _, v = newton(values, -6 + np.arange(N_FRAMES) * SPF)
    seen = np.ones(N_FRAMES, bool)
    v_obs = v + np.random.default_rng(3).normal(0.0, 0.02, N_FRAMES)
    assert v[:2].tolist() == [0.0, 0.0] and abs(v_obs[:2]).min() > 0.01   # held, and their terms not zero
    fast, plain = HeldSlide(v_obs, seen), HeldSlide(v_obs, seen, speedups=False)
    for mu in (0.3, 0.5, 0.3):   # fresh; resumed at the first one's branch; the first one replayed
        point = dict(values, mu=mu)
        want = gaussian_loglik(point, v_obs, seen)
        for lik in (fast, plain):
            assert lik(vec(point))[0] == pytest.approx(want, rel=1e-9)
    other_sigma = vec(dict(values, mu=0.5, log10_sigma_mps=-1.5))   # the second one replayed at another sigma
    assert fast(other_sigma)[0] == plain(other_sigma)[0]
