//! C API, bakes: bake a normal map with one method (options struct per method, progress
//! callback that can cancel), query the result, pack a level of a texture into a caller
//! buffer, write the bake to files as the command line does, free it. Wraps [`crate::bake`],
//! [`crate::pack`] and [`crate::output`].

use super::map::ndf_normal_map;
use super::{
    Out, Outcome, arg, c_str, choose, fail, guard, guard_value, index, ndf_status, path,
    read_options,
};
use crate::bake::{Bake, BakeOptions, FitMode, Method};
use crate::em::{AlignmentForm, EmOptions, KappaEstimator};
use crate::format::{Format, ValueRange};
use crate::methods::bake_with_progress;
use crate::output::InputInfo;
use std::ffi::{CString, c_char, c_int, c_void};

/// A filtering method: one of the `NDF_METHOD_*` values.
pub type ndf_method = u32;
/// Plain MIP-mapping of the normal: one texture `normal` (normalized mean normal).
pub const NDF_METHOD_PLAIN: ndf_method = 0;
/// Toksvig 2005: one texture `mean` (mean normal, its length in alpha).
pub const NDF_METHOD_TOKSVIG: ndf_method = 1;
/// LEAN mapping (Olano & Baker 2010): textures `slopes` and `cross` (slope moments, unbounded:
/// float formats only).
pub const NDF_METHOD_LEAN: ndf_method = 2;
/// Olano & North 1997: textures `mean`, `diagonal`, `offdiagonal` (9 moments).
pub const NDF_METHOD_OLANO: ndf_method = 3;
/// Tan et al. 2005: J planar Gaussians per texel, textures `gauss0` ... (float formats only).
pub const NDF_METHOD_TAN2005: ndf_method = 4;
/// The paper's von Mises–Fisher lobes (Han et al. 2007, Sec 7): textures `lobe0` ... holding
/// `(α, α·r)`, then `color0` ... holding `α·y` when the map has a feature image.
pub const NDF_METHOD_VMF: ndf_method = 5;
/// The spherical-harmonic NDF (Han et al. 2007, Sec 5): `(l*+1)²` coefficients in
/// `⌈(l*+1)²/4⌉` textures; any BRDF at shading time (`ndf_material_sh_coefficients`).
pub const NDF_METHOD_SH: ndf_method = 6;

/// The PBR bake for unmodified GGX metallic-roughness shaders (glTF, Filament, Unity, Unreal,
/// Godot): per level a `normal` texture (signed), a `metallic_roughness` texture in glTF's
/// channel layout (R occlusion, G perceptual roughness `√α′`, B metallic) and, with the
/// anisotropic option, an `anisotropy` texture (`KHR_materials_anisotropy`: direction, strength).
/// Made by `ndf_bake_pbr`; it has no ndfmap shader (the engine's own GGX shader reads it).
pub const NDF_METHOD_PBR: ndf_method = 7;

/// The `NDF_METHOD_*` values, in order: [`Method::ALL`] (the methods with an ndfmap shader; a
/// test checks they agree), then [`Method::Pbr`].
const METHODS: [Method; 8] = {
    let a = Method::ALL;
    [a[0], a[1], a[2], a[3], a[4], a[5], a[6], Method::Pbr]
};

/// A texel storage format for packing and writing: one of the `NDF_FORMAT_*` values. Every
/// format has four channels (RGBA) per texel, in the host's byte order, rows top to bottom.
pub type ndf_format = u32;
/// 32-bit float per channel, 16 bytes per texel (`GL_RGBA32F`, `GL_FLOAT`).
pub const NDF_FORMAT_RGBA_F32: ndf_format = 0;
/// 16-bit float per channel, 8 bytes per texel (`GL_RGBA16F`, `GL_HALF_FLOAT`).
pub const NDF_FORMAT_RGBA_F16: ndf_format = 1;
/// 16-bit unsigned-normalized, 8 bytes per texel (`GL_RGBA16`, `GL_UNSIGNED_SHORT`); channels
/// whose range is `NDF_VALUE_RANGE_SIGNED` store `0.5 + 0.5·v`.
pub const NDF_FORMAT_RGBA_UNORM16: ndf_format = 2;
/// 8-bit unsigned-normalized, 4 bytes per texel (`GL_RGBA8`, `GL_UNSIGNED_BYTE`); signed
/// channels biased as for `NDF_FORMAT_RGBA_UNORM16`.
pub const NDF_FORMAT_RGBA_UNORM8: ndf_format = 3;

/// The `NDF_FORMAT_*` values, in order.
pub(crate) const FORMATS: [Format; 4] = [Format::F32, Format::F16, Format::Unorm16, Format::Unorm8];

/// The range of a channel's values: one of the `NDF_VALUE_RANGE_*` values.
pub type ndf_value_range = u32;
/// In [0, 1], stored as is by unorm formats.
pub const NDF_VALUE_RANGE_UNIT: ndf_value_range = 0;
/// In [−1, 1]; unorm formats store `0.5 + 0.5·v` (the shader undoes the bias).
pub const NDF_VALUE_RANGE_SIGNED: ndf_value_range = 1;
/// Unbounded: float formats only.
pub const NDF_VALUE_RANGE_ANY: ndf_value_range = 2;

