"""The simulation-trained recognition model (galileo/recognition/simulation.py), on the ramp's
default scene: trained on simulations of that one scene from the prior, tested on held-out
simulated "videos" with known latents (tracks built from a simulation plus the likelihood's
noise). Small on purpose (a few hundred simulations, a few epochs): the whole file runs in
well under a minute."""
import json
import math

import numpy as np
import pytest

from galileo import registry
from galileo.datatypes import ObjectTrack, Tracks
from galileo.errors import GalileoError
from galileo.mcmc import Independence

SIMS = 320          # simulations of the scene from the prior
EPOCHS = 60
MEMBERS = 2
SIGMA = 0.05        # the ramp's likelihood noise (m/s), also put on the test tracks
ANGLE_DEG = 20.0    # the default scene's ramp
FRAMES = 90


def ramp():
    return registry.get("ramp")


def fake_tracks(scene, values, rng, n_frames=FRAMES, fps=30.0, noise=SIGMA) -> Tracks:
    """What a perfect tracker with the likelihood's noise would report for a simulation of
    `scene` with `values`: every object seen in every frame, its shape and offset known."""
    traj = ramp().simulate(scene, n_frames, values=values, fps=fps)
    objs = []
    for i, o in enumerate(scene.objects):
        vel = traj.velocity_mps[i].copy()
        vel[:, [0, 2]] += rng.normal(0.0, noise, (traj.n_frames, 2))
        objs.append(ObjectTrack(o.name, o.role, traj.position_m[i].copy(), vel, np.ones(traj.n_frames, bool),
                                o.shape, o.offset_units if o.role == "ramp" else None))
    return Tracks(fps, objs)


@pytest.fixture(scope="module")
def scene():
    return ramp().default_scene()


@pytest.fixture(scope="module")
def template(scene):
    # the training "video": only its shapes, frame rate, length and visibility are used
    return fake_tracks(scene, {"m1_kg": 0.3, "k1": 0.2, "m2_kg": 0.12, "k2": 0.35}, np.random.default_rng(0))


@pytest.fixture(scope="module")
def model(scene, template):
    from galileo.recognition.simulation import fit

    return fit("ramp", [(scene, template)], sims=SIMS, epochs=EPOCHS, members=MEMBERS, seed=0, workers=2,
               progress=False)


def test_observation_features_layout(scene, template):
    from galileo.recognition.simulation import T_MAX, observation_features, tracked_series

    prepared = ramp().prepare(scene, template)
    vel, vis = tracked_series(prepared, template)
    assert vel.shape == (2, FRAMES, 3) and vis.all()
    vis = vis.copy()
    vis[0, 5] = False
    x = observation_features(ramp(), prepared, vel, vis)
    n_scene = len(ramp().recognition_features(prepared))
    assert x.dtype == np.float32 and x.shape == (2 * 3 * T_MAX + n_scene,)
    block = x[:2 * 3 * T_MAX].reshape(2, 3, T_MAX)
    assert np.allclose(block[1, 0, :FRAMES], vel[1, :, 0]) and np.allclose(block[1, 1, :FRAMES], vel[1, :, 2])
    assert block[0, 2, 5] == 0 and block[0, 0, 5] == 0 and block[0, 1, 5] == 0 and block[0, 2, 4] == 1
    # a shorter video: the missing frames are unseen zeros; a third slot for a 2-object scene is empty
    x3 = observation_features(ramp(), prepared, vel[:, :40], vis[:, :40], slots=3).reshape(-1)
    b3 = x3[:3 * 3 * T_MAX].reshape(3, 3, T_MAX)
    assert not b3[:, :, 40:].any() and not b3[2].any()
    assert np.allclose(x3[3 * 3 * T_MAX:], ramp().recognition_features(prepared))


