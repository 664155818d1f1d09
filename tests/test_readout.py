"""Readouts of any named latents (`galileo.readout.Readout`): a scenario says which quantity a
recognition model's reading starts which latent, with the scale from the quantity to the latent;
the recognition init's independence move puts each reading on its latent, scaled; a quantity
the model does not read leaves its latent on the prior, with an info line."""
from __future__ import annotations

import logging
import math

import numpy as np
import pytest

from galileo import registry
from galileo.readout import Readout
from galileo.recognition.model import Reading, independence, recognition_init
from scenarios.drop import DropScenario, DropScene

# what the stub model reads of the ball: a mass, no friction, and two quantities beyond the LeNet's
LOG_MASS, LOG_MASS_SD = math.log(0.05), 0.3
RESTITUTION, RESTITUTION_SD = 0.55, 0.04
LOG_STIFFNESS_NPM, LOG_STIFFNESS_SD = math.log(40.0), 0.2
KN_PER_N = 1e-3        # the scenario's stiffness latent is in kN/m
NAMES = ["e", "k_kn_per_m", "e_percent", "q_c"]
BOUNDS = np.array([[0.0, 1.0], [0.001, 0.2], [0.0, 100.0], [-1.0, 1.0]])


class ReadDrop(DropScenario):
    """The drop, with a readout of the ball's restitution (as e), its stiffness (in kN/m) and its
    charge (which no model reads), and of a second object's restitution in percent."""

    def readouts(self, prepared_scene):
        return (Readout("ball", {"restitution": ("e", 1.0), "stiffness_npm": ("k_kn_per_m", KN_PER_N),
                                 "charge_c": ("q_c", 1.0)}),
                Readout("hook", {"restitution": ("e_percent", 100.0)}))


class StubModel:
    """A model with a stiffness and a restitution head: its reading of each read object."""
    kind = "lenet"
    meta = {"kind": "lenet", "labels": "test"}

    def read_video(self, video, scene, tracks):
        others = {"restitution": ("normal", RESTITUTION, RESTITUTION_SD),
                  "stiffness_npm": ("lognormal", LOG_STIFFNESS_NPM, LOG_STIFFNESS_SD)}
        return {role: Reading(role, LOG_MASS, LOG_MASS_SD, None, None, 3, others) for role in ("ball", "hook")}


@pytest.fixture()
def read_drop():
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(registry, "_loaded", dict(registry._loaded))
        yield registry.register(ReadDrop())


def test_a_third_quantity_reaches_the_independence_move_on_its_latent_scaled(read_drop, caplog):
    """The recognition init's independence move (and the chains' starts) carry the restitution
    reading N(0.55, 0.04^2) as e, N(55, 4^2) as e in percent, and the log-normal stiffness
    reading (median 40 N/m) as ln k ~ N(ln 0.04, 0.2^2) for k in kN/m; the charge, which the
    model does not read, keeps its prior, and an info line says so."""
    scene = DropScene()
    init = recognition_init(StubModel(), "video.mp4", scene, None, move_every=3, source="stub")
    with caplog.at_level(logging.INFO, logger="galileo.recognition.model"):
        out = init(scene, NAMES, BOUNDS, 400, 0, ())
    q = out.independence
    assert q.every == 3
    assert q.kinds == ("normal", "lognormal", "normal", "uniform")
    np.testing.assert_allclose(q.loc, [0.55, math.log(0.04), 55.0, -1.0], rtol=1e-12)
    np.testing.assert_allclose(q.scale, [0.04, 0.2, 4.0, 1.0], rtol=1e-12)
    assert "the model does not read the ball object's charge_c; q_c starts from its prior" in caplog.text
    assert out.info["proposal"] == {"kinds": list(q.kinds), "loc": list(q.loc), "scale": list(q.scale)}
    assert out.info["readings"]["ball"]["stiffness_npm"] == {"kind": "lognormal", "mean": LOG_STIFFNESS_NPM,
                                                            "sd": LOG_STIFFNESS_SD}
    # the starts are draws from it: 400 chains' medians within 4 standard errors of the reading's
    starts = out.starts
    se = 1.2533 / math.sqrt(len(starts))     # the SE of a median, in SDs
    assert abs(np.median(starts[:, 0]) - 0.55) < 4 * se * 0.04
    assert abs(np.median(np.log(starts[:, 1])) - math.log(0.04)) < 4 * se * 0.2
    assert abs(np.median(starts[:, 3])) < 4 / math.sqrt(len(starts))     # U(-1, 1): median 0, SE 1 / sqrt(n)


def test_the_ramp_readings_start_the_same_latents_as_before(demo_frozen):
    """The ramp's readouts read mass and friction into m1_kg, k1 (and m2_kg, k2) unscaled: a
    log-normal with the reading's log mean and SD, a normal with its friction and SD (at least
    1e-3). (The splash's density: tests/test_splash_recognition.py.)"""
    scene, _, _ = demo_frozen
    ramp = registry.get("ramp")
    lats = ramp.latents(scene)
    names = [lat.name for lat in lats]
    bounds = np.array([lat.bounds for lat in lats], float)
    read = {"ramp": Reading("ramp", math.log(0.03), 0.25, 0.31, 0.02, 4),
            "target": Reading("target", math.log(0.08), 0.5, 0.42, 0.0001, 4)}
    q = independence(read, ramp, scene, names, bounds)
    got = {n: (q.kinds[j], q.loc[j], q.scale[j]) for j, n in enumerate(names)}
    assert got == {"m1_kg": ("lognormal", math.log(0.03), 0.25), "k1": ("normal", 0.31, 0.02),
                   "m2_kg": ("lognormal", math.log(0.08), 0.5), "k2": ("normal", 0.42, 1e-3),
                   "e_collision": ("uniform", 0.0, 1.0)}   # no readout reads a restitution: its prior
    assert [(r.role, r.mass, r.friction, r.mass_per_kg) for r in ramp.readouts(scene)] == \
        [("ramp", "m1_kg", "k1", 1.0), ("target", "m2_kg", "k2", 1.0)]


def test_a_readout_checks_its_latents_and_scales():
    r = Readout("object", {"mass_kg": ("density_g_cm3", 0.25)})
    assert (r.latent("mass_kg"), r.mass, r.friction, r.mass_per_kg) == ("density_g_cm3", "density_g_cm3", None, 0.25)
    assert r.latent("stiffness_npm") is None and Readout("object").reads == {}
    for bad in (("k", 0.0), ("k", -1.0), ("k", math.nan), ("", 1.0), (None, 1.0)):
        with pytest.raises(ValueError, match="must map to a latent's name and a scale > 0"):
            Readout("object", {"stiffness_npm": bad})
