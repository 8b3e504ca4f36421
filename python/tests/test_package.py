"""The optistim package: frames equal the CLI's files, errors carry the CLI's messages, the
GIL is released while rendering, threads follow the argument, RAYON_NUM_THREADS and the
process's CPUs."""

from __future__ import annotations

import os
import pathlib
import subprocess
import sys
import threading
import time
import tomllib

import numpy as np
import pytest

import optistim
from optistim.dataset import UniformPoseSampler

from conftest import NRHO, REPO, small_scene_dict


def test_frame_equals_cli_files_bit_for_bit(cli, small_scene_file, tmp_path):
    scene = optistim.Scene.from_toml(small_scene_file)
    frame = optistim.render(scene)
    frame.to_fits(tmp_path / "py")
    subprocess.run([cli, "render", str(small_scene_file), "--out", str(tmp_path / "cli")],
                   check=True, capture_output=True)
    for name in ["power.fits", "signal.fits", "depth.fits", "image.png"]:
        py = (tmp_path / "py" / name).read_bytes()
        assert py == (tmp_path / "cli" / name).read_bytes(), name
        assert frame.encode()[name] == py, name
    # The arrays are the images the files hold (FITS stores rows bottom-up).
    data = np.frombuffer((tmp_path / "py" / "power.fits").read_bytes()[2880 * 1:], dtype=">f8")
    w, h = frame.width, frame.height
    stored = data[: w * h].reshape(h, w)[::-1]
    header = (tmp_path / "py" / "power.fits").read_bytes()[:2880]
    assert b"END" in header  # one header block at this size
    np.testing.assert_array_equal(stored, frame.power)
    assert frame.power.shape == (h, w) and frame.power.dtype == np.float64
    assert frame.dn.dtype == np.uint16 and frame.depth.dtype == np.float64
    assert frame.power.sum() > 0 and np.isnan(frame.depth).any() and np.isfinite(frame.depth).any()


def test_arrays_are_not_copied():
    scene = optistim.Scene.from_dict(small_scene_dict(128))
    frame = optistim.render(scene)
    a, b = frame.power, frame.power
    assert np.shares_memory(a, b)  # every access is the same buffer
    # The memory is the buffer Rust filled, owned by a Python object that holds it (not by a
    # NumPy allocation, as a copy would be).
    root = a
    while isinstance(root.base, np.ndarray):
        root = root.base
    assert not root.flags.owndata and root.base is not None, root.base


def test_pose_forms_and_trajectories_agree():
    scene = optistim.Scene.from_dict(small_scene_dict(128))
    rows = optistim.load_poses(scene, str(NRHO))[:3]
    assert rows.shape == (3, 11)
    frames = iter(optistim.render_trajectory(scene, str(NRHO)))
    it = optistim.render_trajectory(scene, rows[:, 1:])
    assert len(it) == 3 and it.times_s == [0.0, 1.0, 2.0]
    for i, frame in enumerate(it):
        pose = optistim.Pose(rows[i, 1:4], rows[i, 4:8], rows[i, 8:11], frame_id=i)
        direct = optistim.render(scene, pose)
        np.testing.assert_array_equal(frame.power, direct.power)
        np.testing.assert_array_equal(frame.dn, direct.dn)
        from_list = optistim.render(scene, list(rows[i, 1:]), frame_id=i)
        np.testing.assert_array_equal(from_list.dn, direct.dn)
        from_file = next(frames)
        np.testing.assert_array_equal(from_file.dn, direct.dn)
    # 7 numbers: the scene's Sun.
    seven = optistim.render(scene, list(rows[0, 1:8]))
    assert seven.pose.sun_position_m == scene.pose.sun_position_m


