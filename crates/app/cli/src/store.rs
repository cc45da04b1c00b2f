//! `mapmerge store`: inspect, check and roll back a lifelong store (issue 17; the atlas does
//! not write to stores yet). Every refused store (in use, newer schema, not a store,
//! corrupt) is bad input: exit code 2, the file untouched.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Subcommand};
use mapmerge_store::{Store, StoreError};
use serde::Serialize;

use crate::{bad_file, print_json};

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

fn open(site: &SiteArgs) -> anyhow::Result<Store> {
    if !site.site.is_file() {
        return Err(crate::bad_input(format!(
            "{}: no such store",
            site.site.display()
        )));
    }
    Store::open_existing(&site.site).map_err(refused)
}

/// Store errors are the user's file: bad input.
fn refused(error: StoreError) -> anyhow::Error {
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
                        "newest: version {version} ({session}), {} nodes, {} edges, {} keyframes, {} local maps, {:.1} m²",
                        info.nodes, info.edges, info.keyframes, info.local_maps, info.mapped_area_m2
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
                        "version {} ({}): {} nodes, {} edges, {} keyframes, {} local maps, {:.1} m²",
                        v.version, v.session, v.nodes, v.edges, v.keyframes, v.local_maps, v.mapped_area_m2
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
            let mut store = open(&rollback.site)?;
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
    }
    Ok(ExitCode::SUCCESS)
}
