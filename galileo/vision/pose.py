"""Planar pose of a rigid shape from its image points.

Pose: centre (x, z) in the fall-line plane y = 0 and rotation psi about y. Image points
are tied to points on the shape by casting their rays into it (Moller-Trumbore against a
coarse mesh); the pose minimises their reprojection error (Gauss-Newton with numerical
derivatives) with iterative outlier rejection, so that points that slid onto another
object or the background drop out.
"""
from __future__ import annotations

import math

import numpy as np

from . import MAD_TO_SD
from ..camera import Camera
from ..shapes import Shape, coarse_triangles

MIN_INLIERS = 4            # fewer points than this: no pose
INLIER_PX = 1.0            # reprojection residual that always keeps a feature in the pose fit
OUTLIER_MADS = 3.0         # residuals beyond this many robust SDs drop out
OUTLIER_ROUNDS = 3
GN_ITERATIONS = 6
GN_STEPS = (1e-4, 1e-4, 1e-3)   # finite-difference steps: x, z (m), psi (rad)
GN_TOL_M = 1e-6            # converged: |dx| + |dz| below this and |dpsi| below GN_TOL_RAD
GN_TOL_RAD = 1e-5
RAY_MIN_DET = 1e-12        # rays parallel to a triangle miss it
RAY_MIN_T = 1e-9           # hits this close to the origin (or behind it) do not count
RAY_EDGE_TOL = 1e-9        # barycentric slack: a ray through an edge two triangles share hits them (rounding
                           # could leave it outside both, and the ray would pass through the face)


def rot_y(psi: float) -> np.ndarray:
    """Rotation about the world y axis (the object's x axis goes to (cos, 0, -sin))."""
    c, s = math.cos(psi), math.sin(psi)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def to_world(p_obj: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Object-frame points at a planar pose (x, z, psi), in the world frame."""
    return p_obj @ rot_y(pose[2]).T + np.array([pose[0], 0.0, pose[1]])


def project(cam: Camera, p_obj: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Pixels of object-frame points at a planar pose (through the lens: `Camera.project`)."""
    return cam.project(to_world(p_obj, pose))


def ray_cast(shape: Shape, origin_obj: np.ndarray, dirs_obj: np.ndarray) -> np.ndarray:
    """First hit (object frame) of each ray with the shape, NaN where it misses (Moller-Trumbore)."""
    tri = coarse_triangles(shape)
    v0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    d = dirs_obj[:, None, :]                                  # (R, 1, 3)
    pvec = np.cross(d, e2[None])                              # (R, T, 3)
    det = np.einsum("rtk,tk->rt", pvec, e1)
    ok = np.abs(det) > RAY_MIN_DET
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    tvec = origin_obj[None, :] - v0                           # (T, 3)
    u = np.einsum("rtk,tk->rt", pvec, tvec) * inv
    qvec = np.cross(tvec[None], e1[None])                     # (1, T, 3)
    v = np.einsum("rk,tk->rt", dirs_obj, qvec[0]) * inv
    t = np.einsum("tk,tk->t", e2, qvec[0])[None] * inv
    hit = ok & (u >= -RAY_EDGE_TOL) & (v >= -RAY_EDGE_TOL) & (u + v <= 1 + RAY_EDGE_TOL) & (t > RAY_MIN_T)
    t = np.where(hit, t, np.inf)
    best = t.min(axis=1)
    out = origin_obj[None] + best[:, None] * dirs_obj
    out[~np.isfinite(best)] = np.nan
    return out


def solve_pose(cam: Camera, obj: np.ndarray, pts: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Gauss-Newton from `pose` on the reprojection error of object points `obj` seen at `pts`."""
    steps = np.array(GN_STEPS)
    for _ in range(GN_ITERATIONS):
        r0 = (project(cam, obj, pose) - pts).ravel()
        jac = np.empty((len(r0), 3))
        for k in range(3):
            dp = pose.copy()
            dp[k] += steps[k]
            jac[:, k] = ((project(cam, obj, dp) - pts).ravel() - r0) / steps[k]
        delta = np.linalg.lstsq(jac, -r0, rcond=None)[0]
        pose = pose + delta
        if abs(delta[0]) + abs(delta[1]) < GN_TOL_M and abs(delta[2]) < GN_TOL_RAD:
            break
    return pose


def fit_pose(cam: Camera, obj: np.ndarray, pts: np.ndarray, start: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Pose and inlier mask from object points and their pixels (iterative outlier
    rejection around Gauss-Newton from `start`); None with fewer than MIN_INLIERS inliers."""
    if len(pts) < MIN_INLIERS:
        return None
    keep = np.ones(len(pts), bool)
    pose = start.copy()
    for _ in range(OUTLIER_ROUNDS):
        pose = solve_pose(cam, obj[keep], pts[keep], pose)
        res = np.linalg.norm(project(cam, obj, pose) - pts, axis=1)
        mad = float(np.median(res[keep]))
        new = res < max(INLIER_PX, OUTLIER_MADS * MAD_TO_SD * mad)
        if np.array_equal(new, keep) or new.sum() < MIN_INLIERS:
            break
        keep = new
    return (pose, keep) if keep.sum() >= MIN_INLIERS else None
