//! Erroneous protrusions (iRobot, Sec. 5.4): an undetected wheel slip leaves the robot's pose
//! wrong, and what it maps afterwards lands in the wrong place, smearing free space through
//! walls into the unknown. The detector compares the map of the parent version (at the start
//! of a session) with the child's (after it): it segments the space that is free in the child
//! but not in the parent, describes each region by the paper's features (mean distance
//! transform, area, minor axis length, and the others it lists) and classifies it as
//! protrusion or new space with a decision tree (smartcore) trained on simulated maps.
//!
//! Shape alone cannot tell a ghost room from a new one, so the features also test the
//! session against the parent (the "consistency with the parent version"): how far
//! the walls of the session's local maps that see a region lie from the parent's walls, and
//! what is left of the region once every session map is relocalised on the parent's walls
//! (a slip moves everything mapped after it by one rigid error; [`realigned_session`] undoes
//! it). New space survives the realignment; a protrusion does not.
//!
//! Both maps are rendered from local maps in the child's frame: the parent's site map (its
//! largest graph) is moved onto the child's by the rigid transform that best aligns the
//! vertices both hold.

use std::collections::{BTreeMap, VecDeque};

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::{CellClass, CellMask, ClassThresholds, GridGeometry};
use mapmerge_posegraph::{NodeId, PoseGraph2};
use mapmerge_scan::Point2;
use mapmerge_scanmatch::{
    match_scan_above, score_at, CorrelativeParams, MatchTarget, SearchWindow,
};
use serde::{Deserialize, Serialize};
use smartcore::linalg::basic::matrix::DenseMatrix;
use smartcore::tree::decision_tree_classifier::{
    DecisionTreeClassifier, DecisionTreeClassifierParameters,
};

use crate::local_maps::{LocalMapGrid, RenderedMap};
use crate::snapshot::AtlasSnapshot;

/// The features of one region of new space (Sec. 5.4's list).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RegionFeatures {
    /// Area (m²).
    pub area_m2: f64,
    /// Mean distance from the region's cells to the nearest cell outside it (m): how thick
    /// the region is.
    pub mean_distance_m: f64,
    /// Axes of the ellipse with the region's second moments (m).
    pub minor_axis_m: f64,
    /// …
    pub major_axis_m: f64,
    /// Area of its axis-aligned bounding box (m²).
    pub bounding_box_m2: f64,
    /// Length of its boundary (m).
    pub perimeter_m: f64,
    /// Fraction of its cells that are walls (occupied) in the parent's map: free space
    /// painted through known walls (not in the paper; laser maps show it).
    pub parent_wall_fraction: f64,
    /// Fraction of its boundary cells that touch the parent's free space (within two cells)
    /// from the parent's unknown: a frontier the robot explored across (not in the paper).
    pub frontier_fraction: f64,
    /// Fraction of its boundary cells within two cells of a parent wall: space beyond a wall
    /// the parent knew (not in the paper).
    pub parent_wall_contact: f64,
    /// Fraction of its boundary cells next to (4-neighbours) the parent's free space: new
    /// space reached from known space without crossing a wall.
    pub free_contact: f64,
    /// Length of the parent's walls (seen occupied from [`MANY_VIEWS`] or more local maps) that
    /// the region covers (m): free space carved through them.
    pub carved_wall_m: f64,
    /// Of the walls the session's local maps that see the region put on the parent's known
    /// space, the fraction that land in the parent's free space, away from its walls (seen
    /// free from [`MANY_VIEWS`] or more local maps): how far those maps disagree with the
    /// parent. Weighted by how much of the region each map sees.
    pub observer_wall_conflict: f64,
    /// Of the free space those maps put on the parent's known space, the fraction on the
    /// parent's walls seen from [`MANY_VIEWS`] or more local maps.
    pub observer_carve_conflict: f64,
    /// Fraction of those maps' known cells that fall on the parent's known space (what the
    /// two conflicts were measured on).
    pub observer_overlap: f64,
    /// Mean distance from those maps' walls on the parent's known space to the parent's
    /// nearest wall (m, each capped at [`OFFSET_CAP_M`]): how far the maps are off.
    pub observer_wall_offset_m: f64,
    /// The same over the walls any of the session's local maps put within [`LOCAL_RADIUS_M`]
    /// of the region (the observers' offset when there are none): how far the map is off
    /// here, where a turn of the slip moves it more or less.
    pub local_wall_offset_m: f64,
    /// Of the session's walls within [`LOCAL_RADIUS_M`], the fraction in the parent's free
    /// space away from its walls.
    pub local_wall_conflict: f64,
    /// Fraction of its cells that are not free once each of the session's local maps is
    /// realigned on the parent's walls ([`realigned_session`]): the part of the region that
    /// the slip made.
    pub realigned_loss: f64,
    /// How far the realignment moves the region's centre (m), weighted over the maps that
    /// see it.
    pub realigned_shift_m: f64,
}

/// Cap on one wall's distance to the parent's nearest wall (m).
pub const OFFSET_CAP_M: f64 = 2.0;
/// Neighbourhood of a region where its local offset is measured (m).
pub const LOCAL_RADIUS_M: f64 = 2.0;

/// Local maps that must agree on a parent cell for it to count as seen from many views.
pub const MANY_VIEWS: u16 = 2;

