//! Mean time per new vertex of the detectors on a synthetic merged map: an office floor of
//! 6 × 4 rooms (5 × 5 m, doors, furniture), 360-beam scans; the other epoch's 300 scans tour
//! the floor, the current epoch walks through it after a correct merge, and every iteration
//! is one new vertex with n = 10 recent scans (the detectors' caches work as in a live run).
//!
//! `cargo bench -p mapmerge-verify --bench detectors` (one core: `taskset -c 0`).

use std::hint::black_box;
use std::sync::Arc;
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, Criterion};
use mapmerge_geometry::Se2;
use mapmerge_posegraph::NodeId;
use mapmerge_scan::Point2;
use mapmerge_verify::{detector, DetectorScan, MergedMap};

type Wall = (Point2, Point2);

fn office_floor() -> Vec<Wall> {
    let mut walls = Vec::new();
    let mut wall = |x0: f64, y0: f64, x1: f64, y1: f64| {
        walls.push((Point2::new(x0, y0), Point2::new(x1, y1)));
    };
    let (nx, ny, size) = (6, 4, 5.0);
    for i in 0..=nx {
        let x = i as f64 * size;
        for j in 0..ny {
            let y = j as f64 * size;
            if i == 0 || i == nx {
                wall(x, y, x, y + size);
            } else {
                // A door of 1 m in every inner wall.
                wall(x, y, x, y + 2.0);
                wall(x, y + 3.0, x, y + size);
            }
        }
    }
    for j in 0..=ny {
        let y = j as f64 * size;
        for i in 0..nx {
            let x = i as f64 * size;
            if j == 0 || j == ny {
                wall(x, y, x + size, y);
            } else {
                wall(x, y, x + 2.0, y);
                wall(x + 3.0, y, x + size, y);
            }
        }
    }
    // Furniture: one box per room, placed differently in each.
    for i in 0..nx {
        for j in 0..ny {
            let (x, y) = (
                i as f64 * size + 0.8 + 0.3 * ((i * 7 + j * 3) % 5) as f64,
                j as f64 * size + 0.7 + 0.25 * ((i + j * 5) % 4) as f64,
            );
            wall(x, y, x + 0.8, y);
            wall(x + 0.8, y, x + 0.8, y + 0.5);
            wall(x + 0.8, y + 0.5, x, y + 0.5);
            wall(x, y + 0.5, x, y);
        }
    }
    walls
}

fn scan(walls: &[Wall], pose: &Se2, beams: usize) -> Vec<Point2> {
    let origin = Point2::new(pose.x_m, pose.y_m);
    let mut out = Vec::with_capacity(beams);
    for i in 0..beams {
        let a = -std::f64::consts::PI + i as f64 * std::f64::consts::TAU / beams as f64;
        let d = Point2::new((pose.theta_rad + a).cos(), (pose.theta_rad + a).sin());
        let mut best = f64::INFINITY;
        for (a0, a1) in walls {
            let e = a1 - a0;
            let denom = -d.x * e.y + d.y * e.x;
            if denom.abs() < 1e-12 {
                continue;
            }
            let rhs = a0 - origin;
            let t = (-rhs.x * e.y + rhs.y * e.x) / denom;
            let u = (d.x * rhs.y - d.y * rhs.x) / denom;
            if t > 1e-6 && (0.0..=1.0).contains(&u) && t < best {
                best = t;
            }
        }
        if best <= 20.0 {
            out.push(Point2::new(a.cos() * best, a.sin() * best));
        }
    }
    out
}

/// A tour of the rooms through the doors: room centres in a snake, `per_leg` poses a leg.
fn tour(per_leg: usize, offset: f64) -> Vec<Se2> {
    let mut centres = Vec::new();
    for j in 0..4 {
        for i in 0..6 {
            let i = if j % 2 == 0 { i } else { 5 - i };
            centres.push(Point2::new(
                i as f64 * 5.0 + 2.5,
                j as f64 * 5.0 + 2.5 + offset,
            ));
        }
    }
    let mut poses = Vec::new();
    for pair in centres.windows(2) {
        let (a, b) = (pair[0], pair[1]);
        let heading = (b - a).y.atan2((b - a).x);
        for k in 0..per_leg {
            let p = a + (b - a) * (k as f64 / per_leg as f64);
            poses.push(Se2::new(p.x, p.y, heading + 0.1 * (k as f64).sin()));
        }
    }
    poses
}

fn scans(walls: &[Wall], poses: &[Se2], epoch: u32, first: u64) -> Vec<DetectorScan> {
    poses
        .iter()
        .enumerate()
        .map(|(i, pose)| DetectorScan {
            node: NodeId(first + i as u64),
            epoch,
            map_from_robot: *pose,
            points_in_robot: Arc::from(scan(walls, pose, 360)),
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let walls = office_floor();
    let other = scans(&walls, &tour(13, -0.6), 1, 0); // 299 scans
    let current = scans(&walls, &tour(6, 0.6), 2, 10_000); // 138 scans
    let mut group = c.benchmark_group("detectors_office_299_other_scans");
    group
        .sample_size(20)
        .measurement_time(Duration::from_secs(8));
    for name in [
        "change_detection",
        "gridmap",
        "histogram",
        "entropy",
        "sm",
        "dm",
    ] {
        group.bench_function(format!("{name}_per_vertex"), |b| {
            b.iter_custom(|iters| {
                let Some(mut d) = detector(name) else {
                    return Duration::ZERO;
                };
                let start_at = 10;
                d.on_merge(&MergedMap {
                    current: &current[..start_at],
                    other: &other,
                });
                let mut k = start_at;
                let mut total = Duration::ZERO;
                for _ in 0..iters {
                    if k >= current.len() {
                        k = start_at;
                        d.on_merge(&MergedMap {
                            current: &current[..k],
                            other: &other,
                        });
                    }
                    k += 1;
                    let map = MergedMap {
                        current: &current[..k],
                        other: &other,
                    };
                    let t = Instant::now();
                    black_box(d.on_vertex(&map));
                    total += t.elapsed();
                }
                total
            });
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
