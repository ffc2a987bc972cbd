//! C API, materials: one description of the BRDF ([`crate::brdf::Brdf`]) for the shader's
//! uniforms — the BRDF's SH coefficients `ρ̂_l` for SH bakes, the band limit it needs, and a
//! tabulated BRDF's table for the `ndf_brdf_table` texture. The BRDF's kind picks the shader's
//! specialization (`ndf_shader_options.brdf`).

use super::shader::{
    NDF_BRDF_BLINN_PHONG, NDF_BRDF_GGX, NDF_BRDF_LAMBERT, NDF_BRDF_TABULATED,
    NDF_BRDF_TORRANCE_SPARROW, ndf_brdf,
};
use super::{Out, arg, c_str, choose, fail, guard, guard_value, ndf_status, read_options};
use crate::brdf::{Brdf, GGX_WIDENING_C, Ggx, Tabulated};
use std::ffi::c_char;
use std::sync::Arc;

/// A BRDF description. Initialize with `ndf_material_options_default()`, set `model` and the
/// fields it reads, and make the BRDF with `ndf_material_new`.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct ndf_material_options {
    /// `sizeof(ndf_material_options)`, set by `ndf_material_options_default()`.
    pub struct_size: usize,
    /// The model, `NDF_BRDF_*`. Default `NDF_BRDF_GGX`.
    pub model: ndf_brdf,
    /// `NDF_BRDF_BLINN_PHONG`: exponent s in (0, 1e7]. Default 64.
    pub s: f64,
    /// `NDF_BRDF_TORRANCE_SPARROW`: roughness σ of eq 18, finite and >= 2.5e-4. Default 0.1.
    pub sigma: f64,
    /// `NDF_BRDF_GGX`: roughness α (glTF's perceptual roughness squared), in [5e-4, 1].
    /// Default 0.1.
    pub alpha: f64,
    /// `NDF_BRDF_GGX`: nonzero multiplies by the g factor, Smith's height-correlated masking
    /// (against the geometric normal) and Schlick's Fresnel. Default 0: the lobe D alone.
    pub g: u32,
    /// `NDF_BRDF_GGX` with `g`: Schlick's F0 in [0, 1]. Default 0.04.
    pub f0: f64,
    /// `NDF_BRDF_GGX`: the widening constant c of `α'² = α² + c/κ` under a vMF lobe, ≥ 0.
    /// Default the library's measured choice (`ndf_material_default_widening()`).
    pub widening: f64,
    /// `NDF_BRDF_TABULATED`: NUL-terminated JSON text of the tabulated BRDF (format in
    /// `docs/sh-brdf.md`), or NULL to read `tabulated_path`. Default NULL.
    pub tabulated_json: *const c_char,
    /// `NDF_BRDF_TABULATED`: path of a tabulated BRDF file, used when `tabulated_json` is NULL.
    /// Default NULL.
    pub tabulated_path: *const c_char,
}

/// The default BRDF description: GGX α = 0.1 without the g factor (F0 0.04 if turned on),
/// Blinn-Phong s = 64 and σ = 0.1 for the other models, no table.
#[unsafe(no_mangle)]
pub extern "C" fn ndf_material_options_default() -> ndf_material_options {
    let o = ndf_material_options {
        struct_size: size_of::<ndf_material_options>(),
        model: NDF_BRDF_GGX,
        s: 64.0,
        sigma: 0.1,
        alpha: 0.1,
        g: 0,
        f0: 0.04,
        widening: GGX_WIDENING_C,
        tabulated_json: std::ptr::null(),
        tabulated_path: std::ptr::null(),
    };
    guard_value(o, || o)
}

/// The library's GGX widening constant c (`α'² = α² + c/κ`), chosen by measurement.
#[unsafe(no_mangle)]
pub extern "C" fn ndf_material_default_widening() -> f64 {
    GGX_WIDENING_C
}

/// A BRDF (opaque): made by `ndf_material_new`, released by `ndf_material_free`. It never changes;
/// any number of threads may use it at once.
pub struct ndf_material {
    pub(crate) brdf: Brdf,
}

