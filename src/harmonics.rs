//! Real spherical harmonics and the quadratures around them (Han et al. 2007, Sec 4.3 and 5;
//! Ramamoorthi & Hanrahan 2001): the basis `Y_lm` of the spherical-harmonic NDF (module `sh`),
//! the Legendre polynomials of zonal functions, and Gauss–Legendre quadrature for the BRDF
//! coefficients `ρ̂_l` of eq 11 (module `brdf`). The bottom of the data flow: no other module of
//! the crate is used here.
//!
//! **Convention.** Real, orthonormal over the unit sphere, without the Condon–Shortley phase, in
//! Cartesian form for a unit vector `(x, y, z)`:
//! `Y_l0 = N_l0 P_l(z)`, `Y_lm = √2 N_lm P_l^m(z) cos(mφ)` and `Y_l,−m = √2 N_lm P_l^m(z) sin(mφ)`
//! for `m > 0`, `N_lm = sqrt((2l+1)/(4π) · (l−m)!/(l+m)!)`. So `Y_1,−1 = √(3/4π) y`,
//! `Y_10 = √(3/4π) z`, `Y_11 = √(3/4π) x`, as in Ramamoorthi & Hanrahan's irradiance paper.
//! Coefficients are stored in (l, m) order, index `l² + l + m` ([`index`]).
//!
//! **Stability.** No factorial is ever formed: the normalized associated Legendre functions
//! (divided by `sin^m θ`, which the Cartesian factors `Re/Im (x + iy)^m` carry) follow the
//! fully normalized recurrences of geodesy,
//! `P̃_mm = sqrt((2m+1)/(2m)) P̃_{m−1,m−1}`, `P̃_{m+1,m} = sqrt(2m+3) z P̃_mm`,
//! `P̃_lm = a_lm (z P̃_{l−1,m} − b_lm P̃_{l−2,m})` with `a_lm = sqrt((4l²−1)/(l²−m²))` and
//! `b_lm = sqrt(((l−1)²−m²)/(4(l−1)²−1))`, whose terms stay of order `sqrt(2l+1)`: accurate to
//! rounding far beyond the l = 16 the library uses (the tests check l = 32).

use glam::DVec3;
use std::f64::consts::PI;

/// Number of coefficients of a band-limited function up to band `lmax`: `(lmax + 1)²`.
pub const fn count(lmax: usize) -> usize {
    (lmax + 1) * (lmax + 1)
}

/// Index of `Y_lm` in (l, m) order: `l² + l + m`, for `−l ≤ m ≤ l`.
pub const fn index(l: usize, m: i64) -> usize {
    ((l * l + l) as i64 + m) as usize
}

/// `Λ_l = sqrt(4π/(2l+1))` (Sec 7.2): the factor between a zonal function's coefficient `f_l`
/// and its convolution weight `ρ̂_l = Λ_l f_l` (eq 11).
pub fn lambda(l: usize) -> f64 {
    (4.0 * PI / (2 * l + 1) as f64).sqrt()
}

