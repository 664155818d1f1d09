"""Simulations per second: galileo.physics.Simulator.run against a bare pybullet loop.

Both run the demo-like scene (default_scene(20, target="cardboard")) in the same process, on the
same Bullet world, with the same latents (drawn from the scene's priors, different for every run):

* simulator: Simulator(scene).run(n_frames, latents, fps=fps)
* bare:      restoreState + changeDynamics (mass, inertia, friction, restitution per object)
             + the same stepSimulation calls + reading base pose and velocity into arrays once
             per frame (every sim_hz / fps = 8 steps), written directly with pybullet calls.

n frames means frame 0 at t = 0 and then (n - 1) * 8 steps, exactly what Simulator.run does
(90 frames: 712 steps of 1/240 s). The two are interleaved in rounds (alternating which goes
first, every round repeating the same batch of latents) and the medians over rounds are
compared; the target is simulator / bare >= 0.9.

    python bench/bench_sim.py [--rounds 21] [--runs 10] [--json]
"""
from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from galileo.scenarios.ramp.physics import Simulator  # noqa: E402  (imports pybullet without its banner)
from galileo.scenarios.ramp.scene import default_scene  # noqa: E402

import pybullet as pb  # noqa: E402

TARGET_RATIO = 0.9


def make_bare_run(sim: Simulator, n_frames: int, fps: float):
    """A hand-written pybullet loop doing the simulator's work on its world."""
    scene = sim.scene
    world = sim.world
    cid, bodies, state = world.cid, list(world.bodies), world.state
    inertia = [np.asarray(i, float) for i in world.inertia_per_kg]
    restitution = [o.restitution for o in scene.objects]
    spf = int(round(scene.sim_hz / fps))
    n_obj = len(bodies)
    restore, change, step = pb.restoreState, pb.changeDynamics, pb.stepSimulation
    get_pose, get_vel = pb.getBasePositionAndOrientation, pb.getBaseVelocity

    def run(values: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
        restore(state, physicsClientId=cid)
        for i, b in enumerate(bodies):
            n = str(i + 1)
            m = values["m" + n + "_kg"]
            change(b, -1, mass=m, localInertiaDiagonal=(m * inertia[i]).tolist(),
                   lateralFriction=values["k" + n], restitution=restitution[i], physicsClientId=cid)
        pos = np.empty((n_obj, n_frames, 3))
        vel = np.empty((n_obj, n_frames, 3))
        for f in range(n_frames):
            if f:
                for _ in range(spf):
                    step(physicsClientId=cid)
            for i, b in enumerate(bodies):
                pos[i, f] = get_pose(b, physicsClientId=cid)[0]
                vel[i, f] = get_vel(b, physicsClientId=cid)[0]
        return pos, vel

    return run


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=21, help="interleaved rounds (default 21)")
    ap.add_argument("--runs", type=int, default=10, help="simulations per method per round (default 10)")
    ap.add_argument("--frames", type=int, default=90, help="frames per simulation (default 90)")
    ap.add_argument("--fps", type=float, default=30.0, help="frame rate (default 30)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    args = ap.parse_args(argv)
    if args.rounds < 1 or args.runs < 1 or args.frames < 1:
        ap.error("--rounds, --runs and --frames must be >= 1")

    scene = default_scene(20, target="cardboard")
    sim = Simulator(scene)
    bare = make_bare_run(sim, args.frames, args.fps)
    steps = (args.frames - 1) * int(round(scene.sim_hz / args.fps))
    rng = np.random.default_rng(args.seed)
    names = scene.latent_names

    def simulator_batch(latents):
        for v in latents:
            sim.run(args.frames, v, fps=args.fps)

    def bare_batch(latents):
        for v in latents:
            bare(v)

    # warm up both (world build, caches)
    warm = [scene.priors.sample(rng, names) for _ in range(3)]
    simulator_batch(warm)
    bare_batch(warm)

    # one batch of latents (different for every run in it) that every round repeats, so rounds
    # measure the same work and their medians compare
    latents = [scene.priors.sample(rng, names) for _ in range(args.runs)]
    sim_rates, bare_rates = [], []
    for r in range(args.rounds):
        order = [("simulator", simulator_batch), ("bare", bare_batch)]
        if r % 2:
            order.reverse()
        for name, batch in order:
            t0 = time.perf_counter()
            batch(latents)
            rate = args.runs / (time.perf_counter() - t0)
            (sim_rates if name == "simulator" else bare_rates).append(rate)

    sim_med, bare_med = statistics.median(sim_rates), statistics.median(bare_rates)
    ratio = sim_med / bare_med
    paired = statistics.median(a / b for a, b in zip(sim_rates, bare_rates))
    result = {
        "scene": "default_scene(20, target='cardboard')",
        "frames": args.frames, "fps": args.fps, "sim_hz": scene.sim_hz, "steps_per_run": steps,
        "rounds": args.rounds, "runs_per_round": args.runs, "seed": args.seed,
        "simulator_runs_per_s": sim_med, "bare_runs_per_s": bare_med,
        "ratio": ratio, "paired_ratio": paired, "target_ratio": TARGET_RATIO, "ok": ratio >= TARGET_RATIO,
        "simulator_runs_per_s_rounds": sim_rates, "bare_runs_per_s_rounds": bare_rates,
        "python": platform.python_version(), "machine": platform.machine(),
    }
    if args.json:
        print(json.dumps(result))
    else:
        print(f"scene: {result['scene']}, {args.frames} frames at {args.fps:g} fps = {steps} steps at "
              f"{scene.sim_hz} Hz; {args.rounds} rounds x {args.runs} runs each, interleaved")
        print(f"Simulator.run  : {sim_med:8.1f} simulations/s  (rounds {min(sim_rates):.1f}-{max(sim_rates):.1f})")
        print(f"bare pybullet  : {bare_med:8.1f} simulations/s  (rounds {min(bare_rates):.1f}-{max(bare_rates):.1f})")
        print(f"ratio          : {ratio:8.3f}  (target >= {TARGET_RATIO}: {'ok' if result['ok'] else 'BELOW'}; "
              f"median of per-round ratios {paired:.3f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
