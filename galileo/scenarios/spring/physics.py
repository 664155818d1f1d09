"""The spring's physics in Bullet (through `galileo.sim.bullet`: the process's one client, one
cached world). Bullet has no springs, so every physics step applies the spring's forces itself
(external forces are cleared after each step):

* Hooke along the spring's current direction u (from the hanging point to the object's
  centre), so the object also swings like a pendulum: F = -k (l - rest) u, with l the spring's
  length, |centre - top| - hang;
* a dashpot along the spring: -c (v . u) u (the amplitude decays as exp(-c t / (2 M)));
* gravity, applied as a force (the world's gravity is 0): -(m + ms/2) g z.

The spring's own mass ms (uniform along it) enters the way a uniform spring's mass does: its
kinetic energy, with the coils moving in proportion to their distance from the hanging point,
is that of ms/3 at the object's speed, so the body's inertial mass is M = m + ms/3 (Rayleigh's
correction; the period is 2 pi sqrt((m + ms/3) / k)); hanging, the spring stretches under the
object's weight and half its own, so the weight that stretches it is (m + ms/2) g (the static
extension is (m + ms/2) g / k). A chain of small bodies would give both to within its
discretisation and cost a body per link per step; the equivalent here is exact for the
vertical bounce and, for the sway, gives a pendulum of length L (hanging point to centre)
with period 2 pi sqrt(L M / ((m + ms/2) g)): 2 pi sqrt(L / g) for a light spring (within
ms / (12 m) of it). The object is a point at its centre for the forces (applied there: it does
not spin); its drawn shape follows the centre.

Bullet integrates with semi-implicit Euler at `sim_hz` (damping 0), which for an oscillator of
angular frequency w shortens the period by a fraction of about (w dt)^2 / 24 (0.2% for a 2 Hz
bounce at the default 60 Hz). That error is known in closed form, so it is undone: the force law
uses k_sim = k (sin(w dt / 2) / (w dt / 2))^2 and the weight times the same factor (`prewarp`),
which gives the discrete bounce exactly the period 2 pi sqrt(M / k) and keeps the static
extension; the sway, ten times slower, keeps a thousandth of the error. A step applies the
force from the last step's position and velocity (the velocity is the step's displacement over
dt, exactly what semi-implicit Euler moved by), then steps Bullet.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...camera import steps_per_frame
from ...datatypes import Trajectory
from ...sim.bullet import cached_world, client_lock, new_world, pb
from .scene import SpringScene

BODY = "object"
BODY_RADIUS_M = 0.01   # the body's collision sphere (collisions are off: it touches nothing)
IDENTITY = (0.0, 0.0, 0.0, 1.0)


@dataclass(frozen=True)
class Params:
    """What a run needs, in SI units, in the simulation's (true) lengths."""
    mass_kg: float
    k_Npm: float
    spring_mass_kg: float
    damping_Nspm: float
    rest_m: float
    hang_m: float
    top: tuple[float, float, float]
    pos0: tuple[float, float, float]      # the centre at release (world)
    vel0: tuple[float, float, float]
    gravity_mps2: float

    @property
    def inertial_kg(self) -> float:
        return self.mass_kg + self.spring_mass_kg / 3.0

    @property
    def weight_N(self) -> float:
        return (self.mass_kg + self.spring_mass_kg / 2.0) * self.gravity_mps2


def params(scene: SpringScene, values: dict[str, float] | None = None, *, checked: bool = True) -> Params:
    """The run's parameters from a scene and latent values by name (missing ones: the scene's).
    The release state is given in the scene's units relative to the hanging point; times
    `scale` it is the simulation's. `checked=False` (the likelihood, whose values lie inside the
    priors, themselves inside the scene's bounds) skips the scene's checks: a chain asks this
    thousands of times."""
    if checked or not values:
        s = scene.with_values(values) if values else scene
        v = {attr: getattr(s, attr) for attr in _ATTRS}
    else:
        names = scene.names()
        v = {attr: getattr(scene, attr) for attr in _ATTRS}
        v.update({names[k]: float(x) for k, x in values.items() if k in names})
    tx, ty, tz = scene.top_in_world_m
    k = v["scale"]
    return Params(v["mass_kg"], v["k_Npm"], v["spring_mass_kg"], v["damping_Nspm"], v["rest_m"], scene.hang_m,
                  (tx, ty, tz), (tx + k * v["x0_m"], ty, tz + k * v["z0_m"]), (k * v["vx0_mps"], 0.0, k * v["vz0_mps"]),
                  scene.gravity_mps2)


_ATTRS = ("mass_kg", "k_Npm", "spring_mass_kg", "damping_Nspm", "rest_m", "x0_m", "z0_m", "vx0_mps", "vz0_mps", "scale")


class _World:
    def __init__(self, sim_hz: float):
        self.key = ("spring", float(sim_hz))
        cid = self.cid = new_world(sim_hz, 0.0, 10)
        shape = pb.createCollisionShape(pb.GEOM_SPHERE, radius=BODY_RADIUS_M, physicsClientId=cid)
        self.body = pb.createMultiBody(1.0, shape, -1, basePosition=[0, 0, 0], physicsClientId=cid)
        pb.setCollisionFilterGroupMask(self.body, -1, 0, 0, physicsClientId=cid)
        pb.changeDynamics(self.body, -1, linearDamping=0.0, angularDamping=0.0,
                          activationState=pb.ACTIVATION_STATE_DISABLE_SLEEPING, physicsClientId=cid)


