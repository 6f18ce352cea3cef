//! `vlsync-render`'s command line as a user meets it: usage errors that name the
//! flags, refused before anything is written, and honest summaries.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn render_bin(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_vlsync-render"))
        .args(args)
        .output()
        .expect("run vlsync-render")
}

fn temp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("vlsync-render-cli-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// A usage error: status 2, nothing on stdout, stderr containing every one of `words`.
fn refused(args: &[&str], words: &[&str]) -> String {
    let out = render_bin(args);
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
    assert!(out.stdout.is_empty(), "{args:?}: wrote to stdout");
    for w in words {
        assert!(err.contains(w), "{args:?}: `{w}` not in: {err}");
    }
    assert!(!err.contains("panicked"), "{err}");
    err
}

const SMALL: [&str; 6] = ["--duration", "1", "--width", "16", "--height", "16"];

#[test]
fn raw_stdout_refuses_the_flags_it_would_ignore() {
    for extra in [
        &["--mcap"][..],
        &["--mcap", "/tmp/vlsync-render-never.mcap", "--mcap-png"],
        &["--no-png"],
        &["--offset", "0.1"],
        &["--drift-ppm", "-3"],
        &["--step", "0.5:0.01"],
        &["--drop", "0"],
        &["--rays", "100"],
    ] {
        let args = [&["--raw-stdout", "gray"][..], &SMALL, extra].concat();
        refused(&args, &["--raw-stdout", extra[0], "cannot be used with"]);
    }
    assert!(!Path::new("/tmp/vlsync-render-never.mcap").exists());
}

#[test]
fn start_at_without_raw_stdout_is_refused_naming_both() {
    let dir = temp_dir("start-at");
    let d = dir.to_str().unwrap();
    for args in [&["--out", d, "--start-at", "5"][..], &["--start-at", "5"]] {
        let err = refused(
            &[args, &SMALL].concat(),
            &["--start-at needs --raw-stdout LAYOUT"],
        );
        // not clap's list of "required" arguments that cannot both be given
        assert!(!err.contains("required"), "{err}");
    }
    assert!(!dir.exists(), "files written");
    refused(&SMALL, &["give --out DIR", "--raw-stdout LAYOUT"]);
}

#[test]
fn configuration_errors_name_the_flags() {
    let dir = temp_dir("flags");
    let d = dir.to_str().unwrap();
    let err = refused(
        &["--out", d, "--fps", "200"],
        &["--fps 200: ", "8 ms exposure", "--fps < 125"],
    );
    assert!(
        !err.contains("camera.") && !err.contains("render config"),
        "{err}"
    );
    refused(
        &["--out", d, "--rays", "3"],
        &["--rays: 3 is outside 8..=100000"],
    );
    refused(&["--out", d, "--drift-ppm", "2000"], &["--drift-ppm: "]);
    refused(&["--out", d, "--drop", "0.5"], &["--drop: "]);
    refused(&["--out", d, "--duration", "0.5"], &["--duration: "]);
    refused(
        &["--out", d, "--duration", "5", "--step", "6:0.01"],
        &["--step (TIME_S): ", "--duration"],
    );
    // an empty schedule: no scan in the run
    refused(
        &[
            "--out",
            d,
            "--duration",
            "1",
            "--fps",
            "1",
            "--lidar-hz",
            "0.5",
        ],
        &[
            "--duration 1",
            "--lidar-hz 0.5",
            "no whole LiDAR revolution",
        ],
    );
    assert!(!dir.exists(), "files written");
}

#[test]
fn an_mcap_file_among_the_runs_own_files_is_refused() {
    let dir = temp_dir("mcap-own");
    let d = dir.to_str().unwrap();
    let run = [&["--out", d][..], &SMALL].concat();
    let out = render_bin(&run);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let before = std::fs::read(dir.join("frames.csv")).unwrap();
    for own in ["frames.csv", "scans.csv", "truth.csv", "motion.csv"] {
        let file = dir.join("frames").join("..").join(own);
        let f = file.to_str().unwrap();
        refused(
            &[&run[..], &["--mcap", f]].concat(),
            &[
                &format!("--mcap {f} names {own} of --out {d}"),
                "overwritten",
            ],
        );
    }
    assert_eq!(std::fs::read(dir.join("frames.csv")).unwrap(), before);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn no_png_writes_no_frame_list_and_says_so() {
    let dir = temp_dir("no-png");
    let d = dir.to_str().unwrap();
    // an earlier run with PNGs, then one without: no frames.csv is left pointing anywhere
    let out = render_bin(&[&["--out", d][..], &SMALL].concat());
    assert!(out.status.success());
    let out = render_bin(&[&["--out", d, "--no-png"][..], &SMALL].concat());
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains(" frames rendered, no PNGs or frames.csv (--no-png)")
            && !stdout.contains("frames written"),
        "{stdout}"
    );
    assert!(!dir.join("frames.csv").exists());
    for f in ["scans.csv", "truth.csv", "motion.csv"] {
        assert!(dir.join(f).exists(), "{f}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn an_mcap_file_that_cannot_be_written_is_refused_before_the_run() {
    let dir = temp_dir("mcap-dir");
    let d = dir.to_str().unwrap();
    let missing = dir.join("no-such-dir").join("x.mcap");
    refused(
        &[
            &["--out", d, "--mcap", missing.to_str().unwrap()][..],
            &SMALL,
        ]
        .concat(),
        &["--mcap ", "x.mcap", "does not exist"],
    );
    // nothing was made: not the run's directory, not its frames
    assert!(!dir.exists(), "{}", dir.display());
    // a FILE in a directory the run makes: --out however spelt, its frames/ (PNGs
    // on), an ancestor of a new --out
    for (out, file) in [
        (dir.clone(), dir.join(".").join("dot.mcap")),
        (dir.clone(), dir.join("frames").join("in-frames.mcap")),
        (
            dir.join("runs").join("seed3"),
            dir.join("runs").join("seed3.mcap"),
        ),
    ] {
        let args = [
            &[
                "--out",
                out.to_str().unwrap(),
                "--mcap",
                file.to_str().unwrap(),
            ][..],
            &SMALL,
        ]
        .concat();
        let run = render_bin(&args);
        assert!(
            run.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&run.stderr)
        );
        assert!(file.is_file(), "{}", file.display());
        let _ = std::fs::remove_dir_all(&dir);
    }
    // an ancestor of --out that exists is not one the run makes: a FILE there is
    // checked before the run (here a regular file stands where its directory would
    // be: it was taken for a directory the run makes, and the run failed after its
    // setup, with status 1)
    std::fs::create_dir_all(&dir).unwrap();
    let file_dir = dir.join("a-file");
    std::fs::write(&file_dir, b"").unwrap();
    let out = file_dir.join("runs").join("seed3");
    let file = file_dir.join("seed3.mcap");
    refused(
        &[
            &[
                "--out",
                out.to_str().unwrap(),
                "--mcap",
                file.to_str().unwrap(),
            ][..],
            &SMALL,
        ]
        .concat(),
        &["--mcap ", "seed3.mcap", "a-file"],
    );
    let _ = std::fs::remove_dir_all(&dir);
    // a FILE in --out's own directory is made with it
    let inside = dir.join("inside.mcap");
    let out = render_bin(
        &[
            &["--out", d, "--mcap", inside.to_str().unwrap(), "--no-png"][..],
            &SMALL,
        ]
        .concat(),
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(inside.is_file());
    let _ = std::fs::remove_dir_all(&dir);
}
