"""The fall's physics in Bullet (through `galileo.sim.bullet`: the process's one client, one
cached world per shape and rate): a rigid body over a fixed plane, z = 0.

**Contact, and why Bullet's own restitution is not used.** Bullet's restitution coefficient
does not give a bounce of its own size: landing flat from 15-50 cm, a sphere's measured
e = sqrt(h_after / h_before) scatters from 0.08 below to 0.06 above Bullet's value at 240 Hz
(up to 0.21 below at 480 Hz: a finer step does not cure it), depending on where in a time step
the contact begins (contacts met early are slowed by the gap over the step; contacts met late
are pushed out by the position correction, which adds speed); a box landing flat on Bullet's
plane is met one corner a step (its box-plane manifold grows a point at a time), spins up to
60-115 rad/s and bounces 0-0.07 for Bullet's 0.3 (`bench/bench_fall_restitution.py` prints the
tables). A likelihood over e needs a bounce that is a smooth function of e, so:

* Bullet solves each step's contacts as perfectly inelastic (restitution 0) velocity
  constraints with no position correction (ERP 0) and no speculative contacts (a contact is
  solved once it touches: contact processing threshold 0), friction included (Coulomb, the
  body's mu times the plane's 1);
* after the step, each contact that was approaching faster than `BOUNCE_MPS` receives the
  restitution impulse e J_n at its point (J_n its normal impulse in the step: Poisson's
  hypothesis, the restitution impulse is e times the compression impulse), to the linear and
  the angular velocity;
* the body is lifted out of any penetration along the plane's normal.

The step's timing is then undone for the centre (exactly for a flat landing): the contact is
met a penetration depth d into the step after the touch, so the true impact speed is
sqrt((v + g dt / 2)^2 - 2 g d) (v: the stored speed, half a step behind, below) rather than the
v + g dt the solver stopped, and the rebound is stored half a step of gravity ahead like the
release (the leapfrog start). Landing flat, a box and a cylinder on its side then bounce e^2
times their drop whatever the phase (tests: within 2%). The latent is therefore the measured ratio
itself, e = sqrt(h_after / h_before) landing flat. A tumbling landing (a corner, an edge)
bounces by the same law at its contact points; its centre's rebound then depends on the
orientation, as a real object's does.

**Shape against the plane.** A convex body touches a plane at its vertices and rims, so the
body's collision shape is a set of small spheres there (`contact_points`): a box's eight
corners, a cylinder's two rims (`RIM_POINTS` each: octagons), a torus's tube as `TORUS_POINTS`
spheres of the tube's radius along its centre circle. Each sphere meets the plane on its own, so
a box landing flat has four contacts in the same step. Inertia is the shape's
(`Shape.inertia_per_kg`). Bullet keeps at most four contact points between two bodies and, with
more than about 16 small spheres in one compound, misses contacts for whole steps (a cylinder
with 16-point rims sinks 5 cm into the surface): hence octagonal rims, so a cylinder on its side
rolls as an octagonal prism (each vertex's landing takes some of its speed, like a rolling
resistance); the depth the body is lifted by is the shape's own (its spheres' lowest point), not
the contacts'.

Friction is Coulomb's, mu = the latent (`mu_<object>_<surface>`); a box sliding at v0 stops
after v0^2 / (2 mu g) (test within 2%). Rolling friction is 0. Mass changes nothing here
(every force scales with it).

Free fall: Bullet integrates by semi-implicit Euler, whose fall from rest after n steps is
g dt^2 n (n + 1) / 2, ahead of Newton's g t^2 / 2 by g t dt / 2 (1.7% of a 30 cm drop at
240 Hz). Starting the body's vertical velocity half a step of gravity ahead (the leapfrog start,
v0 + g dt / 2) makes it exact: the positions are Newton's at every step, and each step's velocity
is the true one half a step earlier.

Rates: `sim_hz` 240 (8 steps a 30 fps frame) by default; the state before `release_frame` is
the release state, held.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from ...camera import steps_per_frame
from ...datatypes import Trajectory
from ...shapes import Shape
from ...sim.bullet import cached_world, client_lock, new_world, pb
from .scene import FallScene

BODY = "object"
CONTACT_RADIUS_M = 0.001    # the spheres at a box's corners and a cylinder's rims (inset by it)
RIM_POINTS = 8              # spheres around each of a cylinder's rims (see the module docstring)
TORUS_POINTS = 16           # spheres along a torus's centre circle
BOUNCE_MPS = 0.1            # a contact approaching slower than this does not bounce (resting, sliding)
SOLVER_ITERATIONS = 20
SLAB_HALF_M = 25.0          # the surface's slab: 50 m across


@dataclass(frozen=True)
class Params:
    """What a run needs, in SI units."""
    restitution: float
    friction: float
    mass_kg: float
    pos0: tuple[float, float, float]
    orn0: tuple[float, float, float, float]
    vel0: tuple[float, float, float]
    spin0: tuple[float, float, float]
    gravity_mps2: float


_ATTRS = ("restitution", "friction", "x0_m", "y0_m", "z0_m", "roll0_rad", "pitch0_rad", "yaw0_rad", "vx0_mps",
          "vy0_mps", "vz0_mps", "wx0_radps", "wy0_radps", "wz0_radps")


def params(scene: FallScene, values: dict[str, float] | None = None, *, checked: bool = True) -> Params:
    """The run's parameters from a scene and latent values by name (missing ones: the scene's).
    `checked=False` (the likelihood, whose values lie inside the priors, themselves inside the
    scene's bounds) skips the scene's checks: a chain asks this thousands of times."""
    if checked or not values:
        s = scene.with_values(values) if values else scene
        v = {a: getattr(s, a) for a in _ATTRS}
    else:
        names = scene.names()
        v = {a: getattr(scene, a) for a in _ATTRS}
        v.update({names[k]: float(x) for k, x in values.items() if k in names})
    orn = pb.getQuaternionFromEuler((v["roll0_rad"], v["pitch0_rad"], v["yaw0_rad"]))
    return Params(v["restitution"], v["friction"], scene.mass_kg, (v["x0_m"], v["y0_m"], v["z0_m"]), tuple(orn),
                  (v["vx0_mps"], v["vy0_mps"], v["vz0_mps"]), (v["wx0_radps"], v["wy0_radps"], v["wz0_radps"]),
                  scene.gravity_mps2)


def contact_points(shape: Shape) -> tuple[np.ndarray, np.ndarray]:
    """The spheres (centres (N, 3) in the object frame, radii (N,)) that stand for `shape`
    against a plane (see the module docstring)."""
    sx, sy, sz = shape.size_m
    r = CONTACT_RADIUS_M
    if shape.type == "box":
        c = np.array([(a * (sx / 2 - r), b * (sy / 2 - r), d * (sz / 2 - r))
                      for a, b, d in itertools.product((-1, 1), repeat=3)])
        return c, np.full(len(c), r)
    if shape.type == "cylinder":     # axis along x, diameter y = z
        rad = sy / 2 - r
        ang = np.linspace(0, 2 * np.pi, RIM_POINTS, endpoint=False)
        ring = np.c_[np.zeros(RIM_POINTS), rad * np.cos(ang), rad * np.sin(ang)]
        c = np.r_[ring + (sx / 2 - r, 0, 0), ring - (sx / 2 - r, 0, 0)]
        return c, np.full(len(c), r)
    if shape.type == "torus":        # flat, hole along z: outer diameter x = y, tube z
        tube = sz / 2
        big = (sx - sz) / 2
        ang = np.linspace(0, 2 * np.pi, TORUS_POINTS, endpoint=False)
        c = np.c_[big * np.cos(ang), big * np.sin(ang), np.zeros(TORUS_POINTS)]
        return c, np.full(len(c), tube)
    raise ValueError(f"the fall scenario has no contact model for a {shape.type}")


def lowest_point_m(shape: Shape, pos, orn) -> float:
    """The height of the body's lowest point at pose (pos, orn)."""
    c, r = contact_points(shape)
    rot = np.array(pb.getMatrixFromQuaternion(orn)).reshape(3, 3)
    return float(np.min((c @ rot.T)[:, 2] - r) + pos[2])


class _World:
    def __init__(self, shape: Shape, sim_hz: float, gravity_mps2: float):
        self.key = ("fall", shape.type, shape.size_m, float(sim_hz), float(gravity_mps2))
        cid = self.cid = new_world(sim_hz, gravity_mps2, SOLVER_ITERATIONS)
        pb.setPhysicsEngineParameter(erp=0.0, contactERP=0.0, frictionERP=0.0, physicsClientId=cid)
        # the surface: a slab with its top at z = 0 (Bullet's infinite plane misses a compound of
        # many small spheres: its huge bounding box overflows the compound's tree query)
        slab = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[SLAB_HALF_M, SLAB_HALF_M, SLAB_HALF_M],
                                       physicsClientId=cid)
        self.plane = pb.createMultiBody(0.0, slab, basePosition=[0.0, 0.0, -SLAB_HALF_M], physicsClientId=cid)
        pb.changeDynamics(self.plane, -1, restitution=0.0, lateralFriction=1.0, rollingFriction=0.0,
                          spinningFriction=0.0, contactProcessingThreshold=0.0, physicsClientId=cid)
        centres, radii = contact_points(shape)
        self.centres, self.radii = centres, radii
        n = len(radii)
        col = pb.createCollisionShapeArray([pb.GEOM_SPHERE] * n, radii=radii.tolist(),
                                           collisionFramePositions=centres.tolist(), physicsClientId=cid)
        self.body = pb.createMultiBody(1.0, col, -1, basePosition=[0, 0, 1], useMaximalCoordinates=True,
                                       physicsClientId=cid)
        self.inertia_per_kg = np.asarray(shape.inertia_per_kg(), float)
        pb.changeDynamics(self.body, -1, restitution=0.0, rollingFriction=0.0, spinningFriction=0.0,
                          linearDamping=0.0, angularDamping=0.0, contactProcessingThreshold=0.0,
                          activationState=pb.ACTIVATION_STATE_DISABLE_SLEEPING, physicsClientId=cid)
        self.shape = shape


