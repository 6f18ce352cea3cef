//! CPU cost of one `push` (with its `poll`) on a simulated run: its distribution,
//! split into the pushes that complete a hop (an estimate) and the others, which
//! carry the previous hop's step test and the next hop's preparation in stages.
//! `--thrash-mb N` writes an N MiB buffer between pushes, as the daemon's sleeps
//! between samples let other processes empty the caches; the hot figures alone
//! would flatter the daemon. `--urgent` times the daemon's way instead:
//! `push_urgent` and `poll` as the sample's cost, then `idle` (the background
//! stage) on its own.
//!
//! `cargo run --release -p vlsync-estimator --example push_cost -- [--family F] [--seed S] [--thrash-mb N] [--urgent]`
use std::io::Write;
use std::process::ExitCode;
use std::time::Instant;
use vlsync_config::EstimatorConfig;
use vlsync_estimator::Estimator;
use vlsync_sim::families::{try_generate, Family};

const USAGE: &str = "usage: push_cost [--family F] [--seed S] [--thrash-mb N] [--urgent]";

struct Args {
    family: Family,
    seed: u64,
    thrash_mb: usize,
    urgent: bool,
}

fn parse() -> Result<Args, String> {
    let mut a = Args {
        family: Family::Robot,
        seed: 1000,
        thrash_mb: 0,
        urgent: false,
    };
    let mut it = std::env::args().skip(1);
    while let Some(k) = it.next() {
        let mut val = || it.next().ok_or(format!("{k} needs a value\n{USAGE}"));
        match k.as_str() {
            "--family" => a.family = val()?.parse().map_err(|e| format!("--family: {e}"))?,
            "--seed" => {
                let v = val()?;
                a.seed = v
                    .parse()
                    .map_err(|_| format!("--seed: `{v}` is not a u64"))?;
            }
            "--thrash-mb" => {
                let v = val()?;
                a.thrash_mb = v
                    .parse()
                    .ok()
                    .filter(|&m: &usize| m <= 1024)
                    .ok_or(format!("--thrash-mb: `{v}` is not 0..=1024"))?;
            }
            "--urgent" => a.urgent = true,
            "-h" | "--help" => return Err(USAGE.into()),
            _ => return Err(format!("unknown argument `{k}`\n{USAGE}")),
        }
    }
    Ok(a)
}

/// Percentile `p` of `v` (sorted in place), µs.
fn pct(v: &mut [u64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_unstable();
    v[((v.len() - 1) as f64 * p).round() as usize] as f64 / 1e3
}

fn main() -> ExitCode {
    let a = match parse() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("{e}");
            return ExitCode::from(2);
        }
    };
    let run = match try_generate(a.family, a.seed, None) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("push_cost: {e}");
            return ExitCode::FAILURE;
        }
    };
    let all = run.pushes();
    let mut junk = vec![0u8; a.thrash_mb << 20];
    // a closed stdout (`| head`) ends the run quietly
    let mut out = std::io::stdout().lock();
    let header = writeln!(
        out,
        "{} seed {}, {} samples, {} MiB written between pushes; µs per {} (3 runs):",
        a.family.name(),
        a.seed,
        all.len(),
        a.thrash_mb,
        if a.urgent {
            "push_urgent, and per idle"
        } else {
            "push"
        }
    );
    if header.is_err() {
        return ExitCode::SUCCESS;
    }
    for rep in 1..=3 {
        let mut est = Estimator::new(&EstimatorConfig::default());
        let (mut hop, mut other, mut idle) = (Vec::new(), Vec::new(), Vec::new());
        for &(stream, s) in &all {
            for b in junk.iter_mut().step_by(64) {
                *b = b.wrapping_add(1);
            }
            let t0 = Instant::now();
            let _ = if a.urgent {
                est.push_urgent(stream, s)
            } else {
                est.push(stream, s)
            };
            let mut n = 0;
            while est.poll().is_some() {
                n += 1;
            }
            let dt = t0.elapsed().as_nanos() as u64;
            if n > 0 {
                hop.push(dt);
            } else {
                other.push(dt);
            }
            if a.urgent {
                let t1 = Instant::now();
                est.idle();
                idle.push(t1.elapsed().as_nanos() as u64);
            }
        }
        let line = writeln!(
            out,
            "  run {rep}: {} with an estimate: p50 {:.1} p99 {:.1} max {:.1} | {} others: p50 {:.1} p99 {:.1} p99.9 {:.1} max {:.1}",
            hop.len(),
            pct(&mut hop, 0.5),
            pct(&mut hop, 0.99),
            pct(&mut hop, 1.0),
            other.len(),
            pct(&mut other, 0.5),
            pct(&mut other, 0.99),
            pct(&mut other, 0.999),
            pct(&mut other, 1.0),
        );
        if line.is_err() {
            return ExitCode::SUCCESS;
        }
        if a.urgent {
            let line = writeln!(
                out,
                "         idle: p50 {:.1} p99 {:.1} p99.9 {:.1} max {:.1}",
                pct(&mut idle, 0.5),
                pct(&mut idle, 0.99),
                pct(&mut idle, 0.999),
                pct(&mut idle, 1.0),
            );
            if line.is_err() {
                return ExitCode::SUCCESS;
            }
        }
    }
    ExitCode::SUCCESS
}
