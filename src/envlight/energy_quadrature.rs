//! How the prefiltered route's lobe tables are made ([`super::ENERGY_BLOCKS`] quantities of each
//! lobe over [`super::ENERGY_PARAM`] parameters × [`super::ENERGY_COS`] view cosines, by
//! quadrature): the tables are embedded in the library (`energy-*.f64le` beside this file), and
//! this module, compiled for the tests only, recomputes them. The test
//! `embedded_tables_are_the_quadrature` checks the embedded copies against it, and with
//! `NDFMAP_BLESS=1` rewrites them (`NDFMAP_BLESS=1 cargo test --release --lib
//! embedded_tables_are_the_quadrature`).

use super::{ENERGY_BLOCKS, ENERGY_COS, ENERGY_PARAM, ENERGY_SHARES};
use crate::brdf::ggx;
use glam::DVec3;
use rayon::prelude::*;
use std::f64::consts::PI;

/// Row i's Blinn-Phong exponent: `log2 s` in equal steps over [−4, 20] (the lookup,
/// `EnergyTables::blinn_phong`, inverts it).
fn bp_param(i: usize) -> f64 {
    (-4.0 + 24.0 * i as f64 / (ENERGY_PARAM - 1) as f64).exp2()
}

/// Row i's GGX roughness: `log10 α` in equal steps over [−3, 0] (`EnergyTables::ggx`
/// inverts it).
fn ggx_param(i: usize) -> f64 {
    10f64.powf(-3.0 + 3.0 * i as f64 / (ENERGY_PARAM - 1) as f64)
}

/// One family's table: the lobes `f(c) = lobe(p, w)(c)` over [`ENERGY_PARAM`] parameters
/// `param(i)` (quadrature width `width(p)`) × `shares` NDF shares `w = j/(shares − 1)` (one
/// share, `w = 0`, for a family whose lobe keeps its shape under an NDF lobe) × [`ENERGY_COS`]
/// view cosines, for each of the [`ENERGY_BLOCKS`] quantities of [`lobe_moments`]: block after
/// block, parameter after parameter, share after share (`EnergyTables::lookup`'s order;
/// `envgpu::energy` packs it for upload).
///
/// `lobe(p, w)` is built once per parameter and share.
/// With `gaussian` (GGX: `p ↦ s`, the Blinn-Phong exponent of the same variance), block 6 is
/// not the lobe's own half-vector energy but `E_0 · E_h^BP / E_0^BP` at that exponent: the
/// cosine inside the lobe comes from the spread of the *normals*, a vMF, whose shape is
/// Blinn-Phong's, not GGX's long tail (a GGX α' lobe with the cosine at its half vector
/// over-counts its tail towards the view: measured +21 … +36 % at κ = 8 under a constant
/// environment, against +3 … +6 % this way; `one_lobe_matches_its_exact_integral_…`).
/// `rows` limits the parameters computed (the tests check a subset; the rest are NaN).
fn energy_table_of(
    lobe: &(dyn Fn(f64, f64) -> Box<dyn Fn(f64) -> f64> + Sync),
    param: fn(usize) -> f64,
    width: fn(f64) -> f64,
    shares: usize,
    two_vmf: bool,
    gaussian: Option<fn(f64) -> f64>,
    rows: &(dyn Fn(usize) -> bool + Sync),
) -> Vec<f64> {
    let share = |j: usize| {
        if shares > 1 {
            j as f64 / (shares - 1) as f64
        } else {
            0.0
        }
    };
    let cells: Vec<[f64; ENERGY_BLOCKS]> = (0..ENERGY_PARAM * shares)
        .into_par_iter()
        .flat_map_iter(|k| {
            let (i, j) = (k / shares, k % shares);
            let p = param(i);
            let f = rows(i).then(|| lobe(p, share(j)));
            (0..ENERGY_COS).map(move |c| {
                let Some(f) = &f else {
                    return [f64::NAN; ENERGY_BLOCKS];
                };
                let co = c as f64 / (ENERGY_COS - 1) as f64;
                let mut m = lobe_moments(f.as_ref(), width(p), co, two_vmf);
                if let Some(to_s) = gaussian {
                    let s = to_s(p);
                    let bp = lobe_moments(
                        &|c| crate::brdf::blinn_phong(c, s),
                        (1.0 / s.sqrt()).min(0.5 * PI),
                        co,
                        false,
                    );
                    m[6] = if bp[0] > 0.0 {
                        m[0] * bp[6] / bp[0]
                    } else {
                        m[0]
                    };
                    m[8] = bp[8];
                }
                m
            })
        })
        .collect();
    let n = cells.len();
    let mut out = vec![0.0; ENERGY_BLOCKS * n];
    for (k, c) in cells.iter().enumerate() {
        for (b, v) in c.iter().enumerate() {
            out[b * n + k] = *v;
        }
    }
    out
}

