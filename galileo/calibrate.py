"""Calibration of the posterior (`galileo calibrate`): simulation-based calibration (SBC,
Talts et al. 2018) on observations simulated from the prior, and interval coverage on a
rendered dataset with ground truth.

SBC, simulation i = 0..n-1 (each its own task; a worker runs one `infer` with workers=1):

1. a scene: the scenario's default scene, a fixed one, or (`scenes="dataset"`) a random
   scene like its dataset's (the scenario's `synthetic.random_scene(rng)`);
2. the truth theta_i drawn from the prior: uniform on the scene's prior bounds;
3. observations y_i = `Scenario.synthetic.tracks(scene, theta_i, rng, noise)`: what the
   likelihood assumes (for the ramp: its own simulated motion plus iid noise of the scene's
   observation model, Gaussian or Student-t, on each velocity component), no rendering or
   tracking; the scene is the one the move set infers on (`runner.scene_for_moves`);
4. the posterior p(theta | y_i) by `galileo.runner.infer` (chains, sweeps, moves as given);
   its kept draws (after burn-in, all chains) thinned evenly to L draws;
5. the rank of theta_i among the L draws, per latent and per derived quantity (the ramp: the
   log mass ratio log(m1/m2) when the scene has a target), ties broken at random; and
   whether theta_i lies in the central 50% and 90% intervals of all kept draws.

If the posteriors are right (an exact sampler, run long enough, on the model the data come
from), each rank is uniform on 0..L and each interval covers the truth at its nominal rate.
Too narrow posteriors put the ranks at the ends (a U-shaped histogram) and cover too little;
too wide ones pile them in the middle; a biased one tilts them.

Uniformity test (per quantity): the ranks are turned into randomised PIT values
u = (rank + V) / (L + 1), V ~ U(0, 1), exactly uniform on (0, 1) when the ranks are uniform
on 0..L, and tested by the ECDF test of Saeilynoja, Buerkner & Vehtari (2022, "Graphical
test for discrete uniformity and its applications in goodness-of-fit evaluation and
multiple sample comparison", Statistics and Computing 32:32): the statistic is the smallest
two-sided pointwise binomial tail probability of the ECDF over the grid z_j = j / n,
j = 1..n-1; its null distribution is simulated (UNIFORM_SIMULATIONS uniform samples of the
same size, seeded), so p = P_null(statistic <= observed). Its simultaneous band at level BAND
(the pointwise level at which a uniform sample's ECDF stays inside the band everywhere with
probability BAND) is what the ECDF plots draw: the ECDF leaves it exactly when p < 1 - BAND.
This is the method of arviz-stats' `ecdf_utils.simulate_confidence_bands` (and of arviz-plots'
`plot_ecdf_pit`), written out here with scipy's binomial functions because that module needs
xarray and arviz-base, which Galileo does not install. A chi-square test of the rank
histogram's counts (B equal bins, n / B >= 5) is reported beside it (`p_chi2`).

Coverage: the share of simulations whose truth lies in the central 50% and 90% interval,
with a Clopper-Pearson 95% interval for that share.

Files (in the output folder, each written atomically): sbc.json (per simulation: scene,
truth, ranks, inside the intervals or not, converged, R-hat and ESS, timings; per quantity:
the p-values, the coverages, the rank histogram), ranks_<quantity>.png (the rank histogram
with the pointwise binomial 99% band of a bin's count), ecdf_<quantity>.png (ECDF of the
PIT values minus the uniform's, with the simultaneous band) and sbc.md (a table).

`coverage_on_videos`: for each video of a rendered dataset (index.json; per video
scene.json, truth.json, video.mp4, and tracks.json when cached), track it (or read the
cached tracks), infer, and record whether the central 50% and 90% intervals of the
quantities the video identifies (the ramp: k1, and log(m1/m2) where it has a target) hold
the true value; coverage.json and coverage.md. A video that fails tracking or inference is
reported, not fatal.
"""
from __future__ import annotations

import io
import math
import time
from functools import lru_cache
from pathlib import Path

import numpy as np

from .progress import tqdm
from . import registry
from .errors import GalileoError
from .jsonio import atomic_write_bytes, read_json, write_json

