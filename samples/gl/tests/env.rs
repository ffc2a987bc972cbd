//! GL = CPU for the environment-lit shaders (issue 16): the probe variant of
//! `ndfmap::glsl`'s `NDF_LIGHT_ENV_PREFILTERED` and `NDF_LIGHT_ENV_SH` specializations rendered on
//! Mesa through each headless route, against their CPU twin `ndfmap::envlight::shade` (after the
//! same filtering: `ndfmap::sample::trilinear` for hardware sampling, each texel shaded and
//! blended for manual sampling), texel for texel, at every level (integer LOD) and at a
//! fractional LOD, for four views (the zenith, θ_o = 35°, 60° and 80°), plain, Toksvig, LEAN,
//! vMF (3 unaligned lobes, manual; 2 aligned lobes, hardware; f32 and f16), Olano–North, Tan
//! 2005 (2 aligned Gaussians, hardware; with colour textures in the colour test), Lambert,
//! Blinn-Phong s = 32 and 256 and GGX α = 0.3 with its g factor, both routes.
//!
//! The environment is the project's generated sky with a sun (64 × 32: the sun's texel holds
//! about 400 times the sky's radiance), so the lookups next to a very bright texel are covered.
//! The sun is orange (3·10⁴, 1.5·10⁴, 0.5·10⁴) and the sky blue, and the draws of every case
//! cycle through the colour channels (`ndf_probe_channel` 0, 1, 2 against the twin's R, G, B;
//! draw i of view k writes channel (i + k) mod 3, so each case checks all three at several
//! levels without tripling the draws): swapped or collapsed channels fail.
//!
//! Error measure: `|gl − cpu| / (|cpu| + floor)` with `floor = 1e-3 ·` the largest CPU value of
//! the term in the case (relative where the value matters, absolute in the tails). Bound
//! ([`TOLERANCE`]): f32 rounding of the shader's sums (81 SH terms for the SH route) and of the
//! angles from GLSL's `atan`/`acos` (Mesa's polynomial approximations) that place the bilinear
//! lookups; measured maxima are printed by the test and listed in docs/environment.md.
//!
//! Every case runs through EGL; through OSMesa a subset of each test does ([`for_route`]: a
//! mixture drawn by manual and one by hardware sampling, Toksvig, an SH bake, two BRDFs). Both
//! routes reach the same llvmpipe rasterizer and GLSL compiler, so the shaders' arithmetic is
//! the same; what the second route can break is the context it makes, which the subset draws
//! through every shader family. The whole set through both routes took 848 s of CI (Mesa's
//! shader cache off, two cores); with the subset and one compile per program across tangent
//! frames ([`measure_frames`]), 459 s.

use glam::{DMat3, DVec2, DVec3};
use ndfmap::bake::{Bake, BakeOptions, Method};
use ndfmap::brdf::{Brdf, Ggx};
use ndfmap::environment::Sky;
use ndfmap::environment::lights::LightOptions;
use ndfmap::envlight::{EnvLight, Route, shade_in, shade_in_with};
use ndfmap::format::Format;
use ndfmap::glsl::{
    ShaderBrdf, ShaderLight, ShaderOptions, ShaderSpec, Stage, manual_sampling, source,
};
use ndfmap::methods::{bake, bake_with};
use ndfmap::sample::{bilinear, level_weights, trilinear};
use ndfmap::shade::{ShadeOptions, shade_rgb_with};
use ndfmap_gl::{
    BakeTextures, BrdfBinding, EnvTextures, Gl, Program, RenderTarget, draw_fullscreen,
    read_rgba_f32,
};
use std::collections::BTreeMap;

/// Largest accepted error (module docs) of a route. Measured on llvmpipe (both routes): without
/// the sun every case is below 9e-4. With it, prefiltered ≤ 5.7e-3 since the sun is orange
/// (its red texel is 1.5 times the earlier white sun's over a red sky a quarter of the blue:
/// a larger jump next to it; ≤ 4.6e-3 with the white sun) (issue 18's moment-matched
/// lobe: its κ_i is larger than the earlier s'/4, so lookups read finer levels next to the sun;
/// the point + environment shader ≤ 2.4e-3): the bilinear lookup next
/// to the sun's texel (≈ 400 times its neighbours) turns the f32/`atan` error of the texel
/// position into that much radiance; SH ≤ 2.9e-2 where the specular term is 1/100 of the
/// image's largest: the terms of eq 26's series are of the order of the sun's power and cancel
/// (the ringing of a truncated point source), so f32 leaves an absolute error of about 1.5e-4
/// of the largest value (the second number printed).
fn tolerance(route: Route) -> f64 {
    match route {
        Route::Prefiltered => 8e-3,
        Route::Sh => 4e-2,
    }
}

