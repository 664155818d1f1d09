"""Problems over several videos, and latents fixed at known values.

A problem is one or more videos of one scenario, each with its scene and tracks. Each video's
latents are the scenario's for its scene (`Scenario.latents`); across videos a latent is

* **per video** (each video its own value): named `<name>@<v>` in the chain (v = 1, 2, ... in the
  order the videos are given; with one video the names stay as they are),
* **shared** (one value for every video: the same object's friction on two ramps, one spring
  under two loads): named `<name>`; `share` names them, on top of what the scenario says its
  videos share (`Scenario.shared_latents`),
* **fixed** at a known value (a reference object of known mass): not sampled; `fixed` maps a
  name (`m_kg`: in every video, or `m_kg@2`: in video 2 only) to its value.

The chain's position is the flat vector of the free latents; the log-likelihood is the sum of the
videos' log-likelihoods, each at its own and the shared values. `JointScene` is scene-like (it has
`scenario`, `to_json`) and `registry.of(joint_scene)` gives a `JointScenario`, a `Scenario` over
it, so the runner, results, sessions and Dask run a problem of several videos the way they run
one video: `Tracks` become a list of the videos' tracks.

A scene file may fix latents itself with a top-level `"fixed": {"m_kg": 0.1103}` (the scenario's
own fields stay as they are); `galileo infer --fix NAME=VALUE` and `--share NAME` add to it.
"""
from __future__ import annotations

import dataclasses
import math
import threading
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from .datatypes import Tracks, Trajectory
from .errors import GalileoError, SceneError
from .fields import show
from .latents import Latent
from .model import Drawing, Scenario

SEP = "@"   # `<latent>@<video>`: a per-video latent in a problem of several videos


def video_name(name: str, v: int, n_videos: int) -> str:
    """The chain's name of latent `name` of video v (0-based) in a problem of n_videos videos."""
    return name if n_videos == 1 else f"{name}{SEP}{v + 1}"


def split_name(name: str) -> tuple[str, int | None]:
    """(latent, video 0-based or None): `m_kg@2` -> ("m_kg", 1); `k1` -> ("k1", None)."""
    base, sep, v = name.rpartition(SEP)
    if sep and v.isdigit() and int(v) >= 1:
        return base, int(v) - 1
    return name, None


@dataclass(frozen=True)
class JointScene:
    """The scenes of a problem's videos, with what they share and what is fixed (see the module)."""
    scenario: str
    scenes: tuple
    share: tuple[str, ...] = ()
    fixed: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"scenario": self.scenario, "videos": [s.to_json() for s in self.scenes],
                "share": list(self.share), "fixed": dict(self.fixed)}

    @property
    def camera(self):
        return getattr(self.scenes[0], "camera", None)


def is_joint_json(data: Any) -> bool:
    return isinstance(data, dict) and ("videos" in data or "fixed" in data)


def _names(value, what: str) -> tuple[str, ...]:
    if not isinstance(value, (list, tuple)) or not all(isinstance(x, str) and x for x in value):
        raise SceneError(f"{what}: expected a list of latent names, got {show(value)}")
    return tuple(value)


def _fixed(value, what: str) -> dict[str, float]:
    if not isinstance(value, dict):
        raise SceneError(f"{what}: expected {{name: value}}, got {show(value)}")
    out = {}
    for k, v in value.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise SceneError(f"{what}.{k}: expected a finite number, got {show(v)}")
        out[str(k)] = float(v)
    return out


def joint_from_json(data: dict, parse) -> JointScene | Any:
    """A problem's scene from its JSON: {"videos": [scene, ...], "share": [...], "fixed": {...}}
    (a top-level "priors" is merged into every video's), or one scenario scene file with a
    "fixed" section. `parse(scene_json)` parses one video's scene. A plain scene comes back as it
    is (no videos, nothing fixed)."""
    data = dict(data)
    fixed = _fixed(data.pop("fixed", {}), "fixed")
    if "videos" in data:
        videos = data["videos"]
        if not isinstance(videos, list) or not videos:
            raise SceneError(f"videos: expected a non-empty list of scenes, got {show(videos)}")
        share = _names(data.get("share", []), "share")
        priors = data.get("priors")
        scenes = []
        for i, v in enumerate(videos):
            if not isinstance(v, dict):
                raise SceneError(f"videos[{i}]: expected a scene object, got {show(v)}")
            v = dict(v)
            if priors:
                v["priors"] = {**(v.get("priors") or {}), **priors}
            try:
                scenes.append(parse(v))
            except SceneError as e:
                raise SceneError(f"videos[{i}]: {e}") from None
    else:
        share, scenes = (), [parse(data)]
    names = {s.scenario for s in scenes}
    if len(names) != 1:
        raise SceneError(f"videos: a problem's videos are of one scenario, got {', '.join(sorted(names))}")
    if len(scenes) == 1 and not fixed:
        return scenes[0]
    return JointScene(scenes[0].scenario, tuple(scenes), share, fixed)


