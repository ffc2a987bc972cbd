//! Error against run time (DESIGN.md "Ground truth and error"): for each map, every method and
//! storage format is baked (timed, peak memory), measured in texel space ([`crate::eval`]) and
//! in image space ([`crate::render`]: supersampled ground truth vs the CPU twin of the shaders,
//! relative RMSE and FLIP), and costed (texture bytes, fetches and ALU operations per pixel from
//! the specialized shader, [`cost`]; frame times from the sample viewer's benchmark, [`frame`]).
//! [`write()`] turns the rows into `report.md`, `report.json` and plots ([`plot`]).
//!
//! Memory stays bounded: each configuration is baked, measured in every format and dropped
//! before the next; only the ground-truth images of the current map are kept.

pub mod cost;
pub mod env;
pub mod frame;
pub mod pbr;
pub mod planner;
pub mod plot;
pub mod stability;

use crate::bake::{Bake, BakeOptions, Method};
use crate::brdf::Brdf;
use crate::error::{Error, Result};
use crate::eval::{Reference, default_directions, evaluate_from};
use crate::format::Format;
use crate::ingest::NormalMap;
use crate::methods::bake_with;
use crate::render::{
    Camera, Footprint, Image, Light, Material, Scene, Surface, ViewGeometry, common_mask,
    distance_for_lod, exposure, lod_image, mean_radiance, relative_rmse, render_filtered_prepared,
    render_footprint, render_ground_truth, tonemap,
};
use crate::usage::{cpu_seconds, load_average, peak_rss, reset_peak_rss, rss};
use glam::DVec3;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

pub use cost::ShaderCost;

/// Which images [`run`] writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ImageSet {
    /// None.
    None,
    /// Ground truth of every view, and the renders and FLIP maps of a few configurations
    /// ([`REPRESENTATIVE`]) in f32.
    Some,
    /// Every configuration and format.
    All,
}

/// The configurations whose images [`ImageSet::Some`] writes (labels, f32).
pub const REPRESENTATIVE: [&str; 5] = ["plain", "toksvig", "lean", "vmf6", "vmf6a"];

/// Bytes of texel-space exact answers [`run`] keeps per map ([`Reference`]); a larger map's
/// are recomputed for every configuration.
const REFERENCE_BUDGET: u64 = 512 << 20;

/// The most ground-truth samples per pixel [`ReportOptions::spp`] and
/// [`ReportOptions::convergence_spp`] may ask for: 2¹⁶, 64 times the convergence default
/// (1024). The run time grows with them, so an absurd count is refused instead of running for
/// days.
pub const MAX_SPP: u32 = 1 << 16;

/// What to measure and how.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReportOptions {
    /// Side of every rendered view, pixels.
    pub image_size: u32,
    /// Ground-truth samples per pixel, 1 to [`MAX_SPP`].
    pub spp: u32,
    /// Samples per pixel of the second ground truth used to estimate the first's Monte Carlo
    /// error on one view (0 skips it), at most [`MAX_SPP`].
    pub convergence_spp: u32,
    /// Seed of the ground truth's jitter.
    pub seed: u64,
    /// Blinn-Phong exponent of the material (images and texel space).
    pub exponent: f64,
    /// Lambert weight of the material.
    pub kd: f64,
    /// Specular weight of the material.
    pub ks: f64,
    /// vMF lobe counts.
    pub lobes: Vec<usize>,
    /// vMF alignments (`None` unaligned, `Some(C)` aligned with the default eq 29 form).
    pub align: Vec<Option<f64>>,
    /// Tan 2005 lobe counts (unaligned).
    pub tan_lobes: Vec<usize>,
    /// Storage formats measured in texel space.
    pub formats: Vec<Format>,
    /// Storage formats also rendered in image space (narrower than f32: only for the
    /// [`REPRESENTATIVE`] configurations, to bound the run time).
    pub image_formats: Vec<Format>,
    /// Samples per tap texel of the ideal-NDF render ([`crate::render::render_oracle`]) that
    /// measures the floor GL's footprint sets (0 skips it).
    pub oracle_samples: u32,
    /// Levels of detail at the centre of the zoom sequence's views.
    pub zoom_lods: Vec<f64>,
    /// Use every `directions_step`-th light/view pair of [`default_directions`] in texel space.
    pub directions_step: usize,
    /// Images to write.
    pub images: ImageSet,
    /// The material's specular BRDF instead of Blinn-Phong `exponent` (GGX, eq 18, Lambert,
    /// tabulated).
    #[serde(default)]
    pub brdf: Option<Brdf>,
    /// SH band limits l* (one row each).
    #[serde(default = "default_sh_lmax")]
    pub sh_lmax: Vec<usize>,
    /// Anisotropic filtering with at most this many probes ([`crate::sample::aniso_probes`]):
    /// the floor of its footprint per view, and the image error of the configurations whose
    /// parameters filter linearly (baselines, SH, aligned vMF) under it, f32. 0: off.
    #[serde(default)]
    pub anisotropy: u32,
}

fn default_sh_lmax() -> Vec<usize> {
    vec![2, 4, 6, 8]
}

impl ReportOptions {
    /// The material's specular BRDF: [`ReportOptions::brdf`], else Blinn-Phong with
    /// [`ReportOptions::exponent`].
    pub fn material_brdf(&self) -> Brdf {
        self.brdf
            .clone()
            .unwrap_or(Brdf::BlinnPhong { s: self.exponent })
    }
}

impl Default for ReportOptions {
    fn default() -> Self {
        ReportOptions {
            image_size: 256,
            spp: 256,
            convergence_spp: 1024,
            seed: 2007,
            exponent: 128.0,
            kd: 0.3,
            ks: 0.7,
            lobes: vec![1, 2, 4, 6, 8],
            align: vec![
                None,
                Some(crate::em::AlignmentForm::Appendix.default_strength()),
            ],
            tan_lobes: vec![4],
            formats: vec![Format::F32, Format::F16, Format::Unorm8],
            image_formats: vec![Format::F32, Format::F16],
            oracle_samples: 64,
            zoom_lods: vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
            directions_step: 3,
            images: ImageSet::Some,
            brdf: None,
            sh_lmax: default_sh_lmax(),
            anisotropy: 0,
        }
    }
}

/// One configuration to bake: a method and its options.
#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    /// The method.
    pub method: Method,
    /// Its options (lobes and alignment for mixtures).
    pub options: BakeOptions,
}

impl Config {
    /// The label its bake will have ([`Bake::label`] in f32).
    pub fn label(&self) -> String {
        match self.method {
            Method::Sh => format!("sh{}", self.options.lmax),
            Method::Vmf | Method::Tan2005 => {
                let mut l = self.method.name().to_string();
                if l.ends_with(|c: char| c.is_ascii_digit()) {
                    l.push('-');
                }
                l += &self.options.lobes.to_string();
                if let Some(c) = self.options.align {
                    l.push('a');
                    l += &crate::bake::strength_suffix(
                        c,
                        self.options.default_align_strength(self.method),
                    );
                }
                l
            }
            m => m.name().to_string(),
        }
    }

    /// Whether its parameters filter linearly, so hardware (and anisotropic) filtering is
    /// exact: the baselines, SH, aligned vMF lobes.
    pub fn filters_linearly(&self) -> bool {
        match self.method {
            Method::Vmf | Method::Tan2005 => self.options.align.is_some(),
            _ => true,
        }
    }
}

/// The configurations of `options`: the four baselines, SH per band limit, Tan 2005 per lobe
/// count, vMF per lobe count and alignment.
pub fn configs(options: &ReportOptions) -> Vec<Config> {
    let mut out: Vec<Config> = Method::BASELINES
        .iter()
        .map(|&method| Config {
            method,
            options: BakeOptions::default(),
        })
        .collect();
    for &lmax in &options.sh_lmax {
        out.push(Config {
            method: Method::Sh,
            options: BakeOptions {
                lmax,
                ..BakeOptions::default()
            },
        });
    }
    for &lobes in &options.tan_lobes {
        out.push(Config {
            method: Method::Tan2005,
            options: BakeOptions {
                lobes,
                ..BakeOptions::default()
            },
        });
    }
    for &align in &options.align {
        for &lobes in &options.lobes {
            out.push(Config {
                method: Method::Vmf,
                options: BakeOptions {
                    lobes,
                    align,
                    ..BakeOptions::default()
                },
            });
        }
    }
    out
}

