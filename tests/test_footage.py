"""Camera effects (galileo.footage, `galileo dataset --camera`): each effect measured back from
the frames it makes against what it promises - the shake's path by image registration, the
noise's sd against sd^2 = read^2 + gain * level, the lens against the radial model, the gains
on flat images, distractors against the objects' pixels - and a phone build's truth against
the clean build's."""
import json
import math
import subprocess
import sys

import cv2
import numpy as np
import pytest

from galileo.camera import look_at_camera
from galileo.errors import GalileoError
from galileo.footage import (
    EFFECTS,
    FLICKER_BEAT_HZ,
    KEEP_OUT_PX,
    NAMES,
    PRESETS,
    CameraEffects,
    Footage,
    effects_from_name,
)

H, W = 480, 640


def camera(n_frames: int = 30, size=(W, H)):
    """A 640 x 480 camera (focal 560 px, principal point at the centre), as the ramp's."""
    return look_at_camera((0.0, -1.2, 0.3), (0.0, 0.0, 0.2), width_px=size[0], height_px=size[1], n_frames=n_frames)


def texture(seed: int = 0, pad: int = 0) -> np.ndarray:
    """A smooth random RGB texture (features at every scale above a few pixels: registration
    converges, bilinear resampling is accurate), `pad` px bigger on every side."""
    rng = np.random.default_rng(seed)
    noise = cv2.GaussianBlur(rng.normal(0, 1, (H + 2 * pad, W + 2 * pad, 3)).astype(np.float32), (0, 0), 3.0)
    return np.clip(128 + 60 * noise / noise.std(), 0, 255).astype(np.uint8)


def filmed(name: str, frames, seed: int = 0, objects=None, cam=None):
    fo = Footage(effects_from_name(name), cam or camera(len(frames)), seed)
    return fo, list(fo.frames(frames, objects))


def test_clean_is_the_frames_themselves():
    img = texture()
    for name in ("clean", "shake:0", "phone:0"):
        _, out = filmed(name, [img, img])
        assert all(o is img for o in out), name
    assert effects_from_name("clean") == CameraEffects()


def test_shake_measured_back_by_registration_is_the_path_reported():
    """ECC registration (a Euclidean warp, independent of the footage's remap) of each shaken
    frame against the still one recovers the reported shift and roll; frame 0 is unshaken (the
    render, which reaches pad_px beyond the picture, cropped to it)."""
    fo = Footage(EFFECTS["shake"], camera(30), 3)
    p = fo.pad_px
    img = texture(pad=p)
    assert fo.render_camera.width_px == W + 2 * p and fo.render_camera.K[0, 2] == camera().K[0, 2] + p
    out = list(fo.frames([img] * 30))
    assert np.array_equal(out[0], img[p:p + H, p:p + W]) and fo.shift_px[0].tolist() == [0.0, 0.0]
    assert fo.roll_deg[0] == 0.0
    c = fo.centre_px
    grey0 = cv2.cvtColor(out[0], cv2.COLOR_RGB2GRAY).astype(np.float32)
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 200, 1e-6)
    moved = 0.0
    for f in range(5, 30, 4):
        warp = np.eye(2, 3, dtype=np.float32)
        _, warp = cv2.findTransformECC(grey0, cv2.cvtColor(out[f], cv2.COLOR_RGB2GRAY).astype(np.float32), warp,
                                       cv2.MOTION_EUCLIDEAN, crit, None, 5)
        roll = math.degrees(math.atan2(warp[1, 0], warp[0, 0]))
        shift = warp[:, 2] - (c - warp[:, :2] @ c)         # x -> R (x - c) + c + shift
        # the registration's own error on this texture is < 0.01 px (known warps); 0.05 px is 3 % of the shake
        assert shift == pytest.approx(fo.shift_px[f], abs=0.05), f
        assert roll == pytest.approx(fo.roll_deg[f], abs=0.005), f
        moved = max(moved, float(np.linalg.norm(fo.shift_px[f])))
    assert moved > 0.3       # it does shake


