//! The C ABI of the vlsync client: `libvlsync_client.so` and `include/vlsync_client.h`
//! (with a C++ wrapper, `include/vlsync_client.hpp`).
//!
//! C and C++ processes on the robot read the daemon's offset through this library
//! instead of iceoryx2's own C/C++ bindings, which must be built from iceoryx2's
//! source at exactly the daemon's release (crates.io carries no C bindings of 0.10).
//! The library is [`vlsync_ipc::OffsetClient`] behind a handle: the same services,
//! the same validation of every payload, the same conversion of camera stamps.
//!
//! Every function checks its pointers (NULL is an error, not a crash), finds its handle
//! among the open ones before it touches it (a closed or made-up handle is an error, not
//! a use-after-free), catches any panic at the boundary, and reports errors as a return
//! code; the functions that take an `err, err_len` buffer also write the reason there.
//! Four take none (`vlsync_client_latest`, `vlsync_client_camera_to_lidar`,
//! `vlsync_client_close`, `vlsync_client_invalid_count`; `vlsync_status_close` and
//! `vlsync_status_invalid_count` likewise): their failures are a bare -1 (or 0 for the
//! counts). `vlsync_client_latest_err` and
//! `vlsync_client_camera_to_lidar_err` (ABI minor 1) are the first two with a buffer,
//! and also report a failed receive, which the buffer-less ones cannot. A handle is used
//! on the thread that opened it: a call from another thread is refused (with a message
//! where the function has a buffer; the iceoryx2 ports inside are single-threaded).
//!
//! ```
//! // what a C program does, here from Rust: a prefix the daemon would refuse is an
//! // error that names it
//! let mut err = [0u8; 128];
//! // SAFETY: a NUL-terminated prefix, and the buffer with its true length
//! let c = unsafe {
//!     vlsync_client::vlsync_client_open(c"robot/".as_ptr(), err.as_mut_ptr().cast(), err.len())
//! };
//! assert!(c.is_null());
//! let msg = std::ffi::CStr::from_bytes_until_nul(&err).unwrap().to_str().unwrap();
//! assert!(msg.contains("robot/"), "{msg}");
//! ```
// `#[no_mangle]` and the pointer reads of the exported functions need unsafe code:
// each such item allows it, with a `SAFETY` comment (for an item that allows it only
// for `#[no_mangle]`, on the attribute: why its exported name clashes with nothing)
#![deny(unsafe_code)]

use std::any::TypeId;
use std::ffi::{c_char, c_int, CStr};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::Mutex;
use std::thread::ThreadId;
use std::time::Duration;
pub use vlsync_common::wire::Status;
use vlsync_common::{Estimate, Nanos};
use vlsync_ipc::{IpcError, OffsetClient, StatusClient};

/// Version of this ABI ([`vlsync_client_abi_version`], `VLSYNC_CLIENT_ABI_VERSION` in
/// the header): a program compiled against another version must not use the library.
/// It changes only when an existing function or struct changes; an addition raises
/// [`ABI_MINOR`] instead.
pub const ABI_VERSION: u32 = 1;

/// Additions to ABI [`ABI_VERSION`] ([`vlsync_client_abi_minor`],
/// `VLSYNC_CLIENT_ABI_MINOR` in the header): a program compiled against minor `n` needs a
/// library of the same [`ABI_VERSION`] and a minor `>= n`. Minor 0 is the first set of
/// functions (the library then had no `vlsync_client_abi_minor`); minor 1 added
/// `vlsync_client_abi_minor`, `vlsync_client_latest_err`,
/// `vlsync_client_camera_to_lidar_err` and `vlsync_estimate_age_ns`; minor 2 added
/// `vlsync_status_invalid_count`.
pub const ABI_MINOR: u32 = 2;

/// An estimate as the C API hands it out (`vlsync_estimate` in the header): the
/// offset service's own payload, validated, with the time the daemon published it.
/// Its layout is the one `examples/c/vlsync_wire.h` gives `vlsync_offset_estimate`.
pub use vlsync_common::wire::OffsetEstimate;

/// The C view of `e`, published at `publish_ns`: every field as it arrived (the client
/// validated it on receipt, so this check cannot fail on what it hands out); an error
/// is prefixed with `what`, the calling function.
fn c_estimate(e: &Estimate, publish_ns: Nanos, what: &str) -> CallResult<OffsetEstimate> {
    OffsetEstimate::from_estimate(e, publish_ns)
        .map_err(|w| format!("{what}: an estimate it received fails validation now: {w}"))
}

/// A camera stamp on the LiDAR time base (`vlsync_conversion`).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VlsyncConversion {
    /// The stamp on the LiDAR clock, ns.
    pub t_lidar_ns: i64,
    /// One standard deviation of `t_lidar_ns`, seconds.
    pub std_s: f64,
    /// The estimate it was converted with: check its state and age.
    pub estimate: OffsetEstimate,
}

/// A client behind an opaque C handle.
pub struct Handle<T> {
    inner: T,
}

/// Every open handle: its address, its type and the thread that opened it. A handle
/// is dereferenced only once it is found here, of its type, on its thread: a handle
/// closed already (closed twice, used after close) or a pointer that never was one
/// is an error, not a use-after-free. (An address a later open got again is that
/// open's live handle: still no dangling access.)
static LIVE: Mutex<Vec<(usize, TypeId, ThreadId)>> = Mutex::new(Vec::new());

/// [`LIVE`], even after a panic while it was held (it holds plain values only).
fn live() -> std::sync::MutexGuard<'static, Vec<(usize, TypeId, ThreadId)>> {
    LIVE.lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Where handle `c` is in [`LIVE`]: `Ok(index)` when open, of type `T`, on this
/// thread; else what is wrong with it (prefixed with `what`).
fn find_live<T: 'static>(
    live: &[(usize, TypeId, ThreadId)],
    c: *mut Handle<T>,
    what: &str,
) -> CallResult<usize> {
    let i = live
        .iter()
        .position(|&(addr, ty, _)| addr == c.addr() && ty == TypeId::of::<T>())
        .ok_or_else(|| {
            format!("{what}: not an open handle (closed already, or not one this library opened)")
        })?;
    if live[i].2 != std::thread::current().id() {
        return Err(format!(
            "{what}: the client was opened on another thread (use a handle only on the thread that opened it)"
        ));
    }
    Ok(i)
}

/// The handle behind `vlsync_client *`.
pub type VlsyncClient = Handle<OffsetClient>;

/// The handle behind `vlsync_status_client *`.
pub type VlsyncStatusClient = Handle<StatusClient>;

/// What a call failed with.
type CallResult<T> = Result<T, String>;

/// Runs `f`, turning a panic into an error: no unwinding crosses the C boundary.
fn guarded<T>(what: &str, f: impl FnOnce() -> CallResult<T>) -> CallResult<T> {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(r) => r,
        Err(p) => {
            let why = p
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| p.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".into());
            Err(format!("{what}: internal error: {why}"))
        }
    }
}

/// The longest prefix of `msg` that fits a buffer of `cap` bytes with its
/// terminating NUL, cut at a character boundary (so the C string stays UTF-8), and
/// with any NUL of `msg` ending it.
pub fn message_prefix(msg: &str, cap: usize) -> &[u8] {
    if cap == 0 {
        return &[];
    }
    let msg = msg.split('\0').next().unwrap_or("");
    let mut end = msg.len().min(cap - 1);
    while !msg.is_char_boundary(end) {
        end -= 1;
    }
    &msg.as_bytes()[..end]
}

/// Writes `msg` as a NUL-terminated string into `buf` (`cap` bytes); nothing when
/// `buf` is NULL or `cap` is 0.
///
/// # Safety
/// `buf` is NULL or points to `cap` writable bytes.
#[allow(unsafe_code)]
unsafe fn write_message(buf: *mut c_char, cap: usize, msg: &str) {
    if buf.is_null() || cap == 0 {
        return;
    }
    let bytes = message_prefix(msg, cap);
    // SAFETY: `buf` points to `cap` writable bytes (this function's contract, the
    // header's for every `err, err_len` pair); we write `bytes.len() + 1 <= cap` of
    // them, from `msg`, which cannot overlap a buffer the caller handed us.
    unsafe {
        std::ptr::copy_nonoverlapping(bytes.as_ptr(), buf.cast::<u8>(), bytes.len());
        *buf.add(bytes.len()) = 0;
    }
}

/// The client behind handle `c`, on the thread that opened it.
///
/// # Safety
/// The reference returned is dropped before the handle is closed (the caller's
/// thread is the only one that can close it: [`find_live`]).
#[allow(unsafe_code)]
unsafe fn handle<'a, T: 'static>(c: *mut Handle<T>, what: &str) -> CallResult<&'a mut T> {
    if c.is_null() {
        return Err(format!("{what}: the client is NULL"));
    }
    find_live(&live(), c, what)?;
    // SAFETY: `c` is an open handle of type `T` (found in LIVE: `open_handle` put it
    // there when it made it with `Box::into_raw`, and `close_handle` takes it out before
    // freeing it), opened on this thread, the only one that makes references into it or
    // can close it: the single-threaded ports inside stay on their thread. The
    // reference is to the `inner` field only, made from the raw pointer.
    Ok(unsafe { &mut *std::ptr::addr_of_mut!((*c).inner) })
}

