//! Quantisation of fractional screen codes to the screen's DN levels, optionally dithered so
//! that the *mean* F_eff over a region is right to a fraction of one level (a uniform region
//! between two levels otherwise shows the nearer level everywhere: up to half a level of bias).
//!
//! Two threshold patterns: the 8 x 8 Bayer matrix (ordered), and a 64 x 64 blue-noise rank
//! matrix made by Ulichney's void-and-cluster method (1993), whose error has no low
//! frequencies and no visible grid, at the cost of exact means only over 64 x 64 tiles.

/// How a fractional code becomes an integer DN.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Dither {
    /// Round to the nearest level.
    #[default]
    None,
    /// 8 x 8 Bayer ordered dither: over any aligned 8 x 8 block the mean code is the input's to
    /// 1/64 of a level.
    Ordered,
    /// 64 x 64 blue-noise dither ([`blue_noise`]): over any aligned 64 x 64 tile the mean code
    /// is the input's to 1/4096 of a level.
    BlueNoise,
}

/// The blue-noise tile's side [px].
pub const BLUE_NOISE_SIDE: usize = 64;

/// The 64 x 64 blue-noise rank matrix (a permutation of 0..4096, row-major), made once by
/// void-and-cluster with a Gaussian filter of sigma 1.5 px on the torus, from a seeded start:
/// the same on every run and machine.
pub fn blue_noise() -> &'static [u16] {
    static RANKS: std::sync::OnceLock<Vec<u16>> = std::sync::OnceLock::new();
    RANKS.get_or_init(|| void_and_cluster(BLUE_NOISE_SIDE, 1.5, 0x0b5e_55ed))
}

/// Ulichney's void-and-cluster ranks for an `n x n` torus.
fn void_and_cluster(n: usize, sigma: f64, seed: u64) -> Vec<u16> {
    let len = n * n;
    // The filter by toroidal offset.
    let filter: Vec<f64> = (0..len)
        .map(|k| {
            let (dx, dy) = (k % n, k / n);
            let (dx, dy) = (dx.min(n - dx) as f64, dy.min(n - dy) as f64);
            (-(dx * dx + dy * dy) / (2.0 * sigma * sigma)).exp()
        })
        .collect();
    let toggle = |energy: &mut [f64], p: usize, sign: f64| {
        let (px, py) = (p % n, p / n);
        for (q, e) in energy.iter_mut().enumerate() {
            let (dx, dy) = ((q % n + n - px) % n, (q / n + n - py) % n);
            *e += sign * filter[dy * n + dx];
        }
    };
    let extreme = |energy: &[f64], ones: &[bool], want: bool, max: bool| {
        let mut best = None::<(usize, f64)>;
        for (p, (&e, &o)) in energy.iter().zip(ones).enumerate() {
            if o == want && best.is_none_or(|(_, b)| if max { e > b } else { e < b }) {
                best = Some((p, e));
            }
        }
        best.map(|b| b.0)
    };
    // A seeded initial pattern of about a tenth ones (splitmix64).
    let mut state = seed;
    let mut rnd = || {
        state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    };
    let mut ones = vec![false; len];
    let mut energy = vec![0.0; len];
    let mut count = 0;
    while count < len / 10 {
        let p = (rnd() % len as u64) as usize;
        if !ones[p] {
            ones[p] = true;
            toggle(&mut energy, p, 1.0);
            count += 1;
        }
    }
    // Spread it: move the tightest cluster's one into the largest void until that is itself.
    loop {
        let c = extreme(&energy, &ones, true, true).expect("has ones");
        ones[c] = false;
        toggle(&mut energy, c, -1.0);
        let v = extreme(&energy, &ones, false, false).expect("has zeros");
        ones[v] = true;
        toggle(&mut energy, v, 1.0);
        if v == c {
            break;
        }
    }
    let mut rank = vec![0u16; len];
    // Phase 1: the prototype's ones, tightest cluster first, get the ranks below `count`.
    let (mut p1_ones, mut p1_energy) = (ones.clone(), energy.clone());
    for r in (0..count).rev() {
        let c = extreme(&p1_energy, &p1_ones, true, true).expect("has ones");
        p1_ones[c] = false;
        toggle(&mut p1_energy, c, -1.0);
        rank[c] = r as u16;
    }
    // Phases 2 and 3: the largest void is filled next.
    for r in count..len {
        let v = extreme(&energy, &ones, false, false).expect("has zeros");
        ones[v] = true;
        toggle(&mut energy, v, 1.0);
        rank[v] = r as u16;
    }
    rank
}

/// The 8 x 8 Bayer index matrix.
const BAYER8: [[u8; 8]; 8] = [
    [0, 32, 8, 40, 2, 34, 10, 42],
    [48, 16, 56, 24, 50, 18, 58, 26],
    [12, 44, 4, 36, 14, 46, 6, 38],
    [60, 28, 52, 20, 62, 30, 54, 22],
    [3, 35, 11, 43, 1, 33, 9, 41],
    [51, 19, 59, 27, 49, 17, 57, 25],
    [15, 47, 7, 39, 13, 45, 5, 37],
    [63, 31, 55, 23, 61, 29, 53, 21],
];

impl Dither {
    /// The integer level for fractional code `x` at pixel `(i, j)`.
    #[inline(always)]
    pub fn quantise(&self, x: f64, i: usize, j: usize) -> f64 {
        match self {
            Dither::None => (x + 0.5).floor(),
            Dither::Ordered => {
                let t = (BAYER8[j & 7][i & 7] as f64 + 0.5) / 64.0;
                (x + t).floor()
            }
            Dither::BlueNoise => {
                let n = BLUE_NOISE_SIDE;
                let r = blue_noise()[(j % n) * n + i % n];
                (x + (r as f64 + 0.5) / (n * n) as f64).floor()
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bayer_matrix_is_a_permutation() {
        let mut seen = [false; 64];
        for row in BAYER8 {
            for v in row {
                assert!(!seen[v as usize]);
                seen[v as usize] = true;
            }
        }
    }

    #[test]
    fn blue_noise_is_a_permutation_without_low_frequencies() {
        let r = blue_noise();
        let n = BLUE_NOISE_SIDE;
        let mut seen = vec![false; n * n];
        for &v in r {
            assert!(!seen[v as usize]);
            seen[v as usize] = true;
        }
        // Blue noise: the thresholds of any 8 x 8 block average near the middle (white noise
        // of 64 samples would stray by ~0.036 of the range; clumps much more).
        let mut worst = 0.0f64;
        for by in 0..n / 8 {
            for bx in 0..n / 8 {
                let mut s = 0.0;
                for y in 0..8 {
                    for x in 0..8 {
                        s += r[(by * 8 + y) * n + bx * 8 + x] as f64;
                    }
                }
                worst = worst.max((s / 64.0 / (n * n) as f64 - 0.5).abs());
            }
        }
        assert!(
            worst < 0.06,
            "an 8 x 8 block's mean threshold strays by {worst}"
        );
        // The same matrix every time.
        assert_eq!(void_and_cluster(n, 1.5, 0x0b5e_55ed), r);
    }

    #[test]
    fn ordered_dither_keeps_the_block_mean() {
        for k in 0..=100 {
            let x = 10.0 + k as f64 / 100.0;
            let mut s = 0.0;
            for j in 0..8 {
                for i in 0..8 {
                    s += Dither::Ordered.quantise(x, i, j);
                }
            }
            assert!(
                (s / 64.0 - x).abs() <= 1.0 / 128.0 + 1e-12,
                "{x}: {}",
                s / 64.0
            );
        }
    }
}
