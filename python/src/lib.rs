//! `optistim._optistim`: the native half of the Python package `optistim` (PyO3, abi3).
//!
//! # Layout
//!
//! | item | holds |
//! | --- | --- |
//! | [`Scene`] | a validated scene (`Scene.from_toml`, `Scene.from_dict`), its planner when `fidelity = "budget"`, and how to rebuild it in another process (pickling, for Ray) |
//! | [`Pose`] | camera position [m], camera -> body quaternion (w, x, y, z), Sun position [m], frame id |
//! | [`render`] | one frame, the GIL released, in a cached rayon pool of the asked size |
//! | [`Frame`] | power [W], signal [e-/s], DN, depth [m] as NumPy arrays (moved, not copied), stats, settings, error report; its files in memory or in a folder |
//! | [`Trajectory`] | `render_trajectory`'s iterator over poses (N x 7 or N x 10 arrays, or a pose file) |
//!
//! Everything renders through `optistim::app::products`, as `optistim render` does: a frame
//! from Python and the CLI's files are the same bytes. Errors are raised with the CLI's
//! messages as the classes of `optistim/errors.py`: `SceneError` (a bad scene file or dict),
//! `PoseError` (a bad pose), `RenderError` (the frame failed, or its files could not be
//! written).

use numpy::{
    IntoPyArray, PyArray2, PyArrayDyn, PyArrayMethods, PyReadonlyArray2, PyReadonlyArrayDyn,
    PyUntypedArrayMethods,
};
use optistim::app::products::{self, FrameMeta, FrameRecord, Images};
use optistim::config::{self, Config};
use optistim::fidelity::budget::Planner;
use optistim::render::Renderer;
use optistim::scene::Pose as RustPose;
use pyo3::exceptions::{PyRuntimeError, PyTypeError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyType};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

/// An error of the class `kind` of `optistim.errors` (pure Python, so that `SceneError` and
/// `PoseError` are `ValueError`s too), with `message` as the CLI says it.
fn raise(kind: &'static str, message: String) -> PyErr {
    Python::attach(|py| {
        match py
            .import("optistim.errors")
            .and_then(|m| m.getattr(kind))
            .and_then(|t| t.cast_into::<PyType>().map_err(PyErr::from))
        {
            Ok(t) => PyErr::from_type(t, message),
            Err(_) => PyRuntimeError::new_err(format!("{kind}: {message}")),
        }
    })
}

fn scene_err(e: impl std::fmt::Display) -> PyErr {
    raise("SceneError", e.to_string())
}
fn pose_err(e: impl std::fmt::Display) -> PyErr {
    raise("PoseError", e.to_string())
}
fn render_err(e: impl std::fmt::Display) -> PyErr {
    raise("RenderError", e.to_string())
}

/// A JSON text as Python objects (`json.loads`).
fn from_json(py: Python<'_>, text: &str) -> PyResult<Py<PyAny>> {
    Ok(py.import("json")?.call_method1("loads", (text,))?.unbind())
}

// ---------------------------------------------------------------------------------------
// Scene

/// Where a scene came from: its TOML text and the file it names relative paths from.
#[derive(Clone)]
struct Source {
    text: String,
    file: String,
}

/// A validated scene: body, Sun, camera and detector, render settings, its own pose.
#[pyclass(frozen, module = "optistim")]
struct Scene {
    config: Arc<Config>,
    planner: Arc<Option<Planner>>,
    source: Source,
}

impl Scene {
    fn parse(source: Source) -> PyResult<Scene> {
        let config = config::parse(&source.text, &source.file).map_err(scene_err)?;
        let planner = config.planner();
        Ok(Scene {
            config: Arc::new(config),
            planner: Arc::new(planner),
            source,
        })
    }
}