/// The cases a test runs through `route`: all of `all` through EGL, those at the indices `keep`
/// through OSMesa (module docs).
fn for_route<T>(route: ndfmap_gl::Route, all: Vec<T>, keep: &[usize]) -> Vec<T> {
    if route == ndfmap_gl::Route::Egl {
        return all;
    }
    all.into_iter()
        .enumerate()
        .filter(|(i, _)| keep.contains(i))
        .map(|(_, x)| x)
        .collect()
}

fn views() -> Vec<DVec3> {
    let d = |t: f64, p: f64| {
        let (t, p) = (t.to_radians(), p.to_radians());
        DVec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos())
    };
    vec![DVec3::Z, d(35.0, 10.0), d(60.0, 130.0), d(80.0, 250.0)]
}

fn brdfs() -> Vec<Brdf> {
    vec![
        Brdf::Lambert,
        Brdf::BlinnPhong { s: 32.0 },
        Brdf::BlinnPhong { s: 256.0 },
        Brdf::Ggx(Ggx {
            g: true,
            ..Ggx::new(0.3)
        }),
    ]
}

fn bakes() -> Vec<Bake> {
    let map = ndfmap::procedural::generate(16, 5).map;
    let mut out: Vec<Bake> = [Method::Plain, Method::Toksvig, Method::Lean]
        .iter()
        .map(|&m| bake(&map, m))
        .collect();
    let unaligned = BakeOptions {
        lobes: 3,
        ..Default::default()
    };
    let aligned = BakeOptions {
        lobes: 2,
        align: Some(1.0),
        ..Default::default()
    };
    let v3 = bake_with(&map, Method::Vmf, &unaligned).unwrap();
    let v2 = bake_with(&map, Method::Vmf, &aligned).unwrap();
    out.push(ndfmap::pack::quantize(&v3, Format::F16).unwrap());
    out.push(v3);
    out.push(v2);
    out.push(bake(&map, Method::Olano));
    out.push(tan2(&map));
    out
}

/// Tan 2005 with 2 aligned Gaussians (hardware sampling).
fn tan2(map: &ndfmap::NormalMap) -> Bake {
    let o = BakeOptions {
        lobes: 2,
        align: Some(1.0),
        ..Default::default()
    };
    bake_with(map, Method::Tan2005, &o).unwrap()
}

/// Per colour channel (R, G, B): (diffuse, specular).
type Rgb = [(f64, f64); 3];

/// A probe's CPU twin at `uv`, `lod`: `one` (a texel's (diffuse, specular) per channel) on the
/// hardware's trilinear parameters, or on each texel the manual path reads, blended as it
/// blends them.
fn filtered(
    bake: &Bake,
    manual: bool,
    uv: DVec2,
    lod: f64,
    one: impl Fn(&[[f32; 4]]) -> Rgb,
) -> Rgb {
    if !manual {
        return one(&trilinear(bake, uv, lod));
    }
    let mut t = vec![[0.0f32; 4]; bake.textures.len()];
    let mut out = [(0.0, 0.0); 3];
    for (level, lw) in level_weights(lod, bake.level_count()) {
        for (index, bw) in bilinear(bake, level, uv) {
            bake.texel_into(level, index, &mut t);
            for (o, f) in out.iter_mut().zip(one(&t)) {
                o.0 += lw * bw * f.0;
                o.1 += lw * bw * f.1;
            }
        }
    }
    out
}

/// The CPU twin of the probe at `uv`, `lod` (with the colour textures when `color`).
#[allow(clippy::too_many_arguments)]
fn cpu(
    light: &EnvLight,
    bake: &Bake,
    manual: bool,
    uv: DVec2,
    lod: f64,
    v: DVec3,
    brdf: &Brdf,
    route: Route,
    frame: DMat3,
    color: bool,
) -> Rgb {
    filtered(bake, manual, uv, lod, |t| {
        let s = shade_in_with(light, frame, bake, t, v, brdf, route, color);
        std::array::from_fn(|c| (s.diffuse[c], s.specular[c]))
    })
}

