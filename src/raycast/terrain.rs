//! The terrain of a DEM as the ray caster sees it: the surface `r = R + h(lon, lat)` (bilinear
//! heights), met by sphere tracing ([`Terrain::intersect`]), independently of the pipeline's
//! fixed-step ray marching (a quarter texel, which a grazing ray can skip through).
//!
//! Sphere tracing alone crawls where a ray runs low over the ground (a shadow ray at a low Sun:
//! steps of `gap / (1 + s)`), so a pyramid of maximum heights ([`MaxPyramid`]) lets a ray leap
//! over whole blocks of texels whose highest point it clears, the "maximum mipmap" of height-
//! field ray casting. Both give the same answer; the pyramid only skips steps that cannot meet
//! the ground.

use crate::body::{Relief, maps::Map};
use glam::DVec3;
use std::sync::Arc;

pub(super) struct Terrain {
    heights: Arc<Map>,
    radius_m: f64,
    top_m: f64,
    /// The lowest point's radius [m] (a lower bound of any surface point's).
    bottom_radius_m: f64,
    /// The steepest slope between neighbouring texels anywhere (tan of its angle): a ray
    /// rising more steeply than this cannot be blocked.
    max_slope: f64,
    /// The shortest step of the sphere tracing: a hundredth of a texel [m].
    min_step_m: f64,
    /// Block maxima of a global DEM (`None` for a regional one).
    pyramid: Option<MaxPyramid>,
}

/// For a global DEM, level `k` holds per block of `2^k x 2^k` texels the highest height within
/// the blocks from one before to two after it in each direction ([`MaxPyramid::new`]): a point
/// in the block that moves by at most `2^k` texels in longitude and latitude finds every
/// texel its bilinear height reads among them.
struct MaxPyramid {
    levels: Vec<MaxLevel>,
}

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
    /// The highest height in each band of block rows (all longitudes), from one before to
    /// two after: near a pole, where blocks are narrow in arc, a ray leaps by latitude alone.
    band_max_m: Vec<f32>,
}

impl MaxPyramid {
    fn new(map: &Map) -> Option<MaxPyramid> {
        if !map.wraps() {
            return None;
        }
        let (w0, h0) = (map.width, map.height);
        let mut levels = Vec::new();
        // Block maxima of level k, from level k - 1's (the last block of an odd count
        // covers one block).
        let mut block: Vec<f32> = map.values.clone();
        let (mut bw, mut bh) = (w0, h0);
        for k in 1..16 {
            let (nw, nh) = (bw.div_ceil(2), bh.div_ceil(2));
            let mut next = vec![f32::MIN; nw * nh];
            for r in 0..bh {
                for c in 0..bw {
                    let n = &mut next[(r / 2) * nw + c / 2];
                    *n = n.max(block[r * bw + c]);
                }
            }
            (block, bw, bh) = (next, nw, nh);
            let side = 1usize << k;
            // Dilated: blocks from one before to two after (longitude wraps; latitude clamps).
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
            let (dlon, dlat) = map.spacing_rad();
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
                dilated_max_m: dilated,
            });
            if bw < 4 || bh < 2 {
                break;
            }
        }
        Some(MaxPyramid { levels })
    }
}

/// A point of a ray: its gap above the ground [m], its direction from the centre (unit) and
/// that direction's longitude and latitude [rad].
struct Probe {
    gap: f64,
    up: DVec3,
    lon: f64,
    lat: f64,
}

impl Terrain {
    pub(super) fn new(relief: &Relief) -> Terrain {
        let map = relief.heights_m.clone();
        let r0 = relief.reference_radius_m();
        let (dlon, dlat) = map.spacing_rad();
        let (w, h) = (map.width, map.height);
        let v = |r: usize, c: usize| map.values[r * w + c] as f64;
        let (mut top, mut bottom, mut max_slope) = (f64::MIN, f64::MAX, 0.0f64);
        for r in 0..h {
            let arc_e = r0 * map.row_lat(r).cos().abs().max(1e-9) * dlon;
            for c in 0..w {
                let here = v(r, c);
                top = top.max(here);
                bottom = bottom.min(here);
                if c + 1 < w || map.wraps() {
                    let east = v(r, (c + 1) % w);
                    max_slope = max_slope.max((east - here).abs() / arc_e);
                }
                if r + 1 < h {
                    max_slope = max_slope.max((v(r + 1, c) - here).abs() / (r0 * dlat));
                }
            }
        }
        Terrain {
            min_step_m: 1e-2 * r0 * dlat,
            pyramid: MaxPyramid::new(&map),
            heights: map,
            radius_m: r0,
            top_m: top.max(0.0),
            // Outside a regional map the ground is at the reference radius.
            bottom_radius_m: r0 + bottom.min(0.0),
            // Both slopes at once (the gradient's length) bound any direction's.
            max_slope: max_slope * std::f64::consts::SQRT_2,
        }
    }

