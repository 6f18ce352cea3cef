//! `vlsyncd check`: validates a configuration file before it is deployed (the
//! same parsing and range checks `vlsyncd run` applies at start) and, with
//! `--print`, shows the effective configuration: every key, defaults filled in.

use std::path::Path;
use vlsync_config::Config;

/// Loads and validates `path`; returns the report to print on success: one line
/// naming the file, and with `print` the effective configuration after it, the
/// line then a TOML comment so that the whole output is a valid file.
pub fn check(path: &Path, print: bool) -> Result<String, String> {
    let cfg = Config::load(path).map_err(|e| e.to_string())?;
    let comment = if print { "# " } else { "" };
    let mut out = format!("{comment}{}: ok\n", path.display());
    if !cfg.daemon.state_file.is_empty() {
        if let Some(problem) = crate::state::directory_problem(Path::new(&cfg.daemon.state_file)) {
            // a note, not an error: the check often runs on another machine than the
            // robot, and systemd creates the unit's RuntimeDirectory when it starts it
            let unit = if cfg.daemon.state_file.starts_with("/run/vlsync/") {
                " (the shipped systemd unit's RuntimeDirectory=vlsync creates /run/vlsync)"
            } else {
                ""
            };
            // a missing directory may appear; a path that names a directory, or one
            // no file can have, stays wrong
            let then = if problem.ends_with(": is a directory")
                || problem.ends_with("contains a NUL byte, which no file name can")
            {
                "; `vlsyncd run` warns at start and cannot save until it is changed".to_string()
            } else {
                format!(
                    " on this machine; `vlsyncd run` warns at start and saves once it exists{unit}"
                )
            };
            out.push_str(&format!(
                "{comment}note: daemon.state_file: {problem}{then}\n"
            ));
        }
    }
    // the machine's CPUs, not this shell's: a core kept from login shells (`isolcpus`,
    // a CPU set) is the daemon's under its unit (`CPUAffinity=`)
    let cores = std::fs::read_to_string("/sys/devices/system/cpu/online")
        .ok()
        .and_then(|s| parse_cpu_list(&s))
        .unwrap_or_else(vlsync_ipc::rt::available_cores);
    if let Some(note) = core_note(cfg.daemon.core, &cores) {
        out.push_str(&format!("{comment}{note}\n"));
    }
    if let Some(note) = work_note(&cfg.estimator) {
        out.push_str(&format!("{comment}{note}\n"));
    }
    if print {
        let text = toml::to_string(&cfg)
            .map_err(|e| format!("cannot print the configuration of {}: {e}", path.display()))?;
        out.push_str(&text);
    }
    Ok(out)
}

/// The estimator's lag-sum work per second of data, `(searching, locked)`: the sums
/// each grid sample updates and each hop reads (the acquisition window's blocks
/// while searching, the segment's while locked, at every lag the state keeps). A
/// model, not a timing: its ratio between two configurations is what it is for. The
/// grid, hop, lags and blocks are counted as the estimator counts them, by the same
/// functions as the configuration's memory bound (`EstimatorConfig::lag_slots`,
/// `window_blocks`, `segment_blocks`).
pub fn estimator_work(e: &vlsync_config::EstimatorConfig) -> (f64, f64) {
    let fs = e.effective_grid_hz();
    let hop = e.effective_hop_s();
    let lags = e.lag_slots() as f64;
    // the tracking range, the slots beyond it the segment's search reads and the
    // spare each side (estimator/src/track.rs: TRACK_NEED_SLOTS, TRACK_SPARE_SLOTS)
    let active = (2.0 * (e.track_range_s * fs + 6.0 + 8.0) + 1.0).min(lags);
    let window_blocks = e.window_blocks() as f64;
    let segment_blocks = e.segment_blocks() as f64;
    (
        fs * lags + window_blocks * lags / hop,
        fs * active + segment_blocks * active / hop,
    )
}

/// Above this many times the shipped defaults' work, [`work_note`] speaks.
pub const WORK_NOTE_RATIO: f64 = 10.0;

