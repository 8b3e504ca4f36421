//! Area-weighted gridding (Eq. 41): the point is a one-pixel square; each of the (up to) four
//! pixels it overlaps gets the overlapping fraction, `(1 - d_u)(1 - d_v)`, where `d_u`, `d_v`
//! are the distances from the point to the pixel centres.

use super::Accum;

#[inline]
pub fn splat(p: [f64; 2], value: f64, acc: &mut Accum) {
    let (cu, cv) = (p[0] - 0.5, p[1] - 0.5);
    let (i0, j0) = (cu.floor(), cv.floor());
    let (fu, fv) = (cu - i0, cv - j0);
    let (i0, j0) = (i0 as i64, j0 as i64);
    acc.add(i0, j0, value * (1.0 - fu) * (1.0 - fv));
    acc.add(i0 + 1, j0, value * fu * (1.0 - fv));
    acc.add(i0, j0 + 1, value * (1.0 - fu) * fv);
    acc.add(i0 + 1, j0 + 1, value * fu * fv);
}
