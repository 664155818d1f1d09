"""Physics: the scene simulated forward in Bullet (pybullet, DIRECT mode).

One pybullet client per process. The world is built once for a scene's geometry and
reset with restoreState between simulations; only masses, frictions, restitutions and
the ramp object's start offset change between runs, so a proposal in MCMC costs one
restore and the steps, never a rebuild.

Friction semantics: Bullet combines the two bodies' coefficients by multiplying them.
The ramp and the ground have friction 1, so an object's `friction` is exactly its
Coulomb coefficient against the ramp and the ground. Between two objects the
coefficient is the product k1 * k2 (and the restitution the product e1 * e2). With a
collision restitution (`Scene.collision_restitution` or the value e_collision) the
restitutions are set so that the collision's is exactly that while the ramp object's
against the ramp and the ground stays e1: ramp object 1, target e_collision, ramp and
ground e1 (the target's against the ground is then e1 * e_collision).
Linear and angular damping are 0 (Bullet's default 0.04 would slow a sliding block by
about 2% against Newton); rolling and spinning friction are 0 but for cylinders (see
`galileo.shapes.CYLINDER_ROLLING_FRICTION`); sleeping is disabled and a reset drops the previous run's
contacts, so a reused world reproduces a freshly built one bit for bit.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from ...datatypes import Trajectory
from ...errors import GalileoError
from ...sim.bullet import cached_world, collision_shape, new_world, pb, visual_shape
from .scene import Scene

GROUND_SIZE_M = (8.0, 4.0, 0.1)
# Constraint-solver iterations per step: Bullet's own default (pybullet raises it to 50).
# The Newton checks hold as tightly with 10 (tests/test_physics.py) at half the cost.
SOLVER_ITERATIONS = 10


class _World:
    """Bodies of one scene geometry in the process's client, with a saved initial state."""

    def __init__(self, scene: Scene, visual: bool):
        self.key = (scene.geometry_key(), visual)
        cid = self.cid = new_world(scene.sim_hz, scene.gravity_mps2, SOLVER_ITERATIONS)
        gx, gy, gz = GROUND_SIZE_M
        ramp = scene.ramp

        def static_box(half, pos, orn):
            col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=cid)
            vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=cid) if visual else -1
            b = pb.createMultiBody(0, col, vis, basePosition=list(pos), baseOrientation=list(orn),
                                   physicsClientId=cid)
            pb.changeDynamics(b, -1, lateralFriction=1.0, restitution=1.0, rollingFriction=0.0,
                              spinningFriction=0.0, physicsClientId=cid)
            return b

        self.ground = static_box([gx / 2, gy / 2, gz / 2], [0, 0, -gz / 2], [0, 0, 0, 1])
        centre = -(ramp.length_m / 2) * ramp.downhill - (ramp.thickness_m / 2) * ramp.normal
        self.ramp = static_box([ramp.length_m / 2, ramp.width_m / 2, ramp.thickness_m / 2], centre,
                               ramp.orientation_xyzw)
        self.backdrop = None
        if visual:  # a back wall for the camera to see behind the scene (render only, no collision)
            half = [3.0, 0.01, 1.5]
            vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=cid)
            self.backdrop = pb.createMultiBody(0, -1, vis, basePosition=[0, gy / 2, 1.0], physicsClientId=cid)
        self.bodies = []
        self.inertia_per_kg = []
        for i, obj in enumerate(scene.objects):
            pos, orn = scene.initial_pose(i)
            b = pb.createMultiBody(obj.mass_kg, collision_shape(obj.shape, cid),
                                   visual_shape(obj.shape, cid) if visual else -1,
                                   basePosition=pos.tolist(), baseOrientation=list(orn), physicsClientId=cid)
            pb.changeDynamics(b, -1, linearDamping=0.0, angularDamping=0.0, rollingFriction=obj.shape.rolling_friction,
                              spinningFriction=0.0, activationState=pb.ACTIVATION_STATE_DISABLE_SLEEPING,
                              physicsClientId=cid)
            self.bodies.append(b)
            self.inertia_per_kg.append(obj.shape.inertia_per_kg())
        self.state = pb.saveState(physicsClientId=cid)
        # the ramp's and the ground's restitution now (restoreState leaves restitutions alone)
        self.static_restitution = 1.0


