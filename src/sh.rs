//! The spherical-harmonic NDF (Han et al. 2007, Sec 5, eqs 11–12): no fitting at all. At the
//! finest level a texel's NDF is the delta at its normal, with coefficients `γ_lm = Y_lm(n)`
//! (Sec 5.1, real form, module [`crate::harmonics`]); they are linear in the normals, so every
//! coarser texel's coefficients are the plain average over its exact footprint
//! ([`crate::pyramid`]) and the MIP chain — and any hardware linear filter, anisotropic ones
//! included (Fig. 3) — is exact.
//!
//! **Texture layout.** `(l*+1)²` numbers per texel for bands `l ≤ l*`, packed four per RGBA
//! texture in (l, m) order (`sh0 = (c0,0 c1,−1 c1,0 c1,1)`, `sh1 = (c2,−2 … c2,1)`, …; unused
//! channels of the last texture are 0). Each holds `c_lm = Λ_l γ_lm = sqrt(4π/(2l+1)) γ_lm`,
//! which lies in [−1, 1] for every NDF (the addition theorem bounds `|Y_lm| ≤ sqrt((2l+1)/4π)`):
//! a [`ValueRange::Signed`] channel that every storage format holds (unorm formats biased,
//! `0.5 + 0.5·c`). `c_0,0 = 1` always; `(c_1,1, c_1,−1, c_1,0) = E[n]`, the unnormalized mean
//! normal.
//!
//! **Shading** (eq 12, the shaders' `ndf_sh.glsl`, CPU twin [`shade`]): with the BRDF's
//! `ρ̂_l` (eq 11, [`crate::brdf::Brdf::sh_coefficients`]),
//! `ρ^eff(ω) = Σ_{l ≤ l*} ρ̂_l Σ_m γ_lm Y_lm(ω) = Σ_l ρ̂_l/Λ_l Σ_m c_lm Y_lm(ω)`:
//! - diffuse ([`ShDiffuse`]): Lambert's `f(u) = max(u, 0)` *is* the cosine, so eq 12 at
//!   `ω = ω_i` with Lambert's `ρ̂_l` is the diffuse term exactly up to the band limit
//!   ([`ShDiffuse::Series`]). The truncated clamped cosine is a poor kernel at low l* (at
//!   l* = 2 it is `3/32 + u/2 + 15u²/32`: 1/16 too high facing the light, 3/32 at the
//!   terminator), so the default reads the same coefficients differently
//!   ([`ShDiffuse::Moments`]): bands 0–2 give the first two moments of `u = ω_i·n` over the
//!   texel's normals exactly, and the diffuse term is `E[max(u, 0)]` for a Gaussian `u` with
//!   those moments;
//! - specular: eq 12 at `ω = ω_h` times the cosine `max(ω_i·n̄, 0)` of the MIP-mapped normal
//!   `n̄ = normalize(E[n])` (the paper's choice, Sec 4.3), times the BRDF's g factor.
//!   [`product_coefficients`] computes the exact alternative (the SH projection of
//!   `f(ω_h·n) max(ω_i·n, 0)`), for measurement on the CPU.
//!
//! Ringing of a truncated sharp lobe can make either sum negative; both are clamped at 0
//! (the cost is measured in `docs/sh-brdf.md`), and from above at what the exact footprint
//! average cannot exceed: the diffuse sum at 1 (the truncated clamped cosine overshoots it by
//! up to 1/16 at l* = 2), the specular one at the lobe's peak (Gibbs' overshoot of a lobe with
//! a jump).

use crate::bake::{Bake, Method, Progress, Texture};
use crate::brdf::{Brdf, Shading, lambert_coefficient};
use crate::error::{Error, Result};
use crate::format::{Format, ValueRange};
use crate::harmonics::{Basis, count, eval_into, lambda};
use crate::ingest::NormalMap;
use crate::pyramid::pyramid;
use glam::DVec3;
use rayon::prelude::*;
use std::f64::consts::PI;

/// Largest band limit l* baked and shaded (289 coefficients, 73 textures).
pub const MAX_LMAX: usize = 16;

/// Textures a bake with band limit `lmax` has: `⌈(lmax+1)²/4⌉`.
pub fn texture_count(lmax: usize) -> usize {
    count(lmax).div_ceil(4)
}

/// The texture names, channel names and value ranges of a bake with band limit `lmax`
/// (module docs).
pub fn layout(lmax: usize) -> Vec<(&'static str, [&'static str; 4], [ValueRange; 4])> {
    let n = count(lmax);
    (0..texture_count(lmax))
        .map(|t| {
            let channels = std::array::from_fn(|c| {
                let i = 4 * t + c;
                if i < n {
                    COEFFICIENT_NAMES[i]
                } else {
                    "unused"
                }
            });
            let ranges = std::array::from_fn(|c| {
                if 4 * t + c < n {
                    ValueRange::Signed
                } else {
                    ValueRange::Unit
                }
            });
            (TEXTURE_NAMES[t], channels, ranges)
        })
        .collect()
}

/// The band limit of an SH bake (its `lmax` parameter).
pub fn lmax_of(bake: &Bake) -> usize {
    bake.parameters["lmax"].as_u64().unwrap_or(0) as usize
}

