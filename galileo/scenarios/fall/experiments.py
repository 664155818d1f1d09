"""The fall's experiments on a rendered fall dataset (`galileo experiment`, issue 27).

For every video: tracked by the tracker, then two inferences (the scenario's 16 x 75):

* **the whole clip**: the object-surface pair's restitution e and friction mu (posterior median,
  90% interval) against the truth; median absolute error and 90% coverage over the videos
  (friction only over the videos where the object slides: the truth's centre moves more than
  SLIDE_MIN_M along the surface after the first impact; elsewhere friction is barely seen);
* **the first bounce alone**: the track cut `FIRST_BOUNCE_FRAMES` frames after the tracked
  landing; `PREDICT_DRAWS` kept draws simulated to the clip's end predict where the object comes
  to rest (the mean of the draws' resting centres on the surface) and how high the second
  bounce goes (the mean of the draws' centre rise after their second impact); errors against
  the truth, and against a mean-outcome baseline (the resting place: the landing point plus the
  mean displacement from landing to rest over the other videos; the second bounce: the other
  videos' mean);
* **which surface is bouncier**: over every pair of videos whose true e differ by at least
  PAIR_MIN_DE, the share where the posterior medians order them as the truth does.

A failure (tracking, inference) goes into the video's record as one line; it does not stop the
experiment. `galileo.batch` runs `run_video` for every video and calls `summarise`.
"""
from __future__ import annotations

import dataclasses
import itertools
import time
from pathlib import Path

import numpy as np

from ... import registry
from ...datatypes import Trajectory
from ...jsonio import read_json
from ...runner import RunConfig, infer
from .scene import NOISE_LATENTS, pair_latents

FIRST_BOUNCE_FRAMES = 6     # the first bounce: the track up to this many frames (0.2 s at 30 fps) after the landing
PREDICT_DRAWS = 24          # kept draws simulated forward for a prediction
SLIDE_MIN_M = 0.02          # the object slides: its centre moves this far along the surface after the first impact
PAIR_MIN_DE = 0.05          # pairs whose true e differ by less are not asked which is bouncier
TARGETS = {"e_median_abs_error": 0.05, "mu_median_abs_error": 0.05, "coverage_90": (0.85, 0.95),
           "rest_median_error_m": 0.03}
KEEP = ("q05", "q50", "q95", "sd")


def _one_line(e: BaseException) -> str:
    text = str(e).strip().splitlines()
    return text[0] if text else type(e).__name__


def _stats(post: dict, name: str) -> dict:
    return {k: float(post[name][k]) for k in KEEP}


def predict(result, tracks, scene, n_frames: int, draws: int = PREDICT_DRAWS, seed: int = 0) -> dict:
    """Simulate `draws` kept draws of `result` over `n_frames`: the mean resting place (x, y of the
    centre at the last frame) and the mean second-bounce rise (None where under half the draws
    bounce twice)."""
    from .dataset import bounce_apexes_m
    from .physics import simulate

    kept = result.kept().reshape(-1, len(result.names))
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(kept), size=min(draws, len(kept)), replace=False)
    sub = 8                                    # sub-frames: impacts are found in the fine motion
    rests, seconds = [], []
    for i in pick:
        values = {n: float(v) for n, v in zip(result.names, kept[i]) if n not in NOISE_LATENTS}
        s = dataclasses.replace(scene, n_frames=n_frames, camera=None)
        if s.sim_hz % (s.fps * sub):
            sub = 1
        fine = simulate(s, n_frames * sub, values, s.fps * sub)
        pos = fine.position_m[0]
        rests.append(pos[-1, :2])
        second = bounce_apexes_m(fine, float(pos[-1, 2]))[1]
        if second is not None:
            seconds.append(second)
    rest = np.mean(rests, axis=0)
    return {"rest_pos_m": rest.tolist(), "rest_spread_m": float(np.mean(np.linalg.norm(np.array(rests) - rest, axis=1))),
            "second_bounce_apex_m": float(np.mean(seconds)) if len(seconds) * 2 >= len(pick) else None}


