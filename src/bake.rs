//! A bake: the per-level, per-texel parameters of one filtering method, as RGBA MIP chains,
//! and the options and progress reporting every method's baker shares.
//!
//! Every method's output has the same shape: a list of [`Texture`]s, each an RGBA f32 MIP chain
//! whose channels have documented meanings (DESIGN.md "Texture layouts"). That is what the
//! shaders sample, what packing converts, what the CPU twin shades (module `shade`) and what
//! module `output` writes. The methods produce it (modules `baseline`, `mixture`); module
//! `methods` dispatches to them. This module sits below all of them.

use crate::error::{Error, Result};
use crate::format::{Format, ValueRange};
use crate::ingest::Addressing;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::Duration;

/// The filtering methods ndfmap bakes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Plain MIP-mapping of the normal: the normalized mean normal, shaded with the unchanged
    /// BRDF. The row every method must beat.
    Plain,
    /// Toksvig (2005): the mean normal's length shortens with variation; the Blinn-Phong
    /// exponent becomes `s' = |n̄| s / (|n̄| + s (1 − |n̄|))`.
    Toksvig,
    /// LEAN mapping (Olano & Baker 2010): first and second moments of the normal's slopes
    /// `b = (n_x, n_y) / n_z`, giving an anisotropic slope covariance.
    Lean,
    /// Olano & North (1997) normal distribution mapping: the mean normal (3) and the second
    /// moments `E[n nᵀ]` (6) of a 3D Gaussian, all of which filter linearly.
    Olano,
    /// Tan et al. 2005: a mixture of J isotropic Gaussians over the planar projection
    /// `(n_x, n_y)` per texel, fitted by EM, one `(α, αμ, α(σ²+|μ|²))` texture per Gaussian
    /// (the paper's comparison row).
    Tan2005,
    /// The paper's method (Sec 7): a mixture of J von Mises–Fisher lobes per texel fitted by
    /// spherical EM (Algorithm 1), one `(α, α·r)` texture per lobe, shaded by Algorithm 2.
    Vmf,
    /// The paper's spherical-harmonic NDF (Sec 5): the coefficients `γ_lm` of the normals for
    /// bands `l ≤ l*`, linear in the normals (no fitting), shaded by eq 12 under any BRDF.
    Sh,
    /// The PBR bake for unmodified GGX engines (issue 17, module `pbr`): per level a normal
    /// map and glTF's metallic-roughness texture (perceptual `√α′` in G), optionally an
    /// anisotropy texture, fitted per texel to the footprint's average GGX shading. Not in
    /// [`Method::ALL`] (the methods with an ndfmap shader, as the C API numbers them): an
    /// engine's own GGX shader reads it.
    Pbr,
}

impl Method {
    /// Every method, in the order tables list them (and the C API numbers them: new methods
    /// are appended).
    pub const ALL: [Method; 7] = [
        Method::Plain,
        Method::Toksvig,
        Method::Lean,
        Method::Olano,
        Method::Tan2005,
        Method::Vmf,
        Method::Sh,
    ];

    /// The baselines (no options, closed-form moments).
    pub const BASELINES: [Method; 4] =
        [Method::Plain, Method::Toksvig, Method::Lean, Method::Olano];

    /// The lower-case name used on the command line, in manifests and file names.
    pub fn name(self) -> &'static str {
        match self {
            Method::Plain => "plain",
            Method::Toksvig => "toksvig",
            Method::Lean => "lean",
            Method::Olano => "olano",
            Method::Tan2005 => "tan2005",
            Method::Vmf => "vmf",
            Method::Sh => "sh",
            Method::Pbr => "pbr",
        }
    }
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Method {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        // Every method with a name: ALL (the C API's numbering) and PBR.
        let named: Vec<Method> = Method::ALL.into_iter().chain([Method::Pbr]).collect();
        crate::error::parse_named(s, &named, Method::name, "method")
    }
}

