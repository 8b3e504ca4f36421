//! The recording: every message the daemon receives, with its arrival time on the daemon's
//! monotonic clock [ns] and its peer, as JSON lines; bad messages are recorded as their
//! error. A message is written (and handed to the OS) before it is acted on, so that no
//! acknowledged frame is missing from the recording. `optistim replay` reads it back.
//!
//! ```text
//! {"t_ns":1234,"peer":"tcp:127.0.0.1:50312","msg":{"type":"pose","frame_id":0,...}}
//! {"t_ns":1301,"peer":"tcp:127.0.0.1:50312","error":{"code":"bad_crc","message":"..."}}
//! ```

use super::protocol::{Message, ProtocolError};
use serde::Serialize;
use std::collections::VecDeque;
use std::io::Write;
use std::path::Path;
use std::sync::Mutex;

/// Entries held in memory while the disk refuses them, at most (then new ones are lost,
/// counted).
const MAX_HELD_BYTES: usize = 64 << 20;

pub struct Recorder {
    path: String,
    sink: Mutex<Sink>,
    written: std::sync::atomic::AtomicU64,
    failed: std::sync::atomic::AtomicU64,
    lost: std::sync::atomic::AtomicU64,
    last_error: Mutex<Option<String>>,
}

/// Where the entries go: a file, which syncs to the disk at the end.
trait Out: Write + Send {
    fn sync(&mut self) -> std::io::Result<()>;
}

impl Out for std::fs::File {
    fn sync(&mut self) -> std::io::Result<()> {
        self.sync_all()
    }
}

/// The file and the whole entries not yet handed to it, oldest first. Entries go out whole
/// and in order: a disk that fills mid-entry and frees later leaves no broken line.
struct Sink {
    out: Box<dyn Out>,
    held: VecDeque<Vec<u8>>,
    /// Bytes of the first held entry already handed to the OS.
    sent: usize,
    held_bytes: usize,
}

impl Sink {
    /// Hands held entries to the OS until one is refused, counting in `written` those fully
    /// handed.
    fn drain(&mut self, written: &std::sync::atomic::AtomicU64) -> std::io::Result<()> {
        while let Some(first) = self.held.front() {
            match self.out.write(&first[self.sent..]) {
                Ok(0) => return Err(std::io::ErrorKind::WriteZero.into()),
                Ok(n) => {
                    self.sent += n;
                    if self.sent == first.len() {
                        self.held_bytes -= first.len();
                        self.held.pop_front();
                        self.sent = 0;
                        written.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    }
                }
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        Ok(())
    }
}

/// How the recording fares (`/status`, and the acks' `recording_failed`).
#[derive(Clone, Debug, Serialize)]
pub struct RecordingHealth {
    pub path: String,
    /// Entries handed to the OS.
    pub written: u64,
    /// Writes the disk refused (the daemon serves on; the refused entries are held, whole
    /// and in order, and go out when the disk frees up).
    pub failed: u64,
    /// Entries held in memory, waiting for the disk.
    pub held: u64,
    /// Entries lost: the disk refused them while 64 MB were already held.
    pub lost: u64,
    pub last_error: Option<String>,
}

#[derive(Serialize)]
struct Entry<'a> {
    t_ns: u64,
    peer: &'a str,
    #[serde(skip_serializing_if = "Option::is_none")]
    msg: Option<&'a Message>,
    #[serde(skip_serializing_if = "Option::is_none")]
    error: Option<&'a ProtocolError>,
}

impl Recorder {
    /// Creates (or truncates) the recording file.
    pub fn create(path: &Path) -> std::io::Result<Recorder> {
        let file = std::fs::File::create(path)?;
        Ok(Recorder::to_sink(
            &path.display().to_string(),
            Box::new(file),
        ))
    }

    /// A recording written to `out` (named `path` in reports).
    fn to_sink(path: &str, out: Box<dyn Out>) -> Recorder {
        Recorder {
            path: path.to_string(),
            sink: Mutex::new(Sink {
                out,
                held: VecDeque::new(),
                sent: 0,
                held_bytes: 0,
            }),
            written: Default::default(),
            failed: Default::default(),
            lost: Default::default(),
            last_error: Mutex::new(None),
        }
    }

    pub fn message(&self, peer: &str, t_ns: u64, m: &Message) {
        self.write(&Entry {
            t_ns,
            peer,
            msg: Some(m),
            error: None,
        });
    }

    pub fn error(&self, peer: &str, t_ns: u64, e: &ProtocolError) {
        self.write(&Entry {
            t_ns,
            peer,
            msg: None,
            error: Some(e),
        });
    }

