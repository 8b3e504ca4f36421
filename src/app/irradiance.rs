//! `optistim irradiance SCENE --out DIR`: the surface irradiance of a mesh body
//! ([`crate::irradiance`]) for the scene's Sun, direct and scattered, per facet as CSV and as
//! PLY face properties; with `--steps N`, its statistics over one rotation about the body's +Z
//! (SLIM Eq. 14: mean, min, max, fraction of the time in sunlight).

use super::AppError;
use crate::body::Shape;
use crate::brdf::AlbedoType;
use crate::config::Config;
use crate::irradiance::{self as irr, FormFactors};
use ply_rs_bw::ply::{
    Addable, DefaultElement, ElementDef, Encoding, Ply, Property, PropertyDef, PropertyType,
    ScalarType,
};
use serde::Serialize;
use std::path::Path;
use std::time::Instant;

/// The command's summary line.
#[derive(Debug, Serialize)]
pub struct IrradianceSummary {
    pub facets: usize,
    /// Solar irradiance at the body's centre [W/m^2]: the unit of the products.
    pub solar_w_m2: f64,
    pub bond_albedo: f64,
    pub orders: u32,
    /// Facet pairs that exchange light, rows scaled down to 1, and the form factors' time.
    pub pairs: usize,
    pub capped_rows: usize,
    pub form_factors_s: f64,
    pub form_factors_bytes: usize,
    /// Power the body intercepts directly and receives scattered [W].
    pub direct_w: f64,
    pub scattered_w: f64,
    pub steps: u32,
    pub seconds: f64,
}

