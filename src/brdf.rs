//! The one BRDF library every method is shaded with ([`Brdf`]), and the exact shading of one
//! unfiltered normal (the ground truth the filters approximate).
//!
//! Every BRDF has the paper's form (eq 3 and footnote 4): a 1D lobe `f(ω·n)` radially symmetric
//! about the shading normal, times a factor `g(ω_i, ω_o)` that does not depend on n, times the
//! cosine `max(ω_i·n, 0)` (Algorithm 2 line 14). The diffuse term is always Lambert
//! (`ω = ω_i`, `f(u) = max(u, 0)`, Sec 3.1); the specular lobe (`ω = ω_h`) is one of
//! - none ([`Brdf::Lambert`]: the diffuse term alone);
//! - normalized Blinn-Phong `(s+1)/(2π) (ω_h·n)^s` (eq 20's form);
//! - the Torrance–Sparrow-like Gaussian of eq 18, `e^{−β²/(4σ²)}/(4πσ²)`;
//! - GGX / Trowbridge–Reitz `D(ω_h·n) = α²/(π((ω_h·n)²(α²−1)+1)²)` ([`Ggx`]), with Smith's
//!   height-correlated masking and Schlick's Fresnel as the g factor (off by default);
//! - a tabulated `f(θ_h)·g(θ_d)` read from a file ([`Tabulated`], the factored measured
//!   materials of Sec 5.2).
//!
//! The two terms are returned separately (unit weights): any `K_d·diffuse + K_s·specular` is a
//! combination of them, and the error of each is reported on its own.
//!
//! For every BRDF: its spherical-harmonic coefficients `ρ̂_l` (eq 11) by Gauss–Legendre
//! quadrature ([`Brdf::sh_coefficients`]) beside the paper's closed forms
//! ([`Brdf::sh_closed_form`]), and its lobe-widening rule under an NDF lobe of concentration κ
//! (eq 20, eq 21, `α'² = α² + c/κ` for GGX, eq 14 tabulated numerically for tabulated lobes,
//! module [`convolution`]).
//!
//! Also here: the lobe shapes the methods widen ([`widened_lobe`], [`torrance_sparrow_lobe`],
//! [`ggx`], [`ggx_aniso`]) and the geometry they share ([`half_vector`], [`tangent_frame`],
//! [`psd`]). Below every method; the per-method filtered shading (the shaders' CPU twin) is
//! module `shade`.

pub mod convolution;
pub mod ggx_mixture;
pub mod tabulated;

pub use tabulated::Tabulated;

use crate::error::compact_f64;
use glam::{DVec2, DVec3};
use std::f64::consts::PI;
use std::sync::Arc;

/// The two shading terms at one point for one light and view.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Shading {
    /// Lambert: `max(ω_i·n, 0)`.
    pub diffuse: f64,
    /// The specular lobe times the cosine and the g factor: `f(ω_h·n) max(ω_i·n, 0) g`
    /// (0 for [`Brdf::Lambert`]).
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
    clamp_eigenvalues(m, 0.0, f64::INFINITY)
}

