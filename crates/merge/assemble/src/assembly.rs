//! The incremental assembly (AutoMerge Sec. VI, Fig. 6): segments arrive one at a time, in
//! any order; each arrival is associated with every segment already there, the pair weights
//! ω (Eq. 9) are updated and the segments regrouped by spectral clustering (Algorithm 1).
//! Pair results depend on the two segments only (associated in name order), and grouping is
//! canonical, so the final groups do not depend on the arrival order.

use std::collections::{BTreeMap, BTreeSet};
use std::time::Instant;

use mapmerge_association::{DescriptorMatrix, GroupingParams, IncrementalGrouping};
use mapmerge_geometry::{wrap_angle_rad, LieGroup, Se2};
use mapmerge_params::{Checker, Real, Validate};
use mapmerge_place::ScanMatchVerifier;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::associate::{
    associate_pair, pair_verifier, AssociationParams, PairAssociation, PreparedSegment, SegmentLoop,
};
use crate::descriptor::{
    describe_submaps, RingSpectrum3Params, RingSpectrumDescriptor, RingSpectrumDescriptor3,
    RingSpectrumParams,
};
use crate::error::AssembleError;
use crate::optimize::{solve_group_without, GroupGraphParams};
use crate::segment::{Segment, Segment3};
use crate::submap::{build_submaps, SubmapParams};
use crate::three_d::{prepare_3d, GroundSlice};

/// Everything the assembly is tuned by (serde, unknown fields refused).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AssembleParams {
    /// Submaps along each segment.
    pub submaps: SubmapParams,
    /// The 2D descriptor.
    pub descriptor: RingSpectrumParams,
    /// Pairwise association.
    pub association: AssociationParams,
    /// Spectral grouping.
    pub grouping: GroupingParams,
    /// Each group's pose graph.
    pub graph: GroupGraphParams,
    /// A pair whose median loop residual in its group's graph (least squares, no robust
    /// kernel) exceeds this (m, deg) is in a contradiction (default: 0.5 m, 5°); see
    /// `check_groups`.
    pub max_pair_residual: (f64, f64),
    /// … and the pairs of a segment whose odometry had to bend by more than this many
    /// standard deviations on some edge (default: 5) are in one.
    pub max_odometry_excess: f64,
    /// Three pairs closing a triangle agree when their placements compose to within this
    /// (m, deg) (default: 3 m, 10°: the segments' drift between the overlaps).
    pub max_triangle_error: (f64, f64),
    /// A pair that no triangle of pairs confirms (a segment's only link, or the one bridge
    /// between two groups) rests on its own loop edges alone, and nothing else would catch
    /// a placement slid along a corridor: it is kept only with at least this many agreeing
    /// edges (default: 3; a pair confirmed by a triangle needs
    /// `VerificationParams::min_loops`, 2).
    pub unconfirmed_min_loops: usize,
}

impl Default for AssembleParams {
    fn default() -> Self {
        Self {
            submaps: SubmapParams::default(),
            descriptor: RingSpectrumParams::default(),
            association: AssociationParams::default(),
            grouping: GroupingParams::default(),
            graph: GroupGraphParams::default(),
            max_pair_residual: (0.5, 5.0),
            max_odometry_excess: 5.0,
            max_triangle_error: (3.0, 10.0),
            unconfirmed_min_loops: 3,
        }
    }
}

impl Validate for AssembleParams {
    fn check(&self, check: &mut Checker) {
        let degrees = Real::within(0.0, 180.0);
        check
            .nested("submaps", &self.submaps)
            .nested("descriptor", &self.descriptor)
            .nested("association", &self.association)
            .nested("grouping", &self.grouping)
            .nested("graph", &self.graph)
            .reals(
                "max_pair_residual",
                &[
                    (self.max_pair_residual.0, Real::non_negative()),
                    (self.max_pair_residual.1, degrees),
                ],
            )
            .real(
                "max_odometry_excess",
                self.max_odometry_excess,
                Real::positive(),
            )
            .reals(
                "max_triangle_error",
                &[
                    (self.max_triangle_error.0, Real::non_negative()),
                    (self.max_triangle_error.1, degrees),
                ],
            )
            .size(
                "unconfirmed_min_loops",
                self.unconfirmed_min_loops,
                0,
                10_000,
            );
    }
}

