//! Tests of normal-map ingest through the public API. Every input file is generated here (with
//! the `image` and `exr` crates, or by hand for malformed headers) in a temporary folder.
//!
//! Tolerances:
//! - Lossless integer formats: the test quantizes each unit normal n to c = round((n + 1)/2 ·
//!   max); dequantizing, v = 2c/max − 1, is then within 1/max of n per component (1/255 for 8
//!   bits, 1/65535 for 16). The decoded normal must equal normalize(v) to within 1e-6 per
//!   component (f32 rounding only).
//! - Half-float EXR: expected = normalize(f16(n)) to within 1e-6; float EXR/TIFF: normalize(n)
//!   to within 1e-6.
//! - JPEG (lossy): 16×16 solid-colour blocks at quality 100; the decoded normal within 4/255
//!   per component (two 8-bit quantization steps of the [−1, 1] domain) of normalize(v), the
//!   lossless expectation. The observed error is 0.0088 (1.1 steps), from YCbCr rounding.

use exr::prelude::f16;
use glam::Vec3;
use ndfmap::Error;
use ndfmap::ingest::{
    BadNormals, Channels, Encoding, FeatureEncoding, GreenChannel, IngestOptions, NormalMap,
    Samples,
};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

const W: u32 = 13;
const H: u32 = 7;

/// Deterministic unit normals in the upper hemisphere (z ≥ cos 1.2 ≈ 0.36), varied azimuths.
fn normals(w: u32, h: u32) -> Vec<Vec3> {
    (0..w * h)
        .map(|i| {
            let phi = i as f32 * 2.399_963; // golden angle
            let theta = ((i * 7919) % 97) as f32 / 96.0 * 1.2;
            Vec3::new(
                theta.sin() * phi.cos(),
                theta.sin() * phi.sin(),
                theta.cos(),
            )
        })
        .collect()
}

fn q8(v: f32) -> u8 {
    ((v + 1.0) * 0.5 * 255.0).round() as u8
}

fn dq8(c: u8) -> f32 {
    2.0 * c as f32 / 255.0 - 1.0
}

fn q16(v: f32) -> u16 {
    ((v + 1.0) * 0.5 * 65535.0).round() as u16
}

fn dq16(c: u16) -> f32 {
    2.0 * c as f32 / 65535.0 - 1.0
}

/// Independent reference for the sRGB transfer function.
fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// z reconstructed from x and y, as documented.
fn reconstruct(x: f32, y: f32) -> Vec3 {
    let s = x * x + y * y;
    if s > 1.0 {
        Vec3::new(x, y, 0.0) / s.sqrt()
    } else {
        Vec3::new(x, y, (1.0 - s).sqrt())
    }
}

fn dir() -> tempfile::TempDir {
    tempfile::tempdir().expect("temporary folder")
}

fn opts() -> IngestOptions {
    IngestOptions::default()
}

/// Asserts each decoded normal is within `tol` (per component) of the normalized expectation.
fn assert_normals(map: &NormalMap, expected: &[Vec3], tol: f32, label: &str) {
    assert_eq!(map.normals().len(), expected.len(), "{label}: texel count");
    for (i, (&got, &want)) in map.normals().iter().zip(expected).enumerate() {
        let want = want.normalize();
        let err = (got - want).abs().max_element();
        assert!(
            err <= tol,
            "{label}: texel {i} (x={}, y={}): got {got}, want {want}, error {err} > {tol}",
            i as u32 % map.width(),
            i as u32 / map.width()
        );
        assert!(
            (got.length() - 1.0).abs() < 1e-5,
            "{label}: texel {i} not unit"
        );
    }
}

/// Quantizes normals to 8-bit RGB(A) samples and returns them with the dequantized vectors.
fn encode8(ns: &[Vec3], alpha: bool) -> (Vec<u8>, Vec<Vec3>) {
    let mut bytes = Vec::new();
    let mut expected = Vec::new();
    for n in ns {
        let c = [q8(n.x), q8(n.y), q8(n.z)];
        let v = Vec3::new(dq8(c[0]), dq8(c[1]), dq8(c[2]));
        assert!((v - *n).abs().max_element() <= 1.0 / 255.0 + 1e-6);
        bytes.extend_from_slice(&c);
        if alpha {
            bytes.push(200);
        }
        expected.push(v);
    }
    (bytes, expected)
}

/// Quantizes normals to 16-bit RGB(A) samples and returns them with the dequantized vectors.
fn encode16(ns: &[Vec3], alpha: bool) -> (Vec<u16>, Vec<Vec3>) {
    let mut samples = Vec::new();
    let mut expected = Vec::new();
    for n in ns {
        let c = [q16(n.x), q16(n.y), q16(n.z)];
        let v = Vec3::new(dq16(c[0]), dq16(c[1]), dq16(c[2]));
        assert!((v - *n).abs().max_element() <= 1.0 / 65535.0 + 1e-6);
        samples.extend_from_slice(&c);
        if alpha {
            samples.push(40000);
        }
        expected.push(v);
    }
    (samples, expected)
}

/// Writes an 8-bit RGB or RGBA file in the format of `name`'s extension, loads it back.
fn round_trip8(name: &str, alpha: bool) {
    let tmp = dir();
    let path = tmp.path().join(name);
    let ns = normals(W, H);
    let (bytes, expected) = encode8(&ns, alpha);
    if alpha {
        image::RgbaImage::from_raw(W, H, bytes)
            .unwrap()
            .save(&path)
            .unwrap();
    } else {
        image::RgbImage::from_raw(W, H, bytes)
            .unwrap()
            .save(&path)
            .unwrap();
    }
    let map = NormalMap::load(&path, &opts()).unwrap();
    assert_eq!((map.width(), map.height()), (W, H));
    assert_normals(&map, &expected, 1e-6, name);
    let s = map.stats();
    assert_eq!(s.source_channels, if alpha { 4 } else { 3 }, "{name}");
    assert_eq!(s.source_bits, 8, "{name}");
    assert_eq!(s.encoding, Encoding::Unorm, "{name}");
    assert!(!s.reconstructed_z, "{name}");
    assert_eq!(s.bad_total(), 0, "{name}");
}

