//! Frames, rotations and spherical coordinates.
//!
//! Frames (see `docs/conventions.md`, written once there):
//! - **B**, body-fixed: origin at the body centre, +Z north pole, +X prime meridian.
//! - **C**, camera: origin at the camera, +Z boresight, +X image right (u), +Y image down (v).
//! - **CSF**, camera-Sun frame (paper Sec. 4.1): origin at the body centre, +X towards the Sun,
//!   +Z normal to the Sun-camera plane, +Y completes the triad, so the camera lies in the XY
//!   plane at longitude `alpha` (the phase angle), `0 <= alpha <= pi`.
//!
//! Rotations are named `a_from_b`: `v_a = a_from_b * v_b`. All lengths in metres, angles in
//! radians.

pub mod bvh;

use glam::{DMat3, DQuat, DVec3};

/// Builds the body-from-camera rotation from a scalar-first Hamilton quaternion
/// `(w, x, y, z)` that rotates camera-frame vectors into the body frame
/// (`v_body = q v_cam q*`), the convention of the pose streams.
pub fn body_from_camera_wxyz(q: [f64; 4]) -> DQuat {
    DQuat::from_xyzw(q[1], q[2], q[3], q[0])
}

/// Returns `(w, x, y, z)` of a rotation, scalar first, with `w >= 0`.
pub fn wxyz(q: DQuat) -> [f64; 4] {
    let q = if q.w < 0.0 { -q } else { q };
    [q.w, q.x, q.y, q.z]
}

/// Attitude that points the boresight (camera +Z) from `camera_m` at `target_m`, with image
/// down (camera +Y) along the projection of `down_hint` on the image plane. Falls back to body
/// -X when `down_hint` is parallel to the boresight. Returns `body_from_camera`.
pub fn look_at(camera_m: DVec3, target_m: DVec3, down_hint: DVec3) -> DQuat {
    let z = (target_m - camera_m).normalize();
    let mut y = down_hint - z * z.dot(down_hint);
    if y.length() < 1e-9 {
        let alt = DVec3::NEG_X;
        y = alt - z * z.dot(alt);
    }
    let y = y.normalize();
    let x = y.cross(z);
    DQuat::from_mat3(&DMat3::from_cols(x, y, z)).normalize()
}

/// Unit vector of longitude `lon` and latitude `lat` (rad).
#[inline(always)]
pub fn unit_from_lon_lat(lon: f64, lat: f64) -> DVec3 {
    let (sl, cl) = lat.sin_cos();
    let (so, co) = lon.sin_cos();
    DVec3::new(cl * co, cl * so, sl)
}

/// The local east and north unit vectors at the unit direction `up` (the paper's frame O);
/// at a pole, east is +Y.
#[inline]
pub fn east_north(up: DVec3) -> (DVec3, DVec3) {
    let e = DVec3::Z.cross(up);
    let east = if e.length_squared() > 1e-24 {
        e.normalize()
    } else {
        DVec3::Y
    };
    (east, up.cross(east))
}

/// `(lon, lat)` of a non-zero vector, lon in (-pi, pi].
#[inline]
pub fn lon_lat(v: DVec3) -> (f64, f64) {
    let r = v.length();
    (v.y.atan2(v.x), (v.z / r).clamp(-1.0, 1.0).asin())
}

/// [`lon_lat`] of a unit vector, without normalising it (one square root and division
/// fewer on the renderer's hottest path).
#[inline(always)]
pub fn lon_lat_unit(v: DVec3) -> (f64, f64) {
    (v.y.atan2(v.x), v.z.clamp(-1.0, 1.0).asin())
}

