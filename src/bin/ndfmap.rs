//! `ndfmap`: bake filtered normal-distribution textures from a normal map, and measure how well
//! each filtering method matches the exact shading.

use clap::{Args, Parser, Subcommand};
use ndfmap::bake::{Bake, BakeOptions, FitMode, Method};
use ndfmap::brdf::Brdf;
use ndfmap::em::AlignmentForm;
use ndfmap::error::compact_f64;
use ndfmap::eval::{default_directions, evaluate, evaluate_with, format_table};
use ndfmap::format::Format;
use ndfmap::glsl::{Sampling, ShaderBrdf, Stage};
use ndfmap::ingest::{Addressing, BadNormals, Channels, Encoding, FeatureEncoding, GreenChannel};
use ndfmap::methods::bake_with;
use ndfmap::output::{InputInfo, write_bake};
use ndfmap::{Error, IngestOptions, NormalMap, Result};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

/// Filtered normal-distribution textures for normal maps (Han et al. 2007).
///
/// A normal map that is simply MIP-mapped loses its highlights and aliases at a distance,
/// because shading is not linear in the normal. ndfmap bakes, for every MIP level, a
/// description of the distribution of normals a texel covers, so shaders can widen and dim
/// highlights correctly.
///
/// Start with `ndfmap demo`. Then `ndfmap eval MAP.png` compares the methods on your map, and
/// `ndfmap bake MAP.png --method toksvig -o out/` writes textures an engine loads.
#[derive(Parser)]
#[command(name = "ndfmap", version, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Time the vMF and SH bakes (and Toksvig's, for scale) on the built-in sample at several
    /// sizes, lobe counts and band limits: wall seconds, CPU seconds, peak memory, the memory
    /// budget's estimate and texture bytes per run, each run in a process of its own (so a
    /// row's peak is its bake's alone). With `--quality`, measure instead how well
    /// each vMF bake fits its normals (`ndfmap::quality`): per level, the log-likelihood gap to
    /// a multi-start reference fit and the dead / near-empty lobe shares.
    Bench {
        /// Map sizes (square), comma-separated.
        #[arg(long, default_value = "256,512,1024", value_delimiter = ',')]
        sizes: Vec<u32>,
        /// Lobe counts, comma-separated (0: no vMF bake).
        #[arg(long, default_value = "6", value_delimiter = ',')]
        lobes: Vec<usize>,
        /// SH band limits l*, comma-separated.
        #[arg(long, default_value = "2,4,8", value_delimiter = ',')]
        lmax: Vec<usize>,
        /// Alignments, comma-separated: `none`, `default` (eq 29: C = 0.03) or a strength C.
        #[arg(long, default_value = "none,default", value_delimiter = ',')]
        align: Vec<String>,
        /// vMF fitting modes, comma-separated: fast, balanced, exact.
        #[arg(long, default_value = "fast,balanced,exact", value_delimiter = ',')]
        modes: Vec<String>,
        #[command(flatten)]
        em: EmArgs,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
        /// Measure fit quality instead of speed.
        #[arg(long)]
        quality: bool,
        /// Measure the bounded-memory (banded, streamed) bake instead (docs/scale.md): vMF,
        /// the first `--lobes`, aligned with eq 29's default C, balanced (or the one `--modes` given), no colour, written as f16 KTX2 to a
        /// temporary folder (deleted) from the built-in 1024² sample tiled to each size
        /// (`--sizes`: up to 1024, or multiples of 1024 up to 16384), kept as 8-bit samples:
        /// seconds, CPU µs per texel and its ratio to the first size, peak RSS and the
        /// budget's estimate; sizes up to `--untiled-max` are also baked untiled (in memory)
        /// and the files compared byte for byte. Each bake runs in a process of its own.
        #[arg(long)]
        scale: bool,
        /// `--scale`: largest size also baked untiled for the byte comparison (0: none).
        #[arg(long, default_value_t = 2048)]
        untiled_max: u32,
        /// Normal maps to measure (instead of the built-in sample at `--sizes`).
        #[arg(long, value_delimiter = ',')]
        maps: Vec<PathBuf>,
        /// `--quality`: texels sampled per level.
        #[arg(long, default_value_t = 100)]
        samples: usize,
        /// `--quality`: the levels measured, FIRST..=LAST.
        #[arg(long, default_value = "2..=8")]
        levels: String,
        /// `--quality`: EM starts of the reference fit (furthest-point, then k-means++ seeds).
        #[arg(long, default_value_t = 8)]
        reference_starts: usize,
        /// `--quality`: also fit a second reference per texel with other seeds and print how
        /// often it is at least as good as the first (`ref2>=ref`, the share the reference
        /// procedure reaches against itself) and its mean gap to the first; doubles the time.
        #[arg(long)]
        reference_check: bool,
        /// Time each bake this many times (1 to 100) and print the median wall and CPU
        /// seconds and the highest peak (issue 14's speed target is the median of 5; JSON also
        /// lists every run's wall seconds). Not with `--quality` or `--scale`.
        #[arg(long, default_value_t = 1)]
        runs: usize,
        /// Internal: time one run of row N of the speed table (or, with `--scale`, of the scale
        /// table) in this process and print it as JSON (`ndfmap bench` runs every run of every
        /// row so, each in a process of its own).
        #[arg(long, hide = true)]
        job: Option<usize>,
        /// Internal, with `--scale --job`: the folder that row writes its files to.
        #[arg(long, hide = true)]
        job_dir: Option<PathBuf>,
    },
    /// Generate the built-in sample map, bake every method, and print the error table.
    Demo {
        /// Output folder (the sample's PNGs and one bake per method go here).
        #[arg(short, long, default_value = "out/demo")]
        output: PathBuf,
        /// Side of the generated square map, in texels.
        #[arg(long, default_value_t = 512)]
        size: u32,
    },
    /// Read a normal map and print what ingest found (size, mean z, bad normals).
    Info {
        /// The normal map (PNG, JPEG, TGA, TIFF, OpenEXR).
        input: PathBuf,
        #[command(flatten)]
        ingest: IngestArgs,
    },
    /// Bake one method's MIP chain to a folder: manifest.json plus OpenEXR (or PNG) files, or
    /// one KTX2 or DDS file per texture (`--container`). Several inputs (files or quoted globs)
    /// or a batch file (`--batch`) are baked in parallel within the memory budget, each into
    /// its own folder; the manifest records a content hash of the input, the options and the
    /// ndfmap version, and an input whose folder is complete and current is skipped. With
    /// several inputs the exit status is the number that failed (at most 125).
    Bake(BakeCommand),
    /// Plan what a scene needs (docs/planner.md): measure MAP by sampling, choose per level
    /// range the cheapest method, lobe count and storage format meeting SCENE's error target,
    /// and write the plan file and specialized shaders (`bake --plan` consumes the plan).
    Plan {
        /// The scene description (TOML or JSON, docs/planner.md).
        scene: PathBuf,
        /// The normal map.
        input: PathBuf,
        /// Output folder for plan.json and the shaders (part0.frag, ...); without it the plan
        /// is printed.
        #[arg(short, long)]
        output: Option<PathBuf>,
        /// Print every decision, with the error it saves or costs.
        #[arg(long)]
        explain: bool,
        /// Then bake the plan and the full configuration (vMF J = 8 aligned, f32, colour) and
        /// measure both on the whole map: bytes, bake seconds, fetches, ALU, error against the
        /// target and the prediction (the report's planner row; slow: a full bake).
        #[arg(long)]
        verify: bool,
        #[command(flatten)]
        ingest: IngestArgs,
    },
    /// Print a method's GLSL 3.30 shader, specialized by #defines, for an engine to compile or
    /// a tool to validate (e.g. `| glslangValidator --stdin -S frag`).
    Shader {
        /// Filtering method: plain, toksvig, lean, olano, tan2005, vmf, sh.
        #[arg(short, long)]
        method: String,
        /// vmf, tan2005: lobes per texel, 1 to 8.
        #[arg(long, default_value_t = 6)]
        lobes: usize,
        /// sh: the bake's band limit l* (0 to 10 in GLSL: 32 textures at most).
        #[arg(long, default_value_t = 4)]
        lmax: usize,
        /// vmf, tan2005: the lobes were baked aligned (`bake --align`): sample them with one
        /// hardware trilinear fetch. Unaligned lobes are shaded per texel and blended.
        #[arg(long)]
        aligned: bool,
        /// Texture format the bake is uploaded in: f32, f16, unorm16, unorm8.
        #[arg(long, default_value = "f32")]
        format: String,
        /// vmf, tan2005: weight each lobe by its colour texture (a bake with --color).
        #[arg(long)]
        color: bool,
        /// BRDF: blinn-phong (uniform ndf_s), torrance-sparrow (ndf_sigma), lambert, ggx
        /// (ndf_alpha, ndf_ggx_c), tabulated (sampler ndf_brdf_table).
        #[arg(long, default_value = "blinn-phong")]
        brdf: String,
        /// ggx: multiply by the g factor (Smith masking, Schlick Fresnel; uniform ndf_f0).
        #[arg(long)]
        ggx_g: bool,
        /// Sampling: auto (the bake's natural mode), hardware, manual, or anisotropic.
        #[arg(long, default_value = "auto")]
        sampling: String,
        /// anisotropic sampling: the most probes, 2 to 16.
        #[arg(long, default_value_t = 16)]
        max_anisotropy: u32,
        /// vmf: the lobes' diffuse term, mean-vector (max(ω_i·αr, 0), the default) or
        /// algorithm2 (α max(ω_i·μ, 0)).
        #[arg(long, default_value = "mean-vector")]
        vmf_diffuse: String,
        /// vmf, Blinn-Phong and GGX: where the specular term takes its cosine of incidence,
        /// product (the default: at the centre of the NDF lobe's and the BRDF lobe's product) or
        /// algorithm2 (at μ, as Algorithm 2 line 14 is written).
        #[arg(long, default_value = "product")]
        vmf_cosine: String,
        /// vmf: the lobes' specular rule, auto (the default: eq20 under Blinn-Phong; GGX: the
        /// exact convolution of GGX's D as a fitted mixture of vMF lobes), eq20 (the paper's
        /// s' = κs/(κ+s); GGX: one widened lobe α'² = α² + c/κ) or convolved (the closed-form
        /// vMF ⊛ Blinn-Phong lobe; GGX: the peak-matched widening α'² = α² + c·m(κα²/2)/κ).
        #[arg(long, default_value = "auto")]
        vmf_specular: String,
        /// sh: the diffuse term, moments (a Gaussian cosine with the moments of bands 0-2, the
        /// default) or series (eq 12 with Lambert's truncated clamped cosine).
        #[arg(long, default_value = "moments")]
        sh_diffuse: String,
        /// The texture addressing of the bake: wrap or clamp.
        #[arg(long, default_value = "wrap")]
        addressing: String,
        /// Stage to print: fragment or vertex.
        #[arg(long, default_value = "fragment")]
        stage: String,
        /// The probe variant (full-screen, uniforms for uv, LOD, light and half vector) used by
        /// the GL-versus-CPU tests.
        #[arg(long)]
        probe: bool,
        /// The lighting: point (one light), env-prefiltered or env-sh (an environment by that
        /// route: plain, toksvig, lean and vmf; docs/environment.md).
        #[arg(long, default_value = "point")]
        light: String,
    },
    /// Measure error against run time for every method and storage format: texel-space and
    /// image-space error (supersampled ground truth, relative RMSE and FLIP), bake time, peak
    /// memory, texture bytes and shading cost; write report.md, report.json, plots and images.
    #[cfg(feature = "report")]
    Report(ReportArgs),
    /// Compare PBR roughness MIP chains for plain GGX engines (issue 17): plain mip, Filament's
    /// roughness-prefilter (when on PATH), the κ formulas, ndfmap's fitted isotropic and
    /// anisotropic lobes, the best isotropic lobe found, and vMF J = 6, in texel-space GGX
    /// error; prints markdown tables.
    #[cfg(feature = "report")]
    PbrReport {
        /// Normal maps (PNG, JPEG, TGA, TIFF, OpenEXR).
        #[arg(required = true)]
        inputs: Vec<PathBuf>,
        /// Base GGX α values, comma-separated.
        #[arg(long, default_value = "0.05,0.1,0.3", value_delimiter = ',')]
        alpha: Vec<f64>,
        /// First MIP level measured.
        #[arg(long, default_value_t = 2)]
        first_level: usize,
        /// Last MIP level measured.
        #[arg(long, default_value_t = 7)]
        last_level: usize,
        /// Leave out the vMF J = 6 row (its bake takes the longest).
        #[arg(long)]
        no_vmf: bool,
        /// A renderer that never shows views or lights beyond DEG degrees: score every row on
        /// the evaluation's pairs within it and add the bake fitted for it
        /// (`bake -m pbr --fit-max-angle DEG`).
        #[arg(long, value_name = "DEG")]
        fit_max_angle: Option<f64>,
        /// Also write the comparisons as JSON to this file.
        #[arg(long)]
        json: Option<PathBuf>,
    },
    /// Measure each method's texel-space error against the exact footprint average.
    Eval {
        /// The normal map (PNG, JPEG, TGA, TIFF, OpenEXR).
        input: PathBuf,
        /// Methods to compare, comma-separated (plain, toksvig, lean, olano, tan2005, vmf, sh).
        #[arg(
            long,
            default_value = "plain,toksvig,lean,olano,vmf",
            value_delimiter = ','
        )]
        methods: Vec<String>,
        /// SH band limits l* to compare, comma-separated (0 to 16).
        #[arg(long, default_value = "2,4,8", value_delimiter = ',')]
        lmax: Vec<usize>,
        /// vMF lobe counts to compare, comma-separated.
        #[arg(long, default_value = "6", value_delimiter = ',')]
        lobes: Vec<usize>,
        /// vMF alignments to compare, comma-separated: `none` (unaligned), `default` (the
        /// form's usual C: eq 29 0.03, eq 23 0.1) or a strength C.
        #[arg(long, default_value = "none", value_delimiter = ',')]
        align: Vec<String>,
        /// vMF alignment M-step: `appendix` (eq 29) or `main-text` (eq 23).
        #[arg(long, default_value = "appendix")]
        align_form: String,
        /// vMF fitting modes to compare, comma-separated: `fast`, `balanced` (the default),
        /// `exact` (EM options as given).
        #[arg(long, default_value = "balanced", value_delimiter = ',')]
        modes: Vec<String>,
        #[command(flatten)]
        em: EmArgs,
        /// Blinn-Phong exponents, comma-separated.
        #[arg(
            short,
            long = "exponents",
            default_value = "64,512",
            value_delimiter = ','
        )]
        s: Vec<f64>,
        /// Torrance–Sparrow roughness values σ to measure as well, comma-separated (eq 18; vMF
        /// lobes are shaded with eq 21, σ'² = σ² + 1/(2κ)).
        #[arg(long, value_delimiter = ',')]
        sigma: Vec<f64>,
        /// BRDFs, comma-separated: lambert, blinn-phong (each -s), torrance-sparrow (each
        /// --sigma, default 0.1), ggx (each --alpha, default 0.1), or a tabulated BRDF file
        /// (JSON). Without it: Blinn-Phong for each -s, eq 18 for each --sigma, GGX for each
        /// --alpha.
        #[arg(long, value_delimiter = ',')]
        brdf: Vec<String>,
        /// GGX roughness values α, comma-separated.
        #[arg(long, value_delimiter = ',')]
        alpha: Vec<f64>,
        /// GGX: multiply by the g factor (Smith masking, Schlick Fresnel F0 = 0.04).
        #[arg(long)]
        ggx_g: bool,
        /// GGX widening constants c (α'² = α² + c/κ) to compare, comma-separated (default: the
        /// library's choice).
        #[arg(long, value_delimiter = ',')]
        ggx_c: Vec<f64>,
        /// vMF diffuse term: mean-vector (default) or algorithm2.
        #[arg(long, default_value = "mean-vector")]
        vmf_diffuse: String,
        /// vMF specular term's cosine of incidence under Blinn-Phong and GGX: product (default:
        /// at the centre of the NDF lobe's and the BRDF lobe's product) or algorithm2 (at μ).
        #[arg(long, default_value = "product")]
        vmf_cosine: String,
        /// vMF specular rule, comma-separated to compare in one run (labels then name the
        /// rule): auto (the default: eq20 under Blinn-Phong; GGX: the exact convolution of
        /// GGX's D as a fitted mixture of vMF lobes), eq20 (the paper's s' = κs/(κ+s); GGX: one
        /// widened lobe α'² = α² + c/κ), convolved (the closed-form vMF ⊛ Blinn-Phong lobe;
        /// GGX: the peak-matched widening α'² = α² + c·m(κα²/2)/κ) or exact (Blinn-Phong only:
        /// eq 14 by quadrature, CPU only, slow, the bound on what any rule can give).
        #[arg(long, value_delimiter = ',', default_value = "auto")]
        vmf_specular: Vec<String>,
        /// SH diffuse term: moments (default) or series (eq 12 with Lambert's truncated clamped
        /// cosine).
        #[arg(long, default_value = "moments")]
        sh_diffuse: String,
        /// Measure levels from this one on (finer ones are reported as 0; the overall error is
        /// over levels 1 and coarser either way, and level 0 is three quarters of the work).
        #[arg(long, default_value_t = 0)]
        first_level: usize,
        /// Storage formats to measure, comma-separated (f32, f16, unorm16, unorm8, and the
        /// block compressions bc6h, bc7, bc5, bc6h+bc4): each bake is rounded through the
        /// format (encoded and decoded) before shading, so the format's own error shows.
        #[arg(long, default_value = "f32", value_delimiter = ',')]
        formats: Vec<String>,
        /// Print JSON instead of tables.
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        env: EnvArgs,
        #[command(flatten)]
        ingest: IngestArgs,
    },
}

