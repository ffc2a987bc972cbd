//! Times the steps of a headless render on each route (one run each, as the crate docs report):
//! context creation, upload of a 1024² Toksvig bake as RGBA32F with its MIP chain, a 1024²
//! full-screen trilinear draw (first, which includes llvmpipe compiling the shader, and again),
//! and reading the 1024² RGBA32F target back.
//!
//! `cargo run --release -p ndfmap-gl --example timings [egl|osmesa]` (default: both, in turn).

use ndfmap::bake::Method;
use ndfmap::format::Format;
use ndfmap::methods::bake;
use ndfmap_gl::{BakeTextures, Gl, Program, RenderTarget, Route, draw_fullscreen, read_rgba_f32};
use std::time::{Duration, Instant};

const SIZE: u32 = 1024;

fn timed<T>(what: &str, f: impl FnOnce() -> T) -> T {
    let start = Instant::now();
    let out = f();
    let took: Duration = start.elapsed();
    println!("  {what:<44} {:>8.2} ms", took.as_secs_f64() * 1e3);
    out
}

fn run(route: Route, b: &ndfmap::bake::Bake) -> Result<(), ndfmap_gl::Error> {
    println!("{route}:");
    let gl = timed("context creation", || Gl::new(route))?;
    println!("  renderer: {}", gl.renderer());
    let textures = timed("upload, RGBA32F, all levels", || {
        let t = BakeTextures::upload(&gl, b, Format::F32);
        gl.finish();
        t
    })?;
    let program = Program::fullscreen(
        &gl,
        "#version 330 core
in vec2 ndf_screen_uv;
uniform sampler2D ndf_tex0;
out vec4 color;
void main() { color = texture(ndf_tex0, ndf_screen_uv * 3.7); }
",
    )?;
    let target = RenderTarget::new(&gl, SIZE, SIZE)?;
    textures.bind(&program);
    for what in [
        "1024² draw (first: compiles the shader)",
        "1024² draw (again)",
    ] {
        timed(what, || {
            let r = draw_fullscreen(&program, &target);
            gl.finish();
            r
        })?;
    }
    let pixels = timed("1024² RGBA32F read-back", || read_rgba_f32(&target))?;
    assert_eq!(pixels.len(), (SIZE * SIZE) as usize);
    Ok(())
}

fn main() {
    let routes: Vec<Route> = match std::env::args().nth(1).as_deref() {
        None => Route::ALL.to_vec(),
        Some(name) => Route::ALL
            .into_iter()
            .filter(|r| r.name() == name)
            .collect(),
    };
    let sample = ndfmap::procedural::generate(SIZE, 1);
    let b = bake(&sample.map, Method::Toksvig);
    for route in routes {
        if let Err(e) = run(route, &b) {
            eprintln!("{route}: {e}");
            std::process::exit(1);
        }
    }
}
