//! Integration and point-cloud generation (Sec. 4.6, Eqs. 12, 34-38).
//!
//! Each kept quadrangle `j` gets
//! `(P/L)_j = A_sun A_cam cos(eps_j) / (d_sun,j^2 d_cam,j^2) R^2 F_r,j` (Eq. 12), with
//! `F_r,j = integral over the quadrangle of f_r cos(theta_i) cos(theta_r) cos(lat) dlat dlon`
//! (Eq. 34, written in latitude).
//!
//! - **exact**: the paper's Lambert solution (Eqs. 35-36) assumes the Sun and camera
//!   directions of the body centre. Here the same closed form is generalised to the
//!   quadrangle's own midpoint directions `s`, `c`: `mu0 mu = (n.s)(n.c)` is a quadratic form
//!   in the normal `n`, so its integral is `s^T M c` with `M` the second moments of `n` over the
//!   quadrangle, products of one longitude and one latitude integral (Lambert). The Area model
//!   needs the first moments. With `s = X` and `c = (cos a, sin a, 0)` this reduces exactly to
//!   Eq. 35.
//! - **trapezoidal**: the trapezoidal rule on a sub-grid of `points_per_deg` points per degree,
//!   but no more than `points_per_px` per pixel the quadrangle spans in the image (a
//!   far body needs no 25 BRDF evaluations per square degree when a degree is half a pixel),
//!   at least 2 per side; each sample with its own directions and distances.
//! - **midpoint**: the composite midpoint rule on the same sub-grid (nodes at the cells'
//!   centres, at least 1 per side): a faster alternative of the same order.
//! - **pointwise**: the BRDF at the midpoint times the quadrangle's area (Eqs. 37-38).
//!
//! Quadrangles that straddle the limb or the terminator (see [`super::pruning`]) are integrated
//! over their lit and visible part only, which no closed form can do. On a sphere that part is
//! known exactly ([`LitVisible`]): at latitude `lat` a point is lit when
//! `cos(lat) cos(lon) > R/d_sun` and visible when `cos(lat) cos(lon - alpha) > R/d_cam` (Eqs.
//! 29 and 31 with the finite distances), so each Gauss-Legendre latitude node gets its exact
//! longitude interval and a Gauss-Legendre rule over it. The latitude range is split where the
//! interval's ends switch from one curve to another, and mapped by `lat = end - (end-a) u^2`
//! where the interval closes like a square root, so every piece is smooth: the Area model's
//! step at the terminator costs nothing, and Lambert's kink neither. Other shapes fall back to
//! the trapezoidal rule with the integrand clamped at zero.

use super::pruning::{BOUNDARY, PRUNED};
use super::sampling::GridTrig;
use super::settings::{Integration, MapFilter};
use super::view::View;
use crate::body::LitVisible;
use crate::body::{AlbedoMap, Body};
use crate::brdf::{Brdf, ExactForm, Local};
use glam::DVec3;
use rayon::prelude::*;

/// Trapezoid points per side, at least, on boundary quadrangles of shapes without an exact
/// lit-and-visible region ([`crate::body::Shape::lit_visible`]): the clamped integrand has a
/// kink there (a step for the Area model), so the rule converges only as 1/n on them.
const BOUNDARY_MIN_POINTS: usize = 4;

/// Gauss-Legendre nodes and weights on [0, 1].
#[derive(Clone, Debug)]
pub struct Nodes {
    x: Vec<f64>,
    w: Vec<f64>,
}

impl Nodes {
    pub fn new(n: usize) -> Self {
        let (x, w) = crate::radiometry::gauss_legendre(n);
        Nodes {
            x: x.iter().map(|x| 0.5 * (x + 1.0)).collect(),
            w: w.iter().map(|w| 0.5 * w).collect(),
        }
    }
}

