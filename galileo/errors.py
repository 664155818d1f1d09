"""Errors that carry a one-line message for the user (the CLI exits with code 2)."""


class GalileoError(Exception):
    """A problem with the user's input: shown as one line, never as a traceback."""


class SceneError(GalileoError):
    """A scene file that is missing, malformed or physically impossible."""


class StillVideo(GalileoError):
    """The tracker sees nothing move in a video (evidence in itself, but nothing to track)."""


class Terminated(KeyboardInterrupt):
    """SIGTERM (`kill`, a batch system's time limit, `timeout`): raised in the main thread so
    that it stops the work as Ctrl-C does (what Ctrl-C's KeyboardInterrupt closes and keeps,
    it closes and keeps), where the signal's default would end the process at once, silently,
    leaving its workers to the system."""


def _terminated(signum, frame):
    raise Terminated()


def run_reporting_errors(prog: str, fn) -> int:
    """`fn()`'s exit code; a GalileoError (or a system call's OSError: a file refused) becomes
    one line `prog: error: ...` on stderr and exit code 2, Ctrl-C one line `prog: interrupted`
    and exit code 130, SIGTERM (while `fn` runs in the main thread) one line `prog: terminated`
    and exit code 143 (128 + 15, as the shell reports a process it ended) (for the CLI, the app
    and the bench scripts)."""
    import signal
    import sys
    import threading

    main = threading.current_thread() is threading.main_thread()
    before = signal.signal(signal.SIGTERM, _terminated) if main else None
    try:
        return int(fn() or 0)
    except GalileoError as e:
        msg = " ".join(str(e).split())
        print(f"{prog}: error: {msg}", file=sys.stderr)
        return 2
    except OSError as e:
        # a file the system refused (a folder where a file was meant, no permission, a full
        # disk) that no check caught first: still one line naming the file, never a traceback
        if e.errno is None:
            raise
        if getattr(e, "filename2", None) is not None:     # a rename onto it (an atomic write's last step)
            where = f"cannot write {e.filename2}: "
        else:
            where = f"{e.filename}: " if e.filename is not None else ""
        print(f"{prog}: error: {where}{e.strerror or e}", file=sys.stderr)
        return 2
    except Terminated:
        print(f"{prog}: terminated", file=sys.stderr)
        return 128 + signal.SIGTERM
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    finally:
        if main:
            signal.signal(signal.SIGTERM, before if before is not None else signal.SIG_DFL)
