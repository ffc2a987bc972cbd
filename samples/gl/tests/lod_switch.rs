//! GL = CPU for the one shader that switches method by level of detail (issue 18,
//! `ndfmap::glsl::lod_switch_source`): three parts of different methods and samplings (plain
//! L0-1, vMF J = 2 aligned hardware L2-3, vMF J = 3 unaligned manual L4-6), each part's
//! textures holding only its levels, rendered through the probe at every level and at a
//! fractional LOD inside every level (so across each part boundary), against the CPU twin
//! `ndfmap::sample::shade_switch`; and the anisotropic variant (plain L0-2, vMF J = 2 aligned
//! L3-6) against `shade_switch_aniso`; and the three parts lit by the point light and the
//! generated sky (`ShaderLight::PointAndEnvPrefiltered`) against the sum of the two twins per
//! part, blended by `lod_switch_weights`. Each render is also compared with the *wrong* part's
//! CPU shading (the neighbouring part at the same LOD): the test asserts that this differs by
//! far more than the tolerance somewhere on every level, so a shader choosing the wrong part
//! fails.
//!
//! Error measure as `tests/shaders.rs`: `|gl − cpu| / (|cpu| + floor)`, floor 1e-3 (diffuse)
//! and 1e-3 × the BRDF's peak (specular); Blinn-Phong s = 32, f32 textures.

use glam::{DMat3, DVec2, DVec3};
use ndfmap::bake::{Bake, BakeOptions, Method};
use ndfmap::brdf::{Brdf, half_vector};
use ndfmap::environment::Sky;
use ndfmap::envlight::{EnvLight, Route as EnvRoute, shade_in};
use ndfmap::eval::default_directions;
use ndfmap::format::Format;
use ndfmap::glsl::{
    LodPart, Sampling, ShaderBrdf, ShaderLight, ShaderOptions, ShaderSpec, Stage,
    lod_switch_sampler, lod_switch_source, manual_sampling,
};
use ndfmap::methods::bake_with;
use ndfmap::sample::{Filtering, SwitchPart, shade_at, shade_switch, shade_switch_aniso};
use ndfmap::sample::{bilinear, level_weights, lod_switch_weights, trilinear};
use ndfmap::shade::{ShadeOptions, shade_rgb_with};
use ndfmap_gl::glow::HasContext;
use ndfmap_gl::{
    BakeTextures, BrdfBinding, EnvTextures, Gl, Program, RenderTarget, Route, draw_fullscreen,
    glow, read_rgba_f32,
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

struct Setup<'a> {
    bakes: Vec<(Bake, usize, usize)>,
    sampling: Sampling,
    /// Lit by the point light and this environment (`ShaderLight::PointAndEnvPrefiltered`).
    env: Option<(&'a EnvLight, &'a EnvTextures)>,
    /// K_d = 0: `NDF_NO_DIFFUSE` (the probe's diffuse must be exactly 0, the specular the
    /// twin's).
    no_diffuse: bool,
    /// The environment's extracted lights added per part (`NDF_ENV_LIGHTS`, the planner's
    /// shaders under a sun); the twin's `shade_in` adds them (`envlight::add_lights`).
    env_lights: bool,
}

/// The point light's plus the prefiltered environment's shading of one part at its local
/// `lod`, filtered like the part's shader (trilinear parameters, or each texel shaded and
/// blended): the CPU twin of one part of the both-lights probe (as `tests/env.rs`).
#[allow(clippy::too_many_arguments)]
fn both_part(
    light: &EnvLight,
    bake: &Bake,
    manual: bool,
    uv: DVec2,
    lod: f64,
    (l, h, v): (DVec3, DVec3, DVec3),
    brdf: &Brdf,
) -> (f64, f64) {
    let one = |t: &[[f32; 4]]| {
        let p = shade_rgb_with(bake, t, l, h, brdf, false, &ShadeOptions::default());
        let e = shade_in(
            light,
            DMat3::IDENTITY,
            bake,
            t,
            v,
            brdf,
            EnvRoute::Prefiltered,
        );
        (p.diffuse[0] + e.diffuse[0], p.specular[0] + e.specular[0])
    };
    if !manual {
        return one(&trilinear(bake, uv, lod));
    }
    let mut t = vec![[0.0f32; 4]; bake.textures.len()];
    let (mut d, mut s) = (0.0, 0.0);
    for (level, lw) in level_weights(lod, bake.level_count()) {
        for (index, bw) in bilinear(bake, level, uv) {
            bake.texel_into(level, index, &mut t);
            let f = one(&t);
            d += lw * bw * f.0;
            s += lw * bw * f.1;
        }
    }
    (d, s)
}

