//! The systemd deployment in deploy/: the units carry the settings the daemon
//! and iceoryx2 rely on (checked by parsing, works everywhere), they pass
//! `systemd-analyze verify` where that tool exists, the shipped configuration
//! loads and agrees with the units, and deploy/install.sh previews, refuses
//! without root and checks its inputs.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use vlsync_tests::{bin, capi_lib_dir};

fn deploy() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy")
}

/// section -> key -> values (a key may repeat)
type Unit = BTreeMap<String, BTreeMap<String, Vec<String>>>;

fn parse(name: &str) -> Unit {
    let path = deploy().join("systemd").join(name);
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    let mut unit = Unit::new();
    let mut section = None;
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if line.is_empty() || line.starts_with('#') || line.starts_with(';') {
            continue;
        }
        if let Some(s) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            section = Some(s.to_string());
            unit.entry(s.to_string()).or_default();
            continue;
        }
        let (k, v) = line
            .split_once('=')
            .unwrap_or_else(|| panic!("{name}:{}: not key=value: {raw}", i + 1));
        let s = section
            .clone()
            .unwrap_or_else(|| panic!("{name}:{}: key outside a section", i + 1));
        unit.entry(s)
            .or_default()
            .entry(k.trim().to_string())
            .or_default()
            .push(v.trim().to_string());
    }
    unit
}

fn get<'a>(u: &'a Unit, name: &str, section: &str, key: &str) -> &'a str {
    let v = u
        .get(section)
        .and_then(|s| s.get(key))
        .unwrap_or_else(|| panic!("{name}: [{section}] {key}= missing"));
    assert_eq!(
        v.len(),
        1,
        "{name}: [{section}] {key}= given {} times",
        v.len()
    );
    &v[0]
}

fn words(u: &Unit, section: &str, key: &str) -> Vec<String> {
    u.get(section)
        .and_then(|s| s.get(key))
        .map(|vs| {
            vs.iter()
                .flat_map(|v| v.split_whitespace())
                .map(String::from)
                .collect()
        })
        .unwrap_or_default()
}

const SERVICES: [&str; 3] = [
    "vlsyncd.service",
    "vlsync-cam.service",
    "vlsync-lidar.service",
];

