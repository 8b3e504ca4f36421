//! Colour screens for cameras of several bands (issue 17): each of the screen's primaries
//! (R, G, B) excites every camera band. With the primaries' F_eff `f_c` (each the column of the
//! calibration curve of that primary, at its code) the camera's band `b` gets
//!
//! ```text
//! F_b = sum_c X[b][c] f_c          (X: bands x 3, the cross-talk matrix)
//! ```
//!
//! which holds when the primaries add (no channel drives another) and keep their spectra
//! (chromaticity) at every code: a primary's spectrum scales with its drive, so its share in
//! each band does not change. `X[b][c]` is band `b`'s F_eff (Eq. 58 with that band's `k`,
//! Eq. 60) per unit of primary `c`'s column. `optistim calibrate` measures it (uniform frames
//! per primary, [`super::calibrate`]) and normalises each column to 1 in the band the primary
//! excites most, whose F_eff the curve's column then is.
//!
//! To show a rendered colour image, the stimulator solves per pixel for the primaries that
//! give every band its F_eff: `f = P F` with `P = (X^T X)^-1 X^T` (the inverse for three bands,
//! the least-squares solution for more), then inverts each primary's curve to its code. A
//! primary asked to go below its dark level (a colour outside the primaries' gamut, or a
//! band darker than the others' cross-talk allows) or above its maximum is clipped and the
//! pixel counted. The simulated camera sees the screen through `X` and its own bands' `k`.

use super::StimulatorError;
use super::calibration::Curve;
use crate::detector::Detector;

/// A colour screen has three primaries.
pub const PRIMARIES: usize = 3;

/// The cross-talk between a colour screen's primaries and a camera's bands, and its
/// (pseudo-)inverse.
#[derive(Clone, Debug, PartialEq)]
pub struct Crosstalk {
    /// `X[b][c]`: band `b`'s F_eff per unit of primary `c`'s F_eff, bands in the camera's
    /// order.
    pub x: Vec<[f64; PRIMARIES]>,
    /// `P[c][b]`: primary `c`'s F_eff per unit of band `b`'s (`(X^T X)^-1 X^T`).
    pub p: [Vec<f64>; PRIMARIES],
}

/// The smallest `det(X^T X) / prod(diag(X^T X))` accepted: below it the bands cannot tell the
/// primaries apart (two nearly equal columns) and the solve would amplify noise.
const MIN_CONDITION: f64 = 1e-6;

impl Crosstalk {
    /// From its rows, bands x 3 (refused when the bands cannot separate the primaries).
    pub fn new(x: Vec<[f64; PRIMARIES]>) -> Result<Crosstalk, String> {
        if x.len() < PRIMARIES {
            return Err(format!(
                "{} bands: a colour screen's three primaries need three bands or more",
                x.len()
            ));
        }
        // A = X^T X (3 x 3, symmetric).
        let mut a = [[0.0; PRIMARIES]; PRIMARIES];
        for row in &x {
            for i in 0..PRIMARIES {
                for j in 0..PRIMARIES {
                    a[i][j] += row[i] * row[j];
                }
            }
        }
        let inv = inverse3(&a)
            .filter(|_| det3(&a) > MIN_CONDITION * a[0][0] * a[1][1] * a[2][2])
            .ok_or_else(|| {
                format!(
                    "cross-talk matrix {x:?} is singular or nearly so: the bands cannot tell \
                     the primaries apart"
                )
            })?;
        let p = [0, 1, 2].map(|c| {
            x.iter()
                .map(|row| (0..PRIMARIES).map(|j| inv[c][j] * row[j]).sum())
                .collect()
        });
        Ok(Crosstalk { x, p })
    }

    /// What `curve` is to `detector`: `None` for a camera of one band, which a grey screen
    /// drives (a colour curve's first column); a camera of several bands needs a colour screen,
    /// and gets its cross-talk ([`Crosstalk::for_camera`]).
    pub fn of_screen(
        curve: &Curve,
        detector: &Detector,
    ) -> Result<Option<Crosstalk>, StimulatorError> {
        (detector.bands.len() > 1)
            .then(|| Crosstalk::for_camera(curve, detector))
            .transpose()
    }