/// A symmetric 2×2 matrix `(xx, yy, xy)` with its eigenvalues clamped to `[lo, hi]` (NaN ones
/// become `lo`), eigenvectors kept: [`psd`] is `lo = 0, hi = ∞`; GGX's widened slope matrix
/// is held to `hi = 1` ([`Ggx::widened`]).
pub fn clamp_eigenvalues(m: [f64; 3], lo: f64, hi: f64) -> [f64; 3] {
    let (xx, yy, xy) = (m[0], m[1], m[2]);
    let mean = 0.5 * (xx + yy);
    let r = (0.25 * (xx - yy) * (xx - yy) + xy * xy).sqrt();
    let (l1, l2) = ((mean + r).max(lo).min(hi), (mean - r).max(lo).min(hi));
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

/// GGX / Trowbridge–Reitz normal distribution `D(c) = α²/(π(c²(α²−1)+1)²)` at `c = ω_h·n`
/// (Walter et al. 2007; normalized so that `∫ D(ω_h·n)(ω_h·n) dω_h = 1`), zero for `c ≤ 0`.
/// `α > 0` is the roughness (the slope-space width). Evaluated as `α²/(π((1−c)(1+c) + c²α²)²)`
/// so that sharp lobes keep their precision near `c = 1`.
pub fn ggx(cos_h: f64, alpha: f64) -> f64 {
    if cos_h.is_nan() || cos_h <= 0.0 {
        return 0.0;
    }
    let c = cos_h.min(1.0);
    let a2 = alpha * alpha;
    let d = (1.0 - c) * (1.0 + c) + c * c * a2;
    if d <= 0.0 {
        return 0.0;
    }
    a2 / (PI * d * d)
}

/// Anisotropic GGX in slope space: `1/(π sqrt(det S) c⁴ (1 + dᵀS⁻¹d)²)` for the slope offset `d`
/// of ω_h from the lobe's centre (in the lobe's frame) and the slope covariance-like matrix
/// `S = (xx, yy, xy)` (`α² I` gives [`ggx`] exactly; `α² I + c Σ` widens it by an NDF
/// covariance Σ, the GGX form of LEAN's and Olano–North's rules). `c = cos_h` is the cosine
/// between ω_h and the lobe's centre; zero for `c ≤ 0`. S must be positive definite (its
/// determinant is floored at `f64::MIN_POSITIVE`).
pub fn ggx_aniso(cos_h: f64, d: DVec2, s: [f64; 3]) -> f64 {
    if cos_h.is_nan() || cos_h <= 0.0 {
        return 0.0;
    }
    let (a, c, b) = (s[0], s[1], s[2]);
    let det = (a * c - b * b).max(f64::MIN_POSITIVE);
    let q = (c * d.x * d.x - 2.0 * b * d.x * d.y + a * d.y * d.y) / det;
    let c2 = cos_h.min(1.0) * cos_h.min(1.0);
    let t = 1.0 + q.max(0.0);
    1.0 / (PI * det.sqrt() * c2 * c2 * t * t)
}

/// Schlick's Fresnel `F0 + (1 − F0)(1 − cos θ_d)⁵` at `cos θ_d = ω_i·ω_h`.
pub fn schlick(cos_d: f64, f0: f64) -> f64 {
    let m = (1.0 - cos_d.clamp(0.0, 1.0)).powi(5);
    f0 + (1.0 - f0) * m
}

/// Smith's height-correlated visibility for GGX, `V = G₂/(4 cos θ_i cos θ_o)
/// = 0.5/(cos θ_i sqrt(cos²θ_o(1−α²)+α²) + cos θ_o sqrt(cos²θ_i(1−α²)+α²))` (Heitz 2014), with
/// the cosines taken against the geometric normal (tangent-space +Z) so that it does not depend
/// on the filtered normal (footnote 4). Zero when either direction is at or below the horizon.
pub fn smith_visibility(cos_i: f64, cos_o: f64, alpha: f64) -> f64 {
    if !(cos_i > 0.0 && cos_o > 0.0) {
        return 0.0;
    }
    let a2 = alpha * alpha;
    let vi = cos_o * (cos_i * cos_i * (1.0 - a2) + a2).sqrt();
    let vo = cos_i * (cos_o * cos_o * (1.0 - a2) + a2).sqrt();
    let den = vi + vo;
    if den > 0.0 { 0.5 / den } else { 0.0 }
}

/// The widening constant `c` of GGX under an NDF lobe of concentration κ, `α'² = α² + c/κ`
/// (the vMF lobe's per-axis angular variance is 1/κ). Chosen by measurement
/// (`docs/sh-brdf.md`): the least-squares fit against eq 14 computed numerically
/// ([`convolution::fit_ggx_widening`]) and the texel-space errors of the constants in use
/// elsewhere (0.5, 0.75, 1, 2) on the shared maps.
pub const GGX_WIDENING_C: f64 = 2.0;

/// The roughness of the GGX lobe whose peak equals the peak of GGX α convolved with a vMF lobe
/// of per-axis variance `var = 1/κ` (eq 14 at θ = 0): `α'² = α²/(1 − T(a)) + 2/κ`,
/// `a = κα²/2`, at most 1; `var ≤ 0` gives α.
///
/// Derivation (small angles: GGX in slope space is `1/(πα²(1 + |m|²/α²)²)`, the vMF lobe a
/// Gaussian of per-axis variance 1/κ): the convolution's peak is
/// `(κ/2π) ∫₀^∞ e^{−a x}/(1 + x)² dx · a/a = (1/(πα²)) · a (1 − a eᵃ E₁(a))`, and a GGX lobe
/// peaks at `1/(πα'²)`, so `α'² = α²/(a(1 − a eᵃE₁(a)))`. With the continued fraction
/// `eᵃE₁(a) = 1/(a + 1 − T)`, `T = 1²/(a + 3 − 2²/(a + 5 − 3²/(a + 7 − …)))`
/// ([`vmf_ggx_tail`]), this is `α²/(1 − T) + 2/κ` with no cancellation. Its widening
/// `c(a) = κ(α'² − α²)` runs from 2 for NDF lobes much wider than the BRDF lobe (a → 0: the
/// convolution is the vMF lobe, peak κ/2π) to 4 for narrow ones (a → ∞: the peak falls by
/// `4/(κα²)`, twice what `c = 2` gives): the constant `c = 2` leaves narrow NDF lobes too
/// sharp (`docs/pbr.md`, "vMF J = 6 under GGX").
pub fn ggx_vmf_peak_alpha(alpha: f64, var: f64) -> f64 {
    let a2 = alpha * alpha;
    if var.is_nan() || var <= 0.0 {
        return alpha.min(1.0);
    }
    let a = 0.5 * a2 / var;
    (a2 / (1.0 - vmf_ggx_tail(a)) + 2.0 * var).sqrt().min(1.0)
}

/// `T(a) = a + 1 − 1/(eᵃE₁(a))` for `a > 0`, in (0, 1) ([`ggx_vmf_peak_alpha`]): for `a ≥ 1`
/// the continued fraction `1²/(a + 3 − 2²/(a + 5 − …))` to 32 terms, below the series
/// `E₁(a) = −γ − ln a − Σ (−a)ⁿ/(n·n!)` to 16 terms (`1 − T` to better than 10⁻⁸ relative;
/// `brdf::tests::vmf_ggx_tail_matches_e1`). The GLSL twin `ndf_vmf_ggx_tail` uses the same
/// terms in the same order.
pub fn vmf_ggx_tail(a: f64) -> f64 {
    if a >= 1.0 {
        let mut s = 0.0;
        for n in (1..=32).rev() {
            let nf = n as f64;
            s = nf * nf / (a + 2.0 * nf + 1.0 - s);
        }
        s
    } else {
        // E₁(a) = −γ − ln a + a − a²/4 + a³/18 − …: the sum Σ_{n≥1} (−1)^{n+1} aⁿ/(n·n!).
        let mut term = 1.0;
        let mut sum = 0.0;
        for n in 1..=16 {
            let nf = n as f64;
            term *= -a / nf;
            sum -= term / nf;
        }
        let e1 = -0.577_215_664_901_532_9 - a.max(f64::MIN_POSITIVE).ln() + sum;
        a + 1.0 - 1.0 / (a.exp() * e1)
    }
}

/// A GGX / Trowbridge–Reitz specular lobe ([`ggx`]) and its g factor.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Ggx {
    /// Roughness α in (0, 1] (slope-space width; glTF's perceptual roughness squared).
    pub alpha: f64,
    /// Multiply by the g factor `F(ω_i·ω_h) · V(ω_i, ω_o)`: Schlick's Fresnel ([`schlick`])
    /// and Smith's height-correlated visibility against the geometric normal
    /// ([`smith_visibility`]). Off: the lobe `D` alone, times the cosine.
    #[serde(default)]
    pub g: bool,
    /// Schlick's `F0`, the reflectance at normal incidence (0.04: a dielectric).
    #[serde(default = "default_f0")]
    pub f0: f64,
    /// The widening constant `c` of `α'² = α² + c/κ` (default [`GGX_WIDENING_C`]).
    #[serde(default = "default_widening")]
    pub widening: f64,
}

