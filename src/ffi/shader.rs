//! C API, shaders: the GLSL 3.30 source that reads a bake — the files of `glsl/`, specialized
//! with `#define`s for the method, lobe count, upload format and options. Wraps [`crate::glsl`].

use super::bake::{FORMATS, ndf_bake, ndf_format};
use super::{Out, Outcome, arg, choose, fail, guard, guard_value, ndf_status, read_options};
use crate::glsl::{Sampling, ShaderBrdf, ShaderLight, ShaderOptions, ShaderSpec, Stage};
use crate::sh::ShDiffuse;
use crate::shade::{VmfCosine, VmfDiffuse, VmfSpecular};
use std::ffi::c_char;

/// A shader stage: one of the `NDF_SHADER_STAGE_*` values.
pub type ndf_shader_stage = u32;
/// The vertex shader (mesh or, with `probe`, full-screen triangle).
pub const NDF_SHADER_STAGE_VERTEX: ndf_shader_stage = 0;
/// The fragment shader: samples the bake's textures and shades.
pub const NDF_SHADER_STAGE_FRAGMENT: ndf_shader_stage = 1;

/// How the fragment shader filters between texels: one of the `NDF_SAMPLING_*` values.
pub type ndf_sampling = u32;
/// The bake's natural mode: manual for unaligned mixtures, hardware otherwise. Default.
pub const NDF_SAMPLING_AUTO: ndf_sampling = 0;
/// One hardware trilinear fetch per texture, then shading (aligned lobes, baselines).
pub const NDF_SAMPLING_HARDWARE: ndf_sampling = 1;
/// Shade the 8 texels of the two nearest levels and blend (unaligned lobes, Sec 7.3).
pub const NDF_SAMPLING_MANUAL: ndf_sampling = 2;
/// The anisotropic footprint (`GL_EXT_texture_filter_anisotropic`'s reference rule, done in
/// the shader): up to `max_anisotropy` trilinear probes along the pixel's major axis,
/// averaged, then shading. For bakes whose parameters filter linearly (SH, aligned lobes, the
/// baselines).
pub const NDF_SAMPLING_ANISOTROPIC: ndf_sampling = 3;

/// The vMF lobes' diffuse term: one of the `NDF_VMF_DIFFUSE_*` values.
pub type ndf_vmf_diffuse = u32;
/// `max(ω_i·αr, 0)` per lobe (the mean normal of the lobe; lower Lambert error). Default.
pub const NDF_VMF_DIFFUSE_MEAN_VECTOR: ndf_vmf_diffuse = 0;
/// Algorithm 2 line 14 as written: `α max(ω_i·μ, 0)`.
pub const NDF_VMF_DIFFUSE_ALGORITHM2: ndf_vmf_diffuse = 1;

/// The vMF lobes' specular rule under Blinn-Phong and GGX: one of the `NDF_VMF_SPECULAR_*`
/// values.
pub type ndf_vmf_specular = u32;
/// The paper's eq 20: `s' = κs/(κ+s)`, `B = (s'+1)/(2π)(ω_h·μ)^{s'}`; under GGX the single
/// widened lobe `α'² = α² + c/κ` (the GGX rule before `NDF_VMF_SPECULAR_AUTO`). 0: a
/// zero-initialised struct gets it; `ndf_shader_options_default()` gives `NDF_VMF_SPECULAR_AUTO`.
pub const NDF_VMF_SPECULAR_EQ20: ndf_vmf_specular = 0;
/// The closed-form vMF ⊛ Blinn-Phong lobe (within 0.5 % of the exact convolution, eq 14, up to
/// one lobe width; costlier in the shader); under GGX the peak-matched widening
/// `α'² = α² + c·m(κα²/2)/κ` (the exact convolution's peak at c = 2) instead of `α² + c/κ`.
pub const NDF_VMF_SPECULAR_CONVOLVED: ndf_vmf_specular = 1;
/// The recommended rule per BRDF, the default of `ndf_shader_options_default()`: eq 20 under
/// Blinn-Phong (the same shader as `NDF_VMF_SPECULAR_EQ20`), under GGX the exact convolution of
/// GGX's D as a fitted mixture of vMF lobes (uniform arrays `ndf_ggx_w`, `ndf_ggx_eta` from
/// `ndf_material_ggx_mixture`). A host that leaves those arrays unset (all weights 0) gets
/// `NDF_VMF_SPECULAR_EQ20`'s widened lobe instead, not a broken one.
pub const NDF_VMF_SPECULAR_AUTO: ndf_vmf_specular = 2;

