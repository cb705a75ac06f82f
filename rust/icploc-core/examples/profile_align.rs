//! A loop of default `align()` calls over one family's cases, in the benchmark's order
//! (each case once per pass, so each call starts with caches holding the previous
//! case's part of the map), for a profiler:
//! `cargo run --release --example profile_align -- clinic small 20` (family, start, passes).
//! Prints the median and p95 of each case's fastest pass and the cache's size.
use std::hint::black_box;
use std::time::{Duration, Instant};

use icploc_core::index::DEFAULT_CACHE_RESOLUTION;
use icploc_core::testkit::{all_worlds, sample_segments, unseen_worlds, world_cases};
use icploc_core::{align, IcpConfig, MapIndex};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let family = args.get(1).map_or("clinic", |s| s.as_str());
    let start = args.get(2).map_or("small", |s| s.as_str());
    let passes: usize = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(20);
    let err = if start == "large" {
        (1.0, 0.5, 25f64.to_radians())
    } else {
        (0.3, 0.3, 10f64.to_radians())
    };
    let w = all_worlds()
        .into_iter()
        .chain(unseen_worlds())
        .find(|w| w.name == family)
        .expect("a family name");
    let (p, nrm) = sample_segments(&w.map_segments(), 0.025);
    let idx = MapIndex::new(p, Some(nrm))
        .unwrap()
        .with_cache(Some(DEFAULT_CACHE_RESOLUTION))
        .unwrap();
    idx.likelihood_field().expect("the map fits the window grid");
    idx.objects();
    let mut cfg = IcpConfig::default();
    // PLAIN=1: the plain ICP alone (no verified start)
    cfg.window_search = std::env::var_os("PLAIN").is_none();
    let cs = world_cases(&w, 200, err, 7);
    let mut times = vec![Duration::MAX; cs.len()];
    for _ in 0..passes {
        for (k, c) in cs.iter().enumerate() {
            let t0 = Instant::now();
            black_box(align(&c.scan, &idx, c.initial, &cfg).unwrap());
            times[k] = times[k].min(t0.elapsed());
        }
    }
    times.sort();
    println!(
        "{family} {start}: {} map points, grid {} KB in {} tiles; median {:?}, p95 {:?}",
        idx.len(),
        idx.cache_bytes() / 1024,
        idx.cache_tiles(),
        times[times.len() / 2],
        times[times.len() * 95 / 100]
    );
}
