//! Same seed, same dataset (bit for bit, on any number of threads); different seed, different
//! dataset.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use mapmerge_sim::{generate_world, simulate, SimParams, WorldPreset};

fn params() -> SimParams {
    SimParams::default()
        .with_preset(WorldPreset::OfficeAliased)
        .with_sessions(3)
        .with_duration_secs(40.0)
}

#[test]
fn same_seed_gives_the_same_dataset_bit_for_bit() {
    let a = simulate(&params(), 11).unwrap();
    let b = simulate(&params(), 11).unwrap();
    assert_eq!(a, b);
    // `Debug` prints every float exactly (shortest round-trip form, signed zeros), so equal
    // strings mean equal bits.
    assert_eq!(format!("{a:?}"), format!("{b:?}"));
}

#[test]
fn the_dataset_does_not_depend_on_the_number_of_threads() {
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let three = rayon::ThreadPoolBuilder::new()
        .num_threads(3)
        .build()
        .unwrap();
    let a = one.install(|| simulate(&params(), 5).unwrap());
    let b = three.install(|| simulate(&params(), 5).unwrap());
    assert_eq!(format!("{a:?}"), format!("{b:?}"));
}

#[test]
fn different_seeds_give_different_datasets() {
    let a = simulate(&params(), 1).unwrap();
    let b = simulate(&params(), 2).unwrap();
    assert_ne!(a.world, b.world);
    assert_ne!(a.sessions[0].truth, b.sessions[0].truth);
    assert_ne!(
        a.sessions[0].log.scans[0].scan.ranges_m,
        b.sessions[0].log.scans[0].scan.ranges_m
    );
}

#[test]
fn a_fixed_world_seed_keeps_the_world_and_changes_the_runs() {
    let fixed = SimParams {
        world_seed: Some(77),
        ..params()
    };
    let a = simulate(&fixed, 1).unwrap();
    let b = simulate(&fixed, 2).unwrap();
    assert_eq!(a.world, b.world);
    assert_ne!(a.sessions[0].truth, b.sessions[0].truth);
}

#[test]
fn every_preset_generates_deterministically() {
    for preset in WorldPreset::ALL {
        let a = generate_world(&preset.params(), 3).unwrap();
        let b = generate_world(&preset.params(), 3).unwrap();
        assert_eq!(format!("{a:?}"), format!("{b:?}"), "{preset}");
        if preset != WorldPreset::Warehouse {
            // Warehouse geometry is fixed by its parameters; offices are random.
            assert_ne!(a, generate_world(&preset.params(), 4).unwrap(), "{preset}");
        }
    }
}

#[test]
fn a_session_simulated_alone_is_that_session_of_the_whole_simulation() {
    // With named start rooms (so the earlier sessions' rooms do not matter), session k alone
    // is session k of the dataset: same world changes, route, noise and kidnaps.
    let whole = simulate(&params(), 11).unwrap();
    let mut named = params();
    named.start_rooms = whole
        .sessions
        .iter()
        .map(|s| {
            s.world
                .room(s.start_room)
                .map(|r| r.name.clone())
                .unwrap_or_default()
        })
        .collect();
    let whole = simulate(&named, 11).unwrap();
    for (k, session) in whole.sessions.iter().enumerate() {
        let alone = mapmerge_sim::simulate_session_alone(&named, 11, k).unwrap();
        assert_eq!(&alone, session, "session {k}");
    }
    // Session 0 needs no names: no earlier session chose a room before it.
    let first = mapmerge_sim::simulate_session_alone(&params(), 11, 0).unwrap();
    assert_eq!(first, simulate(&params(), 11).unwrap().sessions[0]);
}
