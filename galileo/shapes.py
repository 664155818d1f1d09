"""Shape primitives of the paper (box, cylinder, torus with per-axis scale).

Object frame (the frame in which `size_m` is given): x along the ramp's fall line
(downhill), y horizontal across the ramp, z normal to the surface the object rests on.

* box:      size_m = full extents (x, y, z).
* cylinder: lies on its side with its axis along x: length x, diameter y = z.
* torus:    lies flat with its hole's axis along z: outer diameter x = y, tube
            diameter z (so major radius (x - z)/2, minor radius z/2; needs x > 2 z).

The paper states its footnote in Bullet's y-up frame ("torus x = z, cylinder y = z");
in our z-up frame the same constraints read torus x = y, cylinder y = z.

Each type is one subclass of `Shape` that carries all its behaviour: meshes (physics,
render, coarse for ray casting), outline points for silhouettes, its validity rule, its
collision description for Bullet, and how to build one from measured or drawn sizes. A
subclass with a `name` registers itself: `Shape(name, size_m)` then builds it, and
scene files, tracks and the simulator take it with no other edit.

Volumes, surface areas and inertia come from trimesh meshes of the shapes.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, Callable, ClassVar

import numpy as np
import trimesh

_SECTIONS = 48  # render-mesh resolution
_PHYS_SECTIONS = 128  # mesh resolution for volume, area and inertia (error < 0.1%)
COARSE_SECTIONS = 32  # coarse mesh for ray casting (vision): sections around an axis
COARSE_TUBE_SECTIONS = 12  # ... and around a torus's tube
OUTLINE_SECTIONS = 24  # points per circle of a shape's outline (vision silhouettes)
TORUS_PARTS = 12  # convex pieces of a dynamic torus
BULLET_MESH_MARGIN_M = 0.001  # pybullet's collision margin around convex mesh shapes
CYLINDER_ROLLING_FRICTION = 0.0005  # Bullet: a cylinder rolling on its side slows a little
TORUS_MAX_TUBE = 0.45  # a measured or prior torus's tube diameter at most this x its outer diameter
TORUS_SAMPLE_MAX_TUBE = 0.4  # ... and a catalogue torus's
TEXTURE_TILE_M = 0.05  # render meshes: one texture repeat per this many metres
SMALL_MESH_M = 0.01  # a shape with a size under this is meshed at unit scale (trimesh's tolerances, `mesh`)

SHAPE_CLASSES: dict[str, type["Shape"]] = {}  # name -> class, filled as subclasses are defined


# -- collision descriptions (pybullet's words, without importing it) --------------------------

@dataclass(frozen=True)
class CollisionPrimitive:
    """One Bullet primitive: `geom` names pybullet's GEOM_* constant ("box", "cylinder",
    "sphere", ...), `args` are createCollisionShape's keyword arguments, `frame_euler` the
    primitive's orientation in the object frame (Euler angles, radians) or None."""
    geom: str
    args: dict[str, Any]
    frame_euler: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class CollisionHulls:
    """A compound of convex hulls, one Bullet mesh each (vertex arrays in the object frame);
    `name` keys the mesh files, so equal names must mean equal parts."""
    name: str
    parts: tuple[np.ndarray, ...]


Collision = CollisionPrimitive | CollisionHulls


# -- shapes -------------------------------------------------------------------------------

