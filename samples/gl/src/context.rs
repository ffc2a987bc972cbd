//! Contexts: [`Route`] says how one was made (two headless routes, and the window of
//! `crate::window` with the `window` feature), [`Gl`] owns it with the `glow` function table, and
//! releases it (not current, then destroyed) when the last handle is dropped.

mod egl;
mod osmesa;

use crate::{Error, Result};
use glow::HasContext;
use std::any::Any;
use std::cell::Cell;
use std::fmt;
use std::rc::Rc;

/// How an OpenGL 3.3 core context is created (see the crate docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Route {
    /// glutin's EGL device platform, surfaceless (libEGL at run time).
    Egl,
    /// Mesa's OSMesa (`libOSMesa.so.8` at run time), current on an owned buffer.
    OsMesa,
    /// A winit window with a glutin context on its surface (EGL on X11), made by
    /// `window::Window::new` (the `window` feature); [`Gl::new`] cannot make it.
    Window,
}

impl Route {
    /// Every headless route, in the order [`Gl::any`] tries them.
    pub const ALL: [Route; 2] = [Route::Egl, Route::OsMesa];

    /// Lower-case name: `egl`, `osmesa` or `window`.
    pub fn name(self) -> &'static str {
        match self {
            Route::Egl => "egl",
            Route::OsMesa => "osmesa",
            Route::Window => "window",
        }
    }

    /// The Debian packages that give this route a software (llvmpipe) context.
    pub fn packages(self) -> &'static str {
        match self {
            Route::Egl => "libegl1 libegl-mesa0 libgl1-mesa-dri",
            Route::OsMesa => "libosmesa6",
            Route::Window => "libegl1 libegl-mesa0 libgl1-mesa-dri, and an X server",
        }
    }
}

impl fmt::Display for Route {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

thread_local! {
    /// Whether a context created by this crate lives on this thread.
    static CONTEXT_ON_THREAD: Cell<bool> = const { Cell::new(false) };
}

/// Whether a context created by this crate lives on this thread.
#[cfg(feature = "window")]
pub(crate) fn context_on_thread() -> bool {
    CONTEXT_ON_THREAD.get()
}

/// How [`Gl::time_ms`] times a draw.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Clock {
    /// Wall time between two `glFinish` calls: the draw's whole cost on llvmpipe, where the
    /// rasterizer runs on the CPU.
    Wall,
    /// A `GL_TIME_ELAPSED` query around the draw ([`Gl::gpu_time_ms`]): the GPU's time,
    /// without the driver's fixed cost per call that dominates a small draw's wall time there.
    Gpu,
}

impl Clock {
    /// How a report describes the timing of one draw.
    pub fn describe(self) -> &'static str {
        match self {
            Clock::Wall => "each draw timed between two glFinish calls",
            Clock::Gpu => "each draw timed by a GL_TIME_ELAPSED query",
        }
    }
}

/// A current OpenGL 3.3+ core context and its `glow` functions.
///
/// Cloning gives another handle to the same context. The context stays current on the creating
/// thread until the last handle (including those held by GL objects) is dropped. Not `Send`.
#[derive(Clone)]
pub struct Gl {
    inner: Rc<Inner>,
}

struct Inner {
    glow: glow::Context,
    /// Bound for attribute-less draws: a core profile draws nothing without a vertex array.
    empty_vao: glow::VertexArray,
    renderer: String,
    version: (u32, u32),
    route: Route,
    /// What keeps the route's context alive and current (declared last: dropped after the
    /// fields above, it makes the context not current and destroys it). The windowed route puts
    /// a shared handle to its window, surface and context here.
    _owner: Box<dyn Any>,
}

impl Gl {
    /// Creates a headless 3.3 core context by `route` and makes it current on this thread.
    ///
    /// Fails with [`Error::LibraryMissing`] when the route's library is not installed,
    /// [`Error::Context`] when it gives no 3.3 core context, [`Error::ContextOnThread`] when
    /// this thread already has one, and [`Error::Usage`] for [`Route::Window`] (made by
    /// `window::Window::new`).
    pub fn new(route: Route) -> Result<Gl> {
        if CONTEXT_ON_THREAD.get() {
            return Err(Error::ContextOnThread);
        }
        let (owner, glow): (Box<dyn Any>, _) = match route {
            Route::Egl => {
                let (c, glow) = egl::create()?;
                (Box::new(c), glow)
            }
            Route::OsMesa => {
                let (c, glow) = osmesa::create()?;
                (Box::new(c), glow)
            }
            Route::Window => {
                return Err(Error::Usage(
                    "a windowed context is made by ndfmap_gl::window::Window::new (the `window` \
                     feature), not Gl::new"
                        .into(),
                ));
            }
        };
        // SAFETY: the route made the context behind `glow` current on this thread just now, and
        // `owner` keeps it alive.
        unsafe { Gl::from_current(route, owner, glow) }
    }

