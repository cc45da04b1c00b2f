//! Further mapping after a merge, with periodic verification and undo (Andersone, Sec. 2.3,
//! 3.1 and 3.2).
//!
//! * **2M, multiple maps** (Sec. 3.1): every scan goes into both the own map and the merged
//!   map. Undo drops the merged map; the own map has every scan, so nothing collected after
//!   the merge is lost.
//! * **1M, single map** (Sec. 3.2): every scan goes into the merged map only, plus a
//!   local-update map marking the cells the robot itself updated (its own map's observed
//!   cells at the merge, and every cell a scan touched since). Undo resets every cell not
//!   updated locally to unknown.
//!
//! Every `check_every_scans` scans after a merge a [`MergeCheck`] (e.g. the SM/DM metrics of
//! Sec. 3.3) judges the merge; an inconsistent verdict triggers the undo. Merges,
//! verifications and undos are [`GridMergeEvent`]s, each with its reason.

use std::time::Instant;

use mapmerge_geometry::Se2;
use mapmerge_grid::{
    Cell, CellClass, CellMask, ClassThresholds, GridGeometry, InsertParams, OccupancyGrid,
    SensorModel,
};
use mapmerge_scan::LaserScan;
use serde::{Deserialize, Serialize};

use crate::fusion::{fuse, FusionInfo, FusionParams};
use crate::MergeError;

/// Identifies one merge of a [`ReversibleMapper`] (counted from 0).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct GridMergeId(pub u32);

impl core::fmt::Display for GridMergeId {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "#{}", self.0)
    }
}

/// How mapping continues after a merge.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ReversibleMode {
    /// 2M: own map and merged map both updated (Sec. 3.1).
    MultiMap,
    /// 1M: merged map plus local-update map (Sec. 3.2).
    SingleMap,
}

/// Which maps a mapper is updating.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MapperState {
    /// No merge active: the own map only.
    Own,
    /// 2M: own and merged maps.
    MultiMap,
    /// 1M: merged map and local-update map.
    SingleMap,
}

/// Parameters of [`ReversibleMapper`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ReversibleParams {
    /// 2M or 1M (default `multi_map`: exact undo at twice the update cost).
    pub mode: ReversibleMode,
    /// Run the check after every this many scans since the merge; 0 never checks (default
    /// 10, the paper's further-mapping length, Sec. 4.2).
    pub check_every_scans: usize,
    /// How scans update the maps.
    pub insert: InsertParams,
    /// How the other map is fused.
    pub fusion: FusionParams,
}

impl Default for ReversibleParams {
    fn default() -> Self {
        Self {
            mode: ReversibleMode::MultiMap,
            check_every_scans: 10,
            insert: InsertParams::default(),
            fusion: FusionParams::default(),
        }
    }
}

/// A named number a check reports (e.g. `sm`, `dm`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Metric {
    /// Name.
    pub name: String,
    /// Value.
    pub value: f64,
}

/// A check's judgement of a merge.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "verdict", rename_all = "snake_case")]
pub enum Verdict {
    /// The maps still agree: keep the merge.
    Consistent {
        /// What the check measured.
        metrics: Vec<Metric>,
    },
    /// The merge looks wrong: undo it.
    Inconsistent {
        /// Why, in words (e.g. `DM 7.2 > 3.0`).
        reason: String,
        /// What the check measured.
        metrics: Vec<Metric>,
    },
}

impl Verdict {
    /// True for [`Verdict::Consistent`].
    pub fn is_consistent(&self) -> bool {
        matches!(self, Verdict::Consistent { .. })
    }
}

/// What a [`MergeCheck`] sees.
#[derive(Clone, Copy, Debug)]
pub struct CheckInput<'a> {
    /// The merge being checked.
    pub merge: GridMergeId,
    /// 2M or 1M.
    pub mode: ReversibleMode,
    /// 2M: the own map with every scan (never merged); `None` in 1M.
    pub own: Option<&'a OccupancyGrid>,
    /// The merged map with every scan since the merge.
    pub merged: &'a OccupancyGrid,
    /// Map B as it was fused, resampled onto A's frame and resolution (the merged map's
    /// geometry at the time of the merge).
    pub b_in_a: &'a OccupancyGrid,
    /// 1M: the cells the robot itself updated (same geometry as `merged`); `None` in 2M.
    pub local_updates: Option<&'a LocalUpdateMap>,
    /// Scans inserted since the merge.
    pub scans_since_merge: usize,
}

