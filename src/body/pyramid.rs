//! Block maxima of a global DEM ([`MaxPyramid`]): how far a ray may go over the terrain
//! without meeting it, the "maximum mipmap" of height-field ray casting. A ray that clears
//! the highest ground within a block's reach leaps over the whole block.
//!
//! Both marchers of a DEM read it, each its own way: the pipeline's fixed quarter-texel
//! steps ([`super::Relief::occluded`], Eq. 33) skip the steps a leap clears and test the same
//! points as without it; the reference's sphere tracing (`raycast::terrain`) leaps where it
//! would crawl. The pyramid is a bound on the map, like a map lookup; neither marcher's
//! stepping is shared.

use super::maps::Map;
use glam::DVec3;

/// For a global DEM, level `k` holds per block of `2^k x 2^k` texels the highest height within
/// the blocks from one before to two after it in each direction ([`MaxPyramid::new`]): a point
/// in the block that moves by at most `2^k` texels in longitude and latitude finds every
/// texel its bilinear height reads among them.
#[derive(Debug, PartialEq)]
pub struct MaxPyramid {
    levels: Vec<MaxLevel>,
    /// The sphere the heights are above, and the lowest point's radius [m] (a lower bound of
    /// any surface point's).
    radius_m: f64,
    bottom_radius_m: f64,
}

#[derive(Debug, PartialEq)]
struct MaxLevel {
    /// Blocks across and down.
    w: usize,
    h: usize,
    /// Texels per block side.
    side: usize,
    /// `side` texels of latitude and of longitude [rad], and the cosine and sine of the
    /// former (the latitude a move of that much can reach).
    span_lat_rad: f64,
    span_lon_rad: f64,
    cos_span: f64,
    sin_span: f64,
    dilated_max_m: Vec<f32>,
    /// The steepest slope of the bilinear surface (the length of its gradient, a bound of
    /// the tan of its angle) in the same blocks, dilated alike.
    dilated_slope: Vec<f32>,
    /// The highest height in each band of block rows (all longitudes), from one before to
    /// two after: near a pole, where blocks are narrow in arc, a ray leaps by latitude alone.
    band_max_m: Vec<f32>,
}

/// A point of a ray: its direction from the centre (unit), that direction's longitude
/// and latitude [rad], and its texel coordinates on the map the pyramid was made of
/// ([`Map::texel_coords`]).
#[derive(Clone, Copy, Debug)]
pub struct RayPoint {
    pub up: DVec3,
    pub lon: f64,
    pub lat: f64,
    pub x: f64,
    pub y: f64,
}

impl RayPoint {
    /// The point over the unit direction `up`, at `(lon, lat)`, on `map`'s grid.
    #[inline]
    pub fn on(map: &Map, up: DVec3, lon: f64, lat: f64) -> RayPoint {
        let (x, y) = map.texel_coords(lon, lat);
        RayPoint { up, lon, lat, x, y }
    }
}

/// Where a point lies on the map's grid: its texel coordinates (column wrapped) and the
/// |sine| and cosine of its latitude.
struct Place {
    x: f64,
    y: f64,
    sin_lat: f64,
    cos_lat: f64,
}

impl Place {
    fn of(map: &Map, at: &RayPoint) -> Place {
        // `rem_euclid` without its `fmod` for the columns of longitudes in (-pi, pi], the
        // same value.
        let w = map.width as f64;
        let x = match at.x {
            x if (0.0..w).contains(&x) => x,
            x if (-w..0.0).contains(&x) => x + w,
            x => x.rem_euclid(w),
        };
        Place {
            x,
            y: at.y,
            sin_lat: at.up.z.abs(),
            cos_lat: at.up.truncate().length(),
        }
    }
}

impl MaxLevel {
    /// From `p`: the largest angular move [rad] that keeps the point within `side` texels in
    /// latitude and, with the cosine of the farthest latitude it can reach, in longitude
    /// (with a margin of a tenth); its band of block rows; and its block's index.
    fn reach(&self, p: &Place) -> (f64, usize, usize) {
        let n = self.side as f64;
        let cos_reach = p.cos_lat * self.cos_span - p.sin_lat * self.sin_span;
        let a = 0.9 * self.span_lat_rad.min(self.span_lon_rad * cos_reach);
        let band = ((p.y.max(0.0) / n) as usize).min(self.h - 1);
        let column = (p.x / n) as usize % self.w;
        (a, band, band * self.w + column)
    }
}