/// Environment lighting (`eval --env`).
#[derive(Args)]
struct EnvArgs {
    /// Light with an equirectangular environment (Radiance .hdr or OpenEXR, 2:1, linear), or
    /// `sky` for the generated sky with a small bright sun, instead of point lights; the error
    /// is of the luminance, against a Monte Carlo ground truth (MIS of the environment and the
    /// BRDF). Methods: plain, toksvig, lean, olano, vmf, tan2005, sh; BRDFs: lambert,
    /// blinn-phong, ggx. With `--feature ALBEDO` the surface is coloured: the ground truth
    /// weights each normal by its albedo, vMF and Tan 2005 bakes are shaded with their colour
    /// textures (eq 22) and the other methods times the footprint's mean albedo (the albedo
    /// MIP).
    #[arg(long)]
    env: Option<String>,
    /// vMF specular routes under the environment, comma-separated: prefiltered, sh.
    #[arg(long, default_value = "prefiltered,sh", value_delimiter = ',')]
    env_route: Vec<String>,
    /// Environment rotation about the zenith, degrees.
    #[arg(long, default_value_t = 0.0)]
    env_yaw: f64,
    /// Environment radiance multiplier.
    #[arg(long, default_value_t = 1.0)]
    env_intensity: f64,
    /// Ground-truth MIS iterations per texel and view, 1 to 65536.
    #[arg(long, default_value_t = 512)]
    env_samples: usize,
    /// Texels drawn per MIP level (all of a smaller level), 1 to 1024.
    #[arg(long, default_value_t = 48)]
    env_texels: usize,
    /// Extract up to N compact bright sources (a sun, lamps) from the environment and shade
    /// them as distant lights, each lobe as the point-light path does, with the routes on the
    /// residual, and up to N wider ones (≤ 1 sr: windows) from the diffuse SH only
    /// (docs/environment.md, "Bright sources as lights"); 0: the paper's pure routes.
    /// The ground truth is the full environment either way. The GLSL routes add the same
    /// lights (`NDF_ENV_LIGHTS`), so the CPU figures are what the shaders draw.
    #[arg(long, default_value_t = 4)]
    env_lights: usize,
    /// Largest solid angle (sr) of an extracted light, of its texels and of its spread's cap
    /// `4π/κ` (`--env-lights`; docs/environment.md), in (0, 4π].
    #[arg(long, default_value_t = 0.05)]
    env_light_max_sr: f64,
}

impl EnvArgs {
    /// Refuses sample and texel counts outside their ranges (0 included: it would mean
    /// nothing measured) and a largest light solid angle that is not in (0, 4π] sr.
    fn check(&self) -> Result<()> {
        use ndfmap::envlight::{MAX_SAMPLES, MAX_TEXELS_PER_LEVEL};
        for (option, value, max) in [
            ("--env-samples", self.env_samples, MAX_SAMPLES),
            ("--env-texels", self.env_texels, MAX_TEXELS_PER_LEVEL),
        ] {
            if !(1..=max).contains(&value) {
                return Err(Error::InvalidOption(format!(
                    "{option} {value} (expected 1 to {max})"
                )));
            }
        }
        let sr = self.env_light_max_sr;
        if !(sr > 0.0 && sr <= 4.0 * std::f64::consts::PI) {
            return Err(Error::InvalidOption(format!(
                "--env-light-max-sr {} (expected a solid angle in (0, 4π] sr, 4π = 12.566)",
                compact_f64(sr)
            )));
        }
        Ok(())
    }

    /// The environment's luminance, ready to light with; prints what was repaired and the
    /// projection's check against Filament's cmgen (or that cmgen is absent).
    fn load(&self, quiet: bool) -> Result<Option<(String, ndfmap::envlight::EnvLight)>> {
        let Some(name) = &self.env else {
            return Ok(None);
        };
        let options = ndfmap::environment::EnvOptions {
            yaw_deg: self.env_yaw,
            intensity: self.env_intensity,
            ..Default::default()
        };
        let env = if name == "sky" {
            ndfmap::environment::Sky::default().render_with(&options)?
        } else {
            ndfmap::environment::load(Path::new(name), &options)?
        };
        if env.repaired() > 0 {
            eprintln!(
                "{name}: {} texels with NaN, infinite or negative radiance set to 0",
                env.repaired()
            );
        }
        if !quiet && name != "sky" {
            eprintln!("{}", cmgen_check(Path::new(name), &env));
        }
        let lights = ndfmap::environment::lights::LightOptions {
            max_solid_angle: self.env_light_max_sr,
            ..ndfmap::environment::lights::LightOptions::up_to(self.env_lights)
        };
        let light = ndfmap::envlight::EnvLight::with_lights(&env, &lights);
        if !quiet {
            for (k, l) in light.lights().iter().enumerate() {
                let d = l.direction;
                eprintln!(
                    "{name}: light {k}: direction ({:.4}, {:.4}, {:.4}), power ({:.4e}, {:.4e}, \
                     {:.4e}), {} texels, {:.3e} sr, kappa {:.3e}{}",
                    d.x,
                    d.y,
                    d.z,
                    l.power[0],
                    l.power[1],
                    l.power[2],
                    l.texels,
                    l.solid_angle,
                    l.kappa,
                    if l.diffuse_only {
                        " (diffuse only)"
                    } else {
                        ""
                    }
                );
            }
        }
        Ok(Some((name.clone(), light)))
    }
}

/// Compares the environment's SH projection (bands 0–2, per channel) with Filament's `cmgen`
/// (`--sh=3 --sh-window=no`, radiance, not irradiance) by band energy `sqrt(Σ_m L_lm²)`, which
/// does not depend on the frame or the sign conventions. One line: the largest relative
/// difference, or why there is no check.
fn cmgen_check(path: &Path, env: &ndfmap::environment::Environment) -> String {
    let cmgen = ["/usr/bin/cmgen", "/usr/local/bin/cmgen"]
        .into_iter()
        .map(Path::new)
        .find(|p| p.exists());
    let Some(cmgen) = cmgen else {
        return "cmgen not found: the SH projection is not cross-checked".into();
    };
    if env.repaired() > 0 {
        return "cmgen check skipped: the environment was repaired".into();
    }
    let Ok(dir) = tempdir() else {
        return "cmgen check skipped: no temporary directory".into();
    };
    let out = dir.join("sh.txt");
    let status = std::process::Command::new(cmgen)
        .arg("--sh=3")
        .arg(format!("--sh-output={}", out.display()))
        .arg("--sh-window=no")
        .arg("-q")
        .arg(path)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .status();
    let text = std::fs::read_to_string(&out).unwrap_or_default();
    let _ = std::fs::remove_dir_all(&dir);
    if !matches!(status, Ok(s) if s.success()) || text.is_empty() {
        return "cmgen check skipped: cmgen failed on this file".into();
    }
    let theirs: Vec<[f64; 3]> = text
        .lines()
        .filter_map(|l| {
            let inner = l.split('(').nth(1)?.split(')').next()?;
            let v: Vec<f64> = inner
                .split(',')
                .filter_map(|x| x.trim().parse().ok())
                .collect();
            (v.len() == 3).then(|| [v[0], v[1], v[2]])
        })
        .collect();
    if theirs.len() != 9 {
        return format!(
            "cmgen check skipped: {} coefficients read, 9 expected",
            theirs.len()
        );
    }
    let mut worst: f64 = 0.0;
    let mut cells = Vec::new();
    for c in 0..3 {
        let ours = ndfmap::environment::projection::project(&env.channel(c), 2);
        let cm: Vec<f64> = theirs.iter().map(|t| t[c]).collect();
        // A band's difference is relative to its energy, but to no less than 1 % of band 0's:
        // two near-zero bands (a constant panorama's l = 2: 0.0016 against 0) would read 100 %.
        let floor = 0.01 * ours[0].abs().max(cm[0].abs());
        for l in 0..3usize {
            let band = |v: &dyn Fn(usize) -> f64| {
                (l * l..(l + 1) * (l + 1))
                    .map(|k| v(k) * v(k))
                    .sum::<f64>()
                    .sqrt()
            };
            let a = band(&|k| ours[k]);
            let b = band(&|k| cm[k]);
            let rel = (a - b).abs() / a.max(b).max(floor).max(1e-12);
            worst = worst.max(rel);
            if c == 1 {
                cells.push(format!("l={l} {a:.4}/{b:.4}"));
            }
        }
    }
    format!(
        "SH projection against cmgen (band energies, ours/cmgen, green: {}): largest relative difference {:.2} % (of the band, at least 1 % of l = 0's)",
        cells.join(", "),
        100.0 * worst
    )
}

/// A fresh temporary directory (std only: the binary does not depend on tempfile).
fn tempdir() -> std::io::Result<PathBuf> {
    let d = std::env::temp_dir().join(format!("ndfmap-cmgen-{}", std::process::id()));
    std::fs::create_dir_all(&d)?;
    Ok(d)
}

/// How to read the normal map.
#[derive(Args)]
struct IngestArgs {
    /// Green channel: opengl (+Y) or directx (−Y).
    #[arg(long, default_value = "opengl")]
    green: String,
    /// Value encoding: auto (unorm for integer images, snorm for float), unorm, snorm.
    #[arg(long, default_value = "auto")]
    encoding: String,
    /// Channels: auto, xyz, or xy (2-channel map, z reconstructed).
    #[arg(long, default_value = "auto")]
    channels: String,
    /// Edge addressing: wrap (tiling) or clamp.
    #[arg(long, default_value = "wrap")]
    addressing: String,
    /// Bad normals (zero-length, NaN, below the horizon): repair or reject.
    #[arg(long, default_value = "repair")]
    bad_normals: String,
    /// Optional feature (albedo colour) image of the same size (eq 22's colour per lobe).
    #[arg(long, alias = "color")]
    feature: Option<PathBuf>,
    /// Feature image encoding: srgb (decoded to linear) or linear.
    #[arg(long, default_value = "srgb")]
    feature_encoding: String,
    /// Memory budget (e.g. 512M, 4G): a file or a bake estimated to need more is refused
    /// before it starts. Default: half the machine's memory.
    #[arg(long)]
    memory: Option<String>,
}

/// The EM iteration cap and convergence tolerance of the mixture fits (vmf, tan2005).
#[derive(Args)]
struct EmArgs {
    /// vmf, tan2005: the most EM iterations per texel, 1 to 1000 [default: 20]. Exact mode
    /// and Tan 2005 run up to this many; fast and balanced keep their own lower caps (3 and 8,
    /// lifted by balanced on large texels: see `--mode`) unless this is lower. Exact mode
    /// reaches the reference fit on more texels with 60 to 300 (docs/baker.md, "Stop 49"), at
    /// 2 to 10 times its time.
    #[arg(long, value_name = "N")]
    em_iterations: Option<u32>,
    /// vmf, tan2005: EM stops when the mean log-likelihood per normal changes by at most
    /// this (relative above 1 nat), 0 to 1 [default: 1e-6]. Exact mode and Tan 2005 use it as
    /// given; fast and balanced keep their own 1e-4 unless this is higher.
    #[arg(long, value_name = "T")]
    em_tolerance: Option<f64>,
}

impl EmArgs {
    /// The EM options they give, defaults filled in, checked against their ranges before any
    /// work (an error names the option).
    fn checked(&self) -> Result<ndfmap::em::EmOptions> {
        let d = ndfmap::em::EmOptions::default();
        let em = ndfmap::em::EmOptions {
            max_iterations: self.em_iterations.unwrap_or(d.max_iterations),
            tolerance: self.em_tolerance.unwrap_or(d.tolerance),
            ..d
        };
        let options = BakeOptions {
            em,
            ..BakeOptions::default()
        };
        ndfmap::methods::check_options(Method::Vmf, &options, false, None).map_err(
            |e| match e {
                Error::InvalidOption(m) => {
                    let flag = if m.starts_with("EM iterations") {
                        "iterations"
                    } else {
                        "tolerance"
                    };
                    Error::InvalidOption(format!("--em-{flag}: {m}"))
                }
                e => e,
            },
        )?;
        Ok(em)
    }
}

/// The BRDF of `bake` (it picks SH's band limit when --lmax is not given).
#[derive(Args)]
struct BrdfArgs {
    /// sh without --lmax: the BRDF the bake is meant for, which chooses l*: lambert (the
    /// default), blinn-phong, torrance-sparrow, ggx, or a tabulated BRDF file (JSON).
    #[arg(long)]
    brdf: Option<String>,
    /// Blinn-Phong exponent [default: 64].
    #[arg(short, long = "exponent")]
    s: Option<f64>,
    /// Torrance–Sparrow roughness σ (eq 18) [default: 0.1].
    #[arg(long)]
    sigma: Option<f64>,
    /// GGX roughness α [default: 0.1].
    #[arg(long)]
    alpha: Option<f64>,
}

impl BrdfArgs {
    /// Whether any of the options was given.
    fn given(&self) -> bool {
        self.brdf.is_some() || self.s.is_some() || self.sigma.is_some() || self.alpha.is_some()
    }

    /// The BRDF they name, defaults filled in.
    fn brdf(&self) -> Result<Brdf> {
        parse_brdf(
            self.brdf.as_deref().unwrap_or("lambert"),
            self.s.unwrap_or(64.0),
            self.sigma.unwrap_or(0.1),
            self.alpha.unwrap_or(0.1),
        )
    }
}

/// The PBR bake's options (`--method pbr`).
#[derive(Args)]
struct PbrArgs {
    /// pbr: the base perceptual roughness √α (glTF's), 0 to 1, for every texel (default 0.5).
    #[arg(long, conflicts_with = "roughness_map")]
    roughness: Option<f64>,
    /// pbr: a roughness map (perceptual √α, linear data: the G channel of an RGB(A) image in
    /// glTF's metallic-roughness layout, or a grey image), the normal map's size.
    #[arg(long)]
    roughness_map: Option<PathBuf>,
    /// pbr: a metallic map packed into B (B of an RGB(A) image, or grey); needs --roughness
    /// or --roughness-map given explicitly.
    #[arg(long)]
    metallic_map: Option<PathBuf>,
    /// pbr: an occlusion map packed into R (R of an RGB(A) image, or grey).
    #[arg(long)]
    occlusion_map: Option<PathBuf>,
    /// pbr: fit an anisotropic GGX lobe per texel and write KHR_materials_anisotropy's texture.
    #[arg(long)]
    anisotropic: bool,
    /// pbr: the widest view and light angle from the normal your renderer shows, in degrees
    /// (20 to 90): the fit's light/view pairs are scaled into that range (default: the
    /// standard pairs, grazing ones to 74° included).
    #[arg(long, value_name = "DEG")]
    fit_max_angle: Option<f64>,
    /// pbr: keep every level's normal at the footprint's mean direction (the plain MIP
    /// chain's normal) and fit only the roughness: for engines that make their own normal
    /// mips, or mostly diffuse materials (the fitted normal serves the specular lobe).
    #[arg(long)]
    mean_normal: bool,
}

impl PbrArgs {
    /// Whether a material map (`--roughness-map`, `--metallic-map`, `--occlusion-map`) is given.
    fn maps_given(&self) -> bool {
        self.roughness_map.is_some() || self.metallic_map.is_some() || self.occlusion_map.is_some()
    }

    /// Whether a PBR option other than the maps is given (`--roughness`, `--anisotropic`,
    /// `--fit-max-angle`, `--mean-normal`).
    fn options_given(&self) -> bool {
        self.roughness.is_some()
            || self.anisotropic
            || self.fit_max_angle.is_some()
            || self.mean_normal
    }

    /// The material maps, read and checked against a `w`×`h` map; warns (stderr) of an sRGB-
    /// flagged PNG, which is read as linear.
    fn maps(&self, w: u32, h: u32, opts: &ndfmap::IngestOptions) -> Result<ndfmap::pbr::PbrMaps> {
        use ndfmap::pbr::{MapChannel, load_map};
        let read = |p: &Option<PathBuf>, c: MapChannel| -> Result<Option<Vec<f32>>> {
            let Some(p) = p else { return Ok(None) };
            // Another size is refused from the file's header, before its pixels are decoded.
            let m = load_map(p, opts, c, Some((w, h)))?;
            if m.srgb_flagged {
                eprintln!(
                    "warning: {}: flagged sRGB, but roughness, metallic and occlusion are linear \
                     data: read as stored (linear)",
                    p.display()
                );
            }
            Ok(Some(m.values))
        };
        let maps = ndfmap::pbr::PbrMaps {
            roughness: read(&self.roughness_map, MapChannel::Roughness)?,
            metallic: read(&self.metallic_map, MapChannel::Metallic)?,
            occlusion: read(&self.occlusion_map, MapChannel::Occlusion)?,
        };
        let name = |p: &Option<PathBuf>| p.as_ref().map(|p| p.display().to_string());
        // Name the file in the error, not the map's role.
        for (p, m) in [
            (&self.roughness_map, &maps.roughness),
            (&self.metallic_map, &maps.metallic),
            (&self.occlusion_map, &maps.occlusion),
        ] {
            if let (Some(p), Some(m)) = (name(p), m) {
                let one = ndfmap::pbr::PbrMaps {
                    roughness: Some(m.clone()),
                    ..Default::default()
                };
                one.check(w, h).map_err(|e| match e {
                    Error::BadFeatures {
                        count, kind, x, y, ..
                    } => Error::BadFeatures {
                        what: p.clone(),
                        count,
                        kind,
                        x,
                        y,
                    },
                    e => e,
                })?;
            }
        }
        Ok(maps)
    }
}

