//! Validation against phase laws (paper Sec. 5.1, Eqs. 48-49): Lambert, Area and
//! Lommel-Seeliger spheres at phase 0-150 deg and camera distance 10-10^4 radii. The measured
//! phase law (Eq. 49) must approach the analytic one as the distance grows.
//!
//! Phase laws hold at infinite distance only. At a finite distance `d` the local camera
//! direction lowers `cos(theta_r)` by `(R/d)(1 - mu^2)` and `1/d_cam^2` rises by `2 (R/d) mu`, a
//! first-order change of relative size `(R/d) int f mu0 (3 mu^2 - 1) / int f mu0 mu`, about
//! `-2 R/d` for the thin crescent at 120 deg. The test asserts what that physics allows: the
//! error falls as `1/d` (a factor > 5 per decade while above 1e-3), is below 0.1 % from d/R = 1000 on for phases
//! up to 90 deg, and below 0.1 % at d/R = 10^4 for every phase. A second test computes the
//! exact finite-distance flux by independent quadrature and shows the renderer matches it to
//! 5e-5 from d/R = 100 on, at every phase: the rest is the phase law's far-distance assumption.

mod common;
use common::*;
use glam::DVec3;
use optistim::brdf::Local;
use optistim::config::Config;
use optistim::render::Renderer;

/// The test scene: the camera at `d_over_r` radii and `phase_deg` from the Sun, looking at the
/// centre, the disk about 100 px in radius in a 256 x 256 image.
fn scene(brdf: &str, phase_deg: f64, d_over_r: f64) -> Config {
    let d = d_over_r * R_MOON;
    let a = phase_deg.to_radians();
    // Disk radius about 100 px in a 256 x 256 image.
    let f_px = 100.0 / (1.0 / d_over_r).asin().tan();
    SceneSpec {
        brdf,
        albedo: 0.3,
        camera_m: [d * a.cos(), d * a.sin(), 0.0],
        sun_m: [AU, 0.0, 0.0],
        focal_m: f_px * 5.5e-6,
        ..Default::default()
    }
    .config()
}

/// `Psi_meas` of Eq. 49 for a collected `sum (P/L)`, with cos(eps) = 1 (boresight on the
/// centre) and centre distances.
fn psi(cfg: &Config, total: f64) -> f64 {
    let s = &cfg.scene;
    let d = cfg.pose.camera_position_m.length();
    let d_sun = cfg.pose.sun_position_m.length();
    let r = s.body.shape.bounding_radius_m();
    total
        / (s.sun.area_m2() * s.camera.intrinsics.aperture_area_m2() / (d_sun * d_sun * d * d)
            * r
            * r
            * s.body.brdf.geometric_albedo())
}

/// The rendered `Psi_meas` and the analytic phase law.
fn measured(brdf: &str, phase_deg: f64, d_over_r: f64, renderer: &mut Renderer) -> (f64, f64) {
    let cfg = scene(brdf, phase_deg, d_over_r);
    let frame = renderer
        .render(&cfg.scene, &cfg.pose, &cfg.settings)
        .unwrap();
    let total: f64 = frame.pl.iter().sum();
    (
        psi(&cfg, total),
        cfg.scene.body.brdf.phase_law(phase_deg.to_radians()),
    )
}

