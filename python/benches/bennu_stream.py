#!/usr/bin/env python3
"""A pose stream around Bennu for `optistim verify-budget` on a mesh (issue 16): the camera
circles the body from 10 to 140 deg of phase and back, 0.8 to 3 km from its centre and 25 deg
above and below its equator, looking at the centre with image down towards the south pole;
the Sun fixed at 1.1 AU on +X of the body frame. Pure Python (no numpy).

    python3 python/benches/bennu_stream.py --out /tmp/bennu_stream.csv --rows 120
"""
import argparse
import math

AU = 1.495978707e11


def quat_from_columns(x, y, z):
    """(w, x, y, z) of the rotation whose matrix has columns x, y, z (camera axes in B)."""
    m = [[x[0], y[0], z[0]], [x[1], y[1], z[1]], [x[2], y[2], z[2]]]
    tr = m[0][0] + m[1][1] + m[2][2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        q = (0.25 * s, (m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s)
    elif m[0][0] > m[1][1] and m[0][0] > m[2][2]:
        s = math.sqrt(1.0 + m[0][0] - m[1][1] - m[2][2]) * 2
        q = ((m[2][1] - m[1][2]) / s, 0.25 * s, (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s)
    elif m[1][1] > m[2][2]:
        s = math.sqrt(1.0 + m[1][1] - m[0][0] - m[2][2]) * 2
        q = ((m[0][2] - m[2][0]) / s, (m[0][1] + m[1][0]) / s, 0.25 * s, (m[1][2] + m[2][1]) / s)
    else:
        s = math.sqrt(1.0 + m[2][2] - m[0][0] - m[1][1]) * 2
        q = ((m[1][0] - m[0][1]) / s, (m[0][2] + m[2][0]) / s, (m[1][2] + m[2][1]) / s, 0.25 * s)
    n = math.sqrt(sum(c * c for c in q))
    return [c / n for c in q]


def unit(v):
    n = math.sqrt(sum(c * c for c in v))
    return [c / n for c in v]


def cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--rows", type=int, default=120)
    a = ap.parse_args()
    sun = [1.1 * AU, 0.0, 0.0]
    with open(a.out, "w") as f:
        f.write("t_s,cam_x_m,cam_y_m,cam_z_m,sun_x_m,sun_y_m,sun_z_m,qw,qx,qy,qz\n")
        for k in range(a.rows):
            s = k / max(a.rows - 1, 1)
            lon = math.radians(10.0 + 130.0 * math.sin(math.pi * s))
            lat = math.radians(25.0 * math.sin(2 * math.pi * s))
            r = 1900.0 - 1100.0 * math.cos(3 * math.pi * s)  # 0.8 to 3 km
            cam = [r * math.cos(lat) * math.cos(lon), r * math.cos(lat) * math.sin(lon), r * math.sin(lat)]
            z = unit([-c for c in cam])
            south = [0.0, 0.0, -1.0]
            d = sum(p * q for p, q in zip(south, z))
            y = unit([p - d * q for p, q in zip(south, z)])
            x = cross(y, z)
            q = quat_from_columns(x, y, z)
            f.write(",".join(f"{v:.9f}" for v in [60.0 * k, *cam, *sun, *q]) + "\n")


if __name__ == "__main__":
    main()
