//! Exact-footprint gridding: the projected quadrangle is cut along the pixel grid (one pixel
//! column peeled off at a time, then one pixel row from each column) and each pixel gets
//! `value` times the fraction of the quadrangle's area inside it.
//!
//! With a [`Slope`], the value is spread with a *linear* density over the footprint
//! (second-order conservative remapping): the density is `value/area + g . (x - centroid)`, so
//! each pixel gets `value * area_f/area + g . (M_f - centroid area_f)` with `M_f` the first
//! moment of its fragment. The fragments' first moments sum to `centroid * area`, so the
//! gradient term moves energy between pixels but never creates or loses any.
//!
//! Returns `false` (and grids nothing) when the footprint is not a usable polygon: a corner
//! could not be projected, the quadrangle folds over itself (at the limb), it is degenerate,
//! or it spans more than `MAX_SPAN_PX` pixels. The caller then falls back to a point kernel.

use super::Accum;

const MAX_SPAN_PX: i64 = 64;
/// A convex quadrangle cut by two pairs of parallel lines keeps at most 8 vertices.
const MAX_VERTS: usize = 8;

type Poly = ([[f64; 2]; MAX_VERTS], usize);

#[inline(always)]
fn cross(o: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
}

/// Shoelace signed area and first moments `(int x dA, int y dA)` of a polygon (all three carry
/// the orientation's sign: counter-clockwise positive in a y-up frame). Inlined, so callers
/// that use only the area pay only for the area.
#[inline(always)]
fn area_moments(v: &[[f64; 2]]) -> (f64, f64, f64) {
    let n = v.len();
    let (mut a, mut mx, mut my) = (0.0, 0.0, 0.0);
    for i in 0..n {
        let j = if i + 1 == n { 0 } else { i + 1 };
        let c = v[i][0] * v[j][1] - v[j][0] * v[i][1];
        a += c;
        mx += (v[i][0] + v[j][0]) * c;
        my += (v[i][1] + v[j][1]) * c;
    }
    (0.5 * a, mx / 6.0, my / 6.0)
}

#[inline(always)]
fn verts(p: &Poly) -> &[[f64; 2]] {
    &p.0[..p.1]
}

/// Centroid `[u, v]` and unsigned area [px^2] of a quadrangle footprint (`None` if degenerate).
#[inline]
pub fn centroid_area(c: &[[f64; 2]; 4]) -> Option<([f64; 2], f64)> {
    let (a, mx, my) = area_moments(c);
    (a.is_finite() && a.abs() > 1e-300).then(|| ([mx / a, my / a], a.abs()))
}

/// A linear density over a footprint: gradient `grad` [value/px^3] about `centroid` [px].
#[derive(Clone, Copy, Debug, Default)]
pub struct Slope {
    pub centroid: [f64; 2],
    pub grad: [f64; 2],
}

/// Splits `p` along `coord[axis] = at` into the parts below and above (one pass).
#[inline(always)]
fn split(p: &Poly, axis: usize, at: f64) -> (Poly, Poly) {
    let mut lo = ([[0.0; 2]; MAX_VERTS], 0usize);
    let mut hi = ([[0.0; 2]; MAX_VERTS], 0usize);
    let (v, n) = (&p.0, p.1);
    if n == 0 {
        return (lo, hi);
    }
    let push = |q: &mut Poly, x: [f64; 2]| {
        if q.1 < MAX_VERTS {
            q.0[q.1] = x;
            q.1 += 1;
        }
    };
    let mut prev = v[n - 1];
    let mut prev_lo = prev[axis] <= at;
    for &cur in v.iter().take(n) {
        let cur_lo = cur[axis] <= at;
        if cur_lo != prev_lo {
            let t = (at - prev[axis]) / (cur[axis] - prev[axis]);
            let mut x = [
                prev[0] + t * (cur[0] - prev[0]),
                prev[1] + t * (cur[1] - prev[1]),
            ];
            x[axis] = at;
            push(&mut lo, x);
            push(&mut hi, x);
        }
        if cur_lo {
            push(&mut lo, cur);
        } else {
            push(&mut hi, cur);
        }
        prev = cur;
        prev_lo = cur_lo;
    }
    (lo, hi)
}

