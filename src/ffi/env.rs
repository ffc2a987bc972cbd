//! C API, environment lighting (issue 16): load an equirectangular environment (Radiance
//! `.hdr` or OpenEXR, from a file or from memory, or raw RGB floats), prepare it (per colour
//! channel: SH projection, prefiltered levels, `L′` table), and get what the environment-lit
//! shaders read, packed for upload ([`crate::envgpu`]), RGB interleaved: the SH coefficients,
//! the prefiltered atlas with its level table, the `L′` table, and the lobe-energy tables (one
//! channel: they do not depend on the radiance). The shader source itself comes from
//! `ndf_bake_shader_source` with `ndf_shader_options.light` = `NDF_LIGHT_ENV_PREFILTERED` or
//! `NDF_LIGHT_ENV_SH`. Wraps [`crate::environment`], [`crate::envlight`], [`crate::envgpu`].

use super::shader::{NDF_BRDF_BLINN_PHONG, NDF_BRDF_GGX, ndf_brdf};
use super::{
    Out, Outcome, bytes, c_str, choose, fail, guard, guard_value, ndf_status, null, read_options,
    text,
};
use crate::envgpu::{CHANNELS, ENERGY_SIZE, REFLECTED_COLUMNS, REFLECTED_ROWS, Upload};
use crate::environment::{BadTexels, EnvOptions, Environment};
use crate::envlight::EnvLight;
use std::ffi::{c_char, c_void};

/// What to do with NaN, infinite and negative texels: one of the `NDF_BAD_TEXELS_*` values.
pub type ndf_bad_texels = u32;
/// Set them to 0 and count them (`ndf_environment_info.repaired`). Default.
pub const NDF_BAD_TEXELS_REPAIR: ndf_bad_texels = 0;
/// Fail with `NDF_STATUS_DECODE`, naming the first bad texel.
pub const NDF_BAD_TEXELS_REJECT: ndf_bad_texels = 1;

/// How an environment is read. Initialize with `ndf_env_options_default()`.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct ndf_env_options {
    /// `sizeof(ndf_env_options)`, set by `ndf_env_options_default()`.
    pub struct_size: usize,
    /// Rotation about the zenith in degrees (the radiance at azimuth φ moves to φ + yaw).
    /// Default 0.
    pub yaw_deg: f64,
    /// Radiance multiplier, finite and ≥ 0. Default 1.
    pub intensity: f64,
    /// `NDF_BAD_TEXELS_*`. Default `NDF_BAD_TEXELS_REPAIR`.
    pub bad_texels: ndf_bad_texels,
    /// Extract up to this many compact bright sources as lights, and as many wide ones as
    /// diffuse-only lights (`LightOptions::up_to`; docs/environment.md "Bright sources as
    /// lights"): the tables then hold the residual, `ndf_environment_lights` hands the lights
    /// out and a shader with `ndf_shader_options.env_lights` (on by default) adds them. At
    /// most 8 lights in all (else `NDF_STATUS_INVALID_ARGUMENT`). Default 4 (a sun and lamps
    /// taken out: the better answer, docs/environment.md "Extracted lights by default"); 0: no
    /// extraction, the paper's pure routes (the tables hold the whole environment).
    pub max_lights: u32,
}

/// The default environment options: no rotation, intensity 1, bad texels repaired, up to 4
/// compact and 4 diffuse-only lights extracted.
#[unsafe(no_mangle)]
pub extern "C" fn ndf_env_options_default() -> ndf_env_options {
    let o = ndf_env_options {
        struct_size: size_of::<ndf_env_options>(),
        yaw_deg: 0.0,
        intensity: 1.0,
        bad_texels: NDF_BAD_TEXELS_REPAIR,
        max_lights: 4,
    };
    guard_value(o, || o)
}

/// An environment prepared for lighting (opaque): per colour channel its SH coefficients,
/// prefiltered levels and `L′` table. Released with `ndf_environment_free`.
pub struct ndf_environment {
    width: u32,
    height: u32,
    repaired: usize,
    light: EnvLight,
    upload: Upload,
}