/// Which M-step maximizes the vMF coherence prior (Han et al. 2007, Sec 7.3 and appendix):
/// one of `NDF_ALIGN_FORM_*`.
pub type ndf_align_form = u32;
/// Eq 29, the appendix: `mu_j = normalize(kappa_j alpha_j r_j + C sum_k alpha_jk mu_jk)`; sharp,
/// heavy lobes stay on their normals. The default; C about 1.
pub const NDF_ALIGN_FORM_APPENDIX: ndf_align_form = 0;
/// Eq 23, the main text: `mu_j = normalize(r_j + C sum_k alpha_jk mu_jk)`, the same pull for
/// every lobe; C about 0.1.
pub const NDF_ALIGN_FORM_MAIN_TEXT: ndf_align_form = 1;

/// How hard the vMF baker fits each texel: one of `NDF_FIT_*` (the library's `FitMode`).
pub type ndf_fit_mode = u32;
/// At most 8 EM iterations per texel (2 in the aligned pass), started from the finer level's
/// lobes; on texels of at least 256 normals (level 4 and coarser of a power-of-two map),
/// `em_max_iterations` in the aligned pass; on texels of at least 4096 normals (level 6 and
/// coarser), `em_max_iterations` in the unaligned pass and 6 in the aligned one. The default.
pub const NDF_FIT_BALANCED: ndf_fit_mode = 0;
/// At most 3 EM iterations per texel (1 in the aligned pass): about twice as fast as
/// `NDF_FIT_BALANCED`, with a measurably worse fit at the coarse levels.
pub const NDF_FIT_FAST: ndf_fit_mode = 1;
/// `em_max_iterations` and `em_tolerance` as given, in both passes: the exhaustive fit.
pub const NDF_FIT_EXACT: ndf_fit_mode = 2;

/// How vMF EM derives κ from the mean resultant length: one of `NDF_KAPPA_ESTIMATOR_*`.
pub type ndf_kappa_estimator = u32;
/// Banerjee's approximation `(3r − r³)/(1 − r²)` (the paper's; the shader inverts it). Default.
pub const NDF_KAPPA_ESTIMATOR_BANERJEE: ndf_kappa_estimator = 0;
/// The exact maximum-likelihood κ (slower; every EM step then increases the likelihood).
pub const NDF_KAPPA_ESTIMATOR_EXACT: ndf_kappa_estimator = 1;

/// A progress callback, called on the thread that called the bake with the fraction done:
/// first 0, then non-decreasing (the same value again while a long piece of work runs: it is
/// called at least every 50 ms while the bake runs, unless the bake was called from a thread
/// of a Rust rayon pool), last 1. Return nonzero to go on, 0 to cancel: the bake stops within
/// a fraction of a second, fails with `NDF_STATUS_CANCELLED` and makes no handle, and the
/// callback is not called again.
/// `user_data` is the options' `progress_user_data`. The callback must not throw (C++) and must
/// not call back into the bake being made.
pub type ndf_progress_fn =
    Option<unsafe extern "C" fn(fraction: f32, user_data: *mut c_void) -> c_int>;

/// Options of the baselines (`NDF_METHOD_PLAIN`, `_TOKSVIG`, `_LEAN`, `_OLANO`). Initialize
/// with `ndf_baseline_options_default()`.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct ndf_baseline_options {
    /// `sizeof(ndf_baseline_options)`, set by `ndf_baseline_options_default()`.
    pub struct_size: usize,
    /// Progress callback, or NULL (default) for none.
    pub progress: ndf_progress_fn,
    /// Passed to `progress` unchanged. Default NULL.
    pub progress_user_data: *mut c_void,
    /// Memory budget of the bake in bytes: a bake whose estimated peak (from the map's size and
    /// the method) exceeds it fails with `NDF_STATUS_MEMORY_BUDGET` before it starts. Default
    /// 0: half the machine's memory (its control group's limit when lower).
    pub memory_limit: u64,
}

/// Options of the vMF bake (`NDF_METHOD_VMF`, the paper's method). Initialize with
/// `ndf_vmf_options_default()`.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct ndf_vmf_options {
    /// `sizeof(ndf_vmf_options)`, set by `ndf_vmf_options_default()`.
    pub struct_size: usize,
    /// Lobes per texel J, 1 to 8. Default 6 (the paper's choice). One texture per lobe.
    pub lobes: u32,
    /// Nonzero: coherent lobes (Sec 7.3), so that hardware trilinear filtering of the lobe
    /// textures is valid; 0 (default): each texel fitted on its own.
    pub aligned: u32,
    /// Alignment strength C when `aligned`, 0 to 1000. Default 0.03 (for eq 29; use about 0.1
    /// with `NDF_ALIGN_FORM_MAIN_TEXT`).
    pub align_strength: f64,
    /// The alignment's M-step, `NDF_ALIGN_FORM_*`. Default `NDF_ALIGN_FORM_APPENDIX`.
    pub align_form: ndf_align_form,
    /// How hard each texel is fitted, `NDF_FIT_*`. Default `NDF_FIT_BALANCED`. (This field
    /// was `approximate` before 0.2; its old nonzero value, the removed approximate mode,
    /// now selects `NDF_FIT_FAST`.)
    pub mode: ndf_fit_mode,
    /// Most EM iterations per texel, 1 to 1000: the cap of `NDF_FIT_EXACT`, an upper bound
    /// for the other modes. Default 20.
    pub em_max_iterations: u32,
    /// EM convergence tolerance on the mean log-likelihood, 0 to 1: that of `NDF_FIT_EXACT`,
    /// a lower bound for the other modes. Default 1e-6.
    pub em_tolerance: f64,
    /// κ estimator, `NDF_KAPPA_ESTIMATOR_*`. Default `NDF_KAPPA_ESTIMATOR_BANERJEE`.
    pub kappa_estimator: ndf_kappa_estimator,
    /// Progress callback, or NULL (default) for none.
    pub progress: ndf_progress_fn,
    /// Passed to `progress` unchanged. Default NULL.
    pub progress_user_data: *mut c_void,
    /// Memory budget of the bake in bytes, as in `ndf_baseline_options`. Default 0: half the
    /// machine's memory.
    pub memory_limit: u64,
}

