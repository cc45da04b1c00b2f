//! YAML and JSON documents read from users' files (map_server descriptors, bag metadata,
//! configs, hybrid maps): capped in size and nesting before a parser sees them. YAML parsers
//! take time exponential in the depth of nested flow collections (serde-yaml-ng issue 16),
//! so a few hundred kilobytes of `[[[[…` could stall a command for hours.

use std::io::Read as _;
use std::path::Path;

use crate::reader::parse_error;
use crate::IoError;

/// Largest YAML or JSON document read (bytes).
pub const MAX_DOCUMENT_BYTES: usize = 16 << 20;

/// Deepest nesting of flow collections (`[…]`, `{…}`) in a YAML or JSON document.
pub const MAX_DOCUMENT_DEPTH: usize = 64;

/// The text of the document at `path` (plain or xz-compressed, by its magic bytes): refused
/// when it or its decompressed text is larger than [`MAX_DOCUMENT_BYTES`] (without reading
/// more than that), not UTF-8, or nested deeper than [`MAX_DOCUMENT_DEPTH`]
/// ([`check_document`]).
pub fn read_document(path: &Path) -> Result<String, IoError> {
    let file = path.display().to_string();
    let io_error = |source| IoError::Io {
        file: file.clone(),
        source,
    };
    let cap = MAX_DOCUMENT_BYTES as u64 + 1;
    let mut raw = Vec::new();
    std::fs::File::open(path)
        .and_then(|f| f.take(cap).read_to_end(&mut raw))
        .map_err(io_error)?;
    let bytes = if raw.starts_with(crate::input::XZ_MAGIC) && raw.len() <= MAX_DOCUMENT_BYTES {
        let mut decoded = Vec::new();
        xz2::read::XzDecoder::new_multi_decoder(raw.as_slice())
            .take(cap)
            .read_to_end(&mut decoded)
            .map_err(io_error)?;
        decoded
    } else {
        raw
    };
    if bytes.len() > MAX_DOCUMENT_BYTES {
        return Err(too_large(&file));
    }
    let text = crate::input::text_from_bytes(bytes, &file)?;
    check_document(&text, &file)?;
    Ok(text)
}

/// `Ok` when `text` (a YAML or JSON document named `file`) is at most
/// [`MAX_DOCUMENT_BYTES`] long and nests flow collections at most [`MAX_DOCUMENT_DEPTH`]
/// deep; brackets inside quoted strings and `#` comments do not count. Otherwise an error at
/// the line where the limit is passed.
pub fn check_document(text: &str, file: &str) -> Result<(), IoError> {
    if text.len() > MAX_DOCUMENT_BYTES {
        return Err(too_large(file));
    }
    let (mut depth, mut line) = (0usize, 1usize);
    let mut previous = b'\n';
    let mut bytes = text.bytes();
    while let Some(b) = bytes.next() {
        match b {
            b'\n' => line += 1,
            b'[' | b'{' => {
                depth += 1;
                if depth > MAX_DOCUMENT_DEPTH {
                    return Err(parse_error(
                        file,
                        line,
                        format!("nested deeper than {MAX_DOCUMENT_DEPTH} levels"),
                    ));
                }
            }
            b']' | b'}' => depth = depth.saturating_sub(1),
            // A quoted string starts after a separator (in YAML an apostrophe inside a plain
            // scalar is just a character); it ends at its closing quote (`\"` escaped in a
            // double-quoted one, `''` in a single-quoted one reopens it at once).
            b'"' | b'\'' if is_separator(previous) => {
                let mut escaped = false;
                for c in bytes.by_ref() {
                    if c == b'\n' {
                        line += 1;
                    }
                    if escaped {
                        escaped = false;
                    } else if c == b'\\' && b == b'"' {
                        escaped = true;
                    } else if c == b {
                        break;
                    }
                }
                previous = b;
                continue;
            }
            b'#' if is_separator(previous) => {
                for c in bytes.by_ref() {
                    if c == b'\n' {
                        line += 1;
                        break;
                    }
                }
                previous = b'\n';
                continue;
            }
            _ => {}
        }
        previous = b;
    }
    Ok(())
}

fn is_separator(b: u8) -> bool {
    b.is_ascii_whitespace() || matches!(b, b'[' | b'{' | b',' | b':')
}

fn too_large(file: &str) -> IoError {
    IoError::Invalid {
        file: file.to_owned(),
        reason: format!(
            "larger than {} MiB, the most a YAML or JSON document may be",
            MAX_DOCUMENT_BYTES >> 20
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deep_flow_collections_are_refused_at_their_line_and_strings_do_not_count() {
        let ok = format!(
            "a: {}1{}\n",
            "[".repeat(MAX_DOCUMENT_DEPTH),
            "]".repeat(MAX_DOCUMENT_DEPTH)
        );
        check_document(&ok, "m.yaml").unwrap();
        let deep = format!("a: 1\nb: {}", "[".repeat(MAX_DOCUMENT_DEPTH + 1));
        let error = check_document(&deep, "m.yaml").unwrap_err().to_string();
        assert!(
            error.starts_with("m.yaml:2: nested deeper than 64"),
            "{error}"
        );
        for quiet in [
            format!("a: \"{}\"\n", "[".repeat(500)),
            format!("a: '{}'\n", "{".repeat(500)),
            format!("# {}\nb: 1\n", "[".repeat(500)),
            format!("{{\"a\": \"\\\"{}\"}}", "[".repeat(500)),
        ] {
            check_document(&quiet, "m.yaml").unwrap();
        }
        // An apostrophe inside a plain scalar opens no string.
        let plain = format!("a: it's {}", "[".repeat(MAX_DOCUMENT_DEPTH + 1));
        assert!(check_document(&plain, "m.yaml").is_err());
    }

    #[test]
    fn a_document_larger_than_the_cap_is_refused_without_reading_it_all() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("big.yaml");
        std::fs::write(&path, vec![b' '; MAX_DOCUMENT_BYTES + 10]).unwrap();
        let error = read_document(&path).unwrap_err().to_string();
        assert!(error.contains("larger than 16 MiB"), "{error}");
    }
}