#[pymethods]
impl Scene {
    /// Reads and validates a scene file (`docs/scene.md`); paths in it are relative to it.
    #[staticmethod]
    fn from_toml(path: PathBuf) -> PyResult<Scene> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(&path).map_err(|source| {
            scene_err(config::ConfigError::Read {
                file: file.clone(),
                source,
            })
        })?;
        Scene::parse(Source { text, file })
    }

    /// A scene from a dict with the TOML file's tables and keys (`{"body": {...},
    /// "camera": {...}, ...}`); relative paths are taken from `base_dir` (default: the
    /// working folder).
    #[staticmethod]
    #[pyo3(signature = (scene, base_dir = None))]
    fn from_dict(
        py: Python<'_>,
        scene: &Bound<'_, PyDict>,
        base_dir: Option<PathBuf>,
    ) -> PyResult<Scene> {
        let json: String = py
            .import("json")?
            .call_method1("dumps", (scene,))?
            .extract()
            .map_err(|_| {
                scene_err(
                    "the scene dict is not JSON-like (str keys; numbers, strings, lists, dicts)",
                )
            })?;
        let value: serde_json::Value =
            serde_json::from_str(&json).map_err(|e| scene_err(format!("the scene dict: {e}")))?;
        let text = value_to_toml(&value).map_err(|e| scene_err(format!("the scene dict: {e}")))?;
        let base = base_dir.unwrap_or_else(|| PathBuf::from("."));
        let file = base.join("<scene dict>").display().to_string();
        Scene::parse(Source { text, file })
    }

    /// The scene's own pose (`[pose]` of the file).
    #[getter]
    fn pose(&self) -> Pose {
        Pose(self.config.pose)
    }

    /// Image width and height [px].
    #[getter]
    fn size(&self) -> (usize, usize) {
        let i = &self.config.scene.camera.intrinsics;
        (i.width_px as usize, i.height_px as usize)
    }

    /// `True` under `fidelity = "budget"`: each frame's settings come from the planner.
    #[getter]
    fn budgeted(&self) -> bool {
        self.planner.is_some()
    }

    /// The scene's TOML text (a dict scene's, as converted).
    #[getter]
    fn toml(&self) -> &str {
        &self.source.text
    }

    fn __repr__(&self) -> String {
        let (w, h) = self.size();
        format!(
            "Scene({:?}, body={:?}, {w} x {h} px)",
            self.source.file, self.config.scene.body.name
        )
    }

    /// Pickled as its text and file name (Ray ships scenes to workers this way); the maps it
    /// names must be readable where it is unpickled.
    fn __reduce__(slf: &Bound<'_, Self>) -> PyResult<(Py<PyAny>, (String, String))> {
        let py = slf.py();
        let restore = py.get_type::<Scene>().getattr("_restore")?.unbind();
        let s = slf.get();
        Ok((restore, (s.source.text.clone(), s.source.file.clone())))
    }

    #[staticmethod]
    fn _restore(text: String, file: String) -> PyResult<Scene> {
        Scene::parse(Source { text, file })
    }
}

/// JSON (from the dict) to TOML text: tables, arrays, arrays of tables. `null` is refused.
fn value_to_toml(v: &serde_json::Value) -> Result<String, String> {
    fn conv(v: &serde_json::Value, key: &str) -> Result<toml_value::Value, String> {
        use serde_json::Value as J;
        Ok(match v {
            J::Null => return Err(format!("{key}: None has no TOML value")),
            J::Bool(b) => toml_value::Value::Boolean(*b),
            J::Number(n) => match n.as_i64() {
                Some(i) => toml_value::Value::Integer(i),
                None => toml_value::Value::Float(n.as_f64().unwrap_or(f64::NAN)),
            },
            J::String(s) => toml_value::Value::String(s.clone()),
            J::Array(a) => toml_value::Value::Array(
                a.iter()
                    .enumerate()
                    .map(|(i, x)| conv(x, &format!("{key}[{i}]")))
                    .collect::<Result<_, _>>()?,
            ),
            J::Object(o) => {
                let mut t = toml_value::Table::new();
                for (k, x) in o {
                    let key = if key.is_empty() {
                        k.clone()
                    } else {
                        format!("{key}.{k}")
                    };
                    t.insert(k.clone(), conv(x, &key)?);
                }
                toml_value::Value::Table(t)
            }
        })
    }
    match conv(v, "")? {
        toml_value::Value::Table(t) => toml_value::to_string(&t).map_err(|e| e.to_string()),
        _ => Err("not a dict".into()),
    }
}