/// Writes a 16-bit RGB or RGBA file in the format of `name`'s extension, loads it back.
fn round_trip16(name: &str, alpha: bool) {
    let tmp = dir();
    let path = tmp.path().join(name);
    let ns = normals(W, H);
    let (samples, expected) = encode16(&ns, alpha);
    if alpha {
        image::ImageBuffer::<image::Rgba<u16>, _>::from_raw(W, H, samples)
            .unwrap()
            .save(&path)
            .unwrap();
    } else {
        image::ImageBuffer::<image::Rgb<u16>, _>::from_raw(W, H, samples)
            .unwrap()
            .save(&path)
            .unwrap();
    }
    let map = NormalMap::load(&path, &opts()).unwrap();
    assert_normals(&map, &expected, 1e-6, name);
    let s = map.stats();
    assert_eq!(s.source_channels, if alpha { 4 } else { 3 }, "{name}");
    assert_eq!(s.source_bits, 16, "{name}");
    assert_eq!(s.encoding, Encoding::Unorm, "{name}");
}

#[test]
fn png_8bit_rgb_and_rgba() {
    round_trip8("n.png", false);
    round_trip8("n.png", true);
}

#[test]
fn png_16bit_rgb_and_rgba() {
    round_trip16("n.png", false);
    round_trip16("n.png", true);
}

#[test]
fn tga_8bit_rgb_and_rgba() {
    round_trip8("n.tga", false);
    round_trip8("n.tga", true);
}

#[test]
fn tiff_8bit_and_16bit() {
    round_trip8("n.tif", false);
    round_trip8("n.tiff", true);
    round_trip16("n.tif", false);
    round_trip16("n.tif", true);
}

#[test]
fn tiff_float_is_snorm() {
    let tmp = dir();
    let path = tmp.path().join("n.tif");
    let ns = normals(W, H);
    let data: Vec<f32> = ns.iter().flat_map(|n| n.to_array()).collect();
    image::Rgb32FImage::from_raw(W, H, data)
        .unwrap()
        .save(&path)
        .unwrap();
    let map = NormalMap::load(&path, &opts()).unwrap();
    assert_normals(&map, &ns, 1e-6, "float tiff");
    let s = map.stats();
    assert_eq!((s.source_channels, s.source_bits), (3, 32));
    assert_eq!(s.encoding, Encoding::Snorm);
}

#[test]
fn jpeg_lossy_round_trip() {
    // 4×4 blocks of 16×16 texels, one normal per block: JPEG's 8×8 DCT and 2×2 chroma
    // subsampling then see flat colour, and only colour-conversion rounding remains.
    let blocks = normals(4, 4);
    let (w, h) = (64u32, 64u32);
    let mut bytes = Vec::new();
    let mut expected = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let n = blocks[(y / 16 * 4 + x / 16) as usize];
            let c = [q8(n.x), q8(n.y), q8(n.z)];
            bytes.extend_from_slice(&c);
            expected.push(Vec3::new(dq8(c[0]), dq8(c[1]), dq8(c[2])));
        }
    }
    let tmp = dir();
    let path = tmp.path().join("n.jpg");
    let mut file = std::fs::File::create(&path).unwrap();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut file, 100)
        .encode(&bytes, w, h, image::ExtendedColorType::Rgb8)
        .unwrap();
    drop(file);
    let map = NormalMap::load(&path, &opts()).unwrap();
    // Measured: 0.0088 (1.1 quantization steps of 2/255); allowed: 2 steps.
    assert_normals(&map, &expected, 4.0 / 255.0, "jpeg");
    assert_eq!(map.stats().source_bits, 8);
    assert_eq!(map.stats().source_channels, 3);
}

/// Writes an RGB EXR with samples of type `T` (f16 or f32).
fn write_exr_rgb<T: exr::prelude::IntoSample + Copy + Sync>(
    path: &Path,
    w: usize,
    h: usize,
    px: &[[T; 3]],
) {
    exr::prelude::write_rgb_file(path, w, h, |x, y| {
        let p = px[y * w + x];
        (p[0], p[1], p[2])
    })
    .unwrap();
}

/// Writes an EXR with only R and G channels.
fn write_exr_rg<T: exr::prelude::IntoSample + Copy + Sync>(
    path: &Path,
    w: usize,
    h: usize,
    px: &[[T; 2]],
) {
    use exr::prelude::*;
    let channels = SpecificChannels::build()
        .with_channel("R")
        .with_channel("G")
        .with_pixel_fn(|Vec2(x, y)| {
            let p = px[y * w + x];
            (p[0], p[1])
        });
    Image::from_channels((w, h), channels)
        .write()
        .to_file(path)
        .unwrap();
}

#[test]
fn exr_half_and_float_rgb() {
    let tmp = dir();
    let ns = normals(W, H);
    let (w, h) = (W as usize, H as usize);

    let half: Vec<[f16; 3]> = ns.iter().map(|n| n.to_array().map(f16::from_f32)).collect();
    let expected: Vec<Vec3> = half
        .iter()
        .map(|p| Vec3::from_array(p.map(f16::to_f32)))
        .collect();
    let path = tmp.path().join("half.exr");
    write_exr_rgb(&path, w, h, &half);
    let map = NormalMap::load(&path, &opts()).unwrap();
    assert_normals(&map, &expected, 1e-6, "half exr");
    let s = map.stats();
    assert_eq!((s.source_channels, s.source_bits), (3, 16));
    assert_eq!(s.encoding, Encoding::Snorm);
    assert!(!s.reconstructed_z);

    let float: Vec<[f32; 3]> = ns.iter().map(|n| n.to_array()).collect();
    let path = tmp.path().join("float.exr");
    write_exr_rgb(&path, w, h, &float);
    let map = NormalMap::load(&path, &opts()).unwrap();
    assert_normals(&map, &ns, 1e-6, "float exr");
    assert_eq!(
        (map.stats().source_channels, map.stats().source_bits),
        (3, 32)
    );
}

