//! The doorways seen around each true door passing of one simulated session, with their
//! bearing, range, width and distance from the true door; or, with a scan index, that scan's
//! beams in the world frame. For looking at what door detection sees.
//!
//!     cargo run --release -p mapmerge-lab --example trace_doors -- [WORLD] [SEED] [SCAN]
#![allow(clippy::unwrap_used, clippy::expect_used)]
use mapmerge_areas::{passways, DoorParams};
use mapmerge_sim::{simulate, SimParams};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let world = args.get(1).cloned().unwrap_or("office".into());
    let seed: u64 = args.get(2).map(|s| s.parse().unwrap()).unwrap_or(1);
    let sim = SimParams::default()
        .with_preset_name(&world)
        .unwrap()
        .with_sessions(1)
        .with_duration_secs(120.0);
    let data = simulate(&sim, seed).unwrap();
    let s = &data.sessions[0];
    let params = DoorParams::default();
    if let Some(scan_index) = args.get(3).map(|s| s.parse::<usize>().unwrap()) {
        let (_, truth) = s.truth[scan_index];
        println!("truth {:?}", truth);
        let scan = &s.log.scans[scan_index].scan;
        for (i, r) in scan.ranges_m.iter().enumerate() {
            let a = scan.beam_angle_rad(i);
            let p = truth.transform_point(&mapmerge_scan::Point2::new(
                f64::from(*r) * a.cos(),
                f64::from(*r) * a.sin(),
            ));
            println!(
                "{i} {:.0}° {:.2} -> ({:.2}, {:.2})",
                a.to_degrees(),
                r,
                p.x,
                p.y
            );
        }
        return;
    }
    for p in s.door_passings() {
        let door = s.world.door(p.door).unwrap();
        println!(
            "passing scan {} door {:?} at {:?}",
            p.scan, p.door, door.center_m
        );
        for i in p.scan.saturating_sub(30)..(p.scan + 30).min(s.log.scans.len()) {
            let (_, truth) = s.truth[i];
            let sightings = passways(&s.log.scans[i].scan, &params);
            let line: Vec<String> = sightings
                .iter()
                .map(|g| {
                    let c = g.center_m();
                    let w = truth.transform_point(&c);
                    format!(
                        "b{:.0}° r{:.2} w{:.2} d{:.2}",
                        c.y.atan2(c.x).to_degrees(),
                        c.norm(),
                        g.width_m(),
                        (w - door.center_m).norm()
                    )
                })
                .collect();
            println!("  {i}: {}", line.join(" | "));
        }
    }
}
