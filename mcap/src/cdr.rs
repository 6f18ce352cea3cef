//! Hand-written, bounds-checked CDR for the few ROS 2 messages vlsync reads and
//! writes: `builtin_interfaces/msg/Time`, `std_msgs/msg/Header`,
//! `sensor_msgs/msg/Image`, `sensor_msgs/msg/CompressedImage` and
//! `sensor_msgs/msg/LaserScan`.
//!
//! # Wire format (what ROS 2 puts in an MCAP message with encoding `cdr`)
//!
//! * A 4-byte **encapsulation header**: representation identifier (big-endian
//!   `u16`) and options (`u16`). ROS 2 (Fast DDS / Cyclone, XCDR1) writes
//!   `00 01 00 00` = `CDR_LE`. Only that one is accepted here; `CDR_BE`
//!   (`00 00`) and the XCDR2 identifiers are rejected with a clear error.
//! * The body, little-endian. Every primitive is aligned to its own size
//!   (at most 4 here: no message below has an 8-byte field), **measured from the
//!   end of the encapsulation header**, padding bytes inserted before it.
//! * `string`: `u32` length that *includes* the terminating NUL, the bytes, the
//!   NUL. An empty string is `01 00 00 00 00`; a length of 0 is accepted when
//!   reading, as some writers emit it.
//! * `T[]` (unbounded sequence): `u32` element count, then the elements, the
//!   first aligned to the element size.
//! * A nested message is its fields in order, with no header or padding of its own.
//!
//! Field order follows the message definitions in `ros2/common_interfaces`
//! (`sensor_msgs/msg/Image.msg`: header, height, width, encoding, is_bigendian,
//! step, data; `CompressedImage.msg`: header, format, data; `LaserScan.msg`:
//! header, angle_min, angle_max, angle_increment, time_increment, scan_time,
//! range_min, range_max, ranges, intensities; `std_msgs/msg/Header.msg`: stamp,
//! frame_id; `builtin_interfaces/msg/Time.msg`: `int32 sec`, `uint32 nanosec`).
//! The alignment and string rules are those of OMG CDR (CORBA 3.4 part 2,
//! §9.3 "CDR Transfer Syntax") as implemented by e.g. the `cdr-encoding`
//! crate used by RustDDS, and by eProsima Fast-CDR.
//!
//! Decoding borrows: strings, byte arrays and `float32[]` stay in the message
//! buffer ([`F32Seq`] reads its elements on access), so decoding allocates nothing.
//! Every read is bounds-checked; a length that runs past the buffer is an error
//! naming the field and the byte offset.
//!
//! ```
//! use vlsync_mcap::cdr::{CdrMessage, Header, Image, Time};
//! let img = Image {
//!     header: Header { stamp: Time { sec: 12, nanosec: 5 }, frame_id: "cam" },
//!     height: 1, width: 2, encoding: "mono8", is_bigendian: 0, step: 2, data: &[7, 9],
//! };
//! let mut buf = Vec::new();
//! img.encode(&mut buf).unwrap();
//! assert_eq!(&buf[..4], &[0, 1, 0, 0]); // CDR_LE encapsulation
//! assert_eq!(Image::decode(&buf).unwrap(), img);
//! assert!(Image::decode(&buf[..buf.len() - 1]).is_err());
//! ```

use std::fmt;
use vlsync_common::Nanos;

/// The encapsulation header ROS 2 writes: `CDR_LE`, no options.
pub const CDR_LE_HEADER: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// What went wrong while decoding or encoding a CDR message.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CdrErrorKind {
    /// The buffer ends before the field does.
    Truncated {
        /// Bytes the field needs from `offset`.
        need: u64,
        /// Bytes left from `offset`.
        left: usize,
    },
    /// The buffer is shorter than the 4-byte encapsulation header.
    NoEncapsulation,
    /// An encapsulation other than `CDR_LE` (the two identifier bytes).
    UnsupportedEncapsulation([u8; 2]),
    /// A string whose last byte is not NUL.
    NotNulTerminated,
    /// A string that is not UTF-8.
    InvalidUtf8,
    /// A value that does not fit the wire type (e.g. a sequence longer than `u32::MAX`).
    TooLong(usize),
}

