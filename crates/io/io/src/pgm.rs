//! PGM images (Netpbm "portable graymap", the image format of ROS `map_server` maps): binary
//! `P5` and plain (ASCII) `P2`, any maxval from 1 to 65535, `#` comments in the header.
//! Samples are scaled to 8 bits (`v · 255 / maxval`, rounded); rows are kept in file order,
//! top row first. Written: `P5`, maxval 255.

use crate::reader::{parse_error, quoted};
use crate::IoError;

/// Largest maxval of the format (16-bit samples).
const MAX_MAXVAL: u32 = 65535;

/// An image as `(width, height, pixels)`: `width · height` 8-bit samples, row by row, the top
/// row first.
pub type PgmImage = (usize, usize, Vec<u8>);

/// A cursor over the header: tokens separated by whitespace, `#` comments to the end of the
/// line, and the line number for messages.
struct Header<'a> {
    bytes: &'a [u8],
    at: usize,
    line: usize,
}

impl<'a> Header<'a> {
    /// Skips whitespace and comments.
    fn skip_blank(&mut self) {
        while let Some(&b) = self.bytes.get(self.at) {
            if b == b'#' {
                while let Some(&c) = self.bytes.get(self.at) {
                    if c == b'\n' || c == b'\r' {
                        break;
                    }
                    self.at += 1;
                }
            } else if b.is_ascii_whitespace() || b == 0x0b {
                if b == b'\n' {
                    self.line += 1;
                }
                self.at += 1;
            } else {
                break;
            }
        }
    }

    /// The next token and its line; at the end of the data an empty token and the line where
    /// the data ended (not counting trailing blank lines).
    fn token(&mut self) -> (&'a [u8], usize) {
        let before = self.line;
        self.skip_blank();
        if self.at >= self.bytes.len() {
            return (&[], before);
        }
        let start = self.at;
        while let Some(&b) = self.bytes.get(self.at) {
            if b.is_ascii_whitespace() || b == 0x0b || b == b'#' {
                break;
            }
            self.at += 1;
        }
        (
            self.bytes.get(start..self.at).unwrap_or_default(),
            self.line,
        )
    }

    /// A header number (`what`: "width", "height", "maxval").
    fn number(&mut self, file: &str, what: &str) -> Result<usize, IoError> {
        let (token, line) = self.token();
        let text = String::from_utf8_lossy(token);
        if token.is_empty() {
            return Err(parse_error(
                file,
                line,
                format!("PGM header ends before the {what}"),
            ));
        }
        text.parse::<usize>().map_err(|_| {
            let reason = format!("PGM {what} {} is not a non-negative integer", quoted(&text));
            parse_error(file, line, reason)
        })
    }
}

/// Parses a PGM image (`P5` or `P2`); `source` names it in errors. Header problems are
/// [`IoError::Parse`] errors at their line; pixel data shorter than the header says (or a
/// sample above maxval) is [`IoError::Invalid`]. Bytes after the first image are ignored
/// (Netpbm allows several images in one file).
pub fn parse_pgm(bytes: &[u8], source: &str) -> Result<PgmImage, IoError> {
    let mut header = Header {
        bytes,
        at: 0,
        line: 1,
    };
    let plain = match bytes.get(..2) {
        Some(b"P5") => false,
        Some(b"P2") => true,
        _ => {
            let magic = String::from_utf8_lossy(bytes.get(..2).unwrap_or(bytes));
            let reason = format!(
                "not a PGM file: starts with {} instead of P5 or P2",
                quoted(&magic)
            );
            return Err(parse_error(source, 1, reason));
        }
    };
    header.at = 2;
    if let Some(&b) = bytes.get(2) {
        if !(b.is_ascii_whitespace() || b == b'#') {
            let reason = "not a PGM file: no whitespace after the magic number".to_owned();
            return Err(parse_error(source, 1, reason));
        }
    }
    let width = header.number(source, "width")?;
    let height = header.number(source, "height")?;
    let maxval_line = {
        header.skip_blank();
        header.line
    };
    let maxval = header.number(source, "maxval")?;
    let maxval = u32::try_from(maxval)
        .ok()
        .filter(|m| (1..=MAX_MAXVAL).contains(m))
        .ok_or_else(|| {
            parse_error(
                source,
                maxval_line,
                format!("PGM maxval {maxval} is outside 1..=65535"),
            )
        })?;
    let count = width.checked_mul(height).ok_or_else(|| IoError::Invalid {
        file: source.to_owned(),
        reason: format!("PGM size {width} x {height} is too large"),
    })?;
    let scale = Scale::new(maxval);
    let pixels = if plain {
        plain_samples(&mut header, source, count, width, height, &scale)?
    } else {
        // Exactly one whitespace byte separates maxval from the raster.
        let start = header.at.saturating_add(1);
        raw_samples(
            bytes.get(start..).unwrap_or_default(),
            source,
            count,
            width,
            height,
            &scale,
        )?
    };
    Ok((width, height, pixels))
}

