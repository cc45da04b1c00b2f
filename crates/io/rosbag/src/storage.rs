//! The two rosbag2 storage formats, read into one shape: topics with their message types, and
//! the serialized messages of the topics asked for, in log-time order.
//!
//! - MCAP (rosbag2's default since Iron): schemas named `pkg/msg/Type`, channels with
//!   `message_encoding: cdr`; chunks may be zstd- or lz4-compressed (pure-Rust decoders).
//! - SQLite `.db3` (the default before): tables `topics(id, name, type,
//!   serialization_format, …)` and `messages(id, topic_id, timestamp, data)`.
//! - A bag directory: `metadata.yaml` names the storage and the files, read in order.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use mapmerge_io::IoError;

/// How a bag is stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Storage {
    /// MCAP files.
    Mcap,
    /// SQLite 3 files (`.db3`).
    Sqlite3,
}

impl Storage {
    /// The storage of a file, by its extension (`.mcap`, `.db3`).
    pub fn of_file(path: &Path) -> Option<Self> {
        match path.extension()?.to_str()? {
            "mcap" => Some(Self::Mcap),
            "db3" => Some(Self::Sqlite3),
            _ => None,
        }
    }
    /// rosbag2's name of the storage plugin.
    pub fn identifier(self) -> &'static str {
        match self {
            Self::Mcap => "mcap",
            Self::Sqlite3 => "sqlite3",
        }
    }
}

/// One topic of a bag.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Topic {
    /// Its name (`/scan`).
    pub name: String,
    /// Its message type, normalised to `pkg/msg/Type`.
    pub message_type: String,
    /// How its messages are serialised (`cdr`).
    pub encoding: String,
    /// How many messages it has.
    pub messages: usize,
}

/// One serialized message.
#[derive(Clone, Debug)]
pub(crate) struct RawMessage {
    /// Index into [`RawBag::topics`].
    pub topic: usize,
    /// When it was recorded (ns).
    pub log_time_ns: i64,
    /// Encapsulated CDR.
    pub data: Vec<u8>,
}

/// A bag's topics, and the messages of the topics whose type was asked for.
#[derive(Debug, Default)]
pub(crate) struct RawBag {
    pub storage: Option<Storage>,
    pub topics: Vec<Topic>,
    pub messages: Vec<RawMessage>,
    /// Bytes read from disk.
    pub bytes: u64,
}

impl RawBag {
    /// The index of `name` among the topics, adding it when new.
    fn topic_index(&mut self, name: &str, message_type: &str, encoding: &str) -> usize {
        let message_type = normalise_type(message_type);
        if let Some(index) = self
            .topics
            .iter()
            .position(|t| t.name == name && t.message_type == message_type)
        {
            return index;
        }
        self.topics.push(Topic {
            name: name.to_owned(),
            message_type,
            encoding: encoding.to_owned(),
            messages: 0,
        });
        self.topics.len() - 1
    }
}

/// `pkg/Type` (ROS 1 style) → `pkg/msg/Type`; anything else unchanged.
fn normalise_type(message_type: &str) -> String {
    match message_type.split('/').collect::<Vec<_>>().as_slice() {
        [package, name] => format!("{package}/msg/{name}"),
        _ => message_type.to_owned(),
    }
}

fn invalid(file: &Path, reason: impl Into<String>) -> IoError {
    IoError::Invalid {
        file: file.display().to_string(),
        reason: reason.into(),
    }
}

fn io_error(file: &Path, source: std::io::Error) -> IoError {
    IoError::Io {
        file: file.display().to_string(),
        source,
    }
}

/// True when `path` names a bag: a `.mcap` or `.db3` file, or a directory with
/// `metadata.yaml`.
pub fn is_bag(path: &Path) -> bool {
    Storage::of_file(path).is_some() || path.join("metadata.yaml").is_file()
}

