//! The scene planner's C API (`ndf_plan_*`, module `plan`, `docs/planner.md`): describe a
//! scene ([`ndf_scene`], the same fields as the TOML/JSON scene file, or the file's text
//! itself), plan a loaded map for it, read the plan's file, explanation and specialized shaders,
//! and bake and write what it says.

use super::map::ndf_normal_map;
use super::shader::{
    NDF_BRDF_BLINN_PHONG, NDF_BRDF_GGX, NDF_BRDF_LAMBERT, NDF_BRDF_TORRANCE_SPARROW, ndf_brdf,
};
use super::{
    Out, Outcome, arg, bytes, c_str, fail, guard, guard_value, index, ndf_status, path,
    read_options,
};
use crate::plan::scene::{Budget, Color, LightKind, Material, Model, Scene, Target, View};
use crate::plan::{Plan, execute, plan, write};
use std::ffi::c_char;

/// Light flag: point lights.
pub const NDF_SCENE_LIGHT_POINT: u32 = 1;
/// Light flag: directional lights.
pub const NDF_SCENE_LIGHT_DIRECTIONAL: u32 = 2;
/// Light flag: an environment.
pub const NDF_SCENE_LIGHT_ENVIRONMENT: u32 = 4;

/// Which text `ndf_plan_text` returns: the plan file (JSON, what `ndfmap bake --plan` reads).
pub const NDF_PLAN_TEXT_JSON: u32 = 0;
/// The decisions, one per line (`ndfmap plan --explain`).
pub const NDF_PLAN_TEXT_EXPLAIN: u32 = 1;
/// The specialized GLSL fragment shader of part `part`.
pub const NDF_PLAN_TEXT_SHADER: u32 = 2;
/// `ndf_plan_text`: the plan's one fragment shader switching method by level of detail
/// (every part; samplers `ndf_p{k}_tex{i}`, each a texture whose level 0 is part k's first
/// level; `part` ignored). `NDF_STATUS_INVALID_ARGUMENT` with the reason where it is not built
/// (parts lit differently, more than 32 samplers).
pub const NDF_PLAN_TEXT_LOD_SWITCH_SHADER: u32 = 3;
/// `ndf_plan_text`: what an engine should know before drawing that shader
/// (`Plan::lod_switch_caution`, the `note:` of `ndfmap plan`): one line where the switch has
/// several parts lit by the environment (on an NVIDIA H100/H200 such a switch cost 1.83× its
/// costliest part; the planner avoids it unless a part's target or the texture budget forbids),
/// else the empty string. `part` ignored.
pub const NDF_PLAN_TEXT_LOD_SWITCH_CAUTION: u32 = 4;