fn default_f0() -> f64 {
    0.04
}

fn default_widening() -> f64 {
    GGX_WIDENING_C
}

impl Ggx {
    /// GGX with roughness `alpha`, no g factor, `F0 = 0.04`, widening [`GGX_WIDENING_C`].
    pub fn new(alpha: f64) -> Ggx {
        Ggx {
            alpha,
            g: false,
            f0: default_f0(),
            widening: default_widening(),
        }
    }

    /// The roughness widened by an NDF lobe of per-axis angular variance `var` (1/κ for a vMF
    /// lobe): `sqrt(α² + c·var)`, at most 1 — GGX with α > 1 peaks at grazing angles, above
    /// the unfiltered lobe's peak, and no NDF widens a lobe into that (at α = 1 it is already
    /// uniform over the hemisphere).
    pub fn widened(&self, var: f64) -> f64 {
        (self.alpha * self.alpha + self.widening * var.max(0.0))
            .sqrt()
            .min(1.0)
    }

    /// The roughness a vMF lobe of variance `var = 1/κ` widens this GGX lobe to under point
    /// lights with the opt-in rule `shade::VmfSpecular::Convolved` (the shaders'
    /// `NDF_VMF_SPECULAR_CONVOLVED`; the default is [`Ggx::widened`]): `α'² = α² + c·m(a)/κ`,
    /// at most 1, with
    /// `a = κα²/2` and `m(a) = 1 + a·T(a)/(1 − T(a))` ([`vmf_ggx_tail`]) running from 1
    /// (NDF lobes much wider than the BRDF lobe) to 2 (much narrower). At the default
    /// `c = 2` this is [`ggx_vmf_peak_alpha`]: the lobe with the peak of the exact convolution
    /// (eq 14); another `c` scales that widening by `c/2` (`c = 0`: no widening). The constant
    /// rule [`Ggx::widened`] (`m = 1`) leaves narrow NDF lobes too sharp (half the widening
    /// their peak needs): on the near-flat metal map this rule's error is 3–13× lower; on rough
    /// maps, where a single GGX cannot follow the convolution's shoulders, `c = 2` is better
    /// (`docs/pbr.md`, "vMF J = 6 under GGX"). GLSL: `ndf_vmf_ggx_alpha`.
    pub fn widened_vmf(&self, var: f64) -> f64 {
        let a2 = self.alpha * self.alpha;
        if var.is_nan() || var <= 0.0 {
            return self.alpha.min(1.0);
        }
        let a = 0.5 * a2 / var;
        // m = 2 − 2/a + …: exact to 10⁻¹² beyond a = 10¹² (and a·T would be ∞·0 at a = ∞).
        let m = if a <= 1e12 {
            let t = vmf_ggx_tail(a);
            1.0 + a * t / (1.0 - t)
        } else {
            2.0
        };
        (a2 + self.widening * m * var).sqrt().min(1.0)
    }
}

