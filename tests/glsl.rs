//! Every specialization of the shipped shaders compiles as GLSL 3.30 core: each method, lobe
//! counts 1, 3 and 8 (SH: l* = 0, 2, 8), every BRDF of the library (Blinn-Phong, eq 18,
//! Lambert, GGX with and without its g factor, tabulated), colour on and off, hardware, manual
//! and anisotropic sampling, both vMF diffuse terms, mesh and probe variants, float and
//! unsigned-normalized formats, wrap and clamp, and the environment-lit specializations of
//! issue 16 (`NDF_LIGHT_ENV_PREFILTERED`, `NDF_LIGHT_ENV_SH`) — checked offline by Khronos' reference compiler
//! (`glslangValidator`, Debian `glslang-tools`, installed by scripts/test).
//! The GL tests in `samples/gl` then run them on Mesa and compare with the CPU twin.

use ndfmap::bake::Method;
use ndfmap::format::Format;
use ndfmap::glsl::{
    LodPart, Sampling, ShaderBrdf, ShaderLight, ShaderOptions, ShaderSpec, Stage,
    lod_switch_source, source_for,
};
use ndfmap::ingest::Addressing;
use ndfmap::methods::texture_ranges;
use ndfmap::sh::ShDiffuse;
use ndfmap::shade::{VmfCosine, VmfDiffuse};
use std::process::Command;

fn validator() -> Option<&'static str> {
    let ok = Command::new("glslangValidator")
        .arg("--version")
        .output()
        .is_ok();
    if ok {
        return Some("glslangValidator");
    }
    if std::env::var_os("NDFMAP_SKIP_GL").is_some() {
        eprintln!("skipped: glslangValidator not found and NDFMAP_SKIP_GL is set");
        return None;
    }
    panic!("glslangValidator not found: install Debian's glslang-tools (scripts/test does)");
}

