//! Watching never disturbs the loop (issue 19, item 6): the daemon streams the NRHO in
//! lockstep at 10 Hz (the embedded default scene, CPU presenter) once alone and once while
//! 16 clients poll every HTTP endpoint; the pose-to-presented p99 stays within 10 % of the
//! undisturbed run, and each image is made at most once per frame.

mod common;
use common::*;
use optistim::app::replay;
use optistim::server::frames::{Mode, PresenterChoice};
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

const NRHO: &str = "../shared/trajectories/nrho_2orbits.csv";
const ENDPOINTS: [&str; 10] = [
    "/",
    "/health",
    "/status",
    "/metrics",
    "/frame/latest.png",
    "/frame/view.png",
    "/camera/latest.png",
    "/camera/view.png",
    "/calibration",
    "/config",
];
/// Poll clients, as in the report that opened the issue.
const CLIENTS: usize = 16;
/// Each client's pause between requests [ms]: 20 requests per second each, 320 in all.
const POLL_MS: u64 = 50;
/// Rounds of 100 poses alone and 100 watched, interleaved. The p99 of one round is its
/// second-slowest frame (one of the ~15 perilune frames of 80-110 ms), which moves by
/// +-15 % from round to round with the machine alone; the p99 of all 600 frames of each kind
/// is what is compared.
const ROUNDS: usize = 6;

/// 100 poses spread over the two orbits (perilune, where frames cost most, included).
fn poses() -> Vec<optistim::server::protocol::PoseMsg> {
    let all = replay::read_poses(Path::new(NRHO)).unwrap_or_else(|e| panic!("{e}"));
    let step = all.len() / 100;
    let mut p: Vec<_> = all.into_iter().step_by(step).take(100).collect();
    for (i, q) in p.iter_mut().enumerate() {
        q.frame_id = i as u64;
    }
    p
}

/// Streams the poses in lockstep at 10 Hz; the daemon's pose-to-presented latencies [ms].
fn stream(d: &optistim::server::Server) -> replay::ReplayReport {
    let s = std::net::TcpStream::connect(d.tcp_addr).unwrap();
    s.set_nodelay(true).unwrap();
    let r = replay::stream(
        Box::new(s.try_clone().unwrap()),
        Box::new(s),
        &poses(),
        10.0,
        Mode::Lockstep,
        "tcp",
        None,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!((r.acked, r.lost, r.errors), (100, 0, 0), "{r:?}");
    r
}

/// The calling thread runs only when the CPU is otherwise idle (Linux `SCHED_IDLE`).
fn idle_priority() {
    #[cfg(target_os = "linux")]
    // SAFETY: changes the calling thread's own scheduling policy; the parameter is read only.
    unsafe {
        let p = libc::sched_param { sched_priority: 0 };
        libc::sched_setscheduler(0, libc::SCHED_IDLE, &p);
    }
}

#[test]
fn sixteen_pollers_leave_the_frame_latency_alone() {
    let d = start_daemon(
        optistim::server::DEFAULT_CONFIG,
        PresenterChoice::Cpu,
        Mode::Lockstep,
        None,
        None,
    );
    // A warm-up pass: first touches of buffers and maps are not the pollers' doing.
    let _ = stream(&d);
    // Rounds alone and watched, interleaved, so that the machine's drift hits both alike.
    let (mut alone, mut watched) = (Vec::new(), Vec::new());
    // Each round's p99 (its 100 poses), printed to show the spread.
    let (mut round_alone, mut round_watched) = (Vec::new(), Vec::new());
    let p99 = |v: &[f64]| optistim::stats::quantiles(&mut v.to_vec(), [0.99])[0];
    let stop = Arc::new(AtomicBool::new(false));
    let answered = Arc::new(AtomicU64::new(0));
    let bytes = Arc::new(AtomicU64::new(0));
    for _ in 0..ROUNDS {
        let a = stream(&d).daemon_latencies_ms;
        round_alone.push(p99(&a));
        alone.extend(a);
        stop.store(false, Ordering::Relaxed);
        let pollers: Vec<_> = (0..CLIENTS)
            .map(|k| {
                let (stop, answered, bytes) = (stop.clone(), answered.clone(), bytes.clone());
                let a = d.http_addr;
                std::thread::spawn(move || {
                    // The pollers stand in for operators' browsers, usually on other
                    // machines: on this one they run only when the CPU is idle (what is
                    // tested is the daemon's own work for them). Each asks every POLL_MS,
                    // twice per frame at 10 Hz, faster than any dashboard: without a pause
                    // their own CPU on this 2-core machine is what slows the frames (16
                    // SCHED_IDLE threads spinning, no HTTP at all, raised the p99 by 12.6 %).
                    idle_priority();
                    let mut i = k;
                    while !stop.load(Ordering::Relaxed) {
                        let e = ENDPOINTS[i % ENDPOINTS.len()];
                        let (code, body) = http(a, "GET", e, b"");
                        assert!(code == 200, "{e} -> {code}");
                        answered.fetch_add(1, Ordering::Relaxed);
                        bytes.fetch_add(body.len() as u64, Ordering::Relaxed);
                        i += 1;
                        std::thread::sleep(Duration::from_millis(POLL_MS));
                    }
                })
            })
            .collect();
        std::thread::sleep(Duration::from_millis(300));
        let w = stream(&d).daemon_latencies_ms;
        round_watched.push(p99(&w));
        watched.extend(w);
        stop.store(true, Ordering::Relaxed);
        for p in pollers {
            p.join().unwrap();
        }
    }
    let status: serde_json::Value =
        serde_json::from_slice(&http(d.http_addr, "GET", "/status", b"").1).unwrap();
    let presented = status["frames_presented"].as_u64().unwrap();
    let made = status["views"]["images_made"].as_u64().unwrap();
    let captures = status["views"]["camera_captures"].as_u64().unwrap();
    let during = status["views"]["served_during_frames"].as_u64().unwrap();
    let q = |v: &mut Vec<f64>| optistim::stats::quantiles(v, [0.5, 0.99, 1.0]);
    let ([p50_alone, p99_alone, _], [p50_watched, p99_watched, _]) =
        (q(&mut alone), q(&mut watched));
    eprintln!(
        "p99 pose -> presented: alone {p99_alone:.1} ms, with {CLIENTS} pollers {p99_watched:.1} \
         ms (median {:.1} / {:.1}; per round {round_alone:.0?} / {round_watched:.0?}); {} requests answered ({:.0} MB); {made} images and \
         {captures} camera captures made for {presented} frames; {during} waits for a gap ran out",
        p50_alone,
        p50_watched,
        answered.load(Ordering::Relaxed),
        bytes.load(Ordering::Relaxed) as f64 / 1e6,
    );
    eprintln!(
        "slowest alone {:?}\nslowest watched {:?}",
        &alone[alone.len() - 8..],
        &watched[watched.len() - 8..]
    );
    assert!(
        answered.load(Ordering::Relaxed) > 1000,
        "the pollers were served"
    );
    assert!(
        made <= 4 * presented,
        "{made} images for {presented} frames"
    );
    assert!(
        captures <= presented,
        "{captures} captures for {presented} frames"
    );
    assert!(
        p99_watched <= 1.10 * p99_alone,
        "p99 {p99_watched:.1} ms while watched, {p99_alone:.1} ms alone; per round {round_watched:?} vs {round_alone:?}"
    );
}
