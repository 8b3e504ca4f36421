//! The camera's geometry: pinhole intrinsics `K` (Eq. 40) with Brown distortion (Eq. 39), and
//! its aperture. The detector (QE, noise, ADC) lives in [`crate::detector`].
//!
//! Pixel coordinates: `(0, 0)` is the top-left corner of the top-left pixel, `u` grows right,
//! `v` grows down, pixel `(i, j)` covers `[i, i+1) x [j, j+1)` and has its centre at
//! `(i + 0.5, j + 0.5)`.

/// Brown-Conrady distortion coefficients (Eq. 39).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Brown {
    pub k1: f64,
    pub k2: f64,
    pub k3: f64,
    pub p1: f64,
    pub p2: f64,
}

impl Brown {
    pub fn is_identity(&self) -> bool {
        *self == Brown::default()
    }

    /// Distorted normalised coordinates `(x', y')` of undistorted `(x, y)` (Eq. 39).
    #[inline(always)]
    pub fn apply(&self, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        (
            radial * x + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
            radial * y + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y,
        )
    }

    /// The determinant of the Jacobian of [`Brown::apply`] at undistorted `(x, y)`: how much
    /// a small area of the undistorted image plane grows on the distorted one (1 without
    /// distortion). The ray caster divides by it to turn pixel area into solid angle.
    #[inline]
    pub fn jacobian_det(&self, x: f64, y: f64) -> f64 {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let d_radial = self.k1 + r2 * (2.0 * self.k2 + 3.0 * r2 * self.k3);
        let xx = radial + 2.0 * x * x * d_radial + 2.0 * self.p1 * y + 6.0 * self.p2 * x;
        let cross = 2.0 * x * y * d_radial + 2.0 * self.p1 * x + 2.0 * self.p2 * y;
        let yy = radial + 2.0 * y * y * d_radial + 6.0 * self.p1 * y + 2.0 * self.p2 * x;
        xx * yy - cross * cross
    }

    /// Inverts [`Brown::apply`] by fixed-point iteration (converges for the moderate
    /// distortions of real lenses; 1e-14 relative or 50 steps).
    pub fn invert(&self, xd: f64, yd: f64) -> (f64, f64) {
        if self.is_identity() {
            return (xd, yd);
        }
        let (mut x, mut y) = (xd, yd);
        for _ in 0..50 {
            let (fx, fy) = self.apply(x, y);
            let (ex, ey) = (fx - xd, fy - yd);
            x -= ex;
            y -= ey;
            if ex.abs() + ey.abs() < 1e-14 * (1.0 + xd.abs() + yd.abs()) {
                break;
            }
        }
        (x, y)
    }
}

/// Pinhole camera with distortion.
#[derive(Clone, Debug, PartialEq)]
pub struct Intrinsics {
    pub width_px: u32,
    pub height_px: u32,
    /// Pixel pitch along u and v [m].
    pub pixel_pitch_m: [f64; 2],
    pub focal_length_m: f64,
    pub f_number: f64,
    /// Principal point `(c_u, c_v)` [px].
    pub principal_point_px: [f64; 2],
    /// Skew term `s` of K (Eq. 40) [px].
    pub skew_px: f64,
    pub distortion: Brown,
}

impl Intrinsics {
    /// `f / mu_u` and `f / mu_v` [px].
    pub fn focal_px(&self) -> (f64, f64) {
        (
            self.focal_length_m / self.pixel_pitch_m[0],
            self.focal_length_m / self.pixel_pitch_m[1],
        )
    }

    /// Entrance pupil area `A_cam = pi (f / N)^2 / 4` [m^2].
    pub fn aperture_area_m2(&self) -> f64 {
        let d = self.focal_length_m / self.f_number;
        std::f64::consts::PI * d * d / 4.0
    }

    /// Pixel coordinates of a camera-frame point (`z > 0`), distortion applied (Eqs. 39-40).
    #[inline(always)]
    pub fn project(&self, x: f64, y: f64, z: f64) -> [f64; 2] {
        let (xd, yd) = self.distortion.apply(x / z, y / z);
        let (fu, fv) = self.focal_px();
        [
            fu * xd + self.skew_px * yd + self.principal_point_px[0],
            fv * yd + self.principal_point_px[1],
        ]
    }

    /// Undistorted normalised coordinates `(x, y)` (ray `(x, y, 1)`) of a pixel position.
    pub fn unproject(&self, u: f64, v: f64) -> (f64, f64) {
        let (fu, fv) = self.focal_px();
        let yd = (v - self.principal_point_px[1]) / fv;
        let xd = (u - self.principal_point_px[0] - self.skew_px * yd) / fu;
        self.distortion.invert(xd, yd)
    }

    /// Half-angle of the cone that circumscribes the image (to its farthest corner) [rad].
    pub fn circumscribed_half_angle(&self) -> f64 {
        let (w, h) = (self.width_px as f64, self.height_px as f64);
        [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h)]
            .iter()
            .map(|&(u, v)| {
                let (x, y) = self.unproject(u, v);
                (x * x + y * y).sqrt().atan()
            })
            .fold(0.0, f64::max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn brown_jacobian_matches_finite_differences() {
        let b = Brown {
            k1: -0.21,
            k2: 0.05,
            k3: -0.01,
            p1: 1e-3,
            p2: -2e-3,
        };
        for &(x, y) in &[(0.0, 0.0), (0.3, -0.2), (-0.5, 0.4), (0.7, 0.7)] {
            let h = 1e-6;
            let (ax, ay) = b.apply(x + h, y);
            let (bx, by) = b.apply(x - h, y);
            let (cx, cy) = b.apply(x, y + h);
            let (dx, dy) = b.apply(x, y - h);
            let fd = ((ax - bx) * (cy - dy) - (cx - dx) * (ay - by)) / (4.0 * h * h);
            assert!((fd / b.jacobian_det(x, y) - 1.0).abs() < 1e-8, "{x} {y}");
        }
        assert_eq!(Brown::default().jacobian_det(0.3, 0.4), 1.0);
    }

    #[test]
    fn brown_inverts() {
        let b = Brown {
            k1: -0.2,
            k2: 0.05,
            k3: 0.0,
            p1: 1e-3,
            p2: -2e-3,
        };
        for (x, y) in [(0.1, 0.2), (-0.3, 0.05), (0.0, 0.0), (0.4, -0.4)] {
            let (xd, yd) = b.apply(x, y);
            let (xi, yi) = b.invert(xd, yd);
            assert!((xi - x).abs() < 1e-12 && (yi - y).abs() < 1e-12);
        }
    }
}