/// The sharpest Blinn-Phong exponent [`Brdf::validate`] accepts (about a 0.02° lobe).
pub const MAX_EXPONENT: f64 = 1e7;

/// The narrowest Torrance–Sparrow σ [`Brdf::validate`] accepts (eq 20: `s = 1/(2σ²)` = 8·10⁶).
pub const MIN_SIGMA: f64 = 2.5e-4;

/// The smallest GGX α [`Brdf::validate`] accepts (`2/α² − 2` ≈ 8·10⁶).
pub const MIN_ALPHA: f64 = 5e-4;

/// A BRDF of the library (module docs): the specular lobe `f(ω_h·n)` with its parameters and
/// g factor; the Lambert term is always there as the diffuse term.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "model", rename_all = "snake_case")]
pub enum Brdf {
    /// No specular lobe: the diffuse Lambert term `max(ω_i·n, 0)` alone.
    Lambert,
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
    /// GGX / Trowbridge–Reitz ([`Ggx`]).
    Ggx(Ggx),
    /// A tabulated `f(θ_h)·g(θ_d)` ([`Tabulated`]).
    Tabulated(Arc<Tabulated>),
}

impl Brdf {
    /// Blinn-Phong BRDFs for each exponent in `s`.
    pub fn blinn_phong(s: &[f64]) -> Vec<Brdf> {
        s.iter().map(|&s| Brdf::BlinnPhong { s }).collect()
    }

    /// GGX with roughness `alpha` and the defaults of [`Ggx::new`].
    pub fn ggx(alpha: f64) -> Brdf {
        Brdf::Ggx(Ggx::new(alpha))
    }

