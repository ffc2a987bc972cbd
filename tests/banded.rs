//! Banded, streamed mixture bakes (issue 19 item 4, issue 14 item 5; docs/scale.md): the bake
//! produced in row bands and streamed to its files must be bit-identical to the untiled
//! in-memory bake (`methods::bake_with`), whatever the bands, the source (decoded normals or
//! compact 8-bit samples), the thread count and the container; an interrupted streamed bake
//! leaves nothing that looks complete.
//!
//! The issue asks for the proof on a 2048² map; a 2048² J = 6 aligned bake twice (untiled and
//! banded) is too slow for the test suite's debug build, so the tests use the smallest maps
//! that exercise several fine levels and many bands, with the band height forced small
//! (`Bands { fine: 3, band_rows: 8 }` on 64 rows: 8 bands; a 2048-wide map for full-width
//! wavefronts), and `ndfmap bench --scale` checks the files byte for byte at 2048² (and
//! 4096²) against the untiled bake's.

use ndfmap::bake::{Bake, BakeOptions, FitMode, Method};
use ndfmap::banded::{Bands, CompactSource, Map, bake_in_bands, write_folder};
use ndfmap::container::{Container, write_bake_hashed};
use ndfmap::format::Format;
use ndfmap::ingest::{CompactFeature, CompactNormals, IngestOptions, NormalMap, Samples};
use ndfmap::methods::bake_with;
use ndfmap::output::InputInfo;
use std::path::Path;

/// The built-in sample (1024-pixel feature scale shrunk) cut to `w × h`, as 8-bit RGB samples,
/// and its albedo.
fn sample(w: u32, h: u32) -> (Vec<u8>, Vec<[f32; 4]>) {
    let side = w.max(h);
    let s = ndfmap::procedural::generate(side, 11);
    let rgb = ndfmap::procedural::encode_rgb8(s.map.normals());
    let mut out = Vec::with_capacity((w * h * 3) as usize);
    let mut albedo = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        let row = (y * side) as usize;
        out.extend_from_slice(&rgb[row * 3..(row + w as usize) * 3]);
        albedo.extend_from_slice(&s.albedo[row..row + w as usize]);
    }
    (out, albedo)
}

fn decoded(w: u32, h: u32, rgb: &[u8]) -> NormalMap {
    NormalMap::from_samples(
        "sample",
        w,
        h,
        3,
        Samples::U8(rgb),
        &IngestOptions::default(),
    )
    .unwrap()
}

fn compact(w: u32, h: u32, rgb: &[u8]) -> CompactNormals {
    CompactNormals::from_samples(
        "sample",
        w,
        h,
        3,
        Samples::U8(rgb),
        &IngestOptions::default(),
    )
    .unwrap()
}

fn options(lobes: usize, align: Option<f64>, mode: FitMode) -> BakeOptions {
    BakeOptions {
        lobes,
        align,
        mode,
        ..BakeOptions::default()
    }
}

fn same(a: &Bake, b: &Bake, what: &str) {
    assert_eq!(a.sizes, b.sizes, "{what}");
    assert_eq!(a.parameters, b.parameters, "{what}");
    assert_eq!(a.textures.len(), b.textures.len(), "{what}");
    for (s, t) in a.textures.iter().zip(&b.textures) {
        assert_eq!(s.name, t.name, "{what}");
        for (k, (x, y)) in s.levels.iter().zip(&t.levels).enumerate() {
            // Bits, not values: NaN or −0 would differ here.
            let bits = |l: &Vec<[f32; 4]>| -> Vec<u32> {
                l.iter().flatten().map(|v| v.to_bits()).collect()
            };
            assert!(bits(x) == bits(y), "{what}: {} level {k} differs", s.name);
        }
        assert_eq!(s.levels.len(), t.levels.len(), "{what}");
    }
    assert_eq!(a, b, "{what}");
}

