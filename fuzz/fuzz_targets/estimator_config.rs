//! Every configuration the validation accepts must run: the estimator's keys drawn
//! across their documented ranges (each one's value from the input, the cross-key
//! rules helped along by drawing dependent keys as fractions of the ones they depend
//! on), kept only when `EstimatorConfig::validate` passes, then fed regular motion
//! with noise and a few hostile samples. Nothing may panic, allocate without bound or
//! hang, and every estimate must be well-formed.
#![no_main]
use libfuzzer_sys::arbitrary::{self, Arbitrary};
use libfuzzer_sys::fuzz_target;
use vlsync_common::{Sample, Stream};
use vlsync_config::{CadenceStreams, EstimatorConfig};
use vlsync_estimator::Estimator;

#[path = "shared.rs"]
mod shared;
use shared::{check, motion};

/// One key's draw: a fraction of its range.
#[derive(Arbitrary, Debug, Clone, Copy)]
struct F(u16);

impl F {
    fn unit(self) -> f64 {
        f64::from(self.0) / f64::from(u16::MAX)
    }
    fn lin(self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }
    fn log(self, lo: f64, hi: f64) -> f64 {
        (lo.ln() + (hi.ln() - lo.ln()) * self.unit()).exp()
    }
}

#[derive(Arbitrary, Debug)]
struct Input {
    f: [F; 31],
    cadence: u8,
    cycles: u8,
    noise: u8,
    offset_ms: i16,
    hostile: Vec<(bool, i64, u64)>,
}

fn config(f: &[F; 31], cadence: u8) -> EstimatorConfig {
    let grid_hz = f[0].log(10.0, 2000.0);
    let step = 1.0 / grid_hz;
    // the cross-key rules: a segment of two windows or more, a window at least the
    // lag range's width, a lag range of four grid steps or more, a gap limit of at
    // most half a window, a step window of at least one hop
    let segment_s = f[1].log(2.0, 600.0);
    let window_s = f[2].lin(1.0, (0.5 * segment_s).min(120.0));
    let hop_s = f[3].log(
        0.05f64.max(step),
        10.0f64.min(window_s).max(0.05f64.max(step)),
    );
    let max_lag_s = f[4].log((4.0 * step).max(0.01), (0.5 * window_s).min(2.0));
    let track_range_s = f[5].log((2.0 * step).max(0.005), max_lag_s);
    let lowpass_hz = f[6].log(0.5, (0.45 * grid_hz).min(500.0));
    let max_gap_s = f[7].log(0.25, (0.5 * window_s).min(60.0));
    EstimatorConfig {
        grid_hz,
        window_s,
        segment_s,
        // within the acquisition window in whole hops
        reference_lag_s: f[8].lin(0.0, window_s) * 0.9,
        hop_s,
        max_lag_s,
        lag_center_s: f[9].lin(-1.0, 1.0),
        track_range_s,
        step_window_s: f[10].lin(hop_s.max(0.5), window_s.max(0.5)),
        max_gap_s,
        reset_jump_s: max_gap_s + f[11].log(0.1, 1e6),
        lowpass_hz,
        highpass_hz: f[12].lin(0.0, (0.9 * lowpass_hz).min(100.0)),
        max_abs_value: f[13].log(1e-9, 1e12),
        min_peak_score: f[14].unit() * 0.99,
        min_acquire_score: f[30].unit() * 0.99,
        min_peak_ratio: f[15].lin(1.0, 100.0),
        min_motion_ratio: f[16].unit(),
        acquire_confirm: 1 + (f[17].unit() * 99.0) as u32,
        measurement_noise_scale: f[18].log(0.1, 1e3),
        offset_process_noise: f[19].unit(),
        drift_memory_s: f[20].log(1.0, 1e9),
        initial_drift_std: f[21].log(1e-9, 0.02),
        hold_process_noise: f[22].unit(),
        gate_sigma: f[23].lin(1.0, 100.0),
        step_gate_sigma: f[24].lin(1.0, 100.0),
        step_confirm: 1 + (f[25].unit() * 99.0) as u32,
        lost_std_s: f[26].log(1e-4, 10.0),
        cadence: match cadence % 4 {
            0 => CadenceStreams::Both,
            1 => CadenceStreams::Camera,
            2 => CadenceStreams::Lidar,
            _ => CadenceStreams::Off,
        },
        cadence_min_step_s: f[27].log(1e-4, 0.1),
        cadence_confirm: 1 + (f[28].unit() * 14.0) as u32,
    }
}

fuzz_target!(|input: Input| {
    let cfg = config(&input.f, input.cadence);
    if cfg.validate("fuzz").is_err() {
        return;
    }
    let mut est = Estimator::new(&cfg);
    let offset_s = f64::from(input.offset_ms) * 1e-3;
    let noise = f64::from(input.noise) / 512.0;
    let mut t = [0i64, 0i64];
    let mut last_seq: Option<u64> = None;
    let mut hostile = input.hostile.iter().take(64);
    for c in 0..u32::from(input.cycles) * 2 {
        for (i, period, n) in [(1usize, 100_000_000i64, 1), (0, 33_333_333, 3)] {
            for k in 0..n {
                t[i] += period;
                let lidar = i == 1;
                let true_s = t[i] as f64 * 1e-9 + if lidar { 0.0 } else { offset_s };
                let m = motion(true_s);
                let wobble = noise * if (c + k) % 2 == 0 { 1.0 } else { -1.0 };
                let v = if lidar { -m } else { m } + wobble;
                let stream = if lidar { Stream::Lidar } else { Stream::Cam };
                let _ = est.push(stream, Sample::new(t[i], v));
            }
        }
        if c % 16 == 0 {
            if let Some(&(lidar, dt, bits)) = hostile.next() {
                let i = usize::from(lidar);
                let stream = if lidar { Stream::Lidar } else { Stream::Cam };
                let _ = est.push(
                    stream,
                    Sample::new(t[i].saturating_add(dt), f64::from_bits(bits)),
                );
            }
        }
        while let Some(e) = est.poll() {
            check(&e, &mut last_seq);
        }
    }
});
