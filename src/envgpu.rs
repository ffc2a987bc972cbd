//! Environment lighting on the GPU (issue 16, item 5): the data the environment shaders read,
//! packed for upload. The shaders are `glsl/ndf_env.glsl`, selected by the `#define`
//! `NDF_LIGHT_ENV_PREFILTERED` or `NDF_LIGHT_ENV_SH` ([`crate::glsl::ShaderLight`]); their CPU
//! twin is [`crate::envlight::shade`].
//!
//! **Layout: an equirectangular `RGB32F` atlas, not a cube map and not a GL MIP chain.** The
//! prefiltered levels ([`crate::environment::prefilter`]) are equirectangular, each on a grid
//! that resolves its own lobe (spacing ≤ ½σ), two levels per grid size with κ halving per
//! level, so they are not a GL MIP chain (whose levels must halve) and resampling them to a
//! cube map would change every value. The atlas packs the levels as they are on shelves:
//! level 0 (the environment) at the top, then each level at the right of the previous one
//! when the shelf has room, else at the start of a new shelf ([`Upload::levels`]: width,
//! height, first row, first column). Below [`crate::environment::prefilter::GRID_CAP`] that is
//! level 0, level 1 and level 2 on shelves of their own, then the pairs (3, 4), (5, 6), … side
//! by side: the atlas is `W × < 4H`, under 4 times the environment's texels. The shader reads
//! it with `texelFetch` and does the bilinear lookup (wrapping in φ within the level's own
//! rectangle, clamped at the poles: no gutters are needed) and the blend between the two
//! levels [`crate::environment::prefilter::Prefiltered::blend`] picks (linear in κ,
//! `κ_k = κ_1/2^{k−1}` for k ≥ 1, the nominal `κ_0` for level 0) itself, in the same order as
//! [`crate::environment::prefilter::Prefiltered::lookup`]: that is what makes GL = CPU exact to
//! f32 rounding. Hardware filtering would not be: GPUs (llvmpipe included) filter with
//! fixed-point weights (8 bits on many), a relative error of 1/256 of the difference between
//! neighbouring texels, which next to a sun of radiance 10⁶ is far above the route's own
//! error. The atlas's height is checked against the GL runtime's `GL_MAX_TEXTURE_SIZE` at
//! upload (a 16384-wide panorama: 16384 × 10240, as level 1's grid is capped at 4096).
//!
//! **RGB, `RGB32F` rather than `RGBA16F`**: every radiance-dependent array (atlas, `L′`,
//! `L_lm`) holds the three channels interleaved. Half floats would halve the bytes (8 instead
//! of 12 per texel with the padding channel) but stop at 65504 — below the radiance of a real
//! sun in an HDR panorama (10⁵–10⁹) — and keep 11 significant bits, which would turn GL = CPU
//! agreement next to a sun from 10⁻⁷ into 10⁻³ of the value. A 1024 × 512 panorama's atlas is
//! 1024 × 1920 × 12 B ≈ 24 MB (it was 1024 × 528 when every level's lobe was narrower than its
//! texels), the `L′` table 81 × 256 × 12 B ≈ 0.25 MB. The lobe-energy tables
//! do not depend on the radiance: one `R32F` table per BRDF family serves all three channels.
//!
//! The `L′` table ([`crate::environment::projection::ReflectedTable`]) is an `RGB32F` texture of
//! `count(8) = 81` columns (the coefficients) × `16² = 256` rows (row `iθ·16 + iφ`, the views of
//! [`crate::environment::projection::view_of`]); the lobe-energy table of the BRDF
//! ([`EnvLight::energy_table`]) an `RGBA32F` texture of [`ENERGY_SHARES`] · [`ENERGY_COS`]
//! columns (GGX's NDF shares, share after share; Blinn-Phong's one share repeated) × 3 ·
//! [`ENERGY_PARAM`] rows, its [`ENERGY_BLOCKS`] blocks (energy, blend, `log2 κ_c`, tail share,
//! `log2 κ_t`, core blend, energy, blend and `log2 κ` shift with the cosine at the half vector)
//! four to a texel ([`energy`]). Both are read with `texelFetch` and interpolated in the shader
//! like the CPU does.
//!
//! Uniforms ([`uniforms`]): `vec3 ndf_env_sh[81]` (`L_lm`, environment frame, RGB), `ndf_env_kappa0`,
//! `ndf_env_kappa1`, `ndf_env_level_count`, `vec4 ndf_env_level[24]` (width, height, first
//! row, first column per level),
//! and for the SH route `ndf_env_rho[9]` (the BRDF's `ρ̂_l`, l ≤ 8). Samplers: `ndf_env_atlas`,
//! `ndf_env_energy` (prefiltered route), `ndf_env_reflected` (SH route). Mesh mode adds
//! `mat3 ndf_env_rotation` (world → environment frame), set by the application.
//!
//! **Extracted lights** ([`EnvLight::with_lights`]): the shaders add their term when generated
//! with [`crate::glsl::ShaderOptions::env_lights`] (`NDF_ENV_LIGHTS`); [`Upload::lights`]
//! carries them (at most [`crate::glsl::MAX_ENV_LIGHTS`]) and [`uniforms`] emits
//! `vec3 ndf_env_light_dir[]` (environment frame, unit), `vec3 ndf_env_light_power[]` (RGB),
//! `float ndf_env_light_kappa[]` (0 encodes κ = ∞, a point light),
//! `float ndf_env_light_diffuse_only[]` (0 or 1) and `float ndf_env_light_count`.

