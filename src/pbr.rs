//! The PBR bake (issue 17): per MIP level a normal map and a GGX roughness map that an
//! unmodified GGX / metallic-roughness shader (glTF, Filament, Unity, Unreal, Godot, three.js)
//! samples with ordinary trilinear filtering, fitted so that one GGX lobe per texel reproduces
//! the footprint's average shading as closely as it can.
//!
//! **What is fitted.** At level k, texel t covers finest normals `n_i` with weights `w_i`
//! ([`crate::pyramid`]), each with its base roughness `α_i` (a constant or a roughness map).
//! The exact answer for a light/view pair `(l, v)`, half vector `h`, is the footprint average
//! `G(l, v) = Σ w_i D_{α_i}(n_i·h) max(n_i·l, 0)` (the GGX lobe `D` of [`crate::brdf::ggx`],
//! Walter et al. 2007; its Smith and Schlick factors do not depend on the normal, footnote 4 of
//! the paper, so they weight pairs and do not enter per normal). The texel's lobe `(n′, α′)`
//! minimizes `Σ_p w_p² (D_{α′}(n′·h_p) max(n′·l_p, 0) − G_p)²` over a fixed set of pairs
//! ([`FitSet::standard`]: 112 pairs, views and lights from the zenith to 74°, grazing ones
//! included, unit weights `w_p = 1`: the quantity the targets measure; none of them is
//! one of the evaluation's pairs), by a few Levenberg–Marquardt steps with an analytic
//! Jacobian ([`fit_isotropic`]), started from the best of: the mean normal with the κ formula
//! (`κ = (3r − r³)/(1 − r²)`, `α′² = α² + c/κ` for c = 2, 0.5, 1, 4), the mean normal with the
//! base roughness, the four finer texels' fitted lobes, and the footprint's modes
//! ([`mode_starts`]: mean shift over its normals with kernels matched to α, for footprints
//! like "one flat panel plus tilted edges" whose best lobe sits on the panel, not on the mean
//! normal), the best mode start refined as well when it lies in another basin.
//! [`FitSet::near_peak`] (half
//! vectors within 28°, weighted by the g factor) and [`FitSet::view_range`] are for renderers
//! that never see grazing angles. The
//! targets `G_p` are exact (footprint averages of the per-normal shading, [`targets`]); the
//! fit is a local least-squares optimum on those pairs, not a global one.
//!
//! **Anisotropic option** ([`fit_anisotropic`]):
//! `D = 1/(π α_t α_b ((h·t/α_t)² + (h·b/α_b)² + (h·n)²)²)` with `t` the tangent-space direction `(cos φ, sin φ, 0)` made orthogonal to `n`
//! and `b = n × t` (glTF `KHR_materials_anisotropy`: `α_b` is the roughness texture's α,
//! `α_t = mix(α_b, 1, strength²)`), started from the isotropic fit and from the footprint's
//! tangent-plane covariance Σ (`α² I + 2Σ`, the LEAN/Olano moments), fitted the same way with
//! a forward-difference Jacobian.
//!
//! **Textures** ([`layout`]): `normal` (`n′`, signed), `metallic_roughness` in glTF's
//! channel layout (R occlusion, G perceptual roughness `√α′`, B metallic; occlusion 1 and
//! metallic 0 unless maps are given, box-filtered over the footprint like the normals), and
//! with the anisotropic option `anisotropy` (R, G the direction `(cos φ, sin φ)` in tangent
//! space with `sin φ ≥ 0`, B the strength). Level 0 is the input itself.
//!
//! [`shade`] is the CPU twin of a plain GGX shader reading them (no ndfmap shader code).

use crate::bake::{Bake, Method, PbrOptions, Progress, Texture};
use crate::brdf::{Brdf, Shading, ggx, half_vector, schlick, smith_visibility, tangent_frame};
use crate::error::{Error, Result};
use crate::format::{Format, ValueRange};
use crate::ingest::NormalMap;
use crate::pyramid::{LevelFootprints, pyramid, reduce};
use glam::DVec3;
use rayon::prelude::*;
use std::f64::consts::PI;

mod kernel;

/// Smallest GGX α a PBR bake stores or shades (perceptual roughness ≈ 0.032): a lobe no
/// engine's half floats resolve more sharply. Input roughness below it is raised to it.
pub const MIN_ALPHA: f64 = 1e-3;

/// Largest mean-normal length the κ formula takes (`|r|` as f16 holds it), so that κ stays
/// finite for a footprint whose normals are all equal.
pub const R_MAX: f64 = 1.0 - 1.0 / 2048.0;

/// Most light/view pairs a [`FitSet`] holds (the fit keeps its residuals on the stack).
pub const MAX_PAIRS: usize = 128;

/// A light direction and a view direction, unit vectors in tangent space (z up).
pub type Pair = (DVec3, DVec3);

/// The vMF concentration of a footprint from its mean normal's length `r`:
/// `κ = (3r − r³)/(1 − r²)` (Banerjee et al. 2005, the paper's eq 24 approximation), with `r`
/// held to [`R_MAX`].
pub fn kappa(r: f64) -> f64 {
    let r = r.clamp(0.0, R_MAX);
    (3.0 * r - r * r * r) / (1.0 - r * r)
}

/// A κ-based widening formula of the kind engines use (the rows the report compares with).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Widening {
    /// `α′² = α² + c/κ` (Unity HDRP c = 0.5, Godot 0.75, ndfmap's default and Karis 2).
    Constant(f64),
    /// Filament's `roughness-prefilter`: `α′ = α + min(0.5/κ, 0.04)` (α = perceptual²).
    Filament,
}

impl Widening {
    /// The widened α of a footprint with base roughness `alpha` and mean-normal length `r`,
    /// held to `[MIN_ALPHA, 1]`.
    pub fn apply(self, alpha: f64, r: f64) -> f64 {
        let k = kappa(r);
        let a = match self {
            Widening::Constant(c) => (alpha * alpha + c / k).sqrt(),
            Widening::Filament => alpha + (0.5 / k).min(0.04),
        };
        a.clamp(MIN_ALPHA, 1.0)
    }
}

/// Per-texel material maps of a PBR bake, each a value per finest texel, row-major, in
/// [0, 1]: perceptual roughness (its square is the texel's base α), metallic and occlusion.
/// Without a roughness map, [`PbrOptions::roughness`] is every texel's; metallic and occlusion
/// only pass through (box-filtered) into the `metallic_roughness` texture's B and R.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PbrMaps {
    /// Perceptual roughness `√α` per texel.
    pub roughness: Option<Vec<f32>>,
    /// Metallic per texel.
    pub metallic: Option<Vec<f32>>,
    /// Ambient occlusion per texel.
    pub occlusion: Option<Vec<f32>>,
}

impl PbrMaps {
    /// Checks every map against a `width × height` normal map: its size
    /// ([`Error::FeatureSize`]) and its values, which must be finite and in [0, 1]
    /// ([`Error::BadFeatures`] naming the count and the first bad texel).
    pub fn check(&self, width: u32, height: u32) -> Result<()> {
        for (what, map) in [
            ("roughness map", &self.roughness),
            ("metallic map", &self.metallic),
            ("occlusion map", &self.occlusion),
        ] {
            if let Some(m) = map {
                check_values(what, m, width, height)?;
            }
        }
        Ok(())
    }
}

/// One map's size and values (module [`PbrMaps::check`]).
fn check_values(what: &str, m: &[f32], width: u32, height: u32) -> Result<()> {
    let texels = width as usize * height as usize;
    if m.len() != texels {
        // The map's own size is unknown here (a flat list): report its texel count as a row.
        return Err(Error::FeatureSize {
            what: what.into(),
            feature_width: m.len() as u32,
            feature_height: 1,
            width,
            height,
        });
    }
    let bad = |v: f32| !(0.0..=1.0).contains(&v);
    let count = m.iter().filter(|&&v| bad(v)).count() as u64;
    if let Some(i) = m.iter().position(|&v| bad(v)) {
        return Err(Error::BadFeatures {
            what: what.into(),
            count,
            kind: if m[i].is_nan() {
                "NaN"
            } else {
                "outside [0, 1]"
            },
            x: (i % width as usize) as u32,
            y: (i / width as usize) as u32,
        });
    }
    Ok(())
}

/// Which channel of a data image a material map is read from: glTF's metallic-roughness
/// layout for colour images (occlusion R, roughness G, metallic B); grey images give their
/// value whatever the channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MapChannel {
    /// Occlusion: R.
    Occlusion,
    /// Roughness: G.
    Roughness,
    /// Metallic: B.
    Metallic,
}

/// A material map read from a file by [`load_map`], with what the caller should be warned of.
#[derive(Debug, Clone, PartialEq)]
pub struct LoadedMap {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// The values, row-major (not yet checked: [`PbrMaps::check`]).
    pub values: Vec<f32>,
    /// An 8- or 16-bit PNG that says its data is sRGB (an `sRGB` chunk, or a `gAMA` chunk other
    /// than linear's 1.0; Filament's `roughness-prefilter` writes both by default): roughness,
    /// metallic and occlusion are linear data, so the values were read as stored, and the
    /// caller should warn.
    pub srgb_flagged: bool,
}

/// Reads one material map from an image file ([`crate::ingest::load_data_image`]: linear,
/// never sRGB-decoded) and picks `channel` ([`MapChannel`]). With `size` (the normal map's), a
/// map of another size is refused with [`Error::FeatureSize`] before its pixels are decoded.
pub fn load_map(
    path: &std::path::Path,
    opts: &crate::ingest::IngestOptions,
    channel: MapChannel,
    size: Option<(u32, u32)>,
) -> Result<LoadedMap> {
    let img = crate::ingest::load_data_image(path, opts, size)?;
    let c = if img.channels <= 2 {
        0
    } else {
        match channel {
            MapChannel::Occlusion => 0,
            MapChannel::Roughness => 1,
            MapChannel::Metallic => 2,
        }
    };
    let srgb_flagged = img.bits <= 16 && png_says_srgb(path);
    Ok(LoadedMap {
        width: img.width,
        height: img.height,
        values: img.texels.iter().map(|t| t[c]).collect(),
        srgb_flagged,
    })
}

/// Whether the PNG file at `path` carries an `sRGB` chunk or a non-linear `gAMA` chunk before
/// its image data
/// (false for other files and for anything unreadable: the decoder has already judged them).
fn png_says_srgb(path: &std::path::Path) -> bool {
    use std::io::Read;
    let mut head = Vec::new();
    let Ok(f) = std::fs::File::open(path) else {
        return false;
    };
    if f.take(1 << 20).read_to_end(&mut head).is_err() {
        return false;
    }
    if !head.starts_with(b"\x89PNG\r\n\x1a\n") {
        return false;
    }
    let mut at = 8;
    while at + 8 <= head.len() {
        let len = u32::from_be_bytes([head[at], head[at + 1], head[at + 2], head[at + 3]]) as usize;
        let kind = &head[at + 4..at + 8];
        match kind {
            b"sRGB" => return true,
            // gAMA 1/2.2 (45455), as an sRGB PNG writer sets it; 100000 is linear.
            b"gAMA" if at + 12 <= head.len() => {
                let g =
                    u32::from_be_bytes([head[at + 8], head[at + 9], head[at + 10], head[at + 11]]);
                if g != 100_000 {
                    return true;
                }
            }
            b"IDAT" | b"IEND" => return false,
            _ => {}
        }
        at = at.saturating_add(12).saturating_add(len);
    }
    false
}

/// The light/view pairs a fit minimizes over, with a weight each.
#[derive(Debug, Clone, PartialEq)]
pub struct FitSet {
    /// The pairs, at most [`MAX_PAIRS`].
    pub pairs: Vec<Pair>,
    /// One weight per pair, multiplying its residual.
    pub weights: Vec<f64>,
    /// The half vector of each pair (computed once).
    pub halves: Vec<DVec3>,
}

impl FitSet {
    /// The bake's fixed pairs ([`standard_pairs`]: views and lights up to 74° from the
    /// zenith, grazing ones included) with unit weights: the fit minimizes the unweighted
    /// error of `D·max(n·l, 0)`, the quantity issue 17's targets measure.
    pub fn standard() -> FitSet {
        FitSet::unweighted(&standard_pairs())
    }

