"""Video files: H.264 MP4 writing and frame reading through PyAV (FFmpeg).

OpenCV's bundled FFmpeg writes only mp4v (which rerun rejects) and may not decode
H.264, so all video I/O goes through PyAV.
"""
from __future__ import annotations

import itertools
import operator
import os
import threading
from collections import OrderedDict
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Iterable, Iterator

import av
import numpy as np

from .errors import GalileoError


@dataclass(frozen=True)
class VideoInfo:
    width_px: int
    height_px: int
    fps: float
    n_frames: int


def write_video(path: str | os.PathLike, frames_rgb: Iterable[np.ndarray], fps: float, crf: int = 18,
                bitrate_kbps: float | None = None) -> int:
    """Encode RGB uint8 frames (H, W, 3) as H.264 (yuv420p) MP4, atomically. Returns the frame count.
    Quality `crf` (constant rate factor), or with `bitrate_kbps` an average bitrate (kbit/s) instead,
    as a phone's or webcam's encoder does (`galileo.footage`)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp.mp4")
    n = 0
    try:
        with av.open(str(tmp), "w") as box:
            stream = None
            for frame in frames_rgb:
                if stream is None:
                    stream = box.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
                    stream.height, stream.width = frame.shape[:2]
                    stream.pix_fmt = "yuv420p"
                    rate = {"crf": str(crf)} if bitrate_kbps is None else {}
                    stream.options = {**rate, "preset": "medium", "threads": "1"}
                    if bitrate_kbps is not None:
                        stream.bit_rate = round(bitrate_kbps * 1000)
                for packet in stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")):
                    box.mux(packet)
                n += 1
            if stream is not None:
                for packet in stream.encode():
                    box.mux(packet)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return n


def _open(path: str | os.PathLike):
    path = Path(path)
    if not path.exists():
        raise GalileoError(f"video not found: {path}")
    if path.stat().st_size == 0:
        raise GalileoError(f"video is empty (0 bytes): {path}")
    try:
        box = av.open(str(path))
    except (av.error.FFmpegError, OSError) as e:
        raise GalileoError(f"cannot read video {path}: {e}") from None
    if not box.streams.video:
        box.close()
        raise GalileoError(f"no video stream in {path}")
    return box


def _decoded(path: str | os.PathLike) -> Iterator["av.VideoFrame"]:
    """The video stream's frames as PyAV decodes them, in presentation order."""
    box = _open(path)
    try:
        box.streams.video[0].thread_type = "AUTO"
        yield from box.decode(video=0)
    except av.error.FFmpegError as e:
        raise GalileoError(f"video {path} is corrupt: {e}") from None
    finally:
        box.close()


def read_frames(path: str | os.PathLike, fmt: str = "rgb24") -> Iterator[np.ndarray]:
    """Decoded frames as uint8 arrays (H, W, 3) for rgb24/bgr24, (H, W) for gray,
    (H * 3 / 2, W) for yuv420p (the Y plane, then U and V at half resolution)."""
    for frame in _decoded(path):
        yield frame.to_ndarray(format=fmt)


RATE_PACKETS = 300    # packets whose time stamps give the rate when the container's two figures disagree
RATE_AGREE = 1e-3     # ... by more than this fraction


def _rate(box, stream) -> float | None:
    """The stream's frame rate. Where the container's average (frames over duration) and
    FFmpeg's guess (what ffprobe calls r_frame_rate) agree, that; where they do not, the
    frames per second that the first RATE_PACKETS packets' time stamps span (read without
    decoding).
    The average is wrong for a container whose stated duration or frame count its frames do
    not fill (a real Physics 101 clip states 201 frames in 5.88 s, 29.70 fps, and its 176
    decodable frames are stamped exactly 1/30 s apart), and the guess for a variable frame
    rate (it becomes a multiple of the true rate). Leaves `box` positioned after those
    packets: call it on a container opened for it."""
    if _agreed(stream):
        return float(stream.average_rate)
    pts = [pk.pts for pk in itertools.islice(box.demux(stream), RATE_PACKETS) if pk.pts is not None]
    return _rate_of(stream, sorted(pts))