#[test]
fn daemon_unit_has_notify_watchdog_restart_rt_limits_and_hardening() {
    let n = "vlsyncd.service";
    let u = parse(n);
    for (k, want) in [
        ("Type", "notify"),
        ("NotifyAccess", "main"),
        ("WatchdogSec", "5s"),
        // a clean exit (a stray SIGTERM or SIGHUP) is restarted too
        ("Restart", "always"),
        ("RestartSec", "2"),
        // a configuration the daemon cannot load is not retried (`vlsyncd run` exits
        // 78 then, `a_configuration_it_cannot_load_exits_78`); everything else is,
        // without a start limit
        ("RestartPreventExitStatus", "78"),
        ("User", "vlsync"),
        ("Group", "vlsync"),
        ("RuntimeDirectory", "vlsync"),
        ("RuntimeDirectoryPreserve", "yes"),
        ("ProtectSystem", "strict"),
        ("NoNewPrivileges", "yes"),
        ("ProtectHome", "yes"),
        ("ProtectKernelTunables", "yes"),
        ("ProtectKernelModules", "yes"),
        ("ProtectKernelLogs", "yes"),
        ("ProtectControlGroups", "yes"),
        ("RestrictAddressFamilies", "AF_UNIX"),
        ("LimitMEMLOCK", "infinity"),
        ("KillSignal", "SIGTERM"),
    ] {
        assert_eq!(get(&u, n, "Service", k), want, "{n}: {k}=");
    }
    assert_eq!(get(&u, n, "Unit", "StartLimitIntervalSec"), "0");
    assert_eq!(
        get(&u, n, "Service", "ExecStart"),
        "/usr/local/bin/vlsyncd run --config /etc/vlsync/vlsync.toml"
    );
    let rw = words(&u, "Service", "ReadWritePaths");
    for p in ["/dev/shm", "/tmp/iceoryx2", "/tmp/vlsync"] {
        assert!(
            rw.iter().any(|w| w == p),
            "{n}: ReadWritePaths lacks {p}: {rw:?}"
        );
    }
    // no capability is needed: the rlimits allow SCHED_FIFO and mlockall
    assert_eq!(get(&u, n, "Service", "AmbientCapabilities"), "");
    assert_eq!(get(&u, n, "Service", "CapabilityBoundingSet"), "");
    // the daemon asks the kernel whether the wall clock is synchronized with a
    // read-only adjtimex(2) (`vlsync_ipc::rt::wall_clock_synchronized`), to date a
    // state file saved before a reboot; ProtectClock='s seccomp filter (@clock)
    // refuses even that call, so the file would never be restored on a robot synced
    // by chrony or ntpd. Without CAP_SYS_TIME (the empty bounding set above) the
    // clock cannot be set anyway.
    assert!(
        !u["Service"].contains_key("ProtectClock"),
        "{n}: ProtectClock= forbids the read-only adjtimex(2) of the state file's dating"
    );
    for filter in u["Service"].get("SystemCallFilter").into_iter().flatten() {
        let (deny, list) = match filter.strip_prefix('~') {
            Some(l) => (true, l),
            None => (false, filter.as_str()),
        };
        let names_adjtimex = list
            .split_whitespace()
            .any(|w| ["@clock", "adjtimex", "clock_adjtime"].contains(&w));
        assert!(
            deny != names_adjtimex,
            "{n}: SystemCallFilter={filter} must leave adjtimex(2) allowed"
        );
    }
    assert_eq!(get(&u, n, "Unit", "PartOf"), "vlsync.target");
    assert_eq!(get(&u, n, "Install", "WantedBy"), "vlsync.target");

    // the shipped configuration agrees with the unit
    let cfg_path = deploy().join("vlsync.toml");
    let cfg = vlsync_config::Config::load(&cfg_path).unwrap();
    // CPUAffinity= lists cores and ranges ("0-3", "0 2 3", "0,3"): it must allow the
    // real-time core and at least one other, for the service threads
    let affinity = get(&u, n, "Service", "CPUAffinity");
    let cores: Vec<i64> = affinity
        .split([' ', ','])
        .filter(|w| !w.is_empty())
        .flat_map(|w| {
            let (a, b) = w.split_once('-').unwrap_or((w, w));
            a.parse::<i64>().unwrap()..=b.parse::<i64>().unwrap()
        })
        .collect();
    assert!(
        cores.contains(&cfg.daemon.core) && cores.len() > 1,
        "CPUAffinity={affinity} must include daemon.core = {} of {} and another core",
        cfg.daemon.core,
        cfg_path.display()
    );
    let rtprio: i64 = get(&u, n, "Service", "LimitRTPRIO").parse().unwrap();
    assert!(
        cfg.daemon.fifo_priority > 0 && cfg.daemon.fifo_priority <= rtprio,
        "daemon.fifo_priority {} not allowed by LimitRTPRIO={rtprio}",
        cfg.daemon.fifo_priority
    );
    assert!(cfg.daemon.lock_memory);
    assert!(
        cfg.daemon.state_file.starts_with("/run/vlsync/"),
        "state file {} outside RuntimeDirectory=vlsync",
        cfg.daemon.state_file
    );
}

