//! GL = CPU, texel for texel: the product shaders (`ndfmap::glsl`, probe variant) rendered on Mesa
//! through each headless route, against their CPU twin (`ndfmap::sample::shade_at`, which calls
//! `ndfmap::shade`), for every method, lobe counts 1–8, every storage format a method's textures
//! fit, both BRDFs, hardware and manual sampling, colour on and off — at the texel centres of
//! every level (integer LOD) and at fractional LODs (trilinear between levels).
//!
//! Error measure: `|gl − cpu| / (|cpu| + floor)`, with `floor = 1e-3 ·` the BRDF's peak
//! `(s+1)/(2π)` (or `1/(4πσ²)`) for the specular term and 1e-3 for the diffuse term: relative
//! where the value matters, absolute in the tails where f32 rounding of `cos^s` dominates.
//! The GLSL evaluates in f32 from the same texel values the CPU evaluates in f64, so the bound is
//! f32 rounding amplified by the lobe's exponent: [`tolerance`].
//!
//! Left out: hardware trilinear sampling of unorm8 textures at fractional LODs. llvmpipe filters
//! 8-bit textures in 8-bit fixed point (8-bit weights and results: the filtered value is within
//! 1.6 codes of the exact one, `tests/common` measures it), so Algorithm 2's `θ.yzw/α` of
//! filtered unorm8 values differs from the exact filter's by far more than rounding. Texel
//! centres of unorm8 (exact reads) and manual sampling of unorm8 are compared.

use glam::DVec2;
use ndfmap::bake::{Bake, BakeOptions, Method};
use ndfmap::brdf::{Brdf, half_vector};
use ndfmap::eval::default_directions;
use ndfmap::format::Format;
use ndfmap::glsl::{Sampling, ShaderBrdf, ShaderOptions, Stage, source};
use ndfmap::methods::{bake, bake_with};
use ndfmap::sample::{Filtering, shade_at};
use ndfmap_gl::{BakeTextures, Gl, Program, RenderTarget, Route, draw_fullscreen, read_rgba_f32};
use std::collections::BTreeMap;

/// Largest accepted error (measure above) for a BRDF of Blinn-Phong exponent `s`: f32 rounding
/// of `cos_h` is amplified `s`-fold by `cos_h^s`. Measured on llvmpipe (both routes): ≤ 4.5e-5
/// at s = 64 (all formats, texel centres and trilinear), ≤ 8e-4 at s = 1024.
/// Torrance–Sparrow (σ = 0.1): ≤ 8e-4, dominated by GLSL's `acos` for the half-angle β, which
/// Mesa evaluates by a polynomial approximation (GLSL specifies no precision for it); the lobe's
/// relative error is `β δβ / (2σ²)`.
fn tolerance(brdf: Brdf) -> f64 {
    match brdf {
        Brdf::BlinnPhong { s } => 3e-5 + 2e-6 * s,
        Brdf::TorranceSparrow { .. } => 1.5e-3,
    }
}

struct Case {
    bake: Bake,
    brdf: Brdf,
    sampling: Sampling,
    color: bool,
}

fn label(c: &Case) -> String {
    let brdf = match c.brdf {
        Brdf::BlinnPhong { .. } => "bp",
        Brdf::TorranceSparrow { .. } => "ts",
    };
    format!(
        "{} {brdf} {:?}{}",
        c.bake.label(),
        c.sampling,
        if c.color { " colour" } else { "" }
    )
}

