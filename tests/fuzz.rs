//! Protocol and parser fuzzing (issue 19, item 7): at least a million generated and mutated
//! frames through the pose protocol's decoder, in random chunks: no panic, memory bounded
//! (the decoder holds at most one frame's worth of bytes past what it was fed), every
//! problem a typed error, every valid frame decoded to what was encoded; mutated SurRender
//! messages through its QHash reader; mutated scene and calibration files through their
//! parsers. Seeded: a failure reproduces.

use optistim::server::protocol::{
    AckFidelity, AckMsg, AckStatus, Decoded, Decoder, ErrorCode, MAX_INBOUND_PAYLOAD, Message,
    PoseMsg,
};
use optistim::server::surrender::{self, QVar};
use rand::{RngExt, SeedableRng};
use rand_pcg::Pcg64;

const FRAMES: usize = 1_000_000;

fn random_message(rng: &mut Pcg64) -> Message {
    let f = |rng: &mut Pcg64| -> f64 {
        match rng.random_range(0..8) {
            0 => f64::NAN,
            1 => f64::INFINITY,
            2 => -0.0,
            3 => f64::MAX,
            _ => rng.random_range(-1e12..1e12),
        }
    };
    let s = |rng: &mut Pcg64| -> String {
        let n = rng.random_range(0..24);
        (0..n)
            .map(|_| char::from_u32(rng.random_range(32..0x2fff)).unwrap_or('?'))
            .collect()
    };
    match rng.random_range(0..9) {
        0 => Message::Hello {
            version_min: rng.random(),
            version_max: rng.random(),
            client: s(rng),
            token: rng.random_bool(0.5).then(|| s(rng)),
        },
        1..=3 => Message::Pose(PoseMsg {
            frame_id: rng.random(),
            time_tag_s: f(rng),
            camera_position_m: [f(rng), f(rng), f(rng)],
            attitude_wxyz: [f(rng), f(rng), f(rng), f(rng)],
            sun_position_m: [f(rng), f(rng), f(rng)],
            body_attitude_wxyz: rng
                .random_bool(0.3)
                .then(|| [f(rng), f(rng), f(rng), f(rng)]),
            exposure_s: rng.random_bool(0.3).then(|| f(rng)),
            bodies: rng.random_bool(0.2).then(|| {
                (0..rng.random_range(0..4))
                    .map(|_| optistim::server::protocol::BodyPoseMsg {
                        position_m: [f(rng), f(rng), f(rng)],
                        attitude_wxyz: [f(rng), f(rng), f(rng), f(rng)],
                    })
                    .collect()
            }),
        }),
        4 => Message::Config { json: s(rng) },
        5 => Message::Subscribe {
            camera: rng.random(),
        },
        6 => Message::Trigger,
        7 => Message::Ack(AckMsg {
            frame_id: rng.random(),
            status: AckStatus::Presented,
            calibration_id: s(rng),
            fidelity: rng.random_bool(0.5).then(|| AckFidelity {
                points_per_pixel: f(rng),
                boundary_nodes: rng.random(),
                self_shadowing: rng.random_range(0..3),
                predicted_median: f(rng),
                predicted_p99: f(rng),
                predicted_total: f(rng),
                meets_budget: rng.random(),
                map_filter: rng.random_range(0..4),
                relief_refine: rng.random(),
            }),
            ..AckMsg::dropped(0, 0)
        }),
        _ => Message::Error {
            code: ErrorCode::from_u16(rng.random_range(1..14)),
            frame_id: rng.random_bool(0.5).then(|| rng.random()),
            message: s(rng),
        },
    }
}

/// Flips bits, cuts, duplicates, splices random bytes or rewrites the length field.
fn mutate(rng: &mut Pcg64, b: &mut Vec<u8>) {
    if b.is_empty() {
        return;
    }
    match rng.random_range(0..6) {
        0 => {
            let i = rng.random_range(0..b.len());
            b[i] ^= 1 << rng.random_range(0..8);
        }
        1 => b.truncate(rng.random_range(0..b.len())),
        2 => {
            let i = rng.random_range(0..b.len());
            let junk: Vec<u8> = (0..rng.random_range(1..16)).map(|_| rng.random()).collect();
            b.splice(i..i, junk);
        }
        3 if b.len() >= 8 => {
            let n: u32 = match rng.random_range(0..3) {
                0 => u32::MAX,
                1 => MAX_INBOUND_PAYLOAD + 1,
                _ => rng.random(),
            };
            b[4..8].copy_from_slice(&n.to_le_bytes());
        }
        4 => {
            let i = rng.random_range(0..b.len());
            b.remove(i);
        }
        _ => {
            let i = rng.random_range(0..b.len());
            let j = rng.random_range(i..b.len());
            let copy = b[i..j].to_vec();
            b.extend_from_slice(&copy);
        }
    }
}

