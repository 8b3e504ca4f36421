//! `optistim render-trajectory TRAJ --scene S --out DIR [--shard I/N]`: every pose of a
//! trajectory (or one shard of it) rendered to a dataset folder, resumable.
//!
//! Layout of `DIR` (the same as `optistim.dataset.generate` writes, on Ray or not):
//!
//! ```text
//! DIR/frames/000000/power.fits  signal.fits  depth.fits  image.png  frame.json
//! DIR/frames/000001/...
//! DIR/manifest.jsonl            one FrameRecord per line, by index
//!                               (manifest-I-of-N.jsonl for shard I of N)
//! ```
//!
//! A frame is finished when its `frame.json` exists: it is written last, and every file is
//! written under a temporary name then renamed ([`products::write_atomically`]), so a killed
//! run leaves no truncated file and a rerun renders only the frames without `frame.json`,
//! rewriting nothing that was finished.

use super::AppError;
use super::products::{self, FrameRecord};
use crate::config::Config;
use crate::render::Renderer;
use crate::scene::Pose;
use serde::Serialize;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Shard `index` of `count` (from 0): a contiguous block of the trajectory's frames.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
}

impl Shard {
    pub const WHOLE: Shard = Shard { index: 0, count: 1 };

    /// Parses `I/N` with `0 <= I < N`.
    pub fn parse(text: &str) -> Result<Shard, String> {
        let bad = || format!("--shard {text:?}: expected I/N with 0 <= I < N, e.g. 0/4");
        let (i, n) = text.split_once('/').ok_or_else(bad)?;
        let index: usize = i.trim().parse().map_err(|_| bad())?;
        let count: usize = n.trim().parse().map_err(|_| bad())?;
        if count == 0 || index >= count {
            return Err(bad());
        }
        Ok(Shard { index, count })
    }

    /// The frames of this shard among `len`: blocks differ in size by at most one frame.
    pub fn range(&self, len: usize) -> Range<usize> {
        len * self.index / self.count..len * (self.index + 1) / self.count
    }

    /// The manifest's file name.
    pub fn manifest_name(&self) -> String {
        if *self == Shard::WHOLE {
            "manifest.jsonl".into()
        } else {
            format!("manifest-{}-of-{}.jsonl", self.index, self.count)
        }
    }
}

/// What a run did.
#[derive(Debug, Serialize)]
pub struct TrajectoryReport {
    /// Frames in this shard.
    pub frames: usize,
    /// Frames rendered by this run.
    pub rendered: usize,
    /// Frames already finished by an earlier run (not rendered, not rewritten).
    pub resumed: usize,
    /// Wall time of the run [s], and rendered frames per second.
    pub seconds: f64,
    pub frames_per_s: f64,
    pub threads: usize,
    pub manifest: PathBuf,
}

/// The finished record of frame `index` under `root`, if there is one.
pub fn finished(root: &Path, index: u64) -> Option<FrameRecord> {
    let path = root.join(products::frame_dir(index)).join("frame.json");
    let text = std::fs::read_to_string(path).ok()?;
    serde_json::from_str::<FrameRecord>(&text)
        .ok()
        .filter(|r| r.index == index)
}

/// Writes a rendered frame into `root` (the images, then `frame.json`) and returns its record.
pub fn write_frame(
    config: &Config,
    root: &Path,
    index: u64,
    t_s: f64,
    meta: &products::FrameMeta,
    images: &products::ImageSet,
) -> Result<FrameRecord, AppError> {
    let files = products::encode(config, meta, images.view())?;
    let record = FrameRecord::new(config, meta, images.view(), index, t_s);
    let dir = root.join(products::frame_dir(index));
    products::write_atomically(&dir, &files)?;
    products::write_atomically(&dir, &[("frame.json", record.to_json().into_bytes())])?;
    Ok(record)
}

/// A rendered frame on its way to the writer.
struct Rendered {
    index: u64,
    t_s: f64,
    meta: products::FrameMeta,
    images: products::ImageSet,
}

