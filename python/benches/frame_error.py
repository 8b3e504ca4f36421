"""A frame's error against a reference, as `src/fidelity/metrics.rs` measures it, for the
bench scripts beside this file (`mitsuba_bennu.py`, `shadow_methods.py`)."""

import numpy as np
from astropy.io import fits


def read_fits_top_down(path):
    """A FITS image as float64 rows from the top (optistim writes them bottom-up and says so
    in ROWORDER), a cube's bands summed."""
    with fits.open(path) as f:
        h = f[0].header
        data = np.asarray(f[0].data, dtype=np.float64)
    if data.ndim == 3:
        data = data.sum(axis=0)
    if h.get("ROWORDER", "BOTTOM_UP").strip() == "BOTTOM_UP":
        data = data[::-1, :]
    return data


def errors(image, reference):
    """The figures of src/fidelity/metrics.rs: total, and median / p99 over lit pixels."""
    total = abs(image.sum() / reference.sum() - 1.0)
    positive = reference[reference > 0]
    lit = 0.01 * np.quantile(positive, 0.99)
    m = reference >= lit
    rel = np.abs(image[m] / reference[m] - 1.0)
    return {
        "total": float(total),
        "median": float(np.median(rel)),
        "p99": float(np.quantile(rel, 0.99)),
        "lit_px": int(m.sum()),
    }
