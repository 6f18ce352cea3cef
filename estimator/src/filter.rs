//! The band-pass applied identically to both resampled signals.
//!
//! A causal filter delays both signals equally, so its phase cancels in the
//! cross-correlation (the correlation of two equally filtered signals is the
//! original correlation convolved with the filter's autocorrelation, which is
//! symmetric). The common delay only shifts the reference time of a
//! measurement, which [`BandPass::group_delay_s`] corrects.

use std::f64::consts::PI;

/// Second-order section, transposed direct form II.
#[derive(Debug, Clone, Copy)]
struct Biquad {
    b: [f64; 3],
    a: [f64; 2],
    z: [f64; 2],
}

impl Biquad {
    fn lowpass(fc: f64, fs: f64) -> Self {
        let k = (PI * fc / fs).tan();
        let q = std::f64::consts::FRAC_1_SQRT_2;
        let norm = 1.0 / (1.0 + k / q + k * k);
        let b0 = k * k * norm;
        Self {
            b: [b0, 2.0 * b0, b0],
            a: [2.0 * (k * k - 1.0) * norm, (1.0 - k / q + k * k) * norm],
            z: [0.0; 2],
        }
    }

    fn highpass(fc: f64, fs: f64) -> Self {
        let k = (PI * fc / fs).tan();
        let q = std::f64::consts::FRAC_1_SQRT_2;
        let norm = 1.0 / (1.0 + k / q + k * k);
        Self {
            b: [norm, -2.0 * norm, norm],
            a: [2.0 * (k * k - 1.0) * norm, (1.0 - k / q + k * k) * norm],
            z: [0.0; 2],
        }
    }

    fn dc_gain(&self) -> f64 {
        (self.b[0] + self.b[1] + self.b[2]) / (1.0 + self.a[0] + self.a[1])
    }

    /// Sets the state to the steady state for a constant input `x0`.
    fn settle(&mut self, x0: f64) {
        let y0 = self.dc_gain() * x0;
        let z2 = self.b[2] * x0 - self.a[1] * y0;
        let z1 = self.b[1] * x0 - self.a[0] * y0 + z2;
        self.z = [z1, z2];
    }

    #[inline]
    fn step(&mut self, x: f64) -> f64 {
        let y = self.b[0] * x + self.z[0];
        self.z[0] = self.b[1] * x - self.a[0] * y + self.z[1];
        self.z[1] = self.b[2] * x - self.a[1] * y;
        y
    }

    /// Phase of the frequency response at `f` (radians).
    fn phase(&self, f: f64, fs: f64) -> f64 {
        let w = 2.0 * PI * f / fs;
        let (c1, s1, c2, s2) = (w.cos(), w.sin(), (2.0 * w).cos(), (2.0 * w).sin());
        let num_re = self.b[0] + self.b[1] * c1 + self.b[2] * c2;
        let num_im = -(self.b[1] * s1 + self.b[2] * s2);
        let den_re = 1.0 + self.a[0] * c1 + self.a[1] * c2;
        let den_im = -(self.a[0] * s1 + self.a[1] * s2);
        num_im.atan2(num_re) - den_im.atan2(den_re)
    }
}

/// Butterworth band-pass (2nd-order high-pass then 2nd-order low-pass).
#[derive(Debug, Clone)]
pub struct BandPass {
    hp: Option<Biquad>,
    lp: Biquad,
    fs: f64,
    fresh: bool,
}

impl BandPass {
    /// A band-pass for grid rate `fs`; `highpass_hz == 0` disables the high-pass.
    pub fn new(highpass_hz: f64, lowpass_hz: f64, fs: f64) -> Self {
        Self {
            hp: (highpass_hz > 0.0).then(|| Biquad::highpass(highpass_hz, fs)),
            lp: Biquad::lowpass(lowpass_hz, fs),
            fs,
            fresh: true,
        }
    }

    /// Forget history: the next input settles the filter as if constant before.
    pub fn reset(&mut self) {
        self.fresh = true;
    }

    /// Filters one grid value.
    #[inline]
    pub fn step(&mut self, x: f64) -> f64 {
        if self.fresh {
            self.fresh = false;
            let mut y = x;
            if let Some(hp) = &mut self.hp {
                hp.settle(y);
                y *= hp.dc_gain();
            }
            self.lp.settle(y);
        }
        let mut y = x;
        if let Some(hp) = &mut self.hp {
            y = hp.step(y);
        }
        self.lp.step(y)
    }

    /// Group delay at frequency `f` (seconds), from the phase slope.
    pub fn group_delay_s(&self, f: f64) -> f64 {
        let df = 1e-3 * f.max(1e-3);
        let ph = |x: f64| {
            self.lp.phase(x, self.fs) + self.hp.as_ref().map_or(0.0, |h| h.phase(x, self.fs))
        };
        let mut d = ph(f + df) - ph(f - df);
        while d > PI {
            d -= 2.0 * PI;
        }
        while d < -PI {
            d += 2.0 * PI;
        }
        -d / (2.0 * PI * 2.0 * df)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn passes_band_and_blocks_dc_and_high() {
        let fs = 100.0;
        let amp = |f: f64| {
            let mut bp = BandPass::new(0.1, 2.0, fs);
            let mut peak: f64 = 0.0;
            for i in 0..20_000 {
                let y = bp.step((2.0 * PI * f * i as f64 / fs).sin() + 3.0);
                if i > 15_000 {
                    peak = peak.max(y.abs());
                }
            }
            peak
        };
        assert!((amp(0.7) - 1.0).abs() < 0.1, "{}", amp(0.7));
        assert!(amp(20.0) < 0.02);
        assert!(amp(0.005) < 0.2);
    }

    #[test]
    fn settles_without_transient_on_constant() {
        let mut bp = BandPass::new(0.0, 2.0, 100.0);
        for _ in 0..10 {
            assert!((bp.step(5.0) - 5.0).abs() < 1e-9);
        }
    }

    #[test]
    fn group_delay_matches_butterworth_dc_value() {
        // 2nd-order Butterworth low-pass: group delay at DC = sqrt(2) / (2 pi fc)
        let bp = BandPass::new(0.0, 2.0, 1000.0);
        let expect = 2f64.sqrt() / (2.0 * PI * 2.0);
        assert!((bp.group_delay_s(0.01) - expect).abs() < 0.005);
    }
}
