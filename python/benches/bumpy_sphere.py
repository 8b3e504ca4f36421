"""A closed bumpy sphere as a Wavefront OBJ, for the mesh benchmarks (issue 16's 200,000-facet
bar): an icosahedron's faces each cut into `f^2` triangles (a class I geodesic sphere of
`20 f^2` facets, all about the same size and shape), pushed out to radius `R (1 + bump b)` with
`b` a sum of three sinusoids in longitude and latitude, in km, so that the body shadows
itself. Standard library only.

    python3 python/benches/bumpy_sphere.py --frequency 100 --out /tmp/bumpy_200k.obj

gives 200,000 facets; `bumpy_200k.toml` beside this script renders it with Bennu's camera.
"""

import argparse
import math


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frequency", type=int, default=100, help="triangles per icosahedron edge")
    ap.add_argument("--radius-km", type=float, default=0.25)
    ap.add_argument("--bump", type=float, default=0.08, help="relative amplitude")
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    t = (1 + 5 ** 0.5) / 2
    ico = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t),
           (0, -1, -t), (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
             (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
             (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    f = a.frequency
    index, verts, tris = {}, [], []

    def vertex(face, i, j):
        # Barycentric grid point (i, j) of `face`, keyed exactly so that faces share edges.
        p, q, r = face
        key = tuple(sorted(((f - i - j, p), (i, q), (j, r))))
        key = tuple(kv for kv in key if kv[0] != 0)
        if key not in index:
            x = [sum(w * ico[v][c] for w, v in key) / f for c in range(3)]
            n = math.sqrt(sum(c * c for c in x))
            x = [c / n for c in x]
            lon, lat = math.atan2(x[1], x[0]), math.asin(max(-1.0, min(1.0, x[2])))
            b = (0.5 * math.sin(3 * lon) * math.cos(2 * lat)
                 + 0.3 * math.sin(7 * lon + 1.0) * math.sin(5 * lat)
                 + 0.2 * math.cos(13 * lon + 2.0) * math.cos(11 * lat))
            r = a.radius_km * (1.0 + a.bump * b)
            index[key] = len(verts) + 1
            verts.append([r * c for c in x])
        return index[key]

    for face in faces:
        for i in range(f):
            for j in range(f - i):
                v0, v1, v2 = vertex(face, i, j), vertex(face, i + 1, j), vertex(face, i, j + 1)
                tris.append((v0, v1, v2))
                if i + j < f - 1:
                    tris.append((v1, vertex(face, i + 1, j + 1), v2))
    with open(a.out, "w") as out:
        out.write(f"# bumpy geodesic sphere, {len(tris)} facets (python/benches/bumpy_sphere.py)\n")
        for v in verts:
            out.write(f"v {v[0]:.9f} {v[1]:.9f} {v[2]:.9f}\n")
        for tri in tris:
            out.write(f"f {tri[0]} {tri[1]} {tri[2]}\n")


if __name__ == "__main__":
    main()
