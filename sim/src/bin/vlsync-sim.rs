//! `vlsync-sim`: writes a simulated run (cam.csv, lidar.csv, truth.csv) and prints its summary.
#![forbid(unsafe_code)]

use clap::Parser;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;
use vlsync_sim::{baseline, crb, families, io, score, Family};

/// Simulated camera/LiDAR signature streams with known truth.
#[derive(Debug, Parser)]
#[command(name = "vlsync-sim", version)]
struct Args {
    /// List the families with a one-line description and exit.
    #[arg(long)]
    list: bool,
    /// Family name (see --list), e.g. robot, rates-60x5.
    #[arg(long, required_unless_present = "list")]
    family: Option<String>,
    /// Random seed.
    #[arg(long, allow_negative_numbers = true, default_value_t = 0)]
    seed: u64,
    /// Duration in seconds, 2 to 3600 (default: 12 for seed, 120 otherwise).
    #[arg(long, allow_negative_numbers = true)]
    duration: Option<f64>,
    /// Multiplier of the family's signature noise, 0 to 1000 (0: noiseless values;
    /// jitter, drops and gaps unchanged). Useful to tell estimator bias from noise.
    #[arg(long, allow_negative_numbers = true, default_value_t = 1.0)]
    noise_scale: f64,
    /// Output directory (created if missing). An earlier vlsync-sim run there is
    /// replaced; any other cam.csv, lidar.csv or truth.csv (a recording) is refused.
    #[arg(long, required_unless_present = "list")]
    out: Option<PathBuf>,
    /// Overwrite cam.csv, lidar.csv and truth.csv in --out even when they are not
    /// an earlier vlsync-sim run.
    #[arg(long)]
    force: bool,
}

fn main() -> ExitCode {
    let args = Args::parse();
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            vlsync_common::console::print_err(&format!("vlsync-sim: error: {e}\n"));
            ExitCode::FAILURE
        }
    }
}

/// The header vlsync-sim writes in each of its files.
const OWN_FILES: [(&str, &str); 3] = [
    ("cam.csv", "t,value"),
    ("lidar.csv", "t,value"),
    ("truth.csv", "t,offset"),
];

/// Refuses a directory whose cam.csv, lidar.csv or truth.csv is not an earlier
/// vlsync-sim run: a `vlsyncd record` recording (its files carry a `publish` column
/// and no truth), or a user's own streams without the truth beside them. A run of
/// this tool is replaced: every one of its files present has the header it writes,
/// and the truth is there.
fn refuse_foreign_files(out: &std::path::Path) -> Result<(), String> {
    let present: Vec<_> = OWN_FILES
        .iter()
        .filter(|(name, _)| out.join(name).symlink_metadata().is_ok())
        .collect();
    if present.is_empty() {
        return Ok(());
    }
    let refuse = |name: &str, why: String| {
        Err(format!(
            "{} exists and {why}: refusing to overwrite it (--force overwrites it)",
            out.join(name).display()
        ))
    };
    for (name, header) in &present {
        match first_line(&out.join(name)) {
            Some(line) if line == *header => {}
            Some(line) => {
                let shown: String = line.chars().take(60).collect();
                return refuse(
                    name,
                    format!("is not a vlsync-sim file (its header `{shown}`, not `{header}`)"),
                );
            }
            None => return refuse(name, "is not a vlsync-sim file (no header line)".into()),
        }
    }
    if !present.iter().any(|(name, _)| *name == "truth.csv") {
        return refuse(
            present[0].0,
            "has no truth.csv beside it: not a vlsync-sim run".into(),
        );
    }
    Ok(())
}

/// The first line of a regular file, without its line end (at most 4 KiB read).
fn first_line(path: &std::path::Path) -> Option<String> {
    use std::io::Read;
    let mut buf = Vec::with_capacity(4096);
    vlsync_common::file::open_regular(path)
        .ok()?
        .take(4096)
        .read_to_end(&mut buf)
        .ok()?;
    let end = buf.iter().position(|&b| b == b'\n')?;
    let line = String::from_utf8_lossy(&buf[..end]);
    let line = line.trim_end_matches('\r');
    Some(line.trim_start_matches('\u{feff}').to_string())
}

