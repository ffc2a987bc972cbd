//! GL = CPU, texel for texel: the product shaders (`ndfmap::glsl`, probe variant) rendered on Mesa
//! through each headless route, against their CPU twin (`ndfmap::sample::shade_at`, which calls
//! `ndfmap::shade`), for every method (SH at l* = 2, 4, 6), lobe counts 1–8, every storage
//! format a method's textures fit, Blinn-Phong and eq 18 everywhere and Lambert, GGX (with its
//! g factor) and a tabulated BRDF on one bake per method, hardware and manual sampling, colour
//! on and off, both vMF diffuse terms and both SH diffuse terms — at the texel centres of every level (integer LOD) and at
//! fractional LODs (trilinear between levels) — and the anisotropic footprint
//! (`ndfmap::sample::anisotropic`) for SH, aligned vMF lobes and Toksvig.
//!
//! Error measure: `|gl − cpu| / (|cpu| + floor)`, with `floor = 1e-3 ·` the BRDF's peak
//! `(s+1)/(2π)` (or `1/(4πσ²)`) for the specular term and 1e-3 for the diffuse term (5e-2 for
//! SH's moments diffuse term, [`diffuse_floor`]): relative
//! where the value matters, absolute in the tails where f32 rounding of `cos^s` dominates.
//! The GLSL evaluates in f32 from the same texel values the CPU evaluates in f64, so the bound is
//! f32 rounding amplified by the lobe's exponent: [`tolerance`].
//!
//! On a GPU (any renderer but Mesa's llvmpipe and softpipe) the hardware-filtered column —
//! hardware trilinear and anisotropic sampling at fractional LODs — is printed but not asserted:
//! GL leaves the filter's arithmetic and the anisotropic footprint to the implementation, and
//! an NVIDIA H100 (driver 580) filters f16 and unorm16 textures in reduced precision (up to
//! 7.7e-2 under Blinn-Phong s = 256, whose `cos^s` amplifies it) and takes another anisotropic
//! footprint (3.4e-2), while its texel centres and manual sampling matched the CPU twin within
//! the same tolerances as llvmpipe (≤ 3.6e-4). Those stay asserted everywhere.
//!
//! Left out: hardware trilinear sampling of unorm8 textures at fractional LODs. llvmpipe filters
//! 8-bit textures in 8-bit fixed point (8-bit weights and results: the filtered value is within
//! 1.6 codes of the exact one, `tests/common` measures it), so Algorithm 2's `θ.yzw/α` of
//! filtered unorm8 values differs from the exact filter's by far more than rounding. Texel
//! centres of unorm8 (exact reads) and manual sampling of unorm8 are compared.

use glam::DVec2;
use ndfmap::bake::{Bake, BakeOptions, Method};
use ndfmap::brdf::{Brdf, Ggx, Tabulated, half_vector};
use ndfmap::eval::default_directions;
use ndfmap::format::Format;
use ndfmap::glsl::{Sampling, ShaderBrdf, ShaderOptions, Stage, source};
use ndfmap::methods::{bake, bake_with};
use ndfmap::sample::{Filtering, anisotropic, shade_at};
use ndfmap::sh::ShDiffuse;
use ndfmap::shade::{ShadeOptions, VmfCosine, VmfDiffuse, VmfSpecular, shade_rgb_with};
use ndfmap_gl::{
    BakeTextures, BrdfBinding, Gl, Program, RenderTarget, Route, draw_fullscreen, glow,
    read_rgba_f32,
};
use std::collections::BTreeMap;
use std::sync::Arc;

