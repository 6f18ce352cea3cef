//! One daemon per prefix: the `flock` on `/tmp/vlsync/<prefix>.lock` (see the
//! module above, "One daemon per prefix").

use super::*;

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
    use std::os::unix::fs::MetadataExt;
    let path = lock_path(prefix);
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)
            .map_err(|e| format!("cannot create lock directory {}: {e}", dir.display()))?;
    }
    // a few rounds at most: each retry means another daemon released the file
    // between our open and our lock
    for _ in 0..8 {
        let mut f = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(|e| format!("cannot open lock file {}: {e}", path.display()))?;
        match f.try_lock() {
            Ok(()) => {
                let ours = f.metadata().map(|m| (m.dev(), m.ino())).ok();
                let at_path = std::fs::metadata(&path).map(|m| (m.dev(), m.ino())).ok();
                if ours.is_none() || ours != at_path {
                    continue; // the holder removed it after our open: lock the new one
                }
                f.set_len(0)
                    .and_then(|_| writeln!(f, "{}", std::process::id()))
                    .map_err(|e| format!("cannot write lock file {}: {e}", path.display()))?;
                return Ok(InstanceLock { path, _file: f });
            }
            Err(std::fs::TryLockError::WouldBlock) => {
                let holder = std::fs::read_to_string(&path).unwrap_or_default();
                return Err(format!(
                    "another vlsyncd already serves prefix `{prefix}` (lock {} held by pid {})",
                    path.display(),
                    holder.trim()
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
