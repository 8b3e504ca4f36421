//! Nearest-neighbour gridding: the whole value to the pixel containing the point.

use super::Accum;

#[inline]
pub fn splat(p: [f64; 2], value: f64, acc: &mut Accum) {
    acc.add(p[0].floor() as i64, p[1].floor() as i64, value);
}
