//! Where the prefiltered environment route's error comes from (issue 16, task H16e): for the
//! same baked lobes (vMF J = 6 aligned C = 1, and Toksvig's single lobe), each texel is shaded
//! (a) by the shipped prefiltered route ([`envlight::prefiltered_lobe`], summed over the
//! lobes), and also with the cosine at the lobe's centre (`share = 0`, the route before the
//! half-vector energy blocks: "a old"); (b) by the exact answer for the fitted lobes — the
//! footprint ground truth ([`envlight::ground_truth`]) over normals drawn from each lobe's vMF
//! (stratified, `NORMALS` per lobe), i.e. `∫ vMF(n) ∫ L ρ(n) cos dω_i dn` by Monte Carlo — and
//! (c) by the ground truth over the real normals of the footprint. `(a) − (b)` is the route's
//! approximation (one prefiltered lookup per lobe), `(b) − (c)` the fit.
//!
//! `cargo run --release --example env_error_split -- MAP ENV|sky [TEXELS_PER_LEVEL] [SAMPLES]`
//! (defaults 6 texels per level at levels 1 … last, 2048 MIS iterations per ground truth; the
//! 7 views of `eval`; Blinn-Phong s = 32, 256, GGX α = 0.1, 0.3, no g).
//!
//! Prints, per BRDF and method: the relative RMS error (RMS over levels of each level's
//! `sqrt(Σ(F − G)²/Σ G²)`, as `ndfmap eval`) of (a)−(c), (a old)−(c), (b)−(c), (a)−(b),
//! (a old)−(b), the Monte Carlo noise of (b) and (c) in the same metric, then per level, then
//! per lobe binned by κ and view angle: the lobe's signed bias `Σ α(a − b)/Σ α b` and RMS.

use glam::{DMat3, DVec3};
use ndfmap::bake::{Bake, BakeOptions, Method};
use ndfmap::brdf::Brdf;
use ndfmap::environment::{EnvOptions, LUMINANCE, Sky, load};
use ndfmap::envlight::{
    EnvLight, TexelLobe, default_views, ground_truth, prefiltered_lobe,
    prefiltered_lobe_with_share, texel_lobes,
};
use ndfmap::methods::bake_with;
use ndfmap::pyramid::pyramid;
use ndfmap::{IngestOptions, NormalMap};
use rayon::prelude::*;
use std::f64::consts::PI;
use std::path::Path;

/// Normals drawn per vMF lobe for (b).
const NORMALS: usize = 64;
/// κ bin edges (log2) of the per-lobe split.
const KAPPA_EDGES: [f64; 5] = [4.0, 16.0, 64.0, 256.0, 4096.0];

/// `NORMALS` stratified normals of the vMF (μ, κ), equal weights `alpha / NORMALS`
/// (κ = ∞: μ itself): `cos γ = 1 + ln(u + (1 − u)e^{−2κ})/κ` at `u = (i + ½)/N`, azimuths by
/// the golden angle.
fn vmf_normals(l: &TexelLobe, out: &mut Vec<(DVec3, f64)>) {
    if !l.kappa.is_finite() || l.kappa > 1e7 {
        out.push((l.mu, l.alpha));
        return;
    }
    let k = l.kappa.max(1e-6);
    let (t1, t2) = ndfmap::brdf::tangent_frame(l.mu);
    for i in 0..NORMALS {
        let u = (i as f64 + 0.5) / NORMALS as f64;
        let c = ndfmap::vmf::cos_quantile(u, k);
        let s = (1.0 - c * c).max(0.0).sqrt();
        let phi = 2.0 * PI * (i as f64 * 0.618_033_988_749_894_9).fract();
        let n = t1 * (s * phi.cos()) + t2 * (s * phi.sin()) + l.mu * c;
        out.push((n.normalize(), l.alpha / NORMALS as f64));
    }
}

fn lum(v: [f64; 3]) -> f64 {
    v.iter().zip(LUMINANCE).map(|(a, b)| a * b).sum()
}

/// Sums per (level, brdf, method): [a−c, aold−c, b−c, a−b, aold−b]² , c², b², se_c², se_b².
const NS: usize = 9;

