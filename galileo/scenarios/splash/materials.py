"""The seed's 13 materials for the splash videos: densities, colours, shape kinds, sizes, drag.

Densities (g/cm^3) are effective densities (a hollow object's mass over its outer volume)
and all lie inside the seed's density prior U(0.001, 2). Two materials would fall outside it
as solid pieces of their everyday stuff and are chosen lighter, on purpose:

* metal coin: magnesium-alloy tokens (1.74-1.85); a copper, nickel or steel coin (7-9) or an
  aluminium one (2.7) is denser than the prior allows;
* porcelain: hollow pieces (a small glazed cup or figurine with a cavity, 1.6-1.95); solid
  porcelain is 2.3-2.5.

Floaters (density < 1): foam, cardboard, hollow wood, hollow plastic, wooden block, wooden
pole, plastic toys. Sinkers: metal coin, plastic block, metal pole, porcelain, rubber,
plastic rings (polystyrene, 1.04-1.1: they sink slowly).

Shapes are the splash's three kinds: box (square bottom), vcyl (upright cylinder), hcyl
(cylinder lying down). `aspect` is height / side (box), height / diameter (vcyl) or
length / diameter (hcyl). The seed's rings are drawn as flat upright cylinders (no hole).
Drag coefficients are those of blunt bodies at Reynolds numbers 10^3-10^5: about 1.05 for
a box moving face first, 0.8-1.2 for a cylinder across its axis, 0.5-0.9 for short cylinders
along it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .scene import CM2, CM3, LATENT_SPECS, dimensions

MAX_DIM_M = 0.144       # the default tank's 16 cm inner width x 0.9 (see SplashScene.max_dim_m)


@dataclass(frozen=True)
class Material:
    name: str
    density_g_cm3: tuple[float, float]
    kinds: tuple[tuple[str, tuple[float, float]], ...]    # (kind, aspect range), cycled per object
    volume_cm3: tuple[float, float]
    drag: tuple[float, float]
    color_rgb: tuple[int, int, int]
    n_objects: int      # objects of this material in the catalogue


B, V, H = "box", "vcyl", "hcyl"
MATERIALS: tuple[Material, ...] = (
    Material("foam", (0.02, 0.08), ((B, (0.5, 1.0)),), (20, 100), (0.9, 1.2), (236, 226, 90), 3),
    Material("cardboard", (0.15, 0.35), ((B, (0.6, 1.0)),), (30, 100), (0.9, 1.2), (176, 132, 84), 3),
    Material("hollow wood", (0.25, 0.45), ((B, (0.6, 1.2)), (V, (0.8, 1.5))), (20, 80), (0.8, 1.1), (150, 100, 60), 3),
    Material("hollow plastic", (0.15, 0.40), ((V, (1.0, 2.0)), (B, (0.8, 1.5))), (20, 90), (0.7, 1.0), (60, 170, 200), 3),
    Material("metal coin", (1.74, 1.85), ((V, (0.08, 0.15)),), (1, 5), (0.9, 1.2), (190, 190, 200), 3),
    Material("plastic block", (1.05, 1.40), ((B, (0.5, 1.2)),), (5, 40), (0.9, 1.15), (40, 110, 220), 3),
    Material("metal pole", (1.30, 1.90), ((H, (3.0, 5.0)),), (3, 20), (0.8, 1.1), (160, 165, 175), 3),
    Material("porcelain", (1.60, 1.95), ((V, (0.8, 1.3)), (B, (0.7, 1.2))), (5, 40), (0.8, 1.1), (235, 235, 240), 3),
    Material("wooden block", (0.50, 0.75), ((B, (0.5, 1.2)),), (10, 80), (0.9, 1.15), (205, 160, 100), 3),
    Material("rubber", (1.10, 1.50), ((B, (0.5, 1.0)), (V, (0.5, 1.0))), (3, 30), (0.8, 1.1), (50, 50, 55), 3),
    Material("wooden pole", (0.50, 0.75), ((H, (3.0, 5.0)),), (5, 30), (0.8, 1.1), (170, 120, 70), 2),
    Material("plastic rings", (1.04, 1.10), ((V, (0.2, 0.4)),), (3, 15), (0.5, 0.9), (60, 200, 90), 2),
    Material("plastic toys", (0.40, 0.90), ((B, (0.8, 1.5)), (V, (1.0, 1.6))), (10, 60), (0.8, 1.1), (250, 120, 30), 2),
)
MATERIALS_BY_NAME = {m.name: m for m in MATERIALS}
SINKERS = tuple(m.name for m in MATERIALS if m.density_g_cm3[0] > 1.0)
FLOATERS = tuple(m.name for m in MATERIALS if m.density_g_cm3[1] < 1.0)


@dataclass(frozen=True)
class CatalogueObject:
    material: str
    index: int
    kind: str
    volume_cm3: float
    area_cm2: float
    density_g_cm3: float
    drag_water: float

    @property
    def mass_kg(self) -> float:
        return self.density_g_cm3 * self.volume_cm3 * 1e-3

    @property
    def name(self) -> str:
        return f"{self.material.replace(' ', '-')}{self.index}"


def area_for(kind: str, volume_cm3: float, aspect: float) -> float:
    """Bottom area (cm^2) of a `kind` object of this volume and aspect (see module)."""
    v = volume_cm3
    if kind == "box":        # V = a^2 (aspect a)
        return (v / aspect) ** (2.0 / 3.0)
    if kind == "vcyl":       # V = pi/4 D^2 (aspect D); area pi/4 D^2
        d = (4.0 * v / (math.pi * aspect)) ** (1.0 / 3.0)
        return math.pi / 4.0 * d * d
    if kind == "hcyl":       # V = pi/4 D^2 (aspect D); area = L D
        d = (4.0 * v / (math.pi * aspect)) ** (1.0 / 3.0)
        return aspect * d * d
    raise ValueError(f"unknown kind {kind!r}")


def make_object(material: Material, index: int, rng: np.random.Generator) -> CatalogueObject:
    """One object: kind cycled, volume, aspect, density and drag drawn; redrawn until it fits
    the tank and its bottom area lies inside the area prior."""
    kind, aspects = material.kinds[index % len(material.kinds)]
    lo_a, hi_a = LATENT_SPECS["area_cm2"].bounds
    for _ in range(200):
        vol = float(np.exp(rng.uniform(*np.log(material.volume_cm3))))
        area = area_for(kind, vol, float(rng.uniform(*aspects)))
        if lo_a <= area <= hi_a and dimensions(kind, vol * CM3, area * CM2, MAX_DIM_M) is not None:
            break
    else:  # pragma: no cover - the ranges above always admit an object
        raise RuntimeError(f"no {kind} of {material.name} fits")
    return CatalogueObject(material.name, index, kind, vol, area, float(rng.uniform(*material.density_g_cm3)),
                           float(rng.uniform(*material.drag)))


def catalogue(seed: int = 0) -> list[CatalogueObject]:
    """The dataset's objects (36), drawn once per seed."""
    out = []
    for mi, mat in enumerate(MATERIALS):
        rng = np.random.default_rng([seed, 2000 + mi])
        out += [make_object(mat, j, rng) for j in range(mat.n_objects)]
    return out