/// The integral over quadrangle `(i, k)` of `f_r mu0 mu cos(lat) cos(eps)/(d_s^2 d_c^2)`
/// restricted exactly to the lit and visible part of a sphere; adds its surface samples to
/// `samples`.
#[allow(clippy::too_many_arguments)]
fn clipped(
    view: &View,
    brdf: &Brdf,
    clip: &LitVisible,
    nodes: &Nodes,
    trig: &GridTrig,
    i: usize,
    k: usize,
    samples: &mut usize,
) -> f64 {
    let (mut p0, mut p1) = (trig.lon[i], trig.lon[i + 1]);
    // Longitudes into (-pi, pi] around the quadrangle's centre (the curves are written there).
    let shift = crate::geometry::wrap_pi(0.5 * (p0 + p1)) - 0.5 * (p0 + p1);
    p0 += shift;
    p1 += shift;
    let (l0, l1) = (trig.lat[k], trig.lat[k + 1]);
    let mut cuts = [0.0; 16];
    let nb = clip.breaks(p0, p1, l0, l1, &mut cuts);
    let mut edges = [0.0; 18];
    edges[0] = l0;
    edges[1..=nb].copy_from_slice(&cuts[..nb]);
    edges[nb + 1] = l1;
    let closes = |lat: f64| clip.closes_at(lat.cos());
    let mut total = 0.0;
    for piece in edges[..nb + 2].windows(2) {
        let (a, b) = (piece[0], piece[1]);
        if b <= a {
            continue;
        }
        // Which end (if any) the interval closes at: map it by a square so the width is smooth.
        let (close_lo, close_hi) = (closes(a), closes(b));
        for (&u, &wu) in nodes.x.iter().zip(&nodes.w) {
            let (lat, jac) = match (close_lo, close_hi) {
                (false, true) => (b - (b - a) * u * u, 2.0 * (b - a) * u),
                (true, false) => (a + (b - a) * u * u, 2.0 * (b - a) * u),
                (true, true) => {
                    // Closes at both ends: sine map, width ~ sin, smooth.
                    let t = 0.5 * (1.0 - (std::f64::consts::PI * u).cos());
                    let dt = 0.5 * std::f64::consts::PI * (std::f64::consts::PI * u).sin();
                    (a + (b - a) * t, (b - a) * dt)
                }
                (false, false) => (a + (b - a) * u, b - a),
            };
            let (sl, cl) = lat.sin_cos();
            let Some((lo, hi)) = clip.lon_interval(cl, p0, p1) else {
                continue;
            };
            let mut row = 0.0;
            *samples += nodes.x.len();
            for (&v, &wv) in nodes.x.iter().zip(&nodes.w) {
                let (so, co) = (lo + (hi - lo) * v).sin_cos();
                let (g, geo) = sample(view, DVec3::new(cl * co, cl * so, sl));
                if g.mu0 > 0.0 && g.mu > 0.0 && geo > 0.0 {
                    row += wv * brdf.eval(&g) * g.mu0 * g.mu * geo;
                }
            }
            total += wu * jac * row * (hi - lo) * cl;
        }
    }
    total
}

/// The method after checking it against the BRDF.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Method {
    Exact(ExactForm),
    /// The trapezoidal or midpoint rule on a sub-grid of `points_per_deg` per degree.
    SubGrid {
        rule: Rule,
        points_per_deg: f64,
    },
    Pointwise,
}

/// The rule on a quadrangle's sub-grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rule {
    /// Nodes on the cell corners, halved on the edges (at least 2 per side).
    Trapezoid,
    /// Nodes at the cell centres (at least 1 per side): same order, half the error constant
    /// for smooth integrands, and no node on an edge that the neighbour evaluates again.
    Midpoint,
}

impl Rule {
    /// Nodes per side, at least, on an interior quadrangle.
    fn min_points(self) -> usize {
        match self {
            Rule::Trapezoid => 2,
            Rule::Midpoint => 1,
        }
    }
}

#[derive(Debug, thiserror::Error, PartialEq)]
#[error(
    "render.integration = \"exact\" has no closed form {reason}: use \"auto\", \"trapezoidal\", \"midpoint\" or \"pointwise\""
)]
pub struct NoClosedForm {
    pub reason: String,
}