/// Writes `Y_lm(d)` for every `l ≤ lmax` into `out[index(l, m)]` (`out` holds at least
/// [`count`]`(lmax)` values). `d` need not be unit length (it is normalized; a zero or
/// non-finite vector counts as +Z).
pub fn eval_into(lmax: usize, d: DVec3, out: &mut [f64]) {
    let d = d.try_normalize().unwrap_or(DVec3::Z);
    let (x, y, z) = (d.x, d.y, d.z);
    // c, s: Re and Im of (x + iy)^m, i.e. sin^m θ cos mφ and sin^m θ sin mφ.
    let (mut c, mut s) = (1.0f64, 0.0f64);
    // P̃_mm (normalized, without sin^m θ).
    let mut pmm = 0.5 / PI.sqrt();
    for m in 0..=lmax {
        if m > 0 {
            pmm *= ((2 * m + 1) as f64 / (2 * m) as f64).sqrt();
            let cn = x * c - y * s;
            s = x * s + y * c;
            c = cn;
        }
        let mf = m as f64;
        let mut write = |l: usize, p: f64| {
            if m == 0 {
                out[index(l, 0)] = p;
            } else {
                out[index(l, m as i64)] = std::f64::consts::SQRT_2 * p * c;
                out[index(l, -(m as i64))] = std::f64::consts::SQRT_2 * p * s;
            }
        };
        write(m, pmm);
        if m == lmax {
            break;
        }
        let mut p1 = (2.0 * mf + 3.0).sqrt() * z * pmm; // P̃_{m+1,m}
        write(m + 1, p1);
        let mut p0 = pmm;
        for l in m + 2..=lmax {
            let lf = l as f64;
            let a = ((4.0 * lf * lf - 1.0) / (lf * lf - mf * mf)).sqrt();
            let b = (((lf - 1.0) * (lf - 1.0) - mf * mf) / (4.0 * (lf - 1.0) * (lf - 1.0) - 1.0))
                .sqrt();
            let p = a * (z * p1 - b * p0);
            write(l, p);
            p0 = p1;
            p1 = p;
        }
    }
}

/// [`eval_into`] for a fixed band limit with the recurrences' constants (`sqrt((2m+1)/(2m))`,
/// `sqrt(2m+3)`, `a_lm`, `b_lm`) computed once, for evaluating the basis at many directions
/// (the SH bake evaluates it per finest texel). The constants are the same expressions as
/// [`eval_into`]'s, so [`Basis::eval_into`] is bit for bit what [`eval_into`] gives.
#[derive(Debug, Clone)]
pub struct Basis {
    lmax: usize,
    /// `sqrt((2m+1)/(2m))` for m = 1 … lmax (index m; entry 0 unused).
    pmm: Vec<f64>,
    /// `sqrt(2m+3)` for m = 0 … lmax.
    p1: Vec<f64>,
    /// `(a_lm, b_lm)` for m = 0 … lmax, l = m+2 … lmax, m-major.
    ab: Vec<(f64, f64)>,
}

impl Basis {
    /// The constants for every `l ≤ lmax`.
    pub fn new(lmax: usize) -> Self {
        let pmm = (0..=lmax)
            .map(|m| {
                if m == 0 {
                    0.0
                } else {
                    ((2 * m + 1) as f64 / (2 * m) as f64).sqrt()
                }
            })
            .collect();
        let p1 = (0..=lmax).map(|m| (2.0 * m as f64 + 3.0).sqrt()).collect();
        let mut ab = Vec::new();
        for m in 0..=lmax {
            let mf = m as f64;
            for l in m + 2..=lmax {
                let lf = l as f64;
                let a = ((4.0 * lf * lf - 1.0) / (lf * lf - mf * mf)).sqrt();
                let b = (((lf - 1.0) * (lf - 1.0) - mf * mf)
                    / (4.0 * (lf - 1.0) * (lf - 1.0) - 1.0))
                    .sqrt();
                ab.push((a, b));
            }
        }
        Self { lmax, pmm, p1, ab }
    }

    /// The band limit these constants are for.
    pub fn lmax(&self) -> usize {
        self.lmax
    }

