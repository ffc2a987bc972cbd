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

/// Calls `kernel::<S, C>(args)` with the slot count `count` as the constant `C` (0 to
/// `MAX_LOBES`), so the kernels' loops over slots have fixed trip counts: the compiler then
/// unrolls them and vectorizes each slot's lanes, where a loop of run-time length was
/// vectorized across the slots with gathers. (The operations and their order do not change.)
macro_rules! by_count {
    ($count:expr, $kernel:ident :: <$s:ty> ($($arg:expr),*)) => {
        match $count {
            0 => $kernel::<$s, 0>($($arg),*),
            1 => $kernel::<$s, 1>($($arg),*),
            2 => $kernel::<$s, 2>($($arg),*),
            3 => $kernel::<$s, 3>($($arg),*),
            4 => $kernel::<$s, 4>($($arg),*),
            5 => $kernel::<$s, 5>($($arg),*),
            6 => $kernel::<$s, 6>($($arg),*),
            7 => $kernel::<$s, 7>($($arg),*),
            _ => $kernel::<$s, MAX_LOBES>($($arg),*),
        }
    };
}

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

/// Per-slot constants of one single-precision E-step (the slots of an [`Active`]), one value
/// per lane: the same in every lane for one texel's E-step ([`e_step32`]), one texel per lane
/// for [`e_step_lanes`]. Kept as whole lanes (not one `f32` per slot) so that the kernels load
/// each slot's constants as one vector: with contiguous per-slot scalars the compiler
/// vectorized across the slots instead of across the lanes.
struct Active32 {
    count: usize,
    mu: [[Lane; MAX_LOBES]; 3],
    /// κ/2.
    half_kappa: [Lane; MAX_LOBES],
    /// `ln α + ln(κ/(2π(1 − e^{−2κ})))`, computed in `f64`; −∞ for an unused slot.
    offset: [Lane; MAX_LOBES],
}

impl Active32 {
    /// No slots: every offset −∞.
    fn empty() -> Self {
        Active32 {
            count: 0,
            mu: [[[0.0; LANES]; MAX_LOBES]; 3],
            half_kappa: [[0.0; LANES]; MAX_LOBES],
            offset: [[f32::NEG_INFINITY; LANES]; MAX_LOBES],
        }
    }

    /// The single-precision constants of `a`'s slots, in every lane.
    fn new(a: &Active) -> Self {
        let mut out = Active32::empty();
        out.count = a.count;
        for s in 0..a.count.min(MAX_LOBES) {
            let c = slot32(a, s);
            for (m, &v) in out.mu.iter_mut().zip(&c[..3]) {
                m[s] = [v; LANES];
            }
            out.half_kappa[s] = [c[3]; LANES];
            out.offset[s] = [c[4]; LANES];
        }
        out
    }
}

/// Slot `s`'s single-precision constants: μ, κ/2 and the offset.
fn slot32(a: &Active, s: usize) -> [f32; 5] {
    let (mu, kappa) = (a.mu[s], a.kappa[s]);
    [
        mu.x as f32,
        mu.y as f32,
        mu.z as f32,
        (0.5 * kappa) as f32,
        a.log_scaled[s] as f32,
    ]
}

/// Runs `$body` with `$j` = 0, 1, … `$c − 1` (`$c` a constant ≤ 8) as straight-line code: a
/// loop over the slots, even of constant length, was vectorized across the slots (with
/// gathers) instead of across the lanes.
macro_rules! unroll {
    ($c:expr, $j:ident => $body:block) => {
        if $c > 0 {
            let $j = 0;
            $body
        }
        if $c > 1 {
            let $j = 1;
            $body
        }
        if $c > 2 {
            let $j = 2;
            $body
        }
        if $c > 3 {
            let $j = 3;
            $body
        }
        if $c > 4 {
            let $j = 4;
            $body
        }
        if $c > 5 {
            let $j = 5;
            $body
        }
        if $c > 6 {
            let $j = 6;
            $body
        }
        if $c > 7 {
            let $j = 7;
            $body
        }
    };
}

/// Responsibilities of the samples of `b` (Algorithm 1 line 5 in log space): fills `e[j]`
/// with `e^{x_j − max}`, `x_j = ln α_j + ln C(κ_j) − κ_j|n − μ_j|²/2`, and `d[j]` with the
/// offsets `n − μ_j`, and returns per sample `w · ln Σ_j α_j γ_j(n)` and `w / Σ_j e^{x_j − max}`.
#[inline(always)]
fn block_responsibilities<S: Simd32, const C: usize>(
    b: &Block32,
    a: &Active32,
    e: &mut [S; MAX_LOBES],
    d: &mut [[S; 3]; MAX_LOBES],
) -> (S, S) {
    let (x, y, z, w) = (S::load(&b.x), S::load(&b.y), S::load(&b.z), S::load(&b.w));
    let mut max = S::splat(f32::NEG_INFINITY);
    unroll!(C, j => {
        let dx = x.sub(S::load(&a.mu[0][j]));
        let dy = y.sub(S::load(&a.mu[1][j]));
        let dz = z.sub(S::load(&a.mu[2][j]));
        d[j] = [dx, dy, dz];
        let d2 = dx.mul(dx).add(dy.mul(dy)).add(dz.mul(dz));
        let v = S::load(&a.offset[j]).sub(S::load(&a.half_kappa[j]).mul(d2));
        e[j] = v;
        max = S::select_gt(v, max, v, max);
    });
    let mut sum = S::splat(0.0);
    unroll!(C, j => {
        e[j] = exp_nonpositive(e[j].sub(max));
        sum = sum.add(e[j]);
    });
    (w.mul(max.add(ln_positive(sum))), w.div(sum))
}

