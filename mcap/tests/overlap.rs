//! Chunks whose time ranges overlap are read one at a time: the reader's memory
//! does not grow with their count. In log-time order the index's reader held every
//! chunk whose range had begun, here all forty of 2 MiB (and a few hundred bytes of
//! hostile index made that forty of 250 MiB). Its own test binary: the process's
//! peak resident memory is what it measures, and nothing else runs beside it.

use vlsync_mcap::cdr::{CdrMessage, Image};
use vlsync_mcap::{McapReader, Select};

/// The process's peak resident memory so far (`VmHWM`), bytes.
fn peak_rss() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap();
    let line = status.lines().find(|l| l.starts_with("VmHWM:")).unwrap();
    let kb: u64 = line.split_whitespace().nth(1).unwrap().parse().unwrap();
    kb * 1024
}

#[test]
fn overlapping_chunks_are_held_one_at_a_time() {
    const CHUNKS: u64 = 40;
    const BLOB: usize = 2 << 20;
    let path =
        std::env::temp_dir().join(format!("vlsync-mcap-overlap-{}.mcap", std::process::id()));
    {
        let file = std::io::BufWriter::new(std::fs::File::create(&path).unwrap());
        let mut w = mcap::WriteOptions::new()
            .compression(None)
            .chunk_size(Some(1 << 20))
            .create(file)
            .unwrap();
        let schema = w
            .add_schema(Image::SCHEMA_NAME, "ros2msg", Image::SCHEMA_TEXT.as_bytes())
            .unwrap();
        let ch = w
            .add_channel(schema, "/cam", "cdr", &Default::default())
            .unwrap();
        let blob = vec![7u8; BLOB];
        // every chunk: a message at log time 0, then one of 2 MiB at 1 s, which
        // ends the chunk: forty chunks that each span 0..1 s
        for k in 0..CHUNKS {
            for (t, data) in [(0u64, &blob[..16]), (1_000_000_000, &blob[..])] {
                let header = mcap::records::MessageHeader {
                    channel_id: ch,
                    sequence: k as u32,
                    log_time: t,
                    publish_time: t,
                };
                w.write_to_known_channel(&header, data).unwrap();
            }
        }
        w.finish().unwrap();
    }
    let before = peak_rss();
    let mut r = McapReader::open(
        &path,
        &Select::Schema,
        &vlsync_mcap::IMAGE_SCHEMAS,
        Default::default(),
    )
    .unwrap();
    assert!(r.is_indexed());
    let mut n = 0;
    while r.next_message().unwrap().is_some() {
        n += 1;
    }
    let grown = peak_rss().saturating_sub(before);
    std::fs::remove_file(&path).unwrap();
    assert_eq!(n, 2 * CHUNKS);
    // one chunk at a time is a few of its 2 MiB buffers; all forty would be 80 MiB
    assert!(
        grown < 24 << 20,
        "reading grew the peak resident memory by {} MiB",
        grown >> 20
    );
    // the file order: 0, 1 s, 0, 1 s, ...
    assert_eq!(r.out_of_order(), CHUNKS - 1);
}