    /// Writes `Y_lm(d)` for every `l ≤` [`Basis::lmax`] into `out[index(l, m)]`, bit for bit
    /// as [`eval_into`] does (`out` holds at least [`count`]`(lmax)` values).
    pub fn eval_into(&self, d: DVec3, out: &mut [f64]) {
        let lmax = self.lmax;
        let out = &mut out[..count(lmax)];
        let d = d.try_normalize().unwrap_or(DVec3::Z);
        let (x, y, z) = (d.x, d.y, d.z);
        let (mut c, mut s) = (1.0f64, 0.0f64);
        let mut pmm = 0.5 / PI.sqrt();
        let mut ab = self.ab.iter();
        for m in 0..=lmax {
            if m > 0 {
                pmm *= self.pmm[m];
                let cn = x * c - y * s;
                s = x * s + y * c;
                c = cn;
            }
            // Y_lm for m = 0 at index l² + l; for m > 0 the cos at l² + l + m, the sin at
            // l² + l − m.
            let mut write = |l: usize, p: f64| {
                let centre = l * l + l;
                if m == 0 {
                    out[centre] = p;
                } else {
                    out[centre + m] = std::f64::consts::SQRT_2 * p * c;
                    out[centre - m] = std::f64::consts::SQRT_2 * p * s;
                }
            };
            write(m, pmm);
            if m == lmax {
                break;
            }
            let mut p1 = self.p1[m] * z * pmm;
            write(m + 1, p1);
            let mut p0 = pmm;
            for (l, &(a, b)) in (m + 2..=lmax).zip(&mut ab) {
                let p = a * (z * p1 - b * p0);
                write(l, p);
                p0 = p1;
                p1 = p;
            }
        }
    }
}

/// `Y_lm(d)` for every `l ≤ lmax`, in (l, m) order ([`eval_into`]).
pub fn eval(lmax: usize, d: DVec3) -> Vec<f64> {
    let mut out = vec![0.0; count(lmax)];
    eval_into(lmax, d, &mut out);
    out
}

/// Legendre polynomials `P_0(x) … P_lmax(x)` by Bonnet's recurrence
/// `(l+1) P_{l+1} = (2l+1) x P_l − l P_{l−1}` (stable for `|x| ≤ 1`).
pub fn legendre(lmax: usize, x: f64) -> Vec<f64> {
    let mut p = vec![0.0; lmax + 1];
    p[0] = 1.0;
    if lmax >= 1 {
        p[1] = x;
    }
    for l in 1..lmax {
        let lf = l as f64;
        p[l + 1] = ((2.0 * lf + 1.0) * x * p[l] - lf * p[l - 1]) / (lf + 1.0);
    }
    p
}

/// The `n`-point Gauss–Legendre rule on [−1, 1]: nodes (ascending) and weights, exact for
/// polynomials of degree `2n − 1`. Nodes by Newton's method on `P_n` from Tricomi's
/// approximation, to full double precision.
pub fn gauss_legendre(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut nodes = vec![0.0; n];
    let mut weights = vec![0.0; n];
    let nf = n as f64;
    for i in 0..n.div_ceil(2) {
        // i-th root from the top, Tricomi's initial guess.
        let k = i as f64 + 1.0;
        let mut x =
            (PI * (k - 0.25) / (nf + 0.5)).cos() * (1.0 - (nf - 1.0) / (8.0 * nf * nf * nf));
        let mut dp = 1.0;
        for _ in 0..100 {
            // P_n(x) and P_{n−1}(x) by the recurrence.
            let (mut p0, mut p1) = (1.0, x);
            for l in 1..n {
                let lf = l as f64;
                let p2 = ((2.0 * lf + 1.0) * x * p1 - lf * p0) / (lf + 1.0);
                p0 = p1;
                p1 = p2;
            }
            let pn = if n == 0 { 1.0 } else { p1 };
            let pn1 = p0;
            dp = nf * (x * pn - pn1) / (x * x - 1.0);
            let dx = pn / dp;
            x -= dx;
            if dx.abs() < 1e-16 {
                break;
            }
        }
        let w = 2.0 / ((1.0 - x * x) * dp * dp);
        nodes[n - 1 - i] = x;
        nodes[i] = -x;
        weights[n - 1 - i] = w;
        weights[i] = w;
    }
    (nodes, weights)
}