def _agreed(stream) -> bool:
    avg, guess = stream.average_rate, stream.guessed_rate
    return bool(avg and guess and abs(float(avg) / float(guess) - 1) <= RATE_AGREE)


def _rate_of(stream, pts: list) -> float | None:
    """`_rate` given the stream's first packets' time stamps, in order."""
    if _agreed(stream):
        return float(stream.average_rate)
    if len(pts) >= 3 and stream.time_base:
        step = float((pts[-1] - pts[0]) * stream.time_base) / (len(pts) - 1)   # (stamps rounded to a coarse
        if step > 0:                                                          # time base: not their median)
            return 1.0 / step
    rate = stream.average_rate or stream.guessed_rate
    return float(rate) if rate else None


def _stream_info(path: str | os.PathLike) -> tuple[float, int, int]:
    """The stream's frame rate, width and height (checks that the file opens and has a video
    stream)."""
    box = _open(path)
    try:
        stream = box.streams.video[0]
        rate = _rate(box, stream)
        return (rate if rate else 30.0), int(stream.codec_context.width), int(stream.codec_context.height)
    finally:
        box.close()


# -- the video against the scene's camera -----------------------------------------------------
# A scene file's camera describes one video: its image size, frame rate and length. Every
# tracker checks the video it is given against it, so that a scene file written for another
# video (or another cut or export of it) is refused in one line naming both values, instead
# of being tracked into positions and velocities that are wrong by a factor:
#
# * size: exactly the camera's width_px x height_px. The intrinsics K are in the camera's
#   pixels and no tracker rescales a video (a 2x export would put every pixel ray elsewhere).
# * frame rate: within FPS_TOLERANCE (1%) of camera.fps. The trackers time frames by the
#   camera's fps (velocities are differences times fps), so a 15 or 60 fps video against a
#   30 fps scene would halve or double every velocity. 1% allows containers that state
#   29.97 (30000/1001) for 30 or round a time base; a video whose stream states no rate at
#   all is not checked on it.
# * length: exactly camera.n_frames decoded frames. Every tool that writes a scene (`galileo
#   scene`, the app's upload, the datasets) counts the video's decoded frames into n_frames,
#   so a difference means the scene file describes another cut of the video (a trimmed
#   video: set camera.n_frames to its length). Simulating the scene (`galileo simulate`)
#   gives n_frames frames: with the check, those are the video's frames one for one.

FPS_TOLERANCE = 0.01


class VideoMismatch(GalileoError):
    """A video that is not the one the scene's camera describes (size, frame rate, length)."""


def check_stream(path: str | os.PathLike, camera) -> None:
    """Size and frame rate of the video against `camera` (before decoding it); see above."""
    box = _open(path)
    try:
        stream = box.streams.video[0]
        rate = _rate(box, stream)
        size = (int(stream.codec_context.width), int(stream.codec_context.height))
    finally:
        box.close()
    want = (int(camera.width_px), int(camera.height_px))
    if size != want:
        raise VideoMismatch(f"video {path} is {size[0]}x{size[1]} but the scene's camera is {want[0]}x{want[1]} "
                            "(camera.width_px x camera.height_px must be the video's size)")
    if rate is not None and abs(rate - camera.fps) > FPS_TOLERANCE * camera.fps:
        raise VideoMismatch(f"video {path} is at {rate:.4g} fps but the scene's camera.fps is {camera.fps:g} "
                            f"(they must agree within {FPS_TOLERANCE:.0%})")


def check_length(path: str | os.PathLike, n_frames: int, camera) -> None:
    """The decoded frame count against camera.n_frames; see above."""
    if n_frames != int(camera.n_frames):
        raise VideoMismatch(f"video {path} has {n_frames} frames but the scene's camera.n_frames is "
                            f"{camera.n_frames} (the scene file describes another cut of the video; if you trimmed "
                            f"it, set camera.n_frames to {n_frames})")


