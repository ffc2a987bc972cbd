//! A bake: the per-level, per-texel parameters of one filtering method, as RGBA MIP chains.
//!
//! Every method's output has the same shape: a list of [`Texture`]s, each an RGBA f32 MIP chain
//! whose channels have documented meanings (DESIGN.md "Texture layouts"). That is what the
//! shaders sample, what packing converts, what the CPU twin shades ([`crate::shade`]) and what
//! [`crate::output`] writes.

use crate::error::{Error, Result};
use crate::ingest::{Addressing, NormalMap};
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
}

impl Method {
    /// Every method, in the order tables list them.
    pub const ALL: [Method; 6] = [
        Method::Plain,
        Method::Toksvig,
        Method::Lean,
        Method::Olano,
        Method::Tan2005,
        Method::Vmf,
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

/// The range a channel's values lie in, which decides how unsigned-normalized formats store it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ValueRange {
    /// In [0, 1]: stored as is.
    Unit,
    /// In [−1, 1]: unsigned-normalized formats store `0.5 + 0.5·v` (DESIGN.md "Texture layouts").
    Signed,
    /// Unbounded (LEAN slope moments): float formats only.
    Any,
}

/// Storage format of texel values: what the GPU texture holds (see [`crate::pack`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Format {
    /// 32-bit float RGBA (`GL_RGBA32F`).
    #[default]
    F32,
    /// 16-bit float RGBA (`GL_RGBA16F`).
    F16,
    /// 16-bit unsigned-normalized RGBA (`GL_RGBA16`); signed channels biased.
    Unorm16,
    /// 8-bit unsigned-normalized RGBA (`GL_RGBA8`); signed channels biased.
    Unorm8,
}

impl Format {
    /// Every format, widest first.
    pub const ALL: [Format; 4] = [Format::F32, Format::F16, Format::Unorm16, Format::Unorm8];

    /// The lower-case name used on the command line and in manifests.
    pub fn name(self) -> &'static str {
        match self {
            Format::F32 => "f32",
            Format::F16 => "f16",
            Format::Unorm16 => "unorm16",
            Format::Unorm8 => "unorm8",
        }
    }

    /// Bytes per channel.
    pub fn channel_bytes(self) -> usize {
        match self {
            Format::F32 => 4,
            Format::F16 | Format::Unorm16 => 2,
            Format::Unorm8 => 1,
        }
    }
}