/// Renders `case` at every level (and at fractional LODs) for a few light/view pairs and returns
/// the largest error at texel centres and at fractional LODs.
fn measure(gl: &Gl, case: &Case) -> (f64, f64) {
    let bake = &case.bake;
    let options = ShaderOptions {
        brdf: match case.brdf {
            Brdf::BlinnPhong { .. } => ShaderBrdf::BlinnPhong,
            Brdf::TorranceSparrow { .. } => ShaderBrdf::TorranceSparrow,
        },
        sampling: case.sampling,
        color: case.color,
        probe: true,
    };
    let vertex = source(bake, Stage::Vertex, &options).unwrap();
    let fragment = source(bake, Stage::Fragment, &options).unwrap();
    let program = Program::new(gl, &vertex, &fragment).unwrap_or_else(|e| panic!("{e}"));
    let textures = BakeTextures::upload(gl, bake, bake.format).unwrap();
    textures.bind(&program);
    let manual = ndfmap::glsl::manual_sampling(&ndfmap::glsl::ShaderSpec::of(bake), &options);
    let (peak, param) = match case.brdf {
        Brdf::BlinnPhong { s } => ((s + 1.0) / (2.0 * std::f64::consts::PI), ("ndf_s", s)),
        Brdf::TorranceSparrow { sigma } => (
            1.0 / (4.0 * std::f64::consts::PI * sigma * sigma),
            ("ndf_sigma", sigma),
        ),
    };
    program.set_f32(param.0, param.1 as f32);
    let filtering = Filtering {
        brdf: case.brdf,
        manual,
        color: case.color,
    };
    let directions = default_directions();
    let (mut worst, mut worst_trilinear) = (0.0f64, 0.0f64);
    let channels = if case.color { 3 } else { 1 };
    for &(l, v) in [directions[0], directions[6], directions[13], directions[22]].iter() {
        let h = half_vector(l, v);
        program.set_vec3("ndf_probe_l", l.as_vec3());
        program.set_vec3("ndf_probe_h", h.as_vec3());
        for level in 0..bake.level_count() {
            let (w, hgt) = bake.sizes[level];
            let target = RenderTarget::new(gl, w, hgt).unwrap();
            program.set_vec2("ndf_probe_size", [w as f32, hgt as f32]);
            for frac in [0.0, 0.375] {
                let lod = level as f64 + frac;
                program.set_f32("ndf_probe_lod", lod as f32);
                for channel in 0..channels {
                    program.set_i32("ndf_probe_channel", channel as i32);
                    draw_fullscreen(&program, &target).unwrap();
                    let pixels = read_rgba_f32(&target).unwrap();
                    for (i, p) in pixels.iter().enumerate() {
                        let (x, y) = (i as u32 % w, i as u32 / w);
                        let uv =
                            DVec2::new((x as f64 + 0.5) / w as f64, (y as f64 + 0.5) / hgt as f64);
                        let cpu = shade_at(bake, uv, lod, l, h, filtering);
                        let e_d = (p[0] as f64 - cpu.diffuse[channel]).abs()
                            / (cpu.diffuse[channel].abs() + 1e-3);
                        let e_s = (p[1] as f64 - cpu.specular[channel]).abs()
                            / (cpu.specular[channel].abs() + 1e-3 * peak);
                        assert!(p[0].is_finite() && p[1].is_finite(), "{}", label(case));
                        let e = e_d.max(e_s);
                        if frac > 0.0 && !manual && bake.format == Format::Unorm8 {
                            continue; // 8-bit fixed-point filtering (module docs)
                        }
                        let slot = if frac == 0.0 || manual {
                            &mut worst
                        } else {
                            &mut worst_trilinear
                        };
                        if e > *slot {
                            *slot = e;
                        }
                    }
                }
            }
        }
    }
    (worst, worst_trilinear)
}

/// Every case: methods × lobe counts × formats × BRDFs × sampling × colour.
fn cases() -> Vec<Case> {
    let sample = ndfmap::procedural::generate(16, 11);
    let colored = sample
        .map
        .clone()
        .with_feature(sample.albedo.clone())
        .unwrap();
    let mut out = Vec::new();
    let mut push = |b: &Bake, color: bool| {
        for format in Format::ALL {
            let Ok(q) = ndfmap::pack::quantize(b, format) else {
                continue; // the format cannot hold this method's values (LEAN, Tan in unorm)
            };
            let brdfs: &[Brdf] = if format == Format::F32 {
                &[
                    Brdf::BlinnPhong { s: 64.0 },
                    Brdf::BlinnPhong { s: 1024.0 },
                    Brdf::TorranceSparrow { sigma: 0.1 },
                ]
            } else {
                &[Brdf::BlinnPhong { s: 64.0 }]
            };
            for &brdf in brdfs {
                for sampling in [Sampling::Hardware, Sampling::Manual] {
                    out.push(Case {
                        bake: q.clone(),
                        brdf,
                        sampling,
                        color,
                    });
                }
            }
        }
    };
    for method in Method::BASELINES {
        push(&bake(&sample.map, method), false);
    }
    for method in [Method::Vmf, Method::Tan2005] {
        for lobes in 1..=8 {
            let color = lobes % 3 == 1; // colour at J = 1, 4, 7
            let options = BakeOptions {
                lobes,
                align: (lobes % 2 == 0).then_some(1.0),
                ..Default::default()
            };
            let map = if color { &colored } else { &sample.map };
            push(&bake_with(map, method, &options).unwrap(), color);
        }
    }
    out
}

fn run(route: Route) {
    if std::env::var("NDFMAP_SKIP_GL").is_ok_and(|v| v == "1") {
        println!("skipped: NDFMAP_SKIP_GL=1");
        return;
    }
    let gl = Gl::new(route).unwrap_or_else(|e| panic!("{e}\n(NDFMAP_SKIP_GL=1 skips GL tests)"));
    let mut table: BTreeMap<String, (f64, f64)> = BTreeMap::new();
    let mut failures = Vec::new();
    for case in cases() {
        let (e, et) = measure(&gl, &case);
        let key = format!("{} {}", case.bake.method, case.bake.format);
        let entry = table.entry(key).or_default();
        entry.0 = entry.0.max(e);
        entry.1 = entry.1.max(et);
        if e.max(et) > tolerance(case.brdf) {
            failures.push(format!("{}: {e:.2e} / trilinear {et:.2e}", label(&case)));
        }
    }
    println!(
        "{route}: largest GL-vs-CPU error per method and format \
         (texel centres and manual sampling / hardware trilinear at fractional LOD)"
    );
    for (k, (e, et)) in &table {
        println!("  {k:<16} {e:.2e} / {et:.2e}");
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn shaders_match_the_cpu_twin_through_egl() {
    run(Route::Egl);
}

#[test]
fn shaders_match_the_cpu_twin_through_osmesa() {
    run(Route::OsMesa);
}
