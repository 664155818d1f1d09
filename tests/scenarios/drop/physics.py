"""The drop's Bullet world, through `galileo.sim.bullet` (the process's client, one cached world).

A static ground box (top face at z = 0, restitution 1) and a sphere (damping 0). Bullet
multiplies the two bodies' restitutions, so a bounce's restitution is the ball's, e.
Two engine settings make one bounce exactly "rebound = e x approach speed":

* contactProcessingThreshold 0 on both bodies: a contact is solved only once the ball
  touches the ground. Bullet's default solves contacts it finds at a small gap d
  speculatively, as a bounce that comes out d / dt slower.
* contactERP 0: penetration is not pushed out through the velocity (that would add to
  the rebound); split impulse still corrects positions.

So a bounce is found at the start of the first step that begins with the ball in the
ground, after that step's gravity kick: with dt = 1 / sim_hz and the ball above ground
after n steps (semi-implicit Euler: fallen g dt^2 n (n + 1) / 2), the approach speed is
g (n + 2) dt while sqrt(2 g h) lies in [g dt sqrt(n (n + 1)), g dt sqrt((n + 1) (n + 2))).
The rebound right after the first bounce is therefore e sqrt(2 g h) + e g dt (1/2 .. 3/2].
"""
from __future__ import annotations

import numpy as np

from galileo.datatypes import Trajectory
from galileo.errors import GalileoError
from galileo.sim.bullet import cached_world, client, pb

from .scene import BALL, DropScene

GROUND_HALF_M = (2.0, 2.0, 0.05)


class _World:
    def __init__(self, scene: DropScene):
        self.key = _key(scene)
        cid = self.cid = client()
        pb.resetSimulation(physicsClientId=cid)
        pb.setPhysicsEngineParameter(fixedTimeStep=1.0 / scene.sim_hz, numSubSteps=0,
                                     deterministicOverlappingPairs=1, contactERP=0.0, physicsClientId=cid)
        pb.setGravity(0, 0, -scene.gravity_mps2, physicsClientId=cid)
        col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=list(GROUND_HALF_M), physicsClientId=cid)
        self.ground = pb.createMultiBody(0, col, -1, basePosition=[0, 0, -GROUND_HALF_M[2]], physicsClientId=cid)
        pb.changeDynamics(self.ground, -1, restitution=1.0, lateralFriction=0.5, contactProcessingThreshold=0.0,
                          physicsClientId=cid)
        sphere = pb.createCollisionShape(pb.GEOM_SPHERE, radius=scene.radius_m, physicsClientId=cid)
        self.ball = pb.createMultiBody(scene.mass_kg, sphere, -1,
                                       basePosition=[0, 0, scene.height_m + scene.radius_m], physicsClientId=cid)
        pb.changeDynamics(self.ball, -1, linearDamping=0.0, angularDamping=0.0, lateralFriction=0.5,
                          contactProcessingThreshold=0.0, activationState=pb.ACTIVATION_STATE_DISABLE_SLEEPING,
                          physicsClientId=cid)
        self.state = pb.saveState(physicsClientId=cid)


def _key(scene: DropScene) -> tuple:
    """What the built world depends on (e is set per run)."""
    return ("drop", scene.height_m, scene.radius_m, scene.sim_hz, scene.gravity_mps2)


def world(scene: DropScene) -> _World:
    return cached_world(_key(scene), lambda: _World(scene))


def steps_per_frame(scene: DropScene, fps: float) -> int:
    spf = scene.sim_hz / fps
    if abs(spf - round(spf)) > 1e-9:
        raise GalileoError(f"sim_hz {scene.sim_hz} is not a multiple of fps {fps:g}")
    return int(round(spf))


def frames(scene: DropScene, n_frames: int, e: float, fps: float):
    """Yield (frame, position, velocity, orientation xyzw, physics steps taken for it) for
    frames 0..n_frames-1 (frame 0 is the release, t = 0) of a drop with restitution e."""
    w = world(scene)
    cid, ball = w.cid, w.ball
    pb.restoreState(w.state, physicsClientId=cid)
    # restoreState keeps the last run's contact manifolds (warm-started impulses): re-adding
    # the ball to the broadphase drops them, so every run starts like a fresh world
    pb.setCollisionFilterGroupMask(ball, -1, 1, -1, physicsClientId=cid)
    pb.changeDynamics(ball, -1, restitution=float(e), physicsClientId=cid)
    spf = steps_per_frame(scene, fps)
    for f in range(n_frames):
        if f:
            for _ in range(spf):
                pb.stepSimulation(physicsClientId=cid)
        pos, orn = pb.getBasePositionAndOrientation(ball, physicsClientId=cid)
        vel = pb.getBaseVelocity(ball, physicsClientId=cid)[0]
        yield f, pos, vel, orn, (spf if f else 0)


def simulate(scene: DropScene, n_frames: int, e: float | None = None, fps: float | None = None) -> Trajectory:
    fps = float(fps or scene.fps)
    e = scene.restitution if e is None else e
    pos = np.empty((1, n_frames, 3))
    vel = np.empty((1, n_frames, 3))
    orn = np.empty((1, n_frames, 4))
    for f, p, v, q, _ in frames(scene, n_frames, e, fps):
        pos[0, f], vel[0, f], orn[0, f] = p, v, q
    return Trajectory(fps, [BALL], pos, vel, orn)