/// A note when the estimator keys ask for much more work per second of data than
/// the shipped defaults ([`estimator_work`], either state): the validation bounds the
/// lag sums' memory, not the time, and a configuration a small core cannot keep up
/// with falls behind live (budget overruns, degraded mode).
pub fn work_note(e: &vlsync_config::EstimatorConfig) -> Option<String> {
    let (acq, lock) = estimator_work(e);
    let (acq0, lock0) = estimator_work(&vlsync_config::EstimatorConfig::default());
    let (ra, rl) = (acq / acq0, lock / lock0);
    if ra.max(rl) <= WORK_NOTE_RATIO {
        return None;
    }
    let x = ratio_text;
    Some(format!(
        "note: estimator: about {}x the shipped defaults' work per second of data while \
         locked, {}x while searching (the defaults: some 20 ms of estimator time per 120 s \
         of data on a 2-core x86 VM, several times that on a Pi); time it with `vlsyncd \
         replay --config` on a recording (it prints its estimator time) before running it \
         live, where a daemon that cannot keep up overruns its budget",
        x(rl),
        x(ra)
    ))
}

/// A work ratio as [`work_note`] prints it: a fraction below 1 with one decimal, whole
/// below 100, two significant digits above.
fn ratio_text(r: f64) -> String {
    if r < 1.0 {
        format!("{r:.1}")
    } else if r < 100.0 {
        format!("{r:.0}")
    } else {
        let unit = 10f64.powf(r.log10().floor() - 1.0);
        vlsync_common::text::number((r / unit).round() * unit)
    }
}

/// A note when `daemon.core` names a core this machine does not have online (not an
/// error: the check often runs on another machine than the robot, as for the state
/// file). `cores`: the machine's online CPUs (empty: unknown).
fn core_note(core: i64, cores: &[usize]) -> Option<String> {
    if core < 0 || cores.is_empty() || cores.iter().any(|&c| c as i64 == core) {
        return None;
    }
    let list: Vec<String> = cores.iter().map(|c| c.to_string()).collect();
    Some(format!(
        "note: daemon.core = {core}: not a CPU of this machine (online: [{}]); here the \
         daemon would run unpinned, and say so at start",
        list.join(", ")
    ))
}