/// A CDR error: the field, its byte offset in the message and what is wrong.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CdrError {
    /// Field path, e.g. `header.frame_id` or `ranges`.
    pub field: &'static str,
    /// Byte offset in the whole message (encapsulation header included).
    pub offset: usize,
    /// What is wrong.
    pub kind: CdrErrorKind,
}

impl fmt::Display for CdrError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "CDR field `{}` at byte {}: ", self.field, self.offset)?;
        match &self.kind {
            CdrErrorKind::Truncated { need, left } => {
                write!(f, "needs {need} bytes but only {left} are left")
            }
            CdrErrorKind::NoEncapsulation => {
                write!(f, "message shorter than the 4-byte encapsulation header")
            }
            CdrErrorKind::UnsupportedEncapsulation(id) => write!(
                f,
                "encapsulation {:02x} {:02x} is not supported (only CDR_LE 00 01)",
                id[0], id[1]
            ),
            CdrErrorKind::NotNulTerminated => write!(f, "string is not NUL-terminated"),
            CdrErrorKind::InvalidUtf8 => write!(f, "string is not UTF-8"),
            CdrErrorKind::TooLong(n) => write!(f, "length {n} does not fit a CDR u32"),
        }
    }
}

impl std::error::Error for CdrError {}

/// A bounds-checked little-endian CDR reader over one message.
#[derive(Debug, Clone)]
pub struct CdrReader<'a> {
    /// The body (after the encapsulation header); alignment is relative to its start.
    body: &'a [u8],
    pos: usize,
}

/// Offset of the body in the whole message, for error messages.
const BODY_OFFSET: usize = 4;

impl<'a> CdrReader<'a> {
    /// Checks the encapsulation header (`CDR_LE`) and starts reading the body.
    pub fn new(message: &'a [u8]) -> Result<Self, CdrError> {
        let err = |kind| CdrError {
            field: "encapsulation",
            offset: 0,
            kind,
        };
        let (head, body) = match message.split_first_chunk::<4>() {
            Some((h, b)) => (h, b),
            None => return Err(err(CdrErrorKind::NoEncapsulation)),
        };
        if head[0..2] != CDR_LE_HEADER[0..2] {
            return Err(err(CdrErrorKind::UnsupportedEncapsulation([
                head[0], head[1],
            ])));
        }
        Ok(Self { body, pos: 0 })
    }

    /// Bytes of the body not read yet (trailing padding is allowed and ignored).
    pub fn remaining(&self) -> usize {
        self.body.len() - self.pos
    }

    fn truncated(&self, field: &'static str, need: u64) -> CdrError {
        CdrError {
            field,
            offset: BODY_OFFSET + self.pos,
            kind: CdrErrorKind::Truncated {
                need,
                left: self.remaining(),
            },
        }
    }

    fn align(&mut self, n: usize, field: &'static str) -> Result<(), CdrError> {
        let pad = (n - self.pos % n) % n;
        if pad > self.remaining() {
            return Err(self.truncated(field, pad as u64));
        }
        self.pos += pad;
        Ok(())
    }

