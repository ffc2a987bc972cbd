//! The prefiltered environment (the Gaussian-mixture paper's Sec 4, eqs 8–10): levels of the
//! environment convolved with normalized vMF lobes, looked up at a level set by a lobe's width,
//! `LOD = ½·log2(Ω_s/Ω_p)`.
//!
//! **Lobe-prefiltered levels, not a box MIP chain.** A box-filtered MIP chain of an
//! equirectangular map blurs each texel over a footprint whose solid angle shrinks as `sin θ`
//! towards the poles and is square in (φ, θ), not on the sphere: near the zenith — where a
//! sky's sun often is and where every upward-facing lobe looks — its levels are too narrow
//! across and too wide along the meridians. Here level k is the environment convolved on the
//! sphere with a normalized vMF lobe `C(κ_k) e^{κ_k(ω·ω' − 1)}` (each output texel the
//! solid-angle-weighted, renormalized sum over the input texels within `5/√κ` of it), stored on
//! an equirectangular grid of half the previous resolution (never below 16 × 8 texels, enough
//! for the widest lobe). The lookup is then the lobe's own convolution at every latitude, and a
//! GPU samples the levels as an ordinary mipmapped texture (trilinear between levels).
//!
//! **Levels.** With `Ω_s(κ) = 2π/κ` (eq 8 at coverage `a = 1 − 1/e`) and `Ω_p = 2π²/(W·H)`
//! (eq 9, a texel at the equator of level 0), level k has `κ_k = κ_0 / 4^k`, `κ_0 = W·H/π`,
//! so `LOD(κ) = ½ log2(κ_0/κ)`: one level per halving of the lobe's angular width. Level 0 is
//! the environment itself; levels continue until `κ_k < 1/4` (a lobe wider than a hemisphere).
//! A lobe sharper than `κ_0` (κ → ∞) reads level 0. Level k is made from level k − 1 (downsampled
//! by 2 with solid-angle weights while above 16 × 8) convolved with the increment
//! `1/κ_Δ = 1/κ_k − 1/κ_{k−1}` (vMF variances add, exact in the small-angle limit).
//!
//! Every level keeps `∫ L dω` up to the renormalization at each texel (a constant environment
//! stays exactly constant), so the prefiltered lookup of a black environment is exactly 0 and
//! of a single-texel sun is bounded by the sun's power times the lobe's peak density.

use super::Radiance;
use glam::DVec3;
use rayon::prelude::*;

/// Smallest width of a prefiltered level.
pub const MIN_WIDTH: u32 = 16;

/// The smallest κ a level is made for (a lobe wider than a hemisphere): levels stop below it.
pub const KAPPA_FLOOR: f64 = 0.25;

/// One prefiltered level: the environment convolved with a vMF lobe of concentration `kappa`.
#[derive(Debug, Clone)]
pub struct Level {
    /// The convolved radiance on its grid.
    pub radiance: Radiance,
    /// The lobe's concentration (∞ for level 0, the environment itself).
    pub kappa: f64,
}

/// The levels of a prefiltered environment (module docs).
#[derive(Debug, Clone)]
pub struct Prefiltered {
    levels: Vec<Level>,
    kappa0: f64,
}

impl Prefiltered {
    /// Prefilters `env` (module docs). Deterministic whatever the thread count (each output
    /// texel is one sum in a fixed order).
    pub fn new(env: &Radiance) -> Prefiltered {
        let kappa0 = env.width() as f64 * env.height() as f64 / std::f64::consts::PI;
        let mut levels = vec![Level {
            radiance: env.clone(),
            kappa: f64::INFINITY,
        }];
        let mut k = 1;
        loop {
            let kappa = kappa0 / 4f64.powi(k);
            if kappa < KAPPA_FLOOR {
                break;
            }
            let prev = levels.last().expect("level 0");
            let src = if prev.radiance.width() > MIN_WIDTH {
                prev.radiance.downsample()
            } else {
                prev.radiance.clone()
            };
            let inc = 1.0 / kappa - 1.0 / prev.kappa;
            let radiance = convolve(&src, 1.0 / inc);
            levels.push(Level { radiance, kappa });
            k += 1;
        }
        Prefiltered { levels, kappa0 }
    }

    /// The levels, level 0 (the environment) first.
    pub fn levels(&self) -> &[Level] {
        &self.levels
    }

    /// `κ_0 = W·H/π`: the concentration whose `Ω_s` is level 0's texel (`LOD = 0`).
    pub fn kappa0(&self) -> f64 {
        self.kappa0
    }

    /// `LOD = ½ log2(Ω_s/Ω_p) = ½ log2(κ_0/κ)`, clamped to the levels (κ → ∞ and NaN give 0).
    pub fn lod(&self, kappa: f64) -> f64 {
        if kappa.is_nan() || kappa >= self.kappa0 {
            return 0.0;
        }
        let last = (self.levels.len() - 1) as f64;
        if kappa <= 0.0 {
            return last;
        }
        (0.5 * (self.kappa0 / kappa).log2()).clamp(0.0, last)
    }

    /// The environment convolved with a normalized vMF lobe of concentration `kappa` about `d`,
    /// as a GPU's trilinear lookup gives it: bilinear in the two levels around [`Self::lod`],
    /// linear between them.
    pub fn lookup(&self, d: DVec3, kappa: f64) -> f64 {
        let lod = self.lod(kappa);
        let i = lod.floor() as usize;
        let t = lod - i as f64;
        let a = self.levels[i].radiance.bilinear(d);
        if t <= 0.0 || i + 1 >= self.levels.len() {
            return a;
        }
        (1.0 - t) * a + t * self.levels[i + 1].radiance.bilinear(d)
    }
}

