"""Scene & priors of the splash scenario (Physics 101, splash abstract, section 3): an object
dropped into a glass tank of water, filmed from the side.

World frame (metres, z up): the origin is the centre of the tank's floor (inside); x runs
along the tank's long side, across the image; y away from the camera; the water fills the
tank up to `water_level_m`.

Shapes (the seed's three primitives, two degrees of freedom each), given as volume `h` and
the area `s` the object shows the water it falls into: its horizontal cross-section from
below (the bottom face, a vertical cylinder's disc, a horizontal cylinder's length times
diameter). That is the seed's "surface area that interacts with the water": its prior
U(0.1, 20) cm^2 fits a bottom, not a whole surface (a 100 cm^3 cube has 21.5 cm^2 of bottom
and 129 cm^2 of surface). The dimensions follow deterministically:

    box (square bottom):   side a = sqrt(s), height H = h / s
    vertical cylinder:     diameter D = 2 sqrt(s / pi), height H = h / s
    horizontal cylinder:   diameter D = 4 h / (pi s), length L = pi s^2 / (4 h)

Every positive (h, s) has a solution, but most are not objects: h = 100 cm^3 over s = 0.1
cm^2 is a 10 m needle. A pair whose dimensions fall outside [MIN_DIM_M, the tank's inner
width] has no solution here: `dimensions` returns None, the prior density is 0 there and
MCMC rejects such a proposal without simulating (the prior is U(0.1, 20) cm^2 truncated to
objects that fit in the tank). `equal_area(kind, h)` is the s at which the dimensions are
equal (a = H; D = H; D = L), where the seed starts its chains.

Latents (MCMC): bottom area `area_cm2`, density `density_g_cm3` ~ U(0.001, 2) g/cm^3, water
drag `drag_water` ~ U(0.001, 2) (air drag = 1e-3 x water drag), and three the seed has not:

* the release, in video time: `release_s`, the moment (s; frame f is at f / fps) the object
  is let go at `release_m`, and `push_mps`, the downward speed it is given then. Before
  `release_s` the object is held still at `release_m` (a hand holds it: 0 s to a second in
  real drops); from then on it falls from `release_m` at push_mps downwards. A release
  before frame 0 (release_s < 0) is the seed's "observation start t" (here -t / sim_hz):
  the video opens with the object already falling. A model that can only start at rest a
  few steps before frame 0 explains a held or pushed start with a weightless, draggy object.
* `log_volume_factor`: the natural log of the object's volume over the bottom-up estimate
  `object.volume_cm3` (a log, so that a prior as wide above as below the estimate has its
  median there: a uniform prior on the factor itself puts most of its mass above it) (the
  camera sees width and height, never depth: the volume is uncertain, and with it the mass;
  the motion identifies the density and, weakly, the volume through drag and added mass).
  mass = density x exp(log_volume_factor) x volume_cm3.

Priors left at their defaults are set from the video when tracks are prepared (the
scenario's `prepare`): the area prior U(A/4, 4 A), A the area at which an object of the
bottom-up volume has equal sides (the seed's U(0.1, 20) cm^2 fits neither a 100 cm^3 object,
A = 21.5 cm^2, nor a 0.01 cm^3 bead, A = 0.046 cm^2; a factor of 4 either way spans sides in
the ratios 1:8 to 8:1); the log volume factor's from the tracker's uncertainty (+-2 sd); the
release's a window around the release the tracker saw. Bounds set by hand are kept.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar


from ...camera import Camera, camera_from_json, check_camera, check_run, look_at_camera, physics_hz
from ...errors import SceneError
from ...fields import (Bound, field_value, is_finite_number, is_number, number, pair, show, unknown_fields,
                       where_of)
from ...latents import Latent, check_bounds
from ...scenefile import SceneFile
from ...shapes import Box, Cylinder, Shape

SCENE_VERSION = 2   # 2: the release in video time (release_s, push_mps), the log volume factor; version 1
# files (start_step: frame 0 at that physics step after a release at rest) are read too
KINDS = ("box", "vcyl", "hcyl")   # square-bottomed box, vertical cylinder, horizontal cylinder
MIN_DIM_M = 0.002                 # no dimension below 2 mm
WATER_DENSITY_KG_M3 = 1000.0
RELEASE_ABOVE_WATER_M = 0.15   # the default scene's drop: 0.17 s (41 steps) of fall in air
CM3 = 1e-6                        # m^3 per cm^3
CM2 = 1e-4                        # m^2 per cm^2

# -- what a splash scene may hold: every bound in one place, each with its reason ------------------
# (checked where a file is parsed, where a scene is built in code and by `with_values`, so by
# `galileo simulate --set` too; an error names the field and the bound)
VOLUME_CM3 = Bound(0.01, 100.0)             # the seed's objects: 0.01 cm^3 (a 2 mm bead) to 100 cm^3 (a fist)
VOLUME_RANGE_CM3 = (VOLUME_CM3.lo, VOLUME_CM3.hi)
AREA_CM2 = Bound(0.0, 1000.0, lo_open=True)   # bottom area: above 0; at most 1000 cm^2 (a 32 cm square, the
# size of the tank; the shape must also fit the tank, checked with it)
DENSITY_G_CM3 = Bound(0.001, 25.0)          # at least 0.001 g/cm^3 (1 kg/m^3, about air's 1.2: a lighter object
# would not fall through the air, whose buoyancy the splash leaves out; the paper's prior starts here; Bullet
# takes a mass under 2.2e-16 kg, its epsilon, for an immovable one, so a 1e-300 g/cm^3 object hung at its release
# point, while the smallest object now, 0.01 cm^3, weighs 1e-8 kg and, at least 2 mm across, has inertias 30
# times that epsilon), at most 25 g/cm^3 (osmium's 22.6 is the densest element)
DRAG_WATER = Bound(0.0, 100.0)              # a drag coefficient: 0 (none: a free fall), about 1 for a blunt body
# and 2 for a plate broadside; at most 100 (50 plates), far beyond any body yet finite. The latent's prior
# bounds must lie in (0, 100]: above 0, as the paper's prior U(0.001, 2)
RELEASE_S = Bound(-4.0, 60.0)               # the release's video time: at most 4 s before frame 0 (the object has
# long settled by then), at most a minute into the video (MAX_STEPS bounds the run itself)
PUSH_MPS = Bound(0.0, 5.0)                  # the downward speed at release: 0 (let go) to 5 m/s (a throw: beyond
# it the object hits the water faster than any splash this model has)
YAW_DEG = Bound(-180.0, 180.0)              # the object's turn about the vertical, degrees
LOG_VOLUME_FACTOR = Bound(-5.0, 5.0)        # ln(true volume / the bottom-up one): a factor of e^5 = 148 either way
# (the volume itself is checked against VOLUME_CM3, 0.01-100 cm^3: a factor of 10^4 at most)
TANK_SIZE_M = Bound(0.02, 3.0)              # the tank's inner sizes: 2 cm (room for a 2 mm object) to 3 m (a
# tank on a lab floor)
WALL_M = Bound(0.0, 0.1, lo_open=True)      # glass walls: above 0 (Bullet needs a body), at most 10 cm
LIQUID_DENSITY_KG_M3 = Bound(1.0, 5000.0)   # the liquid: from a gas-like 1 kg/m^3 to 5000 kg/m^3 (denser than any
# liquid but mercury and molten metals)
MAX_DROP_M = 1.0                            # the release point at most 1 m above the water (from higher the object
# hits the water at over 4.4 m/s, a splash beyond this model, and leaves the camera's view)
SIM_HZ = Bound(60, 10_000)                  # Bullet steps per second: at least 60 (the water's forces are applied
# once a step: slower, a falling object crosses the surface in one), at most 10 kHz (40x the cost of 240)
GRAVITY_MPS2 = Bound(0.0, 100.0, lo_open=True)   # downwards, above 0 (without gravity nothing falls: the object
# hangs at its release point and the video holds no evidence), at most 100 m/s^2 (10 g; beyond any lab)
MAX_STEPS = 2_000_000                       # physics steps of one simulated video (from a release before frame 0
# + frames x sim_hz / fps) at most: about a minute of Bullet; inference repeats it thousands of times

LATENT_SPECS = {
    "area_cm2": Latent("area_cm2", "cm^2", (0.1, 20.0), "area the object shows the water from below (drag, shape)",
                       limits=(AREA_CM2.lo, AREA_CM2.hi), limits_open_low=True, narrow=0.05, broad=0.5),
    "density_g_cm3": Latent("density_g_cm3", "g/cm^3", (0.001, 2.0), "object's density (mass = density x volume)",
                            limits=(DENSITY_G_CM3.lo, DENSITY_G_CM3.hi), limits_open_low=DENSITY_G_CM3.lo_open,
                            narrow=0.05, broad=0.5),
    "drag_water": Latent("drag_water", "1", (0.001, 2.0), "drag coefficient in water (in air: 1e-3 x this)",
                         limits=(DRAG_WATER.lo, DRAG_WATER.hi), limits_open_low=True, narrow=0.05, broad=0.5),
    "release_s": Latent("release_s", "s", (-0.25, 1.0), "video time the object is let go (held still before)",
                        limits=(RELEASE_S.lo, RELEASE_S.hi), narrow=0.005, broad=0.05),
    "push_mps": Latent("push_mps", "m/s", (0.0, 0.5), "downward speed the object is let go at",
                       limits=(PUSH_MPS.lo, PUSH_MPS.hi), narrow=0.02, broad=0.1),
    "log_volume_factor": Latent("log_volume_factor", "1", (-0.5, 0.5), "ln(volume / the bottom-up estimate)",
                                limits=(LOG_VOLUME_FACTOR.lo, LOG_VOLUME_FACTOR.hi), narrow=0.02,
                            broad=0.2),
}
# each value `with_values` takes, with its bound
VALUE_BOUNDS = {"area_cm2": AREA_CM2, "density_g_cm3": DENSITY_G_CM3, "drag_water": DRAG_WATER,
                "release_s": RELEASE_S, "push_mps": PUSH_MPS, "log_volume_factor": LOG_VOLUME_FACTOR,
                "volume_cm3": VOLUME_CM3}
LATENT_NAMES = tuple(LATENT_SPECS)


def dimensions(kind: str, volume_m3: float, area_m2: float, max_dim_m: float = math.inf) -> tuple | None:
    """(length x, depth y, height z) in metres of a `kind` object of this volume and
    bottom area, upright as dropped; None where no object of these sizes fits (see module)."""
    if not (volume_m3 > 0 and area_m2 > 0):
        return None
    if kind == "box":
        a = math.sqrt(area_m2)
        dims = (a, a, volume_m3 / area_m2)
    elif kind == "vcyl":
        d = 2.0 * math.sqrt(area_m2 / math.pi)
        dims = (d, d, volume_m3 / area_m2)
    elif kind == "hcyl":
        d = 4.0 * volume_m3 / (math.pi * area_m2)
        dims = (math.pi * area_m2 ** 2 / (4.0 * volume_m3), d, d)
    else:
        raise SceneError(f"unknown shape kind {kind!r}; expected one of {', '.join(KINDS)}")
    if min(dims) < MIN_DIM_M or max(dims) > max_dim_m:
        return None
    return dims


def equal_area(kind: str, volume_m3: float) -> float:
    """The bottom area (m^2) at which the object's dimensions are all equal."""
    if kind == "box":
        return volume_m3 ** (2.0 / 3.0)
    if kind == "vcyl":   # 2 sqrt(s / pi) = h / s
        return (volume_m3 * math.sqrt(math.pi) / 2.0) ** (2.0 / 3.0)
    if kind == "hcyl":   # 4 h / (pi s) = pi s^2 / (4 h)
        return (16.0 * volume_m3 ** 2 / math.pi ** 2) ** (1.0 / 3.0)
    raise SceneError(f"unknown shape kind {kind!r}; expected one of {', '.join(KINDS)}")


