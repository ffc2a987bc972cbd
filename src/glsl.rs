//! The GLSL 3.30 shaders of `glsl/`, embedded and specialized for a bake.
//!
//! The shader files are the product (engines compile them); this module only glues them:
//! `#version 330 core`, the `#define`s of a [`ShaderSpec`] (method, lobe count, BRDF, colour,
//! sampling, addressing, the format's |r| clamp), then `ndf_common.glsl` (lobe math), a
//! generated block declaring exactly the samplers the method reads (no dead samplers) with their
//! fetch functions (which undo the bias of unsigned-normalized storage, DESIGN.md "Texture
//! layouts"), the method's file (`ndf_vmf.glsl` = Algorithm 2, `ndf_tan2005.glsl`,
//! `ndf_sh.glsl` = eq 12, `ndf_baselines.glsl`), and the fragment stage ([`FRAGMENT`]: the
//! pieces `ndf_fragment.glsl`, `ndf_fragment_level.glsl`, `ndf_fragment_both.glsl`,
//! `ndf_fragment_filter.glsl`, `ndf_fragment_main.glsl`, concatenated). The vertex stage is
//! `ndf_vertex.glsl`.
//!
//! The CPU twin of every fragment shader is [`crate::shade`] (one texel) and
//! [`crate::sample`] (sampling at uv and LOD); the GL tests in `samples/gl` compare them.
//!
//! Interface (both stages): samplers `ndf_tex0 … ndf_tex{N−1}` are texture `i` of the bake
//! (lobes first, then colours); the BRDF's uniforms ([`uniforms`]): `ndf_s` (Blinn-Phong),
//! `ndf_sigma` (Torrance–Sparrow), `ndf_alpha`, `ndf_ggx_c` and with the g factor `ndf_f0`
//! (GGX), sampler `ndf_brdf_table` (tabulated: an R32F texture of
//! [`crate::brdf::Tabulated::table`]), and for SH `ndf_sh_rho[l* + 1]` (the BRDF's `ρ̂_l`) and
//! `ndf_sh_peak` (its lobe's peak);
//! mesh mode: attributes 0–3 (position, normal, tangent, uv), uniforms `ndf_model`,
//! `ndf_view_proj`, `ndf_camera_pos`, `ndf_light`, `ndf_light_color`, `ndf_kd`, `ndf_ks`;
//! probe mode ([`ShaderOptions::probe`]): `ndf_probe_size`, `ndf_probe_lod` (or, anisotropic,
//! `ndf_probe_dx`, `ndf_probe_dy`), `ndf_probe_l`, `ndf_probe_h`, `ndf_probe_channel`. Output:
//! `layout(location = 0) out vec4 ndf_out`.

use crate::bake::{Bake, Method};
use crate::brdf::Brdf;
use crate::error::{Error, Result};
use crate::format::{Format, ValueRange};
use crate::ingest::Addressing;
use std::fmt::Write;

/// `glsl/ndf_common.glsl`: shared lobe math.
pub const COMMON: &str = include_str!("../glsl/ndf_common.glsl");
/// `glsl/ndf_vmf.glsl`: the vMF lobes of Algorithm 2.
pub const VMF: &str = include_str!("../glsl/ndf_vmf.glsl");
/// `glsl/ndf_tan2005.glsl`: Tan et al. 2005's planar Gaussians.
pub const TAN2005: &str = include_str!("../glsl/ndf_tan2005.glsl");
/// `glsl/ndf_sh_basis.glsl`: the real SH basis by recurrence, a template instantiated by
/// [`sh_basis`] before `ndf_sh.glsl` (`ndf_sh_eval`, l ≤ l*) and `ndf_env.glsl`
/// (`ndf_env_basis`, l ≤ 8).
pub const SH_BASIS: &str = include_str!("../glsl/ndf_sh_basis.glsl");
/// `glsl/ndf_sh.glsl`: the spherical-harmonic NDF, eq 12.
pub const SH: &str = include_str!("../glsl/ndf_sh.glsl");
/// `glsl/ndf_baselines.glsl`: plain, Toksvig, LEAN and Olano–North.
pub const BASELINES: &str = include_str!("../glsl/ndf_baselines.glsl");
/// `glsl/ndf_env.glsl`: environment lighting, the SH and prefiltered routes (issue 16).
pub const ENV: &str = include_str!("../glsl/ndf_env.glsl");
/// `glsl/ndf_fragment.glsl`: the fragment stage's header comment and output declaration, the
/// first of the five pieces of the fragment stage ([`FRAGMENT`]).
pub const FRAGMENT_HEAD: &str = include_str!("../glsl/ndf_fragment.glsl");
/// `glsl/ndf_fragment_level.glsl`: `ndf_max_level`, the largest MIP level of `ndf_tex0`.
pub const FRAGMENT_LEVEL: &str = include_str!("../glsl/ndf_fragment_level.glsl");
/// `glsl/ndf_fragment_both.glsl`: the `NDF_LIGHT_BOTH` globals the entry point sets (the view,
/// the point light's and the environment's scales); one copy shared by every part of a LOD
/// switch.
pub const FRAGMENT_BOTH: &str = include_str!("../glsl/ndf_fragment_both.glsl");
/// `glsl/ndf_fragment_filter.glsl`: the shading of one texel (`ndf_texel`) and the filtering
/// (hardware, manual, anisotropic: `ndf_shade`, `ndf_shade_footprint`); renamed per part in a
/// LOD switch.
pub const FRAGMENT_FILTER: &str = include_str!("../glsl/ndf_fragment_filter.glsl");
/// `glsl/ndf_fragment_main.glsl`: the entry points (the probe's and the mesh's `main`).
pub const FRAGMENT_MAIN: &str = include_str!("../glsl/ndf_fragment_main.glsl");
/// The fragment stage: sampling and the fragment entry point, the five pieces concatenated
/// (head, level, both-lights globals, filtering, entry points). [`lod_switch_source`] uses the
/// pieces apart: the head and the globals once, the level and filtering pieces per part, the
/// entry points after the switch.
pub const FRAGMENT: &str = concat!(
    include_str!("../glsl/ndf_fragment.glsl"),
    include_str!("../glsl/ndf_fragment_level.glsl"),
    include_str!("../glsl/ndf_fragment_both.glsl"),
    include_str!("../glsl/ndf_fragment_filter.glsl"),
    include_str!("../glsl/ndf_fragment_main.glsl"),
);
/// `glsl/ndf_vertex.glsl`: the vertex entry point.
pub const VERTEX: &str = include_str!("../glsl/ndf_vertex.glsl");

/// A shader stage.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// The vertex shader.
    Vertex,
    /// The fragment shader.
    Fragment,
}

/// How the fragment shader filters between texels (Sec 7.3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Sampling {
    /// The bake's natural mode: manual for unaligned mixtures, hardware otherwise.
    #[default]
    Auto,
    /// One hardware trilinear fetch per texture, then shading (aligned lobes, baselines, SH).
    Hardware,
    /// Shade the 8 texels of the two nearest levels, blend with trilinear weights (unaligned).
    Manual,
    /// The anisotropic footprint with at most this many trilinear probes (2 to 16), averaged,
    /// then shading ([`crate::sample::aniso_probes`]; for parameters that filter linearly: SH,
    /// aligned lobes, the baselines).
    Anisotropic(u32),
}

/// The BRDF the shader evaluates (its parameters are uniforms, [`uniforms`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum ShaderBrdf {
    /// Normalized Blinn-Phong, uniform `ndf_s` (eq 20).
    #[default]
    BlinnPhong,
    /// The Torrance–Sparrow-like Gaussian of eq 18, uniform `ndf_sigma` (eq 21).
    TorranceSparrow,
    /// No specular lobe (the specular output is 0).
    Lambert,
    /// GGX, uniforms `ndf_alpha`, `ndf_ggx_c`; with `g` also `ndf_f0` (Smith and Schlick).
    Ggx {
        /// The g factor is on.
        g: bool,
    },
    /// A tabulated BRDF, sampler `ndf_brdf_table`.
    Tabulated,
}

impl ShaderBrdf {
    /// The specialization a [`Brdf`] needs.
    pub fn of(brdf: &Brdf) -> ShaderBrdf {
        match brdf {
            Brdf::Lambert => ShaderBrdf::Lambert,
            Brdf::BlinnPhong { .. } => ShaderBrdf::BlinnPhong,
            Brdf::TorranceSparrow { .. } => ShaderBrdf::TorranceSparrow,
            Brdf::Ggx(g) => ShaderBrdf::Ggx { g: g.g },
            Brdf::Tabulated(_) => ShaderBrdf::Tabulated,
        }
    }
}

/// What lights the surface: the point (or directional) light of the mesh and probe entry
/// points, or an environment by one of [`crate::envlight::Route`]'s routes (`glsl/ndf_env.glsl`,
/// its data and uniforms packed by module `envgpu`; CPU twin [`crate::envlight::shade`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum ShaderLight {
    /// One light: uniforms `ndf_light`, `ndf_light_color` (probe: `ndf_probe_l`, `ndf_probe_h`).
    #[default]
    Point,
    /// An environment, specular by one prefiltered lookup per lobe (`NDF_LIGHT_ENV_PREFILTERED`).
    EnvPrefiltered,
    /// An environment, specular by eq 26 with the `L′` table (`NDF_LIGHT_ENV_SH`).
    EnvSh,
    /// The point (or directional) light *and* an environment by the prefiltered route, summed
    /// in one shader from the same filtered texels (`NDF_LIGHT_BOTH` +
    /// `NDF_LIGHT_ENV_PREFILTERED`): the point light's uniforms and `ndf_env_color` (the
    /// environment's radiance scale) on meshes; `ndf_probe_l`, `ndf_probe_h` and
    /// `ndf_probe_v` in the probe, which writes the unscaled sum. CPU twin: the point-light
    /// shading (g applied per texel) plus [`crate::envlight::shade`].
    PointAndEnvPrefiltered,
}