#[test]
fn exr_rg_only_reconstructs_z() {
    let tmp = dir();
    let ns = normals(W, H);
    let (w, h) = (W as usize, H as usize);

    let half: Vec<[f16; 2]> = ns
        .iter()
        .map(|n| [f16::from_f32(n.x), f16::from_f32(n.y)])
        .collect();
    let expected: Vec<Vec3> = half
        .iter()
        .map(|p| reconstruct(p[0].to_f32(), p[1].to_f32()))
        .collect();
    let path = tmp.path().join("rg_half.exr");
    write_exr_rg(&path, w, h, &half);
    let map = NormalMap::load(&path, &opts()).unwrap();
    assert_normals(&map, &expected, 1e-6, "half rg exr");
    let s = map.stats();
    assert_eq!((s.source_channels, s.source_bits), (2, 16));
    assert!(s.reconstructed_z);

    let float: Vec<[f32; 2]> = ns.iter().map(|n| [n.x, n.y]).collect();
    let path = tmp.path().join("rg_float.exr");
    write_exr_rg(&path, w, h, &float);
    let map = NormalMap::load(&path, &opts()).unwrap();
    assert_normals(&map, &ns, 1e-6, "float rg exr");
    assert_eq!(
        (map.stats().source_channels, map.stats().source_bits),
        (2, 32)
    );
    assert!(map.stats().reconstructed_z);

    // xyz cannot be read from two channels.
    let xyz = IngestOptions {
        channels: Channels::Xyz,
        ..opts()
    };
    assert!(matches!(
        NormalMap::load(&path, &xyz),
        Err(Error::UnsupportedLayout { .. })
    ));
}

#[test]
fn exr_without_r_and_g_is_unsupported() {
    use exr::prelude::*;
    let tmp = dir();
    let path = tmp.path().join("y.exr");
    let channels = SpecificChannels::build()
        .with_channel("Y")
        .with_pixel_fn(|_: Vec2<usize>| (0.5f32,));
    Image::from_channels((4, 4), channels)
        .write()
        .to_file(&path)
        .unwrap();
    match NormalMap::load(&path, &opts()) {
        Err(ndfmap::Error::UnsupportedLayout { layout, .. }) => {
            assert!(layout.contains("[Y]"), "{layout}")
        }
        other => panic!("expected UnsupportedLayout, got {other:?}"),
    }
}

#[test]
fn directx_negates_green() {
    let tmp = dir();
    let path = tmp.path().join("n.png");
    let ns = normals(W, H);
    let (bytes, expected) = encode8(&ns, false);
    image::RgbImage::from_raw(W, H, bytes)
        .unwrap()
        .save(&path)
        .unwrap();
    let gl = NormalMap::load(&path, &opts()).unwrap();
    let dx_opts = IngestOptions {
        green: GreenChannel::DirectX,
        ..opts()
    };
    let dx = NormalMap::load(&path, &dx_opts).unwrap();
    let flipped: Vec<Vec3> = expected
        .iter()
        .map(|v| *v * Vec3::new(1.0, -1.0, 1.0))
        .collect();
    assert_normals(&gl, &expected, 1e-6, "opengl");
    assert_normals(&dx, &flipped, 1e-6, "directx");
}

/// A grey + alpha image holds x and y only when the caller says so (`channels = xy`); under
/// `auto` it is refused (issue 13: it is far more often a height map with a mask).
#[test]
fn luma_alpha_png_reconstructs_z_with_channels_xy() {
    let tmp = dir();
    let path = tmp.path().join("xy.png");
    let ns = normals(W, H);
    let mut bytes = Vec::new();
    let mut expected = Vec::new();
    for n in &ns {
        let (cx, cy) = (q8(n.x), q8(n.y));
        bytes.extend_from_slice(&[cx, cy]);
        expected.push(reconstruct(dq8(cx), dq8(cy)));
    }
    image::GrayAlphaImage::from_raw(W, H, bytes)
        .unwrap()
        .save(&path)
        .unwrap();
    match NormalMap::load(&path, &opts()) {
        Err(Error::UnsupportedLayout { layout, .. }) => {
            assert!(
                layout.contains("grey + alpha") && layout.contains("xy"),
                "{layout}"
            )
        }
        other => panic!("channels = auto: expected UnsupportedLayout, got {other:?}"),
    }
    let xy = IngestOptions {
        channels: Channels::Xy,
        ..opts()
    };
    let map = NormalMap::load(&path, &xy).unwrap();
    assert_normals(&map, &expected, 1e-6, "luma+alpha png");
    let s = map.stats();
    assert_eq!((s.source_channels, s.source_bits), (2, 8));
    assert!(s.reconstructed_z);
    // DirectX applies before reconstruction: y flips, z is unchanged.
    let dx = NormalMap::load(
        &path,
        &IngestOptions {
            green: GreenChannel::DirectX,
            ..xy
        },
    )
    .unwrap();
    let flipped: Vec<Vec3> = expected
        .iter()
        .map(|v| *v * Vec3::new(1.0, -1.0, 1.0))
        .collect();
    assert_normals(&dx, &flipped, 1e-6, "luma+alpha png, directx");
}

#[test]
fn channels_xy_ignores_blue() {
    // A BC5-style map stored in RG with B = 0: read as xyz, every normal is below the horizon.
    let tmp = dir();
    let path = tmp.path().join("rg.png");
    let ns = normals(W, H);
    let mut bytes = Vec::new();
    let mut expected = Vec::new();
    for n in &ns {
        let (cx, cy) = (q8(n.x), q8(n.y));
        bytes.extend_from_slice(&[cx, cy, 0]);
        expected.push(reconstruct(dq8(cx), dq8(cy)));
    }
    image::RgbImage::from_raw(W, H, bytes)
        .unwrap()
        .save(&path)
        .unwrap();

    let as_xyz = NormalMap::load(&path, &opts()).unwrap();
    assert_eq!(as_xyz.stats().below_horizon.count, (W * H) as u64);
    assert_eq!(as_xyz.stats().below_horizon.first, Some((0, 0)));

    let xy = IngestOptions {
        channels: Channels::Xy,
        ..opts()
    };
    let map = NormalMap::load(&path, &xy).unwrap();
    assert_normals(&map, &expected, 1e-6, "channels xy");
    assert!(map.stats().reconstructed_z);
    assert_eq!(map.stats().source_channels, 3);
    assert_eq!(map.stats().bad_total(), 0);
}

#[test]
fn reconstruction_clamps_outside_unit_disc() {
    // x² + y² > 1: xy normalized, z = 0.
    let samples = [255u8, 255, 0, 128];
    let map = NormalMap::from_samples("xy", 2, 1, 2, Samples::U8(&samples), &opts()).unwrap();
    let h = std::f32::consts::FRAC_1_SQRT_2;
    assert!(
        (map.normal(0, 0) - Vec3::new(h, h, 0.0))
            .abs()
            .max_element()
            < 1e-6
    );
    let x = dq8(0);
    assert!(
        (map.normal(1, 0) - reconstruct(x, dq8(128)))
            .abs()
            .max_element()
            < 1e-6
    );
}

