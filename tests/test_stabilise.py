"""Stabilisation (`galileo.vision.stabilise`) against clips synthesised with known camera motion.

A procedurally textured scene (a table seen by a phone: blurred noise at several scales,
some blocks) is cut out of a larger canvas by KNOWN similarities (1-3 px of smooth shake,
0.3 deg of roll), with a textured object sliding across it, an exposure gain per frame,
sensor noise growing with brightness and a dark shadow over 15% of the frame. The truth is
the similarity each frame was cut with, the gain it was multiplied by (BT.601: luma is
16 + 219/255 of the RGB's weighted mean, so an RGB gain g maps luma y to 16 + g (y - 16)
and chroma c to 128 + g (c - 128)), and the reference frame's own pixels.

Bounds from statistics: KLT on this texture with noise of sd 1.5-2.5 levels locates a
feature to ~0.05-0.1 px; the similarity from ~100 inliers averages that to ~0.01 px at the
centre and ~0.03 px at a corner (its lever arm): measured, RMS 0.009 px and at most 0.03 px.
We bound the RMS over frames of the centre's error by 0.1 px and each frame's worst corner
by 0.3 px (H.264 at crf 28: twice those). The luma gain from ~1500 samples of noise ~1 level
(smoothed) is within 0.1%; the synthesis's own resampling changes the texture's contrast
by ~0.5%, and a frame within 1% of the reference is left alone by design (H.264's drift):
we bound the luma map's error at levels 60-180 by 1%.
"""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from galileo.video import VideoStream, write_video
from galileo.vision.stabilise import Stabilised, apply, similarity_matrix

H, W = 240, 320          # frames (small: fast; the bench runs 640 x 480)
MARGIN = 24              # the canvas reaches this far beyond the reference frame
N_FRAMES = 24
CENTRE_RMS_PX = 0.1      # bounds, see the module docstring
CORNER_MAX_PX = 0.3
GAIN_TOL = 0.01


def _texture(rng: np.random.Generator, hw: tuple[int, int]) -> np.ndarray:
    """An RGB table top: noise blurred at several scales and a few flat blocks, levels 40-200."""
    img = np.zeros((*hw, 3), np.float32)
    for sigma, amp in ((1.5, 30.0), (4.0, 40.0), (12.0, 50.0)):
        n = cv2.GaussianBlur(rng.normal(0, 1, (*hw, 3)).astype(np.float32), (0, 0), sigma)
        img += amp * n / n.std()
    for _ in range(12):
        x, y = rng.integers(0, hw[1] - 30), rng.integers(0, hw[0] - 30)
        img[y:y + rng.integers(8, 30), x:x + rng.integers(8, 30)] += rng.uniform(-40, 40, 3)
    return np.clip(120 + img * 0.6, 40, 200)


def _shake(f: int) -> tuple[np.ndarray, float]:
    """Frame f's camera shake: a smooth translation (px) up to ~3 px and roll up to 0.3 deg."""
    if f == 0:
        return np.zeros(2), 0.0
    return np.array([2.5 * math.sin(0.5 * f) + 0.5, 1.5 * math.cos(0.35 * f) - 1.5]), 0.3 * math.sin(0.27 * f)


def true_transform(f: int) -> np.ndarray:
    """Reference pixels -> frame f's pixels (the stabiliser's convention)."""
    shift, roll = _shake(f)
    return similarity_matrix(shift, roll, 1.0, ((W - 1) / 2, (H - 1) / 2))


