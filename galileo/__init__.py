"""Galileo: physical object properties from video, by running Bullet inside MCMC.

The Python API (`galileo.api`; what the `galileo` command line does, with its defaults):

    import galileo
    scene = galileo.load_scene("demo/scene.json")
    result = galileo.infer(scene, "demo/video.mp4")
    print(result)
    idata = result.to_arviz()
"""
__version__ = "0.1.0"

API = ("load_scene", "load_tracks", "track", "infer", "load_result", "predict", "experiment", "calibrate", "Result",
       "GalileoError")
__all__ = [*API, "__version__"]


def __getattr__(name):   # (lazily: `import galileo` stays light; the API imports torch, pybullet, ... when used)
    if name == "GalileoError":
        from .errors import GalileoError

        return GalileoError
    if name in API:
        from . import api

        return getattr(api, name)
    raise AttributeError(f"module 'galileo' has no attribute {name!r}")
