"""Datasets along trajectories, at scale: shards of poses rendered on Ray (or in this process),
each frame's files under deterministic names, and a Parquet manifest.

    >>> from optistim import dataset
    >>> dataset.generate("nrho_2orbits.csv", "config/nrho_bench.toml", "s3://bucket/nrho",
    ...                  frames_per_shard=256)

Layout of ``out_uri`` (the same as ``optistim render-trajectory`` writes)::

    frames/000000/power.fits  signal.fits  depth.fits  image.png  frame.json
    frames/000001/...
    manifest.parquet          one row per frame, by index

A frame is finished when its ``frame.json`` exists: it is written after the frame's images,
and on a local disk every file is written under a temporary name and renamed (an object
store's put is whole or absent), so a killed job leaves no truncated file, and a rerun renders
only the frames without ``frame.json``, rewriting nothing that was finished. The manifest
(pose, time, phase, range, totals, settings, predicted error, file paths per frame) is built
from the ``frame.json`` files when every shard is done.

Ray: shards of ``frames_per_shard`` poses are Ray tasks of ``num_cpus`` CPUs each, and each
renders with that many threads. ``ray.init()`` is the caller's (a local cluster, or
``ray.init(address="ray://head:10001")`` for a multi-machine one; every worker then needs the
``optistim`` package and read access to the scene's maps at the same paths); when Ray is not
initialised, ``generate`` starts a local one. ``use_ray=False`` renders the shards in this
process, one after the other.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import _optistim
from ._optistim import Pose, Scene, render

__all__ = ["generate", "UniformPoseSampler", "manifest_path", "FRAME_FILES"]

#: The files of a frame, as ``Frame.encode`` names them, and the marker written last.
FRAME_FILES = ("power.fits", "signal.fits", "depth.fits", "image.png")
_MARKER = "frame.json"


def _filesystem(out_uri: str):
    """(pyarrow filesystem, root path) of a local path or an object-store URI."""
    from pyarrow import fs as pafs

    if "://" in str(out_uri):
        return pafs.FileSystem.from_uri(str(out_uri))
    return pafs.LocalFileSystem(), os.path.abspath(os.fspath(out_uri))


def manifest_path(out_uri: str) -> str:
    """Where ``generate`` writes the manifest of ``out_uri``."""
    return f"{str(out_uri).rstrip('/')}/manifest.parquet"


def _frame_dir(root: str, index: int) -> str:
    return f"{root}/frames/{index:06d}"


def _put(fs, path: str, data: bytes) -> None:
    """Writes ``data`` to ``path`` whole or not at all."""
    if fs.type_name == "local":
        head, name = path.rsplit("/", 1)
        partial = f"{head}/.{name}.partial"
        with fs.open_output_stream(partial) as f:
            f.write(data)
        fs.move(partial, path)
    else:
        with fs.open_output_stream(path) as f:
            f.write(data)


def _finished(fs, root: str, index: int) -> dict | None:
    """The record of frame ``index`` if it is finished."""
    from pyarrow import fs as pafs

    path = f"{_frame_dir(root, index)}/{_MARKER}"
    if fs.get_file_info(path).type != pafs.FileType.File:
        return None
    with fs.open_input_stream(path) as f:
        try:
            record = json.loads(f.read().decode())
        except ValueError:
            return None
    return record if record.get("index") == index else None


def _write_frame(fs, root: str, index: int, t_s: float, frame) -> dict:
    """Writes a rendered frame's files, then its ``frame.json``; returns its record."""
    directory = _frame_dir(root, index)
    fs.create_dir(directory, recursive=True)
    for name, data in frame.encode().items():
        _put(fs, f"{directory}/{name}", data)
    text = frame.record(index, t_s)
    _put(fs, f"{directory}/{_MARKER}", text.encode())
    return json.loads(text)


