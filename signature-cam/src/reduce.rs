//! Reductions of per-point flow vectors to one scalar.
//!
//! [`Reducer::reduce`]'s means are **trimmed** means (the `trim` fraction of
//! values is dropped at each end before averaging), which makes them robust to the few points that LK
//! mis-tracks (moving objects, specular spots, repetitive texture), while
//! keeping a mean's low noise. `trim = 0` gives the plain mean; the median is
//! the 0.5 limit.
//!
//! ```
//! use vlsync_signature_cam::flow::FlowVector;
//! use vlsync_signature_cam::reduce::{Reducer, Reduction};
//! let v = |dx, dy| FlowVector { x: 0.0, y: 0.0, dx, dy };
//! let flows = [v(3.0, 4.0), v(0.0, 5.0), v(5.0, 0.0), v(60.0, 80.0)]; // one outlier
//! let mut r = Reducer::new(Reduction::MedianMagnitude, 0.0).unwrap();
//! assert_eq!(r.reduce(&flows, (640, 480)), Some(5.0));
//! let mut r = Reducer::new(Reduction::MeanMagnitude, 0.25).unwrap();
//! assert_eq!(r.reduce(&flows, (640, 480)), Some(5.0)); // outlier trimmed
//! ```

use crate::flow::FlowVector;
use crate::Error;
use serde::{Deserialize, Serialize};

/// How the flow vectors of a frame become one number (pixels per frame pair).
///
/// The default is [`Reduction::Forward`] along `[0, 1]` (image down): for a
/// camera looking ahead at the floor, driving forward moves the floor down the
/// image, and the mean vertical flow over an ROI centred left-right is the
/// forward speed alone. Turning adds flow too, mostly sideways, and its vertical
/// part is opposite on the two halves of the ROI and cancels in the mean: a
/// 1 rad/s turn shows up as well under 1 % of the flow of driving at 0.3 m/s
/// (measured on rendered runs), where it dominates the flow magnitude
/// ([`Reduction::MeanMagnitude`]: about 0.5 m/s worth of flow). The forward
/// component is signed, so reversing reads negative, like the distance rate of
/// a LiDAR.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Reduction {
    /// Trimmed mean of `|v|`. Unsigned; sees rotation as much as translation.
    MeanMagnitude,
    /// Median of `|v|`. Unsigned.
    MedianMagnitude,
    /// Trimmed mean of `v . u` for the unit vector `u` along `direction`
    /// (image coordinates, +y down). Signed: e.g. `[0, 1]` (the default) for a
    /// forward-looking camera whose floor flows downward when driving forward.
    Forward {
        /// Direction in image coordinates; normalised internally, must be non-zero.
        direction: [f32; 2],
    },
    /// Trimmed mean of the radial component `v . (p - f) / |p - f|` about the focus
    /// point `f` (fractions of width and height). Positive when the image expands
    /// (approaching), negative when it contracts. Points within 1 px of `f` are skipped.
    Divergence {
        /// Focus point as fractions of the frame width and height.
        focus: [f32; 2],
    },
}

impl Default for Reduction {
    /// [`Reduction::Forward`] along `[0, 1]` (image down).
    fn default() -> Self {
        Reduction::Forward {
            direction: [0.0, 1.0],
        }
    }
}

/// Default trim fraction at each end for the trimmed means: 10 %.
pub const DEFAULT_TRIM: f32 = 0.1;

/// A reduction with its scratch buffers (reused: no allocation after warm-up)
/// and, for [`Reducer::reduce_grid`], the learnt flow pattern of the grid.
#[derive(Debug, Clone)]
pub struct Reducer {
    kind: Reduction,
    trim: f32,
    unit: [f32; 2],
    scratch: Vec<f32>,
    /// Per grid point: its flow relative to the grid's mean (mean 1).
    pattern: Vec<f32>,
    /// Per grid point: frames in which it taught the pattern as a kept point
    /// (not an outlier), up to [`PATTERN_WARMUP`].
    taught: Vec<u32>,
    /// Per contributing point: (value / pattern, value, pattern, grid index).
    pairs: Vec<(f32, f32, f32, usize)>,
    /// Per grid point of the frame being reduced: (its y, its scalar or NaN).
    points: Vec<(f32, f32)>,
    /// Scratch of [`Reducer::fill_untaught`]: per grid row, (y, share).
    rows: Vec<(f32, f32)>,
}

/// Learning rate of the grid pattern, per frame with motion, once a point has
/// taught it [`PATTERN_WARMUP`] frames; before that a point's share is the
/// running mean of what it taught.
const PATTERN_RATE: f32 = 0.02;
/// Frames after which a point's share learns at [`PATTERN_RATE`] (`1 / (1 + 49)`).
const PATTERN_WARMUP: u32 = 49;
// the warm-up's last rate, 1/49, hands over to the steady 1/50 without a jump
const _: () = assert!(1.0 / (1 + PATTERN_WARMUP) as f32 == PATTERN_RATE);
/// An outlier of its frame (beyond the MAD test's bounds) teaches its point's
/// share at this fraction of [`PATTERN_RATE`], warm-up or not.
const PATTERN_OUTLIER_SLOW: f32 = 0.1;
/// Frames whose reduced flow is below this (pixels) do not teach the pattern.
const PATTERN_MIN_PX: f64 = 1.0;

