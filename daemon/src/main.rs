//! `vlsyncd`: the vlsync daemon binary. Thin: argument parsing and exit codes;
//! the logic lives in the `vlsyncd` library.
#![forbid(unsafe_code)]

use clap::{Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "vlsyncd",
    version,
    about = "Camera-LiDAR time-offset estimator daemon"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Run the estimator offline on recorded signature CSV files.
    Replay {
        /// Camera signature CSV (`t,value`, t in seconds on the camera clock).
        #[arg(long)]
        cam: PathBuf,
        /// LiDAR signature CSV (`t,value`, t in seconds on the LiDAR clock).
        #[arg(long)]
        lidar: PathBuf,
        /// Output estimates CSV.
        #[arg(long)]
        out: PathBuf,
        /// Configuration file (TOML); defaults are used without it.
        #[arg(long)]
        config: Option<PathBuf>,
        /// Truth CSV (`t,offset` on the LiDAR clock, as `vlsync-sim` writes): prints the error.
        #[arg(long)]
        truth: Option<PathBuf>,
        /// Write an SVG plot of the estimates (and the truth, when given).
        #[arg(long)]
        plot: Option<PathBuf>,
        /// Compare with another run's estimates (`vlsyncd record`'s est.csv, or an earlier
        /// replay's --out): prints how many are identical and how far the offsets differ,
        /// and draws them in the --plot.
        #[arg(long)]
        compare: Option<PathBuf>,
        /// How the two files are merged: `publish` in the order the daemon read them
        /// (the `publish` column `vlsyncd record` writes), `stamp` by their stamps (the
        /// camera's moved by `estimator.lag_center_s`), `auto` by publish time when both
        /// files carry it and none is 0 or negative (else by stamp, saying why).
        #[arg(long, value_enum, default_value_t)]
        order: vlsyncd::replay::OrderArg,
    },
    /// Record the live signature streams and estimates of a prefix as the CSV files
    /// `replay` reads and writes (cam.csv, lidar.csv, est.csv), until --duration or Ctrl-C.
    Record(vlsyncd::record::RecordArgs),
    /// Accuracy benchmark: every simulated family over several seeds, against the seed baseline.
    Bench(vlsyncd::bench::BenchArgs),
    /// Run the real-time estimator service on the iceoryx2 services (until SIGINT/SIGTERM).
    Run(vlsyncd::runtime::RunArgs),
    /// Validate a configuration file as `run` would (exit code 2 and the error when it is
    /// not valid); --print shows the effective configuration, defaults filled in.
    Check {
        /// Configuration file (TOML).
        #[arg(long)]
        config: PathBuf,
        /// Also print the effective configuration (every key) as TOML.
        #[arg(long)]
        print: bool,
    },
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            if !e.use_stderr() {
                let _ = e.print();
                return ExitCode::SUCCESS; // --help, --version
            }
            vlsync_common::console::print_err_at(
                vlsync_common::console::Priority::Error,
                &format!("{}\n", e.render().to_string().trim_end()),
            );
            // `run` given options it cannot take (an `ExecStart=` drop-in's typo, a
            // --fifo-priority out of range) is a configuration error as its file's are:
            // 78, which the unit does not restart every 2 s; the one-shot commands keep
            // clap's 2
            let run = std::env::args_os().nth(1).is_some_and(|a| a == "run");
            return ExitCode::from(if run {
                vlsyncd::runtime::EXIT_CONFIG
            } else {
                2
            });
        }
    };
    let result = match cli.cmd {
        Cmd::Replay {
            cam,
            lidar,
            out,
            config,
            truth,
            plot,
            compare,
            order,
        } => vlsyncd::replay::run_cli(&vlsyncd::replay::ReplayArgs {
            cam: &cam,
            lidar: &lidar,
            out: &out,
            config: config.as_deref(),
            truth: truth.as_deref(),
            plot: plot.as_deref(),
            compare: compare.as_deref(),
            order,
        }),
        Cmd::Record(args) => vlsyncd::record::run_cli(&args),
        Cmd::Bench(args) => vlsyncd::bench::run_cli(&args),
        Cmd::Run(args) => match vlsyncd::runtime::load_config(&args) {
            Ok(cfg) => vlsyncd::runtime::run_cli(cfg),
            Err(e) => {
                vlsync_common::console::print_err_at(
                    vlsync_common::console::Priority::Error,
                    &format!("vlsyncd: error: {e}\n"),
                );
                return ExitCode::from(vlsyncd::runtime::EXIT_CONFIG);
            }
        },
        Cmd::Check { config, print } => vlsyncd::check::check(&config, print)
            .and_then(|report| vlsync_common::console::print_out(&report)),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            vlsync_common::console::print_err_at(
                vlsync_common::console::Priority::Error,
                &format!("vlsyncd: error: {e}\n"),
            );
            ExitCode::from(2)
        }
    }
}