/// The `toml` crate, as optistim's config reads it.
mod toml_value {
    pub use toml::{Table, Value, to_string};
}

// ---------------------------------------------------------------------------------------
// Pose

/// A pose in the body frame: camera position [m], camera -> body quaternion scalar first
/// (`docs/conventions.md`), Sun position [m], frame id (seeds the noises).
#[pyclass(frozen, module = "optistim")]
#[derive(Clone, Copy)]
struct Pose(RustPose);

#[pymethods]
impl Pose {
    #[new]
    #[pyo3(signature = (camera_position_m, quaternion_wxyz, sun_position_m, frame_id = 0))]
    fn new(
        camera_position_m: [f64; 3],
        quaternion_wxyz: [f64; 4],
        sun_position_m: [f64; 3],
        frame_id: u64,
    ) -> PyResult<Pose> {
        optistim::trajectory::pose_from(
            frame_id,
            camera_position_m,
            quaternion_wxyz,
            sun_position_m,
        )
        .map(Pose)
        .map_err(|e| pose_err(format!("pose: {e}")))
    }

    #[getter]
    fn camera_position_m(&self) -> [f64; 3] {
        self.0.camera_position_m.to_array()
    }
    #[getter]
    fn quaternion_wxyz(&self) -> [f64; 4] {
        optistim::geometry::wxyz(self.0.body_from_camera)
    }
    #[getter]
    fn sun_position_m(&self) -> [f64; 3] {
        self.0.sun_position_m.to_array()
    }
    #[getter]
    fn frame_id(&self) -> u64 {
        self.0.frame_id
    }

    fn __repr__(&self) -> String {
        format!(
            "Pose(camera_position_m={:?}, quaternion_wxyz={:?}, sun_position_m={:?}, frame_id={})",
            self.camera_position_m(),
            self.quaternion_wxyz(),
            self.sun_position_m(),
            self.0.frame_id
        )
    }
}

/// A pose from a row of 7 (camera x, y, z [m], qw, qx, qy, qz; the scene's Sun) or 10
/// (then Sun x, y, z [m]) numbers.
fn pose_from_row(
    row: &[f64],
    scene_sun: [f64; 3],
    frame_id: u64,
    what: &str,
) -> PyResult<RustPose> {
    let sun = match row.len() {
        7 => scene_sun,
        10 => [row[7], row[8], row[9]],
        n => {
            return Err(pose_err(format!(
                "{what}: {n} values; a pose is 7 (camera x, y, z [m], qw, qx, qy, qz) or 10 (and Sun x, y, z [m])"
            )));
        }
    };
    optistim::trajectory::pose_from(
        frame_id,
        [row[0], row[1], row[2]],
        [row[3], row[4], row[5], row[6]],
        sun,
    )
    .map_err(|e| pose_err(format!("{what}: {e}")))
}

/// `render`'s pose argument: a `Pose`, a sequence of 7 or 10 numbers, or `None` (the scene's).
fn pose_arg(
    scene: &Scene,
    pose: Option<&Bound<'_, PyAny>>,
    frame_id: Option<u64>,
) -> PyResult<RustPose> {
    let mut p = match pose {
        None => scene.config.pose,
        Some(obj) => {
            if let Ok(p) = obj.cast::<Pose>() {
                p.get().0
            } else {
                let row: Vec<f64> = obj.extract().map_err(|_| {
                    PyTypeError::new_err("pose: a Pose, or 7 or 10 numbers (camera [m], quaternion w, x, y, z, Sun [m])")
                })?;
                let sun = scene.config.pose.sun_position_m.to_array();
                pose_from_row(&row, sun, 0, "pose")?
            }
        }
    };
    if let Some(id) = frame_id {
        p.frame_id = id;
    }
    Ok(p)
}

