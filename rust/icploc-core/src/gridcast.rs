//! Occupancy counts from laser rays: the ray casting behind `icploc map build`.
//!
//! Each ray runs from the sensor to its end point. Every cell it passes through before the
//! end cell counts a *pass* (the beam went through: evidence of free space); the end cell
//! counts a *hit* when the ray ended on an obstacle (not for max-range readings, which
//! only clear space). Cells are traversed exactly (Amanatides & Woo): every cell the ray's
//! open segment crosses is visited once.

use crate::error::{IcpError, Result};

/// The grid geometry: cell `(ix, iy)` covers `origin + [ix, ix+1) × [iy, iy+1)` times
/// `resolution` (no rotation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridGeometry {
    /// World coordinates of the outer corner of cell (0, 0).
    pub origin: [f64; 2],
    /// Cell size.
    pub resolution: f64,
    /// Cells along x.
    pub width: usize,
    /// Cells along y.
    pub height: usize,
}

/// Largest grid [`cast_rays`] accepts (cells).
pub const MAX_CELLS: usize = 400_000_000;

/// Per-cell counts: `hits[iy * width + ix]`, `passes[...]`.
#[derive(Debug, Clone, PartialEq)]
pub struct RayCounts {
    /// Rays that ended in the cell on an obstacle.
    pub hits: Vec<u32>,
    /// Rays that passed through the cell.
    pub passes: Vec<u32>,
}

/// Count hits and passes of rays `origins[k] -> ends[k]`; `hit[k]` says whether ray k ended
/// on an obstacle. Rays may start or end outside the grid (only the part inside counts).
pub fn cast_rays(
    g: &GridGeometry,
    origins: &[[f64; 2]],
    ends: &[[f64; 2]],
    hit: &[bool],
) -> Result<RayCounts> {
    if !(g.resolution > 0.0) || !g.resolution.is_finite() {
        return Err(IcpError::InvalidConfig {
            field: "resolution",
            value: g.resolution.to_string(),
            reason: "must be a positive finite number",
        });
    }
    if !(g.origin[0].is_finite() && g.origin[1].is_finite()) {
        return Err(IcpError::InvalidInput {
            what: "origin".into(),
            reason: "must be finite".into(),
        });
    }
    let cells = g.width.checked_mul(g.height).filter(|&c| c <= MAX_CELLS);
    let Some(cells) = cells else {
        return Err(IcpError::InvalidInput {
            what: "grid".into(),
            reason: format!(
                "{} x {} cells is more than the limit of {MAX_CELLS}",
                g.width, g.height
            ),
        });
    };
    if origins.len() != ends.len() || hit.len() != ends.len() {
        return Err(IcpError::Shape {
            what: "rays".into(),
            expected: "origins, ends and hit of one length".into(),
            got: format!("{}, {}, {}", origins.len(), ends.len(), hit.len()),
        });
    }
    crate::check_finite("origins", origins)?;
    crate::check_finite("ends", ends)?;
    let mut out = RayCounts {
        hits: vec![0; cells],
        passes: vec![0; cells],
    };
    for k in 0..origins.len() {
        trace(g, origins[k], ends[k], hit[k], &mut out);
    }
    Ok(out)
}

