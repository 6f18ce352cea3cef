//! The one error type of this crate. Every variant names what was wrong and where.

use std::fmt;
use std::path::PathBuf;

/// Everything that can go wrong in the camera signature.
#[derive(Debug)]
#[non_exhaustive]
pub enum Error {
    /// A configuration value is out of range.
    InvalidConfig {
        /// Field name, e.g. `flow.window`.
        field: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// Frame dimensions that cannot describe an image (zero, overflow, odd YUYV width).
    BadDimensions {
        /// Frame width in pixels.
        width: usize,
        /// Frame height in pixels.
        height: usize,
        /// What is wrong.
        reason: &'static str,
    },
    /// A pixel buffer whose length does not match its declared geometry.
    BufferSize {
        /// What the buffer holds, e.g. `YUYV 640x480 (stride 1280)`.
        what: String,
        /// Minimum length in elements.
        expected: usize,
        /// Actual length in elements.
        actual: usize,
    },
    /// The frame is too small for the configured ROI, margin and pyramid.
    FrameTooSmall {
        /// Frame width in pixels.
        width: usize,
        /// Frame height in pixels.
        height: usize,
        /// Which requirement failed.
        reason: String,
    },
    /// An I/O error on a named file.
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// A malformed line in a text file.
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        reason: String,
    },
    /// A frame file listed in the timestamps file does not exist.
    MissingFrame {
        /// The missing frame file.
        path: PathBuf,
        /// The timestamps file that lists it.
        listed_in: PathBuf,
        /// 1-based line number in `listed_in`.
        line: usize,
    },
    /// An image file that could not be decoded.
    Decode {
        /// The image file.
        path: PathBuf,
        /// Decoder message.
        reason: String,
    },
    /// A source file that cannot be read on, as a whole rather than one image (a
    /// recording that is malformed or truncated).
    Read {
        /// The file.
        path: PathBuf,
        /// What went wrong, and where in the file.
        reason: String,
    },
    /// A frame time that cannot be used (e.g. a negative exposure duration).
    BadFrameTime {
        /// What is wrong.
        reason: String,
    },
    /// The video device does not exist.
    NoDevice {
        /// The device path, e.g. `/dev/video0`.
        path: PathBuf,
    },
    /// The video device exists but cannot be used (or V4L2 support was not built).
    Device {
        /// The device path.
        path: PathBuf,
        /// What went wrong.
        reason: String,
    },
    /// The video device delivered no frame for `after` (a camera that hung, or
    /// stopped streaming): a reopen of the device may bring it back.
    Stalled {
        /// The device path.
        path: PathBuf,
        /// How long it has been silent.
        after: std::time::Duration,
    },
}

impl Error {
    /// Whether the error is one frame's, so that a stream can go on with the next
    /// one: an image that cannot be decoded or used (a recording's corrupt file or
    /// message, [`Error::Decode`]), a frame file that went missing or cannot be read
    /// ([`Error::MissingFrame`], [`Error::Io`]: sources raise them only for frame
    /// files once open). A stream's own faults (a device error, a malformed or
    /// truncated recording, a pixel format that cannot be converted) are not.
    pub fn is_one_frame(&self) -> bool {
        matches!(
            self,
            Error::Decode { .. } | Error::MissingFrame { .. } | Error::Io { .. }
        )
    }
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::InvalidConfig { field, reason } => {
                write!(f, "invalid configuration `{field}`: {reason}")
            }
            Error::BadDimensions {
                width,
                height,
                reason,
            } => write!(f, "bad frame dimensions {width}x{height}: {reason}"),
            Error::BufferSize {
                what,
                expected,
                actual,
            } => write!(
                f,
                "pixel buffer for {what} too short: need {expected} elements, got {actual}"
            ),
            Error::FrameTooSmall {
                width,
                height,
                reason,
            } => write!(f, "frame {width}x{height} too small: {reason}"),
            Error::Io { path, source } => write!(f, "{}: {source}", path.display()),
            Error::Parse { path, line, reason } => {
                write!(f, "{}:{line}: {reason}", path.display())
            }
            Error::MissingFrame {
                path,
                listed_in,
                line,
            } => write!(
                f,
                "{}: frame file not found (listed at {}:{line})",
                path.display(),
                listed_in.display()
            ),
            Error::Decode { path, reason } => {
                write!(f, "{}: cannot decode image: {reason}", path.display())
            }
            Error::Read { path, reason } => write!(f, "{}: {reason}", path.display()),
            Error::BadFrameTime { reason } => write!(f, "bad frame time: {reason}"),
            Error::NoDevice { path } => write!(f, "{}: no such device", path.display()),
            Error::Device { path, reason } => write!(f, "{}: {reason}", path.display()),
            Error::Stalled { path, after } => write!(
                f,
                "{}: no frame for {:.1} s (the camera stalled: unplugged, a hung USB link, or a \
                 camera program that stopped writing)",
                path.display(),
                after.as_secs_f64()
            ),
        }
    }
}

impl std::error::Error for Error {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Error::Io { source, .. } => Some(source),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_name_the_culprit() {
        let e = Error::NoDevice {
            path: "/dev/video0".into(),
        };
        assert_eq!(e.to_string(), "/dev/video0: no such device");
        let e = Error::Parse {
            path: "d/frames.csv".into(),
            line: 7,
            reason: "bad time".into(),
        };
        assert_eq!(e.to_string(), "d/frames.csv:7: bad time");
        let e = Error::MissingFrame {
            path: "d/a.png".into(),
            listed_in: "d/frames.csv".into(),
            line: 3,
        };
        assert!(e.to_string().contains("d/a.png"));
        assert!(e.to_string().contains("frames.csv:3"));
        let e = Error::Read {
            path: "r.mcap".into(),
            reason: "the file is truncated".into(),
        };
        assert_eq!(e.to_string(), "r.mcap: the file is truncated");
    }
}
