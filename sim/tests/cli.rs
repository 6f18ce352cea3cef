//! End-to-end checks of the `vlsync-sim` binary.

use std::path::PathBuf;
use std::process::Command;
use vlsync_sim::{generate, io, Family};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_vlsync-sim"))
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("vlsync-sim-cli-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

#[test]
fn list_names_every_family() {
    let out = bin().arg("--list").output().unwrap();
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    assert_eq!(text.lines().count(), Family::ALL.len());
    for f in Family::ALL {
        assert!(text.contains(f.name()), "{f} missing from --list");
    }
}

#[test]
fn a_full_or_closed_stdout_is_no_panic() {
    // a full disk: an error naming stdout, exit 1 (a panic would be 101)
    let full = std::fs::OpenOptions::new().write(true).open("/dev/full");
    if let Ok(full) = full {
        let out = bin().arg("--list").stdout(full).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{err}");
        assert!(
            err.contains("cannot write to stdout") && !err.contains("panicked"),
            "{err}"
        );
    }
    // a reader that has gone (`| head -0`): quietly done, exit 0
    let mut child = bin()
        .arg("--list")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success() && !err.contains("panicked"),
        "{:?}: {err}",
        out.status
    );
}

#[test]
fn writes_the_generated_run() {
    let dir = tmp("write");
    let out = bin()
        .args([
            "--family",
            "clocks",
            "--seed",
            "3",
            "--duration",
            "20",
            "--out",
        ])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("Cramér-Rao bound"), "{text}");
    let run = generate(Family::Clocks, 3, Some(20.0));
    let (cam, _) = io::read_signature_csv(dir.join("cam.csv")).unwrap();
    let (lidar, _) = io::read_signature_csv(dir.join("lidar.csv")).unwrap();
    assert_eq!(cam, run.cam);
    assert_eq!(lidar, run.lidar);
    let truth = io::read_truth_csv(dir.join("truth.csv")).unwrap();
    assert_eq!(truth.len(), 2001);
    assert!(truth
        .iter()
        .all(|&(t, o)| (o - run.truth.offset_at(t)).abs() < 1e-9));
    assert!(!text.contains("note:"), "{text}");
    // a second run into the directory: what an earlier replay left there is named
    std::fs::write(dir.join("est.csv"), "t,offset\n").unwrap();
    let out = bin()
        .args(["--family", "robot", "--duration", "10", "--out"])
        .arg(&dir)
        .output()
        .unwrap();
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(
        text.contains(&format!(
            "note: {} also holds est.csv from before: not of this run",
            dir.display()
        )),
        "{text}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn errors_are_clear() {
    let dir = tmp("err");
    let out = bin()
        .args(["--family", "warp", "--out"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(
        err.contains("unknown family `warp`") && err.contains("rates-60x5"),
        "{err}"
    );

    // a file where a directory should be
    std::fs::create_dir_all(&dir).unwrap();
    let blocker = dir.join("file");
    std::fs::write(&blocker, "x").unwrap();
    let target = blocker.join("sub");
    let out = bin()
        .args(["--family", "robot", "--out"])
        .arg(&target)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(err.contains(&target.display().to_string()), "{err}");

    let out = bin()
        .args(["--family", "robot", "--duration", "-4", "--out"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8(out.stderr)
        .unwrap()
        .contains("duration -4"));

    // a noise scale past the bound: no run of infinite values, the value and the
    // range named (before anything is written)
    for bad in ["1e308", "-0.5", "NaN"] {
        let out = bin()
            .args(["--family", "robot", "--noise-scale", bad, "--out"])
            .arg(dir.join("noise"))
            .output()
            .unwrap();
        let err = String::from_utf8(out.stderr).unwrap();
        assert_eq!(out.status.code(), Some(1), "{bad}: {err}");
        assert!(
            err.contains(&format!("noise scale {bad} is invalid"))
                && err.contains("[0, 1000]")
                && !err.contains("panicked"),
            "{err}"
        );
        assert!(!dir.join("noise").exists(), "{bad}: files written");
    }
    let help = String::from_utf8(bin().arg("--help").output().unwrap().stdout).unwrap();
    assert!(help.contains("0 to 1000"), "{help}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_recording_in_the_out_directory_is_not_overwritten() {
    let dir = tmp("recording");
    std::fs::create_dir_all(&dir).unwrap();
    // what `vlsyncd record` leaves: stamps with their publish times, no truth
    let recorded = "t,value,publish\n1.0,0.5,1.001\n";
    std::fs::write(dir.join("cam.csv"), recorded).unwrap();
    std::fs::write(dir.join("lidar.csv"), recorded).unwrap();
    std::fs::write(dir.join("est.csv"), "t,offset\n").unwrap();
    let run = |force: bool| {
        let mut c = bin();
        c.args(["--family", "robot", "--duration", "10", "--out"])
            .arg(&dir);
        if force {
            c.arg("--force");
        }
        c.output().unwrap()
    };
    let out = run(false);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains(&format!("{} exists", dir.join("cam.csv").display()))
            && err.contains("`t,value,publish`")
            && err.contains("--force"),
        "{err}"
    );
    assert_eq!(
        std::fs::read_to_string(dir.join("cam.csv")).unwrap(),
        recorded
    );
    assert!(!dir.join("truth.csv").exists());

    // a user's own streams with the sim's header but no truth beside them
    std::fs::write(dir.join("cam.csv"), "t,value\n1.0,0.5\n").unwrap();
    std::fs::write(dir.join("lidar.csv"), "t,value\n1.0,0.5\n").unwrap();
    let out = run(false);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("without truth.csv beside it"), "{err}");
    assert_eq!(
        std::fs::read_to_string(dir.join("lidar.csv")).unwrap(),
        "t,value\n1.0,0.5\n"
    );

    // --force writes the run
    let out = run(true);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let (cam, _) = io::read_signature_csv(dir.join("cam.csv")).unwrap();
    assert_eq!(cam, generate(Family::Robot, 0, Some(10.0)).cam);
    // and the run it wrote is replaced again without --force
    assert!(run(false).status.success());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A `vlsync-render --out` directory (its truth.csv headed as ours) is refused before
/// anything is written: its truth was overwritten, and only then its other files named
/// in a note.
#[test]
fn a_rendered_run_in_the_out_directory_is_not_overwritten() {
    let dir = tmp("rendered");
    std::fs::create_dir_all(&dir).unwrap();
    let truth = "t,offset\n0.000000000,0.123\n";
    let files = [
        ("frames.csv", "t,file\n"),
        ("scans.csv", "t,angle,range\n"),
        ("truth.csv", truth),
        ("motion.csv", "t,x,y,yaw,speed,yaw_rate\n"),
    ];
    for (f, text) in files {
        std::fs::write(dir.join(f), text).unwrap();
    }
    let out = bin()
        .args(["--family", "robot", "--duration", "10", "--out"])
        .arg(&dir)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains(&format!(
            "{} holds frames.csv, motion.csv, scans.csv, truth.csv: a vlsync-render run",
            dir.display()
        )) && err.contains("choose another --out")
            && err.contains("--force"),
        "{err}"
    );
    assert!(
        out.stdout.is_empty(),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );
    assert_eq!(
        std::fs::read_to_string(dir.join("truth.csv")).unwrap(),
        truth
    );
    assert!(!dir.join("cam.csv").exists() && !dir.join("lidar.csv").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}