#[test]
fn no_vlsync_unit_separates_tmp_or_dev_and_all_share_one_user() {
    for n in SERVICES {
        let u = parse(n);
        let svc = &u["Service"];
        for k in [
            "PrivateTmp",
            "PrivateDevices",
            "PrivateUsers",
            "DynamicUser",
            "RestrictRealtime",
            "TemporaryFileSystem",
            "InaccessiblePaths",
        ] {
            assert!(
                !svc.contains_key(k),
                "{n}: {k}= would hide /tmp/iceoryx2 or /dev/shm, or forbid SCHED_FIFO"
            );
        }
        assert_eq!(get(&u, n, "Service", "User"), "vlsync");
        assert_eq!(get(&u, n, "Service", "Group"), "vlsync");
        assert_eq!(get(&u, n, "Service", "ProtectSystem"), "strict");
        assert_eq!(
            get(&u, n, "Service", "ExecStartPre"),
            "+/usr/bin/systemd-tmpfiles --create /etc/tmpfiles.d/vlsync.conf",
            "{n}: the shared directories must exist before the sandbox is set up"
        );
        let rw = words(&u, "Service", "ReadWritePaths");
        for p in ["/dev/shm", "/tmp/iceoryx2"] {
            assert!(rw.iter().any(|w| w == p), "{n}: ReadWritePaths lacks {p}");
        }
    }
}

#[test]
fn driver_units_always_restart_have_a_watchdog_and_the_target_wants_all() {
    for n in ["vlsync-cam.service", "vlsync-lidar.service"] {
        let u = parse(n);
        assert_eq!(get(&u, n, "Service", "Restart"), "always");
        // never given up on: systemd's default start limit would leave a driver dead
        // after 5 quick failures; an unplugged sensor is waited for in the driver
        assert_eq!(get(&u, n, "Unit", "StartLimitIntervalSec"), "0");
        // but not after wrong options or configuration (the drivers exit 78 then,
        // `option_and_configuration_errors_exit_78_source_errors_2`)
        assert_eq!(get(&u, n, "Service", "RestartPreventExitStatus"), "78");
        // a driver stuck in a call is restarted (`vlsync_driver::watchdog`; the pets
        // themselves: tests/systemd_driver.rs); Type=simple, since a driver waiting
        // for its device (--wait-device) is not failing to start
        assert_eq!(get(&u, n, "Service", "Type"), "simple");
        assert_eq!(get(&u, n, "Service", "WatchdogSec"), "30s");
        assert_eq!(get(&u, n, "Service", "NotifyAccess"), "main");
        assert!(words(&u, "Unit", "After").contains(&"vlsyncd.service".to_string()));
        // a driver's restart must not start a daemon stopped on purpose (Wants= would):
        // the target wants all three
        assert!(!words(&u, "Unit", "Wants").contains(&"vlsyncd.service".to_string()));
        assert_eq!(get(&u, n, "Unit", "PartOf"), "vlsync.target");
        assert_eq!(get(&u, n, "Install", "WantedBy"), "vlsync.target");
        let exec = get(&u, n, "Service", "ExecStart");
        let stream = if n.contains("cam") { "cam" } else { "lidar" };
        assert!(
            exec.starts_with(&format!(
                "/usr/local/bin/vlsync-{stream} --config /etc/vlsync/vlsync.toml --wait-device "
            )),
            "{n}: {exec}"
        );
        assert!(deploy().join(format!("{stream}.env")).is_file());
    }
    let t = parse("vlsync.target");
    let wants = words(&t, "Unit", "Wants");
    for s in SERVICES {
        assert!(
            wants.iter().any(|w| w == s),
            "vlsync.target does not want {s}"
        );
    }
    assert_eq!(
        get(&t, "vlsync.target", "Install", "WantedBy"),
        "multi-user.target"
    );
    let tmpfiles = std::fs::read_to_string(deploy().join("tmpfiles.d/vlsync.conf")).unwrap();
    for d in ["/tmp/iceoryx2", "/tmp/vlsync"] {
        assert!(
            tmpfiles
                .lines()
                .any(|l| l.split_whitespace().collect::<Vec<_>>()
                    == ["d", d, "0750", "vlsync", "vlsync", "-"]
                    || l.split_whitespace().collect::<Vec<_>>()
                        == ["d", d, "0755", "vlsync", "vlsync", "-"]),
            "tmpfiles.d/vlsync.conf does not create {d} for vlsync"
        );
    }
}