def test_shake_amplitude_is_the_documented_rms():
    """Over a long video and many seeds the translation's mean square length is shake_px^2 and the
    roll's shake_roll_deg^2 (the tolerance: 4 standard errors of the mean over seeds)."""
    fx = EFFECTS["shake"]
    cam = camera(1800, size=(32, 24))            # 60 s; a tiny image: only the path is used
    ms_px, ms_deg = [], []
    for seed in range(300):
        fo = Footage(fx, cam, seed)
        ms_px.append(float((fo.shift_px ** 2).sum(axis=1).mean()))
        ms_deg.append(float((fo.roll_deg ** 2).mean()))
    for ms, target in ((ms_px, fx.shake_px ** 2), (ms_deg, fx.shake_roll_deg ** 2)):
        se = np.std(ms) / math.sqrt(len(ms))
        assert abs(np.mean(ms) - target) < 4 * se, (np.mean(ms), target, se)


def test_noise_sd_grows_with_brightness_as_specified():
    """On flat grey images of two levels the noise's variance is read^2 + gain * level (+ 1/12 of
    rounding to 8 bits); tolerance 5 standard errors of a variance over the image's effectively
    independent samples (the 3x3 correlation leaves N / 3.78)."""
    fx = EFFECTS["noise"]
    for level in (40, 200):
        img = np.full((H, W, 3), level, np.uint8)
        _, out = filmed("noise", [img])
        resid = out[0].astype(float) - level
        var = resid.var()
        expected = fx.noise_read_sd ** 2 + fx.noise_gain * level + 1 / 12
        se = expected * math.sqrt(2 / (resid.size / 3.78))
        assert abs(var - expected) < 5 * se, (level, var, expected)
        assert abs(resid.mean()) < 5 * math.sqrt(expected / (resid.size / 3.78))
        # neighbours correlated like a demosaiced sensor's: (0.125 + 0.125) / 0.375 of the noise's variance
        rho = (resid[:, 1:] * resid[:, :-1]).mean() / var
        assert rho == pytest.approx(2 / 3 * (var - 1 / 12) / var, abs=0.01)


def test_lens_moves_a_pixel_where_the_radial_model_says():
    """A dot at pinhole pixel q appears at q's distorted position: x_d = x_u (1 + k1 r_u^2) on
    normalised coordinates (computed here from K), and where Camera.distort_px puts it. The
    render reaches beyond the picture (pad_px) as far as the lens sees."""
    cam = camera(1)
    (fx_, _, cx), (_, fy, cy), _ = cam.K
    fo = Footage(EFFECTS["lens"], cam, 0)
    p = fo.pad_px
    vr, ur = np.mgrid[0:H + 2 * p, 0:W + 2 * p] - p        # the render's pixels in the video's coordinates
    v, u = np.mgrid[0:H, 0:W]
    assert p >= 20                                         # barrel: the corners see beyond the pinhole picture
    # (pinhole (0, 0): a dot half outside the pinhole picture, whole in the render and the video)
    for q in ((560.0, 400.0), (90.0, 70.0), (400.0, 300.0), (0.0, 0.0)):
        dot = 250 * np.exp(-((ur - q[0]) ** 2 + (vr - q[1]) ** 2) / (2 * 1.5 ** 2))
        img = np.repeat(dot[..., None], 3, axis=2).astype(np.uint8)
        out = list(fo.frames([img]))
        xu, yu = (q[0] - cx) / fx_, (q[1] - cy) / fy
        s = 1 + EFFECTS["lens"].lens_k1 * (xu * xu + yu * yu)
        expected = np.array([cx + fx_ * xu * s, cy + fy * yu * s])
        assert fo.camera.k1 == EFFECTS["lens"].lens_k1
        assert fo.camera.distort_px(np.array(q)) == pytest.approx(expected, abs=1e-9)
        m = out[0][..., 0].astype(float)
        m[m < 3] = 0                                     # the dot, not the rounding of its far tails
        seen = np.array([(u * m).sum(), (v * m).sum()]) / m.sum()
        assert np.linalg.norm(seen - expected) < 0.05, (q, seen, expected)   # a centroid of a 1.5 px dot
        assert np.linalg.norm(np.array(q) - expected) > 3 or q == (400.0, 300.0)


def _gains(frames, img) -> np.ndarray:
    """Per frame and channel: the frame's sum over the still image's (rounding to 8 bits moves it by
    at most half a level over the image's mean level: `_tol`)."""
    ref = img.reshape(-1, 3).sum(axis=0)
    return np.array([f.reshape(-1, 3).astype(float).sum(axis=0) / ref for f in frames])


