"""Scene & priors of the fall scenario (Physics 101, section 2): a rigid object released by hand
above a flat surface (a table, foam, carpet or cloth); it falls, hits, bounces, tumbles, slides
and comes to rest. Filmed from above one end of the surface.

World frame (metres, z up): the surface is the plane z = 0; the origin is the centre of the
surface's rectangle (`surface_size_m`: its length along x, away from the camera's end, and its
width along y), the rectangle a user clicks to calibrate (`clicks.py`). Observations are the
object's silhouette centroid in pixels; the likelihood compares it with the simulated centre
projected through the scene's camera (`likelihood.py`).

What belongs to what (the names say it: a problem of several videos shares a latent by name,
`galileo.joint`):

    the object `object` on the surface `surface` (every video of that pair):
        the coefficient of restitution  e_<object>_<surface>   (the measured ratio: e^2 = h_after / h_before
                                                                for a flat landing)
        the coefficient of friction     mu_<object>_<surface>  (Coulomb, sliding)
    the video: the release state at `release_frame`: the centre x0_m, y0_m, z0_m (z0: its height
        above the surface); the orientation roll0_rad, pitch0_rad, yaw0_rad (Bullet's Euler
        angles, about world x, y, z); the velocity vx0_mps, vy0_mps, vz0_mps and the spin
        wx0_radps, wy0_radps, wz0_radps (world frame); where the tracker's centroid sits from the
        projected centre, ox_px and oy_px (constant); the tracking noise log10_sigma_px and its
        frame-to-frame correlation rho.

Mass does not change a rigid object's fall, bounce or slide on a fixed surface (gravity,
contact impulses and friction all scale with it): `mass_kg` is a fixed number of the scene
that Bullet needs, never a latent, and `result.json` names it as not identified. The release
*time* is the tracker's release frame, not a latent: a sub-frame shift of it is absorbed
exactly by the release state (the motion after release is free fall).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np

from ...camera import Camera, camera_from_json, look_at_camera, physics_hz
from ...errors import SceneError
from ...fields import Bound, field_value, number, show, unknown_fields, where_of
from ...latents import Latent, check_bounds
from ...scenefile import SceneFile, bottom_up_of, check_camera_of, priors_of
from ...shapes import Shape

SCENE_VERSION = 1
ID = re.compile(r"^[a-z][a-z0-9]{0,23}$")   # an object's or surface's name (it goes into latent names)
SURFACE_KINDS = ("table", "foam", "carpet", "cloth")

# -- what a fall scene may hold: every bound in one place, each with its reason -------------------
MASS = Bound(0.0, 50.0, lo_open=True)       # kg: Bullet needs one; it changes nothing seen
RESTITUTION = Bound(0.0, 1.0)               # the measured bounce ratio: 0 (dead) to 1 (elastic)
FRICTION = Bound(0.0, 3.0)                  # Coulomb's mu: ice's 0.02 to rubber on rubber's 1-2
POSITION = Bound(-20.0, 20.0)               # m: where the release is, from the surface's centre
HEIGHT = Bound(0.0, 5.0)                    # m: the release centre's height above the surface
ANGLE = Bound(-4.0, 4.0)                    # rad: Euler angles (a prior may reach just past pi)
SPEED = Bound(-20.0, 20.0)                  # m/s: a hand releases at a few m/s at most
SPIN = Bound(-200.0, 200.0)                 # rad/s: a flicked object spins at tens of rad/s
SURFACE_SIZE = Bound(0.0, 20.0, lo_open=True)
SIGMA_LOG10 = Bound(-3.0, 3.0)              # log10 px
RHO = Bound(0.0, 0.999)
SIM_HZ = Bound(60.0, 10000.0)               # physics steps a second (a multiple of the video's fps)
GRAVITY = Bound(0.0, 100.0, lo_open=True)
FPS = Bound(1.0, 1000.0)
N_FRAMES = Bound(2, 100_000, integer=True)

# default priors (U(low, high)); a scene's "priors" narrow or widen them
PRIORS = {"e": (0.02, 0.95), "mu": (0.02, 1.5), "ox_px": (-15.0, 15.0), "oy_px": (-15.0, 15.0),
          "log10_sigma_px": (-0.5, 1.5), "rho": (0.0, 0.99)}
# the release state's priors: the scene's (prepare(): the tracked) value +- these
# (a hand lets go of an object roughly level, with little spin: tilts up to 0.5 rad (29 degrees),
# any heading, spins up to 4 rad/s, drifts up to 0.3 m/s)
RELEASE_PRIOR = {"x0_m": 0.05, "y0_m": 0.05, "z0_m": 0.05, "roll0_rad": 0.5, "pitch0_rad": 0.5,
                 "yaw0_rad": math.pi / 2, "vx0_mps": 0.3, "vy0_mps": 0.3, "vz0_mps": 0.5, "wx0_radps": 4.0,
                 "wy0_radps": 4.0, "wz0_radps": 4.0}
RELEASE_LATENTS = tuple(RELEASE_PRIOR)
OFFSET_LATENTS = ("ox_px", "oy_px")
NOISE_LATENTS = OFFSET_LATENTS + ("log10_sigma_px", "rho")
# a scene's nominal observation model: no offset, 1 px of white noise
NOISE_VALUES = {"ox_px": 0.0, "oy_px": 0.0, "log10_sigma_px": 0.0, "rho": 0.0}


def pair_latents(obj: str, surface: str) -> dict[str, str]:
    """{kind: latent name} of an object-surface pair's latents."""
    return {"e": f"e_{obj}_{surface}", "mu": f"mu_{obj}_{surface}"}


