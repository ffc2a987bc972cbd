//! ndfmap-viewer: shows a normal map filtered by each ndfmap method — in a window (orbit, zoom,
//! method and lobe switching, split screen against a supersampled reference, BRDF and light
//! controls, frame time in the title), as headless screenshots (`--headless --screenshot`,
//! `--compare`), or as a frame-time table (`--bench`). The keys are listed in `--help` and in
//! README.md.

mod bench;
mod headless;
mod methods;
mod viewer;
mod window;

use clap::Parser;
use methods::{Bakes, MethodSpec};
use ndfmap::format::Format;
use ndfmap::glsl::ShaderOptions;
use ndfmap::shade::{VmfCosine, VmfSpecular};
use ndfmap::{IngestOptions, NormalMap};
use ndfmap_gl::glam::Vec3;
use std::path::PathBuf;
use viewer::{EnvInput, Settings, Show, ViewName};

/// Keys of the window, also printed by `--help`.
const KEYS: &str = "\
Window controls:
  mouse drag        orbit the camera          wheel, +/-   zoom (macro to far)
  M / Shift+M       next / previous method    1-8          lobe count of vMF / Tan 2005 (re-bakes)
  V                 next preset view          P            plane / sphere
  S                 split screen: method | supersampled reference
  X                 show the reference alone  C            albedo colour on / off
  ] / [             BRDF exponent s x2 / /2   T            Torrance-Sparrow / Blinn-Phong
                    (PBR methods: always GGX at --roughness)
  arrows            turn the light            F            f32 / f16 textures
  E                 environment lighting on / off (the panorama as background; every
                    method but the PBR bakes; Lambert, Blinn-Phong, GGX)
  left / right      (environment mode) turn the environment 15 deg about its zenith
  H                 (environment mode) specular route: prefiltered / SH (eq 26)
  R                 reset the view            Esc, Q       quit
The title shows the method, BRDF, reference passes and the method's draw time (glFinish).";

/// Shows a normal map filtered by the ndfmap methods.
#[derive(Parser, Debug)]
#[command(version, after_help = KEYS)]
struct Cli {
    /// Normal map (PNG, JPEG, TGA, TIFF, OpenEXR); default: the built-in procedural sample
    /// with its albedo.
    #[arg(long)]
    map: Option<PathBuf>,
    /// Albedo image of the map's size (sRGB), used as colour by the vMF and Tan 2005 bakes.
    #[arg(long, requires = "map")]
    albedo: Option<PathBuf>,
    /// Side of the built-in sample.
    #[arg(long, default_value_t = 512)]
    sample_size: u32,
    /// Methods to cycle (`plain,toksvig,lean,olano,vmf6a,vmf4,tan2005-4`, …; `a` = aligned;
    /// `pbr,pbr-aniso,pbr-mip`: PBR bakes drawn by a plain glTF GGX shader, no ndfmap code).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "plain,toksvig,lean,vmf6a"
    )]
    methods: Vec<MethodSpec>,
    /// The method shown first (added to the list if absent).
    #[arg(long)]
    method: Option<MethodSpec>,
    /// Alignment strength C of the aligned mixtures (default: each method's usual C, vMF eq 29
    /// 0.03, Tan 2005 1).
    #[arg(long)]
    align: Option<f64>,
    /// The view shown first.
    #[arg(long, value_enum, default_value = "far")]
    view: ViewName,
    /// Camera distance instead of the view's (0.06 to 600).
    #[arg(long)]
    distance: Option<f32>,
    /// Image size, WxH (window, screenshot; for --compare the size of each panel).
    #[arg(long, value_parser = ndfmap::report::frame::parse_size)]
    size: Option<(u32, u32)>,
    /// Start in split screen: method left, supersampled reference right.
    #[arg(long)]
    split: bool,
    /// Show the supersampled reference alone.
    #[arg(long, conflicts_with = "split")]
    reference: bool,
    /// Blinn-Phong exponent s (Torrance-Sparrow: sigma = sqrt(1/(2s))).
    #[arg(short = 's', long, default_value_t = 256.0)]
    exponent: f64,
    /// Diffuse coefficient K_d (grey; the view's own when absent).
    #[arg(long)]
    kd: Option<f32>,
    /// Specular coefficient K_s (grey; the view's own when absent).
    #[arg(long)]
    ks: Option<f32>,
    /// Torrance-Sparrow (eq 18) instead of Blinn-Phong.
    #[arg(long)]
    torrance_sparrow: bool,
    /// GGX with Smith masking and Schlick Fresnel, α = sqrt(2/(s+2)) (about the width of
    /// Blinn-Phong s), instead of Blinn-Phong.
    #[arg(long)]
    ggx: bool,
    /// Base perceptual roughness √α (glTF's) of the PBR methods (`pbr`, `pbr-aniso`,
    /// `pbr-mip`), which are drawn by a plain glTF GGX shader and lit by GGX of this α.
    #[arg(long, default_value_t = 0.3, value_parser = parse_roughness)]
    roughness: f64,
    /// Ignore the map's albedo.
    #[arg(long)]
    no_color: bool,
    /// Texture format of the uploads.
    #[arg(long, default_value = "f32")]
    format: Format,
    /// Repetitions of the map per side of the plane (default: 32 in the far view, else 8).
    #[arg(long)]
    repeat: Option<f32>,
    /// Reference supersampling: k x k jittered passes (the window adds them progressively).
    #[arg(long, default_value_t = 16)]
    ss: u32,
    /// Render offscreen (EGL, else OSMesa) instead of opening a window.
    #[arg(long)]
    headless: bool,
    /// Write the frame to this PNG (headless; in a window, after the last of --frames).
    #[arg(long)]
    screenshot: Option<PathBuf>,
    /// Write the methods side by side, then the reference, into --screenshot (headless).
    #[arg(long, requires = "screenshot")]
    compare: bool,
    /// Print the frame time of every method's shader (headless; --size, default 1280x720;
    /// --methods other than the default list restricts the shaders, plain always included).
    #[arg(long)]
    bench: bool,
    /// Bench: also write the times as JSON (what `ndfmap report --frame-times` reads).
    #[arg(long, requires = "bench")]
    bench_json: Option<PathBuf>,
    /// Bench: texture formats, comma-separated.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "f32,f16",
        requires = "bench"
    )]
    bench_formats: Vec<Format>,
    /// Bench: how each draw is timed: `wall`, between two glFinish calls (llvmpipe, where the
    /// draw is CPU work), or `gpu`, by a GL_TIME_ELAPSED query (a GPU, where the wall time is
    /// mostly the driver's fixed cost per draw).
    #[arg(long, default_value = "wall", value_parser = bench::parse_clock, requires = "bench")]
    bench_clock: ndfmap_gl::Clock,
    /// Bench: the vMF lobes' specular rule in every shader (`ndfmap shader --vmf-specular`):
    /// auto (the default), eq20 or convolved, to time a rule against the default on one machine.
    #[arg(long, default_value = "auto", value_parser = bench::parse_vmf_specular, requires = "bench")]
    vmf_specular: VmfSpecular,
    /// Bench: the vMF specular cosine in every shader (`ndfmap shader --vmf-cosine`): product
    /// (the default) or algorithm2.
    #[arg(long, default_value = "product", value_parser = bench::parse_vmf_cosine, requires = "bench")]
    vmf_cosine: VmfCosine,
    /// Window: quit after this many frames. Bench: timed frames per shader and view.
    #[arg(long)]
    frames: Option<u32>,
    /// Start lit by this environment (equirectangular Radiance .hdr or OpenEXR, 2:1, linear;
    /// e.g. the shared panoramas, read in place), `sky` for the generated sky with its sun
    /// (the `E` key's default). The panorama is the background; the bake is lit by it in RGB.
    #[arg(long)]
    env: Option<String>,
    /// Specular route under the environment: prefiltered (one lookup per lobe) or sh (eq 26).
    #[arg(long, default_value = "prefiltered")]
    env_route: ndfmap::envlight::Route,
    /// Rotation of the environment about its zenith, degrees.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    env_yaw: f32,
    /// Radiance multiplier of the environment.
    #[arg(long, default_value_t = 1.0)]
    env_intensity: f64,
    /// Extract up to N compact bright sources (a sun, lamps) from the environment, and up to N
    /// wide ones (≤ 1 sr: windows) from its diffuse SH, and shade them as distant lights, per
    /// lobe, with the routes on the residual (as `ndfmap eval --env-lights`, the same default);
    /// 0: the paper's pure routes.
    #[arg(long, default_value_t = 4)]
    env_lights: usize,
}