/// A scene (the fields of the scene file, `docs/planner.md`). Initialize with
/// `ndf_scene_default()`, then set the fields.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct ndf_scene {
    /// `sizeof(ndf_scene)`.
    pub struct_size: usize,
    /// The material model, an `NDF_BRDF_*` value: `NDF_BRDF_LAMBERT` (no specular term),
    /// `NDF_BRDF_BLINN_PHONG` (the default), `NDF_BRDF_TORRANCE_SPARROW` (eq 18) or
    /// `NDF_BRDF_GGX`; `NDF_BRDF_TABULATED` is refused (a scene plans over parameter ranges).
    pub model: ndf_brdf,
    /// The model parameter's range `[param_min, param_max]` (Blinn-Phong: the exponent s > 0;
    /// Torrance–Sparrow σ, GGX α in (0, 1]); ignored for Lambert. Default 16 to 256.
    pub param_min: f64,
    /// See `param_min`.
    pub param_max: f64,
    /// K_d ≥ 0 (default 1).
    pub kd: f64,
    /// K_s ≥ 0 (default 1; must be 0 for Lambert).
    pub ks: f64,
    /// `NDF_SCENE_LIGHT_*` flags, at least one (default point).
    pub lights: u32,
    /// Elevation of the point/directional lights, degrees in (0, 90]; both 0 for the default
    /// (10 to 90).
    pub elevation_min: f64,
    /// See `elevation_min`.
    pub elevation_max: f64,
    /// Nonzero when the albedo varies (used only when the map has no feature image attached,
    /// whose variation is measured instead).
    pub color_varies: u32,
    /// MIP levels reached, finest and coarsest (used when `distance_near` is 0). Default 0
    /// to 0.
    pub level_min: u32,
    /// See `level_min`.
    pub level_max: u32,
    /// Viewing distances (> 0) with `texel_density` (> 0) instead of levels; 0 for none.
    pub distance_near: f64,
    /// See `distance_near`.
    pub distance_far: f64,
    /// Texels per screen pixel at distance 1.
    pub texel_density: f64,
    /// Nonzero for anisotropic filtering.
    pub anisotropic: u32,
    /// The error target, relative RMS in (0, 1] (default 0.05); ignored when
    /// `target_per_level` is given.
    pub target: f64,
    /// Per-level targets instead of `target` (the scene file's `target.per_level`): one per
    /// level reached, finest first, each in (0, 1]; NULL for none.
    pub target_per_level: *const f64,
    /// The number of values at `target_per_level`.
    pub target_per_level_count: usize,
    /// Path of an albedo image (the scene file's `color.albedo`, NUL-terminated, relative to
    /// the working directory) whose variation decides the colour textures; NULL for none. A
    /// feature image attached to the map (`ndf_normal_map_attach_feature_*`) does the same;
    /// giving both is refused.
    pub albedo_path: *const c_char,
    /// With `NDF_SCENE_LIGHT_ENVIRONMENT`: path of an equirectangular Radiance `.hdr` or
    /// OpenEXR environment (NUL-terminated, relative to the working directory); NULL for the
    /// generated sky with a sun (the scene file's `environment`). Its compact bright sources
    /// (up to 4: a sun, lamps) are extracted as lights when planning; when any are, the plan's
    /// shaders add them (`NDF_ENV_LIGHTS`): draw them with the environment read with
    /// `ndf_env_options.max_lights` 4 (the default) and its `ndf_environment_lights`.
    pub environment_path: *const c_char,
    /// Texture memory budget in bytes, 0 for none.
    pub budget_texture_bytes: u64,
    /// Fetches per pixel budget, 0 for none.
    pub budget_fetches: u32,
}

/// The default scene: Blinn-Phong s 16 to 256, K_d = K_s = 1, a point light, level 0 only,
/// target 5 %.
#[unsafe(no_mangle)]
pub extern "C" fn ndf_scene_default() -> ndf_scene {
    ndf_scene {
        struct_size: size_of::<ndf_scene>(),
        model: NDF_BRDF_BLINN_PHONG,
        param_min: 16.0,
        param_max: 256.0,
        kd: 1.0,
        ks: 1.0,
        lights: NDF_SCENE_LIGHT_POINT,
        elevation_min: 0.0,
        elevation_max: 0.0,
        color_varies: 0,
        level_min: 0,
        level_max: 0,
        distance_near: 0.0,
        distance_far: 0.0,
        texel_density: 0.0,
        anisotropic: 0,
        target: 0.05,
        target_per_level: std::ptr::null(),
        target_per_level_count: 0,
        albedo_path: std::ptr::null(),
        environment_path: std::ptr::null(),
        budget_texture_bytes: 0,
        budget_fetches: 0,
    }
}