/// A view of the report: its scene and where it stands in the MIP chain.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct View {
    /// The scene.
    pub scene: Scene,
    /// Median level of detail over the covered pixels.
    pub median_lod: f64,
    /// The ideal NDF method under GL's sampling against the ground truth (the floor every
    /// method shares), when measured.
    pub floor: Option<ViewError>,
    /// Whether it counts as a far view (median λ ≥ 3) in the headline numbers.
    pub far: bool,
    /// The ideal NDF under the anisotropic footprint ([`ReportOptions::anisotropy`]) against
    /// the ground truth, when measured.
    #[serde(default)]
    pub aniso_floor: Option<ViewError>,
}

/// The report's views of a map of `texels` texels across: the zoom sequence on a plane tilted
/// 30° (a point light at the mirror position puts the highlight at the centre, a directional
/// light from the side), a grazing view (12° above the horizon, back-lit at the mirror angle),
/// and a sphere (8 × 4 repeats) lit by a point and a directional light.
pub fn views(options: &ReportOptions, texels: u32) -> Vec<Scene> {
    let px = options.image_size;
    let material = Material {
        kd: options.kd,
        ks: options.ks,
        brdf: options.material_brdf(),
    };
    let fov = 30.0;
    let tile = 1.0;
    // Every view: square, 30° field of view, +z up.
    let camera = |eye: DVec3, target: DVec3| Camera {
        eye,
        target,
        up: DVec3::Z,
        fov_y_deg: fov,
        width: px,
        height: px,
    };
    let mut out = Vec::new();
    for &lambda in &options.zoom_lods {
        let tilt = 30f64.to_radians();
        let d = distance_for_lod(lambda, 30.0, texels, tile, px, fov);
        let eye = DVec3::new(0.0, -d * tilt.sin(), d * tilt.cos());
        out.push(Scene {
            name: format!("zoom{lambda}"),
            camera: camera(eye, DVec3::ZERO),
            surface: Surface::Plane { tile },
            lights: vec![
                Light::Point {
                    position: DVec3::new(0.0, d * tilt.sin(), d * tilt.cos()),
                    intensity: d * d,
                },
                Light::Directional {
                    direction: DVec3::new(1.0, 0.0, 1.0).normalize(),
                    radiance: 0.5,
                },
            ],
            material: material.clone(),
        });
    }
    // Grazing: 12° above the horizon, λ ≈ 4 at the centre, the horizon near the top.
    let elev = 12f64.to_radians();
    let d = distance_for_lod(4.0, 78.0, texels, tile, px, fov);
    let h = d * elev.sin();
    out.push(Scene {
        name: "grazing".into(),
        camera: camera(
            DVec3::new(0.0, 0.0, h),
            DVec3::new(0.0, d * elev.cos(), 0.0),
        ),
        surface: Surface::Plane { tile },
        lights: vec![
            Light::Directional {
                direction: DVec3::new(0.0, elev.cos(), elev.sin()),
                radiance: 1.0,
            },
            Light::Point {
                position: DVec3::new(0.3 * d, 0.2 * d, 0.5 * d),
                intensity: 0.25 * d * d,
            },
        ],
        material: material.clone(),
    });
    out.push(Scene {
        name: "sphere".into(),
        camera: camera(DVec3::new(0.0, -4.5, 1.0), DVec3::ZERO),
        surface: Surface::Sphere {
            center: DVec3::ZERO,
            radius: 1.0,
            tiles_u: 8.0,
            tiles_v: 4.0,
        },
        lights: vec![
            Light::Point {
                position: DVec3::new(-2.0, -4.0, 2.5),
                intensity: 25.0,
            },
            Light::Directional {
                direction: DVec3::new(1.0, -0.5, 0.6).normalize(),
                radiance: 0.6,
            },
        ],
        material,
    });
    out
}

/// A map to report on.
pub struct MapInput {
    /// Its name in tables and file names.
    pub name: String,
    /// The normals.
    pub map: NormalMap,
}

/// One configuration's error in one view.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ViewError {
    /// The view's name.
    pub view: String,
    /// Relative RMSE against the ground truth over fully covered pixels.
    pub rel_rmse: f64,
    /// Mean FLIP over the same pixels (tone-mapped LDR images, 67 pixels per degree).
    pub flip: f64,
    /// Mean radiance of the render over the ground truth's (energy).
    pub energy_ratio: f64,
    /// Pixels that were NaN or infinite.
    pub nonfinite: usize,
}

/// One configuration in one format on one map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Row {
    /// The map.
    pub map: String,
    /// The configuration's label in f32 (`vmf6a`).
    pub config: String,
    /// The bake's label (`vmf6a f16`).
    pub label: String,
    /// The method.
    pub method: Method,
    /// Lobes (mixtures), 0 otherwise.
    pub lobes: usize,
    /// Aligned lobes.
    pub aligned: bool,
    /// Storage format.
    pub format: Format,
    /// Bake wall time, seconds (the f32 bake; formats only round it).
    pub bake_seconds: f64,
    /// Peak resident memory during the bake above what was resident before it, bytes.
    pub bake_peak_bytes: Option<u64>,
    /// Bytes of every texture the shader samples, all levels, in this format.
    pub texture_bytes: u64,
    /// Shading cost per pixel.
    pub cost: ShaderCost,
    /// Frame time on a GL device, ms: the viewer benchmark's median, mean over its views
    /// ([`frame::FrameTimes::lookup`]; `None` when not measured for this label and format).
    pub frame_ms: Option<f64>,
    /// `frame_ms` over the plain shader's in the same format (what is comparable across
    /// machines, and all that a software rasterizer says).
    #[serde(default)]
    pub frame_ratio: Option<f64>,
    /// Texel-space relative RMS error of the specular term over levels ≥ 1 ([`crate::eval`]).
    pub texel_specular: f64,
    /// The same for the Lambert term.
    pub texel_diffuse: f64,
    /// Texel-space specular error per level (level 0 not measured: 0).
    pub texel_levels: Vec<f64>,
    /// Image-space errors per view (empty when this format is not rendered).
    pub views: Vec<ViewError>,
    /// Image-space errors per view under anisotropic filtering ([`ReportOptions::anisotropy`];
    /// f32 configurations that filter linearly).
    #[serde(default)]
    pub aniso_views: Vec<ViewError>,
}

impl Row {
    /// Mean relative RMSE over the views (`None` when not rendered).
    pub fn image_rmse(&self) -> Option<f64> {
        mean(self.views.iter().map(|v| v.rel_rmse))
    }

    /// Mean FLIP over the views.
    pub fn image_flip(&self) -> Option<f64> {
        mean(self.views.iter().map(|v| v.flip))
    }

    /// Mean over the far views of `map` of the error above the view's floor,
    /// `sqrt(max(e² − floor², 0))` (errors add in quadrature when independent).
    pub fn far_excess(&self, map: &MapSummary) -> Option<f64> {
        mean(self.views.iter().filter_map(|v| {
            let view = map.views.iter().find(|w| w.scene.name == v.view && w.far)?;
            let f = view.floor.as_ref()?.rel_rmse;
            Some((v.rel_rmse * v.rel_rmse - f * f).max(0.0).sqrt())
        }))
    }

    /// Mean relative RMSE over the far views of `map`.
    pub fn far_rmse(&self, map: &MapSummary) -> Option<f64> {
        mean(
            self.views
                .iter()
                .filter(|v| map.views.iter().any(|w| w.scene.name == v.view && w.far))
                .map(|v| v.rel_rmse),
        )
    }
}

fn mean(it: impl Iterator<Item = f64>) -> Option<f64> {
    let (mut s, mut n) = (0.0, 0usize);
    for v in it {
        s += v;
        n += 1;
    }
    (n > 0).then(|| s / n as f64)
}

