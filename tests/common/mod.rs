//! Scene builders shared by the integration tests.
#![allow(dead_code)]

use optistim::config::{self, Config};
use optistim::render::Renderer;

pub const AU: f64 = 1.495978707e11;
pub const R_MOON: f64 = 1737400.0;

/// A scene TOML with a sphere of `brdf` and the given camera; `render` is extra `[render]` text.
pub struct SceneSpec<'a> {
    pub brdf: &'a str,
    pub albedo: f64,
    pub camera_m: [f64; 3],
    pub sun_m: [f64; 3],
    pub attitude: Option<[f64; 4]>,
    pub resolution: [u32; 2],
    pub pixel_m: f64,
    pub focal_m: f64,
    pub distortion: &'a str,
    pub render: &'a str,
    pub noise: &'a str,
}

impl Default for SceneSpec<'_> {
    fn default() -> Self {
        SceneSpec {
            brdf: "lambert",
            albedo: 0.12,
            camera_m: [10.0 * R_MOON, 0.0, 0.0],
            sun_m: [AU, 0.0, 0.0],
            attitude: None,
            resolution: [256, 256],
            pixel_m: 5.5e-6,
            focal_m: 0.03,
            distortion: "",
            render: "",
            noise: "",
        }
    }
}

impl SceneSpec<'_> {
    pub fn toml(&self) -> String {
        let pose = match self.attitude {
            Some(q) => format!("attitude_wxyz = {q:?}"),
            None => "look_at_body = true".into(),
        };
        format!(
            r#"
[sun]
spectrum = "blackbody"
temperature_k = 5782.0
radius_m = 6.957e8
position_m = {sun:?}

[body]
name = "Test"
radius_m = {R_MOON}
brdf = "{brdf}"
albedo = {albedo}
albedo_type = "normal"

[camera]
resolution_px = {res:?}
pixel_pitch_m = {pix}
focal_length_m = {focal}
f_number = 2.0
exposure_s = 1e-4
full_well_e = 30000.0
adc_gain_dn_per_e = 0.1
bit_depth = 12
qe = {{ wavelength_nm = [400, 700, 1000], value = [0.5, 0.6, 0.2] }}
{distortion}

[camera.noise]
seed = 5
{noise}

[pose]
camera_position_m = {cam:?}
{pose}

[render]
{render}
"#,
            sun = self.sun_m,
            brdf = self.brdf,
            albedo = self.albedo,
            res = self.resolution,
            pix = self.pixel_m,
            focal = self.focal_m,
            distortion = self.distortion,
            noise = self.noise,
            cam = self.camera_m,
            pose = pose,
            render = self.render,
        )
    }

    pub fn config(&self) -> Config {
        config::parse(&self.toml(), "<test>").unwrap_or_else(|e| panic!("{e}"))
    }
}

/// The flight camera's signal image [e-/s] for the scene and pose of `cfg`.
pub fn rendered_signal(cfg: &Config) -> Vec<f64> {
    let det = &cfg.scene.camera.detector;
    let frame = Renderer::new(0)
        .unwrap()
        .render(&cfg.scene, &cfg.pose, &cfg.settings)
        .unwrap();
    det.signal(&frame.pl, det.signal_factor(&cfg.scene.sun))
}