/// The Rust scene of a C one (checked by [`Scene::check`]).
///
/// # Safety
/// `s.target_per_level` is NULL or readable for `s.target_per_level_count` values;
/// `s.albedo_path` and `s.environment_path` are NULL or NUL-terminated.
unsafe fn scene_of(s: &ndf_scene) -> Outcome<Scene> {
    let range = Some([s.param_min, s.param_max]);
    let model = match s.model {
        NDF_BRDF_LAMBERT => Model::Lambert,
        NDF_BRDF_BLINN_PHONG => Model::BlinnPhong,
        NDF_BRDF_TORRANCE_SPARROW => Model::TorranceSparrow,
        NDF_BRDF_GGX => Model::Ggx,
        v => {
            return Err(fail(
                ndf_status::InvalidArgument,
                format!(
                    "scene model {v} is not a planner model (expected NDF_BRDF_LAMBERT, \
                     _BLINN_PHONG, _TORRANCE_SPARROW or _GGX)"
                ),
            ));
        }
    };
    let per_level = if s.target_per_level.is_null() {
        None
    } else {
        // SAFETY: non-NULL and readable for `target_per_level_count` values (the contract).
        let v = unsafe { std::slice::from_raw_parts(s.target_per_level, s.target_per_level_count) };
        Some(v.to_vec())
    };
    let text = |p: *const c_char, name: &str| -> Outcome<Option<String>> {
        if p.is_null() {
            return Ok(None);
        }
        // SAFETY: non-NULL and NUL-terminated (the contract).
        let c = unsafe { c_str(p, name) }?;
        let t = c.to_str().map_err(|_| {
            fail(
                ndf_status::InvalidArgument,
                format!("scene: field '{name}' is not UTF-8"),
            )
        })?;
        Ok(Some(t.to_owned()))
    };
    let albedo = text(s.albedo_path, "albedo_path")?;
    let environment = text(s.environment_path, "environment_path")?;
    if s.lights & !7 != 0 {
        return Err(fail(
            ndf_status::InvalidArgument,
            format!("scene lights {:#x} has unknown flags", s.lights),
        ));
    }
    let lights = [
        (NDF_SCENE_LIGHT_POINT, LightKind::Point),
        (NDF_SCENE_LIGHT_DIRECTIONAL, LightKind::Directional),
        (NDF_SCENE_LIGHT_ENVIRONMENT, LightKind::Environment),
    ]
    .into_iter()
    .filter(|(f, _)| s.lights & f != 0)
    .map(|(_, k)| k)
    .collect();
    let distances = s.distance_near != 0.0 || s.distance_far != 0.0;
    let scene = Scene {
        material: Material {
            model,
            exponent: (model == Model::BlinnPhong).then_some(range).flatten(),
            alpha: (model == Model::Ggx).then_some(range).flatten(),
            sigma: (model == Model::TorranceSparrow).then_some(range).flatten(),
            kd: s.kd,
            ks: Some(s.ks),
        },
        lights,
        light_elevation: (s.elevation_min != 0.0 || s.elevation_max != 0.0)
            .then_some([s.elevation_min, s.elevation_max]),
        environment,
        color: Color {
            varies: s.color_varies != 0,
            albedo,
        },
        view: View {
            levels: (!distances).then_some([s.level_min, s.level_max]),
            distances: distances.then_some([s.distance_near, s.distance_far]),
            texel_density: distances.then_some(s.texel_density),
            anisotropic: s.anisotropic != 0,
        },
        target: Target {
            error: per_level.is_none().then_some(s.target),
            per_level,
        },
        budget: (s.budget_texture_bytes != 0 || s.budget_fetches != 0).then_some(Budget {
            texture_bytes: (s.budget_texture_bytes != 0).then_some(s.budget_texture_bytes),
            fetches: (s.budget_fetches != 0).then_some(s.budget_fetches),
        }),
    };
    scene.check()?;
    Ok(scene)
}

/// A plan (opaque): made by `ndf_plan_new` or `ndf_plan_new_from_text`, released by
/// `ndf_plan_free`.
pub struct ndf_plan {
    plan: Plan,
    addressing: crate::ingest::Addressing,
}

/// Plans `map` for `scene`, with the scene's albedo image (a path relative to the working
/// directory) attached as the map's feature image when it names one.
fn finish(map: &ndf_normal_map, scene: &Scene, out: Out<*mut ndf_plan>) -> Outcome {
    let p = match &scene.color.albedo {
        None => plan(&map.map, scene, map.input.path.as_deref())?,
        Some(albedo) => {
            if map.map.feature().is_some() {
                return Err(fail(
                    ndf_status::InvalidArgument,
                    "scene: field 'color.albedo': given, and the map has a feature image \
                     attached too: give one",
                ));
            }
            let with = map
                .map
                .clone()
                .with_feature_file(std::path::Path::new(albedo), &map.input.options)?;
            plan(&with, scene, map.input.path.as_deref())?
        }
    };
    let boxed = Box::new(ndf_plan {
        plan: p,
        addressing: map.map.addressing(),
    });
    // SAFETY: `out` was checked non-NULL; the caller's contract makes it writable.
    unsafe { out.write(Box::into_raw(boxed)) };
    Ok(())
}