def body_shape(kind: str, dims: tuple) -> tuple[Shape, tuple[float, float, float, float]]:
    """The Galileo shape (object frame) and the orientation (x, y, z, w) dropping it as `kind`
    says: a box and a horizontal cylinder as they are (a cylinder's axis is its object x),
    a vertical cylinder turned upright (its axis along world z)."""
    lx, ly, lz = dims
    if kind == "box":
        return Box((lx, ly, lz)), (0.0, 0.0, 0.0, 1.0)
    if kind == "hcyl":
        return Cylinder((lx, ly, lz)), (0.0, 0.0, 0.0, 1.0)
    s = math.sqrt(0.5)   # vcyl: its axis (object x) turned onto world z: -90 degrees about y
    return Cylinder((lz, lx, lx)), (0.0, -s, 0.0, s)


@dataclass(frozen=True)
class Tank:
    """The glass tank: inner size (x, y, z), wall thickness, water level above its floor."""
    size_m: tuple[float, float, float] = (0.40, 0.16, 0.30)
    wall_m: float = 0.006
    water_level_m: float = 0.20
    water_density_kg_m3: float = WATER_DENSITY_KG_M3

    def to_json(self) -> dict:
        return {"size_m": list(self.size_m), "wall_m": self.wall_m, "water_level_m": self.water_level_m,
                "water_density_kg_m3": self.water_density_kg_m3}


