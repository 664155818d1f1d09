"""What the spring videos hang, and on what: the seed's 13 materials (Physics 101: foam,
cardboard, hollow wood, hollow plastic, metal coin, plastic block, metal pole, porcelain,
wooden block, rubber, wooden pole, plastic rings, plastic toys), 36 objects of 5-500 g, and the
two springs, "loose" and "tight".

Densities and colours are the seed's (`galileo.materials`, shared by every scenario). An object's
mass is drawn first, log-uniform in its material's range and stratified (the material's j-th of
n objects from the j-th of n equal slices of the log range, so every seed's catalogue spans the
ranges), then its density and proportions; its sizes follow. Shapes, in the world frame (the
camera looks along +y; nothing turns while it bounces):

* box:  extents (x, y, z), `aspect` = (y / x, z / x);
* pole: a cylinder lying across the image (axis x), `aspect` = length / diameter;
* disc: a coin facing the camera (axis y), `aspect` = thickness / diameter;
* cup:  an upright cylinder (axis z), `aspect` = height / diameter;
* ring: a torus facing the camera (hole along y), `aspect` = tube / outer diameter.

An object hangs in a clear bag whose knot is the spring's lower end, or from a hook into its
top (`mount`): `hang_m` (the spring's end to the object's centre) is the knot's or the hook's
length plus half the object's height.

The springs (`SPRINGS`): closed-coil extension springs, short unloaded, whose constants make
every object filmable at 30 fps on a spring it hangs from (`galileo.scenarios.spring.dataset`
says which fit which): a static extension of 3.5-60 cm, so a bounce period of 0.35-1.55 s (at
least 10 frames), and 1-5 % of the amplitude lost per period. No one spring takes 5-500 g (a
100-fold range of extensions): the loose one takes the light objects (5 g to about 70 g), the
tight one the heavy ones (about 20 g to 500 g); those in between hang on either.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...materials import SEED_MATERIALS_BY_NAME
from ...shapes import Shape

MASS_KG = (0.005, 0.5)          # the catalogue's masses (the 5-500 g)
MAX_SIZE_M = 0.2                # no object is longer than this (redrawn proportions otherwise)
KNOT_M = 0.03                   # a bag's knot and neck, from the spring's end to the object's top
HOOK_M = 0.025                  # a hook, from the spring's end to the object's top
BAG_SLACK_M = 0.004             # the bag's film around the object


@dataclass(frozen=True)
class Spring:
    """One of the dataset's springs: its true constants and how it is drawn (a helix of `coils`
    turns of `radius_m`, wire `wire_m` thick)."""
    name: str
    k_Npm: float
    mass_kg: float
    damping_Nspm: float
    rest_m: float
    coils: int
    radius_m: float
    wire_m: float
    color_rgb: tuple[int, int, int]


SPRINGS: tuple[Spring, ...] = (
    Spring("loose", 1.2, 0.003, 0.001, 0.03, 40, 0.008, 0.0008, (175, 175, 185)),
    Spring("tight", 9.0, 0.025, 0.008, 0.02, 28, 0.011, 0.0016, (120, 122, 130)),
)
SPRINGS_BY_NAME = {s.name: s for s in SPRINGS}


@dataclass(frozen=True)
class Material:
    name: str
    density_kgpm3: tuple[float, float]
    kinds: tuple[tuple[str, tuple], ...]     # (kind, aspect range(s)), cycled per object
    mass_kg: tuple[float, float]
    mounts: tuple[str, ...]                  # "bag" | "hook", cycled per object
    color_rgb: tuple[int, int, int]
    n_objects: int


BOX_ASPECT = ((0.6, 1.0), (0.5, 1.0))


def _material(name: str, kinds, mass_kg, mounts, n_objects: int) -> Material:
    """The seed's material `name` (its density and colour: `galileo.materials`) as the spring hangs it."""
    m = SEED_MATERIALS_BY_NAME[name]
    return Material(name, m.density_kgpm3, kinds, mass_kg, mounts, m.color_rgb, n_objects)


MATERIALS: tuple[Material, ...] = (
    _material("foam", (("box", BOX_ASPECT),), (0.005, 0.025), ("bag",), 3),
    _material("cardboard", (("box", BOX_ASPECT),), (0.01, 0.06), ("bag", "hook"), 3),
    _material("hollow wood", (("box", BOX_ASPECT), ("cup", (0.8, 1.5))), (0.015, 0.12), ("hook", "bag"), 3),
    _material("hollow plastic", (("cup", (1.0, 2.0)), ("box", BOX_ASPECT)), (0.008, 0.06), ("bag",), 3),
    _material("metal coin", (("disc", (0.06, 0.1)),), (0.005, 0.014), ("bag",), 3),
    _material("plastic block", (("box", BOX_ASPECT),), (0.03, 0.25), ("hook", "bag"), 3),
    _material("metal pole", (("pole", (5.0, 8.0)),), (0.25, 0.5), ("hook",), 3),
    _material("porcelain", (("cup", (0.8, 1.3)), ("box", BOX_ASPECT)), (0.06, 0.45), ("bag",), 3),
    _material("wooden block", (("box", BOX_ASPECT),), (0.04, 0.25), ("bag", "hook"), 3),
    _material("rubber", (("box", BOX_ASPECT), ("cup", (0.5, 1.0))), (0.02, 0.15), ("bag",), 3),
    _material("wooden pole", (("pole", (5.0, 8.0)),), (0.02, 0.1), ("hook",), 2),
    _material("plastic rings", (("ring", (0.15, 0.3)),), (0.005, 0.04), ("hook",), 2),
    _material("plastic toys", (("box", BOX_ASPECT), ("cup", (1.0, 1.6))), (0.01, 0.12), ("bag",), 2),
)
MATERIALS_BY_NAME = {m.name: m for m in MATERIALS}