#[test]
fn unorm_and_snorm() {
    let ns = normals(W, H);
    let n = (W * H) as usize;

    // Integer Auto = Unorm.
    let (u16s, expected) = encode16(&ns, false);
    let map = NormalMap::from_samples("u16", W, H, 3, Samples::U16(&u16s), &opts()).unwrap();
    assert_eq!(map.stats().encoding, Encoding::Unorm);
    assert_normals(&map, &expected, 1e-6, "u16 auto");

    // Float Auto = Snorm; float Unorm = 2v − 1.
    let snorm: Vec<f32> = ns.iter().flat_map(|v| v.to_array()).collect();
    let map = NormalMap::from_samples("f32", W, H, 3, Samples::F32(&snorm), &opts()).unwrap();
    assert_eq!(map.stats().encoding, Encoding::Snorm);
    assert_normals(&map, &ns, 1e-6, "f32 auto");
    let unorm: Vec<f32> = snorm.iter().map(|v| (v + 1.0) * 0.5).collect();
    let o = IngestOptions {
        encoding: Encoding::Unorm,
        ..opts()
    };
    let map = NormalMap::from_samples("f32 unorm", W, H, 3, Samples::F32(&unorm), &o).unwrap();
    assert_eq!(map.stats().encoding, Encoding::Unorm);
    assert_normals(&map, &ns, 1e-6, "f32 unorm");

    // Integer Snorm: two's complement, s / 127 (−128 clamps to −1).
    let o = IngestOptions {
        encoding: Encoding::Snorm,
        ..opts()
    };
    let mut bytes = Vec::new();
    let mut expected = Vec::new();
    for v in &ns {
        let s = (*v * 127.0).round();
        bytes.extend(s.to_array().map(|c| c as i8 as u8));
        expected.push(s / 127.0);
    }
    let map = NormalMap::from_samples("i8", W, H, 3, Samples::U8(&bytes), &o).unwrap();
    assert_eq!(map.stats().encoding, Encoding::Snorm);
    assert_normals(&map, &expected, 1e-6, "u8 snorm");
    let map = NormalMap::from_samples("i8 min", 1, 1, 3, Samples::U8(&[128, 0, 127]), &o).unwrap();
    let want = Vec3::new(-1.0, 0.0, 1.0).normalize();
    assert!((map.normal(0, 0) - want).abs().max_element() < 1e-6);

    let s16: Vec<u16> = snorm
        .iter()
        .map(|v| (v * 32767.0).round() as i16 as u16)
        .collect();
    let expected: Vec<Vec3> = s16
        .chunks(3)
        .map(|c| Vec3::new(c[0] as i16 as f32, c[1] as i16 as f32, c[2] as i16 as f32) / 32767.0)
        .collect();
    let map = NormalMap::from_samples("i16", W, H, 3, Samples::U16(&s16), &o).unwrap();
    assert_normals(&map, &expected, 1e-6, "u16 snorm");
    assert_eq!(map.normals().len(), n);
}

#[test]
fn statistics_of_bad_normals_in_float_exr() {
    // 4×3 float EXR: zero-length at (1,0), NaN at (2,1) and (0,2), below horizon at (3,1) and
    // straight down at (1,2); the rest are tilted unit normals, one of them of length 2.
    let (w, h) = (4usize, 3usize);
    let t = Vec3::new(0.6, 0.0, 0.8);
    let mut px = vec![t.to_array(); w * h];
    px[1] = [0.0, 0.0, 0.0];
    px[w + 2] = [f32::NAN, 0.0, 1.0];
    px[2 * w] = [0.0, f32::NAN, f32::NAN];
    px[w + 3] = [0.0, 0.6, -0.8];
    px[2 * w + 1] = [0.0, 0.0, -1.0];
    px[3] = [0.0, 0.0, 2.0];
    let tmp = dir();
    let path = tmp.path().join("bad.exr");
    write_exr_rgb(&path, w, h, &px);

    let map = NormalMap::load(&path, &opts()).unwrap();
    let s = map.stats();
    assert_eq!(
        (s.zero_length.count, s.zero_length.first),
        (1, Some((1, 0)))
    );
    assert_eq!((s.nan.count, s.nan.first), (2, Some((2, 1))));
    assert_eq!(
        (s.below_horizon.count, s.below_horizon.first),
        (2, Some((3, 1)))
    );
    assert_eq!(s.bad_total(), 5);
    // Repairs: zero-length and NaN → +Z; below horizon → onto the horizon, same azimuth;
    // straight down → +Z.
    assert_eq!(map.normal(1, 0), Vec3::Z);
    assert_eq!(map.normal(2, 1), Vec3::Z);
    assert_eq!(map.normal(0, 2), Vec3::Z);
    assert!((map.normal(3, 1) - Vec3::Y).abs().max_element() < 1e-6);
    assert_eq!(map.normal(1, 2), Vec3::Z);
    assert_eq!(map.normal(3, 0), Vec3::Z);
    // Mean z: 6 tilted (0.8), 5 at +Z (zero, 2 NaN, straight down, length 2), 1 on the horizon.
    let mean_z = (6.0 * 0.8 + 5.0) / 12.0;
    assert!((s.mean_z - mean_z).abs() < 1e-6, "mean z {}", s.mean_z);
    // Mean length over finite non-zero vectors: 8 of length 1 and one of length 2.
    assert!(
        (s.mean_length - 10.0 / 9.0).abs() < 1e-6,
        "mean length {}",
        s.mean_length
    );
    for n in map.normals() {
        assert!(n.is_finite() && n.z >= 0.0 && (n.length() - 1.0).abs() < 1e-6);
    }

    // Reject names the first bad texel in scan-line order.
    let reject = IngestOptions {
        bad_normals: BadNormals::Reject,
        ..opts()
    };
    match NormalMap::load(&path, &reject) {
        Err(Error::BadNormals {
            count, kind, x, y, ..
        }) => assert_eq!((count, kind, x, y), (5, "zero length", 1, 0)),
        other => panic!("expected BadNormals, got {other:?}"),
    }
}