/// The Blinn-Phong table by quadrature (one share: a Blinn-Phong lobe widened by an NDF lobe
/// is a Blinn-Phong lobe, `1/s' = 1/s + 1/κ`).
pub(super) fn blinn_phong_table() -> Vec<f64> {
    energy_table_of(
        &|s, _| Box::new(move |c| crate::brdf::blinn_phong(c, s)),
        bp_param,
        |s| (1.0 / s.sqrt()).min(0.5 * PI),
        1,
        false,
        None,
        &|_| true,
    )
}

/// The GGX table by quadrature, over `(α', w)`: the lobe of row α' and share w is eq 14 — GGX of
/// roughness `α = α'·sqrt(1 − w)` convolved with a vMF NDF lobe of concentration
/// `κ = c/(w·α'²)` (`c =` [`crate::brdf::GGX_WIDENING_C`]; the widening rule's
/// `α'² = α² + c/κ` with the NDF's share `w = (c/κ)/α'²`, [`super::ndf_share`]) — by
/// [`crate::brdf::convolution::convolve_vmf`] on the lobe's polar quadrature nodes,
/// interpolated linearly in θ between them. `w = 0` is GGX(α') itself (the table before the
/// share axis), `w = 1` the vMF lobe alone (GGX of α' · 10⁻³). A widened GGX has GGX's long
/// tail whatever the NDF; eq 14 of a wide vMF and a sharp GGX keeps the vMF's short one.
/// Only the α' rows `rows(i)` are computed (the rest NaN: the test checks a subset).
pub(super) fn ggx_table(rows: &(dyn Fn(usize) -> bool + Sync)) -> Vec<f64> {
    let mut table = energy_table_of(
        &|a, w| ggx_convolved(a, w),
        ggx_param,
        |a| a.min(0.5 * PI),
        ENERGY_SHARES,
        true,
        // The widening rule equates an NDF variance v with `c·v` of α'²
        // (`brdf::GGX_WIDENING_C`), so α' stands for a per-axis variance α'²/c:
        // Blinn-Phong's `s = c/α'²`.
        Some(|a| crate::brdf::GGX_WIDENING_C / (a * a).max(1e-12)),
        rows,
    );
    exact_share_energy(&mut table, rows);
    table
}

/// The quadrature over half vectors ω_h about the lobe's axis z of a lobe `f(ω_h·z)`: polar
/// panels sized to the lobe ([`crate::harmonics::polar_quadrature`], rings where f vanishes
/// dropped) × `nphi` azimuths, each node carrying `f(cos θ) sin θ dθ dφ`. What
/// [`lobe_moments`] and [`normal_energy`] integrate over ω_i with (`dω_i = 4(ω_o·ω_h) dω_h`).
struct HalfVectors {
    /// Per ring: `sin θ`, `cos θ` and the node weight.
    rings: Vec<(f64, f64, f64)>,
    /// The azimuths' `(cos φ, sin φ)`, shared by every ring.
    azimuths: Vec<(f64, f64)>,
}

