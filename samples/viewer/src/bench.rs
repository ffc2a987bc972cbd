//! `--bench`: the frame time of every method's shader (by default at 1280 × 720) on the standard
//! far and grazing views (`Scene::standard`), as a Markdown table of median milliseconds and the
//! ratio to the plain normal-mapping shader of the same view and format; with `--bench-json`
//! also as JSON (`ndfmap::report::frame::FrameTimes`, what `ndfmap report` reads).
//!
//! Every shader is drawn `frames` times per view after two warm-up draws (the first compiles the
//! shader on llvmpipe); each draw is timed between two `glFinish` calls ([`Clock::Wall`]) or by
//! a `GL_TIME_ELAPSED` query ([`Clock::Gpu`], for a GPU). The draws go round robin over all
//! shaders, so that a change in the machine's load lands on every shader alike.

use crate::headless::context;
use crate::methods::MethodSpec;
use ndfmap::bake::Method;
use ndfmap::format::Format;
use ndfmap::glsl::{ShaderOptions, ShaderSpec, manual_sampling};
use ndfmap::methods::bake_with;
use ndfmap::report::frame::{BenchView, FrameCell, FrameTimes, ShaderTimes};
use ndfmap::shade::{VmfCosine, VmfSpecular};
use ndfmap_gl::glam::Mat4;
use ndfmap_gl::{BakeRenderer, Camera, Clock, RenderTarget, Scene, read_rgba_f32};
use std::path::PathBuf;
use std::time::Instant;

const WARM_UP: usize = 2;

/// `--bench-clock`: how each draw is timed (`wall` or `gpu`, [`Clock`]).
pub fn parse_clock(s: &str) -> Result<Clock, String> {
    match s {
        "wall" => Ok(Clock::Wall),
        "gpu" => Ok(Clock::Gpu),
        _ => Err(format!("'{s}' (expected one of: wall, gpu)")),
    }
}

/// What `--bench` measures and where it writes.
#[derive(Debug, Clone)]
pub struct BenchOptions {
    /// Timed frames per shader, view and format.
    pub frames: u32,
    /// Alignment strength C of the aligned mixtures (`None`: each method's usual C,
    /// [`MethodSpec::bake_options`]).
    pub align: Option<f64>,
    /// Side of the procedural sample the shaders are baked from.
    pub sample_size: u32,
    /// Framebuffer width and height.
    pub size: (u32, u32),
    /// The shaders (empty: [`all_specs`]); plain is put first when absent, as the ratios' base.
    pub specs: Vec<MethodSpec>,
    /// Texture formats (a method that refuses one, as LEAN refuses unorm8, has no cell there).
    pub formats: Vec<Format>,
    /// Also write the times as JSON here.
    pub json: Option<PathBuf>,
    /// How each draw is timed.
    pub clock: Clock,
    /// The options of every shader drawn (the vMF rules; light, BRDF and sampling are the
    /// bench's own).
    pub shader: ShaderOptions,
}

/// `--vmf-specular`: the GPU's rules (`exact` is CPU only).
pub fn parse_vmf_specular(s: &str) -> Result<VmfSpecular, String> {
    match s {
        "auto" => Ok(VmfSpecular::Auto),
        "eq20" => Ok(VmfSpecular::Eq20),
        "convolved" => Ok(VmfSpecular::Convolved),
        _ => Err(format!("'{s}' (expected one of: auto, eq20, convolved)")),
    }
}

/// `--vmf-cosine`.
pub fn parse_vmf_cosine(s: &str) -> Result<VmfCosine, String> {
    match s {
        "product" => Ok(VmfCosine::Product),
        "algorithm2" => Ok(VmfCosine::Algorithm2),
        _ => Err(format!("'{s}' (expected one of: product, algorithm2)")),
    }
}

/// The shaders timed by default: the baselines, Tan 2005 J = 4 (unaligned and aligned), vMF
/// J = 1 … 8 aligned (hardware sampling) and unaligned (manual).
pub fn all_specs() -> Vec<MethodSpec> {
    let mut out: Vec<MethodSpec> = Method::BASELINES
        .into_iter()
        .map(MethodSpec::baseline)
        .collect();
    out.push(MethodSpec::mixture(Method::Tan2005, 4, false));
    out.push(MethodSpec::mixture(Method::Tan2005, 4, true));
    for aligned in [true, false] {
        for j in 1..=8 {
            out.push(MethodSpec::mixture(Method::Vmf, j, aligned));
        }
    }
    out
}