/// Periodic verification of a merge (Andersone, Sec. 2.3 and 3.3). The SM/DM metrics of
/// `mapmerge-gridmatch` implement it; any `Fn(&CheckInput) -> Verdict` does too.
pub trait MergeCheck {
    /// Judges the merge.
    fn check(&self, input: &CheckInput<'_>) -> Verdict;
}

impl<F: Fn(&CheckInput<'_>) -> Verdict> MergeCheck for F {
    fn check(&self, input: &CheckInput<'_>) -> Verdict {
        self(input)
    }
}

/// A check that always keeps the merge.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct KeepMerge;

impl MergeCheck for KeepMerge {
    fn check(&self, _: &CheckInput<'_>) -> Verdict {
        Verdict::Consistent {
            metrics: Vec::new(),
        }
    }
}

/// Why a merge was undone.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "by", rename_all = "snake_case")]
pub enum UndoReason {
    /// The periodic check found the maps inconsistent.
    CheckFailed {
        /// The check's reason.
        reason: String,
        /// The check's metrics.
        metrics: Vec<Metric>,
    },
    /// The caller asked for it.
    Requested {
        /// The caller's reason.
        reason: String,
    },
}

/// What happened.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum GridMergeEventKind {
    /// Map B was fused in.
    Merged {
        /// 2M or 1M from here on.
        mode: ReversibleMode,
        /// B's map frame in A's map frame.
        a_from_b: Se2,
        /// Why (e.g. the decision-table record and the match's acceptance).
        reason: String,
        /// What the fusion did.
        fusion: FusionInfo,
    },
    /// The periodic check ran.
    Verified {
        /// Scans since the merge.
        scans_since_merge: usize,
        /// Its judgement.
        verdict: Verdict,
    },
    /// The merge was taken back.
    Undone {
        /// How.
        mode: ReversibleMode,
        /// Why.
        reason: UndoReason,
        /// Scans since the merge.
        scans_since_merge: usize,
        /// 1M: cells reset to unknown (0 in 2M, where the merged map is dropped whole).
        cells_reset: usize,
    },
}

/// One entry of a mapper's event list.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GridMergeEvent {
    /// The merge it concerns.
    pub merge: GridMergeId,
    /// Scans inserted (in total) when it happened.
    pub after_scans: u64,
    /// What happened.
    pub kind: GridMergeEventKind,
}

/// Time spent on one scan, by map (seconds; 0 for maps not updated). The data behind
/// update-time tables like Andersone's Tables 1–3.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct UpdateTiming {
    /// Index of the scan (0 for the first scan inserted).
    pub scan_index: u64,
    /// Which maps were updated.
    pub state: MapperState,
    /// Own map update.
    pub own_seconds: f64,
    /// Merged map update.
    pub merged_seconds: f64,
    /// Local-update map update (1M).
    pub local_seconds: f64,
    /// Sum of the three: the map update time.
    pub update_seconds: f64,
    /// The periodic check, when it ran after this scan (not part of `update_seconds`).
    pub check_seconds: f64,
}

/// The outcome of [`ReversibleMapper::insert_scan`].
#[derive(Clone, Debug, PartialEq)]
pub struct ScanUpdate {
    /// Update times.
    pub timing: UpdateTiming,
    /// The check's verdict, when it ran.
    pub verdict: Option<Verdict>,
    /// True when the verdict undid the merge.
    pub undone: bool,
}

/// The 1M local-update map (Andersone, Sec. 3.2): which cells of the merged map the robot
/// updated itself. Same geometry as the merged map.
#[derive(Clone, Debug, PartialEq)]
pub struct LocalUpdateMap {
    /// 1.0 where updated locally, 0.0 elsewhere; grown exactly as the merged map.
    marks: OccupancyGrid,
}

/// Scan insertion that sets every touched cell to exactly 1: `(l + 1).clamp(1, 1)`.
const MARK: SensorModel = SensorModel {
    hit_log_odds: 1.0,
    miss_log_odds: 1.0,
    min_log_odds: 1.0,
    max_log_odds: 1.0,
};