    fn write(&self, e: &Entry) {
        use std::sync::atomic::Ordering::Relaxed;
        let mut line = match serde_json::to_vec(e) {
            Ok(l) => l,
            Err(err) => return self.refused(&err.into()),
        };
        line.push(b'\n');
        let mut s = self.sink.lock().unwrap_or_else(|e| e.into_inner());
        if s.held_bytes + line.len() > MAX_HELD_BYTES {
            self.lost.fetch_add(1, Relaxed);
        } else {
            s.held_bytes += line.len();
            s.held.push_back(line);
        }
        if let Err(err) = s.drain(&self.written) {
            self.refused(&err);
        }
    }

    fn refused(&self, err: &std::io::Error) {
        use std::sync::atomic::Ordering::Relaxed;
        let n = self.failed.fetch_add(1, Relaxed) + 1;
        // Logged at the first failure and then every 1000th, not per message.
        if n == 1 || n % 1000 == 0 {
            tracing::error!(path = %self.path, failed = n, "recording: {err}");
        }
        *self.last_error.lock().unwrap_or_else(|e| e.into_inner()) = Some(err.to_string());
    }

    pub fn health(&self) -> RecordingHealth {
        use std::sync::atomic::Ordering::Relaxed;
        let held = self
            .sink
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .held
            .len() as u64;
        RecordingHealth {
            path: self.path.clone(),
            written: self.written.load(Relaxed),
            failed: self.failed.load(Relaxed),
            held,
            lost: self.lost.load(Relaxed),
            last_error: self
                .last_error
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .clone(),
        }
    }

    /// Hands every held entry to the disk and syncs; an error if any is still held or lost.
    pub fn flush(&self) -> std::io::Result<()> {
        let mut s = self.sink.lock().unwrap_or_else(|e| e.into_inner());
        s.drain(&self.written)?;
        s.out.flush()?;
        s.out.sync()?;
        let lost = self.lost.load(std::sync::atomic::Ordering::Relaxed);
        if lost > 0 {
            return Err(std::io::Error::other(format!(
                "{lost} entries were lost while the disk was full"
            )));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::server::protocol::PoseMsg;
    use std::sync::Arc;

    /// A disk of `room` bytes that takes part of a write before it refuses the rest.
    #[derive(Clone, Default)]
    struct Disk(Arc<Mutex<(Vec<u8>, usize)>>);

    impl Write for Disk {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            let mut d = self.0.lock().unwrap();
            let free = d.1.saturating_sub(d.0.len());
            if free == 0 {
                return Err(std::io::Error::from_raw_os_error(28)); // ENOSPC
            }
            let n = free.min(buf.len());
            d.0.extend_from_slice(&buf[..n]);
            Ok(n)
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    impl Out for Disk {
        fn sync(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn a_disk_that_fills_mid_entry_and_frees_later_gets_every_entry_whole_and_in_order() {
        let disk = Disk::default();
        disk.0.lock().unwrap().1 = 300;
        let r = Recorder::to_sink("disk", Box::new(disk.clone()));
        let pose = |i: u64| {
            Message::Pose(PoseMsg {
                frame_id: i,
                time_tag_s: i as f64,
                camera_position_m: [1e8, 0.0, 0.0],
                attitude_wxyz: [1.0, 0.0, 0.0, 0.0],
                sun_position_m: [1.5e11, 0.0, 0.0],
                body_attitude_wxyz: None,
                exposure_s: None,
                bodies: None,
            })
        };
        for i in 0..10 {
            r.message("tcp:test", i, &pose(i));
        }
        let h = r.health();
        assert!(h.written >= 1 && h.held > 0 && h.failed > 0, "{h:?}");
        assert_eq!(h.written + h.held, 10);
        assert!(h.last_error.unwrap().contains("No space left"));
        // The disk frees up: the next entry takes the held ones out before it.
        disk.0.lock().unwrap().1 = usize::MAX;
        r.message("tcp:test", 10, &pose(10));
        let h = r.health();
        assert_eq!((h.written, h.held, h.lost), (11, 0, 0), "{h:?}");
        r.flush().unwrap();
        let text = String::from_utf8(disk.0.lock().unwrap().0.clone()).unwrap();
        let ids: Vec<u64> = text
            .lines()
            .map(|l| {
                let v: serde_json::Value = serde_json::from_str(l).unwrap();
                v["msg"]["frame_id"].as_u64().unwrap()
            })
            .collect();
        assert_eq!(ids, (0..11).collect::<Vec<_>>());
    }
}
