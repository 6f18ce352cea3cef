//! `vlsync-echo` describes itself and refuses a bad command line (exit code 2)
//! naming what was wrong. (This file also makes `cargo test` build it, which
//! the multi-process tests in `tests/` then run.)

use std::process::Command;

#[test]
fn echo_has_help_and_rejects_an_unknown_argument() {
    let bin = env!("CARGO_BIN_EXE_vlsync-echo");
    let out = Command::new(bin).arg("--help").output().unwrap();
    assert!(out.status.success());
    let help = String::from_utf8_lossy(&out.stdout);
    assert!(
        help.contains("--prefix") && help.contains("--json") && help.contains("--status"),
        "{help}"
    );
    let out = Command::new(bin).arg("--bogus").output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--bogus"));
}