impl Method {
    /// The integration method for `body`, whose DEM the quadrangles carry where
    /// `relief_on_quadrangles` (not under `MapFilter::Relief`, where the footprint step reads
    /// it and the quadrangles integrate the smooth shape). The closed forms need the BRDF to
    /// have one and the normals to be the shape's own (no DEM tilting them).
    pub fn resolve(
        integration: Integration,
        body: &Body,
        relief_on_quadrangles: bool,
    ) -> Result<Method, NoClosedForm> {
        let relief = body.relief.as_ref().filter(|_| relief_on_quadrangles);
        let form = match (relief, body.brdf.exact_form()) {
            _ if !body.shape.is_round() => Err(NoClosedForm {
                reason: "on a non-spherical shape (the closed forms are the sphere's)".into(),
            }),
            (None, Some(f)) => Ok(f),
            (Some(_), _) => Err(NoClosedForm {
                reason: "with a DEM (it tilts the normals)".into(),
            }),
            (None, None) => Err(NoClosedForm {
                reason: format!("for the {} BRDF", body.brdf.name()),
            }),
        };
        Ok(match integration {
            Integration::Auto { points_per_deg } => match form {
                Ok(f) => Method::Exact(f),
                Err(_) => Method::SubGrid {
                    rule: Rule::Trapezoid,
                    points_per_deg,
                },
            },
            Integration::Exact => Method::Exact(form?),
            Integration::Trapezoidal { points_per_deg } => Method::SubGrid {
                rule: Rule::Trapezoid,
                points_per_deg,
            },
            Integration::Midpoint { points_per_deg } => Method::SubGrid {
                rule: Rule::Midpoint,
                points_per_deg,
            },
            Integration::Pointwise => Method::Pointwise,
        })
    }
}

/// Longitude integrals of one column `[p0, p1]`.
#[derive(Clone, Copy, Default)]
struct LonMoments {
    d: f64,  // int 1
    c: f64,  // int cos
    s: f64,  // int sin
    cc: f64, // int cos^2
    ss: f64, // int sin^2
    cs: f64, // int cos sin
}

impl LonMoments {
    /// Product-form differences keep full relative precision for tiny steps.
    fn new(p0: f64, p1: f64) -> Self {
        let (m, h) = (0.5 * (p0 + p1), 0.5 * (p1 - p0));
        let (sm, cm) = m.sin_cos();
        let sh = h.sin();
        let d = p1 - p0;
        let dsin = 2.0 * cm * sh; // sin p1 - sin p0
        let dcos = -2.0 * sm * sh; // cos p1 - cos p0
        let dsin2 = 2.0 * (p0 + p1).cos() * d.sin(); // sin 2p1 - sin 2p0
        LonMoments {
            d,
            c: dsin,
            s: -dcos,
            cc: 0.5 * d + 0.25 * dsin2,
            ss: 0.5 * d - 0.25 * dsin2,
            cs: 0.5 * dsin * (p1.sin() + p0.sin()),
        }
    }
}

/// Latitude integrals of one row `[l0, l1]` (the area element carries `cos(lat)`).
#[derive(Clone, Copy, Default)]
struct LatMoments {
    c3: f64,  // int cos^3            (x x, y y, x y)
    s2c: f64, // int sin^2 cos        (z z)
    c2s: f64, // int cos^2 sin        (x z, y z)
    c2: f64,  // int cos^2            (first moments x, y)
    sc: f64,  // int sin cos          (first moment z)
}

impl LatMoments {
    fn new(l0: f64, l1: f64) -> Self {
        let (m, h) = (0.5 * (l0 + l1), 0.5 * (l1 - l0));
        let (sm, cm) = m.sin_cos();
        let sh = h.sin();
        let (s0, s1, c0, c1) = (l0.sin(), l1.sin(), l0.cos(), l1.cos());
        let ds = 2.0 * cm * sh;
        let dc = -2.0 * sm * sh;
        let ds3 = ds * (s1 * s1 + s1 * s0 + s0 * s0);
        let dc3 = dc * (c1 * c1 + c1 * c0 + c0 * c0);
        let d = l1 - l0;
        LatMoments {
            c3: ds - ds3 / 3.0,
            s2c: ds3 / 3.0,
            c2s: -dc3 / 3.0,
            c2: 0.5 * d + 0.5 * (l0 + l1).cos() * d.sin(),
            sc: 0.5 * ds * (s1 + s0),
        }
    }
}