/// What the report found about one map and its ground truth.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MapSummary {
    /// Name.
    pub name: String,
    /// Width and height.
    pub size: (u32, u32),
    /// The views.
    pub views: Vec<View>,
    /// Seconds spent rendering the ground truth of every view.
    pub ground_truth_seconds: f64,
    /// Estimated relative RMS Monte Carlo error of the `spp` ground truth (from a second
    /// render at `convergence_spp` of one view), and that view's name.
    pub ground_truth_error: Option<(String, f64)>,
    /// Configurations skipped in some format, and why.
    pub skipped: Vec<String>,
}

/// Everything measured.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Report {
    /// The options.
    pub options: ReportOptions,
    /// Per map.
    pub maps: Vec<MapSummary>,
    /// Per map, configuration and format.
    pub rows: Vec<Row>,
    /// Worker threads.
    pub threads: usize,
    /// Wall seconds of [`run`]; `ndfmap report` adds the sections it measures after it
    /// (stability, planner, environment, frame times: [`Report::extend_totals`]), so its
    /// figure is the whole report's.
    pub seconds: f64,
    /// CPU seconds (user + system, all threads) of the process and its waited-for children at
    /// the end of [`run`] (Linux; `ndfmap report`: at the end of its last section).
    #[serde(default)]
    pub cpu_seconds: Option<f64>,
    /// `/proc/loadavg`'s 1-minute load at the start and the end of [`run`] (Linux; `ndfmap
    /// report`: the end of its last section): other work on the machine slows the wall times
    /// down.
    #[serde(default)]
    pub load_average: Option<(f64, f64)>,
    /// Stability sweep (cases × methods), when run.
    pub stability: Option<stability::Summary>,
    /// Where the wall time went, by phase (absent in reports written before it was recorded).
    #[serde(default)]
    pub phases: Option<PhaseSeconds>,
    /// The viewer benchmark's frame times the rows' `frame_ms` come from, when there were any.
    #[serde(default)]
    pub frame_times: Option<frame::FrameTimes>,
    /// Why there are no frame times, or where they came from.
    #[serde(default)]
    pub frame_times_note: Option<String>,
    /// The planner section (issue 18), when run.
    #[serde(default)]
    pub planner: Option<planner::Section>,
    /// The environment-lit image-space section (issue 16, `report --env`), when run.
    #[serde(default)]
    pub env: Option<env::EnvSection>,
}

impl Report {
    /// Extends the totals ([`Report::seconds`], [`Report::cpu_seconds`], the end of
    /// [`Report::load_average`]) over `extra` wall time spent after [`run`] on the sections
    /// measured after it (stability, planner, environment, frame times), so they describe the
    /// whole report: call it once, after the last section.
    pub fn extend_totals(&mut self, extra: std::time::Duration) {
        self.seconds += extra.as_secs_f64();
        self.cpu_seconds = cpu_seconds().or(self.cpu_seconds);
        if let (Some((start, end)), now) = (self.load_average, load_average()) {
            self.load_average = Some((start, now.unwrap_or(end)));
        }
    }

    /// Fills every row's `frame_ms` and `frame_ratio` from `times` (by configuration label and
    /// format; rows the benchmark did not draw get `None`) and keeps `times` in the report.
    pub fn set_frame_times(&mut self, times: frame::FrameTimes) {
        for r in &mut self.rows {
            let found = times.lookup(&r.config, r.format);
            r.frame_ms = found.map(|f| f.0);
            r.frame_ratio = found.and_then(|f| f.1);
        }
        self.frame_times = Some(times);
    }
}

/// Wall and CPU seconds of one phase of a report.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct PhaseTime {
    /// Wall seconds.
    pub wall: f64,
    /// CPU seconds of the process in it (user + system, all threads; Linux, else 0): less
    /// sensitive than `wall` to other work on the machine.
    pub cpu: f64,
}

/// Where a report's run time goes, by phase, summed over the maps.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PhaseSeconds {
    /// Supersampled ground truth of every view ([`render_ground_truth`]), with its LOD image.
    pub ground_truth: PhaseTime,
    /// The ideal-NDF render of every view ([`crate::render::render_oracle`]).
    pub oracle: PhaseTime,
    /// The second, denser ground truth that estimates the first's Monte Carlo error.
    pub convergence: PhaseTime,
    /// Bakes (the f32 bake of every configuration).
    pub bake: PhaseTime,
    /// Quantizing the bakes to the narrower formats.
    pub quantize: PhaseTime,
    /// Texel-space error ([`evaluate_from`]).
    pub texel_eval: PhaseTime,
    /// Shader cost (`glslangValidator` and the SPIR-V count), once per label and format.
    pub shader_cost: PhaseTime,
    /// Filtered renders through the CPU twin of the shaders.
    pub filtered_render: PhaseTime,
    /// Error metrics, tone mapping and FLIP of every render (the oracle's included).
    pub compare: PhaseTime,
    /// Writing PNG images.
    pub images: PhaseTime,
    /// Frame times: running the viewer's benchmark, or reading its JSON.
    pub frame_times: PhaseTime,
    /// The stability sweep.
    pub stability: PhaseTime,
    /// The planner section.
    #[serde(default)]
    pub planner: PhaseTime,
}

