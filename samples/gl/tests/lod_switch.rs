//! GL = CPU for the one shader that switches method by level of detail (issue 18,
//! `ndfmap::glsl::lod_switch_source`): three parts of different methods and samplings (plain
//! L0-1, vMF J = 2 aligned hardware L2-3, vMF J = 3 unaligned manual L4-6), each part's
//! textures holding only its levels, rendered through the probe at every level and at a
//! fractional LOD inside every level (so across each part boundary), against the CPU twin
//! `ndfmap::sample::shade_switch`; and the anisotropic variant (plain L0-2, vMF J = 2 aligned
//! L3-6) against `shade_switch_aniso`. Each render is also compared with the *wrong* part's
//! CPU shading (the neighbouring part at the same LOD): the test asserts that this differs by
//! far more than the tolerance somewhere on every level, so a shader choosing the wrong part
//! fails.
//!
//! Error measure as `tests/shaders.rs`: `|gl − cpu| / (|cpu| + floor)`, floor 1e-3 (diffuse)
//! and 1e-3 × the BRDF's peak (specular); Blinn-Phong s = 32, f32 textures.

use glam::DVec2;
use ndfmap_gl::glow::HasContext;
use ndfmap::bake::{Bake, BakeOptions, Method};
use ndfmap::brdf::{Brdf, half_vector};
use ndfmap::eval::default_directions;
use ndfmap::format::Format;
use ndfmap::glsl::{
    LodPart, Sampling, ShaderBrdf, ShaderOptions, ShaderSpec, Stage, lod_switch_sampler,
    lod_switch_source, manual_sampling,
};
use ndfmap::methods::bake_with;
use ndfmap::sample::{Filtering, SwitchPart, shade_at, shade_switch, shade_switch_aniso};
use ndfmap_gl::{
    BakeTextures, BrdfBinding, Gl, Program, RenderTarget, Route, draw_fullscreen, glow,
    read_rgba_f32,
};

const TOLERANCE: f64 = 2e-4;

/// A bake of `method` on the 64² procedural map, kept to levels `first..=last` (level 0 =
/// map level `first`), as `plan::execute` ships a part.
fn part_bake(method: Method, lobes: usize, aligned: bool, first: usize, last: usize) -> Bake {
    let map = ndfmap::procedural::generate(64, 5).map;
    let mut b = bake_with(
        &map,
        method,
        &BakeOptions {
            lobes,
            align: aligned.then_some(1.0),
            ..Default::default()
        },
    )
    .unwrap();
    b.sizes = b.sizes[first..=last].to_vec();
    for t in &mut b.textures {
        t.levels = t.levels[first..=last].to_vec();
    }
    b
}

struct Setup {
    bakes: Vec<(Bake, usize, usize)>,
    sampling: Sampling,
}

