//! GNC against vertigo-style false loop closures on a public graph: the targets as
//! correctness checks (precision/recall of rejections, distance to the outlier-free optimum).
#![allow(clippy::unwrap_used)]

use mapmerge_eval::{
    add_false_loop_closures, count_loop_closures, precision_recall, trajectory_error,
};
use mapmerge_io::{read_graph, AnyGraph};
use mapmerge_posegraph::PoseGraph2;
use mapmerge_solve::{optimize, optimize_gnc, GncParams, OptimizerParams};

fn planar(relative: &str) -> Option<PoseGraph2> {
    let path = mapmerge_testkit::shared_data(relative)?;
    match read_graph(&path).unwrap().graph {
        AnyGraph::Planar(g) => Some(g),
        AnyGraph::Spatial(_) => panic!("{relative} is planar"),
    }
}

const M3500: &str = "g2o/openslam_g2o/manhattanOlson3500.g2o";
const CITY10000: &str = "g2o/se-sync/city10000.g2o.xz";

fn check(graph: &str, fraction: f64, seed: u64) {
    let Some(clean) = planar(graph) else { return };
    let mut reference = clean.clone();
    optimize(&mut reference, &OptimizerParams::default()).unwrap();
    let true_loops = count_loop_closures(&clean);
    let mut corrupted = clean.clone();
    let false_edges = add_false_loop_closures(&mut corrupted, fraction, seed).unwrap();
    let gnc = optimize_gnc(&mut corrupted, &GncParams::default()).unwrap();
    let score = precision_recall(&gnc.rejected, &false_edges, true_loops);
    let error = trajectory_error(&reference, &corrupted, false).unwrap();
    println!(
        "fraction {fraction}: {} false, {} rejected, recall {:.4}, true kept {:.4}, rms {:.4} m, steps {}, inner {}",
        false_edges.len(), gnc.rejected.len(), score.recall, score.true_loops_kept, error.rms_m, gnc.steps, gnc.inner_iterations
    );
    assert!(score.recall >= 0.99, "{score:?}");
    assert!(score.true_loops_kept >= 0.99, "{score:?}");
    assert!(error.rms_m <= 0.05, "{error:?}");
}

#[test]
fn gnc_rejects_ten_percent_false_loops_on_m3500() {
    check(M3500, 0.1, 7);
}

#[test]
fn gnc_rejects_fifty_percent_false_loops_on_m3500() {
    check(M3500, 0.5, 7);
}

/// A long chain whose initial guess drifts far from where its loop closures put it: the
/// cycle-consistent seeds keep the first estimate from folding.
#[test]
fn gnc_rejects_fifty_percent_false_loops_on_city10000() {
    check(CITY10000, 0.5, 7);
}
