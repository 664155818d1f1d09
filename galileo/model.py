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
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, Sequence

import numpy as np

from .datatypes import Trajectory, Tracks
from .drawing import Anchor, Connector, Drawing, Mesh  # noqa: F401  (part of the scenario interface)
from .latents import Latent, Noise, initial_positions
from .readout import Readout  # noqa: F401  (part of the scenario interface)

if TYPE_CHECKING:
    from .camera import Camera
    from .capabilities import Experiments, Recognition, Synthetic
    from .clicks import Calibration
    from .dataset import DatasetSpec

CAPABILITIES = ("dataset", "experiments", "synthetic", "recognition", "calibration")


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
    # whether the default move set adds the adaptive joint random walk (`galileo.mcmc.JointRW`); a
    # scenario whose own exact moves follow its posterior's correlations may leave it out
    adaptive_walk: bool = True
    # the move set that runs until converged (`--until-rhat`, the app's "Run until converged") when
    # none is asked for (`galileo.api.moves_for`): the one `bench/bench_converge.py` found fastest to
    # converge on this scenario ("default", "paper" or "fitted"); a fixed number of sweeps keeps "default"
    converge_moves: str = "default"
    # where chains start unless the recognition model starts them (`initial_positions`), in words
    # for the app's Chains panel
    starts_doc: str = "drawn from the prior"

    # -- capabilities: each None where the scenario has none (subclasses set them, often as
    # properties that import their module only when asked) ----------------------------------------
    dataset: "DatasetSpec | None" = None          # `galileo dataset`: presets, plan, render one video
    experiments: "Experiments | None" = None      # `galileo experiment` / `report`: records, summary, sections
    synthetic: "Synthetic | None" = None          # `galileo calibrate`: observations from the likelihood's model
    recognition: "Recognition | None" = None      # Galileo section 4: read one frame, start the chains
    calibration: "Calibration | None" = None      # `galileo scene` and the upload page: clicks -> scene

    def capabilities(self) -> dict[str, bool]:
        """Which capabilities the scenario has (what `galileo scenarios` lists)."""
        return {name: getattr(self, name) is not None for name in CAPABILITIES}

    # -- scene -----------------------------------------------------------------------------
    @abstractmethod
    def scene_from_json(self, data: Any) -> Any:
        """Parse and validate a scene (SceneError naming the field)."""

    @abstractmethod
    def default_scene(self) -> Any:
        """A standard scene of this scenario (for `galileo scenarios`, the demo and the contract tests)."""

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
        (`galileo.latents.initial_positions`, integer latents rounded); chain c's start must
        not depend on n_chains, so that added chains start like a bigger run's."""
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

    def values(self, scene) -> dict[str, float]:
        """The values the scene gives its latents (in a rendered video's scene: the truth), by
        name. Default: the scene's `latents()`."""
        fn = getattr(scene, "latents", None)
        if fn is None:
            raise NotImplementedError(f"the {self.name} scenario's scenes do not say their latents' values")
        return {k: float(v) for k, v in fn().items()}

    def problem_starts(self, prepared_scenes: Sequence, lay, n_chains: int, seed: int) -> np.ndarray | None:
        """Where chains start in a problem of several videos (`galileo.joint`; `lay` its Layout:
        the flat latents and where each video's come from), where the videos' starts must agree
        (one spring's stiffness with each object's mass): (n_chains, D), or None to start each
        video as `initial_positions` says (a shared latent from the first video). Default: None."""
        return None

    def problem_moves(self, prepared_scenes: Sequence, lay, bounds: np.ndarray) -> tuple:
        """Joint moves over a problem of several videos (`galileo.joint`; `lay` its Layout), for
        moves that need more than one video's latents (one spring's stiffness with every mass
        on it), in the chain's flat vector; where it makes any, they replace the per-video
        `moves` in a problem. Default: none."""
        return ()

    def not_identified(self, prepared_scenes: Sequence, fixed: dict[str, float],
                       tracks: Sequence[Tracks] | None = None, share: Sequence[str] = ()) -> dict[str, str]:
        """The latents and derived quantities (as the problem names them: `name@v` for one
        video's own in a problem of several) that these videos, with these latents fixed, do
        not identify, each with why (result.json's "not_identified"; a derived quantity named
        here gets no point estimate and no posterior summary). `tracks`, one per scene where
        known: what was observed (a video in which nothing moves identifies less than its scene
        could); `share`: the latents the problem shares (one value for all its videos, named
        without `@v`). Default: none said."""
        return {}

    def unidentified(self, scene, tracks=None) -> dict[str, str]:
        """result.json's "not_identified" for a (prepared) scene and its tracks (if known):
        `not_identified([scene], {}, [tracks])`."""
        return self.not_identified([scene], {}, None if tracks is None else [tracks])

    def shared_latents(self, prepared_scenes: Sequence) -> tuple[str, ...]:
        """The latents the videos of a problem share without being told (`galileo.joint`): one
        value for every video, e.g. one spring's stiffness under two loads. Default: none."""
        return ()

    def with_values(self, scene, values: dict[str, float]):
        """A copy of the scene with latents (and scenario knobs) set; SceneError on an unknown name."""
        return scene.with_values(values)

    # -- observations ----------------------------------------------------------------------
    @abstractmethod
    def track(self, video_path, scene, *, progress: bool = True, debug_video=None) -> Tracks:
        """Pixels -> observations: the scene's objects found and followed in the video."""

    @abstractmethod
    def prepare(self, scene, tracks: Tracks):
        """The scene as inferred on: what tracking fixed (shapes, offsets) put in; checks
        that the tracks fit the scene (GalileoError otherwise)."""

    # -- physics and likelihood -----------------------------------------------------------------
    @abstractmethod
    def simulate(self, scene, n_frames: int, values: dict[str, float] | None = None,
                 fps: float | None = None) -> Trajectory:
        """One plain simulation of the scene (with `values` overriding its latents)."""

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

    def summary(self, scene, values: dict[str, float], omit=()) -> str:
        """One line for a MAP estimate (what `galileo infer` prints after "MAP: "), leaving out
        the latents and derived quantities named in `omit` (those not identified)."""
        parts = [f"{k} = {v:.3f}" for k, v in values.items() if k not in omit]
        parts += [f"{k} = {v:.3g}" for k, v in self.derived(scene, values).items() if v is not None and k not in omit]
        return ", ".join(parts)

    # what `galileo predict` may ask this scenario's results (galileo.capabilities.Question)
    questions: tuple = ()

    def predict(self, result_path: str | Path, questions: dict) -> dict:
        """Answers to the scenario's questions from a saved result (see `galileo predict`)."""
        from .errors import GalileoError

        raise GalileoError(f"the {self.name} scenario answers no questions")

    def describe(self, scene=None) -> dict:
        """What `galileo scenarios` prints: name, description, latents with units and priors,
        and which capabilities the scenario has."""
        lats = self.latents(scene if scene is not None else self.default_scene())
        return {"name": self.name, "description": self.description,
                "noise": {"name": self.noise.name, "unit": self.noise.unit, "default": self.noise.default},
                "latents": [lat.to_json() for lat in lats], "capabilities": self.capabilities()}

    # -- recognition (Galileo section 4): physical properties read from one frame ---------------
    # the mass range mapped to 0..1 on the recognition model's log-normalised scale
    recognition_mass_range_kg: tuple[float, float] = (0.005, 0.2)
    # patches come from the frames before the object has moved this far from its first position
    recognition_patch_motion_m: float = 0.01

    def readouts(self, prepared_scene) -> tuple[Readout, ...]:
        """The objects a recognition model reads in this scene and the latents it starts
        (none without the recognition capability)."""
        return tuple(self.recognition.readouts(prepared_scene)) if self.recognition else ()

    def recognition_label(self, prepared_scene, tracks: Tracks, values: dict[str, float]) -> dict[str, dict]:
        """The "Galileo label" of each read object from a MAP: {role: {"mass_kg", "friction"}},
        None where the video does not identify the quantity. Default: the readout latents."""
        if self.recognition and self.recognition.label:
            return self.recognition.label(prepared_scene, tracks, values)
        return {r.role: {q: (values[lat] / per if lat in values else None) for q, (lat, per) in r.reads.items()}
                for r in self.readouts(prepared_scene)}

    def recognition_examples(self, folder: str | Path) -> list:
        """The videos of a rendered dataset as `galileo.recognition.data.Example`s (what to
        read in which video, the object and group that splits keep together, ground truth)."""
        from .errors import GalileoError

        if self.recognition is None or self.recognition.examples is None:
            raise GalileoError(f"the {self.name} scenario has no recognition dataset")
        return self.recognition.examples(Path(folder))

    def recognition_features(self, prepared_scene) -> np.ndarray:
        """Numbers describing a prepared scene beyond its latents (angles, sizes) that the
        simulation-trained recognition model reads beside the tracked velocities."""
        fn = self.recognition.features if self.recognition else None
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