/// Makes a BRDF from `options` (checked: parameters in range; a tabulated BRDF's JSON parsed
/// and validated).
/// - `NDF_STATUS_INVALID_ARGUMENT` for an unknown model, a parameter out of range or a
///   malformed tabulated BRDF; `NDF_STATUS_READ` when `tabulated_path` cannot be read.
/// - `brdf_out`: receives the BRDF, to be released with `ndf_material_free`.
///
/// # Safety
/// `options` is NULL or initialized by `ndf_material_options_default()`, its strings NULL or
/// NUL-terminated; `brdf_out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_material_new(
    options: *const ndf_material_options,
    brdf_out: *mut *mut ndf_material,
) -> ndf_status {
    guard("ndf_material_new", || {
        // SAFETY (all blocks): the pointers are NULL or valid, as this function requires.
        let o = unsafe { read_options(options, "options", "ndf_material_options_default") }?;
        let out = Out::new(brdf_out, "brdf_out")?;
        let models = [
            NDF_BRDF_BLINN_PHONG,
            NDF_BRDF_TORRANCE_SPARROW,
            NDF_BRDF_LAMBERT,
            NDF_BRDF_GGX,
            NDF_BRDF_TABULATED,
        ];
        let brdf = match choose("model", o.model, &models)? {
            NDF_BRDF_BLINN_PHONG => Brdf::BlinnPhong { s: o.s },
            NDF_BRDF_TORRANCE_SPARROW => Brdf::TorranceSparrow { sigma: o.sigma },
            NDF_BRDF_LAMBERT => Brdf::Lambert,
            NDF_BRDF_GGX => Brdf::Ggx(Ggx {
                alpha: o.alpha,
                g: o.g != 0,
                f0: o.f0,
                widening: o.widening,
            }),
            _ => {
                let t = if !o.tabulated_json.is_null() {
                    let text = unsafe { c_str(o.tabulated_json, "tabulated_json") }?;
                    let text = text.to_str().map_err(|_| {
                        fail(
                            ndf_status::InvalidArgument,
                            "tabulated_json is not valid UTF-8",
                        )
                    })?;
                    Tabulated::from_json(text, "tabulated_json")?
                } else if !o.tabulated_path.is_null() {
                    let p = unsafe { c_str(o.tabulated_path, "tabulated_path") }?;
                    Tabulated::load(&super::path(p, "tabulated_path")?)?
                } else {
                    return Err(fail(
                        ndf_status::NullArgument,
                        "NDF_BRDF_TABULATED needs tabulated_json or tabulated_path",
                    ));
                };
                Brdf::Tabulated(Arc::new(t))
            }
        };
        brdf.validate()?;
        let handle = Box::into_raw(Box::new(ndf_material { brdf }));
        // SAFETY: writable (the caller's contract); released by ndf_material_free.
        unsafe { out.write(handle) };
        Ok(())
    })
}

/// Releases a BRDF. NULL is fine. Must not be called twice with the same BRDF.
///
/// # Safety
/// `brdf` is NULL or a BRDF from `ndf_material_new` not yet freed.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_material_free(brdf: *mut ndf_material) {
    guard_value((), || {
        if !brdf.is_null() {
            // SAFETY: made by Box::into_raw in ndf_material_new and freed once.
            drop(unsafe { Box::from_raw(brdf) });
        }
    })
}

/// The number of vMF lobes in GGX's mixture (`ndf_material_ggx_mixture`; the vMF shader's
/// uniform arrays `ndf_ggx_w[NDF_GGX_MIXTURE_LOBES]`, `ndf_ggx_eta[NDF_GGX_MIXTURE_LOBES]`).
pub const NDF_GGX_MIXTURE_LOBES: usize = 5;

