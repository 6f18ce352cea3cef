//! Pyramidal Lucas-Kanade sparse optical flow on a regular grid of points in a ROI.
//!
//! Each frame, a fixed grid of `grid_cols x grid_rows` points inside the ROI is
//! tracked from the previous frame to the current one (points are not carried
//! over: the grid is the same every frame, which is what a per-frame motion
//! signature needs). Points whose window has a weak gradient in some direction
//! (Shi-Tomasi minimum eigenvalue of the structure tensor below
//! [`FlowConfig::min_eigen`]) are skipped.
//!
//! Each window is normalised photometrically (mean and contrast matched to the
//! previous frame's window at every iteration), so auto-exposure and gain
//! changes between frames do not bias the flow.
//!
//! Only the ROI plus a margin of [`FlowConfig::margin_px`] pixels on each side
//! is converted and pyramided: points whose motion takes them outside that
//! crop are dropped, so the margin must exceed the largest flow expected
//! (default 64 px: a 640x480 camera at 30 Hz sees the floor at the bottom of the
//! default ROI move 30 px per frame at 0.6 m/s; each point starts from its last
//! flow, or, lost in the last pair, from its tracked grid neighbours', so the
//! pyramid only has to find the change). A pair in which no point has such a
//! start (the first after a start or a reset, or with every point lost) starts
//! the points from a coarse search of the ROI's shift within the margin, band by
//! band of its rows, on the pyramid's top level (`PyrLk::coarse_search`).
//!
//! All buffers are allocated for the first frame of a given size and reused
//! (the previous and current pyramids are swapped), so steady-state processing
//! allocates nothing.
//!
//! ```
//! use vlsync_signature_cam::flow::{FlowConfig, PyrLk};
//! use vlsync_signature_cam::image::GrayFrame;
//! let (w, h) = (160, 120);
//! // a smooth texture, shifted right by 1.5 px in the second frame
//! let tex = |x: f32, y: f32| 128.0 + 60.0 * ((0.31 * x).sin() * (0.23 * y).cos() + (0.17 * (x + y)).sin());
//! let make = |dx: f32| -> Vec<f32> {
//!     (0..w * h).map(|i| tex((i % w) as f32 - dx, (i / w) as f32)).collect()
//! };
//! let a = GrayFrame::owned_f32(w, h, make(0.0)).unwrap();
//! let b = GrayFrame::owned_f32(w, h, make(1.5)).unwrap();
//! let mut lk = PyrLk::new(FlowConfig::default()).unwrap();
//! assert!(lk.push(&a).unwrap().is_none()); // first frame: nothing to compare
//! let stats = lk.push(&b).unwrap().unwrap();
//! assert!(!stats.low_texture);
//! for v in lk.vectors() {
//!     assert!((v.dx - 1.5).abs() < 0.1 && v.dy.abs() < 0.1, "{v:?}");
//! }
//! ```

use crate::image::{GrayFrame, Pixel};
use crate::Error;
use serde::{Deserialize, Serialize};

/// Region of interest as fractions of the frame width and height (`0 <= x0 < x1 <= 1`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Roi {
    /// Left edge, fraction of width.
    pub x0: f32,
    /// Right edge, fraction of width.
    pub x1: f32,
    /// Top edge, fraction of height.
    pub y0: f32,
    /// Bottom edge, fraction of height.
    pub y1: f32,
}

impl Default for Roi {
    /// The lower-middle part of the image, where the floor is: x 25-75 %, y 55-90 %
    /// (centred left-right, so the vertical flow of a turn cancels in the mean;
    /// clear of the bottom rows, which fast forward motion would carry the
    /// tracked windows past).
    fn default() -> Self {
        Self {
            x0: 0.25,
            x1: 0.75,
            y0: 0.55,
            y1: 0.90,
        }
    }
}

/// Configuration of [`PyrLk`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FlowConfig {
    /// Region where the grid points are placed.
    pub roi: Roi,
    /// Grid points across the ROI (default 16).
    pub grid_cols: usize,
    /// Grid points down the ROI (default 8).
    pub grid_rows: usize,
    /// Pyramid levels including full resolution, 1..=6 (default 3).
    pub levels: usize,
    /// Side of the square LK window in pixels, odd, 3..=31 (default 9).
    pub window: usize,
    /// Maximum Gauss-Newton iterations per level (default 10).
    pub max_iterations: usize,
    /// Stop iterating when the update is below this many pixels (default 0.01).
    pub epsilon_px: f32,
    /// Shi-Tomasi threshold: minimum eigenvalue of the structure tensor divided by
    /// the window area, in (gray levels / px)^2 on the 0..=255 scale (default 2.0).
    /// Sensor noise alone gives about half its variance (σ = 2 levels: ~1.5);
    /// motion blur weakens a floor's gradients along the motion, at 640x480 to
    /// 2-5 near the bottom of the ROI at 0.6 m/s, and a point that drops out when
    /// the robot is fast biases the mean of the flow (the fast points go
    /// missing). Windows that pass on noise alone are rejected by the residual
    /// check ([`FlowConfig::max_residual`]).
    pub min_eigen: f32,
    /// Fewer tracked points than this flags the frame as low-texture (default 16).
    pub min_points: usize,
    /// Pixels around the ROI included in the pyramid (default 64).
    pub margin_px: usize,
    /// Largest accepted residual after tracking, relative to the window's contrast:
    /// `|T' - I'| / |T'|` with `T'` the mean-free template and `I'` the
    /// photometrically matched window. It equals `sqrt(2 (1 - ncc))`: 0.8 (the
    /// default) accepts a normalised cross-correlation down to 0.68; a good match
    /// with sensor noise gives ~0.1-0.3, unrelated content ~1.4.
    pub max_residual: f32,
    /// Start each point's search at its flow of the previous frame pair (scaled by
    /// the ratio of the frame intervals, see [`PyrLk::set_prediction_scale`]) instead
    /// of zero (default true); a point not tracked in that pair starts from the
    /// median of its tracked grid neighbours' flows, or else from the nearest
    /// tracked point of its row. The pyramid then only has to find the change of the
    /// flow, so fast motion (15+ px per frame) is tracked as reliably as slow motion;
    /// a point that fails from its prediction is retried from zero (a second
    /// forward solve). When no point has a prediction (the first pair after a start
    /// or a reset, or every point lost), the points start from a coarse search of
    /// the ROI's shift (within [`FlowConfig::margin_px`], at most 24 px of the
    /// pyramid's top level), so a camera started while the robot is fast tracks
    /// from its first pair; while nothing tracks, the search runs on one pair in
    /// four. Off, the points start from zero.
    pub predict: bool,
    /// Track each grid point both ways, previous → current frame and current →
    /// previous, and average the two displacements (default true). Moving
    /// forward, a floor point drifts toward the bottom of the image, where the
    /// flow is faster, so a one-way displacement grows faster than the speed
    /// (+10 % at 0.6 m/s for the default ROI of a 30 Hz camera); the two ways
    /// err in opposite directions and their mean is the flow at the grid point
    /// itself to second order. The two ways must agree (within the
    /// [`FlowConfig::outlier_px`] tolerance), which also rejects mis-tracks.
    /// Costs a second LK solve per point.
    pub symmetric: bool,
    /// Neighbourhood consistency: a vector farther than `outlier_px + outlier_rel · |m|`
    /// from the median `m` of its tracked 8-neighbours on the grid (at least 3 of them)
    /// is dropped as a mis-track. The flow of a rigid scene is smooth across the grid,
    /// a point locked onto the wrong texture is not. Defaults 1.0 px and 0.25;
    /// `outlier_px = inf` disables the check, and with it the forward/backward
    /// agreement test of [`FlowConfig::symmetric`], which uses the same tolerance.
    pub outlier_px: f32,
    /// See [`FlowConfig::outlier_px`].
    pub outlier_rel: f32,
}

impl Default for FlowConfig {
    fn default() -> Self {
        Self {
            roi: Roi::default(),
            grid_cols: 16,
            grid_rows: 8,
            levels: 3,
            window: 9,
            max_iterations: 10,
            epsilon_px: 0.01,
            min_eigen: 2.0,
            min_points: 16,
            margin_px: 64,
            max_residual: 0.8,
            predict: true,
            symmetric: true,
            outlier_px: 1.0,
            outlier_rel: 0.25,
        }
    }
}

fn invalid(field: &'static str, reason: impl Into<String>) -> Error {
    Error::InvalidConfig {
        field,
        reason: reason.into(),
    }
}

impl FlowConfig {
    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), Error> {
        let r = &self.roi;
        for (field, v) in [
            ("flow.roi.x0", r.x0),
            ("flow.roi.x1", r.x1),
            ("flow.roi.y0", r.y0),
            ("flow.roi.y1", r.y1),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(invalid(field, format!("{v} is outside 0..=1")));
            }
        }
        if r.x0 >= r.x1 {
            return Err(invalid("flow.roi.x1", format!("{} <= x0 = {}", r.x1, r.x0)));
        }
        if r.y0 >= r.y1 {
            return Err(invalid("flow.roi.y1", format!("{} <= y0 = {}", r.y1, r.y0)));
        }
        if !(1..=64).contains(&self.grid_cols) {
            return Err(invalid("flow.grid_cols", "must be 1..=64"));
        }
        if !(1..=64).contains(&self.grid_rows) {
            return Err(invalid("flow.grid_rows", "must be 1..=64"));
        }
        if !(1..=6).contains(&self.levels) {
            return Err(invalid("flow.levels", "must be 1..=6"));
        }
        if !(3..=31).contains(&self.window) || self.window.is_multiple_of(2) {
            return Err(invalid("flow.window", "must be odd and 3..=31"));
        }
        if !(1..=100).contains(&self.max_iterations) {
            return Err(invalid("flow.max_iterations", "must be 1..=100"));
        }
        if !(self.epsilon_px.is_finite() && self.epsilon_px >= 0.0) {
            return Err(invalid("flow.epsilon_px", "must be finite and >= 0"));
        }
        if !(self.min_eigen.is_finite() && self.min_eigen >= 0.0) {
            return Err(invalid("flow.min_eigen", "must be finite and >= 0"));
        }
        if self.min_points > self.grid_cols * self.grid_rows {
            return Err(invalid(
                "flow.min_points",
                format!(
                    "{} exceeds the {} grid points",
                    self.min_points,
                    self.grid_cols * self.grid_rows
                ),
            ));
        }
        if !(self.max_residual.is_finite() && self.max_residual > 0.0) {
            return Err(invalid("flow.max_residual", "must be finite and > 0"));
        }
        if self.margin_px > 4096 {
            return Err(invalid("flow.margin_px", "must be <= 4096"));
        }
        if self.outlier_px.is_nan() || self.outlier_px <= 0.0 {
            return Err(invalid(
                "flow.outlier_px",
                format!("{} must be > 0 (inf disables the check)", self.outlier_px),
            ));
        }
        if !(self.outlier_rel.is_finite() && self.outlier_rel >= 0.0) {
            return Err(invalid(
                "flow.outlier_rel",
                format!("{} must be finite and >= 0", self.outlier_rel),
            ));
        }
        Ok(())
    }
}