#[test]
fn measured_phase_law_converges_to_the_analytic_one() {
    let mut renderer = Renderer::new(0).unwrap();
    for brdf in ["lambert", "area", "lommel_seeliger"] {
        for phase in [0.0, 30.0, 60.0, 90.0, 120.0, 150.0] {
            let mut errs = Vec::new();
            for dr in [10.0, 100.0, 1000.0, 10000.0] {
                let (m, a) = measured(brdf, phase, dr, &mut renderer);
                let e = (m / a - 1.0).abs();
                eprintln!(
                    "{brdf:16} phase {phase:5.1} d/R {dr:7.0}: measured {m:.8} analytic {a:.8} rel err {e:.2e}"
                );
                errs.push(e);
            }
            // Falls with distance until the numerical floor (~1e-4) or the Sun's own parallax
            // (R / 1 AU = 1.2e-5) takes over.
            assert!(
                errs[0] > errs[3] || errs[0] < 1e-4,
                "{brdf} {phase}: error must fall with distance: {errs:?}"
            );
            for w in errs.windows(2) {
                assert!(
                    w[0] > 5.0 * w[1] || w[1] < 1e-3,
                    "{brdf} {phase}: error must fall as 1/d: {errs:?}"
                );
            }
            assert!(errs[3] < 1e-3, "{brdf} {phase}: {errs:?}");
            if phase <= 90.0 {
                assert!(errs[2] < 1e-3, "{brdf} {phase}: {errs:?}");
            }
        }
    }
}

