"""Galileo app: watch and steer physical inference from video in the browser.

    python app.py                                  # the built-in demo (rendered and cached on first run)
    python app.py --scenario splash                # the splash demo: an object dropped into a tank of water
    python app.py --video V.mp4 --scene S.json     # your own video and its scene/camera file
    python app.py --upload                         # your own video, uploaded and calibrated in the browser
    python app.py --session sessions/<name>        # reopen a recorded session (paused: scrub it, Resume runs on)
    python app.py --sweeps 75                      # the paper's fixed 75 sweeps, then pause (default: until converged)

Tracks the video, starts the MCMC chains in background worker processes, serves the viewer
(viser) on http://127.0.0.1:8080 and records the session under sessions/<timestamp>-<name>/.
Log-likelihood traces, posteriors, the video with its tracks and the selected simulation
stream to rerun (`--rerun save`, the default, writes session.rrd in the session folder).

One app per session: the app holds the session folder's lock (`ui.session.SessionLock`) from
the folder's creation (or its reopening) until it exits; a second app on the same folder is
refused in one line naming the first (pid, host). A folder deleted or moved while the app runs
is said at once; the session is then saved in a new folder beside it (see ui/controller.py).
"""
from __future__ import annotations

import argparse
import json
import signal
import threading
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent
DEMO_DIR = ROOT / ".cache" / "demo"
SESSIONS = ROOT / "sessions"


@dataclass(frozen=True)
class Demo:
    """A built-in demo: the scenario whose dataset renders it, where it is cached, the
    session name (it runs its scenario's protocol's chains by default)."""
    scenario: str
    cache: Path
    name: str


DEMO_PRESET = "demo"   # a scenario has a built-in demo when its dataset has this preset


def _demos() -> dict[str, Demo]:
    """Every registered scenario whose dataset has a demo preset. The default scenario's demo is
    cached in .cache/demo/ and recorded as session "demo"; another's in .cache/demo-<name>/ and
    "<name>-demo"."""
    from galileo import registry

    return {n: Demo(n, DEMO_DIR, "demo") if n == registry.DEFAULT else
            Demo(n, ROOT / ".cache" / f"demo-{n}", f"{n}-demo")
            for n in registry.with_capability("dataset") if DEMO_PRESET in registry.get(n).dataset.presets}


DEMOS = _demos()


def _calibrated() -> list[str]:
    """The scenarios whose own videos the upload page calibrates (`Scenario.calibration`)."""
    from galileo import registry

    return registry.with_capability("calibration")


def ensure_demo(progress: bool = True, scenario: str | None = None) -> Path:
    """Render a built-in demo on first run and cache it (with its scene) under its cache folder
    (`_demos`); the folder of the video the app runs: the preset's first (of a preset of
    several videos too: as one problem, each sweep would take as many times as long)."""
    from galileo import registry
    from galileo.dataset import build
    from galileo.errors import GalileoError
    from galileo.jsonio import read_json

    demo = DEMOS[scenario or registry.DEFAULT]
    try:
        index = read_json(demo.cache / "index.json", "demo index")
        folder = demo.cache / index["videos"][0]["name"] if index["preset"] == DEMO_PRESET else None
    except (GalileoError, LookupError, TypeError):    # not rendered yet (or a build was cut short)
        folder = None
    if folder is None or not (folder / "video.mp4").exists() or not (folder / "scene.json").exists():
        entries = build(registry.get(demo.scenario).dataset, DEMO_PRESET, demo.cache, seed=0, workers=1,
                        progress=progress)
        folder = demo.cache / entries[0]["name"]
    return folder