def read_video(path: str | os.PathLike, fmt: str = "rgb24") -> tuple[np.ndarray, VideoInfo]:
    """All frames (n, H, W[, 3]) and the stream's properties (a short video's: n x H x W x 3
    bytes; the trackers stream a video with VideoStream, the viewer reads it with VideoFrames)."""
    fps, _, _ = _stream_info(path)
    frames = list(read_frames(path, fmt))
    if not frames:
        raise GalileoError(f"video {path} has no decodable frames")
    arr = np.stack(frames)
    return arr, VideoInfo(arr.shape[2], arr.shape[1], fps, len(frames))


# -- a video frame by frame, pass after pass ----------------------------------------------------
# The trackers never hold a whole video: a 1440x1080 frame is 2.3 MB of planes, a minute of
# it at 30 fps 4.2 GB. They decode it once to learn their background models (keeping a few
# frames) and again to track (keeping the previous frame), so that memory depends neither on a
# video's length nor, beyond a frame or two, on its size. (A short video, at most KEEP_BYTES
# decoded, is kept by the first pass instead of decoded again: the demo's 61 frames, 28 MB.)
#
# A video's frames are timed as frame f at f / fps everywhere (velocities are differences
# times fps), which a constant-frame-rate video is. Phones record at a variable rate
# (frames come late in dim light, some are dropped); the container stamps each frame with
# its time, and a pass compares those stamps with f / fps: a video whose frames stray more
# than TIMING_TOLERANCE_FRAMES of a frame interval from f / fps gets a note saying where
# and how far (`VideoStream.timing_note`), for the tracks to carry.

TIMING_TOLERANCE_FRAMES = 0.5   # half a frame: stamps rounded to the container's clock stay far inside it
KEEP_BYTES = 96 * 2 ** 20       # a video decoded into at most this much is kept between passes, not decoded again


