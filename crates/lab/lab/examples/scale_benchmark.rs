//! Scale benchmark of segment-to-segment association on synthetic descriptors with planted
//! overlaps: N segments × M submaps × dim-dimensional unit descriptors; segment `s` shares a
//! 100–300 submap stretch (noisy copies, velocity 0.9–1.1, a third reversed) with segment
//! `s + 1` (cyclically), so every segment overlaps two others.
//!
//! Measures (a) full offline association (every pair: difference matrix, sequence matches,
//! single-frame matches, k-means zones + RANSAC with Eq. 7), (b) incremental association of the last segment against all others,
//! (c) with `--curve`, both for n = 5, 10, 20, 50 segments; and the recall of planted submap
//! pairs (a match with the same query and a reference within ±2) and the false matches (no
//! planted pair within ±1 query and ±2 reference submaps).
//!
//! cargo run --release -p mapmerge-lab --example scale_benchmark -- \
//!     [--segments 50] [--submaps 2000] [--dim 256] [--seed 7] [--noise 1.5] \
//!     [--parallel pairs|within] [--curve] [--no-zones] [--json] [--velocity-steps K]
//!     [--velocity-phases P]

use mapmerge_association::{
    difference_matrix_into, sequence_matches, single_frame_matches, verify_zones, DescriptorMatrix,
    DifferenceMatrix, SequenceParams, SingleFrameParams, SubmapMatch, ZoneParams,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Parallel {
    /// rayon over pairs (each pair's stages also use rayon when threads are idle).
    Pairs,
    /// pairs one after the other, each stage parallel inside.
    Within,
}

#[derive(Clone, Debug)]
struct Args {
    segments: usize,
    submaps: usize,
    dim: usize,
    seed: u64,
    noise: f32,
    parallel: Parallel,
    curve: bool,
    /// Stop after the candidates (no zones + RANSAC): the matchers' own recall.
    no_zones: bool,
    json: bool,
    /// Overrides of `SequenceParams::velocity_steps` / `velocity_phases`.
    velocity_steps: Option<usize>,
    velocity_phases: Option<usize>,
}

fn parse_args() -> Result<Args, String> {
    let mut args = Args {
        segments: 50,
        submaps: 2000,
        dim: 256,
        seed: 7,
        noise: 1.5,
        parallel: Parallel::Pairs,
        curve: false,
        no_zones: false,
        json: false,
        velocity_steps: None,
        velocity_phases: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or(format!("{flag} needs a value"));
        match flag.as_str() {
            "--segments" => args.segments = value()?.parse().map_err(|e| format!("{e}"))?,
            "--submaps" => args.submaps = value()?.parse().map_err(|e| format!("{e}"))?,
            "--dim" => args.dim = value()?.parse().map_err(|e| format!("{e}"))?,
            "--seed" => args.seed = value()?.parse().map_err(|e| format!("{e}"))?,
            "--noise" => args.noise = value()?.parse().map_err(|e| format!("{e}"))?,
            "--parallel" => {
                args.parallel = match value()?.as_str() {
                    "pairs" => Parallel::Pairs,
                    "within" => Parallel::Within,
                    other => return Err(format!("--parallel pairs|within, not {other}")),
                }
            }
            "--velocity-steps" => {
                args.velocity_steps = Some(value()?.parse().map_err(|e| format!("{e}"))?)
            }
            "--velocity-phases" => {
                args.velocity_phases = Some(value()?.parse().map_err(|e| format!("{e}"))?)
            }
            "--curve" => args.curve = true,
            "--no-zones" => args.no_zones = true,
            "--json" => args.json = true,
            "-h" | "--help" => {
                return Err(
                    "usage: scale_benchmark [--segments N] [--submaps M] [--dim D] \
                            [--seed S] [--noise SIGMA] [--parallel pairs|within] [--curve] \
                            [--json] [--velocity-steps K] [--velocity-phases P]"
                        .into(),
                )
            }
            other => return Err(format!("unknown argument {other}")),
        }
    }
    if args.segments < 2 || args.submaps < 40 || args.dim == 0 {
        return Err("need --segments ≥ 2, --submaps ≥ 40, --dim ≥ 1".into());
    }
    Ok(args)
}

fn gaussian(rng: &mut impl Rng) -> f32 {
    let u1: f32 = rng.random_range(f32::EPSILON..1.0);
    let u2: f32 = rng.random_range(0.0..1.0);
    (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos()
}

/// Synthetic segments and the planted correspondences of every overlapping pair.
struct World {
    segments: Vec<DescriptorMatrix>,
    /// For pair `(lo, hi)`, lo < hi: `(submap in lo, submap in hi)`.
    planted: std::collections::BTreeMap<(usize, usize), Vec<(usize, usize)>>,
}

fn make_world(args: &Args) -> Result<World, String> {
    let (n, m, dim) = (args.segments, args.submaps, args.dim);
    // Random unit-direction rows (normalised by DescriptorMatrix::new), one RNG per segment.
    let mut data: Vec<Vec<f32>> = (0..n)
        .into_par_iter()
        .map(|s| {
            let mut rng = ChaCha8Rng::seed_from_u64(args.seed ^ (s as u64).wrapping_mul(0x9E37));
            (0..m * dim).map(|_| gaussian(&mut rng)).collect()
        })
        .collect();
    let normalise = |row: &mut [f32]| {
        let norm = row
            .iter()
            .map(|x| x * x)
            .sum::<f32>()
            .sqrt()
            .max(f32::MIN_POSITIVE);
        row.iter_mut().for_each(|x| *x /= norm);
    };
    for segment in &mut data {
        segment.chunks_exact_mut(dim).for_each(normalise);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed);
    let mut planted = std::collections::BTreeMap::new();
    let (len_min, len_max) = ((m / 20).clamp(5, 100), (m * 3 / 20).clamp(10, 300));
    let noise_per_component = args.noise / (dim as f32).sqrt();
    for s in 0..n {
        let t = (s + 1) % n;
        let len = rng.random_range(len_min..=len_max);
        let velocity = [0.9f32, 1.0, 1.1][rng.random_range(0..3)];
        let reversed = rng.random_range(0..3) == 0;
        // Source in the first half of s, copy in the second half of t: stretches never collide.
        let source_span = ((len as f32 - 1.0) * velocity).ceil() as usize + 1;
        let a0 = rng.random_range(0..m / 2 - source_span);
        let b0 = rng.random_range(m / 2..m - len);
        for k in 0..len {
            let a = a0 + (k as f32 * velocity).round() as usize;
            let b = if reversed { b0 + len - 1 - k } else { b0 + k };
            let mut copy: Vec<f32> = data[s][a * dim..(a + 1) * dim]
                .iter()
                .map(|&x| x + noise_per_component * gaussian(&mut rng))
                .collect();
            normalise(&mut copy);
            data[t][b * dim..(b + 1) * dim].copy_from_slice(&copy);
            let (key, pair) = if s < t {
                ((s, t), (a, b))
            } else {
                ((t, s), (b, a))
            };
            planted.entry(key).or_insert_with(Vec::new).push(pair);
        }
    }
    let segments = data
        .into_iter()
        .map(|d| DescriptorMatrix::new(dim, d).map_err(|e| e.to_string()))
        .collect::<Result<_, _>>()?;
    Ok(World { segments, planted })
}

/// CPU time per stage, summed over threads, in nanoseconds.
#[derive(Default)]
struct StageTimes {
    difference: AtomicU64,
    sequence: AtomicU64,
    single: AtomicU64,
    zones: AtomicU64,
}

struct Params {
    sequence: SequenceParams,
    single: SingleFrameParams,
    /// `None`: no zones + RANSAC stage (`--no-zones`).
    zones: Option<ZoneParams>,
}

fn associate_pair(
    d: &mut DifferenceMatrix,
    world: &World,
    (x, y): (usize, usize),
    params: &Params,
    times: &StageTimes,
) -> Result<Vec<SubmapMatch>, String> {
    let nanos = |a: Instant, b: Instant| (b - a).as_nanos() as u64;
    let t0 = Instant::now();
    difference_matrix_into(d, &world.segments[x], &world.segments[y]).map_err(|e| e.to_string())?;
    let t1 = Instant::now();
    let mut matches = sequence_matches(d, &params.sequence).map_err(|e| e.to_string())?;
    let t2 = Instant::now();
    matches.extend(single_frame_matches(d, &params.single).map_err(|e| e.to_string())?);
    let t3 = Instant::now();
    // Zones + RANSAC (Eq. 7) on the candidates; submaps 1 m apart along each segment's own
    // straight path, so the planted overlaps are length-consistent.
    let along = |n: usize| -> Vec<[f64; 3]> { (0..n).map(|k| [k as f64, 0.0, 0.0]).collect() };
    let matches = match &params.zones {
        None => matches,
        Some(zone_params) => {
            verify_zones(
                &matches,
                &along(world.segments[x].rows()),
                &along(world.segments[y].rows()),
                zone_params,
            )
            .map_err(|e| e.to_string())?
            .inliers
        }
    };
    let t4 = Instant::now();
    times.zones.fetch_add(nanos(t3, t4), Ordering::Relaxed);
    times.difference.fetch_add(nanos(t0, t1), Ordering::Relaxed);
    times.sequence.fetch_add(nanos(t1, t2), Ordering::Relaxed);
    times.single.fetch_add(nanos(t2, t3), Ordering::Relaxed);
    Ok(matches)
}

/// CPU seconds of this process so far (user + system, from /proc/self/stat; 0 elsewhere).
fn process_cpu_s() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else {
        return 0.0;
    };
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let Some(rest) = stat.rsplit_once(')').map(|(_, r)| r) else {
        return 0.0;
    };
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |k: usize| {
        fields
            .get(k)
            .and_then(|f| f.parse::<f64>().ok())
            .unwrap_or(0.0)
    };
    (ticks(11) + ticks(12)) / 100.0 // USER_HZ = 100 on Linux
}

/// Associates every listed pair; returns the matches per pair and the wall time.
fn associate(
    world: &World,
    pairs: &[(usize, usize)],
    params: &Params,
    parallel: Parallel,
    times: &StageTimes,
) -> Result<(Vec<Vec<SubmapMatch>>, f64), String> {
    let start = Instant::now();
    let matches = match parallel {
        Parallel::Pairs => pairs
            .par_iter()
            .map_init(DifferenceMatrix::empty, |d, &pair| {
                associate_pair(d, world, pair, params, times)
            })
            .collect::<Result<Vec<_>, _>>()?,
        Parallel::Within => {
            let mut d = DifferenceMatrix::empty();
            pairs
                .iter()
                .map(|&pair| associate_pair(&mut d, world, pair, params, times))
                .collect::<Result<Vec<_>, _>>()?
        }
    };
    Ok((matches, start.elapsed().as_secs_f64()))
}

#[derive(Default, Clone, Copy)]
struct Score {
    planted: usize,
    recovered: usize,
    matches: usize,
    false_matches: usize,
    /// False matches within 5 submaps of a planted pair on both sides: a stretch's end overrun.
    false_near: usize,
}

fn score(
    world: &World,
    submaps: usize,
    pairs: &[(usize, usize)],
    matches: &[Vec<SubmapMatch>],
) -> Score {
    let mut total = Score::default();
    for (pair, found) in pairs.iter().zip(matches) {
        let truth = world.planted.get(pair).map(Vec::as_slice).unwrap_or(&[]);
        let mut partners = vec![Vec::new(); submaps];
        for &(a, b) in truth {
            partners[a].push(b);
        }
        let near = |m: &SubmapMatch, b: usize| b.abs_diff(m.reference) <= 2;
        total.planted += truth.len();
        total.recovered += truth
            .iter()
            .filter(|&&(a, b)| found.iter().any(|m| m.query == a && near(m, b)))
            .count();
        total.matches += found.len();
        // True: a planted pair within ±1 query and ±2 reference submaps (at velocity 1.1 some
        // query submaps have no planted partner of their own).
        let is_true = |m: &SubmapMatch| {
            (m.query.saturating_sub(1)..=(m.query + 1).min(submaps - 1))
                .any(|a| partners[a].iter().any(|&b| near(m, b)))
        };
        let false_matches: Vec<&SubmapMatch> = found.iter().filter(|m| !is_true(m)).collect();
        total.false_matches += false_matches.len();
        total.false_near += false_matches
            .iter()
            .filter(|m| {
                truth
                    .iter()
                    .any(|&(a, b)| a.abs_diff(m.query) <= 5 && b.abs_diff(m.reference) <= 5)
            })
            .count();
        if std::env::var_os("SHOW_FALSE").is_some() {
            for m in &false_matches {
                eprintln!("false match in pair {pair:?}: {m:?}");
            }
        }
    }
    total
}

struct Row {
    segments: usize,
    pairs: usize,
    offline_s: f64,
    offline_cpu_s: f64,
    incremental_s: f64,
    incremental_cpu_s: f64,
    offline: Score,
    gflops: f64,
}

fn run(world: &World, n: usize, args: &Args, params: &Params) -> Result<(Row, StageTimes), String> {
    let offline_pairs: Vec<(usize, usize)> = (0..n)
        .flat_map(|x| (x + 1..n).map(move |y| (x, y)))
        .collect();
    let times = StageTimes::default();
    let cpu0 = process_cpu_s();
    let (matches, offline_s) = associate(world, &offline_pairs, params, args.parallel, &times)?;
    let offline_cpu_s = process_cpu_s() - cpu0;
    let offline = score(world, args.submaps, &offline_pairs, &matches);
    // Incremental: the last segment arrives; against every other one.
    let new_pairs: Vec<(usize, usize)> = (0..n - 1).map(|x| (x, n - 1)).collect();
    let cpu0 = process_cpu_s();
    let (_, incremental_s) = associate(
        world,
        &new_pairs,
        params,
        args.parallel,
        &StageTimes::default(),
    )?;
    let incremental_cpu_s = process_cpu_s() - cpu0;
    let flop = 2.0 * (args.submaps * args.submaps * args.dim) as f64 * offline_pairs.len() as f64;
    let difference_cpu_s = times.difference.load(Ordering::Relaxed) as f64 * 1e-9;
    // Stage times are per call: calls overlap across threads with rayon over pairs.
    let threads = match args.parallel {
        Parallel::Pairs => rayon::current_num_threads() as f64,
        Parallel::Within => 1.0,
    };
    let row = Row {
        segments: n,
        pairs: offline_pairs.len(),
        offline_s,
        offline_cpu_s,
        incremental_s,
        incremental_cpu_s,
        offline,
        gflops: flop / (difference_cpu_s / threads) * 1e-9,
    };
    Ok((row, times))
}

fn main() {
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(2);
        }
    };
    if let Err(e) = bench(&args) {
        eprintln!("scale_benchmark: {e}");
        std::process::exit(1);
    }
}

