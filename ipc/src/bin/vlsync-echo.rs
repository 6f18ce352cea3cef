//! `vlsync-echo`: prints the daemon's offset estimates as they arrive, one
//! readable line each (every estimate, in order; those a stopped or slow reader
//! lost from the client's buffer of 16 are counted on stderr), or one JSON object
//! per line with `--json`; with
//! `--status`, the daemon's counters instead (one line per status period).
#![forbid(unsafe_code)]

use clap::Parser;
use std::io::Write;
use std::process::ExitCode;
use std::time::{Duration, Instant};
use vlsync_common::wire::{Status, REJECT_NAMES};
use vlsync_common::Estimate;

#[derive(Parser)]
#[command(
    name = "vlsync-echo",
    version,
    about = "Print vlsync offset estimates as they arrive (or, with --status, the daemon's counters)"
)]
struct Args {
    /// Service prefix (`services.prefix` of the daemon).
    #[arg(long, default_value = "vlsync/robot")]
    prefix: String,
    /// One JSON object per line instead of readable text.
    #[arg(long)]
    json: bool,
    /// Print the daemon's status (samples received, rejected by reason and lost per
    /// stream, estimates, budget overruns, latency percentiles) as it is published,
    /// every `daemon.status_period_s`, instead of the estimates.
    #[arg(long)]
    status: bool,
    /// Exit after this many estimates (statuses with --status; 0: run until Ctrl-C).
    #[arg(long, allow_negative_numbers = true, default_value_t = 0)]
    count: u64,
    /// Exit after this many seconds (0: no limit).
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.0)]
    duration: f64,
}

fn json_f64(v: f64) -> serde_json::Value {
    // JSON has no NaN/inf: `null` (e.g. `measured_offset_s` when no measurement was
    // accepted), so every field keeps one type, a number or null
    if v.is_finite() {
        serde_json::json!(v)
    } else {
        serde_json::Value::Null
    }
}

fn line(e: &Estimate, json: bool) -> String {
    if json {
        serde_json::json!({
            "seq": e.seq,
            "t_ref_ns": e.t_ref_ns,
            "offset_s": json_f64(e.offset_s),
            "drift": json_f64(e.drift),
            "offset_std_s": json_f64(e.offset_std_s),
            "drift_std": json_f64(e.drift_std),
            "state": e.state.name(),
            "polarity": e.polarity.name(),
            "peak_score": json_f64(e.peak_score),
            "peak_ratio": json_f64(e.peak_ratio),
            "measured_offset_s": json_f64(e.measured_offset_s),
        })
        .to_string()
    } else {
        format!(
            "#{:<6} t_ref {:>14.3} s  offset {:>+10.3} ms ± {:>7.3} ms  drift {:>+9.2} ppm  {:<9} {:<8} score {:.2}",
            e.seq,
            e.t_ref_ns as f64 * 1e-9,
            e.offset_s * 1e3,
            e.offset_std_s * 1e3,
            e.drift * 1e6,
            e.state.name(),
            e.polarity.name(),
            e.peak_score
        )
    }
}

fn status_line(s: &Status, json: bool) -> String {
    if json {
        let streams: Vec<serde_json::Value> = (0..2)
            .map(|i| {
                let rejected: serde_json::Map<String, serde_json::Value> = REJECT_NAMES
                    .iter()
                    .zip(s.rejected[i])
                    .map(|(n, v)| (n.to_string(), serde_json::json!(v)))
                    .collect();
                serde_json::json!({
                    "received": s.received[i], "rejected": rejected, "lost": s.lost[i],
                })
            })
            .collect();
        serde_json::json!({
            "uptime_ns": s.uptime_ns,
            "publish_ns": s.publish_ns,
            "state": s.estimator_state().map_or("none", |st| st.name()),
            "degraded": s.degraded == 1,
            "cam": streams[0],
            "lidar": streams[1],
            "estimates_published": s.estimates_published,
            "budget_overruns": s.budget_overruns,
            "events_dropped": s.events_dropped,
            "processing_ns": {"p50": s.processing_ns[0], "p99": s.processing_ns[1], "max": s.processing_ns[2]},
            "end_to_end_ns": {"p50": s.end_to_end_ns[0], "p99": s.end_to_end_ns[1], "max": s.end_to_end_ns[2]},
            "latency_count": s.latency_count,
        })
        .to_string()
    } else {
        s.to_string()
    }
}

