"""Moved: ramp tracking is `galileo.scenarios.ramp.tracking`, its parts `galileo.vision`.
These re-exports keep not-yet-updated callers working."""
from .scenarios.ramp.tracking import track, write_debug_video  # noqa: F401
from .vision.background import MOG_SCALE  # noqa: F401
from .vision.velocity import velocity_from_positions  # noqa: F401
