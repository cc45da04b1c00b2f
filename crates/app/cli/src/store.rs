//! `mapmerge store`: inspect, check, roll back and export a lifelong store (written by
//! `mapmerge atlas --store`). Every refused store (in use, newer schema, not a store, corrupt)
//! is bad input: exit code 2, the file untouched.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Subcommand};
use mapmerge_jobs::{open_store, open_store_read_only, ProtrusionAction};
use mapmerge_store::Store;
use serde::Serialize;

use crate::{bad_file, job_error, print_json};

/// Arguments of `mapmerge store`.
#[derive(Args, Debug)]
pub struct StoreArgs {
    #[command(subcommand)]
    pub command: StoreCommand,
}

/// What to do with the store.
#[derive(Subcommand, Debug)]
pub enum StoreCommand {
    /// The schema version, the number of versions, the newest version's counts and the size.
    Info(SiteArgs),
    /// Every map version, oldest first.
    Versions(SiteArgs),
    /// Exit 0 only when the store is intact (SQLite's integrity and foreign-key checks, and
    /// each version continuing the one before).
    Check(SiteArgs),
    /// Delete every version after `--to` (a bad session's version and its successors).
    Rollback(RollbackArgs),
    /// Look for erroneous protrusions (iRobot Sec. 5.4) in a version: the space new since
    /// its parent version, classified region by region as protrusion or new space; then
    /// optionally remove them (a new version) or roll the version back.
    Protrusions(ProtrusionArgs),
    /// Write each map of a version: its pose graph (g2o), its occupancy grid (map_server
    /// PGM + YAML; its local maps rendered) with a picture (PNG), and one TUM trajectory per
    /// epoch.
    Export(ExportArgs),
}

/// Arguments of `mapmerge store protrusions`.
#[derive(Args, Debug)]
pub struct ProtrusionArgs {
    #[command(flatten)]
    pub site: SiteArgs,
    /// The version to check against its parent (default: the newest).
    #[arg(long)]
    pub version: Option<i64>,
    /// Remove detected protrusions: the version's new local maps lose those cells, committed
    /// as a new version.
    #[arg(long, conflicts_with = "rollback")]
    pub remove: bool,
    /// Roll the version back (to its parent) when a protrusion is detected.
    #[arg(long)]
    pub rollback: bool,
}

/// Arguments of `mapmerge store export`.
#[derive(Args, Debug)]
pub struct ExportArgs {
    #[command(flatten)]
    pub site: SiteArgs,
    /// The version (default: the newest).
    #[arg(long)]
    pub version: Option<i64>,
    /// Cell side of the occupancy grids (m).
    #[arg(long, default_value_t = 0.05)]
    pub resolution: f64,
    /// Output folder.
    #[arg(short, long)]
    pub output: PathBuf,
}

