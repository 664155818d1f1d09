"""The shared dataset builder (galileo.dataset): a rerun of the same build keeps the videos that
are complete and unchanged and renders only the others (a killed run's, a damaged one), with
the same files as a build from scratch; unknown presets are one-line errors."""
import dataclasses
import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from galileo.dataset import RECORD, DatasetSpec, build
from galileo.errors import GalileoError
from galileo.jsonio import write_json
from galileo.video import read_frames, write_video

N_FRAMES, H_PX, W_PX = 4, 48, 64


@dataclass(frozen=True)
class Clip:
    name: str
    seed: int


def plan_clips(preset: str, seed: int) -> list[Clip]:
    """Three videos (no preset check of its own: the builder's is the one tested)."""
    return [Clip(n, seed * 10 + i) for i, n in enumerate(("a", "b", "c"))]


def render_clip(clip: Clip, out_dir: str) -> dict:
    """A small real video and truth file, the same for the same clip; a file named
    crash-<name> beside the output folder makes it write half a video and fail (a killed run)."""
    folder = Path(out_dir) / clip.name
    frames = np.random.default_rng(clip.seed).integers(0, 256, (N_FRAMES, H_PX, W_PX, 3), dtype=np.uint8)
    if (Path(out_dir).parent / f"crash-{clip.name}").exists():
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "video.mp4").write_bytes(b"\x00\x00\x00\x18ftypisom")
        raise RuntimeError(f"render of {clip.name} killed")
    write_video(folder / "video.mp4", frames, 30.0)
    write_json(folder / "truth.json", {"seed": clip.seed})
    return {"name": clip.name, "seed": clip.seed}


CLIPS = DatasetSpec("clips", ("one",), plan_clips, render_clip, files=("video.mp4", "truth.json"))


def counting(spec: DatasetSpec) -> tuple[DatasetSpec, list[str]]:
    """`spec` whose render_one notes each video it renders (in this process: workers=1)."""
    calls: list[str] = []

    def render_one(video, out_dir):
        calls.append(video.name)
        return spec.render_one(video, out_dir)

    return dataclasses.replace(spec, render_one=render_one), calls


def stamps(out: Path) -> dict[str, tuple[int, int]]:
    """(inode, mtime in ns) of every visible file under `out` but the index and the record."""
    return {p.relative_to(out).as_posix(): (p.stat().st_ino, p.stat().st_mtime_ns)
            for p in sorted(out.rglob("*")) if p.is_file() and p.name not in ("index.json", RECORD)
            and not p.name.startswith(".")}


def assert_same_dataset(a: Path, b: Path) -> None:
    """The two folders hold the same files, byte for byte, and the same decoded frames."""
    assert set(stamps(a)) == set(stamps(b))
    for rel in stamps(a):
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
        if rel.endswith(".mp4"):
            for fa, fb in zip(read_frames(a / rel), read_frames(b / rel), strict=True):
                assert np.array_equal(fa, fb), rel
    assert json.loads((a / "index.json").read_text()) == json.loads((b / "index.json").read_text())


