//! Wall lines from an occupancy grid, traced where occupied cells meet free ones.
//!
//! Coordinates are *cell-corner units*: cell `(ix, iy)` covers `[ix, ix+1] × [iy, iy+1]`.
//! The caller scales by the resolution and applies the map origin.
//!
//! Pipeline:
//!
//! 1. **Faces.** Every side shared by an occupied and a free cell is a unit *face edge*,
//!    directed so that free space lies on its left (its left normal faces free). Sides
//!    towards unknown cells or the grid border are not faces: a laser never saw them.
//!    The midpoint of a face edge is the sub-cell point where occupancy changes along the
//!    line between the two cell centres; for a wall whose face lies on the cell boundaries
//!    (a drawn or rasterised floor plan) it is exact, for a sloping face it is unbiased.
//! 2. **Chains.** Face edges are linked end to start into chains (open ones end at unknown
//!    space; closed ones ring a wall or an obstacle). At a saddle vertex the left turn is
//!    taken: occupied cells that touch at a corner belong to one wall (8-connected), so a
//!    thin diagonal staircase is one chain.
//! 3. **Split.** Each chain is compressed into straight runs; the run corners are split
//!    Douglas-Peucker style at `split_tolerance` cells times the extent of a cell across the
//!    chord (`|ux| + |uy|`: the corners of a digital straight line at 45° spread over √2
//!    cells).
//! 4. **Refit without end cells.** A piece of three or more runs is fitted by total least
//!    squares to the face midpoints of its inner runs only: the first and last run may
//!    belong to the neighbouring wall (a corner) or be a partial step of a staircase.
//! 5. **Join.** Pieces with the same free side, directions within `join_angle` (or three
//!    standard deviations of their fits, at most 10°) and offsets within `join_offset` are
//!    fitted jointly when the gap between them is at most `max_gap` (a door) and one line
//!    explains both about as well as each explains itself (RMS at most 0.15 cells above
//!    theirs, and at most `max_rms`): they share one line. Pieces that touch become one segment; pieces
//!    across a gap keep their own extents (the door stays open).
//! 6. **Snap (optional).** The length-weighted dominant direction (mod 90°) is found; a
//!    line whose direction lies within `snap_sigmas` standard deviations of its own fit
//!    (from its residuals, at least the quantisation of a cell, 1/√12) of a dominant
//!    direction takes that direction exactly.
//! 7. **Explain.** Lines shorter than `min_length` cells are dropped. A surface cell (an
//!    occupied cell with a face) all of whose faces lie on kept lines is *explained*. Every
//!    unexplained surface cell is returned as a point (the mean of its face midpoints) with
//!    a normal (the sum of the face normals of it and its surface neighbours) facing free.
//!
//! **Thin walls.** A wall one cell thick with free space on both sides has two faces, and
//! both are kept: two lines one cell apart with opposite normals, each facing its free side.
//! `surface_offset` moves every face `surface_offset` cells into the occupied side: 0 puts
//! lines on the occupied/free boundary (maps drawn or rasterised from a floor plan, where a
//! cell is occupied when its centre lies inside the wall); 0.5 puts them on the centres of
//! the boundary cells (maps built from laser hits, where a wall surface lies anywhere inside
//! the cell its hits fell into); then the two faces of a one-cell wall coincide on its
//! centre line, still with one normal towards each free side.
//!
//! **Thick or cluttered walls.** Only faces that see free space are traced, so a thick wall
//! gives the face the free side sees; clutter beside it gives short pieces, which stay points.

use std::collections::HashMap;

use crate::error::{IcpError, Result};

/// Cell classes of the input grid.
pub const FREE: u8 = 0;
/// An occupied cell.
pub const OCCUPIED: u8 = 1;
/// Anything else (unknown) is neither free nor occupied.
pub const UNKNOWN: u8 = 2;

/// Settings of [`extract_lines`]; lengths in cells.
#[derive(Debug, Clone, PartialEq)]
pub struct LineConfig {
    /// Douglas-Peucker tolerance on the run corners [cells].
    pub split_tolerance: f64,
    /// Shortest line kept [cells]; shorter pieces stay as points.
    pub min_length: f64,
    /// Largest gap across which collinear pieces are fitted jointly [cells].
    pub max_gap: f64,
    /// Largest direction difference of pieces fitted jointly [degrees].
    pub join_angle_deg: f64,
    /// Largest offset between pieces fitted jointly [cells].
    pub join_offset: f64,
    /// Largest RMS residual of a joint fit [cells].
    pub max_rms: f64,
    /// Snap directions to the map's dominant directions when within the fit's uncertainty.
    pub snap: bool,
    /// How many standard deviations of a line's direction a snap may move it.
    pub snap_sigmas: f64,
    /// Move every face this far into the occupied side [cells], 0..=0.5 (see module doc).
    pub surface_offset: f64,
    /// Unknown cells up to this many steps (through unknown cells) from free space count as
    /// free when finding faces: map editors, thresholds and anti-aliasing leave such a rim
    /// between free space and walls. 0 turns this off.
    pub unknown_rim: usize,
}

impl Default for LineConfig {
    fn default() -> Self {
        LineConfig {
            split_tolerance: 1.5,
            min_length: 4.0,
            max_gap: 20.0,
            join_angle_deg: 2.0,
            join_offset: 0.75,
            max_rms: 0.5,
            snap: true,
            snap_sigmas: 2.0,
            surface_offset: 0.0,
            unknown_rim: 2,
        }
    }
}

