//! Scene files as written (serde, TOML). Unknown keys are errors, so a typo never silently
//! falls back to a default. Validation and unit conversion happen in [`super`] (`config/mod.rs`).

use serde::Deserialize;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawScene {
    pub sun: RawSun,
    /// `[body]`, or `[[body]]` once per body (the first is the one the pose is written in).
    #[serde(deserialize_with = "one_or_many")]
    pub body: Vec<RawBody>,
    pub camera: RawCamera,
    pub pose: RawPose,
    #[serde(default)]
    pub render: RawRender,
    pub stimulator: Option<RawStimulator>,
    pub corto: Option<RawCorto>,
}

/// `[corto]`: how CORTO's poses (Blender units, Blender's camera) map onto the scene.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawCorto {
    /// Metres per Blender unit.
    pub metres_per_unit: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawSun {
    /// `"blackbody"` or `"tabulated"`.
    pub spectrum: String,
    pub temperature_k: Option<f64>,
    pub radius_m: Option<f64>,
    /// Rescale the black body so that its total irradiance at 1 AU is this [W/m^2].
    pub irradiance_at_1au_w_m2: Option<f64>,
    pub wavelength_nm: Option<Vec<f64>>,
    pub irradiance_w_m2_nm: Option<Vec<f64>>,
    /// Distance from the Sun at which the tabulated irradiance holds [m] (default 1 AU).
    pub distance_m: Option<f64>,
    /// Sun position relative to the body centre, body frame [m].
    pub position_m: [f64; 3],
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawBody {
    #[serde(default = "default_name")]
    pub name: String,
    #[serde(default = "default_shape")]
    pub shape: String,
    /// The sphere's radius (and a DEM's reference) [m].
    pub radius_m: Option<f64>,
    /// The ellipsoid's semi-axes along body +X, +Y, +Z [m].
    pub semi_axes_m: Option<[f64; 3]>,
    pub brdf: String,
    pub albedo: f64,
    pub albedo_type: String,
    pub roughness_rad: Option<f64>,
    pub shininess: Option<f64>,
    pub diffuse_weight: Option<f64>,
    pub specular_weight: Option<f64>,
    /// Hapke's parameters after `w`, in the reference configs' order:
    /// `[b, c, B0_C, h_C, B0_S, h_S, theta (rad), filling_factor]`.
    pub hapke: Option<Vec<f64>>,
    pub albedo_map: Option<RawMap>,
    /// Maps of their own for some of the camera's bands: `[[body.band_map]]` tables.
    #[serde(default)]
    pub band_map: Vec<RawBandMap>,
    /// The albedo's spectral shape: `{ table = "moon", reference_nm = 549 }` or
    /// `{ wavelength_nm = [...], value = [...], reference_nm = ... }`.
    pub reflectance_spectrum: Option<RawSpectrum>,
    /// Heights above `radius_m` (after the encoding: metres; the shared LOLA DEM is in km,
    /// so `scale = 1000`).
    pub dem_map: Option<RawMap>,
    /// Elevation angle of the local horizon [rad] per texel (needs `dem_map`).
    pub horizon_map: Option<RawMap>,
    /// The horizon computed from `dem_map` itself in this many azimuths, instead of a
    /// `horizon_map`.
    pub horizon_azimuths: Option<u32>,
    /// What the DEM's values are: `height` above `radius_m` (default) or `radius` from the
    /// centre (a Vesta-like shape model).
    pub dem_values: Option<String>,
    /// A normal map (RGB; `scale = 2, shift = -1` for integer encodings of `(n + 1) / 2`).
    pub normal_map: Option<RawMap>,
    /// The normal map's frame: `local` (x east, y north, z up; default) or `body`.
    pub normal_frame: Option<String>,
    /// Whether the DEM displaces the surface (default false: it only tilts the normals).
    #[serde(default)]
    pub displacement: bool,
    /// `shape = "mesh"`: the mesh file and its units.
    pub mesh: Option<RawMesh>,
    /// A second or later `[[body]]`: its centre in the first body's frame [m].
    pub position_m: Option<[f64; 3]>,
    /// A second or later `[[body]]`: the rotation taking its frame's vectors into the first
    /// body's frame, scalar first (default: none).
    pub attitude_wxyz: Option<[f64; 4]>,
}

/// `[body]` (one table) or `[[body]]` (an array of tables), each checked as a `RawBody`.
fn one_or_many<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Vec<RawBody>, D::Error> {
    use serde::de::Error;
    match toml::Value::deserialize(d)? {
        v @ toml::Value::Table(_) => RawBody::deserialize(v)
            .map(|b| vec![b])
            .map_err(D::Error::custom),
        v @ toml::Value::Array(_) => {
            let many = Vec::<RawBody>::deserialize(v).map_err(D::Error::custom)?;
            if many.is_empty() {
                return Err(D::Error::custom("[[body]]: at least one body"));
            }
            Ok(many)
        }
        _ => Err(D::Error::custom("body: a [body] table or [[body]] tables")),
    }
}

/// `[body.mesh]`: an OBJ, PLY or STL file (`docs/scene.md`, "Meshes").
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawMesh {
    pub path: String,
    /// The file's length unit: `m` or `km`, or `metres_per_unit` instead.
    pub units: Option<String>,
    pub metres_per_unit: Option<f64>,
    /// Rotation from the file's axes to the body frame, scalar first (default: none).
    pub body_from_file_wxyz: Option<[f64; 4]>,
}

/// One band's own albedo map: `band = "R"`, `map = { path = ..., ... }` (the encoding of
/// `albedo_map`), and for an RGB file the `channel` (0, 1, 2) to read; else the channels' mean.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawBandMap {
    pub band: String,
    pub map: RawMap,
    pub channel: Option<usize>,
}

