//! Assembling segments without initial guesses, in any order (`mapmerge assemble`,
//! AutoMerge): segments from logs or bags (trajectories by SLAM or odometry) or KITTI-style
//! folders, arrivals one at a time, groups, one pose graph per group.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use mapmerge_assemble::{
    load_kitti_folder, segment3_from_clouds, solve_group, Arrival, AssembleParams, Assembler,
    GroundSlice, GroupSolution, KittiFolderOptions, RingSpectrum3Params, RingSpectrumDescriptor3,
    Segment, Segment3, SegmentLoop, SubmapParams,
};
use mapmerge_engine::EngineParams;
use mapmerge_rosbag::TopicChoice;
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::Serialize;

use crate::session::{log_file_stem, read_session_log_with, slam_log};
use crate::JobError;

/// Arrival order of the segments.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Order {
    /// As given.
    Given,
    /// Shuffled with the seed.
    Random,
}

/// Where each segment's trajectory comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum TrajectorySource {
    /// The project's 2D SLAM front-end on the segment's scans and odometry.
    Slam,
    /// The log's odometry as it is.
    Odometry,
}

impl crate::Choice for Order {
    const NAMES: &'static [(&'static str, Self)] =
        &[("given", Self::Given), ("random", Self::Random)];
    const WHAT: &'static str = "order";
}

impl crate::Choice for TrajectorySource {
    const NAMES: &'static [(&'static str, Self)] =
        &[("slam", Self::Slam), ("odometry", Self::Odometry)];
    const WHAT: &'static str = "trajectory";
}

/// A segment's name: a log's file stem ([`log_file_stem`]), a folder's name.
pub fn segment_name(path: &Path) -> String {
    log_file_stem(path)
}

/// A segment as read: 2D (a log or laser bag with its trajectory) or 3D (a KITTI-style folder,
/// a bag of PointCloud2 with odometry).
pub enum LoadedSegment {
    /// A log or bag with its trajectory.
    Planar(Segment),
    /// A KITTI-style folder or a PointCloud2 bag.
    Spatial(Segment3),
}

/// Reads the segments (in parallel): logs or laser bags with their trajectories (one
/// front-end each), or 3D segments (KITTI-style folders, PointCloud2 bags), calling
/// `loaded()` after each. Mixing 2D and 3D, two segments of one name, an unreadable segment
/// are bad input.
pub fn load_segments(
    paths: &[PathBuf],
    topics: &TopicChoice,
    source: TrajectorySource,
    loaded: impl Fn() + Sync,
) -> Result<Vec<LoadedSegment>, JobError> {
    let mut spatial = Vec::with_capacity(paths.len());
    for path in paths {
        spatial.push(is_folder_segment(path) || is_cloud_bag(path)?);
    }
    if let Some(k) = spatial
        .iter()
        .position(|&s| s)
        .filter(|_| spatial.contains(&false))
    {
        return Err(JobError::bad_input(format!(
            "{}: a 3D segment among 2D ones; segments are either laser logs or bags (2D), or \
             KITTI-style folders and PointCloud2 bags (3D), not both",
            paths[k].display()
        )));
    }
    let mut names = BTreeMap::new();
    for path in paths {
        if let Some(other) = names.insert(segment_name(path), path) {
            return Err(JobError::bad_input(format!(
                "{} and {} have the same name `{}`",
                other.display(),
                path.display(),
                segment_name(path)
            )));
        }
    }
    let segments: Vec<Result<LoadedSegment, JobError>> = paths
        .par_iter()
        .zip(&spatial)
        .map(|(path, &spatial)| {
            let segment = if spatial {
                load_segment_3d(path, topics)?
            } else {
                load_segment(path, topics, source)?
            };
            loaded();
            Ok(segment)
        })
        .collect();
    segments.into_iter().collect()
}

/// A folder is a 3D segment unless it is a ROS 2 bag folder.
fn is_folder_segment(path: &Path) -> bool {
    path.is_dir() && !mapmerge_rosbag::is_bag(path)
}

