//! Opening input files: regular files only.
//!
//! Opening a named pipe (FIFO) for reading blocks until a writer appears, forever
//! when none does, and a directory or a device is no data file either. The readers
//! of signature, truth, frame and scan files and of recordings check the path first
//! (following symlinks) and refuse anything but a regular file with an error of
//! kind [`std::io::ErrorKind::InvalidInput`] saying "not a regular file", and check
//! the file they opened again, since a named pipe may take the path's place in
//! between: that open does not wait for a writer. (Serial LiDARs are character
//! devices on purpose: they are opened elsewhere.)
//!
//! ```
//! let dir = std::env::temp_dir();
//! let e = vlsync_common::file::read_regular(&dir).unwrap_err();
//! assert_eq!(e.to_string(), "not a regular file (a directory)");
//! ```

use std::fs::File;
use std::io::{self, Read};
use std::path::Path;

/// What `t` is, for the error.
fn kind_of(t: std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return "a named pipe";
        }
        if t.is_char_device() {
            return "a character device";
        }
        if t.is_block_device() {
            return "a block device";
        }
        if t.is_socket() {
            return "a socket";
        }
    }
    if t.is_dir() {
        "a directory"
    } else {
        "not a file"
    }
}

/// `Ok` when `path` is a regular file (following symlinks); otherwise the error of
/// the lookup (e.g. [`io::ErrorKind::NotFound`]) or an `InvalidInput` error
/// "not a regular file (a named pipe)".
pub fn check_regular(path: &Path) -> io::Result<()> {
    regular(&std::fs::metadata(path)?)
}

/// `Ok` for a regular file's metadata, else the `InvalidInput` error saying what it is.
fn regular(m: &std::fs::Metadata) -> io::Result<()> {
    if m.is_file() {
        Ok(())
    } else {
        Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("not a regular file ({})", kind_of(m.file_type())),
        ))
    }
}

/// Opens `path` for reading after [`check_regular`], then checks the file it opened:
/// a named pipe renamed over the path between the check and the open is opened
/// without waiting for a writer (`O_NONBLOCK`, where a plain open would wait forever
/// for one) and refused with the same error.
pub fn open_regular(path: &Path) -> io::Result<File> {
    use std::os::unix::fs::OpenOptionsExt;
    check_regular(path)?;
    // O_NONBLOCK stays set on the file handed out: a regular file's reads ignore it
    let file = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(rustix::fs::OFlags::NONBLOCK.bits() as i32)
        .open(path)?;
    regular(&file.metadata()?)?;
    Ok(file)
}

/// Reads all of `path` after [`check_regular`].
pub fn read_regular(path: &Path) -> io::Result<Vec<u8>> {
    let mut bytes = Vec::new();
    open_regular(path)?.read_to_end(&mut bytes)?;
    Ok(bytes)
}

/// Reads `path` after [`check_regular`], refusing one of more than `max` bytes (a
/// file that cannot be what the caller reads, such as a recording given as a
/// configuration) without reading more than `max + 1` of them. Errors by kind:
/// `NotFound`, `InvalidInput` (not a regular file), `InvalidData` (too large), or the
/// read's own.
pub fn read_regular_at_most(path: &Path, max: u64) -> io::Result<Vec<u8>> {
    let mut bytes = Vec::new();
    open_regular(path)?
        .take(max.saturating_add(1))
        .read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max {
        return Err(io::Error::new(
            io::ErrorKind::InvalidData,
            format!("larger than {max} bytes"),
        ));
    }
    Ok(bytes)
}

/// Reads all of `path` as UTF-8 after [`check_regular`].
pub fn read_regular_to_string(path: &Path) -> io::Result<String> {
    io::read_to_string(open_regular(path)?)
}

