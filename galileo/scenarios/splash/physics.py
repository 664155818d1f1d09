"""Physics of the splash: an object let go above a tank of water, in Bullet (pybullet DIRECT).

Bullet has no fluids, so water acts through forces applied every physics step (Bullet
clears external forces after each step):

* Buoyancy: rho_water g V_sub upwards at the centre of the submerged volume (Archimedes).
  V_sub and its centre come from the object's convex mesh cut by the plane of the water
  (exactly: by the divergence theorem with the apex on the water plane, the cap of the cut
  contributes nothing, so only the clipped surface triangles are summed; compiled with
  numba, a few microseconds a step). The force acts at
  the centre of mass and the lever arm of the centre of buoyancy is applied as a torque, so
  a floating box rights itself. The mesh volume is scaled to the object's nominal volume.
* Drag: quadratic, F = -1/2 rho_water D A_ref |v| v, with D = drag_water below the surface
  and D = drag_air = 1e-3 drag_water above it (blended by the submerged fraction while the
  object crosses the surface); A_ref is the object's area projected on the plane normal to
  its velocity, from its shape and pose (closed forms: a box shows sum_i |u_i| A_i, a
  cylinder |u_axis| pi r^2 + sqrt(1 - u_axis^2) D L). Why quadratic: objects of a few
  centimetres at 0.1-2 m/s in water have Reynolds numbers of 10^3-10^5, where drag grows
  with the square of the speed and D is the usual drag coefficient (about 1 for a blunt
  body; the prior U(0.001, 2) spans it). The seed ties the air's coefficient to the water's
  by their density ratio, so D_a multiplies rho_water too.
* Rotational drag: -1/8 rho_water D A_mean r^3 |w| w (each surface patch at lever arm ~r/2
  moving at w r/2; r is half the largest dimension, A_mean the mean projected area), so a
  tumbling object settles.
Bullet's own damping is off (linear and angular 0) so nothing counts drag twice; sleeping
is off. The tank (floor and four glass walls) is static, friction 0.5, restitution 0.

The object's body is made anew for every run (its dimensions are a latent), in a world that
is built once per tank; a run from the same values reproduces itself bit for bit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
from numba import njit

from ...datatypes import Trajectory
from ...errors import GalileoError
from ...shapes import Box
from ...sim.bullet import cached_world, collision_shape, new_world, pb, visual_shape
from .scene import CM2, SplashScene, body_shape, dimensions

AIR_DRAG_RATIO = 1e-3        # D_a = 1e-3 D_w (the seed: the density ratio of air to water)
TANK_FRICTION = 0.5
SOLVER_ITERATIONS = 10
MESH_SECTIONS = 24           # a cylinder's facets for the submerged-volume cut
GLASS_COLOR = (0.75, 0.85, 0.9, 0.25)
MAX_KEPT_SHAPES = 64         # the object's shapes kept for reuse (one per bottom area proposed)


@dataclass
class Body:
    """The object's geometry for the water forces: a convex mesh in its object frame, its
    projected-area law and sizes."""
    kind: str
    dims: tuple[float, float, float]   # x, y, z as dropped (see scene.dimensions)
    shape: object                     # galileo.shapes shape (object frame)
    orn0: tuple                       # orientation at release
    tris: np.ndarray                  # (T, 3, 3) triangles, object frame, outward
    volume_scale: float               # nominal volume / mesh volume
    volume_m3: float
    half_extents: tuple               # box: half sizes; cylinder: (half length, radius)
    r_m: float                        # half the largest dimension
    mean_area_m2: float

    @classmethod
    def of(cls, kind: str, volume_m3: float, area_m2: float, max_dim_m: float = math.inf) -> "Body | None":
        dims = dimensions(kind, volume_m3, area_m2, max_dim_m)
        if dims is None:
            return None
        shape, orn0 = body_shape(kind, dims)
        m = shape.make_mesh(MESH_SECTIONS)
        tris = np.ascontiguousarray(m.triangles, float)
        if isinstance(shape, Box):
            half = tuple(s / 2 for s in shape.size_m)
            areas = (shape.size_m[1] * shape.size_m[2], shape.size_m[0] * shape.size_m[2],
                     shape.size_m[0] * shape.size_m[1])
            mean_area = sum(areas) / 2.0   # Cauchy: mean projection = surface / 4
        else:
            length, diam = shape.size_m[0], shape.size_m[1]
            half = (length / 2, diam / 2)
            mean_area = (2 * math.pi * (diam / 2) ** 2 + math.pi * diam * length) / 4.0
        return cls(kind, dims, shape, orn0, tris, volume_m3 / float(m.volume), volume_m3, half,
                   max(dims) / 2, mean_area)

    def projected_area(self, u_obj) -> float:
        """Area seen along the unit vector u (object frame)."""
        sx, sy, sz = self.shape.size_m
        if isinstance(self.shape, Box):
            return abs(u_obj[0]) * sy * sz + abs(u_obj[1]) * sx * sz + abs(u_obj[2]) * sx * sy
        ax = abs(u_obj[0])   # a cylinder's axis is its object x
        return ax * math.pi * (sy / 2) ** 2 + math.sqrt(max(0.0, 1.0 - ax * ax)) * sy * sx

    def z_extent(self, rot: tuple) -> float:
        """Half the object's vertical extent at rotation `rot` (row-major 3x3, object->world)."""
        r20, r21, r22 = rot[6], rot[7], rot[8]
        if isinstance(self.shape, Box):
            hx, hy, hz = self.half_extents
            return abs(r20) * hx + abs(r21) * hy + abs(r22) * hz
        hl, r = self.half_extents
        return abs(r20) * hl + r * math.sqrt(max(0.0, 1.0 - r20 * r20))


