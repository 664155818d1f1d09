"""Errors that carry a one-line message for the user (the CLI exits with code 2)."""


class GalileoError(Exception):
    """A problem with the user's input: shown as one line, never as a traceback."""


class SceneError(GalileoError):
    """A scene file that is missing, malformed or physically impossible."""


class StillVideo(GalileoError):
    """The tracker sees nothing move in a video (evidence in itself, but nothing to track)."""


def run_reporting_errors(prog: str, fn) -> int:
    """`fn()`'s exit code; a GalileoError becomes one line on stderr and exit code 2, Ctrl-C
    exit code 130 (for the CLI and the bench scripts)."""
    import sys

    try:
        return int(fn() or 0)
    except GalileoError as e:
        msg = " ".join(str(e).split("\n"))
        print(f"{prog}: error: {msg}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
