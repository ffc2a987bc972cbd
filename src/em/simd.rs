//! Lane arithmetic for the E-step of Algorithm 1: eight `f64` samples at a time, as plain
//! arrays that the compiler vectorizes (the caller compiles the kernel for AVX2 and AVX-512
//! with `multiversion`, so no `unsafe` intrinsics are needed).
//!
//! Every implementation performs the same IEEE-754 operations (add, sub, mul, div, ordered
//! compare, select, integer bit manipulation; never a fused multiply-add) in the same order, so
//! the E-step returns the same bits whichever one the CPU selects. The transcendental functions
//! ([`exp_nonpositive`], [`ln_positive`]) are written once, generically, on top of them.

/// Samples per block (one AVX-512 register, two AVX2 registers).
pub(super) const LANES: usize = 8;

/// One value per sample of a block.
pub(super) type Lane = [f64; LANES];

/// Eight doubles with the handful of operations the E-step needs.
///
/// Implementations other than [`Portable`] may only be used inside functions compiled with
/// their target feature (see `e_step` in the parent module).
pub(super) trait Simd: Copy {
    fn splat(v: f64) -> Self;
    fn load(a: &Lane) -> Self;
    fn to_array(self) -> Lane;
    fn add(self, o: Self) -> Self;
    fn sub(self, o: Self) -> Self;
    fn mul(self, o: Self) -> Self;
    fn div(self, o: Self) -> Self;
    /// Lane-wise `if a > b { x } else { y }` (false for NaN).
    fn select_gt(a: Self, b: Self, x: Self, y: Self) -> Self;
    /// Lane-wise `f64::from_bits((self.to_bits() − c) << 52)`.
    fn exponent_scale(self, c: u64) -> Self;
    /// Lane-wise `(m, e)` with `m` = the mantissa of `self` with a zero exponent (in `[1, 2)`)
    /// and `e` = the biased exponent field as an `f64` minus 1023.
    fn split_exponent(self) -> (Self, Self);
}

const MANTISSA: u64 = 0x000F_FFFF_FFFF_FFFF;
const ONE_BITS: u64 = 0x3FF0_0000_0000_0000;
/// The bits of 2⁵², so `from_bits(TWO52_BITS | n) = 2⁵² + n` for `n < 2⁵²`.
const TWO52_BITS: u64 = 0x4330_0000_0000_0000;
const TWO52: f64 = 4_503_599_627_370_496.0;

/// The reference implementation: plain arrays, any target.
#[derive(Clone, Copy)]
pub(super) struct Portable(Lane);

impl Simd for Portable {
    #[inline(always)]
    fn splat(v: f64) -> Self {
        Portable([v; LANES])
    }
    #[inline(always)]
    fn load(a: &Lane) -> Self {
        Portable(*a)
    }
    #[inline(always)]
    fn to_array(self) -> Lane {
        self.0
    }
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        Portable(std::array::from_fn(|l| self.0[l] + o.0[l]))
    }
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        Portable(std::array::from_fn(|l| self.0[l] - o.0[l]))
    }
    #[inline(always)]
    fn mul(self, o: Self) -> Self {
        Portable(std::array::from_fn(|l| self.0[l] * o.0[l]))
    }
    #[inline(always)]
    fn div(self, o: Self) -> Self {
        Portable(std::array::from_fn(|l| self.0[l] / o.0[l]))
    }
    #[inline(always)]
    fn select_gt(a: Self, b: Self, x: Self, y: Self) -> Self {
        Portable(std::array::from_fn(|l| {
            if a.0[l] > b.0[l] { x.0[l] } else { y.0[l] }
        }))
    }
    #[inline(always)]
    fn exponent_scale(self, c: u64) -> Self {
        Portable(std::array::from_fn(|l| {
            f64::from_bits(self.0[l].to_bits().wrapping_sub(c) << 52)
        }))
    }
    #[inline(always)]
    fn split_exponent(self) -> (Self, Self) {
        let m =
            std::array::from_fn(|l| f64::from_bits((self.0[l].to_bits() & MANTISSA) | ONE_BITS));
        let e = std::array::from_fn(|l| {
            f64::from_bits((self.0[l].to_bits() >> 52) | TWO52_BITS) - (TWO52 + 1023.0)
        });
        (Portable(m), Portable(e))
    }
}

