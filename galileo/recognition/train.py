"""Training and scoring the recognition model on a rendered dataset (Galileo section 4, Fig. 3).

Protocol, as the paper's: hold out objects, not videos. `data.object_folds` deals every
material's objects round 5 folds; fold f's objects are the test set of split f (all their
videos), the rest train. Per split:

* LeNet on Galileo labels (`labels.galileo.json`: what MCMC inferred on each training video;
  an object's label is the mean over its labelled videos, used for all its videos' patches);
* LeNet on ground-truth labels (the "oracle": the same training objects, their true values);
* the uniform baseline: the mean of the test objects' true values (the paper's; its
  correlation is undefined and reported as 0, as the paper's table does).

Scores on the test objects (one prediction per object: its videos' patches pooled) against
ground truth: MSE and Pearson correlation of mass on the log-normalised scale
(`lenet.MASS_RANGE_KG`) and of friction. The table reports mean and SD over the 5 splits.
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from ..progress import tqdm
from .. import registry
from ..errors import GalileoError
from ..jsonio import atomic_write_bytes, write_json
from . import lenet
from .data import QUANTITIES, Example, load_examples, patches, read_labels, split, tracks_for
from .model import LeNetModel

FOLDS = 5
PAPER = {"oracle": {"mse": 0.042, "pearson": 0.71}, "galileo": {"mse": 0.052, "pearson": 0.44},
         "uniform": {"mse": 0.081, "pearson": 0.0}}


def collect_patches(examples: list[Example], progress: bool = True) -> dict[str, np.ndarray]:
    """Patches of every example's object (videos the tracker refuses are cropped where the
    scene file puts the object); an example that cannot be cropped is left out."""
    out = {}
    for ex in tqdm(examples, desc="patches", unit="video", disable=not progress):
        scene = registry.load_scene(ex.scene)
        try:
            tracks = tracks_for(ex, scene)
            prepared = registry.of(scene).prepare(scene, tracks) if tracks is not None else scene
            out[ex.name] = patches(ex.video, prepared, tracks, ex.role)
        except GalileoError:
            continue
    if not out:
        raise GalileoError("no video's object could be cropped")
    return out


def object_labels(examples: list[Example], labels: dict[str, dict]) -> dict[str, dict]:
    """Per object, the mean of its videos' labels (None where none of them has one)."""
    acc: dict[str, dict[str, list]] = {}
    for ex in examples:
        lab = labels.get(ex.name, {})
        for q in QUANTITIES:
            v = lab.get(q)
            acc.setdefault(ex.object_id, {k: [] for k in QUANTITIES})
            if v is not None:
                acc[ex.object_id][q].append(float(v))
    return {o: {q: (float(np.mean(v)) if v else None) for q, v in d.items()} for o, d in acc.items()}


def training_arrays(examples, patch_by_name, labels, mass_range) -> tuple[np.ndarray, np.ndarray]:
    """Patches and labels of the examples' objects."""
    per_object = object_labels(examples, labels)
    xs, ys = [], []
    for ex in examples:
        p = patch_by_name.get(ex.name)
        if p is None:
            continue
        lab = per_object.get(ex.object_id, {})
        m = lab.get("mass_kg")
        y = [float(lenet.mass_to_y(m, mass_range)) if m is not None and m > 0 else math.nan,
             lab.get("friction") if lab.get("friction") is not None else math.nan]
        xs.append(p)
        ys.append(np.tile(y, (len(p), 1)))
    if not xs:
        raise GalileoError("no training video has patches")
    return np.concatenate(xs), np.concatenate(ys)


