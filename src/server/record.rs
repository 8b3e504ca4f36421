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
use std::io::{BufWriter, Write};
use std::path::Path;
use std::sync::Mutex;

pub struct Recorder {
    path: String,
    file: Mutex<BufWriter<std::fs::File>>,
    written: std::sync::atomic::AtomicU64,
    failed: std::sync::atomic::AtomicU64,
    last_error: Mutex<Option<String>>,
}

/// How the recording fares (`/status`, and the acks' `recording_failed`).
#[derive(Clone, Debug, Serialize)]
pub struct RecordingHealth {
    pub path: String,
    /// Entries handed to the OS.
    pub written: u64,
    /// Entries that could not be written (the daemon serves on; a failed entry stays in the
    /// writer's buffer, bounded, and goes out if the disk frees up).
    pub failed: u64,
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
        Ok(Recorder {
            path: path.display().to_string(),
            file: Mutex::new(BufWriter::new(std::fs::File::create(path)?)),
            written: Default::default(),
            failed: Default::default(),
            last_error: Mutex::new(None),
        })
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
        let mut f = self.file.lock().unwrap_or_else(|e| e.into_inner());
        let r = serde_json::to_writer(&mut *f, e)
            .map_err(std::io::Error::from)
            .and_then(|()| f.write_all(b"\n"))
            .and_then(|()| f.flush());
        match r {
            Ok(()) => {
                self.written.fetch_add(1, Relaxed);
            }
            Err(err) => {
                let n = self.failed.fetch_add(1, Relaxed) + 1;
                // Logged at the first failure and then every 1000th, not per message.
                if n == 1 || n % 1000 == 0 {
                    tracing::error!(path = %self.path, failed = n, "recording: {err}");
                }
                *self.last_error.lock().unwrap_or_else(|e| e.into_inner()) = Some(err.to_string());
            }
        }
    }

    pub fn health(&self) -> RecordingHealth {
        use std::sync::atomic::Ordering::Relaxed;
        RecordingHealth {
            path: self.path.clone(),
            written: self.written.load(Relaxed),
            failed: self.failed.load(Relaxed),
            last_error: self
                .last_error
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .clone(),
        }
    }

    pub fn flush(&self) -> std::io::Result<()> {
        let mut f = self.file.lock().unwrap_or_else(|e| e.into_inner());
        f.flush()?;
        f.get_ref().sync_all()
    }
}