@dataclass(frozen=True)
class CatalogueObject:
    material: str
    index: int
    kind: str                               # box | pole | disc | cup | ring
    size_m: tuple[float, float, float]      # world extents (x, y, z)
    mass_kg: float
    mount: str                              # bag | hook

    @property
    def name(self) -> str:
        """A valid object id (it names the mass latent): the material's letters and the index."""
        return f"{self.material.replace(' ', '')}{self.index}"

    @property
    def hang_m(self) -> float:
        """The spring's lower end to the object's centre."""
        return (KNOT_M + BAG_SLACK_M if self.mount == "bag" else HOOK_M) + self.size_m[2] / 2

    def shape(self) -> tuple[Shape, tuple[float, float, float, float]]:
        """The object as a `galileo.shapes` shape and the orientation (x, y, z, w) that turns it
        into the world's axes."""
        sx, sy, sz = self.size_m
        s = math.sqrt(0.5)
        if self.kind == "box":
            return Shape("box", (sx, sy, sz)), (0.0, 0.0, 0.0, 1.0)
        if self.kind == "pole":
            return Shape("cylinder", (sx, sy, sz)), (0.0, 0.0, 0.0, 1.0)
        if self.kind == "disc":     # the cylinder's axis x turned onto y
            return Shape("cylinder", (sy, sx, sz)), (0.0, 0.0, s, s)
        if self.kind == "cup":      # ... onto z
            return Shape("cylinder", (sz, sx, sy)), (0.0, -s, 0.0, s)
        if self.kind == "ring":     # the torus's hole axis z turned onto y
            return Shape("torus", (sx, sz, sy)), (s, 0.0, 0.0, s)
        raise ValueError(f"unknown kind {self.kind!r}")


def size_for(kind: str, volume_m3: float, aspect) -> tuple[float, float, float]:
    """World extents of a `kind` object of this volume and proportions (see the module)."""
    v = volume_m3
    if kind == "box":
        ry, rz = aspect
        x = (v / (ry * rz)) ** (1 / 3)
        return x, ry * x, rz * x
    if kind == "ring":      # V = 2 pi^2 R r^2, R = (D - t) / 2, r = t / 2, t = aspect D
        d = (v / (2 * math.pi ** 2 * (1 - aspect) / 2 * (aspect / 2) ** 2)) ** (1 / 3)
        return d, aspect * d, d
    d = (4 * v / (math.pi * aspect)) ** (1 / 3)     # cylinders: V = pi / 4 d^2 (aspect d)
    length = aspect * d
    return {"pole": (length, d, d), "disc": (d, length, d), "cup": (d, d, length)}[kind]


def make_object(material: Material, index: int, rng: np.random.Generator) -> CatalogueObject:
    """The material's index-th object (of n_objects): mass from the index-th slice of the
    material's log mass range, density and proportions drawn (redrawn while it is too long)."""
    kind, aspects = material.kinds[index % len(material.kinds)]
    lo, hi = np.log(material.mass_kg)
    edges = np.linspace(lo, hi, material.n_objects + 1)
    mass = float(np.exp(rng.uniform(edges[index], edges[index + 1])))
    for _ in range(100):
        density = float(rng.uniform(*material.density_kgpm3))
        aspect = (tuple(float(rng.uniform(*a)) for a in aspects) if kind == "box" else float(rng.uniform(*aspects)))
        size = size_for(kind, mass / density, aspect)
        if max(size) <= MAX_SIZE_M:
            break
    else:  # pragma: no cover - the ranges above always admit an object
        raise RuntimeError(f"no {kind} of {material.name} of {mass * 1e3:.0f} g fits in {MAX_SIZE_M} m")
    return CatalogueObject(material.name, index, kind, tuple(float(s) for s in size), mass,
                           material.mounts[index % len(material.mounts)])


def catalogue(seed: int = 0) -> list[CatalogueObject]:
    """The dataset's 36 objects, drawn once per seed."""
    out = []
    for mi, mat in enumerate(MATERIALS):
        rng = np.random.default_rng([seed, 3000 + mi])
        out += [make_object(mat, j, rng) for j in range(mat.n_objects)]
    return out
