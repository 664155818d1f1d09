"""A trained recognition model: what it reads, from which patches, and where it starts chains.

`LeNetModel` wraps the ensemble of `lenet.py` with its header (scenario, labels it learned
from, the mass scale, the patch geometry, the objects it was trained and tested on) in one
model file (`modelfile.py`: NPZ + JSON, never pickle). `read_video` crops the read objects
of a video (`Scenario.readouts`) and returns a `Reading` per object: a log-normal for the
mass and a normal for the friction. `independence` turns readings into an independence
proposal (`galileo.mcmc.Independence`) over the latents the readouts name, each quantity
scaled to its latent; `chain_starts` draws where MCMC chains start from it (Galileo Fig. 4).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import numpy as np

from .. import registry
from ..errors import GalileoError
from ..readout import FRICTION, MASS
from . import lenet, modelfile

log = logging.getLogger(__name__)

Z90 = 1.6448536269514722     # the 95% quantile of a standard normal: 90% intervals
MIN_SD = 1e-3                # the independence proposal's narrowest spread (a latent's units; logs for log-normals)
DATA = Path(__file__).resolve().parents[1] / "data"
BUILTIN = DATA / "recognition_ramp.npz"     # the ramp's (Galileo labels on the full preset, split 0 held out)


def builtin(scenario: str | None) -> Path | None:
    """The shipped model for a scenario's built-in dataset (data/recognition_<scenario>.npz), if any."""
    path = DATA / f"recognition_{scenario or registry.DEFAULT}.npz"
    return path if path.is_file() else None


@dataclass(frozen=True)
class Reading:
    """One object read from one frame: ln(mass / kg) ~ N(log_mass, log_mass_sd), friction ~
    N(friction, friction_sd), and what a model with more outputs reads of other quantities
    (`others`: quantity -> (kind "normal" or "lognormal", mean, SD), of its log for a
    log-normal; e.g. "stiffness_npm")."""
    role: str
    log_mass: float
    log_mass_sd: float
    friction: float | None      # None: the model never learnt friction (no labels: e.g. splash)
    friction_sd: float | None
    patches: int
    others: Mapping[str, tuple[str, float, float]] = field(default_factory=dict)

    @property
    def mass_kg(self) -> float:
        return math.exp(self.log_mass)   # the median of the log-normal

    def distribution(self, quantity: str) -> tuple[str, float, float] | None:
        """What this reading says of `quantity` (a `Readout` quantity name), in its own units:
        ("lognormal", mean of its log, SD of its log) for the mass, ("normal", mean, SD) for the
        friction, `others`' entry for another; None for a quantity the model does not read."""
        if quantity == MASS:
            return "lognormal", self.log_mass, self.log_mass_sd
        if quantity == FRICTION:
            return None if self.friction is None else ("normal", self.friction, self.friction_sd)
        return self.others.get(quantity)

    def to_json(self) -> dict:
        d = {"role": self.role, "mass_kg": self.mass_kg,
             "mass_kg_90": [math.exp(self.log_mass - Z90 * self.log_mass_sd),
                            math.exp(self.log_mass + Z90 * self.log_mass_sd)],
             "log_mass_sd": self.log_mass_sd, "patches": self.patches}
        if self.friction is not None:
            d.update({"friction": self.friction, "friction_sd": self.friction_sd,
                      "friction_90": [self.friction - Z90 * self.friction_sd, self.friction + Z90 * self.friction_sd]})
        for quantity, (kind, mean, sd) in self.others.items():
            d[quantity] = {"kind": kind, "mean": mean, "sd": sd}
        return d


class LeNetModel:
    kind = "lenet"

    def __init__(self, meta: dict, states: list):
        self.meta = meta
        self.states = states

    @property
    def scenario(self) -> str:
        return self.meta["scenario"]

    @property
    def mass_range_kg(self) -> tuple[float, float]:
        lo, hi = self.meta["mass_range_kg"]
        return float(lo), float(hi)

    # -- files --------------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        arrays = {f"m{i}/{k}": v for i, st in enumerate(self.states) for k, v in st.items()}
        modelfile.save(path, {**self.meta, "kind": self.kind, "members": len(self.states)}, arrays)

    @classmethod
    def load(cls, path: str | Path, scenario: str | None = None) -> "LeNetModel":
        meta, arrays = modelfile.load(path, kind=cls.kind, scenario=scenario)
        try:
            states = [{} for _ in range(int(meta["members"]))]
            for k, v in arrays.items():
                member, name = k.split("/", 1)
                states[int(member[1:])][name] = v
            lo, hi = (float(x) for x in meta["mass_range_kg"])
            if not 0 < lo < hi:
                raise ValueError("mass_range_kg")
            model = cls(meta, states)
            # the weights must fit the network (a file of another architecture is refused here)
            lenet.predict(states, np.zeros((1, 32, 32, 3), np.uint8))
        except GalileoError:
            raise
        except Exception as e:
            raise GalileoError(f"{path}: a recognition model this Galileo cannot use ({type(e).__name__}: {e})") from None
        return model

    # -- reading --------------------------------------------------------------------------------
    def read_patches(self, patches_u8: np.ndarray, role: str = "") -> Reading:
        """One object's reading from its patches (N, 32, 32, 3)."""
        mean, sd = lenet.predict(self.states, patches_u8)
        m, s = lenet.pool(mean, sd)
        scale = math.log(self.mass_range_kg[1] / self.mass_range_kg[0])
        friction = "friction" in self.meta.get("quantities", ("mass_kg", "friction"))
        return Reading(role, math.log(self.mass_range_kg[0]) + float(m[0]) * scale, float(s[0]) * scale,
                       float(m[1]) if friction else None, float(s[1]) if friction else None, int(len(patches_u8)))

    def read_video(self, video, scene, tracks=None) -> dict[str, Reading]:
        """A Reading per object the scenario reads (`Scenario.readouts`) in the video."""
        from .data import patches

        scenario = registry.of(scene)
        if scenario.name != self.scenario:
            raise GalileoError(f"the model reads {self.scenario} videos, not {scenario.name}")
        prepared = scenario.prepare(scene, tracks) if tracks is not None else scene
        out = {}
        for r in scenario.readouts(prepared):
            out[r.role] = self.read_patches(patches(video, prepared, tracks, r.role), r.role)
        if not out:
            raise GalileoError(f"the {scenario.name} scenario reads no objects from a frame")
        return out


