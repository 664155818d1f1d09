"""The live inference controller (ui/controller.py) and its sessions (ui/session.py), on the
demo video: the batch runner's chains, steering applied from the next sweep, saved sessions
that resume bit for bit, and the background thread."""
import json
import re
import shutil
import threading

import numpy as np
import pytest

from conftest import wait_until
from galileo.errors import GalileoError
from galileo.runner import RunConfig as InferenceConfig
from galileo.runner import infer
from galileo.scenarios.ramp.likelihood import VelocityLikelihood
from ui import session as sess
from galileo.runner import Settings
from ui.controller import Controller

NAMES = ("m1_kg", "k1", "m2_kg", "k2", "e_collision")   # (the restitution a latent by default)


@pytest.fixture(scope="module")
def demo(demo_frozen):
    """(scene, tracks) of the demo video: the frozen inputs (tests/data), since the chains
    are compared with the batch runner and the likelihood bit for bit."""
    return demo_frozen[:2]


@pytest.fixture
def make(demo):
    """Controllers on the demo, closed after the test."""
    made = []

    def _make(**kw):
        kw.setdefault("chains", 2)
        kw.setdefault("workers", 1)
        c = Controller(*demo, **kw)
        made.append(c)
        return c
    yield _make
    for c in made:
        c.close()


def lik_at(demo, sigma, x, moves="paper"):
    """The log-likelihood a controller with `moves` scores x with (the paper's: Gaussian)."""
    from galileo.runner import scene_for_moves

    scene, tracks = demo
    return VelocityLikelihood(scene_for_moves(scene, moves), tracks, sigma_mps=sigma)(np.asarray(x, float))[0]


def same_chains(a: Controller, b: Controller, ids=None):
    for c in ids if ids is not None else a.all_chain_ids():
        assert np.array_equal(a.samples(c), b.samples(c)), c
        assert np.array_equal(a.logliks(c), b.logliks(c)), c
        pa, pb = a.proposals(c), b.proposals(c)
        for k in ("site", "proposal", "accepted", "early_stop", "width"):   # (a joint move's width: NaN)
            assert np.array_equal(pa[k], pb[k], equal_nan=k == "width"), (c, k)
        assert np.array_equal(a.sample_noise(c), b.sample_noise(c)), c


# -- running ---------------------------------------------------------------------------------------------

def test_run_sweeps_grows_samples_and_map_is_the_best_sample(make):
    from galileo.runner import default_moves

    ctl = make(chains=2, seed=0)
    joint = [m.name for m in default_moves(ctl.scenario, ctl.likelihood_scene, ctl.tracks, ctl.latents,
                                           ctl.settings.bounds_array(NAMES), ctl.settings)]
    assert ctl.names == NAMES and ctl.chain_ids() == [0, 1] and ctl.map() is None
    assert ctl.samples(0).shape == (0, len(NAMES)) and ctl.logliks(0).shape == (0,)
    ctl.run_sweeps(3)
    assert ctl.samples(0).shape == (3, len(NAMES)) and ctl.logliks(1).shape == (3,)
    ctl.run_sweeps(2)
    for c in (0, 1):
        s, ll = ctl.samples(c), ctl.logliks(c)
        assert s.shape == (5, len(NAMES)) and ll.shape == (5,) and np.all(np.isfinite(ll))
        assert ctl.sample(c, 4) == dict(zip(NAMES, s[4].tolist()))
        # one proposal a latent and one a joint move (the ramp's k1 and mass moves, the joint walk) per sweep
        assert len(ctl.proposals(c)["site"]) == 5 * (len(NAMES) + len(joint))
    all_ll = np.stack([ctl.logliks(c) for c in (0, 1)])
    c, i, values, ll = ctl.map()
    assert ll == all_ll.max() and (c, i) == np.unravel_index(np.argmax(all_ll), all_ll.shape)
    assert values == ctl.sample(c, i)
    st = ctl.status()
    assert st["rounds"] == 5 and st["sweeps"] == 10 and st["proposals"] == 10 * (len(NAMES) + len(joint))
    assert st["moves"]["set"] == "default" and st["moves"]["warmup"] == 37 and st["moves"]["adapting"]
    assert st["moves"]["joint"] == joint and "k1_from_acceleration" in joint
    assert all(0 <= v <= 1 for v in st["moves"]["acceptance"].values())
    assert set(st["chains"]) == {0, 1} and st["chains"][0]["sweeps"] == 5
    assert st["chains"][1]["loglik"] == ctl.logliks(1)[-1] and st["chains"][0]["state"] == "running"
    assert st["chains"][0]["running"] and not st["chains"][0]["paused"]
    assert ctl.likelihood_scene.objects[0].shape == ctl.tracks.by_role("ramp").shape
    assert set(st["acceptance"]) == set(NAMES) and 0 < st["accepted"] < st["proposals"]
    assert st["map"]["loglik"] == ll
    assert all(v is None or np.isfinite(v) for v in st["r_hat"].values())


def test_same_seed_same_chains_for_one_and_two_workers(make):
    one, two = make(chains=3, seed=4, workers=1), make(chains=3, seed=4, workers=2)
    one.run_sweeps(3)
    two.run_sweeps(3)
    same_chains(one, two)
    assert one.map() == two.map()


def assert_batch_chains(ctl, res):
    for c in range(res.samples.shape[0]):
        assert np.array_equal(ctl.samples(c), res.samples[c])
        assert np.array_equal(ctl.logliks(c), res.logliks[c])
        p = ctl.proposals(c)
        for k in ("site", "proposal", "accepted", "early_stop", "proposal_loglik"):
            assert np.array_equal(p[k], res.proposals[k][c]), k
        assert np.array_equal(p["width"], res.proposals["width"][c], equal_nan=True)
    c, i, values, ll = ctl.map()
    assert (c, i) == res.map_index and values == res.map and ll == res.map_loglik