def world(shape: Shape, sim_hz: float, gravity_mps2: float) -> _World:
    return cached_world(("fall", shape.type, shape.size_m, float(sim_hz), float(gravity_mps2)),
                        lambda: _World(shape, sim_hz, gravity_mps2))


class Run:
    """One run, video frame by video frame: before `release_frame` the hand holds the object at
    its release state; from it on, `spf` physics steps per frame. Hold `client_lock`."""

    def __init__(self, p: Params, shape: Shape, sim_hz: float, fps: float, release_frame: int):
        self.p = p
        self.w = world(shape, sim_hz, p.gravity_mps2)
        self.spf = steps_per_frame(sim_hz, fps)
        self.dt = 1.0 / sim_hz
        self.release = release_frame
        self.steps = 0
        cid, body = self.w.cid, self.w.body
        inertia = (self.w.inertia_per_kg * p.mass_kg).tolist()
        self.inv_inertia = 1.0 / np.asarray(inertia)
        pb.changeDynamics(body, -1, mass=p.mass_kg, localInertiaDiagonal=inertia, lateralFriction=p.friction,
                          physicsClientId=cid)
        # the leapfrog start: half a step of gravity ahead, so semi-implicit Euler's free fall is
        # exact (see the module docstring); an object set down on the surface starts as a resting
        # one stands between steps, a step of gravity into it, so its contact holds from the first step
        vx, vy, vz = p.vel0
        lead = 0.5 * p.gravity_mps2 * self.dt
        start = p.pos0
        if lowest_point_m(shape, p.pos0, p.orn0) < lead * self.dt:
            lead = 0.0
            start = (p.pos0[0], p.pos0[1], p.pos0[2] - p.gravity_mps2 * self.dt * self.dt)
        pb.resetBasePositionAndOrientation(body, start, p.orn0, physicsClientId=cid)
        pb.resetBaseVelocity(body, (vx, vy, vz + lead), p.spin0, physicsClientId=cid)
        self.pos, self.orn, self.vel, self.spin = p.pos0, p.orn0, p.vel0, p.spin0

    def step(self) -> None:
        cid, body, plane = self.w.cid, self.w.body, self.w.plane
        e, m, dt = self.p.restitution, self.p.mass_kg, self.dt
        step, contacts = pb.stepSimulation, pb.getContactPoints
        get_pose, get_vel = pb.getBasePositionAndOrientation, pb.getBaseVelocity
        pos, vel, spin = self.pos, self.vel, self.spin
        for _ in range(self.spf):
            step(physicsClientId=cid)
            cps = contacts(body, plane, physicsClientId=cid)
            if cps:
                pos, vel, spin = self._respond(cps, pos, vel, spin, e, m, dt)
            else:
                pos = get_pose(body, physicsClientId=cid)[0]
                vel, spin = get_vel(body, physicsClientId=cid)
        self.steps += self.spf
        self.pos, self.vel, self.spin = pos, vel, spin
        self.orn = get_pose(body, physicsClientId=cid)[1]

    def _respond(self, cps, pos0, vel0, spin0, e, m, dt):
        """Poisson's restitution for the contacts of the step just taken (their points, normals
        and impulses), then the body lifted out of the plane; returns (pos, vel, spin)."""
        cid, body = self.w.cid, self.w.body
        pos, orn = pb.getBasePositionAndOrientation(body, physicsClientId=cid)
        vel, spin = pb.getBaseVelocity(body, physicsClientId=cid)
        jx = jy = jz = tx = ty = tz = 0.0
        rot = np.array(pb.getMatrixFromQuaternion(orn)).reshape(3, 3)
        # the depth from the shape itself: a compound's contacts with the plane share one manifold
        # of at most four points, so a rim of many spheres reports only some of those inside it
        depth = min(0.0, float(np.min(self.w.centres @ rot[2] - self.w.radii)) + pos[2])
        px, py, pz = pos0
        vx, vy, vz = vel0
        wx, wy, wz = spin0
        pushed = False
        for c in cps:
            jn = c[9] * dt
            if jn <= 0.0:
                continue
            pushed = True
            ax, ay, az = c[5]
            nx, ny, nz = c[7]               # from the plane to the body
            # the contact point's approach speed before the step
            rx, ry, rz = ax - px, ay - py, az - pz
            cvx, cvy, cvz = vx + wy * rz - wz * ry, vy + wz * rx - wx * rz, vz + wx * ry - wy * rx
            if -(cvx * nx + cvy * ny + cvz * nz) <= BOUNCE_MPS:
                continue
            j = e * jn
            fx, fy, fz = j * nx, j * ny, j * nz
            jx, jy, jz = jx + fx, jy + fy, jz + fz
            rx, ry, rz = ax - pos[0], ay - pos[1], az - pos[2]
            tx, ty, tz = tx + ry * fz - rz * fy, ty + rz * fx - rx * fz, tz + rx * fy - ry * fx
        changed = False
        if jx or jy or jz:
            dw = rot @ (self.inv_inertia * (rot.T @ np.array((tx, ty, tz))))
            # the step's timing, undone for the centre's rebound (see the module docstring)
            g = self.p.gravity_mps2
            fall = -vz
            if fall > 0.0:
                mid = fall + 0.5 * g * dt
                impact = math.sqrt(max(mid * mid + 2.0 * g * depth, 0.0))
                jz += m * (e * (impact - (fall + g * dt)) + 0.5 * g * dt)
            dv = np.array((jx, jy, jz)) / m
            lam = self._within_energy(rot, np.asarray(vel), np.asarray(spin), dv, dw, vel0, spin0)
            vel = tuple(float(a) for a in np.asarray(vel) + lam * dv)
            spin = tuple(float(a) for a in np.asarray(spin) + lam * dw)
            changed = True
        if depth < 0.0 and pushed:      # (a contact met this step is solved the next: lifted then)
            pos = (pos[0], pos[1], pos[2] - depth)
            pb.resetBasePositionAndOrientation(body, pos, orn, physicsClientId=cid)
            changed = True
        if changed:
            pb.resetBaseVelocity(body, vel, spin, physicsClientId=cid)
        return pos, vel, spin

    def _within_energy(self, rot, vel, spin, dv, dw, vel0, spin0) -> float:
        """The largest share (<= 1) of the restitution impulse (dv, dw) that leaves the body no
        more kinetic energy than it had before the step: Poisson's impulses at several contacts of
        a tumbling body can add energy (the solver's split of the compression impulse among them
        is not unique); a bounce never does."""
        inertia = self.w.inertia_per_kg

        def parts(v, w):
            wb = rot.T @ w
            return v, wb

        v0, w0 = parts(np.asarray(vel0), np.asarray(spin0))
        before = 0.5 * (v0 @ v0 + (inertia * w0) @ w0)
        v, wb = parts(vel, spin)
        dwb = rot.T @ dw
        a = 0.5 * (dv @ dv + (inertia * dwb) @ dwb)
        b = v @ dv + (inertia * wb) @ dwb
        c = 0.5 * (v @ v + (inertia * wb) @ wb) - before
        if a <= 0.0 or a + b + c <= 0.0:
            return 1.0
        disc = b * b - 4 * a * c
        return float(min(1.0, max(0.0, (-b + math.sqrt(disc)) / (2 * a)))) if disc >= 0.0 else 0.0

    def frame(self, f: int) -> tuple:
        """Advance to video frame f (frames come one after the other): (position, orientation,
        velocity, spin)."""
        if f > self.release:
            self.step()
        return self.pos, self.orn, self.vel, self.spin