def test_flicker_exposure_and_white_balance_measured_on_a_flat_image():
    n, fps = 90, 30.0
    img = np.random.default_rng(0).integers(60, 200, (H, W, 3), dtype=np.uint8)
    tol = 0.5 / img.mean()
    fo, out = filmed("flicker", [img] * n, seed=5)
    g = _gains(out, img)
    assert np.allclose(g, fo.gain_rgb, atol=tol)
    a = EFFECTS["flicker"].flicker
    assert np.abs(g - 1).max() <= a + tol and np.abs(g - 1).max() > 0.8 * a
    spectrum = np.abs(np.fft.rfft(g[:, 1] - g[:, 1].mean()))
    beat = np.fft.rfftfreq(n, 1 / fps)[spectrum.argmax()]
    assert FLICKER_BEAT_HZ[0] - fps / n <= beat <= FLICKER_BEAT_HZ[1] + fps / n
    fo, out = filmed("exposure", [img] * n, seed=5)
    g = _gains(out, img)
    a = EFFECTS["exposure"].exposure_drift
    assert np.allclose(g, fo.gain_rgb, atol=tol) and np.abs(g - 1).max() <= a + tol
    assert np.abs(np.diff(g[:, 0])).max() <= 2 * math.pi * 0.3 * a / fps + tol    # slow: at most 0.3 Hz
    assert np.allclose(g[:, 0], g[:, 1], atol=tol) and np.allclose(g[:, 0], g[:, 2], atol=tol)   # grey
    fo, out = filmed("whitebalance", [img] * n, seed=5)
    g = _gains(out, img)
    assert np.allclose(g, fo.gain_rgb, atol=tol) and np.allclose(g[:, 1], 1.0, atol=tol)       # green kept
    assert np.abs(g[:, [0, 2]] - 1).max() <= EFFECTS["whitebalance"].whitebalance_drift + tol


