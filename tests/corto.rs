//! CORTO's decoupled in-the-loop client, exactly as published
//! (`../shared/clients/corto/advanced_CIL_ClosedLoop_remote_Client.py`), runs against the
//! daemon's CORTO endpoint (issue 19, items 2 and 3): it connects to TCP 30001, sends its
//! three poses over UDP 51001 and saves the PNGs it gets back; each equals, byte for byte,
//! the `image.png` that `optistim render` writes for the same pose.
//!
//! The client's ports are fixed in its script, so this test binds 51001 and 30001 on
//! loopback. Needs Python with NumPy (`OPTISTIM_PYTHON`, or `python3`).

mod common;
use common::*;
use optistim::server::corto::{self, CortoPose};
use optistim::server::frames::{Mode, PresenterChoice};
use std::path::Path;

const CLIENT: &str = "../shared/clients/corto/advanced_CIL_ClosedLoop_remote_Client.py";
/// Metres per Blender unit in the test scene: the client's camera, 10.2 units from the
/// body, is then 10,200 km from the Moon's centre.
const METRES_PER_UNIT: f64 = 1e6;

/// The client's poses, as its script defines them (section 3).
fn client_poses() -> Vec<CortoPose> {
    [
        [0.016352521502461803, 0.0, 0.0, 0.999866288580884],
        [-0.49429973225975826, 0.0, 0.0, 0.8692915360728708],
        [-0.5776846363362429, 0.0, 0.0, 0.8162600449250611],
    ]
    .into_iter()
    .map(|body_wxyz| CortoPose {
        sun: [0.0, 30000.0, 0.0],
        camera: [-3.880436735865625, 9.436275094557633, 0.2122852153592106],
        camera_wxyz: [
            -0.13848248126035184,
            -0.13563116230823927,
            0.6864425350546722,
            0.7008733382449409,
        ],
        body: [0.0; 3],
        body_wxyz,
    })
    .collect()
}

#[test]
fn the_published_corto_client_gets_optistims_renders() {
    let text = format!(
        "{}\n[corto]\nmetres_per_unit = {METRES_PER_UNIT:e}\n",
        small_daemon_config()
    );
    let config = optistim::config::parse(&text, "<test>").unwrap();
    let mut o = serve_options(&text, PresenterChoice::Cpu, Mode::Free, None, None);
    o.corto = Some((
        "127.0.0.1:51001".parse().unwrap(),
        "127.0.0.1:30001".parse().unwrap(),
    ));
    let d = optistim::server::Server::start(o).unwrap_or_else(|e| panic!("{e}"));

    let dir = TempDir::new("corto");
    let python = std::env::var("OPTISTIM_PYTHON").unwrap_or_else(|_| "python3".into());
    let client = Path::new(env!("CARGO_MANIFEST_DIR")).join(CLIENT);
    let run = std::process::Command::new(&python)
        .arg(&client)
        .current_dir(&dir.0)
        .output()
        .unwrap_or_else(|e| panic!("{python}: {e}"));
    assert!(
        run.status.success(),
        "CORTO's client failed:\n{}\n{}",
        String::from_utf8_lossy(&run.stdout),
        String::from_utf8_lossy(&run.stderr)
    );
    let presented = d.shared.stats.frames_presented.get();
    d.shutdown();
    assert_eq!(presented, 3, "each pose went onto the stimulator's screen");

    for (i, p) in client_poses().iter().enumerate() {
        let got = std::fs::read(dir.join(&format!("output/decoupled_tutorial/{i:06}.png")))
            .expect("the client saved its image");
        let mut c = config.clone();
        c.pose = corto::to_pose(p, METRES_PER_UNIT, i as u64).unwrap();
        let out = dir.join(&format!("render{i}"));
        let summary = optistim::app::render::run(
            &c,
            "corto test",
            &out,
            optistim::app::render::Method::Quadrangle,
        )
        .unwrap();
        assert!(summary.total_power_w > 0.0, "pose {i}: the Moon is in view");
        let want = std::fs::read(out.join("image.png")).unwrap();
        assert!(
            got == want,
            "pose {i}: the client's PNG differs from image.png"
        );
    }
}
