//! The daemon's closed loop (issue 5, item 7): the embedded default scene (the NRHO camera's
//! Moon on a 1920 x 1200 screen), presented off-screen on the GPU adapter (lavapipe in CI)
//! with the simulated camera, and the replay client streaming 200 poses of the NRHO
//! trajectory at 10 Hz over TCP and over a pty serial line. In lockstep every frame is acked
//! in order; free-running at 100 Hz drops are counted and no frame is presented twice.
//! Needs `../shared/trajectories/` beside the checkout.

mod common;
use common::*;
use optistim::app::replay;
use optistim::server::frames::{Mode, PresenterChoice};
use optistim::server::protocol::{AckStatus, Message};
use std::path::Path;
use std::time::Duration;

const NRHO: &str = "../shared/trajectories/nrho_2orbits.csv";

fn poses(n: usize) -> Vec<optistim::server::protocol::PoseMsg> {
    let mut p = replay::read_poses(Path::new(NRHO)).unwrap_or_else(|e| panic!("{e}"));
    p.truncate(n);
    assert_eq!(p.len(), n);
    p
}

fn tcp_halves(
    addr: std::net::SocketAddr,
) -> (
    Box<dyn std::io::Read + Send>,
    Box<dyn std::io::Write + Send>,
) {
    let s = std::net::TcpStream::connect(addr).unwrap();
    s.set_nodelay(true).unwrap();
    (Box::new(s.try_clone().unwrap()), Box::new(s))
}

#[test]
fn closed_loop_over_tcp_lockstep_then_free_running() {
    let record = std::env::temp_dir().join(format!("optistim-rec-{}.jsonl", std::process::id()));
    let daemon = start_daemon(
        optistim::server::DEFAULT_CONFIG,
        PresenterChoice::Offscreen,
        Mode::Lockstep,
        None,
        Some(record.clone()),
    );
    eprintln!("presenter: {}", daemon.presenter());
    let poses = poses(200);

    // A subscriber, reading as frames come, receives the simulated camera's image of every
    // frame.
    let mut sub = Client::connect(daemon.tcp_addr);
    sub.send(&Message::Subscribe { camera: true });
    std::thread::sleep(Duration::from_millis(200));
    let subscriber = std::thread::spawn(move || {
        let mut camera_frames = 0;
        while let Some(m) = sub.recv(Duration::from_secs(3)) {
            if let Message::CameraFrame {
                width, height, dn, ..
            } = m
            {
                assert_eq!((width, height, dn.len()), (1024, 1024, 1024 * 1024));
                assert!(dn.iter().any(|&x| x > 100), "the camera sees the Moon");
                camera_frames += 1;
            }
        }
        camera_frames
    });

    let (r, w) = tcp_halves(daemon.tcp_addr);
    let lock = replay::stream(r, w, &poses, 10.0, Mode::Lockstep, "tcp", None).unwrap();
    eprintln!(
        "lockstep over TCP: {}",
        serde_json::to_string(&lock).unwrap()
    );
    assert_eq!(lock.sent, 200);
    assert_eq!(lock.acked, 200, "{:?}", lock.error_messages);
    assert!(lock.in_order);
    assert_eq!(
        (lock.dropped, lock.errors, lock.lost, lock.presented_twice),
        (0, 0, 0, 0)
    );

    let camera_frames = subscriber.join().unwrap();
    assert_eq!(camera_frames, 200);

    let (r, w) = tcp_halves(daemon.tcp_addr);
    let free = replay::stream(r, w, &poses, 100.0, Mode::Free, "tcp", None).unwrap();
    eprintln!(
        "free-running over TCP: {}",
        serde_json::to_string(&free).unwrap()
    );
    assert_eq!(free.sent, 200);
    assert_eq!(free.acked + free.dropped, 200);
    assert!(free.dropped > 0, "at 100 Hz some poses must be stale");
    assert_eq!((free.errors, free.lost, free.presented_twice), (0, 0, 0));
    assert!(free.in_order);

    // Every acknowledged frame is in the recording.
    let report = daemon.shutdown();
    assert!(report.recording_flushed);
    let text = std::fs::read_to_string(&record).unwrap();
    let recorded = text
        .lines()
        .filter(|l| l.contains("\"type\":\"pose\""))
        .count();
    assert_eq!(recorded, 400);
    let _ = std::fs::remove_file(&record);
}