/// Whether `a` and `b` name the same file: the same inode when both exist (hard and
/// symbolic links, `./` and `../` spellings included), the same file name in the same
/// (canonical) directory when neither does yet. A writer checks its outputs with it
/// before it truncates anything: an output named like an input would destroy it.
///
/// ```
/// use std::path::Path;
/// let dir = std::env::temp_dir();
/// let f = dir.join(format!("vlsync-same-file-doc-{}", std::process::id()));
/// std::fs::write(&f, "x").unwrap();
/// let spelled = dir.join(".").join(f.file_name().unwrap());
/// assert!(vlsync_common::file::same_file(&f, &spelled));
/// assert!(!vlsync_common::file::same_file(&f, &dir.join("vlsync-no-such-file")));
/// std::fs::remove_file(&f).unwrap();
/// ```
pub fn same_file(a: &Path, b: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (std::fs::metadata(a), std::fs::metadata(b)) {
        (Ok(x), Ok(y)) => x.dev() == y.dev() && x.ino() == y.ino(),
        (Err(_), Err(_)) => match (resolved(a), resolved(b)) {
            (Some(x), Some(y)) => x == y,
            _ => a == b,
        },
        _ => false,
    }
}

/// The directory `p` is in: its parent, or `.` for a bare file name (whose
/// `Path::parent` is the empty path).
pub fn dir_of(p: &Path) -> &Path {
    match p.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    }
}

/// Checks, before a long run whose output is written at its end, that `path` can be
/// written: not a directory, in a directory that exists, and writable: an existing
/// file is opened for writing (not truncated), a new one is created and removed at
/// once (a device or a named pipe is left to the write). Errors name `flag` and the
/// path.
///
/// ```
/// use vlsync_common::file::check_writable;
/// let dir = std::env::temp_dir();
/// assert!(check_writable("--plot", &dir.join("vlsync-doc-probe.svg")).is_ok());
/// assert!(!dir.join("vlsync-doc-probe.svg").exists());
/// let e = check_writable("--plot", &dir).unwrap_err();
/// assert!(e.starts_with("--plot ") && e.ends_with("is a directory"), "{e}");
/// ```
pub fn check_writable(flag: &str, path: &Path) -> Result<(), String> {
    let say = |why: String| format!("{flag} {}: {why}", path.display());
    // a symlink, dangling or not, is checked as the file it names
    let target = link_target(path);
    if is_descriptor(&target) {
        // open already (a pipe's opening would wait for its reader here; a socket,
        // journald's standard output, cannot be opened by path but can be looked at,
        // and is written through the process's own handle); a closed one (`>&-`)
        // does not exist
        return if target.exists() {
            Ok(())
        } else {
            Err(say("is no open descriptor of this process".into()))
        };
    }
    if target.is_dir() {
        return Err(say("is a directory".into()));
    }
    let dir = dir_of(&target);
    if !dir.is_dir() {
        return Err(say(format!("directory {} does not exist", dir.display())));
    }
    if let Ok(m) = std::fs::metadata(&target) {
        if !m.is_file() {
            // a device or a pipe: opening a pipe would wait for its reader here
            return Ok(());
        }
        std::fs::OpenOptions::new()
            .write(true)
            .open(&target)
            .map(drop)
            .map_err(|e| say(format!("cannot be written: {e}")))
    } else {
        std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&target)
            .map_err(|e| say(format!("cannot be created: {e}")))?;
        std::fs::remove_file(&target).map_err(|e| say(format!("cannot remove the probe: {e}")))
    }
}

/// The path a chain of symlinks at `path` ends at (at most 16 links; `path` itself
/// when it is no symlink). The end need not exist: a dangling link names the file
/// a write creates.
fn link_target(path: &Path) -> std::path::PathBuf {
    let mut p = path.to_path_buf();
    for _ in 0..16 {
        // a descriptor's link (`/proc/self/fd/1` -> `pipe:[N]` or the file a shell
        // opened) names no path to write through: kept, and written in place
        if is_descriptor(&p) {
            break;
        }
        match std::fs::symlink_metadata(&p) {
            Ok(m) if m.file_type().is_symlink() => match std::fs::read_link(&p) {
                Ok(t) if t.is_absolute() => p = t,
                Ok(t) => p = dir_of(&p).join(t),
                Err(_) => break,
            },
            _ => break,
        }
    }
    p
}

