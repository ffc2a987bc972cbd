//! KTX2 and DDS containers (issue 19, item 1) checked by independent readers: the `ktx2`
//! crate's `Reader` (header, level index, data-format descriptor, key/value data) and the
//! `ddsfile` crate (DX10 header, MIP data); the level bytes must equal the in-memory bake
//! packed by `pack::pack_level` (uncompressed) or `compress::encode_level` (blocks), and
//! block-compressed levels decoded by `bcdec_rs` must equal `compress::round_trip`.

mod common;

use ndfmap::bake::{Bake, BakeOptions, Method};
use ndfmap::compress::Codec;
use ndfmap::container::{Container, texture_file, write_bake};
use ndfmap::format::Format;
use ndfmap::ingest::IngestOptions;
use ndfmap::output::{InputInfo, Manifest};
use std::path::Path;

/// The built-in sample, 13×9 (odd sizes: levels 13×9, 6×4, 3×2, 1×1).
fn map() -> ndfmap::NormalMap {
    let m = ndfmap::procedural::generate(16, 3).map;
    let v: Vec<glam::Vec3> = (0..9)
        .flat_map(|y| (0..13).map(move |x| (x, y)))
        .map(|(x, y)| m.normal(x, y))
        .collect();
    ndfmap::NormalMap::from_vectors(
        13,
        9,
        v,
        ndfmap::ingest::Addressing::Wrap,
        ndfmap::ingest::BadNormals::Repair,
    )
    .unwrap()
}

fn input(map: &ndfmap::NormalMap) -> InputInfo {
    InputInfo {
        path: None,
        options: IngestOptions::default(),
        stats: map.stats().clone(),
    }
}

fn bakes() -> Vec<Bake> {
    let map = map();
    let vmf = BakeOptions {
        lobes: 2,
        align: Some(1.0),
        ..BakeOptions::default()
    };
    let sh = BakeOptions {
        lmax: 2,
        ..BakeOptions::default()
    };
    vec![
        ndfmap::methods::bake_with(&map, Method::Vmf, &vmf).unwrap(),
        ndfmap::methods::bake_with(&map, Method::Olano, &BakeOptions::default()).unwrap(),
        ndfmap::methods::bake_with(&map, Method::Sh, &sh).unwrap(),
    ]
}

fn manifest(dir: &Path) -> Manifest {
    serde_json::from_str(&std::fs::read_to_string(dir.join("manifest.json")).unwrap()).unwrap()
}

/// The bake's level `k` of texture `t` packed as a GPU upload takes it (little-endian host).
fn packed(b: &Bake, t: usize, k: usize) -> Vec<u8> {
    let mut buf = vec![0u8; ndfmap::pack::packed_len(b, k, b.format)];
    ndfmap::pack::pack_level(b, t, k, b.format, &mut buf).unwrap();
    buf
}