/// One RGBA f32 MIP chain of a bake.
#[derive(Debug, Clone, PartialEq)]
pub struct Texture {
    /// Short name, used in file names (`moments`, `mean`, ...).
    pub name: &'static str,
    /// What each of R, G, B, A holds ([`UNUSED`] for a channel that holds nothing).
    pub channels: [&'static str; 4],
    /// The value range of each channel.
    pub ranges: [ValueRange; 4],
    /// Texels of each level, finest first, row-major.
    pub levels: Vec<Vec<[f32; 4]>>,
}

/// The channel name of a texture channel that holds nothing ([`Texture::channels`]).
pub const UNUSED: &str = "unused";

impl Texture {
    /// Whether channel A holds data (block compression then keeps it; otherwise BC7 may use
    /// its opaque modes, `compress::encode_level`).
    pub fn uses_alpha(&self) -> bool {
        self.channels[3] != UNUSED
    }
}

/// The result of baking one method: level sizes and the textures every level is read from.
#[derive(Debug, Clone, PartialEq)]
pub struct Bake {
    /// The method that produced it.
    pub method: Method,
    /// Width and height of each level, finest first, down to 1×1.
    pub sizes: Vec<(u32, u32)>,
    /// The texture chains; a shader samples all of them at the same coordinates.
    pub textures: Vec<Texture>,
    /// Addressing of the source map (for samplers).
    pub addressing: Addressing,
    /// Number of lobe textures (the first `lobes` textures) for mixture methods; 0 otherwise.
    pub lobes: usize,
    /// Method parameters as recorded in the manifest (lobe count, alignment, EM settings).
    pub parameters: serde_json::Value,
    /// The storage format the values have been rounded to ([`Format::F32`] as baked;
    /// `pack::quantize` gives the values a GPU reads from a narrower format).
    pub format: Format,
}

impl Bake {
    /// The same mixture bake (vMF, Tan 2005) without its colour textures (eq 22's `α·y`,
    /// textures `lobes..`): the lobe textures only, what a renderer without colour textures
    /// samples. Other bakes are returned whole.
    pub fn lobes_only(&self) -> Bake {
        let keep = if matches!(self.method, Method::Vmf | Method::Tan2005) {
            self.lobes.min(self.textures.len())
        } else {
            self.textures.len()
        };
        Bake {
            method: self.method,
            sizes: self.sizes.clone(),
            textures: self.textures[..keep].to_vec(),
            addressing: self.addressing,
            lobes: self.lobes,
            parameters: self.parameters.clone(),
            format: self.format,
        }
    }

    /// A short label for tables: the method name, with the lobe count and `a` for aligned lobes
    /// for mixtures, and for vMF `f` for the fast mode and `x` for the exact one (`vmf6`,
    /// `vmf6a`, `vmf6f`, `vmf6ax`, `tan2005-4`), then the alignment strength when it is not the
    /// method's default (`vmf6a(C=1)`), the band limit for SH (`sh4`), `-aniso` for an
    /// anisotropic PBR bake (`pbr-aniso`), and the format when it is not f32 (`vmf6a f16`).
    pub fn label(&self) -> String {
        let mut l = self.method.name().to_string();
        if self.method == Method::Sh {
            l += &self.parameters["lmax"].to_string();
        }
        if self.method == Method::Pbr && self.parameters["anisotropic"] == true {
            l += "-aniso";
        }
        if self.lobes > 0 {
            if l.ends_with(|c: char| c.is_ascii_digit()) {
                l.push('-');
            }
            l += &self.lobes.to_string();
            if self.parameters["aligned"] == serde_json::Value::Bool(true) {
                l.push('a');
            }
            match self.parameters["mode"].as_str() {
                Some("fast") => l.push('f'),
                Some("exact") => l.push('x'),
                _ => {}
            }
            if let Some(c) = self.parameters["align_strength"].as_f64() {
                let options = BakeOptions {
                    align_form: self.parameters["align_form"]
                        .as_str()
                        .and_then(|f| f.parse().ok())
                        .unwrap_or_default(),
                    ..BakeOptions::default()
                };
                l += &strength_suffix(c, options.default_align_strength(self.method));
            }
        }
        if self.format != Format::F32 {
            l = format!("{l} {}", self.format);
        }
        l
    }

