//! The closest-point grid behind [`MapIndex::correspondence`](super::MapIndex::correspondence):
//! per cell, the map point closest to the cell's centre (a "closest point transform").
//!
//! The grid is sparse: square tiles of `TILE`² cells exist within `reach` (plus two cells)
//! of a map point and in the gaps of up to `GAP_FILL` tiles between those along rows and
//! columns (the free space of a building). When they cover at least half of their bounding
//! box the whole box is taken (a query finds its tile by arithmetic); otherwise a directory
//! maps tile coordinates to tiles (a dense array over the box up to 2²⁰ entries, else an
//! open-addressing hash). A stray point kilometres from the building therefore costs a few
//! tiles around itself, not a coarser grid everywhere. Cells are filled by seeding every point exactly into the
//! 3 × 3 cells around its own and propagating seeds in two raster passes over the tiles
//! (a vector distance transform).
//!
//! Tolerance (checked against brute force in the tests). A cell holds a point at most
//! `CELL_ERROR·res` farther from its centre than the nearest one: the seeds are exact on
//! the 3 × 3 cells around each point, and beyond them the two-pass 8-neighbour propagation
//! misses the nearest point only where its Voronoi cell is not 8-connected on the grid, by
//! a fraction of a cell: measured ≤ 0.09·res over 400 random point clusters and ≤ 0.144·res
//! over 3,000 random maps of three walls (at 2–13 cm cells, 1–7 cm wall sampling); the
//! bound used, and asserted by the property tests, is `CELL_ERROR` = 0.25. Hence, for a
//! query `q` whose exact nearest point `p*` is within `reach`, the cell answer `a` has
//! `|q − a| ≤ |q − p*| + (√2 + CELL_ERROR)·res` (√2·res from answering for the cell centre
//! instead of `q`). Farther queries get a map point farther than `reach` (a real point, so
//! at least as far as `p*`), or no answer where there is no tile (the index then asks the
//! k-d tree).

use std::borrow::Cow;
use std::collections::HashSet;

use super::{hugepages, runs};

/// Version of the cells' computation and storage order: saved cells are valid only for
/// the version that made them (bump on any change to either).
pub const FILL_VERSION: u32 = 1;
/// A grid of tiles whose bounding box has at most this many times the most tiles a grid
/// may have is filled as one box ([`fill_box`]: much faster), then copied into its tiles.
const BOX_FILL_TILES: u64 = 2;
/// Cells per tile side (a power of two).
const TILE_SHIFT: u32 = 5;
const TILE: usize = 1 << TILE_SHIFT;
const TILE_CELLS: usize = TILE * TILE;
const NONE: u32 = u32::MAX;
/// A dense tile directory is used up to this many entries (4 MB).
const DENSE_DIRECTORY: u64 = 1 << 20;
/// Gaps of up to this many tiles between tiles of a row (or column) are filled.
const GAP_FILL: u64 = 16;
/// Bound of a cell's error, in cells: see the module documentation.
pub(super) const CELL_ERROR: f64 = 0.25;
/// Cell coordinates (from the grid origin) stay below this, so tile coordinates fit 31 bits.
const MAX_CELL_COORD: u64 = 1 << 36;
/// |q / res| must stay below this for the cell's integer coordinate to be computed.
const MAX_CELL_QUOTIENT: f64 = (1u64 << 60) as f64;

/// ⌊x⌋ for |x| < 2⁶⁰ (a truncation and a fix-up: cheaper than `f64::floor` on baseline x86-64).
#[inline(always)]
fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    t - i64::from((t as f64) > x)
}

/// ⌊x⌋ of a cell coordinate the caller has checked to lie in [0, `MAX_CELL_COORD`): one
/// truncating instruction on x86-64 (a saturating cast `as i64` adds the tests of its
/// saturation, which such values never reach).
#[inline(always)]
fn trunc(x: f64) -> u64 {
    debug_assert!((0.0..MAX_CELL_COORD as f64).contains(&x));
    // SAFETY: `x` is finite and in [0, 2³⁶), so it truncates to a representable i64
    // (the callers test it first: `fx >= 0.0 && fx < MAX_CELL_COORD as f64`, false for NaN)
    unsafe { x.to_int_unchecked::<i64>() as u64 }
}

/// Why a grid was not built at the requested resolution.
#[derive(Debug, Clone, PartialEq)]
pub(super) enum Unbuilt {
    /// It would need more than `max_cells` cells (`needed` is a lower bound when the count
    /// was stopped early).
    TooManyCells { needed: usize, max_cells: usize },
    /// The map spans more cells than the grid can address.
    TooWide { span: f64 },
}

impl std::fmt::Display for Unbuilt {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Unbuilt::TooManyCells { needed, max_cells } => write!(
                f,
                "the grid would need at least {needed} cells ({} MB), more than the \
                 {max_cells}-cell ({} MB) bound",
                needed * 4 / (1 << 20),
                max_cells * 4 / (1 << 20)
            ),
            Unbuilt::TooWide { span } => write!(
                f,
                "the map spans {span:.3e} m, more than the grid can address at this resolution"
            ),
        }
    }
}

pub(super) struct ClosestGrid {
    /// cell (i, j) of the grid is the square [(i + bx)·res, (i + bx + 1)·res) ×
    /// [(j + by)·res, …): its lattice is anchored at the world origin and the tiles at
    /// multiples of TILE cells, so the cells over one part of a map do not depend on where
    /// its other parts are
    bx: i64,
    by: i64,
    res: f64,
    /// 1 / res (queries multiply: a cell off by one rounding at a border is as good)
    inv_res: f64,
    /// tile key → tile slot
    dir: Directory,
    /// with a full box: (first cell x, first cell y, width, height) in cells, and `cells`
    /// is then row-major over the box (a query is one multiply-add, as in a plain grid)
    full: Option<[u64; 4]>,
    /// TILE_CELLS map indices per tile, tiles in row-major order of their coordinates
    /// (empty when `lazy` holds them)
    cells: Vec<u32>,
    /// the cells of a saved grid, decoded block by block as queries reach them
    lazy: Option<runs::Lazy>,
}

/// Tile coordinates → tile slot: a dense array over the tiles' bounding box when that has at
/// most `DENSE_DIRECTORY` entries (one read per query), else an open-addressing hash (a map
/// in far-apart parts).
enum Directory {
    /// every tile of the box [tx0, tx0 + w) × [ty0, ty0 + h) exists, in row-major slots
    Full {
        tx0: u64,
        ty0: u64,
        w: u64,
        h: u64,
    },
    Dense {
        w: u64,
        h: u64,
        slots: Vec<u32>,
    },
    /// (tile key, slot), slot NONE marks an empty entry; `shift` = 64 − log2(len)
    Hash {
        table: Vec<(u64, u32)>,
        shift: u32,
    },
}

