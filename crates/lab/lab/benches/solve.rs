//! Criterion benchmarks of the optimizer on real graphs from `../shared/data` (skipped, with a
//! message, when the data folder is absent).
//!
//! `cargo bench -p mapmerge-lab --bench solve`

use criterion::{criterion_group, criterion_main, Criterion};
use mapmerge_io::{read_graph, AnyGraph};
use mapmerge_solve::{optimize, optimize_gnc, GncParams, OptimizerParams};

fn load(relative: &str) -> Option<AnyGraph> {
    let path = mapmerge_testkit::shared_data(&format!("g2o/{relative}"))?;
    match read_graph(&path) {
        Ok(loaded) => Some(loaded.graph),
        Err(err) => {
            eprintln!("skipping {relative}: {err}");
            None
        }
    }
}

fn bench_graph(c: &mut Criterion, name: &str, relative: &str) {
    let Some(graph) = load(relative) else { return };
    let params = OptimizerParams::default();
    c.bench_function(name, |b| match &graph {
        AnyGraph::Planar(g) => b.iter(|| {
            let mut g = g.clone();
            optimize(&mut g, &params)
        }),
        AnyGraph::Spatial(g) => b.iter(|| {
            let mut g = g.clone();
            optimize(&mut g, &params)
        }),
    });
}

fn solve_benches(c: &mut Criterion) {
    bench_graph(c, "solve_intel_943", "openslam_g2o/intel.g2o");
    bench_graph(c, "solve_m3500", "openslam_g2o/manhattanOlson3500.g2o");
    bench_graph(c, "solve_city10000", "se-sync/city10000.g2o.xz");
    bench_graph(c, "solve_sphere2500", "se-sync/sphere2500.g2o.xz");
    if let Some(AnyGraph::Planar(g)) = load("openslam_g2o/manhattanOlson3500.g2o") {
        c.bench_function("gnc_m3500_clean", |b| {
            b.iter(|| {
                let mut g = g.clone();
                optimize_gnc(&mut g, &GncParams::default())
            })
        });
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10);
    targets = solve_benches
}
criterion_main!(benches);