impl PhaseSeconds {
    /// The phases as (name, time), in the order they run.
    pub fn list(&self) -> [(&'static str, PhaseTime); 13] {
        [
            ("ground truth", self.ground_truth),
            ("ideal-NDF floor", self.oracle),
            ("convergence", self.convergence),
            ("bake", self.bake),
            ("quantize", self.quantize),
            ("texel eval", self.texel_eval),
            ("shader cost", self.shader_cost),
            ("filtered render", self.filtered_render),
            ("compare + FLIP", self.compare),
            ("images", self.images),
            ("frame times", self.frame_times),
            ("stability", self.stability),
            ("planner", self.planner),
        ]
    }

    /// One line, `name wall s (cpu CPU-s), …`, of every phase that took 0.05 s or more.
    pub fn summary(&self) -> String {
        self.list()
            .iter()
            .filter(|(_, t)| t.wall >= 0.05)
            .map(|(n, t)| format!("{n} {:.1} s ({:.0} CPU-s)", t.wall, t.cpu))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// Measures a stretch of work into a [`PhaseTime`].
pub struct Stopwatch {
    wall: Instant,
    cpu: Option<f64>,
}

impl Stopwatch {
    /// Starts now.
    pub fn start() -> Stopwatch {
        Stopwatch {
            wall: Instant::now(),
            cpu: cpu_seconds(),
        }
    }

    /// Adds the time since [`Stopwatch::start`] to `into`; returns the wall seconds.
    pub fn stop(self, into: &mut PhaseTime) -> f64 {
        let wall = self.wall.elapsed().as_secs_f64();
        into.wall += wall;
        if let (Some(a), Some(b)) = (self.cpu, cpu_seconds()) {
            into.cpu += (b - a).max(0.0);
        }
        wall
    }
}

/// Runs `f`, adding its wall and CPU seconds to `acc`.
fn timed<T>(acc: &mut PhaseTime, f: impl FnOnce() -> T) -> T {
    let w = Stopwatch::start();
    let out = f();
    w.stop(acc);
    out
}

/// Progress of [`run`], for a progress bar.
#[derive(Debug, Clone, Copy)]
pub enum Progress<'a> {
    /// The number of steps to come.
    Total(u64),
    /// A step is starting.
    Step(&'a str),
    /// The step finished.
    Done,
}

fn write_err(path: &Path, e: impl std::fmt::Display) -> Error {
    Error::Write {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// Writes an RGB8 PNG.
pub fn save_rgb(path: &Path, width: u32, height: u32, rgb: Vec<u8>) -> Result<()> {
    image::RgbImage::from_raw(width, height, rgb)
        .expect("buffer matches the size")
        .save(path)
        .map_err(|e| write_err(path, e))
}

/// A perceptual image metric: per-pixel error values of tone-mapped 8-bit RGB `test` against
/// `reference` (both `width × height`, rows top first), and the error map as RGB for a person
/// to look at. `ndfmap report` passes NVIDIA's FLIP (LDR, 67 pixels per degree, crate `nv-flip`,
/// in the binary so that the library, and the C libraries built from it, carry no C++).
pub type FlipMetric =
    fn(reference: &[u8], test: &[u8], width: u32, height: u32) -> (Vec<f32>, Vec<u8>);

/// `metric` of tone-mapped `test` against tone-mapped `reference`: the mean over `mask` and the
/// error map.
fn flip(
    metric: FlipMetric,
    reference: &[u8],
    test: &[u8],
    width: u32,
    height: u32,
    mask: &[bool],
) -> (f64, Vec<u8>) {
    let (values, map) = metric(reference, test, width, height);
    let m = mean(
        values
            .iter()
            .zip(mask)
            .filter(|(_, m)| **m)
            .map(|(&v, _)| v as f64),
    )
    .unwrap_or(0.0);
    (m, map)
}

/// Tone-mapped RGB of `image` with pixels outside `mask` taken from `fill` (so FLIP and the
/// pictures compare filtering, not silhouette antialiasing).
fn masked_tonemap(image: &Image, fill: &Image, mask: &[bool], exposure: f64) -> Vec<u8> {
    let mut merged = image.clone();
    for ((p, &f), &m) in merged.pixels.iter_mut().zip(&fill.pixels).zip(mask) {
        if !m {
            *p = f;
        }
    }
    tonemap(&merged, exposure)
}

/// A label as part of a file name: `vmf6a(C=1) f16` → `vmf6a-c1_f16`.
fn file_label(label: &str) -> String {
    crate::bake::file_label(label).replace(' ', "_")
}

/// Compares a render with the ground truth of its view: the errors, the tone-mapped render
/// (uncovered pixels from the ground truth) and the FLIP map.
fn compare(
    metric: FlipMetric,
    scene: &Scene,
    gt: &Image,
    img: &Image,
    exposure: f64,
) -> (ViewError, Vec<u8>, Vec<u8>) {
    let mask = common_mask(gt, img);
    let nonfinite = img.pixels.iter().filter(|p| !p.is_finite()).count();
    let rel_rmse = relative_rmse(gt, img, &mask);
    let energy_ratio = {
        let g = mean_radiance(gt, &mask);
        if g > 0.0 {
            mean_radiance(img, &mask) / g
        } else {
            1.0
        }
    };
    let gt_rgb = tonemap(gt, exposure);
    let test_rgb = masked_tonemap(img, gt, &mask, exposure);
    let (flip_mean, flip_map) = flip(metric, &gt_rgb, &test_rgb, gt.width, gt.height, &mask);
    (
        ViewError {
            view: scene.name.clone(),
            rel_rmse,
            flip: flip_mean,
            energy_ratio,
            nonfinite,
        },
        test_rgb,
        flip_map,
    )
}

/// Measures every configuration of `options` on every map; writes images under
/// `out/images/<map>/` as `options.images` asks. `progress` hears of every step. A sample
/// count outside its range ([`MAX_SPP`]) is [`crate::Error::InvalidOption`] before any work.
pub fn run(
    maps: &[MapInput],
    options: &ReportOptions,
    out: &Path,
    progress: &(dyn Fn(Progress) + Sync),
    metric: FlipMetric,
) -> Result<Report> {
    if !(1..=MAX_SPP).contains(&options.spp) || options.convergence_spp > MAX_SPP {
        return Err(crate::Error::InvalidOption(format!(
            "report: spp {} / convergence spp {} (expected 1 to {MAX_SPP} / 0 to {MAX_SPP})",
            options.spp, options.convergence_spp
        )));
    }
    let start = Instant::now();
    let load_start = load_average();
    let configs = configs(options);
    progress(Progress::Total(
        (maps.len() * (configs.len() + 2)) as u64 + 1,
    ));
    let directions: Vec<_> = default_directions()
        .into_iter()
        .step_by(options.directions_step.max(1))
        .collect();
    let brdf = options.material_brdf();
    let mut costs: std::collections::HashMap<String, ShaderCost> = Default::default();
    let mut ph = PhaseSeconds::default();
    let mut summaries = Vec::new();
    let mut rows = Vec::new();
    for input in maps {
        let map = &input.map;
        let image_dir = out.join("images").join(&input.name);
        if options.images != ImageSet::None {
            std::fs::create_dir_all(&image_dir).map_err(|e| write_err(&image_dir, e))?;
        }
        // Ground truth of every view.
        progress(Progress::Step(&format!("{}: ground truth", input.name)));
        let t = Instant::now();
        let scenes = views(options, map.width().max(map.height()));
        let mut views_info = Vec::new();
        let mut truths = Vec::new();
        for (i, scene) in scenes.iter().enumerate() {
            let (gt, mut lods) = timed(&mut ph.ground_truth, || {
                let gt = render_ground_truth(scene, map, options.spp, options.seed + i as u64);
                let lods: Vec<f64> = lod_image(scene, (map.width(), map.height()))
                    .into_iter()
                    .filter(|l| l.is_finite())
                    .collect();
                (gt, lods)
            });
            lods.sort_by(f64::total_cmp);
            let median_lod = lods.get(lods.len() / 2).copied().unwrap_or(f64::NAN);
            let exp = exposure(&gt);
            if options.images != ImageSet::None {
                let path = image_dir.join(format!("{}_ground_truth.png", scene.name));
                timed(&mut ph.images, || {
                    save_rgb(&path, gt.width, gt.height, tonemap(&gt, exp))
                })?;
            }
            let floor = if options.oracle_samples > 0 {
                let oracle = timed(&mut ph.oracle, || {
                    crate::render::render_oracle(
                        scene,
                        map,
                        options.oracle_samples,
                        options.seed + 2000 + i as u64,
                    )
                });
                let (e, rgb, _) = timed(&mut ph.compare, || {
                    compare(metric, scene, &gt, &oracle, exp)
                });
                if options.images != ImageSet::None {
                    let path = image_dir.join(format!("{}_ideal.png", scene.name));
                    timed(&mut ph.images, || save_rgb(&path, gt.width, gt.height, rgb))?;
                }
                Some(e)
            } else {
                None
            };
            let aniso_floor = if options.oracle_samples > 0 && options.anisotropy > 0 {
                let oracle = timed(&mut ph.oracle, || {
                    crate::render::render_oracle_footprint(
                        scene,
                        map,
                        options.oracle_samples,
                        options.seed + 3000 + i as u64,
                        Footprint::Anisotropic(options.anisotropy),
                    )
                });
                let (e, _, _) = timed(&mut ph.compare, || {
                    compare(metric, scene, &gt, &oracle, exp)
                });
                Some(e)
            } else {
                None
            };
            views_info.push(View {
                scene: scene.clone(),
                median_lod,
                far: median_lod >= 3.0,
                floor,
                aniso_floor,
            });
            truths.push((gt, exp));
        }
        let ground_truth_seconds = t.elapsed().as_secs_f64();
        progress(Progress::Done);
        // Monte Carlo error of the ground truth, on the first far zoom view.
        progress(Progress::Step(&format!(
            "{}: ground-truth convergence",
            input.name
        )));
        let w = Stopwatch::start();
        let ground_truth_error = if options.convergence_spp > 0 && summaries.is_empty() {
            let i = views_info
                .iter()
                .position(|v| v.far)
                .unwrap_or(0)
                .min(scenes.len() - 1);
            let fine = render_ground_truth(
                &scenes[i],
                map,
                options.convergence_spp,
                options.seed + 1000 + i as u64,
            );
            let mask = common_mask(&truths[i].0, &fine);
            let diff = relative_rmse(&fine, &truths[i].0, &mask);
            // Var(a − b) = σ²/spp + σ²/spp' → σ/√spp = diff / √(1 + spp/spp').
            let ratio = options.spp as f64 / options.convergence_spp as f64;
            Some((scenes[i].name.clone(), diff / (1.0 + ratio).sqrt()))
        } else {
            None
        };
        w.stop(&mut ph.convergence);
        progress(Progress::Done);
        // What every configuration of this map shares: the views' pixel geometry, and the
        // texel-space exact answers (kept when they fit in REFERENCE_BUDGET).
        let geometry: Vec<ViewGeometry> = timed(&mut ph.filtered_render, || {
            scenes.iter().map(ViewGeometry::new).collect()
        });
        let first = if map.width().max(map.height()) > 1 {
            1
        } else {
            0
        };
        let fits = Reference::bytes(map.width(), map.height(), 1, directions.len(), first)
            <= REFERENCE_BUDGET;
        let reference = fits.then(|| {
            timed(&mut ph.texel_eval, || {
                Reference::new(map, std::slice::from_ref(&brdf), &directions, first)
            })
        });
        let mut skipped = Vec::new();
        for config in &configs {
            let label = config.label();
            progress(Progress::Step(&format!("{}: {label}", input.name)));
            reset_peak_rss();
            let before = rss();
            let w = Stopwatch::start();
            let baked = bake_with(map, config.method, &config.options)?;
            let bake_seconds = w.stop(&mut ph.bake);
            let bake_peak_bytes = match (peak_rss(), before) {
                (Some(p), Some(b)) => Some(p.saturating_sub(b)),
                _ => None,
            };
            // The formats in the order asked, one at a time: each narrower one is rounded from
            // the f32 bake, measured and dropped before the next, and the last format that
            // needs the f32 bake rounds it in place (`quantize_into`), so at most two copies of
            // the bake's textures are held (three formats held at once made SH l* = 8, 448 MiB
            // in f32 at 1024², the report's memory peak). Without the kept reference each
            // format recomputes the exact answers: the price of that memory on maps too large
            // for REFERENCE_BUDGET.
            let mut baked = Some(baked);
            for (i, &format) in options.formats.iter().enumerate() {
                let w = Stopwatch::start();
                let needed_later = !options.formats[i + 1..].is_empty();
                let quantized = match (format, baked.take()) {
                    (_, None) => break,
                    (Format::F32, Some(f32_bake)) => Ok(f32_bake),
                    (_, Some(f32_bake)) if needed_later => {
                        let q = crate::pack::quantize(&f32_bake, format);
                        baked = Some(f32_bake);
                        q
                    }
                    (_, Some(f32_bake)) => crate::pack::quantize_into(f32_bake, format),
                };
                w.stop(&mut ph.quantize);
                let bake = match quantized {
                    Ok(b) => b,
                    Err(e) => {
                        skipped.push(format!("{label} in {format}: {e}"));
                        continue;
                    }
                };
                let b = &bake;
                let err = timed(&mut ph.texel_eval, || {
                    let refs: [&Bake; 1] = [b];
                    match &reference {
                        Some(r) => r.evaluate(&refs),
                        None => evaluate_from(
                            map,
                            &refs,
                            std::slice::from_ref(&brdf),
                            &directions,
                            first,
                        ),
                    }
                    .remove(0)
                });
                // Shader cost not known yet (the first map's).
                let key = format!("{label}/{}", b.format);
                if !costs.contains_key(&key) {
                    let c = timed(&mut ph.shader_cost, || cost::shader_cost(b));
                    costs.insert(key.clone(), c);
                }
                let cost = costs[&key].clone();
                let textures = crate::glsl::sampled_textures(
                    &crate::glsl::ShaderSpec::of(b),
                    &Default::default(),
                )
                .unwrap_or(b.textures.len());
                let texture_bytes: u64 = (0..textures)
                    .flat_map(|_| 0..b.level_count())
                    .map(|k| crate::pack::packed_len(b, k, b.format) as u64)
                    .sum();
                let mut view_errors = Vec::new();
                let rendered = options.image_formats.contains(&b.format)
                    && (b.format == Format::F32 || REPRESENTATIVE.contains(&label.as_str()));
                if rendered {
                    // Renders one view at a time (rows in parallel), then the comparisons
                    // (FLIP is serial) of every view in parallel.
                    let images: Vec<Image> = timed(&mut ph.filtered_render, || {
                        scenes
                            .iter()
                            .zip(&geometry)
                            .map(|(scene, g)| render_filtered_prepared(scene, g, b))
                            .collect()
                    });
                    let compared: Vec<(ViewError, Vec<u8>, Vec<u8>)> =
                        timed(&mut ph.compare, || {
                            use rayon::prelude::*;
                            scenes
                                .par_iter()
                                .zip(&truths)
                                .zip(&images)
                                .map(|((scene, (gt, exp)), img)| {
                                    compare(metric, scene, gt, img, *exp)
                                })
                                .collect()
                        });
                    for ((scene, img), (view_error, test_rgb, flip_map)) in
                        scenes.iter().zip(&images).zip(compared)
                    {
                        let write = match options.images {
                            ImageSet::None => false,
                            ImageSet::All => true,
                            ImageSet::Some => {
                                b.format == Format::F32 && REPRESENTATIVE.contains(&label.as_str())
                            }
                        };
                        if write {
                            let w = Stopwatch::start();
                            let stem = format!("{}_{}", scene.name, file_label(&b.label()));
                            save_rgb(
                                &image_dir.join(format!("{stem}.png")),
                                img.width,
                                img.height,
                                test_rgb,
                            )?;
                            save_rgb(
                                &image_dir.join(format!("{stem}_flip.png")),
                                img.width,
                                img.height,
                                flip_map,
                            )?;
                            w.stop(&mut ph.images);
                        }
                        view_errors.push(view_error);
                    }
                }
                let mut aniso_views = Vec::new();
                if options.anisotropy > 0 && b.format == Format::F32 && config.filters_linearly() {
                    let a = Footprint::Anisotropic(options.anisotropy);
                    let images: Vec<Image> = timed(&mut ph.filtered_render, || {
                        scenes
                            .iter()
                            .zip(&geometry)
                            .map(|(scene, g)| render_footprint(scene, g, b, a))
                            .collect()
                    });
                    aniso_views = timed(&mut ph.compare, || {
                        use rayon::prelude::*;
                        scenes
                            .par_iter()
                            .zip(&truths)
                            .zip(&images)
                            .map(|((scene, (gt, exp)), img)| {
                                compare(metric, scene, gt, img, *exp).0
                            })
                            .collect()
                    });
                }
                rows.push(Row {
                    map: input.name.clone(),
                    config: label.clone(),
                    label: b.label(),
                    method: b.method,
                    lobes: b.lobes,
                    aligned: b.parameters["aligned"] == serde_json::Value::Bool(true),
                    format: b.format,
                    bake_seconds,
                    bake_peak_bytes,
                    texture_bytes,
                    cost,
                    frame_ms: None,
                    frame_ratio: None,
                    texel_specular: err.overall_specular,
                    texel_diffuse: err.overall_diffuse,
                    texel_levels: err.levels.iter().map(|l| l.specular).collect(),
                    views: view_errors,
                    aniso_views,
                });
                // The f32 bake, measured in place, goes back for the formats after it.
                if format == Format::F32 && needed_later {
                    baked = Some(bake);
                }
            }
            progress(Progress::Done);
        }
        summaries.push(MapSummary {
            name: input.name.clone(),
            size: (map.width(), map.height()),
            views: views_info,
            ground_truth_seconds,
            ground_truth_error,
            skipped,
        });
    }
    Ok(Report {
        options: options.clone(),
        maps: summaries,
        rows,
        threads: rayon::current_num_threads(),
        seconds: start.elapsed().as_secs_f64(),
        cpu_seconds: cpu_seconds(),
        load_average: load_start.zip(load_average()),
        stability: None,
        phases: Some(ph),
        frame_times: None,
        frame_times_note: None,
        planner: None,
        env: None,
    })
}

/// Loads the maps of `paths` (names from the file stems) with default ingest options.
pub fn load_maps(paths: &[PathBuf]) -> Result<Vec<MapInput>> {
    paths
        .iter()
        .map(|p| {
            let map = NormalMap::load(p, &crate::IngestOptions::default())?;
            let name = p
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "map".into());
            Ok(MapInput { name, map })
        })
        .collect()
}

/// Writes `report.md`, `report.json` and the plots into `out`.
pub fn write(report: &Report, out: &Path) -> Result<()> {
    std::fs::create_dir_all(out).map_err(|e| write_err(out, e))?;
    let json = serde_json::to_string_pretty(report).expect("report serializes");
    let path = out.join("report.json");
    std::fs::write(&path, json).map_err(|e| write_err(&path, e))?;
    let plots = plot::write_plots(report, out)?;
    let md = markdown(report, &plots);
    let path = out.join("report.md");
    std::fs::write(&path, md).map_err(|e| write_err(&path, e))?;
    Ok(())
}

fn pct(v: f64) -> String {
    if v.is_finite() {
        format!("{:.2}", 100.0 * v)
    } else {
        "inf".into()
    }
}

fn opt_pct(v: Option<f64>) -> String {
    v.map_or("–".into(), pct)
}

/// The f32 row of `config` on `map`.
fn find<'a>(report: &'a Report, map: &str, config: &str, format: Format) -> Option<&'a Row> {
    report
        .rows
        .iter()
        .find(|r| r.map == map && r.config == config && r.format == format)
}

/// The report as Markdown.
pub fn markdown(report: &Report, plots: &[String]) -> String {
    use std::fmt::Write;
    let o = &report.options;
    let mut s = String::new();
    let _ = writeln!(s, "# ndfmap: error against run time\n");
    let _ = writeln!(
        s,
        "Generated by `ndfmap report` in {:.0} s on {} threads{}. Maps: {}.\n",
        report.seconds,
        report.threads,
        match (report.cpu_seconds, report.load_average) {
            (Some(c), Some((a, b))) => format!(
                " ({c:.0} CPU-seconds; load average {a:.1} at the start, {b:.1} at the end: \
                 other work shared the machine)"
            ),
            (Some(c), None) => format!(" ({c:.0} CPU-seconds)"),
            _ => String::new(),
        },
        report
            .maps
            .iter()
            .map(|m| format!("{} ({}×{})", m.name, m.size.0, m.size.1))
            .collect::<Vec<_>>()
            .join(", ")
    );
    if let Some(p) = &report.phases {
        let _ = writeln!(s, "Wall time by phase: {}.\n", p.summary());
    }
    let _ = writeln!(
        s,
        "**How it is measured.** Material: `{} · Lambert + {} · {}`. \
         *Texel space*: relative RMS error of the specular term against the exact footprint \
         average, levels ≥ 1, {} light/view pairs (one in {} of `eval`'s 27). *Image space*: \
         {}×{} views (a zoom sequence on a plane tilted 30° with the centre at λ = {}, a grazing \
         view, a sphere), each lit by a point and a directional light; ground truth by {} \
         jittered stratified samples per pixel of the unfiltered map (nearest finest normal, \
         shaded exactly), filtered renders by the CPU twin of the shaders at the pixel centre \
         (GL's LOD from ray differentials, trilinear or manual sampling as the shader's \
         specialization decides). Error = relative RMSE over fully covered pixels; FLIP = mean \
         LDR-FLIP (nv-flip, 67 px/°) of the tone-mapped images; *far* = views with median \
         λ ≥ 3. Cost: bake wall seconds (all threads) and peak RSS above the level before the \
         bake; texture bytes of what the shader samples (all levels); fetch instructions per \
         pixel (hardware: one `textureLod` per texture; manual: 8 `texelFetch` per texture) \
         and ALU = arithmetic SPIR-V instructions of the specialized shader (`glslangValidator \
         -G`; loops weighted by trip count, every branch counted). Labels: `vmfJ` = J vMF \
         lobes fitted per texel (manual sampling), `vmfJa` = aligned lobes (hardware \
         sampling; eq 29, C = {}), `shL` = spherical harmonics to band l* = L (eq 12; hardware \
         sampling). Frame time: {}\n",
        o.kd,
        o.ks,
        o.material_brdf(),
        27usize.div_ceil(o.directions_step.max(1)),
        o.directions_step,
        o.image_size,
        o.image_size,
        o.zoom_lods
            .iter()
            .map(|l| l.to_string())
            .collect::<Vec<_>>()
            .join(", "),
        o.spp,
        o.align
            .iter()
            .flatten()
            .map(|c| c.to_string())
            .collect::<Vec<_>>()
            .join(", "),
        frame_sentence(report),
    );
    for m in &report.maps {
        let _ = writeln!(s, "## {}\n", m.name);
        let views: Vec<String> = m
            .views
            .iter()
            .map(|v| {
                format!(
                    "{} (λ {:.1}{})",
                    v.scene.name,
                    v.median_lod,
                    if v.far { ", far" } else { "" }
                )
            })
            .collect();
        let _ = writeln!(
            s,
            "Views: {}. Ground truth (and the ideal-NDF render): {:.1} s.{}\n",
            views.join(", "),
            m.ground_truth_seconds,
            m.ground_truth_error
                .as_ref()
                .map_or(String::new(), |(v, e)| format!(
                    " Estimated Monte Carlo error of the {}-spp ground truth ({v}, from a second \
                     render at {} spp): {}% relative RMS (this estimate is used for every map); \
                     image errors below twice that are marked †.",
                    o.spp,
                    o.convergence_spp,
                    pct(*e)
                ))
        );
        let floor = report
            .maps
            .iter()
            .find_map(|m| m.ground_truth_error.as_ref())
            .map_or(0.0, |e| 2.0 * e.1);
        let mark = |v: Option<f64>| match v {
            Some(x) if x < floor => format!("{}†", pct(x)),
            other => opt_pct(other),
        };
        let _ = writeln!(
            s,
            "| config | texel err % | image err % | far image err % | FLIP | bake s | peak MiB | \
             texture MiB | fetches/px | ALU/px | frame ms (× plain) |"
        );
        let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
        if m.views.iter().any(|v| v.floor.is_some()) {
            let floors: Vec<&ViewError> = m.views.iter().filter_map(|v| v.floor.as_ref()).collect();
            let far: Vec<f64> = m
                .views
                .iter()
                .filter(|v| v.far)
                .filter_map(|v| v.floor.as_ref().map(|f| f.rel_rmse))
                .collect();
            let _ = writeln!(
                s,
                "| *ideal NDF, GL footprint (floor)* | – | {} | {} | {:.4} | – | – | – | – | – | – |",
                opt_pct(mean(floors.iter().map(|f| f.rel_rmse))),
                opt_pct(mean(far.into_iter())),
                mean(floors.iter().map(|f| f.flip)).unwrap_or(0.0),
            );
        }
        for r in report
            .rows
            .iter()
            .filter(|r| r.map == m.name && r.format == Format::F32)
        {
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} | {:.2} | {} | {:.1} | {} | {} | {} |",
                r.label,
                pct(r.texel_specular),
                mark(r.image_rmse()),
                mark(r.far_rmse(m)),
                r.image_flip().map_or("–".into(), |f| format!("{f:.4}")),
                r.bake_seconds,
                r.bake_peak_bytes
                    .map_or("?".into(), |b| format!("{:.0}", b as f64 / 1048576.0)),
                r.texture_bytes as f64 / 1048576.0,
                r.cost.fetches,
                r.cost.alu.map_or("?".into(), |a| a.to_string()),
                frame_cell(r),
            );
        }
        let _ = writeln!(s);
        // Formats.
        let formats: Vec<Format> = o
            .formats
            .iter()
            .copied()
            .filter(|f| *f != Format::F32)
            .collect();
        if !formats.is_empty() {
            let _ = write!(
                s,
                "Storage formats (texel err %, and image err % where rendered; Δ = minus f32):\n\n| config |"
            );
            for f in &formats {
                let _ = write!(s, " {f} texel | Δ texel |");
                if o.image_formats.contains(f) {
                    let _ = write!(s, " {f} image | Δ image |");
                }
            }
            let _ = writeln!(s);
            let _ = write!(s, "|---|");
            for f in &formats {
                let _ = write!(s, "---:|---:|");
                if o.image_formats.contains(f) {
                    let _ = write!(s, "---:|---:|");
                }
            }
            let _ = writeln!(s);
            for base in report
                .rows
                .iter()
                .filter(|r| r.map == m.name && r.format == Format::F32)
            {
                let _ = write!(s, "| {} |", base.config);
                for &f in &formats {
                    match find(report, &m.name, &base.config, f) {
                        Some(r) => {
                            let _ = write!(
                                s,
                                " {} | {:+.3} |",
                                pct(r.texel_specular),
                                100.0 * (r.texel_specular - base.texel_specular)
                            );
                            if o.image_formats.contains(&f) {
                                let d = r.image_rmse().zip(base.image_rmse()).map(|(a, b)| a - b);
                                let _ = write!(
                                    s,
                                    " {} | {} |",
                                    opt_pct(r.image_rmse()),
                                    d.map_or("–".into(), |d| format!("{:+.3}", 100.0 * d))
                                );
                            }
                        }
                        None => {
                            let _ = write!(s, " skipped | |");
                            if o.image_formats.contains(&f) {
                                let _ = write!(s, " | |");
                            }
                        }
                    }
                }
                let _ = writeln!(s);
            }
            let _ = writeln!(s);
        }
        s += &aniso_table(report, m);
        if !m.skipped.is_empty() {
            let _ = writeln!(s, "Skipped: {}.\n", m.skipped.join("; "));
        }
    }
    s += &targets(report);
    if let Some(st) = &report.stability {
        s += &stability::markdown(st);
    }
    if let Some(p) = &report.planner {
        s += &planner::markdown(p);
    }
    if let Some(e) = &report.env {
        s += &env::markdown(e);
    }
    s += &gallery(report);
    if !plots.is_empty() {
        let _ = writeln!(s, "## Plots\n");
        for p in plots.iter().filter(|p| p.ends_with(".png")) {
            let _ = writeln!(s, "![{p}]({p})\n");
        }
    }
    s
}

