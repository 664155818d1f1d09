"""The simulator against Newton: sliding, sticking, ground friction, collisions; and its bookkeeping
(determinism, one world per geometry, the torus's hole and resting height)."""
import math

import numpy as np
import pytest

import galileo.sim.bullet as bullet
from galileo.scenarios.ramp.physics import Simulator
from galileo.scenarios.ramp.scene import default_scene
from galileo.shapes import Shape

import pybullet as pb  # after galileo.physics, which imports it quietly

BOX = Shape("box", (0.06, 0.05, 0.04))
CYLINDER = Shape("cylinder", (0.08, 0.04, 0.04))  # lying on its side, axis along the fall line
TORUS = Shape("torus", (0.08, 0.08, 0.02))         # R = 3 cm, r = 1 cm
SHAPES = {"box": BOX, "cylinder": CYLINDER, "torus": TORUS}


def slide_cases():
    for angle in (10, 20):
        for mu in (0.0, 0.1, 0.2, 0.3):
            if mu < math.tan(math.radians(angle)) - 0.02:
                yield angle, mu


def along_fall_line(scene, traj):
    """Distance travelled down the fall line since frame 0 (m), per frame."""
    p = traj.position_m[0]
    return (p - p[0]) @ scene.ramp.downhill


def newton_ramp_accel(scene, mu):
    a = scene.ramp.angle_rad
    return scene.gravity_mps2 * (math.sin(a) - mu * math.cos(a))


# -- sliding down the ramp -------------------------------------------------------------------------

# Fitted accelerations against g (sin - mu cos), measured on this pybullet:
#   box       <= 0.09 %  (worst 20 deg / 0.3)
#   torus     <= 0.08 %
#   cylinder  <= 0.33 %  (worst 20 deg / 0.3); a sweep over lengths 4-14 cm, diameters 1.2-8 cm and
#             masses 0.01-1 kg stayed below 0.4 %. Bullet's cylinder-box contact is a line carried
#             by a few manifold points, and the cylinder rocks a little about its axis, which costs
#             a little more friction than Coulomb's; 1 % still leaves it a 3x margin.
SLIDE_TOL = {"box": 0.01, "torus": 0.01, "cylinder": 0.01}


@pytest.mark.parametrize("shape_name", list(SHAPES))
@pytest.mark.parametrize("angle,mu", list(slide_cases()))
def test_ramp_acceleration_is_newtons(shape_name, angle, mu):
    scene = default_scene(angle, friction=mu, target=None, shape=SHAPES[shape_name])
    traj = Simulator(scene).run(60, fps=60)  # 1 s
    d = along_fall_line(scene, traj)
    # frames while the object's downhill face is still > 5 mm above the foot
    to_foot = scene.start_distance_m() - scene.ramp_object.shape.size_m[0] / 2
    on_ramp = d < to_foot - 0.005
    idx = np.arange(traj.n_frames)[on_ramp][2:]
    assert len(idx) >= 20
    assert np.all(np.diff(idx) == 1)  # one contiguous stretch from the start
    a_fit = 2 * np.polyfit(traj.time_s[idx], d[idx], 2)[0]
    a_true = newton_ramp_accel(scene, mu)
    assert a_fit == pytest.approx(a_true, rel=SLIDE_TOL[shape_name])
    # and it slides straight down: no sideways drift to speak of
    assert abs(traj.position_m[0, idx[-1], 1]) < 0.002


# -- stick or slip ---------------------------------------------------------------------------------

@pytest.mark.parametrize("shape_name", list(SHAPES))
@pytest.mark.parametrize("angle", [10, 20])
def test_sticks_above_tan(shape_name, angle):
    mu = math.tan(math.radians(angle)) + 0.02
    scene = default_scene(angle, friction=mu, target=None, shape=SHAPES[shape_name])
    traj = Simulator(scene).run(61, fps=60)  # frames 0..60: 1 s
    # Along the fall line, the direction friction has to hold.
    moved = abs(along_fall_line(scene, traj)[-1])
    assert moved < 1e-3


@pytest.mark.parametrize("shape_name", list(SHAPES))
@pytest.mark.parametrize("angle", [10, 20])
def test_slips_below_tan(shape_name, angle):
    mu = math.tan(math.radians(angle)) - 0.02
    scene = default_scene(angle, friction=mu, target=None, shape=SHAPES[shape_name])
    traj = Simulator(scene).run(61, fps=60)
    moved = along_fall_line(scene, traj)[-1]
    t = 1.0
    expected = min(0.5 * newton_ramp_accel(scene, mu) * t * t,
                   scene.start_distance_m() - scene.ramp_object.shape.size_m[0] / 2)
    assert expected > 0.05
    assert moved >= 0.5 * expected


