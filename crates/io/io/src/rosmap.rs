//! ROS `map_server` maps: a YAML descriptor (`image`, `resolution`, `origin`, `negate`,
//! `occupied_thresh`, `free_thresh`, optional `mode`) next to a PGM image, and their conversion
//! to and from [`OccupancyGrid`] with map_server's semantics (ROS 1 `map_server` /
//! ROS 2 `nav2_map_server`). See `docs/formats.md`.

use std::path::{Path, PathBuf};

use mapmerge_grid::{
    log_odds_of, probability_of, CellClass, ClassThresholds, GridGeometry, OccupancyGrid, Point2,
};
use serde_yaml_ng::{Mapping, Value};

use crate::document::{check_document, read_document};
use crate::input::read_bytes;
use crate::pgm::{format_pgm, parse_pgm};
use crate::reader::{parse_error, quoted};
use crate::writer::{save, save_bytes, write_f64};
use crate::IoError;

/// Occupancy probability given to cells the image marks occupied (OctoMap's upper clamp, the
/// grid's `SensorModel` default): `log_odds_of(0.97)` ≈ 3.48.
pub const OCCUPIED_PROBABILITY: f64 = 0.97;

/// Occupancy probability given to cells the image marks free (OctoMap's lower clamp):
/// `log_odds_of(0.12)` ≈ −1.99.
pub const FREE_PROBABILITY: f64 = 0.12;

/// map_saver's grey levels and thresholds (ROS 1 `map_saver`, trinary).
const OCCUPIED_PIXEL: u8 = 0;
const FREE_PIXEL: u8 = 254;
const UNKNOWN_PIXEL: u8 = 205;
/// `mode: raw` has no unknown grey; nav2's map_saver writes unknown (−1) as 255.
const RAW_UNKNOWN_PIXEL: u8 = 255;
const SAVER_OCCUPIED_THRESH: f64 = 0.65;
const SAVER_FREE_THRESH: f64 = 0.196;

/// How image values become occupancy (`mode` in the YAML).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum MapMode {
    /// Occupied / free / unknown by the thresholds (the default).
    #[default]
    Trinary,
    /// Occupied / free by the thresholds, values in between keep their probability.
    Scale,
    /// The value is the occupancy in percent (0–100); larger values are unknown.
    Raw,
}

impl MapMode {
    /// The YAML spelling: `trinary`, `scale`, `raw`.
    pub fn name(self) -> &'static str {
        match self {
            MapMode::Trinary => "trinary",
            MapMode::Scale => "scale",
            MapMode::Raw => "raw",
        }
    }
}

/// A `map_server` map: the YAML fields and the image.
#[derive(Clone, Debug, PartialEq)]
pub struct RosMap {
    /// The image file as written in the YAML (relative to the YAML's folder unless absolute).
    /// Empty in maps made by [`RosMap::from_grid`]: [`write_ros_map`] then names it after the
    /// YAML file.
    pub image: PathBuf,
    /// Side of one pixel (m).
    pub resolution_m: f64,
    /// x of the lower-left pixel's outer corner in the map frame (m).
    pub origin_x_m: f64,
    /// y of the lower-left pixel's outer corner (m).
    pub origin_y_m: f64,
    /// Yaw of the map (rad). Kept, but not applied by [`RosMap::to_grid`] (nor by most ROS
    /// tools, which ignore it).
    pub origin_yaw_rad: f64,
    /// When true, white is occupied and black free.
    pub negate: bool,
    /// Pixels whose occupancy probability is above this are occupied.
    pub occupied_thresh: f64,
    /// Pixels whose occupancy probability is below this are free.
    pub free_thresh: f64,
    /// How values become occupancy.
    pub mode: MapMode,
    /// Image width (pixels).
    pub width: usize,
    /// Image height (pixels).
    pub height: usize,
    /// `width · height` 8-bit values, row by row, the TOP row first (as in the file).
    pub pixels: Vec<u8>,
}

