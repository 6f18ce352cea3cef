//! The command line shared by `vlsync-cam` and `vlsync-lidar`.

use crate::{run, sim_anchor_ns, DriverError, Pacing, Source, VecSource};
use clap::Parser;
use std::path::PathBuf;
use std::process::ExitCode;
use vlsync_common::Stream;
use vlsync_ipc::{create_node, termination_requested, ServiceNames, SignaturePublisher};

/// Arguments of a signature driver.
#[derive(Parser, Debug, Clone)]
#[command(version, about = "Publish one signature stream to the vlsync daemon")]
pub struct DriverArgs {
    /// Service prefix (`services.prefix`); overrides the one of --config.
    #[arg(long)]
    pub prefix: Option<String>,
    /// Configuration file (only `[services]` is used here).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Replay this signature CSV (header, then `t,value` rows, t in seconds).
    #[arg(long, conflicts_with = "sim")]
    pub csv: Option<PathBuf>,
    /// Run the live signature simulator of this family (e.g. `robot`).
    #[arg(long)]
    pub sim: Option<String>,
    /// Simulator seed (both drivers of a pair must use the same).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Simulated duration in seconds (default: the family's).
    #[arg(long)]
    pub duration: Option<f64>,
    /// Publish as fast as possible instead of in real time.
    #[arg(long, conflicts_with = "speed")]
    pub fast: bool,
    /// Real-time speed factor (1 = real time, 100 = 100x).
    #[arg(long)]
    pub speed: Option<f64>,
    /// Common start instant on CLOCK_MONOTONIC in ns (the demo gives both drivers
    /// the same one; a restarted driver given the same resumes at the current position).
    #[arg(long)]
    pub start_at: Option<i64>,
}

fn source_and_anchor(args: &DriverArgs, stream: Stream) -> Result<(VecSource, i64), DriverError> {
    match (&args.csv, &args.sim) {
        (Some(p), None) => {
            let s = VecSource::from_csv(p).map_err(DriverError::Source)?;
            let anchor = s.first_t_ns().unwrap_or(0);
            Ok((s, anchor))
        }
        (None, Some(fam)) => {
            let family: vlsync_sim::Family = fam
                .parse()
                .map_err(|e| DriverError::Options(format!("--sim: {e}")))?;
            let run = vlsync_sim::try_generate(family, args.seed, args.duration)
                .map_err(|e| DriverError::Options(format!("--duration: {e}")))?;
            Ok((VecSource::from_sim(&run, stream), sim_anchor_ns(&run)))
        }
        _ => Err(DriverError::Options(
            "give exactly one source: --csv FILE or --sim FAMILY".to_string(),
        )),
    }
}

fn prefix(args: &DriverArgs) -> Result<String, DriverError> {
    if let Some(p) = &args.prefix {
        return Ok(p.clone());
    }
    match &args.config {
        Some(path) => vlsync_config::Config::load(path)
            .map(|c| c.services.prefix)
            .map_err(|e| DriverError::Options(e.to_string())),
        None => Ok(vlsync_config::ServicesConfig::default().prefix),
    }
}

/// Runs a driver for `stream` with `args`.
pub fn run_driver(stream: Stream, args: &DriverArgs) -> Result<crate::RunSummary, DriverError> {
    let prefix = prefix(args)?;
    let names = ServiceNames::new(&prefix).map_err(DriverError::Ipc)?;
    let (mut source, anchor) = source_and_anchor(args, stream)?;
    let node = create_node(&format!("vlsync-{stream}"), true).map_err(DriverError::Ipc)?;
    let mut publisher =
        SignaturePublisher::open(&node, &names, stream).map_err(DriverError::Ipc)?;
    let pacing = if args.fast {
        Pacing::Fast
    } else {
        Pacing::Scaled {
            speed: args.speed.unwrap_or(1.0),
            anchor_ns: anchor,
            start_mono_ns: args.start_at,
        }
    };
    eprintln!(
        "vlsync-{stream}: publishing {} ({} samples) on {}",
        source.describe(),
        source.len(),
        names.signature(stream)
    );
    run(&mut source, &mut publisher, pacing, &termination_requested)
}

/// `main` of a driver binary.
pub fn main(stream: Stream) -> ExitCode {
    let args = DriverArgs::parse_from(std::env::args_os());
    match run_driver(stream, &args) {
        Ok(s) => {
            eprintln!(
                "vlsync-{stream}: {} published, {} skipped (before restart), {} failed{}",
                s.published,
                s.skipped,
                s.failed,
                if s.interrupted { ", interrupted" } else { "" }
            );
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("vlsync-{stream}: error: {e}");
            ExitCode::from(2)
        }
    }
}
