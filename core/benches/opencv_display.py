#!/usr/bin/python3
"""Reference for the display benchmark: what a researcher writes today with
numpy and OpenCV to show a signed difference image on a YUYV camera: the
99.5th percentile of |x| as the range, an 8-bit index, cv2.applyColorMap with
the same diverging colormap (or grey), then cv2.cvtColor to YUV and numpy
for the 4:2:2 YUYV packing. One core (cv2.setNumThreads(1)).

usage: opencv_display.py FRAME.f32 WIDTH HEIGHT REPS
Prints "name wall_ms cpu_ms" lines (median wall, mean thread CPU time of REPS runs).
"""
import sys

import cv2
import numpy as np

from bench_timing import median_ms

# The anchors of sdi_core::display's diverging colormap, t = -1 .. 1.
ANCHORS = np.array(
    [[33, 102, 172], [103, 169, 207], [247, 247, 247], [239, 138, 98], [178, 24, 43]],
    dtype=np.float64,
)


def colormap_lut(name):
    """256x1x3 BGR table for cv2.applyColorMap."""
    t = np.linspace(-1.0, 1.0, 256)
    if name == "grey":
        rgb = np.repeat(np.round((t + 1.0) * 127.5)[:, None], 3, axis=1)
    else:
        x = (t + 1.0) * 2.0
        rgb = np.stack([np.interp(x, np.arange(5), ANCHORS[:, c]) for c in range(3)], 1)
    return np.ascontiguousarray(np.round(rgb)[:, ::-1].astype(np.uint8).reshape(256, 1, 3))


def main():
    path, w, h, reps = sys.argv[1:5]
    w, h, reps = int(w), int(h), int(reps)
    cv2.setNumThreads(1)
    img = np.fromfile(path, dtype=np.float32).reshape(h, w)

    for name in ("diverging", "grey"):
        lut = colormap_lut(name)

        def display():
            a = np.abs(img[np.isfinite(img)])
            m = np.percentile(a, 99.5) if a.size else 1.0
            m = m if m > 0 else 1.0
            t = np.nan_to_num(img / m, nan=0.0, posinf=1.0, neginf=-1.0)
            idx = np.round((np.clip(t, -1.0, 1.0) + 1.0) * 127.5).astype(np.uint8)
            bgr = cv2.applyColorMap(idx, lut)
            rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
            yuv = cv2.cvtColor(bgr, cv2.COLOR_BGR2YUV).astype(np.uint16)
            yuyv = np.empty((h, w // 2, 4), np.uint8)
            yuyv[..., 0] = yuv[:, 0::2, 0]
            yuyv[..., 2] = yuv[:, 1::2, 0]
            yuyv[..., 1] = (yuv[:, 0::2, 1] + yuv[:, 1::2, 1] + 1) >> 1
            yuyv[..., 3] = (yuv[:, 0::2, 2] + yuv[:, 1::2, 2] + 1) >> 1
            return rgb, yuyv

        print("opencv_%s %.4f %.4f" % ((name,) + median_ms(display, reps)))


if __name__ == "__main__":
    main()