impl RosMap {
    /// The occupancy grid of this map, with map_server's semantics: a pixel value `v` (after
    /// `negate`) has occupancy `p = (255 − v) / 255`; `p > occupied_thresh` is occupied
    /// (log-odds `log_odds_of(0.97)`), `p < free_thresh` free (`log_odds_of(0.12)`), anything
    /// else unknown (log-odds 0) in [`MapMode::Trinary`] and probability `p` (clamped to
    /// [0.12, 0.97]) in [`MapMode::Scale`], where the value 205 (map_saver's unknown grey)
    /// is unknown. In [`MapMode::Raw`] `v` is the occupancy in percent:
    /// `v ≤ 100` has probability `v / 100` (clamped likewise), larger values are unknown;
    /// `negate` does not apply (as in nav2).
    ///
    /// The image's top row becomes the grid's top row (grid row 0 is the bottom); the grid's
    /// origin is `(origin_x_m, origin_y_m)`; `origin_yaw_rad` is not applied. Fails with
    /// [`IoError::Invalid`] when the pixels do not fill `width × height`, or the grid would be
    /// invalid (resolution, size).
    pub fn to_grid(&self) -> Result<OccupancyGrid, IoError> {
        let invalid = |reason: String| IoError::Invalid {
            file: self.image.display().to_string(),
            reason,
        };
        if self.width.checked_mul(self.height) != Some(self.pixels.len()) {
            return Err(invalid(format!(
                "{} pixels for a {} x {} map",
                self.pixels.len(),
                self.width,
                self.height
            )));
        }
        let table: Vec<f32> = (0..=255u8).map(|v| self.pixel_log_odds(v)).collect();
        let mut log_odds = Vec::with_capacity(self.pixels.len());
        for row in self.pixels.chunks_exact(self.width.max(1)).rev() {
            log_odds.extend(
                row.iter()
                    .map(|&v| table.get(usize::from(v)).copied().unwrap_or(0.0)),
            );
        }
        let geometry = GridGeometry {
            resolution_m: self.resolution_m,
            origin_m: Point2::new(self.origin_x_m, self.origin_y_m),
            width: self.width,
            height: self.height,
        };
        OccupancyGrid::from_log_odds(geometry, log_odds).map_err(|e| invalid(e.to_string()))
    }

    /// The log-odds of one pixel value (see [`RosMap::to_grid`]).
    fn pixel_log_odds(&self, v: u8) -> f32 {
        let clamped = |p: f64| log_odds_of(p.clamp(FREE_PROBABILITY, OCCUPIED_PROBABILITY));
        if self.mode == MapMode::Raw {
            return if v <= 100 {
                clamped(f64::from(v) / 100.0)
            } else {
                0.0
            };
        }
        if self.mode == MapMode::Scale && v == UNKNOWN_PIXEL {
            // map_saver's unknown grey: PGM has no alpha channel for nav2's transparent
            // unknown, and 205 would otherwise read as p = 0.196, almost free.
            return 0.0;
        }
        let v = if self.negate { 255 - v } else { v };
        let p = f64::from(255 - v) / 255.0;
        if p > self.occupied_thresh {
            log_odds_of(OCCUPIED_PROBABILITY)
        } else if p < self.free_thresh {
            log_odds_of(FREE_PROBABILITY)
        } else if self.mode == MapMode::Trinary {
            0.0
        } else {
            clamped(p)
        }
    }

