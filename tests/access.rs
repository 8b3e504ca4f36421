//! The locked-down control plane (issue 19, item 5): a non-loopback listener needs a token or
//! `--insecure`; with a token, mutating HTTP calls and TCP pose connections are refused
//! without it; scenes named over the network, and the files they name, stay inside the scene
//! folders, and no refusal echoes what a non-scene file holds. Each refusal is a test.

mod common;
use common::*;
use optistim::server::access::{Access, AccessError};
use optistim::server::frames::{Mode, PresenterChoice};
use optistim::server::protocol::{ErrorCode, Message, VERSION};
use optistim::server::{ServeOptions, ServerError};
use std::time::Duration;

const TOKEN: &str = "s3cret-bench-token-0123";
const WAIT: Duration = Duration::from_secs(30);

fn options() -> ServeOptions {
    serve_options(
        &small_daemon_config(),
        PresenterChoice::Cpu,
        Mode::Lockstep,
        None,
        None,
    )
}

fn with_token(dirs: &[std::path::PathBuf]) -> optistim::server::Server {
    let mut o = options();
    o.access = Access::new(Some(TOKEN), dirs, false).unwrap();
    optistim::server::Server::start(o).unwrap_or_else(|e| panic!("{e}"))
}

fn hello(token: Option<&str>) -> Message {
    Message::Hello {
        version_min: VERSION,
        version_max: VERSION,
        client: "test".into(),
        token: token.map(str::to_string),
    }
}

/// The client gets an `unauthorized` error, then the daemon closes the connection.
fn refused_and_closed(c: &mut Client) {
    match c.recv(WAIT) {
        Some(Message::Error { code, message, .. }) => {
            assert_eq!(code, ErrorCode::Unauthorized, "{message}");
            assert!(!message.contains(TOKEN));
        }
        other => panic!("expected an unauthorized error, got {other:?}"),
    }
    let next = c.recv(WAIT);
    assert!(next.is_none(), "the connection stays open: {next:?}");
}

#[test]
fn a_non_loopback_listener_needs_a_token_or_insecure() {
    let mut o = options();
    o.http = "0.0.0.0:0".parse().unwrap();
    match optistim::server::Server::start(o) {
        Err(ServerError::Access(AccessError::OpenWithoutToken { what, .. })) => {
            assert_eq!(what, "HTTP listener")
        }
        Err(e) => panic!("wrong refusal: {e}"),
        Ok(_) => panic!("started on 0.0.0.0 without a token"),
    }
    let mut o = options();
    o.listen = "0.0.0.0:0".parse().unwrap();
    let e = optistim::server::Server::start(o).err().expect("refused");
    assert!(e.to_string().contains("--token-file"), "{e}");

    for access in [
        Access::new(None, &[], true).unwrap(),
        Access::new(Some(TOKEN), &[], false).unwrap(),
    ] {
        let mut o = options();
        o.listen = "0.0.0.0:0".parse().unwrap();
        o.access = access;
        let d = optistim::server::Server::start(o).unwrap_or_else(|e| panic!("{e}"));
        d.shutdown();
    }
}

