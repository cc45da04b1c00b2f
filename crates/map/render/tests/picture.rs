//! Pictures: orientation, overlays in the right place, PNG round trip.

#![allow(clippy::unwrap_used)]

use mapmerge_geometry::Se2;
use mapmerge_grid::{Cell, ClassThresholds, GridGeometry, OccupancyGrid};
use mapmerge_posegraph::{Edge, EdgeKind, NodeId, PoseGraph2, SessionId, Vertex};
use mapmerge_render::{session_color, GraphStyle, Picture, PictureStyle, Rgb};
use nalgebra::{Matrix3, Vector2};

fn grid() -> OccupancyGrid {
    let geometry = GridGeometry {
        resolution_m: 0.5,
        origin_m: Vector2::new(-1.0, -1.0),
        width: 8,
        height: 4,
    };
    let mut g = OccupancyGrid::with_geometry(geometry).unwrap();
    g.set(Cell::new(0, 3), 3.0).unwrap(); // top-left: occupied
    g.set(Cell::new(7, 0), -3.0).unwrap(); // bottom-right: free
    g
}

#[test]
fn north_is_up_and_classes_have_their_colours() {
    let style = PictureStyle {
        pixels_per_cell: 2,
        classes: Some(ClassThresholds::default()),
    };
    let picture = Picture::of_grid(&grid(), &style);
    assert_eq!(picture.size_px(), (16, 8));
    assert_eq!(picture.pixel(0, 0), Some(Rgb::BLACK));
    assert_eq!(picture.pixel(1, 1), Some(Rgb::BLACK));
    assert_eq!(picture.pixel(15, 7), Some(Rgb::WHITE));
    assert_eq!(picture.pixel(8, 4), Some(Rgb::UNKNOWN_GREY));
    assert_eq!(picture.pixel(16, 0), None);
}

#[test]
fn overlays_land_on_their_world_positions_and_merges_are_on_top() {
    let mut graph = PoseGraph2::new();
    for (k, (x, y)) in [(-0.75, -0.75), (2.75, -0.75), (2.75, 0.75)]
        .iter()
        .enumerate()
    {
        let mut v = Vertex::new(Se2::new(*x, *y, 0.0));
        v.meta.session = SessionId(if k < 2 { 0 } else { 1 });
        graph.add_vertex(NodeId(k as u64), v).unwrap();
    }
    let info = Matrix3::identity();
    graph
        .add_edge(Edge {
            from: NodeId(0),
            to: NodeId(1),
            measurement: Se2::new(3.5, 0.0, 0.0),
            information: info,
            kind: EdgeKind::Odometry,
        })
        .unwrap();
    graph
        .add_edge(Edge {
            from: NodeId(1),
            to: NodeId(2),
            measurement: Se2::new(0.0, 1.5, 0.0),
            information: info,
            kind: EdgeKind::Merge,
        })
        .unwrap();
    let mut picture = Picture::of_grid(
        &grid(),
        &PictureStyle {
            pixels_per_cell: 4,
            classes: None,
        },
    );
    picture.draw_graph(
        &graph,
        &GraphStyle {
            vertex_radius_px: 0.0,
            ..GraphStyle::default()
        },
    );
    // 0.125 m per pixel, 32 × 16 pixels; world (-0.75, -0.75) is 2 px right of the left edge
    // and 2 px above the bottom.
    let p = picture.to_pixel(&Vector2::new(-0.75, -0.75));
    assert_eq!((p.x, p.y), (2.0, 14.0));
    assert_eq!(picture.pixel(10, 14), Some(session_color(0)));
    // The merge edge at x = 2.75 (pixel column 30) is drawn over the odometry edge's end.
    assert_eq!(picture.pixel(30, 8), Some(Rgb::MAGENTA));
    assert_eq!(picture.pixel(30, 14), Some(Rgb::MAGENTA));
}

#[test]
fn png_decodes_to_the_same_pixels() {
    let picture = Picture::of_grid(&grid(), &PictureStyle::default());
    let bytes = picture.to_png().unwrap();
    let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    let mut reader = decoder.read_info().unwrap();
    let mut buffer = vec![0; reader.output_buffer_size().unwrap()];
    let frame = reader.next_frame(&mut buffer).unwrap();
    assert_eq!((frame.width, frame.height), (8, 4));
    assert_eq!(&buffer[..frame.buffer_size()], picture.rgb_bytes());
}
