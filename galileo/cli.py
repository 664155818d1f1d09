"""The `galileo` command line (also `python -m galileo`).

Every user error (bad file, bad value, bad flag) prints one line `galileo: error: ...` and
exits with code 2; no traceback, no usage block. Flags are read by `Parser` (one-line errors,
subcommands included) as typed, bounded values (`bounded`, `out_file`, `out_dir`, below; app.py
uses them too), so a wrong one is refused before anything slow runs or any file is written.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from .errors import GalileoError, run_reporting_errors


# -- flags: one parser class and the typed values every flag is read as (app.py's too) ---------------
#
# A value that cannot be right is refused while the command line is read, before anything slow
# (tracking, simulation, sampling) and before any file is written, in one line naming the flag.

MAX_FRAMES = 100_000        # frames one simulation writes (--frames, --duration-s x --fps, a scene's video)
MAX_FPS = 1000.0
MAX_SEED = 2**32 - 1
MAX_CHAINS = 1000
MAX_SWEEPS = 100_000        # --sweeps, --max-sweeps, --warmup, --broad-every, --recognition-move
MAX_WORKERS = 256
MAX_COUNT = 100_000         # calibrate's --n and --draws


def one_line(message) -> str:
    return " ".join(str(message).split())


class Parser(argparse.ArgumentParser):
    """argparse whose every error, its subcommands' included (argparse makes subparsers of the
    parent's class), is one line `NAME: error: ...` on stderr and exit code 2; no usage block."""
    error_name = "galileo"

    def error(self, message: str):
        message = one_line(message)
        if message.startswith("argument "):     # "argument --fps: must be ..." reads "--fps must be ..."
            flag, _, rest = message[len("argument "):].partition(": ")
            message = f"{flag} {rest}" if rest.startswith("must ") else f"{flag}: {rest}"
        self.exit(2, f"{self.error_name}: error: {message}\n")


