//! The isotropic fit's inner loops (issue 17's speed goal: a 1024² map well under a second of
//! fit per level on 2 cores). A [`FitSet`]'s pairs are held as columns padded with weight-0
//! pairs to a multiple of eight, and the cost `Σ_p w_p² (D_α(n·h_p) max(n·l_p, 0) − G_p)²` and
//! the Levenberg–Marquardt normal equations `JᵀJ`, `Jᵀr` are summed in eight f64 lanes without
//! branches, so that the compiler vectorizes them. The functions are compiled for AVX-512, AVX2
//! and SSE4.2 and chosen at run time (`multiversion`); every variant performs the same IEEE
//! operations in the same order (no fused multiply-add, lanes combined in a fixed order), so a
//! fit is bit-identical on every CPU and for every thread count.

use super::{FitSet, IsoLobe, MAX_PAIRS, MIN_ALPHA};
use crate::brdf::tangent_frame;
use glam::DVec3;
use std::f64::consts::PI;

/// Lanes summed side by side.
const LANES: usize = 8;

/// Blocks of [`LANES`] pairs in [`MAX_PAIRS`].
const BLOCKS: usize = MAX_PAIRS / LANES;

/// A fit set's half vectors, lights and weights as columns, padded with weight-0 pairs (half
/// vector and light at the zenith) to a multiple of [`LANES`].
#[derive(Debug, Clone)]
pub(super) struct IsoKernel {
    h: [[f64; MAX_PAIRS]; 3],
    l: [[f64; MAX_PAIRS]; 3],
    w: [f64; MAX_PAIRS],
    blocks: usize,
}

/// One texel's targets, padded with zeros like the kernel's pairs.
pub(super) type Targets = [f64; MAX_PAIRS];

impl IsoKernel {
    /// The columns of `set` (at most [`MAX_PAIRS`] pairs: the bake checks).
    pub(super) fn new(set: &FitSet) -> IsoKernel {
        let mut k = IsoKernel {
            h: [[0.0; MAX_PAIRS]; 3],
            l: [[0.0; MAX_PAIRS]; 3],
            w: [0.0; MAX_PAIRS],
            blocks: set.pairs.len().min(MAX_PAIRS).div_ceil(LANES),
        };
        k.h[2] = [1.0; MAX_PAIRS];
        k.l[2] = [1.0; MAX_PAIRS];
        for (i, ((&(l, _), &h), &w)) in set
            .pairs
            .iter()
            .zip(&set.halves)
            .zip(&set.weights)
            .take(MAX_PAIRS)
            .enumerate()
        {
            for c in 0..3 {
                k.h[c][i] = h[c];
                k.l[c][i] = l[c];
            }
            k.w[i] = w;
        }
        k
    }

    /// `target` (one value per pair) padded with zeros.
    pub(super) fn targets(&self, target: &[f64]) -> Targets {
        let mut g = [0.0; MAX_PAIRS];
        for (g, t) in g.iter_mut().zip(target) {
            *g = *t;
        }
        g
    }

    /// The cost `Σ w² (D_α(n·h) max(n·l, 0) − G)²` of lobe `(n, α)` (the module's `cost` of
    /// `iso_value`, summed in lanes).
    pub(super) fn cost(&self, n: DVec3, alpha: f64, g: &Targets) -> f64 {
        cost_lanes(self, [n.x, n.y, n.z], alpha * alpha, g)
    }

    /// The normal equations of the residuals `w (D_α(n·h) max(n·l, 0) − G)` in the parameters
    /// `(u, v, ln α)` at lobe `(n, α)`, with `du`, `dv` the derivatives of `n` along `u` and
    /// `v` (the ln α column is zero when `free_alpha` is false): `(JᵀJ, −Jᵀr)`.
    pub(super) fn normal_equations(
        &self,
        n: DVec3,
        du: DVec3,
        dv: DVec3,
        alpha: f64,
        free_alpha: bool,
        g: &Targets,
    ) -> ([[f64; 3]; 3], [f64; 3]) {
        let v = |d: DVec3| [d.x, d.y, d.z];
        let (a, b) = normal_lanes(
            self,
            [v(n), v(du), v(dv)],
            alpha * alpha,
            if free_alpha { 1.0 } else { 0.0 },
            g,
        );
        // a: uu, uv, ua, vv, va, aa; b: −Jᵀr.
        (
            [[a[0], a[1], a[2]], [a[1], a[3], a[4]], [a[2], a[4], a[5]]],
            b,
        )
    }
}

