# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
#       format_version: '1.3'
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # A splash dataset and its report
#
# The *splash* scenario is from Physics 101 (Wu, Lim, Zhang, Tenenbaum & Freeman, BMVC 2016):
# an object is dropped into a tank of water; whether and how fast it sinks depends on its
# density (and its volume, through buoyancy and drag), so the video is evidence for its mass.
# Galileo tracks the object, estimates its volume bottom-up from its silhouette, and infers its
# density (and a correction to the volume) by MCMC with Bullet in the loop.
#
# One video is an anecdote; the paper's claims are about a dataset. This notebook
#
# 1. renders a dataset of splash videos with known truth (`galileo dataset --scenario splash`),
# 2. runs the paper's experiments on it with `galileo.experiment`: every video tracked and
#    inferred, in parallel on a Dask cluster (here one on this machine; on a cluster you
#    pass a client connected to it), and
# 3. reads the report: predicted against true mass (the paper's correlation), which of two
#    objects is heavier, how often the 90% intervals hold the truth, the volume estimates,
#    convergence.

# %%
import json
import os
import subprocess
import sys
from pathlib import Path

import galileo

# %% [markdown]
# ## Settings
#
# `PRESET` picks the dataset: `small` is 8 videos (4 objects that sink, 4 that float), `full` the
# 72 videos of the paper's experiment. `CHAINS = SWEEPS = None` takes the splash scenario's own
# protocol, 50 chains x 75 sweeps. `GALILEO_EXAMPLES_SMALL=1` (the tests) renders the one-video
# `demo` preset and runs 2 chains x 8 sweeps, the least for the report's "chains agree" rule: the
# report then has too few videos for correlations and pairs (it says so), but every step runs.

# %%
SMALL = os.environ.get("GALILEO_EXAMPLES_SMALL") == "1"
PRESET = "demo" if SMALL else "small"
CHAINS = 2 if SMALL else None       # None: the scenario's protocol (50 chains for the splash)
SWEEPS = 8 if SMALL else None       # None: the protocol's 75 sweeps
WORKERS = 2 if SMALL else os.cpu_count()   # Dask worker processes, one video at a time each
SEED = 0

OUT = Path(os.environ.get("GALILEO_EXAMPLES_OUT", "galileo-examples-out")).resolve()
HERE = OUT / "03_splash_dataset_report"
DATASET = OUT / "datasets" / f"splash-{PRESET}-seed{SEED}"
REPORT = HERE / "report"


# %% [markdown]
# ## 1. The dataset
#
# In a notebook: `!galileo dataset --scenario splash --preset small --out DIR`. Each video gets
# its folder (video.mp4, scene.json, truth.json) and the dataset an index.json. Rendering runs on
# all cores and resumes where it stopped.

# %%
def render_dataset() -> None:
    if (DATASET / "index.json").is_file():
        print(f"{DATASET}: rendered before")
        return
    args = ["dataset", "--scenario", "splash", "--preset", PRESET, "--seed", str(SEED), "--out", str(DATASET),
            "--quiet"]
    print("$ galileo", " ".join(args))
    subprocess.run([sys.executable, "-m", "galileo", *args], check=True)


# %% [markdown]
# ## 2. The experiments, on Dask
#
# `galileo.experiment(dataset, out, client=client)` sends one task per video to the client's
# workers, keeps each video's record as it comes (a rerun resumes), and writes `out/report.md`
# with its figures, `report.json`, and a table with a row per video (`results.csv`,
# `results.parquet`). Without a client it starts a local cluster of `workers=` processes itself.
#
# Any `dask.distributed.Client` will do: `Client(LocalCluster(...))` on this machine as here,
# `Client("tcp://scheduler:8786")` for a running scheduler, or a `dask_jobqueue.SLURMCluster`.
# The workers need Galileo installed (the same version). `client.dashboard_link` shows the
# progress in the browser.
#
# *Run as a script* (`python examples/03_splash_dataset_report.py`), Dask's local worker processes
# start by importing this file again (Python's "spawn"), so the code that starts them sits under
# `if __name__ == "__main__":` at the end; in Jupyter that test is true and the cell just runs.

# %%
def run_experiments(client) -> dict:
    print(f"{len(client.scheduler_info()['workers'])} workers; dashboard: {client.dashboard_link}")
    return galileo.experiment(DATASET, REPORT, client=client, chains=CHAINS, sweeps=SWEEPS, seed=SEED)


# %% [markdown]
# ## 3. The report
#
# `report.md` (open it in any Markdown viewer; the figures are beside it) puts each number next
# to the paper's. The returned dict is `report.json`; its `summary` holds the numbers:
#
# * **mass**: a video's predicted mass is the posterior median of density x volume; Pearson r of
#   predicted against true mass over the objects whose chains agree (the paper: r = 0.85);
# * **which is heavier**: pairs of videos of different objects, in three bands of mass ratio;
# * **coverage**: the share of videos whose 90% interval holds the true value (about 90% for
#   calibrated intervals);
# * **converged**: videos that meet `galileo infer`'s convergence rule, and the weaker "chains
#   agree" rule of the paper's code.

# %%
def show_report(report: dict) -> None:
    s = report["summary"]
    print(f"report: {REPORT / 'report.md'}")
    print(f"figures: {sorted(p.name for p in (REPORT / 'figures').glob('*.png'))}")
    print(f"{s['videos']} videos: {s['predicted']} predicted, {s['chains_agree']} with chains that agree, "
          f"{s['converged']} converged ({s['converged_rule']})")
    mass = s["mass_correlation"]
    r = mass["objects"]["pearson_r"]
    print(f"mass, predicted against true, over objects: Pearson r = {'n/a' if r is None else f'{r:.2f}'} "
          f"(n = {mass['objects']['n']}; the paper: {s['seed']['pearson_r']}); median relative error "
          f"{mass['median_relative_error']:.0%}")
    for band, b in s["which_is_heavier"].items():
        acc = "n/a (no pairs)" if b["accuracy"] is None else f"{b['accuracy']:.0%} of {b['pairs']} pairs"
        print(f"which is heavier, {band} (ratio ~{b['band']['seed_median']:g}): {acc}")
    for name, c in s["coverage_90"].items():
        print(f"90% interval holds the true {name}: {c['covered']}/{c['n']}")
    print(f"bottom-up volume, median error {s['volume']['bottom_up_median_error']:.0%}; "
          f"inference {s['seconds_per_video']:.1f} s a video (mean; tracking aside)")

    import pandas as pd

    table = pd.read_csv(REPORT / "results.csv")
    print(f"results.csv: {len(table)} rows x {table.shape[1]} columns")
    print(table.iloc[:, :6].to_string(index=False))


# %% [markdown]
# ## Run
#
# The cluster is closed when the `with` block ends.

# %%
if __name__ == "__main__":
    from distributed import Client, LocalCluster

    render_dataset()
    with LocalCluster(n_workers=WORKERS, threads_per_worker=1, dashboard_address=":0") as cluster, \
            Client(cluster) as client:
        report = run_experiments(client)
    show_report(report)
    (HERE / "summary.json").write_text(json.dumps(report["summary"], indent=1, default=str))
