"""Inference results: MAP, posterior summaries, diagnostics (arviz-stats), save and load.

`diagnostics` is the one place R-hat and ESS are computed, for the batch result and for the
app's live status alike: over the chains' kept draws (burn-in: the first half, or the warm-up
if longer), each cut to the shortest, needing at least 2 chains of at least 4 kept draws and
a latent that moved. R-hat is arviz-stats' rank-normalised split R-hat (Vehtari et al. 2021);
ESS its bulk and tail ESS. `convergence` turns them into a verdict: converged when every
latent's R-hat is at most RHAT_TARGET (1.01) and its bulk and tail ESS at least MIN_ESS
(400), and otherwise the reasons why not.

Files: `result.json` (MAP, posterior, diagnostics, settings, the scene inferred on) and,
beside it, `<stem>.samples.npz`, the full record (no pickle): names, samples (C, S, D),
logliks (C, S), starts (C, D) and per proposal `proposal_<field>` (C, S * D, ...).
"""
from __future__ import annotations

import io
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from . import registry
from .errors import GalileoError
from .jsonio import atomic_write_bytes, write_json

MIN_KEPT_DRAWS = 4
BURN_IN_FRACTION = 0.5  # posterior summaries and R-hat/ESS use the second half of each chain
RHAT_TARGET = 1.01      # what "converged" means (Vehtari et al. 2021)
EDGE_FRACTION = 0.01    # a MAP this close to a prior bound (a fraction of the prior's width) is at its edge
MIN_ESS = 400           # bulk and tail ESS, per latent


def burn_in(n_sweeps: int, warmup: int = 0) -> int:
    """Sweeps dropped from the start of a chain of `n_sweeps` before summarising it: the first
    half, or the warm-up (widths adapting) if that is longer."""
    return min(int(n_sweeps), max(int(n_sweeps * BURN_IN_FRACTION), int(warmup)))


def _stack(kept: Sequence[np.ndarray]) -> np.ndarray | None:
    kept = [k for k in kept if len(k) >= MIN_KEPT_DRAWS]
    if len(kept) < 2:
        return None
    length = min(len(k) for k in kept)
    return np.stack([k[len(k) - length:] for k in kept])   # (chains, draws, D)


def chain_stats(kept: Sequence[np.ndarray], names: Sequence[str]) -> dict:
    """{"r_hat", "ess_bulk", "ess_tail"}: per latent, None where not computable."""
    out = {k: {n: None for n in names} for k in ("r_hat", "ess_bulk", "ess_tail")}
    x = _stack(kept)
    if x is None:
        return out
    from arviz_stats.base import array_stats

    for j, n in enumerate(names):
        xj = x[..., j]
        if np.ptp(xj) > 0:
            for key, fn in (("r_hat", lambda a: array_stats.rhat(a, chain_axis=0, draw_axis=1)),
                            ("ess_bulk", lambda a: array_stats.ess(a, chain_axis=0, draw_axis=1, method="bulk")),
                            ("ess_tail", lambda a: array_stats.ess(a, chain_axis=0, draw_axis=1, method="tail", prob=(0.05, 0.95)))):
                with np.errstate(divide="ignore", invalid="ignore"):   # a chain that never moved: None
                    v = float(fn(xj))
                out[key][n] = v if math.isfinite(v) else None
    return out


def convergence(kept: Sequence[np.ndarray], names: Sequence[str], rhat_target: float = RHAT_TARGET,
                min_ess: float = MIN_ESS) -> dict:
    """The verdict on per-chain kept draws: {"converged", "why_not" (one line per failing
    latent), "per_latent" {name: True/False}, "r_hat", "ess_bulk", "ess_tail", "rhat_target",
    "min_ess", "summary" (one short line)}."""
    st = chain_stats(kept, names)
    why, ok = [], {}
    for n in names:
        r, eb, et = st["r_hat"][n], st["ess_bulk"][n], st["ess_tail"][n]
        if r is None:
            why.append(f"{n}: R-hat cannot be computed (fewer than 2 chains of {MIN_KEPT_DRAWS} kept draws, "
                       "or the latent never moved)")
            ok[n] = False
            continue
        parts = []
        if r > rhat_target:
            parts.append(f"R-hat {r:.3f} > {rhat_target:g}")
        low = min(x for x in (eb, et) if x is not None) if (eb is not None or et is not None) else None
        if low is None or low < min_ess:
            parts.append(f"ESS {0 if low is None else low:.0f} < {min_ess:g}")
        ok[n] = not parts
        if parts:
            why.append(f"{n}: " + ", ".join(parts))
    rs = [v for v in st["r_hat"].values() if v is not None]
    es = [v for d in (st["ess_bulk"], st["ess_tail"]) for v in d.values() if v is not None]
    summary = (f"R-hat max {max(rs):.3f}" if rs else "R-hat n/a") + (f", ESS min {min(es):.0f}" if es else "")
    return {"converged": not why, "why_not": why, "per_latent": ok, **st, "rhat_target": float(rhat_target),
            "min_ess": float(min_ess), "summary": summary}