impl ShaderLight {
    /// The environment lighting of `route`.
    pub fn env(route: crate::envlight::Route) -> ShaderLight {
        match route {
            crate::envlight::Route::Prefiltered => ShaderLight::EnvPrefiltered,
            crate::envlight::Route::Sh => ShaderLight::EnvSh,
        }
    }

    /// Whether an environment lights the surface (alone or with the point light).
    pub fn is_env(self) -> bool {
        self != ShaderLight::Point
    }

    /// Whether the point (or directional) light lights the surface (alone or with an
    /// environment).
    pub fn has_point(self) -> bool {
        matches!(
            self,
            ShaderLight::Point | ShaderLight::PointAndEnvPrefiltered
        )
    }
}

/// Options of a specialized shader.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ShaderOptions {
    /// The lighting (`NDF_LIGHT_ENV_*`; default: the point light).
    pub light: ShaderLight,
    /// The specular BRDF.
    pub brdf: ShaderBrdf,
    /// Hardware, manual or anisotropic filtering.
    pub sampling: Sampling,
    /// Multiply each lobe by its colour texture `α·y` (eq 22; mixtures baked with colour).
    pub color: bool,
    /// The probe variant used by tests: full-screen, uniforms for uv/LOD/light/half vector.
    pub probe: bool,
    /// The vMF lobes' diffuse term (`NDF_VMF_DIFFUSE_ALG2` for Algorithm 2 as written).
    pub vmf_diffuse: crate::shade::VmfDiffuse,
    /// Where the vMF lobes' specular term takes its cosine of incidence under Blinn-Phong and
    /// GGX (default: the product lobe's centre; `NDF_VMF_COSINE_ALG2` for Algorithm 2's `ω_i·μ`).
    pub vmf_cosine: crate::shade::VmfCosine,
    /// The vMF lobes' specular rule under Blinn-Phong and GGX (the default is the paper's eq 20,
    /// GGX's `α'² = α² + c/κ`; `NDF_VMF_SPECULAR_CONVOLVED` for the closed-form convolution,
    /// GGX's peak-matched widening `Ggx::widened_vmf`). `VmfSpecular::Exact` has no shader and
    /// is refused.
    pub vmf_specular: crate::shade::VmfSpecular,
    /// The SH texels' diffuse term (`NDF_SH_DIFFUSE_SERIES` for eq 12's series).
    pub sh_diffuse: crate::sh::ShDiffuse,
    /// No diffuse term (a scene with K_d = 0; `NDF_NO_DIFFUSE`): the shader declares no
    /// `ndf_kd`, writes `K_s·specular` only and its texel shading returns a zero diffuse term,
    /// so the method's Lambert code is dead and compiled out. The probe writes diffuse 0.
    /// Refused with the Lambert BRDF (nothing would be shaded).
    pub no_diffuse: bool,
    /// Add the environment's extracted lights (`NDF_ENV_LIGHTS` = [`MAX_ENV_LIGHTS`]: the
    /// uniforms `ndf_env_light_*` of module `envgpu`'s `uniforms` and the loop
    /// `ndf_env_lights` of `glsl/ndf_env.glsl`; CPU twin `envlight::add_lights`), for a light
    /// prepared by [`crate::envlight::EnvLight::with_lights`]. Environment lighting only
    /// (refused with the point light; the LOD-switching shader adds them per part when every
    /// part has it); default off, so no other shader declares the loop (the CLI, the C API,
    /// the viewer and the planner turn it on for environments with extracted lights).
    pub env_lights: bool,
}

/// The most extracted environment lights a shader with [`ShaderOptions::env_lights`] adds (the
/// size of its `ndf_env_light_*` arrays; `envgpu::pack` refuses more): the default extraction's
/// 4 compact and 4 diffuse-only lights.
pub const MAX_ENV_LIGHTS: usize = 8;

/// The most textures one shader samples (a sampler each): what llvmpipe and the desktop GPUs
/// offer (`GL_MAX_TEXTURE_IMAGE_UNITS` = 32; GL 3.3 guarantees 16). SH with l* ≤ 10 fits.
pub const MAX_SAMPLERS: usize = 32;

/// The uniforms of `brdf` a shader specialized for it reads, with their values (f32; arrays
/// as several values): `ndf_s`, `ndf_sigma`, `ndf_alpha` + `ndf_ggx_c` + the vMF-mixture fit of
/// GGX's D, `ndf_ggx_w` and `ndf_ggx_eta` ([`crate::brdf::ggx_mixture::GgxMixture::of`]; read by
/// the vMF shader's default GGX rule) (+ `ndf_f0` with the g factor), and for an SH shader of band limit `sh_lmax` also `ndf_sh_rho` (`ρ̂_0 … ρ̂_l*`,
/// [`Brdf::sh_coefficients`]) and `ndf_sh_peak` ([`Brdf::peak`]). A tabulated BRDF's table is a texture
/// ([`crate::brdf::Tabulated::table`], sampler `ndf_brdf_table`), not listed here.
pub fn uniforms(brdf: &Brdf, sh_lmax: Option<usize>) -> Vec<(&'static str, Vec<f32>)> {
    let mut out = Vec::new();
    match brdf {
        Brdf::Lambert | Brdf::Tabulated(_) => {}
        Brdf::BlinnPhong { s } => out.push(("ndf_s", vec![*s as f32])),
        Brdf::TorranceSparrow { sigma } => out.push(("ndf_sigma", vec![*sigma as f32])),
        Brdf::Ggx(g) => {
            out.push(("ndf_alpha", vec![g.alpha as f32]));
            out.push(("ndf_ggx_c", vec![g.widening as f32]));
            let m = crate::brdf::ggx_mixture::GgxMixture::of(g.alpha);
            out.push(("ndf_ggx_w", m.weights.iter().map(|&w| w as f32).collect()));
            out.push(("ndf_ggx_eta", m.etas.iter().map(|&e| e as f32).collect()));
            if g.g {
                out.push(("ndf_f0", vec![g.f0 as f32]));
            }
        }
    }
    if let Some(lmax) = sh_lmax
        && brdf.has_specular()
    {
        let rho = brdf.sh_coefficients(lmax);
        out.push(("ndf_sh_rho", rho.iter().map(|&r| r as f32).collect()));
        out.push(("ndf_sh_peak", vec![brdf.peak() as f32]));
    }
    out
}

/// What a shader is specialized for: everything about a bake that changes the GLSL.
#[derive(Debug, Clone, PartialEq)]
pub struct ShaderSpec {
    /// The method.
    pub method: Method,
    /// Lobe textures (mixtures), 0 for baselines.
    pub lobes: usize,
    /// The value range of each channel of each texture the shader may read, in texture order.
    pub ranges: Vec<[ValueRange; 4]>,
    /// The storage format the textures are uploaded in.
    pub format: Format,
    /// Whether the mixture's lobes were aligned (Sec 7.3): decides [`Sampling::Auto`].
    pub aligned: bool,
    /// The bake's addressing (wrap or clamp).
    pub addressing: Addressing,
    /// SH: the band limit l* (0 for the other methods).
    pub lmax: usize,
    /// Signed channels are stored biased, `0.5 + 0.5·v`, whatever [`ShaderSpec::format`] is:
    /// block-compressed textures (module `compress`: BC6H, BC7, BC5 store signed channels
    /// biased; `format` is then the codec's [`crate::compress::Codec::shading_format`], whose
    /// clamps apply). Unsigned-normalized formats are biased whatever this says.
    pub biased: bool,
}

impl ShaderSpec {
    /// The specification of `bake`'s shader when its textures are uploaded in `bake.format`.
    pub fn of(bake: &Bake) -> Self {
        ShaderSpec {
            method: bake.method,
            lobes: bake.lobes,
            ranges: bake.textures.iter().map(|t| t.ranges).collect(),
            format: bake.format,
            aligned: bake.parameters["aligned"] == serde_json::Value::Bool(true),
            addressing: bake.addressing,
            lmax: if bake.method == Method::Sh {
                crate::sh::lmax_of(bake)
            } else {
                0
            },
            biased: false,
        }
    }
}

/// The `#define` name of a method.
fn method_define(method: Method) -> &'static str {
    match method {
        Method::Plain => "NDF_METHOD_PLAIN",
        Method::Toksvig => "NDF_METHOD_TOKSVIG",
        Method::Lean => "NDF_METHOD_LEAN",
        Method::Olano => "NDF_METHOD_OLANO",
        Method::Tan2005 => "NDF_METHOD_TAN2005",
        Method::Vmf => "NDF_METHOD_VMF",
        Method::Sh => "NDF_METHOD_SH",
        Method::Pbr => "NDF_METHOD_PBR",
    }
}

/// A float literal that parses back to exactly `v` as f32.
fn float_literal(v: f32) -> String {
    let s = format!("{v:?}");
    if s.contains(['.', 'e', 'E']) {
        s
    } else {
        format!("{s}.0")
    }
}

/// The specialized source of `bake`'s shader for `stage` (see [`source_for`]).
pub fn source(bake: &Bake, stage: Stage, options: &ShaderOptions) -> Result<String> {
    source_for(&ShaderSpec::of(bake), stage, options)
}

