//! `mapmerge ros2`'s outputs judged against the offline commands on the same data: a live map
//! against `slam`'s, cell by cell; and a second robot's map with a known placement.

use std::path::PathBuf;

use crate::{bad_input, print_json};
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::{CellClass, ClassThresholds, GridGeometry, OccupancyGrid, Point2};
use serde::Serialize;

/// `a`'s content as another robot would map it: in a frame placed at `a_from_b` in A's, with
/// cells `cell_scale` times A's, just large enough to hold all of A.
pub fn turned_copy(
    a: &OccupancyGrid,
    a_from_b: &Se2,
    cell_scale: f64,
) -> anyhow::Result<OccupancyGrid> {
    let b_from_a = a_from_b.inverse();
    let (lo, hi) = a.geometry().bounds_m();
    let corners = [
        Point2::new(lo.x, lo.y),
        Point2::new(hi.x, lo.y),
        Point2::new(lo.x, hi.y),
        Point2::new(hi.x, hi.y),
    ]
    .map(|c| b_from_a.transform_point(&c));
    let min = corners.iter().fold(corners[0], |m, c| m.inf(c));
    let max = corners.iter().fold(corners[0], |m, c| m.sup(c));
    let resolution_m = cell_scale * a.resolution_m();
    let geometry = GridGeometry {
        resolution_m,
        origin_m: min,
        width: ((max.x - min.x) / resolution_m).ceil() as usize,
        height: ((max.y - min.y) / resolution_m).ceil() as usize,
    };
    Ok(mapmerge_gridmerge::resample_into(a, &b_from_a, &geometry)?)
}

/// How two maps of one resolution agree.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct GridAgreement {
    /// Cells known (occupied or free) in either map.
    pub cells: usize,
    /// Of those, cells of the same class in both.
    pub agreeing: usize,
    /// `agreeing / cells` (1 when neither knows a cell).
    pub fraction: f64,
}

/// Compares `a` and `b` by place: every cell known in either, classified by `thresholds`,
/// found in the other at its centre (unknown outside it). `None` when the resolutions differ
/// by more than 0.1 %.
pub fn grid_agreement(
    a: &OccupancyGrid,
    b: &OccupancyGrid,
    thresholds: &ClassThresholds,
) -> Option<GridAgreement> {
    if (a.resolution_m() - b.resolution_m()).abs() > 1e-3 * a.resolution_m() {
        return None;
    }
    let class_at = |grid: &OccupancyGrid, p: &Point2| {
        let cell = grid.geometry().cell_of(p);
        if grid.geometry().contains(cell) {
            thresholds.classify(grid.cell_log_odds(cell))
        } else {
            CellClass::Unknown
        }
    };
    let (mut cells, mut agreeing) = (0, 0);
    // Cells known in A (B may not know them).
    for (_, p, l) in a.cells() {
        let here = thresholds.classify(l);
        if here == CellClass::Unknown {
            continue;
        }
        cells += 1;
        agreeing += usize::from(class_at(b, &p) == here);
    }
    // Cells known in B alone (outside A, or unknown in A).
    for (_, p, l) in b.cells() {
        let there = thresholds.classify(l);
        if there != CellClass::Unknown && class_at(a, &p) == CellClass::Unknown {
            cells += 1;
        }
    }
    Some(GridAgreement {
        cells,
        agreeing,
        fraction: if cells == 0 {
            1.0
        } else {
            agreeing as f64 / cells as f64
        },
    })
}

/// Arguments of `mapmerge eval map-agreement`.
#[derive(clap::Args, Debug)]
pub struct MapAgreementArgs {
    /// A map (map_server YAML), e.g. the live node's `/map` as saved.
    pub a: PathBuf,
    /// The other map, e.g. `mapmerge slam`'s `map.yaml`.
    pub b: PathBuf,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Runs `mapmerge eval map-agreement`: maps that cannot be read, or of other resolutions, are
/// bad input.
pub fn map_agreement(args: &MapAgreementArgs) -> anyhow::Result<()> {
    let read = |path: &PathBuf| -> anyhow::Result<OccupancyGrid> {
        let (_, grid) = mapmerge_jobs::load_map(path).map_err(mapmerge_jobs::cli::job_error)?;
        Ok(grid)
    };
    let (a, b) = (read(&args.a)?, read(&args.b)?);
    let agreement = grid_agreement(&a, &b, &ClassThresholds::default()).ok_or_else(|| {
        bad_input(format!(
            "{} has cells of {} m, {} of {} m: compare maps of one resolution",
            args.a.display(),
            a.resolution_m(),
            args.b.display(),
            b.resolution_m()
        ))
    })?;
    if args.json {
        print_json(&agreement)?;
    } else {
        println!(
            "{:.4} of {} cells known in either map agree ({} cells)",
            agreement.fraction, agreement.cells, agreement.agreeing
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;
    use mapmerge_grid::{log_odds_of, GridGeometry, Point2};

    #[test]
    fn agreement_counts_cells_known_in_either_map_by_place() {
        let geometry = |x: f64| GridGeometry {
            resolution_m: 1.0,
            origin_m: Point2::new(x, 0.0),
            width: 4,
            height: 1,
        };
        let (o, f) = (log_odds_of(0.97), log_odds_of(0.12));
        let a = OccupancyGrid::from_log_odds(geometry(0.0), vec![o, f, f, 0.0]).unwrap();
        // B is shifted one cell: it sees A's cells 1..3 as free, free, occupied, and one more.
        let b = OccupancyGrid::from_log_odds(geometry(1.0), vec![f, f, o, f]).unwrap();
        let t = ClassThresholds::default();
        let agreement = grid_agreement(&a, &b, &t).unwrap();
        // Known: A's 0 (occupied, B unknown), 1, 2 (agree), 3 (A unknown, B occupied), 4 (B).
        assert_eq!((agreement.cells, agreement.agreeing), (5, 2));
        assert_eq!(grid_agreement(&a, &a, &t).unwrap().fraction, 1.0);
        let coarse = OccupancyGrid::new(2.0).unwrap();
        assert!(grid_agreement(&a, &coarse, &t).is_none());
    }
}
