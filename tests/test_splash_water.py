"""What real water does to a body, in the splash's physics, against the analytic cases
(galileo/scenarios/splash/physics.py's docstring gives each law and its source):

* terminal velocity: added mass changes how a body gets there, not where: Newton's
  balance (rho - rho_w) V g = 1/2 rho_w D A v_t^2 holds to 0.1%;
* heave of a floating plate: a harmonic oscillator of mass m + m_a and stiffness
  rho_w g A_waterline (Archimedes), period 2 pi sqrt((m + m_a) / (rho_w g A)), twice the
  period the body alone would have: the added mass is in the dynamics;
* water entry: a neutrally buoyant body pushed into still water (gravity near 0, no drag)
  keeps its momentum: (m + m_a) v_after = m v_before (von Karman's impulse).
m_a is the documented law, K rho_w A^(3/2) (the sphere's exact 1/2 rho V) times the
submerged fraction; the truths are Newton's and the oscillator's."""
from __future__ import annotations

import math

import numpy as np

from galileo.scenarios.splash.physics import Simulator
from galileo.scenarios.splash.scene import SplashObject, SplashScene, Tank

RHO_W = 1000.0
HZ = 240
# the law's constant from its anchor, a sphere of radius r: 1/2 rho V = K rho (pi r^2)^(3/2)
K_SPHERE = 0.5 * (4 / 3 * math.pi) / math.pi ** 1.5


def scene(tank: Tank, obj: SplashObject, z_m: float, gravity_mps2: float = 9.81, push_mps: float = 0.0):
    s = SplashScene(tank, obj, (0.0, 0.0, z_m), 0.0, None, HZ, gravity_mps2, push_mps=push_mps)
    s.validate()
    return s


def steps(sc: SplashScene, n: int) -> list:
    """The states of n physics steps from the release."""
    st = Simulator(sc).frames()
    state, out = st.state(), []
    for _ in range(n):
        state = st.step(state)
        out.append(state)
    return out


def test_terminal_velocity_is_newtons_with_added_mass():
    tank = Tank((0.5, 0.5, 2.9), 0.006, 2.8)                 # 2.8 m of water: time to get there
    obj = SplashObject("cube", "box", 27.0, 9.0, 2.0, 0.8)    # 3 cm cube, 2 g/cm^3
    vz = Simulator(scene(tank, obj, 2.85)).run(60).velocity_mps[0, :, 2]
    v_t = math.sqrt(2 * (2000.0 - RHO_W) * 27e-6 * 9.81 / (RHO_W * 0.8 * 9e-4))
    assert np.allclose(-vz[-10:], v_t, rtol=1e-3)


def test_a_floating_plate_heaves_with_its_added_mass():
    tank = Tank((0.4, 0.16, 0.3), 0.006, 0.2)
    plate = SplashObject("plate", "box", 27.0, 36.0, 0.5, 0.001)   # 6 x 6 x 0.75 cm, floats half under
    z = np.array([s[0][2] for s in steps(scene(tank, plate, 0.2 + 0.002), 2 * HZ)])   # 2 mm above rest
    crossings = np.flatnonzero(np.diff(np.sign(z - z.mean())))
    period_s = 2 * np.mean(np.diff(crossings)) / HZ
    m, area = 0.5 * 27e-3, 36e-4
    m_a = K_SPHERE * RHO_W * area ** 1.5 * 0.5                      # half under water
    expected = 2 * math.pi * math.sqrt((m + m_a) / (RHO_W * 9.81 * area))
    assert abs(period_s / expected - 1) < 0.03
    assert period_s > 1.5 * 2 * math.pi * math.sqrt(m / (RHO_W * 9.81 * area))   # not the bare body's


def test_entering_the_water_hands_momentum_to_it():
    tank = Tank((0.4, 0.16, 0.3), 0.006, 0.2)
    cube = SplashObject("cube", "box", 27.0, 9.0, 1.0, 0.001)      # neutrally buoyant, no drag to speak of
    sc = scene(tank, cube, 0.2 + 0.0151, gravity_mps2=0.01, push_mps=1.0)   # 1 mm above the water, 1 m/s down
    states = steps(sc, 14)
    m = 27e-3
    m_a = K_SPHERE * RHO_W * (9e-4) ** 1.5
    assert states[-1][0][2] + 0.015 < 0.2                          # wholly under water
    assert abs(-states[-1][2][2] / (m * 1.0 / (m + m_a)) - 1) < 5e-3
