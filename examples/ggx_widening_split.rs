//! Where the vMF → GGX route loses on a map (issue 17, task H17v): bakes vMF J = 6 (aligned,
//! C = 1, balanced, f32) as `ndfmap pbr-report` does, and measures the texel-space error of the
//! specular term `D·max(n·l, 0)` (no g factor) over `eval`'s 27 light/view pairs at levels 2–7
//! for several widening rules of the same lobes, split by the kind of texel:
//! `cargo run --release --example ggx_widening_split -- MAP [ALPHAS]`.
//!
//! Rules: `c = 1, 2, 3, 4` (`α'² = α² + c/κ`; c = 2 was the default before H17t), `conv` (the opt-in
//! peak-matched rule, [`ndfmap::brdf::Ggx::widened_vmf`] at c = 2), `exact` (each lobe shaded
//! with eq 14 of the GGX lobe by quadrature, [`ndfmap::brdf::convolution::convolve_vmf`],
//! tabulated finely in κ and θ and interpolated: the bound on what any rule for these lobes
//! gives), `table` (GGX given as a tabulated BRDF, 1024 samples: the shaders' existing
//! eq 14 table, [`ndfmap::brdf::tabulated::lookup`], what `--brdf FILE` gives) and `mixture`
//! (GGX as a fitted mixture of vMF lobes, each convolved in closed form:
//! [`ndfmap::brdf::ggx_mixture::GgxMixture::convolved`], uncorrected), `mix+c2` (the default
//! rule since H17t, [`ndfmap::brdf::ggx_mixture::GgxMixture::corrected`] with `α_w` from
//! c = 2) and `mix+peak` (the same with the peak rule's `α_w`). `NDF_MIX_SCALES`, `NDF_MIX_REL`
//! and `NDF_MIX_T0` try other mixture constants (the measurements that chose them).
//!
//! Texel kinds: by the lobe-weighted mean of `t = (1/κ)/α²` (how wide the NDF lobes are against
//! the BRDF lobe), and whether the footprint holds one finest normal only (repeated 8-bit
//! normals). The exact answers are box averages over the power-of-two footprints, so the map
//! must have power-of-two sides (the shared maps do).

use glam::DVec3;
use ndfmap::bake::{BakeOptions, Method};
use ndfmap::brdf::convolution::convolve_vmf;
use ndfmap::brdf::tabulated::lookup;
use ndfmap::brdf::{Tabulated, ggx, half_vector};
use ndfmap::eval::default_directions;
use ndfmap::methods::bake_with;
use ndfmap::shade::vmf_decode;
use ndfmap::{IngestOptions, NormalMap};
use rayon::prelude::*;
use std::f64::consts::PI;

/// eq 14 of GGX α under vMF lobes, tabulated on `log κ` × `x = sqrt(θ/(π/2))`.
struct ExactTable {
    alpha: f64,
    logk: Vec<f64>,
    nx: usize,
    values: Vec<f64>,
}

impl ExactTable {
    fn new(alpha: f64) -> ExactTable {
        let logk: Vec<f64> = (0..=64)
            .map(|i| i as f64 * 7.0 / 64.0 * 10f64.ln())
            .collect();
        let nx = 801;
        let d = |b: f64| ggx(b.cos(), alpha);
        let values: Vec<f64> = logk
            .par_iter()
            .flat_map_iter(|&lk| {
                let kappa = lk.exp();
                (0..nx).map(move |i| {
                    let x = i as f64 / (nx - 1) as f64;
                    convolve_vmf(&d, alpha, kappa, 0.5 * PI * x * x)
                })
            })
            .collect();
        ExactTable {
            alpha,
            logk,
            nx,
            values,
        }
    }

    fn lobe(&self, c: f64, var: f64) -> f64 {
        let theta = c.clamp(-1.0, 1.0).acos();
        if theta >= 0.5 * PI {
            return 0.0;
        }
        let kappa = 1.0 / var;
        let last = *self.logk.last().unwrap();
        if kappa.ln() >= last {
            return ggx(c, self.alpha);
        }
        let lk = kappa.ln().max(0.0);
        let step = self.logk[1];
        let fi = (lk / step).min(self.logk.len() as f64 - 1.000001);
        let i = fi as usize;
        let wi = fi - i as f64;
        let fx = (theta / (0.5 * PI)).sqrt() * (self.nx - 1) as f64;
        let j = (fx as usize).min(self.nx - 2);
        let wj = fx - j as f64;
        let at = |i: usize, j: usize| self.values[i * self.nx + j];
        let a = at(i, j) * (1.0 - wj) + at(i, j + 1) * wj;
        let b = at(i + 1, j) * (1.0 - wj) + at(i + 1, j + 1) * wj;
        a * (1.0 - wi) + b * wi
    }
}

