"""Recognition model files: one NPZ of named float arrays plus a JSON header, never pickle.

`save(path, meta, arrays)` writes atomically; `load(path, ...)` reads with
`allow_pickle=False` (loading never executes code) and refuses, in one line, a file that is
not a Galileo recognition model, one of another format version, kind or scenario.
"""
from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np

from ..errors import GalileoError
from ..jsonio import atomic_write_bytes

FORMAT = "galileo-recognition"
VERSION = 1
META_KEY = "__meta__"


def save(path: str | Path, meta: dict, arrays: dict[str, np.ndarray]) -> None:
    header = {"format": FORMAT, "version": VERSION, **meta}
    text = json.dumps(header, sort_keys=True, allow_nan=False)
    buf = io.BytesIO()
    np.savez_compressed(buf, **{META_KEY: np.frombuffer(text.encode(), np.uint8)},
                        **{k: np.ascontiguousarray(v, np.float32) for k, v in arrays.items()})
    atomic_write_bytes(path, buf.getvalue())


def load(path: str | Path, *, kind: str | None = None, scenario: str | None = None) -> tuple[dict, dict]:
    """(header, arrays) of a model file; GalileoError (one line) when it cannot be used."""
    path = Path(path)
    if not path.is_file():
        raise GalileoError(f"{path}: no such model file")
    try:
        with np.load(path, allow_pickle=False) as z:
            if META_KEY not in z.files:
                raise GalileoError(f"{path}: not a Galileo recognition model (no header)")
            meta = json.loads(bytes(z[META_KEY].astype(np.uint8)).decode())
            arrays = {k: z[k] for k in z.files if k != META_KEY}
    except GalileoError:
        raise
    except Exception as e:   # a damaged or foreign file: zip, npy or JSON errors alike
        raise GalileoError(f"{path}: not a readable recognition model ({type(e).__name__}: {e})") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise GalileoError(f"{path}: not a Galileo recognition model")
    if meta.get("version") != VERSION:
        raise GalileoError(f"{path}: model format version {meta.get('version')!r}; this Galileo reads version {VERSION}")
    if kind is not None and meta.get("kind") != kind:
        raise GalileoError(f"{path}: a {meta.get('kind')!r} model, expected {kind!r}")
    if scenario is not None and meta.get("scenario") != scenario:
        raise GalileoError(f"{path}: a model for the {meta.get('scenario')!r} scenario, not {scenario!r}")
    for k, a in arrays.items():
        if a.dtype.kind != "f" or not np.isfinite(a).all():
            raise GalileoError(f"{path}: array {k!r} is not finite floats")
    return meta, arrays
