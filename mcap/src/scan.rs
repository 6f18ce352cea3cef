//! LiDAR scans from `sensor_msgs/msg/LaserScan` messages, as
//! [`vlsync_signature_lidar::Scan`]s.
//!
//! # Conventions (from `LaserScan.msg`)
//!
//! * `header.stamp` is the acquisition time of the **first** ray; ray `i` was
//!   measured at `stamp + i · time_increment` (rounded to the nanosecond).
//!   The `float32` increment is taken as the decimal it prints as (its shortest
//!   round-trip representation, see [`f32_as_decimal`]): `0.025` means 25 ms,
//!   not the binary `0.0250000004`, which would put ray 2 one nanosecond late.
//! * `time_increment = 0`, whatever `scan_time`, says the rays were not spread in
//!   time (`LaserScan.msg`: the time between measurements, used to place the
//!   points of a moving scanner): every ray gets the first ray's time, and the
//!   scan is reported as [`RayTiming::Simultaneous`] ([`McapScanSource::ray_timing`],
//!   counted by [`McapScanSource::simultaneous_scans`]). Depth cameras turned into
//!   scans publish this (`depthimage_to_laserscan`, `pointcloud_to_laserscan`,
//!   `ira_laser_tools`, with `scan_time` their output period), and so do
//!   simulators (Gazebo's ray sensors, `ros_gz_bridge`: both 0). `scan_time` is
//!   the time between scans, not a sweep, so it dates no ray: spreading the rays
//!   over it would date a depth camera's returns up to a frame period apart.
//!   The cost: a spinning scanner whose driver leaves `time_increment` at 0 has
//!   all its rays dated at the stamp, each up to a turn off the time it was
//!   measured (by where the window lies in the turn), and nothing in the message
//!   tells. Check that a spinning scanner's driver fills `time_increment`, or
//!   watch for [`RayTiming::Simultaneous`] scans from one.
//! * Ray `i` points at `angle_min + i · angle_increment` radians, about +Z,
//!   counter-clockwise positive, 0 forward (+X): the same bearing convention as
//!   `vlsync_signature_lidar::scan` (REP-103), wrapped into `(-π, π]`.
//! * Sweep direction: bearings grow with time ([`Rotation::Ccw`]) when
//!   `angle_increment` and `time_increment` have the same sign (simultaneous
//!   rays: when `angle_increment` is not negative), else [`Rotation::Cw`]. The
//!   scan's period is `scan_time` (0 when not positive), read as its decimal like
//!   `time_increment`.
//! * A `time_increment` that is NaN or infinite is an error naming the message.
//! * A ray is valid when its range is finite, positive and within
//!   `[range_min, range_max]` (REP-117: ±Inf and NaN are not measurements;
//!   drivers that mean "no return" by 0 are covered by "positive").
//! * `intensities` may be empty (intensity 0) or have one value per range.
//! * At most [`MAX_RAYS_PER_SCAN`] ranges per scan (a scanner gives a few
//!   thousand); a longer scan is an error naming the message.
//! * `scan_time` may be at most [`MAX_SCAN_TIME_S`] (10 s: no scanner turns more
//!   slowly); a longer one is an error naming the message.
//! * The rays may span at most two turns of `scan_time` (10 s when it is not
//!   given): a `time_increment` that dates them further apart is an
//!   error naming the message. A `header.stamp` is `sec · 1e9 + nanosec` as
//!   `rclcpp` reads it, a `nanosec` of a second or more included.
//! * `rplidar_ros` / `sllidar_ros2` recordings (default `inverted = false`) store
//!   the nodes reversed, `ranges[n-1-i] = node i`, with a positive
//!   `time_increment`: their rays' times read back to front, off by up to a turn
//!   (`(2f - 1)` scan times for the ray a fraction `f` into the message): nothing
//!   in the message tells, so this crate reads them as the convention says. A
//!   window in the middle of the message (bearing 0 in those drivers' frame) is
//!   dated right, one at its ends up to a turn off.
//!
//! With [`StampSource::LogTime`] the MCAP log time replaces `header.stamp` as
//! the first ray's time.
//!
//! The rays vector is reused from scan to scan; `Scan::from_timed` sorts the
//! rays by time, and Rust's stable sort allocates a scratch buffer for scans of
//! more than a few hundred rays.

