//! The acceleration structure of triangle meshes: a compressed wide BVH (eight children per
//! node) from the `obvhs` crate, behind this module so that the ray caster sees only rays in
//! and hits out, in metres and `f64`.
//!
//! `obvhs` traverses in `f32`. Its triangles are stored relative to the mesh's bounding
//! sphere, in units of its radius, so that `f32` keeps ~6e-8 of that radius everywhere; a ray
//! from afar (a camera at 10,000 km from a 500 m asteroid) is first clipped to the bounding
//! sphere in `f64` and starts there. Chosen over the `bvh` crate for its traversal speed
//! (about 8x in the crate authors' published benchmark; 1.6-2.4x on our meshes' camera rays,
//! `docs/performance.md`).

use glam::{DVec3, Vec3A};
use obvhs::cwbvh::CwBvh;
use obvhs::ray::{Ray, RayHit};
use obvhs::triangle::Triangle;
use std::time::Duration;

/// How far outside the bounding sphere (in its radius) a ray from afar starts. `obvhs` skips
/// nodes that end within 1e-4 (local units) of the ray's start; a start on the sphere itself
/// lost rays that meet a fine mesh's surface just inside it (1.3e-3 of a 5e5-facet sphere's
/// light). Within 1e-4 of the bounding radius of a ray's own start (a shadow ray's), nothing
/// is found: 5 cm on Bennu.
const START_MARGIN: f64 = 0.01;

/// A BVH over triangles given in metres.
pub struct TriangleBvh {
    bvh: CwBvh,
    /// Triangles in the BVH's order, relative to `centre_m`, in units of `radius_m`.
    tris: Vec<Triangle>,
    /// For each of `tris`, the caller's triangle index.
    ids: Vec<u32>,
    centre_m: DVec3,
    radius_m: f64,
}

/// The first triangle a ray meets.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleHit {
    /// Distance along the (unit) ray direction [m].
    pub t_m: f64,
    /// The caller's index of the triangle.
    pub triangle: u32,
}

impl std::fmt::Debug for TriangleBvh {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "TriangleBvh {{ {} triangles, {} nodes, radius {} m }}",
            self.tris.len(),
            self.bvh.nodes.len(),
            self.radius_m
        )
    }
}

impl TriangleBvh {
    /// Builds the BVH of `triangles` [m] around the sphere of radius `radius_m` centred on
    /// `centre_m` that holds them all. Returns it with the build time.
    pub fn build(triangles: &[[DVec3; 3]], centre_m: DVec3, radius_m: f64) -> (Self, Duration) {
        let t0 = std::time::Instant::now();
        let k = 1.0 / radius_m;
        let f = |p: DVec3| Vec3A::from(((p - centre_m) * k).as_vec3());
        let local: Vec<Triangle> = triangles
            .iter()
            .map(|t| Triangle {
                v0: f(t[0]),
                v1: f(t[1]),
                v2: f(t[2]),
            })
            .collect();
        let bvh = if local.is_empty() {
            CwBvh::default()
        } else {
            obvhs::cwbvh::builder::build_cwbvh_from_tris(
                &local,
                // No spatial splits: each triangle sits in one leaf (parity counts stay exact).
                obvhs::BvhBuildParams {
                    pre_split: false,
                    ..obvhs::BvhBuildParams::medium_build()
                },
                &mut Duration::default(),
            )
        };
        // Triangles in the BVH's order: one indirection less per intersection.
        let ids: Vec<u32> = bvh.primitive_indices.clone();
        let tris = ids.iter().map(|&i| local[i as usize]).collect();
        (
            TriangleBvh {
                bvh,
                tris,
                ids,
                centre_m,
                radius_m,
            },
            t0.elapsed(),
        )
    }

    /// The ray `origin_m + t dir` (`dir` unit) clipped to the bounding sphere widened by
    /// [`START_MARGIN`]: the start [m] along the ray, the local ray there, and its local length.
    #[inline]
    fn local_ray(&self, origin_m: DVec3, dir: DVec3, t_max_m: f64) -> Option<(f64, Ray)> {
        let o = origin_m - self.centre_m;
        let r = self.radius_m * (1.0 + START_MARGIN);
        let b = o.dot(dir);
        let disc = b * b - (o.length_squared() - r * r);
        if disc < 0.0 {
            return None;
        }
        let sq = disc.sqrt();
        let (near, far) = (-b - sq, -b + sq);
        let start = near.max(0.0);
        let end = far.min(t_max_m);
        if end <= start {
            return None;
        }
        let k = 1.0 / self.radius_m;
        let origin = Vec3A::from(((o + dir * start) * k).as_vec3());
        let len = ((end - start) * k) as f32;
        // Negative zeros become positive (`+ 0.0`): the traversal's octant (`d < 0`) and its
        // inverse direction (the sign of `1 / d`) must agree, and `-0.0` splits them.
        let d = Vec3A::from(dir.as_vec3()) + Vec3A::ZERO;
        Some((start, Ray::new(origin, d, 0.0, len)))
    }

