//! Spherical-harmonic projection of an environment (Han et al. 2007 Sec 8, eqs 24–26): the
//! coefficients `L_lm`, their rotation into another frame, and the view-dependent
//! reparameterized lighting `L′_lm(ω_o)` of eq 26 on a grid of view directions.
//!
//! **Projection.** `L_lm = ∫ L Y_lm dω` over the piecewise-constant radiance, each texel
//! integrated with 2 × 2 sub-samples uniform in solid angle, each of weight `Ω_texel/4`
//! (exact solid angles, [`super::Geometry::solid_angle`]; a panorama of fewer than 32 rows on
//! the grid of texels split to 32 rows, [`super::Geometry::refinement`]), in the basis of
//! [`crate::harmonics`] (real, orthonormal, no Condon–Shortley phase), f64 sums in row order.
//! **A bright sun** is one texel (or a few) of huge radiance: its projection is exact for the
//! piecewise-constant map up to the sub-sampling of `Y_lm` inside its texel, whose error at
//! l ≤ 8 is below 10⁻⁴ relative for any panorama of 64 × 32 texels or more (a texel spans less
//! than 3°, a band-8 lobe 22°). What SH cannot avoid is *ringing*: the truncated series of a
//! point source has negative side lobes of about 10 % of its peak at l* = 8. The shading sums
//! are clamped at 0 (as `sh::shade` clamps the NDF's), and `docs/environment.md` measures how
//! far the route is from the ground truth under the sun.
//!
//! **Rotation** ([`rotate`]): by re-projection with a quadrature exact for band-limited
//! functions (Gauss–Legendre in `cos θ` with l*+1 nodes × 2l*+2 azimuths), so a rotated set of
//! coefficients is exact to rounding for any rotation.
//!
//! **`L′` (eq 26).** `L′(ω_h) = L(ω_i(ω_h, ω_o)) · 4(ω_i·ω_h)`, and with `dω_h = dω_i/(4 ω_i·ω_h)`
//! its coefficients are `L′_lm(ω_o) = ∫ L(ω_i) Y_lm(normalize(ω_i + ω_o)) dω_i`: an integral over
//! the environment's own texels, no resampling of a warped map. It is computed on a
//! [`REFLECTED_GRID`]² grid of views over the upper hemisphere (θ_o = 0 … 90° including both
//! ends, φ_o every 360°/16) from the environment downsampled to at most 128 texels across
//! (powers kept exactly; a sun moves by at most half a coarse texel, 0.7°), each texel at its
//! centre (split to 32 rows first when it has fewer, as for the projection), and interpolated
//! bilinearly in (θ_o, φ_o) as a shader reads it from a texture.

use super::Radiance;
use crate::harmonics::{Basis, count, gauss_legendre};
use glam::{DMat3, DVec3};
use rayon::prelude::*;
use std::f64::consts::PI;

/// Largest band limit of an environment projection.
pub const MAX_LMAX: usize = 16;

/// Views per axis of the `L′` table (the paper's "about 16 × 16").
pub const REFLECTED_GRID: usize = 16;

/// Widest environment the `L′` table integrates (the panorama is downsampled to it).
pub const REFLECTED_WIDTH: u32 = 128;

/// `L_lm` for l ≤ `lmax` (module docs), `(lmax + 1)²` numbers in (l, m) order.
pub fn project(env: &Radiance, lmax: usize) -> Vec<f64> {
    let lmax = lmax.min(MAX_LMAX);
    let n = count(lmax);
    let basis = Basis::new(lmax);
    let m = env.grid().refinement();
    let g = env.grid().refined(m);
    let (w, m) = (env.width() as usize, m as usize);
    let rows: Vec<Vec<f64>> = (0..g.height as usize)
        .into_par_iter()
        .map(|y| {
            let mut acc = vec![0.0f64; n];
            let mut yv = vec![0.0f64; n];
            let wgt = g.solid_angle(y as u32) / 4.0;
            for x in 0..g.width as usize {
                let v = env.values()[y / m * w + x / m] as f64;
                if v == 0.0 {
                    continue;
                }
                for (fx, fy) in [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)] {
                    basis.eval_into(g.sub_direction(x as u32, y as u32, fx, fy), &mut yv);
                    for (a, b) in acc.iter_mut().zip(&yv) {
                        *a += v * wgt * b;
                    }
                }
            }
            acc
        })
        .collect();
    let mut out = vec![0.0f64; n];
    for r in rows {
        for (o, v) in out.iter_mut().zip(r) {
            *o += v;
        }
    }
    out
}