/// One BRDF from its name or file: `lambert`, `blinn-phong` (exponent `s`),
/// `torrance-sparrow` (`sigma`), `ggx` (`alpha`), or the path of a tabulated BRDF (JSON).
fn parse_brdf(name: &str, s: f64, sigma: f64, alpha: f64) -> Result<Brdf> {
    let b = match name.trim() {
        "lambert" => Brdf::Lambert,
        "blinn-phong" => Brdf::BlinnPhong { s },
        "torrance-sparrow" => Brdf::TorranceSparrow { sigma },
        "ggx" => Brdf::ggx(alpha),
        path => {
            let p = Path::new(path);
            if !p.exists() {
                return Err(Error::InvalidOption(format!(
                    "--brdf '{path}' (expected lambert, blinn-phong, torrance-sparrow, ggx or a \
                     tabulated BRDF file)"
                )));
            }
            Brdf::Tabulated(std::sync::Arc::new(ndfmap::brdf::Tabulated::load(p)?))
        }
    };
    b.validate()?;
    Ok(b)
}

/// Parses a lower-case option value into one of the library's serde enums.
fn choice<T: serde::de::DeserializeOwned>(option: &str, value: &str, allowed: &str) -> Result<T> {
    serde_json::from_value(serde_json::Value::String(value.to_ascii_lowercase())).map_err(|_| {
        Error::InvalidOption(format!("--{option} '{value}' (expected one of: {allowed})"))
    })
}

impl IngestArgs {
    fn options(&self) -> Result<IngestOptions> {
        Ok(IngestOptions {
            green: choice::<GreenChannel>("green", &self.green, "opengl, directx")?,
            encoding: choice::<Encoding>("encoding", &self.encoding, "auto, unorm, snorm")?,
            channels: choice::<Channels>("channels", &self.channels, "auto, xyz, xy")?,
            addressing: choice::<Addressing>("addressing", &self.addressing, "wrap, clamp")?,
            bad_normals: choice::<BadNormals>("bad-normals", &self.bad_normals, "repair, reject")?,
            feature_encoding: choice::<FeatureEncoding>(
                "feature-encoding",
                &self.feature_encoding,
                "srgb, linear",
            )?,
            memory_limit: self.memory_limit()?,
        })
    }

    /// The `--memory` budget in bytes, `None` for the default.
    fn memory_limit(&self) -> Result<Option<u64>> {
        self.memory
            .as_deref()
            .map(ndfmap::budget::parse_bytes)
            .transpose()
            .map_err(|e| match e {
                Error::InvalidOption(m) => Error::InvalidOption(format!("--memory: {m}")),
                e => e,
            })
    }

    fn load(&self, input: &Path) -> Result<(NormalMap, InputInfo)> {
        let options = self.options()?;
        let mut map = NormalMap::load(input, &options)?;
        if let Some(feature) = &self.feature {
            map = map.with_feature_file(feature, &options)?;
        }
        let info = InputInfo {
            path: Some(input.display().to_string()),
            options,
            stats: map.stats().clone(),
        };
        Ok((map, info))
    }
}

/// `ndfmap plan`: everything is checked (scene, map, albedo) before anything is written.
fn plan_cmd(
    scene_path: &Path,
    input: &Path,
    output: Option<&Path>,
    explain: bool,
    verify: bool,
    ingest: &IngestArgs,
) -> Result<()> {
    #[cfg(not(feature = "report"))]
    if verify {
        return Err(Error::InvalidOption(
            "plan --verify needs ndfmap built with the `report` feature".into(),
        ));
    }
    let mut scene = ndfmap::plan::Scene::load(scene_path)?;
    // An environment file is named relative to the scene file.
    if let Some(env) = &scene.environment
        && !matches!(env.as_str(), "sky" | "overcast")
        && Path::new(env).is_relative()
    {
        let path = scene_path.parent().unwrap_or(Path::new(".")).join(env);
        scene.environment = Some(path.display().to_string());
    }
    let (mut map, _) = ingest.load(input)?;
    if let Some(albedo) = &scene.color.albedo {
        if ingest.feature.is_some() {
            return Err(Error::InvalidOption(
                "scene: field 'color.albedo': given, and --feature too: give one".into(),
            ));
        }
        let path = scene_path.parent().unwrap_or(Path::new(".")).join(albedo);
        map = map.with_feature_file(&path, &ingest.options()?)?;
    }
    let plan = ndfmap::plan::plan(&map, &scene, Some(&input.display().to_string()))?;
    let addressing = map.addressing();
    let shaders: Vec<String> = (0..plan.parts.len())
        .map(|i| plan.shader(i, addressing))
        .collect::<Result<_>>()?;
    // The one shader switching method by LOD, where it is built (else the reason, printed).
    let switch = match plan.lod_switch_shader(addressing) {
        Ok(s) => {
            if let Some(c) = plan.lod_switch_caution(addressing) {
                eprintln!("note: {c}");
            }
            Some(s)
        }
        Err(e) => {
            eprintln!("note: no LOD-switching shader (lod_switch.frag): {e}");
            None
        }
    };
    if explain {
        print!("{}", plan.explain());
    }
    // Measured before anything is written, so that verify.json goes into the folder with the
    // plan.
    #[cfg(feature = "report")]
    let verified = if verify {
        Some(ndfmap::report::planner::measure(&plan, &map)?)
    } else {
        None
    };
    match output {
        Some(dir) => {
            // The folder is written as a whole (staged, then renamed into place): a failure
            // leaves it as it was.
            let mut files = vec![
                ("plan.json".to_string(), plan.to_json()),
                ("explain.txt".to_string(), plan.explain()),
            ];
            for (i, s) in shaders.iter().enumerate() {
                files.push((format!("part{i}.frag"), s.clone()));
            }
            if let Some(s) = &switch {
                files.push((ndfmap::plan::LOD_SWITCH_FILE.to_string(), s.clone()));
            }
            #[cfg(feature = "report")]
            if let Some(row) = &verified {
                let json = serde_json::to_string_pretty(row).unwrap_or_default();
                files.push(("verify.json".to_string(), json));
            }
            ndfmap::plan::write_plan_folder(dir, &files)?;
            println!(
                "planned in {:.2} s: {} part(s), {} texture bytes (full: {}): {}",
                plan.seconds,
                plan.parts.len(),
                plan.bytes,
                plan.full_bytes,
                dir.join("plan.json").display()
            );
        }
        None if !explain && !verify => print!("{}", plan.to_json()),
        None => {}
    }
    #[cfg(feature = "report")]
    if let Some(row) = verified {
        let name = scene_path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        println!(
            "| scene | plan | bytes plan / full | bake s plan / full | fetches plan / full | ALU \
             plan / full | plan s | meets target | prediction factor |\n|---|---|---|---|---|---|---|---|---|"
        );
        print!("{}", row.markdown(&name));
    }
    Ok(())
}

/// `ndfmap bake --plan`: the plan is read and checked against the map before any work.
fn bake_plan(plan_path: &Path, input: &Path, output: &Path, ingest: &IngestArgs) -> Result<()> {
    let text = ndfmap::ingest::read_text_file(plan_path)?;
    let name = plan_path.display().to_string();
    // Serde's message may quote a key or value of any length: a few hundred characters
    // beyond the name are kept, so a megabyte-long value still makes one readable line.
    let plan = ndfmap::plan::Plan::from_json(&name, &text).map_err(|e| match e {
        Error::InvalidOption(m) => Error::InvalidOption(ndfmap::error::clip_message(
            &m,
            name.chars().count() + ndfmap::error::MAX_PARSE_ERROR_CHARS,
        )),
        e => e,
    })?;
    let (w, h) = ndfmap::ingest::probe_size(input, &ingest.options()?)?;
    if (w, h) != (plan.map.width, plan.map.height) {
        return Err(Error::InvalidOption(format!(
            "{}: the plan was made for a {}x{} map, {} is {w}x{h}",
            plan_path.display(),
            plan.map.width,
            plan.map.height,
            input.display()
        )));
    }
    let (map, info) = ingest.load(input)?;
    let t = Instant::now();
    let baked = ndfmap::plan::execute(&plan, &map).map_err(|e| match e {
        Error::InvalidOption(m) => Error::InvalidOption(format!("{}: {m}", plan_path.display())),
        e => e,
    })?;
    let seconds = t.elapsed().as_secs_f64();
    let manifest = ndfmap::plan::write(&plan, &baked, info, output)?;
    println!(
        "baked the plan ({} part(s)) in {seconds:.3} s: {}",
        plan.parts.len(),
        manifest.display()
    );
    Ok(())
}

fn parse_methods(names: &[String]) -> Result<Vec<Method>> {
    names.iter().map(|n| n.trim().parse()).collect()
}

fn check_exponents(s: &[f64]) -> Result<()> {
    match s.iter().find(|s| !(s.is_finite() && **s > 0.0)) {
        Some(bad) => Err(Error::InvalidOption(format!(
            "Blinn-Phong exponent {} (must be finite and > 0)",
            compact_f64(*bad)
        ))),
        None if s.is_empty() => Err(Error::InvalidOption("no Blinn-Phong exponent given".into())),
        None => Ok(()),
    }
}

/// The BRDFs `eval` measures (see its `--brdf`): each model of `names` with each of its
/// parameters, or without `names` Blinn-Phong for each `s`, eq 18 for each `sigma` and GGX for
/// each `alpha`; GGX once per widening constant of `ggx_c` (the library's when empty).
fn eval_brdfs(
    names: &[String],
    s: &[f64],
    sigma: &[f64],
    alpha: &[f64],
    ggx_g: bool,
    ggx_c: &[f64],
) -> Result<Vec<Brdf>> {
    let or = |v: &[f64], d: f64| if v.is_empty() { vec![d] } else { v.to_vec() };
    let mut out = Vec::new();
    let ggx = |alphas: &[f64], out: &mut Vec<Brdf>| {
        let cs = or(ggx_c, ndfmap::brdf::GGX_WIDENING_C);
        for &a in alphas {
            for &c in &cs {
                out.push(Brdf::Ggx(ndfmap::brdf::Ggx {
                    g: ggx_g,
                    widening: c,
                    ..ndfmap::brdf::Ggx::new(a)
                }));
            }
        }
    };
    if names.is_empty() {
        out.extend(s.iter().map(|&s| Brdf::BlinnPhong { s }));
        out.extend(sigma.iter().map(|&sigma| Brdf::TorranceSparrow { sigma }));
        ggx(alpha, &mut out);
    } else {
        for name in names {
            match name.trim() {
                "lambert" => out.push(Brdf::Lambert),
                "blinn-phong" => out.extend(s.iter().map(|&s| Brdf::BlinnPhong { s })),
                "torrance-sparrow" => out.extend(
                    or(sigma, 0.1)
                        .into_iter()
                        .map(|sigma| Brdf::TorranceSparrow { sigma }),
                ),
                "ggx" => ggx(&or(alpha, 0.1), &mut out),
                file => out.push(parse_brdf(file, 1.0, 1.0, 1.0)?),
            }
        }
    }
    for b in &out {
        b.validate()?;
    }
    if out.is_empty() {
        return Err(Error::InvalidOption("no BRDF to measure".into()));
    }
    Ok(out)
}

fn print_info(map: &NormalMap) {
    let s = map.stats();
    println!(
        "{}x{} texels, {} channel(s) of {} bits, {:?} encoding{}",
        s.width,
        s.height,
        s.source_channels,
        s.source_bits,
        s.encoding,
        if s.reconstructed_z {
            ", z reconstructed"
        } else {
            ""
        }
    );
    println!(
        "mean z {:.4}, mean length before renormalizing {:.4}",
        s.mean_z, s.mean_length
    );
    for (name, c) in [
        ("zero-length", s.zero_length),
        ("NaN", s.nan),
        ("below the horizon", s.below_horizon),
    ] {
        match c.first {
            Some((x, y)) => println!("{} {name} normal(s), the first at x={x}, y={y}", c.count),
            None => println!("0 {name} normals"),
        }
    }
}

/// Parses `--align` values: `none`, `default` (`form`'s usual strength,
/// [`AlignmentForm::default_strength`]) or a strength C.
fn parse_align(values: &[String], form: AlignmentForm) -> Result<Vec<Option<f64>>> {
    values
        .iter()
        .map(|v| match v.trim() {
            "none" => Ok(None),
            "default" => Ok(Some(form.default_strength())),
            c => c
                .parse::<f64>()
                .ok()
                .filter(|c| c.is_finite() && *c >= 0.0)
                .map(Some)
                .ok_or_else(|| {
                    Error::InvalidOption(format!(
                        "--align '{c}' (expected none, default or C >= 0)"
                    ))
                }),
        })
        .collect()
}

/// The mixture variants to bake: every combination of lobe count, alignment and fitting mode;
/// and SH's band limits.
struct MixtureGrid {
    lobes: Vec<usize>,
    align: Vec<Option<f64>>,
    align_form: AlignmentForm,
    /// vMF fitting modes.
    modes: Vec<FitMode>,
    /// The memory budget of every bake (`--memory`).
    memory_limit: Option<u64>,
    /// SH band limits.
    lmax: Vec<usize>,
    /// EM options of every mixture bake (`--em-iterations`, `--em-tolerance`).
    em: ndfmap::em::EmOptions,
}

impl MixtureGrid {
    fn parse(lobes: &[usize], align: &[String], form: &str, modes: &[String]) -> Result<Self> {
        let modes = modes
            .iter()
            .map(|m| m.parse())
            .collect::<Result<Vec<FitMode>>>()?;
        let align_form: AlignmentForm = form.parse()?;
        Ok(MixtureGrid {
            lobes: lobes.to_vec(),
            align: parse_align(align, align_form)?,
            align_form,
            modes,
            memory_limit: None,
            lmax: vec![BakeOptions::default().lmax],
            em: ndfmap::em::EmOptions::default(),
        })
    }

    fn options(&self, method: Method) -> Vec<BakeOptions> {
        let mut out = Vec::new();
        for &lobes in &self.lobes {
            for &align in &self.align {
                for (i, &mode) in self.modes.iter().enumerate() {
                    if i > 0 && method != Method::Vmf {
                        continue; // Tan 2005 has no fitting modes: one bake
                    }
                    out.push(BakeOptions {
                        lobes,
                        align,
                        align_form: self.align_form,
                        mode,
                        em: self.em,
                        memory_limit: self.memory_limit,
                        ..BakeOptions::default()
                    });
                }
            }
        }
        out
    }
}

/// Bakes every method in `methods` (mixtures once per variant of `mixtures`), printing the time
/// each took to stderr unless `quiet`.
fn bake_all(
    map: &NormalMap,
    methods: &[Method],
    mixtures: &MixtureGrid,
    quiet: bool,
) -> Result<Vec<Bake>> {
    let mut jobs = Vec::new();
    for &m in methods {
        if matches!(m, Method::Vmf | Method::Tan2005) {
            for o in mixtures.options(m) {
                jobs.push((m, o));
            }
        } else if m == Method::Sh {
            for &lmax in &mixtures.lmax {
                jobs.push((
                    m,
                    BakeOptions {
                        lmax,
                        ..BakeOptions::default()
                    },
                ));
            }
        } else {
            jobs.push((
                m,
                BakeOptions {
                    memory_limit: mixtures.memory_limit,
                    ..BakeOptions::default()
                },
            ));
        }
    }
    jobs.into_iter()
        .map(|(m, o)| {
            let t = Instant::now();
            let b = bake_with(map, m, &o)?;
            if !quiet {
                eprintln!(
                    "baked {:<8} in {:.3} s",
                    b.label(),
                    t.elapsed().as_secs_f64()
                );
            }
            Ok(b)
        })
        .collect()
}