use crate::brdf::Brdf;
use crate::environment::projection::REFLECTED_GRID;
use crate::envlight::{
    ENERGY_BLOCKS, ENERGY_COS, ENERGY_PARAM, ENERGY_SHARES, ENV_LMAX, EnvLight, Route,
};
use crate::error::{Error, Result};
use crate::harmonics::count;

/// The most prefiltered levels a shader reads (`vec4 ndf_env_level[MAX_LEVELS]`): enough for
/// any panorama (level 1's grid is at most 4096 wide: 20 levels).
pub const MAX_LEVELS: usize = 24;

/// Columns of the `L′` texture: `count(ENV_LMAX)` = 81 coefficients.
pub const REFLECTED_COLUMNS: usize = (ENV_LMAX + 1) * (ENV_LMAX + 1);

/// Rows of the `L′` texture: one per grid view, `REFLECTED_GRID²` = 256.
pub const REFLECTED_ROWS: usize = REFLECTED_GRID * REFLECTED_GRID;

/// Colour channels of the atlas, the `L′` table and `ndf_env_sh` (R, G, B interleaved).
pub const CHANNELS: usize = 3;

/// An environment packed for upload (module docs), RGB: every radiance-dependent array holds
/// [`CHANNELS`] interleaved values (R, G, B) per texel or coefficient.
#[derive(Debug, Clone, PartialEq)]
pub struct Upload {
    /// Atlas width in texels (level 0's width).
    pub atlas_width: u32,
    /// Atlas height in texels (the shelves' heights summed).
    pub atlas_height: u32,
    /// The atlas, RGB per texel, row-major from the top row; texels outside every level are
    /// 0.
    pub atlas: Vec<f32>,
    /// Per level: width, height, first atlas row, first atlas column.
    pub levels: Vec<[u32; 4]>,
    /// `κ_0 = W·H/π`, level 0's nominal concentration (a lobe at least this sharp reads level
    /// 0 alone).
    pub kappa0: f64,
    /// `κ_1`, level 1's concentration; level k ≥ 1 has `κ_1/2^{k−1}`.
    pub kappa1: f64,
    /// `L_lm`, l ≤ 8, environment frame, (l, m) order, RGB per coefficient (81 × 3).
    pub sh: Vec<f32>,
    /// The `L′` table: [`REFLECTED_ROWS`] rows of [`REFLECTED_COLUMNS`] RGB values.
    pub reflected: Vec<f32>,
    /// The extracted lights ([`EnvLight::lights`], most powerful first; empty for
    /// [`EnvLight::new`]): the tables above are of the residual, and a shader generated with
    /// [`crate::glsl::ShaderOptions::env_lights`] adds these (module docs).
    pub lights: Vec<crate::environment::lights::Light>,
}