def parse_args(argv=None) -> argparse.Namespace:
    """The command line, every value checked as it is read (galileo.cli's typed flags): a bad
    one is one line `app: error: ...` and SystemExit(2)."""
    from galileo.cli import (MAX_SWEEPS, Parser, chains_int, nonneg_float, port_int, rhat_float, seed_int, sweeps_int,
                             workers_int)

    class AppParser(Parser):
        error_name = "app"

    p = AppParser(description="Galileo: watch and steer physical inference from video")
    p.add_argument("--video", nargs="+", help="video file (with --scene); several: one problem over them (see "
                   "--share, --fix); default: the built-in demo")
    p.add_argument("--scene", nargs="+", help="scene JSON whose camera describes the video (one per video, in order)")
    p.add_argument("--share", nargs="+", metavar="LATENT",
                   help="with several videos: latents with one value for all (the others are per video, LATENT@1, "
                        "LATENT@2, ...)")
    p.add_argument("--fix", action="append", metavar="NAME=VALUE",
                   help="fix a latent at a known value (NAME in every video, NAME@2 in video 2 only; repeatable)")
    p.add_argument("--session", help="reopen a recorded session folder")
    p.add_argument("--upload", action="store_true",
                   help="upload your own video in the browser, click the points its scenario asks for (the ramp's "
                        "four corners, the splash tank's) on its first frame and start inference there (a new "
                        "session; see ui/calibrate.py)")
    p.add_argument("--scenario", choices=sorted(set(DEMOS) | set(_calibrated())), default=None,
                   help=f"which built-in demo to run without --video/--scene ({', '.join(sorted(DEMOS))}; default "
                        "ramp), or, with --upload, the scenario the page opens on")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)")
    p.add_argument("--port", type=port_int, default=8080, help="port to serve on, 1-65535 (default 8080)")
    p.add_argument("--rerun", nargs="+", default=["save"], metavar="MODE",
                   help="off | save (session.rrd in the session folder) | web (also serve rerun's web viewer) "
                        "| connect URL")
    p.add_argument("--rerun-web-port", type=port_int, default=9090, metavar="PORT",
                   help="with --rerun web: the web viewer's port (default 9090)")
    p.add_argument("--rerun-grpc-port", type=port_int, default=9876, metavar="PORT",
                   help="with --rerun web: the port of its gRPC server, which the viewer reads (default 9876)")
    p.add_argument("--chains", type=chains_int, default=None,
                   help="chains to start (default: the demo's, ramp 16, splash 50)")
    p.add_argument("--sweeps", type=sweeps_int, default=None,
                   help=f"alone: a fixed run, the sweeps per chain before the chains pause (resume to go on; "
                        f"1-{MAX_SWEEPS}); with --until-rhat, the first block run on from (default: a new session "
                        "runs until converged, from a first block of the scenario's 75)")
    p.add_argument("--moves", choices=["default", "paper", "fitted"], default=None,
                   help="default: widths adapted in a warm-up (the first half of --sweeps) plus the scenario's exact "
                        "joint moves; paper: Galileo section 3.2 exactly; fitted: default plus, once every chain is "
                        "past the warm-up, an exact independence move fitted to their warm-ups (galileo infer "
                        "--moves fitted) (a new session; default: the scenario's move set for running until "
                        "converged: ramp fitted, the others default)")
    p.add_argument("--until-rhat", type=rhat_float, default=None, metavar="R",
                   help="after --sweeps, run on until every latent's R-hat <= R and its bulk and tail ESS >= "
                        "--min-ess, or until --max-sweeps; then pause (default for a new session: 1.01, unless "
                        "--sweeps N alone asks for a fixed run; a reopened session keeps its own)")
    p.add_argument("--min-ess", type=nonneg_float, default=None,
                   help="the ESS --until-rhat needs per latent (default 400)")
    p.add_argument("--max-sweeps", type=sweeps_int, default=None,
                   help="the sweep budget of --until-rhat (default: 20 x --sweeps)")
    p.add_argument("--seed", type=seed_int, default=0)
    p.add_argument("--workers", type=workers_int, default=None, help="worker processes (default: all cores)")
    p.add_argument("--name", help="session name (default: the video's name; demo / splash-demo)")
    p.add_argument("--init", choices=["prior", "recognition"], default="prior",
                   help="where chains start: the prior, or what the recognition model reads in the video's "
                        "first frame (Galileo Fig. 4)")
    p.add_argument("--model", help="recognition model for --init recognition (default: the built-in ramp model)")
    args = p.parse_args(argv)
    if args.upload and (args.video or args.scene or args.session or args.share or args.fix):
        p.error("--upload brings the video and its scene from the browser: not with --video, --scene, --session, "
                "--share or --fix")
    if args.until_rhat is not None and not args.until_rhat > 1.0:
        p.error(f"--until-rhat must be above 1 (e.g. 1.01), got {args.until_rhat:g}")
    if args.max_sweeps is not None and args.until_rhat is None and (args.sweeps is not None or args.session):
        p.error("--max-sweeps is the budget of --until-rhat; without it, use --sweeps")
    if not args.session and args.until_rhat is None and args.sweeps is None:
        # a new session runs until converged by default, as `galileo infer` does (issue 30); a
        # reopened one keeps the criteria it was recorded with
        from galileo.results import RHAT_TARGET

        args.until_rhat = RHAT_TARGET
    if args.name is not None and not 0 < len(args.name.strip()) <= MAX_NAME:
        p.error(f"--name must be 1 to {MAX_NAME} characters, got {len(args.name.strip())}")
    from galileo.errors import GalileoError

    try:
        _rerun_mode(args)
    except GalileoError as e:
        p.error(str(e))
    from galileo import registry

    if args.upload:
        if args.scenario is not None and args.scenario not in _calibrated():
            p.error(f"--scenario {args.scenario}: the upload page calibrates {', '.join(_calibrated())}")
    elif not (args.video or args.session):
        args.scenario = args.scenario or registry.DEFAULT
        if args.scenario not in DEMOS:
            p.error(f"--scenario {args.scenario} has no built-in demo; these do: {', '.join(sorted(DEMOS))}")
    # the protocol of the scenario the run is of fills --chains and --sweeps (the first block, or the
    # target of a session recorded without one)
    name = args.scenario or registry.DEFAULT
    if args.scene:
        try:
            name = registry.name_in(json.loads(Path(args.scene[0]).read_text()))
        except (OSError, ValueError, GalileoError):
            pass    # (the file is checked, with its own message, before anything starts)
    protocol = registry.get(name).protocol if name in registry.names() else {"chains": 16, "sweeps": 75}
    args.chains = protocol["chains"] if args.chains is None else args.chains
    args.sweeps = protocol["sweeps"] if args.sweeps is None else args.sweeps
    if args.max_sweeps is not None and args.max_sweeps < args.sweeps:
        p.error(f"--max-sweeps must be >= --sweeps ({args.sweeps}), got {args.max_sweeps}")
    return args