@pytest.mark.parametrize("moves", ["default", "paper"])
def test_chains_equal_the_batch_runner(demo, make, moves):
    """Same kernel, same streams, same starts, the same warm-up adaptation and joint moves
    (default) or the paper's kernel: the batch runner's chains bit for bit."""
    res = infer(*demo, InferenceConfig(chains=2, sweeps=4, seed=3, workers=1, moves=moves), progress=False)
    ctl = make(chains=2, seed=3, workers=2, moves=moves, sweeps=4)
    assert ctl.run_sweeps(6) == 4           # each chain pauses at its 4 sweeps
    assert_batch_chains(ctl, res)
    assert [e["kind"] for e in ctl.events] == ["init", "pause"]
    assert ctl.events[-1]["detail"] == {"chains": [0, 1], "reason": "sweep target 4"}
    st = ctl.status()
    assert all(ch["held"] and ch["paused"] for ch in st["chains"].values())
    if moves == "default":   # the widths each chain adapted in its 2 warm-up sweeps, as the batch runner's
        assert ctl.warmup == res.warmup == 2
        assert [list(ctl.proposal_state(c)[0].narrow) for c in range(2)] == res.moves["adapted"]["narrow"]
        assert (res.proposals["site"] < 0).any()
    else:
        assert ctl.warmup == res.warmup == 0 and ctl.proposal_state(0) == (ctl.settings.proposal(), ())
        assert (res.proposals["site"] >= 0).all()


def test_the_fitted_move_set_equals_the_batch_runner_and_comes_back_with_the_session(demo, make, tmp_path):
    """--moves fitted in the app: once every chain is past its warm-up (10 sweeps), the move
    fitted to their warm-ups joins every chain's moves, as in `galileo infer --moves fitted`:
    the same chains bit for bit; recorded once ("fitted", q in full); a reopened session runs
    on with it, as the chains that never stopped do; too short a warm-up is refused."""
    from galileo.runner import FITTED_MARGINALS, FITTED_PER_SWEEP

    res = infer(*demo, InferenceConfig(chains=3, sweeps=14, warmup=10, seed=2, workers=1, moves="fitted"),
                progress=False)
    ctl = make(chains=3, seed=2, workers=1, moves="fitted", sweeps=14, warmup=10, session_dir=tmp_path / "s")
    assert ctl.run_sweeps(20) == 14
    assert_batch_chains(ctl, res)
    fits = [e for e in ctl.events if e["kind"] == "fitted"]
    assert len(fits) == 1 and fits[0]["detail"]["sweep"] == 10 and fits[0]["detail"]["move"]["name"] == "fitted"
    # the joint proposals from the kernel density estimate of the warm-up draws, recorded with q
    assert fits[0]["detail"]["kernel"]["type"] == "FittedKernel"
    fitted_sites = res.moves["codes"]["fitted_kernel"]
    assert np.isin(ctl.proposals(0)["site"], fitted_sites).sum() == 4 * FITTED_PER_SWEEP   # sweeps 11-14
    assert ctl.status()["moves"]["joint"].count("fitted_kernel") == 1
    assert ctl.status()["moves"]["acceptance"]["fitted_kernel"] == res.diagnostics()["acceptance"]["fitted_kernel_move"]
    # the marginal moves of the latents the others barely determine (k1, e_collision here) with q
    marginals = fits[0]["detail"]["marginals"]
    assert marginals and {m["type"] for m in marginals} == {"FittedMarginal"}
    assert fits[0]["detail"]["marginals_per_sweep"] == FITTED_MARGINALS
    assert np.isin(ctl.proposals(0)["site"], res.moves["codes"]["fitted_marginal"]).sum() == (
        4 * FITTED_MARGINALS * len(marginals))
    # on past the target: the chains that stopped and reopened are the chains that never stopped
    on = make(chains=3, seed=2, workers=1, moves="fitted", sweeps=14, warmup=10)
    on.run_sweeps(14)
    ctl.save()
    ctl.close()
    back = Controller.load(tmp_path / "s", workers=1)
    try:
        for c in (back, on):
            c.resume()
            c.run_sweeps(3)
        for c in range(3):
            assert np.array_equal(back.samples(c), on.samples(c))
        assert [e["kind"] for e in back.events].count("fitted") == 1
    finally:
        back.close()
    with pytest.raises(GalileoError, match="warm-up of at least"):
        make(chains=2, moves="fitted", sweeps=12)


