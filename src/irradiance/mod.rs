//! Surface irradiance of mesh bodies (SLIM Secs. 6.1, 6.2 and 9.3): the sunlight each facet
//! receives directly, with the shadows the body casts on itself; the light scattered between
//! facets by Lambertian radiosity, one Jacobi iteration per order of scattering (Eqs. 4-9);
//! and statistics of both over a rotation (Eq. 14).
//!
//! Irradiances here are fractions of the solar irradiance at the body's centre on a surface
//! facing the Sun (dimensionless); `app::irradiance` multiplies them by it [W/m^2].
//!
//! Radiosity (Eqs. 4-6) in these units: a facet's radiosity is `B_i = rho (E_i + R_i)`, its
//! scattered irradiance `R_i = sum_j F_ij B_j`, with the point form factor of Eq. 7,
//! `F_ij = cos(theta_i) cos(theta_j) A_j / (pi r^2)` between centroids that see each other
//! (a ray between them meets no other facet). Jacobi (Eq. 9) from `B^0 = rho E`:
//! `R^k = sum_j F_ij B^(k-1)_j`, `B^k = rho R^k`, and the scattered irradiance after `K` orders
//! is `R^1 + ... + R^K`. `rho` is the body's Bond albedo (`Brdf::albedo(Bond)`): the scattered
//! light is Lambertian whatever the BRDF (SLIM: only Lambertian scattering goes beyond the
//! first order). The point form factor of two close facets at a sharp concave edge can sum
//! above 1 over a row; such rows are scaled to 1 (energy is not created) and counted.

use crate::body::Mesh;
use glam::DVec3;
use rayon::prelude::*;

/// The form factors of a mesh (Eq. 7) with facet-to-facet visibility, as sparse rows.
pub struct FormFactors {
    /// Row `i` holds `entries[offsets[i]..offsets[i + 1]]`: `(j, F_ij)`.
    offsets: Vec<usize>,
    entries: Vec<(u32, f32)>,
    /// Rows whose form factors summed above 1 and were scaled down to 1.
    pub capped_rows: usize,
}

impl FormFactors {
    /// Every pair of facets that face each other (each in front of the other's plane) and see
    /// each other: `O(N^2)` tests of facing, a ray through the BVH for the pairs that pass.
    pub fn new(mesh: &Mesh) -> FormFactors {
        let c = mesh.centroids_m();
        let n = mesh.normals();
        let a = mesh.areas_m2();
        let lift = 1e-6 * mesh.bounding_radius_m();
        let rows: Vec<(Vec<(u32, f32)>, bool)> = (0..c.len())
            .into_par_iter()
            .map(|i| {
                let (ci, ni) = (c[i], n[i]);
                let mut row = Vec::new();
                for j in 0..c.len() {
                    let d = c[j] - ci;
                    let cos_i = ni.dot(d);
                    let cos_j = -n[j].dot(d);
                    if j == i || cos_i <= 0.0 || cos_j <= 0.0 {
                        continue;
                    }
                    let r2 = d.length_squared();
                    let r = r2.sqrt();
                    let dir = d / r;
                    // From a hair above facet i to a hair short of facet j.
                    let from = ci + ni * lift;
                    if mesh.occluded_between(from, dir, r - 2.0 * lift) {
                        continue;
                    }
                    let f = cos_i * cos_j * a[j] / (std::f64::consts::PI * r2 * r2);
                    row.push((j as u32, f as f32));
                }
                let sum: f64 = row.iter().map(|e| e.1 as f64).sum();
                let capped = sum > 1.0;
                if capped {
                    for e in &mut row {
                        e.1 = (e.1 as f64 / sum) as f32;
                    }
                }
                (row, capped)
            })
            .collect();
        let mut offsets = Vec::with_capacity(rows.len() + 1);
        offsets.push(0);
        let mut entries = Vec::with_capacity(rows.iter().map(|r| r.0.len()).sum());
        let mut capped_rows = 0;
        for (row, capped) in rows {
            entries.extend(row);
            offsets.push(entries.len());
            capped_rows += capped as usize;
        }
        FormFactors {
            offsets,
            entries,
            capped_rows,
        }
    }