@njit(cache=True)
def _cut_below(tris, nx, ny, nz, d):  # pragma: no cover - compiled
    """(volume, cx, cy, cz) of the part of the closed, outward-oriented mesh `tris` (T, 3, 3)
    where n . x < d (n a unit vector). Tetrahedra from the apex q = n d, which lies on the
    plane, so the cap of the cut adds nothing; triangles the plane crosses are clipped."""
    qx, qy, qz = nx * d, ny * d, nz * d
    vol6 = 0.0
    mx = my = mz = 0.0
    pts = np.empty((4, 3))
    h = np.empty(3)
    for i in range(tris.shape[0]):
        below = 0
        for k in range(3):
            h[k] = tris[i, k, 0] * nx + tris[i, k, 1] * ny + tris[i, k, 2] * nz - d
            if h[k] < 0.0:
                below += 1
        if below == 0:
            continue
        n_pts = 3
        if below == 3:
            for k in range(3):
                for j in range(3):
                    pts[k, j] = tris[i, k, j]
        else:
            # a: the vertex on its own side; b, c follow it (the orientation is kept)
            a = 0
            for k in range(3):
                if (h[k] < 0.0) == (below == 1):
                    a = k
            b, c = (a + 1) % 3, (a + 2) % 3
            sb = h[a] / (h[a] - h[b])
            sc = h[a] / (h[a] - h[c])
            if below == 1:      # only a under water: (a, q_ab, q_ac)
                for j in range(3):
                    pts[0, j] = tris[i, a, j]
                    pts[1, j] = tris[i, a, j] + sb * (tris[i, b, j] - tris[i, a, j])
                    pts[2, j] = tris[i, a, j] + sc * (tris[i, c, j] - tris[i, a, j])
            else:               # a above, b and c under: the quad (q_ab, b, c, q_ac)
                n_pts = 4
                for j in range(3):
                    pts[0, j] = tris[i, a, j] + sb * (tris[i, b, j] - tris[i, a, j])
                    pts[1, j] = tris[i, b, j]
                    pts[2, j] = tris[i, c, j]
                    pts[3, j] = tris[i, a, j] + sc * (tris[i, c, j] - tris[i, a, j])
        for t in range(n_pts - 2):      # the fan (0, t + 1, t + 2)
            x0, x1, x2 = pts[0, 0] - qx, pts[0, 1] - qy, pts[0, 2] - qz
            y0, y1, y2 = pts[t + 1, 0] - qx, pts[t + 1, 1] - qy, pts[t + 1, 2] - qz
            z0, z1, z2 = pts[t + 2, 0] - qx, pts[t + 2, 1] - qy, pts[t + 2, 2] - qz
            v = x0 * (y1 * z2 - y2 * z1) + x1 * (y2 * z0 - y0 * z2) + x2 * (y0 * z1 - y1 * z0)
            vol6 += v
            mx += v * (x0 + y0 + z0)
            my += v * (x1 + y1 + z1)
            mz += v * (x2 + y2 + z2)
    if vol6 <= 0.0:
        return 0.0, qx, qy, qz
    return vol6 / 6.0, qx + mx / (4.0 * vol6), qy + my / (4.0 * vol6), qz + mz / (4.0 * vol6)