def test_a_session_fitted_before_the_conditional_moves_reopens_with_the_kernel_it_ran(demo, make, tmp_path):
    """The "fitted" event records how many joint proposals, conditional and marginal moves joined
    with q, the kernel the joint proposals come from and the marginals; a session recorded before
    the kernel, conditional and marginal moves (no kernel: the joint proposals from q; no counts:
    12 joint, none) gives a chain made after reopening those 12 from q and no conditional or
    marginal move, and a session of today all of them."""
    from galileo.mcmc import FittedConditional, FittedIndependence, FittedKernel, FittedMarginal
    from galileo.runner import FITTED_CONDITIONALS, FITTED_MARGINALS, FITTED_PER_SWEEP
    from ui.session import CHAINS_FILE, EVENTS_FILE

    ctl = make(chains=2, seed=2, workers=1, moves="fitted", sweeps=12, warmup=10, session_dir=tmp_path / "s")
    ctl.run_sweeps(10)              # to the fit, before any sweep proposes the moves it adds
    assert [e["kind"] for e in ctl.events].count("fitted") == 1
    ctl.save()
    ctl.close()

    def kinds(folder):
        back = Controller.load(folder, workers=1)
        try:
            moves = back._moves0
            return (sum(isinstance(m, FittedKernel) for m in moves), sum(isinstance(m, FittedIndependence) for m in moves),
                    sorted(m.site for m in moves if isinstance(m, FittedConditional)),
                    sorted(m.site for m in moves if isinstance(m, FittedMarginal)))
        finally:
            back.close()

    fit = next(e for e in ctl.events if e["kind"] == "fitted")["detail"]
    marginal_sites = sorted([m["site"] for m in fit["marginals"]] * FITTED_MARGINALS)
    assert marginal_sites and fit["marginals_per_sweep"] == FITTED_MARGINALS
    assert kinds(tmp_path / "s") == (FITTED_PER_SWEEP, 0, sorted(list(range(len(NAMES))) * FITTED_CONDITIONALS),
                                     marginal_sites)
    # the session as it was recorded before: no counts in the event, no conditional moves in the chains
    path = tmp_path / "s" / EVENTS_FILE
    doc = json.loads(path.read_text())
    for e in doc["events"]:
        if e["kind"] == "fitted":
            del e["detail"]["per_sweep"], e["detail"]["conditionals"]
            del e["detail"]["marginals"], e["detail"]["marginals_per_sweep"], e["detail"]["kernel"]
    path.write_text(json.dumps(doc))
    path = tmp_path / "s" / CHAINS_FILE
    text = path.read_text()
    doc = json.loads(text)
    # today's chains.json writes each distinct move once, in its move table, and the chains' moves
    # as indices into it; before the table, every chain held its moves inline
    assert [m["type"] for m in doc["move_table"]].count("FittedKernel") == 1
    assert all(isinstance(i, int) for ch in doc["chains"] for i in ch["moves"])
    for ch in doc["chains"]:
        ch["moves"] = [doc["move_table"][i] for i in ch["moves"]]
    del doc["move_table"]
    dropped = _drop_moves(doc, "FittedConditional")
    assert dropped == 2 * len(NAMES) * FITTED_CONDITIONALS, dropped      # two chains' conditional moves
    assert _drop_moves(doc, "FittedMarginal") == 2 * len(marginal_sites)
    assert _drop_moves(doc, "FittedKernel", fit["move"]) == 2 * FITTED_PER_SWEEP   # (the joint proposals from q)
    path.write_text(json.dumps(doc))
    assert kinds(tmp_path / "s") == (0, 12, [], [])


def _drop_moves(node, kind: str, instead: dict | None = None) -> int:
    """Remove the recorded joint moves of type `kind` wherever they are in a session file's JSON
    (or put `instead` in their place); how many."""
    n = 0
    if isinstance(node, dict):
        for v in node.values():
            n += _drop_moves(v, kind, instead)
    elif isinstance(node, list):
        keep = [x if not (isinstance(x, dict) and x.get("type") == kind) else instead for x in node]
        n += sum(isinstance(x, dict) and x.get("type") == kind for x in node)
        node[:] = [x for x in keep if x is not None]
        for x in node:
            n += _drop_moves(x, kind, instead)
    return n


def test_run_until_converged_equals_the_batch_runner(demo, make):
    """--until-rhat in the app: held at the sweep target, checked, run on in the batch runner's
    blocks until the budget (4 sweeps, then 2 more: never converged this short) and the
    same chains as `galileo infer --until-rhat` bit for bit."""
    cfg = InferenceConfig(chains=2, sweeps=4, seed=3, workers=1, until_rhat=1.01, max_sweeps=6)
    res = infer(*demo, cfg, progress=False)
    ctl = make(chains=2, seed=3, workers=1, sweeps=4, until_rhat=1.01, max_sweeps=6)
    assert ctl.run_sweeps(10) == 6
    assert res.samples.shape[1] == 6
    assert_batch_chains(ctl, res)
    checks = [e for e in ctl.events if e["kind"] == "until_check"]
    assert [c["detail"]["sweeps"] for c in checks] == [4, 6]
    assert checks[0]["detail"]["target"] == 6 and checks[0]["detail"]["resumed"] == [0, 1]
    assert not checks[1]["detail"]["converged"] and "budget" in checks[1]["detail"]["outcome"]
    st = ctl.status()
    assert st["until"] == {"until_rhat": 1.01, "min_ess": 400.0, "max_sweeps": 6} and st["target_sweeps"] == 6
    assert not st["convergence"]["converged"] and st["convergence"]["why_not"]
    assert st["convergence"]["why_not"] == res.convergence()["why_not"]
    # turned on later (a reopened session, or the app's button): a verdict at once, then blocks (the
    # warm-up is chosen at the start: with until_rhat galileo infer's is all of these 4 sweeps)
    assert ctl.warmup == res.warmup == 4
    later = make(chains=2, seed=3, workers=1, sweeps=4, warmup=4)
    later.run_sweeps(4)
    later.run_until(1.01, max_sweeps=6)
    assert later.events[-1]["kind"] == "until_check" and later.events[-1]["detail"]["target"] == 6
    assert later.run_sweeps(5) == 2
    same_chains(ctl, later)
    with pytest.raises(ValueError, match="until_rhat"):
        later.run_until(0.9)
    with pytest.raises(ValueError, match="max_sweeps"):
        later.run_until(1.01, max_sweeps=2)


# -- steering -----------------------------------------------------------------------------------------------

