//! Lane arithmetic for the single-precision E-step: sixteen `f32` samples at a time, as plain
//! arrays that the compiler vectorizes (one AVX-512 register, two AVX2 registers; the caller
//! compiles the kernel for each with `multiversion`, so no `unsafe` intrinsics are needed).
//!
//! As in the `f64` lanes of [`super::simd`], every operation is a plain IEEE-754 add, sub, mul,
//! div, ordered compare, select or integer bit manipulation — never a fused multiply-add — in
//! a fixed order, so the E-step returns the same bits whichever instruction set runs it. The
//! transcendental functions are written once, generically: [`exp_nonpositive`] and
//! [`ln_positive`], accurate to a few ulps of `f32` over the ranges the E-step uses.

/// Samples per block.
pub(super) const LANES: usize = 16;

/// One value per sample of a block.
pub(super) type Lane = [f32; LANES];

/// Sixteen floats with the operations the E-step needs.
pub(super) trait Simd32: Copy {
    fn splat(v: f32) -> Self;
    fn load(a: &Lane) -> Self;
    fn to_array(self) -> Lane;
    fn add(self, o: Self) -> Self;
    fn sub(self, o: Self) -> Self;
    fn mul(self, o: Self) -> Self;
    fn div(self, o: Self) -> Self;
    /// Lane-wise `if a > b { x } else { y }` (false for NaN).
    fn select_gt(a: Self, b: Self, x: Self, y: Self) -> Self;
    /// Lane-wise `f32::from_bits((self.to_bits() − c) << 23)`: with `self = 1.5·2²³ + k`
    /// (the rounding trick) and `c = bits(1.5·2²³) − 127`, the float `2^k`.
    fn exponent_scale(self, c: u32) -> Self;
    /// Lane-wise `(m, e)`: the mantissa of `self` with a zero exponent (in `[1, 2)`) and the
    /// unbiased exponent as a float.
    fn split_exponent(self) -> (Self, Self);
}

/// The reference implementation: plain arrays, any target.
#[derive(Clone, Copy)]
pub(super) struct Portable32(Lane);

impl Simd32 for Portable32 {
    #[inline(always)]
    fn splat(v: f32) -> Self {
        Portable32([v; LANES])
    }
    #[inline(always)]
    fn load(a: &Lane) -> Self {
        Portable32(*a)
    }
    #[inline(always)]
    fn to_array(self) -> Lane {
        self.0
    }
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        Portable32(std::array::from_fn(|l| self.0[l] + o.0[l]))
    }
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        Portable32(std::array::from_fn(|l| self.0[l] - o.0[l]))
    }
    #[inline(always)]
    fn mul(self, o: Self) -> Self {
        Portable32(std::array::from_fn(|l| self.0[l] * o.0[l]))
    }
    #[inline(always)]
    fn div(self, o: Self) -> Self {
        Portable32(std::array::from_fn(|l| self.0[l] / o.0[l]))
    }
    #[inline(always)]
    fn select_gt(a: Self, b: Self, x: Self, y: Self) -> Self {
        Portable32(std::array::from_fn(|l| {
            if a.0[l] > b.0[l] { x.0[l] } else { y.0[l] }
        }))
    }
    #[inline(always)]
    fn exponent_scale(self, c: u32) -> Self {
        Portable32(std::array::from_fn(|l| {
            f32::from_bits(self.0[l].to_bits().wrapping_sub(c) << 23)
        }))
    }
    #[inline(always)]
    fn split_exponent(self) -> (Self, Self) {
        let m = std::array::from_fn(|l| {
            f32::from_bits((self.0[l].to_bits() & 0x007F_FFFF) | 0x3F80_0000)
        });
        // The exponent field read as a float: 2²³ + e_biased, then the offset removed.
        let e = std::array::from_fn(|l| {
            f32::from_bits((self.0[l].to_bits() >> 23) | 0x4B00_0000) - (8_388_608.0 + 127.0)
        });
        (Portable32(m), Portable32(e))
    }
}

/// `ln 2` split so `k · LN2_HI` is exact for |k| < 2¹² (Cephes' `expf` constants).
const LN2_HI: f32 = 0.693_359_4;
const LN2_LO: f32 = -2.121_944_4e-4;