/// Where the vMF lobes' specular term takes its cosine of incidence under Blinn-Phong and GGX:
/// one of the `NDF_VMF_COSINE_*` values.
pub type ndf_vmf_cosine = u32;
/// At the centre of the NDF lobe's and the BRDF lobe's product, `normalize(μ + (η/κ)ω_h)`
/// (lower specular error; `docs/baker.md`, "The specular cosine"). Default.
pub const NDF_VMF_COSINE_PRODUCT: ndf_vmf_cosine = 0;
/// Algorithm 2 line 14 as written: `max(ω_i·μ, 0)`.
pub const NDF_VMF_COSINE_ALGORITHM2: ndf_vmf_cosine = 1;

/// The SH texels' diffuse term: one of the `NDF_SH_DIFFUSE_*` values.
pub type ndf_sh_diffuse = u32;
/// `E[max(ω_i·n, 0)]` for a Gaussian cosine with the moments bands 0–2 give (l* ≥ 2; lower
/// Lambert error). Default.
pub const NDF_SH_DIFFUSE_MOMENTS: ndf_sh_diffuse = 0;
/// eq 12 with Lambert's truncated clamped cosine.
pub const NDF_SH_DIFFUSE_SERIES: ndf_sh_diffuse = 1;

/// The specular BRDF a shader evaluates: one of the `NDF_BRDF_*` values.
pub type ndf_brdf = u32;
/// Normalized Blinn-Phong, exponent in uniform `ndf_s` (eq 20). Default.
pub const NDF_BRDF_BLINN_PHONG: ndf_brdf = 0;
/// The Torrance–Sparrow-like Gaussian of eq 18, roughness in uniform `ndf_sigma` (eq 21).
pub const NDF_BRDF_TORRANCE_SPARROW: ndf_brdf = 1;
/// No specular lobe: the Lambert term alone (the specular output is 0).
pub const NDF_BRDF_LAMBERT: ndf_brdf = 2;
/// GGX / Trowbridge–Reitz, uniforms `ndf_alpha`, `ndf_ggx_c`, the arrays `ndf_ggx_w` and
/// `ndf_ggx_eta` (`ndf_material_ggx_mixture`; vMF shaders) (and `ndf_f0` with the g
/// factor: Smith's masking and Schlick's Fresnel).
pub const NDF_BRDF_GGX: ndf_brdf = 3;
/// A tabulated `f(θ_h)·g(θ_d)`: sampler `ndf_brdf_table`, an R32F texture of
/// `ndf_material_table()`.
pub const NDF_BRDF_TABULATED: ndf_brdf = 4;

/// What lights the surface in a shader: one of the `NDF_LIGHT_*` values.
pub type ndf_light = u32;
/// One point or directional light (uniforms `ndf_light`, `ndf_light_color`). Default.
pub const NDF_LIGHT_POINT: ndf_light = 0;
/// An environment, the specular term by one prefiltered lookup per lobe (`NDF_LIGHT_ENV_PREFILTERED`;
/// data from `ndf_env_prefiltered` and `ndf_env_energy`, uniforms from `ndf_env_uniforms`).
pub const NDF_LIGHT_ENV_PREFILTERED: ndf_light = 1;
/// An environment, the specular term by eq 26 with the `L′` table (`NDF_LIGHT_ENV_SH`; data
/// from `ndf_env_reflected`, uniforms from `ndf_env_uniforms`). The only environment lighting
/// of SH bakes (`NDF_METHOD_SH`): the environment's `L_lm` and `L′_lm` are rotated per fragment
/// into the tangent frame; they also read the BRDF's `ndf_sh_rho` as under a point light.
pub const NDF_LIGHT_ENV_SH: ndf_light = 2;
/// The point (or directional) light *and* an environment by the prefiltered route, summed in
/// one shader from the same filtered texels (`NDF_LIGHT_BOTH` + `NDF_LIGHT_ENV_PREFILTERED`):
/// the point light's uniforms, `ndf_env_color` (the environment's radiance scale) and the
/// environment's data as for `NDF_LIGHT_ENV_PREFILTERED`. Plain, Toksvig, LEAN and vMF bakes;
/// Lambert, Blinn-Phong or GGX; no colour. What `ndf_plan_text` returns for a scene with both
/// kinds of light.
pub const NDF_LIGHT_POINT_AND_ENV_PREFILTERED: ndf_light = 3;