/// Which features the classifier reads.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FeatureSet {
    /// The three of iRobot's deployed tree (Sec. 5.4: "average distance transform, area, and
    /// minor axis length").
    Paper,
    /// Those and the features that test the region against the parent, from
    /// [`RegionFeatures::parent_wall_fraction`] to [`RegionFeatures::realigned_shift_m`] (the
    /// default).
    #[default]
    PaperAndMap,
}

impl RegionFeatures {
    /// The classifier's inputs for `set`.
    pub fn classifier_inputs(&self, set: FeatureSet) -> Vec<f64> {
        let paper = [self.mean_distance_m, self.area_m2, self.minor_axis_m];
        match set {
            FeatureSet::Paper => paper.to_vec(),
            FeatureSet::PaperAndMap => paper
                .into_iter()
                .chain([
                    self.parent_wall_fraction,
                    self.frontier_fraction,
                    self.parent_wall_contact,
                    self.free_contact,
                    self.carved_wall_m,
                    self.observer_wall_conflict,
                    self.observer_carve_conflict,
                    self.observer_overlap,
                    self.observer_wall_offset_m,
                    self.local_wall_offset_m,
                    self.local_wall_conflict,
                    self.realigned_loss,
                    self.realigned_shift_m,
                ])
                .collect(),
        }
    }
}

/// A connected region of new space in the child's map.
#[derive(Clone, Debug, PartialEq)]
pub struct Region {
    /// Its cells (row-major indices of the child's rendered grid).
    pub cells: Vec<u32>,
    /// Its features.
    pub features: RegionFeatures,
    /// Its centre (child's frame, m).
    pub centre_m: [f64; 2],
}

/// Parameters of the detector.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ProtrusionParams {
    /// Cell side of the rendered maps (m) (default: 0.05).
    pub resolution_m: f64,
    /// Regions smaller than this are ignored (m²) (default: 0.25).
    pub min_area_m2: f64,
    /// Radius (cells) of the morphological opening that removes slivers of new space along
    /// walls first: what two renderings of one wall disagree on (default: 2, so slivers
    /// thinner than 5 cells go).
    pub opening_cells: usize,
    /// Half-widths of the search that realigns each of the session's local maps on the
    /// parent's walls (m, degrees) (default: 1.5, 30).
    pub realign_window_m: f64,
    /// …
    pub realign_window_deg: f64,
    /// A map's best match is a candidate correction when its score (mean likelihood of the
    /// map's walls near the parent's known space) is at least this (default: 0.25).
    pub realign_min_score: f64,
    /// What a change of correction from one map to the next costs, in score (default: 0.2):
    /// a session takes a correction when its maps gain more than that under it.
    pub realign_switch_cost: f64,
}

impl Default for ProtrusionParams {
    fn default() -> Self {
        Self {
            resolution_m: 0.05,
            min_area_m2: 0.25,
            opening_cells: 2,
            realign_window_m: 1.5,
            realign_window_deg: 30.0,
            realign_min_score: 0.25,
            realign_switch_cost: 0.2,
        }
    }
}

/// `child_from_parent`: the rigid transform that best aligns the positions of the vertices
/// both graphs hold (least squares, Umeyama in 2D); `None` with fewer than two.
pub fn align_graphs(parent: &PoseGraph2, child: &PoseGraph2) -> Option<Se2> {
    let pairs: Vec<(Point2, Point2)> = parent
        .vertices()
        .filter_map(|(node, v)| {
            Some((v.pose.translation(), child.vertex(node)?.pose.translation()))
        })
        .collect();
    if pairs.len() < 2 {
        return None;
    }
    let n = pairs.len() as f64;
    let mean_p = pairs.iter().map(|(p, _)| p).sum::<Point2>() / n;
    let mean_c = pairs.iter().map(|(_, c)| c).sum::<Point2>() / n;
    let (mut dot, mut cross) = (0.0, 0.0);
    for (p, c) in &pairs {
        let (a, b) = (p - mean_p, c - mean_c);
        dot += a.x * b.x + a.y * b.y;
        cross += a.x * b.y - a.y * b.x;
    }
    let theta = cross.atan2(dot);
    let rotation = Se2::new(0.0, 0.0, theta);
    let t = mean_c - rotation.transform_point(&mean_p);
    Some(Se2::new(t.x, t.y, theta))
}