/// `integral of (n.a)(n.b) dOmega` over the quadrangle (second moments).
#[inline(always)]
fn bilinear(a: DVec3, b: DVec3, lo: &LonMoments, la: &LatMoments) -> f64 {
    let xx = la.c3 * lo.cc;
    let yy = la.c3 * lo.ss;
    let zz = la.s2c * lo.d;
    let xy = la.c3 * lo.cs;
    let xz = la.c2s * lo.c;
    let yz = la.c2s * lo.s;
    a.x * b.x * xx
        + a.y * b.y * yy
        + a.z * b.z * zz
        + (a.x * b.y + a.y * b.x) * xy
        + (a.x * b.z + a.z * b.x) * xz
        + (a.y * b.z + a.z * b.y) * yz
}

/// `integral of (n.a) dOmega` over the quadrangle (first moments).
#[inline(always)]
fn linear(a: DVec3, lo: &LonMoments, la: &LatMoments) -> f64 {
    a.x * la.c2 * lo.c + a.y * la.c2 * lo.s + a.z * la.sc * lo.d
}

/// A surface sample seen from the camera: local geometry and `cos(eps) / (d_sun^2 d_cam^2)`.
#[inline(always)]
fn sample(view: &View, dir: DVec3) -> (Local, f64) {
    let sp = view.surface_point(dir);
    let (p, n, area) = (sp.p, sp.normal, sp.area);
    let to_c = view.cam_csf - p;
    let to_s = view.sun_csf - p;
    let (dc2, ds2) = (to_c.length_squared(), to_s.length_squared());
    let (dc, ds) = (dc2.sqrt(), ds2.sqrt());
    let cos_eps = view.to_camera(p).z / dc;
    let c_hat = to_c / dc;
    let mut g = Local::new(n, to_s / ds, c_hat);
    // A displaced point where the terrain may hide the camera shows it the ground's own
    // projected area, whatever normal the BRDF sees (as a pixel's lines of sight meet the
    // ground): `area mu` becomes `(ground . c) (|p|/R)^2`
    // ([`crate::body::Relief::ground_normal`]). There the camera's occlusion keeps the
    // ground facing it, which is steeper than the interpolated normal says: weighed by that
    // normal, the LOLA Moon's limb was 1.1e-3 of the frame's light dark. Elsewhere every
    // point is seen, the two weights integrate to the same area over a pixel, and the
    // interpolated normal's, continuous across the texels' edges, is gridded better (the
    // ground's everywhere doubled the median at 20,000 km and 110 deg of phase).
    // (The cheap tests first: the ground's area is made only where it weighs.)
    let area = if sp.ground.is_some() && g.mu > 0.0 && view.camera_below_steep_slopes(dir, c_hat) {
        view.ground_area(&sp, dir, c_hat)
            .map_or(area, |shown| shown / g.mu)
    } else {
        area
    };
    // A shadowed or hidden point contributes nothing (its cosine is taken as 0).
    view.shadow(dir, p, sp.horizon_sin, &mut g);
    (g, area * cos_eps / (ds2 * dc2))
}

/// The largest relative change of a quadrangle's cosines (to the Sun and to the camera) across
/// one cell of its sub-grid.
const GRAZING_STEP: f64 = 0.05;
/// The most nodes per side that grazing adds.
const GRAZING_MAX_POINTS: usize = 16;

