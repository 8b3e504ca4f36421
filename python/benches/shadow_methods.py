"""How far the DEM's cheap shadow methods are from ray marching, frame by frame.

Renders rows of a pose stream with one scene file (by default `config/nrho_textured.toml`,
the textured Moon with its LOLA DEM) at the budget planner's 1-per-pixel rung
(`points_per_pixel = 1`, the midpoint rule, `map_filter = "pixel"`, 4 boundary nodes), once per
self-shadowing method, and measures each against the ray-marched frame (Eq. 33, the method
`fidelity = "budget"` trusts) with the figures of `src/fidelity/metrics.rs`:

- `off`: no self-shadowing;
- `horizon_map`: the scene's horizon map (one elevation per texel, whatever the Sun's azimuth);
- `azN`: horizons computed from the DEM in N azimuths (`body.horizon_azimuths = N`).

    python python/benches/shadow_methods.py --optistim target/release/optistim --out out/shadows

Prints one line per frame and writes `shadow_methods.csv` in `--out`.
"""

import argparse
import csv
import os
import re
import subprocess
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from frame_error import errors, read_fits_top_down  # noqa: E402

ROWS = "0,71,142,178,213,284,355,426,497,526,528,530,532,568,639,710"


def variant(text, scene_dir, method):
    """The scene at the planner's 1-per-pixel rung with `method`'s shadows, paths absolute."""
    text = re.sub(
        r'path = "([^"]+)"',
        lambda m: f'path = "{os.path.normpath(os.path.join(scene_dir, m.group(1)))}"',
        text,
    )
    render = text.index("[render]")
    head, _ = text[:render], text[render:]
    shadows = {"off": "off", "ray_marching": "ray_marching"}.get(method, "horizon_map")
    if method.startswith("az"):
        head = re.sub(r"^horizon_map = .*$", f"horizon_azimuths = {int(method[2:])}", head,
                      flags=re.M)
    return head + (
        "[render]\npoints_per_pixel = 1.0\nintegration = \"midpoint\"\n"
        f"map_filter = \"pixel\"\nboundary_nodes = 4\nself_shadowing = \"{shadows}\"\n"
    )


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--optistim", default="target/release/optistim")
    ap.add_argument("--scene", default="config/nrho_textured.toml")
    ap.add_argument("--trajectory", default="../shared/trajectories/nrho_2orbits.csv")
    ap.add_argument("--rows", default=ROWS)
    ap.add_argument("--methods", default="off,horizon_map,az8,az32")
    ap.add_argument("--out", default="out/shadows")
    args = ap.parse_args()

    os.makedirs(args.out, exist_ok=True)
    rows = [int(r) for r in args.rows.split(",")]
    lines = open(args.trajectory).read().splitlines()
    sub = os.path.join(args.out, "poses.csv")
    with open(sub, "w") as f:
        f.write("\n".join([lines[0]] + [lines[r + 1] for r in rows]) + "\n")
    header = lines[0].split(",")
    poses = [dict(zip(header, lines[r + 1].split(","))) for r in rows]

    text = open(args.scene).read()
    scene_dir = os.path.dirname(os.path.abspath(args.scene))
    methods = args.methods.split(",")
    for m in ["ray_marching"] + methods:
        path = os.path.join(args.out, f"{m}.toml")
        open(path, "w").write(variant(text, scene_dir, m))
        subprocess.run([args.optistim, "render-trajectory", sub, "--scene", path,
                        "--out", os.path.join(args.out, m)], check=True, capture_output=True)

    def power(m, k):
        return read_fits_top_down(os.path.join(args.out, m, "frames", f"{k:06d}", "power.fits"))

    out = []
    for k, (row, pose) in enumerate(zip(rows, poses)):
        reference = power("ray_marching", k)
        rec = {"row": row, "altitude_km": float(pose["altitude_m"]) / 1e3,
               "phase_deg": float(pose["phase_deg"])}
        for m in methods:
            e = errors(power(m, k), reference)
            rec.update({f"{m}_median": e["median"], f"{m}_p99": e["p99"],
                        f"{m}_total": e["total"]})
        out.append(rec)
        print(f"row {row:4d} {rec['altitude_km']:7.0f} km {rec['phase_deg']:5.1f} deg | "
              + " | ".join(f"{m} p99 {rec[m + '_p99']:.1e} total {rec[m + '_total']:.1e}"
                           for m in methods))
    with open(os.path.join(args.out, "shadow_methods.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(out[0]))
        w.writeheader()
        w.writerows(out)
    for m in methods:
        t = np.array([r[f"{m}_total"] for r in out])
        p = np.array([r[f"{m}_p99"] for r in out])
        print(f"{m}: total {t.min():.1e} to {t.max():.1e}, p99 {p.min():.1e} to {p.max():.1e}")


if __name__ == "__main__":
    main()