impl LocalUpdateMap {
    /// Marks the observed cells of `own` on the cells of `geometry` (same resolution and
    /// lattice, `geometry`'s cell = own's cell + `shift`).
    fn new(own: &OccupancyGrid, geometry: GridGeometry, shift: Cell) -> Result<Self, MergeError> {
        let mut marks = OccupancyGrid::with_geometry(geometry)?;
        let own_width = own.geometry().width;
        let width = geometry.width;
        let cells = marks.log_odds_mut();
        if own_width > 0 {
            for (y, row) in own.log_odds().chunks_exact(own_width).enumerate() {
                let ty = (y as i64).saturating_add(shift.y);
                for (x, &l) in row.iter().enumerate() {
                    let tx = (x as i64).saturating_add(shift.x);
                    if l == 0.0 || tx < 0 || ty < 0 || tx as usize >= width {
                        continue;
                    }
                    if let Some(m) = cells.get_mut(ty as usize * width + tx as usize) {
                        *m = 1.0;
                    }
                }
            }
        }
        Ok(Self { marks })
    }

    /// Size and placement (the merged map's).
    pub fn geometry(&self) -> &GridGeometry {
        self.marks.geometry()
    }

    /// Whether the robot updated `cell` itself (false outside).
    pub fn is_updated(&self, cell: Cell) -> bool {
        self.marks.cell_log_odds(cell) != 0.0
    }

    /// Row-major flags, one per cell of [`Self::geometry`].
    pub fn flags(&self) -> impl ExactSizeIterator<Item = bool> + '_ {
        self.marks.log_odds().iter().map(|&m| m != 0.0)
    }

    /// Number of cells updated locally.
    pub fn count(&self) -> usize {
        self.flags().filter(|&f| f).count()
    }

    /// Resets every cell of `merged` (same geometry) not updated locally to unknown: the map
    /// the 1M undo leaves (Sec. 3.2). Returns how many known cells were reset.
    pub fn reset_others(&self, merged: &mut OccupancyGrid) -> usize {
        let mut reset = 0;
        for (cell, mark) in merged.log_odds_mut().iter_mut().zip(self.marks.log_odds()) {
            if *mark == 0.0 && *cell != 0.0 {
                *cell = 0.0;
                reset += 1;
            }
        }
        reset
    }

    /// As a [`CellMask`].
    pub fn to_mask(&self) -> CellMask {
        // Marks are 1.0 (p ≈ 0.73), occupied under the default thresholds.
        self.marks
            .mask(CellClass::Occupied, &ClassThresholds::default())
    }
}

/// An active merge.
#[derive(Clone, Debug)]
struct Active {
    id: GridMergeId,
    b_in_a: OccupancyGrid,
    scans_since_merge: usize,
}

#[derive(Clone, Debug)]
enum State {
    Own(OccupancyGrid),
    MultiMap {
        own: OccupancyGrid,
        merged: OccupancyGrid,
        active: Active,
    },
    SingleMap {
        merged: OccupancyGrid,
        local: LocalUpdateMap,
        active: Active,
    },
}

/// A robot's map with reversible merging (Andersone, Sec. 3).
///
/// ```
/// use mapmerge_geometry::Se2;
/// use mapmerge_grid::OccupancyGrid;
/// use mapmerge_gridmerge::{KeepMerge, ReversibleMapper, ReversibleParams};
/// use mapmerge_scan::LaserScan;
///
/// let mut mapper = ReversibleMapper::new(OccupancyGrid::new(0.1)?, ReversibleParams::default())?;
/// let scan = LaserScan::new(-1.5, 1.5, 10.0, vec![3.0; 61]);
/// mapper.insert_scan(&Se2::new(0.0, 0.0, 0.0), &scan, &KeepMerge)?;
/// let other = mapper.current().clone();
/// mapper.merge(&other, &Se2::new(0.0, 0.0, 0.0), "same robot, for the example")?;
/// mapper.insert_scan(&Se2::new(0.5, 0.0, 0.0), &scan, &KeepMerge)?;
/// mapper.undo("example")?;
/// assert_eq!(mapper.events().len(), 2);
/// # Ok::<(), mapmerge_gridmerge::MergeError>(())
/// ```
#[derive(Clone, Debug)]
pub struct ReversibleMapper {
    params: ReversibleParams,
    state: State,
    events: Vec<GridMergeEvent>,
    timings: Vec<UpdateTiming>,
    scans: u64,
    next_merge: u32,
}