/// The flow of one grid point between the previous and the current frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlowVector {
    /// Point position in the previous frame, full-frame pixel coordinates.
    pub x: f32,
    /// Point position in the previous frame, full-frame pixel coordinates.
    pub y: f32,
    /// Displacement to the current frame, pixels (+x right).
    pub dx: f32,
    /// Displacement to the current frame, pixels (+y down).
    pub dy: f32,
}

/// Counts of one flow computation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FlowStats {
    /// Grid points.
    pub points: usize,
    /// Points that passed the Shi-Tomasi threshold.
    pub textured: usize,
    /// Points tracked successfully (the length of [`PyrLk::vectors`]).
    pub tracked: usize,
    /// Tracked points dropped by the neighbourhood consistency check
    /// (not counted in `tracked`).
    pub inconsistent: usize,
    /// `tracked < min_points`.
    pub low_texture: bool,
}

impl FlowStats {
    /// No frame geometry yet: nothing tracked.
    const NONE: Self = Self {
        points: 0,
        textured: 0,
        tracked: 0,
        inconsistent: 0,
        low_texture: true,
    };
}

/// One pyramid level: a row-major `f32` image.
#[derive(Debug, Default, Clone)]
struct Level {
    w: usize,
    h: usize,
    data: Vec<f32>,
}

/// Frame-size dependent layout, computed on the first frame of a size.
#[derive(Debug, Clone)]
struct Geometry {
    frame_w: usize,
    frame_h: usize,
    crop_x: usize,
    crop_y: usize,
    /// (w, h) of each level.
    dims: Vec<(usize, usize)>,
    /// Grid points in crop coordinates.
    points: Vec<(f32, f32)>,
    /// The ROI in crop coordinates, `[x0, y0, x1, y1)`.
    roi: [usize; 4],
}

/// Pyramidal Lucas-Kanade tracker with reusable buffers.
#[derive(Debug, Clone)]
pub struct PyrLk {
    cfg: FlowConfig,
    geom: Option<Geometry>,
    prev: Vec<Level>,
    cur: Vec<Level>,
    has_prev: bool,
    tmp: Vec<f32>,
    vectors: Vec<FlowVector>,
    // level-0 template (kept across the coarse levels) and a scratch template
    t0: Template,
    tl: Template,
    patch: Vec<f32>,
    warped: Vec<f32>,
    /// Flow of each grid point in the last pair (NaN: not tracked), and the one
    /// before (the prediction); laid out with the geometry.
    grid_flow: Vec<[f32; 2]>,
    prior_flow: Vec<[f32; 2]>,
    /// Scratch of the consistency check: grid points found inconsistent.
    outlier: Vec<bool>,
    has_prior: bool,
    prediction_scale: f32,
    /// Scratch of the coarse search: each band's NCC surface, then the scores.
    search: Vec<f32>,
    /// The coarse search's start for the points of each band of ROI rows.
    band_start: [Option<(f32, f32)>; SEARCH_BANDS],
    /// Pairs still to wait before the next coarse search (after one that led to
    /// nothing tracked).
    search_wait: u32,
    /// Coarse searches run.
    searches: u64,
}

/// Marks a grid point without a flow vector.
const NO_FLOW: [f32; 2] = [f32::NAN, f32::NAN];

/// Reach of the coarse search (`PyrLk::coarse_search`) at most, in pixels of the
/// pyramid's top level (±24: ±96 px at full resolution with the default 3
/// levels); within that, the margin's.
const SEARCH_REACH: usize = 24;
/// Side of the coarse search's NCC surface.
const SEARCH_SIDE: usize = 2 * SEARCH_REACH + 1;
/// Template samples the coarse search compares per shift, about (over all its
/// bands): a larger ROI is thinned by a whole stride, which may leave a few more.
const SEARCH_SAMPLES: usize = 1024;
/// While nothing tracks, the coarse search runs on one pair in this many.
const SEARCH_EVERY: u32 = 4;
/// Bands of ROI rows the coarse search correlates apart...
const SEARCH_BANDS: usize = 4;
/// ...each allowed to differ from the ROI's shift by this many top-level pixels.
const SEARCH_BAND_REACH: usize = 3;
/// The coarse search's best score (the bands' mean normalised cross-correlation,
/// each band's best near the shift) must reach this (unrelated content: 0.34-0.51
/// in 40 pairs of a 320x240 test floor; rendered starts of a 10 Hz camera at
/// 0.45-0.58 m/s, whose bands move 20-45 px: 0.65-0.81)...
const SEARCH_MIN_NCC: f32 = 0.55;
/// ...and exceed by this every other local maximum of the scores farther than
/// twice the band reach from it: a periodic floor, whose shift is ambiguous,
/// gives no start. A reach of no more than that (a margin under 7 top-level
/// pixels: 28 px at 3 levels) has no room for the test, and no search.
const SEARCH_MARGIN: f32 = 0.1;

#[derive(Debug, Clone, Default)]
struct Template {
    val: Vec<f32>,
    gx: Vec<f32>,
    gy: Vec<f32>,
    gxx: f32,
    gxy: f32,
    gyy: f32,
    /// Mean of `val`.
    mean: f32,
    /// `sqrt(sum((val - mean)^2))`.
    norm: f32,
}