MAX_NAME = 100     # characters of a session name (it becomes a folder name)


def _rerun_mode(args) -> tuple[str, str | None]:
    """(mode, URL) of --rerun; GalileoError for an unknown mode, a missing or extra URL."""
    from galileo.errors import GalileoError
    from ui.rerun_log import MODES

    mode, extra = args.rerun[0], args.rerun[1:]
    if mode not in MODES:
        raise GalileoError(f"--rerun must be off, save, web or connect URL, not {mode!r}")
    if mode == "connect":
        if len(extra) != 1 or not extra[0].strip():
            raise GalileoError("--rerun connect needs one URL, e.g. rerun+http://127.0.0.1:9876/proxy")
        return mode, extra[0]
    if extra:
        raise GalileoError(f"--rerun {mode} takes no URL (only connect does), got {' '.join(extra)!r}")
    if mode != "web" and (args.rerun_web_port, args.rerun_grpc_port) != (9090, 9876):
        raise GalileoError("--rerun-web-port and --rerun-grpc-port are for --rerun web")
    if args.rerun_web_port == args.rerun_grpc_port:
        raise GalileoError(f"--rerun-web-port and --rerun-grpc-port must differ (both {args.rerun_web_port})")
    return mode, None


def main(argv=None) -> int:
    try:
        args = parse_args(argv)
    except SystemExit as e:     # --help (0), or a refused value (2, its one line printed)
        return e.code if isinstance(e.code, int) else 2
    from galileo.errors import run_reporting_errors

    def checked_run() -> int:
        check_inputs(args)      # before tracking, rendering the demo or forking workers
        return run(args)

    return run_reporting_errors("app", checked_run)