/// Writes `v` to `out`, aligned or not (a caller's packed or byte buffer).
///
/// # Safety
/// `out` points to `size_of::<T>()` writable bytes.
#[allow(unsafe_code)]
unsafe fn put<T>(out: *mut T, v: T) {
    // SAFETY: this function's contract; `write_unaligned` needs no alignment.
    unsafe { out.write_unaligned(v) }
}

/// The prefix string at `prefix`, read up to its NUL but never more than one byte
/// beyond the longest valid prefix: a string without its NUL within that is refused
/// rather than read on into whatever memory follows it.
///
/// # Safety
/// `prefix` is non-NULL and points to a NUL-terminated string, or to at least
/// `MAX_PREFIX_BYTES + 2` readable bytes.
#[allow(unsafe_code)]
unsafe fn bounded_prefix<'a>(prefix: *const c_char, what: &str) -> Result<&'a CStr, String> {
    let limit = vlsync_config::MAX_PREFIX_BYTES + 1;
    // SAFETY: byte i is read only after bytes 0..i were all non-NUL, so it lies
    // within the caller's string (its NUL at the latest) or within the bytes promised
    let len = (0..=limit).find(|&i| unsafe { *prefix.add(i) } == 0);
    let Some(len) = len else {
        return Err(format!(
            "{what}: the prefix is longer than {} bytes (or not NUL-terminated)",
            vlsync_config::MAX_PREFIX_BYTES
        ));
    };
    // SAFETY: bytes 0..len are readable and byte len is the NUL (found above)
    let bytes = unsafe { std::slice::from_raw_parts(prefix.cast::<u8>(), len + 1) };
    CStr::from_bytes_with_nul(bytes).map_err(|e| format!("{what}: the prefix: {e}"))
}

/// The ABI version the library was built with (`VLSYNC_CLIENT_ABI_VERSION`).
#[allow(unsafe_code)]
// SAFETY: `#[no_mangle]` is the only unsafe part (the function itself is safe): the
// exported name is vlsync_-prefixed, so no other symbol of the library or of a program
// loading it (iceoryx2 and std export none such) has it.
#[no_mangle]
pub extern "C" fn vlsync_client_abi_version() -> u32 {
    ABI_VERSION
}

/// The ABI minor version the library was built with (`VLSYNC_CLIENT_ABI_MINOR`): the
/// additions it has to [`ABI_VERSION`] (see [`ABI_MINOR`]).
#[allow(unsafe_code)]
// SAFETY: as for `vlsync_client_abi_version`: `#[no_mangle]` only, a vlsync_ name
#[no_mangle]
pub extern "C" fn vlsync_client_abi_minor() -> u32 {
    ABI_MINOR
}

/// Opens the offset service of robot `prefix` (e.g. `vlsync/robot`). Returns the
/// handle, or NULL with the reason in `err` (up to `err_len` bytes, NUL-terminated;
/// `err` may be NULL). The daemon need not run yet: estimates arrive once it does.
///
/// # Safety
/// `prefix` is NULL or a NUL-terminated string; `err` is NULL or points to
/// `err_len` writable bytes.
#[allow(unsafe_code)]
#[no_mangle]
pub unsafe extern "C" fn vlsync_client_open(
    prefix: *const c_char,
    err: *mut c_char,
    err_len: usize,
) -> *mut VlsyncClient {
    // SAFETY: the caller's promises, passed on unchanged
    unsafe {
        open_handle(
            prefix,
            err,
            err_len,
            "vlsync_client_open",
            OffsetClient::open,
        )
    }
}

/// Opens a client of robot `prefix` with `open` on this thread: the handle, or NULL
/// with the reason (prefixed with `what`) in `err`.
///
/// # Safety
/// As [`vlsync_client_open`]'s.
#[allow(unsafe_code)]
unsafe fn open_handle<T: 'static>(
    prefix: *const c_char,
    err: *mut c_char,
    err_len: usize,
    what: &str,
    open: impl FnOnce(&str) -> Result<T, IpcError>,
) -> *mut Handle<T> {
    let r = guarded(what, || {
        if prefix.is_null() {
            return Err(format!("{what}: the prefix is NULL"));
        }
        // SAFETY: non-NULL and NUL-terminated, as the caller promised.
        let p = unsafe { bounded_prefix(prefix, what) }?;
        let p = p
            .to_str()
            .map_err(|_| format!("{what}: the prefix {:?} is not UTF-8", p.to_string_lossy()))?;
        if !vlsync_config::prefix_is_valid(p) {
            let shown: String = p.chars().take(60).collect();
            let more = if shown.len() < p.len() { "..." } else { "" };
            return Err(format!(
                "{what}: prefix {shown:?}{more} is invalid: allowed 1-200 characters of [A-Za-z0-9_.-/], no leading, trailing or double `/`"
            ));
        }
        let inner = open(p).map_err(|e| format!("{what}: {e}"))?;
        Ok(Box::new(Handle { inner }))
    });
    match r {
        Ok(b) => {
            let c = Box::into_raw(b);
            live().push((c.addr(), TypeId::of::<T>(), std::thread::current().id()));
            c
        }
        Err(m) => {
            // SAFETY: `err` is NULL or `err_len` writable bytes (the caller's promise)
            unsafe { write_message(err, err_len, &m) };
            std::ptr::null_mut()
        }
    }
}

/// Closes a handle (NULL: nothing to do). Returns 0, or -1 when called on another
/// thread than the one that opened it (the handle is then left open) or for a handle
/// that is not open (closed already: no double free).
///
/// # Safety
/// None beyond the C header's: the handle is looked up among the open ones before use.
#[allow(unsafe_code)]
#[no_mangle]
pub unsafe extern "C" fn vlsync_client_close(c: *mut VlsyncClient) -> c_int {
    // SAFETY: the caller's promise, passed on unchanged
    unsafe { close_handle(c, "vlsync_client_close") }
}

/// Closes handle `c` on its own thread: 0 (NULL: nothing to do), or -1 on another
/// thread (the handle left open) or for a handle not open.
///
/// # Safety
/// None beyond the C header's: `c` is looked up in [`LIVE`] before it is freed.
#[allow(unsafe_code)]
unsafe fn close_handle<T: 'static>(c: *mut Handle<T>, what: &str) -> c_int {
    if c.is_null() {
        return 0;
    }
    // out of LIVE first (a panic in the lookup is caught: no unwinding into C)
    let found = guarded(what, || {
        let mut live = live();
        let i = find_live(&live, c, what)?;
        live.swap_remove(i);
        Ok(())
    });
    if found.is_err() {
        return -1;
    }
    // SAFETY: `c` was in LIVE, so it came from `Box::into_raw` in `open_handle` and was
    // not freed since; it is out of LIVE now, so no later call reaches it; on its own
    // thread (checked by `find_live`), which holds no reference into it between calls.
    let b = unsafe { Box::from_raw(c) };
    // a panic in a port's drop is caught; the handle is gone either way
    let _ = catch_unwind(AssertUnwindSafe(move || drop(b)));
    0
}

/// Waits up to `timeout_ms` (negative: no limit) for the next estimate and writes it
/// to `out`: the newest, when several are pending (the older ones are passed over;
/// [`vlsync_client_wait_one`] hands out each). Returns 1 when one was written; 0 on
/// timeout, and early when a signal interrupts the wait (check your own stop flag and
/// call again); -1 on error, with the reason in `err`.
///
/// # Safety
/// `c` is NULL or an open handle; `out` is NULL or points to a writable
/// `vlsync_estimate`; `err` is NULL or points to `err_len` writable bytes.
#[allow(unsafe_code)]
#[no_mangle]
pub unsafe extern "C" fn vlsync_client_wait_next(
    c: *mut VlsyncClient,
    timeout_ms: i64,
    out: *mut OffsetEstimate,
    err: *mut c_char,
    err_len: usize,
) -> c_int {
    // SAFETY: the caller's promises, passed on unchanged
    unsafe {
        wait_into(
            c,
            timeout_ms,
            out,
            err,
            err_len,
            "vlsync_client_wait_next",
            |h, t| Ok(h.wait_next(t)?.map(|e| (e, h.latest_publish_ns()))),
        )
    }
}

/// The two waits: `wait(client, timeout)` gives an estimate with its publish time or
/// none, written to `out`; 1, 0, or -1 with the reason (prefixed with `what`) in `err`.
///
/// # Safety
/// As [`vlsync_client_wait_next`]'s.
#[allow(unsafe_code)]
unsafe fn wait_into(
    c: *mut VlsyncClient,
    timeout_ms: i64,
    out: *mut OffsetEstimate,
    err: *mut c_char,
    err_len: usize,
    what: &str,
    wait: impl FnOnce(&mut OffsetClient, Duration) -> Result<Option<(Estimate, Nanos)>, IpcError>,
) -> c_int {
    // SAFETY: the caller's promises, passed on unchanged
    unsafe {
        fetch_into(c, out, err, err_len, what, |h| {
            let timeout = u64::try_from(timeout_ms).map_or(Duration::MAX, Duration::from_millis);
            match wait(h, timeout).map_err(|e| format!("{what}: {e}"))? {
                Some((e, publish_ns)) => Ok(Some(c_estimate(&e, publish_ns, what)?)),
                None => Ok(None),
            }
        })
    }
}

