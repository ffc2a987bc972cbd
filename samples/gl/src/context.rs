//! Headless contexts: [`Route`] picks how one is made, [`Gl`] owns it with the `glow` function
//! table, and releases it (not current, then destroyed) when the last handle is dropped.

mod egl;
mod osmesa;

use crate::{Error, Result};
use glow::HasContext;
use std::any::Any;
use std::cell::Cell;
use std::fmt;
use std::rc::Rc;

/// How a headless OpenGL 3.3 core context is created (see the crate docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Route {
    /// glutin's EGL device platform, surfaceless (libEGL at run time).
    Egl,
    /// Mesa's OSMesa (`libOSMesa.so.8` at run time), current on an owned buffer.
    OsMesa,
}

impl Route {
    /// Every route, in the order [`Gl::any`] tries them.
    pub const ALL: [Route; 2] = [Route::Egl, Route::OsMesa];

    /// Lower-case name: `egl` or `osmesa`.
    pub fn name(self) -> &'static str {
        match self {
            Route::Egl => "egl",
            Route::OsMesa => "osmesa",
        }
    }

    /// The Debian packages that give this route a software (llvmpipe) context.
    pub fn packages(self) -> &'static str {
        match self {
            Route::Egl => "libegl1 libegl-mesa0 libgl1-mesa-dri",
            Route::OsMesa => "libosmesa6",
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
    /// fields above, it makes the context not current and destroys it). A windowed route would
    /// put its window and surface here.
    _owner: Box<dyn Any>,
}

impl Gl {
    /// Creates a headless 3.3 core context by `route` and makes it current on this thread.
    ///
    /// Fails with [`Error::LibraryMissing`] when the route's library is not installed,
    /// [`Error::Context`] when it gives no 3.3 core context, and [`Error::ContextOnThread`] when
    /// this thread already has one.
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
        };
        let version = (glow.version().major, glow.version().minor);
        // SAFETY: the context behind `glow` was made current on this thread just now and is
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