/// Largest accepted error (measure above) for a BRDF. Blinn-Phong of exponent `s`: f32
/// rounding of `cos_h` is amplified `s`-fold by `cos_h^s`. Measured on llvmpipe (both routes):
/// ≤ 4.5e-5 at s = 64 (all formats, texel centres and trilinear), ≤ 8e-4 at s = 1024.
/// Torrance–Sparrow (σ = 0.1): ≤ 8e-4, dominated by GLSL's `acos` for the half-angle β, which
/// Mesa evaluates by a polynomial approximation (GLSL specifies no precision for it); the lobe's
/// relative error is `β δβ / (2σ²)`. GGX (α = 0.2, g on): f32 rounding of the widened α and of
/// the Smith term. Tabulated (GGX α = 0.2 tabulated): the table's bilinear lookup at an angle
/// from GLSL's `atan` (Mesa's polynomial approximation again) on the `sqrt(θ/π)` grid, whose
/// cells are narrowest at the peak. Lambert: the SH sums in f32 (≤ 3.2e-5 measured: the
/// diffuse term of an SH bake is a sum of up to 81 terms). Measured: GGX ≤ 3.2e-5, tabulated
/// ≤ 2.5e-4 (Tan 2005, whose lifted means put some lobes' peaks between grid cells).
fn tolerance(brdf: &Brdf) -> f64 {
    match brdf {
        Brdf::BlinnPhong { s } => 3e-5 + 2e-6 * s,
        Brdf::TorranceSparrow { .. } => 1.5e-3,
        Brdf::Lambert => 6e-5,
        Brdf::Ggx(_) => 1e-4,
        Brdf::Tabulated(_) => 1e-3,
    }
}

/// The floor of the diffuse term's error measure: 1e-3, and 5e-2 for SH's moments diffuse
/// term (`ndfmap::sh::diffuse_moments`), whose variance `c_0,0/3 + (2/3)Λ₂Σc_2m Y_2m − mean²`
/// cancels terms of order 1/3 where the light grazes the texel's normals: f32 leaves about 1e-7
/// of it, which the spread's slope (at most `1/√ε` = 100) makes a few 1e-6 of diffuse term
/// where that term is itself near 0 (measured on llvmpipe: 1.3e-6 at a value of 7e-4, f16 SH).
fn diffuse_floor(case: &Case) -> f64 {
    let moments = case.bake.method == Method::Sh
        && ndfmap::sh::lmax_of(&case.bake) >= 2
        && case.sh_diffuse == ShDiffuse::Moments;
    if moments { 5e-2 } else { 1e-3 }
}

struct Case {
    bake: Bake,
    brdf: Brdf,
    sampling: Sampling,
    color: bool,
    diffuse: VmfDiffuse,
    specular: VmfSpecular,
    sh_diffuse: ShDiffuse,
    cosine: VmfCosine,
}

fn label(c: &Case) -> String {
    format!(
        "{} {} {:?}{}{}{}{}{}",
        c.bake.label(),
        c.brdf.model(),
        c.sampling,
        if c.color { " colour" } else { "" },
        if c.diffuse == VmfDiffuse::Algorithm2 {
            " alg2"
        } else {
            ""
        },
        if c.sh_diffuse == ShDiffuse::Series {
            " series"
        } else {
            ""
        },
        match c.specular {
            VmfSpecular::Convolved => " convolved",
            VmfSpecular::Eq20 => " eq20",
            _ => "",
        },
        if c.cosine == VmfCosine::Algorithm2 {
            " cosine-alg2"
        } else {
            ""
        }
    )
}

/// The screen derivatives of uv the anisotropic probe uses at `level` of a `size` map: a
/// footprint about 2^level texels long along a diagonal and 3.4 times narrower across, so
/// 4 probes of LOD ≈ level − 2 (non-integer ratios keep f32 and f64 on the same probe count).
fn aniso_derivatives(level: usize, size: (u32, u32)) -> (DVec2, DVec2) {
    let t = 2f64.powi(level as i32) * 1.3;
    let (w, h) = (size.0 as f64, size.1 as f64);
    let major = DVec2::new(0.8 * t / w, 0.6 * t / h);
    let minor = DVec2::new(-0.6 * t / (3.4 * w), 0.8 * t / (3.4 * h));
    (major, minor)
}

/// Renders `case` at every level (and at fractional LODs, or with an anisotropic footprint)
/// for a few light/view pairs and returns the largest error at texel centres and at
/// fractional LODs (anisotropic: all in the second).
fn measure(gl: &Gl, case: &Case) -> (f64, f64) {
    measure_with(gl, case, case.specular, &|_| {})
}