impl ReversibleMapper {
    /// A mapper starting from the robot's own map.
    pub fn new(own: OccupancyGrid, params: ReversibleParams) -> Result<Self, MergeError> {
        params.fusion.validate()?;
        let m = params.insert.model;
        if !(m.hit_log_odds.is_finite()
            && m.miss_log_odds.is_finite()
            && m.min_log_odds.is_finite()
            && m.max_log_odds.is_finite()
            && m.min_log_odds <= m.max_log_odds)
        {
            return Err(MergeError::BadParams {
                name: "insert.model",
                reason: format!("needs finite values and min ≤ max, got {m:?}"),
            });
        }
        Ok(Self {
            params,
            state: State::Own(own),
            events: Vec::new(),
            timings: Vec::new(),
            scans: 0,
            next_merge: 0,
        })
    }

    /// The parameters.
    pub fn params(&self) -> &ReversibleParams {
        &self.params
    }

    /// Which maps are being updated.
    pub fn state(&self) -> MapperState {
        match self.state {
            State::Own(_) => MapperState::Own,
            State::MultiMap { .. } => MapperState::MultiMap,
            State::SingleMap { .. } => MapperState::SingleMap,
        }
    }

    /// The active merge, if any.
    pub fn active_merge(&self) -> Option<GridMergeId> {
        match &self.state {
            State::Own(_) => None,
            State::MultiMap { active, .. } | State::SingleMap { active, .. } => Some(active.id),
        }
    }

    /// The map the robot navigates with: the merged map while a merge is active, else its own.
    pub fn current(&self) -> &OccupancyGrid {
        match &self.state {
            State::Own(own) => own,
            State::MultiMap { merged, .. } | State::SingleMap { merged, .. } => merged,
        }
    }

    /// The own map (never merged); `None` in 1M while a merge is active.
    pub fn own(&self) -> Option<&OccupancyGrid> {
        match &self.state {
            State::Own(own) | State::MultiMap { own, .. } => Some(own),
            State::SingleMap { .. } => None,
        }
    }

    /// The merged map, while a merge is active.
    pub fn merged(&self) -> Option<&OccupancyGrid> {
        match &self.state {
            State::Own(_) => None,
            State::MultiMap { merged, .. } | State::SingleMap { merged, .. } => Some(merged),
        }
    }

    /// The 1M local-update map, while a 1M merge is active.
    pub fn local_updates(&self) -> Option<&LocalUpdateMap> {
        match &self.state {
            State::SingleMap { local, .. } => Some(local),
            _ => None,
        }
    }

    /// Map B as fused, on A's frame and resolution, while a merge is active.
    pub fn b_in_a(&self) -> Option<&OccupancyGrid> {
        match &self.state {
            State::Own(_) => None,
            State::MultiMap { active, .. } | State::SingleMap { active, .. } => {
                Some(&active.b_in_a)
            }
        }
    }

    /// Every merge, verification and undo so far, oldest first.
    pub fn events(&self) -> &[GridMergeEvent] {
        &self.events
    }

    /// Update times of every scan so far, oldest first.
    pub fn update_times(&self) -> &[UpdateTiming] {
        &self.timings
    }

    /// Scans inserted so far.
    pub fn scans(&self) -> u64 {
        self.scans
    }

    /// The map the robot navigates with, consuming the mapper.
    pub fn into_current(self) -> OccupancyGrid {
        match self.state {
            State::Own(own) => own,
            State::MultiMap { merged, .. } | State::SingleMap { merged, .. } => merged,
        }
    }

    /// Fuses map `b` (its frame given in A's map frame by `a_from_b`) into the current map
    /// and continues in the configured mode. `reason` is recorded with the event. One merge
    /// at a time: undo the active one first.
    pub fn merge(
        &mut self,
        b: &OccupancyGrid,
        a_from_b: &Se2,
        reason: impl Into<String>,
    ) -> Result<GridMergeEvent, MergeError> {
        let own = match &self.state {
            State::Own(own) => own,
            State::MultiMap { active, .. } | State::SingleMap { active, .. } => {
                return Err(MergeError::AlreadyMerged(active.id));
            }
        };
        // Everything fallible first, the state swap last.
        let fused = fuse(own, b, a_from_b, &self.params.fusion)?;
        let local = match self.params.mode {
            ReversibleMode::SingleMap => Some(LocalUpdateMap::new(
                own,
                *fused.merged.geometry(),
                fused.info.a_shift_cells,
            )?),
            ReversibleMode::MultiMap => None,
        };
        let placeholder = State::Own(OccupancyGrid::new(own.resolution_m())?);
        let id = GridMergeId(self.next_merge);
        self.next_merge = self.next_merge.saturating_add(1);
        let active = Active {
            id,
            b_in_a: fused.b_in_a,
            scans_since_merge: 0,
        };
        let State::Own(own) = core::mem::replace(&mut self.state, placeholder) else {
            // Checked above; the state is unchanged in this arm.
            return Err(MergeError::NotMerged);
        };
        self.state = match local {
            Some(local) => State::SingleMap {
                merged: fused.merged,
                local,
                active,
            },
            None => State::MultiMap {
                own,
                merged: fused.merged,
                active,
            },
        };
        Ok(self.push_event(
            id,
            GridMergeEventKind::Merged {
                mode: self.params.mode,
                a_from_b: *a_from_b,
                reason: reason.into(),
                fusion: fused.info,
            },
        ))
    }