    fn take(&mut self, n: u64, field: &'static str) -> Result<&'a [u8], CdrError> {
        match usize::try_from(n) {
            Ok(k) if k <= self.remaining() => {
                let s = &self.body[self.pos..self.pos + k];
                self.pos += k;
                Ok(s)
            }
            _ => Err(self.truncated(field, n)),
        }
    }

    fn array<const N: usize>(&mut self, field: &'static str) -> Result<[u8; N], CdrError> {
        self.align(N, field)?;
        let s = self.take(N as u64, field)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    /// An `uint8`.
    pub fn u8(&mut self, field: &'static str) -> Result<u8, CdrError> {
        Ok(self.array::<1>(field)?[0])
    }

    /// An `uint32` (aligned to 4).
    pub fn u32(&mut self, field: &'static str) -> Result<u32, CdrError> {
        self.array::<4>(field).map(u32::from_le_bytes)
    }

    /// An `int32` (aligned to 4).
    pub fn i32(&mut self, field: &'static str) -> Result<i32, CdrError> {
        self.array::<4>(field).map(i32::from_le_bytes)
    }

    /// A `float32` (aligned to 4).
    pub fn f32(&mut self, field: &'static str) -> Result<f32, CdrError> {
        self.array::<4>(field).map(f32::from_le_bytes)
    }

    /// A `string`, borrowed, without its NUL.
    pub fn string(&mut self, field: &'static str) -> Result<&'a str, CdrError> {
        let len = self.u32(field)?;
        let at = BODY_OFFSET + self.pos;
        let bytes = self.take(u64::from(len), field)?;
        let text = match bytes.split_last() {
            None => bytes,
            Some((0, text)) => text,
            Some(_) => {
                return Err(CdrError {
                    field,
                    offset: at,
                    kind: CdrErrorKind::NotNulTerminated,
                })
            }
        };
        std::str::from_utf8(text).map_err(|_| CdrError {
            field,
            offset: at,
            kind: CdrErrorKind::InvalidUtf8,
        })
    }

    /// A `uint8[]`, borrowed.
    pub fn bytes(&mut self, field: &'static str) -> Result<&'a [u8], CdrError> {
        let n = self.u32(field)?;
        self.take(u64::from(n), field)
    }

    /// A `float32[]`, borrowed.
    pub fn f32_seq(&mut self, field: &'static str) -> Result<F32Seq<'a>, CdrError> {
        let n = self.u32(field)?;
        // an empty sequence has no element to align
        if n == 0 {
            return Ok(F32Seq::EMPTY);
        }
        self.align(4, field)?;
        let b = self.take(u64::from(n) * 4, field)?;
        Ok(F32Seq(Repr::Le(b)))
    }
}

/// A little-endian CDR writer appending to a `Vec` (which it clears first).
#[derive(Debug)]
pub struct CdrWriter<'b> {
    out: &'b mut Vec<u8>,
}

impl<'b> CdrWriter<'b> {
    /// Clears `out` (keeping its capacity) and writes the `CDR_LE` encapsulation header.
    pub fn new(out: &'b mut Vec<u8>) -> Self {
        out.clear();
        out.extend_from_slice(&CDR_LE_HEADER);
        Self { out }
    }

    fn align(&mut self, n: usize) {
        while !(self.out.len() - BODY_OFFSET).is_multiple_of(n) {
            self.out.push(0);
        }
    }

    fn len32(&self, n: usize, field: &'static str) -> Result<u32, CdrError> {
        u32::try_from(n).map_err(|_| CdrError {
            field,
            offset: self.out.len(),
            kind: CdrErrorKind::TooLong(n),
        })
    }

    /// An `uint8`.
    pub fn u8(&mut self, v: u8) {
        self.out.push(v);
    }

    /// An `uint32`.
    pub fn u32(&mut self, v: u32) {
        self.align(4);
        self.out.extend_from_slice(&v.to_le_bytes());
    }

    /// An `int32`.
    pub fn i32(&mut self, v: i32) {
        self.align(4);
        self.out.extend_from_slice(&v.to_le_bytes());
    }

    /// A `float32`.
    pub fn f32(&mut self, v: f32) {
        self.align(4);
        self.out.extend_from_slice(&v.to_le_bytes());
    }

    /// A `string` (length includes the NUL written after it).
    pub fn string(&mut self, s: &str, field: &'static str) -> Result<(), CdrError> {
        let n = self.len32(s.len() + 1, field)?;
        self.u32(n);
        self.out.extend_from_slice(s.as_bytes());
        self.out.push(0);
        Ok(())
    }

    /// A `uint8[]`.
    pub fn bytes(&mut self, b: &[u8], field: &'static str) -> Result<(), CdrError> {
        let n = self.len32(b.len(), field)?;
        self.u32(n);
        self.out.extend_from_slice(b);
        Ok(())
    }

    /// A `float32[]`.
    pub fn f32_seq(&mut self, s: &F32Seq<'_>, field: &'static str) -> Result<(), CdrError> {
        let n = self.len32(s.len(), field)?;
        self.u32(n);
        match s.0 {
            Repr::Le(b) => self.out.extend_from_slice(b),
            Repr::Slice(v) => {
                for x in v {
                    self.out.extend_from_slice(&x.to_le_bytes());
                }
            }
        }
        Ok(())
    }
}

#[derive(Clone, Copy)]
enum Repr<'a> {
    /// Little-endian bytes, length a multiple of 4.
    Le(&'a [u8]),
    Slice(&'a [f32]),
}

/// A `float32[]`: borrowed from a decoded message, or from a caller's slice for encoding.
#[derive(Clone, Copy)]
pub struct F32Seq<'a>(Repr<'a>);

impl<'a> F32Seq<'a> {
    /// The empty sequence.
    pub const EMPTY: F32Seq<'static> = F32Seq(Repr::Slice(&[]));

    /// Wraps a slice (for encoding).
    pub fn from_slice(v: &'a [f32]) -> Self {
        Self(Repr::Slice(v))
    }

    /// Number of elements.
    pub fn len(&self) -> usize {
        match self.0 {
            Repr::Le(b) => b.len() / 4,
            Repr::Slice(v) => v.len(),
        }
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Element `i`, `None` past the end.
    pub fn get(&self, i: usize) -> Option<f32> {
        match self.0 {
            Repr::Le(b) => {
                let c = b.get(i.checked_mul(4)?..)?.first_chunk::<4>()?;
                Some(f32::from_le_bytes(*c))
            }
            Repr::Slice(v) => v.get(i).copied(),
        }
    }

    /// The elements in order.
    pub fn iter(&self) -> impl Iterator<Item = f32> + 'a {
        let this = *self;
        (0..this.len()).filter_map(move |i| this.get(i))
    }

    /// The elements as a vector.
    pub fn to_vec(&self) -> Vec<f32> {
        self.iter().collect()
    }
}

impl fmt::Debug for F32Seq<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_list().entries(self.iter()).finish()
    }
}

/// Equal when the elements are bit for bit equal (so NaN payloads compare too).
impl PartialEq for F32Seq<'_> {
    fn eq(&self, other: &Self) -> bool {
        self.len() == other.len()
            && self
                .iter()
                .zip(other.iter())
                .all(|(a, b)| a.to_bits() == b.to_bits())
    }
}

/// A ROS 2 message this module can decode and encode.
pub trait CdrMessage<'a>: Sized {
    /// The MCAP schema name, e.g. `sensor_msgs/msg/Image`.
    const SCHEMA_NAME: &'static str;
    /// The `ros2msg` schema text (the definition and its dependencies).
    const SCHEMA_TEXT: &'static str;

