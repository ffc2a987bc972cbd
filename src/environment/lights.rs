//! Light extraction (issue 16, H16x): the few compact, very bright sources of an environment
//! (a sun, lamps) taken out as distant analytic lights, leaving a smooth residual environment.
//!
//! The prefiltered route looks a lobe up in an isotropically prefiltered environment, and SH
//! l ≤ 2 cuts the bands a small lamp puts its energy in; both are exact for smooth radiance
//! and worst on a point-like source (`docs/environment.md`, "Where vMF's error comes from").
//! The standard production answer (Frostbite, Filament's IBL + sun) is to shade the bright
//! compact sources as lights — where ndfmap is exact per vMF lobe (Algorithm 2, eq 14/20, the
//! GGX mixture rule) — and prefilter / project only the residual. `envlight::EnvLight` does
//! that when built with [`LightOptions::max_lights`] > 0.
//!
//! **Method** ([`extract`]), on the Rec. 709 luminance with exact texel solid angles
//! ([`super::Geometry::solid_angle`], the weights the SH projection uses):
//! 1. the environment's mean luminance `L̄ = Σ L Ω / 4π`; seeds are texels brighter than
//!    [`LightOptions::threshold`]` · L̄`;
//! 2. each seed, brightest first, grows into the 8-connected region of texels brighter than
//!    [`LightOptions::grow`]` · threshold · L̄` and than [`LightOptions::peak_fraction`] of the
//!    seed (hysteresis, so a sun's anti-aliased rim goes with it but a sunset's glow does
//!    not); neighbours wrap in azimuth and cross the poles (row 0's texel x touches row 0's
//!    `x + W/2`);
//! 3. per channel, the fill is the solid-angle-weighted mean of the region's ring (its
//!    8-neighbours outside it), lowered to the region's own minimum of that channel so that no
//!    texel gives negative power; the light's RGB power is `Σ (L − fill) Ω` over the region
//!    and the residual holds `fill` there. Residual + lights = original exactly (the power is
//!    summed in f64 from the very f32 values the residual stores);
//! 4. a region is kept as a light when it is compact (solid angle and the cap `4π/κ` of its
//!    spread ≤ [`LightOptions::max_solid_angle`]), as a diffuse-only light when they are
//!    within [`LightOptions::max_diffuse_solid_angle`] (taken out of the diffuse SH only: a
//!    window shaded as one spread point is good for the clamped cosine, not for a highlight),
//!    and carries a real share of the power (luminance power ≥ [`LightOptions::min_share`] of
//!    the environment's); the [`LightOptions::max_lights`] (and
//!    [`LightOptions::max_diffuse_lights`]) most powerful are extracted.
//!
//! Each light's direction is the power-weighted mean of its texels' directions; its spread is
//! the vMF κ with the same mean resultant length, each texel counted as a uniform patch
//! (`R̄ = 1 − Ω/4π` for a cap of solid angle Ω).
//!
//! A constant, sunless or all-black environment has no texel above `threshold · L̄` (or
//! `L̄ = 0`) and extracts nothing. NaN/∞/negative texels were repaired when the environment was
//! made ([`super::Environment::from_rgb`]), so every value here is finite and ≥ 0.

use super::{Environment, Geometry, LUMINANCE};
use glam::DVec3;
use std::f64::consts::PI;

/// How lights are extracted ([`extract`]; module docs for the method and why these defaults).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LightOptions {
    /// At most this many lights (0: none, the paper's pure routes). Default 4: a sun, or a few
    /// lamps; the shaders pay one point-light evaluation per lobe and light.
    pub max_lights: usize,
    /// Seed threshold, a multiple of the mean luminance. Default 20: a clear sky's brightest
    /// sky texels stay below 2–3 × the mean, a sun or a lamp is 10³–10⁶ ×.
    pub threshold: f64,
    /// Region growth threshold as a fraction of the seed threshold. Default 0.25.
    pub grow: f64,
    /// A region grows only into texels brighter than this fraction of its peak too. Default
    /// 10⁻²: the generated sky's sun keeps its anti-aliased rim within 1 % of its power, and
    /// venice_sunset's disc (2.3 % of the power in 7 texels) comes apart from its glow (a
    /// 0.22 sr region at 10⁻³, too wide for a light), which is left to the routes.
    pub peak_fraction: f64,
    /// Largest solid angle of a light, sr, both of its texels and of its spread (the cap
    /// `4π/κ` of the vMF with its mean resultant length). Default 0.05 (a cap of about 7° half-angle): a
    /// larger region is not compact — the prefiltered levels and SH resolve it.
    pub max_solid_angle: f64,
    /// At most this many diffuse-only lights (module docs). Default 4.
    pub max_diffuse_lights: usize,
    /// Largest solid angle (texels and spread cap, sr) of a diffuse-only light: a region
    /// wider than [`LightOptions::max_solid_angle`] but within this is taken out of the
    /// diffuse SH only. Default 1 sr (a cap of about 33°): workshop_1k's windows (κ = 27–92),
    /// whose band ≥ 3 energy is what keeps Lambert with SH l ≤ 2 off by 2.4 %; shaded as a
    /// vMF-spread point their specular is far off (docs/environment.md), so they stay in the
    /// specular routes' residual.
    pub max_diffuse_solid_angle: f64,
    /// Smallest share of the environment's luminance power a light carries. Default 0.01
    /// (workshop_1k's fourth compact lamp carries 1.6 %).
    pub min_share: f64,
}