def object_mass_latent(obj: str) -> str:
    """The name a mass would have (it is never a latent here: `not_identified` names it)."""
    return f"m_{obj}_kg"


@dataclass(frozen=True)
class FallScene(SceneFile):
    """One video of an object dropped onto a surface. Values are the latents' values (a rendered
    video's truth; elsewhere where `galileo simulate` starts); `priors` holds U(low, high) per
    kind ("e", "mu", the noise latents) or per release latent."""
    scenario: ClassVar[str] = "fall"
    object: str = "block"
    surface: str = "table"
    surface_kind: str = "table"
    surface_size_m: tuple[float, float] = (1.22, 0.61)
    shape: Shape = field(default_factory=lambda: Shape("box", (0.09, 0.045, 0.045)))
    mass_kg: float = 0.11
    restitution: float = 0.4
    friction: float = 0.4
    x0_m: float = 0.0
    y0_m: float = 0.0
    z0_m: float = 0.30
    roll0_rad: float = 0.0
    pitch0_rad: float = 0.0
    yaw0_rad: float = 0.0
    vx0_mps: float = 0.0
    vy0_mps: float = 0.0
    vz0_mps: float = 0.0
    wx0_radps: float = 0.0
    wy0_radps: float = 0.0
    wz0_radps: float = 0.0
    release_frame: int = 0
    fps: float = 30.0
    n_frames: int = 36
    sim_hz: float = 240.0
    gravity_mps2: float = 9.81
    priors: dict = field(default_factory=dict)
    camera: Camera | None = None
    # what the track says before any physics (prepare()): landing frame and place, the first
    # bounce's apex, the resting place; chains start from it
    bottom_up: dict = field(default_factory=dict, compare=False)

    # -- latents ---------------------------------------------------------------------------
    def names(self) -> dict[str, str]:
        """{latent name: scene attribute} for this video's latents, in order (noise latents apart)."""
        pl = pair_latents(self.object, self.surface)
        return {pl["e"]: "restitution", pl["mu"]: "friction", **{n: n for n in RELEASE_LATENTS}}

    def latents(self) -> dict[str, float]:
        return {name: float(getattr(self, attr)) for name, attr in self.names().items()}

    def latent_specs(self) -> tuple[Latent, ...]:
        pl = pair_latents(self.object, self.surface)
        out = [_with_bounds(replace(LATENTS["e"], name=pl["e"]), self.prior("e", LATENTS["e"])),
               _with_bounds(replace(LATENTS["mu"], name=pl["mu"]), self.prior("mu", LATENTS["mu"]))]
        for name in RELEASE_LATENTS:
            base = _release_latent(name, self)
            out.append(_with_bounds(base, self.prior(name, base)))
        for name in NOISE_LATENTS:
            out.append(_with_bounds(LATENTS[name], self.prior(name, LATENTS[name])))
        return tuple(out)

    def prior(self, key: str, base: Latent) -> tuple[float, float]:
        lo, hi = self.priors.get(key, base.bounds)
        return float(lo), float(hi)

    def with_values(self, values: dict[str, float]) -> FallScene:
        names = self.names()
        extra = {"release_frame": "release_frame", "restitution": "restitution", "friction": "friction",
                 "mass_kg": "mass_kg"}
        known = {**extra, **names}
        unknown = sorted(set(values) - set(known) - set(NOISE_LATENTS))
        if unknown:
            raise SceneError(f"unknown value(s) {', '.join(unknown)}; this fall scene takes "
                             f"{', '.join(list(names) + list(NOISE_LATENTS))}")
        changes = {known[k]: (int(round(v)) if known[k] == "release_frame" else float(v))
                   for k, v in values.items() if k in known}
        scene = replace(self, **changes)
        scene.validate()
        return scene

    # -- checks and JSON -----------------------------------------------------------------------
    def validate(self) -> None:
        for what, name in (("object", self.object), ("surface", self.surface)):
            if not isinstance(name, str) or not ID.match(name):
                raise SceneError(f"{what}: {show(name)} is no name: 1-24 lowercase letters and digits, "
                                 f"starting with a letter (it names latents, e.g. e_{{object}}_{{surface}})")
        if self.surface_kind not in SURFACE_KINDS:
            raise SceneError(f"surface_kind: {show(self.surface_kind)} is not one of {', '.join(SURFACE_KINDS)}")
        problem = self.shape.problem()
        if problem:
            raise SceneError(f"shape: {problem}")
        for where, v, b in (("mass_kg", self.mass_kg, MASS), ("restitution", self.restitution, RESTITUTION),
                            ("friction", self.friction, FRICTION), ("x0_m", self.x0_m, POSITION),
                            ("y0_m", self.y0_m, POSITION), ("z0_m", self.z0_m, HEIGHT),
                            ("roll0_rad", self.roll0_rad, ANGLE), ("pitch0_rad", self.pitch0_rad, ANGLE),
                            ("yaw0_rad", self.yaw0_rad, ANGLE), ("vx0_mps", self.vx0_mps, SPEED),
                            ("vy0_mps", self.vy0_mps, SPEED), ("vz0_mps", self.vz0_mps, SPEED),
                            ("wx0_radps", self.wx0_radps, SPIN), ("wy0_radps", self.wy0_radps, SPIN),
                            ("wz0_radps", self.wz0_radps, SPIN), ("fps", self.fps, FPS),
                            ("sim_hz", self.sim_hz, SIM_HZ), ("gravity_mps2", self.gravity_mps2, GRAVITY)):
            b.check(v, where)
        for i, v in enumerate(self.surface_size_m):
            SURFACE_SIZE.check(v, where_of("surface_size_m", i))
        N_FRAMES.check(self.n_frames, "n_frames")
        if not 0 <= self.release_frame < self.n_frames - 1:
            raise SceneError(f"release_frame: {self.release_frame} must be in [0, n_frames - 1) = "
                             f"[0, {self.n_frames - 1})")
        if abs(physics_hz(self.sim_hz, self.fps) - self.sim_hz) > 1e-9:
            raise SceneError(f"sim_hz ({self.sim_hz:g}) must be a multiple of fps ({self.fps:g})")
        check_camera_of(self.camera, self.fps, self.n_frames)
        self.latent_specs()   # the priors hold together

    def to_json(self) -> dict:
        d = {"scenario": self.scenario, "version": SCENE_VERSION, "object": self.object, "surface": self.surface,
             "surface_kind": self.surface_kind, "surface_size_m": list(self.surface_size_m),
             "shape": self.shape.to_json(), "mass_kg": self.mass_kg,
             "values": {k: getattr(self, k) for k in VALUE_FIELDS},
             "release_frame": self.release_frame, "fps": self.fps, "n_frames": self.n_frames, "sim_hz": self.sim_hz,
             "gravity_mps2": self.gravity_mps2, "priors": {k: list(v) for k, v in self.priors.items()}}
        if self.camera is not None:
            d["camera"] = self.camera.to_json()
        if self.bottom_up:
            d["bottom_up"] = dict(self.bottom_up)
        return d


