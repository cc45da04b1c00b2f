//! `mapmerge`: merge, optimise and inspect robot pose graphs.
//!
//! Exit codes: 0 success, 2 bad input (unreadable or malformed files, bad arguments),
//! 1 any other failure (including a numerical failure, after writing the last good state).

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod areas;
mod assemble;
mod atlas;
mod convert;
mod grid;
mod grid_merge;
mod optimize;
mod render;
#[cfg(feature = "ros2")]
mod ros2;
mod slam;
mod store;

/// Merges robot maps across sessions, robots and scales; optimises pose graphs.
#[derive(Parser, Debug)]
#[command(name = "mapmerge", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Lifelong mapping over sessions (logs or a simulation): epochs, merges by place
    /// recognition, invalid-merge detection and undo; events, graphs and pictures.
    Atlas(atlas::AtlasArgs),
    /// The map manager (Ehlers et al.): one map per area, split at door passings, each built
    /// with its environment's preset, joined by link points into a topological graph.
    Areas(areas::AreasArgs),
    /// The shortest route between two poses in the maps of `mapmerge areas` (exit code 3: no
    /// route).
    Route(areas::RouteArgs),
    /// Assemble trajectory segments (CARMEN logs) without initial guesses, in any order
    /// (AutoMerge): groups, inter-segment loop edges, poses per group, pictures.
    Assemble(assemble::AssembleArgs),
    /// Optimise a pose graph (g2o or TORO, 2D or 3D; `.xz` accepted).
    Optimize(optimize::OptimizeArgs),
    /// Add random false loop closures to a graph (vertigo's pattern) for robustness tests.
    Corrupt(mapmerge_lab::corrupt::CorruptArgs),
    /// Compare two graphs' trajectories (same vertex ids): ATE after optional alignment.
    Compare(mapmerge_lab::compare::CompareArgs),
    /// Generate a synthetic pose graph with known ground truth (Manhattan world).
    #[command(name = "sim-graph", alias = "simulate")]
    Simulate(mapmerge_lab::sim_graph::SimulateArgs),
    /// Simulate robot sessions in a 2D office world: CARMEN logs, ground truth, world map.
    Sim(mapmerge_lab::sim::SimArgs),
    /// Build an occupancy grid (ROS map_server YAML + PGM) from a laser log and poses.
    Grid(grid::GridArgs),
    /// Convert a laser log (CARMEN or ROS 2 bag) to a ROS 2 bag (`.mcap`, `.db3`) or a
    /// CARMEN log; a KITTI-style folder to a bag of PointCloud2.
    Convert(convert::ConvertArgs),
    /// Merge two ROS map_server maps of any resolution without an initial guess (exit code 3:
    /// no acceptable hypothesis).
    GridMerge(grid_merge::GridMergeArgs),
    /// Draw a grid, pose graphs and trajectories to a PNG.
    Render(render::RenderArgs),
    /// SLAM evaluation on corrected logs: odometry noise, relations, ATE/RPE.
    Eval(mapmerge_lab::EvalArgs),
    /// 2D graph SLAM on a laser log: pose graph, map, picture, one pose per scan.
    Slam(slam::SlamArgs),
    /// Cut a corrected laser log into overlapping segments, each re-based to its own origin
    /// (optionally with noisy odometry), with the ground truth kept apart.
    Split(mapmerge_lab::split::SplitArgs),
    /// Inspect, check and roll back a lifelong store (a SQLite file of map versions).
    Store(store::StoreArgs),
    /// Live ROS 2 nodes without a ROS install: `slam` (the lifelong engine on a robot's
    /// topics) and `merge` (m-explore's map_merge topics). Built with `--features ros2`.
    #[cfg(feature = "ros2")]
    Ros2(ros2::Ros2Args),
}

pub use mapmerge_jobs::cli::*;

/// Gives the free pages of the heap back to the system (glibc's `malloc_trim`). After a run,
/// the blocks the engine freed (matching grids of 1–20 MB, which glibc serves from its heaps
/// once its mmap threshold has risen) stay resident, and the map built next would count on
/// top of them.
pub(crate) fn return_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only releases memory no allocation holds; any thread may call it.
    unsafe {
        libc::malloc_trim(0);
    }
}

