//! Run-length coding of `u32` sequences: the closest-point grid's cells hold long runs of
//! one map point (its Voronoi cell crossed by a row), so a saved grid is a few percent of
//! its size in memory.

/// `(values, lengths)`: `cells` as runs of equal values (every length ≥ 1).
pub fn encode(cells: &[u32]) -> (Vec<u32>, Vec<u32>) {
    let (mut values, mut lengths) = (Vec::new(), Vec::new());
    let mut it = cells.iter();
    let Some(&first) = it.next() else {
        return (values, lengths);
    };
    let (mut v, mut n) = (first, 1u32);
    for &c in it {
        if c == v && n < u32::MAX {
            n += 1;
        } else {
            values.push(v);
            lengths.push(n);
            (v, n) = (c, 1);
        }
    }
    values.push(v);
    lengths.push(n);
    (values, lengths)
}

/// The sequence of [`encode`]'s runs; an error when the two lists differ in length, a run
/// is empty or the runs add up to more than `max_len` values.
pub fn decode(values: &[u32], lengths: &[u32], max_len: usize) -> Result<Vec<u32>, String> {
    if values.len() != lengths.len() {
        return Err(format!(
            "{} run values for {} run lengths",
            values.len(),
            lengths.len()
        ));
    }
    let mut total = 0usize;
    for (i, &n) in lengths.iter().enumerate() {
        if n == 0 {
            return Err(format!("run {i} is empty"));
        }
        total = total.saturating_add(n as usize);
        if total > max_len {
            return Err(format!("the runs hold more than {max_len} values"));
        }
    }
    let mut out = Vec::with_capacity(total);
    for (&v, &n) in values.iter().zip(lengths) {
        out.resize(out.len() + n as usize, v);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn runs_of_a_grid_row() {
        let (v, n) = encode(&[7, 7, 7, u32::MAX, u32::MAX, 2, 7]);
        assert_eq!(v, vec![7, u32::MAX, 2, 7]);
        assert_eq!(n, vec![3, 2, 1, 1]);
        assert_eq!(encode(&[]), (vec![], vec![]));
    }

    #[test]
    fn bad_runs_are_refused() {
        assert!(decode(&[1, 2], &[3], 10)
            .unwrap_err()
            .contains("2 run values"));
        assert!(decode(&[1], &[0], 10).unwrap_err().contains("empty"));
        assert!(decode(&[1, 2], &[6, 5], 10)
            .unwrap_err()
            .contains("more than 10"));
    }

    proptest! {
        #[test]
        fn prop_decode_inverts_encode(cells in proptest::collection::vec(0u32..4, 0..300)) {
            let (v, n) = encode(&cells);
            prop_assert_eq!(decode(&v, &n, cells.len()).unwrap(), cells);
        }
    }
}