/// Sizes of what an environment hands out, for allocating the buffers.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default)]
pub struct ndf_environment_info {
    /// Panorama width in texels (twice the height).
    pub width: u32,
    /// Panorama height in texels.
    pub height: u32,
    /// Texels repaired (NaN, infinite, negative set to 0).
    pub repaired: u64,
    /// Floats of `ndf_environment_sh`: 243 (81 coefficients, l ≤ 8, × `channels`).
    pub sh_count: u32,
    /// Atlas width of `ndf_environment_prefiltered` (level 0's width).
    pub atlas_width: u32,
    /// Atlas height (the shelves of levels stacked; under 4 × the panorama's height).
    pub atlas_height: u32,
    /// Prefiltered levels; the level table has 4 × this many `uint32_t` (width, height, first
    /// row, first column).
    pub level_count: u32,
    /// `κ_0 = W·H/π`, level 0's nominal concentration: a lobe at least this sharp reads level
    /// 0 alone (uniform `ndf_env_kappa0`; the level blend: docs/environment.md).
    pub kappa0: f64,
    /// `κ_1`, level 1's concentration; level k ≥ 1 has `κ_1 / 2^(k−1)` (uniform
    /// `ndf_env_kappa1`).
    pub kappa1: f64,
    /// Columns (81 texels of `channels` floats) and rows (256) of `ndf_environment_reflected`.
    pub reflected_columns: u32,
    /// Rows of `ndf_environment_reflected`.
    pub reflected_rows: u32,
    /// Columns (texels) of `ndf_environment_energy`: 9 shares of the NDF lobe in the widened
    /// lobe (GGX's lobe shape; Blinn-Phong's one share repeated) of 33 view cosines (297).
    pub energy_columns: u32,
    /// Rows (texels) of `ndf_environment_energy`: 3 groups of 49 lobe parameters, four blocks
    /// per texel (energy, blend, `log2 κ_c`, tail share `t` | `log2 κ_t`, core blend, energy
    /// and blend with the cosine at the half vector | `log2 κ` shift, 0, 0, 0; 147).
    pub energy_rows: u32,
    /// Floats per texel or coefficient of the radiance-dependent arrays (`ndf_environment_sh`,
    /// `_prefiltered`'s atlas, `_reflected`): 3, R, G, B interleaved (`RGB32F` textures,
    /// `uniform vec3 ndf_env_sh[81]`). The energy tables have four per texel (`RGBA32F`).
    pub channels: u32,
}

fn prepare(env: Environment, max_lights: u32) -> Outcome<ndf_environment> {
    let light = EnvLight::with_lights(
        &env,
        &crate::environment::lights::LightOptions::up_to(max_lights as usize),
    );
    let upload = crate::envgpu::pack(&light)?;
    Ok(ndf_environment {
        width: env.width(),
        height: env.height(),
        repaired: env.repaired(),
        light,
        upload,
    })
}

/// Reads the options argument.
///
/// # Safety
/// `p` is NULL or initialized by `ndf_env_options_default()`.
unsafe fn env_options(p: *const ndf_env_options) -> Outcome<(EnvOptions, u32)> {
    // SAFETY: forwarded from the entry point's contract.
    let o = unsafe { read_options(p, "options", "ndf_env_options_default") }?;
    let env = EnvOptions {
        yaw_deg: o.yaw_deg,
        intensity: o.intensity,
        bad_texels: choose(
            "bad_texels",
            o.bad_texels,
            &[BadTexels::Repair, BadTexels::Reject],
        )?,
    };
    Ok((env, o.max_lights))
}

/// Stores a new environment in `out`.
///
/// # Safety
/// `out` is valid for writes of a pointer.
unsafe fn hand_out(env: ndf_environment, out: Out<*mut ndf_environment>) -> Outcome {
    // SAFETY: forwarded from the caller; the Box is released by ndf_environment_free.
    unsafe { out.write(Box::into_raw(Box::new(env))) };
    Ok(())
}

