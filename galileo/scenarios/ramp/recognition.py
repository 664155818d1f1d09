"""What the recognition model (Galileo section 4) reads in the ramp scenario.

* The objects read from a frame: the ramp object (its latents m1_kg, k1) and the target
  (m2_kg, k2).
* A video's "Galileo label" for the ramp object: its friction is the MAP k1 whenever the
  object slides (one that holds on the ramp, as in a video in which nothing moves, only
  bounds it from below by tan of the ramp angle: no friction label); its mass is
  identified only through a collision (the velocities fix the ratio m1/m2, never the
  masses themselves), so it is labelled only when the tracked target moved, as the MAP
  ratio times the target's mass (the targets are the lab's weighed reference objects: the
  scene file states their mass).
* The dataset's examples: one per video (the ramp object; the object and its material from
  index.json; ground truth from truth.json).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ...errors import GalileoError
from ...jsonio import read_json
from ...readout import Readout

TARGET_MOVED_M = 0.005   # the tracked target moved at least this far: a collision was seen
RAMP_MOVED_M = 0.005     # the tracked ramp object moved at least this far: it slid


def readouts(scene) -> tuple[Readout, ...]:
    out = [Readout("ramp", {"mass_kg": ("m1_kg", 1.0), "friction": ("k1", 1.0)})]
    if scene.target is not None:
        out.append(Readout("target", {"mass_kg": ("m2_kg", 1.0), "friction": ("k2", 1.0)}))
    return tuple(out)


def _moved(tracks, role: str, threshold_m: float) -> bool | None:
    """Whether the tracked object of `role` moved further than `threshold_m` from where it
    was first seen; None when it is seen in fewer than two frames."""
    tr = tracks.by_role(role)
    if tr is None or tr.visible.sum() < 2:
        return None
    pos = tr.position_m[tr.visible]
    return bool(np.linalg.norm(pos - pos[0], axis=1).max() > threshold_m)


def collision_seen(tracks) -> bool:
    return bool(_moved(tracks, "target", TARGET_MOVED_M))


def label(scene, tracks, values: dict) -> dict:
    held = _moved(tracks, "ramp", RAMP_MOVED_M) is False   # it held on the ramp: k1 >= tan(angle), no more
    ramp = {"mass_kg": None, "friction": None if held else float(values["k1"])}
    out = {"ramp": ramp}
    if scene.target is not None and "m2_kg" in values:
        hit = collision_seen(tracks)
        if hit:
            ramp["mass_kg"] = float(values["m1_kg"] / values["m2_kg"] * scene.target.mass_kg)
        out["target"] = {"mass_kg": None, "friction": float(values["k2"]) if hit else None}
    return out


def examples(folder: Path) -> list:
    from ...recognition.data import Example, truth_json

    index = read_json(folder / "index.json", "dataset index")
    out = []
    for v in index["videos"]:
        try:
            name, material, obj = str(v["name"]), str(v["material"]), str(v["object"])
        except (KeyError, TypeError):
            raise GalileoError(f"{folder / 'index.json'}: a video entry without name, material and object") from None
        sub = folder / name
        if not (sub / "video.mp4").is_file() or not (sub / "scene.json").is_file():
            raise GalileoError(f"{sub}: missing video.mp4 or scene.json")
        lat = truth_json(sub).get("latents", {})
        out.append(Example(name, sub, obj, material, "ramp",
                           {"mass_kg": lat.get("m1_kg"), "friction": lat.get("k1")}))
    return out


def features(scene) -> np.ndarray:
    """The ramp's angle, the ramp object's size and start, the target's size and distance
    (zeros without one), for the simulation-trained model."""
    r = scene.ramp
    o = scene.ramp_object
    t = scene.target
    tv = [1.0, *t.shape.size_m, t.distance_m] if t is not None else [0.0, 0.0, 0.0, 0.0, 0.0]
    return np.array([np.sin(r.angle_rad), np.cos(r.angle_rad), *o.shape.size_m,
                     scene.start_distance_m(o), *tv], float)