/// The shape of every call that hands a value out: `fetch` runs guarded on the client
/// behind `c` (on its own thread) and its value is written to `out`. Returns 1 when
/// written, 0 when `fetch` had nothing, -1 on error (a NULL argument, another thread,
/// what `fetch` failed with) with the reason, prefixed with `what`, in `err`.
///
/// # Safety
/// `c` is NULL or an open handle; `out` is NULL or points to a writable `V`; `err` is
/// NULL or points to `err_len` writable bytes.
#[allow(unsafe_code)]
unsafe fn fetch_into<T: 'static, V>(
    c: *mut Handle<T>,
    out: *mut V,
    err: *mut c_char,
    err_len: usize,
    what: &str,
    fetch: impl FnOnce(&mut T) -> CallResult<Option<V>>,
) -> c_int {
    let r = guarded(what, || {
        // SAFETY: `c` is NULL or an open handle (the caller's promise); `h` lives
        // only for this call
        let h = unsafe { handle(c, what) }?;
        if out.is_null() {
            return Err(format!("{what}: out is NULL"));
        }
        Ok(match fetch(h)? {
            Some(v) => {
                // SAFETY: `out` is not NULL (checked) and points to a writable `V`
                // (the caller's promise)
                unsafe { put(out, v) };
                1
            }
            None => 0,
        })
    });
    r.unwrap_or_else(|m| {
        // SAFETY: `err` is NULL or `err_len` writable bytes (the caller's promise)
        unsafe { write_message(err, err_len, &m) };
        -1
    })
}

/// Waits up to `timeout_ms` (negative: no limit) for an estimate and writes the
/// oldest one pending to `out`: every estimate, one per call, in the order the daemon
/// published them (what a recorder or logger needs; [`vlsync_client_wait_next`]
/// keeps only the newest). Returns 1 when one was written; 0 on timeout, and early
/// when a signal interrupts the wait; -1 on error, with the reason in `err`. The
/// subscriber buffers 16 estimates (8 s at the default hop): a caller further behind
/// loses the oldest.
///
/// # Safety
/// `c` is NULL or an open handle; `out` is NULL or points to a writable
/// `vlsync_estimate`; `err` is NULL or points to `err_len` writable bytes.
#[allow(unsafe_code)]
#[no_mangle]
pub unsafe extern "C" fn vlsync_client_wait_one(
    c: *mut VlsyncClient,
    timeout_ms: i64,
    out: *mut OffsetEstimate,
    err: *mut c_char,
    err_len: usize,
) -> c_int {
    // SAFETY: the caller's promises, passed on unchanged
    unsafe {
        wait_into(
            c,
            timeout_ms,
            out,
            err,
            err_len,
            "vlsync_client_wait_one",
            |h, t| h.wait_one(t),
        )
    }
}

/// Writes the most recent estimate to `out`, after taking what is pending (which a
/// later [`vlsync_client_wait_one`] then does not hand out).
/// Returns 1 when written, 0 before the first estimate, -1 when `c` or `out` is
/// NULL, `c` belongs to another thread, or on an internal error (a caught panic, or
/// an estimate that fails validation when handed out); there is no buffer for the
/// reason. A failed receive is not reported: the last estimate is written as before
/// ([`vlsync_client_latest_err`] reports it). Check the estimate's state and age
/// ([`vlsync_estimate_age_ns`]): the last one stays, "tracking" or not, after the
/// daemon stops.
///
/// # Safety
/// `c` is NULL or an open handle; `out` is NULL or points to a writable
/// `vlsync_estimate`.
#[allow(unsafe_code)]
#[no_mangle]
pub unsafe extern "C" fn vlsync_client_latest(
    c: *mut VlsyncClient,
    out: *mut OffsetEstimate,
) -> c_int {
    // SAFETY: the caller's promises, passed on unchanged (no error buffer)
    unsafe {
        latest_into(
            c,
            out,
            std::ptr::null_mut(),
            0,
            "vlsync_client_latest",
            false,
        )
    }
}

/// [`vlsync_client_latest`] with the reason for -1 in `err`, which also covers a
/// failed receive on the offset service: -1 then, with iceoryx2's error, and the
/// client keeps its last estimate (which a later call hands out if the receive
/// recovers, and [`vlsync_client_latest`] hands out regardless). ABI minor 1.
///
/// # Safety
/// `c` is NULL or an open handle; `out` is NULL or points to a writable
/// `vlsync_estimate`; `err` is NULL or points to `err_len` writable bytes.
#[allow(unsafe_code)]
#[no_mangle]
pub unsafe extern "C" fn vlsync_client_latest_err(
    c: *mut VlsyncClient,
    out: *mut OffsetEstimate,
    err: *mut c_char,
    err_len: usize,
) -> c_int {
    // SAFETY: the caller's promises, passed on unchanged
    unsafe { latest_into(c, out, err, err_len, "vlsync_client_latest_err", true) }
}

/// Takes what is pending, with a failed receive as an error (prefixed with `what`)
/// where [`OffsetClient::latest`] and [`OffsetClient::camera_to_lidar`] drop it; the
/// estimates taken before the failure stay the client's latest either way.
fn take_pending(h: &mut OffsetClient, what: &str) -> CallResult<()> {
    h.try_latest()
        .map(|_| ())
        .map_err(|e| format!("{what}: {e}"))
}

/// The two latest calls: the newest estimate into `out`; 1, 0, or -1 with the reason
/// (prefixed with `what`) in `err`; with `report`, a failed receive is -1 too.
///
/// # Safety
/// As [`vlsync_client_latest_err`]'s.
#[allow(unsafe_code)]
unsafe fn latest_into(
    c: *mut VlsyncClient,
    out: *mut OffsetEstimate,
    err: *mut c_char,
    err_len: usize,
    what: &str,
    report: bool,
) -> c_int {
    // SAFETY: the caller's promises, passed on unchanged
    unsafe {
        fetch_into(c, out, err, err_len, what, |h| {
            if report {
                take_pending(h, what)?;
            }
            h.latest()
                .map(|e| c_estimate(&e, h.latest_publish_ns(), what))
                .transpose()
        })
    }
}

/// Converts camera stamp `t_cam_ns` to the LiDAR time base with the latest estimate
/// (extrapolated with its drift; the standard deviation includes the offset's random
/// walk since the estimate's reference time). Returns 1 when written to `out`, 0
/// before the first estimate, -1 when `c` or `out` is NULL, `c` belongs to another
/// thread, or on an internal error (as [`vlsync_client_latest`]; no buffer for the
/// reason, a failed receive not reported: [`vlsync_client_camera_to_lidar_err`]).
/// Check `out->estimate.state` (tracking or holding: a lock) and its age
/// ([`vlsync_estimate_age_ns`]): after the daemon stops, the last estimate keeps
/// converting, in the state it had. Like [`vlsync_client_latest`] it takes what is
/// pending first.
///
/// # Safety
/// `c` is NULL or an open handle; `out` is NULL or points to a writable
/// `vlsync_conversion`.
#[allow(unsafe_code)]
#[no_mangle]
pub unsafe extern "C" fn vlsync_client_camera_to_lidar(
    c: *mut VlsyncClient,
    t_cam_ns: i64,
    out: *mut VlsyncConversion,
) -> c_int {
    // SAFETY: the caller's promises, passed on unchanged (no error buffer)
    unsafe {
        convert_into(
            c,
            t_cam_ns,
            out,
            std::ptr::null_mut(),
            0,
            "vlsync_client_camera_to_lidar",
            false,
        )
    }
}

/// [`vlsync_client_camera_to_lidar`] with the reason for -1 in `err`, which also
/// covers a failed receive (as [`vlsync_client_latest_err`]). ABI minor 1.
///
/// # Safety
/// `c` is NULL or an open handle; `out` is NULL or points to a writable
/// `vlsync_conversion`; `err` is NULL or points to `err_len` writable bytes.
#[allow(unsafe_code)]
#[no_mangle]
pub unsafe extern "C" fn vlsync_client_camera_to_lidar_err(
    c: *mut VlsyncClient,
    t_cam_ns: i64,
    out: *mut VlsyncConversion,
    err: *mut c_char,
    err_len: usize,
) -> c_int {
    // SAFETY: the caller's promises, passed on unchanged
    unsafe {
        convert_into(
            c,
            t_cam_ns,
            out,
            err,
            err_len,
            "vlsync_client_camera_to_lidar_err",
            true,
        )
    }
}