def kept_draws(samples: Sequence[np.ndarray], warmup: int = 0) -> list[np.ndarray]:
    """Each chain's samples after burn-in."""
    return [s[burn_in(len(s), warmup):] for s in samples]


@dataclass
class InferenceResult:
    scenario: str
    names: tuple[str, ...]
    samples: np.ndarray          # (chains, sweeps, latents): state after each sweep
    logliks: np.ndarray          # (chains, sweeps)
    starts: np.ndarray           # (chains, latents)
    proposals: dict              # per-proposal arrays, each (chains, sweeps * latents, ...)
    config: object               # galileo.runner.RunConfig
    settings: object             # galileo.runner.Settings (what was in force)
    timing_s: dict
    steps: int
    scene: object                # the scene inferred on (what tracking fixed put in)
    init: dict | None = None     # how chains started (prior / recognition: the readings) and extra moves
    warmup: int = 0              # sweeps of width adaptation (dropped from the summaries with the burn-in)
    moves: dict | None = None    # {"set": default|paper|fitted, "joint": names, "codes": {name: site code(s)}, "adapted"}
    notes: tuple = ()            # what the observations say about themselves (e.g. nothing moves), shown to users
    tracks: object = None        # the tracks inferred from (a problem's list), if known: what they identify
    stopped: str | None = None   # running until converged: "converged", "max_sweeps" or "max_seconds" (its budgets)

    @property
    def map_index(self) -> tuple[int, int]:
        c, s = np.unravel_index(int(np.argmax(self.logliks)), self.logliks.shape)
        return int(c), int(s)

    @property
    def map(self) -> dict[str, float]:
        c, s = self.map_index
        return {n: float(v) for n, v in zip(self.names, self.samples[c, s])}

    @property
    def map_loglik(self) -> float:
        return float(self.logliks.max())

    def kept(self) -> np.ndarray:
        return self.samples[:, burn_in(self.samples.shape[1], self.warmup):]

    def kept_logliks(self) -> np.ndarray:
        return self.logliks[:, burn_in(self.logliks.shape[1], self.warmup):]

    def convergence(self) -> dict:
        cfg = self.config
        return convergence(list(self.kept()), self.names, getattr(cfg, "until_rhat", None)
                           or getattr(cfg, "rhat_target", RHAT_TARGET), getattr(cfg, "min_ess", MIN_ESS))

    def derived_posterior(self, gone: dict | None = None) -> dict[str, dict]:
        """Posterior summaries of the scenario's derived quantities (e.g. the ramp's mass
        ratio, the identified quantity), one value per kept draw; a positive quantity also gets
        its log's summary (`log_<name>`)."""
        return identified(derived_summaries(registry.of(self.scene), self.scene, self.names,
                                            self.kept().reshape(-1, len(self.names))),
                          self.unidentified() if gone is None else gone)

    def unidentified(self) -> dict[str, str]:
        """What the video(s) do not identify, with why (`Scenario.not_identified`; result.json's
        "not_identified"): such a derived quantity gets no point estimate and no summary."""
        return registry.of(self.scene).unidentified(self.scene, self.tracks)

    def per_chain(self) -> list[dict]:
        """Per chain: acceptance, its kept log-likelihood (median, max), its kept mean of each
        latent, and the first sweep within 1 nat of the MAP."""
        kept, ll = self.kept(), self.kept_logliks()
        acc = self.proposals["accepted"]
        to_map = sweeps_to_map(self.logliks)["per_chain"]
        out = []
        for c in range(self.samples.shape[0]):
            out.append({"chain": c, "acceptance": float(acc[c].mean()) if acc[c].size else None,
                        "loglik_kept_median": float(np.median(ll[c])) if ll[c].size else None,
                        "loglik_kept_max": float(ll[c].max()) if ll[c].size else None,
                        "mean": {n: float(kept[c, :, j].mean()) for j, n in enumerate(self.names)} if kept.shape[1] else None,
                        "sweeps_to_map_1nat": to_map[c]})
        return out

    def posterior(self) -> dict[str, dict]:
        kept = self.kept()
        return {n: _summary(kept[..., j].ravel()) for j, n in enumerate(self.names)}

    def diagnostics(self) -> dict:
        conv = self.convergence()
        site, accepted = self.proposals["site"], self.proposals["accepted"]
        acc = {}
        for j, n in enumerate(self.names):
            sel = site == j
            acc[n] = float(accepted[sel].mean()) if sel.any() else None
        codes = (self.moves or {}).get("codes") or ({"independence": -1} if (site == -1).any() else {})
        for name, code in codes.items():   # joint moves: the independence move, the scenario's moves
            sel = np.isin(site, code)      # (a move made several times a sweep has a list of codes)
            if sel.any():
                acc[f"{name}_move"] = float(accepted[sel].mean())
        return {"r_hat": conv["r_hat"], "ess": conv["ess_bulk"], "ess_tail": conv["ess_tail"],
                "converged": conv["converged"], "why_not": conv["why_not"], "per_latent_converged": conv["per_latent"],
                "rhat_target": conv["rhat_target"], "min_ess": conv["min_ess"],
                "acceptance": acc, "acceptance_all": float(accepted.mean()),
                "sweeps_to_map_1nat": sweeps_to_map(self.logliks),
                "early_stopped": float(self.proposals["early_stop"].mean()), "physics_steps": int(self.steps),
                "burn_in_sweeps": burn_in(self.samples.shape[1], self.warmup), "warmup_sweeps": int(self.warmup),
                "sweeps": int(self.samples.shape[1]), "per_chain": self.per_chain()}

    def derived(self, gone: dict | None = None) -> dict:
        """The scenario's derived quantities at the MAP (None for one not identified; `gone`:
        `unidentified()`, if the caller has it)."""
        gone = self.unidentified() if gone is None else gone
        return {k: None if k in gone else v for k, v in registry.of(self.scene).derived(self.scene, self.map).items()}

    def at_prior_edge(self, gone: dict | None = None) -> list[str]:
        """The latents whose MAP lies within EDGE_FRACTION of its prior's width from a bound that
        is not the latent's own limit: the data pull past what the prior allows (a prior too
        narrow, or the model missing something that the latent bends to absorb); such a MAP is
        not an estimate of that latent. A latent the video does not identify (`unidentified`) is
        not said: its posterior is its prior's."""
        specs = getattr(self.scene, "latent_specs", None)
        gone = self.unidentified() if gone is None else gone
        limits = {lat.name: lat.limits for lat in specs()} if specs is not None else {}
        out = []
        for n, v in self.map.items():
            if n in gone:
                continue
            lo, hi = self.settings.bounds[n]
            low, high = limits.get(n, (-math.inf, math.inf))
            near = EDGE_FRACTION * (hi - lo)
            # a bound at the latent's own limit (a push of 0, a friction of 0) is no prior to widen
            if (v - lo <= near and lo > low) or (hi - v <= near and hi < high):
                out.append(n)
        return out

    def mass_ratio(self) -> float | None:
        return self.derived().get("mass_ratio")

    def to_json(self) -> dict:
        cfg, st = self.config, self.settings
        p = st.proposal()
        config = {"chains": cfg.chains, "sweeps": cfg.sweeps, "seed": cfg.seed, "workers": cfg.workers,
                  st.noise_spec.name: st.noise, "sigma_is": f"standard deviation ({st.noise_spec.unit})",
                  "speedups": cfg.speedups,
                  "proposal": {"narrow": _plain(p.narrow), "broad": _plain(p.broad), "broad_every": p.broad_every},
                  "bounds": {k: list(v) for k, v in st.bounds.items()},
                  "moves": self.moves or {"set": getattr(cfg, "moves", "paper")},
                  "until_rhat": getattr(cfg, "until_rhat", None), "min_ess": getattr(cfg, "min_ess", None),
                  "max_sweeps": cfg.sweep_budget() if getattr(cfg, "until_rhat", None) else None,
                  "max_seconds": getattr(cfg, "max_seconds", None)}
        diag = self.diagnostics()
        gone = self.unidentified()   # (once: the derived values, the prior-edge check and the summaries use it)
        return {"scenario": self.scenario, "map": self.map, "map_loglik": self.map_loglik, **self.derived(gone),
                "converged": diag["converged"], "why_not": diag["why_not"], "stopped": self.stopped,
                "notes": list(self.notes),
                "map_at_prior_edge": self.at_prior_edge(gone),
                "init": self.init or {"starts": "prior"},
                "not_identified": gone,
                "posterior": self.posterior(), "posterior_derived": self.derived_posterior(gone),
                "diagnostics": diag, "timing_s": self.timing_s,
                "config": config, "latents": list(self.names), "scene": self.scene.to_json(), "samples_file": None}

    def warning(self) -> str | None:
        """One line for users when the posterior comes from chains that have not converged."""
        return warning_of(self.convergence())

    def record(self) -> dict[str, np.ndarray]:
        """The full sample record, as <stem>.samples.npz holds it (the module docstring)."""
        return {"names": np.array(self.names), "samples": self.samples, "logliks": self.logliks,
                "starts": self.starts, **{f"proposal_{k}": v for k, v in self.proposals.items()}}

    def save(self, result_path: str | Path, doc: dict | None = None) -> Path:
        """result.json and, beside it, the full record as <stem>.samples.npz (no pickle);
        `doc`: `to_json()` if the caller has it already."""
        return write_result(result_path, self.to_json() if doc is None else doc, self.record())