def check_inputs(args) -> None:
    """What can be refused at once, before anything slow: the host resolves and the port can be
    bound on it, the files named exist (and the scene file is valid), a reopened session has
    its video."""
    from galileo.errors import GalileoError
    from ui.session import VIDEO_FILE

    port_is_free(args.host, args.port)
    if args.rerun and args.rerun[0] == "web":
        for flag in ("--rerun-web-port", "--rerun-grpc-port"):
            port_is_free(args.host, getattr(args, flag[2:].replace("-", "_")), flag)
    paths = [("--video", v, "file") for v in args.video or ()] + [("--scene", v, "file") for v in args.scene or ()]
    for flag, path, kind in paths + [("--model", args.model, "file"), ("--session", args.session, "folder")]:
        if path is None:
            continue
        p = Path(path)
        if not p.exists():
            raise GalileoError(f"{flag}: {path} not found")
        if kind == "file" and not p.is_file():
            raise GalileoError(f"{flag}: {path} is not a file")
        if kind == "folder" and not p.is_dir():
            raise GalileoError(f"{flag}: {path} is not a session folder")
    if args.session and not (Path(args.session) / VIDEO_FILE).is_file():
        raise GalileoError(f"session {args.session} has no {VIDEO_FILE}")
    if args.video and args.scene and len(args.video) != len(args.scene):
        raise GalileoError(f"{len(args.video)} video(s) need {len(args.video)} scene file(s), one --scene per "
                           f"--video; got {len(args.scene)}")
    for scene in args.scene or ():
        from galileo import registry

        registry.load_scene(scene)


def port_is_free(host: str, port: int, flag: str = "--port") -> None:
    """Refuse a host that does not resolve to an address of this machine, or a port another
    program holds on it (the viewer would otherwise move to the next one); bound as the
    viewer's server will bind (every address the host resolves to, address reuse on, an
    address family the machine lacks skipped)."""
    import errno
    import socket

    from galileo.cli import check_host
    from galileo.errors import GalileoError

    if not (isinstance(port, int) and 1 <= port <= 65535):
        raise GalileoError(f"{flag} must be 1-65535, got {port!r}")
    addrs = check_host(host)
    bound = 0
    last = None
    for family, _, _, _, sockaddr in dict.fromkeys((a[0], a[1], a[2], a[3], a[4]) for a in addrs):
        with socket.socket(family, socket.SOCK_STREAM) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if family == socket.AF_INET6 and hasattr(socket, "IPV6_V6ONLY"):
                s.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            try:
                s.bind((sockaddr[0], port, *sockaddr[2:]))
                bound += 1
            except OSError as e:
                if e.errno == errno.EADDRINUSE:
                    raise GalileoError(f"port {port} on {host} is taken (another app running?); choose another with "
                                       f"{flag} ({e.strerror or e})") from None
                if e.errno == errno.EACCES:
                    raise GalileoError(f"port {port} on {host}: permission denied (ports below 1024 need "
                                       f"privileges); choose another with {flag}") from None
                if e.errno != errno.EADDRNOTAVAIL:
                    raise GalileoError(f"--host {host}: cannot serve on port {port} there "
                                       f"({e.strerror or e})") from None
                last = e
    if not bound:
        why = last.strerror if last is not None else "no address"
        raise GalileoError(f"--host {host} is not an address of this machine ({why}); use 127.0.0.1 (this machine "
                           "only) or 0.0.0.0 (every interface)")