fn bench(args: &Args) -> Result<(), String> {
    let t = Instant::now();
    let world = make_world(args)?;
    eprintln!(
        "generated {} segments × {} submaps × {} dims in {:.1} s ({} threads)",
        args.segments,
        args.submaps,
        args.dim,
        t.elapsed().as_secs_f64(),
        rayon::current_num_threads()
    );
    let mut params = Params {
        sequence: SequenceParams::default(),
        single: SingleFrameParams::default(),
        zones: (!args.no_zones).then(ZoneParams::default),
    };
    if let Some(steps) = args.velocity_steps {
        params.sequence.velocity_steps = steps;
    }
    if let Some(phases) = args.velocity_phases {
        params.sequence.velocity_phases = phases;
    }
    let sizes: Vec<usize> = if args.curve {
        let mut s: Vec<usize> = [5, 10, 20, 50]
            .into_iter()
            .filter(|&n| n < args.segments)
            .collect();
        s.push(args.segments);
        s
    } else {
        vec![args.segments]
    };
    let mut rows = Vec::new();
    for &n in &sizes {
        let (row, times) = run(&world, n, args, &params)?;
        let cpu = |a: &AtomicU64| a.load(Ordering::Relaxed) as f64 * 1e-9;
        eprintln!(
            "n = {n}: offline {:.2} s, incremental {:.2} s; CPU s: difference {:.1}, sequence {:.1}, single {:.1}, zones {:.1}",
            row.offline_s,
            row.incremental_s,
            cpu(&times.difference),
            cpu(&times.sequence),
            cpu(&times.single),
            cpu(&times.zones)
        );
        rows.push(row);
    }
    if args.json {
        let items: Vec<String> = rows
            .iter()
            .map(|r| {
                format!(
                    "{{\"segments\":{},\"submaps\":{},\"dim\":{},\"pairs\":{},\"offline_s\":{:.3},\
                     \"offline_cpu_s\":{:.2},\"incremental_s\":{:.3},\"incremental_cpu_s\":{:.2},\"difference_gflops\":{:.1},\"planted\":{},\
                     \"recovered\":{},\"recall\":{:.4},\"matches\":{},\"false_matches\":{},\"false_near_planted\":{}}}",
                    r.segments,
                    args.submaps,
                    args.dim,
                    r.pairs,
                    r.offline_s,
                    r.offline_cpu_s,
                    r.incremental_s,
                    r.incremental_cpu_s,
                    r.gflops,
                    r.offline.planted,
                    r.offline.recovered,
                    r.offline.recovered as f64 / r.offline.planted.max(1) as f64,
                    r.offline.matches,
                    r.offline.false_matches,
                    r.offline.false_near
                )
            })
            .collect();
        println!("[{}]", items.join(","));
    } else {
        println!(
            "| segments | submaps | dim | pairs | offline wall (s) | offline CPU (s) | one new vs rest wall (s) | one new CPU (s) | CPU ms / pair | difference GFLOP/s | recall | matches | false (near a planted end) |"
        );
        println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
        for r in &rows {
            println!(
                "| {} | {} | {} | {} | {:.2} | {:.1} | {:.2} | {:.1} | {:.1} | {:.0} | {:.3} ({}/{}) | {} | {} ({}) |",
                r.segments,
                args.submaps,
                args.dim,
                r.pairs,
                r.offline_s,
                r.offline_cpu_s,
                r.incremental_s,
                r.incremental_cpu_s,
                1e3 * r.offline_cpu_s / r.pairs as f64,
                r.gflops,
                r.offline.recovered as f64 / r.offline.planted.max(1) as f64,
                r.offline.recovered,
                r.offline.planted,
                r.offline.matches,
                r.offline.false_matches,
                r.offline.false_near
            );
        }
    }
    Ok(())
}