impl Reducer {
    /// Validates the reduction and the trim fraction (`0 <= trim < 0.5`).
    pub fn new(kind: Reduction, trim: f32) -> Result<Self, Error> {
        if !(0.0..0.5).contains(&trim) {
            return Err(Error::InvalidConfig {
                field: "reduce.trim",
                reason: format!("{trim} is outside 0 <= trim < 0.5"),
            });
        }
        let mut unit = [0.0, 0.0];
        match kind {
            Reduction::Forward { direction: [x, y] } => {
                let n = x.hypot(y);
                if !(n.is_finite() && n > 0.0) {
                    return Err(Error::InvalidConfig {
                        field: "reduce.direction",
                        reason: format!("[{x}, {y}] is not a finite non-zero vector"),
                    });
                }
                unit = [x / n, y / n];
            }
            Reduction::Divergence { focus: [x, y] } => {
                if !(x.is_finite() && y.is_finite()) {
                    return Err(Error::InvalidConfig {
                        field: "reduce.focus",
                        reason: format!("[{x}, {y}] is not finite"),
                    });
                }
            }
            Reduction::MeanMagnitude | Reduction::MedianMagnitude => {}
        }
        Ok(Self {
            kind,
            trim,
            unit,
            scratch: Vec::new(),
            pattern: Vec::new(),
            taught: Vec::new(),
            pairs: Vec::new(),
            points: Vec::new(),
            rows: Vec::new(),
        })
    }

    /// Reserves scratch space for `n` vectors (and a grid of `n` points), so
    /// reducing up to `n` allocates nothing.
    pub fn reserve(&mut self, n: usize) {
        self.scratch.reserve(n);
        self.pairs.reserve(n);
        self.points.reserve(n);
        self.rows.reserve(n);
        if self.pattern.len() != n {
            self.pattern.clear();
            self.pattern.resize(n, 1.0);
            self.taught.clear();
            self.taught.resize(n, 0);
        }
    }

    /// Forgets the learnt grid pattern (all points equal again).
    pub fn reset_pattern(&mut self) {
        self.pattern.iter_mut().for_each(|g| *g = 1.0);
        self.taught.iter_mut().for_each(|k| *k = 0);
    }

    /// The learnt pattern of [`Reducer::reduce_grid`]: each grid point's flow
    /// relative to the grid's mean.
    pub fn pattern(&self) -> &[f32] {
        &self.pattern
    }

    /// The scalar a vector contributes (`None`: it does not).
    fn scalar(&self, p: &FlowVector, frame_size: (usize, usize)) -> Option<f32> {
        let v = match self.kind {
            Reduction::MeanMagnitude | Reduction::MedianMagnitude => p.dx.hypot(p.dy),
            Reduction::Forward { .. } => p.dx * self.unit[0] + p.dy * self.unit[1],
            Reduction::Divergence { focus: [fx, fy] } => {
                let (rx, ry) = (
                    p.x - fx * frame_size.0 as f32,
                    p.y - fy * frame_size.1 as f32,
                );
                let d = rx.hypot(ry);
                if d.is_nan() || d < 1.0 {
                    return None;
                }
                (p.dx * rx + p.dy * ry) / d
            }
        };
        v.is_finite().then_some(v)
    }

