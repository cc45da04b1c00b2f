//! An RGB image with a world-to-pixel mapping, made from a grid and saved as PNG.

use std::path::Path;

use mapmerge_grid::{probability_of, CellClass, ClassThresholds, GridGeometry, OccupancyGrid};

use crate::Point2;

/// An 8-bit RGB colour.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rgb(pub [u8; 3]);

impl Rgb {
    /// Pure red.
    pub const RED: Rgb = Rgb([220, 40, 40]);
    /// Black.
    pub const BLACK: Rgb = Rgb([0, 0, 0]);
    /// White.
    pub const WHITE: Rgb = Rgb([255, 255, 255]);
    /// ROS map_saver's unknown grey (205).
    pub const UNKNOWN_GREY: Rgb = Rgb([205, 205, 205]);
    /// Merge edges.
    pub const MAGENTA: Rgb = Rgb([230, 0, 200]);
}

/// Why a picture could not be written.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RenderError {
    /// PNG encoding failed.
    #[error("PNG encoding failed: {0}")]
    Encode(String),
    /// The file could not be written.
    #[error("{file}: cannot write the picture")]
    Io {
        /// The file.
        file: String,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
}

/// How a grid becomes pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PictureStyle {
    /// Pixels per cell side (1 = one pixel per cell).
    pub pixels_per_cell: usize,
    /// `Some`: three colours (free white, occupied black, unknown grey) by these thresholds;
    /// `None`: grey shades by occupancy probability, unknown cells grey.
    pub classes: Option<ClassThresholds>,
}

impl Default for PictureStyle {
    fn default() -> Self {
        Self {
            pixels_per_cell: 1,
            classes: None,
        }
    }
}

/// An RGB image; pixel `(0, 0)` is the top-left corner. `origin_m` is the world position of
/// the image's bottom-left corner and `metres_per_pixel` its scale.
#[derive(Clone, Debug, PartialEq)]
pub struct Picture {
    pub(crate) width_px: usize,
    pub(crate) height_px: usize,
    pub(crate) rgb: Vec<u8>,
    pub(crate) origin_m: Point2,
    pub(crate) metres_per_pixel: f64,
}

impl Picture {
    /// A blank (white) picture covering `geometry` at `pixels_per_cell`.
    pub fn blank(geometry: &GridGeometry, pixels_per_cell: usize) -> Self {
        let scale = pixels_per_cell.max(1);
        let (width_px, height_px) = (geometry.width * scale, geometry.height * scale);
        Self {
            width_px,
            height_px,
            rgb: vec![255; width_px * height_px * 3],
            origin_m: geometry.origin_m,
            metres_per_pixel: geometry.resolution_m / scale as f64,
        }
    }

    /// The grid, one `pixels_per_cell`-square per cell, north up.
    pub fn of_grid(grid: &OccupancyGrid, style: &PictureStyle) -> Self {
        let geometry = grid.geometry();
        let mut picture = Self::blank(geometry, style.pixels_per_cell);
        let scale = style.pixels_per_cell.max(1);
        for (cell, _, log_odds) in grid.cells() {
            let colour = cell_colour(log_odds, style.classes.as_ref());
            let top = geometry.height - 1 - cell.y as usize;
            for py in top * scale..(top + 1) * scale {
                for px in cell.x as usize * scale..(cell.x as usize + 1) * scale {
                    picture.put(px, py, colour);
                }
            }
        }
        picture
    }

    /// Width and height in pixels.
    pub fn size_px(&self) -> (usize, usize) {
        (self.width_px, self.height_px)
    }

    /// The colour at pixel `(x, y)` (top-left origin).
    pub fn pixel(&self, x: usize, y: usize) -> Option<Rgb> {
        let i = (y * self.width_px + x) * 3;
        (x < self.width_px && y < self.height_px)
            .then(|| self.rgb.get(i..i + 3).map(|c| Rgb([c[0], c[1], c[2]])))
            .flatten()
    }

    /// Raw RGB bytes, row by row from the top.
    pub fn rgb_bytes(&self) -> &[u8] {
        &self.rgb
    }

    /// The (fractional) pixel position of world point `p`.
    pub fn to_pixel(&self, p: &Point2) -> Point2 {
        let local = (p - self.origin_m) / self.metres_per_pixel;
        Point2::new(local.x, self.height_px as f64 - local.y)
    }

    /// Sets one pixel (ignored outside the picture).
    pub(crate) fn put(&mut self, x: usize, y: usize, colour: Rgb) {
        if x < self.width_px && y < self.height_px {
            let i = (y * self.width_px + x) * 3;
            if let Some(slot) = self.rgb.get_mut(i..i + 3) {
                slot.copy_from_slice(&colour.0);
            }
        }
    }

    /// PNG bytes (8-bit RGB).
    pub fn to_png(&self) -> Result<Vec<u8>, RenderError> {
        let mut bytes = Vec::new();
        let encode = |e: png::EncodingError| RenderError::Encode(e.to_string());
        {
            let width = u32::try_from(self.width_px.max(1))
                .map_err(|e| RenderError::Encode(e.to_string()))?;
            let height = u32::try_from(self.height_px.max(1))
                .map_err(|e| RenderError::Encode(e.to_string()))?;
            let mut encoder = png::Encoder::new(&mut bytes, width, height);
            encoder.set_color(png::ColorType::Rgb);
            encoder.set_depth(png::BitDepth::Eight);
            let mut writer = encoder.write_header().map_err(encode)?;
            if self.rgb.is_empty() {
                writer.write_image_data(&[255, 255, 255]).map_err(encode)?;
            } else {
                writer.write_image_data(&self.rgb).map_err(encode)?;
            }
            writer.finish().map_err(encode)?;
        }
        Ok(bytes)
    }

    /// Writes the picture as PNG, creating missing folders.
    pub fn save_png(&self, path: &Path) -> Result<(), RenderError> {
        let io = |source| RenderError::Io {
            file: path.display().to_string(),
            source,
        };
        let bytes = self.to_png()?;
        if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent).map_err(io)?;
        }
        std::fs::write(path, bytes).map_err(io)
    }
}

/// The colour of a cell with `log_odds`.
fn cell_colour(log_odds: f32, classes: Option<&ClassThresholds>) -> Rgb {
    match classes {
        Some(thresholds) => match thresholds.classify(log_odds) {
            CellClass::Free => Rgb::WHITE,
            CellClass::Occupied => Rgb::BLACK,
            CellClass::Unknown => Rgb::UNKNOWN_GREY,
        },
        None if log_odds == 0.0 => Rgb::UNKNOWN_GREY,
        None => {
            let shade = (255.0 * (1.0 - probability_of(log_odds)))
                .round()
                .clamp(0.0, 255.0) as u8;
            Rgb([shade; 3])
        }
    }
}
