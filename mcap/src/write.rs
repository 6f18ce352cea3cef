//! Writing ROS 2 recordings (MCAP, profile `ros2`, CDR messages, `ros2msg`
//! schemas, uncompressed chunks) for tests and simulators.
//!
//! * [`McapWriter::write_image`]: a `mono8` `sensor_msgs/msg/Image`.
//! * [`McapWriter::write_compressed_png`]: a PNG `sensor_msgs/msg/CompressedImage`
//!   (format `mono8; png compressed`).
//! * [`McapWriter::write_scan`]: a `sensor_msgs/msg/LaserScan` from a
//!   [`Scan`] whose rays are uniform in time and angle (see there).
//! * [`McapWriter::write_message`]: any [`CdrMessage`].
//!
//! The log time of each message is its stamp plus [`McapWriter::set_log_delay_ns`]
//! (0 by default), a stand-in for the recorder's receive latency. Messages should
//! be written in log-time order per topic: this crate's reader yields them in file
//! order (some readers of indexed files sort, [`crate::read`] does not).

use crate::cdr::{CdrMessage, CompressedImage, F32Seq, Header, Image, LaserScan, Time};
use crate::error::Error;
use mcap::records::MessageHeader;
use mcap::{McapError, WriteOptions};
use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use vlsync_common::Nanos;
use vlsync_signature_cam::GrayFrame;
use vlsync_signature_lidar::scan::wrap_pi;
use vlsync_signature_lidar::Scan;

/// Largest deviation of a ray's time from the uniform model `write_scan` accepts, ns.
pub const SCAN_TIME_TOLERANCE_NS: i64 = 1_000;
/// Largest deviation of a ray's bearing from the uniform model `write_scan` accepts, rad.
pub const SCAN_BEARING_TOLERANCE_RAD: f64 = 1e-4;

struct Channel {
    id: u16,
    schema: &'static str,
    sequence: u32,
}

/// An MCAP file being written (see the module docs). Call [`McapWriter::finish`];
/// dropping it finishes too but cannot report errors.
pub struct McapWriter {
    path: PathBuf,
    inner: mcap::Writer<BufWriter<File>>,
    channels: HashMap<String, Channel>,
    log_delay_ns: Nanos,
    frame_id: String,
    cdr: Vec<u8>,
    pixels: Vec<u8>,
    ranges: Vec<f32>,
    intensities: Vec<f32>,
}

impl std::fmt::Debug for McapWriter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("McapWriter")
            .field("path", &self.path)
            .field("topics", &self.channels.keys().collect::<Vec<_>>())
            .finish_non_exhaustive()
    }
}

