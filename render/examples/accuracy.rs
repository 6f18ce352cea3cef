//! End-to-end accuracy over many rendered runs: each seed is rendered once and
//! fed through signature-cam and signature-lidar (shipped defaults) into the
//! estimator (shipped defaults), with midpoint stamping (the default) and with
//! end-of-interval stamping side by side; prints a markdown table of the error
//! of the tracking estimates against the truth.
//!
//! ```sh
//! cargo run --release -p vlsync-render --example accuracy -- --seeds 1-6
//! cargo run --release -p vlsync-render --example accuracy -- --seeds 100-109 --threads 2
//! cargo run --release -p vlsync-render --example accuracy -- --seeds 100-103 --width 640 --height 480
//! # a slower camera or another LiDAR rate (the renderer's checks apply)
//! cargo run --release -p vlsync-render --example accuracy -- --seeds 1-8 --fps 10
//! cargo run --release -p vlsync-render --example accuracy -- --seeds 1-8 --lidar-hz 5.5
//! # another room (length, width in metres), lens or camera mounting
//! cargo run --release -p vlsync-render --example accuracy -- --seeds 1-8 --room 16,5
//! cargo run --release -p vlsync-render --example accuracy -- --seeds 1-8 --hfov 90 --pitch 40
//! # each front-end against the true speed (delay, gain by speed), without stamp jitter,
//! # range noise or dropped frames
//! cargo run --release -p vlsync-render --example accuracy -- --seeds 1-8 --fps 10 --audit --ideal-sensors
//! ```
//!
//! `--audit` adds a table of each front-end's timing against the true speed of
//! the drive (turns excluded): its delay, fitted as in `tests/end_to_end.rs`
//! (positive: the samples describe motion earlier than their stamps), and its
//! gain by speed band relative to its median gain (a front-end losing points at
//! speed reads low there). `--ideal-sensors` takes out the stamp jitter, the
//! LiDAR's range noise and the dropped frames, leaving the front-ends' own
//! timing (the camera's pixel noise, 2 gray levels, stays). `--fps` must stay
//! below 125: the renderer's 8 ms exposure must fit in a frame period.
//!
//! Every seed's run is built before any is rendered: seeds that cannot be (a room
//! too narrow for the boxes a seed draws) are named with why, and nothing runs
//! (status 2). A run that fails while rendering is a `failed` row, said under the
//! table and left out of the means (status 1). `--steps` refuses a step of 0 ms.
//!
//! A 60 s seed at 320x240 takes ~20-30 s of CPU (4x that at 640x480).

#[path = "../tests/support/pipeline.rs"]
mod pipeline;

use pipeline::{check_seeds, parse_pair, parse_steps, table_row, try_run_seeds, TABLE_HEADER};
use std::process::ExitCode;
use vlsync_render::RenderConfig;

struct Args {
    seeds: Vec<u64>,
    duration_s: f64,
    threads: usize,
    size: Option<(usize, usize)>,
    steps: Vec<(f64, f64)>,
    fps: Option<f64>,
    lidar_hz: Option<f64>,
    audit: bool,
    ideal: bool,
    room: Option<(f64, f64)>,
    hfov: Option<f64>,
    pitch: Option<f64>,
    cam_height: Option<f64>,
}

fn parse_seeds(s: &str) -> Result<Vec<u64>, String> {
    let mut out = Vec::new();
    for part in s.split(',') {
        let num = |x: &str| {
            x.trim()
                .parse::<u64>()
                .map_err(|e| format!("seed `{x}` in `{s}`: {e}"))
        };
        match part.split_once('-') {
            Some((a, b)) => {
                let (a, b) = (num(a)?, num(b)?);
                if b < a || b - a > 10_000 {
                    return Err(format!("seed range `{part}` is empty or too long"));
                }
                out.extend(a..=b);
            }
            None => out.push(num(part)?),
        }
    }
    Ok(out)
}

const USAGE: &str = "usage: accuracy [--seeds 1-6,100] [--duration 60] [--threads 2] [--width W --height H] [--fps F] [--lidar-hz H] [--room LENGTH,WIDTH] [--hfov DEG] [--pitch DEG] [--cam-height M] [--opposite-window] [--audit] [--ideal-sensors] [--steps T_S:DELTA_MS,...]";