    /// Number of MIP levels.
    pub fn level_count(&self) -> usize {
        self.sizes.len()
    }

    /// The RGBA value of every texture at texel `(x, y)` of `level`, in texture order.
    pub fn texel(&self, level: usize, x: u32, y: u32) -> Vec<[f32; 4]> {
        let mut out = vec![[0.0; 4]; self.textures.len()];
        self.texel_into(
            level,
            y as usize * self.sizes[level].0 as usize + x as usize,
            &mut out,
        );
        out
    }

    /// Writes the RGBA value of every texture at row-major texel `index` of `level` into `out`
    /// (which must hold one entry per texture), without allocating.
    pub fn texel_into(&self, level: usize, index: usize, out: &mut [[f32; 4]]) {
        for (o, t) in out.iter_mut().zip(&self.textures) {
            *o = t.levels[level][index];
        }
    }
}

/// Most EM iterations per texel a bake accepts ([`crate::em::EmOptions::max_iterations`]): far
/// beyond what converges (the paper: "we seldom need more than 10"; the default is 20), and
/// small enough that every texel's fit ends.
pub const MAX_EM_ITERATIONS: u32 = 1000;

/// Largest EM convergence tolerance a bake accepts ([`crate::em::EmOptions::tolerance`], a
/// relative change of the mean log-likelihood); the range is 0 to this.
pub const MAX_EM_TOLERANCE: f64 = 1.0;

/// Largest alignment strength C a bake accepts ([`BakeOptions::align`]): a thousand times the
/// useful values (eq 29: about 1, eq 23: about 0.1, Tan 2005's prior: 1).
pub const MAX_ALIGN_STRENGTH: f64 = 1000.0;

/// Options of a bake: the mixture methods' and SH's parameters (ignored by the baselines) and
/// the memory budget (every method). Every value has a documented range, checked before any
/// work ([`Error::InvalidOption`] otherwise).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BakeOptions {
    /// Lobes per texel, J, 1 to [`crate::em::MAX_LOBES`] (default 6, the paper's choice).
    pub lobes: usize,
    /// Coherent lobes for hardware interpolation (Sec 7.3): `Some(C)` fits from the coarsest
    /// level down, pulling each lobe towards the same lobe of already-fitted neighbours with
    /// strength C, 0 to [`MAX_ALIGN_STRENGTH`] (vMF: see [`BakeOptions::align_form`]; Tan 2005:
    /// its prior's c); `None` fits each texel on its own from the finest level up (unaligned).
    pub align: Option<f64>,
    /// vMF: which M-step maximizes the coherence prior, eq 29 (the default) or eq 23; each
    /// form's usual C is [`crate::em::AlignmentForm::default_strength`]. Ignored without
    /// `align` and by Tan 2005.
    pub align_form: crate::em::AlignmentForm,
    /// vMF: how hard each texel is fitted ([`FitMode`]): how many EM iterations over the
    /// covered normals follow the start from the finer level's lobes. Tan 2005 ignores it
    /// and runs `em` as given.
    pub mode: FitMode,
    /// EM options: precision, κ estimator, over-relaxation, and the iteration cap (1 to
    /// [`MAX_EM_ITERATIONS`]) and convergence tolerance (0 to [`MAX_EM_TOLERANCE`]) that
    /// [`FitMode::Exact`] uses as they are and the other modes tighten ([`FitMode::passes`]).
    pub em: crate::em::EmOptions,
    /// Memory budget of the bake in bytes: a bake whose estimated peak (`methods`'
    /// `estimate_peak_bytes`, from the map's size and these options) exceeds it is refused
    /// with [`Error::MemoryBudget`] before it starts. `None` (default): the machine's default
    /// ([`crate::budget::default_memory_limit`]).
    pub memory_limit: Option<u64>,
    /// SH: the band limit l* (0 to `sh::MAX_LMAX` = 16, default 4: 25 coefficients in 7
    /// textures); [`crate::brdf::Brdf::suggested_lmax`] gives the paper's choice for a BRDF.
    pub lmax: usize,
    /// PBR ([`Method::Pbr`]): the base roughness and the anisotropic option.
    pub pbr: PbrOptions,
}

