"""What a recognition model reads in a scene (`Scenario.readouts(prepared_scene)`).

A readout names an object (by its tracked role) and, per quantity a recognition model may
read of it ("mass_kg", "friction"; later "stiffness_npm", "restitution"), the latent the
reading starts and the scale from the quantity to that latent. Which quantities a trained
model does read is the model's business: a quantity it does not read starts its latent
from the prior (`galileo.recognition.model.independence`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

MASS = "mass_kg"        # the two quantities the built-in LeNet reads
FRICTION = "friction"


@dataclass(frozen=True)
class Readout:
    """An object a recognition model reads from one frame (by its tracked role), and the
    latents its readings are: `reads` maps a quantity to (latent name, latent per unit of the
    quantity), e.g. {"mass_kg": ("m1_kg", 1.0), "friction": ("k1", 1.0)} for the ramp object,
    {"mass_kg": ("density_g_cm3", 1 / (1000 V))} for the splash's object of V m^3 (its density
    in g/cm^3 per kilogram of it)."""
    role: str
    reads: Mapping[str, tuple[str, float]] = field(default_factory=dict)

    def __post_init__(self):
        reads = {}
        for quantity, (latent, per_unit) in dict(self.reads).items():
            per_unit = float(per_unit)
            if not (isinstance(latent, str) and latent and math.isfinite(per_unit) and per_unit > 0):
                raise ValueError(f"readout {self.role!r}: {quantity} must map to a latent's name and a scale > 0, "
                                 f"got ({latent!r}, {per_unit!r})")
            reads[str(quantity)] = (latent, per_unit)
        object.__setattr__(self, "reads", reads)

    def latent(self, quantity: str) -> str | None:
        """The latent a reading of `quantity` starts (None: not read in this scene)."""
        hit = self.reads.get(quantity)
        return hit[0] if hit else None

    @property
    def mass(self) -> str | None:
        """The latent the mass reading starts."""
        return self.latent(MASS)

    @property
    def friction(self) -> str | None:
        """The latent the friction reading starts."""
        return self.latent(FRICTION)

    @property
    def mass_per_kg(self) -> float:
        """The mass latent's value per kilogram of the object (1 without a mass latent)."""
        return self.reads[MASS][1] if MASS in self.reads else 1.0