/// The anisotropic-filtering table of map `m` (empty when not measured): per view, the floor
/// of GL's trilinear footprint and of the anisotropic one, and each linearly filtering
/// configuration's relative RMSE under both.
fn aniso_table(report: &Report, m: &MapSummary) -> String {
    use std::fmt::Write;
    let rows: Vec<&Row> = report
        .rows
        .iter()
        .filter(|r| r.map == m.name && r.format == Format::F32 && !r.aniso_views.is_empty())
        .collect();
    if rows.is_empty() {
        return String::new();
    }
    let mut s = format!(
        "Anisotropic filtering (up to {} probes, `GL_EXT_texture_filter_anisotropic`'s reference \
         rule, done in the shader; relative RMSE %, trilinear → anisotropic):\n\n| view | λ | \
         ideal NDF (floor) |",
        report.options.anisotropy
    );
    for r in &rows {
        let _ = write!(s, " {} |", r.label);
    }
    let _ = write!(s, "\n|---|---:|---:|");
    for _ in &rows {
        s += "---:|";
    }
    s += "\n";
    for v in &m.views {
        let name = &v.scene.name;
        let cell = |t: Option<f64>, a: Option<f64>| format!("{} → {}", opt_pct(t), opt_pct(a));
        let _ = write!(
            s,
            "| {name} | {:.1} | {} |",
            v.median_lod,
            cell(
                v.floor.as_ref().map(|f| f.rel_rmse),
                v.aniso_floor.as_ref().map(|f| f.rel_rmse)
            )
        );
        for r in &rows {
            let find =
                |list: &[ViewError]| list.iter().find(|e| &e.view == name).map(|e| e.rel_rmse);
            let _ = write!(s, " {} |", cell(find(&r.views), find(&r.aniso_views)));
        }
        s += "\n";
    }
    s + "\n"
}

