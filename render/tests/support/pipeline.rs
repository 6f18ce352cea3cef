#![allow(dead_code)] // shared by a test and an example, each using part of it
//! The end-to-end pipeline shared by `tests/end_to_end.rs` and
//! `examples/accuracy.rs`: rendered frames → signature-cam, rendered scans →
//! signature-lidar, both → the estimator with its shipped defaults, scored
//! against the renderer's truth. Every run renders once and feeds two lanes
//! side by side: the front-ends' default (midpoint) stamping and end-of-interval
//! stamping, everything else equal.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use vlsync_common::{Sample, Stream};
use vlsync_config::EstimatorConfig;
use vlsync_estimator::Estimator;
use vlsync_render::score::{score, Score};
use vlsync_render::{Event, RenderConfig, Renderer};
use vlsync_signature_cam as cam;
use vlsync_signature_lidar as lidar;

/// Also measure the wall behind the robot (`lidar::OppositeWindows`: a second
/// bearing window centred at 180°, its distance rate negated, both windows'
/// samples in time order as the one LiDAR stream; `lidar.opposite_window` of the
/// driver): twice the independent range returns per revolution, so half the
/// rate-noise variance. Off by default.
pub static OPPOSITE_WINDOW: AtomicBool = AtomicBool::new(false);

/// One stamping variant: its two front-ends and its estimator.
struct Lane {
    cam: cam::SignatureProcessor,
    /// the window ahead, and with [`OPPOSITE_WINDOW`] the one behind too
    lidar: lidar::WallFront,
    est: Estimator,
    estimates: Vec<vlsync_common::Estimate>,
    cam_samples: usize,
    lidar_samples: usize,
}

impl Lane {
    fn new(cam_stamping: cam::Stamping, lidar_stamping: lidar::Stamping) -> Self {
        Self {
            cam: cam::SignatureProcessor::new(cam::SignatureConfig {
                stamping: cam_stamping,
                ..cam::SignatureConfig::default()
            })
            .expect("default camera front-end"),
            lidar: lidar::WallFront::new(
                lidar::SignatureConfig {
                    stamping: lidar_stamping,
                    ..lidar::SignatureConfig::default()
                },
                OPPOSITE_WINDOW.load(Ordering::Relaxed),
            )
            .expect("default LiDAR front-end"),
            est: Estimator::new(&EstimatorConfig::default()),
            estimates: Vec::new(),
            cam_samples: 0,
            lidar_samples: 0,
        }
    }

    fn frame(&mut self, f: &vlsync_render::RenderedFrame) -> Option<cam::CamSample> {
        match self.cam.process(&f.image, f.time) {
            Ok(cam::Step::Sample(s)) if s.sample.value.is_finite() && !s.low_texture() => {
                self.cam_samples += 1;
                let _ = self.est.push(Stream::Cam, s.sample);
                self.drain();
                Some(s)
            }
            _ => None,
        }
    }

    fn scan(&mut self, s: &vlsync_render::Scan, out: &mut Vec<Sample>) {
        out.clear();
        self.lidar.push_scan(s, |x| out.push(x));
        for &x in out.iter() {
            self.lidar_samples += 1;
            let _ = self.est.push(Stream::Lidar, x);
        }
        self.drain();
    }

    fn drain(&mut self) {
        while let Some(e) = self.est.poll() {
            self.estimates.push(e);
        }
    }
}

/// The front-ends' samples against the true speed, for the timing audit: rows
/// of `(value, speed at the sample's true time, acceleration there)`.
#[derive(Debug, Default)]
pub struct AuditRows {
    /// Camera samples, midpoint and end stamping.
    pub cam: [Vec<(f64, f64, f64)>; 2],
    /// LiDAR samples, midpoint and end stamping.
    pub lidar: [Vec<(f64, f64, f64)>; 2],
}

/// The outcome of one run.
#[derive(Debug)]
pub struct RunResult {
    /// The seed.
    pub seed: u64,
    /// Midpoint stamping (the default), then end stamping.
    pub scores: [Score; 2],
    /// Camera and LiDAR samples fed to each lane's estimator.
    pub samples: [(usize, usize); 2],
    /// Estimates of each lane.
    pub estimates: [usize; 2],
    /// Rows for the timing audit, when asked for.
    pub audit: Option<AuditRows>,
    /// Per offset step of the run's clock (midpoint lane): seconds after the step
    /// until the estimates followed it ([`follow_times`]), `None` if they did not.
    pub follow: Vec<(f64, f64, Option<f64>)>,
    /// Wall time of the run.
    pub elapsed: Duration,
}