/// One row's sums: per rule Σ(F − G)², ΣG², and per texel kind the same and the texel count.
type RowSums = (
    [f64; RULES.len()],
    f64,
    [[f64; RULES.len()]; KINDS.len()],
    [f64; KINDS.len()],
    [usize; KINDS.len()],
);

const RULES: [&str; 10] = [
    "c=1", "c=2", "c=3", "c=4", "conv", "exact", "table", "mixture", "mix+c2", "mix+peak",
];
const KINDS: [&str; 6] = ["t<0.01", "0.01-0.1", "0.1-1", "1-10", "t>10", "one normal"];

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let path = args.get(1).expect("usage: ggx_widening_split MAP [ALPHAS]");
    let alphas: Vec<f64> = args.get(2).map_or(vec![0.05, 0.1, 0.3], |a| {
        a.split(',').map(|v| v.parse().expect("alpha")).collect()
    });
    let map = NormalMap::load(std::path::Path::new(path), &IngestOptions::default()).unwrap();
    let (w, h) = (map.width() as usize, map.height() as usize);
    assert!(w.is_power_of_two() && h.is_power_of_two());
    let t0 = std::time::Instant::now();
    let bake = bake_with(
        &map,
        Method::Vmf,
        &BakeOptions {
            lobes: 6,
            align: Some(1.0),
            ..BakeOptions::default()
        },
    )
    .unwrap();
    eprintln!("baked in {:.1} s", t0.elapsed().as_secs_f64());
    let r_max = ndfmap::vmf::r_max(bake.format);
    let a_min = ndfmap::vmf::alpha_min(bake.format);
    let normals: Vec<DVec3> = map.normals().iter().map(|n| n.as_dvec3()).collect();
    let dirs = default_directions();
    let levels: Vec<usize> = (2..=7).collect();
    for &alpha in &alphas {
        let table = ExactTable::new(alpha);
        let tab = Tabulated::sample("ggx", 1024, &|t: f64| ggx(t.cos(), alpha), None).unwrap();
        // NDF_MIX_SCALES="s1,s2,…" and NDF_MIX_REL=r try other mixtures (the measurements
        // that chose the constants); by default the library's.
        let mixture = match std::env::var("NDF_MIX_SCALES") {
            Ok(v) => {
                let scales: Vec<f64> = v.split(',').map(|x| x.parse().expect("scale")).collect();
                let rel = std::env::var("NDF_MIX_REL").map_or(0.0, |r| r.parse().expect("rel"));
                ndfmap::brdf::ggx_mixture::fit_scales(alpha, &scales, rel)
            }
            Err(_) => {
                let m = ndfmap::brdf::ggx_mixture::GgxMixture::fit(alpha);
                (m.weights.to_vec(), m.etas.to_vec())
            }
        };
        let fitted = ndfmap::brdf::ggx_mixture::GgxMixture::fit(alpha);
        let rule = |r: usize, c: f64, var: f64| -> f64 {
            match r {
                0..=3 => ggx(c, (alpha * alpha + (r + 1) as f64 * var).sqrt().min(1.0)),
                4 => ggx(c, ndfmap::brdf::Ggx::new(alpha).widened_vmf(var)),
                5 => table.lobe(c, var),
                7 => {
                    let kappa = if var > 0.0 { 1.0 / var } else { f64::INFINITY };
                    mixture
                        .0
                        .iter()
                        .zip(&mixture.1)
                        .map(|(w, e)| w * ndfmap::brdf::ggx_mixture::vmf_product(c, kappa, *e))
                        .sum()
                }
                8 | 9 => {
                    let g = ndfmap::brdf::Ggx::new(alpha);
                    let aw = if r == 8 {
                        g.widened(var)
                    } else {
                        g.widened_vmf(var)
                    };
                    let kappa = if var > 0.0 { 1.0 / var } else { f64::INFINITY };
                    let t0: f64 = std::env::var("NDF_MIX_T0")
                        .map_or(ndfmap::brdf::ggx_mixture::GGX_MIXTURE_T0, |v| {
                            v.parse().expect("t0")
                        });
                    let t = var / (alpha * alpha);
                    fitted.corrected(aw, c, kappa, 1.0 / (1.0 + (t / t0) * (t / t0)))
                }
                _ => {
                    let kappa = if var > 0.0 { 1.0 / var } else { f64::INFINITY };
                    lookup(tab.table(), c.clamp(-1.0, 1.0).acos(), kappa)
                }
            }
        };
        // per level: [rule] err², G², and per kind the same plus texel counts
        println!("\n## {path} α = {alpha}");
        let mut pooled = [0.0f64; RULES.len()];
        let mut kind_err = [[0.0f64; RULES.len()]; KINDS.len()];
        let mut kind_g2 = [0.0f64; KINDS.len()];
        let mut kind_n = [0usize; KINDS.len()];
        println!(
            "| level | {} |\n|---|{}",
            RULES.join(" | "),
            "---:|".repeat(RULES.len())
        );
        for &k in &levels {
            let (lw, lh) = (w >> k, h >> k);
            let side = 1usize << k;
            let rows: Vec<RowSums> = (0..lh)
                .into_par_iter()
                .map(|y| {
                    let mut err = [0.0f64; RULES.len()];
                    let mut g2 = 0.0;
                    let mut ke = [[0.0f64; RULES.len()]; KINDS.len()];
                    let mut kg = [0.0f64; KINDS.len()];
                    let mut kn = [0usize; KINDS.len()];
                    for x in 0..lw {
                        let texels = bake.texel(k, x as u32, y as u32);
                        let lobes: Vec<_> = texels[..bake.lobes]
                            .iter()
                            .filter_map(|&t| vmf_decode(t, r_max, a_min))
                            .collect();
                        let wsum: f64 = lobes.iter().map(|l| l.alpha).sum();
                        let tmean = lobes.iter().map(|l| l.alpha * l.var).sum::<f64>()
                            / wsum.max(1e-300)
                            / (alpha * alpha);
                        let first = normals[y * side * w + x * side];
                        let mut one = true;
                        for yy in 0..side {
                            for xx in 0..side {
                                if normals[(y * side + yy) * w + x * side + xx] != first {
                                    one = false;
                                }
                            }
                        }
                        let kind = if one {
                            5
                        } else if tmean < 0.01 {
                            0
                        } else if tmean < 0.1 {
                            1
                        } else if tmean < 1.0 {
                            2
                        } else if tmean < 10.0 {
                            3
                        } else {
                            4
                        };
                        kn[kind] += 1;
                        for &(l, v) in &dirs {
                            let hv = half_vector(l, v);
                            let mut gsum = 0.0;
                            for yy in 0..side {
                                for xx in 0..side {
                                    let n = normals[(y * side + yy) * w + x * side + xx];
                                    gsum += ggx(n.dot(hv), alpha) * n.dot(l).max(0.0);
                                }
                            }
                            let gref = gsum / (side * side) as f64;
                            g2 += gref * gref;
                            kg[kind] += gref * gref;
                            for r in 0..RULES.len() {
                                let f: f64 = lobes
                                    .iter()
                                    .map(|lo| {
                                        lo.alpha
                                            * rule(r, lo.mu.dot(hv), lo.var)
                                            * lo.mu.dot(l).max(0.0)
                                    })
                                    .sum();
                                err[r] += (f - gref) * (f - gref);
                                ke[kind][r] += (f - gref) * (f - gref);
                            }
                        }
                    }
                    (err, g2, ke, kg, kn)
                })
                .collect();
            let mut err = [0.0f64; RULES.len()];
            let mut g2 = 0.0;
            for (e, g, ke, kg, kn) in rows {
                for r in 0..RULES.len() {
                    err[r] += e[r];
                    for q in 0..KINDS.len() {
                        kind_err[q][r] += ke[q][r];
                    }
                }
                g2 += g;
                for q in 0..KINDS.len() {
                    kind_g2[q] += kg[q];
                    kind_n[q] += kn[q];
                }
            }
            let rel: Vec<f64> = err.iter().map(|e| (e / g2).sqrt()).collect();
            for r in 0..RULES.len() {
                pooled[r] += rel[r] * rel[r];
            }
            println!(
                "| {k} | {} |",
                rel.iter()
                    .map(|v| format!("{v:.4}"))
                    .collect::<Vec<_>>()
                    .join(" | ")
            );
        }
        println!(
            "| 2–7 | {} |",
            pooled
                .iter()
                .map(|v| format!("{:.4}", (v / levels.len() as f64).sqrt()))
                .collect::<Vec<_>>()
                .join(" | ")
        );
        // Kinds: share of the summed squared error (all levels 2–7 pooled by texel, not per
        // level) and of ΣG².
        let total_g2: f64 = kind_g2.iter().sum();
        let total_err: Vec<f64> = (0..RULES.len())
            .map(|r| kind_err.iter().map(|k| k[r]).sum())
            .collect();
        println!(
            "\n| kind | texels | share of ΣG² | {} |\n|---|---:|---:|{}",
            RULES
                .iter()
                .map(|r| format!("share of Σerr² {r}"))
                .collect::<Vec<_>>()
                .join(" | "),
            "---:|".repeat(RULES.len())
        );
        for q in 0..KINDS.len() {
            println!(
                "| {} | {} | {:.3} | {} |",
                KINDS[q],
                kind_n[q],
                kind_g2[q] / total_g2,
                (0..RULES.len())
                    .map(|r| format!(
                        "{:.3}",
                        kind_err[q][r] / total_g2.max(1e-300) / (total_err[1] / total_g2)
                    ))
                    .collect::<Vec<_>>()
                    .join(" | ")
            );
        }
        println!("(error shares are Σerr² of the kind ÷ Σerr² of all kinds under c = 2)");
    }
}