impl Directory {
    /// The directory of `keys` (sorted row-major); `full` when they are the whole box.
    fn new(keys: &[u64], full: Option<[u64; 4]>) -> Self {
        if let Some([tx0, ty0, w, h]) = full {
            return Directory::Full { tx0, ty0, w, h };
        }
        let w = keys.iter().map(|&t| t & 0xFFFF_FFFF).max().unwrap_or(0) + 1;
        let h = keys.last().map_or(0, |&t| t >> 32) + 1;
        if w.saturating_mul(h) <= DENSE_DIRECTORY {
            let mut slots = vec![NONE; (w * h) as usize];
            for (slot, &t) in keys.iter().enumerate() {
                slots[((t >> 32) * w + (t & 0xFFFF_FFFF)) as usize] = slot as u32;
            }
            return Directory::Dense { w, h, slots };
        }
        let cap = (2 * keys.len()).next_power_of_two().max(2);
        let shift = 64 - cap.trailing_zeros();
        let mut table = vec![(0u64, NONE); cap];
        for (slot, &t) in keys.iter().enumerate() {
            let mut i = hash_slot(t, shift);
            while table[i].1 != NONE {
                i = (i + 1) & (cap - 1);
            }
            table[i] = (t, slot as u32);
        }
        Directory::Hash { table, shift }
    }

    #[inline(always)]
    fn get(&self, tx: u64, ty: u64) -> Option<usize> {
        match self {
            Directory::Full { tx0, ty0, w, h } => {
                let (x, y) = (tx.wrapping_sub(*tx0), ty.wrapping_sub(*ty0));
                (x < *w && y < *h).then_some((y * w + x) as usize)
            }
            Directory::Dense { w, h, slots } => {
                if tx < *w && ty < *h {
                    let s = slots[(ty * w + tx) as usize];
                    (s != NONE).then_some(s as usize)
                } else {
                    None
                }
            }
            Directory::Hash { table, shift } => {
                let t = key(tx, ty);
                let mask = table.len() - 1;
                let mut i = hash_slot(t, *shift);
                loop {
                    let (k, s) = table[i];
                    if s == NONE {
                        return None;
                    }
                    if k == t {
                        return Some(s as usize);
                    }
                    i = (i + 1) & mask;
                }
            }
        }
    }

    fn bytes(&self) -> usize {
        match self {
            Directory::Full { .. } => 0,
            Directory::Dense { slots, .. } => slots.len() * std::mem::size_of::<u32>(),
            Directory::Hash { table, .. } => table.len() * std::mem::size_of::<(u64, u32)>(),
        }
    }
}

/// Tile key: row in the high 32 bits, so sorting keys sorts tiles row-major.
#[inline(always)]
fn key(tx: u64, ty: u64) -> u64 {
    (ty << 32) | tx
}

#[inline(always)]
fn hash_slot(k: u64, shift: u32) -> usize {
    (k.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> shift) as usize
}

impl ClosestGrid {
    /// Build the grid of cell size `res` over `points` (finite, |coordinate| bounded by the
    /// caller), covering every query within `reach` of a point, within `max_cells` cells.
    pub(super) fn build(
        points: &[[f64; 2]],
        bounds: [f64; 4],
        res: f64,
        reach: f64,
        max_cells: usize,
    ) -> Result<Self, Unbuilt> {
        Self::build_with(points, bounds, res, reach, max_cells, Fill::Compute)
            .map(|g| g.expect("computed cells always fit"))
    }

    /// The grid [`ClosestGrid::build`] makes, with the cells of an earlier build of the
    /// same points, resolution, reach and bound ([`ClosestGrid::cells`]) instead of
    /// computing them. The layout is computed from the points as in `build`; `Ok(Err(why))`
    /// when the cells do not fit it (another length, or an index that names no point).
    pub(super) fn with_cells(
        points: &[[f64; 2]],
        bounds: [f64; 4],
        res: f64,
        reach: f64,
        max_cells: usize,
        cells: Vec<u32>,
    ) -> Result<std::result::Result<Self, String>, Unbuilt> {
        Self::build_with(points, bounds, res, reach, max_cells, Fill::Given(cells))
    }

    /// The grid [`ClosestGrid::with_cells`] makes from the cells as [`runs::encode`]'s runs,
    /// decoded only where queries reach (`Ok(Err(why))` also for runs that do not decode).
    pub(super) fn with_runs(
        points: &[[f64; 2]],
        bounds: [f64; 4],
        res: f64,
        reach: f64,
        max_cells: usize,
        values: Vec<u32>,
        lengths: &[u32],
    ) -> Result<std::result::Result<Self, String>, Unbuilt> {
        let lazy = match runs::Lazy::new(values, lengths, max_cells) {
            Ok(l) => l,
            Err(why) => return Ok(Err(why)),
        };
        Self::build_with(points, bounds, res, reach, max_cells, Fill::Runs(lazy))
    }

