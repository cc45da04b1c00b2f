//! `mapmerge`: merge, optimise and inspect robot pose graphs.
//!
//! Exit codes: 0 success, 2 bad input (unreadable or malformed files, bad arguments),
//! 1 any other failure (including a numerical failure, after writing the last good state).

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod compare;
mod corrupt;
mod optimize;
mod simulate;

/// Merges robot maps across sessions, robots and scales; optimises pose graphs.
#[derive(Parser, Debug)]
#[command(name = "mapmerge", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Optimise a pose graph (g2o or TORO, 2D or 3D; `.xz` accepted).
    Optimize(optimize::OptimizeArgs),
    /// Add random false loop closures to a graph (vertigo's pattern) for robustness tests.
    Corrupt(corrupt::CorruptArgs),
    /// Compare two graphs' trajectories (same vertex ids): ATE after optional alignment.
    Compare(compare::CompareArgs),
    /// Generate a synthetic pose graph with known ground truth.
    Simulate(simulate::SimulateArgs),
}

/// An error that maps to exit code 2.
#[derive(Debug)]
pub struct BadInput(pub String);

impl std::fmt::Display for BadInput {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for BadInput {}

/// Prints `report` as one JSON object on its own line (the `--json` output of every command).
pub fn print_json(report: &impl serde::Serialize) -> anyhow::Result<()> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    serde_json::to_writer(&mut out, report)?;
    writeln!(out)?;
    Ok(())
}

/// Reads a graph file; any failure is bad input (exit code 2), with the reason chain kept.
pub fn load_graph(path: &std::path::Path) -> anyhow::Result<mapmerge_io::LoadedGraph> {
    load_graph_with(path, &mapmerge_io::ReadParams::default())
}

/// [`load_graph`] with reader options.
pub fn load_graph_with(
    path: &std::path::Path,
    params: &mapmerge_io::ReadParams,
) -> anyhow::Result<mapmerge_io::LoadedGraph> {
    mapmerge_io::read_graph_with(path, params).map_err(|err| {
        let mut message = err.to_string();
        let mut source = std::error::Error::source(&err);
        while let Some(cause) = source {
            message.push_str(&format!(": {cause}"));
            source = cause.source();
        }
        anyhow::Error::new(BadInput(message))
    })
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Optimize(args) => optimize::run(args),
        Command::Corrupt(args) => corrupt::run(args),
        Command::Compare(args) => compare::run(args),
        Command::Simulate(args) => simulate::run(args),
    };
    match result {
        Ok(code) => code,
        Err(err) => {
            eprintln!("mapmerge: error: {err:#}");
            if err.downcast_ref::<BadInput>().is_some() {
                ExitCode::from(2)
            } else {
                ExitCode::from(1)
            }
        }
    }
}