def test_pause_resume_add_and_remove_chains(demo, make):
    ctl = make(chains=2, seed=1, workers=2, warmup=1)
    ctl.run_sweeps(2)
    ctl.pause(0)
    ctl.run_sweeps(2)
    assert len(ctl.samples(0)) == 2 and len(ctl.samples(1)) == 4
    assert ctl.status()["chains"][0]["state"] == "paused"
    ev = ctl.events[-1]
    assert ev["kind"] == "pause" and ev["sweep"] == 2 and ev["detail"]["chains"] == [0]
    ctl.resume(0)
    ctl.run_sweeps(1)
    assert len(ctl.samples(0)) == 3 and len(ctl.samples(1)) == 5
    assert ctl.events[-1]["kind"] == "resume" and ctl.events[-1]["sweep"] == 4

    # a new chain is the batch runner's chain with that index
    assert ctl.add_chains(1) == [2]
    assert ctl.chain_ids() == [0, 1, 2] and len(ctl.samples(2)) == 0
    ctl.run_sweeps(2)
    assert len(ctl.samples(2)) == 2
    res = infer(*demo, InferenceConfig(chains=3, sweeps=2, seed=1, workers=1), progress=False)
    assert np.array_equal(ctl.samples(2), res.samples[2]) and np.array_equal(ctl.logliks(2), res.logliks[2])

    # a removed chain stops, but its samples stay and count for the MAP
    best_chain = ctl.map()[0]
    before = ctl.map()
    ctl.remove_chain(best_chain)
    assert best_chain not in ctl.chain_ids() and best_chain in ctl.all_chain_ids()
    assert ctl.map() == before
    n = len(ctl.samples(best_chain))
    ctl.run_sweeps(1)
    assert len(ctl.samples(best_chain)) == n
    best = max(((c, i) for c in ctl.all_chain_ids() for i in range(len(ctl.logliks(c)))),
               key=lambda ci: ctl.logliks(ci[0])[ci[1]])
    assert ctl.map()[:2] == best
    with pytest.raises(ValueError, match="removed"):
        ctl.resume(best_chain)
    with pytest.raises(ValueError, match="no chain"):
        ctl.pause(99)
    kinds = [e["kind"] for e in ctl.events]
    assert kinds == ["init", "pause", "resume", "add_chains", "remove_chain"]


def test_reset_chain_and_set_chain(make):
    ctl = make(chains=2, seed=2, moves="paper")
    ctl.run_sweeps(3)
    c_map, i_map, map_values, _ = ctl.map()
    other = 1 - c_map
    ctl.reset_chain(other, "map")
    assert ctl.position(other) == map_values
    ev = ctl.events[-1]
    assert ev["kind"] == "reset_chain" and ev["sweep"] == 3 and ev["detail"]["sample"] == [c_map, i_map]
    ctl.run_sweeps(1)  # the next sweep starts at the MAP: narrow moves only
    step = ctl.samples(other)[-1] - np.array([map_values[n] for n in ctl.names])   # (paper: no e_collision)
    assert np.all(np.abs(step) <= 0.05 + 1e-12)

    ctl.reset_chain(c_map, "sample", (other, 0))
    assert ctl.position(c_map) == ctl.sample(other, 0)

    hand = {"m1_kg": 0.3, "k1": 0.2, "m2_kg": 0.6, "k2": 0.4}
    ctl.set_chain(0, hand)
    assert ctl.position(0) == hand and ctl.events[-1]["kind"] == "set_chain"
    ctl.set_chain(0, {"k1": 0.25})
    assert ctl.position(0) == {**hand, "k1": 0.25}
    for bad in ({"k1": 1.5}, {"mass": 1.0}, {"k1": float("nan")}):
        with pytest.raises(ValueError):
            ctl.set_chain(0, bad)
    with pytest.raises(ValueError):
        ctl.reset_chain(0, "somewhere")


def test_set_sigma_applies_from_the_next_sweep(demo, make):
    ctl = make(chains=2, seed=0)
    ctl.run_sweeps(2)
    ctl.set_sigma(0.1)
    ev = ctl.events[-1]
    assert ev["kind"] == "sigma" and ev["sweep"] == 2 and ev["detail"] == {"sigma_mps": 0.1, "old": 0.05}
    assert ev["chain_sweeps"] == {"0": 2, "1": 2}
    ctl.run_sweeps(2)
    s, ll = ctl.samples(0), ctl.logliks(0)
    for k in range(4):  # logliks as VelocityLikelihood computes them under each sweep's sigma
        assert ll[k] == lik_at(demo, 0.05 if k < 2 else 0.1, s[k], ctl.moves_set), k
    assert ctl.settings.noise == 0.1 and ctl.status()["settings"]["sigma_mps"] == 0.1
    for bad in (0, -1, float("inf"), "x"):
        with pytest.raises(ValueError, match="sigma"):
            ctl.set_sigma(bad)