/// A row's frame time as the table shows it: `12.3 (3.41×)`, or `n/a`.
fn frame_cell(r: &Row) -> String {
    match (r.frame_ms, r.frame_ratio) {
        (Some(ms), Some(x)) => format!("{ms:.2} ({x:.2}×)"),
        (Some(ms), None) => format!("{ms:.2}"),
        _ => "n/a".into(),
    }
}

/// The sentence of the report's "How it is measured" on frame times: their source, or why
/// there are none.
fn frame_sentence(report: &Report) -> String {
    let note = report
        .frame_times_note
        .as_ref()
        .map_or(String::new(), |n| format!(" ({n})"));
    match &report.frame_times {
        Some(t) => {
            let soft = t.renderer.to_ascii_lowercase();
            let soft = ["llvmpipe", "softpipe", "swrast", "lavapipe"]
                .iter()
                .any(|s| soft.contains(s));
            format!(
                "{}{note}{}; measured once, on that sample, and shown for every map; *n/a* for \
                 a label or format it did not draw.{}",
                t.describe(),
                t.load_average.map_or(String::new(), |(a, b)| format!(
                    "; load average {a:.1} at its start, {b:.1} at its end"
                )),
                if soft {
                    " This renderer is a software rasterizer on the CPU: read the ratio to \
                     plain, not the milliseconds."
                } else {
                    ""
                }
            )
        }
        None => format!("n/a{note}."),
    }
}