DEFAULT_DRAWS = 99            # L: ranks take values 0..L
DEFAULT_CHAINS = 4
DEFAULT_SWEEPS = 200
INTERVALS = (0.5, 0.9)        # central posterior intervals whose coverage is measured
BAND = 0.99                   # the plots' bands (rank histogram: pointwise; ECDF: simultaneous)
UNIFORM_SIMULATIONS = 10000   # null samples of the ECDF test
SCENE_CHOICES = ("default", "dataset")


# -- statistics ------------------------------------------------------------------------------------

def pit_values(ranks, n_draws: int, rng: np.random.Generator) -> np.ndarray:
    """Randomised PIT values (rank + V) / (L + 1), V ~ U(0, 1): uniform on (0, 1) when the
    ranks are uniform on 0..L."""
    r = np.asarray(ranks, float)
    return (r + rng.uniform(size=r.shape)) / (n_draws + 1)


def _grid(n: int) -> np.ndarray:
    return np.arange(1, n) / n


def _tail(u_sorted: np.ndarray, z: np.ndarray) -> float:
    """The smallest two-sided pointwise binomial tail probability of the ECDF on the grid z."""
    from scipy.special import bdtr

    n = len(u_sorted)
    counts = np.searchsorted(u_sorted, z, side="right")
    low = bdtr(counts, n, z)               # P(Bin(n, z) <= count)
    high = 1.0 - bdtr(counts - 1, n, z)    # P(Bin(n, z) >= count)
    return float(min(low.min(), high.min()))


@lru_cache(maxsize=64)
def _null_tails(n: int, n_sim: int = UNIFORM_SIMULATIONS) -> np.ndarray:
    """The test statistic of n_sim uniform samples of size n (seeded: the same on every run)."""
    rng = np.random.default_rng(np.random.SeedSequence(20180414, spawn_key=(n,)))
    z = _grid(n)
    return np.sort([_tail(np.sort(rng.uniform(size=n)), z) for _ in range(n_sim)])


def ecdf_uniformity(u) -> dict:
    """The ECDF test of uniformity on (0, 1) (Saeilynoja et al. 2022; see the module):
    {"p": p-value, "z": grid, "ecdf": ECDF on it, "lower", "upper": the simultaneous BAND
    band on it}. Needs at least 2 values."""
    from scipy.special import bdtrik

    u = np.sort(np.asarray(u, float))
    n = len(u)
    if n < 2:
        raise ValueError("the ECDF test needs at least 2 values")
    z = _grid(n)
    null = _null_tails(n)
    obs = _tail(u, z)
    p = (np.searchsorted(null, obs, side="right") + 1) / (len(null) + 1)
    # the simultaneous band: the pointwise level gamma that a uniform sample's ECDF stays within
    # everywhere with probability BAND (gamma = 1 - 2 tail, its BAND quantile)
    gamma = float(np.quantile(1.0 - 2.0 * null, BAND))
    lower = np.ceil(bdtrik((1.0 - gamma) / 2.0, n, z)) / n
    upper = np.ceil(bdtrik((1.0 + gamma) / 2.0, n, z)) / n
    return {"p": float(min(1.0, p)), "z": z, "ecdf": np.searchsorted(u, z, side="right") / n,
            "lower": np.nan_to_num(lower, nan=0.0), "upper": np.nan_to_num(upper, nan=1.0)}


def rank_bins(n: int, n_draws: int) -> int:
    """Bins of the rank histogram: the largest divisor of L + 1 that is at most 20 and leaves at
    least 5 simulations a bin (at least 2)."""
    best = 2 if (n_draws + 1) % 2 == 0 else 1
    for b in range(2, 21):
        if (n_draws + 1) % b == 0 and n / b >= 5:
            best = b
    return best