/// Milliseconds to three significant digits at most (a GPU's draws take microseconds).
fn fmt_ms(ms: f64) -> String {
    match ms {
        m if m >= 10.0 => format!("{m:.1}"),
        m if m >= 1.0 => format!("{m:.2}"),
        m => format!("{m:.3}"),
    }
}

/// The shaders of `options`, plain first.
fn specs(options: &BenchOptions) -> Vec<MethodSpec> {
    let mut specs = if options.specs.is_empty() {
        all_specs()
    } else {
        options.specs.clone()
    };
    let plain = MethodSpec::baseline(Method::Plain);
    specs.retain(|s| *s != plain);
    specs.insert(0, plain);
    let mut seen = std::collections::HashSet::new();
    specs.retain(|s| seen.insert(*s));
    specs
}

/// Runs the benchmark and prints the Markdown report (and writes the JSON when asked).
pub fn run(options: &BenchOptions) -> Result<(), String> {
    let (width, height) = options.size;
    let frames = options.frames.max(1);
    let load_start = ndfmap::usage::load_average();
    let gl = context()?;
    let map = ndfmap::procedural::generate(options.sample_size, 1).map;
    let formats = options.formats.clone();
    if formats.is_empty() {
        return Err("--bench-formats: give at least one format".into());
    }
    let views: Vec<(Scene, Camera)> = Scene::standard()
        .into_iter()
        .filter(|s| s.name == "plane-far" || s.name == "plane-grazing")
        .map(|s| {
            let camera = Camera {
                aspect: width as f32 / height as f32,
                ..s.camera
            };
            (s, camera)
        })
        .collect();

    // rows[i] = (spec, sampling, renderer per format: None where the format is refused)
    let mut rows = Vec::new();
    let bake_start = Instant::now();
    for spec in specs(options) {
        let bake_options = spec.bake_options(options.align);
        let b = bake_with(&map, spec.method, &bake_options).map_err(|e| e.to_string())?;
        let manual = manual_sampling(&ShaderSpec::of(&b), &options.shader);
        let mut renderers = Vec::new();
        for &format in &formats {
            let Ok(q) = ndfmap::pack::quantize(&b, format) else {
                renderers.push(None);
                continue;
            };
            let r = BakeRenderer::new(&gl, &q, &options.shader)
                .map_err(|e| format!("{spec} {format}: {e}"))?;
            renderers.push(Some(r));
        }
        if renderers[0].is_none() && rows.is_empty() {
            return Err(format!(
                "plain refuses {}: no base for the ratios",
                formats[0]
            ));
        }
        eprintln!(
            "baked {spec} ({:.0} s so far)",
            bake_start.elapsed().as_secs_f64()
        );
        rows.push((spec, manual, renderers));
    }

    let target = RenderTarget::new(&gl, width, height).map_err(|e| e.to_string())?;
    let meshes: Vec<_> = views
        .iter()
        .map(|(s, _)| s.shape.mesh(&gl))
        .collect::<Result<_, _>>()
        .map_err(|e| e.to_string())?;
    // Pixels each view covers (the plain shader into a target cleared to alpha 0).
    let mut covered = Vec::new();
    for ((scene, camera), mesh) in views.iter().zip(&meshes) {
        target.clear([0.0; 4]);
        let plain = rows[0]
            .2
            .iter()
            .flatten()
            .next()
            .ok_or("plain drew nothing")?;
        plain
            .draw(mesh, &Mat4::IDENTITY, camera, &scene.lighting, &target)
            .map_err(|e| e.to_string())?;
        let px = read_rgba_f32(&target).map_err(|e| e.to_string())?;
        covered.push(px.iter().filter(|p| p[3] > 0.5).count());
    }

    // times[row][view][format]
    let mut times = vec![vec![vec![Vec::new(); formats.len()]; views.len()]; rows.len()];
    let total = WARM_UP + frames as usize;
    for frame in 0..total {
        for (v, ((scene, camera), mesh)) in views.iter().zip(&meshes).enumerate() {
            for (i, (_, _, renderers)) in rows.iter().enumerate() {
                for (f, r) in renderers.iter().enumerate() {
                    let Some(r) = r else { continue };
                    target.clear([0.0, 0.0, 0.0, 1.0]);
                    let (drawn, ms) = gl
                        .time_ms(options.clock, || {
                            r.draw(mesh, &Mat4::IDENTITY, camera, &scene.lighting, &target)
                        })
                        .map_err(|e| e.to_string())?;
                    drawn.map_err(|e| e.to_string())?;
                    if frame >= WARM_UP {
                        times[i][v][f].push(ms);
                    }
                }
            }
        }
        eprintln!("frame {}/{total}", frame + 1);
    }

    // medians[row][view][format]: None where the format was refused.
    let medians: Vec<Vec<Vec<Option<f64>>>> = times
        .iter_mut()
        .map(|per_view| {
            per_view
                .iter_mut()
                .map(|per_format| {
                    per_format
                        .iter_mut()
                        .map(|t| (!t.is_empty()).then(|| ndfmap::usage::median(t)))
                        .collect()
                })
                .collect()
        })
        .collect();
    let load_end = ndfmap::usage::load_average();
    println!(
        "Renderer: `{}` (OpenGL {:?}, {} route).",
        gl.renderer(),
        gl.version(),
        gl.route()
    );
    println!(
        "{width}x{height}, procedural sample {}², Blinn-Phong s = 256, median of \
         {frames} frames after {WARM_UP} warm-up draws, {}; shaders measured round robin in \
         one run.",
        options.sample_size,
        options.clock.describe()
    );
    let defaults = ShaderOptions::default();
    if (options.shader.vmf_specular, options.shader.vmf_cosine)
        != (defaults.vmf_specular, defaults.vmf_cosine)
    {
        println!(
            "vMF shaders: specular rule {:?}, specular cosine {:?} (not the defaults).",
            options.shader.vmf_specular, options.shader.vmf_cosine
        );
    }
    for ((scene, _), px) in views.iter().zip(&covered) {
        println!(
            "- `{}` covers {px} of {} pixels ({:.0} %).",
            scene.name,
            width * height,
            100.0 * *px as f64 / (width * height) as f64
        );
    }
    println!();
    let mut header = String::from("| shader | sampling |");
    let mut rule = String::from("|---|---|");
    for (scene, _) in &views {
        for f in &formats {
            header += &format!(" {} {f} |", scene.name);
            rule += "---:|";
        }
    }
    println!("{header}\n{rule}");
    for ((spec, manual, _), row) in rows.iter().zip(&medians) {
        let mut line = format!(
            "| {spec} | {} |",
            if *manual { "manual" } else { "hardware" }
        );
        for (per_format, plain) in row.iter().zip(&medians[0]) {
            for (ms, plain) in per_format.iter().zip(plain) {
                line += &match (ms, plain) {
                    (Some(ms), Some(plain)) => format!(" {:.2} ({} ms) |", ms / plain, fmt_ms(*ms)),
                    (Some(ms), None) => format!(" – ({} ms) |", fmt_ms(*ms)),
                    _ => " refused |".to_string(),
                };
            }
        }
        println!("{line}");
    }
    if let Some(path) = &options.json {
        let out = FrameTimes {
            renderer: gl.renderer().to_string(),
            gl_version: format!("OpenGL {}.{}", gl.version().0, gl.version().1),
            route: gl.route().to_string(),
            width,
            height,
            frames,
            warm_up: WARM_UP as u32,
            sample_size: options.sample_size,
            views: views
                .iter()
                .zip(&covered)
                .map(|((scene, _), px)| BenchView {
                    name: scene.name.to_string(),
                    covered_pixels: *px as u64,
                })
                .collect(),
            shaders: rows
                .iter()
                .zip(&medians)
                .map(|((spec, manual, _), row)| ShaderTimes {
                    label: spec.to_string(),
                    sampling: if *manual { "manual" } else { "hardware" }.into(),
                    cells: cells(&views, &formats, row, &medians[0]),
                })
                .collect(),
            load_average: load_start.zip(load_end),
            clock: Some(options.clock.describe().to_string()),
        };
        std::fs::write(path, out.to_json()).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    Ok(())
}

/// The JSON cells of one shader: per view and format drawn, the median and its ratio to
/// plain's (`plain[view][format]`).
fn cells(
    views: &[(Scene, Camera)],
    formats: &[Format],
    row: &[Vec<Option<f64>>],
    plain: &[Vec<Option<f64>>],
) -> Vec<FrameCell> {
    let mut out = Vec::new();
    for ((scene, _), (per_format, plain)) in views.iter().zip(row.iter().zip(plain)) {
        for ((&format, ms), plain) in formats.iter().zip(per_format).zip(plain) {
            let (Some(ms), Some(plain)) = (ms, plain) else {
                continue;
            };
            out.push(FrameCell {
                view: scene.name.to_string(),
                format,
                median_ms: *ms,
                ratio_to_plain: ms / plain,
            });
        }
    }
    out
}