/// Gauss-Legendre nodes and weights on [0, 1] (Newton on the Legendre recurrence): written
/// here rather than taken from the renderer, so that the reference shares none of its code.
fn gauss_legendre(n: usize) -> Vec<(f64, f64)> {
    (0..n)
        .map(|i| {
            let mut x = (std::f64::consts::PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
            let mut dp = 1.0;
            for _ in 0..100 {
                let (mut p0, mut p1) = (1.0, x);
                for k in 2..=n {
                    let p2 = ((2 * k - 1) as f64 * x * p1 - (k - 1) as f64 * p0) / k as f64;
                    p0 = p1;
                    p1 = p2;
                }
                dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
                let dx = p1 / dp;
                x -= dx;
                if dx.abs() < 1e-16 {
                    break;
                }
            }
            (0.5 * (1.0 - x), 1.0 / ((1.0 - x * x) * dp * dp))
        })
        .collect()
}

/// The exact `sum (P/L)` a camera collects from the sphere at a finite distance (Eq. 11 summed
/// over the surface, every factor at each surface point: Sun and camera directions and
/// distances, the camera obliquity `cos eps`), integrated independently of the renderer: polar
/// angle `theta` about the camera direction over the visible cap `cos theta > R/d`, split where
/// the lit arc of a ring opens or closes and mapped `theta = a + (b-a)(1 - cos pi t)/2` to
/// smooth the square-root ends; on each ring, Gauss-Legendre over the lit arc.
fn exact_total(cfg: &Config, nodes: usize) -> f64 {
    let s = &cfg.scene;
    let brdf = &s.body.brdf;
    let r = s.body.shape.bounding_radius_m();
    let cam = cfg.pose.camera_position_m;
    let sun = cfg.pose.sun_position_m;
    let d = cam.length();
    let c_hat = cam / d;
    let e1 = c_hat.any_orthonormal_vector();
    let e2 = c_hat.cross(e1);
    let s_hat = sun.normalize();
    let (sc, s1, s2) = (s_hat.dot(c_hat), s_hat.dot(e1), s_hat.dot(e2));
    let (sb, phi_s) = (s1.hypot(s2), s2.atan2(s1));
    let kappa_0 = r / sun.length();
    let theta_max = (r / d).acos();
    // Lit on the ring theta: cos(phi - phi_s) > kappa(theta).
    let kappa = |th: f64| (kappa_0 - th.cos() * sc) / (th.sin() * sb);
    // Rings where the arc opens or closes: sc cos(th) + sb sin(th) (+-1) = kappa_0.
    let mut cuts = vec![0.0, theta_max];
    let (amp, beta) = (sc.hypot(sb), sb.atan2(sc));
    for sign in [1.0, -1.0] {
        let base = (kappa_0 / amp).clamp(-1.0, 1.0).acos();
        for th in [sign * beta + base, sign * beta - base] {
            if th > 0.0 && th < theta_max {
                cuts.push(th);
            }
        }
    }
    cuts.sort_by(f64::total_cmp);
    let gl = gauss_legendre(nodes);
    let pi = std::f64::consts::PI;
    let integrand = |n: DVec3| -> f64 {
        let p = r * n;
        let (to_cam, to_sun) = (cam - p, sun - p);
        let (dc, ds) = (to_cam.length(), to_sun.length());
        let g = Local::new(n, to_sun / ds, to_cam / dc);
        if g.mu <= 0.0 || g.mu0 <= 0.0 {
            return 0.0;
        }
        let cos_eps = c_hat.dot(to_cam / dc);
        brdf.eval(&g) * g.mu0 * g.mu * cos_eps / (ds * ds * dc * dc)
    };
    let mut total = 0.0;
    for w in cuts.windows(2) {
        let (a, b) = (w[0], w[1]);
        if b - a < 1e-15 {
            continue;
        }
        for &(t, wt) in &gl {
            let th = a + (b - a) * 0.5 * (1.0 - (pi * t).cos());
            let dth = (b - a) * 0.5 * pi * (pi * t).sin() * wt;
            let k = kappa(th);
            let half = if k <= -1.0 {
                pi
            } else if k >= 1.0 {
                continue;
            } else {
                k.acos()
            };
            let (sin_t, cos_t) = th.sin_cos();
            let mut ring = 0.0;
            for &(u, wu) in &gl {
                let phi = phi_s - half + 2.0 * half * u;
                let n = cos_t * c_hat + sin_t * (phi.cos() * e1 + phi.sin() * e2);
                ring += wu * integrand(n);
            }
            total += ring * 2.0 * half * sin_t * dth;
        }
    }
    s.sun.area_m2() * s.camera.intrinsics.aperture_area_m2() * r * r * total
}

/// The renderer against the exact finite-distance flux: what remains of the phase-law error
/// above is physics (the phase law's far-distance assumption), not numerics. Measured: below
/// 5e-5 from d/R = 100 on (Lommel-Seeliger, integrated numerically, about 1e-5 at every
/// distance), up to 4.4e-4 at d/R = 10 and 150 deg (a thin crescent seen from close by).
#[test]
fn rendered_flux_matches_the_exact_finite_distance_flux() {
    let mut renderer = Renderer::new(0).unwrap();
    let (mut worst_near, mut worst_far): (f64, f64) = (0.0, 0.0);
    for brdf in ["lambert", "area", "lommel_seeliger"] {
        for phase in [0.0, 30.0, 60.0, 90.0, 120.0, 150.0] {
            for dr in [10.0, 100.0, 1000.0, 10000.0] {
                let cfg = scene(brdf, phase, dr);
                let exact = exact_total(&cfg, 160);
                let check = exact_total(&cfg, 320);
                assert!(
                    ((exact - check) / check).abs() < 1e-9,
                    "{brdf} {phase} {dr}: reference not converged: {exact} vs {check}"
                );
                let (rendered, law) = measured(brdf, phase, dr, &mut renderer);
                let physics = psi(&cfg, exact) / law - 1.0;
                let e = (rendered / psi(&cfg, exact) - 1.0).abs();
                eprintln!(
                    "{brdf:16} phase {phase:5.1} d/R {dr:7.0}: rendered/exact - 1 = {e:.2e}  \
                     (exact finite-distance Psi / phase law - 1 = {physics:+.2e})"
                );
                if dr < 100.0 {
                    worst_near = worst_near.max(e);
                } else {
                    worst_far = worst_far.max(e);
                }
            }
        }
    }
    eprintln!("worst rendered/exact - 1: {worst_near:.2e} at d/R 10, {worst_far:.2e} beyond");
    assert!(worst_near < 1e-3 && worst_far < 1e-4);
}

/// The converged reference (per-pixel ray casting, adaptive cubature over each pixel) against
/// the exact finite-distance flux, at every phase from 0 to 170 deg, near and far: within its
/// own error estimate at every phase, and within 1e-6 up to 150 deg (measured 2026-11-28:
/// Lambert at most 4.4e-8, Lommel-Seeliger 4.1e-8; at 170 deg from 10 radii 5.6e-7 and
/// 7.6e-7, estimated 1.7e-3 and 2.1e-3, and with the cells' signs kept 4.1e-6 and 4.3e-6:
/// within that estimate too). The Area model, whose
/// radiance steps from full to nothing at the terminator, is left out: a cell whose 13 rays
/// are all lit while a corner lies beyond the terminator is taken as lit, and the reference
/// was 6.5e-6 off at 60 deg from 1000 radii while estimating 2.1e-6 (`raycast::reference`).
#[test]
fn the_reference_matches_the_exact_finite_distance_flux_at_every_phase() {
    let settings = optistim::raycast::reference::ReferenceSettings::default();
    let mut worst: f64 = 0.0;
    for brdf in ["lambert", "lommel_seeliger"] {
        for phase in [0.0, 60.0, 120.0, 150.0, 170.0] {
            for dr in [10.0, 1000.0] {
                let cfg = scene(brdf, phase, dr);
                let exact = exact_total(&cfg, 320);
                let r =
                    optistim::raycast::reference::render(&cfg.scene, &cfg.pose, &settings).unwrap();
                let total: f64 = r.frame.pl.iter().sum();
                let e = (total / exact - 1.0).abs();
                eprintln!(
                    "{brdf:16} phase {phase:5.1} d/R {dr:6.0}: reference/exact - 1 = {e:.2e} \
                     (its estimate {:.2e}, with the cells' signs {:.2e}, {} rays)",
                    r.report.est_error_total, r.report.signed_error_total, r.report.rays
                );
                // The estimate with the cells' signs kept (the same cells' errors added with
                // their signs) is below the bound and, on these smooth spheres, still above
                // the error: 5 to 500 times it, where the bound is 100 to 10^4 times.
                assert!(
                    r.report.signed_error_total <= r.report.est_error_total
                        && r.report.signed_error_p99 <= r.report.est_error_p99,
                    "{:?}",
                    r.report
                );
                assert!(
                    e <= r.report.signed_error_total.max(1e-9),
                    "{brdf} {phase} {dr}: {e:e} against {:e}",
                    r.report.signed_error_total
                );
                assert!(
                    e <= r.report.est_error_total.max(1e-9),
                    "{brdf} {phase} {dr}: {e:e}"
                );
                if phase <= 150.0 {
                    worst = worst.max(e);
                }
            }
        }
    }
    assert!(worst < 1e-6, "{worst:e}");
}

/// The midpoint rule (render.integration = "midpoint", the faster sub-grid rule) against the
/// exact finite-distance flux, beside the trapezoidal rule, on the Lommel-Seeliger sphere
/// (no closed form: both integrate it numerically).
#[test]
fn the_midpoint_rule_matches_the_exact_flux_as_the_trapezoid_does() {
    use optistim::render::settings::Integration;
    let mut renderer = Renderer::new(0).unwrap();
    for phase in [0.0, 60.0, 120.0] {
        for dr in [100.0, 1000.0] {
            let mut cfg = scene("lommel_seeliger", phase, dr);
            let exact = exact_total(&cfg, 160);
            let mut err = |integration| {
                cfg.settings.integration = integration;
                let f = renderer
                    .render(&cfg.scene, &cfg.pose, &cfg.settings)
                    .unwrap();
                (f.pl.iter().sum::<f64>() / exact - 1.0).abs()
            };
            let mid = err(Integration::Midpoint {
                points_per_deg: 5.0,
            });
            let trap = err(Integration::Trapezoidal {
                points_per_deg: 5.0,
            });
            eprintln!("phase {phase:5.1} d/R {dr:6.0}: midpoint {mid:.2e} trapezoid {trap:.2e}");
            assert!(mid < 1e-4 && trap < 1e-4, "{mid} {trap}");
        }
    }
}