#[derive(Default, Clone)]
struct Bin {
    // Σ α(a − b), Σ α(aold − b), Σ α b, Σ α²(a − b)², Σ α²(aold − b)², Σ α² b², Σ α² se², n
    v: [f64; 8],
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        eprintln!("usage: env_error_split MAP ENV|sky [TEXELS_PER_LEVEL] [SAMPLES]");
        std::process::exit(2);
    }
    let per_level: usize = args.get(3).map_or(6, |s| s.parse().unwrap());
    let samples: usize = args.get(4).map_or(2048, |s| s.parse().unwrap());
    let map = NormalMap::load(Path::new(&args[1]), &IngestOptions::default()).unwrap();
    let env = if args[2] == "sky" {
        Sky::default().render().unwrap()
    } else {
        load(Path::new(&args[2]), &EnvOptions::default()).unwrap()
    };
    let light = EnvLight::prefiltered_only(&env);
    let vmf = bake_with(
        &map,
        Method::Vmf,
        &BakeOptions {
            lobes: 6,
            align: Some(1.0),
            ..BakeOptions::default()
        },
    )
    .unwrap();
    let toksvig = bake_with(&map, Method::Toksvig, &BakeOptions::default()).unwrap();
    let bakes: [(&str, &Bake); 2] = [("vmf6", &vmf), ("toksvig", &toksvig)];
    let brdfs = vec![
        Brdf::BlinnPhong { s: 32.0 },
        Brdf::BlinnPhong { s: 256.0 },
        Brdf::ggx(0.1),
        Brdf::ggx(0.3),
    ];
    let nb = brdfs.len();
    let views = default_views();
    let levels = pyramid(map.width(), map.height());
    let mut tasks = Vec::new();
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let mut next = || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        state >> 33
    };
    for (k, lf) in levels.iter().enumerate().skip(1) {
        let (w, h) = lf.size;
        let n = (w * h) as usize;
        if n <= per_level {
            (0..n).for_each(|i| tasks.push((k, i as u32 % w, i as u32 / w)));
        } else {
            for _ in 0..per_level {
                tasks.push((k, (next() % w as u64) as u32, (next() % h as u64) as u32));
            }
        }
    }
    let nl = levels.len();
    let nk = KAPPA_EDGES.len() + 1;
    // Per task: level sums [method][brdf][NS] and lobe bins [method][brdf][θ class][κ bin].
    type Out = (usize, Vec<[f64; NS]>, Vec<Bin>);
    let t0 = std::time::Instant::now();
    let results: Vec<Out> = tasks
        .par_iter()
        .enumerate()
        .map(|(ti, &(k, x, y))| {
            let fp = levels[k].texel(x, y);
            let normals: Vec<(DVec3, f64)> = fp
                .iter()
                .map(|&(fx, fy, w)| {
                    (
                        map.normals()[(fy * map.width() + fx) as usize].as_dvec3(),
                        w,
                    )
                })
                .collect();
            let mut sums = vec![[0.0; NS]; 2 * nb];
            let mut bins = vec![Bin::default(); 2 * nb * 3 * nk];
            for (vi, &view) in views.iter().enumerate() {
                let seed = ((ti as u64) << 20) ^ (vi as u64) ^ 0xe5;
                let c = ground_truth(&light, &normals, view, &brdfs, samples, seed);
                let class = if view.z > 0.99 {
                    0
                } else if view.z > 0.5 {
                    1
                } else {
                    2
                };
                for (mi, (_, bake)) in bakes.iter().enumerate() {
                    let idx = y as usize * levels[k].size.0 as usize + x as usize;
                    let mut t = vec![[0.0f32; 4]; bake.textures.len()];
                    bake.texel_into(k, idx, &mut t);
                    let lobes = texel_lobes(bake, &t);
                    let mut a = vec![0.0; nb];
                    let mut aold = vec![0.0; nb];
                    let mut b = vec![0.0; nb];
                    let mut se_b = vec![0.0; nb];
                    for (j, l) in lobes.iter().enumerate() {
                        let mut ns = Vec::new();
                        vmf_normals(&TexelLobe { alpha: 1.0, ..*l }, &mut ns);
                        let seed = seed ^ ((j as u64 + 1) << 40) ^ ((mi as u64) << 50);
                        let e = ground_truth(&light, &ns, view, &brdfs, samples, seed);
                        let kb = KAPPA_EDGES
                            .iter()
                            .position(|&edge| l.kappa < edge)
                            .unwrap_or(KAPPA_EDGES.len());
                        for (bi, brdf) in brdfs.iter().enumerate() {
                            let aj = lum(prefiltered_lobe(
                                &light,
                                DMat3::IDENTITY,
                                l.mu,
                                l.kappa,
                                view,
                                brdf,
                            ));
                            let aoj = lum(prefiltered_lobe_with_share(
                                &light,
                                DMat3::IDENTITY,
                                l.mu,
                                l.kappa,
                                view,
                                brdf,
                                0.0,
                            ));
                            let bj = e.specular[bi];
                            a[bi] += l.alpha * aj;
                            aold[bi] += l.alpha * aoj;
                            b[bi] += l.alpha * bj;
                            se_b[bi] += (l.alpha * e.specular_se[bi]).powi(2);
                            let bin = &mut bins[((mi * nb + bi) * 3 + class) * nk + kb].v;
                            let w = l.alpha;
                            bin[0] += w * (aj - bj);
                            bin[1] += w * (aoj - bj);
                            bin[2] += w * bj;
                            bin[3] += (w * (aj - bj)).powi(2);
                            bin[4] += (w * (aoj - bj)).powi(2);
                            bin[5] += (w * bj).powi(2);
                            bin[6] += (w * e.specular_se[bi]).powi(2);
                            bin[7] += w;
                        }
                    }
                    for bi in 0..nb {
                        let g = c.specular[bi];
                        let s = &mut sums[mi * nb + bi];
                        s[0] += (a[bi] - g).powi(2);
                        s[1] += (aold[bi] - g).powi(2);
                        s[2] += (b[bi] - g).powi(2);
                        s[3] += (a[bi] - b[bi]).powi(2);
                        s[4] += (aold[bi] - b[bi]).powi(2);
                        s[5] += g * g;
                        s[6] += b[bi] * b[bi];
                        s[7] += c.specular_se[bi].powi(2);
                        s[8] += se_b[bi];
                    }
                }
            }
            (k, sums, bins)
        })
        .collect();
    eprintln!(
        "{} texels × {} views, {} MIS iterations per ground truth, {:.0} s",
        tasks.len(),
        views.len(),
        samples,
        t0.elapsed().as_secs_f64()
    );
    let mut lvl = vec![vec![[0.0; NS]; 2 * nb]; nl];
    let mut bins = vec![Bin::default(); 2 * nb * 3 * nk];
    for (k, s, b) in &results {
        for (acc, v) in lvl[*k].iter_mut().zip(s) {
            for (a, x) in acc.iter_mut().zip(v) {
                *a += x;
            }
        }
        for (acc, v) in bins.iter_mut().zip(b) {
            for (a, x) in acc.v.iter_mut().zip(&v.v) {
                *a += x;
            }
        }
    }
    let rel = |e: f64, g: f64| if g > 0.0 { (e / g).sqrt() } else { 0.0 };
    let dn = |e: f64, n: f64| (e * e - n * n).max(0.0).sqrt();
    let name = |b: &Brdf| match b {
        Brdf::BlinnPhong { s } => format!("BP s={s}"),
        Brdf::Ggx(g) => format!("GGX a={}", g.alpha),
        _ => String::new(),
    };
    println!(
        "# {} under {}: {} texels, 7 views, {} iterations per ground truth\n",
        args[1],
        args[2],
        tasks.len(),
        samples
    );
    println!(
        "Relative RMS % over levels 1–{} (denoised: the MC noise of the ground truths involved taken out; measured in brackets)\n",
        nl - 1
    );
    println!(
        "| method | BRDF | (a)−(c) route | (a old)−(c) | (b)−(c) fit | (a)−(b) route approx. | (a old)−(b) | noise (c) / (b) |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|---|");
    for (mi, (mname, _)) in bakes.iter().enumerate() {
        for (bi, brdf) in brdfs.iter().enumerate() {
            // Per-level relative errors, then RMS over levels.
            let mut per: Vec<[f64; 7]> = Vec::new();
            for l in lvl.iter().skip(1) {
                let s = &l[mi * nb + bi];
                let (g2, b2) = (s[5], s[6]);
                per.push([
                    rel(s[0], g2),
                    rel(s[1], g2),
                    rel(s[2], g2),
                    rel(s[3], b2),
                    rel(s[4], b2),
                    rel(s[7], g2),
                    rel(s[8], b2),
                ]);
            }
            let rms =
                |i: usize| (per.iter().map(|p| p[i] * p[i]).sum::<f64>() / per.len() as f64).sqrt();
            let (nc, nbb) = (rms(5), rms(6));
            let both = (nc * nc + nbb * nbb).sqrt();
            let f = |v: f64, n: f64| format!("{:.2} ({:.2})", 100.0 * dn(v, n), 100.0 * v);
            println!(
                "| {mname} | {} | {} | {} | {} | {} | {} | {:.2} / {:.2} |",
                name(brdf),
                f(rms(0), nc),
                f(rms(1), nc),
                f(rms(2), both),
                f(rms(3), nbb),
                f(rms(4), nbb),
                100.0 * nc,
                100.0 * nbb
            );
        }
    }
    println!(
        "\nPer level (denoised %, (a)−(c) / (a old)−(c) / (b)−(c) / (a)−(b) / (a old)−(b)):\n"
    );
    print!("| method | BRDF |");
    for k in 1..nl {
        print!(" L{k} |");
    }
    println!();
    print!("|---|---|");
    for _ in 1..nl {
        print!("---|");
    }
    println!();
    for (mi, (mname, _)) in bakes.iter().enumerate() {
        for (bi, brdf) in brdfs.iter().enumerate() {
            print!("| {mname} | {} |", name(brdf));
            for l in lvl.iter().skip(1) {
                let s = &l[mi * nb + bi];
                let (g2, b2) = (s[5], s[6]);
                let (nc, nbb) = (rel(s[7], g2), rel(s[8], b2));
                let both = (nc * nc + nbb * nbb).sqrt();
                print!(
                    " {:.0}/{:.0}/{:.0}/{:.0}/{:.0} |",
                    100.0 * dn(rel(s[0], g2), nc),
                    100.0 * dn(rel(s[1], g2), nc),
                    100.0 * dn(rel(s[2], g2), both),
                    100.0 * dn(rel(s[3], b2), nbb),
                    100.0 * dn(rel(s[4], b2), nbb)
                );
            }
            println!();
        }
    }
    println!(
        "\nPer lobe, (a)−(b) against the lobe's exact answer, by κ and view (θ_o = 0, 35, 70°): signed bias Σα(a−b)/Σαb %, new / old (share 0); in brackets the denoised relative RMS new / old\n"
    );
    let edges: Vec<String> = std::iter::once("κ<4".to_string())
        .chain(KAPPA_EDGES.windows(2).map(|w| format!("{}–{}", w[0], w[1])))
        .chain(std::iter::once(format!("≥{}", KAPPA_EDGES[4])))
        .collect();
    print!("| method | BRDF | θ_o |");
    for e in &edges {
        print!(" {e} |");
    }
    println!();
    print!("|---|---|---|");
    for _ in &edges {
        print!("---|");
    }
    println!();
    for (mi, (mname, _)) in bakes.iter().enumerate() {
        for (bi, brdf) in brdfs.iter().enumerate() {
            for (class, th) in ["0°", "35°", "70°"].iter().enumerate() {
                print!("| {mname} | {} | {th} |", name(brdf));
                for kb in 0..nk {
                    let v = &bins[((mi * nb + bi) * 3 + class) * nk + kb].v;
                    if v[7] == 0.0 || v[2] <= 0.0 {
                        print!(" – |");
                        continue;
                    }
                    let n = rel(v[6], v[5]);
                    print!(
                        " {:+.1} / {:+.1} ({:.1} / {:.1}) |",
                        100.0 * v[0] / v[2],
                        100.0 * v[1] / v[2],
                        100.0 * dn(rel(v[3], v[5]), n),
                        100.0 * dn(rel(v[4], v[5]), n)
                    );
                }
                println!();
            }
        }
    }
}
