"""A small second scenario, used only by the tests: a ball dropped onto the ground.

One latent, the ball's restitution `e`; observations are the ball's tracked vertical
velocity. It proves the scenario interface (`galileo.model.Scenario`): the tests register
it at run time (`galileo.registry.register(DropScenario())`) and run it through
`galileo infer`, the app's controller, the viewer's server side and rerun logging, with
no edit anywhere but this folder.

    scene file --scene_from_json--> DropScene (scene.py)
    DropScene --physics.simulate--> Trajectory (physics.py: Bullet via galileo.sim.bullet)
    (scene, Tracks, sigma) --likelihood--> DropLikelihood (Gaussian on v_z per visible frame)
    DropScene --drawing--> ground, ball, and a spring drawn from a fixed hook to the ball (a
                           connector whose end follows the ball; drawn only, it exerts no force)
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from galileo.datatypes import ObjectTrack, Tracks, Trajectory
from galileo.drawing import Anchor, Connector
from galileo.errors import GalileoError
from galileo.latents import Noise
from galileo.model import Drawing, Mesh, Scenario
from galileo.shapes import Shape

from . import physics
from .scene import BALL, DropScene, e_latent, newton_rebound_mps, scene_from_json  # noqa: F401

GROUND_COLOR = (150, 150, 150)
BALL_COLOR = (220, 60, 160)
# a drawn spring (drawing only, no force) from a hook this far above the ball's top at release to
# the ball's top: a connector whose one end follows a body
HOOK_ABOVE_M = 0.1
SPRING_COILS = 8
SPRING_RADIUS_PER_BALL_RADIUS = 0.6
SPRING_COLOR = (40, 40, 40)
TRACKS_FILE = "tracks.json"   # `track` reads the tracks from this file next to the video


class DropLikelihood:
    """log N(v_z obs | v_z sim, sigma^2) summed over the frames where the ball was seen.

    Each term is the normalising constant plus -(residual / sigma)^2 / 2 <= 0, so with a
    threshold (and speed-ups) the simulation stops as soon as the partial sum is below it."""

    def __init__(self, scene: DropScene, tracks: Tracks, sigma: float, speedups: bool = True):
        self.scene = scene
        self.names = ("e",)
        self.steps = 0
        self.fps = tracks.fps
        self.n_frames = tracks.n_frames
        self.sigma = float(sigma)
        self.speedups = speedups
        ball = tracks.objects[0]
        self.seen = np.asarray(ball.visible, bool)
        self.vz_obs = np.nan_to_num(np.asarray(ball.velocity_mps, float)[:, 2])
        self.log_norm = -int(self.seen.sum()) * math.log(self.sigma * math.sqrt(2 * math.pi))
        self._half_prec = -0.5 / self.sigma ** 2

    def __call__(self, position, threshold: float | None = None) -> tuple[float, bool]:
        e = float(position[0])
        limit = -math.inf if (threshold is None or not self.speedups) else threshold - self.log_norm
        total = 0.0
        for f, _, vel, _, steps in physics.frames(self.scene, self.n_frames, e, self.fps):
            self.steps += steps
            if self.seen[f]:
                total += self._half_prec * (vel[2] - self.vz_obs[f]) ** 2
                if total < limit:
                    return self.log_norm + total, True
        return self.log_norm + total, False

    def motion(self, position) -> Trajectory:
        """The motion scored (the same simulation, every frame)."""
        return physics.simulate(self.scene, self.n_frames, float(position[0]), self.fps)


class DropScenario(Scenario):
    name = "drop"
    description = "a ball dropped onto the ground (test scenario): its restitution from its tracked vertical velocity"
    noise = Noise("sigma_vz_mps", "m/s", 0.05, "SD of the tracked vertical velocity")

    def scene_from_json(self, data):
        return scene_from_json(data)

    def default_scene(self) -> DropScene:
        return DropScene()

    def latents(self, scene: DropScene):
        return (e_latent(scene.e_bounds),)

    def with_values(self, scene: DropScene, values):
        return scene.with_values(values)

    def track(self, video_path, scene, *, progress: bool = True, debug_video=None) -> Tracks:
        path = Path(video_path).with_name(TRACKS_FILE)
        if not path.is_file():
            raise GalileoError(f"the drop scenario is for tests: it tracks nothing (give --tracks, or put "
                               f"{TRACKS_FILE} next to the video)")
        return Tracks.load(path)

    def prepare(self, scene: DropScene, tracks: Tracks) -> DropScene:
        if len(tracks.objects) != 1 or tracks.objects[0].name != BALL:
            raise GalileoError(f"the drop scenario needs tracks of one object named {BALL!r}, got "
                               f"{[o.name for o in tracks.objects]}")
        if tracks.n_frames < 2:
            raise GalileoError(f"the drop scenario needs at least 2 tracked frames, got {tracks.n_frames}")
        physics.steps_per_frame(scene, tracks.fps)   # GalileoError unless sim_hz is a multiple
        return scene

    def simulate(self, scene: DropScene, n_frames, values=None, fps=None) -> Trajectory:
        if values:
            scene = scene.with_values(values)
        return physics.simulate(scene, n_frames, fps=fps)

    def likelihood(self, prepared_scene: DropScene, tracks: Tracks, noise, speedups=True) -> DropLikelihood:
        return DropLikelihood(prepared_scene, tracks, noise, speedups)

    def drawing(self, scene: DropScene) -> Drawing:
        import trimesh

        ground = trimesh.creation.box(extents=(0.6, 0.6, 0.01))
        ground.apply_translation((0, 0, -0.005))
        ball = trimesh.creation.icosphere(subdivisions=2, radius=scene.radius_m)
        return Drawing(static=(Mesh("ground", np.asarray(ground.vertices), np.asarray(ground.faces),
                                    GROUND_COLOR, 0.6),),
                       objects=(Mesh(BALL, np.asarray(ball.vertices), np.asarray(ball.faces), BALL_COLOR),),
                       ground_z_m=0.0, connectors=(spring(scene),))

    @property
    def synthetic(self):
        from galileo.capabilities import Synthetic

        return Synthetic(synthetic_tracks)

    def derived(self, scene, values):
        return {"energy_kept": values["e"] ** 2} if "e" in values else {}

    def video_timing(self, scene: DropScene):
        return scene.fps, scene.n_frames


def spring(scene: DropScene) -> Connector:
    """The drawn spring: a helix from the hook (fixed, above the release point) to the ball's top."""
    hook_z_m = scene.height_m + 2 * scene.radius_m + HOOK_ABOVE_M
    return Connector("spring", Anchor.fixed((0.0, 0.0, hook_z_m)), Anchor.on(0, (0.0, 0.0, scene.radius_m)),
                     SPRING_COLOR, coils=SPRING_COILS, radius_m=SPRING_RADIUS_PER_BALL_RADIUS * scene.radius_m)


