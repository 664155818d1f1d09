"""Dataset-scale runs on Dask: one task per video, each video's record kept as it arrives.

* **Cluster** (`open_client`): a `LocalCluster` of `workers` processes, one thread each (so
  one pybullet client per process, connected in the worker the first time it simulates), a
  running scheduler (`scheduler="tcp://host:port"`), or SLURM through dask-jobqueue
  (`slurm_cluster(settings)`, see SLURM_SETTINGS). A scheduler that cannot be reached is a
  one-line GalileoError.
* **Granularity**: "videos" (default) runs each video's chains one after another inside its
  worker (a worker under a nanny is daemonic and cannot fork a pool of its own); "chains"
  makes every chain a Dask task of its own (the video's task waits for them outside the
  worker's thread pool), which fills more workers than there are videos.
* **Store** (`RecordStore`): `out/records/<video>.json`, written atomically as each video
  finishes, with a key: a digest of the config and of the video's scene, truth and video
  files. Run again with the same command, videos whose record has the same key are not run
  again (a failed record is), so a killed run resumes and ends with the same report.
* **Failures**: a video whose work raises is recorded `"status": "failed"` with its error in
  one line, and the run goes on. A dataset video whose files are missing or unreadable is
  found before any work starts (a look at each file, no cluster needed: `missing_videos`) and
  recorded failed without being run; when no video can run, the run is refused in one line. A
  worker that dies is replaced by its nanny and its video retried once (the scheduler's
  `allowed-failures`, WORKER_RETRIES); a second death records the video as failed.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

from .progress import tqdm
from . import registry
from .errors import GalileoError
from .jsonio import read_json, write_json

WORKER_RETRIES = 1            # a video whose worker died is run once more before it is reported failed
IN_FLIGHT_PER_WORKER = 2      # videos submitted ahead per worker (memory stays bounded, progress steady)
CONNECT_TIMEOUT_S = 10        # waiting for a scheduler given by address
DASHBOARD = "127.0.0.1:8787"  # Dask's dashboard for a local cluster (another free port if taken)
GRANULARITIES = ("videos", "chains")
VIDEO_FILES = ("scene.json", "truth.json", "video.mp4")   # what each video's folder of a dataset holds
MISSING_SHOWN = 3             # videos with missing files named in the one line that reports them
META_KEYS = ("scenario", "dataset", "videos", "config", "granularity")   # report.json's description of a run
# the Dask settings of the clusters made here (a running scheduler keeps its own):
CLUSTER_CONFIG = {
    "distributed.scheduler.allowed-failures": WORKER_RETRIES,
    # a worker holds only the task it runs: when it dies, no other video is blamed
    "distributed.scheduler.worker-saturation": 1.0,
    # the statistical profiler keeps 1000 one-second profiles per worker: a worker's memory
    # then climbs for the first 17 minutes of a run (0.5 MB a video on `full`) for a
    # dashboard page nobody needs here
    "distributed.worker.profile.enabled": False,
}
# the settings a SLURM cluster is built from (`--slurm FILE.json`): documented in docs/cluster.md
SLURM_SETTINGS = {"queue": None, "account": None, "cores": 16, "memory": "32GB", "walltime": "02:00:00",
                  "jobs": 1, "job_extra_directives": [], "python": None, "local_directory": None}


# -- the dataset folder -------------------------------------------------------------------------------

def dataset_index(folder: str | Path) -> tuple[str, list[dict]]:
    """(scenario, entries) of a dataset folder's index.json (each entry with a valid name)."""
    folder = Path(folder)
    if not (folder / "index.json").is_file():
        raise GalileoError(f"{folder} is not a dataset folder (no index.json; make one with `galileo dataset`)")
    d = read_json(folder / "index.json", "dataset index")
    if not isinstance(d, dict) or not isinstance(d.get("videos"), list):
        raise GalileoError(f"{folder / 'index.json'}: expected an object with a list of videos")
    scenario = d.get("scenario", registry.DEFAULT)
    if not isinstance(scenario, str) or scenario not in registry.names():
        raise GalileoError(f"{folder / 'index.json'}: unknown scenario {scenario!r}; known: {', '.join(registry.names())}")
    entries, seen = [], set()
    for i, v in enumerate(d["videos"]):
        name = v.get("name") if isinstance(v, dict) else None
        if not isinstance(name, str) or not name or "/" in name or "\\" in name or name in (".", ".."):
            raise GalileoError(f"{folder / 'index.json'}: videos[{i}] has no valid name")
        if name in seen:
            raise GalileoError(f"{folder / 'index.json'}: video {name!r} is listed twice")
        seen.add(name)
        entries.append(v)
    if not entries:
        raise GalileoError(f"{folder / 'index.json'}: no videos")
    return scenario, entries


