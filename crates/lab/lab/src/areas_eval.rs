//! `mapmerge eval areas`: global tracking and topological loop closure of the map manager
//! (Ehlers et al., Sec. II-C, II-D) on long simulated tours, scored by the simulator's truth
//! (`crate::area_truth::score_tour`); each span is mapped by the SLAM pipeline.

use std::path::PathBuf;

use crate::area_truth::{score_tour, TourScore};
use clap::Args;
use mapmerge_areas::ManagerParams;
use mapmerge_engine::{run_slam, EngineParams};
use mapmerge_place::PlaceVerifierParams;
use serde::Serialize;

use crate::protrusion_eval::seeds;
use crate::{bad_input, print_json};

/// Arguments of `mapmerge eval areas`.
#[derive(Args, Debug)]
pub struct AreasEvalArgs {
    /// World presets.
    #[arg(long, value_delimiter = ',', default_value = "office,symmetric-hall")]
    pub worlds: Vec<String>,
    /// Seeds (`A-B` or a comma list; the tuning seeds are 1-20, the held-out 101-110).
    #[arg(long, default_value = "101-105")]
    pub seeds: String,
    /// Length of each tour (s of robot time; no kidnaps).
    #[arg(long, default_value_t = 600.0)]
    pub duration: f64,
    /// Sessions per world and seed (later ones must be placed by the global search).
    #[arg(long, default_value_t = 1)]
    pub sessions: usize,
    /// Map-manager parameters as JSON (any subset of `mapmerge_areas::ManagerParams`).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

#[derive(Serialize)]
struct Report {
    tours: Vec<TourScore>,
    revisits: usize,
    revisits_found: usize,
    lost: usize,
    closures: usize,
    false_closures: usize,
    /// Closures at link-point candidates, and the false ones.
    candidate_closures: usize,
    false_candidate_closures: usize,
    /// Passed doors whose two sides ended in one area.
    doors_inside_areas: usize,
    sessions: usize,
    sessions_placed: usize,
    /// Later sessions placed where they are not.
    sessions_placed_wrongly: usize,
    /// Door passings over every session, as areas.json lists them.
    passings: crate::area_truth::DoorCounts,
    passing_precision: f64,
    passing_recall: f64,
    /// Pairs of placed areas, and those `route` joins.
    area_pairs: usize,
    area_pairs_routed: usize,
    /// Largest link-point ATE after optimisation over the tours (m).
    worst_link_ate_m: f64,
}

/// Runs `mapmerge eval areas`.
pub fn run(args: &AreasEvalArgs) -> anyhow::Result<()> {
    let params: ManagerParams = crate::read_config(args.config.as_deref())?;
    let verifier = PlaceVerifierParams::default()
        .verifier()
        .map_err(bad_input)?;
    let mut tours = Vec::new();
    for world in &args.worlds {
        for seed in seeds(&args.seeds)? {
            let mut map_span = |log: &mapmerge_scan::LaserLog, preset: &mapmerge_areas::Preset| {
                let engine = EngineParams {
                    tracker: preset.tracker.clone(),
                    ..EngineParams::default()
                };
                run_slam(log, engine, |_| {})
                    .map(|run| (run.trajectory, run.graph))
                    .map_err(|e| e.to_string())
            };
            let score = score_tour(
                world,
                seed,
                args.sessions,
                args.duration,
                &params,
                &verifier,
                &mut map_span,
            )
            .map_err(bad_input)?;
            tours.push(score);
        }
    }
    let sum = |f: fn(&TourScore) -> usize| tours.iter().map(f).sum::<usize>();
    let mut passings = crate::area_truth::DoorCounts::default();
    for t in &tours {
        passings.add(&t.passings);
    }
    let report = Report {
        revisits: sum(|t| t.revisits),
        revisits_found: sum(|t| t.revisits_found),
        lost: sum(|t| t.lost),
        closures: sum(|t| t.closures),
        false_closures: sum(|t| t.false_closures),
        candidate_closures: sum(|t| t.candidate_closures),
        false_candidate_closures: sum(|t| t.false_candidate_closures),
        doors_inside_areas: sum(|t| t.doors_inside_areas),
        sessions: sum(|t| t.sessions),
        sessions_placed: sum(|t| t.sessions_placed),
        sessions_placed_wrongly: sum(|t| t.sessions_placed_wrongly),
        passings,
        passing_precision: passings.precision(),
        passing_recall: passings.recall(),
        area_pairs: sum(|t| t.area_pairs),
        area_pairs_routed: sum(|t| t.area_pairs_routed),
        worst_link_ate_m: tours.iter().map(|t| t.link_ate_m).fold(0.0, f64::max),
        tours,
    };
    if args.json {
        print_json(&report)?;
    } else {
        println!("| world | seed | boundaries | at doors | revisits | found | lost | closures | false | candidate closures | false | candidates left | doors inside areas | link ATE m | chain ATE m | areas / spans |");
        println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
        for t in &report.tours {
            println!(
                "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.3} | {:.3} | {} / {} |",
                t.world,
                t.seed,
                t.boundaries,
                t.at_doors,
                t.revisits,
                t.revisits_found,
                t.lost,
                t.closures,
                t.false_closures,
                t.candidate_closures,
                t.false_candidate_closures,
                t.candidates,
                t.doors_inside_areas,
                t.link_ate_m,
                t.chain_ate_m,
                t.areas,
                t.spans
            );
        }
        println!(
            "\nsessions placed {} of {} ({} wrongly), door passings over every session: precision {:.3}, recall {:.3} of {}, area pairs routed {} of {}",
            report.sessions_placed,
            report.sessions,
            report.sessions_placed_wrongly,
            report.passing_precision,
            report.passing_recall,
            report.passings.passings,
            report.area_pairs_routed,
            report.area_pairs,
        );
        println!(
            "revisits found {} of {}, lost {}, closures {} ({} false), at candidates {} ({} false), passed doors inside one area {}, worst link-point ATE {:.3} m",
            report.revisits_found,
            report.revisits,
            report.lost,
            report.closures,
            report.false_closures,
            report.candidate_closures,
            report.false_candidate_closures,
            report.doors_inside_areas,
            report.worst_link_ate_m
        );
    }
    Ok(())
}