#[test]
fn reject_reports_first_bad_kind() {
    let reject = IngestOptions {
        bad_normals: BadNormals::Reject,
        ..opts()
    };
    let px = [0.0f32, 0.0, 1.0, 0.5, 0.0, -0.5];
    match NormalMap::from_samples("below", 2, 1, 3, Samples::F32(&px), &reject) {
        Err(Error::BadNormals {
            count, kind, x, y, ..
        }) => assert_eq!((count, kind, x, y), (1, "below the horizon", 1, 0)),
        other => panic!("expected BadNormals, got {other:?}"),
    }
    let px = [0.0f32, 0.0, 1.0, f32::INFINITY, 0.0, 1.0];
    assert!(matches!(
        NormalMap::from_samples("inf", 2, 1, 3, Samples::F32(&px), &reject),
        Err(Error::BadNormals { kind: "NaN", .. })
    ));
}

#[test]
fn from_samples_errors() {
    let o = opts();
    let buf = [128u8; 64];
    assert!(matches!(
        NormalMap::from_samples("short", 4, 4, 3, Samples::U8(&buf[..47]), &o),
        Err(Error::ShortBuffer {
            got: 47,
            needed: 48,
            ..
        })
    ));
    assert!(NormalMap::from_samples("ok", 4, 4, 3, Samples::U8(&buf[..48]), &o).is_ok());
    for channels in [0, 1, 5] {
        assert!(
            matches!(
                NormalMap::from_samples("grey", 4, 4, channels, Samples::U8(&buf), &o),
                Err(Error::UnsupportedLayout { .. })
            ),
            "{channels} channels"
        );
    }
    for (w, h) in [
        (0, 4),
        (4, 0),
        (u32::MAX, u32::MAX),
        (65_536, 65_536),
        (100_000, 1),
    ] {
        assert!(
            matches!(
                NormalMap::from_samples("dims", w, h, 3, Samples::U8(&buf), &o),
                Err(Error::Dimensions { .. })
            ),
            "{w}x{h}"
        );
    }
    let xyz = IngestOptions {
        channels: Channels::Xyz,
        ..o
    };
    assert!(matches!(
        NormalMap::from_samples("xy", 4, 4, 2, Samples::U8(&buf), &xyz),
        Err(Error::UnsupportedLayout { .. })
    ));
    // 4 channels: alpha is ignored.
    let map =
        NormalMap::from_samples("rgba", 1, 1, 4, Samples::U8(&[128, 128, 255, 0]), &o).unwrap();
    assert_eq!(map.stats().source_channels, 4);
    assert!(map.normal(0, 0).z > 0.999);
}

#[test]
fn feature_image_srgb_and_linear() {
    let tmp = dir();
    let normal_path = tmp.path().join("n.png");
    let (bytes, _) = encode8(&normals(W, H), false);
    image::RgbImage::from_raw(W, H, bytes)
        .unwrap()
        .save(&normal_path)
        .unwrap();

    let colour: Vec<u8> = (0..W * H * 4).map(|i| (i * 37 % 256) as u8).collect();
    let feature_path = tmp.path().join("albedo.png");
    image::RgbaImage::from_raw(W, H, colour.clone())
        .unwrap()
        .save(&feature_path)
        .unwrap();

    let map = NormalMap::load(&normal_path, &opts())
        .unwrap()
        .with_feature_file(&feature_path, &opts())
        .unwrap();
    let feature = map.feature().unwrap();
    assert_eq!(feature.len(), (W * H) as usize);
    for (f, c) in feature.iter().zip(colour.chunks(4)) {
        for k in 0..3 {
            let want = srgb_to_linear(c[k] as f32 / 255.0);
            assert!((f[k] - want).abs() < 1e-6, "srgb {f:?} vs {c:?}");
        }
        assert!((f[3] - c[3] as f32 / 255.0).abs() < 1e-6, "alpha is linear");
    }
    // A known value: sRGB 128/255 is 0.2158605 linear.
    let mid = NormalMap::from_samples("n", 1, 1, 3, Samples::U8(&[128, 128, 255]), &opts())
        .unwrap()
        .with_feature_samples("mid", 1, 1, 1, Samples::U8(&[128]), &opts())
        .unwrap();
    let f = mid.feature().unwrap()[0];
    assert!((f[0] - 0.215_860_5).abs() < 1e-6 && f[0] == f[1] && f[1] == f[2]);
    assert_eq!(f[3], 1.0);

    // Linear: divided by the maximum only.
    let linear = IngestOptions {
        feature_encoding: FeatureEncoding::Linear,
        ..opts()
    };
    let map = NormalMap::load(&normal_path, &opts())
        .unwrap()
        .with_feature_file(&feature_path, &linear)
        .unwrap();
    for (f, c) in map.feature().unwrap().iter().zip(colour.chunks(4)) {
        for k in 0..4 {
            assert!((f[k] - c[k] as f32 / 255.0).abs() < 1e-6);
        }
    }

    // 16-bit grey+alpha: replicated, sRGB on grey, alpha linear.
    let ga: Vec<u16> = vec![32768, 65535];
    let map = NormalMap::from_samples("n", 1, 1, 3, Samples::U8(&[128, 128, 255]), &opts())
        .unwrap()
        .with_feature_samples("ga", 1, 1, 2, Samples::U16(&ga), &opts())
        .unwrap();
    let f = map.feature().unwrap()[0];
    let g = srgb_to_linear(32768.0 / 65535.0);
    assert!((f[0] - g).abs() < 1e-6 && f[0] == f[1] && f[1] == f[2]);
    assert_eq!(f[3], 1.0);

    // Float features are linear whatever the encoding option says.
    let map = NormalMap::from_samples("n", 1, 1, 3, Samples::U8(&[128, 128, 255]), &opts())
        .unwrap()
        .with_feature_samples("f", 1, 1, 3, Samples::F32(&[0.5, 0.25, 2.0]), &opts())
        .unwrap();
    assert_eq!(map.feature().unwrap()[0], [0.5, 0.25, 2.0, 1.0]);
}

#[test]
fn feature_from_exr_is_linear() {
    let tmp = dir();
    let path = tmp.path().join("albedo.exr");
    exr::prelude::write_rgba_file(&path, 2, 1, |x, _| {
        (0.5f32 + x as f32, 0.25f32, 0.125f32, 0.75f32)
    })
    .unwrap();
    let map = NormalMap::from_samples("n", 2, 1, 3, Samples::U8(&[128; 6]), &opts())
        .unwrap()
        .with_feature_file(&path, &opts())
        .unwrap();
    assert_eq!(
        map.feature().unwrap(),
        &[[0.5, 0.25, 0.125, 0.75], [1.5, 0.25, 0.125, 0.75]]
    );
}

