"""Atomic, pickle-free file writing and JSON reading with one-line errors."""
from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from .errors import GalileoError


_UMASK = os.umask(0)
os.umask(_UMASK)


def _default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return obj.item()
    raise TypeError(f"cannot serialise {type(obj).__name__} to JSON")


def atomic_write_bytes(path: str | os.PathLike, data: bytes, *, make_parents: bool = True) -> None:
    """Write `data` to `path` so that a crash leaves either the old or the new file. Without
    `make_parents` a missing folder is an error, never made (a session folder deleted under a
    running app must not come back half-written)."""
    path = Path(path)
    if make_parents:
        path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_UMASK)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_json(path: str | os.PathLike, obj: Any, *, indent: int | None = 1, make_parents: bool = True) -> None:
    """`obj` as JSON, atomically. A NaN or infinity is refused (GalileoError): JSON has none,
    and a file that holds one is no result."""
    try:
        text = json.dumps(obj, indent=indent, default=_default, allow_nan=False)
    except ValueError as e:
        raise GalileoError(f"not writing {path}: a value is not a finite number ({e})") from None
    atomic_write_bytes(path, (text + "\n").encode(), make_parents=make_parents)


def read_json(path: str | os.PathLike, what: str = "file") -> Any:
    path = Path(path)
    if not path.exists():
        raise GalileoError(f"{what} not found: {path}")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise GalileoError(f"cannot read {what} {path}: {' '.join(str(e).split())}") from None
    return parse_json(text, f"{what} {path}")


def parse_json(text: str, what: str = "the text") -> Any:
    """`text` parsed as JSON; GalileoError (one line naming `what`) when it is not JSON, is
    nested too deeply for the parser (a RecursionError) or holds an integer too long to read."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise GalileoError(f"{what} is not valid JSON: {e.msg} at line {e.lineno} column {e.colno}") from None
    except RecursionError:
        raise GalileoError(f"{what} is nested too deeply to read (arrays or objects more than about "
                           f"{sys.getrecursionlimit()} levels deep)") from None
    except ValueError as e:   # e.g. an integer of more than 4300 digits
        raise GalileoError(f"{what} cannot be read: {' '.join(str(e).split())[:200]}") from None
