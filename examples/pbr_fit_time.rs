//! Times the PBR bake's isotropic fit per level (issue 17's speed goal) and prints a digest of
//! the bake, so that two builds can be compared in the same run:
//! `cargo run --release --example pbr_fit_time -- MAP ALPHA THREADS REPEATS`.
//! Each repeat bakes with `THREADS` rayon threads; the per-level fit seconds printed are the
//! minimum over the repeats (wall clock of that stage, so the least-loaded repeat). The CPU
//! seconds of the fit (all levels, all threads: the process's user + system time of a bake
//! minus that of the same bake with no level fitted, from `/proc/self/stat`, Linux only) are
//! printed too: on a loaded machine they are what the fit costs.
//!
//! With a fifth argument `error` it also prints the fast fit's texel-space error as
//! `ndfmap pbr-report` scores it (relative RMS of `D·max(n·l, 0)` over the evaluation's 27
//! pairs, levels 2–7 pooled as the RMS of the per-level errors, fitted from level 2 as the
//! report fits), isotropic and anisotropic: the report's "fit iso" and "fit aniso" columns
//! without its slow rows.

use ndfmap::bake::PbrOptions;
use ndfmap::brdf::Brdf;
use ndfmap::eval::{Reference, default_directions};
use ndfmap::pbr::{FitSet, Search, bake_with_set};
use ndfmap::{IngestOptions, NormalMap};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let path = args
        .get(1)
        .expect("usage: pbr_fit_time MAP ALPHA THREADS REPEATS");
    let alpha: f64 = args.get(2).map_or(0.1, |a| a.parse().expect("alpha"));
    let threads: usize = args.get(3).map_or(2, |a| a.parse().expect("threads"));
    let repeats: usize = args.get(4).map_or(3, |a| a.parse().expect("repeats"));
    let map = NormalMap::load(std::path::Path::new(path), &IngestOptions::default()).unwrap();
    let options = PbrOptions {
        roughness: alpha.sqrt(),
        ..PbrOptions::default()
    };
    let set = FitSet::standard();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    let mut best: Vec<f64> = Vec::new();
    let mut digest = 0u64;
    let mut cpu = f64::INFINITY;
    for _ in 0..repeats {
        let c0 = cpu_seconds();
        pool.install(|| bake_with_set(&map, &options, None, &set, Search::Fast, 99).unwrap());
        let c1 = cpu_seconds();
        let (bake, t) =
            pool.install(|| bake_with_set(&map, &options, None, &set, Search::Fast, 0).unwrap());
        let c2 = cpu_seconds();
        cpu = cpu.min((c2 - c1) - (c1 - c0));
        if best.is_empty() {
            best = t.fit.clone();
        }
        for (b, s) in best.iter_mut().zip(&t.fit) {
            *b = b.min(*s);
        }
        digest = 0xcbf2_9ce4_8422_2325;
        for tex in &bake.textures {
            for level in &tex.levels {
                for texel in level {
                    for v in texel {
                        digest = (digest ^ v.to_bits() as u64).wrapping_mul(0x100_0000_01b3);
                    }
                }
            }
        }
    }
    let shown: Vec<String> = best.iter().take(6).map(|s| format!("{s:.3}")).collect();
    println!(
        "fit seconds per level (min of {repeats}, {threads} threads): [{}]",
        shown.join(", ")
    );
    println!("fit CPU seconds, all levels (min of {repeats}): {cpu:.2}");
    println!("bake digest {digest:016x}");
    if args.get(5).map(String::as_str) == Some("error") {
        let (first, last) = (2, 7);
        let bakes: Vec<_> = [false, true]
            .into_iter()
            .map(|anisotropic| {
                let o = PbrOptions {
                    anisotropic,
                    ..options
                };
                pool.install(|| bake_with_set(&map, &o, None, &set, Search::Fast, first))
                    .unwrap()
                    .0
            })
            .collect();
        let reference = Reference::new(&map, &[Brdf::ggx(alpha)], &default_directions(), first);
        let errors = reference.evaluate(&bakes.iter().collect::<Vec<_>>());
        for (label, e) in ["fit iso", "fit aniso"].iter().zip(&errors) {
            let last = last.min(e.levels.len() - 1);
            let lv: Vec<f64> = e.levels[first..=last].iter().map(|l| l.specular).collect();
            let pooled = (lv.iter().map(|v| v * v).sum::<f64>() / lv.len() as f64).sqrt();
            let shown: Vec<String> = lv.iter().map(|v| format!("{v:.3}")).collect();
            println!(
                "{label}: pooled {pooled:.4}, levels {first}-{last} [{}]",
                shown.join(", ")
            );
        }
    }
}

/// User + system CPU seconds of this process so far ([`ndfmap::usage::cpu_seconds`]); NaN
/// where it cannot be read.
fn cpu_seconds() -> f64 {
    ndfmap::usage::cpu_seconds().unwrap_or(f64::NAN)
}