/// Grids `value` over the footprint `c` with the linear density of `slope` (uniform if `None`).
#[inline]
pub fn splat_linear(c: &[[f64; 2]; 4], value: f64, slope: Option<&Slope>, acc: &mut Accum) -> bool {
    if c.iter().any(|p| !(p[0].is_finite() && p[1].is_finite())) {
        return false;
    }
    // Convex and consistently oriented: all corner turns have the same sign.
    let t = [
        cross(c[3], c[0], c[1]),
        cross(c[0], c[1], c[2]),
        cross(c[1], c[2], c[3]),
        cross(c[2], c[3], c[0]),
    ];
    let pos = t.iter().all(|&x| x >= 0.0);
    let neg = t.iter().all(|&x| x <= 0.0);
    if !(pos || neg) {
        return false;
    }
    let (mut umin, mut umax, mut vmin, mut vmax) = (c[0][0], c[0][0], c[0][1], c[0][1]);
    for p in &c[1..] {
        umin = umin.min(p[0]);
        umax = umax.max(p[0]);
        vmin = vmin.min(p[1]);
        vmax = vmax.max(p[1]);
    }
    let (i0, i1, j0, j1) = (
        umin.floor() as i64,
        umax.floor() as i64,
        vmin.floor() as i64,
        vmax.floor() as i64,
    );
    if i0 == i1 && j0 == j1 {
        acc.add(i0, j0, value);
        return true;
    }
    if i1 - i0 >= MAX_SPAN_PX || j1 - j0 >= MAX_SPAN_PX {
        return false;
    }
    let mut quad: Poly = ([[0.0; 2]; MAX_VERTS], 4);
    quad.0[..4].copy_from_slice(c);
    let total = area_moments(c).0;
    if total.abs() < 1e-300 || !total.is_finite() {
        return false;
    }
    let k = value / total;
    // Fragment value: uniform part plus the gradient's first-moment part. Orientation: `total`
    // and every fragment's area and moments carry the same sign, hence `/ sign`.
    let sign = total.signum();
    let frag = |p: &Poly| -> f64 {
        match slope {
            None => area_moments(verts(p)).0 * k,
            Some(s) => {
                let (a, mx, my) = area_moments(verts(p));
                (a * k
                    + (s.grad[0] * (mx - s.centroid[0] * a) + s.grad[1] * (my - s.centroid[1] * a))
                        * sign)
                    .max(0.0)
            }
        }
    };
    // Peel off one pixel column at a time, then one pixel row at a time from each column.
    let mut rest = quad;
    for i in i0..=i1 {
        let col = if i < i1 {
            let (col, r) = split(&rest, 0, (i + 1) as f64);
            rest = r;
            col
        } else {
            rest
        };
        if col.1 < 3 {
            continue;
        }
        let mut rest_col = col;
        for j in j0..=j1 {
            let cell = if j < j1 {
                let (cell, r) = split(&rest_col, 1, (j + 1) as f64);
                rest_col = r;
                cell
            } else {
                rest_col
            };
            if cell.1 >= 3 {
                acc.add(i, j, frag(&cell));
            }
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Grids a unit value over a 4 x 4 pixel grid; `None` when the footprint is refused.
    fn grid_with(c: [[f64; 2]; 4], slope: Option<&Slope>) -> Option<Vec<f64>> {
        let mut data = vec![0i64; 16];
        let scale = (1u64 << 40) as f64;
        let mut acc = Accum {
            data: &mut data,
            x0: 0,
            y0: 0,
            w: 4,
            h: 4,
            scale,
        };
        splat_linear(&c, 1.0, slope, &mut acc)
            .then(|| data.iter().map(|&x| x as f64 / scale).collect())
    }

    fn grid(c: [[f64; 2]; 4]) -> Vec<f64> {
        grid_with(c, None).expect("footprint refused")
    }

    #[test]
    fn a_unit_square_across_four_pixels_splits_in_quarters() {
        let g = grid([[0.5, 0.5], [1.5, 0.5], [1.5, 1.5], [0.5, 1.5]]);
        for (i, x) in g.iter().enumerate() {
            let expect = if [0, 1, 4, 5].contains(&i) { 0.25 } else { 0.0 };
            assert!((x - expect).abs() < 1e-12, "{i} {x}");
        }
    }

    #[test]
    fn a_rotated_quad_conserves_value_and_orientation_does_not_matter() {
        let c = [[1.2, 0.3], [2.9, 1.1], [2.1, 2.8], [0.4, 1.9]];
        let g = grid(c);
        assert!((g.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        let r = grid([c[3], c[2], c[1], c[0]]);
        for (a, b) in g.iter().zip(&r) {
            assert!((a - b).abs() < 1e-12);
        }
    }

    #[test]
    fn a_linear_slope_moves_energy_but_conserves_it() {
        let c = [[0.5, 0.5], [2.5, 0.5], [2.5, 1.5], [0.5, 1.5]];
        let (cen, a) = centroid_area(&c).unwrap();
        assert!(
            (cen[0] - 1.5).abs() < 1e-12 && (cen[1] - 1.0).abs() < 1e-12 && (a - 2.0).abs() < 1e-12
        );
        // Density 0.5 + 0.2 (u - 1.5): positive over the footprint.
        let slope = Slope {
            centroid: cen,
            grad: [0.2, 0.0],
        };
        let g = grid_with(c, Some(&slope)).expect("footprint refused");
        assert!((g.iter().sum::<f64>() - 1.0).abs() < 1e-9);
        // Pixel column 0 covers u in [0.5, 1]: integral of the density over [0.5,1]x[0.5,1].
        let exact = |u0: f64, u1: f64, v0: f64, v1: f64| {
            let f = |u: f64| 0.5 * u + 0.1 * (u - 1.5).powi(2);
            (f(u1) - f(u0)) * (v1 - v0)
        };
        assert!((g[0] - exact(0.5, 1.0, 0.5, 1.0)).abs() < 1e-9, "{}", g[0]);
        assert!((g[1] - exact(1.0, 2.0, 0.5, 1.0)).abs() < 1e-9, "{}", g[1]);
        assert!((g[2] - exact(2.0, 2.5, 0.5, 1.0)).abs() < 1e-9, "{}", g[2]);
    }

    #[test]
    fn a_folded_quad_is_refused() {
        assert!(grid_with([[0.0, 0.0], [2.0, 2.0], [2.0, 0.0], [0.0, 2.0]], None).is_none());
    }
}