    /// The fit set of the previous rounds, for renderers that never see grazing angles
    /// ([`near_peak_pairs`]: 7 views up to 75°, half vectors at most 28° from the zenith),
    /// weighted by the GGX g factor at base roughness `alpha`: `F(l·h) V(l_z, v_z)`
    /// (Schlick, F0 = 0.04; Smith height-correlated), normalized to a mean of 1. Use it
    /// through [`bake_with_set`].
    pub fn near_peak(alpha: f64) -> FitSet {
        let pairs = near_peak_pairs();
        let mut weights: Vec<f64> = pairs
            .iter()
            .map(|&(l, v)| {
                let h = half_vector(l, v);
                schlick(l.dot(h), 0.04) * smith_visibility(l.z, v.z, alpha)
            })
            .collect();
        let mean = weights.iter().sum::<f64>() / weights.len() as f64;
        weights.iter_mut().for_each(|w| *w /= mean);
        let halves = pairs.iter().map(|&(l, v)| half_vector(l, v)).collect();
        FitSet {
            pairs,
            weights,
            halves,
        }
    }

    /// The scene-viewing-range fit set, for a renderer whose views and lights stay within
    /// `max_deg` degrees of the normal: [`standard_pairs`]' design with every polar angle
    /// scaled by `max_deg / 74°` (the same 112 pairs, as dense inside the range as the standard
    /// set is inside 74°), unit weights; the standard set itself from 74° on. `None` unless
    /// `max_deg` is a number in [[`MIN_FIT_ANGLE`], 90]. (Keeping only the standard pairs
    /// within the range was measured and fitted worse, even on pairs within it: docs/pbr.md.)
    pub fn view_range(max_deg: f64) -> Option<FitSet> {
        (MIN_FIT_ANGLE..=90.0)
            .contains(&max_deg)
            .then(|| FitSet::unweighted(&scaled_pairs((max_deg / STANDARD_MAX_ANGLE).min(1.0))))
    }

    /// `pairs` with unit weights (the report's best-possible lobe, fitted on the evaluation's
    /// own pairs). At most [`MAX_PAIRS`] pairs are kept.
    pub fn unweighted(pairs: &[Pair]) -> FitSet {
        let pairs: Vec<Pair> = pairs.iter().copied().take(MAX_PAIRS).collect();
        FitSet {
            weights: vec![1.0; pairs.len()],
            halves: pairs.iter().map(|&(l, v)| half_vector(l, v)).collect(),
            pairs,
        }
    }
}

/// A unit direction from polar angle θ and azimuth φ, in degrees.
fn direction(theta_deg: f64, phi_deg: f64) -> DVec3 {
    let (t, p) = (theta_deg.to_radians(), phi_deg.to_radians());
    DVec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos())
}

/// The bake's fixed light/view pairs, chosen once to cover the range issue 17's targets
/// measure (views and lights from the zenith to 70°, grazing included) without using the
/// evaluation's own directions (`eval::default_directions`: views at 0°, 35°, 70° and lights
/// at 0°, 35°, 70° on the axes), so that the fit is scored on pairs it did not see. The design:
/// 7 views (θ = 12° at φ = 30°; 40° at φ = 75°, 195°, 315°; 68° at φ = 15°, 135°, 255°) and per
/// view 8 lights: the mirror direction (half vector at the zenith: the peak the relative error
/// is dominated by), the zenith, and two lights on each of the rings θ = 25°, 50°, 74°,
/// opposite each other, at azimuths relative to the view's turned by 50° from one view to the
/// next (ring k at `φ_v + 40° + 60° k + 50° i` and 180° further): 56 pairs. Then the same 56
/// turned by 187° about the zenith ([`SECOND_COPY_TURN`]), so that every texel is fitted
/// at other azimuths too: 112 pairs. One copy of 56 overfitted sharp lobes (a lobe a few
/// degrees wide threads between the pairs): docs/pbr.md, "A denser fit set (stop 42)".
pub fn standard_pairs() -> Vec<Pair> {
    scaled_pairs(1.0)
}

/// The widest polar angle of [`standard_pairs`] (its outer light ring), degrees.
pub const STANDARD_MAX_ANGLE: f64 = 74.0;

/// The turn of [`standard_pairs`]' second copy of its design about the zenith, degrees: a half
/// turn and 7° more, so that none of the copy's azimuths is one of the first copy's or the
/// evaluation's (those are all multiples of 5°).
pub const SECOND_COPY_TURN: f64 = 187.0;

/// [`standard_pairs`]' design with every polar angle multiplied by `k` (azimuths unchanged),
/// and its copy turned by [`SECOND_COPY_TURN`].
fn scaled_pairs(k: f64) -> Vec<Pair> {
    let once = design_once(k);
    let (c, s) = (
        SECOND_COPY_TURN.to_radians().cos(),
        SECOND_COPY_TURN.to_radians().sin(),
    );
    let turn = |d: DVec3| DVec3::new(c * d.x - s * d.y, s * d.x + c * d.y, d.z);
    let turned: Vec<Pair> = once.iter().map(|&(l, v)| (turn(l), turn(v))).collect();
    once.into_iter().chain(turned).collect()
}

/// One copy of [`standard_pairs`]' design (56 pairs), polar angles multiplied by `k`.
fn design_once(k: f64) -> Vec<Pair> {
    let views = [
        (12.0, 30.0),
        (40.0, 75.0),
        (40.0, 195.0),
        (40.0, 315.0),
        (68.0, 15.0),
        (68.0, 135.0),
        (68.0, 255.0),
    ];
    let mut out = Vec::new();
    for (i, &(tv, pv)) in views.iter().enumerate() {
        let tv = tv * k;
        let v = direction(tv, pv);
        out.push((direction(tv, pv + 180.0), v));
        out.push((DVec3::Z, v));
        for (ring, tl) in [25.0, 50.0, STANDARD_MAX_ANGLE].into_iter().enumerate() {
            let phi = pv + 40.0 + 60.0 * ring as f64 + 50.0 * i as f64;
            out.push((direction(tl * k, phi), v));
            out.push((direction(tl * k, phi + 180.0), v));
        }
    }
    out
}

/// [`FitSet::near_peak`]'s pairs (the bake's until this round): 7 views (the zenith, θ = 45°
/// at φ = 0°, 120°, 240°, θ = 75° at φ = 60°, 180°, 300°), and per view 7 half vectors (the
/// zenith, θ_h = 12° at three azimuths, 28° at three others, turned by 40° from one view to
/// the next), each light the mirror of the view about its half vector; pairs whose light is
/// within 2° of the horizon are dropped: 39 of the 49 remain.
pub fn near_peak_pairs() -> Vec<Pair> {
    let views = [
        (0.0, 0.0),
        (45.0, 0.0),
        (45.0, 120.0),
        (45.0, 240.0),
        (75.0, 60.0),
        (75.0, 180.0),
        (75.0, 300.0),
    ];
    let mut out = Vec::new();
    for (i, &(tv, pv)) in views.iter().enumerate() {
        let v = direction(tv, pv);
        let turn = 40.0 * i as f64;
        let mut halves = vec![DVec3::Z];
        for k in 0..3 {
            halves.push(direction(12.0, turn + 120.0 * k as f64));
            halves.push(direction(28.0, turn + 60.0 + 120.0 * k as f64));
        }
        for h in halves {
            let l = 2.0 * v.dot(h) * h - v;
            if l.z > 2f64.to_radians().sin() {
                out.push((l.normalize(), v));
            }
        }
    }
    out
}

/// The shading of one isotropic lobe for pair `(l, h)`: `D_α(n·h) max(n·l, 0)`.
fn iso_value(n: DVec3, alpha: f64, l: DVec3, h: DVec3) -> f64 {
    ggx(n.dot(h), alpha) * n.dot(l).max(0.0)
}

/// The exact targets of every level for `pairs`: per level, `pairs.len()` values per texel
/// (texel-major), the footprint averages of `D_{α_i}(n_i·h) max(n_i·l, 0)` over the finest
/// normals (`alphas[i]` their base roughness). Computed per batch of 8 pairs as an image of
/// per-normal values box-filtered onto each level ([`reduce`], f64 sums in a fixed order).
/// Level 0 holds the per-normal values themselves.
pub fn targets(
    map: &NormalMap,
    alphas: &[f64],
    pairs: &[Pair],
    levels: &[LevelFootprints],
) -> Vec<Vec<f64>> {
    targets_from(map, alphas, pairs, levels, 0)
}

/// [`targets`] at levels `first` and coarser; the finer levels' vectors are empty. The bake
/// fits from level 1 and leaves level 0's out: it is three quarters of the values.
fn targets_from(
    map: &NormalMap,
    alphas: &[f64],
    pairs: &[Pair],
    levels: &[LevelFootprints],
    first: usize,
) -> Vec<Vec<f64>> {
    let p = pairs.len();
    let mut out: Vec<Vec<f64>> = levels
        .iter()
        .enumerate()
        .map(|(k, lf)| {
            let texels = if k < first {
                0
            } else {
                lf.size.0 as usize * lf.size.1 as usize
            };
            vec![0.0; texels * p]
        })
        .collect();
    for (b0, batch) in pairs.chunks(8).enumerate() {
        let c = batch.len();
        let lights: Vec<(DVec3, DVec3)> =
            batch.iter().map(|&(l, v)| (l, half_vector(l, v))).collect();
        let mut finest = vec![0.0f64; map.normals().len() * c];
        finest
            .par_chunks_mut(c)
            .zip(map.normals().par_iter().zip(alphas.par_iter()))
            .for_each(|(o, (n, &a))| {
                let n = n.as_dvec3();
                for (o, &(l, h)) in o.iter_mut().zip(&lights) {
                    *o = iso_value(n, a, l, h);
                }
            });
        for (lf, level) in levels.iter().zip(out.iter_mut()).skip(first) {
            let r = reduce(&finest, c, map.width(), lf);
            level
                .par_chunks_mut(p)
                .zip(r.par_chunks(c))
                .for_each(|(dst, src)| dst[b0 * 8..b0 * 8 + c].copy_from_slice(src));
        }
    }
    out
}

/// An isotropic GGX lobe: its direction and roughness α.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IsoLobe {
    /// Unit direction (the texel's normal).
    pub n: DVec3,
    /// GGX α in `[MIN_ALPHA, 1]`.
    pub alpha: f64,
}

/// An anisotropic GGX lobe in `KHR_materials_anisotropy`'s terms.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AnisoLobe {
    /// Unit direction (the texel's normal).
    pub n: DVec3,
    /// Angle of the tangent direction `(cos φ, sin φ, 0)` in tangent space, radians.
    pub phi: f64,
    /// α along the tangent direction.
    pub alpha_t: f64,
    /// α along the bitangent `n × t`.
    pub alpha_b: f64,
}

/// The tangent `t` (`(cos φ, sin φ, 0)` made orthogonal to `n`) and bitangent `n × t` of an
/// anisotropic lobe; `t = tangent_frame(n).0` when `n` is horizontal-aligned with it.
pub fn aniso_frame(n: DVec3, phi: f64) -> (DVec3, DVec3) {
    let d = DVec3::new(phi.cos(), phi.sin(), 0.0);
    let t = (d - n * n.dot(d))
        .try_normalize()
        .unwrap_or_else(|| tangent_frame(n).0);
    (t, n.cross(t))
}

/// Anisotropic GGX `D = 1/(π α_t α_b ((h·t/α_t)² + (h·b/α_b)² + (h·n)²)²)`, zero for
/// `h·n ≤ 0` (module docs); with `α_t = α_b = α` it is [`ggx`].
pub fn ggx_tb(h: DVec3, n: DVec3, t: DVec3, b: DVec3, alpha_t: f64, alpha_b: f64) -> f64 {
    let z = n.dot(h);
    if z.is_nan() || z <= 0.0 {
        return 0.0;
    }
    let (x, y) = (h.dot(t) / alpha_t, h.dot(b) / alpha_b);
    let q = x * x + y * y + z * z;
    1.0 / (PI * alpha_t * alpha_b * q * q)
}