/// Reads an equirectangular environment from a Radiance `.hdr` or OpenEXR file (linear, 2:1,
/// row 0 the zenith) and prepares it (about a second for 1024 × 512 on two cores).
/// - `path`: NUL-terminated file name; `options`: from `ndf_env_options_default()`.
/// - `env_out`: receives the environment, released with `ndf_environment_free`.
/// - Fails with `NDF_STATUS_READ`, `_DECODE` (undecodable, truncated, or bad texels with
///   `NDF_BAD_TEXELS_REJECT`), `_DIMENSIONS` (not 2:1, empty, wider than 16384) or
///   `_INVALID_ARGUMENT` (intensity or yaw not finite, intensity < 0).
///
/// # Safety
/// Pointers are NULL or valid as described; `env_out` is writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_environment_load_file(
    path: *const c_char,
    options: *const ndf_env_options,
    env_out: *mut *mut ndf_environment,
) -> ndf_status {
    guard("ndf_environment_load_file", || {
        // SAFETY (all blocks): the pointers are NULL or valid, as this function requires.
        let file = super::path(unsafe { c_str(path, "path") }?, "path")?;
        let (opts, max_lights) = unsafe { env_options(options) }?;
        let out = Out::new(env_out, "env_out")?;
        let env = crate::environment::load(&file, &opts)?;
        unsafe { hand_out(prepare(env, max_lights)?, out) }
    })
}

/// Reads an environment from the bytes of a `.hdr` or OpenEXR file held in memory.
/// - `data`, `length`: the file's bytes (`data` not NULL); `name`: NUL-terminated, named in
///   errors. Other arguments and failures as for `ndf_environment_load_file`.
///
/// # Safety
/// `data` is NULL or readable for `length` bytes; the other pointers as for
/// `ndf_environment_load_file`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_environment_load_memory(
    data: *const c_void,
    length: usize,
    name: *const c_char,
    options: *const ndf_env_options,
    env_out: *mut *mut ndf_environment,
) -> ndf_status {
    guard("ndf_environment_load_memory", || {
        // SAFETY (all blocks): the pointers are NULL or valid, as this function requires.
        let data = unsafe { bytes(data, length, "data") }?;
        let name = text(unsafe { c_str(name, "name") }?);
        let (opts, max_lights) = unsafe { env_options(options) }?;
        let out = Out::new(env_out, "env_out")?;
        let env = crate::environment::from_memory(&name, data, &opts)?;
        unsafe { hand_out(prepare(env, max_lights)?, out) }
    })
}

/// An environment from linear RGB floats, row-major from the zenith row, `width = 2·height`.
/// - `rgb`: `width × height × 3` floats (`NDF_STATUS_SHORT_PIXELS` is impossible to detect: the
///   caller guarantees the length). Other arguments and failures as for
///   `ndf_environment_load_file`.
///
/// # Safety
/// `rgb` is NULL or readable for `width × height × 3` floats; the other pointers as for
/// `ndf_environment_load_file`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_environment_from_rgb(
    width: u32,
    height: u32,
    rgb: *const f32,
    options: *const ndf_env_options,
    env_out: *mut *mut ndf_environment,
) -> ndf_status {
    guard("ndf_environment_from_rgb", || {
        if rgb.is_null() {
            return Err(null("rgb"));
        }
        let (opts, max_lights) = unsafe { env_options(options) }?;
        let out = Out::new(env_out, "env_out")?;
        // The size is checked (2:1, not empty, not too wide) before `rgb` is read: the
        // caller's buffer holds width × height × 3 floats only for the size it meant.
        crate::environment::check_size("rgb buffer", width, height)?;
        let n = (width as usize)
            .checked_mul(height as usize)
            .filter(|&n| width <= crate::environment::MAX_WIDTH && n <= usize::MAX / 12)
            .ok_or_else(|| {
                fail(
                    ndf_status::Dimensions,
                    format!("environment {width} x {height} is too large"),
                )
            })?;
        // SAFETY: non-NULL and readable for width × height × 3 floats (the caller's contract);
        // the product was checked not to overflow.
        let floats = unsafe { std::slice::from_raw_parts(rgb, n * 3) };
        let texels: Vec<[f32; 3]> = floats.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        let env = Environment::from_rgb("rgb buffer", width, height, texels, &opts)?;
        // SAFETY: `env_out` is writable (the caller's contract).
        unsafe { hand_out(prepare(env, max_lights)?, out) }
    })
}

/// Releases an environment (NULL is ignored).
///
/// # Safety
/// `env` is NULL or a live environment, not used afterwards.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_environment_free(env: *mut ndf_environment) {
    guard_value((), || {
        if !env.is_null() {
            // SAFETY: a live environment was made by Box::into_raw in hand_out, freed once.
            drop(unsafe { Box::from_raw(env) });
        }
    })
}