    /// Pairs that exchange light (the rows' entries).
    pub fn nonzeros(&self) -> usize {
        self.entries.len()
    }

    /// Bytes held.
    pub fn heap_bytes(&self) -> usize {
        self.entries.len() * 8 + self.offsets.len() * 8
    }

    /// `sum_j F_ij b_j` for every facet `i`.
    pub fn gather(&self, b: &[f64]) -> Vec<f64> {
        (0..self.offsets.len() - 1)
            .into_par_iter()
            .map(|i| {
                self.entries[self.offsets[i]..self.offsets[i + 1]]
                    .iter()
                    .map(|&(j, f)| f as f64 * b[j as usize])
                    .sum()
            })
            .collect()
    }
}

/// Direct irradiance of each facet from a Sun at `sun_m` (body frame) as a fraction of the
/// solar irradiance at the body's centre: `(d_0 / d_i)^2 max(0, n_i . s_i)` at the facet's
/// centroid, 0 where the body shadows the centroid (SLIM Sec. 6.1, Eq. 2's dot product).
pub fn direct(mesh: &Mesh, sun_m: DVec3) -> Vec<f64> {
    let d0 = sun_m.length_squared();
    mesh.centroids_m()
        .par_iter()
        .zip(mesh.normals().par_iter())
        .map(|(&c, &n)| {
            let to_sun = sun_m - c;
            let d2 = to_sun.length_squared();
            let s = to_sun / d2.sqrt();
            let mu0 = n.dot(s);
            if mu0 <= 0.0 || mesh.shadows(c, n, s) {
                0.0
            } else {
                d0 / d2 * mu0
            }
        })
        .collect()
}

/// The irradiance scattered onto each facet at each order `1..=orders` (Eq. 9, Jacobi), from
/// the direct irradiance `direct` and the Bond albedo `rho`.
pub fn scattered_by_order(
    ff: &FormFactors,
    direct: &[f64],
    rho: f64,
    orders: u32,
) -> Vec<Vec<f64>> {
    let mut out = Vec::with_capacity(orders as usize);
    let mut b: Vec<f64> = direct.iter().map(|e| rho * e).collect();
    for _ in 0..orders {
        let r = ff.gather(&b);
        b = r.iter().map(|x| rho * x).collect();
        out.push(r);
    }
    out
}

/// The irradiance scattered onto each facet, summed over orders `1..=orders`.
pub fn scattered(ff: &FormFactors, direct: &[f64], rho: f64, orders: u32) -> Vec<f64> {
    let mut sum = vec![0.0; direct.len()];
    for r in scattered_by_order(ff, direct, rho, orders) {
        for (s, x) in sum.iter_mut().zip(r) {
            *s += x;
        }
    }
    sum
}

/// Per-facet statistics of the total irradiance over one rotation (SLIM Eq. 14's samples).
#[derive(Clone, Debug, Default)]
pub struct RotationStats {
    pub mean: Vec<f64>,
    pub min: Vec<f64>,
    pub max: Vec<f64>,
    /// Fraction of the steps in which the facet is in direct sunlight.
    pub lit_fraction: Vec<f64>,
}