/// A quadrature over the polar angle θ ∈ [0, π/2] (nodes θ and weights, `Σ w g(θ)` ≈
/// `∫ g(θ) dθ`) for zonal lobes as narrow as `width` radians around θ = 0: 16-point
/// Gauss–Legendre panels whose edges grow geometrically (ratio 1.25) from `width/8`, so a lobe
/// of any width from 10⁻⁶ rad to a hemisphere is resolved by a few hundred nodes.
pub fn polar_quadrature(width: f64) -> Vec<(f64, f64)> {
    let half = 0.5 * PI;
    let first = (width / 8.0).clamp(1e-7, half / 16.0);
    let mut edges = vec![0.0, first];
    while *edges.last().expect("non-empty") < half {
        let e = edges.last().expect("non-empty") * 1.25;
        edges.push(e.min(half));
    }
    let (x, w) = gauss_legendre(16);
    let mut out = Vec::with_capacity(16 * edges.len());
    for p in edges.windows(2) {
        let (a, b) = (p[0], p[1]);
        for (xi, wi) in x.iter().zip(&w) {
            out.push((0.5 * (a + b) + 0.5 * (b - a) * xi, 0.5 * (b - a) * wi));
        }
    }
    out
}

/// The zonal coefficients `ρ̂_l = 2π ∫ f(cos θ) P_l(cos θ) sin θ dθ`, l = 0 … `lmax`, of a
/// function `f(ω·n)` that vanishes for `ω·n ≤ 0` (every BRDF lobe of this crate): eq 11's
/// `ρ̂_l = Λ_l f_l` with `f_l = ∫ f Y_l0`, by [`polar_quadrature`] with the lobe's angular
/// `width`. Then `f(ω·n) = Σ_l ρ̂_l Σ_m Y_lm(ω) Y_lm(n)` and a lobe normalized to integrate to
/// 1 over the sphere has `ρ̂_0 = 1`.
pub fn zonal_coefficients(f: &dyn Fn(f64) -> f64, lmax: usize, width: f64) -> Vec<f64> {
    let mut out = vec![0.0; lmax + 1];
    for (theta, w) in polar_quadrature(width) {
        let (s, c) = theta.sin_cos();
        let v = f(c);
        if v == 0.0 {
            continue;
        }
        for (o, p) in out.iter_mut().zip(legendre(lmax, c)) {
            *o += 2.0 * PI * w * s * v * p;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn the_precomputed_basis_is_bit_for_bit_eval_into() {
        // Directions of every kind: random, the poles, the equator, unnormalized and zero.
        let mut rng = Rng(19);
        let mut dirs: Vec<DVec3> = (0..200).map(|_| rng.direction()).collect();
        dirs.extend([
            DVec3::Z,
            -DVec3::Z,
            DVec3::X,
            DVec3::new(0.0, -1.0, 0.0),
            DVec3::new(3.0, -4.0, 12.0),
            DVec3::ZERO,
        ]);
        for lmax in [0, 1, 2, 5, 16, 32] {
            let basis = Basis::new(lmax);
            assert_eq!(basis.lmax(), lmax);
            let mut got = vec![f64::NAN; count(lmax) + 3];
            for &d in &dirs {
                basis.eval_into(d, &mut got);
                let want = eval(lmax, d);
                for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                    assert_eq!(g.to_bits(), w.to_bits(), "lmax {lmax} index {i} at {d}");
                }
                assert!(got[count(lmax)..].iter().all(|v| v.is_nan()));
            }
        }
    }

    /// A product rule exact for polynomials of degree 2·lmax on the sphere: Gauss–Legendre in z
    /// (lmax + 1 nodes) times 2·lmax + 2 equally spaced azimuths.
    fn sphere_rule(lmax: usize) -> Vec<(DVec3, f64)> {
        let (zs, wz) = gauss_legendre(lmax + 1);
        let nphi = 2 * lmax + 2;
        let mut out = Vec::new();
        for (z, w) in zs.iter().zip(&wz) {
            let r = (1.0 - z * z).sqrt();
            for k in 0..nphi {
                let phi = 2.0 * PI * (k as f64 + 0.5) / nphi as f64;
                out.push((
                    DVec3::new(r * phi.cos(), r * phi.sin(), *z),
                    w * 2.0 * PI / nphi as f64,
                ));
            }
        }
        out
    }

    #[test]
    fn basis_is_orthonormal_to_1e12_up_to_l_32() {
        for lmax in [2, 16, 32] {
            let n = count(lmax);
            let mut gram = vec![0.0; n * n];
            let mut y = vec![0.0; n];
            for (d, w) in sphere_rule(lmax) {
                eval_into(lmax, d, &mut y);
                for i in 0..n {
                    for j in i..n {
                        gram[i * n + j] += w * y[i] * y[j];
                    }
                }
            }
            let mut worst = 0.0f64;
            for i in 0..n {
                for j in i..n {
                    let want = if i == j { 1.0 } else { 0.0 };
                    worst = worst.max((gram[i * n + j] - want).abs());
                }
            }
            assert!(worst < 1e-12, "lmax {lmax}: worst Gram error {worst:e}");
        }
    }

    #[test]
    fn closed_forms_up_to_l_2() {
        // Ramamoorthi & Hanrahan 2001 (irradiance environment maps), real form, no CS phase.
        let c0 = 0.5 / PI.sqrt();
        let c1 = (3.0 / (4.0 * PI)).sqrt();
        let c2 = 0.5 * (15.0 / PI).sqrt();
        let c20 = 0.25 * (5.0 / PI).sqrt();
        let mut rng = Rng(7);
        for _ in 0..50 {
            let d = rng.direction();
            let (x, y, z) = (d.x, d.y, d.z);
            let want = [
                c0,
                c1 * y,
                c1 * z,
                c1 * x,
                c2 * x * y,
                c2 * y * z,
                c20 * (3.0 * z * z - 1.0),
                c2 * x * z,
                0.5 * c2 * (x * x - y * y),
            ];
            let got = eval(2, d);
            for (k, (g, w)) in got.iter().zip(want).enumerate() {
                assert!((g - w).abs() < 1e-14, "coefficient {k}: {g} vs {w}");
            }
        }
    }

    #[test]
    fn band_energy_is_invariant_under_rotation() {
        // The coefficients of a sum of weighted deltas, before and after a random rotation of
        // every point: Σ_m γ_lm² per band is unchanged (the addition theorem).
        let lmax = 16;
        let mut rng = Rng(11);
        let points: Vec<(DVec3, f64)> = (0..40).map(|_| (rng.direction(), rng.uniform())).collect();
        let energy = |pts: &[(DVec3, f64)]| -> Vec<f64> {
            let mut c = vec![0.0; count(lmax)];
            for &(d, w) in pts {
                for (a, y) in c.iter_mut().zip(eval(lmax, d)) {
                    *a += w * y;
                }
            }
            (0..=lmax)
                .map(|l| (0..=2 * l).map(|k| c[l * l + k].powi(2)).sum())
                .collect()
        };
        let before = energy(&points);
        for _ in 0..5 {
            let q = glam::DQuat::from_axis_angle(rng.direction(), rng.range(0.0, 2.0 * PI));
            let rotated: Vec<(DVec3, f64)> = points.iter().map(|&(d, w)| (q * d, w)).collect();
            for (l, (a, b)) in before.iter().zip(energy(&rotated)).enumerate() {
                assert!((a - b).abs() <= 1e-12 * a.max(1e-3), "band {l}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn addition_theorem_gives_the_legendre_polynomial() {
        // Σ_m Y_lm(a) Y_lm(b) = (2l+1)/(4π) P_l(a·b): checks the zonal and the tesseral parts
        // against Bonnet's recurrence.
        let mut rng = Rng(3);
        let lmax = 20;
        for _ in 0..20 {
            let (a, b) = (rng.direction(), rng.direction());
            let (ya, yb) = (eval(lmax, a), eval(lmax, b));
            let p = legendre(lmax, a.dot(b));
            for (l, pl) in p.iter().enumerate() {
                let s: f64 = (l * l..(l + 1) * (l + 1)).map(|i| ya[i] * yb[i]).sum();
                let want = (2 * l + 1) as f64 / (4.0 * PI) * pl;
                assert!((s - want).abs() < 1e-12, "l {l}: {s} vs {want}");
            }
        }
    }

    #[test]
    fn gauss_legendre_integrates_polynomials_exactly() {
        for n in [1, 2, 5, 16, 64] {
            let (x, w) = gauss_legendre(n);
            for k in 0..2 * n {
                let got: f64 = x.iter().zip(&w).map(|(x, w)| w * x.powi(k as i32)).sum();
                let want = if k % 2 == 0 {
                    2.0 / (k as f64 + 1.0)
                } else {
                    0.0
                };
                assert!((got - want).abs() < 1e-13, "n {n} k {k}: {got} vs {want}");
            }
        }
    }

    #[test]
    fn a_constant_and_a_vmf_lobe_have_their_closed_form_coefficients() {
        // The constant 1: only Y_00, with coefficient sqrt(4π).
        let mut c = vec![0.0; count(6)];
        let mut y = vec![0.0; count(6)];
        for (d, w) in sphere_rule(6) {
            eval_into(6, d, &mut y);
            for (a, v) in c.iter_mut().zip(&y) {
                *a += w * v;
            }
        }
        assert!((c[0] - (4.0 * PI).sqrt()).abs() < 1e-12);
        assert!(c[1..].iter().all(|v| v.abs() < 1e-12), "{c:?}");
        // A normalized vMF lobe (eq 15): Λ_l γ_l = I_{l+1/2}(κ)/I_{1/2}(κ), which is 1, A(κ)
        // (eq 16), 1 − 3A/κ, A − 5(1 − 3A/κ)/κ for l = 0 … 3 (the Bessel recurrence), by
        // Gauss–Legendre over the whole sphere; eq 19's e^{−l²/2κ} approximates them.
        for kappa in [2.0f64, 10.0, 40.0] {
            let (x, w) = gauss_legendre(200);
            let norm = kappa / (2.0 * PI * -(-2.0 * kappa).exp_m1());
            let mut got = [0.0; 4];
            for (xi, wi) in x.iter().zip(&w) {
                let density = norm * (kappa * (xi - 1.0)).exp();
                for (l, p) in legendre(3, *xi).iter().enumerate() {
                    got[l] += 2.0 * PI * wi * density * p;
                }
            }
            let a = 1.0 / kappa.tanh() - 1.0 / kappa;
            let r2 = 1.0 - 3.0 * a / kappa;
            let want = [1.0, a, r2, a - 5.0 * r2 / kappa];
            for l in 0..4 {
                assert!(
                    (got[l] - want[l]).abs() < 1e-12,
                    "κ={kappa} l={l}: {}",
                    got[l]
                );
                // eq 19 drops a factor: the exact values are close to e^{−l(l+1)/2κ}, eq 19 is
                // e^{−l²/2κ} (0.103 too high at κ = 10, l = 3; about 0.03 at κ = 40).
                let eq19 = (-((l * l) as f64) / (2.0 * kappa)).exp();
                let better = (-((l * (l + 1)) as f64) / (2.0 * kappa)).exp();
                if kappa >= 10.0 {
                    assert!((got[l] - eq19).abs() < 0.11, "κ={kappa} l={l}: {eq19}");
                    assert!((got[l] - better).abs() < 0.015, "κ={kappa} l={l}: {better}");
                }
            }
        }
    }

    #[test]
    fn lambert_coefficients_are_the_closed_forms() {
        // ρ̂_l of max(u, 0): π, 2π/3, π/4, 0, −π/24, 0, π/64 (Ramamoorthi & Hanrahan 2001).
        let r = zonal_coefficients(&|u: f64| u.max(0.0), 6, PI);
        let want = [
            PI,
            2.0 * PI / 3.0,
            PI / 4.0,
            0.0,
            -PI / 24.0,
            0.0,
            PI / 64.0,
        ];
        for (l, (g, w)) in r.iter().zip(want).enumerate() {
            assert!((g - w).abs() < 1e-13, "l {l}: {g} vs {w}");
        }
    }
}
