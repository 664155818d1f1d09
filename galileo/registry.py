"""Scenario name -> scenario. A scene file names its scenario (`"scenario": "ramp"`); files
without the field are ramp scenes (the format before scenarios had names).

Built-in scenarios are imported lazily (the ramp pulls in pybullet); `register` adds one
at run time (the tests register a small one of their own)."""
from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any

from .errors import GalileoError, SceneError
from .fields import show
from .joint import JointScenario, JointScene, joint_from_json, split_name, video_name
from .model import Scenario

DEFAULT = "ramp"
_BUILTIN = {"ramp": "galileo.scenarios.ramp:RampScenario", "splash": "galileo.scenarios.splash:SplashScenario",
            "spring": "galileo.scenarios.spring:SpringScenario", "fall": "galileo.scenarios.fall:FallScenario"}
_loaded: dict[str, Scenario] = {}


def register(scenario: Scenario) -> Scenario:
    """Make `scenario` known by its name (replacing one of the same name)."""
    if not scenario.name:
        raise ValueError("a scenario needs a name")
    _loaded[scenario.name] = scenario
    return scenario


def names() -> list[str]:
    return sorted(set(_BUILTIN) | set(_loaded))


def with_capability(capability: str) -> list[str]:
    """The names of the scenarios that have `capability` (see `galileo.model.CAPABILITIES`)."""
    return [n for n in names() if getattr(get(n), capability) is not None]


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
    """The scenario of a scene object (of a problem of several videos, or with fixed latents:
    a `galileo.joint.JointScenario` over its scenario)."""
    if isinstance(scene, JointScene):
        return JointScenario(get(scene.scenario))
    return get(scene.scenario)


def scene_from_json(data: Any):
    """A scene from its JSON: a scenario's scene file, or a problem's (`galileo.joint`: several
    videos, or latents fixed by a "fixed" section)."""
    return joint_from_json(data, get(name_in(data)).scene_from_json)


def problem(scenes, share=(), fixed: dict | None = None):
    """The problem of `scenes` (one per video, of one scenario) sharing the latents `share`,
    with `fixed` ({name or name@video: value}) fixed: a `JointScene`, or the one scene itself
    when there is nothing to join. Scenes that fix latents themselves (their files' "fixed"
    sections) keep them, per video, unless `fixed` names them too."""
    scenes = list(scenes)
    if not scenes:
        raise GalileoError("a problem needs at least one video")
    merged, plain, n = dict(fixed or {}), [], len(scenes)
    for v, s in enumerate(scenes):
        if isinstance(s, JointScene):
            if len(s.scenes) != 1:
                raise GalileoError("give each video of a problem its own scene file")
            for k, val in s.fixed.items():
                base, at = split_name(k)
                merged.setdefault(k if at is not None else video_name(base, v, n), val)
            s = s.scenes[0]
        plain.append(s)
    return scene_from_json({"scenario": plain[0].scenario, "videos": [s.to_json() for s in plain],
                            "share": list(share), "fixed": merged})


def load_scene(path: str | Path):
    """A scene file of any registered scenario."""
    from .jsonio import read_json

    data = read_json(path, "scene file")
    try:
        return scene_from_json(data)
    except SceneError as e:
        raise SceneError(f"{path}: {e}") from None