/// Renders the frames of `shard` of `poses` (time [s] and pose, frame ids as read) into
/// `out`, skipping finished ones; `on_frame(done, total)` after each frame. Frames are
/// encoded and written by a second thread while the next one renders (at most two wait), so
/// the serial file work overlaps the render instead of leaving cores idle.
pub fn run(
    config: &Config,
    poses: &[(f64, Pose)],
    out: &Path,
    shard: Shard,
    threads: usize,
    on_frame: &mut dyn FnMut(usize, usize),
) -> Result<TrajectoryReport, AppError> {
    std::fs::create_dir_all(out).map_err(|source| AppError::OutDir {
        path: out.display().to_string(),
        source,
    })?;
    let range = shard.range(poses.len());
    let total = range.len();
    let mut renderer = Renderer::new(threads)?;
    let planner = config.planner();
    let t0 = Instant::now();
    let (mut rendered, mut resumed) = (0, 0);
    let records = std::thread::scope(|scope| {
        let (to_writer, inbox) = std::sync::mpsc::sync_channel::<Rendered>(1);
        let (to_main, written) = std::sync::mpsc::channel::<Result<FrameRecord, AppError>>();
        scope.spawn(move || {
            for f in inbox {
                let r = write_frame(config, out, f.index, f.t_s, &f.meta, &f.images);
                let failed = r.is_err();
                if to_main.send(r).is_err() || failed {
                    return;
                }
            }
        });
        // Records by position in the shard: finished ones now, rendered ones as written
        // (the writer answers in the order it was handed frames).
        let mut records: Vec<Option<FrameRecord>> = vec![None; total];
        let mut queued = std::collections::VecDeque::new();
        let mut done = 0;
        for (slot, index) in range.enumerate() {
            let (t_s, pose) = &poses[index];
            if let Some(r) = finished(out, index as u64) {
                resumed += 1;
                records[slot] = Some(r);
                done += 1;
            } else {
                rendered += 1;
                let (meta, images) = products::make(config, planner.as_ref(), pose, &mut renderer)?;
                queued.push_back(slot);
                let job = Rendered {
                    index: index as u64,
                    t_s: *t_s,
                    meta,
                    images,
                };
                if to_writer.send(job).is_err() {
                    break; // the writer stopped on an error, which waits in `written`
                }
            }
            while let Some(&slot) = queued.front() {
                let Ok(r) = written.try_recv() else { break };
                queued.pop_front();
                records[slot] = Some(r?);
                done += 1;
            }
            on_frame(done, total);
        }
        drop(to_writer);
        while let Some(slot) = queued.pop_front() {
            let Ok(r) = written.recv() else { break };
            records[slot] = Some(r?);
            done += 1;
            on_frame(done, total);
        }
        Ok::<_, AppError>(records)
    })?;
    let records: Vec<FrameRecord> = records.into_iter().flatten().collect();
    if records.len() != total {
        return Err(AppError::Images(format!(
            "{} of {total} frames written to {}",
            records.len(),
            out.display()
        )));
    }
    let seconds = t0.elapsed().as_secs_f64();
    let manifest: String = records.iter().map(|r| r.to_json() + "\n").collect();
    let name = shard.manifest_name();
    products::write_atomically(out, &[(name.as_str(), manifest.into_bytes())])?;
    Ok(TrajectoryReport {
        frames: total,
        rendered,
        resumed,
        seconds,
        frames_per_s: if seconds > 0.0 {
            rendered as f64 / seconds
        } else {
            0.0
        },
        threads: renderer.threads(),
        manifest: out.join(name),
    })
}

#[cfg(test)]
mod tests {
    use super::Shard;

    #[test]
    fn shards_cover_every_frame_once() {
        for len in [0, 1, 7, 64, 65] {
            for count in 1..6 {
                let mut next = 0;
                for index in 0..count {
                    let r = Shard { index, count }.range(len);
                    assert_eq!(r.start, next);
                    next = r.end;
                }
                assert_eq!(next, len);
            }
        }
        assert_eq!(Shard::parse("1/4"), Ok(Shard { index: 1, count: 4 }));
        for bad in ["4/4", "1", "a/2", "0/0", "-1/3"] {
            assert!(Shard::parse(bad).is_err(), "{bad}");
        }
    }
}