    /// Reduces a whole grid (every point, in a fixed order; untracked points have
    /// NaN flow, see [`crate::flow::PyrLk::grid`]) so that *which* points were
    /// tracked does not move the result.
    ///
    /// The flow differs across the grid (the floor near the bottom of the image
    /// moves fastest), so the plain mean of the tracked points drops whenever the
    /// fast ones go missing: after a dropped frame the floor at the bottom leaves
    /// the image, motion blur takes its texture (on rendered 640x480 runs that
    /// bent the signature by -2 % at 0.6 m/s). Each point's scalar `s_i` is
    /// modelled as `v · g_i`, with `g_i` its learnt share of the motion (mean 1
    /// over the whole grid). Ratios `s_i / g_i` farther than 4 robust σ (4 · 1.4826 · MAD, and 5 %)
    /// from their median are outliers, and the value is `Σ s_i / Σ g_i` over the
    /// points kept: the grid's mean flow as if every point had been tracked (the
    /// median ratio for [`Reduction::MedianMagnitude`]). With every point kept it
    /// is their mean whatever the pattern, so learning the pattern does not move
    /// the scale. Outliers, not a fixed share: while the robot accelerates the
    /// ratios of near and far floor spread a little, and trimming a fixed share
    /// of them would then cut mostly one side (on rendered runs a fixed 10 % trim
    /// read like a 0.5 ms delay; `trim` applies to [`Reducer::reduce`] only).
    /// The pattern starts flat; every contributing point teaches it in frames
    /// that move at least 1 px: in the point's k-th such frame in which it is
    /// kept its share moves 1/k of the way to what the frame says (about a
    /// running mean: each step is clamped to ±0.5, and the pattern is scaled
    /// back to mean 1 every frame), from its 50th 2 % of the way; in a frame in
    /// which it is an outlier, 0.2 % of the way, warm-up or not, so a
    /// mis-track moves it by 0.1 % of the mean at most. A fixed 2 % from the
    /// start needed about 100 frames of motion: a few seconds at 30 Hz, but 10 s
    /// of a 10 Hz camera, whose bottom rows (30-45 px per frame at 0.6 m/s on
    /// 320x240) are the ones lost while the robot is fast, so the unlearnt flat
    /// pattern read the first drives 13-17 % low (rendered runs, seed 5).
    /// A point that has not taught yet takes its row's share (see
    /// `Reducer::fill_untaught`: the shares learnt in its row, or the line
    /// through the rows seen), not the flat start, and an outlier does not teach
    /// it at all: a camera started while the robot is fast never sees its
    /// bottom rows until the robot slows.
    /// `None` when no point contributes; a grid of another size resets the
    /// pattern (allocating).
    pub fn reduce_grid(
        &mut self,
        grid: impl ExactSizeIterator<Item = FlowVector>,
        frame_size: (usize, usize),
    ) -> Option<f64> {
        let n = grid.len();
        if self.pattern.len() != n {
            self.reserve(n);
        }
        let mut points = std::mem::take(&mut self.points);
        points.clear();
        points.extend(
            grid.take(n)
                .map(|p| (p.y, self.scalar(&p, frame_size).unwrap_or(f32::NAN))),
        );
        self.points = points;
        if self.taught.contains(&0) && !matches!(self.kind, Reduction::Divergence { .. }) {
            self.fill_untaught();
        }
        let mut pairs = std::mem::take(&mut self.pairs);
        pairs.clear();
        for (i, &(_, s)) in self.points.iter().enumerate() {
            if s.is_finite() {
                let g = self.pattern[i];
                pairs.push((s / g, s, g, i));
            }
        }
        let out = if pairs.is_empty() {
            None
        } else {
            pairs.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
            let m = pairs.len();
            let med = if m % 2 == 1 {
                pairs[m / 2].0
            } else {
                0.5 * (pairs[m / 2 - 1].0 + pairs[m / 2].0)
            };
            self.scratch.clear();
            self.scratch.extend(pairs.iter().map(|p| (p.0 - med).abs()));
            self.scratch.sort_unstable_by(f32::total_cmp);
            let mad = self.scratch[m / 2];
            let tol = (4.0 * 1.4826 * mad).max(0.05 * med.abs()).max(1e-3);
            let lo = pairs.partition_point(|p| p.0 < med - tol);
            let hi = pairs.partition_point(|p| p.0 <= med + tol);
            let hi = hi.max(lo + 1).min(m);
            let kept = &pairs[lo..hi];
            let v = match self.kind {
                Reduction::MedianMagnitude => f64::from(med),
                _ => {
                    let (ss, sg) = kept.iter().fold((0.0f64, 0.0f64), |(a, b), &(_, s, g, _)| {
                        (a + f64::from(s), b + f64::from(g))
                    });
                    ss / sg
                }
            };
            if v.abs() >= PATTERN_MIN_PX && v.is_finite() {
                // every contributing point learns: a kept one at 1/k in its k-th
                // kept frame, then at 2 %; an outlier of this frame at a tenth of
                // the settled rate, 0.2 % (a point whose share has changed for
                // good, a camera knocked to another pitch, is an outlier until
                // it has learnt it), without counting as a lesson. Each step is
                // clamped to ±0.5. The outliers are mostly mis-tracks of the fast
                // bottom rows: at the full rate they bent the pattern with the
                // speed, and a 10 Hz camera read up to 3.4 ms early on the
                // fastest drives (rendered held-out seeds 100-109: 2.61 ms MAE, 4
                // of 10 runs over 3 ms). A point's first lesson must not be an
                // outlier at all: it would be the point's own share from then
                // on, no longer its row's (a fresh start at speed: the few
                // bottom-row points tracked at half their true flow taught the
                // row a low share within a few frames, and the grid read 10 % low)
                for (j, &(_, s, _, i)) in pairs.iter().enumerate() {
                    let k = &mut self.taught[i];
                    let outlier = !(lo..hi).contains(&j);
                    if outlier && *k == 0 {
                        continue;
                    }
                    let g = &mut self.pattern[i];
                    let rate = if outlier {
                        PATTERN_OUTLIER_SLOW * PATTERN_RATE
                    } else if *k < PATTERN_WARMUP {
                        *k += 1;
                        1.0 / *k as f32
                    } else {
                        PATTERN_RATE
                    };
                    let step = ((f64::from(s) / v) as f32 - *g).clamp(-0.5, 0.5);
                    *g = (*g + rate * step).clamp(0.05, 20.0);
                }
                let mean = self.pattern.iter().sum::<f32>() / n as f32;
                if mean > 0.0 {
                    self.pattern.iter_mut().for_each(|g| *g /= mean);
                }
            }
            Some(v)
        };
        self.pairs = pairs;
        out
    }