/// Whether `p` names an open descriptor rather than a file: `/dev/stdout`,
/// `/dev/stderr`, `/dev/stdin`, `/dev/fd/N`, `/proc/self/fd/N`,
/// `/proc/thread-self/fd/N`, `/proc/PID/fd/N`. What it leads to (a pipe, a
/// terminal, a file a shell opened for appending) is written through the descriptor
/// as it is: never replaced by a temporary file, never truncated.
fn is_descriptor(p: &Path) -> bool {
    let Some(s) = p.to_str() else {
        return false;
    };
    if matches!(s, "/dev/stdout" | "/dev/stderr" | "/dev/stdin") || s.starts_with("/dev/fd/") {
        return true;
    }
    let Some(rest) = s.strip_prefix("/proc/") else {
        return false;
    };
    let Some((who, fd)) = rest.split_once("/fd/") else {
        return false;
    };
    (who == "self" || who == "thread-self" || who.bytes().all(|b| b.is_ascii_digit()))
        && !fd.is_empty()
        && fd.bytes().all(|b| b.is_ascii_digit())
}

/// Which of this process's standard output (1) and error (2) `p` names, if either:
/// `/dev/stdout`, `/dev/fd/1`, `/proc/self/fd/1` (or its pid's, or `thread-self`'s).
fn std_stream(p: &Path) -> Option<u8> {
    let s = p.to_str()?;
    let fd = match s {
        "/dev/stdout" => return Some(1),
        "/dev/stderr" => return Some(2),
        _ => match s.strip_prefix("/dev/fd/") {
            Some(fd) => fd,
            None => {
                let (who, fd) = s.strip_prefix("/proc/")?.split_once("/fd/")?;
                let me = std::process::id().to_string();
                if !(who == "self" || who == "thread-self" || who == me) {
                    return None;
                }
                fd
            }
        },
    };
    match fd {
        "1" => Some(1),
        "2" => Some(2),
        _ => None,
    }
}

/// Writes `contents` through the descriptor `p` names ([`is_descriptor`]). Standard
/// output and error are written through the process's own handles, which share the
/// descriptor's offset and flags: a file a shell opened with `>` or `>>` gets the
/// contents where the process's other output goes (never over it), and a pipe, a
/// terminal or a socket (journald) as well. A pipe whose reader stopped reading
/// (`| head`) ends the write quietly: the reader took what it wanted. Any other
/// descriptor is opened again, appending.
fn write_descriptor(p: &Path, contents: &[u8]) -> io::Result<()> {
    use std::io::Write;
    let written = match std_stream(p) {
        Some(1) => {
            let mut out = std::io::stdout().lock();
            out.write_all(contents).and_then(|()| out.flush())
        }
        Some(_) => std::io::stderr().lock().write_all(contents),
        None => {
            let mut f = std::fs::OpenOptions::new().append(true).open(p)?;
            f.write_all(contents).and_then(|()| f.flush())
        }
    };
    match written {
        Err(e) if e.kind() == io::ErrorKind::BrokenPipe => Ok(()),
        r => r,
    }
}

