//! Checks on the real CC0 normal maps in `../shared/data/normalmaps/` (read in place, never
//! copied). Skipped with a message when that folder is absent (a clone without `shared/`).

use ndfmap::bake::{Bake, BakeOptions, Method};
use ndfmap::brdf::Brdf;
use ndfmap::em::AlignmentForm;
use ndfmap::eval::{default_directions, evaluate};
use ndfmap::methods::{bake, bake_with};
use ndfmap::{IngestOptions, NormalMap};
use std::path::PathBuf;

fn shared_map(name: &str) -> Option<PathBuf> {
    let dir = std::env::var_os("NDFMAP_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/normalmaps")
        });
    let path = dir.join(name);
    if path.exists() {
        Some(path)
    } else {
        eprintln!(
            "skipped: {} not found (set NDFMAP_DATA to the normalmaps folder)",
            path.display()
        );
        None
    }
}

#[test]
fn toksvig_beats_plain_mip_on_rock_at_far_levels() {
    let Some(path) = shared_map("rock.jpg") else {
        return;
    };
    let map = NormalMap::load(&path, &IngestOptions::default()).unwrap();
    assert_eq!((map.width(), map.height()), (1024, 1024));
    assert_eq!(map.stats().bad_total(), 0);
    let plain = bake(&map, Method::Plain);
    let toksvig = bake(&map, Method::Toksvig);
    let refs: Vec<&Bake> = vec![&plain, &toksvig];
    let errors = evaluate(
        &map,
        &refs,
        &Brdf::blinn_phong(&[64.0, 512.0]),
        &default_directions(),
    );
    for s in [64.0, 512.0] {
        let p = errors
            .iter()
            .find(|e| e.method == Method::Plain && e.brdf == Brdf::BlinnPhong { s })
            .unwrap();
        let t = errors
            .iter()
            .find(|e| e.method == Method::Toksvig && e.brdf == Brdf::BlinnPhong { s })
            .unwrap();
        for k in 3..=8 {
            let (ps, ts) = (p.levels[k].specular, t.levels[k].specular);
            assert!(ts < ps, "s={s} level {k}: Toksvig {ts} vs plain {ps}");
        }
        assert!(
            t.overall_specular < 0.8 * p.overall_specular,
            "s={s}: {} vs {}",
            t.overall_specular,
            p.overall_specular
        );
    }
}

#[test]
fn vmf_beats_toksvig_and_lean_on_rock_at_far_levels() {
    let Some(path) = shared_map("rock.jpg") else {
        return;
    };
    let map = NormalMap::load(&path, &IngestOptions::default()).unwrap();
    let vmf = bake(&map, Method::Vmf); // J = 6, unaligned
    let aligned = BakeOptions {
        align: Some(AlignmentForm::default().default_strength()),
        ..BakeOptions::default()
    };
    let vmfa = bake_with(&map, Method::Vmf, &aligned).unwrap(); // eq 29, C = 0.03
    let toksvig = bake(&map, Method::Toksvig);
    let lean = bake(&map, Method::Lean);
    let errors = evaluate(
        &map,
        &[&vmf, &vmfa, &toksvig, &lean],
        &Brdf::blinn_phong(&[32.0, 256.0]),
        &default_directions(),
    );
    for s in [32.0, 256.0] {
        let brdf = Brdf::BlinnPhong { s };
        let get = |label: &str| {
            errors
                .iter()
                .find(|e| e.label == label && e.brdf == brdf)
                .unwrap()
        };
        let (v, t, l) = (get("vmf6"), get("toksvig"), get("lean"));
        // Coherent lobes (eq 29) cost some texel-space accuracy: on the mean of levels 2-6,
        // within 1.85x of the unaligned fit at s = 32 and 1.2x at s = 256 (measured, balanced
        // mode, with the specular cosine at the product lobe's centre: 0.0307 against 0.0178,
        // 1.72x, at s = 32; with Algorithm 2's cosine at μ it was 0.0314 against 0.0217, 1.45x:
        // the cosine helps the unaligned lobes more, and eq 29's pull towards the neighbours'
        // lobes is what is left; before the divergence seeding both fits were worse and close,
        // 0.038 against 0.037), and still over 3x better than Toksvig and LEAN (measured 4x
        // and 6x before the cosine change).
        let mean = |e: &ndfmap::eval::MethodError| {
            (2..=6).map(|k| e.levels[k].specular).sum::<f64>() / 5.0
        };
        let (va, vu) = (mean(get("vmf6a")), mean(v));
        let bound = if s < 100.0 { 1.85 } else { 1.2 };
        assert!(va <= bound * vu, "s={s}: aligned {va} vs unaligned {vu}");
        assert!(
            3.0 * va < mean(t) && 3.0 * va < mean(l),
            "s={s}: aligned {va}"
        );
        for k in 2..=6 {
            let (ve, te, le) = (
                v.levels[k].specular,
                t.levels[k].specular,
                l.levels[k].specular,
            );
            assert!(
                ve < te && ve < le,
                "s={s} level {k}: vMF {ve}, Toksvig {te}, LEAN {le}"
            );
        }
    }
}
