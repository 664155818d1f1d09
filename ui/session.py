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

One app at a time (`SessionLock`): an app holds an exclusive `fcntl.flock` on `<folder>/.lock`
(which names its pid, host and start time) from the moment it creates or opens the session
until it closes it; a second opener is refused in one line naming the holder. The operating
system drops the lock when the holder's process ends, however it ends (a crash, SIGKILL), so a
lock is never stale; the file itself stays. The lock also notices the folder deleted, moved or
replaced while the app runs (`SessionLock.lost`: the folder's device and inode as opened):
saving then stops, and `recover` writes the whole session to a new folder beside it
(`<name>-recovered-<YYYYmmdd-HHMMSS>/`, built under a temporary name and renamed into place),
`video.mp4` included: the lock keeps the video open, so it survives the folder's deletion.
"""
from __future__ import annotations

import fcntl
import io
import json
import logging
import math
import os
import re
import shutil
import socket
import time
import weakref
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
VIDEO_FILE = "video.mp4"   # the app's copy of the video (kept open by the lock, for `recover`)
MAX_VIDEOS = 99            # a problem's videos in one session: video.mp4, video-2.mp4, ...


def video_file(v: int) -> str:
    """The session's copy of video v (0-based) of its problem: video.mp4, video-2.mp4, ..."""
    return VIDEO_FILE if v == 0 else f"video-{v + 1}.mp4"


def video_files(folder: Path) -> list[str]:
    """The session's videos in their problem's order (video.mp4, then video-2.mp4, ... while they exist)."""
    out = []
    for v in range(MAX_VIDEOS):
        if not (Path(folder) / video_file(v)).is_file():
            break
        out.append(video_file(v))
    return out
LOCK_FILE = ".lock"


def new_session_dir(root: str | Path, name: str) -> Path:
    """Make and return `root/<YYYYmmdd-HHMMSS>-<name>/` (with -2, -3, ... if that exists)."""
    root = Path(root)
    safe = re.sub(r"[^A-Za-z0-9._-]+", "-", str(name)).strip("-.") or "session"
    root.mkdir(parents=True, exist_ok=True)
    return _new_folder(root, f"{time.strftime('%Y%m%d-%H%M%S')}-{safe}")


def _new_folder(root: Path, stem: str) -> Path:
    """Make and return the empty folder `root/<stem>` (or -2, -3, ...: never one that exists)."""
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
                record: dict[str, np.ndarray], lock: "SessionLock | None" = None) -> None:
    """The changing state, chains.json (the commit point) last. With the folder's `lock`, each
    file is written only while the folder is still the session's (`SessionLost` otherwise: a
    file written into a folder made anew under its name would be half a session)."""
    writes = ((RECORD_FILE, lambda path: atomic_write_bytes(path, npz_bytes(record), make_parents=False)),
              (EVENTS_FILE, lambda path: write_json(path, {"version": SESSION_VERSION, "events": events},
                                                    make_parents=False)),
              (SETTINGS_FILE, lambda path: write_json(path, {"version": SESSION_VERSION, **settings},
                                                      make_parents=False)),
              (CHAINS_FILE, lambda path: write_json(path, chains, make_parents=False)))
    for name, write in writes:
        why = lock.lost() if lock is not None else None
        if why:
            raise SessionLost(f"the session folder {folder} {why}")
        write(folder / name)


# -- one app at a time -----------------------------------------------------------------------------------

class SessionLost(GalileoError):
    """The session folder was deleted, moved or replaced while the app had it open."""


def _holder(path: Path) -> str:
    """Who holds a session's lock, as its lock file says."""
    try:
        d = json.loads(path.read_text())
        return f"pid {int(d['pid'])} on {d['host']}, since {d['since']}"
    except (OSError, ValueError, KeyError, TypeError):
        return "holder unknown"