#[test]
fn closed_loop_over_a_pty_serial_line() {
    use serialport::SerialPort;
    let (master, slave) = serialport::TTYPort::pair().expect("a pty pair");
    let path = slave.name().expect("the pty's path");
    let daemon = start_daemon(
        optistim::server::DEFAULT_CONFIG,
        PresenterChoice::Offscreen,
        Mode::Lockstep,
        Some(path.clone()),
        None,
    );
    let reader = master.try_clone_native().unwrap();
    let lock = replay::stream(
        Box::new(reader),
        Box::new(master),
        &poses(200),
        10.0,
        Mode::Lockstep,
        &path,
        None,
    )
    .unwrap();
    eprintln!(
        "lockstep over {path}: {}",
        serde_json::to_string(&lock).unwrap()
    );
    assert_eq!(lock.acked, 200, "{:?}", lock.error_messages);
    assert!(lock.in_order);
    assert_eq!(
        (lock.dropped, lock.errors, lock.lost, lock.presented_twice),
        (0, 0, 0, 0)
    );
    drop(slave);
    drop(daemon);
}

#[test]
fn hold_and_trigger_present_on_demand() {
    let daemon = start_daemon(
        &small_daemon_config(),
        PresenterChoice::Cpu,
        Mode::Lockstep,
        None,
        None,
    );
    let mut c = Client::connect(daemon.tcp_addr);
    c.send(&Message::Config {
        json: r#"{"hold": true}"#.into(),
    });
    assert!(matches!(
        c.recv(Duration::from_secs(5)),
        Some(Message::ConfigAck { .. })
    ));
    c.send(&Message::Pose(nrho_pose(1)));
    match c.recv(Duration::from_secs(30)) {
        Some(Message::Ack(a)) => assert_eq!((a.frame_id, a.status), (1, AckStatus::Held)),
        other => panic!("{other:?}"),
    }
    // Nothing is presented until the trigger.
    let (code, _) = http(daemon.http_addr, "GET", "/frame/latest.png", b"");
    assert_eq!(code, 404);
    c.send(&Message::Trigger);
    match c.recv(Duration::from_secs(30)) {
        Some(Message::Ack(a)) => {
            assert_eq!((a.frame_id, a.status), (1, AckStatus::Presented));
            assert!(a.presented_ns >= a.render_end_ns && a.render_end_ns >= a.render_start_ns);
        }
        other => panic!("{other:?}"),
    }
    let (code, png) = http(daemon.http_addr, "GET", "/frame/latest.png", b"");
    assert_eq!(code, 200);
    assert_eq!(&png[1..4], b"PNG");
}

/// `optistim serve` of `scene` on the CPU presenter, recording to `record`, in `mode`: the
/// process, its stdout's lines after the first, and the pose address that line gave.
fn serve_recorded(
    scene: &Path,
    record: &Path,
    mode: &str,
) -> (
    std::process::Child,
    std::io::Lines<std::io::BufReader<std::process::ChildStdout>>,
    std::net::SocketAddr,
) {
    use std::io::{BufRead, BufReader};
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_optistim"))
        .args(["serve", "--config", scene.to_str().unwrap()])
        .args(["--listen", "127.0.0.1:0", "--http", "127.0.0.1:0"])
        .args(["--present", "cpu", "--mode", mode])
        .args(["--record", record.to_str().unwrap()])
        .env_remove("DISPLAY")
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let first: serde_json::Value = serde_json::from_str(&lines.next().unwrap().unwrap()).unwrap();
    let addr = first["listening"].as_str().unwrap().parse().unwrap();
    (child, lines, addr)
}

#[test]
fn sigterm_stops_the_daemon_cleanly_with_its_recording_complete() {
    let dir = TempDir::new("sigterm");
    let scene = dir.join("daemon.toml");
    std::fs::write(&scene, small_daemon_config()).unwrap();
    let record = dir.join("rec.jsonl");
    let (mut child, mut lines, addr) = serve_recorded(&scene, &record, "free");
    let mut c = Client::connect(addr);
    for i in 0..5 {
        c.send(&Message::Pose(nrho_pose(i)));
        loop {
            if let Some(Message::Ack(a)) = c.recv(Duration::from_secs(30)) {
                assert_eq!(a.frame_id, i);
                break;
            }
        }
    }
    let status = std::process::Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let exit = child.wait().unwrap();
    assert!(exit.success(), "{exit:?}");
    let report: serde_json::Value = serde_json::from_str(&lines.next().unwrap().unwrap()).unwrap();
    assert_eq!(report["frames_presented"].as_u64(), Some(5));
    assert_eq!(report["recording_flushed"].as_bool(), Some(true));
    let text = std::fs::read_to_string(&record).unwrap();
    assert_eq!(text.lines().filter(|l| l.contains("\"pose\"")).count(), 5);
    // The recording replays: the same five poses.
    let again = replay::read_poses(&record).unwrap();
    assert_eq!(
        again.iter().map(|p| p.frame_id).collect::<Vec<_>>(),
        [0, 1, 2, 3, 4]
    );
    assert_eq!(again[0], nrho_pose(0));
}