def test_training_set_is_seeded(scene, template):
    from galileo.recognition.simulation import simulate_training_set

    one = simulate_training_set(ramp(), [(scene, template)], sims=6, seed=3, workers=1, progress=False)
    two = simulate_training_set(ramp(), [(scene, template)], sims=6, seed=3, workers=2, progress=False)
    other = simulate_training_set(ramp(), [(scene, template)], sims=6, seed=4, workers=1, progress=False)
    assert np.array_equal(one[0], two[0]) and one[1] == two[1]
    assert one[1] != other[1]
    bounds = {lat.name: lat.bounds for lat in ramp().latents(scene)}
    assert all(bounds[n][0] <= v <= bounds[n][1] for d in one[1] for n, v in d.items())


def test_training_videos_of_other_lengths(scene):
    """A 40-frame video: most simulations see its 40 frames, some are cut shorter or run on
    (to T_MAX at most), so that the network meets every length."""
    from galileo.recognition.simulation import T_MAX, simulate_training_set

    short = fake_tracks(scene, {"m1_kg": 0.3, "k1": 0.2, "m2_kg": 0.12, "k2": 0.35}, np.random.default_rng(1),
                        n_frames=40)
    x, *_ = simulate_training_set(ramp(), [(scene, short)], sims=24, seed=0, workers=1, progress=False)
    seen = x[:, :2 * 3 * T_MAX].reshape(len(x), 2, 3, T_MAX)[:, 0, 2]
    length = seen.sum(axis=1)    # the ramp object is seen in every frame of the video
    assert (length == 40).sum() >= 6 and (length > 40).any() and (length < 40).any() and length.max() <= T_MAX


def test_friction_read_from_held_out_simulations(model, scene):
    """k1 of held-out simulations. Physics: on the 20 degree ramp the object slides with
    a = g (sin 20 - k1 cos 20), so k1 = tan 20 - a / (g cos 20); its ~30-50 sliding frames of
    velocity with 0.05 m/s noise fix a to ~0.03 m/s^2, i.e. k1 to ~0.004 (the ground run
    after the foot, a = -k1 g, fixes it as tightly). What the network adds is its
    approximation error after a few hundred simulations; we allow 0.06 per video (6% of the
    prior's range) and ask for a mean error under a third of the prior mean's."""
    rng = np.random.default_rng(11)
    tan = math.tan(math.radians(ANGLE_DEG))
    truth = [0.04, 0.11, 0.18, 0.25, 0.31]          # all below tan 20 = 0.364: the object slides
    errors, base = [], []
    for k1 in truth:
        values = {"m1_kg": float(rng.uniform(0.05, 1.0)), "k1": k1, "m2_kg": float(rng.uniform(0.05, 1.0)),
                  "k2": float(rng.uniform(0.1, 0.9))}
        loc, scale, kind = model.predict(scene, fake_tracks(scene, values, rng))["k1"]
        assert kind == "normal" and scale > 0
        errors.append(abs(loc - k1))
        base.append(abs(0.5 - k1))                    # the prior mean of U(0, 1)
    assert max(errors) < 0.06, errors
    assert np.mean(errors) < np.mean(base) / 3, (errors, base)
    # an object that never moves only says k1 >= tan 20: the model says so, and is unsure
    values = {"m1_kg": 0.4, "k1": 0.75, "m2_kg": 0.2, "k2": 0.5}
    loc, scale, _ = model.predict(scene, fake_tracks(scene, values, rng))["k1"]
    assert loc > tan and scale > 0.08, (loc, scale)


def test_masses_are_lognormal_in_the_prior(model, scene, template):
    pred = model.predict(scene, template)
    assert set(pred) == {"m1_kg", "k1", "m2_kg", "k2", "e_collision"}
    for name in ("m1_kg", "m2_kg"):
        loc, scale, kind = pred[name]
        assert kind == "lognormal" and math.log(0.001) - 1 < loc < 1 and scale > 0
    assert model.meta["labels"] == "simulation" and model.meta["simulations"] == SIMS
    assert [e["transform"] for e in model.meta["latents"]] == ["log", "identity", "log", "identity", "identity"]