/// Options of the PBR bake ([`Method::Pbr`], module `pbr`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PbrOptions {
    /// The base perceptual roughness `√α` (glTF's), 0 to 1, default 0.5, for every texel
    /// unless a roughness map is given (module `pbr`'s `PbrMaps`).
    pub roughness: f64,
    /// Fit an anisotropic GGX lobe per texel and write `KHR_materials_anisotropy`'s texture.
    pub anisotropic: bool,
    /// The widest view and light angle from the normal the renderer shows, in degrees: `None`
    /// (default) fits the bake's full pair set (`pbr::FitSet::standard`, grazing pairs to 74°
    /// included); `Some(θ)` fits the same design with its angles scaled into θ
    /// (`pbr::FitSet::view_range`; 20° to 90°), for a renderer that never goes grazing.
    pub fit_max_angle: Option<f64>,
    /// Keep every level's normal at the footprint's mean direction (the normalized mean of
    /// the finest normals it covers: the plain MIP chain's normal) and fit only the roughness
    /// (and, anisotropic, the lobe's two α and direction) to the same shading error. For an
    /// engine that makes its own normal mips, or whose materials are mostly diffuse: the
    /// diffuse term is linear in the normal, so the mean direction serves it best, while the
    /// fitted normal (default, `false`) serves the specular lobe (docs/pbr.md, "The mean
    /// normal").
    pub mean_normal: bool,
}

impl Default for PbrOptions {
    fn default() -> Self {
        PbrOptions {
            roughness: 0.5,
            anisotropic: false,
            fit_max_angle: None,
            mean_normal: false,
        }
    }
}

/// The finest normals a texel covers from which [`FitMode::Balanced`] runs the EM options'
/// own iteration cap instead of its lower one ([`FitMode::passes`]): 4096, a 64 × 64
/// footprint.
pub const COARSE_TEXEL_NORMALS: usize = 4096;

/// The finest normals a texel covers from which [`FitMode::Balanced`]'s aligned pass runs the
/// EM options' own iteration cap instead of its 2 ([`FitMode::passes`]): 256, a 16 × 16
/// footprint (level 4 of a power-of-two map). The unaligned pass keeps its budget there, so the
/// chain that coarser texels start from is unchanged.
pub const WIDE_TEXEL_NORMALS: usize = 256;

/// How hard the vMF baker fits each texel. Every mode starts a texel from the lobes of the
/// finer texels it covers (`em::seed_from_children`) and runs EM (Algorithm 1) over every
/// finest normal it covers; they differ in how many iterations, unaligned and in the aligned
/// pass. Measured on the real maps in `docs/baker.md` (likelihood, error and time).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, Hash, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum FitMode {
    /// At most 3 iterations per texel (tolerance ≥ 1e-4); aligned, 2 and then 1 in the aligned
    /// pass.
    Fast,
    /// At most 8 iterations per texel (tolerance ≥ 1e-4); aligned, 5 and then 2 in the
    /// aligned pass. Larger texels get more ([`FitMode::passes`] gives the rule and its
    /// thresholds, [`WIDE_TEXEL_NORMALS`] and [`COARSE_TEXEL_NORMALS`]). Measured on rock and bark (J = 6, 1024², aligned, `docs/baker.md` "Stop 51" to
    /// "Stop 53"): 0.002–0.025 nats per normal below a multi-start reference at levels 4–8
    /// (0.002–0.009 at levels 5–8), in about 0.9–1.7 s on two cores, by machine.
    #[default]
    Balanced,
    /// The EM options as given, in both passes (by default 20 iterations, tolerance 1e-6),
    /// and in the unaligned pass each texel fitted from several starts, the best kept
    /// ([`crate::em::fit_restarts`]: a repeated-normals start for texels of up to 64 normals,
    /// split-and-merge moves): the exhaustive fit. Measured on rock and bark (J = 6,
    /// `docs/baker.md` "Fourth round"): within 0.0025 nats per normal of a best-of-8
    /// multi-start reference at levels 5–8 (−0.009 to 0.008 at level 4), at 2.4–3.4× the
    /// CPU time of one start.
    Exact,
}

