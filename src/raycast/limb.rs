//! A pixel the limb cuts, read in the square root of the distance to the limb.
//!
//! A DEM that tilts the normals only (no displacement) weighs the light of the shape's area
//! elements by the DEM normal's `cos(theta_r)` (Eq. 37): per unit of the image, which is what a
//! line of sight's solid angle covers, that is the radiance times `mu / mu_shape`
//! ([`super::Tracer`]'s foreshortening). The shape's `mu_shape` goes to zero at its limb while
//! the DEM's `mu` need not, so the light per unit of the image grows as the inverse square
//! root of the distance to the limb. Its integral over a pixel is finite, but a rule over the
//! image, adaptive or not, converges slowly there: a cell at the limb holds an error of the
//! order of the square root of its side, and a lattice's variance grows without bound.
//!
//! Read evenly in `s`, the square root of the distance to the limb (`x = x_limb + s^2`,
//! `dx = 2 s ds`), the light per unit of `s` is bounded, and lattices over `s` converge
//! ([`warped_mean`]). On Artemis I row 852 (a crescent of ridge tops 0.1-0.3 px wide at 161 deg
//! of phase, 972 lit pixels) warped lattices of 256 and 512 a side agree on the total to
//! 1.4e-4, where unwarped ones of 64-1024 a side had not settled within 3.4e-3
//! (`docs/performance.md`, "Artemis I 852 against lattices warped at the limb").

use super::Tracer;
use crate::body::Shape;

/// Whether the limb of the scene the tracer sees needs [`warped_mean`]: a DEM tilts the
/// normals of an undisplaced sphere or ellipsoid seen alone (no placed bodies, which the
/// warped lattice, reading only the shape's side of the limb, would miss beyond it), at least
/// `8` px in radius (a line of a pixel then crosses the limb once, which is what
/// [`warped_mean`] assumes).
pub fn is_singular(tracer: &Tracer) -> bool {
    let shape = &tracer.scene.body.shape;
    let (fu, fv) = tracer.intrinsics.focal_px();
    let radius_px = (shape.inner_radius_m() / tracer.camera_m.length())
        .min(1.0)
        .asin()
        * fu.min(fv);
    tracer.terrain.is_some()
        && !tracer.displaced
        && tracer.others.is_empty()
        && !matches!(shape, Shape::Mesh(_))
        && radius_px >= 8.0
}

/// Whether the shape's limb crosses pixel `(i, j)`: its four corners do not all see the shape.
pub fn cuts(tracer: &Tracer, i: usize, j: usize) -> bool {
    let (u, v) = (i as f64, j as f64);
    let on = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)]
        .map(|(a, b)| tracer.shape_at(u + a, v + b).is_some());
    on.iter().any(|&x| x != on[0])
}

/// The integral [sr m^2] of the tracer's light over pixel `(i, j)` by `n` lines of `n` lines of
/// sight, read evenly in the square root of the distance to the limb (the module's
/// documentation), and the lines of sight cast (`n^2`).
///
/// The lines run across the limb: along the image axis on which `mu_shape^2`, read at the
/// pixel's corners, changes most. On each, the limb's crossing nearest to the pixel (among
/// those within 3 px, found at steps of 1/8 px and by bisection on the shape) is `x_limb`; on
/// the shape's side of it, `x = x_limb +- s^2` is read at midpoints of `n` even steps of `s`
/// over the part of the pixel there and weighed by `2 s ds`. A line that does not cross the
/// limb within 3 px is read at `n` even midpoints.
pub fn warped_mean(tracer: &Tracer, i: usize, j: usize, n: usize) -> (f64, u64) {
    let camera_m = tracer.camera_m;
    let q = |u: f64, v: f64| {
        tracer.shape_at(u, v).map_or(0.0, |(p, normal)| {
            let mu = normal.dot((camera_m - p).normalize());
            mu * mu
        })
    };
    let (i, j) = (i as f64, j as f64);
    let [q00, q10, q01, q11] = [q(i, j), q(i + 1.0, j), q(i, j + 1.0), q(i + 1.0, j + 1.0)];
    let across_u = ((q10 - q00) + (q11 - q01)).abs() >= ((q01 - q00) + (q11 - q10)).abs();
    // `x` across the limb, `y` along it.
    let at = |x: f64, y: f64| if across_u { (x, y) } else { (y, x) };
    let (x0, y0) = at(i, j);
    let on = |x: f64, y: f64| {
        let (u, v) = at(x, y);
        tracer.shape_at(u, v).is_some()
    };
    let light = |x: f64, y: f64| {
        let (u, v) = at(x, y);
        tracer.cast(u, v).pl_per_px2
    };
    // The limb's crossing of line `y` nearest to `[x0, x0 + 1]`, among those within 3 px.
    let limb = |y: f64| -> Option<f64> {
        const STEPS: usize = 56;
        let (lo, hi) = (x0 - 3.0, x0 + 4.0);
        let dx = (hi - lo) / STEPS as f64;
        let off = |c: f64| (x0 - c).max(c - x0 - 1.0).max(0.0);
        let mut best: Option<f64> = None;
        let mut prev = on(lo, y);
        for k in 1..=STEPS {
            let x = lo + dx * k as f64;
            let cur = on(x, y);
            if cur != prev {
                let (mut l, mut r) = (x - dx, x);
                for _ in 0..60 {
                    let m = 0.5 * (l + r);
                    if on(m, y) == prev { l = m } else { r = m }
                }
                let c = 0.5 * (l + r);
                if best.is_none_or(|b| off(c) < off(b)) {
                    best = Some(c);
                }
            }
            prev = cur;
        }
        best
    };
    let step = 1.0 / n as f64;
    let line = |y: f64| -> f64 {
        let Some(xl) = limb(y) else {
            return (0..n)
                .map(|a| light(x0 + (a as f64 + 0.5) * step, y))
                .sum::<f64>()
                * step;
        };
        // The shape's side of the crossing, within the pixel.
        let ahead = on(xl + 1e-6, y);
        let (a0, a1) = if ahead {
            (x0.max(xl), x0 + 1.0)
        } else {
            (x0, (x0 + 1.0).min(xl))
        };
        if a1 <= a0 {
            return 0.0;
        }
        let (s0, s1) = ((a0 - xl).abs().sqrt(), (a1 - xl).abs().sqrt());
        let (s0, s1) = (s0.min(s1), s0.max(s1));
        let ds = (s1 - s0) * step;
        (0..n)
            .map(|a| {
                let s = s0 + (a as f64 + 0.5) * ds;
                let x = if ahead { xl + s * s } else { xl - s * s };
                light(x, y) * 2.0 * s * ds
            })
            .sum()
    };
    let sum = (0..n)
        .map(|b| line(y0 + (b as f64 + 0.5) * step))
        .sum::<f64>()
        * step;
    (sum, (n * n) as u64)
}
