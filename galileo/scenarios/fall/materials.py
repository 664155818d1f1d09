"""What the fall videos drop, and onto what: objects of the seed's 13 materials
(`galileo.materials`) as boxes, cylinders and tori of the sizes a hand drops, and the four
surface kinds (`scene.SURFACE_KINDS`), each with its own look and its own bounce and grip.

**The truth of an object-surface pair.** A surface kind sets the range of the restitution e
and of the friction mu (`Surface.e`, `Surface.mu`): a hard table bounces most (e 0.3-0.6), a
cloth laid over it less (0.2-0.4), a carpet little (0.1-0.25) and a foam mat least
(0.03-0.15); the soft ones grip more (mu: table 0.25-0.5, cloth 0.35-0.6, carpet 0.5-0.8,
foam 0.6-1.0). The ranges overlap where real surfaces do, so "which surface is bouncier" is a
question the videos answer, not the kind's name. A material scales both (`BOUNCE`, `GRIP`:
rubber bounces and grips more, foam bounces less, metal and porcelain slide more), and the
pair's values are drawn once per seed and pair (`pair_truth`): every video of that object on
that surface shares them, as the scene's shared latents e_<object>_<surface> and
mu_<object>_<surface> say.

**Objects** (`FallObject`, `catalogue`): per material `OBJECTS_PER_MATERIAL`, the shape
cycling through the material's (`SHAPES`), the longest side 5-11 cm (`SIZE_M`), proportions
drawn per shape; the mass is the material's density times the volume (it changes nothing
seen: the scene says so). Shapes are `galileo.shapes`' (object frame): a box's extents, a
cylinder's axis along x (diameter y = z), a torus flat with its hole along z (outer diameter
x = y, tube z).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...materials import SEED_MATERIALS, SEED_MATERIALS_BY_NAME
from ...shapes import Shape
from .scene import PRIORS

SIZE_M = (0.05, 0.11)                   # an object's longest side
OBJECTS_PER_MATERIAL = 2
# the shapes each material comes in (cycled over its objects)
SHAPES = {"foam": ("box",), "cardboard": ("box",), "hollow wood": ("box", "cylinder"),
          "hollow plastic": ("cylinder", "box"), "metal coin": ("cylinder",), "plastic block": ("box",),
          "metal pole": ("cylinder",), "porcelain": ("cylinder", "box"), "wooden block": ("box",),
          "rubber": ("box", "cylinder"), "wooden pole": ("cylinder",), "plastic rings": ("torus",),
          "plastic toys": ("box", "torus")}
# a cylinder's length over its diameter per material (a coin is a thick disc, a pole long), a box's
# two shorter sides over its longest, a torus's tube over its outer diameter
CYLINDER_ASPECT = {"metal coin": (0.12, 0.2), "metal pole": (3.0, 5.0), "wooden pole": (3.0, 5.0)}
CYLINDER_ASPECT_DEFAULT = (0.8, 1.6)
BOX_ASPECT = ((0.5, 1.0), (0.4, 0.9))
TORUS_TUBE = (0.2, 0.35)
# a material's bounce and grip, times its surface's (see the module)
BOUNCE = {"foam": 0.55, "cardboard": 0.75, "hollow wood": 0.95, "hollow plastic": 1.0, "metal coin": 1.05,
          "plastic block": 1.05, "metal pole": 1.05, "porcelain": 1.1, "wooden block": 1.0, "rubber": 1.4,
          "wooden pole": 1.0, "plastic rings": 1.1, "plastic toys": 1.0}
GRIP = {"foam": 1.3, "cardboard": 1.1, "hollow wood": 1.0, "hollow plastic": 0.9, "metal coin": 0.75,
        "plastic block": 0.9, "metal pole": 0.75, "porcelain": 0.8, "wooden block": 1.0, "rubber": 1.5,
        "wooden pole": 1.0, "plastic rings": 0.9, "plastic toys": 0.95}


@dataclass(frozen=True)
class Surface:
    """A surface kind: its rectangle (length along x, width along y), the slab's thickness
    (its top is z = 0), the floor's depth below its top, whether a table stands under it, how
    it looks (colours to draw from, `texture`: grain | speckle | fibre | weave) and its truth
    ranges."""
    kind: str
    size_m: tuple[float, float]
    thickness_m: float
    floor_below_m: float
    on_table: bool
    colors_rgb: tuple[tuple[int, int, int], ...]
    texture: str
    e: tuple[float, float]
    mu: tuple[float, float]


SURFACES: tuple[Surface, ...] = (
    Surface("table", (1.22, 0.61), 0.03, 0.75, False, ((214, 208, 188), (196, 160, 118), (150, 112, 78)), "grain",
            (0.3, 0.6), (0.25, 0.5)),
    Surface("foam", (1.0, 0.6), 0.04, 0.79, True, ((70, 120, 190), (90, 160, 110), (150, 150, 155)), "speckle",
            (0.03, 0.15), (0.6, 1.0)),
    Surface("carpet", (1.2, 0.8), 0.012, 0.012, False, ((120, 50, 50), (70, 80, 110), (120, 110, 95)), "fibre",
            (0.1, 0.25), (0.5, 0.8)),
    Surface("cloth", (1.22, 0.61), 0.003, 0.753, True, ((200, 60, 60), (60, 90, 160), (220, 210, 170)), "weave",
            (0.2, 0.4), (0.35, 0.6)),
)
SURFACES_BY_KIND = {s.kind: s for s in SURFACES}


@dataclass(frozen=True)
class FallObject:
    material: str
    index: int
    shape: Shape
    mass_kg: float

    @property
    def name(self) -> str:
        """A valid object id (it names the pair's latents): the material's letters and the index."""
        return f"{self.material.replace(' ', '')}{self.index}"

    @property
    def color_rgb(self) -> tuple[int, int, int]:
        return SEED_MATERIALS_BY_NAME[self.material].color_rgb


def make_shape(kind: str, material: str, longest_m: float, rng: np.random.Generator) -> Shape:
    """A `kind` shape of `material`'s proportions whose longest side is `longest_m`."""
    if kind == "box":
        a, b = (float(rng.uniform(*r)) for r in BOX_ASPECT)
        return Shape("box", (longest_m, a * longest_m, b * a * longest_m))
    if kind == "cylinder":
        ratio = float(rng.uniform(*CYLINDER_ASPECT.get(material, CYLINDER_ASPECT_DEFAULT)))
        length, d = (longest_m, longest_m / ratio) if ratio >= 1 else (ratio * longest_m, longest_m)
        return Shape("cylinder", (length, d, d))
    if kind == "torus":
        return Shape("torus", (longest_m, longest_m, float(rng.uniform(*TORUS_TUBE)) * longest_m))
    raise ValueError(f"unknown shape {kind!r}")


def catalogue(seed: int = 0) -> list[FallObject]:
    """The dataset's objects (13 materials x OBJECTS_PER_MATERIAL), drawn once per seed."""
    out = []
    for mi, mat in enumerate(SEED_MATERIALS):
        rng = np.random.default_rng([seed, 5000 + mi])
        for j in range(OBJECTS_PER_MATERIAL):
            kinds = SHAPES[mat.name]
            shape = make_shape(kinds[j % len(kinds)], mat.name, float(rng.uniform(*SIZE_M)), rng)
            mass = float(rng.uniform(*mat.density_kgpm3)) * shape.volume_m3
            out.append(FallObject(mat.name, j, shape, mass))
    return out


def pair_truth(obj: FallObject, surface: Surface, seed: int) -> tuple[float, float]:
    """(e, mu) of the object on the surface: drawn once per seed and pair (see the module),
    inside the scene's default priors."""
    rng = np.random.default_rng([seed, 7000, SURFACES.index(surface), *obj.name.encode()])
    e = BOUNCE[obj.material] * float(rng.uniform(*surface.e))
    mu = GRIP[obj.material] * float(rng.uniform(*surface.mu))
    (e_lo, e_hi), (mu_lo, mu_hi) = PRIORS["e"], PRIORS["mu"]
    return float(np.clip(e, e_lo + 0.01, e_hi - 0.05)), float(np.clip(mu, mu_lo + 0.01, mu_hi - 0.05))