/// Reads the bag at `path` (file or directory), keeping the messages whose type `wanted`
/// accepts; messages come out sorted by log time (stable within a time).
pub(crate) fn read_raw_bag(path: &Path, wanted: &dyn Fn(&str) -> bool) -> Result<RawBag, IoError> {
    let mut bag = RawBag::default();
    if path.is_dir() {
        for (storage, file) in bag_directory_files(path)? {
            read_file(&mut bag, &file, storage, wanted)?;
        }
    } else {
        let storage = Storage::of_file(path).ok_or_else(|| {
            invalid(
                path,
                "not a bag: expected a .mcap or .db3 file or a directory with metadata.yaml",
            )
        })?;
        read_file(&mut bag, path, storage, wanted)?;
    }
    bag.messages.sort_by_key(|m| m.log_time_ns);
    Ok(bag)
}

fn read_file(
    bag: &mut RawBag,
    file: &Path,
    storage: Storage,
    wanted: &dyn Fn(&str) -> bool,
) -> Result<(), IoError> {
    if bag.storage.is_some_and(|s| s != storage) {
        return Err(invalid(file, "a bag mixes storage formats"));
    }
    bag.storage = Some(storage);
    match storage {
        Storage::Mcap => {
            let bytes = std::fs::read(file).map_err(|e| io_error(file, e))?;
            bag.bytes += bytes.len() as u64;
            read_mcap(bag, &bytes, wanted).map_err(|reason| invalid(file, reason))
        }
        Storage::Sqlite3 => {
            bag.bytes += std::fs::metadata(file)
                .map_err(|e| io_error(file, e))?
                .len();
            read_db3(bag, file, wanted).map_err(|reason| invalid(file, reason))
        }
    }
}

/// Largest decompressed record or chunk (bytes) per byte of an MCAP file: far above real
/// compression ratios, and a bound on what a corrupt length can make the reader allocate.
const MAX_RECORD_BYTES_PER_FILE_BYTE: usize = 64;

/// Reads the messages of one MCAP file's bytes into `bag`. The `mcap` crate's sans-io reader
/// walks the file's records (length-limited); chunks come out whole and are opened here
/// ([`chunk_records`]), because the crate's own chunk readers panic on some corrupt chunks
/// (an unbounded allocation for a huge record length, a subtraction overflow for a record
/// longer than its uncompressed chunk; both found by the fuzz target `parse_bag`). Schemas and
/// channels are linked here; other records are not parsed ([`NEEDED_RECORDS`]).
pub(crate) fn read_mcap(
    bag: &mut RawBag,
    bytes: &[u8],
    wanted: &dyn Fn(&str) -> bool,
) -> Result<(), String> {
    use mcap::records::Record;
    use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
    let limit = bytes
        .len()
        .saturating_mul(MAX_RECORD_BYTES_PER_FILE_BYTE)
        .max(1 << 20);
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_record_length_limit(limit)
            .with_emit_chunks(true),
    );
    let malformed = |e: mcap::McapError| format!("malformed MCAP: {e}");
    let mut links = Links::default();
    let mut unread = bytes;
    while let Some(event) = reader.next_event() {
        let (opcode, data) = match event.map_err(malformed)? {
            LinearReadEvent::ReadRequest(wanted_bytes) => {
                let n = wanted_bytes.min(unread.len());
                reader.insert(n).copy_from_slice(&unread[..n]);
                reader.notify_read(n);
                unread = &unread[n..];
                continue;
            }
            LinearReadEvent::Record { opcode, data } => (opcode, data),
        };
        if !NEEDED_RECORDS.contains(&opcode) {
            continue;
        }
        match mcap::parse_record(opcode, data).map_err(malformed)? {
            Record::Chunk { header, data } => {
                let records = chunk_records(&header, &data, limit)?;
                let mut rest = records.as_slice();
                while !rest.is_empty() {
                    let (opcode, body, after) = split_record(rest)?;
                    if NEEDED_RECORDS.contains(&opcode) {
                        links.take(
                            bag,
                            mcap::parse_record(opcode, body).map_err(malformed)?,
                            wanted,
                        )?;
                    }
                    rest = after;
                }
            }
            record => links.take(bag, record, wanted)?,
        }
    }
    Ok(())
}