    /// The cells (map point indices, `u32::MAX` for none) in storage order, for
    /// [`ClosestGrid::with_cells`].
    pub(super) fn cells(&self) -> Cow<'_, [u32]> {
        match &self.lazy {
            Some(l) => Cow::Owned(l.to_vec()),
            None => Cow::Borrowed(&self.cells),
        }
    }

    /// Cell `i` in storage order.
    #[inline(always)]
    fn cell_at(&self, i: usize) -> u32 {
        match &self.lazy {
            Some(l) => l.get(i),
            None => self.cells[i],
        }
    }

    fn cell_count(&self) -> usize {
        self.lazy.as_ref().map_or(self.cells.len(), |l| l.len())
    }

    /// [`ClosestGrid::build`] with the cells filled as `fill` says (`Ok(Err(why))`: given
    /// cells that do not fit the layout).
    fn build_with(
        points: &[[f64; 2]],
        bounds: [f64; 4],
        res: f64,
        reach: f64,
        max_cells: usize,
        fill: Fill,
    ) -> Result<std::result::Result<Self, String>, Unbuilt> {
        let max_tiles = max_cells / TILE_CELLS;
        let tile_w = TILE as f64 * res;
        // every query within `margin` (per axis) of a point falls in a tile at most `k`
        // tiles from the point's own
        let margin = reach + 2.0 * res;
        let kf = (margin / tile_w).ceil().max(1.0);
        let per_point = (2.0 * kf + 1.0).powi(2);
        if !(per_point <= max_tiles as f64) {
            return Err(Unbuilt::TooManyCells {
                needed: (per_point * TILE_CELLS as f64).min(usize::MAX as f64) as usize,
                max_cells,
            });
        }
        let k = kf as u64;
        let span = (bounds[2] - bounds[0]).max(bounds[3] - bounds[1]);
        let q = bounds.map(|b| b / res);
        if !q.iter().all(|v| v.abs() < MAX_CELL_QUOTIENT) {
            return Err(Unbuilt::TooWide { span });
        }
        let tile = TILE as i64;
        let pad = (k as i64 + 1) * tile;
        let bx = (floor_i64(q[0]).div_euclid(tile)) * tile - pad;
        let by = (floor_i64(q[1]).div_euclid(tile)) * tile - pad;
        if !((floor_i64(q[2]) - bx + pad) < MAX_CELL_COORD as i64
            && (floor_i64(q[3]) - by + pad) < MAX_CELL_COORD as i64)
        {
            return Err(Unbuilt::TooWide { span });
        }
        let cell_of = |p: [f64; 2]| -> (u64, u64) {
            (
                (floor_i64(p[0] / res) - bx) as u64,
                (floor_i64(p[1] / res) - by) as u64,
            )
        };

        // the tiles holding points, then every tile within k of those
        let mut own: HashSet<u64> = HashSet::new();
        let mut last = u64::MAX;
        for p in points {
            let (gx, gy) = cell_of(*p);
            let t = key(gx >> TILE_SHIFT, gy >> TILE_SHIFT);
            if t != last && own.insert(t) && own.len() > max_tiles {
                return Err(Unbuilt::TooManyCells {
                    needed: own.len() * TILE_CELLS,
                    max_cells,
                });
            }
            last = t;
        }
        // own.len() ≤ max_tiles and (2k + 1)² ≤ max_tiles were checked: this stays small
        let mut keys: Vec<u64> = Vec::with_capacity(own.len() * (2 * k as usize + 1).pow(2));
        for &t in &own {
            let (tx, ty) = (t & 0xFFFF_FFFF, t >> 32);
            for dy in 0..=2 * k {
                for dx in 0..=2 * k {
                    keys.push(key(tx + dx - k, ty + dy - k));
                }
            }
        }
        drop(own);
        keys.sort_unstable();
        keys.dedup();
        if keys.len() > max_tiles {
            return Err(Unbuilt::TooManyCells {
                needed: keys.len() * TILE_CELLS,
                max_cells,
            });
        }
        // fill gaps of up to GAP_FILL tiles along rows and columns: the free space inside a
        // building is covered (queries there stay O(1); the tree is slow far from dense
        // walls), far-apart parts stay apart
        for transpose in [false, true] {
            let flip = |t: u64| t.rotate_right(32);
            let mut line: Vec<u64> = if transpose {
                keys.iter().map(|&t| flip(t)).collect()
            } else {
                keys.clone()
            };
            line.sort_unstable();
            let mut extra = Vec::new();
            for w in line.windows(2) {
                let gap = w[1].wrapping_sub(w[0]);
                if w[0] >> 32 == w[1] >> 32 && gap > 1 && gap <= GAP_FILL + 1 {
                    extra.extend((w[0] + 1..w[1]).map(|t| if transpose { flip(t) } else { t }));
                }
            }
            keys.extend(extra);
            if keys.len() > max_tiles {
                return Err(Unbuilt::TooManyCells {
                    needed: keys.len() * TILE_CELLS,
                    max_cells,
                });
            }
        }
        keys.sort_unstable();
        keys.dedup();
        // when the tiles cover at least half of their bounding box, take the whole box: a
        // query then finds its tile by arithmetic, as in a plain grid (at most 2× the cells)
        let (tx0, tx1) = keys.iter().fold((u64::MAX, 0), |(a, b), &t| {
            (a.min(t & 0xFFFF_FFFF), b.max(t & 0xFFFF_FFFF))
        });
        let (ty0, ty1) = (keys[0] >> 32, keys[keys.len() - 1] >> 32);
        let (w, h) = (tx1 - tx0 + 1, ty1 - ty0 + 1);
        let full = (w.saturating_mul(h) <= max_tiles as u64 && w * h <= 2 * keys.len() as u64)
            .then_some([tx0, ty0, w, h]);
        if full.is_some() {
            keys = (ty0..=ty1)
                .flat_map(|ty| (tx0..=tx1).map(move |tx| key(tx, ty)))
                .collect();
        }

        let mut grid = Self {
            bx,
            by,
            res,
            inv_res: 1.0 / res,
            dir: Directory::new(&keys, full),
            full: None,
            cells: Vec::new(),
            lazy: None,
        };
        // the tiles' bounding box in cells
        let b = [
            tx0 * TILE as u64,
            ty0 * TILE as u64,
            w * TILE as u64,
            h * TILE as u64,
        ];
        // the cells a given layout must hold (every cell of the box, or of the tiles)
        let want = match full {
            Some(_) => (b[2] * b[3]) as usize,
            None => keys.len() * TILE_CELLS,
        };
        let tiled = match fill {
            Fill::Given(cells) => {
                if cells.len() != want {
                    return Ok(Err(format!(
                        "{} cells given, the layout has {want}",
                        cells.len()
                    )));
                }
                let n = points.len() as u32;
                if let Some(i) = cells.iter().position(|&j| j != NONE && j >= n) {
                    return Ok(Err(format!("cell {i} names point {} of {n}", cells[i])));
                }
                grid.cells = cells;
                hugepages::collapse(&mut grid.cells);
                grid.full = full.map(|_| b);
                return Ok(Ok(grid));
            }
            Fill::Runs(lazy) => {
                if lazy.len() != want {
                    return Ok(Err(format!(
                        "{} cells given, the layout has {want}",
                        lazy.len()
                    )));
                }
                let n = points.len() as u32;
                if let Some(r) = lazy.run_values().iter().position(|&j| j != NONE && j >= n) {
                    let (i, j) = (lazy.run_start(r), lazy.run_values()[r]);
                    return Ok(Err(format!("cell {i} names point {j} of {n}")));
                }
                grid.lazy = Some(lazy);
                grid.full = full.map(|_| b);
                return Ok(Ok(grid));
            }
            Fill::Compute => false,
            #[cfg(test)]
            Fill::Tiled => true,
        };
        match full {
            Some(_) if !tiled => {
                grid.cells = fill_box(points, bx, by, res, b, None);
                grid.full = Some(b);
            }
            // a box of at most `BOX_FILL_TILES` × `max_tiles` tiles (a transient 64 MB at
            // the default bound): filled as a box with the missing tiles left out, then
            // copied into tile-major slots
            None if !tiled && w * h <= BOX_FILL_TILES * max_tiles as u64 => {
                let mut exists = vec![false; (w * h) as usize];
                for &t in &keys {
                    exists[(((t >> 32) - ty0) * w + (t & 0xFFFF_FFFF) - tx0) as usize] = true;
                }
                let boxed = fill_box(points, bx, by, res, b, Some(&exists));
                let cw = w as usize * TILE;
                let mut cells = hugepages::filled(keys.len() * TILE_CELLS, NONE);
                for (tile, &t) in cells.chunks_exact_mut(TILE_CELLS).zip(&keys) {
                    let sx = ((t & 0xFFFF_FFFF) - tx0) as usize;
                    let sy = ((t >> 32) - ty0) as usize;
                    for ly in 0..TILE {
                        let src = (sy * TILE + ly) * cw + sx * TILE;
                        tile[ly * TILE..(ly + 1) * TILE].copy_from_slice(&boxed[src..src + TILE]);
                    }
                }
                grid.cells = cells;
            }
            _ => {
                grid.cells = hugepages::filled(keys.len() * TILE_CELLS, NONE);
                grid.fill(points, &keys);
                if let Some([tx0, ty0, w, h]) = full {
                    // tile-major → row-major over the box
                    let (cw, ch) = (w as usize * TILE, h as usize * TILE);
                    let mut rm = hugepages::filled(cw * ch, NONE);
                    for (s, tile) in grid.cells.chunks_exact(TILE_CELLS).enumerate() {
                        let (sx, sy) = (s % w as usize, s / w as usize);
                        for ly in 0..TILE {
                            let dst = (sy * TILE + ly) * cw + sx * TILE;
                            rm[dst..dst + TILE].copy_from_slice(&tile[ly * TILE..(ly + 1) * TILE]);
                        }
                    }
                    grid.cells = rm;
                    grid.full = Some([tx0 * TILE as u64, ty0 * TILE as u64, cw as u64, ch as u64]);
                }
            }
        }
        Ok(Ok(grid))
    }

    #[inline(always)]
    fn slot_of(&self, t: u64) -> Option<usize> {
        self.dir.get(t & 0xFFFF_FFFF, t >> 32)
    }

    /// The cell's map index for query `q`, if `q` falls in a filled cell.
    #[inline(always)]
    pub(super) fn lookup(&self, q: [f64; 2]) -> Option<usize> {
        // x − bx (bx an integer below 2⁵³) is exact or rounded only right at a cell border
        // (harmless: the neighbouring cell), so its truncation is ⌊x⌋ − bx
        let fx = q[0] * self.inv_res - self.bx as f64;
        let fy = q[1] * self.inv_res - self.by as f64;
        // also false for NaN
        if !(fx >= 0.0 && fy >= 0.0 && fx < MAX_CELL_COORD as f64 && fy < MAX_CELL_COORD as f64) {
            return None;
        }
        let (gx, gy) = (trunc(fx), trunc(fy));
        if let Some([x0, y0, w, h]) = self.full {
            let (x, y) = (gx.wrapping_sub(x0), gy.wrapping_sub(y0));
            if !(x < w && y < h) {
                return None;
            }
            let j = self.cell_at((y * w + x) as usize);
            return (j != NONE).then_some(j as usize);
        }
        let s = self.slot_of(key(gx >> TILE_SHIFT, gy >> TILE_SHIFT))?;
        let lx = (gx as usize) & (TILE - 1);
        let ly = (gy as usize) & (TILE - 1);
        let j = self.cell_at(s * TILE_CELLS + (ly << TILE_SHIFT) + lx);
        (j != NONE).then_some(j as usize)
    }

    /// [`ClosestGrid::lookup`] of each of `qs` into `out`'s second fields (`u32::MAX` for
    /// none): over a full box of cells in memory, the layout's tests once for all queries.
    #[inline]
    pub(super) fn lookup_into(&self, qs: &[[f64; 2]], out: &mut [(f64, u32)]) {
        match (self.full, &self.lazy) {
            (Some([x0, y0, w, h]), None) => {
                let cells = &self.cells[..];
                let (bx, by) = (self.bx as f64, self.by as f64);
                let max = MAX_CELL_COORD as f64;
                for (q, o) in qs.iter().zip(out.iter_mut()) {
                    let fx = q[0] * self.inv_res - bx;
                    let fy = q[1] * self.inv_res - by;
                    o.1 = NONE;
                    if fx >= 0.0 && fy >= 0.0 && fx < max && fy < max {
                        let x = trunc(fx).wrapping_sub(x0);
                        let y = trunc(fy).wrapping_sub(y0);
                        if x < w && y < h {
                            o.1 = cells[(y * w + x) as usize];
                        }
                    }
                }
            }
            _ => {
                for (q, o) in qs.iter().zip(out.iter_mut()) {
                    o.1 = self.lookup(*q).map_or(NONE, |j| j as u32);
                }
            }
        }
    }

    pub(super) fn resolution(&self) -> f64 {
        self.res
    }

    /// The cell (lx, ly) of tile slot `s`, whichever the layout.
    #[cfg(test)]
    fn cell(&self, s: usize, lx: usize, ly: usize) -> u32 {
        match self.full {
            Some([_, _, w, _]) => {
                let tw = w as usize / TILE;
                let (sx, sy) = (s % tw, s / tw);
                self.cell_at((sy * TILE + ly) * w as usize + sx * TILE + lx)
            }
            None => self.cell_at(s * TILE_CELLS + ly * TILE + lx),
        }
    }

    /// The tile keys in slot order.
    #[cfg(test)]
    fn keys(&self) -> Vec<u64> {
        let mut k = Vec::new();
        let t = self.tiles();
        // slots are dense 0..t: find each slot's key by scanning the directory
        match &self.dir {
            Directory::Full { tx0, ty0, w, h } => {
                for y in 0..*h {
                    for x in 0..*w {
                        k.push(key(tx0 + x, ty0 + y));
                    }
                }
            }
            Directory::Dense { w, slots, .. } => {
                k.resize(t, 0);
                for (i, &s) in slots.iter().enumerate() {
                    if s != NONE {
                        k[s as usize] = key(i as u64 % w, i as u64 / w);
                    }
                }
            }
            Directory::Hash { table, .. } => {
                k.resize(t, 0);
                for &(kk, s) in table {
                    if s != NONE {
                        k[s as usize] = kk;
                    }
                }
            }
        }
        k
    }

    /// Number of tiles.
    pub(super) fn tiles(&self) -> usize {
        self.cell_count() / TILE_CELLS
    }

    /// Heap bytes held (cells and hash table).
    pub(super) fn bytes(&self) -> usize {
        self.cells.len() * std::mem::size_of::<u32>()
            + self.lazy.as_ref().map_or(0, |l| l.bytes())
            + self.dir.bytes()
    }

    /// Seed and propagate. `keys` are the tile keys in slot order (sorted row-major).
    // the slot index addresses cells and neighbours, not only `origin`
    #[allow(clippy::needless_range_loop)]
    fn fill(&mut self, points: &[[f64; 2]], keys: &[u64]) {
        let nt = keys.len();
        // neighbour slots of every tile: index (dy + 1) * 3 + (dx + 1), 4 = itself
        let mut nbr = vec![[NONE; 9]; nt];
        for (s, &t) in keys.iter().enumerate() {
            let (tx, ty) = (t & 0xFFFF_FFFF, t >> 32);
            for dy in 0..3u64 {
                for dx in 0..3u64 {
                    // tiles at coordinate 0 have no lower neighbours (padding keeps points away)
                    if (tx == 0 && dx == 0) || (ty == 0 && dy == 0) {
                        continue;
                    }
                    if let Some(n) = self.slot_of(key(tx + dx - 1, ty + dy - 1)) {
                        nbr[s][(dy * 3 + dx) as usize] = n as u32;
                    }
                }
            }
        }
        let (bx, by, res) = (self.bx, self.by, self.res);
        let centre = |s: usize, lx: usize, ly: usize| -> [f64; 2] {
            let t = keys[s];
            let gx = (((t & 0xFFFF_FFFF) as usize) << TILE_SHIFT) + lx;
            let gy = (((t >> 32) as usize) << TILE_SHIFT) + ly;
            [
                ((gx as i64 + bx) as f64 + 0.5) * res,
                ((gy as i64 + by) as f64 + 0.5) * res,
            ]
        };
        // flat index of the cell (lx + dx, ly + dy) of tile s, through the neighbour table
        let at = |s: usize, lx: usize, ly: usize, dx: isize, dy: isize| -> Option<usize> {
            let nx = lx as isize + dx;
            let ny = ly as isize + dy;
            let (tdx, cx) = if nx < 0 {
                (0, TILE - 1)
            } else if nx >= TILE as isize {
                (2, 0)
            } else {
                (1, nx as usize)
            };
            let (tdy, cy) = if ny < 0 {
                (0, TILE - 1)
            } else if ny >= TILE as isize {
                (2, 0)
            } else {
                (1, ny as usize)
            };
            let n = if tdx == 1 && tdy == 1 {
                s
            } else {
                let n = nbr[s][tdy * 3 + tdx];
                if n == NONE {
                    return None;
                }
                n as usize
            };
            Some(n * TILE_CELLS + (cy << TILE_SHIFT) + cx)
        };
        let cells = &mut self.cells;
        let mut best = vec![f64::INFINITY; cells.len()];

        // centre of cell (0, 0) of every tile
        let origin: Vec<[f64; 2]> = (0..nt).map(|s| centre(s, 0, 0)).collect();
        // seeds: every point is tried exactly on the 3 × 3 cells around its own
        let mut last = (u64::MAX, 0usize);
        for (j, p) in points.iter().enumerate() {
            let gx = (floor_i64(p[0] / res) - bx) as u64;
            let gy = (floor_i64(p[1] / res) - by) as u64;
            let t = key(gx >> TILE_SHIFT, gy >> TILE_SHIFT);
            let s = if t == last.0 {
                last.1
            } else {
                // every point's own tile exists (it was inserted above)
                let Some(s) = self.dir.get(t & 0xFFFF_FFFF, t >> 32) else {
                    continue;
                };
                last = (t, s);
                s
            };
            let lx = (gx as usize) & (TILE - 1);
            let ly = (gy as usize) & (TILE - 1);
            if lx > 0 && ly > 0 && lx + 1 < TILE && ly + 1 < TILE {
                let [ox, oy] = origin[s];
                for dy in 0..3 {
                    let cy = oy + (ly + dy - 1) as f64 * res;
                    let row = s * TILE_CELLS + ((ly + dy - 1) << TILE_SHIFT);
                    for dx in 0..3 {
                        let c = row + lx + dx - 1;
                        let cx = ox + (lx + dx - 1) as f64 * res;
                        let d = dist2(points, j as u32, cx, cy);
                        if d < best[c] {
                            best[c] = d;
                            cells[c] = j as u32;
                        }
                    }
                }
                continue;
            }
            for dy in -1..=1isize {
                for dx in -1..=1isize {
                    if let Some(c) = at(s, lx, ly, dx, dy) {
                        let (cs, cl) = (c / TILE_CELLS, c % TILE_CELLS);
                        let [ox, oy] = origin[cs];
                        let q = [
                            ox + (cl & (TILE - 1)) as f64 * res,
                            oy + (cl >> TILE_SHIFT) as f64 * res,
                        ];
                        let d = dist2(points, j as u32, q[0], q[1]);
                        if d < best[c] {
                            best[c] = d;
                            cells[c] = j as u32;
                        }
                    }
                }
            }
        }

        // propagate: each cell takes a neighbour's seed when that seed is closer
        let mut relax = |c: usize, n: Option<usize>, q: [f64; 2]| {
            let Some(n) = n else { return };
            let s = cells[n];
            if s == NONE || s == cells[c] {
                return;
            }
            let d = dist2(points, s, q[0], q[1]);
            if d < best[c] {
                best[c] = d;
                cells[c] = s;
            }
        };
        // tile rows: runs of slots sharing a row coordinate
        let mut rows: Vec<(usize, usize)> = Vec::new();
        let mut a = 0;
        for s in 1..=nt {
            if s == nt || keys[s] >> 32 != keys[a] >> 32 {
                rows.push((a, s));
                a = s;
            }
        }
        sweep::<true>(&rows, &origin, res, &at, &mut relax);
        sweep::<false>(&rows, &origin, res, &at, &mut relax);
    }
}