fn run_case(gl: &Gl, setup: &Setup) {
    let brdf = Brdf::BlinnPhong { s: 32.0 };
    let options = ShaderOptions {
        brdf: ShaderBrdf::of(&brdf),
        sampling: setup.sampling,
        probe: true,
        light: if setup.env.is_some() {
            ShaderLight::PointAndEnvPrefiltered
        } else {
            ShaderLight::Point
        },
        no_diffuse: setup.no_diffuse,
        env_lights: setup.env_lights,
        ..Default::default()
    };
    // The environment's route is within 5e-3 of its twin (tests/env.rs), the point light's 2e-4.
    let tolerance = if setup.env.is_some() { 5e-3 } else { TOLERANCE };
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
    if let Some((_, env)) = setup.env {
        env.bind(&program, unit + 1, &brdf, EnvRoute::Prefiltered);
    }
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
    // The zenith view included: a flat texel seen head on looks the environment up exactly at
    // its pole, where both sides take the azimuth as 0 (`ndf_env_azimuth`, `Geometry::azimuth`).
    let pairs = if setup.env.is_some() {
        [directions[0], directions[10]]
    } else {
        [directions[0], directions[13]]
    };
    for &(l, v) in pairs.iter() {
        let h = half_vector(l, v);
        program.set_vec3("ndf_probe_l", l.as_vec3());
        program.set_vec3("ndf_probe_h", h.as_vec3());
        program.set_vec3("ndf_probe_v", v.as_vec3());
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
                    let cpu = match (aniso, setup.env) {
                        (Some(n), _) => {
                            let c = shade_switch_aniso(&twins, map_size, uv, (dx, dy), n, l, h);
                            (c.diffuse.x, c.specular.x)
                        }
                        (None, None) => {
                            let c = shade_switch(&twins, uv, lod, l, h);
                            (c.diffuse.x, c.specular.x)
                        }
                        (None, Some((light, _))) => {
                            let ranges: Vec<(usize, usize)> =
                                twins.iter().map(|t| (t.first, t.last)).collect();
                            let (mut d, mut s) = (0.0, 0.0);
                            for (k, local, w) in lod_switch_weights(&ranges, lod) {
                                let t = &twins[k];
                                let (pd, ps) = both_part(
                                    light,
                                    t.bake,
                                    t.filtering.manual,
                                    uv,
                                    local,
                                    (l, h, v),
                                    &brdf,
                                );
                                d += w * pd;
                                s += w * ps;
                            }
                            (d, s)
                        }
                    };
                    // K_d = 0: no diffuse term in the shader, the twin's specular alone.
                    let cpu = if setup.no_diffuse {
                        assert_eq!(p[0], 0.0, "NDF_NO_DIFFUSE: the probe's diffuse");
                        (0.0, cpu.1)
                    } else {
                        cpu
                    };
                    let err = |gl: f32, cpu: f64, floor: f64| {
                        (gl as f64 - cpu).abs() / (cpu.abs() + floor)
                    };
                    assert!(p[0].is_finite() && p[1].is_finite());
                    let e = err(p[0], cpu.0, 1e-3).max(err(p[1], cpu.1, 1e-3 * peak));
                    assert!(
                        e <= tolerance,
                        "level {level} + {frac}, texel ({x}, {y}): GL ({}, {}) against the switch's \
                         CPU twin ({}, {}): error {e:.2e} (point light alone {:?})",
                        p[0],
                        p[1],
                        cpu.0,
                        cpu.1,
                        shade_switch(&twins, uv, lod, l, h)
                    );
                    worst = worst.max(e);
                    // The wrong part at the same LOD (its local level clamped to its levels).
                    let w = &twins[wrong];
                    let local = (lod - w.first as f64).clamp(0.0, (w.last - w.first) as f64);
                    let mut bad = match setup.env {
                        Some((light, _)) => both_part(
                            light,
                            w.bake,
                            w.filtering.manual,
                            uv,
                            local,
                            (l, h, v),
                            &brdf,
                        ),
                        None => {
                            let b = shade_at(w.bake, uv, local, l, h, &w.filtering);
                            (b.diffuse.x, b.specular.x)
                        }
                    };
                    if setup.no_diffuse {
                        bad.0 = 0.0;
                    }
                    wrong_worst =
                        wrong_worst
                            .max(err(p[0], bad.0, 1e-3))
                            .max(err(p[1], bad.1, 1e-3 * peak));
                }
                assert!(
                    wrong_worst > 10.0 * tolerance,
                    "level {level} + {frac}: part {wrong} would pass too ({wrong_worst:.2e}): \
                     the test cannot tell the parts apart"
                );
            }
        }
    }
    println!(
        "{}: LOD switch {:?}{}{} GL vs CPU worst {worst:.2e}",
        gl.route(),
        setup.sampling,
        match (setup.env.is_some(), setup.env_lights) {
            (true, true) => " + environment with its extracted lights",
            (true, false) => " + environment",
            _ => "",
        },
        if setup.no_diffuse { ", K_d = 0" } else { "" },
    );
    assert!(Format::F32 == setup.bakes[0].0.format);
}