impl MaxPyramid {
    /// The pyramid of `map` (heights [m] above a sphere of `radius_m`), whose cells' slopes
    /// are `cell_slope` ([`cell_slopes`] at the lowest point's radius); `None` for a regional
    /// map.
    pub fn new(map: &Map, radius_m: f64, cell_slope: &[f32]) -> Option<MaxPyramid> {
        if !map.wraps() {
            return None;
        }
        let (w0, h0) = (map.width, map.height);
        let bottom = map.values.iter().fold(f32::MAX, |a, &v| a.min(v)) as f64;
        let bottom_radius_m = radius_m + bottom.min(0.0);
        let (dlon, dlat) = map.spacing_rad();
        let mut slope = std::borrow::Cow::Borrowed(cell_slope);
        let mut levels = Vec::new();
        // Block maxima of level k, from level k - 1's (the last block of an odd count
        // covers one block).
        let mut block: Vec<f32> = map.values.clone();
        let (mut bw, mut bh) = (w0, h0);
        for k in 1..16 {
            let (nw, nh) = (bw.div_ceil(2), bh.div_ceil(2));
            block = block_max(&block, bw, bh);
            slope = std::borrow::Cow::Owned(block_max(&slope, bw, bh));
            (bw, bh) = (nw, nh);
            let side = 1usize << k;
            let span = side as f64 * dlat;
            let row_max: Vec<f32> = (0..bh)
                .map(|r| {
                    block[r * bw..(r + 1) * bw]
                        .iter()
                        .fold(f32::MIN, |a, &b| a.max(b))
                })
                .collect();
            let band_max_m = (0..bh as i64)
                .map(|r| {
                    (r - 1..=r + 2)
                        .map(|rr| row_max[rr.clamp(0, bh as i64 - 1) as usize])
                        .fold(f32::MIN, f32::max)
                })
                .collect();
            levels.push(MaxLevel {
                band_max_m,
                w: bw,
                h: bh,
                side,
                span_lat_rad: span,
                span_lon_rad: side as f64 * dlon,
                cos_span: span.min(std::f64::consts::FRAC_PI_2).cos(),
                sin_span: span.min(std::f64::consts::FRAC_PI_2).sin(),
                dilated_max_m: dilate(&block, bw, bh),
                dilated_slope: dilate(&slope, bw, bh),
            });
            if bw < 4 || bh < 2 {
                break;
            }
        }
        Some(MaxPyramid {
            levels,
            radius_m,
            bottom_radius_m,
        })
    }

    /// How far a ray may step from `at`, `gap_m` above the ground, without meeting it, where
    /// it rises at least `rise` per metre of its length (a straight ray rising from the
    /// ground: its elevation only grows): within a block's reach the ground rises at most
    /// the block's steepest slope per metre of arc, so the gap cannot close within
    /// `gap / (slope - rise)`, nor at all where the ray is steeper. The longest such step
    /// over the levels (blocks spanning less than 0.1 rad, as [`MaxPyramid::rise_clear`]),
    /// 0 where none allows one.
    pub fn safe_step(&self, map: &Map, at: &RayPoint, gap_m: f64, rise: f64) -> f64 {
        self.small_blocks(map, at)
            .map(|(a, _, slope)| {
                let reach_m = a * self.bottom_radius_m;
                let closing = 1.001 * slope - rise;
                if closing > 0.0 {
                    (gap_m / closing).min(reach_m)
                } else {
                    reach_m
                }
            })
            .fold(0.0, f64::max)
    }