impl fmt::Display for Format {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Format {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        Format::ALL
            .into_iter()
            .find(|m| m.name().eq_ignore_ascii_case(s))
            .ok_or_else(|| {
                Error::InvalidOption(format!(
                    "unknown format '{s}' (expected one of: f32, f16, unorm16, unorm8)"
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
    /// [`crate::pack::quantize`] gives the values a GPU reads from a narrower format).
    pub format: Format,
}

impl Bake {
    /// A short label for tables: the method name, with the lobe count and `a` for aligned lobes
    /// and `f` for the approximate mode for mixtures (`vmf6`, `vmf6a`, `vmf6f`, `tan2005-4`),
    /// and the format when it is not f32
    /// (`vmf6a f16`).
    pub fn label(&self) -> String {
        let mut l = self.method.name().to_string();
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

/// The value ranges of each texture a bake of `method` has, in texture order — what a shader
/// needs to decode unsigned-normalized storage without a bake at hand: the baseline's textures,
/// or `lobes` lobe textures followed, with `color`, by `lobes` colour textures (`α·y`, unit).
pub fn texture_ranges(method: Method, lobes: usize, color: bool) -> Vec<[ValueRange; 4]> {
    use crate::mixture::{Model, TanModel, VmfModel};
    let lobe = match method {
        Method::Vmf => VmfModel::RANGES,
        Method::Tan2005 => TanModel::RANGES,
        _ => {
            return crate::baseline::layout(method)
                .into_iter()
                .map(|(_, _, ranges)| ranges)
                .collect();
        }
    };
    let mut ranges = vec![lobe; lobes];
    if color {
        ranges.extend(std::iter::repeat_n([ValueRange::Unit; 4], lobes));
    }
    ranges
}

/// Options of the mixture methods (ignored by the baselines).
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
}

impl Default for BakeOptions {
    fn default() -> Self {
        BakeOptions {
            lobes: 6,
            align: None,
            align_form: crate::em::AlignmentForm::default(),
            approximate: false,
            em: crate::em::EmOptions::default(),
        }
    }
}

/// Bakes `method` for `map` with default options: the full MIP chain down to 1×1.
pub fn bake(map: &NormalMap, method: Method) -> Bake {
    bake_with(map, method, &BakeOptions::default()).expect("default options are valid")
}

/// Bakes `method` for `map` with `options`; fails only on invalid options.
pub fn bake_with(map: &NormalMap, method: Method, options: &BakeOptions) -> Result<Bake> {
    bake_with_progress(map, method, options, &mut |_| true)
}

/// Bakes like [`bake_with`], reporting progress to `progress` and letting it cancel.
///
/// `progress` is called on the calling thread (between parallel chunks of work, never from a
/// worker) with the fraction done: first 0.0, then non-decreasing values at least every 0.1 %
/// of the work's progress (per MIP level for the baselines, per chunk of texels or wavefront
/// for the mixtures), last 1.0. Returning `false` stops the bake with [`Error::Cancelled`];
/// the result does not depend on the callback otherwise (same bits as [`bake_with`]).
pub fn bake_with_progress(
    map: &NormalMap,
    method: Method,
    options: &BakeOptions,
    progress: &mut dyn FnMut(f32) -> bool,
) -> Result<Bake> {
    let mut progress = Progress::new(progress);
    progress.report(0.0)?;
    let bake = match method {
        Method::Vmf => crate::mixture::bake_vmf(map, options, &mut progress),
        Method::Tan2005 => crate::mixture::bake_tan2005(map, options, &mut progress),
        _ => crate::baseline::bake(map, method, &mut progress),
    }?;
    progress.report(1.0)?;
    Ok(bake)
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The built-in sample of side `size` (at least 8).
    fn bumpy(size: u32) -> NormalMap {
        crate::procedural::generate(size, 3).map
    }

    fn cases() -> Vec<(Method, BakeOptions)> {
        let lobes = |n, align| BakeOptions {
            lobes: n,
            align,
            ..BakeOptions::default()
        };
        vec![
            (Method::Plain, BakeOptions::default()),
            (Method::Olano, BakeOptions::default()),
            (Method::Vmf, lobes(2, None)),
            (Method::Vmf, lobes(2, Some(0.1))),
            (Method::Tan2005, lobes(2, Some(1.0))),
        ]
    }

    #[test]
    fn progress_rises_from_zero_to_one_and_leaves_the_bake_unchanged() {
        // 512²: level 1 has four chunks of PROGRESS_CHUNK texels.
        for (map, (method, options)) in [(bumpy(512), (Method::Vmf, cases()[2].1))]
            .into_iter()
            .chain(cases().into_iter().map(|c| (bumpy(9), c)))
        {
            let mut seen = Vec::new();
            let with = bake_with_progress(&map, method, &options, &mut |f| {
                seen.push(f);
                true
            })
            .unwrap();
            assert_eq!(with, bake_with(&map, method, &options).unwrap(), "{method}");
            assert_eq!(seen.first(), Some(&0.0), "{method}: {seen:?}");
            assert_eq!(seen.last(), Some(&1.0), "{method}: {seen:?}");
            assert!(seen.len() >= 3, "{method}: {seen:?}");
            assert!(seen.windows(2).all(|p| p[0] < p[1]), "{method}: {seen:?}");
        }
    }

    #[test]
    fn a_callback_that_says_stop_cancels_the_bake() {
        let map = bumpy(9);
        for (method, options) in cases() {
            for stop_at in [0, 1, 2] {
                let mut calls = 0;
                let r = bake_with_progress(&map, method, &options, &mut |_| {
                    calls += 1;
                    calls <= stop_at
                });
                assert!(
                    matches!(r, Err(Error::Cancelled)),
                    "{method} stop at {stop_at}"
                );
                assert_eq!(calls, stop_at + 1, "{method}: no call after the stop");
            }
        }
    }
}
