//! A plain glTF metallic-roughness GGX shader (`shaders/gltf_ggx.vert`, `shaders/gltf_ggx.frag`)
//! that contains no ndfmap shader code: what an unmodified engine runs, and what draws PBR bakes
//! (`ndfmap::bake::Method::Pbr`: a normal texture and a glTF metallic-roughness texture per MIP
//! level, optionally `KHR_materials_anisotropy`'s texture). [`BakeRenderer`](crate::BakeRenderer)
//! picks it for PBR bakes; `tests/gltf.rs` proves it equal to its CPU twin
//! (`ndfmap::pbr::shade`) texel for texel and renders the regression scenes with it.

use crate::{Error, Result};
use ndfmap::bake::{Bake, Method};
use ndfmap::format::Format;
use ndfmap::glsl::ShaderBrdf;

/// The vertex stage, without its `#version` line.
pub const VERTEX: &str = include_str!("../shaders/gltf_ggx.vert");
/// The fragment stage, without its `#version` line and defines.
pub const FRAGMENT: &str = include_str!("../shaders/gltf_ggx.frag");

/// The vertex and fragment sources for `bake` (a PBR bake, uploaded in `bake.format`): the
/// anisotropy texture when the bake has one, unorm decoding of signed channels for unorm
/// formats, Schlick's Fresnel and Smith's visibility when `brdf` is `Ggx { g: true }`, and the
/// probe variant (full-screen, uniforms instead of mesh inputs) when `probe`. Fails with
/// [`Error::Usage`] for a bake of another method or a BRDF other than GGX.
pub fn sources(bake: &Bake, brdf: ShaderBrdf, probe: bool) -> Result<(String, String)> {
    if bake.method != Method::Pbr {
        return Err(Error::Usage(format!(
            "the glTF shader draws pbr bakes, not {}",
            bake.method
        )));
    }
    let ShaderBrdf::Ggx { g } = brdf else {
        return Err(Error::Usage(format!(
            "a pbr bake is shaded with GGX (its roughness is a GGX alpha), not {brdf:?}"
        )));
    };
    let mut defines = String::from("#version 330 core\n");
    let mut define = |name: &str, on: bool| {
        if on {
            defines += &format!("#define {name}\n");
        }
    };
    define("PBR_PROBE", probe);
    define("PBR_G", g);
    define(
        "PBR_ANISOTROPY",
        bake.textures.iter().any(|t| t.name == "anisotropy"),
    );
    define(
        "PBR_UNORM",
        matches!(bake.format, Format::Unorm8 | Format::Unorm16),
    );
    Ok((format!("{defines}{VERTEX}"), format!("{defines}{FRAGMENT}")))
}
