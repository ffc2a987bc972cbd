//! Environment lighting on the GPU (issue 16, item 5): the data the environment shaders read,
//! packed for upload. The shaders are `glsl/ndf_env.glsl`, selected by the `#define`
//! `NDF_LIGHT_ENV_PREFILTERED` or `NDF_LIGHT_ENV_SH` ([`crate::glsl::ShaderLight`]); their CPU
//! twin is [`crate::envlight::shade`].
//!
//! **Layout: an equirectangular `R32F` atlas, not a cube map and not a GL MIP chain.** The
//! prefiltered levels ([`crate::environment::prefilter`]) are equirectangular, made by
//! solid-angle-weighted downsampling, and stop halving at 16 × 8 texels while the lobe keeps
//! widening, so they are not a GL MIP chain (whose levels must halve) and resampling them to a
//! cube map would change every value. The atlas stacks the levels as they are, level 0 at the
//! top, each starting at column 0 of its own rows ([`Upload::levels`]: width, height, first
//! row). The shader reads it with `texelFetch` and does the bilinear lookup (wrapping in φ,
//! clamped at the poles) and the blend between the two levels around
//! `LOD = ½ log2(κ_0/κ)` itself, in the same order as [`crate::environment::prefilter::
//! Prefiltered::lookup`]: that is what makes GL = CPU exact to f32 rounding. Hardware filtering
//! would not be: GPUs (llvmpipe included) filter with fixed-point weights (8 bits on many), a
//! relative error of 1/256 of the difference between neighbouring texels, which next to a sun
//! of radiance 10⁶ is far above the route's own error.
//!
//! The `L′` table ([`crate::environment::projection::ReflectedTable`]) is an `R32F` texture of
//! `count(8) = 81` columns (the coefficients) × `16² = 256` rows (row `iθ·16 + iφ`, the views of
//! [`crate::environment::projection::view_of`]); the lobe-energy table of the BRDF
//! ([`EnvLight::energy_table`]) an `R32F` texture of [`ENERGY_COS`] columns ×
//! [`ENERGY_BLOCKS`] · [`ENERGY_PARAM`] rows (energy, blend, `log2 κ_i`, block after block). Both are read with `texelFetch` and interpolated in the shader like the CPU does.
//!
//! Uniforms ([`uniforms`]): `ndf_env_sh[81]` (`L_lm`, environment frame), `ndf_env_kappa0`,
//! `ndf_env_level_count`, `ndf_env_level[3·16]` (width, height, first row per level, as floats),
//! and for the SH route `ndf_env_rho[9]` (the BRDF's `ρ̂_l`, l ≤ 8). Samplers: `ndf_env_atlas`,
//! `ndf_env_energy` (prefiltered route), `ndf_env_reflected` (SH route). Mesh mode adds
//! `mat3 ndf_env_rotation` (world → environment frame), set by the application.

use crate::brdf::Brdf;
use crate::environment::projection::REFLECTED_GRID;
use crate::envlight::{ENERGY_BLOCKS, ENERGY_COS, ENERGY_PARAM, ENV_LMAX, EnvLight, Route};
use crate::error::{Error, Result};
use crate::harmonics::count;

/// The most prefiltered levels a shader reads (`ndf_env_level[3·MAX_LEVELS]`): enough for a
/// 16384-wide panorama (14 levels).
pub const MAX_LEVELS: usize = 16;

/// Columns of the `L′` texture: `count(ENV_LMAX)` = 81 coefficients.
pub const REFLECTED_COLUMNS: usize = (ENV_LMAX + 1) * (ENV_LMAX + 1);

/// Rows of the `L′` texture: one per grid view, `REFLECTED_GRID²` = 256.
pub const REFLECTED_ROWS: usize = REFLECTED_GRID * REFLECTED_GRID;

/// An environment packed for upload (module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct Upload {
    /// Atlas width in texels (level 0's width).
    pub atlas_width: u32,
    /// Atlas height in texels (the levels' heights summed).
    pub atlas_height: u32,
    /// The atlas, row-major from the top row, texels outside a level's width are 0.
    pub atlas: Vec<f32>,
    /// Per level: width, height, first atlas row.
    pub levels: Vec<[u32; 3]>,
    /// `κ_0 = W·H/π` of level 0 (`LOD = ½ log2(κ_0/κ)`).
    pub kappa0: f64,
    /// `L_lm`, l ≤ 8, environment frame, (l, m) order.
    pub sh: Vec<f32>,
    /// The `L′` table: [`REFLECTED_ROWS`] rows of [`REFLECTED_COLUMNS`] values.
    pub reflected: Vec<f32>,
}