#[test]
fn banded_bakes_are_bit_identical_to_untiled_bakes() {
    let (w, h) = (64, 64);
    let (rgb, albedo) = sample(w, h);
    let full = decoded(w, h, &rgb).with_feature(albedo.clone()).unwrap();
    let plain = decoded(w, h, &rgb);
    let small = compact(w, h, &rgb);
    let flat: Vec<f32> = albedo.iter().flatten().copied().collect();
    let albedo_compact = CompactFeature::from_samples(
        "albedo",
        w,
        h,
        4,
        Samples::F32(&flat),
        &IngestOptions::default(),
    )
    .unwrap();
    let cases = [
        (
            "vmf J=6 aligned colour",
            Method::Vmf,
            options(6, Some(1.0), FitMode::Fast),
            true,
        ),
        (
            "vmf J=4 unaligned colour",
            Method::Vmf,
            options(4, None, FitMode::Balanced),
            true,
        ),
        (
            "vmf J=3 aligned eq 29",
            Method::Vmf,
            options(3, Some(1.0), FitMode::Fast),
            false,
        ),
        (
            "tan2005 J=3 aligned",
            Method::Tan2005,
            options(3, Some(1.0), FitMode::Fast),
            false,
        ),
    ];
    for (what, method, o, color) in cases {
        let map = if color { &full } else { &plain };
        let untiled = bake_with(map, method, &o).unwrap();
        for bands in [
            Bands {
                fine: 1,
                band_rows: 1,
            },
            Bands {
                fine: 1,
                band_rows: 24,
            },
            Bands {
                fine: 2,
                band_rows: 4,
            },
            Bands {
                fine: 3,
                band_rows: 8,
            },
            Bands {
                fine: 3,
                band_rows: 24,
            },
            Bands::for_size(w, h),
        ] {
            let b = bake_in_bands(&Map::Full(map), method, &o, bands).unwrap();
            same(&b, &untiled, &format!("{what}, {bands:?}, decoded"));
            let c = CompactSource {
                normals: &small,
                feature: color.then_some(&albedo_compact),
            };
            let b = bake_in_bands(&Map::Compact(c), method, &o, bands).unwrap();
            same(&b, &untiled, &format!("{what}, {bands:?}, compact"));
        }
    }
}

#[test]
fn a_wide_map_in_many_bands_equals_the_untiled_bake_on_any_thread_count() {
    // Full-width rows of 2048 texels (the wavefronts of a 2048² map's level 0..2 rows), 64
    // rows in 8 bands of 8 rows over 3 fine levels: every band boundary, its kept row and the
    // upper-right pull across it are exercised.
    let (w, h) = (2048, 64);
    let (rgb, albedo) = sample(w, h);
    let map = decoded(w, h, &rgb).with_feature(albedo).unwrap();
    let o = options(6, Some(1.0), FitMode::Fast);
    let untiled = bake_with(&map, Method::Vmf, &o).unwrap();
    let bands = Bands {
        fine: 3,
        band_rows: 8,
    };
    for threads in [1, 3] {
        let b = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| bake_in_bands(&Map::Full(&map), Method::Vmf, &o, bands).unwrap());
        same(&b, &untiled, &format!("{threads} threads"));
    }
}

fn input(map: &NormalMap) -> InputInfo {
    InputInfo {
        path: None,
        options: IngestOptions::default(),
        stats: map.stats().clone(),
    }
}

/// Every file of two folders, by name, byte for byte.
fn same_folders(a: &Path, b: &Path, what: &str) {
    let names = |d: &Path| {
        let mut v: Vec<String> = std::fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        v.sort();
        v
    };
    assert_eq!(names(a), names(b), "{what}");
    for n in names(a) {
        let (x, y) = (
            std::fs::read(a.join(&n)).unwrap(),
            std::fs::read(b.join(&n)).unwrap(),
        );
        assert!(x == y, "{what}: {n} differs");
    }
}

#[test]
fn streamed_folders_equal_the_in_memory_writers_files_in_every_container() {
    let (w, h) = (32, 16);
    let (rgb, albedo) = sample(w, h);
    let map = decoded(w, h, &rgb).with_feature(albedo).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let o = options(2, Some(1.0), FitMode::Fast);
    let bands = Bands {
        fine: 2,
        band_rows: 4,
    };
    let untiled = bake_with(&map, Method::Vmf, &o).unwrap();
    for container in [Container::Ktx2, Container::Dds, Container::Exr] {
        for format in [Format::F32, Format::F16, Format::Unorm8] {
            let what = format!("{container} {format}");
            let a = dir.path().join(format!("mem-{container}-{format}"));
            let b = dir.path().join(format!("streamed-{container}-{format}"));
            let q = ndfmap::pack::quantize(&untiled, format).unwrap();
            write_bake_hashed(&q, input(&map), &a, container, None, Some("h".into())).unwrap();
            let m = write_folder(
                &Map::Full(&map),
                Method::Vmf,
                &o,
                format,
                container,
                None,
                &b,
                input(&map),
                Some("h".into()),
                Some(bands),
                &mut |_| true,
            )
            .unwrap();
            assert_eq!(m, b.join("manifest.json"));
            same_folders(&a, &b, &what);
        }
    }
}

