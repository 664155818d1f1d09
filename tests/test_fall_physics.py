"""The fall's physics against Newton, Poisson's restitution and Coulomb's friction (issue 27):
free fall, bounce heights against e^2 for a box landing flat and a cylinder landing on its side,
a box sliding to rest against v^2 / (2 mu g); mass changes nothing; energy never grows; and
inference on the likelihood's own observations."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from galileo import registry
from galileo.errors import SceneError
from galileo.scenarios.fall import physics
from galileo.scenarios.fall.scene import FallScene, default_scene
from galileo.shapes import Shape

G = 9.81
BOX = Shape("box", (0.08, 0.05, 0.04))
CYLINDER = Shape("cylinder", (0.10, 0.05, 0.05))


def fine_run(shape: Shape, seconds: float, hz: float = 240.0, **values) -> np.ndarray:
    """Every physics step's centre (N, 3) of a scene released at frame 0."""
    n = int(round(seconds * hz))
    s = FallScene(shape=shape, fps=hz, sim_hz=hz, n_frames=n, release_frame=0, **values)
    return physics.simulate(s, n).position_m[0]


def apexes(z: np.ndarray, rest_z: float, n: int) -> list[float]:
    """The heights above `rest_z` of the first n maxima of z after it first stops falling."""
    out = []
    i = int(np.argmax(np.diff(z) > 0))
    for f in range(i + 1, len(z) - 1):
        if z[f] > z[f - 1] and z[f] >= z[f + 1] and z[f] - rest_z > 1e-4:
            out.append(float(z[f] - rest_z))
            if len(out) == n:
                break
    return out


def test_free_fall_follows_newton():
    """Released at rest 0.5 m up, the centre falls g t^2 / 2 (1% of the drop, every step before it lands)."""
    z = fine_run(BOX, 0.3, z0_m=0.52)[:, 2]
    t = np.arange(len(z)) / 240.0
    falling = 0.52 - 0.5 * G * t ** 2 > 0.03
    drop = 0.5 * G * t[falling] ** 2
    np.testing.assert_allclose(0.52 - z[falling], drop, rtol=0.01, atol=1e-6)


def test_free_fall_with_a_throw_follows_newton():
    """Thrown up at 1 m/s and sideways at 0.5 m/s: z0 + v t - g t^2 / 2 and x0 + u t (1% of the path)."""
    pos = fine_run(BOX, 0.25, z0_m=0.5, vz0_mps=1.0, vx0_mps=0.5)
    t = np.arange(len(pos)) / 240.0
    np.testing.assert_allclose(pos[:, 2], 0.5 + t - 0.5 * G * t ** 2, atol=0.01 * 0.3)
    np.testing.assert_allclose(pos[:, 0], 0.5 * t, atol=0.01 * 0.125)


@pytest.mark.parametrize("shape,rest_z", [(BOX, 0.02), (CYLINDER, 0.025)])
@pytest.mark.parametrize("e", [0.3, 0.5, 0.7])
@pytest.mark.parametrize("drop_m", [0.17, 0.3, 0.43])
def test_bounce_heights_follow_e_squared(shape, rest_z, e, drop_m):
    """Landing flat (a box on its face, a cylinder on its side), the first bounce rises e^2 times the
    drop and the second e^2 times the first (2%), whatever the drop (where the contact falls in a step)."""
    z = fine_run(shape, 1.2, restitution=e, z0_m=drop_m + rest_z)[:, 2]
    first, second = apexes(z, rest_z, 2)
    assert first == pytest.approx(e * e * drop_m, rel=0.02)
    assert second == pytest.approx(e * e * first, rel=0.02 if e >= 0.5 else 0.05)


def test_a_dead_object_does_not_bounce():
    z = fine_run(BOX, 0.6, restitution=0.0, z0_m=0.32)[:, 2]
    landed = int(np.argmax(z < 0.0205))
    assert z[landed:].max() < 0.0205


@pytest.mark.parametrize("mu", [0.2, 0.5])
@pytest.mark.parametrize("speed", [0.6, 1.2])
def test_a_sliding_box_stops_after_v2_over_2_mu_g(mu, speed):
    """A box set down on its face sliding at v stops v^2 / (2 mu g) further on (2%)."""
    pos = fine_run(BOX, 1.0, friction=mu, z0_m=0.02, vx0_mps=speed, restitution=0.0)
    assert pos[-1, 0] == pytest.approx(physics.slide_distance_m(speed, mu), rel=0.02)
    assert abs(pos[-1, 1]) < 5e-4 and pos[-1, 2] == pytest.approx(0.02, abs=5e-4)


