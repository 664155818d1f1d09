"""The simulation-trained recognition model (issue 11's second model): latents read from the
tracked velocities, learned purely from simulations from the prior. No video labels needed,
and it works for any scenario: it only calls the `galileo.model.Scenario` interface
(`prepare`, `latents`, `simulate`, `noise`, `readouts`, `recognition_features`,
`recognition_label`) and never names a scenario's latents.

Input (`observation_features`): per object slot (the prepared scene's objects in order,
matched to the tracks by role), the x and z velocity of every frame below `T_MAX` (0 where
the object was not seen or the video is shorter) and a visibility flag per frame; then the
scenario's `recognition_features` (angles, sizes, distances). One function serves tracked
videos and simulations, so the network sees both the same way.

Training data (`simulate_training_set`): for each training video with tracks, the prepared
scene is simulated `SIMS_PER_SCENE` times with latents drawn uniformly from its prior bounds
(integer latents rounded), as many frames as the video has (at most `T_MAX`), at its frame
rate; `LENGTH_AUGMENT` of them are cut at, or run on to, a random length, so that the network
meets every video length up to `T_MAX` (a dataset's video lengths follow its objects' true
motion: a slow slider's video is longer than any other). The velocities are masked with the
video's TRACKED visibility and get Gaussian noise of SD `scenario.noise.default` on the
visible components: the likelihood's own observation model, so the network learns
p(latents | observation) under the model MCMC samples. The noise is drawn afresh for every
training batch (`noise_scale`), so the network cannot learn one draw of it by heart (with one
fixed draw, a few hundred simulations gave over-confident readings). Simulations run in
forked worker processes, each with its own pybullet client; only JSON (scene and tracks
files), latent values and frame counts cross to them. Everything is seeded: the same seed
gives the same model.

Output: every latent, transformed (a latent that is some readout's `mass` -> ln, the others
as they are) and standardised by the transformed prior bounds to [0, 1]. The network is an
MLP (inputs standardised; `HIDDEN` ReLU layers) giving a mean and a clamped log-variance per
latent, trained on the Gaussian negative log-likelihood (a latent a scene lacks, e.g. a
target's without a target, is left out of its loss); `MEMBERS` networks from different
seeds form an ensemble whose prediction is the mixture's mean and variance.

`SimulationModel` reads a video (`predict`: per latent (loc, scale, kind) in the latent's own
terms: "lognormal" -> loc, scale of ln value; "normal" -> of the value), gives an
independence proposal for MCMC (`proposal`) and the video's "Galileo label" from its point
estimate (`read_labels`). Model files: `modelfile` (NPZ + JSON header, never pickle).
`train_model` trains on a dataset (holding out one fold of objects, as the LeNet's);
`fig3_rows` plugs it into `train.figure3` as an extra model.
"""
from __future__ import annotations

import math
import os
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

from ..progress import tqdm
from .. import registry
from ..datatypes import Tracks
from ..errors import GalileoError
from . import modelfile
from .lenet import mixture, one_thread   # torch on one thread (the MLP's small matrices gain nothing
                                         # from more: 2 threads made a step 190 ms against 1.2 ms)

# -- tunables -------------------------------------------------------------------------------------
T_MAX = 90                  # frames of velocity read per object (30 fps: 3 s)
SIMS_PER_SCENE = 64         # simulations per training video
LENGTH_AUGMENT = 0.5        # this share of the simulations sees the video cut or run on to a random length
LENGTH_MIN = 15             # ... of LENGTH_MIN to T_MAX frames
HIDDEN = (128, 128)         # MLP hidden layer widths
EPOCHS = 60                 # passes over the simulations, per ensemble member
BATCH = 128
LEARNING_RATE = 2e-3        # Adam, cosine-annealed to LR_FINAL_FRACTION of it
LR_FINAL_FRACTION = 0.05
WEIGHT_DECAY = 1e-5
MEMBERS = 3                 # ensemble size (different seeds)
LOGVAR_RANGE = (-12.0, 2.0)  # predicted log-variances (of the [0, 1] scale) clamped here
MAX_WORKERS = 16            # simulation processes at most (and no more than os.cpu_count())
LABEL_DRAWS = 256           # draws from the predicted marginals for a label's spread
SCALE_FLOOR = 1e-3          # smallest proposal scale (latent's own terms)
VERSION = 1                 # this model kind's own layout (beside modelfile.VERSION)


# -- inputs ---------------------------------------------------------------------------------------

def object_roles(prepared_scene, tracks: Tracks) -> list[str]:
    """The roles of the simulated objects, in the order of a simulation's Trajectory: the
    scene's `objects` (each with a `role`), or, for a scene without such a list (one
    object, e.g. the splash), the tracks' objects in their order."""
    objs = getattr(prepared_scene, "objects", None)
    if objs is not None:
        return [o.role for o in objs]
    return [t.role for t in tracks.objects]