    /// Reads the fields from `r`.
    fn read(r: &mut CdrReader<'a>) -> Result<Self, CdrError>;
    /// Writes the fields to `w`.
    fn write(&self, w: &mut CdrWriter<'_>) -> Result<(), CdrError>;

    /// Decodes a whole message (encapsulation header included). Trailing bytes
    /// (padding) are ignored.
    fn decode(message: &'a [u8]) -> Result<Self, CdrError> {
        let mut r = CdrReader::new(message)?;
        Self::read(&mut r)
    }

    /// Encodes into `out` (cleared first), encapsulation header included.
    fn encode(&self, out: &mut Vec<u8>) -> Result<(), CdrError> {
        let mut w = CdrWriter::new(out);
        self.write(&mut w)
    }
}

/// `builtin_interfaces/msg/Time`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Time {
    /// Seconds.
    pub sec: i32,
    /// Nanoseconds, `< 1_000_000_000` for a well-formed stamp (not enforced when
    /// reading: `rclcpp` adds it to the seconds whatever it is, and so does
    /// [`Time::to_nanos`]).
    pub nanosec: u32,
}

impl Time {
    /// `sec * 1e9 + nanosec` (cannot overflow: |sec| < 2^31).
    pub fn to_nanos(self) -> Nanos {
        i64::from(self.sec) * 1_000_000_000 + i64::from(self.nanosec)
    }