class Simulator:
    """Simulates one scene; `run` may be called many times with different latents.

    >>> sim = Simulator(scene)
    >>> traj = sim.run(90, {"m1_kg": 0.3, "k1": 0.25})
    """

    def __init__(self, scene: Scene, *, visual: bool = False):
        self.scene = scene
        self.visual = visual
        self._world: _World | None = None

    @property
    def world(self) -> _World:
        self._world = cached_world((self.scene.geometry_key(), self.visual), lambda: _World(self.scene, self.visual))
        return self._world

    def reset(self, values: dict[str, float] | None = None) -> _World:
        """Restore the initial state and apply the scene's (or the given) latents."""
        w = self.world
        pb.restoreState(w.state, physicsClientId=w.cid)
        # restoreState leaves the previous run's contact manifolds in place and their cached
        # impulses warm-start the solver, so a reused world would drift (~0.2 mm) from a fresh
        # one. Setting a body's collision filter re-adds it to the broadphase, which drops its
        # manifolds; doing so for every body in creation order keeps the world's object order
        # that of a fresh build. Group 1, mask -1 (all) are Bullet's defaults for dynamic bodies.
        self.drop_contacts()
        self.apply_values(values)
        self.place(values)
        return w

    def snapshot(self) -> tuple:
        """The objects' poses and velocities now (plain floats): what `resume` starts from."""
        w = self._world or self.world
        cid = w.cid
        return tuple(pb.getBasePositionAndOrientation(b, physicsClientId=cid)
                     + pb.getBaseVelocity(b, physicsClientId=cid) for b in w.bodies)

    def resume(self, snapshot: tuple, values: dict[str, float] | None = None) -> _World:
        """The world as `reset` leaves it, with `values` applied and the objects at the
        snapshot's poses and velocities (contacts start cold). Doing this at the frame a
        snapshot was taken, and later from the snapshot, gives the same world bit for bit;
        unlike saveState (~0.3 ms) it costs a few microseconds."""
        w = self.world
        cid = w.cid
        pb.restoreState(w.state, physicsClientId=cid)
        self.drop_contacts()
        self.apply_values(values)
        for b, (pos, orn, lin, ang) in zip(w.bodies, snapshot):
            pb.resetBasePositionAndOrientation(b, pos, orn, physicsClientId=cid)
            pb.resetBaseVelocity(b, lin, ang, physicsClientId=cid)
        return w

    def drop_contacts(self) -> None:
        """Forget all contact manifolds (after restoreState; see `reset`)."""
        w = self._world or self.world
        for b in w.bodies:
            pb.setCollisionFilterGroupMask(b, -1, 1, -1, physicsClientId=w.cid)

    def apply_values(self, values: dict[str, float] | None = None) -> None:
        """Set masses (with inertia), frictions, restitutions and the ramp object's start
        offset from the scene, overridden by `values` (m1_kg, k1, e1, e_collision,
        offset_units, ...; other names, e.g. log10_sigma_mps, are ignored)."""
        w = self._world or self.world
        cid = w.cid
        scene = self.scene
        values = values or {}
        restitution = [values.get("e" + str(i + 1), obj.restitution) for i, obj in enumerate(scene.objects)]
        static = 1.0
        collision = values.get("e_collision", scene.collision_restitution)
        if collision is not None and len(w.bodies) == 2:
            # products: object-ramp = object-ground = e1, object-target = e_collision
            static, restitution = float(restitution[0]), [1.0, float(collision)]
        if w.static_restitution != static:
            for b in (w.ground, w.ramp):
                pb.changeDynamics(b, -1, restitution=static, physicsClientId=cid)
            w.static_restitution = static
        for i, (obj, b) in enumerate(zip(scene.objects, w.bodies)):
            n = str(i + 1)
            mass = values.get("m" + n + "_kg", obj.mass_kg)
            pb.changeDynamics(b, -1, mass=mass, localInertiaDiagonal=(mass * w.inertia_per_kg[i]).tolist(),
                              lateralFriction=values.get("k" + n, obj.friction),
                              restitution=restitution[i], physicsClientId=cid)

    def place(self, values: dict[str, float] | None = None) -> None:
        """Put the ramp object at its start (the scene's offset or values["offset_units"])."""
        w = self._world or self.world
        obj = self.scene.ramp_object
        values = values or {}
        # The saved state holds the ramp object at the offset the world was built with
        # (the offset is not part of the geometry key), so always place it; placing it
        # even when the offset matches keeps the pose bit-identical to a moved one
        # (createMultiBody stores a quaternion that differs in the last bit).
        offset = int(round(values.get("offset_units", obj.offset_units)))
        placed = self.scene if offset == obj.offset_units else self.scene.with_values({"offset_units": offset})
        pos, orn = placed.initial_pose(0)
        pb.resetBasePositionAndOrientation(w.bodies[0], pos.tolist(), orn, physicsClientId=w.cid)

    def run(self, n_frames: int, values: dict[str, float] | None = None, fps: float | None = None,
            on_frame: Callable[[int, np.ndarray, np.ndarray], bool] | None = None,
            with_orientation: bool = False) -> Trajectory:
        """Simulate `n_frames` frames (frame 0 is t = 0) at `fps` (default: the camera's, else 30).

        `on_frame(frame, position_m, velocity_mps)` may return True to stop early; the
        trajectory then holds the frames simulated so far.
        """
        scene = self.scene
        fps = fps or (scene.camera.fps if scene.camera else 30.0)
        spf = scene.sim_hz / fps
        if abs(spf - round(spf)) > 1e-9:
            raise GalileoError(f"sim_hz {scene.sim_hz} is not a multiple of fps {fps}")
        spf = int(round(spf))
        w = self.reset(values)
        cid, bodies = w.cid, w.bodies
        n_obj = len(bodies)
        pos = np.empty((n_obj, n_frames, 3))
        vel = np.empty((n_obj, n_frames, 3))
        orn = np.empty((n_obj, n_frames, 4)) if with_orientation else None
        get_pose, get_vel, step = pb.getBasePositionAndOrientation, pb.getBaseVelocity, pb.stepSimulation
        done = n_frames
        for f in range(n_frames):
            if f:
                for _ in range(spf):
                    step(physicsClientId=cid)
            for i, b in enumerate(bodies):
                p, q = get_pose(b, physicsClientId=cid)
                pos[i, f] = p
                vel[i, f] = get_vel(b, physicsClientId=cid)[0]
                if orn is not None:
                    orn[i, f] = q
            if on_frame is not None and on_frame(f, pos[:, f], vel[:, f]):
                done = f + 1
                break
        return Trajectory(fps, [o.name for o in scene.objects], pos[:, :done], vel[:, :done],
                          None if orn is None else orn[:, :done])

    def poses(self) -> list[tuple[tuple, tuple]]:
        """Current (position, orientation) of each object (for renderers)."""
        w = self._world or self.world
        return [pb.getBasePositionAndOrientation(b, physicsClientId=w.cid) for b in w.bodies]