/// Sums the lanes in a fixed order (pairwise).
#[inline(always)]
fn combine(l: L) -> f64 {
    ((l[0] + l[1]) + (l[2] + l[3])) + ((l[4] + l[5]) + (l[6] + l[7]))
}

/// One value per lane.
type L = [f64; LANES];

/// Lane-wise arithmetic on plain arrays (the compiler turns each into one vector instruction).
#[inline(always)]
fn zip(a: L, b: L, f: impl Fn(f64, f64) -> f64) -> L {
    std::array::from_fn(|i| f(a[i], b[i]))
}
#[inline(always)]
fn add(a: L, b: L) -> L {
    zip(a, b, |x, y| x + y)
}
#[inline(always)]
fn sub(a: L, b: L) -> L {
    zip(a, b, |x, y| x - y)
}
#[inline(always)]
fn mul(a: L, b: L) -> L {
    zip(a, b, |x, y| x * y)
}
#[inline(always)]
fn div(a: L, b: L) -> L {
    zip(a, b, |x, y| x / y)
}
#[inline(always)]
fn splat(v: f64) -> L {
    [v; LANES]
}
/// Lane-wise `if a > 0 { x } else { 0 }` (0 for NaN).
#[inline(always)]
fn positive_or_zero(a: L, x: L) -> L {
    zip(a, x, |a, x| if a > 0.0 { x } else { 0.0 })
}
/// Lane-wise `max(a, 0)`.
#[inline(always)]
fn relu(a: L) -> L {
    positive_or_zero(a, a)
}

/// Block `b` of a column.
#[inline(always)]
fn block(col: &[f64; MAX_PAIRS], b: usize) -> L {
    let o = b * LANES;
    std::array::from_fn(|i| col[o + i])
}

/// `x · (column triple)` for block `b`.
#[inline(always)]
fn dot(x: &[f64; 3], c: &[[f64; MAX_PAIRS]; 3], b: usize) -> L {
    add(
        add(
            mul(splat(x[0]), block(&c[0], b)),
            mul(splat(x[1]), block(&c[1], b)),
        ),
        mul(splat(x[2]), block(&c[2], b)),
    )
}

/// The GGX value `a2/(π d²)` with `d = (1 − c)(1 + c) + c² a2` at `c = min(n·h, 1)` (`d` held
/// above 1e-300), returned with `1/d` and `c`; the caller zeroes it for `n·h ≤ 0`
/// ([`crate::brdf::ggx`]). One division per lane.
#[inline(always)]
fn lobe(c: L, a2: f64) -> (L, L, L) {
    let one = splat(1.0);
    let c = zip(c, one, f64::min);
    let d = add(mul(sub(one, c), add(one, c)), mul(mul(c, c), splat(a2)));
    let inv = div(one, zip(d, splat(1e-300), f64::max));
    (mul(splat(a2 / PI), mul(inv, inv)), inv, c)
}

#[multiversion::multiversion(targets("x86_64+avx512f", "x86_64+avx2+avx", "x86_64+sse4.2"))]
fn cost_lanes(k: &IsoKernel, n: [f64; 3], a2: f64, g: &Targets) -> f64 {
    let mut acc = splat(0.0);
    for b in 0..BLOCKS {
        if b >= k.blocks {
            break;
        }
        let c = dot(&n, &k.h, b);
        let cl = dot(&n, &k.l, b);
        let (dd, _, _) = lobe(c, a2);
        let value = positive_or_zero(c, mul(dd, relu(cl)));
        let r = mul(block(&k.w, b), sub(value, block(g, b)));
        acc = add(acc, mul(r, r));
    }
    combine(acc)
}

