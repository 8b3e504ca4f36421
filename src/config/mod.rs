//! Scene configuration: TOML files go from *as written* ([`raw`]) to *validated*
//! ([`Config`]: a [`Scene`], a [`Pose`] and render [`Settings`]). Every error names the file,
//! the key, the value and what is allowed. The full format is documented in `docs/scene.md`.

pub mod raw;

use crate::body::{Body, Shape, Sphere};
use crate::brdf::{
    AlbedoType, Area, Brdf, Hapke, HapkeParams, Lambert, LommelSeeliger, OrenNayar, Phong, Specular,
};
use crate::camera::{Brown, Intrinsics};
use crate::detector::noise::{DarkCurrent, Noise, Prnu, Readout, Shot};
use crate::detector::{Band, Bayer, Detector, Layout};
use crate::geometry::{body_from_camera_wxyz, look_at};
use crate::radiometry::{AU, Reflectance, SpectralTable, SunSpectrum};
use crate::render::gridding::Gridding;
use crate::render::integration::Method;
use crate::render::reconstruction::Reconstruction;
use crate::render::{FovShape, Integration, PointBudget, Sampling, Settings, Split};
use crate::scene::{Camera, Pose, Scene};
use crate::stimulator::StimulatorConfig;
use crate::stimulator::calibration::Interp;
use crate::stimulator::dither::Dither;
use crate::stimulator::screen::Resampler;
use glam::DVec3;
use raw::*;
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("{file}: cannot read: {source}")]
    Read {
        file: String,
        source: std::io::Error,
    },
    #[error("{file}: {message}")]
    Parse { file: String, message: String },
    /// A file the scene names lies outside the folders a scene loaded over the network may
    /// read (`optistim serve --scene-dir`).
    #[error("{file}: {key} = {path:?}: {reason}")]
    Confined {
        file: String,
        key: String,
        path: String,
        reason: String,
    },
    #[error("{file}: {key} = {value}: {allowed}")]
    Invalid {
        file: String,
        key: String,
        value: String,
        allowed: String,
    },
}

/// A validated scene file.
#[derive(Clone, Debug)]
pub struct Config {
    pub scene: Scene,
    pub pose: Pose,
    pub settings: Settings,
    /// Band of `power.fits` [m]; `None` for the whole spectrum.
    pub power_band_m: Option<(f64, f64)>,
    /// The `[stimulator]` section, when there is one.
    pub stimulator: Option<StimulatorConfig>,
    /// `[render] fidelity = "budget"`: the budget and the error model the planner meets it
    /// with (`None`: the settings above for every frame).
    pub fidelity: Option<BudgetFidelity>,
    /// The `[corto]` section: metres per Blender unit of CORTO's poses.
    pub corto_metres_per_unit: Option<f64>,
}

/// Error-budgeted fidelity ([`crate::fidelity::budget`]).
#[derive(Clone, Debug, PartialEq)]
pub struct BudgetFidelity {
    pub budget: crate::fidelity::budget::Budget,
    pub model: crate::fidelity::budget::ErrorModel,
}

impl Config {
    /// The frame planner of `fidelity = "budget"` (`None` for fixed settings).
    pub fn planner(&self) -> Option<crate::fidelity::budget::Planner> {
        self.fidelity.as_ref().map(|f| {
            crate::fidelity::budget::Planner::new(
                &self.scene,
                &self.settings,
                f.budget,
                f.model.clone(),
            )
        })
    }

    /// [`Config::planner`], or, for a file without `fidelity = "budget"`, a planner with the
    /// default budget and the shipped error model: what a check or a plan of the file's
    /// frames would hold them to.
    pub fn planner_or_default(
        &self,
    ) -> Result<crate::fidelity::budget::Planner, crate::fidelity::budget::ModelError> {
        use crate::fidelity::budget::{Budget, ErrorModel, Planner};
        match self.planner() {
            Some(p) => Ok(p),
            None => Ok(Planner::new(
                &self.scene,
                &self.settings,
                Budget::default(),
                ErrorModel::shipped()?,
            )),
        }
    }
}

/// A setting as the scene file spells it (`"ray_marching"`, `"pixel"`, `"lockstep"`): the
/// serde name of a unit variant, empty for anything else.
pub fn spelled<T: serde::Serialize>(value: &T) -> String {
    serde_json::to_value(value)
        .ok()
        .and_then(|v| v.as_str().map(str::to_string))
        .unwrap_or_default()
}

/// Reads and validates a scene file.
pub fn load(path: &Path) -> Result<Config, ConfigError> {
    let (file, text) = read(path)?;
    parse(&text, &file)
}

/// A scene file's name (as errors give it) and text.
fn read(path: &Path) -> Result<(String, String), ConfigError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
        file: file.clone(),
        source,
    })?;
    Ok((file, text))
}

/// [`load`] with `render` (TOML, the keys of a `[render]` table) over the file's `[render]`:
/// a setting changed for one run without a copy of the file (`optistim verify-budget
/// --render`, whose references, keyed by the file's own text, are then reused).
pub fn load_with_render(path: &Path, render: &str) -> Result<Config, ConfigError> {
    let (file, text) = read(path)?;
    if render.trim().is_empty() {
        return parse(&text, &file);
    }
    let table = |text: &str, file: &str| {
        toml::from_str::<toml::Table>(text).map_err(|e| ConfigError::Parse {
            file: file.to_string(),
            message: e.to_string().trim_end().to_string(),
        })
    };
    let mut scene = table(&text, &file)?;
    let mut patch = toml::Table::new();
    patch.insert(
        "render".into(),
        toml::Value::Table(table(render, "--render")?),
    );
    merge_toml(&mut scene, &patch);
    let text = toml::to_string(&scene).map_err(|e| ConfigError::Parse {
        file: file.clone(),
        message: e.to_string(),
    })?;
    parse(&text, &file)
}

/// Deep-merges `patch` into `base` (tables merge key by key; anything else is replaced).
pub fn merge_toml(base: &mut toml::Table, patch: &toml::Table) {
    for (k, v) in patch {
        match (base.get_mut(k), v) {
            (Some(toml::Value::Table(b)), toml::Value::Table(p)) => merge_toml(b, p),
            _ => {
                base.insert(k.clone(), v.clone());
            }
        }
    }
}

/// Parses and validates scene text; `file` names it in errors.
pub fn parse(text: &str, file: &str) -> Result<Config, ConfigError> {
    let raw: RawScene = toml::from_str(text).map_err(|e| ConfigError::Parse {
        file: file.to_string(),
        message: e.to_string().trim_end().to_string(),
    })?;
    Validator { file, allow: None }.scene(raw)
}

/// What a scene from an untrusted source may read: `Ok` for a file it may, or why not.
pub type FileGuard<'a> = &'a dyn Fn(&Path) -> Result<(), String>;

/// [`parse`] for a scene named by a client: every file it names (maps, curves, the error
/// model) must pass `allow` before it is read, and a parse error says where, never what the
/// text there is (the file may not be a scene at all).
pub fn parse_confined(text: &str, file: &str, allow: FileGuard) -> Result<Config, ConfigError> {
    let raw: RawScene = toml::from_str(text).map_err(|e| ConfigError::Parse {
        file: file.to_string(),
        message: match e.span() {
            Some(span) => {
                let line = text[..span.start.min(text.len())].matches('\n').count() + 1;
                format!("not a valid scene (TOML error on line {line})")
            }
            None => "not a valid scene".to_string(),
        },
    })?;
    Validator {
        file,
        allow: Some(allow),
    }
    .scene(raw)
}

struct Validator<'a> {
    file: &'a str,
    allow: Option<FileGuard<'a>>,
}

type R<T> = Result<T, ConfigError>;