    /// The map of `grid` as ROS `map_saver` writes it: [`MapMode::Trinary`] classifies each
    /// cell with `thresholds` (occupied 0, free 254, unknown 205); [`MapMode::Scale`] writes
    /// `round(255 · (1 − p))` for every observed cell (log-odds ≠ 0; 204 or 206 where that
    /// gives 205) and 205 for unobserved ones; [`MapMode::Raw`] writes `round(100 · p)` and 255 for unobserved cells. The YAML
    /// fields are map_saver's: `occupied_thresh` 0.65, `free_thresh` 0.196 (so that 205 reads
    /// back unknown), `negate` false, origin the grid's lower-left corner with yaw 0. `image`
    /// is left empty for [`write_ros_map`] to fill in.
    pub fn from_grid(grid: &OccupancyGrid, mode: MapMode, thresholds: &ClassThresholds) -> RosMap {
        let geometry = grid.geometry();
        let pixel = |l: f32| -> u8 {
            let unobserved = l == 0.0 || l.is_nan();
            match mode {
                MapMode::Trinary => match thresholds.classify(l) {
                    CellClass::Occupied => OCCUPIED_PIXEL,
                    CellClass::Free => FREE_PIXEL,
                    CellClass::Unknown => UNKNOWN_PIXEL,
                },
                MapMode::Scale if unobserved => UNKNOWN_PIXEL,
                MapMode::Scale => (255.0 * (1.0 - probability_of(l)))
                    .round()
                    .clamp(0.0, 255.0) as u8,
                MapMode::Raw if unobserved => RAW_UNKNOWN_PIXEL,
                MapMode::Raw => (100.0 * probability_of(l)).round().clamp(0.0, 100.0) as u8,
            }
        };
        let mut pixels = Vec::with_capacity(geometry.len());
        for row in grid.log_odds().chunks_exact(geometry.width.max(1)).rev() {
            pixels.extend(row.iter().map(|&l| pixel(l)));
        }
        RosMap {
            image: PathBuf::new(),
            resolution_m: geometry.resolution_m,
            origin_x_m: geometry.origin_m.x,
            origin_y_m: geometry.origin_m.y,
            origin_yaw_rad: 0.0,
            negate: false,
            occupied_thresh: SAVER_OCCUPIED_THRESH,
            free_thresh: SAVER_FREE_THRESH,
            mode,
            width: geometry.width,
            height: geometry.height,
            pixels,
        }
    }
}

/// Reads a `map_server` map: the YAML at `yaml_path` and its image (relative to the YAML's
/// folder unless absolute; when that file is missing but `<image>.xz` exists, that is read;
/// either may be xz-compressed, recognised by the magic bytes).
pub fn read_ros_map(yaml_path: &Path) -> Result<RosMap, IoError> {
    let file = yaml_path.display().to_string();
    let text = read_document(yaml_path)?;
    let mut map = parse_ros_map_yaml(&text, &file)?;
    let folder = yaml_path.parent().unwrap_or_else(|| Path::new(""));
    let image = folder.join(&map.image);
    let mut compressed = image.clone().into_os_string();
    compressed.push(".xz");
    let compressed = PathBuf::from(compressed);
    let image = if image.is_file() || !compressed.is_file() {
        image
    } else {
        compressed
    };
    if !image.is_file() {
        let reason = format!(
            "image file `{}` does not exist (nor with .xz)",
            image.display()
        );
        return Err(parse_error(&file, key_line(&text, "image"), reason));
    }
    let bytes = read_bytes(&image)?;
    let (width, height, pixels) = parse_pgm(&bytes, &image.display().to_string())?;
    map.width = width;
    map.height = height;
    map.pixels = pixels;
    Ok(map)
}

/// The 1-based line where `key` is defined (a line starting, after indentation or `{`, with
/// the key and a colon), or 1.
fn key_line(text: &str, key: &str) -> usize {
    text.split('\n')
        .position(|line| {
            let line = line.trim_start_matches(|c: char| c.is_whitespace() || c == '{');
            let rest = line
                .strip_prefix(key)
                .or_else(|| line.strip_prefix(&format!("\"{key}\"")))
                .or_else(|| line.strip_prefix(&format!("'{key}'")));
            rest.is_some_and(|r| r.trim_start().starts_with(':'))
        })
        .map_or(1, |index| index + 1)
}