/// One raster pass of [`ClosestGrid::fill`] over the tile rows `rows` (runs of slots
/// sharing a row coordinate). Forward (`FWD`): tile rows upwards; each cell row left to
/// right from the left neighbour and the three cells below, then right to left from the
/// right neighbour. Backward: the mirror image (tile rows downwards; right to left from
/// the right neighbour and the three cells above, then left to right from the left
/// neighbour). `at` finds a neighbour across tile borders; `relax(c, n, q)` lets cell `c`
/// (centre `q`) take the seed of cell `n`.
#[inline(always)]
fn sweep<const FWD: bool>(
    rows: &[(usize, usize)],
    origin: &[[f64; 2]],
    res: f64,
    at: &impl Fn(usize, usize, usize, isize, isize) -> Option<usize>,
    relax: &mut impl FnMut(usize, Option<usize>, [f64; 2]),
) {
    const T: usize = TILE;
    // the i-th of 0..n in ascending (`up`) or descending order
    let nth = |up: bool, i: usize, n: usize| if up { i } else { n - 1 - i };
    // the side the pass comes from: -1 (left, below) forward, +1 backward
    let d: isize = if FWD { -1 } else { 1 };
    for r in 0..rows.len() {
        let (a, b) = rows[nth(FWD, r, rows.len())];
        for l in 0..TILE {
            let ly = nth(FWD, l, TILE);
            for i in 0..b - a {
                let s = a + nth(FWD, i, b - a);
                let [ox, oy] = origin[s];
                let cy = oy + ly as f64 * res;
                let row = s * TILE_CELLS + (ly << TILE_SHIFT);
                for k in 0..TILE {
                    let lx = nth(FWD, k, TILE);
                    let c = row + lx;
                    let q = [ox + lx as f64 * res, cy];
                    if lx > 0 && ly > 0 && lx + 1 < TILE && ly + 1 < TILE {
                        let n = if FWD {
                            [c - 1, c - T - 1, c - T, c - T + 1]
                        } else {
                            [c + 1, c + T + 1, c + T, c + T - 1]
                        };
                        for n in n {
                            relax(c, Some(n), q);
                        }
                    } else {
                        relax(c, at(s, lx, ly, d, 0), q);
                        relax(c, at(s, lx, ly, d, d), q);
                        relax(c, at(s, lx, ly, 0, d), q);
                        relax(c, at(s, lx, ly, -d, d), q);
                    }
                }
            }
            // back along the cell row, from the neighbour on the other side
            for i in 0..b - a {
                let s = a + nth(!FWD, i, b - a);
                let [ox, oy] = origin[s];
                let cy = oy + ly as f64 * res;
                let row = s * TILE_CELLS + (ly << TILE_SHIFT);
                for k in 0..TILE {
                    let lx = nth(!FWD, k, TILE);
                    let c = row + lx;
                    let q = [ox + lx as f64 * res, cy];
                    let inside = if FWD { lx + 1 < TILE } else { lx > 0 };
                    let n = if !inside {
                        at(s, lx, ly, -d, 0)
                    } else if FWD {
                        Some(c + 1)
                    } else {
                        Some(c - 1)
                    };
                    relax(c, n, q);
                }
            }
        }
    }
}