def test_set_bounds_pulls_chains_inside_and_set_widths(make):
    ctl = make(chains=2, seed=0, moves="paper")
    ctl.run_sweeps(2)
    k1 = [ctl.position(c)["k1"] for c in (0, 1)]
    lo, hi = 0.05, min(k1) - 0.01          # both chains now lie above the new bound
    ctl.set_bounds("k1", lo, hi)
    ev = ctl.events[-1]
    assert ev["kind"] == "bounds" and ev["sweep"] == 2 and ev["detail"]["old"] == [0.0, 1.0]
    assert set(ev["detail"]["moved"]) == {"0", "1"}
    assert ev["detail"]["moved"]["0"] == {"from": k1[0], "to": hi}
    assert all(ctl.position(c)["k1"] == hi for c in (0, 1))
    assert ctl.settings.bounds["k1"] == (lo, hi)
    ctl.set_widths(0.01, 0.1, 5)
    ev = ctl.events[-1]
    assert ev["kind"] == "widths" and ev["sweep"] == 2
    assert ev["detail"]["old"] == {"narrow": 0.05, "broad": 0.5, "broad_every": 20}
    ctl.run_sweeps(3)
    for c in (0, 1):
        assert np.all((ctl.samples(c)[2:, 1] >= lo) & (ctl.samples(c)[2:, 1] <= hi))
        width = ctl.proposals(c)["width"]
        assert np.all(width[:8] == 0.05)                       # sweeps 1-2
        assert np.all(width[8:16] == 0.01) and np.all(width[16:20] == 0.1)   # 3, 4; the 5th is broad
    for args in (("k1", 0.5, 0.5), ("k1", 0.6, 0.4), ("m1_kg", 0.0, 1.0), ("k2", -0.1, 1.0),
                 ("mass", 0.1, 1.0), ("k1", float("nan"), 1.0)):
        with pytest.raises(ValueError) as e:
            ctl.set_bounds(*args)
        assert "\n" not in str(e.value)
    for args in ((0, 0.5, 20), (0.05, -1, 20), (0.05, 0.5, -1), (0.05, 0.5, 2.5)):
        with pytest.raises(ValueError):
            ctl.set_widths(*args)
    assert [e["kind"] for e in ctl.events] == ["init", "bounds", "widths"]


def narrow_of(ctl, c):
    return ctl.proposal_state(c)[0].narrow


def test_width_edit_replaces_adapted_widths_and_steering_keeps_them(make):
    """Default moves: each chain adapts its own narrow widths in warm-up; setting or resetting a
    chain keeps them; a width edit replaces every chain's from that sweep on and ends adaptation."""
    ctl = make(chains=2, seed=2)
    ctl.run_sweeps(3)
    adapted = {c: narrow_of(ctl, c) for c in (0, 1)}
    assert all(isinstance(w, tuple) and w != (0.05,) * len(NAMES) for w in adapted.values()) and adapted[0] != adapted[1]
    moves = ctl.proposal_state(0)[1]
    ctl.set_chain(0, {"k1": 0.25})
    ctl.reset_chain(1, "map")
    assert {c: narrow_of(ctl, c) for c in (0, 1)} == adapted and ctl.proposal_state(0)[1] == moves
    ctl.run_sweeps(1)   # sweep 4 uses the kept widths (and adapts them further: warm-up is 37 sweeps)
    for c in (0, 1):
        assert np.array_equal(ctl.proposals(c)["width"][-len(NAMES) - 4:-4], adapted[c])   # (then 4 joint moves)
    assert narrow_of(ctl, 0) != adapted[0]

    ctl.set_widths(0.02, 0.3, 20)
    ev = ctl.events[-1]
    assert ev["kind"] == "widths" and "ended" in ev["detail"]["adaptation"]
    assert set(ev["detail"]["replaced_adapted_narrow"]) == {"0", "1"}
    ctl.run_sweeps(2)
    for c in (0, 1):
        d = len(NAMES)   # two sweeps of d site moves, then 4 joint moves
        assert np.all(ctl.proposals(c)["width"][-2 * (d + 4):][[*range(d), *range(d + 4, 2 * d + 4)]] == 0.02)
        assert narrow_of(ctl, c) == 0.02     # no longer adapted
    assert not ctl.status()["moves"]["adapting"]
    c = ctl.add_chains(1)[0]                 # a later chain uses the user's widths too
    ctl.run_sweeps(1)
    assert np.all(ctl.proposals(c)["width"][:len(NAMES)] == 0.02) and narrow_of(ctl, c) == 0.02


def test_map_compares_logliks_under_one_sigma(demo, make):
    """A sigma edit puts every later log-likelihood on another scale: the MAP is the best
    sample under the sigma in force, never an older sample that merely scored higher under
    the old one (pending until a sample under the new sigma exists)."""
    ctl = make(chains=2, seed=0, moves="paper")
    ctl.run_sweeps(3)
    old = ctl.map()
    ctl.set_sigma(0.01)         # a fifth of the noise: every log-likelihood falls far below the old ones
    assert ctl.map() is None and "MAP pending" in ctl.map_note() and "sigma_mps = 0.01" in ctl.map_note()
    st = ctl.status()
    assert st["map"] is None and st["map_note"].startswith("MAP pending")
    with pytest.raises(ValueError, match="MAP pending"):
        ctl.reset_chain(0, "map")
    ctl.run_sweeps(1)
    c, i, values, ll = ctl.map()
    assert i == 3 and ll == max(ctl.logliks(k)[3] for k in (0, 1)) == lik_at(demo, 0.01, ctl.samples(c)[i])
    assert old[3] > ll          # today's rule (the best of all samples) would have kept the old MAP
    assert ctl.status()["map"]["noise"] == 0.01 and ctl.status()["map_note"] is None
    assert [list(ctl.sample_noise(k)) for k in (0, 1)] == [[0.05] * 3 + [0.01]] * 2
    ctl.set_sigma(0.05)         # back: the samples under 0.05 compare again, old and new
    ctl.run_sweeps(1)
    under = [(ctl.logliks(k)[j], k, j) for k in (0, 1) for j in range(5) if ctl.sample_noise(k)[j] == 0.05]
    assert ctl.map()[3] == max(under)[0] and ctl.map()[:2] == max(under)[1:]