    /// Takes the active merge back: 2M drops the merged map, 1M resets every cell not updated
    /// locally to unknown.
    pub fn undo(&mut self, reason: impl Into<String>) -> Result<GridMergeEvent, MergeError> {
        self.undo_with(UndoReason::Requested {
            reason: reason.into(),
        })
    }

    fn undo_with(&mut self, reason: UndoReason) -> Result<GridMergeEvent, MergeError> {
        let resolution_m = match &self.state {
            State::Own(_) => return Err(MergeError::NotMerged),
            State::MultiMap { merged, .. } | State::SingleMap { merged, .. } => {
                merged.resolution_m()
            }
        };
        let placeholder = State::Own(OccupancyGrid::new(resolution_m)?);
        let (own, active, mode, cells_reset) =
            match core::mem::replace(&mut self.state, placeholder) {
                State::Own(own) => {
                    self.state = State::Own(own);
                    return Err(MergeError::NotMerged);
                }
                // Sec. 3.1: the own map already holds every scan; the merged map is dropped.
                State::MultiMap { own, active, .. } => (own, active, ReversibleMode::MultiMap, 0),
                // Sec. 3.2: cells not updated locally go back to unknown.
                State::SingleMap {
                    mut merged,
                    local,
                    active,
                } => {
                    let reset = local.reset_others(&mut merged);
                    (merged, active, ReversibleMode::SingleMap, reset)
                }
            };
        self.state = State::Own(own);
        Ok(self.push_event(
            active.id,
            GridMergeEventKind::Undone {
                mode,
                reason,
                scans_since_merge: active.scans_since_merge,
                cells_reset,
            },
        ))
    }

    /// Inserts a scan taken at `map_from_robot` (the robot's pose in A's map frame) into
    /// every map the state maintains ([`OccupancyGrid::insert_scan`]); every
    /// `check_every_scans` scans after a merge runs `check` and undoes the merge when it
    /// finds the maps inconsistent.
    pub fn insert_scan(
        &mut self,
        map_from_robot: &Se2,
        scan: &LaserScan,
        check: &dyn MergeCheck,
    ) -> Result<ScanUpdate, MergeError> {
        let insert = self.params.insert;
        let mut timing = UpdateTiming {
            scan_index: self.scans,
            state: self.state(),
            own_seconds: 0.0,
            merged_seconds: 0.0,
            local_seconds: 0.0,
            update_seconds: 0.0,
            check_seconds: 0.0,
        };
        match &mut self.state {
            State::Own(own) => {
                timing.own_seconds = timed(|| own.insert_scan(map_from_robot, scan, &insert))?;
            }
            State::MultiMap {
                own,
                merged,
                active,
            } => {
                timing.own_seconds = timed(|| own.insert_scan(map_from_robot, scan, &insert))?;
                timing.merged_seconds =
                    timed(|| merged.insert_scan(map_from_robot, scan, &insert))?;
                active.scans_since_merge += 1;
            }
            State::SingleMap {
                merged,
                local,
                active,
            } => {
                timing.merged_seconds =
                    timed(|| merged.insert_scan(map_from_robot, scan, &insert))?;
                let mark = InsertParams {
                    model: MARK,
                    ..insert
                };
                timing.local_seconds = timed(|| {
                    local.marks.insert_scan(map_from_robot, scan, &mark)?;
                    // Same geometry and same beams grow both grids alike; realign if not.
                    if local.marks.geometry() != merged.geometry() {
                        local.marks = realigned(&local.marks, merged.geometry())?;
                    }
                    Ok::<_, MergeError>(())
                })?;
                active.scans_since_merge += 1;
            }
        }
        self.scans += 1;
        timing.update_seconds = timing.own_seconds + timing.merged_seconds + timing.local_seconds;
        let mut update = ScanUpdate {
            timing,
            verdict: None,
            undone: false,
        };
        if let Some(due) = self.check_due() {
            let start = Instant::now();
            let verdict = self.run_check(check, due);
            update.timing.check_seconds = start.elapsed().as_secs_f64();
            update.verdict = Some(verdict.clone());
            self.push_event(
                due.0,
                GridMergeEventKind::Verified {
                    scans_since_merge: due.1,
                    verdict: verdict.clone(),
                },
            );
            if let Verdict::Inconsistent { reason, metrics } = verdict {
                self.undo_with(UndoReason::CheckFailed { reason, metrics })?;
                update.undone = true;
            }
        }
        self.timings.push(update.timing);
        Ok(update)
    }

