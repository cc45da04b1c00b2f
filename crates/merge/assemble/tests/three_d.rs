//! The 3D path end to end: a synthetic town of box buildings and poles along streets, driven
//! by 3D segments that share stretches of street (one in the opposite direction), plus one in
//! an unrelated street; and the KITTI-style folder loader on a tiny folder.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeMap;
use std::path::PathBuf;

use mapmerge_assemble::{
    load_kitti_folder, project_pose, solve_group, AssembleParams, Assembler, GroundSlice,
    GroupGraphParams, KittiFolderOptions, Point3, RingSpectrum3Params, RingSpectrumDescriptor3,
    RingSpectrumParams, Segment, Segment3, SubmapParams,
};
use mapmerge_geometry::{wrap_angle_rad, LieGroup, Se2, Se3};
use nalgebra::{UnitQuaternion, Vector2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Sensor height above the (flat) ground (m), as KITTI's Velodyne.
const SENSOR_HEIGHT_M: f64 = 1.73;
/// Range of the simulated lidar and radius of the submaps (m).
const RANGE_M: f64 = 30.0;
/// Travel between clouds (m).
const CLOUD_STEP_M: f64 = 1.5;
/// Side of the cells of the world's point index (m).
const CELL_M: f64 = 10.0;
/// Half-width of the road kept free of buildings (m).
const ROAD_HALF_WIDTH_M: f64 = 7.0;

/// A street: a polyline the vehicles follow.
struct Street {
    corners: Vec<Vector2<f64>>,
}

impl Street {
    fn length_m(&self) -> f64 {
        self.corners.windows(2).map(|w| (w[1] - w[0]).norm()).sum()
    }

    /// Position and heading at arc length `s_m`.
    fn at(&self, s_m: f64) -> (Vector2<f64>, f64) {
        let mut rest = s_m;
        for w in self.corners.windows(2) {
            let leg = w[1] - w[0];
            let length = leg.norm();
            if rest <= length {
                return (w[0] + leg * (rest / length), leg.y.atan2(leg.x));
            }
            rest -= length;
        }
        let n = self.corners.len();
        let leg = self.corners[n - 1] - self.corners[n - 2];
        (self.corners[n - 1], leg.y.atan2(leg.x))
    }

    /// Distance of `p` from the polyline (m).
    fn distance_m(&self, p: &Vector2<f64>) -> f64 {
        self.corners
            .windows(2)
            .map(|w| {
                let leg = w[1] - w[0];
                let t = ((p - w[0]).dot(&leg) / leg.norm_squared()).clamp(0.0, 1.0);
                (p - (w[0] + leg * t)).norm()
            })
            .fold(f64::INFINITY, f64::min)
    }
}

/// World points (ground at `z = 0`) binned in `CELL_M` cells for range queries.
struct World {
    cells: BTreeMap<(i64, i64), Vec<Point3>>,
}

impl World {
    fn cell(p: &Point3) -> (i64, i64) {
        ((p.x / CELL_M).floor() as i64, (p.y / CELL_M).floor() as i64)
    }

    fn add(&mut self, p: Point3) {
        self.cells.entry(Self::cell(&p)).or_default().push(p);
    }

    /// Buildings (vertical faces sampled every 0.5 m), poles and road surface along `street`.
    fn build(streets: &[Street], rng: &mut ChaCha8Rng) -> Self {
        let mut world = World {
            cells: BTreeMap::new(),
        };
        for street in streets {
            for w in street.corners.windows(2) {
                let leg = w[1] - w[0];
                let length = leg.norm();
                let along = leg / length;
                let left = Vector2::new(-along.y, along.x);
                for side in [-1.0, 1.0] {
                    // Buildings: random widths, gaps, setbacks, depths and heights.
                    let mut s = -10.0;
                    while s < length + 10.0 {
                        let width = rng.random_range(6.0..18.0);
                        let depth = rng.random_range(6.0..12.0);
                        let setback = rng.random_range(8.0..11.0);
                        let height = rng.random_range(4.0..12.0);
                        let corner = w[0] + along * s + left * (side * setback);
                        let footprint = [
                            corner,
                            corner + along * width,
                            corner + along * width + left * (side * depth),
                            corner + left * (side * depth),
                        ];
                        let on_a_road = streets.iter().any(|other| {
                            (0..=10).any(|i| {
                                (0..=10).any(|j| {
                                    let p = corner
                                        + along * (width * i as f64 / 10.0)
                                        + left * (side * depth * j as f64 / 10.0);
                                    other.distance_m(&p) < ROAD_HALF_WIDTH_M
                                })
                            })
                        });
                        if !on_a_road {
                            for k in 0..4 {
                                world.add_face(footprint[k], footprint[(k + 1) % 4], height);
                            }
                        }
                        s += width + rng.random_range(0.0..8.0);
                    }
                    // Poles and trees on the sidewalk.
                    let mut s = rng.random_range(0.0..10.0);
                    while s < length {
                        let base = w[0] + along * s + left * (side * rng.random_range(5.5..6.5));
                        let height = rng.random_range(3.0..7.0);
                        world.add_pole(base, height);
                        s += rng.random_range(6.0..20.0);
                    }
                }
                // Road surface every metre.
                let mut s = 0.0;
                while s < length {
                    for lateral in -7..=7 {
                        let p = w[0] + along * s + left * lateral as f64;
                        world.add(Point3::new(p.x, p.y, 0.0));
                    }
                    s += 1.0;
                }
            }
        }
        world
    }

    fn add_face(&mut self, a: Vector2<f64>, b: Vector2<f64>, height_m: f64) {
        let steps = ((b - a).norm() / 0.5).ceil() as usize;
        for i in 0..=steps {
            let p = a + (b - a) * (i as f64 / steps as f64);
            let mut z = 0.0;
            while z <= height_m {
                self.add(Point3::new(p.x, p.y, z));
                z += 0.5;
            }
        }
    }

    fn add_pole(&mut self, base: Vector2<f64>, height_m: f64) {
        for k in 0..8 {
            let angle = k as f64 * std::f64::consts::FRAC_PI_4;
            let p = base + Vector2::new(angle.cos(), angle.sin()) * 0.3;
            let mut z = 0.0;
            while z <= height_m {
                self.add(Point3::new(p.x, p.y, z));
                z += 0.25;
            }
        }
    }

    /// A cloud in the robot frame of `world_from_robot`: world points within `RANGE_M`
    /// (no occlusion), each kept with probability 0.6, with 2 cm noise.
    fn cloud(&self, world_from_robot: &Se3, rng: &mut ChaCha8Rng) -> Vec<Point3> {
        let centre = world_from_robot.translation_m;
        let robot_from_world = world_from_robot.inverse();
        let reach = (RANGE_M / CELL_M).ceil() as i64;
        let (cx, cy) = World::cell(&centre);
        let mut cloud = Vec::new();
        for i in cx - reach..=cx + reach {
            for j in cy - reach..=cy + reach {
                let Some(points) = self.cells.get(&(i, j)) else {
                    continue;
                };
                for p in points {
                    let d = p - centre;
                    if d.x * d.x + d.y * d.y >= RANGE_M * RANGE_M || !rng.random_bool(0.6) {
                        continue;
                    }
                    let noise = Vector3::new(
                        rng.random_range(-0.02..0.02),
                        rng.random_range(-0.02..0.02),
                        rng.random_range(-0.02..0.02),
                    );
                    cloud.push(robot_from_world.transform_point(p) + noise);
                }
            }
        }
        cloud
    }
}

/// A segment driving `street` from arc length `from_m` to `to_m` (reversed when
/// `to_m < from_m`), with small roll, pitch and heading wobble; and its true
/// `world_from_robot` poses.
fn drive(
    name: &str,
    world: &World,
    street: &Street,
    (from_m, to_m): (f64, f64),
    rng: &mut ChaCha8Rng,
) -> (Segment3, Vec<Se3>) {
    let count = ((to_m - from_m).abs() / CLOUD_STEP_M) as usize + 1;
    let direction = (to_m - from_m).signum();
    let mut poses = Vec::with_capacity(count);
    let mut clouds = Vec::with_capacity(count);
    for k in 0..count {
        let s = from_m + direction * CLOUD_STEP_M * k as f64;
        let (p, heading) = street.at(s);
        let heading = if direction < 0.0 {
            heading + std::f64::consts::PI
        } else {
            heading
        };
        let lateral = rng.random_range(-1.0..1.0);
        let left = Vector2::new(-heading.sin(), heading.cos());
        let p = p + left * lateral;
        let rotation = UnitQuaternion::from_euler_angles(
            rng.random_range(-0.015..0.015),
            rng.random_range(-0.015..0.015),
            heading + rng.random_range(-0.05..0.05),
        );
        let pose = Se3::new(rotation, Vector3::new(p.x, p.y, SENSOR_HEIGHT_M));
        clouds.push(world.cloud(&pose, rng));
        poses.push(pose);
    }
    (Segment3::new(name, poses.clone(), clouds).unwrap(), poses)
}

fn params() -> AssembleParams {
    AssembleParams {
        submaps: SubmapParams {
            spacing_m: 5.0,
            radius_m: RANGE_M,
            window_m: 10.0,
            voxel_m: 0.5,
            ..SubmapParams::default()
        },
        // The 2D descriptor only seeds the verifier's yaw here, on the planar slices.
        descriptor: RingSpectrumParams {
            max_radius_m: RANGE_M,
            ..RingSpectrumParams::default()
        },
        ..AssembleParams::default()
    }
}

fn descriptor3() -> RingSpectrumDescriptor3 {
    RingSpectrumDescriptor3::new(&RingSpectrum3Params {
        max_radius_m: RANGE_M,
        sensor_height_m: SENSOR_HEIGHT_M,
        ..RingSpectrum3Params::default()
    })
}

/// `a_from_b` of two true poses, projected to the plane.
fn planar_between(a: &Se3, b: &Se3) -> Se2 {
    project_pose(a).between(&project_pose(b))
}

fn error(estimate: &Se2, truth: &Se2) -> (f64, f64) {
    (
        (estimate.translation() - truth.translation()).norm(),
        wrap_angle_rad(estimate.theta_rad - truth.theta_rad)
            .abs()
            .to_degrees(),
    )
}

#[test]
fn segments_sharing_a_street_are_assembled_and_an_unrelated_one_is_not() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    // An L-shaped street (160 m east, then 120 m north) and an unrelated one 1 km away.
    let streets = [
        Street {
            corners: vec![
                Vector2::new(0.0, 0.0),
                Vector2::new(160.0, 0.0),
                Vector2::new(160.0, 120.0),
            ],
        },
        Street {
            corners: vec![Vector2::new(0.0, 1000.0), Vector2::new(150.0, 1030.0)],
        },
    ];
    let world = World::build(&streets, &mut rng);
    let [main, other] = &streets;
    assert!(main.length_m() > 270.0);
    let (alpha, alpha_truth) = drive("alpha", &world, main, (0.0, 170.0), &mut rng);
    let (bravo, bravo_truth) = drive("bravo", &world, main, (100.0, 275.0), &mut rng);
    // Reversed: overlaps alpha (60…170 m) and bravo (100…240 m) in the opposite direction.
    let (charlie, charlie_truth) = drive("charlie", &world, main, (240.0, 60.0), &mut rng);
    let (delta, _) = drive("delta", &world, other, (0.0, 150.0), &mut rng);
    let truth: BTreeMap<&str, &Vec<Se3>> = [
        ("alpha", &alpha_truth),
        ("bravo", &bravo_truth),
        ("charlie", &charlie_truth),
    ]
    .into_iter()
    .collect();

    let descriptor3 = descriptor3();
    let slice = GroundSlice::default();
    let none = BTreeMap::new();
    let mut assembler = Assembler::new(params()).unwrap();
    // Arrival order: the unrelated street in the middle.
    for segment in [&charlie, &delta, &alpha, &bravo] {
        assembler
            .add_segment_3d(segment, &descriptor3, &slice, &none)
            .unwrap();
    }
    let groups = assembler.groups().unwrap();
    for pair in assembler.pairs().values() {
        eprintln!(
            "{} × {}: seq {} single {} zone {} tried {} verified {} loops {} ω {:.3}",
            pair.a,
            pair.b,
            pair.sequence_matches,
            pair.single_frame_matches,
            pair.zone_inliers,
            pair.verifications,
            pair.verified,
            pair.loops.len(),
            pair.weight
        );
    }
    assert_eq!(
        groups,
        vec![
            vec!["alpha".to_owned(), "bravo".to_owned(), "charlie".to_owned()],
            vec!["delta".to_owned()],
        ]
    );
    // Every overlapping pair is associated, the reversed ones included; delta with none.
    for (a, b) in [
        ("alpha", "bravo"),
        ("alpha", "charlie"),
        ("bravo", "charlie"),
    ] {
        let pair = &assembler.pairs()[&(a.to_owned(), b.to_owned())];
        assert!(
            pair.weight > 0.0 && pair.loops.len() >= 2,
            "{a} × {b}: {pair:?}"
        );
    }
    for pair in assembler.pairs().values() {
        if pair.a == "delta" || pair.b == "delta" {
            assert_eq!(pair.weight, 0.0, "{} × {}", pair.a, pair.b);
            assert!(pair.loops.is_empty());
        }
    }
    // Every loop edge agrees with the truth.
    let (mut worst_m, mut worst_deg, mut loops) = (0.0f64, 0.0f64, 0);
    for l in assembler.loops() {
        let expected = planar_between(
            &truth[l.from_segment.as_str()][l.from_scan],
            &truth[l.to_segment.as_str()][l.to_scan],
        );
        let (m, deg) = error(&l.from_from_to, &expected);
        worst_m = worst_m.max(m);
        worst_deg = worst_deg.max(deg);
        loops += 1;
    }
    eprintln!("{loops} loop edges, worst error {worst_m:.3} m, {worst_deg:.2}°");
    assert!(
        worst_m < 0.5 && worst_deg < 10.0,
        "{worst_m} m, {worst_deg}°"
    );
    // The group's graph puts every scan where it belongs (group frame = alpha's first).
    let solution = solve_group(&assembler, &groups[0], &GroupGraphParams::default()).unwrap();
    let group_from_world = project_pose(&alpha_truth[0]).inverse();
    let (mut worst_m, mut worst_deg) = (0.0f64, 0.0f64);
    for (name, poses) in &solution.scan_poses {
        assert_eq!(poses.len(), truth[name.as_str()].len());
        for (estimate, true_pose) in poses.iter().zip(truth[name.as_str()].iter()) {
            let expected = group_from_world.compose(&project_pose(true_pose));
            let (m, deg) = error(estimate, &expected);
            worst_m = worst_m.max(m);
            worst_deg = worst_deg.max(deg);
        }
    }
    eprintln!("group scan poses: worst error {worst_m:.3} m, {worst_deg:.2}°");
    assert!(
        worst_m < 0.5 && worst_deg < 5.0,
        "{worst_m} m, {worst_deg}°"
    );
    // 2D segments, a duplicate or another band cannot join a 3D assembly.
    let planar = assembler.segment("alpha").unwrap().0.clone();
    let renamed = Segment {
        name: "echo".into(),
        ..planar
    };
    assert!(assembler.add_segment(renamed).is_err());
    assert!(assembler
        .add_segment_3d(&alpha, &descriptor3, &slice, &none)
        .is_err());
    let mut other_band = delta.clone();
    other_band.name = "foxtrot".into();
    let narrow = GroundSlice {
        max_height_m: 1.0,
        ..GroundSlice::default()
    };
    let err = assembler
        .add_segment_3d(&other_band, &descriptor3, &narrow, &none)
        .unwrap_err();
    assert!(err.to_string().contains("foxtrot"), "{err}");
    assert_eq!(assembler.names().count(), 4);
}