/// The two conversions: `t_cam_ns` on the LiDAR clock into `out`; 1, 0, or -1 with
/// the reason (prefixed with `what`) in `err`; with `report`, a failed receive is -1 too.
///
/// # Safety
/// As [`vlsync_client_camera_to_lidar_err`]'s.
#[allow(unsafe_code)]
unsafe fn convert_into(
    c: *mut VlsyncClient,
    t_cam_ns: i64,
    out: *mut VlsyncConversion,
    err: *mut c_char,
    err_len: usize,
    what: &str,
    report: bool,
) -> c_int {
    // SAFETY: the caller's promises, passed on unchanged
    unsafe {
        fetch_into(c, out, err, err_len, what, |h| {
            if report {
                take_pending(h, what)?;
            }
            h.camera_to_lidar(t_cam_ns)
                .map(|v| {
                    Ok(VlsyncConversion {
                        t_lidar_ns: v.t_lidar_ns,
                        std_s: v.std_s,
                        estimate: c_estimate(&v.estimate, h.latest_publish_ns(), what)?,
                    })
                })
                .transpose()
        })
    }
}

/// How old estimate `e` is: `CLOCK_MONOTONIC` now minus its `publish_ns`, in ns, or -1
/// when `e` is NULL. A publish time up to [`FUTURE_MARGIN_NS`] ahead is age 0; one
/// further ahead, which the same machine's daemon never gives (another clock, or a
/// faulty publisher on the service), is `INT64_MAX`, so that every age check fails
/// rather than pass for as long as that stamp lies ahead. The state alone does not tell a live lock: after the daemon
/// stops, the last estimate stays "tracking" (or "holding") in every later
/// [`vlsync_client_latest`] and conversion. ABI minor 1.
///
/// # Safety
/// `e` is NULL or points to a readable `vlsync_estimate` (aligned or not).
#[allow(unsafe_code)]
#[no_mangle]
pub unsafe extern "C" fn vlsync_estimate_age_ns(e: *const OffsetEstimate) -> i64 {
    if e.is_null() {
        return -1;
    }
    // SAFETY: `e` is not NULL (checked) and points to a readable `vlsync_estimate`
    // (the caller's promise); only its `publish_ns` field is read, through the raw
    // pointer and without assuming alignment (as `put` writes)
    let publish_ns = unsafe { std::ptr::addr_of!((*e).publish_ns).read_unaligned() };
    // the Rust client's own rule (saturating: any publish_ns gives an answer)
    vlsync_ipc::estimate_age_ns(publish_ns)
}

/// How far ahead of `CLOCK_MONOTONIC` a publish time may be and still count as age 0
/// ([`vlsync_estimate_age_ns`]): a second (`vlsync_ipc::FUTURE_MARGIN_NS`).
pub const FUTURE_MARGIN_NS: i64 = vlsync_ipc::FUTURE_MARGIN_NS;

/// Sets the offset's random walk (s/√s) that conversions assume while tracking and
/// otherwise: the daemon's `estimator.offset_process_noise` and
/// `estimator.hold_process_noise` when it does not run the shipped values (2e-4,
/// 3e-3). Returns 0, or -1 with the reason in `err`: a NULL handle, another thread's
/// handle, or a value that is NaN, infinite or negative (the setting then stays as it
/// was).
///
/// # Safety
/// `c` is NULL or an open handle; `err` is NULL or points to `err_len` writable bytes.
#[allow(unsafe_code)]
#[no_mangle]
pub unsafe extern "C" fn vlsync_client_set_process_noise(
    c: *mut VlsyncClient,
    tracking: f64,
    holding: f64,
    err: *mut c_char,
    err_len: usize,
) -> c_int {
    let r = guarded("vlsync_client_set_process_noise", || {
        // SAFETY: `c` is NULL or an open handle (the caller's promise); `h` lives
        // only for this call
        let h = unsafe { handle(c, "vlsync_client_set_process_noise") }?;
        h.set_process_noise(tracking, holding)
            .map_err(|e| format!("vlsync_client_set_process_noise: {e}"))
    });
    match r {
        Ok(()) => 0,
        Err(m) => {
            // SAFETY: `err` is NULL or `err_len` writable bytes (the caller's promise)
            unsafe { write_message(err, err_len, &m) };
            -1
        }
    }
}

/// Payloads refused by validation so far (0 for NULL or another thread's handle).
///
/// # Safety
/// `c` is NULL or an open handle.
#[allow(unsafe_code)]
#[no_mangle]
pub unsafe extern "C" fn vlsync_client_invalid_count(c: *mut VlsyncClient) -> u64 {
    guarded("vlsync_client_invalid_count", || {
        // SAFETY: `c` is NULL or an open handle (the caller's promise); the reference
        // lives only for this call
        unsafe { handle(c, "vlsync_client_invalid_count") }.map(|h| h.invalid_count())
    })
    .unwrap_or(0)
}

/// Opens the status service of robot `prefix` (the daemon's counters, published every
/// `daemon.status_period_s`). Returns the handle, or NULL with the reason in `err`. The
/// daemon need not run yet. Like an offset client, a handle is used on the thread that
/// opened it.
///
/// # Safety
/// `prefix` is NULL or a NUL-terminated string; `err` is NULL or points to
/// `err_len` writable bytes.
#[allow(unsafe_code)]
#[no_mangle]
pub unsafe extern "C" fn vlsync_status_open(
    prefix: *const c_char,
    err: *mut c_char,
    err_len: usize,
) -> *mut VlsyncStatusClient {
    // SAFETY: the caller's promises, passed on unchanged
    unsafe {
        open_handle(
            prefix,
            err,
            err_len,
            "vlsync_status_open",
            StatusClient::open,
        )
    }
}

/// Closes a status handle (NULL: nothing to do). Returns 0, or -1 when called on
/// another thread than the one that opened it (the handle is then left open) or for a
/// handle that is not open (closed already: no double free).
///
/// # Safety
/// None beyond the C header's: the handle is looked up among the open ones before use.
#[allow(unsafe_code)]
#[no_mangle]
pub unsafe extern "C" fn vlsync_status_close(c: *mut VlsyncStatusClient) -> c_int {
    // SAFETY: the caller's promise, passed on unchanged
    unsafe { close_handle(c, "vlsync_status_close") }
}

/// Writes the newest valid status to `out` (after taking what is pending; invalid
/// payloads are skipped). Returns 1 when written, 0 before the first status, -1 on
/// error with the reason in `err`: a NULL argument, another thread's handle, a
/// transport failure, or, while no valid status ever arrived, the payload's
/// validation error.
///
/// # Safety
/// `c` is NULL or an open status handle; `out` is NULL or points to a writable
/// `vlsync_daemon_status`; `err` is NULL or points to `err_len` writable bytes.
#[allow(unsafe_code)]
#[no_mangle]
pub unsafe extern "C" fn vlsync_status_latest(
    c: *mut VlsyncStatusClient,
    out: *mut Status,
    err: *mut c_char,
    err_len: usize,
) -> c_int {
    let what = "vlsync_status_latest";
    // SAFETY: the caller's promises, passed on unchanged
    unsafe {
        fetch_into(c, out, err, err_len, what, |h| {
            h.latest().map_err(|e| format!("{what}: {e}"))
        })
    }
}

/// Status payloads refused by validation so far (0 for NULL or another thread's
/// handle): a [`vlsync_status_latest`] that returned -1 while this count rose met only
/// invalid payloads (they are skipped; the next call reads on).
///
/// # Safety
/// `c` is NULL or an open status handle.
#[allow(unsafe_code)]
#[no_mangle]
pub unsafe extern "C" fn vlsync_status_invalid_count(c: *mut VlsyncStatusClient) -> u64 {
    guarded("vlsync_status_invalid_count", || {
        // SAFETY: `c` is NULL or an open handle (the caller's promise); the reference
        // lives only for this call
        unsafe { handle(c, "vlsync_status_invalid_count") }.map(|h| h.invalid_count())
    })
    .unwrap_or(0)
}

/// Lowercase name of a state code (`"acquiring"`, `"tracking"`, `"holding"`,
/// `"lost"`), `"unknown"` for any other: a static string, never freed.
#[allow(unsafe_code)]
// SAFETY: as for `vlsync_client_abi_version`: `#[no_mangle]` only, a vlsync_ name
#[no_mangle]
pub extern "C" fn vlsync_state_name(state: u8) -> *const c_char {
    let s: &'static CStr = match vlsync_common::EstimatorState::from_code(state) {
        Some(vlsync_common::EstimatorState::Acquiring) => c"acquiring",
        Some(vlsync_common::EstimatorState::Tracking) => c"tracking",
        Some(vlsync_common::EstimatorState::Holding) => c"holding",
        Some(vlsync_common::EstimatorState::Lost) => c"lost",
        None => c"unknown",
    };
    s.as_ptr()
}

#[cfg(test)]
#[allow(unsafe_code)]
mod tests {
    use super::*;
    use std::mem::{align_of, offset_of, size_of};
    use vlsync_common::{EstimatorState, Polarity};

    fn text(buf: &[u8]) -> String {
        CStr::from_bytes_until_nul(buf)
            .expect("NUL-terminated")
            .to_str()
            .expect("UTF-8")
            .to_string()
    }

    /// An offset service of a prefix of its own (`vlsync/capi-TAG-PID`), a publisher
    /// standing in for the daemon, and a C client open on it.
    struct OffsetRig {
        _node: vlsync_ipc::IpcNode,
        _svc: vlsync_ipc::iceoryx2::service::port_factory::publish_subscribe::PortFactory<
            vlsync_ipc::Svc,
            OffsetEstimate,
            (),
        >,
        publ: vlsync_ipc::iceoryx2::port::publisher::Publisher<vlsync_ipc::Svc, OffsetEstimate, ()>,
        c: *mut VlsyncClient,
    }