def render_shard(
    scene: Scene,
    poses: np.ndarray,
    first_index: int,
    out_uri: str,
    threads: int | None = None,
) -> list[dict]:
    """Renders the frames ``first_index ..`` of ``poses`` (rows of t, camera, quaternion
    w, x, y, z, Sun; as ``load_poses`` gives) into ``out_uri``, skipping finished ones;
    returns their records. A frame is written by a second thread while the next renders
    (rendering and pyarrow's writes release the GIL)."""
    from concurrent.futures import ThreadPoolExecutor

    fs, root = _filesystem(out_uri)
    records = []
    with ThreadPoolExecutor(max_workers=1) as writer:
        pending = None
        for k, row in enumerate(np.asarray(poses, dtype=np.float64)):
            index = first_index + k
            record = _finished(fs, root, index)
            if record is not None:
                records.append(record)
                continue
            pose = Pose(row[1:4].tolist(), row[4:8].tolist(), row[8:11].tolist(), frame_id=index)
            frame = render(scene, pose, threads=threads)
            if pending is not None:
                records.append(pending.result())
            pending = writer.submit(_write_frame, fs, root, index, float(row[0]), frame)
        if pending is not None:
            records.append(pending.result())
    return sorted(records, key=lambda r: r["index"])


def _poses(source: Any, scene: Scene) -> np.ndarray:
    if isinstance(source, UniformPoseSampler):
        rows = source.sample()
        checked = _optistim.load_poses(scene, rows[:, 1:])  # validates every pose
        checked[:, 0] = rows[:, 0]
        return checked
    return _optistim.load_poses(scene, source)