/// Checks an SH band limit: 0 to [`MAX_LMAX`], [`Error::InvalidOption`] otherwise.
pub(crate) fn check(lmax: usize) -> Result<()> {
    if lmax > MAX_LMAX {
        return Err(Error::InvalidOption(format!(
            "SH band limit {lmax} (expected 0 to {MAX_LMAX})"
        )));
    }
    Ok(())
}

/// Bakes the SH NDF with band limit `lmax` (0 to [`MAX_LMAX`]): `Λ_l Y_lm(n)` per finest texel,
/// averaged over every level's exact footprints in f64, stored as f32. Coefficients are computed
/// in batches of up to 32 (eight textures). Per batch, each finest row's coefficients are
/// evaluated once (the basis's constants precomputed, [`Basis`]) and reduced along x into
/// every coarser level at once while the row is in cache; the y pass then reads those row
/// sums level by level. The arithmetic is [`crate::pyramid::reduce`]'s, term for term in the
/// same order, so the result is bit for bit the two-pass reduction of the finest image — which
/// is never formed: the f64 working set is the x-reduced rows, about 8 bytes per texel per
/// coefficient of the batch. Progress is reported per batch and level, and cancellation polled
/// per row.
pub(crate) fn bake(map: &NormalMap, lmax: usize, progress: &mut Progress) -> Result<Bake> {
    check(lmax)?;
    let cancel = progress.cancel_flag();
    let (w, h) = (map.width(), map.height());
    let (fw, fh) = (w as usize, h as usize);
    let n = count(lmax);
    let layout = layout(lmax);
    let levels = pyramid(w, h);
    debug_assert_eq!(levels[0].size, (w, h));
    let coarse = &levels[1..];
    let mut textures: Vec<Texture> = layout
        .iter()
        .map(|&(name, channels, ranges)| Texture {
            name,
            channels,
            ranges,
            levels: vec![Vec::new(); levels.len()],
        })
        .collect();
    const BATCH: usize = 8;
    let batches = textures.len().div_ceil(BATCH);
    // The x-reduced rows are kept across batches (refilled with zeros rather than allocated
    // anew: fresh pages cost a fault each); the y pass's buffer across one batch's levels.
    let mut rows = Vec::new();
    for b in 0..batches {
        let (t0, t1) = (b * BATCH, ((b + 1) * BATCH).min(textures.len()));
        let ch = 4 * (t1 - t0);
        let (first, last) = (4 * t0, (4 * t1).min(n));
        let l_hi = (last as f64).sqrt().ceil() as usize - 1;
        let basis = Basis::new(l_hi);
        let scale: Vec<f64> = (first..last).map(|i| lambda(band(i))).collect();
        // Per finest row: the x-reduced sums of every coarse level, level after level.
        let mut offsets = vec![0usize];
        for lf in coarse {
            offsets.push(offsets.last().unwrap() + lf.size.0 as usize * ch);
        }
        let stride = *offsets.last().unwrap();
        // (A map of one level has no coarse level: rows of one unused value keep the zip below.)
        rows.clear();
        rows.resize(fh * stride.max(1), 0.0f64);
        // Level 0 is the coefficients themselves, written straight into the textures.
        let mut level0: Vec<Vec<[f32; 4]>> = (t0..t1).map(|_| vec![[0.0; 4]; fw * fh]).collect();
        let mut level0_rows: Vec<Vec<&mut [[f32; 4]]>> =
            (0..fh).map(|_| Vec::with_capacity(t1 - t0)).collect();
        for t in level0.iter_mut() {
            for (r, chunk) in level0_rows.iter_mut().zip(t.chunks_mut(fw)) {
                r.push(chunk);
            }
        }
        level0_rows
            .into_par_iter()
            .zip(rows.par_chunks_mut(stride.max(1)))
            .zip(map.normals().par_chunks(fw))
            .for_each_init(
                || (vec![0.0f64; count(l_hi)], vec![0.0f64; fw * ch]),
                |(y, finest), ((mut tex_rows, row), normals)| {
                    // A large map takes a while: rows are skipped once the bake is cancelled.
                    if cancel.is_cancelled() {
                        return;
                    }
                    for (o, nrm) in finest.chunks_exact_mut(ch).zip(normals) {
                        basis.eval_into(nrm.as_dvec3(), y);
                        for (k, (i, s)) in (first..last).zip(&scale).enumerate() {
                            o[k] = s * y[i];
                        }
                    }
                    for (j, t) in tex_rows.iter_mut().enumerate() {
                        for (texel, o) in t.iter_mut().zip(finest.chunks_exact(ch)) {
                            *texel = std::array::from_fn(|c| o[4 * j + c] as f32);
                        }
                    }
                    for (k, lf) in coarse.iter().enumerate() {
                        let out = &mut row[offsets[k]..offsets[k + 1]];
                        for (cx, o) in out.chunks_exact_mut(ch).enumerate() {
                            for (fx, wt) in lf.x.taps(cx) {
                                let s = &finest[fx as usize * ch..(fx as usize + 1) * ch];
                                for (a, v) in o.iter_mut().zip(s) {
                                    *a += wt * v;
                                }
                            }
                        }
                    }
                },
            );
        cancel.check()?;
        for (t, l0) in textures[t0..t1].iter_mut().zip(level0) {
            t.levels[0] = l0;
        }
        progress.report((b * levels.len() + 1) as f64 / (batches * levels.len()) as f64)?;
        let mut avg = Vec::new();
        for (k, lf) in coarse.iter().enumerate() {
            let (cw, chh) = (lf.size.0 as usize, lf.size.1 as usize);
            avg.clear();
            avg.resize(chh * cw * ch, 0.0f64);
            avg.par_chunks_mut(cw * ch).enumerate().for_each(|(cy, o)| {
                for (fy, wt) in lf.y.taps(cy) {
                    let start = fy as usize * stride + offsets[k];
                    for (a, v) in o.iter_mut().zip(&rows[start..start + cw * ch]) {
                        *a += wt * v;
                    }
                }
            });
            for (j, t) in textures[t0..t1].iter_mut().enumerate() {
                t.levels[k + 1] = avg
                    .chunks_exact(ch)
                    .map(|o| std::array::from_fn(|c| o[4 * j + c] as f32))
                    .collect();
            }
            let done = (b * levels.len() + k + 2) as f64 / (batches * levels.len()) as f64;
            progress.report(done)?;
        }
    }
    Ok(Bake {
        method: Method::Sh,
        sizes: levels.iter().map(|l| l.size).collect(),
        textures,
        addressing: map.addressing(),
        lobes: 0,
        parameters: serde_json::json!({
            "lmax": lmax,
            "coefficients": n,
            "order": "(l, m), index l*l + l + m, four per RGBA texture",
            "encoding": "sqrt(4 pi/(2l+1)) * gamma_lm, in [-1, 1]",
            "basis": "real spherical harmonics without the Condon-Shortley phase",
        }),
        format: Format::F32,
    })
}