#[test]
fn ktx2_files_read_back_by_the_ktx2_crate_hold_the_bake() {
    let map = map();
    for base in bakes() {
        for format in Format::ALL {
            let b = ndfmap::pack::quantize(&base, format).unwrap();
            let dir = tempfile::tempdir().unwrap();
            let out = dir.path().join("bake");
            write_bake(&b, input(&map), &out, Container::Ktx2, None).unwrap();
            let m = manifest(&out);
            assert_eq!(m.texel_format, format);
            let (want_format, bits, sfloat) = match format {
                Format::F32 => (ktx2::Format::R32G32B32A32_SFLOAT, 32, true),
                Format::F16 => (ktx2::Format::R16G16B16A16_SFLOAT, 16, true),
                Format::Unorm16 => (ktx2::Format::R16G16B16A16_UNORM, 16, false),
                Format::Unorm8 => (ktx2::Format::R8G8B8A8_UNORM, 8, false),
            };
            let mut listed = vec!["manifest.json".to_string()];
            for (t, info) in b.textures.iter().enumerate() {
                assert_eq!(info_files(&m, t), vec![format!("{}.ktx2", info.name)]);
                listed.push(format!("{}.ktx2", info.name));
                let bytes = std::fs::read(out.join(format!("{}.ktx2", info.name))).unwrap();
                assert_eq!(bytes, texture_file(&b, t, Container::Ktx2, None).unwrap());
                let r = ktx2::Reader::new(&bytes[..]).unwrap();
                let h = r.header();
                assert_eq!(h.format, Some(want_format), "{} {format}", b.method);
                assert_eq!((h.pixel_width, h.pixel_height), (13, 9));
                assert_eq!((h.pixel_depth, h.layer_count, h.face_count), (0, 0, 1));
                assert_eq!(h.level_count as usize, b.level_count());
                assert_eq!(h.type_size, bits / 8);
                assert!(h.supercompression_scheme.is_none());
                // The data-format descriptor: linear RGBA, never sRGB, four samples.
                let dfd = r.basic_dfd().expect("a basic DFD block");
                assert_eq!(dfd.transfer_function, Some(ktx2::TransferFunction::Linear));
                assert_eq!(dfd.color_model, Some(ktx2::ColorModel::RGBSDA));
                assert_eq!(dfd.sample_information.len(), 4);
                for s in &dfd.sample_information {
                    assert_eq!(s.bit_length.get() as u32, bits);
                    let float = s
                        .channel_type_qualifiers
                        .contains(ktx2::dfd::ChannelTypeQualifiers::FLOAT);
                    assert_eq!(float, sfloat);
                }
                // Every level equals the bake, packed.
                let levels: Vec<_> = r.levels().collect();
                for (k, level) in levels.iter().enumerate() {
                    assert_eq!(level.data, &packed(&b, t, k)[..], "{} L{k}", info.name);
                    assert_eq!(level.uncompressed_byte_length as usize, level.data.len());
                }
                // Key/value metadata names the method, texture, channels and encoding.
                let kv: std::collections::HashMap<&str, &[u8]> = r.key_value_data().collect();
                let text = |k: &str| std::str::from_utf8(kv[k]).unwrap().trim_end_matches('\0');
                assert_eq!(text("ndfmap.method"), b.method.name());
                assert_eq!(text("ndfmap.texture"), info.name);
                assert_eq!(text("ndfmap.channels"), info.channels.join(","));
                assert!(text("ndfmap.encoding").starts_with(format.name()));
                assert!(text("KTXwriter").starts_with("ndfmap "));
                assert_eq!(text("KTXorientation"), "rd");
            }
            // The folder holds the manifest and the files it lists, nothing else.
            let mut names: Vec<String> = std::fs::read_dir(&out)
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect();
            names.sort();
            listed.sort();
            assert_eq!(names, listed);
        }
    }
}

fn info_files(m: &Manifest, t: usize) -> Vec<String> {
    m.textures[t].files.clone()
}

#[test]
fn dds_files_read_back_by_ddsfile_hold_the_bake() {
    use ddsfile::{AlphaMode, D3D10ResourceDimension, Dds, DxgiFormat};
    let map = map();
    for base in bakes() {
        for format in Format::ALL {
            let b = ndfmap::pack::quantize(&base, format).unwrap();
            let dir = tempfile::tempdir().unwrap();
            let out = dir.path().join("bake");
            write_bake(&b, input(&map), &out, Container::Dds, None).unwrap();
            let m = manifest(&out);
            for (t, info) in m.textures.iter().enumerate() {
                assert_eq!(info.files, vec![format!("{}.dds", info.name)]);
                let bytes = std::fs::read(out.join(&info.files[0])).unwrap();
                let dds = Dds::read(&bytes[..]).unwrap();
                let want = match format {
                    Format::F32 => DxgiFormat::R32G32B32A32_Float,
                    Format::F16 => DxgiFormat::R16G16B16A16_Float,
                    Format::Unorm16 => DxgiFormat::R16G16B16A16_UNorm,
                    Format::Unorm8 => DxgiFormat::R8G8B8A8_UNorm,
                };
                assert_eq!(dds.get_dxgi_format(), Some(want));
                let h10 = dds.header10.as_ref().unwrap();
                assert_eq!(h10.resource_dimension, D3D10ResourceDimension::Texture2D);
                assert_eq!(h10.array_size, 1);
                assert_eq!(h10.alpha_mode, AlphaMode::Custom);
                assert_eq!((dds.header.width, dds.header.height), (13, 9));
                assert_eq!(dds.get_num_mipmap_levels() as usize, b.level_count());
                let all: Vec<u8> = (0..b.level_count())
                    .flat_map(|k| packed(&b, t, k))
                    .collect();
                assert_eq!(dds.get_data(0).unwrap(), &all[..]);
            }
        }
    }
}