// ---------------------------------------------------------------------------------------
// Rendering

/// Threads of a render: the argument, else `RAYON_NUM_THREADS`, else the CPUs this process
/// may use (its affinity mask and cgroup quota), so that several workers on one machine
/// share its cores instead of each taking all of them.
fn resolve_threads(threads: Option<usize>) -> usize {
    threads
        .filter(|&n| n > 0)
        .or_else(|| {
            std::env::var("RAYON_NUM_THREADS")
                .ok()
                .and_then(|v| v.trim().parse().ok())
                .filter(|&n: &usize| n > 0)
        })
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
}

/// Idle renderers (each owns its rayon pool and buffers) by thread count: a render takes
/// one, or makes one, and gives it back.
static RENDERERS: Mutex<Option<HashMap<usize, Vec<Renderer>>>> = Mutex::new(None);

fn with_renderer<T>(
    threads: usize,
    f: impl FnOnce(&mut Renderer) -> Result<T, optistim::app::AppError>,
) -> Result<T, optistim::app::AppError> {
    let cached = RENDERERS
        .lock()
        .ok()
        .and_then(|mut m| m.get_or_insert_with(HashMap::new).get_mut(&threads)?.pop());
    let mut renderer = match cached {
        Some(r) => r,
        None => Renderer::new(threads)?,
    };
    let out = f(&mut renderer);
    if let Ok(mut m) = RENDERERS.lock() {
        m.get_or_insert_with(HashMap::new)
            .entry(threads)
            .or_default()
            .push(renderer);
    }
    out
}

/// Renders and runs the detector with the GIL released.
fn render_pose(
    py: Python<'_>,
    scene: &Scene,
    pose: RustPose,
    threads: Option<usize>,
) -> PyResult<Frame> {
    let config = scene.config.clone();
    let planner = scene.planner.clone();
    let threads = resolve_threads(threads);
    let (meta, images) = py
        .detach(|| {
            with_renderer(threads, |r| {
                products::make(&config, planner.as_ref().as_ref(), &pose, r)
            })
        })
        .map_err(render_err)?;
    Frame::new(py, config, meta, images)
}

/// Renders one frame of `scene` (the GIL released while it renders).
///
/// `pose`: a `Pose`, 7 or 10 numbers (camera [m], quaternion w, x, y, z[, Sun [m]]), or
/// `None` for the scene's own. `frame_id` seeds the noises. `threads`: the render's rayon
/// pool (default `RAYON_NUM_THREADS`, else the CPUs this process may use).
#[pyfunction]
#[pyo3(signature = (scene, pose = None, *, frame_id = None, threads = None))]
fn render(
    py: Python<'_>,
    scene: &Scene,
    pose: Option<&Bound<'_, PyAny>>,
    frame_id: Option<u64>,
    threads: Option<usize>,
) -> PyResult<Frame> {
    let pose = pose_arg(scene, pose, frame_id)?;
    render_pose(py, scene, pose, threads)
}

/// The threads `render` uses for `threads` (see `render`).
#[pyfunction]
#[pyo3(signature = (threads = None))]
fn render_threads(threads: Option<usize>) -> usize {
    resolve_threads(threads)
}

// ---------------------------------------------------------------------------------------
// Frame

/// An image's array shape: `[height, width]` for one plane, `[planes, height, width]` else.
fn planes_shape(planes: usize, [h, w]: [usize; 2]) -> Vec<usize> {
    if planes == 1 {
        vec![h, w]
    } else {
        vec![planes, h, w]
    }
}

/// One rendered frame: images as NumPy arrays (row-major from the top-left, height x width;
/// a multi-band camera's power and signal bands x height x width, its DN too unless it is a
/// Bayer mosaic), its statistics, the settings it was rendered with and its error report.
#[pyclass(module = "optistim")]
struct Frame {
    config: Arc<Config>,
    meta: FrameMeta,
    power: Py<PyArrayDyn<f64>>,
    signal: Py<PyArrayDyn<f64>>,
    depth: Py<PyArray2<f64>>,
    dn: Py<PyArrayDyn<u16>>,
}