#[test]
fn an_interrupted_streamed_bake_leaves_the_old_folder_and_no_partial_one() {
    let (w, h) = (32, 32);
    let (rgb, _) = sample(w, h);
    let map = decoded(w, h, &rgb);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bake");
    let o = options(3, Some(1.0), FitMode::Fast);
    let write = |progress: &mut (dyn FnMut(f32) -> bool + Send)| {
        write_folder(
            &Map::Full(&map),
            Method::Vmf,
            &o,
            Format::F16,
            Container::Ktx2,
            None,
            &out,
            input(&map),
            None,
            Some(Bands {
                fine: 2,
                band_rows: 4,
            }),
            progress,
        )
    };
    // Never written: a cancelled bake leaves no folder at all.
    let mut calls = 0;
    let e = write(&mut |f| {
        calls += 1;
        f < 0.3
    })
    .unwrap_err();
    assert!(matches!(e, ndfmap::Error::Cancelled), "{e}");
    assert!(!out.exists());
    // Written once, then interrupted: the first bake stays, complete.
    write(&mut |_| true).unwrap();
    let before = std::fs::read(out.join("manifest.json")).unwrap();
    let e = write(&mut |f| f < 0.5).unwrap_err();
    assert!(matches!(e, ndfmap::Error::Cancelled), "{e}");
    assert_eq!(std::fs::read(out.join("manifest.json")).unwrap(), before);
    // Nothing but the folder and its lock beside it.
    let left: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .filter(|n| !n.ends_with("ndfmap-lock"))
        .collect();
    assert_eq!(left, vec!["bake".to_string()]);
    assert!(calls > 1);
}

#[test]
fn bad_bands_and_methods_are_refused_before_any_work() {
    let (w, h) = (32, 24);
    let (rgb, _) = sample(w, h);
    let map = decoded(w, h, &rgb);
    let o = options(2, Some(1.0), FitMode::Fast);
    for bands in [
        Bands {
            fine: 0,
            band_rows: 8,
        },
        Bands {
            fine: 2,
            band_rows: 6,
        },
        Bands {
            fine: 2,
            band_rows: 0,
        },
        // 24 rows are not a multiple of 16.
        Bands {
            fine: 4,
            band_rows: 16,
        },
        Bands {
            fine: 9,
            band_rows: 512,
        },
    ] {
        let e = bake_in_bands(&Map::Full(&map), Method::Vmf, &o, bands).unwrap_err();
        assert!(e.to_string().contains("bands of"), "{bands:?}: {e}");
    }
    let e = bake_in_bands(&Map::Full(&map), Method::Sh, &o, Bands::for_size(w, h)).unwrap_err();
    assert!(e.to_string().contains("no banded bake"), "{e}");
    // The chosen bands always check, and keep level m within the coarse budget.
    for (w, h) in [
        (1, 1),
        (5, 3),
        (1024, 1024),
        (16384, 16384),
        (8192, 96),
        (4096, 4097),
    ] {
        let b = Bands::for_size(w, h);
        b.check(w, h).unwrap();
        assert!(b.band_rows.is_multiple_of(1 << b.fine));
    }
    assert_eq!(Bands::for_size(16384, 16384).fine, 3);
    assert_eq!(Bands::for_size(1024, 1024).fine, 1);
}