use crate::cdr::{CdrMessage, LaserScan};
use crate::error::{Error, MessageAt};
use crate::image::StampSource;
use crate::read::{McapReader, ReaderOptions, Select, TopicInfo};
use std::path::Path;
use vlsync_common::Nanos;
use vlsync_signature_lidar::csv::MAX_RAYS_PER_SCAN;

/// The longest `scan_time` a message may give, s: no scanner turns more slowly.
pub const MAX_SCAN_TIME_S: f64 = 10.0;
use vlsync_signature_lidar::scan::wrap_pi;
use vlsync_signature_lidar::{Ray, Rotation, Scan, ScanTiming};

/// The schema of a scan topic.
pub const SCAN_SCHEMAS: [&str; 1] = [LaserScan::SCHEMA_NAME];

/// How the rays of a `LaserScan` were dated (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RayTiming {
    /// By the message: ray `i` at the first ray's time `+ i · time_increment`.
    Increment,
    /// All at the first ray's time: `time_increment` is 0, which says the rays
    /// were not spread in time (a depth camera or a simulator; or a spinning
    /// scanner whose driver does not fill `time_increment`, then each ray up to a
    /// turn off).
    Simultaneous,
}

impl RayTiming {
    /// How [`laser_scan_to_rays`] dates the rays of `m`.
    pub fn of(m: &LaserScan<'_>) -> Self {
        // -0 too: no spread either way
        if m.time_increment == 0.0 {
            RayTiming::Simultaneous
        } else {
            RayTiming::Increment
        }
    }
}

/// Options of [`McapScanSource`].
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct ScanSourceOptions {
    /// Topic, or [`Select::Schema`] for the only `LaserScan` topic.
    pub select: Select,
    /// Time of the first ray.
    pub stamp: StampSource,
    /// Reader limits.
    pub reader: ReaderOptions,
}

impl ScanSourceOptions {
    /// Options reading `topic`.
    pub fn topic(topic: impl Into<String>) -> Self {
        Self {
            select: Select::Topic(topic.into()),
            ..Self::default()
        }
    }
}

/// Scans from a `LaserScan` topic of an MCAP file (see the module docs).
///
/// ```
/// use vlsync_mcap::{McapScanSource, McapWriter, ScanSourceOptions};
/// use vlsync_signature_lidar::{Ray, Rotation, Scan, ScanTiming};
/// let path = std::env::temp_dir().join(format!("vlsync-mcap-doc-scan-{}.mcap", std::process::id()));
/// let timing = ScanTiming { start_ns: 5_000_000_000, period_ns: 100_000_000, rotation: Rotation::Ccw, start_bearing_rad: 0.0 };
/// // 4 rays a quarter turn apart, 25 ms apart
/// let rays = (0..4).map(|i| Ray::timed(i as f64 * std::f64::consts::FRAC_PI_2, 2.0, 0.0, true,
///                                      5_000_000_000 + i * 25_000_000)).collect();
/// let mut w = McapWriter::create(&path).unwrap();
/// w.write_scan("/scan", &Scan::from_timed(timing, rays)).unwrap();
/// w.finish().unwrap();
/// let mut src = McapScanSource::open(&path, ScanSourceOptions::default()).unwrap();
/// let scan = src.next_scan().unwrap().unwrap();
/// let times: Vec<i64> = scan.rays().iter().map(|r| r.t_ns).collect();
/// assert_eq!(times, [5_000_000_000, 5_025_000_000, 5_050_000_000, 5_075_000_000]);
/// assert!((scan.rays()[1].bearing_rad - std::f64::consts::FRAC_PI_2).abs() < 1e-6);
/// assert!(src.next_scan().unwrap().is_none());
/// # std::fs::remove_file(&path).unwrap();
/// ```
#[derive(Debug)]
pub struct McapScanSource {
    reader: McapReader,
    stamp: StampSource,
    scan: Scan,
    /// How the rays of `scan` were dated; `None` before the first scan and after
    /// an error.
    ray_timing: Option<RayTiming>,
    /// Scans returned whose rays were taken as simultaneous.
    simultaneous: u64,
}

