"""One object's track: KLT features, their 3-D points on the object, and its planar pose."""
from __future__ import annotations

import numpy as np

from ..camera import Camera
from ..shapes import Shape, coarse_triangles
from .klt import klt_window, seed_features
from .pose import MIN_INLIERS, fit_pose, project, ray_cast, rot_y
from .silhouette import project_silhouette

MAX_FEATURES = 48          # features per object
RESEED_FRACTION = 0.5      # re-seed when fewer than this fraction of the most ever seeded remain
MIN_SEEN_FRACTION = 0.25   # an object seen in fewer than this fraction of the frames gets a note


class ObjectTracker:
    """One object's KLT features, their 3-D points on the object, and its planar pose.

    Pose: centre (x, z) in the fall-line plane y = 0 and rotation psi about y. Each feature
    is a point on the object's estimated 3-D shape (found by casting the pixel's ray into
    the shape at the pose when the feature was seeded); the pose per frame minimises the
    features' reprojection error (Gauss-Newton, iterative outlier rejection). Features on
    the front, top and end faces thus each move by their own perspective.
    """

    def __init__(self, shape: Shape, mask: np.ndarray, pose: np.ndarray, cam: Camera, n_frames: int):
        """`mask`: the object's silhouette where it starts (it sets the KLT window); `pose`:
        its starting pose (x, z, psi)."""
        self.shape, self.cam = shape, cam
        self.pts = np.zeros((0, 2), np.float32)    # current image positions
        self.obj = np.zeros((0, 3))                 # the features' points in the object frame, metres
        self.pose = pose                            # x, z, psi
        self.center = np.full((n_frames, 2), np.nan)
        self.visible = np.zeros(n_frames, bool)
        self.features: list[np.ndarray] = [np.zeros((0, 2))] * n_frames
        self.n_seeded = 0
        self.lost = False
        self.velocity = np.zeros(3)                 # pose change per frame, for prediction
        self.win = klt_window(mask)
        self._eye = cam.position_in_world
        self._hull = coarse_triangles(self.shape).reshape(-1, 3)

    def project(self, p_obj: np.ndarray, pose: np.ndarray) -> np.ndarray:
        return project(self.cam, p_obj, pose)

    def predicted_mask(self, pose: np.ndarray | None = None) -> np.ndarray:
        """The object's silhouette at a pose (default: the current one)."""
        pose = self.pose if pose is None else pose
        return project_silhouette(self.cam, self._hull, rot_y(pose[2]), np.array([pose[0], 0.0, pose[1]])) > 0

    def _unproject(self, uv: np.ndarray) -> np.ndarray:
        """Object-frame points where the pixels' rays (through the lens) meet the shape at the
        current pose."""
        dirs_w = self.cam.pixel_rays(uv)
        rot = rot_y(self.pose[2])
        c = np.array([self.pose[0], 0.0, self.pose[1]])
        return ray_cast(self.shape, (self._eye - c) @ rot, dirs_w @ rot)

    def add_features(self, gray: np.ndarray, mask: np.ndarray) -> None:
        """New features inside the mask, up to MAX_FEATURES, tied to the shape at the current pose."""
        want = MAX_FEATURES - len(self.pts)
        if want <= 0:
            return
        new = seed_features(gray, mask, want, self.win, avoid=self.pts)
        if len(new):
            p = self._unproject(new.astype(float))
            hit = np.all(np.isfinite(p), axis=1)
            self.pts = np.concatenate([self.pts, new[hit]]).astype(np.float32)
            self.obj = np.concatenate([self.obj, p[hit]])
            self.n_seeded = max(self.n_seeded, len(self.pts))

    def needs_features(self) -> bool:
        """Too few features left: re-seed."""
        return len(self.pts) < max(MIN_INLIERS * 2, int(self.n_seeded * RESEED_FRACTION))

    def predict(self, frames: int = 1) -> np.ndarray:
        """The pose expected `frames` frames on (constant velocity)."""
        return self.pose + frames * self.velocity

    def reset(self, pose: np.ndarray) -> None:
        """Found again at `pose` after it was lost: at rest, no longer lost."""
        self.pose = pose
        self.velocity = np.zeros(3)
        self.lost = False

    def fit(self, frame: int, start: np.ndarray | None = None) -> None:
        """The pose in `frame` from the tracked features (from `start`, else the current pose);
        lost when too few features agree."""
        found = fit_pose(self.cam, self.obj, self.pts, self.pose if start is None else start)
        if found is not None:
            pose, keep = found
            if frame > 0 and self.visible[frame - 1]:
                self.velocity = pose - self.pose
            self.pose = pose
            self.pts, self.obj = self.pts[keep], self.obj[keep]
            self.center[frame] = pose[:2]
            self.visible[frame] = self._in_view()
            self.features[frame] = self.pts.copy()
            return
        self.lost = True
        if start is not None:  # coast on the prediction until re-acquired
            self.pose = start
        self.pts, self.obj = np.zeros((0, 2), np.float32), np.zeros((0, 3))

    def _in_view(self) -> bool:
        uv = self.project(np.zeros((1, 3)), self.pose)[0]
        return 0 <= uv[0] < self.cam.width_px and 0 <= uv[1] < self.cam.height_px


def rarely_seen_notes(objects) -> list[str]:
    """A note (for `Tracks.notes`) for each tracked object (`ObjectTrack`) seen in fewer than
    MIN_SEEN_FRACTION of the frames: what inference learns of it rests on those frames alone,
    and a scene file that describes another video (or the object's start wrongly) looks so."""
    notes = []
    for o in objects:
        k, n = int(np.count_nonzero(o.visible)), len(o.visible)
        if k < MIN_SEEN_FRACTION * n:
            notes.append(f"{o.name} ({o.role}) is seen in only {k} of {n} frames ({k / n:.1%}): what inference "
                         f"learns of it rests on those; check that the scene file's camera and start describe "
                         f"this video")
    return notes
