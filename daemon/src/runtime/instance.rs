//! One daemon per prefix: the `flock` on `/tmp/vlsync/<prefix>.lock` (see the
//! module above, "One daemon per prefix").

use super::*;
use std::io::Read;

/// The most of a held lock file read for the error's pid (a pid is at most 7 digits;
/// the rest of a longer file is not the pid anyway).
const LOCK_READ_MAX: usize = 64;

/// `/tmp/vlsync/<prefix with / as %>.lock`
pub fn lock_path(prefix: &str) -> PathBuf {
    Path::new("/tmp/vlsync").join(format!("{}.lock", prefix.replace('/', "%")))
}

/// The single-instance lock of a prefix: held while this value lives; dropping it
/// removes the lock file (a daemon killed without that leaves the file, and the
/// next one takes it over: only the lock on it counts, never its existence).
#[derive(Debug)]
pub struct InstanceLock {
    pub(super) path: PathBuf,
    pub(super) _file: File,
}

impl Drop for InstanceLock {
    fn drop(&mut self) {
        // unlinked while still locked: a daemon that opened the old file meanwhile
        // sees its inode gone from the path and tries again (see single_instance_lock)
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Takes the single-instance lock of `prefix`.
pub fn single_instance_lock(prefix: &str) -> Result<InstanceLock, String> {
    let path = lock_path(prefix);
    if let Some(dir) = path.parent() {
        // writable by its owner only, whatever the umask ([`check_lock_dir`])
        use std::os::unix::fs::DirBuilderExt;
        std::fs::DirBuilder::new()
            .recursive(true)
            .mode(0o755)
            .create(dir)
            .map_err(|e| format!("cannot create lock directory {}: {e}", dir.display()))?;
    }
    lock_file(path, prefix)
}

/// Refuses a lock directory another user could plant the lock file in, or unlink a
/// held lock from (a second daemon would then start on the prefix): one anybody may
/// write without the sticky bit, whoever owns it, or one owned by neither this user
/// nor root that its group may write without it. (`/tmp/vlsync` as the units'
/// tmpfiles.d entry makes it, the units' user's and `rwxr-xr-x`, serves root too, and
/// so does `/tmp` itself, sticky; a link planted in any directory is refused by the
/// open itself, [`lock_file`].)
fn check_lock_dir(dir: &Path) -> Result<(), String> {
    use std::os::unix::fs::MetadataExt;
    let m = std::fs::metadata(dir)
        .map_err(|e| format!("cannot read lock directory {}: {e}", dir.display()))?;
    let me = rustix::process::geteuid().as_raw();
    let sticky = m.mode() & 0o1000 != 0;
    let (group_w, world_w) = (m.mode() & 0o020 != 0, m.mode() & 0o002 != 0);
    let foreign = m.uid() != me && m.uid() != 0;
    if !sticky && (world_w || (group_w && foreign)) {
        return Err(format!(
            "refusing lock directory {}: {} may write it (mode {:o}, no sticky bit; owner uid \
             {}), so another user could plant the lock file or remove a held one; with no \
             vlsyncd running, remove it, or make it writable by its owner only (chmod 755)",
            dir.display(),
            if world_w { "anybody" } else { "its group" },
            m.mode() & 0o7777,
            m.uid()
        ));
    }
    Ok(())
}

/// Takes the lock on `path` (its directory exists).
///
/// The file is opened without following a symbolic link (`O_NOFOLLOW`), and must be a
/// regular file with a single name: in `/tmp`, another user could otherwise point the
/// lock at a file of root's (`/etc/...`), which a root daemon would truncate for its
/// pid. Its directory is checked first ([`check_lock_dir`]).
///
/// A lock file this user may not write (a daemon run by hand as root left it, and the
/// unit's user meets it) is opened read-only instead: `flock` needs no write access.
/// Locked, it proves no daemon uses it, so it is replaced by a file of our own where the
/// directory lets us (the units' tmpfiles.d entry gives `/tmp/vlsync` to their user);
/// where not, the read-only lock serves as it is, without our pid in it.
pub(super) fn lock_file(path: PathBuf, prefix: &str) -> Result<InstanceLock, String> {
    use std::os::unix::fs::{MetadataExt, OpenOptionsExt};
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        check_lock_dir(dir)?;
    }
    // a link at the path is refused, by the open itself (ELOOP) and named here
    let refused = |e: std::io::Error| {
        let link = std::fs::symlink_metadata(&path).is_ok_and(|m| m.file_type().is_symlink());
        if link {
            format!(
                "cannot open lock file {}: it is a symbolic link, refused (another user may \
                 have planted it; with no vlsyncd running, remove it)",
                path.display()
            )
        } else {
            format!("cannot open lock file {}: {e}", path.display())
        }
    };
    // a few rounds at most: each retry means another daemon released the file
    // between our open and our lock, or we replaced a file we could not write
    for _ in 0..8 {
        let (mut f, writable) = match std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .custom_flags(vlsync_ipc::O_NOFOLLOW | vlsync_ipc::O_NONBLOCK)
            .open(&path)
        {
            Ok(f) => (f, true),
            Err(e) if e.kind() == std::io::ErrorKind::PermissionDenied => {
                match std::fs::OpenOptions::new()
                    .read(true)
                    // a FIFO planted there would block this open until a writer came
                    .custom_flags(vlsync_ipc::O_NOFOLLOW | vlsync_ipc::O_NONBLOCK)
                    .open(&path)
                {
                    Ok(f) => (f, false),
                    Err(_) => {
                        return Err(format!(
                            "cannot open lock file {}: {e} (it or its directory belongs to \
                             another user: with no vlsyncd running, remove the file, or give \
                             the directory to this user)",
                            path.display()
                        ))
                    }
                }
            }
            Err(e) => return Err(refused(e)),
        };
        // a hard link to another file (or a device, a pipe) planted under the name
        match f.metadata() {
            Ok(m) if m.is_file() && m.nlink() == 1 => {}
            // removed by a daemon that released it between our open and now: try again
            Ok(m) if m.is_file() && m.nlink() == 0 => continue,
            Ok(m) => {
                return Err(format!(
                    "refusing lock file {}: {} (another user may have planted it; with no \
                     vlsyncd running, remove it)",
                    path.display(),
                    if m.is_file() {
                        format!("it has {} names (hard links)", m.nlink())
                    } else {
                        "it is not a regular file".to_string()
                    }
                ))
            }
            Err(e) => return Err(format!("cannot read lock file {}: {e}", path.display())),
        }
        match f.try_lock() {
            Ok(()) => {
                let ours = f.metadata().map(|m| (m.dev(), m.ino())).ok();
                let at_path = std::fs::metadata(&path).map(|m| (m.dev(), m.ino())).ok();
                if ours.is_none() || ours != at_path {
                    continue; // the holder removed it after our open: lock the new one
                }
                if !writable {
                    if std::fs::remove_file(&path).is_ok() {
                        continue; // a stale file of another user: make our own
                    }
                    return Ok(InstanceLock { path, _file: f });
                }
                f.set_len(0)
                    .and_then(|_| writeln!(f, "{}", std::process::id()))
                    .map_err(|e| format!("cannot write lock file {}: {e}", path.display()))?;
                return Ok(InstanceLock { path, _file: f });
            }
            Err(std::fs::TryLockError::WouldBlock) => {
                // the holder wrote its pid; anything else there (another program's file,
                // however large) is read no further than a pid's length and quoted clipped
                // read from the file opened (without following links), not the path
                let mut head = Vec::with_capacity(LOCK_READ_MAX);
                let _ = (&f).take(LOCK_READ_MAX as u64).read_to_end(&mut head);
                let head = String::from_utf8_lossy(&head);
                let holder = match head.trim() {
                    "" => "unknown".to_string(),
                    h => vlsync_common::text::clip(h),
                };
                return Err(format!(
                    "another vlsyncd already serves prefix `{prefix}` (lock {} held by pid {holder})",
                    path.display(),
                ));
            }
            Err(std::fs::TryLockError::Error(e)) => {
                return Err(format!("cannot lock {}: {e}", path.display()))
            }
        }
    }
    Err(format!(
        "cannot take the lock {}: it was replaced 8 times in a row while locking",
        path.display()
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::{MetadataExt, PermissionsExt};

    /// Says that a test skipped its check for want of root (`why`: "test: reason"), as
    /// `vlsync_tests::skipped` does (this crate cannot use it): on stderr, and as a line
    /// of the file `VLSYNC_SKIP_LOG` names, which `scripts/test.sh` lists after its
    /// summary (cargo counts a skipped test as passed).
    fn skipped(why: &str) {
        eprintln!("SKIPPED {why}");
        if let Some(log) = std::env::var_os("VLSYNC_SKIP_LOG") {
            use std::io::Write;
            let f = std::fs::OpenOptions::new().append(true).open(log);
            let _ = f.and_then(|mut f| f.write_all(format!("{why}\n").as_bytes()));
        }
    }

    /// Run as `nobody` by the test below: takes the lock in `VLSYNC_LOCK_CHILD_DIR` and
    /// prints what it found, one line per fact.
    fn child(dir: &Path) {
        let path = dir.join("p.lock");
        match lock_file(path.clone(), "p") {
            Ok(l) => {
                let m = std::fs::metadata(&path).unwrap();
                let text = std::fs::read_to_string(&path).unwrap();
                println!("locked uid={} text={}", m.uid(), text.trim());
                drop(l);
                println!("left={}", path.exists());
            }
            Err(e) => println!("error {e}"),
        }
    }

    /// A symbolic link or a hard link planted under the lock file's name (another
    /// user's, in `/tmp/vlsync`) is refused, naming the path, and what it points at is
    /// left as it was (a root daemon used to truncate it for its pid).
    #[test]
    fn a_link_planted_as_the_lock_file_is_refused() {
        let dir = std::env::temp_dir().join(format!("vlsync-lock-link-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let victim = dir.join("precious");
        std::fs::write(&victim, "keep me\n").unwrap();
        let path = dir.join("p.lock");
        std::os::unix::fs::symlink(&victim, &path).unwrap();
        let e = lock_file(path.clone(), "p").unwrap_err();
        assert!(
            e.contains(&path.display().to_string()) && e.contains("symbolic link"),
            "{e}"
        );
        // a dangling link is not followed to create its target either
        let ghost = dir.join("ghost");
        std::fs::remove_file(&path).unwrap();
        std::os::unix::fs::symlink(&ghost, &path).unwrap();
        assert!(lock_file(path.clone(), "p")
            .unwrap_err()
            .contains("symbolic link"));
        assert!(!ghost.exists());
        // a second name of the victim
        std::fs::remove_file(&path).unwrap();
        std::fs::hard_link(&victim, &path).unwrap();
        let e = lock_file(path.clone(), "p").unwrap_err();
        assert!(e.contains("2 names (hard links)"), "{e}");
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), "keep me\n");
        // removed, the lock is taken as ever
        std::fs::remove_file(&path).unwrap();
        drop(lock_file(path.clone(), "p").unwrap());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A lock directory of another user that others may write without the sticky bit
    /// is refused, naming it and its owner; with the sticky bit (as `/tmp`), or not
    /// writable by others (as the units' `/tmp/vlsync`), it serves. Needs root (a
    /// directory of another user).
    #[test]
    fn a_lock_directory_others_can_write_into_is_refused() {
        if rustix::process::geteuid().as_raw() != 0 {
            skipped(
                "a_lock_directory_others_can_write_into_is_refused: not root, \
                 no directory of another user can be made",
            );
            return;
        }
        const NOBODY: u32 = 65534;
        let dir = std::env::temp_dir().join(format!("vlsync-lock-dir-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        std::os::unix::fs::chown(&dir, Some(NOBODY), Some(NOBODY)).unwrap();
        let path = dir.join("p.lock");
        let mode = |m: u32| std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(m));
        mode(0o777).unwrap();
        let e = lock_file(path.clone(), "p").unwrap_err();
        assert!(
            e.starts_with(&format!("refusing lock directory {}", dir.display()))
                && e.contains(&format!("owner uid {NOBODY}"))
                && e.contains("anybody may write it (mode 777"),
            "{e}"
        );
        assert!(!path.exists());
        mode(0o775).unwrap();
        assert!(lock_file(path.clone(), "p").is_err());
        for ok in [0o1777, 0o755] {
            mode(ok).unwrap();
            drop(lock_file(path.clone(), "p").unwrap());
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A directory anybody may write without the sticky bit is refused even when it
    /// is this user's (anybody could remove a held lock and start a second daemon);
    /// its group may write it when it is this user's. A FIFO planted under the lock's
    /// name is refused as no regular file (the read-write open of one's own FIFO does
    /// not block; the read-only fallback, which would, opens with `O_NONBLOCK` too,
    /// which this test cannot reach: it needs a FIFO this user may not write).
    #[test]
    fn a_lock_directory_anybody_can_write_into_is_refused_whoever_owns_it() {
        let dir = std::env::temp_dir().join(format!("vlsync-lock-own-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("p.lock");
        let mode = |m: u32| std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(m));
        mode(0o777).unwrap();
        let e = lock_file(path.clone(), "p").unwrap_err();
        assert!(e.contains("anybody may write it (mode 777"), "{e}");
        for ok in [0o775, 0o1777, 0o755] {
            mode(ok).unwrap();
            drop(lock_file(path.clone(), "p").unwrap());
        }
        // a FIFO planted under the name is refused at once, not waited on
        let _ = std::fs::remove_file(&path);
        let made = std::process::Command::new("mkfifo").arg(&path).status();
        assert!(made.is_ok_and(|s| s.success()), "mkfifo {}", path.display());
        let e = lock_file(path.clone(), "p").unwrap_err();
        assert!(e.contains("it is not a regular file"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A held lock file that holds something else than a pid (another program's,
    /// however large) is read no further than a pid's length, and quoted clipped.
    #[test]
    fn a_held_lock_file_is_quoted_clipped_and_not_read_whole() {
        let dir = std::env::temp_dir().join(format!("vlsync-lock-big-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("q.lock");
        std::fs::write(&path, "x".repeat(1 << 20)).unwrap();
        // flock belongs to the open file: another open of it in this process conflicts
        let holder = File::open(&path).unwrap();
        holder.try_lock().unwrap();
        let e = lock_file(path.clone(), "q").unwrap_err();
        assert!(
            e.starts_with("another vlsyncd already serves prefix `q`") && e.len() < 300,
            "{e}"
        );
        assert!(
            e.contains(&format!("held by pid {}…)", "x".repeat(40))),
            "{e}"
        );
        drop(holder);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A daemon of the units' user meets the lock file a daemon run by hand as root
    /// left behind (`rw-r--r--`, root's): it takes the lock all the same and replaces
    /// the file where the directory is its own; where not, it holds a read-only lock.
    /// A file root still holds locked is refused as before. Needs root (two users).
    #[test]
    fn a_lock_file_left_by_another_user_does_not_stop_the_daemon() {
        if let Some(dir) = std::env::var_os("VLSYNC_LOCK_CHILD_DIR") {
            child(Path::new(&dir));
            return;
        }
        if !std::fs::metadata("/proc/self").is_ok_and(|m| m.uid() == 0) {
            skipped(
                "a_lock_file_left_by_another_user_does_not_stop_the_daemon: not root, \
                 a second user cannot be played",
            );
            return;
        }
        const NOBODY: u32 = 65534;
        let base = std::env::temp_dir().join(format!("vlsync-lock-users-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&base);
        std::fs::create_dir_all(&base).unwrap();
        std::fs::set_permissions(&base, std::fs::Permissions::from_mode(0o755)).unwrap();
        // the test binary where `nobody` may run it, whatever the checkout's permissions
        let exe = base.join("t");
        std::fs::copy(std::env::current_exe().unwrap(), &exe).unwrap();
        let run_as_nobody = |dir: &Path| -> String {
            let out = std::process::Command::new("setpriv")
                .args([
                    &format!("--reuid={NOBODY}"),
                    &format!("--regid={NOBODY}"),
                    "--clear-groups",
                ])
                .arg(&exe)
                .args([
                    "--exact",
                    "runtime::instance::tests::a_lock_file_left_by_another_user_does_not_stop_the_daemon",
                    "--nocapture",
                    "--test-threads=1",
                ])
                .env("VLSYNC_LOCK_CHILD_DIR", dir)
                .output()
                .expect("setpriv (util-linux) runs");
            let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
            assert!(
                out.status.success(),
                "{stdout}{}",
                String::from_utf8_lossy(&out.stderr)
            );
            stdout
        };
        let stale = |dir: &Path| {
            let p = dir.join("p.lock");
            std::fs::write(&p, "4242\n").unwrap();
            std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o644)).unwrap();
            p
        };
        // the directory is nobody's (as tmpfiles.d makes /tmp/vlsync the units' user's)
        let own = base.join("own");
        std::fs::create_dir(&own).unwrap();
        std::os::unix::fs::chown(&own, Some(NOBODY), Some(NOBODY)).unwrap();
        stale(&own);
        let out = run_as_nobody(&own);
        assert!(out.contains(&format!("locked uid={NOBODY} text=")), "{out}");
        assert!(
            !out.contains("text=4242"),
            "the stale pid is replaced: {out}"
        );
        assert!(out.contains("left=false"), "{out}");
        // the directory is root's: the stale file stays, locked read-only
        let roots = base.join("roots");
        std::fs::create_dir(&roots).unwrap();
        std::fs::set_permissions(&roots, std::fs::Permissions::from_mode(0o755)).unwrap();
        let p = stale(&roots);
        let out = run_as_nobody(&roots);
        assert!(out.contains("locked uid=0 text=4242"), "{out}");
        assert!(out.contains("left=true"), "{out}");
        // root's daemon still runs: refused, naming the holder
        let held = lock_file(p, "p").unwrap();
        let out = run_as_nobody(&roots);
        assert!(
            out.contains("error another vlsyncd already serves prefix `p`")
                && out.contains(&format!("held by pid {}", std::process::id())),
            "{out}"
        );
        drop(held);
        // no file and a directory it may not write: the error says what to do
        let out = run_as_nobody(&roots);
        assert!(
            out.contains("error cannot open lock file")
                && out.contains("Permission denied")
                && out.contains("give the directory to this user"),
            "{out}"
        );
        std::fs::remove_dir_all(&base).unwrap();
    }
}
