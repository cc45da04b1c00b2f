//! Overlays: pose graphs coloured by session with merge edges highlighted, trajectories.

use mapmerge_geometry::Se2;
use mapmerge_posegraph::{EdgeKind, PoseGraph};

use crate::{Picture, Point2, Rgb};

/// Tableau 10: distinct colours for sessions / epochs, cycled.
const SESSION_PALETTE: [Rgb; 10] = [
    Rgb([31, 119, 180]),
    Rgb([255, 127, 14]),
    Rgb([44, 160, 44]),
    Rgb([214, 39, 40]),
    Rgb([148, 103, 189]),
    Rgb([140, 86, 75]),
    Rgb([227, 119, 194]),
    Rgb([127, 127, 127]),
    Rgb([188, 189, 34]),
    Rgb([23, 190, 207]),
];

/// The colour of session (or epoch) number `session`.
pub fn session_color(session: u64) -> Rgb {
    SESSION_PALETTE[(session % SESSION_PALETTE.len() as u64) as usize]
}

/// How a pose graph is drawn.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GraphStyle {
    /// Vertex disc radius (px); 0 hides vertices.
    pub vertex_radius_px: f64,
    /// Odometry edge width (px), in the session's colour.
    pub odometry_width_px: f64,
    /// Loop-closure edge width (px); 0 hides them.
    pub loop_width_px: f64,
    /// Loop-closure colour.
    pub loop_colour: Rgb,
    /// Merge edge width (px); drawn last, on top.
    pub merge_width_px: f64,
    /// Merge edge colour.
    pub merge_colour: Rgb,
}

impl Default for GraphStyle {
    fn default() -> Self {
        Self {
            vertex_radius_px: 1.5,
            odometry_width_px: 1.0,
            loop_width_px: 1.0,
            loop_colour: Rgb([60, 180, 75]),
            merge_width_px: 3.0,
            merge_colour: Rgb::MAGENTA,
        }
    }
}

impl Picture {
    /// Draws a planar pose graph: odometry edges and vertices in their session's colour,
    /// loop closures in `loop_colour`, merge edges thick in `merge_colour` on top.
    pub fn draw_graph(&mut self, graph: &PoseGraph<Se2, 3>, style: &GraphStyle) {
        let position = |id| graph.vertex(id).map(|v| v.pose.translation());
        let mut merges = Vec::new();
        for (_, edge) in graph.edges() {
            let (Some(a), Some(b)) = (position(edge.from), position(edge.to)) else {
                continue;
            };
            match edge.kind {
                EdgeKind::Odometry => {
                    let session = graph.vertex(edge.from).map_or(0, |v| v.meta.session.0);
                    self.draw_line(
                        &a,
                        &b,
                        session_color(u64::from(session)),
                        style.odometry_width_px,
                    );
                }
                EdgeKind::Loop if style.loop_width_px > 0.0 => {
                    self.draw_line(&a, &b, style.loop_colour, style.loop_width_px);
                }
                EdgeKind::Merge => merges.push((a, b)),
                EdgeKind::Loop | EdgeKind::Prior | EdgeKind::Marginal => {}
            }
        }
        if style.vertex_radius_px > 0.0 {
            for (_, vertex) in graph.vertices() {
                let colour = session_color(u64::from(vertex.meta.session.0));
                self.draw_disc(&vertex.pose.translation(), style.vertex_radius_px, colour);
            }
        }
        for (a, b) in merges {
            self.draw_line(&a, &b, style.merge_colour, style.merge_width_px);
        }
    }

    /// Draws a trajectory as a polyline of its positions.
    pub fn draw_trajectory(&mut self, poses: &[Se2], colour: Rgb, width_px: f64) {
        let points: Vec<Point2> = poses.iter().map(Se2::translation).collect();
        self.draw_polyline(&points, colour, width_px);
    }
}
