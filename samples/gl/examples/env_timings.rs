//! Frame time of each environment route relative to plain normal mapping under the same
//! environment (issue 16, "Cost"): the sphere scene (`Scene::standard`'s third view, 512²) lit
//! by the generated sky (1024 × 512, sun included), drawn with plain, Toksvig, LEAN and vMF
//! J = 4 / 6 (unaligned: manual sampling; aligned: hardware), Blinn-Phong s = 256, by the
//! prefiltered and the SH route, and SH bakes l* = 2, 4, 8 by the SH route (the environment
//! rotated per fragment into the tangent frame). `--sh-only`: plain (the base) and the SH
//! bakes only. Each configuration is drawn 3 times untimed (shader
//! compilation), then `--frames` times (default 20), `glFinish` after each; the median frame
//! is reported with its ratio to plain's prefiltered frame, all in the same run.
//!
//! `cargo run --release -p ndfmap-gl --example env_timings [egl|osmesa] [--frames N] [--sh-only]`.

use ndfmap::bake::{Bake, BakeOptions, Method};
use ndfmap::brdf::Brdf;
use ndfmap::environment::Sky;
use ndfmap::envlight::{EnvLight, Route as EnvRoute};
use ndfmap::glsl::{ShaderLight, ShaderOptions};
use ndfmap::methods::{bake, bake_with};
use ndfmap_gl::{BakeRenderer, EnvTextures, Gl, RenderTarget, Route, Scene, env_rotation};
use std::time::Instant;

const SIZE: u32 = 512;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let route = if args.iter().any(|a| a == "osmesa") {
        Route::OsMesa
    } else {
        Route::Egl
    };
    let frames: usize = args
        .iter()
        .position(|a| a == "--frames")
        .and_then(|i| args.get(i + 1))
        .map(|v| v.parse())
        .transpose()?
        .unwrap_or(20);
    let gl = Gl::new(route)?;
    println!(
        "{route} ({}), {SIZE}² sphere, {frames} frames each",
        gl.renderer()
    );
    let sky = Sky {
        width: 1024,
        ..Sky::default()
    }
    .render()?;
    let light = EnvLight::new(&sky);
    let env = EnvTextures::upload(&gl, &light)?;
    let map = ndfmap::procedural::generate(512, 3).map;
    let mixture = |lobes, align| BakeOptions {
        lobes,
        align,
        ..Default::default()
    };
    let sh_only = args.iter().any(|a| a == "--sh-only");
    let sh = |lmax| BakeOptions {
        lmax,
        ..Default::default()
    };
    let mut configs: Vec<(EnvRoute, Bake)> = Vec::new();
    let bakes: Vec<Bake> = vec![
        bake(&map, Method::Plain),
        bake(&map, Method::Toksvig),
        bake(&map, Method::Lean),
        bake_with(&map, Method::Vmf, &mixture(4, Some(1.0)))?,
        bake_with(&map, Method::Vmf, &mixture(6, Some(1.0)))?,
        bake_with(&map, Method::Vmf, &mixture(4, None))?,
        bake_with(&map, Method::Vmf, &mixture(6, None))?,
    ];
    for er in [EnvRoute::Prefiltered, EnvRoute::Sh] {
        for b in &bakes {
            if !sh_only || (er == EnvRoute::Prefiltered && b.method == Method::Plain) {
                configs.push((er, b.clone()));
            }
        }
    }
    for lmax in [2, 4, 8] {
        configs.push((EnvRoute::Sh, bake_with(&map, Method::Sh, &sh(lmax))?));
    }
    let mut scene = Scene::standard().remove(2);
    scene.lighting.brdf = Brdf::BlinnPhong { s: 256.0 };
    scene.lighting.color = glam::Vec3::splat(0.25);
    let mesh = scene.shape.mesh(&gl)?;
    let target = RenderTarget::new(&gl, SIZE, SIZE)?;
    let rotation = env_rotation(0.6);
    let mut base = None;
    println!(
        "  {:<24} {:>10} {:>8}",
        "configuration", "median ms", "ratio"
    );
    for (er, b) in &configs {
        let er = *er;
        let options = ShaderOptions {
            light: ShaderLight::env(er),
            ..Default::default()
        };
        let r = BakeRenderer::new(&gl, b, &options)?;
        let mut times = Vec::new();
        for i in 0..frames + 3 {
            target.clear([0.0, 0.0, 0.0, 1.0]);
            gl.finish();
            let start = Instant::now();
            r.draw_env(
                &mesh,
                &glam::Mat4::IDENTITY,
                &scene.camera,
                &scene.lighting,
                &env,
                &rotation,
                &target,
            )?;
            gl.finish();
            if i >= 3 {
                times.push(start.elapsed().as_secs_f64() * 1e3);
            }
        }
        times.sort_by(f64::total_cmp);
        let median = times[times.len() / 2];
        let b0 = *base.get_or_insert(median);
        println!(
            "  {:<24} {median:>10.2} {:>8.2}",
            format!("{} {}", er.name(), b.label()),
            median / b0
        );
    }
    Ok(())
}