/// Evaluates a band-limited function from its coefficients at direction `d`.
pub fn eval(coeffs: &[f64], lmax: usize, d: DVec3) -> f64 {
    let y = crate::harmonics::eval(lmax, d);
    coeffs.iter().zip(&y).map(|(c, y)| c * y).sum()
}

/// The coefficients of the rotated function `f′(d) = f(Rᵀ d)` (f carried along by the rotation
/// `r`), exact to rounding (module docs).
pub fn rotate(coeffs: &[f64], lmax: usize, r: DMat3) -> Vec<f64> {
    let n = count(lmax);
    let (z, wz) = gauss_legendre(lmax + 1);
    let nphi = 2 * lmax + 2;
    let mut out = vec![0.0f64; n];
    let mut y = vec![0.0f64; n];
    let mut y2 = vec![0.0f64; n];
    let basis = Basis::new(lmax);
    let rt = r.transpose();
    for (&zi, &wi) in z.iter().zip(&wz) {
        let s = (1.0 - zi * zi).max(0.0).sqrt();
        for j in 0..nphi {
            let phi = 2.0 * PI * j as f64 / nphi as f64;
            let d = DVec3::new(s * phi.cos(), s * phi.sin(), zi);
            basis.eval_into(rt * d, &mut y2);
            let f: f64 = coeffs[..n].iter().zip(&y2).map(|(c, y)| c * y).sum();
            basis.eval_into(d, &mut y);
            let wgt = wi * 2.0 * PI / nphi as f64 * f;
            for (o, v) in out.iter_mut().zip(&y) {
                *o += wgt * v;
            }
        }
    }
    out
}

/// The band blocks of the rotation by +90° about x, `D(R_x(90°))` in [`rotate`]'s convention,
/// for l ≤ `lmax`: band l's `(2l+1)²` entries row-major (row = output m, column = input m),
/// bands one after another (`Σ (2l+1)²` numbers). What [`rotate_zyz`] and the shaders'
/// per-fragment rotation (`glsl/ndf_env.glsl`, a generated constant) multiply by.
pub fn x90_blocks(lmax: usize) -> Vec<f64> {
    let lmax = lmax.min(MAX_LMAX);
    let r = DMat3::from_rotation_x(0.5 * PI);
    let mut out = Vec::new();
    for l in 0..=lmax {
        let w = 2 * l + 1;
        let mut block = vec![0.0f64; w * w];
        for j in 0..w {
            // Column j: the rotated unit coefficient vector of (l, m = j − l).
            let mut e = vec![0.0f64; count(lmax)];
            e[l * l + j] = 1.0;
            let col = rotate(&e, lmax, r);
            for i in 0..w {
                let v = col[l * l + i];
                block[i * w + j] = if v.abs() < 1e-12 { 0.0 } else { v };
            }
        }
        out.extend(block);
    }
    out
}

/// The z-y-z Euler angles `(α, β, γ)` of a rotation, `r = R_z(α) R_y(β) R_z(γ)`; in the two
/// degenerate cases (`sin β` below 10⁻⁶) α = 0 and γ carries the rotation about z.
pub fn zyz_angles(r: DMat3) -> (f64, f64, f64) {
    let f = |i: usize, j: usize| r.col(j)[i];
    let s = f(0, 2).hypot(f(1, 2));
    if s < 1e-6 {
        if f(2, 2) > 0.0 {
            (0.0, 0.0, f(1, 0).atan2(f(0, 0)))
        } else {
            (0.0, PI, f(1, 0).atan2(-f(0, 0)))
        }
    } else {
        (
            f(1, 2).atan2(f(0, 2)),
            s.atan2(f(2, 2)),
            f(2, 1).atan2(-f(2, 0)),
        )
    }
}

