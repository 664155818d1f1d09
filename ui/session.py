"""Recorded sessions: a folder of JSON and NPZ files (never pickle), each written atomically.

    <root>/<YYYYmmdd-HHMMSS>-<name>/
        scene.json      the scene inferred on (`Scene.to_json`), written once
        tracks.json     the tracked video (`Tracks.to_json`), written once
        settings.json   the priors and proposal settings in force
        events.json     the priors / steering history: {"version", "events": [...]}
        chains.json     per chain: id, start, position, logdensity, sweep, paused, held (paused
                        at the sweep target), removed, rng state, its proposal widths (as adapted
                        in warm-up) and joint moves, and how many samples / proposals / events
                        are committed; the move set, warm-up, sweep target and run-until criteria
        record.npz      every chain's samples and logliks, the noise (sigma) each sample was
                        scored under, and every proposal (site, proposed vector, loglik,
                        accepted, early_stop, width)

Sessions recorded before moves and per-sample noise existed load as the paper's kernel
(`moves` "paper", no joint moves, the settings' widths) with each sample's noise read from
the sigma events.

A save writes record.npz, events.json and settings.json first and chains.json last: chains.json
is the commit point. It carries the counts of samples, proposals and events (the record and
the history only grow, so the files written before it hold at least as much) and a copy of the
settings, so a crash between two files still loads as the last complete state.

Reading: a missing or damaged file raises `GalileoError` with one line naming the file. A save
killed before its rename leaves a `.<file>.<random>.tmp` behind; opening the session removes it.
"""
from __future__ import annotations

import io
import logging
import math
import re
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from galileo.errors import GalileoError
from galileo.jsonio import atomic_write_bytes, read_json, write_json

log = logging.getLogger(__name__)

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


# -- proposal widths and joint moves as plain JSON -------------------------------------------------

def proposal_to_json(p) -> dict:
    """A `galileo.mcmc.Proposal` (floats round-trip exactly through JSON)."""
    def w(x):
        return [float(v) for v in x] if isinstance(x, (tuple, list, np.ndarray)) else float(x)
    return {"narrow": w(p.narrow), "broad": w(p.broad), "broad_every": int(p.broad_every),
            "integer_sites": [int(i) for i in p.integer_sites]}


def proposal_from_json(d: dict, dim: int):
    """ValueError on a damaged record."""
    from galileo.mcmc import Proposal

    def w(x, what):
        if isinstance(x, list):
            if len(x) != dim:
                raise ValueError(f"proposal {what}: {len(x)} widths for {dim} latents")
            v = tuple(float(a) for a in x)
        else:
            v = float(x)
        if not all(math.isfinite(a) and a > 0 for a in (v if isinstance(v, tuple) else (v,))):
            raise ValueError(f"proposal {what}: widths must be finite and > 0, got {x!r}")
        return v
    every = d["broad_every"]
    if isinstance(every, bool) or not isinstance(every, int) or every < 0:
        raise ValueError(f"proposal broad_every: expected an integer >= 0, got {every!r}")
    sites = tuple(int(i) for i in d["integer_sites"])
    if any(not 0 <= i < dim for i in sites):
        raise ValueError(f"proposal integer_sites outside 0..{dim - 1}: {list(sites)}")
    return Proposal(w(d["narrow"], "narrow"), w(d["broad"], "broad"), every, sites)


def _move_type(d: dict):
    """The class of a recorded joint move: a NamedTuple with `propose` from a module of the
    galileo package (never anything else: a session file names no code to run)."""
    import importlib

    module, name = d.get("module", "galileo.mcmc"), d.get("type")
    if not (isinstance(module, str) and isinstance(name, str) and (module == "galileo" or module.startswith("galileo."))
            and name.isidentifier()):
        return None
    try:
        t = getattr(importlib.import_module(module), name, None)
    except ImportError:
        return None
    ok = isinstance(t, type) and issubclass(t, tuple) and hasattr(t, "_fields") and callable(getattr(t, "propose", None))
    return t if ok else None


def _plain(v):
    return [_plain(x) for x in v] if isinstance(v, (tuple, list)) else v


def _tuples(v):
    return tuple(_tuples(x) for x in v) if isinstance(v, list) else v