/// A short description of a YAML value for messages.
fn describe(value: &Value) -> String {
    match value {
        Value::Null => "nothing".to_owned(),
        Value::Bool(b) => format!("`{b}`"),
        Value::Number(n) => quoted(&n.to_string()),
        Value::String(s) => quoted(s),
        Value::Sequence(_) => "a list".to_owned(),
        Value::Mapping(_) => "a mapping".to_owned(),
        Value::Tagged(_) => "a tagged value".to_owned(),
    }
}

/// The fields of a YAML descriptor, for error messages with lines.
struct Descriptor<'a> {
    text: &'a str,
    file: &'a str,
    mapping: &'a Mapping,
}

impl Descriptor<'_> {
    /// An error at the line of `key`.
    fn error(&self, key: &str, reason: String) -> IoError {
        parse_error(self.file, key_line(self.text, key), reason)
    }

    /// The value of a required key.
    fn required(&self, key: &str) -> Result<&Value, IoError> {
        self.mapping.get(key).ok_or_else(|| IoError::Invalid {
            file: self.file.to_owned(),
            reason: format!("missing key `{key}`"),
        })
    }

    /// A finite number (a YAML number, or a string holding one).
    fn number_of(&self, key: &str, value: &Value) -> Result<f64, IoError> {
        let number = match value {
            Value::Number(n) => n.as_f64(),
            Value::String(s) => s.trim().parse::<f64>().ok(),
            _ => None,
        };
        number.filter(|v| v.is_finite()).ok_or_else(|| {
            self.error(
                key,
                format!("{key} {} is not a finite number", describe(value)),
            )
        })
    }

    /// A required finite number.
    fn number(&self, key: &str) -> Result<f64, IoError> {
        self.number_of(key, self.required(key)?)
    }

    /// A required threshold in [0, 1].
    fn threshold(&self, key: &str) -> Result<f64, IoError> {
        let v = self.number(key)?;
        if (0.0..=1.0).contains(&v) {
            Ok(v)
        } else {
            Err(self.error(key, format!("{key} {v} is outside [0, 1]")))
        }
    }
}

