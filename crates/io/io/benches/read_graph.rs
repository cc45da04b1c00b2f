//! Reading and writing city10000 (10k vertices, 20687 edges): the I/O share of the whole-process
//! comparison with GTSAM.
//!
//! `cargo bench -p mapmerge-io --bench read_graph`

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use mapmerge_io::{format_graph, parse_graph, read_graph, GraphFormat};

fn city10000(c: &mut Criterion) {
    let Some(path) = mapmerge_testkit::shared_data("g2o/se-sync/city10000.g2o.xz") else {
        return;
    };
    let loaded = match read_graph(&path) {
        Ok(loaded) => loaded,
        Err(err) => panic!("{err}"),
    };
    let text = match format_graph(&loaded.graph, GraphFormat::G2o) {
        Ok(text) => text,
        Err(err) => panic!("{err}"),
    };
    c.bench_function("read_city10000_xz", |b| {
        b.iter(|| read_graph(black_box(&path)))
    });
    c.bench_function("parse_city10000", |b| {
        b.iter(|| parse_graph(black_box(&text), "city10000.g2o"))
    });
    c.bench_function("format_city10000", |b| {
        b.iter(|| format_graph(black_box(&loaded.graph), GraphFormat::G2o))
    });
}

criterion_group!(benches, city10000);
criterion_main!(benches);
