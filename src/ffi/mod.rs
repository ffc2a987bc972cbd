//! The C ABI: what `include/ndfmap.h` declares (generated from these files by cbindgen, see
//! `tests/header.rs`). C and C++ engines load a normal map ([`map`]), bake it with one of the
//! methods and pack, query or write the result ([`bake`]), get the GLSL source that reads it
//! ([`shader`]), and describe the material it is shaded with ([`brdf`]: SH coefficients,
//! tabulated BRDF tables). This file holds what every entry point shares: [`ndf_status`], the
//! thread-local error message, the panic guard, argument checks and the version.
//!
//! Conventions (DESIGN.md "C API conventions"):
//! - Functions are `ndf_<object>_<verb>`, constants `NDF_*`, types `ndf_*`; handles are opaque
//!   and released by `ndf_*_free`, which accepts NULL.
//! - Every fallible function returns an [`ndf_status`]; out-parameters come last, must not be
//!   NULL, and are written only on success. [`ndf_last_error_message`] explains a failure.
//! - Enumerations arrive as `uint32_t` and are validated as integers before use (a Rust enum
//!   taken from C with an unknown value would be undefined behaviour).
//! - Every exported body runs inside `guard`: a panic becomes [`ndf_status::Panic`] and a
//!   message instead of unwinding into the host (the crate never builds with `panic = "abort"`).
//! - `unsafe` appears only in this module, each block with the reason it is sound.

#![allow(non_camel_case_types)]

// The header declares the maps' functions, then the bakes', then the shaders' (cbindgen keeps
// this order; the blank lines keep rustfmt from sorting them).
pub mod map;

pub mod bake;

pub mod container;

pub mod shader;

pub mod brdf;

pub mod plan;

pub mod env;
#[cfg(test)]
mod tests;

use crate::error::Error;
use std::cell::RefCell;
use std::ffi::{CStr, CString, c_char};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::PathBuf;

/// Major version of the library this header belongs to (checked against `Cargo.toml` by a test).
pub const NDF_VERSION_MAJOR: u32 = 0;
/// Minor version.
pub const NDF_VERSION_MINOR: u32 = 1;
/// Patch version.
pub const NDF_VERSION_PATCH: u32 = 0;
/// The version as one number, `MAJOR << 16 | MINOR << 8 | PATCH`: what `ndf_version()` returns
/// for the library this header was generated with.
pub const NDF_VERSION: u32 = 0x00_01_00;

/// Status of a call. `NDF_STATUS_OK` (0) is success; the numbers are stable and never reused.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ndf_status {
    /// Success.
    Ok = 0,
    /// A required pointer argument (handle, input or out-parameter) was NULL.
    NullArgument = 1,
    /// An argument has a value outside its domain: an unknown enumeration value, an options
    /// struct whose `struct_size` is not this version's, an option out of its range.
    InvalidArgument = 2,
    /// A texture, level or channel index past the end.
    OutOfRange = 3,
    /// A caller buffer's capacity is smaller than the size the call needs; nothing was written.
    BufferTooSmall = 4,
    /// A file could not be read (missing, permission denied, ...).
    Read = 5,
    /// Bytes that are not a decodable image (corrupt, truncated, unknown format).
    Decode = 6,
    /// An image whose channels cannot be read as requested (a one-channel height map, ...).
    UnsupportedLayout = 7,
    /// Width or height zero or too large, or width × height beyond the supported texel count.
    Dimensions = 8,
    /// A pixel buffer shorter than width × height × channels samples.
    ShortPixels = 9,
    /// A feature (colour) image whose size differs from the normal map's.
    FeatureSize = 10,
    /// Bad normals (zero-length, NaN, below the horizon) with `NDF_BAD_NORMALS_REJECT`.
    BadNormals = 11,
    /// A texture that the requested storage format cannot hold (LEAN's unbounded moments in a
    /// unorm format, a value beyond the f16 range).
    UnsupportedFormat = 12,
    /// Output could not be written.
    Write = 13,
    /// The progress callback asked to stop.
    Cancelled = 14,
    /// An internal error (a bug in ndfmap) was caught at the boundary; the message says where.
    /// Handles passed to the call are still valid; the call had no other effect.
    Panic = 15,
    /// Decoding the file or running the bake would need more memory than the budget
    /// (`memory_limit` of the options, or half the machine's memory by default); refused before
    /// allocating. The message names the size, the estimate and the budget.
    MemoryBudget = 16,
    /// A feature (colour) image has NaN, infinite or negative values with
    /// `NDF_BAD_NORMALS_REJECT`.
    BadFeatures = 17,
}

