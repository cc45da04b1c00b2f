//! The atlas's pictures and files: every graph as g2o with a picture, and the picture of a
//! graph around a merge (points coloured by epoch; the detector's window, the newest
//! current-epoch scans, in change detection's classes, Holoch et al. Fig. 1/3).

use std::collections::BTreeMap;
use std::path::Path;

use mapmerge_engine::Engine;
use mapmerge_grid::{GridGeometry, Point2};
use mapmerge_io::{AnyGraph, GraphFormat};
use mapmerge_posegraph::{EdgeKind, NodeId, PoseGraph2};
use mapmerge_render::{session_color, Picture, Rgb};
use mapmerge_verify::{
    ChangeDetectionDetector, DetectorScan, InvalidMergeDetector, MergedMap, PointClass,
};

use crate::JobError;

/// Draws a graph's scans coloured by epoch; the newest current-epoch scans (the detector's
/// window) as larger dots.
pub fn draw_graph(
    graph: &PoseGraph2,
    engine: &Engine,
    conditional: &[(NodeId, NodeId)],
    path: &Path,
) -> Result<(), JobError> {
    let scans = engine.atlas().keyframes();
    let mut points: Vec<(Point2, Rgb, bool)> = Vec::new();
    let current = engine.atlas().current_epoch().0;
    let recent: Vec<NodeId> = graph
        .vertices()
        .filter(|(_, v)| v.meta.session.0 == current)
        .map(|(id, _)| id)
        .collect();
    let window: Vec<NodeId> = recent.iter().rev().take(10).copied().collect();
    let classes = window_classes(graph, engine);
    for (id, vertex) in graph.vertices() {
        let Some(scan) = scans.get(id) else {
            continue;
        };
        let colour = epoch_colour(vertex.meta.session.0);
        let highlight = window.contains(&id);
        let classes_of_scan = classes.get(&id);
        for (k, p) in scan.iter().enumerate() {
            // Window scans in change-detection colours (Holoch et al., Fig. 1/3): red change,
            // green agree, grey no info.
            let colour = match classes_of_scan.and_then(|c| c.get(k)) {
                Some(PointClass::Change) => Rgb([220, 30, 30]),
                Some(PointClass::Agree) => Rgb([30, 170, 60]),
                Some(PointClass::NoInfo) => Rgb([150, 150, 150]),
                None if k % 2 == 0 => colour,
                None => continue,
            };
            points.push((vertex.pose.transform_point(p), colour, highlight));
        }
    }
    let finite: Vec<&Point2> = points
        .iter()
        .map(|(p, _, _)| p)
        .filter(|p| p.x.is_finite() && p.y.is_finite())
        .collect();
    let Some(first) = finite.first() else {
        return Ok(());
    };
    let (mut min, mut max) = (**first, **first);
    for p in &finite {
        min = min.inf(p);
        max = max.sup(p);
    }
    let margin = Point2::new(1.0, 1.0);
    let resolution_m = ((max.x - min.x).max(max.y - min.y) / 1200.0).max(0.03);
    let geometry = GridGeometry {
        resolution_m,
        origin_m: min - margin,
        width: (((max.x - min.x) + 2.0) / resolution_m).ceil().min(4000.0) as usize,
        height: (((max.y - min.y) + 2.0) / resolution_m).ceil().min(4000.0) as usize,
    };
    let mut picture = Picture::blank(&geometry, 1);
    for (p, colour, highlight) in &points {
        picture.draw_disc(p, if *highlight { 1.5 } else { 0.6 }, *colour);
    }
    for (id, vertex) in graph.vertices() {
        let colour = epoch_colour(vertex.meta.session.0);
        let radius = if window.contains(&id) { 3.0 } else { 1.5 };
        picture.draw_disc(&vertex.pose.translation(), radius, colour);
    }
    // Merge edges magenta; a conditional merge's (in G') black and thicker.
    for (_, edge) in graph.edges().filter(|(_, e)| e.kind == EdgeKind::Merge) {
        if let (Some(a), Some(b)) = (graph.vertex(edge.from), graph.vertex(edge.to)) {
            let (colour, width) = if conditional.contains(&(edge.from, edge.to)) {
                (CONDITIONAL_BLACK, 3.0)
            } else {
                (Rgb::MAGENTA, 2.0)
            };
            picture.draw_line(&a.pose.translation(), &b.pose.translation(), colour, width);
        }
    }
    picture
        .save_png(path)
        .map_err(|e| JobError::writing(path, &e))?;
    Ok(())
}

/// The colour of a conditional merge's edges (no epoch has it).
const CONDITIONAL_BLACK: Rgb = Rgb([0, 0, 0]);

/// An epoch's colour: the session palette without its red and green, which mark change
/// detection's classes.
fn epoch_colour(epoch: u32) -> Rgb {
    const PALETTE: [u64; 8] = [0, 1, 4, 5, 6, 7, 8, 9];
    session_color(PALETTE[epoch as usize % PALETTE.len()])
}

/// Change detection's classes of the newest current-epoch scans against the other epochs in
/// `graph` (empty when it holds one epoch only).
fn window_classes(graph: &PoseGraph2, engine: &Engine) -> BTreeMap<NodeId, Vec<PointClass>> {
    let current = engine.atlas().current_epoch().0;
    let (mut now, mut other) = (Vec::new(), Vec::new());
    for (node, vertex) in graph.vertices() {
        let Some(points) = engine.atlas().keyframes().get(node) else {
            continue;
        };
        let scan = DetectorScan {
            node,
            epoch: vertex.meta.session.0,
            map_from_robot: vertex.pose,
            points_in_robot: std::sync::Arc::clone(points),
        };
        if vertex.meta.session.0 == current {
            now.push(scan);
        } else {
            other.push(scan);
        }
    }
    if now.is_empty() || other.is_empty() {
        return BTreeMap::new();
    }
    let map = MergedMap {
        current: &now,
        other: &other,
    };
    let mut detector = ChangeDetectionDetector::default();
    detector.on_merge(&map);
    detector.on_vertex(&map);
    detector.current_classes().into_iter().collect()
}

/// Writes every graph of the atlas as g2o with a picture.
pub fn write_atlas(engine: &Engine, dir: &Path) -> Result<(), JobError> {
    std::fs::create_dir_all(dir).map_err(|e| JobError::writing(dir, &e))?;
    let atlas = engine.atlas();
    let mut graphs: Vec<(String, &PoseGraph2)> =
        vec![(mapmerge_atlas::map_name(None), atlas.active())];
    graphs.extend(
        atlas
            .inactive_maps()
            .map(|(id, g)| (mapmerge_atlas::map_name(Some(id)), g)),
    );
    for (name, graph) in graphs {
        if graph.num_vertices() == 0 {
            continue;
        }
        let path = dir.join(format!("{name}.g2o"));
        mapmerge_io::write_graph(&path, &AnyGraph::Planar(graph.clone()), GraphFormat::G2o)
            .map_err(|e| JobError::writing(&path, &e))?;
        draw_graph(graph, engine, &[], &dir.join(format!("{name}.png")))?;
    }
    Ok(())
}