    /// Gives each grid point that has not taught the pattern yet the share of
    /// its row: the median of the taught shares of its row, or, for a row
    /// without a quarter of its points taught, the least-squares line through
    /// the rows' shares against their `y` (one row: its share); then scales the
    /// pattern back to mean 1.
    /// Before any point has taught it (the first frame of motion), the shares
    /// are this frame's: each row's median scalar over the frame's median. Nothing
    /// changes without a row to go by, or in a frame without motion before the
    /// first lesson.
    ///
    /// Why: a point's share is learnt only while it is tracked, and a flat
    /// start of 1 for the points never yet tracked makes the grid's mean read
    /// low whenever those are the fast ones. A camera started while the robot
    /// was fast (rendered 10 Hz runs at 0.45-0.58 m/s) loses the bottom rows
    /// just as a running one does, but has never seen them, and its first
    /// seconds read 8-23 % under the value of a front-end running throughout.
    /// The floor's flow grows steadily down the image (rows, not columns), so a
    /// missing row's share follows from the rows seen; the row's own taught
    /// points replace the guess as soon as they are tracked. Not for
    /// [`Reduction::Divergence`], whose flow grows from a focus point instead.
    fn fill_untaught(&mut self) {
        let (points, rows) = (&self.points, &mut self.rows);
        let n = points.len().min(self.pattern.len());
        let taught = self.taught[..n].iter().any(|&k| k > 0);
        // the frame's scale before any lesson: the median of its scalars (one
        // wild vector must not move it)
        let mut scale = 0.0;
        if !taught {
            self.scratch.clear();
            self.scratch
                .extend(points[..n].iter().map(|p| p.1).filter(|s| s.is_finite()));
            if !self.scratch.is_empty() {
                self.scratch.sort_unstable_by(f32::total_cmp);
                scale = median_sorted(&self.scratch);
            }
            if scale.abs() < PATTERN_MIN_PX {
                return;
            }
        }
        rows.clear();
        let mut start = 0;
        while start < n {
            let y = points[start].0;
            let len = points[start..n]
                .iter()
                .take_while(|p| p.0 == y)
                .count()
                .max(1);
            self.scratch.clear();
            let row = start..start + len;
            for ((p, &k), &g) in points[row.clone()]
                .iter()
                .zip(&self.taught[row.clone()])
                .zip(&self.pattern[row])
            {
                let share = if taught {
                    (k > 0).then_some(g)
                } else {
                    Some((f64::from(p.1) / scale) as f32)
                };
                self.scratch.extend(share.filter(|g| g.is_finite()));
            }
            // a row's few points may be mis-tracks its missing neighbours could
            // not expose (rendered runs: one point of the bottom row at -12 px
            // where the floor moved +35): a quarter of the row, at least 2
            if self.scratch.len() >= (len / 4).max(2) && y.is_finite() {
                self.scratch.sort_unstable_by(f32::total_cmp);
                rows.push((y, median_sorted(&self.scratch) as f32));
            }
            start += len;
        }
        if rows.is_empty() {
            return;
        }
        let m = rows.len() as f64;
        let my = rows.iter().map(|r| f64::from(r.0)).sum::<f64>() / m;
        let mg = rows.iter().map(|r| f64::from(r.1)).sum::<f64>() / m;
        let (sxy, sxx) = rows.iter().fold((0.0, 0.0), |(a, b), r| {
            let dy = f64::from(r.0) - my;
            (a + dy * (f64::from(r.1) - mg), b + dy * dy)
        });
        let slope = if sxx > 0.0 { sxy / sxx } else { 0.0 };
        for ((p, &k), g) in points[..n]
            .iter()
            .zip(&self.taught[..n])
            .zip(&mut self.pattern[..n])
        {
            if k > 0 {
                continue;
            }
            let y = p.0;
            let share = match rows.iter().find(|r| r.0 == y) {
                Some(r) => f64::from(r.1),
                None if y.is_finite() => mg + slope * (f64::from(y) - my),
                None => continue,
            };
            *g = (share as f32).clamp(0.05, 20.0);
        }
        let mean = self.pattern.iter().sum::<f32>() / self.pattern.len() as f32;
        if mean > 0.0 && mean.is_finite() {
            self.pattern.iter_mut().for_each(|g| *g /= mean);
        }
    }

    /// The reduction.
    pub fn kind(&self) -> Reduction {
        self.kind
    }

    /// Reduces the vectors of a `frame_size = (width, height)` frame; `None` when no
    /// vector contributes. Non-finite vectors are ignored.
    pub fn reduce(&mut self, v: &[FlowVector], frame_size: (usize, usize)) -> Option<f64> {
        let mut s = std::mem::take(&mut self.scratch);
        s.clear();
        s.extend(v.iter().filter_map(|p| self.scalar(p, frame_size)));
        let out = self.reduce_scalars(&mut s);
        self.scratch = s;
        out
    }

