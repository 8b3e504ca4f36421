//! The highest ground on the way to the Sun, per frame: a bound that stops a marched Sun ray
//! ([`super::Relief::occluded`], Eq. 33) as soon as nothing farther along it can rise to meet
//! it.
//!
//! Rays parallel to the Sun's direction `s` keep their distance from the axis through the
//! body's centre along `s`: a ray leaving a point at angle `theta_P` from `s` (radius `r_P`)
//! stays at `y_P = r_P sin(theta_P)` from that axis, in the half-plane through the axis and
//! the point, and reaches the angle `theta < theta_P` at radius `y_P / sin(theta)`. It is
//! below the ground there exactly when `(R + h) sin(theta) > y_P`, so it meets the ground
//! beyond some angle `theta_c` only if the highest `(R + h) sin(theta)` over the half-plane's
//! angles below `theta_c` reaches `y_P`. Per frame the sphere is cut in cells of `theta` (from
//! the Sun's direction) and azimuth `phi` about it, and each cell keeps the highest height
//! of the DEM's cells (the highest of their four texels bounds the bilinear ground, the
//! poles' blend included) whose spherical caps it meets; along each azimuth the running
//! highest of `(R + H + e) sin(theta)` from the subsolar point outwards is kept. A Sun ray is
//! then marched only until it passes the largest `theta_c` whose running highest is below
//! its `y_P`: beyond that nothing can reach it.
//!
//! The Sun is not at infinity: each point's ray to it leaves `s` by at most `alpha` (the
//! body's ceiling radius over the Sun's distance, about 1.2e-5 rad for the Moon), so over a
//! chord of the ceiling's sphere the true ray and its parallel twin part by at most
//! `e = alpha 2 R_top`; the heights are raised by `e` and the caps widened by the angle it
//! subtends. A ray farther from `s` than `alpha` (the camera's, when the DEM displaces the
//! surface) is marched as before. Building it takes about 0.1 s of one core on the LOLA
//! DEM: a frame whose reads march millions of Sun rays builds it first, on the render pool
//! ([`super::Relief::under_sun_now`]); one whose quadrangles march them builds it only once
//! it has marched `BUILD_AFTER` of them ([`SunRays::envelope`]). The bound is on the map, as
//! the pyramid's and [`super::clearance::Clearance`]'s are: a ray it stops is one the marcher
//! would have found clear, so no answer changes (`tests` below against the marcher without
//! any shortcut).

use super::Relief;
use glam::DVec3;
use rayon::prelude::*;
use std::f64::consts::{FRAC_PI_2, PI, TAU};
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// The cells' side [texels of the DEM's latitude].
const CELL_TEXELS: f64 = 0.5;

/// Sun rays a frame marches before its envelope is built ([`SunRays::envelope`]): a build
/// takes about 0.1 s of one core on the LOLA DEM (1440 x 720), which a frame that marches
/// few rays does not win back (the NRHO perilune at 1/16 per pixel with `ray_marching`,
/// 160 ms a frame, was 190 ms with the envelope built up front).
const BUILD_AFTER: u64 = 250_000;

/// A frame's Sun and, once the frame has marched `BUILD_AFTER` Sun rays, its
/// [`SunEnvelope`] ([`super::Relief::under_sun`]).
#[derive(Debug)]
pub struct SunRays {
    /// The Sun's position [m] (body frame).
    position_m: DVec3,
    marched: AtomicU64,
    claimed: AtomicBool,
    envelope: OnceLock<Option<SunEnvelope>>,
}

impl PartialEq for SunRays {
    fn eq(&self, other: &SunRays) -> bool {
        self.position_m == other.position_m
    }
}

impl SunRays {
    /// For the Sun at `position_m` (body frame), nothing built yet.
    pub fn new(position_m: DVec3) -> SunRays {
        SunRays {
            position_m,
            marched: AtomicU64::new(0),
            claimed: AtomicBool::new(false),
            envelope: OnceLock::new(),
        }
    }