def test_vignette_darkens_the_corners_by_its_share():
    img = np.full((H, W, 3), 200, np.uint8)
    _, out = filmed("vignette", [img])
    share = EFFECTS["vignette"].vignette
    assert out[0][0, 0, 0] == round(200 * (1 - share)) and abs(int(out[0][H // 2, W // 2, 0]) - 200) <= 1


@pytest.mark.parametrize("name", ["shadow", "person", "hand", "webcam:0.5"])
def test_distractors_never_touch_the_objects_region(name):
    """An object crossing the picture (its pixels in each frame known): every pixel within
    KEEP_OUT_PX of any of them is left exactly as rendered in every frame, and the distractor
    does show elsewhere."""
    n = 40
    img = texture(1)
    frames, union = [], np.zeros((H, W), np.uint8)
    for f in range(n):
        frame = img.copy()
        centre = (int(80 + 12 * f), int(150 + 5 * f))
        cv2.circle(frame, centre, 30, (200, 60, 50), -1)
        cv2.circle(union, centre, 30, 1, -1)
        frames.append(frame)
    near = cv2.distanceTransform((1 - union).astype(np.uint8), cv2.DIST_L2, 5) <= KEEP_OUT_PX
    shown = 0
    for seed in range(3):
        fx = effects_from_name(name)
        fx = CameraEffects(shadow=fx.shadow, person=fx.person, hand=fx.hand)      # the distractors alone
        fo = Footage(fx, camera(n), seed)
        for frame, out in zip(frames, fo.frames(frames, union.astype(bool))):
            assert np.array_equal(out[near], frame[near])
            shown = max(shown, int((np.abs(out.astype(int) - frame).max(axis=2) > 10).sum()))
    assert shown > 2000


def test_camera_names_and_levels():
    assert effects_from_name("shake:0.5").shake_px == EFFECTS["shake"].shake_px / 2
    assert effects_from_name("shake:0.5").shake_roll_deg == EFFECTS["shake"].shake_roll_deg / 2
    assert effects_from_name("h264:0.5").h264_kbps == 2 * EFFECTS["h264"].h264_kbps      # half as hard
    noise = effects_from_name("noise:0.5")
    assert noise.noise_read_sd == 2.0 and math.sqrt(noise.noise_gain) == math.sqrt(EFFECTS["noise"].noise_gain) / 2
    assert effects_from_name("phone") == PRESETS["phone"] and set(NAMES) >= {"clean", "webcam", "handheld", "hand"}
    for bad in ("bogus", "Shake", "", "fisheye:0.5"):
        with pytest.raises(GalileoError) as e:
            effects_from_name(bad)
        msg = str(e.value)
        assert "\n" not in msg and "shake:0.5" in msg and all(n in msg for n in NAMES), bad
    for bad, level in (("shake:2", "'2'"), ("shake:-0.1", "'-0.1'"), ("shake:x", "'x'"), ("shake:nan", "'nan'"),
                       ("shake:", "''")):
        with pytest.raises(GalileoError) as e:     # a known camera at a level it has not: the level is the fault
            effects_from_name(bad)
        msg = str(e.value)
        assert "\n" not in msg and f"the level {level} is not a number in [0, 1]" in msg and "shake:0.5" in msg, bad


def run_cli(*args):
    p = subprocess.run([sys.executable, "-m", "galileo", *args], capture_output=True, text=True)
    return p.returncode, p.stdout, p.stderr


def test_cli_refuses_a_bad_camera_and_a_scenario_without_effects(tmp_path):
    code, _, err = run_cli("dataset", "--preset", "demo", "--out", str(tmp_path / "a"), "--camera", "fisheye")
    assert code == 2 and err.startswith("galileo: error: unknown camera 'fisheye'") and err.count("\n") == 1
    code, _, err = run_cli("dataset", "--scenario", "fall", "--preset", "demo", "--out", str(tmp_path / "b"),
                           "--camera", "phone")
    assert code == 2 and err.count("\n") == 1 and "fall" in err and "ramp" in err and "splash" in err
    assert not (tmp_path / "a" / "index.json").exists() and not (tmp_path / "b" / "index.json").exists()


def test_h264_at_a_bitrate(tmp_path):
    """write_video's bitrate mode: the file's rate is the one asked (x264's average bitrate control
    lands within 15% over 3 s of hard, noisy frames), far below the default crf 18's."""
    from galileo.video import read_frames, write_video

    rng = np.random.default_rng(0)
    base = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
    frames = [np.roll(base, 3 * i, axis=1) for i in range(90)]
    write_video(tmp_path / "a.mp4", frames, 30.0, bitrate_kbps=1000)
    write_video(tmp_path / "b.mp4", frames, 30.0)
    kbps = (tmp_path / "a.mp4").stat().st_size * 8 / 3 / 1000
    assert 850 < kbps < 1150 and (tmp_path / "b.mp4").stat().st_size > 2 * (tmp_path / "a.mp4").stat().st_size
    assert len(list(read_frames(tmp_path / "a.mp4"))) == 90


@pytest.mark.slow
@pytest.mark.parametrize("scenario", ["ramp", "splash"])
def test_phone_build_keeps_the_truth(tmp_path, scenario):
    """`galileo dataset --camera phone` (motion blur, lens, shake, ...) renders the demo with the
    clean build's latents and trajectory; scene.json carries the lens's k1, truth.json the path
    (zero at frame 0), index.json the camera."""
    out = {}
    for cam in ("clean", "phone"):
        code, _, err = run_cli("dataset", "--scenario", scenario, "--preset", "demo", "--out", str(tmp_path / cam),
                               "--camera", cam, "--quiet", "--workers", "1")
        assert code == 0, err
        folder = tmp_path / cam / "demo"
        out[cam] = (json.loads((folder / "truth.json").read_text()), json.loads((folder / "scene.json").read_text()),
                    json.loads((tmp_path / cam / "index.json").read_text()))
    (clean, clean_scene, _), (phone, phone_scene, index) = out["clean"], out["phone"]
    assert phone["latents"] == clean["latents"] and phone["trajectory"] == clean["trajectory"]
    assert index["camera"] == "phone" and "camera" not in clean
    assert phone_scene["camera"]["k1"] == PRESETS["phone"].lens_k1 and "k1" not in clean_scene["camera"]
    assert {k: v for k, v in phone_scene["camera"].items() if k != "k1"} == clean_scene["camera"]
    n = len(clean["trajectory"]["time_s"])
    rec = phone["camera"]
    assert rec["name"] == "phone" and rec["effects"] == json.loads(json.dumps(PRESETS["phone"].__dict__))
    assert len(rec["shift_px"]) == len(rec["roll_deg"]) == len(rec["gain_rgb"]) == n
    assert rec["shift_px"][0] == [0.0, 0.0] and rec["roll_deg"][0] == 0.0