/// Parses a `map_server` YAML descriptor; `source` names it in errors. The result has no
/// pixels yet (`width = height = 0`); [`read_ros_map`] adds them from the image.
///
/// Required keys: `image`, `resolution` (> 0), `origin` (`[x, y, yaw]`), `negate` (0/1 or a
/// boolean), `occupied_thresh` and `free_thresh` (in [0, 1], free ≤ occupied); optional
/// `mode` (`trinary`, `scale`, `raw`). Other keys are ignored. Numbers may be quoted.
/// YAML syntax errors, bad values and nesting beyond [`crate::MAX_DOCUMENT_DEPTH`] are
/// [`IoError::Parse`] at their line; missing keys, a document that is not a mapping and one
/// beyond [`crate::MAX_DOCUMENT_BYTES`] are [`IoError::Invalid`].
pub fn parse_ros_map_yaml(text: &str, source: &str) -> Result<RosMap, IoError> {
    check_document(text, source)?;
    let document: Value = serde_yaml_ng::from_str(text).map_err(|err| {
        let line = err.location().map_or(1, |l| l.line());
        parse_error(source, line, format!("invalid YAML: {err}"))
    })?;
    let Some(mapping) = document.as_mapping() else {
        return Err(IoError::Invalid {
            file: source.to_owned(),
            reason: format!(
                "a map_server YAML must be a mapping of keys to values, found {}",
                describe(&document)
            ),
        });
    };
    let d = Descriptor {
        text,
        file: source,
        mapping,
    };
    let image = match d.required("image")? {
        Value::String(s) if !s.is_empty() => PathBuf::from(s),
        other => {
            let reason = format!("image {} is not a file name", describe(other));
            return Err(d.error("image", reason));
        }
    };
    let resolution_m = d.number("resolution")?;
    if resolution_m <= 0.0 {
        let reason = format!("resolution {resolution_m} must be a positive number of metres");
        return Err(d.error("resolution", reason));
    }
    let origin = d.required("origin")?;
    let [origin_x_m, origin_y_m, origin_yaw_rad] = match origin.as_sequence() {
        Some(items) if items.len() == 3 => {
            let mut out = [0.0; 3];
            for (slot, item) in out.iter_mut().zip(items) {
                *slot = d.number_of("origin", item)?;
            }
            out
        }
        _ => {
            let reason = format!(
                "origin must be a list of 3 numbers [x, y, yaw], found {}",
                match origin.as_sequence() {
                    Some(items) => format!("a list of {}", items.len()),
                    None => describe(origin),
                }
            );
            return Err(d.error("origin", reason));
        }
    };
    let negate = match d.required("negate")? {
        Value::Bool(b) => *b,
        Value::Number(n) if n.as_u64() == Some(0) => false,
        Value::Number(n) if n.as_u64() == Some(1) => true,
        other => {
            let reason = format!("negate {} must be 0 or 1", describe(other));
            return Err(d.error("negate", reason));
        }
    };
    let occupied_thresh = d.threshold("occupied_thresh")?;
    let free_thresh = d.threshold("free_thresh")?;
    if free_thresh > occupied_thresh {
        let reason =
            format!("free_thresh {free_thresh} is above occupied_thresh {occupied_thresh}");
        return Err(d.error("free_thresh", reason));
    }
    let mode = match mapping.get("mode") {
        None => MapMode::Trinary,
        Some(Value::String(s)) if s == "trinary" => MapMode::Trinary,
        Some(Value::String(s)) if s == "scale" => MapMode::Scale,
        Some(Value::String(s)) if s == "raw" => MapMode::Raw,
        Some(other) => {
            let reason = format!("mode {} must be trinary, scale or raw", describe(other));
            return Err(d.error("mode", reason));
        }
    };
    Ok(RosMap {
        image,
        resolution_m,
        origin_x_m,
        origin_y_m,
        origin_yaw_rad,
        negate,
        occupied_thresh,
        free_thresh,
        mode,
        width: 0,
        height: 0,
        pixels: Vec::new(),
    })
}

/// The YAML descriptor of `map` (its `image` as is; see [`write_ros_map`] for the default
/// name). Numbers are written with full `f64` precision, so the text parses back to the same
/// fields. An empty or non-UTF-8 image name, a non-finite number, a resolution ≤ 0 or
/// thresholds outside [0, 1] (or free above occupied) are [`IoError::Unwritable`].
pub fn format_ros_map_yaml(map: &RosMap) -> Result<String, IoError> {
    let unwritable = |reason: String| IoError::Unwritable {
        format: "map_server YAML",
        reason,
    };
    let image = map
        .image
        .to_str()
        .filter(|s| !s.is_empty())
        .ok_or_else(|| unwritable(format!("image name {:?} is empty or not UTF-8", map.image)))?;
    let numbers = [
        map.resolution_m,
        map.origin_x_m,
        map.origin_y_m,
        map.origin_yaw_rad,
        map.occupied_thresh,
        map.free_thresh,
    ];
    if numbers.iter().any(|v| !v.is_finite()) {
        return Err(unwritable("a number is not finite".to_owned()));
    }
    if map.resolution_m <= 0.0 {
        return Err(unwritable(format!(
            "resolution {} is not positive",
            map.resolution_m
        )));
    }
    let unit = 0.0..=1.0;
    if !unit.contains(&map.free_thresh)
        || !unit.contains(&map.occupied_thresh)
        || map.free_thresh > map.occupied_thresh
    {
        return Err(unwritable(format!(
            "thresholds free {} / occupied {} are not in [0, 1] in that order",
            map.free_thresh, map.occupied_thresh
        )));
    }
    // serde_yaml_ng quotes names that would read back as something else (`1`, `yes`, …).
    let image =
        serde_yaml_ng::to_string(image).map_err(|e| unwritable(format!("image name: {e}")))?;
    let mut out = String::with_capacity(160);
    out.push_str("image: ");
    out.push_str(image.trim_end());
    out.push_str("\nresolution: ");
    write_f64(&mut out, map.resolution_m);
    out.push_str("\norigin: [");
    write_f64(&mut out, map.origin_x_m);
    out.push_str(", ");
    write_f64(&mut out, map.origin_y_m);
    out.push_str(", ");
    write_f64(&mut out, map.origin_yaw_rad);
    out.push_str("]\nnegate: ");
    out.push_str(if map.negate { "1" } else { "0" });
    out.push_str("\noccupied_thresh: ");
    write_f64(&mut out, map.occupied_thresh);
    out.push_str("\nfree_thresh: ");
    write_f64(&mut out, map.free_thresh);
    out.push_str("\nmode: ");
    out.push_str(map.mode.name());
    out.push('\n');
    Ok(out)
}