def new_session(args, video_path, scene_path, name: str, model=None, say=print):
    """Track the video with the scene (or each of several videos with its scene: one problem,
    `--share`, `--fix`) and make a new session folder, locked from its creation, with the
    videos copied into it: (session, scene, tracks, the chains' recognition init or None, the
    session's lock). `say` reports progress."""
    import shutil

    from galileo import registry
    from galileo.cli import fixed_arg
    from galileo.errors import GalileoError
    from ui.session import SessionLock, new_session_dir, video_file

    videos = [Path(video_path)] if isinstance(video_path, (str, Path)) else [Path(v) for v in video_path]
    scene_paths = [scene_path] if isinstance(scene_path, (str, Path)) else list(scene_path)
    if getattr(args, "share", None) and len(videos) == 1:
        raise GalileoError("--share is for several videos (one value of a latent for all of them)")
    scenes = [registry.load_scene(p) for p in scene_paths]
    scene = registry.problem(scenes, getattr(args, "share", None) or (), fixed_arg(getattr(args, "fix", None)))
    if len(videos) > 1 and model is not None:
        raise GalileoError("--init recognition reads one video: for several, chains start from the prior")
    registry.of(scene).latents(scene)    # a bad --share or --fix fails here, before tracking
    tracks = []
    for v, s in zip(videos, scenes):
        say(f"tracking {v} ...")
        tracks.append(registry.of(s).track(v, s))
        for note in tracks[-1].notes:   # (why an answer may be uncertain: the camera moved, a distractor, ...)
            say(f"note: {note}")
    session = new_session_dir(SESSIONS, name)
    lock = SessionLock(session)
    for i, v in enumerate(videos):
        shutil.copyfile(v, session / video_file(i))
    # (the controller writes scene.json and tracks.json into the session; bounds: the priors')
    init = None
    if model is not None:
        from galileo.recognition.model import recognition_init

        init = recognition_init(model, videos[0], scene, tracks[0], source=str(args.model or "built-in"))
    return session, scene, tracks if len(tracks) > 1 else tracks[0], init, lock


def start_chains(args, session: Path, scene, tracks, init=None, lock=None):
    """The new session's controller, holding its `lock` (its worker processes are forked here:
    call it before any server thread or socket exists)."""
    from galileo import api, registry
    from galileo.errors import GalileoError
    from galileo.results import MIN_ESS
    from ui.controller import Controller

    min_ess = MIN_ESS if args.min_ess is None else args.min_ess
    # the app's chains can always be run until converged: by default the scenario's move set for it
    moves = api.moves_for(registry.of(scene), args.moves, args.until_rhat, args.sweeps, converging=True,
                          max_sweeps=args.max_sweeps)
    try:
        return Controller(scene, tracks, chains=args.chains, seed=args.seed, workers=args.workers,
                          session_dir=session, init=init, moves=moves, sweeps=args.sweeps,
                          until_rhat=args.until_rhat, min_ess=min_ess, max_sweeps=args.max_sweeps,
                          session_lock=lock)
    except ValueError as e:
        raise GalileoError(str(e)) from None


def run(args) -> int:
    from galileo.errors import GalileoError
    from galileo import registry
    from galileo.results import MIN_ESS
    from ui.controller import Controller
    from galileo.joint import tracks_list
    from ui.session import VIDEO_FILE, video_files

    mode, url = _rerun_mode(args)
    port_is_free(args.host, args.port)     # before tracking and the chains, which take a while
    model = None
    if args.session and (args.init != "prior" or args.model):
        raise GalileoError("--init and --model start a new session's chains; a reopened session keeps its own")
    if args.session and args.moves:
        raise GalileoError("--moves starts a new session's chains; a reopened session keeps its own")
    min_ess = MIN_ESS if args.min_ess is None else args.min_ess
    if args.model and args.init != "recognition":
        raise GalileoError("--model is for --init recognition")
    if args.init == "recognition":   # before tracking: a bad model file fails fast
        from galileo.recognition.model import load_model

        model = load_model(args.model, registry.load_scene(args.scene[0]).scenario if args.scene else args.scenario)
    if args.session:
        session = Path(args.session)
        # its chains wait for Resume (those that were running when it was saved too)
        ctrl = Controller.load(session, workers=args.workers, sweeps=args.sweeps, paused=True)
        try:
            if args.until_rhat is not None:   # the criteria, acted on when the user resumes
                ctrl.run_until(args.until_rhat, min_ess, args.max_sweeps, verdict=False)
        except ValueError as e:
            ctrl.close()
            raise GalileoError(str(e)) from None
        scene, tracks = ctrl.scene, ctrl.tracks
        video_path = [session / name for name in video_files(session)]
        n_videos = len(tracks_list(tracks))
        if len(video_path) != n_videos:
            ctrl.close()
            raise GalileoError(f"session {session} holds {len(video_path)} video(s) but its problem has {n_videos}")
    elif args.upload:   # the browser brings the video and its scene, then as --video --scene
        from ui.calibrate import calibrate_in_browser

        # tracking runs while the page shows its progress; the chains' workers are forked once
        # the page's server has stopped (none of its threads or its socket in them)
        session, scene, tracks, init, lock = calibrate_in_browser(
            args.host, args.port, SESSIONS, lambda v, s, n, say: new_session(args, v, s, n, model, say),
            name=args.name, scenario=args.scenario)
        ctrl = start_chains(args, session, scene, tracks, init, lock)
        video_path = [session / VIDEO_FILE]
    else:
        if bool(args.video) != bool(args.scene):
            raise GalileoError("give both --video and --scene (or neither, for the demo)")
        if args.video:
            video_path, scene_path = [Path(v) for v in args.video], [Path(s) for s in args.scene]
            name = args.name or video_path[0].stem
        else:
            folder = ensure_demo(scenario=args.scenario)
            video_path, scene_path = [folder / "video.mp4"], [folder / "scene.json"]
            name = args.name or DEMOS[args.scenario].name
        session, scene, tracks, init, lock = new_session(args, video_path, scene_path, name, model)
        ctrl = start_chains(args, session, scene, tracks, init, lock)
    try:
        return serve(args, ctrl, session, tracks, video_path, mode, url)
    except BaseException:     # nothing served (or a failure while serving): the workers stop, the lock goes
        ctrl.close()
        raise


