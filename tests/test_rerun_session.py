"""ui.rerun_log.ControllerFeed: a session's recording as the app writes it, live and reopened
(issue 14, defect 5: a reopened session's session.rrd must continue the old one), and the
MAP's simulated motion (defect 9)."""
from __future__ import annotations

import numpy as np
import pytest

rr = pytest.importorskip("rerun")
pytest.importorskip("rerun.chunk")   # needs rerun-sdk[catalog]

from test_rerun_log import read_rrd, series  # noqa: E402
from ui.controller import Controller  # noqa: E402
from ui.rerun_log import RRD_NAME, ControllerFeed, RerunLogger, _sweeps_at  # noqa: E402

EVERY = 2   # rounds between posterior / R-hat / MAP logs (the app: the number of chains)


def record(ctrl: Controller, folder) -> tuple[RerunLogger, ControllerFeed]:
    """What app.py sets up: a logger in the session folder and the feed as the listener."""
    logger = RerunLogger("save", session_dir=folder, latents=list(ctrl.names), n_chains=len(ctrl.all_chain_ids()))
    feed = ControllerFeed(logger, ctrl, every=EVERY)
    return logger, feed


def rows(ents, entity: str, column: str = "Scalars:scalars") -> list[tuple[int, float]]:
    return [(t, v[0]) for t, v in series(ents, entity, "sweep", column)]


def test_reopened_session_recording_continues_the_old_one(demo_frozen, tmp_path):
    scene, tracks, _ = demo_frozen
    folder = tmp_path / "s"
    # live: chain 1 paused for two rounds (the chains' sweeps then differ from the rounds),
    # both held at the sweep target 12, a chain added
    ctrl = Controller(scene, tracks, chains=2, seed=3, workers=1, session_dir=folder, sweeps=12)
    logger, feed = record(ctrl, folder)
    ctrl.add_listener(feed.on_controller)
    ctrl.run_sweeps(5)
    ctrl.pause(1)
    ctrl.run_sweeps(2)
    ctrl.resume(1)
    ctrl.run_sweeps(9)            # chain 0 held at 12 (round 12), chain 1 at round 14
    added = ctrl.add_chains(1)
    ctrl.run_sweeps(3)            # only the new chain runs
    ctrl.close()
    logger.close()
    live = read_rrd(folder / RRD_NAME)
    (folder / RRD_NAME).rename(folder / "session.before.rrd")   # as app.py keeps it

    back = Controller.load(folder, workers=1)
    n_before = {c: len(back.samples(c)) for c in back.all_chain_ids()}
    assert n_before == {0: 12, 1: 12, added[0]: 3}
    logger, feed = record(back, folder)
    feed.log_history()
    back.add_listener(feed.on_controller)
    back.resume()
    back.set_chain(0, {"k1": 0.4})
    back.run_sweeps(4)
    back.close()
    logger.close()
    ents = read_rrd(folder / RRD_NAME)

    for c in back.all_chain_ids():
        ll = back.logliks(c)
        assert len(ll) == n_before[c] + 4
        got = rows(ents, f"chains/{c}/loglik")
        # every sweep from 1, no gap, no duplicate, the controller's values
        assert [t for t, _ in got] == list(range(1, len(ll) + 1))
        assert [v for _, v in got] == ll.tolist()
        for j, name in enumerate(back.names):
            assert [v for _, v in rows(ents, f"chains/{c}/{name}")] == back.samples(c)[:, j].tolist()
        # the history is what the live run logged
        assert rows(live, f"chains/{c}/loglik") == got[:n_before[c]]
    # every event once, at its sweep
    texts = series(ents, "events", "sweep", "TextLog:text")
    assert [(t, x[0].split(":")[0]) for t, x in texts] == [(e["sweep"], e["kind"]) for e in back.events]
    assert [x[0].split(":")[0] for _, x in texts].count("add_chains") == 1
    # R-hat: the live run's rows, recomputed from the samples, then the new ones
    r_hats = 0
    for name in back.names:       # (a latent that never moved has none)
        before = rows(live, f"diagnostics/r_hat/{name}")
        now = rows(ents, f"diagnostics/r_hat/{name}")
        assert [t for t, _ in now[:len(before)]] == [t for t, _ in before]
        np.testing.assert_allclose([v for _, v in now[:len(before)]], [v for _, v in before], rtol=1e-12)
        r_hats += len(before)
    assert r_hats >= 3
    assert rows(ents, "diagnostics/converged")[:len(rows(live, "diagnostics/converged"))] == \
        rows(live, "diagnostics/converged")
    # the posterior and the MAP's motion, in both
    for e in (live, ents):
        assert any("BarChart:values" in cols for _, cols in e[f"posterior/{back.names[0]}"])
        assert series(e, f"sim/map/{back.likelihood_scene.objects[0].name}", "sweep", "LineStrips3D:strips")


