use optistim::fidelity::metrics::frame_error;
use optistim::render::Renderer;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let cfg = optistim::config::load(std::path::Path::new(&args[1])).unwrap();
    let poses = optistim::trajectory::read(std::path::Path::new(&args[2])).unwrap();
    let row: usize = args[3].parse().unwrap();
    let pose = poses[row].1;
    let ex = optistim::raycast::exact::render(&cfg.scene, &pose).unwrap();
    let intr = &cfg.scene.camera.intrinsics;
    let (w, h) = (intr.width_px as usize, intr.height_px as usize);
    let mut r = Renderer::new(0).unwrap();
    for &samples in &[1u32, 2, 4] {
        for &n in &[4u32, 16, 64, 128, 256] {
            let mut s = cfg.settings.clone();
            s.raycast_budget = None;
            s.raycast_edge_samples = n;
            s.raycast_samples = samples;
            let f = r.render(&cfg.scene, &pose, &s).unwrap();
            let e = frame_error(&f.pl, &ex.frame.pl, w, h);
            let tot = f.pl.iter().sum::<f64>() / ex.frame.pl.iter().sum::<f64>() - 1.0;
            println!(
                "samples {samples} edge {n}: median {:.2e} p99 {:.2e} total {:+.2e}",
                e.median, e.p99, tot
            );
        }
    }
}
