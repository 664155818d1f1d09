"""Scene & priors of the spring scenario (Physics 101, section 2): an object hanging from a
spring, pulled down (or lifted) by hand and released, bouncing and swaying, filmed from the side.

World frame (metres, z up): the spring hangs from `top_in_world_m` (the hanging point); the
object moves in the vertical plane y = top's y, the plane the camera looks at (x across the
image, z up). Observations are the object's centre in that plane, read from pixels through
the scene's camera (`galileo.camera.backproject_to_plane`).

What belongs to what (the names say it: a problem of several videos shares a latent by name,
`galileo.joint`):

    the object `object`:  its mass                 m_<object>_kg
    the spring `spring`:  stiffness                k_<spring>_Npm
                          its own mass             ms_<spring>_kg
                          damping (a dashpot)      c_<spring>_Nspm
                          unloaded length          rest_<spring>_m
    the video:            the release state at `release_frame` (centre relative to the hanging
                          point, in the scene's units): x0_m, z0_m, vx0_mps, vz0_mps; where
                          the tracker puts the centre relative to the body's, ox_px and oz_px;
                          the tracking noise across and up-down, log10_sigma_x_px and
                          log10_sigma_z_px, and its frame-to-frame correlation rho;
                          and, where the camera's scale is not known (`metric: false`), `scale`:
                          true length / the scene's length

The release *time* is the tracker's release frame, not a latent: a sub-frame shift of it is
absorbed exactly by the release state (the motion after release is free).

`hang_m` is the distance from the spring's lower end to the object's centre (a hook, a bag's
knot, half the object), a property of the video's setup: the spring's length is the distance
from the hanging point to the object's centre minus it.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

from ...camera import Camera, camera_from_json, look_at_camera, physics_hz
from ...errors import SceneError
from ...fields import Bound, field_value, number, show, unknown_fields, where_of
from ...latents import Latent, check_bounds
from ...scenefile import SceneFile, bottom_up_of, check_camera_of, priors_of

SCENE_VERSION = 1
ID = re.compile(r"^[a-z][a-z0-9]{0,23}$")   # an object's or spring's name (it goes into latent names)

# -- what a spring scene may hold: every bound in one place, each with its reason ------------------
MASS = Bound(0.0, 50.0, lo_open=True)       # kg: above 0; 50 kg is beyond any spring on a stand
STIFFNESS = Bound(0.0, 1e5, lo_open=True)   # N/m: a slinky's 1 N/m to a car spring's 1e5
SPRING_MASS = Bound(0.0, 10.0)              # kg: a massless spring is a fine model
DAMPING = Bound(0.0, 100.0)                 # N s/m: 0 (no loss) to overdamped for any mass here
LENGTH = Bound(0.0, 20.0)                   # m: lengths and offsets of a bench-top apparatus
SPEED = Bound(-50.0, 50.0)                  # m/s: a hand releases at a few m/s at most
POSITION = Bound(-20.0, 20.0)               # m: release position relative to the hanging point
SCALE = Bound(0.01, 100.0)                  # true / scene length: a scene 100 times off is no calibration
SIGMA_LOG10 = Bound(-3.0, 3.0)              # log10 px: 0.001 px to 1000 px
RHO = Bound(0.0, 0.999)                     # the residuals' frame-to-frame correlation (1: no information)
SIM_HZ = Bound(30.0, 10000.0)               # physics steps a second (a multiple of the video's fps)
GRAVITY = Bound(0.0, 100.0, lo_open=True)
FPS = Bound(1.0, 1000.0)
N_FRAMES = Bound(2, 100_000, integer=True)

# default priors (U(low, high)); a scene's "priors" narrow or widen them
PRIORS = {"mass": (0.001, 1.0), "k": (0.5, 200.0), "ms": (0.0, 0.1), "c": (0.0, 2.0), "rest": (0.0, 1.0),
          "scale": (0.25, 4.0), "ox_px": (-15.0, 15.0), "oz_px": (-15.0, 15.0), "log10_sigma_x_px": (-0.5, 1.5), "log10_sigma_z_px": (-0.5, 1.5), "rho": (0.0, 0.99)}
RELEASE_POS_PRIOR_M = 0.05     # release position: the tracked one +- this (scene units)
RELEASE_SPEED_PRIOR_MPS = 1.0  # release velocity: the tracked one +- this (scene units)
# the observation model's latents (none enters the simulation): where the tracker puts the centre
# relative to the body's (a bag's outline, a tracker's idea of a centre: a few pixels, constant),
# and the tracking noise
OFFSET_LATENTS = ("ox_px", "oz_px")
NOISE_LATENTS = OFFSET_LATENTS + ("log10_sigma_x_px", "log10_sigma_z_px", "rho")
OFFSET_PRIOR_PX = 15.0
RELEASE_LATENTS = ("x0_m", "z0_m", "vx0_mps", "vz0_mps")
# a scene's nominal observation model: no offset, 1 px of white noise
NOISE_VALUES = {"ox_px": 0.0, "oz_px": 0.0, "log10_sigma_x_px": 0.0, "log10_sigma_z_px": 0.0, "rho": 0.0}


def object_latent(obj: str) -> str:
    return f"m_{obj}_kg"


def spring_latents(spring: str) -> dict[str, str]:
    """{kind: latent name} of a spring's latents."""
    return {"k": f"k_{spring}_Npm", "ms": f"ms_{spring}_kg", "c": f"c_{spring}_Nspm", "rest": f"rest_{spring}_m"}