/// A texture map and its encoding (`docs/scene.md`, `body::maps::Encoding`).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawMap {
    pub path: String,
    pub gamma: Option<f64>,
    pub domain: Option<[f64; 2]>,
    pub scale: Option<f64>,
    pub shift: Option<f64>,
    pub mean: Option<f64>,
    pub lon_limits_deg: Option<[f64; 2]>,
    pub lat_limits_deg: Option<[f64; 2]>,
}

fn default_name() -> String {
    "body".into()
}
fn default_shape() -> String {
    "sphere".into()
}

#[derive(Debug, Deserialize)]
#[serde(untagged)]
pub enum OneOrTwo {
    One(f64),
    Two([f64; 2]),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawCurve {
    pub wavelength_nm: Vec<f64>,
    pub value: Vec<f64>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawDistortion {
    #[serde(default)]
    pub k1: f64,
    #[serde(default)]
    pub k2: f64,
    #[serde(default)]
    pub k3: f64,
    #[serde(default)]
    pub p1: f64,
    #[serde(default)]
    pub p2: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawCamera {
    pub resolution_px: [i64; 2],
    pub pixel_pitch_m: OneOrTwo,
    pub focal_length_m: f64,
    pub f_number: f64,
    pub principal_point_px: Option<[f64; 2]>,
    #[serde(default)]
    pub skew_px: f64,
    #[serde(default)]
    pub distortion: RawDistortion,
    pub exposure_s: f64,
    pub full_well_e: f64,
    pub adc_gain_dn_per_e: f64,
    #[serde(default)]
    pub offset_dn: f64,
    pub bit_depth: i64,
    /// The camera's output depth: the ADC's most significant bits (`bit_depth` when absent).
    pub saved_bit_depth: Option<i64>,
    /// A monochrome camera's QE (or `[[camera.band]]`).
    pub qe: Option<RawCurve>,
    /// The optics' transmittance (every band's, unless the band has its own).
    pub transmittance: Option<RawCurve>,
    /// The camera's wavebands, each with its own QE (instead of `qe`).
    #[serde(default)]
    pub band: Vec<RawBand>,
    /// A Bayer mosaic over three bands R, G, B (in `[[camera.band]]` order): `RGGB`, `BGGR`,
    /// `GRBG` or `GBRG`. Without it every band is a full image.
    pub mosaic: Option<String>,
    /// Gaussian PSF of the optics (and seeing) [px], applied to the camera's own images only.
    #[serde(default)]
    pub psf_sigma_px: f64,
    /// Band for `power.fits` [nm]; the whole spectrum when absent.
    pub power_band_nm: Option<[f64; 2]>,
    #[serde(default)]
    pub noise: RawNoise,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawBand {
    pub name: String,
    pub qe: RawCurve,
    pub transmittance: Option<RawCurve>,
    /// Longitudinal chromatic aberration: this band's Gaussian PSF [px].
    pub psf_sigma_px: Option<f64>,
    /// Lateral chromatic aberration: this band's Brown coefficients.
    pub distortion: Option<RawDistortion>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawSpectrum {
    /// A built-in spectrum: `moon` (Velikodsky et al. 2011, the average Moon).
    pub table: Option<String>,
    pub wavelength_nm: Option<Vec<f64>>,
    pub value: Option<Vec<f64>>,
    /// Where the albedo (and its map) holds [nm].
    pub reference_nm: f64,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawNoise {
    #[serde(default)]
    pub seed: u64,
    #[serde(default)]
    pub shot: bool,
    pub prnu_sigma: Option<f64>,
    pub dark_current_e_per_s: Option<f64>,
    pub dark_fpn_sigma: Option<f64>,
    pub readout_sigma_e: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawPose {
    #[serde(default)]
    pub frame_id: u64,
    pub camera_position_m: [f64; 3],
    /// Unit quaternion (w, x, y, z), scalar first, Hamilton, camera -> body.
    pub attitude_wxyz: Option<[f64; 4]>,
    /// Point the boresight at the body centre with image down along the projected body -Z.
    #[serde(default)]
    pub look_at_body: bool,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawRender {
    pub preset: Option<String>,
    pub points: Option<f64>,
    pub points_per_pixel: Option<f64>,
    pub max_points: Option<f64>,
    pub sampling: Option<String>,
    pub split: Option<String>,
    pub integration: Option<String>,
    pub trapezoid_points_per_deg: Option<f64>,
    pub trapezoid_points_per_px: Option<f64>,
    pub boundary_nodes: Option<i64>,
    pub min_points: Option<i64>,
    pub fov: Option<String>,
    pub gridding: Option<String>,
    pub gaussian_window_px: Option<i64>,
    pub gaussian_sigma_px: Option<f64>,
    pub supersampling: Option<i64>,
    pub reconstruction: Option<String>,
    pub lanczos_a: Option<i64>,
    pub reconstruction_sigma_px: Option<f64>,
    pub antialias_sigma_px: Option<f64>,
    pub threads: Option<i64>,
    pub bounding_tolerance_rad: Option<f64>,
    pub depth: Option<bool>,
    pub self_shadowing: Option<String>,
    pub map_filter: Option<String>,
    pub relief_refine: Option<i64>,
    pub map_read_spacing_texels: Option<f64>,
    /// Mesh bodies: rays per pixel side, everywhere and at edges.
    pub raycast_samples: Option<i64>,
    pub raycast_edge_samples: Option<i64>,
    /// Mesh bodies: a large facet's light interpolated (true, default) or evaluated per sample.
    pub raycast_quadratic_light: Option<bool>,
    /// A mesh body alone through a pinhole: each facet's lit and seen part clipped exactly
    /// (no edge rays).
    pub raycast_clip: Option<bool>,
    /// Mesh bodies: orders of scattered light in the image (0: none).
    pub scattering_orders: Option<i64>,
    /// `fixed` (default: these settings for every frame) or `budget` (per frame, the
    /// cheapest settings predicted to meet `[render.budget]`).
    pub fidelity: Option<String>,
    pub budget: Option<RawBudget>,
}

/// `[render.budget]`: relative errors per lit pixel and in total, and the error model.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawBudget {
    pub median: Option<f64>,
    pub p99: Option<f64>,
    pub total: Option<f64>,
    /// An error model fitted by `optistim sweep --fit` (default: the shipped one).
    pub model: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawStimulator {
    /// Calibration curve CSV, relative to the scene file's folder.
    pub calibration: String,
    pub interpolation: Option<String>,
    pub screen_bit_depth: Option<u32>,
    pub dither: Option<String>,
    pub screen_resolution_px: [u32; 2],
    pub screen_pixel_pitch_m: f64,
    pub region_origin_px: Option<[u32; 2]>,
    pub mapping: Option<String>,
    pub collimator_focal_length_m: f64,
    pub collimator_transmittance: Option<f64>,
    /// The simulated camera's screen: its true response (default: the calibration) and the
    /// gain at the region's corners (default 1, uniform).
    pub true_response: Option<String>,
    pub screen_corner_gain: Option<f64>,
    pub screen_non_uniformity_map: Option<String>,
}
