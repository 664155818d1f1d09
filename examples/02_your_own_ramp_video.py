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
# # Your own ramp video: four clicks, a scene file, a posterior, predictions
#
# To infer anything from a video Galileo needs a *scene file*: where the camera is and how it
# sees (its focal length), the ramp's angle and size, where the object starts, and the target
# box if there is one. For a video you filmed yourself you make it with `galileo scene` from
#
# * **four points you click on the video's first frame**: two on the ramp's side edges some
#   known distance up the ramp, and the two corners of its foot, and
# * **a few numbers you measure** with a ruler and a protractor: the ramp's length, width and
#   angle (and the target box's distance and size).
#
# The camera's position, orientation and focal length follow from the four points (a planar
# pose fit); where the object starts is found in the first frame. Then the video is tracked,
# inferred and used for prediction as any other.
#
# Here "your video" is the rendered demo (a wooden block sliding into a cardboard box at 20
# degrees), so that the answers can be checked against the truth; the points are computed from
# the demo's known camera instead of being read off the image, rounded to whole pixels as a click
# is. Replace `VIDEO`, `CLICKS` and the measurements with your own.

# %%
import json
import os
import shutil
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
# The paper's 16 chains x 75 sweeps; `GALILEO_EXAMPLES_SMALL=1` shrinks them to seconds (the
# tests run it so).

# %%
SMALL = os.environ.get("GALILEO_EXAMPLES_SMALL") == "1"
CHAINS = 4 if SMALL else 16
SWEEPS = 12 if SMALL else 75
SEED = 0

OUT = Path(os.environ.get("GALILEO_EXAMPLES_OUT", "galileo-examples-out")).resolve()
HERE = OUT / "02_your_own_ramp_video"
HERE.mkdir(parents=True, exist_ok=True)
DEMO = Path(os.environ.get("GALILEO_EXAMPLES_DEMO", OUT / "datasets" / "ramp-demo-seed0")).resolve()


def galileo_cli(*args) -> str:
    """Run `galileo ARGS...` (the command line; `!galileo ...` in a notebook) and return its output."""
    print("$ galileo", " ".join(map(str, args)))
    done = subprocess.run([sys.executable, "-m", "galileo", *map(str, args)], capture_output=True, text=True)
    print(done.stdout + done.stderr)
    done.check_returncode()
    return done.stdout


# %% [markdown]
# ## 1. The video
#
# Your video: any frame rate and resolution; the camera held still (a tripod), the ramp's foot
# and a stretch of its side edges in view. Here: the demo, rendered once.

# %%
if not (DEMO / "index.json").is_file():
    galileo_cli("dataset", "--scenario", "ramp", "--preset", "demo", "--seed", 0, "--out", DEMO, "--quiet")
VIDEO = HERE / "my_ramp.mp4"
shutil.copyfile(DEMO / "demo" / "video.mp4", VIDEO)

# %% [markdown]
# ## 2. The first frame, and the four points
#
# Save the first frame and read the points off it in any image viewer that shows pixel
# coordinates (or in `python app.py --upload`, which lets you click them in the browser). The
# order matters: **upper near, upper far, foot far, foot near** ("near": the side edge closer to
# the camera). The upper points can be any marks on the two side edges at a known distance up
# from the foot (`--upper-at-m`); the ramp's top is often out of the frame.

# %%
from galileo.video import read_frames

first_frame = next(iter(read_frames(VIDEO)))[..., :3]
plt.imsave(HERE / "first_frame.png", first_frame)
print(f"first frame {first_frame.shape[1]} x {first_frame.shape[0]} px: {HERE / 'first_frame.png'}")

# %% [markdown]
# What a user would click: since this is the demo, the points are the demo's ramp corners and
# marks 0.5 m up its side edges, projected with the demo's true camera and rounded to pixels.
# (Galileo's own helpers do the projecting; with your video you skip this cell and type the
# numbers you read.)

# %%
from galileo.scenarios.ramp.clicks import ramp_points_in_world

