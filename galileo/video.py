"""Video files: H.264 MP4 writing and frame reading through PyAV (FFmpeg).

OpenCV's bundled FFmpeg writes only mp4v (which rerun rejects) and may not decode
H.264, so all video I/O goes through PyAV.
"""
from __future__ import annotations

import os
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


def write_video(path: str | os.PathLike, frames_rgb: Iterable[np.ndarray], fps: float, crf: int = 18) -> int:
    """Encode RGB uint8 frames (H, W, 3) as H.264 (yuv420p) MP4, atomically. Returns the frame count."""
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
                    stream.options = {"crf": str(crf), "preset": "medium", "threads": "1"}
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


def read_frames(path: str | os.PathLike, fmt: str = "rgb24") -> Iterator[np.ndarray]:
    """Decoded frames as uint8 arrays (H, W, 3) for rgb24/bgr24, (H, W) for gray,
    (H * 3 / 2, W) for yuv420p (the Y plane, then U and V at half resolution)."""
    box = _open(path)
    try:
        box.streams.video[0].thread_type = "AUTO"
        for frame in box.decode(video=0):
            yield frame.to_ndarray(format=fmt)
    except av.error.FFmpegError as e:
        raise GalileoError(f"video {path} is corrupt: {e}") from None
    finally:
        box.close()


def _rate(stream) -> float | None:
    rate = stream.average_rate or stream.guessed_rate
    return float(rate) if rate else None


def _stream_info(path: str | os.PathLike) -> tuple[float, int, int]:
    """The stream's frame rate, width and height (checks that the file opens and has a video
    stream)."""
    box = _open(path)
    try:
        stream = box.streams.video[0]
        rate = _rate(stream)
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
        rate = _rate(stream)
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
    """All frames (n, H, W[, 3]) and the stream's properties."""
    fps, _, _ = _stream_info(path)
    frames = list(read_frames(path, fmt))
    if not frames:
        raise GalileoError(f"video {path} has no decodable frames")
    arr = np.stack(frames)
    return arr, VideoInfo(arr.shape[2], arr.shape[1], fps, len(frames))


def read_video_yuv(path: str | os.PathLike, camera=None,
                   min_frames: int = 1) -> tuple[np.ndarray, np.ndarray, VideoInfo]:
    """Luma (n, H, W) and chroma (n, H/2, W/2, 2) planes without a colour conversion.

    H.264 stores yuv420p: the luma plane is the grey image trackers want and the chroma
    planes are already at the half resolution background subtraction runs at. A video of
    fewer than `min_frames` frames is refused (a tracker's minimum). With a `camera`, the
    video must be the one it describes (`check_stream`, `check_length`: VideoMismatch
    otherwise); its size and rate are checked before decoding, and the frames of a video
    longer than the camera's are counted, not kept.
    """
    fps, width, height = _stream_info(path)
    if width % 2 or height % 2:  # (PyAV cannot decode such a stream to yuv420p)
        raise GalileoError(f"video {path} has odd dimensions {width}x{height}")
    if camera is not None:
        check_stream(path, camera)
    ys, uvs = [], []
    limit = int(camera.n_frames) if camera is not None else None
    count = 0
    for f in read_frames(path, "yuv420p"):
        count += 1
        if limit is not None and count > limit:   # too long: count the rest, keep none of it
            continue
        h = f.shape[0] * 2 // 3
        w = f.shape[1]
        ys.append(f[:h])
        u = f[h:h + h // 4].reshape(h // 2, w // 2)
        v = f[h + h // 4:].reshape(h // 2, w // 2)
        uvs.append(np.stack([u, v], axis=-1))
    if not ys:
        raise GalileoError(f"video {path} has no decodable frames")
    if count < min_frames:
        raise GalileoError(f"video {path} has only {count} frame{'' if count == 1 else 's'}: need at least "
                           f"{min_frames} to see motion")
    if camera is not None:
        check_length(path, count, camera)
    y = np.stack(ys)
    return y, np.stack(uvs), VideoInfo(y.shape[2], y.shape[1], fps, len(ys))


def yuv_to_rgb(y: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """One frame's planes back to RGB (H, W, 3)."""
    import cv2

    h, w = y.shape
    i420 = np.concatenate([y.reshape(-1), uv[..., 0].reshape(-1), uv[..., 1].reshape(-1)]).reshape(h * 3 // 2, w)
    return cv2.cvtColor(i420, cv2.COLOR_YUV2RGB_I420)
