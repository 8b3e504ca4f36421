//! Triangle-mesh shapes (SLIM Sec. 2: a body as a closed triangulated surface, lit facet by
//! facet): loaded from OBJ (`tobj`), PLY ASCII or binary (`ply-rs-bw`) and STL (`stl_io`),
//! checked, repaired where the repair is unambiguous, and put in a BVH
//! ([`crate::geometry::bvh`]).
//!
//! What loading does with a bad mesh (`docs/scene.md`, "Meshes"):
//! - an empty file, a non-finite coordinate, an index out of range, an edge shared by more
//!   than two facets (non-manifold), or a surface that cannot be oriented: a [`MeshError`]
//!   naming the file and what is wrong;
//! - degenerate facets (a repeated vertex, or an area below 1e-12 of the bounding radius
//!   squared): dropped, and counted in the [`MeshReport`];
//! - inconsistent winding: facets flipped to agree with their neighbours across every shared
//!   edge, then each closed part turned so that its normals point outward (positive enclosed
//!   volume); counted. Open edges (a surface patch) are allowed and counted.
//!
//! Facets are flat: one normal per facet, as the mesh describes the surface (SLIM Eq. 1's
//! facet normal).

use crate::geometry::bvh::{TriangleBvh, TriangleHit};
use glam::{DMat3, DVec3};
use serde::Serialize;
use std::collections::HashMap;
use std::path::Path;

#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    #[error("{file}: cannot read: {message}")]
    Read { file: String, message: String },
    #[error("{file}: {message}")]
    Format { file: String, message: String },
}

/// What loading found and repaired.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct MeshReport {
    pub vertices: usize,
    /// Facets kept (after dropping degenerate ones).
    pub facets: usize,
    pub dropped_degenerate: usize,
    /// Facets whose winding was reversed to agree with their neighbours and face outward.
    pub flipped: usize,
    /// Edges with one facet only (0 for a closed surface).
    pub open_edges: usize,
    /// Parts not connected to each other across edges.
    pub components: usize,
    pub bvh_build_ms: f64,
    /// Bytes of the BVH and of the facet tables.
    pub bytes: usize,
}

/// A triangle mesh in the body frame [m].
pub struct Mesh {
    vertices_m: Vec<DVec3>,
    facets: Vec<[u32; 3]>,
    /// Outward unit normal, area [m^2] and centroid [m] of each facet.
    normals: Vec<DVec3>,
    areas_m2: Vec<f64>,
    centroids_m: Vec<DVec3>,
    bounding_radius_m: f64,
    bvh: TriangleBvh,
    report: MeshReport,
}

impl std::fmt::Debug for Mesh {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "Mesh {{ {} vertices, {} facets, bounding radius {} m }}",
            self.vertices_m.len(),
            self.facets.len(),
            self.bounding_radius_m
        )
    }
}

impl PartialEq for Mesh {
    fn eq(&self, other: &Self) -> bool {
        self.vertices_m == other.vertices_m && self.facets == other.facets
    }
}