/// The environment argument.
///
/// # Safety
/// `p` is NULL or a live environment.
unsafe fn environment<'a>(p: *const ndf_environment) -> Outcome<&'a ndf_environment> {
    // SAFETY: forwarded.
    unsafe { super::arg(p, "env") }
}

/// Copies `src` to the caller's `dst` of `capacity` elements (`NDF_STATUS_BUFFER_TOO_SMALL`,
/// nothing written, when it is short).
///
/// # Safety
/// `dst` is NULL or writable for `capacity` elements.
unsafe fn copy_out<T: Copy>(src: &[T], dst: *mut T, capacity: usize, name: &str) -> Outcome {
    if dst.is_null() {
        return Err(null(name));
    }
    if capacity < src.len() {
        return Err(fail(
            ndf_status::BufferTooSmall,
            format!(
                "{name} holds {capacity} values, {} are needed (ndf_environment_info)",
                src.len()
            ),
        ));
    }
    // SAFETY: `dst` is writable for `capacity` ≥ `src.len()` elements and cannot overlap the
    // library's own `src`.
    unsafe { std::ptr::copy_nonoverlapping(src.as_ptr(), dst, src.len()) };
    Ok(())
}

/// The sizes of what `env` hands out.
///
/// # Safety
/// `env` is NULL or live; `info_out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_environment_info_get(
    env: *const ndf_environment,
    info_out: *mut ndf_environment_info,
) -> ndf_status {
    guard("ndf_environment_info_get", || {
        // SAFETY (both blocks): as this function requires.
        let e = unsafe { environment(env) }?;
        let out = Out::new(info_out, "info_out")?;
        let u = &e.upload;
        let info = ndf_environment_info {
            width: e.width,
            height: e.height,
            repaired: e.repaired as u64,
            sh_count: u.sh.len() as u32,
            atlas_width: u.atlas_width,
            atlas_height: u.atlas_height,
            level_count: u.levels.len() as u32,
            kappa0: u.kappa0,
            kappa1: u.kappa1,
            reflected_columns: REFLECTED_COLUMNS as u32,
            reflected_rows: REFLECTED_ROWS as u32,
            energy_columns: ENERGY_SIZE.0 as u32,
            energy_rows: ENERGY_SIZE.1 as u32,
            channels: CHANNELS as u32,
        };
        unsafe { out.write(info) };
        Ok(())
    })
}

/// The extracted lights (`ndf_env_options.max_lights`; none without): their count into
/// `count_out`, and 8 floats per light into `out` (`capacity` floats; NULL allowed when there
/// are none): direction x, y, z (environment frame, unit), RGB power, κ (0 encodes κ = ∞, a
/// point) and the diffuse-only flag (0 or 1) — the values of the uniforms `vec3
/// ndf_env_light_dir[8]`, `vec3 ndf_env_light_power[8]`, `float ndf_env_light_kappa[8]`,
/// `float ndf_env_light_diffuse_only[8]`, and `float ndf_env_light_count` = the count.
///
/// # Safety
/// `env` is NULL or live; `out` is NULL or writable for `capacity` floats; `count_out` is NULL
/// or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_environment_lights(
    env: *const ndf_environment,
    out: *mut f32,
    capacity: usize,
    count_out: *mut usize,
) -> ndf_status {
    guard("ndf_environment_lights", || {
        // SAFETY (all blocks): as this function requires.
        let e = unsafe { environment(env) }?;
        let count = Out::new(count_out, "count_out")?;
        let packed = crate::envgpu::lights_packed(&e.upload);
        if !packed.is_empty() {
            unsafe { copy_out(&packed, out, capacity, "out") }?;
        }
        unsafe { count.write(e.upload.lights.len()) };
        Ok(())
    })
}

