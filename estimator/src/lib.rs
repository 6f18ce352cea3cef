//! The vlsync estimator (API shell; implementation in progress).
#![forbid(unsafe_code)]

use vlsync_common::{Estimate, RejectReason, Sample, Stream};
use vlsync_config::EstimatorConfig;

/// Counters of the estimator.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EstimatorStats {
    /// Accepted samples per stream (index: 0 cam, 1 lidar).
    pub accepted: [u64; 2],
    /// Rejected samples per stream and reason (`RejectReason::index`).
    pub rejected: [[u64; 4]; 2],
    /// Stream resets (large timestamp jumps) per stream.
    pub resets: [u64; 2],
    /// Window breaks caused by gaps per stream.
    pub gaps: [u64; 2],
    /// Estimates produced.
    pub estimates: u64,
    /// Estimates dropped because `poll` was not called often enough.
    pub dropped_estimates: u64,
}

/// Online offset/drift estimator. Push samples of both streams in any
/// interleaving; poll estimates. Allocates nothing after `new`.
pub struct Estimator {
    stats: EstimatorStats,
}

impl Estimator {
    /// Builds an estimator from a validated configuration.
    pub fn new(cfg: &EstimatorConfig) -> Self {
        let _ = cfg;
        Self { stats: EstimatorStats::default() }
    }

    /// Pushes one sample of `stream`. Rejected samples are counted and never reach the sums.
    pub fn push(&mut self, stream: Stream, sample: Sample) -> Result<(), RejectReason> {
        let _ = (stream, sample);
        Ok(())
    }

    /// Takes the oldest pending estimate, if any.
    pub fn poll(&mut self) -> Option<Estimate> {
        None
    }

    /// Counters.
    pub fn stats(&self) -> &EstimatorStats {
        &self.stats
    }

    /// Degraded mode (over the latency budget): narrower work per sample.
    pub fn set_degraded(&mut self, on: bool) {
        let _ = on;
    }
}
