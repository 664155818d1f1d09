"""What every scenario renders its videos with: pybullet's TinyRenderer through a scene's camera.

The renderer looks through the scene's calibrated pinhole camera (OpenCV convention);
`gl_view_projection` converts K and the world->camera transform into the OpenGL
matrices pybullet expects, so that `Camera.project` of a body's centre lands on the
body in the rendered image (tested against the renderer's segmentation mask).

Objects get procedural block textures (`block_texture`: corners for the KLT tracker),
surfaces mild grain (`grain_texture`), both loaded with `load_texture`. Each video has its
own `Look`: light direction, ambient and diffuse levels (`camera_image` draws with them), a
slow brightness drift (`Look.gain`) and Gaussian sensor noise. Motion blur: a frame is the
average of renders at sub-frame times over an exposure centred on the frame's time
(`blur_offsets`, `average_renders`). A scenario's own `render.py`
builds its world's appearance from these (galileo/scenarios/ramp/render.py,
galileo/scenarios/splash/render.py).
"""
from __future__ import annotations

import hashlib
import math
import os
from dataclasses import dataclass

import cv2
import numpy as np

from .camera import Camera
from .sim.bullet import pb, scratch_dir

NEAR_M, FAR_M = 0.05, 20.0
# TinyRenderer's rasterisation puts a projected point this far (pixels) from where the
# OpenCV convention (pixel centres at integer coordinates) does; measured on silhouettes
# (tests/test_render.py) and compensated so renders agree with Camera.project.
RASTER_OFFSET_PX = (0.0, 1.0)
SPECULAR = 0.05              # the lights' specular coefficient (every look)
DRIFT_PERIOD_FRAMES = 47.0   # the brightness drift's period
BLUR_EXPOSURE = 0.5          # motion blur: the shutter is open this share of the frame interval ...
BLUR_RENDERS = 5             # ... and a frame averages this many renders over it


def gl_view_projection(cam: Camera, near: float = NEAR_M, far: float = FAR_M) -> tuple[list[float], list[float]]:
    """pybullet view and projection matrices (column-major) for an OpenCV pinhole camera.

    Always the pinhole: OpenGL's projection is linear and cannot bend lines, so the camera's
    lens distortion (`Camera.k1`) is ignored here; a render through a lens is this pinhole
    render remapped through `Camera.undistort_px` (each output pixel samples the pinhole image
    where the lens's ray lands)."""
    flip = np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV camera axes -> OpenGL camera axes
    view = flip @ cam.world_to_camera
    (fx, _, cx), (_, fy, cy), _ = cam.K
    cx, cy = cx + RASTER_OFFSET_PX[0], cy + RASTER_OFFSET_PX[1]
    w, h = cam.width_px, cam.height_px
    proj = np.array([
        [2 * fx / w, 0, 1 - 2 * cx / w, 0],
        [0, 2 * fy / h, 2 * cy / h - 1, 0],
        [0, 0, -(far + near) / (far - near), -2 * far * near / (far - near)],
        [0, 0, -1, 0]])
    return view.T.reshape(-1).tolist(), proj.T.reshape(-1).tolist()


def block_texture(rgb: tuple[int, int, int], rng: np.random.Generator, blocks: int = 4, px: int = 128,
                  contrast: float = 0.55) -> np.ndarray:
    """A tile of random light/dark blocks around `rgb`: strong corners for feature tracking."""
    base = np.asarray(rgb, float)
    levels = rng.uniform(1 - contrast, 1 + contrast * 0.6, (blocks, blocks, 1))
    tint = rng.uniform(0.85, 1.15, (blocks, blocks, 3))
    tile = np.clip(base * levels * tint, 0, 255)
    img = cv2.resize(tile.astype(np.uint8), (px, px), interpolation=cv2.INTER_NEAREST)
    return img