/// Plans `map` for `scene` (module `plan`): measures the map by sampling and chooses per level
/// range the cheapest configuration meeting the target.
/// - `NDF_STATUS_INVALID_ARGUMENT` for a scene with a field out of range or contradictory (the
///   message names the field), levels beyond the map, or a budget the plan exceeds.
///
/// # Safety
/// `map` is NULL or live; `scene` is NULL or initialized by `ndf_scene_default()`, its
/// `target_per_level` NULL or readable for `target_per_level_count` values and its
/// `albedo_path` and `environment_path` NULL or NUL-terminated; `plan_out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_plan_new(
    map: *const ndf_normal_map,
    scene: *const ndf_scene,
    plan_out: *mut *mut ndf_plan,
) -> ndf_status {
    guard("ndf_plan_new", || {
        // SAFETY (both blocks): the pointers are NULL or valid, as this function requires.
        let m = unsafe { arg(map, "map") }?;
        let s = unsafe { read_options(scene, "scene", "ndf_scene_default") }?;
        let out = Out::new(plan_out, "plan_out")?;
        // SAFETY: the scene's pointers are NULL or valid, as this function requires.
        let scene = unsafe { scene_of(s) }?;
        finish(m, &scene, out)
    })
}

/// Plans `map` for the scene file text `text` (`length` bytes, TOML or JSON, no NUL needed;
/// `docs/planner.md`). Failures as for `ndf_plan_new`, and `NDF_STATUS_INVALID_ARGUMENT` for
/// empty text, syntax errors, unknown keys and wrong types.
///
/// # Safety
/// `map` is NULL or live; `text` is NULL or readable for `length` bytes; `plan_out` is NULL or
/// writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_plan_new_from_text(
    map: *const ndf_normal_map,
    text: *const c_char,
    length: usize,
    plan_out: *mut *mut ndf_plan,
) -> ndf_status {
    guard("ndf_plan_new_from_text", || {
        // SAFETY (both blocks): the pointers are NULL or valid, as this function requires.
        let m = unsafe { arg(map, "map") }?;
        let t = unsafe { bytes(text.cast(), length, "text") }?;
        let out = Out::new(plan_out, "plan_out")?;
        let t = std::str::from_utf8(t)
            .map_err(|_| fail(ndf_status::InvalidArgument, "scene text is not UTF-8"))?;
        finish(m, &Scene::parse("scene text", t)?, out)
    })
}

/// The number of level ranges (parts) of `plan`, each with its own method and shader.
///
/// # Safety
/// `plan` is NULL or live; `count_out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_plan_part_count(
    plan: *const ndf_plan,
    count_out: *mut u32,
) -> ndf_status {
    guard("ndf_plan_part_count", || {
        // SAFETY: the pointers are NULL or valid, as this function requires.
        let p = unsafe { arg(plan, "plan") }?;
        let out = Out::new(count_out, "count_out")?;
        // SAFETY: checked non-NULL, writable by contract.
        unsafe { out.write(p.plan.parts.len() as u32) };
        Ok(())
    })
}

fn text_of(p: &ndf_plan, what: u32, part: u32) -> Outcome<Vec<u8>> {
    let mut s = match what {
        NDF_PLAN_TEXT_JSON => p.plan.to_json(),
        NDF_PLAN_TEXT_EXPLAIN => p.plan.explain(),
        NDF_PLAN_TEXT_SHADER => {
            let i = index("part", part, p.plan.parts.len())?;
            p.plan.shader(i, p.addressing)?
        }
        NDF_PLAN_TEXT_LOD_SWITCH_SHADER => p.plan.lod_switch_shader(p.addressing)?,
        NDF_PLAN_TEXT_LOD_SWITCH_CAUTION => {
            p.plan.lod_switch_caution(p.addressing).unwrap_or_default()
        }
        v => {
            return Err(fail(
                ndf_status::InvalidArgument,
                format!("unknown plan text {v} (expected NDF_PLAN_TEXT_*)"),
            ));
        }
    }
    .into_bytes();
    s.push(0);
    Ok(s)
}

