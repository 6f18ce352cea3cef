//! A stream of operations on the estimator as the daemon drives it: samples of either
//! sensor with timestamps that step, jitter, stall, go back or jump anywhere in `i64`,
//! values that follow a shared motion (so it locks and tracks) or are any bit pattern
//! (NaN, infinities, huge), interleaved with the calls the daemon makes (polls, the
//! idle stage, change announcements and hints, degraded mode, a restored estimate).
//! Nothing may panic (the build has overflow checks on), and every estimate must be
//! well-formed: finite non-negative standard deviations, increasing sequence numbers.
#![no_main]
use libfuzzer_sys::arbitrary::{self, Arbitrary};
use libfuzzer_sys::fuzz_target;
use vlsync_common::{Estimate, EstimatorState, Polarity, Sample, Stream};
use vlsync_config::EstimatorConfig;
use vlsync_estimator::Estimator;

#[path = "shared.rs"]
mod shared;
use shared::{check, motion};

#[derive(Arbitrary, Debug)]
enum Dt {
    /// The sensor's nominal period plus `jitter` × 0.1 ms.
    Nominal(i8),
    /// A small step, 10 µs units (negative: backwards).
    Small(i16),
    /// Any step in ns.
    Big(i32),
    /// An absolute time.
    Abs(i64),
}

#[derive(Arbitrary, Debug)]
enum Val {
    /// The shared motion at the sample's true time, plus noise/256.
    Motion(i8),
    /// Any f64.
    Bits(u64),
}

#[derive(Arbitrary, Debug)]
enum Op {
    Push {
        lidar: bool,
        dt: Dt,
        val: Val,
        urgent: bool,
    },
    /// `cycles` × 100 ms of regular data (one LiDAR scan, three frames each) on the
    /// motion: the long stretches the estimator needs to lock and track.
    Run {
        cycles: u8,
        noise: i8,
    },
    Idle,
    Declare {
        back_ms: u16,
    },
    Hint {
        back_ms: u16,
        std_ms: u8,
    },
    Degraded(bool),
    Restore {
        offset_ms: i32,
        std_us: u32,
        drift_ppm: i16,
        age_s: u16,
        tracking: bool,
    },
}

#[derive(Arbitrary, Debug)]
struct Input {
    wide: bool,
    offset_ms: i16,
    ops: Vec<Op>,
}

fuzz_target!(|input: Input| {
    let mut cfg = EstimatorConfig::default();
    if input.wide {
        cfg.max_lag_s = 2.0;
        cfg.window_s = 12.0;
    }
    let mut est = Estimator::new(&cfg);
    let offset_s = f64::from(input.offset_ms) * 1e-3;
    let mut t = [0i64, 0i64]; // cam, lidar: each on its own clock
    let mut last_seq = None;
    for op in input.ops.iter().take(20_000) {
        match op {
            Op::Push {
                lidar,
                dt,
                val,
                urgent,
            } => {
                let i = usize::from(*lidar);
                let period: i64 = if *lidar { 100_000_000 } else { 33_333_333 };
                t[i] = match dt {
                    Dt::Nominal(j) => t[i].saturating_add(period + i64::from(*j) * 100_000),
                    Dt::Small(d) => t[i].saturating_add(i64::from(*d) * 10_000),
                    Dt::Big(d) => t[i].saturating_add(i64::from(*d)),
                    Dt::Abs(a) => *a,
                };
                // true time of the event: the LiDAR clock is the reference,
                // t_L - t_C = offset
                let true_s = t[i] as f64 * 1e-9 + if *lidar { 0.0 } else { offset_s };
                let value = match val {
                    Val::Motion(n) => {
                        let m = motion(true_s);
                        // negative polarity for the LiDAR, as driving at a wall gives
                        (if *lidar { -m } else { m }) + f64::from(*n) / 256.0
                    }
                    Val::Bits(b) => f64::from_bits(*b),
                };
                let stream = if *lidar { Stream::Lidar } else { Stream::Cam };
                let s = Sample::new(t[i], value);
                let _ = if *urgent {
                    est.push_urgent(stream, s)
                } else {
                    est.push(stream, s)
                };
            }
            Op::Run { cycles, noise } => {
                for c in 0..*cycles {
                    for (i, period, n) in [(1, 100_000_000, 1), (0, 33_333_333, 3)] {
                        for _ in 0..n {
                            t[i] = t[i].saturating_add(period);
                            let lidar = i == 1;
                            let true_s = t[i] as f64 * 1e-9 + if lidar { 0.0 } else { offset_s };
                            let m = motion(true_s);
                            let wobble =
                                f64::from(*noise) / 256.0 * if c % 2 == 0 { 1.0 } else { -1.0 };
                            let v = if lidar { -m } else { m } + wobble;
                            let stream = if lidar { Stream::Lidar } else { Stream::Cam };
                            let _ = est.push(stream, Sample::new(t[i], v));
                            while let Some(e) = est.poll() {
                                check(&e, &mut last_seq);
                            }
                        }
                    }
                }
            }
            Op::Idle => est.idle(),
            Op::Declare { back_ms } => {
                est.declare_change(t[1].saturating_sub(i64::from(*back_ms) * 1_000_000))
            }
            Op::Hint { back_ms, std_ms } => est.hint_change(
                t[1].saturating_sub(i64::from(*back_ms) * 1_000_000),
                f64::from(*std_ms) * 1e-3,
            ),
            Op::Degraded(on) => est.set_degraded(*on),
            Op::Restore {
                offset_ms,
                std_us,
                drift_ppm,
                age_s,
                tracking,
            } => {
                let e = Estimate {
                    seq: 0,
                    t_ref_ns: t[1],
                    offset_s: f64::from(*offset_ms) * 1e-3,
                    drift: f64::from(*drift_ppm) * 1e-6,
                    offset_std_s: f64::from(*std_us) * 1e-6,
                    drift_std: 50e-6,
                    state: if *tracking {
                        EstimatorState::Tracking
                    } else {
                        EstimatorState::Holding
                    },
                    polarity: Polarity::Negative,
                    peak_score: 0.9,
                    peak_ratio: 2.0,
                    measured_offset_s: f64::NAN,
                };
                est.restore(&e, f64::from(*age_s));
            }
        }
        while let Some(e) = est.poll() {
            check(&e, &mut last_seq);
        }
        let _ = est.take_latency_step();
        let _ = est.take_search_move();
        let _ = est.take_offset_step();
    }
});