fn run_case(gl: &Gl, setup: &Setup) {
    let brdf = Brdf::BlinnPhong { s: 32.0 };
    let options = ShaderOptions {
        brdf: ShaderBrdf::of(&brdf),
        sampling: setup.sampling,
        probe: true,
        ..Default::default()
    };
    let aniso = match setup.sampling {
        Sampling::Anisotropic(n) => Some(n),
        _ => None,
    };
    let parts: Vec<LodPart> = setup
        .bakes
        .iter()
        .map(|(b, first, last)| LodPart {
            spec: ShaderSpec::of(b),
            options: ShaderOptions {
                sampling: if aniso.is_some() {
                    setup.sampling
                } else {
                    Sampling::Auto
                },
                ..options
            },
            first: *first,
            last: *last,
        })
        .collect();
    let map_size = (64, 64);
    let vertex = lod_switch_source(&parts, map_size, Stage::Vertex, &options).unwrap();
    let fragment = lod_switch_source(&parts, map_size, Stage::Fragment, &options).unwrap();
    let program = Program::new(gl, &vertex, &fragment).unwrap_or_else(|e| panic!("{e}"));
    let uploads: Vec<BakeTextures> = setup
        .bakes
        .iter()
        .map(|(b, _, _)| BakeTextures::upload(gl, b, b.format).unwrap())
        .collect();
    let mut unit = 0u32;
    for (k, t) in uploads.iter().enumerate() {
        for i in 0..t.len() {
            // SAFETY: the context is current; the texture lives while `uploads` does.
            unsafe {
                gl.glow().active_texture(glow::TEXTURE0 + unit);
                gl.glow().bind_texture(glow::TEXTURE_2D, Some(t.raw(i)));
            }
            program.set_i32(&lod_switch_sampler(k, i), unit as i32);
            unit += 1;
        }
    }
    // SAFETY: as above.
    unsafe { gl.glow().active_texture(glow::TEXTURE0) };
    BrdfBinding::default()
        .apply(gl, &program, &brdf, options.brdf, None, unit)
        .unwrap();
    let twins: Vec<SwitchPart> = setup
        .bakes
        .iter()
        .zip(&parts)
        .map(|((b, first, last), p)| SwitchPart {
            bake: b,
            first: *first,
            last: *last,
            filtering: Filtering {
                manual: manual_sampling(&p.spec, &p.options),
                ..Filtering::new(brdf.clone())
            },
        })
        .collect();
    let last_level = setup.bakes.last().unwrap().2;
    let peak = brdf.peak().max(1.0);
    let directions = default_directions();
    let mut worst = 0.0f64;
    for &(l, v) in [directions[0], directions[13]].iter() {
        let h = half_vector(l, v);
        program.set_vec3("ndf_probe_l", l.as_vec3());
        program.set_vec3("ndf_probe_h", h.as_vec3());
        for level in 0..=last_level {
            let size = (64u32 >> level).max(1);
            let target = RenderTarget::new(gl, size, size).unwrap();
            program.set_vec2("ndf_probe_size", [size as f32, size as f32]);
            program.set_i32("ndf_probe_channel", 0);
            for frac in [0.0, 0.375] {
                let lod = level as f64 + frac;
                // Anisotropic: a footprint 4 times longer than wide, its probes' LOD = lod.
                let t = 2f64.powf(lod + 2.0);
                let (dx, dy) = (
                    DVec2::new(0.8 * t / 64.0, 0.6 * t / 64.0),
                    DVec2::new(-0.6 * t / (4.0 * 64.0), 0.8 * t / (4.0 * 64.0)),
                );
                if aniso.is_some() {
                    program.set_vec2("ndf_probe_dx", dx.as_vec2());
                    program.set_vec2("ndf_probe_dy", dy.as_vec2());
                } else {
                    program.set_f32("ndf_probe_lod", lod as f32);
                }
                draw_fullscreen(&program, &target).unwrap();
                let pixels = read_rgba_f32(&target).unwrap();
                // The part the switch must use at this level, and a wrong one beside it.
                let right = twins
                    .iter()
                    .position(|p| (p.first..=p.last).contains(&level))
                    .unwrap();
                let wrong = if right + 1 < twins.len() {
                    right + 1
                } else {
                    right - 1
                };
                let mut wrong_worst = 0.0f64;
                for (i, p) in pixels.iter().enumerate() {
                    let (x, y) = (i as u32 % size, i as u32 / size);
                    let uv = DVec2::new(
                        (x as f64 + 0.5) / size as f64,
                        (y as f64 + 0.5) / size as f64,
                    );
                    let cpu = match aniso {
                        Some(n) => shade_switch_aniso(&twins, map_size, uv, (dx, dy), n, l, h),
                        None => shade_switch(&twins, uv, lod, l, h),
                    };
                    let err = |gl: f32, cpu: f64, floor: f64| {
                        (gl as f64 - cpu).abs() / (cpu.abs() + floor)
                    };
                    assert!(p[0].is_finite() && p[1].is_finite());
                    let e = err(p[0], cpu.diffuse.x, 1e-3).max(err(p[1], cpu.specular.x, 1e-3 * peak));
                    assert!(
                        e <= TOLERANCE,
                        "level {level} + {frac}, texel ({x}, {y}): GL ({}, {}) against the switch's \
                         CPU twin ({}, {}): error {e:.2e}",
                        p[0],
                        p[1],
                        cpu.diffuse.x,
                        cpu.specular.x
                    );
                    worst = worst.max(e);
                    // The wrong part at the same LOD (its local level clamped to its levels).
                    let w = &twins[wrong];
                    let local = (lod - w.first as f64).clamp(0.0, (w.last - w.first) as f64);
                    let bad = shade_at(w.bake, uv, local, l, h, &w.filtering);
                    wrong_worst = wrong_worst
                        .max(err(p[0], bad.diffuse.x, 1e-3))
                        .max(err(p[1], bad.specular.x, 1e-3 * peak));
                }
                assert!(
                    wrong_worst > 50.0 * TOLERANCE,
                    "level {level} + {frac}: part {wrong} would pass too ({wrong_worst:.2e}): \
                     the test cannot tell the parts apart"
                );
            }
        }
    }
    println!(
        "{}: LOD switch {:?} GL vs CPU worst {worst:.2e}",
        gl.route(),
        setup.sampling
    );
    assert!(Format::F32 == setup.bakes[0].0.format);
}

fn run(route: Route) {
    if std::env::var("NDFMAP_SKIP_GL").is_ok_and(|v| v == "1") {
        println!("skipped: NDFMAP_SKIP_GL=1");
        return;
    }
    let gl = Gl::new(route).unwrap_or_else(|e| panic!("{e}\n(NDFMAP_SKIP_GL=1 skips GL tests)"));
    run_case(
        &gl,
        &Setup {
            bakes: vec![
                (part_bake(Method::Plain, 0, false, 0, 1), 0, 1),
                (part_bake(Method::Vmf, 2, true, 2, 3), 2, 3),
                (part_bake(Method::Vmf, 3, false, 4, 6), 4, 6),
            ],
            sampling: Sampling::Auto,
        },
    );
    run_case(
        &gl,
        &Setup {
            bakes: vec![
                (part_bake(Method::Plain, 0, false, 0, 2), 0, 2),
                (part_bake(Method::Vmf, 2, true, 3, 6), 3, 6),
            ],
            sampling: Sampling::Anisotropic(4),
        },
    );
}

#[test]
fn lod_switch_shader_matches_the_cpu_twin_through_egl() {
    run(Route::Egl);
}

#[test]
fn lod_switch_shader_matches_the_cpu_twin_through_osmesa() {
    run(Route::OsMesa);
}