/// Conversion of samples to 8 bits.
struct Scale {
    maxval: u32,
}

impl Scale {
    fn new(maxval: u32) -> Self {
        Self { maxval }
    }

    /// `v · 255 / maxval`, rounded to nearest; `None` above maxval.
    fn to_u8(&self, v: u32) -> Option<u8> {
        if v > self.maxval {
            return None;
        }
        if self.maxval == 255 {
            return u8::try_from(v).ok();
        }
        let scaled = (u64::from(v) * 255 + u64::from(self.maxval) / 2) / u64::from(self.maxval);
        u8::try_from(scaled).ok()
    }
}

/// The samples of a `P5` raster (1 byte per sample for maxval < 256, else 2, big-endian).
fn raw_samples(
    raster: &[u8],
    file: &str,
    count: usize,
    width: usize,
    height: usize,
    scale: &Scale,
) -> Result<Vec<u8>, IoError> {
    let per_sample = if scale.maxval < 256 { 1 } else { 2 };
    let needed = count.saturating_mul(per_sample);
    let Some(raster) = raster.get(..needed) else {
        return Err(IoError::Invalid {
            file: file.to_owned(),
            reason: format!(
                "PGM pixel data holds {} bytes, expected {needed} ({width} x {height}, \
                 {per_sample} byte(s) per pixel)",
                raster.len()
            ),
        });
    };
    let too_big = |index: usize, v: u32| IoError::Invalid {
        file: file.to_owned(),
        reason: format!(
            "PGM pixel {index} has value {v}, above maxval {}",
            scale.maxval
        ),
    };
    if per_sample == 1 {
        if scale.maxval == 255 {
            return Ok(raster.to_vec());
        }
        raster
            .iter()
            .enumerate()
            .map(|(i, &v)| {
                scale
                    .to_u8(u32::from(v))
                    .ok_or_else(|| too_big(i, u32::from(v)))
            })
            .collect()
    } else {
        raster
            .chunks_exact(2)
            .enumerate()
            .map(|(i, pair)| {
                let v = match pair {
                    [hi, lo] => u32::from(*hi) << 8 | u32::from(*lo),
                    _ => 0,
                };
                scale.to_u8(v).ok_or_else(|| too_big(i, v))
            })
            .collect()
    }
}

/// The samples of a `P2` raster: decimal numbers separated by whitespace (comments allowed).
fn plain_samples(
    header: &mut Header<'_>,
    file: &str,
    count: usize,
    width: usize,
    height: usize,
    scale: &Scale,
) -> Result<Vec<u8>, IoError> {
    // Every sample takes at least two bytes, so this never reserves more than the input.
    let remaining = header.bytes.len().saturating_sub(header.at);
    let mut pixels = Vec::with_capacity(count.min(remaining / 2 + 1));
    loop {
        let (token, line) = header.token();
        if token.is_empty() {
            break;
        }
        let text = String::from_utf8_lossy(token);
        if pixels.len() == count {
            let reason = format!("PGM has more than {width} x {height} samples");
            return Err(parse_error(file, line, reason));
        }
        let value = text.parse::<u32>().ok().and_then(|v| scale.to_u8(v));
        let Some(value) = value else {
            let reason = format!(
                "PGM sample {} is not an integer in 0..={}",
                quoted(&text),
                scale.maxval
            );
            return Err(parse_error(file, line, reason));
        };
        pixels.push(value);
    }
    if pixels.len() < count {
        return Err(IoError::Invalid {
            file: file.to_owned(),
            reason: format!(
                "PGM holds {} samples, expected {count} ({width} x {height})",
                pixels.len()
            ),
        });
    }
    Ok(pixels)
}