def test_model_file_round_trip(model, scene, template, tmp_path):
    from galileo.recognition import modelfile
    from galileo.recognition.model import LeNetModel
    from galileo.recognition.simulation import SimulationModel

    path = tmp_path / "sim.npz"
    model.save(path)
    back = SimulationModel.load(path, scenario="ramp")
    assert back.predict(scene, template) == model.predict(scene, template)
    assert back.meta["latents"] == model.meta["latents"]
    with pytest.raises(GalileoError, match="splash"):
        SimulationModel.load(path, scenario="splash")
    with pytest.raises(GalileoError, match="lenet"):
        LeNetModel.load(path)
    with pytest.raises(GalileoError, match="lenet"):
        modelfile.load(path, kind="lenet")
    other = tmp_path / "lenet.npz"
    modelfile.save(other, {"kind": "lenet", "scenario": "ramp"}, {"m0/w": np.zeros(3)})
    with pytest.raises(GalileoError, match="simulation"):
        SimulationModel.load(other)
    (tmp_path / "junk.npz").write_bytes(b"not a model")
    with pytest.raises(GalileoError):
        SimulationModel.load(tmp_path / "junk.npz")


def test_latents_must_be_the_models(scene, template):
    from galileo.recognition.simulation import fit

    alone = scene.__class__(scene.ramp, scene.objects[:1], camera=scene.camera)   # no target: m1_kg, k1 only
    tracks = Tracks(template.fps, template.objects[:1])
    small = fit("ramp", [(alone, tracks)], sims=6, epochs=1, members=1, workers=1, progress=False)
    assert set(small.predict(alone, tracks)) == {"m1_kg", "k1"}
    with pytest.raises(GalileoError, match="m2_kg"):
        small.predict(scene, template)


def test_proposal_and_labels(model, scene, template):
    from galileo.recognition.model import chain_starts

    lats = ramp().latents(scene)
    names = tuple(lat.name for lat in lats) + ("extra",)
    bounds = np.array([lat.bounds for lat in lats] + [(2.0, 3.0)], float)
    q = model.proposal(scene, template, names, bounds, every=3)
    assert isinstance(q, Independence) and q.every == 3
    assert q.kinds == ("lognormal", "normal", "lognormal", "normal", "normal", "uniform")   # (e_collision: normal)
    assert (q.loc[-1], q.scale[-1]) == (2.0, 3.0)
    rng = np.random.default_rng(0)
    x = np.array([q.sample(rng) for _ in range(500)])
    inside = np.all((x >= bounds[:, 0]) & (x <= bounds[:, 1]), axis=1)
    # most proposals land inside the prior: over 13 training seeds the share was 0.54-0.97 (a
    # trained model's last bits move with the CPU's kernels much as a seed does), so the
    # threshold sits below that spread; a proposal centred off the prior puts far less inside
    assert inside.mean() > 0.3, inside.mean()
    starts = chain_starts(q, bounds, 4, seed=0)
    assert np.all((starts >= bounds[:, 0]) & (starts <= bounds[:, 1]))
    labels = model.read_labels(scene, template)
    assert set(labels) == {"ramp", "target"}
    assert 0.0 <= labels["ramp"]["friction"] <= 1.0
    assert labels["ramp"]["mass_kg"] is not None and labels["ramp"]["mass_kg"] > 0   # the target was hit


