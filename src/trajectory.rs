//! Pose streams (`../shared/trajectories/`): CSV with a header row, or JSON lines with the
//! same keys. Positions in metres in the body frame; quaternion scalar first, camera -> body.

use crate::geometry::body_from_camera_wxyz;
use crate::scene::Pose;
use glam::DVec3;
use serde::Deserialize;
use std::path::Path;

#[derive(Debug, thiserror::Error)]
pub enum TrajectoryError {
    #[error("{file}: cannot read: {source}")]
    Read {
        file: String,
        source: std::io::Error,
    },
    #[error("{file}: line {line}: {message}")]
    Row {
        file: String,
        line: u64,
        message: String,
    },
    #[error("{file}: no poses")]
    Empty { file: String },
}

/// One row of a pose stream (extra columns are ignored).
#[derive(Clone, Debug, Deserialize)]
pub struct Row {
    pub t_s: f64,
    pub cam_x_m: f64,
    pub cam_y_m: f64,
    pub cam_z_m: f64,
    pub sun_x_m: f64,
    pub sun_y_m: f64,
    pub sun_z_m: f64,
    pub qw: f64,
    pub qx: f64,
    pub qy: f64,
    pub qz: f64,
}

impl Row {
    /// The row's pose, validated (see [`pose_from`]).
    pub fn pose(&self, frame_id: u64) -> Result<Pose, String> {
        if !self.t_s.is_finite() {
            return Err("non-finite value".into());
        }
        pose_from(
            frame_id,
            [self.cam_x_m, self.cam_y_m, self.cam_z_m],
            [self.qw, self.qx, self.qy, self.qz],
            [self.sun_x_m, self.sun_y_m, self.sun_z_m],
        )
    }
}

/// A pose from plain numbers: camera and Sun positions in the body frame [m], the
/// camera -> body quaternion scalar first; refused when a value is not finite or the
/// quaternion's norm is off 1 by more than 1e-6 (it is then normalised exactly).
pub fn pose_from(
    frame_id: u64,
    camera_position_m: [f64; 3],
    q_wxyz: [f64; 4],
    sun_position_m: [f64; 3],
) -> Result<Pose, String> {
    if camera_position_m
        .iter()
        .chain(&q_wxyz)
        .chain(&sun_position_m)
        .any(|x| !x.is_finite())
    {
        return Err("non-finite value".into());
    }
    let n = q_wxyz.iter().map(|x| x * x).sum::<f64>().sqrt();
    if (n - 1.0).abs() > 1e-6 {
        return Err(format!("quaternion norm {n} is not 1"));
    }
    Ok(Pose {
        frame_id,
        camera_position_m: DVec3::from_array(camera_position_m),
        body_from_camera: body_from_camera_wxyz(q_wxyz.map(|x| x / n)),
        sun_position_m: DVec3::from_array(sun_position_m),
    })
}

/// Reads a `.csv` or `.jsonl` pose stream; frame ids count from 0.
pub fn read(path: &Path) -> Result<Vec<(f64, Pose)>, TrajectoryError> {
    read_with(path, |row, id| Ok((row.t_s, row.pose(id)?)))
}

/// The rows of a pose stream as written (each one's pose validated): what a dataset shards,
/// so that a pose rebuilt from a row elsewhere is the pose [`read`] gives, bit for bit.
pub fn read_rows(path: &Path) -> Result<Vec<Row>, TrajectoryError> {
    read_with(path, |row, id| row.pose(id).map(|_| row.clone()))
}

fn read_with<T>(
    path: &Path,
    each: impl Fn(&Row, u64) -> Result<T, String>,
) -> Result<Vec<T>, TrajectoryError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|source| TrajectoryError::Read {
        file: file.clone(),
        source,
    })?;
    let row_err = |line: u64, message: String| TrajectoryError::Row {
        file: file.clone(),
        line,
        message,
    };
    let mut out = Vec::new();
    if path.extension().is_some_and(|e| e == "jsonl") {
        for (i, line) in text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty())
        {
            let row: Row =
                serde_json::from_str(line).map_err(|e| row_err(i as u64 + 1, e.to_string()))?;
            out.push(each(&row, out.len() as u64).map_err(|e| row_err(i as u64 + 1, e))?);
        }
    } else {
        let mut rdr = csv::Reader::from_reader(text.as_bytes());
        for rec in rdr.deserialize::<Row>() {
            let row =
                rec.map_err(|e| row_err(e.position().map_or(0, |p| p.line()), e.to_string()))?;
            let line = out.len() as u64 + 2;
            out.push(each(&row, out.len() as u64).map_err(|e| row_err(line, e))?);
        }
    }
    if out.is_empty() {
        return Err(TrajectoryError::Empty { file });
    }
    Ok(out)
}