def synth_clip(seed: int = 0, shaken: bool = True, gains: bool = True, noise: bool = True, shadow: bool = True,
               hand_at: int | None = None) -> tuple[list[np.ndarray], np.ndarray]:
    """RGB frames (uint8) and the truth-free reference (frame 0 without noise, float RGB)."""
    rng = np.random.default_rng(seed)
    canvas = _texture(rng, (H + 2 * MARGIN, W + 2 * MARGIN))
    obj = _texture(rng, (40, 40))[..., ::-1] * 0.5 + 80   # another texture, another colour
    to_ref = similarity_matrix((-MARGIN, -MARGIN))        # canvas -> reference pixels
    frames, ref = [], None
    for f in range(N_FRAMES):
        scene = canvas.copy()
        x = MARGIN + 60 + 6 * f                            # the object slides right across the table
        scene[MARGIN + 120:MARGIN + 160, x:x + 40] = obj
        if shadow and f > 0:                               # a person's shadow over 15% of the frame
            sx = MARGIN + 150 + 2 * f
            scene[MARGIN:MARGIN + H, sx:sx + int(0.15 * W)] *= 0.55
        m = true_transform(f) if shaken else np.eye(2, 3)
        full = np.r_[m, [[0, 0, 1]]] @ np.r_[to_ref, [[0, 0, 1]]]
        img = cv2.warpAffine(scene, full[:2], (W, H), flags=cv2.INTER_LANCZOS4)
        if f == 0:
            ref = img.copy()
        if gains:
            img = img * gain_of(f)
        if noise:                                          # shot noise: grows with brightness
            img = img + rng.normal(0, 1, img.shape) * np.sqrt(1.0 + 0.02 * img)
        if hand_at is not None and f == hand_at:           # a hand over the lens
            img = cv2.GaussianBlur(rng.uniform(150, 200, img.shape).astype(np.float32), (0, 0), 8)
        frames.append(np.clip(np.round(img), 0, 255).astype(np.uint8))
    return frames, ref


def gain_of(f: int) -> float:
    """Exposure drift and flicker: a few % a frame."""
    return 1.0 if f == 0 else 1.0 + 0.04 * math.sin(0.2 * f) + 0.02 * (-1) ** f


class _Frames:
    """What Stabilised uses of a VideoStream, from RGB frames in memory."""

    def __init__(self, frames_rgb):
        self.frames = frames_rgb
        self.height_px, self.width_px = frames_rgb[0].shape[:2]
        self.fps, self.n_frames = 30.0, len(frames_rgb)

    def yuv(self):
        for rgb in self.frames:
            i420 = cv2.cvtColor(rgb, cv2.COLOR_RGB2YUV_I420)
            y = i420[:H]
            u, v = i420[H:].reshape(2, H // 2, W // 2)
            yield y, np.stack([u, v], axis=-1)


def _object_mask() -> np.ndarray:
    """The object's path in the reference frame (what a tracker would exclude)."""
    m = np.zeros((H, W), bool)
    m[110:170, 50:W] = True
    return m


def _errors(stab: Stabilised) -> tuple[np.ndarray, np.ndarray]:
    """Per frame: the frame centre's and the worst corner's distance between the recovered
    and the true transform (px)."""
    centre = np.array([[(W - 1) / 2, (H - 1) / 2]])
    corners = np.array([[0, 0], [W - 1, 0], [0, H - 1], [W - 1, H - 1]], float)
    c_err, k_err = [], []
    for f, fit in enumerate(stab.fits):
        t = true_transform(f)
        c_err.append(np.linalg.norm(apply(fit.transform, centre) - apply(t, centre)))
        k_err.append(np.linalg.norm(apply(fit.transform, corners) - apply(t, corners), axis=1).max())
    return np.array(c_err), np.array(k_err)


def test_recovers_known_shake_gains_despite_object_shadow_and_noise():
    frames, ref = synth_clip()
    stab = Stabilised(_Frames(frames), exclude=_object_mask())
    out = list(stab.yuv())
    assert stab.shown.all()
    centre, corner = _errors(stab)
    assert math.sqrt(np.mean(centre ** 2)) < CENTRE_RMS_PX, centre
    assert corner.max() < CORNER_MAX_PX, corner
    # the luma map undoes the RGB gain g: y -> 16 + (y - 16) / g (BT.601), across the levels seen
    levels = np.array([60.0, 120.0, 180.0])
    for f, fit in enumerate(stab.fits):
        seen = 16 + gain_of(f) * (levels - 16)
        mapped = fit.photo[0, 0] * seen + fit.photo[0, 1]
        assert np.abs(mapped / levels - 1).max() < GAIN_TOL, (f, mapped, levels)
    # the output is the reference where the scene is static: no bias left, only the noise
    ref_y = cv2.cvtColor(np.clip(np.round(ref), 0, 255).astype(np.uint8), cv2.COLOR_RGB2YUV_I420)[:H].astype(float)
    inner = np.zeros((H, W), bool)
    inner[MARGIN:-MARGIN, MARGIN:150] = True             # clear of the object's path, the shadow and the edges
    inner &= ~_object_mask()
    for f in range(1, N_FRAMES):
        d = out[f][0].astype(float)[inner] - ref_y[inner]
        assert abs(d.mean()) < GAIN_TOL * ref_y[inner].mean(), (f, d.mean())
    mo = stab.motion()
    true_shift = max(np.linalg.norm(_shake(f)[0]) for f in range(N_FRAMES))
    assert abs(mo.max_shift_px - true_shift) < 0.1
    assert abs(mo.max_roll_deg - max(abs(_shake(f)[1]) for f in range(N_FRAMES))) < 0.02
    notes = stab.notes()
    assert any(n.startswith("the camera moved up to") for n in notes), notes
    assert any(n.startswith("the exposure changed by up to") for n in notes), notes


def test_replayed_pass_is_the_first():
    frames, _ = synth_clip(seed=1, noise=False, shadow=False)
    stab = Stabilised(_Frames(frames))
    first = [(y.copy(), uv.copy()) for y, uv in stab.yuv()]
    fits = list(stab.fits)
    second = list(stab.yuv())
    assert len(stab.fits) == N_FRAMES and all(a is b for a, b in zip(stab.fits, fits))   # not fitted again
    assert all(np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]) for a, b in zip(first, second))