@dataclass(frozen=True)
class SplashObject:
    name: str
    kind: str                        # box | vcyl | hcyl
    volume_cm3: float
    area_cm2: float
    density_g_cm3: float
    drag_water: float
    material: str | None = None

    @property
    def volume_m3(self) -> float:
        return self.volume_cm3 * CM3

    @property
    def mass_kg(self) -> float:
        return self.density_g_cm3 * 1000.0 * self.volume_m3

    def to_json(self) -> dict:
        d: dict[str, Any] = {"name": self.name, "kind": self.kind, "volume_cm3": self.volume_cm3,
                             "area_cm2": self.area_cm2, "density_g_cm3": self.density_g_cm3,
                             "drag_water": self.drag_water}
        if self.material is not None:
            d["material"] = self.material
        return d


DEFAULT_BOUNDS = {n: lat.bounds for n, lat in LATENT_SPECS.items()}


@dataclass(frozen=True)
class SplashScene(SceneFile):
    scenario: ClassVar[str] = "splash"
    tank: Tank
    obj: SplashObject
    release_m: tuple[float, float, float]     # the object's centre when it is let go
    release_s: float = -10 / 240               # video time of the release (s): held still at release_m before
    camera: Camera | None = None
    sim_hz: float = 240   # asked; with a camera, the multiple of its fps nearest it (camera.physics_hz)
    gravity_mps2: float = 9.81
    bounds: dict = field(default_factory=lambda: dict(DEFAULT_BOUNDS))
    push_mps: float = 0.0                      # downward speed at the release
    log_volume_factor: float = 0.0             # ln(the true volume / object.volume_cm3)
    yaw_deg: float = 0.0                       # the object's turn about the vertical as let go (not inferred: it
    # changes what the camera sees of it, not how it falls)

    def release_orientation(self) -> tuple[float, float, float, float]:
        """The object's orientation (x, y, z, w) as let go: as `body_shape` drops its kind, turned
        by yaw_deg about the vertical."""
        x, y, z, w = body_shape(self.obj.kind, (1.0, 1.0, 1.0))[1]
        half = math.radians(self.yaw_deg) / 2
        sz, cz = math.sin(half), math.cos(half)    # (0, 0, sz, cz) x (x, y, z, w), Hamilton's product
        return (cz * x - sz * y, cz * y + sz * x, cz * z + sz * w, cz * w - sz * z)

    # -- latents ------------------------------------------------------------------------------
    def latent_specs(self) -> tuple[Latent, ...]:
        return tuple(replace(LATENT_SPECS[n], bounds=self.bounds[n]) for n in LATENT_NAMES)

    def latents(self) -> dict[str, float]:
        o = self.obj
        return {"area_cm2": o.area_cm2, "density_g_cm3": o.density_g_cm3, "drag_water": o.drag_water,
                "release_s": float(self.release_s), "push_mps": float(self.push_mps),
                "log_volume_factor": float(self.log_volume_factor)}

    def release_step(self, release_s: float | None = None) -> int:
        """The release in physics steps of video time (frame f is step f * sim_hz / fps),
        rounded to the nearer step (for step counts; the timing itself is `frame_ticks`)."""
        return int(round((self.release_s if release_s is None else release_s) * self.sim_hz))

    def frame_ticks(self, release_s: float | None = None) -> tuple[int, float]:
        """(k, a): video frame 0 falls at physics step k - a of the run from the release (k a
        whole step, 0 <= a < 1), frame f at step k - a + f * sim_hz / fps. The run steps on
        its own grid from the release, so that a release between two steps of video time
        is no coarser than the time itself: a frame's state is interpolated between the two
        steps around it (the likelihood's and `Simulator.run`'s)."""
        x = -(self.release_s if release_s is None else release_s) * self.sim_hz
        k = math.ceil(x - 1e-9)
        a = k - x
        return int(k), (a if a > 1e-9 else 0.0)

    @property
    def volume_m3(self) -> float:
        """The object's volume (m^3): the bottom-up volume times exp(log_volume_factor)."""
        return self.obj.volume_m3 * math.exp(self.log_volume_factor)

    def with_values(self, values: dict[str, float]) -> "SplashScene":
        """A copy with latents (area_cm2, density_g_cm3, drag_water, release_s, push_mps,
        log_volume_factor) and the bottom-up volume set; each value checked against its bound, then
        the new scene validated as a whole."""
        obj, own = self.obj, {}
        for name, value in values.items():
            if name not in VALUE_BOUNDS:
                raise SceneError(f"unknown name {show(name)}; expected one of {', '.join(LATENT_NAMES)}, volume_cm3")
            v = VALUE_BOUNDS[name].check(value, name)
            if name in ("release_s", "push_mps", "log_volume_factor"):
                own[name] = v
            else:
                obj = replace(obj, **{name: v})
        new = replace(self, obj=obj, **own)
        new.validate()
        return new

    def check_simulation(self, n_frames: int, fps: float, names: tuple[str, str] = ("fps", "n_frames")) -> None:
        """SceneError unless `n_frames` frames at `fps` can be simulated in this scene (from a
        release before frame 0, its steps too): fps in [1, 1000], n_frames in [1, 100000], sim_hz a
        multiple of fps, at most MAX_STEPS physics steps (`names`: what to call fps and n_frames
        in a message)."""
        check_run(self.sim_hz, fps, n_frames, MAX_STEPS, max(0, -self.release_step()), names=names)

    # -- geometry -------------------------------------------------------------------------------
    @property
    def fps(self) -> float:
        return self.camera.fps if self.camera is not None else 30.0

    def max_dim_m(self) -> float:
        return min(self.tank.size_m[0], self.tank.size_m[1]) * 0.9

    def dims(self, area_cm2: float | None = None) -> tuple | None:
        o = self.obj
        return dimensions(o.kind, self.volume_m3, (o.area_cm2 if area_cm2 is None else area_cm2) * CM2,
                          self.max_dim_m())

    def geometry_key(self) -> tuple:
        return (self.tank, self.sim_hz, self.gravity_mps2)

    # -- validation & IO ----------------------------------------------------------------------------
    def validate(self) -> None:
        """SceneError naming the field (as the scene file writes it) unless every number lies
        in its bound (the constants at the top of this module) and the cross-field rules hold:
        the object fits the tank, the water is inside the tank, the release point is inside the
        tank and above the water (at most MAX_DROP_M), the priors are proper, the camera is a
        proper pinhole camera whose video sim_hz steps evenly in at most MAX_STEPS steps."""
        t, o = self.tank, self.obj
        if not isinstance(t, Tank):
            raise SceneError(f"tank: expected a tank, got {show(t)}")
        if not isinstance(o, SplashObject):
            raise SceneError(f"object: expected an object, got {show(o)}")
        if not isinstance(t.size_m, (tuple, list)) or len(t.size_m) != 3:
            raise SceneError(f"tank.size_m: expected three numbers (metres), got {show(t.size_m)}")
        for k, x in enumerate(t.size_m):
            TANK_SIZE_M.check(x, f"tank.size_m[{k}]")
        WALL_M.check(t.wall_m, "tank.wall_m")
        LIQUID_DENSITY_KG_M3.check(t.water_density_kg_m3, "tank.water_density_kg_m3")
        Bound(0.0, t.size_m[2], lo_open=True, hi_open=True).check(t.water_level_m, "tank.water_level_m")
        if not isinstance(o.name, str) or not o.name.strip():
            raise SceneError(f"object.name: expected a non-empty string, got {show(o.name)}")
        if o.material is not None and not isinstance(o.material, str):
            raise SceneError(f"object.material: expected a string, got {show(o.material)}")
        if o.kind not in KINDS:
            raise SceneError(f"object.kind: expected one of {', '.join(KINDS)}, got {show(o.kind)}")
        VOLUME_CM3.check(o.volume_cm3, "object.volume_cm3")
        AREA_CM2.check(o.area_cm2, "object.area_cm2")
        DENSITY_G_CM3.check(o.density_g_cm3, "object.density_g_cm3")
        DRAG_WATER.check(o.drag_water, "object.drag_water")
        if self.dims() is None:
            raise SceneError(f"object: no {o.kind} of {self.volume_m3 / CM3:g} cm^3 shows {o.area_cm2:g} cm^2 from below and "
                             f"fits the tank (each side between {MIN_DIM_M * 1000:g} mm and "
                             f"{self.max_dim_m() * 100:.1f} cm)")
        rel = self.release_m
        if not isinstance(rel, (tuple, list)) or len(rel) != 3 or not all(is_finite_number(x) for x in rel):
            raise SceneError(f"release_m: expected three numbers (metres), got {show(rel)}")
        x, y, z = rel
        hx, hy = t.size_m[0] / 2, t.size_m[1] / 2
        if not (-hx < x < hx and -hy < y < hy):
            raise SceneError(f"release_m: ({x:g}, {y:g}) is outside the tank's inner {2 * hx:g} x {2 * hy:g} m")
        if z <= t.water_level_m:
            raise SceneError(f"release_m: the object must be let go above the water (z > {t.water_level_m:g} m)")
        if z > t.water_level_m + MAX_DROP_M:
            raise SceneError(f"release_m: z = {z:g} m is more than {MAX_DROP_M:g} m above the water "
                             f"(at {t.water_level_m:g} m)")
        RELEASE_S.check(self.release_s, "release_s")
        PUSH_MPS.check(self.push_mps, "push_mps")
        LOG_VOLUME_FACTOR.check(self.log_volume_factor, "log_volume_factor")
        YAW_DEG.check(self.yaw_deg, "yaw_deg")
        VOLUME_CM3.check(self.volume_m3 / CM3, "object.volume_cm3 x exp(log_volume_factor)")
        SIM_HZ.check(self.sim_hz, "sim_hz")
        GRAVITY_MPS2.check(self.gravity_mps2, "gravity_mps2")
        check_priors(self.bounds)
        if self.camera is not None:
            if not isinstance(self.camera, Camera):
                raise SceneError(f"camera: expected a camera, got {show(self.camera)}")
            check_camera(self.camera)
            object.__setattr__(self, "sim_hz", physics_hz(self.sim_hz, self.camera.fps, SIM_HZ))  # whole steps a frame
            check_run(self.sim_hz, self.camera.fps, self.camera.n_frames, MAX_STEPS, max(0, -self.release_step()))

    def to_json(self) -> dict:
        d: dict[str, Any] = {"scenario": self.scenario, "version": SCENE_VERSION, "tank": self.tank.to_json(),
                             "object": self.obj.to_json(), "release_m": list(self.release_m),
                             "release_s": self.release_s, "push_mps": self.push_mps,
                             "log_volume_factor": self.log_volume_factor, "yaw_deg": self.yaw_deg,
                             "sim_hz": self.sim_hz,
                             "gravity_mps2": self.gravity_mps2,
                             "priors": {k: list(v) for k, v in self.bounds.items()}}
        if self.camera is not None:
            d["camera"] = self.camera.to_json()
        return d