def unreadable(path: Path) -> str | None:
    """Why `path` cannot be read as a file ("not found", "is not a file", ...), or None."""
    if not path.exists():
        return "not found"
    if not path.is_file():
        return "is not a file"
    if not os.access(path, os.R_OK):
        return "cannot be read (no permission)"
    return None


def missing_videos(folder: str | Path, entries: list[dict]) -> dict[str, str]:
    """{video: its first missing or unreadable file, as "NAME/FILE not found"} for a dataset's
    videos (VIDEO_FILES; a look at each file, so seconds for thousands of videos: done before a
    cluster starts). GalileoError, in one line naming the first few, when no video can run."""
    folder = Path(folder)
    missing = {}
    for v in entries:
        for f in VIDEO_FILES:
            why = unreadable(folder / v["name"] / f)
            if why is not None:
                missing[v["name"]] = f"{v['name']}/{f} {why}"
                break
    if len(missing) == len(entries):
        raise GalileoError(f"{folder}: none of the {len(entries)} video{'s' if len(entries) != 1 else ''} its "
                           f"index.json lists can run: {first_few(list(missing.values()))}")
    return missing


def first_few(items: list[str]) -> str:
    """`items` in a one-line message: the first MISSING_SHOWN, and how many more."""
    more = f"; and {len(items) - MISSING_SHOWN} more" if len(items) > MISSING_SHOWN else ""
    return "; ".join(items[:MISSING_SHOWN]) + more


def digest(paths: list[Path], extra: Any = None) -> str:
    """sha256 over the files' bytes (a missing file counts as missing) and `extra` as JSON."""
    h = hashlib.sha256(json.dumps(extra, sort_keys=True, default=str).encode())
    for p in paths:
        h.update(str(p.name).encode())
        if p.is_file():
            with open(p, "rb") as f:
                for block in iter(lambda: f.read(1 << 20), b""):
                    h.update(block)
        else:
            h.update(b"<missing>")
    return h.hexdigest()[:20]


# -- the record store -----------------------------------------------------------------------------------

@dataclass
class RecordStore:
    """One JSON record per video under `folder` (written atomically; see the module)."""
    folder: Path

    def __post_init__(self):
        self.folder = Path(self.folder)
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise GalileoError(f"cannot create {self.folder}: {e.strerror or e}") from None

    def path(self, name: str) -> Path:
        return self.folder / f"{name}.json"

    def done(self, name: str, key: str) -> dict | None:
        """The kept record of `name` if it was made with `key` and did not fail."""
        p = self.path(name)
        if not p.is_file():
            return None
        try:
            rec = json.loads(p.read_text())
        except (OSError, ValueError):
            return None      # a damaged record is run again
        ok = isinstance(rec, dict) and rec.get("key") == key and rec.get("status") != "failed"
        return rec if ok else None

    def save(self, name: str, rec: dict) -> None:
        write_json(self.path(name), rec)


# -- the cluster ----------------------------------------------------------------------------------------

