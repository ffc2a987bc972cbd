//! Each method's filtered shading from its baked texels: the CPU twin of the shaders, under the
//! BRDFs of [`crate::brdf`] (a Lambert term and a specular lobe, returned apart).
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
//!   of ω_h from μ ([`crate::brdf::widened_lobe`]). With Σ = 0 this is `(s+1)/(2π)(ω_h·μ)^s`.
//!   LEAN's own paper evaluates a Beckmann-like Gaussian instead, which differs from
//!   Blinn-Phong by O(1/s) even unfiltered.

use crate::bake::{Bake, Method};
use crate::brdf::tabulated::lookup;
use crate::brdf::{
    Brdf, Ggx, Shading, blinn_phong, clamp_eigenvalues, ggx, ggx_aniso, psd, reference,
    tangent_frame, torrance_sparrow_lobe, widened_lobe,
};
use glam::{DMat3, DVec2, DVec3};

fn v3(t: [f32; 4]) -> DVec3 {
    DVec3::new(t[0] as f64, t[1] as f64, t[2] as f64)
}

/// A vMF lobe texel decoded as the shader decodes it ([`vmf_decode`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VmfTexel {
    /// The lobe's weight α.
    pub alpha: f64,
    /// Its direction μ (+Z for a zero `r`).
    pub mu: DVec3,
    /// Its variance `1/κ` from the clamped `|r|` ([`crate::vmf::inverse_kappa`]; 10⁶ for a zero
    /// `r`, the uniform lobe).
    pub var: f64,
    /// `|r|` before the clamp (what the mean-vector diffuse term uses).
    pub r_len: f64,
}

/// Decodes a vMF lobe texel `θ = (α, α·r)` as Algorithm 2 lines 7–10 do, in the shader's
/// order: `μ = θ.yzw/|θ.yzw|`, `|r| = |θ.yzw|/α` clamped to `r_max`, `1/κ` from it without
/// cancellation ([`crate::vmf::inverse_kappa`]). `None` for a lobe to skip: `α ≤ alpha_min`
/// (empty — line 8 would divide by 0 —, quantized away, or below the storage format's
/// resolution, [`crate::vmf::alpha_min`]; NaN too). A zero `r` is the uniform lobe (μ = +Z).
pub fn vmf_decode(theta: [f32; 4], r_max: f64, alpha_min: f64) -> Option<VmfTexel> {
    let alpha = theta[0] as f64;
    if alpha.is_nan() || alpha <= alpha_min.max(0.0) {
        return None;
    }
    let m = DVec3::new(theta[1] as f64, theta[2] as f64, theta[3] as f64);
    let len = m.length();
    Some(if len > 0.0 && len.is_finite() {
        let r_len = len / alpha;
        VmfTexel {
            alpha,
            mu: m / len,
            var: crate::vmf::inverse_kappa(r_len.min(r_max)),
            r_len,
        }
    } else {
        VmfTexel {
            alpha,
            mu: DVec3::Z,
            var: UNIFORM_VARIANCE,
            r_len: 0.0,
        }
    })
}

/// The variance a uniform lobe (κ = 0) is shaded with: large enough that every widening rule
/// gives the flattest lobe it has (the shaders use the same constant).
const UNIFORM_VARIANCE: f64 = 1e6;

/// Eq 20's widened exponent `s' = κs/(κ + s)` of a vMF lobe with clamped mean resultant length
/// `r` (≤ the format's [`crate::vmf::r_max`]), in the form the shaders evaluate (issue 14 item 6,
/// `glsl/ndf_vmf.glsl`): with `1/κ = N/D`, `N = (1 − r)(1 + r)`, `D = r(3 − r²)`
/// ([`crate::vmf::inverse_kappa`], no cancellation in `1 − r²`), `s' = s/(1 + sN/D) = sD/(D + sN)`,
/// one division and no `1/κ` or `s/κ` to cancel; `D` is raised to `10⁻⁶N`, the uniform lobe's
/// bound `1/κ ≤ 10⁶` ([`crate::vmf::inverse_kappa`]'s clamp), so `r ≤ 0` or NaN (κ = 0) gives
/// `s/(1 + 10⁶s)`. Equal to `s/(1 + s·inverse_kappa(r))` up to rounding. (The shaders scale `N`
/// and `D` by `α³` so that they need no `|r| = |αr|/α`; the ratio is the same.)
pub fn eq20_exponent(s: f64, r: f64) -> f64 {
    let r = if r > 0.0 { r } else { 0.0 };
    let n = (1.0 - r) * (1.0 + r);
    let d = (r * (3.0 - r * r)).max(UNIFORM_VARIANCE.recip() * n);
    s * d / (d + s * n)
}

/// One vMF lobe of Algorithm 2 (lines 7–14) from its texel `θ = (α, α·r)`, for light `l`, half
/// vector `h`, Blinn-Phong exponent `s`, with `|r|` clamped to `r_max` (the storage format's,
/// [`crate::vmf::r_max`]) before κ is computed ([`vmf_decode`], every α > 0 kept):
/// the specular lobe by the default rule, eq 20 ([`VmfSpecular::Eq20`]):
/// `s' = κs/(κ+s)` computed as the shaders do ([`eq20_exponent`]), `B_s = (s'+1)/(2π)(ω_h·μ)^{s'}`
/// ([`vmf_lobe_with`] takes the closed-form convolution, [`VmfSpecular::Convolved`], too);
/// diffuse `α(ω_i·μ)`, specular `α B_s (ω_i·n_p)` with the cosine at the product lobe's centre
/// ([`VmfCosine::Product`], the default; [`specular_cosine`] with η = s + 1).
/// **Guard**: a lobe with `α ≤ 0` (empty, or quantized to 0) contributes nothing — line 8's
/// `θ.yzw/α` would be 0/0 = NaN. A zero `r` (κ = 0) is a uniform lobe.
pub fn vmf_lobe(theta: [f32; 4], l: DVec3, h: DVec3, s: f64, r_max: f64) -> Shading {
    vmf_lobe_with(theta, l, h, s, r_max, VmfSpecular::default())
}

