//! Drawing primitives in world coordinates: thick lines and discs.

use crate::{Picture, Point2, Rgb};

impl Picture {
    /// A filled disc of `radius_px` pixels around world point `p`.
    pub fn draw_disc(&mut self, p: &Point2, radius_px: f64, colour: Rgb) {
        let c = self.to_pixel(p);
        if c.x.is_finite() && c.y.is_finite() {
            self.disc_px(&c, radius_px.max(0.5), colour);
        }
    }

    /// A line `width_px` pixels wide between world points `a` and `b`.
    pub fn draw_line(&mut self, a: &Point2, b: &Point2, colour: Rgb, width_px: f64) {
        let (pa, pb) = (self.to_pixel(a), self.to_pixel(b));
        let length = (pb - pa).norm();
        if !length.is_finite() {
            return;
        }
        // Clip absurdly long lines (a pose far off the map) to a sane number of steps.
        let steps = (length * 2.0).ceil().min(1e6) as usize;
        let radius = width_px / 2.0;
        for k in 0..=steps {
            let t = if steps == 0 {
                0.0
            } else {
                k as f64 / steps as f64
            };
            let p = pa + (pb - pa) * t;
            if radius <= 0.75 {
                if p.x >= 0.0 && p.y >= 0.0 {
                    self.put(p.x as usize, p.y as usize, colour);
                }
            } else {
                self.disc_px(&p, radius, colour);
            }
        }
    }

    /// A polyline through world points.
    pub fn draw_polyline(&mut self, points: &[Point2], colour: Rgb, width_px: f64) {
        for pair in points.windows(2) {
            self.draw_line(&pair[0], &pair[1], colour, width_px);
        }
    }

    /// One disc per point, each in its own colour (e.g. a detector's class per scan point).
    pub fn draw_points(&mut self, points: &[(Point2, Rgb)], radius_px: f64) {
        for (p, colour) in points {
            self.draw_disc(p, radius_px, *colour);
        }
    }

    /// A disc given in pixel coordinates.
    fn disc_px(&mut self, c: &Point2, r: f64, colour: Rgb) {
        let (x0, x1) = (
            (c.x - r).floor().max(0.0),
            (c.x + r).ceil().min(self.width_px as f64),
        );
        let (y0, y1) = (
            (c.y - r).floor().max(0.0),
            (c.y + r).ceil().min(self.height_px as f64),
        );
        for y in y0 as usize..y1.max(0.0) as usize {
            for x in x0 as usize..x1.max(0.0) as usize {
                let d = Point2::new(x as f64 + 0.5, y as f64 + 0.5) - c;
                if d.norm_squared() <= r * r {
                    self.put(x, y, colour);
                }
            }
        }
    }
}
