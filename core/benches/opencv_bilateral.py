#!/usr/bin/python3
"""Reference for the M3 benchmark: OpenCV computing the same bilateral-weighted
mean and second moment on one core (jointBilateralFilter with the frame as
guide, applied to I and to I^2), plus plain bilateralFilter for the mean alone.

usage: opencv_bilateral.py FRAME.f32 WIDTH HEIGHT SIGMA_DOMAIN SIGMA_RANGE RADIUS REPS
Prints "name wall_ms cpu_ms" lines (median wall, mean thread CPU time of REPS runs).
"""
import sys

import cv2
import numpy as np

from bench_timing import median_ms


def main():
    path, w, h, sd, sr, radius, reps = sys.argv[1:8]
    w, h, radius, reps = int(w), int(h), int(radius), int(reps)
    sd, sr = float(sd), float(sr)
    cv2.setNumThreads(1)
    img = np.fromfile(path, dtype=np.float32).reshape(h, w)
    sq = img * img
    d = 2 * radius + 1

    def moments():
        m1 = cv2.ximgproc.jointBilateralFilter(img, img, d, sr, sd)
        m2 = cv2.ximgproc.jointBilateralFilter(img, sq, d, sr, sd)
        return m1, m2 - m1 * m1

    def mean_only():
        return cv2.bilateralFilter(img, d, sr, sd)

    print("opencv_joint_mean_and_second_moment %.4f %.4f" % median_ms(moments, reps))
    print("opencv_bilateralFilter_mean_only %.4f %.4f" % median_ms(mean_only, reps))


if __name__ == "__main__":
    main()
