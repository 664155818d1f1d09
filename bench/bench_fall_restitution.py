"""Bullet's restitution against the fall scenario's contact law (issue 27): the measured bounce.

Why `galileo.scenarios.fall.physics` solves contacts as inelastic and applies Poisson's
restitution itself (its module docstring): this prints, as markdown tables, the bounce
e = sqrt(h_after / h_before) that each gives for an object released at rest and landing flat,
h the height of the object's lowest point above the surface (z = 0): h_before its release
height, h_after its first bounce's apex. Drops from HEIGHT_RANGE_M (15-50 cm: where in a time step
the contact begins changes from one to the next); statistics over the drops.

* Bullet alone, in a child process of its own (one DIRECT client per process): a fresh world
  with pybullet's default contact settings, gravity 9.81 m/s^2, a fixed step of 1/240 s and of
  1/480 s; the ground, restitution 1 (Bullet multiplies the two bodies' restitutions: the
  pair's is the body's r), a GEOM_PLANE z = 0 or a static GEOM_BOX slab with its top there
  (the scenario's ground; Bullet meets a box with a plane and with a box by different
  algorithms: a plane's manifold grows a point a step, two boxes' starts full); the body a sphere of
  radius 3 cm (SPHERE_RADIUS_M) or a GEOM_BOX of 8 x 5 x 4 cm (BOX_SIZE_M) landing on its
  8 x 5 face, restitution r. Also the landing's spin, the peak up to SPIN_WINDOW_S after the
  first stop (released without any: a box hit one corner a step spins up; a flat landing that
  stays flat has none).
* The scenario's law: `physics.simulate` on a `FallScene` (a box of BOX_SIZE_M on its 8 x 5
  face; a cylinder of CYLINDER_SIZE_M lying on its side, the scenario's round shape: it has no
  sphere) with restitution e, at the scenario's 240 Hz; also the second bounce over the first,
  sqrt(h_2 / h_1) (where the second bounce rises at least APEX_MIN_RISE_M).
* The wall time per simulated second of both, sampling every step (`simulate` with fps =
  sim_hz; Bullet: the pose read after every step), so the contact law's cost is known.

The apex: every physics step is sampled; the first sample after which the lowest point rises
is where the object stops falling, and the next local maximum at least APEX_MIN_RISE_M above
the surface is the bounce's apex (none: e = 0). The second bounce: the next stop after that
apex and the next maximum after it. (Sampling every step, an apex is low by at most
g dt^2 / 8, 0.02 mm at 240 Hz.)

    python bench/bench_fall_restitution.py [--heights 15] [--json]
"""
from __future__ import annotations

import argparse
import itertools
import json
import math
import multiprocessing
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np

from galileo.scenarios.fall import physics
from galileo.scenarios.fall.scene import FallScene
from galileo.shapes import Shape
from galileo.sim.bullet import client, client_lock, pb

G_MPS2 = 9.81
RESTITUTIONS = (0.1, 0.3, 0.5, 0.7, 0.9)
HEIGHT_RANGE_M = (0.15, 0.50)         # the lowest point's release height (the 15-50 cm)
BULLET_HZ = (240.0, 480.0)
SCENARIO_HZ = 240.0                   # the scenario's default rate
SPHERE_RADIUS_M = 0.03
BOX_SIZE_M = (0.08, 0.05, 0.04)       # landing on its 8 x 5 face
CYLINDER_SIZE_M = (0.10, 0.06, 0.06)  # the scenario's cylinder: axis along x, diameter 6 cm (the sphere's)
MASS_KG = 0.1                         # changes nothing (every force scales with it); Bullet needs one
SIM_S = 2.2                           # long enough for the second apex of a 50 cm drop at e = 0.9
APEX_MIN_RISE_M = 1e-4                # a maximum lower than this above the surface is no bounce
SPIN_WINDOW_S = 0.05                  # the landing's spin: the peak up to this long after the first stop
GROUNDS = ("plane", "slab")           # Bullet's ground: GEOM_PLANE z = 0, or a static GEOM_BOX with its top there
SLAB_HALF_M = 5.0                     # (the scenario's ground is such a slab)


def drop_heights_m(n: int) -> np.ndarray:
    return np.linspace(*HEIGHT_RANGE_M, n)


def apex_steps(low_m: np.ndarray, n: int) -> list[int]:
    """The samples of the first n bounces' apexes in the lowest point's heights `low_m` (one a
    step): after each stop (the first sample after which it rises), the next local maximum at
    least APEX_MIN_RISE_M above the surface. Fewer than n where the bounces die out."""
    out: list[int] = []
    i = 0
    while len(out) < n:
        rising = np.flatnonzero(np.diff(low_m[i:]) > 0)
        if not len(rising):
            break
        stop = i + int(rising[0])
        top = None
        for f in range(stop + 1, len(low_m) - 1):
            if low_m[f] >= low_m[f + 1] and low_m[f] >= APEX_MIN_RISE_M:
                top = f
                break
        if top is None:
            break
        out.append(top)
        i = top
    return out