    /// The first triangle the ray `origin_m + t dir` meets with `0 < t < t_max_m`.
    #[inline]
    pub fn closest(&self, origin_m: DVec3, dir: DVec3, t_max_m: f64) -> Option<TriangleHit> {
        let (start, ray) = self.local_ray(origin_m, dir, t_max_m)?;
        let mut hit = RayHit::none();
        if self
            .bvh
            .ray_traverse(ray, &mut hit, |r, i| self.tris[i].intersect(r))
        {
            Some(TriangleHit {
                t_m: start + hit.t as f64 * self.radius_m,
                triangle: self.ids[hit.primitive_id as usize],
            })
        } else {
            None
        }
    }

    /// Whether any triangle lies on the ray `origin_m + t dir` with `0 < t < t_max_m`.
    #[inline]
    pub fn occluded(&self, origin_m: DVec3, dir: DVec3, t_max_m: f64) -> bool {
        match self.local_ray(origin_m, dir, t_max_m) {
            Some((_, ray)) => !self
                .bvh
                .ray_traverse_miss(ray, |r, i| self.tris[i].intersect(r)),
            None => false,
        }
    }

    /// How many triangles the ray `origin_m + t dir` crosses with `t > 0` (a parity test of
    /// inside and outside).
    pub fn crossings(&self, origin_m: DVec3, dir: DVec3) -> usize {
        let Some((_, ray)) = self.local_ray(origin_m, dir, f64::INFINITY) else {
            return 0;
        };
        let mut n = 0;
        self.bvh.ray_traverse_anyhit(ray, |r, i| {
            if self.tris[i].intersect(r).is_finite() {
                n += 1;
            }
        });
        n
    }

    /// Bytes held (nodes, triangles, indices).
    pub fn heap_bytes(&self) -> usize {
        self.bvh.nodes.len() * std::mem::size_of::<obvhs::cwbvh::node::CwBvhNode>()
            + self.bvh.primitive_indices.len() * 4
            + self.tris.len() * std::mem::size_of::<Triangle>()
            + self.ids.len() * 4
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit cube's twelve triangles scaled to `s` metres and moved to `c`.
    fn cube(s: f64, c: DVec3) -> Vec<[DVec3; 3]> {
        let v = |x: f64, y: f64, z: f64| c + DVec3::new(x, y, z) * s;
        let p = [
            v(-1., -1., -1.),
            v(1., -1., -1.),
            v(1., 1., -1.),
            v(-1., 1., -1.),
            v(-1., -1., 1.),
            v(1., -1., 1.),
            v(1., 1., 1.),
            v(-1., 1., 1.),
        ];
        let f = [
            [0, 2, 1],
            [0, 3, 2],
            [4, 5, 6],
            [4, 6, 7],
            [0, 1, 5],
            [0, 5, 4],
            [2, 3, 7],
            [2, 7, 6],
            [1, 2, 6],
            [1, 6, 5],
            [0, 4, 7],
            [0, 7, 3],
        ];
        f.iter().map(|t| [p[t[0]], p[t[1]], p[t[2]]]).collect()
    }

    #[test]
    fn rays_from_far_away_meet_the_cube_at_its_face() {
        let c = DVec3::new(3.0, -2.0, 1.0);
        let tris = cube(250.0, c);
        let (bvh, _) = TriangleBvh::build(&tris, c, 250.0 * 3f64.sqrt());
        // From 10,000 km along -X: the face x = c.x - 250 m.
        let origin = c + DVec3::new(-1e7, 10.0, -20.0);
        let hit = bvh.closest(origin, DVec3::X, f64::INFINITY).unwrap();
        assert!((hit.t_m - (1e7 - 250.0)).abs() < 1e-3, "{hit:?}");
        assert!([10, 11].contains(&hit.triangle), "{hit:?}");
        assert!(bvh.closest(origin, DVec3::Y, f64::INFINITY).is_none());
        assert!(bvh.occluded(origin, DVec3::X, f64::INFINITY));
        assert!(!bvh.occluded(origin, DVec3::X, 1e7 - 300.0));
        // Parity: inside crosses once, outside twice or never.
        assert_eq!(
            bvh.crossings(
                c + DVec3::new(1.0, 2.0, 3.0),
                DVec3::new(0.3, 0.5, 0.81).normalize()
            ),
            1
        );
        assert_eq!(bvh.crossings(origin, DVec3::X), 2);
        // Axis-aligned rays with negative zeros in their direction.
        let down = bvh.closest(c + DVec3::new(0.0, 0.0, 1e4), -DVec3::Z, f64::INFINITY);
        assert!((down.unwrap().t_m - (1e4 - 250.0)).abs() < 1e-3);
    }
}
