"""The only door to pybullet: the module imported without its "pybullet build time" banner
(C-level stderr), the process's single DIRECT client (a forked child connects its own,
never its parent's) and the lock its threads share it under, a per-process scratch folder for mesh files, and collision and
visual shapes made from `galileo.shapes` shapes."""
from __future__ import annotations

import ctypes
import multiprocessing.util as mp_util
import os
import shutil
import sys
import tempfile
import threading
from pathlib import Path
from typing import Any, Callable

import trimesh

from ..shapes import CollisionHulls, Shape


def _import_quietly():
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no real stdout (e.g. captured): import as is
        import pybullet
        return pybullet
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        import pybullet
        try:  # the banner sits in C's stdio buffer: flush it into /dev/null
            ctypes.CDLL(None).fflush(None)
        except (OSError, AttributeError):
            pass
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)
    return pybullet


pb = _import_quietly()


# -- the process's single pybullet client -----------------------------------------------

_client: int | None = None
# The client is one per process and Bullet is not thread-safe: a thread that simulates in a
# process where others may too (the app's viewer re-simulating a scrubbed sample while its
# rerun feed simulates the MAP) holds this lock for the whole simulation, from the world's
# restore to the last step. Two threads stepping one world at once corrupt each other's
# trajectories. (The samplers' worker processes have a client of their own each.)
client_lock = threading.RLock()
_client_pid: int | None = None
_world = None          # the world built last in this process's client (see `cached_world`)
_mesh_dir: Path | None = None
_mesh_dir_pid: int | None = None


def client() -> int:
    """The process's pybullet client (a forked child connects its own, never its parent's)."""
    global _client, _client_pid, _world
    if _client is None or _client_pid != os.getpid() or not pb.isConnected(_client):
        _client = pb.connect(pb.DIRECT)
        _client_pid = os.getpid()
        _world = None
    return _client


def cached_world(key, build: Callable[[], Any]):
    """The world built for `key` in this process's client, built by `build()` (which resets
    the simulation) when the last world built had another key. One world lives at a time:
    worlds are cheap to keep and costly (milliseconds) to build, and a sampler asks for the
    same one thousands of times."""
    global _world
    cid = client()
    if _world is None or _world.key != key or _world.cid != cid:
        _world = None
        _world = build()
    return _world


def new_world(sim_hz: float, gravity_mps2: float, solver_iterations: int) -> int:
    """Empty this process's client for a new world (fixed step of 1/sim_hz, no substeps,
    deterministic pair order, `solver_iterations`, gravity along -z); the client id."""
    cid = client()
    pb.resetSimulation(physicsClientId=cid)
    pb.setPhysicsEngineParameter(fixedTimeStep=1.0 / sim_hz, numSubSteps=0, deterministicOverlappingPairs=1,
                                 numSolverIterations=solver_iterations, physicsClientId=cid)
    pb.setGravity(0, 0, -gravity_mps2, physicsClientId=cid)
    return cid


def scratch_dir() -> Path:
    """This process's folder for mesh and texture files (a forked child makes its own: two
    processes writing the same file name made the renderer read half-written textures)."""
    global _mesh_dir, _mesh_dir_pid
    if _mesh_dir is None or _mesh_dir_pid != os.getpid():
        _mesh_dir = Path(tempfile.mkdtemp(prefix="galileo-meshes-"))
        _mesh_dir_pid = os.getpid()
        # (atexit handlers do not run in multiprocessing's forked workers; its finalizers do,
        # in the parent too, and a child drops the ones it inherited)
        mp_util.Finalize(None, shutil.rmtree, args=(str(_mesh_dir),), kwargs={"ignore_errors": True},
                         exitpriority=0)
    return _mesh_dir


def collision_shape(shape: Shape, cid: int) -> int:
    """A Bullet collision shape for `shape` in its object frame, as the shape describes it
    (`Shape.collision`: one primitive, or a compound of convex hulls)."""
    c = shape.collision()
    if isinstance(c, CollisionHulls):
        files = []
        d = scratch_dir()
        for i, pts in enumerate(c.parts):
            f = d / f"{c.name}_{i}.obj"
            if not f.exists():
                trimesh.convex.convex_hull(pts).export(f)
            files.append(str(f))
        n = len(files)
        return pb.createCollisionShapeArray([pb.GEOM_MESH] * n, fileNames=files, meshScales=[[1, 1, 1]] * n,
                                            physicsClientId=cid)
    args = dict(c.args)
    if c.frame_euler is not None:
        args["collisionFrameOrientation"] = pb.getQuaternionFromEuler(list(c.frame_euler))
    return pb.createCollisionShape(getattr(pb, f"GEOM_{c.geom.upper()}"), **args, physicsClientId=cid)


def visual_shape(shape: Shape, cid: int) -> int:
    m = shape.render_mesh()
    return pb.createVisualShape(pb.GEOM_MESH, vertices=m.vertices.tolist(), indices=m.indices.tolist(),
                                uvs=m.uvs.tolist(), normals=m.normals.tolist(), physicsClientId=cid)