/// Renders `cfg` once and runs both lanes. With `audit`, also collects each
/// front-end's samples against the true speed, turns excluded (±1 s: the camera
/// sees rotation there, the LiDAR other walls). A run that cannot be rendered
/// panics (a test's run is one it knows can be: [`try_run`] otherwise).
pub fn run(cfg: RenderConfig, audit: bool) -> RunResult {
    try_run(cfg, audit).unwrap_or_else(|e| panic!("{e}"))
}

/// [`run`], a run that cannot be rendered an error naming its seed and why: its
/// configuration refused (a room whose boxes, drawn from the seed, leave no clear
/// lane), or a frame that could not be rendered.
pub fn try_run(cfg: RenderConfig, audit: bool) -> Result<RunResult, String> {
    let t0 = Instant::now();
    let seed = cfg.seed;
    let steps = cfg.clock.steps.clone();
    let duration_s = cfg.duration_s;
    let mut r = Renderer::new(cfg).map_err(|e| format!("seed {seed}: {e}"))?;
    let truth = r.truth().clone();
    let traj = r.trajectory().clone();
    let mut lanes = [
        Lane::new(cam::Stamping::Midpoint, lidar::Stamping::Midpoint),
        Lane::new(cam::Stamping::End, lidar::Stamping::End),
    ];
    let mut rows = AuditRows::default();
    let turning = |t: f64| {
        traj.turns()
            .iter()
            .any(|&(a, b)| t > a - 1.0 && t < b + 1.0)
    };
    let acc = |t: f64| (traj.speed(t + 0.005) - traj.speed(t - 0.005)) / 0.01;
    let mut buf = Vec::new();
    for ev in r.events() {
        match ev.map_err(|e| format!("seed {seed}: rendering: {e}"))? {
            Event::Frame(f) => {
                for (i, lane) in lanes.iter_mut().enumerate() {
                    if let (Some(s), true) = (lane.frame(&f), audit) {
                        // camera stamp to true time: τ = t_C + offset(τ)
                        let t = (s.sample.t_ns as f64 + truth.offset_at(f.tau_mid_ns) * 1e9) * 1e-9;
                        if !turning(t) {
                            rows.cam[i].push((s.sample.value, traj.speed(t), acc(t)));
                        }
                    }
                }
            }
            Event::Scan(s) => {
                for (i, lane) in lanes.iter_mut().enumerate() {
                    lane.scan(&s.scan, &mut buf);
                    if audit {
                        for x in &buf {
                            let t = x.t_ns as f64 * 1e-9;
                            if !turning(t) {
                                rows.lidar[i].push((x.value, traj.speed(t), acc(t)));
                            }
                        }
                    }
                }
            }
        }
    }
    let [a, b] = &lanes;
    let ref_lag_s = EstimatorConfig::default().reference_lag_s;
    let follow = follow_times(&a.estimates, &steps, ref_lag_s, duration_s);
    Ok(RunResult {
        seed,
        scores: [score(&a.estimates, &truth), score(&b.estimates, &truth)],
        samples: [
            (a.cam_samples, a.lidar_samples),
            (b.cam_samples, b.lidar_samples),
        ],
        estimates: [a.estimates.len(), b.estimates.len()],
        audit: audit.then_some(rows),
        follow,
        elapsed: t0.elapsed(),
    })
}