/// [`measure`] with the shader generated for the vMF rule `shader_specular` (the CPU twin keeps
/// `case.specular`) and `tweak` applied to the program after its uniforms are set.
fn measure_with(
    gl: &Gl,
    case: &Case,
    shader_specular: VmfSpecular,
    tweak: &dyn Fn(&Program),
) -> (f64, f64) {
    let bake = &case.bake;
    let options = ShaderOptions {
        light: Default::default(),
        brdf: ShaderBrdf::of(&case.brdf),
        sampling: case.sampling,
        color: case.color,
        probe: true,
        vmf_diffuse: case.diffuse,
        vmf_cosine: case.cosine,
        vmf_specular: shader_specular,
        sh_diffuse: case.sh_diffuse,
        ..Default::default()
    };
    let vertex = source(bake, Stage::Vertex, &options).unwrap();
    let fragment = source(bake, Stage::Fragment, &options).unwrap();
    let program = Program::new(gl, &vertex, &fragment).unwrap_or_else(|e| panic!("{e}"));
    let textures = BakeTextures::upload(gl, bake, bake.format).unwrap();
    textures.bind(&program);
    let sh_lmax = (bake.method == Method::Sh).then(|| ndfmap::sh::lmax_of(bake));
    let binding = BrdfBinding::default();
    binding
        .apply(
            gl,
            &program,
            &case.brdf,
            options.brdf,
            sh_lmax,
            textures.len() as u32,
        )
        .unwrap();
    tweak(&program);
    let manual = ndfmap::glsl::manual_sampling(&ndfmap::glsl::ShaderSpec::of(bake), &options);
    let aniso = matches!(case.sampling, Sampling::Anisotropic(_));
    let peak = case.brdf.peak().max(1.0);
    let filtering = Filtering {
        manual,
        color: case.color,
        shading: ShadeOptions {
            vmf_diffuse: case.diffuse,
            vmf_cosine: case.cosine,
            vmf_specular: case.specular,
            sh_diffuse: case.sh_diffuse,
        },
        ..Filtering::new(case.brdf.clone())
    };
    let directions = default_directions();
    let floor_d = diffuse_floor(case);
    let (mut worst, mut worst_trilinear) = (0.0f64, 0.0f64);
    let channels = if case.color { 3 } else { 1 };
    for &(l, v) in [directions[0], directions[6], directions[13], directions[22]].iter() {
        let h = half_vector(l, v);
        let floor_s = 1e-3 * peak * case.brdf.g(l, h).max(1.0);
        program.set_vec3("ndf_probe_l", l.as_vec3());
        program.set_vec3("ndf_probe_h", h.as_vec3());
        for level in 0..bake.level_count() {
            let (w, hgt) = bake.sizes[level];
            let target = RenderTarget::new(gl, w, hgt).unwrap();
            program.set_vec2("ndf_probe_size", [w as f32, hgt as f32]);
            let fracs: &[f64] = if aniso { &[0.0] } else { &[0.0, 0.375] };
            for &frac in fracs {
                let lod = level as f64 + frac;
                let (dx, dy) = aniso_derivatives(level, bake.sizes[0]);
                if aniso {
                    program.set_vec2("ndf_probe_dx", dx.as_vec2());
                    program.set_vec2("ndf_probe_dy", dy.as_vec2());
                } else {
                    program.set_f32("ndf_probe_lod", lod as f32);
                }
                for channel in 0..channels {
                    program.set_i32("ndf_probe_channel", channel as i32);
                    draw_fullscreen(&program, &target).unwrap();
                    let pixels = read_rgba_f32(&target).unwrap();
                    for (i, p) in pixels.iter().enumerate() {
                        let (x, y) = (i as u32 % w, i as u32 / w);
                        let uv =
                            DVec2::new((x as f64 + 0.5) / w as f64, (y as f64 + 0.5) / hgt as f64);
                        let cpu = if let Sampling::Anisotropic(n) = case.sampling {
                            let t = anisotropic(bake, uv, dx, dy, n);
                            let sh = &filtering.shading;
                            shade_rgb_with(bake, &t, l, h, &case.brdf, case.color, sh)
                        } else {
                            shade_at(bake, uv, lod, l, h, &filtering)
                        };
                        let e_d = (p[0] as f64 - cpu.diffuse[channel]).abs()
                            / (cpu.diffuse[channel].abs() + floor_d);
                        let e_s = (p[1] as f64 - cpu.specular[channel]).abs()
                            / (cpu.specular[channel].abs() + floor_s);
                        assert!(p[0].is_finite() && p[1].is_finite(), "{}", label(case));
                        let e = e_d.max(e_s);
                        if (frac > 0.0 || aniso) && !manual && bake.format == Format::Unorm8 {
                            continue; // 8-bit fixed-point filtering (module docs)
                        }
                        let slot = if (frac == 0.0 && !aniso) || manual {
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

/// GGX α = 0.2 with its g factor (Smith, Schlick).
fn ggx() -> Brdf {
    Brdf::Ggx(Ggx {
        g: true,
        ..Ggx::new(0.2)
    })
}

/// GGX α = 0.2 tabulated (90 MERL-spaced samples) with a Schlick-like g.
fn tabulated() -> Brdf {
    let f = |t: f64| ndfmap::brdf::ggx(t.cos(), 0.2);
    let g = |t: f64| ndfmap::brdf::schlick(t.cos(), 0.04) * 10.0;
    Brdf::Tabulated(Arc::new(
        Tabulated::sample("ggx0.2", 90, &f, Some(&g)).unwrap(),
    ))
}

/// Every case: methods × lobe counts × formats × BRDFs × sampling × colour, SH at l* = 2 and
/// 6, every BRDF of the library on one bake per method, anisotropic sampling of the bakes
/// that filter linearly, and Algorithm 2's vMF diffuse term.
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
            for brdf in brdfs {
                for sampling in [Sampling::Hardware, Sampling::Manual] {
                    if q.method == Method::Sh && sampling == Sampling::Manual {
                        continue;
                    }
                    out.push(Case {
                        bake: q.clone(),
                        brdf: brdf.clone(),
                        sampling,
                        color,
                        diffuse: VmfDiffuse::default(),
                        specular: VmfSpecular::default(),
                        sh_diffuse: ShDiffuse::default(),
                        cosine: VmfCosine::default(),
                    });
                }
            }
        }
    };
    for method in Method::BASELINES {
        push(&bake(&sample.map, method), false);
    }
    for lmax in [2, 6] {
        let o = BakeOptions {
            lmax,
            ..Default::default()
        };
        push(&bake_with(&sample.map, Method::Sh, &o).unwrap(), false);
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
    // The other BRDFs on one bake per method (f32), in the bake's natural sampling.
    let three = |align| BakeOptions {
        lobes: 3,
        align,
        lmax: 4,
        ..Default::default()
    };
    let mut bakes: Vec<Bake> = Method::BASELINES
        .iter()
        .map(|&m| bake(&sample.map, m))
        .collect();
    for method in [Method::Vmf, Method::Tan2005, Method::Sh] {
        bakes.push(bake_with(&colored, method, &three(None)).unwrap());
    }
    let aligned = bake_with(&sample.map, Method::Vmf, &three(Some(1.0))).unwrap();
    for b in &bakes {
        for brdf in [Brdf::Lambert, ggx(), tabulated()] {
            out.push(Case {
                bake: b.clone(),
                color: b.lobes > 0 && brdf == Brdf::Lambert,
                brdf,
                sampling: Sampling::Auto,
                diffuse: VmfDiffuse::default(),
                specular: VmfSpecular::default(),
                sh_diffuse: ShDiffuse::default(),
                cosine: VmfCosine::default(),
            });
        }
    }
    // Anisotropic sampling: SH, aligned vMF lobes, Toksvig; f32 and f16.
    for b in [&bakes[1], &bakes[6], &aligned] {
        for format in [Format::F32, Format::F16] {
            out.push(Case {
                bake: ndfmap::pack::quantize(b, format).unwrap(),
                brdf: Brdf::BlinnPhong { s: 64.0 },
                sampling: Sampling::Anisotropic(8),
                color: false,
                diffuse: VmfDiffuse::default(),
                specular: VmfSpecular::default(),
                sh_diffuse: ShDiffuse::default(),
                cosine: VmfCosine::default(),
            });
        }
    }
    // eq 12's series as the SH diffuse term (the alternative to the moments), l* = 2 and 4.
    for lmax in [2, 4] {
        let o = BakeOptions {
            lmax,
            ..Default::default()
        };
        let b = bake_with(&sample.map, Method::Sh, &o).unwrap();
        for sh_diffuse in [ShDiffuse::Series, ShDiffuse::Moments] {
            out.push(Case {
                bake: ndfmap::pack::quantize(&b, Format::F16).unwrap(),
                brdf: Brdf::Lambert,
                sampling: Sampling::Hardware,
                color: false,
                diffuse: VmfDiffuse::default(),
                specular: VmfSpecular::default(),
                sh_diffuse,
                cosine: VmfCosine::default(),
            });
        }
    }
    // Algorithm 2's diffuse term (the alternative to the default).
    for b in [&bakes[4], &aligned] {
        for sampling in [Sampling::Hardware, Sampling::Manual] {
            out.push(Case {
                bake: b.clone(),
                brdf: Brdf::BlinnPhong { s: 64.0 },
                sampling,
                color: false,
                diffuse: VmfDiffuse::Algorithm2,
                specular: VmfSpecular::default(),
                sh_diffuse: ShDiffuse::default(),
                cosine: VmfCosine::default(),
            });
        }
    }
    // Algorithm 2's specular cosine at μ (NDF_VMF_COSINE_ALG2, the alternative to the default
    // cosine at the product lobe's centre): the branch-free eq 20 loop (Blinn-Phong) and the
    // general loop (GGX's mixture rule), unaligned and aligned, f32 and f16.
    for b in [&bakes[4], &aligned] {
        for format in [Format::F32, Format::F16] {
            for brdf in [Brdf::BlinnPhong { s: 64.0 }, Brdf::ggx(0.3)] {
                out.push(Case {
                    bake: ndfmap::pack::quantize(b, format).unwrap(),
                    brdf,
                    sampling: Sampling::Manual,
                    color: false,
                    diffuse: VmfDiffuse::default(),
                    specular: VmfSpecular::default(),
                    sh_diffuse: ShDiffuse::default(),
                    cosine: VmfCosine::Algorithm2,
                });
            }
        }
    }
    // The closed-form vMF ⊛ Blinn-Phong lobe as the vMF lobes' specular rule (the opt-in
    // alternative to the default eq 20; NDF_VMF_SPECULAR_CONVOLVED), broad and sharp exponents,
    // f32 and f16.
    for b in [&bakes[4], &aligned] {
        for format in [Format::F32, Format::F16] {
            for s in [64.0, 1024.0] {
                out.push(Case {
                    bake: ndfmap::pack::quantize(b, format).unwrap(),
                    brdf: Brdf::BlinnPhong { s },
                    sampling: Sampling::Manual,
                    color: false,
                    diffuse: VmfDiffuse::default(),
                    specular: VmfSpecular::Convolved,
                    sh_diffuse: ShDiffuse::default(),
                    cosine: VmfCosine::default(),
                });
            }
            // Under GGX the same option selects the peak-matched widening
            // (ndf_vmf_ggx_alpha: the continued fraction for sharp lobes, E1's series for
            // broad ones), sharp and rough.
            for alpha in [0.05, 0.3] {
                out.push(Case {
                    bake: ndfmap::pack::quantize(b, format).unwrap(),
                    brdf: Brdf::ggx(alpha),
                    sampling: Sampling::Manual,
                    color: false,
                    diffuse: VmfDiffuse::default(),
                    specular: VmfSpecular::Convolved,
                    sh_diffuse: ShDiffuse::default(),
                    cosine: VmfCosine::default(),
                });
                // The default GGX rule (the vMF-mixture convolution, ndf_vmf_ggx_mixture) and
                // the single widened lobe it replaced (NDF_VMF_SPECULAR_EQ20).
                for specular in [VmfSpecular::Auto, VmfSpecular::Eq20] {
                    out.push(Case {
                        bake: ndfmap::pack::quantize(b, format).unwrap(),
                        brdf: Brdf::ggx(alpha),
                        sampling: Sampling::Manual,
                        color: false,
                        diffuse: VmfDiffuse::default(),
                        specular,
                        sh_diffuse: ShDiffuse::default(),
                        cosine: VmfCosine::default(),
                    });
                }
            }
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
    report_hardware_anisotropy(&gl);
    let software = gl.is_software();
    let mut table: BTreeMap<String, (f64, f64)> = BTreeMap::new();
    let mut failures = Vec::new();
    for case in cases() {
        let (e, et) = measure(&gl, &case);
        let key = format!(
            "{} {} {}",
            case.bake.method,
            case.bake.format,
            case.brdf.model()
        );
        let entry = table.entry(key).or_default();
        entry.0 = entry.0.max(e);
        entry.1 = entry.1.max(et);
        // A GPU's texture filter is its own (module docs): its trilinear column is shown, not
        // held to the CPU's filter.
        let filtered_by_hardware = !ndfmap::glsl::manual_sampling(
            &ndfmap::glsl::ShaderSpec::of(&case.bake),
            &ShaderOptions {
                sampling: case.sampling,
                ..ShaderOptions::default()
            },
        );
        let checked = if software || !filtered_by_hardware {
            e.max(et)
        } else {
            e
        };
        if checked > tolerance(&case.brdf) {
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

/// Whether the driver offers `GL_EXT_texture_filter_anisotropic` (or GL 4.6's ARB version) and
/// its largest ratio. Mesa's llvmpipe does (16): an elliptical weighted average (Heckbert's EWA,
/// a Gaussian weight table) over the texels of one MIP level — a different footprint from the
/// shaders' `NDF_ANISO` probes, which is why the shaders do their own (module docs of
/// `ndfmap::sample::aniso_probes`). Both are linear filters of the texel values.
fn report_hardware_anisotropy(gl: &Gl) {
    use glow::HasContext;
    let ext = gl.glow().supported_extensions();
    let has = ext.contains("GL_EXT_texture_filter_anisotropic")
        || ext.contains("GL_ARB_texture_filter_anisotropic");
    // SAFETY: the context is current on this thread; a valid enum of the extension.
    let max = if has {
        unsafe {
            gl.glow()
                .get_parameter_f32(glow::MAX_TEXTURE_MAX_ANISOTROPY)
        }
    } else {
        0.0
    };
    println!(
        "{} ({}): texture_filter_anisotropic {}, max ratio {max}",
        gl.route(),
        gl.renderer(),
        if has { "offered" } else { "absent" }
    );
}

/// A host that never sets the GGX mixture's uniform arrays (weights left at GL's 0) gets the
/// single widened lobe of `NDF_VMF_SPECULAR_EQ20` from the default (`Auto`) shader: the GL
/// output against the CPU twin's eq 20 rule, and the same shader with the arrays set must differ
/// from it (so the comparison can fail).
fn unset_mixture_falls_back(route: Route) {
    if std::env::var("NDFMAP_SKIP_GL").is_ok_and(|v| v == "1") {
        println!("skipped: NDFMAP_SKIP_GL=1");
        return;
    }
    let gl = Gl::new(route).unwrap_or_else(|e| panic!("{e}\n(NDFMAP_SKIP_GL=1 skips GL tests)"));
    let sample = ndfmap::procedural::generate(16, 11);
    let options = BakeOptions {
        lobes: 4,
        ..Default::default()
    };
    let b = bake_with(&sample.map, Method::Vmf, &options).unwrap();
    for alpha in [0.05, 0.3] {
        let case = Case {
            bake: b.clone(),
            brdf: Brdf::ggx(alpha),
            sampling: Sampling::Manual,
            color: false,
            diffuse: VmfDiffuse::default(),
            specular: VmfSpecular::Eq20,
            sh_diffuse: ShDiffuse::default(),
            cosine: VmfCosine::default(),
        };
        let zero = [0.0f32; ndfmap::brdf::ggx_mixture::GGX_MIXTURE_LOBES];
        let unset = measure_with(&gl, &case, VmfSpecular::Auto, &|p| {
            p.set_f32_array("ndf_ggx_w", &zero);
            p.set_f32_array("ndf_ggx_eta", &zero);
        });
        let set = measure_with(&gl, &case, VmfSpecular::Auto, &|_| {});
        println!(
            "{route} GGX α = {alpha}: arrays unset {:.2e}, set {:.2e} from eq 20",
            unset.0, set.0
        );
        assert!(unset.0 <= tolerance(&case.brdf), "α = {alpha}: {unset:?}");
        assert!(set.0 > 10.0 * tolerance(&case.brdf), "α = {alpha}: {set:?}");
    }
}

#[test]
fn an_unset_ggx_mixture_falls_back_to_eq20_through_egl() {
    unset_mixture_falls_back(Route::Egl);
}

#[test]
fn shaders_match_the_cpu_twin_through_egl() {
    run(Route::Egl);
}

#[test]
fn shaders_match_the_cpu_twin_through_osmesa() {
    run(Route::OsMesa);
}