    /// The stamp of `ns` nanoseconds (`nanosec` in `0..1e9`), `None` when the
    /// seconds do not fit ROS 2's `int32`.
    pub fn from_nanos(ns: Nanos) -> Option<Self> {
        let sec = i32::try_from(ns.div_euclid(1_000_000_000)).ok()?;
        let nanosec = ns.rem_euclid(1_000_000_000) as u32;
        Some(Self { sec, nanosec })
    }
}

const TIME_TEXT: &str = "int32 sec\nuint32 nanosec\n";

impl<'a> CdrMessage<'a> for Time {
    const SCHEMA_NAME: &'static str = "builtin_interfaces/msg/Time";
    const SCHEMA_TEXT: &'static str = TIME_TEXT;
    fn read(r: &mut CdrReader<'a>) -> Result<Self, CdrError> {
        Ok(Self {
            sec: r.i32("stamp.sec")?,
            nanosec: r.u32("stamp.nanosec")?,
        })
    }
    fn write(&self, w: &mut CdrWriter<'_>) -> Result<(), CdrError> {
        w.i32(self.sec);
        w.u32(self.nanosec);
        Ok(())
    }
}

/// `std_msgs/msg/Header`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Header<'a> {
    /// Time of the data (acquisition time for sensors).
    pub stamp: Time,
    /// Coordinate frame.
    pub frame_id: &'a str,
}

macro_rules! header_schema {
    () => {
        concat!(
            "\n================================================================================\n",
            "MSG: std_msgs/Header\n",
            "builtin_interfaces/Time stamp\nstring frame_id\n",
            "\n================================================================================\n",
            "MSG: builtin_interfaces/Time\n",
            "int32 sec\nuint32 nanosec\n"
        )
    };
}

impl<'a> CdrMessage<'a> for Header<'a> {
    const SCHEMA_NAME: &'static str = "std_msgs/msg/Header";
    const SCHEMA_TEXT: &'static str = concat!(
        "builtin_interfaces/Time stamp\nstring frame_id\n",
        "\n================================================================================\n",
        "MSG: builtin_interfaces/Time\n",
        "int32 sec\nuint32 nanosec\n"
    );
    fn read(r: &mut CdrReader<'a>) -> Result<Self, CdrError> {
        Ok(Self {
            stamp: Time::read(r)?,
            frame_id: r.string("header.frame_id")?,
        })
    }
    fn write(&self, w: &mut CdrWriter<'_>) -> Result<(), CdrError> {
        self.stamp.write(w)?;
        w.string(self.frame_id, "header.frame_id")
    }
}

/// `sensor_msgs/msg/Image`: an uncompressed image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Image<'a> {
    /// `stamp` = acquisition time of the image.
    pub header: Header<'a>,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// Pixel encoding, e.g. `mono8`, `rgb8`, `bgr8`, `rgba8`, `yuv422_yuy2`.
    pub encoding: &'a str,
    /// Non-zero when multi-byte pixels are big-endian.
    pub is_bigendian: u8,
    /// Bytes per row.
    pub step: u32,
    /// Pixel bytes, `step * height` of them.
    pub data: &'a [u8],
}

impl<'a> CdrMessage<'a> for Image<'a> {
    const SCHEMA_NAME: &'static str = "sensor_msgs/msg/Image";
    const SCHEMA_TEXT: &'static str = concat!(
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\n",
        "uint8 is_bigendian\nuint32 step\nuint8[] data\n",
        header_schema!()
    );
    fn read(r: &mut CdrReader<'a>) -> Result<Self, CdrError> {
        Ok(Self {
            header: Header::read(r)?,
            height: r.u32("height")?,
            width: r.u32("width")?,
            encoding: r.string("encoding")?,
            is_bigendian: r.u8("is_bigendian")?,
            step: r.u32("step")?,
            data: r.bytes("data")?,
        })
    }
    fn write(&self, w: &mut CdrWriter<'_>) -> Result<(), CdrError> {
        self.header.write(w)?;
        w.u32(self.height);
        w.u32(self.width);
        w.string(self.encoding, "encoding")?;
        w.u8(self.is_bigendian);
        w.u32(self.step);
        w.bytes(self.data, "data")
    }
}

/// `sensor_msgs/msg/CompressedImage`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CompressedImage<'a> {
    /// `stamp` = acquisition time of the image.
    pub header: Header<'a>,
    /// e.g. `jpeg`, `png`, `bgr8; jpeg compressed bgr8`.
    pub format: &'a str,
    /// The compressed bytes.
    pub data: &'a [u8],
}