#[test]
fn mutating_http_calls_need_the_token() {
    let d = with_token(&[]);
    let a = d.http_addr;
    for (path, body) in [
        ("/config", &br#"{"mode":"free"}"#[..]),
        ("/calibration", b"feff_w_m2,dn\n"),
    ] {
        for headers in [
            &[][..],
            &["Authorization: Bearer wrong-token-0000000"][..],
            &[&*format!("Authorization: {TOKEN}")][..],
        ] {
            let (code, body) = http_with(a, "PUT", path, headers, body);
            assert_eq!(code, 401, "PUT {path} {headers:?}");
            assert!(!String::from_utf8_lossy(&body).contains(TOKEN));
        }
    }
    let bearer = format!("Authorization: Bearer {TOKEN}");
    let (code, body) = http_with(a, "PUT", "/config", &[&bearer], br#"{"mode":"free"}"#);
    assert_eq!(code, 200, "{}", String::from_utf8_lossy(&body));
    // Past the token, a bad curve is the curve's problem.
    let (code, _) = http_with(a, "PUT", "/calibration", &[&bearer], b"not a curve");
    assert_eq!(code, 422);
    // Reading stays open.
    assert_eq!(http(a, "GET", "/status", b"").0, 200);
    assert_eq!(http(a, "GET", "/config", b"").0, 200);
}

#[test]
fn a_pose_connection_says_hello_with_the_token_first() {
    let d = with_token(&[]);
    // A pose before any hello.
    let mut c = Client::connect(d.tcp_addr);
    c.send(&Message::Pose(nrho_pose(1)));
    refused_and_closed(&mut c);
    // A hello without the token, then with a wrong one.
    for token in [None, Some("wrong-token-000000000")] {
        let mut c = Client::connect(d.tcp_addr);
        c.send(&hello(token));
        c.send(&Message::Pose(nrho_pose(2)));
        refused_and_closed(&mut c);
    }
    // JSON lines are held to the same rule.
    let mut c = Client::connect(d.tcp_addr);
    c.send_raw(b"{\"type\":\"trigger\"}\n");
    let mut line = String::new();
    use std::io::BufRead;
    std::io::BufReader::new(c.stream.try_clone().unwrap())
        .read_line(&mut line)
        .unwrap();
    assert!(line.contains("unauthorized"), "{line}");
    // The right token: served.
    let mut c = Client::connect(d.tcp_addr);
    c.send(&hello(Some(TOKEN)));
    assert!(matches!(c.recv(WAIT), Some(Message::HelloAck { .. })));
    c.send(&Message::Pose(nrho_pose(3)));
    loop {
        match c.recv(WAIT) {
            Some(Message::Ack(a)) if a.frame_id == 3 => break,
            Some(Message::Error { message, .. }) => panic!("{message}"),
            Some(_) => continue,
            None => panic!("pose 3 was not acked"),
        }
    }
    let report = d.shutdown();
    assert_eq!(report.frames_presented, 1);
}

#[test]
fn the_token_stays_out_of_the_recording() {
    let dir = TempDir::new("access-record");
    let rec = dir.join("rec.jsonl");
    let mut o = options();
    o.record = Some(rec.clone());
    o.access = Access::new(Some(TOKEN), &[], false).unwrap();
    let d = optistim::server::Server::start(o).unwrap();
    let mut c = Client::connect(d.tcp_addr);
    c.send(&hello(Some(TOKEN)));
    assert!(matches!(c.recv(WAIT), Some(Message::HelloAck { .. })));
    d.shutdown();
    let text = std::fs::read_to_string(&rec).unwrap();
    assert!(
        text.contains("\"hello\"") && text.contains("<redacted>"),
        "{text}"
    );
    assert!(!text.contains(TOKEN), "{text}");
}

/// `PUT /config {"scene": ...}` and the `config` message read only `.toml` scenes inside the
/// scene folders, whose files lie there too; refusals say why without echoing the file.
#[test]
fn scenes_named_over_the_network_stay_in_the_scene_folders() {
    let dir = TempDir::new("access-scenes");
    let scenes = dir.join("scenes");
    std::fs::create_dir_all(&scenes).unwrap();
    let secret = "SECRET-LINE-root:x:0:0";
    // Outside the folder: a secret, and a map.
    std::fs::write(dir.join("secret.toml"), format!("{secret}\n")).unwrap();
    std::fs::write(dir.join("map.tif"), b"II*\0").unwrap();
    // Inside: a file that is not a scene, and a scene naming a map outside.
    std::fs::write(scenes.join("notes.toml"), format!("{secret}\n")).unwrap();
    let outside_map = small_daemon_config().replace(
        "[camera]",
        "albedo_map = { path = \"../map.tif\" }\n\n[camera]",
    );
    std::fs::write(scenes.join("outside_map.toml"), outside_map).unwrap();
    std::fs::write(scenes.join("good.toml"), small_daemon_config()).unwrap();
    #[cfg(unix)]
    std::os::unix::fs::symlink(dir.join("secret.toml"), scenes.join("link.toml")).unwrap();

    let d = with_token(std::slice::from_ref(&scenes));
    let bearer = format!("Authorization: Bearer {TOKEN}");
    let put = |scene: &str| {
        let body = serde_json::json!({ "scene": scene }).to_string();
        let (code, body) = http_with(d.http_addr, "PUT", "/config", &[&bearer], body.as_bytes());
        (code, String::from_utf8_lossy(&body).into_owned())
    };
    let secret_path = dir.join("secret.toml");
    let cases = [
        ("/etc/shadow", "a .toml file"),
        ("/etc/passwd", "a .toml file"),
        (secret_path.to_str().unwrap(), "outside the scene folders"),
        ("../secret.toml", "outside the scene folders"),
        ("link.toml", "outside the scene folders"),
        ("notes.toml", "not a valid scene (TOML error on line 1)"),
        ("outside_map.toml", "outside the scene folders"),
        ("missing.toml", "No such file"),
    ];
    for (scene, why) in cases {
        let (code, body) = put(scene);
        assert_eq!(code, 422, "{scene}: {body}");
        assert!(body.contains(why), "{scene}: {body}");
        assert!(
            !body.contains("SECRET") && !body.contains("root:"),
            "{scene}: {body}"
        );
    }
    // The same rule over the pose connection's config message.
    let mut c = Client::connect(d.tcp_addr);
    c.send(&hello(Some(TOKEN)));
    assert!(matches!(c.recv(WAIT), Some(Message::HelloAck { .. })));
    c.send(&Message::Config {
        json: r#"{"scene":"../secret.toml"}"#.into(),
    });
    match c.recv(WAIT) {
        Some(Message::Error { code, message, .. }) => {
            assert_eq!(code, ErrorCode::BadConfig);
            assert!(message.contains("outside the scene folders"), "{message}");
            assert!(!message.contains("SECRET"), "{message}");
        }
        other => panic!("{other:?}"),
    }
    // A scene inside, by a relative name: loaded.
    let (code, body) = put("good.toml");
    assert_eq!(code, 200, "{body}");
}

#[test]
fn without_a_scene_folder_no_scene_is_named_over_the_network() {
    let mut o = options();
    o.access = Access::default();
    let d = optistim::server::Server::start(o).unwrap();
    let (code, body) = http(
        d.http_addr,
        "PUT",
        "/config",
        br#"{"scene":"/etc/passwd.toml"}"#,
    );
    assert_eq!(code, 422);
    assert!(String::from_utf8_lossy(&body).contains("--scene-dir"));
}