fn trace(g: &GridGeometry, o: [f64; 2], e: [f64; 2], is_hit: bool, out: &mut RayCounts) {
    let (w, h) = (g.width as i64, g.height as i64);
    // into cell units
    let a = [
        (o[0] - g.origin[0]) / g.resolution,
        (o[1] - g.origin[1]) / g.resolution,
    ];
    let b = [
        (e[0] - g.origin[0]) / g.resolution,
        (e[1] - g.origin[1]) / g.resolution,
    ];
    let d = [b[0] - a[0], b[1] - a[1]];
    // clip the parameter range [0, 1] to the grid box
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for (ai, di, hi) in [(a[0], d[0], w as f64), (a[1], d[1], h as f64)] {
        if di.abs() < 1e-15 {
            if ai < 0.0 || ai >= hi {
                return;
            }
        } else {
            let (mut lo, mut up) = ((0.0 - ai) / di, (hi - ai) / di);
            if lo > up {
                std::mem::swap(&mut lo, &mut up);
            }
            t0 = t0.max(lo);
            t1 = t1.min(up);
        }
    }
    let end_cell = (b[0].floor() as i64, b[1].floor() as i64);
    let end_inside = end_cell.0 >= 0 && end_cell.1 >= 0 && end_cell.0 < w && end_cell.1 < h;
    if t0 > t1 {
        return;
    }
    let p = [a[0] + d[0] * t0, a[1] + d[1] * t0];
    let start = [
        (p[0].floor() as i64).clamp(0, w - 1),
        (p[1].floor() as i64).clamp(0, h - 1),
    ];
    let mut walk = CellWalk::new(start, a, d);
    let max_steps = (w + h + 4) as usize * 2;
    for _ in 0..max_steps {
        let [cx, cy] = walk.cell;
        if (cx, cy) == end_cell {
            break;
        }
        let idx = cy as usize * g.width + cx as usize;
        out.passes[idx] = out.passes[idx].saturating_add(1);
        if walk.exit_t() >= t1 {
            break;
        }
        walk.advance();
        let [cx, cy] = walk.cell;
        if cx < 0 || cy < 0 || cx >= w || cy >= h {
            break;
        }
    }
    if is_hit && end_inside {
        let idx = end_cell.1 as usize * g.width + end_cell.0 as usize;
        out.hits[idx] = out.hits[idx].saturating_add(1);
    }
}

/// The cells a segment `a + t d` (grid units) crosses, one after the other from `cell`
/// (Amanatides–Woo): `exit_t` is the parameter where it leaves the current cell,
/// `advance` steps into the next one (x on a tie goes to y, as both walks always did).
struct CellWalk {
    cell: [i64; 2],
    step: [i64; 2],
    next: [f64; 2],
    delta: [f64; 2],
}

impl CellWalk {
    fn new(cell: [i64; 2], a: [f64; 2], d: [f64; 2]) -> Self {
        let step = [d[0].signum() as i64, d[1].signum() as i64];
        let mut next = [f64::INFINITY; 2];
        let mut delta = [f64::INFINITY; 2];
        for k in 0..2 {
            if step[k] != 0 {
                let boundary = if step[k] > 0 { cell[k] + 1 } else { cell[k] } as f64;
                next[k] = (boundary - a[k]) / d[k];
                delta[k] = 1.0 / d[k].abs();
            }
        }
        Self {
            cell,
            step,
            next,
            delta,
        }
    }

    fn exit_t(&self) -> f64 {
        self.next[0].min(self.next[1])
    }

    fn advance(&mut self) {
        let k = if self.next[0] < self.next[1] { 0 } else { 1 };
        self.cell[k] += self.step[k];
        self.next[k] += self.delta[k];
    }
}