/// [`vmf_lobe`] with the specular rule `rule`.
pub fn vmf_lobe_with(
    theta: [f32; 4],
    l: DVec3,
    h: DVec3,
    s: f64,
    r_max: f64,
    rule: VmfSpecular,
) -> Shading {
    let Some(t) = vmf_decode(theta, r_max, 0.0) else {
        return Shading::default();
    };
    let cos_i = t.mu.dot(l).max(0.0);
    let brdf = Brdf::BlinnPhong { s };
    let lobe = match rule {
        VmfSpecular::Auto | VmfSpecular::Eq20 => {
            blinn_phong(t.mu.dot(h), eq20_exponent(s, t.r_len.min(r_max)))
        }
        _ => rule.lobe(t.mu.dot(h), s, t.var),
    };
    Shading {
        diffuse: t.alpha * cos_i,
        specular: t.alpha * lobe * specular_cosine(t.mu, t.var, h, l, cosine_eta(&brdf)),
    }
}

/// How a vMF lobe widens the Blinn-Phong lobe `(s+1)/(2π)(n·ω_h)^s` (Algorithm 2 lines
/// 12–13), and with [`VmfSpecular::Convolved`] also the GGX lobe: the specular term of every
/// vMF evaluation under Blinn-Phong (point lights; the
/// environment light's prefiltered lookups keep eq 20's `s'`, module `envlight`). The other
/// methods keep their published rules.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum VmfSpecular {
    /// The default: the rule recommended for each BRDF. Under Blinn-Phong (and eq 18, tabulated
    /// BRDFs) the same as [`VmfSpecular::Eq20`]; under GGX the exact convolution of GGX's D
    /// written as a fitted mixture of vMF lobes ([`crate::brdf::ggx_mixture::GgxMixture`]:
    /// `Σ_k w_k P(κ)P(η_k)/P(R_k) e^{R_k−κ−η_k}`), which follows eq 14 where no single GGX lobe
    /// can (`docs/pbr.md`, "vMF J = 6 under GGX: the mixture rule (H17t)"). The shaders'
    /// default (no define; `NDF_VMF_SPECULAR_EQ20` selects the single widened GGX lobe).
    #[default]
    Auto,
    /// Eq 20 as published: `s' = κs/(κ+s)` (for a vMF texel as [`eq20_exponent`]; given
    /// only `1/κ`, as `s/(1 + s/κ)`), `B = (s'+1)/(2π)(ω_h·μ)^{s'}`.
    /// Overshoots the exact convolution (eq 14) at the peak by `≈ s/(κ+s)·…`: 6 % at κ = 20,
    /// 12 % at κ = 10 (s = 32), and falls short in the tail (`docs/baker.md`). The default:
    /// the cheapest rule in the shaders, and on real maps closer than
    /// [`VmfSpecular::Convolved`] at s = 256 and 2048, farther at s = 32 (`docs/baker.md`).
    /// Under GGX, chosen explicitly, the one widened GGX lobe `α'² = α² + c/κ`
    /// ([`crate::brdf::Ggx::widened`]; the GGX default before H17t, kept for comparison).
    Eq20,
    /// The closed-form vMF ⊛ Blinn-Phong lobe ([`crate::vmf::blinn_phong_convolved`]): within
    /// 0.5 % of eq 14 up to one lobe width from μ. Opt-in (`--vmf-specular convolved`); the
    /// shaders' `NDF_VMF_SPECULAR_CONVOLVED`. Under GGX it selects the peak-matched widening
    /// [`crate::brdf::Ggx::widened_vmf`] (`α'² = α² + c·m(κα²/2)/κ`, m from 1 to 2: at c = 2
    /// the peak of the exact vMF ⊛ GGX convolution) in place of `α'² = α² + c/κ`
    /// ([`crate::brdf::Ggx::widened`]); `docs/pbr.md` has what each gives on the maps.
    Convolved,
    /// Eq 14 by quadrature ([`crate::brdf::convolution::convolve_vmf`]): the exact
    /// convolution, the bound on what any rule can give. CPU only (a few hundred Bessel-function
    /// evaluations per lobe: for measurements, `ndfmap eval --vmf-specular exact`); no shader
    /// has it.
    Exact,
}

impl VmfSpecular {
    /// The widened Blinn-Phong lobe (without the cosine) at `ω_h·μ = c` for exponent `s` and a
    /// vMF lobe of variance `var = 1/κ` (`var = 0`: κ = ∞, the lobe itself).
    pub fn lobe(self, c: f64, s: f64, var: f64) -> f64 {
        match self {
            VmfSpecular::Auto | VmfSpecular::Eq20 => blinn_phong(c, s / (1.0 + s * var)),
            VmfSpecular::Convolved => {
                let kappa = if var > 0.0 { 1.0 / var } else { f64::INFINITY };
                crate::vmf::blinn_phong_convolved(c, s, kappa)
            }
            VmfSpecular::Exact => {
                let kappa = if var > 0.0 { 1.0 / var } else { f64::INFINITY };
                exact_convolution(c, s, kappa)
            }
        }
    }

    /// The name used on the command line.
    pub fn name(self) -> &'static str {
        match self {
            VmfSpecular::Auto => "auto",
            VmfSpecular::Eq20 => "eq20",
            VmfSpecular::Convolved => "convolved",
            VmfSpecular::Exact => "exact",
        }
    }
}