/// Packs `light` for upload (module docs). Fails when it has more than [`MAX_LEVELS`]
/// levels (a panorama wider than [`crate::environment::MAX_WIDTH`] would), and when it has more
/// extracted lights ([`EnvLight::with_lights`]) than a shader adds
/// ([`crate::glsl::MAX_ENV_LIGHTS`]; a typed error rather than lights silently dropped). A
/// light with extracted lights must be shaded by a shader generated with
/// [`crate::glsl::ShaderOptions::env_lights`]: the tables hold the residual alone.
pub fn pack(light: &EnvLight) -> Result<Upload> {
    let max = crate::glsl::MAX_ENV_LIGHTS;
    if light.lights().len() > max {
        return Err(Error::InvalidOption(format!(
            "the environment has {} extracted lights, the shaders add at most {max} \
             (extract fewer: --env-lights / LightOptions)",
            light.lights().len()
        )));
    }
    let first = light.channel(0).prefiltered();
    let levels = first.levels();
    if levels.len() > MAX_LEVELS {
        return Err(Error::InvalidOption(format!(
            "the environment has {} prefiltered levels, the shaders read at most {MAX_LEVELS}",
            levels.len()
        )));
    }
    let width = levels[0].radiance.width();
    let table = shelves(
        &levels
            .iter()
            .map(|l| (l.radiance.width(), l.radiance.height()))
            .collect::<Vec<_>>(),
    );
    let height = table.iter().map(|l| l[1] + l[2]).max().unwrap_or(0);
    let mut atlas = vec![0.0f32; CHANNELS * width as usize * height as usize];
    for (k, &[w, h, row, col]) in table.iter().enumerate() {
        let (w, h) = (w as usize, h as usize);
        for (c, ch) in light.channels().iter().enumerate() {
            let values = ch.prefiltered().levels()[k].radiance.values();
            for y in 0..h {
                let dst = (row as usize + y) * width as usize + col as usize;
                for (x, v) in values[y * w..][..w].iter().enumerate() {
                    atlas[CHANNELS * (dst + x) + c] = *v;
                }
            }
        }
    }
    let interleave = |per: Vec<Vec<f32>>| -> Vec<f32> {
        (0..per[0].len())
            .flat_map(|i| per.iter().map(move |p| p[i]))
            .collect()
    };
    let channels = light.channels();
    let reflected = interleave(
        channels
            .iter()
            .map(|c| c.reflected().map(|t| t.packed()))
            .collect::<Result<_>>()?,
    );
    debug_assert_eq!(
        reflected.len(),
        CHANNELS * REFLECTED_COLUMNS * REFLECTED_ROWS
    );
    let sh = interleave(
        channels
            .iter()
            .map(|c| {
                c.sh()[..count(ENV_LMAX)]
                    .iter()
                    .map(|&v| v as f32)
                    .collect()
            })
            .collect(),
    );
    Ok(Upload {
        atlas_width: width,
        atlas_height: height,
        atlas,
        levels: table,
        kappa0: first.kappa0(),
        kappa1: first.kappa1(),
        sh,
        reflected,
        lights: light.lights().to_vec(),
    })
}

/// Shelf packing of rectangles `(width, height)` in order into an atlas as wide as the first:
/// each at the right of the previous one when its shelf has room, else at the start of a new
/// shelf below. Per rectangle: width, height, first row, first column.
fn shelves(sizes: &[(u32, u32)]) -> Vec<[u32; 4]> {
    let width = sizes.first().map_or(0, |s| s.0);
    let (mut row, mut col, mut shelf) = (0u32, 0u32, 0u32);
    let mut out = Vec::with_capacity(sizes.len());
    for &(w, h) in sizes {
        if col > 0 && col + w > width {
            row += shelf;
            col = 0;
            shelf = 0;
        }
        out.push([w, h, row, col]);
        col += w;
        shelf = shelf.max(h);
    }
    out
}

/// The lobe table of `brdf` as f32 for upload: an `RGBA32F` texture of [`ENERGY_SIZE`]
/// texels, row-major, four blocks per texel. Column `j·ENERGY_COS + c` is share j (GGX's
/// shares of the NDF; Blinn-Phong's single share repeated, so both families upload the same
/// size) at view cosine c. Row `g·ENERGY_PARAM + p` is parameter p of blocks `4g … 4g + 3`:
/// energy, blend, `log2 κ_c`, tail share (g = 0); `log2 κ_t`, core blend, energy and blend
/// with the cosine at the half vector (g = 1); the `log2 κ` shift and three zeros (g = 2).
/// One `texelFetch` reads the four blocks the shader interpolates together (GLSL
/// `ndf_env_energy_at`). `None` for a BRDF without a specular lobe.
pub fn energy(light: &EnvLight, brdf: &Brdf) -> Option<Vec<f32>> {
    let table = light.energy_table(brdf)?;
    let shares = table.len() / (ENERGY_BLOCKS * ENERGY_PARAM * ENERGY_COS);
    let at = |b: usize, p: usize, j: usize, c: usize| {
        if b < ENERGY_BLOCKS {
            table[((b * ENERGY_PARAM + p) * shares + j % shares) * ENERGY_COS + c] as f32
        } else {
            0.0
        }
    };
    let mut out = Vec::with_capacity(ENERGY_SIZE.0 * ENERGY_SIZE.1 * ENERGY_CHANNELS);
    for g in 0..ENERGY_GROUPS {
        for p in 0..ENERGY_PARAM {
            for j in 0..ENERGY_SHARES {
                for c in 0..ENERGY_COS {
                    out.extend((0..ENERGY_CHANNELS).map(|k| at(g * ENERGY_CHANNELS + k, p, j, c)));
                }
            }
        }
    }
    Some(out)
}