/// The band l of coefficient index i (`l² ≤ i < (l+1)²`).
fn band(i: usize) -> usize {
    let mut l = (i as f64).sqrt() as usize;
    while (l + 1) * (l + 1) <= i {
        l += 1;
    }
    while l * l > i {
        l -= 1;
    }
    l
}

/// Coefficient i of an SH texel (`texels[i/4][i%4]`).
fn coefficient(texels: &[[f32; 4]], i: usize) -> f64 {
    texels[i / 4][i % 4] as f64
}

/// eq 12 for one direction: `Σ_{l ≤ lmax} w_l/Λ_l Σ_m c_lm Y_lm(ω)` for weights `w_l` (the
/// BRDF's `ρ̂_l`), from the texel's `c_lm` and the basis `y` at ω.
fn series(texels: &[[f32; 4]], lmax: usize, weights: &[f64], y: &[f64]) -> f64 {
    let mut sum = 0.0;
    for (l, &w) in weights.iter().enumerate().take(lmax + 1) {
        if w == 0.0 {
            continue;
        }
        let band = l * l..(l + 1) * (l + 1);
        let band_sum: f64 = band
            .clone()
            .zip(&y[band])
            .map(|(i, yi)| coefficient(texels, i) * yi)
            .sum();
        sum += w / lambda(l) * band_sum;
    }
    sum
}

thread_local! {
    /// `ρ̂_l` (l ≤ MAX_LMAX) of the BRDFs shaded lately on this thread.
    static RHO: std::cell::RefCell<Vec<(Brdf, std::rc::Rc<Vec<f64>>)>> =
        const { std::cell::RefCell::new(Vec::new()) };
}

/// `ρ̂_l` for l ≤ [`MAX_LMAX`] of `brdf`'s specular lobe, computed once per thread and BRDF
/// (the quadrature costs about a millisecond; shading calls this per texel).
fn rho(brdf: &Brdf) -> std::rc::Rc<Vec<f64>> {
    let same = |a: &Brdf, b: &Brdf| match (a, b) {
        (Brdf::Tabulated(x), Brdf::Tabulated(y)) => std::sync::Arc::ptr_eq(x, y),
        _ => a == b,
    };
    RHO.with(|cache| {
        let mut cache = cache.borrow_mut();
        if let Some((_, r)) = cache.iter().find(|(b, _)| same(b, brdf)) {
            return r.clone();
        }
        let r = std::rc::Rc::new(brdf.sh_coefficients(MAX_LMAX));
        if cache.len() >= 8 {
            cache.remove(0);
        }
        cache.push((brdf.clone(), r.clone()));
        r
    })
}

/// Lambert's `ρ̂_l` for l ≤ [`MAX_LMAX`] (closed forms, [`lambert_coefficient`]).
pub fn lambert_rho() -> [f64; MAX_LMAX + 1] {
    std::array::from_fn(lambert_coefficient)
}

/// The MIP-mapped normal of an SH texel: `normalize(c_1,1, c_1,−1, c_1,0) = normalize(E[n])`
/// (+Z when `lmax = 0` or the mean is zero).
pub fn mean_normal(texels: &[[f32; 4]], lmax: usize) -> DVec3 {
    if lmax == 0 {
        return DVec3::Z;
    }
    DVec3::new(
        coefficient(texels, 3),
        coefficient(texels, 1),
        coefficient(texels, 2),
    )
    .try_normalize()
    .unwrap_or(DVec3::Z)
}