def generate(
    trajectory_or_pose_sampler: Any,
    scene: Scene | str | os.PathLike,
    out_uri: str | os.PathLike,
    frames_per_shard: int = 256,
    *,
    num_cpus: int = 1,
    use_ray: bool = True,
    max_retries: int = 3,
    ray_options: dict | None = None,
):
    """Renders every pose into ``out_uri`` and writes ``manifest.parquet`` there.

    ``trajectory_or_pose_sampler``: a pose file (CSV or JSON lines), an (N, 7) or (N, 10)
    array (camera [m], quaternion w, x, y, z[, Sun [m]]), or a ``UniformPoseSampler``.
    ``scene``: a ``Scene`` or the path of its TOML. ``out_uri``: a local folder or an object
    store URI (``s3://bucket/prefix``, through ``pyarrow.fs``). Each shard of
    ``frames_per_shard`` poses is one Ray task of ``num_cpus`` CPUs rendering with as many
    threads (retried up to ``max_retries`` times; ``ray_options`` adds Ray task options, such
    as ``{"runtime_env": {"env_vars": {...}}}`` for the object store's credentials on the
    workers); ``use_ray=False`` renders the shards here.
    Finished frames are kept, never rewritten. Returns the manifest as a ``pyarrow.Table``.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    if not isinstance(scene, Scene):
        scene = Scene.from_toml(os.fspath(scene))
    if frames_per_shard < 1 or num_cpus < 1:
        raise ValueError("frames_per_shard and num_cpus must be at least 1")
    poses = _poses(trajectory_or_pose_sampler, scene)
    out_uri = str(out_uri) if "://" in str(out_uri) else os.path.abspath(os.fspath(out_uri))
    fs, root = _filesystem(out_uri)
    fs.create_dir(root, recursive=True)
    starts = list(range(0, len(poses), frames_per_shard))
    blocks = [(s, poses[s : s + frames_per_shard]) for s in starts]
    if use_ray:
        try:
            import ray
        except ImportError as e:
            raise ImportError(
                "optistim.dataset.generate on Ray needs Ray: pip install './python[ray]', "
                "or pass use_ray=False to render in this process"
            ) from e

        if not ray.is_initialized():
            ray.init(num_cpus=len(os.sched_getaffinity(0)), include_dashboard=False)
        options = {"num_cpus": num_cpus, "max_retries": max_retries, **(ray_options or {})}
        task = ray.remote(**options)(render_shard)
        scene_ref = ray.put(scene)
        refs = [task.remote(scene_ref, block, s, out_uri, num_cpus) for s, block in blocks]
        shards = ray.get(refs)
    else:
        shards = [render_shard(scene, block, s, out_uri, num_cpus) for s, block in blocks]
    records = sorted((r for shard in shards for r in shard), key=lambda r: r["index"])
    table = pa.Table.from_pylist(records, schema=_SCHEMA or _schema())
    buffer = pa.BufferOutputStream()
    pq.write_table(table, buffer)
    _put(fs, f"{root}/manifest.parquet", buffer.getvalue().to_pybytes())
    return table


def _schema():
    import pyarrow as pa

    f64, vec = pa.float64(), pa.list_(pa.float64())
    return pa.schema(
        [
            ("index", pa.int64()),
            ("t_s", f64),
            ("camera_position_m", vec),
            ("quaternion_wxyz", vec),
            ("sun_position_m", vec),
            ("phase_deg", f64),
            ("range_m", f64),
            ("total_power_w", f64),
            ("total_signal_e_per_s", f64),
            ("saturated_px", pa.int64()),
            ("fidelity", pa.string()),
            ("settings_json", pa.string()),
            ("predicted_median", f64),
            ("predicted_p99", f64),
            ("predicted_total", f64),
            ("files", pa.list_(pa.string())),
        ]
    )


try:
    _SCHEMA = _schema()
except ImportError:  # pyarrow is only needed by generate
    _SCHEMA = None


@dataclass(frozen=True)
class UniformPoseSampler:
    """Poses for training sets, uniform over range, phase and off-pointing, seeded.

    The Sun lies along +X of the body frame at ``sun_distance_m``. Each pose draws the range
    [m] (camera to body centre) uniformly in ``range_m``, the phase angle [deg] uniformly in
    ``phase_deg`` and the camera's azimuth about the Sun direction uniformly in 0..360; the
    boresight then points at the body centre tilted by an off-pointing angle [deg] uniform in
    ``off_pointing_deg``, towards a uniform direction, with a uniform roll. ``sample()``
    returns (n, 11) rows: t = the row index [s], camera [m], quaternion w, x, y, z
    (camera -> body), Sun [m]. The same seed gives the same poses.
    """

    n: int
    range_m: tuple[float, float]
    phase_deg: tuple[float, float] = (0.0, 120.0)
    off_pointing_deg: tuple[float, float] = (0.0, 0.0)
    seed: int = 0
    sun_distance_m: float = 1.495978707e11

    def sample(self) -> np.ndarray:
        rng = np.random.default_rng(self.seed)
        n = self.n
        r = rng.uniform(*self.range_m, n)
        phase = np.radians(rng.uniform(*self.phase_deg, n))
        az = rng.uniform(0.0, 2.0 * np.pi, n)
        off = np.radians(rng.uniform(*self.off_pointing_deg, n))
        off_dir = rng.uniform(0.0, 2.0 * np.pi, n)
        roll = rng.uniform(0.0, 2.0 * np.pi, n)
        # Camera direction from the body centre: at `phase` from the Sun (+X).
        cam_dir = np.stack(
            [np.cos(phase), np.sin(phase) * np.cos(az), np.sin(phase) * np.sin(az)], axis=1
        )
        cam = cam_dir * r[:, None]
        rows = np.empty((n, 11))
        for i in range(n):
            z = -cam_dir[i]  # boresight at the body centre
            a = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
            x = np.cross(a, z)
            x /= np.linalg.norm(x)
            y = np.cross(z, x)
            # Off-pointing: tilt the boresight by `off` towards `off_dir` in the (x, y) plane.
            t = np.cos(off_dir[i]) * x + np.sin(off_dir[i]) * y
            z2 = np.cos(off[i]) * z + np.sin(off[i]) * t
            x2 = x - np.dot(x, z2) * z2
            x2 /= np.linalg.norm(x2)
            y2 = np.cross(z2, x2)
            # Roll about the boresight.
            c, s = np.cos(roll[i]), np.sin(roll[i])
            x3, y3 = c * x2 + s * y2, -s * x2 + c * y2
            body_from_camera = np.stack([x3, y3, z2], axis=1)  # columns: camera axes in B
            rows[i, 0] = i
            rows[i, 1:4] = cam[i]
            rows[i, 4:8] = _quaternion_wxyz(body_from_camera)
            rows[i, 8:11] = (self.sun_distance_m, 0.0, 0.0)
        return rows


def _quaternion_wxyz(m: np.ndarray) -> np.ndarray:
    """The unit quaternion (w, x, y, z, w >= 0) of a rotation matrix (Shepperd's method)."""
    t = np.trace(m)
    if t > 0:
        s = 2.0 * np.sqrt(1.0 + t)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    q = np.asarray(q)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q
