//! A CORTO-compatible endpoint (`optistim serve --corto-pose UDP_ADDR --corto-image
//! TCP_ADDR`): CORTO's decoupled in-the-loop client (`../shared/clients/corto`, unchanged)
//! connects to the image port, then sends each pose as one UDP datagram and waits for the
//! image on the TCP connection.
//!
//! - **Pose datagram**: big-endian f64: the Sun's position (3), the camera's position and
//!   quaternion `w x y z` (7), the body's position and quaternion (7): 17 values, as the
//!   published client packs them (its docstring's 21-value layout, with a Sun quaternion after
//!   the Sun's position, is accepted too; the Sun's quaternion is ignored). Positions in
//!   Blender units, converted with the scene's `[corto] metres_per_unit`; quaternions rotate
//!   object axes into world axes; the camera has Blender's axes (X right, Y up, looking
//!   along -Z).
//! - **Image**: u64 little-endian byte count, then a PNG: the scene camera's DN at its saved
//!   bits, exactly `optistim render`'s `image.png` for that pose, the n-th pose's noise seeded
//!   by n (from 0, per image connection).
//!
//! Each pose goes through the frame thread like any other (and onto the stimulator's screen);
//! its `(P/L)` comes back for the client's image. A datagram that is not a pose is counted and
//! logged and gets no image (the protocol has no way to answer it). The threads block on
//! their sockets (never the async runtime).

use super::Shared;
use crate::config::Config;
use glam::{DQuat, DVec3};
use std::io::Write;
use std::net::{TcpListener, TcpStream, UdpSocket};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// A pose, decoded: world frame positions [Blender units], quaternions `w x y z`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CortoPose {
    pub sun: [f64; 3],
    pub camera: [f64; 3],
    pub camera_wxyz: [f64; 4],
    pub body: [f64; 3],
    pub body_wxyz: [f64; 4],
}

/// Decodes a datagram of 17 (or 21) big-endian doubles.
pub fn decode(d: &[u8]) -> Result<CortoPose, String> {
    let v: Vec<f64> = d
        .chunks_exact(8)
        .map(|c| f64::from_be_bytes(c.try_into().expect("8 bytes")))
        .collect();
    let off = match d.len() {
        136 => 0,
        168 => 4,
        n => {
            return Err(format!(
                "a pose datagram of {n} bytes: 17 big-endian doubles (136 bytes) are expected \
                 (or 21, 168 bytes, with a Sun quaternion)"
            ));
        }
    };
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        return Err(format!("value {i} of the pose is {}", v[i]));
    }
    let q = |i: usize| [v[i], v[i + 1], v[i + 2], v[i + 3]];
    let p = |i: usize| [v[i], v[i + 1], v[i + 2]];
    Ok(CortoPose {
        sun: p(0),
        camera: p(3 + off),
        camera_wxyz: q(6 + off),
        body: p(10 + off),
        body_wxyz: q(13 + off),
    })
}

fn unit(name: &str, q: [f64; 4]) -> Result<DQuat, String> {
    let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    if (n - 1.0).abs() > 1e-6 {
        return Err(format!("{name} quaternion {q:?} has norm {n}, not 1"));
    }
    Ok(DQuat::from_xyzw(q[1] / n, q[2] / n, q[3] / n, q[0] / n))
}

/// The scene's pose for a CORTO pose (body frame, metres, optistim's camera axes).
pub fn to_pose(
    p: &CortoPose,
    metres_per_unit: f64,
    frame_id: u64,
) -> Result<crate::scene::Pose, String> {
    let body_from_world = unit("body", p.body_wxyz)?.inverse();
    let world_from_blender_camera = unit("camera", p.camera_wxyz)?;
    // Blender's camera axes from optistim's: a half turn about X.
    let flip = DQuat::from_xyzw(1.0, 0.0, 0.0, 0.0);
    let b = DVec3::from_array(p.body);
    let m = |x: [f64; 3]| body_from_world * ((DVec3::from_array(x) - b) * metres_per_unit);
    Ok(crate::scene::Pose {
        frame_id,
        camera_position_m: m(p.camera),
        body_from_camera: body_from_world * world_from_blender_camera * flip,
        sun_position_m: m(p.sun),
    })
}

/// Serves CORTO clients until shutdown: an acceptor for the image port and a pose thread.
pub fn spawn(
    udp: UdpSocket,
    tcp: TcpListener,
    shared: Arc<Shared>,
) -> std::io::Result<Vec<std::thread::JoinHandle<()>>> {
    let conn: Arc<Mutex<Option<(TcpStream, u64)>>> = Arc::new(Mutex::new(None));
    tcp.set_nonblocking(true)?;
    udp.set_read_timeout(Some(Duration::from_millis(200)))?;
    let acceptor = {
        let (conn, shared) = (conn.clone(), shared.clone());
        std::thread::Builder::new()
            .name("optistim-corto-accept".into())
            .spawn(move || {
                while !*shared.shutdown.borrow() {
                    match tcp.accept() {
                        Ok((s, peer)) => {
                            let _ = s.set_nonblocking(false);
                            let _ = s.set_nodelay(true);
                            tracing::info!(%peer, "CORTO image client connected");
                            // The latest client gets the images, as CORTO's own server.
                            *conn.lock().unwrap_or_else(|e| e.into_inner()) = Some((s, 0));
                        }
                        Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                            std::thread::sleep(Duration::from_millis(20));
                        }
                        Err(e) => {
                            tracing::warn!("CORTO accept: {e}");
                            std::thread::sleep(Duration::from_millis(50));
                        }
                    }
                }
            })?
    };
    let poses = std::thread::Builder::new()
        .name("optistim-corto-poses".into())
        .spawn(move || pose_loop(udp, conn, shared))?;
    Ok(vec![acceptor, poses])
}