impl Default for LightOptions {
    fn default() -> Self {
        LightOptions {
            max_lights: 4,
            threshold: 20.0,
            grow: 0.25,
            peak_fraction: 1e-2,
            max_solid_angle: 0.05,
            max_diffuse_lights: 4,
            max_diffuse_solid_angle: 1.0,
            min_share: 0.01,
        }
    }
}

impl LightOptions {
    /// No extraction: the paper's pure routes.
    pub fn none() -> LightOptions {
        LightOptions {
            max_lights: 0,
            max_diffuse_lights: 0,
            ..LightOptions::default()
        }
    }

    /// The defaults with at most `n` compact and `n` diffuse-only lights (0: none).
    pub fn up_to(n: usize) -> LightOptions {
        LightOptions {
            max_lights: n,
            max_diffuse_lights: n,
            ..LightOptions::default()
        }
    }
}

/// A distant light extracted from an environment (environment frame, +Z up).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Light {
    /// Unit direction towards the light: the power-weighted mean of its texels' directions.
    pub direction: DVec3,
    /// RGB power `Σ (L − fill) Ω` (irradiance on a surface facing it, W/m²-like units of
    /// radiance × sr).
    pub power: [f64; 3],
    /// Solid angle of its texels, sr.
    pub solid_angle: f64,
    /// Concentration of the vMF with its mean resultant length (its angular spread).
    pub kappa: f64,
    /// How many texels it was taken from.
    pub texels: usize,
    /// A wide source (compact only within [`LightOptions::max_diffuse_solid_angle`]): taken
    /// out of the environment's SH for the diffuse term only; the specular routes keep it in
    /// their residual ([`Extraction::residual`]).
    pub diffuse_only: bool,
}

impl Light {
    /// Rec. 709 luminance of [`Light::power`].
    pub fn luminance(&self) -> f64 {
        (0..3).map(|c| LUMINANCE[c] * self.power[c]).sum()
    }
}

/// The lights of an environment and what is left of it.
#[derive(Debug, Clone, PartialEq)]
pub struct Extraction {
    /// The lights: the compact ones most powerful first, then the diffuse-only ones
    /// ([`Light::diffuse_only`]) most powerful first.
    pub lights: Vec<Light>,
    /// The environment with each compact light's texels replaced by its fill: what the
    /// specular routes (prefiltered levels, `L′`) read.
    pub residual: Environment,
    /// [`Extraction::residual`] with the diffuse-only lights' texels replaced by their fill
    /// too: what the diffuse SH (eq 25) reads.
    pub diffuse_residual: Environment,
}

fn lum(t: &[f32; 3]) -> f64 {
    (0..3).map(|c| LUMINANCE[c] * t[c] as f64).sum()
}

/// The 8-neighbours of texel `(x, y)` on a `w × h` lat-long grid: azimuth wraps; at the top and
/// bottom rows the texels across the pole (`x + w/2`) are neighbours too.
fn neighbours(x: usize, y: usize, w: usize, h: usize, out: &mut Vec<usize>) {
    out.clear();
    for dy in -1i64..=1 {
        let yy = y as i64 + dy;
        if yy < 0 || yy >= h as i64 {
            // Across the pole: the same row, half a turn away.
            for dx in -1i64..=1 {
                let xx = (x as i64 + (w / 2) as i64 + dx).rem_euclid(w as i64) as usize;
                out.push(y * w + xx);
            }
            continue;
        }
        for dx in -1i64..=1 {
            if dx == 0 && dy == 0 {
                continue;
            }
            let xx = (x as i64 + dx).rem_euclid(w as i64) as usize;
            out.push(yy as usize * w + xx);
        }
    }
    out.sort_unstable();
    out.dedup();
    out.retain(|&i| i != y * w + x);
}