/// Packs `light` for upload (module docs). Fails only when it has more than [`MAX_LEVELS`]
/// levels (a panorama wider than [`crate::environment::MAX_WIDTH`] would).
pub fn pack(light: &EnvLight) -> Result<Upload> {
    let levels = light.prefiltered().levels();
    if levels.len() > MAX_LEVELS {
        return Err(Error::InvalidOption(format!(
            "the environment has {} prefiltered levels, the shaders read at most {MAX_LEVELS}",
            levels.len()
        )));
    }
    let width = levels[0].radiance.width();
    let height: u32 = levels.iter().map(|l| l.radiance.height()).sum();
    let mut atlas = vec![0.0f32; width as usize * height as usize];
    let mut table = Vec::with_capacity(levels.len());
    let mut row = 0u32;
    for level in levels {
        let r = &level.radiance;
        for y in 0..r.height() as usize {
            let src = &r.values()[y * r.width() as usize..][..r.width() as usize];
            let dst = (row as usize + y) * width as usize;
            atlas[dst..dst + src.len()].copy_from_slice(src);
        }
        table.push([r.width(), r.height(), row]);
        row += r.height();
    }
    let reflected = light.reflected().packed();
    debug_assert_eq!(reflected.len(), REFLECTED_COLUMNS * REFLECTED_ROWS);
    Ok(Upload {
        atlas_width: width,
        atlas_height: height,
        atlas,
        levels: table,
        kappa0: light.prefiltered().kappa0(),
        sh: light.sh()[..count(ENV_LMAX)]
            .iter()
            .map(|&v| v as f32)
            .collect(),
        reflected,
    })
}

/// The lobe table of `brdf` as f32 for upload ([`ENERGY_BLOCKS`] · [`ENERGY_PARAM`] rows ×
/// [`ENERGY_COS`] columns: energy, blend, `log2 κ_i`), `None` for a BRDF without a specular lobe.
pub fn energy(light: &EnvLight, brdf: &Brdf) -> Option<Vec<f32>> {
    light
        .energy_table(brdf)
        .map(|t| t.iter().map(|&v| v as f32).collect())
}

/// The size (columns, rows) of [`energy`]'s texture.
pub const ENERGY_SIZE: (usize, usize) = (ENERGY_COS, ENERGY_BLOCKS * ENERGY_PARAM);

/// The environment uniforms of a shader lit by `route` with `brdf` (module docs), as f32 values
/// (arrays as several).
pub fn uniforms(upload: &Upload, brdf: &Brdf, route: Route) -> Vec<(&'static str, Vec<f32>)> {
    let mut level = vec![0.0f32; 3 * MAX_LEVELS];
    for (i, l) in upload.levels.iter().enumerate() {
        for k in 0..3 {
            level[3 * i + k] = l[k] as f32;
        }
    }
    let mut out = vec![
        ("ndf_env_sh", upload.sh.clone()),
        ("ndf_env_kappa0", vec![upload.kappa0 as f32]),
        ("ndf_env_level_count", vec![upload.levels.len() as f32]),
        ("ndf_env_level", level),
    ];
    if route == Route::Sh && brdf.has_specular() {
        let rho = brdf.sh_coefficients(ENV_LMAX);
        out.push(("ndf_env_rho", rho.iter().map(|&v| v as f32).collect()));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::environment::Sky;

    #[test]
    fn the_atlas_holds_every_level_unchanged() {
        let sky = Sky {
            width: 64,
            ..Sky::default()
        }
        .render()
        .unwrap();
        let light = EnvLight::new(sky.luminance());
        let up = pack(&light).unwrap();
        let levels = light.prefiltered().levels();
        assert_eq!(up.levels.len(), levels.len());
        assert_eq!(up.atlas.len(), (up.atlas_width * up.atlas_height) as usize);
        for (l, &[w, h, row]) in levels.iter().zip(&up.levels) {
            assert_eq!((w, h), (l.radiance.width(), l.radiance.height()));
            for y in 0..h {
                for x in 0..w {
                    let a = up.atlas[((row + y) * up.atlas_width + x) as usize];
                    assert_eq!(a, l.radiance.values()[(y * w + x) as usize]);
                }
            }
        }
        assert_eq!(up.sh.len(), 81);
        assert_eq!(up.reflected.len(), 81 * 256);
        let e = energy(&light, &Brdf::BlinnPhong { s: 32.0 }).unwrap();
        assert_eq!(e.len(), ENERGY_COS * ENERGY_BLOCKS * ENERGY_PARAM);
        assert!(energy(&light, &Brdf::Lambert).is_none());
        let u = uniforms(&up, &Brdf::ggx(0.3), Route::Sh);
        assert!(u.iter().any(|(n, v)| *n == "ndf_env_rho" && v.len() == 9));
        let u = uniforms(&up, &Brdf::ggx(0.3), Route::Prefiltered);
        assert!(u.iter().all(|(n, _)| *n != "ndf_env_rho"));
    }
}