/// Draws the probe `program` at every level of `bake` and a fractional LOD, draw i writing
/// colour channel (i + `first_channel`) mod 3, against `expected(uv, lod)` per pixel (diffuse,
/// specular per channel): the largest error relative to each value (plus a thousandth of the
/// channel's largest), and the largest absolute error over the largest value.
fn probe_levels(
    gl: &Gl,
    program: &Program,
    bake: &Bake,
    first_channel: usize,
    expected: impl Fn(DVec2, f64) -> Rgb,
) -> (f64, f64) {
    let mut draw = first_channel;
    let (mut worst, mut worst_abs) = (0.0f64, 0.0f64);
    for level in 0..bake.level_count() {
        let (w, h) = bake.sizes[level];
        let target = RenderTarget::new(gl, w, h).unwrap();
        program.set_vec2("ndf_probe_size", [w as f32, h as f32]);
        for frac in [0.0, 0.375] {
            let lod = level as f64 + frac;
            program.set_f32("ndf_probe_lod", lod as f32);
            let expected: Vec<Rgb> = (0..(w * h) as usize)
                .map(|i| {
                    let (x, y) = (i as u32 % w, i as u32 / w);
                    let uv = DVec2::new((x as f64 + 0.5) / w as f64, (y as f64 + 0.5) / h as f64);
                    expected(uv, lod)
                })
                .collect();
            {
                let c = draw % 3;
                draw += 1;
                program.set_i32("ndf_probe_channel", c as i32);
                draw_fullscreen(program, &target).unwrap();
                let pixels = read_rgba_f32(&target).unwrap();
                let fd = 1e-3 * expected.iter().map(|e| e[c].0.abs()).fold(0.0, f64::max);
                let fs = 1e-3 * expected.iter().map(|e| e[c].1.abs()).fold(0.0, f64::max);
                for (p, e) in pixels.iter().zip(expected.iter().map(|e| e[c])) {
                    assert!(p[0].is_finite() && p[1].is_finite());
                    let ed = (p[0] as f64 - e.0).abs() / (e.0.abs() + fd + 1e-30);
                    let es = (p[1] as f64 - e.1).abs() / (e.1.abs() + fs + 1e-30);
                    worst = worst.max(ed).max(es);
                    let ad = (p[0] as f64 - e.0).abs() / (1e3 * fd + 1e-30);
                    let as_ = (p[1] as f64 - e.1).abs() / (1e3 * fs + 1e-30);
                    worst_abs = worst_abs.max(ad).max(as_);
                }
            }
        }
    }
    (worst, worst_abs)
}

/// Renders one bake × BRDF × route at every level and a fractional LOD for every view; returns
/// the largest error and the largest absolute error over the largest value.
#[allow(clippy::too_many_arguments)]
fn measure(
    gl: &Gl,
    env: &EnvTextures,
    light: &EnvLight,
    bake: &Bake,
    brdf: &Brdf,
    route: Route,
    frame: Option<DMat3>,
    views: &[DVec3],
) -> (f64, f64) {
    measure_with(gl, env, light, bake, brdf, route, frame, views, false)
}

/// [`measure`], with the colour textures (`NDF_COLOR`, eq 22) when `color`.
#[allow(clippy::too_many_arguments)]
fn measure_with(
    gl: &Gl,
    env: &EnvTextures,
    light: &EnvLight,
    bake: &Bake,
    brdf: &Brdf,
    route: Route,
    frame: Option<DMat3>,
    views: &[DVec3],
    color: bool,
) -> (f64, f64) {
    let frames = [(frame, views)];
    measure_frames(
        gl,
        env,
        light,
        bake,
        brdf,
        route,
        &frames,
        color,
        Lights::None,
    )[0]
}

/// Whether the probe adds the extracted lights ([`measure_frames`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Lights {
    /// No `NDF_ENV_LIGHTS` (the light must have none).
    None,
    /// `NDF_ENV_LIGHTS` with the uploaded lights.
    Added,
    /// `NDF_ENV_LIGHTS` with `ndf_env_light_count` forced to 0 after binding: the shader then
    /// drops the lights the twin adds (the check that the test can fail).
    Dropped,
}