/// `atan2(y, x)` as Cephes computes it (Moshier's `atan`: the argument reduced to
/// `[0, 0.66]` by `pi/4` or `pi/2`, then a rational function of degree 4 over 5; relative
/// error 1.8e-16 peak), about twice as fast here as the system's `atan2` with which it
/// agrees to a few units in the last place (`tests::the_fast_arctangent_agrees_with_libm`).
/// For the marcher's lookups, where a point's position matters to a micrometre.
#[inline]
pub fn atan2_fast(y: f64, x: f64) -> f64 {
    use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};
    const T3P8: f64 = 2.414_213_562_373_095; // tan(3 pi / 8)
    const MOREBITS: f64 = 6.123_233_995_736_766e-17;
    const P: [f64; 5] = [
        -8.750_608_600_031_904e-1,
        -1.615_753_718_733_365e1,
        -7.500_855_792_314_705e1,
        -1.228_866_684_490_136e2,
        -6.485_021_904_942_025e1,
    ];
    const Q: [f64; 5] = [
        2.485_846_490_142_306e1,
        1.650_270_098_316_988e2,
        4.328_810_604_912_903e2,
        4.853_903_996_359_137e2,
        1.945_506_571_482_614e2,
    ];
    if x == 0.0 && y == 0.0 || x.is_nan() || y.is_nan() || x.is_infinite() || y.is_infinite() {
        return y.atan2(x);
    }
    let t = (y / x).abs();
    let (base, u, more) = if t > T3P8 {
        (FRAC_PI_2, -1.0 / t, MOREBITS)
    } else if t <= 0.66 {
        (0.0, t, 0.0)
    } else {
        (FRAC_PI_4, (t - 1.0) / (t + 1.0), 0.5 * MOREBITS)
    };
    let z = u * u;
    let p = (((P[0] * z + P[1]) * z + P[2]) * z + P[3]) * z + P[4];
    let q = ((((z + Q[0]) * z + Q[1]) * z + Q[2]) * z + Q[3]) * z + Q[4];
    let a = base + (u * (z * p / q) + u + more);
    // `a` is the angle in [0, pi/2] of (|x|, |y|).
    let a = if x < 0.0 { PI - a } else { a };
    if y < 0.0 { -a } else { a }
}

/// [`lon_lat`] of a vector by [`atan2_fast`], lon in (-pi, pi].
#[inline]
pub fn lon_lat_fast(v: DVec3) -> (f64, f64) {
    let xy = (v.x * v.x + v.y * v.y).sqrt();
    (atan2_fast(v.y, v.x), atan2_fast(v.z, xy))
}

/// `x.floor() as i64` for finite `x` of magnitude below 2^53, without a libm call (`floor` is
/// not inlined on baseline x86-64 and showed in profiles).
#[inline(always)]
pub fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    t - ((t as f64) > x) as i64
}

/// Wraps an angle to (-pi, pi].
#[inline]
pub fn wrap_pi(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    let mut x = (a + std::f64::consts::PI).rem_euclid(t) - std::f64::consts::PI;
    if x <= -std::f64::consts::PI {
        x += t;
    }
    x
}

/// Distance along a ray `origin + t dir` (`dir` unit) to its first intersection with a sphere
/// of `radius` centred at the origin, if any with `t > 0`.
#[inline]
pub fn ray_sphere(origin: DVec3, dir: DVec3, radius: f64) -> Option<f64> {
    let b = origin.dot(dir);
    let c = origin.length_squared() - radius * radius;
    let disc = b * b - c;
    if disc < 0.0 {
        return None;
    }
    let sq = disc.sqrt();
    // Numerically stable roots.
    let q = if b > 0.0 { -b - sq } else { -b + sq };
    let (t0, t1) = if q == 0.0 { (0.0, 0.0) } else { (c / q, q) };
    let (near, far) = if t0 < t1 { (t0, t1) } else { (t1, t0) };
    if near > 0.0 {
        Some(near)
    } else if far > 0.0 {
        Some(far)
    } else {
        None
    }
}

/// The camera-Sun frame of one pose (paper Sec. 4.1, Fig. 4).
#[derive(Clone, Copy, Debug)]
pub struct CsfFrame {
    /// Columns are the CSF axes expressed in the body frame.
    pub body_from_csf: DMat3,
    /// Phase angle Sun-body-camera at the body centre [rad], in `[0, pi]`.
    pub phase_rad: f64,
}