/// Bytes `ndf_plan_text` writes for the same arguments (the NUL included).
/// - `what`: `NDF_PLAN_TEXT_*`; `part`: the part for `NDF_PLAN_TEXT_SHADER` (else ignored).
///
/// # Safety
/// `plan` is NULL or live; `size_out` is NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_plan_text_size(
    plan: *const ndf_plan,
    what: u32,
    part: u32,
    size_out: *mut usize,
) -> ndf_status {
    guard("ndf_plan_text_size", || {
        // SAFETY: the pointers are NULL or valid, as this function requires.
        let p = unsafe { arg(plan, "plan") }?;
        let out = Out::new(size_out, "size_out")?;
        let t = text_of(p, what, part)?;
        // SAFETY: checked non-NULL, writable by contract.
        unsafe { out.write(t.len()) };
        Ok(())
    })
}

/// Writes a text of `plan` into `buffer`, NUL-terminated: the plan file, the explanation, or
/// a part's specialized fragment shader. `buffer` must hold `ndf_plan_text_size()` bytes
/// (`NDF_STATUS_BUFFER_TOO_SMALL` otherwise, nothing written); `length_out` receives the bytes
/// written.
///
/// # Safety
/// `plan` is NULL or live; `buffer` is NULL or writable for `capacity` bytes; `length_out` is
/// NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_plan_text(
    plan: *const ndf_plan,
    what: u32,
    part: u32,
    buffer: *mut c_char,
    capacity: usize,
    length_out: *mut usize,
) -> ndf_status {
    guard("ndf_plan_text", || {
        // SAFETY: the pointers are NULL or valid, as this function requires.
        let p = unsafe { arg(plan, "plan") }?;
        if buffer.is_null() {
            return Err(super::null("buffer"));
        }
        let out = Out::new(length_out, "length_out")?;
        let t = text_of(p, what, part)?;
        if capacity < t.len() {
            return Err(fail(
                ndf_status::BufferTooSmall,
                format!(
                    "buffer of {capacity} bytes is too small: the text needs {} with its NUL \
                     (ndf_plan_text_size)",
                    t.len()
                ),
            ));
        }
        // SAFETY: `buffer` is writable for `capacity` ≥ `t.len()` bytes (the caller's contract)
        // and cannot overlap the freshly allocated `t`.
        unsafe {
            std::ptr::copy_nonoverlapping(t.as_ptr(), buffer.cast::<u8>(), t.len());
            out.write(t.len());
        }
        Ok(())
    })
}

/// Bakes `plan` for `map` and writes it as folder `directory` with its manifest
/// (`ndfmap bake --plan`): `NDF_STATUS_INVALID_ARGUMENT` when the plan was made for another
/// map (size or content hash), before any work; nothing is written on failure.
///
/// # Safety
/// `plan` and `map` are NULL or live; `directory` is NULL or a NUL-terminated string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_plan_bake_write(
    plan: *const ndf_plan,
    map: *const ndf_normal_map,
    directory: *const c_char,
) -> ndf_status {
    guard("ndf_plan_bake_write", || {
        // SAFETY (all blocks): the pointers are NULL or valid, as this function requires.
        let p = unsafe { arg(plan, "plan") }?;
        let m = unsafe { arg(map, "map") }?;
        let dir = path(unsafe { c_str(directory, "directory") }?, "directory")?;
        let baked = execute(&p.plan, &m.map)?;
        write(&p.plan, &baked, m.input.clone(), &dir)?;
        Ok(())
    })
}

