"""The pinhole camera of a video (OpenCV convention: x right, y down, z forward), shared by
every scenario: projection, back-projection, JSON."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np

from .errors import SceneError
from .fields import matrix, number


@dataclass(frozen=True)
class Camera:
    """Pinhole camera, OpenCV convention (x right, y down, z forward)."""
    K: np.ndarray               # (3, 3) intrinsics in pixels
    world_to_camera: np.ndarray  # (4, 4) rigid transform
    width_px: int = 640
    height_px: int = 480
    fps: float = 30.0
    n_frames: int = 90

    def __eq__(self, other: object) -> bool:
        # the generated __eq__ compares the arrays with `==` and raises on their truth value
        if not isinstance(other, Camera):
            return NotImplemented
        return (np.array_equal(self.K, other.K) and np.array_equal(self.world_to_camera, other.world_to_camera)
                and (self.width_px, self.height_px, self.fps, self.n_frames)
                == (other.width_px, other.height_px, other.fps, other.n_frames))

    def project(self, pos_in_world: np.ndarray) -> np.ndarray:
        """World points (..., 3) -> pixel coordinates (..., 2)."""
        p = np.asarray(pos_in_world, float)
        pc = p @ self.world_to_camera[:3, :3].T + self.world_to_camera[:3, 3]
        uv = pc @ self.K.T
        return uv[..., :2] / uv[..., 2:3]

    @property
    def position_in_world(self) -> np.ndarray:
        r, t = self.world_to_camera[:3, :3], self.world_to_camera[:3, 3]
        return -r.T @ t

    def to_json(self) -> dict:
        return {"K": self.K.tolist(), "world_to_camera": self.world_to_camera.tolist(),
                "width_px": self.width_px, "height_px": self.height_px,
                "fps": self.fps, "n_frames": self.n_frames}


def look_at_camera(eye: Iterable[float], target: Iterable[float], *, focal_px: float = 560.0,
                   width_px: int = 640, height_px: int = 480, fps: float = 30.0,
                   n_frames: int = 90) -> Camera:
    """A camera at `eye` looking at `target` with the world's z axis up in the image."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    fwd = target - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    r = np.stack([right, down, fwd])  # rows: camera axes in world
    m = np.eye(4)
    m[:3, :3] = r
    m[:3, 3] = -r @ eye
    k = np.array([[focal_px, 0, width_px / 2], [0, focal_px, height_px / 2], [0, 0, 1.0]])
    return Camera(k, m, width_px, height_px, fps, n_frames)



def backproject_to_plane(cam: Camera, uv: np.ndarray, y_plane_m: float) -> np.ndarray:
    """Pixels (N, 2) -> world points (N, 3) on the plane y = y_plane_m."""
    uv = np.asarray(uv, float).reshape(-1, 2)
    r, t = cam.world_to_camera[:3, :3], cam.world_to_camera[:3, 3]
    rays_cam = np.c_[uv, np.ones(len(uv))] @ np.linalg.inv(cam.K).T
    rays = rays_cam @ r                 # directions in world (R^T d)
    origin = -r.T @ t
    s = (y_plane_m - origin[1]) / rays[:, 1]
    return origin + s[:, None] * rays



def camera_from_json(d: dict) -> Camera:
    """Parse and check a scene file's `camera` object (SceneError naming the field)."""
    p = "camera"
    k = matrix(d, "K", p, (3, 3))
    m = matrix(d, "world_to_camera", p, (4, 4))
    r = m[:3, :3]
    if not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or not np.allclose(m[3], [0, 0, 0, 1]):
        raise SceneError("camera.world_to_camera: expected a rigid transform (rotation + translation)")
    if k[0, 0] <= 0 or k[1, 1] <= 0:
        raise SceneError("camera.K: focal lengths must be positive")
    return Camera(k, m, number(d, "width_px", p, lo=1, integer=True), number(d, "height_px", p, lo=1, integer=True),
                  number(d, "fps", p, lo=0, lo_open=True), number(d, "n_frames", p, lo=1, integer=True))


