//! CPU shading: the exact per-normal BRDF (the ground truth) and each method's filtered shading
//! from its baked texels (the CPU twin of the shaders).
//!
//! The BRDF is the paper's (Algorithm 2 line 14, Sec 7.2): a Lambert term and a normalized
//! Blinn-Phong term `(s+1)/(2π) (ω_h·n)^s`, both multiplied by the cosine `max(ω_i·n, 0)`.
//! The two terms are returned separately (unit weights): any `K_d·diffuse + K_s·specular` is a
//! combination of them, and the error of each is reported on its own.
//!
//! **Filtered shading of the baselines.** Every baseline estimates the NDF's spread around its
//! mean direction μ and widens the Blinn-Phong lobe accordingly; the lobe is exactly the BRDF
//! when the spread is zero, so at level 0 (and on a flat map) every method reproduces the
//! reference exactly and the measured error is filtering error only.
//! - plain: μ = stored normal, lobe unchanged;
//! - Toksvig: `s' = |n̄| s / (|n̄| + s(1 − |n̄|))`, diffuse from the unnormalized `n̄`;
//! - LEAN and Olano–North: a 2×2 NDF covariance Σ (LEAN: of slopes, `E[bbᵀ] − E[b]E[b]ᵀ`;
//!   Olano–North: of the normal projected on μ's tangent plane, from `E[nnᵀ]`) is added to the
//!   lobe's own covariance `I/s`; the lobe is an anisotropic Blinn-Phong
//!   `sqrt(det S + tr S + 1)/(2π) · (ω_h·μ)^{dᵀSd/dᵀd}` with `S = (I/s + Σ)⁻¹` and d the offset
//!   of ω_h from μ. With Σ = 0 this is `(s+1)/(2π)(ω_h·μ)^s`. LEAN's own paper evaluates a
//!   Beckmann-like Gaussian instead, which differs from Blinn-Phong by O(1/s) even unfiltered.

use crate::bake::{Bake, Method};
use glam::{DVec2, DVec3};
use std::f64::consts::PI;

/// The two shading terms at one point for one light and view.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Shading {
    /// Lambert: `max(ω_i·n, 0)`.
    pub diffuse: f64,
    /// Normalized Blinn-Phong times the cosine: `(s+1)/(2π) max(ω_h·n, 0)^s max(ω_i·n, 0)`.
    pub specular: f64,
}

/// Half vector of a light and a view direction (both unit, pointing away from the surface).
/// Opposite directions have no half vector; +Z is returned so shading stays finite.
pub fn half_vector(l: DVec3, v: DVec3) -> DVec3 {
    (l + v).try_normalize().unwrap_or(DVec3::Z)
}

/// Normalized Blinn-Phong lobe `(s+1)/(2π) max(c, 0)^s` (eq 20's form).
pub fn blinn_phong(cos_h: f64, s: f64) -> f64 {
    (s + 1.0) / (2.0 * PI) * cos_h.max(0.0).powf(s)
}

/// The exact shading of one unfiltered unit normal `n` (the reference the filters approximate).
pub fn reference(n: DVec3, l: DVec3, h: DVec3, s: f64) -> Shading {
    let cos_i = n.dot(l).max(0.0);
    Shading {
        diffuse: cos_i,
        specular: blinn_phong(n.dot(h), s) * cos_i,
    }
}