impl FitMode {
    /// Every mode, fastest first.
    pub const ALL: [FitMode; 3] = [FitMode::Fast, FitMode::Balanced, FitMode::Exact];

    /// The name `ndfmap` reads and manifests record: `fast`, `balanced`, `exact`.
    pub fn name(self) -> &'static str {
        match self {
            FitMode::Fast => "fast",
            FitMode::Balanced => "balanced",
            FitMode::Exact => "exact",
        }
    }

    /// The most normals a texel's EM runs on in a level of `texels` texels, or `None` for all
    /// of them. Texels covering more (levels 7 and coarser of a power-of-two map, over 4096
    /// normals) are fitted to a stratified sample of their normals: one per square cell of the
    /// footprint, weighted by the cell. The cap is 4096 normals, raised so that a level's
    /// texels together keep at least 2¹⁸ samples: the few texels of the coarsest levels
    /// (4096 samples of a million normals left the 1×1 level's error up to 2× higher) cost
    /// little more than one finer level. Exact mode fits every normal.
    pub fn sample_cap(self, texels: usize) -> Option<usize> {
        match self {
            FitMode::Fast | FitMode::Balanced => Some(4096.max((1 << 18) / texels.max(1))),
            FitMode::Exact => None,
        }
    }

    /// The EM options of the unaligned and of the aligned pass (`aligned`: whether the bake
    /// has an aligned pass) for a level whose texels cover `texel_normals` finest normals
    /// each: `em`'s iteration cap lowered and its tolerance raised to the mode's (never the
    /// other way). An aligned bake's unaligned pass only starts the aligned one, which goes
    /// on iterating from it, so it stops sooner.
    ///
    /// Balanced's budget grows with the texel, because coarse levels have few texels and
    /// little per-texel overhead: on texels of at least [`WIDE_TEXEL_NORMALS`] normals (level 4
    /// and coarser of a power-of-two map) the aligned pass keeps `em`'s cap (20 by default);
    /// on texels of at least [`COARSE_TEXEL_NORMALS`] (level 6 and coarser) the unaligned pass
    /// keeps it too and the aligned pass runs at most 6. Below `COARSE_TEXEL_NORMALS` the
    /// unaligned pass keeps its lower cap because it is the start of every coarser texel, and
    /// running it further there made coarser levels' error worse. What each threshold buys and
    /// costs is measured in `docs/baker.md` ("Stop 51" to "Stop 53").
    pub fn passes(
        self,
        em: &crate::em::EmOptions,
        aligned: bool,
        texel_normals: usize,
    ) -> (crate::em::EmOptions, crate::em::EmOptions) {
        let coarse = texel_normals >= COARSE_TEXEL_NORMALS;
        let wide = texel_normals >= WIDE_TEXEL_NORMALS;
        let (cap, first_of_two, tolerance, second) = match self {
            FitMode::Fast => (3, 2, 1e-4, 1),
            FitMode::Balanced if coarse => (u32::MAX, u32::MAX, 1e-4, 6),
            FitMode::Balanced if wide => (8, 5, 1e-4, u32::MAX),
            FitMode::Balanced => (8, 5, 1e-4, 2),
            FitMode::Exact => return (*em, *em),
        };
        let unaligned = crate::em::EmOptions {
            max_iterations: em
                .max_iterations
                .min(if aligned { first_of_two } else { cap }),
            tolerance: em.tolerance.max(tolerance),
            ..*em
        };
        let aligned = crate::em::EmOptions {
            max_iterations: em.max_iterations.min(second),
            ..unaligned
        };
        (unaligned, aligned)
    }
}