impl LineConfig {
    /// Check every field.
    pub fn validate(&self) -> Result<()> {
        let pos = |field: &'static str, v: f64| {
            if !(v > 0.0) || !v.is_finite() {
                Err(IcpError::InvalidConfig {
                    field,
                    value: v.to_string(),
                    reason: "must be a positive finite number",
                })
            } else {
                Ok(())
            }
        };
        pos("split_tolerance", self.split_tolerance)?;
        pos("min_length", self.min_length)?;
        pos("join_angle_deg", self.join_angle_deg)?;
        pos("join_offset", self.join_offset)?;
        pos("max_rms", self.max_rms)?;
        pos("snap_sigmas", self.snap_sigmas)?;
        if !(self.max_gap >= 0.0) || !self.max_gap.is_finite() {
            return Err(IcpError::InvalidConfig {
                field: "max_gap",
                value: self.max_gap.to_string(),
                reason: "must be a finite number >= 0",
            });
        }
        if !(0.0..=0.5).contains(&self.surface_offset) {
            return Err(IcpError::InvalidConfig {
                field: "surface_offset",
                value: self.surface_offset.to_string(),
                reason: "must lie in [0, 0.5] cells",
            });
        }
        Ok(())
    }
}

/// One fitted wall line.
#[derive(Debug, Clone, PartialEq)]
pub struct GridLine {
    /// `[x1, y1, x2, y2]` in cell-corner units; the left normal faces free space.
    pub segment: [f64; 4],
    /// RMS perpendicular residual of the face midpoints it was fitted to [cells].
    pub rms: f64,
    /// Number of face edges that support it.
    pub support: usize,
    /// Standard deviation of its direction [radians].
    pub sigma_angle: f64,
    /// Its direction was snapped to a dominant direction.
    pub snapped: bool,
}

/// Result of [`extract_lines`].
#[derive(Debug, Clone, PartialEq)]
pub struct GridLines {
    /// The kept lines.
    pub lines: Vec<GridLine>,
    /// Unexplained surface points (cell-corner units), one per unexplained surface cell
    /// (or per face where a cell's faces point opposite ways).
    pub points: Vec<[f64; 2]>,
    /// Unit normals of `points`, facing free space.
    pub normals: Vec<[f64; 2]>,
    /// Occupied cells with at least one face.
    pub surface_cells: usize,
    /// Surface cells all of whose faces lie on kept lines.
    pub explained_cells: usize,
    /// Face edges in the grid.
    pub face_edges: usize,
    /// The dominant direction used for snapping [radians, in [0, π/2)], if any.
    pub dominant_direction: Option<f64>,
}

impl GridLines {
    /// Share of surface cells the lines explain (1 when there are none).
    pub fn explained_fraction(&self) -> f64 {
        if self.surface_cells == 0 {
            1.0
        } else {
            self.explained_cells as f64 / self.surface_cells as f64
        }
    }
}

// directions: 0 +x, 1 +y, 2 -x, 3 -y
const DIRS: [(i64, i64); 4] = [(1, 0), (0, 1), (-1, 0), (0, -1)];

#[derive(Clone, Copy)]
struct Edge {
    x: i64, // start vertex
    y: i64,
    dir: u8,
    cell: usize,
}

impl Edge {
    fn end(&self) -> (i64, i64) {
        let (dx, dy) = DIRS[self.dir as usize];
        (self.x + dx, self.y + dy)
    }
    fn mid(&self) -> [f64; 2] {
        let (dx, dy) = DIRS[self.dir as usize];
        [
            self.x as f64 + 0.5 * dx as f64,
            self.y as f64 + 0.5 * dy as f64,
        ]
    }
    /// Left normal (towards free).
    fn normal(&self) -> [f64; 2] {
        let (dx, dy) = DIRS[self.dir as usize];
        [-dy as f64, dx as f64]
    }
}

/// Sufficient statistics of a 2-D point set for a total-least-squares line.
#[derive(Clone, Copy, Default, Debug)]
struct Stats {
    n: f64,
    sx: f64,
    sy: f64,
    sxx: f64,
    sxy: f64,
    syy: f64,
}

impl Stats {
    fn add(&mut self, p: [f64; 2]) {
        self.n += 1.0;
        self.sx += p[0];
        self.sy += p[1];
        self.sxx += p[0] * p[0];
        self.sxy += p[0] * p[1];
        self.syy += p[1] * p[1];
    }
    fn merged(&self, o: &Stats) -> Stats {
        Stats {
            n: self.n + o.n,
            sx: self.sx + o.sx,
            sy: self.sy + o.sy,
            sxx: self.sxx + o.sxx,
            sxy: self.sxy + o.sxy,
            syy: self.syy + o.syy,
        }
    }
    fn centroid(&self) -> [f64; 2] {
        [self.sx / self.n, self.sy / self.n]
    }
    /// Centred scatter (cxx, cxy, cyy).
    fn scatter(&self) -> (f64, f64, f64) {
        let c = self.centroid();
        (
            (self.sxx - self.n * c[0] * c[0]).max(0.0),
            self.sxy - self.n * c[0] * c[1],
            (self.syy - self.n * c[1] * c[1]).max(0.0),
        )
    }
    /// (unit direction, sum of squared residuals, sum of squared along-line spread).
    fn fit(&self) -> ([f64; 2], f64, f64) {
        let (a, b, c) = self.scatter();
        let theta = 0.5 * (2.0 * b).atan2(a - c);
        let u = [theta.cos(), theta.sin()];
        let (lmin, lmax) = self.moments(u);
        (u, lmin, lmax)
    }
    /// (sum of squared residuals normal to u, sum of squared spread along u).
    fn moments(&self, u: [f64; 2]) -> (f64, f64) {
        let (a, b, c) = self.scatter();
        let along = a * u[0] * u[0] + 2.0 * b * u[0] * u[1] + c * u[1] * u[1];
        let across = a * u[1] * u[1] - 2.0 * b * u[0] * u[1] + c * u[0] * u[0];
        (across.max(0.0), along.max(0.0))
    }
}

