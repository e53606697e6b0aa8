"""sdi.simulate and sdi.separate: the same code and numbers as sdictl."""

import subprocess

import numpy as np
import pytest

import sdi


def run(sdictl, *args):
    subprocess.run([sdictl, *args], check=True, capture_output=True, text=True)


@pytest.fixture(scope="module")
def stack():
    """Raw-mode frames of a static scene, cropped small: (16, 48, 64) DN."""
    frames = sdi.simulate("depth-edge", frames=16, seed=7)
    return np.ascontiguousarray(frames[:, 96:144, 128:192])


def test_simulate_is_sdictl_sim(sdictl, tmp_path):
    for mode in ("depth-edge", "separation"):
        out, truth = tmp_path / f"{mode}.npy", tmp_path / f"{mode}-truth.npy"
        run(sdictl, "sim", "--mode", mode, "--frames", "3", "--seed", "5",
            "--out", str(out), "--truth", str(truth))
        frames, wells = sdi.simulate(mode, frames=3, seed=5, truth=True)
        np.testing.assert_array_equal(frames, np.load(out))
        np.testing.assert_array_equal(wells, np.load(truth))
    assert frames.shape[:2] == (3, 2)


def test_simulate_refuses_bad_arguments():
    with pytest.raises(ValueError, match="unknown mode"):
        sdi.simulate("nope")
    with pytest.raises(ValueError, match="frames"):
        sdi.simulate("raw", frames=0)
    assert "depth-edge" in sdi.modes() and sdi.scenes()


@pytest.mark.parametrize("method", ["m1", "m1-pooled", "m2", "m3", "ml"])
def test_separate_is_sdictl_separate(sdictl, tmp_path, stack, method):
    np.save(tmp_path / "in.npy", stack)
    out, sigma, flags = (tmp_path / n for n in ("out.npy", "sigma.npy", "flags.npy"))
    run(sdictl, "separate", "--method", method, "--in", str(tmp_path / "in.npy"),
        "--out", str(out), "--sigma", str(sigma), "--flags", str(flags))
    sep = sdi.separate(stack, method)
    np.testing.assert_array_equal(sep.estimate, np.load(out))
    np.testing.assert_array_equal(sep.sigma, np.load(sigma))
    np.testing.assert_array_equal(sep.flags.astype(np.float32), np.load(flags))
    assert sep.frames == len(stack)


def test_m1_agrees_with_numpy_within_its_standard_error():
    frames, truth = sdi.simulate("depth-edge", frames=200, seed=11, truth=True)
    sep = sdi.separate(frames, "m1")
    g, r = sep.gain_dn_per_electron, sep.read_variance_dn2
    # Section 6 by hand: D = mu / g = I+ - I-, S = (var - r) / g^2 = I+ + I-.
    x = frames.astype(np.float64)
    d = x.mean(axis=0) / g
    s = (x.var(axis=0, ddof=1) - r) / g**2
    mine = np.stack([(s + d) / 2, (s - d) / 2])
    ok = (sep.flags == 0)[None] & np.isfinite(sep.sigma)
    assert ok.mean() > 0.9
    diff = np.abs(mine - sep.estimate)[ok]
    assert np.all(diff <= 0.01 * sep.sigma[ok] + 1e-3)
    # And the estimate finds the simulator's truth within its error bars.
    z = np.abs(sep.estimate - truth)[ok] / sep.sigma[ok]
    assert np.mean(z < 3) > 0.98


def test_separate_refuses_what_sdictl_refuses(stack):
    with pytest.raises(ValueError, match="window"):
        sdi.separate(stack, "m3", window=4)
    with pytest.raises(ValueError, match="at least 2 frames"):
        sdi.separate(stack[:1], "m1")
    with pytest.raises(ValueError, match="method"):
        sdi.separate(stack, "m9")  # type: ignore[arg-type]
