//! The single-precision E-step (Algorithm 1 lines 3–7), the default: sixteen samples per block
//! in `f32`, the M-step sums accumulated in `f32` lanes over short runs of blocks and then in
//! `f64` (so rounding does not grow with the texel's size).
//!
//! `κ(n·μ − 1)` is computed as `−κ|n − μ|²/2` (equal for unit n and μ): near a sharp lobe's
//! centre `n·μ − 1` cancels catastrophically in `f32` (at κ = 4·10⁶ an ulp of `n·μ` is worth
//! 0.24 in the exponent), while `|n − μ|²` keeps the relative precision of the differences, so
//! the exponent stays within about `κ·|n − μ|·2⁻²⁴` of exact — 10⁻⁴ at the storable κ and one
//! standard deviation from the centre. Log-sum-exp, `e^x` and `ln` are in `f32`
//! ([`super::lanes32`]); the `f64` kernel stays as the reference (`Precision::F64`) and the tests
//! compare the two.

use super::lanes32::{LANES, Lane, Portable32, Simd32, exp_nonpositive, ln_positive};
use super::{Active, MAX_LOBES, Sums};

/// Sixteen samples in structure-of-arrays form: normal components and weights (the tail block
/// is padded with zero-weight samples, which add exact zeros).
#[derive(Debug, Clone, Copy)]
pub(super) struct Block32 {
    pub(super) x: Lane,
    pub(super) y: Lane,
    pub(super) z: Lane,
    pub(super) w: Lane,
}

/// A block of padding: normal +Z, weight 0.
pub(super) const PAD_BLOCK32: Block32 = Block32 {
    x: [0.0; LANES],
    y: [0.0; LANES],
    z: [1.0; LANES],
    w: [0.0; LANES],
};

/// Samples per lane slot of a block.
pub(super) const LANES32: usize = LANES;

/// Per-slot constants of one single-precision E-step (the slots of an [`Active`]).
struct Active32 {
    count: usize,
    mu: [[f32; MAX_LOBES]; 3],
    /// κ/2.
    half_kappa: [f32; MAX_LOBES],
    /// `ln α + ln(κ/(2π(1 − e^{−2κ})))`, computed in `f64`.
    offset: [f32; MAX_LOBES],
}

impl Active32 {
    /// The single-precision constants of `a`'s slots.
    fn new(a: &Active) -> Self {
        let mut out = Active32 {
            count: a.count,
            mu: [[0.0; MAX_LOBES]; 3],
            half_kappa: [0.0; MAX_LOBES],
            offset: [f32::NEG_INFINITY; MAX_LOBES],
        };
        for s in 0..a.count {
            let (mu, kappa) = (a.mu[s], a.kappa[s]);
            out.mu[0][s] = mu.x as f32;
            out.mu[1][s] = mu.y as f32;
            out.mu[2][s] = mu.z as f32;
            out.half_kappa[s] = (0.5 * kappa) as f32;
            out.offset[s] = a.log_scaled[s] as f32;
        }
        out
    }
}

/// Responsibilities of the samples of `b` (Algorithm 1 line 5 in log space): fills `e[j]`
/// with `e^{x_j − max}`, `x_j = ln α_j + ln C(κ_j) − κ_j|n − μ_j|²/2`, and `d[j]` with the
/// offsets `n − μ_j`, and returns per sample `w · ln Σ_j α_j γ_j(n)` and `w / Σ_j e^{x_j − max}`.
#[inline(always)]
fn block_responsibilities<S: Simd32>(
    b: &Block32,
    a: &Active32,
    e: &mut [S; MAX_LOBES],
    d: &mut [[S; 3]; MAX_LOBES],
) -> (S, S) {
    let count = a.count.min(MAX_LOBES);
    let (x, y, z, w) = (S::load(&b.x), S::load(&b.y), S::load(&b.z), S::load(&b.w));
    let mut max = S::splat(f32::NEG_INFINITY);
    for (j, (ej, dj)) in e.iter_mut().zip(d.iter_mut()).enumerate().take(count) {
        let dx = x.sub(S::splat(a.mu[0][j]));
        let dy = y.sub(S::splat(a.mu[1][j]));
        let dz = z.sub(S::splat(a.mu[2][j]));
        *dj = [dx, dy, dz];
        let d2 = dx.mul(dx).add(dy.mul(dy)).add(dz.mul(dz));
        let v = S::splat(a.offset[j]).sub(S::splat(a.half_kappa[j]).mul(d2));
        *ej = v;
        max = S::select_gt(v, max, v, max);
    }
    let mut sum = S::splat(0.0);
    for ej in e.iter_mut().take(count) {
        *ej = exp_nonpositive(ej.sub(max));
        sum = sum.add(*ej);
    }
    (w.mul(max.add(ln_positive(sum))), w.div(sum))
}