def start_problem(p: Params, shape: Shape) -> str | None:
    """Why a release state cannot start a run (the object inside the surface), or None."""
    low = lowest_point_m(shape, p.pos0, p.orn0)
    if low < -1e-6:
        return f"the object starts {-low * 100:.1f} cm inside the surface (its lowest point at z = {low:.3f} m)"
    return None


def simulate(scene: FallScene, n_frames: int, values: dict[str, float] | None = None,
             fps: float | None = None) -> Trajectory:
    """One plain run, every video frame (before the release: held at the release state)."""
    from ...errors import SceneError

    fps = float(fps or scene.fps)
    s = scene.with_values(values) if values else scene
    p = params(s)
    why = start_problem(p, s.shape)
    if why:
        raise SceneError(f"release state: {why}")
    release = s.release_frame
    if fps != s.fps:     # a finer sampling of the same motion (sub-frame renders): the release at the same time
        release = int(round(release * fps / s.fps))
    pos = np.empty((1, n_frames, 3))
    vel = np.empty((1, n_frames, 6))
    orn = np.empty((1, n_frames, 4))
    with client_lock:
        run = Run(p, s.shape, s.sim_hz, fps, release)
        for f in range(n_frames):
            q, o, v, w = run.frame(f)
            pos[0, f], orn[0, f] = q, o
            vel[0, f] = (0.0,) * 6 if f < release else (*v, *w)
    return Trajectory(fps, [BODY], pos, vel[..., :3], orn)


# -- closed forms (the physics' own predictions, for tests, priors and starts) -------------------------

def fall_time_s(height_m: float, gravity_mps2: float = 9.81, vz0_mps: float = 0.0) -> float:
    """Time for a free fall of `height_m` from vertical speed vz0 (up positive)."""
    g = gravity_mps2
    return (vz0_mps + math.sqrt(vz0_mps * vz0_mps + 2 * g * height_m)) / g


def slide_distance_m(speed_mps: float, friction: float, gravity_mps2: float = 9.81) -> float:
    """How far a block sliding at `speed_mps` goes before friction stops it: v^2 / (2 mu g)."""
    return speed_mps * speed_mps / (2 * friction * gravity_mps2)