def _number(text, integer: bool) -> float | int:
    s = str(text).strip()
    try:
        if integer:
            return int(s, 10)
        v = float(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {'an integer' if integer else 'a number'}, got {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return v


def bounded(low=None, high=None, *, integer: bool = False, low_open: bool = False, name: str = "number"):
    """An argparse `type=`: the text as an int or a finite float in [low, high] ((low, high] with
    `low_open`); argparse prefixes its one-line refusal with the flag's name."""
    def parse(text):
        v = _number(text, integer)
        if low is not None and (v < low or (low_open and v == low)):
            raise argparse.ArgumentTypeError(f"must be {'above' if low_open else 'at least'} {low:g}, got {text!r}")
        if high is not None and v > high:
            raise argparse.ArgumentTypeError(f"must be at most {high:g}, got {text!r}")
        return v
    parse.__name__ = name
    return parse


finite_float = bounded(name="finite_float")
positive_float = bounded(0.0, low_open=True, name="positive_float")
nonneg_float = bounded(0.0, name="nonneg_float")
positive_int = bounded(1, integer=True, name="positive_int")
nonneg_int = bounded(0, integer=True, name="nonneg_int")
seed_int = bounded(0, MAX_SEED, integer=True, name="seed")
chains_int = bounded(1, MAX_CHAINS, integer=True, name="chains")
sweeps_int = bounded(1, MAX_SWEEPS, integer=True, name="sweeps")
every_int = bounded(0, MAX_SWEEPS, integer=True, name="every")
workers_int = bounded(1, MAX_WORKERS, integer=True, name="workers")
count_int = bounded(1, MAX_COUNT, integer=True, name="count")
frames_int = bounded(1, MAX_FRAMES, integer=True, name="frames")
fps_float = bounded(0.0, MAX_FPS, low_open=True, name="fps")
rhat_float = bounded(1.0, 10.0, low_open=True, name="rhat")
port_int = bounded(1, 65535, integer=True, name="port")


def _type(check):
    """An argparse `type=` from a check that raises GalileoError."""
    def parse(text):
        try:
            return check(text)
        except GalileoError as e:
            raise argparse.ArgumentTypeError(str(e)) from None
    parse.__name__ = check.__name__
    return parse


def _writable_place(target: Path, folder: Path, what: str) -> None:
    """`folder`, or where it does not exist yet its nearest existing parent, takes a new file
    (probed: a temporary file made and removed there, as the atomic write will make one)."""
    import os
    import tempfile

    anc = folder
    while not anc.exists() and anc.parent != anc:
        anc = anc.parent
    if not anc.is_dir():
        raise GalileoError(f"cannot write {what} {target}: {anc} is not a folder")
    try:
        fd, tmp = tempfile.mkstemp(prefix=".galileo-probe.", suffix=".tmp", dir=anc)
        os.close(fd)
        os.unlink(tmp)
    except OSError as e:
        raise GalileoError(f"cannot write {what} {target}: {anc} takes no new file ({e.strerror or e})") from None


def check_out_file(text: str, what: str = "file") -> str:
    """`text` names a file that can be written (atomically): not empty, not a folder, in a
    place that takes a new file. Returns it unchanged."""
    import os

    if not str(text).strip():
        raise GalileoError(f"expected a {what} name, got an empty one")
    path = Path(text)
    if str(text).endswith(("/", os.sep)) or path.name in ("", ".", ".."):
        raise GalileoError(f"{text!r} names a folder; expected a {what} name")
    if path.is_dir():
        raise GalileoError(f"{text} is a folder; expected a {what} name")
    if path.exists() and not path.is_file():
        raise GalileoError(f"{text} exists and is not a regular file; expected a {what} name")
    _writable_place(path, path.parent, what)
    return str(text)


def check_out_dir(text: str, what: str = "folder") -> str:
    """`text` names a folder that exists or can be made, and takes new files."""
    if not str(text).strip():
        raise GalileoError(f"expected a {what} name, got an empty one")
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise GalileoError(f"{text} is a file; expected a {what}")
    _writable_place(path, path, what)
    return str(text)


def check_host(host: str, timeout_s: float = 10.0) -> list[tuple]:
    """The addresses `host` resolves to (getaddrinfo's, for binding), within `timeout_s`: an
    unknown name or a malformed address is a GalileoError, never a wait."""
    import socket
    import threading

    if not str(host).strip():
        raise GalileoError("--host: expected an address or a name, got an empty one")
    box: dict = {}

    def resolve():
        try:
            box["addrs"] = socket.getaddrinfo(host, None, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
        except (OSError, UnicodeError, ValueError) as e:
            box["error"] = e

    t = threading.Thread(target=resolve, daemon=True)
    t.start()
    t.join(timeout_s)
    if t.is_alive():
        raise GalileoError(f"--host {host!r}: the name did not resolve within {timeout_s:g} s")
    if "error" in box:
        e = box["error"]
        raise GalileoError(f"--host {host!r} is not an address or a known name "
                           f"({getattr(e, 'strerror', None) or e})")
    if not box.get("addrs"):
        raise GalileoError(f"--host {host!r} resolves to no address")
    return box["addrs"]


def check_nonempty(text: str) -> str:
    if not str(text).strip():
        raise GalileoError("expected a name, got an empty one")
    return str(text)


out_file = _type(check_out_file)
out_dir = _type(check_out_dir)


def check_not_an_input(args: argparse.Namespace) -> None:
    """No output flag names one of the command's input files, or another output (that would
    overwrite an input, or one output with the other)."""
    import os

    def same(a: str, b: str) -> bool:
        if os.path.realpath(a) == os.path.realpath(b):
            return True
        try:
            return os.path.samefile(a, b)
        except OSError:
            return False

    ins = [getattr(args, k, None) for k in ("video", "scene", "tracks", "result", "model", "slurm", "scenes")]
    seen = []
    for k in ("out", "debug_video"):
        out = getattr(args, k, None)
        if not isinstance(out, str) or not out:
            continue
        flag = f"--{k.replace('_', '-')}"
        for src in ins:
            if isinstance(src, str) and src and Path(src).is_file() and same(out, src):
                raise GalileoError(f"{flag} {out} is also an input of this command: refusing to overwrite it")
        for other_flag, other in seen:
            if same(out, other):
                raise GalileoError(f"{flag} and {other_flag} name the same file {out}")
        seen.append((flag, out))


def _parse_set(items: list[str]) -> dict[str, float]:
    out = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        if not sep:
            raise GalileoError(f"--set {item!r}: expected NAME=VALUE")
        try:
            v = float(value)
        except ValueError:
            raise GalileoError(f"--set {item!r}: {value!r} is not a number") from None
        if not math.isfinite(v):
            raise GalileoError(f"--set {item!r}: expected a finite number, got {value.strip()!r}")
        if not name.strip():
            raise GalileoError(f"--set {item!r}: expected NAME=VALUE")
        out[name.strip()] = v
    return out


def checked_scene(scenario, scene, what: str):
    """`scene` read back through the scenario's own loader (every field's type and range, as a
    scene file's): values set on the command line pass the checks a file would. SceneError
    becomes one line naming `what` set them."""
    import json

    from .errors import SceneError
    from .jsonio import _default

    try:
        return scenario.scene_from_json(json.loads(json.dumps(scene.to_json(), default=_default)))
    except (SceneError, ValueError) as e:
        raise GalileoError(f"{what}: {e}") from None


def frame_count(n, why: str) -> int:
    """`n` frames (a float from duration x fps, or an int), refused past MAX_FRAMES."""
    if not (n >= 1):
        raise GalileoError(f"{why}: need at least one frame")
    if not (n <= MAX_FRAMES):
        raise GalileoError(f"{why}: {n:.6g} frames; at most {MAX_FRAMES} in one simulation")
    return int(n)


def cmd_simulate(args: argparse.Namespace) -> int:
    from . import registry

    if args.scene:
        if args.scenario is not None:
            raise GalileoError("--scenario is for the scenario's default scene; a scene file names its own")
        scene = registry.load_scene(args.scene)
    else:  # the scenario's default scene, knobs from --set
        scene = registry.get(args.scenario or registry.DEFAULT).default_scene()
    scenario = registry.of(scene)
    if args.frames is not None and args.duration_s is not None:
        raise GalileoError("give --frames or --duration-s, not both")
    values = _parse_set(args.set)
    if values:
        scene = scenario.with_values(scene, values)
        scene = checked_scene(scenario, scene, f"--set {', '.join(args.set)}")
    timing = scenario.video_timing(scene)   # (fps, n_frames) of the scene's video, if it says
    fps = args.fps if args.fps is not None else (timing[0] if timing else 30.0)
    if args.frames is not None:
        n = args.frames
    elif args.duration_s is not None:
        n = frame_count(round(args.duration_s * fps) + 1, f"--duration-s {args.duration_s:g} at {fps:g} fps")
    elif timing is not None:
        n = frame_count(timing[1], f"the scene's video ({timing[1]} frames; give --frames)")
    else:
        n = int(round(2.0 * fps)) + 1
    if args.fps is not None and hasattr(scene, "sim_hz"):   # any frame rate: a whole number of steps a frame
        import dataclasses

        from .camera import physics_hz

        scene = dataclasses.replace(scene, sim_hz=physics_hz(scene.sim_hz, fps))
    check = getattr(scene, "check_simulation", None)    # (optional in a scenario's scene: ramp and splash have it)
    if check is not None:
        check(n, fps, ("--fps", "--frames"))    # sim_hz a multiple of fps; at most MAX_STEPS physics steps
    traj = scenario.simulate(scene, n, fps=fps)
    traj.save(args.out)
    print(f"wrote {n} frames of {len(traj.names)} object(s) at {fps:g} fps to {args.out}")
    return 0


def cmd_dataset(args: argparse.Namespace) -> int:
    from . import registry
    from .dataset import build

    spec = registry.get(args.scenario).dataset
    if spec is None:
        raise GalileoError(f"the {args.scenario} scenario renders no datasets; these do: "
                           f"{', '.join(registry.with_capability('dataset'))}")
    entries = build(spec, args.preset, args.out, seed=args.seed, workers=args.workers, progress=not args.quiet,
                    camera=args.camera)
    print(f"wrote {len(entries)} video(s) to {args.out} (index: {Path(args.out) / 'index.json'})")
    return 0


def cmd_track(args: argparse.Namespace) -> int:
    from . import registry

    scene = registry.load_scene(args.scene)
    tracks = registry.of(scene).track(args.video, scene, progress=not args.quiet, debug_video=args.debug_video)
    tracks.save(args.out)
    summary = ", ".join(f"{o.name} ({o.role}): {o.shape.type}, seen in {int(o.visible.sum())}/{len(o.visible)} frames"
                        for o in tracks.objects)
    print(f"wrote {args.out}: {summary}")
    for note in tracks.notes:
        print(f"note: {note}")
    if args.debug_video:
        print(f"wrote {args.debug_video}")
    return 0


def fixed_arg(items: list[str] | None) -> dict[str, float]:
    """--fix NAME=VALUE ... as {name: value} (one-line errors)."""
    out = {}
    for item in items or ():
        name, sep, text = item.partition("=")
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not sep or not name.strip() or not math.isfinite(value):
            raise GalileoError(f"--fix {item}: expected NAME=VALUE with a finite number (e.g. m1_kg=0.1103)")
        out[name.strip()] = value
    return out


def until_converged_by_default(args: argparse.Namespace) -> None:
    """galileo infer's run: until converged unless --sweeps N alone asks for a fixed run, within
    a wall-clock budget (`api.until_converged`, the API's own rule; errors name the flags)."""
    from . import api

    args.until_rhat, args.max_seconds = api.until_converged(
        args.sweeps, args.until_rhat, args.max_sweeps, args.max_seconds,
        names={"sweeps": "--sweeps", "until_rhat": "--until-rhat R", "max_sweeps": "--max-sweeps",
               "max_seconds": "--max-seconds"})


def cmd_infer(args: argparse.Namespace) -> int:
    from . import api, registry
    from .datatypes import Tracks
    from .results import warning_of

    until_converged_by_default(args)
    videos = list(args.video)
    if any(Path(v).is_dir() for v in videos):
        if len(videos) > 1:
            raise GalileoError("give one folder of videos, or video files (several: one problem over them)")
        for flag, given in (("--scene", len(args.scene or ()) > 1), ("--share", args.share), ("--fix", args.fix)):
            if given:
                raise GalileoError(f"{flag} is for one problem of video files; a folder of videos takes at most one "
                                   "--scene and no --share or --fix")
        args.video, args.scene = videos[0], (args.scene or [None])[0]
        return infer_folder(args)
    out = Path(check_out_file(args.out, "result file"))   # before tracking and sampling, which take a while
    check_out_file(str(out.with_name(out.stem + ".samples.npz")), "samples file")
    if not args.scene:
        raise GalileoError("--scene is needed for a video (a folder of videos may instead hold one scene.json per "
                           "subfolder)")
    if len(args.scene) != len(videos):
        raise GalileoError(f"{len(videos)} video(s) need {len(videos)} scene file(s) (--scene A.json B.json ...), "
                           f"got {len(args.scene)}")
    if args.tracks and len(args.tracks) != len(videos):
        raise GalileoError(f"--tracks: one tracks file per video ({len(videos)}), got {len(args.tracks)}")
    if args.scheduler or args.slurm or args.granularity:
        raise GalileoError("--scheduler, --slurm and --granularity are for a folder of videos")
    if args.share and len(videos) == 1:
        raise GalileoError("--share is for several videos (one value of a latent for all of them)")
    if args.recognition_move is not None and args.recognition_move < 1:
        raise GalileoError("--recognition-move must be at least 1 (every how many sweeps)")
    if args.recognition_move and args.init != "recognition":
        raise GalileoError("--recognition-move needs --init recognition (the move draws from the recognition model)")
    if args.model and args.init != "recognition":
        raise GalileoError("--model is for --init recognition")
    if len(videos) > 1 and args.init == "recognition":
        raise GalileoError("--init recognition reads one video: for several, chains start from the prior")
    several = len(videos) > 1
    scenes = [registry.load_scene(p) for p in args.scene]
    made = [Tracks.load(t) for t in args.tracks] if args.tracks else None
    done = api.infer(scenes if several else scenes[0], videos if several else videos[0],
                     tracks=None if made is None else made if several else made[0], share=args.share or (),
                     fix=fixed_arg(args.fix), chains=args.chains, sweeps=args.sweeps, seed=args.seed,
                     workers=args.workers, sigma=args.sigma, moves=args.moves, warmup=args.warmup,
                     until_rhat=args.until_rhat, min_ess=args.min_ess, max_sweeps=args.max_sweeps,
                     max_seconds=args.max_seconds, priors=priors_arg(args.priors), init=args.init, model=args.model,
                     recognition_move=args.recognition_move, narrow=args.narrow, broad=args.broad,
                     broad_every=args.broad_every, speedups=not args.no_speedups, progress=not args.quiet)
    result, cfg = done.inference, done.inference.config
    scenario = registry.of(result.scene)
    doc = done.doc   # diagnostics and derived posteriors, computed once
    npz = result.save(args.out, doc)
    for note in result.notes:
        print(f"note: {note}")
    gone = doc["not_identified"]
    print(f"MAP: {scenario.summary(result.scene, result.map, omit=gone) or '(nothing identified)'}")
    by_why: dict[str, list[str]] = {}
    for name, why in gone.items():
        by_why.setdefault(why, []).append(name)
    for why, names in by_why.items():
        print(f"not identified: {', '.join(names)}: {why}")
    for k, v in doc["posterior_derived"].items():
        if not k.startswith("log_"):
            print(f"posterior {k}: {v['q50']:.3g} (90%: {v['q05']:.3g}-{v['q95']:.3g})")
    diag = doc["diagnostics"]
    budget = (f": the time budget ({cfg.max_seconds:g} s) is spent" if doc["stopped"] == "max_seconds" else
              f": the sweep budget ({cfg.sweep_budget()}) is spent" if doc["stopped"] == "max_sweeps" else "")
    print(f"{'converged' if diag['converged'] else 'NOT converged'} after {diag['sweeps']} sweeps{budget} "
          f"({convergence_line(diag)}; moves {cfg.moves})")
    print(f"wrote {args.out} and {npz} ({result.timing_s['wall']:.1f} s, {result.steps} physics steps)")
    warning = warning_of(diag)
    if warning:
        print(f"galileo: warning: {warning}", file=sys.stderr)
    if doc["map_at_prior_edge"]:
        edge = ", ".join(f"{k} = {result.map[k]:.3g} (prior {lo:g}-{hi:g})" for k in doc["map_at_prior_edge"]
                         for lo, hi in [result.settings.bounds[k]])
        print(f"galileo: warning: the MAP lies at its prior's edge: {edge}; the data pull past the prior (too narrow, "
              "or something the model leaves out bends this latent): widen it with --priors or read it with care",
              file=sys.stderr)
    return 0


def infer_folder(args: argparse.Namespace) -> int:
    """galileo infer FOLDER: every video of the folder on Dask (galileo.batch.infer_folder)."""
    from . import api, batch, registry

    for flag, given in (("--tracks", args.tracks), ("--init recognition", args.init == "recognition"),
                        ("--model", args.model), ("--recognition-move", args.recognition_move)):
        if given:
            raise GalileoError(f"{flag} is for one video, not a folder of videos")
    if not args.out:
        raise GalileoError("--out FOLDER is needed for a folder of videos (one result file per video)")
    batch.out_folder(Path(args.out))
    check_out_dir(args.out, "results folder")
    videos = batch.folder_videos(args.video, args.scene)
    first = registry.load_scene(videos[0][2])
    cfg = api.run_config(registry.of(first), chains=args.chains, sweeps=args.sweeps, seed=args.seed, workers=1,
                         sigma=args.sigma, speedups=not args.no_speedups, narrow=args.narrow, broad=args.broad,
                         broad_every=args.broad_every, moves=args.moves, warmup=args.warmup,
                         until_rhat=args.until_rhat, min_ess=args.min_ess, max_sweeps=args.max_sweeps,
                         max_seconds=args.max_seconds, priors=priors_arg(args.priors))
    api.checked_settings(cfg, registry.of(first), first)
    log = (lambda m: print(m, file=sys.stderr)) if not args.quiet else None
    with batch.open_client(args.workers, args.scheduler, slurm_arg(args.slurm), log=log) as client:
        done = batch.infer_folder(args.video, args.scene, cfg, args.out, client,
                                  granularity=args.granularity or "videos", progress=not args.quiet)
    for r in done.records:
        if r.get("status") == "failed":
            print(f"{r['video']}: failed: {r['error']}")
        else:
            print(f"{r['video']}: {'converged' if r['converged'] else 'NOT converged'}; wrote {r['result_file']}")
    print(f"{len(done.records)} videos ({done.resumed} kept from an earlier run, {len(done.failed)} failed) in "
          f"{done.wall_s:.0f} s on {done.workers} workers; table: {Path(args.out) / 'results.csv'}")
    if done.failed:
        print(f"galileo: warning: {len(done.failed)} videos failed: {', '.join(done.failed[:5])}", file=sys.stderr)
    return 0


def priors_arg(text: str | None) -> dict | None:
    """--priors: a JSON object merged into the scene file's priors section."""
    import json

    if text is None:
        return None
    try:
        d = json.loads(text)
    except RecursionError:
        raise GalileoError("--priors: nested too deeply to read") from None
    except ValueError as e:
        raise GalileoError(f"--priors: not JSON: {one_line(e)[:200]}") from None
    if not isinstance(d, dict):
        raise GalileoError(f"--priors: expected a JSON object, got {one_line(text)[:200]!r}")
    return d


def convergence_line(diag: dict) -> str:
    rs = [v for v in diag["r_hat"].values() if v is not None]
    es = [v for d in (diag["ess"], diag["ess_tail"]) for v in d.values() if v is not None]
    return (f"R-hat max {max(rs):.3f}" if rs else "R-hat n/a") + (f", ESS min {min(es):.0f}" if es else "") + \
        f"; targets R-hat <= {diag['rhat_target']:g}, ESS >= {diag['min_ess']:g}"


def all_questions() -> list:
    """Every registered scenario's questions for `galileo predict`, each name once."""
    from . import registry

    seen: dict = {}
    for name in registry.names():
        for q in registry.get(name).questions:
            seen.setdefault(q.name, q)
    return list(seen.values())


def on_first_parse(parser, add) -> None:
    """`add(parser)` when `parser` (a subcommand's) first parses: the flags it adds are the
    scenarios' own, and importing the scenarios takes a second that every other command would
    pay if the parser were built with them."""
    parse = parser.parse_known_args

    def parse_known_args(args=None, namespace=None):
        del parser.parse_known_args      # (this instance attribute: the class's method again)
        add(parser)
        return parse(args, namespace)

    parser.parse_known_args = parse_known_args


# A question's flag where its own spelling (`Question.flag`, `--<name>`) would say something else
# than the same flag of another command: the ramp's yes/no question `target` reads
# `--target-outcome`, since `galileo scene --target` takes a kind of target box
# (none|cardboard|foam). The old spelling still works, with a deprecation warning.
QUESTION_FLAGS = {"target": "--target-outcome"}


def question_flag(q) -> str:
    """The flag `galileo predict` asks question `q` by."""
    return QUESTION_FLAGS.get(q.name, q.flag)


DEPRECATED = "deprecated_flags"   # the namespace attribute the old spellings used are noted in


class DeprecatedFlag(argparse.Action):
    """An old spelling of a flag, hidden from --help: it sets what the new one sets (`nargs=0`:
    the constant, a switch's True) and notes itself in the namespace's DEPRECATED dict ({dest:
    (old spelling, new)}), which `main` prints as a warning line each once the command has run
    (a refused command prints its one error line only)."""

    def __init__(self, option_strings, dest, new_flag: str, nargs=None, const=None, **kw):
        super().__init__(option_strings, dest, nargs=nargs, const=const, **kw)
        self.new_flag = new_flag

    def __call__(self, parser, namespace, values, option_string=None):
        noted = dict(getattr(namespace, DEPRECATED, None) or {})
        noted[self.dest] = (option_string, self.new_flag)
        setattr(namespace, DEPRECATED, noted)
        setattr(namespace, self.dest, self.const if self.nargs == 0 else values)


def typed_flag(args: argparse.Namespace, q) -> str:
    """The spelling of question `q`'s flag the user typed (the old one where it was that)."""
    old = (getattr(args, DEPRECATED, None) or {}).get(q.name)
    return old[0] if old else question_flag(q)


def add_questions(parser) -> None:
    """The scenarios' questions (`Scenario.questions`) as `parser`'s flags, a group per scenario
    (a renamed one's old spelling, QUESTION_FLAGS, hidden and deprecated)."""
    from . import registry

    for name in registry.names():
        qs = [q for q in registry.get(name).questions if question_flag(q) not in parser._option_string_actions]
        if not qs:
            continue
        group = parser.add_argument_group(f"questions of a {name} result (each asked only if given)")
        for q in qs:
            flag, text = question_flag(q), q.help.replace("%", "%%")
            if q.kind == "yes":
                group.add_argument(flag, dest=q.name, action="store_true", help=text)
            elif q.kind == "number":
                group.add_argument(flag, dest=q.name, type=finite_float, help=text)
            else:
                group.add_argument(flag, dest=q.name, metavar="FILE", help=text)
            if flag != q.flag and q.flag not in parser._option_string_actions:
                group.add_argument(q.flag, dest=q.name, action=DeprecatedFlag, new_flag=flag,
                                   default=argparse.SUPPRESS, help=argparse.SUPPRESS,
                                   **({"nargs": 0, "const": True} if q.kind == "yes" else
                                      {"type": finite_float} if q.kind == "number" else {}))


def cmd_predict(args: argparse.Namespace) -> int:
    import json

    from . import registry
    from .joint import is_joint_json
    from .jsonio import write_json
    from .results import read_result_json

    asked = {q.name: (q, getattr(args, q.name)) for q in all_questions()
             if getattr(args, q.name, None) not in (None, False)}
    for q, value in asked.values():   # numbers against their bounds, before the result is read
        if q.kind == "number" and q.bound is not None and not q.bound.contains(value):
            raise GalileoError(f"{typed_flag(args, q)} must be in {q.bound}, got {value:g}")
    d = read_result_json(args.result)       # a dict with a known scenario, or a one-line error
    scenario = registry.get(d.get("scenario", registry.DEFAULT))
    if is_joint_json(d.get("scene")):
        raise GalileoError(f"{args.result} is a result over several videos or with fixed latents: predict answers "
                           "for one video's result with every latent inferred")
    own = {q.name for q in scenario.questions}
    for name, (q, _) in asked.items():
        if name not in own:
            raise GalileoError(f"{typed_flag(args, q)} is no question of the {scenario.name} scenario"
                               + (f"; it answers {', '.join(question_flag(x) for x in scenario.questions)}" if own
                                  else "; it answers none"))
    if own and not asked:
        flags = ", ".join(question_flag(x) for x in scenario.questions)
        raise GalileoError(f"nothing to predict: ask at least one of {flags} (`galileo predict --help` says what each "
                           "asks)")
    out = scenario.predict(args.result, {q.name: getattr(args, q.name, None) for q in scenario.questions})
    text = json.dumps(out, indent=1)
    if args.out:
        write_json(args.out, out)
    print(text)
    if isinstance(d, dict) and d.get("converged") is False:
        print("galileo: warning: these posterior shares come from chains that have not converged "
              f"({(d.get('why_not') or ['?'])[0]}); trust the MAP answer, not the shares", file=sys.stderr)
    return 0


def cmd_experiment(args: argparse.Namespace) -> int:
    import json

    from . import api, batch, registry

    scenario, entries = batch.dataset_index(args.dataset)
    if registry.get(scenario).experiments is None:
        raise GalileoError(f"{Path(args.dataset) / 'index.json'}: no experiments for scenario {scenario!r}")
    for flag, given in (("--max-sweeps", args.max_sweeps), ("--max-seconds", args.max_seconds)):
        if given is not None and args.until_rhat is None:
            raise GalileoError(f"{flag} is a budget of --until-rhat; without it, use --sweeps")
    cfg = api.run_config(registry.get(scenario), chains=args.chains, sweeps=args.sweeps, seed=args.seed, workers=1,
                         moves=args.moves, priors=priors_arg(args.priors), until_rhat=args.until_rhat,
                         min_ess=args.min_ess, max_sweeps=args.max_sweeps, max_seconds=args.max_seconds)
    batch.out_folder(Path(args.out))      # before a cluster starts
    missing = batch.missing_videos(args.dataset, entries)    # refused here, in seconds, when no video can run
    if missing:
        print(f"galileo: warning: {len(missing)} of {len(entries)} videos lack a file and are recorded as failed "
              f"without running: {batch.first_few(list(missing.values()))}", file=sys.stderr)
    slurm = slurm_arg(args.slurm)
    log = (lambda m: print(m, file=sys.stderr)) if not args.quiet else None
    with batch.open_client(args.workers, args.scheduler, slurm, log=log) as client:
        report = batch.run_experiments(args.dataset, cfg, args.out, client, granularity=args.granularity,
                                       progress=not args.quiet, recognition=args.recognition)
    summary = {k: v for k, v in report["summary"].items() if k not in ("pairs", "failed")}
    print(json.dumps(summary, indent=1))
    run = report["run"]
    print(f"{report['videos']} videos ({run['resumed_videos']} kept from an earlier run, {len(run['failed_videos'])} "
          f"failed) in {run['wall_s']:.0f} s on {run['workers']} workers; wrote {Path(args.out) / 'report.md'}, "
          f"results.parquet, results.csv")
    if run["failed_videos"]:
        print(f"galileo: warning: {len(run['failed_videos'])} videos failed (their errors: report.md, "
              f"records/<video>.json): {', '.join(run['failed_videos'][:5])}", file=sys.stderr)
    return 0


def slurm_arg(path: str | None) -> dict | None:
    """--slurm FILE: a JSON object of SLURM cluster settings (see galileo.batch.SLURM_SETTINGS)."""
    from .jsonio import read_json

    if path is None:
        return None
    d = read_json(path, "SLURM settings file")
    if not isinstance(d, dict):
        raise GalileoError(f"{path}: expected a JSON object of SLURM settings")
    return d


def cmd_report(args: argparse.Namespace) -> int:
    from .batch import META_KEYS
    from .jsonio import read_json
    from .report import build_report, read_table

    records = read_table(args.results)
    if not records:
        raise GalileoError(f"{args.results}: the results table has no rows")
    # the run's description (dataset, config), when its report.json lies beside the table
    where = Path(args.results) if Path(args.results).is_dir() else Path(args.results).parent
    meta = None
    if (where / "report.json").is_file():
        d = read_json(where / "report.json", "report file")
        meta = {k: d[k] for k in META_KEYS if k in d} if isinstance(d, dict) else None
    path = build_report(records, args.out, meta, recognition=args.recognition)
    print(f"wrote {path} ({len(records)} videos)")
    return 0


def cmd_scene(args: argparse.Namespace) -> int:
    """galileo scene: a scene file for your own video, from points clicked on its first frame and
    the numbers its scenario's calibration declares (`galileo.clicks`)."""
    from .camera import steps_per_frame
    from .clicks import calibration_of, calibrations, parse_points, sample_video

    cal = calibration_of(args.scenario)
    mine = {f.name for f in cal.fields}
    others = sorted({f.flag for c in calibrations().values() for f in c.fields if f.name not in mine
                     and getattr(args, f.name, None) is not None})
    if others:
        raise GalileoError(f"{', '.join(others)}: not for --scenario {args.scenario} (its numbers: "
                           f"{', '.join(f.flag for f in cal.fields)})")
    numbers = {f.name: getattr(args, f.name) for f in cal.fields}
    cal.values(numbers)       # every number checked before the video is read
    clicks = parse_points(args.points, len(cal.points))
    if len(clicks) != len(cal.points):
        raise GalileoError(f"--points: give {len(cal.points)} points u,v (pixels): {cal.order}; got {len(clicks)}")
    info, _, frames = sample_video(args.video)
    scene, err = cal.solve(clicks, numbers, info, frames)
    scene.save(args.out)
    cam = scene.camera
    print(f"wrote {args.out} ({args.scenario}): reprojection error {err:.2f} px; {cal.describe(scene, numbers)}")
    print(f"physics at {scene.sim_hz:.6g} Hz: {steps_per_frame(scene.sim_hz, cam.fps)} steps a frame at "
          f"{cam.fps:.4g} fps")
    return 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    from . import api

    # the API's checks, its errors naming the flags
    report = api._calibrate(args.scenario, args.out, n=args.n, videos=args.videos, draws=args.draws, scenes=args.scenes,
                            seed=args.seed, chains=args.chains, sweeps=args.sweeps, workers=args.workers,
                            moves=args.moves, until_rhat=args.until_rhat, max_sweeps=args.max_sweeps,
                            progress=not args.quiet, spell=lambda name: "--" + name.replace("_", "-"))
    if args.videos is not None:
        for k, c in report["coverage"].items():
            parts = [f"{float(a):.0%}: " + ("n/a" if c[a]["coverage"] is None else
                                            f"{c[a]['coverage']:.0%} ({c[a]['covered']}/{c[a]['n']})") for a in c]
            print(f"{k}: coverage " + ", ".join(parts))
        if report["failed"]:
            print(f"failed: {len(report['failed'])} video(s): " + "; ".join(f"{f['name']}: {f['error']}"
                                                                            for f in report["failed"]))
    else:
        for k, q in report["quantities"].items():
            cov = q["coverage"]
            print(f"{k}: uniformity p = {q['p_value']:.3g} (chi2 {q['p_chi2']:.3g}); coverage 50%: "
                  f"{cov['0.5']['coverage']:.0%}, 90%: {cov['0.9']['coverage']:.0%} (n = {q['n']})"
                  if q["p_value"] is not None and q["p_chi2"] is not None else f"{k}: n = {q['n']}, too few to test")
        if report["converged_share"] is not None:
            print(f"converged: {report['converged_share']:.0%} of the simulations")
        if report["failed"]:
            print(f"failed: {len(report['failed'])} simulation(s) (see sbc.json)")
    print(f"wrote {', '.join(report['files'])} ({report['wall_s']:.0f} s)")
    return 0


def cmd_recognize_label(args: argparse.Namespace) -> int:
    from . import registry
    from .recognition.data import LABELS_FILE, dataset_scenario, make_labels
    from .runner import RunConfig

    protocol = registry.get(dataset_scenario(args.dataset)).protocol
    cfg = RunConfig(chains=protocol["chains"] if args.chains is None else args.chains,
                    sweeps=protocol["sweeps"] if args.sweeps is None else args.sweeps, seed=args.seed,
                    workers=args.workers)
    cfg.check()
    out = make_labels(args.dataset, cfg, progress=not args.quiet)
    v = out["videos"].values()
    n_mass = sum(x.get("mass_kg") is not None for x in v)
    n_fric = sum(x.get("friction") is not None for x in v)
    print(f"wrote {Path(args.dataset) / LABELS_FILE}: {len(out['videos'])} videos, {n_mass} with a mass label, "
          f"{n_fric} with a friction label")
    return 0


def cmd_recognize_train(args: argparse.Namespace) -> int:
    if args.labels == "simulation":
        from .recognition.simulation import train_model as train_sim

        model = train_sim(args.dataset, holdout_fold=None if args.holdout_fold < 0 else args.holdout_fold,
                          seed=args.seed, progress=not args.quiet)
    else:
        from .recognition.train import train_model

        model = train_model(args.dataset, args.labels, holdout_fold=None if args.holdout_fold < 0 else args.holdout_fold,
                            seed=args.seed, progress=not args.quiet)
    model.save(args.out)
    m = model.meta
    print(f"wrote {args.out}: {model.kind} model on {args.labels} labels, {len(m['train_objects'])} training "
          f"objects, {len(m['test_objects'])} held out ({m['train_seconds']:.0f} s)")
    return 0


def cmd_recognize_eval(args: argparse.Namespace) -> int:
    from .recognition.train import evaluate_model, figure3, markdown

    if args.splits < 2:
        raise GalileoError("--splits must be at least 2 (each split holds out a share of the objects)")
    if args.model:
        table = evaluate_model(args.dataset, args.model, args.out, progress=not args.quiet)
    else:
        table = figure3(args.dataset, args.out, folds=args.splits, seed=args.seed, progress=not args.quiet,
                        simulation=not args.no_simulation)
    print(markdown(table))
    print(f"wrote {Path(args.out) / 'table.json'}, table.md and the scatter figures")
    return 0


def cmd_recognize_predict(args: argparse.Namespace) -> int:
    from . import registry
    from .datatypes import Tracks
    from .recognition.model import load_model

    scene = registry.load_scene(args.scene)
    scenario = registry.of(scene)
    model = load_model(args.model, scenario.name)
    tracks = Tracks.load(args.tracks) if args.tracks else None
    if tracks is None and not args.no_track:
        from .errors import StillVideo

        try:
            tracks = scenario.track(args.video, scene, progress=False)
        except StillVideo:   # a tracker that refuses a still video (splash; the ramp's tracks it, with a note)
            tracks = None    # read the objects where the scene file puts them
    readings = model.read_video(args.video, scene, tracks)
    out = {"model": str(args.model or "built-in"), "labels": model.meta.get("labels"),
           "objects": {role: r.to_json() for role, r in readings.items()}}
    if args.out:
        from .jsonio import write_json

        write_json(args.out, out)
    for role, r in readings.items():
        j = r.to_json()
        fr = (f"friction {j['friction']:.3f} (90%: {j['friction_90'][0]:.3f}-{j['friction_90'][1]:.3f}), "
              if "friction" in j else "")
        print(f"{role}: mass {j['mass_kg']:.3g} kg (90%: {j['mass_kg_90'][0]:.3g}-{j['mass_kg_90'][1]:.3g}), "
              f"{fr}from {r.patches} patch(es)")
    for note in (tracks.notes if tracks is not None else []):
        print(f"note: {note}")
    return 0


def cmd_scenarios(args: argparse.Namespace) -> int:
    import json

    from . import registry

    described = [registry.get(n).describe() for n in registry.names()]
    if args.json:
        print(json.dumps(described, indent=1))
        return 0
    for d in described:
        print(f"{d['name']}: {d['description']}")
        can = [k for k, v in d["capabilities"].items() if v]
        print(f"  can    infer{''.join(', ' + k for k in can)}")
        noise = d["noise"]
        print(f"  noise  {noise['name']} = {noise['default']:g} {noise['unit']}")
        for lat in d["latents"]:
            lo, hi = lat["bounds"]
            print(f"  {lat['name']:<8} [{lat['unit']}]  prior U({lo:g}, {hi:g})  proposal "
                  f"U(+-{lat['narrow']:g}), broad U(+-{lat['broad']:g})  {lat['doc']}")
    return 0


def scenario_name(text: str) -> str:
    """A registered scenario's name (argparse type: an unknown one is a usage error naming the known)."""
    from . import registry

    if text not in registry.names():
        raise argparse.ArgumentTypeError(f"unknown scenario {text!r}; known: {', '.join(registry.names())}")
    return text


SIGMA_HELP = ("the likelihood's noise SD, in the scenario's unit: ramp: m/s, default: 0.05 (each tracked velocity "
              "component); splash: px, default: 1 (tracked positions; px/frame for velocities); spring: px, default: "
              "0.5; fall: px, default: 1 (`galileo scenarios` lists each scenario's noise)")
MOVES_HELP = ("default: widths adapted in a warm-up plus the scenario's exact joint moves (ramp: k1 from the tracked "
              "acceleration, mass-ratio moves); paper: Galileo section 3.2 exactly; fitted: default plus, after the "
              "warm-up, an exact independence move fitted to every chain's warm-up draws (chains that a jagged "
              "likelihood holds apart meet; needs --warmup >= 10) (default: running until converged, the scenario's "
              "move set for it: ramp fitted, the others default; a fixed run of --sweeps N: default)")
SEED_HELP = "random seed of the {what}, 0 to 2^32-1 (default: 0)"


def overview(parser: argparse.ArgumentParser) -> str:
    """`galileo` alone (and `galileo recognize` alone): the commands, each with its one-line help,
    and where to read more."""
    import shutil
    import textwrap

    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    rows = [(a.dest, (a.help or "").replace("%%", "%")) for a in sub._choices_actions]
    width = max(len(name) for name, _ in rows) + 4
    columns = max(60, min(100, shutil.get_terminal_size().columns - 2))
    lines = [f"usage: {parser.prog} {sub.metavar} [FLAGS]", "", *textwrap.wrap(parser.description or "", columns),
             "", f"{'commands' if sub.metavar == 'COMMAND' else 'steps'}:"]
    for name, text in rows:
        lines += textwrap.wrap(text, columns, initial_indent=f"  {name:<{width - 2}}",
                               subsequent_indent=" " * width) or [f"  {name}"]
    lines += ["", f"`{parser.prog} {sub.metavar} --help`: its flags, each with its unit and default."]
    if parser.prog == "galileo":
        lines += ["`galileo --version`: the version."]
    return "\n".join(lines)


def printing_overview(parser: argparse.ArgumentParser):
    """A command function that prints `parser`'s overview (its subcommand not given)."""
    def show(args: argparse.Namespace) -> int:
        print(overview(parser))
        return 0
    return show


def build_parser(lazy: bool = True) -> argparse.ArgumentParser:
    """The `galileo` parser. Every flag says its unit (in its name, e.g. --duration-s, or its help)
    and its default (`(default: X)`); tests/test_cli_vocabulary.py holds every flag to it.
    `lazy`: the scenarios' own flags (predict's questions, scene's numbers) are added when their
    command first parses (importing the scenarios takes a second); False adds them now."""
    from . import __version__, registry

    defer = on_first_parse if lazy else (lambda parser, add: add(parser))
    p = Parser(prog="galileo", description="Physical object properties from video: "
                                "Bullet simulations inside MCMC (Galileo, NIPS 2015).")
    p.add_argument("--version", action="version", version=f"galileo {__version__}",
                   help="print the version and exit")
    p.set_defaults(func=printing_overview(p))
    sub = p.add_subparsers(dest="command", metavar="COMMAND")

    s = sub.add_parser("simulate", help="simulate a scene and write its trajectory JSON",
                       description="Simulate a scene (a scene file, or a scenario's default scene) and write its "
                                   "trajectory JSON; --set changes any latent or knob, in its unit.")
    s.add_argument("--scene", metavar="FILE", help="scene JSON (default: the default scene of --scenario)")
    s.add_argument("--scenario", type=scenario_name, metavar="NAME",
                   help=f"without --scene: this scenario's default scene (default: {registry.DEFAULT})")
    s.add_argument("--set", action="append", metavar="NAME=VALUE",
                   help="set a latent or another value of the scene, in its unit as named (m1_kg in kg, angle_deg in "
                        "degrees, k1 unitless; repeatable; `galileo scenarios` lists each scenario's latents and "
                        "units) (default: the scene's values)")
    s.add_argument("--duration-s", type=positive_float, metavar="S",
                   help="simulated time in seconds (default: the scene's video length, else 2)")
    s.add_argument("--frames", type=frames_int, metavar="N",
                   help=f"number of frames instead of --duration-s, at most {MAX_FRAMES} (default: from --duration-s)")
    s.add_argument("--fps", type=fps_float, metavar="F", help=f"output frame rate in frames per second, at most "
                   f"{MAX_FPS:g} (default: the scene's video's, else 30)")
    s.add_argument("--out", required=True, type=out_file, metavar="FILE", help="trajectory JSON to write")
    s.set_defaults(func=cmd_simulate)

    d = sub.add_parser("dataset", help="render Physics-101-style videos with ground truth")
    d.add_argument("--scenario", type=scenario_name, default=registry.DEFAULT, metavar="NAME",
                   help="whose videos (`galileo scenarios` lists those with datasets) "
                        f"(default: {registry.DEFAULT})")
    d.add_argument("--preset", default="demo", metavar="NAME",
                   help="how many videos and which: demo (a few), small, full (the paper's size), and the scenario's "
                        "own (ramp: bounce; splash: looks, looks-small) (default: demo)")
    d.add_argument("--out", required=True, type=out_dir, metavar="DIR", help="output folder")
    d.add_argument("--seed", type=seed_int, default=0, help=SEED_HELP.format(what="videos"))
    d.add_argument("--workers", type=workers_int, default=None, help="render processes (default: all cores)")
    d.add_argument("--camera", default="clean", metavar="NAME",
                   help="film the videos through a real camera's effects (ramp, splash): clean, phone, webcam, "
                        "handheld, or one effect (noise, h264, exposure, flicker, whitebalance, shake, blur, lens, "
                        "vignette, shadow, person, hand), optionally at a level in [0, 1] (shake:0.5); the truth is "
                        "the clean video's (default: clean)")
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    d.set_defaults(func=cmd_dataset)

    t = sub.add_parser("track", help="track the objects of a video: positions and velocities in metres")
    t.add_argument("video", help="video file (any format FFmpeg reads)")
    t.add_argument("--scene", required=True, metavar="FILE", help="scene JSON whose camera describes the video")
    t.add_argument("--out", required=True, type=out_file, metavar="FILE", help="tracks JSON to write")
    t.add_argument("--debug-video", type=out_file, metavar="FILE",
                   help="also write the video with features, centres and trails drawn, as MP4 (default: none)")
    t.add_argument("--quiet", action="store_true", help="no progress bar")
    t.set_defaults(func=cmd_track)

    i = sub.add_parser("infer", help="infer a scene's latents (masses, frictions, ...) from a video "
                                     "(MCMC over Bullet)")
    i.add_argument("video", nargs="+", help="video file; several: one problem over them (see --share, --fix); or a "
                   "folder of videos (run on Dask, one result file each in --out)")
    i.add_argument("--scene", nargs="+", metavar="FILE",
                   help="scene JSON describing the video (for the ramp: its camera), one per video in the same order; "
                        "for a folder of videos, the one scene they were all filmed in (default for a folder: each "
                        "subfolder's scene.json)")
    i.add_argument("--tracks", nargs="+", metavar="FILE", help="tracks JSON from `galileo track`, one per video "
                   "(default: track the videos first)")
    i.add_argument("--share", nargs="+", metavar="LATENT",
                   help="with several videos: latents with one value for all of them (e.g. the same object's "
                        "friction k1); the others are per video, named LATENT@1, LATENT@2, ... (default: none shared)")
    i.add_argument("--fix", action="append", metavar="NAME=VALUE",
                   help="fix a latent at a known value, in its unit, instead of inferring it (repeatable): NAME in "
                        "every video, NAME@2 in video 2 only (e.g. a reference object's mass m1_kg=0.11); added to "
                        "the scene files' \"fixed\" sections (default: none fixed)")
    i.add_argument("--chains", type=chains_int, default=None, metavar="N",
                   help="chains (default: the scenario's protocol: 16; splash 50)")
    i.add_argument("--sweeps", type=sweeps_int, default=None, metavar="N",
                   help="alone: a fixed run of N sweeps per chain (the paper's protocol: --sweeps 75); with "
                        "--until-rhat, the first block run on from (default: run until converged, from a first "
                        "block of the scenario's protocol, 75)")
    i.add_argument("--seed", type=seed_int, default=0, help=SEED_HELP.format(what="chains"))
    i.add_argument("--workers", type=workers_int, default=None,
                   help="worker processes (default: all cores; for a folder of videos, the local Dask cluster's)")
    i.add_argument("--sigma", type=positive_float, default=None, metavar="SD", help=SIGMA_HELP)
    i.add_argument("--narrow", type=positive_float, metavar="W",
                   help="half-width of the usual proposal, in each latent's unit (default: each latent's own, "
                        "`galileo scenarios` lists them)")
    i.add_argument("--broad", type=positive_float, metavar="W",
                   help="half-width of the periodic broad proposal, in each latent's unit (default: each latent's "
                        "own, `galileo scenarios` lists them)")
    i.add_argument("--broad-every", type=every_int, metavar="N",
                   help="every how many sweeps the broad proposal is used; 0: never (default: 20)")
    i.add_argument("--no-speedups", action="store_true", help="plain path: full simulations (for checks)")
    i.add_argument("--init", choices=["prior", "recognition"], default="prior",
                   help="where chains start: drawn from the prior (the paper's) or from what the recognition model "
                        "reads in the video (Galileo Fig. 4) (default: prior)")
    i.add_argument("--model", metavar="FILE", help="recognition model file for --init recognition (default: the "
                   "built-in ramp model)")
    i.add_argument("--recognition-move", type=bounded(1, MAX_SWEEPS, integer=True), metavar="EVERY", default=None,
                   help="with --init recognition: also propose the whole latent vector from the recognition "
                        "model every EVERY sweeps, an exact independence MH move (default: never)")
    i.add_argument("--moves", choices=["default", "paper", "fitted"], default=None, help=MOVES_HELP)
    i.add_argument("--warmup", type=every_int, default=None, metavar="N",
                   help="warm-up sweeps in which widths adapt, dropped with the burn-in (default: half of --sweeps)")
    i.add_argument("--until-rhat", type=rhat_float, default=None, metavar="R",
                   help="after --sweeps, run on until every latent's rank-normalised split R-hat <= R and its "
                        "bulk and tail ESS >= --min-ess, or until --max-sweeps or --max-seconds (default: 1.01, "
                        "unless --sweeps alone asks for a fixed run)")
    i.add_argument("--min-ess", type=nonneg_float, default=400.0, metavar="N",
                   help="running until converged: the effective sample size every latent needs (default: 400)")
    i.add_argument("--max-sweeps", type=sweeps_int, default=None, metavar="N",
                   help="running until converged: the sweep budget (default: 20 x --sweeps)")
    i.add_argument("--max-seconds", type=positive_float, default=None, metavar="S",
                   help="running until converged: a wall-clock budget in seconds from the start, checked between "
                        "blocks; the result says \"stopped\": max_seconds and how many sweeps ran: --sweeps N reruns "
                        "it exactly (default: 300)")
    i.add_argument("--priors", metavar="JSON", help="merged into the scene file's priors section, e.g. the ramp's "
                   "model-mismatch options '{\"observation\": \"student_t\", \"infer_sigma\": true}' (default: the "
                   "scene file's priors)")
    i.add_argument("--out", required=True, type=_type(check_nonempty), metavar="FILE|DIR",
                   help="result JSON (the sample record goes beside it as .samples.npz); "
                   "for a folder of videos, a folder (<name>.result.json each, records/, results.csv, results.parquet)")
    i.add_argument("--quiet", action="store_true", help="no progress bars")
    i.add_argument("--scheduler", metavar="ADDRESS", help="a folder of videos: on this running Dask scheduler "
                   "(tcp://host:port) (default: a local Dask cluster of --workers processes)")
    i.add_argument("--slurm", metavar="JSON", help="a folder of videos: on SLURM (dask-jobqueue), settings file, see "
                   "docs/cluster.md (default: a local Dask cluster)")
    i.add_argument("--granularity", choices=["videos", "chains"], default=None,
                   help="a folder of videos: a Dask task per video or per chain (default: videos)")
    i.set_defaults(func=cmd_infer)

    q = sub.add_parser("predict", help="answer the paper's questions from an inference result",
                       description="Answer the paper's questions from an inference result: each question the "
                                   "result's scenario declares is a flag below, asked only if given.")
    q.add_argument("--result", required=True, metavar="FILE", help="result JSON from `galileo infer`")
    q.add_argument("--out", type=out_file, metavar="FILE",
                   help="also write the answers to this JSON file (default: printed only)")
    q.set_defaults(func=cmd_predict)
    defer(q, add_questions)    # each scenario's questions (Scenario.questions) as flags

    e = sub.add_parser("experiment", help="the paper's experiments over a rendered dataset on Dask (ramp: Galileo "
                       "section 6; splash: mass correlation and which is heavier), with a report and figures")
    e.add_argument("dataset", help="folder written by `galileo dataset` (its index.json names the scenario)")
    e.add_argument("--out", required=True, metavar="DIR", type=out_dir,
                   help="results folder: records/ (one JSON per video, kept as it finishes: run the same command "
                        "again to resume), report.json, results.parquet, results.csv, report.md, figures/")
    e.add_argument("--chains", type=chains_int, default=None, metavar="N",
                   help="chains per video (default: the scenario's protocol: 16; splash 50)")
    e.add_argument("--sweeps", type=sweeps_int, default=None, metavar="N",
                   help="sweeps per chain (default: the scenario's protocol: 75)")
    e.add_argument("--seed", type=seed_int, default=0, help=SEED_HELP.format(what="chains"))
    e.add_argument("--moves", choices=["default", "paper", "fitted"], default=None,
                   help="move set of every video's chains (see `galileo infer --help`; paper: Galileo section 3.2 "
                        "exactly) (default: default; with --until-rhat the scenario's: ramp fitted)")
    e.add_argument("--priors", metavar="JSON", help="merged into every video's scene priors (see `galileo infer "
                   "--help`) (default: the scenes' priors)")
    e.add_argument("--until-rhat", type=rhat_float, default=None, metavar="R",
                   help="run each video's chains on until every latent's R-hat <= R and ESS >= --min-ess (see "
                        "`galileo infer --help`; its record says \"stopped\") (default: stop after --sweeps)")
    e.add_argument("--min-ess", type=nonneg_float, default=400.0, metavar="N",
                   help="with --until-rhat: the effective sample size every latent needs (default: 400)")
    e.add_argument("--max-sweeps", type=sweeps_int, default=None, metavar="N",
                   help="with --until-rhat: the sweep budget a video (default: 20 x --sweeps)")
    e.add_argument("--max-seconds", type=positive_float, default=None, metavar="S",
                   help="with --until-rhat: the wall-clock budget a video, in seconds, e.g. 60 (default: none)")
    where = e.add_mutually_exclusive_group()
    where.add_argument("--workers", type=workers_int, default=None,
                       help="worker processes of the local Dask cluster (default: all cores)")
    where.add_argument("--scheduler", metavar="ADDRESS", help="use a running Dask scheduler (tcp://host:port) "
                       "(default: a local Dask cluster)")
    where.add_argument("--slurm", metavar="JSON", help="run on SLURM (dask-jobqueue); settings file, see docs/cluster.md "
                       "(default: a local Dask cluster)")
    e.add_argument("--recognition", metavar="EVAL_DIR",
                   help="add the recognition model's evaluation to the report (the --out of `galileo recognize "
                        "eval`) (default: none)")
    e.add_argument("--granularity", choices=["videos", "chains"], default="videos",
                   help="a Dask task per video (its chains in turn) or per chain (default: videos)")
    e.add_argument("--quiet", action="store_true", help="no progress bars or cluster messages")
    e.set_defaults(func=cmd_experiment)

    rp = sub.add_parser("report", help="rebuild report.md and its figures from a results table, running nothing")
    rp.add_argument("results", help="results.parquet or results.csv of `galileo experiment`, or its --out folder")
    rp.add_argument("--out", required=True, metavar="DIR", type=out_dir, help="folder for report.md and figures/")
    rp.add_argument("--recognition", metavar="EVAL_DIR",
                    help="add the recognition model's evaluation (the --out folder of `galileo recognize eval`) "
                         "(default: none)")
    rp.set_defaults(func=cmd_report)

    from .clicks import add_flags

    sc = sub.add_parser("scene", help="a scene file for your own video, from points clicked on its first frame and "
                        "a few measured numbers (`galileo scene --help`: each scenario's points and numbers)",
                        description="A scene file for your own video, from points clicked on its first frame "
                                    "(pixels) and a few measured numbers (metres, degrees: each in its flag's name "
                                    "or help).")
    sc.add_argument("video", help="your video")
    sc.add_argument("--scenario", type=scenario_name, default=registry.DEFAULT, metavar="NAME",
                    help=f"the scenario the video shows (default: {registry.DEFAULT})")
    sc.add_argument("--points", "--ramp-px", required=True, metavar='"u,v u,v ..."',
                    help="the scenario's points in the video's first frame, in pixels, in its order (below)")
    sc.add_argument("--out", required=True, metavar="FILE", help="scene JSON for galileo track and galileo infer")
    sc.set_defaults(func=cmd_scene)
    defer(sc, add_flags)    # each scenario's numbers, from its calibration's fields

    cb = sub.add_parser("calibrate", help="simulation-based calibration (rank histograms, ECDF tests, interval "
                        "coverage) on simulated observations, or interval coverage on a rendered dataset",
                        description="Simulation-based calibration (SBC) on observations simulated from the prior, "
                                    "or interval coverage on a rendered dataset. Each simulation or video is one "
                                    "inference and SBC needs many (e.g. --n 200), so each is kept cheap: 4 chains x "
                                    "200 sweeps by default, 800 sweeps where galileo infer's protocol (16 x 75, the "
                                    "paper's) runs 1200, still keeping 4 x 100 draws after the warm-up and burn-in "
                                    "for the --draws 99 the truth is ranked among.")
    cb.add_argument("--scenario", type=scenario_name, default=registry.DEFAULT, metavar="NAME",
                    help=f"scenario (default: {registry.DEFAULT})")
    cb.add_argument("--n", type=count_int, default=None, metavar="N",
                    help="SBC: this many simulations from the prior, one inference each (default: none; give --n "
                         "or --videos)")
    cb.add_argument("--videos", metavar="DIR", default=None,
                    help="instead: interval coverage on this rendered dataset, a folder from `galileo dataset` "
                         "(default: none)")
    cb.add_argument("--out", required=True, type=out_dir, metavar="DIR",
                    help="output folder (sbc.json, sbc.md, PNGs; or coverage.json, .md)")
    cb.add_argument("--seed", type=seed_int, default=0, help=SEED_HELP.format(what="simulations and chains"))
    cb.add_argument("--chains", type=chains_int, default=4, metavar="N",
                    help="chains per simulation or video: fewer than galileo infer's 16, since SBC runs an inference "
                         "per simulation (default: 4)")
    cb.add_argument("--sweeps", type=sweeps_int, default=200, metavar="N",
                    help="sweeps per chain, the first half warm-up and burn-in: more than galileo infer's 75, so "
                         "that 4 chains keep 400 draws to thin to --draws (default: 200)")
    cb.add_argument("--until-rhat", type=rhat_float, default=None, metavar="R",
                    help="run each inference on until R-hat <= R and ESS >= the ranked draws, or --max-sweeps "
                         "(default: stop after --sweeps)")
    cb.add_argument("--max-sweeps", type=sweeps_int, default=None, metavar="N",
                    help="with --until-rhat: the sweep budget (default: 20 x --sweeps)")
    cb.add_argument("--moves", choices=["default", "paper", "fitted"], default=None,
                    help="move set of every inference (see `galileo infer --help`) (default: default; with "
                         "--until-rhat the scenario's: ramp fitted)")
    cb.add_argument("--draws", type=count_int, default=99, metavar="L",
                    help="posterior draws the truth is ranked among, ranks 0..L (default: 99)")
    cb.add_argument("--scenes", default="default", metavar="default|dataset|FILE",
                    help="the scenario's default scene, random scenes like its dataset's, or a scene file "
                         "(default: default)")
    cb.add_argument("--workers", type=workers_int, default=None,
                    help="processes, one simulation each (default: all cores)")
    cb.add_argument("--quiet", action="store_true", help="no progress bar")
    cb.set_defaults(func=cmd_calibrate)

    r = sub.add_parser("recognize", help="the recognition model (Galileo section 4): mass and friction from one "
                       "frame, trained on Galileo's own inferences",
                       description="The recognition model (Galileo section 4): mass and friction from one frame, "
                                   "trained on Galileo's own inferences.")
    r.set_defaults(func=printing_overview(r))
    rsub = r.add_subparsers(dest="recognize_command", metavar="STEP")
    rl = rsub.add_parser("label", help="Galileo labels: track and infer every video of a dataset "
                         "(resumable; writes DATASET/labels.galileo.json)")
    rl.add_argument("--dataset", required=True, metavar="DIR", help="folder written by `galileo dataset`")
    rl.add_argument("--chains", type=chains_int, default=None, metavar="N",
                    help="chains per video (default: the scenario's protocol: 16; splash 50)")
    rl.add_argument("--sweeps", type=sweeps_int, default=None, metavar="N",
                    help="sweeps per chain (default: the scenario's protocol: 75)")
    rl.add_argument("--seed", type=seed_int, default=0, help=SEED_HELP.format(what="labels"))
    rl.add_argument("--workers", type=workers_int, default=None, help="worker processes (default: all cores)")
    rl.add_argument("--quiet", action="store_true", help="no progress bars")
    rl.set_defaults(func=cmd_recognize_label)
    rt = rsub.add_parser("train", help="train a recognition model on a dataset")
    rt.add_argument("--dataset", required=True, metavar="DIR", help="folder written by `galileo dataset`")
    rt.add_argument("--labels", choices=["galileo", "oracle", "simulation"], default="galileo",
                    help="galileo: MCMC's estimates (run `recognize label` first); oracle: ground truth; "
                         "simulation: velocity series simulated from the prior, no video labels (default: galileo)")
    rt.add_argument("--holdout-fold", type=bounded(-1, 4, integer=True), default=0, metavar="K",
                    help="hold out the objects of this split (0-4) for testing; -1: train on every object "
                         "(default: 0)")
    rt.add_argument("--seed", type=seed_int, default=0, help=SEED_HELP.format(what="model"))
    rt.add_argument("--out", required=True, type=out_file, metavar="FILE", help="model file to write (.npz)")
    rt.add_argument("--quiet", action="store_true", help="no progress bars")
    rt.set_defaults(func=cmd_recognize_train)
    re_ = rsub.add_parser("eval", help="the Fig. 3 table: MSE and correlation against ground truth on held-out "
                          "objects")
    re_.add_argument("--dataset", required=True, metavar="DIR", help="folder written by `galileo dataset`")
    re_.add_argument("--model", metavar="FILE", help="score this model on the objects it held out (default: the "
                     "whole protocol: --splits splits, Galileo / oracle / simulation / uniform)")
    re_.add_argument("--splits", type=bounded(2, 100, integer=True), default=5, metavar="K",
                     help="the whole protocol's cross-validation: the objects in K splits, each held out once "
                          "(2-100) (default: 5)")
    re_.add_argument("--seed", type=seed_int, default=0, help=SEED_HELP.format(what="splits and models"))
    re_.add_argument("--no-simulation", action="store_true", help="leave the simulation-trained model out")
    re_.add_argument("--out", required=True, type=out_dir, metavar="DIR",
                     help="folder for table.json, table.md and the scatter PNGs")
    re_.add_argument("--quiet", action="store_true", help="no progress bars")
    re_.set_defaults(func=cmd_recognize_eval)
    rp = rsub.add_parser("predict", help="mass and friction of a video's objects from its first frame")
    rp.add_argument("video", help="video file (any format FFmpeg reads)")
    rp.add_argument("--scene", required=True, metavar="FILE", help="scene JSON with the video's camera")
    rp.add_argument("--model", metavar="FILE", help="model file (default: the built-in ramp model)")
    rp.add_argument("--tracks", metavar="FILE", help="tracks JSON (default: track the video; where nothing moves, "
                    "read the objects where the scene file puts them)")
    rp.add_argument("--no-track", action="store_true", help="do not track: read where the scene file puts them")
    rp.add_argument("--out", type=out_file, metavar="FILE",
                    help="also write the readings to this JSON file (default: printed only)")
    rp.set_defaults(func=cmd_recognize_predict)

    c = sub.add_parser("scenarios", help="list the scenarios with their latents, units and default priors")
    c.add_argument("--json", action="store_true", help="as JSON")
    c.set_defaults(func=cmd_scenarios)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:     # --help, --version (0) or a refused flag (2, its one line printed)
        return int(e.code or 0) if not isinstance(e.code, str) else 2

    def run() -> int:
        check_not_an_input(args)
        rc = args.func(args)
        for old, new in (getattr(args, DEPRECATED, None) or {}).values():   # after the command: an error is one line
            print(f"galileo: warning: {old} is deprecated: use {new}", file=sys.stderr)
        return rc

    return run_reporting_errors("galileo", run)


if __name__ == "__main__":
    raise SystemExit(main())