/// The only MCAP records parsed: the others (attachments, metadata, indexes, statistics) are
/// skipped unread; `mcap::parse_record` panics on a short attachment (found by `parse_bag`).
const NEEDED_RECORDS: [u8; 4] = [
    mcap::records::op::SCHEMA,
    mcap::records::op::CHANNEL,
    mcap::records::op::MESSAGE,
    mcap::records::op::CHUNK,
];

/// Schema ids → message types; channel ids → (topic index, whether its messages are kept).
#[derive(Default)]
struct Links {
    schemas: BTreeMap<u16, String>,
    channels: BTreeMap<u16, (usize, bool)>,
}

impl Links {
    fn take(
        &mut self,
        bag: &mut RawBag,
        record: mcap::records::Record<'_>,
        wanted: &dyn Fn(&str) -> bool,
    ) -> Result<(), String> {
        use mcap::records::Record;
        match record {
            Record::Schema { header, .. } => {
                self.schemas.insert(header.id, header.name);
            }
            Record::Channel(channel) => {
                let message_type = self
                    .schemas
                    .get(&channel.schema_id)
                    .map_or("", String::as_str);
                let index =
                    bag.topic_index(&channel.topic, message_type, &channel.message_encoding);
                self.channels
                    .insert(channel.id, (index, wanted(&bag.topics[index].message_type)));
            }
            Record::Message { header, data } => {
                let (topic, kept) = *self
                    .channels
                    .get(&header.channel_id)
                    .ok_or_else(|| format!("message on unknown channel {}", header.channel_id))?;
                bag.topics[topic].messages += 1;
                if kept {
                    bag.messages.push(RawMessage {
                        topic,
                        log_time_ns: i64::try_from(header.log_time).unwrap_or(i64::MAX),
                        data: data.into_owned(),
                    });
                }
            }
            _ => {}
        }
        Ok(())
    }
}

/// The records of a chunk, decompressed (`""`, `zstd`, `lz4`), at most `limit` bytes, checked
/// against the chunk's size and CRC.
fn chunk_records(
    header: &mcap::records::ChunkHeader,
    data: &[u8],
    limit: usize,
) -> Result<Vec<u8>, String> {
    use std::io::Read as _;
    let size = usize::try_from(header.uncompressed_size)
        .ok()
        .filter(|&size| size <= limit)
        .ok_or_else(|| {
            format!(
                "a chunk claims {} bytes uncompressed, more than the file can hold",
                header.uncompressed_size
            )
        })?;
    let records = match header.compression.as_str() {
        "" => data.to_vec(),
        "zstd" => {
            let mut out = Vec::with_capacity(size);
            ruzstd::decoding::StreamingDecoder::new(data)
                .map_err(std::io::Error::other)
                .and_then(|decoder| decoder.take(size as u64 + 1).read_to_end(&mut out))
                .map_err(|e| format!("a zstd chunk does not decompress: {e}"))?;
            out
        }
        "lz4" => {
            let mut out = Vec::with_capacity(size);
            lz4_flex::frame::FrameDecoder::new(data)
                .take(size as u64 + 1)
                .read_to_end(&mut out)
                .map_err(|e| format!("an lz4 chunk does not decompress: {e}"))?;
            out
        }
        other => {
            return Err(format!(
                "chunk compression '{other}' is not supported (zstd, lz4)"
            ))
        }
    };
    if records.len() != size {
        return Err(format!(
            "a chunk holds {} bytes, its header says {size}",
            records.len()
        ));
    }
    if header.uncompressed_crc != 0 && crc32fast::hash(&records) != header.uncompressed_crc {
        return Err("a chunk's CRC does not match its records".to_owned());
    }
    Ok(records)
}

