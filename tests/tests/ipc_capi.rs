//! C and C++ programs read the live daemon through `libvlsync_client.so`: the header's
//! layouts equal the Rust ones (compiled as C and as C++), `examples/c/vlsync_echo.c`
//! prints the estimates of a live run, which converge to the truth, and
//! `examples/cpp/vlsync_convert.cpp` puts camera stamps on the LiDAR clock. Bad
//! arguments and a silent prefix are clear errors with their exit codes.

use core::mem::{offset_of, size_of};
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::Duration;
use vlsync_client::{OffsetEstimate, Status, VlsyncConversion};
use vlsync_common::Stream;
use vlsync_tests::{capi_lib_dir, Piped, Rig};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// A scratch directory for this test's programs.
fn scratch(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("vlsync-capi-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Compiles `src` (C when `cxx` is false) against the header and the library into `exe`.
fn compile(src: &Path, exe: &Path, cxx: bool) {
    let lib = capi_lib_dir();
    let link = [
        "-L".to_string(),
        lib.display().to_string(),
        "-lvlsync_client".to_string(),
        format!("-Wl,-rpath,{}", lib.display()),
    ];
    vlsync_tests::compile(src, exe, cxx, &root().join("capi/include"), &link);
}

/// The C and C++ examples, built into `tmp`: (`vlsync_echo`, `vlsync_convert`).
fn build_examples(tmp: &Path) -> (PathBuf, PathBuf) {
    let (echo, convert) = (tmp.join("vlsync_echo"), tmp.join("vlsync_convert"));
    compile(&root().join("examples/c/vlsync_echo.c"), &echo, false);
    compile(
        &root().join("examples/cpp/vlsync_convert.cpp"),
        &convert,
        true,
    );
    (echo, convert)
}

/// A command running a program linked against the library: the loader searches
/// `LD_LIBRARY_PATH` before the program's run path, and cargo puts
/// `target/<profile>` on it, where an older `cargo build -p vlsync-capi` may have left
/// a stale copy; the library under test goes first.
fn linked(program: impl AsRef<std::ffi::OsStr>) -> Command {
    let mut path = std::ffi::OsString::from(capi_lib_dir());
    if let Some(old) = std::env::var_os("LD_LIBRARY_PATH") {
        path.push(":");
        path.push(old);
    }
    let mut c = Command::new(program);
    c.env("LD_LIBRARY_PATH", path);
    c
}

/// How long a test waits for an example run under `timeout 60`: its own limit ends
/// it first; this one is for a `timeout` that did not.
const RUN_LIMIT: Duration = Duration::from_secs(90);

/// `exe args` under `timeout 60` (which also ends it should this test process die),
/// with its stdout and stderr read beside it, and stopped when dropped: a test that
/// fails before it ends leaves no example running.
fn start(exe: &Path, args: &[&str], stdin: Stdio) -> Piped {
    Piped::spawn(linked("timeout").arg("60").arg(exe).args(args).stdin(stdin))
}

fn run(exe: &Path, args: &[&str], stdin: &str) -> Output {
    let mut p = start(exe, args, Stdio::piped());
    // a program that exits before reading all its input closes the pipe: what it said
    // and its exit code are the result, not the broken pipe
    if let Some(mut input) = p.child().stdin.take() {
        let _ = input.write_all(stdin.as_bytes());
    }
    p.output_within(RUN_LIMIT)
}

#[test]
fn the_headers_layouts_are_the_libraries_in_c_and_cpp() {
    let tmp = scratch("layout");
    let src = r#"#include <stdio.h>
#include "vlsync_client.h"
int main(void) {
  printf("%zu %zu %zu %zu %zu %zu %zu %zu\n", sizeof(vlsync_estimate), offsetof(vlsync_estimate, t_ref_ns),
         offsetof(vlsync_estimate, measured_offset_s), offsetof(vlsync_estimate, publish_ns),
         offsetof(vlsync_estimate, state), offsetof(vlsync_estimate, polarity),
         sizeof(vlsync_conversion), offsetof(vlsync_conversion, estimate));
  printf("%zu %zu %zu %zu %zu %zu %zu\n", sizeof(vlsync_daemon_status),
         offsetof(vlsync_daemon_status, rejected), offsetof(vlsync_daemon_status, lost),
         offsetof(vlsync_daemon_status, end_to_end_ns), offsetof(vlsync_daemon_status, latency_count),
         offsetof(vlsync_daemon_status, state), offsetof(vlsync_daemon_status, degraded));
  return vlsync_client_abi_version() == VLSYNC_CLIENT_ABI_VERSION ? 0 : 3;
}
"#;
    let want = format!(
        "{} {} {} {} {} {} {} {}\n{} {} {} {} {} {} {}\n",
        size_of::<OffsetEstimate>(),
        offset_of!(OffsetEstimate, t_ref_ns),
        offset_of!(OffsetEstimate, measured_offset_s),
        offset_of!(OffsetEstimate, publish_ns),
        offset_of!(OffsetEstimate, state),
        offset_of!(OffsetEstimate, polarity),
        size_of::<VlsyncConversion>(),
        offset_of!(VlsyncConversion, estimate),
        size_of::<Status>(),
        offset_of!(Status, rejected),
        offset_of!(Status, lost),
        offset_of!(Status, end_to_end_ns),
        offset_of!(Status, latency_count),
        offset_of!(Status, state),
        offset_of!(Status, degraded),
    );
    for (name, cxx) in [("layout.c", false), ("layout.cpp", true)] {
        let path = tmp.join(name);
        // the C++ build reads the header through the wrapper, as C++ programs do
        let text = if cxx {
            src.replace("vlsync_client.h", "vlsync_client.hpp")
                .replace("<stdio.h>", "<cstdio>\n#include <cstddef>")
        } else {
            src.to_string()
        };
        std::fs::write(&path, text).unwrap();
        let exe = tmp.join(name.replace('.', "_"));
        compile(&path, &exe, cxx);
        let out = linked(&exe).output().unwrap();
        assert_eq!(out.status.code(), Some(0), "{name}: ABI version differs");
        assert_eq!(String::from_utf8_lossy(&out.stdout), want, "{name}");
    }
    std::fs::remove_dir_all(&tmp).unwrap();
}

/// One line of `vlsync_echo`: (seq, state, t_ref s, offset ms, std ms).
fn echo_line(l: &str) -> (u64, String, f64, f64, f64) {
    let w: Vec<&str> = l.split_whitespace().collect();
    let num = |i: usize| -> f64 {
        w.get(i)
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("field {i} of {l:?}"))
    };
    assert_eq!(w.len(), 15, "{l}");
    assert_eq!(
        (w[0], w[3], w[6], w[9], w[12]),
        ("seq", "t_ref", "offset", "+-", "drift"),
        "{l}"
    );
    (num(1) as u64, w[2].to_string(), num(4), num(7), num(10))
}

#[test]
fn c_and_cpp_programs_read_a_live_daemon() {
    let tmp = scratch("live");
    let (echo, convert) = build_examples(&tmp);

    // 120 s of the run (24 s of wall time) are more than the test needs: the stale
    // converter below must lock on a fresh estimate first, on a loaded machine too,
    // and the drivers are stopped before the daemon, whenever the test gets there
    let rig = Rig::new("capi", "robot", 3, 120.0, 5.0);
    let mut daemon = rig.daemon(0);
    let mut cam = rig.driver(Stream::Cam, 0);
    let mut lidar = rig.driver(Stream::Lidar, 0);
    // 24 estimates: 12 s of the run at 0.5 s per hop, the lock within its first 6 s
    let out = run(
        &echo,
        &["--prefix", &rig.prefix, "--count", "24", "--timeout", "20"],
        "",
    );
    let text = String::from_utf8_lossy(&out.stdout).to_string();
    assert_eq!(
        out.status.code(),
        Some(0),
        "vlsync_echo: {text}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // the daemon's counters through the status API: two statuses, one per second
    let status = run(
        &echo,
        &[
            "--prefix",
            &rig.prefix,
            "--status",
            "--count",
            "2",
            "--timeout",
            "5",
        ],
        "",
    );
    let status_text = String::from_utf8_lossy(&status.stdout).to_string();
    assert_eq!(
        status.status.code(),
        Some(0),
        "vlsync_echo --status: {status_text}\n{}",
        String::from_utf8_lossy(&status.stderr)
    );
    // camera stamps two seconds apart, from the run's first frame on
    let t0 = rig.sim.cam[0].t_ns;
    let stamps_text = |t: i64| t.to_string();
    let stamps: Vec<i64> = (0..5).map(|i| t0 + i * 2_000_000_000).collect();
    let input: String = stamps.iter().map(|t| format!("{t}\n")).collect();
    let conv = run(
        &convert,
        &["--prefix", &rig.prefix, "--timeout", "20"],
        &input,
    );
    let conv_text = String::from_utf8_lossy(&conv.stdout).to_string();
    // a reader that goes away (`| head -1`) ends both with 0, their clients closed
    // (SIGPIPE killed them with 141, leaving their iceoryx2 nodes behind); an output
    // that cannot be written is an error (the C++ one ignored it and exited 0); and
    // the C++ one's --timeout 0 is no limit, as the C one's (it gave up at once)
    let piped = |script: &str| {
        vlsync_tests::output_within(
            Command::new("bash")
                .args(["-c", &format!("set -o pipefail; {script}"), "piped"])
                .arg(&echo)
                .arg(&convert)
                .arg(&rig.prefix)
                .arg(stamps_text(t0)),
            RUN_LIMIT,
        )
    };
    // (--status: the daemon publishes one a second, with or without drivers, so the
    // second line that meets the closed pipe comes whatever the run's timing)
    let c_head = piped(r#""$1" --prefix "$3" --status --timeout 20 | head -1"#);
    let many = tmp.join("stamps.txt");
    std::fs::write(&many, format!("{}\n", stamps_text(t0)).repeat(20_000)).unwrap();
    let cpp_head = piped(&format!(
        r#""$2" --prefix "$3" --timeout 0 < {} | head -1"#,
        many.display()
    ));
    let cpp_full = piped(r#"echo "$4" | "$2" --prefix "$3" --timeout 20 > /dev/full"#);
    // a stamp beyond 64 bits is refused by its line number, not wrapped to the limit
    let big = run(
        &convert,
        &["--prefix", &rig.prefix, "--timeout", "20"],
        &format!("{}\n99999999999999999999\n", stamps[0]),
    );
    // a converter that locked, then outlives the daemon: its next stamp is marked
    // stale, not converted as "tracking" by an estimate seconds old
    let stale_err = tmp.join("stale.err");
    let mut stale_conv = vlsync_tests::Managed {
        name: "vlsync_convert".into(),
        child: linked(&convert)
            .args(["--prefix", &rig.prefix, "--timeout", "20", "--max-age", "1"])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&stale_err).unwrap())
            .spawn()
            .unwrap(),
    };
    let mut stale_in = stale_conv.child.stdin.take().unwrap();
    let mut stale_rows = BufReader::new(stale_conv.child.stdout.take().unwrap()).lines();
    // (a converter that has ended says why on its stderr, in the assertions below)
    let _ = writeln!(stale_in, "{}", stamps[0]);
    let fresh_row = stale_rows.next().and_then(Result::ok).unwrap_or_default();
    assert!(
        cam.stop(std::time::Duration::from_secs(3)) & lidar.stop(std::time::Duration::from_secs(3))
    );
    assert!(daemon.stop(std::time::Duration::from_secs(3)));
    std::thread::sleep(std::time::Duration::from_millis(1500));
    let _ = writeln!(stale_in, "{}", stamps[1]);
    let stale_row = stale_rows.next().and_then(Result::ok).unwrap_or_default();
    drop(stale_in);
    let stale_status = stale_conv.child.wait().unwrap();
    let stale_said = std::fs::read_to_string(&stale_err).unwrap_or_default();
    assert!(
        fresh_row.ends_with(" tracking") || fresh_row.ends_with(" holding"),
        "{fresh_row}\n{stale_said}"
    );
    assert!(stale_row.ends_with(" stale"), "{stale_row}\n{stale_said}");
    assert!(
        stale_said.contains("s old (") && stale_said.contains("stamps are marked stale"),
        "{stale_said}"
    );
    assert_eq!(stale_status.code(), Some(0), "{stale_said}");

    for (what, out, code, says) in [
        ("vlsync_echo --status | head -1", &c_head, 0, "status "),
        ("vlsync_convert --timeout 0 | head -1", &cpp_head, 0, ""),
        ("vlsync_convert > /dev/full", &cpp_full, 2, ""),
    ] {
        let (stdout, stderr) = (
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr),
        );
        assert_eq!(out.status.code(), Some(code), "{what}: {stdout}\n{stderr}");
        assert!(stdout.starts_with(says), "{what}: {stdout}");
        if code == 0 {
            assert_eq!(stdout.lines().count(), 1, "{what}: {stdout}");
            assert!(stderr.is_empty(), "{what}: {stderr}");
        } else {
            assert!(
                stderr.contains("vlsync_convert: writing to stdout: No space left on device"),
                "{what}: {stderr}"
            );
        }
    }
    let lines: Vec<_> = text.lines().map(echo_line).collect();
    assert_eq!(lines.len(), 24, "{text}");
    // vlsync_client_wait_one hands out every estimate: no sequence number is skipped
    for w in lines.windows(2) {
        assert_eq!(w[1].0, w[0].0 + 1, "an estimate skipped:\n{text}");
    }
    let states = ["acquiring", "tracking", "holding", "lost"];
    let mut locked = 0;
    for (_, state, t_ref, offset_ms, std_ms) in &lines {
        assert!(states.contains(&state.as_str()), "{text}");
        assert!(std_ms.is_finite() && *std_ms >= 0.0, "{text}");
        if state == "tracking" || state == "holding" {
            locked += 1;
            let truth_ms = rig.sim.truth.offset_at((t_ref * 1e9) as i64) * 1e3;
            assert!(
                (offset_ms - truth_ms).abs() < 20.0,
                "C client: {offset_ms} ms against the truth {truth_ms} ms at {t_ref} s:\n{text}"
            );
        }
    }
    assert!(locked >= 6, "only {locked} locked estimates:\n{text}");

    assert_eq!(
        conv.status.code(),
        Some(0),
        "vlsync_convert: {conv_text}\n{}",
        String::from_utf8_lossy(&conv.stderr)
    );
    let statuses: Vec<Vec<&str>> = status_text
        .lines()
        .map(|l| l.split_whitespace().collect())
        .collect();
    assert_eq!(statuses.len(), 2, "{status_text}");
    let mut estimates = Vec::new();
    for w in &statuses {
        assert_eq!(w.len(), 20, "{status_text}");
        assert_eq!(
            (w[0], w[2], w[5], w[8], w[11], w[13], w[15], w[17], w[19]),
            (
                "status",
                "received",
                "rejected",
                "lost",
                "estimates",
                "overruns",
                "degraded",
                "p99",
                "us"
            ),
            "{status_text}"
        );
        assert!(
            ["tracking", "holding"].contains(&w[1]),
            "a lock by now: {status_text}"
        );
        let num = |i: usize| w[i].parse::<u64>().unwrap();
        // both streams flow, nothing rejected or lost on a clean run (a debug build
        // beside other work may overrun its budget: not judged here)
        assert!(w[16] == "0" || w[16] == "1", "{status_text}");
        assert!(w[18].parse::<f64>().unwrap() > 0.0, "{status_text}");
        assert!(num(3) > 100 && num(4) > 30, "{status_text}");
        assert_eq!(
            (num(6), num(7), num(9), num(10)),
            (0, 0, 0, 0),
            "{status_text}"
        );
        estimates.push(num(12));
    }
    assert!(estimates[1] > estimates[0], "{status_text}");
    let big_err = String::from_utf8_lossy(&big.stderr);
    assert_eq!(big.status.code(), Some(2), "{big_err}");
    assert!(
        big_err.contains("line 2 is not an integer stamp (64-bit ns): 99999999999999999999"),
        "{big_err}"
    );
    assert_eq!(String::from_utf8_lossy(&big.stdout).lines().count(), 1);
    let rows: Vec<Vec<&str>> = conv_text
        .lines()
        .map(|l| l.split_whitespace().collect())
        .collect();
    assert_eq!(rows.len(), stamps.len(), "{conv_text}");
    for (row, &t_cam) in rows.iter().zip(&stamps) {
        assert_eq!(row.len(), 4, "{conv_text}");
        assert_eq!(row[0].parse::<i64>().unwrap(), t_cam, "{conv_text}");
        let t_lidar: i64 = row[1].parse().unwrap();
        let std_us: f64 = row[2].parse().unwrap();
        assert!(["tracking", "holding"].contains(&row[3]), "{conv_text}");
        // t_lidar = t_cam + offset(t_lidar), within the estimate's error
        let err_ms = ((t_lidar - t_cam) as f64 * 1e-9 - rig.sim.truth.offset_at(t_lidar)) * 1e3;
        assert!(err_ms.abs() < 20.0, "{err_ms} ms off: {conv_text}");
        assert!(std_us > 0.0 && std_us < 50_000.0, "{conv_text}");
    }
    std::fs::remove_dir_all(&tmp).unwrap();
}

#[test]
fn the_examples_refuse_bad_input_with_their_exit_codes() {
    let tmp = scratch("bad");
    let (echo, convert) = build_examples(&tmp);
    let silent = format!("vlsync-it/capi-silent-{}", std::process::id());
    for (exe, args, code, says) in [
        (
            &echo,
            vec!["--prefix", "/bad"],
            2,
            "prefix \"/bad\" is invalid",
        ),
        (
            &echo,
            vec!["--count", "-1"],
            2,
            "--count takes a whole number >= 0, not -1",
        ),
        (
            &echo,
            vec!["--count"],
            2,
            "a value is missing after --count",
        ),
        (&echo, vec!["--what", "1"], 2, "unknown option --what"),
        (
            &echo,
            vec!["--timeout", ""],
            2,
            "--timeout takes seconds >= 0, not ",
        ),
        (&convert, vec!["--what"], 2, "unknown option --what"),
        (
            &convert,
            vec!["--timeout"],
            2,
            "a value is missing after --timeout",
        ),
        (
            &convert,
            vec!["--timeout", ""],
            2,
            "--timeout takes seconds >= 0, not ",
        ),
        (
            &echo,
            vec!["--prefix", &silent, "--timeout", "0.5"],
            1,
            "no estimate on",
        ),
        (
            &convert,
            vec!["--prefix", "robot/"],
            2,
            "prefix \"robot/\" is invalid",
        ),
        (
            &convert,
            vec!["--timeout", "x"],
            2,
            "--timeout takes seconds >= 0, not x",
        ),
        (
            &convert,
            vec!["--timeout", "2e6"],
            2,
            "--timeout takes seconds >= 0, not 2e6 (at most 1000000)",
        ),
        (
            &convert,
            vec!["--max-age", "0"],
            2,
            "--max-age takes seconds > 0, not 0",
        ),
        (
            &echo,
            vec!["--timeout", "2e9"],
            2,
            "--timeout takes seconds >= 0, not 2e9 (at most 1e9)",
        ),
        (
            &convert,
            vec!["--prefix", &silent, "--timeout", "0.5"],
            1,
            "no lock on",
        ),
        (
            &echo,
            vec!["--prefix", &silent, "--status", "--timeout", "0.5"],
            1,
            "no status on",
        ),
    ] {
        let out = run(exe, &args, "");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(code), "{args:?}: {err}");
        assert!(err.contains(says), "{args:?}: {err}");
    }
    // --help: the usage on stdout, exit 0, nothing opened
    for (exe, usage) in [
        (&echo, "usage: vlsync_echo_c [--prefix P]"),
        (&convert, "usage: vlsync_convert [--prefix P]"),
    ] {
        let out = run(exe, &["--help"], "");
        let text = String::from_utf8_lossy(&out.stdout);
        assert_eq!(out.status.code(), Some(0), "{text}");
        assert!(text.starts_with(usage), "{text}");
    }
    std::fs::remove_dir_all(&tmp).unwrap();
}

