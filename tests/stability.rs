//! The stability suite (`optistim stability`, `src/app/stability.rs`) as a test: every case
//! renders (finite, in range, light conserved where the body is wholly in view) or is refused
//! with a typed error, as it must; none gives NaN, panics or hangs (each within 300 s); and
//! under `fidelity = "budget"` none is over the budget without saying so.

use optistim::app::stability::{self, Outcome};

#[test]
fn every_case_renders_or_is_refused_as_it_must_never_nan_panic_or_hang() {
    let work = std::env::temp_dir().join(format!("optistim-stability-test-{}", std::process::id()));
    let reports = stability::run(&work, std::time::Duration::from_secs(300), |r| {
        eprintln!(
            "{:60} {:?} energy {:?} error {:?} ({:.0} ms)",
            r.case, r.outcome, r.energy, r.error, r.ms
        )
    })
    .unwrap();
    let _ = std::fs::remove_dir_all(&work);
    let wrong: Vec<_> = reports.iter().filter(|r| !r.as_expected()).collect();
    assert!(wrong.is_empty(), "not as expected: {wrong:#?}");
    let find = |name: &str| reports.iter().find(|r| r.case.starts_with(name)).unwrap();
    // A refusal names its cause.
    match &find("camera inside the body").outcome {
        Outcome::Refused { error } => assert!(error.contains("outside the body"), "{error}"),
        other => panic!("{other:?}"),
    }
    match &find("degenerate quaternion").outcome {
        Outcome::Refused { error } => assert!(error.contains("unit quaternion"), "{error}"),
        other => panic!("{other:?}"),
    }
    // Where the body is wholly in view the light is conserved.
    let phase0 = find("phase 0");
    assert!(phase0.energy.is_some_and(|e| e < 1e-9), "{phase0:?}");
    // Nothing in view: an empty frame that the reference agrees is empty.
    let behind = find("body behind the camera").error.unwrap();
    assert_eq!((behind.total, behind.lit_px), (0.0, 0));
    assert!(reports.len() >= 30);
    // Under `fidelity = "budget"` a frame is within the budget or says it is not: never
    // silently over it (the model's domain, `Planner::outside_model`, caught the camera 1 m
    // over the ground, the 10 : 1 ellipsoid, the DEM's cliff and spike, the narrow surge).
    let silent: Vec<_> = reports
        .iter()
        .filter(|r| r.budgeted.as_ref().is_some_and(|b| !b.honest()))
        .collect();
    assert!(
        silent.is_empty(),
        "over the budget, said it met it: {silent:#?}"
    );
    let budgeted = |name: &str| find(name).budgeted.clone().unwrap();
    // Inside the model's domain the budget holds where the frame said it would.
    for name in [
        "phase 0",
        "phase 90",
        "body cut by one edge",
        "pole-on view",
    ] {
        let b = budgeted(name);
        assert!(b.meets_budget && b.within(), "{name}: {b:?}");
    }
    // Outside the model's domain a frame says why, renders at the top rung and does not
    // claim the budget.
    for name in [
        "camera 1 m above the surface",
        "ellipsoid of axis ratio 10",
        "vertical DEM step",
        "overhanging DEM step",
        "Hapke h = 1e-6",
    ] {
        let b = budgeted(name);
        assert!(
            b.outside_model.is_some() && !b.meets_budget && b.points_per_pixel == 16.0,
            "{name}: {b:?}"
        );
    }
    assert!(budgeted("flat DEM").outside_model.is_none());
}
