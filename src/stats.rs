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

/// [`quantiles`] without the sort: each rank selected in turn (`ps` ascending), `v` left
/// partly ordered. The same values, in linear time.
pub fn selected_quantiles<const N: usize>(v: &mut [f64], ps: [f64; N]) -> [f64; N] {
    if v.is_empty() {
        return [0.0; N];
    }
    let mut from = 0;
    ps.map(|p| {
        let k = ((v.len() - 1) as f64 * p).round() as usize;
        if k < from {
            // Ranks asked out of order: the prefix is partitioned, not sorted.
            v[..from].sort_by(f64::total_cmp);
            return v[k];
        }
        let (_, x, _) = v[from..].select_nth_unstable_by(k - from, f64::total_cmp);
        let x = *x;
        from = k;
        x
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

    #[test]
    fn selected_quantiles_are_the_sorted_ones() {
        let mut seed = 7u64;
        let v: Vec<f64> = (0..1001)
            .map(|_| {
                seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1);
                (seed >> 11) as f64
            })
            .collect();
        let ps = [0.0, 0.01, 0.5, 0.5, 0.99, 1.0];
        let a = super::quantiles(&mut v.clone(), ps);
        assert_eq!(super::selected_quantiles(&mut v.clone(), ps), a);
        assert_eq!(super::selected_quantiles(&mut [], [0.5]), [0.0]);
    }
}