    impl OffsetRig {
        fn open(tag: &str) -> Self {
            use vlsync_ipc::{create_node, open_or_create_pubsub, publisher, Qos, ServiceNames};
            let names =
                ServiceNames::new(&format!("vlsync/capi-{tag}-{}", std::process::id())).unwrap();
            let node = create_node("capi-test-daemon", false).unwrap();
            let svc =
                open_or_create_pubsub::<OffsetEstimate>(&node, &names.offset(), Qos::latest())
                    .unwrap();
            let publ = publisher(&svc, "offset").unwrap();
            let cp = std::ffi::CString::new(names.prefix.clone()).unwrap();
            let mut err = [0u8; 300];
            // SAFETY: a C string and a buffer with its true length
            let c = unsafe { vlsync_client_open(cp.as_ptr(), err.as_mut_ptr().cast(), err.len()) };
            assert!(!c.is_null(), "{}", text(&err));
            Self {
                _node: node,
                _svc: svc,
                publ,
                c,
            }
        }
    }

    /// The layout `include/vlsync_client.h` states: every size, alignment and offset
    /// its static asserts pin (read from the header's text here) is Rust's, and it
    /// pins every field (`tests/tests/ipc_capi.rs` also compiles it against these).
    #[test]
    fn layouts_are_the_headers() {
        macro_rules! offsets {
            ($c:literal, $t:ty: $($f:ident),*) => {
                vec![$((format!("offsetof({}, {})", $c, stringify!($f)), offset_of!($t, $f))),*]
            };
        }
        let mut rust: Vec<(String, usize)> = vec![];
        for (c, size, align) in [
            (
                "vlsync_estimate",
                size_of::<OffsetEstimate>(),
                align_of::<OffsetEstimate>(),
            ),
            (
                "vlsync_conversion",
                size_of::<VlsyncConversion>(),
                align_of::<VlsyncConversion>(),
            ),
            (
                "vlsync_daemon_status",
                size_of::<Status>(),
                align_of::<Status>(),
            ),
        ] {
            rust.push((format!("sizeof({c})"), size));
            rust.push((format!("VLSYNC_CLIENT_ALIGNOF({c})"), align));
        }
        rust.extend(
            offsets!("vlsync_estimate", OffsetEstimate: seq, t_ref_ns, offset_s, drift,
            offset_std_s, drift_std, peak_score, peak_ratio, measured_offset_s, publish_ns,
            state, polarity, reserved),
        );
        rust.extend(offsets!("vlsync_conversion", VlsyncConversion: t_lidar_ns, std_s, estimate));
        rust.extend(
            offsets!("vlsync_daemon_status", Status: uptime_ns, publish_ns, received,
            rejected, lost, budget_overruns, estimates_published, events_dropped,
            processing_ns, end_to_end_ns, latency_count, state, degraded, reserved),
        );
        let header: Vec<(String, usize)> = include_str!("../include/vlsync_client.h")
            .lines()
            .filter_map(|l| l.strip_prefix("VLSYNC_CLIENT_STATIC_ASSERT("))
            .map(|l| {
                let (what, n) = l.split_once(" == ").expect("`x == n`");
                let n = n.split(',').next().unwrap().parse().expect("a number");
                (what.to_string(), n)
            })
            .collect();
        let sorted = |mut v: Vec<(String, usize)>| {
            v.sort();
            v
        };
        assert_eq!(sorted(header), sorted(rust));
        assert_eq!(
            (size_of::<OffsetEstimate>(), align_of::<OffsetEstimate>()),
            (88, 8)
        );
        assert_eq!((size_of::<Status>(), align_of::<Status>()), (224, 8));
        assert_eq!(size_of::<VlsyncConversion>(), 104);
    }

    #[test]
    fn a_status_handle_checks_its_arguments_and_its_thread() {
        let mut err = [0u8; 300];
        let mut st = Status::default();
        // SAFETY: valid pointers: C strings, buffers with their true lengths, and handles from vlsync_status_open not yet closed.
        unsafe {
            let null = std::ptr::null_mut();
            assert_eq!(
                vlsync_status_latest(null, &mut st, err.as_mut_ptr().cast(), err.len()),
                -1
            );
            assert_eq!(text(&err), "vlsync_status_latest: the client is NULL");
            assert_eq!(vlsync_status_close(null), 0);
            assert!(
                vlsync_status_open(c"a//b".as_ptr(), err.as_mut_ptr().cast(), err.len()).is_null()
            );
            assert!(
                text(&err).starts_with("vlsync_status_open: prefix \"a//b\" is invalid"),
                "{}",
                text(&err)
            );
        }
        let prefix = format!("vlsync/capi-status-{}", std::process::id());
        let cp = std::ffi::CString::new(prefix).unwrap();
        // SAFETY: as above
        let c = unsafe { vlsync_status_open(cp.as_ptr(), err.as_mut_ptr().cast(), err.len()) };
        assert!(!c.is_null(), "{}", text(&err));
        // SAFETY: as above
        unsafe {
            // no daemon: nothing yet
            assert_eq!(
                vlsync_status_latest(c, &mut st, err.as_mut_ptr().cast(), err.len()),
                0
            );
            assert_eq!(
                vlsync_status_latest(c, std::ptr::null_mut(), err.as_mut_ptr().cast(), err.len()),
                -1
            );
            assert_eq!(text(&err), "vlsync_status_latest: out is NULL");
        }
        let addr = c as usize;
        let (code, closed) = std::thread::spawn(move || {
            let c = addr as *mut VlsyncStatusClient;
            let mut st = Status::default();
            // SAFETY: as above (the handle is refused on this thread)
            unsafe {
                (
                    vlsync_status_latest(c, &mut st, std::ptr::null_mut(), 0),
                    vlsync_status_close(c),
                )
            }
        })
        .join()
        .unwrap();
        assert_eq!((code, closed), (-1, -1));
        // SAFETY: as above
        assert_eq!(unsafe { vlsync_status_close(c) }, 0);
    }

    #[test]
    fn an_estimate_keeps_every_field() {
        let e = Estimate {
            seq: 7,
            t_ref_ns: -5,
            offset_s: 0.1,
            drift: 2e-5,
            offset_std_s: 1e-3,
            drift_std: 3e-6,
            state: EstimatorState::Holding,
            polarity: Polarity::Negative,
            peak_score: 0.9,
            peak_ratio: f64::INFINITY,
            measured_offset_s: f64::NAN,
        };
        let c = c_estimate(&e, 42, "f").unwrap();
        assert_eq!((c.seq, c.t_ref_ns, c.publish_ns), (7, -5, 42));
        assert_eq!(
            (c.offset_s, c.drift, c.offset_std_s, c.drift_std),
            (0.1, 2e-5, 1e-3, 3e-6)
        );
        assert_eq!((c.state, c.polarity, c.reserved), (2, -1, [0; 6]));
        assert!(c.peak_ratio.is_infinite() && c.measured_offset_s.is_nan());
        // a good estimate passes (above); one that fails validation, here a NaN offset,
        // is refused rather than handed to C
        let refused = c_estimate(
            &Estimate {
                offset_s: f64::NAN,
                ..e
            },
            0,
            "vlsync_f",
        )
        .unwrap_err();
        assert!(
            refused.starts_with("vlsync_f: an estimate it received fails validation now"),
            "{refused}"
        );
    }

    #[test]
    fn null_pointers_are_errors_not_crashes() {
        let mut err = [0u8; 200];
        let mut est = OffsetEstimate::from_estimate(&zero(), 0).unwrap();
        let mut conv = VlsyncConversion {
            t_lidar_ns: 0,
            std_s: 0.0,
            estimate: est,
        };
        // SAFETY: valid pointers: C strings, buffers with their true lengths, and handles from vlsync_client_open not yet closed.
        unsafe {
            assert!(
                vlsync_client_open(std::ptr::null(), err.as_mut_ptr().cast(), err.len()).is_null()
            );
            assert_eq!(text(&err), "vlsync_client_open: the prefix is NULL");
            let null = std::ptr::null_mut();
            assert_eq!(
                vlsync_client_wait_next(null, 0, &mut est, err.as_mut_ptr().cast(), err.len()),
                -1
            );
            assert_eq!(text(&err), "vlsync_client_wait_next: the client is NULL");
            assert_eq!(
                vlsync_client_wait_one(null, 0, &mut est, err.as_mut_ptr().cast(), err.len()),
                -1
            );
            assert_eq!(text(&err), "vlsync_client_wait_one: the client is NULL");
            assert_eq!(vlsync_client_latest(null, &mut est), -1);
            assert_eq!(vlsync_client_camera_to_lidar(null, 0, &mut conv), -1);
            assert_eq!(
                vlsync_client_latest_err(null, &mut est, err.as_mut_ptr().cast(), err.len()),
                -1
            );
            assert_eq!(text(&err), "vlsync_client_latest_err: the client is NULL");
            assert_eq!(
                vlsync_client_camera_to_lidar_err(
                    null,
                    0,
                    &mut conv,
                    err.as_mut_ptr().cast(),
                    err.len()
                ),
                -1
            );
            assert_eq!(
                text(&err),
                "vlsync_client_camera_to_lidar_err: the client is NULL"
            );
            assert_eq!(vlsync_estimate_age_ns(std::ptr::null()), -1);
            assert_eq!(
                vlsync_client_set_process_noise(null, 0.0, 0.0, std::ptr::null_mut(), 0),
                -1
            );
            assert_eq!(vlsync_client_invalid_count(null), 0);
            assert_eq!(vlsync_status_invalid_count(std::ptr::null_mut()), 0);
            assert_eq!(vlsync_client_close(null), 0);
        }
    }