def tracks_list(tracks) -> list[Tracks]:
    """The tracks of each video: one video's `Tracks`, or a problem's list of them."""
    return list(tracks) if isinstance(tracks, (list, tuple)) else [tracks]


def tracks_to_json(tracks) -> dict | list:
    """A tracks file's content: one video's `Tracks.to_json()`, or a problem's list of them."""
    return [t.to_json() for t in tracks] if isinstance(tracks, (list, tuple)) else tracks.to_json()


def tracks_from_json(data) -> Tracks | list[Tracks]:
    """`tracks_to_json` read back."""
    return [Tracks.from_json(t) for t in data] if isinstance(data, list) else Tracks.from_json(data)


@dataclass(frozen=True)
class Layout:
    """Where each video's latents come from: per video, per latent, ("free", j) (the chain's
    latent j) or ("fixed", value)."""
    latents: tuple[Latent, ...]                       # the chain's free latents, flat names
    sources: tuple[tuple[tuple[str, str, Any], ...], ...]   # per video: (name, "free"|"fixed", j | value)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(lat.name for lat in self.latents)

    def values(self, v: int, position) -> dict[str, float]:
        """Video v's latent values at a chain position."""
        pos = np.asarray(position, float)
        return {name: float(pos[x]) if kind == "free" else float(x) for name, kind, x in self.sources[v]}

    def vector(self, v: int, position) -> np.ndarray:
        return np.array(list(self.values(v, position).values()), float)


def layout(base: Scenario, scene: JointScene, prepared: Sequence) -> Layout:
    """The chain's latents for a joint scene (see the module), checked: a shared or fixed name
    must be some video's latent."""
    n = len(prepared)
    share = set(scene.share) | set(base.shared_latents(list(prepared)))
    per_video = [base.latents(p) for p in prepared]
    known = {lat.name for lats in per_video for lat in lats}
    for name in sorted(share):
        if name not in known:
            raise GalileoError(f"--share {name}: no video has that latent; latents: {', '.join(sorted(known))}")
    fixed: list[dict[str, float]] = [{} for _ in range(n)]
    for key, value in scene.fixed.items():
        base_name, at = split_name(key)
        if at is not None and at >= n:
            raise GalileoError(f"fixed {key}: there are {n} videos")
        videos = [at] if at is not None else range(n)
        hit = False
        for v in videos:
            if any(lat.name == base_name for lat in per_video[v]):
                fixed[v][base_name], hit = value, True
        if not hit:
            raise GalileoError(f"fixed {key}: no such latent; latents: {', '.join(sorted(known))}")
    free: list[Latent] = []
    index: dict[str, int] = {}
    sources = []
    for v, lats in enumerate(per_video):
        row = []
        for lat in lats:
            if lat.name in fixed[v]:
                value = fixed[v][lat.name]
                lo, hi = lat.limits
                if not (lo < value <= hi if lat.limits_open_low else lo <= value <= hi):
                    raise GalileoError(f"fixed {lat.name} = {value:g} {lat.unit} is outside its limits [{lo:g}, {hi:g}]")
                row.append((lat.name, "fixed", value))
                continue
            flat = lat.name if lat.name in share else video_name(lat.name, v, n)
            if flat not in index:
                index[flat] = len(free)
                free.append(dataclasses.replace(lat, name=flat))
            row.append((lat.name, "free", index[flat]))
        sources.append(tuple(row))
    if not free:
        raise GalileoError("every latent is fixed: nothing to infer")
    return Layout(tuple(free), tuple(sources))


MEMO_SIZE = 16   # per video, the last whole evaluations kept (the chain's current states among them)


