//! Run-length coding of `u32` sequences: the closest-point grid's cells hold long runs of
//! one map point (its Voronoi cell crossed by a row), so a saved grid is a few percent of
//! its size in memory.

use std::sync::OnceLock;

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

/// The number of values [`encode`]'s runs hold; an error when the two lists differ in
/// length, a run is empty or the runs add up to more than `max_len` values.
pub fn total(values: &[u32], lengths: &[u32], max_len: usize) -> Result<usize, String> {
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
    Ok(total)
}

/// The sequence of [`encode`]'s runs; the errors of [`total`].
pub fn decode(values: &[u32], lengths: &[u32], max_len: usize) -> Result<Vec<u32>, String> {
    let total = total(values, lengths, max_len)?;
    let mut out = Vec::with_capacity(total);
    for (&v, &n) in values.iter().zip(lengths) {
        out.resize(out.len() + n as usize, v);
    }
    Ok(out)
}

/// Values per block of a [`Lazy`] sequence (64 KB of `u32`).
const BLOCK_SHIFT: u32 = 14;
const BLOCK: usize = 1 << BLOCK_SHIFT;

/// A run-length coded sequence decoded block by block on first read: a saved closest-point
/// grid is tens of MB of cells, of which a replay reads the parts its scans fall in, so a
/// process does not pay for writing (and page-faulting) the rest. Reads are thread-safe;
/// a value reads the same as from [`decode`].
pub struct Lazy {
    values: Vec<u32>,
    /// where each run ends (exclusive), in values (`u32`: a grid has at most
    /// `MAX_CACHE_CELLS` cells; [`Lazy::new`] refuses more than `u32::MAX` values)
    ends: Vec<u32>,
    blocks: Vec<OnceLock<Box<[u32]>>>,
    len: usize,
}

impl Lazy {
    /// The runs as a lazily decoded sequence; the errors of [`total`].
    pub fn new(values: Vec<u32>, lengths: &[u32], max_len: usize) -> Result<Self, String> {
        let len = total(&values, lengths, max_len.min(u32::MAX as usize))?;
        let mut end = 0u32;
        let ends = lengths
            .iter()
            .map(|&n| {
                end += n;
                end
            })
            .collect();
        let blocks = (0..len.div_ceil(BLOCK)).map(|_| OnceLock::new()).collect();
        Ok(Self {
            values,
            ends,
            blocks,
            len,
        })
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The distinct values of the runs (each run's value once, in order).
    pub fn run_values(&self) -> &[u32] {
        &self.values
    }

    /// Where run `r` starts, in values.
    pub fn run_start(&self, r: usize) -> usize {
        if r == 0 {
            0
        } else {
            self.ends[r - 1] as usize
        }
    }

    /// Value `i` (panics beyond [`Lazy::len`], as a slice does).
    #[inline(always)]
    pub fn get(&self, i: usize) -> u32 {
        self.block(i >> BLOCK_SHIFT)[i & (BLOCK - 1)]
    }

    fn block(&self, b: usize) -> &[u32] {
        self.blocks[b].get_or_init(|| {
            let (start, end) = (b * BLOCK, ((b + 1) * BLOCK).min(self.len));
            let mut out = Vec::with_capacity(end - start);
            let mut r = self.ends.partition_point(|&e| (e as usize) <= start);
            let mut pos = start;
            while pos < end {
                let stop = (self.ends[r] as usize).min(end);
                out.resize(out.len() + (stop - pos), self.values[r]);
                pos = stop;
                r += 1;
            }
            out.into_boxed_slice()
        })
    }

    /// The whole sequence ([`decode`]'s result).
    pub fn to_vec(&self) -> Vec<u32> {
        (0..self.blocks.len())
            .flat_map(|b| self.block(b).iter().copied())
            .collect()
    }

    /// Heap bytes held now (the runs and the blocks decoded so far).
    pub fn bytes(&self) -> usize {
        let decoded: usize = self
            .blocks
            .iter()
            .filter_map(|b| b.get().map(|v| v.len()))
            .sum();
        (self.values.len() + decoded) * std::mem::size_of::<u32>()
            + self.ends.len() * std::mem::size_of::<u32>()
    }
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

    #[test]
    fn lazy_runs_read_as_the_decoded_sequence_across_block_borders() {
        let cells: Vec<u32> = (0..3 * BLOCK + 77).map(|i| (i / 1000) as u32).collect();
        let (v, n) = encode(&cells);
        let lazy = Lazy::new(v, &n, usize::MAX).unwrap();
        assert_eq!(lazy.len(), cells.len());
        assert!(Lazy::new(vec![1, 2], &[u32::MAX, 1], usize::MAX).is_err());
        for i in [0, BLOCK - 1, BLOCK, 2 * BLOCK + 5, cells.len() - 1] {
            assert_eq!(lazy.get(i), cells[i], "value {i}");
        }
        assert_eq!(lazy.to_vec(), cells);
    }

    #[test]
    fn lazy_runs_refuse_what_decode_refuses() {
        assert!(Lazy::new(vec![1], &[0], 10).is_err());
        assert!(Lazy::new(vec![1, 2], &[6, 5], 10).is_err());
    }

    proptest! {
        #[test]
        fn prop_lazy_reads_as_decode(cells in proptest::collection::vec(0u32..3, 0..3 * BLOCK)) {
            let (v, n) = encode(&cells);
            let lazy = Lazy::new(v, &n, usize::MAX).unwrap();
            prop_assert_eq!(lazy.to_vec(), cells);
        }

        #[test]
        fn prop_decode_inverts_encode(cells in proptest::collection::vec(0u32..4, 0..300)) {
            let (v, n) = encode(&cells);
            prop_assert_eq!(decode(&v, &n, cells.len()).unwrap(), cells);
        }
    }
}