    #[test]
    fn an_invalid_prefix_names_itself_and_a_short_buffer_cuts_the_message() {
        let mut err = [0xAAu8; 24];
        // SAFETY: valid pointers: C strings, buffers with their true lengths, and handles from vlsync_client_open not yet closed.
        let c = unsafe { vlsync_client_open(c"/bad".as_ptr(), err.as_mut_ptr().cast(), err.len()) };
        assert!(c.is_null());
        let m = text(&err);
        assert_eq!(m.len(), 23, "{m}");
        assert!(m.starts_with("vlsync_client_open: "), "{m}");
        // no buffer at all: still NULL, nothing written anywhere
        // SAFETY: valid pointers: C strings, buffers with their true lengths, and handles from vlsync_client_open not yet closed.
        let c = unsafe { vlsync_client_open(c"/bad".as_ptr(), std::ptr::null_mut(), 99) };
        assert!(c.is_null());
        let mut long = [0u8; 200];
        let c =
            // SAFETY: valid pointers: C strings, buffers with their true lengths, and handles from vlsync_client_open not yet closed.
            unsafe { vlsync_client_open(c"/bad".as_ptr(), long.as_mut_ptr().cast(), long.len()) };
        assert!(c.is_null());
        assert!(
            text(&long).contains("\"/bad\" is invalid"),
            "{}",
            text(&long)
        );
        let mut bytes = *b"\xff\xfe\0";
        // SAFETY: valid pointers: C strings, buffers with their true lengths, and handles from vlsync_client_open not yet closed.
        let c = unsafe {
            vlsync_client_open(
                bytes.as_mut_ptr().cast(),
                long.as_mut_ptr().cast(),
                long.len(),
            )
        };
        assert!(c.is_null());
        assert!(text(&long).contains("not UTF-8"), "{}", text(&long));
        // a prefix without its NUL within 202 bytes: refused after reading those
        // bytes, not read on; one of 201 bytes is the ordinary too-long prefix
        let unterminated = [b'a'; 202];
        // SAFETY: 202 readable bytes, all that the bounded read may touch.
        let c = unsafe {
            vlsync_client_open(
                unterminated.as_ptr().cast(),
                long.as_mut_ptr().cast(),
                long.len(),
            )
        };
        assert!(c.is_null());
        assert_eq!(
            text(&long),
            "vlsync_client_open: the prefix is longer than 200 bytes (or not NUL-terminated)"
        );
        let too_long = std::ffi::CString::new("a".repeat(201)).unwrap();
        // SAFETY: a C string.
        let c =
            unsafe { vlsync_client_open(too_long.as_ptr(), long.as_mut_ptr().cast(), long.len()) };
        assert!(c.is_null());
        assert!(text(&long).contains("is invalid"), "{}", text(&long));
        // the boundary: 200 bytes is within the bounded read, so the prefix rule judges
        // it (here its trailing `/`), with nothing opened
        let at_limit = std::ffi::CString::new(format!("{}/", "a".repeat(199))).unwrap();
        assert_eq!(at_limit.as_bytes().len(), vlsync_config::MAX_PREFIX_BYTES);
        // SAFETY: a C string.
        let c =
            unsafe { vlsync_client_open(at_limit.as_ptr(), long.as_mut_ptr().cast(), long.len()) };
        assert!(c.is_null());
        let m = text(&long);
        assert!(m.starts_with("vlsync_client_open: prefix \"aaa"), "{m}");
        assert!(m.contains("\"... is invalid"), "{m}");
    }

    #[test]
    fn a_handle_answers_only_on_its_own_thread_and_reads_nothing_before_a_daemon() {
        let prefix = format!("vlsync/capi-unit-{}", std::process::id());
        let cp = std::ffi::CString::new(prefix).unwrap();
        let mut err = [0u8; 300];
        // SAFETY: valid pointers: C strings, buffers with their true lengths, and handles from vlsync_client_open not yet closed.
        let c = unsafe { vlsync_client_open(cp.as_ptr(), err.as_mut_ptr().cast(), err.len()) };
        assert!(!c.is_null(), "{}", text(&err));
        let mut est = OffsetEstimate::from_estimate(&zero(), 0).unwrap();
        // SAFETY: valid pointers: C strings, buffers with their true lengths, and handles from vlsync_client_open not yet closed.
        unsafe {
            assert_eq!(vlsync_client_latest(c, &mut est), 0);
            assert_eq!(
                vlsync_client_latest_err(c, &mut est, err.as_mut_ptr().cast(), err.len()),
                0
            );
            let mut conv = VlsyncConversion {
                t_lidar_ns: 0,
                std_s: 0.0,
                estimate: est,
            };
            assert_eq!(vlsync_client_camera_to_lidar(c, 0, &mut conv), 0);
            assert_eq!(
                vlsync_client_camera_to_lidar_err(
                    c,
                    0,
                    &mut conv,
                    err.as_mut_ptr().cast(),
                    err.len()
                ),
                0
            );
            // a valid handle with a NULL out: -1, with the reason where there is a buffer
            assert_eq!(vlsync_client_latest(c, std::ptr::null_mut()), -1);
            assert_eq!(
                vlsync_client_camera_to_lidar(c, 0, std::ptr::null_mut()),
                -1
            );
            assert_eq!(
                vlsync_client_latest_err(
                    c,
                    std::ptr::null_mut(),
                    err.as_mut_ptr().cast(),
                    err.len()
                ),
                -1
            );
            assert_eq!(text(&err), "vlsync_client_latest_err: out is NULL");
            assert_eq!(
                vlsync_client_camera_to_lidar_err(
                    c,
                    0,
                    std::ptr::null_mut(),
                    err.as_mut_ptr().cast(),
                    err.len()
                ),
                -1
            );
            assert_eq!(text(&err), "vlsync_client_camera_to_lidar_err: out is NULL");
            assert_eq!(
                vlsync_client_wait_next(c, 20, &mut est, err.as_mut_ptr().cast(), err.len()),
                0
            );
            assert_eq!(
                vlsync_client_wait_next(
                    c,
                    20,
                    std::ptr::null_mut(),
                    err.as_mut_ptr().cast(),
                    err.len()
                ),
                -1
            );
            assert_eq!(text(&err), "vlsync_client_wait_next: out is NULL");
            assert_eq!(
                vlsync_client_wait_one(c, 20, &mut est, err.as_mut_ptr().cast(), err.len()),
                0
            );
            assert_eq!(
                vlsync_client_wait_one(
                    c,
                    0,
                    std::ptr::null_mut(),
                    err.as_mut_ptr().cast(),
                    err.len()
                ),
                -1
            );
            assert_eq!(text(&err), "vlsync_client_wait_one: out is NULL");
            assert_eq!(
                vlsync_client_set_process_noise(
                    c,
                    f64::NAN,
                    1.0,
                    err.as_mut_ptr().cast(),
                    err.len()
                ),
                -1
            );
            assert!(text(&err).contains("tracking walk NaN"), "{}", text(&err));
            assert_eq!(
                vlsync_client_set_process_noise(c, 1e-4, 1e-3, std::ptr::null_mut(), 0),
                0
            );
        }
        // another thread is refused, and cannot close it
        let addr = c as usize;
        let (code, closed, msg) = std::thread::spawn(move || {
            let c = addr as *mut VlsyncClient;
            let mut err = [0u8; 300];
            let mut est = OffsetEstimate::from_estimate(&zero(), 0).unwrap();
            // SAFETY: valid pointers: C strings, buffers with their true lengths, and handles from vlsync_client_open not yet closed.
            let code = unsafe {
                vlsync_client_wait_next(c, 0, &mut est, err.as_mut_ptr().cast(), err.len())
            };
            // SAFETY: as above
            let one = unsafe { vlsync_client_wait_one(c, 0, &mut est, std::ptr::null_mut(), 0) };
            let mut latest_err = [0u8; 300];
            // SAFETY: as above
            let latest = unsafe {
                (
                    vlsync_client_latest(c, &mut est),
                    vlsync_client_latest_err(
                        c,
                        &mut est,
                        latest_err.as_mut_ptr().cast(),
                        latest_err.len(),
                    ),
                )
            };
            assert_eq!(latest, (-1, -1));
            assert!(
                text(&latest_err).starts_with(
                    "vlsync_client_latest_err: the client was opened on another thread"
                ),
                "{}",
                text(&latest_err)
            );
            // SAFETY: as above
            let count = unsafe { vlsync_client_invalid_count(c) };
            // SAFETY: valid pointers: C strings, buffers with their true lengths, and handles from vlsync_client_open not yet closed.
            let closed = unsafe { vlsync_client_close(c) };
            ((code, one, count), closed, text(&err))
        })
        .join()
        .unwrap();
        assert_eq!((code, closed), ((-1, -1, 0), -1));
        assert!(msg.contains("another thread"), "{msg}");
        // SAFETY: valid pointers: C strings, buffers with their true lengths, and handles from vlsync_client_open not yet closed.
        assert_eq!(unsafe { vlsync_client_close(c) }, 0);
    }

