"""Recorded sessions: a folder of JSON and NPZ files (never pickle), each written atomically.

    <root>/<YYYYmmdd-HHMMSS>-<name>/
        scene.json      the scene inferred on (`Scene.to_json`), written once
        tracks.json     the tracked video (`Tracks.to_json`), written once
        settings.json   the priors and proposal settings in force
        events.json     the priors / steering history: {"version", "events": [...]}
        chains.json     per chain: id, start, position, logdensity, sweep, paused, removed, rng
                        state, and how many samples / proposals / events are committed
        record.npz      every chain's samples and logliks and every proposal (site, proposed
                        vector, loglik, accepted, early_stop, width)

A save writes record.npz, events.json and settings.json first and chains.json last: chains.json
is the commit point. It carries the counts of samples, proposals and events (the record and
the history only grow, so the files written before it hold at least as much) and a copy of the
settings, so a crash between two files still loads as the last complete state.

Reading: a missing or damaged file raises `GalileoError` with one line naming the file.
"""
from __future__ import annotations

import io
import re
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from galileo.errors import GalileoError
from galileo.jsonio import atomic_write_bytes, read_json, write_json

SESSION_VERSION = 1
SCENE_FILE = "scene.json"
TRACKS_FILE = "tracks.json"
SETTINGS_FILE = "settings.json"
EVENTS_FILE = "events.json"
CHAINS_FILE = "chains.json"
RECORD_FILE = "record.npz"
FILES = (SCENE_FILE, TRACKS_FILE, SETTINGS_FILE, EVENTS_FILE, CHAINS_FILE, RECORD_FILE)


def new_session_dir(root: str | Path, name: str) -> Path:
    """Make and return `root/<YYYYmmdd-HHMMSS>-<name>/` (with -2, -3, ... if that exists)."""
    root = Path(root)
    safe = re.sub(r"[^A-Za-z0-9._-]+", "-", str(name)).strip("-.") or "session"
    stem = f"{time.strftime('%Y%m%d-%H%M%S')}-{safe}"
    root.mkdir(parents=True, exist_ok=True)
    for i in range(1, 1000):
        path = root / (stem if i == 1 else f"{stem}-{i}")
        try:
            path.mkdir()
            return path
        except FileExistsError:
            continue
    raise GalileoError(f"cannot make a new session folder under {root}")


# -- writing ------------------------------------------------------------------------------------------

def npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def write_static(folder: Path, scene_json: dict, tracks_json: dict) -> None:
    """scene.json and tracks.json (they never change during a session)."""
    write_json(folder / SCENE_FILE, scene_json)
    write_json(folder / TRACKS_FILE, tracks_json, indent=None)


def write_state(folder: Path, *, settings: dict, events: list[dict], chains: dict,
                record: dict[str, np.ndarray]) -> None:
    """The changing state, chains.json (the commit point) last."""
    atomic_write_bytes(folder / RECORD_FILE, npz_bytes(record))
    write_json(folder / EVENTS_FILE, {"version": SESSION_VERSION, "events": events})
    write_json(folder / SETTINGS_FILE, {"version": SESSION_VERSION, **settings})
    write_json(folder / CHAINS_FILE, chains)


# -- reading ------------------------------------------------------------------------------------------

def _one_line(text: str) -> str:
    return " ".join(str(text).split())


@contextmanager
def reading(path: Path) -> Iterator[None]:
    """Turn any problem met while interpreting `path` into a one-line GalileoError naming it."""
    try:
        yield
    except GalileoError as e:
        msg = _one_line(e)
        if path.name in msg:
            raise GalileoError(msg) from None
        raise GalileoError(f"session file {path} is damaged: {msg}") from None
    except Exception as e:  # noqa: BLE001 - any malformed content
        raise GalileoError(f"session file {path} is damaged: {type(e).__name__}: {_one_line(e)}") from None


def check_folder(folder: str | Path) -> Path:
    folder = Path(folder)
    if not folder.is_dir():
        raise GalileoError(f"session folder not found: {folder}")
    for name in FILES:
        if not (folder / name).is_file():
            raise GalileoError(f"session file missing: {folder / name}")
    return folder


def read_json_file(folder: Path, name: str) -> Any:
    return read_json(folder / name, "session file")


def read_record(folder: Path) -> dict[str, np.ndarray]:
    path = folder / RECORD_FILE
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except Exception as e:  # noqa: BLE001 - truncated zip, bad header, pickled object, ...
        raise GalileoError(f"session file {path} is damaged: {type(e).__name__}: {_one_line(e)}") from None