def tracked_series(prepared_scene, tracks: Tracks) -> tuple[np.ndarray, np.ndarray]:
    """(velocities (n_obj, F, 3), visible (n_obj, F)) of the tracks in the prepared scene's
    object order, matched by role (an object the tracks lack: never visible)."""
    roles = object_roles(prepared_scene, tracks)
    F = tracks.n_frames
    vel = np.full((len(roles), F, 3), np.nan)
    vis = np.zeros((len(roles), F), bool)
    for i, role in enumerate(roles):
        tr = tracks.by_role(role)
        if tr is None:
            continue
        vis[i] = np.asarray(tr.visible, bool)[:F]
        vel[i] = np.asarray(tr.velocity_mps, float)[:F]
    return vel, vis


def observation_features(scenario, prepared_scene, velocities, visible, slots: int | None = None) -> np.ndarray:
    """The network's input: per object (`slots` of them: missing ones are never visible) the
    x and z velocity of frames < T_MAX (0 where not visible or missing) and a visibility
    flag per frame, then `scenario.recognition_features(prepared_scene)`. Float32, 1-D."""
    velocities = np.asarray(velocities, float)
    visible = np.asarray(visible, bool)
    n_obj = velocities.shape[0]
    slots = n_obj if slots is None else int(slots)
    if n_obj > slots:
        raise GalileoError(f"the scene has {n_obj} objects; the model reads at most {slots}")
    F = min(velocities.shape[1], T_MAX)
    block = np.zeros((slots, 3, T_MAX))
    seen = visible[:, :F] & np.isfinite(velocities[:, :F]).all(axis=2)
    block[:n_obj, 0, :F] = np.where(seen, velocities[:, :F, 0], 0.0)
    block[:n_obj, 1, :F] = np.where(seen, velocities[:, :F, 2], 0.0)
    block[:n_obj, 2, :F] = seen
    extra = np.asarray(scenario.recognition_features(prepared_scene), float).ravel()
    return np.concatenate([block.ravel(), extra]).astype(np.float32)


# -- simulations ----------------------------------------------------------------------------------

def _simulate_chunk(task) -> tuple[int, int, np.ndarray]:
    """In a worker: (pair index, first draw, velocities (n, n_obj, T_MAX, 3), NaN after each
    simulation's own frame count) of one chunk of one training video's simulations. Only JSON
    and numbers arrive here; the worker's pybullet client is its own."""
    index, start, scenario_name, scene_json, tracks_json, values, frames, fps = task
    scenario = registry.get(scenario_name)
    scene = scenario.scene_from_json(scene_json)
    tracks = Tracks.from_json(tracks_json)
    prepared = scenario.prepare(scene, tracks)
    n_obj = len(object_roles(prepared, tracks))
    out = []
    for v, n_frames in zip(values, frames):
        try:
            traj = scenario.simulate(prepared, int(n_frames), values=v, fps=fps)
        except GalileoError:   # outside the prior's support (e.g. no splash shape has this area): dropped
            out.append(np.full((n_obj, T_MAX, 3), np.inf))
            continue
        vel = np.asarray(traj.velocity_mps, float)[:, :T_MAX]
        # frames not simulated (or a simulation that stopped early) are unknown: never seen
        out.append(np.concatenate([vel, np.full((vel.shape[0], T_MAX - vel.shape[1], 3), np.nan)], axis=1))
    return index, start, np.stack(out)


def _workers(workers: int | None, n_tasks: int) -> int:
    n = int(workers) if workers else min(MAX_WORKERS, os.cpu_count() or 1)
    return max(1, min(n, n_tasks))


def _draw_values(latents, n: int, rng: np.random.Generator) -> list[dict]:
    """n latent vectors uniform in the prior bounds (integer latents rounded), as dicts."""
    lo = np.array([lat.bounds[0] for lat in latents], float)
    hi = np.array([lat.bounds[1] for lat in latents], float)
    x = rng.uniform(lo, hi, size=(n, len(latents)))
    for j, lat in enumerate(latents):
        if lat.integer:
            x[:, j] = np.clip(np.round(x[:, j]), lo[j], hi[j])
    return [{lat.name: float(row[j]) for j, lat in enumerate(latents)} for row in x]


