"""Two or more optistim builds benchmarked on one scene in one interleaved run: each round runs
`optistim bench --scene S --frames N` once per build, in turn, so that the machine's drift
(15-40 % between runs on the shared 2-core machines) falls on every build alike. Prints, per
build, the median of the rounds' median frame times, their range, and the mean render and
detector stages. Standard library only.

    cp target/release/optistim /tmp/after      # and a build of the commit before as /tmp/before
    python3 python/benches/bench_interleaved.py --scene config/bennu.toml --rounds 5 \\
        /tmp/before /tmp/after
"""

import argparse
import json
import statistics
import subprocess


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("builds", nargs="+", help="optistim executables")
    ap.add_argument("--scene", required=True)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--frames", type=int, default=15)
    a = ap.parse_args()
    runs = {b: [] for b in a.builds}
    for _ in range(a.rounds):
        for b in a.builds:
            out = subprocess.run(
                [b, "bench", "--scene", a.scene, "--frames", str(a.frames)],
                check=True, capture_output=True, text=True,
            ).stdout
            runs[b].append(json.loads(out.strip().splitlines()[-1]))
    for b, rs in runs.items():
        med = [r["median_ms"] for r in rs]
        stage = lambda k: statistics.median(r["mean_stage_ms"][k] for r in rs)  # noqa: E731
        print(f"{b}: frame {statistics.median(med):.1f} ms ({min(med):.0f}-{max(med):.0f}), "
              f"render {stage('total'):.1f} ms, detector {stage('detector'):.1f} ms")


if __name__ == "__main__":
    main()
