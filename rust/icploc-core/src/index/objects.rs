//! The map's objects: its points linked into connected pieces (points in the same or
//! adjacent cells of a grid of `link` metres), each labelled, with its size (the diagonal
//! of its bounding box). The see-through check of `icp()` tells a beam through a small
//! mapped object that the scan does not see at all (a parked car that has left since
//! mapping, a moved cabinet) from a beam through a wall; "small" is at most
//! `IcpConfig::vanished_object_size` (cars, furniture, pillars — not the building's walls:
//! a wall piece between two doors of a corridor is a few metres long, but joined to the
//! walls of its room).

/// The map's connected pieces.
#[derive(Clone, Debug)]
pub struct Objects {
    /// the piece of every map point
    label: Vec<u32>,
    /// the bounding-box diagonal of piece k (m)
    size: Vec<f64>,
}

impl Objects {
    /// Link `points` into pieces: two points are in one piece when a chain of points in
    /// the same or adjacent (8-neighbour) cells of `link` metres joins them (so points
    /// within `link` always are, points up to 2√2 `link` apart may be).
    pub fn build(points: &[[f64; 2]], link: f64) -> Self {
        let n = points.len();
        let mut cells: Vec<(i64, i64, u32)> = points
            .iter()
            .enumerate()
            .map(|(i, p)| {
                (
                    (p[0] / link).floor() as i64,
                    (p[1] / link).floor() as i64,
                    i as u32,
                )
            })
            .collect();
        cells.sort_unstable();
        // distinct cells, and the cell of every point
        let mut keys: Vec<(i64, i64)> = Vec::new();
        let mut cell_of = vec![0u32; n];
        for &(cx, cy, i) in &cells {
            if keys.last() != Some(&(cx, cy)) {
                keys.push((cx, cy));
            }
            cell_of[i as usize] = (keys.len() - 1) as u32;
        }
        drop(cells);
        let mut parent: Vec<u32> = (0..keys.len() as u32).collect();
        fn root(parent: &mut [u32], mut a: u32) -> u32 {
            while parent[a as usize] != a {
                let up = parent[parent[a as usize] as usize];
                parent[a as usize] = up;
                a = up;
            }
            a
        }
        for (k, &(cx, cy)) in keys.iter().enumerate() {
            for (dx, dy) in [(0, 1), (1, -1), (1, 0), (1, 1)] {
                if let Ok(m) = keys.binary_search(&(cx + dx, cy + dy)) {
                    let (a, b) = (root(&mut parent, k as u32), root(&mut parent, m as u32));
                    if a != b {
                        parent[a.max(b) as usize] = a.min(b);
                    }
                }
            }
        }
        // compact labels, and each piece's bounding box
        let mut compact = vec![u32::MAX; keys.len()];
        let mut boxes: Vec<[f64; 4]> = Vec::new();
        let mut label = vec![0u32; n];
        for (i, p) in points.iter().enumerate() {
            let r = root(&mut parent, cell_of[i]) as usize;
            if compact[r] == u32::MAX {
                compact[r] = boxes.len() as u32;
                boxes.push([p[0], p[1], p[0], p[1]]);
            }
            let l = compact[r];
            let b = &mut boxes[l as usize];
            b[0] = b[0].min(p[0]);
            b[1] = b[1].min(p[1]);
            b[2] = b[2].max(p[0]);
            b[3] = b[3].max(p[1]);
            label[i] = l;
        }
        let size = boxes
            .iter()
            .map(|b| (b[2] - b[0]).hypot(b[3] - b[1]))
            .collect();
        Self { label, size }
    }

    /// The piece of map point `j`.
    #[inline]
    pub fn label(&self, j: usize) -> u32 {
        self.label[j]
    }

    /// The size (bounding-box diagonal, m) of the piece map point `j` is on.
    #[inline]
    pub fn size(&self, j: usize) -> f64 {
        self.size[self.label[j] as usize]
    }

    /// Is map point `j` on a piece of at most `limit` m (bounding-box diagonal)?
    #[inline]
    pub fn is_small(&self, j: usize, limit: f64) -> bool {
        self.size(j) <= limit
    }

    /// Number of pieces.
    pub fn count(&self) -> usize {
        self.size.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    /// the default limit of a small object (`IcpConfig::default().vanished_object_size`)
    const CAR: f64 = 6.0;

    fn segment(a: [f64; 2], b: [f64; 2], step: f64) -> Vec<[f64; 2]> {
        let len = (b[0] - a[0]).hypot(b[1] - a[1]);
        let k = (len / step).ceil() as usize;
        (0..=k)
            .map(|i| {
                let t = i as f64 / k as f64;
                [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]
            })
            .collect()
    }

    #[test]
    fn a_car_is_a_small_piece_and_the_wall_behind_it_is_not() {
        let mut pts = segment([0.0, 0.0], [20.0, 0.0], 0.025);
        let wall = pts.len();
        for (a, b) in [
            ([5.0, 1.0], [6.8, 1.0]),
            ([6.8, 1.0], [6.8, 5.6]),
            ([6.8, 5.6], [5.0, 5.6]),
            ([5.0, 5.6], [5.0, 1.0]),
        ] {
            pts.extend(segment(a, b, 0.025));
        }
        let o = Objects::build(&pts, 0.05);
        assert_eq!(o.count(), 2);
        assert!(!o.is_small(0, CAR));
        assert!(!o.is_small(wall - 1, CAR));
        assert!((wall..pts.len()).all(|j| o.is_small(j, CAR) && o.label(j) == o.label(wall)));
        assert_ne!(o.label(0), o.label(wall));
    }

    #[test]
    fn a_gap_wider_than_the_link_splits_a_wall() {
        let mut pts = segment([0.0, 0.0], [3.0, 0.0], 0.025);
        pts.extend(segment([3.2, 0.0], [10.0, 0.0], 0.025));
        let o = Objects::build(&pts, 0.05);
        assert_eq!(o.count(), 2);
        assert!(o.is_small(0, CAR));
        assert!(!o.is_small(pts.len() - 1, CAR));
    }
}