/// `systemd-analyze verify` on a scratch root holding the units, the binaries
/// they start and the distribution's units (without touching the machine).
#[test]
fn units_pass_systemd_analyze_verify() {
    let Ok(out) = Command::new("systemd-analyze").arg("--version").output() else {
        // the suite's script installs systemd where it is missing and then requires it
        assert!(
            std::env::var_os("VLSYNC_REQUIRE_SYSTEMD_ANALYZE").is_none(),
            "systemd-analyze is required (VLSYNC_REQUIRE_SYSTEMD_ANALYZE) but not installed"
        );
        vlsync_tests::skipped(
            "units_pass_systemd_analyze_verify",
            "systemd-analyze not installed (the key checks still ran)",
        );
        return;
    };
    assert!(out.status.success());
    let root = std::env::temp_dir().join(format!("vlsync-it-sdroot-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let unit_dir = root.join("etc/systemd/system");
    let bin_dir = root.join("usr/local/bin");
    std::fs::create_dir_all(&unit_dir).unwrap();
    std::fs::create_dir_all(&bin_dir).unwrap();
    let lib_units = root.join("usr/lib/systemd");
    std::fs::create_dir_all(&lib_units).unwrap();
    let st = Command::new("cp")
        .args(["-a", "/usr/lib/systemd/system"])
        .arg(&lib_units)
        .status()
        .unwrap();
    assert!(st.success());
    for b in ["vlsyncd", "vlsync-cam", "vlsync-lidar"] {
        std::fs::copy(bin(b), bin_dir.join(b)).unwrap();
    }
    // the units' ExecStartPre= (the root's /usr/bin exists only for it)
    let usr_bin = root.join("usr/bin");
    std::fs::create_dir_all(&usr_bin).unwrap();
    std::fs::copy(
        "/usr/bin/systemd-tmpfiles",
        usr_bin.join("systemd-tmpfiles"),
    )
    .unwrap();
    let mut names = vec![];
    for e in std::fs::read_dir(deploy().join("systemd")).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), unit_dir.join(e.file_name())).unwrap();
        names.push(e.file_name().to_string_lossy().into_owned());
    }
    names.sort();
    assert_eq!(names.len(), 4, "{names:?}");
    let out = Command::new("systemd-analyze")
        .args(["verify", "--man=no"])
        .arg(format!("--root={}", root.display()))
        .args(&names)
        .output()
        .unwrap();
    let _ = std::fs::remove_dir_all(&root);
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success() && text.trim().is_empty(), "{text}");
}

fn install_sh() -> Command {
    let mut c = Command::new("bash");
    c.arg(deploy().join("install.sh"));
    c
}