impl Mesh {
    /// Loads a mesh file by its extension (`.obj`, `.ply`, `.stl`), its coordinates in units of
    /// `metres_per_unit` metres, turned into the body frame by `body_from_file`.
    pub fn load(
        path: &Path,
        metres_per_unit: f64,
        body_from_file: DMat3,
    ) -> Result<Mesh, MeshError> {
        let file = path.display().to_string();
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase());
        let read_err = |message: String| MeshError::Read {
            file: file.clone(),
            message,
        };
        let (vertices, facets) = match ext.as_deref() {
            Some("obj") => read_obj(path).map_err(read_err)?,
            Some("ply") => read_ply(path).map_err(read_err)?,
            Some("stl") => read_stl(path).map_err(read_err)?,
            _ => {
                return Err(MeshError::Format {
                    file,
                    message: "not a mesh file: the extension must be .obj, .ply or .stl".into(),
                });
            }
        };
        let vertices = vertices
            .into_iter()
            .map(|v| body_from_file * (DVec3::from_array(v) * metres_per_unit))
            .collect();
        Mesh::new(vertices, facets).map_err(|message| MeshError::Format { file, message })
    }

    /// Checks, repairs and indexes a mesh given as vertices [m] and facets (vertex indices,
    /// counter-clockwise seen from outside where the source is consistent). The error says
    /// what is wrong.
    pub fn new(vertices_m: Vec<DVec3>, facets: Vec<[u32; 3]>) -> Result<Mesh, String> {
        if vertices_m.is_empty() || facets.is_empty() {
            return Err(format!(
                "no surface: {} vertices and {} facets",
                vertices_m.len(),
                facets.len()
            ));
        }
        if let Some((i, v)) = vertices_m.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(format!("vertex {} is not finite: {v:?}", i + 1));
        }
        let n = vertices_m.len() as u32;
        if let Some((i, f)) = facets
            .iter()
            .enumerate()
            .find(|(_, f)| f.iter().any(|&k| k >= n))
        {
            return Err(format!(
                "facet {} names vertex {} of {n}",
                i + 1,
                f.iter().find(|&&k| k >= n).map_or(0, |k| k + 1)
            ));
        }
        let centre = vertices_m.iter().sum::<DVec3>() / vertices_m.len() as f64;
        let reach = vertices_m
            .iter()
            .map(|v| (*v - centre).length())
            .fold(0.0, f64::max);
        let area = |f: &[u32; 3]| {
            let [a, b, c] = f.map(|k| vertices_m[k as usize]);
            0.5 * (b - a).cross(c - a).length()
        };
        let min_area = 1e-12 * reach * reach;
        let before = facets.len();
        let mut facets: Vec<[u32; 3]> = facets
            .into_iter()
            .filter(|f| f[0] != f[1] && f[1] != f[2] && f[0] != f[2] && area(f) > min_area)
            .collect();
        let dropped_degenerate = before - facets.len();
        if facets.is_empty() {
            return Err(format!("all {before} facets are degenerate"));
        }
        let orient = orient(&vertices_m, &mut facets)?;
        let normals: Vec<DVec3> = facets
            .iter()
            .map(|f| {
                let [a, b, c] = f.map(|k| vertices_m[k as usize]);
                (b - a).cross(c - a).normalize()
            })
            .collect();
        let areas_m2: Vec<f64> = facets.iter().map(area).collect();
        let centroids_m: Vec<DVec3> = facets
            .iter()
            .map(|f| f.iter().map(|&k| vertices_m[k as usize]).sum::<DVec3>() / 3.0)
            .collect();
        // The bounding sphere is centred on the body's origin: the renderer bounds and aims
        // at the body centre.
        let bounding_radius_m = facets
            .iter()
            .flatten()
            .map(|&k| vertices_m[k as usize].length())
            .fold(0.0, f64::max);
        let tris: Vec<[DVec3; 3]> = facets
            .iter()
            .map(|f| f.map(|k| vertices_m[k as usize]))
            .collect();
        let (bvh, built) = TriangleBvh::build(&tris, DVec3::ZERO, bounding_radius_m);
        let bytes = bvh.heap_bytes() + vertices_m.len() * 24 + facets.len() * (12 + 24 + 8 + 24);
        let report = MeshReport {
            vertices: vertices_m.len(),
            facets: facets.len(),
            dropped_degenerate,
            flipped: orient.flipped,
            open_edges: orient.open_edges,
            components: orient.components,
            bvh_build_ms: built.as_secs_f64() * 1e3,
            bytes,
        };
        Ok(Mesh {
            vertices_m,
            facets,
            normals,
            areas_m2,
            centroids_m,
            bounding_radius_m,
            bvh,
            report,
        })
    }

    pub fn report(&self) -> &MeshReport {
        &self.report
    }

    /// Radius of the sphere centred on the body origin that holds every vertex [m].
    pub fn bounding_radius_m(&self) -> f64 {
        self.bounding_radius_m
    }

    pub fn facets(&self) -> &[[u32; 3]] {
        &self.facets
    }

    pub fn vertices_m(&self) -> &[DVec3] {
        &self.vertices_m
    }

    /// Outward unit normal of each facet.
    pub fn normals(&self) -> &[DVec3] {
        &self.normals
    }

    /// Area of each facet [m^2].
    pub fn areas_m2(&self) -> &[f64] {
        &self.areas_m2
    }

    /// Centroid of each facet [m].
    pub fn centroids_m(&self) -> &[DVec3] {
        &self.centroids_m
    }

    /// The first facet on the ray `origin_m + t dir` (`dir` unit), `0 < t < t_max_m`.
    #[inline]
    pub fn intersect(&self, origin_m: DVec3, dir: DVec3, t_max_m: f64) -> Option<TriangleHit> {
        self.bvh.closest(origin_m, dir, t_max_m)
    }

    /// Whether the surface hides the direction `dir` (unit; the Sun's) from the surface point
    /// `p_m` whose facet has the normal `normal`: the ray starts a hair above the facet (1e-6
    /// of the bounding radius along its normal), so that the facet does not shadow itself.
    #[inline]
    pub fn shadows(&self, p_m: DVec3, normal: DVec3, dir: DVec3) -> bool {
        self.bvh
            .occluded(self.shadow_origin(p_m, normal, dir), dir, f64::INFINITY)
    }

    /// Where the shadow ray of [`Mesh::shadows`] starts: `p_m` lifted off its facet (normal
    /// `normal`) by 1e-6 of the bounding radius, on the side the ray `dir` leaves to.
    #[inline]
    pub fn shadow_origin(&self, p_m: DVec3, normal: DVec3, dir: DVec3) -> DVec3 {
        let lift = 1e-6 * self.bounding_radius_m;
        let side = if normal.dot(dir) >= 0.0 { 1.0 } else { -1.0 };
        p_m + normal * (side * lift)
    }

    /// Whether a facet lies on the ray `from_m + t dir` (`dir` unit) with `0 < t < t_max_m`.
    #[inline]
    pub fn occluded_between(&self, from_m: DVec3, dir: DVec3, t_max_m: f64) -> bool {
        self.bvh.occluded(from_m, dir, t_max_m)
    }

    /// Whether the point `p_m` lies inside the closed surface (ray parity along a fixed
    /// direction no mesh edge of a generic model lies along).
    pub fn contains(&self, p_m: DVec3) -> bool {
        if p_m.length() >= self.bounding_radius_m {
            return false;
        }
        let dir = DVec3::new(0.5773, 0.5774, 0.5775).normalize();
        self.bvh.crossings(p_m, dir) % 2 == 1
    }

    /// The outermost surface point along the unit direction `dir` from the origin, and its
    /// facet's normal (the origin itself and `dir` where the ray from outside misses).
    pub fn surface(&self, dir: DVec3) -> (DVec3, DVec3) {
        let from = dir * (2.0 * self.bounding_radius_m);
        match self.intersect(from, -dir, 2.0 * self.bounding_radius_m) {
            Some(h) => (from - dir * h.t_m, self.normals[h.triangle as usize]),
            None => (DVec3::ZERO, dir),
        }
    }

    /// The volume the surface encloses [m^3] (the divergence theorem over the facets; exact
    /// for a closed, outward-wound surface).
    pub fn volume_m3(&self) -> f64 {
        signed_volume(&self.vertices_m, &self.facets)
    }
}

