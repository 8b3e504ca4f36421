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
    file: Mutex<BufWriter<std::fs::File>>,
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
            file: Mutex::new(BufWriter::new(std::fs::File::create(path)?)),
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
        let mut f = self.file.lock().unwrap_or_else(|e| e.into_inner());
        let ok = serde_json::to_writer(&mut *f, e).is_ok()
            && f.write_all(b"\n").is_ok()
            && f.flush().is_ok();
        if !ok {
            tracing::error!("the recording could not be written (disk full?)");
        }
    }

    pub fn flush(&self) -> std::io::Result<()> {
        let mut f = self.file.lock().unwrap_or_else(|e| e.into_inner());
        f.flush()?;
        f.get_ref().sync_all()
    }
}