def test_status_says_whether_each_latent_converged_and_gives_the_ratio(make):
    """status(): the verdict of galileo.results.convergence on the kept draws (after max(warm-up,
    half)), per latent and why not, and the mass ratio's posterior on the same draws."""
    from galileo.results import convergence

    ctl = make(chains=2, seed=1, warmup=2, sweeps=10)
    st = ctl.status()
    assert st["convergence"]["converged"] is False and st["derived"] == {}
    ctl.run_sweeps(10)
    st = ctl.status()
    kept = [ctl.samples(c)[5:] for c in (0, 1)]    # burn-in max(2, 10 / 2)
    want = convergence(kept, NAMES)
    conv = st["convergence"]
    assert conv["burn_in"] == 5 and conv["kept_draws"] == 10
    for k in ("converged", "why_not", "per_latent", "r_hat", "ess_bulk", "ess_tail"):
        assert conv[k] == want[k], k
    assert st["r_hat"] == want["r_hat"] and set(conv["per_latent"]) == set(NAMES)
    assert not conv["converged"] and all(w.split(":")[0] in NAMES for w in conv["why_not"])
    ratio = np.concatenate([k[:, 0] / k[:, 2] for k in kept])
    d = st["derived"]["mass_ratio"]
    assert d["q50"] == pytest.approx(np.median(ratio), rel=1e-12)
    assert d["q05"] == pytest.approx(np.quantile(ratio, 0.05), rel=1e-12)
    assert st["derived"]["log_mass_ratio"]["q50"] == pytest.approx(np.median(np.log(ratio)), rel=1e-12)
    assert ctl.status()["convergence"] == conv     # cached until something changes


class GatedPool:
    """An executor (`map`) that runs the tasks in this process once the test opens the gate:
    while it waits, the controller's round is in flight, for certain."""

    def __init__(self):
        self.entered, self.gate = threading.Event(), threading.Event()

    def map(self, fn, tasks):
        self.entered.set()
        if not self.gate.wait(60):
            raise RuntimeError("the test never opened the gate")
        return [fn(t) for t in tasks]


def test_steering_during_a_sweep_applies_after_it(demo, make):
    """A change made while a round is in flight does not wait for it, leaves it alone (it
    finishes with the old settings and its result is kept) and applies right after it."""
    pool = GatedPool()
    ctl = make(chains=3, seed=0, executor=pool, moves="paper")
    runner = threading.Thread(target=ctl.run_sweeps, args=(1,))
    runner.start()
    try:
        assert pool.entered.wait(30), "the round never reached the executor"
        hand = {"m1_kg": 0.3, "k1": 0.2, "m2_kg": 0.6, "k2": 0.4}
        ctl.set_sigma(0.1)           # both return while the round waits at the gate:
        ctl.set_chain(0, hand)       # queued, not waited for
        assert runner.is_alive() and len(ctl.samples(0)) == 0
        assert [e["kind"] for e in ctl.events] == ["init"] and ctl.settings.noise == 0.05
    finally:
        pool.gate.set()
        runner.join(60)
    assert not runner.is_alive()
    assert [e["kind"] for e in ctl.events] == ["init", "sigma", "set_chain"]
    assert all(e["sweep"] == 1 for e in ctl.events[1:])
    assert ll_ok(demo, ctl, 0, 0.05) and ctl.position(0) == hand   # the sweep's result did not undo it
    ctl.run_sweeps(1)
    assert ll_ok(demo, ctl, 1, 0.1)
    assert np.all(np.abs(ctl.samples(0)[1] - [hand[n] for n in ctl.names]) <= 0.05 + 1e-12)


def ll_ok(demo, ctl, index, sigma):
    return all(ctl.logliks(c)[index] == lik_at(demo, sigma, ctl.samples(c)[index], ctl.moves_set) for c in ctl.chain_ids())


def test_settings_are_checked(demo):
    bounds = {n: (0.001, 1.0) for n in NAMES}
    with pytest.raises(ValueError, match="m1_kg"):
        Controller(*demo, chains=1, workers=1, settings=Settings({**bounds, "m1_kg": (0.0, 1.0)}))
    with pytest.raises(ValueError, match="sigma"):
        Controller(*demo, chains=1, workers=1, settings=Settings(bounds, noise=0.0))


# -- sessions ---------------------------------------------------------------------------------------------

def test_session_saved_mid_run_reloads_the_same(make, tmp_path):
    folder = sess.new_session_dir(tmp_path / "sessions", "demo run")
    assert re.fullmatch(r"\d{8}-\d{6}-demo-run", folder.name) and folder.is_dir()
    again = sess.new_session_dir(tmp_path / "sessions", "demo run")
    assert again != folder and again.is_dir() and re.fullmatch(r"\d{8}-\d{6}-demo-run(-2)?", again.name)
    ctl = make(chains=2, seed=0, session_dir=folder)
    ctl.run_sweeps(2)
    ctl.set_sigma(0.08)
    ctl.pause(1)
    ctl.run_sweeps(1)
    ctl.save()
    assert sorted(p.name for p in folder.iterdir()) == sorted(sess.FILES + (sess.LOCK_FILE,))
    with np.load(folder / "record.npz", allow_pickle=False) as z:
        assert z["c0_samples"].shape == (3, len(NAMES)) and z["c1_samples"].shape == (2, len(NAMES))
    for name in ("scene.json", "tracks.json", "settings.json", "events.json", "chains.json"):
        json.loads((folder / name).read_text())
    ctl.close()    # (its lock let go: one controller on a session at a time)
    back = Controller.load(folder, workers=1)
    try:
        same_chains(ctl, back)
        assert back.map() == ctl.map() and back.events == ctl.events
        assert back.chain_ids() == ctl.chain_ids() and back.settings == ctl.settings
        a, b = ctl.status(), back.status()
        for k in ("rounds", "sweeps", "proposals", "accepted", "chains", "acceptance", "r_hat", "map"):
            assert a[k] == b[k], k
    finally:
        back.close()


