//! `ndf_bake_sh` with fuzzed options on tiny maps: the band limit l* (any `u32`: above 16 must be
//! refused before any work), the memory budget (tiny budgets must refuse, not abort), a wrong
//! `struct_size`, a progress callback that cancels at its n-th call; the map is at most 8×8
//! texels (RGB8, RGBA16 or RGBA32F, from the fuzzer's bytes), so every run stays fast.
//!
//! Input: width − 1 and height − 1 (3 bits each) and the sample type in byte 0; l* in byte 1
//! (values ≥ 0xF0 take a 32-bit l* from bytes 4..8); byte 2 the memory budget (0 default, else
//! 2^(byte/4) bytes) and byte 3 the callback (0 none, else cancel at call `byte`; 0xFF also
//! passes a wrong `struct_size`); the rest, the pixels (padded with `0x80`).
//!
//! Checks: a status, never `NDF_STATUS_PANIC`; the out-pointer untouched on failure; l* > 16
//! is `NDF_STATUS_INVALID_ARGUMENT` and calls no callback; a bake made has `⌈(l*+1)²/4⌉`
//! textures whose every level packs as f32 with finite values in [−1, 1] and as f16, and is freed.
#![no_main]

use libfuzzer_sys::fuzz_target;
use ndfmap::ffi::bake::*;
use ndfmap::ffi::map::*;
use ndfmap::ffi::ndf_status;
use std::ffi::c_void;
use std::ptr::null_mut;

struct Cancel {
    calls: u32,
    cancel_at: u32,
}

extern "C" fn progress(_fraction: f32, user: *mut c_void) -> i32 {
    // SAFETY: `user` is the `Cancel` the target passed, alive for the call.
    let c = unsafe { &mut *user.cast::<Cancel>() };
    c.calls += 1;
    i32::from(c.calls < c.cancel_at)
}

fuzz_target!(init: ndfmap_fuzz::contain_dependency_panics(), |data: &[u8]| {
    let Some((head, rest)) = data.split_first_chunk::<4>() else {
        return;
    };
    let width = u32::from(head[0] & 7) + 1;
    let height = u32::from(head[0] >> 3 & 7) + 1;
    let sample_type = u32::from(head[0] >> 6) % 3; // u8, u16, f32
    let (lmax, pixels) = if head[1] >= 0xF0 && rest.len() >= 4 {
        (u32::from_le_bytes([rest[0], rest[1], rest[2], rest[3]]), &rest[4..])
    } else {
        (u32::from(head[1]), rest)
    };
    let memory_limit = match head[2] {
        0 => 0,
        b => 1u64 << (u32::from(b) / 4).min(63),
    };
    let (channels, bytes_per_sample) = match sample_type {
        0 => (3u32, 1usize),
        1 => (4, 2),
        _ => (4, 4),
    };
    let needed = (width * height * channels) as usize * bytes_per_sample;
    let mut buf = vec![0x80u8; needed];
    let n = pixels.len().min(needed);
    buf[..n].copy_from_slice(&pixels[..n]);
    let mut map = null_mut();
    let ingest = ndf_ingest_options {
        bad_normals: NDF_BAD_NORMALS_REPAIR,
        ..ndf_ingest_options_default()
    };
    // SAFETY: `buf` is readable for its length; options and out-pointer valid.
    let s = unsafe {
        ndf_normal_map_from_pixels(
            buf.as_ptr().cast(),
            buf.len(),
            width,
            height,
            channels,
            sample_type,
            &ingest,
            &mut map,
        )
    };
    assert_ne!(s, ndf_status::Panic);
    if s != ndf_status::Ok {
        return; // f32 pixels may be NaN everywhere (nothing to repair from)
    }
    let mut cancel = Cancel {
        calls: 0,
        cancel_at: u32::from(head[3]),
    };
    let mut o = ndf_sh_options {
        lmax,
        memory_limit,
        ..ndf_sh_options_default()
    };
    if head[3] != 0 {
        o.progress = Some(progress);
        o.progress_user_data = (&raw mut cancel).cast();
    }
    if head[3] == 0xFF {
        o.struct_size -= 8;
    }
    let mut bake = null_mut();
    // SAFETY: map live; options valid (the callback's data outlives the call); out-pointer valid.
    let status = unsafe { ndf_bake_sh(map, &o, &mut bake) };
    assert_ne!(status, ndf_status::Panic, "a panic reached the boundary");
    if head[3] == 0xFF || lmax > 16 {
        assert_eq!(status, ndf_status::InvalidArgument, "l* {lmax}");
        assert_eq!(cancel.calls, 0, "work started before the options were checked");
    }
    if status != ndf_status::Ok {
        assert!(bake.is_null(), "out-parameter written on failure");
        // SAFETY: live, freed once.
        unsafe { ndf_normal_map_free(map) };
        return;
    }
    // SAFETY: `bake` and `map` are live, freed once; buffers and out-pointers valid.
    unsafe {
        let mut textures = 0;
        assert_eq!(ndf_bake_texture_count(bake, &mut textures), ndf_status::Ok);
        let coefficients = (lmax + 1) * (lmax + 1);
        assert_eq!(textures, coefficients.div_ceil(4), "l* {lmax}");
        let mut levels = 0;
        assert_eq!(ndf_bake_level_count(bake, &mut levels), ndf_status::Ok);
        for t in 0..textures {
            for l in 0..levels {
                let (mut w, mut h) = (0, 0);
                assert_eq!(ndf_bake_level_size(bake, l, &mut w, &mut h), ndf_status::Ok);
                let mut texels = vec![0f32; (w * h * 4) as usize];
                let mut written = 0;
                let s = ndf_bake_pack(
                    bake,
                    t,
                    l,
                    NDF_FORMAT_RGBA_F32,
                    texels.as_mut_ptr().cast(),
                    texels.len() * 4,
                    &mut written,
                );
                assert_eq!(s, ndf_status::Ok);
                assert_eq!(written, texels.len() * 4);
                for (i, v) in texels.iter().enumerate() {
                    let unused = t * 4 + (i % 4) as u32 >= coefficients;
                    assert!(
                        v.is_finite() && (unused || v.abs() <= 1.0 + 1e-5),
                        "texture {t} level {l}: {v}"
                    );
                }
                let mut half = vec![0u8; (w * h * 8) as usize];
                let s = ndf_bake_pack(
                    bake,
                    t,
                    l,
                    NDF_FORMAT_RGBA_F16,
                    half.as_mut_ptr().cast(),
                    half.len(),
                    &mut written,
                );
                assert_eq!(s, ndf_status::Ok);
            }
        }
        ndf_bake_free(bake);
        ndf_normal_map_free(map);
    }
});
