"""Inference results as ArviZ data: an `xarray.DataTree` in ArviZ's layout (`arviz_base.from_dict`),
which `arviz_stats` summarises and `arviz_plots` draws, and which saves as netCDF or zarr.

Groups (`to_datatree`):

* ``posterior``: each latent's kept draws, dims (chain, draw), in SI units (attribute ``units``;
  ``identified``: "yes", or why the videos do not identify it); the scenario's derived quantities
  that are identified (e.g. the ramp's ``mass_ratio``), per draw (attribute ``derived``: "yes").
* ``warmup_posterior``: the burn-in sweeps' draws (the warm-up in which widths adapt, or the first
  half), which the posterior leaves out, as `galileo.results.burn_in` says.
* ``sample_stats`` (chain, draw): ``lp``, the log-likelihood after the sweep (the priors are
  uniform, so the log posterior up to a constant inside their bounds); ``acceptance_rate``, the share
  of the sweep's proposals accepted; ``n_proposals``; ``early_stopped``, the share of its proposals
  whose simulation stopped early (a guaranteed rejection); and ``move_acceptance`` (chain, draw,
  move): per move (each latent's single-site move, then the joint moves by name: the scenario's,
  the independence move, the fitted move), the share of its proposals accepted in that sweep (NaN
  where the move was not made). The warm-up's sweeps are in ``warmup_sample_stats``.
* ``observed_data``: the tracks inferred from, per video: ``position_m`` and ``velocity_mps``
  (object, frame, axis; NaN where the object was not seen), ``visible`` (object, frame) and the
  frames' ``time_s``; for several videos each variable's name ends in ``_video<k>`` (k from 1).

The root's attributes hold the scenario, the run's settings and the convergence verdict as
result.json says them (JSON text where nested or true/false, which netCDF attributes cannot hold).
"""
from __future__ import annotations

import json
from typing import Sequence

import numpy as np

AXES = ("x", "y", "z")


def sweep_of_proposals(site: np.ndarray) -> np.ndarray:
    """Each proposal's sweep (from 0), for one chain's record of proposals in order: every sweep
    proposes latent 0 first (`galileo.mcmc.sweep`), then the others and the joint moves."""
    return np.cumsum(np.asarray(site) == 0) - 1


def per_sweep(site: np.ndarray, values: np.ndarray, n_sweeps: int, select: np.ndarray | None = None) -> np.ndarray:
    """The mean of `values` over each sweep's proposals (of those `select` picks), (n_sweeps,);
    NaN for a sweep with none."""
    sweep = sweep_of_proposals(site)
    keep = (sweep >= 0) & (sweep < n_sweeps)
    if select is not None:
        keep &= select
    total = np.bincount(sweep[keep], weights=np.asarray(values, float)[keep], minlength=n_sweeps)
    count = np.bincount(sweep[keep], minlength=n_sweeps)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def _move_names(names: Sequence[str], codes: dict) -> list[tuple[str, list[int]]]:
    """(move name, its site codes): each latent's single-site move, then the joint moves."""
    out = [(n, [j]) for j, n in enumerate(names)]
    for name, code in codes.items():
        out.append((f"{name}_move", [int(c) for c in np.atleast_1d(code)]))
    return out


def _sample_stats(names, logliks, proposals, codes) -> tuple[dict, list[str]]:
    """sample_stats' variables over every sweep (chains, sweeps[, move]), and the moves' names."""
    chains, n = logliks.shape
    moves = _move_names(names, codes)
    rate, count, early = np.empty((chains, n)), np.empty((chains, n), int), np.empty((chains, n))
    by_move = np.empty((chains, n, len(moves)))
    for c in range(chains):
        site, accepted = proposals["site"][c], proposals["accepted"][c]
        rate[c] = per_sweep(site, accepted, n)
        early[c] = per_sweep(site, proposals["early_stop"][c], n)
        count[c] = np.bincount(np.clip(sweep_of_proposals(site), 0, None), minlength=n)[:n]
        for k, (_, code) in enumerate(moves):
            by_move[c, :, k] = per_sweep(site, accepted, n, np.isin(site, code))
    return ({"lp": logliks, "acceptance_rate": rate, "n_proposals": count, "early_stopped": early,
             "move_acceptance": by_move}, [m for m, _ in moves])


