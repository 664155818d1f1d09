"""pybullet, imported without its "pybullet build time" banner (C-level stderr)."""
from __future__ import annotations

import ctypes
import os
import sys


def _import_quietly():
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no real stdout (e.g. captured): import as is
        import pybullet
        return pybullet
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        import pybullet
        try:  # the banner sits in C's stdio buffer: flush it into /dev/null
            ctypes.CDLL(None).fflush(None)
        except (OSError, AttributeError):
            pass
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)
    return pybullet


pb = _import_quietly()