/// `ndfmap bake`'s arguments.
#[derive(Args)]
struct BakeCommand {
    /// The normal maps (PNG, JPEG, TGA, TIFF, OpenEXR), or glob patterns (quoted).
    inputs: Vec<PathBuf>,
    /// A batch file (TOML, or JSON when it ends in .json): `[defaults]` and `[[input]]`
    /// tables with `path`, `output`, `method`, `feature` and any option's name (see
    /// docs/batch.md); unknown keys are refused.
    #[arg(long)]
    batch: Option<PathBuf>,
    /// Bake even inputs whose output is complete and current.
    #[arg(long)]
    force: bool,
    /// Bake nothing: print each input's content hash, `current` or `stale`, and its
    /// output folder (one line each); the exit status is the number of stale or
    /// unreadable inputs (at most 125). For build systems that key on the hash.
    #[arg(long)]
    check: bool,
    /// Most bakes running at once (default: the number of cores; each bake also uses
    /// every core).
    #[arg(long, default_value_t = 0)]
    jobs: usize,
    /// Filtering method: plain, toksvig, lean, olano, tan2005, vmf, sh, pbr (a batch file
    /// may set it per input).
    #[arg(short, long)]
    method: Option<String>,
    /// A plan file from `ndfmap plan` (docs/planner.md): bake what it says for the one
    /// input, mixing methods across level ranges, instead of one --method (the method
    /// options are then refused).
    #[arg(long, conflicts_with_all = ["method", "batch"])]
    plan: Option<PathBuf>,
    /// Output folder (created if missing; written all-or-nothing). With several inputs,
    /// the folder that holds one folder per input, named after the input's file stem.
    #[arg(short, long)]
    output: Option<PathBuf>,
    /// vmf, tan2005: lobes (mixture components) per texel, 1 to 8 [default: 6].
    #[arg(long)]
    lobes: Option<usize>,
    /// vmf, tan2005: coherent lobes for hardware trilinear filtering, with alignment
    /// strength C; `--align` alone takes the method's usual C (vMF eq 29: 0.03, eq 23: 0.1;
    /// Tan's prior: c = 1). Without it lobes are fitted per texel (unaligned).
    #[arg(long, num_args = 0..=1, value_name = "C")]
    align: Option<Option<f64>>,
    /// vmf: the alignment's M-step, `appendix` (eq 29: the pull on a lobe shrinks as
    /// 1/(κα), so sharp lobes stay on their normals) or `main-text` (eq 23: the same pull
    /// for every lobe) [default: appendix].
    #[arg(long)]
    align_form: Option<String>,
    /// vmf: how hard each texel is fitted: `fast` (3 EM iterations), `balanced` (the
    /// default: at most 8, and the EM cap in the aligned pass on texels of 256 normals or more,
    /// level 4 and coarser, and in the unaligned pass too from 4096, level 6) or `exact` (the
    /// EM options as given: 20 iterations, tolerance 1e-6).
    #[arg(long)]
    mode: Option<String>,
    #[command(flatten)]
    em: EmArgs,
    /// sh: band limit l* (0 to 16; (l*+1)² coefficients, four per texture). Without it,
    /// chosen from --brdf: 2 for Lambert, about √(4s) for Blinn-Phong (Sec 5.1).
    #[arg(long)]
    lmax: Option<usize>,
    #[command(flatten)]
    brdf: BrdfArgs,
    /// Texel format of the files: f32 or f16 (OpenEXR), unorm16 or unorm8 (PNG).
    #[arg(long, default_value = "f32")]
    format: String,
    /// Files: exr (OpenEXR or PNG per texture per level), ktx2 or dds (one file per
    /// texture with its whole MIP chain).
    #[arg(long, default_value = "exr")]
    container: String,
    /// Block compression of ktx2/dds files: bc6h, bc7 or bc5 (where the textures' channels
    /// and ranges allow; refused before any work otherwise).
    #[arg(long)]
    compress: Option<String>,
    #[command(flatten)]
    pbr: PbrArgs,
    #[command(flatten)]
    ingest: IngestArgs,
}

/// A batch job's error on one line, led by its input's name unless the error already starts
/// with it (a read or decode error names its file).
fn job_error(input: &Path, e: &Error) -> String {
    let text = e.to_string();
    let input = input.display().to_string();
    if text.starts_with(&format!("{input}: ")) {
        one_line(&text)
    } else {
        one_line(&format!("{input}: {text}"))
    }
}

/// `ndfmap bake`: one input into `-o`, or many (files, globs, a batch file) each into its own
/// folder, through `ndfmap::batch`. Returns the number of failed inputs (0 for one input:
/// its failure is the command's error).
fn bake_command(a: BakeCommand) -> Result<u8> {
    use ndfmap::batch::{Outcome, RunOptions, Settings};
    let pbr_maps = a.pbr.maps_given();
    let pbr_flags = pbr_maps || a.pbr.options_given();
    let method: Option<Method> = a.method.as_deref().map(str::parse).transpose()?;
    if pbr_flags && method.is_some_and(|m| m != Method::Pbr) {
        return Err(Error::InvalidOption(
            "--roughness, --roughness-map, --metallic-map, --occlusion-map, \
             --anisotropic, --fit-max-angle and --mean-normal are for --method pbr"
                .into(),
        ));
    }
    if a.pbr.metallic_map.is_some() && a.pbr.roughness_map.is_none() && a.pbr.roughness.is_none() {
        return Err(Error::InvalidOption(
            "--metallic-map without a roughness: the packed texture's G channel is the \
             roughness; give --roughness R or --roughness-map IMG"
                .into(),
        ));
    }
    // SH without --lmax: the band limit the BRDF suggests (Sec 5.1). That is all the BRDF
    // options do in a bake, so they are refused where they cannot.
    if a.brdf.given() && (method != Some(Method::Sh) || a.lmax.is_some()) {
        return Err(Error::InvalidOption(
            "--brdf, --exponent, --sigma and --alpha only choose --lmax for --method sh \
             (give them with -m sh and without --lmax)"
                .into(),
        ));
    }
    let lmax = match (method, a.lmax) {
        (_, Some(l)) => Some(l),
        (Some(Method::Sh), None) => {
            let b = a.brdf.brdf()?;
            let l = b.suggested_lmax();
            eprintln!(
                "no --lmax: l* = {l} chosen for {b} ({})",
                if b.has_specular() {
                    "about √(4s) of the equivalent Blinn-Phong exponent, Sec 5.1"
                } else {
                    "Lambert: nine coefficients, Ramamoorthi & Hanrahan"
                }
            );
            Some(l)
        }
        (_, None) => None,
    };
    let memory = a.ingest.memory_limit()?;
    a.ingest.options()?; // every ingest flag parses
    // The command line's values parse, and a bad one is named as its option (the jobs would
    // name it as a batch file's key).
    let option = |name: &'static str| {
        move |e: Error| match e {
            Error::InvalidOption(m) => Error::InvalidOption(format!("--{name}: {m}")),
            e => e,
        }
    };
    a.format.parse::<Format>().map_err(option("format"))?;
    a.container
        .parse::<ndfmap::container::Container>()
        .map_err(option("container"))?;
    if let Some(c) = &a.compress {
        c.parse::<ndfmap::compress::Codec>()
            .map_err(option("compress"))?;
    }
    if let Some(f) = &a.align_form {
        f.parse::<AlignmentForm>().map_err(option("align-form"))?;
    }
    if let Some(m) = &a.mode {
        m.parse::<FitMode>().map_err(option("mode"))?;
    }
    a.em.checked()?;
    let base = Settings {
        feature: a.ingest.feature.as_ref().map(|f| f.display().to_string()),
        method: a.method.clone(),
        lobes: a.lobes,
        align: a.align.map(|c| match c {
            Some(c) => ndfmap::batch::AlignSetting::Strength(c),
            None => ndfmap::batch::AlignSetting::Name("default".into()),
        }),
        align_form: a.align_form.clone(),
        mode: a.mode.clone(),
        em_iterations: a.em.em_iterations,
        em_tolerance: a.em.em_tolerance,
        lmax,
        roughness: a.pbr.roughness,
        anisotropic: Some(a.pbr.anisotropic),
        fit_max_angle: a.pbr.fit_max_angle,
        mean_normal: Some(a.pbr.mean_normal),
        format: Some(a.format.clone()),
        container: Some(a.container.clone()),
        compress: a.compress.clone(),
        green: Some(a.ingest.green.clone()),
        encoding: Some(a.ingest.encoding.clone()),
        channels: Some(a.ingest.channels.clone()),
        addressing: Some(a.ingest.addressing.clone()),
        bad_normals: Some(a.ingest.bad_normals.clone()),
        feature_encoding: Some(a.ingest.feature_encoding.clone()),
        ..Settings::default()
    };
    // Options `--method` would ignore are refused (`-m plain --lobes 4`). In a batch, each
    // entry's method decides (its own keys are checked; the command line's are defaults that
    // may be meant for other entries).
    if let Some(m) = method.filter(|_| a.batch.is_none()) {
        let stray = base.keys_for_other_methods(m);
        if !stray.is_empty() {
            let names: Vec<String> = stray
                .iter()
                .map(|(k, _)| format!("--{}", k.replace('_', "-")))
                .collect();
            let mut for_methods: Vec<&str> = stray.iter().map(|&(_, f)| f).collect();
            for_methods.dedup();
            return Err(Error::InvalidOption(format!(
                "{} {} not apply to --method {} (for {})",
                names.join(", "),
                if names.len() == 1 { "does" } else { "do" },
                m.name(),
                for_methods.join("; ")
            )));
        }
    }
    let inputs = ndfmap::batch::expand_inputs(&a.inputs)?;
    let single = a.batch.is_none() && inputs.len() == 1;
    if pbr_maps {
        if !single {
            return Err(Error::InvalidOption(
                "the PBR material maps (--roughness-map, --metallic-map, --occlusion-map) \
                 belong to one input: bake it alone"
                    .into(),
            ));
        }
        return bake_pbr_with_maps(&a, &inputs[0]).map(|()| 0);
    }
    let mut jobs = Vec::new();
    if let Some(file) = &a.batch {
        let text = ndfmap::ingest::read_text_file(file)?;
        let json = file
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("json"));
        let dir = file.parent().unwrap_or(Path::new("."));
        jobs = ndfmap::batch::parse_batch(
            &file.display().to_string(),
            &text,
            json,
            &base,
            dir,
            a.output.as_deref(),
            memory,
        )?;
    }
    for input in &inputs {
        let entry = base.overlay(&Settings {
            path: Some(input.display().to_string()),
            // One input alone is written into -o itself, as always.
            output: single
                .then(|| a.output.as_ref().map(|o| o.display().to_string()))
                .flatten(),
            ..Settings::default()
        });
        jobs.push(entry.job(Path::new(""), a.output.as_deref(), memory)?);
    }
    if jobs.is_empty() {
        return Err(Error::InvalidOption(
            "no input: give normal maps, glob patterns or --batch FILE".into(),
        ));
    }
    if a.check {
        let mut stale = 0usize;
        for job in &jobs {
            match job.hash() {
                Ok(hash) => {
                    let current = ndfmap::batch::is_up_to_date(&job.output, &hash);
                    stale += usize::from(!current);
                    println!(
                        "{hash} {} {} {}",
                        if current { "current" } else { "stale" },
                        job.input.display(),
                        job.output.display()
                    );
                }
                Err(e) => {
                    stale += 1;
                    eprintln!("ndfmap: error: {}", job_error(&job.input, &e));
                }
            }
        }
        return Ok(stale.min(125) as u8);
    }
    let run_options = RunOptions {
        memory,
        workers: a.jobs,
        force: a.force,
    };
    if single {
        let outcome = ndfmap::batch::run(&jobs, &run_options, &|_| {}, &|_, _| {})
            .pop()
            .expect("one outcome per job");
        let m = jobs[0].method;
        match outcome {
            Outcome::Baked { manifest, seconds } => {
                println!("baked {m} in {seconds:.3} s: {}", manifest.display())
            }
            Outcome::UpToDate { manifest } => {
                println!(
                    "up to date (same input, options and version): {}",
                    manifest.display()
                )
            }
            Outcome::Failed(e) => return Err(e),
        }
        return Ok(0);
    }
    let started = Instant::now();
    #[cfg(feature = "report")]
    let bar = {
        let bar = indicatif::ProgressBar::new(jobs.len() as u64);
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "{elapsed_precise} [{bar:30}] {pos}/{len} eta {eta} {msg}",
            )
            .expect("valid template")
            .progress_chars("=> "),
        );
        bar
    };
    // Lines print above the bar (or alone when stderr is not a terminal): errors to stderr,
    // the rest to stdout.
    let say = |line: String, error: bool| {
        let print = || {
            if error {
                eprintln!("{line}")
            } else {
                println!("{line}")
            }
        };
        #[cfg(feature = "report")]
        bar.suspend(print);
        #[cfg(not(feature = "report"))]
        print();
    };
    let outcomes = ndfmap::batch::run(
        &jobs,
        &run_options,
        &|i| {
            #[cfg(feature = "report")]
            bar.set_message(jobs[i].input.display().to_string());
            #[cfg(not(feature = "report"))]
            let _ = i;
        },
        &|i, outcome| {
            let input = jobs[i].input.display();
            match outcome {
                Outcome::Baked { manifest, seconds } => say(
                    format!("baked {input} in {seconds:.2} s: {}", manifest.display()),
                    false,
                ),
                Outcome::UpToDate { manifest } => {
                    say(format!("up to date {input}: {}", manifest.display()), false)
                }
                Outcome::Failed(e) => say(
                    format!("ndfmap: error: {}", job_error(&jobs[i].input, e)),
                    true,
                ),
            }
            #[cfg(feature = "report")]
            bar.inc(1);
        },
    );
    #[cfg(feature = "report")]
    bar.finish_and_clear();
    let count = |f: fn(&Outcome) -> bool| outcomes.iter().filter(|o| f(o)).count();
    let baked = count(|o| matches!(o, Outcome::Baked { .. }));
    let current = count(|o| matches!(o, Outcome::UpToDate { .. }));
    let failed = count(Outcome::failed);
    println!(
        "{} inputs in {:.1} s: {baked} baked, {current} up to date, {failed} failed",
        jobs.len(),
        started.elapsed().as_secs_f64()
    );
    Ok(failed.min(125) as u8)
}

/// The PBR bake with material maps, for one input (as before batches; no content hash: the
/// maps are inputs the hash does not cover).
fn bake_pbr_with_maps(a: &BakeCommand, input: &Path) -> Result<()> {
    let Some(output) = &a.output else {
        return Err(Error::InvalidOption("no output folder: give -o DIR".into()));
    };
    let format: Format = a.format.parse()?;
    let options = BakeOptions {
        memory_limit: a.ingest.memory_limit()?,
        pbr: ndfmap::bake::PbrOptions {
            roughness: a.pbr.roughness.unwrap_or(0.5),
            anisotropic: a.pbr.anisotropic,
            fit_max_angle: a.pbr.fit_max_angle,
            mean_normal: a.pbr.mean_normal,
        },
        ..BakeOptions::default()
    };
    let color = a.ingest.feature.is_some();
    ndfmap::methods::check_options(Method::Pbr, &options, color, Some(format))?;
    let container: ndfmap::container::Container = a.container.parse()?;
    let codec = a
        .compress
        .as_deref()
        .map(|c| c.parse::<ndfmap::compress::Codec>())
        .transpose()?;
    ndfmap::container::check(container, Method::Pbr, 0, color, format, codec)?;
    let (w, h) = ndfmap::ingest::probe_size(input, &a.ingest.options()?)?;
    ndfmap::methods::check_memory(w, h, Method::Pbr, &options, color)?;
    let (map, info) = a.ingest.load(input)?;
    let t = Instant::now();
    let maps = a
        .pbr
        .maps(map.width(), map.height(), &a.ingest.options()?)?;
    let b = ndfmap::pbr::bake_with_maps(&map, &options.pbr, Some(&maps))?;
    drop(map);
    let b = ndfmap::pack::quantize_into(b, format)?;
    let seconds = t.elapsed().as_secs_f64();
    let manifest = ndfmap::container::write_bake(&b, info, output, container, codec)?;
    println!("baked pbr in {seconds:.3} s: {}", manifest.display());
    Ok(())
}