fn main() -> ExitCode {
    // `mapmerge … | head` must end quietly, like other Unix tools, instead of panicking in
    // `println!` on a closed pipe: restore the default SIGPIPE action Rust turns off.
    #[cfg(unix)]
    // SAFETY: called before any thread starts; SIG_DFL is a valid handler for SIGPIPE.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Atlas(args) => atlas::run(args),
        Command::Assemble(args) => assemble::run(args).map(|()| ExitCode::SUCCESS),
        Command::Optimize(args) => optimize::run(args),
        Command::Corrupt(args) => mapmerge_lab::corrupt::run(args),
        Command::Compare(args) => mapmerge_lab::compare::run(args),
        Command::Simulate(args) => mapmerge_lab::sim_graph::run(args),
        Command::Sim(args) => mapmerge_lab::sim::run(args),
        Command::Convert(args) => convert::run(args),
        Command::Areas(args) => areas::run(args),
        Command::Route(args) => areas::route(args),
        Command::Grid(args) => grid::run(args),
        Command::GridMerge(args) => grid_merge::run(args),
        Command::Render(args) => render::run(args),
        Command::Eval(args) => mapmerge_lab::run_eval(args),
        Command::Slam(args) => slam::run(args),
        Command::Split(args) => mapmerge_lab::split::run(args),
        Command::Store(args) => store::run(args),
        #[cfg(feature = "ros2")]
        Command::Ros2(args) => ros2::run(args),
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

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    /// `read_config` of `text` (written to a scratch file).
    fn config<T>(name: &str, text: &str) -> anyhow::Result<T>
    where
        T: serde::de::DeserializeOwned + serde::Serialize + Default + mapmerge_params::Validate,
    {
        let path = std::env::temp_dir().join(format!(
            "mapmerge-config-{}-{name}.json",
            std::process::id()
        ));
        std::fs::write(&path, text).unwrap();
        let read = read_config(Some(&path));
        std::fs::remove_file(&path).unwrap();
        read
    }

    /// An empty object gives the defaults of every parameter type a command reads: each
    /// default survives being written as JSON and read back.
    #[test]
    fn an_empty_config_is_every_types_default() {
        fn same<T>(name: &str)
        where
            T: serde::de::DeserializeOwned + serde::Serialize + Default + mapmerge_params::Validate,
        {
            let read: T = config(name, "{}").unwrap();
            assert_eq!(
                serde_json::to_value(read).unwrap(),
                serde_json::to_value(T::default()).unwrap(),
                "{name}"
            );
        }
        same::<mapmerge_engine::EngineParams>("engine");
        same::<mapmerge_areas::ManagerParams>("manager");
        same::<mapmerge_areas::DoorParams>("doors");
        same::<mapmerge_assemble::AssembleParams>("assemble");
        same::<mapmerge_gridmatch::GridMatchParams>("gridmatch");
    }

    /// A field given deep inside keeps its siblings at the enclosing default, which differs
    /// from the nested type's own (the atlas's recognition accepts from 0.975, a bare
    /// `PlaceParams` from 0.5); a misspelt field is still refused.
    #[test]
    fn a_nested_field_keeps_its_siblings_at_the_enclosing_default() {
        let params: mapmerge_engine::EngineParams = config(
            "nested",
            r#"{"atlas": {"recognition": {"place": {"candidates_per_query": 6}}}}"#,
        )
        .unwrap();
        let defaults = mapmerge_engine::EngineParams::default();
        let place = &params.atlas.recognition.place;
        assert_eq!(place.candidates_per_query, 6);
        assert_eq!(place.min_score, defaults.atlas.recognition.place.min_score);
        assert_eq!(place.min_score, 0.975);
        assert!(config::<mapmerge_engine::EngineParams>(
            "typo",
            r#"{"atlas": {"recognition": {"place": {"min_scor": 0.5}}}}"#
        )
        .is_err());
        assert!(config::<mapmerge_engine::EngineParams>("broken", "{").is_err());
    }

    /// Another variant of a tagged enum replaces the default's (whose fields it does not
    /// have); the same variant takes the given fields.
    #[test]
    fn another_variant_of_a_tagged_enum_replaces_the_defaults() {
        use mapmerge_solve::RobustKernel;
        let params: mapmerge_engine::EngineParams = config(
            "variant",
            r#"{"atlas": {"loops": {"optimizer": {"robust": {"kind": "huber", "delta": 2.0}}}}}"#,
        )
        .unwrap();
        assert_eq!(
            params.atlas.loops.optimizer.robust,
            RobustKernel::Huber { delta: 2.0 }
        );
        let params: mapmerge_engine::EngineParams = config(
            "same-variant",
            r#"{"atlas": {"loops": {"optimizer": {"robust": {"phi": 3.0}}}}}"#,
        )
        .unwrap();
        assert_eq!(
            params.atlas.loops.optimizer.robust,
            RobustKernel::Dcs { phi: 3.0 }
        );
    }

    /// Issue 67's hostile configs: each refused as bad input naming the file, the field's
    /// path and the allowed range, before any work.
    #[test]
    fn out_of_range_values_are_refused_by_their_path() {
        fn refused<T>(text: &str, field: &str)
        where
            T: serde::de::DeserializeOwned + serde::Serialize + Default + mapmerge_params::Validate,
        {
            let error = config::<T>("range", text)
                .err()
                .unwrap_or_else(|| panic!("{text}"));
            assert!(error.is::<BadInput>(), "{text}: {error}");
            let message = error.to_string();
            assert!(message.contains("mapmerge-config-"), "{message}");
            assert!(message.contains(&format!("`{field}`")), "{text}: {message}");
            assert!(message.contains("must be"), "{message}");
        }
        use mapmerge_engine::EngineParams as E;
        let cases = [
            (
                r#"{"tracker": {"matcher": {"correlative": {"max_grid_cells": 18446744073709551615, "resolution_m": 0.001}}}}"#,
                "tracker.matcher.correlative.max_grid_cells",
            ),
            (
                r#"{"atlas": {"loops": {"matcher": {"icp": {"max_iterations": 4294967295}}}}}"#,
                "atlas.loops.matcher.icp.max_iterations",
            ),
            (
                r#"{"atlas": {"loops": {"place_gate": [-1, 0.1, 0.1, 0.001]}}}"#,
                "atlas.loops.place_gate[0]",
            ),
            (
                r#"{"tracker": {"keyframes": {"min_translation_m": -0.25}}}"#,
                "tracker.keyframes.min_translation_m",
            ),
            (
                r#"{"tracker": {"max_match_range_m": -20}}"#,
                "tracker.max_match_range_m",
            ),
            (
                r#"{"tracker": {"min_edge_sigma": [-0.01, 0.003]}}"#,
                "tracker.min_edge_sigma[0]",
            ),
            (
                r#"{"atlas": {"optimizer": {"robust": {"kind": "dcs", "phi": -1}}}}"#,
                "atlas.optimizer.robust.phi",
            ),
            (
                r#"{"atlas": {"loops": {"optimize_every_keyframes": 0}}}"#,
                "atlas.loops.optimize_every_keyframes",
            ),
            (
                r#"{"decisions": {"probation_m": -5}}"#,
                "decisions.probation_m",
            ),
            (
                r#"{"decisions": {"filter": {"max_hypotheses": 0}}}"#,
                "decisions.filter.max_hypotheses",
            ),
            (r#"{"detector": "nonesuch"}"#, "detector"),
        ];
        for (text, field) in cases {
            refused::<E>(text, field);
        }
        refused::<mapmerge_areas::ManagerParams>(
            r#"{"tracking": {"base_radius_m": -1}}"#,
            "tracking.base_radius_m",
        );
        refused::<mapmerge_gridmatch::GridMatchParams>(
            r#"{"max_cells": 18446744073709551615}"#,
            "max_cells",
        );
    }
}