/// Releases a plan. NULL is fine. Must not be called twice with the same plan.
///
/// # Safety
/// `plan` is NULL or a plan from this library not yet freed.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ndf_plan_free(plan: *mut ndf_plan) {
    guard_value((), || {
        if !plan.is_null() {
            // SAFETY: a live plan was made by Box::into_raw in `finish` and is freed once.
            drop(unsafe { Box::from_raw(plan) });
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ffi::map::ndf_normal_map;

    fn map() -> ndf_normal_map {
        ndf_normal_map::from_map_for_tests(crate::procedural::generate(32, 5).map)
    }

    #[test]
    fn plan_through_the_c_api() {
        let m = map();
        let mut scene = ndf_scene_default();
        scene.model = NDF_BRDF_LAMBERT;
        scene.ks = 0.0;
        scene.lights = NDF_SCENE_LIGHT_ENVIRONMENT;
        scene.level_min = 1;
        scene.level_max = 5;
        let mut plan: *mut ndf_plan = std::ptr::null_mut();
        // SAFETY (all blocks): the pointers are live locals.
        let st = unsafe { ndf_plan_new(&m, &scene, &mut plan) };
        assert_eq!(st, ndf_status::Ok);
        let mut parts = 0u32;
        assert_eq!(
            unsafe { ndf_plan_part_count(plan, &mut parts) },
            ndf_status::Ok
        );
        assert!(parts >= 1);
        for what in [
            NDF_PLAN_TEXT_JSON,
            NDF_PLAN_TEXT_EXPLAIN,
            NDF_PLAN_TEXT_SHADER,
            NDF_PLAN_TEXT_LOD_SWITCH_SHADER,
            NDF_PLAN_TEXT_LOD_SWITCH_CAUTION,
        ] {
            let mut size = 0usize;
            assert_eq!(
                unsafe { ndf_plan_text_size(plan, what, 0, &mut size) },
                ndf_status::Ok
            );
            let mut buf = vec![0 as c_char; size];
            let mut len = 0usize;
            // Too small: nothing written.
            assert_eq!(
                unsafe { ndf_plan_text(plan, what, 0, buf.as_mut_ptr(), size - 1, &mut len) },
                ndf_status::BufferTooSmall
            );
            assert_eq!(len, 0);
            assert_eq!(
                unsafe { ndf_plan_text(plan, what, 0, buf.as_mut_ptr(), size, &mut len) },
                ndf_status::Ok
            );
            assert_eq!(len, size);
            assert_eq!(buf[size - 1], 0);
        }
        // The caution: one line exactly where the switch has several parts (lit by the
        // environment here), else empty.
        let p = unsafe { &*plan };
        let Ok(caution) = text_of(p, NDF_PLAN_TEXT_LOD_SWITCH_CAUTION, 0) else {
            panic!("the caution text failed");
        };
        let switch_parts = p.plan.lod_switch_parts(p.addressing).len();
        assert_eq!(
            caution.len() == 1,
            switch_parts < 2,
            "{switch_parts} switch parts"
        );
        assert!(!caution[..caution.len() - 1].contains(&b'\n'));
        let mut size = 0usize;
        assert_eq!(
            unsafe { ndf_plan_text_size(plan, NDF_PLAN_TEXT_SHADER, parts, &mut size) },
            ndf_status::OutOfRange
        );
        // The same scene as text plans the same.
        let text = "lights = [\"environment\"]\n[material]\nmodel = \"lambert\"\nks = 0\n\
                    [view]\nlevels = [1, 5]\n[target]\nerror = 0.05\n";
        let mut plan2: *mut ndf_plan = std::ptr::null_mut();
        let st =
            unsafe { ndf_plan_new_from_text(&m, text.as_ptr().cast(), text.len(), &mut plan2) };
        assert_eq!(st, ndf_status::Ok);
        let (a, b) = unsafe { (&(*plan).plan, &(*plan2).plan) };
        assert_eq!(a.parts, b.parts);
        assert_eq!(a.scene, b.scene);
        unsafe {
            ndf_plan_free(plan);
            ndf_plan_free(plan2);
            ndf_plan_free(std::ptr::null_mut());
        }
    }

    #[test]
    fn per_level_targets_and_an_albedo_through_the_struct_and_the_text_agree() {
        let sample = crate::procedural::generate(32, 5);
        let dir = tempfile::tempdir().unwrap();
        let albedo = dir.path().join("albedo.png");
        image::RgbImage::from_raw(32, 32, crate::procedural::encode_srgb8(&sample.albedo))
            .unwrap()
            .save(&albedo)
            .unwrap();
        let m = ndf_normal_map::from_map_for_tests(sample.map);
        let targets = [0.05, 0.08, 0.1];
        let c_albedo = std::ffi::CString::new(albedo.to_str().unwrap()).unwrap();
        let mut scene = ndf_scene_default();
        scene.level_min = 1;
        scene.level_max = 3;
        scene.target_per_level = targets.as_ptr();
        scene.target_per_level_count = targets.len();
        scene.albedo_path = c_albedo.as_ptr();
        let mut plan: *mut ndf_plan = std::ptr::null_mut();
        // SAFETY (all blocks): the pointers are live locals.
        let st = unsafe { ndf_plan_new(&m, &scene, &mut plan) };
        assert_eq!(st, ndf_status::Ok);
        let text = format!(
            "lights = [\"point\"]\n[material]\nmodel = \"blinn-phong\"\nexponent = [16, 256]\nks = 1\n\
             [color]\nalbedo = {:?}\n[view]\nlevels = [1, 3]\n[target]\nper_level = [0.05, 0.08, 0.1]\n",
            albedo.to_str().unwrap()
        );
        let mut plan2: *mut ndf_plan = std::ptr::null_mut();
        let st =
            unsafe { ndf_plan_new_from_text(&m, text.as_ptr().cast(), text.len(), &mut plan2) };
        assert_eq!(st, ndf_status::Ok);
        let (a, b) = unsafe { (&(*plan).plan, &(*plan2).plan) };
        assert_eq!(a.scene.target.per_level.as_deref(), Some(&targets[..]));
        assert_eq!(a.scene, b.scene);
        assert_eq!(a.parts, b.parts);
        // The albedo was measured: its variation is in the colour decision.
        assert!(a.explain().contains("albedo varies by"), "{}", a.explain());
        // An albedo that cannot be read fails, and no plan is made.
        let missing = c"/nonexistent/albedo.png";
        scene.albedo_path = missing.as_ptr();
        let mut plan3: *mut ndf_plan = std::ptr::null_mut();
        let st = unsafe { ndf_plan_new(&m, &scene, &mut plan3) };
        assert_ne!(st, ndf_status::Ok);
        assert!(plan3.is_null());
        unsafe {
            ndf_plan_free(plan);
            ndf_plan_free(plan2);
        }
    }

    #[test]
    fn bad_scenes_through_the_c_api() {
        let m = map();
        type Edit = fn(&mut ndf_scene);
        let bad: [(&str, Edit); 9] = [
            ("target", |s| s.target = f64::NAN),
            ("material.exponent", |s| s.param_min = -1.0),
            ("lights", |s| s.lights = 0),
            ("lights", |s| s.lights = 8),
            ("view.levels", |s| s.level_max = 9),
            ("model", |s| s.model = 7),
            ("model", |s| {
                s.model = crate::ffi::shader::NDF_BRDF_TABULATED
            }),
            ("target.per_level", |s| {
                static BAD: [f64; 2] = [0.05, -1.0];
                s.level_max = 1;
                s.target_per_level = BAD.as_ptr();
                s.target_per_level_count = 2;
            }),
            ("target.per_level", |s| {
                static SHORT: [f64; 1] = [0.05];
                s.level_max = 2;
                s.target_per_level = SHORT.as_ptr();
                s.target_per_level_count = 1;
            }),
        ];
        for (needle, f) in bad {
            let mut scene = ndf_scene_default();
            f(&mut scene);
            let mut plan: *mut ndf_plan = std::ptr::null_mut();
            // SAFETY: the pointers are live locals.
            let st = unsafe { ndf_plan_new(&m, &scene, &mut plan) };
            assert_eq!(st, ndf_status::InvalidArgument, "{needle}");
            assert!(plan.is_null(), "written only on success");
            // SAFETY: the message is a NUL-terminated thread-local string.
            let msg = unsafe { std::ffi::CStr::from_ptr(crate::ffi::ndf_last_error_message()) }
                .to_string_lossy()
                .into_owned();
            assert!(msg.contains(needle), "{needle}: {msg}");
        }
        let text = "";
        let mut plan: *mut ndf_plan = std::ptr::null_mut();
        // SAFETY: the pointers are live locals.
        let st = unsafe { ndf_plan_new_from_text(&m, text.as_ptr().cast(), 0, &mut plan) };
        assert_eq!(st, ndf_status::InvalidArgument);
        let st = unsafe { ndf_plan_new(&m, std::ptr::null(), &mut plan) };
        assert_eq!(st, ndf_status::NullArgument);
    }
}
