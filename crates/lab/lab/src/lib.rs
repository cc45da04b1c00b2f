//! mapmerge's laboratory: the harnesses that make cases, run evaluation protocols, calibrate
//! decisions, judge the product's outputs against ground truth and print the study tables of
//! `docs/benchmarks.md`. The product never depends on it; the binary's `mapmerge eval …`
//! parses its arguments with [`EvalArgs`] and calls [`run_eval`].
//!
//! Entry points:
//! - [`run_eval`]: every `mapmerge eval` command (SLAM scores, grid merging, invalid-merge
//!   cases and detectors, calibration, assembly, protrusions, doors, areas);
//! - [`invalid_merge_eval`]: Holoch et al.'s forced merges and their results files, which
//!   `mapmerge atlas --merge-results` also writes;
//! - [`atlas_judge`]: `mapmerge atlas` against the truth (simulated sessions, every merge
//!   judged, ATE per committed session, epochs that revisit);
//! - [`map_judge`]: `mapmerge atlas`'s written per-map trajectories against the truth, as evo
//!   would judge them (segments merged and placed, misplaced ones, whole-map error), which
//!   `mapmerge eval lifelong` runs over corrected logs as kidnapped robots recorded them
//!   ([`carried`]) and over simulated worlds;
//! - [`area_truth`]: door detection and the map manager scored against the simulator;
//! - the data and cases the experiments run on: [`sim`] (`mapmerge sim`: simulated sessions
//!   with their truth), [`sim_graph`] (`mapmerge sim-graph`: a Manhattan world), [`corrupt`]
//!   (`mapmerge corrupt`: vertigo's false loop closures) and [`compare`] (`mapmerge compare`:
//!   ATE between two graphs), [`split`] (`mapmerge split`: a corrected log cut into
//!   segments for assembly, the truth kept apart).
//!
//! The studies behind single tables are `examples/` of this crate (place recognition,
//! retrieval, association at scale, grid-match crops, door traces, the simulator's speed).

pub mod area_truth;
mod areas_eval;
mod assemble_eval;
pub mod atlas_judge;
pub mod break_judge;
mod calibrate_eval;
pub mod carried;
pub mod compare;
pub mod corrupt;
mod door_eval;
mod eval;
mod grid_merge_eval;
pub mod invalid_merge_eval;
mod lifelong_eval;
pub mod live_judge;
pub mod map_judge;
mod protrusion_eval;
pub mod sim;
pub mod sim_graph;
pub mod slam_judge;
pub mod split;
pub mod start_judge;

pub use eval::{run as run_eval, EvalArgs, INDEX_HEADER};

// What every command shares with the binary's (one definition, in `mapmerge-jobs`).
pub(crate) use mapmerge_jobs::cli::{
    bad_file, bad_input, check_resolution, job_error, load_posed_log, log_short_name, print_json,
    progress_bar, read_config, read_log, BadInput, BagTopics, PosedLog,
};
