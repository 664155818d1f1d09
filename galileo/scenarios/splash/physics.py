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
* Added mass: a body that accelerates in water must accelerate the water around it too, as
  if it weighed m + m_a. For a body moving along u (its direction of motion; straight down
  at rest), m_a = K_ADDED rho_water A_u^(3/2) V_sub / V, A_u its area projected along u:
  for a sphere (A = pi r^2) K_ADDED = (2/3) / sqrt(pi) gives potential flow's exact 1/2 rho V
  (Lamb, Hydrodynamics, sec. 92; Newman, Marine Hydrodynamics, table 4.3); a disc broadside,
  8/3 rho r^3, is then 21% under, a cube face on (0.7 rho V, Brennen 1982) 46% under, a plate
  edge on 0 (as it should be). Scaled by the submerged fraction, a floating body's heave
  added mass is about half the submerged body's, as for a floating hemisphere. The total
  momentum (m + m_a) v changes only by the forces (gravity, buoyancy, drag) and the
  tank's contacts; as a body enters the water and m_a grows, its velocity drops by the
  momentum handed to the water (von Karman's water-entry impulse, 1929); the water does not
  hand it back when m_a shrinks (a body leaving the water sheds its wake). Bullet integrates
  the body's own mass: the force applied is m / (m + m_a) (B + F_drag - m_a g - dm_a v / dt),
  dm_a the growth of m_a since the step before, so that Bullet's step gives
  v' = ((m + m_a_before) v + (m g + B + F_drag) dt) / (m + m_a). It changes the motion, not
  where it ends: terminal velocity and the floating draft are the same with or without it;
  a floating body heaves with period 2 pi sqrt((m + m_a) / (rho g A_waterline)). Rotations
  have no added inertia here.
* Rotational drag: -1/8 rho_water D A_mean r^3 |w| w (each surface patch at lever arm ~r/2
  moving at w r/2; r is half the largest dimension, A_mean the mean projected area), so a
  tumbling object settles.
Bullet's own damping is off (linear and angular 0) so nothing counts drag twice; sleeping
is off. The tank (floor and four glass walls) is static, friction 0.5, restitution 0.

The object's body is made anew for every run (its dimensions are a latent), in a world that
is built once per tank; a run from the same values reproduces itself bit for bit.
"""
from __future__ import annotations

import functools
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
K_ADDED = (2.0 / 3.0) / math.sqrt(math.pi)   # m_a = K rho A^(3/2): a sphere's 1/2 rho V (see module)
TANK_FRICTION = 0.5
SOLVER_ITERATIONS = 10
MESH_SECTIONS = 24           # a cylinder's facets for the submerged-volume cut
GLASS_COLOR = (0.75, 0.85, 0.9, 0.25)
HULL_MARGIN_M = 1e-4         # a cylinder's prism (`_collision`) collides this far outside its faces
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
    r_m: float                        # half the largest dimension
    mean_area_m2: float
    inertia_per_kg: np.ndarray        # principal moments (kg m^2 per kg), object axes: a solid body's
    is_box: bool
    hull: np.ndarray                  # the mesh's vertices (object frame): a cylinder's collision shape

    @classmethod
    def of(cls, kind: str, volume_m3: float, area_m2: float, max_dim_m: float = math.inf) -> "Body | None":
        dims = dimensions(kind, volume_m3, area_m2, max_dim_m)
        if dims is None:
            return None
        shape, orn0 = body_shape(kind, dims)
        sx, sy, sz = shape.size_m
        unit_tris, unit_volume, unit_points = _unit_mesh(type(shape))   # the unit shape's mesh, stretched
        tris = np.ascontiguousarray(unit_tris * np.array([sx, sy, sz]))
        if isinstance(shape, Box):
            mean_area = (sy * sz + sx * sz + sx * sy) / 2.0   # Cauchy: mean projection = surface / 4
            inertia = np.array([sy * sy + sz * sz, sx * sx + sz * sz, sx * sx + sy * sy]) / 12.0
        else:
            length, diam = sx, sy
            mean_area = (2 * math.pi * (diam / 2) ** 2 + math.pi * diam * length) / 4.0
            r2 = (diam / 2) ** 2
            inertia = np.array([r2 / 2, (3 * r2 + length * length) / 12, (3 * r2 + length * length) / 12])
        return cls(kind, dims, shape, orn0, tris, volume_m3 / (unit_volume * sx * sy * sz), volume_m3,
                   max(dims) / 2, mean_area, inertia, isinstance(shape, Box), unit_points * np.array([sx, sy, sz]))


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


@functools.lru_cache(maxsize=None)
def _unit_mesh(shape_type) -> tuple[np.ndarray, float, np.ndarray]:
    """(triangles (T, 3, 3), volume, vertices) of the unit shape's mesh (sizes 1 m: a box's
    sides, a cylinder's length and diameter): a shape of sizes (sx, sy, sz) is it stretched by
    them, its volume by their product (what the water's cut needs; meshing every proposed
    size anew cost more than simulating it)."""
    m = shape_type((1.0, 1.0, 1.0)).make_mesh(MESH_SECTIONS)
    return np.ascontiguousarray(m.triangles, float), float(m.volume), np.asarray(m.vertices, float)


@njit(cache=True)
def _projected(is_box, sx, sy, sz, u0, u1, u2):  # pragma: no cover - compiled
    """The area a box (sizes sx, sy, sz) or a cylinder (axis x, length sx, diameter sy) shows
    along the unit vector u (object frame)."""
    if is_box:
        return abs(u0) * sy * sz + abs(u1) * sx * sz + abs(u2) * sx * sy
    ax = abs(u0)
    return ax * math.pi * (sy / 2) ** 2 + math.sqrt(max(0.0, 1.0 - ax * ax)) * sy * sx


@njit(cache=True)
def _water(tris, c, px, py, pz, qx, qy, qz, qw, vx, vy, vz, wx, wy, wz, added_before):  # pragma: no cover
    """The water's force and torque on the body for the coming step (world frame; see the module
    docstring): buoyancy at the centre of the submerged volume, drag on the area shown along the
    motion, rotational drag, added mass with its entry impulse. `c`: the run's constants
    (`FrameStepper.constants`). Returns (fx, fy, fz, tx, ty, tz, added mass now, V_sub,
    submerged fraction)."""
    is_box, sx, sy, sz, volume, volume_scale, mean_area, r_m = c[0] > 0, c[1], c[2], c[3], c[4], c[5], c[6], c[7]
    level, rho_w, g, d_water, d_air, mass, dt = c[8], c[9], c[10], c[11], c[12], c[13], c[14]
    # the rotation matrix (row-major, object -> world) of the unit quaternion
    r0 = 1 - 2 * (qy * qy + qz * qz)
    r1 = 2 * (qx * qy - qz * qw)
    r2 = 2 * (qx * qz + qy * qw)
    r3 = 2 * (qx * qy + qz * qw)
    r4 = 1 - 2 * (qx * qx + qz * qz)
    r5 = 2 * (qy * qz - qx * qw)
    r6 = 2 * (qx * qz - qy * qw)
    r7 = 2 * (qy * qz + qx * qw)
    r8 = 1 - 2 * (qx * qx + qy * qy)
    if is_box:   # half the vertical extent
        ext = abs(r6) * sx / 2 + abs(r7) * sy / 2 + abs(r8) * sz / 2
    else:
        ext = abs(r6) * sx / 2 + sy / 2 * math.sqrt(max(0.0, 1.0 - r6 * r6))
    cx, cy = px, py
    if pz - ext >= level:
        v_sub = 0.0
    elif pz + ext <= level:
        v_sub = volume
    else:   # cut in the object frame: the water plane is n . x < d there, n = R^T z
        v_mesh, ox, oy, oz = _cut_below(tris, r6, r7, r8, level - pz)
        v_sub = v_mesh * volume_scale
        cx = px + r0 * ox + r1 * oy + r2 * oz
        cy = py + r3 * ox + r4 * oy + r5 * oz
    frac = min(1.0, v_sub / volume)
    fx = fy = fz = tx = ty = tz = 0.0
    if v_sub > 0.0:
        fz = rho_w * g * v_sub
        tx, ty = (cy - py) * fz, -(cx - px) * fz          # (centre - pos) x (0, 0, fz)
    d = frac * d_water + (1.0 - frac) * d_air
    speed = math.sqrt(vx * vx + vy * vy + vz * vz)
    if speed > 0.0:
        ux, uy, uz = vx / speed, vy / speed, vz / speed
        area_u = _projected(is_box, sx, sy, sz, r0 * ux + r3 * uy + r6 * uz, r1 * ux + r4 * uy + r7 * uz,
                            r2 * ux + r5 * uy + r8 * uz)
        k = -0.5 * rho_w * d * area_u * speed
        fx += k * vx
        fy += k * vy
        fz += k * vz
    else:   # at rest: its heave (straight down)
        area_u = _projected(is_box, sx, sy, sz, r6, r7, r8)
    added = 0.0
    if v_sub > 0.0 or added_before > 0.0:   # added mass (module docstring)
        added = K_ADDED * rho_w * area_u ** 1.5 * frac
        grow = max(0.0, added - added_before) / dt
        s = mass / (mass + added)
        fx = s * (fx - grow * vx)
        fy = s * (fy - grow * vy)
        fz = s * (fz + added * g - grow * vz)
    spin = math.sqrt(wx * wx + wy * wy + wz * wz)
    if spin > 0.0:
        k = -0.125 * rho_w * d * mean_area * r_m ** 3 * spin
        tx += k * wx
        ty += k * wy
        tz += k * wz
    return fx, fy, fz, tx, ty, tz, added, v_sub, frac


def _collision(body: Body, cid: int) -> int:
    """The object's Bullet collision shape: a box as it is; a cylinder as the convex prism of
    MESH_SECTIONS sides the water cuts (the same body for the water and the tank; Bullet
    makes a body of its cylinder primitive four times slower, 0.24 ms, than of a prism, and
    the splash makes one for every proposal)."""
    if body.is_box:
        return collision_shape(body.shape, cid)
    return pb.createCollisionShape(pb.GEOM_MESH, vertices=body.hull.tolist(), physicsClientId=cid)


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
        self.orn0 = scene.release_orientation()

    @property
    def world(self) -> _World:
        return cached_world((self.scene.geometry_key(), self.visual), lambda: _World(self.scene, self.visual))

    def body_of(self, area_cm2: float, log_volume_factor: float = 0.0) -> Body | None:
        """The object's geometry with this bottom area and log volume factor (None: no such object
        fits; cached)."""
        key = (float(area_cm2), float(log_volume_factor))
        if key not in self._bodies:
            o = self.scene.obj
            if len(self._bodies) > 64:
                self._bodies.clear()
            self._bodies[key] = Body.of(o.kind, o.volume_m3 * math.exp(key[1]), key[0] * CM2, self.scene.max_dim_m())
        return self._bodies[key]

    def _place(self, body: Body, values: dict) -> int:
        """A fresh object body at the release point, moving down at the values' push (m/s),
        with their density."""
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
            w.shapes[key] = (_collision(body, cid), visual_shape(body.shape, cid) if self.visual else -1)
        col, vis = w.shapes[key]
        b = pb.createMultiBody(mass, col, vis,
                               basePosition=list(self.scene.release_m), baseOrientation=list(self.orn0),
                               physicsClientId=cid)
        pb.changeDynamics(b, -1, lateralFriction=TANK_FRICTION, restitution=0.0, linearDamping=0.0,
                          angularDamping=0.0, rollingFriction=0.0, spinningFriction=0.0,
                          localInertiaDiagonal=(mass * body.inertia_per_kg).tolist(),
                          activationState=pb.ACTIVATION_STATE_DISABLE_SLEEPING, physicsClientId=cid)
        if not body.is_box:   # a convex hull keeps Bullet's margin outside it: 1 mm, a pixel of the video
            pb.changeDynamics(b, -1, collisionMargin=HULL_MARGIN_M, physicsClientId=cid)
        push = float(values.get("push_mps", 0.0))
        if push:
            pb.resetBaseVelocity(b, [0.0, 0.0, -push], [0.0, 0.0, 0.0], physicsClientId=cid)
        w.body = b
        return b

    def values(self, values: dict | None) -> dict:
        out = self.scene.latents()
        out.update(values or {})
        return out

    def frames(self, values: dict | None = None) -> "FrameStepper | None":
        """A stepper over one run from the release, step by step or frame by frame, or None where
        the values' area and volume give no object that fits (see scene.dimensions)."""
        v = self.values(values)
        body = self.body_of(v["area_cm2"], v["log_volume_factor"])
        if body is None:
            return None
        fps = self.scene.fps
        spf = self.scene.sim_hz / fps
        if abs(spf - round(spf)) > 1e-9:
            raise GalileoError(f"sim_hz {self.scene.sim_hz} is not a multiple of fps {fps}")
        return FrameStepper(self, body, self._place(body, v), v, int(round(spf)))

    def run(self, n_frames: int, values: dict | None = None, fps: float | None = None,
            on_frame: Callable[[int, np.ndarray, np.ndarray], bool] | None = None) -> Trajectory:
        """`n_frames` video frames: positions, velocities and orientations. The run steps from
        the release on its own grid; frame f falls at its step k - a + f * sim_hz / fps
        (`scene.frame_ticks`), its state interpolated between the two steps around it
        (`between`); frames before the release show the object held still at the release
        point. `on_frame(frame, position, velocity)` may return True to stop early."""
        if fps is not None and abs(fps - self.scene.fps) > 1e-9:
            raise GalileoError(f"the splash simulates at its camera's {self.scene.fps:g} fps, not {fps:g}")
        stepper = self.frames(values)
        if stepper is None:
            raise GalileoError("no object of this volume shows that area from below and fits the tank")
        k, a = self.scene.frame_ticks(self.values(values)["release_s"])
        state = stepper.state()
        held = (state[0], state[1], (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
        before, tick = None, 0       # the run's state at `tick` and at the step before it
        pos = np.empty((1, n_frames, 3))
        vel = np.empty((1, n_frames, 3))
        orn = np.empty((1, n_frames, 4))
        done = n_frames
        for f in range(n_frames):
            due = k + f * stepper.spf
            while tick < due:
                before, state = state, stepper.step(state)
                tick += 1
            if due < 0 or (due == 0 and a > 0):
                seen = held                                   # not let go yet
            else:
                seen = between(a, state, before) if a > 0 else state
            p, q, lin, _ = seen
            pos[0, f], orn[0, f], vel[0, f] = p, q, lin
            if on_frame is not None and on_frame(f, pos[:, f], vel[:, f]):
                done = f + 1
                break
        return Trajectory(self.scene.fps, [self.scene.obj.name], pos[:, :done], vel[:, :done], orn[:, :done])


def between(a: float, now: tuple, before: tuple) -> tuple:
    """The state (position, orientation xyzw, linear, angular velocity) a fraction a of a step
    before `now`, linear between `before` (the step before) and `now` (the orientation
    normalised, on the nearer of its two signs): a position's error is a dt^2 / 8, 0.02 mm a
    step of 1/240 s under gravity."""
    b = 1.0 - a
    p, q, lin, ang = now
    bp, bq, blin, bang = before
    if bq[0] * q[0] + bq[1] * q[1] + bq[2] * q[2] + bq[3] * q[3] < 0:
        bq = (-bq[0], -bq[1], -bq[2], -bq[3])
    qi = (b * q[0] + a * bq[0], b * q[1] + a * bq[1], b * q[2] + a * bq[2], b * q[3] + a * bq[3])
    norm = math.sqrt(qi[0] * qi[0] + qi[1] * qi[1] + qi[2] * qi[2] + qi[3] * qi[3])
    return ((b * p[0] + a * bp[0], b * p[1] + a * bp[1], b * p[2] + a * bp[2]),
            (qi[0] / norm, qi[1] / norm, qi[2] / norm, qi[3] / norm),
            (b * lin[0] + a * blin[0], b * lin[1] + a * blin[1], b * lin[2] + a * blin[2]),
            (b * ang[0] + a * bang[0], b * ang[1] + a * bang[1], b * ang[2] + a * bang[2]))


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
        self.mass_kg = float(values["density_g_cm3"]) * 1000.0 * body.volume_m3
        self.dt = 1.0 / sc.sim_hz
        self.added_kg = 0.0   # the added mass at the step before (none in the air at the release)
        g = body
        self.constants = np.array([float(g.is_box), *g.shape.size_m, g.volume_m3, g.volume_scale, g.mean_area_m2, g.r_m,
                                   self.level, self.rho_w, self.g, self.d_water, self.d_air, self.mass_kg, self.dt])

    def state(self):
        """(position, orientation xyzw, linear velocity, angular velocity) now."""
        pos, orn = pb.getBasePositionAndOrientation(self.b, physicsClientId=self.cid)
        lin, ang = pb.getBaseVelocity(self.b, physicsClientId=self.cid)
        return pos, orn, lin, ang

    def forces(self, pos, orn, lin, ang) -> tuple[float, float]:
        """Apply buoyancy, drag and added mass for the coming step (`_water`); returns (V_sub,
        submerged fraction)."""
        fx, fy, fz, tx, ty, tz, self.added_kg, v_sub, frac = _water(
            self.geom.tris, self.constants, pos[0], pos[1], pos[2], orn[0], orn[1], orn[2], orn[3],
            lin[0], lin[1], lin[2], ang[0], ang[1], ang[2], self.added_kg)
        pb.applyExternalForce(self.b, -1, (fx, fy, fz), pos, pb.WORLD_FRAME, physicsClientId=self.cid)
        if tx or ty or tz:
            pb.applyExternalTorque(self.b, -1, (tx, ty, tz), pb.WORLD_FRAME, physicsClientId=self.cid)
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
