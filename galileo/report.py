"""The experiments' results table and their report, for any scenario.

A run of `galileo experiment` leaves one nested record per video (see `galileo.batch`).
`write_table` keeps them as one flat row per video (`flatten`: dotted column names such as
`posterior.k1.q05`) in results.parquet and results.csv; `read_table` reads either back into
records. `build_report` writes report.md and figures/*.png: a header (dataset, config,
fitted/skipped/failed counts, the failed videos' errors), the scenario's own sections (its
package's `report.sections(records, fig_dir) -> list[Section]`, found through the registry),
then three sections every scenario gets: convergence (R-hat per latent), interval coverage
(every latent with both a truth and a posterior, counted over the videos that identify it: a
quantity a record lists in `not_identified` is greyed and labelled so) and time and memory per
video and worker ("worker 1", "worker 2", ... on an axis from 0 MiB). Figures set the paper's
numbers beside ours (`paper_bars`: a dashed line labelled "paper: <value>"); log axes label
their major ticks only (`plain_log_axes`).

This module names no latent: it reads whatever the records carry.
"""
from __future__ import annotations

import csv
import io
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from .errors import GalileoError
from .jsonio import atomic_write_bytes

SEP = "."                       # between the parts of a column name
TABLE_STEM = "results"          # results.parquet, results.csv
REPORT_NAME = "report.md"
FIG_DIR = "figures"
JSON_COLUMNS_KEY = b"galileo.json_columns"   # parquet metadata: the columns kept as JSON text
RHAT_MAX = 1.01                 # the line drawn on the R-hat plot
INTERVAL = ("q05", "q95")       # the 90% posterior interval
INTERVAL_LEVEL = 0.90
INNER_INTERVAL = ("q25", "q75")  # the 50% interval, where the records have it
INNER_LEVEL = 0.50
FIG_DPI = 110
FIG_SIZE_IN = (6.4, 4.4)
NA = "n/a"
STATUSES = ("fitted", "skipped", "failed")


@dataclass
class Section:
    """One section of report.md: a figure (`png`, a file in figures/, None without data), the
    paper's figure it reproduces with the paper's numbers (`paper`), a markdown body (the
    numbers and how to read them) and the numbers themselves (`numbers`, for callers and tests)."""
    title: str
    paper: str
    png: str | None
    body: str
    numbers: dict = field(default_factory=dict)


# -- flat rows ------------------------------------------------------------------------------------------

def _plain(v: Any) -> Any:
    """A leaf as plain Python (numpy scalars and arrays, tuples inside lists)."""
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    return v


def flatten(record: dict) -> dict:
    """A nested record as one flat row: nested keys joined by dots, lists kept as lists (numpy
    values and tuples become plain numbers and lists, as in JSON)."""
    out: dict[str, Any] = {}

    def walk(d: dict, prefix: str) -> None:
        for k, v in d.items():
            if not isinstance(k, str) or not k or SEP in k:
                raise GalileoError(f"cannot flatten a record with the key {k!r} (keys must be text without {SEP!r})")
            if isinstance(v, dict) and v:
                walk(v, prefix + k + SEP)
            else:
                out[prefix + k] = _plain(v)

    walk(record, "")
    return out


def _missing(v: Any) -> bool:
    return v is None or (isinstance(v, float) and math.isnan(v))


def unflatten(row: dict) -> dict:
    """The nested record of a flat row (None and NaN cells dropped)."""
    out: dict[str, Any] = {}
    for name, v in row.items():
        if _missing(v):
            continue
        *parents, leaf = name.split(SEP)
        d = out
        for p in parents:
            d = d.setdefault(p, {})
            if not isinstance(d, dict):
                raise GalileoError(f"column {name!r} nests under a value that is not a record")
        if leaf in d:
            raise GalileoError(f"column {name!r} clashes with another column")
        d[leaf] = v
    return out


def _rows(records: Iterable[dict]) -> tuple[list[str], list[dict]]:
    """(column names: video first, then in order of appearance; flat rows sorted by video)."""
    recs = list(records)
    for i, r in enumerate(recs):
        if not isinstance(r, dict) or not isinstance(r.get("video"), str):
            raise GalileoError(f"record {i} has no video name")
    rows = [flatten(r) for r in sorted(recs, key=lambda r: r["video"])]
    columns = {"video": None}
    for row in rows:
        columns.update(dict.fromkeys(row))
    return list(columns), rows


# -- parquet ----------------------------------------------------------------------------------------------

def _has_struct(t) -> bool:
    import pyarrow as pa

    return pa.types.is_struct(t) or (pa.types.is_list(t) and _has_struct(t.value_type))