/// Runs the command; the exit status (0, or the number of failed inputs of a batch bake).
fn run(cli: Cli) -> Result<u8> {
    let mut status = 0u8;
    match cli.command {
        Command::Info { input, ingest } => {
            let (map, _) = ingest.load(&input)?;
            print_info(&map);
        }
        Command::Bake(mut a) => match a.plan.take() {
            Some(plan_path) => {
                let BakeCommand {
                    inputs,
                    force,
                    check,
                    jobs,
                    output,
                    lobes,
                    align,
                    align_form,
                    mode,
                    lmax,
                    brdf,
                    format,
                    pbr,
                    container,
                    compress,
                    ingest,
                    ..
                } = a;
                let defaults = (None, None, None, None, None, "f32", "exr", None);
                if (
                    lobes,
                    align,
                    align_form.as_deref(),
                    mode.as_deref(),
                    lmax,
                    format.as_str(),
                    container.as_str(),
                    compress.as_deref(),
                ) != defaults
                    || pbr.options_given()
                    || brdf.given()
                {
                    return Err(Error::InvalidOption(
                        "--plan decides the method, lobes, alignment, band limit, format and \
                         container: give none of those options with it"
                            .into(),
                    ));
                }
                let ([input], false, false, 0) = (inputs.as_slice(), force, check, jobs) else {
                    return Err(Error::InvalidOption(
                        "--plan bakes one input map (no globs, --batch, --force, --check or --jobs)"
                            .into(),
                    ));
                };
                let output = output.ok_or_else(|| {
                    Error::InvalidOption("--plan needs an output folder (-o DIR)".into())
                })?;
                bake_plan(&plan_path, input, &output, &ingest)?;
            }
            None => status = bake_command(a)?,
        },
        Command::Eval {
            input,
            methods,
            lobes,
            align,
            align_form,
            modes,
            lmax,
            s,
            sigma,
            brdf,
            alpha,
            ggx_g,
            ggx_c,
            vmf_diffuse,
            vmf_cosine,
            vmf_specular,
            sh_diffuse,
            first_level,
            formats,
            json,
            env,
            ingest,
            em,
        } => {
            // Everything is checked before any work.
            env.check()?;
            let mut mixtures = MixtureGrid::parse(&lobes, &align, &align_form, &modes)?;
            mixtures.memory_limit = ingest.memory_limit()?;
            mixtures.lmax = lmax;
            mixtures.em = em.checked()?;
            check_exponents(&s)?;
            if let Some(bad) = sigma.iter().find(|v| !(v.is_finite() && **v > 0.0)) {
                return Err(Error::InvalidOption(format!(
                    "Torrance-Sparrow sigma {} (must be finite and > 0)",
                    compact_f64(*bad)
                )));
            }
            let shading = ndfmap::shade::ShadeOptions {
                vmf_diffuse: choice("vmf-diffuse", &vmf_diffuse, "mean-vector, algorithm2")?,
                vmf_cosine: choice("vmf-cosine", &vmf_cosine, "product, algorithm2")?,
                sh_diffuse: choice("sh-diffuse", &sh_diffuse, "moments, series")?,
                ..Default::default()
            };
            let vmf_rules = vmf_specular
                .iter()
                .map(|r| {
                    choice::<ndfmap::shade::VmfSpecular>(
                        "vmf-specular",
                        r.trim(),
                        "auto, eq20, convolved, exact",
                    )
                })
                .collect::<Result<Vec<_>>>()?;
            let brdfs = eval_brdfs(&brdf, &s, &sigma, &alpha, ggx_g, &ggx_c)?;
            let mut methods = parse_methods(&methods)?;
            let routes = env
                .env_route
                .iter()
                .map(|r| r.parse())
                .collect::<Result<Vec<ndfmap::envlight::Route>>>()?;
            if env.env.is_some() {
                for b in &brdfs {
                    ndfmap::envlight::check_brdf(b)?;
                }
                let left: Vec<String> = methods
                    .iter()
                    .filter(|m| ndfmap::envlight::check_method(**m).is_err())
                    .map(|m| m.to_string())
                    .collect();
                if !left.is_empty() {
                    eprintln!("left out under --env (not supported): {}", left.join(", "));
                }
                methods.retain(|m| ndfmap::envlight::check_method(*m).is_ok());
            }
            let light = env.load(json)?;
            // A storage format, or a block compression (its bakes' labels name the codec).
            let formats = formats
                .iter()
                .map(|f| match f.trim().parse::<Format>() {
                    Ok(f) => Ok(Ok(f)),
                    Err(e) => f
                        .trim()
                        .parse::<ndfmap::compress::Codec>()
                        .map(Err)
                        .map_err(|_| e),
                })
                .collect::<Result<Vec<std::result::Result<Format, ndfmap::compress::Codec>>>>()?;
            let color = ingest.feature.is_some();
            for &m in &methods {
                for o in mixtures.options(m) {
                    ndfmap::methods::check_options(m, &o, color, None)?;
                }
            }
            let (map, _) = ingest.load(&input)?;
            let mut bakes = Vec::new();
            let mut codec_labels = Vec::new();
            for b in bake_all(&map, &methods, &mixtures, json)? {
                for &f in &formats {
                    let (stored, label) = match f {
                        Ok(f) => (ndfmap::pack::quantize(&b, f), None),
                        Err(c) => (
                            ndfmap::compress::round_trip(&b, c),
                            Some(format!("{} {c}", b.label())),
                        ),
                    };
                    match stored {
                        Ok(q) => {
                            bakes.push(q);
                            codec_labels.push(label);
                        }
                        Err(e) => eprintln!(
                            "skipped {} in {}: {e}",
                            b.method,
                            f.map_or_else(|c| c.name(), |f| f.name())
                        ),
                    }
                }
            }
            if color && light.is_some() {
                // What eq 22's colour buys: each colour vMF bake again without its colour
                // textures, shaded times the albedo MIP.
                let stripped: Vec<Bake> = bakes
                    .iter()
                    .filter(|b| b.method == Method::Vmf && b.textures.len() >= 2 * b.lobes)
                    .map(Bake::lobes_only)
                    .collect();
                bakes.extend(stripped);
            }
            let refs: Vec<&Bake> = bakes.iter().collect();
            if let Some((name, light)) = light {
                let t = Instant::now();
                let options = ndfmap::envlight::EvalOptions {
                    first_level: first_level.max(1),
                    texels_per_level: env.env_texels,
                    samples: env.env_samples,
                    color,
                    ..Default::default()
                };
                let e = ndfmap::envlight::evaluate(&map, &refs, &brdfs, &light, &routes, &options)?;
                if json {
                    let v = serde_json::json!({
                        "input": input.display().to_string(),
                        "environment": name,
                        "evaluation": e,
                    });
                    println!(
                        "{}",
                        serde_json::to_string_pretty(&v).expect("errors serialize")
                    );
                } else {
                    print!("{}", ndfmap::envlight::format_table(&e));
                    eprintln!(
                        "evaluated under {name} in {:.2} s",
                        t.elapsed().as_secs_f64()
                    );
                }
                return Ok(0);
            }
            let t = Instant::now();
            let mut errors = Vec::new();
            for (ri, &rule) in vmf_rules.iter().enumerate() {
                // Bakes the rule does not touch are measured under the first rule only.
                let rule_bakes: Vec<(usize, &Bake)> = refs
                    .iter()
                    .enumerate()
                    .filter(|(_, b)| ri == 0 || b.method == Method::Vmf)
                    .map(|(i, b)| (i, *b))
                    .collect();
                let these: Vec<&Bake> = rule_bakes.iter().map(|(_, b)| *b).collect();
                let mut e = evaluate_with(
                    &map,
                    &these,
                    &brdfs,
                    &default_directions(),
                    first_level,
                    &ndfmap::shade::ShadeOptions {
                        vmf_specular: rule,
                        ..shading
                    },
                );
                // Errors come bake by bake, BRDF by BRDF: name the codec of compressed bakes,
                // and the rule when several are compared.
                for (j, e) in e.iter_mut().enumerate() {
                    let (i, b) = rule_bakes[j / brdfs.len().max(1)];
                    if let Some(Some(l)) = codec_labels.get(i) {
                        e.label = l.clone();
                    }
                    if vmf_rules.len() > 1 && b.method == Method::Vmf {
                        e.label = format!("{} {}", e.label, rule.name());
                    }
                }
                errors.extend(e);
            }
            // How well lobe j lines up across neighbouring texels (Sec 7.3), per vMF bake.
            let coherence: Vec<(String, Vec<Option<f64>>)> = bakes
                .iter()
                .filter(|b| b.method == Method::Vmf && b.format == Format::F32)
                .map(|b| (b.label(), ndfmap::mixture::lobe_coherence(b)))
                .collect();
            if json {
                let v = serde_json::json!({
                    "input": input.display().to_string(),
                    "directions": default_directions().len(),
                    "errors": errors,
                    "lobe_coherence_degrees": coherence
                        .iter()
                        .map(|(l, c)| (l.clone(), serde_json::json!(c)))
                        .collect::<serde_json::Map<_, _>>(),
                });
                println!(
                    "{}",
                    serde_json::to_string_pretty(&v).expect("errors serialize")
                );
            } else {
                print!("{}", format_table(&errors));
                for (label, c) in &coherence {
                    let cells: Vec<String> = c
                        .iter()
                        .map(|a| a.map_or("-".into(), |a| format!("{a:.1}")))
                        .collect();
                    println!(
                        "lobe coherence of {label} (mean angle between lobe j of neighbouring texels, degrees, per level): {}",
                        cells.join(" ")
                    );
                }
                eprintln!(
                    "evaluated {} light/view pairs in {:.2} s",
                    default_directions().len(),
                    t.elapsed().as_secs_f64()
                );
            }
        }
        Command::Shader {
            method,
            lobes,
            lmax,
            aligned,
            format,
            color,
            brdf,
            ggx_g,
            sampling,
            max_anisotropy,
            vmf_diffuse,
            vmf_cosine,
            vmf_specular,
            sh_diffuse,
            addressing,
            stage,
            probe,
            light,
        } => {
            let method: Method = method.parse()?;
            let mixture = matches!(method, Method::Vmf | Method::Tan2005);
            if mixture && !(1..=ndfmap::em::MAX_LOBES).contains(&lobes) {
                return Err(Error::InvalidOption(format!(
                    "--lobes {lobes} (expected 1 to {})",
                    ndfmap::em::MAX_LOBES
                )));
            }
            let lobes = if mixture { lobes } else { 0 };
            if method == Method::Sh && lmax > ndfmap::sh::MAX_LMAX {
                return Err(Error::InvalidOption(format!(
                    "--lmax {lmax} (expected 0 to {})",
                    ndfmap::sh::MAX_LMAX
                )));
            }
            let size = if method == Method::Sh { lmax } else { lobes };
            let pick = |what: &str, value: &str, names: &[&str]| -> Result<usize> {
                names.iter().position(|n| *n == value).ok_or_else(|| {
                    Error::InvalidOption(format!(
                        "--{what} {value} (expected one of: {})",
                        names.join(", ")
                    ))
                })
            };
            let spec = ndfmap::glsl::ShaderSpec {
                method,
                lobes,
                ranges: ndfmap::methods::texture_ranges(method, size, color && mixture),
                format: format.parse()?,
                aligned,
                addressing: [Addressing::Wrap, Addressing::Clamp]
                    [pick("addressing", &addressing, &["wrap", "clamp"])?],
                lmax: if method == Method::Sh { lmax } else { 0 },
                biased: false,
            };
            let brdfs = [
                ShaderBrdf::BlinnPhong,
                ShaderBrdf::TorranceSparrow,
                ShaderBrdf::Lambert,
                ShaderBrdf::Ggx { g: ggx_g },
                ShaderBrdf::Tabulated,
            ];
            let brdf_names = [
                "blinn-phong",
                "torrance-sparrow",
                "lambert",
                "ggx",
                "tabulated",
            ];
            let samplings = [
                Sampling::Auto,
                Sampling::Hardware,
                Sampling::Manual,
                Sampling::Anisotropic(max_anisotropy),
            ];
            let sampling_names = ["auto", "hardware", "manual", "anisotropic"];
            let options = ndfmap::glsl::ShaderOptions {
                brdf: brdfs[pick("brdf", &brdf, &brdf_names)?],
                sampling: samplings[pick("sampling", &sampling, &sampling_names)?],
                color,
                probe,
                vmf_diffuse: choice("vmf-diffuse", &vmf_diffuse, "mean-vector, algorithm2")?,
                vmf_cosine: choice("vmf-cosine", &vmf_cosine, "product, algorithm2")?,
                vmf_specular: choice("vmf-specular", &vmf_specular, "auto, eq20, convolved")?,
                sh_diffuse: choice("sh-diffuse", &sh_diffuse, "moments, series")?,
                light: [
                    ndfmap::glsl::ShaderLight::Point,
                    ndfmap::glsl::ShaderLight::EnvPrefiltered,
                    ndfmap::glsl::ShaderLight::EnvSh,
                ][pick("light", &light, &["point", "env-prefiltered", "env-sh"])?],
                ..Default::default()
            };
            let stage =
                [Stage::Fragment, Stage::Vertex][pick("stage", &stage, &["fragment", "vertex"])?];
            print!("{}", ndfmap::glsl::source_for(&spec, stage, &options)?);
        }
        Command::Plan {
            scene,
            input,
            output,
            explain,
            verify,
            ingest,
        } => plan_cmd(&scene, &input, output.as_deref(), explain, verify, &ingest)?,
        Command::Demo { output, size } => demo(&output, size)?,
        #[cfg(feature = "report")]
        Command::Report(args) => report(args)?,
        #[cfg(feature = "report")]
        Command::PbrReport {
            inputs,
            alpha,
            first_level,
            last_level,
            no_vmf,
            fit_max_angle,
            json,
        } => pbr_report(
            &inputs,
            &alpha,
            (first_level, last_level),
            no_vmf,
            fit_max_angle,
            json,
        )?,
        Command::Bench {
            sizes,
            lobes,
            lmax,
            align,
            modes,
            json,
            quality,
            maps,
            samples,
            levels,
            reference_starts,
            reference_check,
            scale,
            untiled_max,
            runs,
            em,
            job,
            job_dir,
        } => {
            if !quality && (reference_check || reference_starts != 8) {
                return Err(Error::InvalidOption(
                    "--reference-starts and --reference-check are options of --quality".into(),
                ));
            }
            if job.is_some() && quality {
                return Err(Error::InvalidOption(
                    "--job is a row of the speed or scale table (not with --quality)".into(),
                ));
            }
            if job_dir.is_some() != (scale && job.is_some()) {
                return Err(Error::InvalidOption(
                    "--job-dir goes with --scale --job, and only there".into(),
                ));
            }
            if runs != 1 && (scale || quality) {
                return Err(Error::InvalidOption(
                    "--runs times the speed table only (not with --quality or --scale)".into(),
                ));
            }
            if scale {
                // One mode given: that one; else (the default list) balanced.
                let mode = match modes.as_slice() {
                    [one] => one.parse()?,
                    _ => FitMode::Balanced,
                };
                let lobes = lobes.first().copied().unwrap_or(6);
                let job = job.zip(job_dir.as_deref());
                bench_scale(&sizes, lobes, mode, untiled_max, json, job)?;
                return Ok(status);
            }
            let mut grid = MixtureGrid::parse(&lobes, &align, "appendix", &modes)?;
            grid.lmax = lmax;
            grid.em = em.checked()?;
            if quality {
                let reference = ndfmap::quality::QualityOptions {
                    samples_per_level: samples.max(1),
                    starts: reference_starts.clamp(1, 1000),
                    reference_check,
                    ..Default::default()
                };
                bench_quality(&sizes, &maps, &grid, reference, &levels, json)?
            } else {
                bench(&sizes, &grid, json, runs, job)?
            }
        }
    }
    Ok(status)
}

