//! Order statistics of timing samples, shared by the benchmarks, the daemon's status and the
//! replay client's report.

/// Sorts `v` and returns its `p`-quantiles for each `p` of `ps` (the sample at rank
/// `round((n - 1) p)`); 0 for an empty sample.
pub fn quantiles<const N: usize>(v: &mut [f64], ps: [f64; N]) -> [f64; N] {
    v.sort_by(f64::total_cmp);
    ps.map(|p| {
        v.get(((v.len().max(1) - 1) as f64 * p).round() as usize)
            .copied()
            .unwrap_or(0.0)
    })
}

#[cfg(test)]
mod tests {
    #[test]
    fn nearest_rank_quantiles() {
        let mut v = vec![5.0, 1.0, 3.0, 2.0, 4.0];
        assert_eq!(super::quantiles(&mut v, [0.0, 0.5, 1.0]), [1.0, 3.0, 5.0]);
        assert_eq!(super::quantiles(&mut [], [0.5]), [0.0]);
    }
}