/// The parent's and the child's site maps rendered on one grid in the child's frame, with
/// the regions of new space (free in the child, not free in the parent), largest first.
/// `None` when a version has no local maps or the two share fewer than two vertices.
pub fn new_regions(
    parent: &AtlasSnapshot,
    child: &AtlasSnapshot,
    params: &ProtrusionParams,
) -> Option<(RenderedMap, Vec<Region>)> {
    let child_graph = child.site_graph()?;
    let parent_graph = parent.site_graph()?;
    let child_from_parent = align_graphs(parent_graph, child_graph)?;
    let mut moved = parent_graph.clone();
    let ids: Vec<NodeId> = moved.vertices().map(|(n, _)| n).collect();
    for node in ids {
        if let Some(v) = moved.vertex_mut(node) {
            v.pose = child_from_parent.compose(&v.pose);
        }
    }
    let rendered_child = RenderedMap::render(child_graph, &child.local_maps, params.resolution_m)?;
    let rendered_parent =
        RenderedMap::render_into(&moved, &parent.local_maps, rendered_child.geometry);
    let thresholds = ClassThresholds::default();
    let new: Vec<bool> = rendered_child
        .sums
        .iter()
        .zip(&rendered_parent.sums)
        .map(|(c, p)| {
            thresholds.classify(*c) == CellClass::Free && thresholds.classify(*p) != CellClass::Free
        })
        .collect();
    let new = opened(new, &rendered_child.geometry, params.opening_cells);
    let parent = ParentEvidence::of(&rendered_parent, &thresholds, params.opening_cells);
    let mut regions = segment(&new, &parent, &rendered_child.geometry, params);
    let geometry = rendered_child.geometry;
    let session: Vec<NodeId> = child
        .local_maps
        .keys()
        .filter(|a| !parent_graph.contains_vertex(**a) && child_graph.contains_vertex(**a))
        .copied()
        .collect();
    let corrections = realigned_session(child_graph, &session, child, &parent, &geometry, params);
    let mut corrected = child_graph.clone();
    for (anchor, correction) in &corrections {
        if let Some(v) = corrected.vertex_mut(*anchor) {
            v.pose = correction.compose(&v.pose);
        }
    }
    let realigned = RenderedMap::render_into(&corrected, &child.local_maps, geometry);
    for region in &mut regions {
        let lost = region
            .cells
            .iter()
            .filter(|&&i| {
                realigned
                    .sums
                    .get(i as usize)
                    .is_none_or(|l| thresholds.classify(*l) != CellClass::Free)
            })
            .count();
        region.features.realigned_loss = lost as f64 / region.cells.len().max(1) as f64;
    }
    let observers = rendered_child
        .contributions
        .iter()
        .filter(|(anchor, _)| !parent_graph.contains_vertex(**anchor))
        .map(|(anchor, cells)| {
            let correction = corrections
                .get(anchor)
                .copied()
                .unwrap_or_else(Se2::identity);
            (correction, cells.as_slice())
        });
    describe_observers(&mut regions, observers, &parent, &thresholds, &geometry);
    Some((rendered_child, regions))
}

/// What the parent's map says of each cell of the child's grid: its class, and how many of
/// its local maps saw the cell occupied and free.
struct ParentEvidence {
    classes: Vec<CellClass>,
    /// Walls seen occupied from [`MANY_VIEWS`] or more local maps.
    many_wall: Vec<bool>,
    /// Free cells seen free from [`MANY_VIEWS`] or more local maps, `margin` cells or more
    /// from any cell that is not free (so a wall a cell or two off is no conflict).
    deep_free: Vec<bool>,
    /// Distance to its nearest wall (m).
    wall_distance_m: Vec<f32>,
}

impl ParentEvidence {
    fn of(rendered: &RenderedMap, thresholds: &ClassThresholds, margin: usize) -> Self {
        let n = rendered.geometry.len();
        let (mut wall_views, mut free_views) = (vec![0u16; n], vec![0u16; n]);
        for cells in rendered.contributions.values() {
            for &(i, l) in cells {
                let views = match thresholds.classify(l) {
                    CellClass::Occupied => &mut wall_views,
                    CellClass::Free => &mut free_views,
                    CellClass::Unknown => continue,
                };
                if let Some(v) = views.get_mut(i as usize) {
                    *v = v.saturating_add(1);
                }
            }
        }
        let classes = rendered.classes(thresholds);
        let many_wall: Vec<bool> = classes
            .iter()
            .zip(&wall_views)
            .map(|(c, v)| *c == CellClass::Occupied && *v >= MANY_VIEWS)
            .collect();
        let free: Vec<bool> = classes
            .iter()
            .zip(&free_views)
            .map(|(c, v)| *c == CellClass::Free && *v >= MANY_VIEWS)
            .collect();
        let deep_free = eroded(free, &rendered.geometry, margin);
        let walls: Vec<bool> = classes.iter().map(|c| *c == CellClass::Occupied).collect();
        let wall_distance_m = CellMask::from_flags(rendered.geometry, walls)
            .map(|m| m.distance_transform().distances_m().to_vec())
            .unwrap_or_default();
        Self {
            classes,
            many_wall,
            deep_free,
            wall_distance_m,
        }
    }

    fn class(&self, i: usize) -> CellClass {
        self.classes.get(i).copied().unwrap_or(CellClass::Unknown)
    }
}