/// Options of a specialized shader. Initialize with `ndf_shader_options_default()`.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct ndf_shader_options {
    /// `sizeof(ndf_shader_options)`, set by `ndf_shader_options_default()`.
    pub struct_size: usize,
    /// The specular BRDF, `NDF_BRDF_*`. Default `NDF_BRDF_BLINN_PHONG`.
    pub brdf: ndf_brdf,
    /// `NDF_BRDF_GGX` only: nonzero multiplies by the g factor (Smith, Schlick). Default 0.
    pub ggx_g: u32,
    /// Hardware, manual or anisotropic filtering, `NDF_SAMPLING_*`. Default
    /// `NDF_SAMPLING_AUTO`.
    pub sampling: ndf_sampling,
    /// `NDF_SAMPLING_ANISOTROPIC` only: the most probes, 2 to 16. Default 16.
    pub max_anisotropy: u32,
    /// vMF bakes: the lobes' diffuse term, `NDF_VMF_DIFFUSE_*`. Default
    /// `NDF_VMF_DIFFUSE_MEAN_VECTOR`.
    pub vmf_diffuse: ndf_vmf_diffuse,
    /// The format the textures are uploaded in (`NDF_FORMAT_*`, as given to `ndf_bake_pack`):
    /// decides the unorm decoding and the vMF |r| clamp. Default `NDF_FORMAT_RGBA_F32`.
    pub format: ndf_format,
    /// Nonzero: multiply each lobe by its colour texture (eq 22); the bake needs colour
    /// textures (a vMF or Tan 2005 bake of a map with a feature image). Default 0.
    pub color: u32,
    /// Nonzero: the probe variant (full-screen triangle, uniforms for uv, LOD, light and half
    /// vector) that ndfmap's tests render. Default 0: the mesh variant.
    pub probe: u32,
    /// SH bakes: the diffuse term, `NDF_SH_DIFFUSE_*`. Default `NDF_SH_DIFFUSE_MOMENTS`.
    pub sh_diffuse: ndf_sh_diffuse,
    /// The lighting, `NDF_LIGHT_*`: a point light or an environment by one of its routes
    /// (every bake but PBR, SH by `NDF_LIGHT_ENV_SH` only; Lambert, Blinn-Phong or GGX).
    /// Default `NDF_LIGHT_POINT`.
    pub light: ndf_light,
    /// vMF bakes under Blinn-Phong or GGX (point lights): the lobes' specular rule,
    /// `NDF_VMF_SPECULAR_*`. Default `NDF_VMF_SPECULAR_AUTO`.
    pub vmf_specular: ndf_vmf_specular,
    /// Nonzero: an environment-lit shader (`NDF_LIGHT_ENV_*`, `NDF_LIGHT_POINT_AND_ENV_*`)
    /// adds the environment's extracted lights (`#define NDF_ENV_LIGHTS 8`, uniforms
    /// `ndf_env_light_*` from `ndf_environment_lights`; `ndf_env_light_count` 0 for an
    /// environment read with `ndf_env_options.max_lights` = 0 adds nothing). Ignored by the
    /// point light's shader (it has no environment). Default 1, matching
    /// `ndf_env_options.max_lights`' default 4: a shader without the lights drawing an
    /// environment with them would shade its residual alone (the sun missing).
    pub env_lights: u32,
    /// vMF bakes under Blinn-Phong or GGX: where the specular term takes its cosine of
    /// incidence, `NDF_VMF_COSINE_*`. Default `NDF_VMF_COSINE_PRODUCT`.
    pub vmf_cosine: ndf_vmf_cosine,
}