    pub(super) fn height_at(&self, p: DVec3) -> Option<f64> {
        let (lon, lat) = crate::geometry::lon_lat(p);
        self.heights.sample(lon, lat)
    }

    /// How far along the ray `origin + t dir` from `t` it may leap without meeting the
    /// ground, from the pyramid (0 when no level allows a leap): the longest step at which
    /// the ray's lowest radius over the step clears the highest ground within reach.
    fn leap(&self, origin: DVec3, dir: DVec3, t: f64, at: &Probe) -> f64 {
        let Some(pyr) = &self.pyramid else {
            return 0.0;
        };
        let map = &self.heights;
        let (x, y) = map.texel_coords(at.lon, at.lat);
        let x = x.rem_euclid(map.width as f64);
        // The ray's lowest radius over [t, t + dt]: |origin + s dir|^2 is convex in s.
        let b = origin.dot(dir);
        let c = origin.length_squared();
        let min_r = |dt: f64| {
            let s = (-b).clamp(t, t + dt);
            (c + 2.0 * s * b + s * s).max(0.0).sqrt()
        };
        // |sin| and cos of the point's latitude.
        let (sin_lat, cos_lat) = (at.up.z.abs(), at.up.truncate().length());
        // Levels from the finest: a level that fails fails all coarser ones (their reach and
        // their step are larger), so the first failure ends the search.
        let mut best = 0.0;
        for lvl in &pyr.levels {
            let n = lvl.side as f64;
            // An angular move of at most `a` keeps the point within `side` texels in latitude
            // and, with the cosine of the farthest latitude it can reach, in longitude.
            let cos_reach = cos_lat * lvl.cos_span - sin_lat * lvl.sin_span;
            let a_block = 0.9 * lvl.span_lat_rad.min(lvl.span_lon_rad * cos_reach);
            let br = ((y.max(0.0) / n) as usize).min(lvl.h - 1);
            // Near a pole the block's longitudes bind: the band of all longitudes, by
            // latitude alone, leaps farther.
            let (a, top) = if a_block >= 0.45 * lvl.span_lat_rad {
                let bc = (x / n) as usize % lvl.w;
                (a_block, lvl.dilated_max_m[br * lvl.w + bc] as f64)
            } else {
                (0.9 * lvl.span_lat_rad, lvl.band_max_m[br] as f64)
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

    /// The first `t > t0` where the ray `origin + t dir` (`dir` unit) is below the terrain
    /// `r = R + h`, by sphere tracing: where the ray is `g` above the ground, the ground cannot
    /// come nearer than `g / (1 + s)` along it (`s` the steepest slope: the height rises at
    /// most `s` per metre and the ray's radius falls at most 1 per metre), so that is the
    /// step, but at least a hundredth of a texel (a ridge thinner than that along the ray may
    /// be skipped by a ray grazing it; where the step overshoots below the ground, the
    /// crossing is found by bisection). Where the ray clears a block's highest point, it leaps
    /// over the block ([`MaxPyramid`]). A ray still above the ground after `MAX_STEPS` steps
    /// counts as meeting it.
    pub(super) fn intersect(&self, origin: DVec3, dir: DVec3, t0: f64) -> Option<f64> {
        const MAX_STEPS: usize = 1_000_000;
        let ceiling = self.radius_m + self.top_m;
        let b = origin.dot(dir);
        let disc = b * b - (origin.length_squared() - ceiling * ceiling);
        if disc < 0.0 {
            return None;
        }
        let (t_in, t_out) = (-b - disc.sqrt(), -b + disc.sqrt());
        if t_out <= t0 {
            return None;
        }
        let hit_within = 1e-9 * self.radius_m;
        let rate = 1.0 + self.max_slope;
        let probe = |t: f64| {
            let q = origin + dir * t;
            let r = q.length();
            let up = q / r;
            let (lon, lat) = crate::geometry::lon_lat_unit(up);
            let h = self.heights.sample(lon, lat).unwrap_or(0.0);
            Probe {
                gap: r - self.radius_m - h,
                up,
                lon,
                lat,
            }
        };
        let gap = |t: f64| probe(t).gap;
        let mut t = t_in.max(t0);
        let mut at = probe(t);
        for _ in 0..MAX_STEPS {
            if at.gap <= hit_within {
                return Some(t);
            }
            let leap = self.leap(origin, dir, t, &at);
            if leap > 0.0 {
                t += leap;
                if t > t_out {
                    return None;
                }
                at = probe(t);
                continue;
            }
            let next = t + (at.gap / rate).max(self.min_step_m);
            let ahead = probe(next);
            if ahead.gap < 0.0 {
                // Overshot (a minimal step): the crossing lies between.
                let (mut lo, mut hi) = (t, next);
                for _ in 0..60 {
                    let mid = 0.5 * (lo + hi);
                    if gap(mid) > 0.0 {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                    if hi - lo < hit_within {
                        break;
                    }
                }
                return Some(hi);
            }
            if next > t_out {
                return None;
            }
            (t, at) = (next, ahead);
        }
        Some(t)
    }

    /// Whether the terrain hides direction `toward` (unit) from the surface point over the
    /// unit direction `up`. On a displaced surface the ray starts on it; on an undisplaced one
    /// (the DEM tilts the normals only) it starts at the terrain's height there, as the DEM
    /// says the ground lies.
    pub(super) fn shadowed(&self, up: DVec3, toward: DVec3, displaced: bool) -> bool {
        let rise = toward.dot(up);
        let horizontal = (1.0 - rise * rise).max(0.0).sqrt();
        if rise > 0.0 && rise >= self.max_slope * horizontal {
            return false;
        }
        if rise <= 0.0 && !displaced {
            return false; // the BRDF's cosine on the sphere already says so
        }
        let h0 = self.height_at(up).unwrap_or(0.0);
        // Clear of the ground it starts on: a thousand times the hit tolerance above it.
        let start = up * (self.radius_m + h0 + 1e-6 * self.radius_m);
        self.intersect(start, toward, 0.0).is_some()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::maps::{Encoding, Map};

    /// A rough global DEM (craters and ridges of a few km on a 720 x 360 grid): the pyramid's
    /// leaps change no answer of the sphere tracing, for shadow rays at low Suns (polar ones
    /// included) and for rays from afar at every incidence, on the displaced surface.
    #[test]
    fn the_pyramid_leaps_change_no_answer() {
        let (w, h) = (720usize, 360usize);
        let hash = |i: usize| {
            let x = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 40;
            x as f64 / (1u64 << 24) as f64
        };
        let v: Vec<f64> = (0..w * h)
            .map(|i| {
                let (c, r) = ((i % w) as f64, (i / w) as f64);
                3000.0 * (c * 0.07).sin() * (r * 0.11).cos() + 1500.0 * hash(i)
            })
            .collect();
        let dem =
            Map::from_values(std::path::Path::new("rough"), w, h, v, &Encoding::default()).unwrap();
        let radius = 1_737_400.0;
        let relief = Relief::new(dem, radius, true).unwrap();
        let fast = Terrain::new(&relief);
        let slow = Terrain {
            pyramid: None,
            ..Terrain::new(&relief)
        };
        let (mut agree, mut n) = (0, 0);
        for k in 0..4000 {
            let u = |j: usize| hash(k * 7 + j) * 2.0 - 1.0;
            // Shadow rays: a surface point (some near the poles), the Sun 0.5 to 20 deg up.
            let lat = if k % 4 == 0 {
                1.45 + 0.1 * u(1)
            } else {
                1.5 * u(1)
            };
            let up = crate::geometry::unit_from_lon_lat(std::f64::consts::PI * u(2), lat);
            let (east, north) = crate::geometry::east_north(up);
            let az = std::f64::consts::PI * u(3);
            let elev = (0.5 + 19.5 * hash(k * 7 + 4)).to_radians();
            let toward =
                (elev.cos() * (az.cos() * east + az.sin() * north) + elev.sin() * up).normalize();
            assert_eq!(
                fast.shadowed(up, toward, true),
                slow.shadowed(up, toward, true),
                "shadow ray {k}"
            );
            // Rays from 3 radii away towards a point near the surface.
            let origin = 3.0 * radius * crate::geometry::unit_from_lon_lat(3.0 * u(5), 1.2 * u(6));
            let target = up * (radius + 2000.0 * u(4));
            let dir = (target - origin).normalize();
            let (a, b) = (
                fast.intersect(origin, dir, 0.0),
                slow.intersect(origin, dir, 0.0),
            );
            n += 1;
            match (a, b) {
                (Some(a), Some(b)) if (a - b).abs() < 1e-3 => agree += 1,
                (None, None) => agree += 1,
                _ => {}
            }
        }
        assert_eq!(agree, n, "{agree} of {n} rays agree");
        assert!(fast.pyramid.as_ref().unwrap().levels.len() >= 6);
    }
}