def train_model(folder: str | Path, labels: str = "galileo", *, holdout_fold: int | None = 0, folds: int = FOLDS,
                seed: int = 0, members: int = lenet.MEMBERS, epochs: int = lenet.EPOCHS, progress: bool = True,
                examples=None, patch_by_name=None) -> LeNetModel:
    """Train LeNet on the dataset's videos (all objects but those of `holdout_fold`)."""
    folder = Path(folder)
    scenario, all_examples = load_examples(folder)
    examples = all_examples if examples is None else examples
    label_values = read_labels(folder, labels, examples)
    if holdout_fold is None:
        train, test = examples, []
    else:
        if not 0 <= holdout_fold < folds:
            raise GalileoError(f"holdout fold must be in 0..{folds - 1}, got {holdout_fold}")
        train, test = split(examples, holdout_fold, folds, seed)
    if patch_by_name is None:
        patch_by_name = collect_patches(train, progress)
    mass_range = registry.get(scenario).recognition_mass_range_kg
    x, y = training_arrays(train, patch_by_name, label_values, mass_range)
    t0 = time.perf_counter()
    trained = lenet.train(x, y, seed=seed, members=members, epochs=epochs, progress=progress,
                          desc=f"LeNet on {labels} labels")
    meta = {"scenario": scenario, "labels": labels, "mass_range_kg": list(mass_range),
            "quantities": [q for j, q in enumerate(QUANTITIES) if np.isfinite(y[:, j]).any()],
            "mass_scale": "y = ln(m / m_lo) / ln(m_hi / m_lo)", "patch": {"side_m": _patch_side(), "size_px": 32},
            "input": "3x32x32 RGB, (x / 255 - 0.5) / 0.25", "loss": "Gaussian negative log-likelihood",
            "architecture": "LeNet-5: conv5x5(6)-relu-pool2-conv5x5(16)-relu-pool2-fc(120)-relu-fc(4)",
            "epochs": epochs, "seed": seed, "folds": folds, "holdout_fold": holdout_fold, "dataset": folder.name,
            "train_objects": sorted({e.object_id for e in train}), "test_objects": sorted({e.object_id for e in test}),
            "train_patches": int(len(x)), "train_seconds": time.perf_counter() - t0,
            "final_loss": [h[-1] for h in trained.history]}
    return LeNetModel(meta, trained.states)


def _patch_side() -> float:
    from ..vision.patch import SIDE_M

    return SIDE_M


# -- scoring -----------------------------------------------------------------------------------------

def predict_objects(model: LeNetModel, examples: list[Example], patch_by_name) -> dict[str, dict]:
    """Per test object: the pooled reading (normalised mass, friction) and its truth."""
    by_obj: dict[str, list] = {}
    truth: dict[str, dict] = {}
    for ex in examples:
        p = patch_by_name.get(ex.name)
        if p is None:
            continue
        by_obj.setdefault(ex.object_id, []).append(p)
        truth[ex.object_id] = ex.truth
    lo, hi = model.mass_range_kg
    out = {}
    for obj, ps in by_obj.items():
        r = model.read_patches(np.concatenate(ps))
        out[obj] = {"y_mass": (r.log_mass - math.log(lo)) / math.log(hi / lo), "friction": r.friction,
                    "mass_kg": r.mass_kg, "log_mass_sd": r.log_mass_sd, "friction_sd": r.friction_sd,
                    "true_y_mass": float(lenet.mass_to_y(truth[obj]["mass_kg"], (lo, hi))),
                    "true_mass_kg": truth[obj]["mass_kg"], "true_friction": truth[obj]["friction"]}
    return out


def metrics(pred: np.ndarray, true: np.ndarray) -> dict:
    pred, true = np.asarray(pred, float), np.asarray(true, float)
    mse = float(np.mean((pred - true) ** 2))
    def varies(x):   # a constant (the uniform baseline) has no correlation: 0, not rounding noise
        return np.ptp(x) > 1e-12 * max(1.0, float(np.abs(x).max()))
    r = float(np.corrcoef(pred, true)[0, 1]) if len(pred) > 2 and varies(pred) and varies(true) else 0.0
    return {"mse": mse, "pearson": r}


def score(rows: dict[str, dict]) -> dict:
    """MSE and Pearson against the truth per quantity, and the share of test objects whose
    true value lies in the model's 90% interval (models that give one)."""
    v = list(rows.values())
    z = 1.6448536269514722
    out = {"mass": metrics([r["y_mass"] for r in v], [r["true_y_mass"] for r in v]), "objects": len(v)}
    if v and all(r.get("log_mass_sd") is not None for r in v):
        out["mass"]["coverage90"] = float(np.mean([abs(math.log(r["true_mass_kg"] / r["mass_kg"]))
                                                   <= z * r["log_mass_sd"] for r in v]))
    if v and all(r.get("friction") is not None and r.get("true_friction") is not None for r in v):
        out["friction"] = metrics([r["friction"] for r in v], [r["true_friction"] for r in v])
        if all(r.get("friction_sd") is not None for r in v):
            out["friction"]["coverage90"] = float(np.mean([abs(r["true_friction"] - r["friction"])
                                                           <= z * r["friction_sd"] for r in v]))
    return out


def uniform_rows(rows: dict[str, dict], mass_range) -> dict[str, dict]:
    """The paper's baseline: every test object gets the mean of the test objects' truths."""
    ym = float(np.mean([r["true_y_mass"] for r in rows.values()]))
    frs = [r["true_friction"] for r in rows.values() if r["true_friction"] is not None]
    fr = float(np.mean(frs)) if frs else None
    return {o: {**r, "y_mass": ym, "friction": fr, "mass_kg": float(lenet.y_to_mass(ym, mass_range)),
                "log_mass_sd": None, "friction_sd": None} for o, r in rows.items()}