#[test]
fn install_script_previews_refuses_without_root_and_checks_inputs() {
    let bins = bin("vlsyncd").parent().unwrap().to_path_buf();
    bin("vlsync-echo");
    let out = install_sh()
        .arg("--dry-run")
        .arg("--bin-dir")
        .arg(&bins)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains("dry run: nothing is changed"), "{text}");
    // the configuration in place (here the shipped one) is checked by the daemon
    // being installed: a kept file it would refuse stops the install
    assert!(text.contains("vlsync.toml: ok"), "{text}");
    for b in ["vlsyncd", "vlsync-cam", "vlsync-lidar", "vlsync-echo"] {
        let want = format!("install -m 0755 {}/{b} /usr/local/bin/{b}", bins.display());
        assert!(text.contains(&want), "no `{want}` in\n{text}");
    }
    for u in [
        "vlsyncd.service",
        "vlsync-cam.service",
        "vlsync-lidar.service",
        "vlsync.target",
    ] {
        assert!(
            text.contains(&format!("/etc/systemd/system/{u}")),
            "{u} not installed:\n{text}"
        );
    }
    assert!(text.contains("/etc/vlsync/vlsync.toml"), "{text}");
    assert!(text.contains("/etc/tmpfiles.d/vlsync.conf"), "{text}");
    assert!(
        text.contains("systemctl daemon-reload")
            || text.contains("skipped systemd-tmpfiles and daemon-reload"),
        "{text}"
    );
    // every action of a dry run is only printed
    let executed: Vec<&str> = text.lines().filter(|l| l.starts_with('+')).collect();
    assert!(executed.is_empty(), "dry run executed {executed:?}");

    // with the C client library built next to the binaries, it and its headers are
    // installed too, then ldconfig runs
    // a directory with links to the four binaries, as a --bin-dir
    let staged = |tag: &str| {
        let d = std::env::temp_dir().join(format!("vlsync-install-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        for b in ["vlsyncd", "vlsync-cam", "vlsync-lidar", "vlsync-echo"] {
            let _ = std::fs::remove_file(d.join(b));
            std::os::unix::fs::symlink(bins.join(b), d.join(b)).unwrap();
        }
        d
    };
    let with_lib = staged("lib");
    let lib = with_lib.join("libvlsync_client.so");
    let _ = std::fs::remove_file(&lib);
    std::os::unix::fs::symlink(capi_lib_dir().join("libvlsync_client.so"), &lib).unwrap();
    let out = install_sh()
        .arg("--dry-run")
        .arg("--bin-dir")
        .arg(&with_lib)
        .output()
        .unwrap();
    let lib_text = String::from_utf8_lossy(&out.stdout).into_owned();
    std::fs::remove_dir_all(&with_lib).unwrap();
    assert!(out.status.success(), "{lib_text}");
    let want = format!(
        "install -m 0755 {} /usr/local/lib/libvlsync_client.so",
        lib.display()
    );
    assert!(lib_text.contains(&want), "no `{want}` in\n{lib_text}");
    for h in ["vlsync_client.h", "vlsync_client.hpp"] {
        assert!(
            lib_text.contains(&format!("/usr/local/include/{h}")),
            "{h} not installed:\n{lib_text}"
        );
    }
    assert!(
        lib_text.contains("would write: /usr/local/lib/pkgconfig/vlsync_client.pc (prefix /usr/local, version 0.1.0)"),
        "{lib_text}"
    );
    assert!(lib_text.contains("would run: ldconfig"), "{lib_text}");
    // a cross build's layout: deploy/ copied alone, the headers and the pkg-config
    // template next to the binaries; the version comes from the binary then
    let cross = std::env::temp_dir().join(format!("vlsync-install-cross-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&cross);
    let cross_bins = staged("crossbins");
    std::fs::create_dir_all(&cross).unwrap();
    let st = Command::new("cp")
        .arg("-r")
        .arg(deploy())
        .arg(cross.join("deploy"))
        .status()
        .unwrap();
    assert!(st.success());
    let capi = deploy().join("../capi");
    std::os::unix::fs::symlink(capi.join("include"), cross_bins.join("include")).unwrap();
    std::fs::copy(
        capi.join("vlsync_client.pc.in"),
        cross_bins.join("vlsync_client.pc.in"),
    )
    .unwrap();
    std::os::unix::fs::symlink(
        capi_lib_dir().join("libvlsync_client.so"),
        cross_bins.join("libvlsync_client.so"),
    )
    .unwrap();
    let out = Command::new("bash")
        .arg(cross.join("deploy/install.sh"))
        .arg("--dry-run")
        .arg("--bin-dir")
        .arg(&cross_bins)
        .output()
        .unwrap();
    std::fs::remove_dir_all(&cross).unwrap();
    std::fs::remove_dir_all(&cross_bins).unwrap();
    let cross_text = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{cross_text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        cross_text.contains(&format!(
            "would write: /usr/local/lib/pkgconfig/vlsync_client.pc (prefix /usr/local, version {})",
            env!("CARGO_PKG_VERSION")
        )),
        "{cross_text}"
    );
    // without it, the script says how to build it
    let bare = staged("bare");
    let out = install_sh()
        .arg("--dry-run")
        .arg("--bin-dir")
        .arg(&bare)
        .output()
        .unwrap();
    std::fs::remove_dir_all(&bare).unwrap();
    let bare_text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{bare_text}");
    assert!(
        bare_text.contains("libvlsync_client.so not built") && !bare_text.contains("ldconfig"),
        "{bare_text}"
    );

    // a missing binary is named before anything happens
    let out = install_sh()
        .args(["--dry-run", "--bin-dir", "/nonexistent/vlsync-bins"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("/nonexistent/vlsync-bins/vlsyncd missing"),
        "{err}"
    );
    let out = install_sh().arg("--bogus").output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("unknown option `--bogus`"));

    // without root and without --dry-run it refuses with a clear message: run as it
    // is when this user is not root, else as nobody through setpriv
    let unprivileged = if effective_uid() != Some(0) {
        Some(install_sh().arg("--bin-dir").arg(&bins).output().unwrap())
    } else {
        match Command::new("setpriv")
            .args(["--reuid=65534", "--regid=65534", "--clear-groups", "bash"])
            .arg(deploy().join("install.sh"))
            .arg("--bin-dir")
            .arg(&bins)
            .output()
        {
            Ok(out) => Some(out),
            Err(e) => {
                vlsync_tests::skipped(
                    "install_script_previews_refuses_without_root_and_checks_inputs",
                    &format!("running as root without setpriv ({e}): the refusal without root is not checked"),
                );
                None
            }
        }
    };
    if let Some(out) = unprivileged {
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("must run as root") && err.contains("--dry-run"),
            "{err}"
        );
    }
}

/// This process's effective user id, from `/proc/self/status`.
fn effective_uid() -> Option<u32> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("Uid:"))?;
    line.split_whitespace().nth(2)?.parse().ok()
}