/// After this long without a line, `vlsync-echo` says on stderr what it waits for.
const QUIET_NOTICE: Duration = Duration::from_secs(5);

/// What an echo that has received nothing yet says (once, on stderr): a daemon on
/// another prefix is the usual cause.
fn quiet_notice(args: &Args) -> String {
    format!(
        "vlsync-echo: nothing received on `{}/{}` for {} s; waiting (is a daemon running \
         with services.prefix = \"{}\"? vlsync-demo uses its own prefix, printed at its start)\n",
        args.prefix,
        if args.status { "status" } else { "offset" },
        QUIET_NOTICE.as_secs(),
        args.prefix
    )
}

/// Prints the lines each `next()` returns until `--count` lines, `--duration`,
/// Ctrl-C, a closed stdout (all exit 0), a full stdout or an error from `next()` (its message,
/// exit code 1). `next()` waits a little for data itself.
fn print_until_done(
    args: &Args,
    mut next: impl FnMut() -> Result<Vec<String>, String>,
) -> ExitCode {
    let start = Instant::now();
    let mut n = 0u64;
    let mut told = false;
    let mut out = std::io::stdout().lock();
    while !vlsync_ipc::termination_requested() {
        if args.duration > 0.0 && start.elapsed().as_secs_f64() >= args.duration {
            break;
        }
        if n == 0 && !told && start.elapsed() >= QUIET_NOTICE {
            told = true;
            vlsync_common::console::print_err(&quiet_notice(args));
        }
        let lines = match next() {
            Ok(lines) => lines,
            Err(e) => {
                vlsync_common::console::print_err(&format!("vlsync-echo: error: {e}\n"));
                return ExitCode::from(1);
            }
        };
        for l in lines {
            // a reader that went away (`| head`) ends the run; a full stdout is an error
            match writeln!(out, "{l}").and_then(|()| out.flush()) {
                Ok(()) => {}
                Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => return ExitCode::SUCCESS,
                Err(e) => {
                    vlsync_common::console::print_err(&format!(
                        "vlsync-echo: error: cannot write to stdout: {e}\n"
                    ));
                    return ExitCode::from(1);
                }
            }
            n += 1;
            if args.count > 0 && n >= args.count {
                return ExitCode::SUCCESS;
            }
        }
    }
    ExitCode::SUCCESS
}