/// Extracts up to `options.max_lights` compact bright sources from `env` (module docs).
/// Deterministic; `max_lights = 0` returns no light and `env` unchanged.
pub fn extract(env: &Environment, options: &LightOptions) -> Extraction {
    let (w, h) = (env.width as usize, env.height as usize);
    let grid = Geometry {
        width: env.width,
        height: env.height,
    };
    let omega: Vec<f64> = (0..h as u32).map(|y| grid.solid_angle(y)).collect();
    let lums: Vec<f64> = env.texels.iter().map(lum).collect();
    let total: f64 = lums.iter().enumerate().map(|(i, l)| l * omega[i / w]).sum();
    let mean = total / (4.0 * PI);
    let none = Extraction {
        lights: Vec::new(),
        residual: env.clone(),
        diffuse_residual: env.clone(),
    };
    let ok = |v: f64| v.is_finite() && v > 0.0;
    let bound = if options.max_diffuse_lights > 0 && options.max_diffuse_solid_angle.is_finite() {
        options.max_solid_angle.max(options.max_diffuse_solid_angle)
    } else {
        options.max_solid_angle
    };
    if options.max_lights + options.max_diffuse_lights == 0
        || !(ok(mean) && ok(options.threshold) && options.grow.is_finite())
        || options.max_solid_angle.is_nan()
        || options.max_solid_angle <= 0.0
    {
        return none;
    }
    let seed = options.threshold * mean;
    let grow = options.grow.clamp(0.0, 1.0) * seed;
    // Connected regions from the seeds (texel order: deterministic).
    let mut label = vec![usize::MAX; w * h];
    let mut regions: Vec<Vec<usize>> = Vec::new();
    let mut nb = Vec::with_capacity(9);
    // Brightest seed first: each region grows from its peak.
    let mut seeds: Vec<usize> = (0..w * h).filter(|&i| lums[i] > seed).collect();
    seeds.sort_by(|&a, &b| lums[b].total_cmp(&lums[a]).then(a.cmp(&b)));
    let peak_fraction = if options.peak_fraction.is_finite() {
        options.peak_fraction.clamp(0.0, 1.0)
    } else {
        0.0
    };
    for start in seeds {
        if label[start] != usize::MAX {
            continue;
        }
        let grow = grow.max(peak_fraction * lums[start]);
        let id = regions.len();
        let mut members = vec![start];
        label[start] = id;
        let mut k = 0;
        while k < members.len() {
            let i = members[k];
            k += 1;
            neighbours(i % w, i / w, w, h, &mut nb);
            for &j in &nb {
                if label[j] == usize::MAX && lums[j] > grow {
                    label[j] = id;
                    members.push(j);
                }
            }
        }
        members.sort_unstable();
        regions.push(members);
    }
    // Candidates: compact regions, their fill, power and spread.
    let mut candidates: Vec<(Light, [f32; 3], usize)> = Vec::new();
    for (id, members) in regions.iter().enumerate() {
        let solid: f64 = members.iter().map(|&i| omega[i / w]).sum();
        if solid > bound || members.len() > w * h / 4 {
            continue;
        }
        let mut ring_sum = [0.0f64; 3];
        let mut ring_omega = 0.0;
        let mut ring: Vec<usize> = Vec::new();
        for &i in members {
            neighbours(i % w, i / w, w, h, &mut nb);
            ring.extend(nb.iter().copied().filter(|&j| label[j] != id));
        }
        ring.sort_unstable();
        ring.dedup();
        for &j in &ring {
            for (sum, v) in ring_sum.iter_mut().zip(env.texels[j]) {
                *sum += v as f64 * omega[j / w];
            }
            ring_omega += omega[j / w];
        }
        let mut fill = [0.0f32; 3];
        for c in 0..3 {
            let ring_mean = if ring_omega > 0.0 {
                ring_sum[c] / ring_omega
            } else {
                0.0
            };
            let lowest = members
                .iter()
                .map(|&i| env.texels[i][c])
                .fold(f32::INFINITY, f32::min);
            fill[c] = (ring_mean as f32).min(lowest).max(0.0);
        }
        let mut power = [0.0f64; 3];
        let mut m = DVec3::ZERO;
        let mut weight = 0.0;
        for &i in members {
            let o = omega[i / w];
            let t = env.texels[i];
            let excess: [f64; 3] = std::array::from_fn(|c| t[c] as f64 - fill[c] as f64);
            for c in 0..3 {
                power[c] += excess[c] * o;
            }
            let wl = (0..3).map(|c| LUMINANCE[c] * excess[c]).sum::<f64>() * o;
            let (x, y) = ((i % w) as u32, (i / w) as u32);
            m += wl * grid.direction(x, y) * (1.0 - o / (4.0 * PI));
            weight += wl;
        }
        let light_lum: f64 = (0..3).map(|c| LUMINANCE[c] * power[c]).sum();
        if !(weight > 0.0 && light_lum >= options.min_share.max(0.0) * total) {
            continue;
        }
        let mean_dir = m / weight;
        let r = mean_dir.length().min(1.0);
        let var = crate::vmf::inverse_kappa(r);
        // Compact in spread too: a long thin region (a window's edge) has a small solid angle
        // but a wide vMF; its cap `4π/κ` is held to the same bound.
        let cap = 4.0 * PI * var;
        if cap > bound {
            continue;
        }
        let diffuse_only = solid > options.max_solid_angle || cap > options.max_solid_angle;
        candidates.push((
            Light {
                direction: mean_dir.try_normalize().unwrap_or(DVec3::Z),
                power,
                solid_angle: solid,
                kappa: if var > 0.0 { 1.0 / var } else { f64::INFINITY },
                texels: members.len(),
                diffuse_only,
            },
            fill,
            id,
        ));
    }
    // Most powerful first; ties by region order (deterministic).
    candidates.sort_by(|a, b| {
        b.0.luminance()
            .total_cmp(&a.0.luminance())
            .then(a.2.cmp(&b.2))
    });
    let (wide, compact): (Vec<_>, Vec<_>) = candidates.into_iter().partition(|c| c.0.diffuse_only);
    let compact: Vec<_> = compact.into_iter().take(options.max_lights).collect();
    let wide: Vec<_> = wide.into_iter().take(options.max_diffuse_lights).collect();
    let mut residual = env.clone();
    for (_, fill, id) in &compact {
        for &i in &regions[*id] {
            residual.texels[i] = *fill;
        }
    }
    let mut diffuse_residual = residual.clone();
    for (_, fill, id) in &wide {
        for &i in &regions[*id] {
            diffuse_residual.texels[i] = *fill;
        }
    }
    Extraction {
        lights: compact.into_iter().chain(wide).map(|c| c.0).collect(),
        residual,
        diffuse_residual,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::environment::{EnvOptions, Sky};

    fn power(env: &Environment) -> [f64; 3] {
        let grid = Geometry {
            width: env.width,
            height: env.height,
        };
        let w = env.width as usize;
        let mut p = [0.0; 3];
        for (i, t) in env.texels.iter().enumerate() {
            for c in 0..3 {
                p[c] += t[c] as f64 * grid.solid_angle((i / w) as u32);
            }
        }
        p
    }

    #[test]
    fn the_sky_s_sun_is_found_where_it_is_with_its_power_and_power_is_conserved() {
        for (width, sun_deg) in [
            (256u32, (55.0, 30.0)),
            (128, (2.0, -170.0)),
            (64, (80.0, 179.0)),
        ] {
            let sky = Sky {
                width,
                sun_deg,
                sun: [3.0e4, 1.5e4, 0.5e4],
                ..Sky::default()
            };
            let env = sky.render().unwrap();
            let ex = extract(&env, &LightOptions::default());
            assert_eq!(ex.lights.len(), 1, "{width} {sun_deg:?}: {:?}", ex.lights);
            let l = ex.lights[0];
            // Within a texel of the sun's direction.
            let texel = PI / env.height as f64;
            let angle = l.direction.angle_between(sky.sun_direction());
            assert!(
                angle < texel,
                "{width} {sun_deg:?}: {angle} vs texel {texel}"
            );
            // Its power within 1 % of the disc's exact L·2π(1 − cos r).
            let disc = 2.0 * PI * (1.0 - sky.sun_radius_deg.to_radians().cos());
            for c in 0..3 {
                let want = sky.sun[c] as f64 * disc;
                assert!(
                    (l.power[c] - want).abs() < 0.01 * want,
                    "{width} {sun_deg:?} channel {c}: {} vs {want}",
                    l.power[c]
                );
            }
            assert!(l.kappa.is_finite() && l.kappa > 1e3, "{}", l.kappa);
            // Residual + light = original, per channel, to 1e-9 relative.
            let (before, after) = (power(&env), power(&ex.residual));
            for c in 0..3 {
                let sum = after[c] + l.power[c];
                assert!(
                    (sum - before[c]).abs() <= 1e-9 * before[c],
                    "channel {c}: {sum} vs {}",
                    before[c]
                );
            }
            assert_eq!(ex.diffuse_residual, ex.residual);
            assert!(!l.diffuse_only);
            // The residual has no sun left: its brightest texel is sky.
            let top = ex.residual.texels.iter().map(lum).fold(0.0, f64::max);
            assert!(top < 2.0, "{top}");
        }
    }

    #[test]
    fn constant_sunless_and_black_environments_give_no_light() {
        let mk = |f: &dyn Fn(u32, u32) -> [f32; 3]| {
            let (w, h) = (64u32, 32u32);
            let t = (0..w * h).map(|i| f(i % w, i / w)).collect();
            Environment::from_rgb("t", w, h, t, &EnvOptions::default()).unwrap()
        };
        let sunless = Sky {
            width: 128,
            sun: [0.0; 3],
            ..Sky::default()
        }
        .render()
        .unwrap();
        for env in [
            mk(&|_, _| [1.0, 2.0, 3.0]),
            mk(&|_, _| [0.0; 3]),
            mk(&|x, y| [x as f32 * 0.1 + y as f32, 1.0, 0.5]),
            sunless,
        ] {
            let ex = extract(&env, &LightOptions::default());
            assert!(ex.lights.is_empty(), "{:?}", ex.lights);
            assert_eq!(ex.residual, env);
        }
        // max_lights = 0: nothing, even with a sun.
        let sky = Sky::default().render().unwrap();
        assert!(extract(&sky, &LightOptions::none()).lights.is_empty());
    }

    #[test]
    fn a_single_texel_sun_of_a_million_is_extracted_finite_and_exact() {
        // The stability suite's case, at the pole and on the seam too.
        for (x, y) in [(17u32, 9u32), (0, 0), (63, 31), (0, 16)] {
            let (w, h) = (64u32, 32u32);
            let mut t = vec![[0.5f32, 0.6, 0.7]; (w * h) as usize];
            t[(y * w + x) as usize] = [1.0e6; 3];
            let env = Environment::from_rgb("t", w, h, t, &EnvOptions::default()).unwrap();
            let ex = extract(&env, &LightOptions::default());
            assert_eq!(ex.lights.len(), 1);
            let l = ex.lights[0];
            let grid = Geometry {
                width: w,
                height: h,
            };
            let o = grid.solid_angle(y);
            for c in 0..3 {
                let want = (1.0e6 - [0.5, 0.6, 0.7][c] as f32 as f64) * o;
                assert!((l.power[c] - want).abs() <= 1e-9 * want, "{l:?}");
            }
            assert!(l.direction.angle_between(grid.direction(x, y)) < 1e-9);
            assert!(l.kappa.is_finite() && l.kappa > 0.0);
            assert_eq!(ex.residual.texels[(y * w + x) as usize], [0.5, 0.6, 0.7]);
        }
    }

    #[test]
    fn a_large_bright_region_is_not_a_light_and_the_strongest_come_first() {
        let (w, h) = (128u32, 64u32);
        let grid = Geometry {
            width: w,
            height: h,
        };
        let mut t = vec![[1.0f32; 3]; (w * h) as usize];
        // A bright patch (about 0.24 sr, far more than 0.05) and three small lamps.
        for x in 20..30 {
            for y in 28..38 {
                t[(y * w + x) as usize] = [2000.0; 3];
            }
        }
        for (k, (x, y)) in [(10u32, 10u32), (70, 20), (100, 50)]
            .into_iter()
            .enumerate()
        {
            t[(y * w + x) as usize] = [1.0e4 * (k + 1) as f32; 3];
        }
        let env = Environment::from_rgb("t", w, h, t, &EnvOptions::default()).unwrap();
        let ex = extract(
            &env,
            &LightOptions {
                min_share: 0.0,
                ..LightOptions::up_to(2)
            },
        );
        // Two compact lamps, then the patch as a diffuse-only light.
        assert_eq!(ex.lights.len(), 3, "{:?}", ex.lights);
        assert!(ex.lights[2].diffuse_only && !ex.lights[1].diffuse_only);
        assert!(ex.lights[2].direction.angle_between(grid.direction(25, 33)) < 0.05);
        assert_eq!(ex.diffuse_residual.texels[(30 * w + 25) as usize], [1.0; 3]);
        assert!(
            ex.lights[0]
                .direction
                .angle_between(grid.direction(100, 50))
                < 1e-9
        );
        assert!(ex.lights[1].direction.angle_between(grid.direction(70, 20)) < 1e-9);
        // The patch and the weakest lamp stay in the residual.
        assert_eq!(ex.residual.texels[(30 * w + 25) as usize], [2000.0; 3]);
        assert_eq!(ex.residual.texels[(10 * w + 10) as usize], [1.0e4; 3]);
    }
}