/// A unit vector's orthonormal tangent frame (Duff et al. 2017, branch on the sign of z only).
pub fn tangent_frame(n: DVec3) -> (DVec3, DVec3) {
    let sign = 1.0f64.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        DVec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

/// Anisotropic Blinn-Phong lobe widened by an NDF covariance `sigma = (xx, yy, xy)` (module
/// docs): `S = (I/s + Σ)⁻¹`, normalization `sqrt(det S + tr S + 1)/(2π)`, exponent the Rayleigh
/// quotient of S along the offset `d`. Σ must be positive semi-definite ([`psd`]).
pub fn widened_lobe(cos_h: f64, d: DVec2, sigma: [f64; 3], s: f64) -> f64 {
    let (a, c, b) = (sigma[0] + 1.0 / s, sigma[1] + 1.0 / s, sigma[2]);
    let det = (a * c - b * b).max(f64::MIN_POSITIVE);
    let (sxx, syy, sxy) = (c / det, a / det, -b / det);
    let norm = (sxx * syy - sxy * sxy + sxx + syy + 1.0).max(0.0).sqrt() / (2.0 * PI);
    let dd = d.length_squared();
    let exponent = if dd > 1e-300 {
        (sxx * d.x * d.x + 2.0 * sxy * d.x * d.y + syy * d.y * d.y) / dd
    } else {
        0.5 * (sxx + syy)
    };
    norm * cos_h.max(0.0).powf(exponent)
}

/// Projects a symmetric 2×2 matrix `(xx, yy, xy)` onto the positive semi-definite cone by
/// clamping its eigenvalues at 0 (rounding can make a filtered covariance slightly indefinite).
pub fn psd(m: [f64; 3]) -> [f64; 3] {
    let (xx, yy, xy) = (m[0], m[1], m[2]);
    let mean = 0.5 * (xx + yy);
    let r = (0.25 * (xx - yy) * (xx - yy) + xy * xy).sqrt();
    let (l1, l2) = ((mean + r).max(0.0), (mean - r).max(0.0));
    if r < 1e-300 {
        return [l1, l1, 0.0];
    }
    // Eigenvector of l1: (xy, l1 - xx) or (l1 - yy, xy), whichever is better conditioned.
    let (ex, ey) = if (mean + r - xx).abs() > (mean + r - yy).abs() {
        (xy, mean + r - xx)
    } else {
        (mean + r - yy, xy)
    };
    let n = (ex * ex + ey * ey).sqrt();
    let (cx, cy) = (ex / n, ey / n);
    [
        l1 * cx * cx + l2 * cy * cy,
        l1 * cy * cy + l2 * cx * cx,
        (l1 - l2) * cx * cy,
    ]
}

fn v3(t: [f32; 4]) -> DVec3 {
    DVec3::new(t[0] as f64, t[1] as f64, t[2] as f64)
}

/// Decodes a vMF lobe texel `θ = (α, α·r)` as Algorithm 2 lines 7–10 do: `(α, μ, κ)` with
/// `|r|` clamped to `r_max`, or `None` for an empty lobe (`α ≤ 0`: line 8 would divide by 0).
/// A zero `r` is the uniform lobe (κ = 0, μ = +Z).
pub fn vmf_decode(theta: [f32; 4], r_max: f64) -> Option<(f64, DVec3, f64)> {
    let alpha = theta[0] as f64;
    if alpha.is_nan() || alpha <= 0.0 {
        return None;
    }
    let r = DVec3::new(theta[1] as f64, theta[2] as f64, theta[3] as f64) / alpha;
    let len = r.length();
    if len > 0.0 && len.is_finite() {
        let rc = len.min(r_max);
        Some((alpha, r / len, (3.0 * rc - rc * rc * rc) / (1.0 - rc * rc)))
    } else {
        Some((alpha, DVec3::Z, 0.0))
    }
}

/// One vMF lobe of Algorithm 2 (lines 7–14) from its texel `θ = (α, α·r)`, for light `l`, half
/// vector `h`, Blinn-Phong exponent `s`, with `|r|` clamped to `r_max` (the storage format's,
/// [`crate::vmf::r_max`]) before κ is computed:
/// `r = θ.yzw/α`, `κ = (3|r| − |r|³)/(1 − |r|²)`, `μ = r/|r|`, `s' = κs/(κ+s)` (eq 20),
/// `B_s = (s'+1)/(2π)(ω_h·μ)^{s'}`; diffuse `α(ω_i·μ)`, specular `α B_s (ω_i·μ)`.
/// **Guard**: a lobe with `α ≤ 0` (empty, or quantized to 0) contributes nothing — line 8's
/// `θ.yzw/α` would be 0/0 = NaN. A zero `r` (κ = 0) is a uniform lobe: `s' = 0`, μ = +Z.
pub fn vmf_lobe(theta: [f32; 4], l: DVec3, h: DVec3, s: f64, r_max: f64) -> Shading {
    let Some((alpha, mu, kappa)) = vmf_decode(theta, r_max) else {
        return Shading::default();
    };
    let s_eff = if kappa + s > 0.0 {
        kappa * s / (kappa + s)
    } else {
        0.0
    };
    let cos_i = mu.dot(l).max(0.0);
    Shading {
        diffuse: alpha * cos_i,
        specular: alpha * blinn_phong(mu.dot(h), s_eff) * cos_i,
    }
}

/// Toksvig's texel decoded: the mean normal `n̄`, its direction (+Z when `n̄ = 0`) and its
/// length `|n̄|` clamped to 1.
fn toksvig_mean(texels: &[[f32; 4]]) -> (DVec3, DVec3, f64) {
    let m = v3(texels[0]);
    let len = m.length();
    let mu = if len > 1e-12 { m / len } else { DVec3::Z };
    (m, mu, len.min(1.0))
}

/// LEAN's texels decoded: mean slope `E[b]` and the slope covariance (PSD-projected).
fn lean_moments(texels: &[[f32; 4]]) -> (DVec2, [f64; 3]) {
    let (t0, t1) = (texels[0], texels[1]);
    let b = DVec2::new(t0[0] as f64, t0[1] as f64);
    let sigma = psd([
        t0[2] as f64 - b.x * b.x,
        t0[3] as f64 - b.y * b.y,
        t1[0] as f64 - b.x * b.y,
    ]);
    (b, sigma)
}

/// Olano–North's texels decoded: mean normal `E[n]`, its direction μ with tangent frame, and
/// the covariance of the normal projected on that frame (PSD-projected).
fn olano_moments(texels: &[[f32; 4]]) -> (DVec3, DVec3, (DVec3, DVec3), [f64; 3]) {
    let m = v3(texels[0]);
    let (d, o) = (texels[1], texels[2]);
    let e = |a: DVec3, b: DVec3| -> f64 {
        a.x * (d[0] as f64 * b.x + o[0] as f64 * b.y + o[1] as f64 * b.z)
            + a.y * (o[0] as f64 * b.x + d[1] as f64 * b.y + o[2] as f64 * b.z)
            + a.z * (o[1] as f64 * b.x + o[2] as f64 * b.y + d[2] as f64 * b.z)
    };
    let mu = m.try_normalize().unwrap_or(DVec3::Z);
    let (t1, t2) = tangent_frame(mu);
    (m, mu, (t1, t2), psd([e(t1, t1), e(t2, t2), e(t1, t2)]))
}

/// Filtered shading of `bake`'s method from one texel's values (`texels[i]` from texture i of
/// the bake, as [`crate::bake::Bake::texel`] returns), for light `l`, half vector `h` and
/// Blinn-Phong exponent `s` (> 0). This is the CPU twin of the method's shader; it applies the
/// clamps of the format the bake was read in ([`Bake::format`]).
pub fn shade(bake: &Bake, texels: &[[f32; 4]], l: DVec3, h: DVec3, s: f64) -> Shading {
    match bake.method {
        Method::Tan2005 => crate::tan2005::shade(&texels[..bake.lobes], l, h, s),
        Method::Vmf => {
            let r_max = crate::vmf::r_max(bake.format);
            let mut sum = Shading::default();
            for &theta in &texels[..bake.lobes] {
                let one = vmf_lobe(theta, l, h, s, r_max);
                sum.diffuse += one.diffuse;
                sum.specular += one.specular;
            }
            sum
        }
        Method::Plain => {
            let mu = v3(texels[0]).try_normalize().unwrap_or(DVec3::Z);
            reference(mu, l, h, s)
        }
        Method::Toksvig => {
            let (m, mu, ft) = toksvig_mean(texels);
            let den = ft + s * (1.0 - ft);
            let s_t = if den > 0.0 { ft * s / den } else { 0.0 };
            Shading {
                diffuse: m.dot(l).max(0.0),
                specular: blinn_phong(mu.dot(h), s_t) * mu.dot(l).max(0.0),
            }
        }
        Method::Lean => {
            let (b, sigma) = lean_moments(texels);
            let mu = DVec3::new(b.x, b.y, 1.0).normalize();
            let cos_i = mu.dot(l).max(0.0);
            let specular = if h.z > 1e-9 {
                let d = DVec2::new(h.x / h.z, h.y / h.z) - b;
                widened_lobe(mu.dot(h), d, sigma, s) * cos_i
            } else {
                0.0
            };
            Shading {
                diffuse: cos_i,
                specular,
            }
        }
        Method::Olano => {
            let (m, mu, (t1, t2), sigma) = olano_moments(texels);
            let offset = DVec2::new(h.dot(t1), h.dot(t2));
            Shading {
                diffuse: m.dot(l).max(0.0),
                specular: widened_lobe(mu.dot(h), offset, sigma, s) * mu.dot(l).max(0.0),
            }
        }
    }
}

/// The specular lobe of a BRDF: normalized Blinn-Phong with exponent `s` (eq 20's form), or the
/// Torrance–Sparrow-like Gaussian of eq 18 with roughness σ,
/// `e^{−β²/(4σ²)}/(4πσ²)` in the angle β between ω_h and the normal.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "model", rename_all = "snake_case")]
pub enum Brdf {
    /// `(s+1)/(2π)(ω_h·n)^s`, s > 0.
    BlinnPhong {
        /// The exponent.
        s: f64,
    },
    /// `e^{−β²/(4σ²)}/(4πσ²)`, σ > 0 (eq 18).
    TorranceSparrow {
        /// The roughness.
        sigma: f64,
    },
}

impl Brdf {
    /// Blinn-Phong BRDFs for each exponent in `s`.
    pub fn blinn_phong(s: &[f64]) -> Vec<Brdf> {
        s.iter().map(|&s| Brdf::BlinnPhong { s }).collect()
    }

    /// The Blinn-Phong exponent with the same angular width: `s`, or `1/(2σ²)` (eq 18 vs eq 20).
    pub fn equivalent_exponent(&self) -> f64 {
        match *self {
            Brdf::BlinnPhong { s } => s,
            Brdf::TorranceSparrow { sigma } => 0.5 / (sigma * sigma),
        }
    }
}

impl std::fmt::Display for Brdf {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Brdf::BlinnPhong { s } => write!(f, "Blinn-Phong s = {s}"),
            Brdf::TorranceSparrow { sigma } => write!(f, "Torrance-Sparrow sigma = {sigma}"),
        }
    }
}

