"""Scene & priors: the ramp world of Galileo (NIPS 2015, section 3) as data.

World frame (metres, z up): the ramp's foot is the origin, the ramp rises towards -x,
the ground is the plane z = 0 and x points from the ramp towards the target; y is the
horizontal axis across the ramp (the camera looks along +y).

The ramp object starts `start_units + offset_units` units up the ramp (measured along
the surface from the foot to the object's centre). One unit is `unit_m` (default 2 cm,
so the paper's "30 units up, offset in {0, ±1, ..., ±5}" is 60 cm ± 10 cm).
The target stands on the ground with its near face `distance_m` from the foot.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar, Iterable

import numpy as np

from ...camera import Camera, camera_from_json, check_camera, check_run, look_at_camera, physics_hz
from ...errors import SceneError
from ...fields import Bound, field_value, is_finite_number, is_number, number, pair, show, unknown_fields, where_of
from ...latents import Latent, check_bounds
from ...scenefile import SceneFile
from ...shapes import SHAPE_TYPES, Shape, shape_class

SCENE_VERSION = 2   # 2: the collision's restitution a latent by default (priors.infer_restitution absent
# means true); version 1 files are read as written (absent means false: the restitution fixed)
ROLES = ("ramp", "target")
TARGET_KINDS = ("cardboard", "foam")
# latent name -> (object index, attribute)
LATENTS = {"m1_kg": (0, "mass_kg"), "k1": (0, "friction"), "m2_kg": (1, "mass_kg"), "k2": (1, "friction")}

# -- what a ramp scene may hold: every bound in one place, each with its reason -------------------
# (checked where a file is parsed, where a scene is built in code, by `with_values`, so by
# `galileo simulate --set` and its quick form too; an error names the field and the bound)
MASS_KG = Bound(1e-6, 100.0)                # a tabletop ramp's objects: at least 1 mg (a 1 mm grain of plastic,
# below anything a camera tracks on a ramp; Bullet takes a mass under 2.2e-16 kg, its epsilon, for an immovable
# one and a principal inertia under it for none: a 1e-18 kg object never moves and a 1e-9 kg millimetre
# cylinder slides 18 mm off its path in a second, while from 1 mg every shape a scene may hold slides as at 1 kg
# to 0.3 um, its smallest inertia 500 times that epsilon), at most 100 kg (a heavier one would crush the ramp;
# 1e308 kg overflows Bullet's impulses into NaN)
FRICTION = Bound(0.0, 10.0)                 # Coulomb coefficients: rubber on concrete is about 1; 10 holds
# anything on any ramp under 60 degrees
RESTITUTION = Bound(0.0, 1.0)               # 0 (no bounce) to 1 (elastic): above 1 a bounce would make energy
ANGLE_DEG = Bound(0.0, 60.0, hi_open=True)  # steeper than 60 degrees an object falls off rather than slides
RAMP_SIZE_M = Bound(0.0, 10.0, lo_open=True)        # the ramp board's length and width: a tabletop ramp, at
# most 10 m (as `galileo scene` takes them, clicks.MAX_RAMP_M)
RAMP_THICKNESS_M = Bound(0.0, 1.0, lo_open=True)    # a board, not a wall: at most 1 m thick
OBJECT_SIZE_M = Bound(0.001, 2.0)           # each of an object's sizes: at least 1 mm (Bullet's collision margin
# around mesh shapes, shapes.BULLET_MESH_MARGIN_M: smaller, the margin is the object), at most 2 m (an object
# that slides down a tabletop ramp)
PRIOR_SIZE_M = Bound(0.005, 2.0)            # the prior's size range: as OBJECT_SIZE_M, from 5 mm so that a
# torus drawn from it (tube at least 0.4 x its diameter) keeps every size above 1 mm
DISTANCE_M = Bound(0.0, 2.0)                # the target's near face from the ramp's foot: on the ground, at most
# 2 m away (the dataset's are 0.08-0.14 m; the ground, physics.GROUND_SIZE_M, reaches 4 m from the foot, and a
# 2 m target 2 m away still stands on it)
UNIT_M = Bound(0.001, 1.0)                  # the offset unit (the paper's is 2 cm): 1 mm (finer than tracking
# resolves) to 1 m
START_UNITS = Bound(0.0, 1e6)               # the nominal start in units, >= 0; where it lands (on the ramp) is
# checked against the ramp's length
OFFSET_UNITS = Bound(-10_000, 10_000, integer=True)   # whole units (never rounded); |offset| <= 10000 keeps the
# arithmetic exact, and the start must still lie on the ramp (checked against its length)
SIM_HZ = Bound(60, 10_000)                  # Bullet steps per second: at least 60 (slower, a 1 m/s object moves
# a third of a 5 cm block a step: contacts are resolved too coarsely), at most 10 kHz (40x the cost of the 240
# every dataset uses)
GRAVITY_MPS2 = Bound(0.0, 100.0, lo_open=True)   # downwards, above 0 (without gravity nothing slides: the video
# holds no evidence of any latent, and k1's estimate from the slide, moves.k1_from_acceleration, divides by g),
# at most 100 m/s^2 (10 g; beyond any lab)
MAX_STEPS = 2_000_000                       # physics steps of one simulated video (camera.n_frames x sim_hz /
# camera.fps) at most: about a minute of Bullet on one core; inference repeats it thousands of times
STUDENT_T_DOF = Bound(0.0, 1000.0, lo_open=True)   # degrees of freedom of the Student-t observation model:
# above 0; above 1000 it is a Gaussian to 1e-3 (and the likelihood's lgamma(dof / 2) overflows at 1e308)
SIGMA_LIMITS_MPS = (1e-4, 10.0)             # the likelihood's sigma (RampScenario.noise.limits): 0.1 mm/s (a
# pixel's jitter is more) to 10 m/s (no ramp is that fast); the sigma latent is its log10

# where any prior's bounds must lie: the masses and frictions a scene may hold (above)
_MASS = dict(unit="kg", limits=(MASS_KG.lo, MASS_KG.hi), limits_open_low=MASS_KG.lo_open)
_FRICTION = dict(unit="1", limits=(FRICTION.lo, FRICTION.hi))
# the latents: the paper's priors (mass ~ U(0.001, 1) kg, friction ~ U(0, 1)) and proposals
LATENT_SPECS = {
    "m1_kg": Latent("m1_kg", bounds=(0.001, 1.0), doc="ramp object's mass", **_MASS),
    "k1": Latent("k1", bounds=(0.0, 1.0), doc="ramp object's friction coefficient (against ramp and ground)",
                 **_FRICTION),
    "m2_kg": Latent("m2_kg", bounds=(0.001, 1.0), doc="target's mass", **_MASS),
    "k2": Latent("k2", bounds=(0.0, 1.0), doc="target's friction coefficient (against the ground)", **_FRICTION),
}
# Model-mismatch latents (`Priors.infer_restitution`, on by default; `Priors.infer_sigma`, off),
# after the four above in this order when enabled:
# * e_collision: the restitution of the ramp object's collision with the target (see
#   `Scene.collision_restitution` for how Bullet's per-body restitutions are set); on by default
#   since scene version 2: with it fixed at 0, log(m1/m2)'s intervals covered the truth of
#   collisions that bounce in 83% of videos, with it a latent 94% (BENCHMARKS.md, issue 30);
# * log10_sigma_mps: the likelihood's sigma, log-uniform (uniform in log10), always last.
OPTIONAL_SPECS = {
    "e_collision": Latent("e_collision", "1", bounds=(0.0, 1.0), limits=(RESTITUTION.lo, RESTITUTION.hi),
                          doc="restitution of the ramp object's collision with the target"),
    # narrow 0.1: the posterior's SD in log10 sigma is about 0.43 / sqrt(2 n) for n tracked
    # velocities (0.03 for 120), and a sigma proposal is cheap (it reuses the physics)
    "log10_sigma_mps": Latent("log10_sigma_mps", "log10 m/s", bounds=(math.log10(0.005), math.log10(0.5)),
                              doc="log10 of the likelihood's sigma (SD of each tracked velocity component)",
                              limits=(math.log10(SIGMA_LIMITS_MPS[0]), math.log10(SIGMA_LIMITS_MPS[1])), narrow=0.1),
}
ALL_SPECS = {**LATENT_SPECS, **OPTIONAL_SPECS}
# the observation models of the likelihood (`Priors.observation`)
OBSERVATIONS = ("gaussian", "student_t")
DEFAULT_STUDENT_T_DOF = 4.0
DEFAULT_OBSERVATION = "student_t"   # measured best on coverage (BENCHMARKS.md, issue 12); the paper's: gaussian
# names `--set` accepts besides the latents (`log10_sigma_mps` is accepted and changes no physics)
SCENE_KNOBS = ("offset_units", "angle_deg", "e1", "e2", "e_collision", "log10_sigma_mps")


# -- priors --------------------------------------------------------------------

DEFAULT_BOUNDS = {n: lat.bounds for n, lat in LATENT_SPECS.items()}


@dataclass(frozen=True)
class Priors:
    """The paper's priors as data: uniform bounds you may change at run time.

    mass ~ U(0.001, 1) kg, friction ~ U(0, 1), shape type uniform over box / cylinder /
    torus, per-axis size uniform over `size_m`, offset uniform over the integers in
    `offset_units`.

    And the observation model: `observation` "student_t" (the default: per velocity
    component, `student_t_dof` degrees of freedom, default 4; it measured better on interval
    coverage than the paper's "gaussian", which `--moves paper` restores);
    `infer_sigma` adds the latent log10_sigma_mps (the likelihood's sigma, log-uniform
    over `bounds["log10_sigma_mps"]`, default 0.005..0.5 m/s; the fixed sigma is then
    unused); `infer_restitution` (on by default) adds e_collision (the collision's
    restitution, U(0, 1)) in a scene with a target; off, the collision's restitution is the
    scene's (the objects' own, 0, or `Scene.collision_restitution`), as in the paper. An
    enabled latent's bounds are always in `bounds`.
    """
    bounds: dict = field(default_factory=lambda: dict(DEFAULT_BOUNDS))
    offset_units: tuple[int, int] = (-5, 5)
    shape_types: tuple[str, ...] = SHAPE_TYPES
    size_m: tuple[float, float] = (0.01, 0.2)
    observation: str = DEFAULT_OBSERVATION
    student_t_dof: float = DEFAULT_STUDENT_T_DOF
    infer_sigma: bool = False
    infer_restitution: bool = True

    def __post_init__(self):
        if self.observation not in OBSERVATIONS:
            raise SceneError(f"priors.observation: expected one of {', '.join(OBSERVATIONS)}, got {self.observation!r}")
        dof = STUDENT_T_DOF.check(self.student_t_dof, "priors.student_t_dof")
        for flag in ("infer_sigma", "infer_restitution"):
            if not isinstance(getattr(self, flag), bool):
                raise SceneError(f"priors.{flag}: expected true or false, got {getattr(self, flag)!r}")
        object.__setattr__(self, "student_t_dof", float(dof))
        enabled = [n for n, on in (("e_collision", self.infer_restitution), ("log10_sigma_mps", self.infer_sigma))
                   if on and n not in self.bounds]
        if enabled:   # an enabled latent's default bounds, explicit
            object.__setattr__(self, "bounds", {**self.bounds, **{n: OPTIONAL_SPECS[n].bounds for n in enabled}})

    def check(self, path: str = "priors") -> None:
        """SceneError naming the field unless every bound is a latent's (low below high, both
        numbers, inside the latent's limits: `check_bounds`), the offset range whole numbers in
        OFFSET_UNITS, the size range in PRIOR_SIZE_M and the shape types known, each once."""
        if not isinstance(self.bounds, dict):
            raise SceneError(f"{path}: expected bounds by latent name, got {show(self.bounds)}")
        for name, b in self.bounds.items():
            if name not in ALL_SPECS:
                raise SceneError(f"{where_of(path, name)}: unknown latent; expected one of {', '.join(ALL_SPECS)}")
            if not isinstance(b, (tuple, list)) or len(b) != 2 or not all(is_finite_number(x) for x in b):
                raise SceneError(f"{path}.{name}: expected [low, high], two numbers, got {show(b)}")
            try:
                check_bounds(ALL_SPECS[name], *b)
            except ValueError as e:
                raise SceneError(f"{path}.{e}") from None
        for key, bound in (("offset_units", OFFSET_UNITS), ("size_m", PRIOR_SIZE_M)):
            v = getattr(self, key)
            if not isinstance(v, (tuple, list)) or len(v) != 2:
                raise SceneError(f"{path}.{key}: expected [low, high], got {show(v)}")
            lo, hi = (bound.check(x, f"{path}.{key}") for x in v)
            if lo > hi:
                raise SceneError(f"{path}.{key}: expected [low, high] with low <= high, got {show(list(v))}")
        types = self.shape_types
        if not isinstance(types, (tuple, list)) or not types or any(t not in SHAPE_TYPES for t in types):
            raise SceneError(f"{path}.shape_types: expected a non-empty list from {', '.join(SHAPE_TYPES)}, "
                             f"got {show(types)}")
        if len(set(types)) != len(types):
            raise SceneError(f"{path}.shape_types: each type at most once, got {show(list(types))}")

    def bound(self, name: str) -> tuple[float, float]:
        """The prior bounds of latent `name` (an optional latent's default if not set)."""
        b = self.bounds.get(name)
        return tuple(b) if b is not None else ALL_SPECS[name].bounds

    def log_prob(self, latents: dict[str, float]) -> float:
        """Log density of the continuous latents (uniform): a constant inside, -inf outside."""
        lp = 0.0
        for name, value in latents.items():
            lo, hi = self.bound(name)
            if not lo <= value <= hi:
                return -math.inf
            lp -= math.log(hi - lo)
        return lp

    def sample(self, rng: np.random.Generator, names: Iterable[str]) -> dict[str, float]:
        return {n: float(rng.uniform(*self.bound(n))) for n in names}

    def sample_offset(self, rng: np.random.Generator) -> int:
        return int(rng.integers(self.offset_units[0], self.offset_units[1] + 1))

    def sample_shape(self, rng: np.random.Generator) -> Shape:
        kind = self.shape_types[int(rng.integers(len(self.shape_types)))]
        lo, hi = self.size_m
        return shape_class(kind).from_uniform_sizes(*rng.uniform(lo, hi, 3))

    def with_bounds(self, **bounds: tuple[float, float]) -> "Priors":
        new = dict(self.bounds)
        for k, v in bounds.items():
            if k not in new and k not in OPTIONAL_SPECS:
                raise KeyError(k)
            new[k] = check_bounds(ALL_SPECS[k], *v)
        return replace(self, bounds=new)

    def to_json(self) -> dict:
        d = {**{k: list(v) for k, v in self.bounds.items()},
             "offset_units": list(self.offset_units), "shape_types": list(self.shape_types),
             "size_m": list(self.size_m)}
        # the observation model only where it is not the default (older files stay as they were)
        if self.observation != DEFAULT_OBSERVATION or self.student_t_dof != DEFAULT_STUDENT_T_DOF:
            d["observation"] = self.observation
            d["student_t_dof"] = self.student_t_dof
        if self.infer_sigma:
            d["infer_sigma"] = True
        if not self.infer_restitution:   # (on by default since scene version 2)
            d["infer_restitution"] = False
        return d


# -- scene parts ------------------------------------------------------------------

@dataclass(frozen=True)
class Ramp:
    angle_deg: float = 20.0
    length_m: float = 0.9
    width_m: float = 0.3
    thickness_m: float = 0.02

    @property
    def angle_rad(self) -> float:
        return math.radians(self.angle_deg)

    @property
    def downhill(self) -> np.ndarray:
        """Unit vector along the fall line, pointing down the slope (world frame)."""
        a = self.angle_rad
        return np.array([math.cos(a), 0.0, -math.sin(a)])

    @property
    def normal(self) -> np.ndarray:
        a = self.angle_rad
        return np.array([math.sin(a), 0.0, math.cos(a)])

    @property
    def orientation_xyzw(self) -> tuple[float, float, float, float]:
        """Rotation taking object axes to ramp axes: +angle about world y."""
        h = self.angle_rad / 2
        return (0.0, math.sin(h), 0.0, math.cos(h))


@dataclass(frozen=True)
class SceneObject:
    name: str
    role: str  # "ramp" | "target"
    shape: Shape
    mass_kg: float
    friction: float
    restitution: float = 0.0
    material: str | None = None
    offset_units: int = 0           # ramp object only
    kind: str | None = None         # target only: cardboard | foam
    distance_m: float = 0.1         # target only: foot of ramp -> near face of target

    def to_json(self) -> dict:
        d: dict[str, Any] = {"name": self.name, "role": self.role, "shape": self.shape.to_json(),
                             "mass_kg": self.mass_kg, "friction": self.friction,
                             "restitution": self.restitution}
        if self.material is not None:
            d["material"] = self.material
        if self.role == "ramp":
            d["offset_units"] = self.offset_units
        else:
            d["kind"] = self.kind
            d["distance_m"] = self.distance_m
        return d


@dataclass(frozen=True)
class Scene(SceneFile):
    scenario: ClassVar[str] = "ramp"
    ramp: Ramp
    objects: tuple[SceneObject, ...]
    camera: Camera | None = None
    unit_m: float = 0.02
    start_units: float = 30.0
    sim_hz: float = 240   # asked; with a camera, the multiple of its fps nearest it (camera.physics_hz)
    gravity_mps2: float = 9.81
    priors: Priors = field(default_factory=Priors)
    # The restitution of the ramp object's collision with the target (None: the objects' own,
    # e1 * e2). When set (or given as the latent e_collision) Bullet's per-body restitutions
    # become: ramp object 1, target e_collision, ramp and ground e1; so the collision's
    # combined restitution (Bullet multiplies the two bodies') is e_collision, the ramp
    # object's against the ramp and the ground stays e1 (the slide, phase A of the
    # likelihood, is unchanged), and the target's against the ground is e1 * e_collision
    # (0, as without it, when e1 = 0: the default and the dataset's).
    collision_restitution: float | None = None

    # -- access ---------------------------------------------------------------
    @property
    def ramp_object(self) -> SceneObject:
        return self.objects[0]

    @property
    def target(self) -> SceneObject | None:
        return self.objects[1] if len(self.objects) > 1 else None

    @property
    def latent_names(self) -> tuple[str, ...]:
        """m1_kg, k1 (m2_kg, k2 with a target), then the optional latents the priors enable:
        e_collision (with a target), log10_sigma_mps (always last)."""
        names = [n for n, (i, _) in LATENTS.items() if i < len(self.objects)]
        if self.priors.infer_restitution and self.target is not None:
            names.append("e_collision")
        if self.priors.infer_sigma:
            names.append("log10_sigma_mps")
        return tuple(names)

    def latent_specs(self) -> tuple[Latent, ...]:
        """The latents of this scene (the target's only with a target), with its prior bounds."""
        return tuple(replace(ALL_SPECS[n], bounds=self.priors.bound(n)) for n in self.latent_names)

    def latents(self) -> dict[str, float]:
        """The values this scene gives its physical latents (a rendered video's scene: the
        truth): the objects' masses and frictions, and e_collision where it is a latent (the
        scene's `collision_restitution`, else the pair's as Bullet combines the objects' own,
        e1 * e2)."""
        out = {n: float(getattr(self.objects[i], a)) for n, (i, a) in LATENTS.items() if i < len(self.objects)}
        if "e_collision" in self.latent_names:
            out["e_collision"] = self.collision_e()
        return out

    def collision_e(self) -> float:
        """The restitution of the ramp object's collision with the target: `collision_restitution`,
        else the pair's as Bullet combines the objects' own (e1 * e2)."""
        e = self.collision_restitution
        return float(e if e is not None else self.objects[0].restitution * self.objects[1].restitution)

    def with_values(self, values: dict[str, float]) -> "Scene":
        """A copy with latents (m1_kg, k1, m2_kg, k2, e_collision) and knobs (offset_units,
        angle_deg, e1, e2) set. log10_sigma_mps (the likelihood's noise) is accepted and
        changes nothing: it is no part of the physical scene. Each value is checked against its
        bound (SceneError naming it: `m1_kg: 1e+308 is outside (0, 100]`; an offset of 1.5 is
        refused, not rounded), then the new scene is validated as a whole."""
        objs = list(self.objects)
        ramp = self.ramp
        collision = self.collision_restitution

        def index(name: str, i: int) -> int:
            if i >= len(objs):
                raise SceneError(f"{name}: this scene has no target object")
            return i

        for name, value in values.items():
            if name in LATENTS:
                i, attr = LATENTS[name]
                v = (MASS_KG if attr == "mass_kg" else FRICTION).check(value, name)
                i = index(name, i)
                objs[i] = replace(objs[i], **{attr: v})
            elif name == "offset_units":
                objs[0] = replace(objs[0], offset_units=OFFSET_UNITS.check(value, name))
            elif name in ("e1", "e2"):
                i = index(name, int(name[1]) - 1)
                objs[i] = replace(objs[i], restitution=RESTITUTION.check(value, name))
            elif name == "angle_deg":
                ramp = replace(ramp, angle_deg=ANGLE_DEG.check(value, name))
            elif name == "e_collision":
                index(name, 1)
                collision = RESTITUTION.check(value, name)
            elif name == "log10_sigma_mps":
                lo, hi = OPTIONAL_SPECS[name].limits
                Bound(lo, hi).check(value, name)
            else:
                raise SceneError(f"unknown name {show(name)}; expected one of {', '.join([*LATENTS, *SCENE_KNOBS])}")
        new = replace(self, objects=tuple(objs), ramp=ramp, collision_restitution=collision)
        new.validate()
        return new

    def check_simulation(self, n_frames: int, fps: float, names: tuple[str, str] = ("fps", "n_frames")) -> None:
        """SceneError unless `n_frames` frames at `fps` can be simulated in this scene: fps in
        [1, 1000], n_frames in [1, 100000], sim_hz a multiple of fps, at most MAX_STEPS physics
        steps (`names`: what to call fps and n_frames in a message, e.g. a command's flags)."""
        check_run(self.sim_hz, fps, n_frames, MAX_STEPS, names=names)

    # -- geometry ---------------------------------------------------------------
    def start_distance_m(self, obj: SceneObject | None = None) -> float:
        obj = obj or self.ramp_object
        return (self.start_units + obj.offset_units) * self.unit_m

    def initial_pose(self, index: int) -> tuple[np.ndarray, tuple[float, float, float, float]]:
        """Centre position (world) and orientation (x, y, z, w) of object `index` at t = 0."""
        obj = self.objects[index]
        if obj.role == "ramp":
            s = self.start_distance_m(obj)
            pos = -s * self.ramp.downhill + (obj.shape.height_m / 2) * self.ramp.normal
            return pos, self.ramp.orientation_xyzw
        return np.array([obj.distance_m + obj.shape.size_m[0] / 2, 0.0, obj.shape.height_m / 2]), (0.0, 0.0, 0.0, 1.0)

    def geometry_key(self) -> tuple:
        """What a physics world must be rebuilt for (everything except latents, offset, restitution)."""
        return (self.ramp, self.sim_hz, self.gravity_mps2,
                tuple((o.role, o.shape, o.distance_m if o.role == "target" else None) for o in self.objects))

    # -- validation & IO --------------------------------------------------------------
    def validate(self) -> None:
        """SceneError naming the field (as the scene file writes it) unless every number lies
        in its bound (the constants at the top of this module) and the cross-field rules hold:
        the ramp object starts on the ramp, object names differ, the priors are proper
        (`Priors.check`), the camera is a proper pinhole camera (`camera.check_camera`) whose
        video sim_hz steps evenly in at most MAX_STEPS steps, a collision restitution has a
        target. Run by the parser, `default_scene`, `with_values` and `scene_for_inference`."""
        r = self.ramp
        if not isinstance(r, Ramp):
            raise SceneError(f"ramp: expected a Ramp, got {show(r)}")
        ANGLE_DEG.check(r.angle_deg, "ramp.angle_deg")
        RAMP_SIZE_M.check(r.length_m, "ramp.length_m")
        RAMP_SIZE_M.check(r.width_m, "ramp.width_m")
        RAMP_THICKNESS_M.check(r.thickness_m, "ramp.thickness_m")
        UNIT_M.check(self.unit_m, "unit_m")
        START_UNITS.check(self.start_units, "start_units")
        SIM_HZ.check(self.sim_hz, "sim_hz")
        GRAVITY_MPS2.check(self.gravity_mps2, "gravity_mps2")
        objs = self.objects
        if not isinstance(objs, (tuple, list)) or not 1 <= len(objs) <= 2:
            raise SceneError("objects: expected a list of one (ramp object) or two (ramp object, target) objects")
        seen: dict[str, int] = {}
        for i, obj in enumerate(objs):
            _check_object(obj, i)
            if obj.name in seen:
                raise SceneError(f"objects[{i}].name: {show(obj.name)} is also the name of objects[{seen[obj.name]}] "
                                 f"(names must differ: tracks and trajectories are keyed by them)")
            seen[obj.name] = i
        ramp_obj = self.ramp_object
        top = self.start_distance_m(ramp_obj) + ramp_obj.shape.size_m[0] / 2
        if top > r.length_m:
            raise SceneError(f"objects[0]: starts {top:.3f} m up the ramp, beyond its length_m {r.length_m}")
        if self.start_distance_m(ramp_obj) - ramp_obj.shape.size_m[0] / 2 < 0:
            raise SceneError("objects[0]: start position puts the object past the ramp's foot")
        if not isinstance(self.priors, Priors):
            raise SceneError(f"priors: expected priors, got {show(self.priors)}")
        self.priors.check()
        e = self.collision_restitution
        if e is not None:
            if self.target is None:
                raise SceneError("collision_restitution: this scene has no target object")
            RESTITUTION.check(e, "collision_restitution")
        if self.camera is not None:
            if not isinstance(self.camera, Camera):
                raise SceneError(f"camera: expected a camera, got {show(self.camera)}")
            check_camera(self.camera)
            object.__setattr__(self, "sim_hz", physics_hz(self.sim_hz, self.camera.fps, SIM_HZ))  # whole steps a frame
            check_run(self.sim_hz, self.camera.fps, self.camera.n_frames, MAX_STEPS)

    def to_json(self) -> dict:
        d: dict[str, Any] = {
            "scenario": self.scenario,
            "version": SCENE_VERSION,
            "ramp": {"angle_deg": self.ramp.angle_deg, "length_m": self.ramp.length_m,
                     "width_m": self.ramp.width_m, "thickness_m": self.ramp.thickness_m},
            "unit_m": self.unit_m, "start_units": self.start_units,
            "sim_hz": self.sim_hz, "gravity_mps2": self.gravity_mps2,
            "objects": [o.to_json() for o in self.objects],
            "priors": self.priors.to_json(),
        }
        if self.collision_restitution is not None:
            d["collision_restitution"] = self.collision_restitution
        if self.camera is not None:
            d["camera"] = self.camera.to_json()
        return d



# -- parsing with field-named errors ---------------------------------------------------

SCENE_FIELDS = ("scenario", "version", "ramp", "unit_m", "start_units", "sim_hz", "gravity_mps2", "objects",
                "priors", "collision_restitution", "camera")
RAMP_FIELDS = ("angle_deg", "length_m", "width_m", "thickness_m")
SHAPE_FIELDS = ("type", "size_m")
OBJECT_FIELDS = ("name", "role", "shape", "mass_kg", "friction", "restitution", "material")
RAMP_OBJECT_FIELDS = (*OBJECT_FIELDS, "offset_units")
TARGET_FIELDS = (*OBJECT_FIELDS, "kind", "distance_m")
PRIOR_FIELDS = (*LATENT_SPECS, *OPTIONAL_SPECS, "offset_units", "shape_types", "size_m", "observation",
                "student_t_dof", "infer_sigma", "infer_restitution")


def _check_shape(shape: Any, path: str) -> None:
    if not isinstance(shape, Shape):
        raise SceneError(f"{path}: expected a shape, got {show(shape)}")
    if not shape.name:   # an unknown type (a plain Shape)
        raise SceneError(f"{path}.type: expected one of {', '.join(SHAPE_TYPES)}, got {show(shape.type)}")
    for k, x in enumerate(shape.size_m):
        OBJECT_SIZE_M.check(x, f"{path}.size_m[{k}]")
    problem = shape.problem()
    if problem:
        raise SceneError(f"{path}: {problem}")


def _check_object(obj: Any, i: int) -> None:
    """SceneError naming the field unless object `i` is a proper ramp object (i = 0) or target."""
    path = f"objects[{i}]"
    if not isinstance(obj, SceneObject):
        raise SceneError(f"{path}: expected a scene object, got {show(obj)}")
    want = ROLES[min(i, 1)]
    if obj.role != want:
        raise SceneError(f"{path}.role: object {i} must be the {want} object, got {show(obj.role)}")
    if not isinstance(obj.name, str) or not obj.name.strip():
        raise SceneError(f"{path}.name: expected a non-empty string, got {show(obj.name)}")
    if obj.material is not None and not isinstance(obj.material, str):
        raise SceneError(f"{path}.material: expected a string, got {show(obj.material)}")
    _check_shape(obj.shape, f"{path}.shape")
    MASS_KG.check(obj.mass_kg, f"{path}.mass_kg")
    FRICTION.check(obj.friction, f"{path}.friction")
    RESTITUTION.check(obj.restitution, f"{path}.restitution")
    if want == "ramp":
        OFFSET_UNITS.check(obj.offset_units, f"{path}.offset_units")
    else:
        if obj.kind not in TARGET_KINDS:
            raise SceneError(f"{path}.kind: expected one of {', '.join(TARGET_KINDS)}, got {show(obj.kind)}")
        DISTANCE_M.check(obj.distance_m, f"{path}.distance_m")


def _shape(d: Any, path: str) -> Shape:
    if not isinstance(d, dict):
        raise SceneError(f"{path}: expected an object with type and size_m, got {show(d)}")
    unknown_fields(d, SHAPE_FIELDS, path)
    t = field_value(d, "type", path)
    if not isinstance(t, str) or t not in SHAPE_TYPES:
        raise SceneError(f"{path}.type: expected one of {', '.join(SHAPE_TYPES)}, got {show(t)}")
    size = field_value(d, "size_m", path)
    if not isinstance(size, list) or len(size) != 3:
        raise SceneError(f"{path}.size_m: expected three numbers (metres), got {show(size)}")
    sizes = tuple(OBJECT_SIZE_M.check(x, f"{path}.size_m[{k}]") for k, x in enumerate(size))
    shape = Shape(t, sizes)
    _check_shape(shape, path)
    return shape


def _object(d: Any, i: int) -> SceneObject:
    path = f"objects[{i}]"
    if not isinstance(d, dict):
        raise SceneError(f"{path}: expected an object, got {show(d)}")
    want = ROLES[min(i, 1)]
    role = field_value(d, "role", path, want)
    if role != want:
        raise SceneError(f"{path}.role: object {i} must be the {want} object, got {show(role)}")
    unknown_fields(d, RAMP_OBJECT_FIELDS if want == "ramp" else TARGET_FIELDS, path)
    name = field_value(d, "name", path, "ramp_object" if i == 0 else "target")
    if not isinstance(name, str) or not name.strip():
        raise SceneError(f"{path}.name: expected a non-empty string, got {show(name)}")
    material = field_value(d, "material", path, None)
    if material is not None and not isinstance(material, str):
        raise SceneError(f"{path}.material: expected a string, got {show(material)}")
    common = dict(
        name=name, role=role, shape=_shape(field_value(d, "shape", path), f"{path}.shape"),
        mass_kg=number(d, "mass_kg", path, bound=MASS_KG),
        friction=number(d, "friction", path, bound=FRICTION),
        restitution=number(d, "restitution", path, 0.0, bound=RESTITUTION),
        material=material)
    if role == "ramp":
        return SceneObject(**common, offset_units=number(d, "offset_units", path, 0, bound=OFFSET_UNITS))
    kind = field_value(d, "kind", path, "cardboard")
    if not isinstance(kind, str) or kind not in TARGET_KINDS:
        raise SceneError(f"{path}.kind: expected one of {', '.join(TARGET_KINDS)}, got {show(kind)}")
    return SceneObject(**common, kind=kind, distance_m=number(d, "distance_m", path, bound=DISTANCE_M))


def _priors(pd: Any, version: int = SCENE_VERSION) -> Priors:
    """A scene file's priors; `version` 1's infer_restitution is false unless it says so
    (version 2's true)."""
    if not isinstance(pd, dict):
        raise SceneError(f"priors: expected an object, got {show(pd)}")
    unknown_fields(pd, PRIOR_FIELDS, "priors")
    base = Priors()
    bounds = {}
    for k, spec in ALL_SPECS.items():   # the four latents' bounds (defaults if not given), the optional ones' if given
        if k in DEFAULT_BOUNDS or k in pd:
            lo, hi = pair(pd, k, "priors", list(spec.bounds))
            try:
                bounds[k] = check_bounds(spec, lo, hi)
            except ValueError as e:
                raise SceneError(f"priors.{e}") from None
    observation = field_value(pd, "observation", "priors", base.observation)
    if not isinstance(observation, str) or observation not in OBSERVATIONS:
        raise SceneError(f"priors.observation: expected one of {', '.join(OBSERVATIONS)}, got {show(observation)}")
    dof = number(pd, "student_t_dof", "priors", base.student_t_dof, bound=STUDENT_T_DOF)
    flags = {}
    defaults = {"infer_sigma": False, "infer_restitution": version >= 2}
    for flag in ("infer_sigma", "infer_restitution"):
        flags[flag] = field_value(pd, flag, "priors", defaults[flag])
        if not isinstance(flags[flag], bool):
            raise SceneError(f"priors.{flag}: expected true or false, got {show(flags[flag])}")
    off = pair(pd, "offset_units", "priors", list(base.offset_units), integer=True)
    for x in off:
        OFFSET_UNITS.check(x, "priors.offset_units")
    size = pair(pd, "size_m", "priors", list(base.size_m))
    for x in size:
        PRIOR_SIZE_M.check(x, "priors.size_m")
    types = field_value(pd, "shape_types", "priors", list(base.shape_types))
    if not isinstance(types, list) or not types or any(not isinstance(t, str) or t not in SHAPE_TYPES for t in types):
        raise SceneError(f"priors.shape_types: expected a non-empty list from {', '.join(SHAPE_TYPES)}, "
                         f"got {show(types)}")
    priors = Priors(bounds=bounds, offset_units=off, shape_types=tuple(types), size_m=size,
                    observation=observation, student_t_dof=dof, **flags)
    priors.check()
    return priors


def scene_from_json(data: Any) -> Scene:
    """Parse and validate a ramp scene file's JSON (SceneError naming the field and the bound)."""
    if not isinstance(data, dict):
        raise SceneError(f"expected a JSON object at the top level, got {show(data)}")
    scenario = field_value(data, "scenario", "", "ramp")
    if scenario != "ramp":
        raise SceneError(f"scenario: this is the ramp scenario's parser, got {show(scenario)}")
    try:   # before the version: another scenario's file that lost its "scenario" is named as such
        unknown_fields(data, SCENE_FIELDS, "")
    except SceneError as e:
        if "scenario" not in data:   # e.g. a splash scene that lost its "scenario"
            raise SceneError(f'{e} (a file without "scenario" is read as a ramp scene)') from None
        raise
    version = field_value(data, "version", "", SCENE_VERSION)
    if not is_number(version) or version not in (1, SCENE_VERSION):
        raise SceneError(f"version: this Galileo reads ramp scene versions 1 and {SCENE_VERSION}, got {show(version)}")
    rd = field_value(data, "ramp", "")
    if not isinstance(rd, dict):
        raise SceneError(f"ramp: expected an object, got {show(rd)}")
    unknown_fields(rd, RAMP_FIELDS, "ramp")
    ramp = Ramp(angle_deg=number(rd, "angle_deg", "ramp", bound=ANGLE_DEG),
                length_m=number(rd, "length_m", "ramp", 0.9, bound=RAMP_SIZE_M),
                width_m=number(rd, "width_m", "ramp", 0.3, bound=RAMP_SIZE_M),
                thickness_m=number(rd, "thickness_m", "ramp", 0.02, bound=RAMP_THICKNESS_M))
    objs = field_value(data, "objects", "")
    if not isinstance(objs, list) or not 1 <= len(objs) <= 2:
        raise SceneError("objects: expected a list of one (ramp object) or two (ramp object, target) objects")
    objects = tuple(_object(o, i) for i, o in enumerate(objs))
    priors = _priors(field_value(data, "priors", "", {}), version)
    cam = field_value(data, "camera", "", None)
    collision = field_value(data, "collision_restitution", "", None)
    if collision is not None:
        collision = number(data, "collision_restitution", "", bound=RESTITUTION)
    scene = Scene(
        ramp=ramp, objects=objects, camera=camera_from_json(cam) if cam is not None else None,
        unit_m=number(data, "unit_m", "", 0.02, bound=UNIT_M),
        start_units=number(data, "start_units", "", 30.0, bound=START_UNITS),
        sim_hz=number(data, "sim_hz", "", 240, bound=SIM_HZ),
        gravity_mps2=number(data, "gravity_mps2", "", 9.81, bound=GRAVITY_MPS2),
        priors=priors, collision_restitution=collision)
    scene.validate()
    return scene


def default_camera(fps: float = 30.0, n_frames: int = 90) -> Camera:
    """The dataset's camera: at the side of the ramp, 1.2 m away, slightly above."""
    return look_at_camera((-0.2, -1.2, 0.3), (-0.2, 0.0, 0.16), fps=fps, n_frames=n_frames)



# -- the default scene ------------------------------------------------------------------

TARGET_DEFAULTS = {
    # kind: (shape, mass_kg, friction)
    "cardboard": (Shape("box", (0.10, 0.08, 0.07)), 0.12, 0.35),
    "foam": (Shape("box", (0.08, 0.08, 0.06)), 0.03, 0.55),
}


def default_scene(angle_deg: float = 20.0, *, mass_kg: float = 0.5, friction: float = 0.2,
                  target: str | None = "cardboard", shape: Shape | None = None,
                  offset_units: int = 0, distance_m: float = 0.1, camera: Camera | None = None) -> Scene:
    """The dataset's standard geometry with the given ramp object and target (or none)."""
    objs = [SceneObject("ramp_object", "ramp", shape or Shape("box", (0.06, 0.05, 0.04)),
                        mass_kg, friction, offset_units=offset_units)]
    if target not in (None, "none"):
        if target not in TARGET_DEFAULTS:
            raise SceneError(f"target: expected none, {', '.join(TARGET_DEFAULTS)}; got {target!r}")
        tshape, tm, tk = TARGET_DEFAULTS[target]
        objs.append(SceneObject("target", "target", tshape, tm, tk, material=target, kind=target,
                                distance_m=distance_m))
    scene = Scene(Ramp(angle_deg=angle_deg), tuple(objs), camera=camera)
    scene.validate()
    return scene
