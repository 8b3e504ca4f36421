"""Optistim against Mitsuba 3 on Bennu's mesh (issue 16's peer comparison).

The scene is `bennu_lambert.toml` beside this script: Bennu's 12,288-facet shape model seen
from 1 km at 41 deg of phase, 1024 x 1024, a Lambert surface (Mitsuba has no Hapke that
matches ours term by term), direct sunlight with the shadows the body casts on itself.
Mitsuba 3 (the `mitsuba` wheel, variant `llvm_ad_rgb`) renders the same mesh, camera and Sun
with its `direct` integrator (one emitter sample, no BSDF sample: the Sun is a directional
emitter) and a box pixel filter, so each pixel is its footprint's mean radiance, what
optistim integrates. Both are compared with optistim's converged reference
(`optistim render --reference`), with the error figures of `src/fidelity/metrics.rs`
(relative error per lit pixel: median, p99; and the total).

Units: optistim's reference is power per pixel [W], Mitsuba's radiance per unit irradiance.
A pinhole pixel's power is `L A p^2 cos^4(eps) / f^2`, so the reference is divided by
`cos^4(eps)` at each pixel's centre and one constant scales Mitsuba to it: the ratio of the
totals of Mitsuba's deepest render (`--scale-spp`), which is not among the compared ones.
Without `--reference` (a mesh's converged reference is slow: the steps of light between
facets are refined to the deepest level everywhere), that deepest render, scaled to
optistim's frame by the median ratio over the lit pixels, is the reference.

Timing, interleaved: each round renders every Mitsuba sample count once (after one warm-up
render per count, which compiles and caches its kernels) and runs `optistim bench` on the
same scene; medians over the rounds. Both on all cores (`--threads`).

    cargo run --release -- render python/benches/bennu_lambert.toml --reference \
        --tolerance 1e-5 --out out/bennu_ref
    pip install mitsuba astropy numpy       # mitsuba 3.9.1, drjit 1.5.0 here
    apt-get install libllvm19               # Debian 12's LLVM 14/15 cannot compile
    DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM-19.so \
        python python/benches/mitsuba_bennu.py --reference out/bennu_ref/power.fits

(Dr.Jit 1.5's kernels use an intrinsic, `llvm.maximum`, that LLVM 14 and 15 abort on.)
"""

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
import tomllib

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from frame_error import errors, read_fits_top_down  # noqa: E402


def mitsuba_scene(mi, scene, scene_dir, spp):
    cam = scene["camera"]
    w, h = cam["resolution_px"]
    pitch = cam["pixel_pitch_m"]
    f = cam["focal_length_m"]
    fov_x = math.degrees(2.0 * math.atan(0.5 * w * pitch / f))
    eye = scene["pose"]["camera_position_m"]
    sun = np.array(scene["sun"]["position_m"], dtype=float)
    sun_dir = sun / np.linalg.norm(sun)
    mesh = scene["body"]["mesh"]
    scale = {"km": 1000.0, "m": 1.0}[mesh.get("units", "m")]
    albedo = scene["body"]["albedo"]
    T = mi.ScalarTransform4f
    return mi.load_dict(
        {
            "type": "scene",
            "integrator": {
                "type": "direct",
                "emitter_samples": 1,
                "bsdf_samples": 0,
                "hide_emitters": True,
            },
            "sensor": {
                "type": "perspective",
                "fov": fov_x,
                "fov_axis": "x",
                # optistim's look_at_body keeps the body's +Z up in the image
                # (src/config/mod.rs: look_at with -Z as image down).
                "to_world": T().look_at(origin=eye, target=[0, 0, 0], up=[0, 0, 1]),
                "film": {
                    "type": "hdrfilm",
                    "width": w,
                    "height": h,
                    "rfilter": {"type": "box"},
                    "pixel_format": "rgb",
                },
                "sampler": {"type": "multijitter", "sample_count": spp},
            },
            "sun": {
                "type": "directional",
                "direction": (-sun_dir).tolist(),
                "irradiance": {"type": "rgb", "value": 1.0},
            },
            "body": {
                "type": "obj",
                "filename": os.path.normpath(os.path.join(scene_dir, mesh["path"])),
                "face_normals": True,
                "to_world": T().scale(scale),
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": albedo}},
            },
        }
    )


def render_mitsuba(mi, dr, scene):
    t0 = time.perf_counter()
    img = mi.render(scene)
    dr.eval(img)
    arr = np.array(img, dtype=np.float64)[:, :, 0]
    return arr, (time.perf_counter() - t0) * 1e3


