//! `mapmerge store`: inspect, check, roll back and export a lifelong store (written by
//! `mapmerge atlas --store`). Every refused store (in use, newer schema, not a store, corrupt)
//! is bad input: exit code 2, the file untouched.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::{Args, Subcommand};
use mapmerge_atlas::RenderedMap;
use mapmerge_geometry::Se2;
use mapmerge_grid::{ClassThresholds, InsertParams, OccupancyGrid, Point2};
use mapmerge_io::{AnyGraph, GraphFormat, MapMode, RosMap};
use mapmerge_render::{session_color, Picture, PictureStyle};
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

fn open(site: &SiteArgs) -> anyhow::Result<Store> {
    open_existing(&site.site)
}

/// Opens the store at `path`; an error when there is none.
pub(crate) fn open_existing(path: &std::path::Path) -> anyhow::Result<Store> {
    if !path.is_file() {
        return Err(crate::bad_input(format!(
            "{}: no such store",
            path.display()
        )));
    }
    Store::open_existing(path).map_err(refused)
}

/// Opens the store at `path`, creating it when there is no file (`atlas --store`).
pub(crate) fn open_or_create(path: &std::path::Path) -> anyhow::Result<Store> {
    Store::open(path).map_err(refused)
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
        StoreCommand::Export(export_args) => export(export_args)?,
        StoreCommand::Protrusions(protrusion_args) => protrusions(protrusion_args)?,
    }
    Ok(ExitCode::SUCCESS)
}

/// One region of new space as `store protrusions` reports it.
#[derive(Serialize)]
struct RegionReport {
    centre_m: [f64; 2],
    features: mapmerge_atlas::RegionFeatures,
    protrusion: bool,
}

/// Runs `mapmerge store protrusions`.
fn protrusions(args: &ProtrusionArgs) -> anyhow::Result<()> {
    let mut store = open(&args.site)?;
    let Some(child) = store.load(args.version).map_err(refused)? else {
        return Err(crate::bad_input(format!(
            "{}: the store has no version yet",
            args.site.site.display()
        )));
    };
    let parent_version = store
        .versions()
        .map_err(refused)?
        .into_iter()
        .find(|v| v.version == child.version)
        .and_then(|v| v.parent)
        .ok_or_else(|| {
            crate::bad_input(format!(
                "version {} has no parent to compare with",
                child.version
            ))
        })?;
    let parent = store
        .load(Some(parent_version))
        .map_err(refused)?
        .ok_or_else(|| crate::bad_input(format!("no version {parent_version}")))?;
    let params = mapmerge_atlas::ProtrusionParams::default();
    let classifier = mapmerge_atlas::ProtrusionClassifier::trained().map_err(anyhow::Error::msg)?;
    let (rendered, regions) = mapmerge_atlas::new_regions(&parent.atlas, &child.atlas, &params)
        .unwrap_or_else(|| {
            (
                mapmerge_atlas::RenderedMap {
                    geometry: mapmerge_grid::GridGeometry {
                        resolution_m: params.resolution_m,
                        origin_m: Point2::zeros(),
                        width: 0,
                        height: 0,
                    },
                    sums: Vec::new(),
                    contributions: BTreeMap::new(),
                },
                Vec::new(),
            )
        });
    let features: Vec<_> = regions.iter().map(|r| r.features).collect();
    let verdicts = classifier.predict(&features).map_err(anyhow::Error::msg)?;
    let found: Vec<&mapmerge_atlas::Region> = regions
        .iter()
        .zip(&verdicts)
        .filter(|(_, p)| **p)
        .map(|(r, _)| r)
        .collect();
    let mut new_version = None;
    let mut rolled_back = false;
    if !found.is_empty() && args.remove {
        let mut atlas = child.atlas.clone();
        mapmerge_atlas::remove_regions(&parent.atlas, &mut atlas, &rendered, &found);
        let session = format!("protrusions removed from version {}", child.version);
        new_version = Some(
            store
                .commit_session(&mapmerge_store::SessionCommit {
                    session: &session,
                    atlas: &atlas,
                    events: &[],
                    reference_poses: &child.reference_poses,
                })
                .map_err(refused)?,
        );
    } else if !found.is_empty() && args.rollback {
        store.rollback_to(parent_version).map_err(refused)?;
        rolled_back = true;
    }
    let report: Vec<RegionReport> = regions
        .iter()
        .zip(&verdicts)
        .map(|(r, p)| RegionReport {
            centre_m: r.centre_m,
            features: r.features,
            protrusion: *p,
        })
        .collect();
    if args.site.json {
        #[derive(Serialize)]
        struct Report<'a> {
            version: i64,
            parent: i64,
            regions: &'a [RegionReport],
            protrusions: usize,
            new_version: Option<i64>,
            rolled_back: bool,
        }
        print_json(&Report {
            version: child.version,
            parent: parent_version,
            regions: &report,
            protrusions: found.len(),
            new_version,
            rolled_back,
        })?;
    } else {
        println!(
            "version {} against {parent_version}: {} regions of new space, {} protrusions",
            child.version,
            report.len(),
            found.len()
        );
        for r in &report {
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
        if let Some(v) = new_version {
            println!("removed: version {v}");
        }
        if rolled_back {
            println!("rolled back to version {parent_version}");
        }
    }
    Ok(())
}