/// `a{b,c}d` as a shell expands it (nested and repeated groups too).
fn brace_expand(word: &str) -> Vec<String> {
    let Some(open) = word.find('{') else {
        return vec![word.to_string()];
    };
    // the group's matching `}` and its top-level commas
    let (mut depth, mut close, mut commas) = (0, None, vec![]);
    for (i, c) in word[open..].char_indices() {
        match c {
            '{' => depth += 1,
            '}' => {
                depth -= 1;
                if depth == 0 {
                    close = Some(open + i);
                    break;
                }
            }
            ',' if depth == 1 => commas.push(open + i),
            _ => {}
        }
    }
    let Some(close) = close else {
        return vec![word.to_string()];
    };
    let mut cuts = vec![open];
    cuts.extend(commas);
    cuts.push(close);
    let (head, tail) = (&word[..open], &word[close + 1..]);
    cuts.windows(2)
        .flat_map(|w| brace_expand(&format!("{head}{}{tail}", &word[w[0] + 1..w[1]])))
        .collect()
}

/// deploy/README.md's "Uninstall" removes what the guide has the user create: the
/// udev rules it names, the units' `systemctl edit` drop-ins, the directories of the
/// tmpfiles entry; and reloads udev and systemd after.
#[test]
fn the_guides_uninstall_removes_what_the_guide_creates() {
    let text = std::fs::read_to_string(deploy().join("README.md")).unwrap();
    let (guide, uninstall) = text
        .split_once("\n## Uninstall\n")
        .expect("deploy/README.md has an `## Uninstall` section");
    let block = uninstall
        .split_once("```sh\n")
        .and_then(|(_, b)| b.split_once("\n```"))
        .expect("the Uninstall section has a sh block")
        .0;
    let removed: Vec<String> = block
        .lines()
        .map(|l| l.split_once('#').map_or(l, |(code, _)| code))
        .flat_map(str::split_whitespace)
        .flat_map(brace_expand)
        .collect();

    let mut created: Vec<String> = guide
        .split(|c: char| c.is_whitespace() || "`'\"(),;".contains(c))
        .filter(|w| w.starts_with("/etc/udev/rules.d/") && w.ends_with(".rules"))
        .map(String::from)
        .collect();
    assert!(created.len() >= 2, "the guide's udev rules: {created:?}");
    let edited: Vec<&str> = guide
        .match_indices("systemctl edit ")
        .filter_map(|(i, m)| guide[i + m.len()..].split([' ', '`', '\n']).next())
        .collect();
    assert!(!edited.is_empty(), "the guide edits no unit?");
    for unit in edited.into_iter().chain(SERVICES) {
        assert!(
            SERVICES.contains(&unit),
            "the guide edits {unit}, not a vlsync service"
        );
        created.push(format!("/etc/systemd/system/{unit}.d"));
    }
    let tmpfiles = std::fs::read_to_string(deploy().join("tmpfiles.d/vlsync.conf")).unwrap();
    for l in tmpfiles.lines() {
        if let ["d", dir, ..] = l.split_whitespace().collect::<Vec<_>>()[..] {
            created.push(dir.to_string());
        }
    }
    for path in &created {
        assert!(
            removed.contains(path),
            "deploy/README.md: Uninstall leaves {path} behind (removes {removed:?})"
        );
    }
    // the removals take effect
    let pos = |s: &str| {
        block
            .find(s)
            .unwrap_or_else(|| panic!("Uninstall lacks `{s}`"))
    };
    assert!(pos("udevadm control --reload") > pos("/etc/udev/rules.d/"));
    assert!(pos("systemctl daemon-reload") > pos(".service.d"));
}

