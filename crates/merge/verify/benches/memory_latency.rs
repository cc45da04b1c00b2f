//! The machine's memory latency, the yardstick for the detectors' times: gridmap's per-vertex
//! update is bound by loads of cells scattered over a grid of tens of MB, so its time scales
//! with this latency, not with the CPU clock.
//!
//! Dependent loads through one random cycle over working sets of 1–64 MB (each load's address
//! is the previous load's value, so no two overlap): the mean time per load is the latency of
//! the level of the memory hierarchy the set fits in.
//!
//! `cargo bench -p mapmerge-verify --bench memory_latency` (one core: `taskset -c 0`).

use std::hint::black_box;
use std::time::Instant;

/// A random cyclic permutation of `0..len` (Sattolo's algorithm, xorshift64).
fn random_cycle(len: usize) -> Vec<u32> {
    let mut next: Vec<u32> = (0..len as u32).collect();
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    for i in (1..len).rev() {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        let j = (state % i as u64) as usize;
        next.swap(i, j);
    }
    next
}

fn main() {
    const LOADS: usize = 2_000_000;
    println!("| working set | ns per dependent load |");
    println!("|---|---|");
    for megabytes in [1usize, 4, 16, 64] {
        let next = random_cycle(megabytes * (1 << 20) / std::mem::size_of::<u32>());
        let mut at = 0u32;
        // One pass to warm caches and TLBs as far as they go.
        for _ in 0..LOADS / 4 {
            at = next[at as usize];
        }
        let started = Instant::now();
        for _ in 0..LOADS {
            at = next[at as usize];
        }
        let ns = started.elapsed().as_secs_f64() * 1e9 / LOADS as f64;
        black_box(at);
        println!("| {megabytes} MB | {ns:.1} |");
    }
}