def simulate_training_set(scenario, pairs, *, sims: int = SIMS_PER_SCENE, seed: int = 0, workers: int | None = None,
                          progress: bool = True, slots: int | None = None):
    """Simulations of each (scene, tracks) pair with latents from the prior: (X (N, inputs)
    without observation noise (`noise_scale` says where it goes; training draws it afresh
    every epoch), list of per-simulation value dicts, list of prepared scenes, number of the
    pair of each simulation). The velocities are masked with the pair's tracked visibility,
    for LENGTH_AUGMENT of the simulations cut at, or run on to, a random length (frames after
    the video's end keep each object's last tracked visibility).
    Seeded per pair (SeedSequence(seed, spawn_key=(pair,))): the same pairs and seed give the
    same set, however many workers run."""
    prepared, tasks, draws, lengths = [], [], [], []
    for i, (scene, tracks) in enumerate(pairs):
        p = scenario.prepare(scene, tracks)
        prepared.append(p)
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(i,)))
        draws.append(_draw_values(scenario.latents(p), sims, rng))
        # the video's own length, or (LENGTH_AUGMENT of them) a random one: the network meets
        # videos of every length up to T_MAX, and objects lost after a few frames
        own = max(1, min(tracks.n_frames, T_MAX))
        other = rng.integers(min(LENGTH_MIN, T_MAX), T_MAX + 1, sims)
        lengths.append(np.where(rng.uniform(size=sims) < LENGTH_AUGMENT, other, own))
    slots = slots or max(len(object_roles(p, t)) for p, (_, t) in zip(prepared, pairs))
    n_workers = _workers(workers, len(pairs) * sims)
    # one chunk per video when there are many videos (a worker builds each world once); split a
    # few videos' simulations so that every worker has some
    per_pair = max(1, min(sims, math.ceil(2 * n_workers / max(1, len(pairs))))) if n_workers > 1 else 1
    size = math.ceil(sims / per_pair)
    for i, ((scene, tracks), p) in enumerate(zip(pairs, prepared)):
        sj, tj = scene.to_json(), tracks.to_json()
        for start in range(0, sims, size):
            tasks.append((i, start, scenario.name, sj, tj, draws[i][start:start + size],
                          [int(n) for n in lengths[i][start:start + size]], float(tracks.fps)))
    results: dict[tuple[int, int], np.ndarray] = {}
    bar = tqdm(total=len(pairs) * sims, desc="simulations from the prior", unit="sim", disable=not progress)
    try:
        if n_workers == 1:
            for t in tasks:
                i, start, v = _simulate_chunk(t)
                results[i, start] = v
                bar.update(len(v))
        else:
            import multiprocessing as mp
            from concurrent.futures.process import BrokenProcessPool

            from ..runner import _ignore_sigint, _workers_born_deaf_to_sigterm

            # forked workers: each connects its own pybullet client (galileo.sim.bullet)
            ex = ProcessPoolExecutor(min(n_workers, len(tasks)), mp_context=mp.get_context("fork"),
                                     initializer=_ignore_sigint)
            try:
                with _workers_born_deaf_to_sigterm():   # the first submit forks every worker
                    futures = [ex.submit(_simulate_chunk, t) for t in tasks]
                for fut in as_completed(futures):
                    i, start, v = fut.result()
                    results[i, start] = v
                    bar.update(len(v))
            except BrokenProcessPool as e:
                raise GalileoError(f"a simulation worker died: {e}") from None
            finally:
                ex.shutdown(wait=True, cancel_futures=True)
    finally:
        bar.close()
    xs, which, values = [], [], []
    for i, ((scene, tracks), p) in enumerate(zip(pairs, prepared)):
        vel = np.concatenate([results[i, s] for s in range(0, sims, size)])    # (sims, n_obj, T_MAX, 3)
        _, vis = tracked_series(p, tracks)
        vis = vis[:, :T_MAX]
        own = vis.shape[1]
        for k in range(sims):
            if np.isposinf(vel[k]).all():   # a draw outside the prior's support: the prior restricted to it
                continue
            values.append(draws[i][k])
            n = int(lengths[i][k])
            seen = np.zeros((vis.shape[0], T_MAX), bool)
            seen[:, :min(n, own)] = vis[:, :min(n, own)]
            if n > own:   # a video run on: each object stays as the tracker last had it
                seen[:, own:n] = vis[:, own - 1:own]
            xs.append(observation_features(scenario, p, vel[k], seen & np.isfinite(vel[k]).all(axis=2), slots))
            which.append(i)
    if not xs:
        raise GalileoError("every simulation from the prior fell outside its support")
    return np.stack(xs), values, prepared, np.array(which)


def noise_scale(x: np.ndarray, slots: int, sigma: float) -> np.ndarray:
    """Per input, the SD of the observation noise it gets: `sigma` on the x and z velocity of
    every visible frame (the visibility flags of `observation_features`' layout), else 0."""
    x = np.asarray(x)
    block = x[:, :slots * 3 * T_MAX].reshape(len(x), slots, 3, T_MAX)
    seen = block[:, :, 2:3, :] > 0.5
    out = np.zeros_like(x, dtype=np.float32)
    out[:, :slots * 3 * T_MAX] = (np.concatenate([seen, seen, np.zeros_like(seen)], axis=2) * sigma).reshape(
        len(x), -1)
    return out


# -- targets --------------------------------------------------------------------------------------

def _forward(transform: str, x):
    return np.log(x) if transform == "log" else np.asarray(x, float)