/// Blocks summed in `f32` lanes before they are added to the `f64` totals (512 samples: the
/// lane sums' relative rounding stays below 32 ulps).
const FLUSH_BLOCKS: usize = 32;

/// One single-precision E-step over `blocks` for the lobes of `active`, returning the M-step
/// sums in `f64`. Compiled for AVX-512, AVX2 and SSE4.2 and chosen at run time; every variant
/// performs the same IEEE operations in the same order (no fused multiply-add), so the result
/// is bit-identical on every CPU.
#[multiversion::multiversion(targets("x86_64+avx512f", "x86_64+avx2+avx", "x86_64+sse4.2"))]
pub(super) fn e_step32(blocks: &[Block32], active: &Active) -> Sums {
    e_step_kernel::<Portable32>(blocks, &Active32::new(active))
}

/// The kernel proper. The moments are accumulated as offsets from the lobe's (f32) centre,
/// `Σ w z (n − μ_j)`, which are small for a sharp lobe and so keep their relative precision in
/// `f32`; `Σ w z · μ_j` is added back in `f64`. That keeps `1 − |r_j|`, and with it κ_j ≈
/// `1/(1 − |r_j|)`, as accurate as the `f64` kernel's for every storable κ.
#[inline(always)]
fn e_step_kernel<S: Simd32>(blocks: &[Block32], active: &Active32) -> Sums {
    let count = active.count.min(MAX_LOBES);
    let zero = S::splat(0.0);
    let mut sums = Sums::default();
    let mut e = [zero; MAX_LOBES];
    let mut d = [[zero; 3]; MAX_LOBES];
    let mut offsets = [[0.0f64; MAX_LOBES]; 3];
    for run in blocks.chunks(FLUSH_BLOCKS) {
        // Per lobe: lanes of Σ w z and Σ w z (n − μ) per component.
        let mut acc = [[zero; 4]; MAX_LOBES];
        let mut log_likelihood = zero;
        for b in run {
            let (ll, scale) = block_responsibilities(b, active, &mut e, &mut d);
            log_likelihood = log_likelihood.add(ll);
            for ((a, ej), dj) in acc.iter_mut().zip(&e).zip(&d).take(count) {
                let wz = ej.mul(scale);
                a[0] = a[0].add(wz);
                a[1] = a[1].add(wz.mul(dj[0]));
                a[2] = a[2].add(wz.mul(dj[1]));
                a[3] = a[3].add(wz.mul(dj[2]));
            }
        }
        sums.log_likelihood += lane_sum(log_likelihood.to_array());
        for (j, a) in acc.iter().enumerate().take(count) {
            sums.weight[j] += lane_sum(a[0].to_array());
            for (c, o) in offsets.iter_mut().enumerate() {
                o[j] += lane_sum(a[c + 1].to_array());
            }
        }
    }
    for (c, o) in offsets.iter().enumerate() {
        for (j, oj) in o.iter().enumerate().take(count) {
            sums.moment[c][j] = sums.weight[j] * active.mu[c][j] as f64 + oj;
        }
    }
    sums
}

/// The lanes added in `f64` by a fixed pairwise tree (16 → 8 → 4 → 2 → 1), which the
/// compiler keeps in vector registers.
#[inline(always)]
fn lane_sum(l: Lane) -> f64 {
    let mut v: [f64; LANES] = l.map(f64::from);
    let mut n = LANES;
    while n > 1 {
        n /= 2;
        for i in 0..n {
            v[i] += v[i + n];
        }
    }
    v[0]
}

