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
# # Several videos, one problem
#
# One ramp video identifies the sliding object's friction and the *ratio* of the two masses in
# the collision, never the masses themselves (example 01). Several videos of the same object
# say more when they are inferred together, as one problem: the object's properties are then
# one set of latents that every video must explain.
#
# Here the same wooden block (0.16 kg, friction 0.22) slides down the same 20 degree ramp in
# `N_VIDEOS` videos, each time into a different cardboard box. Two problems:
#
# * **share the block's friction** (`share=["k1"]`): one `k1` for all videos, each video its own
#   masses and box friction. The friction is measured by every slide at once; the masses still
#   only as ratios, one per video.
# * **weigh the block against a reference** (`share=["m1_kg", "k1"]`, `fix={"m2_kg@1": ...}`):
#   the box in video 1 is one whose mass we know (weighed on a kitchen scale). Its collision turns
#   the mass ratio into the block's mass, and since the block is the same in every video, its mass
#   carries over to weigh the other boxes.
#
# Names: a latent that differs between videos is named `NAME@V` (V = 1, 2, ... in the order the
# videos are given); a shared one keeps its name. `fix` takes `NAME` (every video) or `NAME@V`.

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
# `GALILEO_EXAMPLES_SMALL=1` (the tests): 2 videos, 4 chains x 12 sweeps. Otherwise 3 videos and
# the paper's 16 x 75 (more latents than one video has: give it more sweeps if it has not
# converged).

# %%
SMALL = os.environ.get("GALILEO_EXAMPLES_SMALL") == "1"
N_VIDEOS = 2 if SMALL else 3
CHAINS = 4 if SMALL else 16
SWEEPS = 12 if SMALL else 75
SEED = 0

OUT = Path(os.environ.get("GALILEO_EXAMPLES_OUT", "galileo-examples-out")).resolve()
HERE = OUT / "04_several_videos_one_problem"
HERE.mkdir(parents=True, exist_ok=True)

# %% [markdown]
# ## The videos
#
# The ramp's `demo` preset rendered with different seeds: the same block and ramp, the block
# starting a few centimetres higher or lower, a different cardboard box (size, mass, friction,
# distance) each time. In a notebook: `!galileo dataset --preset demo --seed 1 --out DIR`.

# %%
folders = []
for seed in range(N_VIDEOS):
    data = OUT / "datasets" / f"ramp-demo-seed{seed}"
    if not (data / "index.json").is_file():
        args = ["dataset", "--scenario", "ramp", "--preset", "demo", "--seed", str(seed), "--out", str(data), "--quiet"]
        print("$ galileo", " ".join(args))
        subprocess.run([sys.executable, "-m", "galileo", *args], check=True)
    folders.append(data / "demo")

scenes = [galileo.load_scene(f / "scene.json") for f in folders]
truths = [json.loads((f / "truth.json").read_text())["latents"] for f in folders]
for v, t in enumerate(truths, 1):
    print(f"video {v}: block {t['m1_kg']:.3f} kg, k1 {t['k1']:.3f}; box {t['m2_kg']:.3f} kg, k2 {t['k2']:.3f}; "
          f"m1/m2 {t['m1_kg'] / t['m2_kg']:.2f}")

# %% [markdown]
# Tracking is per video; both problems below reuse the tracks.

# %%
tracks = [galileo.track(f / "video.mp4", s) for f, s in zip(folders, scenes)]
for v, t in enumerate(tracks, 1):
    t.save(HERE / f"tracks_video{v}.json")


# %%
def interval(result, name: str) -> str:
    s = {**result.posterior, **result.posterior_derived}[name]
    return f"{s['q50']:.3f} (90%: {s['q05']:.3f}-{s['q95']:.3f})"


# %% [markdown]
# ## Problem 1: one friction for the block
#
# The masses stay per video (`m1_kg@1`, `m2_kg@1`, ...): each video its own ratio.

# %%
shared_friction = galileo.infer(scenes, tracks, share=["k1"], chains=CHAINS, sweeps=SWEEPS, seed=SEED)
print(shared_friction)
print("latents:", shared_friction.names)
print(f"k1 = {interval(shared_friction, 'k1')}, truth {truths[0]['k1']:.3f}")
for v, t in enumerate(truths, 1):
    print(f"m1/m2 in video {v} = {interval(shared_friction, f'mass_ratio@{v}')}, "
          f"truth {t['m1_kg'] / t['m2_kg']:.2f}")
shared_friction.save(HERE / "shared_friction.json")

# %% [markdown]
# ## Problem 2: weigh the block against a box of known mass
#
# The block's mass and friction are shared; the box in video 1 is fixed at its (known) mass, so
# it is no longer sampled. Now `m1_kg` has a posterior of its own, and through each video's mass
# ratio so do the other boxes' masses: `m2_kg@2 = m1_kg / mass_ratio@2`.

# %%
reference_kg = round(truths[0]["m2_kg"], 3)     # what the kitchen scale says
weighed = galileo.infer(scenes, tracks, share=["m1_kg", "k1"], fix={"m2_kg@1": reference_kg},
                        chains=CHAINS, sweeps=SWEEPS, seed=SEED)
print(weighed)
print("latents:", weighed.names, "fixed: m2_kg@1 =", reference_kg)
print(f"block m1_kg = {interval(weighed, 'm1_kg')}, truth {truths[0]['m1_kg']:.3f}")
for v, t in enumerate(truths[1:], 2):
    print(f"box m2_kg@{v} = {interval(weighed, f'm2_kg@{v}')}, truth {t['m2_kg']:.3f}")
weighed.save(HERE / "weighed.json")

# %% [markdown]
# ## What the shared posterior says
#
# Friction: every slide measures the same `k1`, so one shared latent's interval is at most as
# wide as one video's. Masses: without a reference the videos agree on ratios only (any mass of
# the block, scaled with all the boxes, explains every video); one reference mass fixes the scale
# of them all.
#
# The same in ArviZ: the posterior has the shared latents once and the per-video ones with
# their `@V` names; `observed_data` has each video's tracks (`position_m_video1`, ...).

# %%
import arviz_stats

idata = weighed.to_arviz()
print(list(idata["posterior"].data_vars))
print(list(idata["observed_data"].data_vars))
print(arviz_stats.summary(idata, ci_prob=0.9, round_to=3).to_string())
idata.to_netcdf(HERE / "weighed.nc")
print("converged:", weighed.converged, "|", "; ".join(weighed.why_not[:2]))