/// Which `targets` a sensor at `sensor` sees through a class grid `cells[iy * width + ix]`
/// (0 free; anything else, occupied or unknown, blocks): target k is visible when every
/// cell the ray crosses up to `tolerance` before the target is free (so the wall cell a
/// target lies on does not hide it). Coordinates are in the grid's frame (no rotation).
pub fn grid_visible(
    cells: &[u8],
    g: &GridGeometry,
    sensor: [f64; 2],
    targets: &[[f64; 2]],
    tolerance: f64,
) -> Result<Vec<bool>> {
    if g.width.checked_mul(g.height) != Some(cells.len()) {
        return Err(IcpError::Shape {
            what: "cells".into(),
            expected: format!("{} x {}", g.height, g.width),
            got: format!("{} cells", cells.len()),
        });
    }
    if !(g.resolution > 0.0) || !g.resolution.is_finite() || !(tolerance >= 0.0) {
        return Err(IcpError::InvalidConfig {
            field: "resolution/tolerance",
            value: format!("{} / {}", g.resolution, tolerance),
            reason: "resolution must be positive, tolerance >= 0",
        });
    }
    crate::check_finite("sensor", &[sensor])?;
    crate::check_finite("targets", targets)?;
    let (w, h) = (g.width as i64, g.height as i64);
    let a = [
        (sensor[0] - g.origin[0]) / g.resolution,
        (sensor[1] - g.origin[1]) / g.resolution,
    ];
    let tol = tolerance / g.resolution;
    let blocked = |x: i64, y: i64| -> bool {
        x >= 0 && y >= 0 && x < w && y < h && cells[y as usize * g.width + x as usize] != 0
    };
    Ok(targets
        .iter()
        .map(|t| {
            let b = [
                (t[0] - g.origin[0]) / g.resolution,
                (t[1] - g.origin[1]) / g.resolution,
            ];
            let d = [b[0] - a[0], b[1] - a[1]];
            let len = d[0].hypot(d[1]);
            if len <= tol {
                return true;
            }
            let t_end = 1.0 - tol / len; // stop this far before the target
            let mut walk = CellWalk::new([a[0].floor() as i64, a[1].floor() as i64], a, d);
            let max_steps = (len.ceil() as usize + 2) * 2;
            for _ in 0..max_steps {
                if blocked(walk.cell[0], walk.cell[1]) {
                    return false;
                }
                if walk.exit_t() >= t_end {
                    return true;
                }
                walk.advance();
            }
            true
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn geom(w: usize, h: usize) -> GridGeometry {
        GridGeometry {
            origin: [0.0, 0.0],
            resolution: 0.1,
            width: w,
            height: h,
        }
    }

    #[test]
    fn straight_ray_passes_then_hits() {
        let g = geom(10, 3);
        let r = cast_rays(&g, &[[0.05, 0.15]], &[[0.75, 0.15]], &[true]).unwrap();
        let row: Vec<u32> = r.passes[10..20].to_vec();
        assert_eq!(row, vec![1, 1, 1, 1, 1, 1, 1, 0, 0, 0]);
        assert_eq!(r.hits[17], 1);
        assert_eq!(r.hits.iter().sum::<u32>(), 1);
    }

    #[test]
    fn miss_only_clears_and_outside_parts_are_clipped() {
        let g = geom(5, 5);
        let r = cast_rays(&g, &[[-1.0, 0.25]], &[[2.0, 0.25]], &[false]).unwrap();
        assert_eq!(&r.passes[10..15], &[1, 1, 1, 1, 1]);
        assert_eq!(r.hits.iter().sum::<u32>(), 0);
    }

    #[test]
    fn diagonal_ray_visits_connected_cells() {
        let g = geom(20, 20);
        let r = cast_rays(&g, &[[0.01, 0.02]], &[[1.93, 1.31]], &[true]).unwrap();
        let n: u32 = r.passes.iter().sum();
        // a ray crossing 19 columns and 13 rows visits 19 + 13 + 1 cells (one is the end)
        assert_eq!(n, 19 + 13);
        assert_eq!(r.hits[13 * 20 + 19], 1);
    }

    #[test]
    fn unknown_and_occupied_cells_hide_what_lies_behind() {
        let g = geom(10, 1);
        let mut cells = vec![0u8; 10];
        let targets = [[0.55, 0.05], [0.95, 0.05]];
        assert_eq!(
            grid_visible(&cells, &g, [0.05, 0.05], &targets, 0.05).unwrap(),
            vec![true, true]
        );
        cells[7] = 2; // unknown between the two targets
        assert_eq!(
            grid_visible(&cells, &g, [0.05, 0.05], &targets, 0.05).unwrap(),
            vec![true, false]
        );
        cells[7] = 0;
        cells[9] = 1; // the target's own wall cell does not hide it
        assert_eq!(
            grid_visible(&cells, &g, [0.05, 0.05], &[[0.9, 0.05]], 0.05).unwrap(),
            vec![true]
        );
    }

    #[test]
    fn bad_input() {
        let g = geom(5, 5);
        assert!(cast_rays(&g, &[[0.0, f64::NAN]], &[[0.0, 0.0]], &[true]).is_err());
        assert!(cast_rays(&g, &[[0.0, 0.0]], &[], &[]).is_err());
        let big = geom(100_000, 100_000);
        assert!(cast_rays(&big, &[], &[], &[]).is_err());
    }
}