/// The C++ wrapper's `close()` from another thread throws and leaves the handle open
/// for its own thread; a `Client` destroyed on another thread says on stderr that its
/// handle leaks instead of leaking it silently; a `StatusClient` of a silent prefix
/// has no status, moved or not.
#[test]
fn the_cpp_wrapper_reports_a_close_from_another_thread() {
    let tmp = scratch("cppthread");
    let src = tmp.join("thread.cpp");
    std::fs::write(
        &src,
        r#"#include <cstdio>
#include <string>
#include <thread>
#include "vlsync_client.hpp"
int main(int argc, char **argv) {
  if (argc != 2) return 3;
  vlsync::Client c(argv[1]);
  std::string refused;
  std::thread([&] {
    try { c.close(); } catch (const vlsync::Error &e) { refused = e.what(); }
  }).join();
  if (refused.empty()) return 4;
  std::printf("refused: %s\n", refused.c_str());
  if (c.wait_one(std::chrono::milliseconds(10))) return 5;  // still open here
  c.close();
  c.close();  // closed: nothing to do
  vlsync::Client d(argv[1]);
  std::thread([d = std::move(d)]() mutable { vlsync::Client gone = std::move(d); }).join();
  vlsync::StatusClient s(argv[1]);
  if (s.latest()) return 6;  // no daemon: no status
  vlsync::StatusClient t = std::move(s);
  if (t.latest()) return 7;
  return 0;
}
"#,
    )
    .unwrap();
    let exe = tmp.join("thread");
    compile(&src, &exe, true);
    let prefix = format!("vlsync-it/capi-thread-{}", std::process::id());
    let out = run(&exe, &[&prefix], "");
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert_eq!(out.status.code(), Some(0), "{stdout}\n{stderr}");
    assert!(
        stdout.contains("refused: vlsync_client_close: the client was opened on another thread"),
        "{stdout}"
    );
    assert!(
        stderr.contains("vlsync::Client destroyed on another thread"),
        "{stderr}"
    );
    std::fs::remove_dir_all(&tmp).unwrap();
}