def write_result(result_path: str | Path, doc: dict, record: dict) -> Path:
    """Write result.json (`doc`, naming its record) and the record beside it as
    <stem>.samples.npz, each atomically; the record's path."""
    result_path = Path(result_path)
    npz_path = result_path.with_name(result_path.stem + ".samples.npz")
    buf = io.BytesIO()
    np.savez_compressed(buf, **record)
    atomic_write_bytes(npz_path, buf.getvalue())
    write_json(result_path, {**doc, "samples_file": npz_path.name})
    return npz_path


def sweeps_to_map(logliks: np.ndarray, within_nats: float = 1.0, reference: float | None = None) -> dict:
    """Per chain, the first sweep (1-based) after which its log-likelihood is within
    `within_nats` of the run's MAP (or of `reference`); None if it never is (Galileo Fig. 4's
    measure). The median counts chains that never get there as slower than any that do
    (None when more than half never do)."""
    ll = np.asarray(logliks, float)
    target = (float(ll.max()) if reference is None else float(reference)) - within_nats
    per_chain = []
    for row in ll:
        hit = np.flatnonzero(row >= target)
        per_chain.append(int(hit[0]) + 1 if len(hit) else None)
    ranks = np.array([np.inf if v is None else v for v in per_chain], float)
    med = float(np.median(ranks)) if len(ranks) else None
    return {"per_chain": per_chain, "median": med if med is not None and np.isfinite(med) else None,
            "never": float(np.mean([v is None for v in per_chain])) if per_chain else None,
            "within_nats": within_nats}


