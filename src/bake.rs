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
        Method::ALL
            .into_iter()
            .find(|m| m.name().eq_ignore_ascii_case(s))
            .ok_or_else(|| {
                let names: Vec<_> = Method::ALL.iter().map(|m| m.name()).collect();
                Error::InvalidOption(format!(
                    "unknown method '{s}' (expected one of: {})",
                    names.join(", ")
                ))
            })
    }
}

/// One RGBA f32 MIP chain of a bake.
#[derive(Debug, Clone, PartialEq)]
pub struct Texture {
    /// Short name, used in file names (`moments`, `mean`, ...).
    pub name: &'static str,
    /// What each of R, G, B, A holds.
    pub channels: [&'static str; 4],
    /// The value range of each channel.
    pub ranges: [ValueRange; 4],
    /// Texels of each level, finest first, row-major.
    pub levels: Vec<Vec<[f32; 4]>>,
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
    /// A short label for tables: the method name, with the lobe count and `a` for aligned lobes
    /// and `f` for the approximate mode for mixtures (`vmf6`, `vmf6a`, `vmf6f`, `tan2005-4`),
    /// the band limit for SH (`sh4`), and the format when it is not f32
    /// (`vmf6a f16`).
    pub fn label(&self) -> String {
        let mut l = self.method.name().to_string();
        if self.method == Method::Sh {
            l += &self.parameters["lmax"].to_string();
        }
        if self.lobes > 0 {
            if l.ends_with(|c: char| c.is_ascii_digit()) {
                l.push('-');
            }
            l += &self.lobes.to_string();
            if self.parameters["aligned"] == serde_json::Value::Bool(true) {
                l.push('a');
            }
            if self.parameters["approximate"] == serde_json::Value::Bool(true) {
                l.push('f');
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

/// Options of the mixture methods and of SH (ignored by the baselines).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BakeOptions {
    /// Lobes per texel, J, 1 to [`crate::em::MAX_LOBES`] (default 6, the paper's choice).
    pub lobes: usize,
    /// Coherent lobes for hardware interpolation (Sec 7.3): `Some(C)` fits from the coarsest
    /// level down, pulling each lobe towards the same lobe of already-fitted neighbours with
    /// strength C (vMF: see [`BakeOptions::align_form`]; Tan 2005: its prior's c); `None` fits
    /// each texel on its own from the finest level up (unaligned).
    pub align: Option<f64>,
    /// vMF: which M-step maximizes the coherence prior, eq 29 (the default, C ≈ 1) or eq 23
    /// (C ≈ 0.1). Ignored without `align` and by Tan 2005.
    pub align_form: crate::em::AlignmentForm,
    /// Approximate (fast) mode: levels 2 and coarser are fitted to the lobes of the level below
    /// (their mean vectors `A(κ)μ` weighted by α, hierarchical EM) instead of to every finest
    /// normal they cover. vMF only; Tan 2005 always fits the normals.
    pub approximate: bool,
    /// EM iteration cap and convergence tolerance.
    pub em: crate::em::EmOptions,
    /// SH: the band limit l* (0 to `sh::MAX_LMAX` = 16, default 4: 25 coefficients in 7
    /// textures); [`crate::brdf::Brdf::suggested_lmax`] gives the paper's choice for a BRDF.
    pub lmax: usize,
}

impl Default for BakeOptions {
    fn default() -> Self {
        BakeOptions {
            lobes: 6,
            align: None,
            align_form: crate::em::AlignmentForm::default(),
            approximate: false,
            em: crate::em::EmOptions::default(),
            lmax: 4,
        }
    }
}

/// A bake's progress reporting: forwards the fraction done to the caller's callback (at most
/// once per 0.1 % of progress, plus the first and the last call) and turns "stop" into
/// [`Error::Cancelled`].
pub(crate) struct Progress<'a> {
    callback: &'a mut dyn FnMut(f32) -> bool,
    /// The last fraction passed to the callback (−1 before the first call).
    reported: f32,
}

impl<'a> Progress<'a> {
    /// Reports to `callback`.
    pub(crate) fn new(callback: &'a mut dyn FnMut(f32) -> bool) -> Self {
        Progress {
            callback,
            reported: -1.0,
        }
    }

    /// Reports that `fraction` (0 to 1) of the whole bake is done; fractions never go back.
    pub(crate) fn report(&mut self, fraction: f64) -> Result<()> {
        let f = (fraction.clamp(0.0, 1.0) as f32).max(self.reported.max(0.0));
        let first = self.reported < 0.0;
        let finished = f == 1.0 && self.reported < 1.0;
        if !first && !finished && f - self.reported < 1e-3 {
            return Ok(());
        }
        self.reported = f;
        if (self.callback)(f) {
            Ok(())
        } else {
            Err(Error::Cancelled)
        }
    }
}