/// The shading of one anisotropic lobe for pair `(l, h)`: `D(h) max(n·l, 0)`.
/// The lobe's frame `(t, b)` ([`aniso_frame`]) is computed once by the caller.
fn aniso_value_in(lobe: &AnisoLobe, (t, b): (DVec3, DVec3), l: DVec3, h: DVec3) -> f64 {
    ggx_tb(h, lobe.n, t, b, lobe.alpha_t, lobe.alpha_b) * lobe.n.dot(l).max(0.0)
}

/// The cost of an anisotropic lobe ([`cost`] of [`aniso_value_in`], its frame computed once).
fn aniso_cost(set: &FitSet, target: &[f64], lobe: &AnisoLobe) -> f64 {
    let frame = aniso_frame(lobe.n, lobe.phi);
    cost(set, target, |l, h| aniso_value_in(lobe, frame, l, h))
}

/// The weighted squared error `Σ w_p² (F_p − G_p)²` of a lobe's values `f(l, h)` against one
/// texel's targets.
fn cost(set: &FitSet, target: &[f64], f: impl Fn(DVec3, DVec3) -> f64) -> f64 {
    set.pairs
        .iter()
        .zip(&set.halves)
        .zip(&set.weights)
        .zip(target)
        .map(|(((&(l, _), &h), w), g)| {
            let r = w * (f(l, h) - g);
            r * r
        })
        .sum()
}