/// fdlibm's split of ln 2 (the high part has 32 trailing zero bits, so `k · LN2_HI` is exact).
const LN2_HI: f64 = f64::from_bits(0x3FE6_2E42_FEE0_0000); // 0.6931471803691238
const LN2_LO: f64 = f64::from_bits(0x3DEA_39EF_3579_3C76); // 1.9082149292705877e-10

/// `e^x` for `x ≤ 0` (the log-sum-exp terms `x_j − max`), branch-free: Cody–Waite reduction
/// `x = k ln 2 + r`, `|r| ≤ ln 2 / 2`, a degree-11 Chebyshev-fitted polynomial (fit error
/// 3e-18), and `2^k` built from the exponent bits. Relative error ≤ 2.3e-16 (tested against
/// `f64::exp`); positive `x` is treated as 0 and results below `e^{−708}` (≈ 3e-308) are
/// flushed to 0, which only empties lobes no sample can reach.
#[inline(always)]
pub(super) fn exp_nonpositive<S: Simd>(x: S) -> S {
    const MAGIC: f64 = 6_755_399_441_055_744.0; // 1.5·2⁵²: adding it rounds to an integer
    const P: [f64; 12] = [
        2.511_003_760_596_377_7e-8,
        2.763_263_963_904_103e-7,
        2.755_724_091_857_897e-6,
        2.480_148_548_232_849_4e-5,
        1.984_126_989_004_711_3e-4,
        1.388_888_895_231_477_5e-3,
        8.333_333_333_319_601e-3,
        4.166_666_666_648_81e-2,
        1.666_666_666_666_668e-1,
        5.000_000_000_000_019e-1,
        1.0,
        1.0,
    ];
    let zero = S::splat(0.0);
    let limit = S::splat(-708.0);
    let xc = S::select_gt(limit, x, limit, S::select_gt(x, zero, zero, x));
    let magic = S::splat(MAGIC);
    let t = xc.mul(S::splat(std::f64::consts::LOG2_E)).add(magic);
    let kf = t.sub(magic);
    let r = xc
        .sub(kf.mul(S::splat(LN2_HI)))
        .sub(kf.mul(S::splat(LN2_LO)));
    let mut p = S::splat(P[0]);
    for &c in &P[1..] {
        p = p.mul(r).add(S::splat(c));
    }
    // 2^k with k = bits(t) − bits(MAGIC): exponent field k + 1023.
    let scale = t.exponent_scale(MAGIC.to_bits() - 1023);
    S::select_gt(limit, x, zero, p.mul(scale))
}

/// `ln s` for positive, finite, normal `s` (here the log-sum-exp sum, in `[1, 8]`),
/// branch-free: `s = 2^e m` with `m` in `[√½, √2)`, `ln m = 2 atanh(u)`, `u = (m − 1)/(m + 1)`,
/// by its series to `u²¹`. Error ≤ 2.3e-16 relative (absolute near `s = 1`), tested against
/// `f64::ln`.
#[inline(always)]
pub(super) fn ln_positive<S: Simd>(s: S) -> S {
    const C: [f64; 11] = [
        1.0 / 21.0,
        1.0 / 19.0,
        1.0 / 17.0,
        1.0 / 15.0,
        1.0 / 13.0,
        1.0 / 11.0,
        1.0 / 9.0,
        1.0 / 7.0,
        1.0 / 5.0,
        1.0 / 3.0,
        1.0,
    ];
    let (m, e) = s.split_exponent();
    let sqrt2 = S::splat(std::f64::consts::SQRT_2);
    let one = S::splat(1.0);
    let big_m = S::select_gt(m, sqrt2, m.mul(S::splat(0.5)), m);
    let e = S::select_gt(m, sqrt2, e.add(one), e);
    let f = big_m.sub(one);
    let u = f.div(S::splat(2.0).add(f));
    let u2 = u.mul(u);
    let mut p = S::splat(C[0]);
    for &c in &C[1..] {
        p = p.mul(u2).add(S::splat(c));
    }
    e.mul(S::splat(LN2_HI))
        .add(S::splat(2.0).mul(u).mul(p).add(e.mul(S::splat(LN2_LO))))
}
