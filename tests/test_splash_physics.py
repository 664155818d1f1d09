"""The splash scenario's physics against Archimedes and the drag law (closed forms), and its
shapes from (volume, bottom area)."""
import dataclasses
import math

import numpy as np
import pytest

from galileo.scenarios.splash.physics import Body, Simulator, submerged
from galileo.scenarios.splash.scene import (CM2, CM3, KINDS, Tank, default_scene, dimensions, equal_area)

G = 9.81
RHO_W = 1000.0


def _rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q   # a rotation, not a reflection


# -- shapes from (h, s) ----------------------------------------------------------------------

@pytest.mark.parametrize("kind", KINDS)
def test_dimensions_have_the_volume_and_bottom_area(kind):
    h, s = 20 * CM3, 6 * CM2
    x, y, z = dimensions(kind, h, s)
    if kind == "box":
        vol, bottom = x * y * z, x * y
        assert x == pytest.approx(y)
    elif kind == "vcyl":
        vol, bottom = math.pi * x * x / 4 * z, math.pi * x * x / 4
        assert x == pytest.approx(y)
    else:   # horizontal cylinder: length x, diameter y = z
        vol, bottom = math.pi * y * y / 4 * x, x * y
        assert y == pytest.approx(z)
    assert vol == pytest.approx(h, rel=1e-12) and bottom == pytest.approx(s, rel=1e-12)
    eq = dimensions(kind, h, equal_area(kind, h))   # the seed's start: all dimensions equal
    assert max(eq) == pytest.approx(min(eq), rel=1e-9)


def test_pairs_without_an_object_that_fits_have_no_solution():
    assert dimensions("box", 100 * CM3, 0.1 * CM2, max_dim_m=0.3) is None      # a 10 m needle
    assert dimensions("hcyl", 0.01 * CM3, 20 * CM2) is None                    # a 0.006 mm sheet
    assert dimensions("box", 27 * CM3, 9 * CM2, max_dim_m=0.3) is not None


# -- the submerged part of a mesh ---------------------------------------------------------------

@pytest.mark.parametrize("kind", KINDS)
def test_a_plane_through_the_centre_halves_any_pose(kind):
    """Central symmetry: every plane through the centre leaves half the volume below, whatever
    the rotation; and the mesh wholly below or above gives all or nothing."""
    rng = np.random.default_rng(1)
    body = Body.of(kind, 20 * CM3, 5 * CM2)
    v_mesh = body.volume_m3 / body.volume_scale
    for _ in range(5):
        tris = body.tris @ _rotation(rng).T
        v, c = submerged(tris, 0.0)
        assert v == pytest.approx(v_mesh / 2, rel=1e-9)
        assert c[2] < 0
        assert submerged(tris, 1.0)[0] == pytest.approx(v_mesh, rel=1e-12)
        assert submerged(tris, -1.0)[0] == 0.0


def test_an_upright_box_cut_at_depth_d():
    body = Body.of("box", 27 * CM3, 9 * CM2)    # 3 x 3 x 3 cm
    for d in (-0.012, -0.005, 0.0, 0.009):
        v, c = submerged(body.tris, d)
        depth = d + 0.015
        assert v == pytest.approx(9 * CM2 * depth, rel=1e-9)
        assert c[2] == pytest.approx(-0.015 + depth / 2, abs=1e-12)


# -- Archimedes and the drag law -------------------------------------------------------------------

def _held_under(scene, values, z):
    """A run's stepper with the object moved under water at height z, at rest."""
    from galileo.scenarios.splash.physics import pb

    sim = Simulator(scene)
    stepper = sim.frames(values)
    pb.resetBasePositionAndOrientation(stepper.b, [0, 0, z], stepper.geom.orn0, physicsClientId=stepper.cid)
    return sim, stepper


@pytest.mark.parametrize("kind", KINDS)
def test_a_body_of_waters_density_stays_put(kind):
    scene = default_scene(kind, 20.0, 1.0, 0.8)
    _, stepper = _held_under(scene, {}, 0.08)
    for _ in range(1000):
        stepper.step()
    pos = stepper.state()[0]
    assert abs(pos[2] - 0.08) < 0.01 and math.hypot(pos[0], pos[1]) < 0.01


def test_a_floating_box_settles_at_the_archimedes_draft():
    """A 3 cm cube of density 0.5 floats with draft m / (rho_w A) = 1.5 cm: its centre at the
    water line. Bobbing decays slowly under quadratic drag, so the mean height over the last
    2 s of 10 s is compared (2%)."""
    scene = default_scene("box", 27.0, 0.5, 1.0)
    traj = Simulator(scene).run(301)
    draft = 0.5 * 1000 * 27 * CM3 / (RHO_W * 9 * CM2)
    bottom = traj.position_m[0, -60:, 2].mean() - 0.015
    assert scene.tank.water_level_m - bottom == pytest.approx(draft, rel=0.02)


def test_terminal_velocity_matches_the_drag_law():
    """Sinking at terminal speed, weight - buoyancy = 1/2 rho_w D A v^2 (A: the bottom, the
    object falls flat): v_t = sqrt(2 (rho - rho_w) V g / (rho_w D A))."""
    deep = Tank(size_m=(0.4, 0.2, 2.2), water_level_m=2.0)
    base = default_scene("box", 27.0, 2.0, 0.9)
    scene = dataclasses.replace(base, tank=deep, release_m=(0.0, 0.0, 2.03))
    traj = Simulator(scene).run(40)
    v = -traj.velocity_mps[0, -5:, 2]
    vt = math.sqrt(2 * (2000 - 1000) * 27 * CM3 * G / (RHO_W * 0.9 * 9 * CM2))
    assert np.all(np.abs(v / vt - 1) < 0.02), (v, vt)


def test_a_denser_body_of_the_same_shape_sinks_faster():
    light, heavy = (default_scene("vcyl", 20.0, rho, 0.8, release_s=0.0) for rho in (1.3, 2.6))   # frame 0: the release
    z_light = Simulator(light).run(12).position_m[0, :, 2]
    z_heavy = Simulator(heavy).run(12).position_m[0, :, 2]
    assert z_heavy[-1] < z_light[-1] - 0.01


def test_in_air_without_drag_the_fall_is_mass_independent():
    """Before it reaches the water, an object without drag falls the same whatever its density
    (bit for bit), and as Newton says: z = z0 - g t^2 / 2 up to the step's discretisation."""
    a, b = (default_scene("box", 20.0, rho, 0.0, release_s=0.0) for rho in (0.3, 2.5))   # frame 0: the release
    ta, tb = Simulator(a).run(4), Simulator(b).run(4)
    assert np.array_equal(ta.position_m, tb.position_m)
    t = np.arange(4) / 30.0
    dt = 1 / 240
    # semi-implicit Euler: z_n = z0 - g dt^2 n (n + 1) / 2 after n steps
    n = np.arange(4) * 8
    assert np.allclose(ta.position_m[0, :, 2], a.release_m[2] - G * dt * dt * n * (n + 1) / 2, atol=1e-12)
    assert np.allclose(ta.position_m[0, :, 2], a.release_m[2] - G * t * t / 2, atol=G * dt * t.max())


def test_a_run_reproduces_itself():
    scene = default_scene("hcyl", 15.0, 0.7, 0.6)
    sim = Simulator(scene)
    one = sim.run(40)
    Simulator(default_scene("box", 5.0, 2.0, 0.3)).run(10)   # another run in between
    two = sim.run(40)
    assert np.array_equal(one.position_m, two.position_m) and np.array_equal(one.orientation_xyzw,
                                                                            two.orientation_xyzw)
