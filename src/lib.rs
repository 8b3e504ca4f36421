//! # optistim
//!
//! A physically based renderer of planets and moons for hardware-in-the-loop optical
//! stimulators, after Pizzetti et al. (`../shared/papers/physically-based-rendering-of-celestial-bodies.md`).
//!
//! # Layout
//!
//! | module | holds |
//! | --- | --- |
//! | [`geometry`] | frames (B, C, CSF), rotations named `a_from_b`, spherical coordinates and local east/north, ray-sphere; `bvh`: the triangle BVH (obvhs) behind rays in and hits out |
//! | [`radiometry`] | Planck, the Sun's spectrum, spectral tables, band integrals (Eqs. 5-10, 45), a surface's spectral reflectance shape (the average Moon's built in) |
//! | [`brdf`] | reflectance models, one file each (Lambert to Hapke); phase laws (Eq. 48) and albedo conversions |
//! | [`body`] | the body's shape (sphere, triaxial ellipsoid, triangle mesh: OBJ / PLY / STL loaded, checked and repaired), reflectance, texture maps (TIFF, bilinear, seamless) for albedo, DEM relief (heights or radii, on the sphere or an ellipsoid: normals, displacement, ray-marched shadows that leap over the DEM's block maxima of height and slope, `pyramid`, and skip rays its slopes and far heights clear, `clearance`, and stop a Sun ray once the highest ground towards the frame's Sun can no longer reach it, `sun_envelope`), horizon and normal maps, horizons computed from the DEM by azimuth |
//! | [`camera`] | pinhole intrinsics with Brown distortion (Eqs. 39-40) |
//! | [`compare`] | rendered vs real images (Sec. 5.3): NCC alignment, foreground, SSIM luminance / contrast / structure, the DN response quantile by quantile |
//! | [`detector`] | (P/L) -> signal -> optics PSF -> electrons with noises -> DN at the saved bit depth (Eqs. 45-47); a camera's bands (each its QE, transmittance, PSF and distortion: chromatic aberrations), full images per band or a Bayer mosaic |
//! | [`scene`] | the validated Sun, body and camera, and the per-frame pose |
//! | [`render`] | the pipeline, one module per step: view (the CSF, and the grid's space: the CSF, or an ellipsoid's parameter space), bounding, sampling, pruning, integration, projection, gridding, reconstruction, footprint (the albedo map over each pixel's footprint, `map_filter = "pixel"`; the bands' own maps in the same pass; and an undisplaced DEM's shading and shadows with it, `"relief"`) |
//! | [`raycast`] | per-pixel ray casting, the sibling of the quadrangle pipeline: what a line of sight meets and brings back (shapes, meshes through their BVH, several bodies by depth with eclipses, a DEM met by sphere tracing that leaps over blocks by a max-height pyramid, its shadows, maps, BRDFs, a mesh's scattered light); the frame of meshes and of several bodies (`sampled`: n x n rays per pixel, more at edges; a lone mesh's pixels tiled by its facets' exact shares and its first facets by exact rasterisation, `raster`, its shadows through a grid seen from the Sun that also knows the facets lit all over, `sun_grid`, and a large facet's light read from a quadratic over its image, `facet_light`; the frame's own error estimate from its rays, to which `fidelity = "budget"` refines its edges, `estimate`); and the converged reference of any scene by adaptive cubature over each pixel's footprint (a limb where a DEM tilts the normals by lattices warped at it, `limb`), with its own error estimate |
//! | [`irradiance`] | mesh facets' irradiance (SLIM): direct with shadows, Lambertian radiosity (form factors with BVH visibility, Jacobi orders, Eqs. 4-9), statistics over a rotation (Eq. 14) |
//! | [`inversion`] | Hapke parameters from images of a body of known shape and pose (SLIM Sec. 11): the renderer's lines of sight cast once, Levenberg-Marquardt on the shot- and read-noise-weighted residuals, uncertainties from the normal matrix, the histogram chi-square of Eq. 15 |
//! | [`fidelity`] | a frame's error against the converged reference (total; median, p95, p99 per lit pixel; SSIM): what the sweep charts and budgets are written in; the budget planner (`fidelity = "budget"`): per frame, what it shows (probe rays, the maps' contrast) and the cheapest rung of a settings ladder an error model fitted by the sweep predicts to meet the budget, or the top rung where the frame lies outside the model's fitted domain (a frame with an undisplaced DEM adds the model's relief term, fitted on DEM frames alone with its own margin; one with a displaced DEM, which the model has not seen, keeps the model's rung and does not claim it) |
//! | [`stimulator`] | F_eff (Eqs. 58-60), screen calibration curves (load, validate, interpolate, invert, clip counts, replay), colour screens (cross-talk of the primaries into the camera's bands, the per-pixel solve), dithering, collimator mapping, the simulated camera, curve and cross-talk measurement |
//! | [`display`] | the wgpu presenter: device, queue and the LUT pass (screen-region F_eff -> screen DN on the GPU) into an off-screen buffer read back, a borderless fullscreen window on the stimulator's monitor, or the operator's preview |
//! | [`pipeline`] | one pose's way to the screen: render -> signal -> stimulator -> simulated camera, timed per stage |
//! | [`config`] | scene TOML: raw serde structs -> validated `Scene`, `Pose`, `Settings`, with errors naming file, key, value and what is allowed |
//! | [`trajectory`] | pose streams (CSV, JSON lines) of `../shared/trajectories/` |
//! | [`io`] | FITS and PNG outputs (in memory too), grayscale PNG input (photographs), SHA-256 content hashes |
//! | [`background`] | cooperative pause points: the daemon's background image work pauses between slices while a frame is in flight |
//! | [`stats`] | quantiles of timing samples (benchmarks, daemon status, replay reports) |
//! | [`server`] | the daemon: pose protocol (binary frames with CRC-32, JSON lines), TCP and serial connections, access (token, non-loopback binds, scene folders), the frame thread (free-running, lockstep, hold and trigger), HTTP control and metrics (a background thread; images made once per frame by `views`), the recording |
//! | [`app`] | the commands behind the binary: `products` (a pose's products and their files, shared by `render`, `render-trajectory` and the Python package in `python/`), `render` (the quadrangle pipeline or `--reference`), `render-trajectory` (a resumable dataset folder, by shards), `exposure` (exposure planning, Eqs. 61-62), `sweep` (the speed-accuracy front and its chart; `--fit` the planner's error model), `verify-budget` (the planner against the reference over a pose stream), `plan` (the planner alone over every pose of a stream: its settings, predicted error and the rows not predicted to meet the budget), `stability` (the suite of hard cases, each also under the budget), `bench`, `bench-display`, `show`, `calibrate`, `compare`, `replay` |
//!
//! # Data flow of one frame
//!
//! ```text
//! config/*.toml ─► config::load ─► (Scene, Pose, Settings)
//!                                        │
//!   render::Renderer::render(scene, pose, settings)
//!     view (CSF) → bounding → sampling → pruning → integration → projection
//!     → gridding (i64 fixed point) → reconstruction  ─►  Frame { (P/L) image, depth, stats }
//!                                        │
//!   detector: S_b = (P/L)_b·∫QE_b·T_b·λ/(hc)·r(λ)·L_e dλ per band b (one render; a band's
//!             own distortion grids the same cloud again) → electrons (+noise) → DN
//!             (a full image per band, or a Bayer mosaic)
//!                                        │
//!   app::products: power, signal, depth, DN and their files (the same bytes everywhere)
//!   app::render writes power.fits, signal.fits (cubes of bands), depth.fits, image.png (grey,
//!     RGB, or the raw mosaic) and one JSON line
//!   app::render_trajectory: frames/NNNNNN/ + manifest (and python/: optistim.render,
//!     optistim.dataset on Ray, the same files)
//!
//!   (a mesh body or several bodies: Renderer::render hands the frame to raycast::sampled,
//!    with a mesh's scattered light from irradiance, or, a lone mesh through a pinhole with
//!    raycast_clip, to raycast::exact (facets clipped as polygons); the same Frame comes out)
//!   raycast::reference::render_by(scene, pose, method) ─► the converged Frame (+ its error
//!    per pixel): raycast::exact's clipping for a lone mesh through a pinhole, else the
//!    adaptive cubature of ray casts
//!   fidelity::metrics::frame_error(frame, reference) ─► total, median / p95 / p99, SSIM
//!   fidelity::budget::Planner::plan(scene, pose) ─► Settings + predicted error, per frame
//!     (pipeline::FrameMaker, app::render, app::bench with fidelity = "budget"; reported in
//!      the JSON line, FITS headers, bench rows, the daemon's ack and /status)
//!     (app::sweep: scenes x settings → sweep.csv, front.png / front.svg, --fit the model;
//!      app::stability: the hard cases → docs/stability.md)
//!                                        │ signal [e-/s]
//!   stimulator: F_eff = k·S (Eq. 60) → screen region (collimator) → calibration⁻¹ (+ dither)
//!               → screen DN ─► simulated camera: true response → collimator → detector → DN
//!     (colour: each band's F_eff_b = k_b·S_b → per pixel f = P·F (cross-talk) → each primary's
//!      calibration⁻¹ → R, G, B DN ─► simulated camera: F_b = X·f → each band's detector)
//!   display::Presenter: screen-region F_eff → LUT pass (same inverse, on the GPU) → screen DN
//!               (off-screen with read-back | fullscreen window | preview window)
//!
//! server (optistim serve): TCP | serial ─► protocol::Decoder ─► connection ─► frames::Intake
//!   ─► frame thread: pipeline::FrameMaker → Presenter → ack (+ camera frame to subscribers)
//!   access: token on hellos and mutating HTTP calls; scenes only from the scene folders
//!   http (axum, background thread): status, metrics, calibration replay, run-time settings,
//!   images ◄─ views (one background worker, each image made once per frame, cached)
//! ```
//!
//! Rules: nothing below `app` knows about files except `config`, `trajectory`, `io` and the
//! calibration loader; the renderer is a pure function of (scene, pose, settings) and never
//! panics on input.

pub mod app;
pub mod background;
pub mod body;
pub mod brdf;
pub mod camera;
pub mod compare;
pub mod config;
pub mod detector;
pub mod display;
pub mod fidelity;
pub mod geometry;
pub mod inversion;
pub mod io;
pub mod irradiance;
pub mod pipeline;
pub mod radiometry;
pub mod raycast;
pub mod render;
pub mod scene;
pub mod server;
pub mod stats;
pub mod stimulator;
pub mod trajectory;
