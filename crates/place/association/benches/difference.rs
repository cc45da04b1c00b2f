//! Difference matrix (blocked f32 product) and sequence matching on one segment pair of the
//! scale benchmark's size: 2000 × 2000 submaps, 256-dimensional descriptors. Criterion reports
//! elements/s = FLOP/s for the product (2 · rows · cols · dim per matrix).
//!
//! cargo bench -p mapmerge-association --bench difference

#![allow(clippy::unwrap_used, clippy::expect_used)]

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use mapmerge_association::{
    difference_matrix_into, sequence_matches, single_frame_matches, DescriptorMatrix,
    DifferenceMatrix, SequenceParams, SingleFrameParams,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

fn descriptors(rng: &mut ChaCha8Rng, rows: usize, dim: usize) -> DescriptorMatrix {
    let data = (0..rows * dim)
        .map(|_| rng.random_range(-1.0f32..1.0))
        .collect();
    DescriptorMatrix::new(dim, data).unwrap()
}

fn difference_2000x2000x256(c: &mut Criterion) {
    let (rows, cols, dim) = (2000, 2000, 256);
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let a = descriptors(&mut rng, rows, dim);
    let b = descriptors(&mut rng, cols, dim);
    let mut d = DifferenceMatrix::empty();
    let mut group = c.benchmark_group("association_2000x2000x256");
    group.sample_size(20);
    group.throughput(Throughput::Elements((2 * rows * cols * dim) as u64));
    group.bench_function("difference_matrix", |bench| {
        bench.iter(|| difference_matrix_into(&mut d, black_box(&a), black_box(&b)).unwrap())
    });
    difference_matrix_into(&mut d, &a, &b).unwrap();
    group.throughput(Throughput::Elements((rows * cols) as u64));
    let sequence = SequenceParams::default();
    group.bench_function("sequence_matches", |bench| {
        bench.iter(|| sequence_matches(black_box(&d), &sequence).unwrap())
    });
    let single = SingleFrameParams::default();
    group.bench_function("single_frame_matches", |bench| {
        bench.iter(|| single_frame_matches(black_box(&d), &single).unwrap())
    });
    group.finish();
}

criterion_group!(benches, difference_2000x2000x256);
criterion_main!(benches);
