//! Horizons computed from the DEM in azimuth bins: the fast alternative to ray marching
//! (Eq. 33) that, unlike a map of one horizon per texel, knows where the Sun stands.
//!
//! For every texel of the DEM's grid and each of `n` azimuths `phi_k = 2 pi k / n` (from east
//! towards north), the terrain is walked along the great circle from the texel's centre, at
//! ray marching's points (the near field within the first step, then a quarter texel of
//! latitude a step), and the horizon is the highest
//! elevation seen, as its sine, above the sphere's tangent plane at the point `(R + h) up`:
//! `sin e = (r cos g - r0) / |q - p|` for terrain at radius `r` and arc `g`. A direction from
//! the point is hidden when it rises less than the horizon in its azimuth: that is ray
//! marching's test, since the ray and the terrain it passes over lie in the one plane through
//! the centre. The walk stops where even the highest point of the DEM would sit below the
//! horizon found so far (or below the horizontal: like ray marching, a direction that falls
//! below the horizontal is left to the BRDF's cosines).
//!
//! Only directions that rise more slowly than the steepest slope within the walk's reach can
//! be hidden: that slope is kept per texel (the steepest one-sided difference, which bounds
//! the bilinear DEM's gradient, taken over a window as wide as the reach), so that smooth
//! regions ask for no walk at all even when some crater wall elsewhere is steep. The same
//! bound lets the walk pass over stretches of terrain that cannot rise above the horizon found
//! so far.
//!
//! Texels are computed the first time a frame asks for them, a chunk of a row at a time, and
//! kept: only the terminator and limb bands ask, and the next frames along a trajectory mostly
//! find them. Every texel of a row walks the same path shifted in longitude (a rotation about
//! the pole), so a chunk turns its paths into longitude offsets and latitudes once, and the
//! walks themselves are map lookups only. The values are a pure function of the DEM, so which
//! thread computes a chunk changes nothing in the image.

use super::maps::{Map, Taps};
use glam::DVec3;
use std::sync::{Arc, OnceLock};

/// The walk's step, in texels of latitude: ray marching's.
const STEP_TEXELS: f64 = 0.25;
/// Steps a segment of the walk spans (two texels): a segment whose terrain, bounded by its
/// end samples and the reach's slope, cannot rise above the horizon found so far is passed
/// over with one sample.
const SEGMENT: usize = 8;
/// Texels of a row computed together on first use.
const CHUNK: usize = 8;
/// `sin e` in `[0, 1]` is kept as `u16`.
const SCALE: f64 = u16::MAX as f64;

/// The azimuth-resolved horizon of a DEM, filled on demand. See the module docs.
#[derive(Debug)]
pub struct DemHorizon {
    /// The DEM [m above `radius_m`] the horizons are of.
    heights: Arc<Map>,
    azimuths: usize,
    radius_m: f64,
    /// The highest point above `radius_m` [m].
    top_m: f64,
    /// `(sin g, cos g)` of the walk's arcs `g`, out to where no terrain can rise above the
    /// horizontal of the lowest point.
    arcs: Vec<(f64, f64)>,
    /// The same of the near field within the first step, walked first as ray marching tests
    /// it ([`super::NEAR_FIELD_STEPS`]).
    near: Vec<(f64, f64)>,
    /// Per texel, the tangent of the steepest slope within the walk's reach.
    reach_slope: Vec<f32>,
    chunks_per_row: usize,
    /// Per chunk (row-major), `azimuths` values a texel.
    chunks: Vec<OnceLock<Box<[u16]>>>,
}

impl DemHorizon {
    /// An empty cache for the DEM `heights` [m above `radius_m`], whose lowest and highest
    /// values are `bottom_m` and `top_m`, in `azimuths` bins (at least 4).
    pub fn new(
        heights: Arc<Map>,
        radius_m: f64,
        (bottom_m, top_m): (f64, f64),
        azimuths: usize,
    ) -> DemHorizon {
        let far = ((radius_m + bottom_m) / (radius_m + top_m))
            .clamp(-1.0, 1.0)
            .acos();
        let step = STEP_TEXELS * heights.spacing_rad().1;
        let arcs = (1..)
            .map(|k| k as f64 * step)
            .take_while(|&g| g <= far + step && g < std::f64::consts::FRAC_PI_2)
            .map(f64::sin_cos)
            .collect();
        let chunks_per_row = heights.width.div_ceil(CHUNK);
        DemHorizon {
            azimuths: azimuths.max(4),
            radius_m,
            top_m,
            arcs,
            near: super::NEAR_FIELD_STEPS
                .iter()
                .map(|f| (f * step).sin_cos())
                .collect(),
            reach_slope: reach_slope(&heights, radius_m, far),
            chunks_per_row,
            chunks: (0..chunks_per_row * heights.height)
                .map(|_| OnceLock::new())
                .collect(),
            heights,
        }
    }