def figure3(folder: str | Path, out_dir: str | Path, *, folds: int = FOLDS, seed: int = 0,
            members: int = lenet.MEMBERS, epochs: int = lenet.EPOCHS, progress: bool = True,
            extra_models: dict | None = None, simulation: bool = False) -> dict:
    """The Fig. 3 table over `folds` object-held-out splits; writes table.json, table.md and
    the scatter figures into out_dir. `extra_models`: name -> fn(train, test, fold) -> rows
    (e.g. the simulation-trained model)."""
    folder, out_dir = Path(folder), Path(out_dir)
    scenario, examples = load_examples(folder)
    extra_models = dict(extra_models or {})
    if simulation:
        from .simulation import fig3_rows

        extra_models["simulation"] = fig3_rows(folder, seed=seed, progress=progress)
    mass_range = registry.get(scenario).recognition_mass_range_kg
    label_values = {src: read_labels(folder, src, examples) for src in ("galileo", "oracle")}
    patch_by_name = collect_patches(examples, progress)
    per_fold: dict[str, list] = {}
    rows_all: dict[str, dict] = {}
    t0 = time.perf_counter()
    for fold in range(folds):
        train, test = split(examples, fold, folds, seed)
        fold_rows = {}
        for src in ("galileo", "oracle"):
            x, y = training_arrays(train, patch_by_name, label_values[src], mass_range)
            trained = lenet.train(x, y, seed=seed + fold, members=members, epochs=epochs, progress=progress,
                                  desc=f"split {fold + 1}/{folds}: {src}")
            model = LeNetModel({"scenario": scenario, "mass_range_kg": list(mass_range),
                                "quantities": [q for j, q in enumerate(QUANTITIES) if np.isfinite(y[:, j]).any()]},
                               trained.states)
            fold_rows[src] = predict_objects(model, test, patch_by_name)
        fold_rows["uniform"] = uniform_rows(fold_rows["oracle"], mass_range)
        for name, fn in extra_models.items():
            fold_rows[name] = fn(train, test, fold)
        for name, rows in fold_rows.items():
            per_fold.setdefault(name, []).append(score(rows))
            for o, r in rows.items():
                rows_all.setdefault(name, {})[o] = {**r, "fold": fold}
    table = {"scenario": scenario, "dataset": str(folder), "folds": folds, "seed": seed,
             "mass_scale": {"y": "ln(m / m_lo) / ln(m_hi / m_lo)", "mass_range_kg": list(mass_range)},
             "seconds": time.perf_counter() - t0, "paper_mass": PAPER, "models": {}}
    for name, scores in per_fold.items():
        entry = {}
        for q in ("mass", "friction"):
            if not all(q in s for s in scores):
                continue
            for m in ("mse", "pearson"):
                vals = [s[q][m] for s in scores]
                entry[f"{q}_{m}"] = {"mean": float(np.mean(vals)), "sd": float(np.std(vals, ddof=1)) if len(vals) > 1
                                     else 0.0, "per_split": vals}
        for q in ("mass", "friction"):
            cov = [s[q]["coverage90"] for s in scores if q in s and "coverage90" in s[q]]
            if cov:
                entry[f"{q}_coverage90"] = {"mean": float(np.mean(cov)), "per_split": cov}
        entry["test_objects_per_split"] = [s["objects"] for s in scores]
        table["models"][name] = entry
    table["predictions"] = rows_all
    return write_table(out_dir, table, rows_all)


def evaluate_model(folder: str | Path, model_path: str | Path, out_dir: str | Path, progress: bool = True) -> dict:
    """Score one trained model on the objects it held out (its header names them)."""
    from .model import load_model

    folder, out_dir = Path(folder), Path(out_dir)
    scenario, examples = load_examples(folder)
    model = load_model(model_path, scenario)
    held = set(model.meta.get("test_objects") or [])
    if not held:
        raise GalileoError(f"{model_path} held out no objects (trained with --holdout-fold -1): nothing to test on")
    test = [e for e in examples if e.object_id in held]
    if not test:
        raise GalileoError(f"none of the objects {model_path} held out is in {folder}")
    if model.kind == "simulation":
        from .simulation import predict_objects as simulation_rows

        rows = simulation_rows(model, test)
    else:
        rows = predict_objects(model, test, collect_patches(test, progress))
    rows_all = {model.meta.get("labels", "model"): rows, "uniform": uniform_rows(rows, model.mass_range_kg)}
    table = {"scenario": scenario, "dataset": str(folder), "model": str(model_path), "folds": 1,
             "seed": model.meta.get("seed"),
             "mass_scale": {"y": "ln(m / m_lo) / ln(m_hi / m_lo)", "mass_range_kg": list(model.mass_range_kg)},
             "paper_mass": PAPER, "models": {}, "predictions": rows_all}
    for name, r in rows_all.items():
        sc = score(r)
        table["models"][name] = {f"{q}_{m}": {"mean": sc[q][m], "sd": 0.0, "per_split": [sc[q][m]]}
                                 for q in ("mass", "friction") if q in sc
                                 for m in ("mse", "pearson", "coverage90") if m in sc[q]}
        table["models"][name]["test_objects_per_split"] = [sc["objects"]]
    return write_table(out_dir, table, rows_all)