/// `I₀ₑ(x) = e^{−x} I₀(x)` by Abramowitz & Stegun 9.8.1–9.8.2 (relative error below 2·10⁻⁷):
/// the fast Bessel function of [`exact_convolution`] (a measurement; the full-precision one is
/// `brdf::convolution::bessel_i0e`).
fn bessel_i0e_fast(x: f64) -> f64 {
    let x = x.max(0.0);
    if x <= 3.75 {
        let t = (x / 3.75) * (x / 3.75);
        let p = 1.0
            + t * (3.5156229
                + t * (3.0899424
                    + t * (1.2067492 + t * (0.2659732 + t * (0.0360768 + t * 0.0045813)))));
        p * (-x).exp()
    } else {
        let t = 3.75 / x;
        let p = 0.39894228
            + t * (0.01328592
                + t * (0.00225319
                    + t * (-0.00157565
                        + t * (0.00916281
                            + t * (-0.02057706
                                + t * (0.02635537 + t * (-0.01647633 + t * 0.00392377)))))));
        p / x.sqrt()
    }
}

/// Eq 14 for one vMF lobe under the Blinn-Phong lobe `(s+1)/(2π)(n·ω_h)^s`, by quadrature, at
/// `ω_h·μ = c`: `∫ B(β) sin β · 2π C(κ) e^{κ(cos(θ−β)−1)} I₀ₑ(κ sin θ sin β) dβ` over the polar
/// angle β of n from ω_h (the azimuth in closed form, as `brdf::convolution::convolve_vmf`),
/// restricted to where both factors exceed `e^{−46}` of their peaks — `cos^s β > e^{−46}` and
/// `2κ sin²((θ−β)/2) < 46` — and integrated there with 32 8-point Gauss–Legendre panels (at
/// most 0.3 of the Blinn-Phong lobe's width and 0.6 of the vMF lobe's each). Agrees with
/// `convolve_vmf` to 10⁻⁵ (test below) at a third of its cost: what `VmfSpecular::Exact` uses.
fn exact_convolution(c: f64, s: f64, kappa: f64) -> f64 {
    use std::f64::consts::PI;
    if kappa.is_infinite() {
        return blinn_phong(c, s);
    }
    if !crate::vmf::is_positive(kappa) {
        // The uniform lobe: the Blinn-Phong lobe's unit mass over the sphere's 4π.
        return 1.0 / (4.0 * PI);
    }
    let theta = c.clamp(-1.0, 1.0).acos();
    let beta_s = if s > 0.0 {
        (-46.0 / s).exp().acos().min(0.5 * PI)
    } else {
        0.5 * PI
    };
    let x = 23.0 / kappa;
    let delta = if x >= 1.0 { PI } else { 2.0 * x.sqrt().asin() };
    let (lo, hi) = ((theta - delta).max(0.0), (theta + delta).min(beta_s));
    if !crate::vmf::is_positive(hi - lo) {
        return 0.0;
    }
    let norm = 2.0 * PI * kappa / (2.0 * PI * -(-2.0 * kappa).exp_m1());
    let (st, panels) = (theta.sin(), 32);
    let step = (hi - lo) / panels as f64;
    let mut sum = 0.0;
    for p in 0..panels {
        let mid = lo + (p as f64 + 0.5) * step;
        for (xi, wi) in GL8_X.iter().zip(GL8_W) {
            let beta = mid + 0.5 * step * xi;
            let half = (0.5 * (theta - beta)).sin();
            let ring =
                (-2.0 * kappa * half * half).exp() * bessel_i0e_fast(kappa * st * beta.sin());
            sum += wi * blinn_phong(beta.cos(), s) * beta.sin() * ring;
        }
    }
    0.5 * step * norm * sum
}

/// The 8-point Gauss–Legendre nodes and weights on [−1, 1].
const GL8_X: [f64; 8] = [
    -0.960_289_856_497_536_3,
    -0.796_666_477_413_626_7,
    -0.525_532_409_916_329,
    -0.183_434_642_495_649_8,
    0.183_434_642_495_649_8,
    0.525_532_409_916_329,
    0.796_666_477_413_626_7,
    0.960_289_856_497_536_3,
];
const GL8_W: [f64; 8] = [
    0.101_228_536_290_376_26,
    0.222_381_034_453_374_47,
    0.313_706_645_877_887_3,
    0.362_683_783_378_362,
    0.362_683_783_378_362,
    0.313_706_645_877_887_3,
    0.222_381_034_453_374_47,
    0.101_228_536_290_376_26,
];

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
/// the covariance of the normal projected on that frame (PSD-projected). Also the
/// environment routes' decoding of an Olano–North texel (`envlight`).
pub(crate) fn olano_moments(texels: &[[f32; 4]]) -> (DVec3, DVec3, (DVec3, DVec3), [f64; 3]) {
    let m = v3(texels[0]);
    let second = olano_second_moment(texels);
    let e = |a: DVec3, b: DVec3| a.dot(second * b);
    let mu = m.try_normalize().unwrap_or(DVec3::Z);
    let (t1, t2) = tangent_frame(mu);
    (m, mu, (t1, t2), psd([e(t1, t1), e(t2, t2), e(t1, t2)]))
}

/// Olano–North's `E[nnᵀ]` from its texels: the diagonal `(xx, yy, zz)` in texture 1, the
/// off-diagonal `(xy, xz, yz)` in texture 2 (DESIGN.md "Texture layouts").
pub(crate) fn olano_second_moment(texels: &[[f32; 4]]) -> DMat3 {
    let (d, o) = (texels[1].map(f64::from), texels[2].map(f64::from));
    DMat3::from_cols_array(&[d[0], o[0], o[1], o[0], d[1], o[2], o[1], o[2], d[2]])
}