/// The eq 18 lobe widened by an NDF covariance `cov` (angular, per axis, in the frame of
/// `dir`): a 2D Gaussian in the angle offset `d = β·dir/|dir|` with covariance `2σ²I + cov`,
/// `exp(−½ dᵀΣ⁻¹d)/(2π sqrt det Σ)`. With `cov = 0` it is exactly `e^{−β²/(4σ²)}/(4πσ²)`;
/// with `cov = I/κ` it is eq 21, `σ'² = σ² + 1/(2κ)`. Zero for `cos_h ≤ 0`.
pub fn torrance_sparrow_lobe(cos_h: f64, dir: DVec2, sigma: f64, cov: [f64; 3]) -> f64 {
    if cos_h.is_nan() || cos_h <= 0.0 {
        return 0.0;
    }
    let beta = cos_h.min(1.0).acos();
    let v = 2.0 * sigma * sigma;
    let (a, c, b) = (v + cov[0], v + cov[1], cov[2]);
    let det = (a * c - b * b).max(f64::MIN_POSITIVE);
    let len = dir.length();
    let q = if len > 1e-300 {
        let d = dir * (beta / len);
        (c * d.x * d.x - 2.0 * b * d.x * d.y + a * d.y * d.y) / det
    } else {
        // No direction: isotropic spread, use the mean variance.
        beta * beta * 2.0 / (a + c)
    };
    (-0.5 * q).exp() / (2.0 * PI * det.sqrt())
}