def cut_tracks(tracks, last_frame: int):
    """The tracks seen up to `last_frame` only (the frames after: not seen)."""
    obj = tracks.objects[0]
    vis = np.asarray(obj.visible, bool).copy()
    vis[last_frame + 1:] = False
    pos = np.asarray(obj.position_m, float).copy()
    pos[~vis] = np.nan
    vel = np.asarray(obj.velocity_mps, float).copy()
    vel[~vis] = np.nan
    o = dataclasses.replace(obj, visible=vis, position_m=pos, velocity_mps=vel)
    return dataclasses.replace(tracks, objects=[o])


def run_video(folder: Path, config: RunConfig, executor=None) -> dict:
    """This video's whole-clip and first-bounce inferences against its truth (see the module)."""
    folder = Path(folder)
    scene = registry.load_scene(folder / "scene.json")
    truth = read_json(folder / "truth.json", "truth file")
    pl = pair_latents(scene.object, scene.surface)
    traj = Trajectory.from_json(truth["trajectory"]).position_m[0] if "trajectory" in truth else None
    rec = {"video": folder.name, "scenario": "fall", "object": scene.object, "surface": scene.surface,
           "surface_kind": scene.surface_kind,
           "truth": {"e": scene.restitution, "mu": scene.friction, "rest_pos_m": truth.get("rest_pos_m"),
                     "second_bounce_apex_m": truth.get("second_bounce_apex_m"),
                     "landing_pos_m": None, "slides": None}}
    if traj is not None:
        low = np.flatnonzero(traj[:, 2] <= traj[-1, 2] + 0.01)
        if len(low):
            land = traj[int(low[0]), :2]
            rec["truth"]["landing_pos_m"] = land.tolist()
            rec["truth"]["slides"] = bool(np.linalg.norm(traj[-1, :2] - land) > SLIDE_MIN_M)
    scenario = registry.of(scene)
    try:
        tracks = scenario.track(folder / "video.mp4", scene, progress=False)
    except Exception as e:  # noqa: BLE001 - any tracking failure is a result of the experiment
        return {**rec, "status": "failed", "error": f"tracking: {_one_line(e)}"}
    try:
        t0 = time.perf_counter()
        res = infer(scene, tracks, config, executor=executor, progress=False)
        post, diag = res.posterior(), res.diagnostics()
        rec.update({"e": _stats(post, pl["e"]), "mu": _stats(post, pl["mu"]),
                    "r_hat": {n: diag["r_hat"][n] for n in (pl["e"], pl["mu"])}, "seconds": time.perf_counter() - t0})
        land = int(tracks.objects[0].bottom_up.get("landing_frame", scene.release_frame))
        cut = min(tracks.n_frames - 1, land + FIRST_BOUNCE_FRAMES)
        first = infer(scene, cut_tracks(tracks, cut), config, executor=executor, progress=False)
        rec["first_bounce"] = {"cut_frame": cut, "e": _stats(first.posterior(), pl["e"]),
                               **predict(first, tracks, first.scene, tracks.n_frames)}
    except Exception as e:  # noqa: BLE001 - a failed inference is a result too
        return {**rec, "status": "failed", "error": _one_line(e)}
    rec["status"] = "fitted"
    return rec


def _fitted(records: list[dict]) -> list[dict]:
    return [r for r in records if r.get("status") == "fitted"]


def _err_cover(recs: list[dict], key: str) -> dict:
    if not recs:
        return {"videos": 0, "median_abs_error": None, "coverage_90": None}
    err = [abs(r[key]["q50"] - r["truth"][key]) for r in recs]
    cov = [r[key]["q05"] <= r["truth"][key] <= r[key]["q95"] for r in recs]
    return {"videos": len(recs), "median_abs_error": float(np.median(err)), "coverage_90": float(np.mean(cov))}