def test_still_camera_at_fixed_exposure_comes_out_bit_identical(tmp_path):
    """H.264 (as every video comes) moves a still scene's features by a few hundredths of
    a pixel and its levels by one: frames that need nothing come out as decoded."""
    frames, _ = synth_clip(seed=2, shaken=False, gains=False, shadow=False)
    write_video(tmp_path / "still.mp4", frames, 30.0, crf=28)
    video = VideoStream(tmp_path / "still.mp4")
    stab = Stabilised(video, exclude=_object_mask())
    for (y, uv), (y0, uv0) in zip(stab.yuv(), video.yuv()):
        assert np.array_equal(y, y0) and np.array_equal(uv, uv0)
    assert stab.shown.all()
    assert stab.notes() == []


def test_a_hand_over_the_lens_is_flagged_and_tracking_goes_on():
    frames, _ = synth_clip(seed=3, hand_at=10)
    stab = Stabilised(_Frames(frames), exclude=_object_mask())
    list(stab.yuv())
    assert np.flatnonzero(~stab.shown).tolist() == [10]
    centre, _ = _errors(stab)
    assert math.sqrt(np.mean(np.delete(centre, 10) ** 2)) < CENTRE_RMS_PX
    assert not any("frame 10" in n for n in stab.notes()), stab.notes()   # (the tracker's to report)


def test_noise_estimate_after_registration_is_a_still_cameras():
    """Shaken frames differ by texture at every edge; registered, they differ by the noise.
    Truth: the same clip (the same noise drawn) filmed by a still camera, whose frames 0
    and 1 measure the sensor noise (`background.noise_sd`, as the trackers do). The two
    estimates are MADs of >10^4 samples (~1.5% apart by chance); the warp's interpolation of
    the texture adds ~7%: bound 15%."""
    from galileo.vision.background import noise_sd, yuv_image

    def first_two(video):
        return [yuv_image(y, uv, 0.5) for (y, uv), _ in zip(video.yuv(), range(2))]

    still = noise_sd(first_two(_Frames(synth_clip(seed=4, shaken=False, gains=False, shadow=False)[0])))
    video = _Frames(synth_clip(seed=4, gains=False, shadow=False)[0])
    stab = Stabilised(video, exclude=_object_mask())
    list(stab.yuv())
    assert stab.noise_sd() == pytest.approx(still, rel=0.15)
    assert noise_sd(first_two(video)) > 2 * still   # what the trackers measure without it: the shake's texture