    /// A handle closed already (closed twice, used after close), a handle of the other
    /// type and a pointer that never was a handle are errors, not a use-after-free or
    /// a double free: every call finds its handle among the open ones first.
    #[test]
    fn a_closed_or_foreign_handle_is_an_error_not_a_crash() {
        let prefix = format!("vlsync/capi-closed-{}", std::process::id());
        let cp = std::ffi::CString::new(prefix).unwrap();
        let mut err = [0u8; 300];
        // SAFETY: a C string and a buffer with its true length
        let (c, st) = unsafe {
            (
                vlsync_client_open(cp.as_ptr(), err.as_mut_ptr().cast(), err.len()),
                vlsync_status_open(cp.as_ptr(), err.as_mut_ptr().cast(), err.len()),
            )
        };
        assert!(!c.is_null() && !st.is_null(), "{}", text(&err));
        let mut est = OffsetEstimate::from_estimate(&zero(), 0).unwrap();
        // SAFETY: every pointer below is NULL-free and the buffers have their true
        // lengths; the handles are checked by the library, which is what is tested
        unsafe {
            assert_eq!(vlsync_client_close(c), 0);
            // closed twice, then used after close
            assert_eq!(vlsync_client_close(c), -1);
            assert_eq!(vlsync_client_latest(c, &mut est), -1);
            assert_eq!(
                vlsync_client_latest_err(c, &mut est, err.as_mut_ptr().cast(), err.len()),
                -1
            );
            assert_eq!(
                text(&err),
                "vlsync_client_latest_err: not an open handle (closed already, or not one this library opened)"
            );
            assert_eq!(vlsync_client_invalid_count(c), 0);
            // the status handle passed as an offset client, and a made-up pointer
            for bogus in [
                st.cast::<VlsyncClient>(),
                std::ptr::without_provenance_mut::<VlsyncClient>(0x1234_5678),
            ] {
                assert_eq!(
                    vlsync_client_wait_next(bogus, 0, &mut est, err.as_mut_ptr().cast(), err.len()),
                    -1
                );
                assert!(text(&err).contains("not an open handle"), "{}", text(&err));
                assert_eq!(vlsync_client_close(bogus), -1);
            }
            // the status handle itself is still open, and closes once
            assert_eq!(vlsync_status_close(st), 0);
            assert_eq!(vlsync_status_close(st), -1);
        }
    }

    /// A panic inside a call is an error naming the function and the panic's message
    /// (a `&str` or a `String` payload), not an unwind across the C boundary.
    #[test]
    fn a_panic_is_caught_and_named() {
        let r: CallResult<()> = guarded("vlsync_f", || panic!("boom"));
        assert_eq!(r, Err("vlsync_f: internal error: boom".to_string()));
        let n = 7;
        let r: CallResult<()> = guarded("vlsync_g", || panic!("boom {n}"));
        assert_eq!(r, Err("vlsync_g: internal error: boom 7".to_string()));
        let r: CallResult<()> = guarded("vlsync_h", || std::panic::panic_any(42u8));
        assert_eq!(
            r,
            Err("vlsync_h: internal error: unknown panic".to_string())
        );
        assert_eq!(guarded("vlsync_i", || Ok(3)), Ok(3));
    }

    /// The header's macros are the Rust values: ABI version and minor, states, reject
    /// reasons, polarity (and `vlsync_wire.h`, which defines the same names, agrees).
    #[test]
    fn the_headers_macros_are_the_rust_values() {
        let header = include_str!("../include/vlsync_client.h");
        let wire = include_str!("../../examples/c/vlsync_wire.h");
        let defines = |text: &str| -> std::collections::HashMap<String, String> {
            text.lines()
                .filter_map(|l| l.strip_prefix("#define VLSYNC_"))
                .filter_map(|l| {
                    let l = l.split("/*").next().unwrap();
                    let mut w = l.split_whitespace();
                    Some((
                        format!("VLSYNC_{}", w.next()?),
                        w.collect::<Vec<_>>().join(" "),
                    ))
                })
                .collect()
        };
        let (h, w) = (defines(header), defines(wire));
        let int = |name: &str| -> i64 {
            let v = h
                .get(name)
                .unwrap_or_else(|| panic!("{name} not in vlsync_client.h"));
            let v = v
                .trim_end_matches('u')
                .trim_start_matches('(')
                .trim_end_matches(')');
            match v.strip_prefix("0x").or_else(|| v.strip_prefix("0X")) {
                Some(hex) => i64::from_str_radix(hex, 16).unwrap(),
                None => v.parse().unwrap_or_else(|_| panic!("{name} = {v}")),
            }
        };
        assert_eq!(int("VLSYNC_CLIENT_ABI_VERSION"), i64::from(ABI_VERSION));
        assert_eq!(int("VLSYNC_CLIENT_ABI_MINOR"), i64::from(ABI_MINOR));
        for s in [
            EstimatorState::Acquiring,
            EstimatorState::Tracking,
            EstimatorState::Holding,
            EstimatorState::Lost,
        ] {
            let name = format!("VLSYNC_STATE_{}", s.name().to_uppercase());
            assert_eq!(int(&name), i64::from(s as u8), "{name}");
        }
        assert_eq!(
            int("VLSYNC_STATE_NONE"),
            i64::from(vlsync_common::wire::STATE_NONE)
        );
        for p in [Polarity::Unknown, Polarity::Positive, Polarity::Negative] {
            let name = format!("VLSYNC_POLARITY_{}", p.name().to_uppercase());
            assert_eq!(int(&name), i64::from(p as i8), "{name}");
        }
        for (i, r) in vlsync_common::wire::REJECT_NAMES.iter().enumerate() {
            let name = format!("VLSYNC_REJECT_{}", r.to_uppercase());
            assert_eq!(int(&name), i as i64, "{name}");
        }
        assert_eq!(
            int("VLSYNC_REJECT_REASONS"),
            vlsync_common::wire::REJECT_REASONS as i64
        );
        // every name both headers define has one definition (including both is fine)
        let mut shared = 0;
        for (name, v) in &h {
            if let Some(wv) = w.get(name) {
                assert_eq!(
                    v, wv,
                    "{name} differs between vlsync_client.h and vlsync_wire.h"
                );
                shared += 1;
            }
        }
        assert_eq!(
            shared,
            4 + 1 + 3 + 6,
            "states, NONE, polarity, reject reasons"
        );
    }

    /// A raw publisher on the offset service: the `_err` calls hand out what it sends,
    /// with the publish time, and the age is measured against `CLOCK_MONOTONIC`.
    #[test]
    fn the_err_variants_and_the_age_of_an_estimate() {
        let rig = OffsetRig::open("age");
        let (publ, c) = (&rig.publ, rig.c);
        let mut err = [0u8; 300];
        let e = Estimate {
            seq: 9,
            t_ref_ns: 10_000_000_000,
            offset_s: 0.02,
            state: EstimatorState::Tracking,
            polarity: Polarity::Positive,
            ..zero()
        };
        // published 5 s ago, as by a daemon that stopped since
        let published = vlsync_ipc::monotonic_ns() - 5_000_000_000;
        publ.send_copy(OffsetEstimate::from_estimate(&e, published).unwrap())
            .unwrap();
        let mut est = OffsetEstimate::from_estimate(&zero(), 0).unwrap();
        let mut conv = VlsyncConversion {
            t_lidar_ns: 0,
            std_s: 0.0,
            estimate: est,
        };
        // SAFETY: an open handle of this thread, writable outputs, buffers with their
        // lengths; the unaligned copy is written and read within `bytes`, which holds an
        // estimate's size after its first byte, with `write_unaligned` and a function
        // that reads it unaligned
        unsafe {
            assert_eq!(
                vlsync_client_latest_err(c, &mut est, err.as_mut_ptr().cast(), err.len()),
                1,
                "{}",
                text(&err)
            );
            assert_eq!((est.seq, est.publish_ns, est.state), (9, published, 1));
            let age = vlsync_estimate_age_ns(&est);
            assert!((5_000_000_000..6_000_000_000).contains(&age), "{age}");
            assert_eq!(
                vlsync_client_camera_to_lidar_err(
                    c,
                    5_000_000_000,
                    &mut conv,
                    err.as_mut_ptr().cast(),
                    err.len()
                ),
                1,
                "{}",
                text(&err)
            );
            assert_eq!(conv.t_lidar_ns, 5_020_000_000);
            assert_eq!(
                (conv.estimate.seq, conv.estimate.publish_ns),
                (9, published)
            );
            // still "tracking", still handed out: only its age tells it is stale
            assert_eq!(vlsync_client_latest(c, &mut est), 1);
            assert_eq!(est.state, 1);
            assert!(vlsync_estimate_age_ns(&conv.estimate) >= 5_000_000_000);
            // an unaligned copy reads the same
            let mut bytes = [0u8; size_of::<OffsetEstimate>() + 1];
            std::ptr::write_unaligned(bytes.as_mut_ptr().add(1).cast::<OffsetEstimate>(), est);
            let unaligned = bytes.as_ptr().add(1).cast::<OffsetEstimate>();
            assert!(vlsync_estimate_age_ns(unaligned) >= 5_000_000_000);
            // a publish time far in the future (another clock, a faulty publisher)
            // fails every age check; one just ahead is age 0, not negative
            est.publish_ns = i64::MAX;
            assert_eq!(vlsync_estimate_age_ns(&est), i64::MAX);
            est.publish_ns = vlsync_ipc::monotonic_ns() + 500_000_000;
            assert_eq!(vlsync_estimate_age_ns(&est), 0);
            assert_eq!(vlsync_client_close(c), 0);
        }
    }