/// The main job on the built-in sample: generate, write as PNG, read it back like any user
/// file, bake every method, write the bakes, and print the error table.
fn demo(output: &Path, size: u32) -> Result<()> {
    if !(8..=4096).contains(&size) {
        return Err(Error::InvalidOption(format!(
            "--size {size} (expected 8 to 4096)"
        )));
    }
    let write_err = |path: &Path, e: &dyn std::fmt::Display| Error::Write {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    std::fs::create_dir_all(output).map_err(|e| write_err(output, &e))?;
    let sample = ndfmap::procedural::generate(size, 2007);
    let normal_png = output.join("sample_normal.png");
    let albedo_png = output.join("sample_albedo.png");
    let rgb = |path: &Path, data: Vec<u8>| {
        image::RgbImage::from_raw(size, size, data)
            .expect("buffer matches the size")
            .save(path)
            .map_err(|e| write_err(path, &e))
    };
    rgb(
        &normal_png,
        ndfmap::procedural::encode_rgb8(sample.map.normals()),
    )?;
    rgb(
        &albedo_png,
        ndfmap::procedural::encode_srgb8(&sample.albedo),
    )?;
    let options = IngestOptions::default();
    let map = NormalMap::load(&normal_png, &options)?.with_feature_file(&albedo_png, &options)?;
    println!(
        "sample normal map: {} ({size}x{size}, mean z {:.3})",
        normal_png.display(),
        map.stats().mean_z
    );
    let grid = MixtureGrid {
        lobes: vec![6],
        align: vec![None],
        align_form: AlignmentForm::default(),
        modes: vec![FitMode::default()],
        memory_limit: None,
        lmax: vec![BakeOptions::default().lmax],
        em: ndfmap::em::EmOptions::default(),
    };
    let bakes = bake_all(&map, &Method::ALL, &grid, false)?;
    for b in &bakes {
        let info = InputInfo {
            path: Some(normal_png.display().to_string()),
            options,
            stats: map.stats().clone(),
        };
        let m = write_bake(b, info, &output.join(b.method.name()))?;
        println!("{:<8} bake: {}", b.method.name(), m.display());
    }
    let refs: Vec<&Bake> = bakes.iter().collect();
    let brdfs = [Brdf::BlinnPhong { s: 64.0 }, Brdf::BlinnPhong { s: 512.0 }];
    let errors = evaluate(&map, &refs, &brdfs, &default_directions());
    let table = format_table(&errors);
    let table_path = output.join("eval.txt");
    std::fs::write(&table_path, &table).map_err(|e| write_err(&table_path, &e))?;
    println!("\n{table}error table: {}", table_path.display());
    Ok(())
}

/// A bench's temporary folder, removed however the bench ends.
struct Scratch(PathBuf);

impl Scratch {
    /// Creates `ndfmap-bench-<what>-<pid>` in the system's temporary folder.
    fn new(what: &str) -> Result<Scratch> {
        let dir = std::env::temp_dir().join(format!("ndfmap-bench-{what}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).map_err(bench_io_error)?;
        Ok(Scratch(dir))
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A bench's temporary-folder I/O error as one clear line.
fn bench_io_error(e: std::io::Error) -> Error {
    Error::InvalidOption(format!("bench temporary folder: {e}"))
}

/// One timed run of a bench.
struct Timing {
    /// Wall seconds.
    seconds: f64,
    /// CPU seconds of the process (all threads).
    cpu: Option<f64>,
    /// Peak RSS during the run (after a reset).
    peak: Option<u64>,
    /// Peak RSS just after the reset: what the process held before the run.
    base: Option<u64>,
}

/// Runs `work` once, timed (wall and CPU seconds, peak RSS after a reset).
fn timed<T>(work: impl FnOnce() -> Result<T>) -> Result<(T, Timing)> {
    ndfmap::usage::reset_peak_rss();
    let base = ndfmap::usage::peak_rss();
    let cpu = ndfmap::usage::cpu_seconds();
    let t = Instant::now();
    let out = work()?;
    let seconds = t.elapsed().as_secs_f64();
    let cpu = ndfmap::usage::cpu_seconds().zip(cpu).map(|(b, a)| b - a);
    Ok((
        out,
        Timing {
            seconds,
            cpu,
            peak: ndfmap::usage::peak_rss(),
            base,
        },
    ))
}

/// Which bake of a configuration a row of `ndfmap bench` times.
#[derive(Clone, Copy, PartialEq)]
enum BenchBake {
    /// `methods::bake_with`, the library call: all levels held as f32 textures.
    Memory,
    /// The way `ndfmap bake` writes it (module `banded`): levels streamed to f32 EXR files as
    /// they are fitted, the same bytes.
    Streamed,
}

/// One row of `ndfmap bench`'s speed table: a size of the built-in sample, a method with its
/// options, and which bake.
struct BenchJob {
    size: u32,
    method: Method,
    options: BakeOptions,
    bake: BenchBake,
}

/// The rows of `ndfmap bench`'s speed table, in order: per size, Toksvig, SH per band limit,
/// then every vMF configuration of `grid`, each baked in memory and then streamed.
fn bench_jobs(sizes: &[u32], grid: &MixtureGrid) -> Result<Vec<BenchJob>> {
    let mut jobs = Vec::new();
    for &size in sizes {
        if !(8..=8192).contains(&size) {
            return Err(Error::InvalidOption(format!(
                "--sizes {size} (expected 8 to 8192)"
            )));
        }
        let mut configs = vec![(Method::Toksvig, BakeOptions::default())];
        for &l in &grid.lmax {
            configs.push((
                Method::Sh,
                BakeOptions {
                    lmax: l,
                    ..BakeOptions::default()
                },
            ));
        }
        // `--lobes 0`: no vMF bake (SH and Toksvig only).
        configs.extend(
            grid.options(Method::Vmf)
                .into_iter()
                .filter(|o| o.lobes > 0)
                .map(|o| (Method::Vmf, o)),
        );
        for (method, options) in configs {
            jobs.push(BenchJob {
                size,
                method,
                options,
                bake: BenchBake::Memory,
            });
            if method == Method::Vmf {
                jobs.push(BenchJob {
                    size,
                    method,
                    options,
                    bake: BenchBake::Streamed,
                });
            }
        }
    }
    Ok(jobs)
}

/// `ndfmap bench`: bake time and peak memory on the built-in sample (with its albedo), one row
/// per [`BenchJob`] of [`bench_jobs`], each timed `runs` times ([`bench_child`]: medians).
///
/// Every run of every row is a process of its own (this executable, `bench … --runs 1 --job N
/// --json`), so its peak RSS is the bake's and not what the allocator kept from the bakes
/// before it. In one process, the 1024² J = 6 aligned streamed bake read 165–250 MiB after the
/// in-memory bakes, and more with each further run; alone it peaks at 133–142 MiB
/// (docs/baker.md, "Stop 55"). `job` is that child's row: it prints the row as JSON and
/// nothing else.
fn bench(
    sizes: &[u32],
    grid: &MixtureGrid,
    json: bool,
    runs: usize,
    job: Option<usize>,
) -> Result<()> {
    if !(1..=100).contains(&runs) {
        return Err(Error::InvalidOption(format!(
            "--runs {runs} (expected 1 to 100)"
        )));
    }
    let jobs = bench_jobs(sizes, grid)?;
    if let Some(i) = job {
        let job = jobs.get(i).ok_or_else(|| {
            Error::InvalidOption(format!("--job {i} (the bench has {} rows)", jobs.len()))
        })?;
        let row = bench_row(job)?;
        println!("{}", serde_json::to_string(&row).expect("row serializes"));
        return Ok(());
    }
    let threads = rayon::current_num_threads();
    if !json {
        let timing = if runs == 1 {
            "one run each".to_string()
        } else {
            format!("median of {runs} runs each")
        };
        println!(
            "{threads} threads; built-in sample with albedo; full MIP chain; {timing}; \
             each row in a process of its own"
        );
        println!(
            "{:>6} {:>8} {:>6} {:>9} {:>8} {:>9} {:>10} {:>8} {:>12} {:>14} {:>10}",
            "size",
            "method",
            "lobes",
            "aligned",
            "mode",
            "bake",
            "seconds",
            "CPU s",
            "peak MiB",
            "estimate MiB",
            "f32 MiB"
        );
    }
    let exe = std::env::current_exe().map_err(bench_io_error)?;
    let args = bench_child_args();
    let mut rows: Vec<serde_json::Value> = Vec::with_capacity(jobs.len());
    for (i, job) in jobs.iter().enumerate() {
        let mut row = bench_child(&exe, &args, i, runs)?;
        if job.bake == BenchBake::Streamed {
            // The same configuration's in-memory row, just before, counted the texture bytes.
            row["texture_bytes_f32"] = rows
                .last()
                .map_or(serde_json::Value::Null, |r| r["texture_bytes_f32"].clone());
        }
        if !json {
            print_bench_row(&row);
        }
        rows.push(row);
    }
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&rows).expect("rows serialize")
        );
    }
    Ok(())
}

/// This process's arguments less `--json` and `--runs`, which [`bench_child`] gives its
/// children anew.
fn bench_child_args() -> Vec<std::ffi::OsString> {
    let mut args = Vec::new();
    let mut given = std::env::args_os().skip(1);
    while let Some(a) = given.next() {
        if a == "--runs" {
            given.next();
        } else if a != "--json" && !a.to_string_lossy().starts_with("--runs=") {
            args.push(a);
        }
    }
    args
}

/// Runs row `i` of this bench `runs` times, each in a fresh child process (`exe` with `args`
/// ([`bench_child_args`]) and `--json --runs 1 --job i`), and returns the row: the median wall
/// and CPU seconds, the highest peak, the lowest baseline and every run's wall seconds in
/// order. A child's error line becomes this process's error.
fn bench_child(
    exe: &Path,
    args: &[std::ffi::OsString],
    i: usize,
    runs: usize,
) -> Result<serde_json::Value> {
    let mut rows = Vec::with_capacity(runs);
    for _ in 0..runs {
        let out = std::process::Command::new(exe)
            .args(args)
            .args(["--json", "--runs", "1", "--job", &i.to_string()])
            .stdin(std::process::Stdio::null())
            .output()
            .map_err(bench_io_error)?;
        if !out.status.success() {
            let err = String::from_utf8_lossy(&out.stderr);
            let line = err.trim().trim_start_matches("ndfmap: error: ");
            return Err(Error::InvalidOption(format!("bench row {i}: {line}")));
        }
        let row: serde_json::Value = serde_json::from_slice(&out.stdout).map_err(|e| {
            Error::InvalidOption(format!(
                "bench row {i}: the child printed no JSON row ({e})"
            ))
        })?;
        rows.push(row);
    }
    let all = |key: &str| -> Option<Vec<f64>> { rows.iter().map(|r| r[key].as_f64()).collect() };
    let bytes = |key: &str| -> Vec<u64> { rows.iter().filter_map(|r| r[key].as_u64()).collect() };
    let mut row = rows[0].clone();
    let seconds = all("seconds")
        .filter(|s| !s.is_empty())
        .ok_or_else(|| Error::InvalidOption(format!("bench row {i}: a run without seconds")))?;
    row["seconds"] = serde_json::json!(ndfmap::usage::median(&mut seconds.clone()));
    row["seconds_runs"] = serde_json::json!(seconds);
    row["cpu_seconds"] =
        serde_json::json!(all("cpu_seconds").map(|mut c| ndfmap::usage::median(&mut c)));
    row["peak_bytes"] = serde_json::json!(bytes("peak_bytes").into_iter().max());
    row["baseline_bytes"] = serde_json::json!(bytes("baseline_bytes").into_iter().min());
    row["runs"] = serde_json::json!(runs);
    Ok(row)
}

/// Times one run of a [`BenchJob`] in this process and returns its JSON row (for a streamed
/// bake, `texture_bytes_f32` is null: the parent copies it from the in-memory row before it).
fn bench_row(job: &BenchJob) -> Result<serde_json::Value> {
    let &BenchJob {
        size,
        method,
        ref options,
        bake,
    } = job;
    let sample = ndfmap::procedural::generate(size, 2007);
    let map = sample.map.with_feature(sample.albedo)?;
    let (run, estimate, texture_bytes, name) = match bake {
        BenchBake::Memory => {
            let (b, run) = timed(|| bake_with(&map, method, options))?;
            let texture_bytes: u64 = (0..b.textures.len())
                .flat_map(|_| 0..b.level_count())
                .map(|k| ndfmap::pack::packed_len(&b, k, Format::F32) as u64)
                .sum();
            // The budget's estimate (methods::estimate_peak_bytes), for calibrating it.
            let estimate = ndfmap::methods::estimate_peak_bytes(size, size, method, options, true);
            (run, estimate, Some(texture_bytes), "memory")
        }
        BenchBake::Streamed => {
            let tmp = Scratch::new("bake")?;
            let dir = tmp.0.join("bake");
            let info = InputInfo {
                path: None,
                options: IngestOptions::default(),
                stats: map.stats().clone(),
            };
            // The folder is deleted with `tmp` (untimed).
            let (_, run) = timed(|| {
                ndfmap::banded::write_folder(
                    &ndfmap::banded::Map::Full(&map),
                    method,
                    options,
                    Format::F32,
                    ndfmap::container::Container::Exr,
                    None,
                    &dir,
                    info,
                    None,
                    None,
                    &mut |_| true,
                )
            })?;
            let bands = ndfmap::banded::Bands::for_size(size, size);
            // The bench's map is decoded (`ndfmap bake` of an 8-bit file keeps its samples, a
            // few bytes per texel, so it peaks lower still).
            let source =
                ndfmap::banded::DECODED_NORMAL_BYTES + ndfmap::banded::DECODED_FEATURE_BYTES;
            let estimate =
                ndfmap::banded::estimate_peak_bytes(size, size, options, true, source, bands);
            (run, estimate, None, "streamed")
        }
    };
    let lobes = match method {
        Method::Vmf => options.lobes,
        Method::Sh => options.lmax,
        _ => 0,
    };
    let Timing {
        seconds,
        cpu,
        peak,
        base,
    } = run;
    Ok(serde_json::json!({
        "size": size, "method": method, "lobes": lobes,
        "align": options.align, "mode": options.mode, "bake": name,
        "seconds": seconds, "cpu_seconds": cpu,
        "peak_bytes": peak, "baseline_bytes": base, "estimate_bytes": estimate,
        "threads": rayon::current_num_threads(), "texture_bytes_f32": texture_bytes,
        "runs": 1, "seconds_runs": [seconds],
    }))
}

/// Prints one JSON row of [`bench_row`] as a line of the speed table.
fn print_bench_row(row: &serde_json::Value) {
    let mib = |v: &serde_json::Value| {
        v.as_f64()
            .map_or("?".into(), |b| format!("{:.0}", b / 1048576.0))
    };
    let method = row["method"].as_str().unwrap_or("?");
    let aligned = row["align"]
        .as_f64()
        .map_or("no".into(), |c| format!("C={c}"));
    let mode = if method == Method::Vmf.name() {
        row["mode"].as_str().unwrap_or("?")
    } else {
        "-"
    };
    println!(
        "{:>6} {method:>8} {:>6} {aligned:>9} {mode:>8} {:>9} {:>10.3} {:>8} {:>12} {:>14} {:>10}",
        row["size"].as_u64().unwrap_or(0),
        row["lobes"].as_u64().unwrap_or(0),
        row["bake"].as_str().unwrap_or("?"),
        row["seconds"].as_f64().unwrap_or(f64::NAN),
        row["cpu_seconds"]
            .as_f64()
            .map_or("?".into(), |c| format!("{c:.2}")),
        mib(&row["peak_bytes"]),
        mib(&row["estimate_bytes"]),
        row["texture_bytes_f32"]
            .as_f64()
            .map_or("?".into(), |b| format!("{:.1}", b / 1048576.0)),
    );
}

/// Whether `size` is a size `ndfmap bench --scale` can tile the built-in sample to.
fn check_scale_size(size: u32) -> Result<()> {
    if !(8..=16384).contains(&size) || (size > 1024 && !size.is_multiple_of(1024)) {
        return Err(Error::InvalidOption(format!(
            "--sizes {size} (--scale: 8 to 1024, or a multiple of 1024 up to 16384)"
        )));
    }
    Ok(())
}

/// The 8-bit RGB samples of the built-in sample at `size` (≤ 1024), or of the 1024² sample
/// tiled to `size` (a multiple of 1024), so that every size has the same content per texel.
fn scale_samples(size: u32) -> Result<Vec<u8>> {
    check_scale_size(size)?;
    let side = size.min(1024) as usize;
    let tile = ndfmap::procedural::encode_rgb8(
        ndfmap::procedural::generate(side as u32, 2007)
            .map
            .normals(),
    );
    let n = size as usize;
    let mut out = Vec::with_capacity(n * n * 3);
    for y in 0..n {
        let row = &tile[(y % side) * side * 3..(y % side + 1) * side * 3];
        for _ in 0..n / side {
            out.extend_from_slice(row);
        }
    }
    Ok(out)
}

/// Whether two folders hold the same files, byte for byte.
fn same_files(a: &Path, b: &Path) -> std::io::Result<bool> {
    let names = |d: &Path| -> std::io::Result<Vec<std::ffi::OsString>> {
        let mut v = std::fs::read_dir(d)?
            .map(|e| e.map(|e| e.file_name()))
            .collect::<std::io::Result<Vec<_>>>()?;
        v.sort();
        Ok(v)
    };
    let (na, nb) = (names(a)?, names(b)?);
    if na != nb {
        return Ok(false);
    }
    for n in na {
        if std::fs::read(a.join(&n))? != std::fs::read(b.join(&n))? {
            return Ok(false);
        }
    }
    Ok(true)
}

/// Which bake of a size a row of `ndfmap bench --scale` times.
#[derive(Clone, Copy, PartialEq)]
enum ScaleBake {
    /// `banded::write_folder` from the compact 8-bit source, in bands.
    Banded,
    /// The whole map decoded and baked in memory, then written: the files the banded bake must
    /// equal.
    Untiled,
}

impl ScaleBake {
    /// The name in the table and the JSON.
    fn name(self) -> &'static str {
        match self {
            ScaleBake::Banded => "banded",
            ScaleBake::Untiled => "untiled",
        }
    }
}

/// One row of `ndfmap bench --scale`: a size and which bake of it.
struct ScaleJob {
    size: u32,
    bake: ScaleBake,
}

/// The rows of `ndfmap bench --scale`, in order: per size, the banded bake, then the untiled
/// one for sizes up to `untiled_max`. Every size is checked before any work.
fn scale_jobs(sizes: &[u32], untiled_max: u32) -> Result<Vec<ScaleJob>> {
    let mut jobs = Vec::new();
    for &size in sizes {
        check_scale_size(size)?;
        jobs.push(ScaleJob {
            size,
            bake: ScaleBake::Banded,
        });
        if size <= untiled_max {
            jobs.push(ScaleJob {
                size,
                bake: ScaleBake::Untiled,
            });
        }
    }
    Ok(jobs)
}

/// The bake options of `ndfmap bench --scale`: vMF, `lobes`, aligned at eq 29's default C,
/// `mode`, no colour.
fn scale_options(lobes: usize, mode: FitMode) -> BakeOptions {
    BakeOptions {
        lobes,
        align: Some(AlignmentForm::default().default_strength()),
        mode,
        ..BakeOptions::default()
    }
}

/// Times one [`ScaleJob`] in this process, writing its f16 KTX2 files into `dir` (which the
/// parent compares and deletes), and returns its JSON row.
///
/// The source is built before the timer starts: the compact 8-bit normals for the banded
/// bake (the decoded samples freed first), the 8-bit samples for the untiled one, which
/// decodes them inside the timed work as `ndfmap bake` would.
fn scale_row(job: &ScaleJob, options: &BakeOptions, dir: &Path) -> Result<serde_json::Value> {
    use ndfmap::banded::{Bands, CompactSource, Map};
    use ndfmap::container::Container;
    use ndfmap::ingest::{CompactNormals, Samples};
    let size = job.size;
    let samples = scale_samples(size)?;
    let ingest = IngestOptions::default();
    let bands = Bands::for_size(size, size);
    let info = |stats: &ndfmap::ingest::IngestStats| InputInfo {
        path: None,
        options: ingest,
        stats: stats.clone(),
    };
    let (run, estimate) = match job.bake {
        ScaleBake::Banded => {
            let compact = CompactNormals::from_samples(
                "sample",
                size,
                size,
                3,
                Samples::U8(&samples),
                &ingest,
            )?;
            drop(samples);
            let info = info(compact.stats());
            let map = Map::Compact(CompactSource {
                normals: &compact,
                feature: None,
            });
            let (_, run) = timed(|| {
                ndfmap::banded::write_folder(
                    &map,
                    Method::Vmf,
                    options,
                    Format::F16,
                    Container::Ktx2,
                    None,
                    dir,
                    info,
                    None,
                    Some(bands),
                    &mut |_| true,
                )
                .map(|_| ())
            })?;
            let estimate = ndfmap::banded::estimate_peak_bytes(
                size,
                size,
                options,
                false,
                compact.bytes_per_texel(),
                bands,
            );
            (run, estimate)
        }
        ScaleBake::Untiled => {
            let (_, run) = timed(|| {
                let full = NormalMap::from_samples(
                    "sample",
                    size,
                    size,
                    3,
                    Samples::U8(&samples),
                    &ingest,
                )?;
                let info = info(full.stats());
                let b = bake_with(&full, Method::Vmf, options)?;
                drop(full);
                let b = ndfmap::pack::quantize_into(b, Format::F16)?;
                ndfmap::container::write_bake(&b, info, dir, Container::Ktx2, None).map(|_| ())
            })?;
            let estimate =
                ndfmap::methods::estimate_peak_bytes(size, size, Method::Vmf, options, false);
            (run, estimate)
        }
    };
    let banded = job.bake == ScaleBake::Banded;
    let Timing {
        seconds,
        cpu,
        peak,
        base,
    } = run;
    Ok(serde_json::json!({
        "size": size, "bake": job.bake.name(),
        "fine_levels": banded.then_some(bands.fine),
        "band_rows": banded.then_some(bands.band_rows),
        "seconds": seconds, "cpu_seconds": cpu,
        "peak_bytes": peak, "baseline_bytes": base, "estimate_bytes": estimate,
        "threads": rayon::current_num_threads(),
    }))
}

/// `ndfmap bench --scale`: the banded bake's time and peak memory per size (docs/scale.md),
/// and for sizes up to `untiled_max` the untiled bake's, with the files compared byte for byte.
///
/// Every row is a process of its own (this executable, `bench … --json --runs 1 --job N
/// --job-dir DIR`, [`scale_row`]), as in [`bench`]: in one process a row's peak carried what
/// the allocator kept from the bakes before it (docs/baker.md, "Stop 56"). `job` and `job_dir`
/// are that child's row and output folder.
fn bench_scale(
    sizes: &[u32],
    lobes: usize,
    mode: FitMode,
    untiled_max: u32,
    json: bool,
    job: Option<(usize, &Path)>,
) -> Result<()> {
    let options = scale_options(lobes, mode);
    let jobs = scale_jobs(sizes, untiled_max)?;
    if let Some((i, dir)) = job {
        let job = jobs.get(i).ok_or_else(|| {
            Error::InvalidOption(format!("--job {i} (the bench has {} rows)", jobs.len()))
        })?;
        let row = scale_row(job, &options, dir)?;
        println!("{}", serde_json::to_string(&row).expect("row serializes"));
        return Ok(());
    }
    let threads = rayon::current_num_threads();
    let io = bench_io_error;
    let tmp = Scratch::new("scale")?;
    if !json {
        println!(
            "{threads} threads; vMF J = {lobes} aligned C = {} {}, f16 KTX2, built-in 1024² sample \
             tiled; each row in a process of its own",
            options.align.unwrap_or_default(),
            mode.name()
        );
        println!(
            "{:>6} {:>8} {:>5} {:>6} {:>9} {:>8} {:>12} {:>7} {:>9} {:>13} {:>9}",
            "size",
            "bake",
            "fine",
            "band",
            "seconds",
            "CPU s",
            "CPU µs/texel",
            "ratio",
            "peak MiB",
            "estimate MiB",
            "= untiled"
        );
    }
    let exe = std::env::current_exe().map_err(io)?;
    let args = bench_child_args();
    let mut rows = Vec::new();
    let mut first_per_texel = None;
    let mut i = 0;
    for size_jobs in jobs.chunk_by(|a, b| a.size == b.size) {
        let size = size_jobs[0].size;
        let texels = size as f64 * size as f64;
        let mut size_rows = Vec::with_capacity(size_jobs.len());
        let mut dirs = Vec::with_capacity(size_jobs.len());
        for job in size_jobs {
            let dir = tmp.0.join(format!("{}{size}", job.bake.name()));
            let mut extra = args.clone();
            extra.push("--job-dir".into());
            extra.push(dir.clone().into_os_string());
            let mut row = bench_child(&exe, &extra, i, 1)?;
            i += 1;
            let per_texel = row["cpu_seconds"].as_f64().map(|c| c * 1e6 / texels);
            if job.bake == ScaleBake::Banded && first_per_texel.is_none() {
                first_per_texel = per_texel;
            }
            row["cpu_us_per_texel"] = serde_json::json!(per_texel);
            row["ratio_to_first"] =
                serde_json::json!(per_texel.zip(first_per_texel).map(|(a, b)| a / b));
            size_rows.push(row);
            dirs.push(dir);
        }
        // The banded folder against the untiled one, where there is one.
        let identical = match dirs.as_slice() {
            [banded, untiled] => Some(same_files(banded, untiled).map_err(io)?),
            _ => None,
        };
        for dir in &dirs {
            let _ = std::fs::remove_dir_all(dir);
        }
        for (k, row) in size_rows.iter_mut().enumerate() {
            row["identical_to_untiled"] = serde_json::json!(if k == 0 { identical } else { None });
        }
        if !json {
            for row in &size_rows {
                print_scale_row(row);
            }
        }
        rows.extend(size_rows);
        if identical == Some(false) {
            return Err(Error::InvalidOption(format!(
                "the banded bake of {size}x{size} differs from the untiled bake"
            )));
        }
    }
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&rows).expect("rows serialize")
        );
    }
    Ok(())
}

