//! Tests of the C API called from Rust: every entry point with good and bad arguments.

use std::cell::Cell;

thread_local! {
    /// When set, the next guarded entry point on this thread panics inside its guard.
    static INJECT_PANIC: Cell<bool> = const { Cell::new(false) };
}

/// Panics (once) if a test asked for it: stands for a bug inside any entry point.
pub(super) fn maybe_inject_panic() {
    if INJECT_PANIC.with(|p| p.replace(false)) {
        panic!("injected test panic");
    }
}

use super::bake::*;
use super::brdf::*;
use super::map::*;
use super::shader::*;
use super::*;
use crate::bake::Method;
use crate::format::Format;
use crate::ingest::{IngestOptions, NormalMap, Samples};
use crate::methods::bake_with;

/// The C API's environment lights and the shader lights they stand for.
const ENV_LIGHTS: [(ndf_light, crate::glsl::ShaderLight); 3] = [
    (
        NDF_LIGHT_ENV_PREFILTERED,
        crate::glsl::ShaderLight::EnvPrefiltered,
    ),
    (NDF_LIGHT_ENV_SH, crate::glsl::ShaderLight::EnvSh),
    (
        NDF_LIGHT_POINT_AND_ENV_PREFILTERED,
        crate::glsl::ShaderLight::PointAndEnvPrefiltered,
    ),
];
use std::ffi::{CStr, c_char, c_int, c_void};
use std::ptr::{null, null_mut};

/// The thread's last error message.
fn message() -> String {
    // SAFETY: ndf_last_error_message returns a NUL-terminated string valid until the next failure.
    unsafe { CStr::from_ptr(ndf_last_error_message()) }
        .to_string_lossy()
        .into_owned()
}

/// `check!(ndf_function(args) => Status, "words")`: the call returns `ndf_status::Status`; on
/// failure the thread's message starts with the function's name and contains `words`.
macro_rules! check {
    ($f:ident($($arg:expr),* $(,)?) => $status:ident, $words:expr) => {
        expect($f($($arg),*), ndf_status::$status, stringify!($f), $words)
    };
}

/// Asserts `status` is `want` and, for a failure, that the message names `function` and
/// contains `words`.
#[track_caller]
fn expect(status: ndf_status, want: ndf_status, function: &str, words: &str) {
    assert_eq!(status, want, "{function}: {}", message());
    if want != ndf_status::Ok {
        let m = message();
        assert!(m.starts_with(&format!("{function}: ")), "{m}");
        assert!(m.contains(words), "{function}: '{words}' not in '{m}'");
    }
}

/// 8-bit RGB pixels of a small bumpy map.
fn rgb8(w: u32, h: u32) -> Vec<u8> {
    (0..w * h)
        .flat_map(|i| {
            let (x, y) = ((i % w) as f32, (i / w) as f32);
            let n =
                glam::Vec3::new((x * 0.9).sin() * 0.5, (y * 1.3 + x).cos() * 0.4, 1.0).normalize();
            n.to_array()
                .map(|c| ((c * 0.5 + 0.5) * 255.0).round() as u8)
        })
        .collect()
}

const W: u32 = 12;
const H: u32 = 10;

/// A map from `rgb8(W, H)` through the C API.
fn c_map() -> *mut ndf_normal_map {
    let px = rgb8(W, H);
    let opts = ndf_ingest_options_default();
    let mut map = null_mut();
    // SAFETY: valid pixels, options and out-pointer.
    let s = unsafe {
        ndf_normal_map_from_pixels(
            px.as_ptr().cast(),
            px.len(),
            W,
            H,
            3,
            NDF_SAMPLE_UINT8,
            &opts,
            &mut map,
        )
    };
    assert_eq!(s, ndf_status::Ok, "{}", message());
    map
}

/// The same map through the Rust API.
fn rust_map() -> NormalMap {
    let px = rgb8(W, H);
    NormalMap::from_samples(
        "pixels",
        W,
        H,
        3,
        Samples::U8(&px),
        &IngestOptions::default(),
    )
    .unwrap()
}

/// A bake of `c_map()` with `method` (two lobes for the mixtures).
fn c_bake(map: *const ndf_normal_map, method: ndf_method) -> *mut ndf_bake {
    let mut bake = null_mut();
    // SAFETY: a live map, default options, a valid out-pointer.
    let s = unsafe {
        match method {
            NDF_METHOD_VMF => {
                let o = ndf_vmf_options {
                    lobes: 2,
                    ..ndf_vmf_options_default()
                };
                ndf_bake_vmf(map, &o, &mut bake)
            }
            NDF_METHOD_TAN2005 => {
                let o = ndf_tan2005_options {
                    lobes: 2,
                    ..ndf_tan2005_options_default()
                };
                ndf_bake_tan2005(map, &o, &mut bake)
            }
            NDF_METHOD_SH => {
                let o = ndf_sh_options {
                    lmax: 3,
                    ..ndf_sh_options_default()
                };
                ndf_bake_sh(map, &o, &mut bake)
            }
            NDF_METHOD_PBR => ndf_bake_pbr(map, &ndf_pbr_options_default(), &mut bake),
            m => ndf_bake_baseline(map, m, &ndf_baseline_options_default(), &mut bake),
        }
    };
    assert_eq!(s, ndf_status::Ok, "{}", message());
    bake
}

#[test]
fn status_numbers_and_names_are_stable() {
    for (i, s) in STATUSES.iter().enumerate() {
        assert_eq!(*s as u32, i as u32);
        // SAFETY: static NUL-terminated strings.
        let name = unsafe { CStr::from_ptr(ndf_status_str(i as u32)) };
        assert!(name.to_str().unwrap().starts_with("NDF_STATUS_"));
    }
    assert_eq!(ndf_status::Ok as u32, 0);
    assert_eq!(ndf_status::BufferTooSmall as u32, 4);
    assert_eq!(ndf_status::Cancelled as u32, 14);
    assert_eq!(ndf_status::Panic as u32, 15);
    assert_eq!(ndf_status::MemoryBudget as u32, 16);
    assert_eq!(ndf_status::BadFeatures as u32, 17);
    for unknown in [18, 1000, u32::MAX] {
        // SAFETY: as above.
        let name = unsafe { CStr::from_ptr(ndf_status_str(unknown)) };
        assert_eq!(name, c"NDF_STATUS_UNKNOWN");
    }
}

#[test]
fn enumeration_values_name_the_rust_variants() {
    let map = c_map();
    for (value, method) in [
        (NDF_METHOD_PLAIN, Method::Plain),
        (NDF_METHOD_TOKSVIG, Method::Toksvig),
        (NDF_METHOD_LEAN, Method::Lean),
        (NDF_METHOD_OLANO, Method::Olano),
        (NDF_METHOD_TAN2005, Method::Tan2005),
        (NDF_METHOD_VMF, Method::Vmf),
        (NDF_METHOD_SH, Method::Sh),
        (NDF_METHOD_PBR, Method::Pbr),
    ] {
        let bake = c_bake(map, value);
        let mut got = u32::MAX;
        // SAFETY: a live bake and a valid out-pointer.
        unsafe {
            assert_eq!(ndf_bake_method(bake, &mut got), ndf_status::Ok);
            assert_eq!((*bake).bake.method, method);
            ndf_bake_free(bake);
        }
        assert_eq!(got, value);
    }
    // SAFETY: a live map, freed once.
    unsafe { ndf_normal_map_free(map) };
    for (value, format) in [
        (NDF_FORMAT_RGBA_F32, Format::F32),
        (NDF_FORMAT_RGBA_F16, Format::F16),
        (NDF_FORMAT_RGBA_UNORM16, Format::Unorm16),
        (NDF_FORMAT_RGBA_UNORM8, Format::Unorm8),
    ] {
        assert_eq!(
            choose(
                "format",
                value,
                &[Format::F32, Format::F16, Format::Unorm16, Format::Unorm8]
            )
            .ok(),
            Some(format)
        );
    }
}

#[test]
fn pixels_of_every_sample_type_and_alignment_give_the_rust_map() {
    let want = rust_map();
    let px8 = rgb8(W, H);
    let px16: Vec<u16> = px8.iter().map(|&c| c as u16 * 257).collect();
    let pxf: Vec<f32> = px8.iter().map(|&c| c as f32 / 255.0).collect();
    let opts = ndf_ingest_options {
        encoding: NDF_ENCODING_UNORM,
        ..ndf_ingest_options_default()
    };
    let as_bytes16: Vec<u8> = px16.iter().flat_map(|v| v.to_ne_bytes()).collect();
    let as_bytesf: Vec<u8> = pxf.iter().flat_map(|v| v.to_ne_bytes()).collect();
    for (bytes, ty) in [
        (&px8, NDF_SAMPLE_UINT8),
        (&as_bytes16, NDF_SAMPLE_UINT16),
        (&as_bytesf, NDF_SAMPLE_FLOAT32),
    ] {
        for offset in [0, 1] {
            // A copy at `offset` bytes into a buffer: offset 1 is misaligned for u16 and f32.
            let mut buf = vec![0u8; bytes.len() + 1];
            buf[offset..offset + bytes.len()].copy_from_slice(bytes);
            let mut map = null_mut();
            // SAFETY: the buffer holds `bytes.len()` bytes from `offset`.
            let s = unsafe {
                ndf_normal_map_from_pixels(
                    buf[offset..].as_ptr().cast(),
                    bytes.len(),
                    W,
                    H,
                    3,
                    ty,
                    &opts,
                    &mut map,
                )
            };
            expect(s, ndf_status::Ok, "", "");
            // SAFETY: a live map, freed once.
            unsafe {
                let got = &(*map).map;
                for (a, b) in got.normals().iter().zip(want.normals()) {
                    assert!((*a - *b).length() < 1e-6, "type {ty} offset {offset}");
                }
                ndf_normal_map_free(map);
            }
        }
    }
}

#[test]
fn bad_pixel_arguments_are_errors_that_leave_the_out_pointer_alone() {
    let px = rgb8(W, H);
    let opts = ndf_ingest_options_default();
    let sentinel = 0x5a5a as *mut ndf_normal_map;
    let call = |pixels: *const c_void,
                len: usize,
                w: u32,
                h: u32,
                c: u32,
                ty: u32,
                o: *const ndf_ingest_options,
                out: bool| {
        let mut map = sentinel;
        let out_ptr = if out { &mut map as *mut _ } else { null_mut() };
        // SAFETY: every pointer is NULL or valid for what it claims.
        let s = unsafe { ndf_normal_map_from_pixels(pixels, len, w, h, c, ty, o, out_ptr) };
        assert_eq!(map, sentinel, "out-parameter written on failure");
        s
    };
    let p = px.as_ptr().cast();
    macro_rules! bad {
        ($($arg:expr),* => $status:ident, $words:expr) => {
            expect(call($($arg),*), ndf_status::$status, "ndf_normal_map_from_pixels", $words)
        };
    }
    bad!(null(), px.len(), W, H, 3, 0, &opts, true => NullArgument, "pixels is NULL");
    bad!(p, px.len(), W, H, 3, 0, null(), true => NullArgument, "options is NULL");
    bad!(p, px.len(), W, H, 3, 0, &opts, false => NullArgument, "map_out is NULL");
    // One byte short of width × height × channels.
    bad!(p, px.len() - 1, W, H, 3, 0, &opts, true => ShortPixels, "360 are needed");
    bad!(p, px.len(), 0, H, 3, 0, &opts, true => Dimensions, "at least 1");
    // width × height overflows 32 bits (and the supported texel count).
    bad!(p, px.len(), 65536, 65536, 3, 0, &opts, true => Dimensions, "texels");
    bad!(p, px.len(), 70000, 1, 3, 0, &opts, true => Dimensions, "at most 65536");
    bad!(p, px.len(), W, H, 1, 0, &opts, true => UnsupportedLayout, "one channel");
    bad!(p, px.len(), W, H, 9, 0, &opts, true => UnsupportedLayout, "9 channels");
    bad!(p, px.len(), W, H, 3, 3, &opts, true => InvalidArgument, "unknown sample_type value 3");
    bad!(p, usize::MAX, W, H, 3, 0, &opts, true => InvalidArgument, "largest possible");
    for (field, o) in [
        ("green", ndf_ingest_options { green: 2, ..opts }),
        (
            "encoding",
            ndf_ingest_options {
                encoding: 3,
                ..opts
            },
        ),
        (
            "channels",
            ndf_ingest_options {
                channels: 77,
                ..opts
            },
        ),
        (
            "addressing",
            ndf_ingest_options {
                addressing: u32::MAX,
                ..opts
            },
        ),
        (
            "bad_normals",
            ndf_ingest_options {
                bad_normals: 2,
                ..opts
            },
        ),
        (
            "feature_encoding",
            ndf_ingest_options {
                feature_encoding: 2,
                ..opts
            },
        ),
    ] {
        bad!(p, px.len(), W, H, 3, 0, &o, true => InvalidArgument, &format!("unknown {field} value"));
    }
    let small = ndf_ingest_options {
        struct_size: 8,
        ..opts
    };
    bad!(p, px.len(), W, H, 3, 0, &small, true => InvalidArgument, "struct_size is 8");
    // Bad normals rejected: a zero vector (snorm 0, 0, 0).
    let reject = ndf_ingest_options {
        bad_normals: NDF_BAD_NORMALS_REJECT,
        encoding: NDF_ENCODING_SNORM,
        ..opts
    };
    let zero = [0u8; 3];
    bad!(zero.as_ptr().cast(), 3, 1, 1, 3, 0, &reject, true => BadNormals, "zero length");
}