/// Creates the output directory `path` (and its parents) given by option `flag`; an
/// existing directory is fine, an existing file is an error saying so (rather than
/// the system's "File exists").
///
/// ```
/// use vlsync_common::file::create_out_dir;
/// let file = std::env::temp_dir().join(format!("vlsync-doc-outdir-{}", std::process::id()));
/// std::fs::write(&file, "x").unwrap();
/// let e = create_out_dir("--out", &file).unwrap_err();
/// assert!(e.ends_with("exists and is not a directory"), "{e}");
/// std::fs::remove_file(&file).unwrap();
/// ```
pub fn create_out_dir(flag: &str, path: &Path) -> Result<(), String> {
    if path.exists() && !path.is_dir() {
        return Err(format!(
            "{flag} {}: exists and is not a directory",
            path.display()
        ));
    }
    std::fs::create_dir_all(path).map_err(|e| {
        format!(
            "{flag} {}: cannot create the directory: {e}",
            path.display()
        )
    })
}

/// Writes `contents` to `path` so that a failure leaves no partial file: into a
/// temporary file beside it, renamed over it once complete (an error removes the
/// temporary file and leaves an earlier `path` as it was). A file written over keeps
/// its permissions, and its owner and group where the process may give them (root);
/// a symlink's target is written, not the link. Standard output and error
/// (`/dev/stdout`, `/dev/fd/1`, `/proc/self/fd/2`, ...) are written through the
/// process's own handles, where its other output goes (a shell's `>` or `>>` file, a
/// pipe, a terminal, journald's socket); another descriptor is opened again,
/// appending; a path that exists and is not a regular file (a device, a named pipe)
/// is written directly, and so is an existing file in a directory where no temporary
/// file can be created (it is writable, its directory is not). Errors name `path`.
///
/// ```
/// use vlsync_common::file::write_atomically;
/// let p = std::env::temp_dir().join(format!("vlsync-doc-atomic-{}.csv", std::process::id()));
/// write_atomically(&p, b"t,value\n").unwrap();
/// assert_eq!(std::fs::read_to_string(&p).unwrap(), "t,value\n");
/// std::fs::remove_file(&p).unwrap();
/// ```
pub fn write_atomically(path: &Path, contents: &[u8]) -> Result<(), String> {
    use std::io::Write;
    let say = |e: io::Error| format!("cannot write {}: {e}", path.display());
    let target = link_target(path);
    if is_descriptor(&target) {
        return write_descriptor(&target, contents).map_err(say);
    }
    let existing = std::fs::metadata(&target).ok();
    if existing.as_ref().is_some_and(|m| !m.is_file()) {
        return std::fs::write(&target, contents).map_err(say);
    }
    let name = target
        .file_name()
        .ok_or_else(|| format!("cannot write {}: no file name", path.display()))?;
    let tmp = dir_of(&target).join(format!(
        ".{}.tmp-{}",
        name.to_string_lossy(),
        std::process::id()
    ));
    // a new file of our own: never one planted under the name (a link to another
    // file, which would be truncated and then renamed over the output); a leftover
    // of ours (a crash) or a planted entry is removed first, itself, not what it names
    let create = || {
        std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)
    };
    let created = match create() {
        Err(e) if e.kind() == io::ErrorKind::AlreadyExists => {
            std::fs::remove_file(&tmp).and_then(|()| create())
        }
        r => r,
    };
    let mut f = match created {
        Ok(f) => f,
        // the directory refuses new files, the file itself may still be writable
        Err(e) if existing.is_some() && e.kind() == io::ErrorKind::PermissionDenied => {
            return std::fs::write(&target, contents).map_err(say);
        }
        Err(e) => return Err(say(e)),
    };
    // a file written over keeps its owner and group where this process may give it
    // them (root writing over a user's output); otherwise it becomes this user's, as
    // any file replaced through its directory does
    if let Some(m) = &existing {
        let _ = keep_owner(&f, m);
    }
    let written = (|| {
        if let Some(m) = &existing {
            f.set_permissions(m.permissions())?;
        }
        f.write_all(contents)?;
        f.sync_all()?;
        drop(f);
        std::fs::rename(&tmp, &target)
    })();
    written.map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        say(e)
    })
}