/// Rotation of band-limited coefficients about z by `a` in [`rotate`]'s convention
/// (`f′(d) = f(R_z(a)ᵀ d)`): each (m, −m) pair turns by m·a.
fn rotate_z(c: &mut [f64], lmax: usize, a: f64) {
    for l in 1..=lmax {
        let centre = l * l + l;
        for m in 1..=l {
            let (s, co) = (m as f64 * a).sin_cos();
            let (p, q) = (c[centre + m], c[centre - m]);
            c[centre + m] = p * co - q * s;
            c[centre - m] = p * s + q * co;
        }
    }
}

/// Multiplies each band by its block of `x90` ([`x90_blocks`]), transposed if `transpose`
/// (the rotation by −90°).
fn rotate_x90(c: &mut [f64], lmax: usize, x90: &[f64], transpose: bool) {
    let mut offset = 0;
    let mut tmp = [0.0f64; 2 * MAX_LMAX + 1];
    for l in 0..=lmax {
        let w = 2 * l + 1;
        let band = &mut c[l * l..l * l + w];
        for (i, t) in tmp.iter_mut().enumerate().take(w) {
            *t = (0..w)
                .map(|j| {
                    let k = if transpose { j * w + i } else { i * w + j };
                    x90[offset + k] * band[j]
                })
                .sum();
        }
        band.copy_from_slice(&tmp[..w]);
        offset += w * w;
    }
}

/// [`rotate`] by the z-y-z factorization `D(r) = D(R_z α) D(R_x −90°) D(R_z β) D(R_x 90°) D(R_z γ)`
/// (`R_y(β) = R_x(−90°) R_z(β) R_x(90°)`): about `2 Σ (2l+1)²` multiplications instead of a
/// quadrature, what the environment shaders do per fragment (`ndf_env_rotate` in
/// `glsl/ndf_env.glsl`) and the CPU twin per pixel. `x90` is [`x90_blocks`] of at least `lmax`.
pub fn rotate_zyz(coeffs: &[f64], lmax: usize, r: DMat3, x90: &[f64]) -> Vec<f64> {
    let (a, b, g) = zyz_angles(r);
    let mut c = coeffs[..count(lmax)].to_vec();
    rotate_z(&mut c, lmax, g);
    rotate_x90(&mut c, lmax, x90, false);
    rotate_z(&mut c, lmax, b);
    rotate_x90(&mut c, lmax, x90, true);
    rotate_z(&mut c, lmax, a);
    c
}

/// `L′_lm(ω_o)` (eq 26) on the grid of views (module docs), for the shader's texture and the
/// CPU twin's interpolation.
#[derive(Debug, Clone)]
pub struct ReflectedTable {
    lmax: usize,
    /// `coeffs[(iθ · REFLECTED_GRID + iφ) · count(lmax) + index(l, m)]`.
    coeffs: Vec<f64>,
}

impl ReflectedTable {
    /// Computes the table for band limit `lmax` (≤ [`MAX_LMAX`]).
    pub fn new(env: &Radiance, lmax: usize) -> ReflectedTable {
        let lmax = lmax.min(MAX_LMAX);
        let n = count(lmax);
        let small = env.downsample_to(REFLECTED_WIDTH);
        let m = small.grid().refinement();
        let g = small.grid().refined(m);
        let basis = Basis::new(lmax);
        let texels: Vec<(DVec3, f64)> = (0..g.height)
            .flat_map(|y| (0..g.width).map(move |x| (x, y)))
            .map(|(x, y)| {
                let v = small.values()[(y / m * small.width() + x / m) as usize] as f64;
                (g.direction(x, y), v * g.solid_angle(y))
            })
            .filter(|t| t.1 > 0.0)
            .collect();
        let views: Vec<DVec3> = (0..REFLECTED_GRID * REFLECTED_GRID)
            .map(|i| view_of(i / REFLECTED_GRID, i % REFLECTED_GRID))
            .collect();
        let per_view: Vec<Vec<f64>> = views
            .par_iter()
            .map(|&o| {
                let mut acc = vec![0.0f64; n];
                let mut y = vec![0.0f64; n];
                for &(d, lw) in &texels {
                    let Some(h) = (d + o).try_normalize() else {
                        continue;
                    };
                    basis.eval_into(h, &mut y);
                    for (a, b) in acc.iter_mut().zip(&y) {
                        *a += lw * b;
                    }
                }
                acc
            })
            .collect();
        ReflectedTable {
            lmax,
            coeffs: per_view.concat(),
        }
    }

