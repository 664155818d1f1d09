"""The scenario interface: everything the rest of Galileo knows about a physical scenario.

A scenario (the ramp of Galileo, the splash of Physics 101, ...) lives whole in its own
folder under `galileo/scenarios/` and is registered by name in `galileo.registry`. The
chain runner, the CLI, the app's controller, viewer and rerun logger only call the
methods below; none of them names a scenario's latents.

Data path, per video:

    scene file --load_scene--> scene --track(video)--> Tracks
    (scene, Tracks) --prepare--> the scene inferred on (what tracking fixed)
    prepared scene --latents--> Latent specs (names, units, priors, widths)
    (prepared scene, Tracks, noise) --likelihood--> Likelihood (called by the MH kernel)
    Likelihood.motion(position) --> Trajectory: the motion it scored, drawn by the UI
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, Sequence

import numpy as np

from .datatypes import Trajectory, Tracks
from .latents import Latent, Noise

if TYPE_CHECKING:
    from .camera import Camera


class Likelihood(Protocol):
    """A log-likelihood over the latent vector (in `names` order), for the MH kernel.

    `__call__(position, threshold=None)` returns (value, stopped_early): with a threshold
    (and exact speed-ups on) it may stop as soon as it knows the value is below it and
    return an upper bound below the threshold. `steps` counts the physics steps taken.
    `motion(position)` is the simulated motion exactly as it was scored (same phases,
    same rest rule), for the viewer, rerun and tests. Both are thread-safe: a process has one
    Bullet client, and they hold `galileo.sim.bullet.client_lock` while they simulate."""
    names: tuple[str, ...]
    steps: int

    def __call__(self, position, threshold: float | None = None) -> tuple[float, bool]: ...

    def motion(self, position) -> Trajectory: ...


@dataclass(frozen=True)
class Mesh:
    """A piece of static scene geometry for the viewer: a triangle mesh in the world frame."""
    name: str
    vertices: np.ndarray    # (V, 3) metres, world frame
    faces: np.ndarray       # (T, 3)
    color: tuple[int, int, int] = (180, 180, 180)
    opacity: float = 1.0


@dataclass(frozen=True)
class Drawing:
    """What the viewer draws of a scene: static meshes, and one mesh per object in its own
    frame (posed per frame by a Trajectory's positions and orientations)."""
    static: Sequence[Mesh] = ()
    objects: Sequence[Mesh] = ()    # in object frames, in the Trajectory's object order
    ground_z_m: float | None = 0.0  # a grid at this height, if any


@dataclass(frozen=True)
class Readout:
    """An object a recognition model reads from one frame (by its tracked role), and the
    latents its readings are: its mass and its friction coefficient (None: not a latent of
    this scene). `mass_per_kg` is the mass latent's value per kilogram of the object: 1 for a
    mass in kg, 1 / (1000 V) for a density in g/cm^3 of an object of V m^3."""
    role: str
    mass: str | None = None
    friction: str | None = None
    mass_per_kg: float = 1.0


class SceneFile:
    """`save` and `load` for a scenario's scene class (which names its `scenario` and has
    `to_json`): one JSON file, written atomically, read and checked by the scenario."""
    scenario: str

    def save(self, path: str | Path) -> None:
        from .jsonio import write_json

        write_json(path, self.to_json())

    @classmethod
    def load(cls, path: str | Path):
        from . import registry

        return registry.get(cls.scenario).load_scene(path)


class Scenario(ABC):
    """One physical scenario. Subclasses set `name`, `description` and `noise`.

    Its scene objects carry a class attribute `scenario` (the scenario's name) and
    `to_json()` (a scene file, with `"scenario"`, that `scene_from_json` reads back): the
    runner sends scenes to worker processes and sessions save them that way."""
    name: str = ""
    description: str = ""
    noise: Noise
    protocol: dict = {"chains": 16, "sweeps": 75}   # the paper's chains x sweeps per video (the defaults)
    # settings of the scene file's "priors" section that make the paper's own likelihood, used
    # with `--moves paper` (the paper's whole protocol) where the scenario's defaults differ
    paper_priors: dict = {}
    # the paper's proposal half-widths {latent: (narrow, broad)} where the latents' own (the
    # default move set's starting widths, adapted in warm-up) differ: used with `--moves paper`
    paper_widths: dict = {}
    # where chains start unless the recognition model starts them (`initial_positions`), in words
    # for the app's Chains panel
    starts_doc: str = "drawn from the prior"
    # the scenario's package: by default its `scene` module parses and makes scenes
    # (`scene_from_json`, `default_scene`) and its `tracking` module tracks (`track`)
    package: str = ""

    def _part(self, module: str, name: str):
        import importlib

        if not self.package:
            raise NotImplementedError(f"the {self.name} scenario names no package for its {module}.{name}")
        return getattr(importlib.import_module(f"{self.package}.{module}"), name)

    # -- scene -----------------------------------------------------------------------------
    def scene_from_json(self, data: Any) -> Any:
        """Parse and validate a scene (SceneError naming the field)."""
        return self._part("scene", "scene_from_json")(data)

    def load_scene(self, path: str | Path) -> Any:
        from .errors import SceneError
        from .jsonio import read_json

        try:
            return self.scene_from_json(read_json(path, "scene file"))
        except SceneError as e:
            raise SceneError(f"{path}: {e}") from None

    def latents(self, scene) -> tuple[Latent, ...]:
        """The latents inferred in this scene, with the scene's prior bounds."""
        return scene.latent_specs()

    def initial_positions(self, prepared_scene, latents: Sequence[Latent], bounds: np.ndarray, n_chains: int,
                          seed: int) -> np.ndarray:
        """Where chains 0..n_chains-1 start (n_chains, D): by default drawn from the prior
        (`galileo.runner.initial_positions`, integer latents rounded); chain c's start must
        not depend on n_chains, so that added chains start like a bigger run's."""
        from .runner import initial_positions

        starts = initial_positions(bounds, n_chains, seed)
        for j, lat in enumerate(latents):
            if lat.integer:
                starts[:, j] = np.clip(np.round(starts[:, j]), bounds[j, 0], bounds[j, 1])
        return starts

    def moves(self, prepared_scene, tracks: Tracks, latents: Sequence[Latent], bounds: np.ndarray) -> tuple:
        """Joint Metropolis-Hastings moves (galileo.mcmc: `SiteMixture`, `LogScale`, or anything
        with `propose(rng, position) -> (proposal, log_hastings)`, `every` and `name`) that help
        this scenario's chains mix; each must be exact (carry its Hastings factor). Used by the
        default move set, never by `--moves paper`. Default: none."""
        return ()

    def with_values(self, scene, values: dict[str, float]):
        """A copy of the scene with latents (and scenario knobs) set; SceneError on an unknown name."""
        return scene.with_values(values)

    # -- observations ----------------------------------------------------------------------
    def track(self, video_path, scene, *, progress: bool = True, debug_video=None) -> Tracks:
        """Pixels -> observations."""
        return self._part("tracking", "track")(video_path, scene, progress=progress, debug_video=debug_video)

    @abstractmethod
    def prepare(self, scene, tracks: Tracks):
        """The scene as inferred on: what tracking fixed (shapes, offsets) put in; checks
        that the tracks fit the scene (GalileoError otherwise)."""

    # -- physics and likelihood -----------------------------------------------------------------
    @abstractmethod
    def simulate(self, scene, n_frames: int, values: dict[str, float] | None = None,
                 fps: float | None = None) -> Trajectory:
        """One plain simulation of the scene (with `values` overriding its latents)."""

    def synthetic_tracks(self, prepared_scene, values: dict[str, float], rng: np.random.Generator,
                         noise: float) -> Tracks:
        """The observations this scenario's likelihood assumes, simulated at `values` with
        noise of SD `noise` (for simulation-based calibration, `galileo calibrate`)."""
        from .errors import GalileoError

        raise GalileoError(f"the {self.name} scenario cannot simulate observations")

    @abstractmethod
    def likelihood(self, prepared_scene, tracks: Tracks, noise: float, speedups: bool = True) -> Likelihood:
        """The observation model over `latents(prepared_scene)`, in that order."""

    # -- what the UI draws, and derived answers ---------------------------------------------------
    @abstractmethod
    def drawing(self, scene) -> Drawing:
        """Static geometry and object meshes for the viewer and rerun."""

    def derived(self, scene, values: dict[str, float]) -> dict[str, float | None]:
        """Quantities derived from a latent vector in a (prepared) scene that a result reports
        (e.g. a mass ratio, or a mass from a density and the bottom-up volume)."""
        return {}

    def summary(self, scene, values: dict[str, float]) -> str:
        """One line for a MAP estimate (what `galileo infer` prints after "MAP: ")."""
        parts = [f"{k} = {v:.3f}" for k, v in values.items()]
        parts += [f"{k} = {v:.3g}" for k, v in self.derived(scene, values).items() if v is not None]
        return ", ".join(parts)

    def predict(self, result_path: str | Path, questions: dict) -> dict:
        """Answers to the scenario's questions from a saved result (see `galileo predict`)."""
        from .errors import GalileoError

        raise GalileoError(f"the {self.name} scenario answers no questions")

    def describe(self, scene=None) -> dict:
        """What `galileo scenarios` prints: name, description, latents with units and priors."""
        lats = self.latents(scene if scene is not None else self.default_scene())
        return {"name": self.name, "description": self.description,
                "noise": {"name": self.noise.name, "unit": self.noise.unit, "default": self.noise.default},
                "latents": [lat.to_json() for lat in lats]}

    def default_scene(self):
        """A standard scene of this scenario (for `galileo scenarios` and the demo)."""
        return self._part("scene", "default_scene")()

    # -- recognition (Galileo section 4): physical properties read from one frame ---------------
    # the mass range mapped to 0..1 on the recognition model's log-normalised scale
    recognition_mass_range_kg: tuple[float, float] = (0.005, 0.2)
    # patches come from the frames before the object has moved this far from its first position
    recognition_patch_motion_m: float = 0.01

    # By default these come from the scenario package's `recognition` module, if it has one:
    # `readouts(prepared)`, `label(prepared, tracks, values)`, `examples(folder)`, `features(prepared)`.
    def _recognition(self, name: str):
        return self.optional_part("recognition", name)

    def optional_part(self, module: str, name: str):
        """`name` from the scenario package's module `module` (e.g. "recognition",
        "synthetic"), or None if the package has no such module or name."""
        import importlib

        if not self.package:
            return None
        full = f"{self.package}.{module}"
        try:
            return getattr(importlib.import_module(full), name, None)
        except ModuleNotFoundError as e:
            if e.name == full:
                return None
            raise

    def readouts(self, prepared_scene) -> tuple[Readout, ...]:
        """The objects a recognition model reads in this scene and the latents it starts
        (none without a recognition module: the scenario then has no image recognition)."""
        fn = self._recognition("readouts")
        return tuple(fn(prepared_scene)) if fn else ()

    def recognition_label(self, prepared_scene, tracks: Tracks, values: dict[str, float]) -> dict[str, dict]:
        """The "Galileo label" of each read object from a MAP: {role: {"mass_kg", "friction"}},
        None where the video does not identify the quantity. Default: the readout latents."""
        fn = self._recognition("label")
        if fn:
            return fn(prepared_scene, tracks, values)
        return {r.role: {"mass_kg": values[r.mass] / r.mass_per_kg if r.mass in values else None,
                         "friction": values.get(r.friction) if r.friction else None}
                for r in self.readouts(prepared_scene)}

    def recognition_examples(self, folder: str | Path) -> list:
        """The videos of a rendered dataset as `galileo.recognition.data.Example`s (what to
        read in which video, the object and group that splits keep together, ground truth)."""
        from .errors import GalileoError

        fn = self._recognition("examples")
        if fn is None:
            raise GalileoError(f"the {self.name} scenario has no recognition dataset")
        return fn(Path(folder))

    def recognition_features(self, prepared_scene) -> np.ndarray:
        """Numbers describing a prepared scene beyond its latents (angles, sizes) that the
        simulation-trained recognition model reads beside the tracked velocities."""
        fn = self._recognition("features")
        return np.asarray(fn(prepared_scene), float) if fn else np.zeros(0)

    # -- the video a scene describes ------------------------------------------------------------
    def camera(self, scene) -> "Camera | None":
        """The video's camera, if the scene has one (the viewer's frustum and camera view;
        without one the viewer shows the 3-D scene only). Default: `scene.camera`, if any."""
        return getattr(scene, "camera", None)

    def video_timing(self, scene) -> tuple[float, int] | None:
        """(fps, n_frames) of the video the scene describes, if it says (the defaults of
        `galileo simulate`). Default: the camera's."""
        cam = self.camera(scene)
        return None if cam is None else (float(cam.fps), int(cam.n_frames))