/// True when `path` is a bag of PointCloud2 without LaserScan (a 3D segment).
fn is_cloud_bag(path: &Path) -> Result<bool, JobError> {
    if !mapmerge_rosbag::is_bag(path) {
        return Ok(false);
    }
    let topics = mapmerge_rosbag::list_topics(path).map_err(|e| JobError::bad_file(&e))?;
    let has = |message_type: &str| topics.iter().any(|t| t.message_type == message_type);
    Ok(has(mapmerge_rosbag::POINT_CLOUD2_TYPE) && !has(mapmerge_rosbag::LASER_SCAN_TYPE))
}

/// A 3D segment: a KITTI-style folder, or a PointCloud2 bag with odometry.
fn load_segment_3d(path: &Path, topics: &TopicChoice) -> Result<LoadedSegment, JobError> {
    let segment = if is_folder_segment(path) {
        load_kitti_folder(path, &KittiFolderOptions::default())
    } else {
        let session = mapmerge_rosbag::read_cloud_session(path, None, topics.odom_topic.as_deref())
            .map_err(|e| JobError::bad_file(&e))?;
        let clouds: Vec<_> = session.clouds.into_iter().map(|c| c.points).collect();
        segment3_from_clouds(
            segment_name(path),
            &session.odom_from_sensor,
            &clouds,
            &KittiFolderOptions::default(),
        )
    }
    .map_err(JobError::bad_input)?;
    Ok(LoadedSegment::Spatial(segment))
}

fn load_segment(
    path: &Path,
    topics: &TopicChoice,
    source: TrajectorySource,
) -> Result<LoadedSegment, JobError> {
    let log = read_session_log_with(path, topics)?;
    let name = segment_name(path);
    let segment = match source {
        TrajectorySource::Odometry => Segment::from_log_odometry(name, &log),
        TrajectorySource::Slam => {
            let run = slam_log(path, &log, EngineParams::default(), |_| {})?;
            Segment::from_log(name, &log, &run.trajectory)
        }
    }
    .map_err(|e| JobError::bad_input(format!("{}: {e}", path.display())))?;
    Ok(LoadedSegment::Planar(segment))
}

/// The parameters without a configuration: the defaults, and for 3D segments the paper's
/// outdoor submaps (5 m / 50 m).
pub fn default_params(spatial: bool) -> AssembleParams {
    let mut params = AssembleParams::default();
    if spatial {
        let submaps = SubmapParams::outdoor();
        params.descriptor.max_radius_m = submaps.radius_m;
        params.submaps = submaps;
    }
    params
}

/// The arrival order: indices into `count` segments.
pub fn arrival_order(count: usize, order: Order, seed: u64) -> Vec<usize> {
    let mut indices: Vec<usize> = (0..count).collect();
    if order == Order::Random {
        indices.shuffle(&mut ChaCha8Rng::seed_from_u64(seed));
    }
    indices
}

/// An assembly: the assembler after every arrival, the arrivals in order, the groups and
/// each group's pose graph solution (in the order of the groups).
pub struct Assembled {
    /// The segments, pairs, loops and groups.
    pub assembler: Assembler,
    /// What each arrival did.
    pub arrivals: Vec<Arrival>,
    /// Segment names per group.
    pub groups: Vec<Vec<String>>,
    /// Every scan's pose in its group's frame, per group.
    pub solutions: Vec<GroupSolution>,
    /// Wall time of the arrivals (s).
    pub association_secs: f64,
    /// Wall time of the groups' pose graphs (s).
    pub optimisation_secs: f64,
}