def rank_histogram(ranks, n_draws: int, bins: int) -> np.ndarray:
    r = np.asarray(ranks, int)
    return np.bincount(r * bins // (n_draws + 1), minlength=bins)[:bins]


def chi2_uniformity(counts) -> float | None:
    from scipy.stats import chisquare

    counts = np.asarray(counts, float)
    if len(counts) < 2 or counts.sum() == 0:
        return None
    return float(chisquare(counts).pvalue)


def coverage_summary(inside) -> dict:
    """Share of True in `inside`, with a Clopper-Pearson 95% interval."""
    from scipy.stats import binomtest

    x = np.asarray(inside, bool)
    n, k = len(x), int(x.sum())
    if n == 0:
        return {"n": 0, "covered": 0, "coverage": None, "ci95": None}
    ci = binomtest(k, n).proportion_ci(0.95, method="exact")
    return {"n": n, "covered": k, "coverage": k / n, "ci95": [float(ci.low), float(ci.high)]}


def binomial_range(n: int, prob: float, level: float = 0.999) -> tuple[int, int]:
    """The central `level` range of Binomial(n, prob) counts."""
    from scipy.stats import binom

    return int(binom.ppf((1 - level) / 2, n, prob)), int(binom.ppf((1 + level) / 2, n, prob))


def rank_of(truth: float, draws: np.ndarray, rng: np.random.Generator) -> int:
    """How many draws are below the truth (ties broken at random)."""
    d = np.asarray(draws, float)
    below, equal = int((d < truth).sum()), int((d == truth).sum())
    return below + (int(rng.integers(0, equal + 1)) if equal else 0)


def thin(kept: np.ndarray, n_draws: int) -> np.ndarray:
    """L draws evenly spaced over the chains' kept draws (chains one after another): (L, D)."""
    flat = kept.reshape(-1, kept.shape[-1])
    if len(flat) < n_draws:
        raise GalileoError(f"only {len(flat)} kept draws for {n_draws} ranked draws: run more chains or sweeps, "
                           "or rank fewer draws")
    idx = np.round(np.linspace(0, len(flat) - 1, n_draws)).astype(int)
    return flat[idx]


# -- quantities: latents and derived ones ------------------------------------------------------------

def quantities(scenario, scene, names, rows: np.ndarray) -> dict[str, np.ndarray]:
    """Per quantity, its value in each row of latent values (rows: (N, D)): the latents, then
    the scenario's derived quantities that every row has (a positive one as its log,
    `log_<name>`, as `InferenceResult.derived_posterior` reports it). A derived quantity that
    stays the same while the rows vary (the splash's volume: the scene's, not inferred) is no
    posterior and is left out."""
    out = {n: rows[:, j].astype(float) for j, n in enumerate(names)}
    rows_vary = len(rows) > 1 and bool(np.ptp(rows, axis=0).max() > 0)
    derived: dict[str, list] = {}
    for row in rows:
        for k, v in scenario.derived(scene, dict(zip(names, map(float, row)))).items():
            derived.setdefault(k, []).append(None if v is None else float(v))
    for k, vals in derived.items():
        if len(vals) != len(rows) or any(v is None for v in vals):
            continue
        x = np.asarray(vals, float)
        if not np.all(np.isfinite(x)) or (rows_vary and np.ptp(x) == 0):
            continue
        if np.all(x > 0):
            out[f"log_{k}"] = np.log(x)
        else:
            out[k] = x
    return out


# -- one simulation ----------------------------------------------------------------------------------

def _run_all(fn, tasks: list, workers, desc: str, unit: str, progress: bool) -> tuple[list, int]:
    """fn over the tasks on a local pool (one pybullet client per worker), in order, with a
    bar; (results, the number of workers)."""
    from .runner import local_executor

    executor = local_executor(workers, len(tasks))
    out = []
    try:
        with tqdm(total=len(tasks), desc=desc, unit=unit, disable=not progress) as bar:
            for r in executor.map(fn, tasks):
                out.append(r)
                bar.update()
    finally:
        executor.shutdown()
    return out, getattr(executor, "workers", 1)


def draw_simulation(scenario, i: int, seed: int, scenes: str = "default", scene=None,
                    moves: str = "default") -> tuple:
    """(scene with the true values set, truth {latent: value}) of simulation i (seeded). The
    scene is the one the move set infers on (`runner.scene_for_moves`: with "paper", the
    scenario's paper priors, e.g. the ramp's Gaussian likelihood), so that the observations
    come from the very model that is inferred."""
    from .runner import scene_for_moves

    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(i,)))
    if scene is None:
        if scenes == "dataset":
            fn = scenario.synthetic.random_scene if scenario.synthetic else None
            if fn is None:
                raise GalileoError(f"the {scenario.name} scenario cannot draw random scenes (--scenes dataset)")
            scene = fn(rng)
        else:
            scene = scenario.default_scene()
    scene = scene_for_moves(scene, moves)
    truth = {}
    for lat in scenario.latents(scene):
        lo, hi = (float(b) for b in lat.bounds)
        truth[lat.name] = float(rng.integers(int(math.ceil(lo)), int(math.floor(hi)) + 1)) if lat.integer \
            else float(rng.uniform(lo, hi))
    return scenario.with_values(scene, truth), truth