/// `e^x` for `x ≤ 0` (the log-sum-exp terms `x_j − max`), branch-free: Cody–Waite reduction
/// `x = k ln 2 + r`, `|r| ≤ ln 2 / 2`, Cephes' degree-6 polynomial for `e^r`, and `2^k` from
/// the exponent bits. Relative error below 2e-7 (tested against `f64::exp`); positive `x` is
/// treated as 0 and results below `e^{−87}` (≈ 1.6e-38, the smallest normal `f32`) are
/// flushed to 0.
#[inline(always)]
pub(super) fn exp_nonpositive<S: Simd32>(x: S) -> S {
    const P: [f32; 6] = [
        1.987_569_1e-4,
        1.398_199_9e-3,
        8.333_452e-3,
        4.166_579_6e-2,
        1.666_666_5e-1,
        5e-1,
    ];
    let zero = S::splat(0.0);
    let limit = S::splat(-87.0);
    let xc = S::select_gt(limit, x, limit, S::select_gt(x, zero, zero, x));
    // k = round(x / ln 2) by the 1.5·2²³ trick (exact for |k| < 2²²).
    const MAGIC: f32 = 12_582_912.0;
    let magic = S::splat(MAGIC);
    let t = xc.mul(S::splat(std::f32::consts::LOG2_E)).add(magic);
    let kf = t.sub(magic);
    let r = xc
        .sub(kf.mul(S::splat(LN2_HI)))
        .sub(kf.mul(S::splat(LN2_LO)));
    let mut p = S::splat(P[0]);
    for &c in &P[1..] {
        p = p.mul(r).add(S::splat(c));
    }
    let r2 = r.mul(r);
    let e = p.mul(r2).add(r).add(S::splat(1.0));
    S::select_gt(
        limit,
        x,
        zero,
        e.mul(t.exponent_scale(MAGIC.to_bits() - 127)),
    )
}

/// `ln s` for positive, finite, normal `s` (here the log-sum-exp sum, in `[1, 8]`),
/// branch-free: `s = 2^e m` with `m` in `[√½, √2)`, `ln m = 2 atanh(u)`, `u = (m − 1)/(m + 1)`,
/// by its series to `u⁹` (`|u| ≤ 0.172`, truncation below 3e-9). Absolute error below 2e-7.
#[inline(always)]
pub(super) fn ln_positive<S: Simd32>(s: S) -> S {
    let (m, e) = s.split_exponent();
    let one = S::splat(1.0);
    let big = S::select_gt(m, S::splat(std::f32::consts::SQRT_2), one, S::splat(0.0));
    let m = m.sub(big.mul(m.mul(S::splat(0.5))));
    let e = e.add(big);
    let u = m.sub(one).div(m.add(one));
    let u2 = u.mul(u);
    let mut p = S::splat(1.0 / 9.0);
    for c in [1.0 / 7.0, 1.0 / 5.0, 1.0 / 3.0, 1.0] {
        p = p.mul(u2).add(S::splat(c));
    }
    e.mul(S::splat(std::f32::consts::LN_2))
        .add(S::splat(2.0).mul(u).mul(p))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lanes(f: impl Fn(usize) -> f32) -> Portable32 {
        Portable32(std::array::from_fn(f))
    }

    #[test]
    fn exp_is_accurate_on_the_nonpositive_axis() {
        let mut worst = 0.0f64;
        for i in 0..20_000 {
            let x = lanes(|l| -((i * LANES + l) as f32) * 87.0 / (20_000.0 * LANES as f32));
            let got = exp_nonpositive(x).to_array();
            for (g, xv) in got.iter().zip(x.to_array()) {
                let want = (xv as f64).exp();
                worst = worst.max(((*g as f64) - want).abs() / want);
            }
        }
        assert!(worst < 2e-7, "relative error {worst:e}");
        let edge = exp_nonpositive(lanes(|l| {
            [1.0, 0.0, -88.0, -1e30, f32::NEG_INFINITY][l % 5]
        }));
        assert_eq!(&edge.to_array()[..5], &[1.0, 1.0, 0.0, 0.0, 0.0]);
    }

    #[test]
    fn ln_is_accurate_where_the_e_step_uses_it() {
        let mut worst = 0.0f64;
        for i in 0..20_000 {
            let s = lanes(|l| 1.0 + ((i * LANES + l) as f32) * 15.0 / (20_000.0 * LANES as f32));
            let got = ln_positive(s).to_array();
            for (g, sv) in got.iter().zip(s.to_array()) {
                worst = worst.max(((*g as f64) - (sv as f64).ln()).abs());
            }
        }
        assert!(worst < 2e-7, "absolute error {worst:e}");
    }
}