/// The exact shading of one unfiltered unit normal under `brdf` (the ground truth).
pub fn reference_brdf(n: DVec3, l: DVec3, h: DVec3, brdf: Brdf) -> Shading {
    match brdf {
        Brdf::BlinnPhong { s } => reference(n, l, h, s),
        Brdf::TorranceSparrow { sigma } => {
            let cos_i = n.dot(l).max(0.0);
            Shading {
                diffuse: cos_i,
                specular: torrance_sparrow_lobe(n.dot(h), DVec2::X, sigma, [0.0; 3]) * cos_i,
            }
        }
    }
}

/// [`shade`] for any [`Brdf`]: Blinn-Phong as there; Torrance–Sparrow with each method's NDF
/// spread added to the lobe's (eq 21 for vMF lobes: `σ'² = σ² + 1/(2κ)`; Toksvig's variance
/// `(1 − |n̄|)/|n̄|`; Tan's σ²; LEAN's and Olano–North's covariances), the lobe of
/// [`torrance_sparrow_lobe`].
pub fn shade_brdf(bake: &Bake, texels: &[[f32; 4]], l: DVec3, h: DVec3, brdf: Brdf) -> Shading {
    let sigma = match brdf {
        Brdf::BlinnPhong { s } => return shade(bake, texels, l, h, s),
        Brdf::TorranceSparrow { sigma } => sigma,
    };
    // One isotropic lobe around μ with per-axis angular variance `var`, weight `alpha`.
    let iso = |alpha: f64, mu: DVec3, var: f64| -> f64 {
        let (t1, t2) = tangent_frame(mu);
        let dir = DVec2::new(h.dot(t1), h.dot(t2));
        alpha * torrance_sparrow_lobe(mu.dot(h), dir, sigma, [var, var, 0.0]) * mu.dot(l).max(0.0)
    };
    match bake.method {
        Method::Vmf => {
            let r_max = crate::vmf::r_max(bake.format);
            let mut sum = Shading::default();
            for &theta in &texels[..bake.lobes] {
                if let Some((alpha, mu, kappa)) = vmf_decode(theta, r_max) {
                    let var = if kappa > 0.0 { 1.0 / kappa } else { 1e6 };
                    sum.diffuse += alpha * mu.dot(l).max(0.0);
                    sum.specular += iso(alpha, mu, var);
                }
            }
            sum
        }
        Method::Tan2005 => {
            let mut sum = Shading::default();
            for &t in &texels[..bake.lobes] {
                let g = crate::tan2005::Gaussian::from_texel(t);
                if g.is_empty() {
                    continue;
                }
                let mu = crate::tan2005::lift(g.mean);
                sum.diffuse += g.alpha * mu.dot(l).max(0.0);
                sum.specular += iso(g.alpha, mu, g.variance.max(0.0));
            }
            sum
        }
        Method::Plain => {
            let mu = v3(texels[0]).try_normalize().unwrap_or(DVec3::Z);
            reference_brdf(mu, l, h, brdf)
        }
        Method::Toksvig => {
            let (m, mu, ft) = toksvig_mean(texels);
            let var = if ft > 0.0 { (1.0 - ft) / ft } else { 1e6 };
            Shading {
                diffuse: m.dot(l).max(0.0),
                specular: iso(1.0, mu, var),
            }
        }
        Method::Lean => {
            let (b, cov) = lean_moments(texels);
            let mu = DVec3::new(b.x, b.y, 1.0).normalize();
            let cos_i = mu.dot(l).max(0.0);
            let dir = if h.z > 1e-9 {
                DVec2::new(h.x / h.z, h.y / h.z) - b
            } else {
                DVec2::ZERO
            };
            Shading {
                diffuse: cos_i,
                specular: torrance_sparrow_lobe(mu.dot(h), dir, sigma, cov) * cos_i,
            }
        }
        Method::Olano => {
            let (m, mu, (t1, t2), cov) = olano_moments(texels);
            let dir = DVec2::new(h.dot(t1), h.dot(t2));
            Shading {
                diffuse: m.dot(l).max(0.0),
                specular: torrance_sparrow_lobe(mu.dot(h), dir, sigma, cov) * mu.dot(l).max(0.0),
            }
        }
    }
}

