//! A mesh facet's light over the image, interpolated: what the sampled frame
//! ([`super::sampled`]) reads instead of evaluating the BRDF at every sample of a large facet.
//!
//! A flat facet lit by a distant Sun sends back light that varies smoothly across its image:
//! its normal is one, the Sun's direction turns by `R / d_sun` over the body, and only the line
//! of sight (hence `mu`, the phase angle, `cos^4(eps)` and the range) changes from one end to
//! the other, over the facet's angular size (0.01 rad for Bennu's facets from 1 km). Per
//! facet of the frame whose image is at least [`MIN_AREA_PX2`], the unshadowed light
//! ([`super::Tracer::facet_light`]: direct and scattered, `(P/L)` per px^2) is evaluated at
//! six nodes, the projected corners and the midpoints of the projected edges, and read
//! anywhere on the facet through the quadratic Lagrange element on those nodes (barycentric
//! `l_k`: `l_k (2 l_k - 1)` at corner `k`, `4 l_i l_j` at the midpoint of edge `ij`).
//!
//! The quadratic is kept only where it reproduces the light at two more points of the facet
//! (its centroid and the point of barycentric coordinates `(1/2, 1/4, 1/4)`) within
//! [`TOLERANCE`] of the facet's brightest node: its error is of the third order of the light's
//! variation over the facet, while a facet that holds the opposition surge's cusp or the Sun
//! grazing its plane is not smooth and keeps exact evaluation (a body with an albedo map is
//! never interpolated: its texels are not smooth). Measured on `config/bennu.toml` against the
//! exact evaluation (`tests/mesh.rs`): at 41 deg of phase 99 % of the lit pixels are
//! interpolated (some of the smaller facets linearly, below), the worst of them 5.0e-6 off,
//! the total 5.8e-11; at zero phase 36 %, 8.4e-6 and 2.8e-9. Shadows are not interpolated:
//! where a facet is not lit all over ([`super::sun_grid`]) every sample still casts its
//! shadow ray, and the interpolated light is what a lit sample gets. The depth is cast as
//! before, bit for bit.
//!
//! A facet whose image is smaller, down to [`MIN_LINEAR_AREA_PX2`], is read from a linear
//! element on its three corners (its midpoints' values the means of their corners', so
//! [`Element::at`] serves both), checked at the centroid within [`LINEAR_TOLERANCE`], with a
//! bubble `45 d l_0 l_1 l_2` added (`d` the centroid's light less the plane's): the plane
//! alone over-reads a curved light's mean over the facet by `3/4 d` to the second order, which
//! the bubble takes back. A facet of 2 px^2 covers about 7 pixels, each a fragment cast once
//! ([`super::sampled`]); its element costs 4 evaluations. On the 200,000-facet body of
//! `python/benches/bumpy_200k.toml` (facets 0.4-5.8 px^2, median 2.3) 60,205 of 79,102
//! projected facets are read from elements, the frame is 1.26 times faster (interleaved,
//! 226 -> 179 ms), and against the exact evaluation the lit pixels move by 9.4e-7 at the
//! median, 1.5e-5 at worst, the total by 6.7e-7 (without the bubble: 4.5e-6, 1.8e-5, -4.6e-6).
//!
//! On `config/bennu.toml` this takes the BRDF out of the frame's profile (12 % of it, and the
//! `exp` and `log` it calls 7 %): its 12,288 facets' 4,400 elements cost 42 million
//! instructions a frame where the samples' BRDF evaluations had cost 240 million (callgrind).

use super::Tracer;
use super::raster::Rasteriser;
use rayon::prelude::*;

/// The smallest image of a facet [px^2] whose light is interpolated by a quadratic: below,
/// its eight evaluations cost more than the samples they save, and the linear element serves.
pub const MIN_AREA_PX2: f64 = 8.0;

/// The smallest image of a facet [px^2] whose light is interpolated linearly (below
/// [`MIN_AREA_PX2`]): below, it covers about 4 pixels or fewer, and its element's 4
/// evaluations save nothing (measured on the 200,000-facet body: 0.5 and 2 px^2 are slower).
pub const MIN_LINEAR_AREA_PX2: f64 = 1.0;

/// The largest difference, at the check points, between the quadratic and the light, as a
/// fraction of the facet's brightest node, for the quadratic to be used.
pub const TOLERANCE: f64 = 1e-6;

/// [`TOLERANCE`] for the linear element, at the facet's centroid.
pub const LINEAR_TOLERANCE: f64 = 1e-5;

/// The bubble's coefficient per unit of the centroid's light less the plane's
/// ([`Element::bubble`]).
const BUBBLE: f64 = 45.0;

/// The barycentric coordinates of the points where the quadratic is checked against the
/// light: the centroid, and a point between it and a corner. (Two more such points, toward
/// the other corners, lowered the worst pixel's error on Bennu by a tenth only.)
const CHECKS: [[f64; 3]; 2] = [[1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0], [0.5, 0.25, 0.25]];

/// One facet's light as a quadratic element over its image.
#[derive(Clone, Copy, Debug)]
struct Element {
    /// The projected edges' equations (as [`Rasteriser`]'s: `A u + B v + C`, the doubled area
    /// of the triangle the edge makes with the point, positive inside) and the reciprocal of
    /// their sum: the barycentric coordinates.
    edges: [[f64; 3]; 3],
    inv_area: f64,
    /// Node values, corners 0, 1, 2 then the midpoints of the edges opposite corners 0, 1, 2,
    /// for the direct and the scattered light, `(P/L)` per px^2.
    direct: [f64; 6],
    scattered: [f64; 6],
    /// A linear element's bubble `l_0 l_1 l_2` coefficients, direct and scattered (0 on a
    /// quadratic one): what makes its mean over the facet the light's, to the second order.
    bubble: [f64; 2],
}