@dataclass(frozen=True, init=False)
class Shape:
    """A shape type (`type`, a registered name) with per-axis sizes in metres (object frame).

    `Shape("box", size)` builds the registered subclass (here `Box(size)`); an unknown name
    gives a plain `Shape` whose `problem()` says so. Immutable, hashable, equal by type and
    size.
    """
    type: str
    size_m: tuple[float, float, float]

    name: ClassVar[str] = ""                 # a subclass's registered type name
    rolling_friction: ClassVar[float] = 0.0  # Bullet's rolling friction for this type

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        if cls.__dict__.get("name"):
            SHAPE_CLASSES[cls.name] = cls

    def __new__(cls, *args, **kwargs):
        if cls is Shape:
            cls = SHAPE_CLASSES.get(args[0] if args else kwargs.get("type"), Shape)
        return object.__new__(cls)

    def __init__(self, *args, **kwargs) -> None:
        names = ("size_m",) if self.name and len(args) + len(kwargs) == 1 else ("type", "size_m")
        if len(args) > len(names):
            raise TypeError(f"{type(self).__name__}() takes {', '.join(names)}")
        bound = dict(zip(names, args), **kwargs)
        t = str(bound.get("type", self.name))
        if self.name and t != self.name:
            raise ValueError(f"a {type(self).__name__} has type {self.name!r}, not {t!r}")
        object.__setattr__(self, "type", t)
        object.__setattr__(self, "size_m", tuple(float(s) for s in bound["size_m"]))

    @staticmethod
    def from_json(d: dict) -> "Shape":
        return Shape(d["type"], tuple(d["size_m"]))

    def to_json(self) -> dict:
        return {"type": self.type, "size_m": list(self.size_m)}

    # -- derived geometry -------------------------------------------------
    @property
    def height_m(self) -> float:
        """Extent along the surface normal (object z)."""
        return self.size_m[2]

    @property
    def volume_m3(self) -> float:
        return float(mesh(self).volume)

    @property
    def surface_area_m2(self) -> float:
        return float(mesh(self).area)

    def inertia_per_kg(self) -> np.ndarray:
        """Principal moments of inertia (kg m^2 per kg of mass) about the centre, object axes."""
        return _inertia_per_kg(self)

    def problem(self) -> str | None:
        """Why this shape is invalid, or None."""
        if not self.name:
            return f"type must be one of {', '.join(SHAPE_CLASSES)}, got {self.type!r}"
        if len(self.size_m) != 3 or not all(math.isfinite(s) and s > 0 for s in self.size_m):
            return "size_m must be three positive numbers (metres)"
        return self._size_problem(*self.size_m)

    def box_corners(self) -> np.ndarray:
        """(8, 3) corners of the shape's bounding box (object frame)."""
        sx, sy, sz = self.size_m
        return np.array([[x, y, z] for x in (-sx / 2, sx / 2) for y in (-sy / 2, sy / 2) for z in (-sz / 2, sz / 2)])

    # -- what each type says about itself ---------------------------------
    def _size_problem(self, sx: float, sy: float, sz: float) -> str | None:
        """Why these (positive) sizes do not make a shape of this type, or None."""
        return None

    def make_mesh(self, sections: int, tube_sections: int | None = None) -> trimesh.Trimesh:
        """Watertight triangle mesh in the object frame, centred at the centre of mass, with
        `sections` around an axis (and `tube_sections` around a tube; default `sections`)."""
        raise ValueError(self.type)

    def render_mesh(self) -> "RenderMesh":
        """Triangle mesh with normals and texture coordinates (for the renderer)."""
        raise ValueError(self.type)

    def outline_points(self) -> np.ndarray:
        """Points on the surface whose projected convex hull is the shape's silhouette."""
        raise ValueError(self.type)

    def collision(self) -> Collision:
        """How Bullet should collide with this shape (see `galileo.sim.bullet.collision_shape`)."""
        raise ValueError(self.type)

    # (the three constructors below default to three free sizes, as a box has)
    @classmethod
    def from_measured(cls, length: float, depth: float, height: float) -> "Shape":
        """This type's shape nearest a measured extent along the support (length), across it
        (depth) and along its normal (height)."""
        return cls((length, depth, height))

    @classmethod
    def from_uniform_sizes(cls, sx: float, sy: float, sz: float) -> "Shape":
        """This type's shape from three sizes drawn independently (the prior over sizes)."""
        return cls((sx, sy, sz))

    @classmethod
    def sample(cls, draw: Callable[[int], float]) -> "Shape":
        """A random shape of this type; `draw(axis)` draws a size along object axis 0, 1 or 2
        (called only for the axes the type has free, in axis order)."""
        return cls((draw(0), draw(1), draw(2)))


def shape_class(name: str) -> type[Shape]:
    """The class registered for a type name (KeyError naming the known ones otherwise)."""
    try:
        return SHAPE_CLASSES[name]
    except KeyError:
        raise KeyError(f"unknown shape type {name!r}: one of {', '.join(SHAPE_CLASSES)}") from None


