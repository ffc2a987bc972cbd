//! The prefiltered environment (the Gaussian-mixture paper's Sec 4, eqs 8–10): levels of the
//! environment convolved with normalized vMF lobes, looked up at the level a lobe's width
//! picks (issue 16; the layout and its measurements: docs/environment.md, "The prefiltered
//! levels").
//!
//! **Lobe-prefiltered levels, not a box MIP chain.** A box-filtered MIP chain of an
//! equirectangular map blurs each texel over a footprint whose solid angle shrinks as `sin θ`
//! towards the poles and is square in (φ, θ), not on the sphere: near the zenith — where a
//! sky's sun often is and where every upward-facing lobe looks — its levels are too narrow
//! across and too wide along the meridians. Here level k ≥ 1 is the environment convolved on
//! the sphere with a normalized vMF lobe `C(κ_k) e^{κ_k(ω·ω' − 1)}`, each output texel the
//! solid-angle-weighted, renormalized sum over the input texels within `5/√κ` of it.
//!
//! **Each level's grid resolves its lobe.** A level whose lobe is narrower than its texels
//! cannot be read bilinearly: a convolved point sun then rises and falls by tens of per cent
//! with where it falls between the nodes. Level k's grid spacing (`2π/W_k` at the equator,
//! `π/H_k` along the meridians, finer in φ towards the poles) is at most [`SPACING`] `= ½` of
//! the lobe's `σ_k = 1/√κ_k`, so a bilinear read of a convolved point source is within a few
//! per cent of its peak wherever it falls (the tests measure it against the closed form).
//! Level 1 is on the environment's own grid (at most [`GRID_CAP`] wide; a wider environment
//! halves it first), `κ_1 = (SPACING · W_1 / 2π)²`.
//!
//! **Factor-2 steps in κ.** `κ_k = κ_1 / 2^{k−1}`; the grid halves every second level, so
//! levels come in pairs on one grid (the first at spacing `½σ`, the second at `σ/(2√2)`),
//! never below [`MIN_WIDTH`] × 8 texels; levels stop below [`KAPPA_FLOOR`] (a lobe wider than
//! a hemisphere). With factor-4 steps a point sun looked up between two levels was up to 25 %
//! too bright; here the blend between the two levels around κ is linear in κ
//! ([`Prefiltered::blend`]), which keeps a point source's peak (`∝ κ`) exact and is within
//! ~6 % of the lobe's convolution elsewhere (the tests).
//!
//! **Level 0 is the environment itself** (`κ = ∞`), with the nominal `κ_0 = W·H/π`
//! (`Ω_s(κ) = 2π/κ`, eq 8 at coverage `a = 1 − 1/e`, equal to the solid angle of a texel at the
//! equator, eq 9): a lobe sharper than `κ_0` reads level 0, one between `κ_1` and `κ_0` blends
//! level 0 and level 1 (linear in κ). That range (σ below two texels) is as sharp as the
//! environment's own texels resolve; a lookup there is only as good as the environment's
//! resolution allows.
//!
//! **Memory**: level 1 and 2 each as many texels as the environment (below [`GRID_CAP`]), then a
//! quarter per pair: `1 + 2·(1 + ¼ + …) ≤ 3.7` times the environment's texels, all levels
//! included (3.75 at most for environments so small that the 16 × 8 levels dominate).
//!
//! Level k is made from a sharper level j convolved with the increment κ_Δ that makes band
//! l = 1 exact, `A_1(κ_Δ)·A_1(κ_j) = A_1(κ_k)` ([`increment`]; in the small-angle limit
//! `1/κ_Δ = 1/κ_k − 1/κ_j`, vMF variances add), evaluated on level k's grid. Two vMFs compose
//! to a vMF only up to `O(1/(κ_j κ_Δ))`: for κ_k ≥ 64 the source is level k − 1, below it the
//! coarsest level with `κ_j ≥ 16 κ_k`, so the wide levels do not drift down a chain (which
//! put a wide lobe's sun 8 % off and a smooth environment's band 1 5 % off).
//!
//! **Summed by FFT along the rows.** For one output row and one input row the weight depends
//! on the azimuth offset only, so that row pair's contribution to the output row is a circular
//! correlation in φ: each input row's spectrum is taken once, each row pair's kernel is
//! transformed and multiplied in, the products of all the input rows are summed and one inverse
//! transform (folded to the output's width) gives the output row. Only row pairs whose window is
//! a few taps wide are summed directly (`FFT_COST`). The two agree to f32 rounding (the
//! tests); on venice_sunset_1k the levels take 0.15 s per channel against 1.3 s summed
//! directly, identical bytes (docs/environment.md). `rustfft` (pure Rust, a fixed plan per
//! length, no threads of its own) earns its place: a point source near the pole makes every
//! polar row pair of levels 1–3 a whole ring of taps.
//!
//! Every level keeps `∫ L dω` up to the renormalization at each texel (a constant environment
//! stays exactly constant), so the prefiltered lookup of a black environment is exactly 0 and
//! of a single-texel sun is bounded by the sun's power times the lobe's peak density. Each
//! output texel is one sum in a fixed order: the levels are the same whatever the thread count.