/// Assembles `segments` arriving in `order` (indices into `segments`), calling
/// `arrived(k, arrival)` after the `k`-th arrival, then solves each group's pose graph.
pub fn assemble(
    segments: Vec<LoadedSegment>,
    params: AssembleParams,
    order: &[usize],
    mut arrived: impl FnMut(usize, &Arrival),
) -> Result<Assembled, JobError> {
    let descriptor3 = RingSpectrumDescriptor3::new(&RingSpectrum3Params {
        max_radius_m: params.submaps.radius_m,
        ..RingSpectrum3Params::default()
    });
    let mut assembler = Assembler::new(params).map_err(JobError::bad_input)?;
    let mut slots: Vec<Option<LoadedSegment>> = segments.into_iter().map(Some).collect();
    let started = Instant::now();
    let mut arrivals = Vec::with_capacity(order.len());
    for (k, &i) in order.iter().enumerate() {
        let Some(segment) = slots.get_mut(i).and_then(Option::take) else {
            continue;
        };
        let arrival = match segment {
            LoadedSegment::Planar(segment) => assembler.add_segment(segment),
            LoadedSegment::Spatial(segment) => assembler.add_segment_3d(
                &segment,
                &descriptor3,
                &GroundSlice::default(),
                &BTreeMap::new(),
            ),
        }
        .map_err(|e| JobError::failed(&e))?;
        arrived(k, &arrival);
        arrivals.push(arrival);
    }
    let association_secs = started.elapsed().as_secs_f64();
    let started = Instant::now();
    let groups = assembler.groups().map_err(|e| JobError::failed(&e))?;
    let solutions = groups
        .iter()
        .map(|group| {
            solve_group(&assembler, group, &assembler.params().graph)
                .map_err(|e| JobError::failed(&e))
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok(Assembled {
        assembler,
        arrivals,
        groups,
        solutions,
        association_secs,
        optimisation_secs: started.elapsed().as_secs_f64(),
    })
}

impl Assembled {
    /// Pairs associated and kept (ω > 0, not rejected by the consistency check).
    pub fn pairs_associated(&self) -> usize {
        self.assembler
            .pairs()
            .iter()
            .filter(|(key, p)| p.weight > 0.0 && !self.assembler.rejected_pairs().contains(*key))
            .count()
    }

    /// Every inter-segment loop edge, as a line of `loops.jsonl`.
    pub fn loop_lines(&self) -> Vec<LoopLine<'_>> {
        self.assembler.loops().map(LoopLine::of).collect()
    }
}

/// One inter-segment loop edge (a line of `loops.jsonl`): scans of two segments and the
/// relative pose `from_from_to` as `[x, y, yaw]` (m, rad).
#[derive(Clone, Debug, Serialize)]
pub struct LoopLine<'a> {
    /// The first scan.
    pub from: ScanRef<'a>,
    /// The second scan.
    pub to: ScanRef<'a>,
    /// `from_from_to`.
    pub transform: [f64; 3],
    /// The verification score.
    pub score: f64,
}

/// A scan of a segment.
#[derive(Clone, Debug, Serialize)]
pub struct ScanRef<'a> {
    /// The segment's name.
    pub segment: &'a str,
    /// The scan's index in it.
    pub scan: usize,
}

impl<'a> LoopLine<'a> {
    fn of(l: &'a SegmentLoop) -> Self {
        Self {
            from: ScanRef {
                segment: &l.from_segment,
                scan: l.from_scan,
            },
            to: ScanRef {
                segment: &l.to_segment,
                scan: l.to_scan,
            },
            transform: [
                l.from_from_to.x_m,
                l.from_from_to.y_m,
                l.from_from_to.theta_rad,
            ],
            score: l.score,
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    #[test]
    fn two_segments_of_one_name_are_bad_input() {
        let paths = [PathBuf::from("a/x.log"), PathBuf::from("b/x.log.xz")];
        let err = load_segments(
            &paths,
            &TopicChoice::default(),
            TrajectorySource::Odometry,
            || {},
        )
        .err()
        .unwrap();
        assert_eq!(
            err,
            JobError::BadInput("a/x.log and b/x.log.xz have the same name `x`".into())
        );
    }

    #[test]
    fn a_random_order_is_a_seeded_permutation() {
        let order = arrival_order(6, Order::Random, 3);
        let mut sorted = order.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..6).collect::<Vec<_>>());
        assert_eq!(order, arrival_order(6, Order::Random, 3));
        assert_eq!(arrival_order(3, Order::Given, 3), vec![0, 1, 2]);
    }
}