impl McapWriter {
    /// Creates (truncates) `path`.
    pub fn create(path: impl AsRef<Path>) -> Result<Self, Error> {
        let path = path.as_ref().to_path_buf();
        let file = File::create(&path).map_err(|source| Error::Io {
            path: path.clone(),
            doing: "creating".into(),
            source,
        })?;
        let inner = WriteOptions::new()
            .compression(None)
            .profile("ros2")
            .library(concat!("vlsync-mcap/", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::new(file))
            .map_err(|source| Error::Mcap {
                path: path.clone(),
                at: "writing the header".into(),
                source,
            })?;
        Ok(Self {
            path,
            inner,
            channels: HashMap::new(),
            log_delay_ns: 0,
            frame_id: String::new(),
            cdr: Vec::new(),
            pixels: Vec::new(),
            ranges: Vec::new(),
            intensities: Vec::new(),
        })
    }

    /// Log time = stamp + `delay_ns` for the typed helpers (default 0).
    pub fn set_log_delay_ns(&mut self, delay_ns: Nanos) {
        self.log_delay_ns = delay_ns;
    }

    /// `header.frame_id` written by the typed helpers (default empty).
    pub fn set_frame_id(&mut self, frame_id: impl Into<String>) {
        self.frame_id = frame_id.into();
    }

    fn write_err(&self, topic: &str, reason: impl Into<String>) -> Error {
        Error::Write {
            path: self.path.clone(),
            topic: topic.to_string(),
            reason: reason.into(),
        }
    }

    fn mcap_err(&self, topic: &str, source: McapError) -> Error {
        Error::Mcap {
            path: self.path.clone(),
            at: format!("writing topic `{topic}`"),
            source,
        }
    }

    fn header<'a>(&'a self, topic: &str, stamp_ns: Nanos) -> Result<Header<'a>, Error> {
        let stamp = Time::from_nanos(stamp_ns).ok_or_else(|| {
            self.write_err(
                topic,
                format!("stamp {stamp_ns} ns does not fit builtin_interfaces/Time (int32 seconds)"),
            )
        })?;
        Ok(Header {
            stamp,
            frame_id: &self.frame_id,
        })
    }

    fn log_time(&self, topic: &str, stamp_ns: Nanos) -> Result<u64, Error> {
        stamp_ns
            .checked_add(self.log_delay_ns)
            .and_then(|t| u64::try_from(t).ok())
            .ok_or_else(|| {
                self.write_err(
                    topic,
                    format!(
                        "log time {stamp_ns} + {} ns is not a non-negative u64",
                        self.log_delay_ns
                    ),
                )
            })
    }

    /// Writes already serialized bytes as a message of schema `M` on `topic`,
    /// unchecked (e.g. to make hostile recordings for tests).
    pub fn write_serialized<'m, M: CdrMessage<'m>>(
        &mut self,
        topic: &str,
        log_time: u64,
        data: &[u8],
    ) -> Result<(), Error> {
        let channel = match self.channels.get_mut(topic) {
            Some(c) => c,
            None => {
                let schema = self
                    .inner
                    .add_schema(M::SCHEMA_NAME, "ros2msg", M::SCHEMA_TEXT.as_bytes())
                    .map_err(|e| self.mcap_err(topic, e))?;
                let id = self
                    .inner
                    .add_channel(schema, topic, "cdr", &BTreeMap::new())
                    .map_err(|e| self.mcap_err(topic, e))?;
                self.channels.entry(topic.to_string()).or_insert(Channel {
                    id,
                    schema: M::SCHEMA_NAME,
                    sequence: 0,
                })
            }
        };
        if channel.schema != M::SCHEMA_NAME {
            let reason = format!(
                "topic has schema {}, cannot write {}",
                channel.schema,
                M::SCHEMA_NAME
            );
            return Err(self.write_err(topic, reason));
        }
        let header = MessageHeader {
            channel_id: channel.id,
            sequence: channel.sequence,
            log_time,
            publish_time: log_time,
        };
        channel.sequence = channel.sequence.wrapping_add(1);
        self.inner
            .write_to_known_channel(&header, data)
            .map_err(|e| self.mcap_err(topic, e))
    }

    /// Writes any message with the given log time.
    pub fn write_message<'m, M: CdrMessage<'m>>(
        &mut self,
        topic: &str,
        log_time: u64,
        msg: &M,
    ) -> Result<(), Error> {
        let mut buf = std::mem::take(&mut self.cdr);
        let r = msg
            .encode(&mut buf)
            .map_err(|e| self.write_err(topic, e.to_string()))
            .and_then(|()| self.write_serialized::<M>(topic, log_time, &buf));
        self.cdr = buf;
        r
    }

    /// Writes a `mono8` `Image` stamped `stamp_ns`.
    pub fn write_image(
        &mut self,
        topic: &str,
        stamp_ns: Nanos,
        frame: &GrayFrame<'_, u8>,
    ) -> Result<(), Error> {
        let too_big = |what: &str| self.write_err(topic, format!("{what} does not fit uint32"));
        let width = u32::try_from(frame.width()).map_err(|_| too_big("width"))?;
        let height = u32::try_from(frame.height()).map_err(|_| too_big("height"))?;
        let log_time = self.log_time(topic, stamp_ns)?;
        let mut buf = std::mem::take(&mut self.cdr);
        let enc = self.header(topic, stamp_ns).and_then(|header| {
            let msg = Image {
                header,
                height,
                width,
                encoding: "mono8",
                is_bigendian: 0,
                step: width,
                data: frame.pixels(),
            };
            msg.encode(&mut buf)
                .map_err(|e| self.write_err(topic, e.to_string()))
        });
        let r = enc.and_then(|()| self.write_serialized::<Image>(topic, log_time, &buf));
        self.cdr = buf;
        r
    }

    /// Writes a PNG `CompressedImage` (format `mono8; png compressed`) stamped `stamp_ns`.
    pub fn write_compressed_png(
        &mut self,
        topic: &str,
        stamp_ns: Nanos,
        frame: &GrayFrame<'_, u8>,
    ) -> Result<(), Error> {
        use image::ImageEncoder;
        let log_time = self.log_time(topic, stamp_ns)?;
        let (w, h) = (frame.width(), frame.height());
        let (Ok(w32), Ok(h32)) = (u32::try_from(w), u32::try_from(h)) else {
            return Err(self.write_err(topic, format!("{w}x{h} frame is too large for PNG")));
        };
        let mut png = std::mem::take(&mut self.pixels);
        png.clear();
        let enc = image::codecs::png::PngEncoder::new(&mut png).write_image(
            frame.pixels(),
            w32,
            h32,
            image::ExtendedColorType::L8,
        );
        let mut buf = std::mem::take(&mut self.cdr);
        let enc = enc
            .map_err(|e| self.write_err(topic, format!("PNG encoding failed: {e}")))
            .and_then(|()| self.header(topic, stamp_ns))
            .and_then(|header| {
                let msg = CompressedImage {
                    header,
                    format: "mono8; png compressed",
                    data: &png,
                };
                msg.encode(&mut buf)
                    .map_err(|e| self.write_err(topic, e.to_string()))
            });
        let r = enc.and_then(|()| self.write_serialized::<CompressedImage>(topic, log_time, &buf));
        self.cdr = buf;
        self.pixels = png;
        r
    }

    /// Writes a `LaserScan` from `scan`.
    ///
    /// The stamp is the first ray's time; `time_increment` and `angle_increment`
    /// are the mean steps between consecutive rays (bearings unwrapped). Every ray
    /// must lie within [`SCAN_TIME_TOLERANCE_NS`] and [`SCAN_BEARING_TOLERANCE_RAD`]
    /// of that uniform model, else this is an error (a scan assembled from
    /// packets with jittery times is not a `LaserScan`). Invalid rays, and rays
    /// with a non-finite or non-positive range, are written as NaN; `range_min`
    /// is 0 and `range_max` the largest finite `f32`; `scan_time` is the scan's
    /// period. Reading the message back gives ray times
    /// `stamp + round(i · time_increment)` (the increment read as its decimal,
    /// see [`crate::scan::f32_as_decimal`]): exactly the written times when they
    /// are on that grid, else within the tolerance.
    pub fn write_scan(&mut self, topic: &str, scan: &Scan) -> Result<(), Error> {
        let rays = scan.rays();
        let n = rays.len();
        let stamp_ns = rays.first().map_or(scan.timing().start_ns, |r| r.t_ns);
        let a0 = rays
            .first()
            .map_or(scan.timing().start_bearing_rad, |r| r.bearing_rad);
        let (dt_ns, da) = if n > 1 {
            let span = rays[n - 1].t_ns.saturating_sub(rays[0].t_ns);
            let turn: f64 = rays
                .windows(2)
                .map(|w| wrap_pi(w[1].bearing_rad - w[0].bearing_rad))
                .sum();
            (span as f64 / (n - 1) as f64, turn / (n - 1) as f64)
        } else {
            (0.0, 0.0)
        };
        let time_increment = (dt_ns * 1e-9) as f32;
        let angle_increment = da as f32;
        let angle_min = a0 as f32;
        let (ti, ai, am) = (
            crate::scan::f32_as_decimal(time_increment) * 1e9,
            f64::from(angle_increment),
            f64::from(angle_min),
        );
        for (i, r) in rays.iter().enumerate() {
            let t = stamp_ns.saturating_add((i as f64 * ti).round() as i64);
            if (t - r.t_ns).abs() > SCAN_TIME_TOLERANCE_NS {
                return Err(self.write_err(
                    topic,
                    format!(
                        "ray {i} at {} ns is {} ns off the uniform time step {dt_ns:.1} ns",
                        r.t_ns,
                        r.t_ns - t
                    ),
                ));
            }
            let off = wrap_pi(am + i as f64 * ai - r.bearing_rad);
            if off.is_nan() || off.abs() > SCAN_BEARING_TOLERANCE_RAD {
                return Err(self.write_err(
                    topic,
                    format!(
                        "ray {i} at bearing {} rad is {off:e} rad off the uniform angle step {da} rad",
                        r.bearing_rad
                    ),
                ));
            }
        }
        let mut ranges = std::mem::take(&mut self.ranges);
        let mut intensities = std::mem::take(&mut self.intensities);
        ranges.clear();
        intensities.clear();
        for r in rays {
            let ok = r.valid && r.range_m.is_finite() && r.range_m > 0.0;
            ranges.push(if ok { r.range_m as f32 } else { f32::NAN });
            intensities.push(r.intensity);
        }
        let mut buf = std::mem::take(&mut self.cdr);
        let log_time = self.log_time(topic, stamp_ns);
        let enc = self.header(topic, stamp_ns).and_then(|header| {
            let msg = LaserScan {
                header,
                angle_min,
                angle_max: (am + n.saturating_sub(1) as f64 * ai) as f32,
                angle_increment,
                time_increment,
                scan_time: (scan.timing().period_ns as f64 * 1e-9) as f32,
                range_min: 0.0,
                range_max: f32::MAX,
                ranges: F32Seq::from_slice(&ranges),
                intensities: F32Seq::from_slice(&intensities),
            };
            msg.encode(&mut buf)
                .map_err(|e| self.write_err(topic, e.to_string()))
        });
        let result = enc
            .and(log_time)
            .and_then(|t| self.write_serialized::<LaserScan>(topic, t, &buf));
        self.cdr = buf;
        self.ranges = ranges;
        self.intensities = intensities;
        result
    }

    /// Writes the summary and footer and flushes the file.
    pub fn finish(mut self) -> Result<(), Error> {
        self.inner.finish().map_err(|source| Error::Mcap {
            path: self.path.clone(),
            at: "writing the summary".into(),
            source,
        })?;
        Ok(())
    }
}
