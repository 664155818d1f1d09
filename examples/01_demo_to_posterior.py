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
# # From a video to a posterior: the ramp demo
#
# Galileo (Wu, Yildirim, Lim, Freeman & Tenenbaum, NIPS 2015) infers physical properties of
# objects (mass, friction) from a video by *analysis by synthesis*: it proposes values for the
# properties, runs a physics engine (Bullet) forward from the scene the camera sees, and keeps
# the values whose simulated motion matches the motion tracked in the video. The proposals are
# made by Markov chain Monte Carlo (MCMC), so what comes back is a **posterior distribution**
# over the properties, not a single number.
#
# This notebook goes the whole way on the demo video: a wooden block slides down a 20 degree
# ramp and knocks a cardboard box along the floor. It
#
# 1. renders the demo video (with its scene file and its ground truth),
# 2. tracks the two objects in it,
# 3. infers the block's and the box's masses and frictions,
# 4. reads the result: what the video identifies, the 90% intervals, whether the chains converged,
# 5. opens the posterior in ArviZ (summary table, trace, rank and pair plots), and
# 6. saves it as netCDF and reads it back.
#
# It runs as a notebook (open it with Jupyter through `jupytext`) or as a script:
# `python examples/01_demo_to_posterior.py`. Everything it writes goes to one folder
# (`GALILEO_EXAMPLES_OUT`, default `./galileo-examples-out`).

# %%
import json
import os
import subprocess
import sys
from pathlib import Path

import matplotlib

if "ipykernel" not in sys.modules:      # (run as a script: draw into files, no windows)
    matplotlib.use("Agg")
import matplotlib.pyplot as plt

import galileo

# %% [markdown]
# ## Settings
#
# The chains and sweeps are the paper's (16 chains of 75 sweeps; a *sweep* proposes a new value
# for every property once). `GALILEO_EXAMPLES_SMALL=1` shrinks them so the notebook runs in
# seconds (this is how the tests run it): the numbers then show the workflow, not a trustworthy
# posterior.

# %%
SMALL = os.environ.get("GALILEO_EXAMPLES_SMALL") == "1"
CHAINS = 4 if SMALL else 16        # independent Markov chains
SWEEPS = 12 if SMALL else 75       # sweeps per chain (the first half is burn-in)
SEED = 0

OUT = Path(os.environ.get("GALILEO_EXAMPLES_OUT", "galileo-examples-out")).resolve()
HERE = OUT / "01_demo_to_posterior"        # this notebook's files
HERE.mkdir(parents=True, exist_ok=True)
# a demo rendered before (`galileo dataset --preset demo --out DIR`), or rendered below
DEMO = Path(os.environ.get("GALILEO_EXAMPLES_DEMO", OUT / "datasets" / "ramp-demo-seed0")).resolve()
print(f"{CHAINS} chains x {SWEEPS} sweeps; writing to {HERE}")


# %% [markdown]
# ## 1. The demo video
#
# `galileo dataset` renders videos with known ground truth. Its `demo` preset is one video; the
# folder gets `demo/video.mp4`, `demo/scene.json` (the ramp, the objects' shapes, the camera:
# everything the simulator needs except the properties to infer) and `demo/truth.json` (the
# true masses and frictions). In a notebook the same command is `!galileo dataset --preset demo
# --out DIR`; it is rendered once and reused.

# %%
def galileo_cli(*args) -> str:
    """Run `galileo ARGS...` (the command line; `!galileo ...` in a notebook) and return its output."""
    print("$ galileo", " ".join(map(str, args)))
    done = subprocess.run([sys.executable, "-m", "galileo", *map(str, args)], capture_output=True, text=True)
    print(done.stdout + done.stderr)
    done.check_returncode()
    return done.stdout


if not (DEMO / "index.json").is_file():
    galileo_cli("dataset", "--scenario", "ramp", "--preset", "demo", "--seed", 0, "--out", DEMO, "--quiet")
video = DEMO / "demo" / "video.mp4"
scene = galileo.load_scene(DEMO / "demo" / "scene.json")
truth = json.loads((DEMO / "demo" / "truth.json").read_text())["latents"]
print(f"ramp at {scene.ramp.angle_deg:g} deg; objects: {[o.name for o in scene.objects]}; "
      f"{scene.camera.n_frames} frames at {scene.camera.fps:g} fps")
print("the truth:", {k: truth[k] for k in ("m1_kg", "k1", "m2_kg", "k2")})

# %% [markdown]
# ## 2. Tracking
#
# `galileo.track` finds the sliding block by its motion and the box where the scene file puts
# it, and lifts their image positions onto the ramp and the floor: positions and velocities in
# metres, frame by frame. These *tracks* are all the inference sees of the video.

# %%
tracks = galileo.track(video, scene)
for obj in tracks.objects:
    print(f"{obj.name}: seen in {int(obj.visible.sum())} of {tracks.n_frames} frames")
for note in tracks.notes:
    print("note:", note)
tracks.save(HERE / "tracks.json")

# %% [markdown]
# ## 3. Inference
#
# `galileo.infer` runs the chains: each starts from a draw of the prior and makes Metropolis
# moves, every one of which simulates the whole video in Bullet and scores the simulated motion
# against the tracks. (It also takes the video file itself and tracks it first.)

# %%
result = galileo.infer(scene, tracks, chains=CHAINS, sweeps=SWEEPS, seed=SEED)
print(result)