    /// The envelope of `relief` (the relief this belongs to), once built; the ray that
    /// reaches `BUILD_AFTER` builds it, on its own thread, while the others go on marching
    /// without it (a build on the render pool from within a render task could be stolen into
    /// by a task of the same frame waiting on it). The answers are the same either way, so
    /// the image does not depend on which rays had it.
    #[inline]
    pub fn envelope(&self, relief: &Relief) -> Option<&SunEnvelope> {
        if let Some(built) = self.envelope.get() {
            return built.as_ref();
        }
        if self.marched.fetch_add(1, Ordering::Relaxed) + 1 < BUILD_AFTER
            || self.claimed.swap(true, Ordering::AcqRel)
        {
            return None;
        }
        self.built(relief, false)
    }

    /// The envelope of `relief`, built now if it is not yet, on the current rayon pool if
    /// `parallel` (`None` where there is none: [`SunEnvelope::new`]).
    pub fn built(&self, relief: &Relief, parallel: bool) -> Option<&SunEnvelope> {
        self.envelope
            .get_or_init(|| SunEnvelope::new(relief, self.position_m, parallel))
            .as_ref()
    }
}

/// Per frame: the running highest ground towards the Sun along each azimuth about its
/// direction ([`SunEnvelope::new`]).
#[derive(Debug, PartialEq)]
pub struct SunEnvelope {
    /// The Sun's direction from the body's centre (unit, body frame) and two unit vectors
    /// normal to it and to each other, from which the azimuth `phi` is measured.
    sun: DVec3,
    e1: DVec3,
    e2: DVec3,
    /// The cosine of the widest angle a point's ray to the Sun makes with `sun`.
    cos_alpha: f64,
    /// Cell side [rad] in `theta` and `phi`, and cells in each (`theta` from 0 to pi/2).
    dtheta: f64,
    dphi: f64,
    n_theta: usize,
    n_phi: usize,
    /// Per azimuth cell `j`, per `theta` cell `i` (at `j * n_theta + i`): the highest
    /// `(R + H + e) sin(theta_hi)` over cells `0..=i` [m], `H` the cell's highest ground.
    running_m: Vec<f64>,
}