/// What one arrival did.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Arrival {
    /// The new segment.
    pub segment: String,
    /// Its submaps.
    pub submaps: usize,
    /// Segments it was associated with, and those it connected to (ω > 0; the consistency
    /// check after the arrival may still reject some of these pairs, see
    /// [`Assembler::rejected_pairs`]).
    pub pairs: usize,
    pub connected: Vec<String>,
    /// Groups after the arrival.
    pub groups: usize,
    /// Wall time (s): submaps + descriptors, association with every other segment, grouping.
    pub prepare_secs: f64,
    pub association_secs: f64,
    pub grouping_secs: f64,
}

/// The assembly so far.
pub struct Assembler {
    params: AssembleParams,
    descriptor: RingSpectrumDescriptor,
    verifier: ScanMatchVerifier,
    segments: BTreeMap<String, (Segment, PreparedSegment)>,
    pairs: BTreeMap<(String, String), PairAssociation>,
    grouping: IncrementalGrouping<String>,
    /// Associated pairs the groups' pose graphs contradict (left out of grouping, loops and
    /// graphs); recomputed from all pairs after every arrival.
    rejected: BTreeSet<(String, String)>,
    /// What the first segment was; every later one must be described the same way.
    kind: Option<SegmentKind>,
}

/// How a segment's descriptors were made: all segments of one assembly must agree, since
/// association compares descriptor rows directly.
#[derive(Clone, Debug, PartialEq)]
enum SegmentKind {
    /// 2D scans, the assembler's own descriptor.
    Planar,
    /// 3D clouds ([`crate::three_d`]) with this descriptor and height band.
    Spatial(RingSpectrum3Params, GroundSlice),
}

impl Assembler {
    /// An empty assembly; fails on a parameter out of its range.
    pub fn new(params: AssembleParams) -> Result<Self, AssembleError> {
        Validate::validate(&params)?;
        let verifier = pair_verifier(&params.association.verification)?;
        Ok(Self {
            descriptor: RingSpectrumDescriptor::new(&params.descriptor),
            grouping: IncrementalGrouping::new(params.grouping),
            verifier,
            params,
            segments: BTreeMap::new(),
            pairs: BTreeMap::new(),
            rejected: BTreeSet::new(),
            kind: None,
        })
    }

    /// The parameters.
    pub fn params(&self) -> &AssembleParams {
        &self.params
    }

    /// Submaps and descriptors of `segment`.
    pub fn prepare(&self, segment: &Segment) -> Result<PreparedSegment, AssembleError> {
        let submaps = build_submaps(segment, &self.params.submaps)?;
        let rows = describe_submaps(&self.descriptor, &submaps);
        let descriptors = DescriptorMatrix::new(rows.dim, rows.values).map_err(|e| {
            AssembleError::Association {
                pair: segment.name.clone(),
                reason: e.to_string(),
            }
        })?;
        Ok(PreparedSegment {
            name: segment.name.clone(),
            submaps,
            descriptors,
        })
    }

    /// Adds a segment: association with every segment already here, new weights, new groups.
    /// Fails on a duplicate name (nothing changes then).
    pub fn add_segment(&mut self, segment: Segment) -> Result<Arrival, AssembleError> {
        self.add_segment_reusing(segment, &BTreeMap::new())
    }

    /// As [`Assembler::add_segment`], taking a pair's association from `known` when it holds
    /// it (a pair's result depends on the two segments only, so a replay in another order can
    /// reuse it).
    pub fn add_segment_reusing(
        &mut self,
        segment: Segment,
        known: &BTreeMap<(String, String), PairAssociation>,
    ) -> Result<Arrival, AssembleError> {
        self.check_arrival(&segment.name, &SegmentKind::Planar)?;
        let started = Instant::now();
        let prepared = self.prepare(&segment)?;
        let prepare_secs = started.elapsed().as_secs_f64();
        self.arrive(segment, prepared, SegmentKind::Planar, prepare_secs, known)
    }

    /// Adds a 3D segment ([`crate::three_d`]): its submaps are described by `descriptor3`
    /// and verified and optimised in the ground plane on the `slice` band; from then on it is
    /// a segment like any other ([`Assembler::segment`] gives its planar segment, whose poses
    /// are the projected ones). Pairs in `known` are reused as in
    /// [`Assembler::add_segment_reusing`]. Fails, changing nothing, on a duplicate name, and
    /// when the assembly already holds 2D segments or 3D segments described with other
    /// descriptor parameters or another band (descriptors must be comparable).
    pub fn add_segment_3d(
        &mut self,
        segment: &Segment3,
        descriptor3: &RingSpectrumDescriptor3,
        slice: &GroundSlice,
        known: &BTreeMap<(String, String), PairAssociation>,
    ) -> Result<Arrival, AssembleError> {
        let kind = SegmentKind::Spatial(descriptor3.params().clone(), slice.clone());
        self.check_arrival(&segment.name, &kind)?;
        let started = Instant::now();
        let (prepared, planar) = prepare_3d(segment, &self.params.submaps, descriptor3, slice)?;
        let prepare_secs = started.elapsed().as_secs_f64();
        self.arrive(planar, prepared, kind, prepare_secs, known)
    }