/// How [`ClosestGrid::build_with`] fills the cells.
enum Fill {
    /// computed: a box of tiles at once ([`fill_box`]) when it is small enough, else tile by tile
    Compute,
    /// computed tile by tile ([`ClosestGrid::fill`]; the tests' reference for `fill_box`)
    #[cfg(test)]
    Tiled,
    /// given (an earlier build's cells)
    Given(Vec<u32>),
    /// given as runs, decoded on first use
    Runs(runs::Lazy),
}

/// Squared distance from map point `j` to (qx, qy), written as everywhere in this module
/// (the cells compare these values, so they must be the same expression).
#[inline(always)]
fn dist2(points: &[[f64; 2]], j: u32, qx: f64, qy: f64) -> f64 {
    let p = points[j as usize];
    (p[0] - qx) * (p[0] - qx) + (p[1] - qy) * (p[1] - qy)
}

/// One relaxation of [`ClosestGrid::fill`]: cell (qx, qy), holding `cur` at squared
/// distance `best` (NaN: not computed yet), takes the seed of cell `n` when that is closer.
#[inline(always)]
fn relax_cell(
    cells: &[u32],
    points: &[[f64; 2]],
    n: usize,
    cur: &mut u32,
    best: &mut f64,
    qx: f64,
    qy: f64,
) {
    let s = cells[n];
    if s == NONE || s == *cur {
        return;
    }
    if best.is_nan() {
        *best = if *cur == NONE {
            f64::INFINITY
        } else {
            dist2(points, *cur, qx, qy)
        };
    }
    let d = dist2(points, s, qx, qy);
    if d < *best {
        *best = d;
        *cur = s;
    }
}