def _observed(tracks) -> tuple[dict, dict, dict]:
    """observed_data variables, their dims and coordinates from one Tracks or a list of them."""
    several = isinstance(tracks, (list, tuple))
    data, dims, coords = {}, {}, {"axis": list(AXES)}
    for v, tr in enumerate(tracks if several else [tracks]):
        end = f"_video{v + 1}" if several else ""
        obj, frame = f"object{end}", f"frame{end}"
        coords[obj] = [o.name for o in tr.objects]
        coords[frame] = np.arange(tr.n_frames)
        data[f"position_m{end}"] = np.stack([o.position_m for o in tr.objects]).astype(float)
        data[f"velocity_mps{end}"] = np.stack([o.velocity_mps for o in tr.objects]).astype(float)
        data[f"visible{end}"] = np.stack([o.visible for o in tr.objects]).astype(bool)
        data[f"time_s{end}"] = tr.time_s
        dims.update({f"position_m{end}": [obj, frame, "axis"], f"velocity_mps{end}": [obj, frame, "axis"],
                     f"visible{end}": [obj, frame], f"time_s{end}": [frame]})
    return data, dims, coords


def to_datatree(*, names: Sequence[str], units: dict, samples: np.ndarray, logliks: np.ndarray, proposals: dict,
                burn_in: int, codes: dict | None = None, derived: dict | None = None,
                unidentified: dict | None = None, tracks=None, attrs: dict | None = None):
    """The ArviZ DataTree of a run (see the module): `samples` (chains, sweeps, latents), `logliks`
    (chains, sweeps), `proposals` the per-proposal record (`galileo.results.InferenceResult`),
    `burn_in` the sweeps left out of the posterior, `codes` the joint moves' site codes,
    `derived` {name: (chains, kept draws)} values of derived quantities, `unidentified` {name:
    why}, `tracks` the observations (one Tracks or a list), `attrs` the root's attributes."""
    from arviz_base import from_dict

    samples, logliks = np.asarray(samples, float), np.asarray(logliks, float)
    kept, warm = slice(burn_in, None), slice(0, burn_in)
    unidentified = unidentified or {}
    data = {"posterior": {n: samples[:, kept, j] for j, n in enumerate(names)}}
    for k, v in (derived or {}).items():
        data["posterior"][k] = np.asarray(v, float)
    stats, move_names = _sample_stats(names, logliks, proposals, codes or {})
    data["sample_stats"] = {k: v[:, kept] for k, v in stats.items()}
    dims = {"move_acceptance": ["move"]}
    coords = {"move": move_names}
    if burn_in > 0:
        data["warmup_posterior"] = {n: samples[:, warm, j] for j, n in enumerate(names)}
        data["warmup_sample_stats"] = {k: v[:, warm] for k, v in stats.items()}
    if tracks is not None:
        obs, obs_dims, obs_coords = _observed(tracks)
        data["observed_data"] = obs
        dims.update(obs_dims)
        coords.update(obs_coords)
    # (netCDF attributes: text and numbers; anything else, booleans included, as JSON text)
    root = {k: (v if isinstance(v, (str, int, float)) and not isinstance(v, bool) else json.dumps(v))
            for k, v in (attrs or {}).items() if v is not None}
    dt = from_dict(data, dims=dims, coords=coords, save_warmup=burn_in > 0, attrs={"/": root})
    for j, n in enumerate(names):
        for group in ("posterior", "warmup_posterior"):
            if group in dt.children:
                var = dt[group][n]
                var.attrs["units"] = units.get(n, "")
                var.attrs["identified"] = "yes" if n not in unidentified else f"no: {unidentified[n]}"
    for k in derived or {}:
        dt["posterior"][k].attrs.update({"derived": "yes", "units": units.get(k, "1")})
    dt["sample_stats"]["lp"].attrs["meaning"] = ("log-likelihood after the sweep (uniform priors: the log posterior "
                                                 "up to a constant inside their bounds)")
    return dt