SCENE_FIELDS = ("scenario", "version", "tank", "object", "release_m", "release_s", "push_mps", "log_volume_factor",
                "yaw_deg", "sim_hz", "gravity_mps2", "priors", "camera")
V1_FIELDS = ("scenario", "version", "tank", "object", "release_m", "start_step", "sim_hz", "gravity_mps2",
             "priors", "camera")
V1_START = Bound(0, 1000, integer=True)   # version 1's start_step: the physics step shown as frame 0
TANK_FIELDS = ("size_m", "wall_m", "water_level_m", "water_density_kg_m3")
OBJECT_FIELDS = ("name", "kind", "volume_cm3", "area_cm2", "density_g_cm3", "drag_water", "material")


def check_priors(bounds: Any, path: str = "priors") -> None:
    """SceneError naming the latent unless `bounds` holds proper bounds for each latent (both
    numbers, low below high, inside its limits)."""
    if not isinstance(bounds, dict):
        raise SceneError(f"{path}: expected bounds by latent name, got {show(bounds)}")
    for name in bounds:
        if name not in LATENT_SPECS:
            raise SceneError(f"{where_of(path, name)}: unknown latent; expected one of {', '.join(LATENT_NAMES)}")
    for name, lat in LATENT_SPECS.items():
        b = bounds.get(name)
        if (not isinstance(b, (tuple, list)) or len(b) != 2 or not all(is_finite_number(x) for x in b)
                or (lat.integer and not all(float(x).is_integer() for x in b))):
            what = "two whole numbers" if lat.integer else "two numbers"
            raise SceneError(f"{path}.{name}: expected [low, high], {what}, got {show(b)}")
        try:
            check_bounds(lat, *b)
        except ValueError as e:
            raise SceneError(f"{path}.{e}") from None