def warning_of(verdict: dict) -> str | None:
    """The one-line warning for a `convergence` verdict (or a result's diagnostics); None when
    converged."""
    if verdict["converged"]:
        return None
    why = verdict["why_not"]
    more = f" (and {len(why) - 1} more)" if len(why) > 1 else ""
    return (f"the posterior is not converged: {why[0]}{more}; the MAP may still be good, but intervals and "
            "shares are not to be trusted (run longer: until converged, galileo infer's default without --sweeps N, "
            "with a larger --max-seconds S or --max-sweeps N)")


def derived_summaries(scenario, scene, names: Sequence[str], rows) -> dict[str, dict]:
    """Posterior summaries of `scenario.derived` over draws `rows` (each a latent vector in
    `names` order): per quantity defined and finite at every draw, its summary, and its log's
    (`log_<name>`) when it is positive throughout. A quantity that stays the same while the
    draws vary (the splash's volume: the scene's, not inferred) is marked `"fixed": true`, and
    has no log: it is not a posterior."""
    rows = [np.asarray(r, float) for r in rows]
    draws_vary = len(rows) > 1 and bool(np.ptp(np.stack(rows), axis=0).max() > 0)
    values: dict[str, list] = {}
    for row in rows:
        for k, v in scenario.derived(scene, dict(zip(names, map(float, row)))).items():
            if v is not None:
                values.setdefault(k, []).append(float(v))
    out = {}
    for k, v in values.items():
        x = np.asarray(v)
        if len(x) != len(rows) or not np.all(np.isfinite(x)):
            continue
        out[k] = _summary(x)
        if draws_vary and np.ptp(x) == 0:
            out[k]["fixed"] = True
        elif np.all(x > 0):
            out[f"log_{k}"] = _summary(np.log(x))
    return out


