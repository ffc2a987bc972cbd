//! Several EM starts per texel, the best kept (issue 14: exact mode's way out of EM's local
//! optima). [`fit_restarts`] runs Algorithm 1 ([`super::fit`], its E and M steps unchanged)
//! from the given start, then from
//!
//! 1. for a small texel (at most [`SMALL_TEXEL`] usable normals: levels 2–3 of a
//!    power-of-two map), a start that seeds lobes on its most repeated normals: deterministic
//!    weighted k-means++ over the *distinct* normals, each weighted by how often it occurs,
//!    then one hard assignment (what a multi-start reference fit finds on 8-bit maps, which
//!    repeat normals exactly);
//! 2. split-and-merge moves (Ueda et al. 2000, "SMEM"), from the best fit so far: the lobe
//!    whose members scatter most (weight × tangent-plane variance) is split in two along its
//!    principal axis, and the slot this needs is freed either by dropping the lightest lobe or
//!    by merging the two closest lobes (eq 16's moments added). Up to
//!    [`SPLIT_MERGE_ROUNDS`] rounds, each tried from the best so far; a round that improves
//!    nothing ends the search.
//!
//! Every candidate is a full [`super::fit`] run; the fit with the highest mean
//! log-likelihood (eq 15, as the E-step computes it) wins, the first one on ties, so the
//! result is deterministic and does not depend on the thread count. Eq 22's features are
//! those of the winning fit's final lobes.

use super::{DUPLICATE_COS_EPS, EmFit, EmInput, EmOptions, EmScratch, KAPPA_INIT_MAX, fit};
use crate::vmf::{self, KAPPA_MAX, Lobe, is_positive, kappa_from_r, normalize_robust};
use glam::DVec3;

/// Largest texel (usable normals) that gets the repeated-normals start.
pub const SMALL_TEXEL: usize = 64;

/// Most rounds of split-and-merge moves per texel (each round tries two moves).
pub const SPLIT_MERGE_ROUNDS: usize = 2;

/// A candidate wins only when its mean log-likelihood exceeds the best so far by more than
/// this (nats per normal), so rounding-level differences between equivalent optima do not
/// switch fits.
const MIN_GAIN: f64 = 1e-9;

/// Fits one texel (no alignment) from `init` and from the further starts of the module docs,
/// returning the fit of highest mean log-likelihood. `scratch` as for [`fit`].
///
/// # Panics
/// As [`fit`].
pub fn fit_restarts(
    input: &EmInput,
    init: &[crate::vmf::Lobe],
    options: &EmOptions,
    scratch: &mut EmScratch,
) -> EmFit {
    let mut best = fit(input, init, options, None, scratch);
    let j = init.len();
    if j < 2 || !is_positive(best.total_weight) || input.cancelled() {
        return best;
    }
    let (normals, weights) = usable(input);
    if normals.len() <= j {
        return best;
    }
    let mut consider = |start: &[Lobe], best: &mut EmFit| -> bool {
        let f = fit(input, start, options, None, scratch);
        let better = f.log_likelihood > best.log_likelihood + MIN_GAIN;
        if better {
            *best = f;
        }
        better
    };
    if normals.len() <= SMALL_TEXEL
        && let Some(start) = repeated_normals_start(&normals, &weights, j)
    {
        consider(&start, &mut best);
    }
    for _ in 0..SPLIT_MERGE_ROUNDS {
        if input.cancelled() {
            break;
        }
        let moves = split_merge_starts(&normals, &weights, best.lobes());
        let mut improved = false;
        for start in moves.iter().flatten() {
            improved |= consider(start, &mut best);
        }
        if !improved {
            break;
        }
    }
    best
}

/// The usable samples of `input` as unit `f64` normals and weights (weight 1 without
/// weights; zero, negative or non-finite weights and zero normals dropped).
fn usable(input: &EmInput) -> (Vec<DVec3>, Vec<f64>) {
    let mut normals = Vec::with_capacity(input.normals.len());
    let mut weights = Vec::with_capacity(input.normals.len());
    for (i, n) in input.normals.iter().enumerate() {
        let w = input.weights.map_or(1.0, |w| w[i]);
        if !(is_positive(w) && w.is_finite()) {
            continue;
        }
        if let Some(d) = normalize_robust(n.as_dvec3()) {
            normals.push(d);
            weights.push(w);
        }
    }
    (normals, weights)
}