def latent_table(scenario, prepared_scenes) -> list[dict]:
    """Every latent of the scenes (first seen first) with its transform ("log" for a
    readout's mass, else "identity") and the union of the scenes' prior bounds."""
    table: dict[str, dict] = {}
    for p in prepared_scenes:
        masses = {r.mass for r in scenario.readouts(p) if r.mass}
        for lat in scenario.latents(p):
            e = table.setdefault(lat.name, {"name": lat.name, "transform": "identity",
                                            "bounds": [float(lat.bounds[0]), float(lat.bounds[1])]})
            if lat.name in masses:
                e["transform"] = "log"
            e["bounds"] = [min(e["bounds"][0], float(lat.bounds[0])), max(e["bounds"][1], float(lat.bounds[1]))]
    for e in table.values():
        if e["transform"] == "log" and not e["bounds"][0] > 0:
            raise GalileoError(f"{e['name']}: a mass whose prior reaches {e['bounds'][0]:g}; it must stay above 0")
    return list(table.values())


def _y_range(entry) -> tuple[float, float]:
    lo, hi = (float(v) for v in _forward(entry["transform"], np.array(entry["bounds"], float)))
    return lo, hi


def targets(table, values: list[dict]) -> np.ndarray:
    """(N, D) standardised targets ([0, 1] over the prior), NaN where a scene lacks the latent."""
    y = np.full((len(values), len(table)), np.nan)
    for j, e in enumerate(table):
        lo, hi = _y_range(e)
        for i, v in enumerate(values):
            if e["name"] in v:
                y[i, j] = (float(_forward(e["transform"], v[e["name"]])) - lo) / (hi - lo)
    return y


# -- the network ----------------------------------------------------------------------------------

def _torch():
    import torch

    return torch


def _net(n_in: int, n_out: int, hidden=HIDDEN):
    torch = _torch()
    from torch import nn

    class MLP(nn.Module):
        def __init__(self):
            super().__init__()
            layers, d = [], n_in
            for h in hidden:
                layers += [nn.Linear(d, int(h)), nn.ReLU()]
                d = int(h)
            layers.append(nn.Linear(d, 2 * n_out))
            self.body = nn.Sequential(*layers)

        def forward(self, x):
            out = self.body(x)
            return out[:, :n_out], torch.clamp(out[:, n_out:], *LOGVAR_RANGE)

    return MLP()


def train_networks(x: np.ndarray, y: np.ndarray, *, noise: np.ndarray | None = None, seed: int = 0,
                   members: int = MEMBERS, epochs: int = EPOCHS, hidden=HIDDEN,
                   progress: bool = True) -> tuple[list[dict], list[float]]:
    """An ensemble trained on standardised inputs x (N, I) and targets y (N, D; NaN: no label):
    (state dicts as float32 arrays, final loss per member). `noise` (N, I): the SD of Gaussian
    noise added to each input, drawn afresh for every batch (the observation model: the
    network cannot learn one draw of the noise by heart)."""
    with one_thread():
        return _train_networks(x, y, noise, seed, members, epochs, hidden, progress)


def _train_networks(x, y, noise, seed, members, epochs, hidden, progress):
    torch = _torch()
    xt = torch.from_numpy(np.asarray(x, np.float32))
    nt = None if noise is None else torch.from_numpy(np.asarray(noise, np.float32))
    yv = np.asarray(y, np.float32)
    mt = torch.from_numpy(np.isfinite(yv).astype(np.float32))
    yt = torch.from_numpy(np.nan_to_num(yv))
    n = len(xt)
    states, losses = [], []
    steps = epochs * math.ceil(n / BATCH)
    bar = tqdm(total=members * epochs, desc="training the simulation model", unit="epoch", disable=not progress)
    for m in range(members):
        torch.manual_seed(seed * 1000 + m)
        gen = torch.Generator().manual_seed(seed * 1000 + m)
        net = _net(xt.shape[1], yt.shape[1], hidden)
        opt = torch.optim.Adam(net.parameters(), lr=LEARNING_RATE, weight_decay=WEIGHT_DECAY)
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, max(1, steps), LEARNING_RATE * LR_FINAL_FRACTION)
        last = math.nan
        for _ in range(epochs):
            total, count = 0.0, 0.0
            for idx in torch.randperm(n, generator=gen).split(BATCH):
                xb = xt[idx]
                if nt is not None:
                    xb = xb + nt[idx] * torch.randn(xb.shape, generator=gen)
                mu, logvar = net(xb)
                mask = mt[idx]
                nll = 0.5 * (logvar + (yt[idx] - mu) ** 2 * torch.exp(-logvar)) * mask
                loss = nll.sum() / mask.sum().clamp(min=1.0)
                opt.zero_grad()
                loss.backward()
                opt.step()
                sched.step()
                total += float(nll.detach().sum())
                count += float(mask.sum())
            last = total / max(count, 1.0)
            bar.update(1)
        states.append({k: v.detach().numpy().astype(np.float32).copy() for k, v in net.state_dict().items()})
        losses.append(float(last))
    bar.close()
    return states, losses


