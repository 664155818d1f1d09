"""One dataset builder for every scenario (`galileo dataset`): plan -> render each video -> index.

A scenario declares its dataset as a `DatasetSpec` (in its `dataset.py`, as `DATASET`): the
presets, `plan(preset, seed)` (the videos, each a picklable spec with a `.name`, deterministic
per seed) and `render_one(video, out_dir)` (writes the folder out_dir/<name> - its `files`:
video.mp4, scene.json, truth.json - and returns the video's index entry). `build` renders a
preset on a process pool and writes out/index.json, atomically, when every video is there.
A scenario whose renderer films through a real camera's effects (`galileo.footage`, `cameras`)
plans with the camera's name, `plan(preset, seed, camera)`, each video's spec carrying it;
index.json names the camera ("camera", "clean" when there are none).

Resumable: after each video, `RECORD` in the output folder notes the video's plan (a digest
of the scenario and the video's spec), its index entry and the SHA-256 of each of its files.
A rerun into the same folder keeps each video planned alike whose files are all still there
and unchanged (files added beside them later, such as `galileo recognize label`'s
tracks.json, do not count), and renders the others: those a killed run had not finished, those
whose files were since deleted or changed, and every video of another preset or seed (written
over same-named files, as a first build does).
"""
from __future__ import annotations

import hashlib
import json
import multiprocessing as mp
import os
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

from .errors import GalileoError
from .jsonio import write_json
from .progress import tqdm

RECORD = ".galileo-dataset.json"   # the build's record of finished videos (in the output folder)


@dataclass(frozen=True)
class DatasetSpec:
    """A scenario's rendered dataset."""
    scenario: str                                   # its registry name: progress, and the index's "scenario"
    presets: tuple[str, ...]                        # e.g. ("demo", "small", "full")
    plan: Callable[..., Sequence[Any]]              # (preset, seed[, camera]) -> picklable video specs, each with
                                                    # a .name and a repr that says all that makes the video
    render_one: Callable[[Any, str], dict]          # (video spec, out_dir) -> that video's index entry
    describe: str = ""                              # one line for `galileo scenarios`
    files: tuple[str, ...] = ("video.mp4", "scene.json", "truth.json")   # what render_one writes in out_dir/<name>
    index_names_scenario: bool = True               # False: the index has no "scenario" (the ramp's, from
                                                    # before there were two; readers default to the ramp)
    cameras: bool = False                           # plan takes a camera (galileo.footage's names: --camera)


def _digest(path: Path) -> str:
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def _intact(folder: Path, digests: dict) -> bool:
    """Every file the record lists for `folder` is there with the recorded contents."""
    try:
        return bool(digests) and all(_digest(folder / rel) == d for rel, d in digests.items())
    except OSError:
        return False


def _fingerprint(scenario: str, video: Any) -> str:
    """The planned video, as a digest of its scenario and its spec's repr (a dataclass's: every
    field, floats exact)."""
    return hashlib.sha256(f"{scenario}\n{video!r}".encode()).hexdigest()


def _render(spec: DatasetSpec, video: Any, out_dir: str) -> tuple[dict, dict[str, str]]:
    """Render one video (in a worker); its index entry and its files' SHA-256."""
    entry = spec.render_one(video, out_dir)
    return entry, {name: _digest(Path(out_dir) / video.name / name) for name in spec.files}


def _read_record(path: Path) -> dict:
    """The finished videos the record at `path` lists ({} when it is missing or unreadable: the
    videos are then rendered again)."""
    try:
        record = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        return {}
    videos = record.get("videos") if isinstance(record, dict) else None
    return videos if isinstance(videos, dict) else {}