thread_local! {
    /// The basis at the two directions shaded last on this thread (light and half vector:
    /// shading a level texel by texel asks for the same two directions every time).
    static BASIS: std::cell::RefCell<[(usize, DVec3, Vec<f64>); 2]> = std::cell::RefCell::new([
        (usize::MAX, DVec3::ZERO, vec![0.0; count(MAX_LMAX)]),
        (usize::MAX, DVec3::ZERO, vec![0.0; count(MAX_LMAX)]),
    ]);
}

/// `f(Y(d))` with the basis up to `lmax` at `d` in slot `slot` of this thread's cache
/// (evaluated only when `d` or `lmax` changed; bit for bit what [`eval_into`] gives).
fn with_basis<T>(slot: usize, lmax: usize, d: DVec3, f: impl FnOnce(&[f64]) -> T) -> T {
    BASIS.with(|cache| {
        let mut cache = cache.borrow_mut();
        let (l, dir, y) = &mut cache[slot];
        if *l != lmax || *dir != d {
            eval_into(lmax, d, y);
            *l = lmax;
            *dir = d;
        }
        f(y)
    })
}

/// Filtered shading of one SH texel (band limit `lmax`) for light `l`, half vector `h` and
/// `brdf`, without the g factor (module docs; the CPU twin of `ndf_sh.glsl`):
/// diffuse by `diffuse_term` — [`diffuse_moments`] (l* ≥ 2) or the series
/// `Σ ρ̂^Lambert_l/Λ_l Σ_m c_lm Y_lm(ω_i)` — clamped to [0, 1] (the footprint average of
/// `max(ω_i·n, 0)` lies there; the truncated clamped cosine overshoots it by up to 1/16 at
/// l* = 2),
/// specular `Σ ρ̂_l/Λ_l Σ_m c_lm Y_lm(ω_h)` clamped to [0, the lobe's peak] (Gibbs' overshoot
/// of a lobe with a jump, 25 % at l* = 2 for GGX α = 1's hemisphere step) times
/// `max(ω_i·n̄, 0)`.
pub fn shade(
    texels: &[[f32; 4]],
    lmax: usize,
    l: DVec3,
    h: DVec3,
    brdf: &Brdf,
    diffuse_term: ShDiffuse,
) -> Shading {
    let lmax = lmax.min(MAX_LMAX);
    let diffuse = if diffuse_term == ShDiffuse::Moments && lmax >= 2 {
        diffuse_moments(texels, lmax, l)
    } else {
        with_basis(0, lmax, l, |y| series(texels, lmax, &lambert_rho(), y))
    };
    let f = specular_series(texels, lmax, h, brdf);
    let specular = if brdf.has_specular() {
        f.clamp(0.0, brdf.peak()) * mean_normal(texels, lmax).dot(l).max(0.0)
    } else {
        0.0
    };
    Shading {
        diffuse: diffuse.clamp(0.0, 1.0),
        specular,
    }
}

/// Which diffuse term an SH texel gives (module docs; the shaders' `NDF_SH_DIFFUSE_SERIES`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ShDiffuse {
    /// eq 12 with Lambert's `ρ̂_l`: the footprint average of the clamped cosine truncated to
    /// l* bands (exact up to the band limit, the paper's reading).
    Series,
    /// [`diffuse_moments`]: `E[max(u, 0)]` for a Gaussian `u = ω_i·n` with the mean and
    /// variance that bands 0–2 give exactly. The default for l* ≥ 2 (lower than the series up
    /// to l* = 6 on every shared map, `docs/sh-brdf.md`); l* < 2 has no variance and uses the
    /// series.
    #[default]
    Moments,
}

/// The diffuse term of [`ShDiffuse::Moments`] for light `l`, from bands 0–2 of an SH texel
/// (`lmax ≥ 2`): with `u = ω_i·n` over the texel's normals, `E[u] = (c_1,1, c_1,−1, c_1,0)·ω_i`
/// and, by `u² = (1 + 2P₂(u))/3` and the addition theorem (`c_0,0 = 1`),
/// `E[u²] = c_0,0/3 + (2/3) Λ₂ Σ_m c_2m Y_2m(ω_i)` — both linear in the coefficients, so exact
/// under any linear filter. The result is `E[max(u, 0)]` for a Gaussian `u` of that mean and
/// spread `σ = v/sqrt(v + ε)`, `v = max(E[u²] − E[u]², 0)`, `ε` =
/// [`MOMENTS_VARIANCE_SOFTENING`] ([`clamped_gaussian_mean`]), clamped to [0, 1] by [`shade`].
/// `σ ≈ √v` for spreads over 0.01 rad; below, σ falls linearly instead of as `√v`, whose
/// infinite slope at 0 would amplify the f32 rounding of `E[u²] − E[u]²` (about 10⁻⁷ in a
/// shader) without bound where the spread vanishes (the slope is now at most `1/√ε` = 100;
/// the shared maps' error changes by at most 0.002 points). A single normal (variance 0)
/// gives `max(n·ω_i, 0)` exactly.
pub fn diffuse_moments(texels: &[[f32; 4]], lmax: usize, l: DVec3) -> f64 {
    let l = l.try_normalize().unwrap_or(DVec3::Z);
    let mean = DVec3::new(
        coefficient(texels, 3),
        coefficient(texels, 1),
        coefficient(texels, 2),
    )
    .dot(l);
    let band2 = with_basis(0, lmax, l, |y| {
        (4..9).map(|i| coefficient(texels, i) * y[i]).sum::<f64>()
    });
    let second = coefficient(texels, 0) / 3.0 + 2.0 / 3.0 * lambda(2) * band2;
    let v = (second - mean * mean).max(0.0);
    clamped_gaussian_mean(mean, v / (v + MOMENTS_VARIANCE_SOFTENING).sqrt())
}