/// The SH coefficients `L_lm`, l ≤ 8, (l, m) order, environment frame (+Z up, real
/// orthonormal basis without the Condon–Shortley phase), each as R, G, B: 243 floats into
/// `out` (`capacity` floats; uniform `vec3 ndf_env_sh[81]`, e.g. `glUniform3fv(loc, 81, out)`).
///
/// # Safety
/// `env` is NULL or live; `out` is NULL or writable for `capacity` floats.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_environment_sh(
    env: *const ndf_environment,
    out: *mut f32,
    capacity: usize,
) -> ndf_status {
    guard("ndf_environment_sh", || {
        // SAFETY (both blocks): as this function requires.
        let e = unsafe { environment(env) }?;
        unsafe { copy_out(&e.upload.sh, out, capacity, "out") }
    })
}

/// The prefiltered levels packed for upload as one `RGB32F` texture (`atlas_width ×
/// atlas_height × 3` floats, R, G, B per texel, row-major from the top; sampler
/// `ndf_env_atlas`, read with `texelFetch`) and the level table (`4 × level_count` values:
/// width, height, first row, first column of each level's rectangle in the atlas; uniform
/// `vec4 ndf_env_level[24]` as floats). Both buffers are required.
///
/// # Safety
/// `env` is NULL or live; `atlas` is NULL or writable for `atlas_capacity` floats, `levels` for
/// `levels_capacity` values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_environment_prefiltered(
    env: *const ndf_environment,
    atlas: *mut f32,
    atlas_capacity: usize,
    levels: *mut u32,
    levels_capacity: usize,
) -> ndf_status {
    guard("ndf_environment_prefiltered", || {
        // SAFETY (all blocks): as this function requires.
        let e = unsafe { environment(env) }?;
        let table: Vec<u32> = e.upload.levels.iter().flatten().copied().collect();
        if levels.is_null() {
            return Err(null("levels"));
        }
        if levels_capacity < table.len() {
            return Err(fail(
                ndf_status::BufferTooSmall,
                format!(
                    "levels holds {levels_capacity} values, {} are needed",
                    table.len()
                ),
            ));
        }
        unsafe { copy_out(&e.upload.atlas, atlas, atlas_capacity, "atlas") }?;
        unsafe { copy_out(&table, levels, levels_capacity, "levels") }
    })
}

/// The `L′_lm(ω_o)` table of eq 26 (the SH route): `reflected_rows` (256 views, row
/// `iθ·16 + iφ`) × `reflected_columns` (81) texels of R, G, B: 62208 floats, an `RGB32F`
/// texture (sampler `ndf_env_reflected`).
///
/// # Safety
/// `env` is NULL or live; `out` is NULL or writable for `capacity` floats.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_environment_reflected(
    env: *const ndf_environment,
    out: *mut f32,
    capacity: usize,
) -> ndf_status {
    guard("ndf_environment_reflected", || {
        // SAFETY (both blocks): as this function requires.
        let e = unsafe { environment(env) }?;
        unsafe { copy_out(&e.upload.reflected, out, capacity, "out") }
    })
}

/// The prefiltered route's lobe-energy table of a BRDF family (`NDF_BRDF_BLINN_PHONG` or
/// `NDF_BRDF_GGX`): `energy_rows` × `energy_columns` × 4 floats, an `RGBA32F` texture (sampler
/// `ndf_env_energy`; one table for all colour channels). Other BRDFs: `NDF_STATUS_INVALID_ARGUMENT`.
///
/// # Safety
/// `env` is NULL or live; `out` is NULL or writable for `capacity` floats.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_environment_energy(
    env: *const ndf_environment,
    brdf: ndf_brdf,
    out: *mut f32,
    capacity: usize,
) -> ndf_status {
    guard("ndf_environment_energy", || {
        // SAFETY (both blocks): as this function requires.
        let e = unsafe { environment(env) }?;
        let b = match brdf {
            NDF_BRDF_BLINN_PHONG => crate::brdf::Brdf::BlinnPhong { s: 1.0 },
            NDF_BRDF_GGX => crate::brdf::Brdf::ggx(0.5),
            other => {
                return Err(fail(
                    ndf_status::InvalidArgument,
                    format!(
                        "brdf {other}: energy tables exist for NDF_BRDF_BLINN_PHONG and NDF_BRDF_GGX"
                    ),
                ));
            }
        };
        let table = crate::envgpu::energy(&e.light, &b).unwrap_or_default();
        unsafe { copy_out(&table, out, capacity, "out") }
    })
}