/// What [`orient`] found and did.
struct Orientation {
    flipped: usize,
    open_edges: usize,
    components: usize,
}

fn signed_volume(v: &[DVec3], facets: &[[u32; 3]]) -> f64 {
    facets
        .iter()
        .map(|f| {
            let [a, b, c] = f.map(|k| v[k as usize]);
            a.dot(b.cross(c))
        })
        .sum::<f64>()
        / 6.0
}

/// Makes the winding consistent across every shared edge (a breadth-first walk over each
/// connected part) and turns each closed part outward; refuses non-manifold edges and
/// non-orientable parts.
fn orient(v: &[DVec3], facets: &mut [[u32; 3]]) -> Result<Orientation, String> {
    // Each undirected edge: the facets on it.
    let mut edges: HashMap<(u32, u32), Vec<u32>> = HashMap::with_capacity(facets.len() * 2);
    for (i, f) in facets.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (f[k], f[(k + 1) % 3]);
            edges
                .entry((a.min(b), a.max(b)))
                .or_default()
                .push(i as u32);
        }
    }
    let mut open_edges = 0;
    for ((a, b), on) in &edges {
        match on.len() {
            1 => open_edges += 1,
            2 => {}
            n => {
                return Err(format!(
                    "non-manifold: the edge between vertices {} and {} is shared by {n} facets",
                    a + 1,
                    b + 1
                ));
            }
        }
    }
    // Does facet f run along a -> b?
    let forward = |f: &[u32; 3], a: u32, b: u32| (0..3).any(|k| f[k] == a && f[(k + 1) % 3] == b);
    let mut state = vec![0u8; facets.len()]; // 0 unseen, 1 kept, 2 flipped
    let mut flipped_total = 0;
    let mut components = 0;
    let mut queue = std::collections::VecDeque::new();
    for seed in 0..facets.len() {
        if state[seed] != 0 {
            continue;
        }
        components += 1;
        let mut part = vec![seed as u32];
        let mut closed = true;
        state[seed] = 1;
        queue.push_back(seed as u32);
        while let Some(i) = queue.pop_front() {
            let f = facets[i as usize];
            let f_now = if state[i as usize] == 2 {
                [f[0], f[2], f[1]]
            } else {
                f
            };
            for k in 0..3 {
                let (a, b) = (f_now[k], f_now[(k + 1) % 3]);
                let on = &edges[&(a.min(b), a.max(b))];
                if on.len() == 1 {
                    closed = false;
                }
                for &j in on.iter().filter(|&&j| j != i) {
                    let g = facets[j as usize];
                    // A neighbour agrees when it runs the shared edge the other way.
                    let agrees_as_is = !forward(&g, a, b);
                    let want = if agrees_as_is { 1 } else { 2 };
                    match state[j as usize] {
                        0 => {
                            state[j as usize] = want;
                            part.push(j);
                            queue.push_back(j);
                        }
                        s if s != want => {
                            return Err(format!(
                                "the surface cannot be oriented (a Moebius-like part near \
                                 facet {})",
                                j + 1
                            ));
                        }
                        _ => {}
                    }
                }
            }
        }
        for &i in &part {
            if state[i as usize] == 2 {
                let f = &mut facets[i as usize];
                f.swap(1, 2);
            }
        }
        // A closed part encloses positive volume when its normals point outward.
        let mut part_flipped = part.iter().filter(|&&i| state[i as usize] == 2).count();
        if closed {
            let own: Vec<[u32; 3]> = part.iter().map(|&i| facets[i as usize]).collect();
            if signed_volume(v, &own) < 0.0 {
                for &i in &part {
                    facets[i as usize].swap(1, 2);
                }
                part_flipped = part.len() - part_flipped;
            }
        }
        flipped_total += part_flipped;
    }
    Ok(Orientation {
        flipped: flipped_total,
        open_edges,
        components,
    })
}