def test_fig3_rows_on_a_small_dataset(scene, tmp_path):
    """fig3_rows on a three-video dataset (tracks cached, no real videos): one row per test
    object with the keys of train.predict_objects' rows; a video without a collision leaves
    the mass unidentified (the middle of the scale)."""
    from galileo.recognition import data
    from galileo.recognition.simulation import fig3_rows

    rng = np.random.default_rng(5)
    alone = scene.__class__(scene.ramp, scene.objects[:1], camera=scene.camera)
    videos = [("v0", "a#0", scene, 0.15), ("v1", "a#0", scene, 0.25), ("v2", "b#0", alone, 0.2),
              ("v3", "c#0", scene, 0.1)]
    index = {"scenario": "ramp", "videos": []}
    for name, obj, sc, k1 in videos:
        d = tmp_path / name
        d.mkdir()
        values = {"m1_kg": 0.3, "k1": k1, **({"m2_kg": 0.12, "k2": 0.35} if sc.target is not None else {})}
        (d / "video.mp4").write_bytes(b"")
        sc.save(d / "scene.json")
        fake_tracks(sc, values, rng, n_frames=60).save(d / data.TRACKS_FILE)
        (d / "truth.json").write_text(json.dumps({"latents": values}))
        index["videos"].append({"name": name, "material": obj.split("#")[0], "object": obj})
    (tmp_path / "index.json").write_text(json.dumps(index))
    _, examples = data.load_examples(tmp_path)
    train = [e for e in examples if e.object_id == "c#0"]
    test = [e for e in examples if e.object_id != "c#0"]
    fn = fig3_rows(tmp_path, seed=0, sims=12, epochs=2, members=1, workers=1)
    rows = fn(train, test, 0)
    keys = {"y_mass", "friction", "mass_kg", "log_mass_sd", "friction_sd", "true_y_mass", "true_mass_kg",
            "true_friction", "mass_identified"}
    assert set(rows) == {"a#0", "b#0"} and all(set(r) == keys for r in rows.values())
    assert rows["a#0"]["mass_identified"] and rows["a#0"]["true_friction"] == 0.15
    assert not rows["b#0"]["mass_identified"] and rows["b#0"]["y_mass"] == 0.5
    assert fn.models[0].meta["test_objects"] == ["a#0", "b#0"] and fn.models[0].meta["train_objects"] == ["c#0"]


def test_draws_outside_the_priors_support_are_dropped():
    """Splash: a 20 cm^3 object cannot show every bottom area of the prior U(0.1, 20) cm^2 and
    fit the tank (a 0.1 cm^2 bottom makes it 2 m tall): such draws have prior density 0, so the
    training set is the prior restricted to its support, not an error."""
    from galileo.datatypes import ObjectTrack, Tracks
    from galileo.recognition.simulation import simulate_training_set
    from galileo.scenarios.splash.physics import Simulator
    from galileo.scenarios.splash.scene import dimensions, default_scene
    from galileo.shapes import Box

    scene = default_scene("vcyl", 20.0, 2.0, 0.7, release_s=-12 / 240)
    traj = Simulator(scene).run(30)
    track = ObjectTrack("object", "object", traj.position_m[0], traj.velocity_mps[0], np.ones(30, bool),
                        Box((0.01, 0.01, 0.01)), bottom_up={"kind": "vcyl", "volume_cm3": 20.0})
    splash = registry.get("splash")
    x, values, _, which = simulate_training_set(splash, [(scene, Tracks(scene.fps, [track]))], sims=24, seed=0,
                                                workers=1, progress=False)
    assert len(x) == len(values) == len(which) and np.isfinite(x).all()
    # exactly the draws whose shape exists are kept (checked with the scene's own geometry rule)
    rng = np.random.default_rng(np.random.SeedSequence(0, spawn_key=(0,)))
    from galileo.recognition.simulation import _draw_values

    drawn = _draw_values(splash.latents(splash.prepare(scene, Tracks(scene.fps, [track]))), 24, rng)
    ok = [d for d in drawn   # the volume each draw simulates: the bottom-up 20 cm^3 x its volume factor
          if dimensions("vcyl", 20e-6 * math.exp(d["log_volume_factor"]), d["area_cm2"] * 1e-4, scene.max_dim_m()) is not None]
    assert 0 < len(values) < 24 and values == ok
