//! The terrain of a DEM as the ray caster sees it: the surface `r = R + h(lon, lat)` (bilinear
//! heights), met by sphere tracing ([`Terrain::intersect`]), independently of the pipeline's
//! fixed-step ray marching (a quarter texel, which a grazing ray can skip through).
//!
//! Sphere tracing alone crawls where a ray runs low over the ground (a shadow ray at a low Sun:
//! steps of `gap / (1 + s)`), so a pyramid of maximum heights ([`MaxPyramid`]) lets a ray leap
//! over whole blocks of texels whose highest point it clears, the "maximum mipmap" of height-
//! field ray casting (the DEM's own, [`crate::body::pyramid`]). Both give the same answer; the
//! pyramid only skips steps that cannot meet the ground.
//!
//! Where the gap allows less than the shortest step, a ray grazing a ridge may pass below the
//! ground and out again between two points above it; the bilinear ground is creased along
//! the rows and columns of texel centres, where such a ray is lowest, so the ray is tested
//! there too ([`Terrain::dip`]). Without it the tracer lit what the pipeline's marcher
//! shadowed, at the shadows' edges: the reference of a window of NRHO row 167 (129 deg of
//! phase) was 2.2e-4 too bright in total and 3e-3 at the median of its lit pixels beside a
//! fully dark one, which read as the renderer's bias there (`docs/performance.md`, "The
//! bias beside fully dark pixels was the reference's shadow test").

use crate::body::Relief;
use crate::body::pyramid::{MaxPyramid, RayPoint};
use glam::DVec3;
use std::sync::Arc;

pub(super) struct Terrain {
    radius_m: f64,
    top_m: f64,
    /// The steepest slope between neighbouring texels anywhere (tan of its angle): a ray
    /// rising more steeply than this cannot be blocked.
    max_slope: f64,
    /// The shortest step of the sphere tracing: a hundredth of a texel [m].
    min_step_m: f64,
    /// Block maxima of a global DEM (`None` for a regional one).
    pyramid: Option<Arc<MaxPyramid>>,
    /// The DEM (its heights, and the steepest slope within a rising ray's reach,
    /// [`Relief::slope_within_reach`], a bound on the map like the pyramid).
    relief: Relief,
}

/// A point of a ray: its gap above the ground [m], and where it is.
struct Probe {
    gap: f64,
    at: RayPoint,
}

