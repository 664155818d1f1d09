"""Observations and simulated motion as plain data: `Tracks` (what tracking measured in a
video) and `Trajectory` (what a simulation produced). No OpenCV, no pybullet: the
likelihood, the viewer and the controller read these without importing either."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import GalileoError
from .jsonio import read_json, write_json
from .shapes import Shape


# -- output -----------------------------------------------------------------------------

@dataclass
class ObjectTrack:
    name: str
    role: str
    position_m: np.ndarray      # (F, 3), NaN where not visible
    velocity_mps: np.ndarray    # (F, 3), NaN where not visible
    visible: np.ndarray         # (F,) bool
    shape: Shape
    offset_units: int | None = None
    detected_by: str = "motion"  # motion (ramp object) | scene (target, from the scene file)
    bottom_up: dict = field(default_factory=dict)   # a scenario's other bottom-up estimates (JSON values)
    # for drawing (not saved): image centre and features per frame
    center_px: np.ndarray | None = None
    features_px: list = field(default_factory=list)

    def to_json(self) -> dict:
        def rows(a):
            return [None if not v else [float(x) for x in row] for row, v in zip(a, self.visible)]
        d = {"name": self.name, "role": self.role, "position_m": rows(self.position_m),
             "velocity_mps": rows(self.velocity_mps), "visible": [bool(v) for v in self.visible],
             "shape": {"type": self.shape.type, "size_m": list(self.shape.size_m)},
             "offset_units": self.offset_units, "detected_by": self.detected_by}
        if self.bottom_up:
            d["bottom_up"] = dict(self.bottom_up)
        return d


@dataclass
class Tracks:
    fps: float
    objects: list[ObjectTrack]
    notes: list[str] = field(default_factory=list)   # what the tracker wants the user to know (one line each)

    @property
    def n_frames(self) -> int:
        return len(self.objects[0].visible) if self.objects else 0

    @property
    def time_s(self) -> np.ndarray:
        return np.arange(self.n_frames) / self.fps

    def by_role(self, role: str) -> ObjectTrack | None:
        return next((o for o in self.objects if o.role == role), None)

    def to_json(self) -> dict:
        d = {"fps": self.fps, "time_s": self.time_s.tolist(), "objects": [o.to_json() for o in self.objects]}
        if self.notes:
            d["notes"] = [str(n) for n in self.notes]
        return d

    def save(self, path: str | Path) -> None:
        write_json(path, self.to_json(), indent=None)

    @classmethod
    def from_json(cls, d: dict) -> "Tracks":
        try:
            objs = []
            for o in d["objects"]:
                vis = np.array(o["visible"], bool)
                nan3 = [math.nan] * 3
                pos = np.array([p if p is not None else nan3 for p in o["position_m"]], float).reshape(-1, 3)
                vel = np.array([p if p is not None else nan3 for p in o["velocity_mps"]], float).reshape(-1, 3)
                shape = Shape(o["shape"]["type"], tuple(o["shape"]["size_m"]))
                if not (np.isfinite(pos[vis]).all() and np.isfinite(vel[vis]).all()):
                    raise ValueError(f"object {o['name']!r}: a visible frame without a finite position and velocity")
                bottom_up = o.get("bottom_up", {})
                if not isinstance(bottom_up, dict):
                    raise TypeError("bottom_up must be an object")
                objs.append(ObjectTrack(o["name"], o["role"], pos, vel, vis, shape, o.get("offset_units"),
                                        o.get("detected_by", "motion"), bottom_up))
            notes = d.get("notes", [])
            if not isinstance(notes, list) or not all(isinstance(n, str) for n in notes):
                raise TypeError("notes must be a list of strings")
            return cls(float(d["fps"]), objs, list(notes))
        except (KeyError, TypeError, ValueError, IndexError) as e:
            raise GalileoError(f"malformed tracks JSON: {e}") from None

    @classmethod
    def load(cls, path: str | Path) -> "Tracks":
        return cls.from_json(read_json(path, "tracks file"))



@dataclass
class Trajectory:
    """Per-frame centre-of-mass positions (m) and velocities (m/s) in the world frame."""
    fps: float
    names: list[str]
    position_m: np.ndarray    # (n_objects, n_frames, 3)
    velocity_mps: np.ndarray  # (n_objects, n_frames, 3)
    orientation_xyzw: np.ndarray | None = None  # (n_objects, n_frames, 4), when asked for (not saved)

    @property
    def n_frames(self) -> int:
        return self.position_m.shape[1]

    @property
    def time_s(self) -> np.ndarray:
        return np.arange(self.n_frames) / self.fps

    def to_json(self) -> dict:
        return {"fps": self.fps, "time_s": self.time_s.tolist(),
                "objects": [{"name": n, "position_m": self.position_m[i].tolist(),
                             "velocity_mps": self.velocity_mps[i].tolist()} for i, n in enumerate(self.names)]}

    @classmethod
    def from_json(cls, d: dict) -> "Trajectory":
        try:
            objs = d["objects"]
            return cls(float(d["fps"]), [o["name"] for o in objs],
                       np.array([o["position_m"] for o in objs], float).reshape(len(objs), -1, 3),
                       np.array([o["velocity_mps"] for o in objs], float).reshape(len(objs), -1, 3))
        except (KeyError, TypeError, ValueError) as e:
            raise GalileoError(f"malformed trajectory JSON: {e}") from None

    def save(self, path: str | Path) -> None:
        write_json(path, self.to_json(), indent=None)

    @classmethod
    def load(cls, path: str | Path) -> "Trajectory":
        return cls.from_json(read_json(path, "trajectory file"))