/// GGX's D as a mixture of `NDF_GGX_MIXTURE_LOBES` unit-mass vMF lobes, fitted to the BRDF's α
/// (least squares, non-negative weights): the values of the vMF shader's uniform arrays
/// `ndf_ggx_w` (`weights_out`) and `ndf_ggx_eta` (`etas_out`, the concentrations), which its
/// default GGX rule (`NDF_VMF_SPECULAR_AUTO`) convolves in closed form with each NDF lobe.
/// Arrays left unset (GL's initial 0) make that shader fall back to the single widened lobe of
/// `NDF_VMF_SPECULAR_EQ20`.
/// - `NDF_STATUS_INVALID_ARGUMENT` for a BRDF other than GGX.
///
/// # Safety
/// `brdf` is NULL or a live BRDF; `weights_out` and `etas_out` are NULL or writable for
/// `NDF_GGX_MIXTURE_LOBES` doubles each.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_material_ggx_mixture(
    brdf: *const ndf_material,
    weights_out: *mut f64,
    etas_out: *mut f64,
) -> ndf_status {
    guard("ndf_material_ggx_mixture", || {
        // SAFETY: NULL or a live BRDF (the caller's contract).
        let b = unsafe { arg(brdf, "brdf") }?;
        if weights_out.is_null() {
            return Err(super::null("weights_out"));
        }
        if etas_out.is_null() {
            return Err(super::null("etas_out"));
        }
        let Brdf::Ggx(g) = &b.brdf else {
            return Err(fail(
                ndf_status::InvalidArgument,
                format!("{} has no GGX mixture (GGX only)", b.brdf.model()),
            ));
        };
        let m = crate::brdf::ggx_mixture::GgxMixture::of(g.alpha);
        // SAFETY: both writable for NDF_GGX_MIXTURE_LOBES doubles (the caller's contract).
        unsafe {
            std::ptr::copy_nonoverlapping(m.weights.as_ptr(), weights_out, NDF_GGX_MIXTURE_LOBES);
            std::ptr::copy_nonoverlapping(m.etas.as_ptr(), etas_out, NDF_GGX_MIXTURE_LOBES);
        }
        Ok(())
    })
}

/// The BRDF's `ρ̂_0 … ρ̂_lmax` (eq 11, Gauss–Legendre quadrature): the values of the SH
/// shader's uniform array `ndf_sh_rho` (Lambert: its closed forms π, 2π/3, π/4, …).
/// - `lmax`: 0 to 16. `out`: room for `capacity` doubles, at least `lmax + 1`
///   (`NDF_STATUS_BUFFER_TOO_SMALL` otherwise).
///
/// # Safety
/// `brdf` is NULL or a live BRDF; `out` is NULL or writable for `capacity` doubles.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_material_sh_coefficients(
    brdf: *const ndf_material,
    lmax: u32,
    out: *mut f64,
    capacity: usize,
) -> ndf_status {
    guard("ndf_material_sh_coefficients", || {
        // SAFETY: NULL or a live BRDF (the caller's contract).
        let b = unsafe { arg(brdf, "brdf") }?;
        if out.is_null() {
            return Err(super::null("out"));
        }
        if lmax as usize > crate::sh::MAX_LMAX {
            return Err(fail(
                ndf_status::InvalidArgument,
                format!("lmax {lmax} (expected 0 to {})", crate::sh::MAX_LMAX),
            ));
        }
        if capacity < lmax as usize + 1 {
            return Err(fail(
                ndf_status::BufferTooSmall,
                format!("{capacity} doubles for {} coefficients", lmax + 1),
            ));
        }
        let rho = match &b.brdf {
            Brdf::Lambert => (0..=lmax as usize)
                .map(crate::brdf::lambert_coefficient)
                .collect(),
            other => other.sh_coefficients(lmax as usize),
        };
        // SAFETY: writable for capacity ≥ rho.len() doubles (the caller's contract).
        unsafe { std::ptr::copy_nonoverlapping(rho.as_ptr(), out, rho.len()) };
        Ok(())
    })
}

/// The lobe's largest value (0 for Lambert): the SH shader's uniform `ndf_sh_peak`, where it
/// clamps the ringing of a truncated lobe.
///
/// # Safety
/// `brdf` is NULL or a live BRDF; `peak_out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_material_lobe_peak(
    brdf: *const ndf_material,
    peak_out: *mut f64,
) -> ndf_status {
    guard("ndf_material_lobe_peak", || {
        // SAFETY (both blocks): NULL or valid (the caller's contract).
        let b = unsafe { arg(brdf, "brdf") }?;
        let out = Out::new(peak_out, "peak_out")?;
        unsafe { out.write(b.brdf.peak()) };
        Ok(())
    })
}