    /// The model's name as the command line spells it: `lambert`, `blinn-phong`,
    /// `torrance-sparrow`, `ggx`, `tabulated`.
    pub fn model(&self) -> &'static str {
        match self {
            Brdf::Lambert => "lambert",
            Brdf::BlinnPhong { .. } => "blinn-phong",
            Brdf::TorranceSparrow { .. } => "torrance-sparrow",
            Brdf::Ggx(_) => "ggx",
            Brdf::Tabulated(_) => "tabulated",
        }
    }

    /// Whether the BRDF has a specular lobe (every model but [`Brdf::Lambert`]).
    pub fn has_specular(&self) -> bool {
        !matches!(self, Brdf::Lambert)
    }

    /// Checks the parameters: s in (0, [`MAX_EXPONENT`]], σ ≥ [`MIN_SIGMA`] and finite, α in
    /// [[`MIN_ALPHA`], 1], F0 in [0, 1], c ≥ 0. The bounds on s, σ and α keep lobes no sharper
    /// than a Blinn-Phong exponent of about 10⁷ (eq 20's `s = 1/(2σ²)`, GGX's `2/α² − 2`):
    /// sharper ones are 0 in f64 a fraction of a degree off their peak, so the exact footprint
    /// average an error is relative to is 0 at every light/view pair (`eval` printed `inf`).
    pub fn validate(&self) -> crate::error::Result<()> {
        let bad = |what: &str, v: f64, range: &str| {
            Err(crate::error::Error::InvalidOption(format!(
                "{what} {} (must be {range})",
                crate::error::compact_f64(v)
            )))
        };
        match *self {
            Brdf::BlinnPhong { s } if !(s > 0.0 && s <= MAX_EXPONENT) => bad(
                "Blinn-Phong exponent",
                s,
                &format!("in (0, {MAX_EXPONENT:e}]"),
            ),
            Brdf::TorranceSparrow { sigma } if !(sigma.is_finite() && sigma >= MIN_SIGMA) => bad(
                "Torrance-Sparrow sigma",
                sigma,
                &format!("finite and >= {MIN_SIGMA:e}"),
            ),
            Brdf::Ggx(g) if !(g.alpha >= MIN_ALPHA && g.alpha <= 1.0) => {
                bad("GGX alpha", g.alpha, &format!("in [{MIN_ALPHA:e}, 1]"))
            }
            Brdf::Ggx(g) if !((0.0..=1.0).contains(&g.f0) && g.widening >= 0.0) => {
                Err(crate::error::Error::InvalidOption(format!(
                    "GGX F0 {} / widening {} (expected F0 in [0, 1], widening >= 0)",
                    g.f0, g.widening
                )))
            }
            _ => Ok(()),
        }
    }

    /// The Blinn-Phong exponent with about the same angular width: `s`, `1/(2σ²)` (eq 18 vs
    /// eq 20), `2/α² − 2` for GGX (equal curvature at the peak), from the half-maximum angle
    /// for a tabulated lobe; 1 for Lambert.
    pub fn equivalent_exponent(&self) -> f64 {
        match self {
            Brdf::Lambert => 1.0,
            Brdf::BlinnPhong { s } => *s,
            Brdf::TorranceSparrow { sigma } => 0.5 / (sigma * sigma),
            Brdf::Ggx(g) => (2.0 / (g.alpha * g.alpha) - 2.0).max(1.0),
            Brdf::Tabulated(t) => {
                // (1/2)^(1/s) = cos θ_half  ⇒  s = ln 2 / −ln cos θ_half.
                let c = t.half_width().cos();
                if c < 1.0 && c > 0.0 {
                    (std::f64::consts::LN_2 / -c.ln()).max(1.0)
                } else {
                    1.0
                }
            }
        }
    }

    /// The lobe's angular width in radians (for quadratures): `1/sqrt(s)` of the equivalent
    /// exponent, π/2 for Lambert.
    pub fn angular_width(&self) -> f64 {
        match self {
            Brdf::Lambert => 0.5 * PI,
            Brdf::Ggx(g) => g.alpha.min(0.5 * PI),
            _ => (1.0 / self.equivalent_exponent().sqrt()).min(0.5 * PI),
        }
    }

    /// The lobe `f(c)` at `c = ω·n` (`ω = ω_h` for the specular lobes; Lambert's `max(c, 0)`
    /// for [`Brdf::Lambert`]), without the cosine and the g factor. Zero for `c ≤ 0`.
    pub fn lobe(&self, c: f64) -> f64 {
        match self {
            Brdf::Lambert => c.max(0.0),
            Brdf::BlinnPhong { s } => blinn_phong(c, *s),
            Brdf::TorranceSparrow { sigma } => torrance_sparrow_lobe(c, DVec2::X, *sigma, [0.0; 3]),
            Brdf::Ggx(g) => ggx(c, g.alpha),
            Brdf::Tabulated(t) => {
                if c.is_nan() || c <= 0.0 {
                    0.0
                } else {
                    t.f(c.min(1.0).acos())
                }
            }
        }
    }

    /// The lobe's largest value, `f(1)` for the analytic lobes, the table's maximum for a
    /// tabulated one (0 for Lambert's specular term, which is absent). Without the g factor.
    pub fn peak(&self) -> f64 {
        match self {
            Brdf::Lambert => 0.0,
            Brdf::Tabulated(t) => t.peak(),
            b => b.lobe(1.0),
        }
    }

    /// The g factor for light `l` and half vector `h` (unit, tangent space): 1 for Blinn-Phong
    /// and eq 18; for GGX with `g` on, `F(l·h) V(l_z, v_z)` with the view `v = 2(l·h)h − l`
    /// ([`schlick`], [`smith_visibility`]); for a tabulated BRDF its `g(θ_d)`, `θ_d = acos(l·h)`.
    /// It does not depend on the normal, so every method multiplies its specular term by it.
    pub fn g(&self, l: DVec3, h: DVec3) -> f64 {
        match self {
            Brdf::Ggx(g) if g.g => {
                let cd = l.dot(h).clamp(0.0, 1.0);
                let v = 2.0 * cd * h - l;
                schlick(cd, g.f0) * smith_visibility(l.z, v.z, g.alpha)
            }
            Brdf::Tabulated(t) => t.g(l.dot(h).clamp(-1.0, 1.0).acos()),
            _ => 1.0,
        }
    }

    /// `ρ̂_l`, l = 0 … `lmax` (eq 11): the lobe's zonal spherical-harmonic coefficients times
    /// `Λ_l`, by Gauss–Legendre quadrature over θ ([`crate::harmonics::zonal_coefficients`],
    /// panels sized to the lobe's width; accurate to ~1e-12 relative for every lobe the
    /// library accepts). For Lambert: the clamped cosine's `π, 2π/3, π/4, 0, −π/24, …`.
    pub fn sh_coefficients(&self, lmax: usize) -> Vec<f64> {
        let width = self.angular_width();
        match self {
            Brdf::Lambert => crate::harmonics::zonal_coefficients(&|c| c.max(0.0), lmax, PI),
            b => crate::harmonics::zonal_coefficients(&|c| b.lobe(c), lmax, width),
        }
    }

    /// The paper's closed form of `ρ̂_l`, where there is one: `e^{−l²/2s}` for Blinn-Phong
    /// (Sec 5.1, eq 20, Ramamoorthi & Hanrahan's approximation), `e^{−(σl)²}` for eq 18, and the
    /// exact values for Lambert (`π, 2π/3, π/4`, then `2π (−1)^{l/2+1} (l−2)!/(2^l (l/2−1)!
    /// (l/2+1)!)` for even l, 0 for odd l > 1). `None` for GGX and tabulated lobes.
    pub fn sh_closed_form(&self, l: usize) -> Option<f64> {
        let lf = l as f64;
        match self {
            Brdf::Lambert => Some(lambert_coefficient(l)),
            Brdf::BlinnPhong { s } => Some((-lf * lf / (2.0 * s)).exp()),
            Brdf::TorranceSparrow { sigma } => Some((-(sigma * lf).powi(2)).exp()),
            Brdf::Ggx(_) | Brdf::Tabulated(_) => None,
        }
    }

    /// The band limit the spherical-harmonic method needs for this BRDF (Sec 5.1): 2 for
    /// Lambert (Ramamoorthi & Hanrahan's nine coefficients), `⌈√(4s)⌉` of the equivalent
    /// Blinn-Phong exponent otherwise, at most [`crate::harmonics`]'s practical 16.
    pub fn suggested_lmax(&self) -> usize {
        match self {
            Brdf::Lambert => 2,
            b => ((4.0 * b.equivalent_exponent()).sqrt().ceil() as usize).clamp(2, 16),
        }
    }

    /// The exact shading of one unfiltered unit normal `n` for light `l` and half vector `h`:
    /// Lambert `max(n·l, 0)` and `f(n·h) max(n·l, 0) g(l, h)`.
    pub fn reference(&self, n: DVec3, l: DVec3, h: DVec3) -> Shading {
        let cos_i = n.dot(l).max(0.0);
        let specular = match self {
            Brdf::Lambert => 0.0,
            Brdf::BlinnPhong { s } => return reference(n, l, h, *s),
            b => b.lobe(n.dot(h)) * cos_i * b.g(l, h),
        };
        Shading {
            diffuse: cos_i,
            specular,
        }
    }
}

