"""Reference values for tests/hapke.rs: the Hapke BRDF of refmod 0.1.0 (PyPI `refmod`,
arunoruto/reflectance-models, MIT), its AMSA model with an isotropic particle phase function
(Legendre coefficients [1, 0]: refmod reads b_n[0] and b_n[1] whatever the length), where it coincides with optistim's Hapke with b = 0: isotropic
multiple scattering (2002 H-function), shadow hiding (SHOE) and coherent backscatter (CBOE) on
a smooth surface; refmod has no porosity factor, so K = 1 (filling factor 0).

Writes `w, B0_S, h_S, B0_C, h_C, theta, i_deg, e_deg, azimuth_deg, r` where r is refmod's
reflectance (the BRDF times cos i). Exactly zero phase is left out: there refmod's CBOE term
(1 - exp(-z)) / (z + EPS) is 0 instead of its limit 1. Run with jax and refmod installed:
python hapke_refmod.py > hapke_refmod.csv
"""
import itertools
import numpy as np
import jax
jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp
from refmod.hapke.amsa import _refl_amsa_scalar

# Smooth surfaces only (theta = 0): refmod's roughness correction is not Hapke's (1984) as
# eradiate and optistim implement it (those two agree to 4e-10, tests/hapke.rs); with
# roughness the two differ by up to 160 % at grazing geometries (i = e = 89 deg).
params = [  # w, B0_S, h_S, B0_C, h_C, theta (rad)
    (0.12, 1.8, 0.07, 0.5, 0.05, 0.0),
    (0.55, 1.0, 0.06, 0.5, 0.02, 0.0),
    (0.9, 0.0, 0.1, 0.9, 0.1, 0.0),
    (0.3, 2.5, 0.2, 0.3, 0.005, 0.0),
]
angles = [0.0, 20.0, 45.0, 70.0, 85.0, 89.0]
azimuths = [0.0, 30.0, 90.0, 150.0, 180.0]
print("w,b0_s,h_s,b0_c,h_c,theta,i_deg,e_deg,azimuth_deg,r")
for (w, b0s, hs, b0c, hc, th), i, e, az in itertools.product(params, angles, angles, azimuths):
    ri, re, ra = np.radians([i, e, az])
    cos_g = np.cos(ri) * np.cos(re) + np.sin(ri) * np.sin(re) * np.cos(ra)
    if cos_g > 1.0 - 1e-15:
        continue
    inc = jnp.array([np.sin(ri), 0.0, np.cos(ri)])
    emi = jnp.array([np.sin(re) * np.cos(ra), np.sin(re) * np.sin(ra), np.cos(re)])
    n = jnp.array([0.0, 0.0, 1.0])
    r = float(_refl_amsa_scalar(jnp.array(w), jnp.array([1.0, 0.0]), inc, emi, n, th, hs, b0s, hc, b0c))
    if np.isfinite(r):
        print(f"{w},{b0s},{hs},{b0c},{hc},{th},{i},{e},{az},{r:.17g}")