impl HalfVectors {
    fn new(f: &dyn Fn(f64) -> f64, width: f64, nphi: usize) -> HalfVectors {
        let azimuths = (0..nphi)
            .map(|j| {
                let phi = 2.0 * PI * (j as f64 + 0.5) / nphi as f64;
                (phi.cos(), phi.sin())
            })
            .collect();
        let rings = crate::harmonics::polar_quadrature(width)
            .into_iter()
            .filter_map(|(theta, w)| {
                let (st, ct) = theta.sin_cos();
                let fv = f(ct);
                (fv != 0.0).then_some((st, ct, w * st * fv * 2.0 * PI / nphi as f64))
            })
            .collect();
        HalfVectors { rings, azimuths }
    }

    /// `visit(ω_h, ω_o·ω_h, weight)` for every node with `ω_o·ω_h > 0`.
    fn each(&self, o: DVec3, visit: &mut dyn FnMut(DVec3, f64, f64)) {
        for &(st, ct, k) in &self.rings {
            for &(cp, sp) in &self.azimuths {
                let h = DVec3::new(st * cp, st * sp, ct);
                let oh = o.dot(h);
                if oh > 0.0 {
                    visit(h, oh, k);
                }
            }
        }
    }
}

/// Nodes of [`normal_energy`]'s grid over the angle between the normal and the view, `[0, π]`.
const NORMAL_ANGLES: usize = 129;
/// The vMF quadrature of [`ndf_energy`]: polar nodes (midpoints of the inverse CDF) and
/// azimuths.
const VMF_POLAR: usize = 64;
const VMF_AZIMUTHS: usize = 64;

/// `E(θ) = ∫ f(ω_h·n) max(ω_i·n, 0) dω_i` for a view at angle θ from the normal n, at
/// [`NORMAL_ANGLES`] angles evenly over `[0, π]` (θ > 90°: a normal facing away from the view
/// still reflects it where `ω_h·n > 0` and `ω_i·n > 0`, as the footprint ground truth counts
/// it), by quadrature over ω_h (`dω_i = 4(ω_o·ω_h) dω_h`, polar panels sized to the lobe × 64
/// azimuths).
fn normal_energy(f: &dyn Fn(f64) -> f64, width: f64) -> Vec<f64> {
    let nodes = HalfVectors::new(f, width, 64);
    (0..NORMAL_ANGLES)
        .map(|k| {
            let (so, co) = (PI * k as f64 / (NORMAL_ANGLES - 1) as f64).sin_cos();
            let mut sum = 0.0;
            nodes.each(DVec3::new(so, 0.0, co), &mut |h, oh, weight| {
                let cos_i = 2.0 * oh * h.z - co;
                if cos_i > 0.0 {
                    sum += weight * cos_i * 4.0 * oh;
                }
            });
            sum
        })
        .collect()
}

/// The energy of a vMF NDF lobe of concentration `kappa` under a BRDF lobe for a view at
/// `cos θ_o = co` from the lobe's mean, with the cosine at each normal:
/// `∫ vMF_κ(n) E(∠(n, ω_o)) dn`, `E` the BRDF lobe's [`normal_energy`] (interpolated linearly
/// in the angle). What a footprint of normals drawn from the vMF reflects of a constant
/// environment of unit radiance.
fn ndf_energy(energy: &[f64], kappa: f64, co: f64) -> f64 {
    let so = (1.0 - co * co).max(0.0).sqrt();
    let step = PI / (NORMAL_ANGLES - 1) as f64;
    let at = |c: f64| {
        let x = c.clamp(-1.0, 1.0).acos() / step;
        let i = (x.floor() as usize).min(NORMAL_ANGLES - 2);
        let t = x - i as f64;
        (1.0 - t) * energy[i] + t * energy[i + 1]
    };
    let mut sum = 0.0;
    for i in 0..VMF_POLAR {
        let cg = crate::vmf::cos_quantile((i as f64 + 0.5) / VMF_POLAR as f64, kappa);
        let sg = (1.0 - cg * cg).max(0.0).sqrt();
        for j in 0..VMF_AZIMUTHS {
            let psi = 2.0 * PI * (j as f64 + 0.5) / VMF_AZIMUTHS as f64;
            sum += at(sg * psi.cos() * so + cg * co);
        }
    }
    sum / (VMF_POLAR * VMF_AZIMUTHS) as f64
}