def _arrow_column(values: list):
    """(an arrow array of the values, whether it holds them as JSON text): JSON text where
    arrow would not keep them exactly (mixed types, records inside lists, empty records)."""
    import pyarrow as pa

    try:
        arr = pa.array(values)
        if not _has_struct(arr.type):
            return arr, False
    except (pa.ArrowInvalid, pa.ArrowTypeError, OverflowError):
        pass
    return pa.array([None if v is None else json.dumps(v) for v in values], pa.string()), True


def _parquet_bytes(columns: list[str], rows: list[dict]) -> bytes:
    import pyarrow as pa
    import pyarrow.parquet as pq

    arrays, as_json = [], []
    for c in columns:
        arr, is_json = _arrow_column([row.get(c) for row in rows])
        arrays.append(arr)
        if is_json:
            as_json.append(c)
    table = pa.table(arrays, names=columns).replace_schema_metadata({JSON_COLUMNS_KEY: json.dumps(as_json)})
    buf = pa.BufferOutputStream()
    pq.write_table(table, buf)
    return buf.getvalue().to_pybytes()


def _read_parquet(path: Path) -> list[dict]:
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        table = pq.read_table(path)
    except (pa.ArrowException, OSError) as e:
        raise GalileoError(f"cannot read the results table {path}: {' '.join(str(e).split())}") from None
    if "video" not in table.column_names:
        raise GalileoError(f"{path} is not a results table (no video column)")
    as_json = set(json.loads((table.schema.metadata or {}).get(JSON_COLUMNS_KEY, b"[]")))
    rows = table.to_pylist()
    for row in rows:
        for c in as_json:
            if row.get(c) is not None:
                row[c] = json.loads(row[c])
    return rows


# -- csv --------------------------------------------------------------------------------------------------

_INT = re.compile(r"[+-]?\d+")


def _csv_cell(v: Any) -> str:
    if _missing(v):
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, (list, dict)):
        return json.dumps(v)
    return str(v)


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return cell.strip().lower() not in ("nan", "+nan", "-nan")


def _is_json(cell: str) -> bool:
    if cell[:1] not in ("[", "{"):
        return False
    try:
        json.loads(cell)
    except ValueError:
        return False
    return True


def _csv_column(cells: list[str]) -> list:
    """A column's cells with their types back: booleans, numbers (int where written as one),
    lists and records (JSON), or text, judged on the whole column."""
    full = [c for c in cells if c != ""]
    if full and all(c in ("true", "false") for c in full):
        return [None if c == "" else c == "true" for c in cells]
    if full and all(_is_number(c) for c in full):
        return [None if c == "" else int(c) if _INT.fullmatch(c) else float(c) for c in cells]
    if full and all(_is_json(c) for c in full):
        return [None if c == "" else json.loads(c) for c in cells]
    return [None if c == "" else c for c in cells]


def _csv_bytes(columns: list[str], rows: list[dict]) -> bytes:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for row in rows:
        w.writerow([_csv_cell(row.get(c)) for c in columns])
    return buf.getvalue().encode()


def _read_csv(path: Path) -> list[dict]:
    try:
        with open(path, newline="", encoding="utf-8") as f:
            table = list(csv.reader(f))
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise GalileoError(f"cannot read the results table {path}: {e}") from None
    if not table or "video" not in table[0]:
        raise GalileoError(f"{path} is not a results table (no video column)")
    header, body = table[0], table[1:]
    if any(len(line) != len(header) for line in body):
        raise GalileoError(f"{path} is not a results table (rows of different lengths)")
    columns = {name: _csv_column([line[j] for line in body]) for j, name in enumerate(header)}
    return [{name: cells[i] for name, cells in columns.items()} for i in range(len(body))]


# -- the table's files -----------------------------------------------------------------------------------

def write_table(records: Iterable[dict], out_dir: str | Path) -> tuple[Path, Path]:
    """results.parquet and results.csv (lists and records as JSON text) in `out_dir`, one row
    per video sorted by name, each written atomically; their paths."""
    out_dir = Path(out_dir)
    columns, rows = _rows(records)
    pq_path, csv_path = out_dir / f"{TABLE_STEM}.parquet", out_dir / f"{TABLE_STEM}.csv"
    atomic_write_bytes(pq_path, _parquet_bytes(columns, rows))
    atomic_write_bytes(csv_path, _csv_bytes(columns, rows))
    return pq_path, csv_path


