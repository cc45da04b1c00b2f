//! `mapmerge ros2 slam|merge`: the live nodes (`mapmerge_ros2`, feature `ros2`), on the ROS 2
//! graph of `ROS_DOMAIN_ID` (or `--domain`), until SIGINT (Ctrl-C): the store is committed and
//! the report printed before the node leaves.
//!
//! Exit codes: 0 stopped cleanly, 2 bad input, 1 any other failure.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};

use clap::{Args, Subcommand, ValueEnum};
use mapmerge_engine::EngineParams;
use mapmerge_gridmatch::GridMatchParams;
use mapmerge_ros2::{
    check_domain, domain_from_env, run_merge_node, run_slam_node, Delivery, MergeNodeOptions,
    SlamNodeOptions,
};

use crate::{job_error, print_json};

/// Set by SIGINT and SIGTERM: the node stops at its next turn.
static STOP: AtomicBool = AtomicBool::new(false);

#[cfg(unix)]
extern "C" fn on_signal(_: libc::c_int) {
    STOP.store(true, Ordering::Relaxed);
}

fn stop_on_signals() {
    #[cfg(unix)]
    // SAFETY: the handler only stores to an atomic, which is async-signal-safe.
    unsafe {
        libc::signal(libc::SIGINT, on_signal as *const () as libc::sighandler_t);
        libc::signal(libc::SIGTERM, on_signal as *const () as libc::sighandler_t);
    }
}

/// Arguments of `mapmerge ros2`.
#[derive(Args, Debug)]
pub struct Ros2Args {
    #[command(subcommand)]
    pub command: Ros2Command,
    /// The ROS 2 domain (default: `ROS_DOMAIN_ID`, else 0).
    #[arg(long, global = true)]
    pub domain: Option<u16>,
    /// Stop after this many seconds (default: at SIGINT).
    #[arg(long, global = true)]
    pub duration: Option<f64>,
    /// Print one JSON report at the end instead of text.
    #[arg(long, global = true)]
    pub json: bool,
}

/// The live nodes.
#[derive(Subcommand, Debug)]
pub enum Ros2Command {
    /// The lifelong engine on /scan, /odom, /tf, /tf_static; publishes /map, /tf map → odom
    /// and /mapmerge/events.
    Slam(SlamNodeArgs),
    /// m-explore-ros2's map_merge: every /<robot>/map merged without initial poses into /map.
    Merge(MergeNodeArgs),
}

/// How scans and odometry are heard.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum DeliveryChoice {
    /// Hears every publisher (ROS's sensor-data QoS).
    BestEffort,
    /// Hears reliable publishers only, and loses nothing they send.
    Reliable,
}

/// Arguments of `mapmerge ros2 slam`.
#[derive(Args, Debug)]
pub struct SlamNodeArgs {
    /// The LaserScan topic.
    #[arg(long, default_value = "/scan")]
    pub scan_topic: String,
    /// The Odometry topic.
    #[arg(long, default_value = "/odom")]
    pub odom_topic: String,
    /// QoS of the scan and odometry subscriptions.
    #[arg(long, value_enum, default_value_t = DeliveryChoice::BestEffort)]
    pub qos: DeliveryChoice,
    /// Engine parameters (JSON, `mapmerge_engine::EngineParams`, as `atlas --config`).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Lifelong store (SQLite; created when missing): the session continues its newest
    /// atlas and is committed when the node stops.
    #[arg(long)]
    pub store: Option<PathBuf>,
    /// The session's name in the store.
    #[arg(long, default_value = "live")]
    pub session: String,
    /// Newest store versions that keep their atlas.
    #[arg(long, default_value_t = mapmerge_jobs::DEFAULT_KEEP_VERSIONS)]
    pub keep_versions: usize,
    /// Cell side of /map (m).
    #[arg(long, default_value_t = 0.05)]
    pub resolution: f64,
    /// Seconds between /map publications.
    #[arg(long, default_value_t = 5.0)]
    pub map_period: f64,
    /// The map frame.
    #[arg(long, default_value = "map")]
    pub map_frame: String,
    /// Stop once no scan has come for this many seconds (after the first).
    #[arg(long)]
    pub quiet: Option<f64>,
}

/// Arguments of `mapmerge ros2 merge`.
#[derive(Args, Debug)]
pub struct MergeNodeArgs {
    /// The robots' map topic under their namespaces (m-explore's `robot_map_topic`).
    #[arg(long, default_value = "map")]
    pub robot_map_topic: String,
    /// The merged map's topic (m-explore's `merged_map_topic`).
    #[arg(long, default_value = "/map")]
    pub merged_map_topic: String,
    /// The robot whose map frame /map takes (default: the first by name).
    #[arg(long)]
    pub reference: Option<String>,
    /// Matching parameters (JSON, as `grid-merge --config`).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Seconds between merges of changed maps and /map publications.
    #[arg(long, default_value_t = 1.0)]
    pub period: f64,
}

/// Runs `mapmerge ros2`.
pub fn run(args: &Ros2Args) -> anyhow::Result<ExitCode> {
    let domain = match args.domain {
        Some(d) => check_domain(d),
        None => domain_from_env(),
    }
    .map_err(job_error)?;
    let say = |line: &str| eprintln!("mapmerge: {line}");
    stop_on_signals();
    match &args.command {
        Ros2Command::Slam(slam) => {
            let options = SlamNodeOptions {
                domain,
                scan_topic: slam.scan_topic.clone(),
                odom_topic: slam.odom_topic.clone(),
                delivery: match slam.qos {
                    DeliveryChoice::BestEffort => Delivery::BestEffort,
                    DeliveryChoice::Reliable => Delivery::Reliable,
                },
                params: crate::read_config::<EngineParams>(slam.config.as_deref())?,
                resolution_m: slam.resolution,
                map_period_s: slam.map_period,
                map_frame: slam.map_frame.clone(),
                store: slam.store.clone(),
                keep_versions: slam.keep_versions,
                session: slam.session.clone(),
                duration_s: args.duration,
                quiet_s: slam.quiet,
            };
            let (report, _) = run_slam_node(&options, &STOP, say).map_err(job_error)?;
            if args.json {
                print_json(&report)?;
            } else {
                println!(
                    "{} scans heard, {} mapped; {} epochs started, {} merges, {} undone; pose out {:.1} ms median, {:.1} ms p99; {} maps published{}",
                    report.scans_heard,
                    report.scans_mapped,
                    report.epochs_started,
                    report.merges,
                    report.unmerges,
                    report.pose_latency.median_ms,
                    report.pose_latency.p99_ms,
                    report.maps_published,
                    report
                        .committed
                        .as_ref()
                        .map(|c| format!("; committed store version {}", c.version.version))
                        .unwrap_or_default()
                );
            }
        }
        Ros2Command::Merge(merge) => {
            let options = MergeNodeOptions {
                domain,
                robot_map_topic: merge.robot_map_topic.clone(),
                merged_map_topic: merge.merged_map_topic.clone(),
                reference: merge.reference.clone(),
                params: crate::read_config::<GridMatchParams>(merge.config.as_deref())?,
                period_s: merge.period,
                duration_s: args.duration,
            };
            let report = run_merge_node(&options, &STOP, say).map_err(job_error)?;
            if args.json {
                print_json(&report)?;
            } else {
                println!(
                    "{} robots, {} merged maps published, {} matches in {:.1} s",
                    report.robots.len(),
                    report.published,
                    report.matches,
                    report.match_seconds
                );
            }
        }
    }
    Ok(ExitCode::SUCCESS)
}