/// Options of the Tan et al. 2005 bake (`NDF_METHOD_TAN2005`). Initialize with
/// `ndf_tan2005_options_default()`.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct ndf_tan2005_options {
    /// `sizeof(ndf_tan2005_options)`, set by `ndf_tan2005_options_default()`.
    pub struct_size: usize,
    /// Gaussians per texel J, 1 to 8. Default 6. One texture per Gaussian.
    pub lobes: u32,
    /// Nonzero: coherent Gaussians (Tan's alignment prior); 0 (default): unaligned.
    pub aligned: u32,
    /// Prior strength c when `aligned`, 0 to 1000. Default 1 (Tan's choice).
    pub align_strength: f64,
    /// Most EM iterations per texel, 1 to 1000. Default 20.
    pub em_max_iterations: u32,
    /// EM convergence tolerance, 0 to 1. Default 1e-6.
    pub em_tolerance: f64,
    /// Progress callback, or NULL (default) for none.
    pub progress: ndf_progress_fn,
    /// Passed to `progress` unchanged. Default NULL.
    pub progress_user_data: *mut c_void,
    /// Memory budget of the bake in bytes, as in `ndf_baseline_options`. Default 0: half the
    /// machine's memory.
    pub memory_limit: u64,
}

/// Options of the spherical-harmonic bake (`NDF_METHOD_SH`). Initialize with
/// `ndf_sh_options_default()`.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct ndf_sh_options {
    /// `sizeof(ndf_sh_options)`, set by `ndf_sh_options_default()`.
    pub struct_size: usize,
    /// Band limit l*, 0 to 16. Default 4 (25 coefficients in 7 textures). Lambert needs 2;
    /// Blinn-Phong about `√(4s)` (`ndf_material_suggested_lmax`). A GLSL shader samples at most 32
    /// textures: l* ≤ 10.
    pub lmax: u32,
    /// Progress callback, or NULL (default) for none.
    pub progress: ndf_progress_fn,
    /// Passed to `progress` unchanged. Default NULL.
    pub progress_user_data: *mut c_void,
    /// Memory budget of the bake in bytes, as in `ndf_baseline_options`. Default 0: half the
    /// machine's memory.
    pub memory_limit: u64,
}

/// Options of the PBR bake (`NDF_METHOD_PBR`, `ndf_bake_pbr`). Initialize with
/// `ndf_pbr_options_default()`.
///
/// The material maps are optional: each NULL (default) or `width × height` floats of the
/// map's size, row-major (top row first), every value finite and in [0, 1]
/// (`NDF_STATUS_BAD_FEATURES` names the count of bad values otherwise). They are read during
/// the call only. Roughness is linear data (perceptual `√α`, glTF's): convert 8-bit values
/// with `v / 255`, never through the sRGB curve.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct ndf_pbr_options {
    /// `sizeof(ndf_pbr_options)`, set by `ndf_pbr_options_default()`.
    pub struct_size: usize,
    /// Perceptual roughness `√α` of every texel when `roughness_map` is NULL, 0 to 1.
    /// Default 0.5.
    pub roughness: f64,
    /// Nonzero: fit an anisotropic GGX lobe per texel and add the `anisotropy` texture
    /// (`KHR_materials_anisotropy`). Default 0.
    pub anisotropic: u32,
    /// Per-texel perceptual roughness (its square is the texel's base α), or NULL.
    pub roughness_map: *const f32,
    /// Per-texel metallic, or NULL (metallic 0): box-filtered into the B channel.
    pub metallic_map: *const f32,
    /// Per-texel ambient occlusion, or NULL (occlusion 1): box-filtered into the R channel.
    pub occlusion_map: *const f32,
    /// Progress callback, or NULL (default) for none.
    pub progress: ndf_progress_fn,
    /// Passed to `progress` unchanged. Default NULL.
    pub progress_user_data: *mut c_void,
    /// Memory budget of the bake in bytes, as in `ndf_baseline_options`. Default 0: half the
    /// machine's memory.
    pub memory_limit: u64,
    /// The widest view and light angle from the normal the renderer shows, in degrees, 20 to
    /// 90: the fit's light/view pairs are scaled into it. Default 0: the standard pairs
    /// (grazing ones to 74° included).
    pub fit_max_angle: f64,
    /// Nonzero: keep every level's normal at the footprint's mean direction (the plain MIP
    /// chain's normal) and fit only the roughness (and anisotropy), for engines that make their
    /// own normal mips or shade mostly diffuse materials. Default 0: the fitted normal.
    pub mean_normal: u32,
}