/// How long the estimates took to follow each offset step `(τ s, delta s)`, as
/// the load harness judges it (`vlsyncd`'s `harness::report`): an estimate is
/// published `ref_lag_s` after its reference time; the level is the mean of the
/// locked estimates published in the 5 s before the step (not before the previous
/// step); the step is followed at the first estimate published after it from
/// which every estimate for 2 s has moved at least half the step from that level,
/// those 2 s ending before the next step or the end of the run (`end_s`). Rows
/// `(τ, delta, seconds after the step)`; a step of 0 is never followed (half of
/// nothing is no move: every estimate would pass, or none).
pub fn follow_times(
    estimates: &[vlsync_common::Estimate],
    steps: &[(f64, f64)],
    ref_lag_s: f64,
    end_s: f64,
) -> Vec<(f64, f64, Option<f64>)> {
    use vlsync_common::EstimatorState::{Holding, Tracking};
    let locked: Vec<(f64, f64)> = estimates
        .iter()
        .filter(|e| matches!(e.state, Tracking | Holding))
        .map(|e| (e.t_ref_ns as f64 * 1e-9 + ref_lag_s, e.offset_s))
        .collect();
    let mut out = Vec::new();
    for (j, &(t, delta)) in steps.iter().enumerate() {
        let end = steps.get(j + 1).map_or(end_s, |s| s.0);
        let start = if j > 0 {
            steps[j - 1].0
        } else {
            f64::NEG_INFINITY
        };
        let before: Vec<f64> = locked
            .iter()
            .filter(|(p, _)| *p >= (t - 5.0).max(start) && *p < t)
            .map(|x| x.1)
            .collect();
        if before.len() < 3 || delta == 0.0 {
            out.push((t, delta, None));
            continue;
        }
        let level = before.iter().sum::<f64>() / before.len() as f64;
        let after: Vec<(f64, f64)> = locked
            .iter()
            .copied()
            .filter(|(p, _)| *p >= t && *p < end)
            .collect();
        let moved = |o: f64| (o - level) / delta >= 0.5;
        let found = (0..after.len()).find(|&i| {
            let p0 = after[i].0;
            p0 + 2.0 <= end
                && after[i..]
                    .iter()
                    .take_while(|(p, _)| *p <= p0 + 2.0)
                    .all(|&(_, o)| moved(o))
        });
        out.push((t, delta, found.map(|i| after[i].0 - t)));
    }
    out
}

/// Takes the sensors' imperfections that hide the front-ends' own timing out of
/// `c`: the stamp jitter of both clocks, the LiDAR's range noise and the dropped
/// frames (the camera's pixel noise stays).
pub fn ideal_sensors(c: &mut RenderConfig) {
    c.clock.cam_jitter_s = 0.0;
    c.clock.lidar_jitter_s = 0.0;
    c.lidar.range_noise_m = 0.0;
    c.frame_drop_probability = 0.0;
}

/// Runs `seeds` (each with `make(seed)`) on `threads` threads; results in seed order.
/// With `audit`, each result holds its timing audit's rows ([`run`]). A run that
/// cannot be rendered panics ([`try_run_seeds`] otherwise).
pub fn run_seeds(
    seeds: &[u64],
    threads: usize,
    audit: bool,
    make: impl Fn(u64) -> RenderConfig + Sync,
) -> Vec<RunResult> {
    try_run_seeds(seeds, threads, audit, make)
        .into_iter()
        .map(|(_, r)| r.unwrap_or_else(|e| panic!("{e}")))
        .collect()
}

/// [`run_seeds`], each seed's outcome beside it ([`try_run`]): one run that cannot
/// be rendered is its own row, not the end of every other (it used to panic its
/// worker, and with it the whole table).
pub fn try_run_seeds(
    seeds: &[u64],
    threads: usize,
    audit: bool,
    make: impl Fn(u64) -> RenderConfig + Sync,
) -> Vec<(u64, Result<RunResult, String>)> {
    let queue = std::sync::Mutex::new(seeds.iter().rev().copied().collect::<Vec<_>>());
    let results = std::sync::Mutex::new(Vec::new());
    std::thread::scope(|s| {
        for _ in 0..threads.clamp(1, seeds.len().max(1)) {
            s.spawn(|| loop {
                let next = queue.lock().unwrap().pop();
                let Some(seed) = next else { break };
                let r = try_run(make(seed), audit);
                results.lock().unwrap().push((seed, r));
            });
        }
    });
    let mut out = results.into_inner().unwrap();
    out.sort_by_key(|(seed, _)| seeds.iter().position(|s| s == seed));
    out
}

