"""Shape geometry against closed-form formulas, and shape validation."""
import math

import numpy as np
import pytest

from galileo.shapes import Shape

TOL = 2e-3  # the meshes have 128 sections: polygon error ~ (2 pi / 128)^2 / 6 = 0.04% per direction


def box_truth(a, b, c):
    return (a * b * c, 2 * (a * b + b * c + c * a),
            np.array([b * b + c * c, a * a + c * c, a * a + b * b]) / 12)


def cylinder_truth(length, diameter):
    """Axis along x."""
    r = diameter / 2
    i_axis = r * r / 2
    i_across = (3 * r * r + length * length) / 12
    return (math.pi * r * r * length, 2 * math.pi * r * length + 2 * math.pi * r * r,
            np.array([i_axis, i_across, i_across]))


def torus_truth(outer, tube):
    """Hole axis along z; major radius R = (outer - tube) / 2, minor radius r = tube / 2."""
    big_r, r = (outer - tube) / 2, tube / 2
    i_axis = big_r ** 2 + 3 * r * r / 4
    i_diam = big_r ** 2 / 2 + 5 * r * r / 8
    return (2 * math.pi ** 2 * big_r * r * r, 4 * math.pi ** 2 * big_r * r,
            np.array([i_diam, i_diam, i_axis]))


CASES = [
    (Shape("box", (0.06, 0.05, 0.04)), box_truth(0.06, 0.05, 0.04)),
    (Shape("box", (0.2, 0.01, 0.03)), box_truth(0.2, 0.01, 0.03)),
    (Shape("cylinder", (0.08, 0.04, 0.04)), cylinder_truth(0.08, 0.04)),
    (Shape("cylinder", (0.14, 0.015, 0.015)), cylinder_truth(0.14, 0.015)),  # a pole: I_axis << I_across
    (Shape("cylinder", (0.02, 0.1, 0.1)), cylinder_truth(0.02, 0.1)),        # a disc: I_axis > I_across
    (Shape("torus", (0.08, 0.08, 0.02)), torus_truth(0.08, 0.02)),
    (Shape("torus", (0.1, 0.1, 0.045)), torus_truth(0.1, 0.045)),            # fat tube, small hole
]
IDS = [f"{s.type}-{'x'.join(f'{v:g}' for v in s.size_m)}" for s, _ in CASES]


@pytest.mark.parametrize("shape,truth", CASES, ids=IDS)
def test_volume(shape, truth):
    assert shape.volume_m3 == pytest.approx(truth[0], rel=TOL)


@pytest.mark.parametrize("shape,truth", CASES, ids=IDS)
def test_surface_area(shape, truth):
    assert shape.surface_area_m2 == pytest.approx(truth[1], rel=TOL)


@pytest.mark.parametrize("shape,truth", CASES, ids=IDS)
def test_principal_inertia_per_kg(shape, truth):
    inertia = shape.inertia_per_kg()
    assert inertia.shape == (3,)
    # per axis, in object axes (x, y, z): the order matters, not just the set of values
    np.testing.assert_allclose(inertia, truth[2], rtol=TOL)


def test_height_is_object_z():
    assert Shape("box", (0.06, 0.05, 0.04)).height_m == 0.04
    assert Shape("cylinder", (0.08, 0.03, 0.03)).height_m == 0.03
    assert Shape("torus", (0.08, 0.08, 0.02)).height_m == 0.02


@pytest.mark.parametrize("shape", [s for s, _ in CASES], ids=IDS)
def test_valid_shapes_have_no_problem(shape):
    assert shape.problem() is None


@pytest.mark.parametrize("shape,words", [
    (Shape("cylinder", (0.1, 0.04, 0.05)), ("cylinder", "y == z")),
    (Shape("torus", (0.08, 0.07, 0.02)), ("torus", "x == y")),
    (Shape("torus", (0.04, 0.04, 0.02)), ("torus", "2 * tube")),   # x == 2 z: the hole closes
    (Shape("torus", (0.04, 0.04, 0.03)), ("torus", "2 * tube")),   # x < 2 z
    (Shape("box", (-0.1, 0.1, 0.1)), ("positive",)),
    (Shape("cylinder", (0.1, -0.04, -0.04)), ("positive",)),
    (Shape("box", (0.0, 0.1, 0.1)), ("positive",)),
    (Shape("box", (float("nan"), 0.1, 0.1)), ("positive",)),
    (Shape("box", (0.1, 0.1)), ("three",)),
    (Shape("sphere", (0.1, 0.1, 0.1)), ("type", "sphere")),
], ids=["cyl-y!=z", "torus-x!=y", "torus-x=2z", "torus-x<2z", "neg-box", "neg-cyl", "zero", "nan",
        "two-sizes", "unknown-type"])
def test_problem_rejects(shape, words):
    problem = shape.problem()
    assert isinstance(problem, str) and problem
    assert "\n" not in problem
    for w in words:
        assert w in problem


def test_json_round_trip():
    s = Shape("torus", (0.08, 0.08, 0.02))
    d = s.to_json()
    assert d == {"type": "torus", "size_m": [0.08, 0.08, 0.02]}
    assert Shape(d["type"], d["size_m"]) == s