/// `bytes` of a PNG of `rgb8(W, H)`.
fn png() -> Vec<u8> {
    let mut out = std::io::Cursor::new(Vec::new());
    image::RgbImage::from_raw(W, H, rgb8(W, H))
        .unwrap()
        .write_to(&mut out, image::ImageFormat::Png)
        .unwrap();
    out.into_inner()
}

#[test]
fn files_and_memory_load_like_pixels_and_bad_ones_fail_with_their_status() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("n.png");
    std::fs::write(&file, png()).unwrap();
    let c_file = CString::new(file.to_str().unwrap()).unwrap();
    let opts = ndf_ingest_options_default();
    let want = rust_map();
    let data = png();
    let mut from_file = null_mut();
    let mut from_memory = null_mut();
    // SAFETY: valid paths, buffers, options and out-pointers; maps freed once.
    unsafe {
        check!(ndf_normal_map_load_file(c_file.as_ptr(), &opts, &mut from_file) => Ok, "");
        check!(ndf_normal_map_load_memory(data.as_ptr().cast(), data.len(), c"n.png".as_ptr(), &opts, &mut from_memory,) => Ok, "");
        assert_eq!((*from_file).map.normals(), want.normals());
        assert_eq!((*from_memory).map.normals(), want.normals());
        assert_eq!((*from_file).input.path.as_deref(), file.to_str());
        let (mut w, mut h, mut bad) = (0, 0, 1);
        check!(ndf_normal_map_size(from_file, &mut w, &mut h) => Ok, "");
        check!(ndf_normal_map_bad_normal_count(from_file, &mut bad) => Ok, "");
        assert_eq!((w, h, bad), (W, H, 0));
        ndf_normal_map_free(from_file);
        ndf_normal_map_free(from_memory);

        let mut map = null_mut();
        check!(ndf_normal_map_load_file(null(), &opts, &mut map) => NullArgument, "path is NULL");
        check!(ndf_normal_map_load_file(c_file.as_ptr(), null(), &mut map) => NullArgument, "options");
        check!(ndf_normal_map_load_file(c_file.as_ptr(), &opts, null_mut()) => NullArgument, "map_out");
        check!(ndf_normal_map_load_file(c"/no/such/file.png".as_ptr(), &opts, &mut map) => Read, "/no/such/file.png: cannot read");
        let name = c"in-memory.png".as_ptr();
        check!(ndf_normal_map_load_memory(null(), 5, name, &opts, &mut map) => NullArgument, "data is NULL");
        check!(ndf_normal_map_load_memory(data.as_ptr().cast(), data.len(), null(), &opts, &mut map) => NullArgument, "name is NULL");
        check!(ndf_normal_map_load_memory(data.as_ptr().cast(), data.len(), name, null(), &mut map) => NullArgument, "options");
        check!(ndf_normal_map_load_memory(data.as_ptr().cast(), data.len(), name, &opts, null_mut()) => NullArgument, "map_out");
        check!(ndf_normal_map_load_memory(data.as_ptr().cast(), 0, name, &opts, &mut map) => Decode, "in-memory.png: cannot decode image: the file is empty");
        // Every truncation of the file is a clean error.
        for len in 1..data.len() {
            let s = ndf_normal_map_load_memory(data.as_ptr().cast(), len, name, &opts, &mut map);
            // Without its last chunk (IEND, 12 bytes) a PNG still decodes.
            let end_only = len >= data.len() - 12 && s == ndf_status::Ok;
            assert!(s == ndf_status::Decode || end_only, "{len}: {}", message());
            ndf_normal_map_free(map);
            map = null_mut();
        }
        assert!(map.is_null());
    }
}

#[test]
fn a_feature_attaches_from_pixels_files_and_memory_and_a_bad_one_leaves_the_map_alone() {
    let map = c_map();
    let opts = ndf_ingest_options_default();
    let colour = rgb8(W, H);
    let data = png();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("albedo.png");
    std::fs::write(&file, &data).unwrap();
    let c_file = CString::new(file.to_str().unwrap()).unwrap();
    let want = rust_map()
        .with_feature_samples(
            "albedo",
            W,
            H,
            3,
            Samples::U8(&colour),
            &IngestOptions::default(),
        )
        .unwrap();
    // SAFETY: a live map and valid buffers, paths and options; the map is freed once.
    unsafe {
        let px = colour.as_ptr().cast();
        check!(ndf_normal_map_attach_feature_pixels(map, px, colour.len(), W, H, 3, NDF_SAMPLE_UINT8, &opts,) => Ok, "");
        assert_eq!((*map).map.feature(), want.feature());
        check!(ndf_normal_map_attach_feature_file(map, c_file.as_ptr(), &opts) => Ok, "");
        assert_eq!((*map).map.feature(), want.feature());
        check!(ndf_normal_map_attach_feature_memory(map, data.as_ptr().cast(), data.len(), c"a.png".as_ptr(), &opts,) => Ok, "");
        assert_eq!((*map).map.feature(), want.feature());

        check!(ndf_normal_map_attach_feature_pixels(map, px, colour.len(), W + 1, H, 3, 0, &opts) => FeatureSize, "feature image is 13x10");
        check!(ndf_normal_map_attach_feature_pixels(map, px, colour.len() - 1, W, H, 3, 0, &opts) => ShortPixels, "");
        check!(ndf_normal_map_attach_feature_pixels(null_mut(), px, colour.len(), W, H, 3, 0, &opts) => NullArgument, "map is NULL");
        check!(ndf_normal_map_attach_feature_pixels(map, null(), colour.len(), W, H, 3, 0, &opts) => NullArgument, "pixels");
        check!(ndf_normal_map_attach_feature_pixels(map, px, colour.len(), W, H, 3, 9, &opts) => InvalidArgument, "sample_type");
        check!(ndf_normal_map_attach_feature_pixels(map, px, colour.len(), W, H, 3, 0, null()) => NullArgument, "options");
        check!(ndf_normal_map_attach_feature_file(map, c"/no/such.png".as_ptr(), &opts) => Read, "cannot read");
        check!(ndf_normal_map_attach_feature_file(null_mut(), c_file.as_ptr(), &opts) => NullArgument, "map");
        check!(ndf_normal_map_attach_feature_file(map, null(), &opts) => NullArgument, "path");
        check!(ndf_normal_map_attach_feature_file(map, c_file.as_ptr(), null()) => NullArgument, "options");
        check!(ndf_normal_map_attach_feature_memory(map, data.as_ptr().cast(), 10, c"a.png".as_ptr(), &opts,) => Decode, "a.png");
        check!(ndf_normal_map_attach_feature_memory(null_mut(), data.as_ptr().cast(), 10, c"a.png".as_ptr(), &opts,) => NullArgument, "map");
        check!(ndf_normal_map_attach_feature_memory(map, null(), 10, c"a.png".as_ptr(), &opts) => NullArgument, "data");
        check!(ndf_normal_map_attach_feature_memory(map, data.as_ptr().cast(), 10, null(), &opts) => NullArgument, "name");
        check!(ndf_normal_map_attach_feature_memory(map, data.as_ptr().cast(), 10, c"a.png".as_ptr(), null(),) => NullArgument, "options");
        // Failures left the feature as it was.
        assert_eq!((*map).map.feature(), want.feature());

        let (mut w, mut h, mut n) = (0, 0, 0);
        check!(ndf_normal_map_size(null(), &mut w, &mut h) => NullArgument, "map is NULL");
        check!(ndf_normal_map_size(map, null_mut(), &mut h) => NullArgument, "width_out");
        check!(ndf_normal_map_size(map, &mut w, null_mut()) => NullArgument, "height_out");
        assert_eq!((w, h), (0, 0));
        check!(ndf_normal_map_bad_normal_count(null(), &mut n) => NullArgument, "map");
        check!(ndf_normal_map_bad_normal_count(map, null_mut()) => NullArgument, "count_out");
        ndf_normal_map_free(map);
        ndf_normal_map_free(null_mut());
        ndf_bake_free(null_mut());
    }
}

/// Counts progress calls and stops after `stop_after` of them (`c_int::MAX`: never).
struct Recorder {
    seen: Vec<f32>,
    stop_after: usize,
}

unsafe extern "C" fn record(fraction: f32, user_data: *mut c_void) -> c_int {
    // SAFETY: the tests pass a live, otherwise unused Recorder as user data.
    let r = unsafe { &mut *user_data.cast::<Recorder>() };
    r.seen.push(fraction);
    (r.seen.len() <= r.stop_after) as c_int
}