    pub fn azimuths(&self) -> usize {
        self.azimuths
    }

    /// Computes every texel not computed yet, row by row, until `stop` says so; returns how
    /// many texels it computed. Meant for a background thread (the daemon's warm-up): frames
    /// that meanwhile ask for a chunk compute it themselves or wait for it, never twice.
    pub fn warm(&self, stop: impl Fn() -> bool) -> usize {
        let (w, h) = (self.heights.width, self.heights.height);
        let mut computed = 0;
        for row in 0..h {
            if stop() {
                break;
            }
            for first in (0..w).step_by(CHUNK) {
                self.chunks[row * self.chunks_per_row + first / CHUNK].get_or_init(|| {
                    computed += (first + CHUNK).min(w) - first;
                    self.fill(row, first)
                });
            }
        }
        computed
    }

    /// How many texels the DEM has (what [`DemHorizon::computed_texels`] reaches when warm).
    pub fn texels(&self) -> usize {
        self.heights.width * self.heights.height
    }

    /// How many texels have been computed so far.
    pub fn computed_texels(&self) -> usize {
        self.chunks
            .iter()
            .filter_map(|c| c.get())
            .map(|c| c.len() / self.azimuths)
            .sum()
    }

    /// Whether a direction rising by `rise` (the sine of its elevation) can be hidden
    /// anywhere around `taps`: it rises more slowly than the steepest slope within reach.
    pub fn may_hide(&self, taps: &Taps, rise: f64) -> bool {
        let slope = taps
            .texels()
            .map(|(t, _)| self.reach_slope[t])
            .fold(0.0f32, f32::max) as f64;
        rise < slope * (1.0 - rise * rise).max(0.0).sqrt()
    }

    /// The sine of the horizon's elevation at `taps` (on the DEM's grid) in the azimuth
    /// `azimuth_rad` (from east towards north): bilinear over the texels, linear between the
    /// two nearest bins. A pole's share of the taps is left out (the texels' weights are
    /// renormalised).
    pub fn sin_at(&self, taps: &Taps, azimuth_rad: f64) -> f64 {
        let n = self.azimuths;
        let f = azimuth_rad.rem_euclid(std::f64::consts::TAU) / std::f64::consts::TAU * n as f64;
        let k0 = (f as usize).min(n - 1);
        let (k1, t) = ((k0 + 1) % n, f - k0 as f64);
        let (mut sum, mut weight) = (0.0, 0.0);
        for (texel, w) in taps.texels() {
            if w == 0.0 {
                continue;
            }
            let values = self.texel(texel);
            let v = (1.0 - t) * values[k0] as f64 + t * values[k1] as f64;
            sum += w * v;
            weight += w;
        }
        if weight > 0.0 {
            sum / weight / SCALE
        } else {
            0.0
        }
    }

    /// The horizon of one texel, every azimuth.
    fn texel(&self, texel: usize) -> &[u16] {
        let (row, col) = (texel / self.heights.width, texel % self.heights.width);
        let c = row * self.chunks_per_row + col / CHUNK;
        let chunk = self.chunks[c].get_or_init(|| self.fill(row, col / CHUNK * CHUNK));
        let i = col % CHUNK;
        &chunk[i * self.azimuths..(i + 1) * self.azimuths]
    }