def submerged(tris: np.ndarray, level: float) -> tuple[float, np.ndarray]:
    """Volume (m^3) and centroid of the part of a closed, outward-oriented triangle mesh (world
    frame, (T, 3, 3)) below the plane z = level."""
    v, cx, cy, cz = _cut_below(np.ascontiguousarray(tris, float), 0.0, 0.0, 1.0, float(level))
    return v, np.array([cx, cy, cz])


class _World:
    """The tank in the process's client (static), built once per tank geometry."""

    def __init__(self, scene: SplashScene, visual: bool):
        self.key = (scene.geometry_key(), visual)
        cid = self.cid = new_world(scene.sim_hz, scene.gravity_mps2, SOLVER_ITERATIONS)
        t = scene.tank
        (sx, sy, sz), w = t.size_m, t.wall_m
        self.statics = []
        for half, pos in (([sx / 2 + w, sy / 2 + w, w / 2], [0, 0, -w / 2]),                  # floor
                          ([w / 2, sy / 2 + w, sz / 2], [-(sx / 2 + w / 2), 0, sz / 2]),     # walls
                          ([w / 2, sy / 2 + w, sz / 2], [sx / 2 + w / 2, 0, sz / 2]),
                          ([sx / 2, w / 2, sz / 2], [0, -(sy / 2 + w / 2), sz / 2]),
                          ([sx / 2, w / 2, sz / 2], [0, sy / 2 + w / 2, sz / 2])):
            col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=cid)
            vis = (pb.createVisualShape(pb.GEOM_BOX, halfExtents=half, rgbaColor=list(GLASS_COLOR),
                                        physicsClientId=cid) if visual else -1)
            b = pb.createMultiBody(0, col, vis, basePosition=pos, physicsClientId=cid)
            pb.changeDynamics(b, -1, lateralFriction=1.0, restitution=0.0, physicsClientId=cid)
            self.statics.append(b)
        self.body: int | None = None
        self.shapes: dict = {}    # shape -> (collision shape, visual shape) made in this world