/// One exported map's files.
#[derive(Serialize)]
struct ExportedMap {
    /// `active` or `map-N` (the inactive graph's id).
    name: String,
    vertices: usize,
    edges: usize,
    epochs: Vec<u32>,
    g2o: PathBuf,
    map_yaml: PathBuf,
    png: PathBuf,
    trajectories: Vec<PathBuf>,
}

/// Writes every non-empty graph of a version (see [`StoreCommand::Export`]).
fn export(args: &ExportArgs) -> anyhow::Result<()> {
    crate::check_resolution(args.resolution)?;
    let store = open(&args.site)?;
    let Some(stored) = store.load(args.version).map_err(refused)? else {
        return Err(crate::bad_input(format!(
            "{}: the store has no version yet",
            args.site.site.display()
        )));
    };
    std::fs::create_dir_all(&args.output)
        .with_context(|| format!("creating {}", args.output.display()))?;
    let atlas = &stored.atlas;
    let graphs = std::iter::once(("active".to_owned(), &atlas.active)).chain(
        atlas
            .inactive
            .iter()
            .map(|(id, g)| (format!("map-{}", id.0), g)),
    );
    let thresholds = ClassThresholds::default();
    let mut maps = Vec::new();
    for (name, graph) in graphs.filter(|(_, g)| g.num_vertices() > 0) {
        let g2o = args.output.join(format!("{name}.g2o"));
        mapmerge_io::write_graph(&g2o, &AnyGraph::Planar(graph.clone()), GraphFormat::G2o)
            .map_err(anyhow::Error::from)?;
        // The grid: the graph's local maps rendered (iRobot Sec. 3.3), else every keyframe's
        // beams from its vertex (a graph without local maps).
        let grid = match RenderedMap::render(graph, &atlas.local_maps, args.resolution)
            .and_then(|rendered| rendered.to_grid())
        {
            Some(grid) => grid,
            None => {
                let mut grid = OccupancyGrid::new(args.resolution)?;
                let model = InsertParams::default().model;
                for (node, vertex) in graph.vertices() {
                    let Some(keyframe) = atlas.keyframes.get(&node) else {
                        continue;
                    };
                    let ends: Vec<Point2> = keyframe
                        .points_in_robot
                        .iter()
                        .map(|p| vertex.pose.transform_point(p))
                        .collect();
                    grid.insert_rays(&vertex.pose.translation(), &ends, &[], &model)?;
                }
                grid
            }
        };
        let map_yaml = args.output.join(format!("{name}.yaml"));
        mapmerge_io::write_ros_map(
            &map_yaml,
            &RosMap::from_grid(&grid, MapMode::Trinary, &thresholds),
        )?;
        let png = args.output.join(format!("{name}.png"));
        let style = PictureStyle {
            pixels_per_cell: 1,
            classes: Some(thresholds),
        };
        // One trajectory per epoch, stamped with the vertices' stamps (else their order).
        let mut by_epoch: BTreeMap<u32, Vec<(f64, Se2)>> = BTreeMap::new();
        for (k, (_, vertex)) in graph.vertices().enumerate() {
            let stamp = vertex.meta.stamp_secs.unwrap_or(k as f64);
            by_epoch
                .entry(vertex.meta.session.0)
                .or_default()
                .push((stamp, vertex.pose));
        }
        let mut picture = Picture::of_grid(&grid, &style);
        for (epoch, poses) in &by_epoch {
            let poses: Vec<Se2> = poses.iter().map(|(_, pose)| *pose).collect();
            picture.draw_trajectory(&poses, session_color(u64::from(*epoch)), 1.0);
        }
        picture.save_png(&png)?;
        let mut trajectories = Vec::new();
        for (epoch, poses) in &by_epoch {
            let path = args.output.join(format!("{name}-epoch-{epoch}.tum"));
            mapmerge_io::write_tum_planar(&path, poses)?;
            trajectories.push(path);
        }
        maps.push(ExportedMap {
            name,
            vertices: graph.num_vertices(),
            edges: graph.num_edges(),
            epochs: by_epoch.keys().copied().collect(),
            g2o,
            map_yaml,
            png,
            trajectories,
        });
    }
    if args.site.json {
        #[derive(Serialize)]
        struct Report<'a> {
            version: i64,
            maps: &'a [ExportedMap],
        }
        print_json(&Report {
            version: stored.version,
            maps: &maps,
        })?;
    } else {
        for m in &maps {
            println!(
                "version {}: {} ({} vertices, {} edges, epochs {:?}) -> {}, {}, {}, {} trajectories",
                stored.version,
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
    }
    Ok(())
}