impl Element {
    #[inline]
    fn at(&self, u: f64, v: f64) -> (f64, f64) {
        let l = self
            .edges
            .map(|e| (e[0] * u + e[1] * v + e[2]) * self.inv_area);
        let w = [
            l[0] * (2.0 * l[0] - 1.0),
            l[1] * (2.0 * l[1] - 1.0),
            l[2] * (2.0 * l[2] - 1.0),
            4.0 * l[1] * l[2],
            4.0 * l[2] * l[0],
            4.0 * l[0] * l[1],
        ];
        let dot = |f: &[f64; 6]| w.iter().zip(f).map(|(a, b)| a * b).sum::<f64>();
        let bubble = l[0] * l[1] * l[2];
        (
            dot(&self.direct) + self.bubble[0] * bubble,
            dot(&self.scattered) + self.bubble[1] * bubble,
        )
    }
}

/// The interpolated light of a frame's large facets.
pub struct FacetLights {
    /// Per mesh facet, its element's index in `elements`, or `u32::MAX`.
    slot: Vec<u32>,
    elements: Vec<Element>,
}

impl FacetLights {
    /// The elements of the facets `rasteriser` projected whose images are at least
    /// [`MIN_AREA_PX2`] and whose light the quadratic reproduces; `facets` the mesh's count.
    /// `None` where the body carries an albedo map (its texels are not smooth).
    pub fn new(tracer: &Tracer, rasteriser: &Rasteriser, facets: usize) -> Option<FacetLights> {
        if tracer.scene.body.albedo_map.is_some() {
            return None;
        }
        let made: Vec<(u32, Element)> = (0..rasteriser.len())
            .into_par_iter()
            .filter_map(|k| {
                let (facet, corners, edges) = rasteriser.triangle(k);
                let doubled: f64 = {
                    let c = corners[0];
                    edges.iter().map(|e| e[0] * c.x + e[1] * c.y + e[2]).sum()
                };
                if 0.5 * doubled < MIN_LINEAR_AREA_PX2 || doubled.is_nan() {
                    return None;
                }
                let quadratic = 0.5 * doubled >= MIN_AREA_PX2;
                let mid = |i: usize, j: usize| 0.5 * (corners[i] + corners[j]);
                let nodes = [
                    corners[0],
                    corners[1],
                    corners[2],
                    mid(1, 2),
                    mid(2, 0),
                    mid(0, 1),
                ];
                let mut direct = [0.0; 6];
                let mut scattered = [0.0; 6];
                for (k, q) in nodes.iter().enumerate().take(if quadratic { 6 } else { 3 }) {
                    (direct[k], scattered[k]) = tracer.facet_light(q.x, q.y, facet)?;
                }
                if !quadratic {
                    // The linear element, as a quadratic one: its midpoints the means of
                    // their edge's corners.
                    for (k, (i, j)) in [(1, 2), (2, 0), (0, 1)].into_iter().enumerate() {
                        direct[3 + k] = 0.5 * (direct[i] + direct[j]);
                        scattered[3 + k] = 0.5 * (scattered[i] + scattered[j]);
                    }
                }
                // The Sun grazing the plane: lit at some nodes and not at others.
                let lit = direct.iter().filter(|&&d| d > 0.0).count();
                if lit != 0 && lit != 6 {
                    return None;
                }
                let mut e = Element {
                    edges,
                    inv_area: 1.0 / doubled,
                    direct,
                    scattered,
                    bubble: [0.0; 2],
                };
                let scale = direct
                    .iter()
                    .chain(&scattered)
                    .fold(0.0f64, |m, &x| m.max(x.abs()));
                let (checks, tolerance) = if quadratic {
                    (&CHECKS[..], TOLERANCE)
                } else {
                    (&CHECKS[..1], LINEAR_TOLERANCE)
                };
                for l in checks {
                    let q = l[0] * corners[0] + l[1] * corners[1] + l[2] * corners[2];
                    let (d, s) = tracer.facet_light(q.x, q.y, facet)?;
                    let (di, si) = e.at(q.x, q.y);
                    if (d - di).abs() > tolerance * scale || (s - si).abs() > tolerance * scale {
                        return None;
                    }
                    if !quadratic {
                        // The centroid's light less the plane's, `d`: `45 d l_0 l_1 l_2` has
                        // the mean `3 d / 4` over the facet, the plane's excess over the
                        // light's mean where the light is quadratic.
                        e.bubble = [BUBBLE * (d - di), BUBBLE * (s - si)];
                    }
                }
                Some((facet, e))
            })
            .collect();
        let mut slot = vec![u32::MAX; facets];
        let mut elements = Vec::with_capacity(made.len());
        for (facet, e) in made {
            slot[facet as usize] = elements.len() as u32;
            elements.push(e);
        }
        Some(FacetLights { slot, elements })
    }

    /// The interpolated unshadowed light `(direct, scattered)` of mesh facet `facet` at image
    /// position `(u, v)`, `(P/L)` per px^2; `None` where it is evaluated exactly.
    #[inline]
    pub fn at(&self, facet: u32, u: f64, v: f64) -> Option<(f64, f64)> {
        let k = *self.slot.get(facet as usize)?;
        (k != u32::MAX).then(|| self.elements[k as usize].at(u, v))
    }
}