def read_table(path: str | Path) -> list[dict]:
    """The nested records of results.parquet, results.csv, or a folder with either (parquet
    first). Parquet keeps every type; CSV judges a column's type on all its cells (a text
    column whose every cell reads as a number or true/false comes back as such, and numbers in
    a column that also holds text come back as text)."""
    path = Path(path)
    if path.is_dir():
        found = [p for p in (path / f"{TABLE_STEM}.parquet", path / f"{TABLE_STEM}.csv") if p.is_file()]
        if not found:
            raise GalileoError(f"no {TABLE_STEM}.parquet or {TABLE_STEM}.csv in {path}")
        path = found[0]
    if not path.is_file():
        raise GalileoError(f"results table not found: {path}")
    readers = {".parquet": _read_parquet, ".csv": _read_csv}
    if path.suffix.lower() not in readers:
        raise GalileoError(f"{path}: a results table is a .parquet or .csv file")
    return [unflatten(row) for row in readers[path.suffix.lower()](path)]


# -- helpers for the sections (also the scenarios') --------------------------------------------------------

def status_of(record: dict) -> str:
    """fitted, skipped or failed (records older than the `status` field: from what they hold)."""
    if record.get("status") in STATUSES:
        return record["status"]
    if "error" in record:
        return "failed"
    return "fitted" if "map" in record else "skipped"


def fitted(records: Iterable[dict]) -> list[dict]:
    return [r for r in records if status_of(r) == "fitted"]


def get(record: dict, dotted: str) -> Any:
    """A nested value by its column name (None where any part is missing)."""
    v: Any = record
    for part in dotted.split(SEP):
        if not isinstance(v, dict):
            return None
        v = v.get(part)
    return v


def finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def fmt(v: Any, digits: int = 3) -> str:
    """A number for report.md: `digits` significant digits; n/a for None and NaN."""
    if v is None or isinstance(v, bool):
        return NA if v is None else ("yes" if v else "no")
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return NA
        return ("inf" if v > 0 else "-inf") if math.isinf(v) else f"{v:.{digits}g}"
    return str(v)


def share(k: int, n: int) -> dict:
    """k of n as a share with its Clopper-Pearson 95% interval (None without data)."""
    from .calibrate import coverage_summary

    s = coverage_summary([True] * k + [False] * (n - k))
    return {"k": k, "n": n, "share": s["coverage"], "ci95": s["ci95"]}


def fmt_share(s: dict) -> str:
    """"k/n = share [lo, hi]" (n/a without data)."""
    if not s["n"]:
        return f"0/0 = {NA}"
    return f"{s['k']}/{s['n']} = {s['share']:.2f} [{s['ci95'][0]:.2f}, {s['ci95'][1]:.2f}]"


def correlation(x, y) -> dict:
    """Pearson r and Spearman rho of two samples (None with fewer than 3 points or a constant side)."""
    from scipy.stats import pearsonr, spearmanr

    x, y = np.asarray(x, float), np.asarray(y, float)
    out = {"n": int(len(x)), "pearson_r": None, "spearman_rho": None}
    if len(x) < 3 or np.ptp(x) == 0 or np.ptp(y) == 0:
        return out
    out["pearson_r"] = float(pearsonr(x, y).statistic)
    out["spearman_rho"] = float(spearmanr(x, y).statistic)
    return out


def _cell(v: Any) -> str:
    text = fmt(v) if not isinstance(v, str) else v
    return " ".join(text.split()).replace("|", "\\|")