fn run(args: &Args) -> Result<(), String> {
    // printed at the end, after the files are written: a closed or full stdout
    // must not panic (`vlsync-sim --list | head -1`)
    let mut text = String::new();
    if args.list {
        for f in Family::ALL {
            let _ = writeln!(text, "{:<16} {}", f.name(), f.description());
        }
        return vlsync_common::console::print_out(&text);
    }
    let (Some(name), Some(out)) = (&args.family, &args.out) else {
        return Err("--family and --out are required (or --list)".into());
    };
    let family: Family = name
        .parse()
        .map_err(|e: families::UnknownFamily| e.to_string())?;
    let run = families::try_generate_with(family, args.seed, args.duration, args.noise_scale)
        .map_err(|e| e.to_string())?;
    vlsync_common::file::create_out_dir("--out", out)?;
    // each file checked before any is written, then written whole (a temporary file
    // renamed into place): a run is not left half new, half old or cut mid-row
    let files = [
        ("cam.csv", io::signature_csv_string(&run.cam)),
        ("lidar.csv", io::signature_csv_string(&run.lidar)),
        ("truth.csv", io::truth_csv_string(&run.truth, 10_000_000)),
    ];
    if !args.force {
        refuse_foreign_files(out)?;
    }
    for (name, _) in &files {
        vlsync_common::file::check_writable("--out", &out.join(name))?;
    }
    for (i, (name, text)) in files.iter().enumerate() {
        vlsync_common::file::write_atomically(&out.join(name), text.as_bytes()).map_err(|e| {
            let done: Vec<&str> = files[..i].iter().map(|f| f.0).collect();
            if done.is_empty() {
                e
            } else {
                format!(
                    "{e} ({} written before it: the run in {} is incomplete)",
                    done.join(", "),
                    out.display()
                )
            }
        })?;
    }
    let base = score::score_pairs(
        &baseline::seed_chunked(&run.cam, &run.lidar, run.cam_hz),
        &run,
    );
    let win = |w: f64| match crb::crb_window_std_s(&run, w) {
        Ok(v) => format!("{:.2} ms", v * 1e3),
        Err(_) => "n/a".into(),
    };
    let end = vlsync_common::secs_to_nanos(run.duration_s);
    let _ = writeln!(
        text,
        "family {} seed {} duration {:.1} s -> {}",
        family,
        run.seed,
        run.duration_s,
        out.display()
    );
    let _ = writeln!(text, "  {}", family.description());
    let _ = writeln!(
        text,
        "  cam {} samples @ {} Hz ({} dropped), lidar {} samples @ {} Hz ({} dropped, gaps {})",
        run.cam.len(),
        run.cam_hz,
        run.cam_dropped,
        run.lidar.len(),
        run.lidar_hz,
        run.lidar_dropped,
        run.lidar_gaps.len()
    );
    let _ = writeln!(
        text,
        "  truth offset {:+.2} ms at t=0 .. {:+.2} ms at end, drift {:+.1} ppm, {} steps, polarity {}",
        run.truth.offset_at(0) * 1e3,
        run.truth.offset_at(end) * 1e3,
        run.truth.drift * 1e6,
        run.step_times_ns.len(),
        run.polarity
    );
    let _ = writeln!(
        text,
        "  noise cam {:.4} lidar {:.4}; jitter cam {:.1} ms lidar {:.1} ms; motion starts {:.2} s; {} standstill(s)",
        run.noise_cam,
        run.noise_lidar,
        run.jitter_cam_s * 1e3,
        run.jitter_lidar_s * 1e3,
        vlsync_common::nanos_to_secs(run.motion_start_ns),
        run.standstills.len()
    );
    let _ = writeln!(
        text,
        "  Cramér-Rao bound: {:.3} ms whole run; median per window {} (4 s), {} (6 s)",
        run.crb_std_s * 1e3,
        win(4.0),
        win(6.0)
    );
    let _ = writeln!(text, "  seed baseline (bugs fixed): {base}");
    // files an earlier run left beside the new one (a replay's est.csv, a plot)
    let mut stale: Vec<String> = std::fs::read_dir(out)
        .map(|d| {
            d.flatten()
                .filter(|e| e.file_type().is_ok_and(|t| t.is_file()))
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| !files.iter().any(|f| f.0 == n) && !n.starts_with('.'))
                .collect()
        })
        .unwrap_or_default();
    stale.sort();
    if !stale.is_empty() {
        let _ = writeln!(
            text,
            "  note: {} also holds {} from before: not of this run",
            out.display(),
            stale.join(", ")
        );
    }
    vlsync_common::console::print_out(&text)
}