# -- friction on the ground ---------------------------------------------------------------------------

@pytest.mark.parametrize("shape_name", list(SHAPES))
@pytest.mark.parametrize("mu", [0.1, 0.15])
def test_ground_deceleration_is_mu_g(shape_name, mu):
    scene = default_scene(20, friction=mu, target=None, shape=SHAPES[shape_name])
    traj = Simulator(scene).run(180, fps=60)
    x = traj.position_m[0, :, 0]
    vx = traj.velocity_mps[0, :, 0]
    half = scene.ramp_object.shape.size_m[0] / 2
    # the whole object 2 cm past the foot, and still sliding
    idx = np.nonzero((x - half > 0.02) & (vx > 0.05))[0]
    assert len(idx) >= 20
    assert np.all(np.diff(idx) == 1)
    decel = -np.polyfit(traj.time_s[idx], vx[idx], 1)[0]
    assert decel == pytest.approx(mu * scene.gravity_mps2, rel=0.02)
    # it does stop, and stays stopped
    assert abs(vx[-1]) < 1e-3


# -- collisions ---------------------------------------------------------------------------------------

M2 = 0.12


def collide(angle, m1, restitution=None, n_frames=240):
    scene = default_scene(angle, target="cardboard")
    values = {"k1": 0.0, "k2": 0.0, "m1_kg": m1, "m2_kg": M2}
    if restitution is not None:
        values.update(e1=restitution, e2=restitution)
    traj = Simulator(scene).run(n_frames, values, fps=240)
    v = traj.velocity_mps
    moving = np.nonzero(np.abs(v[1, :, 0]) > 1e-4)[0]
    assert len(moving), "the ramp object never reached the target"
    return traj, int(moving[0])


@pytest.mark.parametrize("m1", [0.05, 0.2, 0.8])
def test_collision_conserves_horizontal_momentum(m1):
    traj, c = collide(20, m1)
    v = traj.velocity_mps
    before, after = c - 3, c + 5
    assert np.all(v[1, :before + 1, 0] == pytest.approx(0.0, abs=1e-4))  # target at rest until then
    assert traj.position_m[0, before, 0] > 0.0                              # ramp object on the ground
    p_before = m1 * v[0, before, 0] + M2 * v[1, before, 0]
    p_after = m1 * v[0, after, 0] + M2 * v[1, after, 0]
    assert p_after == pytest.approx(p_before, rel=0.02)
    # and it is a real collision: after any impact (0 <= e <= 1) the target moves at least with the
    # common (perfectly inelastic) velocity
    assert v[1, after, 0] > 0.95 * p_before / (m1 + M2)


@pytest.mark.parametrize("m1", [0.05, 0.2, 0.8])
def test_elastic_collision_is_one_dimensional_elastic(m1):
    # On a 3 degree ramp the ramp object arrives flat and without bouncing. (At 20 degrees with
    # e1 = 1 it bounces at the foot, since the ground's restitution is 1, and hits the target
    # tumbling, on an edge: the 1-D formula does not apply there.)
    traj, c = collide(3, m1, restitution=1.0, n_frames=480)
    v = traj.velocity_mps
    u = v[0, c - 2, 0]
    assert u > 0.5
    assert abs(v[0, c - 2, 2]) < 0.05 * u  # arriving horizontally
    v1 = (m1 - M2) / (m1 + M2) * u
    v2 = 2 * m1 / (m1 + M2) * u
    assert v[1, c + 3, 0] == pytest.approx(v2, rel=0.05)
    assert v[0, c + 3, 0] == pytest.approx(v1, abs=0.05 * u)
    # inelastic (e = 0, the default) is clearly different: the target gets less than the elastic share
    traj0, c0 = collide(3, m1, n_frames=480)
    assert traj0.velocity_mps[1, c0 + 3, 0] < 0.8 * v2


# -- determinism & world reuse -------------------------------------------------------------------------

def test_same_run_twice_is_bit_identical():
    scene = default_scene(20, target="cardboard")
    sim = Simulator(scene)
    values = {"m1_kg": 0.3, "k1": 0.15, "m2_kg": 0.2, "k2": 0.4}
    a = sim.run(90, values)
    b = sim.run(90, values)
    assert np.array_equal(a.position_m, b.position_m)
    assert np.array_equal(a.velocity_mps, b.velocity_mps)
    # the objects did collide, so contact state had a chance to leak from one run to the next
    assert np.abs(a.velocity_mps[1]).max() > 0.1