/// A straight piece of a chain: a range of face edges.
struct Piece {
    stats: Stats,
    dir_hint: [f64; 2], // chain direction from first to last vertex
    edges: Vec<usize>,  // all face edges of the piece (for extents / explained)
    extent_pts: Vec<[f64; 2]>,
}

/// Extract wall lines from an occupancy grid `cells[iy * width + ix]` whose values are
/// [`FREE`], [`OCCUPIED`] or anything else (unknown).
pub fn extract_lines(
    cells: &[u8],
    width: usize,
    height: usize,
    cfg: &LineConfig,
) -> Result<GridLines> {
    cfg.validate()?;
    if width.checked_mul(height) != Some(cells.len()) {
        return Err(IcpError::Shape {
            what: "grid".into(),
            expected: format!("{width} x {height} = {} cells", width * height),
            got: format!("{} cells", cells.len()),
        });
    }
    let rimmed;
    let cells = if cfg.unknown_rim > 0 {
        rimmed = fill_rim(cells, width, height, cfg.unknown_rim);
        &rimmed[..]
    } else {
        cells
    };
    let edges = face_edges(cells, width, height);
    let chains = link_chains(&edges);
    let mut pieces = Vec::new();
    for chain in &chains {
        split_chain(&edges, chain, cfg.split_tolerance, &mut pieces);
    }
    let groups = join_pieces(&pieces, cfg);
    let (lines_raw, dominant) = finish_groups(&pieces, &groups, cfg);
    let mut lines = Vec::new();
    let mut explained_edge = vec![false; edges.len()];
    for (line, members) in lines_raw {
        if line_len(&line.segment) + 1e-9 < cfg.min_length {
            continue;
        }
        for &pi in &members {
            for &e in &pieces[pi].edges {
                explained_edge[e] = true;
            }
        }
        lines.push(line);
    }
    // per cell: are all faces explained?
    let mut cell_faces: HashMap<usize, (u32, u32)> = HashMap::with_capacity(edges.len());
    for (k, e) in edges.iter().enumerate() {
        let c = cell_faces.entry(e.cell).or_insert((0, 0));
        c.0 += 1;
        if explained_edge[k] {
            c.1 += 1;
        }
    }
    let surface_cells = cell_faces.len();
    let explained_cells = cell_faces.values().filter(|(t, x)| t == x).count();
    let (points, normals) = unexplained_points(&edges, &explained_edge, width, cfg);
    Ok(GridLines {
        lines,
        points,
        normals,
        surface_cells,
        explained_cells,
        face_edges: edges.len(),
        dominant_direction: dominant,
    })
}

fn line_len(s: &[f64; 4]) -> f64 {
    (s[2] - s[0]).hypot(s[3] - s[1])
}

/// A copy of `cells` where unknown cells within `rim` 4-steps (through unknown cells) of
/// free space are free.
fn fill_rim(cells: &[u8], width: usize, height: usize, rim: usize) -> Vec<u8> {
    let mut out = cells.to_vec();
    let mut frontier: Vec<usize> = Vec::new();
    let is_unknown = |v: u8| v != FREE && v != OCCUPIED;
    for (k, &v) in cells.iter().enumerate() {
        if v == FREE {
            frontier.push(k);
        }
    }
    for _ in 0..rim {
        let mut next = Vec::new();
        for &k in &frontier {
            let (x, y) = (k % width, k / width);
            let mut visit = |j: usize| {
                if is_unknown(out[j]) {
                    out[j] = FREE;
                    next.push(j);
                }
            };
            if x > 0 {
                visit(k - 1);
            }
            if x + 1 < width {
                visit(k + 1);
            }
            if y > 0 {
                visit(k - width);
            }
            if y + 1 < height {
                visit(k + width);
            }
        }
        frontier = next;
    }
    out
}

fn face_edges(cells: &[u8], width: usize, height: usize) -> Vec<Edge> {
    let at = |x: i64, y: i64| -> u8 {
        if x < 0 || y < 0 || x >= width as i64 || y >= height as i64 {
            UNKNOWN
        } else {
            cells[y as usize * width + x as usize]
        }
    };
    let mut edges = Vec::new();
    for iy in 0..height {
        let row = &cells[iy * width..(iy + 1) * width];
        for (ix, &v) in row.iter().enumerate() {
            if v != OCCUPIED {
                continue;
            }
            let (x, y) = (ix as i64, iy as i64);
            let cell = iy * width + ix;
            if at(x, y + 1) == FREE {
                edges.push(Edge {
                    x,
                    y: y + 1,
                    dir: 0,
                    cell,
                });
            }
            if at(x + 1, y) == FREE {
                edges.push(Edge {
                    x: x + 1,
                    y: y + 1,
                    dir: 3,
                    cell,
                });
            }
            if at(x, y - 1) == FREE {
                edges.push(Edge {
                    x: x + 1,
                    y,
                    dir: 2,
                    cell,
                });
            }
            if at(x - 1, y) == FREE {
                edges.push(Edge { x, y, dir: 1, cell });
            }
        }
    }
    edges
}