/// The first record of `bytes` (opcode u8, length u64 LE, body) and the rest.
fn split_record(bytes: &[u8]) -> Result<(u8, &[u8], &[u8]), String> {
    let truncated = || "a chunk ends inside a record".to_owned();
    let (&opcode, rest) = bytes.split_first().ok_or_else(truncated)?;
    let (length, rest) = rest.split_first_chunk::<8>().ok_or_else(truncated)?;
    let length = usize::try_from(u64::from_le_bytes(*length)).map_err(|_| truncated())?;
    if length > rest.len() {
        return Err(truncated());
    }
    let (body, after) = rest.split_at(length);
    Ok((opcode, body, after))
}

fn read_db3(bag: &mut RawBag, file: &Path, wanted: &dyn Fn(&str) -> bool) -> Result<(), String> {
    use rusqlite::OpenFlags;
    let sql = |e: rusqlite::Error| format!("not a readable rosbag2 SQLite file: {e}");
    let connection = rusqlite::Connection::open_with_flags(
        file,
        OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
    )
    .map_err(sql)?;
    // Topic id → (topic index, whether its messages are kept).
    let mut ids: BTreeMap<i64, (usize, bool)> = BTreeMap::new();
    {
        let mut statement = connection
            .prepare("SELECT id, name, type, serialization_format FROM topics")
            .map_err(sql)?;
        let rows = statement
            .query_map([], |row| {
                Ok((
                    row.get::<_, i64>(0)?,
                    row.get::<_, String>(1)?,
                    row.get::<_, String>(2)?,
                    row.get::<_, String>(3)?,
                ))
            })
            .map_err(sql)?;
        for row in rows {
            let (id, name, message_type, encoding) = row.map_err(sql)?;
            let index = bag.topic_index(&name, &message_type, &encoding);
            ids.insert(id, (index, wanted(&bag.topics[index].message_type)));
        }
    }
    let mut statement = connection
        .prepare("SELECT topic_id, timestamp, data FROM messages ORDER BY timestamp, id")
        .map_err(sql)?;
    let mut rows = statement.query([]).map_err(sql)?;
    while let Some(row) = rows.next().map_err(sql)? {
        let topic_id: i64 = row.get(0).map_err(sql)?;
        let (topic, kept) = *ids.get(&topic_id).ok_or_else(|| {
            format!("a message names topic id {topic_id}, which the topics table lacks")
        })?;
        bag.topics[topic].messages += 1;
        if !kept {
            continue;
        }
        bag.messages.push(RawMessage {
            topic,
            log_time_ns: row.get(1).map_err(sql)?,
            data: row.get(2).map_err(sql)?,
        });
    }
    Ok(())
}

/// `metadata.yaml` of a bag directory, the fields read here.
#[derive(serde::Deserialize)]
struct Metadata {
    rosbag2_bagfile_information: BagfileInformation,
}

#[derive(serde::Deserialize)]
struct BagfileInformation {
    storage_identifier: String,
    #[serde(default)]
    relative_file_paths: Vec<String>,
    #[serde(default)]
    compression_format: String,
}