/// The environment of environment mode: `--env FILE` loaded (with `--env-intensity`), or the
/// generated sky (`--env sky`, or none: made when `E` is first pressed).
fn load_env(cli: &Cli) -> Result<EnvInput, String> {
    let options = ndfmap::environment::EnvOptions {
        intensity: cli.env_intensity,
        ..Default::default()
    };
    let sky = || -> Result<ndfmap::environment::Environment, String> {
        ndfmap::environment::Sky {
            width: 1024,
            ..Default::default()
        }
        .render_with(&options)
        .map_err(|e| e.to_string())
    };
    match cli.env.as_deref() {
        None | Some("sky") => Ok(EnvInput {
            name: "sky".into(),
            environment: sky()?,
            max_lights: cli.env_lights,
        }),
        Some(path) => {
            let env = ndfmap::environment::load(std::path::Path::new(path), &options)
                .map_err(|e| e.to_string())?;
            if env.repaired() > 0 {
                eprintln!(
                    "ndfmap-viewer: {path}: {} NaN, infinite or negative texels set to 0",
                    env.repaired()
                );
            }
            let name = std::path::Path::new(path)
                .file_stem()
                .map_or(path.to_string(), |s| s.to_string_lossy().into_owned());
            Ok(EnvInput {
                name,
                environment: env,
                max_lights: cli.env_lights,
            })
        }
    }
}