/// Chains of edge indices, linked end to start.
fn link_chains(edges: &[Edge]) -> Vec<Vec<usize>> {
    let mut by_start: HashMap<(i64, i64), [u32; 2]> = HashMap::with_capacity(edges.len());
    for (k, e) in edges.iter().enumerate() {
        let slot = by_start.entry((e.x, e.y)).or_insert([u32::MAX; 2]);
        if slot[0] == u32::MAX {
            slot[0] = k as u32;
        } else {
            slot[1] = k as u32;
        }
    }
    let mut has_pred = vec![false; edges.len()];
    for e in edges {
        if let Some(s) = by_start.get(&e.end()) {
            for &k in s {
                if k != u32::MAX {
                    has_pred[k as usize] = true;
                }
            }
        }
    }
    let mut used = vec![false; edges.len()];
    let mut chains = Vec::new();
    let next = |k: usize, used: &[bool]| -> Option<usize> {
        let e = edges[k];
        let s = by_start.get(&e.end())?;
        let mut best: Option<(u8, usize)> = None;
        for &c in s {
            if c == u32::MAX || used[c as usize] {
                continue;
            }
            let d = edges[c as usize].dir;
            // priority: left turn, straight, right turn (occupied cells touching at a
            // corner are one wall: a diagonal staircase one cell thin stays one chain)
            let rank = match (d + 4 - e.dir) % 4 {
                1 => 0,
                0 => 1,
                3 => 2,
                _ => 3,
            };
            if best.is_none_or(|(r, _)| rank < r) {
                best = Some((rank, c as usize));
            }
        }
        best.map(|b| b.1)
    };
    let starts: Vec<usize> = (0..edges.len())
        .filter(|&k| !has_pred[k])
        .chain(0..edges.len())
        .collect();
    for s in starts {
        if used[s] {
            continue;
        }
        let mut chain = vec![s];
        used[s] = true;
        let mut cur = s;
        while let Some(n) = next(cur, &used) {
            used[n] = true;
            chain.push(n);
            cur = n;
        }
        chains.push(chain);
    }
    chains
}

/// Split one chain into pieces at its run corners (Douglas-Peucker).
fn split_chain(edges: &[Edge], chain: &[usize], tol: f64, out: &mut Vec<Piece>) {
    if chain.is_empty() {
        return;
    }
    // runs: (first edge position in chain, count)
    let mut runs: Vec<(usize, usize)> = Vec::new();
    for (i, &k) in chain.iter().enumerate() {
        match runs.last_mut() {
            Some((s, n)) if edges[chain[*s]].dir == edges[k].dir => *n += 1,
            _ => runs.push((i, 1)),
        }
    }
    let first = edges[chain[0]];
    let last = edges[*chain.last().expect("non-empty")];
    let closed = last.end() == (first.x, first.y) && chain.len() > 2;
    if closed && runs.len() > 1 && edges[chain[runs[0].0]].dir == last.dir {
        // the first and last runs are one run across the start: rotate so it is whole
        let (s, n) = runs.pop().expect("several runs");
        runs[0] = (s, n + runs[0].1);
    }
    if closed && runs.len() > 2 {
        // start a ring at one end of its longest extent (the vertex farthest from the
        // vertex farthest from run 0), so no wall face is cut at an arbitrary start
        let start_of = |r: &(usize, usize)| {
            let e = edges[chain[r.0 % chain.len()]];
            [e.x as f64, e.y as f64]
        };
        let v0 = start_of(&runs[0]);
        let far = |from: [f64; 2]| {
            (0..runs.len())
                .max_by(|&a, &b| {
                    dist2(start_of(&runs[a]), from)
                        .partial_cmp(&dist2(start_of(&runs[b]), from))
                        .expect("finite")
                })
                .unwrap_or(0)
        };
        let f1 = far(v0);
        let f2 = far(start_of(&runs[f1]));
        runs.rotate_left(f2);
    }
    let m = chain.len();
    let vertex = |r: usize| -> [f64; 2] {
        // start vertex of run r
        let e = edges[chain[runs[r % runs.len()].0 % m]];
        [e.x as f64, e.y as f64]
    };
    let nr = runs.len();
    // vertices 0..=nr (vertex nr = end of the last run; for a closed chain = vertex 0)
    let vert = |i: usize| -> [f64; 2] {
        if i < nr {
            vertex(i)
        } else if closed {
            vertex(0)
        } else {
            let (ex, ey) = last.end();
            [ex as f64, ey as f64]
        }
    };
    let mut cuts: Vec<usize> = vec![0, nr];
    if closed {
        // split a ring at the vertex farthest from vertex 0
        let v0 = vert(0);
        let far = (1..nr)
            .max_by(|&a, &b| {
                let da = dist2(vert(a), v0);
                let db = dist2(vert(b), v0);
                da.partial_cmp(&db).expect("finite")
            })
            .unwrap_or(0);
        if far > 0 {
            cuts.push(far);
        }
    }
    cuts.sort_unstable();
    let mut stack: Vec<(usize, usize)> = cuts.windows(2).map(|w| (w[0], w[1])).collect();
    let mut ranges = Vec::new();
    while let Some((i, j)) = stack.pop() {
        if j - i < 2 {
            ranges.push((i, j));
            continue;
        }
        let (a, b) = (vert(i), vert(j));
        let d = [b[0] - a[0], b[1] - a[1]];
        let len = d[0].hypot(d[1]);
        let mut best = (0.0, i);
        for k in i + 1..j {
            let p = vert(k);
            let q = [p[0] - a[0], p[1] - a[1]];
            let dist = if len < 1e-12 {
                q[0].hypot(q[1])
            } else {
                (d[0] * q[1] - d[1] * q[0]).abs() / len
            };
            if dist > best.0 {
                best = (dist, k);
            }
        }
        // a cell's extent across the chord: vertices of a digital straight line lie within
        // (|ux| + |uy|) of each other across it
        let across = if len < 1e-12 {
            1.0
        } else {
            (d[0].abs() + d[1].abs()) / len
        };
        if best.0 > tol * across {
            stack.push((i, best.1));
            stack.push((best.1, j));
        } else {
            ranges.push((i, j));
        }
    }
    // a piece of two runs is one corner (or a single step): split it into its runs
    let mut split: Vec<(usize, usize)> = Vec::with_capacity(ranges.len());
    for (i, j) in ranges {
        if j - i == 2 {
            split.push((i, i + 1));
            split.push((i + 1, j));
        } else {
            split.push((i, j));
        }
    }
    split.sort_unstable();
    for (i, j) in split {
        // runs i..j; the end runs are left out of the fit when they are no longer than the
        // longest inner run (a corner stub or a partial step, not the body of the wall)
        let mut stats = Stats::default();
        let mut all = Vec::new();
        let longest_inner = (i + 1..j.saturating_sub(1))
            .map(|r| runs[r].1)
            .max()
            .unwrap_or(0);
        let inner = j - i >= 3 && runs[i].1.max(runs[j - 1].1) <= longest_inner;
        for (r, &(s, n)) in runs.iter().enumerate().take(j).skip(i) {
            let fit_this = !inner || (r != i && r != j - 1);
            for q in 0..n {
                let k = chain[(s + q) % m];
                all.push(k);
                if fit_this {
                    stats.add(edges[k].mid());
                }
            }
        }
        let (a, b) = (vert(i), vert(j));
        let mut extent_pts = Vec::with_capacity(all.len() + 1);
        for &k in &all {
            extent_pts.push([edges[k].x as f64, edges[k].y as f64]);
        }
        extent_pts.push(b);
        out.push(Piece {
            stats,
            dir_hint: [b[0] - a[0], b[1] - a[1]],
            edges: all,
            extent_pts,
        });
    }
}