type Read = (Vec<[f64; 3]>, Vec<[u32; 3]>);

/// Splits polygons into triangle fans.
fn fan(poly: &[u32], out: &mut Vec<[u32; 3]>) {
    for k in 1..poly.len().saturating_sub(1) {
        out.push([poly[0], poly[k], poly[k + 1]]);
    }
}

fn read_obj(path: &Path) -> Result<Read, String> {
    let opts = tobj::LoadOptions {
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
    };
    let file = std::fs::File::open(path).map_err(|e| e.to_string())?;
    let mut reader = std::io::BufReader::new(file);
    // Materials are not ours (the reflectance comes from the scene file).
    let (models, _) =
        tobj::load_obj_buf(&mut reader, &opts, |_| Err(tobj::LoadError::OpenFileFailed))
            .map_err(|e| format!("not a readable OBJ file ({e})"))?;
    let (mut vertices, mut facets) = (Vec::new(), Vec::new());
    for m in models {
        let base = vertices.len() as u32;
        let p = &m.mesh.positions;
        vertices.extend(p.chunks_exact(3).map(|c| [c[0], c[1], c[2]]));
        facets.extend(
            m.mesh
                .indices
                .chunks_exact(3)
                .map(|c| [c[0] + base, c[1] + base, c[2] + base]),
        );
    }
    Ok((vertices, facets))
}