impl SunEnvelope {
    /// The envelope of `relief`'s ground towards the Sun at `sun_position_m` (body frame, from
    /// the centre); `None` for a DEM that does not cover the globe with both poles.
    /// `parallel`: on the current rayon pool (never from within a task that another task of
    /// the pool may wait on: [`SunRays::envelope`]).
    pub fn new(relief: &Relief, sun_position_m: DVec3, parallel: bool) -> Option<SunEnvelope> {
        let map = relief.heights_m.as_ref();
        let (pole_north, pole_south) = map.pole_values()?;
        let d_sun = sun_position_m.length();
        let (radius, top, bottom) = (relief.radius_m, relief.top_m, relief.bottom_m);
        let ceiling = radius + top.max(0.0);
        // A Sun within the body's reach (or not finite) is no Sun to bound rays towards.
        if !d_sun.is_finite() || d_sun <= 2.0 * ceiling {
            return None;
        }
        let sun = sun_position_m / d_sun;
        let e1 = sun.any_orthonormal_vector();
        let e2 = sun.cross(e1);
        // A ray from any point within the ceiling towards the Sun leaves `sun` by at most
        // asin(ceiling / (d_sun - ceiling)); marched over at most a chord of the ceiling's
        // sphere, it parts from its parallel twin by at most `e`.
        let alpha = 1.001 * (ceiling / (d_sun - ceiling)).asin() + 1e-12;
        let e = alpha * 2.0 * ceiling * 1.001 + 1e-3;
        let lowest = radius + bottom.min(0.0);
        if e >= 0.5 * lowest {
            return None; // a Sun so near that the margins would bound nothing
        }
        let widen = 1.01 * e / (lowest - e) + 1e-9;
        let (_, dlat) = map.spacing_rad();
        let dtheta = CELL_TEXELS * dlat;
        let n_theta = (FRAC_PI_2 / dtheta).ceil() as usize;
        let n_phi = (TAU / dtheta).ceil() as usize;
        let dphi = TAU / n_phi as f64;
        let (w, h) = (map.width, map.height);
        let (dlon, _) = map.spacing_rad();
        // The cells' `theta` and `phi` ranges [cells]: `(H, i0, i1, j0, columns)`, from a cap
        // of angular radius `reach` about the unit `centre` bounding ground up to `high`.
        let range = |high: f64, centre: DVec3, rho: f64, sin_rho: f64| {
            let cos_theta = centre.dot(sun).clamp(-1.0, 1.0);
            // Beyond 90 deg from the Sun by more than the cap's radius: no ray crosses it.
            if cos_theta < -sin_rho {
                return None;
            }
            let theta = cos_theta.acos();
            // A cap reaching 90 deg only by its rim (by rounding) still fills the last cell.
            let i1 = (((theta + rho).min(FRAC_PI_2) / dtheta) as u32).min(n_theta as u32 - 1);
            let i0 = (((theta - rho).max(0.0) / dtheta) as u32).min(i1);
            let (j0, columns) = if theta <= rho {
                (0, n_phi as u32)
            } else {
                let sin_theta = (1.0 - cos_theta * cos_theta).sqrt();
                let spread = (sin_rho / sin_theta).min(1.0).asin();
                let phi = crate::geometry::atan2_fast(centre.dot(e2), centre.dot(e1));
                let j0 = crate::geometry::floor_i64((phi - spread + PI) / dphi);
                let j1 = crate::geometry::floor_i64((phi + spread + PI) / dphi);
                let columns = ((j1 - j0 + 1) as usize).min(n_phi) as u32;
                (j0.rem_euclid(n_phi as i64) as u32, columns)
            };
            Some((high as f32, i0, i1, j0, columns))
        };
        // The caps of the DEM's cells (between the centres of rows `r` and `r + 1` and of
        // columns `c` and `c + 1`: the highest of the four texels), row by row; then the
        // poles' (the first and last rows' highest and the poles' values).
        let (sin_lon, cos_lon): (Vec<f64>, Vec<f64>) = (0..w)
            .map(|c| (map.texel_centre(c, 0).0 + 0.5 * dlon).sin_cos())
            .unzip();
        let row_max = |r: usize| {
            map.values[r * w..][..w]
                .iter()
                .fold(f64::MIN, |a, &v| a.max(v as f64))
        };
        let (_, lat_first) = map.texel_centre(0, 0);
        let (_, lat_last) = map.texel_centre(0, h - 1);
        let poles = [
            (
                row_max(0).max(pole_north),
                DVec3::Z,
                FRAC_PI_2 - lat_first + widen,
            ),
            (
                row_max(h - 1).max(pole_south),
                -DVec3::Z,
                FRAC_PI_2 + lat_last + widen,
            ),
        ];
        let row_ranges = |r: usize| {
            let (_, lat_n) = map.texel_centre(0, r);
            let (_, lat_s) = map.texel_centre(0, r + 1);
            let lat_c = 0.5 * (lat_n + lat_s);
            let (sin_lat, cos_lat) = lat_c.sin_cos();
            // The farthest corners from a cell's centre: the same on every cell of a row.
            let half = DVec3::new(cos_lat, 0.0, sin_lat);
            let reach = [lat_n, lat_s]
                .iter()
                .map(|&lat| {
                    let corner = crate::geometry::unit_from_lon_lat(0.5 * dlon, lat);
                    corner.dot(half).clamp(-1.0, 1.0).acos()
                })
                .fold(0.0f64, f64::max);
            let rho = reach + widen;
            let sin_rho = rho.sin();
            let (sin_lon, cos_lon) = (&sin_lon, &cos_lon);
            let (north, south) = (&map.values[r * w..][..w], &map.values[(r + 1) * w..][..w]);
            (0..w).filter_map(move |c| {
                let east = if c + 1 == w { 0 } else { c + 1 };
                let high = north[c].max(north[east]).max(south[c]).max(south[east]) as f64;
                let centre = DVec3::new(cos_lat * cos_lon[c], cos_lat * sin_lon[c], sin_lat);
                range(high, centre, rho, sin_rho)
            })
        };
        let pole_ranges = poles
            .into_iter()
            .filter_map(|(high, centre, rho)| range(high, centre, rho, rho.sin()));
        let ranges: Vec<(f32, u32, u32, u32, u32)> = match parallel {
            true => (0..h - 1)
                .into_par_iter()
                .flat_map_iter(row_ranges)
                .collect::<Vec<_>>()
                .into_iter()
                .chain(pole_ranges)
                .collect(),
            false => (0..h - 1).flat_map(row_ranges).chain(pole_ranges).collect(),
        };
        // Each cap fills the cells it meets, its columns wrapped (at most two runs); on the
        // pool, each task the columns from `first` that it holds.
        let fill = |first: usize, columns: &mut [f64]| {
            let owned = first..first + columns.len() / n_theta;
            for &(high, i0, i1, j0, count) in &ranges {
                let high = high as f64;
                let (i0, i1) = (i0 as usize, i1 as usize);
                let (j0, count) = (j0 as usize, count as usize);
                let runs = [
                    (j0, (j0 + count).min(n_phi)),
                    (0, (j0 + count).saturating_sub(n_phi)),
                ];
                for (a, b) in runs {
                    for j in a.max(owned.start)..b.min(owned.end) {
                        for cell in &mut columns[(j - first) * n_theta..][i0..=i1] {
                            *cell = cell.max(high);
                        }
                    }
                }
            }
        };
        let mut highest = vec![f64::NEG_INFINITY; n_phi * n_theta];
        match parallel {
            true => {
                let per_task = n_phi.div_ceil(rayon::current_num_threads().max(1));
                highest
                    .par_chunks_mut(per_task * n_theta)
                    .enumerate()
                    .for_each(|(task, columns)| fill(task * per_task, columns));
            }
            false => fill(0, &mut highest),
        }
        let mut running_m = highest;
        let sin_hi: Vec<f64> = (0..n_theta)
            .map(|i| ((i + 1) as f64 * dtheta).min(FRAC_PI_2).sin())
            .collect();
        running_m.chunks_mut(n_theta).for_each(|column| {
            let mut most = f64::NEG_INFINITY;
            for (cell, sin_hi) in column.iter_mut().zip(&sin_hi) {
                // Every cell meets a cap (the caps cover the sphere); one that did not would
                // bound nothing, and stops every ray beyond it from being cut.
                let high = match cell.is_finite() {
                    true => *cell,
                    false => f64::INFINITY,
                };
                most = most.max((radius + high + e) * sin_hi);
                *cell = most;
            }
        });
        Some(SunEnvelope {
            sun,
            e1,
            e2,
            cos_alpha: alpha.cos(),
            dtheta,
            dphi,
            n_theta,
            n_phi,
            running_m,
        })
    }