pub fn run(
    config: &Config,
    out: &Path,
    orders: u32,
    steps: u32,
) -> Result<IrradianceSummary, AppError> {
    let t0 = Instant::now();
    let Shape::Mesh(mesh) = &config.scene.body.shape else {
        return Err(AppError::Irradiance(
            "the scene's body is not a mesh (body.shape = \"mesh\")".into(),
        ));
    };
    std::fs::create_dir_all(out).map_err(|source| AppError::OutDir {
        path: out.display().to_string(),
        source,
    })?;
    let sun_m = config.pose.sun_position_m;
    let solar = config.scene.sun.irradiance_at(sun_m.length());
    let rho = config.scene.body.brdf.albedo(AlbedoType::Bond);
    let t_ff = Instant::now();
    let ff = (orders > 0).then(|| FormFactors::new(mesh));
    let form_factors_s = t_ff.elapsed().as_secs_f64();
    let direct = irr::direct(mesh, sun_m);
    let scattered = match &ff {
        Some(ff) => irr::scattered(ff, &direct, rho, orders),
        None => vec![0.0; direct.len()],
    };
    let stats =
        (steps > 0).then(|| irr::rotation_stats(mesh, ff.as_ref(), sun_m, rho, orders, steps));

    // CSV, one row per facet, in W/m^2.
    let write_err = |e: String| AppError::Irradiance(format!("{}: {e}", out.display()));
    let mut csv =
        csv::Writer::from_path(out.join("irradiance.csv")).map_err(|e| write_err(e.to_string()))?;
    let mut header = vec![
        "facet",
        "x_m",
        "y_m",
        "z_m",
        "nx",
        "ny",
        "nz",
        "area_m2",
        "direct_w_m2",
        "scattered_w_m2",
        "total_w_m2",
    ];
    if stats.is_some() {
        header.extend(["mean_w_m2", "min_w_m2", "max_w_m2", "lit_fraction"]);
    }
    csv.write_record(&header)
        .map_err(|e| write_err(e.to_string()))?;
    let (c, n, a) = (mesh.centroids_m(), mesh.normals(), mesh.areas_m2());
    for i in 0..direct.len() {
        let mut row = vec![
            i.to_string(),
            c[i].x.to_string(),
            c[i].y.to_string(),
            c[i].z.to_string(),
            n[i].x.to_string(),
            n[i].y.to_string(),
            n[i].z.to_string(),
            a[i].to_string(),
            (solar * direct[i]).to_string(),
            (solar * scattered[i]).to_string(),
            (solar * (direct[i] + scattered[i])).to_string(),
        ];
        if let Some(s) = &stats {
            row.extend([
                (solar * s.mean[i]).to_string(),
                (solar * s.min[i]).to_string(),
                (solar * s.max[i]).to_string(),
                s.lit_fraction[i].to_string(),
            ]);
        }
        csv.write_record(&row)
            .map_err(|e| write_err(e.to_string()))?;
    }
    csv.flush().map_err(|e| write_err(e.to_string()))?;

    // PLY: the mesh with the same quantities as face properties (binary little-endian).
    let mut faces: Vec<(&str, Vec<f64>)> = vec![
        ("direct_w_m2", direct.iter().map(|x| solar * x).collect()),
        (
            "scattered_w_m2",
            scattered.iter().map(|x| solar * x).collect(),
        ),
    ];
    if let Some(s) = &stats {
        faces.push(("mean_w_m2", s.mean.iter().map(|x| solar * x).collect()));
        faces.push(("min_w_m2", s.min.iter().map(|x| solar * x).collect()));
        faces.push(("max_w_m2", s.max.iter().map(|x| solar * x).collect()));
        faces.push(("lit_fraction", s.lit_fraction.clone()));
    }
    let ply_path = out.join("irradiance.ply");
    let mut file = std::io::BufWriter::new(
        std::fs::File::create(&ply_path).map_err(|e| write_err(e.to_string()))?,
    );
    let mut ply = face_ply(mesh, &faces);
    ply_rs_bw::writer::Writer::new()
        .write_ply(&mut file, &mut ply)
        .map_err(|e| write_err(e.to_string()))?;

    let power = |e: &[f64]| solar * e.iter().zip(a).map(|(x, a)| x * a).sum::<f64>();
    Ok(IrradianceSummary {
        facets: direct.len(),
        solar_w_m2: solar,
        bond_albedo: rho,
        orders,
        pairs: ff.as_ref().map_or(0, |f| f.nonzeros()),
        capped_rows: ff.as_ref().map_or(0, |f| f.capped_rows),
        form_factors_s,
        form_factors_bytes: ff.as_ref().map_or(0, |f| f.heap_bytes()),
        direct_w: power(&direct),
        scattered_w: power(&scattered),
        steps,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// The mesh as PLY (vertices in metres) with `faces` as float face properties.
fn face_ply(mesh: &crate::body::Mesh, faces: &[(&str, Vec<f64>)]) -> Ply<DefaultElement> {
    let mut ply = Ply::<DefaultElement>::new();
    ply.header.encoding = Encoding::BinaryLittleEndian;
    ply.header
        .comments
        .push("optistim irradiance: face properties in W/m^2 (lit_fraction: 0..1)".into());
    let mut vertex = ElementDef::new("vertex".into());
    for k in ["x", "y", "z"] {
        vertex.properties.add(PropertyDef::new(
            k.into(),
            PropertyType::Scalar(ScalarType::Double),
        ));
    }
    ply.header.elements.add(vertex);
    let mut face = ElementDef::new("face".into());
    face.properties.add(PropertyDef::new(
        "vertex_indices".into(),
        PropertyType::List(ScalarType::UChar, ScalarType::UInt),
    ));
    for (name, _) in faces {
        face.properties.add(PropertyDef::new(
            (*name).into(),
            PropertyType::Scalar(ScalarType::Float),
        ));
    }
    ply.header.elements.add(face);
    let vertices = mesh
        .vertices_m()
        .iter()
        .map(|v| {
            let mut e = DefaultElement::new();
            e.insert("x".into(), Property::Double(v.x));
            e.insert("y".into(), Property::Double(v.y));
            e.insert("z".into(), Property::Double(v.z));
            e
        })
        .collect();
    ply.payload.insert("vertex".into(), vertices);
    let facets = mesh
        .facets()
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let mut e = DefaultElement::new();
            e.insert("vertex_indices".into(), Property::ListUInt(f.to_vec()));
            for (name, values) in faces {
                e.insert((*name).into(), Property::Float(values[i] as f32));
            }
            e
        })
        .collect();
    ply.payload.insert("face".into(), facets);
    ply
}