/// A block's features (eq 22's `y_i`, four channels) in structure-of-arrays form, beside its
/// [`Block32`] (zeros in the padding).
pub(super) type FeatureBlock = [Lane; 4];

/// Eq 22 as one more E-step pass: per active slot j, `Σ_i w_i z_ij` and `Σ_i w_i z_ij y_i`
/// with the responsibilities of `active`'s lobes, in `f32` lanes flushed to `f64` like the
/// E-step's sums. Returns `(weight[j], feature sums[j])`. Multiversioned like [`e_step32`].
#[multiversion::multiversion(targets("x86_64+avx512f", "x86_64+avx2+avx", "x86_64+sse4.2"))]
pub(super) fn feature_sums(
    blocks: &[Block32],
    features: &[FeatureBlock],
    active: &Active,
) -> ([f64; MAX_LOBES], [[f64; 4]; MAX_LOBES]) {
    feature_kernel::<Portable32>(blocks, features, &Active32::new(active))
}

#[inline(always)]
fn feature_kernel<S: Simd32>(
    blocks: &[Block32],
    features: &[FeatureBlock],
    active: &Active32,
) -> ([f64; MAX_LOBES], [[f64; 4]; MAX_LOBES]) {
    let count = active.count.min(MAX_LOBES);
    let zero = S::splat(0.0);
    let mut weight = [0.0f64; MAX_LOBES];
    let mut sums = [[0.0f64; 4]; MAX_LOBES];
    let mut e = [zero; MAX_LOBES];
    let mut d = [[zero; 3]; MAX_LOBES];
    for (run, fruns) in blocks
        .chunks(FLUSH_BLOCKS)
        .zip(features.chunks(FLUSH_BLOCKS))
    {
        let mut acc = [[zero; 5]; MAX_LOBES];
        for (b, f) in run.iter().zip(fruns) {
            let (_, scale) = block_responsibilities(b, active, &mut e, &mut d);
            let y = [
                S::load(&f[0]),
                S::load(&f[1]),
                S::load(&f[2]),
                S::load(&f[3]),
            ];
            for (a, ej) in acc.iter_mut().zip(&e).take(count) {
                let wz = ej.mul(scale);
                a[0] = a[0].add(wz);
                for c in 0..4 {
                    a[c + 1] = a[c + 1].add(wz.mul(y[c]));
                }
            }
        }
        for (j, a) in acc.iter().enumerate().take(count) {
            weight[j] += lane_sum(a[0].to_array());
            for c in 0..4 {
                sums[j][c] += lane_sum(a[c + 1].to_array());
            }
        }
    }
    (weight, sums)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vmf::Lobe;
    use glam::DVec3;

    #[test]
    #[ignore = "timing; run with --ignored --nocapture in release"]
    fn timing_e_step32() {
        let lobes: Vec<Lobe> = (0..6)
            .map(|j| {
                Lobe::new(
                    1.0 / 6.0,
                    DVec3::new(0.1 * j as f64, 0.05, 1.0),
                    50.0 + 100.0 * j as f64,
                )
            })
            .collect();
        let active = Active::new(&lobes);
        let mut blocks = vec![PAD_BLOCK32; 4096 / LANES];
        for (i, b) in blocks.iter_mut().enumerate() {
            for l in 0..LANES {
                let t = (i * LANES + l) as f32 * 0.001;
                let n = DVec3::new(t.sin() as f64 * 0.3, t.cos() as f64 * 0.3, 1.0).normalize();
                (b.x[l], b.y[l], b.z[l], b.w[l]) = (n.x as f32, n.y as f32, n.z as f32, 1.0);
            }
        }
        let reps = 2000;
        let t = std::time::Instant::now();
        let mut acc = 0.0;
        for _ in 0..reps {
            acc += e_step32(&blocks, &active).log_likelihood;
        }
        let ns = t.elapsed().as_secs_f64() * 1e9 / (reps * 4096 * 6) as f64;
        eprintln!("e_step32: {ns:.3} ns per normal·lobe ({acc})");
    }
}