#[test]
fn feature_size_mismatch() {
    let tmp = dir();
    let path = tmp.path().join("albedo.png");
    image::RgbImage::new(W + 1, H).save(&path).unwrap();
    let map = NormalMap::from_samples(
        "n",
        W,
        H,
        3,
        Samples::U8(&vec![200; (W * H * 3) as usize]),
        &opts(),
    )
    .unwrap();
    match map.clone().with_feature_file(&path, &opts()) {
        Err(Error::FeatureSize {
            feature_width,
            feature_height,
            width,
            height,
            ..
        }) => assert_eq!(
            (feature_width, feature_height, width, height),
            (W + 1, H, W, H)
        ),
        other => panic!("expected FeatureSize, got {other:?}"),
    }
    assert!(matches!(
        map.clone()
            .with_feature_samples("f", W, H, 3, Samples::U8(&[0; 10]), &opts()),
        Err(Error::ShortBuffer { .. })
    ));
    assert!(matches!(
        map.with_feature_samples("f", W, H, 5, Samples::U8(&[0; 1000]), &opts()),
        Err(Error::UnsupportedLayout { .. })
    ));
}

#[test]
fn format_detected_by_content() {
    let tmp = dir();
    let ns = normals(W, H);
    let (bytes, expected) = encode8(&ns, false);
    // A PNG named .tga, and one with no extension.
    let png = tmp.path().join("n.png");
    image::RgbImage::from_raw(W, H, bytes)
        .unwrap()
        .save(&png)
        .unwrap();
    for name in ["really_png.tga", "noext", "really_png.exr"] {
        let path = tmp.path().join(name);
        std::fs::copy(&png, &path).unwrap();
        let map = NormalMap::load(&path, &opts()).unwrap();
        assert_normals(&map, &expected, 1e-6, name);
    }
    // An EXR named .bin.
    let exr = tmp.path().join("n.bin");
    let float: Vec<[f32; 3]> = ns.iter().map(|n| n.to_array()).collect();
    write_exr_rgb(&exr, W as usize, H as usize, &float);
    let map = NormalMap::load(&exr, &opts()).unwrap();
    assert_normals(&map, &ns, 1e-6, "exr named .bin");
}

/// Deterministic pseudo-random bytes.
fn noise(n: usize, seed: u64) -> Vec<u8> {
    let mut s = seed;
    (0..n)
        .map(|_| {
            s = s
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (s >> 33) as u8
        })
        .collect()
}

fn write(tmp: &tempfile::TempDir, name: &str, bytes: &[u8]) -> PathBuf {
    let path = tmp.path().join(name);
    std::fs::write(&path, bytes).unwrap();
    path
}

fn expect_decode_error(path: &Path) {
    match NormalMap::load(path, &opts()) {
        Err(Error::Decode { path: p, message }) => {
            assert_eq!(p, path);
            assert!(!message.is_empty());
        }
        other => panic!("{}: expected Decode, got {other:?}", path.display()),
    }
}

#[test]
fn corrupt_truncated_empty_and_missing_files() {
    let tmp = dir();
    for name in [
        "noise.png",
        "noise.tga",
        "noise.tif",
        "noise.jpg",
        "noise.exr",
        "noise.dat",
    ] {
        let path = write(&tmp, name, &noise(4096, 7));
        expect_decode_error(&path);
    }
    // EXR magic followed by garbage.
    let mut bytes = vec![0x76, 0x2f, 0x31, 0x01];
    bytes.extend(noise(1000, 3));
    expect_decode_error(&write(&tmp, "garbage.exr", &bytes));

    // Truncated PNG: a valid file cut in half.
    let png = tmp.path().join("full.png");
    let (rgb, _) = encode8(&normals(64, 64), false);
    image::RgbImage::from_raw(64, 64, rgb)
        .unwrap()
        .save(&png)
        .unwrap();
    let full = std::fs::read(&png).unwrap();
    expect_decode_error(&write(&tmp, "half.png", &full[..full.len() / 2]));

    // Truncated EXR.
    let exr = tmp.path().join("full.exr");
    let float: Vec<[f32; 3]> = normals(64, 64).iter().map(|n| n.to_array()).collect();
    write_exr_rgb(&exr, 64, 64, &float);
    let full = std::fs::read(&exr).unwrap();
    expect_decode_error(&write(&tmp, "half.exr", &full[..full.len() / 2]));

    // Empty file.
    expect_decode_error(&write(&tmp, "empty.png", &[]));

    // Missing file and a folder.
    let missing = tmp.path().join("missing.png");
    assert!(matches!(
        NormalMap::load(&missing, &opts()),
        Err(Error::Read { path, .. }) if path == missing
    ));
    assert!(matches!(
        NormalMap::load(tmp.path(), &opts()),
        Err(Error::Read { .. })
    ));
    assert!(matches!(
        NormalMap::from_samples("n", 1, 1, 3, Samples::U8(&[1, 2, 3]), &opts())
            .unwrap()
            .with_feature_file(&missing, &opts()),
        Err(Error::Read { .. })
    ));
}

#[test]
fn grey_image_is_unsupported() {
    let tmp = dir();
    for (name, sixteen) in [("h.png", false), ("h16.png", true), ("h.tga", false)] {
        let path = tmp.path().join(name);
        if sixteen {
            image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::new(8, 8)
                .save(&path)
                .unwrap();
        } else {
            image::GrayImage::new(8, 8).save(&path).unwrap();
        }
        match NormalMap::load(&path, &opts()) {
            Err(Error::UnsupportedLayout { layout, .. }) => {
                assert!(layout.contains("height"), "{layout}")
            }
            other => panic!("{name}: expected UnsupportedLayout, got {other:?}"),
        }
    }
}

/// CRC-32 (ISO-HDLC), as PNG chunks need.
fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= b as u32;
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

fn png_chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
    out.extend((data.len() as u32).to_be_bytes());
    let start = out.len();
    out.extend(kind);
    out.extend(data);
    let crc = crc32(&out[start..]);
    out.extend(crc.to_be_bytes());
}

