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