def summarise(records: list[dict]) -> dict:
    fitted = _fitted(records)
    e = _err_cover(fitted, "e")
    mu = _err_cover([r for r in fitted if r["truth"].get("slides")], "mu")
    pairs = [(a, b) for a, b in itertools.combinations(fitted, 2) if abs(a["truth"]["e"] - b["truth"]["e"]) >= PAIR_MIN_DE]
    right = [(a["e"]["q50"] > b["e"]["q50"]) == (a["truth"]["e"] > b["truth"]["e"]) for a, b in pairs]
    rest_err, rest_base, sec_err, sec_base = [], [], [], []
    for r in fitted:
        fb, t = r.get("first_bounce"), r["truth"]
        if not fb or t.get("rest_pos_m") is None:
            continue
        others = [o for o in fitted if o is not r and o["truth"].get("landing_pos_m") is not None]
        rest_err.append(float(np.linalg.norm(np.subtract(fb["rest_pos_m"], t["rest_pos_m"]))))
        if others and t.get("landing_pos_m") is not None:
            shift = np.mean([np.subtract(o["truth"]["rest_pos_m"], o["truth"]["landing_pos_m"]) for o in others], axis=0)
            rest_base.append(float(np.linalg.norm(np.add(t["landing_pos_m"], shift) - np.asarray(t["rest_pos_m"]))))
        seconds = [o["truth"]["second_bounce_apex_m"] or 0.0 for o in others]
        if fb.get("second_bounce_apex_m") is not None or t.get("second_bounce_apex_m") is not None:
            sec_err.append(abs((fb.get("second_bounce_apex_m") or 0.0) - (t.get("second_bounce_apex_m") or 0.0)))
            if seconds:
                sec_base.append(abs(float(np.mean(seconds)) - (t.get("second_bounce_apex_m") or 0.0)))

    def med(x):
        return float(np.median(x)) if x else None

    return {"videos": len(records), "fitted": len(fitted), "restitution": e, "friction_sliding": mu,
            "which_is_bouncier": {"pairs": len(pairs), "accuracy": float(np.mean(right)) if right else None},
            "prediction_from_first_bounce": {"videos": len(rest_err), "rest_median_error_m": med(rest_err),
                                             "rest_baseline_median_error_m": med(rest_base),
                                             "second_bounce_median_error_m": med(sec_err),
                                             "second_bounce_baseline_median_error_m": med(sec_base)},
            "targets": TARGETS}


def sections(records: list[dict], fig_dir: Path) -> list:
    """The report's section: restitution against its truth, and the predictions, with the numbers."""
    from ...report import Section, diagonal, md_table, new_figure, save_figure

    s = summarise(records)
    title = "Bounciness and friction from a fall"
    paper = ("Physics 101 section 2 drops every object onto surfaces of several kinds; this experiment asks the "
             "object-surface pair's restitution and friction (issue 27's targets: within 0.05 median, 90% intervals "
             "covering 85-95%, the resting place from the first bounce within 3 cm).")

    def f(v, unit=""):
        return "-" if v is None else f"{v:.3g}{unit}"

    e, mu, p = s["restitution"], s["friction_sliding"], s["prediction_from_first_bounce"]
    rows = [["restitution: median |error| (videos)", f"{f(e['median_abs_error'])} ({e['videos']})"],
            ["restitution: 90% coverage", f(e["coverage_90"])],
            ["friction, sliding videos: median |error| (videos)", f"{f(mu['median_abs_error'])} ({mu['videos']})"],
            ["friction: 90% coverage", f(mu["coverage_90"])],
            ["which is bouncier (pairs)", f"{f(s['which_is_bouncier']['accuracy'])} "
                                          f"({s['which_is_bouncier']['pairs']})"],
            ["resting place from the first bounce: median error", f(p["rest_median_error_m"], " m")],
            ["... mean-outcome baseline", f(p["rest_baseline_median_error_m"], " m")],
            ["second bounce's height: median error", f(p["second_bounce_median_error_m"], " m")],
            ["... mean-outcome baseline", f(p["second_bounce_baseline_median_error_m"], " m")]]
    body = md_table(["quantity", "value"], rows)
    fitted = _fitted(records)
    if not fitted:
        return [Section(title, paper, None, "No data: no video was fitted.\n\n" + body, s)]
    fig, ax = new_figure()
    t = np.array([r["truth"]["e"] for r in fitted])
    q = np.array([[r["e"]["q05"], r["e"]["q50"], r["e"]["q95"]] for r in fitted])
    ax.errorbar(t, q[:, 1], yerr=[q[:, 1] - q[:, 0], q[:, 2] - q[:, 1]], fmt="o", ms=3)
    diagonal(ax, "inferred = true")
    ax.set_xlabel("true restitution e")
    ax.set_ylabel("posterior e, median and 90%")
    png = save_figure(fig, Path(fig_dir) / "fall_restitution.png")
    return [Section(title, paper, png, body, s)]