def _run_networks(states: list[dict], x: np.ndarray, n_out: int, hidden) -> tuple[np.ndarray, np.ndarray]:
    """The ensemble's mixture mean and variance (N, D) on standardised inputs."""
    with one_thread() as torch, torch.no_grad():
        xt = torch.from_numpy(np.asarray(x, np.float32))
        mus, vars_ = [], []
        for st in states:
            net = _net(xt.shape[1], n_out, hidden)
            net.load_state_dict({k: torch.from_numpy(np.asarray(v, np.float32)) for k, v in st.items()}, strict=True)
            net.eval()
            mu, logvar = net(xt)
            mus.append(mu.numpy().astype(float))
            vars_.append(np.exp(logvar.numpy().astype(float)))
    return mixture(np.stack(mus), np.stack(vars_))


# -- the model --------------------------------------------------------------------------------------

class SimulationModel:
    """Latents read from a video's tracked velocities by an ensemble trained on simulations."""
    kind = "simulation"

    def __init__(self, meta: dict, states: list[dict], x_mean: np.ndarray, x_sd: np.ndarray):
        self.meta = meta
        self.states = states
        self.x_mean = np.asarray(x_mean, np.float32)
        self.x_sd = np.asarray(x_sd, np.float32)

    @property
    def scenario(self) -> str:
        return self.meta["scenario"]

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(e["name"] for e in self.meta["latents"])

    # -- files --------------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        arrays = {f"m{i}/{k}": v for i, st in enumerate(self.states) for k, v in st.items()}
        arrays["x_mean"], arrays["x_sd"] = self.x_mean, self.x_sd
        modelfile.save(path, {**self.meta, "kind": self.kind, "members": len(self.states),
                              "simulation_version": VERSION}, arrays)

    @classmethod
    def load(cls, path: str | Path, scenario: str | None = None) -> "SimulationModel":
        meta, arrays = modelfile.load(path, kind=cls.kind, scenario=scenario)
        try:
            if meta.get("simulation_version") != VERSION:
                raise GalileoError(f"{path}: simulation model layout {meta.get('simulation_version')!r}; "
                                   f"this Galileo reads {VERSION}")
            states = [{} for _ in range(int(meta["members"]))]
            for k, v in arrays.items():
                if "/" in k:
                    member, name = k.split("/", 1)
                    states[int(member[1:])][name] = v
            model = cls(meta, states, arrays["x_mean"], arrays["x_sd"])
            if int(meta["t_max"]) != T_MAX or model.x_mean.shape != (int(meta["features"]["inputs"]),):
                raise ValueError("input layout")
            for e in meta["latents"]:
                lo, hi = _y_range(e)
                if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi) or e["transform"] not in ("log", "identity"):
                    raise ValueError(f"latent {e.get('name')!r}")
            model._standardised(np.zeros((1, len(model.x_mean)), np.float32))   # the weights must fit
        except GalileoError:
            raise
        except Exception as e:
            raise GalileoError(f"{path}: a simulation model this Galileo cannot use ({type(e).__name__}: {e})") from None
        return model

    # -- reading --------------------------------------------------------------------------------
    def _standardised(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        z = (np.asarray(x, np.float32) - self.x_mean) / self.x_sd
        return _run_networks(self.states, z, len(self.meta["latents"]), self.meta["hidden"])

    def _prepared(self, scene, tracks: Tracks):
        scenario = registry.of(scene)
        if scenario.name != self.scenario:
            raise GalileoError(f"the simulation model reads {self.scenario} videos, not {scenario.name}")
        prepared = scenario.prepare(scene, tracks)
        names = [lat.name for lat in scenario.latents(prepared)]
        unknown = [n for n in names if n not in self.names]
        if unknown:
            raise GalileoError(f"the scene's latents ({', '.join(names)}) are not the model's "
                               f"({', '.join(self.names)}): it never learned {', '.join(unknown)}")
        return scenario, prepared

    def features(self, scenario, prepared, tracks: Tracks) -> np.ndarray:
        vel, vis = tracked_series(prepared, tracks)
        x = observation_features(scenario, prepared, vel, vis, int(self.meta["features"]["slots"]))
        if x.shape != self.x_mean.shape:
            raise GalileoError(f"the scene gives {x.size} inputs; the model reads {self.x_mean.size} "
                               "(other scene features than it was trained on)")
        return x

    def predict(self, scene, tracks: Tracks) -> dict[str, tuple[float, float, str]]:
        """Per latent of the scene: (loc, scale, kind) in the latent's own terms ("lognormal":
        loc and scale of its natural log; "normal": of the value)."""
        scenario, prepared = self._prepared(scene, tracks)
        return self._predict_prepared(scenario, prepared, tracks)

    def _predict_prepared(self, scenario, prepared, tracks) -> dict[str, tuple[float, float, str]]:
        mean, var = self._standardised(self.features(scenario, prepared, tracks)[None])
        out = {}
        wanted = {lat.name for lat in scenario.latents(prepared)}
        for j, e in enumerate(self.meta["latents"]):
            if e["name"] not in wanted:
                continue
            lo, hi = _y_range(e)
            loc = lo + float(mean[0, j]) * (hi - lo)
            scale = math.sqrt(float(var[0, j])) * (hi - lo)
            out[e["name"]] = (loc, scale, "lognormal" if e["transform"] == "log" else "normal")
        return out

    def proposal(self, scene, tracks: Tracks, names, bounds, every: int = 1):
        """An independence proposal over `names` (with prior `bounds` (D, 2)): the predicted
        log-normal / normal per latent the model reads, uniform over the bounds otherwise."""
        from ..mcmc import Independence

        pred = self.predict(scene, tracks)
        bounds = np.asarray(bounds, float)
        kinds, loc, scale = [], [], []
        for j, n in enumerate(names):
            if n in pred:
                m, s, k = pred[n]
                kinds.append(k), loc.append(float(m)), scale.append(max(float(s), SCALE_FLOOR))
            else:
                kinds.append("uniform"), loc.append(float(bounds[j, 0])), scale.append(float(bounds[j, 1]))
        q = Independence(tuple(kinds), tuple(loc), tuple(scale), int(every))
        try:
            q.check(len(names))
        except ValueError as e:
            raise GalileoError(str(e)) from None
        return q

    def point_estimate(self, scenario, prepared, pred: dict) -> dict[str, float]:
        """The prediction's point: exp(loc) of a log-normal (its median), loc of a normal,
        clipped into the scene's prior bounds (integer latents rounded)."""
        out = {}
        for lat in scenario.latents(prepared):
            loc, _, kind = pred[lat.name]
            v = math.exp(loc) if kind == "lognormal" else loc
            v = min(max(v, float(lat.bounds[0])), float(lat.bounds[1]))
            out[lat.name] = float(round(v)) if lat.integer else float(v)
        return out

    def read_labels(self, scene, tracks: Tracks) -> dict[str, dict]:
        """The video's label per read object, {role: {"mass_kg", "friction"}} (None where the
        video does not identify it): the scenario's `recognition_label` of the point estimate."""
        return self.read_labels_with_spread(scene, tracks)[0]

    def read_labels_with_spread(self, scene, tracks: Tracks, seed: int = 0) -> tuple[dict, dict]:
        """(labels, spreads): spreads per role {"log_mass_sd", "friction_sd"}, the SDs of the
        labels of LABEL_DRAWS draws from the predicted marginals (clipped into the bounds).
        The draws are independent per latent, so where a label combines latents (a mass
        ratio) the spread over-states the uncertainty."""
        scenario, prepared = self._prepared(scene, tracks)
        pred = self._predict_prepared(scenario, prepared, tracks)
        labels = scenario.recognition_label(prepared, tracks, self.point_estimate(scenario, prepared, pred))
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(3,)))
        draws = {n: rng.normal(loc, scale, LABEL_DRAWS) for n, (loc, scale, _) in pred.items()}
        samples: dict[str, dict[str, list]] = {}
        for k in range(LABEL_DRAWS):
            p = {n: (float(draws[n][k]), 0.0, kind) for n, (_, _, kind) in pred.items()}
            drawn = scenario.recognition_label(prepared, tracks, self.point_estimate(scenario, prepared, p))
            for role, lab in drawn.items():
                s = samples.setdefault(role, {"mass_kg": [], "friction": []})
                for q in s:
                    if lab.get(q) is not None:
                        s[q].append(float(lab[q]))
        spreads = {}
        for role, s in samples.items():
            masses = np.array([m for m in s["mass_kg"] if m > 0])
            spreads[role] = {"log_mass_sd": float(np.std(np.log(masses))) if len(masses) > 1 else None,
                             "friction_sd": float(np.std(s["friction"])) if len(s["friction"]) > 1 else None}
        return labels, spreads


