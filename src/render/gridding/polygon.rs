//! Exact-footprint gridding: the projected quadrangle is clipped against each pixel it touches
//! (Sutherland-Hodgman against the pixel's four edges) and each pixel gets `value` times the
//! fraction of the quadrangle's area inside it.
//!
//! Returns `false` (and grids nothing) when the footprint is not a usable polygon: a corner
//! could not be projected, the quadrangle folds over itself (at the limb), it is degenerate,
//! or it spans more than `MAX_SPAN_PX` pixels. The caller then falls back to a point kernel.

use super::Accum;

const MAX_SPAN_PX: i64 = 64;
/// A quadrangle clipped by two pairs of parallel lines has at most 8 vertices.
const MAX_VERTS: usize = 10;

type Poly = ([[f64; 2]; MAX_VERTS], usize);

#[inline(always)]
fn cross(o: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
}

/// Shoelace area (signed, counter-clockwise positive in a y-up frame).
#[inline]
fn area(p: &Poly) -> f64 {
    let (v, n) = (&p.0, p.1);
    let mut s = 0.0;
    for i in 0..n {
        let j = if i + 1 == n { 0 } else { i + 1 };
        s += v[i][0] * v[j][1] - v[j][0] * v[i][1];
    }
    0.5 * s
}

/// Keeps the part of `p` where `sign * (coord[axis] - at) <= 0`.
#[inline]
fn clip(p: &Poly, axis: usize, at: f64, sign: f64) -> Poly {
    let mut out = ([[0.0; 2]; MAX_VERTS], 0usize);
    let (v, n) = (&p.0, p.1);
    if n == 0 {
        return out;
    }
    let mut prev = v[n - 1];
    let mut prev_in = sign * (prev[axis] - at) <= 0.0;
    for &cur in v.iter().take(n) {
        let cur_in = sign * (cur[axis] - at) <= 0.0;
        if cur_in != prev_in && out.1 < MAX_VERTS {
            let t = (at - prev[axis]) / (cur[axis] - prev[axis]);
            out.0[out.1] = [
                prev[0] + t * (cur[0] - prev[0]),
                prev[1] + t * (cur[1] - prev[1]),
            ];
            out.1 += 1;
        }
        if cur_in && out.1 < MAX_VERTS {
            out.0[out.1] = cur;
            out.1 += 1;
        }
        prev = cur;
        prev_in = cur_in;
    }
    out
}

#[inline]
pub fn splat(c: &[[f64; 2]; 4], value: f64, acc: &mut Accum) -> bool {
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
    let total = area(&quad);
    if total.abs() < 1e-300 || !total.is_finite() {
        return false;
    }
    let k = value / total;
    for i in i0..=i1 {
        let col = if i0 == i1 {
            quad
        } else {
            clip(&clip(&quad, 0, i as f64, -1.0), 0, (i + 1) as f64, 1.0)
        };
        if col.1 < 3 {
            continue;
        }
        if j0 == j1 {
            acc.add(i, j0, area(&col) * k);
            continue;
        }
        for j in j0..=j1 {
            let cell = clip(&clip(&col, 1, j as f64, -1.0), 1, (j + 1) as f64, 1.0);
            if cell.1 >= 3 {
                acc.add(i, j, area(&cell) * k);
            }
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(c: [[f64; 2]; 4]) -> Vec<f64> {
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
        assert!(splat(&c, 1.0, &mut acc));
        data.iter().map(|&x| x as f64 / scale).collect()
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
    fn a_folded_quad_is_refused() {
        let mut data = vec![0i64; 16];
        let mut acc = Accum {
            data: &mut data,
            x0: 0,
            y0: 0,
            w: 4,
            h: 4,
            scale: 1.0,
        };
        assert!(!splat(
            &[[0.0, 0.0], [2.0, 2.0], [2.0, 0.0], [0.0, 2.0]],
            1.0,
            &mut acc
        ));
    }
}