def _render_on_pool(spec: DatasetSpec, todo: list, out_dir: str, n_workers: int, finished, bar) -> None:
    """Render `todo` on `n_workers` forked processes (each connects its own pybullet client,
    galileo.sim.bullet), calling finished(video, entry, files) as each ends. No more videos are
    handed out than there are workers, so that on Ctrl-C (the parent's alone) or an error the
    build stops once the videos under way are done, and keeps them."""
    from .runner import _ignore_sigint, _workers_born_deaf_to_sigterm

    pool = ProcessPoolExecutor(n_workers, mp_context=mp.get_context("fork"), initializer=_ignore_sigint)
    queue, running = iter(todo), {}

    def hand_out() -> None:
        video = next(queue, None)
        if video is not None:
            running[pool.submit(_render, spec, video, out_dir)] = video

    try:
        with _workers_born_deaf_to_sigterm():   # the first submit forks every worker
            for _ in range(n_workers):
                hand_out()
        while running:
            for fut in wait(running, return_when=FIRST_COMPLETED).done:
                finished(running.pop(fut), *fut.result())
                hand_out()
    except BrokenProcessPool as e:
        raise GalileoError(f"a render worker died ({e}); run the same command again to render the rest") from None
    except BaseException:
        if running:
            bar.set_description_str(f"stopping once the {len(running)} video(s) under way are done")
        raise
    finally:
        pool.shutdown(wait=True)
        for fut, video in running.items():
            if not fut.cancelled() and fut.exception() is None:
                finished(video, *fut.result())


def build(spec: DatasetSpec, preset: str, out: str | Path, seed: int = 0, workers: int | None = None,
          progress: bool = True, camera: str = "clean") -> list[dict]:
    """Render `spec`'s `preset` into `out`, filmed through `camera` (`galileo.footage`'s names),
    keeping the videos a same build there finished; the index entries in plan order (also
    written to out/index.json)."""
    from .footage import CameraEffects, effects_from_name

    if preset not in spec.presets:
        raise GalileoError(f"unknown {spec.scenario} dataset preset {preset!r}; expected one of {', '.join(spec.presets)}")
    plain = effects_from_name(camera) == CameraEffects()
    if not spec.cameras and not plain:
        from . import registry

        filmed = [n for n in registry.with_capability("dataset") if registry.get(n).dataset.cameras]
        raise GalileoError(f"the {spec.scenario} scenario renders clean videos only, not --camera {camera}; "
                           f"these render camera effects: {', '.join(filmed)}")
    videos = list(spec.plan(preset, seed, camera) if spec.cameras else spec.plan(preset, seed))
    names = [v.name for v in videos]
    if len(set(names)) != len(names):
        raise ValueError(f"{spec.scenario} plan({preset!r}, {seed}) names two videos alike")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    kept = _read_record(out / RECORD)
    done: dict[str, dict] = {}
    for v in videos:
        r = kept.get(v.name)
        if (isinstance(r, dict) and r.get("plan") == _fingerprint(spec.scenario, v) and isinstance(r.get("entry"), dict)
                and isinstance(r.get("files"), dict) and _intact(out / v.name, r["files"])):
            done[v.name] = r
    todo = [v for v in videos if v.name not in done]

    def finished(video, entry: dict, files: dict) -> None:
        done[video.name] = {"plan": _fingerprint(spec.scenario, video), "entry": entry, "files": files}
        write_json(out / RECORD, {"scenario": spec.scenario, "preset": preset, "seed": seed, "videos": done},
                   indent=None)
        bar.update()

    bar = tqdm(total=len(videos), initial=len(videos) - len(todo), unit="video", disable=not progress,
               desc=f"rendering {spec.scenario} {preset}" + (f" ({len(done)} kept)" if done else ""))
    try:
        n_workers = max(1, min(workers or os.cpu_count() or 1, len(todo)))
        if n_workers == 1:
            for v in todo:
                finished(v, *_render(spec, v, str(out)))
        else:
            _render_on_pool(spec, todo, str(out), n_workers, finished, bar)
    finally:
        bar.close()
    entries = [done[n]["entry"] for n in names]
    index = {"scenario": spec.scenario} if spec.index_names_scenario else {}
    write_json(out / "index.json", {**index, "preset": preset, "seed": seed, "camera": camera if spec.cameras else "clean",
                                    "videos": entries})
    return entries


__all__ = ["DatasetSpec", "RECORD", "build"]
