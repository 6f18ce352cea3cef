//! The daemon package's binaries start, describe themselves, and refuse a bad
//! command line with clap's usage error (exit code 2) naming what was wrong.
//! (This file also makes `cargo test` build these binaries, which the
//! multi-process tests in `tests/` then run.)

use std::process::Command;

fn run(bin: &str, args: &[&str]) -> (i32, String, String) {
    let out = Command::new(bin)
        .args(args)
        .output()
        .expect("run the binary");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn every_binary_has_help_and_rejects_an_unknown_argument() {
    for (bin, help_names) in [
        (
            env!("CARGO_BIN_EXE_vlsyncd"),
            &["run", "replay", "bench", "check"][..],
        ),
        (
            env!("CARGO_BIN_EXE_vlsync-demo"),
            &["--seed", "--duration"][..],
        ),
        (
            env!("CARGO_BIN_EXE_vlsync-loadtest"),
            &["--profile", "--check"][..],
        ),
        (
            env!("CARGO_BIN_EXE_vlsync-latency"),
            &["--config", "--check"][..],
        ),
    ] {
        let (code, out, _) = run(bin, &["--help"]);
        assert_eq!(code, 0, "{bin} --help");
        for name in help_names {
            assert!(out.contains(name), "{bin} --help lacks {name}:\n{out}");
        }
        let (code, _, err) = run(bin, &["--no-such-option"]);
        assert_eq!(code, 2, "{bin}: {err}");
        assert!(err.contains("--no-such-option"), "{bin}: {err}");
    }
    let (code, _, err) = run(env!("CARGO_BIN_EXE_vlsyncd"), &["frobnicate"]);
    assert_eq!(code, 2);
    assert!(err.contains("frobnicate"), "{err}");
}

/// A negative number given to a numeric flag is that flag's value: the error names the
/// flag and says why the value is refused (clap alone calls `-1` an unexpected argument
/// and suggests `-- -1`, which would not help).
#[test]
fn a_negative_number_is_the_flags_value_and_its_error_names_the_flag() {
    for (bin, args, names) in [
        (
            env!("CARGO_BIN_EXE_vlsync-demo"),
            &["--speed", "-1"][..],
            "--speed -1 is out of range",
        ),
        (
            env!("CARGO_BIN_EXE_vlsyncd"),
            &["bench", "--seeds", "-3"][..],
            "'-3' for '--seeds",
        ),
        (
            env!("CARGO_BIN_EXE_vlsync-latency"),
            &["--speed", "-100"][..],
            "--speed",
        ),
        (
            env!("CARGO_BIN_EXE_vlsync-demo"),
            &["--fifo", "-1"][..],
            "'-1' for '--fifo",
        ),
        (
            env!("CARGO_BIN_EXE_vlsyncd"),
            &["run", "--fifo-priority", "100"][..],
            "'100' for '--fifo-priority",
        ),
        (
            env!("CARGO_BIN_EXE_vlsyncd"),
            &["run", "--fifo-priority", "-1"][..],
            "'-1' for '--fifo-priority",
        ),
    ] {
        let (code, _, err) = run(bin, args);
        assert_ne!(code, 0, "{bin} {args:?}");
        assert!(err.contains(names), "{bin} {args:?}: {err}");
        assert!(
            !err.contains("unexpected argument"),
            "{bin} {args:?}: {err}"
        );
    }
}

/// `vlsyncd run` with a configuration it cannot load exits 78 (EX_CONFIG), which the
/// systemd unit does not restart (`RestartPreventExitStatus=78`), naming the file and
/// the key; a bad `--prefix` is the configuration's too. It exits before it opens
/// anything, so no daemon is started here.
#[test]
fn a_configuration_it_cannot_load_exits_78() {
    let dir = std::env::temp_dir().join(format!("vlsyncd-cli-cfg-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad.toml");
    std::fs::write(&bad, "[daemon]\ncore = -3\n").unwrap();
    let missing = dir.join("missing.toml");
    let vlsyncd = env!("CARGO_BIN_EXE_vlsyncd");
    for (args, names) in [
        (
            vec!["run", "--config", bad.to_str().unwrap()],
            vec!["bad.toml", "core"],
        ),
        (
            vec!["run", "--config", missing.to_str().unwrap()],
            vec!["missing.toml"],
        ),
        (vec!["run", "--prefix", "no spaces/allowed"], vec!["prefix"]),
        // options `run` cannot take: a unit would restart them every 2 s on exit 2
        (
            vec!["run", "--fifo-priority", "100"],
            vec!["--fifo-priority"],
        ),
        (vec!["run", "--bogus"], vec!["--bogus"]),
    ] {
        let (code, _, err) = run(vlsyncd, &args);
        assert_eq!(code, 78, "{args:?}: {err}");
        for n in names {
            assert!(err.contains(n), "{args:?}: {err}");
        }
    }
    // `check` keeps its documented exit code 2 for the same file, and the one-shot
    // commands clap's 2 for an option they cannot take
    let (code, _, err) = run(vlsyncd, &["check", "--config", bad.to_str().unwrap()]);
    assert_eq!(code, 2, "{err}");
    let (code, _, err) = run(vlsyncd, &["replay", "--bogus"]);
    assert_eq!(code, 2, "{err}");
    let (code, out, _) = run(vlsyncd, &["run", "--help"]);
    assert_eq!(code, 0, "{out}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn replay_refuses_an_output_that_names_an_input_or_the_other_output() {
    let dir = std::env::temp_dir().join(format!("vlsyncd-cli-out-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (cam, lidar) = (dir.join("cam.csv"), dir.join("lidar.csv"));
    let rows = "t,value\n0.0,1.0\n0.1,2.0\n0.2,1.5\n";
    std::fs::write(&cam, rows).unwrap();
    std::fs::write(&lidar, rows).unwrap();
    let p = |x: &std::path::Path| x.to_str().unwrap().to_string();
    // the same file spelled another way still is the same file
    let cam_spelled = p(&dir.join(".").join("cam.csv"));
    let est = p(&dir.join("est.csv"));
    let (cam_s, lidar_s) = (p(&cam), p(&lidar));
    let vlsyncd = env!("CARGO_BIN_EXE_vlsyncd");
    for (extra, names) in [
        (vec!["--out", cam_spelled.as_str()], ["--out", "--cam"]),
        (
            vec!["--out", &est, "--plot", &lidar_s],
            ["--plot", "--lidar"],
        ),
        (vec!["--out", &est, "--plot", &est], ["--out", "--plot"]),
    ] {
        let mut args = vec!["replay", "--cam", &cam_s, "--lidar", &lidar_s];
        args.extend(extra.iter().copied());
        let (code, _, err) = run(vlsyncd, &args);
        assert_eq!(code, 2, "{args:?}: {err}");
        assert!(err.contains("refusing to overwrite"), "{args:?}: {err}");
        for n in names {
            assert!(err.contains(n), "{args:?}: {err}");
        }
        // nothing was written: the inputs are as they were, no estimates file
        assert_eq!(std::fs::read_to_string(&cam).unwrap(), rows);
        assert_eq!(std::fs::read_to_string(&lidar).unwrap(), rows);
        assert!(!dir.join("est.csv").exists(), "{args:?}");
    }
    // one file for both streams
    let (code, _, err) = run(
        vlsyncd,
        &[
            "replay",
            "--cam",
            &cam_s,
            "--lidar",
            &cam_spelled,
            "--out",
            &est,
        ],
    );
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("--cam and --lidar name the same file"),
        "{err}"
    );
    assert!(!dir.join("est.csv").exists());
    // an output that cannot be written is refused before the run, naming its flag
    for (flag, bad) in [
        ("--out", "/proc/vlsync-est.csv"),
        ("--plot", "/proc/vlsync.svg"),
    ] {
        let mut args = vec!["replay", "--cam", &cam_s, "--lidar", &lidar_s];
        if flag == "--plot" {
            args.extend(["--out", &est]);
        }
        args.extend([flag, bad]);
        let (code, _, err) = run(vlsyncd, &args);
        assert_eq!(code, 2, "{args:?}: {err}");
        assert!(
            err.contains(&format!("{flag} {bad}: cannot be created")),
            "{err}"
        );
        assert!(!dir.join("est.csv").exists(), "{args:?}");
    }
    // distinct files: accepted
    let (code, _, err) = run(
        vlsyncd,
        &[
            "replay", "--cam", &cam_s, "--lidar", &lidar_s, "--out", &est,
        ],
    );
    assert_eq!(code, 0, "{err}");
    // both outputs thrown away: one device, nothing truncated, accepted
    let (code, _, err) = run(
        vlsyncd,
        &[
            "replay",
            "--cam",
            &cam_s,
            "--lidar",
            &lidar_s,
            "--out",
            "/dev/null",
            "--plot",
            "/dev/null",
        ],
    );
    assert_eq!(code, 0, "{err}");
    // written whole, with no temporary file beside it
    let names: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    assert!(names.iter().all(|n| !n.contains(".tmp-")), "{names:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn replay_merges_by_publish_time_only_when_both_files_carry_it() {
    let dir = std::env::temp_dir().join(format!("vlsyncd-cli-order-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let plain = dir.join("plain.csv");
    let recorded = dir.join("recorded.csv");
    std::fs::write(&plain, "t,value\n0.0,1.0\n0.1,2.0\n").unwrap();
    std::fs::write(
        &recorded,
        "t,value,seq,publish,flags\n0.0,1.0,0,5.0,1\n0.1,2.0,1,5.1,0\n",
    )
    .unwrap();
    // the LiDAR's: another file with the same rows (one file for both is refused)
    let recorded_l = dir.join("recorded-lidar.csv");
    std::fs::copy(&recorded, &recorded_l).unwrap();
    let bad = dir.join("bad.csv");
    std::fs::write(
        &bad,
        "t,value,seq,publish,flags\n0.0,1.0,0,5.0,1\n0.1,2.0,1,,0\n",
    )
    .unwrap();
    let (est, cmp) = (dir.join("est.csv"), dir.join("cmp.csv"));
    let p = |x: &std::path::Path| x.to_str().unwrap().to_string();
    let vlsyncd = env!("CARGO_BIN_EXE_vlsyncd");
    let replay = |cam: &std::path::Path, lidar: &std::path::Path, extra: &[&str]| {
        let mut args = vec![
            "replay".to_string(),
            "--cam".into(),
            p(cam),
            "--lidar".into(),
        ];
        args.extend([p(lidar), "--out".into(), p(&est)]);
        args.extend(extra.iter().map(|s| s.to_string()));
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        run(vlsyncd, &args)
    };
    let (code, _, err) = replay(&recorded, &recorded_l, &[]);
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("merged by publish time"), "{err}");
    for (cam, lidar, extra) in [
        (&plain, &recorded, &[][..]),
        (&recorded, &recorded_l, &["--order", "stamp"][..]),
    ] {
        let (code, _, err) = replay(cam, lidar, extra);
        assert_eq!(code, 0, "{err}");
        assert!(err.contains("merged by stamp"), "{err}");
    }
    let (code, _, err) = replay(&recorded, &plain, &["--order", "publish"]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains(&format!(
            "--order publish: {} has no `publish` column",
            p(&plain)
        )),
        "{err}"
    );
    let (code, _, err) = replay(&bad, &recorded, &[]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains(&format!("{}:3: missing column 4 (publish)", p(&bad))),
        "{err}"
    );
    // by stamp the publish column is not read: a recording cut in it replays
    let (code, _, err) = replay(&bad, &recorded, &["--order", "stamp"]);
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("merged by stamp"), "{err}");
    // publish times that cannot be the order the daemon read in: auto merges by
    // stamp and says why; an explicit --order publish is obeyed with a warning
    let zero = dir.join("zero.csv");
    std::fs::write(
        &zero,
        "t,value,seq,publish,flags\n0.0,1.0,0,0.0,1\n0.1,2.0,1,0.0,0\n",
    )
    .unwrap();
    let back = dir.join("back.csv");
    std::fs::write(
        &back,
        "t,value,seq,publish,flags\n0.0,1.0,0,5.0,1\n0.1,2.0,1,4.0,0\n",
    )
    .unwrap();
    let (code, _, err) = replay(&recorded, &zero, &[]);
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains(&format!(
            "--order auto: {}: publish time 0 s of sample 1 is not positive: merging by stamp",
            p(&zero)
        )) && err.contains("merged by stamp"),
        "{err}"
    );
    let (code, _, err) = replay(&recorded, &zero, &["--order", "publish"]);
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains(&format!(
            "warning: --order publish: {}: publish time 0 s of sample 1 is not positive",
            p(&zero)
        )) && err.contains("merged by publish time"),
        "{err}"
    );
    // times that go back (two publishers on one stream) are followed, with a note
    let (code, _, err) = replay(&back, &recorded, &[]);
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains(&format!(
            "note: {}: publish times go back at sample 2 (4.000000000 s after 5.000000000 s); merged in that order all the same",
            p(&back)
        )) && err.contains("merged by publish time"),
        "{err}"
    );
    // --compare: a file that is no estimates file is an error naming it
    std::fs::write(&cmp, "t,value\n0.0,1.0\n").unwrap();
    let (code, _, err) = replay(&plain, &recorded_l, &["--compare", &p(&cmp)]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains(&format!(
            "{}:1: expected the header of an estimates file",
            p(&cmp)
        )),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `vlsyncd record` whose file cannot be written stops at the first flush, says in its
/// summary that the recording was cut short and why, offers no replay, and exits 2.
#[test]
fn a_recording_cut_short_by_a_write_error_says_so() {
    let dir = std::env::temp_dir().join(format!("vlsyncd-cli-recfull-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    std::os::unix::fs::symlink("/dev/full", dir.join("est.csv")).unwrap();
    let prefix = format!("vlsync-test/recfull-{}", std::process::id());
    let (code, _, err) = run(
        env!("CARGO_BIN_EXE_vlsyncd"),
        &[
            "record",
            "--prefix",
            &prefix,
            "--out",
            dir.to_str().unwrap(),
            "--duration",
            "5",
            "--force",
        ],
    );
    assert_eq!(code, 2, "{err}");
    let path = dir.join("est.csv");
    assert!(
        err.contains("ended after")
            && err.contains(&format!(
                "cannot write {}: No space left on device",
                path.display()
            )),
        "{err}"
    );
    assert!(!err.contains("replay it"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `vlsyncd bench` whose output cannot be written names the option: a directory for
/// `--plots` that cannot be made fails before any run; a `--json` file that cannot be
/// written fails after the table, which is still printed.
#[test]
fn bench_outputs_that_cannot_be_written_name_their_option() {
    let vlsyncd = env!("CARGO_BIN_EXE_vlsyncd");
    let (code, out, err) = run(
        vlsyncd,
        &["bench", "--seeds", "1", "--plots", "/dev/null/plots"],
    );
    assert_ne!(code, 0, "{err}");
    assert!(
        err.contains("--plots /dev/null/plots: cannot create the directory"),
        "{err}"
    );
    assert!(out.is_empty(), "no run before the refusal: {out}");
    let dir = std::env::temp_dir().join(format!("vlsyncd-cli-benchjson-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let json = dir.join("b.json");
    std::os::unix::fs::symlink("/dev/full", &json).unwrap();
    // one seed of `families`, and `extra`
    let bench = |families: &str, extra: &[&str]| {
        let mut args = vec!["bench", "--seeds", "1", "--families", families];
        args.extend_from_slice(extra);
        run(vlsyncd, &args)
    };
    // the configuration it read named as its JSON output: refused before the run
    let cfg = dir.join("my.toml");
    std::fs::write(&cfg, "[estimator]\n").unwrap();
    let cfg_s = cfg.to_str().unwrap();
    let (code, out, err) = bench("seed", &["--config", cfg_s, "--json", cfg_s]);
    assert_ne!(code, 0, "{err}");
    assert!(
        err.contains(&format!(
            "--json {cfg_s} is the same file as --config: refusing to overwrite it"
        )),
        "{err}"
    );
    assert!(out.is_empty(), "no run before the refusal: {out}");
    assert_eq!(std::fs::read_to_string(&cfg).unwrap(), "[estimator]\n");
    let (code, out, err) = bench("seed", &["--json", json.to_str().unwrap()]);
    assert_ne!(code, 0, "{err}");
    let want = format!(
        "--json: cannot write {}: No space left on device",
        json.display()
    );
    assert!(err.contains(&want), "{err}");
    assert!(
        out.contains("seed"),
        "the table is printed all the same: {out}"
    );
    // a family's plot that is a directory: refused before any run
    let plots = dir.join("plots");
    let plots_arg = plots.to_str().unwrap();
    std::fs::create_dir_all(plots.join("robot.svg")).unwrap();
    let (code, out, err) = bench("seed,robot", &["--plots", plots_arg]);
    assert_ne!(code, 0, "{err}");
    let want = format!(
        "--plots {}: is a directory",
        plots.join("robot.svg").display()
    );
    assert!(err.contains(&want), "{err}");
    assert!(out.is_empty(), "no run before the refusal: {out}");
    // a family's plot that fails to be written: the others still run and are
    // tabled, the failure names the family and is the exit status
    std::fs::remove_dir_all(plots.join("robot.svg")).unwrap();
    std::os::unix::fs::symlink("/dev/full", plots.join("seed.svg")).unwrap();
    let (code, out, err) = bench("seed,robot", &["--duration", "20", "--plots", plots_arg]);
    assert_ne!(code, 0, "{err}");
    assert!(
        err.contains("1 of 2 families failed, the first: seed: --plots: cannot write"),
        "{err}"
    );
    assert!(!err.contains("wrote one SVG per family"), "{err}");
    assert!(
        out.contains("| robot |") && !out.contains("| seed |"),
        "{out}"
    );
    assert!(plots.join("robot.svg").is_file());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// An output named `/dev/stdout` goes where the process's standard output goes: into
/// a file a shell opened with `>` beside the rest of the output (not over it), and
/// into a pipe whose reader stops early (`| head`) without an error.
#[test]
fn an_output_on_standard_output_shares_it() {
    let vlsyncd = env!("CARGO_BIN_EXE_vlsyncd");
    let dir = std::env::temp_dir().join(format!("vlsyncd-cli-stdout-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    // `> out.txt`: the JSON, then the table after it
    let out = dir.join("out.txt");
    let status = std::process::Command::new(vlsyncd)
        .args(["bench", "--families", "seed", "--seeds", "1"])
        .args(["--json", "/dev/stdout"])
        .stdout(std::fs::File::create(&out).unwrap())
        .stderr(std::process::Stdio::null())
        .status()
        .unwrap();
    assert!(status.success());
    let text = std::fs::read_to_string(&out).unwrap();
    let table = text.find("| family |").expect("the table");
    let json_end = text.rfind(']').expect("the JSON");
    assert!(text.starts_with('[') && json_end < table, "{text}");
    // `| head -1` on a replay's estimates (some 200 kB: more than a pipe holds)
    let sim = dir.join("run");
    let samples: String = (0..100_000)
        .map(|i| format!("{},{}\n", i as f64 * 0.01, (i as f64 * 0.1).sin()))
        .collect();
    std::fs::create_dir_all(&sim).unwrap();
    for f in ["cam.csv", "lidar.csv"] {
        std::fs::write(sim.join(f), format!("t,value\n{samples}")).unwrap();
    }
    let mut child = std::process::Command::new(vlsyncd)
        .args(["replay", "--cam"])
        .arg(sim.join("cam.csv"))
        .arg("--lidar")
        .arg(sim.join("lidar.csv"))
        .args(["--out", "/dev/stdout"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    {
        use std::io::BufRead;
        let mut first = String::new();
        std::io::BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut first)
            .unwrap();
        assert!(first.starts_with("t,offset"), "{first}");
        // the reader goes away with the rest unread
    }
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