def test_bad_scene_raises_the_cli_message(cli, tmp_path):
    bad = small_scene_dict(64)
    bad["body"]["albedo"] = -0.5
    with pytest.raises(optistim.SceneError) as e:
        optistim.Scene.from_dict(bad)
    assert isinstance(e.value, ValueError)
    assert "body.albedo" in str(e.value)
    path = tmp_path / "bad.toml"
    path.write_text(optistim.Scene.from_dict(small_scene_dict(64)).toml.replace(
        "albedo = 0.12", "albedo = -0.5"))
    with pytest.raises(optistim.SceneError) as from_file:
        optistim.Scene.from_toml(path)
    run = subprocess.run([cli, "render", str(path), "--out", str(tmp_path / "o")],
                         capture_output=True, text=True)
    assert run.returncode != 0
    assert str(from_file.value) in run.stderr, (str(from_file.value), run.stderr)
    with pytest.raises(optistim.SceneError, match="cannot read"):
        optistim.Scene.from_toml(tmp_path / "missing.toml")


def test_bad_pose_raises():
    scene = optistim.Scene.from_dict(small_scene_dict(64))
    good = list(optistim.load_poses(scene, str(NRHO))[0, 1:])
    with pytest.raises(optistim.PoseError, match="quaternion norm"):
        optistim.render(scene, good[:3] + [2.0, 0.0, 0.0, 0.0])
    with pytest.raises(optistim.PoseError, match="non-finite"):
        optistim.render(scene, [float("nan")] + good[1:])
    with pytest.raises(optistim.PoseError, match="a pose is 7 .* or 10"):
        optistim.render(scene, good[:5])
    with pytest.raises(optistim.PoseError):
        optistim.render_trajectory(scene, np.zeros((2, 7)))
    with pytest.raises(TypeError):
        optistim.render(scene, "not a pose")
    # A camera inside the body: the renderer's own error.
    with pytest.raises(optistim.RenderError):
        optistim.render(scene, [1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])


def test_gil_is_released_while_rendering():
    scene = optistim.Scene.from_toml(REPO / "config" / "nrho_bench.toml")  # 1024 x 1024
    optistim.render(scene, threads=1)  # warm the pool
    stamps = []
    stop = False

    def spin():
        # A Python thread that stamps the time as often as it runs.
        while not stop:
            stamps.append(time.perf_counter())

    t = threading.Thread(target=spin)
    t.start()
    try:
        time.sleep(0.05)
        start = time.perf_counter()
        optistim.render(scene, threads=1)
        end = time.perf_counter()
    finally:
        stop = True
        t.join()
    took = end - start
    inside = [s for s in stamps if start <= s <= end]
    # The longest time the spinner did not run during the render. Were the GIL held through
    # the call, it could run at most at the call's edges (a switch interval, 5 ms, each):
    # the gap would be the render's own time, tens of milliseconds.
    edges = [start] + inside + [end]
    gap = max(b - a for a, b in zip(edges, edges[1:]))
    assert took > 0.03, took
    print(f"longest gap {gap * 1e3:.2f} ms of {took * 1e3:.1f} ms")
    assert gap < 0.3 * took, (gap, took, len(inside))


def test_threads_follow_argument_env_and_affinity():
    assert optistim.render_threads(3) == 3
    code = "import optistim; print(optistim.render_threads())"
    env = dict(os.environ, RAYON_NUM_THREADS="5")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "5"
    env.pop("RAYON_NUM_THREADS")
    code = "import os; os.sched_setaffinity(0, {0}); import optistim; print(optistim.render_threads())"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "1"
    scene = optistim.Scene.from_dict(small_scene_dict(64))
    # Any thread count, the same frame.
    np.testing.assert_array_equal(optistim.render(scene, threads=1).power,
                                  optistim.render(scene, threads=2).power)


def test_scene_pickles_for_workers():
    import pickle

    scene = optistim.Scene.from_dict(small_scene_dict(64))
    again = pickle.loads(pickle.dumps(scene))
    np.testing.assert_array_equal(optistim.render(again).power, optistim.render(scene).power)


