"""Tracking accuracy against ground truth (rendered videos' truth.json)."""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ...datatypes import Tracks, Trajectory
from .scene import Scene
from .tracking import track

MOVING_MPS = 0.02  # a frame counts as "moving" for an object whose true speed exceeds this


@dataclass
class TrackScore:
    video: str
    position_errors_m: list[float]   # per moving, visible frame, all objects
    velocity_errors_mps: list[float]
    identity_ok: bool
    shapes_true: list[str]
    shapes_found: list[str]
    offset_true: int
    offset_found: int | None
    visible_fraction: float

    def summary(self) -> dict:
        d = asdict(self)
        d.pop("position_errors_m")
        d.pop("velocity_errors_mps")
        pe, ve = np.array(self.position_errors_m), np.array(self.velocity_errors_mps)
        d["median_position_error_m"] = float(np.median(pe)) if len(pe) else None
        d["velocity_rmse_mps"] = float(np.sqrt(np.mean(ve ** 2))) if len(ve) else None
        return d


def score(tracks: Tracks, truth: Trajectory, latents: dict, video: str = "") -> TrackScore:
    pos_err, vel_err = [], []
    identity_ok = True
    visible = []
    for i, obj in enumerate(tracks.objects):
        tp, tv = truth.position_m[i], truth.velocity_mps[i]
        vis = obj.visible
        visible.append(vis.mean())
        moving = np.linalg.norm(tv, axis=1) > MOVING_MPS
        sel = vis & moving
        # compare in the fall-line plane (x, z): the tracker reports y = 0
        pos_err += np.linalg.norm((obj.position_m[sel] - tp[sel])[:, [0, 2]], axis=1).tolist()
        vel_err += np.linalg.norm((obj.velocity_mps[sel] - tv[sel])[:, [0, 2]], axis=1).tolist()
        # identity: never closer to another object's true position than to its own
        for j in range(truth.position_m.shape[0]):
            if j != i:
                d_own = np.linalg.norm(obj.position_m[vis] - tp[vis], axis=1)
                d_other = np.linalg.norm(obj.position_m[vis] - truth.position_m[j][vis], axis=1)
                if np.any(d_other < d_own):
                    identity_ok = False
    shapes_true = [latents["shape1"]["type"]] + ([latents["shape2"]["type"]] if "shape2" in latents else [])
    return TrackScore(video, pos_err, vel_err, identity_ok, shapes_true, [o.shape.type for o in tracks.objects],
                      int(latents["offset_units"]), tracks.objects[0].offset_units, float(np.mean(visible)))


def evaluate_folder(folder: str | Path, progress: bool = False) -> TrackScore:
    folder = Path(folder)
    scene = Scene.load(folder / "scene.json")
    truth = json.loads((folder / "truth.json").read_text())
    tracks = track(folder / "video.mp4", scene, progress=progress)
    return score(tracks, Trajectory.from_json(truth["trajectory"]), truth["latents"], folder.name)


def aggregate(scores: list[TrackScore]) -> dict:
    pe = np.concatenate([s.position_errors_m for s in scores]) if scores else np.zeros(0)
    ve = np.concatenate([s.velocity_errors_mps for s in scores]) if scores else np.zeros(0)
    ramp_shape = [s.shapes_true[0] == s.shapes_found[0] for s in scores]
    all_shapes = [a == b for s in scores for a, b in zip(s.shapes_true, s.shapes_found)]
    return {"videos": len(scores),
            "median_position_error_m": float(np.median(pe)) if len(pe) else None,
            "velocity_rmse_mps": float(np.sqrt(np.mean(ve ** 2))) if len(ve) else None,
            "identity_preserved": sum(s.identity_ok for s in scores),
            "shape_type_right_ramp_objects": float(np.mean(ramp_shape)) if ramp_shape else None,
            "shape_type_right_all_objects": float(np.mean(all_shapes)) if all_shapes else None,
            "offset_right": float(np.mean([s.offset_true == s.offset_found for s in scores])) if scores else None}