impl McapScanSource {
    /// Opens a recording and selects the scan topic.
    pub fn open(path: impl AsRef<Path>, options: ScanSourceOptions) -> Result<Self, Error> {
        let reader = McapReader::open(path, &options.select, &SCAN_SCHEMAS, options.reader)?;
        Ok(Self {
            reader,
            stamp: options.stamp,
            scan: Scan::with_capacity(0),
            ray_timing: None,
            simultaneous: 0,
        })
    }

    /// The topic read.
    pub fn topic(&self) -> &TopicInfo {
        self.reader.topic()
    }

    /// The underlying reader (order, counters).
    pub fn reader(&self) -> &McapReader {
        &self.reader
    }

    /// How the rays of the scan last returned by [`Self::next_scan`] were dated:
    /// by the message's `time_increment`, or all at the stamp because it is 0
    /// (see the module docs); `None` before the first scan, at the end and after an
    /// error.
    pub fn ray_timing(&self) -> Option<RayTiming> {
        self.ray_timing
    }

    /// How many of the scans returned so far had their rays taken as simultaneous
    /// ([`RayTiming::Simultaneous`]: `time_increment` 0). From a spinning scanner
    /// this is a driver that does not fill `time_increment`: each ray is then
    /// dated up to a turn off.
    pub fn simultaneous_scans(&self) -> u64 {
        self.simultaneous
    }

    /// The next scan, `Ok(None)` at the end of the topic. The scan borrows the
    /// source's buffer until the next call.
    pub fn next_scan(&mut self) -> Result<Option<&Scan>, Error> {
        self.ray_timing = None;
        let Some(msg) = self.reader.next_message()? else {
            return Ok(None);
        };
        let (index, log_time) = (msg.index, msg.log_time);
        let mut rays = std::mem::replace(&mut self.scan, Scan::with_capacity(0)).into_rays();
        let result = LaserScan::decode(msg.data)
            .map_err(|e| e.to_string())
            .and_then(|m| {
                let start = match self.stamp {
                    StampSource::Header => m.header.stamp.to_nanos(),
                    StampSource::LogTime => i64::try_from(log_time)
                        .map_err(|_| format!("log time {log_time} ns does not fit i64"))?,
                };
                laser_scan_to_rays(&m, start, &mut rays).map(|t| (t, RayTiming::of(&m)))
            });
        match result {
            Ok((timing, ray_timing)) => {
                self.scan = Scan::from_timed(timing, rays);
                self.ray_timing = Some(ray_timing);
                if ray_timing == RayTiming::Simultaneous {
                    self.simultaneous += 1;
                }
                Ok(Some(&self.scan))
            }
            Err(reason) => Err(Error::Message {
                path: self.reader.path().to_path_buf(),
                at: MessageAt {
                    topic: self.reader.topic().topic.clone(),
                    index,
                    log_time,
                },
                reason,
            }),
        }
    }
}