@dataclass(frozen=True)
class SpringScene(SceneFile):
    """One video of an object on a spring. Values are the latents' values (a rendered video's
    truth; elsewhere where `galileo simulate` starts); `priors` holds U(low, high) per kind
    ("mass", "k", "ms", "c", "rest", "scale", "ox_px", "oz_px", "log10_sigma_x_px", "log10_sigma_z_px",
    "rho") or per release latent."""
    scenario: ClassVar[str] = "spring"
    object: str = "object"
    spring: str = "spring"
    top_in_world_m: tuple[float, float, float] = (0.0, 0.0, 1.0)
    hang_m: float = 0.03
    size_m: tuple[float, float, float] = (0.05, 0.05, 0.05)
    mass_kg: float = 0.1
    k_Npm: float = 20.0
    spring_mass_kg: float = 0.01
    damping_Nspm: float = 0.02
    rest_m: float = 0.25
    x0_m: float = 0.0
    z0_m: float = -0.40
    vx0_mps: float = 0.0
    vz0_mps: float = 0.0
    scale: float = 1.0
    release_frame: int = 0
    metric: bool = True
    fps: float = 30.0
    n_frames: int = 150
    sim_hz: float = 60.0
    gravity_mps2: float = 9.81
    priors: dict = field(default_factory=dict)
    camera: Camera | None = None
    # what the track says before any physics (prepare(): a damped sine fitted to it): period_s,
    # decay_per_s, centre_x_m, centre_z_m (scene units, from the hanging point); chains start from it
    bottom_up: dict = field(default_factory=dict, compare=False)

    # -- latents ---------------------------------------------------------------------------
    def names(self) -> dict[str, str]:
        """{latent name: scene attribute} for this video's latents, in order."""
        sp = spring_latents(self.spring)
        d = {object_latent(self.object): "mass_kg", sp["k"]: "k_Npm", sp["ms"]: "spring_mass_kg",
             sp["c"]: "damping_Nspm", sp["rest"]: "rest_m", "x0_m": "x0_m", "z0_m": "z0_m",
             "vx0_mps": "vx0_mps", "vz0_mps": "vz0_mps"}
        if not self.metric:
            d["scale"] = "scale"
        return d

    def latents(self) -> dict[str, float]:
        """The latents' values in this scene (its truth when the scene made the observations);
        the noise latents have no truth here."""
        return {name: float(getattr(self, attr)) for name, attr in self.names().items()}

    def latent_specs(self) -> tuple[Latent, ...]:
        sp = spring_latents(self.spring)
        kinds = {object_latent(self.object): "mass", sp["k"]: "k", sp["ms"]: "ms", sp["c"]: "c", sp["rest"]: "rest"}
        out = []
        for name in self.names():
            kind = kinds.get(name, name)
            base = LATENTS[kind] if kind in LATENTS else _release_latent(name, self)
            out.append(_with_bounds(replace(base, name=name), self.prior(kind if kind in LATENTS else name, base)))
        for name in NOISE_LATENTS:
            base = LATENTS[name]
            out.append(_with_bounds(base, self.prior(name, base)))
        return tuple(out)

    def prior(self, key: str, base: Latent) -> tuple[float, float]:
        lo, hi = self.priors.get(key, base.bounds)
        return float(lo), float(hi)

    def with_values(self, values: dict[str, float]) -> SpringScene:
        names = self.names()
        extra = {"release_frame": "release_frame", "hang_m": "hang_m", "mass_kg": "mass_kg", "k_Npm": "k_Npm",
                 "spring_mass_kg": "spring_mass_kg", "damping_Nspm": "damping_Nspm", "rest_m": "rest_m",
                 "scale": "scale"}
        known = {**extra, **names}
        unknown = sorted(set(values) - set(known) - set(NOISE_LATENTS))
        if unknown:
            raise SceneError(f"unknown value(s) {', '.join(unknown)}; this spring scene takes "
                             f"{', '.join(list(names) + list(NOISE_LATENTS))}")
        changes = {known[k]: (int(round(v)) if known[k] == "release_frame" else float(v))
                   for k, v in values.items() if k in known}
        scene = replace(self, **changes)
        scene.validate()
        return scene

    # -- checks and JSON -----------------------------------------------------------------------
    def validate(self) -> None:
        for what, name in (("object", self.object), ("spring", self.spring)):
            if not isinstance(name, str) or not ID.match(name):
                raise SceneError(f"{what}: {show(name)} is no name: 1-24 lowercase letters and digits, "
                                 f"starting with a letter (it names latents, e.g. m_{{object}}_kg)")
        for where, v, b in (("mass_kg", self.mass_kg, MASS), ("k_Npm", self.k_Npm, STIFFNESS),
                            ("spring_mass_kg", self.spring_mass_kg, SPRING_MASS),
                            ("damping_Nspm", self.damping_Nspm, DAMPING), ("rest_m", self.rest_m, LENGTH),
                            ("hang_m", self.hang_m, LENGTH), ("x0_m", self.x0_m, POSITION),
                            ("z0_m", self.z0_m, POSITION), ("vx0_mps", self.vx0_mps, SPEED),
                            ("vz0_mps", self.vz0_mps, SPEED), ("scale", self.scale, SCALE),
                            ("fps", self.fps, FPS), ("sim_hz", self.sim_hz, SIM_HZ),
                            ("gravity_mps2", self.gravity_mps2, GRAVITY)):
            b.check(v, where)
        N_FRAMES.check(self.n_frames, "n_frames")
        if not 0 <= self.release_frame < self.n_frames - 1:
            raise SceneError(f"release_frame: {self.release_frame} must be in [0, n_frames - 1) = "
                             f"[0, {self.n_frames - 1})")
        if abs(physics_hz(self.sim_hz, self.fps) - self.sim_hz) > 1e-9:
            raise SceneError(f"sim_hz ({self.sim_hz:g}) must be a multiple of fps ({self.fps:g})")
        if any(not (0 < s <= 5) for s in self.size_m):
            raise SceneError(f"size_m: {list(self.size_m)} must be three sizes in (0, 5] m")
        if self.metric and self.scale != 1.0:
            raise SceneError("scale: a metric scene's scale is 1 (set \"metric\": false to infer it)")
        check_camera_of(self.camera, self.fps, self.n_frames)
        self.latent_specs()   # the priors hold together

    def to_json(self) -> dict:
        d = {"scenario": self.scenario, "version": SCENE_VERSION, "object": self.object, "spring": self.spring,
             "top_in_world_m": list(self.top_in_world_m), "hang_m": self.hang_m, "size_m": list(self.size_m),
             "values": {"mass_kg": self.mass_kg, "k_Npm": self.k_Npm, "spring_mass_kg": self.spring_mass_kg,
                        "damping_Nspm": self.damping_Nspm, "rest_m": self.rest_m, "x0_m": self.x0_m,
                        "z0_m": self.z0_m, "vx0_mps": self.vx0_mps, "vz0_mps": self.vz0_mps, "scale": self.scale},
             "release_frame": self.release_frame, "metric": self.metric, "fps": self.fps,
             "n_frames": self.n_frames, "sim_hz": self.sim_hz, "gravity_mps2": self.gravity_mps2,
             "priors": {k: list(v) for k, v in self.priors.items()}}
        if self.camera is not None:
            d["camera"] = self.camera.to_json()
        if self.bottom_up:
            d["bottom_up"] = dict(self.bottom_up)
        return d