def tracks_from(traj: Trajectory, scene: DropScene, *, noise_mps: float = 0.0, seed: int = 0) -> Tracks:
    """Tracks of a simulated drop (observations for the tests), with Gaussian noise of SD
    `noise_mps` on every velocity component (a fixed seed)."""
    rng = np.random.default_rng(seed)
    pos = traj.position_m[0].copy()
    vel = traj.velocity_mps[0] + noise_mps * rng.standard_normal(traj.velocity_mps[0].shape)
    d = 2 * scene.radius_m
    ball = ObjectTrack(BALL, "ball", pos, vel, np.ones(traj.n_frames, bool), Shape("sphere", (d, d, d)),
                       detected_by="test")
    return Tracks(traj.fps, [ball])


def synthetic_tracks(scene: DropScene, values: dict, rng: np.random.Generator, noise: float) -> Tracks:
    """The observations the likelihood assumes at `values`: the simulated drop, N(0, noise^2) on its velocities."""
    traj = physics.simulate(scene.with_values(values), scene.n_frames, fps=scene.fps)
    vel = traj.velocity_mps[0] + noise * rng.standard_normal(traj.velocity_mps[0].shape)
    d = 2 * scene.radius_m
    ball = ObjectTrack(BALL, "ball", traj.position_m[0].copy(), vel, np.ones(traj.n_frames, bool),
                       Shape("sphere", (d, d, d)), detected_by="test")
    return Tracks(traj.fps, [ball])