/// The serial line vanishes mid-stream (its pty closes) and comes back (a new pty at the same
/// path, a symbolic link as a udev rule would make): the daemon reopens it and serves the
/// poses that come over the new line.
#[test]
fn a_serial_line_that_vanishes_and_comes_back_is_served_again() {
    use optistim::server::protocol::{Decoded, Decoder, Message};
    use serialport::SerialPort;
    use std::io::{Read, Write};
    let dir = TempDir::new("serial-vanish");
    let link = dir.join("ttyBENCH");
    let pair = || {
        let (master, slave) = serialport::TTYPort::pair().expect("a pty pair");
        let _ = std::fs::remove_file(&link);
        std::os::unix::fs::symlink(slave.name().unwrap(), &link).unwrap();
        (master, slave)
    };
    // Sends pose `id` (again every 300 ms) until its ack comes back over `master`.
    let acked = |master: &mut serialport::TTYPort, id: u64| {
        master
            .set_timeout(std::time::Duration::from_millis(300))
            .unwrap();
        let mut d = Decoder::new(u32::MAX);
        let t0 = std::time::Instant::now();
        let mut buf = [0u8; 4096];
        while t0.elapsed() < std::time::Duration::from_secs(20) {
            master
                .write_all(&Message::Pose(nrho_pose(id)).encode())
                .unwrap();
            if let Ok(n) = master.read(&mut buf) {
                d.push(&buf[..n]);
            }
            while let Decoded::Message(m) = d.next_message() {
                if matches!(m, Message::Ack(ref a) if a.frame_id == id && a.status == AckStatus::Presented)
                {
                    return true;
                }
            }
        }
        false
    };
    let (mut master, slave) = pair();
    let daemon = start_daemon(
        &small_daemon_config(),
        PresenterChoice::Cpu,
        Mode::Free,
        Some(link.to_str().unwrap().to_string()),
        None,
    );
    assert!(acked(&mut master, 1), "the first line served no pose");
    // The line vanishes: both ends close, the pty is gone.
    drop(master);
    drop(slave);
    std::thread::sleep(std::time::Duration::from_millis(1500));
    // It comes back at the same path.
    let (mut master, _slave) = pair();
    assert!(
        acked(&mut master, 2),
        "the line came back but was not served"
    );
    let status: serde_json::Value =
        serde_json::from_slice(&http(daemon.http_addr, "GET", "/status", b"").1).unwrap();
    assert!(
        status["frames_presented"].as_u64().unwrap() >= 2,
        "{status}"
    );
    daemon.shutdown();
}

/// SIGTERM while frames are in flight (20 poses queued in lockstep, the signal right after the
/// first ack): every pose is answered, presented or `shutting_down`, none twice; the
/// recording has all 20; the daemon exits cleanly and its report adds up.
#[test]
fn sigterm_with_frames_in_flight_answers_every_pose() {
    use optistim::server::protocol::ErrorCode;
    let dir = TempDir::new("sigterm-inflight");
    let scene = dir.join("daemon.toml");
    std::fs::write(&scene, optistim::server::DEFAULT_CONFIG).unwrap();
    let record = dir.join("rec.jsonl");
    let (mut child, mut lines, addr) = serve_recorded(&scene, &record, "lockstep");
    let mut c = Client::connect(addr);
    for p in poses(20) {
        c.send(&Message::Pose(p));
    }
    let (mut presented, mut refused) = (Vec::new(), Vec::new());
    let mut signalled = false;
    while let Some(m) = c.recv(Duration::from_secs(30)) {
        match m {
            Message::Ack(a) if a.status == AckStatus::Presented => presented.push(a.frame_id),
            Message::Error {
                code: ErrorCode::ShuttingDown,
                frame_id: Some(f),
                ..
            } => refused.push(f),
            other => panic!("unexpected {other:?}"),
        }
        if !signalled {
            // A frame is rendering now, the rest wait.
            let ok = std::process::Command::new("kill")
                .args(["-TERM", &child.id().to_string()])
                .status()
                .unwrap();
            assert!(ok.success());
            signalled = true;
        }
    }
    let exit = child.wait().unwrap();
    assert!(exit.success(), "{exit:?}");
    let report: serde_json::Value = serde_json::from_str(&lines.next().unwrap().unwrap()).unwrap();
    let mut all: Vec<u64> = presented.iter().chain(&refused).copied().collect();
    all.sort_unstable();
    assert_eq!(all, (0..20).collect::<Vec<_>>(), "every pose answered once");
    assert!(!refused.is_empty(), "some poses were still waiting");
    assert_eq!(
        report["frames_presented"].as_u64(),
        Some(presented.len() as u64)
    );
    assert_eq!(
        report["poses_not_rendered"].as_u64(),
        Some(refused.len() as u64)
    );
    assert_eq!(report["recording_flushed"].as_bool(), Some(true));
    let text = std::fs::read_to_string(&record).unwrap();
    assert_eq!(text.lines().filter(|l| l.contains("\"pose\"")).count(), 20);
}