impl Frame {
    /// Moves the images into NumPy (no copy: the arrays own the buffers the detector filled).
    fn new(
        py: Python<'_>,
        config: Arc<Config>,
        meta: FrameMeta,
        images: products::ImageSet,
    ) -> PyResult<Frame> {
        let shape = [meta.height, meta.width];
        let det = &config.scene.camera.detector;
        let bands = planes_shape(det.bands.len(), shape);
        let dn_planes = planes_shape(det.dn_planes(), shape);
        Ok(Frame {
            power: images
                .power_w
                .into_pyarray(py)
                .reshape(&bands[..])?
                .unbind(),
            signal: images
                .signal_e_per_s
                .into_pyarray(py)
                .reshape(&bands[..])?
                .unbind(),
            depth: images.depth_m.into_pyarray(py).reshape(shape)?.unbind(),
            dn: images.dn.into_pyarray(py).reshape(&dn_planes[..])?.unbind(),
            config,
            meta,
        })
    }

    /// The frame's files in memory, from the arrays as they are now.
    fn files(&self, py: Python<'_>) -> PyResult<Vec<(&'static str, Vec<u8>)>> {
        self.with_images(py, |im| products::encode(&self.config, &self.meta, im))?
            .map_err(render_err)
    }

    /// Reads the arrays (as they are now) and hands them to `f`.
    fn with_images<T>(&self, py: Python<'_>, f: impl FnOnce(Images<'_>) -> T) -> PyResult<T> {
        let power: PyReadonlyArrayDyn<f64> = self.power.bind(py).readonly();
        let signal: PyReadonlyArrayDyn<f64> = self.signal.bind(py).readonly();
        let depth: PyReadonlyArray2<f64> = self.depth.bind(py).readonly();
        let dn: PyReadonlyArrayDyn<u16> = self.dn.bind(py).readonly();
        let shape = [self.meta.height, self.meta.width];
        let det = &self.config.scene.camera.detector;
        let bands = planes_shape(det.bands.len(), shape);
        let dn_planes = planes_shape(det.dn_planes(), shape);
        for (name, s, want) in [
            ("power", power.shape(), &bands[..]),
            ("signal", signal.shape(), &bands[..]),
            ("depth", depth.shape(), &shape[..]),
            ("dn", dn.shape(), &dn_planes[..]),
        ] {
            if s != want {
                return Err(render_err(format!(
                    "frame.{name}: shape {s:?}, the frame's is {want:?}"
                )));
            }
        }
        fn slice<'a, T>(r: Result<&'a [T], numpy::AsSliceError>, name: &str) -> PyResult<&'a [T]> {
            r.map_err(|_| render_err(format!("frame.{name} is not contiguous")))
        }
        Ok(f(Images {
            power_w: slice(power.as_slice(), "power")?,
            signal_e_per_s: slice(signal.as_slice(), "signal")?,
            depth_m: slice(depth.as_slice(), "depth")?,
            dn: slice(dn.as_slice(), "dn")?,
        }))
    }
}