def bounce_e(h_before_m: float, h_after_m: float | None) -> float:
    return math.sqrt(max(h_after_m, 0.0) / h_before_m) if h_after_m is not None else 0.0


# -- Bullet alone (run in a child process: its own client) -----------------------------------------

def _bullet_world(hz: float, shape: str, ground: str) -> tuple[int, int, float]:
    """A fresh world with pybullet's default contact settings at a step of 1/hz, the ground a
    GEOM_PLANE or a GEOM_BOX slab: (client, body, the body's lowest point below its centre when
    level)."""
    cid = client()
    pb.resetSimulation(physicsClientId=cid)
    pb.setPhysicsEngineParameter(fixedTimeStep=1.0 / hz, physicsClientId=cid)
    pb.setGravity(0, 0, -G_MPS2, physicsClientId=cid)
    if ground == "plane":
        col = pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=cid)
        ground_id = pb.createMultiBody(0.0, col, physicsClientId=cid)
    else:
        col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[SLAB_HALF_M] * 3, physicsClientId=cid)
        ground_id = pb.createMultiBody(0.0, col, basePosition=[0, 0, -SLAB_HALF_M], physicsClientId=cid)
    pb.changeDynamics(ground_id, -1, restitution=1.0, physicsClientId=cid)
    if shape == "sphere":
        col = pb.createCollisionShape(pb.GEOM_SPHERE, radius=SPHERE_RADIUS_M, physicsClientId=cid)
        below = SPHERE_RADIUS_M
    else:
        col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[s / 2 for s in BOX_SIZE_M], physicsClientId=cid)
        below = BOX_SIZE_M[2] / 2
    body = pb.createMultiBody(MASS_KG, col, basePosition=[0, 0, 1], physicsClientId=cid)
    return cid, body, below


def _bullet_drop(cid: int, body: int, shape: str, below_m: float, r: float, h_m: float, hz: float):
    """One drop from rest, lowest point at h_m: (the lowest point's height, release and after each
    step; the spin after each step (rad/s); the wall seconds stepping and reading took)."""
    pb.changeDynamics(body, -1, restitution=r, physicsClientId=cid)
    pb.resetBasePositionAndOrientation(body, [0, 0, h_m + below_m], [0, 0, 0, 1], physicsClientId=cid)
    pb.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0], physicsClientId=cid)
    n = round(SIM_S * hz)
    step, get_pose, get_vel = pb.stepSimulation, pb.getBasePositionAndOrientation, pb.getBaseVelocity
    poses, spins = [], []
    t0 = time.perf_counter()
    for _ in range(n):
        step(physicsClientId=cid)
        poses.append(get_pose(body, physicsClientId=cid))
        spins.append(get_vel(body, physicsClientId=cid)[1])
    wall = time.perf_counter() - t0
    half = np.asarray(BOX_SIZE_M) / 2
    low = np.empty(n + 1)
    low[0] = h_m
    for k, (pos, orn) in enumerate(poses, 1):
        if shape == "sphere":
            low[k] = pos[2] - SPHERE_RADIUS_M
        else:   # a box's lowest corner: its centre less |R_z.| . half extents
            rz = np.array(pb.getMatrixFromQuaternion(orn)).reshape(3, 3)[2]
            low[k] = pos[2] - float(np.abs(rz) @ half)
    return low, np.linalg.norm(np.asarray(spins), axis=1), wall


def bullet_part(heights_m: list[float]) -> dict:
    """Bullet alone, every shape, rate and r (run in a process of its own)."""
    out = {"rows": [], "timing": []}
    with client_lock:
        for shape, ground in itertools.product(("sphere", "box"), GROUNDS):
            for hz in BULLET_HZ:
                cid, body, below = _bullet_world(hz, shape, ground)
                wall = 0.0
                for r in RESTITUTIONS:
                    es, spins = [], []
                    for h in heights_m:
                        low, spin, w = _bullet_drop(cid, body, shape, below, r, h, hz)
                        wall += w
                        first = apex_steps(low, 1)
                        es.append(bounce_e(h, float(low[first[0]]) if first else None))
                        rising = np.flatnonzero(np.diff(low) > 0)
                        landed = int(rising[0]) if len(rising) else len(spin)
                        spins.append(float(spin[:landed + round(SPIN_WINDOW_S * hz)].max()))
                    out["rows"].append({"shape": shape, "ground": ground, "hz": hz, "r": r, "e": es,
                                        "spin_radps": spins})
                    print(f"  bullet {shape} on a {ground} {hz:g} Hz r = {r}: e {np.mean(es):.3f}", file=sys.stderr,
                          flush=True)
                out["timing"].append({"shape": shape, "ground": ground, "hz": hz, "wall_s": wall,
                                      "simulated_s": SIM_S * len(heights_m) * len(RESTITUTIONS)})
    return out


# -- the scenario's law (this process) --------------------------------------------------------------

