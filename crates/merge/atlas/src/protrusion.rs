//! Erroneous protrusions (iRobot, Sec. 5.4): an undetected wheel slip leaves the robot's pose
//! wrong, and what it maps afterwards lands in the wrong place, smearing free space through
//! walls into the unknown. The detector compares the map of the parent version (at the start
//! of a session) with the child's (after it): it segments the space that is free in the child
//! but not in the parent, describes each region by the paper's features (mean distance
//! transform, area, minor axis length, and the others it lists) and classifies it as
//! protrusion or new space with a decision tree (smartcore) trained on simulated maps.
//!
//! Both maps are rendered from local maps in the child's frame: the parent's site map (its
//! largest graph) is moved onto the child's by the rigid transform that best aligns the
//! vertices both hold.

use std::collections::VecDeque;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::{CellClass, CellMask, ClassThresholds, GridGeometry};
use mapmerge_posegraph::{NodeId, PoseGraph2};
use mapmerge_scan::Point2;
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
}

/// Which features the classifier reads.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FeatureSet {
    /// The three of iRobot's deployed tree (Sec. 5.4: "average distance transform, area, and
    /// minor axis length").
    Paper,
    /// Those and the three map-difference features ([`RegionFeatures::parent_wall_fraction`],
    /// [`RegionFeatures::frontier_fraction`], [`RegionFeatures::parent_wall_contact`]) (the
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
}

impl Default for ProtrusionParams {
    fn default() -> Self {
        Self {
            resolution_m: 0.05,
            min_area_m2: 0.25,
            opening_cells: 2,
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
    let parent_classes = rendered_parent.classes(&thresholds);
    let regions = segment(&new, &parent_classes, &rendered_child.geometry, params);
    Some((rendered_child, regions))
}

/// `set` eroded then dilated by a square of radius `radius` (cells), within `set`.
fn opened(set: Vec<bool>, geometry: &GridGeometry, radius: usize) -> Vec<bool> {
    if radius == 0 {
        return set;
    }
    let complement: Vec<bool> = set.iter().map(|s| !s).collect();
    let Some(eroded) = CellMask::from_flags(*geometry, complement).map(|m| m.dilate(radius)) else {
        return set;
    };
    let eroded: Vec<bool> = eroded.flags().iter().map(|s| !s).collect();
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
    parent: &[CellClass],
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
    parent: &[CellClass],
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
    let class = |i: usize| parent.get(i).copied().unwrap_or(CellClass::Unknown);
    let walls = cells
        .iter()
        .filter(|&&i| class(i) == CellClass::Occupied)
        .count();
    // Boundary cells, and what lies within two cells of each outside the region.
    let (mut boundary, mut frontier, mut contact) = (0usize, 0usize, 0usize);
    for &i in cells {
        let (x, y) = ((i % w) as i64, (i / w) as i64);
        let mut outside_free = false;
        let mut outside_wall = false;
        let mut on_boundary = false;
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
                on_boundary |= dx.abs() + dy.abs() == 1;
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