/// [`measure_with`] for several tangent frames, each with its views, from one compiled program
/// with the extracted lights' loop (`ShaderOptions::env_lights`) per `lights` (the frame is a
/// uniform; llvmpipe's compile of an SH-route shader is most of this test's
/// time, and CI runs with Mesa's shader cache off). The unset frame (`None`, the identity) must
/// come first, before the uniform is set.
#[allow(clippy::too_many_arguments)]
fn measure_frames(
    gl: &Gl,
    env: &EnvTextures,
    light: &EnvLight,
    bake: &Bake,
    brdf: &Brdf,
    route: Route,
    frames: &[(Option<DMat3>, &[DVec3])],
    color: bool,
    lights: Lights,
) -> Vec<(f64, f64)> {
    assert!(
        frames.iter().skip(1).all(|(f, _)| f.is_some()),
        "the unset frame goes first"
    );
    let options = ShaderOptions {
        brdf: ShaderBrdf::of(brdf),
        probe: true,
        light: ShaderLight::env(route),
        color,
        env_lights: lights != Lights::None,
        ..Default::default()
    };
    let vertex = source(bake, Stage::Vertex, &options).unwrap();
    let fragment = source(bake, Stage::Fragment, &options).unwrap();
    let program = Program::new(gl, &vertex, &fragment).unwrap_or_else(|e| panic!("{e}"));
    let textures = BakeTextures::upload(gl, bake, bake.format).unwrap();
    textures.bind(&program);
    let unit = textures.len() as u32;
    BrdfBinding::default()
        .apply(
            gl,
            &program,
            brdf,
            options.brdf,
            (bake.method == Method::Sh).then(|| ndfmap::sh::lmax_of(bake)),
            unit,
        )
        .unwrap();
    env.bind(&program, unit + 1, brdf, route);
    if lights == Lights::Dropped {
        program.set_f32("ndf_env_light_count", 0.0);
    }
    let manual = manual_sampling(&ShaderSpec::of(bake), &options);
    let mut out = Vec::new();
    for &(frame, views) in frames {
        // None: ndf_probe_frame left unset (the identity).
        if let Some(f) = frame {
            program.set_mat3("ndf_probe_frame", &f.as_mat3());
        }
        let frame = frame.unwrap_or(DMat3::IDENTITY);
        let mut worst = 0.0f64;
        let mut worst_abs = 0.0f64;
        for (k, &v) in views.iter().enumerate() {
            program.set_vec3("ndf_probe_v", v.as_vec3());
            let (e, a) = probe_levels(gl, &program, bake, k, |uv, lod| {
                cpu(light, bake, manual, uv, lod, v, brdf, route, frame, color)
            });
            worst = worst.max(e);
            worst_abs = worst_abs.max(a);
        }
        out.push((worst, worst_abs));
    }
    out
}

/// A GL context on `route` with the generated 64 × 32 sky (its sun orange, its sky blue)
/// uploaded, or `None`
/// (said on stdout) when `NDFMAP_SKIP_GL=1`.
fn lit_context(route: ndfmap_gl::Route) -> Option<(Gl, EnvLight, EnvTextures)> {
    sky_context(route, EnvLight::new)
}

/// [`lit_context`] with the sky's light prepared by `prepare`.
fn sky_context(
    route: ndfmap_gl::Route,
    prepare: impl Fn(&ndfmap::environment::Environment) -> EnvLight,
) -> Option<(Gl, EnvLight, EnvTextures)> {
    if std::env::var("NDFMAP_SKIP_GL").is_ok_and(|v| v == "1") {
        println!("skipped: NDFMAP_SKIP_GL=1");
        return None;
    }
    let gl = Gl::new(route).unwrap_or_else(|e| panic!("{e}\n(NDFMAP_SKIP_GL=1 skips GL tests)"));
    let sky = Sky {
        width: 64,
        sun: [3.0e4, 1.5e4, 0.5e4],
        ..Sky::default()
    }
    .render()
    .unwrap();
    let light = prepare(&sky);
    let env = EnvTextures::upload(&gl, &light).unwrap();
    Some((gl, light, env))
}

