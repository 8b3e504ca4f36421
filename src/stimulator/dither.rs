//! Quantisation of fractional screen codes to the screen's DN levels, optionally dithered so
//! that the *mean* F_eff over a region is right to a fraction of one level (a uniform region
//! between two levels otherwise shows the nearer level everywhere: up to half a level of bias).

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