/// Builds every seed's run (`make(seed)`) before any is rendered, so that a bad
/// seed is said at once rather than after the others' minutes of rendering: the
/// seeds whose run cannot be built, grouped by why (a room too narrow for one
/// seed's boxes, drawn from the seed, fails that seed only; a bad option fails
/// them all), or `Ok`.
pub fn check_seeds(seeds: &[u64], make: impl Fn(u64) -> RenderConfig) -> Result<(), String> {
    let mut why: Vec<(String, Vec<u64>)> = Vec::new();
    for &seed in seeds {
        if let Err(e) = Renderer::new(make(seed)) {
            let e = e.to_string();
            match why.iter_mut().find(|(w, _)| *w == e) {
                Some((_, s)) => s.push(seed),
                None => why.push((e, vec![seed])),
            }
        }
    }
    if why.is_empty() {
        return Ok(());
    }
    let bad: usize = why.iter().map(|(_, s)| s.len()).sum();
    let groups: Vec<String> = why
        .iter()
        .map(|(w, s)| {
            let list: Vec<String> = s.iter().map(u64::to_string).collect();
            let noun = if s.len() == 1 { "seed" } else { "seeds" };
            format!("{noun} {}: {w}", list.join(", "))
        })
        .collect();
    Err(format!(
        "{bad} of the {} seeds cannot be rendered: {}",
        seeds.len(),
        groups.join("; ")
    ))
}

/// `T:D,...` (the example's `--steps`): offset steps of `D` ms at `T` s (a camera
/// latency increase of Δ is a step of -Δ), as `(T, D / 1000)`. A step of 0 ms is
/// refused: it has nothing to follow.
pub fn parse_steps(s: &str) -> Result<Vec<(f64, f64)>, String> {
    s.split(',')
        .map(|part| {
            let (t, d) = parse_pair("--steps", part, ':', "TIME_S:DELTA_MS")?;
            if d == 0.0 {
                return Err(format!(
                    "--steps: `{part}` is a step of 0 ms, which has nothing to follow \
                     (give a non-zero DELTA_MS)"
                ));
            }
            Ok((t, d * 1e-3))
        })
        .collect()
}

/// Two finite numbers `A<sep>B` of `flag`'s value `v` (`shape` names them in the error).
pub fn parse_pair(flag: &str, v: &str, sep: char, shape: &str) -> Result<(f64, f64), String> {
    let (a, b) = v
        .split_once(sep)
        .ok_or(format!("{flag}: `{v}` is not {shape}"))?;
    let num = |x: &str| {
        x.trim()
            .parse::<f64>()
            .ok()
            .filter(|n| n.is_finite())
            .ok_or(format!("{flag}: `{x}` in `{v}` is not a number"))
    };
    Ok((num(a)?, num(b)?))
}

/// Least-squares fit `y = g·x + h·a` (no intercept) of `(y, x, a)` rows; the delay
/// `-h / g` of a sample that reads `g·v(t - δ) ≈ g·v(t) - g·δ·a(t)`: positive
/// means stamped late.
pub fn delay(rows: &[(f64, f64, f64)]) -> f64 {
    let (mut sxx, mut sxa, mut saa, mut sxy, mut say) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for &(y, x, a) in rows {
        sxx += x * x;
        sxa += x * a;
        saa += a * a;
        sxy += x * y;
        say += a * y;
    }
    let det = sxx * saa - sxa * sxa;
    let (g, h) = ((sxy * saa - say * sxa) / det, (say * sxx - sxy * sxa) / det);
    -h / g
}

/// One line of the per-seed table (milliseconds).
pub fn table_row(r: &RunResult) -> String {
    let [m, e] = &r.scores;
    let (plain, signed) = (|x| ms(x, false), |x| ms(x, true));
    format!(
        "| {} | {} | {} | {} | {} | {} | {} | {} | {:.1} |",
        r.seed,
        plain(m.mae_s),
        signed(m.bias_s),
        plain(m.p95_s),
        m.n,
        plain(e.mae_s),
        signed(e.bias_s),
        plain(e.p95_s),
        r.elapsed.as_secs_f64()
    )
}

/// Seconds `x` as milliseconds to 0.01 (with its sign when `signed`), or "-" when
/// not finite: a run with no tracking estimate has no error to print.
pub fn ms(x: f64, signed: bool) -> String {
    match (x.is_finite(), signed) {
        (false, _) => "-".into(),
        (true, true) => format!("{:+.2}", x * 1e3),
        (true, false) => format!("{:.2}", x * 1e3),
    }
}

/// The header of [`table_row`]'s table.
pub const TABLE_HEADER: &str = "| seed | midpoint MAE ms | bias ms | p95 ms | tracking estimates | end MAE ms | end bias ms | end p95 ms | run s |\n|---:|---:|---:|---:|---:|---:|---:|---:|---:|";