FIELDS = ("scenario", "version", "object", "spring", "top_in_world_m", "hang_m", "size_m", "values",
          "release_frame", "metric", "fps", "n_frames", "sim_hz", "gravity_mps2", "priors", "camera", "bottom_up")
VALUE_FIELDS = ("mass_kg", "k_Npm", "spring_mass_kg", "damping_Nspm", "rest_m", "x0_m", "z0_m", "vx0_mps",
                "vz0_mps", "scale")

LATENTS = {
    "mass": Latent("m_kg", "kg", PRIORS["mass"], "the object's mass", limits=(0.0, MASS.hi), limits_open_low=True,
                   narrow=0.01, broad=0.2),
    "k": Latent("k_Npm", "N/m", PRIORS["k"], "the spring's stiffness (Hooke's k)", limits=(0.0, STIFFNESS.hi),
                limits_open_low=True, narrow=0.5, broad=20.0),
    "ms": Latent("ms_kg", "kg", PRIORS["ms"], "the spring's own mass (oscillates as a third of it, stretches "
                 "as half)", limits=(0.0, SPRING_MASS.hi), narrow=0.005, broad=0.03),
    "c": Latent("c_Nspm", "N s/m", PRIORS["c"], "the spring's damping (a dashpot along it)",
                limits=(0.0, DAMPING.hi), narrow=0.005, broad=0.2),
    "rest": Latent("rest_m", "m", PRIORS["rest"], "the unloaded spring's length", limits=(0.0, LENGTH.hi),
                   narrow=0.005, broad=0.1),
    "scale": Latent("scale", "1", PRIORS["scale"], "true length / the scene's length (the camera's scale "
                    "is not known)", limits=(SCALE.lo, SCALE.hi), narrow=0.02, broad=0.5),
    "ox_px": Latent("ox_px", "px", PRIORS["ox_px"], "where the tracker puts the centre across, relative to the "
                    "body's (constant)", limits=(-1e3, 1e3), narrow=0.2, broad=3.0),
    "oz_px": Latent("oz_px", "px", PRIORS["oz_px"], "where the tracker puts the centre up-down, relative to the "
                    "body's (constant)", limits=(-1e3, 1e3), narrow=0.2, broad=3.0),
    "log10_sigma_x_px": Latent("log10_sigma_x_px", "log10 px", PRIORS["log10_sigma_x_px"],
                               "the tracked centre's noise across (log10 of its SD in pixels): the sway's misfit",
                               limits=(SIGMA_LOG10.lo, SIGMA_LOG10.hi), observation=True, narrow=0.02, broad=0.3),
    "log10_sigma_z_px": Latent("log10_sigma_z_px", "log10 px", PRIORS["log10_sigma_z_px"],
                               "the tracked centre's noise up and down (log10 of its SD in pixels)",
                               limits=(SIGMA_LOG10.lo, SIGMA_LOG10.hi), observation=True, narrow=0.02, broad=0.3),
    "rho": Latent("rho", "1", PRIORS["rho"], "the noise's correlation from one frame to the next (AR(1))",
                  limits=(RHO.lo, RHO.hi), observation=True, narrow=0.05, broad=0.3),
}


