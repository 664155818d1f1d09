"""What the viewer and rerun draw of a scene: static meshes, the objects' meshes and the
connectors between them (springs, strings), posed per frame by a `Trajectory`
(`Scenario.drawing(scene)`).

A connector's ends are anchors, each fixed in the world or on a body (an object of the
Trajectory, at a point in its frame); `connector_points` turns one into a polyline in the
world frame for the objects' poses at one frame, so a drawn spring stretches and
compresses with the bodies it joins. Drawing only: a connector exerts no force (the
scenario's physics does that).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

HELIX_POINTS_PER_COIL = 16   # a helix's polyline: this many points per turn (a smooth coil on screen)
MIN_AXIS_M = 1e-9            # anchors closer than this: the helix's axis is taken along +z


@dataclass(frozen=True)
class Mesh:
    """A piece of static scene geometry for the viewer: a triangle mesh in the world frame."""
    name: str
    vertices: np.ndarray    # (V, 3) metres, world frame
    faces: np.ndarray       # (T, 3)
    color: tuple[int, int, int] = (180, 180, 180)
    opacity: float = 1.0


@dataclass(frozen=True)
class Anchor:
    """One end of a connector: `point_m` in the world frame (`body` None), or in the frame of
    object `body` (its index in the Trajectory's object order; the frame its mesh is drawn
    in: origin at the object's position, turned by its orientation)."""
    point_m: tuple[float, float, float]
    body: int | None = None

    @classmethod
    def fixed(cls, point_in_world_m) -> "Anchor":
        return cls(tuple(float(x) for x in point_in_world_m))

    @classmethod
    def on(cls, body: int, point_in_body_m=(0.0, 0.0, 0.0)) -> "Anchor":
        return cls(tuple(float(x) for x in point_in_body_m), int(body))


@dataclass(frozen=True)
class Connector:
    """A line (`coils` 0) or a helix of `coils` turns of `radius_m` between two anchors: the
    helix's axis runs from `start` to `end` (so it stretches and compresses with them), with
    a straight lead from each anchor to the coil. `width_px`: the drawn line's width in screen
    pixels (rerun: in UI points)."""
    name: str
    start: Anchor
    end: Anchor
    color: tuple[int, int, int] = (90, 90, 90)
    width_px: float = 2.0
    coils: int = 0
    radius_m: float = 0.0

    def __post_init__(self):
        if self.coils < 0 or self.coils != int(self.coils) or (self.coils > 0 and not self.radius_m > 0):
            raise ValueError(f"connector {self.name!r}: a helix needs coils > 0 and radius_m > 0 (coils a whole "
                             f"number; 0 for a line), got {self.coils} coils of {self.radius_m} m")

    @property
    def n_points(self) -> int:
        """Points of its polyline: the two anchors, and a helix's coil between them."""
        return 2 + (self.coils * HELIX_POINTS_PER_COIL + 1 if self.coils else 0)

    @property
    def bodies(self) -> tuple[int, ...]:
        """The objects its anchors are on."""
        return tuple(a.body for a in (self.start, self.end) if a.body is not None)


@dataclass(frozen=True)
class Drawing:
    """What the viewer draws of a scene: static meshes, one mesh per object in its own frame
    (posed per frame by a Trajectory's positions and orientations), and connectors whose
    ends follow the objects."""
    static: Sequence[Mesh] = ()
    objects: Sequence[Mesh] = ()    # in object frames, in the Trajectory's object order
    ground_z_m: float | None = 0.0  # a grid at this height, if any
    connectors: Sequence[Connector] = ()


def _rotate(q_xyzw: np.ndarray, v: np.ndarray) -> np.ndarray:
    """v turned by the unit quaternion q (x, y, z, w): v + 2w (u x v) + 2 u x (u x v)."""
    u, w = q_xyzw[:3], q_xyzw[3]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def anchor_in_world(anchor: Anchor, position_m: np.ndarray, orientation_xyzw: np.ndarray | None) -> np.ndarray:
    """The anchor's point in the world frame, with the objects at `position_m` (n_objects, 3)
    turned by `orientation_xyzw` (n_objects, 4; None: not turned)."""
    p = np.asarray(anchor.point_m, float)
    if anchor.body is None:
        return p
    if orientation_xyzw is not None:
        p = _rotate(np.asarray(orientation_xyzw[anchor.body], float), p)
    return np.asarray(position_m[anchor.body], float) + p


def connector_points(connector: Connector, position_m, orientation_xyzw=None) -> np.ndarray:
    """The connector's polyline (connector.n_points, 3) in the world frame with the objects'
    poses at one frame (position_m (n_objects, 3), orientation_xyzw (n_objects, 4) or None,
    as `Trajectory.position_m[:, f]` and `Trajectory.orientation_xyzw[:, f]`): the two
    anchors, and for a helix, between them, `coils` turns at `radius_m` from the axis joining
    the anchors, from the start anchor's end of the axis to the end anchor's. The coil starts
    on the side of world +x (of +y for an axis within 26 degrees of x), so it does not spin
    about its axis as the bodies move."""
    a = anchor_in_world(connector.start, position_m, orientation_xyzw)
    b = anchor_in_world(connector.end, position_m, orientation_xyzw)
    if not connector.coils:
        return np.stack([a, b])
    axis = b - a
    length = float(np.linalg.norm(axis))
    d = axis / length if length > MIN_AXIS_M else np.array([0.0, 0.0, 1.0])
    ref = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = ref - (ref @ d) * d
    u /= np.linalg.norm(u)
    v = np.cross(d, u)
    n = connector.coils * HELIX_POINTS_PER_COIL
    s = np.arange(n + 1) / n
    angle = 2.0 * math.pi * connector.coils * s
    coil = a + s[:, None] * axis + connector.radius_m * (np.cos(angle)[:, None] * u + np.sin(angle)[:, None] * v)
    return np.vstack([a, coil, b])


def frame_pose(traj, frame: int) -> tuple[np.ndarray, np.ndarray | None]:
    """(position_m, orientation_xyzw) of a Trajectory's objects at one frame, as
    `connector_points` takes them (orientation None: the trajectory has none, e.g. one read
    from a file)."""
    orientation = traj.orientation_xyzw
    return traj.position_m[:, frame], None if orientation is None else orientation[:, frame]
