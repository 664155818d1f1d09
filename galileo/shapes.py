"""Shape primitives of the paper (box, cylinder, torus with per-axis scale).

Object frame (the frame in which `size_m` is given): x along the ramp's fall line
(downhill), y horizontal across the ramp, z normal to the surface the object rests on.

* box:      size_m = full extents (x, y, z).
* cylinder: lies on its side with its axis along x: length x, diameter y = z.
* torus:    lies flat with its hole's axis along z: outer diameter x = y, tube
            diameter z (so major radius (x - z)/2, minor radius z/2; needs x > 2 z).

The paper states its footnote in Bullet's y-up frame ("torus x = z, cylinder y = z");
in our z-up frame the same constraints read torus x = y, cylinder y = z.

Volumes, surface areas and inertia come from trimesh meshes of the shapes.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import trimesh

SHAPE_TYPES = ("box", "cylinder", "torus")
_SECTIONS = 48  # render-mesh resolution
_PHYS_SECTIONS = 128  # mesh resolution for volume, area and inertia (error < 0.1%)
TORUS_PARTS = 12  # convex pieces of a dynamic torus
BULLET_MESH_MARGIN_M = 0.001  # pybullet's collision margin around convex mesh shapes


@dataclass(frozen=True)
class Shape:
    type: str
    size_m: tuple[float, float, float]

    def __post_init__(self) -> None:
        object.__setattr__(self, "size_m", tuple(float(s) for s in self.size_m))

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
        if self.type not in SHAPE_TYPES:
            return f"type must be one of {', '.join(SHAPE_TYPES)}, got {self.type!r}"
        if len(self.size_m) != 3 or not all(math.isfinite(s) and s > 0 for s in self.size_m):
            return "size_m must be three positive numbers (metres)"
        sx, sy, sz = self.size_m
        if self.type == "cylinder" and not math.isclose(sy, sz, rel_tol=1e-6):
            return f"a cylinder needs size_m y == z (its diameter), got {sy} and {sz}"
        if self.type == "torus":
            if not math.isclose(sx, sy, rel_tol=1e-6):
                return f"a torus needs size_m x == y (its outer diameter), got {sx} and {sy}"
            if not sx > 2 * sz:
                return f"a torus needs outer diameter x > 2 * tube diameter z, got {sx} and {sz}"
        return None

    def to_json(self) -> dict:
        return {"type": self.type, "size_m": list(self.size_m)}


@functools.lru_cache(maxsize=256)
def mesh(shape: Shape) -> trimesh.Trimesh:
    """Watertight triangle mesh of the shape in the object frame, centred at its centre of mass."""
    sx, sy, sz = shape.size_m
    if shape.type == "box":
        return trimesh.creation.box(extents=(sx, sy, sz))
    if shape.type == "cylinder":
        m = trimesh.creation.cylinder(radius=sy / 2, height=sx, sections=_PHYS_SECTIONS)
        m.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, (0, 1, 0)))
        return m
    if shape.type == "torus":
        r = sz / 2
        return trimesh.creation.torus(
            major_radius=(sx - sz) / 2, minor_radius=r,
            major_sections=_PHYS_SECTIONS, minor_sections=_PHYS_SECTIONS)
    raise ValueError(shape.type)


@functools.lru_cache(maxsize=256)
def _inertia_per_kg(shape: Shape) -> np.ndarray:
    m = mesh(shape)
    m = m.copy()
    m.density = 1.0 / m.volume  # total mass 1 kg
    return np.diag(m.moment_inertia).copy()


def torus_convex_parts(shape: Shape, n_parts: int = TORUS_PARTS) -> list[np.ndarray]:
    """Vertices of `n_parts` convex pieces (ring sectors) whose union is the torus.

    A single convex hull would fill the hole and a triangle mesh cannot be dynamic in
    Bullet, so a dynamic torus is a compound of these pieces.
    """
    sx, _, sz = shape.size_m
    big_r, r = (sx - sz) / 2, sz / 2
    # circumscribe the tube polygon so the pieces do not shrink the tube, then take off the
    # collision margin Bullet adds around mesh shapes so the effective surface is the torus
    n_tube = 16
    r_out = max(r - BULLET_MESH_MARGIN_M, 0.5 * r) / math.cos(math.pi / n_tube)
    parts = []
    for i in range(n_parts):
        a = np.linspace(2 * math.pi * i / n_parts, 2 * math.pi * (i + 1) / n_parts, 4)
        t = np.linspace(0, 2 * math.pi, n_tube, endpoint=False) + math.pi / n_tube
        aa, tt = np.meshgrid(a, t, indexing="ij")
        rho = big_r + r_out * np.cos(tt)
        pts = np.stack([rho * np.cos(aa), rho * np.sin(aa), r_out * np.sin(tt)], -1).reshape(-1, 3)
        parts.append(pts)
    return parts


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


def render_mesh(shape: Shape) -> RenderMesh:
    """Triangle mesh with normals and texture coordinates (for the renderer)."""
    sx, sy, sz = shape.size_m
    n = _SECTIONS
    if shape.type == "box":
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
                faces.append(_grid(pts, nrm, uv_scale=(2 * half[a] / 0.05, 2 * half[b] / 0.05), flip=sgn < 0))
        return _concat(faces)
    if shape.type == "cylinder":
        r = sy / 2
        t = np.linspace(0, 2 * math.pi, n + 1)
        x = np.linspace(-sx / 2, sx / 2, 2)
        tt, xx = np.meshgrid(t, x, indexing="ij")
        pts = np.stack([xx, r * np.cos(tt), r * np.sin(tt)], -1)
        nrm = np.stack([np.zeros_like(tt), np.cos(tt), np.sin(tt)], -1)
        side = _grid(pts, nrm, uv_scale=(2 * math.pi * r / 0.05, sx / 0.05), flip=True)
        return _concat([side, _disc(sx / 2, r, 1.0, n), _disc(-sx / 2, r, -1.0, n)])
    if shape.type == "torus":
        big_r, r = (sx - sz) / 2, sz / 2
        a = np.linspace(0, 2 * math.pi, n + 1)
        t = np.linspace(0, 2 * math.pi, n // 2 + 1)
        aa, tt = np.meshgrid(a, t, indexing="ij")
        rho = big_r + r * np.cos(tt)
        pts = np.stack([rho * np.cos(aa), rho * np.sin(aa), r * np.sin(tt)], -1)
        nrm = np.stack([np.cos(tt) * np.cos(aa), np.cos(tt) * np.sin(aa), np.sin(tt)], -1)
        return _grid(pts, nrm, uv_scale=(2 * math.pi * big_r / 0.05, 2 * math.pi * r / 0.05))
    raise ValueError(shape.type)