def grain_texture(rgb: tuple[int, int, int], rng: np.random.Generator, px: int = 256, strength: float = 10.0,
                  streaks: bool = False) -> np.ndarray:
    """A tile of smooth noise around `rgb` (wood-like streaks along x with `streaks`): a surface's
    texture, faint enough not to draw the tracker's features."""
    noise = rng.normal(0, 1, (px // 8, px // 8))
    noise = cv2.resize(noise, (px, px), interpolation=cv2.INTER_CUBIC)
    if streaks:
        noise = cv2.GaussianBlur(noise, (0, 0), sigmaX=px / 16, sigmaY=0.5)
        noise /= noise.std() + 1e-9
    img = np.asarray(rgb, float) + strength * noise[..., None]
    return np.clip(img, 0, 255).astype(np.uint8)


def load_texture(img_rgb: np.ndarray, name: str, cid: int) -> int:
    """Write the texture to a PNG (whole, then renamed into place) and load it into client `cid`;
    its pybullet texture id. The file is named by its content too: pybullet keeps a texture by its
    path for the process's life, so a second scene's texture of the same name (another object
    under the same seed) would have been drawn with the first's."""
    digest = hashlib.sha256(np.ascontiguousarray(img_rgb).tobytes() + repr(img_rgb.shape).encode()).hexdigest()[:16]
    path = scratch_dir() / f"{name}_{digest}.png"
    tmp = path.with_name(f".{path.stem}.tmp.png")
    if not cv2.imwrite(str(tmp), img_rgb[..., ::-1]):
        raise RuntimeError(f"cannot write texture {tmp}")
    os.replace(tmp, path)
    tex = pb.loadTexture(str(path), physicsClientId=cid)
    if tex < 0:
        raise RuntimeError(f"pybullet could not load texture {path}")
    return tex


@dataclass
class Look:
    """Per-video appearance: light, exposure drift and sensor noise."""
    light_dir: tuple[float, float, float]
    ambient: float
    diffuse: float
    gain_drift: float      # amplitude of slow brightness drift (fraction)
    noise_sd: float        # sensor noise, 8-bit levels
    seed: int

    @classmethod
    def random(cls, rng: np.random.Generator) -> "Look":
        az = rng.uniform(-0.8, 0.8)
        return cls((math.sin(az), -1.2, 2.0 + rng.uniform(-0.3, 0.3)), float(rng.uniform(0.55, 0.7)),
                   float(rng.uniform(0.35, 0.5)), float(rng.uniform(0.005, 0.02)), float(rng.uniform(1.5, 3.0)),
                   int(rng.integers(2**31)))

    def gain(self, frame_index: int) -> float:
        """The exposure's gain in video frame `frame_index` (1 without drift)."""
        return 1.0 + self.gain_drift * math.sin(2 * math.pi * frame_index / DRIFT_PERIOD_FRAMES + self.seed % 7)


def blur_offsets(exposure: float = BLUR_EXPOSURE, renders: int = BLUR_RENDERS) -> tuple[int, np.ndarray]:
    """Motion blur's sampling: (n, k) such that the frame at time t averages the renders at
    t + k / (n fps), k integers centred on 0 (an exposure of `exposure` frame intervals centred
    on the frame's time, `renders` evenly spaced samples). Simulating at n times the video's
    rate gives every sample's pose. The defaults: n = 8, k = -2..2."""
    n = (renders - 1) / exposure
    if renders < 3 or renders % 2 == 0 or abs(n - round(n)) > 1e-9:
        raise ValueError(f"motion blur takes an odd number (3 or more) of renders a whole number of sub-frames "
                         f"apart, got {renders} over {exposure} of a frame")
    return round(n), np.arange(renders) - (renders - 1) // 2


def average_renders(images: list[np.ndarray]) -> np.ndarray:
    """A blurred frame (float32) from its sub-frame renders (each (H, W, C)): their mean, the light
    each pixel gathers while the shutter is open."""
    out = np.zeros(images[0].shape, np.float32)
    for img in images:
        out += img
    return out / len(images)


DEFAULT_LOOK = Look((0.3, -1.2, 2.0), 0.6, 0.45, 0.0, 0.0, 0)   # fixed light, no drift, no noise


def camera_image(cam: Camera, view: list[float], proj: list[float], look: Look,
                 cid: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """TinyRenderer's image of client `cid`'s world through `cam` (its `gl_view_projection`) lit
    by `look`, before drift and noise: RGBA uint8 (H, W, 4), the depth buffer float32 (H, W) and
    the segmentation int32 (H, W) of body ids."""
    h, w = cam.height_px, cam.width_px
    _, _, rgba, depth, seg = pb.getCameraImage(
        w, h, view, proj, renderer=pb.ER_TINY_RENDERER, lightDirection=list(look.light_dir),
        lightAmbientCoeff=look.ambient, lightDiffuseCoeff=look.diffuse, lightSpecularCoeff=SPECULAR,
        shadow=0, physicsClientId=cid)
    return (np.asarray(rgba, np.uint8).reshape(h, w, 4), np.asarray(depth, np.float32).reshape(h, w),
            np.asarray(seg, np.int32).reshape(h, w))
