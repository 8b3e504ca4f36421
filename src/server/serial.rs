//! The serial line: the same binary frames as TCP through `serialport`. A reader and a writer
//! thread bridge the (blocking) port to an in-memory duplex stream that the ordinary
//! connection handler serves. When the line goes away (a cable pulled, a pty closed) the
//! port is reopened every second until the daemon stops.

use super::Shared;
use super::connection::{self, Wire};
use std::io::{Read, Write};
use std::sync::Arc;
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

/// Opens `path` at `baud` (failing now if it cannot be opened) and serves it from then on.
pub fn spawn(
    path: &str,
    baud: u32,
    shared: Arc<Shared>,
    rt: tokio::runtime::Handle,
) -> Result<(), String> {
    let port = open(path, baud)?;
    let path = path.to_string();
    std::thread::Builder::new()
        .name("optistim-serial".into())
        .spawn(move || {
            let mut port = Some(port);
            while !*shared.shutdown.borrow() {
                let p = match port.take() {
                    Some(p) => p,
                    None => match open(&path, baud) {
                        Ok(p) => p,
                        Err(_) => {
                            std::thread::sleep(Duration::from_secs(1));
                            continue;
                        }
                    },
                };
                tracing::info!(%path, baud, "serial line open");
                serve_port(p, &path, &shared, &rt);
                tracing::warn!(%path, "serial line closed; reopening");
                std::thread::sleep(Duration::from_millis(200));
            }
        })
        .map_err(|e| e.to_string())?;
    Ok(())
}

fn open(path: &str, baud: u32) -> Result<Box<dyn serialport::SerialPort>, String> {
    serialport::new(path, baud)
        .timeout(Duration::from_millis(50))
        .open()
        .map_err(|e| e.to_string())
}

/// Serves one opened port until it fails or the daemon stops.
fn serve_port(
    mut port: Box<dyn serialport::SerialPort>,
    path: &str,
    shared: &Arc<Shared>,
    rt: &tokio::runtime::Handle,
) {
    let Ok(mut port_out) = port.try_clone() else {
        tracing::error!(%path, "cannot clone the serial port for writing");
        return;
    };
    let (daemon_side, bridge_side) = tokio::io::duplex(64 * 1024);
    let (mut from_daemon, mut to_daemon) = tokio::io::split(bridge_side);
    let conn = rt.spawn(connection::serve(
        daemon_side,
        format!("serial:{path}"),
        Wire::Binary,
        shared.clone(),
    ));
    // Writer: daemon -> port.
    let writer_rt = rt.clone();
    let writer = std::thread::spawn(move || {
        let mut buf = vec![0u8; 64 * 1024];
        loop {
            match writer_rt.block_on(from_daemon.read(&mut buf)) {
                Ok(0) | Err(_) => break,
                Ok(n) => {
                    if port_out.write_all(&buf[..n]).is_err() {
                        break;
                    }
                }
            }
        }
    });
    // Reader: port -> daemon, on this thread.
    let mut buf = vec![0u8; 4096];
    while !*shared.shutdown.borrow() {
        match port.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => {
                if rt.block_on(to_daemon.write_all(&buf[..n])).is_err() {
                    break;
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => continue,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(_) => break,
        }
    }
    let _ = rt.block_on(to_daemon.shutdown());
    drop(to_daemon);
    let _ = rt.block_on(conn);
    let _ = writer.join();
}