def slurm_cluster(settings: dict):
    """A dask-jobqueue SLURMCluster from `settings` (keys: SLURM_SETTINGS; one worker process
    of one thread per core), scaled to `jobs` jobs. Building it submits nothing: `scale` does."""
    unknown = sorted(set(settings) - set(SLURM_SETTINGS))
    if unknown:
        raise GalileoError(f"unknown SLURM setting(s) {', '.join(unknown)}; known: {', '.join(SLURM_SETTINGS)}")
    s = {**SLURM_SETTINGS, **settings}
    if not (isinstance(s["cores"], int) and s["cores"] >= 1) or not (isinstance(s["jobs"], int) and s["jobs"] >= 1):
        raise GalileoError("SLURM settings: cores and jobs must be integers >= 1")
    from dask_jobqueue import SLURMCluster

    cluster = SLURMCluster(cores=s["cores"], processes=s["cores"], memory=s["memory"], queue=s["queue"],
                           account=s["account"], walltime=s["walltime"],
                           job_extra_directives=list(s["job_extra_directives"]),
                           python=s["python"] or sys.executable, local_directory=s["local_directory"])
    return cluster, s["jobs"]


def local_cluster(workers: int | None):
    import signal
    import threading

    from distributed import LocalCluster

    n = max(1, int(workers or os.cpu_count() or 1))
    # the worker processes start with Ctrl-C ignored (an ignored signal stays ignored in a child):
    # Ctrl-C reaches the whole terminal's process group, and this process alone shuts the cluster
    # down, instead of every worker printing its own traceback
    main = threading.current_thread() is threading.main_thread()
    before = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
    try:
        return LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                            dashboard_address=DASHBOARD if _has_dashboard() else None, silence_logs=logging.ERROR)
    finally:
        if main:
            signal.signal(signal.SIGINT, before)


def _has_dashboard() -> bool:
    try:
        import bokeh  # noqa: F401 - Dask's dashboard needs it
    except ImportError:
        return False
    return True


@contextlib.contextmanager
def open_client(workers: int | None = None, scheduler: str | None = None, slurm: dict | None = None,
                log: Callable[[str], None] | None = None) -> Iterator[Any]:
    """A Dask client on a local cluster, a running scheduler or SLURM (see the module); closed
    (and a cluster it made shut down) on exit."""
    from distributed import Client

    log = log or (lambda s: None)
    if sum(x is not None for x in (scheduler, slurm)) > 1:
        raise GalileoError("give either a scheduler address or SLURM settings, not both")
    if workers is not None and (scheduler is not None or slurm is not None):
        raise GalileoError("--workers is for the local cluster; a scheduler's or SLURM's cluster has its own")
    if workers is not None and (int(workers) != workers or workers < 1):
        raise GalileoError(f"workers must be an integer >= 1, got {workers!r}")
    cluster = None
    try:
        if scheduler is not None:
            try:
                client = Client(scheduler, timeout=f"{CONNECT_TIMEOUT_S}s")
            except (OSError, TimeoutError, ValueError, TypeError) as e:
                raise GalileoError(f"cannot reach the Dask scheduler at {scheduler}: "
                                   f"{str(e).splitlines()[0] if str(e) else type(e).__name__}") from None
        else:
            import dask

            import warnings

            with dask.config.set(CLUSTER_CONFIG), warnings.catch_warnings():
                # "port 8787 in use": the dashboard's address is printed anyway
                warnings.filterwarnings("ignore", message="Port .* is already in use", category=UserWarning)
                if slurm is not None:
                    cluster, jobs = slurm_cluster(slurm)
                    cluster.scale(jobs=jobs)
                else:
                    cluster = local_cluster(workers)
            client = Client(cluster)
    except BaseException:
        if cluster is not None:
            cluster.close()
        raise
    try:
        n = len(client.scheduler_info().get("workers", {}))
        where = f"the scheduler at {scheduler}" if scheduler else ("SLURM" if slurm is not None else "a local cluster")
        board = f"; dashboard {client.dashboard_link}" if _has_dashboard() and client.dashboard_link else ""
        log(f"dask: {n} worker{'s' if n != 1 else ''} on {where}{board}")
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def n_workers(client) -> int:
    return max(1, len(client.scheduler_info().get("workers", {})))