def test_reused_world_matches_fresh_world():
    scene = default_scene(20, target="cardboard")
    rng = np.random.default_rng(1234)
    values = [{"m1_kg": float(rng.uniform(0.05, 1.0)), "k1": float(rng.uniform(0.0, 0.3)),
               "m2_kg": float(rng.uniform(0.05, 1.0)), "k2": float(rng.uniform(0.0, 1.0)),
               "offset_units": int(o)} for o in (-5, -2, 0, 3, 5)]
    values = [values[i] for i in rng.permutation(len(values))]
    sim = Simulator(scene)
    reused = [sim.run(90, v) for v in values]
    assert bullet._world is sim.world  # no rebuild happened along the way
    for v, r in zip(values, reused):
        bullet._world = None
        fresh = Simulator(scene).run(90, v)
        assert np.array_equal(fresh.position_m, r.position_m), v
        assert np.array_equal(fresh.velocity_mps, r.velocity_mps), v
    # different values gave different trajectories (the comparison above is not vacuous)
    assert not np.array_equal(reused[0].position_m, reused[1].position_m)


def test_world_built_for_another_offset():
    # the world is built once per geometry; a scene whose offset differs from the one the world was
    # built with must still start at its own offset, exactly as a world built for it would
    a = default_scene(20, target="cardboard", offset_units=0)
    b = default_scene(20, target="cardboard", offset_units=3)
    bullet._world = None
    Simulator(a).run(30)
    world = bullet._world
    reused = Simulator(b).run(30)
    assert bullet._world is world
    np.testing.assert_allclose(reused.position_m[0, 0], b.initial_pose(0)[0], atol=1e-12)
    bullet._world = None
    fresh = Simulator(b).run(30)
    assert bullet._world is not world
    assert np.array_equal(fresh.position_m, reused.position_m)
    assert np.array_equal(fresh.velocity_mps, reused.velocity_mps)


def test_world_built_once_per_geometry():
    scene = default_scene(20, target="cardboard")
    Simulator(scene).run(5)
    world = bullet._world
    assert world is not None
    # latents, offset and restitution are not geometry: same world
    other = scene.with_values({"m1_kg": 0.1, "k1": 0.5, "m2_kg": 0.9, "k2": 0.1, "offset_units": -3, "e1": 0.5})
    sim = Simulator(other)
    sim.run(5)
    assert bullet._world is world and sim.world is world
    Simulator(default_scene(20, target="cardboard")).run(5)
    assert bullet._world is world
    # a different geometry is a different world
    Simulator(default_scene(25, target="cardboard")).run(5)
    assert bullet._world is not world


# -- the torus -----------------------------------------------------------------------------------------

def torus_scene(**kw):
    return default_scene(10, friction=1.0, target=None, shape=TORUS, **kw)


def test_torus_keeps_its_hole():
    scene = torus_scene()
    world = Simulator(scene).reset()  # the world at its initial pose
    cid, torus = world.cid, world.bodies[0]
    centre, _ = scene.initial_pose(0)
    n, across = scene.ramp.normal, np.array([0.0, 1.0, 0.0])
    big_r, r = (TORUS.size_m[0] - TORUS.size_m[2]) / 2, TORUS.size_m[2] / 2

    def first_hit(lateral, direction=across, depth=0.5 * r):
        """Ray along the hole axis at `lateral` from it, from well above to `depth` below the centre."""
        p = centre + lateral * direction
        return pb.rayTest((p + 0.05 * n).tolist(), (p - depth * n).tolist(), physicsClientId=cid)[0][0]

    downhill = scene.ramp.downhill
    # through the hole: nothing, at the centre and at half the hole's radius
    for d in (across, downhill, (across + downhill) / math.sqrt(2)):
        assert first_hit(0.0, d) == -1
        assert first_hit(0.5 * (big_r - r), d) == -1
    # all the way down through the hole the ray reaches the ramp, not the torus
    assert first_hit(0.0, depth=0.05) == world.ramp
    # through the tube: the torus, in several directions around the ring
    for d in (across, -across, downhill, -downhill, (across - downhill) / math.sqrt(2)):
        assert first_hit(big_r, d) == torus
    # and outside the ring nothing again
    assert first_hit(big_r + r + 0.005) == -1