/// Shading per colour channel: the Lambert and specular terms as RGB.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ShadingRgb {
    /// Σ weight · max(ω_i·μ, 0) per channel.
    pub diffuse: DVec3,
    /// Σ weight · lobe · max(ω_i·μ, 0) per channel.
    pub specular: DVec3,
}

/// One mixture component of a texel, decoded and shaded with unit weight under `brdf`:
/// `(α, max(ω_i·μ, 0), lobe · max(ω_i·μ, 0))`, or `None` for an empty component. The terms of
/// [`shade_brdf`]'s vMF and Tan 2005 arms before they are weighted by α.
fn mixture_component(
    bake: &Bake,
    texel: [f32; 4],
    l: DVec3,
    h: DVec3,
    brdf: Brdf,
) -> Option<(f64, f64, f64)> {
    let (alpha, mu, var, s_eff) = match bake.method {
        Method::Vmf => {
            let (alpha, mu, kappa) = vmf_decode(texel, crate::vmf::r_max(bake.format))?;
            let var = if kappa > 0.0 { 1.0 / kappa } else { 1e6 };
            let s = brdf.equivalent_exponent();
            let s_eff = if kappa + s > 0.0 {
                kappa * s / (kappa + s)
            } else {
                0.0
            };
            (alpha, mu, var, s_eff)
        }
        Method::Tan2005 => {
            let g = crate::tan2005::Gaussian::from_texel(texel);
            if g.is_empty() {
                return None;
            }
            let var = g.variance.max(0.0);
            let s = brdf.equivalent_exponent();
            (
                g.alpha,
                crate::tan2005::lift(g.mean),
                var,
                s / (1.0 + s * var),
            )
        }
        _ => return None,
    };
    let cos_i = mu.dot(l).max(0.0);
    let lobe = match brdf {
        Brdf::BlinnPhong { .. } => blinn_phong(mu.dot(h), s_eff),
        Brdf::TorranceSparrow { sigma } => {
            let (t1, t2) = tangent_frame(mu);
            let dir = DVec2::new(h.dot(t1), h.dot(t2));
            torrance_sparrow_lobe(mu.dot(h), dir, sigma, [var, var, 0.0])
        }
    };
    Some((alpha, cos_i, lobe * cos_i))
}