impl FromStr for FitMode {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        FitMode::ALL
            .into_iter()
            .find(|m| m.name().eq_ignore_ascii_case(s.trim()))
            .ok_or_else(|| {
                Error::InvalidOption(format!("fit mode '{s}' (expected fast, balanced or exact)"))
            })
    }
}

impl BakeOptions {
    /// The alignment strength a caller gets when it asks `method` for aligned lobes without
    /// giving one: vMF [`crate::em::AlignmentForm::default_strength`] of
    /// [`BakeOptions::align_form`], Tan 2005 [`crate::tan2005::DEFAULT_ALIGN_STRENGTH`].
    pub fn default_align_strength(&self, method: Method) -> f64 {
        match method {
            Method::Tan2005 => crate::tan2005::DEFAULT_ALIGN_STRENGTH,
            _ => self.align_form.default_strength(),
        }
    }
}

/// `(C=…)` for an alignment strength `c` other than the method's `default`, else nothing: the
/// labels of bakes at two strengths must differ, and the default's stays short.
pub(crate) fn strength_suffix(c: f64, default: f64) -> String {
    if c == default {
        String::new()
    } else {
        format!("(C={c})")
    }
}

/// A label's alignment strength spelled for a file name: `vmf6a(C=1)` → `vmf6a-c1` (other
/// characters unchanged; callers choose what a space becomes).
pub fn file_label(label: &str) -> String {
    label.replace("(C=", "-c").replace(')', "")
}

impl Default for BakeOptions {
    fn default() -> Self {
        BakeOptions {
            lobes: 6,
            align: None,
            align_form: crate::em::AlignmentForm::default(),
            mode: FitMode::default(),
            em: crate::em::EmOptions::default(),
            memory_limit: None,
            lmax: 4,
            pbr: PbrOptions::default(),
        }
    }
}

/// How often a running bake calls its progress callback at least, so that it can cancel (unless
/// the bake was started on a thread of a rayon pool, see `methods::bake_with_progress`).
pub const PROGRESS_POLL: Duration = Duration::from_millis(50);

/// A bake's cancellation request: set when the progress callback says stop, read by every
/// worker between texels (one relaxed atomic load: cheap enough to poll per texel or per EM
/// iteration). `Sync`; borrowed from [`Progress::cancel_flag`].
#[derive(Debug, Default)]
pub(crate) struct CancelFlag(AtomicBool);

impl CancelFlag {
    /// Whether the bake was cancelled; work should stop as soon as it can.
    pub(crate) fn is_cancelled(&self) -> bool {
        self.0.load(Ordering::Relaxed)
    }

    /// The flag itself, for [`crate::em::EmInput::with_cancel`].
    pub(crate) fn as_atomic(&self) -> &AtomicBool {
        &self.0
    }

    /// [`Error::Cancelled`] once cancelled.
    pub(crate) fn check(&self) -> Result<()> {
        if self.is_cancelled() {
            Err(Error::Cancelled)
        } else {
            Ok(())
        }
    }

    fn cancel(&self) {
        self.0.store(true, Ordering::Relaxed);
    }
}

/// Sets the flag when dropped: a panic on the thread that polls the callback stops the work.
struct CancelOnDrop<'a>(&'a CancelFlag);

impl Drop for CancelOnDrop<'_> {
    fn drop(&mut self) {
        self.0.cancel();
    }
}

/// Where [`Progress::report`] sends the fraction done.
enum Sink<'a> {
    /// The caller's callback, called directly (the work runs on the caller's thread).
    Callback(&'a mut dyn FnMut(f32) -> bool),
    /// The calling thread, which calls the callback (the work runs on a thread of its own).
    Caller(mpsc::Sender<f32>),
}

/// A bake's progress reporting, as the methods see it: [`Progress::report`] passes the fraction
/// done on (at most once per 0.1 % of progress, plus the first and the last call) and fails with
/// [`Error::Cancelled`] once the callback has said stop; [`Progress::cancel_flag`] is what
/// workers poll between texels. Made by [`run_with_progress`].
pub(crate) struct Progress<'a> {
    sink: Sink<'a>,
    cancel: &'a CancelFlag,
    /// The last fraction passed on (−1 before the first).
    reported: f32,
}