    /// The horizons of the chunk of row `row` from column `first`.
    fn fill(&self, row: usize, first: usize) -> Box<[u16]> {
        let heights = &*self.heights;
        let n = self.azimuths;
        let last = (first + CHUNK).min(heights.width);
        // The paths from the chunk's first texel, as longitude offsets and latitudes.
        let (lon0, lat) = heights.texel_centre(first, row);
        let up = crate::geometry::unit_from_lon_lat(lon0, lat);
        let (east, north) = crate::geometry::east_north(up);
        let per_walk = self.near.len() + self.arcs.len();
        let mut path = Vec::with_capacity(n * per_walk);
        for k in 0..n {
            let phi = std::f64::consts::TAU * k as f64 / n as f64;
            let along = phi.cos() * east + phi.sin() * north;
            for &(s, c) in self.near.iter().chain(&self.arcs) {
                let q: DVec3 = up * c + along * s;
                let (lon, lat) = crate::geometry::lon_lat(q);
                path.push((lon - lon0, lat));
            }
        }
        let r_top = self.radius_m + self.top_m;
        let (dlon, dlat) = heights.spacing_rad();
        // A segment of SEGMENT steps [m]: between two samples of it, the terrain rises at most
        // the reach's slope times half of it above their mean.
        let segment_m = self.radius_m * SEGMENT as f64 * STEP_TEXELS * dlat;
        let mut out = vec![0u16; (last - first) * n];
        for (col, values) in (first..last).zip(out.chunks_mut(n)) {
            let lon = lon0 + (col - first) as f64 * dlon;
            let texel = row * heights.width + col;
            let h0 = heights.values[texel] as f64;
            let r0 = self.radius_m + h0;
            // `sin e` of terrain at radius `r` and arc `(sin g, cos g)` seen from `r0 up`.
            let sin_elevation = |r: f64, (s, c): (f64, f64)| {
                let (x, y) = (r * c - r0, r * s);
                x / (x * x + y * y).sqrt()
            };
            let rise = self.reach_slope[texel] as f64 * segment_m;
            for (value, walk) in values.iter_mut().zip(path.chunks(per_walk)) {
                let mut best = 0.0f64;
                let (near, walk) = walk.split_at(self.near.len());
                for (&sc, &(dl, la)) in self.near.iter().zip(near) {
                    if let Some(h) = heights.sample(lon + dl, la) {
                        best = best.max(sin_elevation(self.radius_m + h, sc));
                    }
                }
                // Segment by segment: sampled a step at a time only where the bound on its
                // terrain could rise above the horizon found so far. What is skipped cannot
                // change the result (as far as the one-sided slopes bound the bilinear DEM's):
                // on config/moon.toml it is the same as walking every step.
                let mut h_start = Some(h0);
                for (arcs, walk) in self.arcs.chunks(SEGMENT).zip(walk.chunks(SEGMENT)) {
                    // The highest point of the DEM at this arc bounds the rest of the walk.
                    if sin_elevation(r_top, arcs[0]) <= best {
                        break;
                    }
                    let (dl, la) = walk[walk.len() - 1];
                    let h_end = heights.sample(lon + dl, la);
                    if let (Some(a), Some(b), true) = (h_start, h_end, arcs.len() == SEGMENT) {
                        let top = 0.5 * (a + b + rise);
                        if sin_elevation(self.radius_m + top, arcs[0]) <= best {
                            h_start = h_end;
                            continue;
                        }
                    }
                    for (&sc, &(dl, la)) in arcs.iter().zip(walk) {
                        if sin_elevation(r_top, sc) <= best {
                            break;
                        }
                        if let Some(h) = heights.sample(lon + dl, la) {
                            best = best.max(sin_elevation(self.radius_m + h, sc));
                        }
                    }
                    h_start = h_end;
                }
                *value = (best * SCALE).round() as u16;
            }
        }
        out.into_boxed_slice()
    }
}

/// Per texel, the tangent of the steepest slope within `reach_rad` of arc: the steepest
/// one-sided differences east-west and north-south [m/m] combined, then the largest over a
/// window of that reach ([`super::pyramid::window_max`]).
fn reach_slope(heights: &Map, radius_m: f64, reach_rad: f64) -> Vec<f32> {
    let (w, h) = (heights.width, heights.height);
    let (dlon, dlat) = heights.spacing_rad();
    let v = |r: usize, c: usize| heights.values[r * w + c] as f64;
    let wraps = heights.wraps();
    let mut slope = vec![0.0f32; w * h];
    for r in 0..h {
        let dx = radius_m * heights.row_lat(r).cos().max(1e-6) * dlon;
        let dy = radius_m * dlat;
        for c in 0..w {
            let (cw, ce) = if wraps {
                ((c + w - 1) % w, (c + 1) % w)
            } else {
                (c.saturating_sub(1), (c + 1).min(w - 1))
            };
            let x = (v(r, ce) - v(r, c)).abs().max((v(r, c) - v(r, cw)).abs()) / dx;
            let (rn, rs) = (r.saturating_sub(1), (r + 1).min(h - 1));
            let y = (v(rs, c) - v(r, c)).abs().max((v(r, c) - v(rn, c)).abs()) / dy;
            slope[r * w + c] = x.hypot(y) as f32;
        }
    }
    super::pyramid::window_max(&slope, heights, reach_rad)
}

/// Two caches are equal when they would hold the same values for equal DEMs.
impl PartialEq for DemHorizon {
    fn eq(&self, other: &Self) -> bool {
        (self.azimuths, self.radius_m, self.top_m, self.chunks.len())
            == (
                other.azimuths,
                other.radius_m,
                other.top_m,
                other.chunks.len(),
            )
    }
}
