//! `match_grids` on two 1000 × 1000-cell crops (50 m at 0.05 m) of UT Austin GDC floor 1,
//! B turned by 37° and shifted (about half overlap); `map_metrics` on the same pair.
//!
//! `cargo bench -p mapmerge-gridmatch`

use criterion::{criterion_group, criterion_main, Criterion};
use mapmerge_gridmatch::{map_metrics, match_grids, GridMatchParams};

#[path = "../tests/common/crops.rs"]
mod crops;

fn bench(c: &mut Criterion) {
    let Some(path) = mapmerge_testkit::shared_data("gridmaps/utexas-gdc-1/1.yaml") else {
        return;
    };
    let Some(map) = crops::read_map(&path) else {
        eprintln!("cannot read {}", path.display());
        return;
    };
    let (a, b, truth) = crops::pair_1000(&map);
    let params = GridMatchParams::default();
    let mut group = c.benchmark_group("gridmatch");
    group.sample_size(20);
    group.bench_function("match_grids_utexas_1000x1000", |bench| {
        bench.iter(|| match_grids(&a, &b, &params))
    });
    group.bench_function("map_metrics_utexas_1000x1000", |bench| {
        bench.iter(|| map_metrics(&a, &b, &truth, &params.thresholds))
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