/// [`ClosestGrid::fill`] for a grid that is its whole box `b` = (first cell x, first cell
/// y, width, height in cells; x and y multiples of `TILE`), straight into row-major cells.
///
/// The same cells bit for bit: in a full box every tile row spans the box, so the
/// tile-by-tile raster passes of `fill` are plain row scans over the box; the seeds are
/// tried in the same order, the relaxations too, and the cell centres are computed with
/// the same arithmetic (the tile's first centre plus the offset within the tile). What is
/// gone: the tile indirection at every tile border, the distance array (a cell's current
/// distance is recomputed from its point when a neighbour offers another: the same value)
/// and the copy from tile-major to row-major order.
// x and y address cells, neighbours and centres at once
#[allow(clippy::needless_range_loop)]
fn fill_box(
    points: &[[f64; 2]],
    bx: i64,
    by: i64,
    res: f64,
    b: [u64; 4],
    exists: Option<&[bool]>,
) -> Vec<u32> {
    let [x0, y0, w, h] = b;
    let (w, h) = (w as usize, h as usize);
    let tw = w / TILE;
    // does the tile of cell (x, y) exist (cells of missing tiles stay empty, as they are
    // absent in the tiled fill)
    let tile_ok =
        |x: usize, y: usize| exists.is_none_or(|e| e[(y >> TILE_SHIFT) * tw + (x >> TILE_SHIFT)]);
    let centres = |g0: u64, n: usize, base: i64| -> Vec<f64> {
        (0..n)
            .map(|i| {
                let g = g0 as usize + i;
                let tile0 = (g >> TILE_SHIFT) << TILE_SHIFT;
                ((tile0 as i64 + base) as f64 + 0.5) * res + (g & (TILE - 1)) as f64 * res
            })
            .collect()
    };
    let cx = centres(x0, w, bx);
    let cy = centres(y0, h, by);
    let mut cells = hugepages::filled(w * h, NONE);
    // seeds: every point is tried exactly on the 3 × 3 cells around its own
    for (j, p) in points.iter().enumerate() {
        let gx = (floor_i64(p[0] / res) - bx) as u64;
        let gy = (floor_i64(p[1] / res) - by) as u64;
        let (x, y) = (gx.wrapping_sub(x0) as usize, gy.wrapping_sub(y0) as usize);
        for dy in 0..3usize {
            let yy = (y + dy).wrapping_sub(1);
            if yy >= h {
                continue;
            }
            for dx in 0..3usize {
                let xx = (x + dx).wrapping_sub(1);
                if xx >= w || !tile_ok(xx, yy) {
                    continue;
                }
                let c = yy * w + xx;
                let (qx, qy) = (cx[xx], cy[yy]);
                let d = dist2(points, j as u32, qx, qy);
                let cur = cells[c];
                if cur == NONE || d < dist2(points, cur, qx, qy) {
                    cells[c] = j as u32;
                }
            }
        }
    }
    // the tile columns of row band `ty` that exist
    let band = |ty: usize| -> Vec<usize> {
        (0..tw)
            .filter(|&tx| exists.is_none_or(|e| e[ty * tw + tx]))
            .collect()
    };
    // forward: rows upwards; left to right from the row below, then right to left
    for ty in 0..h / TILE {
        let cols = band(ty);
        for y in ty * TILE..(ty + 1) * TILE {
            let qy = cy[y];
            let row = y * w;
            for &tx in &cols {
                for x in tx * TILE..(tx + 1) * TILE {
                    let c = row + x;
                    let qx = cx[x];
                    let (mut cur, mut best) = (cells[c], f64::NAN);
                    if x > 0 {
                        relax_cell(&cells, points, c - 1, &mut cur, &mut best, qx, qy);
                    }
                    if y > 0 {
                        if x > 0 {
                            relax_cell(&cells, points, c - w - 1, &mut cur, &mut best, qx, qy);
                        }
                        relax_cell(&cells, points, c - w, &mut cur, &mut best, qx, qy);
                        if x + 1 < w {
                            relax_cell(&cells, points, c - w + 1, &mut cur, &mut best, qx, qy);
                        }
                    }
                    cells[c] = cur;
                }
            }
            for &tx in cols.iter().rev() {
                for x in (tx * TILE..((tx + 1) * TILE).min(w - 1)).rev() {
                    let c = row + x;
                    let (mut cur, mut best) = (cells[c], f64::NAN);
                    relax_cell(&cells, points, c + 1, &mut cur, &mut best, cx[x], qy);
                    cells[c] = cur;
                }
            }
        }
    }
    // backward: rows downwards; right to left from the row above, then left to right
    for ty in (0..h / TILE).rev() {
        let cols = band(ty);
        for y in (ty * TILE..(ty + 1) * TILE).rev() {
            let qy = cy[y];
            let row = y * w;
            for &tx in cols.iter().rev() {
                for x in (tx * TILE..(tx + 1) * TILE).rev() {
                    let c = row + x;
                    let qx = cx[x];
                    let (mut cur, mut best) = (cells[c], f64::NAN);
                    if x + 1 < w {
                        relax_cell(&cells, points, c + 1, &mut cur, &mut best, qx, qy);
                    }
                    if y + 1 < h {
                        if x + 1 < w {
                            relax_cell(&cells, points, c + w + 1, &mut cur, &mut best, qx, qy);
                        }
                        relax_cell(&cells, points, c + w, &mut cur, &mut best, qx, qy);
                        if x > 0 {
                            relax_cell(&cells, points, c + w - 1, &mut cur, &mut best, qx, qy);
                        }
                    }
                    cells[c] = cur;
                }
            }
            for &tx in &cols {
                for x in (tx * TILE).max(1)..(tx + 1) * TILE {
                    let c = row + x;
                    let (mut cur, mut best) = (cells[c], f64::NAN);
                    relax_cell(&cells, points, c - 1, &mut cur, &mut best, cx[x], qy);
                    cells[c] = cur;
                }
            }
        }
    }
    cells
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn bounds(points: &[[f64; 2]]) -> [f64; 4] {
        points.iter().fold(
            [
                f64::INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::NEG_INFINITY,
            ],
            |b, p| {
                [
                    b[0].min(p[0]),
                    b[1].min(p[1]),
                    b[2].max(p[0]),
                    b[3].max(p[1]),
                ]
            },
        )
    }

    fn brute(points: &[[f64; 2]], q: [f64; 2]) -> f64 {
        points
            .iter()
            .map(|p| (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2))
            .fold(f64::INFINITY, f64::min)
    }

    /// Every filled cell whose nearest point is within reach holds a point at most
    /// CELL_ERROR·res farther from its centre than the brute-force nearest one (and most
    /// hold exactly that one). Returns (cells checked, cells holding exactly the nearest).
    fn check_cells(points: &[[f64; 2]], res: f64, reach: f64) -> (usize, usize) {
        let g = ClosestGrid::build(points, bounds(points), res, reach, 1 << 22).unwrap();
        let keys = g.keys();
        let (mut checked, mut exact_cells) = (0, 0);
        for (s, &t) in keys.iter().enumerate() {
            for ly in 0..TILE {
                for lx in 0..TILE {
                    let gx = (((t & 0xFFFF_FFFF) as usize) << TILE_SHIFT) + lx;
                    let gy = (((t >> 32) as usize) << TILE_SHIFT) + ly;
                    let c = [
                        ((gx as i64 + g.bx) as f64 + 0.5) * res,
                        ((gy as i64 + g.by) as f64 + 0.5) * res,
                    ];
                    let exact = brute(points, c);
                    if exact > reach * reach {
                        continue;
                    }
                    let j = g.cell(s, lx, ly);
                    assert_ne!(j, NONE, "cell {gx},{gy} within reach has no point");
                    // a query anywhere in the cell reads that cell (the look-up's
                    // arithmetic agrees with the storage order)
                    for f in [[0.5, 0.5], [0.01, 0.01], [0.99, 0.02], [0.03, 0.98]] {
                        let q = [
                            ((gx as i64 + g.bx) as f64 + f[0]) * res,
                            ((gy as i64 + g.by) as f64 + f[1]) * res,
                        ];
                        assert_eq!(
                            g.lookup(q),
                            Some(j as usize),
                            "query {q:?} in cell {gx},{gy}"
                        );
                    }
                    let p = points[j as usize];
                    let d = (p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2);
                    assert!(
                        d.sqrt() <= exact.sqrt() + CELL_ERROR * res,
                        "cell centre {c:?}: holds a point at {} m, nearest is {} m",
                        d.sqrt(),
                        exact.sqrt()
                    );
                    checked += 1;
                    exact_cells += usize::from(d <= exact);
                }
            }
        }
        (checked, exact_cells)
    }

    #[test]
    fn cells_hold_the_exact_closest_point_of_their_centre() {
        let mut rng = crate::testkit::Rng::new(11);
        // random points and a few walls, with a point 5 km away
        let mut pts: Vec<[f64; 2]> = (0..300)
            .map(|_| [rng.range(0.0, 6.0), rng.range(0.0, 4.0)])
            .collect();
        for i in 0..200 {
            let t = i as f64 * 0.03;
            pts.push([t, 1.7]);
            pts.push([2.2, t * 0.7]);
        }
        pts.push([5000.0, 3.0]);
        let (checked, exact) = check_cells(&pts, 0.05, 1.0);
        assert!(checked > 10_000);
        assert!(exact as f64 > 0.99 * checked as f64, "{exact} of {checked}");
    }

    #[test]
    fn far_apart_points_cost_tiles_not_resolution() {
        let near: Vec<[f64; 2]> = (0..100).map(|i| [i as f64 * 0.1, 0.0]).collect();
        let alone = ClosestGrid::build(&near, bounds(&near), 0.02, 2.0, 1 << 23).unwrap();
        let mut far = near.clone();
        far.push([5000.0, 5000.0]);
        let both = ClosestGrid::build(&far, bounds(&far), 0.02, 2.0, 1 << 23).unwrap();
        assert_eq!(both.resolution(), 0.02);
        // the far point adds at most one (2k+1)² block of tiles: k = ceil(2.04 / 0.64) = 4
        assert!(
            both.tiles() <= alone.tiles() + 81,
            "{} vs {}",
            both.tiles(),
            alone.tiles()
        );
    }

    #[test]
    fn too_many_cells_is_refused_not_coarsened() {
        // the tiles around one point at 0.1 mm already exceed the bound
        let e = ClosestGrid::build(&[[0.0, 0.0]], [0.0; 4], 1e-4, 2.0, 1 << 23)
            .err()
            .unwrap();
        assert!(matches!(e, Unbuilt::TooManyCells { .. }));
        // points scattered over 10 km: 81 tiles each
        let mut rng = crate::testkit::Rng::new(3);
        let pts: Vec<[f64; 2]> = (0..3000)
            .map(|_| [rng.range(0.0, 1e4), rng.range(0.0, 1e4)])
            .collect();
        let e = ClosestGrid::build(&pts, bounds(&pts), 0.02, 2.0, 1 << 23)
            .err()
            .unwrap();
        assert!(matches!(e, Unbuilt::TooManyCells { .. }), "{e}");
        // a span the cell coordinates cannot address
        let wide = [[-1e9, 0.0], [1e9, 0.0]];
        let e = ClosestGrid::build(&wide, bounds(&wide), 0.02, 2.0, 1 << 23)
            .err()
            .unwrap();
        assert_eq!(e, Unbuilt::TooWide { span: 2e9 });
    }

    /// The box fill ([`fill_box`]) and the tile-by-tile fill give the same grid; returns
    /// whether it is a full box.
    fn assert_same_fill(points: &[[f64; 2]], res: f64, reach: f64) -> bool {
        let b = bounds(points);
        let rows = ClosestGrid::build_with(points, b, res, reach, 1 << 22, Fill::Compute)
            .unwrap()
            .unwrap();
        let tiles = ClosestGrid::build_with(points, b, res, reach, 1 << 22, Fill::Tiled)
            .unwrap()
            .unwrap();
        assert_eq!(rows.full, tiles.full);
        assert_eq!(rows.keys(), tiles.keys());
        assert_eq!(rows.cells.len(), tiles.cells.len());
        let differ = rows
            .cells
            .iter()
            .zip(&tiles.cells)
            .filter(|(a, b)| a != b)
            .count();
        assert_eq!(differ, 0, "{differ} of {} cells differ", rows.cells.len());
        rows.full.is_some()
    }

    #[test]
    fn row_major_fill_is_the_tiled_fill_on_a_building() {
        // rooms of walls sampled at 5 cm off the axes' lattice, plus clutter, over several tiles
        let mut rng = crate::testkit::Rng::new(5);
        let mut pts = Vec::new();
        for k in 0..6 {
            let (x0, y0) = (k as f64 * 3.1 + 0.013, (k % 2) as f64 * 2.7 - 0.021);
            for i in 0..60 {
                let t = i as f64 * 0.05;
                pts.push([x0 + t, y0]);
                pts.push([x0, y0 + t * 0.9]);
            }
        }
        pts.extend((0..200).map(|_| [rng.range(0.0, 18.0), rng.range(-1.0, 5.0)]));
        assert!(assert_same_fill(&pts, 0.02, 2.0), "expected a full box");
        assert!(assert_same_fill(&pts, 0.05, 2.0), "expected a full box");
    }

    #[test]
    fn box_fill_is_the_tiled_fill_on_an_l_shaped_map() {
        // two 30 m walls meeting at a corner: their tiles cover less than half of the box
        let mut pts: Vec<[f64; 2]> = (0..600).map(|i| [i as f64 * 0.05 + 0.01, 0.02]).collect();
        pts.extend((0..600).map(|i| [0.02, i as f64 * 0.05 + 0.01]));
        assert!(
            !assert_same_fill(&pts, 0.05, 2.0),
            "expected tiles, not a full box"
        );
        assert!(
            !assert_same_fill(&pts, 0.02, 0.6),
            "expected tiles, not a full box"
        );
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 48, .. ProptestConfig::default() })]

        /// Cells hold the closest point (to the tolerance) for random clusters and walls,
        /// at any offset, including single points, identical points and collinear ones.
        #[test]
        fn prop_cells_within_tolerance(seed in 0u64..10_000, n in 1usize..60, spread in 0.0f64..3.0,
                            kind in 0usize..4,
                            offset in prop_oneof![Just(0.0), Just(-7.3e3), Just(1e6), Just(-3e8)],
                            res in prop_oneof![Just(0.02), Just(0.05), Just(0.13)]) {
            let mut rng = crate::testkit::Rng::new(seed);
            let base = [offset, offset * 0.5];
            let pts: Vec<[f64; 2]> = match kind {
                // a cluster
                0 => (0..n).map(|_| [base[0] + rng.range(0.0, spread), base[1] + rng.range(0.0, spread)]).collect(),
                // all points identical
                1 => vec![[base[0] + spread, base[1]]; n],
                // collinear, random direction
                2 => {
                    let a = rng.range(0.0, std::f64::consts::PI);
                    (0..n).map(|_| { let t = rng.range(0.0, spread); [base[0] + t * a.cos(), base[1] + t * a.sin()] }).collect()
                }
                // walls: three random segments sampled at 3 cm
                _ => (0..3).flat_map(|_| {
                    let (x, y) = (base[0] + rng.range(0.0, spread), base[1] + rng.range(0.0, spread));
                    let (u, v) = (base[0] + rng.range(0.0, spread), base[1] + rng.range(0.0, spread));
                    let m = (((u - x).hypot(v - y) / 0.03) as usize).max(1);
                    (0..=m).map(move |i| { let t = i as f64 / m as f64; [x + t * (u - x), y + t * (v - y)] })
                }).collect(),
            };
            prop_assert!(check_cells(&pts, res, 0.6).0 > 0);
        }

        /// Bit-identical cells from the box fill, for one or two random clusters (a full
        /// box, or tiles with gaps) at any offset and cell size.
        #[test]
        fn prop_box_fill_is_the_tiled_fill(seed in 0u64..10_000, n in 1usize..80,
                            spread in 0.0f64..4.0, apart in prop_oneof![Just(0.0), 3.0f64..20.0],
                            offset in prop_oneof![Just(0.0), Just(-7.3e3), Just(1e6), Just(-3e8)],
                            res in prop_oneof![Just(0.02), Just(0.05), Just(0.13)]) {
            let mut rng = crate::testkit::Rng::new(seed);
            let pts: Vec<[f64; 2]> = (0..n)
                .map(|i| {
                    let d = if i % 2 == 1 { apart } else { 0.0 };
                    [offset + d + rng.range(0.0, spread), offset * 0.5 + 0.7 * d + rng.range(0.0, spread)]
                })
                .collect();
            assert_same_fill(&pts, res, 0.6);
        }
    }
}
