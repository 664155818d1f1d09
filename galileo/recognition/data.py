"""A rendered dataset as recognition examples: which object to read in which video, the
object and group that splits keep together, ground truth, Galileo's labels and the patches.

Labels are on Galileo's own inferences ("Galileo labels", the paper's self-supervised sleep
phase): `make_labels` tracks and infers every video (the paper's 16 x 75 by default) and
keeps, per video, what the scenario says the video identifies (`Scenario.recognition_label`),
in `<dataset>/labels.galileo.json` (appended per video, atomically, so a stopped run resumes).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..progress import tqdm
from .. import registry
from ..datatypes import Tracks
from ..errors import GalileoError, StillVideo
from ..jsonio import read_json, write_json

LABELS_FILE = "labels.galileo.json"
TRACKS_FILE = "tracks.json"        # cached beside each video's scene file
PATCH_FRAMES = 4                   # patches from the first frame and up to 3 more before motion
QUANTITIES = ("mass_kg", "friction")


@dataclass(frozen=True)
class Example:
    name: str                  # the video's folder name
    folder: Path               # the video's folder (video.mp4, scene.json)
    object_id: str             # the physical object (splits never put one on both sides)
    group: str                 # e.g. its material: each split holds out some objects of every group
    role: str                  # which tracked object the patches show
    truth: dict = field(default_factory=dict)   # {"mass_kg": ..., "friction": ...}

    @property
    def video(self) -> Path:
        return self.folder / "video.mp4"

    @property
    def scene(self) -> Path:
        return self.folder / "scene.json"


def dataset_scenario(folder: str | Path) -> str:
    index = Path(folder) / "index.json"
    if not index.is_file():
        raise GalileoError(f"{folder} is not a dataset folder (no index.json; make one with `galileo dataset`)")
    d = read_json(index, "dataset index")
    if not isinstance(d, dict) or not isinstance(d.get("videos"), list):
        raise GalileoError(f"{index}: expected a JSON object with the dataset's videos")
    return d.get("scenario", registry.DEFAULT)


def load_examples(folder: str | Path) -> tuple[str, list[Example]]:
    name = dataset_scenario(folder)
    examples = registry.get(name).recognition_examples(Path(folder))
    if not examples:
        raise GalileoError(f"{folder}: no videos to learn from")
    return name, examples


# -- object splits (hold out objects, not videos) ----------------------------------------------

def object_folds(examples: list[Example], k: int = 5, seed: int = 0) -> dict[str, int]:
    """Object id -> fold 0..k-1: within each group the objects are shuffled (seeded) and
    dealt round the folds, so every fold holds out some objects of every group with at
    least k objects, and all videos of an object share its fold."""
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(7,)))
    by_group: dict[str, list[str]] = {}
    for ex in examples:
        objs = by_group.setdefault(ex.group, [])
        if ex.object_id not in objs:
            objs.append(ex.object_id)
    folds: dict[str, int] = {}
    offset = 0
    for group in sorted(by_group):
        objs = sorted(by_group[group])
        for i, j in enumerate(rng.permutation(len(objs))):
            folds[objs[j]] = (i + offset) % k
        offset += len(objs)   # groups smaller than k do not all land in the first folds
    return folds


def split(examples: list[Example], fold: int, k: int = 5, seed: int = 0) -> tuple[list[Example], list[Example]]:
    """(train, test) for one fold: the test side holds every video of the fold's objects."""
    folds = object_folds(examples, k, seed)
    train = [e for e in examples if folds[e.object_id] != fold]
    test = [e for e in examples if folds[e.object_id] == fold]
    return train, test


# -- tracks, patches ---------------------------------------------------------------------------------

def tracks_for(ex: Example, scene=None) -> Tracks | None:
    """The video's tracks (cached as tracks.json in its folder), or None when the scenario's
    tracker refuses a video in which nothing moves (`StillVideo`: the splash tracker; the
    ramp's reports the objects at rest, with a note). Other tracking errors are raised."""
    cached = ex.folder / TRACKS_FILE
    if cached.is_file():
        return Tracks.load(cached)
    scene = scene if scene is not None else registry.load_scene(ex.scene)
    try:
        tracks = registry.of(scene).track(ex.video, scene, progress=False)
    except StillVideo:
        return None
    tracks.save(cached)
    return tracks


def start_positions(scene) -> dict[str, np.ndarray]:
    """Where the scene file puts each object at frame 0 (for a video the tracker refuses)."""
    scenario = registry.of(scene)
    traj = scenario.simulate(scene, 1)
    return {o.role: traj.position_m[i, 0] for i, o in enumerate(scene.objects)}