impl<'a> CdrMessage<'a> for CompressedImage<'a> {
    const SCHEMA_NAME: &'static str = "sensor_msgs/msg/CompressedImage";
    const SCHEMA_TEXT: &'static str = concat!(
        "std_msgs/Header header\nstring format\nuint8[] data\n",
        header_schema!()
    );
    fn read(r: &mut CdrReader<'a>) -> Result<Self, CdrError> {
        Ok(Self {
            header: Header::read(r)?,
            format: r.string("format")?,
            data: r.bytes("data")?,
        })
    }
    fn write(&self, w: &mut CdrWriter<'_>) -> Result<(), CdrError> {
        self.header.write(w)?;
        w.string(self.format, "format")?;
        w.bytes(self.data, "data")
    }
}

/// `sensor_msgs/msg/LaserScan`: one scan of a planar range finder.
///
/// ROS conventions (from `LaserScan.msg`): `header.stamp` is the acquisition
/// time of the **first** ray; angles are about +Z, counter-clockwise positive,
/// 0 forward along +X; ray `i` is at `angle_min + i * angle_increment` and was
/// measured `i * time_increment` seconds after the stamp; a range outside
/// `[range_min, range_max]` is to be discarded.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LaserScan<'a> {
    /// `stamp` = time of the first ray.
    pub header: Header<'a>,
    /// Angle of the first ray, rad.
    pub angle_min: f32,
    /// Angle of the last ray, rad.
    pub angle_max: f32,
    /// Angle between rays, rad.
    pub angle_increment: f32,
    /// Time between rays, s.
    pub time_increment: f32,
    /// Time between scans, s.
    pub scan_time: f32,
    /// Minimum valid range, m.
    pub range_min: f32,
    /// Maximum valid range, m.
    pub range_max: f32,
    /// Ranges, m.
    pub ranges: F32Seq<'a>,
    /// Intensities (device units); empty when the device has none.
    pub intensities: F32Seq<'a>,
}

impl Default for F32Seq<'_> {
    fn default() -> Self {
        F32Seq::EMPTY
    }
}