def test_uniform_pose_sampler():
    s = UniformPoseSampler(n=200, range_m=(3e6, 2e7), phase_deg=(10, 100),
                           off_pointing_deg=(0, 5), seed=7)
    a, b = s.sample(), s.sample()
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, UniformPoseSampler(**{**s.__dict__, "seed": 8}).sample())
    cam, q, sun = a[:, 1:4], a[:, 4:8], a[:, 8:11]
    r = np.linalg.norm(cam, axis=1)
    assert (r >= 3e6).all() and (r <= 2e7).all()
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    to_sun = sun / np.linalg.norm(sun, axis=1)[:, None]
    phase = np.degrees(np.arccos(np.sum(cam / r[:, None] * to_sun, axis=1)))
    assert (phase >= 10 - 1e-9).all() and (phase <= 100 + 1e-9).all()
    # The boresight (camera +Z in the body frame) within 5 deg of the body centre.
    w, x, y, z = q.T
    bore = np.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], axis=1)
    off = np.degrees(np.arccos(np.clip(np.sum(bore * (-cam / r[:, None]), axis=1), -1, 1)))
    assert off.max() <= 5 + 1e-6 and off.max() > 3
    # The renderer takes them.
    scene = optistim.Scene.from_dict(small_scene_dict(64))
    frame = optistim.render(scene, list(a[0, 1:]))
    assert abs(frame.stats["phase_deg"] - phase[0]) < 1e-6


def test_budgeted_frames_carry_their_error_report(tmp_path):
    import json

    scene = optistim.Scene.from_toml(REPO / "config" / "nrho_budget.toml")
    assert scene.budgeted
    frame = optistim.render(scene)
    report = frame.error
    assert set(report["predicted"]) == {"median", "p99", "total"}
    assert report["budget"]["median"] > 0 and isinstance(report["meets_budget"], bool)
    # The frame was rendered with the planner's rung, and says so everywhere.
    assert frame.settings["points"]["per_pixel"] == report["points_per_pixel"]
    record = json.loads(frame.record(5, 1.5))
    assert record["fidelity"] == "budget"
    assert record["predicted_median"] == report["predicted"]["median"]
    header = frame.encode()["power.fits"][:2880 * 4].decode("ascii")
    assert "FIDELITY= 'budget  '" in header and "PREDMED" in header
    # Fixed settings: no model ran, no report.
    fixed = optistim.render(optistim.Scene.from_dict(small_scene_dict(64)))
    assert fixed.error is None and json.loads(fixed.record(0))["predicted_median"] is None


def test_a_colour_camera_gives_a_plane_per_band(cli, tmp_path):
    """config/nrho_bench_rgb.toml (RGGB) at 128 px: power and signal are bands x height x
    width, the DN one raw mosaic; without the mosaic a DN image per band; the files equal the
    CLI's."""
    with open(REPO / "config" / "nrho_bench_rgb.toml", "rb") as f:
        d = tomllib.load(f)
    d["camera"]["resolution_px"] = [128, 128]
    d["camera"]["pixel_pitch_m"] = d["camera"]["pixel_pitch_m"] * 8
    d["pose"]["camera_position_m"] = [2.0e7, 0.0, 0.0]
    frame = optistim.render(optistim.Scene.from_dict(d, base_dir=REPO / "config"))
    assert frame.bands == ["R", "G", "B"]
    assert frame.power.shape == (3, 128, 128) and frame.signal.shape == (3, 128, 128)
    assert frame.dn.shape == (128, 128)
    assert frame.depth.shape == (128, 128)
    # Each band is the one (P/L) image times its own factor: the bands' ratio is one number.
    lit = frame.signal[1] > 0
    ratio = frame.signal[0][lit] / frame.signal[1][lit]
    assert lit.sum() > 100 and np.ptp(ratio) < 1e-12 * ratio.mean()
    del d["camera"]["mosaic"]
    scene = optistim.Scene.from_dict(d, base_dir=REPO / "config")
    planes = optistim.render(scene)
    assert planes.dn.shape == (3, 128, 128)
    planes.to_fits(tmp_path / "py")
    toml = tmp_path / "rgb.toml"
    toml.write_text(scene.toml)
    subprocess.run([cli, "render", str(toml), "--out", str(tmp_path / "cli")], check=True,
                   capture_output=True)
    for name in ["power.fits", "signal.fits", "depth.fits", "image.png"]:
        assert (tmp_path / "py" / name).read_bytes() == (tmp_path / "cli" / name).read_bytes(), name
