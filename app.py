"""Galileo app entry point: `python app.py` runs the built-in demo.

The browser viewer (viser), live priors/steering, rerun streams and recorded sessions
arrive with the app issue; until then this renders (and caches) the demo video and
says what the app will do with it.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent
DEMO_DIR = ROOT / ".cache" / "demo"


def ensure_demo(progress: bool = True) -> Path:
    """Render the demo video on first run and cache it under .cache/demo/."""
    from galileo.dataset import build

    folder = DEMO_DIR / "demo"
    if not (folder / "video.mp4").exists() or not (folder / "scene.json").exists():
        build("demo", DEMO_DIR, seed=0, workers=1, progress=progress)
    return folder


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Galileo: watch and steer physical inference from video")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=8080)
    args = parser.parse_args(argv)
    from galileo.errors import GalileoError
    from galileo.scene import Scene

    try:
        folder = ensure_demo()
        scene = Scene.load(folder / "scene.json")
    except GalileoError as e:
        print(f"app: error: {e}", file=sys.stderr)
        return 2
    print(f"demo video: {folder / 'video.mp4'} ({scene.camera.n_frames} frames at {scene.camera.fps:g} fps, "
          f"ramp {scene.ramp.angle_deg:g} deg, target {scene.target.kind if scene.target else 'none'})")
    print("The app will: track the video, run 16 MCMC chains over m1, k1, m2, k2 in background workers, "
          f"and serve the viewer on http://{args.host}:{args.port} (not built yet: see the open app issue).")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