/// Writes `map` as a YAML descriptor at `yaml_path` and a binary PGM (maxval 255) next to it:
/// at `image` (relative to the YAML's folder unless absolute), or, when `image` is empty, at
/// the YAML's file stem + `.pgm` (`maps/floor.yaml` → `maps/floor.pgm`, `image: floor.pgm`).
/// Either file is xz-compressed when its name ends in `.xz`. Missing folders are created.
pub fn write_ros_map(yaml_path: &Path, map: &RosMap) -> Result<(), IoError> {
    write_ros_map_with(yaml_path, map, false)
}

/// [`write_ros_map`], optionally storing the image xz-compressed as `<image>.xz` while the
/// YAML keeps naming `<image>` (as the public data sets do; [`read_ros_map`] falls back to the
/// `.xz` file, ROS tools need `xz -d` first).
pub fn write_ros_map_with(
    yaml_path: &Path,
    map: &RosMap,
    compress_image: bool,
) -> Result<(), IoError> {
    let image = if map.image.as_os_str().is_empty() {
        let stem = yaml_path
            .file_stem()
            .map_or_else(|| "map".into(), |s| s.to_string_lossy());
        PathBuf::from(format!("{stem}.pgm"))
    } else {
        map.image.clone()
    };
    let mut header = map.clone_without_pixels();
    header.image = image.clone();
    let yaml = format_ros_map_yaml(&header)?;
    let pgm = format_pgm(map.width, map.height, &map.pixels)?;
    let folder = yaml_path.parent().unwrap_or_else(|| Path::new(""));
    let mut image_path = folder.join(&image).into_os_string();
    if compress_image {
        image_path.push(".xz");
    }
    save_bytes(Path::new(&image_path), &pgm)?;
    save(yaml_path, &yaml)
}