fn assert_dimensions_error(path: &Path, want: (u64, u64)) {
    let start = Instant::now();
    let result = NormalMap::load(path, &opts());
    let elapsed = start.elapsed();
    match result {
        Err(Error::Dimensions { width, height, .. }) => assert_eq!((width, height), want),
        other => panic!("{}: expected Dimensions, got {other:?}", path.display()),
    }
    assert!(
        elapsed < Duration::from_secs(2),
        "{}: took {elapsed:?}",
        path.display()
    );
}

#[test]
fn absurd_dimensions_fail_fast() {
    let tmp = dir();

    // PNG declaring 100000×100000 RGB8 (30 GB), with a tiny IDAT.
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = Vec::new();
    ihdr.extend(100_000u32.to_be_bytes());
    ihdr.extend(100_000u32.to_be_bytes());
    ihdr.extend([8, 2, 0, 0, 0]);
    png_chunk(&mut png, b"IHDR", &ihdr);
    png_chunk(
        &mut png,
        b"IDAT",
        &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01],
    );
    png_chunk(&mut png, b"IEND", &[]);
    assert_dimensions_error(&write(&tmp, "huge.png", &png), (100_000, 100_000));

    // TGA declaring 65535×65535 (each side allowed, the texel count is not).
    let mut tga = vec![0u8, 0, 2, 0, 0, 0, 0, 0, 0, 0, 0, 0];
    tga.extend(65_535u16.to_le_bytes());
    tga.extend(65_535u16.to_le_bytes());
    tga.extend([24, 0x20]);
    assert_dimensions_error(&write(&tmp, "huge.tga", &tga), (65_535, 65_535));

    // EXR whose data window is patched to 100000×100000.
    let exr = tmp.path().join("small.exr");
    write_exr_rgb(&exr, 2, 2, &[[0.0f32, 0.0, 1.0]; 4]);
    let mut bytes = std::fs::read(&exr).unwrap();
    let key = b"dataWindow\0box2i\0";
    let at = bytes
        .windows(key.len())
        .position(|w| w == key)
        .expect("dataWindow attribute")
        + key.len()
        + 4;
    bytes[at..at + 16].copy_from_slice(
        &[0i32, 0, 99_999, 99_999]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect::<Vec<_>>(),
    );
    assert_dimensions_error(&write(&tmp, "huge.exr", &bytes), (100_000, 100_000));
}

#[test]
fn mutated_files_never_panic() {
    // Valid small files of every format with random bytes overwritten: every load must return
    // (Ok or a typed error) without panicking.
    let tmp = dir();
    let ns = normals(16, 16);
    let (rgb, _) = encode8(&ns, false);
    let img = image::RgbImage::from_raw(16, 16, rgb).unwrap();
    let mut files = Vec::new();
    for name in ["m.png", "m.tga", "m.tif", "m.jpg"] {
        let path = tmp.path().join(name);
        img.save(&path).unwrap();
        files.push((name, std::fs::read(&path).unwrap()));
    }
    let exr = tmp.path().join("m.exr");
    let float: Vec<[f32; 3]> = ns.iter().map(|n| n.to_array()).collect();
    write_exr_rgb(&exr, 16, 16, &float);
    files.push(("m.exr", std::fs::read(&exr).unwrap()));

    let start = Instant::now();
    for (name, original) in &files {
        for round in 0..60u64 {
            let mut bytes = original.clone();
            let r = noise(16, round * 31 + 1);
            for k in 0..4 {
                let at = u32::from_le_bytes([r[4 * k], r[4 * k + 1], r[4 * k + 2], 0]) as usize
                    % bytes.len();
                bytes[at] = r[4 * k + 3];
            }
            let path = write(&tmp, &format!("mut_{round}_{name}"), &bytes);
            let _ = NormalMap::load(&path, &opts());
        }
    }
    assert!(start.elapsed() < Duration::from_secs(60));
}

#[test]
fn load_memory_reads_every_format_as_load_reads_the_file() {
    let tmp = dir();
    let ns = normals(W, H);
    let (rgb, _) = encode8(&ns, false);
    let img = image::RgbImage::from_raw(W, H, rgb).unwrap();
    let mut files = Vec::new();
    for name in ["n.png", "n.tga", "n.tif"] {
        let path = tmp.path().join(name);
        img.save(&path).unwrap();
        files.push(path);
    }
    let exr = tmp.path().join("n.exr");
    let float: Vec<[f32; 3]> = ns.iter().map(|n| n.to_array()).collect();
    write_exr_rgb(&exr, W as usize, H as usize, &float);
    files.push(exr);
    for path in &files {
        let name = path.file_name().unwrap().to_str().unwrap();
        let bytes = std::fs::read(path).unwrap();
        let from_file = NormalMap::load(path, &opts()).unwrap();
        let from_memory = NormalMap::load_memory(name, &bytes, &opts()).unwrap();
        assert_eq!(from_memory.normals(), from_file.normals(), "{name}");
        assert_eq!(from_memory.stats(), from_file.stats(), "{name}");
        // The feature counterpart.
        let with = from_file.clone().with_feature_file(path, &opts()).unwrap();
        let with_memory = from_file
            .with_feature_memory(name, &bytes, &opts())
            .unwrap();
        assert_eq!(with.feature(), with_memory.feature(), "{name}");
    }
    // TGA has no signature: without its extension the bytes are not recognized.
    let tga = std::fs::read(tmp.path().join("n.tga")).unwrap();
    assert!(NormalMap::load_memory("buffer", &tga, &opts()).is_err());
    // Errors name the buffer.
    for bytes in [&[][..], &noise(512, 3)[..]] {
        match NormalMap::load_memory("in-memory.png", bytes, &opts()) {
            Err(Error::Decode { path, .. }) => assert_eq!(path, Path::new("in-memory.png")),
            other => panic!("expected Decode, got {other:?}"),
        }
    }
}