/// Rewrites block 6 of the GGX table's cells with a share `w > 0` so that the route's energy
/// `(1 − w)·E_0 + w·E_h` is the exact energy of the cell's NDF lobe under a constant
/// environment: [`ndf_energy`] of GGX α = α'·sqrt(1 − w) and κ = c/(w α'²) with the cosine at
/// every normal, `E_h = (E − (1 − w) E_0)/w`; the interpolation between two shares is then
/// exact at both. Block 6 was the half-vector cosine of [`lobe_moments`] (through
/// [`energy_table_of`]'s Blinn-Phong ratio), a second-order model of the same thing: under a
/// constant environment it was measured 3–13 % low for κ ≤ 64 at a 70° view
/// (`examples/env_lobe_probe.rs constant`). Only the rows `rows(i)` are rewritten.
fn exact_share_energy(table: &mut [f64], rows: &(dyn Fn(usize) -> bool + Sync)) {
    let n = ENERGY_PARAM * ENERGY_SHARES * ENERGY_COS;
    let cells: Vec<(usize, Vec<f64>)> = (0..ENERGY_PARAM * ENERGY_SHARES)
        .into_par_iter()
        .filter(|k| rows(k / ENERGY_SHARES) && k % ENERGY_SHARES > 0)
        .map(|k| {
            let (i, j) = (k / ENERGY_SHARES, k % ENERGY_SHARES);
            let w = j as f64 / (ENERGY_SHARES - 1) as f64;
            let (alpha, kappa) = ggx_cell(ggx_param(i), w);
            let energy = normal_energy(&|c| ggx(c, alpha), alpha.min(0.5 * PI));
            let e: Vec<f64> = (0..ENERGY_COS)
                .map(|c| {
                    let co = (c as f64 / (ENERGY_COS - 1) as f64).min(MOMENT_MIN_ANGLE.cos());
                    ndf_energy(&energy, kappa, co)
                })
                .collect();
            (k, e)
        })
        .collect();
    for (k, e) in cells {
        let w = (k % ENERGY_SHARES) as f64 / (ENERGY_SHARES - 1) as f64;
        for (c, e) in e.into_iter().enumerate() {
            let cell = k * ENERGY_COS + c;
            table[6 * n + cell] = (e - (1.0 - w) * table[cell]) / w;
        }
    }
}

/// The GGX roughness and the vMF concentration a GGX table cell `(α', w)` stands for (w > 0):
/// `α = α'·sqrt(1 − w)` (at least `10⁻³ α'`) and `κ = c/(w α'²)`, so that `α² + c/κ = α'²`
/// and the NDF's share of it is w ([`ggx_table`]).
fn ggx_cell(alpha_w: f64, w: f64) -> (f64, f64) {
    let a2 = alpha_w * alpha_w;
    let alpha = (a2 * (1.0 - w)).max(1e-6 * a2).sqrt();
    (alpha, crate::brdf::GGX_WIDENING_C / (w * a2))
}

/// The lobe `f(c)` of the GGX table's cell `(α', w)` ([`ggx_table`]).
fn ggx_convolved(alpha_w: f64, w: f64) -> Box<dyn Fn(f64) -> f64> {
    if w <= 0.0 {
        return Box::new(move |c| ggx(c, alpha_w));
    }
    let (alpha, kappa) = ggx_cell(alpha_w, w);
    let nodes: Vec<f64> = crate::harmonics::polar_quadrature(alpha_w.min(0.5 * PI))
        .iter()
        .map(|n| n.0)
        .collect();
    let d = |beta: f64| ggx(beta.cos(), alpha);
    let values: Vec<f64> = nodes
        .iter()
        .map(|&t| crate::brdf::convolution::convolve_vmf(&d, alpha.min(0.5 * PI), kappa, t))
        .collect();
    Box::new(move |c| crate::brdf::tabulated::interp(&nodes, &values, c.clamp(-1.0, 1.0).acos()))
}

