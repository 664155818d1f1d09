"""Recognition (Galileo section 4) in the splash scenario: the object's mass read from one frame
becomes a density start (mass = density x the bottom-up volume), Galileo labels are the MAP
density times the volume (the bottom-up one times the MAP's volume factor), examples come
from a splash dataset's index, and the patch of the demo object is centred on it."""
import json
import math
import shutil

import numpy as np
import pytest

from galileo import registry
from galileo.errors import GalileoError


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """The rendered splash demo dataset (one video: a 3 cm plastic block, 1.3 g/cm^3), its
    example, scene, tracks and prepared scene."""
    from galileo.recognition.data import load_examples, tracks_for
    from galileo.scenarios.splash.dataset import build

    out = tmp_path_factory.mktemp("splash_recognition")
    build("demo", out, seed=0, workers=1, progress=False)
    _, (ex,) = load_examples(out)
    scene = registry.load_scene(ex.scene)
    tracks = tracks_for(ex, scene)
    assert tracks is not None
    prepared = registry.of(scene).prepare(scene, tracks)
    return out, ex, scene, tracks, prepared


def test_readout_turns_a_mass_reading_into_a_density(demo):
    from galileo.recognition.model import Reading, independence

    _, _, _, tracks, prepared = demo
    splash = registry.get("splash")
    (r,) = splash.readouts(prepared)
    assert (r.role, r.mass, r.friction) == ("object", "density_g_cm3", None)
    assert tracks.by_role(r.role) is not None
    volume_cm3 = prepared.obj.volume_cm3          # the bottom-up volume tracking measured
    assert volume_cm3 == tracks.objects[0].bottom_up["volume_cm3"]
    m = 0.035
    density = m / (volume_cm3 / 1e6) / 1000.0     # kg / m^3 -> g / cm^3
    assert m * r.mass_per_kg == pytest.approx(density, rel=1e-12)
    # a log-normal mass reading becomes a log-normal density proposal (no friction latent)
    lats = splash.latents(prepared)
    names = [lat.name for lat in lats]
    bounds = np.array([lat.bounds for lat in lats], float)
    q = independence({"object": Reading("object", math.log(m), 0.3, None, None, 1)}, splash, prepared, names, bounds)
    j = names.index("density_g_cm3")
    assert q.kinds[j] == "lognormal" and q.loc[j] == pytest.approx(math.log(density)) and q.scale[j] == 0.3
    assert all(k == "uniform" for i, k in enumerate(q.kinds) if i != j)


def test_label_is_map_density_times_volume(demo):
    """The label is the MAP's mass: density x the volume, the bottom-up volume x the MAP's
    volume factor (1.3 here: the object is 30% larger than tracking measured)."""
    _, _, _, tracks, prepared = demo
    splash = registry.get("splash")
    values = {"area_cm2": 9.0, "density_g_cm3": 1.25, "drag_water": 0.9, "release_s": -5 / 240, "push_mps": 0.0,
              "log_volume_factor": math.log(1.3)}
    lab = splash.recognition_label(prepared, tracks, values)
    assert set(lab) == {"object"} and lab["object"]["friction"] is None
    assert lab["object"]["mass_kg"] == pytest.approx(1.25 * 1.3 * prepared.obj.volume_cm3 / 1000.0, rel=1e-12)
    assert lab["object"]["mass_kg"] == pytest.approx(splash.derived(prepared, values)["mass_kg"], rel=1e-12)


def test_examples_from_the_demo_index(demo):
    out, ex, _, _, _ = demo
    index = json.loads((out / "index.json").read_text())["videos"][0]
    truth = json.loads((out / "demo" / "truth.json").read_text())["latents"]
    assert (ex.name, ex.object_id, ex.group, ex.role) == ("demo", index["object"], index["material"], "object")
    assert ex.folder == out / "demo" and ex.video.is_file() and ex.scene.is_file()
    assert ex.truth == {"mass_kg": truth["mass_kg"], "friction": None}
    assert ex.truth["mass_kg"] == pytest.approx(1.3 * 27.0 / 1000.0)
    lo, hi = registry.get("splash").recognition_mass_range_kg
    assert lo < ex.truth["mass_kg"] < hi


def test_catalogue_masses_lie_in_the_mass_range():
    from galileo.scenarios.splash.materials import catalogue

    lo, hi = registry.get("splash").recognition_mass_range_kg
    masses = [o.mass_kg for o in catalogue(0)]
    assert lo <= min(masses) < 2 * lo and hi / 1.2 < max(masses) <= hi


