//! The place-recognition benchmark: precision and recall of verified loops.
//!
//! ```sh
//! cargo run --release -p mapmerge-lab --example place_benchmark -- LOG-corrected.log.xz
//! cargo run --release -p mapmerge-lab --example place_benchmark -- --sim testdata/sim/office-aliased
//! ```
//!
//! A public log: intra-log loops along its corrected poses. `--sim DIR`: keyframes of sessions
//! 1 and 2 against session 0 of a simulated data set, with the true poses. Prints one JSON line
//! (see `support/place_eval.rs` for the definitions). `--config JSON` overrides fields of the
//! default configuration (experiments only), `--dump FILE` writes every query's verified
//! candidates as JSON lines.

#[path = "support/place_eval.rs"]
mod place_eval;

use std::io::Write;
use std::path::PathBuf;

use place_eval::BenchConfig;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let (mut log, mut sim, mut dump): (Option<PathBuf>, Option<PathBuf>, Option<PathBuf>) =
        (None, None, None);
    let mut config = BenchConfig::default();
    let usage = "usage: place_benchmark (LOG | --sim DIR) [--config JSON] [--dump FILE]";
    while let Some(arg) = args.next() {
        match arg.as_str() {
            "--sim" => sim = Some(args.next().ok_or(usage)?.into()),
            "--dump" => dump = Some(args.next().ok_or(usage)?.into()),
            "--config" => config = serde_json::from_str(&args.next().ok_or(usage)?)?,
            _ if log.is_none() && !arg.starts_with("--") => log = Some(arg.into()),
            _ => return Err(usage.into()),
        }
    }
    let (report, records) = match (&log, &sim) {
        (Some(path), None) => {
            let (keyframes, fov_rad) = place_eval::carmen_keyframes(path, &config)?;
            let name = path.file_name().map_or_else(String::new, |n| {
                n.to_string_lossy().replace("-corrected.log.xz", "")
            });
            place_eval::evaluate_log(&name, &keyframes, fov_rad, &config)?
        }
        (None, Some(dir)) => place_eval::evaluate_sim(dir, &[1, 2], &config)?,
        _ => return Err(usage.into()),
    };
    if let Some(dump) = dump {
        let mut out = std::io::BufWriter::new(std::fs::File::create(dump)?);
        for record in &records {
            writeln!(out, "{}", serde_json::to_string(record)?)?;
        }
    }
    println!("{}", serde_json::to_string(&report)?);
    Ok(())
}
