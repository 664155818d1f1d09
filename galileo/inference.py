"""Inference: N single-site MH chains over Bullet, MAP, posterior summaries, diagnostics.

Galileo section 4: 16 chains x 75 sweeps per video, MAP over all samples of all chains.
Chains run in worker processes (each with its own pybullet client); chain c draws its
random numbers from SeedSequence(seed, spawn_key=(c,)), so a seed gives the same chains
whatever the number of workers. Initial positions are drawn from the prior with the same
seed. Every proposal is recorded (chain, sweep, latent, proposed values, log-likelihood,
accepted, stopped early); the viewer and sessions replay from this record.
"""
from __future__ import annotations

import multiprocessing as mp
import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from .errors import GalileoError
from .jsonio import atomic_write_bytes, write_json
from .scenarios.ramp.likelihood import SIGMA_MPS, VelocityLikelihood
from .mcmc import Proposal, run_chain
from .scenarios.ramp.scene import Scene
from .datatypes import Tracks

BURN_IN_FRACTION = 0.5  # posterior summaries and R-hat/ESS use the second half of each chain


def burn_in(n_sweeps: int) -> int:
    """Sweeps dropped from the start of a chain of `n_sweeps` before summarising it."""
    return int(n_sweeps * BURN_IN_FRACTION)


@dataclass
class InferenceConfig:
    chains: int = 16
    sweeps: int = 75
    seed: int = 0
    workers: int | None = None          # None: all cores
    sigma_mps: float = SIGMA_MPS
    speedups: bool = True
    proposal: Proposal = field(default_factory=Proposal)


def initial_positions(bounds: np.ndarray, n_chains: int, seed: int) -> np.ndarray:
    """Chain starts drawn uniformly from the prior (reproducible from the seed)."""
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(2**31,)))
    lo, hi = bounds[:, 0], bounds[:, 1]
    return lo + (hi - lo) * rng.uniform(size=(n_chains, len(bounds)))


# -- worker side ------------------------------------------------------------------------------

_worker_likelihood: VelocityLikelihood | None = None


def _worker_init(scene_json: dict, tracks_json: dict, sigma: float, speedups: bool) -> None:
    """Runs in each worker: the likelihood, built once (with the worker's own pybullet client)."""
    global _worker_likelihood
    import signal

    if mp.parent_process() is not None:  # in a worker: Ctrl-C is the parent's to handle
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    from .scenarios.ramp.scene import scene_from_json

    _worker_likelihood = VelocityLikelihood(scene_from_json(scene_json), Tracks.from_json(tracks_json),
                                            sigma, speedups)


def _worker_chain(args) -> dict:
    seed, chain, start, bounds, sweeps, proposal, speedups = args
    lik = _worker_likelihood
    t0 = time.perf_counter()
    steps0 = lik.steps
    positions, values, infos = run_chain(seed, chain, start, lik, bounds, sweeps, proposal, speedups)
    return {"chain": chain, "positions": positions, "logliks": values,
            "site": np.array([i.site for i in infos], np.int8),
            "proposal": np.array([i.proposal for i in infos]),
            "proposal_loglik": np.array([i.logdensity for i in infos]),
            "accepted": np.array([i.accepted for i in infos]),
            "early_stop": np.array([i.early_stop for i in infos]),
            "steps": lik.steps - steps0, "seconds": time.perf_counter() - t0}


# -- results ------------------------------------------------------------------------------------