class JointLikelihood:
    """The sum of the videos' log-likelihoods (each at its own and the shared latents).

    A video whose values a proposal leaves as they were (a move of another video's latent) is
    not evaluated again: its last whole values are kept (per video, the MEMO_SIZE latest; each
    a deterministic function of the video's values, so this is exact). The others are evaluated
    in order, and the last of them gets what is left of the threshold, so an early stop there is
    exact: its value is an upper bound below its share, and the sum one below the threshold."""

    def __init__(self, parts: Sequence, lay: Layout, speedups: bool = True):
        self.parts = list(parts)
        self.layout = lay
        self.names = lay.names
        self.speedups = speedups
        self._memo: list[OrderedDict] = [OrderedDict() for _ in self.parts]
        self._lock = threading.Lock()

    @property
    def steps(self) -> int:
        return int(sum(p.steps for p in self.parts))

    def _remember(self, v: int, key: tuple, value: float) -> None:
        with self._lock:
            memo = self._memo[v]
            memo[key] = value
            memo.move_to_end(key)
            while len(memo) > MEMO_SIZE:
                memo.popitem(last=False)

    def __call__(self, position, threshold: float | None = None) -> tuple[float, bool]:
        total = 0.0
        todo = []
        for v in range(len(self.parts)):
            x = self.layout.vector(v, position)
            key = tuple(x.tolist())
            with self._lock:
                known = self._memo[v].get(key) if self.speedups else None
            if known is None:
                todo.append((v, x, key))
            else:
                total += known
        for i, (v, x, key) in enumerate(todo):
            if total == -math.inf:
                return total, False
            last = i == len(todo) - 1
            if last and threshold is not None and self.speedups:
                value, stopped = self.parts[v](x, threshold - total)
            else:
                value, stopped = self.parts[v](x)
            if not stopped:
                self._remember(v, key, float(value))
            total += float(value)
            if stopped:
                return total, True
        return total, False

    def motion(self, position, video: int = 0) -> Trajectory:
        """The motion video `video` scored at this position."""
        return self.parts[video].motion(self.layout.vector(video, position))


