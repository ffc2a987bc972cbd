//! The windowed route (feature `window`): [`Window::new`] opens a winit window (X11) and makes a
//! glutin 3.3 core context (EGL on the X11 display) current on its surface, returning a [`Gl`]
//! like the headless routes do, with [`Route::Window`]. Everything past [`Gl`] is the same:
//! draw into a [`crate::RenderTarget`], then [`crate::Presenter`] tone-maps it into the window's
//! default framebuffer ([`crate::Destination::Window`]) and [`Window::swap_buffers`] shows it.
//!
//! The window, surface and context live in one shared state: the [`Gl`] handle holds it through
//! its owner hook and [`Window`] holds it too, so the context stays current until both (and every
//! GL object) are gone, then is made not current and destroyed before its surface and window.
//!
//! A window needs a display server: `DISPLAY` naming an X server (Xvfb works, see
//! `/work/shared/GL-NOTES.md`). winit wants its event loop on the main thread.

use crate::{Error, Gl, Result, Route};
use glutin::config::{Api, ConfigTemplateBuilder, GlConfig};
use glutin::context::{
    ContextApi, ContextAttributesBuilder, GlProfile, NotCurrentGlContext, PossiblyCurrentContext,
    PossiblyCurrentGlContext, Version,
};
use glutin::display::{GetGlDisplay, GlDisplay};
use glutin::surface::{GlSurface, Surface, SwapInterval, WindowSurface};
use glutin_winit::{ApiPreference, DisplayBuilder, GlWindow};
use std::num::NonZeroU32;
use std::rc::Rc;
use winit::event_loop::ActiveEventLoop;
use winit::raw_window_handle::HasWindowHandle;
use winit::window::WindowAttributes;

/// The context, its surface and the window, dropped in that order.
struct State {
    context: PossiblyCurrentContext,
    surface: Surface<WindowSurface>,
    window: winit::window::Window,
}

impl Drop for State {
    fn drop(&mut self) {
        // Not current first, or the context is not destroyed when glutin drops it; a failure
        // leaves nothing better to do than to go on dropping.
        let _ = self.context.make_not_current_in_place();
    }
}

/// A window whose surface a [`Gl`] context draws to. Not `Send`.
pub struct Window {
    state: Rc<State>,
}

impl Window {
    /// Opens a window with `attributes` on `event_loop`'s display and makes a 3.3 core context
    /// current on its surface (no multisampling, swap interval 0 where the platform allows).
    ///
    /// Fails with [`Error::ContextOnThread`] when this thread already has a context, and with
    /// [`Error::Context`] when there is no display, no config or no 3.3 core context.
    pub fn new(event_loop: &ActiveEventLoop, attributes: WindowAttributes) -> Result<(Gl, Window)> {
        if crate::context::context_on_thread() {
            return Err(Error::ContextOnThread);
        }
        let fail = |detail: String| Error::Context {
            route: Route::Window,
            detail,
            install: Route::Window.packages(),
        };
        let template = ConfigTemplateBuilder::new().with_api(Api::OPENGL);
        let (window, config) = DisplayBuilder::new()
            .with_preference(ApiPreference::PreferEgl)
            .with_window_attributes(Some(attributes))
            .build(event_loop, template, |configs| {
                configs
                    .reduce(|best, c| {
                        if best.num_samples() > 0 && c.num_samples() == 0 {
                            c
                        } else {
                            best
                        }
                    })
                    .expect("glutin gives at least one config or an error")
            })
            .map_err(|e| fail(format!("display and config: {e}")))?;
        let window = window.ok_or_else(|| fail("no window was created".into()))?;
        let handle = window
            .window_handle()
            .map_err(|e| fail(format!("window handle: {e}")))?
            .as_raw();
        let display = config.display();
        let attributes = ContextAttributesBuilder::new()
            .with_context_api(ContextApi::OpenGl(Some(Version::new(3, 3))))
            .with_profile(GlProfile::Core)
            .build(Some(handle));
        // SAFETY: `handle` is the window's, which the returned state keeps alive longer than
        // the context.
        let context = unsafe { display.create_context(&config, &attributes) }
            .map_err(|e| fail(format!("3.3 core context: {e}")))?;
        let surface_attributes = window
            .build_surface_attributes(Default::default())
            .map_err(|e| fail(format!("surface attributes: {e}")))?;
        // SAFETY: as above, the window outlives the surface (the state drops it last).
        let surface = unsafe { display.create_window_surface(&config, &surface_attributes) }
            .map_err(|e| fail(format!("window surface: {e}")))?;
        let context = context
            .make_current(&surface)
            .map_err(|e| fail(format!("make current: {e}")))?;
        // Not every platform can stop waiting for vertical blank; drawing still works.
        let _ = surface.set_swap_interval(&context, SwapInterval::DontWait);
        // SAFETY: the context is current on this thread; the loader returns the display's
        // function pointers, valid while the display lives (the context holds it).
        let glow =
            unsafe { glow::Context::from_loader_function_cstr(|n| display.get_proc_address(n)) };
        let state = Rc::new(State {
            context,
            surface,
            window,
        });
        // SAFETY: the context was made current on this thread just now; the owner (a handle
        // to the state) keeps it alive and current, and no other context lives on the thread.
        let gl = unsafe { Gl::from_current(Route::Window, Box::new(state.clone()), glow)? };
        Ok((gl, Window { state }))
    }

    /// The winit window (title, size, redraw requests).
    pub fn winit(&self) -> &winit::window::Window {
        &self.state.window
    }

    /// The window's inner size in pixels (at least 1×1).
    pub fn size(&self) -> (u32, u32) {
        let s = self.state.window.inner_size();
        (s.width.max(1), s.height.max(1))
    }

    /// Resizes the surface to the window's inner size (call on winit's `Resized`).
    pub fn resize_surface(&self) {
        let (w, h) = self.size();
        let (Some(w), Some(h)) = (NonZeroU32::new(w), NonZeroU32::new(h)) else {
            return;
        };
        self.state.surface.resize(&self.state.context, w, h);
    }

    /// Shows what was drawn into the default framebuffer.
    pub fn swap_buffers(&self) -> Result<()> {
        self.state
            .surface
            .swap_buffers(&self.state.context)
            .map_err(|e| Error::Gl {
                operation: "swap buffers",
                detail: e.to_string(),
            })
    }
}