def md_table(header: list[str], rows: list[list]) -> str:
    """A markdown table (numbers through `fmt`)."""
    lines = ["| " + " | ".join(_cell(h) for h in header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def no_data(title: str, paper: str, why: str) -> Section:
    return Section(title, paper, None, f"No data: {why}.")


def new_figure(ncols: int = 1, size_in: tuple[float, float] = FIG_SIZE_IN, width_ratios: list[float] | None = None):
    """(figure, axes) without pyplot (no display, no global state); `width_ratios` for axes of
    different widths (e.g. a figure beside a narrow panel of the paper's numbers)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=size_in)
    return fig, fig.subplots(1, ncols, gridspec_kw={"width_ratios": width_ratios} if width_ratios else None)


def _log_subs(vmin: float, vmax: float) -> tuple[float, ...]:
    """Which multiples of each decade carry a labelled tick: fewer as the axis spans more
    decades, so that labels never run into each other (0.6, 0.7, 0.8, 0.9 and 1 crowd the top
    of a decade)."""
    decades = abs(math.log10(vmax / vmin)) if vmin > 0 and vmax > 0 else math.inf
    return (1.0, 2.0, 3.0, 5.0) if decades <= 1.2 else (1.0, 2.0, 5.0) if decades <= 3.5 else (1.0,)


def _plain_log_locator():
    """A log axis's major ticks at 1, 2, 5 x 10^n or fewer (`_log_subs`; matplotlib's LogLocator
    falls back to evenly spaced ticks where a narrow axis holds at most one)."""
    from matplotlib.ticker import LogLocator

    class PlainLogLocator(LogLocator):
        def tick_values(self, vmin, vmax):
            self._subs = np.array(_log_subs(vmin, vmax))
            return super().tick_values(vmin, vmax)

    return PlainLogLocator(base=10.0, subs=(1.0,))


def plain_log_axes(ax, which: str = "xy") -> None:
    """Log scale on `which` axes, ticks written as plain numbers (0.5, 1, 2, not 5x10^-1): labels
    on the major ticks only (`_log_subs` picks them by the axis's span), minor ticks unlabelled."""
    from matplotlib.ticker import FuncFormatter, NullFormatter

    plain = FuncFormatter(lambda v, _: f"{v:g}")
    for name in which:
        axis = ax.xaxis if name == "x" else ax.yaxis
        (ax.set_xscale if name == "x" else ax.set_yscale)("log")
        axis.set_major_locator(_plain_log_locator())
        axis.set_major_formatter(plain)
        axis.set_minor_formatter(NullFormatter())


PAPER_COLOR = "tab:purple"


def paper_bars(ax, items: list[tuple[str, float | None, float | None, str | None]], ylabel: str,
               title: str = "against the paper") -> None:
    """A narrow panel setting our numbers beside the paper's: per item (name, ours, the paper's
    value, how the paper states it), a bar at ours (its value written above it, n/a without
    one) and a dashed line at the paper's labelled "paper: <statement>" (the line's label too),
    over its bar, or across the panel where every item shares one paper value."""
    names = [it[0] for it in items]
    ours = np.array([it[1] if finite(it[1]) else np.nan for it in items], float)
    x = np.arange(len(items))
    ax.bar(x, np.nan_to_num(ours), 0.6, color="tab:blue", alpha=0.8, label="ours")
    for j, v in enumerate(ours):
        ax.text(j, (v if math.isfinite(v) else 0.0) + 0.03, fmt(v, 2) if math.isfinite(v) else NA, ha="center",
                va="bottom", fontsize=8)
    refs = [(j, it[2], it[3] if it[3] is not None else fmt(it[2], 2)) for j, it in enumerate(items) if finite(it[2])]
    box = {"facecolor": "white", "edgecolor": "none", "alpha": 0.85, "pad": 1.0}
    if len(refs) == len(items) and len({(v, s) for _, v, s in refs}) == 1:
        _, v, text = refs[0]
        ax.axhline(v, color=PAPER_COLOR, ls="--", lw=1.5, label=f"paper: {text}")
        ax.text(-0.45, v + 0.015, f"paper: {text}", color=PAPER_COLOR, fontsize=8, ha="left", va="bottom", bbox=box)
    else:
        for j, v, text in refs:
            ax.plot([j - 0.45, j + 0.45], [v, v], color=PAPER_COLOR, ls="--", lw=1.5, label=f"paper: {text}")
            ax.text(j, v + 0.015, f"paper: {text}", color=PAPER_COLOR, fontsize=7.5, ha="center", va="bottom",
                    bbox=box)
    low = min([0.0, *(v for v in ours if math.isfinite(v)), *(v for _, v, _ in refs)])
    ax.set_ylim(low - 0.05 if low < 0 else 0.0, 1.12)
    ax.axhline(0, color="0.6", lw=0.6)
    ax.set_xticks(x, names, fontsize=8)
    ax.set_xlim(-0.5, len(items) - 0.5)
    ax.set(ylabel=ylabel, title=title)


def diagonal(ax, label: str) -> None:
    """The line y = x across the axes' current range (inferred = true)."""
    lo = min(ax.get_xlim()[0], ax.get_ylim()[0])
    hi = max(ax.get_xlim()[1], ax.get_ylim()[1])
    ax.plot([lo, hi], [lo, hi], color="0.5", lw=1, ls="--", label=label)


def interval_points(ax, x, low, mid, high, label: str, **style) -> None:
    """Points at `mid` with bars from `low` to `high` (e.g. a posterior median and its interval)."""
    low, mid, high = (np.asarray(v, float) for v in (low, mid, high))
    ax.errorbar(x, mid, yerr=[np.maximum(mid - low, 0), np.maximum(high - mid, 0)], ms=4, capsize=2, alpha=0.7,
                label=label, **({"fmt": "o"} | style))


def save_figure(fig, path: Path) -> str:
    """Write the figure as PNG, atomically; its file name."""
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=FIG_DPI)
    atomic_write_bytes(path, buf.getvalue())
    return Path(path).name


# -- the generic sections ---------------------------------------------------------------------------------

def _latent_order(dicts: Iterable[dict]) -> list[str]:
    return list(dict.fromkeys(k for d in dicts for k in d))


def convergence_section(records: list[dict], fig_dir: Path) -> Section:
    """R-hat of every latent per fitted video, and the share the runner judged converged."""
    title = "Convergence"
    paper = "none: the paper reports no convergence diagnostics (it runs brief MCMC chains)."
    fit = fitted(records)
    # a latent without an R-hat (too short a run) is left out, as the table (which keeps no None) leaves it
    rhats = [d for d in ({k: v for k, v in r["r_hat"].items() if finite(v)}
                         for r in fit if isinstance(r.get("r_hat"), dict)) if d]
    verdicts = [bool(r["converged"]) for r in fit if "converged" in r]
    conv = share(sum(verdicts), len(verdicts))
    if not rhats:
        return Section(title, paper, None, f"No data: no fitted video carries R-hat. Converged: {fmt_share(conv)}.",
                       {"converged": conv})
    latents = _latent_order(rhats)
    ess = [r["ess_bulk"] for r in fit if isinstance(r.get("ess_bulk"), dict)]
    rows, per = [], {}
    for name in latents:
        vals = [d[name] for d in rhats if name in d]
        ok = [v for v in vals if finite(v)]
        e = [d[name] for d in ess if finite(d.get(name))]
        per[name] = {"videos": len(vals), "median": float(np.median(ok)) if ok else None,
                     "max": float(np.max(ok)) if ok else None,
                     "below": share(sum(v < RHAT_MAX for v in ok), len(vals)),
                     "median_ess_bulk": float(np.median(e)) if e else None}
        rows.append([name, len(vals), per[name]["median"], per[name]["max"], fmt_share(per[name]["below"]),
                     per[name]["median_ess_bulk"]])
    fig, ax = new_figure()
    rng = np.random.default_rng(0)
    for j, name in enumerate(latents):
        ok = np.array([d[name] for d in rhats if finite(d.get(name))], float)
        ax.plot(j + rng.uniform(-0.15, 0.15, len(ok)), ok, "o", ms=4, alpha=0.6, color="tab:blue",
                label="one video" if j == 0 else None)
    ax.axhline(RHAT_MAX, color="tab:red", ls="--", label=f"R-hat = {RHAT_MAX}")
    ax.set_xticks(range(len(latents)), latents)
    if all(v > 0 for d in rhats for v in d.values() if finite(v)):
        plain_log_axes(ax, "y")
    ax.set(xlabel="latent", ylabel="split R-hat (dimensionless)", title="R-hat per latent, one point per video")
    ax.legend(fontsize=8)
    png = save_figure(fig, fig_dir / "convergence.png")
    body = "\n\n".join([
        md_table(["latent", "videos", "median R-hat", "max R-hat", f"share below {RHAT_MAX} [95% CI]",
                  "median bulk ESS"], rows),
        f"Videos the runner judged converged (their `converged` field, the scenario's rule): {fmt_share(conv)}.",
        f"Each point is one fitted video's R-hat for that latent; points above the dashed line at {RHAT_MAX} "
        "come from chains that disagree, and their intervals below are less trustworthy."])
    return Section(title, paper, png, body, {"converged": conv, "latents": per})


def not_identified(record: dict) -> dict:
    """{quantity: why} a fitted video does not identify (its result.json's "not_identified",
    which the record carries; empty for a record without it)."""
    gone = record.get("not_identified")
    return gone if isinstance(gone, dict) else {}


def coverage(records: list[dict], interval: tuple[str, str] = INTERVAL, identified: bool | None = True) -> dict:
    """Per latent (or derived quantity: `posterior_derived`) with both a truth and a posterior
    interval: the share of fitted videos whose interval [lo, hi] (closed) holds the truth, with
    its Clopper-Pearson 95% interval. Counted over the videos that identify the quantity
    (`identified` True: not in the record's `not_identified`), those that do not (False), or all
    (None): where a video does not identify a quantity, its interval is the prior's and its
    coverage says nothing about calibration."""
    lo, hi = interval
    out: dict[str, list] = {}
    for r in fitted(records):
        truth = r.get("truth")
        post = {**(r.get("posterior") or {}), **(r.get("posterior_derived") or {})}
        if not isinstance(truth, dict):
            continue
        gone = not_identified(r)
        for name, q in post.items():
            if identified is not None and (name not in gone) != identified:
                continue
            if isinstance(q, dict) and finite(q.get(lo)) and finite(q.get(hi)) and finite(truth.get(name)):
                out.setdefault(name, []).append(q[lo] <= truth[name] <= q[hi])
    return {name: share(sum(v), len(v)) for name, v in out.items()}


NOT_IDENTIFIED = "not identified"
GREY = "0.6"


def _why_not_identified(records: list[dict], name: str) -> str:
    """The commonest reason the fitted videos give for not identifying `name`."""
    whys: dict[str, int] = {}
    for r in fitted(records):
        why = not_identified(r).get(name)
        if isinstance(why, str):
            whys[why] = whys.get(why, 0) + 1
    return max(whys, key=whys.get) if whys else NA


def coverage_section(records: list[dict], fig_dir: Path) -> Section:
    title = "Interval coverage"
    paper = "none: the paper reports point estimates only."
    cov90, cov50 = coverage(records, INTERVAL), coverage(records, INNER_INTERVAL)
    # the videos that do not identify a quantity: their intervals are the prior's (apart, and greyed)
    gone90, gone50 = coverage(records, INTERVAL, False), coverage(records, INNER_INTERVAL, False)
    if not cov90 and not gone90:
        return no_data(title, paper, "no fitted video has both a truth and a posterior interval of a latent")
    names = list(cov90) + [n for n in gone90 if n not in cov90]     # identified somewhere first, then never
    fig, ax = new_figure(size_in=(6.4, 5.0))
    x = np.arange(len(names))
    for offset, cov, gone, level, color, grey in ((-0.1, cov90, gone90, INTERVAL_LEVEL, "tab:blue", "0.45"),
                                                  (0.1, cov50, gone50, INNER_LEVEL, "tab:orange", "0.7")):
        for data, c, label in ((cov, color, f"{level:.0%} interval holds the truth (95% CI)"),
                               ({n: v for n, v in gone.items() if n not in cov90}, grey,
                                f"{level:.0%} interval, {NOT_IDENTIFIED}: the prior's (95% CI)")):
            have = [j for j, n in enumerate(names) if n in data]
            if not have:
                continue
            s = [data[names[j]] for j in have]
            y = np.array([v["share"] for v in s])
            err = np.array([[v["share"] - v["ci95"][0] for v in s], [v["ci95"][1] - v["share"] for v in s]])
            ax.errorbar(x[have] + offset, y, yerr=err, fmt="o", color=c, capsize=3,
                        mfc=c if c == color else "none", label=label)   # hollow: the prior's
        ax.axhline(level, color=color, ls="--", lw=1, label=f"nominal {level:.0%}")
    never = [n for n in names if n not in cov90]
    ax.set_xticks(x, [f"{n}\n({NOT_IDENTIFIED})" if n in never else n for n in names])
    for n, tick in zip(names, ax.get_xticklabels()):
        if n in never:
            tick.set_color(GREY)
    if never:
        ax.axvspan(len(names) - len(never) - 0.5, len(names) - 0.5, color="0.93", zorder=0)
    ax.set_xlim(-0.5, len(names) - 0.5)
    ax.set_ylim(-0.02, 1.02)
    ax.set(xlabel="latent", ylabel="share of fitted videos", title="Posterior interval coverage")
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2)
    png = save_figure(fig, fig_dir / "coverage.png")

    def cell(cov: dict, n: str) -> str:
        return fmt_share(cov[n]) if n in cov else NA

    rows = [[n, cov90[n]["n"] if n in cov90 else 0, cell(cov90, n), cell(cov50, n),
             gone90[n]["n"] if n in gone90 else 0] for n in names]
    grouped: dict[str, list[str]] = {}
    for n in names:
        if n in gone90:
            grouped.setdefault(_why_not_identified(records, n), []).append(f"**{n}** ({gone90[n]['n']} videos)")
    whys = [f"- {', '.join(ns)}, {NOT_IDENTIFIED}: {why}" for why, ns in grouped.items()]
    body = "\n\n".join(x for x in [
        md_table(["latent", "videos identifying it",
                  f"{INTERVAL_LEVEL:.0%} interval ({INTERVAL[0]}-{INTERVAL[1]}) holds truth [95% CI]",
                  f"{INNER_LEVEL:.0%} interval ({INNER_INTERVAL[0]}-{INNER_INTERVAL[1]}) holds truth [95% CI]",
                  f"videos where {NOT_IDENTIFIED}"], rows),
        f"A calibrated posterior holds the truth in {INTERVAL_LEVEL:.0%} of videos with its {INTERVAL_LEVEL:.0%} "
        "interval: a share whose 95% CI lies below the dashed line means overconfident intervals, above it too "
        "wide ones. Coverage is counted over the videos that identify the quantity (a record's `not_identified`, "
        "from its result.json). A quantity the videos do not identify has intervals the prior sets, and their "
        f"coverage says nothing about calibration: such a quantity is drawn in grey at the right, labelled "
        f"\"{NOT_IDENTIFIED}\". On the ramp, velocities fix the mass ratio (log_mass_ratio, scored on collision "
        "videos), never the masses themselves.",
        "\n".join(whys) if whys else ""] if x)
    numbers = {"coverage_90": cov90, "coverage_50": cov50, "not_identified_90": gone90, "not_identified": never}
    return Section(title, paper, png, body, numbers)