/// Payloads that fail validation reach the C echo's reader as a line on stderr, not as
/// silence (estimates) or an exit 2 (a status that came before any valid one); a
/// prefix nobody publishes on is said once after 5 s.
#[test]
fn the_c_echo_says_what_it_skipped_and_when_nothing_comes() {
    use vlsync_ipc::iceoryx2::service::port_factory::PortFactory as _;
    use vlsync_ipc::{
        create_node, notifier, open_or_create_event, open_or_create_pubsub, publisher, Qos,
        ServiceNames,
    };
    let tmp = scratch("skipped");
    let (echo, _) = build_examples(&tmp);
    let spawn = |args: &[&str]| start(&echo, args, Stdio::null());
    // nobody publishes here: said once, at 5 s, then the --timeout
    let silent = format!("vlsync-it/capi-quiet-{}", std::process::id());
    let quiet = spawn(&["--prefix", &silent, "--timeout", "6.5"]);
    let quiet_status = spawn(&["--prefix", &silent, "--status", "--timeout", "6.5"]);

    let names = ServiceNames::new(&format!("vlsync-it/capi-skip-{}", std::process::id())).unwrap();
    let node = create_node("test-daemon", false).unwrap();
    let offset =
        open_or_create_pubsub::<OffsetEstimate>(&node, &names.offset(), Qos::latest()).unwrap();
    let offset_ev = open_or_create_event(&node, &names.offset()).unwrap();
    let offset_pub = publisher(&offset, "offset").unwrap();
    let offset_note = notifier(&offset_ev, "offset").unwrap();
    let status = open_or_create_pubsub::<Status>(&node, &names.status(), Qos::latest()).unwrap();
    let status_pub = publisher(&status, "status").unwrap();

    let estimates = spawn(&["--prefix", &names.prefix, "--count", "1", "--timeout", "20"]);
    let statuses = spawn(&[
        "--prefix",
        &names.prefix,
        "--status",
        "--count",
        "1",
        "--timeout",
        "20",
    ]);
    // both echoes subscribed (each service's one subscriber: the quiet ones are on
    // another prefix) before anything is published, however slow their start
    let t0 = std::time::Instant::now();
    while offset.dynamic_config().number_of_subscribers() == 0
        || status.dynamic_config().number_of_subscribers() == 0
    {
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "the echoes did not subscribe within 30 s"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    let e = vlsync_tests::tracking_estimate(7);
    let mut bad = OffsetEstimate::from_estimate(&e, 1).unwrap();
    bad.offset_s = f64::NAN;
    offset_pub.send_copy(bad).unwrap();
    offset_note.notify().unwrap();
    // an invalid status alone first: the echo polls every 250 ms and meets it alone
    status_pub
        .send_copy(Status {
            degraded: 9,
            ..Status::default()
        })
        .unwrap();
    std::thread::sleep(Duration::from_millis(1000));
    offset_pub
        .send_copy(OffsetEstimate::from_estimate(&e, 2).unwrap())
        .unwrap();
    offset_note.notify().unwrap();
    status_pub
        .send_copy(Status {
            estimates_published: 5,
            ..Status::default()
        })
        .unwrap();

    let text = |o: &Output| {
        (
            String::from_utf8_lossy(&o.stdout).to_string(),
            String::from_utf8_lossy(&o.stderr).to_string(),
        )
    };
    // each echo printed the valid payload after skipping, and said the skip
    let printed_estimate: fn(&str) -> bool = |so| so.starts_with("seq 7 tracking");
    let printed_status: fn(&str) -> bool = |so| so.contains("estimates 5 ");
    for (child, printed, kind, service) in [
        (estimates, printed_estimate, "estimate", "offset"),
        (statuses, printed_status, "status", "status"),
    ] {
        let out = child.output_within(RUN_LIMIT);
        let (so, se) = text(&out);
        assert_eq!(out.status.code(), Some(0), "{so}\n{se}");
        assert!(printed(&so), "{so}");
        assert!(
            se.contains(&format!(
                "vlsync_echo_c: skipped 1 invalid {kind} payload(s) on {}/{service}",
                names.prefix
            )),
            "{se}"
        );
    }
    for (child, service) in [(quiet, "offset"), (quiet_status, "status")] {
        let out = child.output_within(RUN_LIMIT);
        let (so, se) = text(&out);
        assert_eq!(out.status.code(), Some(1), "{so}\n{se}");
        let notice = format!(
            "vlsync_echo_c: nothing on {silent}/{service} for 5 s; waiting (is vlsyncd running with this prefix?)"
        );
        assert_eq!(se.matches(&notice).count(), 1, "{se}");
    }
    std::fs::remove_dir_all(&tmp).unwrap();
}