/// Fills the observer features of `regions`: `observers` are the cells (index, log-odds) each
/// of the session's local maps added to the child's grid.
fn describe_observers<'a>(
    regions: &mut [Region],
    observers: impl Iterator<Item = (Se2, &'a [(u32, f32)])>,
    parent: &ParentEvidence,
    thresholds: &ClassThresholds,
    geometry: &GridGeometry,
) {
    let cells = geometry.len();
    let mut region_of = vec![u32::MAX; cells];
    // Per cell, over the session's maps: walls on the parent's known space, those on its
    // deep free space, and their summed offsets.
    let mut local = vec![[0.0f32; 3]; cells];
    for (k, region) in regions.iter().enumerate() {
        for &i in &region.cells {
            if let Some(r) = region_of.get_mut(i as usize) {
                *r = k as u32;
            }
        }
    }
    // Per region: Σ weight, Σ weight × (wall conflict, carve conflict, overlap, offset).
    let mut sums = vec![[0.0f64; 6]; regions.len()];
    let mut seen: Vec<(u32, u32)> = Vec::new();
    for (correction, contributions) in observers {
        let (mut walls, mut walls_on_known, mut walls_on_free) = (0usize, 0usize, 0usize);
        let mut offset_sum = 0.0f64;
        let (mut free, mut free_on_known, mut free_on_walls) = (0usize, 0usize, 0usize);
        seen.clear();
        for &(i, l) in contributions {
            let index = i as usize;
            let known = parent.class(index) != CellClass::Unknown;
            match thresholds.classify(l) {
                CellClass::Occupied => {
                    walls += 1;
                    if known {
                        let on_free = parent.deep_free.get(index) == Some(&true);
                        let offset = parent
                            .wall_distance_m
                            .get(index)
                            .map_or(OFFSET_CAP_M, |d| f64::from(*d).min(OFFSET_CAP_M));
                        walls_on_known += 1;
                        walls_on_free += usize::from(on_free);
                        offset_sum += offset;
                        if let Some(cell) = local.get_mut(index) {
                            cell[0] += 1.0;
                            cell[1] += f32::from(u8::from(on_free));
                            cell[2] += offset as f32;
                        }
                    }
                }
                CellClass::Free => {
                    free += 1;
                    free_on_known += usize::from(known);
                    free_on_walls += usize::from(parent.many_wall.get(index) == Some(&true));
                    if let Some(&r) = region_of.get(index).filter(|r| **r != u32::MAX) {
                        match seen.iter_mut().find(|(region, _)| *region == r) {
                            Some((_, count)) => *count += 1,
                            None => seen.push((r, 1)),
                        }
                    }
                }
                CellClass::Unknown => {}
            }
        }
        let ratio = |a: usize, b: usize| if b == 0 { 0.0 } else { a as f64 / b as f64 };
        let wall_conflict = ratio(walls_on_free, walls_on_known);
        let carve_conflict = ratio(free_on_walls, free_on_known);
        let overlap = ratio(walls_on_known + free_on_known, walls + free);
        let offset_m = if walls_on_known == 0 {
            0.0
        } else {
            offset_sum / walls_on_known as f64
        };
        for &(r, count) in &seen {
            let (Some(sum), Some(region)) = (sums.get_mut(r as usize), regions.get(r as usize))
            else {
                continue;
            };
            let centre = Point2::new(region.centre_m[0], region.centre_m[1]);
            let shift_m = (correction.transform_point(&centre) - centre).norm();
            let w = f64::from(count);
            for (s, v) in sum.iter_mut().zip([
                1.0,
                wall_conflict,
                carve_conflict,
                overlap,
                offset_m,
                shift_m,
            ]) {
                *s += w * v;
            }
        }
    }
    for (region, sum) in regions.iter_mut().zip(&sums) {
        let f = &mut region.features;
        if sum[0] > 0.0 {
            f.observer_wall_conflict = sum[1] / sum[0];
            f.observer_carve_conflict = sum[2] / sum[0];
            f.observer_overlap = sum[3] / sum[0];
            f.observer_wall_offset_m = sum[4] / sum[0];
            f.realigned_shift_m = sum[5] / sum[0];
        }
        let [walls, on_free, offsets] = neighbourhood_sum(&region.cells, &local, geometry);
        (f.local_wall_offset_m, f.local_wall_conflict) = if walls > 0.0 {
            (offsets / walls, on_free / walls)
        } else {
            (f.observer_wall_offset_m, f.observer_wall_conflict)
        };
    }
}