# -- training -------------------------------------------------------------------------------------

def fit(scenario_name: str, pairs, *, sims: int = SIMS_PER_SCENE, seed: int = 0, members: int = MEMBERS,
        epochs: int = EPOCHS, hidden=HIDDEN, workers: int | None = None, progress: bool = True) -> SimulationModel:
    """A model trained on simulations of the (scene, tracks) pairs (the tracks give each
    scene's tracked shapes, frame rate, length and visibility; never its latents)."""
    scenario = registry.get(scenario_name)
    pairs = list(pairs)
    if not pairs:
        raise GalileoError("no tracked videos to simulate")
    t0 = time.perf_counter()
    x, values, prepared, _ = simulate_training_set(scenario, pairs, sims=sims, seed=seed, workers=workers,
                                                   progress=progress)
    t_sim = time.perf_counter() - t0
    table = latent_table(scenario, prepared)
    y = targets(table, values)
    slots = max(len(object_roles(p, t)) for p, (_, t) in zip(prepared, pairs))
    noise = noise_scale(x, slots, float(scenario.noise.default))
    # inputs standardised by their spread with the noise (one seeded draw)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(2**31 + 5,)))
    noisy = x + noise * rng.standard_normal(x.shape).astype(np.float32)
    x_mean = noisy.mean(0)
    x_sd = noisy.std(0)
    x_sd = np.where(x_sd > 1e-6, x_sd, 1.0).astype(np.float32)
    del noisy
    t1 = time.perf_counter()
    states, losses = train_networks((x - x_mean) / x_sd, y, noise=noise / x_sd, seed=seed, members=members,
                                    epochs=epochs, hidden=hidden, progress=progress)
    n_scene = x.shape[1] - slots * 3 * T_MAX
    meta = {"scenario": scenario.name, "labels": "simulation", "latents": table, "t_max": T_MAX,
            "features": {"slots": slots, "per_slot": 3 * T_MAX, "scene": int(n_scene), "inputs": int(x.shape[1]),
                         "layout": "per object slot: vx[t_max], vz[t_max], visible[t_max]; then the scenario's "
                                   "recognition_features"},
            "targets": "per latent: transform (ln for masses), then (t - t(lo)) / (t(hi) - t(lo))",
            "noise": {"name": scenario.noise.name, "sd": float(scenario.noise.default)},
            "hidden": [int(h) for h in hidden], "members": members, "epochs": epochs, "batch": BATCH,
            "loss": "Gaussian negative log-likelihood", "seed": seed, "sims_per_scene": sims,
            "simulations": int(len(x)), "scenes": len(pairs), "simulate_seconds": t_sim,
            "fit_seconds": time.perf_counter() - t1, "train_seconds": time.perf_counter() - t0,
            "final_loss": losses, "train_objects": [], "test_objects": [], "holdout_fold": None}
    return SimulationModel(meta, states, x_mean.astype(np.float32), x_sd)