def world(sim_hz: float) -> _World:
    return cached_world(("spring", float(sim_hz)), lambda: _World(sim_hz))


class Run:
    """One run, video frame by video frame: before `release_frame` the hand holds the object at
    its release state; from it on, `spf` physics steps per frame. Hold `client_lock`."""

    def __init__(self, p: Params, sim_hz: float, fps: float, release_frame: int):
        self.p = p
        self.w = world(sim_hz)
        self.spf = steps_per_frame(sim_hz, fps)
        self.dt = 1.0 / sim_hz
        self.release = release_frame
        self.steps = 0
        # the integrator's frequency error, undone for the bounce (see the module docstring)
        f = prewarp(math.sqrt(p.k_Npm / p.inertial_kg) * self.dt)
        self.k_sim, self.weight_sim = p.k_Npm * f, p.weight_N * f
        cid, body = self.w.cid, self.w.body
        pb.changeDynamics(body, -1, mass=p.inertial_kg, physicsClientId=cid)
        pb.resetBasePositionAndOrientation(body, p.pos0, IDENTITY, physicsClientId=cid)
        pb.resetBaseVelocity(body, p.vel0, (0.0, 0.0, 0.0), physicsClientId=cid)
        self.pos, self.vel = p.pos0, p.vel0

    def step(self) -> None:
        p, cid, body = self.p, self.w.cid, self.w.body
        tx, ty, tz = p.top
        k, c, rest, hang, weight = self.k_sim, p.damping_Nspm, p.rest_m, p.hang_m, self.weight_sim
        get_pos, apply, step = pb.getBasePositionAndOrientation, pb.applyExternalForce, pb.stepSimulation
        frame = pb.WORLD_FRAME
        inv_dt = 1.0 / self.dt
        pos, vel = self.pos, self.vel
        for _ in range(self.spf):
            dx, dy, dz = pos[0] - tx, pos[1] - ty, pos[2] - tz
            dist = math.sqrt(dx * dx + dy * dy + dz * dz)
            if dist > 1e-9:
                ux, uy, uz = dx / dist, dy / dist, dz / dist
                pull = k * (dist - hang - rest) + c * (vel[0] * ux + vel[1] * uy + vel[2] * uz)
                force = (-pull * ux, -pull * uy, -pull * uz - weight)
            else:
                force = (0.0, 0.0, -weight)
            apply(body, -1, force, pos, frame, physicsClientId=cid)
            step(physicsClientId=cid)
            new = get_pos(body, physicsClientId=cid)[0]
            # semi-implicit Euler moves by the new velocity: it is the step's displacement / dt
            vel = ((new[0] - pos[0]) * inv_dt, (new[1] - pos[1]) * inv_dt, (new[2] - pos[2]) * inv_dt)
            pos = new
        self.steps += self.spf
        self.pos, self.vel = pos, vel

    def frame(self, f: int) -> tuple[tuple, tuple]:
        """Advance to video frame f (frames come one after the other): (position, velocity)."""
        if f > self.release:
            self.step()
        return self.pos, self.vel


def prewarp(theta: float) -> float:
    """The factor on the stiffness (and on the weight, so the extension stays) that gives
    semi-implicit Euler's oscillator the exact period: with w dt = theta its discrete frequency
    solves cos(w' dt) = 1 - (w_sim dt)^2 / 2, which is w when w_sim = 2 sin(theta / 2) / dt."""
    if theta <= 0 or theta >= math.pi:
        return 1.0
    return (math.sin(theta / 2) / (theta / 2)) ** 2


def simulate(scene: SpringScene, n_frames: int, values: dict[str, float] | None = None,
             fps: float | None = None) -> Trajectory:
    """One plain run, every video frame (before the release: held at the release state)."""
    fps = float(fps or scene.fps)
    s = scene.with_values(values) if values else scene
    p = params(s)
    release = s.release_frame
    pos = np.empty((1, n_frames, 3))
    vel = np.empty((1, n_frames, 3))
    orn = np.tile(np.array(IDENTITY), (1, n_frames, 1))
    with client_lock:
        run = Run(p, s.sim_hz, fps, release)
        for f in range(n_frames):
            pos[0, f], vel[0, f] = run.frame(f)
            if f < release:
                vel[0, f] = 0.0
    return Trajectory(fps, [BODY], pos, vel, orn)


# -- closed forms (the physics' own predictions, for tests, priors and starts) -----------------------

def equilibrium_below_top_m(p: Params) -> float:
    """The centre's distance below the hanging point at rest: rest + hang + (m + ms/2) g / k."""
    return p.rest_m + p.hang_m + p.weight_N / p.k_Npm


def period_s(p: Params) -> float:
    """The vertical bounce's undamped period, 2 pi sqrt((m + ms/3) / k)."""
    return 2 * math.pi * math.sqrt(p.inertial_kg / p.k_Npm)