def run_simulation(task: dict) -> dict:
    """One SBC simulation (a top-level function of plain data: it runs in a worker process)."""
    from .runner import RunConfig, infer

    t0 = time.perf_counter()
    scenario = registry.get(task["scenario"])
    scene = scenario.scene_from_json(task["scene"])
    truth = task["truth"]
    rng = np.random.default_rng(np.random.SeedSequence(task["seed"], spawn_key=(task["index"], 1)))
    out = {"index": task["index"], "truth": truth}
    if scenario.synthetic.describe is not None:
        out["scene"] = scenario.synthetic.describe(scene)
    try:
        tracks = scenario.synthetic.tracks(scene, truth, rng, task["noise"])
        if getattr(tracks, "notes", None):
            out["observations"] = "; ".join(tracks.notes)   # what was simulated (e.g. the noise model)
        t1 = time.perf_counter()
        cfg = RunConfig(**task["config"], workers=1,
                        seed=int(np.random.SeedSequence(task["seed"], spawn_key=(task["index"], 2)).generate_state(1)[0]))
        result = infer(scene, tracks, cfg, progress=False)
    except GalileoError as e:
        return {**out, "error": str(e)}
    names = list(result.names)
    kept = result.kept()
    flat = kept.reshape(-1, len(names))
    thinned = thin(kept, task["draws"])
    true_row = np.array([[truth[n] for n in names]], float)
    q_true = quantities(scenario, result.scene, names, true_row)
    q_all = quantities(scenario, result.scene, names, flat)
    q_thin = quantities(scenario, result.scene, names, thinned)
    ranks, inside = {}, {str(a): {} for a in INTERVALS}
    for k in q_true:
        if k not in q_all or k not in q_thin:
            continue
        t = float(q_true[k][0])
        ranks[k] = rank_of(t, q_thin[k], rng)
        for a in INTERVALS:
            lo, hi = np.quantile(q_all[k], [(1 - a) / 2, (1 + a) / 2])
            inside[str(a)][k] = bool(lo <= t <= hi)
    q_true = {k: float(v[0]) for k, v in q_true.items()}
    conv = result.convergence()
    rs = [v for v in conv["r_hat"].values() if v is not None]
    es = [v for d in (conv["ess_bulk"], conv["ess_tail"]) for v in d.values() if v is not None]
    return {**out, "truth": q_true, "ranks": ranks, "inside": inside, "converged": bool(conv["converged"]),
            "r_hat_max": max(rs) if rs else None, "ess_min": min(es) if es else None,
            "sweeps": int(result.samples.shape[1]), "kept_draws": int(len(flat)),
            "seconds": {"simulate": t1 - t0, "infer": float(result.timing_s["wall"]),
                        "total": time.perf_counter() - t0}}


# -- the SBC run -----------------------------------------------------------------------------------

def _config(chains, sweeps, moves, until_rhat, max_sweeps, min_ess, noise) -> dict:
    """The RunConfig fields of every inference (checked; GalileoError on a bad value)."""
    from .runner import RunConfig

    cfg = dict(chains=int(chains), sweeps=int(sweeps), moves=moves, until_rhat=until_rhat, max_sweeps=max_sweeps,
               noise=noise)
    if min_ess is not None:
        cfg["min_ess"] = float(min_ess)
    RunConfig(**cfg, workers=1).check()
    return cfg