/// The view angle the moments of a view at the normal are taken at (its limit: at exactly
/// 0 the reflected lobe has no plane to tilt in).
pub(super) const MOMENT_MIN_ANGLE: f64 = 1e-3;

/// Bins of the histogram of `x = 1 − cos γ` (γ the angle from the lobe's mean direction) the
/// two-vMF fit reads its quantiles from: log-spaced over `[MIX_X_MIN, 2]`.
const MIX_BINS: usize = 512;
/// The smallest `1 − cos γ` binned (γ ≈ 4.5·10⁻⁵ rad; below it everything is bin 0).
const MIX_X_MIN: f64 = 1e-9;
/// The quantiles of the lobe's angular distribution the two-vMF fit matches.
pub(super) const MIX_QUANTILES: [f64; 14] = [
    0.02, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.98,
];
/// The largest tail share the fit considers.
const MIX_TAIL_MAX: f64 = 0.9;

/// The weight of the squared log ratio of the mixture's density at its mean direction to the
/// lobe's in the two-vMF fit's measure (against the CDF errors at the quantiles): a sun in
/// the lobe's core sees that density.
const MIX_PEAK_WEIGHT: f64 = 100.0;

/// The density of a normalized vMF of concentration `kappa` at its mean direction,
/// `κ / (2π (1 − e^{−2κ}))` (`1/4π` as κ → 0).
pub(super) fn vmf_peak(kappa: f64) -> f64 {
    if kappa < 1e-9 {
        return 0.25 / PI;
    }
    kappa / (2.0 * PI * (-(-2.0 * kappa).exp_m1()))
}

/// `P(1 − cos γ ≤ x)` under a vMF of concentration `kappa` (γ from its mean):
/// `(1 − e^{−κx}) / (1 − e^{−2κ})`.
pub(super) fn vmf_cdf(kappa: f64, x: f64) -> f64 {
    if kappa < 1e-9 {
        return 0.5 * x;
    }
    (-(-kappa * x).exp_m1()) / (-(-2.0 * kappa).exp_m1())
}

/// The two-vMF split of a lobe (both about its mean direction) with total first moment `r`
/// (mean resultant length) whose angular distribution has `1 − cos γ` equal to `xq[j]` at the
/// quantiles [`MIX_QUANTILES`]: `(1 − t)·vMF(κ_c) + t·vMF(κ_t)` with
/// `(1 − t) A(κ_c) + t A(κ_t) = r` (the first moment stays the single vMF's; `A` is
/// [`crate::vmf::a_kappa`]) and `κ_t ≤ κ_c`, the `(t, κ_c)` minimizing the squared CDF error
/// at the quantiles plus [`MIX_PEAK_WEIGHT`] times the squared log ratio of the mixture's
/// density at the mean direction to the lobe's (`peak`, 0: not used) over a grid (t in steps of 0.02 up to [`MIX_TAIL_MAX`], κ_c from the single
/// vMF's κ in steps of 2^{1/8} up to 2^{12} times it). `t = 0` (the single vMF) is a candidate,
/// so the fit is never worse than it in this measure. Returns `(κ_c, t, κ_t)`.
pub(super) fn two_vmf_fit(r: f64, xq: &[f64; MIX_QUANTILES.len()], peak: f64) -> (f64, f64, f64) {
    let kappa1 = crate::vmf::kappa_from_r_exact(r);
    let err = |kc: f64, t: f64, kt: f64| -> f64 {
        let cdf: f64 = MIX_QUANTILES
            .iter()
            .zip(xq)
            .map(|(q, &x)| {
                let f = (1.0 - t) * vmf_cdf(kc, x) + t * vmf_cdf(kt, x);
                (f - q) * (f - q)
            })
            .sum();
        let p = (1.0 - t) * vmf_peak(kc) + t * vmf_peak(kt);
        let dp = if peak > 0.0 && p > 0.0 {
            (p / peak).ln()
        } else {
            0.0
        };
        cdf + MIX_PEAK_WEIGHT * dp * dp
    };
    let mut best = (err(kappa1, 0.0, kappa1), kappa1, 0.0, kappa1);
    if !kappa1.is_finite() {
        return (kappa1, 0.0, kappa1);
    }
    for i in 1..=(MIX_TAIL_MAX / 0.02).round() as usize {
        let t = 0.02 * i as f64;
        for k in 1..=96 {
            let kc = kappa1 * (k as f64 / 8.0).exp2();
            let at = (r - (1.0 - t) * crate::vmf::a_kappa(kc)) / t;
            // NaN or ≤ 0: κ_c alone carries the whole moment (and more as it grows).
            if at.is_nan() || at <= 0.0 {
                break;
            }
            let kt = crate::vmf::kappa_from_r_exact(at.min(1.0));
            if kt > kc {
                continue;
            }
            let e = err(kc, t, kt);
            if e < best.0 {
                best = (e, kc, t, kt);
            }
        }
    }
    (best.1, best.2, best.3)
}