def identified(summaries: dict[str, dict], unidentified: dict[str, str]) -> dict[str, dict]:
    """`derived_summaries` less the quantities not identified (and their logs): no interval for them."""
    return {k: v for k, v in summaries.items()
            if k not in unidentified and not (k.startswith("log_") and k[4:] in unidentified)}


def _summary(x: np.ndarray) -> dict:
    x = np.asarray(x, float).ravel()
    q5, q25, q50, q75, q95 = np.quantile(x, [0.05, 0.25, 0.5, 0.75, 0.95])
    return {"mean": float(x.mean()), "sd": float(x.std(ddof=1)) if x.size > 1 else 0.0,
            "q05": float(q5), "q25": float(q25), "q50": float(q50), "q75": float(q75), "q95": float(q95)}


def _plain(w):
    return list(w) if isinstance(w, tuple) else w


def load_samples(npz_path: str | Path) -> dict[str, np.ndarray]:
    """The sample record written by `InferenceResult.save`."""
    import zipfile
    import zlib

    try:
        z = np.load(npz_path, allow_pickle=False)
        if not hasattr(z, "files"):   # a single .npy array, not a record
            raise ValueError("not an .npz record of named arrays")
        with z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error) as e:
        raise ResultError(f"cannot read sample record {npz_path}: {e}") from None


# -- reading a result file back (galileo predict, the library) -------------------------------------
# What `InferenceResult.save` writes and `load_result` checks, each problem one line naming
# the field:
#   scenario      a known scenario's name (default "ramp", the format before scenarios had names)
#   scene         that scenario's scene (its own parser's rules)
#   latents       optional: the latent names, each once (default: the map's keys); they must
#                 be the latents the scene infers
#   map           a finite number for every latent, none for anything else, each within the
#                 latent's limits (a mass above 0, ...)
#   samples_file  null, or a plain file name beside the result file (no folder part: the
#                 record goes where the result goes) that exists; its samples (C, S, D) finite,
#                 D the latents, its names the latents
#   converged     optional true/false; why_not optional list of strings;
#   diagnostics.warmup_sweeps  optional integer >= 0

class ResultError(GalileoError):
    """A result file that does not hold together (one line, naming the file and field)."""


@dataclass
class ResultFile:
    """A checked result file: its scenario, scene, latents, MAP and where its samples are."""
    path: Path
    scenario: str
    scene: object
    names: tuple[str, ...]
    map: dict[str, float]
    converged: bool | None
    why_not: list[str]
    warmup: int
    samples_path: Path | None
    data: dict

    def samples(self) -> np.ndarray | None:
        """The record's samples (chains, sweeps, latents), checked; None without a record."""
        if self.samples_path is None:
            return None
        rec = load_samples(self.samples_path)
        where = f"sample record {self.samples_path}"
        s = rec.get("samples")
        if s is None:
            raise ResultError(f"{where}: no samples array")
        if s.ndim != 3 or s.shape[0] < 1 or s.shape[1] < 1 or s.shape[2] != len(self.names):
            raise ResultError(f"{where}: samples of shape {tuple(s.shape)}, expected (chains, sweeps, "
                              f"{len(self.names)}) for the latents {', '.join(self.names)}")
        if not np.issubdtype(s.dtype, np.number) or not np.all(np.isfinite(s)):
            raise ResultError(f"{where}: samples are not all finite numbers")
        names = rec.get("names")
        if names is not None and tuple(str(n) for n in np.ravel(names)) != self.names:
            raise ResultError(f"{where}: names {[str(n) for n in np.ravel(names)]} are not the result's latents "
                              f"{list(self.names)} (the record of another result?)")
        return s.astype(float)


def read_result_json(path: str | Path) -> dict:
    """A result file's JSON, with its top level checked: an object naming a known scenario."""
    from .jsonio import read_json

    d = read_json(path, "result file")
    if not isinstance(d, dict):
        raise ResultError(f"{path} is not a galileo result file: expected a JSON object at the top level")
    name = d.get("scenario", registry.DEFAULT)
    if not isinstance(name, str):
        raise ResultError(f"result file {path}: scenario: expected a name, got {name!r}")
    if name not in registry.names():
        raise ResultError(f"result file {path}: scenario: unknown scenario {name!r}; known: "
                          f"{', '.join(registry.names())}")
    return d


