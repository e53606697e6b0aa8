"""The Dask example: sdi.separate over several files on a LocalCluster of
1 and 2 workers gives what sdi.separate gives here."""

import sys
from pathlib import Path

import numpy as np
import pytest

import sdi

pytest.importorskip("distributed", reason="dask's distributed is not installed (pip install dask distributed)")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
import dask_separate  # noqa: E402


def test_separate_over_files_with_one_and_two_workers(tmp_path):
    paths = []
    for seed in range(4):
        p = tmp_path / f"stack{seed}.npy"
        np.save(p, sdi.simulate("depth-edge", frames=12, seed=seed))
        paths.append(str(p))
    want = [sdi.separate(np.load(p), "m3").estimate for p in paths]
    for workers in (1, 2):
        got, frames, seconds = dask_separate.separate_all(paths, "m3", workers)
        print(f"{workers} worker(s): {frames} frames in {seconds:.2f} s = {frames / seconds:.1f} frames/s")
        assert frames == 48
        for g, w in zip(got, want):
            np.testing.assert_array_equal(g, w)