    fn reduce_scalars(&self, s: &mut [f32]) -> Option<f64> {
        if s.is_empty() {
            return None;
        }
        s.sort_unstable_by(f32::total_cmp);
        Some(match self.kind {
            Reduction::MedianMagnitude => median_sorted(s),
            _ => trimmed_mean_sorted(s, self.trim),
        })
    }
}

/// Median of a sorted non-empty slice.
fn median_sorted(s: &[f32]) -> f64 {
    let n = s.len();
    if n % 2 == 1 {
        f64::from(s[n / 2])
    } else {
        0.5 * (f64::from(s[n / 2 - 1]) + f64::from(s[n / 2]))
    }
}

/// Mean of a sorted non-empty slice without `floor(trim * n)` values at each end.
fn trimmed_mean_sorted(s: &[f32], trim: f32) -> f64 {
    let n = s.len();
    let k = ((trim as f64) * n as f64).floor() as usize;
    let k = k.min((n - 1) / 2);
    let kept = &s[k..n - k];
    kept.iter().map(|&x| f64::from(x)).sum::<f64>() / kept.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn v(x: f32, y: f32, dx: f32, dy: f32) -> FlowVector {
        FlowVector { x, y, dx, dy }
    }

    #[test]
    fn forward_is_signed() {
        let mut r = Reducer::new(
            Reduction::Forward {
                direction: [0.0, 2.0],
            },
            0.0,
        )
        .unwrap();
        let f = [v(0.0, 0.0, 1.0, 3.0), v(0.0, 0.0, -1.0, 1.0)];
        assert_eq!(r.reduce(&f, (10, 10)), Some(2.0));
        let back = [v(0.0, 0.0, 0.0, -3.0)];
        assert_eq!(r.reduce(&back, (10, 10)), Some(-3.0));
    }

    #[test]
    fn divergence_of_zoom() {
        // flow = 0.1 * (p - f), f = (50, 50) in a 100x100 frame
        let mut r = Reducer::new(Reduction::Divergence { focus: [0.5, 0.5] }, 0.0).unwrap();
        let f: Vec<_> = [(60.0, 50.0), (50.0, 20.0), (10.0, 90.0), (50.0, 50.0)]
            .iter()
            .map(|&(x, y)| v(x, y, 0.1 * (x - 50.0), 0.1 * (y - 50.0)))
            .collect();
        let d = r.reduce(&f, (100, 100)).unwrap();
        let expect = (1.0 + 3.0 + 0.1 * 40.0f64.hypot(40.0)) / 3.0; // the focus point is skipped
        assert!((d - expect).abs() < 1e-5, "{d} vs {expect}");
        // pure translation has no net radial component for symmetric points
        let t = [v(40.0, 50.0, 2.0, 0.0), v(60.0, 50.0, 2.0, 0.0)];
        assert!(r.reduce(&t, (100, 100)).unwrap().abs() < 1e-9);
    }

    #[test]
    fn empty_and_non_finite() {
        let mut r = Reducer::new(Reduction::MeanMagnitude, 0.1).unwrap();
        assert_eq!(r.reduce(&[], (1, 1)), None);
        assert_eq!(r.reduce(&[v(0.0, 0.0, f32::NAN, 1.0)], (1, 1)), None);
    }

    #[test]
    fn invalid_parameters() {
        assert!(Reducer::new(Reduction::MeanMagnitude, 0.5).is_err());
        assert!(Reducer::new(Reduction::MeanMagnitude, f32::NAN).is_err());
        let e = Reducer::new(
            Reduction::Forward {
                direction: [0.0, 0.0],
            },
            0.1,
        )
        .unwrap_err();
        assert!(e.to_string().contains("reduce.direction"), "{e}");
        assert!(Reducer::new(
            Reduction::Divergence {
                focus: [f32::INFINITY, 0.0]
            },
            0.1
        )
        .is_err());
    }

    /// A 8x4 grid whose points move `v · g_i`, `g_i` from 0.5 (top) to 1.5
    /// (bottom), as the floor ahead of a robot does.
    fn floor_grid(v: f32, missing: impl Fn(usize) -> bool) -> Vec<FlowVector> {
        (0..32)
            .map(|i| {
                let g = 0.5 + (i / 8) as f32 / 3.0;
                let d = if missing(i) { f32::NAN } else { v * g };
                FlowVector {
                    x: (i % 8) as f32 * 10.0,
                    y: (i / 8) as f32 * 10.0,
                    dx: 0.0,
                    dy: d,
                }
            })
            .collect()
    }

    #[test]
    fn the_pattern_is_learnt_within_a_few_frames_of_motion() {
        // a slow camera's first seconds of driving: the fastest row goes missing
        // after five frames of motion (with a fixed 2 % per frame from the flat
        // start the grid then read 2.54 px for 3; the tracked points' mean is 2.50)
        let mut r = Reducer::new(Reduction::default(), 0.1).unwrap();
        r.reserve(32);
        for k in 0..5 {
            let v = 2.0 + k as f32;
            r.reduce_grid(floor_grid(v, |_| false).into_iter(), (80, 40))
                .unwrap();
        }
        let v = r
            .reduce_grid(floor_grid(3.0, |i| i >= 24).into_iter(), (80, 40))
            .unwrap();
        assert!((v - 3.0).abs() < 0.03, "{v}");
        // a mis-track is an outlier of its frame: in the very first frame it
        // teaches nothing (its point keeps its row's share, 0.5, untaught), in
        // the second it moves its share by 0.2 % of the step, clamped to 0.5,
        // at most; the grid, its fastest row missing, reads the motion
        let mut r = Reducer::new(Reduction::default(), 0.1).unwrap();
        r.reserve(32);
        let wild = || {
            let mut g = floor_grid(3.0, |_| false);
            g[3].dy = 90.0;
            g
        };
        let v = r.reduce_grid(wild().into_iter(), (80, 40)).unwrap();
        assert!((v - 3.0).abs() < 1e-3, "{v}");
        assert_eq!(r.taught[3], 0);
        assert!((r.pattern()[3] - 0.5).abs() < 1e-3, "{:?}", r.pattern());
        let before = r.pattern()[3] / r.pattern()[0];
        r.reduce_grid(wild().into_iter(), (80, 40)).unwrap();
        let after = r.pattern()[3] / r.pattern()[0];
        assert!(
            (after - before).abs() <= 0.002 * 0.5 / 0.5 + 1e-5,
            "{before} -> {after}"
        );
        assert_eq!(r.taught[3], 0);
        for _ in 0..5 {
            r.reduce_grid(floor_grid(3.0, |_| false).into_iter(), (80, 40))
                .unwrap();
        }
        let v = r
            .reduce_grid(floor_grid(3.0, |i| i >= 24).into_iter(), (80, 40))
            .unwrap();
        assert!((v - 3.0).abs() < 0.01, "{v}");
    }

    #[test]
    fn a_fresh_pattern_fills_the_rows_it_has_not_seen() {
        // a front-end started while the robot is fast: the fastest row is lost
        // from the first frame on. Its share follows from the rows seen (their
        // line against y), so the grid reads its mean, 3 px, where the tracked
        // points' own mean (a flat start) is 2.5
        let mut r = Reducer::new(Reduction::default(), 0.1).unwrap();
        r.reserve(32);
        let v = r
            .reduce_grid(floor_grid(3.0, |i| i >= 24).into_iter(), (80, 40))
            .unwrap();
        assert!((v - 3.0).abs() < 1e-3, "{v}");
        // a point of that row tracked at half its flow, which its missing
        // neighbours cannot expose: an outlier, so it does not teach its first
        // lesson (which would move its share all the way, 0.5) and the row
        // keeps the share of the line
        for k in 0..10 {
            let mut g = floor_grid(3.0, |i| i >= 24 && i != 27);
            g[27].dy = 0.5 * 3.0 * 1.5;
            let v = r.reduce_grid(g.into_iter(), (80, 40)).unwrap();
            assert!((v - 3.0).abs() < 1e-3, "frame {k}: {v}");
        }
        assert!((r.pattern()[27] - 1.5).abs() < 1e-3, "{:?}", r.pattern());
        // once the row is tracked, it teaches its own shares
        let v = r
            .reduce_grid(floor_grid(3.0, |_| false).into_iter(), (80, 40))
            .unwrap();
        assert!((v - 3.0).abs() < 1e-3, "{v}");
        assert!(r.taught[24..].iter().all(|&k| k == 1), "{:?}", r.taught);
        // the first frame's scale is its median: one wild vector elsewhere
        // does not clamp every share (with the mean, all went to 0.05: 2.54 px)
        let mut r = Reducer::new(Reduction::default(), 0.1).unwrap();
        let mut g = floor_grid(3.0, |i| i >= 24);
        g[0].dy = 1e5;
        let v = r.reduce_grid(g.into_iter(), (80, 40)).unwrap();
        assert!((v - 3.0).abs() < 1e-3, "{v}");
        // a row of a few points is not a row to go by: one wild point alone in
        // the bottom row of a fresh pattern is an outlier, not the row's share
        let mut r = Reducer::new(Reduction::default(), 0.1).unwrap();
        let mut g = floor_grid(3.0, |i| i >= 24 && i != 30);
        g[30].dy = -4.0;
        let v = r.reduce_grid(g.into_iter(), (80, 40)).unwrap();
        assert!((v - 3.0).abs() < 1e-3, "{v}");
        // the divergence's flow grows from a focus point, not down the rows: no
        // row fill there. A zoom about a point above the grid, its top and
        // bottom rows lost: the lost points keep the flat start, where a row
        // fill would have given them the line through the middle two
        let mut r = Reducer::new(Reduction::Divergence { focus: [0.5, -0.5] }, 0.1).unwrap();
        r.reserve(32);
        let zoom: Vec<FlowVector> = (0..32)
            .map(|i| {
                let (x, y) = ((i % 8) as f32 * 10.0 + 5.0, (i / 8) as f32 * 10.0 + 5.0);
                let lost = i / 8 == 0 || i / 8 == 3;
                let d = if lost { f32::NAN } else { 0.2 };
                FlowVector {
                    x,
                    y,
                    dx: d * (x - 40.0),
                    dy: d * (y + 20.0),
                }
            })
            .collect();
        r.reduce_grid(zoom.iter().copied(), (80, 40)).unwrap();
        assert_eq!(&r.taught[..8], &[0; 8]);
        let g = r.pattern();
        assert!(g[..8].iter().all(|&x| x == g[0]) && g[0] == g[31], "{g:?}");
        // the same zoom read as the forward component does fill them
        let mut f = Reducer::new(Reduction::default(), 0.1).unwrap();
        f.reduce_grid(zoom.into_iter(), (80, 40)).unwrap();
        assert!(f.pattern()[0] != f.pattern()[31], "{:?}", f.pattern());
    }

    #[test]
    fn a_changed_pattern_is_learnt_again() {
        // the camera knocked to another pitch after months of driving: its
        // bottom row now moves 30 % more against the rest. Those points are
        // outliers to the learnt pattern, which teach it only slowly (a few
        // mis-tracks must not bend it), but a lasting change is learnt: the
        // grid then reads the same with that row or without it
        let bumped = |v: f32, missing: bool| -> Vec<FlowVector> {
            let mut g = floor_grid(v, |i| missing && i >= 24);
            for p in &mut g[24..] {
                p.dy *= 1.3;
            }
            g
        };
        let mut r = Reducer::new(Reduction::default(), 0.1).unwrap();
        r.reserve(32);
        for k in 0..300 {
            let v = 4.0 + 2.0 * (k as f32 * 0.1).sin();
            r.reduce_grid(floor_grid(v, |_| false).into_iter(), (80, 40));
        }
        let bottom_to_top = |r: &Reducer| r.pattern()[31] / r.pattern()[0];
        assert!((bottom_to_top(&r) - 3.0).abs() < 0.01);
        // right after the knock the bottom row is trimmed: the rest reads on
        let v = r
            .reduce_grid(bumped(3.0, false).into_iter(), (80, 40))
            .unwrap();
        assert!((v - 3.0).abs() < 0.01, "{v}");
        for k in 0..1500 {
            let v = 4.0 + 2.0 * (k as f32 * 0.1).sin();
            r.reduce_grid(bumped(v, false).into_iter(), (80, 40));
        }
        assert!((bottom_to_top(&r) - 3.9).abs() < 0.01, "{:?}", r.pattern());
        // learnt: the row counts again, and missing it changes nothing
        let read = |r: &mut Reducer, missing| {
            r.reduce_grid(bumped(3.0, missing).into_iter(), (80, 40))
                .unwrap()
        };
        let (with, without) = (read(&mut r, false), read(&mut r, true));
        assert!((with / without - 1.0).abs() < 0.002, "{with} {without}");
    }

    #[test]
    fn grid_reduction_does_not_depend_on_which_points_are_tracked() {
        let fwd = Reduction::default();
        let mut r = Reducer::new(fwd, 0.1).unwrap();
        r.reserve(32);
        // flat pattern, full grid, no outlier: the mean
        let full = floor_grid(3.0, |_| false);
        let plain = Reducer::new(fwd, 0.0)
            .unwrap()
            .reduce(&full, (80, 40))
            .unwrap();
        let grid = r.reduce_grid(full.iter().copied(), (80, 40)).unwrap();
        assert!((grid - plain).abs() < 1e-6, "{grid} vs {plain}");
        // learn the pattern while driving at 2-6 px per frame: the scale stays put
        for k in 0..300 {
            let v = 4.0 + 2.0 * (k as f32 * 0.1).sin();
            let out = r
                .reduce_grid(floor_grid(v, |_| false).into_iter(), (80, 40))
                .unwrap();
            assert!(
                (out - f64::from(v)).abs() < 1e-3 * f64::from(v),
                "{k}: {out} vs {v}"
            );
        }
        let g = r.pattern();
        assert!(
            (g[0] - 0.5).abs() < 0.01 && (g[31] - 1.5).abs() < 0.01,
            "{g:?}"
        );
        // the fastest row goes missing (the floor left the image): the grid
        // reduction still reads 3 px; the tracked points' own mean reads 2.6
        let cut = floor_grid(3.0, |i| i >= 24);
        let v = r.reduce_grid(cut.iter().copied(), (80, 40)).unwrap();
        assert!((v - 3.0).abs() < 0.01, "{v}");
        let tracked: Vec<_> = cut.into_iter().filter(|p| p.dy.is_finite()).collect();
        let plain = Reducer::new(fwd, 0.1)
            .unwrap()
            .reduce(&tracked, (80, 40))
            .unwrap();
        assert!(plain < 2.7, "{plain}");
        // nothing tracked: no value; reset: flat again
        assert_eq!(
            r.reduce_grid(floor_grid(3.0, |_| true).into_iter(), (80, 40)),
            None
        );
        r.reset_pattern();
        assert!(r.pattern().iter().all(|&g| g == 1.0));
    }

    proptest! {
        /// After learning, any subset of at least a quarter of the grid, with
        /// up to 10 % wild vectors, reads the true motion to 2 %.
        #[test]
        fn grid_reduction_of_any_subset(
            seed in any::<u64>(), v in 1.0f32..20.0, keep in 8usize..32,
        ) {
            let mut r = Reducer::new(Reduction::default(), 0.1).unwrap();
            for k in 0..300 {
                let s = 5.0 + (k % 7) as f32;
                r.reduce_grid(floor_grid(s, |_| false).into_iter(), (80, 40)).unwrap();
            }
            let mut x = seed | 1;
            let mut next = move || { x ^= x << 13; x ^= x >> 7; x ^= x << 17; x };
            let mut grid = floor_grid(v, |_| false);
            let mut order: Vec<usize> = (0..32).collect();
            for i in (1..32).rev() {
                order.swap(i, (next() % (i as u64 + 1)) as usize);
            }
            for &i in &order[keep..] {
                grid[i].dy = f32::NAN;
            }
            for &i in order[..keep].iter().take(keep / 10) {
                grid[i].dy = v * 40.0; // wild
            }
            let out = r.reduce_grid(grid.into_iter(), (80, 40)).unwrap();
            prop_assert!((out - f64::from(v)).abs() <= 0.02 * f64::from(v), "{} vs {}", out, v);
        }

        /// A fresh pattern, a floor whose flow is any line in the row (positive),
        /// any rows lost from the first frame on but two: the grid reads its
        /// mean (the rows' line extends to the lost ones exactly).
        #[test]
        fn a_fresh_pattern_reads_a_linear_floor_from_any_two_rows(
            a in 0.2f32..2.0, b in -0.3f32..0.6, lost in proptest::collection::vec(any::<bool>(), 4),
            keep in 0usize..4, v in 1.0f32..20.0,
        ) {
            let mut lost = lost;
            lost[keep] = false;
            lost[(keep + 1) % 4] = false;
            let grid: Vec<FlowVector> = (0..32)
                .map(|i| {
                    let row = i / 8;
                    let g = a + b * row as f32;
                    let d = if lost[row] { f32::NAN } else { v * g };
                    FlowVector { x: (i % 8) as f32 * 10.0, y: row as f32 * 10.0, dx: 0.0, dy: d }
                })
                .collect();
            let mean = v * (a + 1.5 * b);
            prop_assume!((0..4).all(|row| a + b * row as f32 >= 0.1));
            // a frame of motion (a median tracked flow of 1 px or more), or
            // there is nothing to learn from
            let mut seen: Vec<f32> = grid.iter().map(|p| p.dy).filter(|d| d.is_finite()).collect();
            seen.sort_unstable_by(f32::total_cmp);
            prop_assume!(median_sorted(&seen) >= 1.0);
            let mut r = Reducer::new(Reduction::default(), 0.1).unwrap();
            let out = r.reduce_grid(grid.into_iter(), (80, 40)).unwrap();
            prop_assert!((out - f64::from(mean)).abs() <= 1e-3 * f64::from(mean), "{} vs {}", out, mean);
        }

        #[test]
        fn trimmed_mean_is_between_min_and_max_and_ignores_outliers(
            xs in proptest::collection::vec(0.0f32..10.0, 10..60), trim in 0.0f32..0.49,
        ) {
            let mut s = xs.clone();
            s.sort_unstable_by(f32::total_cmp);
            let m = trimmed_mean_sorted(&s, trim);
            prop_assert!(m >= f64::from(s[0]) - 1e-9 && m <= f64::from(s[s.len() - 1]) + 1e-9);
            // one wild outlier moves the 10 %-trimmed mean no further than the data range
            let mut flows: Vec<_> = xs.iter().map(|&x| v(0.0, 0.0, x, 0.0)).collect();
            flows.push(v(0.0, 0.0, 1e6, 0.0));
            let mut r = Reducer::new(Reduction::MeanMagnitude, 0.1).unwrap();
            let out = r.reduce(&flows, (1, 1)).unwrap();
            prop_assert!(out <= 10.0);
        }

        #[test]
        fn median_matches_definition(xs in proptest::collection::vec(-5.0f32..5.0, 1..40)) {
            let flows: Vec<_> = xs.iter().map(|&x| v(0.0, 0.0, x, 0.0)).collect();
            let mut r = Reducer::new(Reduction::MedianMagnitude, 0.0).unwrap();
            let m = r.reduce(&flows, (1, 1)).unwrap();
            let below = xs.iter().filter(|x| f64::from(x.abs()) < m).count();
            let above = xs.iter().filter(|x| f64::from(x.abs()) > m).count();
            prop_assert!(below <= xs.len() / 2 && above <= xs.len() / 2);
        }
    }
}