    /// Per level whose blocks span less than 0.1 rad (where an arc and its chord differ by
    /// less than the margin of 1e-3), finest first: the reach from `at` [rad]
    /// ([`MaxLevel::reach`]), the blocks' span [rad] and the steepest slope in the dilated
    /// block there.
    fn small_blocks<'a>(
        &'a self,
        map: &Map,
        at: &RayPoint,
    ) -> impl Iterator<Item = (f64, f64, f64)> + 'a {
        let place = Place::of(map, at);
        self.levels
            .iter()
            .take_while(|lvl| lvl.span_lat_rad <= 0.1)
            .map(move |lvl| {
                let (a, _, block) = lvl.reach(&place);
                (a, lvl.span_lat_rad, lvl.dilated_slope[block] as f64)
            })
    }

    /// How far a ray may go from the ground point `at` (on the bilinear surface) without
    /// meeting it, rising at `rise` (the sine of its elevation above the horizontal): as long
    /// as the point stays within a block's reach, the ground beneath it rises at most the
    /// block's steepest slope per metre of arc, and the ray, at least `rise` per metre of its
    /// length; so where `rise` is steeper, nothing within reach can block it. 0 where no
    /// level allows it. Blocks spanning less than 0.1 rad only, where an arc and its chord
    /// differ by less than the margin of 1e-3.
    pub fn rise_clear(&self, map: &Map, at: &RayPoint, rise: f64) -> f64 {
        let mut best = 0.0;
        for (a, span, slope) in self.small_blocks(map, at) {
            // A NaN slope (a broken DEM's) ends the walk too.
            let steeper = rise > 1.001 * slope;
            if a < 0.45 * span || !steeper {
                break;
            }
            best = a * self.bottom_radius_m;
        }
        best
    }

    /// A bound on the ground's slope (the length of the bilinear surface's gradient, per
    /// metre of arc at the lowest radius) wherever a point moving at most `dist_m` of arc
    /// from `at` can read: the finest block whose reach holds that move. `None` where none
    /// does (a move across a pole's narrow blocks).
    pub fn slope_within(&self, map: &Map, at: &RayPoint, dist_m: f64) -> Option<f64> {
        let place = Place::of(map, at);
        self.levels.iter().find_map(|lvl| {
            let (a, _, block) = lvl.reach(&place);
            (a * self.bottom_radius_m >= dist_m).then(|| lvl.dilated_slope[block] as f64)
        })
    }

    /// Levels above the texels.
    pub fn depth(&self) -> usize {
        self.levels.len()
    }

    /// How far along the ray `origin + t dir` (`dir` unit) from `t`, where it passes over
    /// `at`, it may go without meeting the ground of `map` (the map the pyramid was made
    /// of), 0 when no level allows a leap: the longest step over which the ray's lowest
    /// radius clears the highest ground within reach.
    pub fn leap(&self, map: &Map, origin: DVec3, dir: DVec3, t: f64, at: &RayPoint) -> f64 {
        let place = Place::of(map, at);
        // The ray's lowest radius over [t, t + dt]: |origin + s dir|^2 is convex in s.
        let b = origin.dot(dir);
        let c = origin.length_squared();
        let min_r = |dt: f64| {
            let s = (-b).clamp(t, t + dt);
            (c + 2.0 * s * b + s * s).max(0.0).sqrt()
        };
        // Levels from the finest: a level that fails fails all coarser ones (their reach and
        // their step are larger), so the first failure ends the search.
        let mut best = 0.0;
        for lvl in &self.levels {
            let (a_block, band, block) = lvl.reach(&place);
            // Near a pole the block's longitudes bind: the band of all longitudes, by
            // latitude alone, leaps farther.
            let (a, top) = if a_block >= 0.45 * lvl.span_lat_rad {
                (a_block, lvl.dilated_max_m[block] as f64)
            } else {
                (0.9 * lvl.span_lat_rad, lvl.band_max_m[band] as f64)
            };
            // The ray's point moves by at most dt / r_min of arc about the centre.
            let dt = a * self.bottom_radius_m;
            if min_r(dt) > self.radius_m + top.max(0.0) {
                best = dt;
            } else {
                break;
            }
        }
        best
    }
}