/// Solves the `N × N` system `a x = b` by Gaussian elimination with partial pivoting;
/// `None` when it is singular.
fn solve<const N: usize>(mut a: [[f64; N]; N], mut b: [f64; N]) -> Option<[f64; N]> {
    for c in 0..N {
        let p = (c..N).max_by(|&i, &j| a[i][c].abs().total_cmp(&a[j][c].abs()))?;
        if a[p][c].abs() < 1e-300 {
            return None;
        }
        a.swap(c, p);
        b.swap(c, p);
        let pivot = a[c];
        for r in c + 1..N {
            let f = a[r][c] / pivot[c];
            for (x, y) in a[r][c..].iter_mut().zip(&pivot[c..]) {
                *x -= f * y;
            }
            b[r] -= f * b[c];
        }
    }
    let mut x = [0.0; N];
    for c in (0..N).rev() {
        let s: f64 = (c + 1..N).map(|k| a[c][k] * x[k]).sum();
        x[c] = (b[c] - s) / a[c][c];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Levenberg–Marquardt over `N` parameters, shared by the isotropic fit (analytic normal
/// equations in lanes, `pbr/kernel.rs`) and the anisotropic one (forward differences):
/// from `p` of cost `current`, each of up to `iterations` steps takes the normal equations
/// `(JᵀJ, −Jᵀr)` at `p` from `normal_equations` and tries up to three dampings
/// `(JᵀJ + λ diag(JᵀJ)) δ = −Jᵀr` (λ × 10 after a failure, × 0.3 after a success), each step
/// component held to `max_step`; a trial is taken when `cost_at` is lower. Stops when no
/// damping lowers the cost or a step lowers it by `converged` of itself or less (0: only the
/// former). Returns the parameters and their cost.
fn levenberg_marquardt<const N: usize>(
    mut p: [f64; N],
    mut current: f64,
    iterations: usize,
    max_step: [f64; N],
    converged: f64,
    mut normal_equations: impl FnMut(&[f64; N]) -> ([[f64; N]; N], [f64; N]),
    cost_at: impl Fn(&[f64; N]) -> f64,
) -> ([f64; N], f64) {
    let mut lambda = 1e-3;
    for _ in 0..iterations {
        let (a, g) = normal_equations(&p);
        let before = current;
        let mut improved = false;
        for _ in 0..3 {
            let mut damped = a;
            for u in 0..N {
                damped[u][u] += lambda * a[u][u].max(1e-12);
            }
            let Some(step) = solve(damped, g) else {
                lambda *= 10.0;
                continue;
            };
            let mut trial = p;
            for u in 0..N {
                trial[u] += step[u].clamp(-max_step[u], max_step[u]);
            }
            let c = cost_at(&trial);
            if c < current {
                p = trial;
                current = c;
                lambda = (lambda * 0.3).max(1e-9);
                improved = true;
                break;
            }
            lambda *= 10.0;
        }
        if !improved || before - current <= converged * before {
            break;
        }
    }
    (p, current)
}

/// `normalize(n0 + u t1 + v t2)` for the tangent frame `(t1, t2)` of `n0`.
fn offset(n0: DVec3, t1: DVec3, t2: DVec3, u: f64, v: f64) -> DVec3 {
    (n0 + u * t1 + v * t2).normalize()
}

/// Fits one isotropic lobe to one texel's `target` (values for `set`'s pairs): the best of
/// `starts` by `cost`, refined by up to `iterations` Levenberg–Marquardt steps over
/// `(u, v, ln α)` (the normal `normalize(n₀ + u t₁ + v t₂)` in the start's tangent frame)
/// with the analytic Jacobian `∂D/∂c = 4α²c(1 − α²)/(π d³)`, `∂D/∂ln α = 2D(1 − 2c²α²/d)`
/// for `d = 1 − c²(1 − α²)`. Returns the lobe and its cost. `α` stays in `[floor, 1]`
/// (the bake's floor is the footprint's base roughness `sqrt(E[α²])`: filtering only widens,
/// and a narrower lobe fitted to a few pairs overshoots between them). The sums run in eight
/// f64 lanes (`pbr/kernel.rs`); the bake stops a texel's steps early ([`FAST_CONVERGED`]),
/// this function does not.
pub fn fit_isotropic(
    set: &FitSet,
    target: &[f64],
    starts: &[IsoLobe],
    iterations: usize,
    floor: f64,
) -> (IsoLobe, f64) {
    let k = kernel::IsoKernel::new(set);
    kernel::fit(
        &k,
        &k.targets(target),
        starts,
        iterations,
        floor,
        0.0,
        false,
    )
}

/// Fits one anisotropic lobe to one texel's `target`: the best two of `starts`, refined by
/// `iterations` Levenberg–Marquardt steps over `(u, v, ln α_t, ln α_b, φ)` with a
/// forward-difference Jacobian. The result has `α_t ≥ α_b` (swapped with φ turned by 90°
/// otherwise), `φ ∈ [0, π)` and both α in `[floor, 1]`.
pub fn fit_anisotropic(
    set: &FitSet,
    target: &[f64],
    starts: &[AnisoLobe],
    iterations: usize,
    floor: f64,
) -> (AnisoLobe, f64) {
    fit_anisotropic_held(set, target, starts, iterations, floor, false)
}

/// [`fit_anisotropic`]; with `hold_normal` the steps keep each start's normal and move the
/// two α and φ only ([`PbrOptions::mean_normal`]).
fn fit_anisotropic_held(
    set: &FitSet,
    target: &[f64],
    starts: &[AnisoLobe],
    iterations: usize,
    floor: f64,
    hold_normal: bool,
) -> (AnisoLobe, f64) {
    // The two best starts are refined (an anisotropic lobe has local minima in φ).
    let mut ranked: Vec<(f64, AnisoLobe)> = starts
        .iter()
        .map(|s| (aniso_cost(set, target, s), *s))
        .collect();
    ranked.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut out = (canonical(ranked[0].1), ranked[0].0);
    for &(c, s) in ranked.iter().take(2) {
        let r = refine_anisotropic(set, target, s, c, iterations, floor, hold_normal);
        if r.1 < out.1 {
            out = r;
        }
    }
    out
}

/// [`fit_anisotropic`]'s refinement of one start `best` of cost `best_cost`.
fn refine_anisotropic(
    set: &FitSet,
    target: &[f64],
    best: AnisoLobe,
    best_cost: f64,
    iterations: usize,
    floor: f64,
    hold_normal: bool,
) -> (AnisoLobe, f64) {
    let n0 = best.n;
    let (t1, t2) = tangent_frame(n0);
    let lo = floor.clamp(MIN_ALPHA, 1.0).ln();
    let lobe_of = |p: &[f64; 5]| AnisoLobe {
        n: offset(n0, t1, t2, p[0], p[1]),
        alpha_t: p[2].clamp(lo, 0.0).exp(),
        alpha_b: p[3].clamp(lo, 0.0).exp(),
        phi: p[4],
    };
    let residuals = |p: &[f64; 5], r: &mut [f64]| {
        let lobe = lobe_of(p);
        let frame = aniso_frame(lobe.n, lobe.phi);
        let pairs = set
            .pairs
            .iter()
            .zip(&set.halves)
            .zip(&set.weights)
            .zip(target);
        for (k, (((&(l, _), &h), &w), g)) in pairs.enumerate() {
            r[k] = w * (aniso_value_in(&lobe, frame, l, h) - g);
        }
    };
    let pairs = set.pairs.len();
    let normal_equations = |p: &[f64; 5]| {
        // Forward-difference Jacobian rows, then JᵀJ and −Jᵀr.
        let mut r = [0.0; MAX_PAIRS];
        let mut j = [[0.0; 5]; MAX_PAIRS];
        residuals(p, &mut r[..pairs]);
        let mut shifted = [0.0; MAX_PAIRS];
        for u in 0..5 {
            let step = 1e-6;
            let mut q = *p;
            q[u] += step;
            residuals(&q, &mut shifted[..pairs]);
            for k in 0..pairs {
                j[k][u] = (shifted[k] - r[k]) / step;
            }
        }
        let mut a = [[0.0; 5]; 5];
        let mut g = [0.0; 5];
        for (ri, ji) in r[..pairs].iter().zip(&j[..pairs]) {
            for u in 0..5 {
                g[u] -= ji[u] * ri;
                for w in 0..5 {
                    a[u][w] += ji[u] * ji[w];
                }
            }
        }
        if hold_normal {
            hold_normal_parameters(&mut a, &mut g);
        }
        (a, g)
    };
    let cost_at = |p: &[f64; 5]| aniso_cost(set, target, &lobe_of(p));
    let p0 = [0.0, 0.0, best.alpha_t.ln(), best.alpha_b.ln(), best.phi];
    let (p, c) = levenberg_marquardt(
        p0,
        cost_at(&p0),
        iterations,
        [0.3, 0.3, 1.0, 1.0, 0.5],
        0.0,
        normal_equations,
        cost_at,
    );
    let lobe = if c < best_cost { lobe_of(&p) } else { best };
    (canonical(lobe), c.min(best_cost))
}

/// Takes the normal's parameters `u`, `v` (the first two) out of the normal equations
/// `(JᵀJ, −Jᵀr)`: their rows and columns zero, so [`levenberg_marquardt`]'s steps leave them
/// at 0 ([`PbrOptions::mean_normal`]).
fn hold_normal_parameters<const N: usize>(a: &mut [[f64; N]; N], b: &mut [f64; N]) {
    for u in 0..2 {
        a[u] = [0.0; N];
        for row in a.iter_mut() {
            row[u] = 0.0;
        }
        b[u] = 0.0;
    }
}

/// The same lobe with `α_t ≥ α_b` and `φ ∈ [0, π)`.
fn canonical(mut lobe: AnisoLobe) -> AnisoLobe {
    if lobe.alpha_t < lobe.alpha_b {
        std::mem::swap(&mut lobe.alpha_t, &mut lobe.alpha_b);
        lobe.phi += 0.5 * PI;
    }
    lobe.phi = lobe.phi.rem_euclid(PI);
    lobe
}

/// α values (log-spaced from the floor to 1) among the starts of the roughness-only fit
/// ([`PbrOptions::mean_normal`]); its steps are the default fit's ([`FAST_ITERATIONS`], the
/// same early stop).
pub const HELD_SCAN: usize = 16;

/// Most Levenberg–Marquardt steps of the bake's isotropic fit per texel ([`Search::Fast`]).
pub const FAST_ITERATIONS: usize = 8;

/// The bake's isotropic fit stops a texel's steps once one lowers the cost by less than this
/// fraction of itself ([`Search::Fast`]).
pub const FAST_CONVERGED: f64 = 1e-3;

/// How hard a PBR bake searches per texel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Search {
    /// The bake's: the best of nine starts plus six mode starts (module docs, [`mode_starts`]),
    /// then up to [`FAST_ITERATIONS`] Levenberg–Marquardt steps, fewer once a step gains less
    /// than [`FAST_CONVERGED`]; the best mode start is refined as well when its normal is more
    /// than half the base α from the refined lobe's, and the lower cost kept (anisotropic: 4
    /// more from the isotropic fit and the covariance start).
    Fast,
    /// The report's best-possible lobe: the fast starts plus up to 16 of the footprint's own
    /// normals at 1, 2 and 4 times the base α, each of
    /// the best three refined by 25 steps, at levels `from_level` and coarser (finer levels as
    /// [`Search::Fast`]: their lobes are only the coarser levels' starts).
    Thorough {
        /// The finest level searched thoroughly.
        from_level: usize,
    },
}

/// Seconds a PBR bake spent, per stage ([`bake_with_set`]): not part of the bake, so that
/// its bytes do not depend on the machine.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PbrTimings {
    /// The exact targets of every level ([`targets`]) and the footprint statistics.
    pub targets: f64,
    /// The isotropic fit, per level (level 0: none).
    pub fit: Vec<f64>,
    /// The anisotropic fit, per level (empty without the option).
    pub anisotropic: Vec<f64>,
}

/// Bakes the PBR textures of `map` for `options` and the optional per-texel `maps` (checked
/// first, [`PbrMaps::check`]) with the options' pairs ([`fit_set`]) and [`Search::Fast`].
pub(crate) fn bake(
    map: &NormalMap,
    options: &PbrOptions,
    maps: Option<&PbrMaps>,
    progress: &mut Progress,
) -> Result<Bake> {
    bake_fit(
        map,
        options,
        maps,
        &fit_set(options)?,
        Search::Fast,
        0,
        progress,
        &mut PbrTimings::default(),
    )
}

/// Bakes the PBR textures of `map` with per-texel material `maps` (checked first,
/// [`PbrMaps::check`]): what `methods::bake_with` does for [`Method::Pbr`], with maps. The
/// memory budget is the caller's to check (`methods::check_memory`).
pub fn bake_with_maps(
    map: &NormalMap,
    options: &PbrOptions,
    maps: Option<&PbrMaps>,
) -> Result<Bake> {
    crate::bake::run_with_progress(&mut |_| true, |p| bake(map, options, maps, p))
}

/// `bake` with any pair set and search (the report's best-possible isotropic lobe: the
/// evaluation's own pairs, [`Search::Thorough`]), and the seconds each stage took; `set`
/// replaces the options' own ([`PbrOptions::fit_max_angle`] is then only checked). Levels
/// 1 to `fit_from − 1` are not fitted (the κ formula's lobe, c = 2, isotropic): for a report
/// that measures only coarser levels.
pub fn bake_with_set(
    map: &NormalMap,
    options: &PbrOptions,
    maps: Option<&PbrMaps>,
    set: &FitSet,
    search: Search,
    fit_from: usize,
) -> Result<(Bake, PbrTimings)> {
    let mut timings = PbrTimings::default();
    let bake = crate::bake::run_with_progress(&mut |_| true, |p| {
        bake_fit(map, options, maps, set, search, fit_from, p, &mut timings)
    })?;
    Ok((bake, timings))
}

/// α from a perceptual roughness, held to `[MIN_ALPHA, 1]`.
pub fn base_alpha(perceptual: f64) -> f64 {
    (perceptual * perceptual).clamp(MIN_ALPHA, 1.0)
}

/// Per finest texel: base α, metallic, occlusion.
fn material(map: &NormalMap, options: &PbrOptions, maps: Option<&PbrMaps>) -> Vec<[f64; 3]> {
    let texels = map.normals().len();
    let get = |m: Option<&Vec<f32>>, i: usize, d: f64| m.map_or(d, |m| m[i] as f64);
    (0..texels)
        .map(|i| {
            let r = get(
                maps.and_then(|m| m.roughness.as_ref()),
                i,
                options.roughness,
            );
            [
                base_alpha(r),
                get(maps.and_then(|m| m.metallic.as_ref()), i, 0.0),
                get(maps.and_then(|m| m.occlusion.as_ref()), i, 1.0),
            ]
        })
        .collect()
}

/// Per level: mean normal (3), mean α², metallic, occlusion, and `E[n nᵀ]` (6) per texel.
const STATS: usize = 12;

fn statistics(map: &NormalMap, mat: &[[f64; 3]], levels: &[LevelFootprints]) -> Vec<Vec<f64>> {
    let mut finest = vec![0.0f64; map.normals().len() * STATS];
    finest
        .par_chunks_mut(STATS)
        .zip(map.normals().par_iter().zip(mat.par_iter()))
        .for_each(|(o, (n, m))| {
            let n = n.as_dvec3();
            o.copy_from_slice(&[
                n.x,
                n.y,
                n.z,
                m[0] * m[0],
                m[1],
                m[2],
                n.x * n.x,
                n.y * n.y,
                n.z * n.z,
                n.x * n.y,
                n.x * n.z,
                n.y * n.z,
            ]);
        });
    levels
        .iter()
        .map(|lf| reduce(&finest, STATS, map.width(), lf))
        .collect()
}

/// The starts of a texel at a level ≥ 1: the κ formula with c = 2, the mean normal at base
/// α, the four children, the κ formula with c = 0.5, 1, 4, the footprint's modes `modes`
/// ([`mode_starts`]) (and, for [`Search::Thorough`], the footprint's own normals `own` at 1,
/// 2, 4 × the base α).
fn iso_starts(
    stats: &[f64],
    children: [Option<IsoLobe>; 4],
    search: Search,
    own: &[DVec3],
    modes: &[IsoLobe],
) -> Vec<IsoLobe> {
    let m = DVec3::new(stats[0], stats[1], stats[2]);
    let r = m.length();
    let mean = m.try_normalize().unwrap_or(DVec3::Z);
    let alpha = stats[3].max(0.0).sqrt().clamp(MIN_ALPHA, 1.0);
    let mut s = vec![
        IsoLobe {
            n: mean,
            alpha: Widening::Constant(crate::brdf::GGX_WIDENING_C).apply(alpha, r),
        },
        IsoLobe { n: mean, alpha },
    ];
    s.extend(children.into_iter().flatten());
    for c in [0.5, 1.0, 4.0] {
        s.push(IsoLobe {
            n: mean,
            alpha: Widening::Constant(c).apply(alpha, r),
        });
    }
    s.extend_from_slice(modes);
    if search != Search::Fast {
        for &n in own {
            for f in [1.0, 2.0, 4.0] {
                s.push(IsoLobe {
                    n,
                    alpha: (alpha * f).min(1.0),
                });
            }
        }
    }
    s
}

/// The tangent-plane covariance start of the anisotropic fit about `n`: eigenvectors of
/// `Σ_ab = t_aᵀ E[n nᵀ] t_b` give the direction, `α² + 2λ` the two α² (held to [MIN_ALPHA², 1]).
fn covariance_start(stats: &[f64], n: DVec3) -> AnisoLobe {
    let alpha2 = stats[3].max(MIN_ALPHA * MIN_ALPHA);
    let (t1, t2) = tangent_frame(n);
    let mm = |a: DVec3, b: DVec3| {
        let (xx, yy, zz, xy, xz, yz) =
            (stats[6], stats[7], stats[8], stats[9], stats[10], stats[11]);
        a.x * (xx * b.x + xy * b.y + xz * b.z)
            + a.y * (xy * b.x + yy * b.y + yz * b.z)
            + a.z * (xz * b.x + yz * b.y + zz * b.z)
    };
    let (sxx, syy, sxy) = (mm(t1, t1), mm(t2, t2), mm(t1, t2));
    let tr = sxx + syy;
    let disc = ((sxx - syy) * (sxx - syy) * 0.25 + sxy * sxy).sqrt();
    let (l1, l2) = ((0.5 * tr + disc).max(0.0), (0.5 * tr - disc).max(0.0));
    let angle = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    let e = t1 * angle.cos() + t2 * angle.sin();
    let clamp = |v: f64| v.sqrt().clamp(MIN_ALPHA, 1.0);
    canonical(AnisoLobe {
        n,
        phi: e.y.atan2(e.x),
        alpha_t: clamp(alpha2 + 2.0 * l1),
        alpha_b: clamp(alpha2 + 2.0 * l2),
    })
}

/// The anisotropic fit's starts: the covariance start, the isotropic lobe, and the isotropic
/// lobe stretched 1.5× along and 1.5× less across four directions (φ = 0, π/4, π/2, 3π/4),
/// so that the orientation does not start where its derivative vanishes.
pub fn aniso_starts(iso: IsoLobe, covariance: AnisoLobe) -> Vec<AnisoLobe> {
    let mut s = vec![
        covariance,
        AnisoLobe {
            n: iso.n,
            phi: 0.0,
            alpha_t: iso.alpha,
            alpha_b: iso.alpha,
        },
    ];
    for q in 0..4 {
        s.push(AnisoLobe {
            n: iso.n,
            phi: 0.25 * PI * q as f64,
            alpha_t: (iso.alpha * 1.5).min(1.0),
            alpha_b: (iso.alpha / 1.5).max(MIN_ALPHA),
        });
    }
    s
}

/// The fast search's refinement ([`Search::Fast`]): of `starts`, the first `split` the mean
/// normal's and the children's, the rest the mode starts, every cost is evaluated once; the
/// best start is refined (`fit(j)` refines start j), and so is the best start of the other
/// family when its normal is more than `apart` radians from the refined lobe's: a second
/// basin (adding the mode starts must not lose the mean-normal basin when a mode start has
/// the lower cost before refinement but the higher after). Returns the lower of the two
/// (the first on a tie).
fn two_basins(
    kernel: &kernel::IsoKernel,
    t: &kernel::Targets,
    starts: &[IsoLobe],
    split: usize,
    apart: f64,
    fit: impl Fn(usize) -> (IsoLobe, f64),
) -> (IsoLobe, f64) {
    let costs: Vec<f64> = starts
        .iter()
        .map(|l| kernel.cost(l.n, l.alpha, t))
        .collect();
    let pick = |r: std::ops::Range<usize>| {
        r.fold(None, |b: Option<usize>, j| match b {
            Some(b) if costs[b] <= costs[j] => Some(b),
            _ => Some(j),
        })
    };
    let Some(b) = pick(0..starts.len()) else {
        return (starts[0], f64::INFINITY);
    };
    let best = fit(b);
    let other = if b < split {
        pick(split..starts.len())
    } else {
        pick(0..split)
    };
    match other {
        Some(o) if starts[o].n.angle_between(best.0.n) > apart => {
            let second = fit(o);
            if second.1 < best.1 { second } else { best }
        }
        _ => best,
    }
}

/// Taps per axis a texel's mode search reads (`footprint_sample`): up to 8 × 8 of its
/// footprint's finest normals (levels 1–3 of a power-of-two map: all of them).
pub const MODE_TAPS: usize = 8;

/// Mean-shift steps per kernel of [`mode_starts`].
pub const MODE_STEPS: usize = 3;

/// The kernels of [`mode_starts`]: concentrations `c/α²` for these `c` (2: the vMF that
/// matches a GGX lobe of the base α, `κ ≈ 2/α²`; 0.5: one twice as wide).
pub const MODE_KERNELS: [f64; 2] = [2.0, 0.5];

/// A texel's footprint sampled for the mode search: up to [`MODE_TAPS`] taps per axis of its
/// exact footprint ([`LevelFootprints`]), evenly strided from the middle of each stride, each
/// with its footprint weight. Writes into `out` and returns how many it wrote.
fn footprint_sample(
    map: &NormalMap,
    lf: &LevelFootprints,
    x: u32,
    y: u32,
    out: &mut [(DVec3, f64); MODE_TAPS * MODE_TAPS],
) -> usize {
    let pick = |taps: Vec<(u32, f64)>| -> Vec<(u32, f64)> {
        let step = taps.len().div_ceil(MODE_TAPS).max(1);
        taps.into_iter()
            .skip((step - 1) / 2)
            .step_by(step)
            .collect()
    };
    let xs = pick(lf.x.taps(x as usize).collect());
    let ys = pick(lf.y.taps(y as usize).collect());
    let mut count = 0;
    for &(fy, wy) in &ys {
        for &(fx, wx) in &xs {
            out[count] = (map.normal(fx, fy).as_dvec3(), wx * wy);
            count += 1;
        }
    }
    count
}

/// Mean shift on the sphere over weighted normals `samples` from `start`: `steps` times
/// `m ← normalize(Σ w_j exp(κ (n_j·m − 1)) n_j)` (the exponent shifted by its largest term so
/// that no weight set underflows to all zeros). Returns the mode and the kernel-weighted mean
/// length `|Σ k_j n_j| / Σ k_j` there (the mode's local spread; 1 when the samples agree).
pub fn mean_shift(
    samples: &[(DVec3, f64)],
    start: DVec3,
    kappa: f64,
    steps: usize,
) -> (DVec3, f64) {
    let mut m = start;
    let mut r = 1.0;
    for _ in 0..steps {
        let top = samples
            .iter()
            .map(|(n, _)| n.dot(m))
            .fold(f64::NEG_INFINITY, f64::max);
        let (mut sum, mut weight) = (DVec3::ZERO, 0.0);
        for &(n, w) in samples {
            let k = w * (kappa * (n.dot(m) - top)).exp();
            sum += k * n;
            weight += k;
        }
        let len = sum.length();
        if !(len > 0.0 && weight > 0.0) {
            break;
        }
        m = sum / len;
        r = (len / weight).min(1.0);
    }
    (m, r)
}

/// The mode-seeking starts of a texel (issue 17: a footprint of one flat panel plus tilted
/// edges is best served by a lobe on the panel's normal, the NDF's mode, not on the mean
/// normal every κ start uses): per kernel `κ = c/α²` of [`MODE_KERNELS`] (α the footprint's
/// base roughness), [`MODE_STEPS`] mean-shift steps ([`mean_shift`]) from the mean normal over
/// the footprint's sampled normals (`footprint_sample`), and at the mode three α: the base
/// α, and the κ formula `α² + 2/κ(r)` for the mode's local spread (`r` the kernel-weighted
/// mean length) and for the footprint's spread about the mode (`r` the mean normal's
/// projection on it). `stats` are the texel's statistics, `samples` its sampled normals. None
/// for four samples or fewer (level 1 of a power-of-two map: the four children's lobes, which
/// are starts already, are the footprint's normals).
pub fn mode_starts(stats: &[f64], samples: &[(DVec3, f64)]) -> Vec<IsoLobe> {
    let m = DVec3::new(stats[0], stats[1], stats[2]);
    let mean = m.try_normalize().unwrap_or(DVec3::Z);
    let alpha = stats[3].max(0.0).sqrt().clamp(MIN_ALPHA, 1.0);
    let widen = |r: f64| Widening::Constant(crate::brdf::GGX_WIDENING_C).apply(alpha, r);
    let mut out = Vec::with_capacity(3 * MODE_KERNELS.len());
    if samples.len() <= 4 {
        return out;
    }
    for c in MODE_KERNELS {
        let (mode, local) = mean_shift(samples, mean, c / (alpha * alpha), MODE_STEPS);
        for a in [alpha, widen(local), widen(m.dot(mode).max(0.0))] {
            out.push(IsoLobe { n: mode, alpha: a });
        }
    }
    out
}

/// Up to 16 of the finest normals texel `(x, y)` of `lf` covers, evenly strided.
fn footprint_normals(map: &NormalMap, lf: &LevelFootprints, x: u32, y: u32) -> Vec<DVec3> {
    let taps = lf.texel(x, y);
    let step = taps.len().div_ceil(16).max(1);
    taps.iter()
        .step_by(step)
        .map(|&(fx, fy, _)| map.normal(fx, fy).as_dvec3())
        .collect()
}

#[allow(clippy::too_many_arguments)] // the bake's inputs, its search, and where it reports
fn bake_fit(
    map: &NormalMap,
    options: &PbrOptions,
    maps: Option<&PbrMaps>,
    set: &FitSet,
    search: Search,
    fit_from: usize,
    progress: &mut Progress,
    timings: &mut PbrTimings,
) -> Result<Bake> {
    check_options(options)?;
    if let Some(m) = maps {
        m.check(map.width(), map.height())?;
    }
    if set.pairs.is_empty()
        || set.pairs.len() > MAX_PAIRS
        || set.weights.len() != set.pairs.len()
        || set.halves.len() != set.pairs.len()
    {
        return Err(Error::InvalidOption(format!(
            "PBR fit: {} light/view pairs with {} weights (expected 1 to {MAX_PAIRS}, one weight each)",
            set.pairs.len(),
            set.weights.len()
        )));
    }
    let (w, _) = (map.width(), map.height());
    let levels = pyramid(map.width(), map.height());
    let mat = material(map, options, maps);
    let alphas: Vec<f64> = mat.iter().map(|m| m[0]).collect();
    progress.report(0.0)?;
    let clock = std::time::Instant::now();
    // Level 0 is the input itself (no fit): its targets are not kept.
    let target = targets_from(map, &alphas, &set.pairs, &levels, 1);
    progress.report(0.3)?;
    let stats = statistics(map, &mat, &levels);
    timings.targets = clock.elapsed().as_secs_f64();
    let p = set.pairs.len();
    let kernel = kernel::IsoKernel::new(set);
    let cancel = progress.cancel_flag();
    let mut iso_levels: Vec<Vec<IsoLobe>> = Vec::new();
    let mut aniso_levels: Vec<Vec<AnisoLobe>> = Vec::new();
    for (k, lf) in levels.iter().enumerate() {
        let (lw, lh) = lf.size;
        let texels = lw as usize * lh as usize;
        let st = &stats[k];
        let search = match search {
            Search::Thorough { from_level } if k < from_level => Search::Fast,
            s => s,
        };
        let (iterations, keep) = match search {
            _ if k < fit_from => (0, 1),
            Search::Fast => (FAST_ITERATIONS, 1),
            Search::Thorough { .. } => (25, 3),
        };
        // The fast search stops a texel's steps once they stop paying; the thorough one runs
        // them all.
        // The anisotropic fit (forward differences, 12× the isotropic one's cost) keeps 4.
        let aniso_iterations = iterations.min(4);
        let converged = if search == Search::Fast {
            FAST_CONVERGED
        } else {
            0.0
        };
        let clock = std::time::Instant::now();
        let iso: Vec<IsoLobe> = if k == 0 {
            map.normals()
                .iter()
                .zip(&alphas)
                .map(|(n, &alpha)| IsoLobe {
                    n: n.as_dvec3(),
                    alpha,
                })
                .collect()
        } else {
            let (pw, ph) = levels[k - 1].size;
            let prev = &iso_levels[k - 1];
            (0..texels)
                .into_par_iter()
                .map(|i| {
                    if i % 4096 == 0 && cancel.check().is_err() {
                        return IsoLobe {
                            n: DVec3::Z,
                            alpha: 1.0,
                        };
                    }
                    let (x, y) = ((i % lw as usize) as u32, (i / lw as usize) as u32);
                    let child = |dx: u32, dy: u32| {
                        let (cx, cy) = ((2 * x + dx).min(pw - 1), (2 * y + dy).min(ph - 1));
                        Some(prev[cy as usize * pw as usize + cx as usize])
                    };
                    // With the mean normal held, every start is about the mean normal: no
                    // children's, own-normal or mode starts.
                    let hold = options.mean_normal;
                    let own = if search != Search::Fast && !hold {
                        footprint_normals(map, lf, x, y)
                    } else {
                        Vec::new()
                    };
                    let s = &st[i * STATS..(i + 1) * STATS];
                    let modes = if iterations > 0 && !hold {
                        let mut sample = [(DVec3::ZERO, 0.0); MODE_TAPS * MODE_TAPS];
                        let count = footprint_sample(map, lf, x, y, &mut sample);
                        mode_starts(s, &sample[..count])
                    } else {
                        Vec::new()
                    };
                    let children = if hold {
                        [None; 4]
                    } else {
                        [child(0, 0), child(1, 0), child(0, 1), child(1, 1)]
                    };
                    // The footprint's base roughness: α′'s floor, and the scale of a basin.
                    let floor = s[3].max(0.0).sqrt();
                    let base = floor.clamp(MIN_ALPHA, 1.0);
                    let mut starts = iso_starts(s, children, search, &own, &modes);
                    if hold && iterations > 0 {
                        // One parameter: its cost can have two basins (a lobe for the
                        // footprint's peak, a wide one for its spread), so the starts also
                        // scan α from the floor to 1.
                        let n = starts[0].n;
                        starts.extend((0..HELD_SCAN).map(|j| IsoLobe {
                            n,
                            alpha: base * (1.0 / base).powf(j as f64 / (HELD_SCAN - 1) as f64),
                        }));
                    }
                    let t = kernel.targets(&target[k][i * p..(i + 1) * p]);
                    if iterations == 0 {
                        starts[0]
                    } else if keep == 1 {
                        let split = starts.len() - modes.len();
                        let apart = 0.5 * base;
                        let fit = |j: usize| {
                            kernel::fit(
                                &kernel,
                                &t,
                                &starts[j..=j],
                                iterations,
                                floor,
                                converged,
                                hold,
                            )
                        };
                        two_basins(&kernel, &t, &starts, split, apart, fit).0
                    } else {
                        // The best `keep` starts, each refined; the best result.
                        let mut ranked: Vec<(f64, IsoLobe)> = starts
                            .iter()
                            .map(|s| (kernel.cost(s.n, s.alpha, &t), *s))
                            .collect();
                        ranked.sort_by(|a, b| a.0.total_cmp(&b.0));
                        ranked
                            .iter()
                            .take(keep)
                            .map(|&(_, s)| {
                                kernel::fit(&kernel, &t, &[s], iterations, floor, converged, hold)
                            })
                            .min_by(|a, b| a.1.total_cmp(&b.1))
                            .map(|r| r.0)
                            .unwrap_or(starts[0])
                    }
                })
                .collect()
        };
        cancel.check()?;
        timings.fit.push(clock.elapsed().as_secs_f64());
        let clock = std::time::Instant::now();
        if options.anisotropic {
            let aniso: Vec<AnisoLobe> = if k == 0 {
                iso.iter()
                    .map(|l| AnisoLobe {
                        n: l.n,
                        phi: 0.0,
                        alpha_t: l.alpha,
                        alpha_b: l.alpha,
                    })
                    .collect()
            } else {
                (0..texels)
                    .into_par_iter()
                    .map(|i| {
                        let lobe = iso[i];
                        let from_iso = AnisoLobe {
                            n: lobe.n,
                            phi: 0.0,
                            alpha_t: lobe.alpha,
                            alpha_b: lobe.alpha,
                        };
                        if k < fit_from || (i % 4096 == 0 && cancel.check().is_err()) {
                            return from_iso;
                        }
                        let s = &st[i * STATS..(i + 1) * STATS];
                        let cov = covariance_start(s, lobe.n);
                        let t = &target[k][i * p..(i + 1) * p];
                        let floor = s[3].max(0.0).sqrt();
                        fit_anisotropic_held(
                            set,
                            t,
                            &aniso_starts(lobe, cov),
                            aniso_iterations,
                            floor,
                            options.mean_normal,
                        )
                        .0
                    })
                    .collect()
            };
            cancel.check()?;
            timings.anisotropic.push(clock.elapsed().as_secs_f64());
            aniso_levels.push(aniso);
        }
        iso_levels.push(iso);
        progress.report(0.3 + 0.7 * (k + 1) as f64 / levels.len() as f64)?;
    }
    let _ = w;
    Ok(assemble(
        map,
        options,
        &levels,
        &stats,
        |k, i| {
            if options.anisotropic {
                let a = aniso_levels[k][i];
                (a.n, a.alpha_b, Some((a.phi, a.alpha_t)))
            } else {
                let l = iso_levels[k][i];
                (l.n, l.alpha, None)
            }
        },
        serde_json::json!({
            "roughness": if maps.and_then(|m| m.roughness.as_ref()).is_some() {
                serde_json::Value::from("map")
            } else {
                serde_json::Value::from(options.roughness)
            },
            "anisotropic": options.anisotropic,
            "fit": match search {
                _ if options.mean_normal => {
                    "levenberg-marquardt over α alone at the mean normal, up to 8 steps from the best of 5 formula starts and 16 α values from the floor to 1"
                }
                Search::Fast => {
                    "levenberg-marquardt, up to 8 steps from the best of 15 starts (9 + 6 mode starts) and from the best mode start"
                }
                Search::Thorough { .. } => {
                    "levenberg-marquardt, 25 steps from the best 3 of many starts"
                }
            },
            "fit_pairs": set.pairs.len(),
            "fit_max_angle": options.fit_max_angle,
            "normal": if options.mean_normal { "mean" } else { "fitted" },
        }),
    ))
}

/// Checks a PBR bake's options: the roughness must be finite and in [0, 1], the fit's widest
/// angle ([`PbrOptions::fit_max_angle`]) in [[`MIN_FIT_ANGLE`], 90]°.
pub fn check_options(options: &PbrOptions) -> Result<()> {
    if !(0.0..=1.0).contains(&options.roughness) {
        return Err(Error::InvalidOption(format!(
            "roughness {} (expected a perceptual roughness in [0, 1])",
            crate::error::compact_f64(options.roughness)
        )));
    }
    fit_set(options).map(|_| ())
}

/// The smallest [`PbrOptions::fit_max_angle`], degrees: a sanity bound (the standard design
/// scaled to 20° puts its views between 3° and 18° of the normal).
pub const MIN_FIT_ANGLE: f64 = 20.0;

/// The pairs the bake fits for `options`: [`FitSet::standard`], or [`FitSet::view_range`] of
/// [`PbrOptions::fit_max_angle`] (an error naming the option when it is not a number in
/// [[`MIN_FIT_ANGLE`], 90]°).
pub fn fit_set(options: &PbrOptions) -> Result<FitSet> {
    let Some(deg) = options.fit_max_angle else {
        return Ok(FitSet::standard());
    };
    FitSet::view_range(deg).ok_or_else(|| {
        Error::InvalidOption(format!(
            "fit max angle {}° (expected the widest view and light angle the renderer \
                 shows, {MIN_FIT_ANGLE}° to 90°)",
            crate::error::compact_f64(deg)
        ))
    })
}

/// Builds the bake's textures from a per-texel lobe `lobe(level, texel)`: normal, α_b, and for
/// anisotropic lobes `(φ, α_t)`.
fn assemble(
    map: &NormalMap,
    options: &PbrOptions,
    levels: &[LevelFootprints],
    stats: &[Vec<f64>],
    lobe: impl Fn(usize, usize) -> (DVec3, f64, Option<(f64, f64)>) + Sync,
    parameters: serde_json::Value,
) -> Bake {
    let mut textures: Vec<Texture> = layout(options.anisotropic)
        .into_iter()
        .map(|(name, channels, ranges)| Texture {
            name,
            channels,
            ranges,
            levels: Vec::new(),
        })
        .collect();
    for (k, lf) in levels.iter().enumerate() {
        let texels = lf.size.0 as usize * lf.size.1 as usize;
        let st = &stats[k];
        let rows: Vec<[[f32; 4]; 3]> = (0..texels)
            .into_par_iter()
            .map(|i| {
                let (n, ab, aniso) = lobe(k, i);
                let s = &st[i * STATS..(i + 1) * STATS];
                let normal = [n.x as f32, n.y as f32, n.z as f32, 0.0];
                let mr = [s[5] as f32, ab.sqrt() as f32, s[4] as f32, 0.0];
                let an = match aniso {
                    Some((phi, at)) => {
                        let strength = if ab < 1.0 {
                            ((at - ab) / (1.0 - ab)).clamp(0.0, 1.0).sqrt()
                        } else {
                            0.0
                        };
                        [phi.cos() as f32, phi.sin() as f32, strength as f32, 0.0]
                    }
                    None => [1.0, 0.0, 0.0, 0.0],
                };
                [normal, mr, an]
            })
            .collect();
        for (ti, t) in textures.iter_mut().enumerate() {
            t.levels.push(rows.iter().map(|r| r[ti]).collect());
        }
    }
    Bake {
        method: Method::Pbr,
        sizes: levels.iter().map(|l| l.size).collect(),
        textures,
        addressing: map.addressing(),
        lobes: 0,
        parameters,
        format: Format::F32,
    }
}

/// A PBR bake whose normal is the normalized mean (plain mip) and whose roughness comes from a
/// κ formula (`widening`) at every level ≥ 1: the engines' heuristics, for the report's rows.
/// Level 0 is the input.
pub fn bake_formula(
    map: &NormalMap,
    options: &PbrOptions,
    maps: Option<&PbrMaps>,
    widening: Widening,
) -> Result<Bake> {
    check_options(options)?;
    if let Some(m) = maps {
        m.check(map.width(), map.height())?;
    }
    let levels = pyramid(map.width(), map.height());
    let mat = material(map, options, maps);
    let stats = statistics(map, &mat, &levels);
    let plain = PbrOptions {
        anisotropic: false,
        ..*options
    };
    Ok(assemble(
        map,
        &plain,
        &levels,
        &stats,
        |k, i| {
            let s = &stats[k][i * STATS..(i + 1) * STATS];
            let m = DVec3::new(s[0], s[1], s[2]);
            let alpha = s[3].max(0.0).sqrt().clamp(MIN_ALPHA, 1.0);
            let n = m.try_normalize().unwrap_or(DVec3::Z);
            if k == 0 {
                (n, alpha, None)
            } else {
                (n, widening.apply(alpha, m.length()), None)
            }
        },
        serde_json::json!({ "widening": format!("{widening:?}") }),
    ))
}

/// A PBR bake whose normal is the normalized mean and whose perceptual roughness per level is
/// given (`roughness[k]`, row-major, each the level's size): another tool's roughness MIP
/// chain (Filament's `roughness-prefilter`) shaded beside ndfmap's. Fails with
/// [`Error::InvalidOption`] when the level count or a level's size differs.
pub fn bake_with_roughness(map: &NormalMap, roughness: &[Vec<f32>]) -> Result<Bake> {
    let levels = pyramid(map.width(), map.height());
    if roughness.len() != levels.len()
        || roughness
            .iter()
            .zip(&levels)
            .any(|(r, lf)| r.len() != lf.size.0 as usize * lf.size.1 as usize)
    {
        return Err(Error::InvalidOption(format!(
            "roughness MIP chain of {} levels for a map with {} levels (or a level of another size)",
            roughness.len(),
            levels.len()
        )));
    }
    let options = PbrOptions::default();
    let mat = material(map, &options, None);
    let stats = statistics(map, &mat, &levels);
    Ok(assemble(
        map,
        &options,
        &levels,
        &stats,
        |k, i| {
            let s = &stats[k][i * STATS..(i + 1) * STATS];
            let n = DVec3::new(s[0], s[1], s[2])
                .try_normalize()
                .unwrap_or(DVec3::Z);
            (n, base_alpha(roughness[k][i] as f64), None)
        },
        serde_json::json!({ "roughness": "given per level" }),
    ))
}

/// Texture names, channel meanings and value ranges of a PBR bake (module docs).
pub fn layout(anisotropic: bool) -> Vec<(&'static str, [&'static str; 4], [ValueRange; 4])> {
    use ValueRange::{Signed as S, Unit as U};
    let mut out = vec![
        ("normal", ["n_x", "n_y", "n_z", "unused"], [S, S, S, U]),
        (
            "metallic_roughness",
            ["occlusion", "roughness", "metallic", "unused"],
            [U; 4],
        ),
    ];
    if anisotropic {
        out.push((
            "anisotropy",
            ["direction_x", "direction_y", "strength", "unused"],
            [S, S, U, U],
        ));
    }
    out
}