def timing_section(records: list[dict], fig_dir: Path) -> Section:
    """Time per video and the workers' memory in the order their videos finished: workers named
    "worker 1", "worker 2", ... in the order of their first finished video (the table gives each
    one's address and pid), memory on an axis from 0 MiB, so that a few MiB of drift look as
    small as they are beside what a worker holds."""
    title = "Time and memory"
    paper = "none: the paper gives no timings."
    total = [get(r, "timing.total_s") for r in records]
    total = [t for t in total if finite(t)]
    by_process: dict[str, list[dict]] = {}
    for i, r in enumerate(records):
        w = r.get("worker")
        if isinstance(w, dict) and finite(w.get("rss_mb")):
            by_process.setdefault(f"{w.get('address', '?')} pid {w.get('pid', '?')}", []).append({**w, "_i": i})
    if not total and not by_process:
        return no_data(title, paper, "no record carries timing.total_s or worker.rss_mb")
    timed = all(finite(w.get("finished_unix_s")) for ws in by_process.values() for w in ws)
    for ws in by_process.values():
        ws.sort(key=lambda w: w["finished_unix_s"] if timed else w["_i"])
    first = sorted(by_process, key=lambda k: (by_process[k][0]["finished_unix_s"] if timed else by_process[k][0]["_i"], k))
    names = {k: f"worker {j}" for j, k in enumerate(first, 1)}
    workers = {names[k]: by_process[k] for k in first}
    growth = {k: ws[-1]["rss_mb"] - ws[0]["rss_mb"] for k, ws in workers.items()}
    fig, (ax_t, ax_m) = new_figure(2, (11.0, 4.4))
    if total:
        ax_t.hist(total, bins=min(30, max(5, len(total) // 3)), color="tab:blue")
    ax_t.set(xlabel="total time per video (s)", ylabel="videos", title="Time per video")
    ax_t.yaxis.get_major_locator().set_params(integer=True)
    for k, ws in workers.items():
        ax_m.plot(range(1, len(ws) + 1), [w["rss_mb"] for w in ws], "o-", ms=3, label=k)
    ax_m.xaxis.get_major_locator().set_params(integer=True)
    top = max((w["rss_mb"] for ws in workers.values() for w in ws), default=0.0)
    ax_m.set_ylim(0, max(top * 1.1, 1.0))    # from 0: drift is read against what the worker holds
    order = "completion order" if timed else "record order (no worker.finished_unix_s in the records)"
    ax_m.set(xlabel=f"video on this worker, in {order}", ylabel="worker resident memory (MiB)",
             title="Worker memory after each video")
    if workers and len(workers) <= 12:
        ax_m.legend(fontsize=7, loc="lower right")
    png = save_figure(fig, fig_dir / "timing.png")
    numbers = {"videos_timed": len(total), "total_s_median": float(np.median(total)) if total else None,
               "total_s_max": float(np.max(total)) if total else None, "total_s_sum": float(np.sum(total)),
               "workers": len(workers), "rss_growth_mb": growth,
               "worker_processes": {names[k]: k for k in first}}
    rows = [[k, numbers["worker_processes"][k], len(ws), ws[0]["rss_mb"], ws[-1]["rss_mb"],
             max(w["rss_mb"] for w in ws), growth[k]] for k, ws in workers.items()]
    body = "\n\n".join([
        md_table(["videos timed", "median total (s)", "max total (s)", "sum of totals (s)"],
                 [[len(total), numbers["total_s_median"], numbers["total_s_max"], numbers["total_s_sum"]]]),
        md_table(["worker", "process", "videos", "first RSS (MiB)", "last RSS (MiB)", "max RSS (MiB)",
                  "last - first (MiB)"], rows) if rows else "No worker memory in the records.",
        f"Left: how long a video took, tracking and inference together. Right: each worker's resident memory "
        f"after each of its videos, in {order}, on an axis from 0 MiB; a flat line means no leak, a steady climb "
        "means one. Workers are numbered in the order their first video finished."])
    return Section(title, paper, png, body, numbers)


# -- report.md --------------------------------------------------------------------------------------------

def _scenario(records: list[dict], meta: dict) -> str | None:
    if meta.get("scenario"):
        return meta["scenario"]
    names = {r["scenario"] for r in records if isinstance(r.get("scenario"), str)}
    if len(names) > 1:
        raise GalileoError(f"the records are of several scenarios ({', '.join(sorted(names))}); report one at a time")
    return names.pop() if names else None


def _header(records: list[dict], meta: dict, scenario: str | None) -> str:
    lines = [f"# Experiments report: {scenario or 'unknown scenario'}", ""]
    for k, v in meta.items():
        text = json.dumps(v, sort_keys=True) if isinstance(v, (dict, list)) else fmt(v)
        lines.append(f"- **{k}**: `{text}`" if isinstance(v, (dict, list)) else f"- **{k}**: {text}")
    counts = {s: sum(status_of(r) == s for r in records) for s in STATUSES}
    lines += ["", md_table(["videos", *STATUSES], [[len(records), *counts.values()]]), ""]
    reasons: dict[str, int] = {}
    for r in records:
        if status_of(r) == "skipped":
            reason = r.get("skip_reason") or "no reason given"
            reasons[reason] = reasons.get(reason, 0) + 1
    if reasons:
        lines += ["Skipped videos:", "", md_table(["reason", "videos"], [[k, v] for k, v in reasons.items()]), ""]
    failed = [[r.get("video", "?"), r.get("error") or "no error given"] for r in records if status_of(r) == "failed"]
    if failed:
        lines += ["Failed videos:", "", md_table(["video", "error"], sorted(failed)), ""]
    return "\n".join(lines)


def _render(i: int, s: Section) -> str:
    parts = [f"## {i}. {s.title}", "", f"**The paper:** {s.paper}", ""]
    if s.png:
        parts += [f"![{s.title}]({FIG_DIR}/{s.png})", ""]
    parts += [s.body, ""]
    return "\n".join(parts)


def recognition_section(eval_dir: str | Path, fig_dir: Path) -> Section:
    """The recognition model's evaluation (`galileo recognize eval --out EVAL_DIR`: its
    table.md and figures) as a section of the report; its PNGs are copied into figures/."""
    import shutil

    eval_dir = Path(eval_dir)
    table = eval_dir / "table.md"
    if not table.is_file():
        raise GalileoError(f"{eval_dir} holds no table.md: give the --out folder of `galileo recognize eval`")
    lines = table.read_text().splitlines()
    body = "\n".join(lines[1:] if lines and lines[0].startswith("# ") else lines).strip()
    pngs = []
    for png in sorted(eval_dir.glob("*.png")):
        name = f"recognition_{png.name}"
        shutil.copyfile(png, fig_dir / name)
        pngs.append(name)
    images = "\n\n".join(f"![{name}]({FIG_DIR}/{name})" for name in pngs[1:])
    return Section("Recognition from one frame", "Fig. 3 (mass MSE 0.052 and Pearson 0.44 with Galileo's labels, "
                   "oracle 0.042 / 0.71, uniform 0.081) and Fig. 4 (chains started by the network reach the MAP sooner)",
                   pngs[0] if pngs else None, "\n\n".join(x for x in (body, images) if x))


def build_report(records: Iterable[dict], out_dir: str | Path, meta: dict | None = None,
                 recognition: str | Path | None = None) -> Path:
    """report.md and figures/*.png in `out_dir` (see the module), with the recognition model's
    evaluation folder (`recognition`) as a section when given; report.md's path."""
    from . import registry

    records, meta = list(records), dict(meta or {})
    out_dir = Path(out_dir)
    fig_dir = out_dir / FIG_DIR
    fig_dir.mkdir(parents=True, exist_ok=True)
    scenario = _scenario(records, meta)
    sections: list[Section] = []
    if scenario is not None:
        exp = registry.get(scenario).experiments
        if exp is not None and exp.sections is not None:
            sections += exp.sections(records, fig_dir)
    if recognition is not None:
        sections.append(recognition_section(recognition, fig_dir))
    sections += [convergence_section(records, fig_dir), coverage_section(records, fig_dir),
                 timing_section(records, fig_dir)]
    text = "\n".join([_header(records, meta, scenario), *(_render(i, s) for i, s in enumerate(sections, 1))])
    path = out_dir / REPORT_NAME
    atomic_write_bytes(path, text.encode())
    return path
