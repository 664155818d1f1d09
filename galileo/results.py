"""Inference results: MAP, posterior summaries, diagnostics (arviz-stats), save and load.

`diagnostics` is the one place R-hat and ESS are computed, for the batch result and for the
app's live status alike: over the chains' second halves (burn-in: the first half), each cut
to the shortest, needing at least 2 chains of at least 4 kept draws and a latent that moved.

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


def burn_in(n_sweeps: int) -> int:
    """Sweeps dropped from the start of a chain of `n_sweeps` before summarising it."""
    return int(n_sweeps * BURN_IN_FRACTION)


def rhat_ess(kept: Sequence[np.ndarray], names: Sequence[str]) -> tuple[dict, dict]:
    """Split R-hat and bulk ESS per latent from per-chain kept draws (each (n_i, D)); None
    where they cannot be computed (fewer than 2 chains of MIN_KEPT_DRAWS, a constant latent)."""
    r_hat = {n: None for n in names}
    ess = {n: None for n in names}
    kept = [k for k in kept if len(k) >= MIN_KEPT_DRAWS]
    if len(kept) < 2:
        return r_hat, ess
    from arviz_stats.base import array_stats

    length = min(len(k) for k in kept)
    x = np.stack([k[len(k) - length:] for k in kept])   # (chains, draws, D)
    for j, n in enumerate(names):
        xj = x[..., j]
        if np.ptp(xj) > 0:
            r, e = float(array_stats.rhat(xj, chain_axis=0, draw_axis=1)), float(
                array_stats.ess(xj, chain_axis=0, draw_axis=1))
            r_hat[n] = r if math.isfinite(r) else None
            ess[n] = e if math.isfinite(e) else None
    return r_hat, ess


def kept_draws(samples: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Each chain's samples after burn-in."""
    return [s[burn_in(len(s)):] for s in samples]


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
        return self.samples[:, burn_in(self.samples.shape[1]):]

    def posterior(self) -> dict[str, dict]:
        kept = self.kept()
        out = {}
        for j, n in enumerate(self.names):
            x = kept[..., j].ravel()
            q5, q50, q95 = np.quantile(x, [0.05, 0.5, 0.95])
            out[n] = {"mean": float(x.mean()), "sd": float(x.std(ddof=1)) if x.size > 1 else 0.0,
                      "q05": float(q5), "q50": float(q50), "q95": float(q95)}
        return out

    def diagnostics(self) -> dict:
        r_hat, ess = rhat_ess(list(self.kept()), self.names)
        site, accepted = self.proposals["site"], self.proposals["accepted"]
        acc = {}
        for j, n in enumerate(self.names):
            sel = site == j
            acc[n] = float(accepted[sel].mean()) if sel.any() else None
        if (site == -1).any():   # the joint independence move (--recognition-move)
            acc["independence_move"] = float(accepted[site == -1].mean())
        return {"r_hat": r_hat, "ess": ess, "acceptance": acc, "acceptance_all": float(accepted.mean()),
                "sweeps_to_map_1nat": sweeps_to_map(self.logliks),
                "early_stopped": float(self.proposals["early_stop"].mean()), "physics_steps": int(self.steps),
                "burn_in_sweeps": burn_in(self.samples.shape[1])}

    def derived(self) -> dict:
        return registry.get(self.scenario).derived(self.scene, self.map)

    def mass_ratio(self) -> float | None:
        return self.derived().get("mass_ratio")

    def to_json(self) -> dict:
        cfg, st = self.config, self.settings
        p = st.proposal()
        config = {"chains": cfg.chains, "sweeps": cfg.sweeps, "seed": cfg.seed, "workers": cfg.workers,
                  st.noise_spec.name: st.noise, "sigma_is": f"standard deviation ({st.noise_spec.unit})",
                  "speedups": cfg.speedups,
                  "proposal": {"narrow": _plain(p.narrow), "broad": _plain(p.broad), "broad_every": p.broad_every},
                  "bounds": {k: list(v) for k, v in st.bounds.items()}}
        return {"scenario": self.scenario, "map": self.map, "map_loglik": self.map_loglik, **self.derived(),
                "init": self.init or {"starts": "prior"},
                "posterior": self.posterior(), "diagnostics": self.diagnostics(), "timing_s": self.timing_s,
                "config": config, "latents": list(self.names), "scene": self.scene.to_json(), "samples_file": None}

    def save(self, result_path: str | Path) -> Path:
        """result.json and, beside it, the full record as <stem>.samples.npz (no pickle)."""
        result_path = Path(result_path)
        npz_path = result_path.with_name(result_path.stem + ".samples.npz")
        buf = io.BytesIO()
        np.savez_compressed(buf, names=np.array(self.names), samples=self.samples, logliks=self.logliks,
                            starts=self.starts, **{f"proposal_{k}": v for k, v in self.proposals.items()})
        atomic_write_bytes(npz_path, buf.getvalue())
        d = self.to_json()
        d["samples_file"] = npz_path.name
        write_json(result_path, d)
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


def _plain(w):
    return list(w) if isinstance(w, tuple) else w


def load_samples(npz_path: str | Path) -> dict[str, np.ndarray]:
    """The sample record written by `InferenceResult.save`."""
    try:
        with np.load(npz_path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError) as e:
        raise GalileoError(f"cannot read sample record {npz_path}: {e}") from None