#[pymethods]
impl Frame {
    /// Collected power per pixel [W] (float64, height x width; bands x height x width for a
    /// multi-band camera, in `[[camera.band]]` order).
    #[getter]
    fn power(&self, py: Python<'_>) -> Py<PyArrayDyn<f64>> {
        self.power.clone_ref(py)
    }
    /// Signal per pixel [e-/s] (float64; per band like `power`).
    #[getter]
    fn signal(&self, py: Python<'_>) -> Py<PyArrayDyn<f64>> {
        self.signal.clone_ref(py)
    }
    /// Saved DN per pixel (uint16, noise included; per band for a camera of full images per
    /// band, one height x width raw mosaic for a Bayer camera).
    #[getter]
    fn dn(&self, py: Python<'_>) -> Py<PyArrayDyn<u16>> {
        self.dn.clone_ref(py)
    }
    /// The camera's band names, in the order of the arrays' planes.
    #[getter]
    fn bands(&self) -> Vec<String> {
        let det = &self.config.scene.camera.detector;
        det.bands.iter().map(|b| b.name.clone()).collect()
    }
    /// Range from the camera to the surface per pixel [m], NaN where empty (float64).
    #[getter]
    fn depth(&self, py: Python<'_>) -> Py<PyArray2<f64>> {
        self.depth.clone_ref(py)
    }
    /// The pose the frame was rendered from.
    #[getter]
    fn pose(&self) -> Pose {
        Pose(self.meta.pose)
    }
    /// Statistics: phase [deg], quadrangles sampled and kept, covered pixels, time per stage
    /// [ms] (`timings_ms`), ...
    #[getter]
    fn stats(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        let mut v = serde_json::to_value(self.meta.stats).map_err(render_err)?;
        if let Some(o) = v.as_object_mut() {
            o.insert("detector_ms".into(), self.meta.detector_ms.into());
        }
        from_json(py, &v.to_string())
    }
    /// Every setting the frame was rendered with (the planner's under a budget).
    #[getter]
    fn settings(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        from_json(
            py,
            &serde_json::to_string(&self.meta.settings).map_err(render_err)?,
        )
    }
    /// The frame's error report under `fidelity = "budget"`: the chosen rung, the predicted
    /// relative errors (`predicted`: median and p99 per lit pixel, total), the budget and
    /// whether the prediction meets it, and what the planner saw (`features`). `None` with
    /// fixed settings (no model ran).
    #[getter]
    fn error(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        match &self.meta.plan {
            None => Ok(py.None()),
            Some(p) => from_json(py, &serde_json::to_string(p).map_err(render_err)?),
        }
    }
    #[getter]
    fn width(&self) -> usize {
        self.meta.width
    }
    #[getter]
    fn height(&self) -> usize {
        self.meta.height
    }

    /// The frame's files in memory: `{"power.fits": bytes, "signal.fits": ..., "depth.fits":
    /// ..., "image.png": ...}` (the bytes `optistim render` writes).
    fn encode<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let files = self.files(py)?;
        let d = PyDict::new(py);
        for (name, bytes) in files {
            d.set_item(name, PyBytes::new(py, &bytes))?;
        }
        Ok(d)
    }

    /// Writes `power.fits`, `signal.fits`, `depth.fits` and `image.png` into `dir` (created
    /// if missing), each whole or not at all.
    fn to_fits(&self, py: Python<'_>, dir: PathBuf) -> PyResult<()> {
        let files = self.files(py)?;
        py.detach(|| products::write_atomically(Path::new(&dir), &files))
            .map_err(render_err)
    }

    /// The frame's manifest row (`frame.json`) as JSON text, for frame `index` at `t_s` [s].
    #[pyo3(signature = (index, t_s = 0.0))]
    fn record(&self, py: Python<'_>, index: u64, t_s: f64) -> PyResult<String> {
        self.with_images(py, |im| {
            FrameRecord::new(&self.config, &self.meta, im, index, t_s).to_json()
        })
    }

    fn __repr__(&self) -> String {
        format!(
            "Frame({} x {} px, phase {:.2} deg, frame_id {})",
            self.meta.width, self.meta.height, self.meta.stats.phase_deg, self.meta.pose.frame_id
        )
    }
}

// ---------------------------------------------------------------------------------------
// Trajectories

/// `render_trajectory`'s iterator: one `Frame` per pose, rendered when asked for.
#[pyclass(module = "optistim")]
struct Trajectory {
    scene: Py<Scene>,
    poses: Vec<(f64, RustPose)>,
    next: usize,
    threads: Option<usize>,
}