def bench_optistim(exe, scene_path, frames, threads):
    with tempfile.TemporaryDirectory() as d:
        per = os.path.join(d, "frames.jsonl")
        subprocess.run(
            [exe, "bench", "--scene", scene_path, "--frames", str(frames),
             "--threads", str(threads), "--per-frame", per],
            check=True, capture_output=True,
        )
        rows = [json.loads(line) for line in open(per)]
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=os.path.join(HERE, "bennu_lambert.toml"))
    ap.add_argument("--optistim", default="target/release/optistim")
    ap.add_argument("--reference", default=None,
                    help="power.fits of optistim render --reference; without it, Mitsuba's "
                         "own render at --scale-spp samples is the reference")
    ap.add_argument("--spp", default="1,2,4,8,16,32,64,128,256")
    ap.add_argument("--scale-spp", type=int, default=1024)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--frames", type=int, default=10, help="optistim bench frames per round")
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--out", default=None, help="write the results as JSON here")
    args = ap.parse_args()

    import drjit as dr
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    if args.threads:
        dr.set_thread_count(args.threads)

    scene = tomllib.load(open(args.scene, "rb"))
    scene_dir = os.path.dirname(os.path.abspath(args.scene))
    cam = scene["camera"]
    w, h = cam["resolution_px"]
    pitch, f = cam["pixel_pitch_m"], cam["focal_length_m"]
    x = (np.arange(w) + 0.5 - 0.5 * w) * pitch
    y = (np.arange(h) + 0.5 - 0.5 * h) * pitch
    cos_eps = f / np.sqrt(f * f + x[None, :] ** 2 + y[:, None] ** 2)
    spps = [int(s) for s in args.spp.split(",")]
    scenes = {s: mitsuba_scene(mi, scene, scene_dir, s) for s in spps}
    # The deepest render as passes of 256 samples with their own seeds (one pass of all
    # would hold every sample's state in memory at once).
    passes = max(1, args.scale_spp // 256)
    pass_scene = mitsuba_scene(mi, scene, scene_dir, min(256, args.scale_spp))
    t0 = time.perf_counter()
    deep = sum(np.array(mi.render(pass_scene, seed=1000 + k), dtype=np.float64)[:, :, 0]
               for k in range(passes)) / passes
    deep_ms = (time.perf_counter() - t0) * 1e3
    with tempfile.TemporaryDirectory() as d:
        subprocess.run([args.optistim, "render", args.scene, "--out", d],
                       check=True, capture_output=True)
        ours = read_fits_top_down(os.path.join(d, "power.fits"))
    if args.reference:
        reference = read_fits_top_down(args.reference) / cos_eps**4
        k = reference.sum() / deep.sum()
        print(f"scale from {args.scale_spp} spp: {k:.6e}; its own figures:",
              errors(k * deep, reference), file=sys.stderr)
    else:
        # Mitsuba's deepest render, in optistim's units by the median ratio over the lit
        # pixels (those inside a facet, where both are exact; a ratio of totals would carry
        # optistim's own error at the edges of the light into every pixel). The totals are
        # then compared as they are.
        lit = deep >= 0.01 * np.quantile(deep[deep > 0], 0.99)
        k = np.median((ours / cos_eps**4)[lit] / deep[lit])
        reference = k * deep
        print(f"reference: Mitsuba at {args.scale_spp} spp ({deep_ms:.0f} ms)", file=sys.stderr)

    images, times = {}, {s: [] for s in spps}
    ours_frame, ours_render = [], []
    for s in spps:
        images[s], _ = render_mitsuba(mi, dr, scenes[s])  # warm-up: kernels compiled here
    for r in range(args.rounds):
        for s in spps:
            _, ms = render_mitsuba(mi, dr, scenes[s])
            times[s].append(ms)
        rows = bench_optistim(args.optistim, args.scene, args.frames, args.threads)
        ours_frame += [row["ms"] for row in rows]
        ours_render += [row["timings_ms"]["total"] for row in rows]
        print(f"round {r + 1}: optistim frame median {statistics.median(ours_frame):.1f} ms",
              file=sys.stderr)

    results = {"mitsuba": [], "optistim": {},
               "reference": args.reference or f"mitsuba {args.scale_spp} spp"}
    for s in spps:
        e = errors(k * images[s], reference)
        e.update(spp=s, ms=statistics.median(times[s]))
        results["mitsuba"].append(e)
    results["optistim"] = errors(ours / cos_eps**4, reference)
    results["optistim"].update(
        frame_ms=statistics.median(ours_frame),
        render_ms=statistics.median(ours_render),
    )
    print(json.dumps(results, indent=1))
    if args.out:
        json.dump(results, open(args.out, "w"), indent=1)


if __name__ == "__main__":
    main()