impl<'a> Progress<'a> {
    /// Reports that `fraction` (0 to 1) of the whole bake is done; fractions never go back.
    /// Fails with [`Error::Cancelled`] once the bake is cancelled.
    pub(crate) fn report(&mut self, fraction: f64) -> Result<()> {
        self.cancel.check()?;
        let f = (fraction.clamp(0.0, 1.0) as f32).max(self.reported.max(0.0));
        let first = self.reported < 0.0;
        let finished = f == 1.0 && self.reported < 1.0;
        if !first && !finished && f - self.reported < 1e-3 {
            return Ok(());
        }
        self.reported = f;
        match &mut self.sink {
            Sink::Callback(callback) => {
                if !callback(f) {
                    self.cancel.cancel();
                }
            }
            // A caller that has gone has stopped listening: nothing to do.
            Sink::Caller(to_caller) => drop(to_caller.send(f)),
        }
        self.cancel.check()
    }

    /// The bake's cancellation flag, for workers to poll between texels (and for an EM fit to
    /// poll between iterations). Outlives this borrow, so a driver may hold it while it
    /// reports.
    pub(crate) fn cancel_flag(&self) -> &'a CancelFlag {
        self.cancel
    }
}

/// Runs `work` (a bake) with a [`Progress`] that reports to `callback`, on the calling thread:
/// `callback` gets every fraction `work` reports and, while `work` runs, the last one again at
/// least every [`PROGRESS_POLL`]; once it returns `false`, it is not called again, the
/// [`CancelFlag`] is set, and the result is [`Error::Cancelled`] (after `work` has stopped, at
/// its next poll of the flag).
///
/// `work` runs as a job of the global rayon pool (no thread is created) while the calling
/// thread waits for its reports and polls the callback. When the caller is itself a thread of
/// a rayon pool (a bake started from parallel code, as the report's sweeps do), the
/// work runs on the calling thread instead: blocking a pool thread until pool work finishes
/// can deadlock when every pool thread does it. The callback is then called only when `work`
/// reports (between chunks of texels), and cancellation takes effect there.
///
/// A panic in `work` or in `callback` reaches the caller (after `work` has stopped).
pub(crate) fn run_with_progress<T: Send>(
    callback: &mut dyn FnMut(f32) -> bool,
    work: impl FnOnce(&mut Progress) -> Result<T> + Send,
) -> Result<T> {
    let cancel = CancelFlag::default();
    if rayon::current_thread_index().is_some() {
        let mut progress = Progress {
            sink: Sink::Callback(callback),
            cancel: &cancel,
            reported: -1.0,
        };
        return work(&mut progress);
    }
    let (to_caller, reports) = mpsc::channel::<f32>();
    let mut outcome = None;
    // The work is a job of the global pool; this thread polls the callback meanwhile.
    let stopped = rayon::in_place_scope(|scope| {
        let cancel = &cancel;
        let outcome = &mut outcome;
        let _stop_on_panic = CancelOnDrop(cancel);
        scope.spawn(move |_| {
            let mut progress = Progress {
                sink: Sink::Caller(to_caller),
                cancel,
                reported: -1.0,
            };
            *outcome = Some(work(&mut progress));
        });
        let mut last = None;
        let mut stopped = false;
        loop {
            let fraction = match reports.recv_timeout(PROGRESS_POLL) {
                Ok(f) => Some(f),
                Err(mpsc::RecvTimeoutError::Timeout) => last,
                // The work has ended (its `Progress` is gone).
                Err(mpsc::RecvTimeoutError::Disconnected) => break,
            };
            if let Some(f) = fraction.filter(|_| !stopped) {
                last = Some(f);
                if !callback(f) {
                    stopped = true;
                    cancel.cancel();
                }
            }
        }
        stopped
    });
    // A panic of the work has been resumed by the scope: here the outcome is set.
    let result = outcome.expect("the bake's job ran to its end");
    if stopped {
        Err(Error::Cancelled)
    } else {
        result
    }
}