/// A binary `P5` PGM with maxval 255 of `pixels` (row by row, top row first). Fails with
/// [`IoError::Unwritable`] when `pixels` does not hold `width · height` samples.
pub fn format_pgm(width: usize, height: usize, pixels: &[u8]) -> Result<Vec<u8>, IoError> {
    if width.checked_mul(height) != Some(pixels.len()) {
        return Err(IoError::Unwritable {
            format: "PGM",
            reason: format!("{} pixels for a {width} x {height} image", pixels.len()),
        });
    }
    let header = format!("P5\n{width} {height}\n255\n");
    let mut out = Vec::with_capacity(header.len() + pixels.len());
    out.extend_from_slice(header.as_bytes());
    out.extend_from_slice(pixels);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(bytes: &[u8]) -> Result<PgmImage, String> {
        parse_pgm(bytes, "t.pgm").map_err(|e| e.to_string())
    }

    #[test]
    fn binary_plain_comments_and_16_bit() {
        let mut p5 = b"P5\n# made by hand\n3 2 # size\n255\n".to_vec();
        p5.extend([0, 128, 255, 205, 254, 1]);
        assert_eq!(parse(&p5), Ok((3, 2, vec![0, 128, 255, 205, 254, 1])));
        let p2 = b"P2 2 2\n#c\n15\n0 15\n# mid\n 8 1\n";
        assert_eq!(parse(p2), Ok((2, 2, vec![0, 255, 136, 17])));
        let mut wide = b"P5 2 1 65535\n".to_vec();
        wide.extend([0xff, 0xff, 0x80, 0x00]);
        assert_eq!(parse(&wide), Ok((2, 1, vec![255, 128])));
        assert_eq!(parse(b"P5\n0 0\n255\n"), Ok((0, 0, vec![])));
        // Trailing bytes (a second image) are ignored.
        assert_eq!(
            parse(b"P5 1 1 255\n\x07P5 1 1 255\n\x08"),
            Ok((1, 1, vec![7]))
        );
    }

    #[test]
    fn written_images_read_back() {
        let pixels = [0, 1, 2, 3, 250, 255];
        let bytes = format_pgm(3, 2, &pixels).unwrap_or_default();
        assert_eq!(parse(&bytes), Ok((3, 2, pixels.to_vec())));
        assert!(format_pgm(2, 2, &pixels).is_err());
    }

    #[test]
    fn errors_name_file_line_and_reason() {
        assert_eq!(
            parse(b"P6\n1 1\n255\n\0\0\0"),
            Err("t.pgm:1: not a PGM file: starts with `P6` instead of P5 or P2".into())
        );
        assert_eq!(
            parse(b"P5\n# c\nx 1\n255\n\0"),
            Err("t.pgm:3: PGM width `x` is not a non-negative integer".into())
        );
        assert_eq!(
            parse(b"P5\n1\n"),
            Err("t.pgm:2: PGM header ends before the height".into())
        );
        assert_eq!(
            parse(b"P5\n1 1\n\n0\n\0"),
            Err("t.pgm:4: PGM maxval 0 is outside 1..=65535".into())
        );
        assert_eq!(
            parse(b"P5 2 2 255\n\0\0\0"),
            Err(
                "t.pgm: PGM pixel data holds 3 bytes, expected 4 (2 x 2, 1 byte(s) per pixel)"
                    .into()
            )
        );
        assert_eq!(
            parse(b"P5 1 1 100\n\xff"),
            Err("t.pgm: PGM pixel 0 has value 255, above maxval 100".into())
        );
        assert_eq!(
            parse(b"P2 2 1 255\n1\n-2\n"),
            Err("t.pgm:3: PGM sample `-2` is not an integer in 0..=255".into())
        );
        assert_eq!(
            parse(b"P2 1 1 255\n1\n2\n"),
            Err("t.pgm:3: PGM has more than 1 x 1 samples".into())
        );
        assert_eq!(
            parse(b"P2 2 2 255\n1 2 3"),
            Err("t.pgm: PGM holds 3 samples, expected 4 (2 x 2)".into())
        );
        assert_eq!(
            parse(b"P5 99999999999 99999999999 255\n"),
            Err("t.pgm: PGM size 99999999999 x 99999999999 is too large".into())
        );
        // A huge declared size with little data is rejected without allocating it.
        assert!(parse(b"P2 100000 100000 255\n1 2 3").is_err());
    }
}
