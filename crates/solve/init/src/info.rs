//! What an initialisation did.

use mapmerge_posegraph::NodeId;

/// What an initialisation did (gtsam's `XxxInfo` convention).
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct InitInfo {
    /// Number of vertex poses written. Fixed vertices and anchors keep their pose and are not
    /// counted.
    pub vertices_set: usize,
    /// Connected components (priors ignored); each is initialised from its own anchor.
    pub components: usize,
    /// The anchor of each component, in the order of the components' smallest ids: the
    /// component's lowest-id fixed vertex, else its lowest id. Anchors keep their current pose
    /// (the identity for files without vertices).
    pub anchors: Vec<NodeId>,
    /// Relative (non-prior) edges that entered the estimate: all of them for LAGO and chordal,
    /// the spanning-tree edges for odometry chaining.
    pub edges_used: usize,
    /// LAGO only: edges whose measured heading was shifted by a non-zero multiple of 2π to
    /// agree with the spanning tree (Carlone et al. 2014, orientation regularisation).
    pub angle_corrections: usize,
    /// Wall-clock time spent (s).
    pub seconds: f64,
}