fn parse() -> Result<Args, String> {
    let mut a = Args {
        seeds: (1..=6).collect(),
        duration_s: 60.0,
        threads: 2,
        size: None,
        steps: Vec::new(),
        fps: None,
        lidar_hz: None,
        audit: false,
        ideal: false,
        room: None,
        hfov: None,
        pitch: None,
        cam_height: None,
    };
    let mut it = std::env::args().skip(1);
    let mut width = None;
    let mut height = None;
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or_else(|| format!("{flag} needs a value"));
        match flag.as_str() {
            "--seeds" => a.seeds = parse_seeds(&value()?)?,
            "--duration" => {
                a.duration_s = value()?.parse().map_err(|e| format!("--duration: {e}"))?
            }
            "--threads" => a.threads = value()?.parse().map_err(|e| format!("--threads: {e}"))?,
            "--width" => width = Some(value()?.parse().map_err(|e| format!("--width: {e}"))?),
            "--height" => height = Some(value()?.parse().map_err(|e| format!("--height: {e}"))?),
            "--steps" => a.steps = parse_steps(&value()?)?,
            "--fps" => a.fps = Some(value()?.parse().map_err(|e| format!("--fps: {e}"))?),
            "--lidar-hz" => {
                a.lidar_hz = Some(value()?.parse().map_err(|e| format!("--lidar-hz: {e}"))?)
            }
            "--room" => {
                a.room = Some(parse_pair(
                    "--room",
                    &value()?,
                    ',',
                    "LENGTH,WIDTH (metres)",
                )?)
            }
            "--hfov" => a.hfov = Some(value()?.parse().map_err(|e| format!("--hfov: {e}"))?),
            "--pitch" => a.pitch = Some(value()?.parse().map_err(|e| format!("--pitch: {e}"))?),
            "--cam-height" => {
                a.cam_height = Some(value()?.parse().map_err(|e| format!("--cam-height: {e}"))?)
            }
            "--audit" => a.audit = true,
            "--ideal-sensors" => a.ideal = true,
            "--opposite-window" => {
                pipeline::OPPOSITE_WINDOW.store(true, std::sync::atomic::Ordering::Relaxed)
            }
            "--help" | "-h" => {
                println!("{USAGE}");
                std::process::exit(0);
            }
            other => return Err(format!("unknown argument `{other}` (try --help)")),
        }
    }
    a.size = match (width, height) {
        (Some(w), Some(h)) => Some((w, h)),
        (None, None) => None,
        _ => return Err("--width and --height go together".into()),
    };
    Ok(a)
}

