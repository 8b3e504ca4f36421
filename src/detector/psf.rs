//! The camera's point-spread function: a Gaussian of standard deviation `sigma` [px], applied
//! to the signal before exposure. Separable, normalised (energy-conserving away from the
//! edges), truncated at `ceil(3 sigma)` pixels each side (`radius`), edges replicated.

use rayon::prelude::*;

/// `data` (row-major, `width` x `height`) convolved with the Gaussian.
pub fn gaussian_blur(
    data: &[f64],
    width: usize,
    height: usize,
    sigma: f64,
    radius: usize,
) -> Vec<f64> {
    let k: Vec<f64> = (-(radius as i64)..=radius as i64)
        .map(|i| (-((i * i) as f64) / (2.0 * sigma * sigma)).exp())
        .collect();
    let norm: f64 = k.iter().sum();
    let k: Vec<f64> = k.iter().map(|v| v / norm).collect();
    let r = radius as i64;
    let (w, h) = (width as i64, height as i64);
    let mut rows = vec![0.0; data.len()];
    rows.par_chunks_mut(width.max(1))
        .enumerate()
        .for_each(|(y, out)| {
            let src = &data[y * width..(y + 1) * width];
            for (x, o) in out.iter_mut().enumerate() {
                *o = k
                    .iter()
                    .enumerate()
                    .map(|(t, kv)| kv * src[(x as i64 + t as i64 - r).clamp(0, w - 1) as usize])
                    .sum();
            }
        });
    let mut out = vec![0.0; data.len()];
    out.par_chunks_mut(width.max(1))
        .enumerate()
        .for_each(|(y, o)| {
            for (t, kv) in k.iter().enumerate() {
                let sy = (y as i64 + t as i64 - r).clamp(0, h - 1) as usize;
                let src = &rows[sy * width..(sy + 1) * width];
                for (a, b) in o.iter_mut().zip(src) {
                    *a += kv * b;
                }
            }
        });
    out
}

/// The truncation radius for `sigma`: `ceil(3 sigma)` pixels.
pub fn radius(sigma: f64) -> usize {
    (3.0 * sigma).ceil() as usize
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_point_keeps_its_energy_and_spreads_as_sigma() {
        let (w, h) = (41, 41);
        let mut d = vec![0.0; w * h];
        d[20 * w + 20] = 1.0;
        let b = gaussian_blur(&d, w, h, 1.2, radius(1.2));
        let total: f64 = b.iter().sum();
        assert!((total - 1.0).abs() < 1e-12, "{total}");
        let var_x: f64 = b
            .iter()
            .enumerate()
            .map(|(i, v)| v * ((i % w) as f64 - 20.0).powi(2))
            .sum();
        // Truncation at 3 sigma trims the variance by about 3 %.
        assert!((var_x / 1.44 - 1.0).abs() < 0.04, "{var_x}");
    }
}