/// A store and the output format.
#[derive(Args, Debug)]
pub struct SiteArgs {
    /// The store (e.g. `site.mapmerge`); it must exist.
    pub site: PathBuf,
    /// Print one JSON object on stdout instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Arguments of `mapmerge store rollback`.
#[derive(Args, Debug)]
pub struct RollbackArgs {
    #[command(flatten)]
    pub site: SiteArgs,
    /// The version to keep as the newest.
    #[arg(long)]
    pub to: i64,
}

/// Opens the store for reading only.
fn open(site: &SiteArgs) -> anyhow::Result<Store> {
    open_store_read_only(&site.site).map_err(job_error)
}

/// Store errors are the user's file: bad input.
fn refused(error: mapmerge_store::StoreError) -> anyhow::Error {
    bad_file(error)
}

/// Runs `mapmerge store`.
pub fn run(args: &StoreArgs) -> anyhow::Result<ExitCode> {
    match &args.command {
        StoreCommand::Info(site) => {
            let info = open(site)?.info().map_err(refused)?;
            if site.json {
                print_json(&info)?;
            } else {
                println!(
                    "{}: schema {}, {} versions, {} bytes",
                    site.site.display(),
                    info.schema_version,
                    info.versions,
                    info.bytes
                );
                if let (Some(version), Some(session)) = (info.newest_version, &info.session) {
                    println!(
                        "newest: version {version} ({session}), {} nodes, {} edges, {} keyframes, {} local maps, {:.1} m², {} areas, {} link points",
                        info.nodes, info.edges, info.keyframes, info.local_maps, info.mapped_area_m2, info.areas, info.link_points
                    );
                }
            }
        }
        StoreCommand::Versions(site) => {
            let versions = open(site)?.versions().map_err(refused)?;
            if site.json {
                #[derive(Serialize)]
                struct Report<'a> {
                    versions: &'a [mapmerge_store::VersionInfo],
                }
                print_json(&Report {
                    versions: &versions,
                })?;
            } else {
                for v in &versions {
                    println!(
                        "version {} ({}): {} nodes, {} edges, {} keyframes, {} local maps, {:.1} m², {} areas, {} link points",
                        v.version, v.session, v.nodes, v.edges, v.keyframes, v.local_maps, v.mapped_area_m2, v.areas, v.link_points
                    );
                }
            }
        }
        StoreCommand::Check(site) => {
            let result = open(site).and_then(|s| s.check().map_err(refused));
            if site.json {
                #[derive(Serialize)]
                struct Report {
                    intact: bool,
                    problem: Option<String>,
                }
                print_json(&Report {
                    intact: result.is_ok(),
                    problem: result.as_ref().err().map(|e| format!("{e:#}")),
                })?;
            }
            result?;
            if !site.json {
                println!("{}: intact", site.site.display());
            }
        }
        StoreCommand::Rollback(rollback) => {
            let mut store = open_store(&rollback.site.site).map_err(job_error)?;
            let deleted = store.rollback_to(rollback.to).map_err(refused)?;
            if rollback.site.json {
                #[derive(Serialize)]
                struct Report {
                    kept_version: i64,
                    deleted_versions: usize,
                }
                print_json(&Report {
                    kept_version: rollback.to,
                    deleted_versions: deleted,
                })?;
            } else {
                println!(
                    "{}: version {} is the newest; {deleted} deleted",
                    rollback.site.site.display(),
                    rollback.to
                );
            }
        }
        StoreCommand::Export(export_args) => export(export_args)?,
        StoreCommand::Protrusions(protrusion_args) => protrusions(protrusion_args)?,
    }
    Ok(ExitCode::SUCCESS)
}

/// Runs `mapmerge store protrusions`.
fn protrusions(args: &ProtrusionArgs) -> anyhow::Result<()> {
    let action = if args.remove {
        ProtrusionAction::Remove
    } else if args.rollback {
        ProtrusionAction::Rollback
    } else {
        ProtrusionAction::Report
    };
    let report = mapmerge_jobs::store_protrusions(&args.site.site, args.version, action)
        .map_err(job_error)?;
    if args.site.json {
        return print_json(&report);
    }
    println!(
        "version {} against {}: {} regions of new space, {} protrusions",
        report.version,
        report.parent,
        report.regions.len(),
        report.protrusions
    );
    for r in &report.regions {
        println!(
            "  ({:.1}, {:.1}) m: {:.2} m², mean distance {:.2} m, minor axis {:.2} m -> {}",
            r.centre_m[0],
            r.centre_m[1],
            r.features.area_m2,
            r.features.mean_distance_m,
            r.features.minor_axis_m,
            if r.protrusion {
                "protrusion"
            } else {
                "new space"
            }
        );
    }
    if let Some(v) = report.new_version {
        println!("removed: version {v}");
    }
    if report.rolled_back {
        println!("rolled back to version {}", report.parent);
    }
    Ok(())
}

/// Runs `mapmerge store export` (see [`StoreCommand::Export`]).
fn export(args: &ExportArgs) -> anyhow::Result<()> {
    crate::check_output_dir(&args.output)?;
    let report =
        mapmerge_jobs::export_version(&args.site.site, args.version, args.resolution, &args.output)
            .map_err(job_error)?;
    if args.site.json {
        return print_json(&report);
    }
    for m in &report.maps {
        println!(
            "version {}: {} ({} vertices, {} edges, epochs {:?}) -> {}, {}, {}, {} trajectories",
            report.version,
            m.name,
            m.vertices,
            m.edges,
            m.epochs,
            m.g2o.display(),
            m.map_yaml.display(),
            m.png.display(),
            m.trajectories.len()
        );
    }
    Ok(())
}
