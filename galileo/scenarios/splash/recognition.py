"""What the recognition model (Galileo section 4) reads in the splash scenario.

* The object read from a frame: the dropped object (tracked role "object"). Its mass is not
  a latent here: the latent is its density, and mass = density x the bottom-up volume (what
  tracking measured, in the prepared scene). So the readout's mass scale is the density
  (g/cm^3) per kilogram of this object, 1 / (1000 V) for V in m^3: a log-normal mass
  reading becomes a log-normal density start. There is no friction.
* A video's "Galileo label": mass = the MAP density x the bottom-up volume (every video
  identifies it: the object always falls into the water, and how it sinks or floats fixes
  its density); no friction.
* The dataset's examples: one per video (the object and its material from index.json;
  ground truth, the true mass, from truth.json).
* Scene features for the simulation-trained model: the bottom-up shape kind (one-hot), the
  log bottom-up volume and where it is let go (height above the water, across the tank).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ...errors import GalileoError
from ...jsonio import read_json
from ...readout import Readout
from .scene import CM3, KINDS

ROLE = "object"          # the role splash tracking gives the dropped object


def density_per_kg(scene) -> float:
    """The density latent (g/cm^3) per kilogram of the scene's object (of its volume)."""
    return 1.0 / (1000.0 * scene.volume_m3)


def readouts(scene) -> tuple[Readout, ...]:
    return (Readout(ROLE, {"mass_kg": ("density_g_cm3", density_per_kg(scene))}),)


def label(scene, tracks, values: dict) -> dict:
    d = values.get("density_g_cm3")
    log_factor = values.get("log_volume_factor", scene.log_volume_factor)   # the inferred volume's
    mass = None if d is None else float(d) * 1000.0 * scene.obj.volume_m3 * math.exp(float(log_factor))
    return {ROLE: {"mass_kg": mass, "friction": None}}


def examples(folder: Path) -> list:
    from ...recognition.data import Example, truth_json

    path = folder / "index.json"
    index = read_json(path, "dataset index")
    if not isinstance(index, dict) or not isinstance(index.get("videos"), list):
        raise GalileoError(f"{path}: expected a JSON object with the dataset's videos")
    out = []
    for i, v in enumerate(index["videos"]):
        try:
            name, material, obj = v["name"], v["material"], v["object"]
        except (KeyError, TypeError):
            raise GalileoError(f"{path}: video {i} has no name, material and object") from None
        if not all(isinstance(s, str) and s for s in (name, material, obj)) or "/" in name or name in (".", ".."):
            raise GalileoError(f"{path}: video {i}: name, material and object must be non-empty strings "
                               f"(and the name a folder's), got {name!r}, {material!r}, {obj!r}")
        sub = folder / name
        if not (sub / "video.mp4").is_file() or not (sub / "scene.json").is_file():
            raise GalileoError(f"{sub}: missing video.mp4 or scene.json")
        lat = truth_json(sub).get("latents", {})
        m = lat.get("mass_kg") if isinstance(lat, dict) else None
        if m is not None and (isinstance(m, bool) or not isinstance(m, (int, float)) or not math.isfinite(m)
                              or m <= 0):
            raise GalileoError(f"{sub / 'truth.json'}: latents.mass_kg must be a positive number, got {m!r}")
        out.append(Example(name, sub, obj, material, ROLE,
                           {"mass_kg": None if m is None else float(m), "friction": None}))
    return out


def features(scene) -> np.ndarray:
    """One-hot bottom-up kind (box, vcyl, hcyl), ln(volume / cm^3), the release point's height
    above the water and its x across the tank (m), for the simulation-trained model."""
    o = scene.obj
    onehot = [1.0 if o.kind == k else 0.0 for k in KINDS]
    x, _, z = scene.release_m
    return np.array([*onehot, math.log(o.volume_m3 / CM3), z - scene.tank.water_level_m, x], float)