/// Which diffuse term a vMF lobe contributes (Algorithm 2 line 14's cosine).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum VmfDiffuse {
    /// Algorithm 2 as written: `α max(ω_i·μ, 0)` — the lobe's whole weight at its centre's
    /// cosine, dropping `|r|`.
    Algorithm2,
    /// `max(ω_i·αr, 0) = α|r| max(ω_i·μ, 0)`: the footprint average of `ω_i·n` over the lobe's
    /// normals, exact where none of them faces away from the light. The default: lower Lambert
    /// error on every shared map measured (J = 6, levels ≥ 1: rock 0.77 % against 2.44 %, bark
    /// 0.08 % against 0.49 %, facade 0.25 % against 0.70 %; `docs/sh-brdf.md`).
    #[default]
    MeanVector,
}

/// Where a vMF lobe's specular term takes its cosine of incidence (Algorithm 2 line 14's
/// `ω_i·μ`) under Blinn-Phong and GGX.
///
/// The exact term of one lobe is `∫ γ(n) ρ(n·ω_h) max(n·ω_i, 0) dn`, and the BRDF lobe picks
/// the normals near `ω_h` out of the NDF lobe γ: the cosine that matters is the one at the
/// centre of their product, not at μ. With the BRDF lobe written as a vMF lobe of concentration
/// η about `ω_h` (Blinn-Phong `η = s + 1`, as [`crate::vmf::blinn_phong_convolved`] writes it;
/// GGX the Blinn-Phong lobe of the same peak, `η = max(2/α² − 2, 1) + 1`), the product of two
/// vMF lobes is a vMF lobe about `normalize(κμ + ηω_h) = normalize(μ + (η/κ)ω_h)`, which needs
/// no division by `1/κ` ([`specular_cosine`]). κ = ∞ gives μ (level 0 and flat maps keep
/// Algorithm 2's cosine exactly); κ → 0 gives `ω_h`. On rock (J = 6, levels 4–8) the mean
/// texel-space error at s = 32 falls 22 % with eq 20 and 51 % with the closed-form convolution
/// (`docs/baker.md`, "The specular cosine"). Other BRDFs (eq 18, tabulated) keep Algorithm 2's.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum VmfCosine {
    /// The default: `max(n_p·ω_i, 0)` at the product lobe's centre
    /// `n_p = normalize(μ + (η/κ)ω_h)` ([`specular_cosine`]; GLSL: the same in
    /// `glsl/ndf_vmf.glsl`).
    #[default]
    Product,
    /// Algorithm 2 line 14 as written: `max(ω_i·μ, 0)` for the specular term too
    /// (`NDF_VMF_COSINE_ALG2`).
    Algorithm2,
}

/// The concentration η of `brdf`'s specular lobe written as a vMF lobe about `ω_h`, for
/// [`VmfCosine::Product`]: Blinn-Phong `s + 1`, GGX `max(2/α² − 2, 1) + 1` (the Blinn-Phong
/// lobe of GGX's peak, [`Brdf::equivalent_exponent`]); 0 (the cosine at μ) for the other
/// BRDFs. GLSL: `ndf_cosine_eta`.
pub fn cosine_eta(brdf: &Brdf) -> f64 {
    match brdf {
        Brdf::BlinnPhong { .. } | Brdf::Ggx(_) => brdf.equivalent_exponent() + 1.0,
        _ => 0.0,
    }
}

/// The specular term's cosine of incidence for a vMF lobe about μ of variance `var = 1/κ` under a
/// BRDF lobe of concentration `eta` about `h` ([`VmfCosine::Product`]): `max(n_p·l, 0)` with
/// `n_p = normalize(μ + η·var·h)`, the centre of the two lobes' product. `var = 0` (κ = ∞) or
/// `eta = 0` is μ's cosine; a vanishing `|μ + η·var·h|` (only for `h = −μ`, where the BRDF
/// lobe is 0 anyway) gives 0, as in the shaders (`max(|v|², 10⁻³⁰)`).
pub fn specular_cosine(mu: DVec3, var: f64, h: DVec3, l: DVec3, eta: f64) -> f64 {
    let v = mu + (eta * var.max(0.0)) * h;
    (v.dot(l) / v.length_squared().max(1e-30).sqrt()).max(0.0)
}

/// Shading choices that are not part of the BRDF (the shaders' matching `#define`s are in
/// `glsl::ShaderOptions`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ShadeOptions {
    /// The vMF lobes' diffuse term.
    pub vmf_diffuse: VmfDiffuse,
    /// Where the vMF lobes' specular term takes its cosine of incidence.
    pub vmf_cosine: VmfCosine,
    /// The vMF lobes' specular rule under Blinn-Phong.
    pub vmf_specular: VmfSpecular,
    /// The SH texels' diffuse term.
    pub sh_diffuse: crate::sh::ShDiffuse,
}

/// Filtered shading of `bake`'s method from one texel's values (`texels[i]` from texture i of
/// the bake, as [`crate::bake::Bake::texel`] returns), for light `l`, half vector `h` and
/// Blinn-Phong exponent `s` (> 0): [`shade_brdf`] with `Brdf::BlinnPhong { s }`.
pub fn shade(bake: &Bake, texels: &[[f32; 4]], l: DVec3, h: DVec3, s: f64) -> Shading {
    shade_brdf(bake, texels, l, h, &Brdf::BlinnPhong { s })
}

/// [`shade_with`] with the default [`ShadeOptions`].
pub fn shade_brdf(bake: &Bake, texels: &[[f32; 4]], l: DVec3, h: DVec3, brdf: &Brdf) -> Shading {
    shade_with(bake, texels, l, h, brdf, &ShadeOptions::default())
}