#[test]
fn block_compressed_files_hold_the_encoders_blocks_and_decode_to_the_round_trip() {
    let map = map();
    let olano = &bakes()[1];
    for (codec, vk, dxgi) in [
        (
            Codec::Bc7,
            ktx2::Format::BC7_UNORM_BLOCK,
            ddsfile::DxgiFormat::BC7_UNorm,
        ),
        (
            Codec::Bc6h,
            ktx2::Format::BC6H_UFLOAT_BLOCK,
            ddsfile::DxgiFormat::BC6H_UF16,
        ),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let (k_dir, d_dir) = (dir.path().join("k"), dir.path().join("d"));
        write_bake(olano, input(&map), &k_dir, Container::Ktx2, Some(codec)).unwrap();
        write_bake(olano, input(&map), &d_dir, Container::Dds, Some(codec)).unwrap();
        let m = manifest(&k_dir);
        assert_eq!(m.compression.as_deref(), Some(codec.name()));
        assert_eq!(m.texel_format, codec.shading_format());
        let seen = ndfmap::compress::round_trip(olano, codec).unwrap();
        for (t, texture) in olano.textures.iter().enumerate() {
            let bytes = std::fs::read(k_dir.join(format!("{}.ktx2", texture.name))).unwrap();
            let r = ktx2::Reader::new(&bytes[..]).unwrap();
            assert_eq!(r.header().format, Some(vk));
            assert_eq!(r.header().type_size, 1);
            let dfd = r.basic_dfd().unwrap();
            assert_eq!(dfd.transfer_function, Some(ktx2::TransferFunction::Linear));
            assert_eq!(
                dfd.texel_block_dimensions.map(|d| d.get()),
                [4, 4, 1, 1],
                "4×4 blocks"
            );
            let dds = ddsfile::Dds::read(
                &std::fs::read(d_dir.join(format!("{}.dds", texture.name))).unwrap()[..],
            )
            .unwrap();
            assert_eq!(dds.get_dxgi_format(), Some(dxgi));
            let mut dds_data = dds.get_data(0).unwrap();
            for (k, level) in r.levels().enumerate() {
                let (w, h) = olano.sizes[k];
                let blocks = ndfmap::compress::encode_level(
                    "t",
                    w,
                    h,
                    &texture.levels[k],
                    texture.ranges,
                    texture.uses_alpha(),
                    codec,
                )
                .unwrap();
                assert_eq!(level.data, &blocks[..]);
                assert_eq!(
                    level.data.len(),
                    w.div_ceil(4) as usize * h.div_ceil(4) as usize * 16
                );
                assert_eq!(&dds_data[..blocks.len()], &blocks[..]);
                dds_data = &dds_data[blocks.len()..];
                let decoded =
                    ndfmap::compress::decode_level(level.data, w, h, texture.ranges, codec)
                        .unwrap();
                assert_eq!(decoded, seen.textures[t].levels[k]);
            }
            assert!(dds_data.is_empty());
        }
    }
}

#[test]
fn container_bytes_do_not_depend_on_the_thread_count() {
    let map = map();
    let b = &bakes()[0];
    let write = |threads: usize, container: Container, codec: Option<Codec>| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("bake");
        pool.install(|| write_bake(b, input(&map), &out, container, codec).unwrap());
        let mut files: Vec<(String, Vec<u8>)> = std::fs::read_dir(&out)
            .unwrap()
            .map(|e| {
                let e = e.unwrap();
                (
                    e.file_name().to_string_lossy().into_owned(),
                    std::fs::read(e.path()).unwrap(),
                )
            })
            .collect();
        files.sort();
        files
    };
    for (container, codec) in [
        (Container::Ktx2, None),
        (Container::Dds, None),
        (Container::Ktx2, Some(Codec::Bc7)),
    ] {
        let one = write(1, container, codec);
        assert_eq!(one.len(), b.textures.len() + 1);
        assert_eq!(one, write(4, container, codec), "{container} {codec:?}");
    }
}