class Box(Shape):
    """size_m = full extents (x, y, z)."""
    name = "box"

    def make_mesh(self, sections: int, tube_sections: int | None = None) -> trimesh.Trimesh:
        return trimesh.creation.box(extents=self.size_m)

    def render_mesh(self) -> "RenderMesh":
        sx, sy, sz = self.size_m
        faces = []
        half = np.array([sx, sy, sz]) / 2
        for axis in range(3):
            a, b = (axis + 1) % 3, (axis + 2) % 3
            for sgn in (-1.0, 1.0):
                g = np.linspace(-1, 1, 2)
                ga, gb = np.meshgrid(g, g, indexing="ij")
                pts = np.zeros((2, 2, 3))
                pts[..., axis] = sgn * half[axis]
                pts[..., a] = ga * half[a]
                pts[..., b] = gb * half[b]
                nrm = np.zeros_like(pts)
                nrm[..., axis] = sgn
                # texture scaled by physical size so the pattern density is uniform
                faces.append(_grid(pts, nrm, uv_scale=(2 * half[a] / TEXTURE_TILE_M, 2 * half[b] / TEXTURE_TILE_M),
                                   flip=sgn < 0))
        return _concat(faces)

    def outline_points(self) -> np.ndarray:
        return self.box_corners()

    def collision(self) -> Collision:
        sx, sy, sz = self.size_m
        return CollisionPrimitive("box", {"halfExtents": [sx / 2, sy / 2, sz / 2]})



class Cylinder(Shape):
    """Lies on its side with its axis along x: length x, diameter y = z."""
    name = "cylinder"
    rolling_friction = CYLINDER_ROLLING_FRICTION

    def _size_problem(self, sx: float, sy: float, sz: float) -> str | None:
        if not math.isclose(sy, sz, rel_tol=1e-6):
            return f"a cylinder needs size_m y == z (its diameter), got {sy} and {sz}"
        return None

    def make_mesh(self, sections: int, tube_sections: int | None = None) -> trimesh.Trimesh:
        sx, sy, _ = self.size_m
        m = trimesh.creation.cylinder(radius=sy / 2, height=sx, sections=sections)
        m.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, (0, 1, 0)))
        return m

    def render_mesh(self) -> "RenderMesh":
        sx, sy, _ = self.size_m
        n = _SECTIONS
        r = sy / 2
        t = np.linspace(0, 2 * math.pi, n + 1)
        x = np.linspace(-sx / 2, sx / 2, 2)
        tt, xx = np.meshgrid(t, x, indexing="ij")
        pts = np.stack([xx, r * np.cos(tt), r * np.sin(tt)], -1)
        nrm = np.stack([np.zeros_like(tt), np.cos(tt), np.sin(tt)], -1)
        side = _grid(pts, nrm, uv_scale=(2 * math.pi * r / TEXTURE_TILE_M, sx / TEXTURE_TILE_M), flip=True)
        return _concat([side, _disc(sx / 2, r, 1.0, n), _disc(-sx / 2, r, -1.0, n)])

    def outline_points(self) -> np.ndarray:
        sx, sy, _ = self.size_m
        t = np.linspace(0, 2 * math.pi, OUTLINE_SECTIONS, endpoint=False)
        r = sy / 2
        ring = np.c_[np.zeros_like(t), r * np.cos(t), r * np.sin(t)]
        return np.concatenate([ring + [-sx / 2, 0, 0], ring + [sx / 2, 0, 0]])

    def collision(self) -> Collision:
        # Bullet's cylinder runs along z; ours lies along x
        sx, sy, _ = self.size_m
        return CollisionPrimitive("cylinder", {"radius": sy / 2, "height": sx}, frame_euler=(0, math.pi / 2, 0))

    @classmethod
    def from_measured(cls, length: float, depth: float, height: float) -> Shape:
        return cls((length, height, height))

    @classmethod
    def from_uniform_sizes(cls, sx: float, sy: float, sz: float) -> Shape:
        return cls((sx, sy, sy))

    @classmethod
    def sample(cls, draw: Callable[[int], float]) -> Shape:
        x = draw(0)
        d = draw(1)
        return cls((x, d, d))