/// The views and configurations the gallery of [`markdown`] shows (first map).
pub const GALLERY_VIEWS: [&str; 3] = ["zoom5", "grazing", "sphere"];

/// Image files of the gallery, relative to the report folder: per view of
/// [`GALLERY_VIEWS`], the ground truth, the ideal-NDF render, and renders and FLIP maps of
/// toksvig, lean and vmf6a.
pub fn gallery_files(report: &Report) -> Vec<(String, Vec<(String, String)>)> {
    let Some(m) = report.maps.first() else {
        return Vec::new();
    };
    if report.options.images == ImageSet::None {
        return Vec::new();
    }
    GALLERY_VIEWS
        .iter()
        .filter(|v| m.views.iter().any(|w| &w.scene.name == *v))
        .map(|v| {
            let f = |stem: &str| format!("images/{}/{v}_{stem}.png", m.name);
            let files = vec![
                ("ground truth".to_string(), f("ground_truth")),
                ("ideal NDF (floor)".to_string(), f("ideal")),
                ("vmf6a".to_string(), f("vmf6a")),
                ("toksvig".to_string(), f("toksvig")),
                ("lean".to_string(), f("lean")),
                ("vmf6a FLIP".to_string(), f("vmf6a_flip")),
                ("toksvig FLIP".to_string(), f("toksvig_flip")),
            ];
            (v.to_string(), files)
        })
        .collect()
}

fn gallery(report: &Report) -> String {
    use std::fmt::Write;
    let rows = gallery_files(report);
    if rows.is_empty() {
        return String::new();
    }
    let mut s = format!(
        "## Images ({})\n\nTone-mapped `1 − e^(−k·x)` with one exposure per view (the ground \
         truth's 99th percentile at 0.95); FLIP maps in magma (black = no visible \
         difference).\n\n",
        report.maps[0].name
    );
    let _ = writeln!(
        s,
        "| view | {} |",
        rows[0]
            .1
            .iter()
            .map(|c| c.0.as_str())
            .collect::<Vec<_>>()
            .join(" | ")
    );
    let _ = writeln!(s, "|---|{}", "---|".repeat(rows[0].1.len()));
    for (view, row) in &rows {
        let cells: Vec<String> = row.iter().map(|(l, f)| format!("![{l}]({f})")).collect();
        let _ = writeln!(s, "| {view} | {} |", cells.join(" | "));
    }
    s.push('\n');
    s
}

