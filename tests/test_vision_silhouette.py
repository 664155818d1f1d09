"""Vision parts on synthetic silhouettes: projection, IoU, the silhouette fits, rotation,
ray casting and the KLT window."""
import math

import numpy as np
import pytest

from galileo.scenarios.ramp.scene import default_camera
from galileo.shapes import Shape
from galileo.vision.klt import WIN_MAX, WIN_MIN, klt_window
from galileo.vision.pose import ray_cast, rot_y
from galileo.vision.silhouette import crop, fit_silhouette, iou_loss, shape_silhouette, slide_silhouette


def _on_ground(shape, x):
    return shape, np.eye(3), np.array([x, 0.0, shape.height_m / 2])


@pytest.mark.parametrize("kind,size", [("box", (0.06, 0.05, 0.04)), ("cylinder", (0.08, 0.04, 0.04)),
                                       ("torus", (0.08, 0.08, 0.02))])
def test_silhouette_and_iou(kind, size):
    cam = default_camera()
    shape = Shape(kind, size)
    m = shape_silhouette(cam, *_on_ground(shape, 0.1)).astype(bool)
    assert m.shape == (cam.height_px, cam.width_px) and m.sum() > 100
    assert iou_loss(m, m) == 0.0
    assert iou_loss(m, np.zeros_like(m)) == 1.0
    moved = shape_silhouette(cam, *_on_ground(shape, 0.13)).astype(bool)
    assert 0.0 < iou_loss(m, moved) < 1.0
    roi, obs = crop(m, 10)
    assert obs.sum() == m.sum()
    assert np.array_equal(shape_silhouette(cam, *_on_ground(shape, 0.1), roi).astype(bool), obs)


def test_fits_recover_position_and_size():
    cam = default_camera()
    truth = Shape("box", (0.06, 0.05, 0.04))
    m = shape_silhouette(cam, *_on_ground(truth, 0.12)).astype(bool)
    x = slide_silhouette(cam, m, lambda a: _on_ground(truth, a), (0.08, 0.16), 20)
    assert x == pytest.approx(0.12, abs=1e-3)

    def posed(p):
        return _on_ground(Shape("box", tuple(np.exp(p[1:4]))), p[0])

    res = fit_silhouette(cam, m, posed, np.array([0.11, *np.log([0.05, 0.05, 0.05])]), 30)
    assert res.fun < 0.05 and res.x[0] == pytest.approx(0.12, abs=3e-3)


def test_rotation_and_ray_cast():
    r = rot_y(0.3)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(r @ [1, 0, 0], [math.cos(0.3), 0, -math.sin(0.3)])
    box = Shape("box", (0.06, 0.05, 0.04))
    hits = ray_cast(box, np.array([0.0, 0.0, 1.0]), np.array([[0.0, 0.0, -1.0], [1.0, 0.1, 0.1]]))
    np.testing.assert_allclose(hits[0], [0, 0, 0.02])
    assert np.isnan(hits[1]).all()


def test_klt_window_fits_the_silhouette():
    thin = np.zeros((100, 200), bool)
    thin[50:56, 20:180] = True
    fat = np.zeros((100, 200), bool)
    fat[20:80, 20:180] = True
    assert klt_window(thin) == WIN_MIN and klt_window(fat) == WIN_MAX
    assert all(klt_window(m) % 2 == 1 for m in (thin, fat))


def test_a_polygon_filled_by_pixel_centres_holds_the_integer_points_inside_it():
    """Pixel (x, y) is centred on (x, y): a square from 2.2 to 7.9 holds the centres 3..7 on
    each axis (25 pixels; OpenCV's fill of its rounded corners takes 2..8, 49), a triangle the
    lattice points inside it (counted directly), whichever way round its corners are given."""
    from galileo.vision.silhouette import fill_polygon, fill_polygon_centres

    sq = np.array([(2.2, 2.2), (7.9, 2.2), (7.9, 7.9), (2.2, 7.9)])
    m = fill_polygon_centres(sq, (12, 12))
    ys, xs = np.nonzero(m)
    assert (xs.min(), xs.max(), ys.min(), ys.max(), int(m.sum())) == (3, 7, 3, 7, 25)
    assert fill_polygon(np.round(sq).astype(np.int32), (12, 12)).sum() == 49   # (rounded: 2..8, 7 x 7)
    tri = np.array([(1.3, 1.7), (17.6, 4.2), (6.1, 14.9)])
    inside = 0
    for y in range(20):
        for x in range(20):
            d = [(b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0])
                 for a, b in ((tri[i], tri[(i + 1) % 3]) for i in range(3))]
            inside += all(v >= 0 for v in d) or all(v <= 0 for v in d)
    for pts in (tri, tri[::-1]):
        assert int(fill_polygon_centres(pts, (20, 20)).sum()) == inside