/// The default shader options: Blinn-Phong, automatic sampling (16 probes if anisotropic), f32
/// textures, no colour, the mean-vector vMF diffuse term, eq 20 as the vMF specular rule (its
/// cosine at the product lobe's centre), the
/// moments SH diffuse term, the mesh variant, the point light (environment-lit shaders add the
/// extracted lights).
#[unsafe(no_mangle)]
pub extern "C" fn ndf_shader_options_default() -> ndf_shader_options {
    let o = ndf_shader_options {
        struct_size: size_of::<ndf_shader_options>(),
        brdf: NDF_BRDF_BLINN_PHONG,
        ggx_g: 0,
        sampling: NDF_SAMPLING_AUTO,
        max_anisotropy: 16,
        vmf_diffuse: NDF_VMF_DIFFUSE_MEAN_VECTOR,
        format: super::bake::NDF_FORMAT_RGBA_F32,
        color: 0,
        probe: 0,
        sh_diffuse: NDF_SH_DIFFUSE_MOMENTS,
        light: NDF_LIGHT_POINT,
        vmf_specular: NDF_VMF_SPECULAR_AUTO,
        env_lights: 1,
        vmf_cosine: NDF_VMF_COSINE_PRODUCT,
    };
    guard_value(o, || o)
}

/// The NUL-terminated source of `bake`'s shader for `stage` with `options`.
///
/// # Safety
/// `bake` is NULL or a live bake; `options` is NULL or initialized by
/// `ndf_shader_options_default()`.
unsafe fn shader(
    bake: *const ndf_bake,
    stage: ndf_shader_stage,
    options: *const ndf_shader_options,
) -> Outcome<Vec<u8>> {
    // SAFETY (both blocks): forwarded from the caller's contract.
    let b = unsafe { arg(bake, "bake") }?;
    let o = unsafe { read_options(options, "options", "ndf_shader_options_default") }?;
    let stage = choose("stage", stage, &[Stage::Vertex, Stage::Fragment])?;
    let sampling = [
        Sampling::Auto,
        Sampling::Hardware,
        Sampling::Manual,
        Sampling::Anisotropic(o.max_anisotropy),
    ];
    let brdf = [
        ShaderBrdf::BlinnPhong,
        ShaderBrdf::TorranceSparrow,
        ShaderBrdf::Lambert,
        ShaderBrdf::Ggx { g: o.ggx_g != 0 },
        ShaderBrdf::Tabulated,
    ];
    let diffuse = [VmfDiffuse::MeanVector, VmfDiffuse::Algorithm2];
    let light = choose(
        "light",
        o.light,
        &[
            ShaderLight::Point,
            ShaderLight::EnvPrefiltered,
            ShaderLight::EnvSh,
            ShaderLight::PointAndEnvPrefiltered,
        ],
    )?;
    let shader_options = ShaderOptions {
        brdf: choose("brdf", o.brdf, &brdf)?,
        sampling: choose("sampling", o.sampling, &sampling)?,
        color: o.color != 0,
        probe: o.probe != 0,
        vmf_diffuse: choose("vmf_diffuse", o.vmf_diffuse, &diffuse)?,
        vmf_cosine: choose(
            "vmf_cosine",
            o.vmf_cosine,
            &[VmfCosine::Product, VmfCosine::Algorithm2],
        )?,
        vmf_specular: choose(
            "vmf_specular",
            o.vmf_specular,
            &[VmfSpecular::Eq20, VmfSpecular::Convolved, VmfSpecular::Auto],
        )?,
        sh_diffuse: choose(
            "sh_diffuse",
            o.sh_diffuse,
            &[ShDiffuse::Moments, ShDiffuse::Series],
        )?,
        light,
        // The point light's shader has no environment: the (default-on) flag is ignored.
        env_lights: o.env_lights != 0 && light.is_env(),
        ..Default::default()
    };
    let format = choose("format", o.format, &FORMATS)?;
    for t in 0..b.bake.textures.len() {
        crate::pack::check(&b.bake, t, format)
            .map_err(|e| fail(ndf_status::UnsupportedFormat, e.to_string()))?;
    }
    let spec = ShaderSpec {
        format,
        ..ShaderSpec::of(&b.bake)
    };
    let mut source = crate::glsl::source_for(&spec, stage, &shader_options)?.into_bytes();
    if source.contains(&0) {
        return Err(fail(
            ndf_status::Panic,
            "the shader source contains a NUL byte",
        ));
    }
    source.push(0);
    Ok(source)
}

