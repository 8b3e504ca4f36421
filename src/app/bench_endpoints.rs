//! `optistim bench-endpoints`: what each compatible endpoint adds to a frame's latency over
//! the native protocol, for the same poses. An in-process daemon (the scene's `[stimulator]`,
//! presented as `--present` says, lockstep) serves all three; one client per protocol sends the
//! same poses one at a time and times each from the pose sent to its answer: the native
//! `presented` ack; SurRender's `setObjectPosition` / `setObjectAttitude` (camera, Sun),
//! `render` and `getImageGray32F` (the image is what that client asks for); CORTO's datagram to
//! its PNG. The protocols interleave pose by pose, so that drift hits them alike.

use super::AppError;
use crate::config::Config;
use crate::server::protocol::{Decoded, Decoder, Message, PoseMsg};
use crate::server::surrender::{self, QVar};
use serde::Serialize;
use std::io::{Read, Write};
use std::net::{TcpStream, UdpSocket};
use std::time::{Duration, Instant};

/// Latency percentiles of one protocol [ms].
#[derive(Debug, Serialize)]
pub struct EndpointLatency {
    pub protocol: &'static str,
    pub p50_ms: f64,
    pub p99_ms: f64,
    /// Over the native protocol's, pose by pose: median and p99 of the differences.
    pub added_p50_ms: f64,
    pub added_p99_ms: f64,
}

#[derive(Debug, Serialize)]
pub struct EndpointReport {
    pub scene: String,
    pub presenter: String,
    pub poses: usize,
    pub camera_px: [u32; 2],
    pub endpoints: Vec<EndpointLatency>,
}

fn err(what: &str) -> impl Fn(std::io::Error) -> AppError + '_ {
    move |e| AppError::Replay(format!("{what}: {e}"))
}