/// Sums of `values` over the cells within [`LOCAL_RADIUS_M`] of `cells` (row-major indices
/// of `geometry`).
fn neighbourhood_sum(cells: &[u32], values: &[[f32; 3]], geometry: &GridGeometry) -> [f64; 3] {
    let (w, h, r) = (geometry.width, geometry.height, geometry.resolution_m);
    let pad = (LOCAL_RADIUS_M / r).ceil() as usize;
    let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
    for &i in cells {
        let (x, y) = (i as usize % w, i as usize / w);
        (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
    }
    if x0 > x1 {
        return [0.0; 3];
    }
    let (x0, y0) = (x0.saturating_sub(pad), y0.saturating_sub(pad));
    let (x1, y1) = ((x1 + pad).min(w - 1), (y1 + pad).min(h - 1));
    let (bw, bh) = (x1 - x0 + 1, y1 - y0 + 1);
    let mut inside = vec![false; bw * bh];
    for &i in cells {
        let (x, y) = (i as usize % w, i as usize / w);
        inside[(y - y0) * bw + (x - x0)] = true;
    }
    let box_geometry = GridGeometry {
        resolution_m: r,
        origin_m: Point2::zeros(),
        width: bw,
        height: bh,
    };
    let Some(mask) = CellMask::from_flags(box_geometry, inside) else {
        return [0.0; 3];
    };
    let field = mask.distance_transform();
    let mut sum = [0.0f64; 3];
    for (k, d) in field.distances_m().iter().enumerate() {
        if f64::from(*d) > LOCAL_RADIUS_M {
            continue;
        }
        let index = (y0 + k / bw) * w + x0 + k % bw;
        if let Some(v) = values.get(index) {
            for (s, v) in sum.iter_mut().zip(v) {
                *s += f64::from(*v);
            }
        }
    }
    sum
}

/// `map_from_map` corrections of the session's local maps (`session`, in time order): an
/// undetected slip moves everything mapped after it by one rigid error, so undoing it is
/// relocalising the session's maps on the parent. Each map's walls near the parent's known
/// space are matched on the parent's walls (correlative search within
/// [`ProtrusionParams::realign_window_m`] of its pose); every good match is a candidate
/// correction, scored on every map. The corrections are then piecewise constant in time:
/// the sequence, starting uncorrected, that maximises the maps' summed scores less
/// [`ProtrusionParams::realign_switch_cost`] per change ([`piecewise_constant`]). A map far
/// from the slip, beyond its own search window, or with too little overlap to match, takes
/// the correction of the maps around it.
fn realigned_session(
    graph: &PoseGraph2,
    session: &[NodeId],
    child: &AtlasSnapshot,
    parent: &ParentEvidence,
    geometry: &GridGeometry,
    params: &ProtrusionParams,
) -> BTreeMap<NodeId, Se2> {
    let walls: Vec<Point2> = parent
        .classes
        .iter()
        .enumerate()
        .filter(|(_, c)| **c == CellClass::Occupied)
        .map(|(i, _)| geometry.center_of(geometry.cell_at(i)))
        .collect();
    let correlative = CorrelativeParams::default();
    let Ok(target) = MatchTarget::new(&walls, &correlative) else {
        return BTreeMap::new();
    };
    let pad = (params.realign_window_m / geometry.resolution_m).ceil() as usize;
    let known: Vec<bool> = parent
        .classes
        .iter()
        .map(|c| *c != CellClass::Unknown)
        .collect();
    let Some(near_known) = CellMask::from_flags(*geometry, known).map(|m| m.dilate(pad)) else {
        return BTreeMap::new();
    };
    let window = SearchWindow::new(
        params.realign_window_m,
        params.realign_window_deg.to_radians(),
    );
    let thresholds = ClassThresholds::default();
    // Each map's walls near the parent's known space, and its pose.
    let queries: Vec<(Se2, Vec<Point2>)> = session
        .iter()
        .map(|anchor| {
            let (Some(v), Some(map)) = (graph.vertex(*anchor), child.local_maps.get(anchor)) else {
                return (Se2::identity(), Vec::new());
            };
            let (occupied, _) = map.cells_within(&Point2::zeros(), map.reach_m(), &thresholds);
            let query: Vec<Point2> = occupied
                .into_iter()
                .filter(|p| near_known.is_set(geometry.cell_of(&v.pose.transform_point(p))))
                .collect();
            (v.pose, query)
        })
        .collect();
    // Candidate corrections: none, and each map's best match about its own pose.
    let mut candidates = vec![Se2::identity()];
    for (map_from_anchor, query) in &queries {
        if query.len() < MIN_REALIGN_POINTS {
            continue;
        }
        if let Some(m) = match_scan_above(&target, query, map_from_anchor, &window, 0.0) {
            if m.score >= params.realign_min_score {
                candidates.push(m.target_from_query.compose(&map_from_anchor.inverse()));
            }
        }
    }
    // Score of every map under every candidate (0 for a map with too little overlap).
    let scores: Vec<Vec<f64>> = queries
        .iter()
        .map(|(map_from_anchor, query)| {
            candidates
                .iter()
                .map(|c| {
                    if query.len() < MIN_REALIGN_POINTS {
                        return 0.0;
                    }
                    score_at(&target, query, &c.compose(map_from_anchor)).unwrap_or(0.0)
                })
                .collect()
        })
        .collect();
    let path = piecewise_constant(&scores, params.realign_switch_cost);
    session
        .iter()
        .zip(path)
        .map(|(anchor, c)| {
            (
                *anchor,
                candidates.get(c).copied().unwrap_or_else(Se2::identity),
            )
        })
        .collect()
}

/// The sequence of states (`scores[i][c]`: step `i` in state `c`, every row as long) that
/// maximises the summed scores less `switch_cost` per change of state, starting in state 0
/// (Viterbi).
fn piecewise_constant(scores: &[Vec<f64>], switch_cost: f64) -> Vec<usize> {
    let Some(states) = scores.first().map(Vec::len) else {
        return Vec::new();
    };
    // best[c]: the best total ending in state c; back[i][c]: the state before it. On a tie
    // the change comes as late as it can (a map without evidence keeps the state before).
    let mut best: Vec<f64> = (0..states)
        .map(|c| if c == 0 { 0.0 } else { -switch_cost })
        .collect();
    let mut back: Vec<Vec<usize>> = Vec::with_capacity(scores.len());
    for (i, row) in scores.iter().enumerate() {
        let (stay_or_switch, from): (Vec<f64>, Vec<usize>) = if i == 0 {
            (best.clone(), (0..states).map(|_| 0).collect())
        } else {
            let (top, top_state) = arg_max(&best);
            (0..states)
                .map(|c| {
                    let stay = best.get(c).copied().unwrap_or(f64::NEG_INFINITY);
                    if stay > top - switch_cost {
                        (stay, c)
                    } else {
                        (top - switch_cost, top_state)
                    }
                })
                .unzip()
        };
        best = stay_or_switch.iter().zip(row).map(|(b, s)| b + s).collect();
        back.push(from);
    }
    let mut state = arg_max(&best).1;
    let mut path = vec![0; scores.len()];
    for (i, slot) in path.iter_mut().enumerate().rev() {
        *slot = state;
        if i > 0 {
            state = back.get(i).and_then(|b| b.get(state)).copied().unwrap_or(0);
        }
    }
    path
}

/// The largest value and its index (the first of equals; index 0 when empty).
fn arg_max(values: &[f64]) -> (f64, usize) {
    values
        .iter()
        .enumerate()
        .fold((f64::NEG_INFINITY, 0), |(top, at), (k, v)| {
            if *v > top {
                (*v, k)
            } else {
                (top, at)
            }
        })
}

#[cfg(test)]
mod tests {
    use super::piecewise_constant;

    #[test]
    fn corrections_change_only_when_the_maps_gain_more_than_the_switch_costs() {
        // Three maps fit state 0, then three fit state 1: one change.
        let slip = [
            [0.8, 0.1],
            [0.7, 0.2],
            [0.6, 0.5],
            [0.1, 0.9],
            [0.2, 0.8],
            [0.0, 0.7],
        ];
        let rows: Vec<Vec<f64>> = slip.iter().map(|r| r.to_vec()).collect();
        assert_eq!(piecewise_constant(&rows, 0.2), [0, 0, 0, 1, 1, 1]);
        // One map alone that prefers state 1 by less than two switches stays in state 0; a
        // map with no overlap (all zeros) follows its neighbours.
        let blip = [[0.8, 0.1], [0.5, 0.8], [0.0, 0.0], [0.7, 0.2]];
        let rows: Vec<Vec<f64>> = blip.iter().map(|r| r.to_vec()).collect();
        assert_eq!(piecewise_constant(&rows, 0.2), [0, 0, 0, 0]);
        // The session starts uncorrected: a first map that prefers state 1 by less than one
        // switch does not take it.
        let rows = vec![vec![0.5, 0.6], vec![0.0, 0.0]];
        assert_eq!(piecewise_constant(&rows, 0.2), [0, 0]);
        assert!(piecewise_constant(&[], 0.2).is_empty());
    }
}

/// Walls a local map must put near the parent's known space to be realigned.
const MIN_REALIGN_POINTS: usize = 50;

/// `set` eroded by a square of radius `radius` (cells): a cell stays when every cell of the
/// square around it is set.
fn eroded(set: Vec<bool>, geometry: &GridGeometry, radius: usize) -> Vec<bool> {
    if radius == 0 {
        return set;
    }
    let complement: Vec<bool> = set.iter().map(|s| !s).collect();
    match CellMask::from_flags(*geometry, complement).map(|m| m.dilate(radius)) {
        Some(grown) => grown.flags().iter().map(|s| !s).collect(),
        None => set,
    }
}

/// `set` eroded then dilated by a square of radius `radius` (cells), within `set`.
fn opened(set: Vec<bool>, geometry: &GridGeometry, radius: usize) -> Vec<bool> {
    if radius == 0 {
        return set;
    }
    let eroded = eroded(set.clone(), geometry, radius);
    let Some(opened) = CellMask::from_flags(*geometry, eroded).map(|m| m.dilate(radius)) else {
        return set;
    };
    opened
        .flags()
        .iter()
        .zip(&set)
        .map(|(o, s)| *o && *s)
        .collect()
}

/// 8-connected components of `set` of at least `min_area_m2`, with their features, largest
/// first.
fn segment(
    set: &[bool],
    parent: &ParentEvidence,
    geometry: &GridGeometry,
    params: &ProtrusionParams,
) -> Vec<Region> {
    let (w, h) = (geometry.width, geometry.height);
    let r = geometry.resolution_m;
    let min_cells = (params.min_area_m2 / (r * r)).ceil() as usize;
    let mut label = vec![false; set.len()];
    let mut regions = Vec::new();
    for start in 0..set.len() {
        if !set[start] || label[start] {
            continue;
        }
        let mut cells = Vec::new();
        let mut queue = VecDeque::from([start]);
        label[start] = true;
        while let Some(i) = queue.pop_front() {
            cells.push(i);
            let (x, y) = ((i % w) as i64, (i / w) as i64);
            for (dx, dy) in [
                (-1, -1),
                (0, -1),
                (1, -1),
                (-1, 0),
                (1, 0),
                (-1, 1),
                (0, 1),
                (1, 1),
            ] {
                let (nx, ny) = (x + dx, y + dy);
                if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                    continue;
                }
                let j = ny as usize * w + nx as usize;
                if set[j] && !label[j] {
                    label[j] = true;
                    queue.push_back(j);
                }
            }
        }
        if cells.len() >= min_cells {
            regions.push(describe(&cells, set, parent, geometry));
        }
    }
    regions.sort_by_key(|r| std::cmp::Reverse(r.cells.len()));
    regions
}