impl Validator<'_> {
    fn err<T>(&self, key: &str, value: impl std::fmt::Debug, allowed: &str) -> R<T> {
        Err(ConfigError::Invalid {
            file: self.file.to_string(),
            key: key.to_string(),
            value: format!("{value:?}"),
            allowed: allowed.to_string(),
        })
    }
    fn positive(&self, key: &str, x: f64) -> R<f64> {
        if x.is_finite() && x > 0.0 {
            Ok(x)
        } else {
            self.err(key, x, "a finite number > 0")
        }
    }
    fn non_negative(&self, key: &str, x: f64) -> R<f64> {
        if x.is_finite() && x >= 0.0 {
            Ok(x)
        } else {
            self.err(key, x, "a finite number >= 0")
        }
    }
    fn in_range(&self, key: &str, x: f64, lo: f64, hi: f64) -> R<f64> {
        if x.is_finite() && x >= lo && x <= hi {
            Ok(x)
        } else {
            self.err(key, x, &format!("a number in [{lo}, {hi}]"))
        }
    }
    fn finite3(&self, key: &str, v: [f64; 3]) -> R<DVec3> {
        if v.iter().all(|x| x.is_finite()) {
            Ok(DVec3::from_array(v))
        } else {
            self.err(key, v, "three finite numbers [m]")
        }
    }
    fn choice<'s>(&self, key: &str, value: &'s str, allowed: &[&str]) -> R<&'s str> {
        if allowed.contains(&value) {
            Ok(value)
        } else {
            self.err(key, value, &format!("one of {}", allowed.join(", ")))
        }
    }
    /// The value named `value` among `options` (name, value), or an error listing the names.
    fn pick<T: Copy>(&self, key: &str, value: &str, options: &[(&str, T)]) -> R<T> {
        match options.iter().find(|(name, _)| *name == value) {
            Some(&(_, v)) => Ok(v),
            None => {
                let names: Vec<&str> = options.iter().map(|o| o.0).collect();
                self.err(key, value, &format!("one of {}", names.join(", ")))
            }
        }
    }
    fn need<T>(&self, key: &str, v: Option<T>, why: &str) -> R<T> {
        match v {
            Some(x) => Ok(x),
            None => Err(ConfigError::Invalid {
                file: self.file.to_string(),
                key: key.to_string(),
                value: "(missing)".into(),
                allowed: why.to_string(),
            }),
        }
    }
    fn table(
        &self,
        key: &str,
        wl_nm: &[f64],
        value: &[f64],
        range: (f64, f64),
    ) -> R<SpectralTable> {
        let wl: Vec<f64> = wl_nm.iter().map(|x| x * 1e-9).collect();
        SpectralTable::new(wl, value.to_vec(), range).map_err(|e| ConfigError::Invalid {
            file: self.file.to_string(),
            key: key.to_string(),
            value: format!("{} points", value.len()),
            allowed: e.to_string(),
        })
    }

    fn scene(&self, raw: RawScene) -> R<Config> {
        let sun = self.sun(&raw.sun)?;
        let sun_position_m = self.finite3("sun.position_m", raw.sun.position_m)?;
        let (camera, power_band_m) = self.camera(&raw.camera)?;
        let band_names: Vec<&str> = camera
            .detector
            .bands
            .iter()
            .map(|b| b.name.as_str())
            .collect();
        let body = self.body(&raw.body[0], &band_names)?;
        if sun_position_m.length() <= body.shape.bounding_radius_m() {
            return self.err(
                "sun.position_m",
                raw.sun.position_m,
                "a point outside the body",
            );
        }
        if raw.body[0].position_m.is_some() || raw.body[0].attitude_wxyz.is_some() {
            return self.err(
                "body.position_m",
                "given on the first body",
                "absent on the first body: its frame is the scene's (the pose's)",
            );
        }
        let mut others = Vec::new();
        for (k, b) in raw.body.iter().enumerate().skip(1) {
            others.push(self.placed(k, b, &body, &others, sun_position_m)?);
            // One (P/L) image serves every band only while the bodies share one spectrum.
            if others[k - 1].body.spectrum != body.spectrum {
                return self.err(
                    &format!("body[{k}].reflectance_spectrum"),
                    "(differs from the first body's)",
                    "the same spectral shape as the first body's (or none on both)",
                );
            }
        }
        let pose = self.pose(&raw.pose, sun_position_m, &body)?;
        let settings = self.render(&raw.render, &body)?;
        if let Some(allowed) = settings.map_filter.refusal(&body) {
            return self.err(
                "render.map_filter",
                format!("{:?}", settings.map_filter).to_lowercase(),
                allowed,
            );
        }
        let stimulator = match &raw.stimulator {
            Some(st) => Some(self.stimulator(st, &camera.intrinsics)?),
            None => None,
        };
        let fidelity = self.fidelity(&raw.render)?;
        let corto_metres_per_unit = match &raw.corto {
            Some(c) => Some(self.positive("corto.metres_per_unit", c.metres_per_unit)?),
            None => None,
        };
        Ok(Config {
            scene: Scene {
                sun,
                body,
                others,
                camera,
            },
            pose,
            settings,
            power_band_m,
            stimulator,
            fidelity,
            corto_metres_per_unit,
        })
    }

    /// `[render] fidelity` and `[render.budget]`.
    fn fidelity(&self, r: &RawRender) -> R<Option<BudgetFidelity>> {
        use crate::fidelity::budget::{Budget, ErrorModel};
        let budget_mode = match r.fidelity.as_deref() {
            None => false,
            Some(v) => self.pick("render.fidelity", v, &[("fixed", false), ("budget", true)])?,
        };
        if !budget_mode {
            if r.budget.is_some() {
                return self.err(
                    "render.budget",
                    "a table",
                    "only with render.fidelity = \"budget\"",
                );
            }
            return Ok(None);
        }
        let d = Budget::default();
        let raw = r.budget.as_ref();
        let figure = |key: &str, v: Option<f64>, default: f64| match v {
            Some(x) => self.in_range(key, x, 1e-12, 1.0),
            None => Ok(default),
        };
        let budget = Budget {
            median: figure("render.budget.median", raw.and_then(|b| b.median), d.median)?,
            p99: figure("render.budget.p99", raw.and_then(|b| b.p99), d.p99)?,
            total: figure("render.budget.total", raw.and_then(|b| b.total), d.total)?,
        };
        let model = match raw.and_then(|b| b.model.as_deref()) {
            None => ErrorModel::shipped(),
            Some(m) => {
                let path = self.path("render.budget.model", m)?;
                match std::fs::read_to_string(&path) {
                    Ok(text) => ErrorModel::parse(&text, &path.display().to_string()),
                    Err(e) => return self.err("render.budget.model", m, &e.to_string()),
                }
            }
        }
        .map_err(|e| ConfigError::Invalid {
            file: self.file.to_string(),
            key: "render.budget.model".into(),
            value: "the error model".into(),
            allowed: e.to_string(),
        })?;
        Ok(Some(BudgetFidelity { budget, model }))
    }

    /// A path in the file (at `key`), relative to the file's folder (`join` keeps an absolute
    /// one); refused when the scene is confined and the path lies outside what it may read.
    fn path(&self, key: &str, p: &str) -> R<PathBuf> {
        if p.starts_with(crate::stimulator::calibration::BUILTIN) {
            return Ok(PathBuf::from(p));
        }
        let path = Path::new(self.file)
            .parent()
            .map_or_else(|| PathBuf::from(p), |d| d.join(p));
        if let Some(allow) = self.allow {
            allow(&path).map_err(|reason| ConfigError::Confined {
                file: self.file.to_string(),
                key: key.to_string(),
                path: p.to_string(),
                reason,
            })?;
        }
        Ok(path)
    }

    /// `body.hapke = [b, c, B0_C, h_C, B0_S, h_S, theta_rad, filling_factor]`, each in its
    /// domain (`w` comes from the albedo).
    fn hapke(&self, b: &RawBody) -> R<Hapke> {
        let p = self.need(
            "body.hapke",
            b.hapke.clone(),
            "required for brdf = \"hapke\": [b, c, B0_C, h_C, B0_S, h_S, theta_rad, \
             filling_factor]",
        )?;
        if p.len() != 8 {
            return self.err(
                "body.hapke",
                format!("{} values", p.len()),
                "8 values: [b, c, B0_C, h_C, B0_S, h_S, theta_rad, filling_factor]",
            );
        }
        let check = |i: usize, name: &str, lo: f64, hi: f64, open_hi: bool| {
            let v = p[i];
            let ok = v.is_finite() && v >= lo && if open_hi { v < hi } else { v <= hi };
            if ok {
                Ok(v)
            } else {
                let bracket = if open_hi { ")" } else { "]" };
                self.err(
                    "body.hapke",
                    format!("{name} = {v}"),
                    &format!("{name} in [{lo}, {hi}{bracket}"),
                )
            }
        };
        let positive = |i: usize, name: &str| {
            let v = p[i];
            if v.is_finite() && v > 0.0 {
                Ok(v)
            } else {
                self.err(
                    "body.hapke",
                    format!("{name} = {v}"),
                    &format!("{name} > 0"),
                )
            }
        };
        Ok(Hapke::new(
            1.0,
            HapkeParams {
                b: check(0, "b", 0.0, 1.0, true)?,
                c: check(1, "c (back-lobe weight)", 0.0, 1.0, false)?,
                b0_c: check(2, "B0_C", 0.0, 10.0, false)?,
                h_c: positive(3, "h_C")?,
                b0_s: check(4, "B0_S", 0.0, 10.0, false)?,
                h_s: positive(5, "h_S")?,
                theta_rad: check(6, "theta_rad", 0.0, std::f64::consts::FRAC_PI_2, true)?,
                filling_factor: check(7, "filling_factor", 0.0, 0.752, true)?,
            },
        ))
    }

    fn stimulator(&self, s: &RawStimulator, cam: &Intrinsics) -> R<StimulatorConfig> {
        let interp = match self.choice(
            "stimulator.interpolation",
            s.interpolation.as_deref().unwrap_or("pchip"),
            &["linear", "pchip"],
        )? {
            "linear" => Interp::Linear,
            _ => Interp::Pchip,
        };
        let bits = s.screen_bit_depth.unwrap_or(10);
        if bits != 8 && bits != 10 {
            return self.err("stimulator.screen_bit_depth", bits, "8 or 10");
        }
        let dither = match self.choice(
            "stimulator.dither",
            s.dither.as_deref().unwrap_or("none"),
            &["none", "ordered", "blue_noise"],
        )? {
            "ordered" => Dither::Ordered,
            "blue_noise" => Dither::BlueNoise,
            _ => Dither::None,
        };
        let screen = s.screen_resolution_px;
        if screen.iter().any(|&n| n == 0 || n > 16384) {
            return self.err(
                "stimulator.screen_resolution_px",
                screen,
                "two integers in [1, 16384]",
            );
        }
        let pitch = self.positive("stimulator.screen_pixel_pitch_m", s.screen_pixel_pitch_m)?;
        let f_col = self.positive(
            "stimulator.collimator_focal_length_m",
            s.collimator_focal_length_m,
        )?;
        let t_col = s.collimator_transmittance.unwrap_or(1.0);
        if !(t_col > 0.0 && t_col <= 1.0) {
            return self.err(
                "stimulator.collimator_transmittance",
                t_col,
                "a number in (0, 1]",
            );
        }
        let corner_gain = self.in_range(
            "stimulator.screen_corner_gain",
            s.screen_corner_gain.unwrap_or(1.0),
            0.01,
            2.0,
        )?;
        // Camera pixels per screen pixel (stimulator::screen).
        let scale = [0, 1].map(|a| (pitch / f_col) / (cam.pixel_pitch_m[a] / cam.focal_length_m));
        let scale = match self.choice(
            "stimulator.mapping",
            s.mapping.as_deref().unwrap_or("one_to_one"),
            &["one_to_one", "area"],
        )? {
            "one_to_one" => {
                if scale.iter().any(|x| (x - 1.0).abs() > 1e-6) {
                    return self.err(
                        "stimulator.mapping",
                        "one_to_one",
                        &format!(
                            "\"area\", or a screen pitch and collimator focal length giving one \
                             camera pixel per screen pixel (they give {:.6} x {:.6})",
                            scale[0], scale[1]
                        ),
                    );
                }
                [1.0, 1.0]
            }
            _ => scale,
        };
        let region =
            Resampler::region_px_for([cam.width_px as usize, cam.height_px as usize], scale);
        let screen_px = [screen[0] as usize, screen[1] as usize];
        let origin_px = match s.region_origin_px {
            Some(o) => [o[0] as usize, o[1] as usize],
            None => [0, 1].map(|a| screen_px[a].saturating_sub(region[a]) / 2),
        };
        if (0..2).any(|a| origin_px[a] + region[a] > screen_px[a]) {
            return self.err(
                "stimulator.region_origin_px",
                origin_px,
                &format!(
                    "a region of {} x {} screen px inside the {} x {} screen",
                    region[0], region[1], screen_px[0], screen_px[1]
                ),
            );
        }
        Ok(StimulatorConfig {
            calibration: self.path("stimulator.calibration", &s.calibration)?,
            interp,
            screen_bits: bits,
            dither,
            screen_px,
            origin_px,
            scale,
            collimator_transmittance: t_col,
            true_response: s
                .true_response
                .as_deref()
                .map(|p| self.path("stimulator.true_response", p))
                .transpose()?,
            corner_gain,
            non_uniformity_map: s
                .screen_non_uniformity_map
                .as_deref()
                .map(|p| self.path("stimulator.screen_non_uniformity_map", p))
                .transpose()?,
        })
    }

    fn sun(&self, s: &RawSun) -> R<SunSpectrum> {
        match self.choice("sun.spectrum", &s.spectrum, &["blackbody", "tabulated"])? {
            "blackbody" => {
                let temperature_k =
                    self.positive("sun.temperature_k", s.temperature_k.unwrap_or(5782.0))?;
                let radius_m = self.positive("sun.radius_m", s.radius_m.unwrap_or(6.957e8))?;
                let mut sun = SunSpectrum::BlackBody {
                    temperature_k,
                    radius_m,
                    scale: 1.0,
                };
                if let Some(f) = s.irradiance_at_1au_w_m2 {
                    let f = self.positive("sun.irradiance_at_1au_w_m2", f)?;
                    sun = SunSpectrum::BlackBody {
                        temperature_k,
                        radius_m,
                        scale: f / sun.irradiance_at(AU),
                    };
                }
                Ok(sun)
            }
            _ => {
                let wl = self.need(
                    "sun.wavelength_nm",
                    s.wavelength_nm.as_ref(),
                    "required for spectrum = \"tabulated\"",
                )?;
                let irr = self.need(
                    "sun.irradiance_w_m2_nm",
                    s.irradiance_w_m2_nm.as_ref(),
                    "required for spectrum = \"tabulated\"",
                )?;
                // W m^-2 nm^-1 -> W m^-2 m^-1.
                let per_m: Vec<f64> = irr.iter().map(|x| x * 1e9).collect();
                let table =
                    self.table("sun.irradiance_w_m2_nm", wl, &per_m, (0.0, f64::INFINITY))?;
                let distance_m = self.positive("sun.distance_m", s.distance_m.unwrap_or(AU))?;
                let radius_m = self.positive("sun.radius_m", s.radius_m.unwrap_or(6.957e8))?;
                Ok(SunSpectrum::Tabulated {
                    irradiance: table,
                    distance_m,
                    radius_m,
                })
            }
        }
    }

    /// The body of `b`; `bands` names the camera's bands (for `[[body.band_map]]`).
    fn body(&self, b: &RawBody, bands: &[&str]) -> R<Body> {
        let (shape, radius_m) =
            match self.choice("body.shape", &b.shape, &["sphere", "ellipsoid", "mesh"])? {
                "mesh" => {
                    let mesh = self.mesh(b)?;
                    let r = mesh.bounding_radius_m();
                    (Shape::Mesh(std::sync::Arc::new(mesh)), r)
                }
                "ellipsoid" => {
                    let axes = self.need(
                        "body.semi_axes_m",
                        b.semi_axes_m,
                        "required for shape = \"ellipsoid\": [a, b, c] along body X, Y, Z",
                    )?;
                    for (k, v) in axes.iter().enumerate() {
                        self.positive(&format!("body.semi_axes_m[{k}]"), *v)?;
                    }
                    if b.radius_m.is_some() {
                        return self.err(
                            "body.radius_m",
                            b.radius_m,
                            "absent for an ellipsoid (its size is semi_axes_m)",
                        );
                    }
                    let e = crate::body::Ellipsoid {
                        semi_axes_m: glam::DVec3::from_array(axes),
                    };
                    (Shape::Ellipsoid(e), e.max_axis_m())
                }
                _ => {
                    let r = self.need("body.radius_m", b.radius_m, "required for a sphere")?;
                    let radius_m = self.positive("body.radius_m", r)?;
                    (Shape::Sphere(Sphere { radius_m }), radius_m)
                }
            };
        let unit = |key: &str, v: Option<f64>, default: f64| {
            self.in_range(key, v.unwrap_or(default), 0.0, 1.0)
        };
        let brdf = match self.choice(
            "body.brdf",
            &b.brdf,
            &[
                "lambert",
                "area",
                "lommel_seeliger",
                "oren_nayar",
                "specular",
                "phong",
                "hapke",
            ],
        )? {
            "hapke" => Brdf::Hapke(self.hapke(b)?),
            "lambert" => Brdf::Lambert(Lambert { rho: 1.0 }),
            "area" => Brdf::Area(Area { rho: 1.0 }),
            "lommel_seeliger" => Brdf::LommelSeeliger(LommelSeeliger { w: 1.0 }),
            "oren_nayar" => Brdf::OrenNayar(OrenNayar {
                rho: 1.0,
                sigma_rad: self.in_range(
                    "body.roughness_rad",
                    self.need(
                        "body.roughness_rad",
                        b.roughness_rad,
                        "required for brdf = \"oren_nayar\" [rad]",
                    )?,
                    0.0,
                    1.5,
                )?,
            }),
            "specular" => Brdf::Specular(Specular {
                rho: 1.0,
                shininess: self.in_range(
                    "body.shininess",
                    b.shininess.unwrap_or(20.0),
                    0.0,
                    1e4,
                )?,
            }),
            _ => {
                let kd = unit("body.diffuse_weight", b.diffuse_weight, 0.5)?;
                let ks = unit("body.specular_weight", b.specular_weight, 0.5)?;
                if kd + ks > 1.0 {
                    return self.err(
                        "body.specular_weight",
                        ks,
                        "diffuse_weight + specular_weight <= 1",
                    );
                }
                Brdf::Phong(Phong {
                    rho: 1.0,
                    diffuse_weight: kd,
                    specular_weight: ks,
                    shininess: self.in_range(
                        "body.shininess",
                        b.shininess.unwrap_or(20.0),
                        0.0,
                        1e4,
                    )?,
                })
            }
        };
        let kind = match self.choice(
            "body.albedo_type",
            &b.albedo_type,
            &["normal", "geometric", "bond", "single_scattering"],
        )? {
            "normal" => Some(AlbedoType::Normal),
            "geometric" => Some(AlbedoType::Geometric),
            "bond" => Some(AlbedoType::Bond),
            _ => None,
        };
        let albedo = self.in_range("body.albedo", b.albedo, 0.0, 1.0)?;
        let brdf = match kind {
            Some(kind) => brdf.with_albedo(albedo, kind),
            // w itself, for the models that have one.
            None if matches!(brdf, Brdf::Hapke(_) | Brdf::LommelSeeliger(_)) => {
                brdf.with_scale(albedo)
            }
            None => {
                return self.err(
                    "body.albedo_type",
                    "single_scattering",
                    "normal, geometric or bond for this BRDF (single_scattering is w of hapke \
                     and lommel_seeliger)",
                );
            }
        };
        if !brdf.scale().is_finite() {
            return self.err("body.albedo", albedo, "an albedo this BRDF can reach");
        }
        let albedo_map = match &b.albedo_map {
            None => None,
            Some(m) => {
                let map = self.map("body.albedo_map", m)?;
                Some(self.albedo_map("body.albedo_map", m, map, &brdf, kind, &b.albedo_type)?)
            }
        };
        let mut band_maps = Vec::new();
        for (k, bm) in b.band_map.iter().enumerate() {
            let key = format!("body.band_map[{k}].map");
            if b.albedo_map.is_none() {
                return self.err(
                    &format!("body.band_map[{k}]"),
                    "a band map without body.albedo_map",
                    "with body.albedo_map: the geometry is integrated with its mean, each band's \
                     map read over each pixel",
                );
            }
            let map = match bm.channel {
                None => self.map(&key, &bm.map)?,
                Some(c @ 0..=2) => {
                    let [r, g, bl] = self.map_rgb(&key, &bm.map)?;
                    [r, g, bl].into_iter().nth(c).expect("0..=2")
                }
                Some(c) => {
                    return self.err(
                        &format!("body.band_map[{k}].channel"),
                        c,
                        "0, 1 or 2 (an RGB file's R, G, B)",
                    );
                }
            };
            let Some(band) = bands.iter().position(|n| *n == bm.band) else {
                return self.err(
                    &format!("body.band_map[{k}].band"),
                    &bm.band,
                    &format!("one of the camera's bands ({})", bands.join(", ")),
                );
            };
            if band_maps.iter().any(|(b, _)| *b == band) {
                return self.err(
                    &format!("body.band_map[{k}].band"),
                    &bm.band,
                    "a band without a map yet (one map per band)",
                );
            }
            if b.reflectance_spectrum.is_some() {
                return self.err(
                    &format!("body.band_map[{k}]"),
                    "with body.reflectance_spectrum",
                    "maps per band or a reflectance spectrum, not both (a band's map is its \
                     albedo over its whole band)",
                );
            }
            let albedo = self.albedo_map(&key, &bm.map, map, &brdf, kind, &b.albedo_type)?;
            band_maps.push((band, albedo));
        }
        let ellipsoid = match &shape {
            Shape::Ellipsoid(e) => Some(*e),
            _ => None,
        };
        let relief = self.relief(b, radius_m, ellipsoid.as_ref())?;
        let spectrum = b
            .reflectance_spectrum
            .as_ref()
            .map(|r| self.spectrum(r))
            .transpose()?;
        Ok(Body {
            name: b.name.clone(),
            shape,
            brdf,
            albedo_map,
            relief,
            spectrum,
            band_maps,
        })
    }

    /// An albedo map's values as the BRDF's scale: albedos of `kind` (Hapke's normal albedos
    /// become `w` once, at load), or the scale itself.
    fn albedo_map(
        &self,
        key: &str,
        m: &raw::RawMap,
        map: crate::body::maps::Map,
        brdf: &Brdf,
        kind: Option<AlbedoType>,
        albedo_type: &str,
    ) -> R<crate::body::AlbedoMap> {
        // Map values are albedos of `albedo_type` (w itself for single_scattering).
        let (map, scale_per_value) = match kind {
            None => (map, 1.0),
            // Hapke's albedos are not linear in w: the map of normal albedos becomes
            // a map of w, once, at load.
            Some(AlbedoType::Normal) if matches!(brdf, Brdf::Hapke(_)) => {
                let values: Vec<f64> = map.values.iter().map(|&v| v as f64).collect();
                let w = brdf.scales_for_normal_albedos(&values).or_else(|v| {
                    self.err(
                        key,
                        format!("a normal albedo of {v}"),
                        "values this hapke body reaches with w <= 1",
                    )
                })?;
                let w_map = map.with_values(w).or_else(|e| self.unusable(key, m, e))?;
                (w_map, 1.0)
            }
            Some(_) if matches!(brdf, Brdf::Hapke(_)) => {
                return self.err(
                    "body.albedo_type",
                    albedo_type,
                    "normal or single_scattering with an albedo map on a hapke body",
                );
            }
            // Linear in the scale: the scale that gives an albedo of 1, per unit.
            Some(kind) => (map, brdf.with_albedo(1.0, kind).scale()),
        };
        Ok(crate::body::AlbedoMap::new(map, scale_per_value))
    }

    /// `body.reflectance_spectrum`: a built-in table or one given, and its reference.
    fn spectrum(&self, r: &RawSpectrum) -> R<Reflectance> {
        let key = "body.reflectance_spectrum";
        let reference_m = self.positive(&format!("{key}.reference_nm"), r.reference_nm)? * 1e-9;
        let bad = |e: crate::radiometry::TableError| ConfigError::Invalid {
            file: self.file.to_string(),
            key: key.to_string(),
            value: format!("reference_nm = {}", r.reference_nm),
            allowed: format!("a spectrum positive at its reference ({e})"),
        };
        match (&r.table, &r.wavelength_nm, &r.value) {
            (Some(t), None, None) if t == "moon" => Reflectance::moon(reference_m).map_err(bad),
            (Some(t), None, None) => self.err(&format!("{key}.table"), t, "moon"),
            (None, Some(wl), Some(v)) => {
                let table = self.table(key, wl, v, (0.0, f64::INFINITY))?;
                Reflectance::new("tabulated", table, reference_m).map_err(bad)
            }
            _ => self.err(
                key,
                "(table and wavelength_nm / value)",
                "either table = \"moon\" or wavelength_nm and value, with reference_nm",
            ),
        }
    }

    /// The body's relief: its DEM (heights or radii from the centre, displacing or not), the
    /// horizon map beside it and a normal map (alone, on a flat DEM of its grid, without one);
    /// each refused without what it needs.
    ///
    /// On an `ellipsoid`, heights are above its surface along the direction from the
    /// centre: they become radii once, at each texel's centre, so the relief displaces around
    /// `radius_m` (the longest semi-axis) as a DEM of radii would, and carries the ellipsoid's
    /// shape in its normals and bounding.
    fn relief(
        &self,
        b: &RawBody,
        radius_m: f64,
        ellipsoid: Option<&crate::body::Ellipsoid>,
    ) -> R<Option<crate::body::Relief>> {
        use crate::body::{NormalFrame, Relief};
        if b.dem_map.is_none() {
            for (given, key, needs) in [
                (b.displacement, "body.displacement", "a DEM to apply to"),
                (
                    b.dem_values.is_some(),
                    "body.dem_values",
                    "a DEM to apply to",
                ),
                (
                    b.horizon_map.is_some(),
                    "body.horizon_map",
                    "a horizon map beside the DEM it was computed from",
                ),
                (
                    b.horizon_azimuths.is_some(),
                    "body.horizon_azimuths",
                    "a DEM to compute the horizon from",
                ),
            ] {
                if given {
                    return self.err(key, "without body.dem_map", needs);
                }
            }
        }
        if b.normal_map.is_none() && b.normal_frame.is_some() {
            return self.err(
                "body.normal_frame",
                "without body.normal_map",
                "a normal map",
            );
        }
        let mut relief = match &b.dem_map {
            None => None,
            Some(m) => {
                let dem = self.map("body.dem_map", m)?;
                let radii = self.pick(
                    "body.dem_values",
                    b.dem_values.as_deref().unwrap_or("height"),
                    &[("height", false), ("radius", true)],
                )?;
                let heights = match (radii, ellipsoid) {
                    (false, None) => dem,
                    (false, Some(_)) if !b.displacement => {
                        return self.err(
                            "body.displacement",
                            "false with DEM heights above an ellipsoid",
                            "true (the heights are above the ellipsoid's surface, which only \
                             the displaced DEM carries)",
                        );
                    }
                    // Radii (from the centre) or heights above the ellipsoid's surface, at
                    // each texel's centre: to heights above the sphere of `radius_m`.
                    (radii, ellipsoid) => {
                        let from_m = |i: usize| match ellipsoid.filter(|_| !radii) {
                            Some(e) => {
                                let (lon, lat) = dem.texel_centre(i % dem.width, i / dem.width);
                                e.surface(crate::geometry::unit_from_lon_lat(lon, lat))
                                    .0
                                    .length()
                            }
                            None => 0.0,
                        };
                        let h = (0..dem.values.len())
                            .map(|i| from_m(i) + dem.values[i] as f64 - radius_m)
                            .collect();
                        dem.with_values(h)
                            .or_else(|e| self.unusable("body.dem_map", m, e))?
                    }
                };
                let relief = Relief::new(heights, radius_m, b.displacement).or_else(|e| {
                    self.err(
                        "body.dem_map",
                        m.path.as_str(),
                        &format!("a usable DEM ({e})"),
                    )
                })?;
                Some(match (&b.horizon_map, b.horizon_azimuths) {
                    (None, None) => relief,
                    (Some(_), Some(n)) => {
                        return self.err(
                            "body.horizon_azimuths",
                            n,
                            "absent with a body.horizon_map (one horizon or the other)",
                        );
                    }
                    (None, Some(n)) if !(4..=256).contains(&n) => {
                        return self.err("body.horizon_azimuths", n, "4 to 256");
                    }
                    (None, Some(n)) => relief.with_dem_horizon(n as usize),
                    (Some(h), None) => relief
                        .with_horizon(self.map("body.horizon_map", h)?)
                        .or_else(|e| self.unusable("body.horizon_map", h, e))?,
                })
            }
        };
        if let Some(m) = &b.normal_map {
            let frame = self.pick(
                "body.normal_frame",
                b.normal_frame.as_deref().unwrap_or("local"),
                &[("local", NormalFrame::Local), ("body", NormalFrame::Body)],
            )?;
            let components = self.map_rgb("body.normal_map", m)?;
            let base = match relief {
                Some(r) => r,
                None => components[0]
                    .with_values(vec![0.0; components[0].values.len()])
                    .and_then(|h| Relief::new(h, radius_m, false))
                    .or_else(|e| self.unusable("body.normal_map", m, e))?,
            };
            relief = Some(
                base.with_normal_map(components, frame)
                    .or_else(|e| self.unusable("body.normal_map", m, e))?,
            );
        }
        Ok(relief)
    }

    /// The `k`-th `[[body]]` (from 0), placed in the first body's frame: its shape and
    /// reflectance as any body's (no DEM: relief belongs to the first body), its centre and
    /// attitude; its bounding sphere must not meet another body's, nor hold the Sun.
    fn placed(
        &self,
        k: usize,
        b: &RawBody,
        first: &Body,
        others: &[crate::scene::Placed],
        sun_m: glam::DVec3,
    ) -> R<crate::scene::Placed> {
        let key = |f: &str| format!("body[{k}].{f}");
        if b.dem_map.is_some() || b.horizon_map.is_some() || b.normal_map.is_some() {
            return self.err(
                &key("dem_map"),
                "given",
                "absent: relief is the first body's only",
            );
        }
        if !b.band_map.is_empty() {
            return self.err(
                &key("band_map"),
                "given",
                "absent: maps per band are the first body's only",
            );
        }
        let body = self.body(b, &[])?;
        let raw_pos = self.need(
            &key("position_m"),
            b.position_m,
            "required after the first body: its centre in the first body's frame [m]",
        )?;
        let position_m = self.finite3(&key("position_m"), raw_pos)?;
        let b_from_body = match b.attitude_wxyz {
            None => glam::DQuat::IDENTITY,
            Some(q) => {
                let q = crate::geometry::body_from_camera_wxyz(q);
                if !q.is_finite() || (q.length() - 1.0).abs() > 1e-6 {
                    return self.err(&key("attitude_wxyz"), format!("{q:?}"), "a unit quaternion");
                }
                q
            }
        };
        let r = body.shape.bounding_radius_m();
        let spheres: Vec<(glam::DVec3, f64)> =
            std::iter::once((glam::DVec3::ZERO, first.shape.bounding_radius_m()))
                .chain(
                    others
                        .iter()
                        .map(|o| (o.position_m, o.body.shape.bounding_radius_m())),
                )
                .chain([(position_m, r)])
                .collect();
        if crate::scene::overlapping(&spheres).is_some() {
            return self.err(
                &key("position_m"),
                raw_pos,
                "a place where its bounding sphere meets no other body's",
            );
        }
        if (sun_m - position_m).length() <= r {
            return self.err(
                "sun.position_m",
                "inside a body",
                "a point outside every body",
            );
        }
        Ok(crate::scene::Placed {
            body,
            position_m,
            b_from_body,
        })
    }

    /// A mesh body's surface (`[body.mesh]`), which carries no DEM, horizon or normal map.
    fn mesh(&self, b: &RawBody) -> R<crate::body::Mesh> {
        let m = self.need(
            "body.mesh",
            b.mesh.as_ref(),
            "required for shape = \"mesh\": { path, units }",
        )?;
        for (key, given) in [
            ("body.radius_m", b.radius_m.is_some()),
            ("body.semi_axes_m", b.semi_axes_m.is_some()),
            ("body.dem_map", b.dem_map.is_some()),
            ("body.horizon_map", b.horizon_map.is_some()),
            ("body.normal_map", b.normal_map.is_some()),
        ] {
            if given {
                return self.err(key, "given", "absent for a mesh (its surface is the mesh)");
            }
        }
        let metres_per_unit = match (m.units.as_deref(), m.metres_per_unit) {
            (Some("m"), None) => 1.0,
            (Some("km"), None) => 1000.0,
            (None, Some(k)) => self.positive("body.mesh.metres_per_unit", k)?,
            (Some(u), None) => return self.err("body.mesh.units", u, "m or km"),
            _ => {
                return self.err(
                    "body.mesh.units",
                    "missing or given with metres_per_unit",
                    "one of units = \"m\" | \"km\" or metres_per_unit",
                );
            }
        };
        let rotation = match m.body_from_file_wxyz {
            None => glam::DMat3::IDENTITY,
            Some(q) => {
                let q = crate::geometry::body_from_camera_wxyz(q);
                if !q.is_finite() || (q.length() - 1.0).abs() > 1e-6 {
                    return self.err(
                        "body.mesh.body_from_file_wxyz",
                        format!("{q:?}"),
                        "a unit quaternion, scalar first",
                    );
                }
                glam::DMat3::from_quat(q)
            }
        };
        let path = self.path("body.mesh.path", &m.path)?;
        crate::body::Mesh::load(&path, metres_per_unit, rotation).or_else(|e| {
            self.err(
                "body.mesh.path",
                path.display().to_string(),
                &format!("a readable, valid mesh ({e})"),
            )
        })
    }

    /// A map that loaded but cannot serve: `key`, its path, and why.
    fn unusable<T>(&self, key: &str, m: &raw::RawMap, e: crate::body::maps::MapError) -> R<T> {
        self.err(key, m.path.as_str(), &e.to_string())
    }

    /// A map's encoding from its table; `key` names it in errors.
    fn encoding(&self, key: &str, m: &raw::RawMap) -> R<crate::body::maps::Encoding> {
        use crate::body::maps::Encoding;
        let d = Encoding::default();
        let enc = Encoding {
            gamma: self.positive(&format!("{key}.gamma"), m.gamma.unwrap_or(1.0))?,
            domain: m.domain,
            scale: m.scale.unwrap_or(1.0),
            shift: m.shift.unwrap_or(0.0),
            mean: m.mean,
            lon_limits_deg: m.lon_limits_deg.unwrap_or(d.lon_limits_deg),
            lat_limits_deg: m.lat_limits_deg.unwrap_or(d.lat_limits_deg),
        };
        if ![enc.scale, enc.shift].iter().all(|x| x.is_finite())
            || enc
                .domain
                .is_some_and(|[a, b]| !(a.is_finite() && b.is_finite()))
        {
            return self.err(key, "scale/shift/domain", "finite numbers");
        }
        Ok(enc)
    }

    /// Loads a map with its encoding; `key` names it in errors.
    fn map(&self, key: &str, m: &raw::RawMap) -> R<crate::body::maps::Map> {
        self.load_map(key, m, "a readable map", crate::body::maps::Map::load)
    }

    /// Loads an RGB map as its three channels, each with the encoding.
    fn map_rgb(&self, key: &str, m: &raw::RawMap) -> R<[crate::body::maps::Map; 3]> {
        self.load_map(
            key,
            m,
            "a readable RGB map",
            crate::body::maps::Map::load_rgb,
        )
    }

    fn load_map<T>(
        &self,
        key: &str,
        m: &raw::RawMap,
        what: &str,
        load: impl Fn(&Path, &crate::body::maps::Encoding) -> Result<T, crate::body::maps::MapError>,
    ) -> R<T> {
        let enc = self.encoding(key, m)?;
        let path = self.path(&format!("{key}.path"), &m.path)?;
        load(&path, &enc).or_else(|e| {
            self.err(
                &format!("{key}.path"),
                path.display().to_string(),
                &format!("{what} ({e})"),
            )
        })
    }

    fn camera(&self, c: &RawCamera) -> R<(Camera, Option<(f64, f64)>)> {
        let [w, h] = c.resolution_px;
        if !(1..=32768).contains(&w) || !(1..=32768).contains(&h) {
            return self.err(
                "camera.resolution_px",
                c.resolution_px,
                "two integers in [1, 32768]",
            );
        }
        let pitch = match c.pixel_pitch_m {
            OneOrTwo::One(p) => [p, p],
            OneOrTwo::Two(p) => p,
        };
        for p in pitch {
            self.in_range("camera.pixel_pitch_m", p, 1e-8, 1e-2)?;
        }
        let focal_length_m =
            self.in_range("camera.focal_length_m", c.focal_length_m, 1e-5, 100.0)?;
        let f_number = self.in_range("camera.f_number", c.f_number, 0.1, 1e4)?;
        let pp = c
            .principal_point_px
            .unwrap_or([w as f64 / 2.0, h as f64 / 2.0]);
        if !pp.iter().all(|x| x.is_finite()) {
            return self.err("camera.principal_point_px", pp, "two finite numbers [px]");
        }
        if !c.skew_px.is_finite() {
            return self.err("camera.skew_px", c.skew_px, "a finite number [px]");
        }
        let distortion = self.brown("camera.distortion", &c.distortion)?;
        let intrinsics = Intrinsics {
            width_px: w as u32,
            height_px: h as u32,
            pixel_pitch_m: pitch,
            focal_length_m,
            f_number,
            principal_point_px: pp,
            skew_px: c.skew_px,
            distortion,
        };
        let (bands, layout) = self.bands(c)?;
        if !(1..=16).contains(&c.bit_depth) {
            return self.err("camera.bit_depth", c.bit_depth, "an integer in [1, 16]");
        }
        let saved_bits = c.saved_bit_depth.unwrap_or(c.bit_depth);
        if !(1..=c.bit_depth).contains(&saved_bits) {
            return self.err(
                "camera.saved_bit_depth",
                saved_bits,
                "an integer in [1, camera.bit_depth]",
            );
        }
        let n = &c.noise;
        let noise = Noise {
            shot: n.shot.then_some(Shot),
            prnu: n
                .prnu_sigma
                .map(|s| {
                    self.in_range("camera.noise.prnu_sigma", s, 0.0, 1.0)
                        .map(|sigma| Prnu { sigma })
                })
                .transpose()?,
            dark: match n.dark_current_e_per_s {
                Some(r) => Some(DarkCurrent {
                    rate_e_per_s: self.non_negative("camera.noise.dark_current_e_per_s", r)?,
                    fpn_sigma: self.in_range(
                        "camera.noise.dark_fpn_sigma",
                        n.dark_fpn_sigma.unwrap_or(0.0),
                        0.0,
                        10.0,
                    )?,
                }),
                None => None,
            },
            readout: n
                .readout_sigma_e
                .map(|s| {
                    self.non_negative("camera.noise.readout_sigma_e", s)
                        .map(|sigma_e| Readout { sigma_e })
                })
                .transpose()?,
        };
        let detector = Detector {
            exposure_s: self.positive("camera.exposure_s", c.exposure_s)?,
            full_well_e: self.positive("camera.full_well_e", c.full_well_e)?,
            adc_gain_dn_per_e: self.positive("camera.adc_gain_dn_per_e", c.adc_gain_dn_per_e)?,
            offset_dn: self.non_negative("camera.offset_dn", c.offset_dn)?,
            bit_depth: c.bit_depth as u32,
            saved_bits: saved_bits as u32,
            bands,
            layout,
            psf_sigma_px: self.in_range("camera.psf_sigma_px", c.psf_sigma_px, 0.0, 100.0)?,
            noise,
            seed: n.seed,
        };
        let band = match c.power_band_nm {
            Some([lo, hi]) if lo.is_finite() && hi.is_finite() && lo > 0.0 && hi > lo => {
                Some((lo * 1e-9, hi * 1e-9))
            }
            Some(b) => {
                return self.err(
                    "camera.power_band_nm",
                    b,
                    "[min, max] with 0 < min < max [nm]",
                );
            }
            None => None,
        };
        if band.is_some() && detector.bands.len() > 1 {
            return self.err(
                "camera.power_band_nm",
                c.power_band_nm.unwrap_or_default(),
                "absent with [[camera.band]]: each band's power.fits plane is over its own range",
            );
        }
        Ok((
            Camera {
                intrinsics,
                detector,
            },
            band,
        ))
    }

    /// Brown coefficients at `key`, each in [-10, 10].
    fn brown(&self, key: &str, d: &RawDistortion) -> R<Brown> {
        for (k, v) in [
            ("k1", d.k1),
            ("k2", d.k2),
            ("k3", d.k3),
            ("p1", d.p1),
            ("p2", d.p2),
        ] {
            self.in_range(&format!("{key}.{k}"), v, -10.0, 10.0)?;
        }
        Ok(Brown {
            k1: d.k1,
            k2: d.k2,
            k3: d.k3,
            p1: d.p1,
            p2: d.p2,
        })
    }

    /// The camera's bands: `camera.qe` (one band, `mono`) or `[[camera.band]]`, each with its
    /// transmittance (its own, else the camera's, else 1), and the mosaic over them.
    fn bands(&self, c: &RawCamera) -> R<(Vec<Band>, Layout)> {
        let curve =
            |key: &str, t: &RawCurve| self.table(key, &t.wavelength_nm, &t.value, (0.0, 1.0));
        let optics = c
            .transmittance
            .as_ref()
            .map(|t| curve("camera.transmittance", t))
            .transpose()?;
        let transmittance = |own: Option<SpectralTable>, qe: &SpectralTable| {
            own.or_else(|| optics.clone()).unwrap_or_else(|| {
                let (lo, hi) = qe.range_m();
                SpectralTable::flat(lo, hi, 1.0)
            })
        };
        let bands = match (&c.qe, c.band.is_empty()) {
            (Some(q), true) => {
                let qe = curve("camera.qe", q)?;
                vec![Band {
                    name: "mono".into(),
                    transmittance: transmittance(None, &qe),
                    qe,
                    psf_sigma_px: None,
                    distortion: None,
                }]
            }
            (None, false) => {
                let mut bands: Vec<Band> = Vec::new();
                for (k, b) in c.band.iter().enumerate() {
                    let key = format!("camera.band[{k}]");
                    if b.name.is_empty() || bands.iter().any(|o| o.name == b.name) {
                        return self.err(&format!("{key}.name"), &b.name, "a name of its own");
                    }
                    let qe = curve(&format!("{key}.qe"), &b.qe)?;
                    let own = b
                        .transmittance
                        .as_ref()
                        .map(|t| curve(&format!("{key}.transmittance"), t))
                        .transpose()?;
                    let psf_sigma_px = b
                        .psf_sigma_px
                        .map(|s| self.in_range(&format!("{key}.psf_sigma_px"), s, 0.0, 100.0))
                        .transpose()?;
                    let distortion = b
                        .distortion
                        .as_ref()
                        .map(|d| self.brown(&format!("{key}.distortion"), d))
                        .transpose()?;
                    bands.push(Band {
                        name: b.name.clone(),
                        transmittance: transmittance(own, &qe),
                        qe,
                        psf_sigma_px,
                        distortion,
                    });
                }
                if bands.len() > 64 {
                    return self.err("camera.band", bands.len(), "at most 64 bands");
                }
                bands
            }
            (Some(_), false) => {
                return self.err(
                    "camera.qe",
                    "(with [[camera.band]])",
                    "either camera.qe (one band) or [[camera.band]], each with its qe",
                );
            }
            (None, true) => {
                return self.err("camera.qe", "(missing)", "a QE curve, or [[camera.band]]");
            }
        };
        let layout = match c.mosaic.as_deref() {
            None => Layout::Planes,
            Some(m) => {
                let Some(order) = Bayer::ALL.into_iter().find(|o| o.name() == m) else {
                    return self.err("camera.mosaic", m, "RGGB, BGGR, GRBG or GBRG");
                };
                if bands.len() != 3 {
                    return self.err(
                        "camera.mosaic",
                        m,
                        "a mosaic over exactly three [[camera.band]]: R, G and B, in that order",
                    );
                }
                Layout::Bayer(order)
            }
        };
        Ok((bands, layout))
    }

    fn pose(&self, p: &RawPose, sun_position_m: DVec3, body: &Body) -> R<Pose> {
        let camera_position_m = self.finite3("pose.camera_position_m", p.camera_position_m)?;
        if !body.admits_camera_at(camera_position_m) {
            let r = body.keep_out_radius_m(camera_position_m.normalize_or_zero());
            return self.err(
                "pose.camera_position_m",
                p.camera_position_m,
                &format!("a point outside the body (radius {r} m in that direction)"),
            );
        }
        let body_from_camera = match (p.attitude_wxyz, p.look_at_body) {
            (Some(_), true) => {
                return self.err(
                    "pose.look_at_body",
                    true,
                    "either attitude_wxyz or look_at_body = true, not both",
                );
            }
            (Some(q), false) => {
                let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
                if !q.iter().all(|x| x.is_finite()) || (n - 1.0).abs() > 1e-6 {
                    return self.err(
                        "pose.attitude_wxyz",
                        q,
                        "a unit quaternion (w, x, y, z), norm within 1e-6 of 1",
                    );
                }
                body_from_camera_wxyz(q.map(|x| x / n))
            }
            (None, true) => look_at(camera_position_m, DVec3::ZERO, DVec3::NEG_Z),
            (None, false) => {
                return self.err(
                    "pose.attitude_wxyz",
                    "(missing)",
                    "a unit quaternion (w, x, y, z), or look_at_body = true",
                );
            }
        };
        Ok(Pose {
            frame_id: p.frame_id,
            camera_position_m,
            body_from_camera,
            sun_position_m,
        })
    }

    fn render(&self, r: &RawRender, body: &Body) -> R<Settings> {
        let mut s = match &r.preset {
            Some(p) => {
                Settings::preset(self.choice("render.preset", p, &["default", "high_accuracy"])?)
                    .unwrap_or_default()
            }
            None => Settings::default(),
        };
        match (r.points, r.points_per_pixel) {
            (Some(_), Some(_)) => {
                return self.err(
                    "render.points",
                    r.points,
                    "either points or points_per_pixel, not both",
                );
            }
            (Some(n), None) => {
                let n = self.in_range("render.points", n, 1.0, 1e9)?;
                s.points = PointBudget::Total(n.round() as usize);
            }
            (None, Some(p)) => {
                s.points =
                    PointBudget::PerPixel(self.in_range("render.points_per_pixel", p, 1e-6, 1e4)?)
            }
            (None, None) => {}
        }
        if let Some(m) = r.max_points {
            s.max_points = self.in_range("render.max_points", m, 1.0, 1e9)?.round() as usize;
        }
        if let Some(v) = &r.sampling {
            s.sampling =
                match self.choice("render.sampling", v, &["uniform", "projected_uniform"])? {
                    "uniform" => Sampling::Uniform,
                    _ => Sampling::ProjectedUniform,
                };
        }
        if let Some(v) = &r.split {
            s.split = match self.choice("render.split", v, &["aspect", "eq23"])? {
                "eq23" => Split::Eq23,
                _ => Split::Aspect,
            };
        }
        if let Some(n) = r.min_points {
            if !(1..=1_000_000).contains(&n) {
                return self.err("render.min_points", n, "an integer in [1, 1000000]");
            }
            s.min_points = n as usize;
        }
        if let Some(n) = r.boundary_nodes {
            if !(1..=32).contains(&n) {
                return self.err("render.boundary_nodes", n, "an integer in [1, 32]");
            }
            s.boundary_nodes = n as u32;
        }
        if let Some(v) = r.trapezoid_points_per_px {
            s.trapezoid_points_per_px =
                self.in_range("render.trapezoid_points_per_px", v, 0.0, 1e3)?;
        }
        let ppd = self.in_range(
            "render.trapezoid_points_per_deg",
            r.trapezoid_points_per_deg.unwrap_or(5.0),
            1e-3,
            1e3,
        )?;
        let points_per_deg = ppd;
        s.integration = self.pick(
            "render.integration",
            r.integration.as_deref().unwrap_or("auto"),
            &[
                ("auto", Integration::Auto { points_per_deg }),
                ("exact", Integration::Exact),
                ("trapezoidal", Integration::Trapezoidal { points_per_deg }),
                ("midpoint", Integration::Midpoint { points_per_deg }),
                ("pointwise", Integration::Pointwise),
            ],
        )?;
        if let Some(v) = &r.fov {
            s.fov = match self.choice("render.fov", v, &["frustum", "cone"])? {
                "cone" => FovShape::Cone,
                _ => FovShape::Frustum,
            };
        }
        if let Some(v) = &r.gridding {
            s.gridding = match self.choice(
                "render.gridding",
                v,
                &["polygon", "polygon_linear", "nearest", "area", "gaussian"],
            )? {
                "nearest" => Gridding::Nearest,
                "polygon_linear" => Gridding::PolygonLinear,
                "area" => Gridding::Area,
                "gaussian" => {
                    let window = r.gaussian_window_px.unwrap_or(3);
                    if !(1..=15).contains(&window) || window % 2 == 0 {
                        return self.err(
                            "render.gaussian_window_px",
                            window,
                            "an odd integer in [1, 15]",
                        );
                    }
                    // Default: 3 sigma at the window's edge (Sec. 4.8).
                    let sigma = r.gaussian_sigma_px.unwrap_or(window as f64 / 2.0 / 3.0);
                    Gridding::Gaussian {
                        window_px: window as u32,
                        sigma_px: self.in_range("render.gaussian_sigma_px", sigma, 1e-3, 10.0)?,
                    }
                }
                _ => Gridding::Polygon,
            };
        }
        if let Some(m) = r.supersampling {
            if !(1..=16).contains(&m) {
                return self.err("render.supersampling", m, "an integer in [1, 16]");
            }
            s.supersampling = m as u32;
        }
        if let Some(v) = &r.reconstruction {
            s.reconstruction = match self.choice(
                "render.reconstruction",
                v,
                &["box", "bilinear", "lanczos", "gaussian"],
            )? {
                "bilinear" => Reconstruction::Bilinear,
                "lanczos" => {
                    let a = r.lanczos_a.unwrap_or(3);
                    if !(1..=8).contains(&a) {
                        return self.err("render.lanczos_a", a, "an integer in [1, 8]");
                    }
                    Reconstruction::Lanczos { a: a as u32 }
                }
                "gaussian" => Reconstruction::Gaussian {
                    sigma_px: self.in_range(
                        "render.reconstruction_sigma_px",
                        r.reconstruction_sigma_px.unwrap_or(0.5),
                        1e-3,
                        10.0,
                    )?,
                },
                _ => Reconstruction::Box,
            };
        }
        if let Some(a) = r.antialias_sigma_px {
            s.antialias_sigma_px = self.in_range("render.antialias_sigma_px", a, 0.0, 10.0)?;
        }
        if let Some(t) = r.threads {
            if !(0..=1024).contains(&t) {
                return self.err(
                    "render.threads",
                    t,
                    "an integer in [0, 1024] (0 = all cores)",
                );
            }
            s.threads = t as usize;
        }
        if let Some(t) = r.bounding_tolerance_rad {
            s.bounding_tolerance_rad =
                self.in_range("render.bounding_tolerance_rad", t, 1e-12, 1e-2)?;
        }
        if let Some(v) = &r.self_shadowing {
            use crate::render::settings::SelfShadowing;
            s.self_shadowing = self.pick(
                "render.self_shadowing",
                v,
                &[
                    ("off", SelfShadowing::Off),
                    ("ray_marching", SelfShadowing::RayMarching),
                    ("horizon_map", SelfShadowing::HorizonMap),
                ],
            )?;
            // Shadows asked for and impossible would silently be none.
            let relief = body.relief.as_ref();
            match s.self_shadowing {
                SelfShadowing::RayMarching if relief.is_none() => {
                    return self.err("render.self_shadowing", v, "off without a body.dem_map");
                }
                SelfShadowing::HorizonMap if relief.is_none_or(|r| !r.has_horizon()) => {
                    return self.err(
                        "render.self_shadowing",
                        v,
                        "off or ray_marching without a body.horizon_map or body.horizon_azimuths",
                    );
                }
                _ => {}
            }
        }
        if let Some(d) = r.depth {
            s.depth = d;
        }
        for (key, v, field) in [
            (
                "render.raycast_samples",
                r.raycast_samples,
                &mut s.raycast_samples,
            ),
            (
                "render.raycast_edge_samples",
                r.raycast_edge_samples,
                &mut s.raycast_edge_samples,
            ),
        ] {
            if let Some(n) = v {
                if !(1..=64).contains(&n) {
                    return self.err(key, n, "an integer in [1, 64]");
                }
                *field = n as u32;
            }
        }
        if let Some(q) = r.raycast_quadratic_light {
            s.raycast_quadratic_light = q;
        }
        if let Some(c) = r.raycast_clip {
            s.raycast_clip = c;
        }
        if let Some(k) = r.scattering_orders {
            if !(0..=20).contains(&k) {
                return self.err("render.scattering_orders", k, "an integer in [0, 20]");
            }
            s.scattering_orders = k as u32;
        }
        if let Some(v) = &r.map_filter {
            use crate::render::MapFilter;
            s.map_filter = self.pick(
                "render.map_filter",
                v,
                &[
                    ("point", MapFilter::Point),
                    ("area", MapFilter::Area),
                    ("pixel", MapFilter::Pixel),
                    ("relief", MapFilter::Relief),
                ],
            )?;
        }
        if let Some(k) = r.relief_refine {
            if ![1, 2, 4, 8].contains(&k) {
                return self.err("render.relief_refine", k, "1, 2, 4 or 8");
            }
            s.relief_refine = k as u32;
        }
        if let Some(x) = r.map_read_spacing_texels {
            if !(1.0 / 16.0..=1.0).contains(&x) {
                return self.err("render.map_read_spacing_texels", x, "0.0625 to 1 texel");
            }
            s.map_read_spacing_texels = x;
        }
        // Under `map_filter = "relief"` the quadrangles integrate the smooth shape.
        let relief_on_quadrangles = s.map_filter != crate::render::MapFilter::Relief;
        if s.integration == Integration::Exact
            && let Err(e) = Method::resolve(Integration::Exact, body, relief_on_quadrangles)
        {
            return self.err("render.integration", "exact", &e.to_string());
        }
        Ok(s)
    }
}
