//! ndfmap-gl: the OpenGL 3.3 core runtime that draws ndfmap bakes — headless and windowed
//! contexts, texture upload, shader programs, float render targets, meshes, an orbit camera and
//! tone-mapped presentation. The core `ndfmap` crate has no GL dependency; this crate is what
//! the sample viewer (`samples/viewer`) and the headless render tests build on.
//!
//! # Routes to a context
//!
//! [`Gl::new`] creates a headless context with no window and no display server, by one of two
//! headless [`Route`]s (both give Mesa's llvmpipe a 3.3 core request; it answers with 4.5 core):
//!
//! - [`Route::Egl`]: glutin's EGL device platform. Devices with `EGL_MESA_device_software` are
//!   tried first, then any other (`NDFMAP_EGL_DEVICE=hardware` reverses that, for a GPU's frame
//!   times on a machine that also has Mesa); the config is asked for with an empty surface-type
//!   mask and the context is made current with no surface. libEGL is loaded at run time (Debian:
//!   `libegl1 libgl1-mesa-dri`).
//! - [`Route::OsMesa`]: `libOSMesa.so.8` loaded at run time with `libloading` (Debian:
//!   `libosmesa6`; Mesa removed OSMesa in 25.1), a core 3.3 context current on a small buffer
//!   the context owns.
//!
//! [`BakeRenderer`] joins the pieces for the product shaders: a bake's textures uploaded, its
//! `ndfmap::glsl` vertex and fragment shaders compiled, meshes drawn under a [`Lighting`];
//! [`Scene::standard`] lists the views the regression renders (`tests/scenes.rs`) and the
//! frame-time table use. `tests/shaders.rs` proves the shaders equal their CPU twin texel for
//! texel. [`EnvTextures`] uploads an environment for the environment-lit shaders
//! ([`ndfmap::glsl::ShaderLight`]) and [`BakeRenderer::draw_env`] draws with it
//! (`tests/env.rs` proves those shaders equal their CPU twin). PBR bakes are drawn by a plain glTF metallic-roughness GGX shader with no ndfmap code
//! ([`gltf`]; `tests/gltf.rs`), as an unmodified engine would draw them.
//!
//! A third route, [`Route::Window`], is a window: with the `window` feature,
//! `window::Window::new` opens a winit window (X11) and makes a glutin context (EGL on the X11
//! display) current on its surface, handing the window, surface and context to [`Gl`] through
//! the same owner hook the headless routes use. It needs an X server (`DISPLAY`; Xvfb works).
//!
//! Drawing always goes to a [`RenderTarget`] (an RGBA32F framebuffer object with a depth
//! buffer), never to a default framebuffer, so every route behaves the same; everything past
//! [`Gl`] is independent of how the context was made. Only the last step differs:
//! [`Presenter`] tone-maps a target into a window's default framebuffer
//! ([`Destination::Window`]) or into another target for a headless screenshot
//! ([`Destination::Target`]).
//!
//! # Presentation
//!
//! Shaders write linear radiance. [`tone_map`] (Reinhard `x/(1+x)` per channel, then the sRGB
//! curve) is the one tone map of the project: the regression references, the viewer's window
//! and its screenshots; [`present::TONE_MAP_GLSL`] is its GLSL twin, which [`Presenter`] runs
//! (the route tests check that they agree to 1e-6). [`Presenter`] can show two images split at
//! a column (a method beside its reference), and [`Accumulator`] sums passes on the GPU (the
//! viewer's jittered supersampling, with [`Camera::jitter`]).
//!
//! # Ownership and threads
//!
//! A context is current on the thread that created it for as long as it lives, and at most one
//! lives per thread ([`Gl::new`] refuses a second). [`Gl`] is a cheap, clonable handle that is
//! neither `Send` nor `Sync`; every GL object ([`BakeTextures`], [`Program`], [`RenderTarget`],
//! [`Mesh`]) holds one and deletes its GL names when dropped, and the context is released (made
//! not current, then destroyed) when the last handle goes. Tests that run in parallel each create
//! their own context on their own thread.
//!
//! # Conventions the shaders see
//!
//! - **Vertex attributes** (fixed locations, also bound by name before linking):
//!   0 `ndf_position` vec3, 1 `ndf_normal` vec3, 2 `ndf_tangent` vec4 (xyz along +u, w the
//!   bitangent sign: `B = w·cross(N, T)` points to decreasing v, towards bake row 0, the top of the
//!   image — the OpenGL "+Y up" normal-map convention), 3 `ndf_uv` vec2.
//! - **Uniforms**: `mat4 ndf_model`, `mat4 ndf_view_proj`, `vec3 ndf_camera_pos`
//!   ([`Camera::set_uniforms`]); bake texture `i` is `sampler2D ndf_tex{i}` on texture unit `i`
//!   ([`BakeTextures::bind`]). Setting a uniform a program lacks is not an error.
//! - **Texture rows**: bake row 0 (the top image row) is uploaded first, so it is at `t = 0`.
//! - **Read-back rows**: [`read_rgba_f32`] returns rows in `glReadPixels` order: row 0 is the
//!   row at `gl_FragCoord.y = 0.5`. A full-screen draw that samples a level at
//!   `uv = gl_FragCoord.xy / size` therefore reads back in the bake's own row order.
//! - **Values**: unsigned-normalized textures return the stored `u` (signed channels biased as
//!   `0.5 + 0.5·v`, see `ndfmap::pack`); the shader removes the bias.
//!
//! # Measured costs
//!
//! llvmpipe (Mesa 22.3.6, LLVM 15), 2 CPU cores shared with other builds, release build, one
//! run each of `cargo run --release -p ndfmap-gl --example timings -- egl` (then `osmesa`):
//!
//! | step | EGL | OSMesa |
//! | --- | --- | --- |
//! | context creation | 41 ms | 15 ms |
//! | upload of a 1024² Toksvig bake, RGBA32F, 11 levels | 22 ms | 23 ms |
//! | 1024² full-screen trilinear draw, first (llvmpipe compiles the shader) | 48 ms | 48 ms |
//! | 1024² full-screen trilinear draw, again | 9.6 ms | 9.3 ms |
//! | 1024² RGBA32F read-back | 15 ms | 15 ms |
//!
//! Repeated runs on the loaded machine varied by up to 3×; the very first EGL context of a cold
//! start (libraries not yet in the page cache) took 425 ms.

