//! Reading input files: the bytes of a plain or xz-compressed file (recognised by its magic
//! bytes, not its name), and bytes → text. Every reader of this crate goes through here.

use std::io::Read as _;
use std::path::Path;

use crate::reader::parse_error;
use crate::IoError;

/// The magic bytes that start an xz stream.
pub(crate) const XZ_MAGIC: &[u8] = &[0xFD, b'7', b'z', b'X', b'Z', 0x00];

/// Expected xz compression ratio of our inputs (text about 5:1); only sizes the first buffer.
const XZ_RATIO_GUESS: usize = 6;

/// Largest buffer reserved up front for decompressed data; a hostile header cannot reserve more.
const MAX_INITIAL_BUFFER: usize = 1 << 28;

/// The contents of `path`, decompressed in memory when they start with the xz magic bytes.
pub(crate) fn read_bytes(path: &Path) -> Result<Vec<u8>, IoError> {
    let file = path.display().to_string();
    let io_error = |source| IoError::Io {
        file: file.clone(),
        source,
    };
    let raw = std::fs::read(path).map_err(io_error)?;
    if !raw.starts_with(XZ_MAGIC) {
        return Ok(raw);
    }
    let capacity = raw
        .len()
        .saturating_mul(XZ_RATIO_GUESS)
        .min(MAX_INITIAL_BUFFER);
    let mut decoded = Vec::with_capacity(capacity);
    xz2::read::XzDecoder::new_multi_decoder(raw.as_slice())
        .read_to_end(&mut decoded)
        .map_err(io_error)?;
    Ok(decoded)
}

/// `bytes` as UTF-8 text; otherwise an [`IoError::Parse`] at the line of the first bad byte.
pub(crate) fn text_from_bytes(bytes: Vec<u8>, file: &str) -> Result<String, IoError> {
    String::from_utf8(bytes).map_err(|err| {
        let valid = err.as_bytes().get(..err.utf8_error().valid_up_to());
        let line = valid
            .unwrap_or_default()
            .iter()
            .filter(|b| **b == b'\n')
            .count()
            + 1;
        parse_error(file, line, "invalid UTF-8".to_owned())
    })
}

/// The text of `path` (plain or xz, see [`read_bytes`]).
pub(crate) fn read_text(path: &Path) -> Result<String, IoError> {
    text_from_bytes(read_bytes(path)?, &path.display().to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn invalid_utf8_names_its_line() {
        let err = text_from_bytes(b"a\nb\n\xff\n".to_vec(), "x.log").unwrap_err();
        assert_eq!(err.to_string(), "x.log:3: invalid UTF-8");
        let ok = text_from_bytes(b"fine\n".to_vec(), "x.log").unwrap_or_default();
        assert_eq!(ok, "fine\n");
    }
}