class JointScenario(Scenario):
    """A scenario over a `JointScene`: the videos' scenario (`base`) for each video, joined as the
    module says. What it cannot join (tracking several videos at once, recognition from one
    frame) it leaves out: readouts are empty."""

    def __init__(self, base: Scenario):
        self.base = base
        self.name = base.name
        self.description = base.description
        self.noise = base.noise
        self.protocol = base.protocol
        self.paper_priors = base.paper_priors
        self.paper_widths = base.paper_widths
        self.starts_doc = base.starts_doc
        self.adaptive_walk = base.adaptive_walk
        self.converge_moves = base.converge_moves

    # -- scenes --------------------------------------------------------------------------------
    def scene_from_json(self, data):
        return joint_from_json(data, self.base.scene_from_json)

    def default_scene(self):
        return self.base.default_scene()

    def track(self, video_path, scene, *, progress=True, debug_video=None):
        if len(scene.scenes) != 1:
            raise GalileoError("track each video of a problem with its own scene")
        return self.base.track(video_path, scene.scenes[0], progress=progress, debug_video=debug_video)

    def prepare(self, scene: JointScene, tracks):
        ts = tracks_list(tracks)
        if len(ts) != len(scene.scenes):
            raise GalileoError(f"{len(scene.scenes)} video(s) but {len(ts)} set(s) of tracks")
        return dataclasses.replace(scene, scenes=tuple(self.base.prepare(s, t) for s, t in zip(scene.scenes, ts)))

    def latents(self, scene: JointScene) -> tuple[Latent, ...]:
        return layout(self.base, scene, scene.scenes).latents

    def values(self, scene: JointScene) -> dict[str, float]:
        """The free latents' values in the videos' scenes (a shared one: the first video's)."""
        lay = layout(self.base, scene, scene.scenes)
        out: dict[str, float] = {}
        for s, row in zip(scene.scenes, lay.sources):
            own = self.base.values(s)
            for name, kind, x in row:
                if kind == "free" and lay.names[x] not in out:
                    out[lay.names[x]] = own[name]
        return {n: out[n] for n in lay.names}

    def with_values(self, scene: JointScene, values: dict[str, float]):
        n = len(scene.scenes)
        per: list[dict] = [{} for _ in range(n)]
        for k, val in values.items():
            base_name, at = split_name(k)
            for v in ([at] if at is not None else range(n)):
                if v >= n:
                    raise SceneError(f"{k}: there are {n} videos")
                per[v][base_name] = val
        return dataclasses.replace(scene, scenes=tuple(self.base.with_values(s, d) if d else s
                                                       for s, d in zip(scene.scenes, per)))

    # -- physics and likelihood --------------------------------------------------------------------
    def likelihood(self, prepared_scene: JointScene, tracks, noise, speedups=True):
        lay = layout(self.base, prepared_scene, prepared_scene.scenes)
        parts = [self.base.likelihood(s, t, noise, speedups)
                 for s, t in zip(prepared_scene.scenes, tracks_list(tracks))]
        return JointLikelihood(parts, lay, speedups)

    def moves(self, prepared_scene: JointScene, tracks, latents, bounds) -> tuple:
        """Each video's own joint moves (its scenario's `moves`, given its latents where they sit in
        the chain's vector: a shared latent's moves act on the one value, a fixed latent's are
        not made), named `<move>@<v>` when there are several videos."""
        lay = layout(self.base, prepared_scene, prepared_scene.scenes)
        whole = tuple(self.base.problem_moves(prepared_scene.scenes, lay, bounds))
        if whole:    # the scenario's moves over the whole problem replace its per-video ones
            return whole
        n = len(prepared_scene.scenes)
        out = []
        for v, (s, t, row) in enumerate(zip(prepared_scene.scenes, tracks_list(tracks), lay.sources)):
            own = {x: name for name, kind, x in row if kind == "free"}
            # the chain's latents under this video's own names; another video's under a name no
            # scenario uses (so its moves leave them alone)
            named = [dataclasses.replace(lat, name=own.get(j, f"{SEP}{lat.name}")) for j, lat in enumerate(latents)]
            for m in self.base.moves(s, t, named, bounds):
                out.append(m._replace(name=video_name(m.name, v, n)) if hasattr(m, "_replace") else m)
        return tuple(out)

    def simulate(self, scene: JointScene, n_frames, values=None, fps=None) -> Trajectory:
        """Video 1's simulation (its own values from `values`)."""
        s = self.with_values(scene, values).scenes[0] if values else scene.scenes[0]
        return self.base.simulate(s, n_frames, None, fps)

    def initial_positions(self, prepared_scene, latents, bounds, n_chains, seed):
        """Each video's starts as its scenario says, read into the flat vector (a shared latent
        from the first video that has it)."""
        lay = layout(self.base, prepared_scene, prepared_scene.scenes)
        own = self.base.problem_starts(prepared_scene.scenes, lay, n_chains, seed)
        if own is not None:
            return np.clip(own, bounds[:, 0], bounds[:, 1])
        starts = np.full((n_chains, len(lay.latents)), np.nan)
        for v, (s, row) in enumerate(zip(prepared_scene.scenes, lay.sources)):
            lats = self.base.latents(s)
            b = np.array([bounds[x] if kind == "free" else (x, x) for _, kind, x in row], float)
            own = self.base.initial_positions(s, lats, b, n_chains, seed)
            for j, (_, kind, x) in enumerate(row):
                if kind == "free" and np.isnan(starts[0, x]):
                    starts[:, x] = own[:, j]
        return starts

    # -- what the UI draws, and derived answers ------------------------------------------------------
    def drawing(self, scene: JointScene) -> Drawing:
        return self.base.drawing(scene.scenes[0])

    def camera(self, scene: JointScene):
        return self.base.camera(scene.scenes[0])

    def video_timing(self, scene: JointScene):
        return self.base.video_timing(scene.scenes[0])

    def derived(self, scene: JointScene, values: dict[str, float]) -> dict:
        """Each video's derived quantities (suffixed with its number when there are several)."""
        lay = layout(self.base, scene, scene.scenes)
        pos = np.array([values[n] for n in lay.names], float)
        n = len(scene.scenes)
        out = {}
        for v, s in enumerate(scene.scenes):
            for k, val in self.base.derived(s, lay.values(v, pos)).items():
                out[video_name(k, v, n)] = val
        return out

    def unidentified(self, scene: JointScene, tracks=None) -> dict[str, str]:
        """The base scenario's, over the problem's videos, fixed latents and tracks (if known)."""
        return self.base.not_identified(scene.scenes, scene.fixed, None if tracks is None else tracks_list(tracks),
                                        scene.share)

    def summary(self, scene, values, omit=()):
        parts = [f"{k} = {v:.4g}" for k, v in values.items() if k not in omit]
        parts += [f"{k} = {v:.4g}" for k, v in self.derived(scene, values).items() if v is not None and k not in omit]
        if scene.fixed:
            parts.append("fixed " + ", ".join(f"{k} = {v:g}" for k, v in scene.fixed.items()))
        return ", ".join(parts)