/// Every status, in number order.
const STATUSES: [ndf_status; 18] = [
    ndf_status::Ok,
    ndf_status::NullArgument,
    ndf_status::InvalidArgument,
    ndf_status::OutOfRange,
    ndf_status::BufferTooSmall,
    ndf_status::Read,
    ndf_status::Decode,
    ndf_status::UnsupportedLayout,
    ndf_status::Dimensions,
    ndf_status::ShortPixels,
    ndf_status::FeatureSize,
    ndf_status::BadNormals,
    ndf_status::UnsupportedFormat,
    ndf_status::Write,
    ndf_status::Cancelled,
    ndf_status::Panic,
    ndf_status::MemoryBudget,
    ndf_status::BadFeatures,
];

impl ndf_status {
    /// The constant's name in the header.
    fn name(self) -> &'static CStr {
        match self {
            ndf_status::Ok => c"NDF_STATUS_OK",
            ndf_status::NullArgument => c"NDF_STATUS_NULL_ARGUMENT",
            ndf_status::InvalidArgument => c"NDF_STATUS_INVALID_ARGUMENT",
            ndf_status::OutOfRange => c"NDF_STATUS_OUT_OF_RANGE",
            ndf_status::BufferTooSmall => c"NDF_STATUS_BUFFER_TOO_SMALL",
            ndf_status::Read => c"NDF_STATUS_READ",
            ndf_status::Decode => c"NDF_STATUS_DECODE",
            ndf_status::UnsupportedLayout => c"NDF_STATUS_UNSUPPORTED_LAYOUT",
            ndf_status::Dimensions => c"NDF_STATUS_DIMENSIONS",
            ndf_status::ShortPixels => c"NDF_STATUS_SHORT_PIXELS",
            ndf_status::FeatureSize => c"NDF_STATUS_FEATURE_SIZE",
            ndf_status::BadNormals => c"NDF_STATUS_BAD_NORMALS",
            ndf_status::UnsupportedFormat => c"NDF_STATUS_UNSUPPORTED_FORMAT",
            ndf_status::Write => c"NDF_STATUS_WRITE",
            ndf_status::Cancelled => c"NDF_STATUS_CANCELLED",
            ndf_status::Panic => c"NDF_STATUS_PANIC",
            ndf_status::MemoryBudget => c"NDF_STATUS_MEMORY_BUDGET",
            ndf_status::BadFeatures => c"NDF_STATUS_BAD_FEATURES",
        }
    }
}

/// The name of a status (`"NDF_STATUS_BUFFER_TOO_SMALL"`), or `"NDF_STATUS_UNKNOWN"` for a
/// number that is not a status.
/// - The string is static: never free it.
#[unsafe(no_mangle)]
pub extern "C" fn ndf_status_str(status: u32) -> *const c_char {
    guard_value(c"NDF_STATUS_PANIC".as_ptr(), || {
        STATUSES
            .get(status as usize)
            .map_or(c"NDF_STATUS_UNKNOWN", |s| s.name())
            .as_ptr()
    })
}

