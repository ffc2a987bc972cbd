//! The tabulated BRDF parser (JSON, `docs/sh-brdf.md`) through the C API's
//! `ndf_material_new`, and the same text through the Rust paths (`Tabulated::from_json`,
//! `Tabulated::load`, and a `Brdf` deserialized with its `model` tag).
//!
//! Input: one selector byte, then the JSON text. Selector bits: 0 reads the text from a file
//! through `tabulated_path` (else `tabulated_json`, NUL-terminated, cut at the first NUL);
//! 1 to 5 pick the band limit asked of `ndf_material_sh_coefficients` (0 to 31: above 16 must be
//! refused); 6 and 7 both set also compute the shader's table (about half a second, so a
//! quarter of the inputs at most).
//!
//! Checks: a status, never `NDF_STATUS_PANIC`; the out-pointer untouched on failure; the C and
//! Rust parsers agree; an accepted BRDF has finite coefficients, peak and table, serializes back
//! to JSON that parses to the same BRDF, and is freed (LeakSanitizer).
#![no_main]

use libfuzzer_sys::fuzz_target;
use ndfmap::brdf::{Brdf, Tabulated};
use ndfmap::ffi::brdf::*;
use ndfmap::ffi::ndf_status;
use ndfmap::ffi::shader::NDF_BRDF_TABULATED;
use std::ffi::CString;
use std::path::PathBuf;
use std::ptr::null_mut;
use std::sync::OnceLock;

/// A per-process temporary file for the path variant.
fn scratch() -> &'static PathBuf {
    static P: OnceLock<PathBuf> = OnceLock::new();
    P.get_or_init(|| std::env::temp_dir().join(format!("ndfmap-fuzz-{}.json", std::process::id())))
}

fuzz_target!(init: ndfmap_fuzz::contain_dependency_panics(), |data: &[u8]| {
    let Some((&sel, body)) = data.split_first() else {
        return;
    };
    let via_path = sel & 1 != 0;
    let lmax = u32::from(sel >> 1 & 31);
    let want_table = sel & 0xC0 == 0xC0;
    // The C string stops at the first NUL; the file holds the same bytes.
    let text = &body[..body.iter().position(|&b| b == 0).unwrap_or(body.len())];
    let c_text = CString::new(text).unwrap();
    let c_path;
    let mut options = ndf_material_options {
        model: NDF_BRDF_TABULATED,
        ..ndf_material_options_default()
    };
    if via_path {
        std::fs::write(scratch(), text).unwrap();
        c_path = CString::new(scratch().to_str().unwrap()).unwrap();
        options.tabulated_path = c_path.as_ptr();
    } else {
        options.tabulated_json = c_text.as_ptr();
    }
    let mut m = null_mut();
    // SAFETY: options valid, its strings NUL-terminated and alive; out-pointer valid.
    let status = unsafe { ndf_material_new(&options, &mut m) };
    assert_ne!(status, ndf_status::Panic, "a panic reached the boundary");

    // The Rust paths agree with the C one.
    let rust = match std::str::from_utf8(text) {
        Ok(s) => Tabulated::from_json(s, "fuzz"),
        Err(_) => Tabulated::from_json("not UTF-8", "fuzz"),
    };
    if via_path {
        let loaded = Tabulated::load(scratch());
        assert_eq!(loaded.is_ok(), rust.is_ok(), "load and from_json disagree");
    }
    if let Ok(s) = std::str::from_utf8(text) {
        // A BRDF written with its model tag goes through the same validation.
        if let Ok(Brdf::Tabulated(t)) = serde_json::from_str::<Brdf>(s) {
            assert!(t.peak().is_finite());
        }
    }
    if status != ndf_status::Ok {
        assert!(m.is_null(), "out-parameter written on failure");
        assert!(rust.is_err(), "C refused what Rust accepted: {status:?}");
        return;
    }
    assert!(!m.is_null());
    let t = rust.expect("C accepted what Rust refused");
    // Round trip: the file written back parses to the same BRDF.
    let json = serde_json::to_string(&t).unwrap();
    let back = Tabulated::from_json(&json, "round trip").expect("round trip");
    assert_eq!(back, t);

    // SAFETY: `m` is the live BRDF just made, freed once; buffers and out-pointers are valid.
    unsafe {
        let mut rho = vec![f64::NAN; 33];
        let s = ndf_material_sh_coefficients(m, lmax, rho.as_mut_ptr(), rho.len());
        if lmax > 16 {
            assert_eq!(s, ndf_status::InvalidArgument);
        } else {
            assert_eq!(s, ndf_status::Ok);
            let n = lmax as usize + 1;
            assert!(rho[..n].iter().all(|v| v.is_finite()), "ρ̂ = {:?}", &rho[..n]);
            assert!(rho[n..].iter().all(|v| v.is_nan()), "wrote past lmax + 1");
            let s = ndf_material_sh_coefficients(m, lmax, rho.as_mut_ptr(), lmax as usize);
            assert_eq!(s, ndf_status::BufferTooSmall);
        }
        let mut peak = f64::NAN;
        assert_eq!(ndf_material_lobe_peak(m, &mut peak), ndf_status::Ok);
        assert!(peak.is_finite() && peak >= 0.0, "peak {peak}");
        let mut l = 0;
        assert_eq!(ndf_material_suggested_lmax(m, &mut l), ndf_status::Ok);
        assert!((2..=16).contains(&l), "suggested l* {l}");
        let (mut w, mut h) = (0, 0);
        assert_eq!(ndf_material_table_size(m, &mut w, &mut h), ndf_status::Ok);
        let len = w as usize * h as usize;
        let mut table = vec![0.0f32; len];
        let s = ndf_material_table(m, table.as_mut_ptr(), 3);
        assert_eq!(s, ndf_status::BufferTooSmall);
        if want_table {
            let s = ndf_material_table(m, table.as_mut_ptr(), len);
            assert_eq!(s, ndf_status::Ok);
            assert!(table.iter().all(|v| v.is_finite() && *v >= 0.0), "table not finite");
        }
        ndf_material_free(m);
    }
});