fn run(route: Route) {
    if std::env::var("NDFMAP_SKIP_GL").is_ok_and(|v| v == "1") {
        println!("skipped: NDFMAP_SKIP_GL=1");
        return;
    }
    let gl = Gl::new(route).unwrap_or_else(|e| panic!("{e}\n(NDFMAP_SKIP_GL=1 skips GL tests)"));
    // Plain, vMF J = 2 aligned (hardware) and vMF J = 3 unaligned (manual) over levels 0-6.
    let three_parts = || {
        vec![
            (part_bake(Method::Plain, 0, false, 0, 1), 0, 1),
            (part_bake(Method::Vmf, 2, true, 2, 3), 2, 3),
            (part_bake(Method::Vmf, 3, false, 4, 6), 4, 6),
        ]
    };
    run_case(
        &gl,
        &Setup {
            bakes: three_parts(),
            sampling: Sampling::Auto,
            env: None,
            no_diffuse: false,
            env_lights: false,
        },
    );
    // Lit by the point light and the generated 64 x 32 sky (sun included), as tests/env.rs.
    let sky = Sky {
        width: 64,
        ..Sky::default()
    }
    .render()
    .unwrap();
    let light = EnvLight::new(&sky);
    let env = EnvTextures::upload(&gl, &light).unwrap();
    run_case(
        &gl,
        &Setup {
            bakes: three_parts(),
            sampling: Sampling::Auto,
            env: Some((&light, &env)),
            no_diffuse: false,
            env_lights: false,
        },
    );
    // The same sky with its sun extracted (the default: one light) and the switch adding it in
    // every part (`NDF_ENV_LIGHTS`, as the planner's shaders under a sun).
    let lit = EnvLight::with_lights(&sky, &ndfmap::environment::lights::LightOptions::up_to(4));
    assert_eq!(lit.lights().len(), 1, "the sun");
    let lit_env = EnvTextures::upload(&gl, &lit).unwrap();
    run_case(
        &gl,
        &Setup {
            bakes: three_parts(),
            sampling: Sampling::Auto,
            env: Some((&lit, &lit_env)),
            no_diffuse: false,
            env_lights: true,
        },
    );
    // K_d = 0 (NDF_NO_DIFFUSE): the point light and the environment, specular only.
    run_case(
        &gl,
        &Setup {
            bakes: three_parts(),
            sampling: Sampling::Auto,
            env: Some((&light, &env)),
            no_diffuse: true,
            env_lights: false,
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
            env: None,
            no_diffuse: false,
            env_lights: false,
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