/// The trapezoidal or midpoint rule over quadrangle `(i, k)` with clamped cosines, on a
/// sub-grid of `points_per_deg` per degree, capped by `px_cap`, at least `min_points` per side;
/// adds its surface samples to `samples`.
#[allow(clippy::too_many_arguments)]
fn sub_grid(
    view: &View,
    brdf: &Brdf,
    trig: &GridTrig,
    i: usize,
    k: usize,
    rule: Rule,
    points_per_deg: f64,
    px_cap: &PixelCap,
    min_points: usize,
    samples: &mut usize,
) -> f64 {
    let (p0, p1) = (trig.lon[i], trig.lon[i + 1]);
    let (l0, l1) = (trig.lat[k], trig.lat[k + 1]);
    // Pixels per radian of arc on the surface here (an upper bound: no foreshortening).
    let px_per_rad = px_cap.px_per_rad(view, trig.mid_dir(i, k));
    let extra = match rule {
        Rule::Trapezoid => 1,
        Rule::Midpoint => 0,
    };
    let count = |span: f64, arc: f64| {
        let n = (span.to_degrees() * points_per_deg).min(span * arc * px_per_rad);
        (n.ceil() as usize + extra).clamp(min_points, 64)
    };
    let lat_mid = 0.5 * (l0 + l1);
    let (mut nu, mut nv) = (count(p1 - p0, lat_mid.cos()), count(l1 - l0, 1.0));
    // Where the Sun or the camera grazes the quadrangle, its cosines change across it by
    // more than a few percent of themselves (by about its angular side over the cosine) and
    // the integrand's curvature biases a rule with few nodes: the Artemis I pass 263 km above
    // the Moon at 118 deg of phase, whose lit strip is seen near the horizon, summed 4.4e-3
    // too much light at 1 quadrangle per pixel with one node each. There the nodes are set
    // so that each cell's cosines change by at most GRAZING_STEP of themselves.
    let (mid, mid_geo) = sample(view, trig.mid_dir(i, k));
    let low = mid.mu0.min(mid.mu);
    if low > 0.0 {
        let need = |side_rad: f64| {
            ((side_rad / (GRAZING_STEP * low)).ceil() as usize + extra).min(GRAZING_MAX_POINTS)
        };
        nu = nu.max(need((p1 - p0) * lat_mid.cos()));
        nv = nv.max(need(l1 - l0));
    }
    if rule == Rule::Midpoint && nu == 1 && nv == 1 {
        // One node: the midpoint already sampled.
        *samples += 1;
        if mid.mu0 > 0.0 && mid.mu > 0.0 && mid_geo > 0.0 {
            return brdf.eval(&mid)
                * mid.mu0
                * mid.mu
                * lat_mid.cos()
                * mid_geo
                * (p1 - p0)
                * (l1 - l0);
        }
        return 0.0;
    }
    // Node `a` of `n` across `[lo, hi]` and its weight in units of the spacing.
    let node = |lo: f64, hi: f64, a: usize, n: usize| match rule {
        Rule::Trapezoid => {
            let w = if a == 0 || a == n - 1 { 0.5 } else { 1.0 };
            (lo + (hi - lo) * a as f64 / (n - 1) as f64, w)
        }
        Rule::Midpoint => (lo + (hi - lo) * (a as f64 + 0.5) / n as f64, 1.0),
    };
    // The longitude nodes' sines, cosines and weights, shared by every latitude row.
    let mut columns = [(0.0, 0.0, 0.0); 64];
    for (a, c) in columns[..nu].iter_mut().enumerate() {
        let (lon, wa) = node(p0, p1, a, nu);
        let (so, co) = lon.sin_cos();
        *c = (so, co, wa);
    }
    *samples += nu * nv;
    let mut sum = 0.0;
    for b in 0..nv {
        let (lat, wb) = node(l0, l1, b, nv);
        let (sl, cl) = lat.sin_cos();
        for &(so, co, wa) in &columns[..nu] {
            let (g, geo) = sample(view, DVec3::new(cl * co, cl * so, sl));
            if g.mu0 > 0.0 && g.mu > 0.0 && geo > 0.0 {
                sum += wa * wb * brdf.eval(&g) * g.mu0 * g.mu * cl * geo;
            }
        }
    }
    let cells = |n: usize| (n - extra) as f64;
    sum * (p1 - p0) / cells(nu) * (l1 - l0) / cells(nv)
}

/// The sub-grid's cap in image space: at most `points_per_px` points per pixel a quadrangle
/// spans (0 = no cap).
pub struct PixelCap {
    /// `points_per_px * R * f_px` [px m]: divided by the range, points per radian of arc.
    scale: f64,
}

impl PixelCap {
    pub fn new(view: &View, points_per_px: f64) -> PixelCap {
        let (fu, fv) = view.intrinsics.focal_px();
        let scale = if points_per_px > 0.0 {
            points_per_px * view.shape.bounding_radius_m() * fu.max(fv) * view.m
        } else {
            f64::INFINITY
        };
        PixelCap { scale }
    }