# Bullet puts a 1 mm collision margin around convex-hull (mesh) shapes; the torus's pieces are
# shrunk by it (galileo.shapes.BULLET_MESH_MARGIN_M). Without that the torus rested 0.99 mm high.
TORUS_REST_TOL_M = 0.3e-3


def test_torus_rests_on_ramp_at_tube_radius():
    scene = torus_scene()  # mu = 1 > tan 10 deg: it stays
    traj = Simulator(scene).run(61, fps=60)
    height = traj.position_m[0, -1] @ scene.ramp.normal  # distance to the ramp plane through the foot
    r = TORUS.size_m[2] / 2
    assert np.linalg.norm(traj.velocity_mps[0, -1]) < 1e-3
    assert abs(height - r) < TORUS_REST_TOL_M


def test_torus_rests_on_ground_at_tube_radius():
    scene = default_scene(20, friction=0.3, target=None, shape=TORUS)
    traj = Simulator(scene).run(180, fps=60)
    p, v = traj.position_m[0, -1], traj.velocity_mps[0, -1]
    assert np.linalg.norm(v) < 1e-3                     # at rest ...
    assert p[0] - TORUS.size_m[0] / 2 > 0.01            # ... wholly on the ground
    assert abs(p[2] - TORUS.size_m[2] / 2) < TORUS_REST_TOL_M


def test_cylinder_along_fall_line_does_not_roll_sideways():
    """Neutrally stable across the ramp: without a little rolling friction Bullet's contact
    noise rolled it off the ramp's side (0.73 m in 4 s here)."""
    cyl = Shape("cylinder", (0.133, 0.0214, 0.0214))
    scene = default_scene(10, friction=0.165, target=None, shape=cyl, offset_units=5)
    traj = Simulator(scene).run(121)
    assert np.abs(traj.position_m[0, :, 1]).max() < 1e-3
    # and it still slides (tan 10 deg = 0.176 > 0.165)
    assert along_fall_line(scene, traj)[-1] > 0.3


def test_simulations_from_two_threads_equal_each_alone(demo_frozen):
    """The app simulates in several threads of one process on its single Bullet client: the
    viewer re-simulating a scrubbed sample, the rerun feed the MAP, and with `--workers 1` the
    chains themselves. Each thread's motion and log-likelihood must be what it gets alone
    (without `client_lock` they step each other's world and come out wrong)."""
    import threading

    from galileo import registry

    scene, tracks, truth = demo_frozen
    positions = [truth, truth * np.array([1.6, 0.5, 0.7, 1.3]), truth * np.array([0.8, 1.2, 1.3, 0.9])]
    lik = [registry.of(scene).likelihood(scene, tracks, 0.05) for _ in positions]
    alone = [lik[0].motion(positions[0]).position_m, lik[1].motion(positions[1]).position_m,
             lik[2](positions[2])[0]]
    got: list[list] = [[], [], []]
    start = threading.Barrier(3)

    def run(i: int) -> None:
        start.wait()
        for _ in range(15):
            got[i].append(lik[i].motion(positions[i]).position_m if i < 2 else lik[i](positions[i])[0])

    threads = [threading.Thread(target=run, args=(i,)) for i in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    for i in range(3):
        assert len(got[i]) == 15
        for value in got[i]:
            np.testing.assert_array_equal(value, alone[i])


def test_a_likelihood_made_while_another_thread_simulates_is_the_same(demo_frozen):
    """Reopening a session builds the viewer's and the rerun feed's likelihoods while chains may
    already simulate in this process: building one simulates the target alone on the shared
    Bullet client (issue 24: `GetBasePositionAndOrientation failed` when another thread reset
    the world under it). Built beside a thread that simulates without pause, each is the one
    built alone."""
    import threading

    from galileo import registry

    scene, tracks, truth = demo_frozen
    scenario = registry.of(scene)
    busy = scenario.likelihood(scene, tracks, 0.05)
    other = truth * np.array([1.6, 0.5, 0.7, 1.3])
    alone = scenario.likelihood(scene, tracks, 0.05)._target_alone
    stop = threading.Event()

    def simulate() -> None:
        while not stop.is_set():
            busy.motion(other)

    t = threading.Thread(target=simulate, daemon=True)
    t.start()
    try:
        for _ in range(10):
            built = scenario.likelihood(scene, tracks, 0.05)._target_alone
            assert len(built) == len(alone) and all(b == a for b, a in zip(built, alone))
    finally:
        stop.set()
        t.join(60)