/// The band limit the SH method needs for this BRDF (Sec 5.1): 2 for Lambert, `⌈√(4s)⌉` of
/// the equivalent Blinn-Phong exponent otherwise, at most 16.
///
/// # Safety
/// `brdf` is NULL or a live BRDF; `lmax_out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_material_suggested_lmax(
    brdf: *const ndf_material,
    lmax_out: *mut u32,
) -> ndf_status {
    guard("ndf_material_suggested_lmax", || {
        // SAFETY (both blocks): NULL or valid (the caller's contract).
        let b = unsafe { arg(brdf, "brdf") }?;
        let out = Out::new(lmax_out, "lmax_out")?;
        unsafe { out.write(b.brdf.suggested_lmax() as u32) };
        Ok(())
    })
}

/// The size of a tabulated BRDF's table, in texels: `width` angles × `height` rows (the
/// `ndf_brdf_table` texture). `NDF_STATUS_INVALID_ARGUMENT` for other models.
///
/// # Safety
/// `brdf` is NULL or a live BRDF; the out-pointers NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_material_table_size(
    brdf: *const ndf_material,
    width_out: *mut u32,
    height_out: *mut u32,
) -> ndf_status {
    guard("ndf_material_table_size", || {
        // SAFETY (all blocks): NULL or valid (the caller's contract).
        let b = unsafe { arg(brdf, "brdf") }?;
        let w = Out::new(width_out, "width_out")?;
        let h = Out::new(height_out, "height_out")?;
        tabulated(&b.brdf)?;
        unsafe {
            w.write(crate::brdf::tabulated::GRID as u32);
            h.write(crate::brdf::tabulated::KAPPA_ROWS as u32 + 1);
        }
        Ok(())
    })
}

/// Writes a tabulated BRDF's table (`width × height` floats, row-major, rows bottom to top
/// as `glTexImage2D` takes them with `GL_R32F`/`GL_RED`/`GL_FLOAT`): the texture the shader
/// samples as `ndf_brdf_table` with `texelFetch`. Computed on first use (about half a second).
/// - `out`: room for `capacity` floats, at least `width × height`
///   (`NDF_STATUS_BUFFER_TOO_SMALL` otherwise).
///
/// # Safety
/// `brdf` is NULL or a live BRDF; `out` is NULL or writable for `capacity` floats.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_material_table(
    brdf: *const ndf_material,
    out: *mut f32,
    capacity: usize,
) -> ndf_status {
    guard("ndf_material_table", || {
        // SAFETY: NULL or a live BRDF (the caller's contract).
        let b = unsafe { arg(brdf, "brdf") }?;
        if out.is_null() {
            return Err(super::null("out"));
        }
        let t = tabulated(&b.brdf)?;
        // A short buffer is refused before the table is computed (half a second).
        let len = crate::brdf::tabulated::GRID * (crate::brdf::tabulated::KAPPA_ROWS + 1);
        if capacity < len {
            return Err(fail(
                ndf_status::BufferTooSmall,
                format!("{capacity} floats for a table of {len}"),
            ));
        }
        let table = t.table();
        debug_assert_eq!(table.len(), len);
        // SAFETY: writable for capacity ≥ table.len() floats (the caller's contract).
        unsafe { std::ptr::copy_nonoverlapping(table.as_ptr(), out, table.len()) };
        Ok(())
    })
}

/// The tabulated BRDF behind `brdf`, or an error naming the model.
fn tabulated(brdf: &Brdf) -> super::Outcome<&Tabulated> {
    match brdf {
        Brdf::Tabulated(t) => Ok(t),
        other => Err(fail(
            ndf_status::InvalidArgument,
            format!("{other} has no table (only NDF_BRDF_TABULATED)"),
        )),
    }
}