#[test]
fn bakes_equal_the_rust_bakes_and_report_progress() {
    let map = c_map();
    let rust = rust_map();
    let mut r = Recorder {
        seen: Vec::new(),
        stop_after: usize::MAX,
    };
    let o = ndf_vmf_options {
        lobes: 3,
        aligned: 1,
        progress: Some(record),
        progress_user_data: (&mut r as *mut Recorder).cast(),
        ..ndf_vmf_options_default()
    };
    let mut bake = null_mut();
    // SAFETY: a live map, valid options and out-pointer; the bake is freed once.
    unsafe {
        check!(ndf_bake_vmf(map, &o, &mut bake) => Ok, "");
        let want = bake_with(
            &rust,
            Method::Vmf,
            &crate::bake::BakeOptions {
                lobes: 3,
                align: Some(crate::em::AlignmentForm::Appendix.default_strength()),
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!((*bake).bake, want);
        ndf_bake_free(bake);
        // The main text's form (eq 23) is reachable too.
        let o = ndf_vmf_options {
            lobes: 2,
            aligned: 1,
            align_strength: 0.1,
            align_form: NDF_ALIGN_FORM_MAIN_TEXT,
            ..ndf_vmf_options_default()
        };
        check!(ndf_bake_vmf(map, &o, &mut bake) => Ok, "");
        let want = bake_with(
            &rust,
            Method::Vmf,
            &crate::bake::BakeOptions {
                lobes: 2,
                align: Some(0.1),
                align_form: crate::em::AlignmentForm::MainText,
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!((*bake).bake, want);
        ndf_bake_free(bake);
    }
    assert_eq!(r.seen.first(), Some(&0.0));
    assert_eq!(r.seen.last(), Some(&1.0));
    for method in [
        NDF_METHOD_PLAIN,
        NDF_METHOD_TOKSVIG,
        NDF_METHOD_LEAN,
        NDF_METHOD_OLANO,
        NDF_METHOD_TAN2005,
    ] {
        let bake = c_bake(map, method);
        let m = [
            Method::Plain,
            Method::Toksvig,
            Method::Lean,
            Method::Olano,
            Method::Tan2005,
        ][method as usize];
        let opts = crate::bake::BakeOptions {
            lobes: 2,
            align: None,
            ..Default::default()
        };
        // SAFETY: a live bake, freed once.
        unsafe {
            assert_eq!((*bake).bake, bake_with(&rust, m, &opts).unwrap(), "{m}");
            ndf_bake_free(bake);
        }
    }
    // SAFETY: freed once.
    unsafe { ndf_normal_map_free(map) };
}

#[test]
fn pbr_bakes_equal_the_rust_bakes_and_bad_material_maps_make_no_bake() {
    let map = c_map();
    let rust = rust_map();
    let texels = (W * H) as usize;
    let ramp =
        |scale: f32| -> Vec<f32> { (0..texels).map(|i| scale * (i % 7) as f32 / 6.0).collect() };
    let (rough, metal, occl) = (ramp(0.8), ramp(1.0), ramp(0.5));
    let mut r = Recorder {
        seen: Vec::new(),
        stop_after: usize::MAX,
    };
    let o = ndf_pbr_options {
        anisotropic: 1,
        roughness_map: rough.as_ptr(),
        metallic_map: metal.as_ptr(),
        occlusion_map: occl.as_ptr(),
        progress: Some(record),
        progress_user_data: (&mut r as *mut Recorder).cast(),
        ..ndf_pbr_options_default()
    };
    let options = crate::bake::PbrOptions {
        roughness: 0.5,
        anisotropic: true,
        ..Default::default()
    };
    let maps = crate::pbr::PbrMaps {
        roughness: Some(rough.clone()),
        metallic: Some(metal.clone()),
        occlusion: Some(occl.clone()),
    };
    let want = crate::pbr::bake_with_maps(&rust, &options, Some(&maps)).unwrap();
    let sentinel = 0x77 as *mut ndf_bake;
    let mut bake = null_mut();
    // SAFETY: a live map, valid options (maps of W × H floats) and out-pointers; each bake
    // made is freed once.
    unsafe {
        check!(ndf_bake_pbr(map, &o, &mut bake) => Ok, "");
        assert_eq!((*bake).bake, want);
        let mut method = u32::MAX;
        assert_eq!(ndf_bake_method(bake, &mut method), ndf_status::Ok);
        assert_eq!(method, NDF_METHOD_PBR);
        ndf_bake_free(bake);
        // Without maps: the constant roughness, as the Rust bake with none.
        let plain = ndf_pbr_options {
            roughness: 0.3,
            ..ndf_pbr_options_default()
        };
        check!(ndf_bake_pbr(map, &plain, &mut bake) => Ok, "");
        let options = crate::bake::PbrOptions {
            roughness: 0.3,
            ..Default::default()
        };
        let want = crate::pbr::bake_with_maps(&rust, &options, None).unwrap();
        assert_eq!((*bake).bake, want);
        ndf_bake_free(bake);
        // A renderer that never goes grazing: the fit over the pairs scaled into 50°, as the
        // Rust bake over `FitSet::view_range(50)` — and not the full set's bake.
        let narrow = ndf_pbr_options {
            roughness: 0.3,
            fit_max_angle: 50.0,
            ..ndf_pbr_options_default()
        };
        check!(ndf_bake_pbr(map, &narrow, &mut bake) => Ok, "");
        let set = crate::pbr::FitSet::view_range(50.0).unwrap();
        let (by_set, _) =
            crate::pbr::bake_with_set(&rust, &options, None, &set, crate::pbr::Search::Fast, 0)
                .unwrap();
        assert_eq!((*bake).bake.textures, by_set.textures);
        assert_ne!((*bake).bake.textures, want.textures);
        ndf_bake_free(bake);
        // The mean normal held, the roughness fitted: the Rust bake with `mean_normal`.
        let held = ndf_pbr_options {
            roughness: 0.3,
            mean_normal: 1,
            ..ndf_pbr_options_default()
        };
        check!(ndf_bake_pbr(map, &held, &mut bake) => Ok, "");
        let by_mean = crate::pbr::bake_with_maps(
            &rust,
            &crate::bake::PbrOptions {
                mean_normal: true,
                ..options
            },
            None,
        )
        .unwrap();
        assert_eq!((*bake).bake, by_mean);
        assert_ne!((*bake).bake.textures, want.textures);
        ndf_bake_free(bake);
        // Bad options and maps: a status naming the problem, no bake, the out-pointer alone.
        let mut nan = rough.clone();
        nan[5] = f32::NAN;
        let mut high = rough.clone();
        high[0] = 1.5;
        let bad = [
            (
                ndf_pbr_options {
                    roughness: 1.5,
                    ..ndf_pbr_options_default()
                },
                ndf_status::InvalidArgument,
                "roughness 1.5",
            ),
            (
                ndf_pbr_options {
                    fit_max_angle: 10.0,
                    ..ndf_pbr_options_default()
                },
                ndf_status::InvalidArgument,
                "fit max angle 10",
            ),
            (
                ndf_pbr_options {
                    fit_max_angle: f64::NAN,
                    ..ndf_pbr_options_default()
                },
                ndf_status::InvalidArgument,
                "fit max angle NaN",
            ),
            (
                ndf_pbr_options {
                    roughness_map: nan.as_ptr(),
                    ..ndf_pbr_options_default()
                },
                ndf_status::BadFeatures,
                "roughness map",
            ),
            (
                ndf_pbr_options {
                    metallic_map: high.as_ptr(),
                    ..ndf_pbr_options_default()
                },
                ndf_status::BadFeatures,
                "metallic map",
            ),
            (
                ndf_pbr_options {
                    struct_size: 8,
                    ..ndf_pbr_options_default()
                },
                ndf_status::InvalidArgument,
                "ndf_pbr_options_default",
            ),
        ];
        for (options, status, words) in bad {
            let mut out = sentinel;
            expect(
                ndf_bake_pbr(map, &options, &mut out),
                status,
                "ndf_bake_pbr",
                words,
            );
            assert_eq!(out, sentinel, "{words}");
        }
        // Cancelled after the first report.
        let mut c = Recorder {
            seen: Vec::new(),
            stop_after: 1,
        };
        let cancel = ndf_pbr_options {
            progress: Some(record),
            progress_user_data: (&mut c as *mut Recorder).cast(),
            ..ndf_pbr_options_default()
        };
        let mut out = sentinel;
        check!(ndf_bake_pbr(map, &cancel, &mut out) => Cancelled, "cancelled");
        assert_eq!(out, sentinel);
        ndf_normal_map_free(map);
    }
    assert_eq!(r.seen.first(), Some(&0.0));
    assert_eq!(r.seen.last(), Some(&1.0));
}

#[test]
fn bad_bake_arguments_and_a_cancelled_bake_make_no_bake() {
    let map = c_map();
    let sentinel = 0x77 as *mut ndf_bake;
    let vmf = ndf_vmf_options_default();
    let tan = ndf_tan2005_options_default();
    let base = ndf_baseline_options_default();
    let mut out = sentinel;
    // SAFETY: every pointer is NULL or valid for what it claims.
    unsafe {
        check!(ndf_bake_vmf(null(), &vmf, &mut out) => NullArgument, "map is NULL");
        check!(ndf_bake_vmf(map, null(), &mut out) => NullArgument, "options is NULL");
        check!(ndf_bake_vmf(map, &vmf, null_mut()) => NullArgument, "bake_out is NULL");
        for (o, words) in [
            (ndf_vmf_options { lobes: 0, ..vmf }, "lobe count 0"),
            (ndf_vmf_options { lobes: 9, ..vmf }, "lobe count 9"),
            (
                ndf_vmf_options {
                    aligned: 1,
                    align_strength: f64::NAN,
                    ..vmf
                },
                "alignment strength",
            ),
            (
                ndf_vmf_options {
                    aligned: 1,
                    align_strength: -1.0,
                    ..vmf
                },
                "alignment strength",
            ),
            (
                ndf_vmf_options {
                    em_max_iterations: 0,
                    ..vmf
                },
                "EM iterations 0 (expected 1 to 1000)",
            ),
            (
                ndf_vmf_options {
                    em_tolerance: f64::NAN,
                    ..vmf
                },
                "tolerance",
            ),
            (
                ndf_vmf_options {
                    kappa_estimator: 2,
                    ..vmf
                },
                "unknown kappa_estimator value 2",
            ),
            (
                ndf_vmf_options {
                    aligned: 1,
                    align_form: 2,
                    ..vmf
                },
                "unknown align_form value 2",
            ),
            (
                ndf_vmf_options {
                    struct_size: 0,
                    ..vmf
                },
                "struct_size is 0",
            ),
        ] {
            check!(ndf_bake_vmf(map, &o, &mut out) => InvalidArgument, words);
        }
        check!(ndf_bake_tan2005(null(), &tan, &mut out) => NullArgument, "map");
        check!(ndf_bake_tan2005(map, null(), &mut out) => NullArgument, "options");
        check!(ndf_bake_tan2005(map, &tan, null_mut()) => NullArgument, "bake_out");
        let o = ndf_tan2005_options { lobes: 100, ..tan };
        check!(ndf_bake_tan2005(map, &o, &mut out) => InvalidArgument, "lobe count 100");
        let o = ndf_tan2005_options {
            struct_size: size_of::<ndf_vmf_options>(),
            ..tan
        };
        check!(ndf_bake_tan2005(map, &o, &mut out) => InvalidArgument, "struct_size");
        check!(ndf_bake_baseline(null(), 0, &base, &mut out) => NullArgument, "map");
        check!(ndf_bake_baseline(map, 0, null(), &mut out) => NullArgument, "options");
        check!(ndf_bake_baseline(map, 0, &base, null_mut()) => NullArgument, "bake_out");
        check!(ndf_bake_baseline(map, 8, &base, &mut out) => InvalidArgument, "unknown method value 8");
        check!(ndf_bake_baseline(map, NDF_METHOD_PBR, &base, &mut out) => InvalidArgument, "use ndf_bake_pbr");
        check!(ndf_bake_baseline(map, NDF_METHOD_SH, &base, &mut out) => InvalidArgument, "use ndf_bake_sh");
        check!(ndf_bake_baseline(map, NDF_METHOD_VMF, &base, &mut out) => InvalidArgument, "use ndf_bake_vmf");
        // Cancelled at the first report, and half-way.
        for stop_after in [0, 3] {
            let mut r = Recorder {
                seen: Vec::new(),
                stop_after,
            };
            let user = (&mut r as *mut Recorder).cast();
            let o = ndf_vmf_options {
                lobes: 2,
                progress: Some(record),
                progress_user_data: user,
                ..vmf
            };
            check!(ndf_bake_vmf(map, &o, &mut out) => Cancelled, "cancelled");
            assert_eq!(r.seen.len(), stop_after + 1);
            let o = ndf_baseline_options {
                progress: Some(record),
                progress_user_data: user,
                ..base
            };
            r.seen.clear();
            check!(ndf_bake_baseline(map, NDF_METHOD_LEAN, &o, &mut out) => Cancelled, "cancelled");
            r.seen.clear();
            let o = ndf_tan2005_options {
                lobes: 2,
                progress: Some(record),
                progress_user_data: user,
                ..tan
            };
            check!(ndf_bake_tan2005(map, &o, &mut out) => Cancelled, "cancelled");
        }
        assert_eq!(out, sentinel, "no bake handed out");
        ndf_normal_map_free(map);
    }
}

#[test]
fn queries_describe_the_bake_and_refuse_bad_arguments() {
    let map = c_map();
    let bake = c_bake(map, NDF_METHOD_VMF);
    // SAFETY: every pointer is NULL or valid for what it claims; freed once.
    unsafe {
        let b = &(*bake).bake;
        let (mut n, mut w, mut h) = (0u32, 0u32, 0u32);
        check!(ndf_bake_lobe_count(bake, &mut n) => Ok, "");
        assert_eq!(n, 2);
        check!(ndf_bake_level_count(bake, &mut n) => Ok, "");
        assert_eq!(n as usize, b.level_count());
        for level in 0..n {
            check!(ndf_bake_level_size(bake, level, &mut w, &mut h) => Ok, "");
            assert_eq!((w, h), b.sizes[level as usize]);
        }
        check!(ndf_bake_texture_count(bake, &mut n) => Ok, "");
        assert_eq!(n, 2);
        for t in 0..n {
            let mut name = null();
            check!(ndf_bake_texture_name(bake, t, &mut name) => Ok, "");
            assert_eq!(
                CStr::from_ptr(name).to_str().unwrap(),
                b.textures[t as usize].name
            );
            for c in 0..4 {
                let (mut meaning, mut range) = (null(), 9);
                check!(ndf_bake_texture_channel(bake, t, c, &mut meaning, &mut range) => Ok, "");
                assert_eq!(
                    CStr::from_ptr(meaning).to_str().unwrap(),
                    b.textures[t as usize].channels[c as usize]
                );
                assert_eq!(
                    range,
                    if c == 0 {
                        NDF_VALUE_RANGE_UNIT
                    } else {
                        NDF_VALUE_RANGE_SIGNED
                    }
                );
            }
        }

        let levels = b.level_count() as u32;
        let (mut m, mut s, mut name) = (0, 0usize, null());
        let (mut meaning, mut range) = (null(), 0);
        check!(ndf_bake_method(null(), &mut m) => NullArgument, "bake is NULL");
        check!(ndf_bake_lobe_count(null(), &mut n) => NullArgument, "bake is NULL");
        check!(ndf_bake_level_count(null(), &mut n) => NullArgument, "bake is NULL");
        check!(ndf_bake_level_size(null(), 0, &mut w, &mut h) => NullArgument, "bake is NULL");
        check!(ndf_bake_texture_count(null(), &mut n) => NullArgument, "bake is NULL");
        check!(ndf_bake_texture_name(null(), 0, &mut name) => NullArgument, "bake is NULL");
        check!(ndf_bake_texture_channel(null(), 0, 0, &mut meaning, &mut range) => NullArgument, "bake is NULL");
        check!(ndf_bake_packed_size(null(), 0, 0, 0, &mut s) => NullArgument, "bake is NULL");
        check!(ndf_bake_method(bake, null_mut()) => NullArgument, "method_out is NULL");
        check!(ndf_bake_lobe_count(bake, null_mut()) => NullArgument, "count_out is NULL");
        check!(ndf_bake_level_count(bake, null_mut()) => NullArgument, "count_out is NULL");
        check!(ndf_bake_level_size(bake, 0, null_mut(), &mut h) => NullArgument, "width_out is NULL");
        check!(ndf_bake_level_size(bake, 0, &mut w, null_mut()) => NullArgument, "height_out is NULL");
        check!(ndf_bake_texture_count(bake, null_mut()) => NullArgument, "count_out is NULL");
        check!(ndf_bake_texture_name(bake, 0, null_mut()) => NullArgument, "name_out is NULL");
        check!(ndf_bake_texture_channel(bake, 0, 0, null_mut(), &mut range) => NullArgument, "meaning_out is NULL");
        check!(ndf_bake_texture_channel(bake, 0, 0, &mut meaning, null_mut()) => NullArgument, "range_out is NULL");
        check!(ndf_bake_packed_size(bake, 0, 0, 0, null_mut()) => NullArgument, "size_out is NULL");
        check!(ndf_bake_level_size(bake, levels, &mut w, &mut h) => OutOfRange, "level 4 is out of range (there are 4)");
        check!(ndf_bake_texture_name(bake, 2, &mut name) => OutOfRange, "texture 2");
        check!(ndf_bake_texture_channel(bake, 2, 0, &mut meaning, &mut range) => OutOfRange, "texture 2");
        check!(ndf_bake_texture_channel(bake, 0, 4, &mut meaning, &mut range) => OutOfRange, "channel 4");
        check!(ndf_bake_packed_size(bake, 2, 0, 0, &mut s) => OutOfRange, "texture 2");
        check!(ndf_bake_packed_size(bake, 0, u32::MAX, 0, &mut s) => OutOfRange, "level 4294967295");
        check!(ndf_bake_packed_size(bake, 0, 0, 4, &mut s) => InvalidArgument, "unknown format value 4");
        assert_eq!((w, h, s), (1, 1, 0), "untouched by the failures");
        ndf_bake_free(bake);
        ndf_normal_map_free(map);
    }
}

#[test]
fn packing_gives_the_rust_bytes_and_refuses_a_buffer_one_byte_short() {
    let map = c_map();
    for method in [NDF_METHOD_TOKSVIG, NDF_METHOD_LEAN, NDF_METHOD_VMF] {
        let bake = c_bake(map, method);
        // SAFETY: every pointer is NULL or valid for what it claims; freed once.
        unsafe {
            let b = &(*bake).bake;
            for (format, rust_format) in [
                (0, Format::F32),
                (1, Format::F16),
                (2, Format::Unorm16),
                (3, Format::Unorm8),
            ] {
                for t in 0..b.textures.len() {
                    for level in 0..b.level_count() {
                        let mut size = 0;
                        let s =
                            ndf_bake_packed_size(bake, t as u32, level as u32, format, &mut size);
                        if method == NDF_METHOD_LEAN && format >= 2 {
                            expect(
                                s,
                                ndf_status::UnsupportedFormat,
                                "ndf_bake_packed_size",
                                "unbounded",
                            );
                            continue;
                        }
                        expect(s, ndf_status::Ok, "", "");
                        let mut want = vec![0u8; crate::pack::packed_len(b, level, rust_format)];
                        crate::pack::pack_level(b, t, level, rust_format, &mut want).unwrap();
                        assert_eq!(size, want.len());
                        // Packed one byte into the buffer (misaligned), with guard bytes around.
                        let mut buf = vec![0xeeu8; size + 2];
                        let mut written = 0;
                        let dst = buf[1..].as_mut_ptr().cast();
                        let s = ndf_bake_pack(
                            bake,
                            t as u32,
                            level as u32,
                            format,
                            dst,
                            size - 1,
                            &mut written,
                        );
                        expect(
                            s,
                            ndf_status::BufferTooSmall,
                            "ndf_bake_pack",
                            &format!("buffer of {} bytes is too small", size - 1),
                        );
                        assert!(
                            buf.iter().all(|&x| x == 0xee) && written == 0,
                            "nothing written"
                        );
                        check!(ndf_bake_pack(bake, t as u32, level as u32, format, dst, size, &mut written,) => Ok, "");
                        assert_eq!(written, size);
                        assert_eq!(&buf[1..=size], &want[..]);
                        assert_eq!((buf[0], buf[size + 1]), (0xee, 0xee));
                    }
                }
            }
            let mut buf = [0u8; 64];
            let mut written = 0;
            let p = buf.as_mut_ptr().cast();
            check!(ndf_bake_pack(null(), 0, 0, 0, p, 64, &mut written) => NullArgument, "bake is NULL");
            check!(ndf_bake_pack(bake, 0, 0, 0, null_mut(), 64, &mut written) => NullArgument, "buffer is NULL");
            check!(ndf_bake_pack(bake, 0, 0, 0, p, 64, null_mut()) => NullArgument, "written_out is NULL");
            check!(ndf_bake_pack(bake, 99, 0, 0, p, 64, &mut written) => OutOfRange, "texture 99");
            check!(ndf_bake_pack(bake, 0, 99, 0, p, 64, &mut written) => OutOfRange, "level 99");
            check!(ndf_bake_pack(bake, 0, 0, 7, p, 64, &mut written) => InvalidArgument, "unknown format value 7");
            ndf_bake_free(bake);
        }
    }
    // SAFETY: freed once.
    unsafe { ndf_normal_map_free(map) };
}

#[test]
fn written_bakes_are_the_command_lines_and_bad_folders_fail() {
    let map = c_map();
    let bake = c_bake(map, NDF_METHOD_LEAN);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("lean");
    let c_out = CString::new(out.to_str().unwrap()).unwrap();
    // SAFETY: every pointer is NULL or valid for what it claims; freed once.
    unsafe {
        check!(ndf_bake_write(bake, c_out.as_ptr(), NDF_FORMAT_RGBA_F16) => Ok, "");
        // The command line writes this manifest for the same bake and format.
        let text = std::fs::read_to_string(out.join("manifest.json")).unwrap();
        let want = crate::output::Manifest::new(
            &crate::pack::quantize(&(*bake).bake, Format::F16).unwrap(),
            (*bake).input.clone(),
        );
        assert_eq!(text, serde_json::to_string_pretty(&want).unwrap() + "\n");
        let manifest: crate::output::Manifest = serde_json::from_str(&text).unwrap();
        for t in &manifest.textures {
            for f in &t.files {
                assert!(out.join(f).is_file(), "{f}");
            }
        }
        check!(ndf_bake_write(bake, c_out.as_ptr(), NDF_FORMAT_RGBA_UNORM8) => UnsupportedFormat, "unorm8 cannot hold texture 'slopes'");
        check!(ndf_bake_write(bake, c_out.as_ptr(), 4) => InvalidArgument, "unknown format value 4");
        check!(ndf_bake_write(null(), c_out.as_ptr(), 0) => NullArgument, "bake is NULL");
        check!(ndf_bake_write(bake, null(), 0) => NullArgument, "directory is NULL");
        let file = dir.path().join("a-file");
        std::fs::write(&file, b"x").unwrap();
        let below_file = CString::new(file.join("sub").to_str().unwrap()).unwrap();
        check!(ndf_bake_write(bake, below_file.as_ptr(), 0) => Write, "cannot write");
        ndf_bake_free(bake);
        ndf_normal_map_free(map);
    }
}

#[test]
fn the_last_error_is_per_thread_and_kept_across_successes() {
    let mut n = 0;
    // SAFETY: NULL bake, valid out-pointer.
    let s = unsafe { ndf_bake_level_count(null(), &mut n) };
    assert_eq!(s, ndf_status::NullArgument);
    let here = message();
    assert_eq!(here, "ndf_bake_level_count: bake is NULL");
    let map = c_map(); // succeeds
    assert_eq!(message(), here);
    std::thread::spawn(|| assert_eq!(message(), ""))
        .join()
        .unwrap();
    // SAFETY: freed once.
    unsafe { ndf_normal_map_free(map) };
}

/// A call of one entry point with valid arguments, freeing what it makes.
type Call<'a> = (&'static str, Box<dyn Fn() -> ndf_status + 'a>);

/// Every fallible entry point, called with valid arguments (handles it makes are freed).
fn every_entry_point<'a>(
    map: *mut ndf_normal_map,
    bake: *mut ndf_bake,
    mat: *mut ndf_material,
    px: &'a [u8],
    png: &'a [u8],
    dir: &'a CStr,
) -> Vec<Call<'a>> {
    // Options are made here: their initializers run guarded too, and would take the panic.
    let o = ndf_ingest_options_default();
    let base = ndf_baseline_options_default();
    let vmf = ndf_vmf_options {
        lobes: 1,
        ..ndf_vmf_options_default()
    };
    let tan = ndf_tan2005_options {
        lobes: 1,
        ..ndf_tan2005_options_default()
    };
    let so = ndf_shader_options_default();
    let sh = ndf_sh_options_default();
    let pbr = ndf_pbr_options_default();
    let mo = ndf_material_options_default();
    let (pxp, pngp) = (px.as_ptr().cast::<c_void>(), png.as_ptr().cast::<c_void>());
    let name = c"n.png".as_ptr();
    let missing = c"/no/such/file.png".as_ptr();
    /// Runs `make` with an out-pointer for a new handle and frees the handle it made.
    unsafe fn made<T>(
        make: impl FnOnce(*mut *mut T) -> ndf_status,
        free: unsafe extern "C" fn(*mut T),
    ) -> ndf_status {
        let mut handle = null_mut();
        let s = make(&mut handle);
        // SAFETY: NULL or the handle just made, freed once.
        unsafe { free(handle) };
        s
    }
    let (mf, bf) = (
        ndf_normal_map_free as unsafe extern "C" fn(_),
        ndf_bake_free as unsafe extern "C" fn(_),
    );
    // SAFETY (all closures): valid handles, buffers and out-pointers that outlive the calls.
    vec![
        (
            "ndf_normal_map_from_pixels",
            Box::new(move || unsafe {
                made(
                    |m| ndf_normal_map_from_pixels(pxp, px.len(), W, H, 3, 0, &o, m),
                    mf,
                )
            }),
        ),
        (
            "ndf_normal_map_load_memory",
            Box::new(move || unsafe {
                made(
                    |m| ndf_normal_map_load_memory(pngp, png.len(), name, &o, m),
                    mf,
                )
            }),
        ),
        (
            "ndf_normal_map_load_file",
            Box::new(move || unsafe { made(|m| ndf_normal_map_load_file(missing, &o, m), mf) }),
        ),
        (
            "ndf_normal_map_attach_feature_pixels",
            Box::new(move || unsafe {
                ndf_normal_map_attach_feature_pixels(map, pxp, px.len(), W, H, 3, 0, &o)
            }),
        ),
        (
            "ndf_normal_map_attach_feature_memory",
            Box::new(move || unsafe {
                ndf_normal_map_attach_feature_memory(map, pngp, png.len(), name, &o)
            }),
        ),
        (
            "ndf_normal_map_attach_feature_file",
            Box::new(move || unsafe { ndf_normal_map_attach_feature_file(map, missing, &o) }),
        ),
        (
            "ndf_normal_map_size",
            Box::new(move || unsafe { ndf_normal_map_size(map, &mut 0, &mut 0) }),
        ),
        (
            "ndf_normal_map_bad_normal_count",
            Box::new(move || unsafe { ndf_normal_map_bad_normal_count(map, &mut 0) }),
        ),
        (
            "ndf_bake_baseline",
            Box::new(move || unsafe { made(|b| ndf_bake_baseline(map, 0, &base, b), bf) }),
        ),
        (
            "ndf_bake_vmf",
            Box::new(move || unsafe { made(|b| ndf_bake_vmf(map, &vmf, b), bf) }),
        ),
        (
            "ndf_bake_tan2005",
            Box::new(move || unsafe { made(|b| ndf_bake_tan2005(map, &tan, b), bf) }),
        ),
        (
            "ndf_bake_sh",
            Box::new(move || unsafe { made(|b| ndf_bake_sh(map, &sh, b), bf) }),
        ),
        (
            "ndf_bake_pbr",
            Box::new(move || unsafe { made(|b| ndf_bake_pbr(map, &pbr, b), bf) }),
        ),
        (
            "ndf_material_new",
            Box::new(move || unsafe { made(|m| ndf_material_new(&mo, m), ndf_material_free) }),
        ),
        (
            "ndf_material_sh_coefficients",
            Box::new(move || unsafe {
                let mut out = [0.0; 5];
                ndf_material_sh_coefficients(mat, 4, out.as_mut_ptr(), out.len())
            }),
        ),
        (
            "ndf_material_suggested_lmax",
            Box::new(move || unsafe { ndf_material_suggested_lmax(mat, &mut 0) }),
        ),
        (
            "ndf_material_lobe_peak",
            Box::new(move || unsafe { ndf_material_lobe_peak(mat, &mut 0.0) }),
        ),
        (
            "ndf_material_table_size",
            Box::new(move || unsafe { ndf_material_table_size(mat, &mut 0, &mut 0) }),
        ),
        (
            "ndf_material_table",
            Box::new(move || unsafe {
                let mut out = vec![0.0f32; 1 << 15];
                ndf_material_table(mat, out.as_mut_ptr(), out.len())
            }),
        ),
        (
            "ndf_bake_method",
            Box::new(move || unsafe { ndf_bake_method(bake, &mut 0) }),
        ),
        (
            "ndf_bake_lobe_count",
            Box::new(move || unsafe { ndf_bake_lobe_count(bake, &mut 0) }),
        ),
        (
            "ndf_bake_level_count",
            Box::new(move || unsafe { ndf_bake_level_count(bake, &mut 0) }),
        ),
        (
            "ndf_bake_level_size",
            Box::new(move || unsafe { ndf_bake_level_size(bake, 0, &mut 0, &mut 0) }),
        ),
        (
            "ndf_bake_texture_count",
            Box::new(move || unsafe { ndf_bake_texture_count(bake, &mut 0) }),
        ),
        (
            "ndf_bake_texture_name",
            Box::new(move || unsafe { ndf_bake_texture_name(bake, 0, &mut null()) }),
        ),
        (
            "ndf_bake_texture_channel",
            Box::new(move || unsafe { ndf_bake_texture_channel(bake, 0, 0, &mut null(), &mut 0) }),
        ),
        (
            "ndf_bake_packed_size",
            Box::new(move || unsafe { ndf_bake_packed_size(bake, 0, 1, 0, &mut 0) }),
        ),
        (
            "ndf_bake_pack",
            Box::new(move || unsafe {
                let mut buf = vec![0u8; 1 << 12];
                ndf_bake_pack(bake, 0, 1, 0, buf.as_mut_ptr().cast(), buf.len(), &mut 0)
            }),
        ),
        (
            "ndf_bake_shader_source_size",
            Box::new(move || unsafe { ndf_bake_shader_source_size(bake, 1, &so, &mut 0) }),
        ),
        (
            "ndf_bake_shader_source",
            Box::new(move || unsafe {
                let mut buf = vec![0 as c_char; 1 << 16];
                ndf_bake_shader_source(bake, 1, &so, buf.as_mut_ptr(), buf.len(), &mut 0)
            }),
        ),
        (
            "ndf_bake_write",
            Box::new(move || unsafe { ndf_bake_write(bake, dir.as_ptr(), 0) }),
        ),
    ]
}

#[test]
fn a_panic_inside_any_entry_point_is_a_status_not_an_unwind() {
    let map = c_map();
    let bake = c_bake(map, NDF_METHOD_PLAIN);
    let px = rgb8(W, H);
    let png = png();
    let tmp = tempfile::tempdir().unwrap();
    let dir = CString::new(tmp.path().join("out").to_str().unwrap()).unwrap();
    let mut mat = null_mut();
    let table = ndf_material_options {
        model: NDF_BRDF_TABULATED,
        tabulated_json: c"{\"f\": [2.0, 1.0]}".as_ptr(),
        ..ndf_material_options_default()
    };
    // SAFETY: valid options and out-pointer; freed below.
    assert_eq!(
        unsafe { ndf_material_new(&table, &mut mat) },
        ndf_status::Ok
    );
    for (name, call) in every_entry_point(map, bake, mat, &px, &png, &dir) {
        INJECT_PANIC.with(|p| p.set(true));
        let status = call();
        expect(
            status,
            ndf_status::Panic,
            name,
            "internal error (a bug in ndfmap; please report it): injected test panic",
        );
        // The handles are intact: the same call without the panic works (or fails cleanly).
        let again = call();
        assert_ne!(again, ndf_status::Panic, "{name}");
    }
    // The entry points that cannot fail return their fallback.
    INJECT_PANIC.with(|p| p.set(true));
    assert_eq!(ndf_version(), 0);
    INJECT_PANIC.with(|p| p.set(true));
    // SAFETY: static string.
    assert_eq!(
        unsafe { CStr::from_ptr(ndf_status_str(0)) },
        c"NDF_STATUS_PANIC"
    );
    INJECT_PANIC.with(|p| p.set(true));
    assert_eq!(
        ndf_vmf_options_default().struct_size,
        size_of::<ndf_vmf_options>()
    );
    INJECT_PANIC.with(|p| p.set(true));
    // SAFETY: NULL is always fine for the destructors.
    unsafe { ndf_bake_free(null_mut()) };
    assert!(
        !INJECT_PANIC.with(|p| p.get()),
        "the destructor ran inside its guard"
    );
    // SAFETY: live handles, freed once.
    unsafe {
        ndf_bake_free(bake);
        ndf_normal_map_free(map);
        ndf_material_free(mat);
    }
}

#[test]
fn sh_bakes_and_materials_through_the_c_api() {
    let map = c_map();
    let bake = c_bake(map, NDF_METHOD_SH);
    // SAFETY: every pointer is NULL or valid for what it claims; handles freed once.
    unsafe {
        let want = bake_with(
            &rust_map(),
            Method::Sh,
            &crate::bake::BakeOptions {
                lmax: 3,
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!((*bake).bake, want);
        let mut n = 0;
        check!(ndf_bake_texture_count(bake, &mut n) => Ok, "");
        assert_eq!(n, 4);
        let mut out = null_mut();
        let o = ndf_sh_options {
            lmax: 17,
            ..ndf_sh_options_default()
        };
        check!(ndf_bake_sh(map, &o, &mut out) => InvalidArgument, "band limit 17");
        assert!(out.is_null());
        // The SH shader for GGX with the g factor, anisotropic sampling.
        let so = ndf_shader_options {
            brdf: NDF_BRDF_GGX,
            ggx_g: 1,
            sampling: NDF_SAMPLING_ANISOTROPIC,
            max_anisotropy: 8,
            ..ndf_shader_options_default()
        };
        let mut size = 0;
        check!(ndf_bake_shader_source_size(bake, 1, &so, &mut size) => Ok, "");
        let mut buf = vec![0 as c_char; size];
        let mut len = 0;
        check!(ndf_bake_shader_source(bake, 1, &so, buf.as_mut_ptr(), size, &mut len) => Ok, "");
        let src = CStr::from_ptr(buf.as_ptr()).to_str().unwrap();
        for d in [
            "#define NDF_METHOD_SH 1",
            "#define NDF_SH_LMAX 3",
            "#define NDF_BRDF_GGX 1",
            "#define NDF_BRDF_G 1",
            "#define NDF_ANISO 8",
        ] {
            assert!(src.contains(d), "{d}");
        }
        let manual = ndf_shader_options {
            sampling: NDF_SAMPLING_MANUAL,
            ..ndf_shader_options_default()
        };
        check!(ndf_bake_shader_source_size(bake, 1, &manual, &mut size) => InvalidArgument,
            "filter linearly");
        ndf_bake_free(bake);

        // Materials: Lambert's coefficients are the closed forms; GGX's are the library's.
        let mut m = null_mut();
        let lo = ndf_material_options {
            model: NDF_BRDF_LAMBERT,
            ..ndf_material_options_default()
        };
        check!(ndf_material_new(&lo, &mut m) => Ok, "");
        let mut rho = [0.0; 5];
        check!(ndf_material_sh_coefficients(m, 4, rho.as_mut_ptr(), 5) => Ok, "");
        let pi = std::f64::consts::PI;
        for (got, want) in rho
            .iter()
            .zip([pi, 2.0 * pi / 3.0, pi / 4.0, 0.0, -pi / 24.0])
        {
            assert!((got - want).abs() < 1e-15, "{got} vs {want}");
        }
        check!(ndf_material_sh_coefficients(m, 4, rho.as_mut_ptr(), 4) => BufferTooSmall, "4 doubles");
        let mut l = 0;
        check!(ndf_material_suggested_lmax(m, &mut l) => Ok, "");
        assert_eq!(l, 2);
        check!(ndf_material_table_size(m, &mut 0, &mut 0) => InvalidArgument, "no table");
        ndf_material_free(m);
        let mut m = null_mut();
        check!(ndf_material_new(&ndf_material_options_default(), &mut m) => Ok, "");
        assert_eq!((*m).brdf, crate::brdf::Brdf::ggx(0.1));
        check!(ndf_material_sh_coefficients(m, 2, rho.as_mut_ptr(), 5) => Ok, "");
        let want = crate::brdf::Brdf::ggx(0.1).sh_coefficients(2);
        assert_eq!(&rho[..3], &want[..]);
        let mut peak = 0.0;
        check!(ndf_material_lobe_peak(m, &mut peak) => Ok, "");
        assert!((peak - 1.0 / (std::f64::consts::PI * 0.01)).abs() < 1e-9);
        ndf_material_free(m);
        // A tabulated BRDF from JSON text: its table; bad JSON and parameters are refused.
        let json = c"{\"name\": \"t\", \"f\": [3.0, 1.0, 0.0], \"g\": [1.0, 0.5]}";
        let to = ndf_material_options {
            model: NDF_BRDF_TABULATED,
            tabulated_json: json.as_ptr(),
            ..ndf_material_options_default()
        };
        let mut m = null_mut();
        check!(ndf_material_new(&to, &mut m) => Ok, "");
        let (mut w, mut h) = (0, 0);
        check!(ndf_material_table_size(m, &mut w, &mut h) => Ok, "");
        let mut table = vec![0.0f32; (w * h) as usize];
        check!(ndf_material_table(m, table.as_mut_ptr(), table.len()) => Ok, "");
        let crate::brdf::Brdf::Tabulated(t) = &(*m).brdf else {
            panic!("tabulated")
        };
        assert_eq!(&table[..], t.table());
        check!(ndf_material_table(m, table.as_mut_ptr(), 3) => BufferTooSmall, "floats");
        ndf_material_free(m);
        let bad = ndf_material_options {
            tabulated_json: c"{\"f\": [1.0]}".as_ptr(),
            ..to
        };
        let mut m = null_mut();
        check!(ndf_material_new(&bad, &mut m) => InvalidArgument, "2 to");
        assert!(m.is_null());
        let none = ndf_material_options {
            tabulated_json: null(),
            ..to
        };
        check!(ndf_material_new(&none, &mut m) => NullArgument, "tabulated_json");
        let nan = ndf_material_options {
            alpha: f64::NAN,
            ..ndf_material_options_default()
        };
        check!(ndf_material_new(&nan, &mut m) => InvalidArgument, "GGX alpha");
        let unknown = ndf_material_options {
            model: 9,
            ..ndf_material_options_default()
        };
        check!(ndf_material_new(&unknown, &mut m) => InvalidArgument, "model");
        ndf_material_free(null_mut());
        ndf_normal_map_free(map);
    }
}

#[test]
fn colour_shaders_are_given_for_every_environment_light() {
    // Eq 22 under the environment (issue 16): a vMF bake of a map with a feature image gives
    // the colour shader for each environment light, the glsl module's source, with NDF_COLOR
    // and the environment's code; without colour textures it is still refused.
    let map = c_map();
    let colour = rgb8(W, H);
    let opts = ndf_ingest_options_default();
    // SAFETY: live map and bakes, valid buffers and options; each freed once.
    unsafe {
        let plain_vmf = c_bake(map, NDF_METHOD_VMF);
        let px = colour.as_ptr().cast();
        check!(ndf_normal_map_attach_feature_pixels(map, px, colour.len(), W, H, 3, NDF_SAMPLE_UINT8, &opts,) => Ok, "");
        let vmf = c_bake(map, NDF_METHOD_VMF);
        assert_eq!((*vmf).bake.textures.len(), 2 * (*vmf).bake.lobes);
        for (light, rust) in ENV_LIGHTS {
            let o = ndf_shader_options {
                color: 1,
                light,
                ..ndf_shader_options_default()
            };
            let want = crate::glsl::source_for(
                &crate::glsl::ShaderSpec::of(&(*vmf).bake),
                crate::glsl::Stage::Fragment,
                &crate::glsl::ShaderOptions {
                    color: true,
                    light: rust,
                    // `ndf_shader_options.env_lights` is on by default.
                    env_lights: true,
                    ..Default::default()
                },
            )
            .unwrap();
            assert!(want.contains("#define NDF_COLOR 1") && want.contains("ndf_env_texel("));
            let mut size = 0;
            check!(ndf_bake_shader_source_size(vmf, 1, &o, &mut size) => Ok, "");
            let mut buf = vec![0 as c_char; size];
            let mut written = 0;
            check!(ndf_bake_shader_source(vmf, 1, &o, buf.as_mut_ptr(), size, &mut written) => Ok, "");
            assert_eq!(CStr::from_ptr(buf.as_ptr()).to_str().unwrap(), want);
            check!(ndf_bake_shader_source_size(plain_vmf, 1, &o, &mut size) => InvalidArgument, "colour textures");
        }
        ndf_bake_free(vmf);
        ndf_bake_free(plain_vmf);
        ndf_normal_map_free(map);
    }
}

#[test]
fn the_vmf_specular_rule_defaults_to_auto_and_convolved_is_opt_in() {
    // ndf_shader_options_default gives auto (2: the Rust default's source, eq 20 under
    // Blinn-Phong); 0 (a zero-initialised field) is eq 20, the same Blinn-Phong shader without
    // NDF_VMF_SPECULAR_CONVOLVED; 1 is the closed-form convolution.
    let map = c_map();
    let vmf = c_bake(map, NDF_METHOD_VMF);
    let o = ndf_shader_options_default();
    assert_eq!(o.vmf_specular, NDF_VMF_SPECULAR_AUTO);
    assert_eq!(NDF_VMF_SPECULAR_EQ20, 0);
    // SAFETY: every pointer is NULL or valid for what it claims; freed once.
    unsafe {
        let spec = crate::glsl::ShaderSpec::of(&(*vmf).bake);
        for (value, rule) in [
            (NDF_VMF_SPECULAR_EQ20, crate::shade::VmfSpecular::Eq20),
            (
                NDF_VMF_SPECULAR_CONVOLVED,
                crate::shade::VmfSpecular::Convolved,
            ),
            (NDF_VMF_SPECULAR_AUTO, crate::shade::VmfSpecular::Auto),
        ] {
            let opts = ndf_shader_options {
                vmf_specular: value,
                ..o
            };
            let rust_opts = crate::glsl::ShaderOptions {
                vmf_specular: rule,
                ..Default::default()
            };
            let want =
                crate::glsl::source_for(&spec, crate::glsl::Stage::Fragment, &rust_opts).unwrap();
            assert_eq!(
                want.contains("#define NDF_VMF_SPECULAR_CONVOLVED"),
                rule == crate::shade::VmfSpecular::Convolved
            );
            let mut size = 0;
            check!(ndf_bake_shader_source_size(vmf, 1, &opts, &mut size) => Ok, "");
            let mut buf = vec![0 as c_char; size];
            let mut written = 0;
            check!(ndf_bake_shader_source(vmf, 1, &opts, buf.as_mut_ptr(), size, &mut written) => Ok, "");
            assert_eq!(CStr::from_ptr(buf.as_ptr()).to_str().unwrap(), want);
        }
        let mut n = 0;
        let bad = ndf_shader_options {
            vmf_specular: 3,
            ..o
        };
        check!(ndf_bake_shader_source_size(vmf, 1, &bad, &mut n) => InvalidArgument, "unknown vmf_specular value 3");
        ndf_bake_free(vmf);
        ndf_normal_map_free(map);
    }
}

#[test]
fn the_vmf_cosine_defaults_to_the_product_centre_and_algorithm2_is_a_define() {
    // ndf_shader_options_default (and a zero field) give the product lobe's centre, the Rust
    // default's source with no define; 1 is Algorithm 2's ω_i·μ (NDF_VMF_COSINE_ALG2, vMF only);
    // 2 is refused.
    let map = c_map();
    let vmf = c_bake(map, NDF_METHOD_VMF);
    let lean = c_bake(map, NDF_METHOD_LEAN);
    let o = ndf_shader_options_default();
    assert_eq!(o.vmf_cosine, NDF_VMF_COSINE_PRODUCT);
    assert_eq!(NDF_VMF_COSINE_PRODUCT, 0);
    // SAFETY: every pointer is NULL or valid for what it claims; freed once.
    unsafe {
        for bake in [vmf, lean] {
            let spec = crate::glsl::ShaderSpec::of(&(*bake).bake);
            for (value, cosine) in [
                (NDF_VMF_COSINE_PRODUCT, crate::shade::VmfCosine::Product),
                (
                    NDF_VMF_COSINE_ALGORITHM2,
                    crate::shade::VmfCosine::Algorithm2,
                ),
            ] {
                let opts = ndf_shader_options {
                    vmf_cosine: value,
                    ..o
                };
                let rust_opts = crate::glsl::ShaderOptions {
                    vmf_cosine: cosine,
                    ..Default::default()
                };
                let want = crate::glsl::source_for(&spec, crate::glsl::Stage::Fragment, &rust_opts)
                    .unwrap();
                assert_eq!(
                    want.contains("#define NDF_VMF_COSINE_ALG2"),
                    bake == vmf && cosine == crate::shade::VmfCosine::Algorithm2
                );
                let mut size = 0;
                check!(ndf_bake_shader_source_size(bake, 1, &opts, &mut size) => Ok, "");
                let mut buf = vec![0 as c_char; size];
                let mut written = 0;
                check!(ndf_bake_shader_source(bake, 1, &opts, buf.as_mut_ptr(), size, &mut written) => Ok, "");
                assert_eq!(CStr::from_ptr(buf.as_ptr()).to_str().unwrap(), want);
            }
        }
        let mut n = 0;
        let bad = ndf_shader_options { vmf_cosine: 2, ..o };
        check!(ndf_bake_shader_source_size(vmf, 1, &bad, &mut n) => InvalidArgument, "unknown vmf_cosine value 2");
        ndf_bake_free(vmf);
        ndf_bake_free(lean);
        ndf_normal_map_free(map);
    }
}

#[test]
fn shader_source_is_the_glsl_modules_for_the_upload_format() {
    let map = c_map();
    let vmf = c_bake(map, NDF_METHOD_VMF);
    let lean = c_bake(map, NDF_METHOD_LEAN);
    let o = ndf_shader_options_default();
    // SAFETY: every pointer is NULL or valid for what it claims; freed once.
    unsafe {
        for (stage, rust_stage) in [
            (0, crate::glsl::Stage::Vertex),
            (1, crate::glsl::Stage::Fragment),
        ] {
            for (format, rust_format) in [(1, Format::F16), (3, Format::Unorm8)] {
                let opts = ndf_shader_options {
                    format,
                    sampling: NDF_SAMPLING_MANUAL,
                    brdf: NDF_BRDF_TORRANCE_SPARROW,
                    ..o
                };
                let spec = crate::glsl::ShaderSpec {
                    format: rust_format,
                    ..crate::glsl::ShaderSpec::of(&(*vmf).bake)
                };
                let rust_opts = crate::glsl::ShaderOptions {
                    brdf: crate::glsl::ShaderBrdf::TorranceSparrow,
                    sampling: crate::glsl::Sampling::Manual,
                    ..Default::default()
                };
                let want = crate::glsl::source_for(&spec, rust_stage, &rust_opts).unwrap();
                let mut size = 0;
                check!(ndf_bake_shader_source_size(vmf, stage, &opts, &mut size) => Ok, "");
                assert_eq!(size, want.len() + 1);
                let mut buf = vec![1 as c_char; size + 1];
                let mut written = 0;
                let s = ndf_bake_shader_source(
                    vmf,
                    stage,
                    &opts,
                    buf.as_mut_ptr(),
                    size - 1,
                    &mut written,
                );
                expect(
                    s,
                    ndf_status::BufferTooSmall,
                    "ndf_bake_shader_source",
                    "needs",
                );
                assert!(
                    buf.iter().all(|&c| c == 1) && written == 0,
                    "nothing written"
                );
                check!(ndf_bake_shader_source(vmf, stage, &opts, buf.as_mut_ptr(), size, &mut written) => Ok, "");
                assert_eq!(written, size);
                assert_eq!(CStr::from_ptr(buf.as_ptr()).to_str().unwrap(), want);
                assert_eq!(buf[size], 1, "nothing past the NUL");
            }
        }
        let mut n = 0;
        let mut buf = [0 as c_char; 16];
        check!(ndf_bake_shader_source_size(null(), 1, &o, &mut n) => NullArgument, "bake is NULL");
        check!(ndf_bake_shader_source_size(vmf, 1, null(), &mut n) => NullArgument, "options is NULL");
        check!(ndf_bake_shader_source_size(vmf, 1, &o, null_mut()) => NullArgument, "size_out is NULL");
        check!(ndf_bake_shader_source_size(vmf, 2, &o, &mut n) => InvalidArgument, "unknown stage value 2");
        for (bad, words) in [
            (ndf_shader_options { brdf: 5, ..o }, "unknown brdf value 5"),
            (
                ndf_shader_options { sampling: 4, ..o },
                "unknown sampling value 4",
            ),
            (
                ndf_shader_options {
                    sampling: NDF_SAMPLING_ANISOTROPIC,
                    max_anisotropy: 17,
                    ..o
                },
                "anisotropic sampling with 17 probes",
            ),
            (
                ndf_shader_options {
                    vmf_diffuse: 2,
                    ..o
                },
                "unknown vmf_diffuse value 2",
            ),
            (
                ndf_shader_options { sh_diffuse: 2, ..o },
                "unknown sh_diffuse value 2",
            ),
            (
                ndf_shader_options { format: 4, ..o },
                "unknown format value 4",
            ),
            (
                ndf_shader_options {
                    struct_size: 1,
                    ..o
                },
                "struct_size is 1",
            ),
            (
                ndf_shader_options { color: 1, ..o },
                "colour shading needs a mixture bake with colour textures",
            ),
        ] {
            check!(ndf_bake_shader_source_size(vmf, 1, &bad, &mut n) => InvalidArgument, words);
        }
        let unorm = ndf_shader_options {
            format: NDF_FORMAT_RGBA_UNORM8,
            ..o
        };
        check!(ndf_bake_shader_source_size(lean, 1, &unorm, &mut n) => UnsupportedFormat, "unbounded");
        check!(ndf_bake_shader_source(null(), 1, &o, buf.as_mut_ptr(), 16, &mut n) => NullArgument, "bake is NULL");
        check!(ndf_bake_shader_source(vmf, 1, &o, null_mut(), 16, &mut n) => NullArgument, "buffer is NULL");
        check!(ndf_bake_shader_source(vmf, 1, &o, buf.as_mut_ptr(), 16, null_mut()) => NullArgument, "length_out is NULL");
        check!(ndf_bake_shader_source(vmf, 9, &o, buf.as_mut_ptr(), 16, &mut n) => InvalidArgument, "stage");
        assert_eq!(n, 0);
        ndf_bake_free(vmf);
        ndf_bake_free(lean);
        ndf_normal_map_free(map);
    }
}

/// Fuzzing finding 1 (fuzz/README.md) through the C API: never a panic status. Since ingest reads
/// only the channels it uses (issue 13), `exr`'s channel-selecting reader skips the stray line
/// instead of panicking; a panic there would still be a decode status.
#[test]
fn fuzz_finding_exr_line_outside_its_level_is_a_decode_status() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/fuzz/exr-line-outside-level.exr"
    );
    let bytes = std::fs::read(path).unwrap();
    let opts = ndf_ingest_options_default();
    let mut map = null_mut();
    // SAFETY: valid bytes, name, options and out-pointer; the map (if any) is freed once.
    let status = unsafe {
        ndf_normal_map_load_memory(
            bytes.as_ptr().cast(),
            bytes.len(),
            c"f.exr".as_ptr(),
            &opts,
            &mut map,
        )
    };
    if status != ndf_status::Ok {
        expect(
            status,
            ndf_status::Decode,
            "ndf_normal_map_load_memory",
            "the decoder failed unexpectedly",
        );
    }
    // SAFETY: NULL or the map just made.
    unsafe { ndf_normal_map_free(map) };
}

/// Issue 19: the container files through the C API, in memory and on disk, equal the Rust
/// API's bytes (which tests/containers.rs reads back with the ktx2 and ddsfile crates);
/// refusals come before any write.
#[test]
fn container_files_in_memory_and_on_disk_equal_the_rust_apis() {
    use super::container::*;
    use crate::container::Container;
    let map = c_map();
    let bake = c_bake(map, NDF_METHOD_OLANO);
    // SAFETY: a live bake from c_bake.
    let b = unsafe { &*bake };
    let dir = tempfile::tempdir().unwrap();
    for (container, c_container, compression, codec, format, c_format) in [
        (
            Container::Ktx2,
            NDF_CONTAINER_KTX2,
            NDF_COMPRESSION_NONE,
            None,
            Format::F16,
            NDF_FORMAT_RGBA_F16,
        ),
        (
            Container::Dds,
            NDF_CONTAINER_DDS,
            NDF_COMPRESSION_NONE,
            None,
            Format::Unorm8,
            NDF_FORMAT_RGBA_UNORM8,
        ),
        (
            Container::Ktx2,
            NDF_CONTAINER_KTX2,
            NDF_COMPRESSION_BC7,
            Some(crate::compress::Codec::Bc7),
            Format::F32,
            NDF_FORMAT_RGBA_F32,
        ),
        (
            Container::Dds,
            NDF_CONTAINER_DDS,
            NDF_COMPRESSION_BC6H,
            Some(crate::compress::Codec::Bc6h),
            Format::F32,
            NDF_FORMAT_RGBA_F32,
        ),
    ] {
        let q = crate::pack::quantize(&b.bake, format).unwrap();
        let out = dir.path().join(format!("{container}-{compression}"));
        let c_out = std::ffi::CString::new(out.to_str().unwrap()).unwrap();
        // SAFETY: a live bake and a NUL-terminated path.
        let s = unsafe {
            ndf_bake_write_container(bake, c_out.as_ptr(), c_format, c_container, compression)
        };
        assert_eq!(s, ndf_status::Ok, "{}", message());
        for t in 0..q.textures.len() {
            let want = crate::container::texture_file(&q, t, container, codec).unwrap();
            let mut size = 0usize;
            // SAFETY: a live bake, a writable out-pointer.
            let s = unsafe {
                ndf_bake_container_size(
                    bake,
                    t as u32,
                    c_format,
                    c_container,
                    compression,
                    &mut size,
                )
            };
            assert_eq!((s, size), (ndf_status::Ok, want.len()), "{}", message());
            // One byte short: refused, nothing written.
            let mut buf = vec![0xAAu8; size];
            let mut written = 7usize;
            // SAFETY: `buf` is writable for `size - 1` bytes.
            let s = unsafe {
                ndf_bake_container_file(
                    bake,
                    t as u32,
                    c_format,
                    c_container,
                    compression,
                    buf.as_mut_ptr().cast(),
                    size - 1,
                    &mut written,
                )
            };
            assert_eq!(s, ndf_status::BufferTooSmall);
            assert!(buf.iter().all(|&x| x == 0xAA) && written == 7);
            // SAFETY: `buf` is writable for `size` bytes.
            let s = unsafe {
                ndf_bake_container_file(
                    bake,
                    t as u32,
                    c_format,
                    c_container,
                    compression,
                    buf.as_mut_ptr().cast(),
                    size,
                    &mut written,
                )
            };
            assert_eq!((s, written), (ndf_status::Ok, size), "{}", message());
            assert_eq!(buf, want);
            let name = crate::container::file_name(q.textures[t].name, container);
            assert_eq!(std::fs::read(out.join(name)).unwrap(), want);
        }
    }
    let mut size = 0usize;
    // SAFETY: a live bake, a writable out-pointer (every call below).
    unsafe {
        // EXR is a folder, not one file; a compression over f16 is refused; texture 9 does
        // not exist; 99 is no compression.
        let refused = [
            (
                0,
                NDF_FORMAT_RGBA_F32,
                NDF_CONTAINER_EXR,
                NDF_COMPRESSION_NONE,
                ndf_status::InvalidArgument,
            ),
            (
                0,
                NDF_FORMAT_RGBA_F16,
                NDF_CONTAINER_KTX2,
                NDF_COMPRESSION_BC7,
                ndf_status::UnsupportedFormat,
            ),
            (
                9,
                NDF_FORMAT_RGBA_F32,
                NDF_CONTAINER_KTX2,
                NDF_COMPRESSION_NONE,
                ndf_status::OutOfRange,
            ),
            (
                0,
                NDF_FORMAT_RGBA_F32,
                NDF_CONTAINER_KTX2,
                99,
                ndf_status::InvalidArgument,
            ),
        ];
        for (texture, format, container, compression, want) in refused {
            let s =
                ndf_bake_container_size(bake, texture, format, container, compression, &mut size);
            assert_eq!(s, want, "{texture} {format} {container} {compression}");
        }
        ndf_bake_free(bake);
    }
    // vMF lobes use alpha: BC6H is refused naming the texture, and no folder appears.
    let vmf = c_bake(map, NDF_METHOD_VMF);
    let out = dir.path().join("vmf-bc6h");
    let c_out = std::ffi::CString::new(out.to_str().unwrap()).unwrap();
    // SAFETY: a live bake and a NUL-terminated path; then the handles are released once.
    unsafe {
        let s = ndf_bake_write_container(
            vmf,
            c_out.as_ptr(),
            NDF_FORMAT_RGBA_F32,
            NDF_CONTAINER_KTX2,
            NDF_COMPRESSION_BC6H,
        );
        assert_eq!(s, ndf_status::UnsupportedFormat);
        assert!(message().contains("'lobe0'"), "{}", message());
        ndf_bake_free(vmf);
        ndf_normal_map_free(map);
    }
    assert!(!out.exists());
}

/// Issue 16: environments through the C API — from raw RGB, from an `.hdr` in memory and from a
/// file, every packed array equal to what the Rust side computes, bad arguments refused with a
/// status and a message, and the environment-lit shader source through
/// `ndf_bake_shader_source`.
#[test]
fn environments_load_and_pack_for_upload() {
    use super::env::*;
    use crate::envlight::EnvLight;
    // A sun whose colour differs from the sky's: every array is compared per channel.
    let sky = crate::environment::Sky {
        width: 32,
        sun: [3.0e4, 1.5e4, 0.5e4],
        ..Default::default()
    }
    .render()
    .unwrap();
    let rgb: Vec<f32> = sky.texels().iter().flatten().copied().collect();
    let o = ndf_env_options_default();
    // SAFETY (whole test): every pointer passed is valid or deliberately NULL.
    unsafe {
        let mut env = null_mut();
        check!(ndf_environment_from_rgb(32, 16, rgb.as_ptr(), &o, &mut env) => Ok, "");
        let mut info = ndf_environment_info::default();
        check!(ndf_environment_info_get(env, &mut info) => Ok, "");
        // The default extracts up to 4 lights (here the sun): the residual's tables.
        let light =
            EnvLight::with_lights(&sky, &crate::environment::lights::LightOptions::up_to(4));
        assert_eq!(light.lights().len(), 1, "the sun");
        let up = crate::envgpu::pack(&light).unwrap();
        assert_eq!(
            (info.width, info.height, info.sh_count, info.channels),
            (32, 16, 243, 3)
        );
        assert_eq!(
            (
                info.atlas_width,
                info.atlas_height,
                info.level_count as usize
            ),
            (up.atlas_width, up.atlas_height, up.levels.len())
        );
        assert_eq!(info.kappa0, up.kappa0);
        assert_eq!(info.kappa1, up.kappa1);
        let mut sh = vec![0.0f32; 243];
        check!(ndf_environment_sh(env, sh.as_mut_ptr(), 242) => BufferTooSmall, "243 are needed");
        check!(ndf_environment_sh(env, sh.as_mut_ptr(), 243) => Ok, "");
        assert_eq!(sh, up.sh);
        for c in 0..3 {
            let want: Vec<f32> = light.channel(c).sh().iter().map(|&v| v as f32).collect();
            let got: Vec<f32> = sh.iter().skip(c).step_by(3).copied().collect();
            assert_eq!(got, want, "channel {c}");
        }
        // The sun is out of the residual: the sky's blue dominates (with it, sh[0] > 1.2 sh[2]).
        assert!(sh[2] > sh[0], "the residual's colour: {} {}", sh[0], sh[2]);
        let mut atlas = vec![0.0f32; 3 * (info.atlas_width * info.atlas_height) as usize];
        let mut levels = vec![0u32; 4 * info.level_count as usize];
        check!(ndf_environment_prefiltered(env, atlas.as_mut_ptr(), atlas.len(), levels.as_mut_ptr(), levels.len()) => Ok, "");
        assert_eq!(atlas, up.atlas);
        assert_eq!(
            levels,
            up.levels.iter().flatten().copied().collect::<Vec<_>>()
        );
        check!(ndf_environment_prefiltered(env, atlas.as_mut_ptr(), atlas.len(), levels.as_mut_ptr(), 2) => BufferTooSmall, "levels");
        check!(ndf_environment_prefiltered(env, null_mut(), 0, levels.as_mut_ptr(), levels.len()) => NullArgument, "atlas is NULL");
        let mut lp = vec![0.0f32; 3 * (info.reflected_columns * info.reflected_rows) as usize];
        check!(ndf_environment_reflected(env, lp.as_mut_ptr(), lp.len()) => Ok, "");
        assert_eq!(lp, up.reflected);
        let mut e = vec![0.0f32; 4 * (info.energy_columns * info.energy_rows) as usize];
        check!(ndf_environment_energy(env, NDF_BRDF_GGX, e.as_mut_ptr(), e.len()) => Ok, "");
        assert_eq!(
            e,
            crate::envgpu::energy(&light, &crate::brdf::Brdf::ggx(0.1)).unwrap()
        );
        check!(ndf_environment_energy(env, NDF_BRDF_LAMBERT, e.as_mut_ptr(), e.len()) => InvalidArgument, "energy tables");
        check!(ndf_environment_sh(null(), sh.as_mut_ptr(), 243) => NullArgument, "env is NULL");
        check!(ndf_environment_info_get(env, null_mut()) => NullArgument, "info_out is NULL");
        ndf_environment_free(env);
        ndf_environment_free(null_mut());

        // An .hdr in memory and on disk, yawed: the same texels as the Rust loader's.
        let mut hdr = Vec::new();
        let px: Vec<image::Rgb<f32>> = sky.texels().iter().map(|t| image::Rgb(*t)).collect();
        image::codecs::hdr::HdrEncoder::new(&mut hdr)
            .encode(&px, 32, 16)
            .unwrap();
        let yawed = ndf_env_options { yaw_deg: 90.0, ..o };
        let name = c"sky.hdr";
        let mut env = null_mut();
        check!(ndf_environment_load_memory(hdr.as_ptr().cast(), hdr.len(), name.as_ptr(), &yawed, &mut env) => Ok, "");
        let rust = crate::environment::from_memory(
            "sky.hdr",
            &hdr,
            &crate::environment::EnvOptions {
                yaw_deg: 90.0,
                ..Default::default()
            },
        )
        .unwrap();
        let want = crate::envgpu::pack(&EnvLight::with_lights(
            &rust,
            &crate::environment::lights::LightOptions::up_to(4),
        ))
        .unwrap();
        check!(ndf_environment_sh(env, sh.as_mut_ptr(), 243) => Ok, "");
        assert_eq!(sh, want.sh);
        ndf_environment_free(env);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sky.hdr");
        std::fs::write(&path, &hdr).unwrap();
        let cpath = std::ffi::CString::new(path.to_str().unwrap()).unwrap();
        check!(ndf_environment_load_file(cpath.as_ptr(), &yawed, &mut env) => Ok, "");
        check!(ndf_environment_sh(env, sh.as_mut_ptr(), 243) => Ok, "");
        assert_eq!(sh, want.sh);
        ndf_environment_free(env);

        // Bad input: truncated, not 2:1, NaN rejected, bad options, NULLs, missing file.
        let mut env = null_mut();
        check!(ndf_environment_load_memory(hdr.as_ptr().cast(), hdr.len() / 2, name.as_ptr(), &o, &mut env) => Decode, "sky.hdr");
        assert!(env.is_null());
        check!(ndf_environment_from_rgb(32, 32, vec![0.0f32; 32 * 32 * 3].as_ptr(), &o, &mut env) => Dimensions, "");
        let mut nan = rgb.clone();
        nan[7] = f32::NAN;
        let reject = ndf_env_options {
            bad_texels: NDF_BAD_TEXELS_REJECT,
            ..o
        };
        check!(ndf_environment_from_rgb(32, 16, nan.as_ptr(), &reject, &mut env) => Decode, "");
        check!(ndf_environment_from_rgb(32, 16, nan.as_ptr(), &o, &mut env) => Ok, "");
        check!(ndf_environment_info_get(env, &mut info) => Ok, "");
        assert_eq!(info.repaired, 1);
        ndf_environment_free(env);
        let bad = ndf_env_options {
            intensity: f64::NAN,
            ..o
        };
        check!(ndf_environment_from_rgb(32, 16, rgb.as_ptr(), &bad, &mut env) => InvalidArgument, "intensity");
        let bad = ndf_env_options { bad_texels: 7, ..o };
        check!(ndf_environment_from_rgb(32, 16, rgb.as_ptr(), &bad, &mut env) => InvalidArgument, "bad_texels");
        let bad = ndf_env_options {
            struct_size: 3,
            ..o
        };
        check!(ndf_environment_from_rgb(32, 16, rgb.as_ptr(), &bad, &mut env) => InvalidArgument, "struct_size");
        check!(ndf_environment_from_rgb(32, 16, null(), &o, &mut env) => NullArgument, "rgb is NULL");
        check!(ndf_environment_from_rgb(32, 16, rgb.as_ptr(), &o, null_mut()) => NullArgument, "env_out is NULL");
        check!(ndf_environment_load_file(c"/nonexistent/x.hdr".as_ptr(), &o, &mut env) => Read, "x.hdr");
        check!(ndf_environment_load_memory(null(), 0, name.as_ptr(), &o, &mut env) => NullArgument, "data is NULL");

        // The environment-lit shader through ndf_bake_shader_source: the Rust source, and
        // refused for a method without one.
        let map = c_map();
        let vmf = c_bake(map, NDF_METHOD_VMF);
        for (light, rust) in ENV_LIGHTS {
            let so = ndf_shader_options {
                light,
                ..ndf_shader_options_default()
            };
            let want = crate::glsl::source_for(
                &crate::glsl::ShaderSpec::of(&(*vmf).bake),
                crate::glsl::Stage::Fragment,
                &crate::glsl::ShaderOptions {
                    light: rust,
                    env_lights: true,
                    ..Default::default()
                },
            )
            .unwrap();
            let mut size = 0;
            check!(ndf_bake_shader_source_size(vmf, 1, &so, &mut size) => Ok, "");
            let mut buf = vec![0 as c_char; size];
            check!(ndf_bake_shader_source(vmf, 1, &so, buf.as_mut_ptr(), size, &mut size) => Ok, "");
            assert_eq!(CStr::from_ptr(buf.as_ptr()).to_str().unwrap(), want);
        }
        let so = ndf_shader_options {
            light: 4,
            ..ndf_shader_options_default()
        };
        let mut size = 0;
        check!(ndf_bake_shader_source_size(vmf, 1, &so, &mut size) => InvalidArgument, "light");
        // Both lights: the point light's and the environment's defines, not NDF_LIGHT_ENV.
        let so = ndf_shader_options {
            light: NDF_LIGHT_POINT_AND_ENV_PREFILTERED,
            ..ndf_shader_options_default()
        };
        check!(ndf_bake_shader_source_size(vmf, 1, &so, &mut size) => Ok, "");
        let mut buf = vec![0 as c_char; size];
        check!(ndf_bake_shader_source(vmf, 1, &so, buf.as_mut_ptr(), size, &mut size) => Ok, "");
        let got = CStr::from_ptr(buf.as_ptr()).to_str().unwrap();
        assert!(
            got.contains("#define NDF_LIGHT_BOTH 1") && !got.contains("#define NDF_LIGHT_ENV 1")
        );
        // SH bakes: the SH route (the Rust source, with the per-fragment rotation's table);
        // the prefiltered route is refused with a message naming the one to use.
        let sh = c_bake(map, NDF_METHOD_SH);
        let so = ndf_shader_options {
            light: NDF_LIGHT_ENV_SH,
            ..ndf_shader_options_default()
        };
        let want = crate::glsl::source_for(
            &crate::glsl::ShaderSpec::of(&(*sh).bake),
            crate::glsl::Stage::Fragment,
            &crate::glsl::ShaderOptions {
                light: crate::glsl::ShaderLight::EnvSh,
                env_lights: true,
                ..Default::default()
            },
        )
        .unwrap();
        check!(ndf_bake_shader_source_size(sh, 1, &so, &mut size) => Ok, "");
        let mut buf = vec![0 as c_char; size];
        check!(ndf_bake_shader_source(sh, 1, &so, buf.as_mut_ptr(), size, &mut size) => Ok, "");
        let got = CStr::from_ptr(buf.as_ptr()).to_str().unwrap();
        assert_eq!(got, want);
        assert!(
            got.contains("const float NDF_ENV_X90[") && got.contains("#define NDF_LIGHT_ENV_SH 1")
        );
        let so = ndf_shader_options {
            light: NDF_LIGHT_ENV_PREFILTERED,
            ..ndf_shader_options_default()
        };
        check!(ndf_bake_shader_source_size(sh, 1, &so, &mut size) => InvalidArgument, "light env-sh");
        ndf_bake_free(sh);
        ndf_bake_free(vmf);
        ndf_normal_map_free(map);
    }
}

/// Issue 16's extracted lights through the C API: `ndf_env_options.max_lights` (default 4)
/// prepares the environment as `EnvLight::with_lights` (the residual's tables, bit for bit),
/// 0 as `EnvLight::new`; the lights come out of `ndf_environment_lights` as the uniforms hold
/// them, and `ndf_shader_options.env_lights` (default on) is the Rust shader with
/// `env_lights`, off the Rust shader without, ignored by the point light's shader.
#[test]
fn extracted_lights_through_the_c_api() {
    use super::env::*;
    use crate::envlight::EnvLight;
    let sky = crate::environment::Sky {
        width: 32,
        sun: [3.0e4, 1.5e4, 0.5e4],
        ..Default::default()
    }
    .render()
    .unwrap();
    let rgb: Vec<f32> = sky.texels().iter().flatten().copied().collect();
    let o = ndf_env_options_default();
    assert_eq!(o.max_lights, 4, "extraction is the default");
    // SAFETY (whole test): every pointer passed is valid or deliberately NULL.
    unsafe {
        let mut env = null_mut();
        check!(ndf_environment_from_rgb(32, 16, rgb.as_ptr(), &o, &mut env) => Ok, "");
        let light =
            EnvLight::with_lights(&sky, &crate::environment::lights::LightOptions::up_to(4));
        let up = crate::envgpu::pack(&light).unwrap();
        assert_eq!(up.lights.len(), 1, "the sun");
        let mut sh = vec![0.0f32; 243];
        check!(ndf_environment_sh(env, sh.as_mut_ptr(), 243) => Ok, "");
        assert_eq!(sh, up.sh);
        let mut count = 9;
        let mut out = vec![0.0f32; 8];
        check!(ndf_environment_lights(env, out.as_mut_ptr(), 7, &mut count) => BufferTooSmall, "");
        check!(ndf_environment_lights(env, out.as_mut_ptr(), 8, &mut count) => Ok, "");
        assert_eq!(count, 1);
        let sun = up.lights[0];
        let f = |v: f64| v as f32;
        let want = [
            f(sun.direction.x),
            f(sun.direction.y),
            f(sun.direction.z),
            f(sun.power[0]),
            f(sun.power[1]),
            f(sun.power[2]),
            f(sun.kappa),
            0.0,
        ];
        assert_eq!(out, want);
        check!(ndf_environment_lights(env, out.as_mut_ptr(), 8, null_mut()) => NullArgument, "count_out");
        ndf_environment_free(env);
        // Without extraction (max_lights 0): no lights, the whole sky's tables, NULL allowed.
        let none = ndf_env_options {
            max_lights: 0,
            ..ndf_env_options_default()
        };
        check!(ndf_environment_from_rgb(32, 16, rgb.as_ptr(), &none, &mut env) => Ok, "");
        check!(ndf_environment_lights(env, null_mut(), 0, &mut count) => Ok, "");
        assert_eq!(count, 0);
        check!(ndf_environment_sh(env, sh.as_mut_ptr(), 243) => Ok, "");
        assert_eq!(sh, crate::envgpu::pack(&EnvLight::new(&sky)).unwrap().sh);
        ndf_environment_free(env);

        // The shader option: the Rust source with env_lights (the default), without it when
        // off; the point light's shader ignores it.
        let map = c_map();
        let vmf = c_bake(map, NDF_METHOD_VMF);
        assert_eq!(ndf_shader_options_default().env_lights, 1);
        let so = ndf_shader_options {
            light: NDF_LIGHT_ENV_PREFILTERED,
            ..ndf_shader_options_default()
        };
        let want = crate::glsl::source_for(
            &crate::glsl::ShaderSpec::of(&(*vmf).bake),
            crate::glsl::Stage::Fragment,
            &crate::glsl::ShaderOptions {
                light: crate::glsl::ShaderLight::EnvPrefiltered,
                env_lights: true,
                ..Default::default()
            },
        )
        .unwrap();
        assert!(want.contains("#define NDF_ENV_LIGHTS 8"));
        let mut size = 0;
        check!(ndf_bake_shader_source_size(vmf, 1, &so, &mut size) => Ok, "");
        let mut buf = vec![0 as c_char; size];
        check!(ndf_bake_shader_source(vmf, 1, &so, buf.as_mut_ptr(), size, &mut size) => Ok, "");
        assert_eq!(CStr::from_ptr(buf.as_ptr()).to_str().unwrap(), want);
        let source = |so: &ndf_shader_options| {
            let mut size = 0;
            check!(ndf_bake_shader_source_size(vmf, 1, so, &mut size) => Ok, "");
            let mut buf = vec![0 as c_char; size];
            check!(ndf_bake_shader_source(vmf, 1, so, buf.as_mut_ptr(), size, &mut size) => Ok, "");
            CStr::from_ptr(buf.as_ptr()).to_str().unwrap().to_string()
        };
        let rust = |light, env_lights| {
            crate::glsl::source_for(
                &crate::glsl::ShaderSpec::of(&(*vmf).bake),
                crate::glsl::Stage::Fragment,
                &crate::glsl::ShaderOptions {
                    light,
                    env_lights,
                    ..Default::default()
                },
            )
            .unwrap()
        };
        let off = source(&ndf_shader_options {
            env_lights: 0,
            ..so
        });
        assert_eq!(off, rust(crate::glsl::ShaderLight::EnvPrefiltered, false));
        assert!(!off.contains("#define NDF_ENV_LIGHTS"));
        let point = source(&ndf_shader_options_default());
        assert_eq!(point, rust(crate::glsl::ShaderLight::Point, false));
        ndf_bake_free(vmf);
        ndf_normal_map_free(map);
    }
}

#[test]
fn the_ggx_mixture_is_the_library_fit_and_refuses_other_brdfs() {
    // SAFETY: every pointer is NULL or valid for what it claims; freed once.
    unsafe {
        let mut opts = ndf_material_options_default();
        opts.alpha = 0.1;
        let mut b = std::ptr::null_mut();
        check!(ndf_material_new(&opts, &mut b) => Ok, "");
        let (mut w, mut e) = ([0.0; NDF_GGX_MIXTURE_LOBES], [0.0; NDF_GGX_MIXTURE_LOBES]);
        check!(ndf_material_ggx_mixture(b, w.as_mut_ptr(), e.as_mut_ptr()) => Ok, "");
        assert_eq!(
            NDF_GGX_MIXTURE_LOBES,
            crate::brdf::ggx_mixture::GGX_MIXTURE_LOBES
        );
        let m = crate::brdf::ggx_mixture::GgxMixture::fit(0.1);
        assert_eq!(w, m.weights);
        assert_eq!(e, m.etas);
        check!(ndf_material_ggx_mixture(b, std::ptr::null_mut(), e.as_mut_ptr()) => NullArgument, "weights_out");
        ndf_material_free(b);
        let mut blinn = std::ptr::null_mut();
        let mut bp = ndf_material_options_default();
        bp.model = NDF_BRDF_BLINN_PHONG;
        check!(ndf_material_new(&bp, &mut blinn) => Ok, "");
        check!(ndf_material_ggx_mixture(blinn, w.as_mut_ptr(), e.as_mut_ptr()) => InvalidArgument, "GGX only");
        ndf_material_free(blinn);
    }
}
