//! A triaxial ellipsoid `x^2/a^2 + y^2/b^2 + z^2/c^2 = 1` in the body frame (semi-axes along
//! +X, +Y, +Z). Along the direction `d` from its centre the surface point is `r(d) d` with
//! `r(d) = 1 / sqrt(dx^2/a^2 + dy^2/b^2 + dz^2/c^2)` and the outward normal
//! `normalize(x/a^2, y/b^2, z/c^2)`: what the camera's keep-out distance and DEM heights above
//! the ellipsoid are measured with. The renderer lays an undisplaced ellipsoid out in its
//! parameter space instead, `x = A u` with `u` on the unit sphere (`render::view::Grid`).

use glam::DVec3;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ellipsoid {
    /// Semi-axes along body +X, +Y, +Z [m].
    pub semi_axes_m: DVec3,
}

impl Ellipsoid {
    /// `1 / (a^2, b^2, c^2)`.
    #[inline(always)]
    fn inv_sq(&self) -> DVec3 {
        DVec3::ONE / (self.semi_axes_m * self.semi_axes_m)
    }

    /// Surface point [m] and outward unit normal over the unit direction `dir` (body frame).
    #[inline]
    pub fn surface(&self, dir: DVec3) -> (DVec3, DVec3) {
        let q = self.inv_sq();
        let r = 1.0 / (dir * dir).dot(q).sqrt();
        let p = dir * r;
        (p, (p * q).normalize())
    }

    pub fn max_axis_m(&self) -> f64 {
        self.semi_axes_m.max_element()
    }

    pub fn min_axis_m(&self) -> f64 {
        self.semi_axes_m.min_element()
    }

    /// First intersection `t > 0` of the ray `origin + t dir` (`dir` unit): the ray is scaled
    /// onto the unit sphere.
    pub fn intersect(&self, origin: DVec3, dir: DVec3) -> Option<f64> {
        let inv = DVec3::ONE / self.semi_axes_m;
        let (o, d) = (origin * inv, dir * inv);
        let a = d.length_squared();
        let b = o.dot(d);
        let c = o.length_squared() - 1.0;
        let disc = b * b - a * c;
        if disc < 0.0 {
            return None;
        }
        let s = disc.sqrt();
        [(-b - s) / a, (-b + s) / a].into_iter().find(|&t| t > 0.0)
    }

    pub fn contains(&self, p: DVec3) -> bool {
        (p * p).dot(self.inv_sq()) < 1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn surface_points_lie_on_it_with_gradient_normals() {
        let e = Ellipsoid {
            semi_axes_m: DVec3::new(3.0, 2.0, 1.0),
        };
        for d in [
            DVec3::X,
            DVec3::Y,
            DVec3::Z,
            DVec3::new(1.0, -2.0, 0.5).normalize(),
        ] {
            let (p, n) = e.surface(d);
            let f = (p * p).dot(e.inv_sq());
            assert!((f - 1.0).abs() < 1e-12, "{f}");
            assert!((n.length() - 1.0).abs() < 1e-12 && n.dot(d) > 0.0);
            // A ray from outside towards the centre meets the same point.
            let o = d * 10.0;
            let t = e.intersect(o, -d).unwrap();
            assert!(((o - d * t) - p).length() < 1e-9);
        }
        assert_eq!(e.surface(DVec3::X).0, DVec3::new(3.0, 0.0, 0.0));
        assert!(e.contains(DVec3::new(2.9, 0.0, 0.0)) && !e.contains(DVec3::new(0.0, 2.1, 0.0)));
        assert!(e.intersect(DVec3::new(0.0, 0.0, 5.0), DVec3::X).is_none());
    }
}