fn main() -> ExitCode {
    let a = match parse() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("accuracy: {e}");
            return ExitCode::from(2);
        }
    };
    let make = |seed| {
        let mut c = RenderConfig::from_seed(seed, a.duration_s);
        c.clock.steps.clone_from(&a.steps);
        if let Some((w, h)) = a.size {
            c.camera.width = w;
            c.camera.height = h;
        }
        if let Some(fps) = a.fps {
            c.camera.fps = fps;
        }
        if let Some(hz) = a.lidar_hz {
            c.lidar.rate_hz = hz;
        }
        if let Some((l, w)) = a.room {
            c.room.0 = l;
            c.room.1 = w;
        }
        if let Some(deg) = a.hfov {
            c.camera.hfov_deg = deg;
        }
        if let Some(deg) = a.pitch {
            c.camera.pitch_deg = deg;
        }
        if let Some(m) = a.cam_height {
            c.camera.height_m = m;
        }
        if a.ideal {
            pipeline::ideal_sensors(&mut c);
        }
        c
    };
    // every seed's run is built first: a room too narrow for one seed's boxes
    // fails that seed, said now, not after the others have rendered
    if let Err(e) = check_seeds(&a.seeds, make) {
        eprintln!("accuracy: {e}");
        return ExitCode::from(2);
    }
    let outcomes = try_run_seeds(&a.seeds, a.threads, a.audit, make);
    println!("{TABLE_HEADER}");
    for (seed, o) in &outcomes {
        match o {
            Ok(r) => println!("{}", table_row(r)),
            Err(_) => println!("| {seed} | failed | - | - | 0 | - | - | - | - |"),
        }
    }
    // a frame that could not be rendered: said under the table, the run left out
    let failed: Vec<String> = outcomes
        .iter()
        .filter_map(|(_, o)| o.as_ref().err().cloned())
        .collect();
    for e in &failed {
        println!("  failed: {e}");
    }
    let results: Vec<pipeline::RunResult> =
        outcomes.into_iter().filter_map(|(_, o)| o.ok()).collect();
    if !a.steps.is_empty() {
        println!("\nsteps followed (as the load harness judges it, publish time; midpoint):");
        for r in &results {
            let cells: Vec<String> = r
                .follow
                .iter()
                .map(|(t, d, f)| match f {
                    Some(f) => format!("{:+.0} ms at {t:.0} s: {f:.1} s", d * 1e3),
                    None => format!("{:+.0} ms at {t:.0} s: not followed", d * 1e3),
                })
                .collect();
            println!("  seed {}: {}", r.seed, cells.join(", "));
        }
    }
    if a.audit {
        print_audit(&results);
    }
    // a run that never locked has no error to average: it is counted apart, so
    // one such run does not turn every mean into NaN
    let mean_ms = |f: &dyn Fn(&pipeline::RunResult) -> f64, signed: bool| {
        let v: Vec<f64> = results.iter().map(f).filter(|x| x.is_finite()).collect();
        // none: NaN, printed "-"
        pipeline::ms(v.iter().sum::<f64>() / v.len() as f64, signed)
    };
    let met = results
        .iter()
        .filter(|r| r.scores[0].mae_s <= 0.003)
        .count();
    let unlocked = results.iter().filter(|r| r.scores[0].n == 0).count();
    let unlocked = match unlocked {
        0 => String::new(),
        k => format!(" ({k} never tracking, left out of the means)"),
    };
    let failed_note = match failed.len() {
        0 => String::new(),
        k => format!(" ({k} failed, above, left out)"),
    };
    println!(
        "\nmidpoint: mean MAE {} ms, mean bias {} ms, {met}/{} runs <= 3 ms{unlocked}{failed_note}; end: mean MAE {} ms",
        mean_ms(&|r| r.scores[0].mae_s, false),
        mean_ms(&|r| r.scores[0].bias_s, true),
        results.len(),
        mean_ms(&|r| r.scores[1].mae_s, false),
    );
    if failed.is_empty() {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    }
}

/// Each front-end against the true speed (turns excluded), midpoint stamping: its
/// delay (positive: the sample describes motion earlier than its stamp says) and
/// its gain (value per m/s) by speed, which shows a front-end that saturates or
/// loses its track at speed.
fn print_audit(results: &[pipeline::RunResult]) {
    const BINS: [(f64, f64); 4] = [(0.05, 0.2), (0.2, 0.4), (0.4, 0.6), (0.6, f64::INFINITY)];
    let gains = |rows: &[(f64, f64, f64)]| -> Vec<String> {
        let all: Vec<f64> = rows
            .iter()
            .filter(|r| r.1.abs() >= BINS[0].0)
            .map(|r| r.0 / r.1)
            .collect();
        let reference = median(all).unwrap_or(f64::NAN);
        BINS.iter()
            .map(|&(lo, hi)| {
                let g: Vec<f64> = rows
                    .iter()
                    .filter(|r| r.1.abs() >= lo && r.1.abs() < hi)
                    .map(|r| r.0 / r.1)
                    .collect();
                let n = g.len();
                match median(g) {
                    Some(m) => format!("{:.2} ({n})", m / reference),
                    None => "-".into(),
                }
            })
            .collect()
    };
    println!(
        "\ntiming audit (midpoint; gain: median value / speed in each speed band, over all bands'):"
    );
    println!("| seed | camera delay ms | LiDAR delay ms | camera gain 0.05-0.2 / 0.2-0.4 / 0.4-0.6 / 0.6+ m/s (samples) | LiDAR gain, same bands |");
    println!("|---:|---:|---:|---|---|");
    // a run without rows to fit (all of it turning, or too short) has no delay
    let ms = |d: f64| pipeline::ms(d, true);
    for r in results {
        let Some(rows) = &r.audit else { continue };
        println!(
            "| {} | {} | {} | {} | {} |",
            r.seed,
            ms(pipeline::delay(&rows.cam[0])),
            ms(pipeline::delay(&rows.lidar[0])),
            gains(&rows.cam[0]).join(" / "),
            gains(&rows.lidar[0]).join(" / "),
        );
    }
}

/// The median of the finite values (the upper one of an even count).
fn median(mut v: Vec<f64>) -> Option<f64> {
    v.retain(|x| x.is_finite());
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[v.len() / 2])
}
