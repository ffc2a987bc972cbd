//! CPU texture sampling with OpenGL's rules, and filtered shading at a texture coordinate: the
//! CPU twin of `glsl/ndf_fragment.glsl`'s `ndf_lod` and `ndf_shade` (hardware and manual
//! sampling, Han et al. 2007 Sec 7.3).
//!
//! Conventions (OpenGL 3.3 core, Sec 3.8.11): texel `i` of a level of width `w` has its centre at
//! `u = (i + 0.5)/w`; `LINEAR` blends the two texels around `u·w − 0.5` per axis, wrapped
//! (`REPEAT`) or clamped (`CLAMP_TO_EDGE`) as the bake's addressing says; `LINEAR_MIPMAP_LINEAR`
//! with level of detail λ ≤ 0 samples level 0, otherwise blends levels `⌊λ⌋` and `⌊λ⌋ + 1` with
//! weight `frac(λ)`, clamped to the last level. Row 0 of a level is `v` near 0.

use crate::bake::Bake;
use crate::brdf::Brdf;
use crate::pyramid::bilinear_taps;
use crate::shade::{ShadeOptions, ShadingRgb, shade_rgb_with};
use glam::{DVec2, DVec3};

/// GL's level of detail for screen derivatives of uv on a texture of base `size`:
/// `λ = log2 max(|∂(uv·size)/∂x|, |∂(uv·size)/∂y|)` (the shaders' `ndf_lod`).
pub fn lod(duv_dx: DVec2, duv_dy: DVec2, size: (u32, u32)) -> f64 {
    let s = DVec2::new(size.0 as f64, size.1 as f64);
    let (dx, dy) = (duv_dx * s, duv_dy * s);
    0.5 * dx
        .length_squared()
        .max(dy.length_squared())
        .max(1e-30)
        .log2()
}

/// The levels and weights `LINEAR_MIPMAP_LINEAR` blends at level of detail `lod` on a chain of
/// `levels` levels: one or two `(level, weight)` pairs, weights summing to 1.
pub fn level_weights(lod: f64, levels: usize) -> Vec<(usize, f64)> {
    let last = levels.saturating_sub(1);
    let lambda = if lod.is_nan() {
        0.0
    } else {
        lod.clamp(0.0, last as f64)
    };
    let level = lambda.floor() as usize;
    let f = lambda - level as f64;
    if f > 0.0 {
        vec![(level, 1.0 - f), (level + 1, f)]
    } else {
        vec![(level, 1.0)]
    }
}

/// The texels of `level` around `uv` with their bilinear weights (zero weights left out, as the
/// manual shader skips them): up to four `(row-major index, weight)` pairs.
pub fn bilinear(bake: &Bake, level: usize, uv: DVec2) -> Vec<(usize, f64)> {
    let (w, h) = bake.sizes[level];
    let xs = bilinear_taps(uv.x, w, bake.addressing);
    let ys = bilinear_taps(uv.y, h, bake.addressing);
    let mut taps = Vec::with_capacity(4);
    for &(y, wy) in &ys {
        for &(x, wx) in &xs {
            let weight = wx * wy;
            if weight != 0.0 {
                taps.push((y as usize * w as usize + x as usize, weight));
            }
        }
    }
    taps
}

/// Trilinear (`LINEAR_MIPMAP_LINEAR`) sample of every texture of `bake` at `uv` and level of
/// detail `lod`, accumulated in f64 and rounded to f32: what one hardware fetch per texture
/// returns (up to the GPU's own weight precision).
pub fn trilinear(bake: &Bake, uv: DVec2, lod: f64) -> Vec<[f32; 4]> {
    let n = bake.textures.len();
    let mut acc = vec![[0.0f64; 4]; n];
    let mut texel = vec![[0.0f32; 4]; n];
    for (level, lw) in level_weights(lod, bake.level_count()) {
        for (index, bw) in bilinear(bake, level, uv) {
            bake.texel_into(level, index, &mut texel);
            for (a, t) in acc.iter_mut().zip(&texel) {
                for c in 0..4 {
                    a[c] += lw * bw * t[c] as f64;
                }
            }
        }
    }
    acc.iter().map(|a| a.map(|v| v as f32)).collect()
}

/// How [`shade_at`] filters and shades: the shader's specialization.
#[derive(Debug, Clone, PartialEq)]
pub struct Filtering {
    /// The BRDF.
    pub brdf: Brdf,
    /// Manual sampling (shade each texel, then blend) instead of hardware trilinear sampling.
    pub manual: bool,
    /// Weight mixture lobes by their colour textures ([`crate::shade::shade_rgb`]).
    pub color: bool,
    /// Shading choices that are not part of the BRDF.
    pub shading: ShadeOptions,
}

