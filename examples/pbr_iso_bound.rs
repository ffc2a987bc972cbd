//! How far a PBR isotropic search is from the best isotropic lobe of its own pair set, and what
//! that better optimum scores on the evaluation's pairs (issue 17; numbers in docs/pbr.md,
//! "The isotropic bound, by brute force"):
//! `cargo run --release --example pbr_iso_bound -- MAP ALPHA [eval|standard] [TEXELS]`.
//!
//! - `eval`: the report's "best isotropic found" row (the thorough search fitted on the
//!   evaluation's own 27 pairs, [`Search::Thorough`]);
//! - `standard`: the bake's own fit ([`Search::Fast`] on [`FitSet::standard`]'s 56 pairs).
//!
//! Per level 2–5, on about `TEXELS` texels (default 1000, every k-th in row-major order), each
//! texel's lobe is searched again by brute force on the same pairs: every normal on rings of
//! 1.25° out to 50° from the zenith (8 per degree-step ring) at 31 roughnesses from the base α
//! to 1 (log-spaced), the best grid point (and the search's own lobe) refined by 60
//! Levenberg–Marquardt steps ([`fit_isotropic`], the base α as the floor). Printed per level:
//! the summed cost on the fitting pairs (search, brute force) and the relative RMS error of
//! `D·max(n·l, 0)` on the evaluation's pairs over the sampled texels (search, brute force), as
//! `eval`/`pbr-report` define it. A search at its set's optimum has equal costs; a brute-force
//! lobe that lowers the fitting cost but raises the evaluation's error overfits its pairs.

use glam::DVec3;
use ndfmap::bake::PbrOptions;
use ndfmap::brdf::{ggx, half_vector};
use ndfmap::eval::default_directions;
use ndfmap::pbr::{FitSet, IsoLobe, Search, bake_with_set, fit_isotropic, targets};
use ndfmap::pyramid::pyramid;
use ndfmap::{IngestOptions, NormalMap};
use rayon::prelude::*;

/// `Σ_p (D_α(n·h_p) max(n·l_p, 0) − g_p)²` over `pairs` (light, half vector).
fn cost(pairs: &[(DVec3, DVec3)], n: DVec3, alpha: f64, target: &[f64]) -> f64 {
    pairs
        .iter()
        .zip(target)
        .map(|(&(l, h), &g)| {
            let f = ggx(n.dot(h), alpha) * n.dot(l).max(0.0);
            (f - g) * (f - g)
        })
        .sum()
}

/// The best point of the brute-force grid (module docs) for `target` on `pairs`.
fn grid_best(pairs: &[(DVec3, DVec3)], base: f64, target: &[f64]) -> IsoLobe {
    let mut best = (
        f64::INFINITY,
        IsoLobe {
            n: DVec3::Z,
            alpha: base,
        },
    );
    for ring in 0..=40usize {
        let theta = (ring as f64 * 1.25).to_radians();
        let around = if ring == 0 { 1 } else { ring * 8 };
        for k in 0..around {
            let phi = k as f64 / around as f64 * std::f64::consts::TAU;
            let n = DVec3::new(
                theta.sin() * phi.cos(),
                theta.sin() * phi.sin(),
                theta.cos(),
            );
            for step in 0..=30 {
                let alpha = (base.ln() * (1.0 - step as f64 / 30.0)).exp();
                let c = cost(pairs, n, alpha, target);
                if c < best.0 {
                    best = (c, IsoLobe { n, alpha });
                }
            }
        }
    }
    best.1
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let usage = "usage: pbr_iso_bound MAP ALPHA [eval|standard] [TEXELS]";
    let path = args.get(1).expect(usage);
    let alpha: f64 = args.get(2).expect(usage).parse().expect("ALPHA");
    let standard = match args.get(3).map_or("eval", String::as_str) {
        "eval" => false,
        "standard" => true,
        other => panic!("{other}: {usage}"),
    };
    let texels: usize = args.get(4).map_or(1000, |t| t.parse().expect("TEXELS"));
    let map = NormalMap::load(std::path::Path::new(path), &IngestOptions::default())
        .expect("a readable normal map");
    let evaluation = default_directions();
    let (set, search) = if standard {
        (FitSet::standard(), Search::Fast)
    } else {
        (
            FitSet::unweighted(&evaluation),
            Search::Thorough { from_level: 2 },
        )
    };
    let options = PbrOptions {
        roughness: alpha.sqrt(),
        ..PbrOptions::default()
    };
    let (bake, _) = bake_with_set(&map, &options, None, &set, search, 2).expect("the bake");
    let levels = pyramid(map.width(), map.height());
    let alphas = vec![alpha; map.normals().len()];
    let fit_targets = targets(&map, &alphas, &set.pairs, &levels);
    let eval_targets = targets(&map, &alphas, &evaluation, &levels);
    let with_halves = |pairs: &[(DVec3, DVec3)]| -> Vec<(DVec3, DVec3)> {
        pairs.iter().map(|&(l, v)| (l, half_vector(l, v))).collect()
    };
    let (fit_pairs, eval_pairs) = (with_halves(&set.pairs), with_halves(&evaluation));
    let (pf, pe) = (fit_pairs.len(), eval_pairs.len());
    println!(
        "{path}, α = {alpha}, {} search on {} pairs:",
        if standard {
            "the bake's fast"
        } else {
            "the report's thorough"
        },
        pf
    );
    println!(
        "| level | texels | fit cost, search | fit cost, brute force | eval error, search | eval error, brute force |"
    );
    println!("|---:|---:|---:|---:|---:|---:|");
    for k in 2..=5usize.min(bake.sizes.len() - 1) {
        let (w, h) = bake.sizes[k];
        let count = w as usize * h as usize;
        let picked: Vec<usize> = (0..count).step_by((count / texels).max(1)).collect();
        // Per texel: fit cost (search, brute), eval squared error (search, brute), eval ΣG².
        let rows: Vec<[f64; 5]> = picked
            .par_iter()
            .map(|&i| {
                let gf = &fit_targets[k][i * pf..(i + 1) * pf];
                let ge = &eval_targets[k][i * pe..(i + 1) * pe];
                let t = bake.textures[0].levels[k][i];
                let n = DVec3::new(t[0] as f64, t[1] as f64, t[2] as f64).normalize();
                let r = bake.textures[1].levels[k][i][1] as f64;
                let found = IsoLobe {
                    n,
                    alpha: (r * r).max(ndfmap::pbr::MIN_ALPHA),
                };
                let grid = grid_best(&fit_pairs, alpha, gf);
                let (brute, brute_cost) = fit_isotropic(&set, gf, &[grid, found], 60, alpha);
                [
                    cost(&fit_pairs, found.n, found.alpha, gf),
                    brute_cost,
                    cost(&eval_pairs, found.n, found.alpha, ge),
                    cost(&eval_pairs, brute.n, brute.alpha, ge),
                    ge.iter().map(|g| g * g).sum(),
                ]
            })
            .collect();
        let sum = |j: usize| rows.iter().map(|r| r[j]).sum::<f64>();
        println!(
            "| {k} | {} | {:.4e} | {:.4e} | {:.4} | {:.4} |",
            rows.len(),
            sum(0),
            sum(1),
            (sum(2) / sum(4)).sqrt(),
            (sum(3) / sum(4)).sqrt()
        );
    }
}