/// Lobes from one hard assignment of every normal to its nearest seed (ties: the lower seed):
/// per cluster the weight fraction, the mean direction and Banerjee's κ of its mean resultant
/// length (up to [`KAPPA_MAX`]: a cluster of identical normals starts as the spike it is).
/// Slots beyond `seeds` are empty copies of the first lobe.
fn hard_start(normals: &[DVec3], weights: &[f64], seeds: &[DVec3], j: usize) -> Vec<Lobe> {
    let k = seeds.len();
    let mut sum_w = vec![0.0; k];
    let mut sum_n = vec![DVec3::ZERO; k];
    for (n, &w) in normals.iter().zip(weights) {
        let mut best = 0;
        for s in 1..k {
            if n.dot(seeds[s]) > n.dot(seeds[best]) {
                best = s;
            }
        }
        sum_w[best] += w;
        sum_n[best] += w * *n;
    }
    let total: f64 = sum_w.iter().sum();
    let mut lobes: Vec<Lobe> = (0..k)
        .map(|s| {
            if !is_positive(sum_w[s]) {
                return Lobe::new(0.0, seeds[s], 1.0);
            }
            let r = sum_n[s] / sum_w[s];
            Lobe::new(
                sum_w[s] / total,
                normalize_robust(r).unwrap_or(seeds[s]),
                kappa_from_r(r.length()).min(KAPPA_MAX),
            )
        })
        .collect();
    let first = lobes[0];
    lobes.resize(
        j,
        Lobe {
            alpha: 0.0,
            ..first
        },
    );
    lobes
}

/// The repeated-normals start (module docs, 1): the distinct normals, each weighted by the
/// total weight of its copies; the heaviest first, then each next the one with the largest
/// `w · (1 − cos)` to its nearest pick (ties: the lower index); then a hard assignment. `None`
/// when there are no normals.
fn repeated_normals_start(normals: &[DVec3], weights: &[f64], j: usize) -> Option<Vec<Lobe>> {
    let mut distinct: Vec<(DVec3, f64)> = Vec::with_capacity(normals.len());
    for (n, &w) in normals.iter().zip(weights) {
        match distinct
            .iter_mut()
            .find(|(d, _)| d.dot(*n) >= 1.0 - DUPLICATE_COS_EPS)
        {
            Some((_, dw)) => *dw += w,
            None => distinct.push((*n, w)),
        }
    }
    let first =
        (0..distinct.len()).reduce(|a, b| if distinct[b].1 > distinct[a].1 { b } else { a })?;
    let mut seeds = vec![distinct[first].0];
    let mut closeness: Vec<f64> = distinct.iter().map(|(d, _)| d.dot(seeds[0])).collect();
    while seeds.len() < j {
        let mut next: Option<(usize, f64)> = None;
        for (c, (_, w)) in distinct.iter().enumerate() {
            let score = w * (1.0 - closeness[c]).max(0.0);
            if score > 0.0 && next.is_none_or(|(_, s)| score > s) {
                next = Some((c, score));
            }
        }
        let Some((c, _)) = next else { break };
        let seed = distinct[c].0;
        seeds.push(seed);
        for (cl, (d, _)) in closeness.iter_mut().zip(&distinct) {
            *cl = cl.max(d.dot(seed));
        }
    }
    Some(hard_start(normals, weights, &seeds, j))
}

/// The members' statistics of one lobe under a hard assignment: weight, and the first and
/// second moments of their tangent-plane coordinates in the basis `(t1, t2)` of the lobe's μ.
#[derive(Clone, Copy, Default)]
struct Members {
    w: f64,
    u: f64,
    v: f64,
    uu: f64,
    uv: f64,
    vv: f64,
}