class DaskMap:
    """The chain runner's executor slot filled by Dask from inside a task: every chain a task,
    waited for outside the worker's thread pool (so the chains can run on this worker too)."""

    def __init__(self, client):
        self.client = client
        self.workers = n_workers(client)

    def map(self, fn, iterable):
        from distributed import rejoin, secede

        futures = self.client.map(fn, list(iterable), pure=False)
        secede()
        try:
            return self.client.gather(futures)
        finally:
            rejoin()

    def shutdown(self) -> None:
        pass


def release_memory() -> None:
    """Hand freed memory back to the system after a video. glibc's malloc keeps what a video
    freed in its arenas, so a worker's resident memory crept up by ~0.7 MB a video over the
    `full` preset although nothing leaked (flat within 1 MB over 70 videos with this)."""
    import ctypes
    import gc

    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):   # not glibc: nothing to trim
        pass


def worker_memory() -> dict:
    """This process's resident and peak resident memory (MiB)."""
    import resource

    import psutil

    return {"rss_mb": psutil.Process().memory_info().rss / 2**20,
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def _one_line(e: BaseException) -> str:
    text = str(e).strip().splitlines()
    return f"{type(e).__name__}: {text[0]}" if text else type(e).__name__


# -- one task -------------------------------------------------------------------------------------------

def video_task(fn: Callable[..., dict], args: tuple, name: str, key: str, granularity: str,
               stamp: dict | None = None) -> dict:
    """Run `fn(*args, executor=...)` on a worker: its record, or a failed one with the error;
    stamped with the key, the worker and the time taken."""
    from .runner import InProcess

    t0, c0 = time.perf_counter(), time.process_time()
    try:
        if granularity == "chains":
            from distributed import get_client

            rec = fn(*args, executor=DaskMap(get_client()))
        else:
            rec = fn(*args, executor=InProcess())
    except Exception as e:  # noqa: BLE001 - a video's failure is its record; the run goes on
        rec = {"video": name, "status": "failed", "error": _one_line(e)}
    rec = {**(stamp or {}), **rec}
    release_memory()
    try:
        from distributed import get_worker

        address = get_worker().address
    except (ImportError, ValueError):
        address = "local"
    rec["key"] = key
    rec.setdefault("timing", {}).update({"total_s": time.perf_counter() - t0, "task_cpu_s": time.process_time() - c0})
    rec["worker"] = {"address": address, "pid": os.getpid(), "finished_unix_s": time.time(), **worker_memory()}
    return rec


@dataclass
class Job:
    name: str
    fn: Callable[..., dict]
    args: tuple
    key: str
    stamp: dict = field(default_factory=dict)   # fields every record of it carries (e.g. its scenario)
    error: str | None = None                    # known before it runs (a missing file): recorded failed, not run


@dataclass
class Outcome:
    records: list[dict]
    resumed: int
    wall_s: float
    workers: int

    @property
    def failed(self) -> list[str]:
        return [r["video"] for r in self.records if r.get("status") == "failed"]


def run_jobs(client, jobs: list[Job], store: RecordStore, *, granularity: str = "videos", progress: bool = True,
             desc: str = "videos") -> Outcome:
    """Every job's record: kept ones from `store`, the rest run on `client` (see the module)."""
    from distributed import as_completed
    from distributed.client import FutureCancelledError

    if granularity not in GRANULARITIES:
        raise GalileoError(f"granularity must be one of {', '.join(GRANULARITIES)}, got {granularity!r}")
    t0 = time.perf_counter()
    records: dict[str, dict] = {}
    for job in jobs:
        kept = store.done(job.name, job.key)
        if kept is not None:
            records[job.name] = kept
    resumed = len(records)
    for job in jobs:
        if job.name not in records and job.error is not None:
            records[job.name] = {**job.stamp, "video": job.name, "status": "failed", "error": job.error, "key": job.key}
            store.save(job.name, records[job.name])
    failed = len(records) - resumed
    todo = [j for j in jobs if j.name not in records]
    by_key = {}
    with tqdm(total=len(jobs), initial=len(records), desc=desc, unit="video", disable=not progress) as bar:
        if failed:
            bar.set_postfix_str(f"{failed} failed", refresh=False)
        queue = list(reversed(todo))
        running = as_completed()

        def refill():
            while queue and running.count() < IN_FLIGHT_PER_WORKER * n_workers(client):
                job = queue.pop()
                f = client.submit(video_task, job.fn, job.args, job.name, job.key, granularity, job.stamp,
                                  key=f"video-{job.key}-{job.name}", pure=False)
                by_key[f.key] = job
                running.add(f)

        refill()
        for f in running:
            job = by_key.pop(f.key)
            try:
                rec = f.result()
            except FutureCancelledError as e:
                rec = {**job.stamp, "video": job.name, "status": "failed", "error": f"cancelled: {e}", "key": job.key}
            except Exception as e:  # noqa: BLE001 - KilledWorker: the worker died running it, twice
                rec = {**job.stamp, "video": job.name, "status": "failed", "key": job.key,
                       "error": f"its worker died {WORKER_RETRIES + 1} times running it ({_one_line(e)})"}
            store.save(job.name, rec)
            records[job.name] = rec
            if rec.get("status") == "failed":
                failed += 1
                bar.set_postfix_str(f"{failed} failed", refresh=False)
            bar.update(1)
            refill()
    return Outcome([records[j.name] for j in jobs], resumed, time.perf_counter() - t0, n_workers(client))


# -- the experiments over a dataset ---------------------------------------------------------------------

def experiment_jobs(folder: Path, scenario: str, entries: list[dict], config,
                    missing: dict[str, str] | None = None) -> list[Job]:
    """One job per video; those in `missing` (`missing_videos`) carry their error, not run."""
    exp = registry.get(scenario).experiments
    if exp is None:
        raise GalileoError(f"scenario {scenario!r} has no experiments")
    fn = exp.run_video
    conf = config_json(config)
    missing = missing or {}
    jobs = []
    for v in entries:
        d = folder / v["name"]
        key = digest([d / f for f in VIDEO_FILES], {"scenario": scenario, "config": conf})
        jobs.append(Job(v["name"], fn, (d, config), key, {"scenario": scenario}, missing.get(v["name"])))
    return jobs


def out_folder(out: Path) -> None:
    """Refuse an --out that cannot be the results folder (records, tables, report)."""
    if out.exists() and not out.is_dir():
        raise GalileoError(f"--out must be a folder (it holds the records, tables and report), not a file: {out}")
    if out.suffix.lower() in (".json", ".md", ".csv", ".parquet"):
        raise GalileoError(f"--out names the results folder, not a file: {out} (e.g. --out {out.with_suffix('')})")


def config_json(cfg) -> dict:
    import dataclasses

    return {k: v for k, v in dataclasses.asdict(cfg).items() if k != "workers"}


def run_experiments(folder: str | Path, config, out: str | Path, client, *, granularity: str = "videos",
                    progress: bool = True, recognition: str | Path | None = None) -> dict:
    """The scenario's experiments over a dataset folder on `client`; writes into `out`:
    records/, report.json (the summary), results.parquet and results.csv (one row per
    video), report.md and figures/ (with the recognition evaluation folder `recognition` as a
    section). Returns report.json's content."""
    from .report import build_report, write_table

    folder, out = Path(folder), Path(out)
    scenario, entries = dataset_index(folder)
    out_folder(out)
    config.check()
    if recognition is not None and not (Path(recognition) / "table.md").is_file():
        raise GalileoError(f"{recognition} holds no table.md: give the --out folder of `galileo recognize eval`")
    missing = missing_videos(folder, entries)
    store = RecordStore(out / "records")
    jobs = experiment_jobs(folder, scenario, entries, config, missing)
    done = run_jobs(client, jobs, store, granularity=granularity, progress=progress)
    summary = registry.get(scenario).experiments.summarise(done.records)
    meta = {"scenario": scenario, "dataset": str(folder), "videos": len(entries), "config": config_json(config),
            "granularity": granularity}
    report = {**meta, "summary": summary,
              "run": {"wall_s": done.wall_s, "workers": done.workers, "resumed_videos": done.resumed,
                      "failed_videos": done.failed}}
    write_json(out / "report.json", report)
    write_table(done.records, out)
    build_report(done.records, out, meta, recognition=recognition)
    return report


# -- galileo infer over a folder of videos --------------------------------------------------------------

VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".m4v", ".webm")


