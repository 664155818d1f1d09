"""What a scenario may be able to do beyond inference, each as a small typed object.

A scenario (`galileo.model.Scenario`) declares each capability as an attribute that is `None`
when it has none; the CLI, the app and the experiments ask that attribute, never a module
name. The others live beside the code they serve: `galileo.dataset.DatasetSpec` (rendered
datasets) and `galileo.clicks.Calibration` (own-video calibration from clicks).

    Experiments   `galileo experiment`: one video of a dataset -> a record; records -> summary; report sections
    Synthetic     `galileo calibrate`: observations simulated from the likelihood's own model (SBC)
    Recognition   Galileo section 4: what a network reads from one frame and the labels it learns from
    Question      `galileo predict`: a question a scenario answers from a result (`Scenario.questions`)
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from .fields import Bound


@dataclass(frozen=True)
class Experiments:
    """The paper's experiments over a rendered dataset (`galileo experiment`, `galileo report`).

    `run_video(folder, config, executor=None) -> record`: infer on one video folder of the
    dataset (video.mp4, scene.json, truth.json) and compare with the truth; a JSON-able record.
    `summarise(records) -> dict`: the numbers of report.json's "summary".
    `sections(records, fig_dir) -> [galileo.report.Section]`: the scenario's own report sections.
    `coverage`: the quantities whose interval coverage `galileo calibrate --videos` checks against
    a video's truth.json: latent names, or `log_<derived>` for a positive derived quantity
    (`galileo.calibrate.quantities`), those the videos identify."""
    run_video: Callable[..., dict]
    summarise: Callable[[list], dict]
    sections: Callable[[list, Path], list] | None = None
    coverage: tuple[str, ...] = ()


@dataclass(frozen=True)
class Synthetic:
    """Observations simulated from the very model the likelihood assumes, for simulation-based
    calibration (`galileo calibrate`).

    `tracks(prepared_scene, values, rng, noise) -> Tracks`: what tracking would give at `values`
    with noise of SD `noise`. `random_scene(rng) -> scene` (optional): a scene like the dataset's
    (`--scenes dataset`). `describe(scene) -> dict` (optional): the scene's knobs for the record."""
    tracks: Callable[..., Any]
    random_scene: Callable[[np.random.Generator], Any] | None = None
    describe: Callable[[Any], dict] | None = None


@dataclass(frozen=True)
class Recognition:
    """What a recognition model (a LeNet reading one frame, Galileo section 4) reads and learns.

    `readouts(prepared_scene) -> [galileo.readout.Readout]`: the objects read and the latents
    their readings start. `examples(folder) -> [galileo.recognition.data.Example]`: a rendered
    dataset's videos as training examples. `features(prepared_scene) -> array`: numbers beyond
    the latents (angles, sizes) the simulation-trained model reads. `label(prepared, tracks,
    values) -> {role: {...}}` (optional): the "Galileo label" of each read object from a MAP,
    None where the video does not identify a quantity (default: the readout latents)."""
    readouts: Callable[[Any], Sequence]
    examples: Callable[[Path], list] | None = None
    features: Callable[[Any], Any] | None = None
    label: Callable[..., dict] | None = None


@dataclass(frozen=True)
class Question:
    """A question `galileo predict` asks a scenario's result (`Scenario.questions`; answered by
    `Scenario.predict(result, {name: value})`). Its flag is `--<name with dashes>`; `kind`:
    "number" (checked against `bound` before the result is read), "yes" (a switch) or "file"."""
    name: str
    help: str
    kind: str = "number"
    bound: Bound | None = None

    @property
    def flag(self) -> str:
        return "--" + self.name.replace("_", "-")