fn pose_loop(udp: UdpSocket, conn: Arc<Mutex<Option<(TcpStream, u64)>>>, shared: Arc<Shared>) {
    let mut link = super::CompatLink::new(shared.clone());
    let mut buf = [0u8; 2048];
    while !*shared.shutdown.borrow() {
        let (n, from) = match udp.recv_from(&mut buf) {
            Ok(x) => x,
            Err(_) => continue, // the timeout: look at shutdown
        };
        let config = shared.scene().config;
        // The client connects to the image port before it sends a pose; the acceptor may
        // not have taken the connection yet: give it 2 s.
        for _ in 0..400 {
            if conn.lock().unwrap_or_else(|e| e.into_inner()).is_some() {
                break;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        let mut slot = conn.lock().unwrap_or_else(|e| e.into_inner());
        let Some((stream, count)) = slot.as_mut() else {
            shared.stats.protocol_errors.inc();
            tracing::warn!(%from, "CORTO pose with no image client connected: not rendered");
            continue;
        };
        let png = decode(&buf[..n]).and_then(|p| {
            let pose = to_pose(&p, config.corto_metres_per_unit.unwrap_or(1.0), *count)?;
            let pl = link.present(pose, None)?;
            image_png(&config, &pose, &pl)
        });
        match png {
            Ok(png) => {
                *count += 1;
                let mut msg = (png.len() as u64).to_le_bytes().to_vec();
                msg.extend_from_slice(&png);
                if let Err(e) = stream.write_all(&msg) {
                    tracing::warn!("CORTO image client gone: {e}");
                    *slot = None;
                }
            }
            Err(e) => {
                shared.stats.protocol_errors.inc();
                tracing::warn!(%from, "CORTO pose refused: {e}");
            }
        }
    }
}

/// The camera's DN image of a frame's `(P/L)` as `optistim render` makes `image.png`.
pub fn image_png(
    config: &Config,
    pose: &crate::scene::Pose,
    pl: &[f64],
) -> Result<Vec<u8>, String> {
    let det = &config.scene.camera.detector;
    if let Some(b) = det.bands.iter().find(|b| b.distortion.is_some()) {
        // The frame thread hands back the one (P/L) image, not a band's own.
        return Err(format!(
            "band {} has a distortion of its own: the CORTO endpoint serves cameras whose \
             bands share the camera's distortion",
            b.name
        ));
    }
    let i = &config.scene.camera.intrinsics;
    let (w, h) = (i.width_px as usize, i.height_px as usize);
    let dn = config.scene.record_dn(|_| pl, (w, h), pose.frame_id);
    // A colour camera's planes as RGB, or its mosaic with its pattern, as image.png.
    let text = crate::app::products::png_text(det);
    crate::io::encode_png_planes(w, h, &dn, det.saved_bits, &text).map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn poses_decode_in_both_layouts_and_refuse_the_rest() {
        let v17: Vec<f64> = (0..17).map(f64::from).collect();
        let bytes: Vec<u8> = v17.iter().flat_map(|x| x.to_be_bytes()).collect();
        let p = decode(&bytes).unwrap();
        assert_eq!(p.sun, [0.0, 1.0, 2.0]);
        assert_eq!(p.camera_wxyz, [6.0, 7.0, 8.0, 9.0]);
        assert_eq!(p.body_wxyz, [13.0, 14.0, 15.0, 16.0]);
        let v21: Vec<u8> = (0..21)
            .map(|i| {
                if (3..7).contains(&i) {
                    -1.0
                } else {
                    f64::from(i)
                }
            })
            .flat_map(|x: f64| x.to_be_bytes())
            .collect();
        let q = decode(&v21).unwrap();
        assert_eq!((q.sun, q.camera), ([0.0, 1.0, 2.0], [7.0, 8.0, 9.0]));
        assert!(decode(&bytes[..100]).is_err());
        let mut nan = bytes.clone();
        nan[..8].copy_from_slice(&f64::NAN.to_be_bytes());
        assert!(decode(&nan).unwrap_err().contains("value 0"));
    }

    #[test]
    fn blender_camera_looking_down_minus_z_is_optistim_looking_down_plus_z() {
        let p = CortoPose {
            sun: [0.0, 100.0, 0.0],
            camera: [0.0, 0.0, 10.0],
            camera_wxyz: [1.0, 0.0, 0.0, 0.0],
            body: [0.0, 0.0, 0.0],
            body_wxyz: [1.0, 0.0, 0.0, 0.0],
        };
        let pose = to_pose(&p, 1e3, 0).unwrap();
        assert_eq!(pose.camera_position_m, DVec3::new(0.0, 0.0, 1e4));
        // Optistim's boresight (+Z) points at the body (-Z in the world).
        let boresight = pose.body_from_camera * DVec3::Z;
        assert!((boresight - DVec3::NEG_Z).length() < 1e-12);
        // Image down (+Y) is Blender's -Y (Blender's Y is up).
        assert!((pose.body_from_camera * DVec3::Y - DVec3::NEG_Y).length() < 1e-12);
    }
}
