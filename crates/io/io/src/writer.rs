//! Shared writing helpers: number formatting that round-trips, and saving (optionally xz).

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;

use crate::IoError;

/// xz preset used for `.xz` output (xz's default).
const XZ_PRESET: u32 = 6;

/// Appends `v` in the shortest form that parses back to the same `f64` (ryu; exponent form
/// for tiny or huge magnitudes), without a trailing `.0` on whole numbers.
pub(crate) fn write_f64(out: &mut String, v: f64) {
    write_shortest(out, v, v.is_finite());
}

/// Appends `v` in the shortest form that parses back (as `f32`) to the same `f32`, without a
/// trailing `.0` (laser ranges: `81.91`, not `81.91000366210938`).
pub(crate) fn write_f32(out: &mut String, v: f32) {
    write_shortest(out, v, v.is_finite());
}

/// The shared body of [`write_f64`] and [`write_f32`].
fn write_shortest<F: ryu::Float + std::fmt::Display>(out: &mut String, v: F, finite: bool) {
    if !finite {
        // Never reached: writers reject non-finite numbers first.
        let _ = write!(out, "{v}");
        return;
    }
    let mut buffer = ryu::Buffer::new();
    let text = buffer.format_finite(v);
    out.push_str(text.strip_suffix(".0").unwrap_or(text));
}

/// Appends `' '` and `v` (see [`write_f32`]).
pub(crate) fn push_f32(out: &mut String, v: f32) {
    out.push(' ');
    write_f32(out, v);
}

/// Appends `' '` and `v` (see [`write_f64`]).
pub(crate) fn push_f64(out: &mut String, v: f64) {
    out.push(' ');
    write_f64(out, v);
}

/// Appends `' '` and an id.
pub(crate) fn push_id(out: &mut String, id: u64) {
    let _ = write!(out, " {id}");
}

/// Appends every value with [`push_f64`].
pub(crate) fn push_fields(out: &mut String, values: impl IntoIterator<Item = f64>) {
    for v in values {
        push_f64(out, v);
    }
}

/// Writes `text` to `path` (creating missing folders), xz-compressed when the path ends in `.xz`.
pub(crate) fn save(path: &Path, text: &str) -> Result<(), IoError> {
    save_bytes(path, text.as_bytes())
}

/// Writes `bytes` to `path` (creating missing folders), xz-compressed when the path ends in
/// `.xz`.
pub(crate) fn save_bytes(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    let io_error = |source| IoError::Io {
        file: path.display().to_string(),
        source,
    };
    // A missing output folder is created, as users of `-o some/dir/out.g2o` expect.
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(io_error)?;
    }
    let file = std::fs::File::create(path).map_err(io_error)?;
    let buffered = std::io::BufWriter::new(file);
    let compressed = path.extension().is_some_and(|ext| ext == "xz");
    let mut buffered = if compressed {
        let mut encoder = xz2::write::XzEncoder::new(buffered, XZ_PRESET);
        encoder.write_all(bytes).map_err(io_error)?;
        encoder.finish().map_err(io_error)?
    } else {
        let mut buffered = buffered;
        buffered.write_all(bytes).map_err(io_error)?;
        buffered
    };
    buffered.flush().map_err(io_error)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_round_trip_and_stay_short() {
        for v in [
            0.0,
            -0.0,
            1.0,
            -2.5,
            0.1 + 0.2,
            1e-5,
            9.99e-6,
            1e16,
            123456789.123,
            f64::MIN_POSITIVE,
            f64::MAX,
            -f64::MAX,
            5e-324,
        ] {
            let mut s = String::new();
            push_f64(&mut s, v);
            let back: f64 = s.trim().parse().unwrap_or(f64::NAN);
            assert_eq!(back.to_bits(), v.to_bits(), "{v} -> {s}");
            assert!(s.len() < 30, "{s}");
        }
    }

    #[test]
    fn f32_numbers_round_trip_and_stay_short() {
        for v in [
            0.0f32,
            -0.0,
            81.91,
            32.767,
            0.1,
            1e-7,
            3.4e38,
            f32::MIN_POSITIVE,
            1e-45,
        ] {
            let mut s = String::new();
            push_f32(&mut s, v);
            let back: f32 = s.trim().parse().unwrap_or(f32::NAN);
            assert_eq!(back.to_bits(), v.to_bits(), "{v} -> {s}");
            assert!(s.len() < 16, "{s}");
        }
        let mut s = String::new();
        write_f32(&mut s, 81.91);
        assert_eq!(s, "81.91");
    }
}