/// The default PBR options: perceptual roughness 0.5 everywhere, isotropic, no material maps,
/// no progress callback, the default memory budget.
#[unsafe(no_mangle)]
pub extern "C" fn ndf_pbr_options_default() -> ndf_pbr_options {
    let d = crate::bake::PbrOptions::default();
    let o = ndf_pbr_options {
        struct_size: size_of::<ndf_pbr_options>(),
        roughness: d.roughness,
        anisotropic: u32::from(d.anisotropic),
        roughness_map: std::ptr::null(),
        metallic_map: std::ptr::null(),
        occlusion_map: std::ptr::null(),
        progress: None,
        progress_user_data: std::ptr::null_mut(),
        memory_limit: 0,
        fit_max_angle: d.fit_max_angle.unwrap_or(0.0),
        mean_normal: u32::from(d.mean_normal),
    };
    guard_value(o, || o)
}

/// The default SH options: l* = 4, no progress callback, the default memory budget.
#[unsafe(no_mangle)]
pub extern "C" fn ndf_sh_options_default() -> ndf_sh_options {
    let o = ndf_sh_options {
        struct_size: size_of::<ndf_sh_options>(),
        lmax: BakeOptions::default().lmax as u32,
        progress: None,
        progress_user_data: std::ptr::null_mut(),
        memory_limit: 0,
    };
    guard_value(o, || o)
}

/// The default baseline options: no progress callback.
#[unsafe(no_mangle)]
pub extern "C" fn ndf_baseline_options_default() -> ndf_baseline_options {
    let o = ndf_baseline_options {
        struct_size: size_of::<ndf_baseline_options>(),
        progress: None,
        progress_user_data: std::ptr::null_mut(),
        memory_limit: 0,
    };
    guard_value(o, || o)
}

/// The default vMF options: 6 unaligned lobes, balanced fit (`NDF_FIT_BALANCED`), 20 EM
/// iterations and tolerance 1e-6 for the exact mode, Banerjee's κ, no progress callback.
#[unsafe(no_mangle)]
pub extern "C" fn ndf_vmf_options_default() -> ndf_vmf_options {
    let d = BakeOptions::default();
    let o = ndf_vmf_options {
        struct_size: size_of::<ndf_vmf_options>(),
        lobes: d.lobes as u32,
        aligned: 0,
        align_strength: d.align_form.default_strength(),
        align_form: NDF_ALIGN_FORM_APPENDIX,
        mode: NDF_FIT_BALANCED,
        em_max_iterations: d.em.max_iterations,
        em_tolerance: d.em.tolerance,
        kappa_estimator: NDF_KAPPA_ESTIMATOR_BANERJEE,
        progress: None,
        progress_user_data: std::ptr::null_mut(),
        memory_limit: 0,
    };
    guard_value(o, || o)
}

/// The default Tan 2005 options: 6 unaligned Gaussians, 20 EM iterations, tolerance 1e-6, no
/// progress callback.
#[unsafe(no_mangle)]
pub extern "C" fn ndf_tan2005_options_default() -> ndf_tan2005_options {
    let d = BakeOptions::default();
    let o = ndf_tan2005_options {
        struct_size: size_of::<ndf_tan2005_options>(),
        lobes: d.lobes as u32,
        aligned: 0,
        align_strength: crate::tan2005::DEFAULT_ALIGN_STRENGTH,
        em_max_iterations: d.em.max_iterations,
        em_tolerance: d.em.tolerance,
        progress: None,
        progress_user_data: std::ptr::null_mut(),
        memory_limit: 0,
    };
    guard_value(o, || o)
}

/// A baked set of filtered textures (opaque): per texture an RGBA MIP chain, finest level
/// first, down to 1×1. Made by `ndf_bake_baseline`, `ndf_bake_vmf`, `ndf_bake_tan2005`,
/// `ndf_bake_sh` or `ndf_bake_pbr`; released by `ndf_bake_free`. A bake never changes: any number of threads may query, pack
/// and write it at once.
pub struct ndf_bake {
    pub(crate) bake: Bake,
    pub(crate) input: InputInfo,
    /// Per texture: its name, then the meaning of R, G, B, A, NUL-terminated for C.
    names: Vec<[CString; 5]>,
}

/// The C string of a texture or channel name (they are identifiers; never contain NUL).
fn c_name(s: &str) -> CString {
    CString::new(s).unwrap_or_default()
}

/// Bakes `map` with `method` and stores the handle in `out`.
///
/// # Safety
/// `progress` is NULL or a callback that may be called with `user_data`; `out` is writable.
unsafe fn run(
    map: &ndf_normal_map,
    method: Method,
    options: &BakeOptions,
    progress: ndf_progress_fn,
    user_data: *mut c_void,
    out: Out<*mut ndf_bake>,
) -> Outcome {
    // SAFETY: forwarded from this function's contract.
    unsafe {
        run_with(map, progress, user_data, out, |report| {
            bake_with_progress(&map.map, method, options, report)
        })
    }
}

/// Runs `make` (a bake of `map` reporting to a progress callback) and stores the handle in
/// `out`.
///
/// # Safety
/// As for [`run`].
unsafe fn run_with(
    map: &ndf_normal_map,
    progress: ndf_progress_fn,
    user_data: *mut c_void,
    out: Out<*mut ndf_bake>,
    make: impl FnOnce(&mut dyn FnMut(f32) -> bool) -> crate::error::Result<Bake>,
) -> Outcome {
    let mut report = |fraction: f32| match progress {
        // SAFETY: a callback of type ndf_progress_fn with the caller's user data, called on
        // the caller's thread (the function's contract).
        Some(callback) => (unsafe { callback(fraction, user_data) }) != 0,
        None => true,
    };
    let bake = make(&mut report)?;
    let names = bake
        .textures
        .iter()
        .map(|t| {
            let [r, g, b, a] = t.channels.map(c_name);
            [c_name(t.name), r, g, b, a]
        })
        .collect();
    let handle = ndf_bake {
        bake,
        input: map.input.clone(),
        names,
    };
    // SAFETY: writable (the caller's contract); the Box is released by ndf_bake_free.
    unsafe { out.write(Box::into_raw(Box::new(handle))) };
    Ok(())
}