/// Filtered shading of `bake`'s method from one texel's values under any [`Brdf`]: the CPU
/// twin of the method's shader, with the clamps of the format the bake was read in
/// ([`Bake::format`]). Each method's NDF estimate widens the BRDF's lobe by that BRDF's rule:
/// - Blinn-Phong: for vMF lobes [`ShadeOptions::vmf_specular`] (default eq 20's
///   `s' = κs/(κ+s)`; the closed-form convolution, [`crate::vmf::blinn_phong_convolved`], on
///   request), Toksvig's and Tan's `s' = s/(1+sσ²)`,
///   LEAN's and Olano–North's covariance ([`widened_lobe`]);
/// - eq 18: eq 21 for vMF lobes (`σ'² = σ² + 1/(2κ)`), the variance or covariance added to the
///   lobe's ([`torrance_sparrow_lobe`]);
/// - GGX: `α'² = α² + c·v` for a per-axis angular variance v (1/κ for vMF lobes, Toksvig's
///   `(1 − |n̄|)/|n̄|`, Tan's σ²), and `S = α²I + cΣ` with LEAN's slope covariance and
///   Olano–North's tangent-plane covariance ([`ggx_aniso`]);
/// - tabulated: eq 14 from the BRDF's per-κ table ([`crate::brdf::tabulated::lookup`]) at the
///   lobe's κ (`1/v` for the single-lobe baselines, `2/tr Σ` for LEAN and Olano–North: the
///   closest isotropic lobe);
/// - SH: eq 12 ([`crate::sh::shade`]), any BRDF through its `ρ̂_l`.
///
/// The specular term is then multiplied by the BRDF's g factor ([`Brdf::g`]).
pub fn shade_with(
    bake: &Bake,
    texels: &[[f32; 4]],
    l: DVec3,
    h: DVec3,
    brdf: &Brdf,
    options: &ShadeOptions,
) -> Shading {
    let mut out = match bake.method {
        Method::Sh => crate::sh::shade(
            texels,
            crate::sh::lmax_of(bake),
            l,
            h,
            brdf,
            options.sh_diffuse,
        ),
        Method::Pbr => crate::pbr::shade(texels, l, h, brdf),
        Method::Vmf | Method::Tan2005 => {
            let mut sum = Shading::default();
            for &t in &texels[..bake.lobes] {
                if let Some(c) = mixture_component(bake, t, l, h, brdf, options) {
                    sum.diffuse += c.alpha * c.diffuse;
                    sum.specular += c.alpha * c.specular;
                }
            }
            sum
        }
        method => baseline(method, texels, l, h, brdf),
    };
    if brdf.has_specular() {
        out.specular *= brdf.g(l, h);
    }
    out
}

/// The specular lobe of an isotropic NDF estimate around μ with per-axis angular variance
/// `var` under `brdf` (without the cosine and g): the widening rules of [`shade_with`] for one
/// lobe. Blinn-Phong: `s' = s/(1 + s·var)`.
fn iso_lobe(brdf: &Brdf, mu: DVec3, var: f64, h: DVec3) -> f64 {
    let c = mu.dot(h);
    match brdf {
        Brdf::Lambert => 0.0,
        Brdf::BlinnPhong { s } => blinn_phong(c, s / (1.0 + s * var)),
        Brdf::TorranceSparrow { sigma } => {
            let (t1, t2) = tangent_frame(mu);
            let dir = DVec2::new(h.dot(t1), h.dot(t2));
            torrance_sparrow_lobe(c, dir, *sigma, [var, var, 0.0])
        }
        Brdf::Ggx(g) => ggx(c, g.widened(var)),
        Brdf::Tabulated(t) => {
            let kappa = if var > 0.0 { 1.0 / var } else { f64::INFINITY };
            lookup(t.table(), mu.cross(h).length().atan2(c), kappa)
        }
    }
}

/// The single-lobe baselines (module docs) under any BRDF, without the g factor.
fn baseline(method: Method, texels: &[[f32; 4]], l: DVec3, h: DVec3, brdf: &Brdf) -> Shading {
    match method {
        Method::Plain => {
            let mu = v3(texels[0]).try_normalize().unwrap_or(DVec3::Z);
            let cos_i = mu.dot(l).max(0.0);
            let specular = match brdf {
                Brdf::BlinnPhong { s } => return reference(mu, l, h, *s),
                Brdf::TorranceSparrow { sigma } => {
                    torrance_sparrow_lobe(mu.dot(h), DVec2::X, *sigma, [0.0; 3]) * cos_i
                }
                other => iso_lobe(other, mu, 0.0, h) * cos_i,
            };
            Shading {
                diffuse: cos_i,
                specular,
            }
        }
        Method::Toksvig => {
            let (m, mu, ft) = toksvig_mean(texels);
            let specular = match brdf {
                Brdf::BlinnPhong { s } => {
                    let den = ft + s * (1.0 - ft);
                    let s_t = if den > 0.0 { ft * s / den } else { 0.0 };
                    blinn_phong(mu.dot(h), s_t)
                }
                b => {
                    let var = if ft > 0.0 { (1.0 - ft) / ft } else { 1e6 };
                    iso_lobe(b, mu, var, h)
                }
            };
            Shading {
                diffuse: m.dot(l).max(0.0),
                specular: specular * mu.dot(l).max(0.0),
            }
        }
        Method::Lean => {
            let (b, cov) = lean_moments(texels);
            let mu = DVec3::new(b.x, b.y, 1.0).normalize();
            let cos_i = mu.dot(l).max(0.0);
            let d = if h.z > 1e-9 {
                DVec2::new(h.x / h.z, h.y / h.z) - b
            } else {
                DVec2::ZERO
            };
            let lobe = match brdf {
                Brdf::BlinnPhong { s } if h.z > 1e-9 => widened_lobe(mu.dot(h), d, cov, *s),
                Brdf::BlinnPhong { .. } => 0.0,
                Brdf::TorranceSparrow { sigma } => torrance_sparrow_lobe(mu.dot(h), d, *sigma, cov),
                Brdf::Ggx(g) => {
                    // The slope offset's direction d with the length tan θ of the angle between
                    // μ and h (as the other BRDFs take only d's direction): at Σ = 0 this is
                    // GGX about μ exactly.
                    let c = mu.dot(h);
                    let len = d.length();
                    let slope = if len > 1e-300 && c > 0.0 {
                        d * (mu.cross(h).length() / c / len)
                    } else {
                        DVec2::ZERO
                    };
                    ggx_aniso(c, slope, ggx_covariance(g, cov))
                }
                other => iso_lobe(other, mu, 0.5 * (cov[0] + cov[1]), h),
            };
            Shading {
                diffuse: cos_i,
                specular: lobe * cos_i,
            }
        }
        Method::Olano => {
            let (m, mu, (t1, t2), cov) = olano_moments(texels);
            let dir = DVec2::new(h.dot(t1), h.dot(t2));
            let c = mu.dot(h);
            let lobe = match brdf {
                Brdf::BlinnPhong { s } => widened_lobe(c, dir, cov, *s),
                Brdf::TorranceSparrow { sigma } => torrance_sparrow_lobe(c, dir, *sigma, cov),
                Brdf::Ggx(g) if c > 0.0 => ggx_aniso(c, dir / c, ggx_covariance(g, cov)),
                Brdf::Ggx(_) => 0.0,
                other => iso_lobe(other, mu, 0.5 * (cov[0] + cov[1]), h),
            };
            Shading {
                diffuse: m.dot(l).max(0.0),
                specular: lobe * mu.dot(l).max(0.0),
            }
        }
        Method::Vmf | Method::Tan2005 | Method::Sh | Method::Pbr => {
            unreachable!("not a single-lobe baseline")
        }
    }
}