/// [`shade_brdf`] per colour channel. With `color`, a mixture bake's lobe j is weighted by its
/// colour texture `α·y` (texture `lobes + j`) instead of α — Algorithm 2 line 14,
/// `ρ += αy (K_s B + K_d)(ω_i·μ)` with the two terms apart; otherwise every channel is the
/// scalar result. The CPU twin of the shaders' `NDF_COLOR` variant. `color` on a bake without
/// colour textures is a programming error and panics.
pub fn shade_rgb(
    bake: &Bake,
    texels: &[[f32; 4]],
    l: DVec3,
    h: DVec3,
    brdf: Brdf,
    color: bool,
) -> ShadingRgb {
    if !color {
        let s = shade_brdf(bake, texels, l, h, brdf);
        return ShadingRgb {
            diffuse: DVec3::splat(s.diffuse),
            specular: DVec3::splat(s.specular),
        };
    }
    assert!(
        bake.lobes > 0 && texels.len() >= 2 * bake.lobes,
        "colour shading needs a mixture bake with colour textures"
    );
    let mut sum = ShadingRgb::default();
    for j in 0..bake.lobes {
        if let Some((_, cos_i, spec)) = mixture_component(bake, texels[j], l, h, brdf) {
            let y = v3(texels[bake.lobes + j]);
            sum.diffuse += y * cos_i;
            sum.specular += y * spec;
        }
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blinn_phong_is_normalized_over_the_hemisphere() {
        // ∫ (s+1)/(2π) cos^s θ cos θ... the normalization is for ∫ cos^s dω projected: check
        // ∫_hemisphere (s+1)/(2π) cos^s θ sin θ dθ dφ = (s+1)/(s+1) = 1.
        for s in [1.0, 8.0, 64.0, 1000.0] {
            let n = 20000;
            let mut sum = 0.0;
            for i in 0..n {
                let t = (i as f64 + 0.5) / n as f64 * PI / 2.0;
                sum += blinn_phong(t.cos(), s) * t.sin() * (PI / 2.0 / n as f64) * 2.0 * PI;
            }
            assert!((sum - 1.0).abs() < 1e-3, "s={s} integral={sum}");
        }
    }

    #[test]
    fn widened_lobe_with_zero_spread_is_blinn_phong() {
        for s in [1.0, 32.0, 1e6] {
            for (c, d) in [
                (0.9, DVec2::new(0.3, -0.1)),
                (1.0, DVec2::ZERO),
                (0.2, DVec2::new(0.0, 2.0)),
            ] {
                let a = widened_lobe(c, d, [0.0; 3], s);
                let b = blinn_phong(c, s);
                assert!(
                    (a - b).abs() <= 1e-12 * b.max(1e-300) + 1e-300,
                    "s={s} {a} {b}"
                );
            }
        }
    }

    #[test]
    fn widened_lobe_of_isotropic_spread_is_toksvig_like() {
        // Σ = σ² I → S = I/(1/s + σ²) → exponent and normalization of s' = s/(1 + s σ²).
        let (s, var) = (100.0, 0.01);
        let sp = s / (1.0 + s * var);
        let a = widened_lobe(0.95, DVec2::new(0.2, 0.1), [var, var, 0.0], s);
        assert!((a - blinn_phong(0.95, sp)).abs() < 1e-12);
    }

    #[test]
    fn psd_keeps_psd_and_clamps_negative_eigenvalues() {
        let m = [2.0, 1.0, 0.5];
        let p = psd(m);
        for k in 0..3 {
            assert!((p[k] - m[k]).abs() < 1e-12);
        }
        let p = psd([1.0, 1.0, 2.0]); // eigenvalues 3 and -1
        assert!(
            (p[0] * p[1] - p[2] * p[2]).abs() < 1e-12,
            "rank 1 after clamping"
        );
        assert!((p[0] - 1.5).abs() < 1e-12 && (p[2] - 1.5).abs() < 1e-12);
    }

    #[test]
    fn torrance_sparrow_lobe_is_eq_18_and_widens_by_eq_21() {
        for sigma in [0.05, 0.2, 0.5] {
            for beta in [0.0f64, 0.1, 0.4] {
                let want =
                    (-beta * beta / (4.0 * sigma * sigma)).exp() / (4.0 * PI * sigma * sigma);
                let got = torrance_sparrow_lobe(beta.cos(), DVec2::new(0.3, 0.7), sigma, [0.0; 3]);
                assert!(
                    (got - want).abs() <= 1e-12 * want,
                    "σ={sigma} β={beta}: {got} vs {want}"
                );
                // eq 21: an isotropic NDF variance 1/κ per axis gives σ'² = σ² + 1/(2κ).
                let kappa = 40.0;
                let s2 = (sigma * sigma + 0.5 / kappa).sqrt();
                let want = (-beta * beta / (4.0 * s2 * s2)).exp() / (4.0 * PI * s2 * s2);
                let got = torrance_sparrow_lobe(
                    beta.cos(),
                    DVec2::X,
                    sigma,
                    [1.0 / kappa, 1.0 / kappa, 0.0],
                );
                assert!((got - want).abs() <= 1e-12 * want);
            }
        }
        assert_eq!(torrance_sparrow_lobe(-0.1, DVec2::X, 0.1, [0.0; 3]), 0.0);
    }

    #[test]
    fn colour_shading_with_white_albedo_is_the_scalar_shading() {
        // y = 1 everywhere: every lobe's α·y is α, so Algorithm 2 line 14 with colour equals the
        // uncoloured sum, for both methods and both BRDFs.
        let sample = crate::procedural::generate(16, 5);
        let white = vec![[1.0f32; 4]; sample.albedo.len()];
        let map = sample.map.with_feature(white).unwrap();
        let opts = crate::bake::BakeOptions {
            lobes: 3,
            ..Default::default()
        };
        let (l, h) = (
            DVec3::new(0.2, -0.3, 0.93).normalize(),
            DVec3::new(0.1, 0.05, 1.0).normalize(),
        );
        for method in [Method::Vmf, Method::Tan2005] {
            let b = crate::bake::bake_with(&map, method, &opts).unwrap();
            for brdf in [
                Brdf::BlinnPhong { s: 50.0 },
                Brdf::TorranceSparrow { sigma: 0.2 },
            ] {
                for level in [0, 2] {
                    let t = b.texel(level, 1, 1);
                    let c = shade_rgb(&b, &t, l, h, brdf, true);
                    let g = shade_brdf(&b, &t, l, h, brdf);
                    for k in 0..3 {
                        assert!((c.diffuse[k] - g.diffuse).abs() < 1e-6, "{method} {brdf}");
                        let tol = 1e-6 * g.specular.max(1.0);
                        assert!((c.specular[k] - g.specular).abs() < tol, "{method} {brdf}");
                    }
                }
            }
        }
    }

    #[test]
    fn tangent_frame_is_orthonormal() {
        for n in [
            DVec3::Z,
            -DVec3::Z,
            DVec3::new(0.3, -0.4, 0.2).normalize(),
            DVec3::X,
        ] {
            let (t, b) = tangent_frame(n);
            assert!(t.dot(b).abs() < 1e-12 && t.dot(n).abs() < 1e-12 && b.dot(n).abs() < 1e-12);
            assert!((t.length() - 1.0).abs() < 1e-12 && (b.length() - 1.0).abs() < 1e-12);
        }
    }
}