/// Bakes a baseline method (plain, Toksvig, LEAN, Olano–North) of `map`.
/// - `method`: `NDF_METHOD_PLAIN`, `_TOKSVIG`, `_LEAN` or `_OLANO`; the mixtures have their
///   own functions (`NDF_STATUS_INVALID_ARGUMENT` otherwise).
/// - `options`: from `ndf_baseline_options_default()`.
/// - `bake_out`: receives the bake, to be released with `ndf_bake_free`.
///
/// # Safety
/// `map` is NULL or a live map; `options` is NULL or initialized by
/// `ndf_baseline_options_default()`; `bake_out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_bake_baseline(
    map: *const ndf_normal_map,
    method: ndf_method,
    options: *const ndf_baseline_options,
    bake_out: *mut *mut ndf_bake,
) -> ndf_status {
    guard("ndf_bake_baseline", || {
        // SAFETY (all blocks): the pointers are NULL or valid, as this function requires.
        let map = unsafe { arg(map, "map") }?;
        let m = choose("method", method, &METHODS)?;
        let o = unsafe { read_options(options, "options", "ndf_baseline_options_default") }?;
        let out = Out::new(bake_out, "bake_out")?;
        if !Method::BASELINES.contains(&m) {
            return Err(fail(
                ndf_status::InvalidArgument,
                format!("method {m} is not a baseline (use ndf_bake_{m})"),
            ));
        }
        let none = BakeOptions {
            memory_limit: super::memory_limit(o.memory_limit),
            ..BakeOptions::default()
        };
        unsafe { run(map, m, &none, o.progress, o.progress_user_data, out) }
    })
}

/// Bakes the paper's vMF lobes (Algorithm 1) of `map`; with a feature image attached, the
/// colour per lobe too (eq 22).
/// - `options`: from `ndf_vmf_options_default()`; out-of-range values give
///   `NDF_STATUS_INVALID_ARGUMENT`.
/// - `bake_out`: receives the bake, to be released with `ndf_bake_free`.
/// - A cancelled bake returns `NDF_STATUS_CANCELLED`.
///
/// # Safety
/// As for `ndf_bake_baseline`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_bake_vmf(
    map: *const ndf_normal_map,
    options: *const ndf_vmf_options,
    bake_out: *mut *mut ndf_bake,
) -> ndf_status {
    guard("ndf_bake_vmf", || {
        // SAFETY (all blocks): the pointers are NULL or valid, as this function requires.
        let map = unsafe { arg(map, "map") }?;
        let o = unsafe { read_options(options, "options", "ndf_vmf_options_default") }?;
        let out = Out::new(bake_out, "bake_out")?;
        let kappa = [KappaEstimator::Banerjee, KappaEstimator::Exact];
        let forms = [AlignmentForm::Appendix, AlignmentForm::MainText];
        let bake_options = BakeOptions {
            lobes: o.lobes as usize,
            align: (o.aligned != 0).then_some(o.align_strength),
            align_form: choose("align_form", o.align_form, &forms)?,
            mode: choose(
                "mode",
                o.mode,
                &[FitMode::Balanced, FitMode::Fast, FitMode::Exact],
            )?,
            em: EmOptions {
                max_iterations: o.em_max_iterations,
                tolerance: o.em_tolerance,
                kappa_estimator: choose("kappa_estimator", o.kappa_estimator, &kappa)?,
                ..EmOptions::default()
            },
            memory_limit: super::memory_limit(o.memory_limit),
            ..BakeOptions::default()
        };
        unsafe {
            run(
                map,
                Method::Vmf,
                &bake_options,
                o.progress,
                o.progress_user_data,
                out,
            )
        }
    })
}

/// Bakes the spherical-harmonic NDF of `map` (Sec 5): per texel the coefficients
/// `sqrt(4π/(2l+1))·γ_lm` for l ≤ l*, each in [−1, 1], four per texture in (l, m) order (the
/// bake's channel names say which: `c<l>,<m>`).
/// - `options`: from `ndf_sh_options_default()`; `lmax` above 16 gives
///   `NDF_STATUS_INVALID_ARGUMENT`.
/// - `bake_out`, cancellation: as for `ndf_bake_vmf`.
///
/// # Safety
/// As for `ndf_bake_baseline`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_bake_sh(
    map: *const ndf_normal_map,
    options: *const ndf_sh_options,
    bake_out: *mut *mut ndf_bake,
) -> ndf_status {
    guard("ndf_bake_sh", || {
        // SAFETY (all blocks): the pointers are NULL or valid, as this function requires.
        let map = unsafe { arg(map, "map") }?;
        let o = unsafe { read_options(options, "options", "ndf_sh_options_default") }?;
        let out = Out::new(bake_out, "bake_out")?;
        let bake_options = BakeOptions {
            lmax: o.lmax as usize,
            memory_limit: super::memory_limit(o.memory_limit),
            ..BakeOptions::default()
        };
        unsafe {
            run(
                map,
                Method::Sh,
                &bake_options,
                o.progress,
                o.progress_user_data,
                out,
            )
        }
    })
}