/// All the specializations, named.
fn variants() -> Vec<(String, ShaderSpec, ShaderOptions)> {
    let mut out = Vec::new();
    for method in Method::ALL {
        let mixture = matches!(method, Method::Vmf | Method::Tan2005);
        let sh = method == Method::Sh;
        let lobe_counts: &[usize] = if mixture {
            &[1, 3, 8]
        } else if sh {
            &[0, 2, 8]
        } else {
            &[0]
        };
        for &lobes in lobe_counts {
            for color in [false, true] {
                if color && !mixture {
                    continue;
                }
                for brdf in [
                    ShaderBrdf::BlinnPhong,
                    ShaderBrdf::TorranceSparrow,
                    ShaderBrdf::Lambert,
                    ShaderBrdf::Ggx { g: false },
                    ShaderBrdf::Ggx { g: true },
                    ShaderBrdf::Tabulated,
                ] {
                    let classic =
                        matches!(brdf, ShaderBrdf::BlinnPhong | ShaderBrdf::TorranceSparrow);
                    for sampling in [
                        Sampling::Hardware,
                        Sampling::Manual,
                        Sampling::Anisotropic(8),
                    ] {
                        // SH is never sampled manually; the new BRDFs and anisotropic sampling
                        // once per method and size (probe variant, f32).
                        if (sh && sampling == Sampling::Manual)
                            || (matches!(sampling, Sampling::Anisotropic(_))
                                && brdf != ShaderBrdf::BlinnPhong)
                        {
                            continue;
                        }
                        for probe in [false, true] {
                            if (!classic || matches!(sampling, Sampling::Anisotropic(_))) && !probe
                            {
                                continue;
                            }
                            // Formats change the decode lines and NDF_R_MAX only: vary them with
                            // the addressing on one BRDF to keep the count down.
                            let formats: &[Format] = if brdf == ShaderBrdf::BlinnPhong {
                                &[Format::F32, Format::Unorm8]
                            } else if classic {
                                &[Format::F16]
                            } else {
                                &[Format::F32]
                            };
                            for &format in formats {
                                let clamp = format == Format::Unorm8;
                                let spec = ShaderSpec {
                                    method,
                                    lobes,
                                    ranges: texture_ranges(method, lobes, color),
                                    format,
                                    aligned: false,
                                    addressing: if clamp {
                                        Addressing::Clamp
                                    } else {
                                        Addressing::Wrap
                                    },
                                    lmax: lobes,
                                    // Biased as block-compressed textures are, with f16.
                                    biased: format == Format::F16 && lobes == 3,
                                };
                                let opts = ShaderOptions {
                                    light: ShaderLight::Point,
                                    brdf,
                                    sampling,
                                    color,
                                    probe,
                                    // Algorithm 2's diffuse term on every other vMF variant.
                                    vmf_diffuse: if lobes == 3 && probe {
                                        VmfDiffuse::Algorithm2
                                    } else {
                                        VmfDiffuse::MeanVector
                                    },
                                    // Algorithm 2's specular cosine (at μ) on others.
                                    vmf_cosine: if lobes == 2 {
                                        VmfCosine::Algorithm2
                                    } else {
                                        VmfCosine::Product
                                    },
                                    // eq 12's series as the SH diffuse term at l* = 2.
                                    sh_diffuse: if lobes == 2 && probe {
                                        ShDiffuse::Series
                                    } else {
                                        ShDiffuse::Moments
                                    },
                                    ..Default::default()
                                };
                                let name = format!(
                                    "{method}{lobes}-c{}-{brdf:?}-{sampling:?}-p{}-{format}",
                                    color as u8, probe as u8
                                );
                                out.push((name, spec, opts));
                            }
                        }
                    }
                }
            }
        }
    }
    // Issue 16: the environment-lit specializations (both routes) of plain, Toksvig, LEAN,
    // Olano–North, vMF (J = 1, 3, 8) and Tan 2005 (J = 2, 4), Lambert, Blinn-Phong and GGX with
    // and without g, every sampling, mesh and probe, f32 and unorm8 (wrap and clamp).
    for light in [ShaderLight::EnvPrefiltered, ShaderLight::EnvSh] {
        for (method, lobes) in [
            (Method::Plain, 0),
            (Method::Toksvig, 0),
            (Method::Lean, 0),
            (Method::Olano, 0),
            (Method::Vmf, 1),
            (Method::Vmf, 3),
            (Method::Vmf, 8),
            (Method::Tan2005, 2),
            (Method::Tan2005, 4),
        ] {
            for brdf in [
                ShaderBrdf::BlinnPhong,
                ShaderBrdf::Lambert,
                ShaderBrdf::Ggx { g: false },
                ShaderBrdf::Ggx { g: true },
            ] {
                for sampling in [
                    Sampling::Hardware,
                    Sampling::Manual,
                    Sampling::Anisotropic(8),
                ] {
                    for probe in [false, true] {
                        let format = if lobes == 3 && method != Method::Lean {
                            Format::Unorm8
                        } else {
                            Format::F32
                        };
                        let spec = ShaderSpec {
                            method,
                            lobes,
                            ranges: texture_ranges(method, lobes, false),
                            format,
                            aligned: false,
                            addressing: if probe {
                                Addressing::Clamp
                            } else {
                                Addressing::Wrap
                            },
                            lmax: 0,
                            biased: false,
                        };
                        let opts = ShaderOptions {
                            light,
                            brdf,
                            sampling,
                            probe,
                            ..Default::default()
                        };
                        let name = format!(
                            "env-{light:?}-{method}{lobes}-{brdf:?}-{sampling:?}-p{}-{format}",
                            probe as u8
                        );
                        out.push((name, spec, opts));
                    }
                }
            }
        }
    }
    // Eq 22 under the environment: vMF and Tan 2005 bakes with colour textures (NDF_COLOR)
    // lit by either route and by the point light + environment shader.
    for light in [
        ShaderLight::EnvPrefiltered,
        ShaderLight::EnvSh,
        ShaderLight::PointAndEnvPrefiltered,
    ] {
        for (method, lobes) in [
            (Method::Vmf, 3usize),
            (Method::Vmf, 8),
            (Method::Tan2005, 3),
        ] {
            for brdf in [
                ShaderBrdf::BlinnPhong,
                ShaderBrdf::Lambert,
                ShaderBrdf::Ggx { g: true },
            ] {
                for sampling in [Sampling::Hardware, Sampling::Manual] {
                    for probe in [false, true] {
                        let spec = ShaderSpec {
                            method,
                            lobes,
                            ranges: texture_ranges(method, lobes, true),
                            format: Format::F16,
                            aligned: sampling == Sampling::Hardware,
                            addressing: Addressing::Wrap,
                            lmax: 0,
                            biased: false,
                        };
                        let opts = ShaderOptions {
                            light,
                            brdf,
                            sampling,
                            probe,
                            color: true,
                            ..Default::default()
                        };
                        let name = format!(
                            "env-colour-{light:?}-{method}{lobes}-{brdf:?}-{sampling:?}-p{}",
                            probe as u8
                        );
                        out.push((name, spec, opts));
                    }
                }
            }
        }
    }
    // SH bakes under the SH route (per-fragment rotation into the tangent frame): l* = 0, 1, 2,
    // 4, 8, 10, hardware and anisotropic sampling, mesh and probe.
    for lmax in [0usize, 1, 2, 4, 8, 10] {
        for brdf in [
            ShaderBrdf::BlinnPhong,
            ShaderBrdf::Lambert,
            ShaderBrdf::Ggx { g: true },
        ] {
            for sampling in [Sampling::Hardware, Sampling::Anisotropic(4)] {
                for probe in [false, true] {
                    let spec = ShaderSpec {
                        method: Method::Sh,
                        lobes: 0,
                        ranges: texture_ranges(Method::Sh, lmax, false),
                        format: Format::F32,
                        aligned: false,
                        addressing: Addressing::Wrap,
                        lmax,
                        biased: false,
                    };
                    let opts = ShaderOptions {
                        light: ShaderLight::EnvSh,
                        brdf,
                        sampling,
                        probe,
                        ..Default::default()
                    };
                    let name = format!("env-sh{lmax}-{brdf:?}-{sampling:?}-p{}", probe as u8);
                    out.push((name, spec, opts));
                }
            }
        }
    }
    // The extracted lights' loop (NDF_ENV_LIGHTS): one variant per method, lobe count, lighting,
    // BRDF, probe flag and colour of the environment-lit ones above.
    let mut seen = Vec::new();
    let mut lit = Vec::new();
    for (name, spec, opts) in &out {
        let key = (
            spec.method,
            spec.lobes,
            opts.light,
            opts.brdf,
            opts.probe,
            opts.color,
        );
        if opts.light.is_env() && !seen.contains(&key) {
            seen.push(key);
            let opts = ShaderOptions {
                env_lights: true,
                ..*opts
            };
            lit.push((format!("{name}-lights"), spec.clone(), opts));
        }
    }
    out.extend(lit);
    out
}

