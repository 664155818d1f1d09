"""`save` and `load` for scene classes: a scene is one JSON file naming its scenario."""
from __future__ import annotations

from pathlib import Path

from . import registry
from .jsonio import write_json


class SceneFile:
    """`save` and `load` for a scenario's scene class (which names its `scenario` and has
    `to_json`): one JSON file, written atomically, read and checked by the scenario."""
    scenario: str

    def save(self, path: str | Path) -> None:
        write_json(path, self.to_json())

    @classmethod
    def load(cls, path: str | Path):
        return registry.load_scene(path)


# -- pieces of a scene file that several scenarios' parsers share -------------------------------------

def priors_of(data: dict, known) -> dict:
    """The file's "priors" section: {name: (low, high)} for names in `known` (each pair is
    checked against its latent by the scene's own `latent_specs`); SceneError otherwise."""
    from .errors import SceneError
    from .fields import field_value, show, unknown_fields

    pri = field_value(data, "priors", "", {})
    if not isinstance(pri, dict):
        raise SceneError("priors: expected an object {name: [low, high]}")
    unknown_fields(pri, tuple(known), "priors")
    out = {}
    for k, v in pri.items():
        if not (isinstance(v, list) and len(v) == 2):
            raise SceneError(f"priors.{k}: expected [low, high], got {show(v)}")
        out[k] = (v[0], v[1])
    return out


def bottom_up_of(data: dict) -> dict:
    """The file's "bottom_up" section (what a track said before any physics): finite numbers by name."""
    import math

    from .errors import SceneError
    from .fields import field_value

    bu = field_value(data, "bottom_up", "", {})
    if not (isinstance(bu, dict) and all(isinstance(k, str) and isinstance(v, (int, float)) and not isinstance(v, bool)
                                         and math.isfinite(v) for k, v in bu.items())):
        raise SceneError("bottom_up: expected an object of finite numbers")
    return {k: float(v) for k, v in bu.items()}


def check_camera_of(camera, fps: float, n_frames: int) -> None:
    """A scene's camera, if any: valid, and filming the scene's video (its fps and frame count)."""
    from .camera import check_camera
    from .errors import SceneError

    if camera is None:
        return
    check_camera(camera)
    if (camera.fps, camera.n_frames) != (fps, n_frames):
        raise SceneError(f"camera: its fps and n_frames ({camera.fps:g}, {camera.n_frames}) differ from the scene's "
                         f"({fps:g}, {n_frames})")
