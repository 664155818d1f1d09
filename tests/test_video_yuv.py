"""`galileo.video.VideoStream.yuv` on frame sizes whose half-height is odd (480x270, a quarter
of 1080p): the chroma planes are (H/2, W/2) whatever the parity of H/2. Truth: the frames
written, four flat colours, read back through the planes."""
from __future__ import annotations

import numpy as np

from galileo.video import VideoStream, write_video, yuv_to_rgb

COLOURS = [(200, 40, 40), (40, 180, 60), (50, 60, 210), (230, 220, 90)]   # RGB, one per quadrant
CODEC_LEVELS = 6    # H.264 at crf 10 on flat colours, and the 4:2:0 chroma's rounding, stay within this (levels)


def test_planes_of_a_video_whose_half_height_is_odd(tmp_path):
    w, h = 480, 270
    img = np.zeros((h, w, 3), np.uint8)
    img[:h // 2, :w // 2], img[:h // 2, w // 2:], img[h // 2:, :w // 2], img[h // 2:, w // 2:] = COLOURS
    path = tmp_path / "odd_half.mp4"
    write_video(path, [img] * 3, 30.0, crf=10)
    planes = list(VideoStream(path).yuv())
    assert len(planes) == 3
    y, uv = planes[0]
    assert y.shape == (h, w) and uv.shape == (h // 2, w // 2, 2)
    rgb = yuv_to_rgb(y, uv).astype(int)
    inner = np.ones((h, w), bool)      # away from the quadrants' edges (chroma subsampling blurs them)
    inner[h // 2 - 4:h // 2 + 4] = inner[:, w // 2 - 4:w // 2 + 4] = False
    assert np.abs(rgb - img)[inner].max() <= CODEC_LEVELS