/// The targets, measured: vMF J = 6 aligned at far views against Toksvig and LEAN,
/// SH (not implemented), and what f16 adds.
fn targets(report: &Report) -> String {
    use std::fmt::Write;
    let mut s = String::from("## Targets\n\n");
    let _ = writeln!(
        s,
        "| map | vmf6a far err % | toksvig far % | ratio (goal ≤ 1/3) | lean far % | ratio (goal ≤ 1/2) | excess-over-floor ratio vs toksvig / lean | f16 − f32 image err, vmf6a (goal < 0.5 %) |"
    );
    let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|---:|---:|");
    let mut shortfalls = Vec::new();
    let noise = report
        .maps
        .iter()
        .find_map(|m| m.ground_truth_error.as_ref())
        .map_or(0.0, |e| 2.0 * e.1);
    for m in &report.maps {
        let get = |c: &str, f: Format| find(report, &m.name, c, f).and_then(|r| r.far_rmse(m));
        let (v, t, l) = (
            get("vmf6a", Format::F32),
            get("toksvig", Format::F32),
            get("lean", Format::F32),
        );
        let ratio =
            |a: Option<f64>, b: Option<f64>| a.zip(b).and_then(|(a, b)| (b > 0.0).then(|| a / b));
        // Errors below twice the ground truth's Monte Carlo error cannot be ranked.
        let measurable = v
            .zip(t)
            .zip(l)
            .is_some_and(|((v, t), l)| v.max(t).max(l) >= noise);
        let (rt, rl) = if measurable {
            (ratio(v, t), ratio(v, l))
        } else {
            (None, None)
        };
        let f16 = find(report, &m.name, "vmf6a", Format::F16)
            .and_then(|r| r.image_rmse())
            .zip(find(report, &m.name, "vmf6a", Format::F32).and_then(|r| r.image_rmse()))
            .map(|(a, b)| a - b);
        let excess = |c: &str| find(report, &m.name, c, Format::F32).and_then(|r| r.far_excess(m));
        let (xv, xt, xl) = if measurable {
            (excess("vmf6a"), excess("toksvig"), excess("lean"))
        } else {
            (None, None, None)
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} / {} | {} |",
            m.name,
            opt_pct(v),
            opt_pct(t),
            rt.map_or(
                if measurable { "–" } else { "below noise" }.into(),
                |r| format!("{r:.2}")
            ),
            opt_pct(l),
            rl.map_or(
                if measurable { "–" } else { "below noise" }.into(),
                |r| format!("{r:.2}")
            ),
            ratio(xv, xt).map_or("–".into(), |r| format!("{r:.2}")),
            ratio(xv, xl).map_or("–".into(), |r| format!("{r:.2}")),
            f16.map_or("–".into(), |d| format!("{:+.3}", 100.0 * d)),
        );
        if rt.is_some_and(|r| r > 1.0 / 3.0) {
            shortfalls.push(format!(
                "{}: vmf6a's far-view error is {:.2}× Toksvig's (goal ≤ 0.33)",
                m.name,
                rt.unwrap_or(0.0)
            ));
        }
        if rl.is_some_and(|r| r > 0.5) {
            shortfalls.push(format!(
                "{}: vmf6a's far-view error is {:.2}× LEAN's (goal ≤ 0.5)",
                m.name,
                rl.unwrap_or(0.0)
            ));
        }
        if f16.is_some_and(|d| d.abs() >= 0.005) {
            shortfalls.push(format!(
                "{}: f16 changes vmf6a's image error by ≥ 0.5 %",
                m.name
            ));
        }
    }
    let _ = writeln!(
        s,
        "\nThe excess-over-floor ratio compares `sqrt(e² − floor²)` per far view, where the \
         floor is the ideal NDF method's error under GL's footprint (bilinear taps over two \
         levels against the ground truth's box pixel), which no per-texel filtering removes."
    );
    // The Lambertian SH target (issue 15; Ramamoorthi & Hanrahan's 1 %), texel space.
    let mut lambert = Vec::new();
    for m in &report.maps {
        match find(report, &m.name, "sh2", Format::F32) {
            Some(r) => {
                lambert.push(format!("{} {:.2} %", m.name, 100.0 * r.texel_diffuse));
                if r.texel_diffuse > 0.01 {
                    shortfalls.push(format!(
                        "{}: SH l* = 2 Lambertian texel error {:.2} % (goal ≤ 1 %)",
                        m.name,
                        100.0 * r.texel_diffuse
                    ));
                }
            }
            None => lambert.push(format!("{} not measured (no sh2 row)", m.name)),
        }
    }
    let _ = writeln!(
        s,
        "\nSH l* = 2 Lambertian texel-space error (goal ≤ 1 %, the moments diffuse term): {}.\n",
        lambert.join(", ")
    );
    if shortfalls.is_empty() {
        let _ = writeln!(s, "Every measured target is met.\n");
    } else {
        let _ = writeln!(s, "**Where ndfmap falls short:**\n");
        for f in shortfalls {
            let _ = writeln!(s, "- {f}");
        }
        let _ = writeln!(s);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::em::AlignmentForm;
    use crate::ingest::{IngestOptions, Samples};

    /// Bakes at two alignment strengths get two labels, the default's the short one, and a
    /// configuration's label is its bake's.
    #[test]
    fn labels_name_an_alignment_strength_other_than_the_default() {
        let pixels: Vec<u8> = (0..8 * 8 * 3).map(|i| (i * 37 % 251) as u8).collect();
        let map = NormalMap::from_samples(
            "pixels",
            8,
            8,
            3,
            Samples::U8(&pixels),
            &IngestOptions::default(),
        )
        .unwrap();
        let cases = [
            (Method::Vmf, AlignmentForm::Appendix, 0.03, "vmf2a"),
            (Method::Vmf, AlignmentForm::Appendix, 1.0, "vmf2a(C=1)"),
            (Method::Vmf, AlignmentForm::MainText, 0.1, "vmf2a"),
            (Method::Vmf, AlignmentForm::MainText, 0.03, "vmf2a(C=0.03)"),
            (Method::Tan2005, AlignmentForm::Appendix, 1.0, "tan2005-2a"),
            (
                Method::Tan2005,
                AlignmentForm::Appendix,
                0.5,
                "tan2005-2a(C=0.5)",
            ),
        ];
        for (method, form, c, want) in cases {
            let config = Config {
                method,
                options: BakeOptions {
                    lobes: 2,
                    align: Some(c),
                    align_form: form,
                    ..BakeOptions::default()
                },
            };
            let baked = bake_with(&map, method, &config.options).unwrap();
            assert_eq!(baked.label(), want);
            assert_eq!(config.label(), want);
        }
    }

    /// A FLIP stand-in (zero error everywhere): the rows' FLIP column is not what this module's
    /// tests check, and the metric is C++ linked into the binary only.
    fn no_flip(_: &[u8], _: &[u8], width: u32, height: u32) -> (Vec<f32>, Vec<u8>) {
        let n = (width * height) as usize;
        (vec![0.0; n], vec![0; 3 * n])
    }

    /// The storage formats are measured one at a time (the f32 bake handed back when formats
    /// follow it, the last narrower one rounded from it in place): in any order, every
    /// (configuration, format) row has the texel and image errors of another order's, and
    /// every format asked gets its row.
    #[test]
    fn format_rows_do_not_depend_on_the_order_of_the_formats() {
        let map = crate::procedural::generate(16, 7).map;
        let maps = [MapInput {
            name: "sample".into(),
            map,
        }];
        let dir = tempfile::tempdir().unwrap();
        let run_with = |formats: Vec<Format>| {
            let options = ReportOptions {
                image_size: 12,
                spp: 2,
                convergence_spp: 0,
                lobes: vec![2],
                align: vec![None],
                tan_lobes: vec![],
                sh_lmax: vec![],
                image_formats: formats.clone(),
                formats,
                oracle_samples: 0,
                zoom_lods: vec![1.0],
                images: ImageSet::None,
                ..ReportOptions::default()
            };
            run(&maps, &options, dir.path(), &|_| {}, no_flip)
                .unwrap()
                .rows
        };
        let first = run_with(vec![Format::F32, Format::F16, Format::Unorm8]);
        let second = run_with(vec![Format::Unorm8, Format::F32, Format::F16]);
        assert_eq!(first.len(), second.len());
        let formats: std::collections::BTreeSet<String> =
            first.iter().map(|r| r.format.to_string()).collect();
        assert_eq!(formats.len(), 3, "{formats:?}");
        for a in &first {
            let b = second
                .iter()
                .find(|b| b.label == a.label)
                .unwrap_or_else(|| panic!("{} missing", a.label));
            assert_eq!(a.format, b.format);
            assert_eq!(
                a.texel_specular.to_bits(),
                b.texel_specular.to_bits(),
                "{}",
                a.label
            );
            assert_eq!(a.texel_levels, b.texel_levels, "{}", a.label);
            let rmse = |r: &Row| r.views.iter().map(|v| v.rel_rmse).collect::<Vec<_>>();
            assert_eq!(rmse(a), rmse(b), "{}", a.label);
            assert!(
                !a.views.is_empty() || a.format != Format::F32,
                "{}",
                a.label
            );
        }
    }
}