/// Runs the comparison over `poses` (in the scene's world frame, the body frame).
pub fn run(
    config: &Config,
    scene: &str,
    poses: &[PoseMsg],
    presenter: crate::server::frames::PresenterChoice,
) -> Result<EndpointReport, AppError> {
    let metres = 1.0;
    let mut c = config.clone();
    c.corto_metres_per_unit = Some(metres);
    let loopback = "127.0.0.1:0".parse().expect("an address");
    let d = crate::server::Server::start(crate::server::ServeOptions {
        config: c,
        config_label: scene.into(),
        config_sha256: String::new(),
        listen: loopback,
        http: loopback,
        serial: None,
        presenter,
        mode: crate::server::frames::Mode::Lockstep,
        record: None,
        access: Default::default(),
        surrender: Some(loopback),
        corto: Some((loopback, loopback)),
    })?;
    let presenter_name = d.presenter().to_string();
    let (corto_pose, corto_image) = d.corto_addrs.expect("served");

    // Native: binary frames.
    let mut native = TcpStream::connect(d.tcp_addr).map_err(err("native"))?;
    native.set_nodelay(true).map_err(err("native"))?;
    let mut decoder = Decoder::new(u32::MAX);
    // SurRender: the session starts with the scene's camera; conventions w x y z, Z front.
    let mut sr = TcpStream::connect(d.surrender_addr.expect("served")).map_err(err("SurRender"))?;
    sr.set_nodelay(true).map_err(err("SurRender"))?;
    let call = |sr: &mut TcpStream, fields: Vec<(String, QVar)>, wait: bool| {
        sr.write_all(&surrender::encode_hash(&fields))
            .map_err(err("SurRender"))?;
        if !wait {
            return Ok::<_, AppError>(None);
        }
        let name = fields[0].1.clone();
        loop {
            let h = surrender::read_hash(sr).map_err(|e| AppError::Replay(e.to_string()))?;
            if let Some((_, QVar::String(s))) = h.iter().find(|(k, _)| k.is_empty())
                && s.is_empty()
                && let Some((_, QVar::Bytes(b))) = h.iter().find(|(k, _)| k == "data")
            {
                return Err(AppError::Replay(String::from_utf8_lossy(b).into_owned()));
            }
            if h.first().map(|x| &x.1) == Some(&name) {
                return Ok(Some(h));
            }
        }
    };
    let s = |x: &str| QVar::String(x.into());
    let list = |v: &[f64]| QVar::List(v.iter().map(|&x| QVar::Double(x)).collect());
    call(
        &mut sr,
        vec![
            (String::new(), s("setConventions")),
            ("quaternion_convention".into(), QVar::Int(1)),
            ("camera_convention".into(), QVar::Int(1)),
        ],
        true,
    )?;
    // CORTO: its image connection first.
    let mut corto_tcp = TcpStream::connect(corto_image).map_err(err("CORTO"))?;
    let corto_udp = UdpSocket::bind("127.0.0.1:0").map_err(err("CORTO"))?;
    std::thread::sleep(Duration::from_millis(100));
    // Blender's camera axes: a half turn about X from optistim's.
    let flip = glam::DQuat::from_xyzw(1.0, 0.0, 0.0, 0.0);

    let mut t = [Vec::new(), Vec::new(), Vec::new()];
    for (i, p) in poses.iter().enumerate() {
        // Native.
        let mut pose = p.clone();
        pose.frame_id = i as u64;
        let t0 = Instant::now();
        native
            .write_all(&Message::Pose(pose).encode())
            .map_err(err("native"))?;
        let mut buf = vec![0u8; 1 << 16];
        'ack: loop {
            let n = native.read(&mut buf).map_err(err("native"))?;
            if n == 0 {
                return Err(AppError::Replay("native: the daemon closed".into()));
            }
            decoder.push(&buf[..n]);
            while let Decoded::Message(m) = decoder.next_message() {
                match m {
                    Message::Ack(a) if a.frame_id == i as u64 => break 'ack,
                    Message::Error { message, .. } => return Err(AppError::Replay(message)),
                    _ => {}
                }
            }
        }
        t[0].push(t0.elapsed().as_secs_f64() * 1e3);

        // SurRender.
        let t0 = Instant::now();
        for (object, key, v) in [
            ("camera", "pos", &p.camera_position_m[..]),
            ("camera", "attitude", &p.attitude_wxyz[..]),
            ("sun", "pos", &p.sun_position_m[..]),
        ] {
            let command = if key == "pos" {
                "setObjectPosition"
            } else {
                "setObjectAttitude"
            };
            call(
                &mut sr,
                vec![
                    (String::new(), s(command)),
                    ("object_name".into(), s(object)),
                    (key.into(), list(v)),
                ],
                false,
            )?;
        }
        call(&mut sr, vec![(String::new(), s("render"))], false)?;
        call(&mut sr, vec![(String::new(), s("getImageGray32F"))], true)?;
        t[1].push(t0.elapsed().as_secs_f64() * 1e3);

        // CORTO: the body at the origin, unturned; Blender's camera.
        let [w, x, y, z] = p.attitude_wxyz;
        let q = glam::DQuat::from_xyzw(x, y, z, w) * flip;
        let mut v: Vec<f64> = p.sun_position_m.to_vec();
        v.extend_from_slice(&p.camera_position_m);
        v.extend_from_slice(&[q.w, q.x, q.y, q.z]);
        v.extend_from_slice(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]);
        let datagram: Vec<u8> = v
            .iter()
            .map(|x| x / metres)
            .flat_map(|x| x.to_be_bytes())
            .collect();
        let t0 = Instant::now();
        corto_udp
            .send_to(&datagram, corto_pose)
            .map_err(err("CORTO"))?;
        let mut len = [0u8; 8];
        corto_tcp.read_exact(&mut len).map_err(err("CORTO"))?;
        let mut png = vec![0u8; u64::from_le_bytes(len) as usize];
        corto_tcp.read_exact(&mut png).map_err(err("CORTO"))?;
        t[2].push(t0.elapsed().as_secs_f64() * 1e3);
    }
    d.shutdown();
    let q = |v: &[f64]| {
        let mut v = v.to_vec();
        crate::stats::quantiles(&mut v, [0.5, 0.99])
    };
    let endpoints = ["native", "surrender", "corto"]
        .iter()
        .enumerate()
        .map(|(k, &protocol)| {
            let [p50, p99] = q(&t[k]);
            let added: Vec<f64> = t[k].iter().zip(&t[0]).map(|(a, b)| a - b).collect();
            let [a50, a99] = q(&added);
            EndpointLatency {
                protocol,
                p50_ms: p50,
                p99_ms: p99,
                added_p50_ms: a50,
                added_p99_ms: a99,
            }
        })
        .collect();
    let i = &config.scene.camera.intrinsics;
    Ok(EndpointReport {
        scene: scene.into(),
        presenter: presenter_name,
        poses: poses.len(),
        camera_px: [i.width_px, i.height_px],
        endpoints,
    })
}