def sbc(scenario_name: str, n: int, out_dir, *, seed: int = 0, chains: int = DEFAULT_CHAINS,
        sweeps: int = DEFAULT_SWEEPS, workers: int | None = None, draws: int = DEFAULT_DRAWS,
        scenes: str = "default", scene=None, noise: float | None = None, infer_noise: float | None = None,
        moves: str = "default", until_rhat: float | None = None, max_sweeps: int | None = None,
        min_ess: float | None = None, plots: bool = True, progress: bool = True) -> dict:
    """Simulation-based calibration (see the module): n simulations; writes sbc.json, sbc.md
    and the plots into out_dir; returns what sbc.json holds.

    `scene`: a fixed scene for every simulation (else `scenes`: "default" or "dataset");
    `noise`: the scale (SD) of the simulated observation noise (default: the scenario's likelihood
    noise); `infer_noise`: the likelihood's noise during inference (default: the same;
    another value makes a deliberately wrong posterior, for negative controls)."""
    scenario = registry.get(scenario_name)
    if scenario.synthetic is None:
        raise GalileoError(f"the {scenario.name} scenario cannot simulate observations: "
                           "no simulation-based calibration for it")
    if isinstance(n, bool) or int(n) != n or n < 1:
        raise GalileoError(f"n must be an integer >= 1 (simulations), got {n!r}")
    if isinstance(draws, bool) or int(draws) != draws or draws < 1:
        raise GalileoError(f"draws must be an integer >= 1, got {draws!r}")
    if scene is None and scenes not in SCENE_CHOICES:
        raise GalileoError(f"scenes must be one of {', '.join(SCENE_CHOICES)}, got {scenes!r}")
    noise = float(scenario.noise.default if noise is None else noise)
    infer_noise = noise if infer_noise is None else float(infer_noise)
    if not (math.isfinite(noise) and noise > 0 and math.isfinite(infer_noise) and infer_noise > 0):
        raise GalileoError("the noise must be a positive number")
    if until_rhat is not None and min_ess is None:
        min_ess = max(100, int(draws))   # the ranks use L draws: ask for at least that many effective ones
    cfg = _config(chains, sweeps, moves, until_rhat, max_sweeps, min_ess, infer_noise)
    if int(chains) * (int(sweeps) - int(sweeps) // 2) < draws and until_rhat is None:
        raise GalileoError(f"{chains} chains x {sweeps} sweeps keep fewer than {draws} draws to rank "
                           "(the first half is burn-in): run more, or rank fewer (--draws)")
    out_dir = Path(out_dir)
    tasks = []
    for i in range(int(n)):
        sc, truth = draw_simulation(scenario, i, seed, scenes, scene, moves)
        tasks.append({"scenario": scenario.name, "scene": sc.to_json(), "truth": truth, "index": i, "seed": int(seed),
                      "noise": noise, "draws": int(draws), "config": cfg})
    t0 = time.perf_counter()
    sims, n_workers = _run_all(run_simulation, tasks, workers, "SBC", "simulation", progress)
    wall = time.perf_counter() - t0
    if all("error" in s for s in sims):
        raise GalileoError(f"every simulation failed; the first: {sims[0]['error']}")
    report = summarise(sims, int(draws))
    report.update({"scenario": scenario.name, "n": int(n), "seed": int(seed), "draws": int(draws),
                   "scenes": "fixed" if scene is not None else scenes, "noise": noise, "infer_noise": infer_noise,
                   "config": cfg, "workers": n_workers, "wall_s": wall,
                   "simulations": sims})
    write_report(report, out_dir, plots=plots)
    return report


def rank_uniformity(name: str, ranks, n_draws: int) -> dict:
    """`ecdf_uniformity` of a quantity's ranks (their PIT values randomised by a generator
    seeded from the quantity's name and count: the same p-value and plot on every run)."""
    ranks = np.asarray(ranks, int)
    rng = np.random.default_rng(np.random.SeedSequence(len(ranks), spawn_key=(sum(map(ord, name)),)))
    return ecdf_uniformity(pit_values(ranks, n_draws, rng))


def summarise(sims: list[dict], n_draws: int) -> dict:
    """Per quantity: n, rank histogram, uniformity p-values, coverages."""
    ok = [s for s in sims if "error" not in s]
    names: list[str] = []
    for s in ok:
        names += [k for k in s["ranks"] if k not in names]
    per = {}
    for k in names:
        rows = [s for s in ok if k in s["ranks"]]
        ranks = np.array([s["ranks"][k] for s in rows], int)
        bins = rank_bins(len(ranks), n_draws)
        counts = rank_histogram(ranks, n_draws, bins)
        test = rank_uniformity(k, ranks, n_draws) if len(ranks) >= 2 else None
        per[k] = {"n": len(ranks), "p_value": test["p"] if test else None, "p_chi2": chi2_uniformity(counts),
                  "bins": bins, "rank_counts": counts.tolist(),
                  "coverage": {str(a): coverage_summary([s["inside"][str(a)][k] for s in rows]) for a in INTERVALS}}
    conv = [s["converged"] for s in ok]
    secs = [s["seconds"]["total"] for s in ok]
    return {"quantities": per, "failed": [{"index": s["index"], "error": s["error"]} for s in sims if "error" in s],
            "converged_share": float(np.mean(conv)) if conv else None,
            "seconds_per_simulation": {"mean": float(np.mean(secs)), "max": float(np.max(secs))} if secs else None}


# -- files -------------------------------------------------------------------------------------------

def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    return buf.getvalue()


def _finish(fig, ax, xlabel: str, ylabel: str, title: str, path: Path) -> None:
    """Label a figure's one axes, write it as PNG (atomically) and close it."""
    import matplotlib.pyplot as plt

    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    atomic_write_bytes(path, _png(fig))
    plt.close(fig)


def plot_ranks(name: str, counts, n_draws: int, path: Path) -> None:
    """The rank histogram with the pointwise binomial BAND band of a bin's count."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.stats import binom

    counts = np.asarray(counts)
    bins, n = len(counts), int(counts.sum())
    lo, hi = binom.ppf((1 - BAND) / 2, n, 1 / bins), binom.ppf((1 + BAND) / 2, n, 1 / bins)
    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    edges = np.arange(bins + 1) * (n_draws + 1) / bins
    ax.axhspan(lo, hi, color="0.85", label=f"{BAND:.0%} binomial band of a bin")
    ax.axhline(n / bins, color="0.5", lw=1)
    ax.bar(edges[:-1], counts, width=np.diff(edges), align="edge", color="#4477aa", edgecolor="white")
    ax.set_xlim(0, n_draws + 1)
    _finish(fig, ax, f"rank of the truth among {n_draws} posterior draws", "simulations",
            f"SBC ranks: {name} (n = {n})", path)


def plot_ecdf(name: str, test: dict, p: float, n: int, path: Path) -> None:
    """ECDF of the PIT values minus the uniform CDF, with the simultaneous BAND band."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    z = np.concatenate([[0.0], test["z"], [1.0]])
    diff = np.concatenate([[0.0], test["ecdf"] - test["z"], [0.0]])
    lo = np.concatenate([[0.0], test["lower"] - test["z"], [0.0]])
    hi = np.concatenate([[0.0], test["upper"] - test["z"], [0.0]])
    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    ax.fill_between(z, lo, hi, step="post", color="0.85", label=f"{BAND:.0%} simultaneous band")
    ax.step(z, diff, where="post", color="#cc3311", lw=1.5, label="ECDF - uniform")
    ax.axhline(0.0, color="0.5", lw=1)
    ax.set_xlim(0, 1)
    _finish(fig, ax, "fractional rank (PIT)", "ECDF difference",
            f"SBC ECDF difference: {name} (n = {n}, p = {p:.3g})", path)


def _fmt_cov(c: dict) -> str:
    if not c or c.get("coverage") is None:
        return "n/a"
    lo, hi = c["ci95"]
    return f"{c['coverage']:.0%} ({c['covered']}/{c['n']}; {lo:.0%}-{hi:.0%})"


def sbc_markdown(report: dict) -> str:
    cfg = report["config"]
    lines = [f"# SBC: {report['scenario']}, {report['n']} simulations",
             "",
             f"scenes: {report['scenes']}; noise scale {report['noise']:g} (inference: {report['infer_noise']:g}); "
             f"{cfg['chains']} chains x {cfg['sweeps']} sweeps, moves {cfg['moves']}"
             + (f", until R-hat <= {cfg['until_rhat']} (max {cfg['max_sweeps']})" if cfg.get("until_rhat") else "")
             + f"; L = {report['draws']} ranked draws; seed {report['seed']}; "
             f"{report['wall_s']:.0f} s on {report['workers']} worker(s)",
             ""]
    first = next((s for s in report["simulations"] if s.get("observations")), None)
    if first is not None:
        lines += [f"observations (simulation {first['index']}): {first['observations']}", ""]
    lines += ["| quantity | n | p (ECDF) | p (chi2) | 50% coverage | 90% coverage |",
              "|---|---|---|---|---|---|"]
    for k, q in report["quantities"].items():
        pc = "n/a" if q["p_chi2"] is None else f"{q['p_chi2']:.3g}"
        pe = "n/a" if q["p_value"] is None else f"{q['p_value']:.3g}"
        lines.append(f"| {k} | {q['n']} | {pe} | {pc} | {_fmt_cov(q['coverage']['0.5'])} | "
                     f"{_fmt_cov(q['coverage']['0.9'])} |")
    conv = report.get("converged_share")
    lines += ["", "converged (R-hat and ESS at their targets for every latent): "
                  f"{'n/a' if conv is None else f'{conv:.0%}'} of the simulations"]
    if report["failed"]:
        lines.append(f"failed: {len(report['failed'])} (see sbc.json)")
    lines += ["", "p (ECDF): the ECDF uniformity test of the fractional ranks (Saeilynoja et al. 2022); "
                  "p (chi2): the rank histogram's chi-square test; coverage with its Clopper-Pearson 95% interval."]
    return "\n".join(lines) + "\n"


def write_report(report: dict, out_dir: Path, plots: bool = True) -> list[Path]:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    if plots:
        for k, q in report["quantities"].items():
            if q["n"] < 2:
                continue
            rows = [s for s in report["simulations"] if "ranks" in s and k in s["ranks"]]
            test = rank_uniformity(k, [s["ranks"][k] for s in rows], report["draws"])
            plot_ranks(k, q["rank_counts"], report["draws"], out_dir / f"ranks_{k}.png")
            plot_ecdf(k, test, q["p_value"], q["n"], out_dir / f"ecdf_{k}.png")
            written += [out_dir / f"ranks_{k}.png", out_dir / f"ecdf_{k}.png"]
    write_json(out_dir / "sbc.json", report)
    atomic_write_bytes(out_dir / "sbc.md", sbc_markdown(report).encode())
    report["files"] = [str(p) for p in [out_dir / "sbc.json", out_dir / "sbc.md", *written]]
    return written


# -- coverage on rendered videos ---------------------------------------------------------------------

def _video_task(task: dict) -> dict:
    """Track (or read the cached tracks of) one video, infer, and check its intervals."""
    from .recognition.data import Example, tracks_for
    from .runner import RunConfig, infer

    t0 = time.perf_counter()
    folder = Path(task["folder"])
    out = {"name": folder.name}
    try:
        truth = read_json(folder / "truth.json", "truth file").get("latents", {})
        scene = registry.load_scene(folder / "scene.json")
        scenario = registry.of(scene)
        tracks = tracks_for(Example(folder.name, folder, folder.name, "", ""), scene)
        if tracks is None:
            return {**out, "error": "the tracker sees nothing move"}
        t1 = time.perf_counter()
        result = infer(scene, tracks, RunConfig(**task["config"], workers=1, seed=task["seed"]), progress=False)
    except GalileoError as e:
        return {**out, "error": str(e)}
    names = list(result.names)
    flat = result.kept().reshape(-1, len(names))
    q_all = quantities(scenario, result.scene, names, flat)
    known = {n: float(truth[n]) for n in names if isinstance(truth.get(n), (int, float))}
    q_true = {n: np.array([v]) for n, v in known.items()}
    if len(known) == len(names):   # derived quantities need every latent's truth
        q_true = quantities(scenario, result.scene, names, np.array([[known[n] for n in names]]))
    checks = {}
    for k in scenario.experiments.coverage:
        if k not in q_all or k not in q_true:
            continue
        t = float(q_true[k][0])
        qs = np.quantile(q_all[k], [0.05, 0.25, 0.5, 0.75, 0.95])
        checks[k] = {"truth": t, "q05": float(qs[0]), "q25": float(qs[1]), "q50": float(qs[2]), "q75": float(qs[3]),
                     "q95": float(qs[4]), "inside": {"0.5": bool(qs[1] <= t <= qs[3]), "0.9": bool(qs[0] <= t <= qs[4])}}
    conv = result.convergence()
    return {**out, "target": truth.get("target"), "angle_deg": truth.get("angle_deg"), "quantities": checks,
            "converged": bool(conv["converged"]), "sweeps": int(result.samples.shape[1]),
            "seconds": {"tracks": t1 - t0, "infer": float(result.timing_s["wall"]), "total": time.perf_counter() - t0}}


def coverage_on_videos(dataset_dir, out_dir, *, seed: int = 0, chains: int = DEFAULT_CHAINS,
                       sweeps: int = DEFAULT_SWEEPS, workers: int | None = None, moves: str = "default",
                       until_rhat: float | None = None, max_sweeps: int | None = None, min_ess: float | None = None,
                       progress: bool = True) -> dict:
    """Interval coverage on a rendered dataset (see the module); writes coverage.json and
    coverage.md into out_dir; returns what coverage.json holds."""
    dataset_dir = Path(dataset_dir)
    if not dataset_dir.is_dir():
        raise GalileoError(f"dataset folder not found: {dataset_dir}")
    index = read_json(dataset_dir / "index.json", "dataset index") if (dataset_dir / "index.json").is_file() else None
    if not isinstance(index, dict) or not isinstance(index.get("videos"), list):
        raise GalileoError(f"{dataset_dir} is not a dataset folder (no index.json listing videos; make one with "
                           "`galileo dataset`)")
    name = index.get("scenario", registry.DEFAULT)
    scenario = registry.get(name)
    if scenario.experiments is None or not scenario.experiments.coverage:
        raise GalileoError(f"{dataset_dir}: the {name} scenario names no quantities to check coverage of on videos")
    cfg = _config(chains, sweeps, moves, until_rhat, max_sweeps, min_ess, None)
    names = [v["name"] for v in index["videos"] if isinstance(v, dict) and "name" in v]
    tasks = [{"folder": str(dataset_dir / name), "config": cfg, "seed": int(seed)} for name in names]
    if not tasks:
        raise GalileoError(f"{dataset_dir}: the index lists no videos")
    t0 = time.perf_counter()
    videos, n_workers = _run_all(_video_task, tasks, workers, "videos", "video", progress)
    per = {}
    for k in scenario.experiments.coverage:
        rows = [v for v in videos if k in v.get("quantities", {})]
        per[k] = {str(a): coverage_summary([v["quantities"][k]["inside"][str(a)] for v in rows]) for a in INTERVALS}
    done = [v for v in videos if "error" not in v]
    report = {"dataset": str(dataset_dir), "preset": index.get("preset"), "n_videos": len(videos),
              "failed": [{"name": v["name"], "error": v["error"]} for v in videos if "error" in v],
              "coverage": per, "converged_share": float(np.mean([v["converged"] for v in done])) if done else None,
              "config": cfg, "seed": int(seed), "workers": n_workers,
              "wall_s": time.perf_counter() - t0, "videos": videos}
    out_dir = Path(out_dir)
    write_json(out_dir / "coverage.json", report)
    atomic_write_bytes(out_dir / "coverage.md", coverage_markdown(report).encode())
    report["files"] = [str(out_dir / "coverage.json"), str(out_dir / "coverage.md")]
    return report


def coverage_markdown(report: dict) -> str:
    cfg = report["config"]
    lines = [f"# Interval coverage on {report['dataset']} ({report.get('preset') or '?'}, "
             f"{report['n_videos']} videos)", "",
             f"{cfg['chains']} chains x {cfg['sweeps']} sweeps, moves {cfg['moves']}"
             + (f", until R-hat <= {cfg['until_rhat']}" if cfg.get("until_rhat") else "")
             + f"; seed {report['seed']}; {report['wall_s']:.0f} s on {report['workers']} worker(s)", "",
             "| quantity | videos | 50% coverage | 90% coverage |", "|---|---|---|---|"]
    for k, c in report["coverage"].items():
        lines.append(f"| {k} | {c['0.5']['n']} | {_fmt_cov(c['0.5'])} | {_fmt_cov(c['0.9'])} |")
    conv = report.get("converged_share")
    lines += ["", f"converged: {'n/a' if conv is None else f'{conv:.0%}'} of the videos"]
    for f in report["failed"]:
        lines.append(f"* failed: {f['name']}: {f['error']}")
    keys = list(report["coverage"])
    lines += ["", "| video | " + " | ".join(f"{k} truth | {k} 90% interval" for k in keys) + " | converged |",
              "|---|" + "---|---|" * len(keys) + "---|"]
    for v in report["videos"]:
        if "error" in v:
            continue
        q = v["quantities"]
        cells = []
        for k in keys:
            if k in q:
                mark = "" if q[k]["inside"]["0.9"] else " **out**"
                cells += [f"{q[k]['truth']:.3f}", f"{q[k]['q05']:.3f}-{q[k]['q95']:.3f}{mark}"]
            else:
                cells += ["", ""]
        lines.append(f"| {v['name']} | " + " | ".join(cells) + f" | {'yes' if v['converged'] else 'no'} |")
    return "\n".join(lines) + "\n"
