//! `--bench`: the frame time of every method's shader at 1280 × 720 on the standard far and
//! grazing views (`Scene::standard`), as a Markdown table of median milliseconds and the ratio
//! to the plain normal-mapping shader of the same view and format.
//!
//! Every shader is drawn `frames` times per view after two warm-up draws (the first compiles the
//! shader on llvmpipe); each draw is timed between two `glFinish` calls. The draws go round
//! robin over all shaders, so that a change in the machine's load lands on every shader alike.

use crate::headless::context;
use crate::methods::MethodSpec;
use ndfmap::bake::{BakeOptions, Format, Method, bake_with};
use ndfmap::glsl::{ShaderOptions, ShaderSpec, manual_sampling};
use ndfmap_gl::glam::Mat4;
use ndfmap_gl::{BakeRenderer, Camera, RenderTarget, Scene, read_rgba_f32};
use std::time::Instant;

const WIDTH: u32 = 1280;
const HEIGHT: u32 = 720;
const WARM_UP: usize = 2;

/// The shaders timed: the baselines, Tan 2005 J = 4 (unaligned and aligned), vMF J = 1 … 8
/// aligned (hardware sampling) and unaligned (manual).
fn specs() -> Vec<MethodSpec> {
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

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Runs the benchmark and prints the Markdown report.
pub fn run(frames: u32, align: f64, sample_size: u32) -> Result<(), String> {
    let gl = context()?;
    let map = ndfmap::procedural::generate(sample_size, 1).map;
    let formats = [Format::F32, Format::F16];
    let views: Vec<(Scene, Camera)> = Scene::standard()
        .into_iter()
        .filter(|s| s.name == "plane-far" || s.name == "plane-grazing")
        .map(|s| {
            let camera = Camera {
                aspect: WIDTH as f32 / HEIGHT as f32,
                ..s.camera
            };
            (s, camera)
        })
        .collect();

    // rows[i] = (spec, sampling, renderer per format)
    let mut rows = Vec::new();
    let bake_start = Instant::now();
    for spec in specs() {
        let options = BakeOptions {
            lobes: spec.lobes.max(1),
            align: spec.aligned.then_some(align),
            ..BakeOptions::default()
        };
        let b = bake_with(&map, spec.method, &options).map_err(|e| e.to_string())?;
        let manual = manual_sampling(&ShaderSpec::of(&b), &ShaderOptions::default());
        let mut renderers = Vec::new();
        for format in formats {
            let q = ndfmap::pack::quantize(&b, format).map_err(|e| e.to_string())?;
            let r = BakeRenderer::new(&gl, &q, &ShaderOptions::default())
                .map_err(|e| format!("{spec} {format}: {e}"))?;
            renderers.push(r);
        }
        eprintln!(
            "baked {spec} ({:.0} s so far)",
            bake_start.elapsed().as_secs_f64()
        );
        rows.push((spec, manual, renderers));
    }

    let target = RenderTarget::new(&gl, WIDTH, HEIGHT).map_err(|e| e.to_string())?;
    let meshes: Vec<_> = views
        .iter()
        .map(|(s, _)| s.shape.mesh(&gl))
        .collect::<Result<_, _>>()
        .map_err(|e| e.to_string())?;
    // Pixels each view covers (the plain shader into a target cleared to alpha 0).
    let mut covered = Vec::new();
    for ((scene, camera), mesh) in views.iter().zip(&meshes) {
        target.clear([0.0; 4]);
        rows[0].2[0]
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
                    target.clear([0.0, 0.0, 0.0, 1.0]);
                    gl.finish();
                    let start = Instant::now();
                    r.draw(mesh, &Mat4::IDENTITY, camera, &scene.lighting, &target)
                        .map_err(|e| e.to_string())?;
                    gl.finish();
                    if frame >= WARM_UP {
                        times[i][v][f].push(start.elapsed().as_secs_f64() * 1e3);
                    }
                }
            }
        }
        eprintln!("frame {}/{total}", frame + 1);
    }

    let medians: Vec<Vec<Vec<f64>>> = times
        .iter_mut()
        .map(|per_view| {
            per_view
                .iter_mut()
                .map(|per_format| per_format.iter_mut().map(|t| median(t)).collect())
                .collect()
        })
        .collect();
    println!(
        "Renderer: `{}` (OpenGL {:?}, {} route).",
        gl.renderer(),
        gl.version(),
        gl.route()
    );
    println!(
        "{WIDTH}x{HEIGHT}, procedural sample {sample_size}², Blinn-Phong s = 256, median of \
         {frames} frames after {WARM_UP} warm-up draws, each draw timed between two glFinish \
         calls; shaders measured round robin in one run."
    );
    for ((scene, _), px) in views.iter().zip(&covered) {
        println!(
            "- `{}` covers {px} of {} pixels ({:.0} %).",
            scene.name,
            WIDTH * HEIGHT,
            100.0 * *px as f64 / (WIDTH * HEIGHT) as f64
        );
    }
    println!();
    let mut header = String::from("| shader | sampling |");
    let mut rule = String::from("|---|---|");
    for (scene, _) in &views {
        for f in formats {
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
                line += &format!(" {:.2} ({ms:.1} ms) |", ms / plain);
            }
        }
        println!("{line}");
    }
    Ok(())
}
