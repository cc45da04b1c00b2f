//! LAGO and chordal initialisation on public benchmark graphs (from `../shared/data/g2o`):
//! the initial guess must have a much lower chi2 than odometry chaining and, where the file's
//! own guess is plain odometry, than that too. Run with `--nocapture` to see the numbers.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common {
    //! The public se-sync graphs, read as `mapmerge optimize` reads them.
    use mapmerge_io::{read_graph_with, AnyGraph, BadInformation, ReadParams};
    use mapmerge_posegraph::{PoseGraph2, PoseGraph3};

    /// A 2D graph from `../shared/data/g2o/se-sync`, or `None` when the data folder is absent
    /// (outside CI). Non-positive-definite information matrices keep their diagonal.
    pub fn load_2d(name: &str) -> Option<PoseGraph2> {
        match load(name)? {
            AnyGraph::Planar(g) => Some(g),
            AnyGraph::Spatial(_) => panic!("{name} is 3D"),
        }
    }

    /// A 3D graph from `../shared/data/g2o/se-sync` (see [`load_2d`]).
    pub fn load_3d(name: &str) -> Option<PoseGraph3> {
        match load(name)? {
            AnyGraph::Spatial(g) => Some(g),
            AnyGraph::Planar(_) => panic!("{name} is 2D"),
        }
    }

    fn load(name: &str) -> Option<AnyGraph> {
        let path = mapmerge_testkit::shared_data(&format!("g2o/se-sync/{name}"))?;
        let params = ReadParams {
            bad_information: BadInformation::KeepDiagonal,
        };
        Some(read_graph_with(&path, &params).unwrap().graph)
    }
}

use std::time::Instant;

use mapmerge_init::{
    initialize_chordal, initialize_lago, initialize_odometry, ChordalParams, LagoParams,
    RotationWeighting,
};

struct Chi2 {
    file: f64,
    odometry: f64,
    init: f64,
    init_secs: f64,
}

fn run_2d(name: &str) -> Option<Chi2> {
    let graph = common::load_2d(name)?;
    assert!(
        graph.num_edges() > 1000,
        "{name}: parsed only {} edges",
        graph.num_edges()
    );
    let mut odo = graph.clone();
    initialize_odometry(&mut odo).unwrap();
    let mut init = graph.clone();
    let start = Instant::now();
    let info = initialize_lago(&mut init, &LagoParams::default()).unwrap();
    let init_secs = start.elapsed().as_secs_f64();
    assert_eq!(info.components, 1, "{name}");
    let chi2 = Chi2 {
        file: graph.chi2(),
        odometry: odo.chi2(),
        init: init.chi2(),
        init_secs,
    };
    println!(
        "{name}: {} vertices, {} edges; chi2 file {:.6e}, odometry {:.6e}, LAGO {:.6e} ({:.3} s, {} angle corrections)",
        graph.num_vertices(),
        graph.num_edges(),
        chi2.file,
        chi2.odometry,
        chi2.init,
        chi2.init_secs,
        info.angle_corrections
    );
    Some(chi2)
}

fn run_3d(name: &str) -> Option<Chi2> {
    let graph = common::load_3d(name)?;
    assert!(
        graph.num_edges() > 1000,
        "{name}: parsed only {} edges",
        graph.num_edges()
    );
    let mut odo = graph.clone();
    initialize_odometry(&mut odo).unwrap();
    let mut init = graph.clone();
    let start = Instant::now();
    let info = initialize_chordal(&mut init, &ChordalParams::default()).unwrap();
    let init_secs = start.elapsed().as_secs_f64();
    assert_eq!(info.components, 1, "{name}");
    let chi2 = Chi2 {
        file: graph.chi2(),
        odometry: odo.chi2(),
        init: init.chi2(),
        init_secs,
    };
    println!(
        "{name}: {} vertices, {} edges; chi2 file {:.6e}, odometry {:.6e}, chordal {:.6e} ({:.3} s)",
        graph.num_vertices(),
        graph.num_edges(),
        chi2.file,
        chi2.odometry,
        chi2.init,
        chi2.init_secs
    );
    Some(chi2)
}

#[test]
fn chordal_beats_the_file_guess_and_odometry_on_torus3d() {
    let Some(c) = run_3d("torus3D.g2o.xz") else {
        return;
    };
    assert!(
        c.init < 0.01 * c.file,
        "chordal {} vs file {}",
        c.init,
        c.file
    );
    assert!(
        c.init < 0.01 * c.odometry,
        "chordal {} vs odometry {}",
        c.init,
        c.odometry
    );
}

#[test]
fn chordal_beats_the_file_guess_and_odometry_on_cubicle() {
    let Some(c) = run_3d("cubicle.g2o.xz") else {
        return;
    };
    assert!(
        c.init < 0.01 * c.file,
        "chordal {} vs file {}",
        c.init,
        c.file
    );
    assert!(
        c.init < 0.01 * c.odometry,
        "chordal {} vs odometry {}",
        c.init,
        c.odometry
    );
}

#[test]
fn chordal_beats_odometry_on_sphere2500() {
    let Some(c) = run_3d("sphere2500.g2o.xz") else {
        return;
    };
    assert!(
        c.init < 0.01 * c.odometry,
        "chordal {} vs odometry {}",
        c.init,
        c.odometry
    );
}

#[test]
fn lago_beats_odometry_and_the_file_guess_on_ais2klinik() {
    let Some(c) = run_2d("ais2klinik.g2o.xz") else {
        return;
    };
    assert!(
        c.init < 0.01 * c.odometry,
        "LAGO {} vs odometry {}",
        c.init,
        c.odometry
    );
    assert!(c.init < 0.2 * c.file, "LAGO {} vs file {}", c.init, c.file);
}

#[test]
fn lago_beats_odometry_and_the_file_guess_on_intel() {
    let Some(c) = run_2d("intel.g2o") else { return };
    assert!(
        c.init < 0.01 * c.odometry,
        "LAGO {} vs odometry {}",
        c.init,
        c.odometry
    );
    assert!(c.init < 0.2 * c.file, "LAGO {} vs file {}", c.init, c.file);
}

#[test]
fn lago_beats_odometry_and_the_file_guess_on_city10000() {
    let Some(c) = run_2d("city10000.g2o.xz") else {
        return;
    };
    assert!(
        c.init < 0.01 * c.odometry,
        "LAGO {} vs odometry {}",
        c.init,
        c.odometry
    );
    assert!(c.init < 0.2 * c.file, "LAGO {} vs file {}", c.init, c.file);
}

#[test]
fn anisotropic_rotation_weights_beat_isotropic_ones_on_cubicle() {
    // cubicle's odometry has roll/pitch information 10⁶ and yaw 6.25: a scalar weight makes
    // the uncertain odometry yaw override the loop closures.
    let Some(graph) = common::load_3d("cubicle.g2o.xz") else {
        return;
    };
    let mut chi2 = Vec::new();
    for weighting in [
        RotationWeighting::Information,
        RotationWeighting::Trace,
        RotationWeighting::Unit,
    ] {
        let mut g = graph.clone();
        initialize_chordal(
            &mut g,
            &ChordalParams {
                rotation_weighting: weighting,
            },
        )
        .unwrap();
        println!(
            "cubicle, {weighting:?} weighting: chordal chi2 {:.6e}",
            g.chi2()
        );
        chi2.push(g.chi2());
    }
    assert!(chi2[0] < chi2[1] && chi2[0] < chi2[2], "{chi2:?}");
}