/// Bytes `ndf_bake_shader_source` writes for the same arguments: the source's length plus its
/// NUL terminator.
/// - `stage`: `NDF_SHADER_STAGE_*`; `options`: from `ndf_shader_options_default()`.
/// - `NDF_STATUS_INVALID_ARGUMENT` for unknown values or colour asked of a bake without colour
///   textures; `NDF_STATUS_UNSUPPORTED_FORMAT` when `options->format` cannot hold the bake.
///
/// # Safety
/// `bake` is NULL or a live bake; `options` is NULL or initialized by
/// `ndf_shader_options_default()`; `size_out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_bake_shader_source_size(
    bake: *const ndf_bake,
    stage: ndf_shader_stage,
    options: *const ndf_shader_options,
    size_out: *mut usize,
) -> ndf_status {
    guard("ndf_bake_shader_source_size", || {
        let out = Out::new(size_out, "size_out")?;
        // SAFETY (both blocks): the pointers are NULL or valid, as this function requires.
        let source = unsafe { shader(bake, stage, options) }?;
        unsafe { out.write(source.len()) };
        Ok(())
    })
}

/// Writes the GLSL 3.30 source of `bake`'s shader for `stage` into `buffer`, NUL-terminated:
/// `#version 330 core`, the `#define`s of the bake (method, lobe count, textures, format clamp,
/// addressing) and of `options`, then the shader files of `glsl/`. Samplers are
/// `ndf_tex0` ... (texture `i` of the bake); `glsl/README.md` lists the uniforms.
/// - `buffer`, `capacity`: the destination and its size in bytes; it must hold
///   `ndf_bake_shader_source_size()` bytes (`NDF_STATUS_BUFFER_TOO_SMALL` otherwise, and
///   nothing is written).
/// - `length_out`: receives the bytes written, the NUL terminator included.
/// - Other failures as for `ndf_bake_shader_source_size`.
///
/// # Safety
/// As for `ndf_bake_shader_source_size`, and `buffer` is NULL or writable for `capacity` bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_bake_shader_source(
    bake: *const ndf_bake,
    stage: ndf_shader_stage,
    options: *const ndf_shader_options,
    buffer: *mut c_char,
    capacity: usize,
    length_out: *mut usize,
) -> ndf_status {
    guard("ndf_bake_shader_source", || {
        if buffer.is_null() {
            return Err(super::null("buffer"));
        }
        let out = Out::new(length_out, "length_out")?;
        // SAFETY: the pointers are NULL or valid, as this function requires.
        let source = unsafe { shader(bake, stage, options) }?;
        if capacity < source.len() {
            return Err(fail(
                ndf_status::BufferTooSmall,
                format!(
                    "buffer of {capacity} bytes is too small: the source needs {} with its NUL \
                     (ndf_bake_shader_source_size)",
                    source.len()
                ),
            ));
        }
        // SAFETY: `buffer` is writable for `capacity` ≥ `source.len()` bytes (the caller's
        // contract) and cannot overlap the freshly allocated `source`.
        unsafe {
            std::ptr::copy_nonoverlapping(source.as_ptr(), buffer.cast::<u8>(), source.len());
            out.write(source.len());
        }
        Ok(())
    })
}