fn run(route: ndfmap_gl::Route) {
    let Some((gl, light, env)) = lit_context(route) else {
        return;
    };
    let mut table: BTreeMap<String, (f64, f64)> = BTreeMap::new();
    let mut failures = Vec::new();
    // Through OSMesa: Toksvig and vMF J = 3 (manual sampling), Blinn-Phong s = 32 and GGX.
    for b in for_route(route, bakes(), &[1, 4]) {
        for brdf in for_route(route, brdfs(), &[1, 3]) {
            for r in [Route::Prefiltered, Route::Sh] {
                let (e, a) = measure(&gl, &env, &light, &b, &brdf, r, None, &views());
                let name = match &brdf {
                    Brdf::BlinnPhong { s } => format!("blinn-phong s={s}"),
                    Brdf::Ggx(g) => format!("ggx a={} g", g.alpha),
                    b => b.model().to_string(),
                };
                let key = format!("{} {} {name}", r.name(), b.label());
                if e > tolerance(r) {
                    failures.push(format!("{key}: {e:.2e}"));
                }
                table.insert(key, (e, a));
            }
        }
    }
    println!(
        "{route}: largest GL-vs-CPU error of the environment-lit shaders \
         (measure of the module docs / absolute error over the largest value)"
    );
    for (k, (e, a)) in &table {
        println!("  {k:<40} {e:.2e} / {a:.2e}");
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// A tangent frame turned 50° away from the environment's zenith and 20° about it (a curved
/// mesh's fragment): the per-fragment rotation of the SH bakes, and the lookups of the others.
fn tilted() -> DMat3 {
    DMat3::from_rotation_z(0.35)
        * DMat3::from_axis_angle(DVec3::new(1.0, 0.4, 0.0).normalize(), 0.87)
}

/// Largest accepted error of an SH bake under the SH route (module docs; measured maxima in
/// docs/environment.md): the series' terms are of the order of the sun's power and cancel,
/// and the per-fragment rotation adds f32 rounding of `2 Σ (2l+1)²` products.
const SH_TOLERANCE: f64 = 2e-2;

/// SH bakes (l* = 2, 4, 8) lit by the SH route in the environment's frame and in [`tilted`],
/// and Toksvig / vMF J = 3 (manual) in [`tilted`] (the frame of every other lookup).
fn run_framed(route: ndfmap_gl::Route) {
    let Some((gl, light, env)) = lit_context(route) else {
        return;
    };
    let map = ndfmap::procedural::generate(16, 5).map;
    let mut cases: Vec<(Bake, Route, f64)> = [2usize, 4, 8]
        .iter()
        .map(|&lmax| {
            let o = BakeOptions {
                lmax,
                ..Default::default()
            };
            (
                bake_with(&map, Method::Sh, &o).unwrap(),
                Route::Sh,
                SH_TOLERANCE,
            )
        })
        .collect();
    let v3 = bake_with(
        &map,
        Method::Vmf,
        &BakeOptions {
            lobes: 3,
            ..Default::default()
        },
    )
    .unwrap();
    for r in [Route::Prefiltered, Route::Sh] {
        cases.push((bake(&map, Method::Toksvig), r, tolerance(r)));
        cases.push((v3.clone(), r, tolerance(r)));
    }
    // Olano–North's diffuse term rotates its moments into the environment's frame.
    for r in [Route::Prefiltered, Route::Sh] {
        cases.push((bake(&map, Method::Olano), r, tolerance(r)));
    }
    // Through OSMesa: SH l* = 4 and vMF J = 3 by the SH route, Blinn-Phong s = 32 and GGX.
    let cases = for_route(route, cases, &[1, 6]);
    let mut failures = Vec::new();
    println!("{route}: largest GL-vs-CPU error, SH bakes and tilted tangent frames");
    for (b, r, tol) in &cases {
        let brdfs = vec![
            Brdf::Lambert,
            Brdf::BlinnPhong { s: 32.0 },
            brdfs()[3].clone(),
        ];
        for brdf in for_route(route, brdfs, &[1, 2]) {
            let frames: &[Option<DMat3>] = if b.method == Method::Sh {
                &[None, Some(tilted())]
            } else {
                &[Some(tilted())]
            };
            let vs = views();
            let cases: Vec<_> = frames.iter().map(|&f| (f, &vs[1..3])).collect();
            let errors =
                measure_frames(&gl, &env, &light, b, &brdf, *r, &cases, false, Lights::None);
            for (&frame, (e, a)) in frames.iter().zip(errors) {
                let key = format!(
                    "{} {} {} {}",
                    r.name(),
                    b.label(),
                    brdf.model(),
                    if frame.is_some() {
                        "tilted"
                    } else {
                        "env frame"
                    }
                );
                println!("  {key:<44} {e:.2e} / {a:.2e}");
                if e > *tol {
                    failures.push(format!("{key}: {e:.2e}"));
                }
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn sh_bakes_and_tilted_frames_match_the_cpu_twin_through_egl() {
    run_framed(ndfmap_gl::Route::Egl);
}

#[test]
fn sh_bakes_and_tilted_frames_match_the_cpu_twin_through_osmesa() {
    run_framed(ndfmap_gl::Route::OsMesa);
}

#[test]
fn env_shaders_match_the_cpu_twin_through_egl() {
    run(ndfmap_gl::Route::Egl);
}

#[test]
fn env_shaders_match_the_cpu_twin_through_osmesa() {
    run(ndfmap_gl::Route::OsMesa);
}

/// The CPU twin of the `ShaderLight::PointAndEnvPrefiltered` probe: per texel the point
/// light's shading (`shade_rgb_with` applies its g factor) plus the prefiltered environment's, filtered like
/// the shader (trilinear parameters, or each texel shaded and blended).
#[allow(clippy::too_many_arguments)]
fn cpu_both(
    light: &EnvLight,
    bake: &Bake,
    manual: bool,
    uv: DVec2,
    lod: f64,
    (l, h, v): (DVec3, DVec3, DVec3),
    brdf: &Brdf,
    color: bool,
) -> Rgb {
    filtered(bake, manual, uv, lod, |t| {
        let p = shade_rgb_with(bake, t, l, h, brdf, color, &ShadeOptions::default());
        let e = shade_in_with(
            light,
            DMat3::IDENTITY,
            bake,
            t,
            v,
            brdf,
            Route::Prefiltered,
            color,
        );
        std::array::from_fn(|c| (p.diffuse[c] + e.diffuse[c], p.specular[c] + e.specular[c]))
    })
}

/// One shader lit by a point light and the environment (issue 18): the probe of
/// `ShaderLight::PointAndEnvPrefiltered` against the sum of the two CPU twins, for plain, vMF
/// aligned (hardware) and unaligned (manual), Lambert, Blinn-Phong and GGX with g, two
/// light/view pairs, every level and a fractional LOD. Returns the largest error.
fn both(route: ndfmap_gl::Route) {
    let Some((gl, light, env)) = lit_context(route) else {
        return;
    };
    let all = bakes();
    // Through OSMesa: vMF J = 2 aligned (hardware sampling).
    let picked = for_route(route, vec![&all[0], &all[4], &all[5]], &[2]);
    let worst = both_of(&gl, &light, &env, &picked, false);
    println!("{route}: largest GL-vs-CPU error of the point + environment shader: {worst:.2e}");
    assert!(worst <= tolerance(Route::Prefiltered), "{worst:.2e}");
}

/// The point + environment probe of each of `picked` (with the colour textures when `color`)
/// against the sum of the twins; the largest error.
fn both_of(gl: &Gl, light: &EnvLight, env: &EnvTextures, picked: &[&Bake], color: bool) -> f64 {
    let mut worst = 0.0f64;
    for bake in picked {
        for brdf in [
            Brdf::Lambert,
            Brdf::BlinnPhong { s: 32.0 },
            Brdf::Ggx(Ggx {
                g: true,
                ..Ggx::new(0.3)
            }),
        ] {
            let options = ShaderOptions {
                brdf: ShaderBrdf::of(&brdf),
                probe: true,
                light: ShaderLight::PointAndEnvPrefiltered,
                color,
                ..Default::default()
            };
            let vertex = source(bake, Stage::Vertex, &options).unwrap();
            let fragment = source(bake, Stage::Fragment, &options).unwrap();
            assert!(fragment.contains("#define NDF_LIGHT_BOTH 1"));
            assert!(!fragment.contains("#define NDF_LIGHT_ENV 1"));
            let program = Program::new(gl, &vertex, &fragment).unwrap_or_else(|e| panic!("{e}"));
            let textures = BakeTextures::upload(gl, bake, bake.format).unwrap();
            textures.bind(&program);
            let unit = textures.len() as u32;
            BrdfBinding::default()
                .apply(gl, &program, &brdf, options.brdf, None, unit)
                .unwrap();
            env.bind(&program, unit + 1, &brdf, Route::Prefiltered);
            let manual = manual_sampling(&ShaderSpec::of(bake), &options);
            let vs = views();
            for (k, (l, v)) in [(vs[1], vs[0]), (vs[2], vs[3])].into_iter().enumerate() {
                let h = (l + v).normalize();
                program.set_vec3("ndf_probe_l", l.as_vec3());
                program.set_vec3("ndf_probe_h", h.as_vec3());
                program.set_vec3("ndf_probe_v", v.as_vec3());
                let (e, _) = probe_levels(gl, &program, bake, k, |uv, lod| {
                    cpu_both(light, bake, manual, uv, lod, (l, h, v), &brdf, color)
                });
                worst = worst.max(e);
            }
        }
    }
    worst
}

#[test]
fn point_and_env_shader_matches_the_sum_of_the_twins_through_egl() {
    both(ndfmap_gl::Route::Egl);
}

#[test]
fn point_and_env_shader_matches_the_sum_of_the_twins_through_osmesa() {
    both(ndfmap_gl::Route::OsMesa);
}

/// Mixture bakes of a map with a two-colour albedo (orange where the normal leans to +x, blue
/// elsewhere, so lobes of one texel differ in colour and the channels in weight): 3 unaligned
/// lobes (manual sampling; f32 and f16) and 2 aligned lobes (hardware), and Tan 2005 with 2
/// aligned Gaussians (hardware), each with its colour textures (`α·y`).
fn coloured_bakes() -> Vec<Bake> {
    let map = ndfmap::procedural::generate(16, 5).map;
    let albedo = map
        .normals()
        .iter()
        .map(|n| {
            if n.x > 0.0 {
                [0.9, 0.25, 0.05, 1.0]
            } else {
                [0.05, 0.3, 0.8, 1.0]
            }
        })
        .collect();
    let map = map.with_feature(albedo).unwrap();
    let v3 = bake_with(
        &map,
        Method::Vmf,
        &BakeOptions {
            lobes: 3,
            ..Default::default()
        },
    )
    .unwrap();
    let v2 = bake_with(
        &map,
        Method::Vmf,
        &BakeOptions {
            lobes: 2,
            align: Some(1.0),
            ..Default::default()
        },
    )
    .unwrap();
    let t2 = tan2(&map);
    for b in [&v3, &v2, &t2] {
        assert_eq!(b.textures.len(), 2 * b.lobes, "colour textures baked");
    }
    vec![
        ndfmap::pack::quantize(&v3, Format::F16).unwrap(),
        v3,
        v2,
        t2,
    ]
}

/// Eq 22 under the environment: the `NDF_COLOR` probes of [`coloured_bakes`] under the orange
/// sun and blue sky, both routes (in the environment's frame and in [`tilted`]) and the point +
/// environment shader, against the coloured CPU twin (`shade_in_with(.., true)`,
/// `shade_rgb_with(.., true)`), all three channels. Ignoring the colour textures or swapping
/// their channels puts the GL result tens of percent off the twin (the albedo's channels differ
/// by up to 18×); the test also checks that the twin's colour changes the result that much.
fn colour(route: ndfmap_gl::Route) {
    let Some((gl, light, env)) = lit_context(route) else {
        return;
    };
    let bakes = coloured_bakes();
    // The twin's colour matters: against the uncoloured twin the coloured one is far off.
    let b = &bakes[1];
    let t = b.texel(0, 2, 3);
    let v = views()[1];
    let brdf = Brdf::BlinnPhong { s: 32.0 };
    let c = shade_in_with(
        &light,
        DMat3::IDENTITY,
        b,
        &t,
        v,
        &brdf,
        Route::Prefiltered,
        true,
    );
    let g = shade_in(&light, DMat3::IDENTITY, b, &t, v, &brdf, Route::Prefiltered);
    let ratio: Vec<f64> = (0..3).map(|k| c.diffuse[k] / g.diffuse[k]).collect();
    assert!(
        ratio.iter().fold(0.0f64, |a, &x| a.max(x))
            > 2.0 * ratio.iter().fold(9.0f64, |a, &x| a.min(x)),
        "{ratio:?}"
    );
    let mut failures = Vec::new();
    println!("{route}: largest GL-vs-CPU error, colour bakes (NDF_COLOR) under the environment");
    // Through OSMesa: vMF J = 2 aligned with colour, Blinn-Phong s = 32.
    let bakes = for_route(route, bakes, &[2]);
    for b in &bakes {
        let brdfs = vec![
            Brdf::Lambert,
            Brdf::BlinnPhong { s: 32.0 },
            brdfs()[3].clone(),
        ];
        for brdf in for_route(route, brdfs, &[1]) {
            for r in [Route::Prefiltered, Route::Sh] {
                let vs = views();
                let frames = [None, Some(tilted())];
                let cases: Vec<_> = frames.iter().map(|&f| (f, &vs[..])).collect();
                let errors =
                    measure_frames(&gl, &env, &light, b, &brdf, r, &cases, true, Lights::None);
                for (frame, (e, a)) in frames.into_iter().zip(errors) {
                    let key = format!(
                        "{} {}+colour {} {}",
                        r.name(),
                        b.label(),
                        brdf.model(),
                        if frame.is_some() {
                            "tilted"
                        } else {
                            "env frame"
                        }
                    );
                    println!("  {key:<50} {e:.2e} / {a:.2e}");
                    if e > tolerance(r) {
                        failures.push(format!("{key}: {e:.2e}"));
                    }
                }
            }
        }
    }
    let picked: Vec<&Bake> = bakes.iter().collect();
    let worst = both_of(&gl, &light, &env, &picked, true);
    println!("  point + environment, colour: {worst:.2e}");
    if worst > tolerance(Route::Prefiltered) {
        failures.push(format!("point + environment colour: {worst:.2e}"));
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn colour_bakes_match_the_cpu_twin_through_egl() {
    colour(ndfmap_gl::Route::Egl);
}

#[test]
fn colour_bakes_match_the_cpu_twin_through_osmesa() {
    colour(ndfmap_gl::Route::OsMesa);
}

/// The generated coloured sky (as [`lit_context`]) with its sun extracted as a light
/// (`EnvLight::with_lights`, the default extraction), uploaded, or `None` when
/// `NDFMAP_SKIP_GL=1`.
fn lights_context(route: ndfmap_gl::Route) -> Option<(Gl, EnvLight, EnvTextures)> {
    let (gl, light, env) = sky_context(route, |sky| {
        EnvLight::with_lights(sky, &LightOptions::default())
    })?;
    assert_eq!(light.lights().len(), 1, "the sun extracted");
    assert_eq!(env.data().lights.len(), 1);
    Some((gl, light, env))
}

/// Issue 16's extracted lights on the GPU: the probes with `NDF_ENV_LIGHTS` under the sky whose
/// sun is extracted (the tables hold the residual, the sun is added per texel by
/// `ndf_env_lights`), against the CPU twin `shade_in_with` (whose `add_lights` adds the same
/// term): plain, Toksvig, LEAN, vMF J = 2 (aligned, hardware sampling; and with its colour
/// textures), both routes, and SH l* = 2 by the SH route; Lambert, Blinn-Phong s = 32 and GGX
/// α = 0.3 with g; in the environment's frame (four views) and in [`tilted`] (two views), all
/// three channels. Then the same shader with `ndf_env_light_count = 0` must be far off the twin
/// (the sun's term is most of the image), so the comparison can fail.
fn extracted_lights(route: ndfmap_gl::Route) {
    let Some((gl, light, env)) = lights_context(route) else {
        return;
    };
    let all = bakes();
    let coloured = coloured_bakes();
    let map = ndfmap::procedural::generate(16, 5).map;
    let sh2 = bake_with(
        &map,
        Method::Sh,
        &BakeOptions {
            lmax: 2,
            ..Default::default()
        },
    )
    .unwrap();
    // (bake, colour): plain, Toksvig, LEAN, vMF J = 2 aligned, the same with colour, SH l* = 2,
    // Olano–North, Tan 2005 J = 2 aligned without and with colour.
    // Through OSMesa: vMF J = 2 aligned and SH l* = 2, Blinn-Phong s = 32 and GGX.
    let cases: Vec<(&Bake, bool)> = for_route(
        route,
        vec![
            (&all[0], false),
            (&all[1], false),
            (&all[2], false),
            (&all[5], false),
            (&coloured[2], true),
            (&sh2, false),
            (&all[6], false),
            (&all[7], false),
            (&coloured[3], true),
        ],
        &[3, 5],
    );
    let mut failures = Vec::new();
    let mut table: BTreeMap<String, (f64, f64)> = BTreeMap::new();
    for &(b, color) in &cases {
        let brdfs = vec![
            Brdf::Lambert,
            Brdf::BlinnPhong { s: 32.0 },
            brdfs()[3].clone(),
        ];
        for brdf in for_route(route, brdfs, &[1, 2]) {
            for r in [Route::Prefiltered, Route::Sh] {
                if b.method == Method::Sh && r != Route::Sh {
                    continue;
                }
                let vs = views();
                let cases = [(None, &vs[..]), (Some(tilted()), &vs[1..3])];
                let errors =
                    measure_frames(&gl, &env, &light, b, &brdf, r, &cases, color, Lights::Added);
                for ((frame, _), (e, a)) in cases.into_iter().zip(errors) {
                    let key = format!(
                        "{} {}{} {} {}",
                        r.name(),
                        b.label(),
                        if color { "+colour" } else { "" },
                        brdf.model(),
                        if frame.is_some() {
                            "tilted"
                        } else {
                            "env frame"
                        }
                    );
                    let tol = if b.method == Method::Sh {
                        SH_TOLERANCE
                    } else {
                        tolerance(r)
                    };
                    if e > tol {
                        failures.push(format!("{key}: {e:.2e}"));
                    }
                    table.insert(key, (e, a));
                }
            }
        }
    }
    println!(
        "{route}: largest GL-vs-CPU error with the sun extracted as a light (NDF_ENV_LIGHTS; \
         measure of the module docs / absolute error over the largest value)"
    );
    for (k, (e, a)) in &table {
        println!("  {k:<52} {e:.2e} / {a:.2e}");
    }
    // The same shader without its lights is far off the twin that adds them.
    for r in [Route::Prefiltered, Route::Sh] {
        let vs = views();
        let frames = [(None, &vs[..2])];
        let brdf = Brdf::BlinnPhong { s: 32.0 };
        let (e, _) = measure_frames(
            &gl,
            &env,
            &light,
            &all[5],
            &brdf,
            r,
            &frames,
            false,
            Lights::Dropped,
        )[0];
        println!("  {} count = 0 (must fail): {e:.2e}", r.name());
        if e < 10.0 * tolerance(r) {
            failures.push(format!(
                "{}: without its lights the shader is only {e:.2e} off",
                r.name()
            ));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn extracted_lights_match_the_cpu_twin_through_egl() {
    extracted_lights(ndfmap_gl::Route::Egl);
}

#[test]
fn extracted_lights_match_the_cpu_twin_through_osmesa() {
    extracted_lights(ndfmap_gl::Route::OsMesa);
}