#![warn(missing_docs)]

pub mod camera;
pub mod context;
pub mod env;
pub mod gltf;
pub mod mesh;
pub mod present;
pub mod program;
pub mod render;
pub mod target;
pub mod texture;
#[cfg(feature = "window")]
pub mod window;

pub use camera::Camera;
pub use context::{Clock, Gl, Route};
pub use env::{EnvBackground, EnvTextures, env_rotation};
pub use glam;
pub use glow;
pub use mesh::{Mesh, MeshData, Vertex, draw_mesh};
pub use present::{Accumulator, Destination, Layer, Presenter, tone_map};
pub use program::{FULLSCREEN_VERTEX_SHADER, Program};
pub use render::{BakeRenderer, BrdfBinding, Lighting, Scene, Shape};
pub use target::{RenderTarget, draw_fullscreen, read_rgba_f32};
pub use texture::{BakeTextures, Compression, TableTexture};
#[cfg(feature = "window")]
pub use winit;

/// What can go wrong in this crate.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A system library a route loads at run time is not installed.
    #[error(
        "{route}: cannot load {library} ({detail}); install it (Debian: apt install {install})"
    )]
    LibraryMissing {
        /// The route that needed it.
        route: Route,
        /// The library file name.
        library: &'static str,
        /// The Debian packages that provide it.
        install: &'static str,
        /// The loader's message.
        detail: String,
    },
    /// The library loaded but gave no usable 3.3 core context.
    #[error("{route}: no OpenGL 3.3 core context: {detail} (Debian packages: {install})")]
    Context {
        /// The route tried.
        route: Route,
        /// What failed, for every device tried.
        detail: String,
        /// The Debian packages the route needs.
        install: &'static str,
    },
    /// No route gave a context ([`Gl::any`]); the text lists every route's failure.
    #[error("no headless OpenGL 3.3 core context by any route: {0}")]
    NoRoute(String),
    /// A context already lives on this thread; drop it first (one context per thread).
    #[error("an ndfmap-gl context already lives on this thread")]
    ContextOnThread,
    /// A shader failed to compile; `log` is the driver's info log.
    #[error("{stage} shader does not compile:\n{log}")]
    Compile {
        /// `vertex` or `fragment`.
        stage: &'static str,
        /// The compiler's info log.
        log: String,
    },
    /// A program failed to link; `log` is the driver's info log.
    #[error("program does not link:\n{log}")]
    Link {
        /// The linker's info log.
        log: String,
    },
    /// A call the API does not support, e.g. a BRDF the shader was not compiled for.
    #[error("{0}")]
    Usage(String),
    /// The bake cannot be packed in the requested format (e.g. unbounded values in unorm).
    #[error(transparent)]
    Pack(#[from] ndfmap::Error),
    /// A framebuffer is incomplete (`status` is the `glCheckFramebufferStatus` value).
    #[error("framebuffer {width}x{height} is incomplete (status 0x{status:04x})")]
    Framebuffer {
        /// Requested width.
        width: u32,
        /// Requested height.
        height: u32,
        /// The GL status enum.
        status: u32,
    },
    /// A GL call failed: object creation, or `glGetError` after an operation.
    #[error("OpenGL error during {operation}: {detail}")]
    Gl {
        /// What was being done.
        operation: &'static str,
        /// The GL error or driver message.
        detail: String,
    },
}

/// This crate's result type.
pub type Result<T, E = Error> = std::result::Result<T, E>;