/// GGX's slope matrix widened by an NDF covariance: `α² I + c Σ` ([`ggx_aniso`]), its
/// eigenvalues held to at most 1 as [`Ggx::widened`] holds α'.
fn ggx_covariance(g: &Ggx, cov: [f64; 3]) -> [f64; 3] {
    let a2 = g.alpha * g.alpha;
    let s = [
        a2 + g.widening * cov[0],
        a2 + g.widening * cov[1],
        g.widening * cov[2],
    ];
    clamp_eigenvalues(s, 0.0, 1.0)
}

/// Shading per colour channel: the Lambert and specular terms as RGB.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ShadingRgb {
    /// Σ weight · max(ω_i·μ, 0) per channel.
    pub diffuse: DVec3,
    /// Σ weight · lobe · max(ω_i·μ, 0) per channel.
    pub specular: DVec3,
}

/// One mixture component of a texel, decoded and shaded with unit weight.
struct Component {
    /// Its weight α.
    alpha: f64,
    /// Diffuse term per unit weight: `max(ω_i·μ, 0)` (Algorithm 2) or `|r| max(ω_i·μ, 0)`.
    diffuse: f64,
    /// Specular lobe times `max(ω_i·μ, 0)`, without the g factor.
    specular: f64,
}

/// One mixture component of a texel (vMF lobe or Tan 2005 Gaussian), decoded and shaded with
/// unit weight under `brdf`, or `None` for an empty component: the terms of [`shade_with`]'s
/// mixture arm before they are weighted by α (or by the colour `α·y`).
/// vMF, Blinn-Phong: Algorithm 2 lines 7–14 with [`ShadeOptions::vmf_specular`]'s lobe; see
/// [`vmf_lobe`].
fn mixture_component(
    bake: &Bake,
    texel: [f32; 4],
    l: DVec3,
    h: DVec3,
    brdf: &Brdf,
    options: &ShadeOptions,
) -> Option<Component> {
    let (alpha, mu, var, s_eff, r_len) = match bake.method {
        Method::Vmf => {
            let r_max = crate::vmf::r_max(bake.format);
            let t = vmf_decode(texel, r_max, crate::vmf::alpha_min(bake.format))?;
            let s = brdf.equivalent_exponent();
            // Eq 20's s' in the shaders' form (eq20_exponent), what the Blinn-Phong arm uses
            // under the default rule (auto) and eq20.
            let s_eff = eq20_exponent(s, t.r_len.min(r_max));
            (t.alpha, t.mu, t.var, s_eff, t.r_len)
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
                1.0,
            )
        }
        _ => return None,
    };
    let cos_i = mu.dot(l).max(0.0);
    // BRDFs without an η (eq 18, tabulated, Lambert) keep μ's cosine, as the shaders do.
    let eta = cosine_eta(brdf);
    let cos_s = match (bake.method, options.vmf_cosine) {
        (Method::Vmf, VmfCosine::Product) if eta > 0.0 => specular_cosine(mu, var, h, l, eta),
        _ => cos_i,
    };
    let lobe = match brdf {
        Brdf::BlinnPhong { s }
            if bake.method == Method::Vmf
                && !matches!(options.vmf_specular, VmfSpecular::Auto | VmfSpecular::Eq20) =>
        {
            options.vmf_specular.lobe(mu.dot(h), *s, var)
        }
        Brdf::BlinnPhong { .. } => blinn_phong(mu.dot(h), s_eff),
        Brdf::Ggx(g)
            if bake.method == Method::Vmf && options.vmf_specular == VmfSpecular::Convolved =>
        {
            ggx(mu.dot(h), g.widened_vmf(var))
        }
        Brdf::Ggx(g) if bake.method == Method::Vmf && options.vmf_specular == VmfSpecular::Auto => {
            crate::brdf::ggx_mixture::GgxMixture::of(g.alpha).lobe(mu, h, var, g.widening)
        }
        b => iso_lobe(b, mu, var, h),
    };
    let diffuse = match (bake.method, options.vmf_diffuse) {
        (Method::Vmf, VmfDiffuse::MeanVector) => r_len.min(1.0) * cos_i,
        _ => cos_i,
    };
    Some(Component {
        alpha,
        diffuse,
        specular: lobe * cos_s,
    })
}

