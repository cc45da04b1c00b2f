//! The lifelong store's jobs beyond what `mapmerge-store` does itself: opening a site (every
//! refused store is the user's file: bad input), erroneous protrusions of a version against
//! its parent (iRobot Sec. 5.4), and a version's maps written out as g2o, map_server grids,
//! pictures and one TUM trajectory per epoch.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use mapmerge_atlas::RenderedMap;
use mapmerge_geometry::Se2;
use mapmerge_grid::{ClassThresholds, InsertParams, OccupancyGrid, Point2};
use mapmerge_io::{AnyGraph, GraphFormat, MapMode, RosMap};
use mapmerge_render::{session_color, Picture, PictureStyle};
use mapmerge_store::{Store, StoreError};
use serde::Serialize;

use crate::JobError;

/// Store errors are the user's file: bad input.
fn refused(error: StoreError) -> JobError {
    JobError::bad_file(&error)
}

/// Opens the store at `path` for writing, checked first; bad input when there is none.
pub fn open_store(path: &Path) -> Result<Store, JobError> {
    require_file(path)?;
    Store::open_existing(path).map_err(refused)
}

/// Opens the store at `path` for reading only; bad input when there is none.
pub fn open_store_read_only(path: &Path) -> Result<Store, JobError> {
    require_file(path)?;
    Store::open_read_only(path).map_err(refused)
}

fn require_file(path: &Path) -> Result<(), JobError> {
    if path.is_file() {
        Ok(())
    } else {
        Err(JobError::bad_input(format!(
            "{}: no such store",
            path.display()
        )))
    }
}

/// Opens the store at `path`, creating it when there is no file (`atlas --store`).
pub fn open_or_create_store(path: &Path) -> Result<Store, JobError> {
    Store::open(path).map_err(refused)
}

/// What to do with a version's protrusions once found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ProtrusionAction {
    /// Report them only.
    Report,
    /// Remove them: the version's new local maps lose those cells, committed as a new version.
    Remove,
    /// Roll the version back to its parent.
    Rollback,
}

/// One region of new space as `store protrusions` reports it.
#[derive(Clone, Debug, Serialize)]
pub struct RegionReport {
    /// Its centre (m, map frame).
    pub centre_m: [f64; 2],
    /// The classifier's features.
    pub features: mapmerge_atlas::RegionFeatures,
    /// Whether it was classified a protrusion.
    pub protrusion: bool,
}

/// What `store protrusions` found and did (the object `--json` prints).
#[derive(Clone, Debug, Serialize)]
pub struct ProtrusionReport {
    /// The version checked.
    pub version: i64,
    /// Its parent.
    pub parent: i64,
    /// Every region of new space.
    pub regions: Vec<RegionReport>,
    /// How many are protrusions.
    pub protrusions: usize,
    /// The version committed without them (`Remove`).
    pub new_version: Option<i64>,
    /// Whether the version was rolled back (`Rollback`).
    pub rolled_back: bool,
}

/// Erroneous protrusions (iRobot Sec. 5.4) of `version` (default: the newest) of the store at
/// `site`: the space new since its parent, classified region by region; then `action`.
pub fn store_protrusions(
    site: &Path,
    version: Option<i64>,
    action: ProtrusionAction,
) -> Result<ProtrusionReport, JobError> {
    let mut store = match action {
        ProtrusionAction::Report => open_store_read_only(site)?,
        ProtrusionAction::Remove | ProtrusionAction::Rollback => open_store(site)?,
    };
    let Some(child) = store.load(version).map_err(refused)? else {
        return Err(JobError::bad_input(format!(
            "{}: the store has no version yet",
            site.display()
        )));
    };
    let parent_version = store
        .versions()
        .map_err(refused)?
        .into_iter()
        .find(|v| v.version == child.version)
        .and_then(|v| v.parent)
        .ok_or_else(|| {
            JobError::bad_input(format!(
                "version {} has no parent to compare with",
                child.version
            ))
        })?;
    let parent = store
        .load(Some(parent_version))
        .map_err(refused)?
        .ok_or_else(|| JobError::bad_input(format!("no version {parent_version}")))?;
    let params = mapmerge_atlas::ProtrusionParams::default();
    let classifier = mapmerge_atlas::ProtrusionClassifier::trained().map_err(JobError::Failed)?;
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
    let verdicts = classifier.predict(&features).map_err(JobError::Failed)?;
    let found: Vec<&mapmerge_atlas::Region> = regions
        .iter()
        .zip(&verdicts)
        .filter(|(_, p)| **p)
        .map(|(r, _)| r)
        .collect();
    let mut new_version = None;
    let mut rolled_back = false;
    if !found.is_empty() && action == ProtrusionAction::Remove {
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
    } else if !found.is_empty() && action == ProtrusionAction::Rollback {
        store.rollback_to(parent_version).map_err(refused)?;
        rolled_back = true;
    }
    let reports: Vec<RegionReport> = regions
        .iter()
        .zip(&verdicts)
        .map(|(r, p)| RegionReport {
            centre_m: r.centre_m,
            features: r.features,
            protrusion: *p,
        })
        .collect();
    Ok(ProtrusionReport {
        version: child.version,
        parent: parent_version,
        protrusions: found.len(),
        regions: reports,
        new_version,
        rolled_back,
    })
}