@pytest.mark.parametrize("workers", [1, 2])
def test_resumed_session_equals_an_uninterrupted_run(make, tmp_path, workers):
    """6 sweeps, a sigma change (logdensities left stale), save, load, 4 more == 10 in one go."""
    first = make(chains=2, seed=7, workers=workers, session_dir=tmp_path / "s")
    first.run_sweeps(6)
    first.set_sigma(0.07)
    first.close()
    resumed = Controller.load(tmp_path / "s", workers=workers)
    try:
        resumed.run_sweeps(4)
        whole = make(chains=2, seed=7, workers=workers)
        whole.run_sweeps(6)
        whole.set_sigma(0.07)
        whole.run_sweeps(4)
        same_chains(resumed, whole)
        assert resumed.map() == whole.map()
        strip = [{k: v for k, v in e.items() if k != "time"} for e in whole.events]
        assert [{k: v for k, v in e.items() if k != "time"} for e in resumed.events] == strip
    finally:
        resumed.close()


def test_a_crash_between_two_files_loads_the_last_complete_state(make, tmp_path):
    """chains.json is written last: with older chains.json beside newer record, events and
    settings (a crash in between), the session loads as of that chains.json and goes on as if
    the later sweeps had never happened."""
    ctl = make(chains=2, seed=5, session_dir=tmp_path / "s")
    ctl.run_sweeps(2)
    ctl.save()
    committed = (tmp_path / "s" / "chains.json").read_bytes()
    ctl.set_sigma(0.09)
    ctl.set_bounds("k2", 0.1, 0.9)
    ctl.run_sweeps(2)
    ctl.close()
    (tmp_path / "s" / "chains.json").write_bytes(committed)
    back = Controller.load(tmp_path / "s", workers=1)
    try:
        assert [len(back.samples(c)) for c in (0, 1)] == [2, 2]
        assert [e["kind"] for e in back.events] == ["init"] and back.settings.noise == 0.05
        back.run_sweeps(2)
        whole = make(chains=2, seed=5)
        whole.run_sweeps(4)
        same_chains(back, whole)
    finally:
        back.close()


@pytest.fixture
def saved_session(make, tmp_path):
    ctl = make(chains=2, seed=0, session_dir=tmp_path / "good")
    ctl.run_sweeps(2)
    ctl.close()
    return tmp_path / "good"


@pytest.mark.parametrize("name, damage", [
    ("record.npz", "truncate"), ("record.npz", "garbage"), ("record.npz", "site"), ("chains.json", "move"),
    ("chains.json", "move_index"), ("chains.json", "widths"), ("events.json", "moves"), ("chains.json", "invalid"),
    ("events.json", "invalid"), ("settings.json", "invalid"), ("scene.json", "invalid"),
    ("tracks.json", "invalid"), ("chains.json", "wrong"), ("settings.json", "wrong"),
    ("scene.json", "wrong"), ("tracks.json", "wrong"), ("events.json", "missing"), ("record.npz", "missing"),
])
def test_damaged_session_is_a_one_line_error_naming_the_file(saved_session, tmp_path, name, damage):
    folder = tmp_path / "bad"
    shutil.copytree(saved_session, folder)
    path = folder / name
    if damage == "truncate":
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    elif damage == "garbage":
        path.write_bytes(b"not a zip file")
    elif damage == "site":     # a proposal site that is neither a latent nor one of the joint moves
        with np.load(path) as z:
            rec = {k: z[k] for k in z.files}
        rec["c0_site"][1] = -9
        path.write_bytes(sess.npz_bytes(rec))
    elif damage in ("move", "move_index", "widths", "moves"):
        d = json.loads(path.read_text())
        if damage == "move":
            d["move_table"][d["chains"][0]["moves"][-1]]["chol"] = [[1.0]]
        elif damage == "move_index":
            d["chains"][0]["moves"][-1] = len(d["move_table"])
        elif damage == "widths":
            d["chains"][0]["proposal"]["narrow"] = [0.1, -1.0, 0.1, 0.1]
        else:
            d["events"][0]["detail"]["moves"] = "fancy"
        path.write_text(json.dumps(d))
    elif damage == "invalid":
        path.write_text(path.read_text()[:-20])
    elif damage == "wrong":
        d = json.loads(path.read_text())
        if name == "chains.json":
            d["chains"][0]["rng"] = "nope"
        elif name == "settings.json":
            d["sigma_mps"] = -1
        elif name == "scene.json":
            d["objects"][0]["mass_kg"] = "heavy"
        else:
            del d["objects"]
        path.write_text(json.dumps(d))
    else:
        path.unlink()
    with pytest.raises(GalileoError) as e:
        Controller.load(folder, workers=1)
    msg = str(e.value)
    assert name in msg and "\n" not in msg and e.value.__cause__ is None


def test_a_session_recorded_before_moves_replays_as_the_paper_kernel(make, tmp_path):
    """A session without a move set, adapted widths or per-sample noise (recorded before them)
    opens as the paper's kernel, each sample's sigma read from the sigma events, and goes on
    exactly as it would have."""
    old = make(chains=2, seed=6, moves="paper", sweeps=None, session_dir=tmp_path / "s")
    old.run_sweeps(2)
    old.set_sigma(0.08)
    old.run_sweeps(1)
    old.add_chains(1)
    old.run_sweeps(1)
    old.close()
    folder = tmp_path / "s"
    doc = json.loads((folder / "chains.json").read_text())
    for k in ("moves", "warmup", "adapt_until", "target_sweeps", "until"):
        del doc[k]
    for ch in doc["chains"]:
        for k in ("held", "proposal", "moves"):
            del ch[k]
    (folder / "chains.json").write_text(json.dumps(doc))
    ev = json.loads((folder / "events.json").read_text())
    for k in ("moves", "warmup", "joint_moves", "sweeps", "until"):
        del ev["events"][0]["detail"][k]
    (folder / "events.json").write_text(json.dumps(ev))
    with np.load(folder / "record.npz") as z:
        rec = {k: z[k] for k in z.files if not k.endswith("_noise")}
    (folder / "record.npz").write_bytes(sess.npz_bytes(rec))

    back = Controller.load(folder, workers=1)
    try:
        assert back.status()["moves"]["set"] == "paper" and back.target_sweeps is None
        assert [list(back.sample_noise(c)) for c in (0, 1, 2)] == [[0.05, 0.05, 0.08, 0.08]] * 2 + [[0.08]]
        back.run_sweeps(2)
        whole = make(chains=2, seed=6, moves="paper", sweeps=None)
        whole.run_sweeps(2)
        whole.set_sigma(0.08)
        whole.run_sweeps(1)
        whole.add_chains(1)
        whole.run_sweeps(3)
        same_chains(back, whole)
        assert back.map() == whole.map()
    finally:
        back.close()