    /// A conversion with a drift that matters, for stamps 12 s before and 15 s after
    /// t_ref and an hour after it: libvlsync_client gives `vlsync_common`'s LiDAR time
    /// (`Estimate::camera_to_lidar`) and σ (`Estimate::offset_std_with_walk` at the
    /// walk of the estimate's state: the shipped `estimator.offset_process_noise` while
    /// tracking, `hold_process_noise` otherwise, or the ones
    /// `vlsync_client_set_process_noise` set) bit for bit, where the other tests
    /// convert with drift 0.
    #[test]
    fn a_conversion_with_drift_far_from_t_ref_is_the_rust_one() {
        let rig = OffsetRig::open("drift");
        let (publ, c) = (&rig.publ, rig.c);
        let mut err = [0u8; 300];
        let shipped = vlsync_config::EstimatorConfig::default();
        let shipped = (shipped.offset_process_noise, shipped.hold_process_noise);
        let mut conv = VlsyncConversion {
            t_lidar_ns: 0,
            std_s: 0.0,
            estimate: OffsetEstimate::from_estimate(&zero(), 0).unwrap(),
        };
        for (seq, state, drift, walks) in [
            (1, EstimatorState::Tracking, 4.2e-5, shipped),
            (2, EstimatorState::Holding, -2.75e-4, shipped),
            (3, EstimatorState::Tracking, 1e-3, (1e-4, 5e-3)),
            (4, EstimatorState::Lost, -3.1e-6, (1e-4, 5e-3)),
        ] {
            if walks != shipped {
                // SAFETY: an open handle of this thread, no error buffer
                let set = unsafe {
                    vlsync_client_set_process_noise(c, walks.0, walks.1, std::ptr::null_mut(), 0)
                };
                assert_eq!(set, 0);
            }
            let e = Estimate {
                seq,
                t_ref_ns: 1_234_567_890_123,
                offset_s: 0.1 / 3.0,
                drift,
                offset_std_s: 0.0011,
                drift_std: 3.3e-7,
                state,
                polarity: Polarity::Positive,
                peak_score: 0.8,
                peak_ratio: 2.0,
                measured_offset_s: f64::NAN,
            };
            publ.send_copy(OffsetEstimate::from_estimate(&e, vlsync_ipc::monotonic_ns()).unwrap())
                .unwrap();
            let walk = if state == EstimatorState::Tracking {
                walks.0
            } else {
                walks.1
            };
            for from_ref in [-12_345_678_901i64, 15_000_000_001, 3_600_000_000_000] {
                let t_cam = e.t_ref_ns + from_ref;
                // SAFETY: an open handle of this thread, a writable output, a buffer
                // with its length
                let got = unsafe {
                    vlsync_client_camera_to_lidar_err(
                        c,
                        t_cam,
                        &mut conv,
                        err.as_mut_ptr().cast(),
                        err.len(),
                    )
                };
                assert_eq!(got, 1, "{}", text(&err));
                assert_eq!(conv.estimate.seq, seq);
                let want_t = e.camera_to_lidar(t_cam);
                let want_std = e.offset_std_with_walk(want_t, walk);
                assert_eq!(
                    (conv.t_lidar_ns, conv.std_s.to_bits()),
                    (want_t, want_std.to_bits()),
                    "{state:?} at {from_ref} ns from t_ref: C {} ± {}, Rust {want_t} ± {want_std}",
                    conv.t_lidar_ns,
                    conv.std_s
                );
                // the drift and the walk matter here: the offset at t_ref alone, or
                // the σ at t_ref, would fail the comparison above
                assert_ne!(want_t, t_cam + vlsync_common::secs_to_nanos(e.offset_s));
                assert!(want_std > 1.01 * e.offset_std_s, "{want_std}");
            }
        }
        // SAFETY: an open handle of this thread
        assert_eq!(unsafe { vlsync_client_close(c) }, 0);
    }

    /// A status service that has carried only invalid payloads: -1 with the
    /// validation error, where a silent one is 0.
    #[test]
    fn status_latest_after_only_invalid_payloads_is_an_error() {
        use vlsync_ipc::{create_node, open_or_create_pubsub, publisher, Qos, ServiceNames};
        let names =
            ServiceNames::new(&format!("vlsync/capi-badstatus-{}", std::process::id())).unwrap();
        let node = create_node("capi-test-daemon", false).unwrap();
        let svc = open_or_create_pubsub::<Status>(&node, &names.status(), Qos::latest()).unwrap();
        let publ = publisher(&svc, "status").unwrap();
        let cp = std::ffi::CString::new(names.prefix.clone()).unwrap();
        let mut err = [0u8; 300];
        // SAFETY: a C string and a buffer with its true length
        let c = unsafe { vlsync_status_open(cp.as_ptr(), err.as_mut_ptr().cast(), err.len()) };
        assert!(!c.is_null(), "{}", text(&err));
        let mut st = Status::default();
        // SAFETY: an open status handle of this thread, a writable output, a buffer
        unsafe {
            assert_eq!(
                vlsync_status_latest(c, &mut st, err.as_mut_ptr().cast(), err.len()),
                0
            );
            publ.send_copy(Status {
                degraded: 9,
                ..Status::default()
            })
            .unwrap();
            assert_eq!(
                vlsync_status_latest(c, &mut st, err.as_mut_ptr().cast(), err.len()),
                -1
            );
            let m = text(&err);
            assert!(
                m.starts_with("vlsync_status_latest: invalid status payload"),
                "{m}"
            );
            // a valid one after it: written; an invalid one then is skipped
            publ.send_copy(Status {
                estimates_published: 4,
                ..Status::default()
            })
            .unwrap();
            assert_eq!(
                vlsync_status_latest(c, &mut st, err.as_mut_ptr().cast(), err.len()),
                1
            );
            publ.send_copy(Status {
                degraded: 9,
                ..Status::default()
            })
            .unwrap();
            assert_eq!(
                vlsync_status_latest(c, &mut st, err.as_mut_ptr().cast(), err.len()),
                1
            );
            assert_eq!(st.estimates_published, 4);
            assert_eq!(vlsync_status_close(c), 0);
        }
    }

    #[test]
    fn state_names() {
        let name = |s| {
            // SAFETY: vlsync_state_name returns a static NUL-terminated string.
            unsafe { CStr::from_ptr(vlsync_state_name(s)) }
                .to_str()
                .unwrap()
        };
        assert_eq!(
            [name(0), name(1), name(2), name(3), name(4), name(255)],
            [
                "acquiring",
                "tracking",
                "holding",
                "lost",
                "unknown",
                "unknown"
            ]
        );
        assert_eq!(vlsync_client_abi_version(), ABI_VERSION);
        assert_eq!(vlsync_client_abi_minor(), ABI_MINOR);
    }

    fn zero() -> Estimate {
        Estimate {
            seq: 0,
            t_ref_ns: 0,
            offset_s: 0.0,
            drift: 0.0,
            offset_std_s: 0.0,
            drift_std: 0.0,
            state: EstimatorState::Acquiring,
            polarity: Polarity::Unknown,
            peak_score: 0.0,
            peak_ratio: 0.0,
            measured_offset_s: f64::NAN,
        }
    }

    proptest::proptest! {
        /// Any message into any buffer: NUL-terminated within it, a prefix of the
        /// message up to its first NUL, valid UTF-8, as long as fits.
        #[test]
        fn messages_fit_their_buffer(msg in ".{0,80}", cap in 0usize..100) {
            let mut buf = vec![0xAAu8; cap + 4];
            // SAFETY: `buf` holds `cap + 4` bytes
            unsafe { write_message(buf.as_mut_ptr().cast(), cap, &msg) };
            // nothing beyond the buffer
            proptest::prop_assert!(buf[cap..].iter().all(|&b| b == 0xAA));
            if cap == 0 {
                return Ok(());
            }
            let got = text(&buf[..cap]);
            let whole = msg.split('\0').next().unwrap();
            proptest::prop_assert!(whole.starts_with(&got));
            // the cut is as late as fits: the next character would not
            if got.len() < whole.len() {
                let next = whole[got.len()..].chars().next().unwrap().len_utf8();
                proptest::prop_assert!(got.len() + next > cap - 1);
            }
        }
    }
}
