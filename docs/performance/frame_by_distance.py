"""A kept frame against its reference, by distance from the dark (docs/performance.md, stop 71).

    python3 docs/performance/frame_by_distance.py out/DIR/frames/ROW.f64 out/DIR/references/KEY.f64

`optistim verify-budget ... --keep-frames --out out/DIR` writes both: the frame's (P/L) as
little-endian f64 row by row, the reference's after a head of five f64 (seconds, the bound's
total and p99, the signed estimate's total and p99). Prints the signed total, the median and
p99 over the lit pixels (those at least 1 % of the reference's 99th percentile, as
`fidelity::metrics::frame_error`), and, by chessboard distance from the nearest pixel the
reference leaves dark (space or night: on a crescent the limb and the terminator alike), each
class's pixels, share of the light and signed error, of the class's light and of the frame's.
Needs numpy and scipy; a square image unless `--width W` is given.
"""

import argparse

import numpy as np
from scipy import ndimage

HEAD = 5
LIT_FRACTION = 0.01


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("frame")
    ap.add_argument("reference")
    ap.add_argument("--width", type=int)
    ap.add_argument("--classes", type=int, default=8)
    a = ap.parse_args()
    frame = np.fromfile(a.frame, dtype="<f8")
    ref = np.fromfile(a.reference, dtype="<f8")
    head, ref = ref[:HEAD], ref[HEAD:]
    if ref.size != frame.size:
        raise SystemExit(f"{a.reference}: {ref.size} pixels after its head, the frame {frame.size}")
    w = a.width or int(round(frame.size**0.5))
    if frame.size % w:
        raise SystemExit(f"{frame.size} pixels are not rows of {w}")
    frame, ref = frame.reshape(-1, w), ref.reshape(-1, w)
    total = ref.sum()
    print(f"reference: {head[0]:.0f} s, signed estimate total {head[3]:.1e} p99 {head[4]:.1e}")
    print(f"signed total {frame.sum() / total - 1:+.3e}")
    lit = ref >= LIT_FRACTION * np.quantile(ref[ref > 0], 0.99)
    rel = np.abs(frame[lit] / ref[lit] - 1)
    print(f"lit px {lit.sum()} median {np.median(rel):.3e} p99 {np.quantile(rel, 0.99):.3e}")
    dist = ndimage.distance_transform_cdt(ref > 0, metric="chessboard")
    for k in range(1, a.classes + 2):
        m = dist == k if k <= a.classes else dist > a.classes
        if not m.any():
            continue
        err = (frame[m] - ref[m]).sum()
        name = f"{k} px" if k <= a.classes else f">{a.classes} px"
        print(
            f"{name:>6}: {m.sum():7d} px, {ref[m].sum() / total:.3e} of the light, "
            f"signed {err / ref[m].sum():+.3e} of it, {err / total:+.3e} of the frame"
        )


if __name__ == "__main__":
    main()