use super::Radiance;
use crate::vmf;
use glam::DVec3;
use rayon::prelude::*;
use rustfft::FftPlanner;
use rustfft::num_complex::Complex64;
use std::f64::consts::{PI, TAU};

/// Smallest width of a prefiltered level's grid.
pub const MIN_WIDTH: u32 = 16;

/// The smallest κ a level is made for (a lobe wider than a hemisphere): levels stop below it.
pub const KAPPA_FLOOR: f64 = 0.25;

/// A level's grid spacing at most, in units of its lobe's `σ = 1/√κ` (module docs).
pub const SPACING: f64 = 0.5;

/// The widest grid of a convolved level: an environment wider than this has level 1 on its
/// grid halved until it fits (the atlas of a 16384-wide panorama then stays within a
/// 16384-texel `GL_MAX_TEXTURE_SIZE`, docs/environment.md).
pub const GRID_CAP: u32 = 4096;

/// Levels with κ at least this are made from the level before (module docs).
const DIRECT_KAPPA: f64 = 64.0;

/// A level with κ below [`DIRECT_KAPPA`] is made from the coarsest level at least this many
/// times sharper (module docs).
const DIRECT_RATIO: f64 = 16.0;

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
    kappa1: f64,
}

impl Prefiltered {
    /// Prefilters `env` (module docs). Deterministic whatever the thread count (each output
    /// texel is one sum in a fixed order).
    pub fn new(env: &Radiance) -> Prefiltered {
        Prefiltered::build(env, FFT_COST, &mut Vec::new())
    }

    /// [`Self::new`] with [`convolve_with`]'s FFT threshold as a parameter; each convolved
    /// level's time in seconds is appended to `seconds`.
    fn build(env: &Radiance, fft_cost: f64, seconds: &mut Vec<f64>) -> Prefiltered {
        let (w, h) = (env.width(), env.height());
        let kappa0 = w as f64 * h as f64 / PI;
        let mut grid = w;
        while grid > GRID_CAP && grid % 4 == 0 {
            grid /= 2;
        }
        let kappa1 = (SPACING * grid as f64 / TAU).powi(2).max(KAPPA_FLOOR);
        let mut levels = vec![Level {
            radiance: env.clone(),
            kappa: f64::INFINITY,
        }];
        for k in 1.. {
            let kappa = kappa1 / 2f64.powi(k - 1);
            if k > 1 && kappa < KAPPA_FLOOR {
                break;
            }
            // Levels 1 and 2 on level 1's grid, then the grid halves every second level.
            if k >= 3 && k % 2 == 1 && grid / 2 >= MIN_WIDTH && grid % 4 == 0 {
                grid /= 2;
            }
            // The source: the previous level while lobes are narrow (the composition of two
            // vMFs is a vMF to O(1/κ²)); below `DIRECT_KAPPA` the coarsest level at least
            // `DIRECT_RATIO` times sharper, so that wide levels do not drift down a chain.
            let src = if kappa >= DIRECT_KAPPA {
                levels.last().expect("level 0")
            } else {
                levels
                    .iter()
                    .rev()
                    .find(|l| l.kappa >= DIRECT_RATIO * kappa)
                    .expect("level 0 has κ = ∞")
            };
            let start = std::time::Instant::now();
            let radiance =
                convolve_with(&src.radiance, grid, increment(src.kappa, kappa), fft_cost);
            seconds.push(start.elapsed().as_secs_f64());
            levels.push(Level { radiance, kappa });
        }
        Prefiltered {
            levels,
            kappa0,
            kappa1,
        }
    }