def _usable(examples, cache: dict | None = None) -> list[tuple]:
    """(example, scene, tracks) of the examples whose video the tracker accepts and whose
    tracks fit the scene; the others contribute nothing."""
    from .data import tracks_for

    cache = {} if cache is None else cache
    out = []
    for ex in examples:
        if ex.name not in cache:
            scene = registry.load_scene(ex.scene)
            try:
                tracks = tracks_for(ex, scene)
                if tracks is not None:
                    registry.of(scene).prepare(scene, tracks)
            except GalileoError:
                tracks = None
            cache[ex.name] = (scene, tracks)
        scene, tracks = cache[ex.name]
        if tracks is not None:
            out.append((ex, scene, tracks))
    return out


def train_model(folder: str | Path, *, holdout_fold: int | None = 0, folds: int = 5, seed: int = 0,
                progress: bool = True, examples=None, sims: int = SIMS_PER_SCENE, members: int = MEMBERS,
                epochs: int = EPOCHS, workers: int | None = None, cache: dict | None = None) -> SimulationModel:
    """Train on simulations of the dataset's tracked videos (all objects but those of
    `holdout_fold`; None: all); no labels are read."""
    from .data import load_examples, split

    folder = Path(folder)
    scenario, all_examples = load_examples(folder)
    examples = all_examples if examples is None else examples
    if holdout_fold is None:
        train, test = list(examples), []
    else:
        if not 0 <= holdout_fold < folds:
            raise GalileoError(f"holdout fold must be in 0..{folds - 1}, got {holdout_fold}")
        train, test = split(examples, holdout_fold, folds, seed)
    usable = _usable(train, cache)
    if not usable:
        raise GalileoError(f"{folder}: no training video has tracks")
    model = fit(scenario, [(s, t) for _, s, t in usable], sims=sims, seed=seed, members=members, epochs=epochs,
                workers=workers, progress=progress)
    model.meta.update({"dataset": folder.name, "folds": folds, "holdout_fold": holdout_fold,
                       "train_objects": sorted({e.object_id for e in train}),
                       "test_objects": sorted({e.object_id for e in test}),
                       "train_videos": len(usable)})
    return model


# -- scoring (Fig. 3) -----------------------------------------------------------------------------

