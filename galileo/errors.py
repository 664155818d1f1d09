"""Errors that carry a one-line message for the user (the CLI exits with code 2)."""


class GalileoError(Exception):
    """A problem with the user's input: shown as one line, never as a traceback."""


class SceneError(GalileoError):
    """A scene file that is missing, malformed or physically impossible."""