fn read_ply(path: &Path) -> Result<Read, String> {
    use ply_rs_bw::ply::{DefaultElement, Property};
    let mut file = std::io::BufReader::new(std::fs::File::open(path).map_err(|e| e.to_string())?);
    let ply = ply_rs_bw::parser::Parser::<DefaultElement>::new()
        .read_ply(&mut file)
        .map_err(|e| format!("not a readable PLY file ({e})"))?;
    let scalar = |p: Option<&Property>| -> Option<f64> {
        Some(match p? {
            Property::Float(x) => *x as f64,
            Property::Double(x) => *x,
            Property::Int(x) => *x as f64,
            Property::UInt(x) => *x as f64,
            Property::Short(x) => *x as f64,
            Property::UShort(x) => *x as f64,
            Property::Char(x) => *x as f64,
            Property::UChar(x) => *x as f64,
            _ => return None,
        })
    };
    let vertex_el = ply.payload.get("vertex").ok_or("no \"vertex\" element")?;
    let mut vertices = Vec::with_capacity(vertex_el.len());
    for (i, e) in vertex_el.iter().enumerate() {
        let c =
            |k: &str| scalar(e.get(k)).ok_or_else(|| format!("vertex {}: no numeric {k:?}", i + 1));
        vertices.push([c("x")?, c("y")?, c("z")?]);
    }
    let face_el = ply.payload.get("face").ok_or("no \"face\" element")?;
    let mut facets = Vec::with_capacity(face_el.len());
    let mut poly = Vec::new();
    for (i, e) in face_el.iter().enumerate() {
        let list = e
            .get("vertex_indices")
            .or_else(|| e.get("vertex_index"))
            .ok_or_else(|| format!("face {}: no vertex_indices list", i + 1))?;
        poly.clear();
        let bad = || format!("face {}: a negative vertex index", i + 1);
        match list {
            Property::ListInt(l) => {
                for &k in l {
                    poly.push(u32::try_from(k).map_err(|_| bad())?);
                }
            }
            Property::ListUInt(l) => poly.extend_from_slice(l),
            Property::ListShort(l) => {
                for &k in l {
                    poly.push(u32::try_from(k).map_err(|_| bad())?);
                }
            }
            Property::ListUShort(l) => poly.extend(l.iter().map(|&k| k as u32)),
            Property::ListChar(l) => {
                for &k in l {
                    poly.push(u32::try_from(k).map_err(|_| bad())?);
                }
            }
            Property::ListUChar(l) => poly.extend(l.iter().map(|&k| k as u32)),
            _ => {
                return Err(format!(
                    "face {}: vertex_indices is not a list of integers",
                    i + 1
                ));
            }
        }
        fan(&poly, &mut facets);
    }
    Ok((vertices, facets))
}

fn read_stl(path: &Path) -> Result<Read, String> {
    let mut file = std::io::BufReader::new(std::fs::File::open(path).map_err(|e| e.to_string())?);
    let m = stl_io::read_stl(&mut file).map_err(|e| format!("not a readable STL file ({e})"))?;
    let vertices = m
        .vertices
        .iter()
        .map(|v| [v.0[0] as f64, v.0[1] as f64, v.0[2] as f64])
        .collect();
    let facets = m
        .faces
        .iter()
        .map(|f| f.vertices.map(|k| k as u32))
        .collect();
    Ok((vertices, facets))
}