/// Whether `spec` with `options` filters manually (the resolved [`Sampling`]).
pub fn manual_sampling(spec: &ShaderSpec, options: &ShaderOptions) -> bool {
    match options.sampling {
        Sampling::Manual => true,
        Sampling::Hardware | Sampling::Anisotropic(_) => false,
        Sampling::Auto => spec.lobes > 0 && !spec.aligned,
    }
}

/// The textures the shader samples: the lobes (or the baseline's textures), plus the colours
/// when [`ShaderOptions::color`] asks for them. Fails when colour is asked of a bake without
/// colour textures or of a baseline.
pub fn sampled_textures(spec: &ShaderSpec, options: &ShaderOptions) -> Result<usize> {
    let own = if spec.lobes > 0 {
        spec.lobes
    } else {
        spec.ranges.len()
    };
    if !options.color {
        return Ok(own);
    }
    if spec.lobes == 0 || spec.ranges.len() < 2 * spec.lobes {
        return Err(Error::InvalidOption(format!(
            "colour shading needs a mixture bake with colour textures ({} has none)",
            spec.method
        )));
    }
    Ok(2 * spec.lobes)
}

/// The specialized GLSL 3.30 source for `stage`: `#version 330 core`, the `#define`s of `spec`
/// and `options`, then the shader files (module docs). The vertex stage depends on
/// [`ShaderOptions::probe`] only.
pub fn source_for(spec: &ShaderSpec, stage: Stage, options: &ShaderOptions) -> Result<String> {
    if spec.method == Method::Pbr {
        return Err(Error::InvalidOption(
            "a pbr bake has no ndfmap shader: an engine's own GGX metallic-roughness shader reads \
             its normal and roughness textures"
                .into(),
        ));
    }
    let textures = sampled_textures(spec, options)?;
    if spec.ranges.len() < textures || textures == 0 {
        return Err(Error::InvalidOption(format!(
            "the {} bake has {} textures, the shader needs {textures}",
            spec.method,
            spec.ranges.len()
        )));
    }
    if textures > MAX_SAMPLERS {
        return Err(Error::InvalidOption(format!(
            "the shader would sample {textures} textures, more than the {MAX_SAMPLERS} texture \
             units GPUs offer (SH: use l* <= 10)"
        )));
    }
    if let Sampling::Anisotropic(n) = options.sampling
        && !(2..=16).contains(&n)
    {
        return Err(Error::InvalidOption(format!(
            "anisotropic sampling with {n} probes (expected 2 to 16)"
        )));
    }
    if options.vmf_specular == crate::shade::VmfSpecular::Exact {
        return Err(Error::InvalidOption(
            "the exact vMF convolution (quadrature) is a CPU measurement: no shader has it \
             (use auto, eq20 or convolved)"
                .into(),
        ));
    }
    if options.env_lights && !options.light.is_env() {
        return Err(Error::InvalidOption(
            "extracted environment lights need an environment-lit shader".into(),
        ));
    }
    if options.no_diffuse && options.brdf == ShaderBrdf::Lambert {
        return Err(Error::InvalidOption(
            "no diffuse term with the lambert BRDF leaves nothing to shade".into(),
        ));
    }
    if spec.method == Method::Sh && manual_sampling(spec, options) {
        return Err(Error::InvalidOption(
            "SH coefficients filter linearly: sample them with hardware or anisotropic \
             filtering, not manually"
                .into(),
        ));
    }
    if options.light.is_env() {
        // The methods the CPU twin shades (`envlight::check_method`): all but the PBR bake.
        crate::envlight::check_method(spec.method)?;
        if spec.method == Method::Sh && options.light != ShaderLight::EnvSh {
            return Err(Error::InvalidOption(
                "an sh bake is lit by the environment's SH (light env-sh), not by prefiltered \
                 lookups"
                    .into(),
            ));
        }
        if !matches!(
            options.brdf,
            ShaderBrdf::BlinnPhong | ShaderBrdf::Lambert | ShaderBrdf::Ggx { .. }
        ) {
            return Err(Error::InvalidOption(
                "environment lighting supports lambert, blinn-phong and ggx".into(),
            ));
        }
    }
    let mut out = String::from("#version 330 core\n");
    out += &format!(
        "// ndfmap {} - {} shader for {}\n",
        env!("CARGO_PKG_VERSION"),
        match stage {
            Stage::Vertex => "vertex",
            Stage::Fragment => "fragment",
        },
        spec.method
    );
    if options.probe {
        out += "#define NDF_PROBE 1\n";
    }
    if stage == Stage::Vertex {
        out += VERTEX;
        return Ok(out);
    }
    let manual = manual_sampling(spec, options);
    for (name, value, _) in defines(spec, options, textures, manual) {
        let _ = writeln!(out, "#define {name} {value}");
    }
    out += COMMON;
    out += &bindings(spec, textures, manual);
    out += &method_file(spec.method);
    if options.light.is_env() {
        out += &env_block(spec);
    }
    out += FRAGMENT;
    Ok(out)
}

/// One level range of a shader that switches method by level of detail
/// ([`lod_switch_source`]).
#[derive(Debug, Clone, PartialEq)]
pub struct LodPart {
    /// The part's textures and method. Level 0 of its textures is map level `first` (a texture
    /// holding only the part's levels, or the map's chain with `GL_TEXTURE_BASE_LEVEL` =
    /// `first`); the shader reads its levels `0 ..= last − first`.
    pub spec: ShaderSpec,
    /// Its shader options ([`ShaderOptions::color`], [`ShaderOptions::sampling`] and
    /// [`ShaderOptions::vmf_diffuse`], [`ShaderOptions::vmf_cosine`] /
    /// [`ShaderOptions::sh_diffuse`] are the part's own; the
    /// lighting, BRDF, probe flag and [`ShaderOptions::no_diffuse`] must be those of every
    /// part).
    pub options: ShaderOptions,
    /// The finest map level it shades.
    pub first: usize,
    /// The coarsest.
    pub last: usize,
}

