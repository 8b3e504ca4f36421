"""optistim.dataset on a local Ray cluster: 64 NRHO frames at a reduced resolution in 4 shards;
every file and manifest row present; a killed job resumed without rewriting finished frames;
the output equal to the single-process CLI's (`optistim render-trajectory`)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pyarrow.parquet as pq
import pytest

import optistim
from optistim import dataset

FILES = dataset.FRAME_FILES + ("frame.json",)


def finished(root) -> list[int]:
    frames = root / "frames"
    if not frames.exists():
        return []
    return sorted(int(d.name) for d in frames.iterdir() if (d / "frame.json").exists())


def snapshot(root, indices) -> dict:
    """(inode, mtime_ns, size) of every file of the frames `indices`."""
    out = {}
    for i in indices:
        for name in FILES:
            st = os.stat(root / "frames" / f"{i:06d}" / name)
            out[(i, name)] = (st.st_ino, st.st_mtime_ns, st.st_size)
    return out


@pytest.fixture(scope="module")
def ray_cluster():
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


def test_ray_dataset_resumes_and_equals_the_cli(ray_cluster, cli, small_scene_file, nrho64, tmp_path):
    out = tmp_path / "ray"
    # 1. A job killed part-way: a driver of its own (its own local Ray), killed with SIGKILL,
    #    with its whole process group (raylet and workers), once a few frames are finished.
    driver = textwrap.dedent(f"""
        import ray, optistim
        from optistim import dataset
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
        scene = optistim.Scene.from_toml({str(small_scene_file)!r})
        dataset.generate({str(nrho64)!r}, scene, {str(out)!r}, frames_per_shard=16)
        print("finished")
    """)
    proc = subprocess.Popen([sys.executable, "-c", driver], start_new_session=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while len(finished(out)) < 4 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.002)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    time.sleep(1.0)  # anything the kill missed would still be writing
    done = finished(out)
    assert 4 <= len(done) < 64, f"the kill should land mid-job: {len(done)} frames finished"
    assert finished(out) == done, "frames kept appearing after the kill"
    assert not (out / "manifest.parquet").exists()
    before = snapshot(out, done)

    # 2. The job again, on this process's Ray: the rest is rendered, nothing finished rewritten.
    scene = optistim.Scene.from_toml(small_scene_file)
    table = dataset.generate(str(nrho64), scene, out, frames_per_shard=16)
    assert finished(out) == list(range(64))
    assert snapshot(out, done) == before, "a finished frame was rewritten"
    leftovers = [p for p in out.rglob(".*.partial")]
    assert not leftovers, leftovers

    # Every file and manifest row.
    manifest = pq.read_table(out / "manifest.parquet")
    assert manifest.equals(table)
    rows = manifest.to_pylist()
    assert [r["index"] for r in rows] == list(range(64))
    poses = optistim.load_poses(scene, str(nrho64))
    for r, pose in zip(rows, poses):
        assert r["t_s"] == pose[0]
        np.testing.assert_array_equal(r["camera_position_m"], pose[1:4])
        assert len(r["files"]) == 4
        for f in r["files"]:
            assert (out / f).stat().st_size > 0
        assert 0 <= r["phase_deg"] <= 180 and r["range_m"] > 1.7374e6
        assert json.loads(r["settings_json"])["depth"] is True

    # 3. The single-process CLI over the same frames: the same files and records.
    single = tmp_path / "cli"
    run = subprocess.run([cli, "render-trajectory", str(nrho64), "--scene", str(small_scene_file),
                          "--out", str(single)], capture_output=True, text=True, check=True)
    report = json.loads(run.stdout)
    assert report["frames"] == 64 and report["rendered"] == 64
    for i in range(64):
        for name in FILES:
            a = (out / "frames" / f"{i:06d}" / name).read_bytes()
            b = (single / "frames" / f"{i:06d}" / name).read_bytes()
            assert a == b, (i, name)
    cli_rows = [json.loads(line) for line in (single / "manifest.jsonl").read_text().splitlines()]
    assert [r["index"] for r in cli_rows] == list(range(64))
    assert cli_rows == [{k: v for k, v in r.items()} for r in rows]

    # The CLI resumes too: a second run renders nothing.
    again = json.loads(subprocess.run(
        [cli, "render-trajectory", str(nrho64), "--scene", str(small_scene_file), "--out", str(single)],
        capture_output=True, text=True, check=True).stdout)
    assert again["rendered"] == 0 and again["resumed"] == 64


def test_generate_without_ray_and_from_a_sampler(small_scene_file, tmp_path):
    scene = optistim.Scene.from_toml(small_scene_file)
    sampler = dataset.UniformPoseSampler(n=6, range_m=(5e6, 2e7), phase_deg=(0, 90), seed=3)
    table = dataset.generate(sampler, scene, tmp_path / "local", frames_per_shard=4, use_ray=False)
    assert table.num_rows == 6
    np.testing.assert_array_equal(np.array(table.column("camera_position_m").to_pylist()),
                                  sampler.sample()[:, 1:4])
    # Sharded CLI runs of the same frames make the same dataset as one run.
    assert finished(tmp_path / "local") == list(range(6))


CREDENTIALS = dict(AWS_ACCESS_KEY_ID="test", AWS_SECRET_ACCESS_KEY="test", AWS_DEFAULT_REGION="us-east-1")


@pytest.fixture
def s3_uri(monkeypatch):
    """A bucket on an S3 server of our own (moto, on loopback), as a pyarrow URI."""
    moto_server = pytest.importorskip("moto.server")
    import socket

    import boto3

    for k, v in CREDENTIALS.items():
        monkeypatch.setenv(k, v)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = moto_server.ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
    server.start()
    client = boto3.client("s3", endpoint_url=f"http://127.0.0.1:{port}")
    client.create_bucket(Bucket="bench")
    yield f"s3://bench/sets/nrho?endpoint_override=127.0.0.1:{port}&scheme=http&region=us-east-1", client
    server.stop()


def test_object_store_dataset_equals_local(ray_cluster, s3_uri, small_scene_file, tmp_path):
    uri, client = s3_uri
    scene = optistim.Scene.from_toml(small_scene_file)
    sampler = dataset.UniformPoseSampler(n=8, range_m=(4e6, 2e7), phase_deg=(0, 120),
                                         off_pointing_deg=(0, 3), seed=11)
    workers = {"runtime_env": {"env_vars": CREDENTIALS}}
    table = dataset.generate(sampler, scene, uri, frames_per_shard=3, ray_options=workers)
    local = dataset.generate(sampler, scene, tmp_path / "local", frames_per_shard=3, use_ray=False)
    assert table.equals(local)

    def objects():
        listed = client.list_objects_v2(Bucket="bench", Prefix="sets/nrho/")["Contents"]
        return {o["Key"][len("sets/nrho/"):]: (o["ETag"], o["LastModified"]) for o in listed}

    first = objects()
    expected = {f"frames/{i:06d}/{n}" for i in range(8) for n in FILES} | {"manifest.parquet"}
    assert set(first) - {"frames/", "frames"} >= expected
    for key in expected:
        body = client.get_object(Bucket="bench", Key=f"sets/nrho/{key}")["Body"].read()
        assert body == (tmp_path / "local" / key).read_bytes(), key
    # A rerun finds every frame finished and puts only the manifest again.
    time.sleep(1.1)  # S3's LastModified has 1 s resolution
    dataset.generate(sampler, scene, uri, frames_per_shard=3, ray_options=workers)
    again = objects()
    rewritten = sorted(k for k in expected if again[k] != first[k])
    assert rewritten == ["manifest.parquet"], rewritten