def _release_latent(name: str, scene: SpringScene) -> Latent:
    """A release latent, its default prior around the scene's value (prepare() centres it on
    the tracked release)."""
    v = float(getattr(scene, name))
    if name.startswith("v"):
        w, unit, doc, b = RELEASE_SPEED_PRIOR_MPS, "m/s", "the object's velocity at release", SPEED
    else:
        w, unit, doc, b = RELEASE_POS_PRIOR_M, "m", "the object's centre at release, from the hanging point", POSITION
    axis = "horizontal" if "x" in name else "vertical"
    return Latent(name, unit, (max(b.lo, v - w), min(b.hi, v + w)), f"{doc} ({axis})", limits=(b.lo, b.hi),
                  narrow=w / 100, broad=w / 5)


def _with_bounds(lat: Latent, bounds: tuple[float, float]) -> Latent:
    try:
        lo, hi = check_bounds(lat, *bounds)
    except ValueError as err:
        raise SceneError(f"priors.{err}") from None
    return replace(lat, bounds=(lo, hi))


def px_per_m(camera: Camera, top_in_world_m) -> float:
    """The scene's scale in the spring's plane: pixels a metre (of the scene's) at the hanging point,
    the mean of across and up-down (1 cm each way)."""
    import numpy as np

    top = np.asarray(top_in_world_m, float)
    return 0.5 * sum(float(np.linalg.norm(camera.project(top + d) - camera.project(top))) / 0.01
                     for d in ((0.01, 0.0, 0.0), (0.0, 0.0, 0.01)))