FIELDS = ("scenario", "version", "object", "surface", "surface_kind", "surface_size_m", "shape", "mass_kg", "values",
          "release_frame", "fps", "n_frames", "sim_hz", "gravity_mps2", "priors", "camera", "bottom_up")
VALUE_FIELDS = ("restitution", "friction") + RELEASE_LATENTS

LATENTS = {
    "e": Latent("e", "1", PRIORS["e"], "the coefficient of restitution (the measured ratio: e^2 = bounce height "
                "over drop height, landing flat)", limits=(RESTITUTION.lo, RESTITUTION.hi), narrow=0.01, broad=0.1),
    "mu": Latent("mu", "1", PRIORS["mu"], "the coefficient of friction (Coulomb, sliding)",
                 limits=(FRICTION.lo, FRICTION.hi), narrow=0.02, broad=0.2),
    "ox_px": Latent("ox_px", "px", PRIORS["ox_px"], "where the tracker puts the centroid across the image, from "
                    "the projected centre (constant)", limits=(-1e3, 1e3), narrow=0.2, broad=3.0),
    "oy_px": Latent("oy_px", "px", PRIORS["oy_px"], "where the tracker puts the centroid down the image, from the "
                    "projected centre (constant)", limits=(-1e3, 1e3), narrow=0.2, broad=3.0),
    "log10_sigma_px": Latent("log10_sigma_px", "log10 px", PRIORS["log10_sigma_px"],
                             "the tracked centroid's noise (log10 of its SD in pixels, each image axis)",
                             limits=(SIGMA_LOG10.lo, SIGMA_LOG10.hi), observation=True, narrow=0.02, broad=0.3),
    "rho": Latent("rho", "1", PRIORS["rho"], "the noise's correlation from one frame to the next (AR(1))",
                  limits=(RHO.lo, RHO.hi), observation=True, narrow=0.05, broad=0.3),
}

