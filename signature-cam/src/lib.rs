//! Camera signature for vlsync: per frame, the optical flow in a region of
//! interest (by default the floor in front of the robot) reduced to one scalar,
//! in pixels per second, stamped at the midpoint of the two frames compared.
//!
//! Pipeline:
//!
//! 1. [`image`]: gray frames ([`image::GrayFrame`], `u8` or `f32`, borrowed or
//!    owned) and gray/RGB/BGR/RGBA/YUYV/UYVY/NV12/NV21/YU12/YV12 to gray conversion
//!    ([`image::RawFrame`]; the planar formats by their luma plane).
//! 2. [`flow`]: pyramidal Lucas-Kanade on a grid of points in the ROI, with a
//!    Shi-Tomasi texture test, each point started from its last flow (on a
//!    start, from a coarse search of the ROI's shift), tracked both ways and
//!    checked against its neighbours; allocation-free after the first frame.
//! 3. [`reduce`]: flow vectors to one number (by default the downward
//!    component over the whole grid against a learnt per-point pattern, i.e.
//!    forward motion for a camera looking at the floor; mean or median
//!    magnitude, divergence; trimmed means of the tracked points).
//! 4. [`signature`]: frames and times to [`vlsync_common::Sample`]s (midpoint
//!    stamping, mid-exposure times, px/s scaled by whole frame periods, gap
//!    restart).
//! 5. [`source`]: a directory of PNG/JPEG frames with `frames.csv`; [`v4l2`]:
//!    a V4L2 camera behind the `v4l2` cargo feature (frames its driver cannot
//!    stamp are stamped at dequeue and put back on their buffer sequence numbers'
//!    line by [`sequence_clock`]); [`pipe`]: raw frames a camera program writes to a
//!    pipe (`rpicam-vid` for a Pi camera module).
//!
//! ```
//! use vlsync_signature_cam::{FrameTime, GrayFrame, SignatureConfig, SignatureProcessor, Step};
//! let (w, h) = (160, 120);
//! let frame = |shift: f32| {
//!     let px = (0..w * h).map(|i| {
//!         let (x, y) = ((i % w) as f32, (i / w) as f32 - shift);
//!         128.0 + 50.0 * (0.3 * x + 0.1 * y).sin() + 40.0 * (0.2 * y - 0.15 * x).cos()
//!     });
//!     GrayFrame::owned_f32(w, h, px.collect()).unwrap()
//! };
//! let mut p = SignatureProcessor::new(SignatureConfig::default()).unwrap();
//! p.process(&frame(0.0), FrameTime::Instant(0)).unwrap();
//! match p.process(&frame(1.0), FrameTime::Instant(50_000_000)).unwrap() {
//!     Step::Sample(s) => {
//!         assert_eq!(s.sample.t_ns, 25_000_000); // midpoint
//!         assert!((s.sample.value - 20.0).abs() < 0.5); // 1 px down in 50 ms
//!     }
//!     Step::Started(r) => panic!("{r:?}"),
//! }
//! ```
#![forbid(unsafe_code)]
#![warn(missing_docs)]

mod error;
pub mod flow;
pub mod image;
pub mod pipe;
pub mod reduce;
pub mod sequence_clock;
pub mod signature;
pub mod source;
pub mod v4l2;

pub use error::Error;
pub use flow::{FlowConfig, FlowStats, FlowVector, PyrLk, Roi};
pub use image::{GrayFrame, Pixel, PixelFormat, RawFrame};
pub use reduce::{Reducer, Reduction};
pub use signature::{
    CamSample, FramePeriod, FrameTime, SignatureConfig, SignatureProcessor, Stamping, StartReason,
    Step,
};
pub use source::{DirSource, FrameSource, UnusableFrames, MAX_UNUSABLE_IN_ROW};
pub use v4l2::{FrameStamps, V4l2Config, V4l2Source};
