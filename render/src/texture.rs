//! Procedural, deterministic, tileable gray textures: multi-octave value noise
//! blended with a checker, sampled bilinearly with wrap-around.
//!
//! ```
//! use vlsync_render::texture::Texture;
//! let t = Texture::generate(256, 0.004, 3, 0.1);
//! let a = t.sample(0.5, 0.25);
//! assert!((0.0..=255.0).contains(&a));
//! // tileable: one tile (256 texels of 4 mm) further is the same value
//! assert!((t.sample(0.5 + 1.024, 0.25) - a).abs() < 1e-3);
//! ```

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A square, power-of-two, wrapping texture of `u8` texels.
#[derive(Debug, Clone, PartialEq)]
pub struct Texture {
    size: usize,
    mask: usize,
    inv_texel: f64,
    data: Vec<u8>,
}

impl Texture {
    /// Generates a `size x size` texture (`size` rounded up to a power of two,
    /// at least 16) whose texels are `texel_m` metres wide. `checker_m` is the
    /// checker tile size in metres (0 = none). Octave wavelengths run from 2
    /// texels up to `size / 4` texels, amplitudes falling by 15 % per octave
    /// (fine grain like carpet or concrete, with structure at every pyramid
    /// level of an optical-flow tracker); the sum is normalised to mean 128 and
    /// standard deviation 40 gray levels, and the checker adds ±15.
    pub fn generate(size: usize, texel_m: f64, seed: u64, checker_m: f64) -> Self {
        let size = size.max(16).next_power_of_two();
        let mask = size - 1;
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x7465_7874); // "text"
        let mut acc = vec![0f32; size * size];
        let mut period = 2usize;
        let mut amp = 1.0f32;
        while period <= size / 4 {
            let cells = size / period;
            let lattice: Vec<f32> = (0..cells * cells).map(|_| rng.gen::<f32>() - 0.5).collect();
            for y in 0..size {
                let gy = y / period;
                let fy = smooth((y % period) as f32 / period as f32);
                let (y0, y1) = (gy % cells, (gy + 1) % cells);
                for x in 0..size {
                    let gx = x / period;
                    let fx = smooth((x % period) as f32 / period as f32);
                    let (x0, x1) = (gx % cells, (gx + 1) % cells);
                    let a = lattice[y0 * cells + x0];
                    let b = lattice[y0 * cells + x1];
                    let c = lattice[y1 * cells + x0];
                    let d = lattice[y1 * cells + x1];
                    let top = a + (b - a) * fx;
                    let bot = c + (d - c) * fx;
                    acc[y * size + x] += amp * (top + (bot - top) * fy);
                }
            }
            amp *= 0.85;
            period *= 2;
        }
        // normalise to a fixed contrast: mean 128, standard deviation 40 gray levels
        let n = acc.len() as f64;
        let mean = acc.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
        let sd = (acc
            .iter()
            .map(|&v| (f64::from(v) - mean).powi(2))
            .sum::<f64>()
            / n)
            .sqrt()
            .max(1e-9);
        let checker_texels = if checker_m > 0.0 {
            (checker_m / texel_m).round().max(1.0) as usize
        } else {
            0
        };
        let data = acc
            .iter()
            .enumerate()
            .map(|(i, &v)| {
                let (x, y) = (i % size, i / size);
                let check =
                    if checker_texels > 0 && ((x / checker_texels + y / checker_texels) % 2 == 1) {
                        15.0
                    } else {
                        -15.0 * f64::from(u8::from(checker_texels > 0))
                    };
                (128.0 + 40.0 * (f64::from(v) - mean) / sd + check).clamp(0.0, 255.0) as u8
            })
            .collect();
        Self {
            size,
            mask,
            inv_texel: 1.0 / texel_m,
            data,
        }
    }

    /// Side of the texture in texels.
    pub fn size(&self) -> usize {
        self.size
    }

    /// Bilinear sample at `(u, v)` metres (wrapping), gray level `0..=255`.
    #[inline]
    pub fn sample(&self, u: f64, v: f64) -> f32 {
        let fu = u * self.inv_texel;
        let fv = v * self.inv_texel;
        let (iu, iv) = (fast_floor(fu), fast_floor(fv));
        let (au, av) = ((fu - iu) as f32, (fv - iv) as f32);
        // wrap via two's complement masking (valid for any finite integer value)
        let x0 = (iu as i64 as usize) & self.mask;
        let y0 = (iv as i64 as usize) & self.mask;
        let x1 = (x0 + 1) & self.mask;
        let y1 = (y0 + 1) & self.mask;
        let d = &self.data;
        let (r0, r1) = (y0 * self.size, y1 * self.size);
        let a = f32::from(d[r0 + x0]);
        let b = f32::from(d[r0 + x1]);
        let c = f32::from(d[r1 + x0]);
        let e = f32::from(d[r1 + x1]);
        let top = a + (b - a) * au;
        let bot = c + (e - c) * au;
        top + (bot - top) * av
    }
}

/// `x.floor()` for `|x| < 2^52` without the libm call (`f64::floor` is not an
/// instruction on baseline x86-64, and this runs for every pixel); other inputs
/// (huge, NaN) give some finite or NaN value, never a panic.
#[inline]
fn fast_floor(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x {
        t - 1.0
    } else {
        t
    }
}

fn smooth(x: f32) -> f32 {
    x * x * (3.0 - 2.0 * x)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn deterministic_with_contrast() {
        let a = Texture::generate(128, 0.004, 9, 0.1);
        assert_eq!(a, Texture::generate(128, 0.004, 9, 0.1));
        assert_ne!(a, Texture::generate(128, 0.004, 10, 0.1));
        let mean = a.data.iter().map(|&v| f64::from(v)).sum::<f64>() / a.data.len() as f64;
        let var = a
            .data
            .iter()
            .map(|&v| (f64::from(v) - mean).powi(2))
            .sum::<f64>()
            / a.data.len() as f64;
        assert!((80.0..170.0).contains(&mean), "{mean}");
        assert!(var.sqrt() > 15.0, "{}", var.sqrt());
        // neighbouring texels differ: fine-scale gradient exists
        let grad = (0..a.data.len() - 1)
            .map(|i| (f64::from(a.data[i + 1]) - f64::from(a.data[i])).abs())
            .sum::<f64>()
            / a.data.len() as f64;
        assert!(grad > 1.0, "{grad}");
        assert_eq!(Texture::generate(3, 0.01, 0, 0.0).size(), 16);
    }

    proptest! {
        #[test]
        fn fast_floor_is_floor(x in -4.0e15f64..4.0e15, f in 0.0f64..1.0) {
            for v in [x, x.trunc() + f, x.trunc() - f, x.trunc()] {
                prop_assert_eq!(fast_floor(v), v.floor());
            }
        }

        /// Bilinear sampling stays within the texel range, interpolates exactly
        /// at texel centres and never panics on large or negative coordinates.
        #[test]
        fn sampling_is_bounded_and_exact_on_texels(u in -1e6f64..1e6, v in -1e6f64..1e6, i in 0usize..64, j in 0usize..64) {
            let t = Texture::generate(64, 0.01, 1, 0.0);
            let s = t.sample(u, v);
            prop_assert!((0.0..=255.0).contains(&s));
            let exact = t.sample(i as f64 * 0.01 + 1e-9, j as f64 * 0.01 + 1e-9);
            prop_assert!((exact - f32::from(t.data[j * 64 + i])).abs() < 1e-2);
        }
    }
}