def load_result(path: str | Path) -> ResultFile:
    """A result file written by `InferenceResult.save`, every field `predict` uses checked
    (see the comment above); ResultError naming the field otherwise."""
    path = Path(path)
    d = read_result_json(path)
    for key in ("scene", "map"):
        if key not in d:
            raise ResultError(f"{path} is not a galileo result file: missing {key!r}")
    where = f"result file {path}"
    name = d.get("scenario", registry.DEFAULT)
    scene_d = d["scene"]
    if not isinstance(scene_d, dict):
        raise ResultError(f"{where}: scene: expected an object")
    try:
        scene_name = registry.name_in(scene_d)
    except GalileoError as e:
        raise ResultError(f"{where}: scene.{e}") from None
    if scene_name != name:
        raise ResultError(f"{where}: scene: a {scene_name!r} scene in a {name!r} result")
    try:
        scene = registry.scene_from_json(scene_d)
    except GalileoError as e:
        raise ResultError(f"{where}: scene: {e}") from None
    m = d["map"]
    if not isinstance(m, dict) or not m:
        raise ResultError(f"{where}: map: expected an object of latent values, got {m!r}")
    try:
        specs = {lat.name: lat for lat in registry.of(scene).latents(scene)}
    except GalileoError as e:
        raise ResultError(f"{where}: scene: {e}") from None
    latents = d.get("latents", list(specs))   # (results before the field: the scene's)
    if (not isinstance(latents, list) or not latents or not all(isinstance(n, str) and n for n in latents)
            or len(set(latents)) != len(latents)):
        raise ResultError(f"{where}: latents: expected a list of latent names, each once, got {latents!r}")
    if set(latents) != set(specs):
        raise ResultError(f"{where}: latents: {latents} are not the latents its scene infers ({', '.join(specs)})")
    for n in latents:
        if n not in m:
            raise ResultError(f"{where}: map: lacks latent {n!r} (the result's latents: {', '.join(latents)})")
    for k, v in m.items():
        if k not in specs:
            raise ResultError(f"{where}: map.{k}: not a latent of this result ({', '.join(latents)})")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ResultError(f"{where}: map.{k}: expected a finite number, got {v!r}")
        lo, hi = specs[k].limits
        if v < lo or v > hi or (specs[k].limits_open_low and v == lo):
            bound = f"({lo:g}, {hi:g}]" if specs[k].limits_open_low else f"[{lo:g}, {hi:g}]"
            raise ResultError(f"{where}: map.{k}: {v:g} is outside {bound}")
    converged = d.get("converged")
    if converged is not None and not isinstance(converged, bool):
        raise ResultError(f"{where}: converged: expected true or false, got {converged!r}")
    why_not = d.get("why_not") or []
    if not isinstance(why_not, list) or not all(isinstance(w, str) for w in why_not):
        raise ResultError(f"{where}: why_not: expected a list of strings, got {why_not!r}")
    diag = d.get("diagnostics") or {}
    if not isinstance(diag, dict):
        raise ResultError(f"{where}: diagnostics: expected an object")
    warmup = diag.get("warmup_sweeps", 0)
    if isinstance(warmup, bool) or not isinstance(warmup, int) or warmup < 0:
        raise ResultError(f"{where}: diagnostics.warmup_sweeps: expected an integer >= 0, got {warmup!r}")
    samples_path = None
    sf = d.get("samples_file")
    if sf is not None:
        if not isinstance(sf, str) or not sf or sf in (".", "..") or Path(sf).name != sf or "\\" in sf:
            raise ResultError(f"{where}: samples_file: expected the name of a file beside the result file (no "
                              f"folder), got {sf!r}")
        samples_path = path.with_name(sf)
        if not samples_path.is_file():
            raise ResultError(f"{where}: samples_file: {sf} is not beside it in {path.parent} (copy the .samples.npz "
                              "there, or set samples_file to null to predict from the MAP alone)")
    return ResultFile(path, name, scene, tuple(latents), {k: float(v) for k, v in m.items()}, converged,
                      list(why_not), int(warmup), samples_path, d)