impl Filtering {
    /// Hardware trilinear sampling, no colour, default shading options.
    pub fn new(brdf: Brdf) -> Filtering {
        Filtering {
            brdf,
            manual: false,
            color: false,
            shading: ShadeOptions::default(),
        }
    }
}

/// Filtered shading of `bake` at `uv` and level of detail `lod` for light `l` and half vector
/// `h` (tangent space): with `f.manual`, every texel of the trilinear footprint is shaded and the
/// results blended with the trilinear weights (unaligned lobes); otherwise the textures are
/// sampled trilinearly and shaded once (aligned lobes, baselines).
pub fn shade_at(bake: &Bake, uv: DVec2, lod: f64, l: DVec3, h: DVec3, f: &Filtering) -> ShadingRgb {
    let mut out = [ShadingRgb::default()];
    shade_at_lights(bake, uv, lod, &[(l, h)], f, &mut out);
    out[0]
}

/// [`shade_at`] for several lights at one point: `lights` holds each light's `(l, h)`, and
/// `out[i]` receives light i's shading, bit for bit what `shade_at` gives for it. The texels
/// (or the trilinear sample) are fetched once for all the lights.
pub fn shade_at_lights(
    bake: &Bake,
    uv: DVec2,
    lod: f64,
    lights: &[(DVec3, DVec3)],
    f: &Filtering,
    out: &mut [ShadingRgb],
) {
    let Filtering {
        brdf,
        manual,
        color,
        shading,
    } = f;
    let (manual, color) = (*manual, *color);
    if !manual {
        let sample = trilinear(bake, uv, lod);
        for (o, &(l, h)) in out.iter_mut().zip(lights) {
            *o = shade_rgb_with(bake, &sample, l, h, brdf, color, shading);
        }
        return;
    }
    let mut texel = vec![[0.0f32; 4]; bake.textures.len()];
    for o in out.iter_mut() {
        *o = ShadingRgb::default();
    }
    for (level, lw) in level_weights(lod, bake.level_count()) {
        for (index, bw) in bilinear(bake, level, uv) {
            bake.texel_into(level, index, &mut texel);
            for (sum, &(l, h)) in out.iter_mut().zip(lights) {
                let s = shade_rgb_with(bake, &texel, l, h, brdf, color, shading);
                sum.diffuse += lw * bw * s.diffuse;
                sum.specular += lw * bw * s.specular;
            }
        }
    }
}

/// The anisotropic footprint, as `GL_EXT_texture_filter_anisotropic` specifies its reference
/// implementation (the shaders' `NDF_ANISO` sampling, `glsl/ndf_fragment.glsl`): with the
/// screen derivatives of the texel coordinates `P_x = |∂(uv·size)/∂x|`, `P_y = |∂(uv·size)/∂y|`,
/// `P_max = max`, `P_min = min`, take `N = min(⌈P_max/P_min⌉, max_aniso)` trilinear probes at
/// level of detail `λ' = log2(P_max/N)`, at `uv + (i/(N+1) − ½)·∂uv/∂(major axis)` for
/// i = 1 … N, and average them with equal weights. `P_min = 0` counts as `P_max/max_aniso`.
/// Returns `λ'` and the probes' uv offsets.
pub fn aniso_probes(
    duv_dx: DVec2,
    duv_dy: DVec2,
    size: (u32, u32),
    max_aniso: u32,
) -> (f64, Vec<DVec2>) {
    let sz = DVec2::new(size.0 as f64, size.1 as f64);
    let (px, py) = ((duv_dx * sz).length(), (duv_dy * sz).length());
    let (pmax, pmin) = (px.max(py), px.min(py));
    let max_aniso = max_aniso.max(1);
    let ratio = if pmin > 0.0 {
        pmax / pmin
    } else {
        max_aniso as f64
    };
    let n = if ratio.is_finite() {
        (ratio.ceil() as u32).clamp(1, max_aniso)
    } else {
        max_aniso
    };
    let lod = (pmax / n as f64).max(1e-15).log2();
    let major = if px >= py { duv_dx } else { duv_dy };
    let offsets = (1..=n)
        .map(|i| major * (i as f64 / (n + 1) as f64 - 0.5))
        .collect();
    (lod, offsets)
}