/// 1/sqrt(12): the standard deviation of a position quantised to a cell.
const QUANT: f64 = 0.288_675_134_594_812_9;

/// Standard deviation of a TLS direction [rad]: residual (at least the quantisation of a
/// cell) over the root of the spread along the line.
fn angle_sigma(s: &Stats) -> f64 {
    if s.n < 2.0 {
        return std::f64::consts::PI;
    }
    let (_, ss, spread) = s.fit();
    (ss / s.n).sqrt().max(QUANT) / spread.max(1e-12).sqrt()
}

fn dist2(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)
}

fn oriented(u: [f64; 2], hint: [f64; 2]) -> [f64; 2] {
    if u[0] * hint[0] + u[1] * hint[1] < 0.0 {
        [-u[0], -u[1]]
    } else {
        u
    }
}

/// (t_min, t_max) of points projected on a line through c with direction u.
fn extent(pts: &[[f64; 2]], c: [f64; 2], u: [f64; 2]) -> (f64, f64) {
    pts.iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
            let t = (p[0] - c[0]) * u[0] + (p[1] - c[1]) * u[1];
            (lo.min(t), hi.max(t))
        })
}

struct Dsu {
    parent: Vec<usize>,
    stats: Vec<Stats>,
    hint: Vec<[f64; 2]>,
}

impl Dsu {
    fn find(&mut self, mut a: usize) -> usize {
        while self.parent[a] != a {
            self.parent[a] = self.parent[self.parent[a]];
            a = self.parent[a];
        }
        a
    }
}

/// (centroid, unit direction, (t_min, t_max)) of a piece's fit.
type LineFitOf = ([f64; 2], [f64; 2], (f64, f64));