class Simulator:
    """Simulates a splash scene; `run` may be called many times with different latents."""

    def __init__(self, scene: SplashScene, *, visual: bool = False):
        self.scene = scene
        self.visual = visual
        self.spf = None
        self.steps = 0
        self._bodies: dict = {}

    @property
    def world(self) -> _World:
        return cached_world((self.scene.geometry_key(), self.visual), lambda: _World(self.scene, self.visual))

    def body_of(self, area_cm2: float) -> Body | None:
        """The object's geometry with this bottom area (None: no such object fits; cached)."""
        key = float(area_cm2)
        if key not in self._bodies:
            o = self.scene.obj
            if len(self._bodies) > 64:
                self._bodies.clear()
            self._bodies[key] = Body.of(o.kind, o.volume_m3, key * CM2, self.scene.max_dim_m())
        return self._bodies[key]

    def _place(self, body: Body, values: dict) -> int:
        """A fresh object body at the release point, at rest, with the values' density."""
        w = self.world
        key = body.shape
        if key not in w.shapes and len(w.shapes) >= MAX_KEPT_SHAPES:
            # Bullet frees a collision shape only with its world (removeCollisionShape refuses
            # one a body has used, even a removed body): build the tank anew
            w.key = None
            w = self.world
        cid = w.cid
        if w.body is not None:
            pb.removeBody(w.body, physicsClientId=cid)
            w.body = None
        mass = values["density_g_cm3"] * 1000.0 * body.volume_m3
        if key not in w.shapes:    # one shape per object size, reused by later runs of that size
            w.shapes[key] = (collision_shape(body.shape, cid), visual_shape(body.shape, cid) if self.visual else -1)
        col, vis = w.shapes[key]
        b = pb.createMultiBody(mass, col, vis,
                               basePosition=list(self.scene.release_m), baseOrientation=list(body.orn0),
                               physicsClientId=cid)
        pb.changeDynamics(b, -1, lateralFriction=TANK_FRICTION, restitution=0.0, linearDamping=0.0,
                          angularDamping=0.0, rollingFriction=0.0, spinningFriction=0.0,
                          localInertiaDiagonal=(mass * body.shape.inertia_per_kg()).tolist(),
                          activationState=pb.ACTIVATION_STATE_DISABLE_SLEEPING, physicsClientId=cid)
        w.body = b
        return b

    def values(self, values: dict | None) -> dict:
        out = self.scene.latents()
        out.update(values or {})
        return out

    def frames(self, values: dict | None = None) -> "FrameStepper | None":
        """A stepper over one run from the release (at rest), step by step or frame by frame, or None
        where the values' area gives no object that fits (see scene.dimensions)."""
        v = self.values(values)
        body = self.body_of(v["area_cm2"])
        if body is None:
            return None
        fps = self.scene.fps
        spf = self.scene.sim_hz / fps
        if abs(spf - round(spf)) > 1e-9:
            raise GalileoError(f"sim_hz {self.scene.sim_hz} is not a multiple of fps {fps}")
        return FrameStepper(self, body, self._place(body, v), v, int(round(spf)))

    def run(self, n_frames: int, values: dict | None = None, fps: float | None = None,
            on_frame: Callable[[int, np.ndarray, np.ndarray], bool] | None = None,
            start_step: int = 0) -> Trajectory:
        """`n_frames` frames, frame f at physics step start_step + f * sim_hz / fps after the
        release (start_step 0: frame 0 is the object at rest at the release point): positions,
        velocities and orientations. `on_frame(frame, position, velocity)` may return True to
        stop early."""
        if fps is not None and abs(fps - self.scene.fps) > 1e-9:
            raise GalileoError(f"the splash simulates at its camera's {self.scene.fps:g} fps, not {fps:g}")
        stepper = self.frames(values)
        if stepper is None:
            raise GalileoError("no object of this volume shows that area from below and fits the tank")
        state = stepper.state()
        for _ in range(int(start_step)):
            state = stepper.step(state)
        pos = np.empty((1, n_frames, 3))
        vel = np.empty((1, n_frames, 3))
        orn = np.empty((1, n_frames, 4))
        done = n_frames
        for f in range(n_frames):
            if f:
                for _ in range(stepper.spf):
                    state = stepper.step(state)
            p, q, lin, _ = state
            pos[0, f], orn[0, f], vel[0, f] = p, q, lin
            if on_frame is not None and on_frame(f, pos[:, f], vel[:, f]):
                done = f + 1
                break
        return Trajectory(self.scene.fps, [self.scene.obj.name], pos[:, :done], vel[:, :done], orn[:, :done])


