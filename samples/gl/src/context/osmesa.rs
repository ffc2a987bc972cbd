//! The OSMesa route: `libOSMesa.so.8` loaded at run time, a core 3.3 context from
//! `OSMesaCreateContextAttribs`, current on a small buffer the context owns (drawing goes to
//! framebuffer objects, so the buffer is never drawn to).

use super::Route;
use crate::{Error, Result};
use libloading::Library;
use std::ffi::{c_char, c_int, c_void};
use std::ptr;
use std::sync::OnceLock;

/// The library file: the soname of Mesa's gallium OSMesa (Debian `libosmesa6`).
const LIBRARY: &str = "libOSMesa.so.8";

// Attribute names and values of `GL/osmesa.h`.
const OSMESA_FORMAT: c_int = 0x22;
const OSMESA_RGBA: c_int = 0x1908;
const OSMESA_DEPTH_BITS: c_int = 0x30;
const OSMESA_STENCIL_BITS: c_int = 0x31;
const OSMESA_ACCUM_BITS: c_int = 0x32;
const OSMESA_PROFILE: c_int = 0x33;
const OSMESA_CORE_PROFILE: c_int = 0x34;
const OSMESA_CONTEXT_MAJOR_VERSION: c_int = 0x36;
const OSMESA_CONTEXT_MINOR_VERSION: c_int = 0x37;
const GL_UNSIGNED_BYTE: u32 = 0x1401;

/// Side of the square buffer the context is current on.
const BUFFER_SIDE: c_int = 4;

type CreateContextAttribs = unsafe extern "C" fn(*const c_int, *mut c_void) -> *mut c_void;
type MakeCurrent = unsafe extern "C" fn(*mut c_void, *mut c_void, u32, c_int, c_int) -> u8;
type DestroyContext = unsafe extern "C" fn(*mut c_void);
type GetProcAddress = unsafe extern "C" fn(*const c_char) -> *const c_void;

/// The OSMesa entry points, loaded once per process. The library stays loaded for the process:
/// the function pointers are kept, and Mesa does not promise a clean unload.
struct Functions {
    create: CreateContextAttribs,
    make_current: MakeCurrent,
    destroy: DestroyContext,
    get_proc_address: GetProcAddress,
    _library: Library,
}

static FUNCTIONS: OnceLock<Result<Functions, String>> = OnceLock::new();

fn load() -> Result<Functions, String> {
    // SAFETY: loading runs libOSMesa's (Mesa's) initializers, which have no preconditions.
    let library = unsafe { Library::new(LIBRARY) }.map_err(|e| e.to_string())?;
    /// Copies the function pointer `name` out of `library`.
    ///
    /// SAFETY (caller): `T` is the function's prototype from `GL/osmesa.h`, and the pointer is
    /// used only while `library` is loaded.
    unsafe fn symbol<T: Copy>(library: &Library, name: &[u8]) -> Result<T, String> {
        // SAFETY: the caller's contract above.
        unsafe {
            library
                .get::<T>(name)
                .map(|s| *s)
                .map_err(|e| e.to_string())
        }
    }
    // SAFETY: the types are the prototypes of `GL/osmesa.h`; the pointers are kept beside
    // `_library`, which stays loaded as long as they do (the whole process).
    unsafe {
        Ok(Functions {
            create: symbol(&library, b"OSMesaCreateContextAttribs\0")?,
            make_current: symbol(&library, b"OSMesaMakeCurrent\0")?,
            destroy: symbol(&library, b"OSMesaDestroyContext\0")?,
            get_proc_address: symbol(&library, b"OSMesaGetProcAddress\0")?,
            _library: library,
        })
    }
}

/// A current OSMesa context and the buffer it is current on.
pub(super) struct OsMesaContext {
    context: *mut c_void,
    functions: &'static Functions,
    /// Must outlive the context's use of it: released in `drop` before the buffer is freed.
    _buffer: Vec<u8>,
}

impl Drop for OsMesaContext {
    fn drop(&mut self) {
        // SAFETY: `context` came from `OSMesaCreateContextAttribs` and is destroyed only here;
        // `OSMesaMakeCurrent(NULL, NULL, ..)` releases the current context first, so the
        // buffer (dropped after this body) is no longer in use.
        unsafe {
            (self.functions.make_current)(ptr::null_mut(), ptr::null_mut(), 0, 0, 0);
            (self.functions.destroy)(self.context);
        }
    }
}

/// Creates a core 3.3 context and makes it current on this thread.
pub(super) fn create() -> Result<(OsMesaContext, glow::Context)> {
    let functions =
        FUNCTIONS
            .get_or_init(load)
            .as_ref()
            .map_err(|detail| Error::LibraryMissing {
                route: Route::OsMesa,
                library: LIBRARY,
                install: Route::OsMesa.packages(),
                detail: detail.clone(),
            })?;
    let fail = |detail: &str| Error::Context {
        route: Route::OsMesa,
        detail: detail.into(),
        install: Route::OsMesa.packages(),
    };
    let attributes = [
        OSMESA_FORMAT,
        OSMESA_RGBA,
        OSMESA_DEPTH_BITS,
        24,
        OSMESA_STENCIL_BITS,
        0,
        OSMESA_ACCUM_BITS,
        0,
        OSMESA_PROFILE,
        OSMESA_CORE_PROFILE,
        OSMESA_CONTEXT_MAJOR_VERSION,
        3,
        OSMESA_CONTEXT_MINOR_VERSION,
        3,
        0,
    ];
    // SAFETY: `attributes` is a zero-terminated list of the documented pairs; no share context.
    let context = unsafe { (functions.create)(attributes.as_ptr(), ptr::null_mut()) };
    if context.is_null() {
        return Err(fail(
            "OSMesaCreateContextAttribs refused a 3.3 core context",
        ));
    }
    let mut buffer = vec![0u8; (BUFFER_SIDE * BUFFER_SIDE * 4) as usize];
    let mut owned = OsMesaContext {
        context,
        functions,
        _buffer: Vec::new(),
    };
    // SAFETY: `buffer` holds BUFFER_SIDE² RGBA8 pixels; its heap block does not move when the
    // Vec is moved into `owned`, which keeps it until the context is released.
    let current = unsafe {
        (functions.make_current)(
            context,
            buffer.as_mut_ptr().cast(),
            GL_UNSIGNED_BYTE,
            BUFFER_SIDE,
            BUFFER_SIDE,
        )
    };
    owned._buffer = buffer;
    if current == 0 {
        return Err(fail("OSMesaMakeCurrent failed"));
    }
    // SAFETY: the context is current on this thread; OSMesaGetProcAddress returns functions of
    // the loaded library, which stays loaded for the process.
    let glow = unsafe {
        glow::Context::from_loader_function_cstr(|name| (functions.get_proc_address)(name.as_ptr()))
    };
    Ok((owned, glow))
}