/// The lobe's split-sum quantities for the view at `cos θ_o = co` in the xz plane, by
/// quadrature over ω_h (`dω_i = 4(ω_o·ω_h) dω_h`: polar panels sized to the lobe
/// ([`crate::harmonics::polar_quadrature`]) × 128 azimuths) of the weight
/// `w(ω_i) = f(ω_h·z) max(ω_i·z, 0)`:
/// 0. the energy `E = ∫ w dω_i`;
/// 1. the weight's mean direction `m = ∫ ω_i w / E` as a blend of the normal and the reflected
///    direction r: `m̂ = normalize(b z + (1 − b) r)` (the cosine and the horizon pull the lobe
///    towards the normal, by up to a third of r's angle at grazing views);
/// 2. `log2 κ_c`: with `two_vmf` false, the κ of the vMF whose mean resultant length is `|m|`
///    ([`crate::vmf::kappa_from_r_exact`]: the vMF matching the lobe's first moment, which
///    includes the `4(ω_o·ω_h)` Jacobian and the horizon; `s'/4` is its limit for a sharp lobe
///    seen head on); with `two_vmf` (GGX, whose long tail makes that single vMF much broader
///    than its core) the core's κ of [`two_vmf_fit`] over the weight's distribution of
///    `1 − m̂·ω_i`;
/// 3. the tail's share `t` of the energy (0 without `two_vmf`);
/// 4. `log2 κ_t`, the tail's κ (equal to block 2 when `t = 0`);
/// 5. the core's blend: the lobe's mode (its density's maximum in the plane of incidence) as
///    block 1 gives the mean; the core is looked up there, the tail about the mean (block 1
///    when `t = 0`). The fit's peak density is the lobe's at its mode;
/// 6. the energy with the cosine at the half vector, `E_h = ∫ f(ω_h·z) 4(ω_o·ω_h)² dω_h` over
///    `ω_o·ω_h > 0`: the limit of an NDF lobe much wider than the BRDF's, where the normal
///    that reflects ω_o into ω_i is ω_h itself, so the cosine `ω_i·n = ω_o·ω_h` varies across
///    the lobe (blocks 0 and 1 take it at the lobe's centre, `ω_i·z`, exact for a sharp NDF
///    lobe). The route mixes blocks 0 and 6 by the NDF's share `w` of the lobe's variance
///    ([`ndf_share`]): the normal given ω_h is then, to second order, `(1 − w) μ + w ω_h`
///    (the posterior of the vMF normal under the BRDF lobe about ω_h), and
///    `E = (1 − w) E_0 + w E_h` (the posterior's spread and its mean's normalization cancel
///    at second order);
///    (GGX's table replaces this block: at share 0 by a Gaussian-shaped lobe's ratio,
///    [`energy_table_of`]; at shares w > 0 by the value that makes the route's energy the NDF
///    lobe's exact one, [`exact_share_energy`]);
/// 7. the mean direction's blend (as block 1) under the weights of block 6;
/// 8. the shift `Δ = log2 κ_h − log2 κ` of the first-moment vMF's concentration under the
///    weights of block 6 (GGX's table: the Gaussian-shaped lobe's shift, as block 6); the
///    route adds `w·Δ` to `log2 κ_c` and `log2 κ_t`.
pub(super) fn lobe_moments(
    f: &dyn Fn(f64) -> f64,
    width: f64,
    co: f64,
    two_vmf: bool,
) -> [f64; ENERGY_BLOCKS] {
    let co = co.min(MOMENT_MIN_ANGLE.cos());
    let o = DVec3::new((1.0 - co * co).max(0.0).sqrt(), 0.0, co);
    let nodes = HalfVectors::new(f, width, 128);
    // One pass over the samples: `visit(l, weight, weight with the cosine at ω_h)` for every
    // incident direction.
    let each = |visit: &mut dyn FnMut(DVec3, f64, f64)| {
        nodes.each(o, &mut |h, oh, k| {
            let l = 2.0 * oh * h - o;
            let x = l.z.max(0.0) * 4.0 * oh;
            visit(l, k * x, k * 4.0 * oh * oh);
        });
    };
    let (mut sum, mut sum_h) = (0.0, 0.0);
    let (mut m, mut m_h) = (DVec3::ZERO, DVec3::ZERO);
    each(&mut |l, x, xh| {
        sum += x;
        m += x * l;
        sum_h += xh;
        m_h += xh * l;
    });
    if sum.is_nan() || sum <= 0.0 {
        return [0.0, 1.0, 60.0, 0.0, 60.0, 1.0, 0.0, 1.0, 0.0];
    }
    let mean = m / sum;
    let theta_o = co.clamp(-1.0, 1.0).acos();
    // The view is at +x, the reflected direction at −x; the mean lies between the normal and
    // it, at θ_m from the normal: the direction `∝ sin(θ_o − θ_m) z + sin(θ_m) r`, stored as
    // the blend weight of the normal (a normalize in the shader, no inverse trigonometry).
    let theta_m = (-mean.x).atan2(mean.z).clamp(0.0, theta_o);
    let blend_at = |theta_m: f64| {
        let (a, b) = ((theta_o - theta_m).sin(), theta_m.sin());
        if a + b > 0.0 { a / (a + b) } else { 0.0 }
    };
    let blend = blend_at(theta_m);
    let blend_h = if sum_h > 0.0 {
        blend_at((-m_h.x).atan2(m_h.z).clamp(0.0, theta_o))
    } else {
        blend
    };
    let r = mean.length().min(1.0);
    let kappa = crate::vmf::kappa_from_r_exact(r);
    let lk = |k: f64| k.max(1e-6).log2().min(60.0);
    let shift = if sum_h > 0.0 {
        lk(crate::vmf::kappa_from_r_exact(
            (m_h / sum_h).length().min(1.0),
        )) - lk(kappa)
    } else {
        0.0
    };
    if !two_vmf || !kappa.is_finite() {
        return [
            sum,
            blend,
            lk(kappa),
            0.0,
            lk(kappa),
            blend,
            sum_h,
            blend_h,
            shift,
        ];
    }
    // The lobe's mode in the plane of incidence, `l(θ) = (−sin θ, 0, cos θ)`, θ ∈ [0, θ_o]
    // (golden-section search of the density `f(ĥ·z) cos θ`): the core is looked up there.
    let density = |th: f64| {
        let l = DVec3::new(-th.sin(), 0.0, th.cos());
        let h = (o + l).try_normalize().unwrap_or(DVec3::Z);
        f(h.z) * l.z.max(0.0)
    };
    let (mut lo, mut hi) = (0.0, theta_o);
    let g = 0.5 * (5f64.sqrt() - 1.0);
    for _ in 0..80 {
        let (p, q) = (hi - g * (hi - lo), lo + g * (hi - lo));
        if density(p) < density(q) {
            lo = p;
        } else {
            hi = q;
        }
    }
    let theta_mode = 0.5 * (lo + hi);
    let blend_core = blend_at(theta_mode);
    // The distribution of x = 1 − m̂·ω_i (log-spaced bins), then its quantiles (log-linear
    // within a bin).
    let mhat = mean / mean.length();
    let span = (2.0 / MIX_X_MIN).ln();
    let mut hist = vec![0.0f64; MIX_BINS];
    each(&mut |l, x, _| {
        if x <= 0.0 {
            return;
        }
        let g = (1.0 - mhat.dot(l)).max(MIX_X_MIN);
        let i = ((g / MIX_X_MIN).ln() / span * MIX_BINS as f64) as usize;
        hist[i.min(MIX_BINS - 1)] += x;
    });
    let edge = |i: usize| MIX_X_MIN * (span * i as f64 / MIX_BINS as f64).exp();
    let mut xq = [0.0; MIX_QUANTILES.len()];
    let (mut acc, mut j) = (0.0, 0);
    for (i, h) in hist.iter().enumerate() {
        while j < xq.len() && acc + h >= MIX_QUANTILES[j] * sum {
            let f = if *h > 0.0 {
                ((MIX_QUANTILES[j] * sum - acc) / h).clamp(0.0, 1.0)
            } else {
                0.0
            };
            xq[j] = (edge(i).ln() + f * (edge(i + 1).ln() - edge(i).ln())).exp();
            j += 1;
        }
        acc += h;
    }
    for v in xq.iter_mut().skip(j) {
        *v = 2.0;
    }
    // The lobe's own density at m̂ (per unit solid angle of ω_i, normalized):
    // f(ĥ·z) max(m̂·z, 0) / E with ĥ the half vector of m̂ and the view.
    let peak = density(theta_mode) / sum;
    let (kc, t, kt) = two_vmf_fit(r, &xq, peak);
    [
        sum,
        blend,
        lk(kc),
        t,
        lk(kt),
        if t > 0.0 { blend_core } else { blend },
        sum_h,
        blend_h,
        shift,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The embedded tables are this module's quadrature (to 10⁻¹² relative: another libm may
    /// round the quadrature's transcendental functions differently); `NDFMAP_BLESS=1` rewrites
    /// them from it.
    #[test]
    fn embedded_tables_are_the_quadrature() {
        // GGX's eq 14 costs a numerical convolution per node: every seventh α' row (and the
        // last) is checked, all of them when blessing.
        let bless = std::env::var_os("NDFMAP_BLESS").is_some();
        let rows = |i: usize| bless || i.is_multiple_of(7) || i == ENERGY_PARAM - 1;
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("src/envlight");
        for (name, embedded, computed) in [
            (
                "blinn-phong",
                super::super::BLINN_PHONG_TABLE,
                blinn_phong_table(),
            ),
            ("ggx", super::super::GGX_TABLE, ggx_table(&rows)),
        ] {
            if std::env::var_os("NDFMAP_BLESS").is_some() {
                let bytes: Vec<u8> = computed.iter().flat_map(|v| v.to_le_bytes()).collect();
                std::fs::write(dir.join(format!("energy-{name}.f64le")), bytes).unwrap();
                continue;
            }
            let embedded = super::super::decode_table(embedded);
            assert_eq!(embedded.len(), computed.len(), "{name}");
            for (k, (e, c)) in embedded.iter().zip(&computed).enumerate() {
                if c.is_nan() {
                    continue;
                }
                assert!(
                    (e - c).abs() <= 1e-12 * c.abs().max(1e-300) || e == c,
                    "{name} entry {k}: embedded {e}, quadrature {c} (NDFMAP_BLESS=1 rewrites \
                     the table)"
                );
            }
        }
    }
}
