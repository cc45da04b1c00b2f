//! How much of each epoch could have been merged at all: the travel along its true path that
//! passes near a place an earlier epoch visited (the chance place recognition had).

use std::collections::HashMap;

use nalgebra::Vector2;

/// For every epoch (its true positions in one world frame, in order), the travel (m) along
/// its path within `radius_m` of a position of any earlier epoch: a step counts when it ends
/// there. The first epoch has nothing before it (0). Positions that are not finite are
/// skipped; a `radius_m` that is not positive gives 0 everywhere.
pub fn revisit_travel_m(epochs: &[Vec<Vector2<f64>>], radius_m: f64) -> Vec<f64> {
    let mut out = Vec::with_capacity(epochs.len());
    if radius_m.is_nan() || radius_m <= 0.0 {
        out.resize(epochs.len(), 0.0);
        return out;
    }
    // Earlier epochs' positions, hashed in cells of the radius: a neighbour lies in the 3×3
    // cells around a point's.
    let cell = |p: &Vector2<f64>| {
        (
            (p.x / radius_m).floor() as i64,
            (p.y / radius_m).floor() as i64,
        )
    };
    let mut earlier: HashMap<(i64, i64), Vec<Vector2<f64>>> = HashMap::new();
    for path in epochs {
        let near_earlier = |p: &Vector2<f64>| {
            let (cx, cy) = cell(p);
            (-1..=1).any(|dx| {
                (-1..=1).any(|dy| {
                    earlier
                        .get(&(cx + dx, cy + dy))
                        .is_some_and(|ps| ps.iter().any(|q| (q - p).norm() <= radius_m))
                })
            })
        };
        let mut travel_m = 0.0;
        let mut last: Option<Vector2<f64>> = None;
        for p in path.iter().filter(|p| p.x.is_finite() && p.y.is_finite()) {
            if let Some(previous) = last {
                if near_earlier(p) {
                    travel_m += (p - previous).norm();
                }
            }
            last = Some(*p);
        }
        out.push(travel_m);
        for p in path.iter().filter(|p| p.x.is_finite() && p.y.is_finite()) {
            earlier.entry(cell(p)).or_default().push(*p);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(x0: f64, x1: f64, y: f64, steps: usize) -> Vec<Vector2<f64>> {
        (0..=steps)
            .map(|k| Vector2::new(x0 + (x1 - x0) * k as f64 / steps as f64, y))
            .collect()
    }

    #[test]
    fn travel_near_an_earlier_path_counts_and_elsewhere_does_not() {
        // Epoch 0 walks x 0..10 at y 0; epoch 1 walks x 5..15 at y 1 (its first 5 m are
        // within 1.5 m of epoch 0); epoch 2 walks far away.
        let epochs = vec![
            line(0.0, 10.0, 0.0, 100),
            line(5.0, 15.0, 1.0, 100),
            line(0.0, 10.0, 50.0, 100),
        ];
        let revisits = revisit_travel_m(&epochs, 1.5);
        assert_eq!(revisits[0], 0.0);
        // Steps ending at x in (5, 10] plus the one ending where epoch 0's end is within
        // reach (x ≤ 10 + √(1.5² − 1)).
        let reach = 10.0 + (1.5f64.powi(2) - 1.0).sqrt();
        assert!((revisits[1] - (reach - 5.0)).abs() < 0.11, "{revisits:?}");
        assert_eq!(revisits[2], 0.0);
        // Epoch 2 retraced by a fourth: all of it counts.
        let mut four = epochs.clone();
        four.push(line(10.0, 0.0, 50.0, 100));
        assert!((revisit_travel_m(&four, 1.5)[3] - 10.0).abs() < 1e-9);
    }

    #[test]
    fn a_radius_that_is_not_positive_or_a_non_finite_point_gives_no_revisit_and_no_panic() {
        let epochs = vec![
            line(0.0, 1.0, 0.0, 10),
            vec![Vector2::new(f64::NAN, 0.0), Vector2::new(0.5, 0.0)],
        ];
        assert_eq!(revisit_travel_m(&epochs, 0.0), vec![0.0, 0.0]);
        assert_eq!(revisit_travel_m(&epochs, f64::NAN), vec![0.0, 0.0]);
        assert_eq!(revisit_travel_m(&epochs, 1.0), vec![0.0, 0.0]);
        assert!(revisit_travel_m(&[], 1.0).is_empty());
    }
}