    /// The levels, level 0 (the environment) first.
    pub fn levels(&self) -> &[Level] {
        &self.levels
    }

    /// `κ_0 = W·H/π`: level 0's nominal concentration (its texel's solid angle at the equator
    /// is `Ω_s(κ_0) = 2π/κ_0`, eqs 8–9).
    pub fn kappa0(&self) -> f64 {
        self.kappa0
    }

    /// `κ_1 = (SPACING · W_1 / 2π)²`, level 1's concentration; level k ≥ 1 has
    /// `κ_1 / 2^{k−1}`.
    pub fn kappa1(&self) -> f64 {
        self.kappa1
    }

    /// The two levels a lobe of concentration `kappa` reads: `(i, t)` blends level i by
    /// `1 − t` and level i + 1 by `t`, with `t` linear in κ between the levels' κ (which keeps
    /// a point source's peak, `∝ κ`, exact). κ ≥ κ_0, ∞ and NaN read level 0; κ at or below
    /// the last level's (0 and negative included) the last level. The shader computes the same
    /// (`ndf_env_lookup`).
    pub fn blend(&self, kappa: f64) -> (usize, f64) {
        let last = self.levels.len() - 1;
        if kappa.is_nan() || kappa >= self.kappa0 || last == 0 {
            return (0, 0.0);
        }
        if kappa <= self.levels[last].kappa {
            return (last, 0.0);
        }
        if kappa >= self.kappa1 {
            let span = self.kappa0 - self.kappa1;
            let t = if span > 0.0 {
                ((self.kappa0 - kappa) / span).clamp(0.0, 1.0)
            } else {
                1.0
            };
            return (0, t);
        }
        let i = (1 + (self.kappa1 / kappa).log2().floor().max(0.0) as usize).min(last - 1);
        let ki = self.kappa1 / 2f64.powi(i as i32 - 1);
        let t = ((ki - kappa) / (0.5 * ki)).clamp(0.0, 1.0);
        (i, t)
    }

    /// [`Self::blend`] as one number, `i + t` (0 for κ → ∞).
    pub fn lod(&self, kappa: f64) -> f64 {
        let (i, t) = self.blend(kappa);
        i as f64 + t
    }

    /// The environment convolved with a normalized vMF lobe of concentration `kappa` about `d`:
    /// bilinear in the two levels [`Self::blend`] picks, blended.
    pub fn lookup(&self, d: DVec3, kappa: f64) -> f64 {
        let (i, t) = self.blend(kappa);
        let a = self.levels[i].radiance.bilinear(d);
        if t <= 0.0 || i + 1 >= self.levels.len() {
            return a;
        }
        (1.0 - t) * a + t * self.levels[i + 1].radiance.bilinear(d)
    }
}

/// The κ of the vMF that takes a level of concentration `from` to one of `to` < `from`:
/// `A(κ_Δ) = A(to)/A(from)` (`A = coth κ − 1/κ`, [`vmf::a_kappa`]: the mean cosine of a vMF,
/// the factor by which its convolution scales band l = 1), so band 1 is exact (the small-angle
/// rule `1/κ_Δ = 1/to − 1/from` drifts by several per cent over the chain of wide levels).
/// Solved by [`vmf::kappa_from_r_exact`], held to `[2⁻³⁰, 2⁶⁰]`.
pub fn increment(from: f64, to: f64) -> f64 {
    let r = vmf::a_kappa(to) / vmf::a_kappa(from);
    vmf::kappa_from_r_exact(r).clamp(2f64.powi(-30), 2f64.powi(60))
}

/// `env` convolved with a normalized vMF lobe of concentration `kappa` on its own grid
/// (renormalized per output texel; window `5/√κ`).
pub fn convolve(env: &Radiance, kappa: f64) -> Radiance {
    convolve_to(env, env.width(), kappa)
}