def _vector3(d: dict, key: str, path: str, bound: Bound = Bound()) -> tuple[float, float, float]:
    v = field_value(d, key, path)
    where = where_of(path, key)
    if not isinstance(v, list) or len(v) != 3 or not all(is_number(x) for x in v):
        raise SceneError(f"{where}: expected three numbers (metres), got {show(v)}")
    x, y, z = (bound.check(x, f"{where}[{k}]") for k, x in enumerate(v))
    return x, y, z


def scene_from_json(data: Any) -> SplashScene:
    """Parse and validate a splash scene file's JSON (SceneError naming the field and the bound)."""
    if not isinstance(data, dict):
        raise SceneError(f"expected a JSON object at the top level, got {show(data)}")
    scenario = field_value(data, "scenario", "")
    if scenario != "splash":
        raise SceneError(f"scenario: this is the splash scenario's parser, got {show(scenario)}")
    version = field_value(data, "version", "", SCENE_VERSION)
    if not is_number(version) or version not in (1, SCENE_VERSION):
        raise SceneError(f"version: this Galileo reads splash scene versions 1 and {SCENE_VERSION}, got {show(version)}")
    unknown_fields(data, V1_FIELDS if version == 1 else SCENE_FIELDS, "")
    td = field_value(data, "tank", "")
    if not isinstance(td, dict):
        raise SceneError(f"tank: expected an object, got {show(td)}")
    unknown_fields(td, TANK_FIELDS, "tank")
    size = _vector3(td, "size_m", "tank", TANK_SIZE_M)
    tank = Tank(size, number(td, "wall_m", "tank", 0.006, bound=WALL_M),
                number(td, "water_level_m", "tank", bound=Bound(0.0, size[2], lo_open=True, hi_open=True)),
                number(td, "water_density_kg_m3", "tank", WATER_DENSITY_KG_M3,
                       bound=LIQUID_DENSITY_KG_M3))
    od = field_value(data, "object", "")
    if not isinstance(od, dict):
        raise SceneError(f"object: expected an object, got {show(od)}")
    unknown_fields(od, OBJECT_FIELDS, "object")
    kind = field_value(od, "kind", "object")
    if not isinstance(kind, str) or kind not in KINDS:
        raise SceneError(f"object.kind: expected one of {', '.join(KINDS)}, got {show(kind)}")
    name = field_value(od, "name", "object", "object")
    if not isinstance(name, str) or not name.strip():
        raise SceneError(f"object.name: expected a non-empty string, got {show(name)}")
    material = field_value(od, "material", "object", None)
    if material is not None and not isinstance(material, str):
        raise SceneError(f"object.material: expected a string, got {show(material)}")
    obj = SplashObject(name, kind, number(od, "volume_cm3", "object", bound=VOLUME_CM3),
                       number(od, "area_cm2", "object", bound=AREA_CM2),
                       number(od, "density_g_cm3", "object", bound=DENSITY_G_CM3),
                       number(od, "drag_water", "object", bound=DRAG_WATER), material)
    pd = field_value(data, "priors", "", {})
    if not isinstance(pd, dict):
        raise SceneError(f"priors: expected an object, got {show(pd)}")
    pd = dict(pd)
    if version == 1:   # its start_step prior (physics steps before frame 0) is a release before frame 0
        if "start_step" in pd:
            lo, hi = pair(pd, "start_step", "priors", None, integer=True)
            hz = number(data, "sim_hz", "", 240, bound=SIM_HZ)
            pd["release_s"] = [-hi / hz, -lo / hz]
            del pd["start_step"]
    unknown_fields(pd, LATENT_NAMES, "priors")
    bounds = {}
    for k, lat in LATENT_SPECS.items():
        bounds[k] = pair(pd, k, "priors", list(lat.bounds), integer=lat.integer)
    check_priors(bounds)
    bounds = {k: (float(lo), float(hi)) for k, (lo, hi) in bounds.items()}
    cam = field_value(data, "camera", "", None)
    sim_hz = number(data, "sim_hz", "", 240, bound=SIM_HZ)
    if version == 1:
        release_s = -number(data, "start_step", "", 10, bound=V1_START) / sim_hz
        push, factor, yaw = 0.0, 0.0, 0.0
    else:
        release_s = number(data, "release_s", "", -10 / 240, bound=RELEASE_S)
        push = number(data, "push_mps", "", 0.0, bound=PUSH_MPS)
        factor = number(data, "log_volume_factor", "", 0.0, bound=LOG_VOLUME_FACTOR)
        yaw = number(data, "yaw_deg", "", 0.0, bound=YAW_DEG)
    scene = SplashScene(tank, obj, _vector3(data, "release_m", ""), release_s,
                        camera_from_json(cam) if cam is not None else None, sim_hz,
                        number(data, "gravity_mps2", "", 9.81, bound=GRAVITY_MPS2), bounds, push, factor, yaw)
    scene.validate()
    return scene


def default_camera(tank: Tank, fps: float = 30.0, n_frames: int = 60) -> Camera:
    """A side view of the tank from 0.9 m, level with the water line, slightly above it."""
    z = tank.water_level_m + 0.02
    return look_at_camera((0.0, -0.95, z + 0.04), (0.0, 0.0, z), focal_px=900.0, fps=fps, n_frames=n_frames)


def default_scene(kind: str = "box", volume_cm3: float = 27.0, density_g_cm3: float = 2.7,
                  drag_water: float = 0.8, area_cm2: float | None = None, release_s: float = -10 / 240,
                  camera: Camera | None = None, material: str | None = None, push_mps: float = 0.0) -> SplashScene:
    """A tank of water and one object let go 15 cm above the water, seen from the side."""
    tank = Tank()
    if area_cm2 is None:
        area_cm2 = equal_area(kind, volume_cm3 * CM3) / CM2
    obj = SplashObject("object", kind, volume_cm3, area_cm2, density_g_cm3, drag_water, material)
    scene = SplashScene(tank, obj, (0.0, 0.0, tank.water_level_m + RELEASE_ABOVE_WATER_M), release_s,
                        camera if camera is not None else default_camera(tank), push_mps=push_mps)
    scene.validate()
    return scene
