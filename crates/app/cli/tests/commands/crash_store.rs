//! Crash safety of the lifelong store: `mapmerge atlas --store` is killed with SIGKILL at
//! random moments, session after session. After every kill the store opens, `store check`
//! passes, every version committed before the kill is still there exactly as it was committed,
//! and a version either is complete or does not exist (no half-written session).
//!
//! CI runs 12 kills (and the sessions between them that run to their end);
//! `MAPMERGE_CRASH_KILLS=100` runs the benchmark's hundred (docs/benchmarks.md, "The lifelong
//! store").

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeMap;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::common::{p, scratch, BIN};
use mapmerge_store::{Store, StoredAtlas};

/// A small deterministic generator (xorshift64*): kill times that a failure can be replayed
/// with.
struct Moments(u64);

impl Moments {
    fn next_unit(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Starts one simulated session into the store.
fn start_session(
    site: &std::path::Path,
    index: usize,
    output: &std::path::Path,
) -> std::process::Child {
    Command::new(BIN)
        .args([
            "atlas",
            "--sim",
            "office",
            "--session-index",
            &index.to_string(),
            "--duration",
            "30",
            "--no-pictures",
            "--store",
            p(site),
            "-o",
            p(output),
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap()
}

/// Every retained version of the store, loaded.
fn committed(store: &Store) -> BTreeMap<i64, StoredAtlas> {
    store
        .versions()
        .unwrap()
        .into_iter()
        .filter(|v| v.retained)
        .map(|v| (v.version, store.load(Some(v.version)).unwrap().unwrap()))
        .collect()
}

#[test]
fn sigkill_at_random_moments_loses_no_committed_version_and_corrupts_nothing() {
    let kills: usize = std::env::var("MAPMERGE_CRASH_KILLS")
        .ok()
        .and_then(|k| k.parse().ok())
        .unwrap_or(12);
    let dir = scratch("crash-store");
    let site = dir.join("site.mapmerge");
    // One session run to the end: how long a session takes.
    let started = Instant::now();
    let status = start_session(&site, 0, &dir.join("out")).wait().unwrap();
    assert!(status.success());
    let mut session = started.elapsed();
    let mut known = committed(&Store::open_existing(&site).unwrap());
    assert_eq!(known.len(), 1);
    let mut moments = Moments(0x9e37_79b9_7f4a_7c15);
    let (mut killed, mut killed_late, mut finished) = (0, 0, 0);
    let mut index = 1;
    while killed < kills {
        // Every fourth session runs to its end: the store grows, and the session's length
        // is measured again. The others are killed: half anywhere in the session, half near
        // its end, where it commits.
        let kill = index % 4 != 0;
        let fraction = if moments.next_unit() < 0.5 {
            moments.next_unit()
        } else {
            0.85 + 0.25 * moments.next_unit()
        };
        let wait = if kill {
            session.mul_f64(fraction)
        } else {
            Duration::from_secs(3600)
        };
        let k = index;
        let started = Instant::now();
        let mut child = start_session(&site, index, &dir.join("out"));
        index += 1;
        let deadline = started + wait;
        let mut exited = None;
        while Instant::now() < deadline {
            if let Some(status) = child.try_wait().unwrap() {
                exited = Some(status);
                break;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        match exited {
            Some(status) => {
                assert!(status.success(), "session {k}: failed on its own");
                finished += 1;
                if !kill {
                    session = started.elapsed();
                }
            }
            None => {
                child.kill().unwrap(); // SIGKILL
                child.wait().unwrap();
                killed += 1;
                killed_late += usize::from(fraction >= 0.85);
            }
        }
        let store = Store::open_existing(&site).unwrap_or_else(|e| {
            panic!("session {k}, killed after {wait:?}: the store does not open: {e}")
        });
        store
            .check()
            .unwrap_or_else(|e| panic!("session {k}, killed after {wait:?}: {e}"));
        let now = committed(&store);
        for (version, stored) in &known {
            // Retention may forget old versions; a retained one is as committed.
            if let Some(again) = now.get(version) {
                assert_eq!(again, stored, "session {k}: version {version} changed");
            } else {
                assert!(
                    store
                        .versions()
                        .unwrap()
                        .iter()
                        .any(|v| v.version == *version),
                    "session {k}: version {version} was lost"
                );
            }
        }
        // At most the session being killed was added, and then completely (it loaded).
        assert!(now.len() <= known.len() + 1, "session {k}");
        known = now;
    }
    eprintln!(
        "{} sessions: {killed} killed ({killed_late} near their end), {finished} finished",
        index - 1
    );
    assert!(finished > 0, "no session was committed after the first");
    let _ = std::fs::remove_dir_all(&dir);
}