/// Bakes Tan et al. 2005's planar Gaussian mixture of `map`.
/// - `options`: from `ndf_tan2005_options_default()`; out-of-range values give
///   `NDF_STATUS_INVALID_ARGUMENT`.
/// - `bake_out`, cancellation: as for `ndf_bake_vmf`.
///
/// # Safety
/// As for `ndf_bake_baseline`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_bake_tan2005(
    map: *const ndf_normal_map,
    options: *const ndf_tan2005_options,
    bake_out: *mut *mut ndf_bake,
) -> ndf_status {
    guard("ndf_bake_tan2005", || {
        // SAFETY (all blocks): the pointers are NULL or valid, as this function requires.
        let map = unsafe { arg(map, "map") }?;
        let o = unsafe { read_options(options, "options", "ndf_tan2005_options_default") }?;
        let out = Out::new(bake_out, "bake_out")?;
        let bake_options = BakeOptions {
            lobes: o.lobes as usize,
            align: (o.aligned != 0).then_some(o.align_strength),
            align_form: AlignmentForm::default(),
            mode: FitMode::default(),
            em: EmOptions {
                max_iterations: o.em_max_iterations,
                tolerance: o.em_tolerance,
                ..EmOptions::default()
            },
            memory_limit: super::memory_limit(o.memory_limit),
            ..BakeOptions::default()
        };
        unsafe {
            run(
                map,
                Method::Tan2005,
                &bake_options,
                o.progress,
                o.progress_user_data,
                out,
            )
        }
    })
}

/// Bakes the PBR textures of `map` (`NDF_METHOD_PBR`): per level a normal and a GGX roughness
/// fitted so that one GGX lobe per texel, sampled with ordinary trilinear filtering by an
/// unmodified metallic-roughness shader, reproduces the footprint's average shading (the
/// library's `pbr` module; `docs/pbr.md` has the measurements).
/// - `options`: from `ndf_pbr_options_default()`; a roughness outside [0, 1] or a
///   `fit_max_angle` other than 0 outside [20, 90] (or NaN) gives `NDF_STATUS_INVALID_ARGUMENT`, a material map with a value that is not finite or not in
///   [0, 1] gives `NDF_STATUS_BAD_FEATURES`.
/// - `bake_out`, cancellation: as for `ndf_bake_vmf`.
///
/// # Safety
/// As for `ndf_bake_baseline`; and each of `options`' material maps is NULL or points to
/// `width × height` readable floats of `map`'s size.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_bake_pbr(
    map: *const ndf_normal_map,
    options: *const ndf_pbr_options,
    bake_out: *mut *mut ndf_bake,
) -> ndf_status {
    guard("ndf_bake_pbr", || {
        // SAFETY (all blocks): the pointers are NULL or valid, as this function requires.
        let map = unsafe { arg(map, "map") }?;
        let o = unsafe { read_options(options, "options", "ndf_pbr_options_default") }?;
        let out = Out::new(bake_out, "bake_out")?;
        let texels = map.map.width() as usize * map.map.height() as usize;
        let read = |p: *const f32| {
            // SAFETY: NULL or `texels` readable floats (this function's contract).
            (!p.is_null()).then(|| unsafe { std::slice::from_raw_parts(p, texels) }.to_vec())
        };
        let maps = crate::pbr::PbrMaps {
            roughness: read(o.roughness_map),
            metallic: read(o.metallic_map),
            occlusion: read(o.occlusion_map),
        };
        let bake_options = BakeOptions {
            pbr: crate::bake::PbrOptions {
                roughness: o.roughness,
                anisotropic: o.anisotropic != 0,
                fit_max_angle: (o.fit_max_angle != 0.0).then_some(o.fit_max_angle),
                mean_normal: o.mean_normal != 0,
            },
            memory_limit: super::memory_limit(o.memory_limit),
            ..BakeOptions::default()
        };
        unsafe {
            run_with(map, o.progress, o.progress_user_data, out, |report| {
                crate::methods::bake_pbr_with_progress(&map.map, &bake_options, &maps, report)
            })
        }
    })
}

/// Runs a query body for entry point `function` with the bake behind `bake`, writing the
/// query's value to `out` on success.
///
/// # Safety
/// `bake` is NULL or a live bake; `out` is NULL or writable.
unsafe fn query<T>(
    function: &str,
    bake: *const ndf_bake,
    out: *mut T,
    out_name: &str,
    body: impl FnOnce(&ndf_bake) -> Outcome<T>,
) -> ndf_status {
    guard(function, || {
        // SAFETY: NULL or a live bake, as the caller guarantees.
        let b = unsafe { arg(bake, "bake") }?;
        let out = Out::new(out, out_name)?;
        let value = body(b)?;
        // SAFETY: writable, as the caller guarantees.
        unsafe { out.write(value) };
        Ok(())
    })
}

/// The method that made the bake (`NDF_METHOD_*`).
///
/// # Safety
/// `bake` is NULL or a live bake; `method_out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_bake_method(
    bake: *const ndf_bake,
    method_out: *mut ndf_method,
) -> ndf_status {
    // SAFETY: forwarded from this function's contract.
    unsafe {
        query("ndf_bake_method", bake, method_out, "method_out", |b| {
            let i = METHODS.iter().position(|&m| m == b.bake.method);
            Ok(i.unwrap_or_default() as ndf_method)
        })
    }
}

