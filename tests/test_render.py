"""The renderer looks through the scene's calibrated camera: projections of known 3D
points land where the renderer draws them (checked on its segmentation mask)."""
import dataclasses
import itertools

import numpy as np
import pytest

from galileo.render import Look
from galileo.scenarios.ramp.render import Renderer
from galileo.scenarios.ramp.scene import default_camera, default_scene
from galileo.shapes import Shape


def _box_corners_in_world(scene, index, pos, orn):
    from galileo.sim.bullet import pb

    sx, sy, sz = scene.objects[index].shape.size_m
    r = np.array(pb.getMatrixFromQuaternion(orn)).reshape(3, 3)
    corners = np.array(list(itertools.product([-sx / 2, sx / 2], [-sy / 2, sy / 2], [-sz / 2, sz / 2])))
    return corners @ r.T + np.asarray(pos)


@pytest.mark.parametrize("principal_offset_px", [(0, 0), (-25, 18)])
def test_projected_box_matches_rendered_silhouette(principal_offset_px):
    cam = default_camera()
    k = cam.K.copy()
    k[0, 2] += principal_offset_px[0]
    k[1, 2] += principal_offset_px[1]
    cam = dataclasses.replace(cam, K=k)
    scene = default_scene(20, target="cardboard", shape=Shape("box", (0.08, 0.06, 0.05)), camera=cam)
    r = Renderer(scene)
    r.sim.reset()
    rgb, seg = r.render_current(0, with_segmentation=True)
    assert rgb.shape == (480, 640, 3) and rgb.dtype == np.uint8
    for i, body in enumerate(r.body_ids):
        pos, orn = scene.initial_pose(i)
        uv = cam.project(_box_corners_in_world(scene, i, pos, orn))
        ys, xs = np.nonzero(seg == body)
        assert len(xs) > 200, "object not visible"
        # a pixel is filled when its centre (integer coordinates) lies inside the projection,
        # so the first filled pixel is within [u_min, u_min + 1) and one past the last within
        # (u_max, u_max + 1]: both within 0.5 (+ slack) of the bound + 0.5. (A render off by
        # one pixel, e.g. without RASTER_OFFSET_PX, fails; the old 1.5 px tolerance passed it.)
        np.testing.assert_allclose([xs.min(), ys.min()], uv.min(0) + 0.5, atol=0.6)
        np.testing.assert_allclose([xs.max() + 1, ys.max() + 1], uv.max(0) + 0.5, atol=0.6)


def test_noise_and_lighting_are_mild_but_present():
    scene = default_scene(20, target=None, camera=default_camera())
    look = Look((0.3, -1.2, 2.0), 0.6, 0.45, gain_drift=0.01, noise_sd=2.0, seed=3)
    r = Renderer(scene, look)
    r.sim.reset()
    a = r.render_current(0).astype(float)
    b = r.render_current(1).astype(float)
    diff = (a - b)[300:, :]  # static ground: only noise and gain differ
    assert 1.0 < diff.std() < 6.0