#[pymethods]
impl Trajectory {
    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __next__(&mut self, py: Python<'_>) -> PyResult<Option<Frame>> {
        let Some((_, pose)) = self.poses.get(self.next).copied() else {
            return Ok(None);
        };
        self.next += 1;
        let scene = self.scene.bind(py).get();
        render_pose(py, scene, pose, self.threads).map(Some)
    }

    fn __len__(&self) -> usize {
        self.poses.len()
    }

    /// Each pose's time [s] (the file's `t_s`; the row index for arrays).
    #[getter]
    fn times_s(&self) -> Vec<f64> {
        self.poses.iter().map(|p| p.0).collect()
    }
}

/// Renders `poses` one frame at a time, as an iterator of `Frame`.
///
/// `poses`: an array of shape (N, 7) (camera x, y, z [m], qw, qx, qy, qz; the scene's Sun)
/// or (N, 10) (and Sun x, y, z [m]), or the path of a pose file (CSV or JSON lines, as in
/// `../shared/trajectories/`). Frame ids count from 0 (they seed the noises).
#[pyfunction]
#[pyo3(signature = (scene, poses, *, threads = None))]
fn render_trajectory(
    py: Python<'_>,
    scene: Py<Scene>,
    poses: &Bound<'_, PyAny>,
    threads: Option<usize>,
) -> PyResult<Trajectory> {
    let poses = read_poses(py, scene.bind(py).get(), poses)?;
    Ok(Trajectory {
        scene,
        poses,
        next: 0,
        threads,
    })
}

/// Poses of a file path or an (N, 7) / (N, 10) array, with their times.
fn read_poses(
    py: Python<'_>,
    scene: &Scene,
    poses: &Bound<'_, PyAny>,
) -> PyResult<Vec<(f64, RustPose)>> {
    if is_path(py, poses)? {
        let path: PathBuf = poses.extract()?;
        return optistim::trajectory::read(&path).map_err(pose_err);
    }
    let rows = array_rows(poses)?;
    let sun = scene.config.pose.sun_position_m.to_array();
    rows.iter()
        .enumerate()
        .map(|(i, r)| {
            Ok((
                i as f64,
                pose_from_row(r, sun, i as u64, &format!("poses[{i}]"))?,
            ))
        })
        .collect()
}

/// The poses of a file or array as an (N, 11) float64 array: t [s], camera x, y, z [m],
/// qw, qx, qy, qz, Sun x, y, z [m], as written (each row checked to be a pose): a pose
/// rebuilt from a row is the pose `render_trajectory` renders, bit for bit. This is what
/// `optistim.dataset` shards.
#[pyfunction]
fn load_poses<'py>(
    py: Python<'py>,
    scene: &Scene,
    poses: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let rows: Vec<[f64; 11]> = if is_path(py, poses)? {
        let path: PathBuf = poses.extract()?;
        optistim::trajectory::read_rows(&path)
            .map_err(pose_err)?
            .iter()
            .map(|r| {
                [
                    r.t_s, r.cam_x_m, r.cam_y_m, r.cam_z_m, r.qw, r.qx, r.qy, r.qz, r.sun_x_m,
                    r.sun_y_m, r.sun_z_m,
                ]
            })
            .collect()
    } else {
        let sun = scene.config.pose.sun_position_m.to_array();
        array_rows(poses)?
            .iter()
            .enumerate()
            .map(|(i, r)| {
                pose_from_row(r, sun, i as u64, &format!("poses[{i}]"))?;
                let s = if r.len() == 10 {
                    [r[7], r[8], r[9]]
                } else {
                    sun
                };
                Ok([
                    i as f64, r[0], r[1], r[2], r[3], r[4], r[5], r[6], s[0], s[1], s[2],
                ])
            })
            .collect::<PyResult<_>>()?
    };
    let n = rows.len();
    rows.concat().into_pyarray(py).reshape([n, 11])
}

fn is_path(py: Python<'_>, obj: &Bound<'_, PyAny>) -> PyResult<bool> {
    Ok(obj.is_instance_of::<pyo3::types::PyString>()
        || obj.is_instance(&py.import("os")?.getattr("PathLike")?)?)
}