/// Fuzzing finding 1 (fuzz/README.md): an OpenEXR file whose scan line lies outside the level
/// being read makes `exr` 1.74.2 panic inside its decoder (a debug assertion; without debug
/// assertions the line is written at a wrong place or an index panics). Ingest's decoder guard
/// turns such a panic into a decode error; nothing unwinds into the caller. Since ingest reads
/// only the channels it uses (issue 13), `exr`'s channel-selecting reader skips the stray line,
/// so the file may also load.
#[test]
fn fuzz_finding_exr_line_outside_its_level_is_a_decode_error() {
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/fuzz/exr-line-outside-level.exr");
    let bytes = std::fs::read(&path).unwrap();
    for result in [
        NormalMap::load(&path, &opts()),
        NormalMap::load_memory("f.exr", &bytes, &opts()),
    ] {
        match result {
            Err(Error::Decode { message, .. }) => {
                assert!(
                    message.contains("the decoder failed unexpectedly"),
                    "{message}"
                )
            }
            Ok(map) => assert_eq!((map.width(), map.height()), (8, 8)),
            other => panic!("expected a map or a decode error, got {other:?}"),
        }
    }
}

/// `CompactNormals` (issue 19's tiled bakes) decodes each texel to exactly the bits
/// `NormalMap::from_samples` stores, with the same statistics, for 8- and 16-bit samples,
/// unorm and snorm, RGB, RGBA and two-channel maps, either green convention, including zero,
/// below-horizon and reconstructed-z texels; the reject policy refuses the same maps.
#[test]
fn compact_normals_decode_the_same_bits_as_normal_maps() {
    use ndfmap::ingest::{BadNormals, Channels, CompactNormals, Encoding, GreenChannel, Samples};
    let (w, h) = (37u32, 23u32);
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    for channels in [2u32, 3, 4] {
        let n = (w * h * channels) as usize;
        let mut u8s: Vec<u8> = (0..n).map(|_| next() as u8).collect();
        // A zero texel under snorm, one pointing down under unorm.
        u8s[..channels as usize].fill(0);
        let u16s: Vec<u16> = (0..n).map(|_| next() as u16).collect();
        for encoding in [Encoding::Unorm, Encoding::Snorm] {
            for green in [GreenChannel::OpenGl, GreenChannel::DirectX] {
                for chan in [Channels::Auto, Channels::Xy] {
                    for bad in [BadNormals::Repair, BadNormals::Reject] {
                        let opts = ndfmap::IngestOptions {
                            encoding,
                            green,
                            channels: chan,
                            bad_normals: bad,
                            ..Default::default()
                        };
                        for samples in [Samples::U8(&u8s), Samples::U16(&u16s)] {
                            let full = ndfmap::NormalMap::from_samples(
                                "m", w, h, channels, samples, &opts,
                            );
                            let compact =
                                CompactNormals::from_samples("m", w, h, channels, samples, &opts);
                            match (full, compact) {
                                (Ok(f), Ok(c)) => {
                                    assert_eq!(f.stats(), c.stats());
                                    for (i, n) in f.normals().iter().enumerate() {
                                        let m = c.normal(i);
                                        assert_eq!(
                                            n.to_array().map(f32::to_bits),
                                            m.to_array().map(f32::to_bits),
                                            "texel {i}"
                                        );
                                    }
                                }
                                (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string()),
                                (a, b) => panic!("{:?} vs {:?}", a.err(), b.err()),
                            }
                        }
                    }
                }
            }
        }
    }
}

/// `CompactFeature` (the bounded-memory bake's colour image) converts each texel to exactly the
/// bits `NormalMap::with_feature_samples` stores, with the same repair counts, for 8-, 16-bit
/// and float samples, 1 to 4 channels, sRGB and linear; a wrong size is the same error.
#[test]
fn compact_features_convert_the_same_bits_as_normal_maps() {
    use ndfmap::ingest::{BadNormals, CompactFeature, FeatureEncoding, Samples};
    let (w, h) = (19u32, 11u32);
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let normals: Vec<glam::Vec3> = (0..w * h).map(|_| glam::Vec3::Z).collect();
    for channels in 1u32..=4 {
        let n = (w * h * channels) as usize;
        let u8s: Vec<u8> = (0..n).map(|_| next() as u8).collect();
        let u16s: Vec<u16> = (0..n).map(|_| next() as u16).collect();
        // Floats with a negative and a NaN value to repair.
        let mut f32s: Vec<f32> = (0..n).map(|_| (next() % 1000) as f32 / 700.0).collect();
        f32s[1] = -0.5;
        f32s[n - 1] = f32::NAN;
        for encoding in [FeatureEncoding::Srgb, FeatureEncoding::Linear] {
            for samples in [Samples::U8(&u8s), Samples::U16(&u16s), Samples::F32(&f32s)] {
                let opts = ndfmap::IngestOptions {
                    feature_encoding: encoding,
                    bad_normals: BadNormals::Repair,
                    ..Default::default()
                };
                let map = ndfmap::NormalMap::from_vectors(
                    w,
                    h,
                    normals.clone(),
                    Default::default(),
                    BadNormals::Repair,
                )
                .unwrap()
                .with_feature_samples("f", w, h, channels, samples, &opts)
                .unwrap();
                let c = CompactFeature::from_samples("f", w, h, channels, samples, &opts).unwrap();
                for (i, t) in map.feature().unwrap().iter().enumerate() {
                    assert_eq!(
                        t.map(f32::to_bits),
                        c.texel(i).map(f32::to_bits),
                        "{channels} channels {encoding:?} texel {i}"
                    );
                }
                let compact = ndfmap::ingest::CompactNormals::from_samples(
                    "n",
                    w,
                    h,
                    3,
                    Samples::U8(&[128u8, 128, 255].repeat((w * h) as usize)),
                    &opts,
                )
                .unwrap();
                let stats = compact.stats_with(Some(&c));
                assert_eq!(stats.feature_nan, map.stats().feature_nan);
                assert_eq!(stats.feature_negative, map.stats().feature_negative);
                let expected = matches!(samples, Samples::F32(_)) as u64;
                assert_eq!(stats.feature_nan.count, expected);
            }
        }
    }
    let c = CompactFeature::from_samples("f", 2, 2, 3, Samples::U8(&[0; 12]), &Default::default())
        .unwrap();
    let full = ndfmap::NormalMap::from_vectors(
        3,
        2,
        vec![glam::Vec3::Z; 6],
        Default::default(),
        BadNormals::Repair,
    )
    .unwrap()
    .with_feature_samples("f", 2, 2, 3, Samples::U8(&[0; 12]), &Default::default())
    .unwrap_err();
    assert_eq!(
        c.check_size("f", (3, 2)).unwrap_err().to_string(),
        full.to_string()
    );
}