/// Floats per texel of [`energy`]'s texture (`RGBA32F`: four blocks).
pub const ENERGY_CHANNELS: usize = 4;

/// Row groups of [`energy`]'s texture: the blocks, four to a texel.
const ENERGY_GROUPS: usize = ENERGY_BLOCKS.div_ceil(ENERGY_CHANNELS);

/// The size (columns, rows) of [`energy`]'s texture, in texels of [`ENERGY_CHANNELS`] floats.
pub const ENERGY_SIZE: (usize, usize) = (ENERGY_SHARES * ENERGY_COS, ENERGY_GROUPS * ENERGY_PARAM);

/// One environment uniform: its name, components per element (1: `float`, 3: `vec3`, 4:
/// `vec4`) and values (arrays as several elements).
#[derive(Debug, Clone, PartialEq)]
pub struct EnvUniform {
    /// The GLSL name.
    pub name: &'static str,
    /// Components per element: 1 (`float`, `float[]`), 3 (`vec3[]`) or 4 (`vec4[]`).
    pub components: usize,
    /// The values, `components` per element.
    pub values: Vec<f32>,
}

/// The environment uniforms of a shader lit by `route` with `brdf` (module docs): `ndf_env_sh`
/// as `vec3[81]` (RGB), `ndf_env_level` as `vec4[MAX_LEVELS]`, the rest as floats.
pub fn uniforms(upload: &Upload, brdf: &Brdf, route: Route) -> Vec<EnvUniform> {
    let mut level = vec![0.0f32; 4 * MAX_LEVELS];
    for (i, l) in upload.levels.iter().enumerate() {
        for k in 0..4 {
            level[4 * i + k] = l[k] as f32;
        }
    }
    let u = |name, components, values| EnvUniform {
        name,
        components,
        values,
    };
    let mut out = vec![
        u("ndf_env_sh", CHANNELS, upload.sh.clone()),
        u("ndf_env_kappa0", 1, vec![upload.kappa0 as f32]),
        u("ndf_env_kappa1", 1, vec![upload.kappa1 as f32]),
        u("ndf_env_level_count", 1, vec![upload.levels.len() as f32]),
        u("ndf_env_level", 4, level),
    ];
    if route == Route::Sh && brdf.has_specular() {
        let rho = brdf.sh_coefficients(ENV_LMAX);
        out.push(u("ndf_env_rho", 1, rho.iter().map(|&v| v as f32).collect()));
    }
    if !upload.lights.is_empty() {
        let ls = &upload.lights;
        out.push(u(
            "ndf_env_light_dir",
            3,
            ls.iter()
                .flat_map(|l| l.direction.to_array().map(|v| v as f32))
                .collect(),
        ));
        out.push(u(
            "ndf_env_light_power",
            3,
            ls.iter().flat_map(|l| l.power.map(|v| v as f32)).collect(),
        ));
        out.push(u(
            "ndf_env_light_kappa",
            1,
            ls.iter().map(|l| kappa_uniform(l.kappa)).collect(),
        ));
        out.push(u(
            "ndf_env_light_diffuse_only",
            1,
            ls.iter()
                .map(|l| if l.diffuse_only { 1.0 } else { 0.0 })
                .collect(),
        ));
    }
    // Always set (0 without lights), so a shader with the loop never reads stale lights.
    out.push(u(
        "ndf_env_light_count",
        1,
        vec![upload.lights.len() as f32],
    ));
    out
}

/// Floats per light of [`lights_packed`].
pub const LIGHT_FLOATS: usize = 8;