/// Group pieces that lie on one line (same free side, close direction and offset, gap at
/// most `max_gap`). Returns groups of piece indices.
fn join_pieces(pieces: &[Piece], cfg: &LineConfig) -> Vec<Vec<usize>> {
    let n = pieces.len();
    let fits: Vec<Option<LineFitOf>> = pieces
        .iter()
        .map(|p| {
            if p.stats.n < 2.0 {
                return None;
            }
            let (u, _, _) = p.stats.fit();
            let u = oriented(u, p.dir_hint);
            let c = p.stats.centroid();
            Some((c, u, extent(&p.extent_pts, c, u)))
        })
        .collect();
    // candidate pairs from a hash of end points
    let cell = (cfg.max_gap + 1.0).max(2.0);
    let key = |p: [f64; 2]| ((p[0] / cell).floor() as i64, (p[1] / cell).floor() as i64);
    let mut buckets: HashMap<(i64, i64), Vec<usize>> = HashMap::new();
    let mut ends: Vec<[[f64; 2]; 2]> = vec![[[0.0; 2]; 2]; n];
    for (k, f) in fits.iter().enumerate() {
        if let Some((c, u, (lo, hi))) = f {
            let a = [c[0] + u[0] * lo, c[1] + u[1] * lo];
            let b = [c[0] + u[0] * hi, c[1] + u[1] * hi];
            ends[k] = [a, b];
            for p in [a, b] {
                buckets.entry(key(p)).or_default().push(k);
            }
        }
    }
    let sigma: Vec<f64> = pieces.iter().map(|p| angle_sigma(&p.stats)).collect();
    let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
    for (k, f) in fits.iter().enumerate() {
        let Some((ck, uk, (lo_k, hi_k))) = f else {
            continue;
        };
        let mut seen: Vec<usize> = Vec::new();
        for p in ends[k] {
            let (bx, by) = key(p);
            for dx in -1..=1 {
                for dy in -1..=1 {
                    if let Some(v) = buckets.get(&(bx + dx, by + dy)) {
                        seen.extend(v.iter().copied().filter(|&j| j > k));
                    }
                }
            }
        }
        seen.sort_unstable();
        seen.dedup();
        for j in seen {
            let Some((cj, uj, _)) = fits[j] else { continue };
            // directions agree within the join angle or the two fits' own uncertainty
            let allowed = cfg
                .join_angle_deg
                .to_radians()
                .max(3.0 * sigma[k].hypot(sigma[j]))
                .min(10f64.to_radians());
            if uk[0] * uj[0] + uk[1] * uj[1] < allowed.cos() {
                continue;
            }
            // offset of j's centroid from k's line, and k's from j's
            let nk = [-uk[1], uk[0]];
            let nj = [-uj[1], uj[0]];
            let off1 = ((cj[0] - ck[0]) * nk[0] + (cj[1] - ck[1]) * nk[1]).abs();
            let off2 = ((ck[0] - cj[0]) * nj[0] + (ck[1] - cj[1]) * nj[1]).abs();
            if off1.max(off2) > cfg.join_offset {
                continue;
            }
            // gap along k's direction
            let (lo_j, hi_j) = extent(&pieces[j].extent_pts, *ck, *uk);
            let gap = (lo_j - hi_k).max(lo_k - hi_j);
            if gap > cfg.max_gap {
                continue;
            }
            pairs.push((gap, k, j));
        }
    }
    pairs.sort_by(|a, b| a.0.partial_cmp(&b.0).expect("finite gaps"));
    let mut dsu = Dsu {
        parent: (0..n).collect(),
        stats: pieces.iter().map(|p| p.stats).collect(),
        hint: pieces.iter().map(|p| p.dir_hint).collect(),
    };
    for (_, a, b) in pairs {
        let (ra, rb) = (dsu.find(a), dsu.find(b));
        if ra == rb {
            continue;
        }
        let m = dsu.stats[ra].merged(&dsu.stats[rb]);
        let (_, ss, _) = m.fit();
        let rms_of = |s: &Stats| (s.fit().1 / s.n).sqrt();
        // one line must explain both about as well as each explains itself
        let own = rms_of(&dsu.stats[ra])
            .max(rms_of(&dsu.stats[rb]))
            .max(QUANT);
        if (ss / m.n).sqrt() > cfg.max_rms.min(own + 0.15) {
            continue;
        }
        dsu.parent[rb] = ra;
        dsu.stats[ra] = m;
        let h = [
            dsu.hint[ra][0] + dsu.hint[rb][0],
            dsu.hint[ra][1] + dsu.hint[rb][1],
        ];
        dsu.hint[ra] = h;
    }
    let mut groups: HashMap<usize, Vec<usize>> = HashMap::new();
    for k in 0..n {
        let r = dsu.find(k);
        groups.entry(r).or_default().push(k);
    }
    let mut out: Vec<Vec<usize>> = groups.into_values().collect();
    out.sort_unstable_by_key(|g| g[0]);
    out
}

/// Fit each group, snap, and cut it into segments at its gaps. Returns the segments with
/// their member pieces, and the dominant direction.
fn finish_groups(
    pieces: &[Piece],
    groups: &[Vec<usize>],
    cfg: &LineConfig,
) -> (Vec<(GridLine, Vec<usize>)>, Option<f64>) {
    struct G {
        c: [f64; 2],
        u: [f64; 2],
        rms: f64,
        sigma: f64,
        n: f64,
        len: f64,
    }
    let mut fitted: Vec<Option<G>> = Vec::with_capacity(groups.len());
    for g in groups {
        let mut s = Stats::default();
        let mut hint = [0.0, 0.0];
        for &p in g {
            s = s.merged(&pieces[p].stats);
            hint[0] += pieces[p].dir_hint[0];
            hint[1] += pieces[p].dir_hint[1];
        }
        if s.n < 2.0 {
            fitted.push(None);
            continue;
        }
        let (u, ss, spread) = s.fit();
        let u = oriented(u, hint);
        let rms = (ss / s.n).sqrt();
        let sigma = rms.max(QUANT) / spread.max(1e-12).sqrt();
        fitted.push(Some(G {
            c: s.centroid(),
            u,
            rms,
            sigma,
            n: s.n,
            len: spread.sqrt(),
        }));
    }
    // dominant direction mod 90 degrees: length-weighted circular mean of 4*theta around
    // the peak of a 1-degree histogram
    let mut dominant = None;
    if cfg.snap {
        let mut hist = [0.0f64; 90];
        let mut any = false;
        for g in fitted.iter().flatten() {
            if g.n < 6.0 {
                continue;
            }
            let th = g.u[1].atan2(g.u[0]).rem_euclid(std::f64::consts::FRAC_PI_2);
            let b = ((th.to_degrees()).floor() as usize).min(89);
            hist[b] += g.n;
            any = true;
        }
        if any {
            let (peak, _) = hist
                .iter()
                .enumerate()
                .map(|(i, &w)| (i, w + hist[(i + 89) % 90] + hist[(i + 1) % 90]))
                .fold((0, -1.0), |b, x| if x.1 > b.1 { x } else { b });
            // weighted mean of the lines near the peak (within 2 degrees), then again of
            // those consistent with that mean (within 3 sigma of their own fit + 0.05 deg)
            let mut centre = (peak as f64 + 0.5).to_radians();
            for pass in 0..2 {
                let (mut sc, mut ss) = (0.0, 0.0);
                for g in fitted.iter().flatten() {
                    if g.n < 6.0 {
                        continue;
                    }
                    let th = g.u[1].atan2(g.u[0]);
                    let mut d = (4.0 * (th - centre)).rem_euclid(std::f64::consts::TAU);
                    if d > std::f64::consts::PI {
                        d -= std::f64::consts::TAU;
                    }
                    let window = if pass == 0 {
                        2f64.to_radians()
                    } else {
                        3.0 * g.sigma + 0.05f64.to_radians()
                    };
                    if (0.25 * d).abs() <= window {
                        let w = g.n / g.sigma.max(1e-6);
                        sc += w * (4.0 * th).cos();
                        ss += w * (4.0 * th).sin();
                    }
                }
                if sc == 0.0 && ss == 0.0 {
                    break;
                }
                centre = (0.25 * ss.atan2(sc)).rem_euclid(std::f64::consts::FRAC_PI_2);
                dominant = Some(centre);
            }
        }
    }
    let mut out = Vec::new();
    for (g, members) in fitted.iter().zip(groups) {
        let Some(g) = g else { continue };
        let mut u = g.u;
        let mut snapped = false;
        if let Some(dom) = dominant {
            let th = u[1].atan2(u[0]);
            let k = ((th - dom) / std::f64::consts::FRAC_PI_2).round();
            let target = dom + k * std::f64::consts::FRAC_PI_2;
            if (th - target).abs() <= cfg.snap_sigmas * g.sigma && g.len > 0.0 {
                u = [target.cos(), target.sin()];
                snapped = true;
            }
        }
        let nrm = [-u[1], u[0]];
        let off = -cfg.surface_offset;
        let c = [g.c[0] + off * nrm[0], g.c[1] + off * nrm[1]];
        // member extents along the group line, merged where they touch
        let mut spans: Vec<(f64, f64, usize)> = members
            .iter()
            .map(|&p| {
                let (lo, hi) = extent(&pieces[p].extent_pts, c, u);
                (lo, hi, p)
            })
            .collect();
        spans.sort_by(|a, b| a.0.partial_cmp(&b.0).expect("finite"));
        let mut cur: Option<(f64, f64, Vec<usize>)> = None;
        let emit = |lo: f64, hi: f64, mem: Vec<usize>, out: &mut Vec<(GridLine, Vec<usize>)>| {
            let support = mem.iter().map(|&p| pieces[p].edges.len()).sum();
            out.push((
                GridLine {
                    segment: [
                        c[0] + u[0] * lo,
                        c[1] + u[1] * lo,
                        c[0] + u[0] * hi,
                        c[1] + u[1] * hi,
                    ],
                    rms: g.rms,
                    support,
                    sigma_angle: g.sigma,
                    snapped,
                },
                mem,
            ));
        };
        for (lo, hi, p) in spans {
            match cur.as_mut() {
                Some((_, chi, mem)) if lo <= *chi + 1.0 => {
                    *chi = chi.max(hi);
                    mem.push(p);
                }
                _ => {
                    if let Some((a, b, mem)) = cur.take() {
                        emit(a, b, mem, &mut out);
                    }
                    cur = Some((lo, hi, vec![p]));
                }
            }
        }
        if let Some((a, b, mem)) = cur.take() {
            emit(a, b, mem, &mut out);
        }
    }
    (out, dominant)
}