#[test]
fn a_million_generated_and_mutated_frames_never_break_the_decoder() {
    let mut rng = Pcg64::seed_from_u64(19);
    let mut d = Decoder::new(MAX_INBOUND_PAYLOAD);
    let (mut clean_ok, mut errors, mut decoded) = (0usize, 0usize, 0usize);
    let mut stream = Vec::new();
    let mut max_pending = 0;
    for n in 0..FRAMES {
        let m = random_message(&mut rng);
        let mut bytes = m.encode();
        let mutated = rng.random_bool(0.5);
        if mutated {
            for _ in 0..rng.random_range(1..4) {
                mutate(&mut rng, &mut bytes);
            }
        } else if n % 1000 == 0 {
            // A clean frame on a fresh decoder comes back as it went.
            let mut fresh = Decoder::new(MAX_INBOUND_PAYLOAD);
            fresh.push(&bytes);
            match fresh.next_message() {
                Decoded::Message(got) => {
                    // NaN never equals itself: compare the re-encoding.
                    assert_eq!(got.encode(), bytes, "frame {n}");
                    clean_ok += 1;
                }
                other => panic!("frame {n}: a clean frame gave {other:?}"),
            }
        }
        stream.extend_from_slice(&bytes);
        // Fed in random chunks, as a socket would.
        while !stream.is_empty() && (stream.len() > 4096 || rng.random_bool(0.5)) {
            let k = rng.random_range(1..=stream.len());
            d.push(&stream[..k]);
            stream.drain(..k);
            loop {
                match d.next_message() {
                    Decoded::Message(_) => decoded += 1,
                    Decoded::Error(e) => {
                        errors += 1;
                        assert!(!e.message.is_empty());
                    }
                    Decoded::NeedMore => break,
                }
            }
            max_pending = max_pending.max(d.pending());
        }
    }
    assert!(
        max_pending <= MAX_INBOUND_PAYLOAD as usize + 4096 + 12,
        "the decoder held {max_pending} bytes"
    );
    eprintln!(
        "{FRAMES} frames: {decoded} decoded, {errors} errors, {clean_ok} clean round trips, \
         at most {max_pending} bytes held"
    );
    assert!(decoded > FRAMES / 3 && errors > FRAMES / 10);
}

#[test]
fn mutated_surrender_messages_are_typed_errors() {
    let mut rng = Pcg64::seed_from_u64(5151);
    let base = surrender::encode_hash(&[
        (String::new(), QVar::String("setObjectAttitude".into())),
        ("object_name".into(), QVar::String("camera".into())),
        ("attitude".into(), QVar::List(vec![QVar::Double(0.5); 4])),
        ("blob".into(), QVar::Bytes(vec![7; 40])),
        ("n".into(), QVar::Hash(vec![("k".into(), QVar::Int(3))])),
    ]);
    let (mut ok, mut bad) = (0, 0);
    for _ in 0..200_000 {
        let mut b = base.clone();
        for _ in 0..rng.random_range(1..4) {
            mutate(&mut rng, &mut b);
        }
        match surrender::read_hash(&mut &b[..]) {
            Ok(_) => ok += 1,
            Err(e) => {
                bad += 1;
                assert!(!e.to_string().is_empty());
            }
        }
    }
    assert!(ok > 0 && bad > 0, "{ok} parsed, {bad} refused");
}

/// Random edits of a text: characters changed, lines dropped or doubled.
fn mutate_text(rng: &mut Pcg64, text: &str) -> String {
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    for _ in 0..rng.random_range(1..4) {
        let i = rng.random_range(0..lines.len());
        match rng.random_range(0..4) {
            0 => {
                lines.remove(i);
            }
            1 => {
                let l = lines[i].clone();
                lines.insert(i, l);
            }
            2 => {
                let mut chars: Vec<char> = lines[i].chars().collect();
                if !chars.is_empty() {
                    let j = rng.random_range(0..chars.len());
                    chars[j] = *b"=[]{}\"0-9.e,#x "
                        .get(rng.random_range(0..15))
                        .map(|c| char::from(*c))
                        .as_ref()
                        .unwrap();
                }
                lines[i] = chars.into_iter().collect();
            }
            _ => lines[i] = lines[i].replace(|c: char| c.is_ascii_digit(), "9"),
        }
        if lines.is_empty() {
            break;
        }
    }
    lines.join("\n")
}

#[test]
fn mutated_scenes_and_curves_are_refused_or_accepted_never_panics() {
    let mut rng = Pcg64::seed_from_u64(7);
    let scene = optistim::server::DEFAULT_CONFIG;
    let (mut ok, mut bad) = (0, 0);
    for _ in 0..3000 {
        let t = mutate_text(&mut rng, scene);
        match optistim::config::parse(&t, "fuzz.toml") {
            Ok(_) => ok += 1,
            Err(e) => {
                bad += 1;
                assert!(e.to_string().starts_with("fuzz.toml"), "{e}");
            }
        }
    }
    assert!(bad > 0, "{ok} accepted, {bad} refused");
    let curve = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/calibration/example_gamma22.csv"
    ))
    .unwrap();
    let (mut ok, mut bad) = (0, 0);
    for _ in 0..3000 {
        let t = mutate_text(&mut rng, &curve);
        match optistim::stimulator::calibration::Curve::parse(
            t.as_bytes(),
            "fuzz",
            "fuzz.csv",
            Default::default(),
        ) {
            Ok(_) => ok += 1,
            Err(e) => {
                bad += 1;
                assert!(!e.to_string().is_empty());
            }
        }
    }
    assert!(bad > 0 && ok > 0, "{ok} accepted, {bad} refused");
}