/// `ρ̂_l` of Lambert's clamped cosine in closed form (Ramamoorthi & Hanrahan 2001): `π`,
/// `2π/3`, then 0 for odd l and `2π (−1)^{l/2+1} (l−2)! / (2^l (l/2−1)! (l/2+1)!)` for even l,
/// evaluated by the ratio `(l−1)/(l+4)` between successive even l (from `1/8` at l = 2), so no
/// factorial is formed.
pub fn lambert_coefficient(l: usize) -> f64 {
    match l {
        0 => PI,
        1 => 2.0 * PI / 3.0,
        l if l % 2 == 1 => 0.0,
        l => {
            let mut v = 0.125;
            let mut k = 2;
            while k < l {
                v *= (k as f64 - 1.0) / (k as f64 + 4.0);
                k += 2;
            }
            let sign = if (l / 2) % 2 == 1 { 1.0 } else { -1.0 };
            2.0 * PI * sign * v
        }
    }
}

impl std::fmt::Display for Brdf {
    /// The model and its parameter, numbers compact at any magnitude
    /// ([`crate::error::compact_f64`]).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Brdf::Lambert => write!(f, "Lambert"),
            Brdf::BlinnPhong { s } => write!(f, "Blinn-Phong s = {}", compact_f64(*s)),
            Brdf::TorranceSparrow { sigma } => {
                write!(f, "Torrance-Sparrow sigma = {}", compact_f64(*sigma))
            }
            Brdf::Ggx(g) => {
                write!(f, "GGX alpha = {}", compact_f64(g.alpha))?;
                if g.g {
                    write!(f, " (Smith, Schlick F0 = {})", g.f0)?;
                }
                if g.widening != GGX_WIDENING_C {
                    write!(f, " c = {}", g.widening)?;
                }
                Ok(())
            }
            Brdf::Tabulated(t) => write!(f, "tabulated '{}'", t.name()),
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

/// The exact shading of one unfiltered unit normal under `brdf` (the ground truth):
/// [`Brdf::reference`].
pub fn reference_brdf(n: DVec3, l: DVec3, h: DVec3, brdf: &Brdf) -> Shading {
    brdf.reference(n, l, h)
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

    /// `∫₀^∞ e^{−ax}/(1 + x)² dx` by Gauss–Legendre panels (geometric from 10⁻⁴·min(1, 1/a)
    /// to where `e^{−ax}` is below 10⁻²⁰), independent of E₁'s series and continued fraction.
    fn peak_integral(a: f64) -> f64 {
        let (x, w) = crate::harmonics::gauss_legendre(16);
        let end = 46.0 / a;
        let mut edges = vec![0.0];
        let mut e = 1e-4 * (1.0f64).min(1.0 / a);
        while e < end {
            edges.push(e);
            e *= 1.3;
        }
        edges.push(end);
        let mut sum = 0.0;
        for p in edges.windows(2) {
            let (mid, half) = (0.5 * (p[0] + p[1]), 0.5 * (p[1] - p[0]));
            for (xi, wi) in x.iter().zip(&w) {
                let u = mid + half * xi;
                sum += half * wi * (-a * u).exp() / ((1.0 + u) * (1.0 + u));
            }
        }
        sum
    }

    #[test]
    fn vmf_ggx_tail_matches_e1() {
        // 1 − a eᵃE₁(a) = ∫ e^{−ax}/(1 + x)² dx = (1 − T)/(a + 1 − T): both branches (the
        // series below a = 1, the continued fraction from 1 on) and the switch between them.
        let mut worst: f64 = 0.0;
        for a in [
            1e-6, 1e-3, 0.01, 0.1, 0.3, 0.7, 0.999_999, 1.0, 1.5, 3.0, 10.0, 100.0, 1e4, 1e6,
        ] {
            let t = vmf_ggx_tail(a);
            assert!(t > 0.0 && t < 1.0, "a={a}: T={t}");
            let got = (1.0 - t) / (a + 1.0 - t);
            let want = peak_integral(a);
            worst = worst.max((got / want - 1.0).abs());
            assert!((got / want - 1.0).abs() < 1e-8, "a={a}: {got} vs {want}");
        }
        eprintln!("vmf_ggx_tail: worst relative error {worst:e}");
        // The peak rule: c(a) = κ(α'² − α²) from 2 (wide NDF lobes) to 4 (narrow ones).
        let g = Ggx::new(0.1);
        let c_of = |var: f64| (g.widened_vmf(var).powi(2) - 0.01) / var;
        assert!((c_of(1e-7) - 4.0).abs() < 1e-3, "{}", c_of(1e-7));
        // The wide limit comes slowly (c ≈ 2 + 2a(−γ − ln a)): a = 0.05 gives 2.198, and
        // α = 0.01 under 1/κ = 0.05 (a = 10⁻³) 2.011.
        assert!((c_of(0.1) - 2.198).abs() < 1e-3, "{}", c_of(0.1));
        let sharp = Ggx::new(0.01);
        let c_wide = (sharp.widened_vmf(0.05).powi(2) - 1e-4) / 0.05;
        assert!((c_wide - 2.0).abs() < 0.02, "{c_wide}");
        assert_eq!(g.widened_vmf(0.0), 0.1);
        assert_eq!(g.widened_vmf(1e6), 1.0);
        assert!((ggx_vmf_peak_alpha(0.1, 1e-3) - g.widened_vmf(1e-3)).abs() < 1e-15);
        let half = Ggx {
            widening: 1.0,
            ..Ggx::new(0.1)
        };
        assert!(
            ((half.widened_vmf(1e-3).powi(2) - 0.01) * 2.0 - (c_of(1e-3) * 1e-3)).abs() < 1e-15
        );
    }

    #[test]
    fn ggx_is_normalized_and_its_anisotropic_form_agrees() {
        // ∫ D(θ) cos θ dω = 1 (projected-area normalization), by the polar quadrature.
        for alpha in [0.01, 0.05, 0.3, 1.0] {
            let sum: f64 = crate::harmonics::polar_quadrature(alpha)
                .into_iter()
                .map(|(t, w)| 2.0 * PI * w * t.sin() * t.cos() * ggx(t.cos(), alpha))
                .sum();
            assert!((sum - 1.0).abs() < 1e-9, "α={alpha}: {sum}");
            for t in [0.0f64, 0.05, 0.4, 1.2] {
                let slope = DVec2::new(t.tan() * 0.6, t.tan() * 0.8);
                let a = ggx_aniso(t.cos(), slope, [alpha * alpha, alpha * alpha, 0.0]);
                let b = ggx(t.cos(), alpha);
                assert!(
                    (a - b).abs() <= 1e-12 * b.max(1e-300),
                    "α={alpha} θ={t}: {a} {b}"
                );
            }
        }
        assert_eq!(ggx(-0.2, 0.1), 0.0);
        assert_eq!(ggx_aniso(0.0, DVec2::ZERO, [0.01, 0.01, 0.0]), 0.0);
    }

    #[test]
    fn ggx_g_factor_on_a_flat_surface_is_cook_torrance() {
        // Independent form: D G₂ F / (4 (n·l)(n·v)) · (n·l) with G₂ = 1/(1 + Λ(l) + Λ(v)),
        // Λ(θ) = (−1 + sqrt(1 + α² tan²θ))/2 (Heitz 2014), F Schlick's.
        let lam = |c: f64, a: f64| 0.5 * (-1.0 + (1.0 + a * a * (1.0 - c * c) / (c * c)).sqrt());
        for alpha in [0.05, 0.3, 0.8] {
            let brdf = Brdf::Ggx(Ggx {
                g: true,
                f0: 0.04,
                ..Ggx::new(alpha)
            });
            for (l, v) in [
                (DVec3::new(0.3, 0.1, 0.9), DVec3::new(-0.2, 0.0, 1.0)),
                (DVec3::new(0.9, 0.0, 0.2), DVec3::new(-0.5, 0.3, 0.6)),
            ] {
                let (l, v) = (l.normalize(), v.normalize());
                let h = half_vector(l, v);
                let g2 = 1.0 / (1.0 + lam(l.z, alpha) + lam(v.z, alpha));
                let f = 0.04 + 0.96 * (1.0 - l.dot(h)).powi(5);
                let want = ggx(h.z, alpha) * g2 * f / (4.0 * l.z * v.z) * l.z;
                let got = brdf.reference(DVec3::Z, l, h).specular;
                assert!(
                    (got - want).abs() <= 1e-12 * want,
                    "α={alpha}: {got} vs {want}"
                );
            }
        }
        // Below the horizon the g factor is 0.
        let b = Brdf::Ggx(Ggx {
            g: true,
            ..Ggx::new(0.2)
        });
        assert_eq!(b.g(DVec3::new(0.0, 0.6, -0.8), DVec3::Z), 0.0);
    }

    #[test]
    fn sh_coefficients_match_the_closed_forms() {
        // Lambert: the exact values, by quadrature and by the closed form, to 1e-12.
        let q = Brdf::Lambert.sh_coefficients(16);
        for (l, v) in q.iter().enumerate() {
            assert!((v - lambert_coefficient(l)).abs() < 1e-12, "l={l}: {v}");
        }
        assert!((lambert_coefficient(4) + PI / 24.0).abs() < 1e-15);
        assert!((lambert_coefficient(6) - PI / 64.0).abs() < 1e-15);
        // Blinn-Phong and eq 18: ρ̂_0 = 1 (normalized lobes) and the paper's Gaussians
        // e^{−l²/2s}, e^{−(σl)²} are approximations; measured maximum differences over l ≤ 16
        // (docs/sh-brdf.md lists them per parameter): 0.052 at s = 8 and 0.139 at σ = 0.3,
        // smaller for sharper lobes.
        for b in [
            Brdf::BlinnPhong { s: 8.0 },
            Brdf::BlinnPhong { s: 128.0 },
            Brdf::TorranceSparrow { sigma: 0.1 },
            Brdf::TorranceSparrow { sigma: 0.3 },
        ] {
            let r = b.sh_coefficients(16);
            // Blinn-Phong integrates to 1; eq 18 only in its small-angle form (ρ̂_0 = 0.9934 at
            // σ = 0.1, 0.9415 at σ = 0.3).
            let want0 = match b {
                Brdf::TorranceSparrow { sigma } if sigma > 0.2 => 0.9415,
                Brdf::TorranceSparrow { .. } => 0.9934,
                _ => 1.0,
            };
            assert!((r[0] - want0).abs() < 1e-4, "{b}: ρ̂_0 = {}", r[0]);
            let worst = (0..=16)
                .map(|l| (r[l] - b.sh_closed_form(l).unwrap()).abs())
                .fold(0.0, f64::max);
            eprintln!("{b}: largest |ρ̂_l − closed form| over l ≤ 16: {worst:.4}");
            assert!(worst < 0.15, "{b}: {worst}");
        }
        // A single normal's SH series reproduces the lobe: f(ω·n) = Σ ρ̂_l (2l+1)/(4π) P_l.
        let b = Brdf::BlinnPhong { s: 4.0 };
        let r = b.sh_coefficients(40);
        for c in [1.0, 0.8, 0.3] {
            let p = crate::harmonics::legendre(40, c);
            let f: f64 = (0..=40)
                .map(|l| r[l] * (2 * l + 1) as f64 / (4.0 * PI) * p[l])
                .sum();
            assert!((f - b.lobe(c)).abs() < 1e-3 * b.peak(), "c={c}: {f}");
        }
    }

    #[test]
    fn suggested_band_limits_follow_sec_5() {
        assert_eq!(Brdf::Lambert.suggested_lmax(), 2);
        assert_eq!(Brdf::BlinnPhong { s: 16.0 }.suggested_lmax(), 8);
        assert_eq!(Brdf::BlinnPhong { s: 12.0 }.suggested_lmax(), 7);
        assert_eq!(Brdf::BlinnPhong { s: 1e4 }.suggested_lmax(), 16);
        assert_eq!(Brdf::TorranceSparrow { sigma: 0.25 }.suggested_lmax(), 6);
        assert_eq!(Brdf::ggx(0.5).suggested_lmax(), 5);
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