def scenario_part(heights_m: list[float]) -> dict:
    """The scenario's law, both shapes and every e (this process's client, through `simulate`)."""
    out = {"rows": [], "timing": []}
    n = round(SIM_S * SCENARIO_HZ)
    for name, shape in (("box", Shape("box", BOX_SIZE_M)), ("cylinder", Shape("cylinder", CYLINDER_SIZE_M))):
        below = -physics.lowest_point_m(shape, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
        wall = 0.0
        for e in RESTITUTIONS:
            firsts, seconds = [], []
            for h in heights_m:
                s = FallScene(shape=shape, restitution=e, z0_m=h + below, fps=SCENARIO_HZ, sim_hz=SCENARIO_HZ,
                              n_frames=n, release_frame=0, mass_kg=MASS_KG)
                t0 = time.perf_counter()
                tr = physics.simulate(s, n)
                wall += time.perf_counter() - t0
                low = np.array([physics.lowest_point_m(shape, p, o)
                                for p, o in zip(tr.position_m[0], tr.orientation_xyzw[0])])
                ap = [float(low[k]) for k in apex_steps(low, 2)]
                firsts.append(bounce_e(h, ap[0] if ap else None))
                seconds.append(bounce_e(ap[0], ap[1]) if len(ap) == 2 else None)
            out["rows"].append({"shape": name, "hz": SCENARIO_HZ, "r": e, "e": firsts, "e2": seconds})
            print(f"  scenario {name} e = {e}: e {np.mean(firsts):.3f}", file=sys.stderr, flush=True)
        out["timing"].append({"shape": name, "hz": SCENARIO_HZ, "wall_s": wall,     # frame 0 is the release
                              "simulated_s": (n - 1) / SCENARIO_HZ * len(heights_m) * len(RESTITUTIONS)})
    return out


# -- tables -----------------------------------------------------------------------------------------

def _stats(xs) -> str:
    a = np.asarray([x for x in xs if x is not None], float)
    if not len(a):
        return "— | — | —"
    return f"{a.mean():.3f} | {a.std(ddof=1) if len(a) > 1 else 0.0:.4f} | {a.min():.3f}–{a.max():.3f}"


def tables(bullet: dict, scen: dict, n_heights: int) -> str:
    lo, hi = (100 * h for h in HEIGHT_RANGE_M)
    drops = f"{n_heights} drops of the lowest point from {lo:g} to {hi:g} cm, released at rest, landing flat"
    lines = [(f"Bullet alone (default contact settings; ground restitution 1, body r; {drops}): "
              "e = sqrt(h_after / h_before)"), "",
             "| shape | ground | Hz | Bullet r | e mean | e SD | e min–max | landing spin, rad/s (max) |",
             "|---|---|---|---|---|---|---|---|"]
    for row in bullet["rows"]:
        lines.append(f"| {row['shape']} | {row['ground']} | {row['hz']:g} | {row['r']:g} | {_stats(row['e'])} | "
                     f"{max(row['spin_radps']):.1f} |")
    lines += ["", (f"The scenario's law (`physics.simulate`, {SCENARIO_HZ:g} Hz; the same drops): e of the first "
                   "bounce, and sqrt(h_2 / h_1) of the second over the first (n: the drops whose second bounce "
                   f"rises ≥ {APEX_MIN_RISE_M * 1000:g} mm)"), "",
              "| shape | latent e | e mean | e SD | e min–max | 2nd/1st mean | SD | min–max | n |",
              "|---|---|---|---|---|---|---|---|---|"]
    for row in scen["rows"]:
        n = sum(x is not None for x in row["e2"])
        lines.append(f"| {row['shape']} | {row['r']:g} | {_stats(row['e'])} | {_stats(row['e2'])} | {n} |")
    lines += ["", ("Wall time per simulated second (every step sampled, all drops and e together; one process; "
                   "the scenario's body is a compound of small spheres on a slab)"), "",
              "| method | shape | ground | Hz | ms per simulated s |", "|---|---|---|---|---|"]
    for what, part in (("Bullet alone", bullet), ("scenario's law", scen)):
        for t in part["timing"]:
            lines.append(f"| {what} | {t['shape']} | {t.get('ground', 'slab')} | {t['hz']:g} | "
                         f"{1000 * t['wall_s'] / t['simulated_s']:.1f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--heights", type=int, default=15, help="drop heights from 15 to 50 cm (default 15)")
    ap.add_argument("--json", action="store_true", help="print one JSON object instead of the tables")
    args = ap.parse_args(argv)
    if args.heights < 2:
        ap.error("--heights must be >= 2")
    heights = drop_heights_m(args.heights).tolist()
    print("Bullet alone (a child process) ...", file=sys.stderr, flush=True)
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as ex:
        bullet = ex.submit(bullet_part, heights).result()
    print("the scenario's law ...", file=sys.stderr, flush=True)
    scen = scenario_part(heights)
    if args.json:
        print(json.dumps({"heights_m": heights, "bullet": bullet, "scenario": scen,
                          "python": platform.python_version(), "pybullet_api": pb.getAPIVersion()}))
    else:
        print(tables(bullet, scen, args.heights))
    return 0


if __name__ == "__main__":
    sys.exit(main())