impl PyrLk {
    /// A tracker; fails on an invalid configuration.
    pub fn new(cfg: FlowConfig) -> Result<Self, Error> {
        cfg.validate()?;
        let n = cfg.window * cfg.window;
        let pn = (cfg.window + 2) * (cfg.window + 2);
        let tpl = || Template {
            val: vec![0.0; n],
            gx: vec![0.0; n],
            gy: vec![0.0; n],
            ..Template::default()
        };
        Ok(Self {
            cfg,
            geom: None,
            prev: Vec::new(),
            cur: Vec::new(),
            has_prev: false,
            tmp: Vec::new(),
            vectors: Vec::with_capacity(cfg.grid_cols * cfg.grid_rows),
            t0: tpl(),
            tl: tpl(),
            patch: vec![0.0; pn],
            warped: vec![0.0; n],
            grid_flow: Vec::new(),
            prior_flow: Vec::new(),
            outlier: Vec::new(),
            has_prior: false,
            prediction_scale: 1.0,
            search: vec![f32::NAN; (SEARCH_BANDS + 1) * SEARCH_SIDE * SEARCH_SIDE],
            band_start: [None; SEARCH_BANDS],
            search_wait: 0,
            searches: 0,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &FlowConfig {
        &self.cfg
    }

    /// Forgets the previous frame: the next [`PyrLk::push`] starts a new pair.
    pub fn reset(&mut self) {
        self.has_prev = false;
        self.has_prior = false;
        // a fresh start searches at once
        self.search_wait = 0;
        self.vectors.clear();
        // no pair, no flows: grid() must not serve the last pair's
        self.grid_flow.fill(NO_FLOW);
    }

    /// Coarse searches run so far (see [`FlowConfig::predict`]): one per start
    /// while the robot moves, and while nothing tracks one every
    /// `SEARCH_EVERY` (4) pairs.
    pub fn searches(&self) -> u64 {
        self.searches
    }

    /// Scales the prediction of the next [`PyrLk::push`]: the ratio of the coming
    /// frame interval to the previous one (2 when one frame was dropped). Values
    /// that are not finite and positive turn the prediction off for that push:
    /// the points start from the coarse search instead (see
    /// [`FlowConfig::predict`]). Reset to 1 after every push.
    pub fn set_prediction_scale(&mut self, scale: f32) {
        self.prediction_scale = scale;
    }

    /// The frame size the buffers are laid out for, if any.
    pub fn frame_size(&self) -> Option<(usize, usize)> {
        self.geom.as_ref().map(|g| (g.frame_w, g.frame_h))
    }

    /// Flow vectors of the last successful [`PyrLk::push`] (tracked points only).
    pub fn vectors(&self) -> &[FlowVector] {
        &self.vectors
    }

    /// Every grid point of the last successful [`PyrLk::push`] in grid order
    /// (row by row), tracked or not: `dx`, `dy` are NaN for a point without a
    /// vector. Empty before the first frame; all NaN after [`PyrLk::reset`] and
    /// after a push that returned `None` (no pair).
    pub fn grid(&self) -> impl ExactSizeIterator<Item = FlowVector> + '_ {
        let (cx, cy, pts) = match &self.geom {
            Some(g) => (g.crop_x as f32, g.crop_y as f32, &g.points[..]),
            None => (0.0, 0.0, &[][..]),
        };
        let flows = if self.grid_flow.len() == pts.len() {
            &self.grid_flow[..]
        } else {
            &[][..]
        };
        pts.iter()
            .zip(flows)
            .map(move |(&(x, y), &[dx, dy])| FlowVector {
                x: x + cx,
                y: y + cy,
                dx,
                dy,
            })
    }

    /// Loads a frame. Returns the flow statistics from the previous frame to this
    /// one, or `None` when there is no previous frame (first frame, after
    /// [`PyrLk::reset`], or after a change of frame size). On error the previous
    /// frame is forgotten.
    pub fn push<T: Pixel>(&mut self, frame: &GrayFrame<'_, T>) -> Result<Option<FlowStats>, Error> {
        let (w, h) = (frame.width(), frame.height());
        if self.frame_size() != Some((w, h)) {
            self.has_prev = false;
            self.geom = None;
            let g = self.layout(w, h)?;
            let alloc = |dims: &[(usize, usize)]| {
                dims.iter()
                    .map(|&(w, h)| Level {
                        w,
                        h,
                        data: vec![0.0; w * h],
                    })
                    .collect::<Vec<_>>()
            };
            self.prev = alloc(&g.dims);
            self.cur = alloc(&g.dims);
            let (w0, h0) = g.dims[0];
            self.tmp = vec![0.0; w0.div_ceil(2) * h0];
            self.grid_flow = vec![NO_FLOW; g.points.len()];
            self.prior_flow = vec![NO_FLOW; g.points.len()];
            self.outlier = vec![false; g.points.len()];
            self.has_prior = false;
            self.geom = Some(g);
        }
        self.build_pyramid(frame);
        let stats = if self.has_prev {
            // the last pair's flow predicts this pair's
            std::mem::swap(&mut self.grid_flow, &mut self.prior_flow);
            Some(self.track())
        } else {
            self.vectors.clear();
            self.grid_flow.fill(NO_FLOW);
            self.has_prior = false;
            self.search_wait = 0;
            None
        };
        self.prediction_scale = 1.0;
        std::mem::swap(&mut self.prev, &mut self.cur);
        self.has_prev = true;
        Ok(stats)
    }

    /// Computes the layout for a `w x h` frame, or says why it is too small.
    fn layout(&self, w: usize, h: usize) -> Result<Geometry, Error> {
        crate::image::pixel_count(w, h)?;
        let c = &self.cfg;
        let span = |lo: f32, hi: f32, n: usize| {
            let a = ((lo as f64) * n as f64).floor() as usize;
            let b = (((hi as f64) * n as f64).ceil() as usize).min(n);
            (a.min(n), b)
        };
        let (x0, x1) = span(c.roi.x0, c.roi.x1, w);
        let (y0, y1) = span(c.roi.y0, c.roi.y1, h);
        if x1 <= x0 || y1 <= y0 {
            return Err(Error::FrameTooSmall {
                width: w,
                height: h,
                reason: "the ROI covers no pixel".into(),
            });
        }
        let cx0 = x0.saturating_sub(c.margin_px);
        let cy0 = y0.saturating_sub(c.margin_px);
        let cx1 = x1.saturating_add(c.margin_px).min(w);
        let cy1 = y1.saturating_add(c.margin_px).min(h);
        let mut dims = Vec::with_capacity(c.levels);
        let (mut lw, mut lh) = (cx1 - cx0, cy1 - cy0);
        let need = c.window + 2;
        for level in 0..c.levels {
            if lw < need || lh < need {
                return Err(Error::FrameTooSmall {
                    width: w,
                    height: h,
                    reason: format!(
                        "ROI plus margin is {}x{} px, pyramid level {level} would be {lw}x{lh}, \
                         below the {need}x{need} needed by a {}x{} window",
                        cx1 - cx0,
                        cy1 - cy0,
                        c.window,
                        c.window
                    ),
                });
            }
            dims.push((lw, lh));
            lw = lw.div_ceil(2);
            lh = lh.div_ceil(2);
        }
        let mut points = Vec::with_capacity(c.grid_cols * c.grid_rows);
        for j in 0..c.grid_rows {
            let py = y0 + ((2 * j + 1) * (y1 - y0)) / (2 * c.grid_rows);
            for i in 0..c.grid_cols {
                let px = x0 + ((2 * i + 1) * (x1 - x0)) / (2 * c.grid_cols);
                points.push(((px - cx0) as f32, (py - cy0) as f32));
            }
        }
        Ok(Geometry {
            frame_w: w,
            frame_h: h,
            crop_x: cx0,
            crop_y: cy0,
            dims,
            points,
            roi: [x0 - cx0, y0 - cy0, x1 - cx0, y1 - cy0],
        })
    }

    /// Fills `self.cur` with the pyramid of the crop of `frame`.
    fn build_pyramid<T: Pixel>(&mut self, frame: &GrayFrame<'_, T>) {
        let Some(g) = &self.geom else { return };
        let fw = frame.width();
        let src = frame.pixels();
        let l0 = &mut self.cur[0];
        for (y, dst) in l0.data.chunks_exact_mut(l0.w).enumerate() {
            let start = (g.crop_y + y) * fw + g.crop_x;
            for (d, s) in dst.iter_mut().zip(&src[start..start + l0.w]) {
                *d = s.to_f32();
            }
        }
        for l in 1..self.cur.len() {
            let (lower, upper) = self.cur.split_at_mut(l);
            pyr_down(&lower[l - 1], &mut upper[0], &mut self.tmp);
        }
    }

    /// Tracks every grid point from `self.prev` to `self.cur`, then drops the
    /// vectors that disagree with their grid neighbours.
    fn track(&mut self) -> FlowStats {
        self.vectors.clear();
        let Some(g) = &self.geom else {
            return FlowStats::NONE;
        };
        let c = self.cfg;
        let n = (c.window * c.window) as f32;
        let (w0, h0) = g.dims[0];
        let npts = g.points.len();
        let scale = self.prediction_scale;
        let predict = c.predict && self.has_prior && scale.is_finite() && scale > 0.0;
        // no point has a start of its own (a start, a restart after a gap, every
        // point lost): the whole ROI's shift, searched coarsely, is every point's
        // start; searched once, at the first point that needs it
        // (while nothing tracks, every SEARCH_EVERY-th pair: its 2-3 ms at 640x480
        // must not become every frame's cost on a small computer)
        let unpredicted =
            c.predict && !(predict && self.prior_flow.iter().any(|v| v[0].is_finite()));
        let search = unpredicted && self.search_wait == 0;
        if unpredicted && !search {
            self.search_wait -= 1;
        }
        let mut searched = false;
        let mut textured = 0;
        for i in 0..npts {
            let (px, py) = self.geom.as_ref().map_or((0.0, 0.0), |g| g.points[i]);
            self.grid_flow[i] = NO_FLOW;
            // level-0 template first: the texture test decides whether to track at all
            if !has_texture(&self.prev[0], px, py, &c, n, &mut self.patch, &mut self.t0) {
                continue;
            }
            textured += 1;
            let guess = if search {
                if !searched {
                    self.coarse_search();
                    searched = true;
                }
                // the band that holds the grid row's centre
                self.band_start[((2 * (i / c.grid_cols) + 1) * SEARCH_BANDS) / (2 * c.grid_rows)]
            } else if predict {
                predicted_flow(&self.prior_flow, c.grid_cols, i)
                    .map(|[fx, fy]| (fx * scale, fy * scale))
            } else {
                None
            };
            let Some(mut d) = self.track_both_ways(px, py, guess, false) else {
                continue;
            };
            if c.symmetric {
                // the backward template must be textured too
                if !has_texture(&self.cur[0], px, py, &c, n, &mut self.patch, &mut self.t0) {
                    continue;
                }
                let Some(b) = self.track_both_ways(px, py, Some((-d.0, -d.1)), true) else {
                    continue;
                };
                // forward and backward disagree by the change of flow along the
                // way (second order) plus tracking error
                let tol = c.outlier_px + c.outlier_rel * d.0.hypot(d.1);
                let gap = (d.0 + b.0).hypot(d.1 + b.1);
                if gap.is_nan() || gap > tol {
                    continue;
                }
                d = (0.5 * (d.0 - b.0), 0.5 * (d.1 - b.1));
            }
            let (qx, qy) = (px + d.0, py + d.1);
            if qx >= 0.0 && qy >= 0.0 && qx <= (w0 - 1) as f32 && qy <= (h0 - 1) as f32 {
                self.grid_flow[i] = [d.0, d.1];
            }
        }
        let inconsistent = self.drop_inconsistent();
        self.has_prior = true;
        let Some(g) = &self.geom else {
            return FlowStats::NONE;
        };
        for (&(px, py), &[dx, dy]) in g.points.iter().zip(&self.grid_flow) {
            if dx.is_finite() {
                self.vectors.push(FlowVector {
                    x: px + g.crop_x as f32,
                    y: py + g.crop_y as f32,
                    dx,
                    dy,
                });
            }
        }
        let tracked = self.vectors.len();
        if searched {
            self.searches += 1;
            // a search that found nothing to track waits a few pairs
            self.search_wait = if tracked == 0 { SEARCH_EVERY - 1 } else { 0 };
        }
        FlowStats {
            points: npts,
            textured,
            tracked,
            inconsistent,
            low_texture: tracked < c.min_points,
        }
    }

    /// Tracks one point from its `guess` when there is one, else (or when that
    /// fails) from zero. `backward`: from the current frame to the previous one.
    fn track_both_ways(
        &mut self,
        px: f32,
        py: f32,
        guess: Option<(f32, f32)>,
        backward: bool,
    ) -> Option<(f32, f32)> {
        guess
            .and_then(|g| self.track_point(px, py, g, backward))
            .or_else(|| self.track_point(px, py, (0.0, 0.0), backward))
    }

    /// Each band of the ROI's shift from the previous frame to the current one,
    /// in full-resolution pixels, into `self.band_start` (`None` for all when the
    /// search finds nothing). On the pyramid's top level, each of
    /// [`SEARCH_BANDS`] bands of ROI rows is correlated (normalised) with the
    /// current frame at every integer shift within the margin's reach (at most
    /// [`SEARCH_REACH`]); the floor's flow grows down the image (at 10 Hz, 0.5
    /// m/s and 320x240: 20 px a frame at the ROI's top rows, 36 px at its bottom
    /// ones), so a shift's score is the mean over the bands of each band's best
    /// within [`SEARCH_BAND_REACH`] of it. The best score must reach
    /// [`SEARCH_MIN_NCC`] and beat every other local maximum of the scores by
    /// [`SEARCH_MARGIN`] (a periodic floor gives no start); each band then starts
    /// from its own best near it. No search when the reach is no more than twice
    /// [`SEARCH_BAND_REACH`].
    ///
    /// Why: a point without a flow to start from searches from zero, and from zero
    /// three levels with a 9x9 window reach about 28 px at best. A camera started
    /// (or restarted after a gap) while the robot is fast tracked almost nothing
    /// until the robot slowed (rendered 10 Hz runs at 0.45-0.58 m/s: 16-43 of 128
    /// points, against 66-109 tracked by a front-end running throughout). The
    /// forward/backward and neighbourhood checks judge each point as before, and a
    /// point that fails from its band's start is retried from zero.
    ///
    /// Cost: `(2 * reach + 1)^2` comparisons of about [`SEARCH_SAMPLES`]
    /// samples, 2.8 ms at 640x480 on an x86 server core; for a pair in which no
    /// point has a prediction: once per start, and while nothing tracks on one
    /// pair in [`SEARCH_EVERY`].
    fn coarse_search(&mut self) {
        self.band_start = [None; SEARCH_BANDS];
        let Some(g) = self.geom.as_ref() else { return };
        let Some(top) = self.prev.len().checked_sub(1) else {
            return;
        };
        let f = 1usize << top;
        let reach = (self.cfg.margin_px / f).min(SEARCH_REACH);
        let (Some(prev), Some(cur)) = (self.prev.get(top), self.cur.get(top)) else {
            return;
        };
        // the second-peak test looks beyond twice the band reach: a smaller
        // reach leaves it nothing to look at
        if reach <= 2 * SEARCH_BAND_REACH || cur.w != prev.w || cur.h != prev.h {
            return;
        }
        let [x0, y0, x1, y1] = g.roi;
        let (x0, x1) = (x0 / f, x1.div_ceil(f).min(prev.w));
        let (y0, y1) = (y0 / f, y1.div_ceil(f).min(prev.h));
        if x1 <= x0 || y1 < y0 + SEARCH_BANDS {
            return;
        }
        let side = 2 * reach + 1;
        let n = side * side;
        let (bands, score) = self
            .search
            .split_at_mut(SEARCH_BANDS * SEARCH_SIDE * SEARCH_SIDE);
        let band = |b: usize| {
            [
                x0,
                y0 + (y1 - y0) * b / SEARCH_BANDS,
                x1,
                y0 + (y1 - y0) * (b + 1) / SEARCH_BANDS,
            ]
        };
        for (b, surface) in bands.chunks_exact_mut(n).take(SEARCH_BANDS).enumerate() {
            for (k, out) in surface.iter_mut().enumerate() {
                let (dx, dy) = (
                    (k % side) as isize - reach as isize,
                    (k / side) as isize - reach as isize,
                );
                *out = ncc(prev, cur, band(b), dx, dy, SEARCH_SAMPLES / SEARCH_BANDS);
            }
        }
        let bands = &bands[..SEARCH_BANDS * n];
        // a band's best within the band reach of (x, y), and where
        let near_best = |b: usize, x: usize, y: usize| {
            let r = SEARCH_BAND_REACH;
            let surface = &bands[b * n..(b + 1) * n];
            let mut best: Option<(usize, f32)> = None;
            for yy in y.saturating_sub(r)..(y + r + 1).min(side) {
                for xx in x.saturating_sub(r)..(x + r + 1).min(side) {
                    let v = surface[yy * side + xx];
                    if v.is_finite() && best.is_none_or(|(_, m)| v > m) {
                        best = Some((yy * side + xx, v));
                    }
                }
            }
            best
        };
        let score = &mut score[..n];
        for (k, out) in score.iter_mut().enumerate() {
            let (x, y) = (k % side, k / side);
            let (sum, m) = (0..SEARCH_BANDS)
                .filter_map(|b| near_best(b, x, y))
                .fold((0.0f32, 0usize), |(s, m), (_, v)| (s + v, m + 1));
            // every band must see the floor at a shift
            *out = if m == SEARCH_BANDS {
                sum / m as f32
            } else {
                f32::NAN
            };
        }
        let Some((best, top_score)) = score
            .iter()
            .enumerate()
            .filter(|(_, v)| v.is_finite())
            .max_by(|a, b| a.1.total_cmp(b.1))
            .map(|(k, &v)| (k, v))
        else {
            return;
        };
        if top_score < SEARCH_MIN_NCC {
            return;
        }
        let (bx, by) = (best % side, best / side);
        let at = |x: usize, y: usize| score[y * side + x];
        for y in 0..side {
            for x in 0..side {
                let v = at(x, y);
                // the scores are each band's best within the band reach: flat
                // around a peak, so a second peak must lie beyond it
                let near = x.abs_diff(bx).max(y.abs_diff(by)) <= 2 * SEARCH_BAND_REACH;
                if near || v.is_nan() || v <= top_score - SEARCH_MARGIN {
                    continue;
                }
                // a local maximum: no neighbour higher (NaN neighbours are not)
                let peak = (y.saturating_sub(1)..(y + 2).min(side)).all(|yy| {
                    (x.saturating_sub(1)..(x + 2).min(side))
                        .all(|xx| at(xx, yy).partial_cmp(&v) != Some(std::cmp::Ordering::Greater))
                });
                if peak {
                    return;
                }
            }
        }
        let full = |c: usize| (c as isize - reach as isize) as f32 * f as f32;
        for (b, start) in self.band_start.iter_mut().enumerate() {
            let k = near_best(b, bx, by).map_or(best, |(k, _)| k);
            *start = Some((full(k % side), full(k / side)));
        }
    }

    /// Pyramidal LK of one point (crop coordinates, template of level 0 in
    /// `self.t0`) starting from the full-resolution displacement `guess`, from
    /// the previous frame to the current one (or back, with `backward`).
    /// Returns the displacement, or `None` when the solve fails or the final
    /// residual exceeds the limit.
    fn track_point(
        &mut self,
        px: f32,
        py: f32,
        guess: (f32, f32),
        backward: bool,
    ) -> Option<(f32, f32)> {
        let c = self.cfg;
        let r = (c.window / 2) as f32;
        let top = 1u32 << (c.levels - 1);
        let mut gx = guess.0 / top as f32;
        let mut gy = guess.1 / top as f32;
        let mut residual = 0.0f32;
        for l in (0..c.levels).rev() {
            let s = 1.0 / (1u32 << l) as f32;
            let (lx, ly) = (px * s, py * s);
            let (src, dst) = if backward {
                (&self.cur, &self.prev)
            } else {
                (&self.prev, &self.cur)
            };
            let tpl = if l == 0 {
                &self.t0
            } else {
                make_template(&src[l], lx, ly, c.window, &mut self.patch, &mut self.tl);
                &self.tl
            };
            let (dx, dy, res) = solve_level(
                tpl,
                &dst[l],
                lx + gx,
                ly + gy,
                r,
                c.max_iterations,
                c.epsilon_px,
                &mut self.warped,
            )?;
            residual = res;
            gx += dx;
            gy += dy;
            if l > 0 {
                gx *= 2.0;
                gy *= 2.0;
            }
        }
        (residual <= c.max_residual).then_some((gx, gy))
    }

    /// Neighbourhood consistency on the grid (see [`FlowConfig::outlier_px`]):
    /// clears the vectors of `grid_flow` that disagree with the median of their
    /// tracked 8-neighbours. Every decision sees the field before any vector is
    /// cleared. Returns the number cleared.
    fn drop_inconsistent(&mut self) -> usize {
        let c = self.cfg;
        if !c.outlier_px.is_finite() {
            return 0;
        }
        let (cols, rows) = (c.grid_cols, c.grid_rows);
        let field = &self.grid_flow;
        let mut dropped = 0;
        for j in 0..rows {
            for i in 0..cols {
                let [vx, vy] = field[j * cols + i];
                self.outlier[j * cols + i] = false;
                if !vx.is_finite() {
                    continue;
                }
                let ([mx, my], k) = neighbour_median(field, cols, rows, j, i);
                if k < 3 {
                    continue;
                }
                let tol = c.outlier_px + c.outlier_rel * mx.hypot(my);
                if (vx - mx).hypot(vy - my) > tol {
                    self.outlier[j * cols + i] = true;
                    dropped += 1;
                }
            }
        }
        for (v, &o) in self.grid_flow.iter_mut().zip(&self.outlier) {
            if o {
                *v = NO_FLOW;
            }
        }
        dropped
    }
}

/// The prediction of grid point `i` from the last pair's flow field `prior`
/// (row-major, `cols` points per row; NaN where a point was not tracked): its
/// own vector; for a point that was not tracked, the median of its tracked
/// 8-neighbours'; without those, the vector of the nearest tracked point in
/// its row. `None` when none of these was tracked.
///
/// A point lost once (the robot fast, the point's window briefly without
/// texture) would otherwise search from zero from then on, and from zero the
/// pyramid reaches only a few pixels per level: with a slow camera (10 Hz: 30-45
/// px per frame near the bottom of a 320x240 ROI at 0.6 m/s) it never found the
/// point again until the robot slowed, and the fast points missing made the
/// signature read low exactly while the robot was fast. The floor's flow is
/// smooth across the grid, so a neighbour's vector is a start within the
/// pyramid's reach; the forward/backward and neighbourhood checks still judge
/// the result. The row's fallback may reach far: the sideways flow of driving
/// forward changes across a row, but any tracked point of the row is a closer
/// start than zero, and zero is what a point without a start searches from. In
/// `a_point_lost_at_speed_is_found_again_from_its_neighbours` (half the grid lost
/// at 32 px a frame) with the row's reach capped at two columns, the points
/// beyond it searched from zero and a third of them converged on wrong matches
/// that passed every check (their neighbours lost too), then predicted the next
/// pair from those: 101 of 128 points right four frames later. With the whole
/// row every point was found again at once.
fn predicted_flow(prior: &[[f32; 2]], cols: usize, i: usize) -> Option<[f32; 2]> {
    let own = prior.get(i)?;
    if own[0].is_finite() && own[1].is_finite() {
        return Some(*own);
    }
    // no grid, or a point past its last whole row: no neighbours to ask
    if cols == 0 || i / cols >= prior.len() / cols {
        return None;
    }
    let rows = prior.len() / cols;
    let (j, c) = (i / cols, i % cols);
    let (median, k) = neighbour_median(prior, cols, rows, j, c);
    if k > 0 {
        return Some(median);
    }
    let row = &prior[j * cols..(j + 1) * cols];
    (1..cols).find_map(|step| {
        [c.checked_sub(step), Some(c + step)]
            .into_iter()
            .flatten()
            .filter_map(|ii| row.get(ii))
            .find(|v| v[0].is_finite() && v[1].is_finite())
            .copied()
    })
}

/// The componentwise median of the tracked 8-neighbours of grid point `(row j,
/// column i)` in a row-major `field` of `rows` whole rows of `cols` (NaN:
/// untracked), and how many there are (NaN medians when none).
fn neighbour_median(
    field: &[[f32; 2]],
    cols: usize,
    rows: usize,
    j: usize,
    i: usize,
) -> ([f32; 2], usize) {
    let mut nx = [0.0f32; 8];
    let mut ny = [0.0f32; 8];
    let mut k = 0;
    for jj in j.saturating_sub(1)..(j + 2).min(rows) {
        for ii in i.saturating_sub(1)..(i + 2).min(cols) {
            let [ax, ay] = field[jj * cols + ii];
            if (ii, jj) != (i, j) && ax.is_finite() && ay.is_finite() {
                nx[k] = ax;
                ny[k] = ay;
                k += 1;
            }
        }
    }
    if k == 0 {
        return (NO_FLOW, 0);
    }
    ([median_small(&mut nx[..k]), median_small(&mut ny[..k])], k)
}

/// Median of a small non-empty slice (sorts it).
fn median_small(v: &mut [f32]) -> f32 {
    v.sort_unstable_by(f32::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// The Shi-Tomasi texture test of the level-0 window around `(px, py)`: its
/// smaller gradient eigenvalue, per pixel (`n`), reaches `c.min_eigen`. NaN
/// (non-finite pixels in an f32 frame) counts as no texture. Leaves the
/// template in `t`.
fn has_texture(
    lv: &Level,
    px: f32,
    py: f32,
    c: &FlowConfig,
    n: f32,
    patch: &mut [f32],
    t: &mut Template,
) -> bool {
    make_template(lv, px, py, c.window, patch, t);
    let eig = min_eigen(t) / n;
    !eig.is_nan() && eig >= c.min_eigen
}

/// Smallest eigenvalue of the template's structure tensor.
fn min_eigen(t: &Template) -> f32 {
    let tr = t.gxx + t.gyy;
    let d = ((t.gxx - t.gyy) * (t.gxx - t.gyy) + 4.0 * t.gxy * t.gxy).sqrt();
    0.5 * (tr - d)
}

/// Samples a `side x side` patch of `lv` whose top-left sample is at `(sx, sy)`,
/// bilinearly, with edge replication outside the image.
fn sample(lv: &Level, sx: f32, sy: f32, side: usize, out: &mut [f32]) {
    let fx0 = sx.floor();
    let fy0 = sy.floor();
    let (ax, ay) = (sx - fx0, sy - fy0);
    let (w00, w10, w01, w11) = (
        (1.0 - ax) * (1.0 - ay),
        ax * (1.0 - ay),
        (1.0 - ax) * ay,
        ax * ay,
    );
    let (w, h) = (lv.w, lv.h);
    let inside = fx0 >= 0.0
        && fy0 >= 0.0
        && fx0 + (side as f32) < w as f32
        && fy0 + (side as f32) < h as f32;
    if inside {
        let (ix, iy) = (fx0 as usize, fy0 as usize);
        for (j, o) in out.chunks_exact_mut(side).take(side).enumerate() {
            let a = (iy + j) * w + ix;
            let r0 = &lv.data[a..a + side + 1];
            let r1 = &lv.data[a + w..a + w + side + 1];
            for i in 0..side {
                o[i] = w00 * r0[i] + w10 * r0[i + 1] + w01 * r1[i] + w11 * r1[i + 1];
            }
        }
    } else {
        // slow path near or past the border: clamp every tap (no NaN: inputs are finite
        // because positions are checked before sampling)
        let cl = |v: f32, n: usize| -> usize { v.clamp(0.0, (n - 1) as f32) as usize };
        for j in 0..side {
            let y = fy0 + j as f32;
            let (y0, y1) = (cl(y, h), cl(y + 1.0, h));
            for i in 0..side {
                let x = fx0 + i as f32;
                let (x0, x1) = (cl(x, w), cl(x + 1.0, w));
                out[j * side + i] = w00 * lv.data[y0 * w + x0]
                    + w10 * lv.data[y0 * w + x1]
                    + w01 * lv.data[y1 * w + x0]
                    + w11 * lv.data[y1 * w + x1];
            }
        }
    }
}

/// Template values and gradients (central differences) of the `win x win` window
/// centred at `(cx, cy)`, plus its structure tensor.
fn make_template(lv: &Level, cx: f32, cy: f32, win: usize, patch: &mut [f32], t: &mut Template) {
    let r = (win / 2) as f32;
    let pw = win + 2;
    sample(lv, cx - r - 1.0, cy - r - 1.0, pw, patch);
    let (mut gxx, mut gxy, mut gyy) = (0.0f32, 0.0f32, 0.0f32);
    for j in 0..win {
        let row = (j + 1) * pw;
        for i in 0..win {
            let k = row + i + 1;
            let gx = 0.5 * (patch[k + 1] - patch[k - 1]);
            let gy = 0.5 * (patch[k + pw] - patch[k - pw]);
            let o = j * win + i;
            t.val[o] = patch[k];
            t.gx[o] = gx;
            t.gy[o] = gy;
            gxx += gx * gx;
            gxy += gx * gy;
            gyy += gy * gy;
        }
    }
    t.gxx = gxx;
    t.gxy = gxy;
    t.gyy = gyy;
    let (mean, norm) = mean_norm(&t.val);
    t.mean = mean;
    t.norm = norm;
}

/// Mean and centred Euclidean norm of a non-empty slice (two passes: exact enough
/// in `f32` for 0..=255 values).
fn mean_norm(v: &[f32]) -> (f32, f32) {
    let mean = v.iter().sum::<f32>() / v.len() as f32;
    let ss: f32 = v.iter().map(|&x| (x - mean) * (x - mean)).sum();
    (mean, ss.sqrt())
}

/// The normalised cross-correlation of `prev` over `rect` (`[x0, y0, x1, y1)`)
/// with `cur` shifted by `(dx, dy)`, over the samples of a stride that keeps at
/// most `samples` of them, and of those the ones the shift keeps inside
/// `cur` (at least half); NaN when fewer overlap, or either side has no contrast
/// (or holds a non-finite pixel). `prev` and `cur` have the same size.
fn ncc(prev: &Level, cur: &Level, rect: [usize; 4], dx: isize, dy: isize, samples: usize) -> f32 {
    let [x0, y0, x1, y1] = rect;
    let (w, h) = (prev.w as isize, prev.h as isize);
    let area = (x1 - x0) * (y1 - y0);
    let stride = ((area as f64 / samples.max(1) as f64).sqrt().ceil() as usize).max(1);
    let count = (x1 - x0).div_ceil(stride) * (y1 - y0).div_ceil(stride);
    let (mut n, mut sa, mut sb, mut saa, mut sbb, mut sab) = (0usize, 0.0f64, 0.0, 0.0, 0.0, 0.0);
    for y in (y0..y1).step_by(stride) {
        let qy = y as isize + dy;
        if qy < 0 || qy >= h {
            continue;
        }
        let (ra, rb) = (y * prev.w, qy as usize * cur.w);
        for x in (x0..x1).step_by(stride) {
            let qx = x as isize + dx;
            if qx < 0 || qx >= w {
                continue;
            }
            let a = f64::from(prev.data[ra + x]);
            let b = f64::from(cur.data[rb + qx as usize]);
            n += 1;
            sa += a;
            sb += b;
            saa += a * a;
            sbb += b * b;
            sab += a * b;
        }
    }
    if 2 * n < count || n < 2 {
        return f32::NAN;
    }
    let m = n as f64;
    let va = saa - sa * sa / m;
    let vb = sbb - sb * sb / m;
    if va > 1e-6 * m && vb > 1e-6 * m {
        ((sab - sa * sb / m) / (va * vb).sqrt()) as f32
    } else {
        f32::NAN
    }
}

/// Gauss-Newton iterations of one level, starting at `(x, y)` in `cur`.
/// Returns the refinement `(dx, dy)` and the relative residual, or `None` when the system is singular or
/// the point leaves the level.
#[allow(clippy::too_many_arguments)]
fn solve_level(
    t: &Template,
    cur: &Level,
    x: f32,
    y: f32,
    r: f32,
    iters: usize,
    eps: f32,
    warped: &mut [f32],
) -> Option<(f32, f32, f32)> {
    let det = t.gxx * t.gyy - t.gxy * t.gxy;
    let n = t.val.len() as f32;
    // singular or nearly so: the determinant of the structure tensor averaged over
    // the window (det / n²) at most 1e-6 (gray levels per pixel, to the fourth). The
    // floor is absolute, not relative to the window's gradients, and low: level 0's
    // texture test (`min_eigen`, 2 by default) asks at least 2² = 4 of it; the
    // coarser levels have no texture test of their own, and this floor is all they
    // must pass
    if det.is_nan() || det <= 1e-6 * n * n {
        return None;
    }
    let inv = 1.0 / det;
    let side = t.val.len().isqrt();
    let (mut dx, mut dy) = (0.0f32, 0.0f32);
    let mut sse = 0.0f32;
    for _ in 0..iters {
        let (qx, qy) = (x + dx, y + dy);
        if !(qx > -r && qy > -r && qx < cur.w as f32 - 1.0 + r && qy < cur.h as f32 - 1.0 + r) {
            return None;
        }
        sample(cur, qx - r, qy - r, side, warped);
        // photometric normalisation: match the window's mean and contrast to the
        // template's, so exposure and gain changes between frames do not bias the flow
        let (wm, wn) = mean_norm(warped);
        let gain = if wn > 1e-3 * n {
            (t.norm / wn).clamp(0.5, 2.0)
        } else {
            1.0
        };
        let (mut bx, mut by) = (0.0f32, 0.0f32);
        sse = 0.0;
        for (((&tv, &gx), &gy), &iv) in t.val.iter().zip(&t.gx).zip(&t.gy).zip(warped.iter()) {
            let e = (tv - t.mean) - gain * (iv - wm);
            bx += gx * e;
            by += gy * e;
            sse += e * e;
        }
        let ux = inv * (t.gyy * bx - t.gxy * by);
        let uy = inv * (t.gxx * by - t.gxy * bx);
        dx += ux;
        dy += uy;
        if ux * ux + uy * uy < eps * eps {
            break;
        }
    }
    // residual of the last iteration relative to the template's contrast:
    // ~0.1 for a good match with sensor noise, ~1.4 for unrelated windows
    let residual = sse.sqrt() / t.norm.max(1e-6);
    if dx.is_finite() && dy.is_finite() {
        Some((dx, dy, residual))
    } else {
        None
    }
}

/// Gaussian `[1 4 6 4 1] / 16` blur and 2x decimation, edge-replicated;
/// `dst` is `ceil(w/2) x ceil(h/2)`. `tmp` holds at least `ceil(w/2) * h`.
fn pyr_down(src: &Level, dst: &mut Level, tmp: &mut [f32]) {
    let (w, h) = (src.w, src.h);
    let (dw, dh) = (dst.w, dst.h);
    // horizontal pass: h rows of dw samples
    for y in 0..h {
        let s = &src.data[y * w..(y + 1) * w];
        let t = &mut tmp[y * dw..(y + 1) * dw];
        let at = |i: isize| s[i.clamp(0, w as isize - 1) as usize];
        for (x, o) in t.iter_mut().enumerate() {
            let c = 2 * x;
            *o = if c >= 2 && c + 2 < w {
                s[c - 2] + 4.0 * (s[c - 1] + s[c + 1]) + 6.0 * s[c] + s[c + 2]
            } else {
                let c = c as isize;
                at(c - 2) + 4.0 * (at(c - 1) + at(c + 1)) + 6.0 * at(c) + at(c + 2)
            };
        }
    }
    // vertical pass: rows clamped, inner loop vectorises
    let row = |y: isize| {
        let y = y.clamp(0, h as isize - 1) as usize;
        &tmp[y * dw..(y + 1) * dw]
    };
    for y in 0..dh {
        let c = 2 * y as isize;
        let (r0, r1, r2, r3, r4) = (row(c - 2), row(c - 1), row(c), row(c + 1), row(c + 2));
        let o = &mut dst.data[y * dw..(y + 1) * dw];
        for x in 0..dw {
            o[x] = (r0[x] + 4.0 * (r1[x] + r3[x]) + 6.0 * r2[x] + r4[x]) * (1.0 / 256.0);
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A smooth, non-periodic texture (sum of sinusoids with wavelengths of 6-40 px).
    pub(crate) fn texture(x: f32, y: f32) -> f32 {
        let mut v = 128.0;
        let waves: [(f32, f32, f32, f32); 6] = [
            (0.31, 0.05, 0.0, 25.0),
            (-0.12, 0.27, 1.0, 25.0),
            (0.21, 0.33, 2.0, 20.0),
            (0.07, -0.19, 0.5, 20.0),
            (0.55, 0.40, 1.5, 12.0),
            (-0.45, 0.61, 2.5, 12.0),
        ];
        for (kx, ky, ph, a) in waves {
            v += a * (kx * x + ky * y + ph).sin();
        }
        v
    }

    /// A floor-like, broadband texture: value noise of periods 4-64 px (a hashed
    /// lattice, smoothly interpolated), amplitudes falling by 15 % an octave.
    /// Unlike [`texture`], whose few sinusoids correlate almost as well at many
    /// shifts on the pyramid's top level, it has one best shift at every scale.
    pub(crate) fn grain(x: f32, y: f32) -> f32 {
        let lattice = |i: i64, j: i64, o: u64| {
            let mut h = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
                ^ (j as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
                ^ o.wrapping_mul(0x1656_67B1_9E37_79F9);
            h ^= h >> 29;
            h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
            h ^= h >> 32;
            (h & 0xFFFF) as f32 / 65535.0 - 0.5
        };
        let smooth = |t: f32| t * t * (3.0 - 2.0 * t);
        let (mut v, mut amp) = (128.0, 90.0);
        for (o, period) in [4.0f32, 8.0, 16.0, 32.0, 64.0].into_iter().enumerate() {
            let (gx, gy) = (x / period, y / period);
            let (i, j) = (gx.floor(), gy.floor());
            let (fx, fy) = (smooth(gx - i), smooth(gy - j));
            let (i, j, o) = (i as i64, j as i64, o as u64);
            let top = lattice(i, j, o) + (lattice(i + 1, j, o) - lattice(i, j, o)) * fx;
            let bot = lattice(i, j + 1, o) + (lattice(i + 1, j + 1, o) - lattice(i, j + 1, o)) * fx;
            v += amp * (top + (bot - top) * fy);
            amp *= 0.85;
        }
        v
    }

    /// A frame whose content at pixel p is `tex(map(p))`.
    fn textured(
        w: usize,
        h: usize,
        tex: fn(f32, f32) -> f32,
        map: impl Fn(f32, f32) -> (f32, f32),
    ) -> GrayFrame<'static, f32> {
        let data = (0..w * h)
            .map(|i| {
                let (x, y) = map((i % w) as f32, (i / w) as f32);
                tex(x, y)
            })
            .collect();
        GrayFrame::owned_f32(w, h, data).unwrap()
    }

    /// A frame whose content at pixel p is `grain(map(p))`.
    pub(crate) fn grain_frame(
        w: usize,
        h: usize,
        map: impl Fn(f32, f32) -> (f32, f32),
    ) -> GrayFrame<'static, f32> {
        textured(w, h, grain, map)
    }

    /// A frame whose content at pixel p is `texture(map(p))`.
    pub(crate) fn frame(
        w: usize,
        h: usize,
        map: impl Fn(f32, f32) -> (f32, f32),
    ) -> GrayFrame<'static, f32> {
        textured(w, h, texture, map)
    }

    fn flow_of(
        cfg: FlowConfig,
        a: &GrayFrame<f32>,
        b: &GrayFrame<f32>,
    ) -> (FlowStats, Vec<FlowVector>) {
        let mut lk = PyrLk::new(cfg).unwrap();
        assert!(lk.push(a).unwrap().is_none());
        let s = lk.push(b).unwrap().unwrap();
        (s, lk.vectors().to_vec())
    }

    #[test]
    fn subpixel_shifts_are_accurate() {
        let (w, h) = (320, 240);
        let a = frame(w, h, |x, y| (x, y));
        for (sx, sy) in [(0.3, 0.0), (1.7, -0.6), (4.2, 2.9), (-3.3, 7.1)] {
            let b = frame(w, h, |x, y| (x - sx, y - sy));
            let (s, v) = flow_of(FlowConfig::default(), &a, &b);
            assert_eq!(s.tracked, s.points, "shift ({sx}, {sy}): {s:?}");
            let mut worst = 0.0f32;
            for p in &v {
                worst = worst.max((p.dx - sx).hypot(p.dy - sy));
            }
            eprintln!("shift ({sx}, {sy}): worst error {worst:.4} px");
            assert!(worst < 0.1, "shift ({sx}, {sy}): worst error {worst} px");
        }
    }

    #[test]
    fn zoom_gives_radial_flow() {
        let (w, h) = (320, 240);
        let (cx, cy) = (160.0, 170.0);
        let k = 1.03f32;
        let a = frame(w, h, |x, y| (x, y));
        // the second frame is the first magnified by k about (cx, cy)
        let b = frame(w, h, |x, y| (cx + (x - cx) / k, cy + (y - cy) / k));
        // one way, a point at p moves by (k - 1)(p - c); back, the point that
        // ends at p came from c + (p - c) / k: their mean is (k - 1/k) / 2 (p - c)
        for (symmetric, gain) in [(false, k - 1.0), (true, 0.5 * (k - 1.0 / k))] {
            let cfg = FlowConfig {
                symmetric,
                ..FlowConfig::default()
            };
            let (s, v) = flow_of(cfg, &a, &b);
            assert!(s.tracked > s.points * 9 / 10, "{s:?}");
            // a 3 % zoom deforms a 9x9 window by up to 0.12 px (and the 4x larger
            // coarse-level windows more), which the translation model cannot
            // follow: individual points are allowed 0.12 px, the mean error must
            // stay small
            let (mut worst, mut sum) = (0.0f32, 0.0f32);
            for p in &v {
                let (ex, ey) = (gain * (p.x - cx), gain * (p.y - cy));
                let err = (p.dx - ex).hypot(p.dy - ey);
                assert!(err < 0.12, "{p:?}: expected ({ex}, {ey}), error {err}");
                worst = worst.max(err);
                sum += err;
            }
            let mean = sum / v.len() as f32;
            eprintln!(
                "zoom 3 %, symmetric {symmetric}: mean error {mean:.4} px, worst {worst:.4} px"
            );
            assert!(mean < 0.05, "mean error {mean}");
        }
    }

    /// A ROI high in a 320x240 frame, so that 32 px of downward motion stay in
    /// the crop.
    fn room_below(predict: bool) -> FlowConfig {
        FlowConfig {
            predict,
            margin_px: 48,
            roi: Roi {
                x0: 0.25,
                x1: 0.75,
                y0: 0.3,
                y1: 0.6,
            },
            ..FlowConfig::default()
        }
    }

    /// Vectors of the last pair within 0.1 px of `d` px straight down.
    fn good_downward(lk: &PyrLk, d: f32) -> usize {
        lk.vectors()
            .iter()
            .filter(|v| v.dx.abs() < 0.1 && (v.dy - d).abs() < 0.1)
            .count()
    }

    #[test]
    fn fast_motion_is_tracked_from_the_prediction() {
        // a robot speeding up: 4, 8, ..., 32 px per frame downward. From the
        // previous pair's flow every pair is a 4 px correction; from zero, the
        // pyramid (3 levels, 9x9) cannot reach 28 px. The ROI leaves room below.
        let (w, h) = (320, 240);
        let steps = [4.0f32, 8.0, 12.0, 16.0, 20.0, 24.0, 28.0, 32.0];
        for predict in [true, false] {
            let mut lk = PyrLk::new(room_below(predict)).unwrap();
            let mut pos = 0.0f32;
            lk.push(&frame(w, h, |x, y| (x, y))).unwrap();
            for (i, &d) in steps.iter().enumerate() {
                pos += d;
                let st = lk.push(&frame(w, h, |x, y| (x, y - pos))).unwrap().unwrap();
                let good = good_downward(&lk, d);
                if predict {
                    assert!(good >= st.points * 9 / 10, "{d} px: {good} good, {st:?}");
                } else if d >= 28.0 {
                    assert!(
                        good < st.points / 2,
                        "{d} px: {good} good from zero, {st:?}"
                    );
                }
                eprintln!(
                    "predict {predict}, pair {i}, {d} px: {good} good of {}",
                    st.points
                );
            }
        }
    }

    #[test]
    fn a_start_at_speed_is_found_by_the_coarse_search() {
        // the first pair of a tracker (a start, a restart after a gap) while the
        // robot is fast: no point has a flow to start from. From zero the pyramid
        // does not reach 30+ px (predict off: no search); the ROI's coarse shift
        // is a start within reach for every point
        let (w, h) = (320, 240);
        let a = grain_frame(w, h, |x, y| (x, y));
        for (sx, sy) in [(0.0f32, 36.0f32), (10.0, 40.0), (-14.0, 30.0), (0.0, 2.5)] {
            let b = grain_frame(w, h, |x, y| (x - sx, y - sy));
            for predict in [true, false] {
                let (st, v) = flow_of(room_below(predict), &a, &b);
                let good = v
                    .iter()
                    .filter(|p| (p.dx - sx).hypot(p.dy - sy) < 0.1)
                    .count();
                eprintln!(
                    "shift ({sx}, {sy}), predict {predict}: {good} good of {}",
                    st.points
                );
                if predict || sy < 10.0 {
                    assert!(
                        good >= st.points * 9 / 10,
                        "({sx}, {sy}): {good} good, {st:?}"
                    );
                } else {
                    assert!(
                        good < st.points / 2,
                        "({sx}, {sy}): {good} good from zero, {st:?}"
                    );
                }
            }
        }
    }

    const NONE: [Option<(f32, f32)>; SEARCH_BANDS] = [None; SEARCH_BANDS];

    /// The coarse search on the pair `a` → `b`, as the tracker's first pair sees
    /// it: each band's start.
    fn coarse(
        cfg: FlowConfig,
        a: &GrayFrame<f32>,
        b: &GrayFrame<f32>,
    ) -> [Option<(f32, f32)>; SEARCH_BANDS] {
        let mut lk = PyrLk::new(cfg).unwrap();
        assert!(lk.push(a).unwrap().is_none());
        lk.build_pyramid(b);
        lk.coarse_search();
        lk.band_start
    }

    #[test]
    fn while_nothing_tracks_the_search_runs_on_one_pair_in_four() {
        // every frame unrelated to the one before (a textured scene, nothing
        // that tracks): the search that finds nothing waits three pairs
        let (w, h) = (320, 240);
        let mut lk = PyrLk::new(room_below(true)).unwrap();
        for k in 0..13u64 {
            // fresh pixel noise every frame
            let data = (0..w * h)
                .map(|i| {
                    let mut z = (i as u64 ^ (k << 32)).wrapping_mul(0x9E37_79B9_7F4A_7C15);
                    z ^= z >> 31;
                    z = z.wrapping_mul(0xBF58_476D_1CE4_E5B9);
                    z ^= z >> 29;
                    64.0 + (z & 0x7F) as f32
                })
                .collect();
            let f = GrayFrame::owned_f32(w, h, data).unwrap();
            if let Some(st) = lk.push(&f).unwrap() {
                assert_eq!(st.tracked, 0, "pair {k}: {st:?}");
            }
        }
        assert_eq!(lk.searches(), 3, "12 pairs");
        // a reset searches at once: a start at speed is found
        lk.reset();
        lk.push(&grain_frame(w, h, |x, y| (x, y))).unwrap();
        let st = lk
            .push(&grain_frame(w, h, |x, y| (x, y - 36.0)))
            .unwrap()
            .unwrap();
        assert_eq!(lk.searches(), 4);
        assert!(st.tracked >= st.points * 9 / 10, "{st:?}");
    }

    #[test]
    fn a_periodic_floor_gives_no_coarse_start() {
        // tiles: a pattern repeating every 24 px both ways, shifted by 30 px. The
        // shifts 24 px apart match equally well: no start (the points search from
        // zero, as without the search)
        let (w, h) = (320, 240);
        let tile = |x: f32, y: f32| {
            let k = std::f32::consts::TAU / 24.0;
            128.0 + 40.0 * (k * x).sin() + 40.0 * (k * y).cos() + 20.0 * (2.0 * k * (x + y)).sin()
        };
        let make = |dy: f32| {
            let data = (0..w * h)
                .map(|i| tile((i % w) as f32, (i / w) as f32 - dy))
                .collect();
            GrayFrame::owned_f32(w, h, data).unwrap()
        };
        assert_eq!(coarse(room_below(true), &make(0.0), &make(30.0)), NONE);
        // the same shift of a floor's grain is found, to the top level's pixel
        let a = grain_frame(w, h, |x, y| (x, y));
        let b = grain_frame(w, h, |x, y| (x, y - 30.0));
        for start in coarse(room_below(true), &a, &b) {
            let (gx, gy) = start.expect("a start");
            assert!(gx.abs() <= 2.0 && (gy - 30.0).abs() <= 2.0, "({gx}, {gy})");
        }
        // a frame without contrast, or unrelated content: no start
        let flat = GrayFrame::owned_f32(w, h, vec![100.0; w * h]).unwrap();
        assert_eq!(coarse(room_below(true), &a, &flat), NONE);
        let other = grain_frame(w, h, |x, y| (y + 500.0, -x));
        assert_eq!(coarse(room_below(true), &a, &other), NONE);
        // no margin, nothing to reach
        let none = FlowConfig {
            margin_px: 0,
            ..room_below(true)
        };
        assert_eq!(coarse(none, &a, &b), NONE);
    }

    #[test]
    fn a_point_lost_at_speed_is_found_again_from_its_neighbours() {
        // as above, but the frame at 24 px has no texture on its left half, so
        // the points there are lost for two pairs (tracked into a flat frame,
        // then without a template). At 28 and 32 px per frame they are beyond
        // the pyramid's reach from zero: without a vector of their own they must
        // start from their neighbours' (or their row's) flow, or they stay lost,
        // or worse, for as long as the robot is fast
        let (w, h) = (320, 240);
        let steps = [4.0f32, 8.0, 12.0, 16.0, 20.0, 24.0, 28.0, 32.0];
        let mut lk = PyrLk::new(room_below(true)).unwrap();
        let mut pos = 0.0f32;
        lk.push(&frame(w, h, |x, y| (x, y))).unwrap();
        for (i, &d) in steps.iter().enumerate() {
            pos += d;
            let f = if i == 5 {
                let data = (0..w * h)
                    .map(|k| {
                        let (x, y) = ((k % w) as f32, (k / w) as f32);
                        if x < 160.0 {
                            128.0
                        } else {
                            texture(x, y - pos)
                        }
                    })
                    .collect();
                GrayFrame::owned_f32(w, h, data).unwrap()
            } else {
                frame(w, h, |x, y| (x, y - pos))
            };
            let st = lk.push(&f).unwrap().unwrap();
            let good = good_downward(&lk, d);
            eprintln!("pair {i}, {d} px: {good} good of {}", st.points);
            if i == 6 {
                // the left half had no template in the last pair
                assert!(good < st.points * 6 / 10, "{d} px: {good} good, {st:?}");
            } else if i == 7 {
                assert!(good >= st.points * 9 / 10, "{d} px: {good} good, {st:?}");
            }
        }
    }

    #[test]
    fn a_lost_point_is_predicted_from_its_neighbours_then_its_row() {
        let n = NO_FLOW;
        // 3 rows of 4
        let prior = [
            [1.0, 10.0],
            n,
            [3.0, 30.0],
            n, //
            n,
            n,
            [5.0, 50.0],
            n, //
            n,
            n,
            n,
            [7.0, 70.0],
        ];
        // its own vector
        assert_eq!(predicted_flow(&prior, 4, 0), Some([1.0, 10.0]));
        // the median of its tracked 8-neighbours: (1, 10), (3, 30), (5, 50)
        assert_eq!(predicted_flow(&prior, 4, 5), Some([3.0, 30.0]));
        assert_eq!(predicted_flow(&prior, 4, 1), Some([3.0, 30.0]));
        // two neighbours: their mean; one: its vector
        assert_eq!(predicted_flow(&prior, 4, 3), Some([4.0, 40.0]));
        assert_eq!(predicted_flow(&prior, 4, 4), Some([1.0, 10.0]));
        // none around (row 2, column 0): the nearest tracked point of its row
        assert_eq!(predicted_flow(&prior, 4, 8), Some([7.0, 70.0]));
        // nothing tracked at all, or out of range: no prediction
        assert_eq!(predicted_flow(&[n; 12], 4, 5), None);
        assert_eq!(predicted_flow(&prior, 4, 12), None);
        assert_eq!(predicted_flow(&prior, 0, 1), None);
    }

    #[test]
    fn symmetric_tracking_cancels_the_change_of_flow_along_the_way() {
        // content at row y moves to c + (y - c) e^a: the flow grows along the way,
        // like the floor ahead of a robot sliding down the image. One way, the
        // mean of dy / (y - c) is e^a - 1 (second order in a); both ways it is
        // sinh a = a (1 + a²/6): linear in the "speed" a
        let (w, h) = (320, 240);
        let c = 60.0f32;
        let a0 = frame(w, h, |x, y| (x, y));
        for a in [0.02f32, 0.05, 0.08] {
            let b = frame(w, h, |x, y| (x, c + (y - c) * (-a).exp()));
            let mean_gain = |symmetric| {
                let cfg = FlowConfig {
                    symmetric,
                    ..FlowConfig::default()
                };
                let (s, v) = flow_of(cfg, &a0, &b);
                assert!(s.tracked >= s.points * 9 / 10, "{s:?}");
                v.iter().map(|p| p.dy / (p.y - c)).sum::<f32>() / v.len() as f32
            };
            let (one, both) = (mean_gain(false), mean_gain(true));
            eprintln!(
                "stretch {a}: one way {one:.5} (e^a - 1 = {:.5}), both ways {both:.5}",
                a.exp() - 1.0
            );
            assert!(
                (one - (a.exp() - 1.0)).abs() < 0.003 * a.max(0.05) / 0.05,
                "{a}: {one}"
            );
            assert!(
                (both - a.sinh()).abs() < 0.003 * a.max(0.05) / 0.05,
                "{a}: {both}"
            );
            assert!((both / a - 1.0).abs() < 0.02, "{a}: {both}");
        }
    }

    #[test]
    fn inconsistent_vectors_are_dropped() {
        let a = frame(200, 150, |x, y| (x, y));
        let cfg = FlowConfig {
            grid_cols: 4,
            grid_rows: 3,
            min_points: 0,
            ..FlowConfig::default()
        };
        let mut lk = PyrLk::new(cfg).unwrap();
        lk.push(&a).unwrap();
        // a smooth field with one wild vector and one untracked point
        for (i, f) in lk.grid_flow.iter_mut().enumerate() {
            *f = [2.0 + 0.1 * i as f32, 5.0];
        }
        lk.grid_flow[5] = [9.0, -3.0];
        lk.grid_flow[0] = NO_FLOW;
        assert_eq!(lk.drop_inconsistent(), 1);
        assert!(lk.grid_flow[5][0].is_nan() && lk.grid_flow[0][0].is_nan());
        assert_eq!(lk.grid_flow.iter().filter(|f| f[0].is_finite()).count(), 10);
        // inf disables the check
        lk.cfg.outlier_px = f32::INFINITY;
        lk.grid_flow[6] = [9.0, -3.0];
        assert_eq!(lk.drop_inconsistent(), 0);
        // and the tracker counts what it drops: everything moves 3 px down but a
        // small object around grid point (155, 168), which moves 6 px right
        let mut lk = PyrLk::new(FlowConfig::default()).unwrap();
        lk.push(&frame(320, 240, |x, y| (x, y))).unwrap();
        let object = |x: f32, y: f32| (147.0..163.0).contains(&x) && (160.0..176.0).contains(&y);
        let st = lk
            .push(&frame(320, 240, |x, y| {
                if object(x, y) {
                    (x - 6.0, y)
                } else {
                    (x, y - 3.0)
                }
            }))
            .unwrap()
            .unwrap();
        assert!(
            st.inconsistent >= 1 && st.tracked + st.inconsistent <= st.points,
            "{st:?}"
        );
        // no vector inside the object survives; windows straddling its edge may
        // be off by up to the tolerance, 1 px + 25 % of 3 px
        let bad: Vec<_> = lk
            .vectors()
            .iter()
            .filter(|v| v.dx.hypot(v.dy - 3.0) > 1.75)
            .collect();
        assert!(bad.is_empty(), "{bad:?}");
        assert!(PyrLk::new(FlowConfig {
            outlier_px: 0.0,
            ..FlowConfig::default()
        })
        .is_err());
        assert!(PyrLk::new(FlowConfig {
            outlier_rel: f32::NAN,
            ..FlowConfig::default()
        })
        .is_err());
    }

    /// Adds uniform noise of standard deviation `sigma` (deterministic xorshift).
    fn noisy(
        f: &GrayFrame<f32>,
        sigma: f32,
        seed: u64,
        gain: f32,
        offset: f32,
    ) -> GrayFrame<'static, f32> {
        let mut s = seed | 1;
        let data = f
            .pixels()
            .iter()
            .map(|&v| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                let u = (s >> 40) as f32 / (1u64 << 24) as f32 - 0.5; // uniform, sd 1/sqrt(12)
                v * gain + offset + u * sigma * 12f32.sqrt()
            })
            .collect();
        GrayFrame::owned_f32(f.width(), f.height(), data).unwrap()
    }

    #[test]
    fn exposure_changes_do_not_bias_the_flow() {
        let (w, h) = (320, 240);
        let a = frame(w, h, |x, y| (x, y));
        let b = frame(w, h, |x, y| (x - 1.7, y + 0.6));
        for (gain, off) in [(1.1, 0.0), (1.0, 15.0), (0.85, 10.0)] {
            let b = noisy(&b, 0.0, 1, gain, off);
            let (s, v) = flow_of(FlowConfig::default(), &a, &b);
            assert_eq!(s.tracked, s.points);
            for p in &v {
                let err = (p.dx - 1.7).hypot(p.dy + 0.6);
                assert!(err < 0.1, "gain {gain} offset {off}: {p:?}");
            }
        }
    }

    #[test]
    fn sensor_noise_keeps_the_mean_flow_accurate() {
        let (w, h) = (320, 240);
        let a = noisy(&frame(w, h, |x, y| (x, y)), 2.0, 7, 1.0, 0.0);
        let b = noisy(&frame(w, h, |x, y| (x - 2.5, y - 1.0)), 2.0, 11, 1.0, 0.0);
        let (s, v) = flow_of(FlowConfig::default(), &a, &b);
        assert!(s.tracked >= s.points * 9 / 10, "{s:?}");
        let n = v.len() as f32;
        let (mx, my) = v
            .iter()
            .fold((0.0, 0.0), |(x, y), p| (x + p.dx / n, y + p.dy / n));
        let worst = v
            .iter()
            .map(|p| (p.dx - 2.5).hypot(p.dy - 1.0))
            .fold(0.0f32, f32::max);
        eprintln!("noise sd 2: mean flow ({mx:.4}, {my:.4}), worst point error {worst:.3} px");
        assert!((mx - 2.5).abs() < 0.02 && (my - 1.0).abs() < 0.02);
        assert!(worst < 0.3);
        // pure noise on a flat frame is not texture
        let flat = GrayFrame::owned_f32(w, h, vec![120.0; w * h]).unwrap();
        let (s, _) = flow_of(
            FlowConfig::default(),
            &noisy(&flat, 2.0, 3, 1.0, 0.0),
            &noisy(&flat, 2.0, 5, 1.0, 0.0),
        );
        assert!(s.low_texture, "{s:?}");
    }

    #[test]
    fn non_finite_pixels_are_not_texture() {
        let (w, h) = (200, 150);
        let mut px = frame(w, h, |x, y| (x, y)).pixels().to_vec();
        for (i, v) in px.iter_mut().enumerate() {
            if i % 3 == 0 {
                *v = if i % 2 == 0 { f32::NAN } else { f32::INFINITY };
            }
        }
        let f = GrayFrame::owned_f32(w, h, px).unwrap();
        let (s, v) = flow_of(FlowConfig::default(), &f, &f);
        assert_eq!((s.textured, s.tracked), (0, 0), "{s:?}");
        assert!(v.is_empty());
    }

    #[test]
    fn unrelated_content_is_rejected() {
        let (w, h) = (320, 240);
        let a = frame(w, h, |x, y| (x, y));
        // white noise: strong gradients, nothing in common with `a`
        let flat = GrayFrame::owned_f32(w, h, vec![128.0; w * h]).unwrap();
        let b = noisy(&flat, 40.0, 9, 1.0, 0.0);
        let (s, _) = flow_of(FlowConfig::default(), &a, &b);
        assert!(s.tracked < s.points / 4, "{s:?}");
        assert!(s.low_texture);
    }

    #[test]
    fn flat_frame_is_low_texture() {
        let (w, h) = (200, 150);
        let a = GrayFrame::owned(w, h, vec![100u8; w * h]).unwrap();
        let mut lk = PyrLk::new(FlowConfig::default()).unwrap();
        lk.push(&a).unwrap();
        let s = lk.push(&a).unwrap().unwrap();
        assert_eq!(s.textured, 0);
        assert_eq!(s.tracked, 0);
        assert!(s.low_texture);
        assert!(lk.vectors().is_empty());
    }

    #[test]
    fn size_change_restarts_and_reset_forgets() {
        let a = frame(200, 150, |x, y| (x, y));
        let b = frame(210, 150, |x, y| (x, y));
        let mut lk = PyrLk::new(FlowConfig::default()).unwrap();
        assert!(lk.push(&a).unwrap().is_none());
        assert!(lk.push(&a).unwrap().is_some());
        assert!(lk.push(&b).unwrap().is_none());
        assert_eq!(lk.frame_size(), Some((210, 150)));
        lk.reset();
        assert!(lk.push(&b).unwrap().is_none());
    }

    #[test]
    fn grid_is_empty_of_flows_after_a_reset_or_a_restart() {
        // a pair with flow, then a reset (or a restart by the caller): the next
        // push starts a new pair, and grid() must not serve the old pair's flows
        let a = frame(200, 150, |x, y| (x, y));
        let b = frame(200, 150, |x, y| (x, y - 2.0));
        let c = frame(200, 150, |x, y| (x, y - 50.0));
        let finite = |lk: &PyrLk| {
            lk.grid()
                .filter(|v| v.dx.is_finite() || v.dy.is_finite())
                .count()
        };
        let mut lk = PyrLk::new(FlowConfig::default()).unwrap();
        assert!(lk.push(&a).unwrap().is_none());
        assert!(lk.push(&b).unwrap().unwrap().tracked > 0);
        assert!(finite(&lk) > 0);
        lk.reset();
        assert_eq!(finite(&lk), 0, "grid() after reset()");
        assert!(lk.push(&c).unwrap().is_none());
        assert!(lk.vectors().is_empty());
        assert_eq!(finite(&lk), 0, "grid() after reset() and a first frame");
        // the same through a restart without reset(): a size change
        assert!(lk.push(&a).unwrap().is_some());
        assert!(lk.push(&b).unwrap().unwrap().tracked > 0);
        assert!(finite(&lk) > 0);
        let d = frame(210, 150, |x, y| (x, y));
        assert!(lk.push(&d).unwrap().is_none());
        assert_eq!(finite(&lk), 0, "grid() after a size change");
        // every grid point is still listed, with NaN flows
        assert!(lk.grid().len() > 0);
    }

    #[test]
    fn tiny_frames_are_errors_not_panics() {
        let mut lk = PyrLk::new(FlowConfig::default()).unwrap();
        for (w, h) in [(1, 1), (2, 3), (10, 10), (40, 30), (5000, 1)] {
            let f = GrayFrame::owned(w, h, vec![7u8; w * h]).unwrap();
            let e = lk.push(&f).unwrap_err();
            assert!(matches!(e, Error::FrameTooSmall { .. }), "{w}x{h}: {e}");
        }
        // after an error the next good frame starts afresh
        let a = frame(200, 150, |x, y| (x, y));
        assert!(lk.push(&a).unwrap().is_none());
    }

    #[test]
    fn config_validation_names_the_field() {
        let bad = [
            FlowConfig {
                window: 8,
                ..FlowConfig::default()
            },
            FlowConfig {
                levels: 0,
                ..FlowConfig::default()
            },
            FlowConfig {
                roi: Roi {
                    x0: 0.5,
                    x1: 0.4,
                    y0: 0.0,
                    y1: 1.0,
                },
                ..FlowConfig::default()
            },
            FlowConfig {
                min_eigen: f32::NAN,
                ..FlowConfig::default()
            },
            FlowConfig {
                min_points: 1000,
                ..FlowConfig::default()
            },
        ];
        for (cfg, field) in bad.iter().zip([
            "flow.window",
            "flow.levels",
            "flow.roi.x1",
            "flow.min_eigen",
            "flow.min_points",
        ]) {
            match PyrLk::new(*cfg) {
                Err(Error::InvalidConfig { field: f, .. }) => assert_eq!(f, field),
                other => panic!("{field}: {other:?}"),
            }
        }
    }

    #[test]
    fn pyr_down_preserves_constant_and_mean() {
        let src = Level {
            w: 7,
            h: 5,
            data: vec![3.0; 35],
        };
        let mut dst = Level {
            w: 4,
            h: 3,
            data: vec![0.0; 12],
        };
        let mut tmp = vec![0.0; 4 * 5];
        pyr_down(&src, &mut dst, &mut tmp);
        assert!(dst.data.iter().all(|&v| (v - 3.0).abs() < 1e-6));
    }

    proptest! {
        /// Any field of last flows (NaN where untracked), any grid width and index:
        /// no panic; a prediction exactly when the point, a neighbour or a point of
        /// its row was tracked; within the range of the tracked vectors.
        #[test]
        fn predictions_come_from_tracked_vectors(
            field in proptest::collection::vec(
                proptest::option::weighted(0.4, (-50.0f32..50.0, -50.0f32..50.0)), 0..40),
            cols in 0usize..9, i in 0usize..45,
        ) {
            let prior: Vec<[f32; 2]> = field
                .iter()
                .map(|v| v.map_or(NO_FLOW, |(x, y)| [x, y]))
                .collect();
            let got = predicted_flow(&prior, cols, i);
            let tracked = |k: usize| prior.get(k).is_some_and(|v| v[0].is_finite());
            let expected = if i >= prior.len() {
                false
            } else if tracked(i) {
                true
            } else if cols == 0 || i / cols >= prior.len() / cols {
                // no grid, or past its last whole row
                false
            } else {
                let rows = prior.len() / cols;
                let (j, c) = (i / cols, i % cols);
                let rows_around = j.saturating_sub(1)..(j + 2).min(rows);
                rows_around
                    .flat_map(|jj| (c.saturating_sub(1)..(c + 2).min(cols)).map(move |ii| jj * cols + ii))
                    .any(|k| k != i && tracked(k))
                    || (0..cols).any(|ii| tracked(j * cols + ii))
            };
            prop_assert_eq!(got.is_some(), expected, "{:?} cols {} i {}", got, cols, i);
            if let Some([x, y]) = got {
                let fin: Vec<[f32; 2]> = prior.iter().copied().filter(|v| v[0].is_finite()).collect();
                let (lo_x, hi_x) = fin.iter().fold((f32::MAX, f32::MIN), |a, v| (a.0.min(v[0]), a.1.max(v[0])));
                let (lo_y, hi_y) = fin.iter().fold((f32::MAX, f32::MIN), |a, v| (a.0.min(v[1]), a.1.max(v[1])));
                prop_assert!(x >= lo_x && x <= hi_x && y >= lo_y && y <= hi_y);
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]
        /// Any frame content and (small) size: no panic, finite flow.
        #[test]
        fn arbitrary_frames_never_panic(
            w in 1usize..120, h in 1usize..120, seed in any::<u64>(), levels in 1usize..5,
        ) {
            let mut s = seed | 1;
            let mut next = || { s ^= s << 13; s ^= s >> 7; s ^= s << 17; (s >> 56) as u8 };
            let a: Vec<u8> = (0..w * h).map(|_| next()).collect();
            let b: Vec<u8> = (0..w * h).map(|_| next()).collect();
            let cfg = FlowConfig { levels, margin_px: 8, min_points: 0, ..FlowConfig::default() };
            let mut lk = PyrLk::new(cfg).unwrap();
            let fa = GrayFrame::owned(w, h, a).unwrap();
            let fb = GrayFrame::owned(w, h, b).unwrap();
            if lk.push(&fa).is_ok() {
                let st = lk.push(&fb).unwrap().unwrap();
                prop_assert!(st.tracked <= st.textured && st.textured <= st.points);
                for v in lk.vectors() {
                    prop_assert!(v.dx.is_finite() && v.dy.is_finite());
                }
            }
        }

        /// Any shift within the margin's reach: the coarse search finds it to
        /// within the top level's pixel (4 px), and the first pair tracks it.
        #[test]
        fn coarse_search_finds_any_shift_within_reach(sx in -40.0f32..40.0, sy in -40.0f32..40.0) {
            let a = grain_frame(320, 240, |x, y| (x, y));
            let b = grain_frame(320, 240, |x, y| (x - sx, y - sy));
            let cfg = FlowConfig { margin_px: 48, ..room_below(true) };
            for start in coarse(cfg, &a, &b) {
                let (gx, gy) = start.expect("a start");
                prop_assert!((gx - sx).abs() <= 4.0 && (gy - sy).abs() <= 4.0, "({gx}, {gy})");
            }
            let (st, v) = flow_of(cfg, &a, &b);
            let good = v.iter().filter(|p| (p.dx - sx).hypot(p.dy - sy) < 0.1).count();
            prop_assert!(good >= st.points * 9 / 10, "{} good, {:?}", good, st);
        }

        /// Uniform subpixel shifts in range are recovered to 0.1 px.
        #[test]
        fn random_shifts(sx in -6.0f32..6.0, sy in -6.0f32..6.0) {
            let a = frame(240, 180, |x, y| (x, y));
            let b = frame(240, 180, |x, y| (x - sx, y - sy));
            let (s, v) = flow_of(FlowConfig::default(), &a, &b);
            prop_assert!(s.tracked >= s.points * 9 / 10);
            for p in &v {
                prop_assert!((p.dx - sx).hypot(p.dy - sy) < 0.1, "{:?}", p);
            }
        }
    }
}