true_scene = galileo.load_scene(DEMO / "demo" / "scene.json")    # (only to make up the clicks)
ramp = true_scene.ramp
UPPER_AT_M = 0.5
world_points = ramp_points_in_world(ramp.length_m, ramp.width_m, ramp.angle_deg, upper_at_m=UPPER_AT_M)
CLICKS = [(round(u), round(v)) for u, v in true_scene.camera.project(world_points)]
print("clicks (upper near, upper far, foot far, foot near):", CLICKS)

# %% [markdown]
# ## 3. The measurements, and the scene file
#
# Measured with a ruler: the ramp board (90 x 30 cm at 20 degrees), the cardboard box in front
# of its foot (12 cm from the foot, about 9.5 x 7 x 6 cm). Not given: the focal length
# (estimated from the four points) and the object's start (found in the first frame).

# %%
MEASURED = {"--ramp-length-m": 0.90, "--ramp-width-m": 0.30, "--angle-deg": 20,
            "--upper-at-m": UPPER_AT_M, "--target": "cardboard", "--target-distance-m": 0.12,
            "--target-size-m": "0.095,0.07,0.06"}
points = " ".join(f"{u},{v}" for u, v in CLICKS)
flags = [x for kv in MEASURED.items() for x in kv]
galileo_cli("scene", VIDEO, "--points", points, *flags, "--out", HERE / "scene.json")
scene = galileo.load_scene(HERE / "scene.json")

# %% [markdown]
# Check the scene by eye: the ramp's outline (yellow), a 10 cm grid on the floor, the object's
# start (green) and the target (cyan), drawn with the solved camera over the first frame, with
# your clicks (red). If they do not sit on the image, a click is off or a measurement is wrong.

# %%
from galileo.clicks import calibration_of

overlay = calibration_of("ramp").draw_overlay(first_frame, scene, CLICKS)
plt.imsave(HERE / "overlay.png", overlay)
cam_err_m = ((scene.camera.position_in_world - true_scene.camera.position_in_world) ** 2).sum() ** 0.5
print(f"focal {scene.camera.K[0, 0]:.0f} px (true {true_scene.camera.K[0, 0]:.0f}); camera within "
      f"{100 * cam_err_m:.1f} cm of the true one; start {scene.start_distance_m():.3f} m up the ramp "
      f"(true {true_scene.start_distance_m():.3f})")

# %% [markdown]
# ## 4. Track and infer
#
# As for any video (see example 01 for reading the result): the block's friction `k1` and the
# mass ratio `m1/m2` are what one such video identifies.

# %%
tracks = galileo.track(VIDEO, scene)
tracks.save(HERE / "tracks.json")
result = galileo.infer(scene, tracks, chains=CHAINS, sweeps=SWEEPS, seed=SEED)
print(result)
result.save(HERE / "result.json")

truth = json.loads((DEMO / "demo" / "truth.json").read_text())["latents"]
ratio = result.posterior_derived["mass_ratio"]
print(f"k1: {result.posterior['k1']['q50']:.3f} (90%: {result.posterior['k1']['q05']:.3f}-"
      f"{result.posterior['k1']['q95']:.3f}), truth {truth['k1']:.3f}")
print(f"m1/m2: {ratio['q50']:.2f} (90%: {ratio['q05']:.2f}-{ratio['q95']:.2f}), "
      f"truth {truth['m1_kg'] / truth['m2_kg']:.2f}")

# %% [markdown]
# ## 5. Predict
#
# The paper's questions, answered by simulating with the inferred values: would the block slide
# at all on a 10 degree ramp (it slides when its friction is below tan 10 deg = 0.176), and where
# does the box end up? `posterior_share_moving` and the target's interval come from the
# posterior draws: trust them only when the run converged (the answer says).

# %%
answers = galileo.predict(result, angle_deg=10.0, target=True)
print(json.dumps(answers, indent=1))
(HERE / "predictions.json").write_text(json.dumps(answers, indent=1))
plt.close("all")