impl<'a> CdrMessage<'a> for LaserScan<'a> {
    const SCHEMA_NAME: &'static str = "sensor_msgs/msg/LaserScan";
    const SCHEMA_TEXT: &'static str = concat!(
        "std_msgs/Header header\nfloat32 angle_min\nfloat32 angle_max\nfloat32 angle_increment\n",
        "float32 time_increment\nfloat32 scan_time\nfloat32 range_min\nfloat32 range_max\n",
        "float32[] ranges\nfloat32[] intensities\n",
        header_schema!()
    );
    fn read(r: &mut CdrReader<'a>) -> Result<Self, CdrError> {
        Ok(Self {
            header: Header::read(r)?,
            angle_min: r.f32("angle_min")?,
            angle_max: r.f32("angle_max")?,
            angle_increment: r.f32("angle_increment")?,
            time_increment: r.f32("time_increment")?,
            scan_time: r.f32("scan_time")?,
            range_min: r.f32("range_min")?,
            range_max: r.f32("range_max")?,
            ranges: r.f32_seq("ranges")?,
            intensities: r.f32_seq("intensities")?,
        })
    }
    fn write(&self, w: &mut CdrWriter<'_>) -> Result<(), CdrError> {
        self.header.write(w)?;
        for v in [
            self.angle_min,
            self.angle_max,
            self.angle_increment,
            self.time_increment,
            self.scan_time,
            self.range_min,
            self.range_max,
        ] {
            w.f32(v);
        }
        w.f32_seq(&self.ranges, "ranges")?;
        w.f32_seq(&self.intensities, "intensities")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn image_bytes_match_a_hand_layout() {
        let img = Image {
            header: Header {
                stamp: Time { sec: 1, nanosec: 2 },
                frame_id: "ab",
            },
            height: 3,
            width: 4,
            encoding: "mono8",
            is_bigendian: 0,
            step: 4,
            data: &[9; 12],
        };
        let mut buf = Vec::new();
        img.encode(&mut buf).unwrap();
        let mut want = vec![0, 1, 0, 0];
        want.extend_from_slice(&1i32.to_le_bytes());
        want.extend_from_slice(&2u32.to_le_bytes());
        want.extend_from_slice(&3u32.to_le_bytes()); // "ab\0" length 3
        want.extend_from_slice(b"ab\0");
        want.push(0); // pad to 4 (body offset 12 -> 15, pad to 16)
        want.extend_from_slice(&3u32.to_le_bytes()); // height
        want.extend_from_slice(&4u32.to_le_bytes()); // width
        want.extend_from_slice(&6u32.to_le_bytes()); // "mono8\0"
        want.extend_from_slice(b"mono8\0");
        want.push(0); // is_bigendian at body 34 (a u8 needs no alignment)
        want.push(0); // pad to 36 for step
        want.extend_from_slice(&4u32.to_le_bytes()); // step
        want.extend_from_slice(&12u32.to_le_bytes());
        want.extend_from_slice(&[9; 12]);
        assert_eq!(buf, want);
        assert_eq!(Image::decode(&buf).unwrap(), img);
    }

    #[test]
    fn laser_scan_round_trip_and_alignment() {
        let ranges = [1.0f32, f32::INFINITY, f32::NAN];
        let scan = LaserScan {
            header: Header {
                stamp: Time {
                    sec: -3,
                    nanosec: 999_999_999,
                },
                frame_id: "laser",
            },
            angle_min: -1.5,
            angle_max: 1.5,
            angle_increment: 1.5,
            time_increment: 1e-4,
            scan_time: 0.1,
            range_min: 0.1,
            range_max: 12.0,
            ranges: F32Seq::from_slice(&ranges),
            intensities: F32Seq::EMPTY,
        };
        let mut buf = Vec::new();
        scan.encode(&mut buf).unwrap();
        let back = LaserScan::decode(&buf).unwrap();
        assert_eq!(back, scan);
        assert!(back.ranges.get(2).unwrap().is_nan());
        assert_eq!(back.ranges.get(3), None);
        // "laser\0" is 6 bytes: body 12+6 = 18, padded to 20 before angle_min
        assert_eq!(&buf[4 + 18..4 + 20], &[0, 0]);
        assert_eq!(&buf[4 + 20..4 + 24], &(-1.5f32).to_le_bytes());
    }

    #[test]
    fn errors_name_field_and_offset() {
        let img = CompressedImage {
            header: Header::default(),
            format: "png",
            data: &[1, 2, 3],
        };
        let mut buf = Vec::new();
        img.encode(&mut buf).unwrap();
        let e = CompressedImage::decode(&buf[..buf.len() - 1]).unwrap_err();
        assert_eq!(e.field, "data");
        assert!(e.to_string().contains("needs 3 bytes but only 2"), "{e}");
        // a length far beyond the buffer
        let mut bad = buf.clone();
        let n = bad.len();
        bad[n - 7..n - 3].copy_from_slice(&u32::MAX.to_le_bytes());
        let e = CompressedImage::decode(&bad).unwrap_err();
        assert!(
            matches!(
                e.kind,
                CdrErrorKind::Truncated {
                    need: 4294967295,
                    ..
                }
            ),
            "{e}"
        );
        // big-endian encapsulation
        let mut be = buf.clone();
        be[1] = 0;
        let e = CompressedImage::decode(&be).unwrap_err();
        assert!(e.to_string().contains("00 00 is not supported"), "{e}");
        assert_eq!(
            Time::decode(&[0, 1]).unwrap_err().kind,
            CdrErrorKind::NoEncapsulation
        );
        // string without its NUL
        let mut nonul = buf.clone();
        nonul[4 + 23] = b'x'; // the NUL of "png" (format length at body 16)
        assert_eq!(
            CompressedImage::decode(&nonul).unwrap_err().kind,
            CdrErrorKind::NotNulTerminated
        );
    }

    #[test]
    fn empty_string_forms() {
        // length 1 + NUL (what Fast-CDR writes) and length 0 (tolerated)
        let a = [0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0];
        let b = [0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0];
        assert_eq!(Header::decode(&a).unwrap().frame_id, "");
        assert_eq!(Header::decode(&b).unwrap().frame_id, "");
    }

    #[test]
    fn time_conversions() {
        assert_eq!(
            Time::from_nanos(-1),
            Some(Time {
                sec: -1,
                nanosec: 999_999_999
            })
        );
        assert_eq!(Time::from_nanos(-1).unwrap().to_nanos(), -1);
        assert_eq!(Time::from_nanos(i64::MAX), None);
    }

    #[test]
    fn schema_texts_list_dependencies() {
        assert!(Image::SCHEMA_TEXT.contains("MSG: std_msgs/Header"));
        assert!(LaserScan::SCHEMA_TEXT.contains("MSG: builtin_interfaces/Time"));
        assert!(Header::SCHEMA_TEXT.starts_with("builtin_interfaces/Time stamp\n"));
        assert!(Time::SCHEMA_TEXT == TIME_TEXT);
        assert!(Image::SCHEMA_TEXT.contains(&format!("\n{}\nMSG: ", "=".repeat(80))));
    }

    fn arb_time() -> impl Strategy<Value = Time> {
        (any::<i32>(), any::<u32>()).prop_map(|(sec, nanosec)| Time { sec, nanosec })
    }

    proptest! {
        #[test]
        fn decoders_never_panic(data in proptest::collection::vec(any::<u8>(), 0..300)) {
            let _ = Time::decode(&data);
            let _ = Header::decode(&data);
            let _ = Image::decode(&data);
            let _ = CompressedImage::decode(&data);
            let _ = LaserScan::decode(&data);
            // and with a valid encapsulation header in front
            let mut d = CDR_LE_HEADER.to_vec();
            d.extend_from_slice(&data);
            let _ = Image::decode(&d);
            let _ = CompressedImage::decode(&d);
            if let Ok(s) = LaserScan::decode(&d) {
                let _ = s.ranges.to_vec();
                let _ = s.intensities.get(usize::MAX);
            }
        }

        #[test]
        fn image_round_trip(
            t in arb_time(), frame in "\\PC{0,12}", enc in "[a-z0-9_]{0,12}",
            h in any::<u32>(), w in any::<u32>(), be in any::<u8>(), step in any::<u32>(),
            data in proptest::collection::vec(any::<u8>(), 0..64),
        ) {
            let img = Image { header: Header { stamp: t, frame_id: &frame }, height: h, width: w,
                encoding: &enc, is_bigendian: be, step, data: &data };
            let mut buf = Vec::new();
            img.encode(&mut buf).unwrap();
            prop_assert_eq!(Image::decode(&buf).unwrap(), img);
            // every strict prefix fails cleanly
            for cut in 0..buf.len() {
                prop_assert!(Image::decode(&buf[..cut]).is_err());
            }
        }

        #[test]
        fn compressed_round_trip(
            t in arb_time(), frame in "\\PC{0,12}", fmt in "\\PC{0,20}",
            data in proptest::collection::vec(any::<u8>(), 0..64),
        ) {
            let img = CompressedImage { header: Header { stamp: t, frame_id: &frame }, format: &fmt, data: &data };
            let mut buf = Vec::new();
            img.encode(&mut buf).unwrap();
            prop_assert_eq!(CompressedImage::decode(&buf).unwrap(), img);
        }

        #[test]
        fn scan_round_trip(
            t in arb_time(), frame in "\\PC{0,12}",
            f in proptest::array::uniform7(any::<u32>()),
            ranges in proptest::collection::vec(any::<u32>(), 0..50),
            intens in proptest::collection::vec(any::<u32>(), 0..50),
        ) {
            let r: Vec<f32> = ranges.iter().map(|&b| f32::from_bits(b)).collect();
            let i: Vec<f32> = intens.iter().map(|&b| f32::from_bits(b)).collect();
            let f = f.map(f32::from_bits);
            let scan = LaserScan { header: Header { stamp: t, frame_id: &frame },
                angle_min: f[0], angle_max: f[1], angle_increment: f[2], time_increment: f[3],
                scan_time: f[4], range_min: f[5], range_max: f[6],
                ranges: F32Seq::from_slice(&r), intensities: F32Seq::from_slice(&i) };
            let mut buf = Vec::new();
            scan.encode(&mut buf).unwrap();
            let back = LaserScan::decode(&buf).unwrap();
            prop_assert_eq!(back.header, scan.header);
            prop_assert_eq!(back.ranges, scan.ranges);
            prop_assert_eq!(back.intensities, scan.intensities);
            let g = [back.angle_min, back.angle_max, back.angle_increment, back.time_increment,
                back.scan_time, back.range_min, back.range_max];
            prop_assert_eq!(g.map(f32::to_bits), f.map(f32::to_bits));
        }
    }
}