class Torus(Shape):
    """Lies flat with its hole's axis along z: outer diameter x = y, tube diameter z."""
    name = "torus"

    @property
    def radii_m(self) -> tuple[float, float]:
        """Major radius (centre to the tube's centre) and minor radius (the tube's)."""
        sx, _, sz = self.size_m
        return (sx - sz) / 2, sz / 2

    def _size_problem(self, sx: float, sy: float, sz: float) -> str | None:
        if not math.isclose(sx, sy, rel_tol=1e-6):
            return f"a torus needs size_m x == y (its outer diameter), got {sx} and {sy}"
        if not sx > 2 * sz:
            return f"a torus needs outer diameter x > 2 * tube diameter z, got {sx} and {sz}"
        return None

    def make_mesh(self, sections: int, tube_sections: int | None = None) -> trimesh.Trimesh:
        big_r, r = self.radii_m
        return trimesh.creation.torus(major_radius=big_r, minor_radius=r, major_sections=sections,
                                      minor_sections=tube_sections or sections)

    def _tube_grid(self, around: np.ndarray, tube: np.ndarray, r: float):
        """Points (and the angle grids) on a torus of the shape's major radius and tube radius r."""
        big_r = self.radii_m[0]
        aa, tt = np.meshgrid(around, tube, indexing="ij")
        rho = big_r + r * np.cos(tt)
        return np.stack([rho * np.cos(aa), rho * np.sin(aa), r * np.sin(tt)], -1), aa, tt

    def render_mesh(self) -> "RenderMesh":
        n = _SECTIONS
        big_r, r = self.radii_m
        pts, aa, tt = self._tube_grid(np.linspace(0, 2 * math.pi, n + 1), np.linspace(0, 2 * math.pi, n // 2 + 1), r)
        nrm = np.stack([np.cos(tt) * np.cos(aa), np.cos(tt) * np.sin(aa), np.sin(tt)], -1)
        return _grid(pts, nrm, uv_scale=(2 * math.pi * big_r / TEXTURE_TILE_M, 2 * math.pi * r / TEXTURE_TILE_M))

    def outline_points(self) -> np.ndarray:
        t = np.linspace(0, 2 * math.pi, OUTLINE_SECTIONS, endpoint=False)
        return self._tube_grid(t, t[::2], self.radii_m[1])[0].reshape(-1, 3)

    def convex_parts(self, n_parts: int = TORUS_PARTS) -> list[np.ndarray]:
        """Vertices of `n_parts` convex pieces (ring sectors) whose union is the torus.

        A single convex hull would fill the hole and a triangle mesh cannot be dynamic in
        Bullet, so a dynamic torus is a compound of these pieces.
        """
        r = self.radii_m[1]
        # circumscribe the tube polygon so the pieces do not shrink the tube, then take off the
        # collision margin Bullet adds around mesh shapes so the effective surface is the torus
        n_tube = 16
        r_out = max(r - BULLET_MESH_MARGIN_M, 0.5 * r) / math.cos(math.pi / n_tube)
        parts = []
        for i in range(n_parts):
            a = np.linspace(2 * math.pi * i / n_parts, 2 * math.pi * (i + 1) / n_parts, 4)
            t = np.linspace(0, 2 * math.pi, n_tube, endpoint=False) + math.pi / n_tube
            parts.append(self._tube_grid(a, t, r_out)[0].reshape(-1, 3))
        return parts

    def collision(self) -> Collision:
        sx, _, sz = self.size_m
        return CollisionHulls(f"torus_{sx:.6f}_{sz:.6f}", tuple(self.convex_parts()))

    @classmethod
    def from_measured(cls, length: float, depth: float, height: float) -> Shape:
        return cls((length, length, min(height, TORUS_MAX_TUBE * length)))

    @classmethod
    def from_uniform_sizes(cls, sx: float, sy: float, sz: float) -> Shape:
        sy = sx = max(sx, sy)
        return cls((sx, sy, min(sz, TORUS_MAX_TUBE * sx)))

    @classmethod
    def sample(cls, draw: Callable[[int], float]) -> Shape:
        x = draw(0)
        return cls((x, x, min(draw(2), TORUS_SAMPLE_MAX_TUBE * x)))


SHAPE_TYPES: tuple[str, ...] = tuple(SHAPE_CLASSES)  # the types that ship, in the order they were defined


def build_mesh(shape: Shape, sections: int, tube_sections: int | None = None) -> trimesh.Trimesh:
    """`shape.make_mesh`; for a shape with a size under SMALL_MESH_M, built at the scale where
    its smallest size is 1 and scaled back. trimesh's primitives lose millimetre detail to
    absolute tolerances: a cylinder 1 mm thick came out not watertight with a negative volume
    (and negative inertia), a 1 cm torus with a 1 mm tube with volume 0, a 1.3 cm torus with a
    3.5 mm tube 39% too big. Scaled, every shape a scene may hold (sizes 1 mm to 2 m) meshes
    watertight with its volume within 1%; larger shapes are built as they always were."""
    low = min(shape.size_m)
    if not SMALL_MESH_M > low > 0 or not shape.name:
        return shape.make_mesh(sections, tube_sections)
    k = 1.0 / low
    m = type(shape)(tuple(s * k for s in shape.size_m)).make_mesh(sections, tube_sections)
    m.apply_scale(1.0 / k)
    return m


@functools.lru_cache(maxsize=256)
def mesh(shape: Shape) -> trimesh.Trimesh:
    """Watertight triangle mesh of the shape in the object frame, centred at its centre of mass."""
    return build_mesh(shape, _PHYS_SECTIONS)


@functools.lru_cache(maxsize=64)
def coarse_triangles(shape: Shape) -> np.ndarray:
    """(T, 3, 3) triangles of a coarse mesh of the shape (object frame), for ray casting."""
    return np.asarray(build_mesh(shape, COARSE_SECTIONS, COARSE_TUBE_SECTIONS).triangles)


@functools.lru_cache(maxsize=256)
def _inertia_per_kg(shape: Shape) -> np.ndarray:
    m = mesh(shape)
    m = m.copy()
    m.density = 1.0 / m.volume  # total mass 1 kg
    return np.diag(m.moment_inertia).copy()


# -- render meshes with texture coordinates ---------------------------------

@dataclass(frozen=True)
class RenderMesh:
    vertices: np.ndarray  # (V, 3)
    normals: np.ndarray   # (V, 3)
    uvs: np.ndarray       # (V, 2)
    indices: np.ndarray   # (T*3,)


def _grid(points: np.ndarray, normals: np.ndarray, uv_scale=(1.0, 1.0), flip=False) -> RenderMesh:
    nu, nv = points.shape[:2]
    u = np.linspace(0, uv_scale[0], nu)
    v = np.linspace(0, uv_scale[1], nv)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    idx = np.arange(nu * nv).reshape(nu, nv)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    tris = np.stack([a, b, c, a, c, d], -1).reshape(-1, 3)
    if flip:
        tris = tris[:, ::-1]
    return RenderMesh(points.reshape(-1, 3), normals.reshape(-1, 3),
                      np.stack([uu, vv], -1).reshape(-1, 2), tris.reshape(-1))


def _concat(meshes: list[RenderMesh]) -> RenderMesh:
    out_i, off = [], 0
    for m in meshes:
        out_i.append(m.indices + off)
        off += len(m.vertices)
    return RenderMesh(np.concatenate([m.vertices for m in meshes]), np.concatenate([m.normals for m in meshes]),
                      np.concatenate([m.uvs for m in meshes]), np.concatenate(out_i))


def _disc(center_x: float, radius: float, direction: float, n: int) -> RenderMesh:
    t = np.linspace(0, 2 * math.pi, n + 1)
    rr = np.array([0.0, radius])
    tt, rg = np.meshgrid(t, rr, indexing="ij")
    pts = np.stack([np.full_like(tt, center_x), rg * np.cos(tt), rg * np.sin(tt)], -1)
    nrm = np.zeros_like(pts)
    nrm[..., 0] = direction
    return _grid(pts, nrm, flip=direction < 0)
