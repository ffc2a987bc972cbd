//! Frame time of each environment route relative to plain normal mapping under the same
//! environment (issue 16, "Cost"): the sphere scene (`Scene::standard`'s third view, 512²) lit
//! by the generated sky (1024 × 512, sun included), drawn with plain, Toksvig, LEAN,
//! Olano–North, vMF J = 4 / 6 (unaligned: manual sampling; aligned: hardware) and Tan 2005
//! J = 4 aligned, Blinn-Phong s = 256, by the
//! prefiltered and the SH route, and SH bakes l* = 2, 4, 8 by the SH route (the environment
//! rotated per fragment into the tangent frame). `--sh-only`: plain (the base) and the SH
//! bakes only. `--prefiltered-only`: the prefiltered route only, with the vMF J = 6 aligned
//! bake with colour textures (eq 22, one more fetch per lobe) beside it. `--ggx A`: GGX α = A
//! instead of Blinn-Phong (the prefiltered route's two-vMF lobe: a second lookup per lobe).
//! `--env-lights N`: the sun taken out of the sky as a light and added by every shader
//! (`NDF_ENV_LIGHTS`), as `ndfmap eval`/`report`, the C API and the viewer do by default; the
//! default here is 0, the pure routes, so earlier tables stay comparable.
//! Each configuration is drawn 3 times untimed (shader compilation), then `--frames` times
//! (default 20), each between two `glFinish` calls or, with `--gpu-clock` (on a GPU, where the
//! wall time of a draw is mostly the driver's fixed cost), by a `GL_TIME_ELAPSED` query
//! (`Gl::gpu_time_ms`); the median frame is reported with its ratio to plain's prefiltered
//! frame, all in the same run.
//!
//! `cargo run --release -p ndfmap-gl --example env_timings [egl|osmesa] [--frames N]
//! [--sh-only | --prefiltered-only] [--ggx A] [--env-lights N] [--gpu-clock]`.

use ndfmap::bake::{Bake, BakeOptions, Method};
use ndfmap::brdf::Brdf;
use ndfmap::environment::Sky;
use ndfmap::envlight::{EnvLight, Route as EnvRoute};
use ndfmap::glsl::{ShaderBrdf, ShaderLight, ShaderOptions};
use ndfmap::methods::{bake, bake_with};
use ndfmap_gl::{BakeRenderer, Clock, EnvTextures, Gl, RenderTarget, Route, Scene, env_rotation};

const SIZE: u32 = 512;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let route = if args.iter().any(|a| a == "osmesa") {
        Route::OsMesa
    } else {
        Route::Egl
    };
    let value = |flag: &str| {
        args.iter()
            .position(|a| a == flag)
            .and_then(|i| args.get(i + 1))
    };
    let frames: usize = value("--frames")
        .map(|v| v.parse())
        .transpose()?
        .unwrap_or(20);
    let ggx: Option<f64> = value("--ggx").map(|v| v.parse()).transpose()?;
    let prefiltered_only = args.iter().any(|a| a == "--prefiltered-only");
    let clock = if args.iter().any(|a| a == "--gpu-clock") {
        Clock::Gpu
    } else {
        Clock::Wall
    };
    let gl = Gl::new(route)?;
    println!(
        "{route} ({}), {SIZE}² sphere, {frames} frames each, {}",
        gl.renderer(),
        clock.describe()
    );
    let sky = Sky {
        width: 1024,
        ..Sky::default()
    }
    .render()?;
    let env_lights: usize = value("--env-lights")
        .map(|v| v.parse())
        .transpose()?
        .unwrap_or(0);
    let light = EnvLight::with_lights(
        &sky,
        &ndfmap::environment::lights::LightOptions::up_to(env_lights),
    );
    println!("  {} extracted light(s)", light.lights().len());
    let env = EnvTextures::upload(&gl, &light)?;
    let sample = ndfmap::procedural::generate(512, 3);
    let map = sample.map.clone();
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
        bake(&map, Method::Olano),
        bake_with(&map, Method::Vmf, &mixture(4, Some(1.0)))?,
        bake_with(&map, Method::Vmf, &mixture(6, Some(1.0)))?,
        bake_with(&map, Method::Vmf, &mixture(4, None))?,
        bake_with(&map, Method::Vmf, &mixture(6, None))?,
        bake_with(&map, Method::Tan2005, &mixture(4, Some(1.0)))?,
    ];
    for er in [EnvRoute::Prefiltered, EnvRoute::Sh] {
        for b in &bakes {
            let wanted = if sh_only {
                er == EnvRoute::Prefiltered && b.method == Method::Plain
            } else {
                !prefiltered_only || er == EnvRoute::Prefiltered
            };
            if wanted {
                configs.push((er, b.clone()));
            }
        }
    }
    if prefiltered_only {
        let coloured = sample.map.with_feature(sample.albedo.clone())?;
        let b = bake_with(&coloured, Method::Vmf, &mixture(6, Some(1.0)))?;
        configs.push((EnvRoute::Prefiltered, b));
    } else {
        for lmax in [2, 4, 8] {
            configs.push((EnvRoute::Sh, bake_with(&map, Method::Sh, &sh(lmax))?));
        }
    }
    let mut scene = Scene::standard().remove(2);
    scene.lighting.brdf = match ggx {
        Some(a) => Brdf::ggx(a),
        None => Brdf::BlinnPhong { s: 256.0 },
    };
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
        let color = b.method == Method::Vmf && b.textures.len() > b.lobes;
        let options = ShaderOptions {
            light: ShaderLight::env(er),
            brdf: ShaderBrdf::of(&scene.lighting.brdf),
            color,
            env_lights: !light.lights().is_empty(),
            ..Default::default()
        };
        let r = BakeRenderer::new(&gl, b, &options)?;
        let mut times = Vec::new();
        for i in 0..frames + 3 {
            target.clear([0.0, 0.0, 0.0, 1.0]);
            let (drawn, ms) = gl.time_ms(clock, || {
                r.draw_env(
                    &mesh,
                    &glam::Mat4::IDENTITY,
                    &scene.camera,
                    &scene.lighting,
                    &env,
                    &rotation,
                    &target,
                )
            })?;
            drawn?;
            if i >= 3 {
                times.push(ms);
            }
        }
        times.sort_by(f64::total_cmp);
        let median = times[times.len() / 2];
        let b0 = *base.get_or_insert(median);
        println!(
            "  {:<24} {median:>10.4} {:>8.2}",
            format!(
                "{} {}{}",
                er.name(),
                b.label(),
                if color { " + colour" } else { "" }
            ),
            median / b0
        );
    }
    Ok(())
}