#[multiversion::multiversion(targets("x86_64+avx512f", "x86_64+avx2+avx", "x86_64+sse4.2"))]
fn normal_lanes(
    k: &IsoKernel,
    [n, du, dv]: [[f64; 3]; 3],
    a2: f64,
    free_alpha: f64,
    g: &Targets,
) -> ([f64; 6], [f64; 3]) {
    let mut a = [splat(0.0); 6];
    let mut bv = [splat(0.0); 3];
    let one = splat(1.0);
    for b in 0..BLOCKS {
        if b >= k.blocks {
            break;
        }
        let c0 = dot(&n, &k.h, b);
        let cl = dot(&n, &k.l, b);
        let (dd, inv, c) = lobe(c0, a2);
        let s = relu(cl);
        let ds = positive_or_zero(cl, one);
        let wb = block(&k.w, b);
        let w = positive_or_zero(c0, wb);
        // ∂D/∂c = 4 a2 c (1 − a2)/(π d³); ∂D/∂ln α = 2 D (1 − 2 c² a2 / d).
        let dc = mul(
            mul(splat(4.0 * a2 * (1.0 - a2) / PI), c),
            mul(inv, mul(inv, inv)),
        );
        let dlna = mul(
            mul(splat(2.0), dd),
            sub(one, mul(mul(splat(2.0 * a2), mul(c, c)), inv)),
        );
        let r = mul(wb, sub(positive_or_zero(c0, mul(dd, s)), block(g, b)));
        let dds = mul(dd, ds);
        let dcs = mul(dc, s);
        let ju = mul(
            w,
            add(mul(dcs, dot(&du, &k.h, b)), mul(dds, dot(&du, &k.l, b))),
        );
        let jv = mul(
            w,
            add(mul(dcs, dot(&dv, &k.h, b)), mul(dds, dot(&dv, &k.l, b))),
        );
        let ja = mul(mul(w, mul(dlna, s)), splat(free_alpha));
        a[0] = add(a[0], mul(ju, ju));
        a[1] = add(a[1], mul(ju, jv));
        a[2] = add(a[2], mul(ju, ja));
        a[3] = add(a[3], mul(jv, jv));
        a[4] = add(a[4], mul(jv, ja));
        a[5] = add(a[5], mul(ja, ja));
        bv[0] = sub(bv[0], mul(ju, r));
        bv[1] = sub(bv[1], mul(jv, r));
        bv[2] = sub(bv[2], mul(ja, r));
    }
    (a.map(combine), bv.map(combine))
}

