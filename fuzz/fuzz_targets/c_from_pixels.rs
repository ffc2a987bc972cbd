//! The C API's raw-pixel entry points, `ndf_normal_map_from_pixels` and
//! `ndf_normal_map_attach_feature_pixels`, with width, height, channels, sample type and options
//! taken from the first bytes (often absurd: zero, overflowing, unknown values) and the rest as
//! the pixel buffer, at any alignment. Every call must return a status without reading past the
//! buffer; a map that loads is baked (vMF, one lobe) when small, packed and freed.
#![no_main]

use libfuzzer_sys::fuzz_target;
use ndfmap::ffi::bake::*;
use ndfmap::ffi::map::*;
use ndfmap::ffi::ndf_status;
use std::ptr::null_mut;

fuzz_target!(init: ndfmap_fuzz::contain_dependency_panics(), |data: &[u8]| {
    let Some((head, pixels)) = data.split_first_chunk::<8>() else {
        return;
    };
    let width = u32::from(u16::from_le_bytes([head[0], head[1]])) % 70_000;
    let height = u32::from(u16::from_le_bytes([head[2], head[3]]));
    let channels = u32::from(head[4] % 6);
    let sample_type = u32::from(head[5] % 4);
    let options = ndf_ingest_options {
        encoding: u32::from(head[6] % 4),
        channels: u32::from(head[6] / 4 % 4),
        bad_normals: u32::from(head[7] % 3),
        green: u32::from(head[7] / 3 % 3),
        ..ndf_ingest_options_default()
    };
    // An odd offset makes the buffer misaligned for 16- and 32-bit samples.
    let offset = usize::from(head[7] & 1).min(pixels.len());
    let pixels = &pixels[offset..];
    let mut map = null_mut();
    // SAFETY: `pixels` is readable for its length; options and out-pointer are valid.
    let status = unsafe {
        ndf_normal_map_from_pixels(
            pixels.as_ptr().cast(),
            pixels.len(),
            width,
            height,
            channels,
            sample_type,
            &options,
            &mut map,
        )
    };
    assert_ne!(status, ndf_status::Panic, "a panic reached the boundary");
    if status != ndf_status::Ok {
        assert!(map.is_null(), "out-parameter written on failure");
        return;
    }
    // SAFETY: `map` is the live map just made, freed once; buffers and out-pointers are valid.
    unsafe {
        let s = ndf_normal_map_attach_feature_pixels(
            map,
            pixels.as_ptr().cast(),
            pixels.len(),
            width,
            height,
            channels,
            sample_type,
            &options,
        );
        assert_ne!(s, ndf_status::Panic);
        if u64::from(width) * u64::from(height) <= 1024 {
            let mut bake = null_mut();
            let o = ndf_vmf_options {
                lobes: 1,
                em_max_iterations: 3,
                ..ndf_vmf_options_default()
            };
            assert_eq!(ndf_bake_vmf(map, &o, &mut bake), ndf_status::Ok);
            let mut buf = vec![0u8; width as usize * height as usize * 8];
            let mut written = 0;
            let s = ndf_bake_pack(
                bake,
                0,
                0,
                NDF_FORMAT_RGBA_F16,
                buf.as_mut_ptr().cast(),
                buf.len(),
                &mut written,
            );
            assert_eq!(s, ndf_status::Ok);
            ndf_bake_free(bake);
        }
        ndf_normal_map_free(map);
    }
});