fn unexplained_points(
    edges: &[Edge],
    explained: &[bool],
    width: usize,
    cfg: &LineConfig,
) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
    // per cell: sum of face normals (all faces) for the neighbourhood normal
    let mut normal_sum: HashMap<usize, [f64; 2]> = HashMap::new();
    let mut unexplained: HashMap<usize, Vec<usize>> = HashMap::new();
    for (k, e) in edges.iter().enumerate() {
        let n = e.normal();
        let s = normal_sum.entry(e.cell).or_insert([0.0, 0.0]);
        s[0] += n[0];
        s[1] += n[1];
        if !explained[k] {
            unexplained.entry(e.cell).or_default().push(k);
        }
    }
    let mut cells: Vec<usize> = unexplained.keys().copied().collect();
    cells.sort_unstable();
    let mut pts = Vec::new();
    let mut nrms = Vec::new();
    let off = cfg.surface_offset;
    for cell in cells {
        let own = &unexplained[&cell];
        let own_sum = normal_sum[&cell];
        let opposite = own_sum[0].hypot(own_sum[1]) < 0.5;
        if opposite {
            // faces point opposite ways (a one-cell wall or pillar): one point per face
            for &k in own {
                let (m, n) = (edges[k].mid(), edges[k].normal());
                pts.push([m[0] - off * n[0], m[1] - off * n[1]]);
                nrms.push(n);
            }
            continue;
        }
        let (cx, cy) = ((cell % width) as i64, (cell / width) as i64);
        let mut s = [0.0, 0.0];
        for dy in -1..=1i64 {
            for dx in -1..=1i64 {
                let (x, y) = (cx + dx, cy + dy);
                if x < 0 || y < 0 || x >= width as i64 {
                    continue;
                }
                if let Some(v) = normal_sum.get(&(y as usize * width + x as usize)) {
                    let w = if dx == 0 && dy == 0 { 2.0 } else { 1.0 };
                    s[0] += w * v[0];
                    s[1] += w * v[1];
                }
            }
        }
        if s[0].hypot(s[1]) < 1e-9 {
            s = own_sum;
        }
        let l = s[0].hypot(s[1]);
        let n = [s[0] / l, s[1] / l];
        let mut p = [0.0, 0.0];
        for &k in own {
            let m = edges[k].mid();
            p[0] += m[0];
            p[1] += m[1];
        }
        let c = own.len() as f64;
        pts.push([p[0] / c - off * n[0], p[1] / c - off * n[1]]);
        nrms.push(n);
    }
    (pts, nrms)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(w: usize, h: usize, occ: impl Fn(usize, usize) -> bool) -> Vec<u8> {
        let mut g = vec![FREE; w * h];
        for y in 0..h {
            for x in 0..w {
                if occ(x, y) {
                    g[y * w + x] = OCCUPIED;
                }
            }
        }
        g
    }

    fn find(r: &GridLines, pred: impl Fn(&[f64; 4]) -> bool) -> Vec<[f64; 4]> {
        r.lines
            .iter()
            .map(|l| l.segment)
            .filter(|s| pred(s))
            .collect()
    }

    #[test]
    fn thick_block_faces_are_exact() {
        // a 10 x 4 block at x 5..15, y 6..10
        let g = grid(30, 20, |x, y| (5..15).contains(&x) && (6..10).contains(&y));
        let r = extract_lines(&g, 30, 20, &LineConfig::default()).unwrap();
        // four faces
        let top = find(&r, |s| {
            (s[1] - 10.0).abs() < 1e-9 && (s[3] - 10.0).abs() < 1e-9
        });
        assert_eq!(top.len(), 1);
        let t = top[0];
        // left normal faces +y: direction +x
        assert!(
            (t[0] - 5.0).abs() < 1e-9 && (t[2] - 15.0).abs() < 1e-9,
            "{t:?}"
        );
        let bottom = find(&r, |s| {
            (s[1] - 6.0).abs() < 1e-9 && (s[3] - 6.0).abs() < 1e-9
        });
        assert_eq!(bottom.len(), 1);
        assert!(
            bottom[0][0] > bottom[0][2],
            "bottom runs -x so its normal faces -y"
        );
        assert_eq!(r.explained_cells, r.surface_cells);
    }

    #[test]
    fn thin_wall_keeps_both_faces_or_centre_line() {
        let g = grid(40, 10, |x, y| y == 5 && (5..35).contains(&x));
        let r = extract_lines(&g, 40, 10, &LineConfig::default()).unwrap();
        let faces = find(&r, |s| (s[1] - s[3]).abs() < 1e-9);
        assert_eq!(faces.len(), 2);
        let mut ys: Vec<f64> = faces.iter().map(|s| s[1]).collect();
        ys.sort_by(|a, b| a.partial_cmp(b).unwrap());
        assert!((ys[0] - 5.0).abs() < 1e-9 && (ys[1] - 6.0).abs() < 1e-9);
        let cfg = LineConfig {
            surface_offset: 0.5,
            ..LineConfig::default()
        };
        let r = extract_lines(&g, 40, 10, &cfg).unwrap();
        let faces = find(&r, |s| (s[1] - s[3]).abs() < 1e-9);
        assert_eq!(faces.len(), 2);
        for f in &faces {
            assert!((f[1] - 5.5).abs() < 1e-9);
        }
        assert!((faces[0][2] - faces[0][0]) * (faces[1][2] - faces[1][0]) < 0.0);
    }

    #[test]
    fn door_gap_stays_open_and_shares_the_line() {
        let g = grid(60, 10, |x, y| {
            (3..=5).contains(&y) && !(25..40).contains(&x)
        });
        let r = extract_lines(&g, 60, 10, &LineConfig::default()).unwrap();
        let top = find(&r, |s| {
            (s[1] - 6.0).abs() < 1e-9 && (s[3] - 6.0).abs() < 1e-9
        });
        assert_eq!(top.len(), 2, "{:?}", r.lines);
    }

    #[test]
    fn unknown_and_border_sides_are_not_faces() {
        let mut g = grid(10, 10, |x, _| x == 5);
        for y in 0..10 {
            g[y * 10 + 6] = UNKNOWN;
        }
        let cfg = LineConfig {
            unknown_rim: 0,
            ..LineConfig::default()
        };
        let r = extract_lines(&g, 10, 10, &cfg).unwrap();
        assert_eq!(r.face_edges, 10); // only the left faces
        assert_eq!(r.lines.len(), 1);
        let s = r.lines[0].segment;
        assert!((s[0] - 5.0).abs() < 1e-9 && (s[2] - 5.0).abs() < 1e-9);
        assert!(s[1] < s[3], "runs +y so its normal faces -x");
    }

    #[test]
    fn sloped_face_is_unbiased() {
        // half plane below y = 0.3 x + 10.2 (cell occupied when its centre is below)
        let (w, h) = (200, 80);
        let (m, b) = (0.3, 10.2);
        let g = grid(w, h, |x, y| (y as f64 + 0.5) < m * (x as f64 + 0.5) + b);
        let r = extract_lines(&g, w, h, &LineConfig::default()).unwrap();
        let long = r
            .lines
            .iter()
            .max_by(|a, b| {
                line_len(&a.segment)
                    .partial_cmp(&line_len(&b.segment))
                    .unwrap()
            })
            .unwrap();
        let s = long.segment;
        let ang = (s[3] - s[1]).atan2(s[2] - s[0]);
        assert!(
            (ang - m.atan()).abs() < 0.1f64.to_radians(),
            "{}",
            ang.to_degrees()
        );
        let xm = 0.5 * (s[0] + s[2]);
        let ym = 0.5 * (s[1] + s[3]);
        let d = (ym - (m * xm + b)) * m.atan().cos();
        assert!(d.abs() < 0.05, "offset {d}");
    }

    #[test]
    fn clutter_becomes_points_with_outward_normals() {
        let g = grid(20, 20, |x, y| (9..12).contains(&x) && (9..12).contains(&y));
        let r = extract_lines(&g, 20, 20, &LineConfig::default()).unwrap();
        assert!(r.lines.is_empty());
        assert_eq!(r.points.len(), 8);
        for (p, n) in r.points.iter().zip(&r.normals) {
            let q = [p[0] - 10.5, p[1] - 10.5];
            assert!(q[0] * n[0] + q[1] * n[1] > 0.0);
        }
        assert_eq!(r.explained_cells, 0);
    }

    #[test]
    fn bad_shape_and_config() {
        assert!(extract_lines(&[0; 5], 2, 2, &LineConfig::default()).is_err());
        let cfg = LineConfig {
            surface_offset: 0.7,
            ..LineConfig::default()
        };
        assert!(extract_lines(&[0; 4], 2, 2, &cfg).is_err());
    }
}