    /// Refuses a duplicate name or a segment described differently from those already here.
    fn check_arrival(&self, name: &str, kind: &SegmentKind) -> Result<(), AssembleError> {
        if self.segments.contains_key(name) {
            return Err(AssembleError::InvalidSegment {
                segment: name.to_owned(),
                reason: "a segment of that name was already added".into(),
            });
        }
        match &self.kind {
            Some(first) if first != kind => Err(AssembleError::InvalidSegment {
                segment: name.to_owned(),
                reason: format!(
                    "described as {kind:?} but the assembly holds segments described as \
                     {first:?}; 2D and 3D segments (or 3D ones with other descriptor or band \
                     parameters) cannot be compared"
                ),
            }),
            _ => Ok(()),
        }
    }

    /// The arrival shared by 2D and 3D segments: association with every segment already here
    /// (or the `known` result), then the commit: weights, segment, pairs, groups.
    fn arrive(
        &mut self,
        segment: Segment,
        prepared: PreparedSegment,
        kind: SegmentKind,
        prepare_secs: f64,
        known: &BTreeMap<(String, String), PairAssociation>,
    ) -> Result<Arrival, AssembleError> {
        let started = Instant::now();
        let spacing_m = self.params.submaps.spacing_m;
        let results: Vec<Result<PairAssociation, AssembleError>> = self
            .segments
            .values()
            .collect::<Vec<_>>()
            .par_iter()
            .map(|(_, other)| {
                let (a, b) = if other.name < prepared.name {
                    (other, &prepared)
                } else {
                    (&prepared, other)
                };
                if let Some(done) = known.get(&(a.name.clone(), b.name.clone())) {
                    return Ok(done.clone());
                }
                associate_pair(
                    a,
                    b,
                    &self.descriptor,
                    &self.verifier,
                    &self.params.association,
                    spacing_m,
                )
            })
            .collect();
        let association_secs = started.elapsed().as_secs_f64();
        let mut pairs = Vec::with_capacity(results.len());
        for r in results {
            pairs.push(r?);
        }
        // Commit.
        let started = Instant::now();
        let name = segment.name.clone();
        self.grouping.add_segment(name.clone());
        let mut connected = Vec::new();
        for pair in &pairs {
            if pair.weight > 0.0 {
                self.grouping
                    .set_weight(&pair.a, &pair.b, pair.weight)
                    .map_err(|e| AssembleError::Association {
                        pair: format!("{} × {}", pair.a, pair.b),
                        reason: e.to_string(),
                    })?;
                connected.push(if pair.a == name {
                    pair.b.clone()
                } else {
                    pair.a.clone()
                });
            }
        }
        let submaps = prepared.submaps.len();
        self.segments.insert(name.clone(), (segment, prepared));
        self.kind.get_or_insert(kind);
        let pair_count = pairs.len();
        for pair in pairs {
            self.pairs.insert((pair.a.clone(), pair.b.clone()), pair);
        }
        let groups = self.check_groups()?.len();
        Ok(Arrival {
            segment: name,
            submaps,
            pairs: pair_count,
            connected,
            groups,
            prepare_secs,
            association_secs,
            grouping_secs: started.elapsed().as_secs_f64(),
        })
    }

    /// The groups (Algorithm 1): each sorted by name, groups by their first name.
    pub fn groups(&mut self) -> Result<Vec<Vec<String>>, AssembleError> {
        self.grouping
            .groups()
            .map(<[Vec<String>]>::to_vec)
            .map_err(|e| AssembleError::Association {
                pair: "grouping".into(),
                reason: e.to_string(),
            })
    }

    /// Every pair's association, by `(a, b)` with `a < b`.
    pub fn pairs(&self) -> &BTreeMap<(String, String), PairAssociation> {
        &self.pairs
    }