/// Per cell of `map` (the texels from (r, c) to (r + 1, c + 1), which a bilinear height
/// between them reads), the length of the steepest gradient within it [m/m]: each component
/// is at most the larger of its two edges' differences, over the cell's shortest arc (at
/// `bottom_radius_m`, the lowest radius, and the latitude nearest a pole). A regional map's
/// last column and every map's last row have no cell beyond them: their edges count alone.
pub(crate) fn cell_slopes(map: &Map, bottom_radius_m: f64) -> Vec<f32> {
    let (w0, h0) = (map.width, map.height);
    let (dlon, dlat) = map.spacing_rad();
    let east = |c: usize| {
        if map.wraps() {
            (c + 1) % w0
        } else {
            (c + 1).min(w0 - 1)
        }
    };
    let v = |r: usize, c: usize| map.values[r.min(h0 - 1) * w0 + c] as f64;
    let mut slope: Vec<f32> = Vec::with_capacity(w0 * h0);
    for r in 0..h0 {
        let polar = map
            .row_lat(r)
            .abs()
            .max(map.row_lat((r + 1).min(h0 - 1)).abs());
        let arc_e = bottom_radius_m * polar.cos().max(1e-9) * dlon;
        let arc_n = bottom_radius_m * dlat;
        for c in 0..w0 {
            let (a, b, cc, d) = (v(r, c), v(r, east(c)), v(r + 1, c), v(r + 1, east(c)));
            let e = (b - a).abs().max((d - cc).abs()) / arc_e;
            let n = (cc - a).abs().max((d - b).abs()) / arc_n;
            slope.push(e.hypot(n) as f32);
        }
    }
    slope
}

/// Per texel of `map`'s grid, the largest of `values` (one per texel or per cell, on that
/// grid) over every texel a point within `reach_rad` of arc from it can lie beside: a window
/// of the reach in latitude and, wider towards the poles, in longitude (the widest span of
/// longitude an arc of the reach crossing the row can cover, whole rows where it can pass
/// over a pole), a texel more on each side for the bilinear footprint. A regional map's
/// windows stop at its edges.
pub(crate) fn window_max(values: &[f32], map: &Map, reach_rad: f64) -> Vec<f32> {
    use rayon::prelude::*;
    let (w, h) = (map.width, map.height);
    let dlon = map.spacing_rad().0;
    let dlat = map.spacing_rad().1;
    let wraps = map.wraps();
    // Along each row, a window of the reach in longitude.
    let mut rows = vec![0.0f32; w * h];
    rows.par_chunks_mut(w).enumerate().for_each(|(r, out)| {
        let lat = (map.row_lat(r).abs() + reach_rad).min(std::f64::consts::FRAC_PI_2);
        let s = reach_rad.sin() / lat.cos().max(1e-12);
        let half = if s >= 1.0 {
            w
        } else {
            ((s.asin() / dlon).ceil() as usize + 1).min(w)
        };
        let row = &values[r * w..(r + 1) * w];
        if 2 * half + 1 >= w {
            out.fill(row.iter().cloned().fold(0.0, f32::max));
            return;
        }
        for (c, o) in out.iter_mut().enumerate() {
            let mut m = 0.0f32;
            for k in 0..=2 * half {
                let cc = c as isize + k as isize - half as isize;
                let cc = if wraps {
                    cc.rem_euclid(w as isize) as usize
                } else if cc < 0 || cc >= w as isize {
                    continue;
                } else {
                    cc as usize
                };
                m = m.max(row[cc]);
            }
            *o = m;
        }
    });
    // Then across rows, a window of the reach in latitude.
    let half = (reach_rad / dlat).ceil() as usize + 1;
    let mut out = vec![0.0f32; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(r, out)| {
        let (r0, r1) = (r.saturating_sub(half), (r + half).min(h - 1));
        for (c, o) in out.iter_mut().enumerate() {
            *o = (r0..=r1).map(|rr| rows[rr * w + c]).fold(0.0, f32::max);
        }
    });
    out
}

/// The maxima of `values` (`w x h`) over blocks of 2 x 2 (the last block of an odd count
/// covers one).
fn block_max(values: &[f32], w: usize, h: usize) -> Vec<f32> {
    let nw = w.div_ceil(2);
    let mut next = vec![f32::MIN; nw * h.div_ceil(2)];
    for r in 0..h {
        for c in 0..w {
            let n = &mut next[(r / 2) * nw + c / 2];
            *n = n.max(values[r * w + c]);
        }
    }
    next
}