def test_missing_session_folder(tmp_path):
    with pytest.raises(GalileoError, match="session folder not found"):
        Controller.load(tmp_path / "nowhere", workers=1)


def test_a_session_folder_is_not_overwritten(saved_session, demo):
    with pytest.raises(GalileoError, match="already holds a session"):
        Controller(*demo, chains=1, workers=1, session_dir=saved_session)


# -- the background thread -----------------------------------------------------------------------------------

def test_start_stop_in_the_background(demo, make, tmp_path):
    ctl = make(chains=2, seed=0, workers=2, session_dir=tmp_path / "bg", save_every_s=0.2)
    heard = []
    main = threading.get_ident()
    ctl.add_listener(lambda kind, payload: heard.append((kind, payload, threading.get_ident())))
    rounds_seen = threading.Condition()
    done = [0]

    def count(kind, payload):
        if kind == "sweeps":
            with rounds_seen:
                done[0] = payload["round"]
                rounds_seen.notify_all()
    ctl.add_listener(count)

    def wait_rounds(k):
        with rounds_seen:
            assert rounds_seen.wait_for(lambda: done[0] >= k, timeout=60), f"round {k} never came"

    # the runner thread is held in its listener after round `hold_at` while stop() is asked
    hold_at, held, release = [None], threading.Event(), threading.Event()

    def hold(kind, payload):
        if kind == "sweeps" and payload["round"] == hold_at[0]:
            held.set()
            assert release.wait(60)
    ctl.add_listener(hold)

    ctl.start()
    assert ctl.running
    wait_rounds(3)
    ctl.set_sigma(0.08)          # while rounds run: applies between two of them
    hold_at[0] = ctl.status()["rounds"] + 2
    assert held.wait(60)
    stopper = threading.Thread(target=ctl.stop)
    stopper.start()
    assert wait_until(ctl._stop_evt.is_set, 60)     # stop() has asked; the runner is still held
    release.set()
    stopper.join(120)
    # stop lets the round that was under way finish and starts no other
    assert not stopper.is_alive() and not ctl.running and ctl.status()["rounds"] == hold_at[0]
    assert ctl.status()["error"] is None

    ev = next(e for e in ctl.events if e["kind"] == "sigma")
    k = ev["chain_sweeps"]["0"]
    s, ll = ctl.samples(0), ctl.logliks(0)
    assert 3 <= k < len(s)
    assert (ll[k - 1] == lik_at(demo, 0.05, s[k - 1], ctl.moves_set)
            and ll[k] == lik_at(demo, 0.08, s[k], ctl.moves_set))

    # listeners: from the runner thread, sweeps of every round and the event in order
    rounds = [p for kind, p, _ in heard if kind == "sweeps"]
    assert [p["round"] for p in rounds] == list(range(1, ctl.status()["rounds"] + 1))
    assert all(tid != main for kind, _, tid in heard if kind == "sweeps")
    kinds = [(kind, p.get("kind")) for kind, p, _ in heard]
    assert ("event", "sigma") in kinds and kinds[0] == ("event", "init")
    sigma_at = kinds.index(("event", "sigma"))
    assert [p["round"] for kind, p, _ in heard[:sigma_at] if kind == "sweeps"][-1] == ev["sweep"]
    chain, sweep, loglik, values = rounds[-1]["results"][0]
    assert chain == 0 and sweep == len(s) and loglik == ll[-1] and values == ctl.sample(0, -1)

    # the session on disk is complete
    ctl.close()
    back = Controller.load(tmp_path / "bg", workers=1)
    try:
        same_chains(ctl, back)
        assert back.events == ctl.events and back.map() == ctl.map()
    finally:
        back.close()


def test_a_saves_move_table_keeps_moves_apart_by_type_and_value():
    """chains.json's move table (`_table_index`): the same move in two chains is written once;
    two moves of different types with equal fields (equal as tuples) are two entries; a move
    holding a list (unhashable) is keyed by its JSON."""
    from typing import NamedTuple

    from galileo.mcmc import LogScale
    from ui.controller import _table_index

    class Twin(NamedTuple):      # LogScale's fields, another type
        sites: tuple
        signs: tuple
        width: float
        every: int = 1
        name: str = "log_scale"

    table: dict = {}
    a, b = LogScale((0, 2), (1.0, 1.0), 0.1), LogScale((0, 2), (1.0, 1.0), 0.1)
    assert _table_index(table, a) == _table_index(table, b) == 0
    twin = Twin(*a)
    assert twin == a and _table_index(table, twin) == 1
    listed = LogScale([0, 2], [1.0, -1.0], 0.3)
    assert _table_index(table, listed) == 2 == _table_index(table, LogScale([0, 2], [1.0, -1.0], 0.3))
    assert [type(m) for _, m in table.values()] == [LogScale, Twin, LogScale]