def test_map_motion_logged_when_the_map_changes(demo_frozen, tmp_path):
    """sim/map/<object>: the MAP sample's motion (the scenario's likelihood's, the viewer's
    own), logged from the feed's thread only when the MAP (chain, index) changed."""
    from galileo import registry

    scene, tracks, _ = demo_frozen
    ctrl = Controller(scene, tracks, chains=2, seed=0, workers=1, sweeps=None)
    logger = RerunLogger("save", session_dir=tmp_path, latents=list(ctrl.names), n_chains=2)
    feed = ControllerFeed(logger, ctrl, every=EVERY)
    ctrl.add_listener(feed.on_controller)
    maps = []
    for _ in range(4):
        ctrl.run_sweeps(EVERY)
        maps.append(ctrl.map())
    feed.request_map(ctrl.status()["rounds"])       # again, unchanged: not logged again
    ctrl.close()
    logger.close()                                   # waits for the feed's thread
    ents = read_rrd(tmp_path / RRD_NAME)
    lik_scene = ctrl.likelihood_scene
    model = registry.of(lik_scene).likelihood(lik_scene, tracks, ctrl.settings.noise)
    last = maps[-1]
    traj = model.motion(np.array([last[2][n] for n in ctrl.names]))
    changes = len({(m[0], m[1]) for m in maps})
    for j, name in enumerate(traj.names):
        strips = series(ents, f"sim/map/{name}", "sweep", "LineStrips3D:strips")
        assert 1 <= len(strips) <= changes and len({t for t, _ in strips}) == len(strips)
        np.testing.assert_allclose(np.array(strips[-1][1][0]), traj.position_m[j], atol=1e-9)
        labels = series(ents, f"sim/map/{name}", "sweep", "LineStrips3D:labels")
        assert labels[-1][1] == [f"{name} (MAP, chain {last[0]} sample {last[1]})"]


def test_chain_sweeps_at_a_past_round():
    """Between two events' snapshots a chain runs every round or none: chain 1 paused at
    round 3 and resumed at 5, chain 2 added at 4 and removed at 6 (with 2 sweeps)."""
    events = [{"sweep": 0, "kind": "init", "chain_sweeps": {"0": 0, "1": 0}},
              {"sweep": 3, "kind": "pause", "chain_sweeps": {"0": 3, "1": 3}},
              {"sweep": 4, "kind": "add_chains", "chain_sweeps": {"0": 4, "1": 3, "2": 0}},
              {"sweep": 5, "kind": "resume", "chain_sweeps": {"0": 5, "1": 3, "2": 1}},
              {"sweep": 6, "kind": "remove_chain", "chain_sweeps": {"0": 6, "1": 4}}]
    at = _sweeps_at(events, 8, {0: 8, 1: 6, 2: 2})
    assert [at(r) for r in (0, 2, 4, 5, 6, 7, 8)] == [
        {0: 0, 1: 0, 2: 0}, {0: 2, 1: 2, 2: 0}, {0: 4, 1: 3, 2: 0}, {0: 5, 1: 3, 2: 1},
        {0: 6, 1: 4, 2: 2}, {0: 7, 1: 5, 2: 2}, {0: 8, 1: 6, 2: 2}]
    # a session recorded without snapshots: the chains ran together from round 1
    assert _sweeps_at([], 5, {0: 5, 1: 3})(4) == {0: 4, 1: 3}