/// Fills `rays` (cleared first) from a `LaserScan` whose first ray is at
/// `start_ns`; returns the scan timing. The rays are dated as
/// [`RayTiming::of`] says: all at `start_ns` when `time_increment` is 0. See the
/// module docs for the rules.
pub fn laser_scan_to_rays(
    m: &LaserScan<'_>,
    start_ns: Nanos,
    rays: &mut Vec<Ray>,
) -> Result<ScanTiming, String> {
    rays.clear();
    for (name, v) in [
        ("angle_min", m.angle_min),
        ("angle_increment", m.angle_increment),
        ("time_increment", m.time_increment),
    ] {
        if !v.is_finite() {
            return Err(format!("{name} is {v}"));
        }
    }
    let n = m.ranges.len();
    if n > MAX_RAYS_PER_SCAN {
        // each 4-byte range becomes a 32-byte ray: refused before any is made
        return Err(format!(
            "{n} ranges in one scan, more than the {MAX_RAYS_PER_SCAN} a scan may have"
        ));
    }
    if !m.intensities.is_empty() && m.intensities.len() != n {
        return Err(format!(
            "{} intensities for {n} ranges (must be 0 or one per range)",
            m.intensities.len()
        ));
    }
    let (a0, da) = (f64::from(m.angle_min), f64::from(m.angle_increment));
    let period = f32_as_decimal(m.scan_time) * 1e9;
    if period > MAX_SCAN_TIME_S * 1e9 {
        // else "two turns" would allow rays dated years apart
        return Err(format!(
            "scan_time {} s is more than {MAX_SCAN_TIME_S} s: no scanner turns that slowly",
            vlsync_common::text::number(f64::from(m.scan_time))
        ));
    }
    let period_ns = if period.is_finite() && period > 0.0 {
        period.round() as i64
    } else {
        0
    };
    let dt_ns = match RayTiming::of(m) {
        // not spread in time: every ray at the stamp, whatever `scan_time` (the
        // time between scans, not a sweep)
        RayTiming::Simultaneous => 0.0,
        RayTiming::Increment => f32_as_decimal(m.time_increment) * 1e9,
    };
    // rays over more than two turns (or 10 s where no turn is given) are no scan: a
    // hostile or broken increment would date them hours or centuries apart
    let span_ns = dt_ns.abs() * n.saturating_sub(1) as f64;
    let max_span_ns = if period_ns > 0 {
        2.0 * period_ns as f64
    } else {
        10e9
    };
    if span_ns > max_span_ns {
        return Err(format!(
            "{n} ranges {} s apart (time_increment) span {:.3} s, more than {}",
            dt_ns.abs() * 1e-9,
            span_ns * 1e-9,
            if period_ns > 0 {
                format!("two turns of scan_time {} s", m.scan_time)
            } else {
                "10 s (scan_time not given)".to_string()
            }
        ));
    }
    let (rmin, rmax) = (f64::from(m.range_min), f64::from(m.range_max));
    rays.reserve(n);
    for (i, r) in m.ranges.iter().enumerate() {
        let r = f64::from(r);
        let valid = r.is_finite() && r > 0.0 && r >= rmin && r <= rmax;
        // saturating float-to-int cast: a hostile increment cannot overflow
        let t = start_ns.saturating_add((i as f64 * dt_ns).round() as i64);
        let intensity = m.intensities.get(i).unwrap_or(0.0);
        rays.push(Ray::timed(a0 + i as f64 * da, r, intensity, valid, t));
    }
    let rotation = if (da >= 0.0) == (dt_ns >= 0.0) {
        Rotation::Ccw
    } else {
        Rotation::Cw
    };
    Ok(ScanTiming {
        start_ns,
        period_ns,
        rotation,
        start_bearing_rad: wrap_pi(a0),
    })
}

