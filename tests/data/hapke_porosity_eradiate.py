"""Reference values for Hapke's porosity factor K (Hapke 2008), from an independent
implementation that has no K: the `hapke` BSDF of the PyPI package `eradiate-mitsuba` 0.5.0
(variant scalar_mono_double), through Hapke's own scaling. On a smooth surface (no macroscopic
roughness) and without coherent backscatter,

    r_K(mu0, mu, g) = K w/(4 pi) mu0/(mu0 + mu) [P(g)(1 + B_S(g)) + H(mu0/K) H(mu/K) - 1]
                    = K r_1(mu0/K, mu/K, g),

so the BRDF f_r = r/mu0 with porosity equals the BRDF without it at the cosines divided by K,
at the same phase angle: f_r,K(mu0, mu, g) = f_r,1(mu0/K, mu/K, g). For each geometry
(incidence i, emission e, azimuth psi between their planes) the script evaluates eradiate at
the incidence acos(mu0/K), the emission acos(mu/K) and the azimuth that keeps the phase angle
(geometries where no azimuth does are left out), with K from the filling factor phi:
K = -ln(1 - 1.209 phi^(2/3)) / (1.209 phi^(2/3)) (Hapke 2008, Eq. 14).

    python -m venv v && v/bin/pip install eradiate-mitsuba==0.5.0 && \
        v/bin/python tests/data/hapke_porosity_eradiate.py > tests/data/hapke_porosity_eradiate.csv

Columns: phi, K, the parameters (w, b, c, B0, h), the geometry (i_deg, e_deg, psi_deg) and
eradiate's f_r [1/sr] at the scaled geometry, which tests/hapke.rs compares with optistim's
Hapke of filling factor phi at (i, e, psi).
"""
import itertools
import math
import mitsuba as mi

mi.set_variant("scalar_mono_double")

phis = [0.1, 0.41, 0.6]
params = [
    # w, b, c, B0, h (smooth: theta = 0)
    (0.25, 0.21, 0.7, 1.0, 0.07),
    (0.6, 0.3, 0.4, 0.5, 0.2),
    (0.95, 0.5, 0.2, 0.8, 0.5),
]
angles = [0.0, 30.0, 60.0, 80.0, 89.0]
azimuths = [0.0, 90.0, 180.0]
ctx = mi.BSDFContext()
print("phi,K,w,b,c,B0,h,i_deg,e_deg,psi_deg,f_r")
for phi, (w, b, c, B0, h) in itertools.product(phis, params):
    x = 1.209 * phi ** (2.0 / 3.0)
    K = -math.log(1.0 - x) / x
    bsdf = mi.load_dict({"type": "hapke", "w": w, "b": b, "c": c, "theta": 0.0, "B_0": B0, "h": h})
    for i, e, psi in itertools.product(angles, angles, azimuths):
        ri, re, rp = (math.radians(a) for a in (i, e, psi))
        mu0, mu = math.cos(ri), math.cos(re)
        cos_g = mu0 * mu + math.sin(ri) * math.sin(re) * math.cos(rp)
        mu0s, mus = mu0 / K, mu / K
        si_s, se_s = math.sqrt(1.0 - mu0s * mu0s), math.sqrt(1.0 - mus * mus)
        cos_psi_s = (cos_g - mu0s * mus) / (si_s * se_s)
        if abs(cos_psi_s) > 1.0:
            continue
        psi_s = math.acos(cos_psi_s)
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(si_s, 0.0, mu0s)
        wo = mi.Vector3f(se_s * math.cos(psi_s), se_s * math.sin(psi_s), mus)
        v = bsdf.eval(ctx, si, wo)
        val = float(v[0] if hasattr(v, "__len__") else v) / mus
        print(f"{phi},{K:.17g},{w},{b},{c},{B0},{h},{i},{e},{psi},{val:.17g}")
