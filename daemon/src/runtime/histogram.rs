//! Fixed-bucket latency histogram: no allocation after construction.
//!
//! Log-linear buckets: values below 16 ns each have their own bucket; above,
//! every power of two is split into 16 equal sub-buckets, so a percentile is
//! reported as its bucket's upper bound, at most 1/16 (6.25 %) above the true
//! value. Covers 0 ns to `u64::MAX` ns.

const SUB_BITS: u32 = 4;
const SUB: usize = 1 << SUB_BITS;
const BUCKETS: usize = (64 - SUB_BITS as usize + 1) * SUB;

/// A latency histogram in nanoseconds.
#[derive(Clone)]
pub struct Histogram {
    counts: Box<[u64; BUCKETS]>,
    total: u64,
    max: u64,
}

impl Default for Histogram {
    fn default() -> Self {
        Self::new()
    }
}

impl std::fmt::Debug for Histogram {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "Histogram {{ n: {}, p50: {}, p99: {}, max: {} }}",
            self.total,
            self.percentile(0.5),
            self.percentile(0.99),
            self.max
        )
    }
}

fn index(v: u64) -> usize {
    if v < SUB as u64 {
        return v as usize;
    }
    let msb = 63 - v.leading_zeros(); // >= SUB_BITS
    let shift = msb - SUB_BITS;
    let sub = ((v >> shift) as usize) & (SUB - 1);
    ((msb - SUB_BITS + 1) as usize) * SUB + sub
}

/// Largest value that falls in bucket `i`.
fn upper_bound(i: usize) -> u64 {
    if i < SUB {
        return i as u64;
    }
    let group = (i / SUB) as u32; // >= 1
    let sub = (i % SUB) as u64;
    let msb = group + SUB_BITS - 1;
    let shift = msb - SUB_BITS;
    let base = (SUB as u64 + sub) << shift;
    base.saturating_add((1u64 << shift) - 1)
}

impl Histogram {
    /// An empty histogram (the only allocation).
    pub fn new() -> Self {
        Self {
            counts: Box::new([0; BUCKETS]),
            total: 0,
            max: 0,
        }
    }

    /// Records one value.
    pub fn record(&mut self, v: u64) {
        self.counts[index(v)] += 1;
        self.total += 1;
        self.max = self.max.max(v);
    }

    /// Number of values recorded.
    pub fn count(&self) -> u64 {
        self.total
    }

    /// Largest value recorded (exact).
    pub fn max(&self) -> u64 {
        self.max
    }

    /// The `q` quantile (0..=1) as the upper bound of its bucket, capped at the
    /// exact maximum; 0 when empty.
    pub fn percentile(&self, q: f64) -> u64 {
        if self.total == 0 {
            return 0;
        }
        let q = if q.is_nan() { 1.0 } else { q.clamp(0.0, 1.0) };
        let rank = ((q * self.total as f64).ceil() as u64).max(1);
        let mut seen = 0u64;
        for (i, &c) in self.counts.iter().enumerate() {
            seen += c;
            if seen >= rank {
                return upper_bound(i).min(self.max);
            }
        }
        self.max
    }

    /// `[p50, p99, max]`.
    pub fn summary(&self) -> [u64; 3] {
        [self.percentile(0.5), self.percentile(0.99), self.max]
    }

    /// Forgets every value (no allocation).
    pub fn clear(&mut self) {
        self.counts.fill(0);
        self.total = 0;
        self.max = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn empty_is_zero() {
        let h = Histogram::new();
        assert_eq!(h.summary(), [0, 0, 0]);
    }

    #[test]
    fn clear_starts_over() {
        let mut h = Histogram::new();
        h.record(5_000);
        h.record(9_000);
        h.clear();
        assert_eq!((h.count(), h.summary()), (0, [0, 0, 0]));
        h.record(7);
        assert_eq!(h.summary(), [7, 7, 7]);
    }

    #[test]
    fn small_values_are_exact() {
        let mut h = Histogram::new();
        for v in 0..16 {
            h.record(v);
        }
        assert_eq!(h.percentile(1.0 / 16.0), 0);
        assert_eq!(h.percentile(0.5), 7);
        assert_eq!(h.max(), 15);
    }

    #[test]
    fn percentiles_of_a_uniform_spread() {
        let mut h = Histogram::new();
        for v in 1..=10_000u64 {
            h.record(v * 1000);
        }
        let p50 = h.percentile(0.5) as f64;
        let p99 = h.percentile(0.99) as f64;
        assert!((5e6..=5e6 * 1.0625).contains(&p50), "{p50}");
        assert!((9.9e6..=9.9e6 * 1.0625).contains(&p99), "{p99}");
        assert_eq!(h.max(), 10_000_000);
        assert_eq!(h.count(), 10_000);
    }

    proptest! {
        #[test]
        fn bucket_bounds_hold(v in any::<u64>()) {
            let i = index(v);
            prop_assert!(i < BUCKETS);
            prop_assert!(upper_bound(i) >= v);
            // within 1/16 above the value
            prop_assert!((upper_bound(i) - v) as f64 <= v as f64 / 16.0 + 1.0);
            if i > 0 {
                prop_assert!(upper_bound(i - 1) < v);
            }
        }
    }
}
