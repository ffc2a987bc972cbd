//! Measurements behind `docs/sh-brdf.md` that `ndfmap eval` does not make: the SH specular
//! cosine term done exactly (the SH projection of `f(ω_h·n) max(ω_i·n, 0)`) against the paper's
//! MIP-mapped normal, and what clamping SH ringing at 0 costs. On the shared real maps, so they
//! are `#[ignore]`d; run them with
//! `cargo test --release --test sh_brdf_experiments -- --ignored --nocapture`.

use glam::DVec3;
use ndfmap::bake::{Bake, BakeOptions, Method};
use ndfmap::brdf::{Brdf, half_vector};
use ndfmap::eval::{LightView, default_directions, relative_rms};
use ndfmap::methods::bake_with;
use ndfmap::pyramid::{pyramid, reduce};
use ndfmap::sh::{lmax_of, mean_normal, product_coefficients, shade_product, shade_series};
use ndfmap::{IngestOptions, NormalMap};
use std::path::PathBuf;

fn shared_map(name: &str) -> Option<NormalMap> {
    let dir = std::env::var_os("NDFMAP_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/normalmaps")
        });
    let path = dir.join(name);
    if !path.exists() {
        eprintln!("skipped: {} not found", path.display());
        return None;
    }
    Some(NormalMap::load(&path, &IngestOptions::default()).unwrap())
}

fn sh(map: &NormalMap, lmax: usize) -> Bake {
    let o = BakeOptions {
        lmax,
        ..BakeOptions::default()
    };
    bake_with(map, Method::Sh, &o).unwrap()
}

/// Per level ≥ 1, the exact footprint averages of the specular term of `brdf` (without g) for
/// light/view `lv`.
fn exact_specular(map: &NormalMap, brdf: &Brdf, (l, v): LightView) -> Vec<Vec<f64>> {
    let h = half_vector(l, v);
    let finest: Vec<f64> = map
        .normals()
        .iter()
        .map(|n| brdf.reference(n.as_dvec3(), l, h).specular)
        .collect();
    pyramid(map.width(), map.height())
        .iter()
        .map(|lf| reduce(&finest, 1, map.width(), lf))
        .collect()
}

/// Relative RMS over levels 1 … of per-level errors, given per-level sums `(Σ(F−G)², ΣG²)`.
fn overall(sums: &[(f64, f64)]) -> f64 {
    let e: Vec<f64> = sums[1..].iter().map(|&(a, b)| relative_rms(a, b)).collect();
    (e.iter().map(|x| x * x).sum::<f64>() / e.len() as f64).sqrt()
}

#[test]
#[ignore]
fn cosine_term_mip_normal_against_the_exact_product() {
    for name in ["rock.jpg", "bark.jpg"] {
        let Some(map) = shared_map(name) else { return };
        for lmax in [4, 8] {
            let b = sh(&map, lmax);
            for brdf in [Brdf::BlinnPhong { s: 8.0 }, Brdf::BlinnPhong { s: 32.0 }] {
                let levels = b.level_count();
                let (mut mip, mut exact) = (vec![(0.0, 0.0); levels], vec![(0.0, 0.0); levels]);
                for &lv in &default_directions() {
                    let (l, v) = lv;
                    let h = half_vector(l, v);
                    let truth = exact_specular(&map, &brdf, lv);
                    let p = product_coefficients(&brdf, lmax, l, h);
                    let mut t = vec![[0.0f32; 4]; b.textures.len()];
                    for k in 1..levels {
                        for (i, g) in truth[k].iter().enumerate() {
                            b.texel_into(k, i, &mut t);
                            let (_, f) = shade_series(&t, lmax, l, h, &brdf);
                            let a = f.max(0.0) * mean_normal(&t, lmax).dot(l).max(0.0);
                            let e = shade_product(&t, lmax, &p);
                            mip[k].0 += (a - g) * (a - g);
                            mip[k].1 += g * g;
                            exact[k].0 += (e - g) * (e - g);
                            exact[k].1 += g * g;
                        }
                    }
                }
                println!(
                    "{name} sh{lmax} {brdf}: MIP-mapped normal {:.4}, exact product {:.4} \
                     (levels 1+); per level MIP / exact: {}",
                    overall(&mip),
                    overall(&exact),
                    (1..levels)
                        .map(|k| format!(
                            "{k}: {:.3}/{:.3}",
                            relative_rms(mip[k].0, mip[k].1),
                            relative_rms(exact[k].0, exact[k].1)
                        ))
                        .collect::<Vec<_>>()
                        .join(", ")
                );
            }
        }
    }
}