/// A geodesic sphere of radius `radius_m`: the icosahedron with each face split into
/// `n x n` triangles, projected on the sphere (`20 n^2` facets).
pub fn geodesic_sphere(radius_m: f64, n: u32) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let ico = [
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ]
    .map(DVec3::from_array);
    let faces: [[usize; 3]; 20] = [
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    let mut vertices = Vec::new();
    let mut index: HashMap<[i64; 3], u32> = HashMap::new();
    let mut vertex = |p: DVec3| {
        let p = p.normalize();
        // Shared edge points are merged by their rounded position.
        let key = (p * 1e9).round().as_i64vec3().to_array();
        *index.entry(key).or_insert_with(|| {
            vertices.push(p * radius_m);
            (vertices.len() - 1) as u32
        })
    };
    let mut facets = Vec::new();
    let n = n.max(1);
    for f in faces {
        let [a, b, c] = f.map(|k| ico[k]);
        let at =
            |i: u32, j: u32| a + (b - a) * (i as f64 / n as f64) + (c - a) * (j as f64 / n as f64);
        let mut ids = vec![vec![0u32; n as usize + 1]; n as usize + 1];
        for i in 0..=n {
            for j in 0..=(n - i) {
                ids[i as usize][j as usize] = vertex(at(i, j));
            }
        }
        for i in 0..n {
            for j in 0..(n - i) {
                let (i, j) = (i as usize, j as usize);
                facets.push([ids[i][j], ids[i + 1][j], ids[i][j + 1]]);
                if i + j + 1 < n as usize {
                    facets.push([ids[i + 1][j], ids[i + 1][j + 1], ids[i][j + 1]]);
                }
            }
        }
    }
    (vertices, facets)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_geodesic_sphere_is_closed_outward_and_encloses_the_ball() {
        let (v, f) = geodesic_sphere(1000.0, 8);
        let m = Mesh::new(v, f).unwrap();
        let r = m.report();
        assert_eq!((r.facets, r.open_edges, r.components), (20 * 64, 0, 1));
        let ball = 4.0 / 3.0 * std::f64::consts::PI * 1e9;
        assert!(m.volume_m3() > 0.97 * ball && m.volume_m3() < ball);
        assert!(m.contains(DVec3::new(10.0, -20.0, 30.0)));
        assert!(!m.contains(DVec3::new(990.0, 300.0, 0.0)));
        let (p, n) = m.surface(DVec3::Z);
        assert!((p.z - 1000.0).abs() < 5.0 && n.z > 0.99, "{p} {n}");
    }

    #[test]
    fn inverted_and_mixed_windings_are_repaired_outward() {
        let (v, mut f) = geodesic_sphere(1.0, 4);
        for (i, t) in f.iter_mut().enumerate() {
            if i % 3 == 0 {
                t.swap(0, 1);
            }
        }
        let m = Mesh::new(v.clone(), f.clone()).unwrap();
        assert_eq!(m.report().flipped, f.len().div_ceil(3));
        assert!(m.volume_m3() > 0.0);
        // Every facet turned inside out: all flipped back.
        let inside_out: Vec<_> = geodesic_sphere(1.0, 4)
            .1
            .into_iter()
            .map(|t| [t[0], t[2], t[1]])
            .collect();
        let m = Mesh::new(v, inside_out.clone()).unwrap();
        assert_eq!(m.report().flipped, inside_out.len());
        assert!(
            m.normals()
                .iter()
                .zip(m.centroids_m())
                .all(|(n, c)| n.dot(*c) > 0.0)
        );
    }

    #[test]
    fn bad_meshes_are_refused_with_what_is_wrong() {
        let (v, f) = geodesic_sphere(1.0, 2);
        let e = Mesh::new(vec![], vec![]).unwrap_err();
        assert!(e.contains("no surface"), "{e}");
        let mut nan = v.clone();
        nan[3].y = f64::NAN;
        assert!(
            Mesh::new(nan, f.clone())
                .unwrap_err()
                .contains("vertex 4 is not finite")
        );
        let mut out = f.clone();
        out[5][1] = 9999;
        assert!(
            Mesh::new(v.clone(), out)
                .unwrap_err()
                .contains("facet 6 names vertex 10000")
        );
        // A third facet on an edge.
        let mut nm = f.clone();
        let [a, b, _] = f[0];
        let mut v3 = v.clone();
        v3.push(DVec3::new(5.0, 5.0, 5.0));
        nm.push([a, b, v3.len() as u32 - 1]);
        assert!(Mesh::new(v3, nm).unwrap_err().contains("non-manifold"));
        // Degenerate facets are dropped and counted.
        let mut deg = f.clone();
        deg.push([0, 0, 1]);
        deg.push([0, 1, 1]);
        let m = Mesh::new(v, deg).unwrap();
        assert_eq!(m.report().dropped_degenerate, 2);
    }
}