/// `upload`'s lights as the uniforms hold them, [`LIGHT_FLOATS`] per light: direction x, y, z
/// (environment frame, unit), RGB power, κ (0 for κ = ∞) and the diffuse-only flag (0 or 1)
/// (the C API's `ndf_environment_lights`).
pub fn lights_packed(upload: &Upload) -> Vec<f32> {
    upload
        .lights
        .iter()
        .flat_map(|l| {
            let d = l.direction.to_array().map(|v| v as f32);
            let p = l.power.map(|v| v as f32);
            let flag = if l.diffuse_only { 1.0 } else { 0.0 };
            [
                d[0],
                d[1],
                d[2],
                p[0],
                p[1],
                p[2],
                kappa_uniform(l.kappa),
                flag,
            ]
        })
        .collect()
}

/// A light's concentration as `ndf_env_light_kappa` holds it: 0 for κ = ∞ (a point light, the
/// CPU's `!kappa.is_finite()`), else κ in f32 (a κ beyond f32's range becomes +∞, which the
/// shader's `A(κ)`, `1/κ` and `e^{−l²/2κ}` take as the point's 1, 0 and 1 as the CPU's f64
/// values round).
fn kappa_uniform(kappa: f64) -> f32 {
    if kappa.is_finite() { kappa as f32 } else { 0.0 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shader_declares_the_same_table_shape() {
        let src = include_str!("../glsl/ndf_env.glsl");
        for (name, v) in [
            ("COS", ENERGY_COS),
            ("PARAM", ENERGY_PARAM),
            ("SHARES", ENERGY_SHARES),
        ] {
            let line = format!("const int NDF_ENV_ENERGY_{name} = {v};");
            assert!(src.contains(&line), "{line}");
        }
    }

    #[test]
    fn extracted_lights_are_packed_into_their_uniforms() {
        // The sky's sun, extracted: its direction, RGB power, κ and flag reach the uniforms
        // element for element, the count is 1; without extraction the count is 0 and no light
        // array is emitted.
        let sky = crate::environment::coloured_test_sky();
        let lights = crate::environment::lights::LightOptions::default();
        let with = EnvLight::with_lights(&sky, &lights);
        assert_eq!(with.lights().len(), 1);
        let up = pack(&with).unwrap();
        assert_eq!(up.lights, with.lights());
        let sun = with.lights()[0];
        let u = uniforms(&up, &Brdf::ggx(0.3), Route::Prefiltered);
        let get = |n: &str| {
            u.iter()
                .find(|u| u.name == n)
                .unwrap_or_else(|| panic!("{n}"))
        };
        let f = |v: f64| v as f32;
        assert_eq!(get("ndf_env_light_count").values, vec![1.0]);
        assert_eq!(get("ndf_env_light_dir").components, 3);
        assert_eq!(
            get("ndf_env_light_dir").values,
            sun.direction.to_array().map(f).to_vec()
        );
        assert_eq!(get("ndf_env_light_power").components, 3);
        assert_eq!(get("ndf_env_light_power").values, sun.power.map(f).to_vec());
        // The orange sun: red carries more power than blue.
        assert!(sun.power[0] > 2.0 * sun.power[2], "{:?}", sun.power);
        assert!(sun.kappa.is_finite() && sun.kappa > 1.0, "{}", sun.kappa);
        assert_eq!(get("ndf_env_light_kappa").values, vec![f(sun.kappa)]);
        assert_eq!(
            get("ndf_env_light_diffuse_only").values,
            vec![if sun.diffuse_only { 1.0 } else { 0.0 }]
        );
        assert_eq!(kappa_uniform(f64::INFINITY), 0.0);
        assert_eq!(kappa_uniform(2.5), 2.5);
        let none = crate::environment::lights::LightOptions::none();
        let up0 = pack(&EnvLight::with_lights(&sky, &none)).unwrap();
        assert!(up0.lights.is_empty());
        let u0 = uniforms(&up0, &Brdf::ggx(0.3), Route::Prefiltered);
        assert!(u0.iter().all(|u| !u.name.starts_with("ndf_env_light_")
            || (u.name == "ndf_env_light_count" && u.values == [0.0])));
        assert!(u0.iter().any(|u| u.name == "ndf_env_light_count"));
        // The residual's tables differ from the whole sky's (the sun is out of them).
        assert!(up.sh[0] < 0.9 * up0.sh[0], "{} {}", up.sh[0], up0.sh[0]);
    }

    #[test]
    fn the_atlas_holds_every_level_of_every_channel_unchanged() {
        // A sun and sky of different colours: a swapped or collapsed channel fails.
        let sky = crate::environment::coloured_test_sky();
        let light = EnvLight::new(&sky);
        let up = pack(&light).unwrap();
        for (c, ch) in light.channels().iter().enumerate() {
            let levels = ch.prefiltered().levels();
            assert_eq!(up.levels.len(), levels.len());
            assert_eq!(
                up.atlas.len(),
                CHANNELS * (up.atlas_width * up.atlas_height) as usize
            );
            for (l, &[w, h, row, col]) in levels.iter().zip(&up.levels) {
                assert_eq!((w, h), (l.radiance.width(), l.radiance.height()));
                assert!(col + w <= up.atlas_width && row + h <= up.atlas_height);
                for y in 0..h {
                    for x in 0..w {
                        let at = (row + y) * up.atlas_width + col + x;
                        let a = up.atlas[CHANNELS * at as usize + c];
                        assert_eq!(a, l.radiance.values()[(y * w + x) as usize]);
                    }
                }
            }
            for k in 0..81 {
                assert_eq!(up.sh[CHANNELS * k + c], ch.sh()[k] as f32);
            }
            let lp = ch.reflected().unwrap().packed();
            for (i, v) in lp.iter().enumerate() {
                assert_eq!(up.reflected[CHANNELS * i + c], *v);
            }
        }
        // No two levels overlap, and the atlas is under 4 times the environment's texels.
        for (i, a) in up.levels.iter().enumerate() {
            for b in &up.levels[..i] {
                let apart = a[3] >= b[3] + b[0]
                    || b[3] >= a[3] + a[0]
                    || a[2] >= b[2] + b[1]
                    || b[2] >= a[2] + a[1];
                assert!(apart, "{a:?} overlaps {b:?}");
            }
        }
        let (w0, h0) = (up.levels[0][0], up.levels[0][1]);
        assert!(
            up.atlas_width == w0 && up.atlas_height < 4 * h0,
            "{}",
            up.atlas_height
        );
        // The channels differ (the sun's colour reaches every table).
        assert!(up.sh[0] > 1.2 * up.sh[2], "{} {}", up.sh[0], up.sh[2]);
        assert_eq!(up.sh.len(), 81 * 3);
        assert_eq!(up.reflected.len(), 81 * 256 * 3);
        let bp = Brdf::BlinnPhong { s: 32.0 };
        let e = energy(&light, &bp).unwrap();
        assert_eq!(e.len(), ENERGY_SIZE.0 * ENERGY_SIZE.1 * ENERGY_CHANNELS);
        // Texel (column j·33 + c, row g·49 + p) holds blocks 4g … 4g + 3 of share j.
        let texel = |t: &[f32], j: usize, c: usize, g: usize, p: usize| {
            let k = ((g * ENERGY_PARAM + p) * ENERGY_SIZE.0 + j * ENERGY_COS + c) * ENERGY_CHANNELS;
            [t[k], t[k + 1], t[k + 2], t[k + 3]]
        };
        let table = light.energy_table(&bp).unwrap();
        let block = |b: usize, p: usize, c: usize| table[(b * ENERGY_PARAM + p) * ENERGY_COS + c];
        assert_eq!(texel(&e, 0, 7, 1, 20)[1], block(5, 20, 7) as f32);
        assert_eq!(
            texel(&e, 0, 7, 2, 20),
            [block(8, 20, 7) as f32, 0.0, 0.0, 0.0]
        );
        // Blinn-Phong's one share, repeated; GGX's shares differ (w = 0 against w = 1).
        assert_eq!(texel(&e, 0, 7, 0, 20), texel(&e, 8, 7, 0, 20));
        let g = energy(&light, &Brdf::ggx(0.1)).unwrap();
        assert_eq!(g.len(), e.len());
        assert_ne!(texel(&g, 0, 7, 0, 20), texel(&g, 8, 7, 0, 20));
        assert!(energy(&light, &Brdf::Lambert).is_none());
        let u = uniforms(&up, &Brdf::ggx(0.3), Route::Sh);
        assert!(
            u.iter()
                .any(|u| u.name == "ndf_env_rho" && u.values.len() == 9)
        );
        assert!(
            u.iter()
                .any(|u| u.name == "ndf_env_sh" && u.components == 3 && u.values == up.sh)
        );
        let u = uniforms(&up, &Brdf::ggx(0.3), Route::Prefiltered);
        assert!(u.iter().all(|u| u.name != "ndf_env_rho"));
    }
}
