"""What a real camera does to a rendered video (`galileo dataset --camera NAME`): footage that
looks filmed by a phone, a webcam or a hand, over a scene whose truth is unchanged.

A video's `CameraEffects` say how strong each effect is (0: off); `Footage` applies them to
one video's rendered (pinhole) frames, deterministically per the video's seed, and records
what it did (`Footage.to_json`: the parameters, the camera's path and gains per frame) for
truth.json. The effects, in the order a camera applies them:

* distractors, in the world (drawn first, into the render): `shadow` (a passer-by's soft
  shadow crossing the background: its darkening at the core), `person` (a person-sized,
  out-of-focus dark shape walking through the background: its opacity) and `hand` (a
  skin-coloured hand with fingers reaching in from the frame's edge for part of the video: its
  opacity). They stay out of the objects' way: each keeps KEEP_OUT_PX clear of the union over
  the video of the objects' masks (the renderer's segmentation), exactly (their alpha fades
  to 0 there), placed where they overlap that region least (DISTRACTOR_TRIES draws);
* shake (`shake_px`, `shake_roll_deg`): the camera moves, the picture with it - a smooth path
  of translation (px, RMS length) and roll about the principal point (deg, RMS), each axis a
  sum of SHAKE_WAVES sinusoids at SHAKE_HZ, zero at frame 0 (the scene file's camera is the
  first frame's: where a user clicks its calibration). A point the still camera sees at p is
  seen at R(roll) (p - c) + c + shift (x right, y down; positive roll turns the picture
  clockwise);
* lens (`lens_k1`): radial distortion, `galileo.camera`'s model: each output pixel samples the
  pinhole image at `Camera.undistort_px` of itself (one remap with the shake). The video's
  scene.json carries the k1 (`Footage.camera`);
* vignetting (`vignette`): radial darkening, 1 - vignette (r / r_corner)^2 from the image's
  centre, the given share at the corners;
* exposure (`exposure_drift`: a slow sinusoid at DRIFT_HZ), mains flicker (`flicker`: 100/120 Hz
  light aliased by the frame rate into a beat at FLICKER_BEAT_HZ) and white balance
  (`whitebalance_drift`: the red and blue gains, slow sinusoids at WHITE_BALANCE_HZ): per-frame
  channel gains, each effect's amplitude a share;
* sensor noise (`noise_read_sd`, `noise_gain`): per pixel and channel, sd^2 = read^2 + gain *
  level (8-bit levels, the level after the gains), a little spatially correlated like a
  demosaiced sensor's (white noise filtered by NOISE_KERNEL, scaled to keep that sd);
* H.264 (`h264_kbps`): encoded at this average bitrate for 640 x 480 at 30 fps (scaled by the
  pixel rate for other sizes) instead of the clean videos' crf 18;
* motion blur (`blur_exposure`, a share of the frame interval): the renderer's, from sub-frame
  renders (`galileo.render.blur_offsets`, `Footage.blur_sampling`).

Presets (`PRESETS`; the numbers are the fields above):

* clean    - all off (the videos as they always were, byte for byte);
* phone    - a phone on a table indoors: noise read 2, gain 0.1 (sd 4 at level 128), H.264 1800
             kbit/s, exposure drift 0.03, flicker 0.015, white balance 0.03, shake 0.5 px and 0.03
             deg, blur 0.5 (1/60 s), lens k1 -0.05, vignette 0.2;
* webcam   - a webcam: noise read 4, gain 0.25 (sd 7 at 128), H.264 1000 kbit/s, flicker 0.03,
             shake 0.2 px, vignette 0.3, a passer-by (person 1);
* handheld - a phone held in a hand: shake 1.5 px and 0.2 deg, blur 0.5, noise read 2, gain 0.1,
             H.264 1800 kbit/s, a passing shadow 0.3.

Each effect alone, at its strongest documented level (`EFFECTS`): noise (read 4, gain 0.25),
h264 (1000 kbit/s), exposure (0.04), flicker (0.03), whitebalance (0.04), shake (1.5 px, 0.2
deg), blur (0.5), lens (k1 -0.15), vignette (0.35), shadow (0.35), person (1), hand (1).
`NAME:LEVEL` (LEVEL in [0, 1]) scales any of these names: `shake:0.5` is half of shake. A level
scales every amplitude, share and opacity, the noise's sd (its gain by the level squared) and
k1; a bitrate is divided by it (half as hard: twice the bits); blur's exposure is rounded to
whole pairs of physics steps (`blur_sampling`).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Iterable, Iterator

import cv2
import numpy as np

from .camera import Camera
from .errors import GalileoError
from .render import blur_offsets

KEEP_OUT_PX = 24                       # distractors stay this far from every pixel an object covers in the render
FADE_PX = 8                            # ... their alpha fading to 0 over this many pixels further out
DISTRACTOR_TRIES = 16                  # placements drawn per distractor; the one overlapping the objects least
DRAW_SCALE = 2                         # distractors are drawn at 1/this resolution (soft shapes), then resized
SHAKE_HZ, SHAKE_WAVES = (0.5, 4.0), 4  # shake: sinusoids at log-uniform frequencies in this band, amplitudes ~ 1/f
DRIFT_HZ = (0.1, 0.3)                  # exposure drift's frequency
WHITE_BALANCE_HZ = (0.05, 0.2)         # the red and blue gains' frequencies
FLICKER_BEAT_HZ = (2.0, 5.0)           # mains flicker as the frame rate aliases it
NOISE_KERNEL = np.array([0.25, 0.5, 0.25]) / math.sqrt(0.375)   # separable, unit energy: the sd is kept
REFERENCE_PIXEL_RATE = 640 * 480 * 30.0   # the pixel rate bitrates are stated for
PERSON_RGB = ((38, 38, 46), (60, 48, 40), (30, 44, 70), (70, 70, 74))
SKIN_RGB = ((224, 172, 140), (198, 140, 104), (150, 102, 72), (236, 192, 164))
HAND_SHARE = 0.5                       # the hand is in the picture this share of the video ...
HAND_MOVE_S = 0.3                      # ... sliding in and out over this long
SHARES = ("exposure_drift", "flicker", "whitebalance_drift", "blur_exposure", "lens_k1", "vignette", "shadow",
          "person", "hand")            # CameraEffects' fields that are shares (|value| at most 1)


@dataclass(frozen=True)
class CameraEffects:
    """How strong each camera effect is (0: off; see the module for what each does)."""
    noise_read_sd: float = 0.0        # sensor read noise (8-bit levels)
    noise_gain: float = 0.0           # shot noise: variance per level (sd^2 = read^2 + gain * level)
    h264_kbps: float = 0.0            # H.264 average bitrate at 640 x 480, 30 fps (0: crf 18, the clean videos')
    exposure_drift: float = 0.0       # slow exposure drift: amplitude (share)
    flicker: float = 0.0              # mains flicker: amplitude (share)
    whitebalance_drift: float = 0.0   # slow red and blue gains: amplitude (share)
    shake_px: float = 0.0             # smooth camera shake: RMS length of the translation (px)
    shake_roll_deg: float = 0.0       # ... and RMS roll (deg)
    blur_exposure: float = 0.0        # motion blur: the shutter open this share of the frame interval
    lens_k1: float = 0.0              # radial lens distortion (galileo.camera's k1; < 0: barrel)
    vignette: float = 0.0             # darkening at the image's corners (share)
    shadow: float = 0.0               # a passer-by's shadow: darkening at its core (share)
    person: float = 0.0               # a person walking through the background: opacity
    hand: float = 0.0                 # a hand at the frame's edge: opacity

    def __post_init__(self):
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            top = 1.0 if f.name in SHARES else math.inf
            low = -top if f.name == "lens_k1" else 0.0
            if not (math.isfinite(v) and low <= v <= top):
                raise GalileoError(f"camera effect {f.name} = {v!r} is outside [{low:g}, {top:g}]")

    def scaled(self, level: float) -> "CameraEffects":
        """These effects at `level` (0 to 1) of their strength (see the module)."""
        out = {f.name: getattr(self, f.name) * level for f in dataclasses.fields(self)}
        out["noise_gain"] = self.noise_gain * level ** 2
        out["h264_kbps"] = self.h264_kbps / level if level > 0 else 0.0
        return CameraEffects(**out)

    @property
    def distractors(self) -> bool:
        return bool(self.shadow or self.person or self.hand)


PRESETS: dict[str, CameraEffects] = {
    "clean": CameraEffects(),
    "phone": CameraEffects(noise_read_sd=2.0, noise_gain=0.1, h264_kbps=1800.0, exposure_drift=0.03, flicker=0.015,
                           whitebalance_drift=0.03, shake_px=0.5, shake_roll_deg=0.03, blur_exposure=0.5,
                           lens_k1=-0.05, vignette=0.2),
    "webcam": CameraEffects(noise_read_sd=4.0, noise_gain=0.25, h264_kbps=1000.0, flicker=0.03, shake_px=0.2,
                            vignette=0.3, person=1.0),
    "handheld": CameraEffects(shake_px=1.5, shake_roll_deg=0.2, blur_exposure=0.5, noise_read_sd=2.0, noise_gain=0.1,
                              h264_kbps=1800.0, shadow=0.3),
}
EFFECTS: dict[str, CameraEffects] = {
    "noise": CameraEffects(noise_read_sd=4.0, noise_gain=0.25),
    "h264": CameraEffects(h264_kbps=1000.0),
    "exposure": CameraEffects(exposure_drift=0.04),
    "flicker": CameraEffects(flicker=0.03),
    "whitebalance": CameraEffects(whitebalance_drift=0.04),
    "shake": CameraEffects(shake_px=1.5, shake_roll_deg=0.2),
    "blur": CameraEffects(blur_exposure=0.5),
    "lens": CameraEffects(lens_k1=-0.15),
    "vignette": CameraEffects(vignette=0.35),
    "shadow": CameraEffects(shadow=0.35),
    "person": CameraEffects(person=1.0),
    "hand": CameraEffects(hand=1.0),
}
NAMES = (*PRESETS, *EFFECTS)


def effects_from_name(name: str) -> CameraEffects:
    """The effects a camera name stands for: a preset or an effect, optionally `:LEVEL` (see the
    module); a one-line GalileoError listing the names for anything else."""
    base, sep, level_text = str(name).partition(":")
    level = 1.0
    if sep:
        try:
            level = float(level_text)
        except ValueError:
            level = math.nan
    effects = {**PRESETS, **EFFECTS}.get(base)
    if effects is None:
        raise GalileoError(f"unknown camera {name!r}; expected one of {', '.join(NAMES)}, optionally with a level "
                           "in [0, 1] (e.g. shake:0.5)")
    if not 0.0 <= level <= 1.0:
        raise GalileoError(f"camera {name!r}: the level {level_text!r} is not a number in [0, 1] (1: the strongest "
                           f"documented {base!r}; e.g. {base}:0.5)")
    return effects if level == 1.0 else effects.scaled(level)


def blur_sampling(effects: CameraEffects, steps_per_frame: int) -> tuple[int, np.ndarray] | None:
    """Motion blur's sub-frame sampling for a video simulated at `steps_per_frame` physics steps a
    frame: `galileo.render.blur_offsets` (n, k) with n = steps_per_frame, the exposure rounded
    to a whole number of step pairs; None: no blur (off, or shorter than two steps)."""
    half = round(effects.blur_exposure * steps_per_frame / 2)
    if half == 0:
        return None
    return blur_offsets(2 * half / steps_per_frame, 2 * half + 1)


def _waves(rng: np.random.Generator, t_s: np.ndarray, rms: float, band_hz: tuple[float, float],
           n: int) -> np.ndarray:
    """A smooth random path over times t_s, zero at t = 0: n sinusoids at log-uniform frequencies
    in band_hz, amplitudes ~ 1/f scaled so that its mean square over a long time is rms^2 (each
    sin(w t + phi) - sin(phi) contributes its amplitude squared)."""
    f = np.exp(rng.uniform(math.log(band_hz[0]), math.log(band_hz[1]), n))
    phase = rng.uniform(0, 2 * math.pi, n)
    amp = 1.0 / f
    amp *= rms / math.sqrt(float((amp ** 2).sum()))
    return (amp * (np.sin(2 * math.pi * f * t_s[:, None] + phase) - np.sin(phase))).sum(axis=1)


def _sinusoid(rng: np.random.Generator, t_s: np.ndarray, amplitude: float, band_hz: tuple[float, float]) -> np.ndarray:
    """1 + amplitude sin(2 pi f t + phi), f uniform in band_hz, phi uniform."""
    f, phase = rng.uniform(*band_hz), rng.uniform(0, 2 * math.pi)
    return 1.0 + amplitude * np.sin(2 * math.pi * f * t_s + phase)


class Footage:
    """One video's camera: `effects` over the video of (pinhole) camera `cam` (its n_frames), drawn
    from `seed` (each effect its own stream: turning one on changes no other). The renderer
    renders through `render_camera`: `cam` grown by `pad_px` on every side where the lens or the
    shake bring in what lies beyond the picture (no mirrored or smeared borders)."""

    def __init__(self, effects: CameraEffects, cam: Camera, seed: int):
        self.effects, self.seed = effects, int(seed)
        self.camera = dataclasses.replace(cam, k1=effects.lens_k1) if effects.lens_k1 else cam
        self.size = (cam.height_px, cam.width_px)
        self.centre_px = np.asarray(cam.K[:2, 2], float)
        n = cam.n_frames
        t = np.arange(n) / cam.fps
        fx = effects
        self.shift_px = np.zeros((n, 2))
        self.roll_deg = np.zeros(n)
        if fx.shake_px:
            rng = self._rng("shake")
            self.shift_px = np.stack([_waves(rng, t, fx.shake_px / math.sqrt(2), SHAKE_HZ, SHAKE_WAVES)
                                      for _ in range(2)], axis=1)
        if fx.shake_roll_deg:
            self.roll_deg = _waves(self._rng("roll"), t, fx.shake_roll_deg, SHAKE_HZ, SHAKE_WAVES)
        gain = np.ones((n, 3))
        if fx.exposure_drift:
            gain *= _sinusoid(self._rng("exposure"), t, fx.exposure_drift, DRIFT_HZ)[:, None]
        if fx.flicker:
            gain *= _sinusoid(self._rng("flicker"), t, fx.flicker, FLICKER_BEAT_HZ)[:, None]
        if fx.whitebalance_drift:
            rng = self._rng("whitebalance")
            for c in (0, 2):
                gain[:, c] *= _sinusoid(rng, t, fx.whitebalance_drift, WHITE_BALANCE_HZ)
        self.gain_rgb = gain
        self._noise_rng = self._rng("noise")
        h, w = self.size
        v, u = np.mgrid[0:h, 0:w].astype(np.float64)
        grid = np.stack([u, v], axis=-1)
        lens = self.camera.undistort_px(grid) if fx.lens_k1 else grid
        self._lens_px = lens.astype(np.float32)
        self.pad_px = 0
        if fx.lens_k1 or fx.shake_px or fx.shake_roll_deg:
            beyond = max(0.0, -lens.min(), float((lens[..., 0] - (w - 1)).max()), float((lens[..., 1] - (h - 1)).max()))
            d = float(np.linalg.norm(self.shift_px, axis=1).max())
            r = float(np.linalg.norm(lens - self.centre_px, axis=-1).max()) + d
            self.pad_px = math.ceil(beyond + d + r * math.radians(float(np.abs(self.roll_deg).max()))) + 2
        k = cam.K.copy()
        k[:2, 2] += self.pad_px
        self.render_camera = dataclasses.replace(cam, K=k, width_px=w + 2 * self.pad_px, height_px=h + 2 * self.pad_px)
        self._vignette = None
        if fx.vignette:
            r2 = ((u - (w - 1) / 2) ** 2 + (v - (h - 1) / 2) ** 2) / (((w - 1) / 2) ** 2 + ((h - 1) / 2) ** 2)
            self._vignette = (1.0 - fx.vignette * r2).astype(np.float32)[..., None]
        self._distractors: list = []

    def _rng(self, what: str) -> np.random.Generator:
        return np.random.default_rng([self.seed, 29, *what.encode()])

    @property
    def bitrate_kbps(self) -> float | None:
        """The encoder's bitrate for this video (kbit/s; None: the clean videos' crf)."""
        if not self.effects.h264_kbps:
            return None
        h, w = self.size
        return self.effects.h264_kbps * h * w * self.camera.fps / REFERENCE_PIXEL_RATE

    def blur_sampling(self, steps_per_frame: int) -> tuple[int, np.ndarray] | None:
        return blur_sampling(self.effects, steps_per_frame)

    def to_json(self) -> dict:
        """What this camera did: the effects' parameters, the encoder's bitrate, the shake per frame
        (shift_px [dx, dy], roll_deg about centre_px: where a point the still camera sees at p is
        seen, see the module) and the channel gains per frame (exposure x flicker x white balance)."""
        return {"effects": dataclasses.asdict(self.effects), "seed": self.seed, "bitrate_kbps": self.bitrate_kbps,
                "centre_px": self.centre_px.tolist(), "shift_px": self.shift_px.tolist(),
                "roll_deg": self.roll_deg.tolist(), "gain_rgb": self.gain_rgb.tolist()}

    # -- applying it --------------------------------------------------------------------------------
    def frames(self, frames_rgb: Iterable[np.ndarray], objects_px: np.ndarray | None = None) -> Iterator[np.ndarray]:
        """The frames rendered through `render_camera` (RGB uint8, in order) as this camera films
        them (the video's size). objects_px: bool, the render's size, every pixel an object covers
        in some frame (needed for distractors). Clean effects give the frames themselves."""
        if self.effects == CameraEffects():
            yield from frames_rgb
            return
        if self.effects.distractors:
            if objects_px is None:
                raise ValueError("distractors need the objects' pixels (objects_px)")
            self._place_distractors(objects_px)
        for f, rgb in enumerate(frames_rgb):
            yield self.frame(f, rgb)

    def frame(self, f: int, rgb: np.ndarray) -> np.ndarray:
        """Frame f through the camera (see `frames`; distractors once placed)."""
        fx, pad = self.effects, self.pad_px
        h, w = self.size
        if rgb.shape[:2] != (h + 2 * pad, w + 2 * pad):
            raise ValueError(f"frame {f} is {rgb.shape[1]}x{rgb.shape[0]}, not the render camera's "
                             f"{w + 2 * pad}x{h + 2 * pad}")
        img = rgb.astype(np.float32)
        for d in self._distractors:
            d.draw(img, f)
        roll, (dx, dy) = math.radians(self.roll_deg[f]), map(float, self.shift_px[f])
        if fx.lens_k1 or roll or dx or dy:
            cx, cy = map(float, self.centre_px)     # (python floats keep the maps float32)
            px, py = self._lens_px[..., 0] - (cx + dx), self._lens_px[..., 1] - (cy + dy)
            c, s = math.cos(roll), math.sin(roll)
            img = cv2.remap(img, c * px + s * py + (cx + pad), c * py - s * px + (cy + pad), cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_REPLICATE)
        elif pad:
            img = img[pad:pad + h, pad:pad + w]
        if self._vignette is not None:
            img *= self._vignette
        if not np.all(self.gain_rgb[f] == 1.0):
            img *= self.gain_rgb[f].astype(np.float32)
        if fx.noise_read_sd or fx.noise_gain:
            z = self._noise_rng.standard_normal((h + 2, w + 2, 3), dtype=np.float32)
            z = cv2.sepFilter2D(z, -1, NOISE_KERNEL, NOISE_KERNEL)[1:-1, 1:-1]
            img += z * np.sqrt(fx.noise_read_sd ** 2 + fx.noise_gain * np.clip(img, 0, 255))
        return np.clip(img + 0.5, 0, 255).astype(np.uint8)

    def _place_distractors(self, objects_px: np.ndarray) -> None:
        """Each distractor's path, where it overlaps the objects' region (grown by KEEP_OUT_PX) least,
        and the fade that keeps it off that region."""
        size = h, w = objects_px.shape
        near = cv2.dilate(objects_px.astype(np.uint8), _disk(KEEP_OUT_PX + FADE_PX))
        fade = cv2.GaussianBlur((1 - near).astype(np.float32), (2 * FADE_PX + 1, 2 * FADE_PX + 1), FADE_PX / 3)
        forbidden = cv2.resize(cv2.dilate(objects_px.astype(np.uint8), _disk(KEEP_OUT_PX)),
                               (w // DRAW_SCALE, h // DRAW_SCALE), interpolation=cv2.INTER_AREA) > 0
        n = len(self.roll_deg)
        self._distractors = []
        for kind, cls in (("shadow", _Shadow), ("person", _Person), ("hand", _Hand)):
            strength = getattr(self.effects, kind)
            if not strength:
                continue
            rng = self._rng(kind)
            tries = [cls(rng, n, size, self.camera.fps, strength, fade) for _ in range(DISTRACTOR_TRIES)]
            self._distractors.append(min(tries, key=lambda d: d.overlap(forbidden)))


def _disk(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


class _Distractor:
    """A shape moving through the picture: alpha(f) at 1/DRAW_SCALE resolution, drawn over a frame
    (`draw`) faded off the objects' region."""
    SAMPLES = 8      # frames its overlap with the objects is measured on

    def __init__(self, n_frames: int, size: tuple[int, int], strength: float, fade: np.ndarray):
        self.n, self.size, self.strength, self.fade = n_frames, size, strength, fade

    def alpha(self, f: int) -> np.ndarray | None:   # pragma: no cover - each kind's own
        raise NotImplementedError

    def overlap(self, forbidden: np.ndarray) -> float:
        """Its share on the forbidden pixels, over SAMPLES frames (its whole mass: 1 when unseen)."""
        on, total = 0.0, 0.0
        for f in np.linspace(0, self.n - 1, self.SAMPLES).round().astype(int):
            a = self.alpha(int(f))
            if a is not None:
                on += float(a[forbidden].sum())
                total += float(a.sum())
        return on / total if total > 0 else 1.0

    def full_alpha(self, f: int) -> np.ndarray | None:
        a = self.alpha(f)
        if a is None:
            return None
        h, w = self.size
        return (cv2.resize(a, (w, h), interpolation=cv2.INTER_LINEAR) * self.fade * self.strength)[..., None]

    def canvas(self) -> np.ndarray:
        h, w = self.size
        return np.zeros((h // DRAW_SCALE, w // DRAW_SCALE), np.float32)


def _ellipse(img: np.ndarray, centre, axes, angle_deg: float) -> None:
    """A filled ellipse (1.0) on a 1/DRAW_SCALE canvas, in full-resolution pixels (sub-pixel)."""
    s, shift = 1.0 / DRAW_SCALE, 4
    c = tuple(round(v * s * (1 << shift)) for v in centre)
    a = tuple(max(1, round(v * s * (1 << shift))) for v in axes)
    cv2.ellipse(img, c, a, float(angle_deg), 0, 360, 1.0, -1, cv2.LINE_AA, shift)


class _Crossing(_Distractor):
    """A shape crossing the picture sideways over the whole video, from beyond one side to beyond
    the other, at a drawn height and size."""

    def __init__(self, rng, n_frames, size, fps, strength, fade):
        super().__init__(n_frames, size, strength, fade)
        h, w = size
        self.scale = float(rng.uniform(0.4, 1.0))
        self.y = float(rng.uniform(0.15, 0.85)) * h
        self.x0, self.x1 = (-0.3 * w, 1.3 * w) if rng.uniform() < 0.5 else (1.3 * w, -0.3 * w)
        self.fps = fps

    def x(self, f: int) -> float:
        return self.x0 + (self.x1 - self.x0) * f / max(1, self.n - 1)


class _Shadow(_Crossing):
    """A passer-by's shadow: a large soft dark ellipse, its edge a smoothstep over SOFTNESS of its
    radius either side (darkens: `strength` at its core)."""
    SOFTNESS = 0.35

    def alpha(self, f):
        h, w = self.size
        k = h * self.scale
        v, u = np.ogrid[0:h:DRAW_SCALE, 0:w:DRAW_SCALE]
        rho = np.sqrt(((u - self.x(f)) / (0.22 * k)) ** 2 + ((v - self.y) / (0.5 * k)) ** 2).astype(np.float32)
        t = np.clip((1 + self.SOFTNESS - rho) / (2 * self.SOFTNESS), 0, 1)
        return t * t * (3 - 2 * t)

    def draw(self, img, f):
        a = self.full_alpha(f)
        if a is not None:
            img *= 1.0 - a


class _Person(_Crossing):
    """A person walking through the background, out of focus: head, body and legs in one dark
    colour, bobbing with the gait."""

    def __init__(self, rng, n_frames, size, fps, strength, fade):
        super().__init__(rng, n_frames, size, fps, strength, fade)
        self.rgb = np.asarray(PERSON_RGB[int(rng.integers(len(PERSON_RGB)))], np.float32)
        self.step_hz = float(rng.uniform(1.6, 2.2))

    def alpha(self, f):
        h, _ = self.size
        k = h * self.scale
        x, y = self.x(f), self.y + 0.01 * k * math.sin(2 * math.pi * self.step_hz * f / self.fps)
        a = self.canvas()
        _ellipse(a, (x, y - 0.42 * k), (0.07 * k, 0.09 * k), 0.0)           # head
        _ellipse(a, (x, y - 0.08 * k), (0.15 * k, 0.27 * k), 0.0)           # body
        swing = 8.0 * math.sin(2 * math.pi * self.step_hz * f / self.fps)
        for side in (-1, 1):                                                 # legs
            _ellipse(a, (x + side * 0.06 * k, y + 0.38 * k), (0.06 * k, 0.3 * k), side * swing)
        return cv2.GaussianBlur(a, (0, 0), 0.02 * k / DRAW_SCALE + 1.0)

    def draw(self, img, f):
        a = self.full_alpha(f)
        if a is not None:
            img += a * (self.rgb - img)


class _Hand(_Distractor):
    """A hand reaching in from an edge of the frame (palm, four fingers, a thumb, the forearm out
    of the picture) for HAND_SHARE of the video, sliding in and out over HAND_MOVE_S, skin-coloured
    with soft edges, darker towards its outline."""

    def __init__(self, rng, n_frames, size, fps, strength, fade):
        super().__init__(n_frames, size, strength, fade)
        h, w = size
        side = int(rng.integers(4))                           # the edge it comes from: left, right, top, bottom
        along = float(rng.uniform(0.2, 0.8))
        self.inward = np.array([(1, 0), (-1, 0), (0, 1), (0, -1)][side], float)
        self.edge = np.array([(0, along * h), (w, along * h), (along * w, 0), (along * w, h)][side], float)
        self.rgb = np.asarray(SKIN_RGB[int(rng.integers(len(SKIN_RGB)))], np.float32)
        self.reach = float(rng.uniform(0.0, 0.08)) * h
        stay = max(1, round(HAND_SHARE * n_frames))
        self.first = int(rng.integers(0, max(1, n_frames - stay) + 1))
        self.last = self.first + stay
        self.move = max(1.0, HAND_MOVE_S * fps)

    def depth(self, f: int) -> float | None:
        """How far in (0: out of the picture, 1: fully in) at frame f; None: away."""
        if not self.first <= f < self.last:
            return None
        return min(1.0, (f - self.first + 1) / self.move, (self.last - f) / self.move)

    def alpha(self, f):
        share = self.depth(f)
        if share is None:
            return None
        h, _ = self.size
        d, n = self.inward, np.array([-self.inward[1], self.inward[0]])
        wrist = self.edge + d * (share * (0.05 * h + self.reach) - (1 - share) * 0.35 * h)
        angle = math.degrees(math.atan2(d[1], d[0]))
        a = self.canvas()
        _ellipse(a, wrist - 0.3 * h * d, (0.34 * h, 0.07 * h), angle)                   # forearm
        _ellipse(a, wrist + 0.06 * h * d, (0.09 * h, 0.085 * h), angle)                  # palm
        for i in range(4):                                                               # fingers
            base = wrist + 0.14 * h * d + (i - 1.5) * 0.04 * h * n
            spread = (i - 1.5) * 6.0
            tip = np.array([math.cos(math.radians(angle + spread)), math.sin(math.radians(angle + spread))])
            _ellipse(a, base + (0.05 - 0.008 * abs(i - 1.5)) * h * tip, (0.06 * h, 0.018 * h), angle + spread)
        _ellipse(a, wrist + 0.05 * h * d + 0.1 * h * n, (0.05 * h, 0.02 * h), angle + 50.0)   # thumb
        return cv2.GaussianBlur(a, (0, 0), 1.5)

    def draw(self, img, f):
        a = self.full_alpha(f)
        if a is not None:
            shade = 0.8 + 0.2 * np.minimum(1.0, cv2.GaussianBlur(a[..., 0], (0, 0), 6.0) * 1.6)[..., None]
            img += a * (self.rgb * shade - img)


__all__ = ["CameraEffects", "EFFECTS", "Footage", "NAMES", "PRESETS", "blur_sampling", "effects_from_name"]