/// Blocks summed in `f32` lanes before they are added to the `f64` totals (512 samples: the
/// lane sums' relative rounding stays below 32 ulps).
pub(super) const FLUSH_BLOCKS: usize = 32;

/// One single-precision E-step over `blocks` for the lobes of `active`, returning the M-step
/// sums in `f64`. Compiled for AVX-512, AVX2 and SSE4.2 and chosen at run time; every variant
/// performs the same IEEE operations in the same order (no fused multiply-add), so the result
/// is bit-identical on every CPU.
#[multiversion::multiversion(targets("x86_64+avx512f", "x86_64+avx2+avx", "x86_64+sse4.2"))]
pub(super) fn e_step32(blocks: &[Block32], active: &Active) -> Sums {
    let a = Active32::new(active);
    by_count!(a.count, e_step_kernel::<Portable32>(blocks, &a))
}

/// The kernel proper. The moments are accumulated as offsets from the lobe's (f32) centre,
/// `Σ w z (n − μ_j)`, which are small for a sharp lobe and so keep their relative precision in
/// `f32`; `Σ w z · μ_j` is added back in `f64`. That keeps `1 − |r_j|`, and with it κ_j ≈
/// `1/(1 − |r_j|)`, as accurate as the `f64` kernel's for every storable κ.
#[inline(always)]
fn e_step_kernel<S: Simd32, const C: usize>(blocks: &[Block32], active: &Active32) -> Sums {
    let count = C;
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
            let (ll, scale) = block_responsibilities::<S, C>(b, active, &mut e, &mut d);
            log_likelihood = log_likelihood.add(ll);
            unroll!(C, j => {
                let (a, dj) = (&mut acc[j], &d[j]);
                let wz = e[j].mul(scale);
                a[0] = a[0].add(wz);
                a[1] = a[1].add(wz.mul(dj[0]));
                a[2] = a[2].add(wz.mul(dj[1]));
                a[3] = a[3].add(wz.mul(dj[2]));
            });
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
            sums.moment[c][j] = sums.weight[j] * active.mu[c][j][0] as f64 + oj;
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
    let a = Active32::new(active);
    by_count!(a.count, feature_kernel::<Portable32>(blocks, features, &a))
}