    /// How far along the ray from the point `start_m` (body frame, from the centre) towards
    /// `toward` (unit) the ground may still meet it [m]: beyond this distance nothing can.
    /// `None` where the envelope does not say (a ray that is not the Sun's, a point at or
    /// beyond 90 deg from the subsolar point, or ground within the first cell towards the
    /// Sun high enough to reach the ray).
    #[inline]
    pub fn clear_beyond_m(&self, start_m: DVec3, toward: DVec3) -> Option<f64> {
        if toward.dot(self.sun) < self.cos_alpha {
            return None;
        }
        let r = start_m.length();
        let cos_theta = start_m.dot(self.sun) / r;
        if cos_theta <= 0.0 {
            return None;
        }
        let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
        let theta = crate::geometry::atan2_fast(sin_theta, cos_theta);
        let k = ((theta / self.dtheta) as usize).min(self.n_theta);
        if k == 0 {
            return None;
        }
        let phi = crate::geometry::atan2_fast(start_m.dot(self.e2), start_m.dot(self.e1));
        let j = (crate::geometry::floor_i64((phi + PI) / self.dphi).max(0) as usize)
            .min(self.n_phi - 1);
        let y = r * sin_theta;
        let column = &self.running_m[j * self.n_theta..][..k];
        // The running highest only grows with `theta`: the cells below `y` come first.
        let below = column.partition_point(|&v| v < y);
        if below == 0 {
            return None;
        }
        let theta_c = below as f64 * self.dtheta;
        // The parallel ray reaches `theta_c` at `x = y / tan(theta_c)` along the Sun's axis.
        Some((y / theta_c.tan() - r * cos_theta).max(0.0))
    }
}