def test_malformed_index_or_missing_video_refused_in_one_line(demo, tmp_path):
    out = demo[0]
    ds = tmp_path / "ds"
    shutil.copytree(out, ds, ignore=shutil.ignore_patterns("tracks.json"))
    splash = registry.get("splash")
    index = json.loads((ds / "index.json").read_text())
    bad = [{"scenario": "splash", "videos": {"demo": 1}},
           {"scenario": "splash", "videos": [{"name": "demo", "material": "plastic block"}]},
           {"scenario": "splash", "videos": ["demo"]},
           {"scenario": "splash", "videos": [{**index["videos"][0], "object": 3}]}]
    for d in bad:
        (ds / "index.json").write_text(json.dumps(d))
        with pytest.raises(GalileoError) as e:
            splash.recognition_examples(ds)
        assert "\n" not in str(e.value)
    (ds / "index.json").write_text(json.dumps(index))
    assert len(splash.recognition_examples(ds)) == 1
    (ds / "demo" / "video.mp4").unlink()
    with pytest.raises(GalileoError, match="missing video.mp4") as e:
        splash.recognition_examples(ds)
    assert "\n" not in str(e.value)


def test_features_describe_the_prepared_scene(demo):
    _, _, scene, _, prepared = demo
    f = registry.get("splash").recognition_features(prepared)
    assert f.shape == (6,) and np.isfinite(f).all()
    from galileo.scenarios.splash.scene import KINDS

    assert list(f[:3]) == [float(k == prepared.obj.kind) for k in KINDS]   # the tracker's kind
    assert f[3] == pytest.approx(math.log(prepared.obj.volume_cm3))
    assert f[4] == pytest.approx(0.15) and f[5] == 0.0          # let go 15 cm above the water, mid-tank


def test_patch_of_the_demo_object_is_centred_on_it(demo):
    """The demo block in its first patch (cropped where the tracker puts it), found
    independently as what changed by a later frame (it fell away and the wall behind it
    stayed), is centred and about its 3 cm in size at 32 px / 0.20 m."""
    from galileo.recognition.data import patches
    from galileo.video import read_frames
    from galileo.vision.patch import SIDE_M, SIZE_PX, object_patch

    _, ex, _, tracks, prepared = demo
    p = patches(ex.video, prepared, tracks, "object")
    assert p.ndim == 4 and p.shape[1:] == (SIZE_PX, SIZE_PX, 3) and len(p) >= 1 and p.dtype == np.uint8
    centre = tracks.by_role("object").position_m[0]
    frames = list(read_frames(ex.video))
    later = object_patch(frames[15], prepared.camera, centre).astype(float)
    block = np.abs(p[0].astype(float) - later).sum(axis=2) > 40
    ys, xs = np.nonzero(block)
    c = SIZE_PX / 2
    assert abs(xs.mean() + 0.5 - c) < 1.5 and abs(ys.mean() + 0.5 - c) < 1.5
    side_px = 0.03 * SIZE_PX / SIDE_M
    width, height = xs.max() - xs.min() + 1, ys.max() - ys.min() + 1
    assert side_px - 1.5 <= width <= side_px + 2 and side_px - 1.5 <= height <= side_px + 2.5


def test_a_model_trained_on_splash_starts_chains_at_a_density(demo, tmp_path):
    """A (tiny) LeNet trained on the demo's ground truth reads no friction and starts the
    density latent from its mass reading."""
    from galileo.recognition.model import load_model, recognition_init
    from galileo.recognition.train import train_model

    out, ex, scene, tracks, prepared = demo
    model = train_model(out, "oracle", holdout_fold=None, members=1, epochs=2, progress=False)
    assert model.meta["quantities"] == ["mass_kg"] and model.meta["mass_range_kg"] == [0.001, 0.06]
    model.save(tmp_path / "m.npz")
    model = load_model(tmp_path / "m.npz", "splash")
    (reading,) = model.read_video(ex.video, scene, tracks).values()
    assert reading.role == "object" and reading.friction is None and reading.patches >= 1
    splash = registry.get("splash")
    lats = splash.latents(prepared)
    names = [lat.name for lat in lats]
    bounds = np.array([lat.bounds for lat in lats], float)
    init = recognition_init(model, ex.video, scene, tracks)(prepared, names, bounds, 4, 0, ())
    j = names.index("density_g_cm3")
    assert init.info["proposal"]["kinds"][j] == "lognormal"
    assert init.info["proposal"]["loc"][j] == pytest.approx(
        reading.log_mass - math.log(prepared.obj.volume_cm3 / 1e6 * 1000.0))
    assert np.all((init.starts >= bounds[:, 0]) & (init.starts <= bounds[:, 1]))