thread_local! {
    /// The message of the most recent failure on this thread.
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

/// Explains the most recent failure on the calling thread in words, naming the function, the
/// file or argument and the problem (`"ndf_bake_pack: buffer of 255 bytes is too small: ..."`);
/// `""` when no call on this thread has failed.
/// - The string belongs to the library: do not free it. It stays valid until the next failing
///   call on the same thread.
/// - Successful calls leave it unchanged.
#[unsafe(no_mangle)]
pub extern "C" fn ndf_last_error_message() -> *const c_char {
    guard_value(c"".as_ptr(), || LAST_ERROR.with(|m| m.borrow().as_ptr()))
}

/// The library's version at run time, `MAJOR << 16 | MINOR << 8 | PATCH` (compare with
/// `NDF_VERSION` to detect a header/library mismatch).
#[unsafe(no_mangle)]
pub extern "C" fn ndf_version() -> u32 {
    guard_value(0, || {
        let part = |s: &str| s.parse::<u32>().unwrap_or(0);
        part(env!("CARGO_PKG_VERSION_MAJOR")) << 16
            | part(env!("CARGO_PKG_VERSION_MINOR")) << 8
            | part(env!("CARGO_PKG_VERSION_PATCH"))
    })
}

/// The library's version at run time as text, `"MAJOR.MINOR.PATCH"`.
/// - The string is static: never free it.
#[unsafe(no_mangle)]
pub extern "C" fn ndf_version_string() -> *const c_char {
    guard_value(c"".as_ptr(), || {
        concat!(env!("CARGO_PKG_VERSION"), "\0").as_ptr().cast()
    })
}

/// A failed call: its status and the message for [`ndf_last_error_message`].
pub(crate) struct Failure {
    status: ndf_status,
    message: String,
}

/// What an entry point's body returns.
pub(crate) type Outcome<T = ()> = Result<T, Failure>;

/// A failure with `status` and `message`.
pub(crate) fn fail(status: ndf_status, message: impl Into<String>) -> Failure {
    Failure {
        status,
        message: message.into(),
    }
}

impl From<Error> for Failure {
    fn from(e: Error) -> Self {
        let status = match &e {
            Error::Read { .. } => ndf_status::Read,
            Error::Decode { .. } => ndf_status::Decode,
            Error::UnsupportedLayout { .. } => ndf_status::UnsupportedLayout,
            Error::Dimensions { .. } => ndf_status::Dimensions,
            Error::ShortBuffer { .. } => ndf_status::ShortPixels,
            Error::FeatureSize { .. } => ndf_status::FeatureSize,
            Error::BadNormals { .. } => ndf_status::BadNormals,
            Error::InvalidOption(_) | Error::Brdf { .. } => ndf_status::InvalidArgument,
            Error::Write { .. } => ndf_status::Write,
            Error::Cancelled => ndf_status::Cancelled,
            Error::MemoryBudget { .. } => ndf_status::MemoryBudget,
            Error::BadFeatures { .. } => ndf_status::BadFeatures,
            // Values a decoded environment cannot hold: reported as undecodable content.
            Error::BadEnvironment { .. } => ndf_status::Decode,
        };
        fail(status, e.to_string())
    }
}

fn set_last_error(message: String) {
    // Interior NULs (from a decoder's message, say) would end the C string early.
    let message = CString::new(message.replace('\0', "?")).unwrap_or_default();
    LAST_ERROR.with(|m| *m.borrow_mut() = message);
}

/// The text of a panic's payload.
fn panic_message(payload: &(dyn std::any::Any + Send)) -> &str {
    payload
        .downcast_ref::<&str>()
        .copied()
        .or_else(|| payload.downcast_ref::<String>().map(String::as_str))
        .unwrap_or("unknown reason")
}

/// Runs the body of entry point `function`: a failure or a panic becomes its status, with the
/// message (prefixed by `function`) stored for [`ndf_last_error_message`].
pub(crate) fn guard(function: &str, body: impl FnOnce() -> Outcome) -> ndf_status {
    let outcome = catch_unwind(AssertUnwindSafe(|| {
        #[cfg(test)]
        tests::maybe_inject_panic();
        body()
    }))
    .unwrap_or_else(|payload| {
        Err(fail(
            ndf_status::Panic,
            format!(
                "internal error (a bug in ndfmap; please report it): {}",
                panic_message(payload.as_ref())
            ),
        ))
    });
    match outcome {
        Ok(()) => ndf_status::Ok,
        Err(f) => {
            set_last_error(format!("{function}: {}", f.message));
            f.status
        }
    }
}

/// Runs the body of an entry point that cannot fail (`*_free`, `*_default`, names): a panic
/// returns `fallback` instead of unwinding into the host.
pub(crate) fn guard_value<T>(fallback: T, body: impl FnOnce() -> T) -> T {
    catch_unwind(AssertUnwindSafe(|| {
        #[cfg(test)]
        tests::maybe_inject_panic();
        body()
    }))
    .unwrap_or(fallback)
}

/// The NULL-argument failure for argument `name`.
pub(crate) fn null(name: &str) -> Failure {
    fail(ndf_status::NullArgument, format!("{name} is NULL"))
}

/// `p` as a shared reference, or a NULL-argument failure naming `name`.
///
/// # Safety
/// `p` is NULL or points to a live, initialized `T` that nothing mutates while the reference
/// lives (the entry points' documented contract).
pub(crate) unsafe fn arg<'a, T>(p: *const T, name: &str) -> Outcome<&'a T> {
    // SAFETY: the caller guarantees `p` is NULL or valid for reads of a `T` for 'a.
    unsafe { p.as_ref() }.ok_or_else(|| null(name))
}

/// `p` as an exclusive reference, or a NULL-argument failure naming `name`.
///
/// # Safety
/// `p` is NULL or points to a live `T` that nothing else accesses while the reference lives.
pub(crate) unsafe fn arg_mut<'a, T>(p: *mut T, name: &str) -> Outcome<&'a mut T> {
    // SAFETY: the caller guarantees `p` is NULL or valid and unaliased for 'a.
    unsafe { p.as_mut() }.ok_or_else(|| null(name))
}

/// An out-parameter, checked for NULL before any work so that it can be written on success.
pub(crate) struct Out<T>(*mut T);

impl<T> Out<T> {
    /// Checks `p` (argument `name`) for NULL.
    pub(crate) fn new(p: *mut T, name: &str) -> Outcome<Self> {
        if p.is_null() {
            Err(null(name))
        } else {
            Ok(Out(p))
        }
    }

    /// Writes `value`.
    ///
    /// # Safety
    /// The pointer given to [`Out::new`] is valid for writes of a `T` (it need not be aligned
    /// or initialized).
    pub(crate) unsafe fn write(self, value: T) {
        // SAFETY: non-NULL (checked in `new`) and valid for writes (the caller's contract);
        // `write_unaligned` neither reads nor drops the old contents.
        unsafe { self.0.write_unaligned(value) }
    }
}

/// `len` bytes at `p` (argument `name`), NULL refused.
///
/// # Safety
/// `p` is NULL or valid for reads of `len` bytes that nothing mutates while the slice lives.
pub(crate) unsafe fn bytes<'a>(
    p: *const std::ffi::c_void,
    len: usize,
    name: &str,
) -> Outcome<&'a [u8]> {
    if p.is_null() {
        return Err(null(name));
    }
    if len > isize::MAX as usize {
        return Err(fail(
            ndf_status::InvalidArgument,
            format!("{name}: length {len} exceeds the largest possible buffer"),
        ));
    }
    // SAFETY: non-NULL, `len` ≤ isize::MAX, and readable for `len` bytes (the caller's
    // contract); u8 has alignment 1 and every bit pattern is a valid u8.
    Ok(unsafe { std::slice::from_raw_parts(p.cast::<u8>(), len) })
}