/// The direct plus scattered irradiance of every facet at `steps` evenly spaced rotation
/// angles about the body's +Z (the spin axis), the Sun fixed in inertial space at `sun_m`
/// (body frame at angle 0): the Sun turns by `-phi` in the body frame.
pub fn rotation_stats(
    mesh: &Mesh,
    ff: Option<&FormFactors>,
    sun_m: DVec3,
    rho: f64,
    orders: u32,
    steps: u32,
) -> RotationStats {
    let n = mesh.facets().len();
    let mut st = RotationStats {
        mean: vec![0.0; n],
        min: vec![f64::INFINITY; n],
        max: vec![0.0; n],
        lit_fraction: vec![0.0; n],
    };
    let steps = steps.max(1);
    for k in 0..steps {
        let phi = std::f64::consts::TAU * k as f64 / steps as f64;
        let sun = glam::DMat3::from_rotation_z(-phi) * sun_m;
        let e = direct(mesh, sun);
        let s = match ff {
            Some(ff) if orders > 0 => scattered(ff, &e, rho, orders),
            _ => vec![0.0; n],
        };
        for i in 0..n {
            let t = e[i] + s[i];
            st.mean[i] += t / steps as f64;
            st.min[i] = st.min[i].min(t);
            st.max[i] = st.max[i].max(t);
            st.lit_fraction[i] += (e[i] > 0.0) as u8 as f64 / steps as f64;
        }
    }
    st
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::mesh::geodesic_sphere;

    /// The inside of a sphere of radius 1 below `z_max`, normals inward: a spherical bowl.
    fn bowl(n: u32, z_max: f64) -> Mesh {
        let (v, f) = geodesic_sphere(1.0, n);
        let f: Vec<[u32; 3]> = f
            .into_iter()
            .filter(|t| t.iter().map(|&k| v[k as usize].z).sum::<f64>() / 3.0 < z_max)
            .map(|t| [t[0], t[2], t[1]])
            .collect();
        Mesh::new(v, f).unwrap()
    }

    #[test]
    fn once_scattered_light_is_uniform_in_a_spherical_bowl_and_orders_sum_geometrically() {
        // A hemispherical bowl lit from 40 deg above its rim: its rim shadows part of it.
        let m = bowl(24, 0.0);
        assert!(
            m.normals()
                .iter()
                .zip(m.centroids_m())
                .all(|(n, c)| n.dot(*c) < 0.0)
        );
        let sun = DVec3::new(40f64.to_radians().cos(), 0.0, 40f64.to_radians().sin()) * 1.5e11;
        let e = direct(&m, sun);
        let lit = e.iter().filter(|&&x| x > 0.0).count();
        assert!(
            lit > m.facets().len() / 4 && lit < m.facets().len() * 3 / 4,
            "{lit}"
        );
        let ff = FormFactors::new(&m);
        let rho = 0.3;
        let orders = scattered_by_order(&ff, &e, rho, 6);
        // Order 1: uniform (cos cos / (pi r^2) = 1 / (4 pi R^2) between points of a sphere).
        let r1 = &orders[0];
        let mean = r1.iter().sum::<f64>() / r1.len() as f64;
        let spread = r1
            .iter()
            .map(|x| (x / mean - 1.0).abs())
            .fold(0.0, f64::max);
        eprintln!(
            "bowl: {} facets, once-scattered spread {spread:.2e}",
            m.facets().len()
        );
        assert!(
            spread < 0.01,
            "once-scattered irradiance varies by {spread:.2e}"
        );
        // The power leaving the bowl's facets once, over the whole sphere's area.
        let a = m.areas_m2();
        let power: f64 = e.iter().zip(a).map(|(x, a)| rho * x * a).sum();
        let analytic = power / (4.0 * std::f64::consts::PI);
        assert!((mean / analytic - 1.0).abs() < 0.01, "{mean} vs {analytic}");
        // Each further order is the last times rho f (f: the bowl's share of the sphere), so
        // the sum is R1 / (1 - rho f).
        let f = a.iter().sum::<f64>() / (4.0 * std::f64::consts::PI);
        let total = scattered(&ff, &e, rho, 6);
        let series = mean * (1.0 - (rho * f).powi(6)) / (1.0 - rho * f);
        let got = total.iter().sum::<f64>() / total.len() as f64;
        assert!((got / series - 1.0).abs() < 0.01, "{got} vs {series}");
        assert_eq!(ff.capped_rows, 0);
    }

    #[test]
    fn a_convex_body_exchanges_no_light() {
        let (v, f) = geodesic_sphere(1000.0, 8);
        let m = Mesh::new(v, f).unwrap();
        let ff = FormFactors::new(&m);
        assert_eq!(ff.nonzeros(), 0);
        let e = direct(&m, DVec3::new(1.5e11, 0.0, 0.0));
        // Half the facets lit; the disk's irradiance integrated is pi R^2.
        let a = m.areas_m2();
        let power: f64 = e.iter().zip(a).map(|(x, a)| x * a).sum();
        assert!(
            (power / (std::f64::consts::PI * 1e6) - 1.0).abs() < 0.01,
            "{power}"
        );
    }
}