fn array_rows(obj: &Bound<'_, PyAny>) -> PyResult<Vec<Vec<f64>>> {
    obj.extract().map_err(|_| {
        PyTypeError::new_err("poses: an (N, 7) or (N, 10) array of numbers, or a pose file path")
    })
}

/// Exposure planning along `poses` (Sec. 6.3.2, Eqs. 61-62), as `optistim exposure`.
///
/// Returns a dict: `keep`, `dnr_db`, `full_well_e`, `noise_floor_e`, `scene_exposure_s`,
/// `frames` (per frame: `t_lo_s` and `t_hi_s`, the bracket's ends; `active_px`; the loss at
/// the scene's exposure), `bracket_s` (the intersection over frames, or None), and as NumPy
/// arrays `exposures_s` (G), `saturated` and `under_noise` (N x G: the fraction of each
/// frame's active pixels lost at each exposure), `pooled_saturated` and
/// `pooled_under_noise` (G: over every frame). With `out`, also writes the CSV files and the
/// chart there.
#[pyfunction]
#[pyo3(signature = (scene, poses, *, keep = 0.95, dnr_db = None, threads = None, out = None))]
fn exposure<'py>(
    py: Python<'py>,
    scene: &Scene,
    poses: &Bound<'py, PyAny>,
    keep: f64,
    dnr_db: Option<f64>,
    threads: Option<usize>,
    out: Option<PathBuf>,
) -> PyResult<Bound<'py, PyDict>> {
    use optistim::app::exposure as ex;
    let poses = read_poses(py, scene, poses)?;
    let config = scene.config.clone();
    let plan = ex::ExposurePlan {
        keep,
        dnr_db,
        threads: resolve_threads(threads),
    };
    let report = py
        .detach(|| {
            let r = ex::run(&config, &poses, plan, &mut |_, _| {})?;
            if let Some(dir) = &out {
                ex::write(&r, dir)?;
            }
            Ok::<_, optistim::app::AppError>(r)
        })
        .map_err(|e| match e {
            optistim::app::AppError::Exposure(_) => raise("OptistimError", e.to_string()),
            e => render_err(e),
        })?;
    let d: Bound<'py, PyDict> =
        from_json(py, &serde_json::to_string(&report).map_err(render_err)?)?
            .into_bound(py)
            .cast_into()
            .map_err(PyErr::from)?;
    let g = report.exposures_s.len();
    let n = report.loss.len();
    let grid = |f: fn(&ex::Loss) -> f64| -> Vec<f64> {
        report
            .loss
            .iter()
            .flat_map(|row| row.iter().map(f))
            .collect()
    };
    d.set_item("exposures_s", report.exposures_s.clone().into_pyarray(py))?;
    d.set_item(
        "saturated",
        grid(|l| l.saturated).into_pyarray(py).reshape([n, g])?,
    )?;
    d.set_item(
        "under_noise",
        grid(|l| l.under_noise).into_pyarray(py).reshape([n, g])?,
    )?;
    let pooled = |f: fn(&ex::Loss) -> f64| -> Vec<f64> { report.pooled.iter().map(f).collect() };
    d.set_item("pooled_saturated", pooled(|l| l.saturated).into_pyarray(py))?;
    d.set_item(
        "pooled_under_noise",
        pooled(|l| l.under_noise).into_pyarray(py),
    )?;
    Ok(d)
}

// ---------------------------------------------------------------------------------------

#[pymodule]
fn _optistim(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<Scene>()?;
    m.add_class::<Pose>()?;
    m.add_class::<Frame>()?;
    m.add_class::<Trajectory>()?;
    m.add_function(wrap_pyfunction!(render, m)?)?;
    m.add_function(wrap_pyfunction!(render_trajectory, m)?)?;
    m.add_function(wrap_pyfunction!(render_threads, m)?)?;
    m.add_function(wrap_pyfunction!(load_poses, m)?)?;
    m.add_function(wrap_pyfunction!(exposure, m)?)?;
    Ok(())
}