/// `src` convolved with a normalized vMF lobe of concentration `kappa`, evaluated on the
/// `width × width/2` grid (`src`'s width must be a multiple of `width`, else `src`'s own grid
/// is used): each output texel the solid-angle-weighted sum over the input texels within
/// `5/√κ` of it, renormalized. The weights depend on the output row, the input row and the
/// azimuth offset only, so they are computed once per pair of rows; a row pair whose window
/// spans many texels (the polar rows, the wide lobes) is summed as a circular correlation in
/// φ by FFT (`FFT_COST`), the others directly.
pub fn convolve_to(src: &Radiance, width: u32, kappa: f64) -> Radiance {
    convolve_with(src, width, kappa, FFT_COST)
}

/// A row pair is summed by FFT when its direct sum (`n` taps at each of `W_out` output texels)
/// costs more than `FFT_COST · W_in · log2 W_in` (one forward transform of the kernel and a
/// product per pair). Measured on venice_sunset_1k (`prefilter_timing`): 0.15 s per channel
/// with 0 or 1, 0.20 s with 2, 0.44 s with 4, 0.87 s with 16; 1 keeps the few-tap pairs of
/// small grids direct.
const FFT_COST: f64 = 1.0;

/// [`convolve_to`] with the FFT threshold as a parameter (`f64::INFINITY`: every row pair
/// summed directly, the reference the tests compare the FFT against).
fn convolve_with(src: &Radiance, width: u32, kappa: f64, fft_cost: f64) -> Radiance {
    let (ws, hs) = (src.width() as usize, src.height() as usize);
    let wd = if width > 0 && src.width().is_multiple_of(width) {
        width as usize
    } else {
        ws
    };
    let hd = (wd / 2).max(1);
    let m = ws / wd;
    let radius = (5.0 / kappa.max(1e-12).sqrt()).min(PI);
    let dphi = TAU / ws as f64;
    let theta_s = |y: usize| PI * (y as f64 + 0.5) / hs as f64;
    let theta_d = |y: usize| PI * (y as f64 + 0.5) / hd as f64;
    let omega: Vec<f64> = (0..hs).map(|y| src.solid_angle(y as u32)).collect();
    let values = src.values();
    // Input texel xi = m·xo + j lies Δφ = dphi·((m − 1)/2 − j) from output texel xo.
    let centre = (m as f64 - 1.0) / 2.0;
    // The taps of output row yo from input row yi: (first j, count), None out of reach.
    let reach = |yo: usize, yi: usize| -> Option<(i64, usize)> {
        let (to, ti) = (theta_d(yo), theta_s(yi));
        if (ti - to).abs() > radius + PI / hs as f64 {
            return None;
        }
        let prod = to.sin() * ti.sin();
        let half = if radius >= PI || prod < 1e-12 {
            ws
        } else {
            let c = (radius.cos() - to.cos() * ti.cos()) / prod;
            if c >= 1.0 {
                1
            } else if c <= -1.0 {
                ws
            } else {
                ((c.acos() / dphi).ceil() as usize + 1).min(ws)
            }
        };
        Some(if 2 * half + m >= ws {
            (centre.round() as i64 - (ws / 2) as i64, ws)
        } else {
            (-(half as i64), 2 * half + m)
        })
    };
    let fft_limit = fft_cost * ws as f64 * (ws as f64).log2().max(1.0);
    let by_fft = |n: usize| (n * wd) as f64 > fft_limit;
    // The input rows some pair sums by FFT, and their spectra.
    let needs: Vec<bool> = (0..hs)
        .into_par_iter()
        .map(|yi| (0..hd).any(|yo| reach(yo, yi).is_some_and(|(_, n)| by_fft(n))))
        .collect();
    let mut planner = FftPlanner::<f64>::new();
    let forward = planner.plan_fft_forward(ws);
    let inverse = planner.plan_fft_inverse(wd);
    let spectra: Vec<Option<Vec<Complex64>>> = (0..hs)
        .into_par_iter()
        .map(|yi| {
            needs[yi].then(|| {
                let mut s: Vec<Complex64> = values[yi * ws..(yi + 1) * ws]
                    .iter()
                    .map(|&v| Complex64::new(v as f64, 0.0))
                    .collect();
                forward.process(&mut s);
                s
            })
        })
        .collect();
    let rows: Vec<Vec<f32>> = (0..hd)
        .into_par_iter()
        .map(|yo| {
            let to = theta_d(yo);
            let so = to.sin();
            // Direct taps per input row: (row, first j, weights); the FFT-summed rows'
            // correlation accumulated as a spectrum; the weights' sum.
            let mut taps: Vec<(usize, i64, Vec<f64>)> = Vec::new();
            let mut acc: Vec<Complex64> = Vec::new();
            let mut kernel: Vec<Complex64> = Vec::new();
            let mut den = 0.0f64;
            for (yi, &om) in omega.iter().enumerate() {
                let Some((j0, n)) = reach(yo, yi) else {
                    continue;
                };
                let prod = so * theta_s(yi).sin();
                let dtheta = 2.0 * (0.5 * (theta_s(yi) - to)).sin().powi(2);
                let wts: Vec<f64> = (0..n)
                    .map(|k| {
                        let j = j0 + k as i64;
                        let dp = dphi * (centre - j as f64);
                        // 1 − ω·ω′, without cancellation.
                        let one_minus = dtheta + 2.0 * prod * (0.5 * dp).sin().powi(2);
                        om * (-kappa * one_minus).exp()
                    })
                    .collect();
                den += wts.iter().sum::<f64>();
                if by_fft(n) {
                    // c[x] = Σ_t k[t] row[x + t] (circular), k[(j0 + j) mod W] = w_j:
                    // ĉ = conj(k̂) · roŵ (k real).
                    let spectrum = spectra[yi].as_ref().expect("marked in `needs`");
                    kernel.clear();
                    kernel.resize(ws, Complex64::new(0.0, 0.0));
                    let mut t = j0.rem_euclid(ws as i64) as usize;
                    for &wgt in &wts {
                        kernel[t].re += wgt;
                        t += 1;
                        if t == ws {
                            t = 0;
                        }
                    }
                    forward.process(&mut kernel);
                    if acc.is_empty() {
                        acc.resize(ws, Complex64::new(0.0, 0.0));
                    }
                    for ((a, k), s) in acc.iter_mut().zip(&kernel).zip(spectrum) {
                        *a += k.conj() * s;
                    }
                } else {
                    taps.push((yi, j0, wts));
                }
            }
            // The correlation at x = m·xo only: the spectrum folded to W_out bins and
            // transformed back (c[m·xo] = (1/W_in) Σ_g (Σ_r ĉ[g + r·W_out]) e^{2πi g xo/W_out}).
            let corr: Vec<f64> = if acc.is_empty() {
                Vec::new()
            } else {
                let mut folded = vec![Complex64::new(0.0, 0.0); wd];
                for (f, a) in acc.iter().enumerate() {
                    folded[f % wd] += a;
                }
                inverse.process(&mut folded);
                folded.iter().map(|c| c.re / ws as f64).collect()
            };
            (0..wd)
                .map(|xo| {
                    let mut num = corr.get(xo).copied().unwrap_or(0.0);
                    for (yi, j0, wts) in &taps {
                        let row = &values[yi * ws..(yi + 1) * ws];
                        let start = (m * xo) as i64 + j0;
                        let mut x = start.rem_euclid(ws as i64) as usize;
                        for &wgt in wts {
                            num += wgt * row[x] as f64;
                            x += 1;
                            if x == ws {
                                x = 0;
                            }
                        }
                    }
                    // A weighted mean of non-negative radiance: the FFT's rounding may leave
                    // it a hair below 0 where the row is dark.
                    if den > 0.0 {
                        (num / den).max(0.0) as f32
                    } else {
                        0.0
                    }
                })
                .collect()
        })
        .collect();
    Radiance::new(wd as u32, hd as u32, rows.concat()).expect("a 2:1 grid")
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

    /// The largest difference between two levels, relative to the first's maximum.
    fn level_difference(a: &Radiance, b: &Radiance) -> f64 {
        assert_eq!((a.width(), a.height()), (b.width(), b.height()));
        let max = a.values().iter().fold(0.0f32, |m, &v| m.max(v)) as f64;
        let diff = a
            .values()
            .iter()
            .zip(b.values())
            .fold(0.0f64, |d, (&x, &y)| d.max((x as f64 - y as f64).abs()));
        if max > 0.0 { diff / max } else { diff }
    }

    #[test]
    fn fft_sums_match_the_direct_sums() {
        // Noise over 5 decades with a bright texel near the zenith and one on the seam; every
        // row pair by FFT (cost 0), the default split, and every pair summed directly.
        let (w, h) = (128u32, 64u32);
        let mut rng = Rng(11);
        let mut v: Vec<f32> = (0..w * h)
            .map(|_| 10f64.powf(rng.range(-3.0, 2.0)) as f32)
            .collect();
        v[(2 * w + 40) as usize] = 1e5;
        v[(37 * w) as usize] = 3e4;
        let env = Radiance::new(w, h, v).unwrap();
        let mut worst: f64 = 0.0;
        for (width, kappa) in [(128, 600.0), (128, 40.0), (64, 150.0), (32, 3.0), (16, 0.3)] {
            let direct = convolve_with(&env, width, kappa, f64::INFINITY);
            for cost in [0.0, FFT_COST] {
                let fft = convolve_with(&env, width, kappa, cost);
                let d = level_difference(&direct, &fft);
                worst = worst.max(d);
                assert!(d < 1e-6, "width {width} κ {kappa} cost {cost}: {d}");
            }
            // A dark texel stays non-negative and a black environment exactly 0 by FFT.
            let black = convolve_with(&Radiance::constant(w, 0.0), width, kappa, 0.0);
            assert!(black.values().iter().all(|&x| x == 0.0));
            let c = convolve_with(&Radiance::constant(w, 2.5), width, kappa, 0.0);
            assert!(
                c.values().iter().all(|&x| (x - 2.5).abs() < 1e-6),
                "{kappa}"
            );
        }
        eprintln!("FFT vs direct, worst relative to the level's maximum: {worst:.2e}");
    }

    /// Timing and accuracy on a real environment (`NDFMAP_PREFILTER_ENV=path.hdr cargo test
    /// --release --lib prefilter_timing -- --ignored --nocapture`): each level's time, and its
    /// largest difference from the direct sums relative to the level's maximum.
    #[test]
    #[ignore = "measurement on real data"]
    fn prefilter_timing() {
        let Ok(path) = std::env::var("NDFMAP_PREFILTER_ENV") else {
            return;
        };
        let env = crate::environment::load(
            std::path::Path::new(&path),
            &crate::environment::EnvOptions::default(),
        )
        .unwrap();
        for c in 0..3 {
            let r = env.channel(c);
            let (mut t_fast, mut t_slow) = (Vec::new(), Vec::new());
            let fast = Prefiltered::build(&r, FFT_COST, &mut t_fast);
            let slow = Prefiltered::build(&r, f64::INFINITY, &mut t_slow);
            for (k, (a, b)) in fast.levels().iter().zip(slow.levels()).enumerate().skip(1) {
                eprintln!(
                    "channel {c} level {k} {}x{} κ {:.1}: FFT {:.3} s, direct {:.3} s, \
                     difference / max {:.2e}",
                    a.radiance.width(),
                    a.radiance.height(),
                    a.kappa,
                    t_fast[k - 1],
                    t_slow[k - 1],
                    level_difference(&b.radiance, &a.radiance)
                );
            }
            let sum = |t: &[f64]| t.iter().sum::<f64>();
            eprintln!(
                "channel {c}: FFT {:.3} s, direct {:.3} s",
                sum(&t_fast),
                sum(&t_slow)
            );
        }
        // The threshold's choice.
        for cost in [0.0, 1.0, 2.0, 4.0, 8.0, 16.0] {
            let mut t = Vec::new();
            Prefiltered::build(&env.channel(0), cost, &mut t);
            eprintln!("FFT_COST {cost}: {:.3} s", t.iter().sum::<f64>());
        }
    }

    #[test]
    fn sharp_lobes_read_level_zero() {
        let p = Prefiltered::new(&Radiance::constant(32, 1.0));
        assert_eq!(p.lod(f64::INFINITY), 0.0);
        assert_eq!(p.lod(1e30), 0.0);
        assert_eq!(p.lod(f64::NAN), 0.0);
        assert_eq!(p.lod(p.kappa1()), 1.0);
        assert_eq!(p.lod(p.kappa1() / 2.0), 2.0);
        assert_eq!(p.lod(0.0), (p.levels().len() - 1) as f64);
    }
    /// The old layout (before issue 16's fix): κ_k = κ_0/4^k on grids that halve per level,
    /// blended linearly in `½ log2(κ_0/κ)`: what the sun test shows failing.
    fn old_lookup(levels: &[Level], kappa0: f64, d: DVec3, kappa: f64) -> f64 {
        let last = (levels.len() - 1) as f64;
        let lod = if kappa >= kappa0 {
            0.0
        } else {
            (0.5 * (kappa0 / kappa).log2()).clamp(0.0, last)
        };
        let i = lod.floor() as usize;
        let t = lod - i as f64;
        let a = levels[i].radiance.bilinear(d);
        if t <= 0.0 || i + 1 >= levels.len() {
            return a;
        }
        (1.0 - t) * a + t * levels[i + 1].radiance.bilinear(d)
    }

    fn old_levels(env: &Radiance) -> (Vec<Level>, f64) {
        let kappa0 = env.width() as f64 * env.height() as f64 / PI;
        let mut levels = vec![Level {
            radiance: env.clone(),
            kappa: f64::INFINITY,
        }];
        for k in 1.. {
            let kappa = kappa0 / 4f64.powi(k);
            if kappa < KAPPA_FLOOR {
                break;
            }
            let prev = levels.last().unwrap();
            let src = if prev.radiance.width() > MIN_WIDTH {
                prev.radiance.downsample()
            } else {
                prev.radiance.clone()
            };
            let radiance = convolve(&src, 1.0 / (1.0 / kappa - 1.0 / prev.kappa));
            levels.push(Level { radiance, kappa });
        }
        (levels, kappa0)
    }

    /// `∫_texel C(κ) e^{κ(d·ω − 1)} dω`: a unit-radiance texel convolved with a normalized vMF,
    /// by a 24 × 24 midpoint rule in (φ, cos θ) (exact solid angles of the sub-cells).
    fn texel_convolution(
        g: &crate::environment::Geometry,
        x: u32,
        y: u32,
        d: DVec3,
        k: f64,
    ) -> f64 {
        let n = 24;
        let (c0, c1) = g.cos_bounds(y);
        let (w, _) = (g.width as f64, g.height as f64);
        let c = k / (TAU * (1.0 - (-2.0 * k).exp()));
        let mut sum = 0.0;
        for i in 0..n {
            let z = c0 + (c1 - c0) * (i as f64 + 0.5) / n as f64;
            let s = (1.0 - z * z).max(0.0).sqrt();
            for j in 0..n {
                let phi = -PI + TAU * (x as f64 + (j as f64 + 0.5) / n as f64) / w;
                let o = DVec3::new(s * phi.cos(), s * phi.sin(), z);
                sum += (k * (d.dot(o) - 1.0)).exp();
            }
        }
        c * sum * TAU / w * (c0 - c1) / (n * n) as f64
    }

    #[test]
    fn a_single_texel_sun_reads_like_its_closed_form_convolution() {
        // A one-texel sun of radiance 1 on a 256-wide environment, at the equator, near the
        // zenith (row 2) and on the φ seam (column 0); lobes from level 1's κ down through
        // several levels, between their κ; looked up at the sun's centre and 0.5, 1 and 2 σ
        // away (towards directions between the grids' nodes). Error relative to the peak
        // (the closed form at the centre). Measured: the new layout 4.9 % at most (the old
        // one 59 %).
        let (w, h) = (256u32, 128u32);
        let g = Radiance::geometry(w, h);
        let mut new_worst: f64 = 0.0;
        let mut old_worst: f64 = 0.0;
        for (sx, sy) in [(77u32, 63u32), (40, 2), (0, 50)] {
            let mut v = vec![0.0f32; (w * h) as usize];
            v[(sy * w + sx) as usize] = 1.0;
            let env = Radiance::new(w, h, v).unwrap();
            let p = Prefiltered::new(&env);
            let (old, kappa0) = old_levels(&env);
            let sun = g.direction(sx, sy);
            let (t1, t2) = sun.any_orthonormal_pair();
            for kappa in [400.0, 290.0, 170.0, 97.0, 61.0, 23.0, 7.3] {
                assert!(kappa < p.kappa1(), "{}", p.kappa1());
                let sigma = 1.0 / f64::sqrt(kappa);
                let peak = texel_convolution(&g, sx, sy, sun, kappa);
                for (r, a) in [(0.0, 0.0), (0.5, 0.3), (1.0, 1.9), (2.0, 4.0), (1.0, 5.1)] {
                    let d = (sun + r * sigma * (f64::cos(a) * t1 + f64::sin(a) * t2)).normalize();
                    let exact = texel_convolution(&g, sx, sy, d, kappa);
                    let new = (p.lookup(d, kappa) - exact).abs() / peak;
                    let old = (old_lookup(&old, kappa0, d, kappa) - exact).abs() / peak;
                    new_worst = new_worst.max(new);
                    old_worst = old_worst.max(old);
                    assert!(new < 0.06, "sun ({sx},{sy}) κ {kappa} r {r}σ: {new}");
                }
            }
        }
        eprintln!("worst error / peak: new {new_worst:.4}, old {old_worst:.4}");
        assert!(old_worst > 0.2, "the old layout {old_worst}");
    }

    #[test]
    fn levels_resolve_their_lobes_within_the_memory_bound() {
        for w in [64u32, 256, 1024, 8192] {
            let env = Radiance::constant(w, 1.0);
            let p = if w > 1024 {
                None
            } else {
                Some(Prefiltered::new(&env))
            };
            if let Some(p) = p {
                let texels: u64 = p
                    .levels()
                    .iter()
                    .map(|l| l.radiance.width() as u64 * l.radiance.height() as u64)
                    .sum();
                assert!(
                    texels as f64 <= 3.7 * (w as f64 * w as f64 / 2.0),
                    "{w}: {texels}"
                );
                for (k, l) in p.levels().iter().enumerate().skip(1) {
                    let spacing = TAU / l.radiance.width() as f64;
                    let grid_fine = l.radiance.width() == MIN_WIDTH;
                    assert!(
                        spacing * l.kappa.sqrt() <= SPACING + 1e-12 || grid_fine,
                        "{w} level {k}: spacing {spacing} κ {}",
                        l.kappa
                    );
                    assert_eq!(l.kappa, p.kappa1() / 2f64.powi(k as i32 - 1));
                }
                assert!(p.levels().last().unwrap().kappa >= KAPPA_FLOOR);
            }
        }
    }

    #[test]
    fn the_blend_keeps_a_point_sources_peak_and_is_continuous() {
        let p = Prefiltered::new(&Radiance::constant(256, 1.0));
        let n = p.levels().len();
        let kappa_of = |i: usize| {
            if i == 0 {
                p.kappa0()
            } else {
                p.levels()[i].kappa
            }
        };
        let mut prev = 0.0;
        let mut kappa = 2.0 * p.kappa0();
        while kappa > 0.1 {
            let (i, t) = p.blend(kappa);
            let lod = i as f64 + t;
            assert!(lod >= prev - 1e-12, "{kappa}: {lod} < {prev}");
            assert!((0.0..=1.0).contains(&t));
            if kappa < p.kappa0() && kappa > p.levels()[n - 1].kappa {
                // (1 − t) κ_i + t κ_{i+1} = κ: a point source's peak is kept.
                let mix = (1.0 - t) * kappa_of(i) + t * kappa_of(i + 1);
                assert!((mix - kappa).abs() < 1e-9 * kappa, "{kappa}: {mix}");
            }
            prev = lod;
            kappa *= 0.97;
        }
    }
}