/// `env` convolved with a normalized vMF lobe of concentration `kappa` on its own grid
/// (renormalized per output texel; window `5/√κ`).
pub fn convolve(env: &Radiance, kappa: f64) -> Radiance {
    let g = env.grid();
    let (w, h) = (env.width() as usize, env.height() as usize);
    let radius = (5.0 / kappa.max(1e-12).sqrt()).min(std::f64::consts::PI);
    let cos_r = radius.cos();
    let dirs: Vec<DVec3> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| g.direction(x as u32, y as u32))
        .collect();
    let omega: Vec<f64> = (0..h).map(|y| env.solid_angle(y as u32)).collect();
    let theta = |y: usize| std::f64::consts::PI * (y as f64 + 0.5) / h as f64;
    let dphi = 2.0 * std::f64::consts::PI / w as f64;
    let values = env.values();
    let rows: Vec<Vec<f32>> = (0..h)
        .into_par_iter()
        .map(|yo| {
            let to = theta(yo);
            // Input rows in reach and their azimuth half-widths (in texels).
            let mut reach = Vec::new();
            for yi in 0..h {
                let ti = theta(yi);
                if (ti - to).abs() > radius + std::f64::consts::PI / h as f64 {
                    continue;
                }
                let den = to.sin() * ti.sin();
                let half = if radius >= std::f64::consts::PI || den < 1e-12 {
                    w
                } else {
                    let c = (cos_r - to.cos() * ti.cos()) / den;
                    if c >= 1.0 {
                        // The cone only grazes this row: take the nearest texels.
                        1
                    } else if c <= -1.0 {
                        w
                    } else {
                        ((c.acos() / dphi).ceil() as usize + 1).min(w)
                    }
                };
                reach.push((yi, half));
            }
            (0..w)
                .map(|xo| {
                    let d = dirs[yo * w + xo];
                    let (mut num, mut den) = (0.0f64, 0.0f64);
                    for &(yi, half) in &reach {
                        let row = &values[yi * w..(yi + 1) * w];
                        let xs: Box<dyn Iterator<Item = usize>> = if 2 * half + 1 >= w {
                            Box::new(0..w)
                        } else {
                            Box::new((0..2 * half + 1).map(move |j| (xo + w + j - half) % w))
                        };
                        for xi in xs {
                            let wgt = omega[yi] * (kappa * (d.dot(dirs[yi * w + xi]) - 1.0)).exp();
                            num += wgt * row[xi] as f64;
                            den += wgt;
                        }
                    }
                    if den > 0.0 { (num / den) as f32 } else { 0.0 }
                })
                .collect()
        })
        .collect();
    Radiance::new(env.width(), env.height(), rows.concat()).expect("same grid")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn constant_stays_constant_and_black_stays_black() {
        let p = Prefiltered::new(&Radiance::constant(64, 2.5));
        for l in p.levels() {
            for &v in l.radiance.values() {
                assert!((v - 2.5).abs() < 1e-5, "{v}");
            }
        }
        let p = Prefiltered::new(&Radiance::constant(64, 0.0));
        let mut rng = Rng(3);
        for _ in 0..100 {
            assert_eq!(p.lookup(rng.direction(), rng.range(0.0, 1e4)), 0.0);
        }
    }

    #[test]
    fn levels_match_the_direct_convolution() {
        // A smooth environment (1 + z + x²) against the vMF convolution by quadrature.
        let (w, h) = (128u32, 64u32);
        let g = Radiance::geometry(w, h);
        let f = |d: DVec3| 1.0 + d.z + d.x * d.x;
        let v: Vec<f32> = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| f(g.direction(x, y)) as f32)
            .collect();
        let env = Radiance::new(w, h, v).unwrap();
        let p = Prefiltered::new(&env);
        // vMF smoothing of a band-limited function: band l scales by A_l(κ) (≈ e^{−l(l+1)/2κ}):
        // for 1 + z + x², l = 1 by coth κ − 1/κ, and x² = 1/3 + (x² − 1/3) with l = 2 by
        // 1 − 3 A_1/κ.
        for l in &p.levels()[2..] {
            let k = l.kappa;
            let a1 = 1.0 / k.tanh() - 1.0 / k;
            let a2 = 1.0 - 3.0 * a1 / k;
            for d in [
                DVec3::Z,
                DVec3::new(0.6, 0.0, 0.8),
                DVec3::new(0.0, -1.0, 0.0),
            ] {
                let exact = 1.0 + a1 * d.z + 1.0 / 3.0 + a2 * (d.x * d.x - 1.0 / 3.0);
                let got = l.radiance.bilinear(d);
                assert!(
                    (got - exact).abs() < 0.03 * exact,
                    "κ={k} {d} {got} {exact}"
                );
            }
        }
    }

    #[test]
    fn sharp_lobes_read_level_zero() {
        let p = Prefiltered::new(&Radiance::constant(32, 1.0));
        assert_eq!(p.lod(f64::INFINITY), 0.0);
        assert_eq!(p.lod(1e30), 0.0);
        assert_eq!(p.lod(f64::NAN), 0.0);
        assert_eq!(p.lod(p.kappa0() / 4.0), 1.0);
        assert_eq!(p.lod(0.0), (p.levels().len() - 1) as f64);
    }
}