def test_mass_changes_nothing():
    """A rigid object's tumble on a fixed surface is the same for any mass (it is not identified):
    a drop and a tumble to within 2 mm (the solver's rounding, grown by
    the tumble; a mass that mattered would move it centimetres)."""
    for s, tol in ((dataclasses.replace(default_scene(), roll0_rad=0.0, pitch0_rad=0.0, wy0_radps=0.0), 2e-3),
                   (dataclasses.replace(default_scene(), roll0_rad=0.4, wz0_radps=3.0), 2e-3)):
        a = physics.simulate(s, s.n_frames).position_m
        b = physics.simulate(dataclasses.replace(s, mass_kg=s.mass_kg * 7.3), s.n_frames).position_m
        np.testing.assert_allclose(a, b, atol=tol)
    rec = registry.get("fall").not_identified([s], {})
    assert list(rec) == [f"m_{s.object}_kg"]


@pytest.mark.parametrize("seed", range(6))
def test_energy_never_grows(seed):
    """Tumbling landings from random releases: kinetic + potential energy never rises above the
    release's, and no step adds more than the lift out of the surface can (g x 2 mm: a corner
    meets the surface up to a step's travel in, and is lifted out by the shape's depth)."""
    rng = np.random.default_rng(seed)
    s = dataclasses.replace(default_scene(), release_frame=0, restitution=float(rng.uniform(0.1, 0.9)),
                            friction=float(rng.uniform(0.1, 1.0)), roll0_rad=float(rng.uniform(-0.5, 0.5)),
                            pitch0_rad=float(rng.uniform(-0.5, 0.5)), wx0_radps=float(rng.uniform(-4, 4)),
                            wy0_radps=float(rng.uniform(-4, 4)), n_frames=240, fps=240.0, camera=None)
    with physics.client_lock:
        run = physics.Run(physics.params(s), s.shape, s.sim_hz, s.fps, 0)
        inertia = s.shape.inertia_per_kg()
        energies = []
        for f in range(s.n_frames):
            pos, orn, vel, spin = run.frame(f)
            rot = np.array(physics.pb.getMatrixFromQuaternion(orn)).reshape(3, 3)
            w_body = rot.T @ np.asarray(spin)
            v_now = np.array(vel) - (0.0, 0.0, 0.5 * G / s.sim_hz)   # the stored velocity is half a step behind
            energies.append(0.5 * np.dot(v_now, v_now) + 0.5 * np.dot(inertia * w_body, w_body) + G * pos[2])
    grows = np.diff(energies)
    assert grows.max() < G * 0.002, f"energy grew by {grows.max():.2g} J/kg in a step"
    assert max(energies) <= energies[0] + G * 0.002
    assert energies[-1] < energies[0]


def test_a_release_inside_the_surface_is_refused():
    s = dataclasses.replace(default_scene(), z0_m=0.01)
    with pytest.raises(SceneError, match="inside the surface"):
        physics.simulate(s, 10)


def test_near_the_truth_the_posterior_pins_the_bounce(monkeypatch):
    """Synthetic tracks of a tumbling drop (2 px AR(1) noise), chains started at the truth (the search
    that starts them elsewhere is `search`'s business): the likelihood's 90% intervals of e and mu cover
    their truths and are far narrower than their priors."""
    from galileo.runner import RunConfig, infer
    from galileo.scenarios.fall import tracks as fall_tracks

    sc = registry.get("fall")
    s = dataclasses.replace(default_scene(), restitution=0.5, friction=0.4)
    tracks = sc.synthetic.tracks(s, {"log10_sigma_px": 0.3, "rho": 0.5}, np.random.default_rng(0), 0.0)
    prepare = fall_tracks.prepare

    def at_truth(scene, tr):
        p = prepare(scene, tr)
        bu = {k: v for k, v in p.bottom_up.items() if not k.startswith("fit")}
        bu.update({f"fit0_{k}": float(np.clip(v, *p.priors.get(k, (-np.inf, np.inf))))
                   for k, v in s.latents().items()})
        return dataclasses.replace(p, bottom_up=bu)

    monkeypatch.setattr(fall_tracks, "prepare", at_truth)
    res = infer(s, tracks, RunConfig(chains=4, sweeps=40, seed=0, workers=1), progress=False)
    post = res.posterior()
    for name, truth in (("e_block_table", 0.5), ("mu_block_table", 0.4)):
        assert post[name]["q05"] <= truth <= post[name]["q95"], (name, post[name])
        assert post[name]["q95"] - post[name]["q05"] < 0.3, (name, post[name])     # the priors' are 0.93, 1.48
