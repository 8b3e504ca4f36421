"""Datasets on Ray against the single-process CLI over the same frames (docs/performance.md,
"Datasets on Ray").

    python python/benches/dataset.py --frames 512 --px 512 --out /tmp/bench

Renders the first FRAMES poses of the NRHO stream with config/nrho_bench.toml at PX x PX
(the same field of view): once with `optistim render-trajectory` (one process, all cores),
then with `optistim.dataset.generate` on a local Ray cluster of this machine's CPUs, at
256 frames per shard, with 1 CPU per task (as many workers as CPUs) and with all CPUs per task
(one worker); each run into a fresh folder, the Ray cluster started before the clock starts.
Prints frames per second and Ray's overhead against the CLI.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import pathlib
import shutil
import subprocess
import sys
import time
import tomllib

REPO = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "python" / "tests"))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=512)
    ap.add_argument("--px", type=int, default=512)
    ap.add_argument("--per-shard", type=int, default=256)
    ap.add_argument("--out", default="/tmp/optistim-dataset-bench")
    ap.add_argument("--cli", default=str(REPO / "target" / "release" / "optistim"))
    args = ap.parse_args()

    import ray

    import optistim
    from conftest import small_scene_dict
    from optistim import dataset

    out = pathlib.Path(args.out)
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    scene_dict = small_scene_dict(args.px)
    scene = optistim.Scene.from_dict(scene_dict, base_dir=REPO / "config")
    scene_file = out / "scene.toml"
    scene_file.write_text(scene.toml)
    with open(REPO.parent / "shared" / "trajectories" / "nrho_2orbits.csv", newline="") as f:
        rows = list(csv.reader(f))
    traj = out / "poses.csv"
    with open(traj, "w", newline="") as f:
        csv.writer(f).writerows(rows[: args.frames + 1])

    cpus = len(os.sched_getaffinity(0))
    results = []

    def cli_run(tag):
        t = time.perf_counter()
        subprocess.run([args.cli, "render-trajectory", str(traj), "--scene", str(scene_file),
                        "--out", str(out / tag)], check=True, capture_output=True)
        return time.perf_counter() - t

    ray.init(num_cpus=cpus, include_dashboard=False, log_to_driver=False)
    # Warm the workers (imports, the scene), outside the clock.
    warm = optistim.load_poses(scene, str(traj))[: 2 * cpus, 1:]
    dataset.generate(warm, scene, out / "warm", frames_per_shard=1, num_cpus=1)
    for tag, per_task in [("cli", None), ("ray-1cpu", 1), (f"ray-{cpus}cpu", cpus)]:
        if per_task is None:
            s = cli_run(tag)
        else:
            t = time.perf_counter()
            dataset.generate(str(traj), scene, out / tag, frames_per_shard=args.per_shard,
                             num_cpus=per_task)
            s = time.perf_counter() - t
        results.append((tag, s))
        shutil.rmtree(out / tag)
    ray.shutdown()
    cli_s = results[0][1]
    print(f"{args.frames} frames, {args.px} x {args.px} px, {args.per_shard} per shard, {cpus} CPUs")
    for tag, s in results:
        print(f"{tag:>10}: {s:7.2f} s  {args.frames / s:6.1f} frames/s  "
              f"{(s / cli_s - 1) * 100:+6.1f} % against the CLI")
    print(json.dumps({tag: s for tag, s in results}))


if __name__ == "__main__":
    main()