#[test]
fn impossible_combinations_are_refused_before_any_work_naming_texture_and_format() {
    use ndfmap::container::check;
    // (container, method, lobes, colour, format, codec, words the error must contain)
    let refused = [
        (
            Container::Exr,
            Method::Olano,
            0,
            Format::F32,
            Codec::Bc7,
            ["exr", "bc7"],
        ),
        (
            Container::Ktx2,
            Method::Vmf,
            6,
            Format::F32,
            Codec::Bc6h,
            ["'lobe0'", "bc6h"],
        ),
        (
            Container::Dds,
            Method::Lean,
            0,
            Format::F32,
            Codec::Bc7,
            ["'slopes'", "bc7"],
        ),
        (
            Container::Dds,
            Method::Vmf,
            2,
            Format::F32,
            Codec::Bc6hBc4,
            ["bc6h+bc4", "bc6h+bc4"],
        ),
        (
            Container::Ktx2,
            Method::Vmf,
            2,
            Format::F16,
            Codec::Bc7,
            ["f16", "bc7"],
        ),
    ];
    for (container, method, lobes, format, codec, words) in refused {
        let e = check(container, method, lobes, false, format, Some(codec))
            .unwrap_err()
            .to_string();
        assert!(words.iter().all(|w| e.contains(w)), "{e}");
    }
    let colour_bc7 = check(
        Container::Ktx2,
        Method::Vmf,
        6,
        true,
        Format::F32,
        Some(Codec::Bc7),
    );
    assert!(colour_bc7.is_ok());
    // The same through the command line: one line, exit non-zero, no folder written.
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o");
    let run = common::ndfmap(&[
        "bake",
        "no-such-map.png", // refused before the input is even opened
        "-m",
        "vmf",
        "--lobes",
        "2",
        "--container",
        "ktx2",
        "--compress",
        "bc6h",
        "-o",
        out.to_str().unwrap(),
    ]);
    common::assert_one_line_error(&run, &["bc6h", "'lobe0'"]);
    assert!(!out.exists());
}

/// A KTX2 or DDS file streamed a band of rows at a time, bands in reverse order and levels
/// coarsest first (as a tiled bake finishes them), from a description of the bake without its
/// levels, is byte-identical to the in-memory `texture_file` of the whole bake, in every
/// uncompressed format; rows outside a level and partial rows are refused.
#[test]
fn streamed_files_equal_in_memory_files() {
    use ndfmap::container::StreamedFile;
    let dir = tempfile::tempdir().unwrap();
    for bake in bakes() {
        for format in [Format::F32, Format::F16, Format::Unorm16, Format::Unorm8] {
            let Ok(b) = ndfmap::pack::quantize(&bake, format) else {
                continue; // unbounded textures in unorm formats
            };
            let mut described = b.clone();
            for t in &mut described.textures {
                t.levels.clear();
            }
            for container in [Container::Ktx2, Container::Dds] {
                for t in 0..b.textures.len() {
                    let path = dir.path().join(format!("t{t}.{container}"));
                    let f = StreamedFile::create(&path, &described, t, container).unwrap();
                    for k in (0..b.sizes.len()).rev() {
                        let (w, h) = b.sizes[k];
                        let rows: Vec<u32> = (0..h).step_by(2).collect();
                        for &r in rows.iter().rev() {
                            let end = (r + 2).min(h);
                            let band =
                                &b.textures[t].levels[k][(r * w) as usize..(end * w) as usize];
                            f.write_rows(k, r, band).unwrap();
                        }
                    }
                    drop(f);
                    let streamed = std::fs::read(&path).unwrap();
                    let whole = texture_file(&b, t, container, None).unwrap();
                    assert!(
                        streamed == whole,
                        "{} {format} {container} texture {t}",
                        b.method
                    );
                }
            }
        }
    }
    let b = &bakes()[1];
    let path = dir.path().join("bad.ktx2");
    let f = StreamedFile::create(&path, b, 0, Container::Ktx2).unwrap();
    let (w, h) = b.sizes[0];
    assert!(f.write_rows(0, h, &vec![[0.0; 4]; w as usize]).is_err());
    assert!(f.write_rows(0, 0, &vec![[0.0; 4]; w as usize - 1]).is_err());
    assert!(f.write_rows(b.sizes.len(), 0, &[]).is_err());
    assert!(StreamedFile::create(&path, b, 0, Container::Exr).is_err());
    // Block-compressed files take whole 4-row blocks (the level's last rows excepted).
    let bc7 = StreamedFile::create_blocks(&path, b, 0, Container::Ktx2, Some(Codec::Bc7)).unwrap();
    let row = vec![[0.0; 4]; w as usize];
    assert!(bc7.write_rows(0, 2, &row).is_err());
    assert!(h > 4 && bc7.write_rows(0, 0, &row).is_err());
    let rest = (h - h % 4) as usize;
    let tail = vec![[0.0; 4]; w as usize * (h as usize - rest)];
    assert!(bc7.write_rows(0, rest as u32, &tail).is_ok());
}
