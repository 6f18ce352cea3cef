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
    /// replaced; another run is refused: a vlsync-render run (frames.csv, scans.csv,
    /// motion.csv), a recording's cam.csv/lidar.csv, an est.csv without a vlsync-sim
    /// run beside it, any cam.csv, lidar.csv or truth.csv without the other two.
    #[arg(long, required_unless_present = "list")]
    out: Option<PathBuf>,
    /// Write cam.csv, lidar.csv and truth.csv in --out (overwriting them) even when
    /// the directory holds another run than an earlier vlsync-sim one.
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

/// The files of a `vlsync-render` run beside its own truth.csv (headed as ours is, so
/// only these tell the two apart; its `RUN_FILES`).
const RENDER_FILES: [&str; 3] = ["frames.csv", "scans.csv", "motion.csv"];
/// The estimates `vlsyncd record` writes beside its recording (and a replay's usual
/// `--out`): without a run of this tool beside it, another run's, whose truth a new
/// truth.csv would be taken for.
const ESTIMATES_FILE: &str = "est.csv";

/// What `--force` does, said with every refusal.
const HOW_TO_PROCEED: &str = "refusing to write the run there: choose another --out, \
    or add --force to overwrite cam.csv, lidar.csv and truth.csv there";

/// Refuses a directory that holds another run than an earlier vlsync-sim one: an
/// earlier run of this tool (cam.csv and lidar.csv headed `t,value` beside a truth.csv
/// headed `t,offset`, all three) is replaced; other files beside it (a replay's est.csv
/// of it, a plot) are named after the new run is written. Refused, before anything is
/// written (so the note never follows an overwrite of another run's file):
/// * a `vlsync-render` run (frames.csv, scans.csv or motion.csv): its truth.csv has
///   the same header as ours, and would be replaced, or ours taken for its truth;
/// * a cam.csv, lidar.csv or truth.csv with another header: a `vlsyncd record`
///   recording (a `publish` column), an estimates file, a user's own streams;
/// * some of the three files without the others (a user's streams without a truth,
///   a truth without streams): not a run of this tool;
/// * an est.csv without a run of this tool beside it: estimates of another run,
///   which a truth.csv written beside them would pass for the truth of.
fn refuse_foreign_files(out: &std::path::Path) -> Result<(), String> {
    let exists = |name: &str| out.join(name).symlink_metadata().is_ok();
    let present: Vec<&(&str, &str)> = OWN_FILES.iter().filter(|(n, _)| exists(n)).collect();
    let render: Vec<&str> = RENDER_FILES.iter().copied().filter(|n| exists(n)).collect();
    let found = || {
        let mut names: Vec<&str> = present
            .iter()
            .map(|(n, _)| *n)
            .chain(render.iter().copied())
            .collect();
        if exists(ESTIMATES_FILE) {
            names.push(ESTIMATES_FILE);
        }
        names.sort_unstable();
        names.join(", ")
    };
    if !render.is_empty() {
        return Err(format!(
            "{} holds {}: a vlsync-render run, not an earlier vlsync-sim one (its truth.csv \
             would be replaced, or this run's taken for its truth); {HOW_TO_PROCEED}",
            out.display(),
            found()
        ));
    }
    for (name, header) in &present {
        let why = match first_line(&out.join(name)) {
            Some(line) if line == *header => continue,
            Some(line) => {
                let shown: String = line.chars().take(60).collect();
                format!("its header `{shown}`, not `{header}`")
            }
            None => "no header line".into(),
        };
        return Err(format!(
            "{} exists and is not a vlsync-sim file ({why}); {HOW_TO_PROCEED}",
            out.join(name).display()
        ));
    }
    if !present.is_empty() && present.len() < OWN_FILES.len() {
        let missing: Vec<&str> = OWN_FILES
            .iter()
            .map(|(n, _)| *n)
            .filter(|n| !exists(n))
            .collect();
        return Err(format!(
            "{} holds {} without {} beside it: not an earlier vlsync-sim run (which writes \
             all three); {HOW_TO_PROCEED}",
            out.display(),
            found(),
            missing.join(" or ")
        ));
    }
    if present.is_empty() && exists(ESTIMATES_FILE) {
        return Err(format!(
            "{} holds {}: estimates of another run (`vlsyncd record`'s, or a replay's) \
             without an earlier vlsync-sim run beside them; a truth.csv written there would \
             pass for theirs; {HOW_TO_PROCEED}",
            out.display(),
            found()
        ));
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

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::{Path, PathBuf};

    /// A fresh directory holding `files` (name, contents).
    fn dir_with(name: &str, files: &[(&str, &str)]) -> PathBuf {
        let d =
            std::env::temp_dir().join(format!("vlsync-sim-refuse-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        for (f, text) in files {
            std::fs::write(d.join(f), text).unwrap();
        }
        d
    }

    fn refused(d: &Path) -> String {
        let e = refuse_foreign_files(d).expect_err("refused");
        assert!(
            e.contains("choose another --out") && e.contains("--force"),
            "how to proceed: {e}"
        );
        e
    }

    const SIM: [(&str, &str); 3] = [
        ("cam.csv", "t,value\n0.0,1\n"),
        ("lidar.csv", "t,value\n0.0,1\n"),
        ("truth.csv", "t,offset\n0.0,0.1\n"),
    ];

    /// A `vlsync-render --out` directory has a truth.csv headed as ours: it was taken
    /// for an earlier run of this tool and its truth overwritten.
    #[test]
    fn a_render_run_is_not_taken_for_an_earlier_sim_run() {
        let render = [
            ("frames.csv", "t_cam,file\n"),
            ("scans.csv", "t,angle,range\n"),
            ("truth.csv", "t,offset\n0.0,0.1\n"),
            ("motion.csv", "t,x,y\n"),
        ];
        let d = dir_with("render", &render);
        let e = refused(&d);
        assert!(
            e.contains("holds frames.csv, motion.csv, scans.csv, truth.csv: a vlsync-render run"),
            "{e}"
        );
        // a render run written over an earlier sim run: its cam.csv and lidar.csv stay
        for (f, text) in &SIM[..2] {
            std::fs::write(d.join(f), text).unwrap();
        }
        assert!(refused(&d).contains("vlsync-render run"));
        // any one of render's own files tells
        let d2 = dir_with("render-one", &[SIM[0], SIM[1], SIM[2], ("motion.csv", "")]);
        assert!(refused(&d2).contains("holds cam.csv, lidar.csv, motion.csv, truth.csv"));
        for d in [d, d2] {
            std::fs::remove_dir_all(d).unwrap();
        }
    }

    /// An earlier run of this tool is its three files together; one or two of them,
    /// or another run's estimates alone, are not.
    #[test]
    fn an_earlier_sim_run_is_all_three_files() {
        // (directory, its files, what the refusal says or None: accepted)
        type Case = (
            &'static str,
            Vec<(&'static str, &'static str)>,
            Option<&'static str>,
        );
        let cases: [Case; 5] = [
            (
                "truth",
                vec![SIM[2]],
                Some("holds truth.csv without cam.csv or lidar.csv"),
            ),
            (
                "cam-truth",
                vec![SIM[0], SIM[2]],
                Some("holds cam.csv, truth.csv without lidar.csv"),
            ),
            (
                "est",
                vec![("est.csv", "t,offset,drift\n")],
                Some("holds est.csv: estimates of another run"),
            ),
            ("nothing", vec![("notes.txt", "x")], None),
            // a replay's estimates beside an earlier run: replaced, the est.csv named
            (
                "sim-est",
                vec![SIM[0], SIM[1], SIM[2], ("est.csv", "t,offset\n")],
                None,
            ),
        ];
        for (name, files, want) in cases {
            let d = dir_with(name, &files);
            match want {
                Some(w) => assert!(refused(&d).contains(w), "{name}: {}", refused(&d)),
                None => assert_eq!(refuse_foreign_files(&d), Ok(()), "{name}"),
            }
            std::fs::remove_dir_all(d).unwrap();
        }
        let empty = dir_with("empty", &[]);
        assert_eq!(refuse_foreign_files(&empty), Ok(()));
        std::fs::remove_dir_all(empty).unwrap();
    }
}