/// A region's features (its cells are row-major indices of `geometry`; `set` marks new space,
/// `parent` the parent's classes on the same grid).
fn describe(
    cells: &[usize],
    set: &[bool],
    parent: &ParentEvidence,
    geometry: &GridGeometry,
) -> Region {
    let (w, r) = (geometry.width, geometry.resolution_m);
    let xy = |i: usize| ((i % w) as i64, (i / w) as i64);
    let (mut x0, mut y0, mut x1, mut y1) = (i64::MAX, i64::MAX, i64::MIN, i64::MIN);
    for &i in cells {
        let (x, y) = xy(i);
        (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
    }
    // The region in its own padded box: distance transform of its complement.
    let (bw, bh) = ((x1 - x0 + 3) as usize, (y1 - y0 + 3) as usize);
    let mut inside = vec![false; bw * bh];
    for &i in cells {
        let (x, y) = xy(i);
        inside[(y - y0 + 1) as usize * bw + (x - x0 + 1) as usize] = true;
    }
    let box_geometry = GridGeometry {
        resolution_m: r,
        origin_m: Point2::zeros(),
        width: bw,
        height: bh,
    };
    let outside: Vec<bool> = inside.iter().map(|s| !s).collect();
    let distance_sum: f64 = CellMask::from_flags(box_geometry, outside)
        .map(|mask| {
            let field = mask.distance_transform();
            inside
                .iter()
                .zip(field.distances_m())
                .filter(|(s, _)| **s)
                .map(|(_, d)| f64::from(*d))
                .sum()
        })
        .unwrap_or(0.0);
    let mut perimeter_edges = 0usize;
    for (k, s) in inside.iter().enumerate() {
        if !*s {
            continue;
        }
        let (x, y) = (k % bw, k / bw);
        for (nx, ny) in [(x - 1, y), (x + 1, y), (x, y - 1), (x, y + 1)] {
            if !inside[ny * bw + nx] {
                perimeter_edges += 1;
            }
        }
    }
    // Against the parent's map: walls under the region, and its frontier cells (parent
    // unknown, next to parent free space outside the region).
    let h = geometry.height;
    let class = |i: usize| parent.class(i);
    let walls = cells
        .iter()
        .filter(|&&i| class(i) == CellClass::Occupied)
        .count();
    let carved = cells
        .iter()
        .filter(|&&i| parent.many_wall.get(i) == Some(&true))
        .count();
    // Boundary cells, and what lies within two cells of each outside the region.
    let (mut boundary, mut frontier, mut contact, mut free_contact) =
        (0usize, 0usize, 0usize, 0usize);
    for &i in cells {
        let (x, y) = ((i % w) as i64, (i / w) as i64);
        let mut outside_free = false;
        let mut outside_wall = false;
        let mut on_boundary = false;
        let mut next_to_free = false;
        for dy in -2..=2i64 {
            for dx in -2..=2i64 {
                let (nx, ny) = (x + dx, y + dy);
                if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                    continue;
                }
                let j = ny as usize * w + nx as usize;
                if set.get(j).copied().unwrap_or(false) {
                    continue;
                }
                let adjacent = dx.abs() + dy.abs() == 1;
                on_boundary |= adjacent;
                next_to_free |= adjacent && class(j) == CellClass::Free;
                match class(j) {
                    CellClass::Free => outside_free = true,
                    CellClass::Occupied => outside_wall = true,
                    CellClass::Unknown => {}
                }
            }
        }
        if on_boundary {
            boundary += 1;
            frontier += usize::from(outside_free && class(i) == CellClass::Unknown);
            contact += usize::from(outside_wall);
            free_contact += usize::from(next_to_free);
        }
    }
    // Second moments of the cell centres.
    let n = cells.len() as f64;
    let centres: Vec<(f64, f64)> = cells
        .iter()
        .map(|&i| {
            let (x, y) = xy(i);
            ((x as f64 + 0.5) * r, (y as f64 + 0.5) * r)
        })
        .collect();
    let (mx, my) = (
        centres.iter().map(|c| c.0).sum::<f64>() / n,
        centres.iter().map(|c| c.1).sum::<f64>() / n,
    );
    let (mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0);
    for (x, y) in &centres {
        sxx += (x - mx).powi(2);
        syy += (y - my).powi(2);
        sxy += (x - mx) * (y - my);
    }
    // A cell's own extent (r²/12 per axis) keeps thin regions from a zero axis.
    let (sxx, syy, sxy) = (sxx / n + r * r / 12.0, syy / n + r * r / 12.0, sxy / n);
    let half_trace = (sxx + syy) / 2.0;
    let spread = ((sxx - syy).powi(2) / 4.0 + sxy * sxy).sqrt();
    let (major, minor) = (half_trace + spread, (half_trace - spread).max(0.0));
    Region {
        cells: cells.iter().map(|&i| i as u32).collect(),
        features: RegionFeatures {
            area_m2: n * r * r,
            mean_distance_m: distance_sum / n,
            minor_axis_m: 4.0 * minor.sqrt(),
            major_axis_m: 4.0 * major.sqrt(),
            bounding_box_m2: ((x1 - x0 + 1) * (y1 - y0 + 1)) as f64 * r * r,
            perimeter_m: perimeter_edges as f64 * r,
            parent_wall_fraction: walls as f64 / n,
            frontier_fraction: frontier as f64 / boundary.max(1) as f64,
            parent_wall_contact: contact as f64 / boundary.max(1) as f64,
            free_contact: free_contact as f64 / boundary.max(1) as f64,
            carved_wall_m: carved as f64 * r,
            observer_wall_conflict: 0.0,
            observer_carve_conflict: 0.0,
            observer_overlap: 0.0,
            observer_wall_offset_m: 0.0,
            local_wall_offset_m: 0.0,
            local_wall_conflict: 0.0,
            realigned_loss: 0.0,
            realigned_shift_m: 0.0,
        },
        centre_m: [geometry.origin_m.x + mx, geometry.origin_m.y + my],
    }
}