/// The kernel's CPU list format (`/sys/devices/system/cpu/online`: `0-3`, `0,2-3`),
/// sorted; `None` when it is not one.
fn parse_cpu_list(text: &str) -> Option<Vec<usize>> {
    let mut cpus = Vec::new();
    for part in text.trim().split(',') {
        let (a, b) = match part.split_once('-') {
            Some((a, b)) => (a.parse::<usize>().ok()?, b.parse::<usize>().ok()?),
            None => {
                let a = part.parse::<usize>().ok()?;
                (a, a)
            }
        };
        // a kernel has at most a few thousand CPUs: a range beyond is no CPU list
        if a > b || b >= 1 << 16 {
            return None;
        }
        cpus.extend(a..=b);
    }
    cpus.sort_unstable();
    cpus.dedup();
    Some(cpus)
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_core_this_machine_lacks_gets_a_note() {
        assert_eq!(super::core_note(1, &[0, 1]), None);
        assert_eq!(super::core_note(-1, &[0]), None);
        assert_eq!(super::core_note(3, &[]), None);
        assert_eq!(super::core_note(3, &[2, 3]), None);
        let n = super::core_note(3, &[0, 1]).unwrap();
        assert!(
            n.starts_with("note: daemon.core = 3: not a CPU of this machine (online: [0, 1])"),
            "{n}"
        );
    }

    /// The shipped defaults, and the settings README's speed table measures, say
    /// nothing; a configuration thousands of times the work gets the note, rounded (a
    /// review's: 118 s of estimator time for 120 s of data on this VM against the
    /// defaults' 19 ms, 6200x; the model, counting blocks as the estimator does, says 6100x).
    #[test]
    fn a_configuration_of_much_more_work_gets_a_note() {
        use vlsync_config::EstimatorConfig;
        let d = EstimatorConfig::default();
        assert_eq!(super::work_note(&d), None);
        let longer = EstimatorConfig {
            window_s: 12.0,
            max_lag_s: 1.0,
            ..d.clone()
        };
        assert_eq!(super::work_note(&longer), None);
        let heavy = EstimatorConfig {
            grid_hz: 2000.0,
            max_lag_s: 2.0,
            track_range_s: 2.0,
            segment_s: 24.0,
            hop_s: 0.05,
            step_window_s: 2.0,
            ..d.clone()
        };
        heavy.validate("heavy").unwrap();
        let n = super::work_note(&heavy).expect("a note");
        assert!(
            n.starts_with("note: estimator: about 6100x the shipped defaults' work per second of data while locked, 2800x while searching"),
            "{n}"
        );
        // less work in one state than the defaults: a fraction, not "0x"
        assert_eq!(super::ratio_text(0.23), "0.2");
        assert_eq!(super::ratio_text(39.4), "39");
        assert_eq!(super::ratio_text(6123.0), "6100");
        let (acq, lock) = super::estimator_work(&heavy);
        let (acq0, lock0) = super::estimator_work(&d);
        assert!(lock / lock0 > 1000.0 && acq / acq0 > 1000.0);
    }

    /// The work model counts the segment's blocks as the estimator keeps them (60 s of
    /// 0.5 s hops: 120, not ceil + 1 = 121) and its lags from the grid it runs.
    #[test]
    fn the_work_model_counts_as_the_estimator_does() {
        use vlsync_config::EstimatorConfig;
        let d = EstimatorConfig::default();
        // ±50 lags; tracking reads 2·(8 + 6 + 8) + 1 = 45 of them; 12 and 120 blocks
        assert_eq!(
            super::estimator_work(&d),
            (
                100.0 * 101.0 + 12.0 * 101.0 / 0.5,
                100.0 * 45.0 + 120.0 * 45.0 / 0.5
            )
        );
        // a grid off whole nanoseconds and a hop off whole grid steps: 0.05 s at
        // 89.8 Hz runs as 4 steps, 555 s of them as 12460 blocks
        let odd = EstimatorConfig {
            grid_hz: 89.8,
            hop_s: 0.05,
            max_lag_s: 1.0,
            window_s: 4.0,
            segment_s: 555.0,
            ..d
        };
        odd.validate("odd").unwrap();
        let (fs, hop) = (odd.effective_grid_hz(), odd.effective_hop_s());
        assert_eq!((odd.lag_slots(), odd.segment_blocks()), (181, 12460));
        let active = 2.0 * (0.08 * fs + 14.0) + 1.0;
        let (_, lock) = super::estimator_work(&odd);
        assert!(
            (lock - (fs * active + 12460.0 * active / hop)).abs() < 1e-6 * lock,
            "{lock}"
        );
    }

    /// The floor on `estimator.highpass_hz` keeps the estimator's own band-pass
    /// finite at every grid rate allowed, while 1e-15 Hz (which the old range 0 ..= 100
    /// accepted) makes it NaN: refused now.
    #[test]
    fn the_highpass_floor_keeps_the_estimators_filter_finite() {
        use vlsync_config::{EstimatorConfig, MIN_HIGHPASS_HZ, MIN_LOWPASS_HZ};
        use vlsync_estimator::filter::BandPass;
        let run = |hp: f64, fs: f64| {
            let mut bp = BandPass::new(hp, MIN_LOWPASS_HZ, fs);
            let n = (60.0 * fs) as usize;
            // the largest output of the last 10 s
            let mut peak: f64 = 0.0;
            for i in 0..n {
                let t = i as f64 / fs;
                let y = bp.step(50.0 + (2.0 * std::f64::consts::PI * t).sin());
                assert!(y.is_finite(), "{hp} Hz at {fs} Hz: sample {i} is {y}");
                if t >= 50.0 {
                    peak = peak.max(y.abs());
                }
            }
            assert!(bp.group_delay_s(0.3).is_finite());
            peak
        };
        for grid_hz in [10.0, 100.0, 2000.0] {
            let c = EstimatorConfig {
                grid_hz,
                highpass_hz: MIN_HIGHPASS_HZ,
                lowpass_hz: MIN_LOWPASS_HZ,
                // two grid steps at 10 Hz
                track_range_s: 0.2,
                ..EstimatorConfig::default()
            };
            c.validate("floor").unwrap();
            let fs = c.effective_grid_hz();
            // the offset of 50 is gone; the 1 Hz motion remains, through the 0.5 Hz
            // low-pass (a gain of 1/√17, 0.24)
            let peak = run(MIN_HIGHPASS_HZ, fs);
            assert!((0.2..0.3).contains(&peak), "{grid_hz} Hz: {peak}");
        }
        // the degenerate cut-off the review found: NaN at once, and refused
        let mut bp = BandPass::new(1e-15, MIN_LOWPASS_HZ, 100.0);
        assert!(bp.step(1.0).is_nan());
        let tiny = EstimatorConfig {
            highpass_hz: 1e-15,
            ..EstimatorConfig::default()
        };
        let e = tiny.validate("tiny").unwrap_err().message;
        assert!(e.contains("`estimator.highpass_hz` = 1e-15"), "{e}");
    }

    #[test]
    fn the_kernels_cpu_lists_are_read() {
        assert_eq!(super::parse_cpu_list("0-3\n"), Some(vec![0, 1, 2, 3]));
        assert_eq!(super::parse_cpu_list("0,2-3"), Some(vec![0, 2, 3]));
        assert_eq!(super::parse_cpu_list("5"), Some(vec![5]));
        for bad in ["", "a", "3-1", "0-", "-2", "0,,1", "0-99999999", "1-2-3"] {
            assert_eq!(super::parse_cpu_list(bad), None, "{bad:?}");
        }
    }

    proptest::proptest! {
        /// Any set of CPUs written as the kernel writes it (runs of consecutive
        /// CPUs as ranges) reads back as that set.
        #[test]
        fn any_cpu_set_reads_back(set in proptest::collection::btree_set(0usize..512, 1..40)) {
            let cpus: Vec<usize> = set.into_iter().collect();
            let mut parts = Vec::new();
            let mut i = 0;
            while i < cpus.len() {
                let mut j = i;
                while j + 1 < cpus.len() && cpus[j + 1] == cpus[j] + 1 {
                    j += 1;
                }
                parts.push(if i == j {
                    cpus[i].to_string()
                } else {
                    format!("{}-{}", cpus[i], cpus[j])
                });
                i = j + 1;
            }
            proptest::prop_assert_eq!(super::parse_cpu_list(&parts.join(",")), Some(cpus));
        }
    }

    use super::*;

    fn file(name: &str, text: &str) -> std::path::PathBuf {
        let p = std::env::temp_dir().join(format!("vlsync-check-{}-{name}", std::process::id()));
        std::fs::write(&p, text).unwrap();
        p
    }

    #[test]
    fn a_partial_file_prints_every_key_with_its_default() {
        let p = file("ok.toml", "[estimator]\nwindow_s = 8.0\n");
        let out = check(&p, true).unwrap();
        assert!(
            out.starts_with(&format!("# {}: ok\n", p.display())),
            "{out}"
        );
        // the whole output is itself a valid file with the same values
        let back = Config::from_toml_str(&out, "printed").unwrap();
        assert_eq!(back.estimator.window_s, 8.0);
        assert_eq!(back, Config::load(&p).unwrap());
        assert!(out.contains("hop_s") && out.contains("[daemon]") && out.contains("prefix"));
        assert_eq!(check(&p, false).unwrap(), format!("{}: ok\n", p.display()));
        let _ = std::fs::remove_file(p);
    }

    #[test]
    fn a_state_file_whose_directory_is_missing_gets_a_note_not_an_error() {
        let missing =
            std::env::temp_dir().join(format!("vlsync-check-nodir-{}", std::process::id()));
        let state = missing.join("vlsync.state");
        let p = file(
            "state.toml",
            &format!("[daemon]\nstate_file = \"{}\"\n", state.display()),
        );
        let out = check(&p, false).unwrap();
        assert!(out.starts_with(&format!("{}: ok\n", p.display())), "{out}");
        assert!(
            out.contains("note: daemon.state_file") && out.contains(&missing.display().to_string()),
            "{out}"
        );
        // with --print the note is a comment: the output stays a valid file
        let printed = check(&p, true).unwrap();
        assert!(printed.contains("# note: daemon.state_file"), "{printed}");
        assert_eq!(
            Config::from_toml_str(&printed, "printed").unwrap(),
            Config::load(&p).unwrap()
        );
        // the directory there: no note
        std::fs::create_dir_all(&missing).unwrap();
        assert_eq!(check(&p, false).unwrap(), format!("{}: ok\n", p.display()));
        // a file where the directory should be
        std::fs::remove_dir(&missing).unwrap();
        std::fs::write(&missing, "").unwrap();
        let out = check(&p, false).unwrap();
        assert!(out.contains("is not a directory"), "{out}");
        let _ = std::fs::remove_file(&missing);
        let _ = std::fs::remove_file(p);
    }

    #[test]
    fn errors_name_the_file_and_the_key() {
        let p = file("bad.toml", "[estimator]\nwindow_s = 500.0\n");
        let e = check(&p, true).unwrap_err();
        assert!(e.contains("window_s") && e.contains("bad.toml"), "{e}");
        let missing = std::env::temp_dir().join("vlsync-check-no-such-file.toml");
        let e = check(&missing, false).unwrap_err();
        assert!(e.contains("no-such-file"), "{e}");
        let _ = std::fs::remove_file(p);
    }
}