class FrameStepper:
    """One run, a frame at a time; the water's forces applied at every physics step."""

    def __init__(self, sim: Simulator, body: Body, body_id: int, values: dict, spf: int):
        sc = sim.scene
        self.sim, self.geom, self.b, self.spf = sim, body, body_id, spf
        self.cid = sim.world.cid
        t = sc.tank
        self.level = t.water_level_m
        self.rho_w = t.water_density_kg_m3
        self.g = sc.gravity_mps2
        self.d_water = float(values["drag_water"])
        self.d_air = AIR_DRAG_RATIO * self.d_water

    def state(self):
        """(position, orientation xyzw, linear velocity, angular velocity) now."""
        pos, orn = pb.getBasePositionAndOrientation(self.b, physicsClientId=self.cid)
        lin, ang = pb.getBaseVelocity(self.b, physicsClientId=self.cid)
        return pos, orn, lin, ang

    def forces(self, pos, orn, lin, ang) -> tuple[float, float]:
        """Apply buoyancy and drag for the coming step; returns (V_sub, submerged fraction)."""
        geom, cid, b = self.geom, self.cid, self.b
        rot = pb.getMatrixFromQuaternion(orn)
        ext = geom.z_extent(rot)
        z = pos[2]
        if z - ext >= self.level:
            v_sub, centre = 0.0, None
        elif z + ext <= self.level:
            v_sub, centre = geom.volume_m3, pos
        else:   # cut in the object frame: the water plane is n . x < d there, n = R^T z
            v_mesh, cx, cy, cz = _cut_below(geom.tris, rot[6], rot[7], rot[8], self.level - z)
            v_sub = v_mesh * geom.volume_scale
            centre = (pos[0] + rot[0] * cx + rot[1] * cy + rot[2] * cz, pos[1] + rot[3] * cx + rot[4] * cy + rot[5] * cz,
                      pos[2] + rot[6] * cx + rot[7] * cy + rot[8] * cz)
        frac = min(1.0, v_sub / geom.volume_m3)
        fx = fy = fz = tx = ty = tz = 0.0
        if v_sub > 0.0:
            fz = self.rho_w * self.g * v_sub
            dx, dy = centre[0] - pos[0], centre[1] - pos[1]
            tx, ty = dy * fz, -dx * fz          # (centre - pos) x (0, 0, fz)
        d = frac * self.d_water + (1.0 - frac) * self.d_air
        speed = math.sqrt(lin[0] * lin[0] + lin[1] * lin[1] + lin[2] * lin[2])
        if speed > 0.0:
            u = (lin[0] / speed, lin[1] / speed, lin[2] / speed)
            u_obj = (rot[0] * u[0] + rot[3] * u[1] + rot[6] * u[2], rot[1] * u[0] + rot[4] * u[1] + rot[7] * u[2],
                     rot[2] * u[0] + rot[5] * u[1] + rot[8] * u[2])
            k = -0.5 * self.rho_w * d * geom.projected_area(u_obj) * speed
            fx += k * lin[0]
            fy += k * lin[1]
            fz += k * lin[2]
        spin = math.sqrt(ang[0] * ang[0] + ang[1] * ang[1] + ang[2] * ang[2])
        if spin > 0.0:
            k = -0.125 * self.rho_w * d * geom.mean_area_m2 * geom.r_m ** 3 * spin
            tx += k * ang[0]
            ty += k * ang[1]
            tz += k * ang[2]
        pb.applyExternalForce(b, -1, (fx, fy, fz), pos, pb.WORLD_FRAME, physicsClientId=cid)
        if tx or ty or tz:
            pb.applyExternalTorque(b, -1, (tx, ty, tz), pb.WORLD_FRAME, physicsClientId=cid)
        return v_sub, frac

    def step(self, state=None):
        """One physics step with the water's forces (computed from `state`, the state now,
        when the caller has it); the state after it."""
        self.forces(*(state if state is not None else self.state()))
        pb.stepSimulation(physicsClientId=self.cid)
        self.sim.steps += 1
        return self.state()

    def advance(self):
        """Step to the next frame; its state."""
        state = self.state()
        for _ in range(self.spf):
            state = self.step(state)
        return state