/// Gives `f` the owner and group of `was` where they differ (a no-op for one's own
/// files; root replacing another user's file keeps it theirs).
fn keep_owner(f: &File, was: &std::fs::Metadata) -> io::Result<()> {
    use std::os::unix::fs::MetadataExt;
    let now = f.metadata()?;
    if (now.uid(), now.gid()) == (was.uid(), was.gid()) {
        return Ok(());
    }
    std::os::unix::fs::fchown(f, Some(was.uid()), Some(was.gid()))
}

/// `p`'s directory made canonical, joined with its file name.
fn resolved(p: &Path) -> Option<std::path::PathBuf> {
    let name = p.file_name()?;
    Some(std::fs::canonicalize(dir_of(p)).ok()?.join(name))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::FileTypeExt;
    use std::path::PathBuf;

    #[test]
    fn atomic_writes_replace_whole_files_keep_links_and_permissions_and_leave_no_temporary() {
        let dir = std::env::temp_dir().join(format!("vlsync-atomic-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("est.csv");
        write_atomically(&p, b"old\n").unwrap();
        // written over, it keeps its permissions
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o600)).unwrap();
        write_atomically(&p, b"older\n").unwrap();
        let mode = std::fs::metadata(&p).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, 0o600);
        // another user's file, written over by root, stays theirs (the suite runs as
        // root in CI; a user who may not give files away replaces it with their own)
        use std::os::unix::fs::MetadataExt;
        if std::fs::metadata(&p).unwrap().uid() == 0 {
            std::os::unix::fs::chown(&p, Some(65534), Some(65534)).unwrap();
            write_atomically(&p, b"theirs\n").unwrap();
            let m = std::fs::metadata(&p).unwrap();
            assert_eq!((m.uid(), m.gid(), m.mode() & 0o777), (65534, 65534, 0o600));
            assert_eq!(std::fs::read_to_string(&p).unwrap(), "theirs\n");
            std::os::unix::fs::chown(&p, Some(0), Some(0)).unwrap();
        }
        // through a symlink: the file it names is replaced, the link stays
        let link = dir.join("link.csv");
        std::os::unix::fs::symlink(&p, &link).unwrap();
        write_atomically(&link, b"new\n").unwrap();
        assert!(std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink());
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "new\n");
        // a device is written directly (and /dev/full fails, naming the path)
        let e = write_atomically(Path::new("/dev/full"), b"x").unwrap_err();
        assert!(e.starts_with("cannot write /dev/full: "), "{e}");
        assert!(std::fs::metadata("/dev/full")
            .unwrap()
            .file_type()
            .is_char_device());
        // a directory that does not exist: an error naming the path
        let e = write_atomically(&dir.join("no/such.csv"), b"x").unwrap_err();
        assert!(e.contains("no/such.csv"), "{e}");
        // a dangling symlink: the file it names is created, the link stays
        let dangling = dir.join("dangling.csv");
        std::os::unix::fs::symlink("made.csv", &dangling).unwrap();
        assert!(check_writable("--out", &dangling).is_ok());
        write_atomically(&dangling, b"made\n").unwrap();
        assert_eq!(
            std::fs::read_to_string(dir.join("made.csv")).unwrap(),
            "made\n"
        );
        assert!(std::fs::symlink_metadata(&dangling)
            .unwrap()
            .file_type()
            .is_symlink());
        // no temporary file is left beside the outputs
        let mut left: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .collect();
        left.sort();
        assert_eq!(left, ["dangling.csv", "est.csv", "link.csv", "made.csv"]);
        // a named pipe is not opened by the probe (that would wait for a reader)
        let fifo = dir.join("fifo");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        assert!(made.is_ok_and(|s| s.success()), "mkfifo {}", fifo.display());
        assert!(check_writable("--out", &fifo).is_ok());
        std::fs::remove_file(&fifo).unwrap();
        // the probe: writable paths pass and leave nothing; others name the flag
        assert!(check_writable("--out", &dir.join("new.csv")).is_ok());
        assert!(!dir.join("new.csv").exists());
        assert!(check_writable("--out", &p).is_ok());
        assert_eq!(
            std::fs::read_to_string(&p).unwrap(),
            "new\n",
            "not truncated"
        );
        for (bad, why) in [
            (dir.clone(), "is a directory"),
            (dir.join("no/such.csv"), "does not exist"),
            (PathBuf::from("/proc/vlsync-probe.svg"), "cannot be created"),
        ] {
            let e = check_writable("--plot", &bad).unwrap_err();
            assert!(e.starts_with("--plot ") && e.contains(why), "{e}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn only_regular_files_are_read() {
        let dir = std::env::temp_dir().join(format!("vlsync-common-file-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let f = dir.join("a.txt");
        std::fs::write(&f, "x\n").unwrap();
        assert_eq!(read_regular(&f).unwrap(), b"x\n");
        assert_eq!(read_regular_to_string(&f).unwrap(), "x\n");
        let e = read_regular(&dir).unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::InvalidInput);
        assert!(e.to_string().contains("not a regular file"), "{e}");
        let e = read_regular(&dir.join("missing")).unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::NotFound);
        // a FIFO without a writer: refused at once instead of blocking in open()
        let fifo = dir.join("fifo");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        assert!(made.is_ok_and(|s| s.success()), "mkfifo {}", fifo.display());
        let e = read_regular_to_string(&fifo).unwrap_err();
        assert_eq!(e.to_string(), "not a regular file (a named pipe)");
        // /dev/null is a character device
        if Path::new("/dev/null").exists() {
            let e = open_regular(Path::new("/dev/null")).unwrap_err();
            assert!(e.to_string().contains("character device"), "{e}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A named pipe renamed over the path between the type check and the open is
    /// refused, not waited on: a reader opening in a loop while the path flips
    /// between a regular file and a FIFO without a writer always returns (the open
    /// used to block for good once the FIFO came in between).
    #[test]
    fn a_named_pipe_swapped_in_after_the_check_does_not_block_the_open() {
        use std::sync::atomic::{AtomicBool, Ordering};
        use std::sync::Arc;
        let dir = std::env::temp_dir().join(format!("vlsync-swap-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let (file, fifo, path) = (dir.join("file"), dir.join("fifo"), dir.join("input"));
        std::fs::write(&file, "x\n").unwrap();
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        assert!(made.is_ok_and(|s| s.success()), "mkfifo {}", fifo.display());
        std::fs::copy(&file, &path).unwrap();
        let stop = Arc::new(AtomicBool::new(false));
        let swapper = {
            let (stop, dir, path) = (stop.clone(), dir.clone(), path.clone());
            let (file, fifo) = (file.clone(), fifo.clone());
            std::thread::spawn(move || {
                let tmp = dir.join("tmp");
                while !stop.load(Ordering::Relaxed) {
                    for src in [&fifo, &file] {
                        let _ = std::fs::remove_file(&tmp);
                        std::fs::hard_link(src, &tmp).unwrap();
                        std::fs::rename(&tmp, &path).unwrap();
                    }
                }
            })
        };
        let (tx, rx) = std::sync::mpsc::channel();
        let reader = {
            let path = path.clone();
            std::thread::spawn(move || {
                let t0 = std::time::Instant::now();
                let (mut files, mut pipes) = (0, 0);
                while t0.elapsed() < std::time::Duration::from_secs(2) {
                    match open_regular(&path) {
                        Ok(_) => files += 1,
                        Err(e) => {
                            assert_eq!(e.to_string(), "not a regular file (a named pipe)");
                            pipes += 1;
                        }
                    }
                }
                let _ = tx.send((files, pipes));
            })
        };
        let done = rx.recv_timeout(std::time::Duration::from_secs(20));
        if done.is_err() {
            // the reader is stuck in open(): a writer's open lets it go
            let _ = std::fs::OpenOptions::new().write(true).open(&fifo);
        }
        stop.store(true, Ordering::Relaxed);
        swapper.join().unwrap();
        let read = reader.join();
        std::fs::remove_dir_all(&dir).unwrap();
        let (files, pipes) = done.expect("an open waited for a writer on the named pipe");
        assert!(read.is_ok());
        assert!(files > 0 && pipes > 0, "{files} files, {pipes} pipes");
    }

    #[test]
    fn a_link_planted_as_the_temporary_file_is_not_followed() {
        let dir = std::env::temp_dir().join(format!("vlsync-planted-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let victim = dir.join("victim");
        std::fs::write(&victim, "keep me\n").unwrap();
        let out = dir.join("est.csv");
        let tmp = dir.join(format!(".est.csv.tmp-{}", std::process::id()));
        std::os::unix::fs::symlink(&victim, &tmp).unwrap();
        write_atomically(&out, b"t,offset\n").unwrap();
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), "keep me\n");
        assert_eq!(std::fs::read_to_string(&out).unwrap(), "t,offset\n");
        assert!(!std::fs::symlink_metadata(&out)
            .unwrap()
            .file_type()
            .is_symlink());
        assert!(std::fs::symlink_metadata(&tmp).is_err(), "nothing left");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn descriptors_are_written_through_appending_never_replaced() {
        use std::os::fd::AsRawFd;
        for (p, yes) in [
            ("/dev/stdout", true),
            ("/dev/fd/3", true),
            ("/proc/self/fd/1", true),
            ("/proc/thread-self/fd/12", true),
            ("/proc/4242/fd/0", true),
            ("/proc/self/fd/", false),
            ("/proc/self/fdinfo/1", false),
            ("/proc/self/fd/x", false),
            ("/tmp/dev/stdout", false),
        ] {
            assert_eq!(is_descriptor(Path::new(p)), yes, "{p}");
        }
        let me = std::process::id();
        for (p, want) in [
            ("/dev/stdout".to_string(), Some(1)),
            ("/dev/stderr".to_string(), Some(2)),
            ("/dev/fd/1".to_string(), Some(1)),
            ("/proc/self/fd/2".to_string(), Some(2)),
            (format!("/proc/{me}/fd/1"), Some(1)),
            (format!("/proc/{}/fd/1", me + 1), None),
            ("/proc/self/fd/3".to_string(), None),
            ("/dev/fd/10".to_string(), None),
        ] {
            assert_eq!(std_stream(Path::new(&p)), want, "{p}");
        }
        let dir = std::env::temp_dir().join(format!("vlsync-fd-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        // a shell's `cmd --out /dev/stdout >> log`: the log keeps its lines
        let log = dir.join("app.log");
        std::fs::write(&log, "earlier line\n").unwrap();
        let held = std::fs::OpenOptions::new().append(true).open(&log).unwrap();
        let fd = PathBuf::from(format!("/proc/self/fd/{}", held.as_raw_fd()));
        check_writable("--out", &fd).unwrap();
        write_atomically(&fd, b"t,offset\n").unwrap();
        assert_eq!(
            std::fs::read_to_string(&log).unwrap(),
            "earlier line\nt,offset\n"
        );
        // the same through a symlink to the descriptor, as /dev/stdout is one
        let link = dir.join("out");
        std::os::unix::fs::symlink(&fd, &link).unwrap();
        write_atomically(&link, b"1,2\n").unwrap();
        assert_eq!(
            std::fs::read_to_string(&log).unwrap(),
            "earlier line\nt,offset\n1,2\n"
        );
        let left: Vec<_> = std::fs::read_dir(&dir).unwrap().collect();
        assert_eq!(left.len(), 2, "no temporary file beside the log");
        drop(held);
        // a descriptor this process does not hold
        let e = check_writable("--out", Path::new("/proc/self/fd/987654")).unwrap_err();
        assert!(e.contains("no open descriptor"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
