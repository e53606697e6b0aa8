#!/usr/bin/python3
"""Reference for the simulator_motion benchmark: the fan-and-pellets scene
simulated the way a researcher writes it in numpy: 16 sub-steps of the whole
frame (fan coverage from radius and angle, pellets as discs that fall and
then rest: no bounces, a little less work than sdi-core), the wells
split by a single transition at mid-exposure, Poisson wells, Gaussian read
noise, 12-bit ADC. Same geometry, rates and sensor as sdi-core's defaults.

usage: numpy_fan_pellets.py WIDTH HEIGHT REPS
Prints "numpy_fan_pellets wall_ms cpu_ms" (median wall, mean thread CPU).
"""
import sys

import numpy as np

from bench_timing import median_ms

BLADES, BLADE_FRACTION = 5, 0.4
BACKGROUND, OBJECT, RPM = 1.0, 12.0, 1500.0
EXPOSURE_US, SUBSTEPS, PELLETS = 2000.0, 16, 12
GAIN, CONTRAST, READ_DN = 0.08, 0.65, 15.05 ** 0.5


def main():
    w, h, reps = (int(v) for v in sys.argv[1:4])
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:h, 0:w].astype(np.float32) + 0.5
    cx, cy, radius, hub_r = 0.3 * w, 0.45 * h, 0.38 * h, 0.07 * h
    floor_y = 0.92 * h
    r = np.hypot(x - cx, y - cy)
    turns = np.arctan2(y - cy, x - cx) / (2 * np.pi) * BLADES
    base = BACKGROUND + np.clip(y - floor_y + 0.5, 0, 1) * 0.25 * (OBJECT - BACKGROUND)
    rim = np.clip(radius - r + 0.5, 0, 1)
    hub = np.clip(hub_r - r + 0.5, 0, 1)
    pr = max(0.02 * h, 1.5)
    px = rng.uniform(0.6, 0.95, PELLETS) * w
    g = 9.81 * 2.0 * h
    drop = rng.uniform(0.3, 0.8, PELLETS) * floor_y
    phase = rng.uniform(0, 1.5, PELLETS)
    state = {"t": 0.0}

    def rate(t_us):
        rot = (t_us * 1e-6 * RPM / 60 * BLADES) % 1.0
        ph = (turns - rot) % 1.0
        d = np.where(ph < BLADE_FRACTION, np.minimum(ph, BLADE_FRACTION - ph),
                     -np.minimum(ph - BLADE_FRACTION, 1.0 - ph))
        cov = np.maximum(np.clip(d * 2 * np.pi / BLADES * r + 0.5, 0, 1) * rim, hub)
        tau = (t_us * 1e-6 + phase) % 1.5
        py = floor_y - pr - drop + 0.5 * g * np.minimum(tau, np.sqrt(2 * drop / g)) ** 2
        for k in range(PELLETS):
            x0, x1 = int(max(px[k] - pr - 1, 0)), int(min(px[k] + pr + 2, w))
            y0, y1 = int(max(py[k] - pr - 1, 0)), int(min(py[k] + pr + 2, h))
            dd = np.hypot(x[y0:y1, x0:x1] - px[k], y[y0:y1, x0:x1] - py[k])
            c = cov[y0:y1, x0:x1]
            np.maximum(c, np.clip(pr - dd + 0.5, 0, 1), out=c)
        return base + cov * (OBJECT - base)

    def frame():
        t0 = state["t"]
        dt = EXPOSURE_US / SUBSTEPS
        plus = np.zeros((h, w), np.float32)
        minus = np.zeros((h, w), np.float32)
        for k in range(SUBSTEPS):
            rr = rate(t0 + (k + 0.5) * dt) * dt
            (plus if k >= SUBSTEPS // 2 else minus).__iadd__(rr.astype(np.float32))
        n_plus = rng.poisson(np.minimum(plus, 40000.0))
        n_minus = rng.poisson(np.minimum(minus, 40000.0))
        dn = GAIN * CONTRAST * (n_plus - n_minus) + rng.normal(0, READ_DN, (h, w))
        state["t"] += 1e6 / 60
        return np.clip(np.round(dn), -2048, 2047).astype(np.int16)

    print("numpy_fan_pellets %.4f %.4f" % median_ms(frame, reps))


if __name__ == "__main__":
    main()