/// Prints one JSON row of [`bench_scale`] as a line of its table.
fn print_scale_row(row: &serde_json::Value) {
    let num = |v: &serde_json::Value, digits: usize| {
        v.as_f64().map_or("?".into(), |x| format!("{x:.digits$}"))
    };
    let dash = |v: &serde_json::Value| v.as_u64().map_or("-".into(), |x| x.to_string());
    let mib = |v: &serde_json::Value| {
        v.as_f64()
            .map_or("?".into(), |b| format!("{:.0}", b / 1048576.0))
    };
    let same = row["identical_to_untiled"]
        .as_bool()
        .map_or("-", |s| if s { "yes" } else { "NO" });
    println!(
        "{:>6} {:>8} {:>5} {:>6} {:>9} {:>8} {:>12} {:>7} {:>9} {:>13} {same:>9}",
        row["size"].as_u64().unwrap_or(0),
        row["bake"].as_str().unwrap_or("?"),
        dash(&row["fine_levels"]),
        dash(&row["band_rows"]),
        num(&row["seconds"], 2),
        num(&row["cpu_seconds"], 1),
        num(&row["cpu_us_per_texel"], 3),
        num(&row["ratio_to_first"], 3),
        mib(&row["peak_bytes"]),
        mib(&row["estimate_bytes"]),
    );
}

/// `ndfmap bench --quality`: fit quality of each vMF configuration on the given maps, or on
/// the built-in sample at each size.
fn bench_quality(
    sizes: &[u32],
    maps: &[PathBuf],
    grid: &MixtureGrid,
    reference: ndfmap::quality::QualityOptions,
    levels: &str,
    json: bool,
) -> Result<()> {
    let (first, last) = levels
        .split_once("..=")
        .and_then(|(a, b)| Some((a.trim().parse().ok()?, b.trim().parse().ok()?)))
        .filter(|(a, b): &(usize, usize)| a <= b)
        .ok_or_else(|| {
            Error::InvalidOption(format!("--levels {levels} (expected FIRST..=LAST)"))
        })?;
    let quality = ndfmap::quality::QualityOptions {
        first_level: first,
        last_level: last,
        ..reference
    };
    let mut inputs: Vec<(String, NormalMap)> = Vec::new();
    for path in maps {
        let map = NormalMap::load(path, &IngestOptions::default())?;
        inputs.push((path.display().to_string(), map));
    }
    if maps.is_empty() {
        for &size in sizes {
            inputs.push((
                format!("sample {size}"),
                ndfmap::procedural::generate(size, 2007).map,
            ));
        }
    }
    let mut rows = Vec::new();
    for (name, map) in &inputs {
        for options in grid.options(Method::Vmf) {
            let t = Instant::now();
            let bake = bake_with(map, Method::Vmf, &options)?;
            let seconds = t.elapsed().as_secs_f64();
            let q = ndfmap::quality::fit_quality(map, &bake, &quality)?;
            if !json {
                println!("\n{name}: {} (baked in {seconds:.2} s)", bake.label());
                let check = if quality.reference_check {
                    format!(" {:>9} {:>10}", "ref2>=ref", "ref-ref2")
                } else {
                    String::new()
                };
                println!(
                    "{:>5} {:>7} {:>10} {:>9} {:>11} {:>8} {:>8} {:>7} {:>7} {:>7} {:>8}{check}",
                    "level",
                    "sampled",
                    "mean gap",
                    "max gap",
                    "gap κ≤1.6e4",
                    ">= ref",
                    ">= ref κ≤",
                    "dead",
                    "<0.01",
                    "wasted",
                    "ref<0.01"
                );
                for l in &q {
                    let check = match (l.reference_repeat, l.reference_repeat_gap) {
                        (Some(r), Some(g)) => format!(" {:>8.0}% {g:>10.5}", 100.0 * r),
                        _ => String::new(),
                    };
                    println!(
                        "{:>5} {:>7} {:>10.5} {:>9.4} {:>11.5} {:>7.0}% {:>7.0}% {:>6.1}% {:>6.1}% {:>7.2} {:>7.1}%{check}",
                        l.level,
                        l.sampled,
                        l.mean_gap,
                        l.max_gap,
                        l.mean_gap_resolved,
                        100.0 * l.at_least_as_good,
                        100.0 * l.at_least_as_good_resolved,
                        100.0 * l.dead,
                        100.0 * l.near_empty,
                        l.wasted,
                        100.0 * l.reference_near_empty
                    );
                }
            }
            rows.push(serde_json::json!({
                "map": name, "label": bake.label(), "lobes": options.lobes,
                "align": options.align, "mode": options.mode, "seconds": seconds,
                "em_max_iterations": options.em.max_iterations,
                "em_tolerance": options.em.tolerance,
                "reference_starts": quality.starts, "levels": q,
            }));
        }
    }
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&rows).expect("rows serialize")
        );
    }
    Ok(())
}

/// Options of `ndfmap report`.
#[cfg(feature = "report")]
#[derive(Args)]
struct ReportArgs {
    /// Normal maps (default: rock, bark, metal and facade .jpg from $NDFMAP_DATA or
    /// ../shared/data/normalmaps/ when present, else the built-in sample).
    maps: Vec<PathBuf>,
    /// Output folder: report.md, report.json, plots (PNG, SVG), images/.
    #[arg(short, long, default_value = "out/report")]
    output: PathBuf,
    /// Side of each rendered view, pixels.
    #[arg(long, default_value_t = 256)]
    size: u32,
    /// Ground-truth samples per pixel, 1 to 65536.
    #[arg(long, default_value_t = 256)]
    spp: u32,
    /// Samples per pixel of the second ground truth that estimates the first's Monte Carlo
    /// error on one view (0 skips it), at most 65536.
    #[arg(long, default_value_t = 1024)]
    convergence_spp: u32,
    /// vMF lobe counts, comma-separated (the full sweep, 1 to 8, takes about 1.6× as long).
    #[arg(long, default_value = "1,2,4,6,8", value_delimiter = ',')]
    lobes: Vec<usize>,
    /// vMF alignments, comma-separated: `none`, `default` (eq 29: C = 0.03) or a strength C.
    #[arg(long, default_value = "none,default", value_delimiter = ',')]
    align: Vec<String>,
    /// Tan 2005 lobe counts, comma-separated (empty: none).
    #[arg(long, default_value = "4", value_delimiter = ',')]
    tan_lobes: Vec<String>,
    /// Storage formats measured in texel space, comma-separated.
    #[arg(long, default_value = "f32,f16,unorm8", value_delimiter = ',')]
    formats: Vec<String>,
    /// Storage formats also rendered in image space, comma-separated.
    #[arg(long, default_value = "f32,f16", value_delimiter = ',')]
    image_formats: Vec<String>,
    /// Blinn-Phong exponent of the material.
    #[arg(short, long = "exponent", default_value_t = 128.0)]
    s: f64,
    /// The material's specular BRDF instead of Blinn-Phong -s: lambert, torrance-sparrow
    /// (--sigma), ggx (--alpha), or a tabulated BRDF file (JSON).
    #[arg(long)]
    brdf: Option<String>,
    /// Torrance–Sparrow roughness σ of --brdf torrance-sparrow.
    #[arg(long, default_value_t = 0.1)]
    sigma: f64,
    /// GGX roughness α of --brdf ggx.
    #[arg(long, default_value_t = 0.1)]
    alpha: f64,
    /// SH band limits l*, comma-separated (one row each; empty: none).
    #[arg(long, default_value = "2,4,6,8", value_delimiter = ',')]
    sh_lmax: Vec<String>,
    /// Also measure anisotropic filtering with up to this many probes (its floor per view, and
    /// the configurations that filter linearly under it); 0: off.
    #[arg(long, default_value_t = 0)]
    anisotropy: u32,
    /// Images to write: none, some (ground truth and a few methods), all.
    #[arg(long, default_value = "some")]
    images: String,
    /// Side of the built-in sample when no map is found.
    #[arg(long, default_value_t = 512)]
    sample_size: u32,
    /// Skip the stability sweep.
    #[arg(long)]
    no_stability: bool,
    /// Skip the planner section (the four scenes of docs/planner planned for their shared
    /// maps, or for the built-in sample where those are absent, each measured against the
    /// full configuration: about a minute).
    #[arg(long)]
    no_planner: bool,
    /// Also light the plane and sphere views by this environment (Radiance .hdr or OpenEXR, 2:1,
    /// linear; `sky`: the generated sky with its sun) and measure plain, Toksvig, LEAN,
    /// Olano–North, SH l* 2/4/8, Tan 2005 (--tan-lobes' largest) and vMF (--lobes' largest),
    /// the mixtures by both routes, against a per-pixel Monte Carlo ground truth
    /// (docs/environment.md); the material's BRDF must be lambert, blinn-phong or ggx.
    #[arg(long)]
    env: Option<String>,
    /// Albedo images (linear-RGB colour, each the size of its map), comma-separated, one per
    /// map in the maps' order (`-` for a map without): the --env section then scores colour —
    /// the ground truth with each normal's albedo, vMF and Tan 2005 by eq 22's colour, every
    /// other configuration times the albedo MIP (docs/environment.md).
    #[arg(long, value_delimiter = ',')]
    env_albedo: Vec<PathBuf>,
    /// Ground-truth MIS iterations per pixel under --env, 1 to 65536.
    #[arg(long, default_value_t = 64)]
    env_samples: usize,
    /// Extract up to N bright compact sources from --env as distant lights, and up to N wide
    /// ones from the diffuse SH (as `eval --env-lights`, the same default; 0: the paper's pure
    /// routes).
    #[arg(long, default_value_t = 4)]
    env_lights: usize,
    /// Ground-truth sub-pixel normals per side (k × k per pixel) under --env.
    #[arg(long, default_value_t = 4)]
    env_subpixels: u32,
    /// Environment rotation about the zenith, degrees (--env).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    env_yaw: f64,
    /// Environment radiance multiplier (--env).
    #[arg(long, default_value_t = 1.0)]
    env_intensity: f64,
    /// Measure nothing: rewrite report.md and the plots from a report.json of an earlier run
    /// (with --frame-times, also replace its frame times).
    #[arg(long)]
    from_json: Option<PathBuf>,
    /// Frame times from `ndfmap-viewer --bench --bench-json FILE`. Without it, an
    /// `ndfmap-viewer` beside this executable is run (--bench-size, --bench-frames, a 256²
    /// sample, the report's formats; about 8 s on llvmpipe on 2 idle cores).
    #[arg(long, conflicts_with = "no_frame_times")]
    frame_times: Option<PathBuf>,
    /// No frame times (the table shows n/a).
    #[arg(long)]
    no_frame_times: bool,
    /// Framebuffer of the viewer benchmark the report runs, WxH.
    #[arg(long, default_value = "640x360", value_parser = ndfmap::report::frame::parse_size)]
    bench_size: (u32, u32),
    /// Timed frames of the viewer benchmark the report runs.
    #[arg(long, default_value_t = 8)]
    bench_frames: u32,
}