/// Lobes (mixture components) per texel J for vMF and Tan 2005; 0 for the baselines. The
/// first J textures are the lobes; with colour, the next J are their colours.
///
/// # Safety
/// `bake` is NULL or a live bake; `count_out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_bake_lobe_count(
    bake: *const ndf_bake,
    count_out: *mut u32,
) -> ndf_status {
    // SAFETY: forwarded from this function's contract.
    unsafe {
        query("ndf_bake_lobe_count", bake, count_out, "count_out", |b| {
            Ok(b.bake.lobes as u32)
        })
    }
}

/// Number of MIP levels: from the map's size (level 0) halving, rounded down, to 1×1.
///
/// # Safety
/// `bake` is NULL or a live bake; `count_out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_bake_level_count(
    bake: *const ndf_bake,
    count_out: *mut u32,
) -> ndf_status {
    // SAFETY: forwarded from this function's contract.
    unsafe {
        query("ndf_bake_level_count", bake, count_out, "count_out", |b| {
            Ok(b.bake.level_count() as u32)
        })
    }
}

/// Width and height of level `level` (0 = finest), as `glTexImage2D` takes them.
/// - `level` below the level count (`NDF_STATUS_OUT_OF_RANGE` otherwise).
///
/// # Safety
/// `bake` is NULL or a live bake; the out-pointers are NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_bake_level_size(
    bake: *const ndf_bake,
    level: u32,
    width_out: *mut u32,
    height_out: *mut u32,
) -> ndf_status {
    guard("ndf_bake_level_size", || {
        // SAFETY (all blocks): the pointers are NULL or valid, as this function requires.
        let b = unsafe { arg(bake, "bake") }?;
        let (w, h) = (
            Out::new(width_out, "width_out")?,
            Out::new(height_out, "height_out")?,
        );
        let (width, height) = b.bake.sizes[index("level", level, b.bake.level_count())?];
        unsafe { w.write(width) };
        unsafe { h.write(height) };
        Ok(())
    })
}

/// Number of textures (RGBA MIP chains) a shader samples; each is packed and uploaded on its
/// own. Their meaning: `ndf_bake_texture_name` and `ndf_bake_texture_channel`.
///
/// # Safety
/// `bake` is NULL or a live bake; `count_out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_bake_texture_count(
    bake: *const ndf_bake,
    count_out: *mut u32,
) -> ndf_status {
    // SAFETY: forwarded from this function's contract.
    unsafe {
        query(
            "ndf_bake_texture_count",
            bake,
            count_out,
            "count_out",
            |b| Ok(b.bake.textures.len() as u32),
        )
    }
}

/// The name of texture `texture` (`"lobe0"`, `"color0"`, `"mean"`, ...), as used in file names
/// and the manifest.
/// - The string belongs to the bake and lives as long as it; do not free it.
///
/// # Safety
/// `bake` is NULL or a live bake; `name_out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_bake_texture_name(
    bake: *const ndf_bake,
    texture: u32,
    name_out: *mut *const c_char,
) -> ndf_status {
    // SAFETY: forwarded from this function's contract.
    unsafe {
        query("ndf_bake_texture_name", bake, name_out, "name_out", |b| {
            Ok(b.names[index("texture", texture, b.names.len())?][0].as_ptr())
        })
    }
}

/// What channel `channel` (0 = R, 1 = G, 2 = B, 3 = A) of texture `texture` holds
/// (`"alpha*r_x"`, `"mean_length"`, `"unused"`, ...) and its value range
/// (`NDF_VALUE_RANGE_*`, which decides the unorm bias).
/// - The string belongs to the bake and lives as long as it; do not free it.
///
/// # Safety
/// `bake` is NULL or a live bake; the out-pointers are NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_bake_texture_channel(
    bake: *const ndf_bake,
    texture: u32,
    channel: u32,
    meaning_out: *mut *const c_char,
    range_out: *mut ndf_value_range,
) -> ndf_status {
    guard("ndf_bake_texture_channel", || {
        // SAFETY (all blocks): the pointers are NULL or valid, as this function requires.
        let b = unsafe { arg(bake, "bake") }?;
        let meaning = Out::new(meaning_out, "meaning_out")?;
        let range = Out::new(range_out, "range_out")?;
        let t = index("texture", texture, b.names.len())?;
        let c = index("channel", channel, 4)?;
        let r = match b.bake.textures[t].ranges[c] {
            ValueRange::Unit => NDF_VALUE_RANGE_UNIT,
            ValueRange::Signed => NDF_VALUE_RANGE_SIGNED,
            ValueRange::Any => NDF_VALUE_RANGE_ANY,
        };
        unsafe { meaning.write(b.names[t][1 + c].as_ptr()) };
        unsafe { range.write(r) };
        Ok(())
    })
}

/// Validated texture, level and format of a pack call, and the byte length it needs.
fn pack_args(b: &ndf_bake, texture: u32, level: u32, format: ndf_format) -> Outcome<Packing> {
    let texture = index("texture", texture, b.bake.textures.len())?;
    let level = index("level", level, b.bake.level_count())?;
    let format = choose("format", format, &FORMATS)?;
    crate::pack::check(&b.bake, texture, format)
        .map_err(|e| fail(ndf_status::UnsupportedFormat, e.to_string()))?;
    let bytes = crate::pack::packed_len(&b.bake, level, format);
    Ok(Packing {
        texture,
        level,
        format,
        bytes,
    })
}