/// The `f64` nearest to the shortest decimal that reads back as `x` (what
/// `x` prints as), e.g. `0.025f32` → `0.025f64`. Allocation-free.
///
/// ```
/// use vlsync_mcap::scan::f32_as_decimal;
/// assert_eq!(f32_as_decimal(0.025), 0.025);
/// assert_eq!(f64::from(0.025f32) == 0.025, false);
/// assert!(f32_as_decimal(f32::NAN).is_nan());
/// ```
pub fn f32_as_decimal(x: f32) -> f64 {
    use std::io::Write;
    let mut buf = [0u8; 64];
    let mut cursor = std::io::Cursor::new(&mut buf[..]);
    if !x.is_finite() || write!(cursor, "{x}").is_err() {
        return f64::from(x);
    }
    let n = usize::try_from(cursor.position()).unwrap_or(0);
    std::str::from_utf8(&buf[..n.min(64)])
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(f64::from(x))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cdr::{F32Seq, Header, Time};
    use proptest::prelude::*;

    #[test]
    fn a_scan_of_more_rays_than_any_scanner_gives_is_refused_before_any_is_made() {
        let ranges = vec![1.0f32; MAX_RAYS_PER_SCAN + 1];
        let m = LaserScan {
            angle_increment: 0.001,
            time_increment: 1e-7,
            range_max: 12.0,
            ranges: F32Seq::from_slice(&ranges),
            ..LaserScan::default()
        };
        let mut rays = Vec::new();
        let e = laser_scan_to_rays(&m, 0, &mut rays).unwrap_err();
        assert_eq!(
            e,
            "1048577 ranges in one scan, more than the 1048576 a scan may have"
        );
        assert_eq!(rays.capacity(), 0);
        let m = LaserScan {
            ranges: F32Seq::from_slice(&ranges[1..]),
            ..m
        };
        assert!(laser_scan_to_rays(&m, 0, &mut rays).is_ok());
        assert_eq!(rays.len(), MAX_RAYS_PER_SCAN);
    }

    #[test]
    fn validity_times_and_direction() {
        let ranges = [1.0, f32::INFINITY, f32::NAN, 0.0, 0.05, 30.0, 2.0];
        let m = LaserScan {
            header: Header {
                stamp: Time { sec: 1, nanosec: 0 },
                frame_id: "laser",
            },
            angle_min: 3.0,
            angle_increment: -0.5,
            time_increment: 0.001,
            scan_time: 0.125,
            range_min: 0.1,
            range_max: 12.0,
            ranges: F32Seq::from_slice(&ranges),
            ..LaserScan::default()
        };
        let mut rays = Vec::new();
        let t = laser_scan_to_rays(&m, 1_000_000_000, &mut rays).unwrap();
        assert_eq!(t.rotation, Rotation::Cw);
        assert_eq!(t.period_ns, 125_000_000);
        let valid: Vec<bool> = rays.iter().map(|r| r.valid).collect();
        assert_eq!(valid, [true, false, false, false, false, false, true]);
        assert_eq!(rays[6].t_ns, 1_006_000_000);
        // 3.0 - 6 * 0.5 = 0; 3.0 - 0.5 = 2.5; wrapped past π: 3.0 stays
        assert!(rays[6].bearing_rad.abs() < 1e-12);
        assert!((rays[0].bearing_rad - 3.0).abs() < 1e-12);
        let m2 = LaserScan {
            angle_increment: 0.5,
            angle_min: 3.0,
            ..m
        };
        laser_scan_to_rays(&m2, 0, &mut rays).unwrap();
        assert!((rays[1].bearing_rad - (3.5 - std::f64::consts::TAU)).abs() < 1e-12);
    }

    /// A scan of `n` 2 m rays from bearing -0.5 rad stamped at 1 s, with the given
    /// increments, and how its rays were dated.
    fn scan_of(
        n: usize,
        angle_increment: f32,
        time_increment: f32,
        scan_time: f32,
    ) -> (ScanTiming, Vec<Ray>, RayTiming) {
        let ranges = vec![2.0f32; n];
        let m = LaserScan {
            angle_min: -0.5,
            angle_increment,
            time_increment,
            scan_time,
            range_max: 12.0,
            ranges: F32Seq::from_slice(&ranges),
            ..LaserScan::default()
        };
        let mut rays = Vec::new();
        let timing = laser_scan_to_rays(&m, 1_000_000_000, &mut rays).unwrap();
        assert_eq!(rays.len(), n);
        (timing, rays, RayTiming::of(&m))
    }

    #[test]
    fn a_depth_camera_scan_with_a_scan_time_has_every_ray_at_the_stamp() {
        // pointcloud_to_laserscan / depthimage_to_laserscan: time_increment 0 and
        // scan_time the output period, for returns measured at one instant
        for da in [0.0016f32, -0.0016] {
            let (timing, rays, how) = scan_of(640, da, 0.0, 1.0 / 30.0);
            assert_eq!(how, RayTiming::Simultaneous);
            assert!(
                rays.iter().all(|r| r.t_ns == 1_000_000_000),
                "rays spread over {} ns",
                rays[639].t_ns - rays[0].t_ns
            );
            assert_eq!(timing.start_ns, 1_000_000_000);
            // the scan period is still scan_time (1/30 as f32 prints as 0.033333335),
            // the sweep follows angle_increment
            assert_eq!(timing.period_ns, 33_333_335);
            let ccw = da > 0.0;
            assert_eq!(
                timing.rotation,
                if ccw { Rotation::Ccw } else { Rotation::Cw }
            );
            let last = wrap_pi(-0.5 + 639.0 * f64::from(da));
            assert!((rays[639].bearing_rad - last).abs() < 1e-9);
        }
    }

    #[test]
    fn a_gazebo_scan_without_time_increment_or_scan_time_is_accepted() {
        // Gazebo's ray sensors and ros_gz_bridge: an instantaneous simulated scan
        let inc = (std::f64::consts::TAU / 720.0) as f32;
        let (timing, rays, how) = scan_of(720, inc, 0.0, 0.0);
        assert_eq!(how, RayTiming::Simultaneous);
        assert!(rays.iter().all(|r| r.t_ns == 1_000_000_000));
        assert_eq!(timing.period_ns, 0);
        assert_eq!(timing.rotation, Rotation::Ccw);
        // -0 is 0, and a scan of one ray has nothing to spread
        let (_, rays, how) = scan_of(8, 0.1, -0.0, 0.0);
        assert_eq!(how, RayTiming::Simultaneous);
        assert!(rays.iter().all(|r| r.t_ns == 1_000_000_000));
        assert_eq!(scan_of(1, 0.0, 0.0, 0.0).2, RayTiming::Simultaneous);
    }

    #[test]
    fn a_time_increment_dates_each_ray_from_the_stamp() {
        let inc = (std::f64::consts::TAU / 720.0) as f32;
        for (da, rotation) in [(inc, Rotation::Ccw), (-inc, Rotation::Cw)] {
            let (timing, rays, how) = scan_of(720, da, 0.1 / 720.0, 0.1);
            assert_eq!(how, RayTiming::Increment);
            assert_eq!((timing.period_ns, timing.rotation), (100_000_000, rotation));
            // 0.1 / 720 as f32 prints as 0.00013888889: 138888.89 ns a ray
            for (i, r) in rays.iter().enumerate() {
                assert_eq!(
                    r.t_ns,
                    1_000_000_000 + (i as f64 * 138_888.89).round() as i64,
                    "ray {i}"
                );
            }
        }
        // a negative increment dates the rays back from the stamp: a sweep the
        // other way
        let (timing, rays, how) = scan_of(4, 0.1, -0.001, 0.1);
        assert_eq!(how, RayTiming::Increment);
        assert_eq!(timing.rotation, Rotation::Cw);
        let times: Vec<Nanos> = rays.iter().map(|r| r.t_ns).collect();
        assert_eq!(
            times,
            [1_000_000_000, 999_000_000, 998_000_000, 997_000_000]
        );
    }

    #[test]
    fn a_time_increment_that_is_no_number_is_refused() {
        let r = [1.0f32; 4];
        let mut rays = Vec::new();
        for (ti, want) in [
            (f32::NAN, "time_increment is NaN"),
            (f32::INFINITY, "time_increment is inf"),
            (f32::NEG_INFINITY, "time_increment is -inf"),
        ] {
            let m = LaserScan {
                angle_increment: 0.1,
                time_increment: ti,
                scan_time: 0.1,
                range_max: 10.0,
                ranges: F32Seq::from_slice(&r),
                ..LaserScan::default()
            };
            assert_eq!(laser_scan_to_rays(&m, 0, &mut rays).unwrap_err(), want);
        }
    }

    #[test]
    fn bad_scans_are_errors() {
        let r = [1.0f32, 2.0];
        let m = LaserScan {
            ranges: F32Seq::from_slice(&r),
            intensities: F32Seq::from_slice(&r[..1]),
            ..LaserScan::default()
        };
        let mut rays = Vec::new();
        assert!(laser_scan_to_rays(&m, 0, &mut rays)
            .unwrap_err()
            .contains("1 intensities for 2 ranges"));
        // rays dated over more than two turns, or 10 s without a turn: no scan
        let r = [1.0f32; 361];
        let m = LaserScan {
            ranges: F32Seq::from_slice(&r),
            angle_increment: 0.0174,
            time_increment: 0.001,
            scan_time: 0.1,
            range_max: 10.0,
            ..LaserScan::default()
        };
        let e = laser_scan_to_rays(&m, 0, &mut rays).unwrap_err();
        assert_eq!(
            e,
            "361 ranges 0.001 s apart (time_increment) span 0.360 s, more than two turns of scan_time 0.1 s"
        );
        let m = LaserScan {
            time_increment: 1e30,
            scan_time: 0.0,
            ..m
        };
        let e = laser_scan_to_rays(&m, 0, &mut rays).unwrap_err();
        assert!(e.ends_with("more than 10 s (scan_time not given)"), "{e}");
        // time_increment 0 spreads nothing, whatever the angles and scan_time
        let m = LaserScan {
            time_increment: 0.0,
            angle_increment: 1e30,
            scan_time: 0.1,
            ..m
        };
        laser_scan_to_rays(&m, 0, &mut rays).unwrap();
        assert!(rays.iter().all(|r| r.t_ns == 0));
        // one turn is a scan
        let m = LaserScan {
            angle_increment: 0.0174,
            time_increment: 0.1 / 360.0,
            scan_time: 0.1,
            ..m
        };
        laser_scan_to_rays(&m, 0, &mut rays).unwrap();
        // a turn of years would let the rays span years
        let m = LaserScan {
            time_increment: 1e8,
            scan_time: 1e9,
            ..m
        };
        let e = laser_scan_to_rays(&m, 0, &mut rays).unwrap_err();
        assert_eq!(
            e,
            "scan_time 1e9 s is more than 10 s: no scanner turns that slowly"
        );
        let m = LaserScan {
            time_increment: 0.0,
            scan_time: 10.0,
            ..m
        };
        laser_scan_to_rays(&m, 0, &mut rays).unwrap();
    }

    proptest! {
        #[test]
        fn decimal_reading_stays_within_f32_precision(bits in any::<u32>()) {
            let x = f32::from_bits(bits);
            let d = f32_as_decimal(x);
            if x.is_finite() {
                prop_assert_eq!(d as f32, x);
            } else {
                prop_assert_eq!(d.to_bits(), f64::from(x).to_bits());
            }
        }

        #[test]
        fn any_scan_values_never_panic(
            f in proptest::array::uniform7(any::<u32>()),
            ranges in proptest::collection::vec(any::<u32>(), 0..40),
            start in any::<i64>(),
        ) {
            let f = f.map(f32::from_bits);
            let r: Vec<f32> = ranges.iter().map(|&b| f32::from_bits(b)).collect();
            let m = LaserScan { angle_min: f[0], angle_max: f[1], angle_increment: f[2],
                time_increment: f[3], scan_time: f[4], range_min: f[5], range_max: f[6],
                ranges: F32Seq::from_slice(&r), ..LaserScan::default() };
            let mut rays = Vec::new();
            if laser_scan_to_rays(&m, start, &mut rays).is_ok() {
                prop_assert_eq!(rays.len(), r.len());
                for ray in &rays {
                    prop_assert!(!ray.valid || ray.range_m.is_finite());
                }
            }
        }
    }
}