#[test]
fn the_budget_estimate_lies_above_the_measured_peaks() {
    // docs/scale.md: whole `ndfmap bake` command (decoded source, colour) and `ndfmap bench
    // --scale` (compact source, no colour), MiB.
    let o = options(6, Some(1.0), FitMode::Balanced);
    let measured: [(u32, bool, bool, u64); 5] = [
        (1024, true, false, 153),
        (1024, false, true, 89),
        (2048, false, true, 320),
        (4096, false, true, 1112),
        (8192, false, true, 1257),
    ];
    for (size, color, compact, mib) in measured {
        let bands = Bands::for_size(size, size);
        let source = if compact {
            3
        } else {
            ndfmap::banded::DECODED_NORMAL_BYTES
        } + if color {
            ndfmap::banded::DECODED_FEATURE_BYTES
        } else {
            0
        };
        let e = ndfmap::banded::estimate_peak_bytes(size, size, &o, color, source, bands);
        assert!(
            e > (mib << 20) * 11 / 10,
            "{size}: {} MiB estimated, {mib} measured",
            e >> 20
        );
    }
    // 16384² compact, no colour: under the 3 GiB.
    let bands = Bands::for_size(16384, 16384);
    let e = ndfmap::banded::estimate_peak_bytes(16384, 16384, &o, false, 3, bands);
    assert!(e < 3 << 30, "{} MiB", e >> 20);
    // 16384² from a 16-bit RGB PNG (6 bytes per texel kept): still under 3 GiB.
    let e = ndfmap::banded::estimate_peak_bytes(16384, 16384, &o, false, 6, bands);
    assert!(e < 3 << 30, "{} MiB", e >> 20);
}

/// `ndfmap bake`'s banded path (`batch::run`) keeps 8- and 16-bit inputs as their decoded
/// samples (`ingest::load_normals_compact`, `CompactFeature`) instead of a `NormalMap`: its
/// files and manifest must equal, byte for byte, those of the decoded, untiled path
/// (`NormalMap::load_memory` + `with_feature_memory` + `bake_with` + `quantize` +
/// `write_bake_hashed`), for an 8-bit RGB PNG with an sRGB 8-bit albedo, a 16-bit RGBA PNG
/// with a 16-bit grey + alpha albedo, a JPEG with a linear RGBA8 albedo, and a float OpenEXR
/// (kept decoded) with an 8-bit albedo.
#[test]
fn bakes_from_kept_samples_equal_bakes_from_decoded_files() {
    use ndfmap::batch::{AlignSetting, RunOptions, Settings};
    use ndfmap::ingest::{LoadedNormals, load_normals_compact};
    let (w, h) = (40u32, 24u32);
    let side = w.max(h);
    let s = ndfmap::procedural::generate(side, 7);
    let normal = |x: u32, y: u32| s.map.normals()[(y * side + x) as usize];
    let albedo = |x: u32, y: u32| s.albedo[(y * side + x) as usize];
    let dir = tempfile::tempdir().unwrap();
    let p = |name: &str| dir.path().join(name);
    let unorm = |v: f32, max: f32| ((v * 0.5 + 0.5) * max).round().clamp(0.0, max);
    image::RgbImage::from_fn(w, h, |x, y| {
        image::Rgb(normal(x, y).to_array().map(|v| unorm(v, 255.0) as u8))
    })
    .save(p("n8.png"))
    .unwrap();
    image::RgbImage::from_fn(w, h, |x, y| {
        image::Rgb([0, 1, 2].map(|c| (albedo(x, y)[c] * 255.0).round() as u8))
    })
    .save(p("a8.png"))
    .unwrap();
    image::ImageBuffer::<image::Rgba<u16>, Vec<u16>>::from_fn(w, h, |x, y| {
        let n = normal(x, y).to_array().map(|v| unorm(v, 65535.0) as u16);
        image::Rgba([n[0], n[1], n[2], 65535 - (x * 97) as u16])
    })
    .save(p("n16.png"))
    .unwrap();
    image::ImageBuffer::<image::LumaA<u16>, Vec<u16>>::from_fn(w, h, |x, y| {
        image::LumaA([(albedo(x, y)[1] * 65535.0) as u16, (y * 2000) as u16])
    })
    .save(p("a16.png"))
    .unwrap();
    image::RgbImage::from_fn(w, h, |x, y| {
        image::Rgb(normal(x, y).to_array().map(|v| unorm(v, 255.0) as u8))
    })
    .save(p("n.jpg"))
    .unwrap();
    image::RgbaImage::from_fn(w, h, |x, y| {
        let a = albedo(x, y);
        image::Rgba([
            (a[0] * 255.0) as u8,
            (a[1] * 255.0) as u8,
            (a[2] * 255.0) as u8,
            (x * 6) as u8,
        ])
    })
    .save(p("a8a.png"))
    .unwrap();
    exr::prelude::write_rgb_file(p("n.exr"), w as usize, h as usize, |x, y| {
        let n = normal(x as u32, y as u32);
        (n.x, n.y, n.z)
    })
    .unwrap();
    let cases = [
        ("n8.png", "a8.png", "srgb", true),
        ("n16.png", "a16.png", "srgb", true),
        ("n.jpg", "a8a.png", "linear", true),
        ("n.exr", "a8.png", "srgb", false),
    ];
    for (normals, feature, encoding, compact) in cases {
        let out = dir.path().join("out");
        let job = Settings {
            path: Some(normals.into()),
            feature: Some(feature.into()),
            method: Some("vmf".into()),
            lobes: Some(3),
            align: Some(AlignSetting::Strength(1.0)),
            mode: Some("fast".into()),
            container: Some("ktx2".into()),
            format: Some("f32".into()),
            feature_encoding: Some(encoding.into()),
            ..Settings::default()
        }
        .job(dir.path(), Some(&out), None)
        .unwrap();
        let name = job.input.display().to_string();
        let bytes = std::fs::read(&job.input).unwrap();
        let loaded = load_normals_compact(&name, &bytes, &job.ingest).unwrap();
        assert_eq!(
            matches!(loaded, LoadedNormals::Compact(_)),
            compact,
            "{normals}"
        );
        let outcomes = ndfmap::batch::run(
            std::slice::from_ref(&job),
            &RunOptions {
                force: true,
                ..RunOptions::default()
            },
            &|_| {},
            &|_, _| {},
        );
        assert!(
            matches!(outcomes[0], ndfmap::batch::Outcome::Baked { .. }),
            "{normals}: {:?}",
            outcomes[0]
        );
        // The decoded, untiled path.
        let fname = job.feature.as_ref().unwrap().display().to_string();
        let map = NormalMap::load_memory(&name, &bytes, &job.ingest)
            .unwrap()
            .with_feature_memory(&fname, &std::fs::read(&fname).unwrap(), &job.ingest)
            .unwrap();
        let bake = bake_with(&map, job.method, &job.options).unwrap();
        let q = ndfmap::pack::quantize(&bake, job.format).unwrap();
        let reference = dir.path().join("reference");
        write_bake_hashed(
            &q,
            InputInfo {
                path: Some(name),
                options: job.ingest,
                stats: map.stats().clone(),
            },
            &reference,
            job.container,
            None,
            Some(job.hash().unwrap()),
        )
        .unwrap();
        same_folders(&job.output, &reference, normals);
        std::fs::remove_dir_all(&out).unwrap();
        std::fs::remove_dir_all(&reference).unwrap();
    }
}