def patches(video: str | Path, scene, tracks: Tracks | None, role: str, max_frames: int = PATCH_FRAMES) -> np.ndarray:
    """Patches (N, 32, 32, 3) uint8 of object `role` from the first frame and the frames
    before it moves (`Scenario.recognition_patch_motion_m`), cropped where the tracker puts it (where the scene file puts it, in the
    first frame only, without tracks). GalileoError when it cannot be cropped."""
    from ..video import read_frames
    from ..vision.patch import object_patch

    cam = registry.of(scene).camera(scene)
    if cam is None:
        raise GalileoError("the scene file has no camera: the object cannot be cropped")
    if tracks is not None:
        tr = tracks.by_role(role)
        if tr is None:
            raise GalileoError(f"the tracks have no {role} object to crop")
        vis = np.flatnonzero(tr.visible)
        if not len(vis):
            raise GalileoError(f"the {role} object is never seen: it cannot be cropped")
        first = tr.position_m[vis[0]]
        motion_m = registry.of(scene).recognition_patch_motion_m
        frames = [int(f) for f in vis if np.linalg.norm(tr.position_m[f] - first) < motion_m][:max_frames]
        centres = {f: tr.position_m[f] for f in frames}
    else:
        centres = {0: start_positions(scene)[role]}
    out = []
    last = max(centres)
    for f, rgb in enumerate(read_frames(video)):
        if f in centres:
            p = object_patch(rgb, cam, centres[f])
            if p is not None:
                out.append(p)
        if f >= last:
            break
    if not out:
        raise GalileoError(f"{video}: the {role} object cannot be cropped (it is outside the frame)")
    return np.stack(out)


# -- labels --------------------------------------------------------------------------------------------

def read_labels(folder: str | Path, source: str, examples: list[Example]) -> dict[str, dict]:
    """Per video name, {"mass_kg", "friction"} (None where unknown) from `source`:
    "oracle" (ground truth) or "galileo" (the labels file)."""
    if source == "oracle":
        return {e.name: {q: e.truth.get(q) for q in QUANTITIES} for e in examples}
    if source != "galileo":
        raise GalileoError(f"unknown labels {source!r}; expected galileo, oracle or simulation")
    path = Path(folder) / LABELS_FILE
    if not path.is_file():
        raise GalileoError(f"{folder} has no Galileo labels ({LABELS_FILE}); make them with "
                           f"`galileo recognize label --dataset {folder}`")
    d = read_json(path, "labels file")
    if not isinstance(d, dict) or not isinstance(d.get("videos"), dict):
        raise GalileoError(f"{path}: expected an object with per-video labels")
    out = {}
    for e in examples:
        lab = d["videos"].get(e.name)
        if isinstance(lab, dict):
            out[e.name] = {q: _number_or_none(lab.get(q), f"{path}: {e.name}.{q}") for q in QUANTITIES}
    if not any(v["mass_kg"] is not None or v["friction"] is not None for v in out.values()):
        raise GalileoError(f"{path}: no video has a label yet (is `galileo recognize label` still running?)")
    return out


def _number_or_none(x, what: str):
    if x is None:
        return None
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not np.isfinite(x):
        raise GalileoError(f"{what}: expected a finite number or null, got {x!r}")
    return float(x)


def make_labels(folder: str | Path, config=None, progress: bool = True, executor=None) -> dict:
    """Track and infer every video of the dataset (skipping those already labelled) and
    write what each video identifies to labels.galileo.json; returns its contents."""
    from ..runner import RunConfig, infer

    folder = Path(folder)
    name, examples = load_examples(folder)
    scenario = registry.get(name)
    cfg = config or RunConfig(chains=scenario.protocol["chains"], sweeps=scenario.protocol["sweeps"])
    path = folder / LABELS_FILE
    done = {}
    if path.is_file():
        d = read_json(path, "labels file")
        if isinstance(d, dict) and isinstance(d.get("videos"), dict):
            if d.get("config") not in (None, _cfg_json(cfg)):
                raise GalileoError(f"{path} was made with other settings ({d.get('config')}); delete it "
                                   "or label with those")
            done = d["videos"]
    todo = [e for e in examples if e.name not in done or "error" in done[e.name]]   # errors are tried again
    own = executor is None
    if own and todo:
        from ..runner import local_executor

        executor = local_executor(cfg.workers, cfg.chains)
    try:
        for ex in tqdm(todo, desc="labelling", unit="video", disable=not progress):
            try:
                scene = registry.load_scene(ex.scene)
                tracks = tracks_for(ex, scene)
            except GalileoError as e:   # this video is unusable: say why, go on with the others
                done[ex.name] = {"mass_kg": None, "friction": None, "error": str(e)}
                tracks = scene = None
            if scene is not None and tracks is None:
                done[ex.name] = {"mass_kg": None, "friction": None,
                                 "note": "nothing moves in the video: no label"}
            elif tracks is not None:
                res = infer(scene, tracks, cfg, executor=executor, progress=False)
                lab = scenario.recognition_label(res.scene, tracks, res.map).get(ex.role, {})
                done[ex.name] = {"mass_kg": lab.get("mass_kg"), "friction": lab.get("friction"),
                                 "map": res.map, "map_loglik": res.map_loglik, "seconds": res.timing_s["wall"]}
                if tracks.notes:   # e.g. nothing moves: the label says only what the stillness identifies
                    done[ex.name]["note"] = " ".join(tracks.notes)
            write_json(path, {"scenario": name, "config": _cfg_json(cfg), "videos": done})
    finally:
        if own and todo:
            executor.shutdown()
    out = {"scenario": name, "config": _cfg_json(cfg), "videos": done}
    write_json(path, out)
    return out


def _cfg_json(cfg) -> dict:
    return {"chains": int(cfg.chains), "sweeps": int(cfg.sweeps), "seed": int(cfg.seed)}


def truth_json(folder: Path) -> dict:
    try:
        return json.loads((folder / "truth.json").read_text())
    except (OSError, ValueError) as e:
        raise GalileoError(f"{folder / 'truth.json'}: unreadable ground truth ({e})") from None
