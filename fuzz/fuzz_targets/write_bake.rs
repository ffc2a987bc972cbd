//! The output layer: the atomic folder writer and the OpenEXR and PNG encoders. A small map
//! (size, method, storage format and normals from the input) is baked and written twice into
//! the same folder; each time the folder must hold exactly the files its manifest lists, both
//! writes must give the same bytes (deterministic output), and every file must read back to the
//! texels of the bake as stored. Any panic, abort or sanitizer report is a finding.
#![no_main]

use libfuzzer_sys::fuzz_target;
use ndfmap::bake::{BakeOptions, Method};
use ndfmap::format::Format;
use ndfmap::ingest::{Addressing, BadNormals, IngestOptions, NormalMap};
use ndfmap::output::{InputInfo, Manifest, read_level, write_bake};
use std::collections::BTreeMap;
use std::path::Path;

/// Every file of `dir` with its bytes.
fn files(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| {
            let e = e.unwrap();
            let name = e.file_name().to_string_lossy().into_owned();
            (name, std::fs::read(e.path()).unwrap())
        })
        .collect()
}

fuzz_target!(init: ndfmap_fuzz::contain_dependency_panics(), |data: &[u8]| {
    let Some((head, rest)) = data.split_first_chunk::<4>() else {
        return;
    };
    let (w, h) = (1 + u32::from(head[0] % 24), 1 + u32::from(head[1] % 24));
    let methods = [Method::Plain, Method::Toksvig, Method::Lean, Method::Olano, Method::Vmf];
    let method = methods[usize::from(head[2]) % methods.len()];
    let format = Format::ALL[usize::from(head[3]) % Format::ALL.len()];
    let mut bytes = rest.iter().copied().chain(std::iter::repeat(255));
    let mut next = || f32::from(bytes.next().unwrap_or(255)) / 127.5 - 1.0;
    let vectors = (0..w * h)
        .map(|_| glam::Vec3::new(next(), next(), next().abs() + 0.01))
        .collect();
    let map = NormalMap::from_vectors(w, h, vectors, Addressing::Wrap, BadNormals::Repair)
        .expect("valid sizes");
    let options = BakeOptions {
        lobes: 1 + usize::from(head[2] / 5 % 2),
        ..BakeOptions::default()
    };
    let baked = ndfmap::methods::bake_with(&map, method, &options).expect("valid options");
    let Ok(bake) = ndfmap::pack::quantize(&baked, format) else {
        return; // a format that cannot hold the bake (LEAN in unorm)
    };
    let info = InputInfo {
        path: None,
        options: IngestOptions::default(),
        stats: map.stats().clone(),
    };
    let root = std::env::temp_dir().join(format!("ndfmap-fuzz-write-{}", std::process::id()));
    let dir = root.join("bake");
    let mut written = Vec::new();
    for _ in 0..2 {
        write_bake(&bake, info.clone(), &dir).expect("the folder is writable");
        written.push(files(&dir));
    }
    assert_eq!(written[0], written[1], "the same bake gave different bytes");
    let manifest: Manifest =
        serde_json::from_slice(&written[0]["manifest.json"]).expect("a manifest");
    let mut listed: Vec<String> = manifest
        .textures
        .iter()
        .flat_map(|t| t.files.clone())
        .chain(["manifest.json".to_string()])
        .collect();
    listed.sort();
    assert_eq!(written[0].keys().cloned().collect::<Vec<_>>(), listed);
    if matches!(format, Format::F32 | Format::F16) {
        for (t, info) in bake.textures.iter().zip(&manifest.textures) {
            for (k, f) in info.files.iter().enumerate() {
                let (_, _, px) = read_level(&dir.join(f)).expect("a readable level");
                assert!(
                    px.iter().zip(&t.levels[k]).all(|(a, b)| a == b
                        || a.iter().zip(b).all(|(x, y)| x.is_nan() && y.is_nan())),
                    "{f} reads back different texels"
                );
            }
        }
    }
    let _ = std::fs::remove_dir_all(&root);
});