class SessionLock:
    """This app's hold on a session folder (see the module docstring): an exclusive flock on
    `<folder>/.lock`, taken at once or refused (GalileoError naming the holder); and the
    folder's identity, for `lost`. `release` lets go (so does the process's end). A folder
    where no lock file can be made (read-only: an archive) opens unlocked, with a warning."""

    def __init__(self, folder: str | Path):
        folder = Path(folder)
        if not folder.is_dir():
            raise GalileoError(f"session folder not found: {folder}")
        self.folder = folder
        self.kept: dict[str, Any] = {}    # file name -> open file (see `keep`)
        self._file = None
        path = folder / LOCK_FILE
        try:   # (never truncated before the lock is ours: a refused opener reads the holder there)
            f = os.fdopen(os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666), "r+b", buffering=0)
        except OSError as e:
            log.warning("cannot lock session folder %s (%s): another app could open it too", folder,
                        e.strerror or e)
        else:
            try:
                fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as e:
                f.close()
                if isinstance(e, BlockingIOError):
                    raise GalileoError(f"session {folder} is open in another app ({_holder(path)}): close it "
                                       "there first, or open a copy of the folder") from None
                log.warning("cannot lock session folder %s (%s): another app could open it too", folder,
                            e.strerror or e)   # a file system without locks
            else:
                holder = {"pid": os.getpid(), "host": socket.gethostname(), "since": time.strftime("%Y-%m-%d %H:%M:%S")}
                os.ftruncate(f.fileno(), 0)
                os.pwrite(f.fileno(), (json.dumps(holder) + "\n").encode(), 0)
                self._file = f
                _held.add(self)
        st = os.stat(folder)
        self._identity = (st.st_dev, st.st_ino)

    def keep(self, name: str) -> None:
        """Keep `<folder>/<name>` open (if there) so that `recover` can copy it even after the
        folder is deleted."""
        if name not in self.kept and (self.folder / name).is_file():
            self.kept[name] = open(self.folder / name, "rb")

    def lost(self) -> str | None:
        """Why the folder is no longer this session's ("was deleted", "was moved or renamed
        (now at ...)", ...); None while it is."""
        try:
            st = os.stat(self.folder)
            if (st.st_dev, st.st_ino) == self._identity:
                return None
            taken = True      # another folder has its name now
        except FileNotFoundError:
            taken = False
        except OSError as e:
            return f"cannot be read ({e.strerror or e})"
        if self._file is None:
            what = "was deleted or moved"
        elif os.fstat(self._file.fileno()).st_nlink == 0:
            what = "was deleted"
        else:
            now = _path_of(self._file)
            what = "was moved or renamed" + (f" (now {now.parent})" if now and now.name == LOCK_FILE else "")
        return what + (" and another folder took its name" if taken else "")

    def release(self) -> None:
        for f in self.kept.values():
            f.close()
        self.kept = {}
        if self._file is not None:
            self._file.close()    # (closing the lock file lets the lock go)
            self._file = None
        _held.discard(self)


def _path_of(f) -> Path | None:
    """Where an open file is now (Linux: /proc/self/fd; None elsewhere or once it is deleted)."""
    try:
        return Path(os.readlink(f"/proc/self/fd/{f.fileno()}"))
    except OSError:
        return None


_held: "weakref.WeakSet[SessionLock]" = weakref.WeakSet()   # this process's locks


def _close_in_child() -> None:
    """A forked child (a chain worker) closes its copies of the lock files: a flock belongs to
    the open file, so a child that kept its copy would hold the session after the app ended."""
    for lock in list(_held):
        if lock._file is not None:
            lock._file.close()    # (the child's copy only: the parent's lock stays)
            lock._file = None
    _held.clear()


os.register_at_fork(after_in_child=_close_in_child)


def recover(lost: SessionLock, *, scene_json: dict, tracks_json: dict, **state) -> SessionLock:
    """Write the whole session (`write_static`, the kept files (the video), `write_state`'s
    `state`) to a new folder beside the lost one, `<name>-recovered-<YYYYmmdd-HHMMSS>/`,
    atomically: built in a temporary folder, locked, then renamed onto a freshly made empty
    folder of that name. Returns the new folder's lock (OSError or GalileoError if it cannot)."""
    parent, stem = lost.folder.parent, f"{lost.folder.name}-recovered-{time.strftime('%Y%m%d-%H%M%S')}"
    tmp = _new_folder(parent, f".{stem}.tmp")
    lock = None
    try:
        lock = SessionLock(tmp)
        write_static(tmp, scene_json, tracks_json)
        for name, f in lost.kept.items():
            f.seek(0)
            with open(tmp / name, "wb") as out:
                shutil.copyfileobj(f, out)
                out.flush()
                os.fsync(out.fileno())
        write_state(tmp, **state)
        final = _new_folder(parent, stem)
        try:
            os.rename(tmp, final)    # onto the empty folder just made: atomic, and never over another's
        except OSError:
            final.rmdir()
            raise
    except BaseException:
        if lock is not None:
            lock.release()
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    lock.folder = final
    for name in lost.kept:
        lock.keep(name)
    return lock


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
            elif k in ("log", "others_log"):     # FittedConditional's flags
                if not isinstance(x, bool):
                    raise ValueError(f"joint move {d['type']}: {k} must be true or false, got {x!r}")
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