/// The anisotropic sample of every texture of `bake` ([`aniso_probes`]): the mean of the
/// probes' trilinear samples, accumulated in f64 and rounded to f32.
pub fn anisotropic(
    bake: &Bake,
    uv: DVec2,
    duv_dx: DVec2,
    duv_dy: DVec2,
    max_aniso: u32,
) -> Vec<[f32; 4]> {
    let (lod, offsets) = aniso_probes(duv_dx, duv_dy, bake.sizes[0], max_aniso);
    probe_mean(bake, uv, &offsets, lod)
}

/// The mean of the trilinear samples of every texture of `bake` at `uv + offsets[i]` and
/// `lod`, accumulated in f64 and rounded to f32 (the anisotropic probes' average).
fn probe_mean(bake: &Bake, uv: DVec2, offsets: &[DVec2], lod: f64) -> Vec<[f32; 4]> {
    let mut acc = vec![[0.0f64; 4]; bake.textures.len()];
    for o in offsets {
        for (a, t) in acc.iter_mut().zip(trilinear(bake, uv + *o, lod)) {
            for c in 0..4 {
                a[c] += t[c] as f64;
            }
        }
    }
    let n = offsets.len() as f64;
    acc.iter().map(|a| a.map(|v| (v / n) as f32)).collect()
}

/// Shading under the anisotropic footprint (the shaders' `NDF_ANISO`): the textures sampled
/// by [`anisotropic`], then shaded once per light, as hardware filtering does — valid where
/// the parameters filter linearly (SH coefficients, aligned vMF lobes, the baselines' moments).
pub fn shade_aniso_lights(
    bake: &Bake,
    uv: DVec2,
    (duv_dx, duv_dy): (DVec2, DVec2),
    max_aniso: u32,
    lights: &[(DVec3, DVec3)],
    f: &Filtering,
    out: &mut [ShadingRgb],
) {
    let sample = anisotropic(bake, uv, duv_dx, duv_dy, max_aniso);
    for (o, &(l, h)) in out.iter_mut().zip(lights) {
        *o = shade_rgb_with(bake, &sample, l, h, &f.brdf, f.color, &f.shading);
    }
}

/// The parts and weights of a shader that switches method by level of detail
/// (`glsl::lod_switch_source`) at `lod`: `ranges[k]` is part k's `(first, last)` map
/// levels, consecutive. λ = `lod` clamped to the levels shipped; the part k holding ⌊λ⌋ shades
/// at its local level of detail λ − first_k, except at its last level with f = frac(λ) > 0,
/// where the trilinear blend crosses into the next part: `(k, last_k − first_k, 1 − f)` and
/// `(k + 1, 0, f)`. Returns `(part, local lod, weight)`, weights summing to 1.
pub fn lod_switch_weights(ranges: &[(usize, usize)], lod: f64) -> Vec<(usize, f64, f64)> {
    let (Some(&(lo, _)), Some(&(_, hi))) = (ranges.first(), ranges.last()) else {
        return Vec::new();
    };
    let lambda = if lod.is_nan() {
        lo as f64
    } else {
        lod.clamp(lo as f64, hi as f64)
    };
    let level = lambda.floor() as usize;
    let f = lambda - level as f64;
    let k = ranges.iter().rposition(|r| level >= r.0).unwrap_or(0);
    let (first, last) = ranges[k];
    if f == 0.0 || level < last || k + 1 == ranges.len() {
        vec![(k, lambda - first as f64, 1.0)]
    } else {
        vec![(k, (last - first) as f64, 1.0 - f), (k + 1, 0.0, f)]
    }
}

/// One part of a LOD-switching shader's CPU twin ([`shade_switch`]).
#[derive(Debug, Clone)]
pub struct SwitchPart<'a> {
    /// The part's bake: its level 0 is map level `first` (what `plan::execute` returns).
    pub bake: &'a Bake,
    /// The finest map level it shades.
    pub first: usize,
    /// The coarsest.
    pub last: usize,
    /// Its filtering and shading.
    pub filtering: Filtering,
}

/// The CPU twin of `glsl::lod_switch_source`'s `ndf_shade` (hardware or manual
/// sampling per part): the [`lod_switch_weights`] blend of the parts' [`shade_at`].
pub fn shade_switch(parts: &[SwitchPart], uv: DVec2, lod: f64, l: DVec3, h: DVec3) -> ShadingRgb {
    let ranges: Vec<(usize, usize)> = parts.iter().map(|p| (p.first, p.last)).collect();
    let mut out = ShadingRgb::default();
    for (k, local, w) in lod_switch_weights(&ranges, lod) {
        let s = shade_at(parts[k].bake, uv, local, l, h, &parts[k].filtering);
        out.diffuse += w * s.diffuse;
        out.specular += w * s.specular;
    }
    out
}