def _numbers(v) -> list:
    return [y for x in v for y in _numbers(x)] if isinstance(v, tuple) else [v]


def move_to_json(m) -> dict:
    """A joint move (a NamedTuple of `galileo.mcmc`) as {"type", field: value} (tuples as lists)."""
    t = type(m)
    d = {"type": t.__name__, "module": t.__module__}
    if _move_type(d) is not t:
        raise ValueError(f"cannot record a joint move of type {t.__module__}.{t.__name__}")
    return {**d, **{k: _plain(v) for k, v in m._asdict().items()}}


def move_from_json(d: dict, dim: int):
    """ValueError on a damaged record (an unknown type, missing, malformed or inconsistent fields)."""
    t = _move_type(d) if isinstance(d, dict) else None
    if t is None:
        raise ValueError(f"unknown joint move {d!r:.80}")
    fields = {k: _tuples(v) for k, v in d.items() if k not in ("type", "module")}
    if set(fields) - set(t._fields):
        raise ValueError(f"joint move {d['type']}: unknown fields {sorted(set(fields) - set(t._fields))}")
    move = t(**fields)
    for k, v in move._asdict().items():
        if v is None and k in t._field_defaults and t._field_defaults[k] is None:
            continue
        for x in _numbers(v):
            if k in ("name", "kinds"):
                if not isinstance(x, str):
                    raise ValueError(f"joint move {d['type']}: {k} must be text, got {x!r}")
            elif isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
                raise ValueError(f"joint move {d['type']}: {k} must be finite numbers, got {v!r:.80}")
    sites = tuple(getattr(move, "sites", ()) or ()) + tuple(getattr(move, "log_sites", ()) or ())
    sites += (move.site,) if hasattr(move, "site") else ()
    for site in sites:
        if not (isinstance(site, int) and 0 <= site < dim):
            raise ValueError(f"joint move {d['type']}: site {site!r} outside 0..{dim - 1}")
    n = len(getattr(move, "sites", ()) or ())
    for k, shape in (("chol", (n, n)), ("cov", (n, n)), ("mean", (n,))):
        v = getattr(move, k, None)
        if v is not None and np.shape(np.asarray(v, dtype=object)) != shape:
            raise ValueError(f"joint move {d['type']}: {k} is not {'x'.join(map(str, shape))}")
    every = getattr(move, "every", 1)
    if not isinstance(every, int) or every < 1:
        raise ValueError(f"joint move {d['type']}: every must be an integer >= 1, got {every!r}")
    if callable(getattr(move, "check", None)):
        move.check(dim)
    return move


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


def stale_temp_files(folder: Path) -> list[Path]:
    """The temporary files an interrupted save left in a session folder: `.<name>.<random>.tmp`
    of the session's own files (what `galileo.jsonio.atomic_write_bytes` writes before it
    renames one into place), nothing else."""
    names = "|".join(re.escape(n) for n in FILES)
    pattern = re.compile(rf"\.(?:{names})\.[A-Za-z0-9_]+\.tmp")
    return sorted(p for p in folder.iterdir() if pattern.fullmatch(p.name) and p.is_file() and not p.is_symlink())


def remove_stale_temp_files(folder: Path) -> list[Path]:
    """Remove `stale_temp_files` (a kill during a save leaves one behind: the save it belonged
    to never happened, and the files it would have replaced are whole). Returns those removed."""
    gone = []
    for p in stale_temp_files(folder):
        try:
            p.unlink()
            gone.append(p)
        except FileNotFoundError:
            pass
        except OSError as e:   # a read-only folder still opens; the file just stays
            log.warning("cannot remove %s: %s", p, e)
    if gone:
        log.info("removed %d temporary file(s) an interrupted save left in %s", len(gone), folder)
    return gone


def check_folder(folder: str | Path) -> Path:
    """The session folder, every file there (GalileoError naming what is missing); the
    temporary files an interrupted save left are removed."""
    folder = Path(folder)
    if not folder.is_dir():
        raise GalileoError(f"session folder not found: {folder}")
    for name in FILES:
        if not (folder / name).is_file():
            raise GalileoError(f"session file missing: {folder / name}")
    remove_stale_temp_files(folder)
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