/// A checked pack request.
struct Packing {
    texture: usize,
    level: usize,
    format: Format,
    bytes: usize,
}

/// Bytes that `ndf_bake_pack` writes for level `level` of texture `texture` in `format`:
/// width × height × 4 channels × the format's channel size.
/// - `NDF_STATUS_OUT_OF_RANGE` for a texture or level past the end,
///   `NDF_STATUS_INVALID_ARGUMENT` for an unknown format, `NDF_STATUS_UNSUPPORTED_FORMAT` when
///   the format cannot hold the texture.
///
/// # Safety
/// `bake` is NULL or a live bake; `size_out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_bake_packed_size(
    bake: *const ndf_bake,
    texture: u32,
    level: u32,
    format: ndf_format,
    size_out: *mut usize,
) -> ndf_status {
    // SAFETY: forwarded from this function's contract.
    unsafe {
        query("ndf_bake_packed_size", bake, size_out, "size_out", |b| {
            Ok(pack_args(b, texture, level, format)?.bytes)
        })
    }
}

/// Packs level `level` of texture `texture` into `buffer` in `format`: RGBA texels, rows top
/// to bottom, tightly packed, host byte order — the data `glTexImage2D` takes.
/// - `buffer`, `capacity`: the destination and its size in bytes; it must hold
///   `ndf_bake_packed_size()` bytes (`NDF_STATUS_BUFFER_TOO_SMALL` otherwise, and nothing is
///   written). Any alignment.
/// - `written_out`: receives the number of bytes written.
/// - Other failures as for `ndf_bake_packed_size`.
///
/// # Safety
/// `bake` is NULL or a live bake; `buffer` is NULL or writable for `capacity` bytes;
/// `written_out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_bake_pack(
    bake: *const ndf_bake,
    texture: u32,
    level: u32,
    format: ndf_format,
    buffer: *mut c_void,
    capacity: usize,
    written_out: *mut usize,
) -> ndf_status {
    guard("ndf_bake_pack", || {
        // SAFETY: NULL or a live bake, as this function requires.
        let b = unsafe { arg(bake, "bake") }?;
        if buffer.is_null() {
            return Err(super::null("buffer"));
        }
        let out = Out::new(written_out, "written_out")?;
        let p = pack_args(b, texture, level, format)?;
        if capacity < p.bytes {
            return Err(fail(
                ndf_status::BufferTooSmall,
                format!(
                    "buffer of {capacity} bytes is too small: level {} of texture {} in {} \
                     needs {} (ndf_bake_packed_size)",
                    p.level, p.texture, p.format, p.bytes
                ),
            ));
        }
        // SAFETY: `buffer` is writable for `capacity` ≥ `p.bytes` bytes (the caller's
        // contract). Zeroing first makes every byte initialized before a `&mut [u8]` covers
        // them (the caller's memory may be uninitialized); u8 needs no alignment.
        let dst = unsafe {
            std::ptr::write_bytes(buffer.cast::<u8>(), 0, p.bytes);
            std::slice::from_raw_parts_mut(buffer.cast::<u8>(), p.bytes)
        };
        let written = crate::pack::pack_level(&b.bake, p.texture, p.level, p.format, dst)?;
        // SAFETY: writable, as this function requires.
        unsafe { out.write(written) };
        Ok(())
    })
}

/// Writes the bake to folder `directory` (created if missing) exactly as the command line's
/// `ndfmap bake` does: `manifest.json` and one file per texture per level, OpenEXR for the
/// float formats and PNG for the unorm ones, all-or-nothing.
/// - `format`: the texel format of the files (`NDF_FORMAT_*`).
/// - Fails with `NDF_STATUS_UNSUPPORTED_FORMAT` when a texture does not fit the format and
///   `NDF_STATUS_WRITE` when the folder or a file cannot be written.
///
/// # Safety
/// `bake` is NULL or a live bake; `directory` is NULL or a NUL-terminated string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_bake_write(
    bake: *const ndf_bake,
    directory: *const c_char,
    format: ndf_format,
) -> ndf_status {
    guard("ndf_bake_write", || {
        // SAFETY (both blocks): the pointers are NULL or valid, as this function requires.
        let b = unsafe { arg(bake, "bake") }?;
        let dir = path(unsafe { c_str(directory, "directory") }?, "directory")?;
        let format = choose("format", format, &FORMATS)?;
        let quantized;
        let to_write = if format == Format::F32 {
            &b.bake
        } else {
            quantized = crate::pack::quantize(&b.bake, format)
                .map_err(|e| fail(ndf_status::UnsupportedFormat, e.to_string()))?;
            &quantized
        };
        crate::output::write_bake(to_write, b.input.clone(), &dir)?;
        Ok(())
    })
}

/// Releases a bake. NULL is fine. Must not be called twice with the same bake (undefined
/// behaviour), nor while another call uses it; strings it handed out die with it.
///
/// # Safety
/// `bake` is NULL or a bake from this library not yet freed.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_bake_free(bake: *mut ndf_bake) {
    guard_value((), || {
        if !bake.is_null() {
            // SAFETY: a live bake was made by Box::into_raw in `run` and is freed once.
            drop(unsafe { Box::from_raw(bake) });
        }
    })
}