def test_rebuild_renders_only_damaged_videos(tmp_path):
    fresh, out = tmp_path / "fresh", tmp_path / "out"
    build(CLIPS, "one", fresh, seed=3, workers=1, progress=False)
    spec, calls = counting(CLIPS)
    build(spec, "one", out, seed=3, workers=1, progress=False)
    assert calls == ["a", "b", "c"]
    before = stamps(out)

    calls.clear()
    entries = build(spec, "one", out, seed=3, workers=1, progress=False)
    assert calls == [] and stamps(out) == before           # nothing rendered, nothing rewritten
    assert entries == [{"name": n, "seed": 30 + i} for i, n in enumerate("abc")]

    (out / "b" / "tracks.json").write_text("[1]")                   # as `galileo recognize label` adds
    data = (out / "b" / "video.mp4").read_bytes()
    (out / "b" / "video.mp4").write_bytes(data[:len(data) // 2])   # truncated
    (out / "c" / "truth.json").unlink()                             # deleted
    build(spec, "one", out, seed=3, workers=1, progress=False)
    assert calls == ["b", "c"]
    after = stamps(out)
    assert after["a/video.mp4"] == before["a/video.mp4"] and after["a/truth.json"] == before["a/truth.json"]
    (out / "b" / "tracks.json").write_text("[2]")                   # not a file of the video: no new render
    build(spec, "one", out, seed=3, workers=1, progress=False)
    assert calls == ["b", "c"]
    (out / "b" / "tracks.json").unlink()
    assert_same_dataset(out, fresh)


def test_killed_build_resumes_with_the_unfinished_videos(tmp_path):
    fresh, out = tmp_path / "fresh", tmp_path / "out"
    build(CLIPS, "one", fresh, workers=1, progress=False)
    (tmp_path / "crash-b").touch()
    spec, calls = counting(CLIPS)
    with pytest.raises(RuntimeError, match="killed"):
        build(spec, "one", out, workers=1, progress=False)
    assert calls == ["a", "b"] and not (out / "index.json").exists()
    (tmp_path / "crash-b").unlink()
    calls.clear()
    build(spec, "one", out, workers=1, progress=False)
    assert calls == ["b", "c"]                  # b's partial video redone, c rendered, a kept
    assert_same_dataset(out, fresh)


def test_workers_rebuild_only_the_damaged_video(tmp_path):
    fresh, out = tmp_path / "fresh", tmp_path / "out"
    build(CLIPS, "one", fresh, workers=1, progress=False)
    build(CLIPS, "one", out, workers=2, progress=False)
    before = stamps(out)
    (out / "a" / "video.mp4").write_bytes(b"")
    build(CLIPS, "one", out, workers=2, progress=False)
    after = stamps(out)
    assert after["a/video.mp4"] != before["a/video.mp4"]
    assert {k: v for k, v in after.items() if not k.startswith("a/")} == \
        {k: v for k, v in before.items() if not k.startswith("a/")}
    assert_same_dataset(out, fresh)


def test_another_build_in_the_folder_renders_every_video(tmp_path):
    spec, calls = counting(CLIPS)
    build(spec, "one", tmp_path / "out", seed=0, workers=1, progress=False)
    build(spec, "one", tmp_path / "out", seed=1, workers=1, progress=False)
    assert calls == ["a", "b", "c"] * 2
    assert json.loads((tmp_path / "out" / "b" / "truth.json").read_text()) == {"seed": 11}
    (tmp_path / "out" / RECORD).write_text("{not json")           # an unreadable record: render again
    calls.clear()
    build(spec, "one", tmp_path / "out", seed=1, workers=1, progress=False)
    assert calls == ["a", "b", "c"]


def test_ramp_demo_rebuilt_after_its_video_is_truncated(demo_dir, tmp_path):
    """The real scenario: the session's demo build, copied, is kept whole by a rebuild; its
    video truncated, the rebuild renders it again, the same frames and files as the first."""
    from galileo.scenarios.ramp.dataset import DATASET

    out = tmp_path / "ds"
    shutil.copytree(demo_dir.parent, out)
    spec, calls = counting(DATASET)
    build(spec, "demo", out, seed=0, workers=1, progress=False)
    assert calls == []
    video = out / "demo" / "video.mp4"
    video.write_bytes(video.read_bytes()[:1000])
    build(spec, "demo", out, seed=0, workers=1, progress=False)
    assert calls == ["demo"]
    assert_same_dataset(out, demo_dir.parent)


@pytest.mark.parametrize("scenario", ["ramp", "splash", "clips"])
def test_unknown_preset_is_one_line_naming_the_presets(scenario, tmp_path):
    from galileo.scenarios.ramp.dataset import DATASET as RAMP
    from galileo.scenarios.splash.dataset import DATASET as SPLASH

    spec = {"ramp": RAMP, "splash": SPLASH, "clips": CLIPS}[scenario]
    with pytest.raises(GalileoError) as e:
        build(spec, "huge", tmp_path / "out", progress=False)
    msg = str(e.value)
    assert "\n" not in msg and "'huge'" in msg and ", ".join(spec.presets) in msg
    assert not (tmp_path / "out").exists()