/// The drivers' shipped arguments (the uncommented line of `cam.env` and `lidar.env`,
/// the simulator by default) start the driver: each publishes, says where its
/// aligned run started, and stops cleanly on SIGTERM. A key the driver no longer
/// takes would otherwise only show on a robot, as a unit failed with exit 78.
#[test]
fn the_shipped_driver_arguments_run() {
    for stream in ["cam", "lidar"] {
        let env = std::fs::read_to_string(deploy().join(format!("{stream}.env"))).unwrap();
        let key = format!("VLSYNC_{}_ARGS=", stream.to_uppercase());
        let lines: Vec<&str> = env
            .lines()
            .filter_map(|l| l.trim().strip_prefix(key.as_str()))
            .collect();
        assert_eq!(lines.len(), 1, "{stream}.env: one uncommented {key} line");
        // the default line has no quoted parts (systemd splits it on spaces here)
        assert!(!lines[0].contains('"'), "{stream}.env: {}", lines[0]);
        let dir =
            std::env::temp_dir().join(format!("vlsync-it-env-{stream}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let log = dir.join("driver.log");
        let prefix = format!("vlsync-it/env-{stream}-{}", std::process::id());
        let mut args: Vec<String> = vec!["--prefix".into(), prefix];
        args.extend(lines[0].split_whitespace().map(String::from));
        let mut m = vlsync_tests::Managed::spawn(
            &format!("vlsync-{stream}"),
            &bin(&format!("vlsync-{stream}")),
            &args,
            Some(&log),
        )
        .unwrap();
        let text = || std::fs::read_to_string(&log).unwrap_or_default();
        // the aligned run's line comes after the publishing one
        let last_line = if lines[0].contains("--aligned") {
            "--aligned: this run started at"
        } else {
            "publishing"
        };
        assert_eq!(
            m.wait_for_log(&log, last_line, std::time::Duration::from_secs(60)),
            Ok(true),
            "{}",
            text()
        );
        assert!(m.stop(std::time::Duration::from_secs(10)), "{}", text());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