/// A perceptual roughness in [0, 1].
fn parse_roughness(s: &str) -> Result<f64, String> {
    let r: f64 = s.parse().map_err(|e| format!("{e}"))?;
    if (0.0..=1.0).contains(&r) {
        Ok(r)
    } else {
        Err(format!("{r} is not a perceptual roughness in [0, 1]"))
    }
}

/// The map to show: `--map` (with `--albedo`), or the built-in sample with its albedo.
fn load_map(cli: &Cli) -> Result<NormalMap, String> {
    let Some(path) = &cli.map else {
        let sample = ndfmap::procedural::generate(cli.sample_size, 1);
        return sample
            .map
            .with_feature(sample.albedo)
            .map_err(|e| e.to_string());
    };
    let opts = IngestOptions::default();
    let map = NormalMap::load(path, &opts).map_err(|e| e.to_string())?;
    match &cli.albedo {
        Some(a) => map.with_feature_file(a, &opts).map_err(|e| e.to_string()),
        None => Ok(map),
    }
}

/// The settings the command line asks for.
fn settings(cli: &Cli) -> Result<Settings, String> {
    let mut methods = cli.methods.clone();
    let mut current = 0;
    if let Some(m) = cli.method {
        current = methods.iter().position(|x| *x == m).unwrap_or_else(|| {
            methods.push(m);
            methods.len() - 1
        });
    }
    let mut s = Settings::new(methods, cli.view);
    s.repeat = cli.repeat.map(|r| r.max(0.01));
    s.set_view(cli.view);
    if let Some(d) = cli.distance {
        s.camera.distance = 1.0;
        s.zoom(d);
    }
    s.current = current;
    s.exponent = cli.exponent;
    if let Some(kd) = cli.kd {
        s.lighting.kd = Vec3::splat(kd);
    }
    if let Some(ks) = cli.ks {
        s.lighting.ks = Vec3::splat(ks);
    }
    s.torrance_sparrow = cli.torrance_sparrow;
    s.ggx = cli.ggx;
    s.pbr_roughness = cli.roughness;
    s.color = !cli.no_color;
    s.format = cli.format;
    s.supersampling = cli.ss.max(1);
    s.env_route = cli.env_route;
    s.turn_env(cli.env_yaw.to_radians());
    s.show = match (cli.split, cli.reference) {
        (true, _) => Show::Split,
        (_, true) => Show::Reference,
        _ => Show::Method,
    };
    if cli.env.is_some() {
        s.set_env(true)?;
    }
    Ok(s)
}

fn run(cli: Cli) -> Result<(), String> {
    if cli.methods.is_empty() {
        return Err("--methods: give at least one method".into());
    }
    if cli.bench {
        return bench::run(&bench::BenchOptions {
            frames: cli.frames.unwrap_or(20),
            align: cli.align,
            sample_size: cli.sample_size,
            size: cli.size.unwrap_or((1280, 720)),
            specs: if cli.methods == MethodSpec::defaults() {
                Vec::new()
            } else {
                cli.methods.clone()
            },
            formats: cli.bench_formats.clone(),
            json: cli.bench_json.clone(),
            clock: cli.bench_clock,
            shader: ShaderOptions {
                vmf_specular: cli.vmf_specular,
                vmf_cosine: cli.vmf_cosine,
                ..ShaderOptions::default()
            },
        });
    }
    let map = load_map(&cli)?;
    let bakes = Bakes::new(map, cli.align, cli.roughness);
    let settings = settings(&cli)?;
    let env = load_env(&cli)?;
    if cli.headless || cli.compare {
        let path = cli
            .screenshot
            .as_deref()
            .ok_or("--headless needs --screenshot PATH")?;
        if cli.compare {
            let (w, h) = cli.size.unwrap_or((360, 360));
            let methods = if cli.methods == MethodSpec::defaults() {
                headless::COMPARED.to_vec()
            } else {
                cli.methods.clone()
            };
            headless::compare(bakes, env, settings, &methods, w, h, path)
        } else {
            let (w, h) = cli.size.unwrap_or((1280, 720));
            headless::screenshot(bakes, env, settings, w, h, path)
        }
    } else {
        window::run(
            bakes,
            env,
            settings,
            cli.size.unwrap_or((1280, 720)),
            cli.frames,
            cli.screenshot,
        )
    }
}

fn main() {
    if let Err(e) = run(Cli::parse()) {
        eprintln!("ndfmap-viewer: {e}");
        std::process::exit(1);
    }
}