def folder_videos(folder: str | Path, scene: str | Path | None) -> list[tuple[str, Path, Path]]:
    """(name, video, scene file) for a folder of videos: with `scene`, every video file in the
    folder, filmed in that one scene; without, every subfolder holding a scene.json and one
    video file (video.mp4 when there are several)."""
    folder = Path(folder)
    out = []
    if scene is not None:
        for p in sorted(folder.iterdir()):
            if p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES:
                out.append((p.stem, p, Path(scene)))
        what = f"no video files ({', '.join(VIDEO_SUFFIXES)}) in {folder}"
    else:
        for d in sorted(p for p in folder.iterdir() if p.is_dir()):
            videos = sorted(p for p in d.iterdir() if p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES)
            if (d / "scene.json").is_file() and videos:
                video = d / "video.mp4" if (d / "video.mp4").is_file() else videos[0]
                out.append((d.name, video, d / "scene.json"))
        what = (f"no subfolders of {folder} hold a scene.json and a video; give --scene SCENE for a folder of "
                "videos filmed in one scene")
    if not out:
        raise GalileoError(what)
    names = [n for n, _, _ in out]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise GalileoError(f"{folder}: two videos named {dup[0]!r} (with different suffixes); rename one")
    return out


def infer_video(video: Path, scene_path: Path, config, result_path: Path, executor=None) -> dict:
    """Track and infer one video; its result file written next to the others; the table's row."""
    from .results import warning_of
    from .runner import infer

    t0 = time.perf_counter()
    scene = registry.load_scene(scene_path)
    scenario = registry.of(scene)
    tracks = scenario.track(video, scene, progress=False)
    t1 = time.perf_counter()
    res = infer(scene, tracks, config, executor=executor, progress=False)
    res.notes = tuple(getattr(tracks, "notes", ()) or ())
    doc = res.to_json()
    res.save(result_path, doc)
    diag = doc["diagnostics"]
    return {"video": Path(result_path).name.removesuffix(".result.json"), "scenario": scenario.name,
            "status": "fitted", "source": str(video), "result_file": Path(result_path).name, "map": res.map,
            "map_loglik": res.map_loglik,
            "posterior": {k: {q: v[q] for q in ("q05", "q25", "q50", "q75", "q95")} for k, v in doc["posterior"].items()},
            "posterior_derived": {k: {q: v[q] for q in ("q05", "q50", "q95")} for k, v in doc["posterior_derived"].items()},
            "converged": bool(diag["converged"]), "why_not": list(diag["why_not"]), "warning": warning_of(diag),
            "r_hat": diag["r_hat"], "ess_bulk": diag["ess"], "sweeps": diag["sweeps"], "notes": list(res.notes),
            "timing": {"track_s": t1 - t0, "infer_s": time.perf_counter() - t1}}


def infer_folder(folder: str | Path, scene: str | Path | None, config, out: str | Path, client, *,
                 granularity: str = "videos", progress: bool = True) -> Outcome:
    """`galileo infer FOLDER`: every video's result file in `out` (<name>.result.json and its
    samples), records/ (resumable), results.parquet and results.csv."""
    from .report import write_table

    out = Path(out)
    out_folder(out)
    videos = folder_videos(folder, scene)
    config.check()
    conf = config_json(config)
    jobs = [Job(name, infer_video, (video, sp, config, out / f"{name}.result.json"),
                digest([video, sp], {"config": conf})) for name, video, sp in videos]
    done = run_jobs(client, jobs, RecordStore(out / "records"), granularity=granularity, progress=progress)
    write_table(done.records, out)
    return done