#[test]
fn planar_segment_carries_projected_poses_and_virtual_scans() {
    // Two clouds 2 m apart, the second turned by 0.5 rad and tilted; a wall 5 m ahead.
    let tilt = UnitQuaternion::from_euler_angles(0.02, -0.02, 0.5);
    let poses = vec![
        Se3::new(UnitQuaternion::identity(), Vector3::new(10.0, 5.0, 1.73)),
        Se3::new(tilt, Vector3::new(12.0, 5.0, 1.73)),
    ];
    let wall: Vec<Point3> = (-20..=20)
        .flat_map(|i| (-3..=4).map(move |j| Point3::new(5.0, i as f64 * 0.25, j as f64 * 0.5)))
        .collect();
    let segment = Segment3::new("tiny", poses, vec![wall.clone(), wall]).unwrap();
    let submap_params = SubmapParams {
        spacing_m: 1.0,
        radius_m: 20.0,
        window_m: 0.5,
        voxel_m: 0.2,
        ..SubmapParams::default()
    };
    let (prepared, planar) = mapmerge_assemble::prepare_3d(
        &segment,
        &submap_params,
        &descriptor3(),
        &GroundSlice::default(),
    )
    .unwrap();
    assert_eq!(prepared.submaps.len(), 2);
    assert_eq!(prepared.descriptors.rows(), 2);
    assert_eq!(planar.poses[0], Se2::identity());
    let second = planar.poses[1];
    assert!((second.x_m - 2.0).abs() < 1e-9 && second.y_m.abs() < 1e-9);
    assert!((second.theta_rad - 0.5).abs() < 2e-3, "{second:?}");
    assert_eq!(prepared.submaps[1].segment_from_centre, second);
    // Only band heights (−1.2…1.5 m) survive: the wall's planar points lie on x = 5.
    let points = &prepared.submaps[0].points_in_centre;
    assert!(!points.is_empty());
    assert!(
        points.iter().all(|p| (p.x - 5.0).abs() < 0.06),
        "{points:?}"
    );
    // The virtual scan sees the wall straight ahead at 5 m.
    let scan = &planar.scans[0];
    let ahead = scan
        .beams()
        .filter(|(angle, _)| angle.abs() < 1e-3)
        .map(|(_, r)| r)
        .next()
        .unwrap();
    assert!((ahead - 5.0).abs() < 0.01, "{ahead}");
    // A bad band is refused.
    let bad = GroundSlice {
        min_height_m: f64::NAN,
        ..GroundSlice::default()
    };
    assert!(mapmerge_assemble::prepare_3d(&segment, &submap_params, &descriptor3(), &bad).is_err());
}