def test_h264_round_trip_of_a_shaken_clip_registers(tmp_path):
    frames, _ = synth_clip(seed=5)
    path = tmp_path / "shaken.mp4"
    write_video(path, frames, 30.0, crf=28)
    stab = Stabilised(VideoStream(path), exclude=_object_mask())
    list(stab.yuv())
    assert stab.shown.all()
    centre, corner = _errors(stab)
    assert math.sqrt(np.mean(centre ** 2)) < 2 * CENTRE_RMS_PX, centre
    assert corner.max() < 2 * CORNER_MAX_PX, corner


def test_blurred_frames_are_measured_and_noted():
    """Truth: the frames blurred (a Gaussian of sd 1.5 px: motion blur's loss of detail)."""
    frames, _ = synth_clip(seed=6, gains=False, shadow=False)
    for f in (8, 9, 10):
        frames[f] = cv2.GaussianBlur(frames[f], (0, 0), 1.5)
    stab = Stabilised(_Frames(frames), exclude=_object_mask())
    list(stab.yuv())
    assert np.flatnonzero(stab.sharpness < 0.5).tolist() == [8, 9, 10], stab.sharpness
    assert any(n.startswith("the video is blurred in frames 8-10") for n in stab.notes()), stab.notes()


def test_white_balance_drift_is_normalised():
    """A warmer then cooler white balance (red and blue gains of 1 -/+ 6%): truth is the
    reference's own chroma, which the normalised frames match where the scene is static
    (before: several levels off) to within what is left alone as H.264's drift (1% of the
    chroma's 128, 1.3 levels; plus rounding)."""
    frames, _ = synth_clip(seed=7, gains=False, shadow=False, noise=False)
    for f in range(1, N_FRAMES):
        k = 0.06 * math.sin(0.3 * f)
        frames[f] = np.clip(np.round(frames[f] * [1 + k, 1.0, 1 - k]), 0, 255).astype(np.uint8)
    video = _Frames(frames)
    stab = Stabilised(video, exclude=_object_mask())
    inner = (slice(MARGIN // 2, 55), slice(MARGIN // 2, 75))   # half resolution: clear of the object and the edges
    ref_uv = next(video.yuv())[1][inner].astype(float)
    before = [np.abs((uv[inner].astype(float) - ref_uv).mean(axis=(0, 1))).max() for _, uv in video.yuv()]
    after = [np.abs((uv[inner].astype(float) - ref_uv).mean(axis=(0, 1))).max() for _, uv in stab.yuv()]
    assert max(before) > 3
    assert max(after) < 1.5, after
    assert any(n.startswith("the white balance drifted") for n in stab.notes()), stab.notes()


def test_foreground_with_a_pixels_shift_leaves_out_edges_a_misregistration_moves_and_keeps_an_object():
    """A textured scene moved by 0.6 px (what stabilising a shaking camera leaves) differs along its
    edges from the unmoved one: plain foreground marks them; with shift_px=1 none remain, while a
    block of 40 levels placed on it is marked whole by both."""
    from galileo.vision.background import foreground

    rng = np.random.default_rng(0)
    scene = cv2.resize(rng.uniform(0, 255, (30, 40, 3)).astype(np.uint8), (160, 120), interpolation=cv2.INTER_NEAREST)
    moved = cv2.warpAffine(scene, np.float32([[1, 0, 0.6], [0, 1, 0.0]]), (160, 120), flags=cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REPLICATE)
    assert foreground(moved, scene, 1.0)[2:-2, 2:-2].mean() > 0.05 * 255       # the edges, plain
    assert not foreground(moved, scene, 1.0, shift_px=1)[2:-2, 2:-2].any()
    block = moved.copy()
    block[50:70, 60:90] = np.clip(block[50:70, 60:90].astype(int) + 40, 0, 255).astype(np.uint8)
    inside = foreground(block, scene, 1.0, shift_px=1)[52:68, 62:88] > 0
    assert inside.mean() > 0.5
