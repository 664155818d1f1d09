"""The paper's 15 materials with real-world ballpark densities and friction ranges.

Friction is the Coulomb coefficient against the dataset's ramp (a smooth board) and
ground. Densities are effective densities (a hollow object's mass over its outer volume).
Each material lists the shapes its objects take, as (type, size ranges in metres along
object x, y, z); see `galileo.shapes` for what x, y, z mean per type.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...shapes import Shape, shape_class


@dataclass(frozen=True)
class Material:
    name: str
    density_kgpm3: tuple[float, float]
    friction: tuple[float, float]
    shapes: tuple[tuple[str, tuple[tuple[float, float], ...]], ...]
    color_rgb: tuple[int, int, int]
    n_objects: int  # objects of this material in the catalogue (4-12)


B, C, T = "box", "cylinder", "torus"
MATERIALS: tuple[Material, ...] = (
    Material("cardboard", (150, 300), (0.26, 0.34), ((B, ((0.05, 0.09), (0.04, 0.08), (0.04, 0.07))),), (176, 132, 84), 4),
    Material("dough", (1100, 1300), (0.28, 0.36), ((B, ((0.04, 0.06), (0.03, 0.05), (0.025, 0.04))), (C, ((0.05, 0.08), (0.03, 0.04), None))), (228, 210, 160), 5),
    Material("foam", (25, 60), (0.28, 0.35), ((B, ((0.05, 0.10), (0.04, 0.08), (0.03, 0.06))),), (236, 226, 90), 6),
    Material("hollow rubber", (200, 350), (0.28, 0.35), ((B, ((0.04, 0.07), (0.04, 0.06), (0.03, 0.05))), (C, ((0.05, 0.09), (0.03, 0.05), None))), (200, 60, 60), 4),
    Material("hollow wood", (200, 350), (0.20, 0.30), ((B, ((0.04, 0.08), (0.04, 0.07), (0.03, 0.06))),), (150, 100, 60), 5),
    Material("metal coin", (7000, 9000), (0.10, 0.18), ((B, ((0.025, 0.04), (0.025, 0.04), (0.01, 0.02))),), (190, 190, 200), 6),
    Material("metal pole", (2700, 7800), (0.12, 0.20), ((C, ((0.08, 0.14), (0.012, 0.022), None)),), (160, 165, 175), 4),
    Material("plastic block", (900, 1300), (0.16, 0.26), ((B, ((0.03, 0.06), (0.03, 0.06), (0.025, 0.05))),), (40, 110, 220), 5),
    Material("plastic doll", (300, 600), (0.20, 0.30), ((B, ((0.04, 0.06), (0.03, 0.04), (0.05, 0.08))),), (240, 150, 180), 6),
    Material("plastic ring", (900, 1200), (0.16, 0.26), ((T, ((0.06, 0.10), None, (0.012, 0.02))),), (60, 200, 90), 4),
    Material("plastic toy", (300, 700), (0.18, 0.28), ((B, ((0.04, 0.07), (0.04, 0.06), (0.03, 0.06))), (C, ((0.05, 0.08), (0.03, 0.05), None))), (250, 120, 30), 5),
    Material("porcelain", (2200, 2500), (0.14, 0.22), ((B, ((0.03, 0.05), (0.03, 0.05), (0.025, 0.04))), (C, ((0.04, 0.06), (0.03, 0.04), None))), (235, 235, 240), 6),
    Material("rubber", (1100, 1300), (0.30, 0.40), ((B, ((0.03, 0.05), (0.03, 0.05), (0.02, 0.04))),), (50, 50, 55), 4),
    Material("wooden block", (450, 750), (0.20, 0.30), ((B, ((0.04, 0.07), (0.04, 0.06), (0.03, 0.06))),), (205, 160, 100), 5),
    Material("wooden pole", (450, 750), (0.18, 0.28), ((C, ((0.10, 0.16), (0.015, 0.03), None)),), (170, 120, 70), 6),
)
MATERIALS_BY_NAME = {m.name: m for m in MATERIALS}

# targets on the ground: (size ranges x, y, z), mass range, friction range, colour
TARGETS = {
    "cardboard": (((0.09, 0.11), (0.07, 0.09), (0.06, 0.08)), (0.08, 0.15), (0.30, 0.40), (165, 120, 75)),
    "foam": (((0.07, 0.09), (0.07, 0.09), (0.05, 0.07)), (0.015, 0.04), (0.45, 0.60), (245, 240, 120)),
}


@dataclass(frozen=True)
class CatalogueObject:
    material: str
    index: int
    shape: Shape
    mass_kg: float
    friction: float


def _sample_shape(rng: np.random.Generator, kind: str, ranges) -> Shape:
    return shape_class(kind).sample(lambda axis: rng.uniform(*ranges[axis]))


def make_object(material: Material, index: int, rng: np.random.Generator, max_mass_kg: float = 0.95) -> CatalogueObject:
    kind, ranges = material.shapes[index % len(material.shapes)]
    for _ in range(100):
        shape = _sample_shape(rng, kind, ranges)
        mass = rng.uniform(*material.density_kgpm3) * shape.volume_m3
        if 0.005 <= mass <= max_mass_kg:
            break
    else:  # pragma: no cover - ranges above always admit a valid mass
        raise RuntimeError(f"no valid mass for {material.name}")
    return CatalogueObject(material.name, index, shape, float(mass), float(rng.uniform(*material.friction)))


def catalogue(seed: int = 0) -> list[CatalogueObject]:
    """The dataset's objects: 4-12 per material, shapes and sizes drawn once per seed."""
    out = []
    for mi, mat in enumerate(MATERIALS):
        rng = np.random.default_rng([seed, 1000 + mi])
        out += [make_object(mat, j, rng) for j in range(mat.n_objects)]
    return out


def sample_target(kind: str, rng: np.random.Generator) -> tuple[Shape, float, float]:
    sizes, mass, friction, _ = TARGETS[kind]
    shape = Shape("box", tuple(rng.uniform(*r) for r in sizes))
    return shape, float(rng.uniform(*mass)), float(rng.uniform(*friction))