    /// Wraps a context `route` made: checks that it is 3.3+ core, creates the empty vertex
    /// array, and marks the thread as having a context. Dropping `owner` must make the context
    /// not current and destroy it; it is dropped (also on error) after every GL call of this
    /// crate on the context.
    ///
    /// # Safety
    ///
    /// The context behind `glow` must be current on this thread and stay current and alive for
    /// as long as `owner` lives, and no other context of this crate may live on this thread.
    pub(crate) unsafe fn from_current(
        route: Route,
        owner: Box<dyn Any>,
        glow: glow::Context,
    ) -> Result<Gl> {
        if CONTEXT_ON_THREAD.get() {
            return Err(Error::ContextOnThread);
        }
        let version = (glow.version().major, glow.version().minor);
        // SAFETY: the caller guarantees the context behind `glow` is current on this thread and
        // kept alive by `owner`; these calls only read state and create one object.
        let (renderer, core, empty_vao) = unsafe {
            let renderer = glow.get_parameter_string(glow::RENDERER);
            let mask = glow.get_parameter_i32(glow::CONTEXT_PROFILE_MASK) as u32;
            let vao = glow.create_vertex_array();
            (renderer, mask & glow::CONTEXT_CORE_PROFILE_BIT != 0, vao)
        };
        let fail = |detail: String| Error::Context {
            route,
            detail,
            install: route.packages(),
        };
        if version < (3, 3) || !core {
            return Err(fail(format!(
                "got OpenGL {}.{} {} ({renderer})",
                version.0,
                version.1,
                if core { "core" } else { "compatibility" }
            )));
        }
        let empty_vao = empty_vao.map_err(|e| fail(format!("creating a vertex array: {e}")))?;
        CONTEXT_ON_THREAD.set(true);
        Ok(Gl {
            inner: Rc::new(Inner {
                glow,
                empty_vao,
                renderer,
                version,
                route,
                _owner: owner,
            }),
        })
    }

    /// Creates a context by the first route of [`Route::ALL`] that works; the error lists why
    /// each failed.
    pub fn any() -> Result<Gl> {
        let mut failures = Vec::new();
        for route in Route::ALL {
            match Gl::new(route) {
                Ok(gl) => return Ok(gl),
                Err(Error::ContextOnThread) => return Err(Error::ContextOnThread),
                Err(e) => failures.push(e.to_string()),
            }
        }
        Err(Error::NoRoute(failures.join("; ")))
    }

    /// The `glow` function table, for GL calls this crate does not wrap. Every call is `unsafe`:
    /// the context is current on this thread while a `Gl` lives, so the caller's duty is the
    /// usual one of passing valid names and sizes.
    pub fn glow(&self) -> &glow::Context {
        &self.inner.glow
    }

    /// The `GL_RENDERER` string (`llvmpipe (LLVM 15.0.6, 256 bits)` on Mesa's software path).
    pub fn renderer(&self) -> &str {
        &self.inner.renderer
    }

    /// The context's OpenGL version, major and minor (at least 3.3).
    pub fn version(&self) -> (u32, u32) {
        self.inner.version
    }

    /// The route that created the context.
    pub fn route(&self) -> Route {
        self.inner.route
    }

    /// Whether the context has the core profile bit (always true for a created context).
    pub fn is_core(&self) -> bool {
        // SAFETY: the context is current on this thread while `self` lives; a state query.
        let mask = unsafe { self.glow().get_parameter_i32(glow::CONTEXT_PROFILE_MASK) } as u32;
        mask & glow::CONTEXT_CORE_PROFILE_BIT != 0
    }

    /// Waits until every command issued so far has completed (`glFinish`), for timing.
    pub fn finish(&self) {
        // SAFETY: the context is current on this thread while `self` lives.
        unsafe { self.glow().finish() };
    }

    /// Whether the context renders on Mesa's CPU rasterizers (llvmpipe, softpipe): the
    /// renderer the regression references were drawn with, and whose texture filter the tests'
    /// CPU twin models.
    pub fn is_software(&self) -> bool {
        let r = self.renderer();
        r.contains("llvmpipe") || r.contains("softpipe")
    }