fn write_cloud(path: &std::path::Path, points: &[[f32; 3]]) {
    let mut bytes = Vec::new();
    for p in points {
        for v in [p[0], p[1], p[2], 0.5] {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    std::fs::write(path, bytes).unwrap();
}

#[test]
fn kitti_folder_loads_as_a_segment() {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("three_d_kitti/drive_0042");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(dir.join("velodyne")).unwrap();
    // Written out of order: the loader sorts by name.
    write_cloud(&dir.join("velodyne/000001.bin"), &[[2.0, 0.0, 0.0]]);
    write_cloud(
        &dir.join("velodyne/000000.bin"),
        &[[1.0, 0.0, 0.0], [0.0, 100.0, 0.0]],
    );
    std::fs::write(dir.join("velodyne/notes.txt"), "not a cloud").unwrap();
    // Velodyne poses: the second 3 m along x of the first and turned by 90° about z.
    std::fs::write(
        dir.join("poses.txt"),
        "1 0 0 5 0 1 0 6 0 0 1 7\n0 -1 0 8 1 0 0 6 0 0 1 7\n",
    )
    .unwrap();
    let segment = load_kitti_folder(&dir, &KittiFolderOptions::default()).unwrap();
    assert_eq!(segment.name, "drive_0042");
    assert_eq!(segment.len(), 2);
    // Far points (100 m) are dropped by the default 80 m range.
    assert_eq!(segment.clouds[0], vec![Point3::new(1.0, 0.0, 0.0)]);
    assert_eq!(segment.clouds[1], vec![Point3::new(2.0, 0.0, 0.0)]);
    assert!(segment.poses[0].log().norm() < 1e-12);
    let planar = project_pose(&segment.poses[1]);
    assert!((planar.x_m - 3.0).abs() < 1e-9 && planar.y_m.abs() < 1e-9);
    assert!((planar.theta_rad - std::f64::consts::FRAC_PI_2).abs() < 1e-9);

    // KITTI camera poses with the calibration: camera x right, y down, z forward.
    std::fs::write(
        dir.join("calib.txt"),
        "P0: 1 0 0 0 0 1 0 0 0 0 1 0\nTr: 0 -1 0 0 0 0 -1 0 1 0 0 0\n",
    )
    .unwrap();
    // The camera moves 3 m forward (its z) between the frames.
    std::fs::write(
        dir.join("poses.txt"),
        "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1 3\n",
    )
    .unwrap();
    let segment = load_kitti_folder(&dir, &KittiFolderOptions::default()).unwrap();
    let planar = project_pose(&segment.poses[1]);
    assert!(
        (planar.x_m - 3.0).abs() < 1e-9 && planar.y_m.abs() < 1e-9 && planar.theta_rad.abs() < 1e-9,
        "forward in the camera is forward (x) for the Velodyne: {planar:?}"
    );
    std::fs::remove_file(dir.join("calib.txt")).unwrap();

    // One pose too many: the error names both.
    std::fs::write(
        dir.join("poses.txt"),
        "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 1 0 1 0 0 0 0 1 0\n1 0 0 2 0 1 0 0 0 0 1 0\n",
    )
    .unwrap();
    let err = load_kitti_folder(&dir, &KittiFolderOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("poses.txt") && err.contains("2 clouds") && err.contains("3 poses"),
        "{err}"
    );
    // A broken cloud is named.
    std::fs::write(dir.join("velodyne/000001.bin"), [0u8; 7]).unwrap();
    std::fs::write(
        dir.join("poses.txt"),
        "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 1 0 1 0 0 0 0 1 0\n",
    )
    .unwrap();
    let err = load_kitti_folder(&dir, &KittiFolderOptions::default())
        .unwrap_err()
        .to_string();
    assert!(err.contains("000001.bin"), "{err}");
    // A missing folder is an error, not a panic.
    assert!(load_kitti_folder(&dir.join("nowhere"), &KittiFolderOptions::default()).is_err());
    let _ = std::fs::remove_dir_all(&dir);
}