impl CsfFrame {
    /// Builds CSF from the Sun and camera positions relative to the body centre (body frame).
    /// At zero or 180 deg phase the Sun-camera plane is undefined; +Z is then taken normal to
    /// the Sun direction and to `fallback_up` (the camera's image-up axis), so the choice is
    /// stable along a trajectory.
    pub fn new(sun_m: DVec3, camera_m: DVec3, fallback_up: DVec3) -> Self {
        let x = sun_m.normalize();
        let c = camera_m.normalize();
        let mut z = x.cross(c);
        if z.length() < 1e-12 {
            z = x.cross(fallback_up);
            if z.length() < 1e-12 {
                z = x.any_orthonormal_vector();
            }
        }
        let z = z.normalize();
        let y = z.cross(x);
        let phase_rad = c.dot(y).atan2(c.dot(x)).abs();
        CsfFrame {
            body_from_csf: DMat3::from_cols(x, y, z),
            phase_rad,
        }
    }

    pub fn csf_from_body(&self) -> DMat3 {
        self.body_from_csf.transpose()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`atan2_fast`] against the system's `atan2` over every octant, the axes and the
    /// reductions' bounds: within 2 units in the last place of pi (4.4e-16 rad), and
    /// [`lon_lat_fast`] within as much of the system's arctangents. (Against [`lon_lat`]'s
    /// `asin`, which is ill-conditioned near a pole, latitudes differ by up to 2.9e-15.)
    #[test]
    fn the_fast_arctangent_agrees_with_libm() {
        let mut worst = 0.0f64;
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        let special = [0.0, 1.0, -1.0, 0.66, 2.414_213_562_373_095, 1e-300, 1e300];
        for k in 0..200_000 {
            let (y, x) = if k < special.len() * special.len() {
                (special[k / special.len()], special[k % special.len()])
            } else {
                let scale = 10f64.powf(6.0 * next());
                (next() * scale, next())
            };
            if x == 0.0 && y == 0.0 {
                continue;
            }
            worst = worst.max((atan2_fast(y, x) - y.atan2(x)).abs());
            let v = DVec3::new(x, y, next() * 3.0);
            let (a, b) = (lon_lat_fast(v), (v.y.atan2(v.x), v.z.atan2(v.x.hypot(v.y))));
            worst = worst.max((a.0 - b.0).abs()).max((a.1 - b.1).abs());
        }
        assert!(worst <= 4.5e-16, "worst {worst:e} rad");
    }

    #[test]
    fn look_at_puts_target_on_boresight() {
        let cam = DVec3::new(1e7, 2e6, -3e6);
        let q = look_at(cam, DVec3::ZERO, DVec3::NEG_Z);
        let bore = q * DVec3::Z;
        assert!((bore - (-cam).normalize()).length() < 1e-12);
        // Image down is the projected south.
        let down = q * DVec3::Y;
        assert!(down.z < 0.0);
    }

    #[test]
    fn csf_puts_camera_at_phase_longitude() {
        let sun = DVec3::new(1.5e11, 0.0, 0.0);
        let cam = DVec3::new(0.0, 1e7, 1e7);
        let f = CsfFrame::new(sun, cam, DVec3::Z);
        assert!((f.phase_rad - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        let c_csf = f.csf_from_body() * cam.normalize();
        assert!(c_csf.z.abs() < 1e-12);
        assert!((c_csf.y - 1.0).abs() < 1e-12);
    }

    #[test]
    fn ray_sphere_hits_near_side() {
        let t = ray_sphere(DVec3::new(0.0, 0.0, -10.0), DVec3::Z, 1.0).unwrap();
        assert!((t - 9.0).abs() < 1e-12);
        assert!(ray_sphere(DVec3::new(0.0, 2.0, -10.0), DVec3::Z, 1.0).is_none());
    }

    #[test]
    fn wrap_is_in_range() {
        for a in [-10.0, -3.2, 0.0, 3.2, 10.0] {
            let w = wrap_pi(a);
            assert!(w > -std::f64::consts::PI && w <= std::f64::consts::PI);
            assert!(((a - w) / std::f64::consts::TAU).fract().abs() < 1e-12);
        }
    }
}