_RELEASE_DOC = {"x0_m": ("m", "the centre at release along the surface's length", POSITION),
                "y0_m": ("m", "the centre at release across the surface", POSITION),
                "z0_m": ("m", "the centre's height above the surface at release", HEIGHT),
                "roll0_rad": ("rad", "the orientation at release: roll (about world x)", ANGLE),
                "pitch0_rad": ("rad", "the orientation at release: pitch (about world y)", ANGLE),
                "yaw0_rad": ("rad", "the orientation at release: yaw (about world z)", ANGLE),
                "vx0_mps": ("m/s", "the velocity at release along the surface's length", SPEED),
                "vy0_mps": ("m/s", "the velocity at release across the surface", SPEED),
                "vz0_mps": ("m/s", "the velocity at release, up", SPEED),
                "wx0_radps": ("rad/s", "the spin at release about world x", SPIN),
                "wy0_radps": ("rad/s", "the spin at release about world y", SPIN),
                "wz0_radps": ("rad/s", "the spin at release about world z", SPIN)}


def _release_latent(name: str, scene: FallScene) -> Latent:
    """A release latent, its default prior around the scene's value (prepare() centres it on
    the tracked release)."""
    v = float(getattr(scene, name))
    w = RELEASE_PRIOR[name]
    unit, doc, b = _RELEASE_DOC[name]
    lo, hi = max(b.lo, v - w), min(b.hi, v + w)
    return Latent(name, unit, (lo, hi), doc, limits=(b.lo, b.hi), narrow=w / 50, broad=w / 5)


def _with_bounds(lat: Latent, bounds: tuple[float, float]) -> Latent:
    try:
        lo, hi = check_bounds(lat, *bounds)
    except ValueError as err:
        raise SceneError(f"priors.{err}") from None
    return replace(lat, bounds=(lo, hi))


def default_camera(surface_size_m=(1.22, 0.61), fps: float = 30.0, n_frames: int = 36, width_px: int = 640,
                   height_px: int = 360) -> Camera:
    """A camera above the near end of the surface looking down along it (as the Physics 101
    clips are filmed): 0.45 m behind the near edge, 0.75 m up, looking at a point a quarter of
    the way in, a 62 degree horizontal field of view."""
    length = float(surface_size_m[0])
    eye = (-length / 2 - 0.45, 0.0, 0.75)
    target = (-length / 4 + 0.1, 0.0, 0.0)
    focal = width_px / (2 * math.tan(math.radians(62.0) / 2))
    return look_at_camera(eye, target, focal_px=focal, width_px=width_px, height_px=height_px, fps=fps,
                          n_frames=n_frames)