#[test]
fn streamed_block_compressed_folders_equal_the_in_memory_writers_files() {
    // BC7 takes whole 4-row blocks: bands of 3 finest rows (fine 1) and of 4 (fine 2: level 1
    // gets 2 rows per band) make the sink hold rows back until a block row is complete; the
    // coarse levels' heights (5, 3) end in partial, padded blocks.
    let (w, h) = (30, 20);
    let (rgb, albedo) = sample(w, h);
    let map = decoded(w, h, &rgb).with_feature(albedo).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let o = options(3, Some(1.0), FitMode::Fast);
    let untiled = bake_with(&map, Method::Vmf, &o).unwrap();
    let codec = ndfmap::compress::Codec::Bc7;
    for container in [Container::Ktx2, Container::Dds] {
        let a = dir.path().join(format!("mem-{container}"));
        write_bake_hashed(&untiled, input(&map), &a, container, Some(codec), None).unwrap();
        for bands in [
            Bands {
                fine: 1,
                band_rows: 3,
            },
            Bands {
                fine: 2,
                band_rows: 4,
            },
        ] {
            let what = format!("{container} {bands:?}");
            let b = dir
                .path()
                .join(format!("streamed-{container}-{}", bands.fine));
            write_folder(
                &Map::Full(&map),
                Method::Vmf,
                &o,
                Format::F32,
                container,
                Some(codec),
                &b,
                input(&map),
                None,
                Some(bands),
                &mut |_| true,
            )
            .unwrap();
            same_folders(&a, &b, &what);
        }
    }
    // A codec the lobes do not fit is refused before any work, as in memory.
    let e = write_folder(
        &Map::Full(&map),
        Method::Vmf,
        &o,
        Format::F32,
        Container::Ktx2,
        Some(ndfmap::compress::Codec::Bc6h),
        &dir.path().join("refused"),
        input(&map),
        None,
        None,
        &mut |_| true,
    )
    .unwrap_err();
    assert!(e.to_string().contains("bc6h"), "{e}");
    assert!(!dir.path().join("refused").exists());
}