    /// The matrix of a colour curve for `detector`'s bands, read by band name from the
    /// curve's `# crosstalk` lines.
    pub fn for_camera(curve: &Curve, detector: &Detector) -> Result<Crosstalk, StimulatorError> {
        let bad = |m: String| StimulatorError::Colour(format!("calibration {}: {m}", curve.id));
        if curve.channels() != PRIMARIES {
            return Err(bad(format!(
                "{} F_eff columns: a camera of {} bands needs a colour screen's three \
                 (feff_r_w_m2, feff_g_w_m2, feff_b_w_m2)",
                curve.channels(),
                detector.bands.len()
            )));
        }
        let rows = detector
            .bands
            .iter()
            .map(|band| {
                let row = curve
                    .crosstalk
                    .iter()
                    .find(|(name, _)| *name == band.name)
                    .ok_or_else(|| {
                        bad(format!(
                            "no \"# crosstalk {}: ...\" line for the camera's band {} \
                             (measure it with optistim calibrate)",
                            band.name, band.name
                        ))
                    })?;
                Ok([row.1[0], row.1[1], row.1[2]])
            })
            .collect::<Result<Vec<_>, StimulatorError>>()?;
        Crosstalk::new(rows).map_err(bad)
    }

    pub fn bands(&self) -> usize {
        self.x.len()
    }

    /// The primaries' F_eff that give band `b` the F_eff `band(b)` (least squares over more
    /// than three bands).
    #[inline]
    pub fn primaries(&self, band: impl Fn(usize) -> f64) -> [f64; PRIMARIES] {
        let mut f = [0.0; PRIMARIES];
        for b in 0..self.x.len() {
            let v = band(b);
            for (fc, pc) in f.iter_mut().zip(&self.p) {
                *fc += pc[b] * v;
            }
        }
        f
    }

    /// Band `b`'s F_eff from the primaries' `f`.
    #[inline]
    pub fn band(&self, b: usize, f: &[f64; PRIMARIES]) -> f64 {
        self.x[b].iter().zip(f).map(|(x, f)| x * f).sum()
    }
}

fn det3(a: &[[f64; 3]; 3]) -> f64 {
    a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
        - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
        + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
}

/// The inverse of a 3 x 3 matrix by cofactors; `None` when singular.
pub fn inverse3(a: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let d = det3(a);
    if d == 0.0 || !d.is_finite() {
        return None;
    }
    let c = |i: usize, j: usize| {
        let (r0, r1) = ((i + 1) % 3, (i + 2) % 3);
        let (c0, c1) = ((j + 1) % 3, (j + 2) % 3);
        a[r0][c0] * a[r1][c1] - a[r0][c1] * a[r1][c0]
    };
    // inv[i][j] = cofactor(j, i) / det (the cyclic indices carry the signs).
    Some([0, 1, 2].map(|i| [0, 1, 2].map(|j| c(j, i) / d)))
}

#[cfg(test)]
mod tests {
    use super::*;

    const X: [[f64; 3]; 3] = [[1.0, 0.09, 0.02], [0.12, 1.0, 0.18], [0.01, 0.08, 1.0]];

    #[test]
    fn three_bands_solve_exactly() {
        let ct = Crosstalk::new(X.to_vec()).unwrap();
        let f = [3e-6, 5e-6, 1e-6];
        let bands: Vec<f64> = (0..3).map(|b| ct.band(b, &f)).collect();
        let back = ct.primaries(|b| bands[b]);
        for c in 0..3 {
            assert!((back[c] / f[c] - 1.0).abs() < 1e-12, "{back:?}");
        }
    }

    /// Four bands (a fourth, NIR-like band seeing all primaries a little): consistent data is
    /// solved exactly, and the solution is the least-squares one.
    #[test]
    fn more_bands_solve_in_the_least_squares_sense() {
        let mut x = X.to_vec();
        x.push([0.3, 0.2, 0.1]);
        let ct = Crosstalk::new(x).unwrap();
        let f = [2e-6, 4e-6, 6e-6];
        let bands: Vec<f64> = (0..4).map(|b| ct.band(b, &f)).collect();
        let back = ct.primaries(|b| bands[b]);
        for c in 0..3 {
            assert!((back[c] / f[c] - 1.0).abs() < 1e-12, "{back:?}");
        }
        // Perturbed data: the residual is orthogonal to every column of X.
        let noisy: Vec<f64> = bands
            .iter()
            .zip([1.0, -0.5, 0.7, 2.0])
            .map(|(v, e)| v + e * 1e-7)
            .collect();
        let sol = ct.primaries(|b| noisy[b]);
        for c in 0..3 {
            let dot: f64 = (0..4)
                .map(|b| ct.x[b][c] * (noisy[b] - ct.band(b, &sol)))
                .sum();
            assert!(dot.abs() < 1e-18, "{dot}");
        }
    }

    #[test]
    fn bands_that_cannot_separate_the_primaries_are_refused() {
        assert!(Crosstalk::new(X[..2].to_vec()).is_err());
        let same = vec![[1.0, 1.0, 0.1], [0.5, 0.5, 0.1], [0.1, 0.1, 1.0]];
        let e = Crosstalk::new(same).unwrap_err();
        assert!(e.contains("singular"), "{e}");
    }
}