/// The identifiers a method's part defines (functions, `const` arrays, samplers) in `text`:
/// what [`lod_switch_source`] renames per part so that several methods live in one shader.
fn part_identifiers(text: &str) -> Vec<String> {
    let mut names: Vec<String> = Vec::new();
    for line in text.lines() {
        let words: Vec<&str> = line
            .split(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
            .filter(|w| !w.is_empty())
            .collect();
        let name = match words.as_slice() {
            // `type name(` at the start of a line: a function definition.
            [ty, name, ..]
                if !line.starts_with(char::is_whitespace)
                    && line.contains(&format!("{ty} {name}("))
                    && matches!(
                        *ty,
                        "void" | "float" | "vec2" | "vec3" | "vec4" | "bool" | "int" | "ivec2"
                    )
                    && !line.trim_start().starts_with("//") =>
            {
                Some(*name)
            }
            ["const", _, name, ..] if line.starts_with("const ") => Some(*name),
            ["uniform", "sampler2D", name, ..] if line.starts_with("uniform ") => Some(*name),
            _ => None,
        };
        // The SH basis is defined as `NDF_BASIS_NAME`, a macro the text sets to `ndf_sh_eval`.
        let name = match name {
            Some("NDF_BASIS_NAME") => Some("ndf_sh_eval"),
            n => n,
        };
        if let Some(n) = name
            && (n.starts_with("ndf_") || n.starts_with("NDF_"))
            && !names.iter().any(|x| x == n)
        {
            names.push(n.to_string());
        }
    }
    names
}

/// The per-part identifier of `name` in part `k`: `ndf_x` → `ndf_p{k}_x`, `NDF_X` → `NDF_P{k}_X`.
fn part_name(name: &str, k: usize) -> String {
    if let Some(rest) = name.strip_prefix("ndf_") {
        format!("ndf_p{k}_{rest}")
    } else {
        format!("NDF_P{k}_{}", &name[4..])
    }
}

/// The sampler of texture `texture` of part `k` in a [`lod_switch_source`] shader:
/// `ndf_p{k}_tex{texture}`.
pub fn lod_switch_sampler(part: usize, texture: usize) -> String {
    format!("ndf_p{part}_tex{texture}")
}

/// One shader for a plan that mixes methods across level ranges (issue 18): the fragment
/// shader (or, for [`Stage::Vertex`], the usual vertex shader) that shades each pixel with the
/// part whose levels hold its level of detail.
///
/// Each part's method code, sampler block and filtering functions are the single-method
/// shader's ([`source_for`]), with the part's `#define`s and every identifier it defines
/// renamed `ndf_p{k}_…` (`#define` renaming, `#undef` after the part): samplers
/// `ndf_p{k}_tex{i}` ([`lod_switch_sampler`]), exactly the textures each part reads. The
/// switch (CPU twin [`crate::sample::lod_switch_weights`] / [`crate::sample::shade_switch`]):
/// λ = the level of detail on the map (`map_size`, GL's rule) clamped to the levels shipped
/// `[first of part 0, last of the last part]`; with ℓ = ⌊λ⌋ and f = λ − ℓ, the part k holding
/// ℓ shades at its local LOD λ − first_k (hardware trilinear or manual within the part); at a
/// part's last level with f > 0, the trilinear blend across the boundary is done as
/// `(1 − f)·shade_k(last_k) + f·shade_{k+1}(first_{k+1})`, the blend of the two parts'
/// shadings. With anisotropic sampling, λ is the probes' `λ'` (`sample::aniso_probes` on the
/// map) and each part averages its probes at its local LOD (clamped to its levels), then
/// shades. Lit by the point light, the prefiltered environment or both ([`ShaderLight`];
/// the environment's helpers once, its `ndf_env_texel` per part); the SH route is refused.
/// Each part's shading is called at one place, weighted (1 inside its levels, 1 − f at its
/// last level, f at the level before its first): each part's code is in the shader once.
/// llvmpipe paid for every inlined copy, even one never executed (docs/planner.md, "why the
/// LOD switch was slow": a one-part switch with three call sites cost 4.5× its part, now 1.0×).
/// The source only; [`lod_switch`] also gives the samplers.
pub fn lod_switch_source(
    parts: &[LodPart],
    map_size: (u32, u32),
    stage: Stage,
    options: &ShaderOptions,
) -> Result<String> {
    lod_switch(parts, map_size, stage, options).map(|s| s.source)
}

/// A shader of [`lod_switch`]: its source and the samplers it declares.
#[derive(Debug, Clone, PartialEq)]
pub struct LodSwitch {
    /// The source ([`lod_switch_source`]).
    pub source: String,
    /// Per part, the samplers the fragment shader declares for it, in texture order:
    /// `samplers[k][i]` = [`lod_switch_sampler`]`(k, i)` reads the part's texture `i`
    /// ([`sampled_textures`] of the part: its lobes or the baseline's textures, then its
    /// colour textures).
    pub samplers: Vec<Vec<String>>,
}

/// [`lod_switch_source`] with the samplers of each part, so that a caller binds textures
/// without reading the source.
pub fn lod_switch(
    parts: &[LodPart],
    map_size: (u32, u32),
    stage: Stage,
    options: &ShaderOptions,
) -> Result<LodSwitch> {
    let bad = |m: String| Err(Error::InvalidOption(m));
    if parts.is_empty() {
        return bad("a LOD-switching shader needs at least one part".into());
    }
    if map_size.0 == 0 || map_size.1 == 0 {
        return bad(format!("map size {}x{}", map_size.0, map_size.1));
    }
    if options.light == ShaderLight::EnvSh {
        return bad(
            "the LOD-switching shader lights by the point light and/or the prefiltered \
             environment route, not the SH route: use one shader per part"
                .into(),
        );
    }
    let aniso = matches!(options.sampling, Sampling::Anisotropic(_));
    let mut samplers = 0;
    for (k, p) in parts.iter().enumerate() {
        if p.first > p.last || (k > 0 && p.first != parts[k - 1].last + 1) {
            return bad(format!(
                "part {k} (levels {}-{}) does not follow the previous part's levels",
                p.first, p.last
            ));
        }
        let o = &p.options;
        if o.light != options.light
            || o.env_lights != options.env_lights
            || o.brdf != options.brdf
            || o.probe != options.probe
            || o.no_diffuse != options.no_diffuse
        {
            return bad(format!(
                "part {k}: lighting (extracted lights included), BRDF, probe flag and diffuse \
                 term must be the shader's"
            ));
        }
        if p.spec.addressing != parts[0].spec.addressing {
            return bad(format!("part {k}: another texture addressing"));
        }
        if matches!(o.sampling, Sampling::Anisotropic(_)) != aniso {
            return bad(format!(
                "part {k}: anisotropic sampling must be every part's or none's"
            ));
        }
        // Every check of the single-method shader applies to the part.
        source_for(&p.spec, Stage::Fragment, o)?;
        samplers += sampled_textures(&p.spec, o)?;
    }
    if samplers > MAX_SAMPLERS {
        return bad(format!(
            "the LOD-switching shader would sample {samplers} textures, more than the \
             {MAX_SAMPLERS} texture units GPUs offer: use one shader per part"
        ));
    }
    let sampler_names = parts
        .iter()
        .enumerate()
        .map(|(k, p)| {
            Ok((0..sampled_textures(&p.spec, &p.options)?)
                .map(|i| lod_switch_sampler(k, i))
                .collect())
        })
        .collect::<Result<Vec<Vec<String>>>>()?;
    let label: Vec<String> = parts
        .iter()
        .map(|p| format!("L{}-{} {}", p.first, p.last, p.spec.method))
        .collect();
    let mut out = String::from("#version 330 core\n");
    let _ = writeln!(
        out,
        "// ndfmap {} - {} shader switching method by level of detail: {}",
        env!("CARGO_PKG_VERSION"),
        match stage {
            Stage::Vertex => "vertex",
            Stage::Fragment => "fragment",
        },
        label.join("; ")
    );
    if options.probe {
        out += "#define NDF_PROBE 1\n";
    }
    if stage == Stage::Vertex {
        out += VERTEX;
        return Ok(LodSwitch {
            source: out,
            samplers: sampler_names,
        });
    }
    let first_spec = &parts[0].spec;
    let first_textures = sampled_textures(first_spec, &parts[0].options)?;
    let manual0 = manual_sampling(first_spec, &parts[0].options);
    for (name, value, scope) in defines(first_spec, options, first_textures, manual0) {
        if scope == Scope::Common {
            let _ = writeln!(out, "#define {name} {value}");
        }
    }
    out += "#define NDF_LOD_SWITCH 1\n";
    // The convolved vMF rule's helpers live in the common code, before any part's defines.
    if parts.iter().any(|p| {
        p.spec.method == Method::Vmf
            && p.options.vmf_specular == crate::shade::VmfSpecular::Convolved
    }) {
        out += "#define NDF_LOD_SWITCH_VMF_CONVOLVED 1\n";
    }
    out += COMMON;
    out += FRAGMENT_HEAD;
    let (env_helpers, env_texel) = if options.light.is_env() {
        env_sections()?
    } else {
        (String::new(), String::new())
    };
    if options.light == ShaderLight::PointAndEnvPrefiltered {
        out += FRAGMENT_BOTH;
    }
    out += &env_helpers;
    let probes = if aniso {
        "\n// The anisotropic probes of ndf_shade_switch_aniso averaged at this part's local LOD, \
         then shaded.\nvoid ndf_shade_probes(vec2 uv, vec2 major, int n, float lod, vec3 l, \
         vec3 h, out vec3 diffuse,\n                      out vec3 specular) {\n    \
         vec4 t[NDF_TEXTURES];\n    for (int k = 0; k < NDF_TEXTURES; ++k) t[k] = vec4(0.0);\n    \
         for (int i = 1; i <= NDF_ANISO; ++i) {\n        if (i > n) break;\n        \
         vec4 p[NDF_TEXTURES];\n        ndf_fetch_lod(uv + major * (float(i) / float(n + 1) - \
         0.5), lod, p);\n        for (int k = 0; k < NDF_TEXTURES; ++k) t[k] += p[k];\n    }\n    \
         for (int k = 0; k < NDF_TEXTURES; ++k) t[k] /= float(n);\n    \
         ndf_texel(t, l, h, diffuse, specular);\n}\n"
    } else {
        ""
    };
    for (k, p) in parts.iter().enumerate() {
        let textures = sampled_textures(&p.spec, &p.options)?;
        let manual = manual_sampling(&p.spec, &p.options);
        let defs: Vec<(&str, String)> = defines(&p.spec, &p.options, textures, manual)
            .into_iter()
            .filter(|d| d.2 == Scope::Part)
            .map(|(n, v, _)| (n, v))
            .collect();
        let text = bindings(&p.spec, textures, manual)
            + &method_file(p.spec.method)
            + &env_texel
            + FRAGMENT_LEVEL
            + FRAGMENT_FILTER
            + probes;
        let names = part_identifiers(&text);
        // Macros the part's text defines for itself (`NDF_ENV_LP`) are undefined after it.
        let own: Vec<&str> = text
            .lines()
            .filter_map(|l| l.trim_start().strip_prefix("#define "))
            .filter_map(|l| l.split_whitespace().next())
            .filter(|n| !text.contains(&format!("#undef {n}")))
            .collect();
        let _ = writeln!(
            out,
            "\n// ---- part {k}: levels {}-{}, {} ({} texture(s) {}, level 0 = map level {})",
            p.first, p.last, p.spec.method, textures, p.spec.format, p.first
        );
        for (n, v) in &defs {
            let _ = writeln!(out, "#define {n} {v}");
        }
        for n in &names {
            let _ = writeln!(out, "#define {n} {}", part_name(n, k));
        }
        out += &text;
        let mut undone: Vec<&str> = Vec::new();
        for n in defs
            .iter()
            .map(|d| d.0)
            .chain(names.iter().map(|n| n.as_str()))
            .chain(own)
        {
            if !undone.contains(&n) {
                undone.push(n);
                let _ = writeln!(out, "#undef {n}");
            }
        }
    }
    if let Sampling::Anisotropic(n) = options.sampling {
        let _ = writeln!(out, "#define NDF_ANISO {n}");
    }
    out += &switch_block(parts, map_size, aniso);
    out += FRAGMENT_MAIN;
    Ok(LodSwitch {
        source: out,
        samplers: sampler_names,
    })
}

/// [`env_block`] cut for the LOD-switching shader: the environment's data and lobe helpers
/// (once; no method defined, so no SH-bake code) and `ndf_env_texel` with its comment (per
/// part: it reads the part's method and textures).
fn env_sections() -> Result<(String, String)> {
    let whole = sh_basis("ndf_env_basis", "8") + ENV;
    let Some(at) = whole.find("\nvoid ndf_env_texel(") else {
        return Err(Error::InvalidOption(
            "glsl/ndf_env.glsl lacks ndf_env_texel, where the LOD-switching shader cuts it".into(),
        ));
    };
    // Back over the function's comment lines.
    let mut cut = at + 1;
    while let Some(prev) = whole[..cut - 1].rfind('\n') {
        if whole[prev + 1..cut].starts_with("//") {
            cut = prev + 1;
        } else {
            break;
        }
    }
    Ok((whole[..cut].to_string(), whole[cut..].to_string()))
}

/// What an engine should know before drawing the [`lod_switch`] shader of `parts` lit by
/// `light`, where something is known: `Some` for two parts or more under the environment. Each
/// part shades its own environment term, so the shader holds one inlined copy of the prefiltered
/// lookups per part. On an NVIDIA H100/H200 the planner's mixed scene's switch (two parts, both
/// lights) cost 1.83× its costliest part, for the second copy and not for work done
/// (docs/planner.md, "Frame time on a GPU"); llvmpipe showed 0.99–1.14×. `None` otherwise.
pub fn lod_switch_caution(parts: &[LodPart], light: ShaderLight) -> Option<String> {
    (parts.len() >= 2 && light.is_env()).then(|| {
        format!(
            "the LOD-switching shader has {} parts lit by the environment, each with its own copy \
             of the environment's shading: on an NVIDIA H100/H200 such a switch cost 1.83x its \
             costliest part (docs/planner.md, \"Frame time on a GPU\"); time it on your GPU, or \
             draw each part's shader for the levels it holds",
            parts.len()
        )
    })
}

/// The generated switch of [`lod_switch_source`]: `ndf_shade` (and, anisotropic,
/// `ndf_shade_footprint`) choosing the part by level of detail, blending two parts across a
/// boundary.
fn switch_block(parts: &[LodPart], map_size: (u32, u32), aniso: bool) -> String {
    let n = parts.len();
    let mut s = String::from(
        "\n// ---- the switch: the part holding floor(lambda) shades (CPU twin: sample::shade_switch)\n",
    );
    let _ = writeln!(
        s,
        "const vec2 NDF_MAP_SIZE = vec2({}, {});",
        float_literal(map_size.0 as f32),
        float_literal(map_size.1 as f32)
    );
    let (sig, call) = if aniso {
        (
            "vec2 uv, vec2 major, int n, float lod",
            "(uv, major, n, {lod}, l, h, {out});",
        )
    } else {
        ("vec2 uv, float lod", "(uv, {lod}, l, h, {out});")
    };
    let name = if aniso { "shade_probes" } else { "shade" };
    let part_call = |k: usize, lod: &str, out: &str| {
        format!(
            "ndf_p{k}_{name}{}",
            call.replace("{lod}", lod).replace("{out}", out)
        )
    };
    let first = parts[0].first;
    let last = parts[n - 1].last;
    let _ = write!(
        s,
        "\n// The switch at level of detail lod: lambda = lod clamped to the levels shipped, \
         level = floor(lambda),\n// f = lambda - level. Part k (levels a..b) shades at its \
         local LOD clamp(lambda - a, 0, b - a) with\n// weight 1 inside its levels, 1 - f at \
         its last level b (the trilinear blend across the boundary)\n// and f at level a - 1 \
         (the previous part's last): each part's code appears once, called where\n// its \
         weight is > 0 (llvmpipe paid for every inlined copy of a part's shading, even one \
         never\n// executed).\n\
         void ndf_switch({sig}, vec3 l, vec3 h, out vec3 diffuse,\n\
         \x20               out vec3 specular) {{\n"
    );
    if n == 1 {
        // One part: its weight is 1 at every LOD (lambda <= its last level, where f = 0).
        let _ = writeln!(
            s,
            "    float local = clamp(lod, {}, {}) - {};\n    {}\n}}",
            float_literal(first as f32),
            float_literal(last as f32),
            float_literal(first as f32),
            part_call(0, "local", "diffuse, specular")
        );
    } else {
        let _ = writeln!(
            s,
            "    float lambda = clamp(lod, {}, {});\n    float level = floor(lambda);\n    \
             float f = lambda - level;\n    diffuse = vec3(0.0);\n    specular = vec3(0.0);\n    \
             vec3 d;\n    vec3 s;\n    float w;",
            float_literal(first as f32),
            float_literal(last as f32),
        );
        for (k, p) in parts.iter().enumerate() {
            let a = float_literal(p.first as f32);
            let b = float_literal(p.last as f32);
            // Inside [a, b): 1; at b: 1 - f (f = 0 at the last part's last level); at a - 1
            // (not for part 0, which starts at the clamp): f.
            let inner = if p.first == p.last {
                format!("level == {b} ? 1.0 - f")
            } else {
                format!("level >= {a} && level < {b} ? 1.0 : (level == {b} ? 1.0 - f")
            };
            let before = if k == 0 {
                String::new()
            } else {
                format!(" : (level == {} ? f", float_literal(p.first as f32 - 1.0))
            };
            let closes = if k == 0 { "" } else { ")" };
            let inner_closes = if p.first == p.last { "" } else { ")" };
            let _ = writeln!(
                s,
                "    // part {k}: levels {}-{}\n    w = {inner}{before} : 0.0{closes}{inner_closes};\n    \
                 if (w > 0.0) {{\n        {}\n        diffuse += w * d;\n        \
                 specular += w * s;\n    }}",
                p.first,
                p.last,
                part_call(
                    k,
                    &format!(
                        "clamp(lambda - {a}, 0.0, {})",
                        float_literal((p.last - p.first) as f32)
                    ),
                    "d, s"
                ),
            );
        }
        s += "}\n";
    }
    if aniso {
        s += "\n// The anisotropic footprint on the map (sample::aniso_probes), switched by its \
              probes' LOD.\nvoid ndf_shade_footprint(vec2 uv, vec2 dx, vec2 dy, vec3 l, vec3 h, \
              out vec3 diffuse,\n                         out vec3 specular) {\n    \
              float px = length(dx * NDF_MAP_SIZE);\n    float py = length(dy * NDF_MAP_SIZE);\n    \
              float pmax = max(px, py);\n    float pmin = min(px, py);\n    \
              float ratio = pmin > 0.0 ? min(pmax / pmin, float(NDF_ANISO)) : float(NDF_ANISO);\n    \
              int n = clamp(int(ceil(ratio)), 1, NDF_ANISO);\n    \
              float lod = log2(max(pmax / float(n), 1e-15));\n    \
              ndf_switch(uv, px >= py ? dx : dy, n, lod, l, h, diffuse, specular);\n\
              #if !defined(NDF_LIGHT_ENV) && !defined(NDF_LIGHT_BOTH)\n    \
              specular *= ndf_g(l, h);\n#endif\n}\n";
    } else {
        s += "\n// Filtered shading at uv and level of detail lod (the entry points' ndf_shade).\n\
              void ndf_shade(vec2 uv, float lod, vec3 l, vec3 h, out vec3 diffuse, out vec3 specular) {\n    \
              ndf_switch(uv, lod, l, h, diffuse, specular);\n}\n\n\
              // At GL's level of detail on the map, times the g factor.\n\
              void ndf_shade_footprint(vec2 uv, vec2 dx, vec2 dy, vec3 l, vec3 h, out vec3 diffuse,\n\
              \x20                        out vec3 specular) {\n    \
              ndf_shade(uv, ndf_lod(dx, dy, NDF_MAP_SIZE), l, h, diffuse, specular);\n\
              #if !defined(NDF_LIGHT_ENV) && !defined(NDF_LIGHT_BOTH)\n    \
              specular *= ndf_g(l, h);\n#endif\n}\n";
    }
    s
}

/// Whether a `#define` of [`defines`] belongs to the method's part of a shader (renewed per
/// part in [`lod_switch_source`]) or is common to the whole shader.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Scope {
    /// Method, textures, sampling: one value per part.
    Part,
    /// BRDF, lighting, addressing: the same for every part.
    Common,
}