    /// Runs `check` on the active merge now and undoes it if the verdict is inconsistent.
    pub fn verify_now(&mut self, check: &dyn MergeCheck) -> Result<Verdict, MergeError> {
        let due = match &self.state {
            State::Own(_) => return Err(MergeError::NotMerged),
            State::MultiMap { active, .. } | State::SingleMap { active, .. } => {
                (active.id, active.scans_since_merge)
            }
        };
        let verdict = self.run_check(check, due);
        self.push_event(
            due.0,
            GridMergeEventKind::Verified {
                scans_since_merge: due.1,
                verdict: verdict.clone(),
            },
        );
        if let Verdict::Inconsistent { reason, metrics } = &verdict {
            self.undo_with(UndoReason::CheckFailed {
                reason: reason.clone(),
                metrics: metrics.clone(),
            })?;
        }
        Ok(verdict)
    }

    fn check_due(&self) -> Option<(GridMergeId, usize)> {
        let every = self.params.check_every_scans;
        match &self.state {
            State::MultiMap { active, .. } | State::SingleMap { active, .. }
                if every > 0
                    && active.scans_since_merge > 0
                    && active.scans_since_merge % every == 0 =>
            {
                Some((active.id, active.scans_since_merge))
            }
            _ => None,
        }
    }

    /// What a check sees now; `None` while no merge is active.
    pub fn check_input(&self) -> Option<CheckInput<'_>> {
        match &self.state {
            State::MultiMap {
                own,
                merged,
                active,
            } => Some(CheckInput {
                merge: active.id,
                mode: ReversibleMode::MultiMap,
                own: Some(own),
                merged,
                b_in_a: &active.b_in_a,
                local_updates: None,
                scans_since_merge: active.scans_since_merge,
            }),
            State::SingleMap {
                merged,
                local,
                active,
            } => Some(CheckInput {
                merge: active.id,
                mode: ReversibleMode::SingleMap,
                own: None,
                merged,
                b_in_a: &active.b_in_a,
                local_updates: Some(local),
                scans_since_merge: active.scans_since_merge,
            }),
            State::Own(_) => None,
        }
    }

    fn run_check(&self, check: &dyn MergeCheck, (id, scans): (GridMergeId, usize)) -> Verdict {
        match self.check_input() {
            Some(input) => check.check(&CheckInput {
                merge: id,
                scans_since_merge: scans,
                ..input
            }),
            None => Verdict::Consistent {
                metrics: Vec::new(),
            },
        }
    }

    fn push_event(&mut self, merge: GridMergeId, kind: GridMergeEventKind) -> GridMergeEvent {
        let event = GridMergeEvent {
            merge,
            after_scans: self.scans,
            kind,
        };
        self.events.push(event.clone());
        event
    }
}

/// Runs `f`, returning the seconds it took.
fn timed<T, E>(f: impl FnOnce() -> Result<T, E>) -> Result<f64, MergeError>
where
    MergeError: From<E>,
{
    let start = Instant::now();
    f()?;
    Ok(start.elapsed().as_secs_f64())
}

/// `marks` placed on `geometry` (same resolution, lattice offset by whole cells).
fn realigned(marks: &OccupancyGrid, geometry: &GridGeometry) -> Result<OccupancyGrid, MergeError> {
    let offset = (marks.geometry().origin_m - geometry.origin_m) / geometry.resolution_m;
    let shift = Cell::new(offset.x.round() as i64, offset.y.round() as i64);
    Ok(LocalUpdateMap::new(marks, *geometry, shift)?.marks)
}