def write_table(out_dir: Path, table: dict, rows_all: dict) -> dict:
    """table.json, table.md and the mass and friction scatter PNGs into out_dir."""
    out_dir.mkdir(parents=True, exist_ok=True)
    write_json(out_dir / "table.json", table)
    atomic_write_bytes(out_dir / "table.md", markdown(table).encode())
    scatter(rows_all, out_dir / "mass_scatter.png", "mass")
    scatter(rows_all, out_dir / "friction_scatter.png", "friction")
    return table


def markdown(table: dict) -> str:
    lines = [f"# Recognition from one frame (Galileo Fig. 3): {table['dataset']}", "",
             f"{table['folds']} splits holding out objects (every material's objects dealt round the splits), "
             f"seed {table['seed']}; mean +- SD over the splits. Mass on the log-normalised scale "
             f"y = ln(m / {table['mass_scale']['mass_range_kg'][0]} kg) / ln({table['mass_scale']['mass_range_kg'][1]}"
             f" / {table['mass_scale']['mass_range_kg'][0]}).", "",
             "| model | mass MSE | mass Pearson | paper MSE / Pearson | friction MSE | friction Pearson | "
             "90% intervals cover (mass, friction) |",
             "|---|---|---|---|---|---|---|"]
    for name, e in table["models"].items():
        paper = table["paper_mass"].get(name)
        p = f"{paper['mse']:.3f} / {paper['pearson']:.2f}" if paper else "-"

        def f(key, digits):
            return f"{e[key]['mean']:.{digits}f} +- {e[key]['sd']:.{digits}f}" if key in e else "-"

        def pct(key):
            return f"{100 * e[key]['mean']:.0f}%" if key in e else "-"
        cov = f"{pct('mass_coverage90')}, {pct('friction_coverage90')}"
        lines.append(f"| {name} | {f('mass_mse', 3)} | {f('mass_pearson', 2)} | {p} | {f('friction_mse', 4)} | "
                     f"{f('friction_pearson', 2)} | {cov} |")
    lines += ["", "uniform: every test object gets the mean of the test objects' true values (its correlation "
              "is undefined; 0 as in the paper).", ""]
    return "\n".join(lines)


def scatter(rows_all: dict[str, dict], path: Path, quantity: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.2, 5.0), dpi=110)
    markers = {"oracle": "s", "galileo": "o", "uniform": "x", "simulation": "^"}
    for name, rows in rows_all.items():
        v = list(rows.values())
        if quantity == "mass":
            x, y = [r["true_mass_kg"] for r in v], [r["mass_kg"] for r in v]
        else:
            v = [r for r in v if r.get("friction") is not None and r.get("true_friction") is not None]
            if not v:
                continue
            x, y = [r["true_friction"] for r in v], [r["friction"] for r in v]
        ax.scatter(x, y, s=18, marker=markers.get(name, "o"), alpha=0.75, label=name)
    lo = min(ax.get_xlim()[0], ax.get_ylim()[0])
    hi = max(ax.get_xlim()[1], ax.get_ylim()[1])
    if quantity == "mass":
        ax.set_xscale("log"), ax.set_yscale("log")
        lo = max(lo, 1e-3)
    ax.plot([lo, hi], [lo, hi], "k--", lw=0.8, label="y = x")
    unit = " (kg)" if quantity == "mass" else ""
    ax.set_xlabel(f"true {quantity}{unit}"), ax.set_ylabel(f"predicted {quantity}{unit}")
    ax.set_title(f"{quantity} of held-out objects\n(LeNet: one frame; simulation model: the tracked motion)",
                 fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.png")
    fig.savefig(tmp)
    plt.close(fig)
    tmp.replace(path)