/// The `#define`s of `spec` and `options` (name, value, scope), in the order [`source_for`]
/// writes them.
fn defines(
    spec: &ShaderSpec,
    options: &ShaderOptions,
    textures: usize,
    manual: bool,
) -> Vec<(&'static str, String, Scope)> {
    use Scope::{Common, Part};
    let mut v: Vec<(&'static str, String, Scope)> = Vec::new();
    let mut d = |name: &'static str, value: &str, scope: Scope| v.push((name, value.into(), scope));
    d(method_define(spec.method), "1", Part);
    if spec.lobes > 0 {
        d("NDF_LOBES", &spec.lobes.to_string(), Part);
    }
    d("NDF_TEXTURES", &textures.to_string(), Part);
    match options.brdf {
        ShaderBrdf::BlinnPhong => {}
        ShaderBrdf::TorranceSparrow => d("NDF_BRDF_TORRANCE_SPARROW", "1", Common),
        ShaderBrdf::Lambert => d("NDF_BRDF_LAMBERT", "1", Common),
        ShaderBrdf::Ggx { g } => {
            d("NDF_BRDF_GGX", "1", Common);
            if g {
                d("NDF_BRDF_G", "1", Common);
            }
        }
        ShaderBrdf::Tabulated => d("NDF_BRDF_TABULATED", "1", Common),
    }
    if spec.method == Method::Sh {
        d("NDF_SH_LMAX", &spec.lmax.to_string(), Part);
    }
    if let Sampling::Anisotropic(n) = options.sampling {
        d("NDF_ANISO", &n.to_string(), Part);
    }
    if spec.method == Method::Vmf && options.vmf_diffuse == crate::shade::VmfDiffuse::Algorithm2 {
        d("NDF_VMF_DIFFUSE_ALG2", "1", Part);
    }
    if spec.method == Method::Vmf && options.vmf_specular == crate::shade::VmfSpecular::Convolved {
        d("NDF_VMF_SPECULAR_CONVOLVED", "1", Part);
    }
    if spec.method == Method::Vmf && options.vmf_cosine == crate::shade::VmfCosine::Algorithm2 {
        d("NDF_VMF_COSINE_ALG2", "1", Part);
    }
    // Under GGX the default (Auto) is the vMF-mixture convolution; eq20 asks for the single
    // widened lobe. Blinn-Phong's eq 20 is the default already: no define, the same source.
    if spec.method == Method::Vmf
        && options.vmf_specular == crate::shade::VmfSpecular::Eq20
        && matches!(options.brdf, ShaderBrdf::Ggx { .. })
    {
        d("NDF_VMF_SPECULAR_EQ20", "1", Part);
    }
    if spec.method == Method::Sh && options.sh_diffuse == crate::sh::ShDiffuse::Series {
        d("NDF_SH_DIFFUSE_SERIES", "1", Part);
    }
    if options.color {
        d("NDF_COLOR", "1", Part);
    }
    match options.light {
        ShaderLight::Point => {}
        ShaderLight::EnvPrefiltered => {
            d("NDF_LIGHT_ENV", "1", Common);
            d("NDF_LIGHT_ENV_PREFILTERED", "1", Common);
        }
        ShaderLight::EnvSh => {
            d("NDF_LIGHT_ENV", "1", Common);
            d("NDF_LIGHT_ENV_SH", "1", Common);
        }
        ShaderLight::PointAndEnvPrefiltered => {
            d("NDF_LIGHT_BOTH", "1", Common);
            d("NDF_LIGHT_ENV_PREFILTERED", "1", Common);
        }
    }
    if options.env_lights && options.light.is_env() {
        d("NDF_ENV_LIGHTS", &MAX_ENV_LIGHTS.to_string(), Common);
    }
    if options.no_diffuse {
        d("NDF_NO_DIFFUSE", "1", Common);
    }
    if manual {
        d("NDF_MANUAL", "1", Part);
    }
    if spec.addressing == Addressing::Clamp {
        d("NDF_CLAMP", "1", Common);
    }
    if spec.method == Method::Vmf || (spec.method == Method::Toksvig && options.light.is_env()) {
        d(
            "NDF_R_MAX",
            &float_literal(crate::vmf::r_max(spec.format) as f32),
            Part,
        );
        d(
            "NDF_ALPHA_MIN",
            &float_literal(crate::vmf::alpha_min(spec.format) as f32),
            Part,
        );
    }
    v
}

/// The method file(s) of `method` (SH: the basis instantiated as `ndf_sh_eval`, then eq 12).
fn method_file(method: Method) -> String {
    match method {
        Method::Vmf => VMF.to_string(),
        Method::Tan2005 => TAN2005.to_string(),
        Method::Sh => sh_basis("ndf_sh_eval", "NDF_SH_LMAX") + SH,
        _ => BASELINES.to_string(),
    }
}

/// [`SH_BASIS`] instantiated as `void name(vec3 d, out float y[(lmax + 1)²])` (`lmax`: a
/// literal or a macro defined before it).
pub fn sh_basis(name: &str, lmax: &str) -> String {
    format!(
        "\n#define NDF_BASIS_NAME {name}\n#define NDF_BASIS_LMAX {lmax}\n{SH_BASIS}\
         #undef NDF_BASIS_NAME\n#undef NDF_BASIS_LMAX\n"
    )
}

/// What an environment [`ShaderLight`] appends after the method file: `ndf_env_basis`
/// ([`sh_basis`] at l ≤ 8), for SH bakes the constant `NDF_ENV_X90` (the band blocks of the
/// rotation by 90° about x up to `min(l*, 8)`, [`crate::environment::projection::x90_blocks`],
/// for the per-fragment rotation into the tangent frame), and [`ENV`].
fn env_block(spec: &ShaderSpec) -> String {
    let mut out = sh_basis("ndf_env_basis", "8");
    if spec.method == Method::Sh {
        let blocks =
            crate::environment::projection::x90_blocks(spec.lmax.min(crate::envlight::ENV_LMAX));
        let values: Vec<String> = blocks.iter().map(|&v| float_literal(v as f32)).collect();
        let _ = writeln!(
            out,
            "const float NDF_ENV_X90[{}] = float[]({});",
            values.len(),
            values.join(", ")
        );
    }
    out + ENV
}

/// The generated block: one sampler per texture read, and the fetch function (`textureLod` for
/// hardware sampling, `texelFetch` for manual) that decodes unsigned-normalized storage.
fn bindings(spec: &ShaderSpec, textures: usize, manual: bool) -> String {
    let unorm = spec.biased || matches!(spec.format, Format::Unorm16 | Format::Unorm8);
    let mut s = String::from("\n// Generated by ndfmap::glsl: the samplers this shader reads.\n");
    for i in 0..textures {
        let _ = writeln!(s, "uniform sampler2D ndf_tex{i};");
    }
    let (signature, call) = if manual {
        (
            "void ndf_fetch_texel(ivec2 p, int level, out vec4 t[NDF_TEXTURES])",
            "texelFetch(ndf_tex{i}, p, level)",
        )
    } else {
        (
            "void ndf_fetch_lod(vec2 uv, float lod, out vec4 t[NDF_TEXTURES])",
            "textureLod(ndf_tex{i}, uv, lod)",
        )
    };
    let _ = writeln!(s, "{signature} {{");
    for (i, ranges) in spec.ranges.iter().take(textures).enumerate() {
        let fetch = call.replace("{i}", &i.to_string());
        let signed = ranges.map(|r| r == ValueRange::Signed);
        if unorm && signed.contains(&true) {
            // Signed channels are stored as 0.5 + 0.5 v: v = 2u − 1 (linear, so it commutes
            // with filtering).
            let scale = signed.map(|b| if b { "2.0" } else { "1.0" }).join(", ");
            let offset = signed.map(|b| if b { "-1.0" } else { "0.0" }).join(", ");
            let _ = writeln!(s, "    t[{i}] = {fetch} * vec4({scale}) + vec4({offset});");
        } else {
            let _ = writeln!(s, "    t[{i}] = {fetch};");
        }
    }
    s += "}\n\n";
    if spec.method == Method::Sh {
        // Lambert's ρ̂_l (closed forms, brdf::lambert_coefficient): the diffuse term's weights.
        let rho: Vec<String> = (0..=spec.lmax)
            .map(|l| float_literal(crate::brdf::lambert_coefficient(l) as f32))
            .collect();
        let _ = writeln!(
            s,
            "const float NDF_SH_LAMBERT[{}] = float[]({});\n",
            spec.lmax + 1,
            rho.join(", ")
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::BakeOptions;
    use crate::ingest::NormalMap;
    use crate::methods::{bake, bake_with};

    fn map() -> NormalMap {
        crate::procedural::generate(8, 1).map
    }

    /// A vMF J = 2 bake of [`map`].
    fn vmf2() -> Bake {
        let options = BakeOptions {
            lobes: 2,
            ..Default::default()
        };
        bake_with(&map(), Method::Vmf, &options).unwrap()
    }

    #[test]
    fn texture_ranges_match_what_bakes_produce() {
        let sample = crate::procedural::generate(8, 2);
        let colored = sample
            .map
            .clone()
            .with_feature(sample.albedo.clone())
            .unwrap();
        for method in Method::ALL {
            for color in [false, true] {
                if color && !matches!(method, Method::Vmf | Method::Tan2005) {
                    continue;
                }
                let opts = BakeOptions {
                    lobes: 2,
                    ..Default::default()
                };
                let m = if color { &colored } else { &sample.map };
                let b = bake_with(m, method, &opts).unwrap();
                let size = if method == Method::Sh {
                    crate::sh::lmax_of(&b)
                } else {
                    b.lobes
                };
                let want = crate::methods::texture_ranges(method, size, color);
                assert_eq!(ShaderSpec::of(&b).ranges, want, "{method} color={color}");
            }
        }
    }

    #[test]
    fn the_lod_switch_renames_each_part_and_refuses_what_it_cannot_switch() {
        let vmf = |lobes: usize, aligned: bool| {
            let b = bake_with(
                &map(),
                Method::Vmf,
                &BakeOptions {
                    lobes,
                    align: aligned.then_some(1.0),
                    ..Default::default()
                },
            )
            .unwrap();
            ShaderSpec::of(&b)
        };
        let plain = ShaderSpec::of(&bake(&map(), Method::Plain));
        let o = ShaderOptions::default();
        let part = |spec: ShaderSpec, first, last| LodPart {
            spec,
            options: o,
            first,
            last,
        };
        let parts = vec![
            part(plain.clone(), 0, 1),
            part(vmf(2, true), 2, 3),
            part(vmf(3, false), 4, 5),
        ];
        let src = lod_switch_source(&parts, (32, 32), Stage::Fragment, &o).unwrap();
        // The caution for several parts under the environment only.
        let env = ShaderLight::PointAndEnvPrefiltered;
        assert!(lod_switch_caution(&parts, env).is_some_and(|c| c.contains("has 3 parts")));
        assert!(lod_switch_caution(&parts, ShaderLight::EnvPrefiltered).is_some());
        assert_eq!(lod_switch_caution(&parts, ShaderLight::Point), None);
        assert_eq!(lod_switch_caution(&parts[..1], env), None);
        // Exactly the samplers each part reads, renamed per part; no unrenamed sampler.
        for (k, n) in [(0, 1), (1, 2), (2, 3)] {
            for i in 0..4 {
                let decl = format!("#define ndf_tex{i} {}", lod_switch_sampler(k, i));
                assert_eq!(src.contains(&decl), i < n, "part {k} texture {i}");
            }
        }
        assert_eq!(src.matches("uniform sampler2D ndf_tex").count(), 6);
        // The convolved vMF rule's helpers only where a part uses that rule.
        assert!(!src.contains("#define NDF_LOD_SWITCH_VMF_CONVOLVED"));
        let convolved = ShaderOptions {
            vmf_specular: crate::shade::VmfSpecular::Convolved,
            ..o
        };
        let mut with_rule = parts.clone();
        with_rule[2].options = convolved;
        let src2 = lod_switch_source(&with_rule, (32, 32), Stage::Fragment, &o).unwrap();
        let common = src2.find("#define NDF_LOD_SWITCH_VMF_CONVOLVED 1").unwrap();
        assert!(common < src2.find("float ndf_vmf_half_norm(").unwrap());
        assert_eq!(
            src2.matches("#define NDF_VMF_SPECULAR_CONVOLVED 1").count(),
            1
        );
        // Each part's functions under its own name, the switch's once.
        for k in 0..3 {
            assert!(src.contains(&format!("#define ndf_shade_texel ndf_p{k}_shade_texel")));
            // One call site per part (llvmpipe paid for every inlined copy of a part's
            // shading, even a never-executed one): weighted, at the part's local LOD.
            assert_eq!(
                src.matches(&format!("ndf_p{k}_shade(")).count(),
                1,
                "part {k}"
            );
            let a = 2 * k;
            assert!(src.contains(&format!(
                "ndf_p{k}_shade(uv, clamp(lambda - {a}.0, 0.0, 1.0), l, h, d, s);"
            )));
        }
        assert!(
            src.contains("w = level >= 0.0 && level < 1.0 ? 1.0 : (level == 1.0 ? 1.0 - f : 0.0);")
        );
        assert!(src.contains(
            "w = level >= 2.0 && level < 3.0 ? 1.0 : (level == 3.0 ? 1.0 - f : (level == 1.0 ? f : 0.0));"
        ));
        assert!(src.contains("float lambda = clamp(lod, 0.0, 5.0);"));
        assert!(src.contains("#define ndf_vmf_decode ndf_p1_vmf_decode"));
        // One part: called once, unweighted (its weight is 1 at every LOD it is clamped to).
        let one = lod_switch_source(&parts[1..2], (32, 32), Stage::Fragment, &o).unwrap();
        assert_eq!(one.matches("ndf_p0_shade(").count(), 1);
        assert!(one.contains(
            "float local = clamp(lod, 2.0, 3.0) - 2.0;\n    ndf_p0_shade(uv, local, l, h, diffuse, specular);"
        ));
        assert!(!one.contains("    w = level"));
        // The samplers the generator returns are those the source declares per part (its
        // renaming #defines, in texture order).
        let switch = lod_switch(&parts, (32, 32), Stage::Fragment, &o).unwrap();
        assert_eq!(switch.source, src);
        for (k, n) in [(0, 1), (1, 2), (2, 3)] {
            let declared: Vec<String> = src
                .lines()
                .filter_map(|l| l.strip_prefix("#define ndf_tex")?.split_once(' '))
                .filter(|(i, _)| i.parse::<usize>().is_ok())
                .map(|(_, target)| target.to_string())
                .filter(|t| t.starts_with(&format!("ndf_p{k}_tex")))
                .collect();
            assert_eq!(declared.len(), n);
            assert_eq!(switch.samplers[k], declared, "part {k}");
        }
        assert!(src.contains("const vec2 NDF_MAP_SIZE = vec2(32.0, 32.0);"));
        // Three part copies (renamed by their #defines) and the switch's.
        assert_eq!(src.matches("void ndf_shade(").count(), 4);
        assert_eq!(
            src.matches("void main()").count(),
            2,
            "probe and mesh, once each"
        );
        // Part 2 is unaligned: manual sampling there only.
        let p2 = &src[src.find("// ---- part 2").unwrap()..];
        assert!(p2.contains("#define NDF_MANUAL 1"));
        assert!(!src[..src.find("// ---- part 2").unwrap()].contains("#define NDF_MANUAL 1"));
        // The vertex shader is the usual one.
        let vert = lod_switch_source(&parts, (32, 32), Stage::Vertex, &o).unwrap();
        assert!(vert.ends_with(VERTEX));
        // Refused: gaps or overlaps, another lighting in a part, the SH route, mixed
        // anisotropy, no part, an empty map, too many samplers.
        let err = |parts: &[LodPart], opts: &ShaderOptions| {
            lod_switch_source(parts, (32, 32), Stage::Fragment, opts)
                .unwrap_err()
                .to_string()
        };
        let mut gap = parts.clone();
        gap[1].first = 3;
        assert!(err(&gap, &o).contains("does not follow"));
        let mut lit = parts.clone();
        lit[1].options.light = ShaderLight::PointAndEnvPrefiltered;
        assert!(err(&lit, &o).contains("must be the shader's"));
        let sh = ShaderOptions {
            light: ShaderLight::EnvSh,
            ..o
        };
        assert!(err(&parts, &sh).contains("SH route"));
        let mut aniso = parts.clone();
        aniso[0].options.sampling = Sampling::Anisotropic(4);
        assert!(err(&aniso, &o).contains("anisotropic"));
        assert!(err(&[], &o).contains("at least one part"));
        assert!(lod_switch_source(&parts, (0, 32), Stage::Fragment, &o).is_err());
        let many: Vec<LodPart> = (0..5).map(|k| part(vmf(8, true), k, k)).collect();
        assert!(err(&many, &o).contains("more than the 32"));
        // A part's own refusals apply (colour of a bake without colour textures).
        let mut color = parts.clone();
        color[1].options.color = true;
        assert!(lod_switch_source(&color, (32, 32), Stage::Fragment, &o).is_err());
    }

    #[test]
    fn float_literals_round_trip() {
        for v in [
            1.0f32,
            0.5,
            1.0 - 2f32.powi(-22),
            1.0 - 2f32.powi(-11),
            3.0e-7,
        ] {
            let s = float_literal(v);
            assert!(s.contains('.') || s.contains('e'), "{s}");
            assert_eq!(s.parse::<f32>().unwrap(), v);
        }
    }

    #[test]
    fn only_the_samplers_read_are_declared() {
        let opts = BakeOptions {
            lobes: 3,
            ..Default::default()
        };
        let b = bake_with(&map(), Method::Vmf, &opts).unwrap();
        let src = source(&b, Stage::Fragment, &ShaderOptions::default()).unwrap();
        assert!(src.starts_with("#version 330 core\n"));
        assert!(src.contains("uniform sampler2D ndf_tex2;"));
        assert!(!src.contains("ndf_tex3"));
        assert!(
            src.contains("#define NDF_MANUAL 1"),
            "unaligned vMF filters manually"
        );
        let err = source(
            &b,
            Stage::Fragment,
            &ShaderOptions {
                color: true,
                ..Default::default()
            },
        );
        assert!(matches!(err, Err(Error::InvalidOption(_))));
        let toksvig = bake(&map(), Method::Toksvig);
        let src = source(&toksvig, Stage::Fragment, &ShaderOptions::default()).unwrap();
        assert!(
            src.contains("#define NDF_METHOD_TOKSVIG 1") && !src.contains("#define NDF_MANUAL")
        );
        // The SH diffuse term: moments unless the series is asked for (SH bakes only).
        let sh = bake_with(
            &map(),
            Method::Sh,
            &BakeOptions {
                lmax: 2,
                ..Default::default()
            },
        )
        .unwrap();
        let series = ShaderOptions {
            sh_diffuse: crate::sh::ShDiffuse::Series,
            ..Default::default()
        };
        let define = "#define NDF_SH_DIFFUSE_SERIES 1";
        assert!(
            !source(&sh, Stage::Fragment, &ShaderOptions::default())
                .unwrap()
                .contains(define)
        );
        assert!(
            source(&sh, Stage::Fragment, &series)
                .unwrap()
                .contains(define)
        );
        assert!(
            !source(&toksvig, Stage::Fragment, &series)
                .unwrap()
                .contains(define)
        );
    }

    #[test]
    fn extracted_lights_are_one_define_on_environment_shaders_only() {
        // env_lights adds exactly `#define NDF_ENV_LIGHTS 8` to an environment-lit shader (the
        // loop and its uniforms are in ndf_env.glsl under it); off, the source is unchanged.
        let b = vmf2();
        for light in [
            ShaderLight::EnvPrefiltered,
            ShaderLight::EnvSh,
            ShaderLight::PointAndEnvPrefiltered,
        ] {
            let o = ShaderOptions {
                light,
                ..Default::default()
            };
            let off = source(&b, Stage::Fragment, &o).unwrap();
            assert!(!off.contains("#define NDF_ENV_LIGHTS"));
            let on = source(
                &b,
                Stage::Fragment,
                &ShaderOptions {
                    env_lights: true,
                    ..o
                },
            )
            .unwrap();
            let define = format!("#define NDF_ENV_LIGHTS {MAX_ENV_LIGHTS}\n");
            assert_eq!(on.matches(&define).count(), 1, "{light:?}");
            assert_eq!(on.replacen(&define, "", 1), off, "{light:?}");
            assert!(on.contains("void ndf_env_lights(") && on.contains("ndf_env_light_count"));
        }
        // Refused with the point light alone.
        let point = ShaderOptions {
            env_lights: true,
            ..Default::default()
        };
        assert!(matches!(
            source(&b, Stage::Fragment, &point),
            Err(Error::InvalidOption(_))
        ));
        let env = ShaderOptions {
            light: ShaderLight::EnvPrefiltered,
            env_lights: true,
            ..Default::default()
        };
        // The LOD-switching shader (the planner's): the define once, before the common code,
        // each part's light loop renamed like its other functions (`ndf_p{k}_…`, it reads the
        // part's method), the uniforms once; every part must agree.
        let part = |first, last, options| LodPart {
            spec: ShaderSpec::of(&b),
            options,
            first,
            last,
        };
        let n = b.level_count() - 1;
        let two = [part(0, 0, env), part(1, n, env)];
        let on = lod_switch_source(&two, (16, 16), Stage::Fragment, &env).unwrap();
        let define = format!("#define NDF_ENV_LIGHTS {MAX_ENV_LIGHTS}\n");
        assert_eq!(on.matches(&define).count(), 1);
        assert!(on.find(&define).unwrap() < on.find("#define NDF_LOD_SWITCH 1").unwrap());
        assert_eq!(on.matches("uniform float ndf_env_light_count;").count(), 1);
        for k in 0..2 {
            assert!(
                on.contains(&format!("#define ndf_env_lights ndf_p{k}_env_lights")),
                "part {k}"
            );
        }
        let off_options = ShaderOptions {
            env_lights: false,
            ..env
        };
        let off = lod_switch_source(
            &[part(0, 0, off_options), part(1, n, off_options)],
            (16, 16),
            Stage::Fragment,
            &off_options,
        )
        .unwrap();
        assert_eq!(on.replacen(&define, "", 1), off);
        assert!(matches!(
            lod_switch_source(
                &[part(0, 0, env), part(1, n, off_options)],
                (16, 16),
                Stage::Fragment,
                &env
            ),
            Err(Error::InvalidOption(_))
        ));
    }

    #[test]
    fn environment_lighting_is_one_define_and_refuses_what_it_lacks() {
        let b = vmf2();
        let point = source(&b, Stage::Fragment, &ShaderOptions::default()).unwrap();
        assert!(!point.contains("#define NDF_LIGHT_ENV") && !point.contains("void ndf_env_texel("));
        // Both lights: the point-light defines plus NDF_LIGHT_BOTH and the prefiltered route,
        // the environment file included, the SH route's L' sampler not declared.
        let both = ShaderOptions {
            light: ShaderLight::PointAndEnvPrefiltered,
            ..Default::default()
        };
        let src = source(&b, Stage::Fragment, &both).unwrap();
        assert!(src.contains("#define NDF_LIGHT_BOTH 1"));
        assert!(src.contains("#define NDF_LIGHT_ENV_PREFILTERED 1"));
        assert!(!src.contains("#define NDF_LIGHT_ENV 1") && !src.contains("NDF_LIGHT_ENV_SH 1"));
        assert!(
            src.contains("void ndf_env_texel(") && src.contains(&env_block(&ShaderSpec::of(&b)))
        );
        assert!(ShaderLight::PointAndEnvPrefiltered.has_point() && !ShaderLight::EnvSh.has_point());
        for (light, define) in [
            (
                ShaderLight::EnvPrefiltered,
                "#define NDF_LIGHT_ENV_PREFILTERED 1",
            ),
            (ShaderLight::EnvSh, "#define NDF_LIGHT_ENV_SH 1"),
        ] {
            let o = ShaderOptions {
                light,
                ..Default::default()
            };
            let src = source(&b, Stage::Fragment, &o).unwrap();
            assert!(src.contains(define) && src.contains("#define NDF_LIGHT_ENV 1"));
            assert!(src.contains("void ndf_env_texel("));
            // The point-light shader is the same text up to the defines and the env file.
            let stripped = src
                .replace(&env_block(&ShaderSpec::of(&b)), "")
                .lines()
                .filter(|l| !l.starts_with("#define NDF_LIGHT_ENV"))
                .collect::<Vec<_>>()
                .join("\n");
            assert_eq!(stripped, point.lines().collect::<Vec<_>>().join("\n"));
            let toksvig = bake(&map(), Method::Toksvig);
            assert!(
                source(&toksvig, Stage::Fragment, &o)
                    .unwrap()
                    .contains("#define NDF_R_MAX")
            );
            // Olano–North (its moments' diffuse term) and Tan 2005 (a lobe per Gaussian).
            let olano = source(&bake(&map(), Method::Olano), Stage::Fragment, &o).unwrap();
            assert!(olano.contains("#define NDF_METHOD_OLANO 1"));
            assert!(olano.contains("vec3 ndf_env_moments_diffuse("));
            let tan = bake_with(
                &map(),
                Method::Tan2005,
                &BakeOptions {
                    lobes: 2,
                    ..Default::default()
                },
            )
            .unwrap();
            let tan = source(&tan, Stage::Fragment, &o).unwrap();
            assert!(tan.contains("#define NDF_METHOD_TAN2005 1") && tan.contains("ndf_tan_lift("));
            // SH bakes: the SH route only, with the rotation's constant table.
            let sh = bake_with(&map(), Method::Sh, &BakeOptions::default()).unwrap();
            match light {
                ShaderLight::EnvSh => {
                    let src = source(&sh, Stage::Fragment, &o).unwrap();
                    assert!(src.contains("const float NDF_ENV_X90["));
                    assert!(src.contains("ndf_env_sh_texel(t, v,"));
                }
                _ => assert!(matches!(
                    source(&sh, Stage::Fragment, &o),
                    Err(Error::InvalidOption(_))
                )),
            }
            for brdf in [ShaderBrdf::TorranceSparrow, ShaderBrdf::Tabulated] {
                let o = ShaderOptions { brdf, ..o };
                assert!(source(&b, Stage::Fragment, &o).is_err());
            }
        }
    }

    #[test]
    fn unorm_formats_undo_the_bias_of_signed_channels_only() {
        let mut b = bake(&map(), Method::Toksvig);
        b.format = Format::Unorm8;
        let src = source(&b, Stage::Fragment, &ShaderOptions::default()).unwrap();
        assert!(src.contains(
            "t[0] = textureLod(ndf_tex0, uv, lod) * vec4(2.0, 2.0, 2.0, 1.0) \
             + vec4(-1.0, -1.0, -1.0, 0.0);"
        ));
        b.format = Format::F16;
        let src = source(&b, Stage::Fragment, &ShaderOptions::default()).unwrap();
        assert!(src.contains("t[0] = textureLod(ndf_tex0, uv, lod);"));
        // Block-compressed storage (BC6H shades as f16) is biased like unorm.
        let spec = ShaderSpec {
            biased: true,
            ..ShaderSpec::of(&b)
        };
        let src = source_for(&spec, Stage::Fragment, &ShaderOptions::default()).unwrap();
        assert!(src.contains(
            "t[0] = textureLod(ndf_tex0, uv, lod) * vec4(2.0, 2.0, 2.0, 1.0) \
             + vec4(-1.0, -1.0, -1.0, 0.0);"
        ));
    }

    #[test]
    fn no_diffuse_is_one_define_for_every_light_and_the_lod_switch() {
        // K_d = 0: NDF_NO_DIFFUSE defined once (also in the LOD-switching shader), the K_d
        // uniform and term only under its #ifndef/#else, refused with Lambert and for parts
        // that disagree; without it no define.
        let b = vmf2();
        let plain = source(&b, Stage::Fragment, &ShaderOptions::default()).unwrap();
        assert!(!plain.contains("#define NDF_NO_DIFFUSE"));
        for light in [
            ShaderLight::Point,
            ShaderLight::EnvPrefiltered,
            ShaderLight::PointAndEnvPrefiltered,
        ] {
            let o = ShaderOptions {
                light,
                no_diffuse: true,
                ..Default::default()
            };
            let src = source(&b, Stage::Fragment, &o).unwrap();
            assert_eq!(
                src.matches("#define NDF_NO_DIFFUSE 1").count(),
                1,
                "{light:?}"
            );
            assert!(src.contains("#ifndef NDF_NO_DIFFUSE\nuniform vec3 ndf_kd;"));
            assert_eq!(src.matches("uniform vec3 ndf_kd;").count(), 1);
            assert!(src.contains("#ifdef NDF_NO_DIFFUSE\n    // K_d = 0"));
            let lambert = ShaderOptions {
                brdf: ShaderBrdf::Lambert,
                ..o
            };
            assert!(source(&b, Stage::Fragment, &lambert).is_err());
        }
        let spec = ShaderSpec::of(&b);
        let o = ShaderOptions {
            no_diffuse: true,
            ..Default::default()
        };
        let part = |options, first, last| LodPart {
            spec: spec.clone(),
            options,
            first,
            last,
        };
        let src = lod_switch_source(&[part(o, 0, 1), part(o, 2, 3)], (8, 8), Stage::Fragment, &o)
            .unwrap();
        assert_eq!(src.matches("#define NDF_NO_DIFFUSE 1").count(), 1);
        let mixed = [part(o, 0, 1), part(ShaderOptions::default(), 2, 3)];
        let e = lod_switch_source(&mixed, (8, 8), Stage::Fragment, &o).unwrap_err();
        assert!(e.to_string().contains("diffuse term"), "{e}");
    }
}