    /// The band limit.
    pub fn lmax(&self) -> usize {
        self.lmax
    }

    /// The table as f32 for upload: `REFLECTED_GRID²` views (θ_o rows, φ_o columns), each
    /// `count(lmax)` coefficients.
    pub fn packed(&self) -> Vec<f32> {
        self.coeffs.iter().map(|&v| v as f32).collect()
    }

    /// `L′_lm(ω_o)` bilinearly interpolated in (θ_o, φ_o) (views below the horizon read the
    /// horizon's row).
    pub fn at(&self, view: DVec3) -> Vec<f64> {
        let n = count(self.lmax);
        let v = view.try_normalize().unwrap_or(DVec3::Z);
        let step_t = 0.5 * PI / (REFLECTED_GRID - 1) as f64;
        let t = (v.z.clamp(0.0, 1.0).acos() / step_t).clamp(0.0, (REFLECTED_GRID - 1) as f64);
        let p = (super::azimuth(v) + PI) / (2.0 * PI) * REFLECTED_GRID as f64;
        let (t0, p0) = (t.floor() as usize, p.floor());
        let (ft, fp) = (t - t0 as f64, p - p0);
        let t1 = (t0 + 1).min(REFLECTED_GRID - 1);
        let p0 = (p0 as i64).rem_euclid(REFLECTED_GRID as i64) as usize;
        let p1 = (p0 + 1) % REFLECTED_GRID;
        let at = |i: usize, j: usize| &self.coeffs[(i * REFLECTED_GRID + j) * n..][..n];
        let w = [
            ((1.0 - ft) * (1.0 - fp), at(t0, p0)),
            ((1.0 - ft) * fp, at(t0, p1)),
            (ft * (1.0 - fp), at(t1, p0)),
            (ft * fp, at(t1, p1)),
        ];
        (0..n)
            .map(|k| w.iter().map(|(wt, c)| wt * c[k]).sum())
            .collect()
    }
}