class VideoStream:
    """A video read frame by frame, as many passes as the reader needs.

    Opening checks what can be checked before decoding: the file opens, has a video stream
    of even size (PyAV decodes yuv420p only then) and, with a `camera`, is the video the
    camera describes (`check_stream`). The first pass that runs to its end checks the length:
    at least `min_frames` frames (a tracker's minimum), and with a camera exactly
    camera.n_frames (`check_length`; a longer video's extra frames are counted, not
    yielded); it also records the frames' time stamps (`timing_note`). A video whose decoded
    frames take at most `keep_bytes` (KEEP_BYTES: 218 frames of 640x480) is kept by that pass
    and replayed by the next ones instead of decoded again; a longer one is never held.
    """

    def __init__(self, path: str | os.PathLike, camera=None, min_frames: int = 1, keep_bytes: int | None = None):
        self.path, self.camera, self.min_frames = path, camera, min_frames
        self.keep_bytes = KEEP_BYTES if keep_bytes is None else keep_bytes
        self.fps, self.width_px, self.height_px = _stream_info(path)
        if self.width_px % 2 or self.height_px % 2:  # (PyAV cannot decode such a stream to yuv420p)
            raise GalileoError(f"video {path} has odd dimensions {self.width_px}x{self.height_px}")
        if camera is not None:
            check_stream(path, camera)
        self.n_frames: int | None = None          # known once a pass has run to the end
        self.times_s: np.ndarray | None = None    # the frames' time stamps (None where the container has none)
        self._kept: list[np.ndarray] | None = None   # a short video's frames (yuv420p), from the first pass

    def yuv(self) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """One pass: each frame's luma (H, W) and chroma (H/2, W/2, 2, U then V) planes, as
        H.264 stores them (yuv420p: no colour conversion; the luma is the grey image trackers
        want, the chroma already at the half resolution background models run at). The
        planes are read-only."""
        frames = self._kept if self._kept is not None else self._decode()
        for f in frames:
            h, w = f.shape[0] * 2 // 3, f.shape[1]
            u, v = f[h:].reshape(2, h // 2, w // 2)   # (the planes by size, not rows: H/2 may be odd)
            uv = np.stack([u, v], axis=-1)
            uv.flags.writeable = False
            yield f[:h], uv

    def _decode(self) -> Iterator[np.ndarray]:
        """The frames (yuv420p, (H * 3 / 2, W)) decoded; the first pass to its end checks them."""
        limit = int(self.camera.n_frames) if self.camera is not None else None
        count, times, size = 0, [], 0
        kept = [] if self.n_frames is None else None
        for frame in _decoded(self.path):
            count += 1
            times.append(frame.time)
            if limit is not None and count > limit:   # too long: count the rest, yield none of it
                continue
            f = frame.to_ndarray(format="yuv420p")
            f.flags.writeable = False
            if kept is not None:
                size += f.nbytes
                kept = kept if size <= self.keep_bytes else None
                if kept is not None:
                    kept.append(f)
            yield f
        if self.n_frames is None:
            self._first_pass_done(count, times)
            self._kept = kept

    def _first_pass_done(self, count: int, times: list) -> None:
        if not count:
            raise GalileoError(f"video {self.path} has no decodable frames")
        if count < self.min_frames:
            raise GalileoError(f"video {self.path} has only {count} frame{'' if count == 1 else 's'}: need at "
                               f"least {self.min_frames} to see motion")
        if self.camera is not None:
            check_length(self.path, count, self.camera)
        self.n_frames = count
        self.times_s = None if None in times else np.array(times, float)

    def timing_note(self) -> str | None:
        """A line saying that the frames' time stamps stray from f / fps (a variable frame
        rate), where and by how much; None if they keep to it (or carry no stamps, or no pass
        has run to the end yet)."""
        if self.times_s is None or len(self.times_s) < 2:
            return None
        fps = float(self.camera.fps) if self.camera is not None else self.fps   # the rate frames are timed by
        t = self.times_s - self.times_s[0]
        off = t * fps - np.arange(len(t))     # in frame intervals
        worst = int(np.argmax(np.abs(off)))
        if abs(off[worst]) <= TIMING_TOLERANCE_FRAMES:
            return None
        gaps_ms = np.diff(t) * 1e3
        return (f"the video's frames are not evenly timed (a variable frame rate, as phones record): frame {worst} "
                f"is stamped {t[worst]:.3f} s but is taken as {worst / fps:.3f} s ({abs(off[worst]):.1f} frames "
                f"off; frames {gaps_ms.min():.1f}-{gaps_ms.max():.1f} ms apart, not {1e3 / fps:.1f}), so "
                f"velocities near it are off too; re-encode it at a constant rate (ffmpeg -i IN -vf "
                f"fps={fps:.5g} OUT.mp4) and make its scene file again")


def read_video_yuv(path: str | os.PathLike, camera=None,
                   min_frames: int = 1) -> tuple[np.ndarray, np.ndarray, VideoInfo]:
    """All frames' luma (n, H, W) and chroma (n, H/2, W/2, 2) planes (VideoStream's, held:
    for short videos and benchmarks)."""
    video = VideoStream(path, camera, min_frames)
    ys, uvs = zip(*video.yuv())
    return np.stack(ys), np.stack(uvs), VideoInfo(video.width_px, video.height_px, video.fps, len(ys))


# -- the viewer's frames ------------------------------------------------------------------------

DISPLAY_MAX_WIDTH_PX = 1920        # the viewer shows frames at most this wide (a full-HD screen)
FRAME_CACHE_BYTES = 128 * 2 ** 20  # decoded frames kept for scrubbing (all of a 640x480 demo's 61 frames)
DECODE_ON_FRAMES = 60              # a frame at most this far ahead is decoded on to, a farther one sought


class VideoFrames:
    """A video's RGB frames by index, for the viewer: `len(frames)`, `frames[i]` -> (H, W, 3)
    uint8 (read-only), decoded on demand and shrunk to at most `max_width_px` wide; `fps`,
    `width_px`, `height_px` are those of the frames it gives.

    Frame i is the i-th frame in presentation order, as every pass over the video counts
    them (the frames' time stamps are indexed from the packets when it opens, without
    decoding). Playing forwards decodes each frame once; a jump back or far ahead seeks to
    the key frame before it and decodes from there. Frames decoded on the way are kept, the
    least recently used dropped beyond `cache_bytes`. One decoder behind a lock: any thread
    may ask. `close()` ends it (so does garbage collection).
    """

    def __init__(self, path: str | os.PathLike, max_width_px: int | None = DISPLAY_MAX_WIDTH_PX,
                 cache_bytes: int = FRAME_CACHE_BYTES):
        self.path = path
        self._box = box = _open(path)
        self._stream = stream = box.streams.video[0]
        try:
            pts = [p.pts for p in box.demux(stream) if p.size and not p.is_discard]
        except av.error.FFmpegError as e:
            box.close()
            raise GalileoError(f"video {path} is corrupt: {e}") from None
        if not pts:
            box.close()
            raise GalileoError(f"video {path} has no decodable frames")
        self._n = len(pts)
        # the frames' time stamps in order; without them frames are counted from the start
        self._pts = None if None in pts else sorted(pts)
        self._index_of = {} if self._pts is None else {p: i for i, p in enumerate(self._pts)}
        stream.thread_type = "AUTO"
        w, h = int(stream.codec_context.width), int(stream.codec_context.height)
        scale = min(1.0, max_width_px / w) if max_width_px else 1.0
        self.width_px, self.height_px = max(1, round(w * scale)), max(1, round(h * scale))
        self._resize = {} if scale == 1.0 else {"width": self.width_px, "height": self.height_px,
                                                 "interpolation": "AREA"}
        self.fps = _rate_of(stream, (self._pts or [])[:RATE_PACKETS]) or 30.0
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self._cache_bytes, self._cached_bytes = cache_bytes, 0
        self._lock = threading.Lock()
        self._seek(0)

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, i: int) -> np.ndarray:
        i = operator.index(i)
        if i < 0:
            i += self._n
        if not 0 <= i < self._n:
            raise IndexError(f"frame {i} of a {self._n}-frame video")
        with self._lock:
            if i in self._cache:
                self._cache.move_to_end(i)
                return self._cache[i]
            if not 0 <= i - self._next < DECODE_ON_FRAMES:
                self._seek(i)
            while True:
                try:
                    frame = next(self._frames)
                except StopIteration:
                    raise GalileoError(f"video {self.path} ends before its frame {i}") from None
                except av.error.FFmpegError as e:
                    raise GalileoError(f"video {self.path} is corrupt: {e}") from None
                j = self._index_of.get(frame.pts, self._next)
                self._next = j + 1
                if j >= i - DECODE_ON_FRAMES:   # (not those long before it: a seek passes up to a key frame's worth)
                    self._keep(j, frame.to_ndarray(format="rgb24", **self._resize))
                if j >= i:
                    return self._cache.get(i, self._cache[j])

    def _seek(self, i: int) -> None:
        """Put the decoder on the key frame at or before frame i (the start, without time stamps)."""
        if self._pts is None or i == 0:
            self._box.seek(0)
            self._next = 0
        else:
            self._box.seek(self._pts[i], stream=self._stream, backward=True, any_frame=False)
            self._next = i   # (until a frame comes out: its stamp tells where the decoder landed)
        self._frames = self._box.decode(self._stream)

    def _keep(self, j: int, img: np.ndarray) -> None:
        img.flags.writeable = False
        old = self._cache.pop(j, None)
        self._cached_bytes += img.nbytes - (0 if old is None else old.nbytes)
        self._cache[j] = img
        while len(self._cache) > 1 and self._cached_bytes > self._cache_bytes:
            self._cached_bytes -= self._cache.popitem(last=False)[1].nbytes

    def close(self) -> None:
        with self._lock:
            self._box.close()


def yuv_to_rgb(y: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """One frame's planes back to RGB (H, W, 3)."""
    import cv2

    h, w = y.shape
    i420 = np.concatenate([y.reshape(-1), uv[..., 0].reshape(-1), uv[..., 1].reshape(-1)]).reshape(h * 3 // 2, w)
    return cv2.cvtColor(i420, cv2.COLOR_YUV2RGB_I420)