@dataclass
class InferenceResult:
    names: tuple[str, ...]
    samples: np.ndarray          # (chains, sweeps, latents): state after each sweep
    logliks: np.ndarray          # (chains, sweeps)
    starts: np.ndarray           # (chains, latents)
    proposals: dict              # per-proposal arrays, each (chains, sweeps * latents, ...)
    config: InferenceConfig
    timing_s: dict
    steps: int
    scene: Scene                 # the scene inferred on (shapes and offset from tracking)

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
        burn = burn_in(self.samples.shape[1])
        return self.samples[:, burn:]

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
        from arviz_stats.base import array_stats

        kept = self.kept()
        acc = {}
        site = self.proposals["site"]
        accepted = self.proposals["accepted"]
        for j, n in enumerate(self.names):
            sel = site == j
            acc[n] = float(accepted[sel].mean()) if sel.any() else None
        r_hat, ess = {}, {}
        for j, n in enumerate(self.names):
            x = kept[..., j]
            if x.shape[0] >= 2 and x.shape[1] >= 4 and np.ptp(x) > 0:
                r_hat[n] = float(array_stats.rhat(x, chain_axis=0, draw_axis=1))
                ess[n] = float(array_stats.ess(x, chain_axis=0, draw_axis=1))
            else:
                r_hat[n], ess[n] = None, None
        early = self.proposals["early_stop"]
        return {"r_hat": r_hat, "ess": ess, "acceptance": acc, "acceptance_all": float(accepted.mean()),
                "early_stopped": float(early.mean()), "physics_steps": int(self.steps),
                "burn_in_sweeps": burn_in(self.samples.shape[1])}

    def mass_ratio(self) -> float | None:
        m = self.map
        return m["m1_kg"] / m["m2_kg"] if "m2_kg" in m else None

    def to_json(self) -> dict:
        cfg = self.config
        return {"map": self.map, "map_loglik": self.map_loglik, "mass_ratio": self.mass_ratio(),
                "posterior": self.posterior(), "diagnostics": self.diagnostics(), "timing_s": self.timing_s,
                "config": {"chains": cfg.chains, "sweeps": cfg.sweeps, "seed": cfg.seed, "workers": cfg.workers,
                           "sigma_mps": cfg.sigma_mps, "sigma_is": "standard deviation (m/s)",
                           "speedups": cfg.speedups,
                           "proposal": {"narrow": cfg.proposal.narrow, "broad": cfg.proposal.broad,
                                        "broad_every": cfg.proposal.broad_every}},
                "latents": list(self.names), "scene": self.scene.to_json(), "samples_file": None}

    def save(self, result_path: str | Path) -> Path:
        """result.json and, beside it, the full record as <stem>.samples.npz (no pickle)."""
        import io

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


def load_samples(npz_path: str | Path) -> dict[str, np.ndarray]:
    """The sample record written by `InferenceResult.save`."""
    try:
        with np.load(npz_path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError) as e:
        raise GalileoError(f"cannot read sample record {npz_path}: {e}") from None


def prior_bounds(scene: Scene, names) -> np.ndarray:
    return np.array([scene.priors.bounds[n] for n in names], float)


def infer(scene: Scene, tracks: Tracks, config: InferenceConfig | None = None, progress: bool = True) -> InferenceResult:
    """Run the chains; see the module docstring."""
    cfg = config or InferenceConfig()
    if cfg.chains < 1 or cfg.sweeps < 1:
        raise GalileoError("need at least one chain and one sweep")
    t0 = time.perf_counter()
    names = scene.latent_names
    bounds = prior_bounds(scene, names)
    starts = initial_positions(bounds, cfg.chains, cfg.seed)
    workers = max(1, min(cfg.workers or os.cpu_count() or 1, cfg.chains))
    tasks = [(cfg.seed, c, starts[c], bounds, cfg.sweeps, cfg.proposal, cfg.speedups) for c in range(cfg.chains)]
    init_args = (scene.to_json(), tracks.to_json(), cfg.sigma_mps, cfg.speedups)
    bar = tqdm(total=cfg.chains, desc="chains", unit="chain", disable=not progress)
    results = []
    if workers == 1:
        _worker_init(*init_args)
        for t in tasks:
            results.append(_worker_chain(t))
            bar.update()
    else:
        ctx = mp.get_context("fork")
        with ProcessPoolExecutor(workers, mp_context=ctx, initializer=_worker_init, initargs=init_args) as pool:
            for r in pool.map(_worker_chain, tasks):
                results.append(r)
                bar.update()
    bar.close()
    results.sort(key=lambda r: r["chain"])
    from .scenarios.ramp.likelihood import scene_for_inference

    proposals = {k: np.stack([r[k] for r in results]) for k in
                 ("site", "proposal", "proposal_loglik", "accepted", "early_stop")}
    wall = time.perf_counter() - t0
    return InferenceResult(
        names=tuple(names), samples=np.stack([r["positions"] for r in results]),
        logliks=np.stack([r["logliks"] for r in results]), starts=starts, proposals=proposals, config=cfg,
        timing_s={"wall": wall, "chains_cpu": float(sum(r["seconds"] for r in results)), "workers": workers},
        steps=int(sum(r["steps"] for r in results)), scene=scene_for_inference(scene, tracks))