# %% [markdown]
# ## 4. What the video says
#
# **What is identified.** The block's friction `k1` sets how fast it accelerates down the ramp,
# whatever its mass, so the slide pins `k1` down. The collision conserves momentum, which fixes
# the *ratio* of the masses `m1/m2` but not the masses: both scaled together make exactly the
# same video. So the posterior of `m1_kg` and `m2_kg` alone is the prior stretched along a line,
# and Galileo reports no point estimate for them (`result.not_identified` says why); the
# quantity to read is `mass_ratio`. (Give the box's mass, e.g. `fix={"m2_kg": 0.137}`, and the
# block's mass becomes identified: see example 04.)
#
# **The intervals** are the 5% and 95% quantiles of the kept draws (after burn-in): a 90%
# credible interval.

# %%
for name, why in result.not_identified.items():
    print(f"not identified: {name} ({why.split(':')[0]})")
truth["mass_ratio"] = truth["m1_kg"] / truth["m2_kg"]
rows = {**{k: v for k, v in result.posterior.items() if k not in result.not_identified},
        **{k: v for k, v in result.posterior_derived.items() if not k.startswith("log_")}}
print(f"{'':12s} {'median':>8s} {'90% interval':>18s} {'truth':>8s}   unit")
for name, s in rows.items():
    unit = result.units.get(name, "1")
    print(f"{name:12s} {s['q50']:8.3f} {s['q05']:8.3f} - {s['q95']:7.3f} {truth[name]:8.3f}   {unit}")

# %% [markdown]
# **Convergence.** Independent chains that have found the posterior agree with each other:
# Galileo calls a run *converged* when, for every latent, the rank-normalised split R-hat is at
# most 1.01 and the bulk and tail effective sample sizes (ESS) are at least 400 (Vehtari et al.
# 2021). "NOT converged" means the chains still disagree or are too short to tell: the MAP (the
# best point any chain found) may still be good, but the intervals and the posterior shares are
# not yet the posterior's; run more sweeps (`sweeps=`) or let Galileo run until converged
# (`until_rhat=1.01, max_sweeps=...`). With the small settings it is never converged.

# %%
print("converged:", result.converged)
for line in result.why_not:
    print("  ", line)
diag = result.diagnostics
print("R-hat:", {k: None if v is None else round(v, 3) for k, v in diag["r_hat"].items()})
print("bulk ESS:", {k: None if v is None else round(v) for k, v in diag["ess"].items()})
print(f"acceptance {diag['acceptance_all']:.0%}, burn-in {result.burn_in} of {diag['sweeps']} sweeps")

# %% [markdown]
# ## 5. ArviZ
#
# `result.to_arviz()` gives ArviZ's data structure, an `xarray.DataTree` with the groups
# `posterior` (each latent per chain and draw, with its unit; the derived `mass_ratio`),
# `warmup_posterior` (the burn-in), `sample_stats` (`lp`, the log-likelihood; the acceptance
# per sweep and per move) and `observed_data` (the tracks). ArviZ's own functions take it as is.

# %%
import arviz_plots as azp
import arviz_stats

idata = result.to_arviz()
print(list(idata.children))
print({name: (var.attrs["units"], var.attrs.get("identified", "derived")[:3])
       for name, var in idata["posterior"].data_vars.items()})
table = arviz_stats.summary(idata, ci_prob=0.9, round_to=4)   # 90% equal-tailed intervals, R-hat, ESS
print(table.to_string())
table.to_csv(HERE / "summary.csv")

# %% [markdown]
# ArviZ's R-hat is the one Galileo's verdict uses (the same estimator on the same draws):

# %%
for name, r in diag["r_hat"].items():
    if r is not None:
        print(f"{name}: galileo {r:.4f}, arviz {table.loc[name, 'r_hat']:.4f}")

# %% [markdown]
# The **trace plot** shows every chain's draws, sweep after sweep (one colour a chain): chains
# that explore the same region overlap (`azp.plot_trace_dist` adds their densities). The **rank plot** ranks all draws together and
# histograms each chain's ranks: for chains mixing well the histograms are flat. The **pair
# plot** of the two masses shows why they are not identified: in a full run the draws lie along
# a line through the origin, the line of one mass ratio (with the small settings there are too
# few draws to see it).

# %%
plots = {
    "trace.png": azp.plot_trace(idata),
    "rank.png": azp.plot_rank(idata, var_names=["k1", "k2", "mass_ratio"]),
    "pair_masses.png": azp.plot_pair(idata, var_names=["m1_kg", "m2_kg", "k1"]),
    "ess.png": azp.plot_ess(idata),
}
for name, pc in plots.items():
    pc.savefig(HERE / name)
    print("wrote", HERE / name)
plt.close("all")

# %% [markdown]
# ## 6. Saving
#
# The DataTree saves as netCDF (any tool that reads netCDF/HDF5 opens it) and reads back with
# `xarray.open_datatree`. `result.save` writes what `galileo infer --out` writes (result.json
# and the sample record beside it), which `galileo.load_result` and `galileo predict` read.

# %%
import xarray as xr

idata.to_netcdf(HERE / "posterior.nc")
back = xr.open_datatree(HERE / "posterior.nc")
assert (back["posterior"]["k1"].values == idata["posterior"]["k1"].values).all()
print("reopened:", dict(back["posterior"].sizes), "converged:", json.loads(back.attrs["converged"]))

result.save(HERE / "result.json")
again = galileo.load_result(HERE / "result.json", tracks=HERE / "tracks.json")
print("result.json read back:", again.names, "MAP k1 =", round(again.map["k1"], 4))