/// A NUL-terminated string argument.
///
/// # Safety
/// `p` is NULL or points to a NUL-terminated string that lives and stays unchanged for 'a.
pub(crate) unsafe fn c_str<'a>(p: *const c_char, name: &str) -> Outcome<&'a CStr> {
    if p.is_null() {
        return Err(null(name));
    }
    // SAFETY: non-NULL and NUL-terminated (the caller's contract).
    Ok(unsafe { CStr::from_ptr(p) })
}

/// A file-system path from a C string: bytes as they are on Unix, UTF-8 elsewhere.
pub(crate) fn path(s: &CStr, name: &str) -> Outcome<PathBuf> {
    #[cfg(unix)]
    {
        use std::os::unix::ffi::OsStrExt;
        let _ = name;
        Ok(std::ffi::OsStr::from_bytes(s.to_bytes()).into())
    }
    #[cfg(not(unix))]
    {
        s.to_str().map(PathBuf::from).map_err(|_| {
            fail(
                ndf_status::InvalidArgument,
                format!("{name} is not valid UTF-8"),
            )
        })
    }
}

/// A C string argument as text (invalid UTF-8 replaced), for names in messages.
pub(crate) fn text(s: &CStr) -> String {
    s.to_string_lossy().into_owned()
}

/// Value `v` of the C enumeration `what`, whose constants are the indices of `table`.
pub(crate) fn choose<T: Copy>(what: &str, v: u32, table: &[T]) -> Outcome<T> {
    table.get(v as usize).copied().ok_or_else(|| {
        fail(
            ndf_status::InvalidArgument,
            format!(
                "unknown {what} value {v} (expected 0 to {})",
                table.len() - 1
            ),
        )
    })
}

/// A `memory_limit` field of an options struct: bytes, 0 for the default budget.
pub(crate) fn memory_limit(bytes: u64) -> Option<u64> {
    (bytes != 0).then_some(bytes)
}

/// An index argument below `count`, or an out-of-range failure.
pub(crate) fn index(what: &str, v: u32, count: usize) -> Outcome<usize> {
    let i = v as usize;
    if i < count {
        Ok(i)
    } else {
        Err(fail(
            ndf_status::OutOfRange,
            format!("{what} {v} is out of range (there are {count})"),
        ))
    }
}

/// An options struct whose first field is its `struct_size`.
///
/// # Safety
/// `p` is NULL or points to at least a `size_t` that, when it equals `size_of::<T>()`, is the
/// first field of a live, initialized `T`.
pub(crate) unsafe fn read_options<'a, T>(p: *const T, name: &str, init: &str) -> Outcome<&'a T> {
    if p.is_null() {
        return Err(null(name));
    }
    // SAFETY: non-NULL; every options struct starts with a `size_t struct_size` (repr(C), first
    // field), so reading one `usize` is within the caller's struct whatever its version.
    let size = unsafe { p.cast::<usize>().read_unaligned() };
    if size != size_of::<T>() {
        return Err(fail(
            ndf_status::InvalidArgument,
            format!(
                "{name}->struct_size is {size}, this library expects {} (initialize the struct \
                 with {init}())",
                size_of::<T>()
            ),
        ));
    }
    // SAFETY: the size matches, so `p` points to a whole `T` (the caller's contract).
    unsafe { arg(p, name) }
}