#[inline(always)]
fn feature_kernel<S: Simd32, const C: usize>(
    blocks: &[Block32],
    features: &[FeatureBlock],
    active: &Active32,
) -> ([f64; MAX_LOBES], [[f64; 4]; MAX_LOBES]) {
    let count = C;
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
            let (_, scale) = block_responsibilities::<S, C>(b, active, &mut e, &mut d);
            let (y0, y1, y2, y3) = (
                S::load(&f[0]),
                S::load(&f[1]),
                S::load(&f[2]),
                S::load(&f[3]),
            );
            // The four channels written out: an inner loop over them (the same operations)
            // compiled to code 1.8× slower per call on a 16-sample texel (stop 46).
            unroll!(C, j => {
                let a = &mut acc[j];
                let wz = e[j].mul(scale);
                a[0] = a[0].add(wz);
                a[1] = a[1].add(wz.mul(y0));
                a[2] = a[2].add(wz.mul(y1));
                a[3] = a[3].add(wz.mul(y2));
                a[4] = a[4].add(wz.mul(y3));
            });
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

/// The slots of up to sixteen texels side by side for [`e_step_lanes`]: lane `t` holds texel
/// `t`'s constants. A slot a texel does not use has offset −∞ (it adds exact zeros to that
/// texel's sums); a lane no texel uses has one slot of offset 0 (finite, discarded).
pub(super) struct LaneLobes {
    slots: Active32,
    /// Per lane, the slots its texel uses.
    counts: [usize; LANES],
}

impl LaneLobes {
    /// No texels yet: every lane unused.
    pub(super) fn new() -> Self {
        let mut slots = Active32::empty();
        slots.count = 1;
        slots.offset[0] = [0.0; LANES];
        LaneLobes {
            slots,
            counts: [0; LANES],
        }
    }

    /// Puts the slots of `a` (one texel's E-step) into lane `t`.
    pub(super) fn set(&mut self, t: usize, a: &Active) {
        let count = a.count.min(MAX_LOBES);
        let k = &mut self.slots;
        for s in 0..MAX_LOBES {
            let c = if s < count {
                slot32(a, s)
            } else {
                [0.0, 0.0, 0.0, 0.0, f32::NEG_INFINITY]
            };
            for (m, &v) in k.mu.iter_mut().zip(&c[..3]) {
                m[s][t] = v;
            }
            k.half_kappa[s][t] = c[3];
            k.offset[s][t] = c[4];
        }
        self.counts[t] = count;
        k.count = k.count.max(count);
    }
}

/// Quantities summed per texel by [`e_step_lanes`]: the log-likelihood, then per slot `Σ w z`
/// and `Σ w z (n − μ)`.
const QUANTITIES: usize = 1 + 4 * MAX_LOBES;

/// Partial sums of one texel lane: `[quantity][texel]` in `f64`.
type Node = [[f64; LANES]; QUANTITIES];

/// [`e_step32`] for up to sixteen texels at once, one texel per lane: `lanes[b * LANES + l]`
/// holds sample `l` of block `b` of every texel (lane `t`: texel `t`, padded with zero-weight
/// samples beyond its own blocks), `blocks ≤ FLUSH_BLOCKS`. Each texel's sums have the bits
/// [`e_step32`] gives for it alone: per sample position `l` the same `f32` operations over its
/// blocks in the same order, then the same `f64` pairwise tree over `l` as `lane_sum`, with
/// the padding adding exact zeros. Multiversioned like [`e_step32`].
#[multiversion::multiversion(targets("x86_64+avx512f", "x86_64+avx2+avx", "x86_64+sse4.2"))]
pub(super) fn e_step_lanes(lanes: &[Block32], blocks: usize, lobes: &LaneLobes) -> [Sums; LANES] {
    by_count!(
        lobes.slots.count,
        lanes_kernel::<Portable32>(lanes, blocks, lobes)
    )
}

/// The leaves of `lane_sum`'s tree in an order that evaluates it with a stack (each pair
/// merged as soon as both halves are done): the tree adds `l` and `l + 8`, then `+ 4`, `+ 2`,
/// `+ 1`.
const TREE_ORDER: [usize; LANES] = [0, 8, 4, 12, 2, 10, 6, 14, 1, 9, 5, 13, 3, 11, 7, 15];

#[inline(always)]
fn lanes_kernel<S: Simd32, const C: usize>(
    lanes: &[Block32],
    blocks: usize,
    k: &LaneLobes,
) -> [Sums; LANES] {
    debug_assert!(blocks <= FLUSH_BLOCKS && lanes.len() >= blocks * LANES);
    let count = C;
    let used = 1 + 4 * count;
    let zero = S::splat(0.0);
    let mut e = [zero; MAX_LOBES];
    let mut d = [[zero; 3]; MAX_LOBES];
    let mut stack: [Node; 5] = [[[0.0; LANES]; QUANTITIES]; 5];
    let mut heights = [0u32; 5];
    let mut top = 0;
    for &l in &TREE_ORDER {
        let mut acc = [[zero; 4]; MAX_LOBES];
        let mut log_likelihood = zero;
        for b in 0..blocks {
            let blk = &lanes[b * LANES + l];
            let (ll, scale) = block_responsibilities::<S, C>(blk, &k.slots, &mut e, &mut d);
            log_likelihood = log_likelihood.add(ll);
            unroll!(C, j => {
                let (a, dj) = (&mut acc[j], &d[j]);
                let wz = e[j].mul(scale);
                a[0] = a[0].add(wz);
                a[1] = a[1].add(wz.mul(dj[0]));
                a[2] = a[2].add(wz.mul(dj[1]));
                a[3] = a[3].add(wz.mul(dj[2]));
            });
        }
        let node = &mut stack[top];
        node[0] = log_likelihood.to_array().map(f64::from);
        for (s, a) in acc.iter().enumerate().take(count) {
            for (c, v) in a.iter().enumerate() {
                node[1 + 4 * s + c] = v.to_array().map(f64::from);
            }
        }
        heights[top] = 0;
        top += 1;
        while top >= 2 && heights[top - 1] == heights[top - 2] {
            let (lo, hi) = stack.split_at_mut(top - 1);
            let (left, right) = (&mut lo[top - 2], &hi[0]);
            for (a, b) in left.iter_mut().zip(right.iter()).take(used) {
                for (a, b) in a.iter_mut().zip(b) {
                    *a += *b;
                }
            }
            heights[top - 2] += 1;
            top -= 1;
        }
    }
    debug_assert_eq!(top, 1);
    let root = &stack[0];
    let mut out: [Sums; LANES] = std::array::from_fn(|_| Sums::default());
    for (t, sums) in out.iter_mut().enumerate() {
        let count = k.counts[t];
        sums.log_likelihood += root[0][t];
        for j in 0..count {
            sums.weight[j] += root[1 + 4 * j][t];
            for c in 0..3 {
                let offset = 0.0 + root[1 + 4 * j + 1 + c][t];
                sums.moment[c][j] = sums.weight[j] * k.slots.mu[c][j][t] as f64 + offset;
            }
        }
    }
    out
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
