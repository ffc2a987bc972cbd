//! The C API's load-from-memory entry point, `ndf_normal_map_load_memory`, called as a C program
//! would, on arbitrary bytes and with arbitrary (often invalid) option values taken from the
//! first bytes. Every call must return a status (a panic caught at the boundary would be
//! `NDF_STATUS_PANIC`, itself a finding); a map that loads is queried, baked when small, packed
//! and freed, so leaks and invalid accesses show under the sanitizer.
#![no_main]

use libfuzzer_sys::fuzz_target;
use ndfmap::ffi::bake::*;
use ndfmap::ffi::map::*;
use ndfmap::ffi::ndf_status;
use std::ptr::null_mut;

fuzz_target!(init: ndfmap_fuzz::contain_dependency_panics(), |data: &[u8]| {
    let Some((head, bytes)) = data.split_first_chunk::<3>() else {
        return;
    };
    let options = ndf_ingest_options {
        green: u32::from(head[0] % 3),
        encoding: u32::from(head[0] / 3 % 4),
        channels: u32::from(head[1] % 4),
        addressing: u32::from(head[1] / 4 % 3),
        bad_normals: u32::from(head[1] / 12 % 3),
        feature_encoding: u32::from(head[2] % 3),
        // The decoding budget (issue 13), well inside the fuzzer's 4 GiB.
        memory_limit: 512 << 20,
        ..ndf_ingest_options_default()
    };
    let names = [c"f.png", c"f.tga", c"f.tif", c"f.jpg", c"f.exr", c"f"];
    let name = names[usize::from(head[2] / 3) % names.len()];
    let mut map = null_mut();
    // SAFETY: `bytes` is readable for its length; the name and options are valid.
    let status = unsafe {
        ndf_normal_map_load_memory(
            bytes.as_ptr().cast(),
            bytes.len(),
            name.as_ptr(),
            &options,
            &mut map,
        )
    };
    assert_ne!(status, ndf_status::Panic, "a panic reached the boundary");
    if status != ndf_status::Ok {
        assert!(map.is_null(), "out-parameter written on failure");
        return;
    }
    let (mut w, mut h) = (0, 0);
    // SAFETY: `map` is the live map just loaded, freed once; out-pointers are valid.
    unsafe {
        assert_eq!(ndf_normal_map_size(map, &mut w, &mut h), ndf_status::Ok);
        if u64::from(w) * u64::from(h) <= 4096 {
            let mut bake = null_mut();
            let s = ndf_bake_baseline(
                map,
                NDF_METHOD_OLANO,
                &ndf_baseline_options_default(),
                &mut bake,
            );
            assert_eq!(s, ndf_status::Ok);
            let mut levels = 0;
            assert_eq!(ndf_bake_level_count(bake, &mut levels), ndf_status::Ok);
            let mut buf = vec![0u8; w as usize * h as usize * 16];
            let mut written = 0;
            for level in 0..levels {
                let s = ndf_bake_pack(
                    bake,
                    0,
                    level,
                    NDF_FORMAT_RGBA_UNORM8,
                    buf.as_mut_ptr().cast(),
                    buf.len(),
                    &mut written,
                );
                assert_eq!(s, ndf_status::Ok);
            }
            ndf_bake_free(bake);
        }
        ndf_normal_map_free(map);
    }
});