/// Frame times for `rep` as `a` asks: read from --frame-times (`given`, loaded before the
/// measurements so a bad file fails early), none with --no-frame-times, else measured by an
/// `ndfmap-viewer` beside this executable. Notes the source, or why there are none.
#[cfg(feature = "report")]
fn attach_frame_times(
    a: &ReportArgs,
    given: Option<ndfmap::report::frame::FrameTimes>,
    rep: &mut ndfmap::report::Report,
) {
    use ndfmap::report::frame::{BenchSettings, run_viewer_bench, viewer_beside};
    if let Some(times) = given {
        let path = a.frame_times.as_deref().unwrap_or(Path::new("?"));
        rep.set_frame_times(times);
        rep.frame_times_note = Some(format!("read from {}", path.display()));
        return;
    }
    if a.no_frame_times {
        rep.frame_times_note = Some("not measured: --no-frame-times".into());
        return;
    }
    let exe = std::env::current_exe().ok();
    let Some(viewer) = exe.as_deref().and_then(viewer_beside) else {
        rep.frame_times_note = Some(format!(
            "no `ndfmap-viewer` beside {}: build it (`cargo build --release -p \
             ndfmap-viewer`) or pass `--frame-times FILE`",
            exe.as_deref()
                .unwrap_or(Path::new("this executable"))
                .display()
        ));
        return;
    };
    let mut labels: Vec<String> = Vec::new();
    for r in &rep.rows {
        if !labels.contains(&r.config) {
            labels.push(r.config.clone());
        }
    }
    let settings = BenchSettings {
        size: a.bench_size,
        frames: a.bench_frames.max(1),
        labels,
        formats: rep.options.formats.clone(),
        ..BenchSettings::default()
    };
    match run_viewer_bench(&viewer, &settings) {
        Ok(times) => {
            rep.set_frame_times(times);
            rep.frame_times_note = Some(format!("run by this report: {}", viewer.display()));
        }
        Err(e) => rep.frame_times_note = Some(format!("not measured: {e}")),
    }
}

/// NVIDIA's FLIP (LDR, 67 pixels per degree) through `nv-flip`: per-pixel errors and the
/// magma-coloured error map ([`ndfmap::report::FlipMetric`]).
#[cfg(feature = "report")]
fn flip_metric(reference: &[u8], test: &[u8], width: u32, height: u32) -> (Vec<f32>, Vec<u8>) {
    let r = nv_flip::FlipImageRgb8::with_data(width, height, reference);
    let t = nv_flip::FlipImageRgb8::with_data(width, height, test);
    let map = nv_flip::flip(r, t, nv_flip::DEFAULT_PIXELS_PER_DEGREE);
    (
        map.to_vec(),
        map.apply_color_lut(&nv_flip::magma_lut()).to_vec(),
    )
}

/// The frame times of --frame-times, if given.
#[cfg(feature = "report")]
fn load_frame_times(a: &ReportArgs) -> Result<Option<ndfmap::report::frame::FrameTimes>> {
    a.frame_times
        .as_ref()
        .map(|path| {
            let text = ndfmap::ingest::read_text_file(path)?;
            ndfmap::report::frame::FrameTimes::from_json(&text).map_err(|message| Error::Decode {
                path: path.clone(),
                message,
            })
        })
        .transpose()
}

/// The shared normal maps' folder: $NDFMAP_DATA, else ../shared/data/normalmaps beside the
/// current folder or beside the source tree this binary was built from.
#[cfg(feature = "report")]
fn shared_maps_dir() -> Option<PathBuf> {
    std::env::var_os("NDFMAP_DATA")
        .map(PathBuf::from)
        .or_else(|| {
            [
                PathBuf::from("../shared/data/normalmaps"),
                Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/normalmaps"),
            ]
            .into_iter()
            .find(|d| d.is_dir())
        })
}

/// `ndfmap report`: measure, then write the report with a progress bar.
#[cfg(feature = "report")]
fn report(a: ReportArgs) -> Result<()> {
    use ndfmap::report::{ImageSet, MapInput, Progress, ReportOptions};
    if let Some(path) = &a.from_json {
        let text = ndfmap::ingest::read_text_file(path)?;
        let mut rep: ndfmap::report::Report =
            serde_json::from_str(&text).map_err(|e| Error::Decode {
                path: path.clone(),
                message: ndfmap::error::clip_message(
                    &e.to_string(),
                    ndfmap::error::MAX_PARSE_ERROR_CHARS,
                ),
            })?;
        if a.frame_times.is_some() {
            let given = load_frame_times(&a)?;
            attach_frame_times(&a, given, &mut rep);
        }
        ndfmap::report::write(&rep, &a.output)?;
        println!("report: {}", a.output.join("report.md").display());
        return Ok(());
    }
    let formats =
        |v: &[String]| -> Result<Vec<Format>> { v.iter().map(|f| f.trim().parse()).collect() };
    let tan_lobes: Vec<usize> = a
        .tan_lobes
        .iter()
        .map(|s| s.trim())
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse().map_err(|_| {
                Error::InvalidOption(format!("--tan-lobes {s} (expected lobe counts)"))
            })
        })
        .collect::<Result<_>>()?;
    let mut lobes_ok = a.lobes.clone();
    lobes_ok.extend(&tan_lobes);
    if let Some(j) = lobes_ok
        .iter()
        .find(|j| !(1..=ndfmap::em::MAX_LOBES).contains(j))
    {
        return Err(Error::InvalidOption(format!(
            "lobe count {j} (expected 1 to {})",
            ndfmap::em::MAX_LOBES
        )));
    }
    if !(8..=4096).contains(&a.size) {
        return Err(Error::InvalidOption(format!(
            "--size {} (expected 8 to 4096)",
            a.size
        )));
    }
    use ndfmap::report::MAX_SPP;
    if !(1..=MAX_SPP).contains(&a.spp) {
        return Err(Error::InvalidOption(format!(
            "--spp {} (expected 1 to {MAX_SPP})",
            a.spp
        )));
    }
    if a.convergence_spp > MAX_SPP {
        return Err(Error::InvalidOption(format!(
            "--convergence-spp {} (expected 0, to skip it, to {MAX_SPP})",
            a.convergence_spp
        )));
    }
    let max_env = ndfmap::envlight::MAX_SAMPLES;
    if !(1..=max_env).contains(&a.env_samples) {
        return Err(Error::InvalidOption(format!(
            "--env-samples {} (expected 1 to {max_env})",
            a.env_samples
        )));
    }
    check_exponents(&[a.s])?;
    let brdf = a
        .brdf
        .as_deref()
        .map(|b| parse_brdf(b, a.s, a.sigma, a.alpha))
        .transpose()?;
    let sh_lmax: Vec<usize> = a
        .sh_lmax
        .iter()
        .map(|s| s.trim())
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse()
                .ok()
                .filter(|l| *l <= ndfmap::sh::MAX_LMAX)
                .ok_or_else(|| Error::InvalidOption(format!("--sh-lmax {s} (expected 0 to 16)")))
        })
        .collect::<Result<_>>()?;
    if a.anisotropy == 1 || a.anisotropy > 16 {
        return Err(Error::InvalidOption(format!(
            "--anisotropy {} (expected 0, or 2 to 16)",
            a.anisotropy
        )));
    }
    let given_frame_times = load_frame_times(&a)?;
    // The environment first: a bad file or BRDF fails before the long run.
    let env = EnvArgs {
        env: a.env.clone(),
        env_route: Vec::new(),
        env_yaw: a.env_yaw,
        env_intensity: a.env_intensity,
        env_samples: a.env_samples,
        env_texels: 0,
        env_lights: a.env_lights,
        env_light_max_sr: 0.05,
    }
    .load(false)?;
    if env.is_none() && !a.env_albedo.is_empty() {
        return Err(Error::InvalidOption(
            "--env-albedo colours the --env section: give --env too".into(),
        ));
    }
    if env.is_some() {
        if !(1..=16).contains(&a.env_subpixels) {
            return Err(Error::InvalidOption(format!(
                "--env-subpixels {} (expected 1 to 16)",
                a.env_subpixels
            )));
        }
        ndfmap::envlight::check_brdf(
            &brdf
                .clone()
                .unwrap_or(ndfmap::brdf::Brdf::BlinnPhong { s: a.s }),
        )?;
    }
    let options = ReportOptions {
        image_size: a.size,
        spp: a.spp,
        convergence_spp: a.convergence_spp,
        exponent: a.s,
        lobes: a.lobes.clone(),
        align: parse_align(&a.align, AlignmentForm::Appendix)?,
        tan_lobes,
        formats: formats(&a.formats)?,
        image_formats: formats(&a.image_formats)?,
        images: choice::<ImageSet>("images", &a.images, "none, some, all")?,
        brdf,
        sh_lmax,
        anisotropy: a.anisotropy,
        ..ReportOptions::default()
    };
    let mut maps = a.maps.clone();
    if maps.is_empty() {
        // $NDFMAP_DATA, else ../shared/data/normalmaps beside the current folder or beside
        // the source tree this binary was built from.
        let dir = shared_maps_dir().unwrap_or_default();
        maps = ["rock.jpg", "bark.jpg", "metal.jpg", "facade.jpg"]
            .iter()
            .map(|n| dir.join(n))
            .filter(|p| p.exists())
            .collect();
    }
    let inputs = if maps.is_empty() {
        eprintln!(
            "no maps given or found: using the built-in sample ({0}x{0})",
            a.sample_size
        );
        vec![MapInput {
            name: "sample".into(),
            map: ndfmap::procedural::generate(a.sample_size.clamp(8, 4096), 2007).map,
        }]
    } else {
        ndfmap::report::load_maps(&maps)?
    };
    // Each map's albedo for the --env section, checked (and read) before the long run.
    let env_albedo: Vec<Option<NormalMap>> = if a.env_albedo.is_empty() {
        vec![None; inputs.len()]
    } else if a.env_albedo.len() != inputs.len() {
        return Err(Error::InvalidOption(format!(
            "--env-albedo: {} images for {} maps (one per map, `-` for none)",
            a.env_albedo.len(),
            inputs.len()
        )));
    } else {
        inputs
            .iter()
            .zip(&a.env_albedo)
            .map(|(input, path)| {
                (path.as_os_str() != "-")
                    .then(|| {
                        input
                            .map
                            .clone()
                            .with_feature_file(path, &IngestOptions::default())
                    })
                    .transpose()
            })
            .collect::<Result<_>>()?
    };
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{elapsed_precise} [{bar:30}] {pos}/{len} eta {eta} {msg}",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    let progress = |p: Progress| match p {
        Progress::Total(n) => bar.set_length(n),
        Progress::Step(s) => bar.set_message(s.to_string()),
        Progress::Done => bar.inc(1),
    };
    let mut rep = ndfmap::report::run(&inputs, &options, &a.output, &progress, flip_metric)?;
    let after_run = std::time::Instant::now();
    if !a.no_stability {
        progress(Progress::Step("stability sweep"));
        let w = ndfmap::report::Stopwatch::start();
        rep.stability = Some(ndfmap::report::stability::sweep(true));
        if let Some(p) = &mut rep.phases {
            w.stop(&mut p.stability);
        }
        progress(Progress::Done);
    }
    if !a.no_planner {
        bar.inc_length(1);
        let w = ndfmap::report::Stopwatch::start();
        let step = |name: &str| progress(Progress::Step(&format!("planner: {name}")));
        rep.planner = Some(ndfmap::report::planner::section(
            shared_maps_dir().as_deref(),
            ndfmap::report::planner::SAMPLE_SIDE,
            &step,
        ));
        if let Some(p) = &mut rep.phases {
            w.stop(&mut p.planner);
        }
        progress(Progress::Done);
    }
    if let Some((name, light)) = &env {
        use ndfmap::report::env::{EnvImageOptions, EnvSection, measure};
        let mut section = EnvSection {
            environment: name.clone(),
            options: EnvImageOptions {
                subpixels: a.env_subpixels,
                samples: a.env_samples,
                lobes: a.lobes.iter().max().map(|&j| vec![j]).unwrap_or_default(),
                tan_lobes: options
                    .tan_lobes
                    .iter()
                    .max()
                    .map(|&j| vec![j])
                    .unwrap_or_default(),
                ..EnvImageOptions::default()
            },
            brdf: options.material_brdf().to_string(),
            ground_truth: Vec::new(),
            rows: Vec::new(),
            skipped: Vec::new(),
        };
        for (input, coloured) in inputs.iter().zip(&env_albedo) {
            bar.inc_length(1);
            progress(Progress::Step(&format!("environment: {}", input.name)));
            let scenes = ndfmap::report::views(&options, input.map.width());
            let map = coloured.as_ref().unwrap_or(&input.map);
            measure(&input.name, map, &scenes, light, &mut section)?;
            progress(Progress::Done);
        }
        rep.env = Some(section);
    }
    bar.inc_length(1);
    progress(Progress::Step("frame times"));
    let w = ndfmap::report::Stopwatch::start();
    attach_frame_times(&a, given_frame_times, &mut rep);
    if let Some(p) = &mut rep.phases {
        w.stop(&mut p.frame_times);
    }
    progress(Progress::Done);
    bar.finish_and_clear();
    // The totals cover the sections measured after `run` too.
    rep.extend_totals(after_run.elapsed());
    let t = std::time::Instant::now();
    ndfmap::report::write(&rep, &a.output)?;
    println!(
        "report: {} ({} rows, {:.0} s; writing it and the plots {:.1} s)",
        a.output.join("report.md").display(),
        rep.rows.len(),
        rep.seconds,
        t.elapsed().as_secs_f64()
    );
    if let Some(p) = &rep.phases {
        println!("phases: {}", p.summary());
    }
    Ok(())
}

/// `ndfmap pbr-report`: every map at every α, markdown to stdout (module `report::pbr`).
#[cfg(feature = "report")]
fn pbr_report(
    inputs: &[PathBuf],
    alphas: &[f64],
    levels: (usize, usize),
    no_vmf: bool,
    fit_max_angle: Option<f64>,
    json: Option<PathBuf>,
) -> Result<()> {
    use ndfmap::report::pbr::{compare, find_filament, markdown};
    if let Some(bad) = alphas.iter().find(|a| !(**a > 0.0 && **a <= 1.0)) {
        return Err(Error::InvalidOption(format!(
            "--alpha {} (expected 0 < α ≤ 1)",
            compact_f64(*bad)
        )));
    }
    if levels.0 > levels.1 {
        return Err(Error::InvalidOption(format!(
            "--first-level {} is after --last-level {}",
            levels.0, levels.1
        )));
    }
    let filament = find_filament();
    match &filament {
        Some(p) => println!("Filament's tool: {}\n", p.display()),
        None => println!("roughness-prefilter is not on PATH: Filament's rows are absent\n"),
    }
    let mut all = Vec::new();
    for input in inputs {
        let map = NormalMap::load(input, &ndfmap::IngestOptions::default())?;
        let name = input
            .file_stem()
            .map_or("map".into(), |s| s.to_string_lossy().into_owned());
        let vmf = if no_vmf {
            None
        } else {
            let t = Instant::now();
            let b = bake_with(
                &map,
                Method::Vmf,
                &BakeOptions {
                    lobes: 6,
                    align: Some(AlignmentForm::default().default_strength()),
                    ..BakeOptions::default()
                },
            )?;
            eprintln!(
                "{name}: vMF J = 6 baked in {:.1} s",
                t.elapsed().as_secs_f64()
            );
            Some(b)
        };
        for &a in alphas {
            let c = compare(
                &map,
                &name,
                a,
                levels,
                vmf.as_ref(),
                filament.as_deref(),
                fit_max_angle,
            )?;
            print!("{}", markdown(&c));
            all.push(c);
        }
    }
    if let Some(path) = json {
        let text = serde_json::to_string_pretty(&all).map_err(|e| Error::Write {
            path: path.clone(),
            message: e.to_string(),
        })?;
        std::fs::write(&path, text).map_err(|e| Error::Write {
            path: path.clone(),
            message: e.to_string(),
        })?;
    }
    Ok(())
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => return command_line_error(e),
    };
    match run(cli) {
        Ok(status) => ExitCode::from(status),
        Err(e) => {
            print_error(&e.to_string());
            ExitCode::FAILURE
        }
    }
}

/// The longest error line the CLI prints, in characters: twice the longest path Linux opens
/// (4096 bytes), so a real message is never cut, while one quoting a megabyte-long value
/// from an input file (a batch entry's path) stays readable.
const MAX_ERROR_CHARS: usize = 8192;

/// One error line: `text`'s whitespace runs (line breaks included) as single spaces, cut to
/// [`MAX_ERROR_CHARS`].
fn one_line(text: &str) -> String {
    let text = text.split_whitespace().collect::<Vec<_>>().join(" ");
    ndfmap::error::clip_message(&text, MAX_ERROR_CHARS)
}

/// Prints `text` as the CLI's one error line, `ndfmap: error: …`, whatever line breaks a
/// decoder's (or clap's) message holds.
fn print_error(text: &str) {
    eprintln!("ndfmap: error: {}", one_line(text));
}

/// A command line clap refuses: help and version as clap prints them; anything else as one
/// line, `ndfmap: error: …` (clap's first paragraph: what is wrong; its tip and usage dropped),
/// exit status 2 as clap's.
fn command_line_error(e: clap::Error) -> ExitCode {
    use clap::error::ErrorKind;
    match e.kind() {
        ErrorKind::DisplayHelp
        | ErrorKind::DisplayVersion
        | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand => e.exit(),
        _ => {
            // The first paragraph (a missing argument's names follow its line), on one line.
            let text = e.render().to_string();
            let first: Vec<&str> = text
                .lines()
                .skip_while(|l| l.trim().is_empty())
                .take_while(|l| !l.trim().is_empty())
                .collect();
            let first = first.join(" ");
            let first = first.trim_start().strip_prefix("error: ").unwrap_or(&first);
            print_error(&format!("{first} (--help lists the options)"));
            ExitCode::from(2)
        }
    }
}
