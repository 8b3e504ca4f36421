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
#[derive(Debug, Deserialize)]
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
    fn pose(&self, frame_id: u64) -> Result<Pose, String> {
        let v = [
            self.t_s,
            self.cam_x_m,
            self.cam_y_m,
            self.cam_z_m,
            self.sun_x_m,
            self.sun_y_m,
            self.sun_z_m,
            self.qw,
            self.qx,
            self.qy,
            self.qz,
        ];
        if v.iter().any(|x| !x.is_finite()) {
            return Err("non-finite value".into());
        }
        let q = [self.qw, self.qx, self.qy, self.qz];
        let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
        if (n - 1.0).abs() > 1e-6 {
            return Err(format!("quaternion norm {n} is not 1"));
        }
        Ok(Pose {
            frame_id,
            camera_position_m: DVec3::new(self.cam_x_m, self.cam_y_m, self.cam_z_m),
            body_from_camera: body_from_camera_wxyz(q.map(|x| x / n)),
            sun_position_m: DVec3::new(self.sun_x_m, self.sun_y_m, self.sun_z_m),
        })
    }
}

/// Reads a `.csv` or `.jsonl` pose stream; frame ids count from 0.
pub fn read(path: &Path) -> Result<Vec<(f64, Pose)>, TrajectoryError> {
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
            out.push((
                row.t_s,
                row.pose(out.len() as u64)
                    .map_err(|e| row_err(i as u64 + 1, e))?,
            ));
        }
    } else {
        let mut rdr = csv::Reader::from_reader(text.as_bytes());
        for rec in rdr.deserialize::<Row>() {
            let row =
                rec.map_err(|e| row_err(e.position().map_or(0, |p| p.line()), e.to_string()))?;
            let line = out.len() as u64 + 2;
            out.push((
                row.t_s,
                row.pose(out.len() as u64).map_err(|e| row_err(line, e))?,
            ));
        }
    }
    if out.is_empty() {
        return Err(TrajectoryError::Empty { file });
    }
    Ok(out)
}