#[cfg(test)]
mod tests {
    use crate::body::pyramid::{plains_rims_spikes, test_relief_over, unit_hash};
    use crate::geometry::unit_from_lon_lat;

    /// Rolling plains, crater rims 3 km high, single-texel spikes of 2 km and a polar cap of
    /// hills on a 720 x 360 grid over a body of 200 km, displaced and not, under Suns far and
    /// near (the nearer, the wider the envelope's margins): every Sun ray the envelope cuts
    /// short gets the answer of the marcher without any shortcut, from points spread over the
    /// lit side and crowded near the terminator (the grazing rays the envelope is for); a
    /// ray from any other direction is not cut; many rays are cut; and the envelope built on
    /// the pool is the one built on one thread.
    #[test]
    fn a_sun_ray_cut_by_the_envelope_gets_the_marchers_answer() {
        let hash = unit_hash;
        let height = |c: f64, r: f64, i: usize| {
            let cap = if r < 12.0 {
                800.0 * (c * 0.3).sin().abs()
            } else {
                0.0
            };
            plains_rims_spikes(c, r, i) + cap
        };
        let radius_m = 200_000.0;
        for displaces in [false, true] {
            let relief = test_relief_over(height, displaces, radius_m);
            let (mut cut, mut asked) = (0, 0);
            for (n, sun_km) in [(0, 1.5e8), (1, 4.0e4), (2, 5.0e3)] {
                let sun_dir = unit_from_lon_lat(
                    std::f64::consts::PI * (2.0 * hash(7 * n + 1) - 1.0),
                    1.4 * (2.0 * hash(7 * n + 2) - 1.0),
                );
                let sun_m = sun_dir * sun_km * 1e3;
                let framed = relief.under_sun(sun_m);
                let sun = framed.sun.as_deref().expect("a global DEM");
                let envelope = sun.built(&framed, n % 2 == 0).expect("a Sun far enough");
                // Built on the pool or on one thread, the same envelope.
                assert_eq!(
                    super::SunEnvelope::new(&framed, sun_m, n % 2 == 1).as_ref(),
                    Some(envelope)
                );
                for k in 0..6_000 {
                    let u = |j: usize| hash(k * 17 + j + 1000 * n);
                    // Half within 6 deg of the terminator, the others anywhere on the lit side.
                    let theta = if k % 2 == 0 {
                        (84.0 + 6.5 * u(1)).to_radians()
                    } else {
                        (90.0 * u(1)).to_radians()
                    };
                    let e1 = sun_dir.any_orthonormal_vector();
                    let e2 = sun_dir.cross(e1);
                    let phi = std::f64::consts::TAU * u(2);
                    let up = (theta.cos() * sun_dir
                        + theta.sin() * (phi.cos() * e1 + phi.sin() * e2))
                        .normalize();
                    let p = up * radius_m;
                    let toward = (sun_m - p).normalize();
                    // Only what the footprint and the view ask: a ray from a point of the
                    // smooth shape to the Sun.
                    let without = relief.march(up, toward, false);
                    assert_eq!(
                        framed.occluded(up, toward),
                        without,
                        "displaces {displaces}, Sun at {sun_km} km, ray {k} at {:.3} deg",
                        theta.to_degrees()
                    );
                    let (lon, lat) = crate::geometry::lon_lat(up);
                    let h0 = relief.heights_m.sample(lon, lat).unwrap();
                    let start = up * (radius_m + h0 + super::super::SHADOW_RAY_LIFT * radius_m);
                    asked += 1;
                    cut += envelope.clear_beyond_m(start, toward).is_some() as usize;
                    // A ray that is not the Sun's (the camera's) is never cut.
                    let elsewhere = (toward + 0.2 * toward.any_orthonormal_vector()).normalize();
                    assert_eq!(envelope.clear_beyond_m(start, elsewhere), None);
                }
            }
            assert!(
                cut > asked / 4,
                "displaces {displaces}: {cut} of {asked} rays cut short"
            );
        }
    }
}