#[test]
#[ignore]
fn ringing_and_what_the_clamp_costs() {
    for name in ["rock.jpg", "bark.jpg"] {
        let Some(map) = shared_map(name) else { return };
        for lmax in [2, 8, 16] {
            let b = sh(&map, lmax);
            assert_eq!(lmax_of(&b), lmax);
            for brdf in [
                Brdf::Lambert,
                Brdf::BlinnPhong { s: 1.0 },
                Brdf::BlinnPhong { s: 128.0 },
                Brdf::BlinnPhong { s: 1e5 },
            ] {
                let levels = b.level_count();
                let (mut clamped, mut raw) = (vec![(0.0, 0.0); levels], vec![(0.0, 0.0); levels]);
                let (mut negative, mut total) = (0u64, 0u64);
                for &(l, v) in &default_directions() {
                    let h = half_vector(l, v);
                    let finest: Vec<f64> = map
                        .normals()
                        .iter()
                        .map(|n| {
                            let r = brdf.reference(n.as_dvec3(), l, h);
                            if brdf.has_specular() {
                                r.specular
                            } else {
                                r.diffuse
                            }
                        })
                        .collect();
                    let lfs = pyramid(map.width(), map.height());
                    let mut t = vec![[0.0f32; 4]; b.textures.len()];
                    for (k, lf) in lfs.iter().enumerate().skip(1) {
                        let truth = reduce(&finest, 1, map.width(), lf);
                        for (i, g) in truth.iter().enumerate() {
                            b.texel_into(k, i, &mut t);
                            let (d, f) = shade_series(&t, lmax, l, h, &brdf);
                            let cos = mean_normal(&t, lmax).dot(l).max(0.0);
                            let series = if brdf.has_specular() { f } else { d };
                            let scale = if brdf.has_specular() { cos } else { 1.0 };
                            total += 1;
                            if series < 0.0 {
                                negative += 1;
                            }
                            let (a, c) = (series * scale, series.max(0.0) * scale);
                            raw[k].0 += (a - g) * (a - g);
                            raw[k].1 += g * g;
                            clamped[k].0 += (c - g) * (c - g);
                            clamped[k].1 += g * g;
                        }
                    }
                }
                println!(
                    "{name} sh{lmax} {brdf}: {:.2} % of (texel, direction) negative; error \
                     unclamped {:.4}, clamped {:.4} (levels 1+)",
                    100.0 * negative as f64 / total as f64,
                    overall(&raw),
                    overall(&clamped)
                );
            }
        }
    }
}

/// The diffuse error of one normal pointing at the light with the truncated clamped cosine:
/// what l* = 2 costs a flat texel (1/16 at normal incidence).
#[test]
fn a_flat_texel_shows_the_truncation_of_the_clamped_cosine() {
    let map = NormalMap::from_vectors(
        2,
        2,
        vec![glam::Vec3::Z; 4],
        ndfmap::ingest::Addressing::Wrap,
        ndfmap::ingest::BadNormals::Repair,
    )
    .unwrap();
    for (lmax, want) in [(2, 1.0625), (4, 1.0 - 0.03125), (8, 1.0 - 0.013671875)] {
        let b = sh(&map, lmax);
        let t = b.texel(0, 0, 0);
        let (d, _) = shade_series(&t, lmax, DVec3::Z, DVec3::Z, &Brdf::Lambert);
        assert!((d - want).abs() < 1e-6, "l* = {lmax}: {d} vs {want}");
    }
}