/// The files of a bag directory, in the order `metadata.yaml` gives.
fn bag_directory_files(directory: &Path) -> Result<Vec<(Storage, PathBuf)>, IoError> {
    let metadata_path = directory.join("metadata.yaml");
    let text = mapmerge_io::read_document(&metadata_path)?;
    let metadata: Metadata = serde_yaml_ng::from_str(&text)
        .map_err(|e| invalid(&metadata_path, format!("not rosbag2 metadata: {e}")))?;
    let info = metadata.rosbag2_bagfile_information;
    if !info.compression_format.is_empty() {
        return Err(invalid(
            &metadata_path,
            format!("file compression '{}' is not supported; decompress the bag first (ros2 bag convert)", info.compression_format),
        ));
    }
    let storage = match info.storage_identifier.as_str() {
        "mcap" => Storage::Mcap,
        "sqlite3" => Storage::Sqlite3,
        other => {
            return Err(invalid(
                &metadata_path,
                format!("unknown storage '{other}' (mcap and sqlite3 are read)"),
            ))
        }
    };
    if info.relative_file_paths.is_empty() {
        return Err(invalid(
            &metadata_path,
            "no relative_file_paths: the bag has no files",
        ));
    }
    Ok(info
        .relative_file_paths
        .iter()
        .map(|file| (storage, directory.join(file)))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn types_normalise_to_the_ros2_form() {
        assert_eq!(
            normalise_type("sensor_msgs/LaserScan"),
            "sensor_msgs/msg/LaserScan"
        );
        assert_eq!(
            normalise_type("sensor_msgs/msg/LaserScan"),
            "sensor_msgs/msg/LaserScan"
        );
        assert_eq!(normalise_type(""), "");
    }

    #[test]
    fn garbage_is_an_error_not_a_panic() {
        let mut bag = RawBag::default();
        assert!(read_mcap(&mut bag, b"\x89MCAP0\r\nnonsense", &|_| true).is_err());
        assert!(read_mcap(&mut bag, b"", &|_| true).is_err());
        let dir = tempfile::tempdir().unwrap();
        let db3 = dir.path().join("x.db3");
        std::fs::write(&db3, b"not sqlite at all, not at all, not at all").unwrap();
        let err = read_raw_bag(&db3, &|_| true).unwrap_err().to_string();
        assert!(err.contains("x.db3") && err.contains("SQLite"), "{err}");
        std::fs::write(
            dir.path().join("metadata.yaml"),
            "rosbag2_bagfile_information:\n  storage_identifier: rosbag_v1\n",
        )
        .unwrap();
        let err = read_raw_bag(dir.path(), &|_| true).unwrap_err().to_string();
        assert!(err.contains("unknown storage 'rosbag_v1'"), "{err}");
    }

    /// Bags written by mapmerge have uncompressed chunks, so the fuzz companions in
    /// tests/never_panics.rs do not reach the decoders: this mutates compressed chunks here.
    #[test]
    fn compressed_chunks_decode_and_mutated_ones_are_errors_not_panics() {
        use std::io::Write as _;
        let records: Vec<u8> = (0..20_000u32)
            .flat_map(|k| (k % 251).to_le_bytes())
            .collect();
        let zstd = ruzstd::encoding::compress_to_vec(
            &records[..],
            ruzstd::encoding::CompressionLevel::Fastest,
        );
        let mut lz4 = lz4_flex::frame::FrameEncoder::new(Vec::new());
        lz4.write_all(&records).unwrap();
        let lz4 = lz4.finish().unwrap();
        let header = |compression: &str, data: &[u8], size: usize| mcap::records::ChunkHeader {
            message_start_time: 0,
            message_end_time: 0,
            uncompressed_size: size as u64,
            uncompressed_crc: crc32fast::hash(&records),
            compression: compression.to_owned(),
            compressed_size: data.len() as u64,
        };
        let limit = 4 * records.len();
        let mut state = 0x9E37_79B9_7F4A_7C15_u64;
        let mut next = move || {
            state ^= state >> 12;
            state ^= state << 25;
            state ^= state >> 27;
            state.wrapping_mul(0x2545_F491_4F6C_DD1D)
        };
        for (name, data) in [("zstd", &zstd), ("lz4", &lz4)] {
            assert!(
                data.len() < records.len() / 2,
                "{name}: {} bytes",
                data.len()
            );
            let decoded = chunk_records(&header(name, data, records.len()), data, limit);
            assert_eq!(decoded.as_deref(), Ok(&records[..]), "{name}");
            // A chunk that claims more than the file can hold is refused before decoding.
            assert!(chunk_records(&header(name, data, limit + 1), data, limit).is_err());
            let mut failed = 0;
            for round in 0..3000 {
                let mut mutated = data.clone();
                if round % 4 == 0 {
                    mutated.truncate(next() as usize % data.len());
                } else {
                    for _ in 0..1 + next() % 4 {
                        let at = next() as usize % mutated.len();
                        mutated[at] = next() as u8;
                    }
                }
                let header = header(name, &mutated, records.len());
                failed += usize::from(chunk_records(&header, &mutated, limit).is_err());
            }
            assert!(
                failed > 1000,
                "{name}: only {failed} of 3000 mutations were errors"
            );
        }
    }
}
