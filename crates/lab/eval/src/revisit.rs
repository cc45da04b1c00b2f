//! How much of each epoch could have been merged at all: the travel along its true path that
//! passes near a place an earlier epoch visited (the chance place recognition had).

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::Vector2;

/// For every epoch (its true positions in one world frame, in order), the travel (m) along
/// its path within `radius_m` of a position of any earlier epoch: a step counts when it ends
/// there. The first epoch has nothing before it (0). Positions that are not finite are
/// skipped; a `radius_m` that is not positive gives 0 everywhere.
pub fn revisit_travel_m(epochs: &[Vec<Vector2<f64>>], radius_m: f64) -> Vec<f64> {
    if radius_m.is_nan() || radius_m <= 0.0 {
        return vec![0.0; epochs.len()];
    }
    let finite = |p: &&Vector2<f64>| p.x.is_finite() && p.y.is_finite();
    let mut earlier: Vec<[f64; 2]> = Vec::new();
    let mut out = Vec::with_capacity(epochs.len());
    for path in epochs {
        let tree: Option<ImmutableKdTree<f64, 2>> = (!earlier.is_empty())
            .then(|| ImmutableKdTree::new_from_slice(&earlier).ok())
            .flatten();
        let near_earlier = |p: &Vector2<f64>| {
            tree.as_ref().is_some_and(|tree| {
                let nearest = tree
                    .query(&[p.x, p.y])
                    .nearest_one::<SquaredEuclidean<f64>>()
                    .execute();
                nearest.distance <= radius_m * radius_m
            })
        };
        let mut travel_m = 0.0;
        let mut last: Option<&Vector2<f64>> = None;
        for p in path.iter().filter(finite) {
            if last.is_some_and(|_| near_earlier(p)) {
                travel_m += last.map_or(0.0, |q| (p - q).norm());
            }
            last = Some(p);
        }
        out.push(travel_m);
        earlier.extend(path.iter().filter(finite).map(|p| [p.x, p.y]));
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
