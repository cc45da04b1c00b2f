//! The periodic verification of a merge by Andersone's metrics (Sec. 3.3): DM, and SM
//! beside it, between what the robot mapped itself and the other robot's map.

use mapmerge_geometry::Se2;
use mapmerge_grid::ClassThresholds;
use mapmerge_gridmatch::{map_metrics, MapMetrics};
use serde::{Deserialize, Serialize};

use crate::reversible::{CheckInput, MergeCheck, Metric, ReversibleMode, Verdict};

/// A [`MergeCheck`] by DM (and optionally SM) with one threshold per mode.
///
/// - 2M: the own map (every scan, never merged) against B as fused.
/// - 1M: the merged map with every cell the robot did not update itself reset to unknown
///   (the map the 1M undo would leave) against B. The paper compares the whole merged map,
///   which already holds B, so its SM cannot tell (Table 4); restricted to the robot's own
///   cells it sees what the robot saw, as 2M does, without a second map
///   (`mapmerge eval grid-merge` measures both).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MetricsCheck {
    /// Cell classes.
    pub thresholds: ClassThresholds,
    /// 2M: the merge is wrong when DM exceeds this (cells of the coarser map) (default: 3).
    /// On the Intel experiment correct merges measured 0.3–3.4, wrong ones 2.8–20.
    pub max_dm_cells_multi_map: f64,
    /// 1M: the same for the restricted merged map (default: 1.8; correct 0.1–1.8, wrong
    /// 1.0–11.6 on Intel).
    pub max_dm_cells_single_map: f64,
    /// The merge is also wrong when SM falls below this (default: 0, off: DM separates better,
    /// Sec. 4.3).
    pub min_sm: f64,
    /// Fewer cells known in both maps than this say nothing: the merge is kept (default: 200).
    pub min_overlap_cells: usize,
}

impl Default for MetricsCheck {
    fn default() -> Self {
        Self {
            thresholds: ClassThresholds::default(),
            max_dm_cells_multi_map: 3.0,
            max_dm_cells_single_map: 1.8,
            min_sm: 0.0,
            min_overlap_cells: 200,
        }
    }
}

impl MetricsCheck {
    /// SM and DM of the robot's own mapping against B, as this check compares them; `None`
    /// when the maps cannot be compared (e.g. nothing known).
    pub fn measure(&self, input: &CheckInput<'_>) -> Option<MapMetrics> {
        let identity = Se2::new(0.0, 0.0, 0.0);
        match (input.mode, input.own, input.local_updates) {
            (ReversibleMode::MultiMap, Some(own), _) => {
                map_metrics(own, input.b_in_a, &identity, &self.thresholds).ok()
            }
            (ReversibleMode::SingleMap, _, Some(local)) => {
                let mut restricted = input.merged.clone();
                local.reset_others(&mut restricted);
                map_metrics(&restricted, input.b_in_a, &identity, &self.thresholds).ok()
            }
            _ => None,
        }
    }
}

impl MergeCheck for MetricsCheck {
    fn check(&self, input: &CheckInput<'_>) -> Verdict {
        let Some(m) = self.measure(input) else {
            return Verdict::Consistent {
                metrics: Vec::new(),
            };
        };
        let metrics = vec![
            Metric {
                name: "sm".into(),
                value: m.sm,
            },
            Metric {
                name: "dm_cells".into(),
                value: m.dm_cells,
            },
            Metric {
                name: "overlap_cells".into(),
                value: m.overlap_cells as f64,
            },
        ];
        let max_dm = match input.mode {
            ReversibleMode::MultiMap => self.max_dm_cells_multi_map,
            ReversibleMode::SingleMap => self.max_dm_cells_single_map,
        };
        let reason = if m.overlap_cells < self.min_overlap_cells {
            None
        } else if m.dm_cells > max_dm {
            Some(format!("DM {:.2} > {max_dm:.2} cells", m.dm_cells))
        } else if m.sm < self.min_sm {
            Some(format!("SM {:.3} < {:.3}", m.sm, self.min_sm))
        } else {
            None
        };
        match reason {
            Some(reason) => Verdict::Inconsistent { reason, metrics },
            None => Verdict::Consistent { metrics },
        }
    }
}