/// The view of grid cell (iθ, iφ): θ_o = iθ·90°/15, φ_o = −180° + iφ·360°/16.
pub fn view_of(it: usize, ip: usize) -> DVec3 {
    let t = 0.5 * PI * it as f64 / (REFLECTED_GRID - 1) as f64;
    let p = -PI + 2.0 * PI * ip as f64 / REFLECTED_GRID as f64;
    DVec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::harmonics::index;
    use crate::rng::Rng;

    fn from_fn(w: u32, f: impl Fn(DVec3) -> f64) -> Radiance {
        let g = Radiance::geometry(w, w / 2);
        let v: Vec<f32> = (0..w / 2)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| f(g.direction(x, y)) as f32)
            .collect();
        Radiance::new(w, w / 2, v).unwrap()
    }

    #[test]
    fn projection_recovers_band_limited_functions() {
        // 2 + Y_1,1-like x + 0.5·(3z² − 1): coefficients known in closed form.
        let env = from_fn(512, |d| 2.0 + d.x + 0.5 * (3.0 * d.z * d.z - 1.0));
        let c = project(&env, 4);
        let k1 = (4.0 * PI / 3.0).sqrt(); // x = k1·Y_11
        let k2 = (16.0 * PI / 5.0).sqrt(); // 3z² − 1 = k2·Y_20
        assert!((c[0] - 2.0 * (4.0 * PI).sqrt()).abs() < 1e-3, "{}", c[0]);
        assert!((c[index(1, 1)] - k1).abs() < 1e-3);
        assert!((c[index(2, 0)] - 0.5 * k2).abs() < 1e-3);
        for (i, v) in c.iter().enumerate() {
            if ![0, index(1, 1), index(2, 0)].contains(&i) {
                assert!(v.abs() < 1e-3, "{i} {v}");
            }
        }
    }

    #[test]
    fn rotation_is_exact_and_matches_rotating_the_map() {
        let mut rng = Rng(11);
        let lmax = 6;
        let c: Vec<f64> = (0..count(lmax)).map(|_| rng.normal()).collect();
        let r = DMat3::from_axis_angle(rng.direction(), 1.1);
        let cr = rotate(&c, lmax, r);
        for _ in 0..20 {
            let d = rng.direction();
            let a = eval(&cr, lmax, r * d);
            let b = eval(&c, lmax, d);
            assert!((a - b).abs() < 1e-10, "{a} {b}");
        }
    }

    #[test]
    fn zyz_rotation_equals_the_quadrature_rotation() {
        let mut rng = Rng(23);
        let lmax = 8;
        let x90 = x90_blocks(lmax);
        let c: Vec<f64> = (0..count(lmax)).map(|_| rng.normal()).collect();
        let mut rotations: Vec<DMat3> = (0..6)
            .map(|i| DMat3::from_axis_angle(rng.direction(), 0.4 + i as f64))
            .collect();
        // The degenerate Euler cases: about z only, and turned upside down.
        rotations.push(DMat3::from_rotation_z(0.8));
        rotations.push(DMat3::from_rotation_x(PI) * DMat3::from_rotation_z(-1.3));
        rotations.push(DMat3::IDENTITY);
        for r in rotations {
            let exact = rotate(&c, lmax, r);
            let fast = rotate_zyz(&c, lmax, r, &x90);
            for (a, b) in exact.iter().zip(&fast) {
                assert!((a - b).abs() < 1e-9, "{a} {b}");
            }
        }
    }

    /// A constant panorama of 2 × 1 to 16 × 8 texels projects as a 64 × 32 one does, and has its
    /// `L′` table: its texels are split to 32 rows first (its centres alone gave a 2 × 1
    /// constant an l = 2 energy of 0.99 against l = 0's 3.54, and a flat map's diffuse term
    /// under it 15.6 % of error).
    #[test]
    fn small_panoramas_project_like_large_ones() {
        let fine = ReflectedTable::new(&Radiance::constant(64, 1.0), 4);
        // The 64 × 32 constant's own projection: l = 0 exact, the rest within 5·10⁻³.
        let reference = project(&Radiance::constant(64, 1.0), 8);
        assert!((reference[0] - (4.0 * PI).sqrt()).abs() < 1e-9);
        assert!(
            reference[1..].iter().all(|v| v.abs() < 5e-3),
            "{reference:?}"
        );
        for w in [2, 4, 8, 16] {
            // Split to 32 rows, the panorama is integrated on the 64 × 32 grid itself.
            assert_eq!(project(&Radiance::constant(w, 1.0), 8), reference, "{w}");
            let t = ReflectedTable::new(&Radiance::constant(w, 1.0), 4);
            let mut rng = Rng(3);
            for _ in 0..10 {
                let o = rng.upper();
                assert_eq!(t.at(o), fine.at(o), "{w}");
            }
        }
    }

    #[test]
    fn reflected_table_of_a_constant_is_the_half_vector_density() {
        // L = 1: L′_00(ω_o) = ∫ Y_00 dω_i = √(4π) for any view; interpolation keeps it.
        let t = ReflectedTable::new(&Radiance::constant(64, 1.0), 2);
        let mut rng = Rng(5);
        for _ in 0..10 {
            let c = t.at(rng.upper());
            assert!((c[0] - (4.0 * PI).sqrt()).abs() < 1e-9, "{}", c[0]);
        }
    }
}