def default_scene() -> FallScene:
    s = FallScene(x0_m=-0.15, z0_m=0.30, roll0_rad=0.15, pitch0_rad=-0.1, vx0_mps=0.1, wy0_radps=2.0,
                  release_frame=3)
    return replace(s, camera=default_camera(s.surface_size_m, s.fps, s.n_frames))


def _pair_of_numbers(data: dict, key: str, default, bound: Bound, n: int) -> tuple:
    v = field_value(data, key, "", list(default))
    if not (isinstance(v, list) and len(v) == n):
        raise SceneError(f"{key}: expected {n} numbers, got {show(v)}")
    return tuple(bound.check(x, where_of(key, i)) for i, x in enumerate(v))


def scene_from_json(data: Any) -> FallScene:
    if not isinstance(data, dict):
        raise SceneError("expected a JSON object at the top level")
    if field_value(data, "scenario", "", "") != "fall":
        raise SceneError(f"scenario: this is the fall scenario's parser, got {show(data.get('scenario'))}")
    unknown_fields(data, FIELDS, "")
    version = field_value(data, "version", "", SCENE_VERSION)
    if version != SCENE_VERSION:
        raise SceneError(f"version: {show(version)} is not a fall scene version this Galileo reads ({SCENE_VERSION})")
    vals = field_value(data, "values", "", {})
    if not isinstance(vals, dict):
        raise SceneError(f"values: expected an object of {', '.join(VALUE_FIELDS)}")
    unknown_fields(vals, VALUE_FIELDS, "values")
    d = FallScene()
    kw: dict[str, Any] = {key: number(vals, key, "values", getattr(d, key)) for key in VALUE_FIELDS}
    for key in ("mass_kg", "fps", "sim_hz", "gravity_mps2"):
        kw[key] = number(data, key, "", getattr(d, key))
    kw["n_frames"] = N_FRAMES.check(field_value(data, "n_frames", "", d.n_frames), "n_frames")
    kw["release_frame"] = Bound(0, 100_000, integer=True).check(field_value(data, "release_frame", "", 0),
                                                                 "release_frame")
    for key in ("object", "surface", "surface_kind"):
        kw[key] = field_value(data, key, "", getattr(d, key))
    kw["surface_size_m"] = _pair_of_numbers(data, "surface_size_m", d.surface_size_m, SURFACE_SIZE, 2)
    sh = field_value(data, "shape", "", d.shape.to_json())
    if not (isinstance(sh, dict) and set(sh) == {"type", "size_m"} and isinstance(sh["size_m"], list)
            and len(sh["size_m"]) == 3 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                and math.isfinite(x) and 0 < x <= 5 for x in sh["size_m"])):
        raise SceneError(f"shape: expected {{\"type\": box|cylinder|torus, \"size_m\": three sizes in (0, 5] m}}, "
                         f"got {show(sh)}")
    try:
        kw["shape"] = Shape.from_json(sh)
    except (ValueError, KeyError, TypeError) as err:
        raise SceneError(f"shape: {err}") from None
    kw["priors"] = priors_of(data, tuple(PRIORS) + RELEASE_LATENTS)
    kw["bottom_up"] = bottom_up_of(data)
    cam = field_value(data, "camera", "", None)
    kw["camera"] = camera_from_json(cam) if cam is not None else None
    scene = FallScene(**kw)
    scene.validate()
    return scene


def surface_corners_m(scene: FallScene) -> np.ndarray:
    """The surface rectangle's corners (4, 3) in the order a user clicks them: near left, near
    right, far right, far left (near: the camera's end, x = -length / 2; left: +y)."""
    L, W = scene.surface_size_m
    return np.array([(-L / 2, W / 2, 0.0), (-L / 2, -W / 2, 0.0), (L / 2, -W / 2, 0.0), (L / 2, W / 2, 0.0)])
