"""Exposure planning from Python: the NRHO perilune passage's brackets against a direct count
of saturated and under-noise pixels in frames rendered at the brackets' ends."""

from __future__ import annotations

import numpy as np
import pytest

import optistim

from conftest import NRHO, small_scene_dict


def test_perilune_bracket_against_direct_counts(tmp_path):
    d = small_scene_dict(128)
    d["camera"]["noise"]["shot"] = False
    scene = optistim.Scene.from_dict(d)
    rows = optistim.load_poses(scene, str(NRHO))
    closest = int(np.argmin(np.linalg.norm(rows[:, 1:4], axis=1)))
    passage = rows[closest - 30 : closest + 31 : 10, 1:]
    report = optistim.exposure(scene, passage, keep=0.9, out=tmp_path)
    assert len(report["frames"]) == len(passage)
    assert report["saturated"].shape == (len(passage), report["exposures_s"].size)
    fwc, floor = report["full_well_e"], report["noise_floor_e"]
    for i, f in enumerate(report["frames"]):
        signal = optistim.render(scene, list(passage[i]), frame_id=i).signal
        s = signal[signal > 0]
        assert s.size == f["active_px"] > 0
        lo, hi = f["t_lo_s"], f["t_hi_s"]
        assert lo < hi
        # Direct counts at the ends and just beyond them.
        assert np.mean(s * hi > fwc) <= 0.1
        assert np.mean(s * hi * 1.001 > fwc) > 0.1
        assert np.mean(s * lo >= floor) >= 0.9
        assert np.mean(s * lo * 0.999 >= floor) < 0.9
    lo = max(f["t_lo_s"] for f in report["frames"])
    hi = min(f["t_hi_s"] for f in report["frames"])
    assert report["bracket_s"] == [lo, hi]
    for name in ["frames.csv", "loss.csv", "pooled.csv", "exposure.png", "exposure.svg"]:
        assert (tmp_path / name).stat().st_size > 100
    with pytest.raises(optistim.OptistimError, match="keep"):
        optistim.exposure(scene, passage, keep=1.5)