    /// Points per radian of surface arc at the surface over CSF direction `dir`, an upper
    /// bound: the arc is taken face-on. (Foreshortening it by the line of sight, so that a
    /// limb quadrangle gets as many points per pixel as a central one, saved 30 % of the
    /// samples on the NRHO Moon at 2 points per pixel but doubled the 99th-percentile pixel
    /// error there and the total's error at 150 deg phase; with the cap raised to match the
    /// accuracy it saved nothing.)
    #[inline]
    fn px_per_rad(&self, view: &View, dir: DVec3) -> f64 {
        if self.scale.is_infinite() {
            return f64::INFINITY;
        }
        self.scale / (view.cam_csf - view.rough_point(dir)).length()
    }
}

/// Fills `pl` with `(P/L)_j` [sr m^2] of every quadrangle (zero where pruned) and returns
/// their sum, accumulated row by row in a fixed order, and the number of surface samples
/// (BRDF evaluations) it took.
/// `boundary_nodes` Gauss-Legendre nodes per dimension and per piece integrate the
/// quadrangles that straddle the limb or the terminator.
#[allow(clippy::too_many_arguments)]
pub fn integrate(
    view: &View,
    trig: &GridTrig,
    keep: &[u8],
    brdf: &Brdf,
    albedo: Option<&AlbedoMap>,
    map_filter: MapFilter,
    method: Method,
    boundary_nodes: usize,
    points_per_px: f64,
    a_sun_m2: f64,
    a_cam_m2: f64,
    pl: &mut Vec<f64>,
) -> (f64, usize) {
    // The closed form's constant is the BRDF's own: the one passed here (the reference scale
    // of `MapFilter::Pixel`), or per quadrangle the map's.
    let method = match method {
        Method::Exact(_) => brdf.exact_form().map_or(method, Method::Exact),
        _ => method,
    };
    let clip = view.lit_visible();
    let nodes = Nodes::new(boundary_nodes.max(1));
    let (nl, nk) = (trig.n_lon(), trig.n_lat());
    let r = view.shape.bounding_radius_m();
    let k_const = a_sun_m2 * a_cam_m2 * r * r;
    let lon_m: Vec<LonMoments> = match method {
        Method::Exact(_) => (0..nl)
            .map(|i| LonMoments::new(trig.lon[i], trig.lon[i + 1]))
            .collect(),
        _ => Vec::new(),
    };
    let px_cap = PixelCap::new(view, points_per_px);
    let boundary_ppd = match method {
        Method::SubGrid { points_per_deg, .. } => points_per_deg,
        _ => 5.0,
    };
    pl.clear();
    pl.resize(nl * nk, 0.0);
    let row_sums: Vec<(f64, usize)> = pl
        .par_chunks_mut(nl)
        .enumerate()
        .map(|(k, row)| {
            let la = LatMoments::new(trig.lat[k], trig.lat[k + 1]);
            let area_lat = trig.lat[k + 1].sin() - trig.lat[k].sin();
            let (mut sum, mut samples) = (0.0, 0);
            for (i, out) in row.iter_mut().enumerate() {
                let class = keep[k * nl + i];
                if class == PRUNED {
                    continue;
                }
                // With an albedo map the BRDF's scale is constant over the quadrangle (paper
                // Sec. 4.4): the map's at its centre, or its mean over the quadrangle (whose
                // side is the square root of its area on the unit sphere).
                let local;
                let brdf = match albedo {
                    Some(a) => {
                        let n_body = view.body_dir(trig.mid_dir(i, k));
                        let scale = match map_filter {
                            MapFilter::Point => a.scale_at(n_body, brdf.scale()),
                            // (Under `Pixel` and `Relief` the renderer passes no map here.)
                            MapFilter::Area | MapFilter::Pixel | MapFilter::Relief => {
                                let side = ((trig.lon[i + 1] - trig.lon[i]) * area_lat).sqrt();
                                a.scale_over(n_body, side, brdf.scale())
                            }
                        };
                        local = brdf.with_scale(scale);
                        &local
                    }
                    None => brdf,
                };
                let method = match (method, albedo) {
                    (Method::Exact(_), Some(_)) => brdf.exact_form().map_or(method, Method::Exact),
                    _ => method,
                };
                let f = if class == BOUNDARY {
                    match &clip {
                        Some(c) => clipped(view, brdf, c, &nodes, trig, i, k, &mut samples),
                        None => {
                            let (rule, n) = (Rule::Trapezoid, BOUNDARY_MIN_POINTS);
                            let ppd = boundary_ppd;
                            sub_grid(view, brdf, trig, i, k, rule, ppd, &px_cap, n, &mut samples)
                        }
                    }
                } else {
                    match method {
                        Method::Exact(form) => {
                            samples += 1;
                            let (g, geo) = sample(view, trig.mid_dir(i, k));
                            geo * match form {
                                ExactForm::Bilinear(kf) => kf * bilinear(g.s, g.c, &lon_m[i], &la),
                                ExactForm::Linear(kf) => kf * linear(g.c, &lon_m[i], &la),
                            }
                        }
                        Method::SubGrid {
                            rule,
                            points_per_deg: ppd,
                        } => {
                            let n = rule.min_points();
                            sub_grid(view, brdf, trig, i, k, rule, ppd, &px_cap, n, &mut samples)
                        }
                        Method::Pointwise => {
                            samples += 1;
                            let (g, geo) = sample(view, trig.mid_dir(i, k));
                            // Eq. 38: the quadrangle's area on the unit sphere.
                            let area = (trig.lon[i + 1] - trig.lon[i]) * area_lat;
                            geo * brdf.eval(&g) * g.mu0.max(0.0) * g.mu.max(0.0) * area
                        }
                    }
                };
                *out = (k_const * f).max(0.0);
                sum += *out;
            }
            (sum, samples)
        })
        .collect();
    row_sums
        .iter()
        .fold((0.0, 0), |(t, n), &(s, m)| (t + s, n + m))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The generalised closed form reduces to Eq. 35 for the far-field directions.
    #[test]
    fn bilinear_moments_reduce_to_eq_35() {
        let alpha: f64 = 0.9;
        let (p0, p1, l0, l1) = (0.1f64, 0.35f64, -0.4f64, 0.2f64);
        let s = DVec3::X;
        let c = DVec3::new(alpha.cos(), alpha.sin(), 0.0);
        let ours = bilinear(s, c, &LonMoments::new(p0, p1), &LatMoments::new(l0, l1));
        // Eq. 35 with colatitude theta = pi/2 - lat; without the 1/pi of the BRDF.
        let g = |t: f64| (3.0 * t).cos() - 9.0 * t.cos();
        let m = |p: f64| (alpha - 2.0 * p).sin() - 2.0 * p * alpha.cos();
        let (t0, t1) = (
            std::f64::consts::FRAC_PI_2 - l1,
            std::f64::consts::FRAC_PI_2 - l0,
        );
        let eq35 = (g(t0) - g(t1)) * (m(p1) - m(p0)) / 48.0;
        assert!((ours / eq35 - 1.0).abs() < 1e-12, "{ours} vs {eq35}");
    }

    /// Moments against brute-force quadrature for arbitrary directions.
    #[test]
    fn moments_match_quadrature() {
        let (p0, p1, l0, l1) = (-0.3f64, 0.5f64, 0.1f64, 0.9f64);
        let a = DVec3::new(0.3, -0.5, 0.8).normalize();
        let b = DVec3::new(-0.2, 0.9, 0.1).normalize();
        let (x, w) = crate::radiometry::gauss_legendre(40);
        let (mut q2, mut q1) = (0.0, 0.0);
        for (xi, wi) in x.iter().zip(&w) {
            let lon = 0.5 * (p0 + p1) + 0.5 * (p1 - p0) * xi;
            for (xj, wj) in x.iter().zip(&w) {
                let lat = 0.5 * (l0 + l1) + 0.5 * (l1 - l0) * xj;
                let n = crate::geometry::unit_from_lon_lat(lon, lat);
                q2 += wi * wj * n.dot(a) * n.dot(b) * lat.cos();
                q1 += wi * wj * n.dot(a) * lat.cos();
            }
        }
        let s = 0.25 * (p1 - p0) * (l1 - l0);
        let (lo, la) = (LonMoments::new(p0, p1), LatMoments::new(l0, l1));
        assert!((bilinear(a, b, &lo, &la) - q2 * s).abs() < 1e-13);
        assert!((linear(a, &lo, &la) - q1 * s).abs() < 1e-13);
    }
}