/// The CPU twin of a plain GGX shader reading a PBR bake's texel (`texels` in [`layout`]
/// order): `n = normalize(normal)`, `α = max(roughness², MIN_ALPHA)`, and with an anisotropy
/// texture `α_t = mix(α, 1, strength²)` along `(direction, 0)` made orthogonal to `n`
/// (`KHR_materials_anisotropy`); diffuse `max(n·l, 0)`, specular `D(h) max(n·l, 0)` under GGX
/// (the bake's own roughness: the BRDF's α is what it was baked for), without the g factor.
/// Under another BRDF the specular term is that BRDF's unfiltered lobe about `n` (plain mip).
pub fn shade(texels: &[[f32; 4]], l: DVec3, h: DVec3, brdf: &Brdf) -> Shading {
    let t = texels[0];
    let n = DVec3::new(t[0] as f64, t[1] as f64, t[2] as f64)
        .try_normalize()
        .unwrap_or(DVec3::Z);
    let cos_i = n.dot(l).max(0.0);
    let specular = match brdf {
        Brdf::Ggx(_) => {
            let alpha = (texels[1][1] as f64).powi(2).clamp(MIN_ALPHA, 1.0);
            let lobe = match texels.get(2) {
                Some(a) if a[2] > 0.0 => {
                    let s = (a[2] as f64).clamp(0.0, 1.0);
                    let at = alpha + (1.0 - alpha) * s * s;
                    let phi = (a[1] as f64).atan2(a[0] as f64);
                    let (tt, bb) = aniso_frame(n, phi);
                    ggx_tb(h, n, tt, bb, at, alpha)
                }
                _ => ggx(n.dot(h), alpha),
            };
            lobe * cos_i
        }
        Brdf::Lambert => 0.0,
        Brdf::BlinnPhong { s } => return crate::brdf::reference(n, l, h, *s),
        b => b.lobe(n.dot(h)) * cos_i,
    };
    Shading {
        diffuse: cos_i,
        specular,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bumpy(w: u32, h: u32) -> NormalMap {
        crate::baseline::tests::test_map(w, h)
    }

    fn run(map: &NormalMap, options: &PbrOptions, maps: Option<&PbrMaps>) -> Result<Bake> {
        crate::bake::run_with_progress(&mut |_| true, |p| bake(map, options, maps, p))
    }

    fn iso_as_aniso(l: IsoLobe) -> AnisoLobe {
        AnisoLobe {
            n: l.n,
            phi: 0.0,
            alpha_t: l.alpha,
            alpha_b: l.alpha,
        }
    }

    #[test]
    fn kappa_formula_and_widenings() {
        assert!((kappa(0.5) - (1.5 - 0.125) / 0.75).abs() < 1e-12);
        assert!(kappa(1.0).is_finite());
        let r = 0.9;
        let k = kappa(r);
        let a = Widening::Constant(2.0).apply(0.1, r);
        assert!((a * a - (0.01 + 2.0 / k)).abs() < 1e-12);
        let f = Widening::Filament.apply(0.1, r);
        assert!((f - (0.1 + (0.5 / k).min(0.04))).abs() < 1e-12);
    }

    #[test]
    fn anisotropic_ggx_is_ggx_when_round_and_is_normalized() {
        let n = DVec3::new(0.2, -0.1, 1.0).normalize();
        let (t, b) = aniso_frame(n, 0.7);
        for c in [0.99, 0.9, 0.5] {
            let h = (n * c + t * (1.0 - c * c).sqrt() * 0.6 + b * (1.0 - c * c).sqrt() * 0.8)
                .normalize();
            let a = ggx_tb(h, n, t, b, 0.2, 0.2);
            let g = ggx(n.dot(h), 0.2);
            assert!((a - g).abs() <= 1e-12 * g, "{a} {g}");
        }
        // ∫ D (h·n) dω = 1 for an anisotropic lobe about +Z, by the midpoint rule.
        let (at, ab) = (0.3, 0.1);
        let (t, b) = aniso_frame(DVec3::Z, 0.4);
        let (nt, np) = (2000, 400);
        let mut sum = 0.0;
        for i in 0..nt {
            let th = (i as f64 + 0.5) / nt as f64 * 0.5 * PI;
            for j in 0..np {
                let ph = (j as f64 + 0.5) / np as f64 * 2.0 * PI;
                let h = DVec3::new(th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos());
                sum += ggx_tb(h, DVec3::Z, t, b, at, ab) * th.cos() * th.sin();
            }
        }
        sum *= (0.5 * PI / nt as f64) * (2.0 * PI / np as f64);
        assert!((sum - 1.0).abs() < 2e-3, "{sum}");
    }

    #[test]
    fn targets_are_brute_force_footprint_averages() {
        let map = bumpy(6, 5);
        let levels = pyramid(6, 5);
        let alphas: Vec<f64> = (0..30).map(|i| 0.05 + 0.01 * i as f64).collect();
        let pairs = standard_pairs();
        let t = targets(&map, &alphas, &pairs, &levels);
        for (k, lf) in levels.iter().enumerate() {
            for (x, y) in [(0, 0), (lf.size.0 - 1, lf.size.1 - 1)] {
                let i = y as usize * lf.size.0 as usize + x as usize;
                for (p, &(l, v)) in pairs.iter().enumerate() {
                    let h = half_vector(l, v);
                    let want: f64 = lf
                        .texel(x, y)
                        .iter()
                        .map(|&(fx, fy, w)| {
                            let j = (fy * 6 + fx) as usize;
                            w * iso_value(map.normal(fx, fy).as_dvec3(), alphas[j], l, h)
                        })
                        .sum();
                    let got = t[k][i * pairs.len() + p];
                    assert!((got - want).abs() <= 1e-12 * (1.0 + want), "{got} {want}");
                }
            }
        }
    }

    /// The bake's pairs are unit vectors above the horizon, at most [`MAX_PAIRS`], reach
    /// grazing angles (views and lights beyond 65°, half vectors beyond 35°) and hold none of
    /// the evaluation's pairs (held out); [`FitSet::view_range`] keeps exactly those within
    /// its range; [`FitSet::near_peak`]'s half vectors stay within 28°.
    #[test]
    fn fit_sets_cover_grazing_pairs_and_hold_out_the_evaluations() {
        let set = FitSet::standard();
        assert_eq!(set.pairs.len(), 112);
        assert!(set.pairs.len() <= MAX_PAIRS && set.weights.iter().all(|&w| w == 1.0));
        let deg = |d: DVec3| d.z.clamp(-1.0, 1.0).acos().to_degrees();
        for &(l, v) in &set.pairs {
            assert!((l.length() - 1.0).abs() < 1e-12 && (v.length() - 1.0).abs() < 1e-12);
            assert!(deg(l) <= 74.0 + 1e-9 && deg(v) <= 68.0 + 1e-9);
        }
        assert!(set.pairs.iter().any(|&(l, _)| deg(l) > 65.0));
        assert!(set.pairs.iter().any(|&(_, v)| deg(v) > 65.0));
        assert!(set.halves.iter().any(|&h| deg(h) > 35.0));
        // Fourteen mirror pairs (half vector at the zenith), seven per copy of the design.
        assert_eq!(set.halves.iter().filter(|h| deg(**h) < 1e-6).count(), 14);
        // The second copy is the first turned by 187°: same polar angles, and no azimuth of
        // either copy repeats one of the other's (all of the first's are multiples of 5°).
        let (first, second) = set.pairs.split_at(56);
        let azimuth = |d: DVec3| d.y.atan2(d.x).to_degrees().rem_euclid(360.0);
        for (&(l, v), &(tl, tv)) in first.iter().zip(second) {
            assert!((deg(l) - deg(tl)).abs() < 1e-9 && (deg(v) - deg(tv)).abs() < 1e-9);
            for (a, b) in [(l, tl), (v, tv)] {
                if deg(a) > 1e-6 {
                    let turned = (azimuth(b) - azimuth(a)).rem_euclid(360.0);
                    assert!((turned - SECOND_COPY_TURN).abs() < 1e-9, "{turned}");
                    assert!((azimuth(a) / 5.0 - (azimuth(a) / 5.0).round()).abs() < 1e-9);
                }
            }
        }
        for &(el, ev) in &crate::eval::default_directions() {
            for &(l, v) in &set.pairs {
                assert!(
                    l.angle_between(el) + v.angle_between(ev) > 5f64.to_radians(),
                    "{l} {v} is an evaluation pair"
                );
            }
        }
        // A view range: the same design scaled into it (112 pairs, the widest at the range,
        // the mirror pairs kept), the standard set from 74° on; the bake's option picks it.
        let narrow = FitSet::view_range(45.0).unwrap();
        assert_eq!(narrow.pairs.len(), 112);
        let widest = |s: &FitSet| {
            s.pairs
                .iter()
                .map(|&(l, v)| deg(l).max(deg(v)))
                .fold(0.0, f64::max)
        };
        assert!((widest(&narrow) - 45.0).abs() < 1e-9, "{}", widest(&narrow));
        assert_eq!(narrow.halves.iter().filter(|h| deg(**h) < 1e-6).count(), 14);
        for (&(l, v), &(sl, sv)) in narrow.pairs.iter().zip(&set.pairs) {
            assert!((deg(l) - deg(sl) * 45.0 / 74.0).abs() < 1e-9);
            assert!((deg(v) - deg(sv) * 45.0 / 74.0).abs() < 1e-9);
        }
        assert_eq!(FitSet::view_range(74.0).unwrap(), set);
        assert_eq!(FitSet::view_range(90.0).unwrap(), set);
        let with = |a: Option<f64>| {
            fit_set(&PbrOptions {
                fit_max_angle: a,
                ..PbrOptions::default()
            })
        };
        assert_eq!(with(None).unwrap(), set);
        assert_eq!(with(Some(45.0)).unwrap(), narrow);
        assert!(with(Some(MIN_FIT_ANGLE)).is_ok());
        for bad in [MIN_FIT_ANGLE - 0.5, 90.5, f64::NAN, f64::INFINITY] {
            assert!(FitSet::view_range(bad).is_none());
            let e = with(Some(bad)).unwrap_err().to_string();
            assert!(e.contains("fit max angle"), "{e}");
        }
        let near = FitSet::near_peak(0.1);
        assert_eq!(near.pairs.len(), 39);
        assert!(near.halves.iter().all(|&h| deg(h) <= 28.0 + 1e-9));
        let mean = near.weights.iter().sum::<f64>() / 39.0;
        assert!((mean - 1.0).abs() < 1e-12);
    }

    #[test]
    fn the_fit_recovers_a_single_lobe_and_beats_its_starts() {
        // A target made by one known lobe is recovered from a poor start.
        let set = FitSet::standard();
        let truth = IsoLobe {
            n: DVec3::new(0.15, -0.1, 1.0).normalize(),
            alpha: 0.17,
        };
        let target: Vec<f64> = set
            .pairs
            .iter()
            .map(|&(l, v)| iso_value(truth.n, truth.alpha, l, half_vector(l, v)))
            .collect();
        let start = IsoLobe {
            n: DVec3::new(0.1, -0.05, 1.0).normalize(),
            alpha: 0.25,
        };
        let (fit, c) = fit_isotropic(&set, &target, &[start], 30, MIN_ALPHA);
        assert!(fit.n.angle_between(truth.n) < 1e-4, "{fit:?}");
        assert!((fit.alpha - truth.alpha).abs() < 1e-4, "{fit:?}");
        assert!(c < 1e-8);
        // The anisotropic fit recovers an anisotropic lobe.
        let truth = AnisoLobe {
            n: DVec3::new(0.05, 0.1, 1.0).normalize(),
            phi: 0.6,
            alpha_t: 0.3,
            alpha_b: 0.12,
        };
        let target: Vec<f64> = set
            .pairs
            .iter()
            .map(|&(l, v)| {
                let frame = aniso_frame(truth.n, truth.phi);
                aniso_value_in(&truth, frame, l, half_vector(l, v))
            })
            .collect();
        let iso = IsoLobe {
            n: DVec3::Z,
            alpha: 0.2,
        };
        let starts = aniso_starts(iso, aniso_starts(iso, iso_as_aniso(iso))[1]);
        let (fit, _) = fit_anisotropic(&set, &target, &starts, 60, MIN_ALPHA);
        assert!(fit.n.angle_between(truth.n) < 1e-3, "{fit:?}");
        assert!((fit.alpha_t - 0.3).abs() < 1e-3 && (fit.alpha_b - 0.12).abs() < 1e-3);
        assert!((fit.phi - 0.6).abs() < 1e-2, "{fit:?}");
    }

    /// A footprint of one flat panel (3/4 of its normals, jittered by ±0.6°) plus two tilted
    /// edges (1/8 each, 30° off the panel towards +x and +y), issue 17's facade case: the
    /// mean normal is pulled ≈ 6° off the panel. The mode-seeking starts ([`mode_starts`])
    /// find the panel's normal, and the fit from them reaches the optimum a brute-force search
    /// over a grid of (normal, α) finds (polished by the same fit), where the fit from the
    /// mean-normal starts alone (κ formula and base α) stays clearly worse.
    #[test]
    fn mode_starts_find_the_panel_that_the_mean_normal_starts_miss() {
        let set = FitSet::standard();
        let panel = DVec3::new(0.1, -0.05, 1.0).normalize();
        let (t1, t2) = tangent_frame(panel);
        let tilt = |d: DVec3, deg: f64| {
            let a = deg.to_radians();
            (panel * a.cos() + d * a.sin()).normalize()
        };
        let mut normals = Vec::new();
        for i in 0..64 {
            let n = match i % 8 {
                0 => tilt(t1, 30.0),
                4 => tilt(t2, 30.0),
                _ => {
                    // Deterministic jitter within ±0.6°.
                    let j = |k: u64| ((k * 2_654_435_761 % 1000) as f64 / 1000.0 - 0.5) * 0.021;
                    (panel + j(i) * t1 + j(i + 77) * t2).normalize()
                }
            };
            normals.push((n, 1.0 / 64.0));
        }
        for alpha in [0.05, 0.1] {
            let target: Vec<f64> = set
                .pairs
                .iter()
                .map(|&(l, v)| {
                    let h = half_vector(l, v);
                    normals
                        .iter()
                        .map(|&(n, w)| w * iso_value(n, alpha, l, h))
                        .sum()
                })
                .collect();
            let mean: DVec3 = normals.iter().map(|&(n, w)| w * n).sum();
            let mut stats = [0.0; STATS];
            stats[..3].copy_from_slice(&mean.to_array());
            stats[3] = alpha * alpha;
            let r = mean.length();
            let mn = mean.normalize();
            assert!(mn.angle_between(panel).to_degrees() > 5.0);
            // The mean-normal starts of the fast fit: κ formula c = 2, 0.5, 1, 4 and base α.
            let mean_starts: Vec<IsoLobe> = [2.0, 0.5, 1.0, 4.0]
                .iter()
                .map(|&c| IsoLobe {
                    n: mn,
                    alpha: Widening::Constant(c).apply(alpha, r),
                })
                .chain([IsoLobe { n: mn, alpha }])
                .collect();
            let modes = mode_starts(&stats, &normals);
            assert_eq!(modes.len(), 3 * MODE_KERNELS.len());
            assert!(
                modes[0].n.angle_between(panel).to_degrees() < 0.5,
                "mode {:.2}° off the panel",
                modes[0].n.angle_between(panel).to_degrees()
            );
            // The fast search's rule (two_basins) on the mean-normal starts alone and with the
            // mode starts.
            let k = kernel::IsoKernel::new(&set);
            let t = k.targets(&target);
            let fast = |starts: &[IsoLobe], split: usize| {
                let fit = |j: usize| {
                    kernel::fit(
                        &k,
                        &t,
                        &starts[j..=j],
                        FAST_ITERATIONS,
                        alpha,
                        FAST_CONVERGED,
                        false,
                    )
                };
                two_basins(&k, &t, starts, split, 0.5 * alpha, fit)
            };
            let (_, from_mean) = fast(&mean_starts, mean_starts.len());
            let all: Vec<IsoLobe> = mean_starts.iter().chain(&modes).copied().collect();
            let (with_modes, from_modes) = fast(&all, mean_starts.len());
            // Brute force: normals n = normalize(panel + u t1 + v t2), |u|, |v| ≤ 0.6 in steps
            // of 0.02, α from the base to 1 in 24 geometric steps; the best polished by the fit.
            let plain = |n: DVec3, a: f64| cost(&set, &target, |l, h| iso_value(n, a, l, h));
            let mut best = (f64::INFINITY, IsoLobe { n: panel, alpha });
            for iu in -30..=30 {
                for iv in -30..=30 {
                    let n = (panel + 0.02 * iu as f64 * t1 + 0.02 * iv as f64 * t2).normalize();
                    for ia in 0..24 {
                        let a = alpha * (1.0 / alpha).powf(ia as f64 / 23.0);
                        let c = plain(n, a);
                        if c < best.0 {
                            best = (c, IsoLobe { n, alpha: a });
                        }
                    }
                }
            }
            let (brute_lobe, brute) = fit_isotropic(&set, &target, &[best.1], 25, alpha);
            eprintln!(
                "α {alpha}: mean starts {from_mean:e}, with modes {from_modes:e} {with_modes:?} ({:.2}° off the panel), brute force {brute:e} {brute_lobe:?} ({:.2}°)",
                with_modes.n.angle_between(panel).to_degrees(),
                brute_lobe.n.angle_between(panel).to_degrees()
            );
            assert!(brute <= best.0);
            assert!(
                from_modes <= brute * 1.02 || alpha > 0.05,
                "α {alpha}: with the mode starts {from_modes:e}, brute force {brute:e}"
            );
            // At α = 0.05 the mean-normal starts stay in a basin 1.7× worse (4.6× with one
            // copy of the design, 56 pairs); at α = 0.1 they reach the optimum too (a wider
            // lobe on the panel), and the mode starts must not lose it.
            if alpha == 0.05 {
                assert!(
                    from_mean >= 1.5 * from_modes,
                    "α {alpha}: mean-normal starts {from_mean:e}, with the mode starts {from_modes:e}"
                );
            }
            assert!(with_modes.n.angle_between(panel).to_degrees() < 2.0);
            assert!((plain(with_modes.n, with_modes.alpha) - from_modes).abs() <= 1e-9 * brute);
        }
    }

    /// Mean shift with a narrow kernel climbs from the mean to the densest cluster and reports
    /// its local spread; the footprint sample of a power-of-two map reads every normal up to
    /// 8 × 8 and strides above.
    #[test]
    fn mean_shift_climbs_to_the_densest_cluster_and_the_sample_strides() {
        let a = DVec3::new(0.0, 0.0, 1.0);
        let b = DVec3::new(0.5, 0.0, 1.0).normalize();
        let samples = [(a, 0.3), (a, 0.3), (b, 0.4)];
        let mean: DVec3 = samples.iter().map(|&(n, w)| w * n).sum();
        // Kernel 200: the weights of a and b differ by exp(200 (cos 26.6° − 1)) ≈ 1e-9.
        let (m, r) = mean_shift(&samples, mean.normalize(), 200.0, 3);
        assert!(m.angle_between(a) < 1e-6, "{m}");
        assert!((r - 1.0).abs() < 1e-6);
        // A wide kernel stays near the mean, and the spread there is the mean length.
        let (m, r) = mean_shift(&samples, mean.normalize(), 1e-9, 1);
        assert!(m.angle_between(mean.normalize()) < 1e-6);
        assert!((r - mean.length()).abs() < 1e-6);
        let map = bumpy(32, 32);
        let levels = pyramid(32, 32);
        let mut out = [(DVec3::ZERO, 0.0); MODE_TAPS * MODE_TAPS];
        for (k, count) in [(1, 4), (2, 16), (3, 64), (4, 64), (5, 64)] {
            assert_eq!(footprint_sample(&map, &levels[k], 0, 0, &mut out), count);
        }
        // Level 4 (16 × 16 footprints): every second finest texel; texel (1, 1) of the level
        // covers finest 16..32, sampled at 16, 18, …, 30. Level 5 (32 × 32): every fourth from
        // the second, 1, 5, …, 29.
        footprint_sample(&map, &levels[4], 1, 1, &mut out);
        assert_eq!(out[0].0, map.normal(16, 16).as_dvec3());
        assert_eq!(out[63].0, map.normal(30, 30).as_dvec3());
        footprint_sample(&map, &levels[5], 0, 0, &mut out);
        assert_eq!(out[9].0, map.normal(5, 5).as_dvec3());
        assert_eq!(out[63].0, map.normal(29, 29).as_dvec3());
        // Fewer than five samples: no mode starts (the children are the footprint's normals).
        let stats = [0.0, 0.0, 1.0, 0.01, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
        assert!(mode_starts(&stats, &samples).is_empty());
    }

    #[test]
    fn the_bake_fits_better_than_the_kappa_formula_on_its_pairs() {
        let map = bumpy(16, 16);
        let options = PbrOptions {
            roughness: 0.3,
            ..PbrOptions::default()
        };
        let fitted = run(&map, &options, None).unwrap();
        let formula = bake_formula(&map, &options, None, Widening::Constant(2.0)).unwrap();
        let set = FitSet::standard();
        let levels = pyramid(16, 16);
        let alphas = vec![base_alpha(0.3); 256];
        let t = targets(&map, &alphas, &set.pairs, &levels);
        let brdf = Brdf::ggx(0.09);
        for k in 1..levels.len() {
            let err = |b: &Bake| -> f64 {
                let texels = (levels[k].size.0 * levels[k].size.1) as usize;
                (0..texels)
                    .map(|i| {
                        let tx: Vec<[f32; 4]> = b.textures.iter().map(|t| t.levels[k][i]).collect();
                        cost(&set, &t[k][i * set.pairs.len()..], |l, h| {
                            shade(&tx, l, h, &brdf).specular
                        })
                    })
                    .sum()
            };
            assert!(err(&fitted) <= err(&formula) * 1.0001, "level {k}");
        }
        // Level 0 is the input: the normal and the roughness as given.
        let t0 = fitted.texel(0, 3, 2);
        let n = map.normal(3, 2);
        assert!((t0[0][0] - n.x).abs() < 1e-6 && (t0[1][1] - 0.3).abs() < 1e-6);
    }

    /// `mean_normal`: every level's normal is the plain MIP chain's (the normalized footprint
    /// mean), and the fitted roughness is, texel by texel, within 0.5 % of the lowest cost a
    /// brute-force scan of α finds at that normal (401 values, log-spaced from the floor to 1).
    /// Anisotropic, the normal is held as well and the cost is no higher than the isotropic
    /// lobe's.
    #[test]
    fn the_mean_normal_bake_keeps_plain_mips_normal_and_fits_the_roughness() {
        let map = bumpy(16, 16);
        let options = PbrOptions {
            roughness: 0.3,
            mean_normal: true,
            ..PbrOptions::default()
        };
        let held = run(&map, &options, None).unwrap();
        assert_eq!(held.parameters["normal"], "mean");
        let plain =
            crate::methods::bake_with(&map, crate::bake::Method::Plain, &Default::default())
                .unwrap();
        let aniso = run(
            &map,
            &PbrOptions {
                anisotropic: true,
                ..options
            },
            None,
        )
        .unwrap();
        let set = FitSet::standard();
        let levels = pyramid(16, 16);
        let alphas = vec![base_alpha(0.3); 256];
        let t = targets(&map, &alphas, &set.pairs, &levels);
        let p = set.pairs.len();
        let brdf = Brdf::ggx(0.09);
        let normal = |b: &Bake, k: usize, i: usize| {
            let v = b.textures[0].levels[k][i];
            DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64).normalize()
        };
        for k in 1..levels.len() {
            let texels = (levels[k].size.0 * levels[k].size.1) as usize;
            for i in 0..texels {
                let n = normal(&held, k, i);
                let angle = n.angle_between(normal(&plain, k, i));
                assert!(
                    angle < 1e-5,
                    "level {k} texel {i}: {angle} rad from plain mip"
                );
                assert!(
                    normal(&aniso, k, i).angle_between(n) < 1e-5,
                    "aniso {k} {i}"
                );
                let target = &t[k][i * p..(i + 1) * p];
                let tx: Vec<[f32; 4]> = held.textures.iter().map(|t| t.levels[k][i]).collect();
                let fitted = cost(&set, target, |l, h| shade(&tx, l, h, &brdf).specular);
                let floor = 0.09f64;
                let scan = (0..=400)
                    .map(|j| {
                        let a = floor * (1.0 / floor).powf(j as f64 / 400.0);
                        cost(&set, target, |l, h| iso_value(n, a, l, h))
                    })
                    .fold(f64::INFINITY, f64::min);
                assert!(
                    fitted <= scan * 1.005 + 1e-12,
                    "level {k} texel {i}: {fitted} > {scan}"
                );
                let tx: Vec<[f32; 4]> = aniso.textures.iter().map(|t| t.levels[k][i]).collect();
                let a = cost(&set, target, |l, h| shade(&tx, l, h, &brdf).specular);
                assert!(
                    a <= fitted * 1.001 + 1e-12,
                    "aniso level {k} texel {i}: {a} > {fitted}"
                );
            }
        }
    }

    #[test]
    fn the_bake_is_the_same_whatever_the_thread_count() {
        let map = bumpy(16, 8);
        for mean_normal in [false, true] {
            let options = PbrOptions {
                roughness: 0.4,
                anisotropic: true,
                mean_normal,
                ..PbrOptions::default()
            };
            let a = run(&map, &options, None).unwrap();
            let b = rayon::ThreadPoolBuilder::new()
                .num_threads(1)
                .build()
                .unwrap()
                .install(|| {
                    // From a pool thread the bake runs on it (bake::run_with_progress).
                    run(&map, &options, None).unwrap()
                });
            assert_eq!(a, b, "mean normal {mean_normal}");
        }
    }

    #[test]
    fn bad_maps_are_refused() {
        let map = bumpy(4, 4);
        let o = PbrOptions::default();
        let with = |m: PbrMaps| run(&map, &o, Some(&m)).unwrap_err();
        let e = with(PbrMaps {
            roughness: Some(vec![0.5; 12]),
            ..PbrMaps::default()
        });
        assert!(matches!(e, Error::FeatureSize { .. }), "{e}");
        let mut v = vec![0.5; 16];
        v[5] = f32::NAN;
        let e = with(PbrMaps {
            roughness: Some(v),
            ..PbrMaps::default()
        });
        assert!(
            matches!(
                e,
                Error::BadFeatures {
                    kind: "NaN",
                    x: 1,
                    y: 1,
                    ..
                }
            ),
            "{e}"
        );
        let mut v = vec![0.5; 16];
        v[2] = 1.5;
        v[9] = -0.1;
        let e = with(PbrMaps {
            metallic: Some(v),
            ..PbrMaps::default()
        });
        assert!(
            matches!(
                e,
                Error::BadFeatures {
                    count: 2,
                    kind: "outside [0, 1]",
                    x: 2,
                    y: 0,
                    ..
                }
            ),
            "{e}"
        );
        let e = run(
            &map,
            &PbrOptions {
                roughness: 1.2,
                ..PbrOptions::default()
            },
            None,
        )
        .unwrap_err();
        assert!(matches!(e, Error::InvalidOption(_)), "{e}");
    }

    #[test]
    fn metallic_and_occlusion_are_box_filtered_into_the_packed_texture() {
        let map = bumpy(4, 4);
        let metallic: Vec<f32> = (0..16).map(|i| i as f32 / 15.0).collect();
        let occlusion: Vec<f32> = (0..16).map(|i| 1.0 - i as f32 / 30.0).collect();
        let b = run(
            &map,
            &PbrOptions::default(),
            Some(&PbrMaps {
                roughness: None,
                metallic: Some(metallic.clone()),
                occlusion: Some(occlusion.clone()),
            }),
        )
        .unwrap();
        // Level 1 texel (1, 0) covers finest (2..4, 0..2).
        let idx = [2, 3, 6, 7];
        let m: f32 = idx.iter().map(|&i| metallic[i]).sum::<f32>() / 4.0;
        let o: f32 = idx.iter().map(|&i| occlusion[i]).sum::<f32>() / 4.0;
        let t = b.texel(1, 1, 0)[1];
        assert!((t[2] - m).abs() < 1e-6 && (t[0] - o).abs() < 1e-6, "{t:?}");
    }
}
