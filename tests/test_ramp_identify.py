"""What a ramp video identifies (`galileo.scenarios.ramp.identify`), against Newton: the
physics the rule rests on (masses scale out of a slide, a common factor on both masses out of
a collision), the rule itself, and a result that gives no point estimate for what it names."""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from galileo import registry
from galileo.datatypes import Tracks
from galileo.runner import RunConfig, infer
from galileo.scenarios.ramp.identify import moves, not_identified
from galileo.scenarios.ramp.tracking import held_still

DATA = Path(__file__).parent / "data"
RAMP = registry.get("ramp")


def _scene():
    return RAMP.load_scene(DATA / "scene.json")


def _no_target(scene):
    return dataclasses.replace(scene, objects=(scene.ramp_object,))


def _paths(scene, values, n=60):
    return RAMP.simulate(scene, n, values).position_m


def test_masses_scale_out_of_the_motion_as_newton_says():
    # the premise of the rule: a slide does not depend on the sliding mass, a collision only on the ratio
    scene = _scene()
    base = {"m1_kg": 0.2, "k1": 0.1, "m2_kg": 0.1, "k2": 0.3}
    both = _paths(scene, base)
    assert np.ptp(both[1], axis=0).max() > 0.01   # the target is hit and moves
    scaled = _paths(scene, {**base, "m1_kg": 0.6, "m2_kg": 0.3})
    np.testing.assert_allclose(scaled, both, atol=2e-4)
    other_ratio = _paths(scene, {**base, "m2_kg": 0.4})
    assert np.abs(other_ratio[1] - both[1]).max() > 0.01   # the ratio does show
    alone = _no_target(scene)
    one = {"m1_kg": 0.2, "k1": 0.1}
    np.testing.assert_allclose(_paths(alone, {**one, "m1_kg": 1.0}), _paths(alone, one), atol=2e-4)


def test_the_rule_per_video_and_problem():
    scene = _scene()
    assert set(not_identified([scene], {})) == {"m1_kg", "m2_kg"}            # a collision: the ratio only
    assert not_identified([scene], {"m2_kg": 0.1}) == {}                       # a mass fixed weighs the other
    assert set(not_identified([_no_target(scene)], {})) == {"m1_kg"}          # no target: no mass at all
    still = held_still(scene, 30)
    assert not moves(still, "ramp") and not moves(still, "target")
    out = not_identified([scene], {}, [still])
    assert set(out) == {"k1", "m1_kg", "m2_kg", "mass_ratio", "k2", "e_collision"}   # (no collision, no restitution)
    assert f"{math.tan(math.radians(scene.ramp.angle_deg)):.3f}" in out["k1"]   # the bound it does give
    two = not_identified([scene, scene], {"m2_kg@1": 0.1})
    assert set(two) == {"m1_kg@2", "m2_kg@2"}


def test_shared_latents_are_identified_by_any_of_their_videos():
    """A shared mass carries a weighing from one collision into another: the same block (m1 shared)
    hits a weighed box in video 1 and an unweighed one in video 2, so both boxes are weighed; a
    shared k1 is identified by the video in which the block slides, though the other holds it
    still. Without the reference every mass is unweighed (the ratios only)."""
    scene = _scene()
    assert not_identified([scene, scene], {"m2_kg@1": 0.137}, share=("m1_kg", "k1")) == {}
    assert set(not_identified([scene, scene], {}, share=("m1_kg", "k1"))) == {"m1_kg", "m2_kg@1", "m2_kg@2"}
    assert set(not_identified([scene, scene], {"m2_kg@1": 0.137})) == {"m1_kg@2", "m2_kg@2"}   # (nothing shared)
    still = held_still(scene, 30)
    moving = Tracks.load(DATA / "tracks.json")   # (the demo: the block slides and hits the box)
    out = not_identified([scene, scene], {"m2_kg": 0.1}, [still, moving], share=("k1",))
    assert "k1" not in out and {"m1_kg@1", "k2@1", "mass_ratio@1"} <= set(out)
    assert "k1" in not_identified([scene, scene], {"m2_kg": 0.1}, [still, still], share=("k1",))


def test_a_still_video_gets_no_mass_ratio_and_no_interval():
    scene = _scene()
    still = held_still(scene, 30)
    res = infer(scene, still, RunConfig(chains=2, sweeps=6, seed=0, workers=1), progress=False)
    doc = res.to_json()
    assert doc["mass_ratio"] is None
    assert "mass_ratio" not in doc["posterior_derived"] and "log_mass_ratio" not in doc["posterior_derived"]
    assert {"k1", "mass_ratio", "m1_kg", "m2_kg"} <= set(doc["not_identified"])
    # the k1 the chains drew respects the bound the rule states
    assert doc["posterior"]["k1"]["q05"] >= math.tan(math.radians(scene.ramp.angle_deg)) - 1e-9


def test_the_app_shows_no_mass_ratio_for_a_still_video():
    from ui.controller import Controller

    scene = _scene()
    ctl = Controller(scene, held_still(scene, 30), chains=2, seed=0, workers=1, sweeps=6)
    try:
        ctl.run_sweeps(6)
        derived = ctl.status()["derived"]
        assert "mass_ratio" not in derived and "log_mass_ratio" not in derived
    finally:
        ctl.close()