def predict_objects(model: SimulationModel, examples, cache: dict | None = None, seed: int = 0) -> dict[str, dict]:
    """One row per object (its videos pooled; the keys of `train.predict_objects`' rows and
    "mass_identified"): the labels the object's tracked videos identify, averaged with
    inverse-variance weights (`read_labels_with_spread`; the mass as ln kg): the videos are
    independent readings, and one that barely identifies a quantity (an object creeping down
    a 10 degree ramp says little more than "friction near tan 10") must not pull a sharp
    reading from another video half way to its prior. Videos the tracker refuses contribute
    nothing."""
    from . import lenet

    scenario = registry.get(model.scenario)
    usable = {ex.name: (scene, tracks) for ex, scene, tracks in _usable(examples, cache)}
    # the scenario's log-normalised mass scale, as the LeNet rows use it
    mass_range = tuple(scenario.recognition_mass_range_kg)
    m_lo, m_hi = mass_range
    prior_log_sd = math.log(m_hi / m_lo) / math.sqrt(12)   # a uniform over the log-normalised scale
    by_obj: dict[str, dict] = {}
    for ex in examples:
        acc = by_obj.setdefault(ex.object_id, {"mass": [], "log_mass_sd": [], "friction": [], "friction_sd": [],
                                               "truth": ex.truth, "fallback_friction": None})
        if ex.name in usable:
            scene, tracks = usable[ex.name]
            labels, spreads = model.read_labels_with_spread(scene, tracks, seed)
            lab, spr = labels.get(ex.role, {}), spreads.get(ex.role, {})
            if lab.get("mass_kg") is not None and lab["mass_kg"] > 0:
                acc["mass"].append(float(lab["mass_kg"]))
                acc["log_mass_sd"].append(spr.get("log_mass_sd"))
            if lab.get("friction") is not None:
                acc["friction"].append(float(lab["friction"]))
                acc["friction_sd"].append(spr.get("friction_sd"))
        if acc["fallback_friction"] is None:
            acc["fallback_friction"] = _prior_friction(scenario, ex, usable.get(ex.name), model)
    rows = {}
    for obj, acc in by_obj.items():
        truth = acc["truth"]
        if acc["mass"]:
            log_mass, log_sd = _pooled(np.log(acc["mass"]), acc["log_mass_sd"], prior_log_sd)
            mass = math.exp(log_mass)
            y = float(lenet.mass_to_y(mass, mass_range))
        else:
            # no video of the object identifies its mass (no collision seen): the middle of the
            # log-normalised scale, y = 0.5, with the SD of a uniform over the scale
            y = 0.5
            mass = float(lenet.y_to_mass(y, mass_range))
            log_sd = prior_log_sd
        if acc["friction"]:
            friction, friction_sd = _pooled(acc["friction"], acc["friction_sd"], acc["fallback_friction"][1])
        else:
            friction, friction_sd = acc["fallback_friction"]
        true_m = truth.get("mass_kg")
        rows[obj] = {"y_mass": y, "friction": friction, "mass_kg": mass, "log_mass_sd": log_sd,
                     "friction_sd": friction_sd,
                     "true_y_mass": float(lenet.mass_to_y(true_m, mass_range)) if true_m else None,
                     "true_mass_kg": true_m, "true_friction": truth.get("friction"),
                     "mass_identified": bool(acc["mass"])}
    return rows


def _pooled(values, sds, default_sd: float) -> tuple[float, float]:
    """Inverse-variance weighted mean and its SD (a reading without an SD counts with
    `default_sd`; SDs floored at SCALE_FLOOR)."""
    v = np.asarray(values, float)
    sd = np.array([default_sd if s is None else max(float(s), SCALE_FLOOR) for s in sds], float)
    w = 1.0 / sd ** 2
    return float(np.sum(w * v) / np.sum(w)), float(1.0 / math.sqrt(np.sum(w)))


def _prior_friction(scenario, ex, usable_pair, model) -> tuple[float, float]:
    """(mean, SD) of the prior of the friction latent of the example's object: its scene's
    (prepared when tracked), else the model's bounds of that latent, else U(0, 1)."""
    try:
        scene = usable_pair[0] if usable_pair else registry.load_scene(ex.scene)
        prepared = scenario.prepare(scene, usable_pair[1]) if usable_pair else scene
        name = next((r.friction for r in scenario.readouts(prepared) if r.role == ex.role), None)
        lats = {lat.name: lat for lat in scenario.latents(prepared)}
        if name in lats:
            lo, hi = lats[name].bounds
            return (lo + hi) / 2, (hi - lo) / math.sqrt(12)
        entry = next((e for e in model.meta["latents"] if e["name"] == name), None)
        if entry is not None:
            lo, hi = entry["bounds"]
            return (lo + hi) / 2, (hi - lo) / math.sqrt(12)
    except GalileoError:
        pass
    return 0.5, 1 / math.sqrt(12)


def fig3_rows(folder: str | Path, seed: int = 0, progress: bool = False, **train_kw):
    """fn(train, test, fold) -> rows for `train.figure3(extra_models={"simulation": fn})`:
    trains on the training examples' simulations (seed + fold) and reads the test objects.
    Tracks are read once per video for all folds."""
    folder = Path(folder)
    cache: dict = {}

    def fn(train, test, fold):
        model = train_model(folder, holdout_fold=None, seed=seed + fold, progress=progress, examples=train,
                            cache=cache, **train_kw)
        model.meta.update({"holdout_fold": fold, "test_objects": sorted({e.object_id for e in test})})
        fn.models[fold] = model
        return predict_objects(model, test, cache, seed=seed + fold)

    fn.models = {}
    return fn
