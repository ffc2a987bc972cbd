//! The BRDFs every method is shaded with, and the exact shading of one unfiltered normal (the
//! ground truth the filters approximate).
//!
//! The BRDF is the paper's (Algorithm 2 line 14, Sec 7.2): a Lambert term and a specular lobe
//! — normalized Blinn-Phong `(s+1)/(2π) (ω_h·n)^s` (eq 20's form) or the Torrance–Sparrow-like
//! Gaussian of eq 18 — both multiplied by the cosine `max(ω_i·n, 0)`. The two terms are
//! returned separately (unit weights): any `K_d·diffuse + K_s·specular` is a combination of
//! them, and the error of each is reported on its own.
//!
//! Also here: the lobe shapes the methods widen ([`widened_lobe`], [`torrance_sparrow_lobe`])
//! and the geometry they share ([`half_vector`], [`tangent_frame`], [`psd`]). Below every
//! method; the per-method filtered shading (the shaders' CPU twin) is module `shade`.

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