/// Per block, the maximum over the blocks from one before to two after it in each direction
/// (longitude wraps; latitude clamps).
fn dilate(block: &[f32], bw: usize, bh: usize) -> Vec<f32> {
    let mut dilated = vec![f32::MIN; bw * bh];
    for r in 0..bh {
        for c in 0..bw {
            let mut m = f32::MIN;
            for dr in -1i64..=2 {
                let rr = (r as i64 + dr).clamp(0, bh as i64 - 1) as usize;
                for dc in -1i64..=2 {
                    let cc = (c as i64 + dc).rem_euclid(bw as i64) as usize;
                    m = m.max(block[rr * bw + cc]);
                }
            }
            dilated[r * bw + c] = m;
        }
    }
    dilated
}

/// A number in [0, 1) from `i`, the same everywhere: the rough terrains of the marchers'
/// tests.
#[cfg(test)]
pub(crate) fn unit_hash(i: usize) -> f64 {
    let x = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 40;
    x as f64 / (1u64 << 24) as f64
}

/// Rolling plains, six crater rims 3 km high and single-texel spikes of 2 km every 20
/// texels, at texel `(c, r)` (index `i`) of a 720 x 360 grid [m]: the terrain of the
/// marchers' shortcut tests ([`test_relief_over`]).
#[cfg(test)]
pub(crate) fn plains_rims_spikes(c: f64, r: f64, i: usize) -> f64 {
    let plains = 400.0 * (c * 0.013).sin() * (r * 0.021).cos() + 30.0 * unit_hash(i);
    let rims = crater_rims((c, r), (57.0, 90.0), (115.0, 35.0), 6.0, 2.0);
    let spike = if r % 20.0 == 0.0 && c % 20.0 == 0.0 {
        2000.0
    } else {
        0.0
    };
    plains + rims + spike
}

/// Six crater rims 3 km high at texel `(c, r)` [m]: rim `k` centred at `first + k spacing`
/// (columns, rows), of radius `rim` texels, its profile `exp(-(d - rim)^2 / width)`.
#[cfg(test)]
pub(crate) fn crater_rims(
    (c, r): (f64, f64),
    first: (f64, f64),
    spacing: (f64, f64),
    rim: f64,
    width: f64,
) -> f64 {
    (0..6)
        .map(|k| {
            let (cc, rc) = (
                first.0 + spacing.0 * k as f64,
                first.1 + spacing.1 * k as f64,
            );
            let d = ((c - cc).powi(2) + (r - rc).powi(2)).sqrt();
            3000.0 * (-(d - rim).powi(2) / width).exp()
        })
        .sum()
}

/// A global DEM on a 720 x 360 grid (half a degree a texel) over the Moon's radius, its
/// height [m] at texel `(column, row)` (and index `i`) by `height`: the marchers' tests'
/// terrains.
#[cfg(test)]
pub(crate) fn test_relief(
    height: impl Fn(f64, f64, usize) -> f64,
    displaces: bool,
) -> super::Relief {
    test_relief_over(height, displaces, 1_737_400.0)
}