/// One exported map's files.
#[derive(Clone, Debug, Serialize)]
pub struct ExportedMap {
    /// `active` or `map-N` (the inactive graph's id).
    pub name: String,
    pub vertices: usize,
    pub edges: usize,
    pub epochs: Vec<u32>,
    pub g2o: PathBuf,
    pub map_yaml: PathBuf,
    pub png: PathBuf,
    pub trajectories: Vec<PathBuf>,
}

/// What `store export` wrote (the object `--json` prints).
#[derive(Clone, Debug, Serialize)]
pub struct ExportReport {
    /// The version written.
    pub version: i64,
    /// Its maps.
    pub maps: Vec<ExportedMap>,
}

/// Writes every non-empty graph of `version` (default: the newest) of the store at `site`
/// into `output`: its pose graph (g2o), its occupancy grid at `resolution_m` (map_server PGM
/// + YAML; its local maps rendered) with a picture, and one TUM trajectory per epoch.
pub fn export_version(
    site: &Path,
    version: Option<i64>,
    resolution_m: f64,
    output: &Path,
) -> Result<ExportReport, JobError> {
    crate::check_resolution(resolution_m)?;
    let store = open_store_read_only(site)?;
    let Some(stored) = store.load(version).map_err(refused)? else {
        return Err(JobError::bad_input(format!(
            "{}: the store has no version yet",
            site.display()
        )));
    };
    std::fs::create_dir_all(output).map_err(|e| JobError::writing(output, &e))?;
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
        let g2o = output.join(format!("{name}.g2o"));
        mapmerge_io::write_graph(&g2o, &AnyGraph::Planar(graph.clone()), GraphFormat::G2o)
            .map_err(|e| JobError::writing(&g2o, &e))?;
        // The grid: the graph's local maps rendered (iRobot Sec. 3.3), else every keyframe's
        // beams from its vertex (a graph without local maps).
        let grid = match RenderedMap::render(graph, &atlas.local_maps, resolution_m)
            .and_then(|rendered| rendered.to_grid())
        {
            Some(grid) => grid,
            None => {
                let mut grid = OccupancyGrid::new(resolution_m)
                    .map_err(|e| JobError::context("building the grid", &e))?;
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
                    grid.insert_rays(&vertex.pose.translation(), &ends, &[], &model)
                        .map_err(|e| JobError::context("building the grid", &e))?;
                }
                grid
            }
        };
        let map_yaml = output.join(format!("{name}.yaml"));
        mapmerge_io::write_ros_map(
            &map_yaml,
            &RosMap::from_grid(&grid, MapMode::Trinary, &thresholds),
        )
        .map_err(|e| JobError::writing(&map_yaml, &e))?;
        let png = output.join(format!("{name}.png"));
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
        picture
            .save_png(&png)
            .map_err(|e| JobError::writing(&png, &e))?;
        let mut trajectories = Vec::new();
        for (epoch, poses) in &by_epoch {
            let path = output.join(format!("{name}-epoch-{epoch}.tum"));
            mapmerge_io::write_tum_planar(&path, poses)
                .map_err(|e| JobError::writing(&path, &e))?;
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
    Ok(ExportReport {
        version: stored.version,
        maps,
    })
}