fn main() -> ExitCode {
    let args = Args::parse();
    if !(args.duration.is_finite() && args.duration >= 0.0) {
        vlsync_common::console::print_err(
            "vlsync-echo: error: --duration must be a finite number >= 0\n",
        );
        return ExitCode::from(2);
    }
    // a bad prefix is a bad argument (exit 2, as clap's), found before anything opens
    if let Err(e) = vlsync_ipc::ServiceNames::new(&args.prefix) {
        vlsync_common::console::print_err(&format!("vlsync-echo: error: {e}\n"));
        return ExitCode::from(2);
    }
    // a node that handles SIGINT/SIGTERM, so Ctrl-C ends the loop cleanly
    let _signals = match vlsync_ipc::create_node("vlsync-echo", true) {
        Ok(n) => n,
        Err(e) => {
            vlsync_common::console::print_err(&format!("vlsync-echo: error: {e}\n"));
            return ExitCode::from(1);
        }
    };
    let json = args.json;
    if args.status {
        // statuses are polled every 100 ms (the daemon publishes one every
        // `daemon.status_period_s`); an invalid payload is reported and skipped
        let mut client = match vlsync_ipc::StatusClient::open(&args.prefix) {
            Ok(c) => c,
            Err(e) => {
                vlsync_common::console::print_err(&format!("vlsync-echo: error: {e}\n"));
                return ExitCode::from(1);
            }
        };
        return print_until_done(&args, || {
            let lines = match client.receive_all() {
                Ok(all) => all.iter().map(|s| status_line(s, json)).collect(),
                Err(vlsync_ipc::WireErrorOrIpc::Wire(e)) => {
                    vlsync_common::console::print_err(&format!(
                        "vlsync-echo: skipped an invalid status: {e}\n"
                    ));
                    vec![]
                }
                Err(e) => return Err(e.to_string()),
            };
            std::thread::sleep(Duration::from_millis(100));
            Ok(lines)
        });
    }
    let mut client = match vlsync_ipc::OffsetClient::open(&args.prefix) {
        Ok(c) => c,
        Err(e) => {
            vlsync_common::console::print_err(&format!("vlsync-echo: error: {e}\n"));
            return ExitCode::from(1);
        }
    };
    let mut invalid = 0;
    let mut last_seq: Option<u64> = None;
    print_until_done(&args, || {
        // every estimate pending, in order (one line each, `--count` counts them); the
        // client buffers 16, and estimates a stopped or slow reader lost before it read
        // them are said on stderr from their sequence numbers
        let got = client.wait_all(Duration::from_millis(200));
        // a payload the client refused is not printed: said, as the status's are
        if client.invalid_count() > invalid {
            vlsync_common::console::print_err(&format!(
                "vlsync-echo: skipped {} invalid estimate payload(s) on `{}/offset` ({} in all)\n",
                client.invalid_count() - invalid,
                args.prefix,
                client.invalid_count()
            ));
            invalid = client.invalid_count();
        }
        let got = got.map_err(|e| e.to_string())?;
        for (e, _) in &got {
            if let Some(n) = last_seq.and_then(|l| missed(l, e.seq)) {
                vlsync_common::console::print_err(&format!(
                    "vlsync-echo: {n} estimate(s) missed before #{} (lost by a stopped or \
                     slow reader, the client buffering 16, or never published: the daemon's \
                     log says so)\n",
                    e.seq
                ));
            }
            last_seq = Some(e.seq);
        }
        Ok(got.iter().map(|(e, _)| line(e, json)).collect())
    })
}

/// Estimates missed between sequence numbers `last` and `seq` (`None` when none
/// were, or the numbering restarted: a new daemon).
fn missed(last: u64, seq: u64) -> Option<u64> {
    seq.checked_sub(last)
        .and_then(|d| d.checked_sub(1))
        .filter(|&n| n > 0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use vlsync_common::{EstimatorState, Polarity};

    #[test]
    fn json_lines_write_null_for_non_finite_numbers() {
        let e = Estimate {
            seq: 3,
            t_ref_ns: 5_000_000_000,
            offset_s: 0.025,
            drift: f64::INFINITY,
            offset_std_s: 0.001,
            drift_std: 1e-6,
            state: EstimatorState::Holding,
            polarity: Polarity::Negative,
            peak_score: 0.0,
            peak_ratio: f64::NEG_INFINITY,
            measured_offset_s: f64::NAN,
        };
        let text = line(&e, true);
        assert!(text.contains("\"measured_offset_s\":null"), "{text}");
        let v: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert!(v["measured_offset_s"].is_null() && v["drift"].is_null());
        assert!(v["peak_ratio"].is_null());
        assert_eq!(v["offset_s"].as_f64(), Some(0.025));
        assert_eq!(v["state"], "holding");
    }

    #[test]
    fn missed_estimates_are_counted_from_their_numbers() {
        assert_eq!(missed(4, 5), None);
        assert_eq!(missed(4, 9), Some(4));
        // a daemon that restarted numbers from the start again
        assert_eq!(missed(40, 0), None);
        assert_eq!(missed(40, 40), None);
        assert_eq!(missed(0, u64::MAX), Some(u64::MAX - 1));
    }

    #[test]
    fn the_quiet_notice_names_the_service_and_the_prefix_key() {
        let a = Args::try_parse_from(["vlsync-echo", "--prefix", "bot/x"]).unwrap();
        let n = quiet_notice(&a);
        assert!(
            n.contains("`bot/x/offset`") && n.contains("services.prefix = \"bot/x\""),
            "{n}"
        );
        let a = Args::try_parse_from(["vlsync-echo", "--status"]).unwrap();
        assert!(quiet_notice(&a).contains("`vlsync/robot/status`"));
    }
}