/// [`test_relief`] over a sphere of `radius_m`.
#[cfg(test)]
pub(crate) fn test_relief_over(
    height: impl Fn(f64, f64, usize) -> f64,
    displaces: bool,
    radius_m: f64,
) -> super::Relief {
    let (w, h) = (720usize, 360usize);
    let v: Vec<f64> = (0..w * h)
        .map(|i| height((i % w) as f64, (i / w) as f64, i))
        .collect();
    let dem = Map::from_values(
        std::path::Path::new("rough"),
        w,
        h,
        v,
        &super::maps::Encoding::default(),
    )
    .unwrap();
    super::Relief::new(dem, radius_m, displaces).unwrap()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::Relief;
    use crate::body::maps::Encoding;
    use crate::geometry::{east_north, unit_from_lon_lat};

    /// Plains with a few steep craters' rims and a polar cap of hills, on a global 1440 x 720
    /// grid (the LOLA map's): the leaps, from the ground by slope and in the air by height,
    /// change no answer of the pipeline's marcher, displaced or not, nor does clearing a ray
    /// at once that rises more steeply than every slope within its reach; and all three
    /// shortcuts do happen.
    #[test]
    fn the_marchers_leaps_change_no_answer() {
        let (w, h) = (1440usize, 720usize);
        let hash = unit_hash;
        let v: Vec<f64> = (0..w * h)
            .map(|i| {
                let (c, r) = ((i % w) as f64, (i / w) as f64);
                let plains = 400.0 * (c * 0.013).sin() * (r * 0.021).cos();
                let rims = crater_rims((c, r), (97.0, 120.0), (231.0, 83.0), 12.0, 4.0);
                let hills = if r < 40.0 { 1500.0 * hash(i) } else { 0.0 };
                // Single-texel spikes of 2 km every 40 texels from row 400: obstacles thin
                // enough for a wrong leap to jump over.
                let spike = if r >= 400.0 && r % 40.0 == 0.0 && c % 40.0 == 0.0 {
                    2000.0
                } else {
                    0.0
                };
                plains + rims + hills + spike
            })
            .collect();
        let dem = Map::from_values(
            std::path::Path::new("plains"),
            w,
            h,
            v,
            &Encoding::default(),
        )
        .unwrap();
        let radius = 1_737_400.0;
        for displaces in [false, true] {
            let relief = Relief::new(dem.clone(), radius, displaces).unwrap();
            let p = relief.pyramid().expect("a global DEM");
            let (mut from_ground, mut in_air, mut shadowed, mut at_once) = (0, 0, 0, 0);
            for k in 0..6000 {
                let u = |j: usize| hash(k * 11 + j) * 2.0 - 1.0;
                // A fifth near a pole, half on a crater (where slopes are steep), the rest
                // anywhere.
                let (lon, lat) = if k % 5 == 0 {
                    (std::f64::consts::PI * u(2), 1.45 + 0.1 * u(1))
                } else if k % 2 == 0 {
                    let m = (k / 2) % 6;
                    let (c, r) = (
                        97.0 + 231.0 * m as f64 + 16.0 * u(1),
                        120.0 + 83.0 * m as f64 + 16.0 * u(2),
                    );
                    dem.texel_centre(c as usize, r as usize)
                } else {
                    (std::f64::consts::PI * u(2), 1.4 * u(1))
                };
                let up = unit_from_lon_lat(lon, lat);
                let (east, north) = east_north(up);
                let az = std::f64::consts::PI * u(3);
                // From 2 deg below the horizontal (marched on a displaced surface) to 25 up.
                let elev = (-2.0 + 27.0 * hash(k * 11 + 4)).to_radians();
                let toward = (elev.cos() * (az.cos() * east + az.sin() * north) + elev.sin() * up)
                    .normalize();
                // Every fourth ray from 1 to 4 texels west of a spike, towards it, low
                // enough to meet it.
                let (up, toward, lon, lat, elev) = if k % 4 == 1 {
                    let d = 1 + (k / 4) % 4;
                    let (c, r) = (40 * (1 + (k / 16) % 30) - d, 400 + 40 * ((k / 480) % 7));
                    let (lon, lat) = dem.texel_centre(c, r);
                    let up = unit_from_lon_lat(lon, lat);
                    let (east, _) = east_north(up);
                    let top =
                        (2000.0 / (d as f64 * radius * dem.spacing_rad().0 * lat.cos())).atan();
                    let elev = top * hash(k * 11 + 5);
                    let toward = (elev.cos() * east + elev.sin() * up).normalize();
                    (up, toward, lon, lat, elev)
                } else {
                    (up, toward, lon, lat, elev)
                };
                let fast = relief.march(up, toward, true);
                assert_eq!(fast, relief.march(up, toward, false), "ray {k}");
                shadowed += fast as usize;
                at_once += crate::body::rises_above(elev.sin(), relief.slope_within_reach(lon, lat))
                    as usize;
                let at = RayPoint::on(&dem, up, lon, lat);
                from_ground += (p.rise_clear(&dem, &at, elev.sin()) > relief.step_m) as usize;
                let start = up * (radius + 5000.0);
                in_air += (p.leap(&dem, start, toward, 0.0, &at) > relief.step_m) as usize;
            }
            assert!(
                shadowed > 300 && from_ground > 1000 && in_air > 1000 && at_once > 1000,
                "displaces {displaces}: {shadowed} shadowed, {from_ground} leaps from the \
                 ground, {in_air} in the air, {at_once} clear at once"
            );
        }
    }
}