def default_camera(top_in_world_m=(0.0, 0.0, 1.0), fps: float = 30.0, n_frames: int = 150) -> Camera:
    """A side view of the spring's plane from 1.5 m, looking at a point 0.35 m below the hanging point."""
    tx, ty, tz = top_in_world_m
    return look_at_camera((tx, ty - 1.5, tz - 0.3), (tx, ty, tz - 0.35), focal_px=700.0, width_px=640,
                          height_px=480, fps=fps, n_frames=n_frames)


def default_scene() -> SpringScene:
    s = SpringScene()
    return replace(s, camera=default_camera(s.top_in_world_m, s.fps, s.n_frames))


def scene_from_json(data: Any) -> SpringScene:
    if not isinstance(data, dict):
        raise SceneError("expected a JSON object at the top level")
    if field_value(data, "scenario", "", "") != "spring":
        raise SceneError(f"scenario: this is the spring scenario's parser, got {show(data.get('scenario'))}")
    unknown_fields(data, FIELDS, "")
    version = field_value(data, "version", "", SCENE_VERSION)
    if version != SCENE_VERSION:
        raise SceneError(f"version: {show(version)} is not a spring scene version this Galileo reads "
                         f"({SCENE_VERSION})")
    vals = field_value(data, "values", "", {})
    if not isinstance(vals, dict):
        raise SceneError(f"values: expected an object of {', '.join(VALUE_FIELDS)}")
    unknown_fields(vals, VALUE_FIELDS, "values")
    d = SpringScene()
    kw: dict[str, Any] = {}
    for key in VALUE_FIELDS:
        kw[key] = number(vals, key, "values", getattr(d, key))
    for key in ("hang_m", "fps", "sim_hz", "gravity_mps2"):
        kw[key] = number(data, key, "", getattr(d, key))
    kw["n_frames"] = N_FRAMES.check(field_value(data, "n_frames", "", d.n_frames), "n_frames")
    kw["release_frame"] = Bound(0, 100_000, integer=True).check(field_value(data, "release_frame", "", 0),
                                                                 "release_frame")
    for key in ("object", "spring"):
        kw[key] = field_value(data, key, "", getattr(d, key))
    metric = field_value(data, "metric", "", True)
    if not isinstance(metric, bool):
        raise SceneError(f"metric: expected true or false, got {show(metric)}")
    kw["metric"] = metric
    for key in ("top_in_world_m", "size_m"):
        v = field_value(data, key, "", list(getattr(d, key)))
        if not (isinstance(v, list) and len(v) == 3):
            raise SceneError(f"{key}: expected three numbers, got {show(v)}")
        kw[key] = tuple(POSITION.check(x, where_of(key, i)) for i, x in enumerate(v))
    kw["priors"] = priors_of(data, tuple(PRIORS) + RELEASE_LATENTS)
    kw["bottom_up"] = bottom_up_of(data)
    cam = field_value(data, "camera", "", None)
    kw["camera"] = camera_from_json(cam) if cam is not None else None
    scene = SpringScene(**kw)
    scene.validate()
    return scene
