"""Reference values of the Hapke BRDF from an independent implementation: the `hapke` BSDF of
the PyPI package `eradiate-mitsuba` (Hapke 1984 roughness, 2002 H function, shadow-hiding
opposition effect, two-term Henyey-Greenstein with c the back-lobe weight), evaluated in
double precision (variant scalar_mono_double).

    python -m venv v && v/bin/pip install eradiate-mitsuba==0.5.0 && v/bin/python tests/data/hapke_eradiate.py > tests/data/hapke_eradiate.csv

Columns: the parameters (w, b, c, theta_deg, B0, h), the geometry (incidence i, emission e and
the azimuth psi between the planes of incidence and emission, deg) and the BSDF's value
divided by cos(e): the BRDF f_r [1/sr], which tests/hapke.rs compares with optistim's.
"""
import itertools
import mitsuba as mi

mi.set_variant("scalar_mono_double")
import math

params = [
    # w, b, c, theta_deg, B0, h: lunar-like (Sato et al. 2014 style), rough, smooth, bright
    (0.25, 0.21, 0.7, 23.0, 1.0, 0.07),
    (0.6, 0.3, 0.4, 35.0, 0.5, 0.2),
    (0.12, 0.1, 0.9, 0.0, 0.0, 0.05),
    (0.95, 0.5, 0.2, 10.0, 0.8, 0.5),
]
geometry = [
    (i, e, psi)
    for i, e, psi in itertools.product(
        [0.0, 15.0, 45.0, 70.0, 85.0, 89.5], [0.0, 30.0, 60.0, 80.0, 89.5], [0.0, 45.0, 120.0, 180.0]
    )
]
ctx = mi.BSDFContext()
print("w,b,c,theta_deg,B0,h,i_deg,e_deg,psi_deg,f_r")
for w, b, c, th, B0, h in params:
    bsdf = mi.load_dict({"type": "hapke", "w": w, "b": b, "c": c, "theta": th, "B_0": B0, "h": h})
    for i, e, psi in geometry:
        ri, re, rp = (math.radians(x) for x in (i, e, psi))
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(math.sin(ri), 0.0, math.cos(ri))
        wo = mi.Vector3f(math.sin(re) * math.cos(rp), math.sin(re) * math.sin(rp), math.cos(re))
        v = bsdf.eval(ctx, si, wo)
        val = float(v[0] if hasattr(v, "__len__") else v) / math.cos(re)
        print(f"{w},{b},{c},{th},{B0},{h},{i},{e},{psi},{val:.17g}")
