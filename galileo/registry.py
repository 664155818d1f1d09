"""Scenario name -> scenario. A scene file names its scenario (`"scenario": "ramp"`); files
without the field are ramp scenes (the format before scenarios had names).

Built-in scenarios are imported lazily (the ramp pulls in pybullet); `register` adds one
at run time (the tests register a small one of their own)."""
from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any

from .errors import SceneError
from .fields import show
from .model import Scenario

DEFAULT = "ramp"
_BUILTIN = {"ramp": "galileo.scenarios.ramp:RampScenario", "splash": "galileo.scenarios.splash:SplashScenario"}
_loaded: dict[str, Scenario] = {}


def register(scenario: Scenario) -> Scenario:
    """Make `scenario` known by its name (replacing one of the same name)."""
    if not scenario.name:
        raise ValueError("a scenario needs a name")
    _loaded[scenario.name] = scenario
    return scenario


def names() -> list[str]:
    return sorted(set(_BUILTIN) | set(_loaded))


def get(name: str) -> Scenario:
    if name not in _loaded:
        if name not in _BUILTIN:
            raise SceneError(f"unknown scenario {name!r}; known: {', '.join(names())}")
        module, cls = _BUILTIN[name].split(":")
        _loaded[name] = getattr(importlib.import_module(module), cls)()
    return _loaded[name]


def name_in(data: Any) -> str:
    """The scenario a parsed scene file names."""
    if isinstance(data, dict) and "scenario" in data:
        name = data["scenario"]
        if not isinstance(name, str):
            raise SceneError(f"scenario: expected a name, got {show(name)}")
        return name
    return DEFAULT


def of(scene) -> Scenario:
    """The scenario of a scene object."""
    return get(scene.scenario)


def scene_from_json(data: Any):
    return get(name_in(data)).scene_from_json(data)


def load_scene(path: str | Path):
    """A scene file of any registered scenario."""
    from .jsonio import read_json

    data = read_json(path, "scene file")
    try:
        return scene_from_json(data)
    except SceneError as e:
        raise SceneError(f"{path}: {e}") from None
