//! Direct gridding of the point cloud into the pixel array (Sec. 4.8, Eqs. 41-44), one file
//! per kernel. Every kernel distributes a point's value with weights that sum to one over the
//! pixels it touches, so gridding conserves energy; only what falls outside the frame is lost.
//!
//! Accumulation is in 64-bit fixed point ([`Accum`]): integer addition is associative, so the
//! image is bit-identical whatever the number of threads or the order of the points.

mod area;
mod gaussian;
mod nearest;
mod polygon;

pub use polygon::{Slope, centroid_area};

use serde::Serialize;

#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case", tag = "kernel")]
pub enum Gridding {
    /// Whole value to the pixel that contains the point.
    Nearest,
    /// Eq. 41: a one-pixel square centred on the point, split over up to 4 pixels by area.
    Area,
    /// Eqs. 42-43: a Gaussian of `sigma_px` sampled at the centres of a `window_px` x
    /// `window_px` window around the point's pixel, normalised to sum to one.
    Gaussian { window_px: u32, sigma_px: f64 },
    /// Exact footprint: the quadrangle's projected corners form a polygon that is clipped
    /// against the pixel grid, and each pixel gets the fraction of the polygon's area it
    /// covers. Neighbouring quadrangles share corners, so their polygons tile the image with
    /// no gap or overlap: no aliasing at any density.
    Polygon,
    /// [`Gridding::Polygon`] with a linear density over each footprint: the density gradient
    /// is fitted (least squares) to the neighbouring quadrangles' densities and limited so the
    /// density stays non-negative over the footprint. Second-order accurate, still exactly
    /// energy-conserving.
    PolygonLinear,
}

impl Gridding {
    /// How far beyond a point's pixel (or its quadrangle's corners) the kernel reaches [px].
    pub fn reach_px(&self) -> i64 {
        match self {
            Gridding::Nearest | Gridding::Polygon | Gridding::PolygonLinear => 1,
            Gridding::Area => 2,
            Gridding::Gaussian { window_px, .. } => (*window_px as i64) / 2 + 1,
        }
    }

    /// Whether the kernel uses the quadrangle corners.
    pub fn needs_corners(&self) -> bool {
        matches!(self, Gridding::Polygon | Gridding::PolygonLinear)
    }

    /// Grids one quadrangle: `corners` in order around the quadrangle (NaN when a corner could
    /// not be projected), `mid` its projected midpoint, `value` its (P/L).
    #[inline]
    pub fn splat(
        &self,
        corners: &[[f64; 2]; 4],
        mid: [f64; 2],
        value: f64,
        slope: Option<&Slope>,
        acc: &mut Accum,
    ) {
        match self {
            Gridding::Nearest => nearest::splat(mid, value, acc),
            Gridding::Area => area::splat(mid, value, acc),
            Gridding::Gaussian {
                window_px,
                sigma_px,
            } => gaussian::splat(mid, value, *window_px, *sigma_px, acc),
            Gridding::Polygon | Gridding::PolygonLinear => {
                if !polygon::splat_linear(corners, value, slope, acc) {
                    area::splat(mid, value, acc);
                }
            }
        }
    }
}

pub(crate) use crate::geometry::floor_i64;

/// A fixed-point accumulation window `[x0, x0 + w) x [y0, y0 + h)` of a grid of
/// `grid_w x grid_h` pixels; contributions outside the grid are dropped.
pub struct Accum<'a> {
    pub data: &'a mut [i64],
    /// The kernels' work space, reused footprint after footprint.
    pub scratch: &'a mut Scratch,
    pub x0: i64,
    pub y0: i64,
    pub w: i64,
    pub h: i64,
    /// Fixed-point units per unit of value.
    pub scale: f64,
}

/// A gridding band's work space for the kernels that need one, reused footprint after
/// footprint (one per band, so one per thread at a time).
#[derive(Default)]
pub struct Scratch {
    /// The polygon's edge sums (reused, never shrunk): all zero when handed over, and left so
    /// by the edge sums.
    cells: Vec<f64>,
    /// The polygon's peeling buffers (boxed: taken out and put back for each footprint).
    peel: Option<Box<polygon::Peelers>>,
}

/// `value` (non-negative) in fixed point of `scale` units per unit: `+ 0.5` then truncation
/// rounds half up (libm's `round` is not inlined and showed in profiles).
#[inline(always)]
fn to_fixed(value: f64, scale: f64) -> i64 {
    (value * scale + 0.5) as i64
}

impl Accum<'_> {
    #[inline(always)]
    pub fn add(&mut self, x: i64, y: i64, value: f64) {
        let (dx, dy) = (x - self.x0, y - self.y0);
        if dx >= 0 && dy >= 0 && dx < self.w && dy < self.h {
            self.data[(dy * self.w + dx) as usize] += to_fixed(value, self.scale);
        }
    }

    /// Row `y` of the window (`None` outside it), for kernels that fill runs of a row: its
    /// column `x` is `x - x0`.
    #[inline(always)]
    pub fn row(&mut self, y: i64) -> Option<&mut [i64]> {
        let dy = y - self.y0;
        (dy >= 0 && dy < self.h).then(|| {
            let w = self.w as usize;
            &mut self.data[dy as usize * w..][..w]
        })
    }
}