def serve(args, ctrl, session: Path, tracks, video_path: list[Path], mode: str, url: str | None) -> int:
    """Log to rerun, serve the viewer and run the chains until Ctrl-C (or SIGTERM); then stop,
    save and say where the session is saved (exit code 1, saying so, when it could not be)."""
    import sys

    from galileo.errors import GalileoError
    from galileo.joint import tracks_list
    from galileo.video import VideoFrames
    from ui.rerun_log import RRD_NAME, ControllerFeed, RerunLogger
    from ui.viewer import Viewer

    # decoded frame by frame as the viewer shows them, never all held (one per video of the problem)
    videos = [VideoFrames(p) for p in video_path]
    video = videos if len(videos) > 1 else videos[0]
    first_tracks = tracks_list(tracks)[0]
    old_rrd = session / RRD_NAME
    if mode != "off" and old_rrd.exists():  # keep the earlier run's recording
        import time as _time

        old_rrd.rename(session / f"session.{_time.strftime('%Y%m%d-%H%M%S', _time.localtime(old_rrd.stat().st_mtime))}.rrd")

    try:
        logger = RerunLogger(mode, session_dir=session, connect_url=url, host=args.host,
                             web_port=args.rerun_web_port, grpc_port=args.rerun_grpc_port,
                             latents=list(ctrl.names), n_chains=len(ctrl.all_chain_ids()))
    except RuntimeError as e:
        raise GalileoError(f"rerun: {e}") from None
    logger.log_video(video_path[0], first_tracks, first_tracks.fps)   # rerun shows the first video
    # traces, posterior and R-hat every len(chains) rounds, events, the MAP's motion (its own thread)
    feed = ControllerFeed(logger, ctrl)
    if args.session:   # the new session.rrd continues the old one: every chain's sweeps from 1, events, R-hat
        feed.log_history()
    ctrl.add_listener(feed.on_controller)

    try:
        viewer = Viewer(ctrl, ctrl.likelihood_scene, tracks, video, host=args.host, port=args.port,
                        target_sweeps=args.sweeps)
    except GalileoError:     # the port was taken since the check: nothing started yet, close what is open
        logger.close()
        raise
    logger.log_selected(viewer.traj)   # the sample the viewer shows, and each one the user selects
    viewer.add_selection_listener(logger.log_selected)
    print(f"viewer: {viewer.url}")
    if logger.web_url:
        print(f"rerun web viewer: {logger.web_url}")
    print(f"session: {session}  (Ctrl-C to stop; the session is saved as it goes)")
    ctrl.start()
    done = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: done.set())
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    done.wait()
    print("stopping ...")
    ctrl.stop()
    viewer.close()
    logger.close()
    ctrl.close()
    saved = ctrl.status()["session"]
    if not saved["saving"]:
        print(f"app: error: the session is NOT saved: {saved['note']}", file=sys.stderr)
        return 1
    moved = saved["folder"] != str(session)
    print(f"saved {saved['folder']}" + (f" (not {session}: that folder was lost while the app ran)" if moved else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
