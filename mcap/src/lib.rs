//! ROS 2 recordings (MCAP files with CDR messages) as sources for vlsync's two
//! front-ends, and writers for tests and simulators.
//!
//! * [`cdr`]: hand-written, bounds-checked CDR (XCDR1 little-endian) for
//!   `builtin_interfaces/Time`, `std_msgs/Header`, `sensor_msgs/Image`,
//!   `sensor_msgs/CompressedImage` and `sensor_msgs/LaserScan`, both ways.
//! * [`read`]: the messages of one topic, in file order (through the index when
//!   the file has one), by topic name or by schema.
//! * [`image`]: [`McapImageSource`], a `vlsync_signature_cam::FrameSource`
//!   (mono8, rgb8, bgr8, rgba8, yuv422/yuyv, PNG, JPEG).
//! * [`scan`]: [`McapScanSource`], `vlsync_signature_lidar::Scan`s with per-ray
//!   times from `header.stamp + i · time_increment`.
//! * [`write`](mod@write): [`McapWriter`]: mono8 images, PNG images and scans.
//! * [`decompress`]: which chunk compressions are read.
//!
//! A recording is hostile input: nothing here panics on any file, and every
//! error names the file and, for a message, its topic, index and log time.
//!
//! ```
//! use vlsync_mcap::{McapReader, McapWriter, Select};
//! use vlsync_signature_cam::GrayFrame;
//! let path = std::env::temp_dir().join(format!("vlsync-mcap-doc-lib-{}.mcap", std::process::id()));
//! let mut w = McapWriter::create(&path).unwrap();
//! w.write_image("/camera/image_raw", 10, &GrayFrame::owned(2, 2, vec![1, 2, 3, 4]).unwrap()).unwrap();
//! w.finish().unwrap();
//! let topics = McapReader::topics(&path).unwrap();
//! assert_eq!(topics[0].topic, "/camera/image_raw");
//! assert_eq!(topics[0].schema_name, "sensor_msgs/msg/Image");
//! assert_eq!(topics[0].message_count, Some(1));
//! let mut r = McapReader::open(&path, &Select::Schema, &vlsync_mcap::IMAGE_SCHEMAS, Default::default()).unwrap();
//! let m = r.next_message().unwrap().unwrap();
//! assert_eq!((m.index, m.log_time), (0, 10));
//! # std::fs::remove_file(&path).unwrap();
//! ```
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod cdr;
pub mod decompress;
mod error;
pub mod image;
mod lengths;
mod linear;
pub mod read;
pub mod scan;
pub mod write;

pub use error::{Error, MessageAt};
pub use image::{ImageFrame, ImageSourceOptions, McapImageSource, StampSource, IMAGE_SCHEMAS};
pub use read::{McapReader, MessageRef, ReaderOptions, Select, TopicInfo};
pub use scan::{McapScanSource, ScanSourceOptions, SCAN_SCHEMAS};
pub use write::McapWriter;