/// The two split-and-merge starts from `lobes` (module docs, 2): `[drop the lightest lobe,
/// merge the closest pair]`, each splitting the most scattered lobe; `None` where a move does
/// not exist (fewer than two live lobes, no lobe with spread, or no pair to merge).
fn split_merge_starts(
    normals: &[DVec3],
    weights: &[f64],
    lobes: &[Lobe],
) -> [Option<Vec<Lobe>>; 2] {
    let j = lobes.len();
    let live: Vec<usize> = (0..j).filter(|&s| is_positive(lobes[s].alpha)).collect();
    if live.is_empty() || j < 2 {
        return [None, None];
    }
    // Hard membership by the E-step's score ln α + ln γ (ties: the lower slot).
    let score_k: Vec<f64> = live
        .iter()
        .map(|&s| lobes[s].alpha.ln() + vmf::log_peak_density(lobes[s].kappa))
        .collect();
    let bases: Vec<(DVec3, DVec3)> = live
        .iter()
        .map(|&s| crate::brdf::tangent_frame(lobes[s].mu))
        .collect();
    let mut members = vec![Members::default(); live.len()];
    for (n, &w) in normals.iter().zip(weights) {
        let mut best = 0;
        let mut best_score = f64::NEG_INFINITY;
        for (k, &s) in live.iter().enumerate() {
            let score = score_k[k] + lobes[s].kappa * (n.dot(lobes[s].mu) - 1.0);
            if score > best_score {
                (best, best_score) = (k, score);
            }
        }
        let (t1, t2) = bases[best];
        let (u, v) = (n.dot(t1), n.dot(t2));
        let m = &mut members[best];
        m.w += w;
        m.u += w * u;
        m.v += w * v;
        m.uu += w * u * u;
        m.uv += w * u * v;
        m.vv += w * v * v;
    }
    // The split: the live lobe of largest weight × tangent variance (ties: the lower slot).
    let mut split: Option<(usize, f64, f64, f64, DVec3)> = None; // (k, spread, λ1, λ2, axis)
    for (k, m) in members.iter().enumerate() {
        if !is_positive(m.w) {
            continue;
        }
        let (mu, mv) = (m.u / m.w, m.v / m.w);
        let cuu = (m.uu / m.w - mu * mu).max(0.0);
        let cvv = (m.vv / m.w - mv * mv).max(0.0);
        let cuv = m.uv / m.w - mu * mv;
        let half_trace = 0.5 * (cuu + cvv);
        let disc = (0.25 * (cuu - cvv) * (cuu - cvv) + cuv * cuv).sqrt();
        let (l1, l2) = (half_trace + disc, (half_trace - disc).max(0.0));
        let spread = m.w * (cuu + cvv);
        // Principal axis of [[cuu, cuv], [cuv, cvv]] for λ1.
        let (a, b) = if cuv.abs() > 0.0 {
            (l1 - cvv, cuv)
        } else if cuu >= cvv {
            (1.0, 0.0)
        } else {
            (0.0, 1.0)
        };
        let (t1, t2) = bases[k];
        let Some(axis) = normalize_robust(t1 * a + t2 * b) else {
            continue;
        };
        if l1 > 1e-12 && split.is_none_or(|(_, s, ..)| spread > s) {
            split = Some((k, spread, l1, l2, axis));
        }
    }
    let Some((k, _, l1, l2, axis)) = split else {
        return [None, None];
    };
    let s = live[k];
    let m = members[k];
    let centre =
        normalize_robust(lobes[s].mu + bases[k].0 * (m.u / m.w) + bases[k].1 * (m.v / m.w))
            .unwrap_or(lobes[s].mu);
    let offset = l1.sqrt();
    let halves = [
        normalize_robust(centre + axis * offset).unwrap_or(centre),
        normalize_robust(centre - axis * offset).unwrap_or(centre),
    ];
    // Each half's spread across the axis is λ2 (a vMF's variance per tangent axis ≈ 1/κ).
    let kappa = (1.0 / l2.max(1.0 / KAPPA_INIT_MAX)).clamp(1.0, KAPPA_INIT_MAX);
    let split_into = |start: &mut Vec<Lobe>, other: usize, alpha: f64| {
        start[s] = Lobe::new(alpha / 2.0, halves[0], kappa);
        start[other] = Lobe::new(alpha / 2.0, halves[1], kappa);
    };
    // Drop the lightest other lobe (ties: the lower slot).
    let drop = (0..j).filter(|&o| o != s).reduce(|a, b| {
        if lobes[b].alpha < lobes[a].alpha {
            b
        } else {
            a
        }
    });
    let dropped = drop.map(|o| {
        let mut start = lobes.to_vec();
        split_into(&mut start, o, lobes[s].alpha + lobes[o].alpha);
        start
    });
    // Merge the closest live pair other than the split lobe (ties: the first pair).
    let mut pair: Option<(usize, usize, f64)> = None;
    for (x, &a) in live.iter().enumerate() {
        for &b in &live[x + 1..] {
            if a == s || b == s {
                continue;
            }
            let c = lobes[a].mu.dot(lobes[b].mu);
            if pair.is_none_or(|(_, _, pc)| c > pc) {
                pair = Some((a, b, c));
            }
        }
    }
    let merged = pair.map(|(a, b, _)| {
        let mut start = lobes.to_vec();
        let alpha = lobes[a].alpha + lobes[b].alpha;
        let r = (lobes[a].mu * (lobes[a].alpha * vmf::a_kappa(lobes[a].kappa))
            + lobes[b].mu * (lobes[b].alpha * vmf::a_kappa(lobes[b].kappa)))
            / alpha;
        start[a] = Lobe::new(
            alpha,
            normalize_robust(r).unwrap_or(lobes[a].mu),
            kappa_from_r(r.length()).min(KAPPA_INIT_MAX),
        );
        split_into(&mut start, b, lobes[s].alpha);
        start
    });
    [dropped, merged]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quality::{mean_log_likelihood, reference_fit};
    use crate::rng::Rng;
    use glam::Vec3;

    /// `count` normals scattered about `centre` (tangent offsets of standard deviation
    /// `spread` radians).
    fn cluster(rng: &mut Rng, centre: DVec3, spread: f64, count: usize) -> Vec<Vec3> {
        let (t1, t2) = crate::brdf::tangent_frame(centre.normalize());
        (0..count)
            .map(|_| {
                let n = centre.normalize()
                    + t1 * (spread * rng.normal())
                    + t2 * (spread * rng.normal());
                n.normalize().as_vec3()
            })
            .collect()
    }

    fn dir(theta_deg: f64, phi_deg: f64) -> DVec3 {
        let (t, p) = (theta_deg.to_radians(), phi_deg.to_radians());
        DVec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos())
    }

    /// Three clusters, J = 3, started in the classic local optimum: two lobes sharing cluster
    /// A, one broad lobe over B and C. Plain EM stays there; the merge-and-split move finds
    /// the three clusters, as a best-of-8 multi-start reference fit does.
    #[test]
    fn split_and_merge_leaves_a_local_optimum_plain_em_keeps() {
        let mut rng = Rng(14);
        let (a, b, c) = (dir(0.0, 0.0), dir(35.0, 0.0), dir(35.0, 90.0));
        let mut normals = cluster(&mut rng, a, 0.03, 60);
        normals.extend(cluster(&mut rng, b, 0.03, 60));
        normals.extend(cluster(&mut rng, c, 0.03, 60));
        let weights = vec![1.0; normals.len()];
        let init = [
            Lobe::new(0.3, dir(0.5, 0.0), 1000.0),
            Lobe::new(0.3, dir(0.5, 180.0), 1000.0),
            Lobe::new(0.4, (b + c).normalize(), 10.0),
        ];
        let input = EmInput::new(&normals).with_weights(&weights);
        let options = EmOptions::default();
        let mut scratch = EmScratch::new();
        let plain = fit(&input, &init, &options, None, &mut scratch);
        let restarted = fit_restarts(&input, &init, &options, &mut scratch);
        let (_, reference) = reference_fit(&normals, &weights, 3, 8, 2007);
        let score = |f: &EmFit| mean_log_likelihood(&normals, &weights, f.lobes());
        let (p, r) = (score(&plain), score(&restarted));
        assert!(p < reference - 0.1, "plain {p} reference {reference}");
        assert!(r > reference - 1e-3, "restarts {r} reference {reference}");
        // Every lobe explains one cluster.
        for centre in [a, b, c] {
            assert!(
                restarted
                    .lobes()
                    .iter()
                    .any(|l| l.mu.dot(centre) > 0.999 && (l.alpha - 1.0 / 3.0).abs() < 0.02),
                "{:?}",
                restarted.lobes()
            );
        }
    }

    /// A 16-normal texel of an 8-bit map: two normals repeated 6 and 5 times, five others
    /// spread. The repeated-normals start finds the spikes a multi-start reference finds,
    /// where the children's start (one broad lobe over them) does not.
    #[test]
    fn small_texels_seed_lobes_on_repeated_normals() {
        let mut rng = Rng(7);
        let (n0, n1) = (dir(10.0, 20.0).as_vec3(), dir(14.0, 80.0).as_vec3());
        let mut normals = vec![n0; 6];
        normals.extend(vec![n1; 5]);
        normals.extend(cluster(&mut rng, dir(12.0, 50.0), 0.15, 5));
        let weights = vec![1.0; normals.len()];
        let init = [
            Lobe::new(0.8, dir(12.0, 50.0), 50.0),
            Lobe::new(0.1, normals[11].as_dvec3(), 2048.0),
            Lobe::new(0.1, normals[12].as_dvec3(), 2048.0),
        ];
        let input = EmInput::new(&normals).with_weights(&weights);
        let options = EmOptions::default();
        let mut scratch = EmScratch::new();
        let plain = fit(&input, &init, &options, None, &mut scratch);
        let restarted = fit_restarts(&input, &init, &options, &mut scratch);
        let (_, reference) = reference_fit(&normals, &weights, 3, 8, 2007);
        let score = |f: &EmFit| mean_log_likelihood(&normals, &weights, f.lobes());
        let (p, r) = (score(&plain), score(&restarted));
        assert!(p < reference - 0.5, "plain {p} reference {reference}");
        assert!(r > reference - 0.05, "restarts {r} reference {reference}");
        // Same result for the same input (deterministic).
        let again = fit_restarts(&input, &init, &options, &mut scratch);
        assert_eq!(again, restarted);
    }
}