/// The `ε` of [`diffuse_moments`]' spread `σ = v/sqrt(v + ε)`: 10⁻⁴, a spread of 0.01 rad.
pub const MOMENTS_VARIANCE_SOFTENING: f64 = 1e-4;

/// `E[max(X, 0)] = m Φ(m/σ) + σ φ(m/σ)` for `X ~ N(m, σ²)`, `σ ≥ 0`; σ is floored at 10⁻⁶
/// inside the ratio so σ → 0 gives `max(m, 0)`. Φ through [`erf`] (the shaders use the same
/// approximation).
pub fn clamped_gaussian_mean(m: f64, sigma: f64) -> f64 {
    let sigma = sigma.max(0.0);
    let z = m / sigma.max(1e-6);
    let cdf = 0.5 * (1.0 + erf(z * std::f64::consts::FRAC_1_SQRT_2));
    let pdf = (-0.5 * z * z).exp() / (2.0 * PI).sqrt();
    m * cdf + sigma * pdf
}

/// The error function by Abramowitz & Stegun 7.1.26 (absolute error ≤ 1.5·10⁻⁷), odd
/// extension; `ndf_erf` in `ndf_sh.glsl` is the same formula.
pub fn erf(x: f64) -> f64 {
    const P: f64 = 0.327_591_1;
    const A: [f64; 5] = [
        0.254_829_592,
        -0.284_496_736,
        1.421_413_741,
        -1.453_152_027,
        1.061_405_429,
    ];
    let ax = x.abs();
    let t = 1.0 / (1.0 + P * ax);
    let poly = t * (A[0] + t * (A[1] + t * (A[2] + t * (A[3] + t * A[4]))));
    let y = 1.0 - poly * (-ax * ax).exp();
    if x < 0.0 { -y } else { y }
}

/// The two sums of eq 12 before any clamp: Lambert's at `l` and the BRDF's at `h` (0 for
/// Lambert). Negative values are the ringing [`shade`] clamps.
pub fn shade_series(
    texels: &[[f32; 4]],
    lmax: usize,
    l: DVec3,
    h: DVec3,
    brdf: &Brdf,
) -> (f64, f64) {
    let lmax = lmax.min(MAX_LMAX);
    let diffuse = with_basis(0, lmax, l, |y| series(texels, lmax, &lambert_rho(), y));
    (diffuse, specular_series(texels, lmax, h, brdf))
}

/// eq 12 at the half vector with the BRDF's `ρ̂_l` (0 for Lambert), before any clamp.
fn specular_series(texels: &[[f32; 4]], lmax: usize, h: DVec3, brdf: &Brdf) -> f64 {
    if brdf.has_specular() {
        let rho = rho(brdf);
        with_basis(1, lmax, h, |y| series(texels, lmax, &rho, y))
    } else {
        0.0
    }
}

/// The exact alternative to the MIP-mapped cosine (module docs), for measurement on the CPU:
/// the SH coefficients up to `lmax` of `P(n) = f(ω_h·n) max(ω_i·n, 0)`, by a quadrature in
/// the frame of `h` (polar panels sized to the lobe, 256 azimuths), so that
/// `Σ_lm P_lm γ_lm` ([`shade_product`]) is the footprint average of the specular term exactly up
/// to the band limit (without the g factor).
pub fn product_coefficients(brdf: &Brdf, lmax: usize, l: DVec3, h: DVec3) -> Vec<f64> {
    let mut out = vec![0.0; count(lmax)];
    let mut y = vec![0.0; count(lmax)];
    let (t1, t2) = crate::brdf::tangent_frame(h);
    let nphi = 256;
    for (theta, w) in crate::harmonics::polar_quadrature(brdf.angular_width()) {
        let (st, ct) = theta.sin_cos();
        let f = brdf.lobe(ct);
        if f == 0.0 {
            continue;
        }
        for k in 0..nphi {
            let phi = 2.0 * PI * (k as f64 + 0.5) / nphi as f64;
            let n = ct * h + st * (phi.cos() * t1 + phi.sin() * t2);
            let c = n.dot(l);
            if c <= 0.0 {
                continue;
            }
            let weight = w * st * 2.0 * PI / nphi as f64 * f * c;
            eval_into(lmax, n, &mut y);
            for (o, v) in out.iter_mut().zip(&y) {
                *o += weight * v;
            }
        }
    }
    out
}

/// `Σ_lm P_lm γ_lm` for the coefficients of [`product_coefficients`] and an SH texel
/// (`γ_lm = c_lm/Λ_l`), clamped at 0.
pub fn shade_product(texels: &[[f32; 4]], lmax: usize, p: &[f64]) -> f64 {
    let mut sum = 0.0;
    for (i, pi) in p.iter().enumerate().take(count(lmax)) {
        sum += pi * coefficient(texels, i) / lambda(band(i));
    }
    sum.max(0.0)
}