/// [`super::fit_isotropic`] on a kernel: the best of `starts`, then up to `iterations`
/// Levenberg–Marquardt steps over `(u, v, ln α)`, stopping early once a step lowers the cost
/// by `converged` of itself or less (or no damping lowers it). With `hold_normal` the steps
/// move ln α only: the best start's normal is kept ([`super::PbrOptions::mean_normal`]).
pub(super) fn fit(
    k: &IsoKernel,
    g: &Targets,
    starts: &[IsoLobe],
    iterations: usize,
    floor: f64,
    converged: f64,
    hold_normal: bool,
) -> (IsoLobe, f64) {
    let mut best = starts[0];
    let mut best_cost = f64::INFINITY;
    for s in starts {
        let c = k.cost(s.n, s.alpha, g);
        if c < best_cost {
            best = *s;
            best_cost = c;
        }
    }
    if iterations == 0 || best_cost == 0.0 {
        return (best, best_cost);
    }
    let n0 = best.n;
    let (t1, t2) = tangent_frame(n0);
    let lo = floor.clamp(MIN_ALPHA, 1.0).ln();
    let lobe_of = |p: &[f64; 3]| IsoLobe {
        n: (n0 + p[0] * t1 + p[1] * t2).normalize(),
        alpha: p[2].clamp(lo, 0.0).exp(),
    };
    let normal_equations = |p: &[f64; 3]| {
        let lobe = lobe_of(p);
        let n = lobe.n;
        // dn/du, dn/dv of n = normalize(n0 + u t1 + v t2): (t − n (n·t)) / |n0 + u t1 + v t2|.
        let len = (n0 + p[0] * t1 + p[1] * t2).length();
        let du = (t1 - n * n.dot(t1)) / len;
        let dv = (t2 - n * n.dot(t2)) / len;
        let (mut a, mut b) = k.normal_equations(n, du, dv, lobe.alpha, true, g);
        if hold_normal {
            super::hold_normal_parameters(&mut a, &mut b);
        }
        // ln α is held at a bound only while the descent direction −Jᵀr points out of the
        // range (an active set): a start at the floor (the base α) can still widen.
        if (p[2] <= lo && b[2] <= 0.0) || (p[2] >= 0.0 && b[2] >= 0.0) {
            for row in a.iter_mut() {
                row[2] = 0.0;
            }
            a[2] = [0.0; 3];
            b[2] = 0.0;
        }
        (a, b)
    };
    let cost_at = |p: &[f64; 3]| {
        let t = lobe_of(p);
        k.cost(t.n, t.alpha, g)
    };
    let (p, current) = super::levenberg_marquardt(
        [0.0, 0.0, best.alpha.ln().clamp(lo, 0.0)],
        best_cost,
        iterations,
        [0.3, 0.3, 1.0],
        converged,
        normal_equations,
        cost_at,
    );
    if current < best_cost {
        (lobe_of(&p), current)
    } else {
        (best, best_cost)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::half_vector;

    /// The lane sums equal the module's plain per-pair cost, and the normal equations equal
    /// those of a central-difference Jacobian of the plain residuals.
    #[test]
    fn lane_sums_equal_plain_sums_and_finite_differences() {
        let set = FitSet::near_peak(0.05);
        let truth = DVec3::new(0.2, -0.1, 1.0).normalize();
        let target: Vec<f64> = set
            .pairs
            .iter()
            .map(|&(l, v)| 0.7 * super::super::iso_value(truth, 0.21, l, half_vector(l, v)))
            .collect();
        let k = IsoKernel::new(&set);
        let g = k.targets(&target);
        let residuals = |n: DVec3, a: f64| -> Vec<f64> {
            set.pairs
                .iter()
                .zip(&set.weights)
                .zip(&target)
                .map(|((&(l, v), w), t)| {
                    w * (super::super::iso_value(n, a, l, half_vector(l, v)) - t)
                })
                .collect()
        };
        for (n, a) in [
            (DVec3::Z, 0.1),
            (DVec3::new(0.3, 0.1, 1.0).normalize(), 0.3),
            (DVec3::new(-0.5, 0.4, 0.6).normalize(), 0.02),
        ] {
            let plain: f64 = residuals(n, a).iter().map(|r| r * r).sum();
            let lanes = k.cost(n, a, &g);
            assert!(
                (lanes - plain).abs() <= 1e-12 * plain.max(1e-300),
                "{lanes} {plain}"
            );
            let (t1, t2) = tangent_frame(n);
            let at = |p: [f64; 3]| residuals((n + p[0] * t1 + p[1] * t2).normalize(), p[2].exp());
            let r0 = at([0.0, 0.0, a.ln()]);
            let e = 1e-6;
            let cols: Vec<Vec<f64>> = (0..3)
                .map(|u| {
                    let (mut p, mut q) = ([0.0, 0.0, a.ln()], [0.0, 0.0, a.ln()]);
                    p[u] += e;
                    q[u] -= e;
                    at(p)
                        .iter()
                        .zip(at(q))
                        .map(|(x, y)| (x - y) / (2.0 * e))
                        .collect()
                })
                .collect();
            let (ja, jb) = k.normal_equations(n, t1, t2, a, true, &g);
            let scale = ja[0][0].abs() + ja[1][1].abs() + ja[2][2].abs();
            for u in 0..3 {
                let b: f64 = -cols[u].iter().zip(&r0).map(|(j, r)| j * r).sum::<f64>();
                let bs = (ja[u][u] * plain).sqrt().max(1e-12);
                assert!((jb[u] - b).abs() <= 1e-5 * bs, "Jᵀr {u}: {} {b}", jb[u]);
                for w in 0..3 {
                    let a: f64 = cols[u].iter().zip(&cols[w]).map(|(x, y)| x * y).sum();
                    assert!(
                        (ja[u][w] - a).abs() <= 1e-5 * scale,
                        "JᵀJ {u}{w}: {} {a}",
                        ja[u][w]
                    );
                }
            }
        }
    }
}