def load_model(path: str | Path | None, scenario: str | None = None):
    """A model file, LeNet or simulation-trained (default: the scenario's built-in LeNet)."""
    if path is None:
        path = builtin(scenario)
        if path is None:
            raise GalileoError(f"no built-in recognition model for the {scenario} scenario; give --model")
    meta, _ = modelfile.load(path, scenario=scenario)
    if meta.get("kind") == "simulation":
        from .simulation import SimulationModel

        return SimulationModel.load(path, scenario)
    return LeNetModel.load(path, scenario)


def recognition_init(model, video, scene, tracks, move_every: int = 0, source: str = ""):
    """An `init` for `galileo.runner.infer`: chains start at draws from what the model reads
    in the video (LeNet: from the first frame; the simulation-trained model: from the tracked
    velocities), and with `move_every` > 0 an independence proposal from the same
    distribution joins the sweeps every `move_every` sweeps (exact: with its Hastings factor)."""
    from ..runner import Init

    def init(prepared, names, bounds, n_chains, seed, integer_sites):
        names = list(names)
        if move_every and integer_sites:
            raise GalileoError("the recognition move draws continuous values: not for a scenario with integer "
                               f"latents ({', '.join(names[j] for j in integer_sites)}); start chains with it instead")
        scenario = registry.of(prepared)
        if getattr(model, "kind", "lenet") == "simulation":
            q = model.proposal(scene, tracks, names, bounds, every=max(move_every, 1))
            readings = {"latents": model.predict(scene, tracks)}
        else:
            read = model.read_video(video, scene, tracks)
            q = independence(read, scenario, prepared, names, bounds, every=max(move_every, 1))
            readings = {role: r.to_json() for role, r in read.items()}
        starts = chain_starts(q, bounds, n_chains, seed, integer_sites)
        info = {"starts": "recognition", "model": source or str(getattr(model, "path", "")),
                "kind": model.meta.get("kind", getattr(model, "kind", "")), "labels": model.meta.get("labels"),
                "readings": readings, "independence_every": int(move_every) if move_every else None,
                "proposal": {"kinds": list(q.kinds), "loc": list(q.loc), "scale": list(q.scale)}}
        return Init(starts, q if move_every else None, info)

    return init


def independence(readings: dict[str, Reading], scenario, prepared_scene, names, bounds: np.ndarray, every: int = 1):
    """The readings as an independence proposal over the latent vector (`names` order): each
    latent a readout names (`Readout.reads`) gets what the model read of its quantity, scaled
    to the latent (latent = scale x quantity: a log-normal's log shifted by ln scale, a
    normal's mean and SD multiplied by it); the prior (uniform) for every other latent, and
    for a quantity the model does not read (an info line says so)."""
    from ..mcmc import Independence

    kinds, loc, scale = [], [], []
    for j, n in enumerate(names):
        kinds.append("uniform"), loc.append(float(bounds[j, 0])), scale.append(float(bounds[j, 1]))
    for r in scenario.readouts(prepared_scene):
        rd = readings.get(r.role)
        if rd is None:
            continue
        for quantity, (latent, per_unit) in r.reads.items():
            if latent not in names:
                continue
            read = rd.distribution(quantity)
            if read is None:
                log.info("recognition: the model does not read the %s object's %s; %s starts from its prior",
                         r.role, quantity, latent)
                continue
            kind, mean, sd = read
            j = names.index(latent)
            if kind == "lognormal":
                kinds[j], loc[j], scale[j] = kind, mean + math.log(per_unit), max(sd, MIN_SD)
            else:
                kinds[j], loc[j], scale[j] = kind, mean * per_unit, max(sd * per_unit, MIN_SD)
    q = Independence(tuple(kinds), tuple(loc), tuple(scale), every)
    q.check()
    return q


def chain_starts(q, bounds: np.ndarray, n_chains: int, seed: int, integer_sites=()) -> np.ndarray:
    """Chain c starts at a draw from q inside the prior's bounds, from its own stream
    (SeedSequence(seed, spawn_key=(2**31 + 1, c))), so a chain's start does not depend on
    how many chains run."""
    out = np.empty((n_chains, len(bounds)))
    for c in range(n_chains):
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(2**31 + 1, c)))
        for _ in range(1000):
            x = q.sample(rng)
            if np.all((x >= bounds[:, 0]) & (x <= bounds[:, 1])):
                break
        out[c] = np.clip(x, bounds[:, 0], bounds[:, 1])
        for j in integer_sites:
            out[c, j] = np.clip(np.round(out[c, j]), bounds[j, 0], bounds[j, 1])
    return out