    /// Every accepted loop edge, pair by pair (none of a rejected pair).
    pub fn loops(&self) -> impl Iterator<Item = &SegmentLoop> + '_ {
        self.pairs
            .iter()
            .filter(|(key, _)| !self.rejected.contains(*key))
            .flat_map(|(_, p)| p.loops.iter())
    }

    /// Associated pairs the group graphs contradicted.
    pub fn rejected_pairs(&self) -> &BTreeSet<(String, String)> {
        &self.rejected
    }

    /// Groups whose pose graphs agree with every pair in them. From all associated pairs:
    /// first the pairs that triangles of pairs contradict more than confirm leave (most
    /// contradicted first), and so do the pairs no triangle confirms that have too few edges
    /// of their own (`unconfirmed_min_loops`); then the groups (Algorithm 1) and each group's
    /// graph; while some pairs are in a contradiction (`violating_pairs`), the one of them
    /// with the least evidence (shortest overlap `L_ij`) leaves the grouping and the groups
    /// are made again. Then the rejected
    /// pairs are offered back, most evidence first, and stay when the graphs accept them
    /// (a correct pair bent by a wrong one comes back). A look-alike that joined two groups
    /// disagrees with the segments' other connections and is dropped once later evidence
    /// contradicts it (the paper's Fig. 13 recovery). Computed from scratch, so it depends on
    /// the pair set only, never on the arrival order.
    fn check_groups(&mut self) -> Result<Vec<Vec<String>>, AssembleError> {
        let accepted: Vec<(String, String, f64)> = self
            .pairs
            .values()
            .filter(|p| p.weight > 0.0)
            .map(|p| (p.a.clone(), p.b.clone(), p.weight))
            .collect();
        for (a, b, weight) in accepted {
            self.set_pair_weight(&a, &b, weight)?;
        }
        self.rejected.clear();
        // 1. Cycles of three: the pair most often contradicted by triangles it closes, and
        //    contradicted more often than confirmed, goes first (fewest confirmations, then
        //    least evidence, break ties).
        loop {
            let votes = self.triangle_votes();
            let Some((pair, _)) = votes
                .into_iter()
                .filter(|(_, (confirmed, contradicted))| contradicted > confirmed)
                .min_by(|(x, (cx, kx)), (y, (cy, ky))| {
                    (ky - cy)
                        .cmp(&(kx - cx))
                        .then_with(|| self.evidence(x).total_cmp(&self.evidence(y)))
                        .then_with(|| x.cmp(y))
                })
            else {
                break;
            };
            self.set_pair_weight(&pair.0, &pair.1, 0.0)?;
            self.rejected.insert(pair);
        }
        // 2. A pair no triangle confirms needs more edges of its own (removing it takes no
        //    confirmation from another pair: it closes no consistent triangle).
        let votes = self.triangle_votes();
        let weak: Vec<(String, String)> = self
            .pairs
            .keys()
            .filter(|key| !self.rejected.contains(*key) && self.unconfirmed_and_weak(key, &votes))
            .cloned()
            .collect();
        for pair in weak {
            self.set_pair_weight(&pair.0, &pair.1, 0.0)?;
            self.rejected.insert(pair);
        }
        // 3. The groups' pose graphs.
        loop {
            let violating = self.violating_pairs()?;
            let Some(pair) = violating.into_iter().min_by(|x, y| {
                self.evidence(x)
                    .total_cmp(&self.evidence(y))
                    .then_with(|| x.cmp(y))
            }) else {
                break;
            };
            self.set_pair_weight(&pair.0, &pair.1, 0.0)?;
            self.rejected.insert(pair);
        }
        let mut offered: Vec<(String, String)> = self.rejected.iter().cloned().collect();
        offered.sort_by(|x, y| {
            self.evidence(y)
                .total_cmp(&self.evidence(x))
                .then_with(|| x.cmp(y))
        });
        for pair in offered {
            let weight = self.pairs.get(&pair).map_or(0.0, |p| p.weight);
            self.rejected.remove(&pair);
            self.set_pair_weight(&pair.0, &pair.1, weight)?;
            let votes = self.triangle_votes();
            let contradicted = votes
                .get(&pair)
                .is_some_and(|(_, contradicted)| *contradicted > 0);
            if contradicted
                || self.unconfirmed_and_weak(&pair, &votes)
                || !self.violating_pairs()?.is_empty()
            {
                self.set_pair_weight(&pair.0, &pair.1, 0.0)?;
                self.rejected.insert(pair);
            }
        }
        self.groups()
    }

    /// Pairs whose median loop residual in their group's graph, optimised without and with
    /// the robust kernel, exceeds `max_pair_residual`, and the pairs of segments a graph had
    /// to fold (`max_odometry_excess`).
    fn violating_pairs(&mut self) -> Result<Vec<(String, String)>, AssembleError> {
        let (gate_m, gate_deg) = self.params.max_pair_residual;
        let plain = GroupGraphParams {
            robust: false,
            ..self.params.graph.clone()
        };
        let mut violating = Vec::new();
        for group in self.groups()?.iter().filter(|g| g.len() > 1) {
            // Least squares spreads a contradiction over its cycle (or folds a segment);
            // DCS leaves it on the pair it gave up on. Either counts.
            for params in [&plain, &self.params.graph] {
                let solution = solve_group_without(self, group, params, &self.rejected)?;
                let folded: BTreeSet<&String> = solution
                    .odometry_excess
                    .iter()
                    .filter(|(_, excess)| **excess > self.params.max_odometry_excess)
                    .map(|(name, _)| name)
                    .collect();
                for (pair, (metres, radians)) in &solution.pair_residuals {
                    if *metres > gate_m
                        || radians.to_degrees() > gate_deg
                        || folded.contains(&pair.0)
                        || folded.contains(&pair.1)
                    {
                        violating.push(pair.clone());
                    }
                }
            }
        }
        violating.sort();
        violating.dedup();
        Ok(violating)
    }

    /// For every accepted pair: how many triangles of accepted pairs it closes consistently
    /// and how many it contradicts (`a_from_b · b_from_c` against `a_from_c`, within
    /// `max_triangle_error`; the placements come from different places of the segments, so
    /// the tolerance covers their drift in between).
    fn triangle_votes(&self) -> BTreeMap<(String, String), (usize, usize)> {
        let placements: BTreeMap<(&str, &str), Se2> = self
            .pairs
            .iter()
            .filter(|(key, p)| p.weight > 0.0 && !self.rejected.contains(*key))
            .filter_map(|(_, p)| Some(((p.a.as_str(), p.b.as_str()), p.a_from_b?)))
            .collect();
        let mut neighbours: BTreeMap<&str, BTreeSet<&str>> = BTreeMap::new();
        for (a, b) in placements.keys() {
            neighbours.entry(a).or_default().insert(b);
            neighbours.entry(b).or_default().insert(a);
        }
        let (tolerance_m, tolerance_deg) = self.params.max_triangle_error;
        let mut votes: BTreeMap<(String, String), (usize, usize)> = BTreeMap::new();
        for (&(a, b), a_from_b) in &placements {
            let (Some(na), Some(nb)) = (neighbours.get(a), neighbours.get(b)) else {
                continue;
            };
            // Each triangle a < b < c once.
            for &c in na.intersection(nb).filter(|&&c| c > b) {
                let (Some(b_from_c), Some(a_from_c)) =
                    (placements.get(&(b, c)), placements.get(&(a, c)))
                else {
                    continue;
                };
                let error = a_from_b.compose(b_from_c).between(a_from_c);
                let consistent = error.translation().norm() <= tolerance_m
                    && wrap_angle_rad(error.theta_rad).abs().to_degrees() <= tolerance_deg;
                for (x, y) in [(a, b), (b, c), (a, c)] {
                    let vote = votes.entry((x.to_owned(), y.to_owned())).or_default();
                    if consistent {
                        vote.0 += 1;
                    } else {
                        vote.1 += 1;
                    }
                }
            }
        }
        votes
    }

    /// Whether the accepted pair `key` closes no consistent triangle (by `votes`) and has
    /// fewer than `unconfirmed_min_loops` loop edges.
    fn unconfirmed_and_weak(
        &self,
        key: &(String, String),
        votes: &BTreeMap<(String, String), (usize, usize)>,
    ) -> bool {
        self.pairs.get(key).is_some_and(|p| {
            p.weight > 0.0
                && votes.get(key).map_or(0, |(confirmed, _)| *confirmed) == 0
                && p.loops.len() < self.params.unconfirmed_min_loops
        })
    }

    /// How much a pair's association rests on: its overlap length `L_ij` (m).
    fn evidence(&self, pair: &(String, String)) -> f64 {
        self.pairs.get(pair).map_or(0.0, |p| p.overlap_length_m)
    }

    fn set_pair_weight(&mut self, a: &str, b: &str, weight: f64) -> Result<(), AssembleError> {
        self.grouping
            .set_weight(&a.to_owned(), &b.to_owned(), weight)
            .map_err(|e| AssembleError::Association {
                pair: format!("{a} × {b}"),
                reason: e.to_string(),
            })
    }

    /// A segment and its submaps by name.
    pub fn segment(&self, name: &str) -> Option<(&Segment, &PreparedSegment)> {
        self.segments.get(name).map(|(s, p)| (s, p))
    }

    /// Segment names, sorted.
    pub fn names(&self) -> impl Iterator<Item = &String> + '_ {
        self.segments.keys()
    }
}
