"""Galileo as a Python library: what the `galileo` command line does, with the same defaults and
the same errors (`galileo.errors.GalileoError`, one line, never a traceback from bad input).

    import galileo
    scene = galileo.load_scene("demo/scene.json")
    result = galileo.infer(scene, "demo/video.mp4")    # tracks the video, then 16 x 75 MCMC
    print(result)                                    # what the video identifies, with 90% intervals
    idata = result.to_arviz()                        # ArviZ's DataTree (posterior, sample_stats, ...)
    idata.to_netcdf("demo.nc")

* `load_scene`, `load_tracks`, `track`: a scene file; a video's tracks (positions and velocities
  in metres, the objects' shapes, notes on the camera).
* `infer`: one video, or several as one problem (`share`, `fix`); a `Result`.
* `load_result`: a result file written by `galileo infer --out` or `Result.save`, as a `Result`.
* `predict`: the paper's questions from a result (`galileo predict`).
* `experiment`: the paper's experiments over a rendered dataset, locally or on a Dask client you
  pass in (`galileo experiment`).
* `calibrate`: simulation-based calibration (`galileo calibrate`).

A `Result` holds what result.json holds (`Result.doc`) and the full sample record: `.map`,
`.posterior`, `.posterior_derived`, `.diagnostics`, `.converged`, `.not_identified`, `.samples`,
`.to_arviz()` (`galileo.inferencedata`), `.save(path)`.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .errors import GalileoError

# `infer`'s wall-clock budget when it runs until converged by default (issue 30): 300 s, since the
# ramp demo with the collision's restitution a latent (the default model) converges in 150-170 s
# on 2 cores (BENCHMARKS.md); a run that converges sooner stops sooner
DEFAULT_MAX_SECONDS = 300.0
WIDTH_RANGES = 100   # a proposal width at most this many times its latent's prior range
UNIT_SUFFIXES = (("_g_cm3", "g/cm^3"), ("_cm3", "cm^3"), ("_kg", "kg"), ("_Nspm", "N s/m"), ("_Npm", "N/m"),
                 ("_mps", "m/s"), ("_m", "m"), ("_s", "s"), ("_deg", "deg"), ("_px", "px"))


def unit_of(name: str) -> str:
    """A quantity's unit from its name's suffix (Galileo names carry their units: `mass_kg`,
    `period_s`); "1" (dimensionless) otherwise."""
    base = name.split("@")[0]
    return next((u for end, u in UNIT_SUFFIXES if base.endswith(end)), "1")


# -- scenes and tracks -----------------------------------------------------------------------------

def load_scene(path: str | Path):
    """A scene file (any scenario's: the file names it), checked; GalileoError saying what is wrong."""
    from . import registry

    return registry.load_scene(path)


def load_tracks(path: str | Path):
    """A tracks file written by `galileo track --out` or `Tracks.save`."""
    from .datatypes import Tracks

    return Tracks.load(path)


def _scene(scene):
    return load_scene(scene) if isinstance(scene, (str, Path)) else scene


def track(video: str | Path, scene, *, progress: bool = True, debug_video: str | Path | None = None):
    """Track the scene's objects in a video (`galileo track`): a `galileo.datatypes.Tracks`.
    `scene`: a scene or its file."""
    from . import registry

    scene = _scene(scene)
    return registry.of(scene).track(str(video), scene, progress=progress, debug_video=debug_video)


# -- inference -------------------------------------------------------------------------------------

def moves_for(scenario, moves: str | None, until_rhat: float | None, sweeps: int | None = None,
              warmup: int | None = None, *, converging: bool | None = None, max_sweeps: int | None = None) -> str:
    """The move set a run uses: `moves` if given; else, for a run that may go on until converged
    (`converging`; by default: `until_rhat` is given), the scenario's `converge_moves` (the ramp's
    "fitted"), and "default" for a fixed number of sweeps (the paper's protocol's budget, whose
    figures BENCHMARKS.md reports). The app's chains can always be run until converged
    (`converging=True`). "fitted" needs a warm-up to fit to: where `sweeps`, `warmup` and
    `until_rhat` (and its `max_sweeps`) leave too short a one (`RunConfig.warmup_sweeps`), "default"."""
    from .runner import FITTED_MIN_WARMUP, RunConfig

    if moves is not None:
        return moves
    if not (until_rhat is not None if converging is None else converging):
        return "default"
    if scenario.converge_moves == "fitted" and sweeps is not None and RunConfig(
            sweeps=sweeps, until_rhat=until_rhat, warmup=warmup, max_sweeps=max_sweeps).warmup_sweeps() < FITTED_MIN_WARMUP:
        return "default"
    return scenario.converge_moves


def until_converged(sweeps: int | None, until_rhat: float | None, max_sweeps: int | None,
                    max_seconds: float | None, names: dict | None = None) -> tuple[float | None, float | None]:
    """`infer`'s rule for what to run, as (until_rhat, max_seconds): without `sweeps` and
    `until_rhat`, until converged (every latent's R-hat <= RHAT_TARGET and ESS >= min_ess) after a
    first block of the scenario's protocol; `sweeps` alone, a fixed run of that many sweeps (the
    paper's protocol: 75), its budgets refused. Running until converged has a wall-clock
    budget, DEFAULT_MAX_SECONDS unless given. `names` words the error for the CLI's flags."""
    from .results import RHAT_TARGET

    name = {"sweeps": "sweeps", "until_rhat": "until_rhat", "max_sweeps": "max_sweeps",
            "max_seconds": "max_seconds", **(names or {})}
    if until_rhat is None and sweeps is not None:
        for what, given in (("max_sweeps", max_sweeps), ("max_seconds", max_seconds)):
            if given is not None:
                raise GalileoError(f"{name[what]} is a budget of running until converged; {name['sweeps']} "
                                   f"{sweeps} alone is a fixed run (add {name['until_rhat']} to run on from it "
                                   "until converged)")
        return None, None
    return (RHAT_TARGET if until_rhat is None else until_rhat,
            DEFAULT_MAX_SECONDS if max_seconds is None else max_seconds)


def run_config(scenario, *, chains: int | None = None, sweeps: int | None = None, seed: int = 0,
               workers: int | None = None, sigma: float | None = None, moves: str | None = None,
               warmup: int | None = None, until_rhat: float | None = None, min_ess: float | None = None,
               max_sweeps: int | None = None, max_seconds: float | None = None, priors: dict | None = None,
               narrow: float | None = None, broad: float | None = None, broad_every: int | None = None,
               speedups: bool = True):
    """The `galileo.runner.RunConfig` of these settings, the scenario's protocol filling what is
    not given (the ramp's 16 x 75, the splash's 50 chains; `moves`: `moves_for`), checked (GalileoError)."""
    from .results import MIN_ESS
    from .runner import RunConfig

    protocol = scenario.protocol
    for what, given in (("max_sweeps", max_sweeps), ("max_seconds", max_seconds)):
        if given is not None and until_rhat is None:
            raise GalileoError(f"{what} is a budget of until_rhat (run until converged); without it, give sweeps")
    if priors is not None and not isinstance(priors, dict):
        raise GalileoError(f"priors: expected a dict merged into the scene's priors, got {priors!r}")
    sweeps = protocol["sweeps"] if sweeps is None else sweeps
    cfg = RunConfig(chains=protocol["chains"] if chains is None else chains,
                    sweeps=sweeps, seed=seed, workers=workers, noise=sigma,
                    speedups=speedups, narrow=narrow, broad=broad, broad_every=broad_every,
                    moves=moves_for(scenario, moves, until_rhat, sweeps, warmup, max_sweeps=max_sweeps), warmup=warmup,
                    until_rhat=until_rhat,
                    min_ess=float(MIN_ESS if min_ess is None else min_ess), max_sweeps=max_sweeps,
                    max_seconds=max_seconds, priors=priors)
    cfg.check()
    return cfg


def checked_settings(cfg, scenario, scene):
    """The run's sampler settings checked by the library's one rule (latents.check_noise for the
    noise (--sigma), check_widths for the proposal widths (--narrow, --broad, --broad-every),
    check_bounds for the priors); a width given more than WIDTH_RANGES times a latent's prior
    range is refused too (its proposals would almost never land inside the prior: chains that never
    move, as a width of 0 makes chains that accept everything)."""
    latents = scenario.latents(scene)
    try:
        settings = cfg.settings(latents, scenario.noise, scenario.paper_widths)
    except ValueError as e:
        raise GalileoError(str(e)) from None
    for flag, given, w in (("--narrow", cfg.narrow, settings.narrow), ("--broad", cfg.broad, settings.broad)):
        if given is None:
            continue
        ws = w if isinstance(w, tuple) else (w,) * len(latents)
        for lat, width in zip(latents, ws):
            lo, hi = settings.bounds[lat.name]
            if width > WIDTH_RANGES * (hi - lo):
                raise GalileoError(f"{flag} {width:g} is more than {WIDTH_RANGES} times {lat.name}'s prior range "
                                   f"({hi - lo:g} {lat.unit}): its proposals would almost never land inside the prior")
    return settings


def infer(scene, observed, *, tracks=None, share: Sequence[str] = (), fix: dict | None = None, chains: int | None = None,
          sweeps: int | None = None, seed: int = 0, workers: int | None = None, sigma: float | None = None,
          moves: str | None = None, warmup: int | None = None, until_rhat: float | None = None,
          min_ess: float | None = None, max_sweeps: int | None = None, max_seconds: float | None = None,
          priors: dict | None = None, init: str = "prior", model: str | Path | None = None,
          recognition_move: int | None = None, narrow: float | None = None, broad: float | None = None,
          broad_every: int | None = None, speedups: bool = True, progress: bool = True) -> "Result":
    """Infer a scene's latents from a video (`galileo infer`): a `Result`.

    `scene`: a scene or its file; `observed`: the video's file or its `Tracks` (tracked first if a
    video); `tracks`: the video's tracks made already (`galileo infer --tracks`), the video then read
    only by `init` recognition. Several videos as one problem: lists of scenes and of videos/tracks, with `share` (latents
    with one value for all) and `fix` ({name: value}: NAME in every video, NAME@2 in video 2 only).
    The other settings are `galileo infer`'s flags (`chains`: the scenario's protocol by default;
    `moves`: default|paper|fitted, else `moves_for`'s; `sigma` in the scenario's noise unit;
    `init`: prior|recognition). What runs (`until_converged`): by default until converged (every
    latent's R-hat <= 1.01, bulk and tail ESS >= `min_ess`) from a first block of the protocol's
    sweeps, within `max_sweeps` and `max_seconds` (DEFAULT_MAX_SECONDS, 300); `sweeps` alone is a
    fixed run of that many sweeps; `until_rhat` with `sweeps` runs on from them."""
    from . import registry
    from .runner import infer as run

    several = isinstance(scene, (list, tuple))
    scenes = [_scene(s) for s in (scene if several else [scene])]
    observed = list(observed) if isinstance(observed, (list, tuple)) else [observed]
    if len(observed) != len(scenes):
        raise GalileoError(f"{len(scenes)} scene(s) need as many videos or tracks, got {len(observed)}")
    made = None
    if tracks is not None:
        made = list(tracks) if isinstance(tracks, (list, tuple)) else [tracks]
        if len(made) != len(scenes):
            raise GalileoError(f"tracks: one per video ({len(scenes)}), got {len(made)}")
    if share and len(scenes) == 1:
        raise GalileoError("share is for several videos (one value of a latent for all of them)")
    fixed = {}
    for name, value in (fix or {}).items():
        if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
            raise GalileoError(f"fix {name}: expected a finite number, got {value!r}")
        fixed[str(name)] = float(value)
    problem = registry.problem(scenes, tuple(share), fixed)
    scenario = registry.of(problem)
    scenario.latents(problem)    # a bad share or fix fails here, before tracking
    until_rhat, max_seconds = until_converged(sweeps, until_rhat, max_sweeps, max_seconds)
    cfg = run_config(scenario, chains=chains, sweeps=sweeps, seed=seed, workers=workers, sigma=sigma, moves=moves,
                     warmup=warmup, until_rhat=until_rhat, min_ess=min_ess, max_sweeps=max_sweeps,
                     max_seconds=max_seconds, priors=priors, narrow=narrow, broad=broad, broad_every=broad_every,
                     speedups=speedups)
    checked_settings(cfg, scenario, problem)
    if init not in ("prior", "recognition"):
        raise GalileoError(f"init must be prior or recognition, got {init!r}")
    if init == "recognition" and len(scenes) > 1:
        raise GalileoError("init recognition reads one video: for several, chains start from the prior")
    if recognition_move is not None and (init != "recognition" or recognition_move < 1):
        raise GalileoError("recognition_move (every how many sweeps, >= 1) needs init recognition")
    loaded = None
    if init == "recognition":
        from .recognition.model import load_model

        loaded = load_model(model, scenario.name)   # before tracking: a bad model file fails fast
    elif model is not None:
        raise GalileoError("model is for init recognition")
    tracks, videos = [], []
    for v, (obs, s) in enumerate(zip(observed, scenes)):
        video = obs if isinstance(obs, (str, Path)) else None
        videos.append(video)
        if made is not None:
            tracks.append(load_tracks(made[v]) if isinstance(made[v], (str, Path)) else made[v])
        elif video is not None:
            tracks.append(track(video, s, progress=progress))
        else:
            tracks.append(obs)
    start = None
    if loaded is not None:
        if videos[0] is None:
            raise GalileoError("init recognition reads the video: give its file, not its tracks")
        from .recognition.model import recognition_init

        start = recognition_init(loaded, videos[0], problem, tracks[0], recognition_move or 0,
                                 source=str(model or "built-in"))
    result = run(problem, tracks if several else tracks[0], cfg, progress=progress, init=start)
    result.notes = tuple(f"video {v + 1}: {n}" if several else n
                         for v, t in enumerate(tracks) for n in (getattr(t, "notes", ()) or ()))
    return Result.of(result)


class Result:
    """An inference's result: result.json's content (`doc`) and the full sample record.

    Made by `infer` (`Result.of`) or read back by `load_result`. Everything a user reads is a
    property over `doc` (the file's keys); `to_arviz()` builds ArviZ's DataTree."""

    def __init__(self, doc: dict, record: dict, scene, tracks=None, inference=None):
        self.doc = doc              # what result.json holds
        self.record = record        # names, samples (C, S, D), logliks (C, S), starts, proposal_<field>
        self.scene = scene          # the scene inferred on
        self.tracks = tracks        # the observations (one Tracks or a list), if known
        self.inference = inference  # the galileo.results.InferenceResult, for a result made in this process

    @classmethod
    def of(cls, inference) -> "Result":
        """The Result of a `galileo.runner.infer` run."""
        return cls(inference.to_json(), inference.record(), inference.scene, inference.tracks, inference)

    # what result.json says
    @property
    def scenario(self) -> str:
        """The scenario's name (ramp, splash, spring, fall)."""
        return self.doc["scenario"]

    @property
    def names(self) -> tuple[str, ...]:
        """The latents, in the samples' order (`name@v`: video v's own in a problem of several)."""
        return tuple(self.doc["latents"])

    @property
    def map(self) -> dict[str, float]:
        """The MAP: the sampled point of highest likelihood, per latent (SI units)."""
        return dict(self.doc["map"])

    @property
    def posterior(self) -> dict[str, dict]:
        """Per latent: mean, sd, q05, q25, q50, q75, q95 of the kept draws (a latent the videos do not
        identify is summarised too: its posterior is its prior's; see `not_identified`)."""
        return self.doc["posterior"]

    @property
    def posterior_derived(self) -> dict[str, dict]:
        """The scenario's derived quantities' summaries (the ramp's mass_ratio, the splash's mass_kg),
        those identified only; a positive one also as `log_<name>`."""
        return self.doc["posterior_derived"]

    @property
    def not_identified(self) -> dict[str, str]:
        """{name: why} of what the videos do not identify: no point estimate for those."""
        return dict(self.doc["not_identified"])

    @property
    def diagnostics(self) -> dict:
        """R-hat, bulk and tail ESS per latent, acceptance per move, sweeps, burn-in, per chain."""
        return self.doc["diagnostics"]

    @property
    def converged(self) -> bool:
        """Every latent's R-hat <= 1.01 and bulk and tail ESS >= 400 (the targets in `diagnostics`)."""
        return bool(self.doc["converged"])

    @property
    def why_not(self) -> list[str]:
        """One line per latent that has not converged."""
        return list(self.doc["why_not"])

    @property
    def stopped(self) -> str | None:
        """Running until converged: "converged", "max_sweeps" or "max_seconds" (None otherwise)."""
        return self.doc.get("stopped")

    @property
    def notes(self) -> list[str]:
        """What the tracks say about themselves (nothing moves, the camera moved, ...)."""
        return list(self.doc["notes"])

    @property
    def samples(self) -> np.ndarray:
        """Every chain's state after every sweep, burn-in included: (chains, sweeps, latents)."""
        return np.asarray(self.record["samples"], float)

    @property
    def burn_in(self) -> int:
        """Sweeps left out of the posterior (the warm-up or the first half, whichever is longer)."""
        return int(self.doc["diagnostics"]["burn_in_sweeps"])

    def draws(self) -> dict[str, np.ndarray]:
        """The kept draws of each latent: {name: (chains, draws)}."""
        kept = self.samples[:, self.burn_in:]
        return {n: kept[..., j] for j, n in enumerate(self.names)}

    @property
    def units(self) -> dict[str, str]:
        """Each latent's unit, and each derived quantity's ("1": dimensionless)."""
        from . import registry

        units = {lat.name: lat.unit for lat in registry.of(self.scene).latents(self.scene) if lat.name in self.names}
        derived = [k for k in self.posterior_derived if not k.startswith("log_")]
        return {**{n: units.get(n, unit_of(n)) for n in self.names}, **{k: unit_of(k) for k in derived}}

    def derived_draws(self) -> dict[str, np.ndarray]:
        """The identified derived quantities (those `posterior_derived` summarises, logs aside) at
        every kept draw: {name: (chains, draws)}."""
        from . import registry

        scenario = registry.of(self.scene)
        keep = [k for k in self.posterior_derived if not k.startswith("log_")
                and not self.posterior_derived[k].get("fixed")]
        kept = self.samples[:, self.burn_in:]
        out = {k: np.empty(kept.shape[:2]) for k in keep}
        for c in range(kept.shape[0]):
            for d in range(kept.shape[1]):
                values = scenario.derived(self.scene, dict(zip(self.names, map(float, kept[c, d]))))
                for k in keep:
                    out[k][c, d] = values[k]
        return out

    def to_arviz(self):
        """ArviZ's data for this result: an `xarray.DataTree` with groups posterior (latents and the
        identified derived quantities, units as attributes), warmup_posterior, sample_stats (lp: the
        log-likelihood, acceptance, per-move acceptance), observed_data (the tracks, when known);
        see `galileo.inferencedata`. Save it with `.to_netcdf(path)` (or `.to_zarr(path)` with the
        zarr package installed) and reopen it with `xarray.open_datatree(path)`."""
        from .inferencedata import to_datatree

        rec = self.record
        proposals = {k[len("proposal_"):]: np.asarray(v) for k, v in rec.items() if k.startswith("proposal_")}
        codes = ((self.doc.get("config") or {}).get("moves") or {}).get("codes") or {}
        derived = self.derived_draws()
        units = self.units
        diag = self.diagnostics
        attrs = {"scenario": self.scenario, "converged": self.converged, "stopped": self.stopped,
                 "why_not": self.why_not, "r_hat": diag["r_hat"], "ess_bulk": diag["ess"], "ess_tail": diag["ess_tail"],
                 "rhat_target": diag["rhat_target"], "min_ess": diag["min_ess"], "map": self.map,
                 "not_identified": self.not_identified, "notes": self.notes, "config": self.doc.get("config"),
                 "inference_library": "galileo"}
        return to_datatree(names=self.names, units=units, samples=self.samples, logliks=np.asarray(rec["logliks"]),
                           proposals=proposals, burn_in=self.burn_in, codes=codes, derived=derived,
                           unidentified=self.not_identified, tracks=self.tracks, attrs=attrs)

    def save(self, path: str | Path) -> Path:
        """result.json at `path` and the sample record beside it (<stem>.samples.npz), as
        `galileo infer --out` writes them (atomically); the record's path."""
        from .results import write_result

        return write_result(path, self.doc, self.record)

    def summary(self) -> str:
        """What the video identifies, its 90% intervals and whether the chains converged (what
        `galileo infer` prints)."""
        from . import registry

        gone = self.not_identified
        lines = [f"MAP: {registry.of(self.scene).summary(self.scene, self.map, omit=gone) or '(nothing identified)'}"]
        by_why: dict[str, list[str]] = {}
        for name, why in gone.items():
            by_why.setdefault(why, []).append(name)
        lines += [f"not identified: {', '.join(names)}: {why}" for why, names in by_why.items()]
        for k, v in self.posterior_derived.items():
            if not k.startswith("log_"):
                lines.append(f"posterior {k}: {v['q50']:.3g} (90%: {v['q05']:.3g}-{v['q95']:.3g})")
        diag = self.diagnostics
        lines.append(f"{'converged' if self.converged else 'NOT converged'} after {diag['sweeps']} sweeps"
                     + ("" if self.converged else f" ({'; '.join(self.why_not[:2])}): the MAP may still be good, but "
                        "the intervals are not to be trusted; run on until converged: infer(..., until_rhat=1.01)"))
        return "\n".join(lines)

    def __repr__(self) -> str:
        return f"<galileo.Result {self.scenario}: {', '.join(self.names)}>\n{self.summary()}"


def load_result(path: str | Path, tracks=None) -> Result:
    """A result file (`galileo infer --out`, `Result.save`) with its sample record, as a `Result`
    (`tracks`: the observations, a Tracks, its file or a list, for `to_arviz`'s observed_data)."""
    from .results import load_result as read, load_samples

    rf = read(path)
    if rf.samples_path is None:
        raise GalileoError(f"{path}: no sample record beside it (samples_file): a Result needs the samples")
    record = load_samples(rf.samples_path)
    rf.samples()    # (checked against the result's latents)
    for key in ("latents", "posterior", "posterior_derived", "diagnostics", "not_identified", "notes"):
        if key not in rf.data:
            raise GalileoError(f"{path}: missing {key!r} (a result file from an older galileo? rerun galileo infer)")
    if isinstance(tracks, (str, Path)):
        tracks = load_tracks(tracks)
    elif isinstance(tracks, (list, tuple)):
        tracks = [load_tracks(t) if isinstance(t, (str, Path)) else t for t in tracks]
    return Result(rf.data, dict(record), rf.scene, tracks)


# -- questions, experiments, calibration ----------------------------------------------------------

def predict(result: Result | str | Path, **answers: Any) -> dict:
    """The paper's questions from a result (`galileo predict`): keyword arguments are the
    scenario's questions (the ramp's `target` True/False ...); a dict of answers. `result`: a
    `Result` or a result file."""
    import tempfile

    from . import registry

    if isinstance(result, Result):
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "result.json"
            result.save(path)
            return predict(path, **answers)
    from .joint import is_joint_json
    from .results import read_result_json

    d = read_result_json(result)
    if is_joint_json(d.get("scene")):
        raise GalileoError(f"{result} is a result over several videos or with fixed latents: predict answers for "
                           "one video's result with every latent inferred")
    scenario = registry.get(d.get("scenario", registry.DEFAULT))
    own = {q.name: q for q in scenario.questions}
    for name, value in answers.items():
        if name not in own:
            raise GalileoError(f"{name} is no question of the {scenario.name} scenario; it answers "
                               f"{', '.join(own) or 'none'}")
        q = own[name]
        if q.kind == "number" and q.bound is not None and value is not None and not q.bound.contains(value):
            raise GalileoError(f"{name} must be in {q.bound}, got {value:g}")
    out = scenario.predict(str(result), {name: answers.get(name) for name in own})
    if d.get("converged") is False:
        import warnings

        warnings.warn("these posterior shares come from chains that have not converged "
                      f"({(d.get('why_not') or ['?'])[0]}); trust the MAP answer, not the shares", stacklevel=2)
    return out


def experiment(dataset: str | Path, out: str | Path, *, client=None, workers: int | None = None,
               chains: int | None = None, sweeps: int | None = None, seed: int = 0, moves: str | None = None,
               priors: dict | None = None, until_rhat: float | None = None, min_ess: float | None = None,
               max_sweeps: int | None = None, max_seconds: float | None = None, granularity: str = "videos",
               recognition: str | Path | None = None, progress: bool = True) -> dict:
    """The paper's experiments over a rendered dataset (`galileo experiment`): every video tracked
    and inferred, OUT/report.md, results.parquet and results.csv written (a rerun resumes); the
    report as a dict. `client`: a `dask.distributed.Client` to run on (default: a local cluster of
    `workers` processes). In a script, call it under `if __name__ == "__main__":` (Dask's worker
    processes import the script that starts them); `granularity`: a Dask task per video or per chain ("chains");
    `recognition`: a `galileo recognize eval` folder whose figures join the report."""
    from . import batch, registry

    scenario, entries = batch.dataset_index(dataset)
    if registry.get(scenario).experiments is None:
        raise GalileoError(f"{Path(dataset) / 'index.json'}: no experiments for scenario {scenario!r}")
    cfg = run_config(registry.get(scenario), chains=chains, sweeps=sweeps, seed=seed, workers=1, moves=moves,
                     priors=priors, until_rhat=until_rhat, min_ess=min_ess, max_sweeps=max_sweeps,
                     max_seconds=max_seconds)
    batch.out_folder(Path(out))
    if client is not None:
        return batch.run_experiments(dataset, cfg, out, client, granularity=granularity, progress=progress,
                                     recognition=recognition)
    with batch.open_client(workers, None, None) as own:
        return batch.run_experiments(dataset, cfg, out, own, granularity=granularity, progress=progress,
                                     recognition=recognition)


def calibrate(scenario: str, out: str | Path, *, n: int | None = None, videos: str | Path | None = None,
              draws: int | None = None, scenes: str = "default", seed: int = 0, chains: int | None = None,
              sweeps: int | None = None, workers: int | None = None, moves: str | None = None,
              until_rhat: float | None = None, max_sweeps: int | None = None, progress: bool = True) -> dict:
    """Simulation-based calibration (`galileo calibrate`): `n` simulations from the prior, each
    inferred, their ranks and interval coverage (OUT/sbc.json and figures); or, with `videos` (a
    rendered dataset), interval coverage on its videos. The report as a dict."""
    return _calibrate(scenario, out, n=n, videos=videos, draws=draws, scenes=scenes, seed=seed, chains=chains,
                      sweeps=sweeps, workers=workers, moves=moves, until_rhat=until_rhat, max_sweeps=max_sweeps,
                      progress=progress, spell=lambda name: name)


def _calibrate(scenario: str, out: str | Path, *, n, videos, draws, scenes, seed, chains, sweeps, workers, moves,
               until_rhat, max_sweeps, progress, spell) -> dict:
    """`calibrate`, its errors naming each argument as `spell(name)` does (the CLI: its flags)."""
    from . import registry
    from .calibrate import DEFAULT_CHAINS, DEFAULT_DRAWS, DEFAULT_SWEEPS, coverage_on_videos, sbc

    chains = DEFAULT_CHAINS if chains is None else chains
    sweeps = DEFAULT_SWEEPS if sweeps is None else sweeps
    draws = DEFAULT_DRAWS if draws is None else draws
    # (an unknown scenario fails here, named)
    moves = moves_for(registry.get(scenario), moves, until_rhat, sweeps, max_sweeps=max_sweeps)
    for what, v, lo in (("chains", chains, 1), ("sweeps", sweeps, 1), ("draws", draws, 1),
                        ("workers", workers, 1), ("seed", seed, 0), ("n", n, 1)):
        if v is not None and v < lo:
            raise GalileoError(f"{spell(what)} must be at least {lo}, got {v}")
    if max_sweeps is not None and until_rhat is None:
        raise GalileoError(f"{spell('max_sweeps')} is the budget of {spell('until_rhat')}; without it, give "
                           f"{spell('sweeps')}")
    common = dict(seed=seed, chains=chains, sweeps=sweeps, workers=workers, moves=moves, until_rhat=until_rhat,
                  max_sweeps=max_sweeps, progress=progress)
    if (n is None) == (videos is None):
        raise GalileoError(f"give either {spell('n')} (simulations from the prior) or {spell('videos')} (a rendered "
                           f"dataset){', not both' if n is not None else ''}")
    if videos is not None:
        if not Path(videos).is_dir():
            raise GalileoError(f"{spell('videos')}: dataset folder not found: {videos}")
        return coverage_on_videos(videos, out, **common)
    scene = None
    if scenes not in ("default", "dataset"):
        scene = load_scene(scenes)
        if scene.scenario != scenario:
            raise GalileoError(f"{spell('scenes')} {scenes}: a {scene.scenario} scene, not {scenario}")
    return sbc(scenario, n, out, draws=draws, scenes=scenes, scene=scene, **common)