impl Terrain {
    pub(super) fn new(relief: &Relief) -> Terrain {
        let map = relief.heights_m.clone();
        let r0 = relief.reference_radius_m();
        let (dlon, dlat) = map.spacing_rad();
        let (w, h) = (map.width, map.height);
        let v = |r: usize, c: usize| map.values[r * w + c] as f64;
        let (mut top, mut max_slope) = (f64::MIN, 0.0f64);
        for r in 0..h {
            let arc_e = r0 * map.row_lat(r).cos().abs().max(1e-9) * dlon;
            for c in 0..w {
                let here = v(r, c);
                top = top.max(here);
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
            relief: relief.clone(),
            min_step_m: 1e-2 * r0 * dlat,
            pyramid: relief.pyramid(),
            radius_m: r0,
            top_m: top.max(0.0),
            // Both slopes at once (the gradient's length) bound any direction's.
            max_slope: max_slope * std::f64::consts::SQRT_2,
        }
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
        self.trace(origin, dir, t0, 1.0 + self.max_slope, None)
    }

    /// [`Terrain::intersect`] with the step `g / rate`: `rate` at least the rate at which the
    /// ray can come nearer the ground per metre along it. A ray that `rises` (at least that
    /// sine of an elevation, from the ground) may step farther, by the slopes of the blocks
    /// within reach of each point ([`MaxPyramid::safe_step`]).
    fn trace(
        &self,
        origin: DVec3,
        dir: DVec3,
        t0: f64,
        rate: f64,
        rises: Option<f64>,
    ) -> Option<f64> {
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
        let hit_within = self.hit_within_m();
        let probe = |t: f64| {
            let q = origin + dir * t;
            let r = q.length();
            let up = q / r;
            let (lon, lat) = crate::geometry::lon_lat_fast(q);
            let h = self.relief.heights_m.sample(lon, lat).unwrap_or(0.0);
            Probe {
                gap: r - self.radius_m - h,
                at: RayPoint::on(&self.relief.heights_m, up, lon, lat),
            }
        };
        let gap = |t: f64| probe(t).gap;
        let mut t = t_in.max(t0);
        let mut at = probe(t);
        for _ in 0..MAX_STEPS {
            if at.gap <= hit_within {
                return Some(t);
            }
            let leap = self.pyramid.as_ref().map_or(0.0, |p| {
                p.leap(&self.relief.heights_m, origin, dir, t, &at.at)
            });
            if leap > 0.0 {
                t += leap;
                if t > t_out {
                    return None;
                }
                at = probe(t);
                continue;
            }
            let safe = match (rises, self.pyramid.as_ref()) {
                (Some(rise), Some(p)) => p.safe_step(&self.relief.heights_m, &at.at, at.gap, rise),
                _ => 0.0,
            };
            let bound = (at.gap / rate).max(safe);
            let next = t + bound.max(self.min_step_m);
            let ahead = probe(next);
            // The crossing between a point above the ground and one below it, by bisection.
            let crossing = |(mut lo, mut hi): (f64, f64)| {
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
                hi
            };
            if ahead.gap < 0.0 {
                // Overshot (a minimal step): the crossing lies between.
                return Some(crossing((t, next)));
            }
            // A minimal step, longer than the gap allows: the ray may dip below the ground
            // between two points above it (a grazing ray over a ridge).
            if bound < self.min_step_m
                && let Some(below) = self.dip(&gap, (t, &at.at), (next, &ahead.at))
            {
                return Some(crossing((t, below)));
            }
            if next > t_out {
                return None;
            }
            (t, at) = (next, ahead);
        }
        Some(t)
    }

    /// How near the ground a ray's point counts as meeting it [m].
    fn hit_within_m(&self) -> f64 {
        1e-9 * self.radius_m
    }

    /// A point of the ray between its points at `ta` and `tb` [m along it] (both above the
    /// ground, a minimal step apart) where it is below the ground: the bilinear ground is
    /// creased along the rows and columns of texel centres, and a ray grazing a ridge there
    /// is lowest above the crease, so the ray is tested where its track crosses one (at most
    /// one of each within a hundredth of a texel; the track taken straight in texel
    /// coordinates over the step). Within a cell the ground bends along the track by its
    /// twist alone, millimetres over a step. `None` where neither crossing is below the
    /// ground.
    fn dip(
        &self,
        gap: &impl Fn(f64) -> f64,
        (ta, pa): (f64, &RayPoint),
        (tb, pb): (f64, &RayPoint),
    ) -> Option<f64> {
        let map = &self.relief.heights_m;
        let w = map.width as f64;
        let mut dx = pb.x - pa.x;
        if map.wraps() && dx.abs() > 0.5 * w {
            dx -= w * dx.signum();
        }
        let dy = pb.y - pa.y;
        [(pa.x, dx), (pa.y, dy)].into_iter().find_map(|(from, d)| {
            let node = if d > 0.0 {
                from.floor() + 1.0
            } else {
                from.ceil() - 1.0
            };
            let f = (node - from) / d;
            let t = ta + f * (tb - ta);
            (d != 0.0 && f > 0.0 && f < 1.0 && gap(t) <= self.hit_within_m()).then_some(t)
        })
    }

    /// Whether the terrain hides direction `toward` (unit) from the surface point over the
    /// unit direction `up`. On a displaced surface the ray starts on it; on an undisplaced one
    /// (the DEM tilts the normals only) it starts at the terrain's height there, as the DEM
    /// says the ground lies.
    ///
    /// A rising ray is traced at the rate of the steepest slope within its reach (its radius
    /// does not fall; [`Relief::slope_within_reach`]), and one rising more steeply than that
    /// is clear at once ([`crate::body::rises_above`]). With the steepest slope anywhere
    /// (1 + 13.8 a metre on the LOLA DEM) and the system's arctangents, the reference of the
    /// NRHO's row 232 at 128 x 128 pixels (`config/nrho_textured.toml`, tolerance 1e-4)
    /// took 60 s; at the reach's rate 9.7 s, with the blocks' steps ([`Terrain::trace`])
    /// 6.2 s. Each step changed its total by less than 1e-7 and a hundred of its 16,343 lit
    /// pixels (by 8e-3, then 2.8e-3, at most: shadowed slivers where the cubature stops
    /// differently); the renderer's error against it is the same to three digits.
    pub(super) fn shadowed(&self, up: DVec3, toward: DVec3, displaced: bool) -> bool {
        let rise = toward.dot(up);
        let horizontal = (1.0 - rise * rise).max(0.0).sqrt();
        if rise > 0.0 && rise >= self.max_slope * horizontal {
            return false;
        }
        if rise <= 0.0 && !displaced {
            return false; // the BRDF's cosine on the sphere already says so
        }
        let (lon, lat) = crate::geometry::lon_lat(up);
        let (rate, rises) = if rise > 0.0 {
            if self.relief.rises_clear(rise, lon, lat) {
                return false;
            }
            let reach = self.relief.slope_within_reach(lon, lat);
            (reach, Some(rise))
        } else {
            (1.0 + self.max_slope, None)
        };
        let h0 = self.relief.heights_m.sample(lon, lat).unwrap_or(0.0);
        // Clear of the ground it starts on (a thousand times the hit tolerance above it), as
        // the pipeline's marcher's rays leave it.
        let start = up * (self.radius_m + h0 + crate::body::SHADOW_RAY_LIFT * self.radius_m);
        self.trace(start, toward, 0.0, rate, rises).is_some()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::maps::{Encoding, Map};

    /// A rough global DEM (craters and ridges of a few km on a 720 x 360 grid): the pyramid's
    /// leaps change no answer of the sphere tracing, for shadow rays at low Suns (polar ones
    /// included) and for rays from afar at every incidence, on the displaced surface; nor do
    /// a shadow ray's steps at the rate of the steepest slope within its reach, against the
    /// steepest anywhere.
    #[test]
    fn the_pyramid_leaps_and_the_reach_change_no_answer() {
        let hash = crate::body::pyramid::unit_hash;
        let relief = crate::body::pyramid::test_relief(
            |c, r, i| 3000.0 * (c * 0.07).sin() * (r * 0.11).cos() + 1500.0 * hash(i),
            true,
        );
        let radius = 1_737_400.0;
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
            // At the steepest slope anywhere, without leaps.
            let (lon, lat) = crate::geometry::lon_lat(up);
            let h0 = relief.heights_m.sample(lon, lat).unwrap_or(0.0);
            let start = up * (radius + h0 + crate::body::SHADOW_RAY_LIFT * radius);
            assert_eq!(
                fast.shadowed(up, toward, true),
                slow.intersect(start, toward, 0.0).is_some(),
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
        assert!(fast.pyramid.as_ref().unwrap().depth() >= 6);
    }

    /// Shadow rays from `n` points of `relief` within 69 deg of the equator, the Sun 0.1 to 15
    /// deg up in every azimuth: how many the pipeline's marcher ([`Relief::occluded`]) and
    /// this tracer both find shadowed, and how many only the one or the other.
    fn marcher_and_tracer(relief: &Relief, n: usize) -> (usize, usize, usize) {
        let tracer = Terrain::new(relief);
        let hash = crate::body::pyramid::unit_hash;
        let (mut shadowed, mut marcher_only, mut tracer_only) = (0, 0, 0);
        for k in 0..n {
            let u = |j: usize| hash(k * 7 + j) * 2.0 - 1.0;
            let up = crate::geometry::unit_from_lon_lat(std::f64::consts::PI * u(2), 1.2 * u(1));
            let (east, north) = crate::geometry::east_north(up);
            let az = std::f64::consts::PI * u(3);
            let elev = (0.1 + 15.0 * hash(k * 7 + 4)).to_radians();
            let toward =
                (elev.cos() * (az.cos() * east + az.sin() * north) + elev.sin() * up).normalize();
            match (
                relief.occluded(up, toward),
                tracer.shadowed(up, toward, false),
            ) {
                (true, true) => shadowed += 1,
                (true, false) => marcher_only += 1,
                (false, true) => tracer_only += 1,
                _ => {}
            }
        }
        eprintln!("shadowed {shadowed}, marcher only {marcher_only}, tracer only {tracer_only}");
        (shadowed, marcher_only, tracer_only)
    }

    /// The pipeline's marcher and this tracer agree on shadow rays over smooth hills at a low
    /// Sun (8 km high, 4.5 deg apart, slopes up to 0.18), where a grazing ray dips a few
    /// metres below a hilltop between two of the marcher's quarter-texel steps. With the
    /// steps alone the marcher lit 113 of the 23,700 points in 100,000 that the tracer
    /// shadows (0.5 %, all one way: a total 2.5e-4 too bright on the hills at 84 deg of
    /// phase and 16 points per pixel); checking each interval where the slopes allow a dip
    /// ([`Relief::occluded`]), it finds them. The dips of millimetres to decimetres that the
    /// tracer's shortest step (a hundredth of a texel) passed over, found by the marcher
    /// alone (8 here), it now finds at the ground's creases ([`Terrain::dip`]).
    #[test]
    fn the_marcher_and_the_tracer_agree_on_grazing_shadow_rays() {
        let (w, h) = (1440usize, 720usize);
        let values = (0..w * h)
            .map(|i| {
                let lon = ((i % w) as f64 + 0.5) / w as f64 * std::f64::consts::TAU;
                let lat = std::f64::consts::FRAC_PI_2
                    - ((i / w) as f64 + 0.5) / h as f64 * std::f64::consts::PI;
                4000.0 * (80.0 * lon).sin() * (80.0 * lat).cos()
            })
            .collect();
        let map = Map::from_values(
            std::path::Path::new("hills"),
            w,
            h,
            values,
            &Encoding::default(),
        )
        .unwrap();
        let relief = Relief::new(map, 1_737_400.0, false).unwrap();
        let (shadowed, marcher_only, tracer_only) = marcher_and_tracer(&relief, 100_000);
        assert!(shadowed > 20_000, "{shadowed}");
        assert!(tracer_only <= 5, "{tracer_only}");
        assert!(marcher_only <= 2, "{marcher_only}");
    }

    /// The Moon's LOLA DEM (`../shared`, 4 px/deg) over a sphere of `radius_m`, tilting the
    /// normals only.
    fn lunar_relief(radius_m: f64) -> Relief {
        let dem = Map::load(
            std::path::Path::new("../shared/data/moon/ldem_4.tif"),
            &Encoding {
                scale: 1000.0,
                ..Encoding::default()
            },
        )
        .unwrap_or_else(|e| panic!("{e}"));
        Relief::new(dem, radius_m, false).unwrap()
    }

    /// The same on the Moon's LOLA DEM (`../shared`, 4 px/deg): with the steps alone the
    /// marcher lit 133 of the 18,000 points the tracer shadows (0.7 %); now none. The
    /// tracer's steps alone lit 18 that the marcher shadows; with its creases tested, none.
    #[test]
    fn the_marcher_and_the_tracer_agree_on_the_lunar_dem() {
        let relief = lunar_relief(1_737_400.0);
        let (shadowed, marcher_only, tracer_only) = marcher_and_tracer(&relief, 100_000);
        assert!(shadowed > 15_000, "{shadowed}");
        assert!(tracer_only <= 5, "{tracer_only}");
        assert!(marcher_only <= 2, "{marcher_only}");
    }

    /// Sun rays from lit points beside the limb of Artemis I row 861 (159 deg of phase,
    /// `config/nrho_textured_budget.toml`), rising at 0.1 to 2 deg over the LOLA DEM, that
    /// pass a few centimetres below a ridge a few kilometres on. Between two of the
    /// marcher's points the ray lies up to `s^2 / (8 r)` below its chord (26 cm over a
    /// quarter texel of the 4 px/deg DEM); the marcher tested it only where the chord came
    /// lowest, and lit those points: 137 of 416,457 near that limb (2.2e-4 of their light,
    /// all one way), the frame +1.7e-4 too bright in total. It now halves such an interval
    /// where the ray is not below the ground there ([`Relief::occluded`]). A march of 2 m
    /// steps finds each of them under the ground, as the tracer does.
    #[test]
    fn the_marcher_finds_rays_a_few_centimetres_below_a_ridge() {
        let radius = 1_737_400.0;
        let relief = lunar_relief(radius);
        let tracer = Terrain::new(&relief);
        // (longitude, latitude) [deg] of the point and the unit direction to the Sun (B).
        let rays: [(f64, f64, f64, f64, f64); 7] = [
            (
                -65.41375962966924,
                11.040387231219073,
                -0.9051554404263973,
                -0.42501716943361917,
                -0.007350806291077111,
            ),
            (
                -65.21985189597008,
                10.97106346519989,
                -0.9051554418142447,
                -0.42501716672489404,
                -0.007350792011945166,
            ),
            (
                -65.5010774798416,
                10.956021959842943,
                -0.9051554418656546,
                -0.4250171666607026,
                -0.007350789393005991,
            ),
            (
                -65.24226138373749,
                8.399921749026468,
                -0.9051554830687008,
                -0.42501708787682874,
                -0.007350270972351305,
            ),
            (
                -65.0310152933832,
                7.304261298463067,
                -0.9051554977292937,
                -0.4250170605190975,
                -0.007350047492400347,
            ),
            (
                -65.63184148622683,
                -0.5983116695099538,
                -0.9051555484240555,
                -0.4250169805652761,
                -0.0073484276088688245,
            ),
            (
                -65.15620990852776,
                -1.4758133906672337,
                -0.9051555486372301,
                -0.42501698324261716,
                -0.0073482464969550736,
            ),
        ];
        for (lon, lat, x, y, z) in rays {
            let (lon_rad, lat_rad) = (lon.to_radians(), lat.to_radians());
            let up = crate::geometry::unit_from_lon_lat(lon_rad, lat_rad);
            let toward = DVec3::new(x, y, z);
            let h0 = relief.heights_m.sample(lon_rad, lat_rad).unwrap();
            let start = up * (radius + h0 + crate::body::SHADOW_RAY_LIFT * radius);
            let below = (1..25_000).any(|k| {
                let q = start + toward * (2.0 * k as f64);
                let (l, b) = crate::geometry::lon_lat_unit(q.normalize());
                q.length() < radius + relief.heights_m.sample(l, b).unwrap()
            });
            assert!(below, "({lon}, {lat}): the 2 m march finds no ground");
            assert!(
                tracer.shadowed(up, toward, false),
                "({lon}, {lat}): the tracer"
            );
            assert!(relief.occluded(up, toward), "({lon}, {lat}): the marcher");
        }
    }
}