/// One labelled region for training and evaluation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LabelledRegion {
    /// Where it came from (world, seed, case).
    pub source: String,
    /// Its features.
    pub features: RegionFeatures,
    /// True for an erroneous protrusion, false for new space.
    pub protrusion: bool,
}

/// The decision tree over [`RegionFeatures::classifier_inputs`].
pub struct ProtrusionClassifier {
    tree: DecisionTreeClassifier<f64, u32, DenseMatrix<f64>, Vec<u32>>,
    features: FeatureSet,
}

impl std::fmt::Debug for ProtrusionClassifier {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ProtrusionClassifier")
            .finish_non_exhaustive()
    }
}

/// Depth of the default tree.
pub const DEFAULT_DEPTH: u16 = 4;
/// Smallest leaf of the default tree (regions).
pub const DEFAULT_MIN_LEAF: usize = 3;

/// The labelled regions the default classifier is trained on (written by
/// `mapmerge eval protrusions --write-training`; simulator tuning seeds only).
const TRAINING: &str = include_str!("protrusion_training.json");

impl ProtrusionClassifier {
    /// Fits a tree (depth at most `max_depth`, at least `min_leaf` regions a leaf). Fails
    /// without both classes.
    pub fn fit(
        regions: &[LabelledRegion],
        features: FeatureSet,
        max_depth: u16,
        min_leaf: usize,
    ) -> Result<Self, String> {
        if !regions.iter().any(|r| r.protrusion) || regions.iter().all(|r| r.protrusion) {
            return Err("training needs regions of both classes".into());
        }
        let rows: Vec<Vec<f64>> = regions
            .iter()
            .map(|r| r.features.classifier_inputs(features))
            .collect();
        let x = DenseMatrix::from_2d_vec(&rows).map_err(|e| e.to_string())?;
        let y: Vec<u32> = regions.iter().map(|r| u32::from(r.protrusion)).collect();
        let parameters = DecisionTreeClassifierParameters::default()
            .with_max_depth(max_depth)
            .with_min_samples_leaf(min_leaf);
        let tree = DecisionTreeClassifier::fit(&x, &y, parameters).map_err(|e| e.to_string())?;
        Ok(Self { tree, features })
    }