    /// Runs `f` (a draw) and returns its result with the milliseconds it took by `clock`, after
    /// a `glFinish` so that earlier commands are not counted: the frame-time measure of the
    /// benchmarks.
    pub fn time_ms<T>(&self, clock: Clock, f: impl FnOnce() -> T) -> Result<(T, f64)> {
        self.finish();
        match clock {
            Clock::Wall => {
                let start = std::time::Instant::now();
                let out = f();
                self.finish();
                Ok((out, start.elapsed().as_secs_f64() * 1e3))
            }
            Clock::Gpu => self.gpu_time_ms(f),
        }
    }

    /// Runs `f` and returns its result with the GPU time, in milliseconds, of the commands it
    /// issued: a `GL_TIME_ELAPSED` query (OpenGL 3.3 core), read back after they complete.
    /// On a GPU this is the frame-time measure (the wall time between two `glFinish` calls is
    /// then mostly the driver's fixed cost); llvmpipe answers it too. `f` must not call this
    /// (elapsed-time queries do not nest).
    pub fn gpu_time_ms<T>(&self, f: impl FnOnce() -> T) -> Result<(T, f64)> {
        let g = self.glow();
        // SAFETY: the context is current on this thread while `self` lives; the query is
        // created, used and deleted here.
        let query = unsafe { g.create_query() }.map_err(|detail| Error::Gl {
            operation: "creating a timer query",
            detail,
        })?;
        // SAFETY: as above; `query` is a live query name and no elapsed-time query is active.
        unsafe { g.begin_query(glow::TIME_ELAPSED, query) };
        let out = f();
        // SAFETY: as above; ends the query begun above, then waits for its result (QUERY_RESULT
        // blocks until the commands are done) and deletes it.
        let ns = unsafe {
            g.end_query(glow::TIME_ELAPSED);
            let ns = g.get_query_parameter_u64(query, glow::QUERY_RESULT);
            g.delete_query(query);
            ns
        };
        self.check_error("timing with a GL_TIME_ELAPSED query")?;
        Ok((out, ns as f64 * 1e-6))
    }

    /// Returns [`Error::Gl`] naming `operation` if `glGetError` reports an error (and clears
    /// every pending error flag).
    pub fn check_error(&self, operation: &'static str) -> Result<()> {
        let mut codes = Vec::new();
        loop {
            // SAFETY: the context is current on this thread while `self` lives.
            let code = unsafe { self.glow().get_error() };
            if code == glow::NO_ERROR || codes.len() >= 8 {
                break;
            }
            codes.push(format!("0x{code:04x}"));
        }
        if codes.is_empty() {
            Ok(())
        } else {
            Err(Error::Gl {
                operation,
                detail: format!("glGetError {}", codes.join(", ")),
            })
        }
    }

    /// The vertex array object bound for attribute-less draws.
    pub(crate) fn empty_vao(&self) -> glow::VertexArray {
        self.inner.empty_vao
    }

    /// Runs `f` with `texture` bound to `GL_TEXTURE_2D` of the active unit, then binds back
    /// what was bound there, so creating objects never disturbs textures bound for a draw.
    pub(crate) fn with_texture_2d<T>(&self, texture: glow::Texture, f: impl FnOnce() -> T) -> T {
        let g = self.glow();
        // SAFETY: the context is current on this thread while `self` lives; `texture` is a
        // live texture name of this context (the caller's).
        let previous = unsafe {
            let previous = g.get_parameter_texture(glow::TEXTURE_BINDING_2D);
            g.bind_texture(glow::TEXTURE_2D, Some(texture));
            previous
        };
        let out = f();
        // SAFETY: as above; `previous` was bound a moment ago, so it is a live name or none.
        unsafe { g.bind_texture(glow::TEXTURE_2D, previous) };
        out
    }

    /// A GL object-creation failure as an [`Error::Gl`].
    pub(crate) fn creation_error(operation: &'static str, detail: String) -> Error {
        Error::Gl { operation, detail }
    }
}

impl fmt::Debug for Gl {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Gl")
            .field("route", &self.inner.route)
            .field("version", &self.inner.version)
            .field("renderer", &self.inner.renderer)
            .finish()
    }
}

impl Drop for Inner {
    fn drop(&mut self) {
        // SAFETY: `_owner` has not been dropped yet (fields drop after this body), so the
        // context is still current on this thread.
        unsafe { self.glow.delete_vertex_array(self.empty_vao) };
        CONTEXT_ON_THREAD.set(false);
    }
}