/// The CPU twin of the LOD-switching shader's anisotropic `ndf_shade_footprint`: the probes of
/// [`aniso_probes`] on the map (`map_size`), the parts of [`lod_switch_weights`] at the probes'
/// LOD, each averaging its probes' trilinear samples at its local LOD and shading once.
#[allow(clippy::too_many_arguments)]
pub fn shade_switch_aniso(
    parts: &[SwitchPart],
    map_size: (u32, u32),
    uv: DVec2,
    (duv_dx, duv_dy): (DVec2, DVec2),
    max_aniso: u32,
    l: DVec3,
    h: DVec3,
) -> ShadingRgb {
    let ranges: Vec<(usize, usize)> = parts.iter().map(|p| (p.first, p.last)).collect();
    let (lod, offsets) = aniso_probes(duv_dx, duv_dy, map_size, max_aniso);
    let mut out = ShadingRgb::default();
    for (k, local, w) in lod_switch_weights(&ranges, lod) {
        let (bake, f) = (parts[k].bake, &parts[k].filtering);
        let t = probe_mean(bake, uv, &offsets, local);
        let s = shade_rgb_with(bake, &t, l, h, &f.brdf, f.color, &f.shading);
        out.diffuse += w * s.diffuse;
        out.specular += w * s.specular;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::Method;
    use crate::methods::bake;

    #[test]
    fn the_lod_switch_picks_the_part_holding_the_level_and_blends_across_boundaries() {
        let r = [(0, 0), (1, 3), (4, 6)];
        assert_eq!(lod_switch_weights(&r, -2.0), vec![(0, 0.0, 1.0)]);
        assert_eq!(lod_switch_weights(&r, 0.0), vec![(0, 0.0, 1.0)]);
        assert_eq!(
            lod_switch_weights(&r, 0.25),
            vec![(0, 0.0, 0.75), (1, 0.0, 0.25)]
        );
        assert_eq!(lod_switch_weights(&r, 1.0), vec![(1, 0.0, 1.0)]);
        assert_eq!(lod_switch_weights(&r, 2.5), vec![(1, 1.5, 1.0)]);
        assert_eq!(lod_switch_weights(&r, 3.0), vec![(1, 2.0, 1.0)]);
        assert_eq!(
            lod_switch_weights(&r, 3.5),
            vec![(1, 2.0, 0.5), (2, 0.0, 0.5)]
        );
        assert_eq!(lod_switch_weights(&r, 5.75), vec![(2, 1.75, 1.0)]);
        assert_eq!(lod_switch_weights(&r, 9.0), vec![(2, 2.0, 1.0)]);
        assert_eq!(lod_switch_weights(&[(2, 5)], 1.0), vec![(0, 0.0, 1.0)]);
        assert!(lod_switch_weights(&[], 1.0).is_empty());
    }

    #[test]
    fn anisotropic_footprint_follows_the_extension_rule() {
        // 8 texels along x, 2 along y: N = 4 probes at λ' = log2(8/4) = 1, spread over the
        // major axis at i/5 − 1/2.
        let (dx, dy) = (DVec2::new(8.0 / 256.0, 0.0), DVec2::new(0.0, 2.0 / 256.0));
        let (lod, off) = aniso_probes(dx, dy, (256, 256), 16);
        assert!((lod - 1.0).abs() < 1e-12);
        assert_eq!(off.len(), 4);
        for (i, o) in off.iter().enumerate() {
            let t = (i + 1) as f64 / 5.0 - 0.5;
            assert!((o.x - t * 8.0 / 256.0).abs() < 1e-15 && o.y == 0.0);
        }
        // Capped at max_aniso, and isotropic footprints are one trilinear probe.
        assert_eq!(aniso_probes(dx, dy, (256, 256), 2).1.len(), 2);
        let (lod, off) = aniso_probes(dy, dy, (256, 256), 16);
        assert_eq!(off, vec![DVec2::ZERO]);
        assert!((lod - 1.0).abs() < 1e-12);
        // The anisotropic sample of a linear bake is the mean of its probes' trilinear samples.
        let map = crate::procedural::generate(16, 2).map;
        let b = bake(&map, Method::Toksvig);
        let uv = DVec2::new(0.3, 0.6);
        let (dx, dy) = (DVec2::new(0.2, 0.05), DVec2::new(0.0, 0.02));
        let got = anisotropic(&b, uv, dx, dy, 16);
        let (lod, off) = aniso_probes(dx, dy, (16, 16), 16);
        for (c, g) in got[0].iter().enumerate() {
            let want: f64 = off
                .iter()
                .map(|o| trilinear(&b, uv + *o, lod)[0][c] as f64)
                .sum::<f64>()
                / off.len() as f64;
            assert!((*g as f64 - want).abs() < 1e-6);
        }
    }

    #[test]
    fn lod_is_log2_of_the_texel_footprint() {
        // One pixel spans 4 texels along x on a 256-wide texture: λ = 2.
        let l = lod(
            DVec2::new(4.0 / 256.0, 0.0),
            DVec2::new(0.0, 1.0 / 256.0),
            (256, 256),
        );
        assert!((l - 2.0).abs() < 1e-12);
    }

    #[test]
    fn level_weights_follow_linear_mipmap_linear() {
        assert_eq!(level_weights(-1.0, 5), vec![(0, 1.0)]);
        assert_eq!(level_weights(2.0, 5), vec![(2, 1.0)]);
        assert_eq!(level_weights(9.0, 5), vec![(4, 1.0)]);
        assert_eq!(level_weights(1.25, 5), vec![(1, 0.75), (2, 0.25)]);
        assert_eq!(level_weights(f64::NAN, 3), vec![(0, 1.0)]);
    }

    #[test]
    fn trilinear_at_texel_centres_returns_the_texel() {
        let map = crate::procedural::generate(8, 3).map;
        let b = bake(&map, Method::Olano);
        for level in 0..b.level_count() {
            let (w, h) = b.sizes[level];
            for y in 0..h {
                for x in 0..w {
                    let uv = DVec2::new((x as f64 + 0.5) / w as f64, (y as f64 + 0.5) / h as f64);
                    assert_eq!(trilinear(&b, uv, level as f64), b.texel(level, x, y));
                }
            }
        }
    }

    #[test]
    fn manual_and_hardware_agree_for_linear_shading() {
        // Plain mipmapping's diffuse term is not linear in the texel (normalization), but for a
        // flat map every texel is the same: both modes give the texel's shading.
        let flat = vec![glam::Vec3::Z; 16];
        use crate::ingest::{Addressing, BadNormals, NormalMap};
        let map =
            NormalMap::from_vectors(4, 4, flat, Addressing::Wrap, BadNormals::Repair).unwrap();
        let b = bake(&map, Method::Toksvig);
        let (l, h) = (DVec3::new(0.3, 0.1, 0.9).normalize(), DVec3::Z);
        let brdf = Brdf::BlinnPhong { s: 32.0 };
        let uv = DVec2::new(0.37, 0.81);
        let f = |manual| Filtering {
            manual,
            ..Filtering::new(brdf.clone())
        };
        let a = shade_at(&b, uv, 0.6, l, h, &f(true));
        let c = shade_at(&b, uv, 0.6, l, h, &f(false));
        assert!((a.specular - c.specular).abs().max_element() < 1e-12);
        assert!((a.diffuse - DVec3::splat(l.z)).abs().max_element() < 1e-6);
    }

    #[test]
    fn shading_several_lights_at_once_is_shading_each_alone() {
        // What the renders rely on to fetch texels once for all lights: bit-identical results.
        let map = crate::procedural::generate(16, 5).map;
        let lights = [
            (DVec3::new(0.3, 0.1, 0.9).normalize(), DVec3::Z),
            (
                DVec3::new(-0.6, 0.2, 0.4).normalize(),
                DVec3::new(0.1, -0.2, 1.0).normalize(),
            ),
        ];
        for (method, align) in [
            (Method::Vmf, None),
            (Method::Vmf, Some(0.1)),
            (Method::Lean, None),
        ] {
            let options = crate::bake::BakeOptions {
                lobes: 3,
                align,
                ..Default::default()
            };
            let b = crate::methods::bake_with(&map, method, &options).unwrap();
            for manual in [false, true] {
                let f = Filtering {
                    manual,
                    ..Filtering::new(Brdf::BlinnPhong { s: 64.0 })
                };
                for (uv, lod) in [(DVec2::new(0.37, 0.81), 0.6), (DVec2::new(0.9, 0.02), 2.3)] {
                    let mut out = [ShadingRgb::default(); 2];
                    shade_at_lights(&b, uv, lod, &lights, &f, &mut out);
                    for (o, &(l, h)) in out.iter().zip(&lights) {
                        assert_eq!(*o, shade_at(&b, uv, lod, l, h, &f), "{method} {manual}");
                    }
                }
            }
        }
    }
}