/// Texture names `sh0`, `sh1`, … (file names, manifest).
const TEXTURE_NAMES: [&str; 73] = [
    "sh0", "sh1", "sh2", "sh3", "sh4", "sh5", "sh6", "sh7", "sh8", "sh9", "sh10", "sh11", "sh12",
    "sh13", "sh14", "sh15", "sh16", "sh17", "sh18", "sh19", "sh20", "sh21", "sh22", "sh23", "sh24",
    "sh25", "sh26", "sh27", "sh28", "sh29", "sh30", "sh31", "sh32", "sh33", "sh34", "sh35", "sh36",
    "sh37", "sh38", "sh39", "sh40", "sh41", "sh42", "sh43", "sh44", "sh45", "sh46", "sh47", "sh48",
    "sh49", "sh50", "sh51", "sh52", "sh53", "sh54", "sh55", "sh56", "sh57", "sh58", "sh59", "sh60",
    "sh61", "sh62", "sh63", "sh64", "sh65", "sh66", "sh67", "sh68", "sh69", "sh70", "sh71", "sh72",
];

/// Channel names `c<l>,<m>` of the coefficients in (l, m) order.
const COEFFICIENT_NAMES: [&str; 289] = [
    "c0,0", "c1,-1", "c1,0", "c1,1", "c2,-2", "c2,-1", "c2,0", "c2,1", "c2,2", "c3,-3", "c3,-2",
    "c3,-1", "c3,0", "c3,1", "c3,2", "c3,3", "c4,-4", "c4,-3", "c4,-2", "c4,-1", "c4,0", "c4,1",
    "c4,2", "c4,3", "c4,4", "c5,-5", "c5,-4", "c5,-3", "c5,-2", "c5,-1", "c5,0", "c5,1", "c5,2",
    "c5,3", "c5,4", "c5,5", "c6,-6", "c6,-5", "c6,-4", "c6,-3", "c6,-2", "c6,-1", "c6,0", "c6,1",
    "c6,2", "c6,3", "c6,4", "c6,5", "c6,6", "c7,-7", "c7,-6", "c7,-5", "c7,-4", "c7,-3", "c7,-2",
    "c7,-1", "c7,0", "c7,1", "c7,2", "c7,3", "c7,4", "c7,5", "c7,6", "c7,7", "c8,-8", "c8,-7",
    "c8,-6", "c8,-5", "c8,-4", "c8,-3", "c8,-2", "c8,-1", "c8,0", "c8,1", "c8,2", "c8,3", "c8,4",
    "c8,5", "c8,6", "c8,7", "c8,8", "c9,-9", "c9,-8", "c9,-7", "c9,-6", "c9,-5", "c9,-4", "c9,-3",
    "c9,-2", "c9,-1", "c9,0", "c9,1", "c9,2", "c9,3", "c9,4", "c9,5", "c9,6", "c9,7", "c9,8",
    "c9,9", "c10,-10", "c10,-9", "c10,-8", "c10,-7", "c10,-6", "c10,-5", "c10,-4", "c10,-3",
    "c10,-2", "c10,-1", "c10,0", "c10,1", "c10,2", "c10,3", "c10,4", "c10,5", "c10,6", "c10,7",
    "c10,8", "c10,9", "c10,10", "c11,-11", "c11,-10", "c11,-9", "c11,-8", "c11,-7", "c11,-6",
    "c11,-5", "c11,-4", "c11,-3", "c11,-2", "c11,-1", "c11,0", "c11,1", "c11,2", "c11,3", "c11,4",
    "c11,5", "c11,6", "c11,7", "c11,8", "c11,9", "c11,10", "c11,11", "c12,-12", "c12,-11",
    "c12,-10", "c12,-9", "c12,-8", "c12,-7", "c12,-6", "c12,-5", "c12,-4", "c12,-3", "c12,-2",
    "c12,-1", "c12,0", "c12,1", "c12,2", "c12,3", "c12,4", "c12,5", "c12,6", "c12,7", "c12,8",
    "c12,9", "c12,10", "c12,11", "c12,12", "c13,-13", "c13,-12", "c13,-11", "c13,-10", "c13,-9",
    "c13,-8", "c13,-7", "c13,-6", "c13,-5", "c13,-4", "c13,-3", "c13,-2", "c13,-1", "c13,0",
    "c13,1", "c13,2", "c13,3", "c13,4", "c13,5", "c13,6", "c13,7", "c13,8", "c13,9", "c13,10",
    "c13,11", "c13,12", "c13,13", "c14,-14", "c14,-13", "c14,-12", "c14,-11", "c14,-10", "c14,-9",
    "c14,-8", "c14,-7", "c14,-6", "c14,-5", "c14,-4", "c14,-3", "c14,-2", "c14,-1", "c14,0",
    "c14,1", "c14,2", "c14,3", "c14,4", "c14,5", "c14,6", "c14,7", "c14,8", "c14,9", "c14,10",
    "c14,11", "c14,12", "c14,13", "c14,14", "c15,-15", "c15,-14", "c15,-13", "c15,-12", "c15,-11",
    "c15,-10", "c15,-9", "c15,-8", "c15,-7", "c15,-6", "c15,-5", "c15,-4", "c15,-3", "c15,-2",
    "c15,-1", "c15,0", "c15,1", "c15,2", "c15,3", "c15,4", "c15,5", "c15,6", "c15,7", "c15,8",
    "c15,9", "c15,10", "c15,11", "c15,12", "c15,13", "c15,14", "c15,15", "c16,-16", "c16,-15",
    "c16,-14", "c16,-13", "c16,-12", "c16,-11", "c16,-10", "c16,-9", "c16,-8", "c16,-7", "c16,-6",
    "c16,-5", "c16,-4", "c16,-3", "c16,-2", "c16,-1", "c16,0", "c16,1", "c16,2", "c16,3", "c16,4",
    "c16,5", "c16,6", "c16,7", "c16,8", "c16,9", "c16,10", "c16,11", "c16,12", "c16,13", "c16,14",
    "c16,15", "c16,16",
];

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::BakeOptions;
    use crate::baseline::tests::test_map;
    use crate::ingest::{Addressing, BadNormals};

    fn sh_bake(map: &NormalMap, lmax: usize) -> Bake {
        let o = BakeOptions {
            lmax,
            ..BakeOptions::default()
        };
        crate::methods::bake_with(map, Method::Sh, &o).unwrap()
    }

    #[test]
    fn level_k_coefficients_are_the_direct_footprint_averages() {
        let map = test_map(13, 6);
        let lmax = 6;
        let b = sh_bake(&map, lmax);
        assert_eq!(b.textures.len(), texture_count(lmax));
        for (level, lf) in pyramid(13, 6).iter().enumerate() {
            let (lw, lh) = lf.size;
            for (x, y) in [(0, 0), (lw - 1, lh - 1), (lw / 2, lh / 2)] {
                let mut want = vec![0.0; count(lmax)];
                for (fx, fy, wt) in lf.texel(x, y) {
                    let yv = crate::harmonics::eval(lmax, map.normal(fx, fy).as_dvec3());
                    for (i, v) in yv.iter().enumerate() {
                        want[i] += wt * lambda(band(i)) * v;
                    }
                }
                let t = b.texel(level, x, y);
                for (i, w) in want.iter().enumerate() {
                    let got = coefficient(&t, i);
                    assert!((got - w).abs() < 1e-6, "level {level} c{i}: {got} vs {w}");
                    assert!(got.abs() <= 1.0 + 1e-6);
                }
                assert!((coefficient(&t, 0) - 1.0).abs() < 1e-6);
            }
        }
    }

    /// The reference the bake must reproduce bit for bit: the finest image of every
    /// coefficient and [`crate::pyramid::reduce`] onto each level.
    fn reference_levels(map: &NormalMap, lmax: usize) -> Vec<Vec<f32>> {
        let (w, h) = (map.width(), map.height());
        let n = count(lmax);
        let mut finest = Vec::with_capacity(w as usize * h as usize * n);
        for y in 0..h {
            for x in 0..w {
                let v = crate::harmonics::eval(lmax, map.normal(x, y).as_dvec3());
                finest.extend(v.iter().enumerate().map(|(i, c)| lambda(band(i)) * c));
            }
        }
        pyramid(w, h)
            .iter()
            .map(|lf| {
                let avg = crate::pyramid::reduce(&finest, n, w, lf);
                avg.iter().map(|&v| v as f32).collect()
            })
            .collect()
    }

    #[test]
    fn the_bake_is_bit_for_bit_the_two_pass_reduction() {
        // Odd, thin and one-texel maps; l* = 9 spans four batches of 32 coefficients.
        for (w, h, lmax) in [(13, 6, 9), (1, 8, 2), (8, 1, 3), (1, 1, 4), (16, 16, 1)] {
            let map = test_map(w, h);
            let b = sh_bake(&map, lmax);
            let want = reference_levels(&map, lmax);
            let n = count(lmax);
            assert_eq!(b.sizes.len(), want.len());
            for (level, lw) in want.iter().enumerate() {
                let (sw, sh) = b.sizes[level];
                for t in 0..(sw * sh) as usize {
                    for i in 0..texture_count(lmax) * 4 {
                        let got = b.textures[i / 4].levels[level][t][i % 4];
                        let w = if i < n { lw[t * n + i] } else { 0.0 };
                        assert_eq!(got.to_bits(), w.to_bits(), "{w}x{h} level {level} c{i}");
                    }
                }
            }
        }
    }

    #[test]
    fn unused_channels_are_zero_and_layout_names_bands() {
        let l = layout(2);
        assert_eq!(l.len(), 3);
        assert_eq!(l[0].1, ["c0,0", "c1,-1", "c1,0", "c1,1"]);
        assert_eq!(l[2].1, ["c2,2", "unused", "unused", "unused"]);
        let b = sh_bake(&test_map(4, 4), 2);
        assert!(
            b.textures[2]
                .levels
                .iter()
                .flatten()
                .all(|t| t[1..] == [0.0; 3])
        );
        for i in 0..count(MAX_LMAX) {
            assert_eq!(l_of(i), band(i));
        }
    }

    fn l_of(i: usize) -> usize {
        (0..=MAX_LMAX).find(|l| i < (l + 1) * (l + 1)).unwrap()
    }

    #[test]
    fn a_single_normal_shades_like_the_truncated_lobe_and_lambert_converges() {
        // One normal n: γ = δ(n), so eq 12 gives the truncated SH series of f(ω·n). For
        // Lambert with l* = 16 the series (computed independently in 1D with Legendre
        // polynomials) is within 0.0183 of max(ω·n, 0) everywhere, the worst at the terminator,
        // and within 0.0055 where |ω·n| > 0.3 (the worst at ω = n).
        let n = DVec3::new(0.3, -0.2, 0.93).normalize();
        let map = NormalMap::from_vectors(
            1,
            1,
            vec![n.as_vec3()],
            Addressing::Wrap,
            BadNormals::Repair,
        )
        .unwrap();
        let b = sh_bake(&map, 16);
        let t = b.texel(0, 0, 0);
        let (mut worst, mut far): (f64, f64) = (0.0, 0.0);
        let mut rng = crate::rng::Rng(5);
        for _ in 0..400 {
            let l = rng.direction();
            let s = shade(&t, 16, l, DVec3::Z, &Brdf::Lambert, ShDiffuse::Series);
            let e = (s.diffuse - n.dot(l).max(0.0)).abs();
            worst = worst.max(e);
            if n.dot(l).abs() > 0.3 {
                far = far.max(e);
            }
        }
        assert!(worst < 0.0183 && far < 0.0055, "{worst} {far}");
        // At ω = n the truncated series of max(u, 0) is 1 − 0.00545 (the Legendre tail).
        let s = shade(&t, 16, n, DVec3::Z, &Brdf::Lambert, ShDiffuse::Series);
        assert!(
            (s.diffuse - (1.0 - 0.005455017)).abs() < 1e-6,
            "{}",
            s.diffuse
        );
    }

    #[test]
    fn erf_and_the_clamped_gaussian_mean_match_independent_values() {
        // erf at 0.5, 1, 2 to 10 digits (Abramowitz & Stegun Table 7.1).
        for (x, want) in [
            (0.5, 0.520_499_877_8),
            (1.0, 0.842_700_792_9),
            (2.0, 0.995_322_265),
        ] {
            assert!((erf(x) - want).abs() < 2e-7, "{x}");
            assert!((erf(-x) + want).abs() < 2e-7, "{x}");
        }
        // E[max(X, 0)] by a midpoint rule over ±12σ.
        for (m, v) in [
            (0.3, 0.04),
            (-0.1, 0.01),
            (0.0, 0.25),
            (0.8, 1e-4),
            (-0.5, 0.09),
        ] {
            let sd = f64::sqrt(v);
            let n = 200_000;
            let (a, b) = (m - 12.0 * sd, m + 12.0 * sd);
            let dx = (b - a) / n as f64;
            let want: f64 = (0..n)
                .map(|i| {
                    let x = a + (i as f64 + 0.5) * dx;
                    x.max(0.0) * (-(x - m) * (x - m) / (2.0 * v)).exp()
                })
                .sum::<f64>()
                * dx
                / (2.0 * PI * v).sqrt();
            assert!(
                (clamped_gaussian_mean(m, sd) - want).abs() < 1e-6,
                "{m} {v}"
            );
        }
        assert_eq!(clamped_gaussian_mean(0.4, 0.0), 0.4);
        assert_eq!(clamped_gaussian_mean(-0.4, -1e-9), 0.0);
    }

    #[test]
    fn the_moments_diffuse_term_is_the_gaussian_of_the_footprints_own_moments() {
        // A 4×4 map of scattered normals: the 1×1 level covers all 16. The moments the SH
        // coefficients give must be the brute-force moments of u = ω_i·n over those normals.
        let mut rng = crate::rng::Rng(11);
        let normals: Vec<DVec3> = (0..16)
            .map(|_| (DVec3::Z + 0.6 * rng.direction()).normalize())
            .collect();
        let map = NormalMap::from_vectors(
            4,
            4,
            normals.iter().map(|n| n.as_vec3()).collect(),
            Addressing::Wrap,
            BadNormals::Repair,
        )
        .unwrap();
        for lmax in [2, 4] {
            let b = sh_bake(&map, lmax);
            let coarse = b.texel(2, 0, 0);
            for _ in 0..50 {
                let l = rng.direction();
                let u: Vec<f64> = normals
                    .iter()
                    .map(|n| n.as_vec3().as_dvec3().dot(l))
                    .collect();
                let mean = u.iter().sum::<f64>() / 16.0;
                let second = u.iter().map(|u| u * u).sum::<f64>() / 16.0;
                let v = second - mean * mean;
                let want = clamped_gaussian_mean(mean, v / (v + 1e-4).sqrt());
                let got = diffuse_moments(&coarse, lmax, l);
                assert!((got - want).abs() < 2e-6, "l* {lmax}: {got} {want}");
            }
            // One normal (level 0): the exact cosine, where the series is off by up to 1/16.
            let fine = b.texel(0, 1, 2);
            let n = normals[2 * 4 + 1].as_vec3().as_dvec3();
            for _ in 0..50 {
                let l = rng.direction();
                let got = shade(&fine, lmax, l, DVec3::Z, &Brdf::Lambert, ShDiffuse::Moments);
                assert!(
                    (got.diffuse - n.dot(l).max(0.0)).abs() < 5e-4,
                    "{}",
                    got.diffuse
                );
            }
        }
    }
}
