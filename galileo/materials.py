"""The seed's 13 materials (Physics 101: foam, cardboard, hollow wood, hollow plastic, metal
coin, plastic block, metal pole, porcelain, wooden block, rubber, wooden pole, plastic rings,
plastic toys): what every scenario's rendered objects are made of.

Densities are real ones (kg/m^3; a hollow object's mass over its outer volume); the colour is
how the material is drawn. A scenario adds what is its own (the spring's masses and mounts,
the fall's bounce and grip: their `materials.py`).
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class SeedMaterial:
    name: str
    density_kgpm3: tuple[float, float]
    color_rgb: tuple[int, int, int]


SEED_MATERIALS: tuple[SeedMaterial, ...] = (
    SeedMaterial("foam", (25, 60), (236, 226, 90)),
    SeedMaterial("cardboard", (100, 250), (176, 132, 84)),
    SeedMaterial("hollow wood", (250, 450), (150, 100, 60)),
    SeedMaterial("hollow plastic", (150, 400), (60, 170, 200)),
    SeedMaterial("metal coin", (7000, 8900), (190, 190, 200)),
    SeedMaterial("plastic block", (1050, 1400), (40, 110, 220)),
    SeedMaterial("metal pole", (2700, 7800), (160, 165, 175)),
    SeedMaterial("porcelain", (1600, 2400), (235, 235, 240)),
    SeedMaterial("wooden block", (450, 750), (205, 160, 100)),
    SeedMaterial("rubber", (1100, 1500), (50, 50, 55)),
    SeedMaterial("wooden pole", (450, 750), (170, 120, 70)),
    SeedMaterial("plastic rings", (1040, 1100), (60, 200, 90)),
    SeedMaterial("plastic toys", (400, 900), (250, 120, 30)),
)
SEED_MATERIALS_BY_NAME = {m.name: m for m in SEED_MATERIALS}