#[test]
fn every_specialization_compiles_as_glsl_330_core() {
    let Some(tool) = validator() else { return };
    let dir = tempfile::tempdir().unwrap();
    let mut files = Vec::new();
    // K_d = 0 (NDF_NO_DIFFUSE; the method files guard their diffuse lines with #ifndef
    // NDF_NO_DIFFUSE): one variant per method, lighting, probe flag, specular BRDF and colour
    // (every variant once compiled the same, 92 s: too slow to keep).
    let mut seen = Vec::new();
    let mut without = Vec::new();
    for (name, spec, opts) in variants() {
        let key = (spec.method, opts.light, opts.probe, opts.brdf, opts.color);
        if opts.brdf != ShaderBrdf::Lambert && !seen.contains(&key) {
            seen.push(key);
            let opts = ShaderOptions {
                no_diffuse: true,
                ..opts
            };
            without.push((format!("{name}-nokd"), spec, opts));
        }
    }
    for (name, spec, opts) in variants().into_iter().chain(without) {
        let src = source_for(&spec, Stage::Fragment, &opts).unwrap();
        // GLSL 3.30's character set is ASCII (non-ASCII even in comments trips some drivers).
        assert!(src.is_ascii(), "{name} has non-ASCII characters");
        let path = dir.path().join(format!("{name}.frag"));
        std::fs::write(&path, src).unwrap();
        files.push(path);
    }
    for probe in [false, true] {
        let spec = ShaderSpec {
            method: Method::Vmf,
            lobes: 1,
            ranges: texture_ranges(Method::Vmf, 1, false),
            format: Format::F32,
            aligned: true,
            addressing: Addressing::Wrap,
            lmax: 0,
            biased: false,
        };
        let opts = ShaderOptions {
            probe,
            ..Default::default()
        };
        let path = dir.path().join(format!("probe{}.vert", probe as u8));
        std::fs::write(&path, source_for(&spec, Stage::Vertex, &opts).unwrap()).unwrap();
        files.push(path);
    }
    // The LOD-switching shaders of issue 18 (glsl::lod_switch_source): every method in one
    // shader under the point light (each BRDF family, mesh and probe, wrap and clamp), the
    // environment-lit methods under both lights and the prefiltered environment, and the
    // anisotropic switch.
    for (name, spec, opts) in lod_switch_variants() {
        let src = lod_switch_source(&spec.0, spec.1, Stage::Fragment, &opts).unwrap();
        assert!(src.is_ascii(), "{name} has non-ASCII characters");
        let path = dir.path().join(format!("{name}.frag"));
        std::fs::write(&path, src).unwrap();
        files.push(path);
    }
    let mut failures = Vec::new();
    // One validator run per shader (it stops at the first file's errors otherwise), in
    // batches of threads to keep the test short.
    let results: Vec<_> = std::thread::scope(|scope| {
        let handles: Vec<_> = files
            .chunks(files.len().div_ceil(4))
            .map(|chunk| {
                scope.spawn(move || {
                    chunk
                        .iter()
                        .map(|f| (f.clone(), Command::new(tool).arg(f).output().unwrap()))
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().unwrap())
            .collect()
    });
    for (file, output) in &results {
        if !output.status.success() {
            failures.push(format!(
                "{}:\n{}",
                file.file_name().unwrap().to_string_lossy(),
                String::from_utf8_lossy(&output.stdout)
            ));
        }
    }
    assert!(
        failures.is_empty(),
        "{} of {} shaders failed to compile:\n{}",
        failures.len(),
        results.len(),
        failures.join("\n")
    );
    assert!(results.len() > 100, "{} variants", results.len());
}

/// LOD-switching shaders: (name, (parts, map size), options).
#[allow(clippy::type_complexity)]
fn lod_switch_variants() -> Vec<(String, (Vec<LodPart>, (u32, u32)), ShaderOptions)> {
    let spec = |method: Method, n: usize, format: Format, aligned: bool, addressing| {
        let (lobes, lmax) = match method {
            Method::Vmf | Method::Tan2005 => (n, 0),
            Method::Sh => (0, n),
            _ => (0, 0),
        };
        ShaderSpec {
            method,
            lobes,
            ranges: texture_ranges(method, n, false),
            format,
            aligned,
            addressing,
            lmax,
            biased: false,
        }
    };
    let chain = |specs: Vec<ShaderSpec>, o: ShaderOptions| -> Vec<LodPart> {
        specs
            .into_iter()
            .enumerate()
            .map(|(k, spec)| LodPart {
                spec,
                options: o,
                first: k,
                last: k,
            })
            .collect()
    };
    let mut out = Vec::new();
    for addressing in [Addressing::Wrap, Addressing::Clamp] {
        let every = |a| {
            vec![
                spec(Method::Plain, 0, Format::Unorm8, false, a),
                spec(Method::Toksvig, 0, Format::F16, false, a),
                spec(Method::Lean, 0, Format::F32, false, a),
                spec(Method::Olano, 0, Format::F32, false, a),
                spec(Method::Sh, 2, Format::F16, false, a),
                spec(Method::Tan2005, 2, Format::F32, true, a),
                spec(Method::Vmf, 3, Format::Unorm16, true, a),
                spec(Method::Vmf, 8, Format::F32, false, a),
            ]
        };
        for brdf in [
            ShaderBrdf::BlinnPhong,
            ShaderBrdf::TorranceSparrow,
            ShaderBrdf::Lambert,
            ShaderBrdf::Ggx { g: true },
            ShaderBrdf::Tabulated,
        ] {
            for probe in [false, true] {
                let o = ShaderOptions {
                    brdf,
                    probe,
                    ..Default::default()
                };
                out.push((
                    format!("switch_{addressing:?}_{brdf:?}_probe{}", probe as u8)
                        .replace([' ', '{', '}', ':'], ""),
                    (chain(every(addressing), o), (1000, 600)),
                    o,
                ));
            }
        }
        let env = |a| {
            vec![
                spec(Method::Plain, 0, Format::Unorm8, false, a),
                spec(Method::Toksvig, 0, Format::F16, false, a),
                spec(Method::Lean, 0, Format::F32, false, a),
                spec(Method::Vmf, 3, Format::Unorm16, true, a),
                spec(Method::Vmf, 2, Format::F32, false, a),
                spec(Method::Olano, 0, Format::F32, false, a),
                spec(Method::Tan2005, 2, Format::F32, true, a),
            ]
        };
        for light in [
            ShaderLight::EnvPrefiltered,
            ShaderLight::PointAndEnvPrefiltered,
        ] {
            for brdf in [ShaderBrdf::BlinnPhong, ShaderBrdf::Ggx { g: true }] {
                for probe in [false, true] {
                    // With the extracted lights (the planner's default) and without.
                    for env_lights in [false, true] {
                        let o = ShaderOptions {
                            brdf,
                            probe,
                            light,
                            env_lights,
                            ..Default::default()
                        };
                        out.push((
                            format!(
                                "switch_{addressing:?}_{light:?}_{brdf:?}_probe{}_lights{}",
                                probe as u8, env_lights as u8
                            )
                            .replace([' ', '{', '}', ':'], ""),
                            (chain(env(addressing), o), (256, 256)),
                            o,
                        ));
                    }
                }
            }
        }
        // The opt-in convolved vMF rule in a switch: its helpers come before every part.
        let o = ShaderOptions {
            vmf_specular: ndfmap::shade::VmfSpecular::Convolved,
            ..Default::default()
        };
        let vmfs = vec![
            spec(Method::Plain, 0, Format::Unorm8, false, addressing),
            spec(Method::Vmf, 3, Format::Unorm16, true, addressing),
            spec(Method::Vmf, 8, Format::F32, false, addressing),
        ];
        out.push((
            format!("switch_{addressing:?}_vmf_convolved"),
            (chain(vmfs.clone(), o), (1000, 600)),
            o,
        ));
        // Under GGX the default vMF rule is the mixture convolution; eq20 keeps the single
        // widened lobe (NDF_VMF_SPECULAR_EQ20).
        let o = ShaderOptions {
            brdf: ShaderBrdf::Ggx { g: true },
            vmf_specular: ndfmap::shade::VmfSpecular::Eq20,
            ..Default::default()
        };
        out.push((
            format!("switch_{addressing:?}_vmf_ggx_eq20"),
            (chain(vmfs, o), (1000, 600)),
            o,
        ));
        let o = ShaderOptions {
            sampling: Sampling::Anisotropic(8),
            ..Default::default()
        };
        let aniso = vec![
            spec(Method::Plain, 0, Format::F32, false, addressing),
            spec(Method::Sh, 3, Format::F32, false, addressing),
            spec(Method::Vmf, 4, Format::F32, true, addressing),
        ];
        out.push((
            format!("switch_{addressing:?}_aniso"),
            (chain(aniso, o), (512, 512)),
            o,
        ));
    }
    out
}
