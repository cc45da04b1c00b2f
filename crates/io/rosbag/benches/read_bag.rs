//! Reading a laser session from a bag against reading the same log as CARMEN text, in one
//! process (the target: reading a bag is at least as fast as reading the CARMEN log). Each
//! public log is written to a temporary folder as plain CARMEN text, `.mcap` and `.db3`;
//! throughput is the file's bytes.
//!
//! `cargo bench -p mapmerge-rosbag --bench read_bag` (`-- intel` for one log)

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use mapmerge_rosbag::{read_log, write_bag, BagWriteParams, TopicChoice};

use mapmerge_testkit::PUBLIC_LOGS as LOGS;

fn read_bag(c: &mut Criterion) {
    let Some(data) = mapmerge_testkit::shared_data_dir() else {
        return;
    };
    let dir = match tempfile::tempdir() {
        Ok(dir) => dir,
        Err(err) => panic!("{err}"),
    };
    for name in LOGS {
        let source = data.join(format!("carmen/{name}-corrected.log.xz"));
        let log = match mapmerge_io::read_carmen(&source) {
            Ok(log) => log,
            Err(err) => panic!("{err}"),
        };
        // The log as published, decompressed: the CARMEN reader's own input.
        let mut text = Vec::new();
        let decompressed = std::fs::File::open(&source)
            .and_then(|file| {
                std::io::Read::read_to_end(&mut xz2::read::XzDecoder::new(file), &mut text)
            })
            .and_then(|_| std::fs::write(dir.path().join(format!("{name}.log")), &text));
        if let Err(err) = decompressed {
            panic!("{err}");
        }
        let written = write_bag(
            &dir.path().join(format!("{name}.mcap")),
            &log,
            &BagWriteParams::default(),
        )
        .and_then(|_| {
            write_bag(
                &dir.path().join(format!("{name}.db3")),
                &log,
                &BagWriteParams::default(),
            )
        });
        if let Err(err) = written {
            panic!("{err}");
        }
        let mut group = c.benchmark_group(name);
        group
            .sample_size(20)
            .warm_up_time(Duration::from_millis(300))
            .measurement_time(Duration::from_secs(1));
        for extension in ["log", "mcap", "db3"] {
            let path = dir.path().join(format!("{name}.{extension}"));
            let bytes = std::fs::metadata(&path).map_or(0, |m| m.len());
            group.throughput(Throughput::Bytes(bytes));
            group.bench_function(extension, |b| {
                b.iter(|| read_log(black_box(&path), &TopicChoice::default()))
            });
        }
        group.finish();
    }
}

criterion_group!(benches, read_bag);
criterion_main!(benches);