/// [`shade_rgb_with`] with the default [`ShadeOptions`].
pub fn shade_rgb(
    bake: &Bake,
    texels: &[[f32; 4]],
    l: DVec3,
    h: DVec3,
    brdf: &Brdf,
    color: bool,
) -> ShadingRgb {
    shade_rgb_with(bake, texels, l, h, brdf, color, &ShadeOptions::default())
}

/// [`shade_with`] per colour channel. With `color`, a mixture bake's lobe j is weighted by its
/// colour texture `α·y` (texture `lobes + j`) instead of α — Algorithm 2 line 14,
/// `ρ += αy (K_s B + K_d)(ω_i·μ)` with the two terms apart; otherwise every channel is the
/// scalar result. The CPU twin of the shaders' `NDF_COLOR` variant. `color` on a bake without
/// colour textures is a programming error and panics.
pub fn shade_rgb_with(
    bake: &Bake,
    texels: &[[f32; 4]],
    l: DVec3,
    h: DVec3,
    brdf: &Brdf,
    color: bool,
    options: &ShadeOptions,
) -> ShadingRgb {
    if !color {
        let s = shade_with(bake, texels, l, h, brdf, options);
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
        if let Some(c) = mixture_component(bake, texels[j], l, h, brdf, options) {
            let y = v3(texels[bake.lobes + j]);
            sum.diffuse += y * c.diffuse;
            sum.specular += y * c.specular;
        }
    }
    if brdf.has_specular() {
        sum.specular *= brdf.g(l, h);
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eq20_exponent_is_kappa_s_over_kappa_plus_s() {
        // The one-division form against s/(1 + s/κ) with 1/κ from vmf::inverse_kappa, and
        // against κs/(κ + s) with Banerjee's κ where it is well conditioned; the clamps at r = 0
        // (uniform lobe, 1/κ = 1e6), r ≤ 0 and NaN.
        for s in [0.5f64, 32.0, 256.0, 2048.0, 1e5] {
            for r in [1e-9, 1e-4, 0.01, 0.3, 0.5, 0.9, 0.99, 0.999_9, 0.999_999_76] {
                let want = s / (1.0 + s * crate::vmf::inverse_kappa(r));
                let got = eq20_exponent(s, r);
                assert!(
                    (got - want).abs() <= 1e-13 * want,
                    "s={s} r={r}: {got} vs {want}"
                );
                if r > 0.01 && r < 0.999 {
                    let k = crate::vmf::kappa_banerjee(r);
                    let direct = k * s / (k + s);
                    assert!((got - direct).abs() <= 1e-12 * direct, "s={s} r={r}");
                }
            }
            for r in [0.0, -0.5, f64::NAN] {
                let want = s / (1.0 + s * 1e6);
                let got = eq20_exponent(s, r);
                assert!((got - want).abs() <= 1e-13 * want, "s={s} r={r}: {got}");
            }
        }
    }

    #[test]
    fn the_fast_exact_convolution_is_the_full_quadrature() {
        // VmfSpecular::Exact's windowed quadrature against brdf::convolution's full one.
        for s in [32.0f64, 256.0, 2048.0] {
            for kappa in [0.5, 5.0, 30.0, 300.0, 1e4, 1e6] {
                let w = (1.0 / kappa + 1.0 / s).sqrt();
                for x in [0.0, 0.7, 1.5, 3.0] {
                    let theta = (x * w).min(1.5);
                    let f = |b: f64| blinn_phong(b.cos(), s);
                    let full =
                        crate::brdf::convolution::convolve_vmf(&f, 1.0 / s.sqrt(), kappa, theta);
                    let fast = exact_convolution(theta.cos(), s, kappa);
                    let peak = blinn_phong(1.0, s);
                    assert!(
                        (fast - full).abs() <= 1e-5 * full + 1e-9 * peak,
                        "s={s} κ={kappa} θ={theta}: {fast} vs {full}"
                    );
                }
            }
        }
    }

    #[test]
    fn convolved_ggx_vmf_lobes_use_the_peak_matched_widening() {
        // One lobe per texel, shaded by hand with each rule: eq 20's option keeps
        // α'² = α² + c/κ, the convolved one takes Ggx::widened_vmf; they differ.
        let sample = crate::procedural::generate(16, 5);
        let b = crate::methods::bake_with(
            &sample.map,
            Method::Vmf,
            &crate::bake::BakeOptions {
                lobes: 1,
                ..Default::default()
            },
        )
        .unwrap();
        let g = Ggx::new(0.1);
        let brdf = Brdf::Ggx(g);
        let (l, h) = (DVec3::new(0.1, 0.0, 1.0).normalize(), DVec3::Z);
        let t = b.texel(2, 1, 1);
        let lobe = vmf_decode(t[0], crate::vmf::r_max(b.format), 0.0).unwrap();
        // The specular term's cosine at the product lobe's centre (the default VmfCosine).
        let cos_i = specular_cosine(lobe.mu, lobe.var, h, l, cosine_eta(&brdf));
        let mut differ = false;
        for (rule, alpha) in [
            (VmfSpecular::Eq20, g.widened(lobe.var)),
            (VmfSpecular::Convolved, g.widened_vmf(lobe.var)),
        ] {
            let got = shade_with(
                &b,
                &t,
                l,
                h,
                &brdf,
                &ShadeOptions {
                    vmf_specular: rule,
                    ..Default::default()
                },
            );
            let want = lobe.alpha * ggx(lobe.mu.dot(h), alpha) * cos_i;
            assert!(
                (got.specular - want).abs() <= 1e-12 * want,
                "{rule:?}: {got:?} vs {want}"
            );
            differ |= alpha != g.widened(lobe.var);
        }
        assert!(
            differ,
            "the texel's lobe must be widened (var {})",
            lobe.var
        );
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
            let b = crate::methods::bake_with(&map, method, &opts).unwrap();
            for brdf in [
                Brdf::BlinnPhong { s: 50.0 },
                Brdf::TorranceSparrow { sigma: 0.2 },
                Brdf::Ggx(Ggx {
                    g: true,
                    ..Ggx::new(0.2)
                }),
            ] {
                for level in [0, 2] {
                    let t = b.texel(level, 1, 1);
                    let c = shade_rgb(&b, &t, l, h, &brdf, true);
                    let g = shade_brdf(&b, &t, l, h, &brdf);
                    for k in 0..3 {
                        assert!((c.diffuse[k] - g.diffuse).abs() < 1e-6, "{method} {brdf}");
                        let tol = 1e-6 * g.specular.max(1.0);
                        assert!((c.specular[k] - g.specular).abs() < tol, "{method} {brdf}");
                    }
                }
            }
        }
    }

    /// The specular cosine at the product lobe's centre against the exact term of one vMF lobe,
    /// `∫ γ(n) (s+1)/(2π) max(n·ω_h, 0)^s max(n·ω_i, 0) dn`, by brute-force quadrature over the
    /// sphere (polar and azimuth midpoints about μ, 600 × 720). Both rules shade the lobe by
    /// the exact convolution (eq 14, [`VmfSpecular::Exact`]), so the only difference is where
    /// the cosine is taken. Broad-to-sharp lobes (κ = 8 … 128), s = 32 and 256, half vectors
    /// inside the widened lobe, lights from 20° to 80° off the normal.
    #[test]
    fn the_cosine_at_the_product_centre_follows_the_exact_lobe_integral() {
        use std::f64::consts::PI;
        let exact = |kappa: f64, s: f64, h: DVec3, l: DVec3| {
            let c = kappa / (2.0 * PI * -(-2.0 * kappa).exp_m1());
            // Beyond κ(1 − cos θ) = 40 the vMF density is below e^-40 of its peak.
            let theta_max = (1.0 - 40.0 / kappa).max(-1.0).acos();
            let (nt, np) = (600, 720);
            let (dt, dp) = (theta_max / nt as f64, 2.0 * PI / np as f64);
            let mut sum = 0.0;
            for i in 0..nt {
                let t = (i as f64 + 0.5) * dt;
                let w = c * (kappa * (t.cos() - 1.0)).exp() * t.sin() * dt * dp;
                for j in 0..np {
                    let p = (j as f64 + 0.5) * dp;
                    let n = DVec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos());
                    sum += w * blinn_phong(n.dot(h), s) * n.dot(l).max(0.0);
                }
            }
            sum
        };
        let mu = DVec3::Z;
        for (kappa, s) in [
            (8.0f64, 32.0f64),
            (32.0, 32.0),
            (128.0, 32.0),
            (32.0, 256.0),
        ] {
            let var = 1.0 / kappa;
            let width = (var + 1.0 / s).sqrt();
            let (mut e_product, mut e_mu, mut norm) = (0.0, 0.0, 0.0);
            for light_deg in [20.0f64, 50.0, 80.0] {
                for (offset, azimuth) in [(0.5f64, 0.0f64), (1.0, 1.0), (1.5, 2.5), (1.0, 3.0)] {
                    // ω_h `offset` combined widths from μ; ω_i `light_deg` from the normal on
                    // the plane through ω_h (ω_o its mirror about ω_h).
                    let th = offset * width;
                    let h = DVec3::new(
                        th.sin() * f64::cos(azimuth),
                        th.sin() * f64::sin(azimuth),
                        th.cos(),
                    );
                    let tl = light_deg.to_radians();
                    let l = DVec3::new(
                        tl.sin() * f64::cos(azimuth + 0.4),
                        tl.sin() * f64::sin(azimuth + 0.4),
                        tl.cos(),
                    );
                    let v = 2.0 * h.dot(l) * h - l;
                    if v.z <= 0.05 || h.dot(l) <= 0.0 {
                        continue;
                    }
                    let truth = exact(kappa, s, h, l);
                    let lobe = VmfSpecular::Exact.lobe(mu.dot(h), s, var);
                    let product = lobe * specular_cosine(mu, var, h, l, s + 1.0);
                    let at_mu = lobe * mu.dot(l).max(0.0);
                    e_product += (product - truth).powi(2);
                    e_mu += (at_mu - truth).powi(2);
                    norm += truth * truth;
                }
            }
            let (rel_product, rel_mu) = ((e_product / norm).sqrt(), (e_mu / norm).sqrt());
            println!("κ {kappa} s {s}: product {rel_product:.4}, at μ {rel_mu:.4}");
            assert!(rel_product < 0.03, "κ {kappa} s {s}: {rel_product}");
            assert!(
                rel_mu > 3.0 * rel_product,
                "κ {kappa} s {s}: {rel_mu} vs {rel_product}"
            );
        }
        // κ = ∞ is μ's cosine exactly; the uniform lobe's variance gives ω_h's.
        let (h, l) = (
            DVec3::new(0.3, 0.0, 1.0).normalize(),
            DVec3::new(0.8, 0.1, 0.6).normalize(),
        );
        assert_eq!(specular_cosine(mu, 0.0, h, l, 33.0), mu.dot(l));
        assert!((specular_cosine(mu, 1e6, h, l, 33.0) - h.dot(l)).abs() < 1e-6);
    }
}
