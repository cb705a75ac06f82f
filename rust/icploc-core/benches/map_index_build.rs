//! Criterion benchmark of building the map index as the Python API does by default (k-d
//! tree + closest-point grid at `DEFAULT_CACHE_RESOLUTION`, 2 cm): the largest fixed cost
//! of a replay process (`benches/replay_speed.py`, stage `index`).
//!
//! The map: a 52 m × 52 m building of 4 m × 5 m rooms (walls sampled every 5 cm, as
//! `Map.sample(0.05)` does, with a door gap in each wall, a little clutter), about the size
//! of the real-data benchmark's aces map, whose grid is one full box of tiles; and a
//! small 20 m × 12 m office wing. `kdtree+grid_from_runs`: the same index rebuilt from its
//! grid's saved cells (`index::runs` + `MapIndex::with_cache_cells`, what a process does when
//! the prepared-map cache holds them). `two_wings_1km_apart`: two wings 1 km apart, a grid
//! whose box of tiles is too sparse for the box fill: the tile-by-tile fill. Run with
//! `cargo bench -p icploc-core --bench map_index_build`.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use icploc_core::index::{runs, DEFAULT_CACHE_RESOLUTION, MAX_CACHE_CELLS};
use icploc_core::testkit::Rng;
use icploc_core::MapIndex;

/// Wall points (every 5 cm) and normals of a `w` × `h` m building of `rx` × `ry` m rooms.
fn building(w: f64, h: f64, rx: f64, ry: f64) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
    let (mut p, mut n) = (Vec::new(), Vec::new());
    let step = 0.05;
    let mut x = 0.0;
    while x <= w + 1e-9 {
        let mut t = 0.0;
        while t <= h {
            // a 0.9 m door in the middle of each room's wall
            if (t % ry - 0.5 * ry).abs() > 0.45 || x == 0.0 || x >= w - 1e-9 {
                p.push([x + 0.013, t - 0.021]);
                n.push([1.0, 0.0]);
            }
            t += step;
        }
        x += rx;
    }
    let mut y = 0.0;
    while y <= h + 1e-9 {
        let mut t = 0.0;
        while t <= w {
            if (t % rx - 0.5 * rx).abs() > 0.45 || y == 0.0 || y >= h - 1e-9 {
                p.push([t + 0.013, y - 0.021]);
                n.push([0.0, 1.0]);
            }
            t += step;
        }
        y += ry;
    }
    let mut rng = Rng::new(7);
    for _ in 0..(w * h / 4.0) as usize {
        p.push([rng.range(0.0, w), rng.range(0.0, h)]);
        n.push([rng.normal(), rng.normal()]);
    }
    (p, n)
}

/// The index as the Python API builds it: k-d tree and closest-point grid at 2 cm.
fn with_grid(p: &[[f64; 2]], n: &[[f64; 2]]) -> MapIndex {
    MapIndex::new(p.to_vec(), Some(n.to_vec()))
        .unwrap()
        .with_cache(Some(DEFAULT_CACHE_RESOLUTION))
        .unwrap()
}

fn bench_build(c: &mut Criterion) {
    for (name, (w, h)) in [
        ("building_52m", (52.0, 52.0)),
        ("wing_20x12m", (20.0, 12.0)),
    ] {
        let (p, n) = building(w, h, 4.0, 5.0);
        let idx = with_grid(&p, &n);
        println!(
            "{name}: {} points, {} tiles of the closest-point grid ({} MB)",
            p.len(),
            idx.cache_tiles(),
            idx.cache_bytes() >> 20
        );
        let mut g = c.benchmark_group(format!("map_index_build_{name}"));
        g.sample_size(10);
        g.bench_function("kdtree", |b| {
            b.iter(|| black_box(MapIndex::new(p.clone(), Some(n.clone())).unwrap()))
        });
        g.bench_function("kdtree+grid_2cm", |b| {
            b.iter(|| black_box(with_grid(&p, &n)))
        });
        let (values, lengths) = runs::encode(&idx.cache_cells().expect("a grid"));
        println!(
            "{name}: {} runs of {} cells",
            values.len(),
            idx.cache_cells().map_or(0, |c| c.len())
        );
        g.bench_function("kdtree+grid_from_runs", |b| {
            b.iter(|| {
                let cells = runs::decode(&values, &lengths, MAX_CACHE_CELLS).unwrap();
                black_box(
                    MapIndex::new(p.clone(), Some(n.clone()))
                        .unwrap()
                        .with_cache_cells(DEFAULT_CACHE_RESOLUTION, cells)
                        .unwrap(),
                )
            })
        });
        // what a cached map's load does: the runs decoded block by block on first use
        g.bench_function("kdtree+grid_lazy_runs", |b| {
            b.iter(|| {
                black_box(
                    MapIndex::new(p.clone(), Some(n.clone()))
                        .unwrap()
                        .with_cache_runs(DEFAULT_CACHE_RESOLUTION, values.clone(), &lengths)
                        .unwrap(),
                )
            })
        });
        g.finish();
    }
}

/// Two office wings 1 km apart: the grid's box holds far more tiles than the grid, so its
/// cells are filled tile by tile (`ClosestGrid::fill`), not as a box.
fn bench_sparse(c: &mut Criterion) {
    let (mut p, mut n) = building(20.0, 12.0, 4.0, 5.0);
    let (p2, n2) = building(20.0, 12.0, 4.0, 5.0);
    p.extend(p2.iter().map(|q| [q[0] + 1000.0, q[1]]));
    n.extend(n2);
    let idx = with_grid(&p, &n);
    println!(
        "two_wings_1km_apart: {} points, {} tiles of the closest-point grid",
        p.len(),
        idx.cache_tiles()
    );
    let mut g = c.benchmark_group("map_index_build_two_wings_1km_apart");
    g.sample_size(10);
    g.bench_function("kdtree+grid_2cm", |b| {
        b.iter(|| black_box(with_grid(&p, &n)))
    });
    g.finish();
}

criterion_group!(benches, bench_build, bench_sparse);
criterion_main!(benches);