    /// The tree fitted on the committed training regions (all features, depth
    /// [`DEFAULT_DEPTH`], [`DEFAULT_MIN_LEAF`] regions a leaf).
    pub fn trained() -> Result<Self, String> {
        let regions: Vec<LabelledRegion> =
            serde_json::from_str(TRAINING).map_err(|e| e.to_string())?;
        Self::fit(
            &regions,
            FeatureSet::default(),
            DEFAULT_DEPTH,
            DEFAULT_MIN_LEAF,
        )
    }

    /// Whether each region is a protrusion.
    pub fn predict(&self, features: &[RegionFeatures]) -> Result<Vec<bool>, String> {
        if features.is_empty() {
            return Ok(Vec::new());
        }
        let rows: Vec<Vec<f64>> = features
            .iter()
            .map(|f| f.classifier_inputs(self.features))
            .collect();
        let x = DenseMatrix::from_2d_vec(&rows).map_err(|e| e.to_string())?;
        let y = self.tree.predict(&x).map_err(|e| e.to_string())?;
        Ok(y.into_iter().map(|c| c == 1).collect())
    }
}

/// Removes protrusions from the local maps the session added (those not in `parent`): each
/// of their cells that renders into one of `regions`' cells becomes unknown, so the parent's
/// map shows there again. Returns how many local maps changed.
pub fn remove_regions(
    parent: &AtlasSnapshot,
    child: &mut AtlasSnapshot,
    rendered: &RenderedMap,
    regions: &[&Region],
) -> usize {
    let Some(graph) = child.site_graph().cloned() else {
        return 0;
    };
    let geometry = rendered.geometry;
    let mut doomed = vec![false; geometry.len()];
    for region in regions {
        for &i in &region.cells {
            if let Some(d) = doomed.get_mut(i as usize) {
                *d = true;
            }
        }
    }
    let mut changed = 0;
    let anchors: Vec<NodeId> = child
        .local_maps
        .keys()
        .filter(|a| !parent.local_maps.contains_key(a))
        .copied()
        .collect();
    for anchor in anchors {
        let Some(map_from_anchor) = graph.vertex(anchor).map(|v| v.pose) else {
            continue;
        };
        let Some(map) = child.local_maps.get_mut(&anchor) else {
            continue;
        };
        if clear_cells(map, &map_from_anchor, &geometry, &doomed) {
            changed += 1;
        }
    }
    changed
}

/// Sets to unknown every cell of `map` whose centre falls in a `doomed` cell of `geometry`.
fn clear_cells(
    map: &mut LocalMapGrid,
    map_from_anchor: &Se2,
    geometry: &GridGeometry,
    doomed: &[bool],
) -> bool {
    let mut changed = false;
    let width = map.width as usize;
    for (k, cell) in map.cells.iter_mut().enumerate() {
        if *cell == 0 {
            continue;
        }
        let centre = Point2::new(
            map.origin_m[0] + ((k % width) as f64 + 0.5) * map.resolution_m,
            map.origin_m[1] + ((k / width) as f64 + 0.5) * map.resolution_m,
        );
        let p = map_from_anchor.transform_point(&centre);
        let index = geometry.index_of(geometry.cell_of(&p));
        if index.and_then(|i| doomed.get(i)).copied().unwrap_or(false) {
            *cell = 0;
            changed = true;
        }
    }
    changed
}