impl RosMap {
    /// A copy of the YAML fields with no pixels (cheap for large maps).
    fn clone_without_pixels(&self) -> RosMap {
        RosMap {
            image: self.image.clone(),
            resolution_m: self.resolution_m,
            origin_x_m: self.origin_x_m,
            origin_y_m: self.origin_y_m,
            origin_yaw_rad: self.origin_yaw_rad,
            negate: self.negate,
            occupied_thresh: self.occupied_thresh,
            free_thresh: self.free_thresh,
            mode: self.mode,
            width: self.width,
            height: self.height,
            pixels: Vec::new(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const YAML: &str = "image: m.pgm\nresolution: 0.05\norigin: [-1.5, 2, 0.1]\nnegate: 0\n\
                        occupied_thresh: 0.65\nfree_thresh: 0.196\n";

    fn map_of(pixels: Vec<u8>, width: usize, mode: MapMode) -> RosMap {
        let mut map = parse_ros_map_yaml(YAML, "m.yaml").unwrap_or_else(|e| panic!("{e}"));
        map.width = width;
        map.height = pixels.len() / width;
        map.pixels = pixels;
        map.mode = mode;
        map
    }

    #[test]
    fn trinary_scale_raw_and_row_order() {
        // Top row: occupied, free; bottom row: unknown, mid grey.
        let map = map_of(vec![0, 254, 205, 128], 2, MapMode::Trinary);
        let grid = map.to_grid().unwrap_or_else(|e| panic!("{e}"));
        let occupied = log_odds_of(OCCUPIED_PROBABILITY);
        let free = log_odds_of(FREE_PROBABILITY);
        // Grid row 0 is the image's bottom row.
        assert_eq!(grid.log_odds(), &[0.0, 0.0, occupied, free]);
        assert_eq!(grid.geometry().origin_m, Point2::new(-1.5, 2.0));
        let scale = map_of(vec![0, 254, 205, 128], 2, MapMode::Scale);
        let grid = scale.to_grid().unwrap_or_else(|e| panic!("{e}"));
        let mid = log_odds_of(127.0 / 255.0);
        // 205 is map_saver's unknown grey, also in scale mode.
        assert_eq!(grid.log_odds(), &[0.0, mid, occupied, free]);
        let raw = map_of(vec![0, 100, 50, 101], 2, MapMode::Raw);
        let grid = raw.to_grid().unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(grid.log_odds(), &[0.0, 0.0, free, occupied]);
        let mut negated = map_of(vec![0, 255], 2, MapMode::Trinary);
        negated.negate = true;
        let grid = negated.to_grid().unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(grid.log_odds(), &[free, occupied]);
    }

    #[test]
    fn from_grid_writes_map_saver_values_and_reads_back() {
        let occupied = log_odds_of(OCCUPIED_PROBABILITY);
        let free = log_odds_of(FREE_PROBABILITY);
        let geometry = GridGeometry {
            resolution_m: 0.1,
            origin_m: Point2::new(1.0, -2.0),
            width: 3,
            height: 2,
        };
        let values = vec![occupied, free, 0.0, 0.3, -0.3, log_odds_of(0.7)];
        let grid = OccupancyGrid::from_log_odds(geometry, values).unwrap_or_else(|e| panic!("{e}"));
        let thresholds = ClassThresholds::default();
        let trinary = RosMap::from_grid(&grid, MapMode::Trinary, &thresholds);
        assert_eq!(trinary.pixels, [205, 205, 0, 0, 254, 205]);
        let back = trinary.to_grid().unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(back.classes(&thresholds), grid.classes(&thresholds));
        let scale = RosMap::from_grid(&grid, MapMode::Scale, &thresholds);
        assert_eq!(scale.pixels[3..], [8, 224, 205]);
        let back = scale.to_grid().unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(back.classes(&thresholds), grid.classes(&thresholds));
        let raw = RosMap::from_grid(&grid, MapMode::Raw, &thresholds);
        assert_eq!(raw.pixels, [57, 43, 70, 97, 12, 255]);
    }

    #[test]
    fn key_lines() {
        let text = "# c\nimage: a\n  resolution : 1\n{origin: [1]}\n\"negate\": 0\n";
        assert_eq!(key_line(text, "image"), 2);
        assert_eq!(key_line(text, "resolution"), 3);
        assert_eq!(key_line(text, "origin"), 4);
        assert_eq!(key_line(text, "negate"), 5);
        assert_eq!(key_line(text, "mode"), 1);
    }

    /// Issue 67: a descriptor nesting flow lists deeply is refused before the YAML parser
    /// sees it (which once took 37 s on one), at its line.
    #[test]
    fn a_deeply_nested_descriptor_is_refused_at_its_line() {
        let text = format!("{YAML}extra: {}\n", "[".repeat(200_000));
        let error = parse_ros_map_yaml(&text, "m.yaml").map(|_| ()).unwrap_err();
        assert!(error.to_string().contains("nested deeper than"), "{error}");
    }
}
