//! The scene planner (issue 18, `docs/planner.md`): reads a [`Scene`] and the normal map, and
//! chooses the cheapest configuration that meets the scene's error target — which MIP levels
//! to ship, the method per level range (plain, Toksvig, SH l*, vMF J aligned or not), lobes
//! dropped, the storage format per texture, colour textures, and the shader's specialization —
//! with one line per decision saying what was left out and the error it saves or costs.
//!
//! The errors are *predicted by measurement*: every candidate configuration is baked on small
//! samples of the map and its texel-space error measured against the exact footprint average
//! ([`crate::eval`], DESIGN.md "Ground truth and error") under the scene's BRDFs and
//! light/view directions:
//! - levels up to `log2 C` on two aligned `C × C` crops (C = 128 at most): a crop aligned to a
//!   multiple of C has exactly the map's footprints at those levels, so the sample differs
//!   from the whole map only in which texels it holds;
//! - the coarser levels on the map subsampled with stride s (one normal per `s × s` cell, the
//!   cell's centre): its level `k − log2 s` covers the footprint of the map's level k with
//!   `(2^k / s)²` of its normals.
//!
//! Sits above the methods, eval, glsl and pack; below the CLI, the C API and the report.
//! [`execute`] bakes a plan (`ndfmap bake --plan`).

pub mod scene;

use crate::bake::{Bake, BakeOptions, Method};
use crate::brdf::Brdf;
use crate::error::{Error, Result};
use crate::eval::{LightView, direction};
use crate::format::Format;
use crate::glsl::{Sampling, ShaderBrdf, ShaderOptions, ShaderSpec, Stage};
use crate::ingest::{BadNormals, NormalMap};
pub use scene::Scene;
use serde::{Deserialize, Serialize};
use std::fmt::Write;

/// The plan file's `format` field.
pub const PLAN_FORMAT: &str = "ndfmap-plan";

/// Version of the plan file layout.
pub const PLAN_VERSION: u32 = 1;

/// A predicted error must lie at or below this fraction of the target for a configuration to
/// be chosen: the margin for the prediction's sampling error (measured within a factor 1.5 of
/// the whole map's error on the shared maps, `docs/planner.md`).
pub const MARGIN: f64 = 0.75;

/// A lobe whose weight α stays at or below this in every sampled texel of a level range is
/// dropped from that range.
pub const DROP_ALPHA: f64 = 0.02;

/// Albedo whose relative RMS variation (luminance) is at or below this is treated as constant:
/// colour textures are left out.
pub const COLOR_VARIATION: f64 = 0.01;

/// Side of the crops the planner measures (at most).
pub const CROP: u32 = 128;

/// Side of the small crops that stand for the finest levels (0 to [`FINE_LEVELS`] − 1) in
/// place of the `CROP` ones: those levels hold most of a crop's texels, and an RMS over a few
/// thousand texels from four places of the map predicts as well as one over tens of thousands
/// from two (the whole-map check in `docs/planner.md`) at a fraction of the shading.
pub const FINE_CROP: u32 = 32;

/// Levels measured on the [`FINE_CROP`] crops.
pub const FINE_LEVELS: usize = 3;

/// One configuration the planner can choose for a level range.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Config {
    /// The method.
    pub method: Method,
    /// Mixture lobes J: vMF, or Tan 2005's Gaussians (0 for the others).
    pub lobes: usize,
    /// SH band limit l* (0 for the others).
    pub lmax: usize,
    /// vMF and Tan 2005: aligned lobes (hardware trilinear filtering).
    pub aligned: bool,
}

impl Config {
    /// A label: `plain`, `toksvig`, `lean`, `olano`, `sh2`, `tan2a`, `vmf3a`, `vmf8`.
    pub fn label(&self) -> String {
        let a = if self.aligned { "a" } else { "" };
        match self.method {
            Method::Vmf => format!("vmf{}{a}", self.lobes),
            Method::Tan2005 => format!("tan{}{a}", self.lobes),
            Method::Sh => format!("sh{}", self.lmax),
            m => m.name().to_string(),
        }
    }

    /// Textures the method's shading reads (without colour).
    pub fn textures(&self) -> usize {
        match self.method {
            Method::Vmf | Method::Tan2005 => self.lobes,
            Method::Sh => crate::sh::texture_count(self.lmax),
            m => crate::methods::texture_layout(m, 0, false).len(),
        }
    }

    /// The bake options of this configuration.
    pub fn bake_options(&self) -> BakeOptions {
        let d = BakeOptions::default();
        BakeOptions {
            lobes: self.lobes.max(1),
            align: self.aligned.then(|| d.default_align_strength(self.method)),
            lmax: self.lmax,
            ..d
        }
    }

    /// Texture fetches per pixel of its shader (manual sampling reads 8 texels per texture).
    pub fn fetches(&self, color: bool) -> usize {
        let t = self.textures() * if color { 2 } else { 1 };
        if matches!(self.method, Method::Vmf | Method::Tan2005) && !self.aligned {
            8 * t
        } else {
            t
        }
    }
}

/// The full configuration every plan is measured against: vMF J = 8, aligned, f32, colour,
/// every level.
pub const FULL: Config = Config {
    method: Method::Vmf,
    lobes: 8,
    lmax: 0,
    aligned: true,
};

/// A level range of the plan and how it is baked.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Part {
    /// Finest level of the range (0 = the map's resolution).
    pub first: usize,
    /// Coarsest level of the range.
    pub last: usize,
    /// The method and its parameters.
    pub config: Config,
    /// vMF lobes (indices into the bake of `config.lobes`) left out of this range.
    pub dropped: Vec<usize>,
    /// The storage format of the method's textures.
    pub format: Format,
    /// Whether colour textures (`α·y` per lobe) are shipped.
    pub color: bool,
    /// Their storage format.
    pub color_format: Format,
    /// The largest predicted error over the range's levels.
    pub predicted: f64,
}

impl Part {
    /// Checks a part read from a plan file for what the planner never writes and a
    /// bake could not honour: a method the planner does not choose, a lobe count or band limit
    /// out of range, colour textures on a method without lobes, and left-out lobes that
    /// repeat, do not exist, or leave none. [`Error::InvalidOption`] naming the part and field.
    fn check(&self) -> Result<()> {
        let c = &self.config;
        let refuse = |what: String| {
            Err(Error::InvalidOption(format!(
                "part levels {}-{}: {what}",
                self.first, self.last
            )))
        };
        let mixture = matches!(c.method, Method::Vmf | Method::Tan2005);
        match c.method {
            Method::Vmf | Method::Tan2005 if !(1..=crate::em::MAX_LOBES).contains(&c.lobes) => {
                return refuse(format!(
                    "lobe count {} (expected 1 to {})",
                    c.lobes,
                    crate::em::MAX_LOBES
                ));
            }
            Method::Sh if c.lmax > crate::sh::MAX_LMAX => {
                return refuse(format!(
                    "SH band limit {} (expected 0 to {})",
                    c.lmax,
                    crate::sh::MAX_LMAX
                ));
            }
            Method::Pbr => return refuse("method pbr is not one a plan bakes".into()),
            _ => {}
        }
        if self.color && !mixture {
            return refuse(format!(
                "colour textures on a {} part (only vMF and Tan 2005 parts carry them)",
                c.method
            ));
        }
        if !self.dropped.is_empty() && !mixture {
            return refuse(format!(
                "left-out lobes on a {} part (only mixtures have lobes)",
                c.method
            ));
        }
        if mixture && self.dropped.len() >= c.lobes {
            return refuse(format!(
                "{} left-out lobes of {} (at least one lobe must stay)",
                self.dropped.len(),
                c.lobes
            ));
        }
        for (i, &j) in self.dropped.iter().enumerate() {
            if j >= c.lobes || self.dropped[..i].contains(&j) {
                return refuse(format!(
                    "left-out lobe {j} (expected distinct lobe indices below {})",
                    c.lobes
                ));
            }
        }
        Ok(())
    }

    /// Lobe (or method) textures shipped.
    pub fn textures(&self) -> usize {
        self.config.textures() - self.dropped.len()
    }

    /// Texture fetches per pixel of its shader: [`Config::fetches`] less the lobes (and their
    /// colour textures) left out.
    fn fetches(&self) -> usize {
        self.config.fetches(self.color) - self.dropped.len() * (1 + usize::from(self.color))
    }

    /// Its texture bytes on a `w × h` map, colour textures included.
    fn bytes(&self, (w, h): (u32, u32)) -> u64 {
        let levels = [self.first, self.last];
        bytes(w, h, levels, self.textures(), self.format)
            + if self.color {
                bytes(w, h, levels, self.textures(), self.color_format)
            } else {
                0
            }
    }
}

/// The map a plan was made for.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct MapId {
    /// The file, if known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub path: Option<String>,
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// [`content_hash`] of its normals, hexadecimal.
    pub hash: String,
}

/// What the plan's shaders are specialized for.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShaderPlan {
    /// The BRDF model compiled in (`lambert` removes the specular path; `ggx`,
    /// `torrance-sparrow` select theirs).
    pub brdf: String,
    /// Whether the diffuse (Lambert) term is used (K_d > 0).
    pub diffuse: bool,
    /// Whether the specular term is used.
    pub specular: bool,
    /// Anisotropic filtering (probes per pixel), if the scene asks for it.
    pub anisotropic: Option<u32>,
    /// Whether the scene has an environment: the plan's errors were measured under it with
    /// its compact bright sources extracted as lights ([`Scene::environment_light`]) and the
    /// rest by the prefiltered route (one prefiltered-environment lookup per lobe), which its
    /// shaders then use (`NDF_LIGHT_ENV_PREFILTERED`).
    pub environment: bool,
    /// How many lights (compact and diffuse-only) were extracted from the environment when
    /// planning ([`Scene::environment_light`]); the shaders add them (`NDF_ENV_LIGHTS`,
    /// [`ShaderOptions::env_lights`]) when there are any — an environment without a sun or
    /// lamp (the overcast sky) keeps the shaders without the light loop. Absent (0) in plans
    /// of environments without lights and of earlier versions (measured without extraction).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub env_lights: usize,
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

/// One level's prediction.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LevelPrediction {
    /// MIP level.
    pub level: usize,
    /// The target there.
    pub target: f64,
    /// The configuration chosen (label).
    pub chosen: String,
    /// Its predicted error (the largest over the terms the scene uses).
    pub predicted: f64,
    /// The full configuration's predicted error.
    pub full: f64,
}

/// A plan: what to bake for a scene, and why.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    /// Always [`PLAN_FORMAT`].
    pub format: String,
    /// [`PLAN_VERSION`].
    pub version: u32,
    /// The map it was made for.
    pub map: MapId,
    /// The scene.
    pub scene: Scene,
    /// The levels shipped, `[finest, coarsest]`.
    pub levels: [usize; 2],
    /// The level ranges, finest first, covering `levels`.
    pub parts: Vec<Part>,
    /// The shaders' specialization.
    pub shader: ShaderPlan,
    /// One line per decision.
    pub decisions: Vec<String>,
    /// Per level shipped, the prediction.
    pub predictions: Vec<LevelPrediction>,
    /// Texture bytes of the plan (every shipped level, every texture).
    pub bytes: u64,
    /// Texture bytes of the full configuration ([`FULL`], f32, colour, every level).
    pub full_bytes: u64,
    /// Seconds the planning took.
    pub seconds: f64,
}

/// A 64-bit FNV-1a hash of the map's size and normals' bits, hexadecimal: what `bake --plan`
/// compares to refuse a plan made for another map.
pub fn content_hash(map: &NormalMap) -> String {
    let mut h: u64 = 0xcbf29ce484222325;
    let mut eat = |bytes: &[u8]| {
        for &b in bytes {
            h ^= b as u64;
            h = h.wrapping_mul(0x100000001b3);
        }
    };
    eat(&map.width().to_le_bytes());
    eat(&map.height().to_le_bytes());
    for n in map.normals() {
        for c in n.to_array() {
            eat(&c.to_bits().to_le_bytes());
        }
    }
    format!("{h:016x}")
}

/// The light/view pairs the planner measures for `scene`'s point and directional lights:
/// elevations at the two ends and the middle of `light_elevation` (default 10°–90°) at four
/// azimuths; views at 0°, 35° and 70°. Empty for a scene lit only by an environment (which is
/// measured under the environment itself, [`EnvMeasure`]).
pub fn directions(scene: &Scene) -> Vec<LightView> {
    let mut lights = Vec::new();
    if scene.has_direct() {
        let [lo, hi] = scene.light_elevation.unwrap_or([10.0, 90.0]);
        let mut elevations = vec![lo, 0.5 * (lo + hi), hi];
        elevations.dedup();
        for e in elevations {
            if e >= 90.0 {
                lights.push(direction(0.0, 0.0));
                continue;
            }
            for phi in [0.0, 90.0, 180.0, 270.0] {
                lights.push(direction(90.0 - e, phi));
            }
        }
    }
    let mut out = Vec::new();
    for view in [0.0, 35.0, 70.0] {
        for &l in &lights {
            out.push((l, direction(view, 0.0)));
        }
    }
    out.dedup();
    out
}

/// The samples a plan measures: maps and, per map level, the map level it stands for.
struct Samples {
    maps: Vec<(NormalMap, Vec<Option<usize>>)>,
    /// Per map, how many maps stand for the same levels (they share the environment's
    /// ground-truth texels).
    share: Vec<usize>,
}

fn crop(map: &NormalMap, x0: u32, y0: u32, c: u32) -> Result<NormalMap> {
    let w = map.width();
    let normals = (0..c)
        .flat_map(|y| (0..c).map(move |x| (x, y)))
        .map(|(x, y)| map.normals()[((y0 + y) * w + x0 + x) as usize])
        .collect();
    NormalMap::from_vectors(c, c, normals, map.addressing(), BadNormals::Repair)
}

/// Builds the measurement samples of `map` for levels `0..levels`.
fn samples(map: &NormalMap, levels: usize) -> Result<Samples> {
    let (w, h) = (map.width(), map.height());
    let side = w.min(h);
    let mut c = 1u32;
    while c * 2 <= side.min(CROP) {
        c *= 2;
    }
    let crop_levels = c.trailing_zeros() as usize; // levels 0..=crop_levels are exact
    let mut maps = Vec::new();
    if w == c && h == c {
        let own = (0..levels).map(Some).collect();
        maps.push((map.clone(), own));
        return Ok(Samples {
            maps,
            share: vec![1],
        });
    }
    // Two crops: the top-left one and one near the centre, aligned to multiples of c.
    let positions = [(0, 0), ((w / 2 / c) * c, (h / 2 / c) * c)];
    for (i, &(x, y)) in positions.iter().enumerate() {
        if i == 1 && (x, y) == (0, 0) {
            break;
        }
        let m = crop(map, x.min(w - c), y.min(h - c), c)?;
        let stands: Vec<Option<usize>> = (0..=crop_levels)
            .map(|k| (k < levels).then_some(k))
            .collect();
        maps.push((m, stands));
    }
    let mut share = vec![maps.len(); maps.len()];
    // The finest levels on four small crops instead (when the map is large enough that they
    // are fewer texels than the big crops' levels): the big crops stand for the rest.
    if c >= 4 * FINE_CROP && w >= 2 * c && h >= 2 * c && levels > 0 {
        for (_, stands) in &mut maps {
            for s in stands.iter_mut().take(FINE_LEVELS) {
                *s = None;
            }
        }
        let f = FINE_CROP;
        // Four places spread over the map (eighths), aligned to multiples of the crop.
        let spots = [(1u32, 5u32), (5, 1), (3, 3), (7, 7)];
        for (a, b) in spots {
            let (x, y) = ((w / 8 * a / f) * f, (h / 8 * b / f) * f);
            let m = crop(map, x.min(w - f), y.min(h - f), f)?;
            let count = crate::pyramid::level_sizes(f, f).len();
            let stands = (0..count)
                .map(|k| (k < FINE_LEVELS && k < levels).then_some(k))
                .collect();
            maps.push((m, stands));
            share.push(spots.len());
        }
    }
    // The coarser levels: the map subsampled with stride s (a power of two).
    if levels > crop_levels + 1 {
        let mut s = 1u32;
        while side / (s * 2) >= c {
            s *= 2;
        }
        let shift = s.trailing_zeros() as usize;
        let (sw, sh) = (w / s, h / s);
        let normals = (0..sh)
            .flat_map(|y| (0..sw).map(move |x| (x, y)))
            .map(|(x, y)| map.normal(x * s + s / 2, y * s + s / 2))
            .collect();
        let m = NormalMap::from_vectors(sw, sh, normals, map.addressing(), BadNormals::Repair)?;
        let count = crate::pyramid::level_sizes(sw, sh).len();
        let stands: Vec<Option<usize>> = (0..count)
            .map(|k| {
                let level = k + shift;
                (level > crop_levels && level < levels).then_some(level)
            })
            .collect();
        maps.push((m, stands));
        share.push(1);
    }
    Ok(Samples { maps, share })
}

/// A candidate's measured errors: per map level, (diffuse, specular) relative RMS, the
/// specular one the largest over the BRDFs; `None` where no sample stands for the level.
#[derive(Debug, Clone)]
struct Measured {
    levels: Vec<Option<(f64, f64)>>,
    /// Per map level, per lobe, the largest α seen (vMF).
    alpha_max: Vec<Vec<f64>>,
}

impl Measured {
    /// The error the scene sees at `level`: the largest over the terms it uses.
    fn error(&self, level: usize, scene: &Scene) -> f64 {
        let Some((d, s)) = self.levels.get(level).copied().flatten() else {
            return f64::INFINITY;
        };
        let (kd, _) = scene.kd_ks();
        let mut e: f64 = 0.0;
        if kd > 0.0 {
            e = e.max(d);
        }
        if scene.specular() {
            e = e.max(s);
        }
        e
    }

    /// The largest [`Measured::error`] over `levels`.
    fn worst(&self, levels: std::ops::RangeInclusive<usize>, scene: &Scene) -> f64 {
        levels.map(|k| self.error(k, scene)).fold(0.0, f64::max)
    }

    /// Whether every level of `levels` meets its target with the [`MARGIN`] (`first`: the
    /// scene's finest level, which its per-level targets count from).
    fn meets(&self, levels: std::ops::RangeInclusive<usize>, scene: &Scene, first: usize) -> bool {
        levels
            .into_iter()
            .all(|k| self.error(k, scene) <= MARGIN * scene.target_at(first, k))
    }
}

/// The lobe count of the aligned vMF candidate measured first when the planner reaches the
/// cheaper vMF candidates at a level: where it misses, the vMF candidates with fewer lobes are
/// not measured there (more lobes fit no worse).
pub const PROBE_LOBES: usize = 4;

/// Ground-truth samples per texel and view of the planner's environment measurement (the
/// prediction; its Monte Carlo noise is taken out of each level's error, `envlight::denoised`).
pub const ENV_SAMPLES: usize = 256;
/// Texels drawn per level of each sample map under an environment.
pub const ENV_TEXELS: usize = 32;
/// Ground-truth samples per texel and view of `plan --verify` and the report
/// ([`WholeMap`]): the measurement the prediction is checked against.
pub const VERIFY_ENV_SAMPLES: usize = 512;

/// The environment a scene is measured under: its light, and the ground truth of every
/// sample map ([`crate::envlight::Reference`], computed once, scored against every
/// candidate). Configurations are shaded by the prefiltered route (vMF: one lookup per lobe;
/// the baselines: their single lobe) or, for SH bakes, eq 25/26.
pub struct EnvMeasure {
    /// The environment's luminance, ready to light with.
    pub light: crate::envlight::EnvLight,
    /// Per sample map (in [`Samples`] order), its ground truth (`None` for a sample that
    /// stands for none of the scene's levels).
    references: Vec<Option<crate::envlight::Reference>>,
}

impl EnvMeasure {
    /// The ground truth of `maps` under `light` for `brdfs` (the views of
    /// [`crate::envlight::default_views`], [`ENV_SAMPLES`] samples), from level `first[i]` of
    /// map i on, `texels[i]` texels per level (the crops standing for the same levels share
    /// [`ENV_TEXELS`] between them: measuring each with all of them computed the same level's
    /// ground truth once per crop, the planner's costliest step under an environment).
    fn new(
        light: crate::envlight::EnvLight,
        maps: &[&NormalMap],
        brdfs: &[Brdf],
        first: &[Option<usize>],
        texels: &[usize],
    ) -> Result<EnvMeasure> {
        let references = maps
            .iter()
            .zip(first)
            .zip(texels)
            .map(|((map, &first_level), &texels_per_level)| {
                // A sample standing for none of the scene's levels is never measured.
                let Some(first_level) = first_level else {
                    return Ok(None);
                };
                let options = crate::envlight::EvalOptions {
                    first_level,
                    texels_per_level,
                    samples: ENV_SAMPLES,
                    ..Default::default()
                };
                crate::envlight::Reference::new(map, brdfs, &light, &options).map(Some)
            })
            .collect::<Result<_>>()?;
        Ok(EnvMeasure { light, references })
    }

    /// [`environment_errors`] of `bake` against sample map `i`'s reference, at the sample
    /// map's levels `levels`.
    fn errors(
        &self,
        i: usize,
        bake: &Bake,
        levels: std::ops::RangeInclusive<usize>,
    ) -> Result<Vec<Option<(f64, f64)>>> {
        match &self.references[i] {
            Some(r) => environment_errors(r, &self.light, bake, levels),
            None => Ok(Vec::new()),
        }
    }
}

/// Per level of the reference's map: (diffuse, specular) relative RMS of `bake` under the
/// environment `light` by the prefiltered route, the specular one the largest over the
/// reference's BRDFs, with the ground truth's own noise taken out
/// ([`crate::envlight::denoised`]); `None` below the reference's first level.
pub fn environment_errors(
    reference: &crate::envlight::Reference,
    light: &crate::envlight::EnvLight,
    bake: &Bake,
    levels: std::ops::RangeInclusive<usize>,
) -> Result<Vec<Option<(f64, f64)>>> {
    let e = reference.score_levels(
        &[bake],
        light,
        &[crate::envlight::Route::Prefiltered],
        levels,
    )?;
    let mut out = Vec::new();
    for (err, b) in e.errors.iter().zip(0..) {
        for (&(k, d, sp), (k2, nd, ns)) in err.levels.iter().zip(&e.level_noise) {
            debug_assert_eq!(k, *k2);
            let d = crate::envlight::denoised(d, *nd);
            let sp = crate::envlight::denoised(sp, ns[b]);
            if out.len() <= k {
                out.resize(k + 1, None);
            }
            let (d0, s0) = out[k].unwrap_or((0.0f64, 0.0f64));
            out[k] = Some((d0.max(d), s0.max(sp)));
        }
    }
    Ok(out)
}

/// Measures bakes of a map on the whole map as a plan's scene sees them: the texel-space
/// error per level against the exact footprint average under its point/directional lights
/// ([`crate::eval::evaluate_from`]) and against a Monte Carlo ground truth under its
/// environment ([`environment_errors`]), the largest over the terms the scene uses and its
/// BRDFs. What `plan --verify`, the report's planner section and the tests measure.
pub struct WholeMap<'a> {
    plan: &'a Plan,
    map: &'a NormalMap,
    brdfs: Vec<Brdf>,
    directions: Vec<LightView>,
    env: Option<(crate::envlight::EnvLight, crate::envlight::Reference)>,
    levels: usize,
}

impl<'a> WholeMap<'a> {
    /// The measurement of `plan`'s scene on `map`; under an environment, its ground truth on
    /// `env_texels` texels per level from the plan's first level ([`VERIFY_ENV_SAMPLES`]
    /// samples).
    pub fn new(plan: &'a Plan, map: &'a NormalMap, env_texels: usize) -> Result<WholeMap<'a>> {
        let brdfs = plan.scene.brdfs();
        let sh_route = plan
            .scene
            .needs_sh_route(plan.parts.iter().map(|p| p.config.method));
        let env = match plan.scene.environment_light(sh_route)? {
            Some(light) => {
                let options = crate::envlight::EvalOptions {
                    first_level: plan.levels[0],
                    texels_per_level: env_texels,
                    samples: VERIFY_ENV_SAMPLES,
                    ..Default::default()
                };
                let reference = crate::envlight::Reference::new(map, &brdfs, &light, &options)?;
                Some((light, reference))
            }
            None => None,
        };
        Ok(WholeMap {
            plan,
            map,
            directions: directions(&plan.scene),
            brdfs,
            env,
            levels: crate::pyramid::level_sizes(map.width(), map.height()).len(),
        })
    }

    /// The scene's error at every level of `bake` (a bake of the map) in `from..=to` (0
    /// outside; levels the environment's ground truth does not measure count 0).
    pub fn errors(&self, bake: &Bake, from: usize, to: usize) -> Result<Vec<f64>> {
        let scene = &self.plan.scene;
        let (kd, _) = scene.kd_ks();
        let mut v = vec![0.0f64; self.levels];
        if !self.directions.is_empty() {
            let errors =
                crate::eval::evaluate_from(self.map, &[bake], &self.brdfs, &self.directions, from);
            for (k, a) in v.iter_mut().enumerate().skip(from) {
                for e in &errors {
                    if kd > 0.0 {
                        *a = a.max(e.levels[k].diffuse);
                    }
                    if scene.specular() {
                        *a = a.max(e.levels[k].specular);
                    }
                }
            }
        }
        if let Some((light, reference)) = &self.env {
            let errors = environment_errors(reference, light, bake, from..=to)?;
            for (k, x) in errors.iter().enumerate() {
                let Some((d, s)) = *x else { continue };
                if !(from..=to).contains(&k) {
                    continue;
                }
                if kd > 0.0 {
                    v[k] = v[k].max(d);
                }
                if scene.specular() {
                    v[k] = v[k].max(s);
                }
            }
        }
        Ok(v)
    }
}

/// What [`Measure::run`] does to a sample bake before measuring it (quantize, drop lobes).
type Edit = dyn Fn(Bake) -> Result<Bake> + Sync;

/// The environment's errors of one crop per level (diffuse, specular), as
/// [`EnvMeasure::errors`] gives them.
type EnvErrors = Vec<Option<(f64, f64)>>;

/// The measurement context: samples, BRDFs, directions, and the sample bakes of every
/// configuration measured so far (each configuration is baked once; quantizing and dropping
/// lobes edit a copy).
struct Measure<'a> {
    samples: &'a Samples,
    brdfs: Vec<Brdf>,
    /// Per sample map, the exact footprint averages under the point/directional lights,
    /// computed once and scored against every candidate ([`crate::eval::Reference`]; empty
    /// for a scene lit only by an environment).
    exact: Vec<Option<crate::eval::Reference>>,
    /// The environment, when the scene has one.
    env: Option<EnvMeasure>,
    levels: usize,
    /// The finest map level measured.
    from: usize,
    bakes: std::sync::Mutex<Vec<(Config, usize, std::sync::Arc<Bake>)>>,
}

impl Measure<'_> {
    /// The bake of `config` on sample map `i`, baked on first use (a sample map standing for
    /// none of the levels measured is never baked: a scene whose finest level is coarse skips
    /// the fine crops).
    fn bake(&self, config: Config, i: usize) -> Result<std::sync::Arc<Bake>> {
        let cached = |bakes: &[(Config, usize, std::sync::Arc<Bake>)]| {
            bakes
                .iter()
                .find(|(c, j, _)| *c == config && *j == i)
                .map(|(_, _, b)| b.clone())
        };
        if let Some(b) = cached(&self.bakes.lock().expect("no panic holds the lock")) {
            return Ok(b);
        }
        let map = &self.samples.maps[i].0;
        let b = std::sync::Arc::new(crate::methods::bake_with(
            map,
            config.method,
            &config.bake_options(),
        )?);
        // Each (config, crop) is baked by one call of `run_from` only, so no other thread
        // has put it there since.
        self.bakes
            .lock()
            .expect("no panic holds the lock")
            .push((config, i, b.clone()));
        Ok(b)
    }

    /// Measures `config`'s sample bakes after `edit` (quantizing, dropping lobes), at map
    /// levels `from` and coarser.
    fn run(&self, config: Config, edit: &Edit) -> Result<Measured> {
        self.run_from(config, edit, self.from, usize::MAX)
    }

    /// [`Measure::run_from`] of `config`'s bakes as a part ships them: without the lobes
    /// `dropped`, stored in `format`.
    fn run_stored(
        &self,
        config: Config,
        dropped: &[usize],
        format: Format,
        from: usize,
        to: usize,
    ) -> Result<Measured> {
        let dropped = dropped.to_vec();
        let edit = move |b| crate::pack::quantize_into(drop_lobes(b, &dropped), format);
        self.run_from(config, &edit, from, to)
    }

    /// [`Measure::run`] at map levels `from..=to` only (a level range's own checks; the
    /// other levels are unmeasured).
    fn run_from(&self, config: Config, edit: &Edit, from: usize, to: usize) -> Result<Measured> {
        use rayon::prelude::*;
        /// One crop's errors: its levels `first..=last`, the bake (for the lobes' α), the
        /// per-BRDF texel-space errors and the environment's.
        type CropErrors = (usize, usize, Bake, Vec<crate::eval::MethodError>, EnvErrors);
        // The crops are measured in parallel (each is small: their bakes and errors alone
        // leave a core idle), then summed in crop order, so the result does not depend on the
        // thread count.
        let crops: Vec<Option<CropErrors>> = self
            .samples
            .maps
            .par_iter()
            .enumerate()
            .map(|(i, (_, stands))| -> Result<Option<CropErrors>> {
                let inside = |l: &Option<usize>| l.is_some_and(|l| (from..=to).contains(&l));
                let Some(first) = stands.iter().position(inside) else {
                    return Ok(None);
                };
                let last = stands.iter().rposition(inside).unwrap_or(first);
                let bake = edit(Bake::clone(&*self.bake(config, i)?))?;
                let errors = match self.exact.get(i).and_then(Option::as_ref) {
                    Some(exact) => exact.evaluate_levels(&[&bake], first..=last),
                    None => Vec::new(),
                };
                let env = match &self.env {
                    Some(env) => env.errors(i, &bake, first..=last)?,
                    None => Vec::new(),
                };
                Ok(Some((first, last, bake, errors, env)))
            })
            .collect::<Result<_>>()?;
        // Per map level: Σ squared relative errors over samples, count.
        let mut acc = vec![(0.0f64, 0.0f64, 0usize); self.levels];
        let mut alpha_max = vec![Vec::<f64>::new(); self.levels];
        for ((_, stands), crop) in self.samples.maps.iter().zip(crops) {
            let Some((first, last, bake, errors, env)) = crop else {
                continue;
            };
            for (k, level) in stands.iter().enumerate().take(last + 1).skip(first) {
                let Some(level) = *level else { continue };
                let (ed, es) = env.get(k).copied().flatten().unwrap_or((0.0, 0.0));
                let d = errors
                    .iter()
                    .map(|e| e.levels[k].diffuse)
                    .fold(ed, f64::max);
                let s = errors
                    .iter()
                    .map(|e| e.levels[k].specular)
                    .fold(es, f64::max);
                acc[level].0 += d * d;
                acc[level].1 += s * s;
                acc[level].2 += 1;
                if bake.lobes > 0 {
                    let a = &mut alpha_max[level];
                    a.resize(bake.lobes, 0.0);
                    for (j, t) in bake.textures[..bake.lobes].iter().enumerate() {
                        let m = t.levels[k].iter().map(|v| v[0] as f64).fold(0.0, f64::max);
                        a[j] = a[j].max(m);
                    }
                }
            }
        }
        let levels = acc
            .into_iter()
            .map(|(d, s, n)| (n > 0).then(|| ((d / n as f64).sqrt(), (s / n as f64).sqrt())))
            .collect();
        Ok(Measured { levels, alpha_max })
    }
}

/// The candidates, cheapest first (fewest textures; at equal count the cheaper shading: the
/// moment baselines LEAN (2 textures) and Olano–North (3) before the vMF mixture of as many
/// textures, Tan 2005's aligned Gaussian mixtures (J = 2, 4) after it — the paper's Fig 6 has
/// vMF ahead at equal lobe count). The environment routes shade every one of them
/// (`envlight::check_method`), but an environment-lit scene leaves Tan 2005 out: scoring its
/// two fits under the environment took the mixed scene's plan from 1.05 to 1.55 s and changed
/// none of the four scenes' plans (docs/planner.md).
fn candidates(scene: &Scene) -> Vec<Config> {
    let c = |method, lobes, lmax, aligned| Config {
        method,
        lobes,
        lmax,
        aligned,
    };
    let mut out = vec![
        c(Method::Plain, 0, 0, false),
        c(Method::Toksvig, 0, 0, false),
    ];
    // SH for low-frequency materials: the band limit of the sharpest BRDF (Sec 5.1), when
    // it needs at most 4 textures (l* ≤ 3).
    let lmax = scene
        .brdfs()
        .iter()
        .map(|b| b.suggested_lmax())
        .max()
        .unwrap_or(2);
    // (Not under an environment alone: the environment shaders have no SH-bake variant.)
    let env_only = scene.has_environment() && !scene.has_direct();
    let sh = (lmax <= 3 && !env_only).then(|| c(Method::Sh, 0, lmax, false));
    for j in [1, 2, 3, 4, 6, 8] {
        if let Some(s) = sh
            && s.textures() <= j
            && !out.contains(&s)
        {
            out.push(s);
        }
        if j == 2 {
            out.push(c(Method::Lean, 0, 0, false));
        }
        if j == 3 {
            out.push(c(Method::Olano, 0, 0, false));
        }
        out.push(c(Method::Vmf, j, 0, true));
        if (j == 2 || j == 4) && !scene.has_environment() {
            out.push(c(Method::Tan2005, j, 0, true));
        }
    }
    if let Some(s) = sh
        && !out.contains(&s)
    {
        out.push(s);
    }
    if !scene.view.anisotropic {
        // Unaligned lobes need manual sampling (8 fetches per texture): last resort.
        out.push(c(Method::Vmf, 8, 0, false));
    }
    out
}

/// Texture bytes of `textures` RGBA textures of `format` over `levels` of a `w × h` map.
fn bytes(w: u32, h: u32, levels: [usize; 2], textures: usize, format: Format) -> u64 {
    let texels: u64 = crate::pyramid::level_sizes(w, h)
        .iter()
        .enumerate()
        .filter(|(k, _)| (levels[0]..=levels[1]).contains(k))
        .map(|(_, &(w, h))| w as u64 * h as u64)
        .sum();
    texels * textures as u64 * 4 * format.channel_bytes() as u64
}

/// The relative RMS variation of the albedo's luminance (0 for a constant albedo).
pub fn color_variation(albedo: &[[f32; 4]]) -> f64 {
    let lum: Vec<f64> = albedo
        .iter()
        .map(|c| 0.2126 * c[0] as f64 + 0.7152 * c[1] as f64 + 0.0722 * c[2] as f64)
        .collect();
    let n = lum.len().max(1) as f64;
    let mean = lum.iter().sum::<f64>() / n;
    let var = lum.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / n;
    if mean > 0.0 { var.sqrt() / mean } else { 0.0 }
}

fn pct(e: f64) -> String {
    if e.is_finite() {
        format!("{:.2} %", 100.0 * e)
    } else {
        "unmeasured".into()
    }
}

/// Plans `map` for `scene` (`path`: the map's file, recorded). The map's feature image, if
/// any, is the albedo whose variation decides the colour textures (else `scene.color.varies`).
pub fn plan(map: &NormalMap, scene: &Scene, path: Option<&str>) -> Result<Plan> {
    scene.check()?;
    let start = std::time::Instant::now();
    let (w, h) = (map.width(), map.height());
    let sizes = crate::pyramid::level_sizes(w, h);
    let nl = sizes.len();
    let range = scene.level_range(nl)?;
    let mut decisions = Vec::new();
    let full_bytes = bytes(w, h, [0, nl - 1], 2 * FULL.lobes, Format::F32);

    // Levels.
    if range[0] > 0 {
        decisions.push(format!(
            "levels 0-{}: left out (the scene never samples them): saves {} bytes of the full \
             configuration, no error",
            range[0] - 1,
            bytes(w, h, [0, range[0] - 1], 2 * FULL.lobes, Format::F32)
        ));
    }
    if range[1] + 1 < nl {
        decisions.push(format!(
            "levels {}-{}: left out (coarser than the scene samples): saves {} bytes, no error",
            range[1] + 1,
            nl - 1,
            bytes(w, h, [range[1] + 1, nl - 1], 2 * FULL.lobes, Format::F32)
        ));
    }

    // Measure.
    let measure_levels = range[1] + 1;
    let samples = samples(map, measure_levels)?;
    // The SH route's L′ tables only when an SH candidate is measured under a specular BRDF.
    let sh_route = scene.needs_sh_route(candidates(scene).iter().map(|c| c.method));
    let env = match scene.environment_light(sh_route)? {
        Some(light) => {
            let maps: Vec<&NormalMap> = samples.maps.iter().map(|(m, _)| m).collect();
            let first: Vec<Option<usize>> = samples
                .maps
                .iter()
                .map(|(_, stands)| stands.iter().position(|l| l.is_some_and(|l| l >= range[0])))
                .collect();
            let texels: Vec<usize> = samples
                .share
                .iter()
                .map(|&n| ENV_TEXELS.div_ceil(n.max(1)))
                .collect();
            Some(EnvMeasure::new(
                light,
                &maps,
                &scene.brdfs(),
                &first,
                &texels,
            )?)
        }
        None => None,
    };
    let dirs = directions(scene);
    let exact = if dirs.is_empty() {
        Vec::new()
    } else {
        use rayon::prelude::*;
        samples
            .maps
            .par_iter()
            .map(|(map, stands)| {
                stands
                    .iter()
                    .position(|l| l.is_some_and(|l| l >= range[0]))
                    .map(|first| crate::eval::Reference::new(map, &scene.brdfs(), &dirs, first))
            })
            .collect()
    };
    let env_lights = env.as_ref().map_or(0, |e| e.light.lights().len());
    let m = Measure {
        samples: &samples,
        brdfs: scene.brdfs(),
        exact,
        env,
        levels: measure_levels,
        from: range[0],
        bakes: Default::default(),
    };
    let cands = candidates(scene);
    let mut measured: Vec<Option<Measured>> = vec![None; cands.len()];
    let keep = |b: Bake| Ok(b);
    let full_index = cands.iter().position(|c| *c == FULL);
    let full_measured = m.run(FULL, &keep)?;
    if let Some(i) = full_index {
        measured[i] = Some(full_measured.clone());
    }

    // Per level: the cheapest candidate that meets the target with the margin.
    let mut chosen: Vec<usize> = Vec::new();
    for level in range[0]..=range[1] {
        let target = scene.target_at(range[0], level);
        let mut pick = None;
        let mut best: Option<(usize, f64)> = None;
        for (i, c) in cands.iter().enumerate() {
            // A vMF candidate is not measured at a level where an aligned vMF with more lobes
            // already misses (more lobes fit no worse): reaching the first cheap vMF, the one
            // of PROBE_LOBES is measured first, so that a scene needing more skips the fewer.
            let dominated = |measured: &[Option<Measured>]| {
                c.method == Method::Vmf
                    && cands.iter().zip(measured).any(|(d, x)| {
                        d.method == Method::Vmf
                            && d.aligned
                            && d.lobes > c.lobes
                            && x.as_ref()
                                .is_some_and(|x| x.error(level, scene) > MARGIN * target)
                    })
            };
            if measured[i].is_none() && c.method == Method::Vmf && c.lobes < PROBE_LOBES {
                let probe = cands
                    .iter()
                    .position(|d| d.method == Method::Vmf && d.aligned && d.lobes == PROBE_LOBES);
                if let Some(p) = probe
                    && measured[p].is_none()
                {
                    measured[p] = Some(m.run(cands[p], &keep)?);
                }
            }
            if dominated(&measured) {
                continue;
            }
            if measured[i].is_none() {
                measured[i] = Some(m.run(*c, &keep)?);
            }
            let e = measured[i]
                .as_ref()
                .map_or(f64::INFINITY, |x| x.error(level, scene));
            if best.is_none_or(|(_, b)| e < b) {
                best = Some((i, e));
            }
            if e <= MARGIN * target {
                pick = Some(i);
                break;
            }
        }
        let i = match pick {
            Some(i) => i,
            None => {
                let (i, e) = best.unwrap_or((cands.len() - 1, f64::INFINITY));
                decisions.push(format!(
                    "level {level}: no configuration is predicted to meet {} (with the margin \
                     {MARGIN}): {} chosen, predicted {}",
                    pct(target),
                    cands[i].label(),
                    pct(e)
                ));
                i
            }
        };
        chosen.push(i);
    }

    // Colour.
    let color_measured = map.feature().map(color_variation);
    // The same under an environment: its shaders read the eq 22 colour textures too.
    let color = match color_measured {
        Some(v) => v > COLOR_VARIATION,
        None => scene.color.varies,
    };

    // One vMF bake for the plan: every aligned vMF range reads the bake with the most lobes
    // any level needs (one bake instead of one per lobe count), and a range that needs fewer
    // keeps only its heaviest lobes (below, measured).
    let jmax = chosen
        .iter()
        .map(|&i| cands[i])
        .filter(|c| c.method == Method::Vmf && c.aligned)
        .map(|c| c.lobes)
        .max();
    let mut want = vec![0usize; chosen.len()];
    if let Some(jmax) = jmax {
        let big = cands
            .iter()
            .position(|c| c.method == Method::Vmf && c.aligned && c.lobes == jmax);
        for (o, i) in chosen.iter_mut().enumerate() {
            let c = cands[*i];
            if c.method == Method::Vmf && c.aligned {
                want[o] = c.lobes;
                if let Some(b) = big {
                    *i = b;
                }
            }
        }
    }

    // Group into parts.
    let mut parts: Vec<Part> = Vec::new();
    let mut wants: Vec<usize> = Vec::new();
    for (offset, &i) in chosen.iter().enumerate() {
        let level = range[0] + offset;
        match parts.last_mut() {
            Some(p)
                if p.config == cands[i]
                    && p.last + 1 == level
                    && wants.last() == Some(&want[offset]) =>
            {
                p.last = level
            }
            _ => {
                wants.push(want[offset]);
                parts.push(Part {
                    first: level,
                    last: level,
                    config: cands[i],
                    dropped: Vec::new(),
                    format: Format::F32,
                    color: false,
                    color_format: Format::Unorm8,
                    predicted: 0.0,
                })
            }
        }
    }

    let mut predictions = Vec::new();
    for (p, &wanted) in parts.iter_mut().zip(&wants) {
        let ci = cands.iter().position(|c| *c == p.config).unwrap_or(0);
        let meas = measured[ci]
            .clone()
            .unwrap_or_else(|| full_measured.clone());
        let levels = p.first..=p.last;
        let err = |x: &Measured| x.worst(levels.clone(), scene);
        let full_err = err(&full_measured);
        let targets_ok = |x: &Measured| x.meets(levels.clone(), scene, range[0]);
        let mut e = err(&meas);
        let mut last = meas.clone();
        // A range whose configuration already misses a target cannot meet it with fewer
        // lobes or narrower storage (both only add error): neither is measured.
        let misses = !targets_ok(&meas);
        let left = 2 * FULL.lobes - p.config.textures();
        decisions.push(format!(
            "levels {}-{}: {} ({} texture{}, {} fetch{} per pixel): predicted at most {} \
             against the full vmf8a's {} (targets {}); leaves out {left} of the full \
             configuration's 16 textures, costing {} of error",
            p.first,
            p.last,
            p.config.label(),
            p.config.textures(),
            if p.config.textures() == 1 { "" } else { "s" },
            p.config.fetches(false),
            if p.config.fetches(false) == 1 {
                ""
            } else {
                "es"
            },
            pct(e),
            pct(full_err),
            {
                let t: Vec<String> = levels
                    .clone()
                    .map(|k| pct(scene.target_at(range[0], k)))
                    .collect();
                t.join(", ")
            },
            pct((e - full_err).max(0.0)),
        ));
        if p.config.method == Method::Vmf {
            decisions.push(if p.config.aligned {
                format!(
                    "levels {}-{}: aligned lobes: one hardware trilinear fetch per texture \
                     instead of 8 texel fetches{}",
                    p.first,
                    p.last,
                    if scene.view.anisotropic {
                        " (and anisotropic filtering needs parameters that filter linearly)"
                    } else {
                        ""
                    }
                )
            } else {
                format!(
                    "levels {}-{}: unaligned lobes (aligned ones miss the target): manual \
                     sampling, 8 texel fetches per texture",
                    p.first, p.last
                )
            });
            // Lobes whose α never exceeds the threshold.
            let mut amax = vec![0.0f64; p.config.lobes];
            for k in levels.clone() {
                for (j, a) in meas.alpha_max[k].iter().enumerate() {
                    amax[j] = amax[j].max(*a);
                }
            }
            // The lightest lobes first: those below the threshold, then, where the range
            // was measured to need only `wanted` lobes, down to that many.
            let mut order: Vec<usize> = (0..p.config.lobes).collect();
            order.sort_by(|&a, &b| amax[a].total_cmp(&amax[b]).then(a.cmp(&b)));
            let light = order.iter().filter(|&&j| amax[j] <= DROP_ALPHA).count();
            let mut n = light.max(p.config.lobes.saturating_sub(wanted.max(1)));
            n = n.min(p.config.lobes - 1);
            if misses {
                n = 0;
            }
            // Dropping a lobe removes its weight, so the error grows with every lobe dropped:
            // when dropping the lightest one alone misses the target, so does dropping more
            // (one measurement instead of n).
            if n > 1 {
                let d1 = vec![order[0]];
                let one =
                    m.run_from(p.config, &move |b| Ok(drop_lobes(b, &d1)), p.first, p.last)?;
                if !targets_ok(&one) {
                    n = 0;
                }
            }
            let mut done = false;
            while n > 0 {
                let mut drop = order[..n].to_vec();
                drop.sort_unstable();
                let d2 = drop.clone();
                let dm = m.run_from(p.config, &move |b| Ok(drop_lobes(b, &d2)), p.first, p.last)?;
                let ed = err(&dm);
                if targets_ok(&dm) {
                    decisions.push(format!(
                        "levels {}-{}: {} of vmf{}a's lobes kept (lobes {:?} dropped: their α \
                         is at most {:.3} in every sampled texel): predicted {} instead of {}; \
                         saves {} textures{}",
                        p.first,
                        p.last,
                        p.config.lobes - n,
                        p.config.lobes,
                        drop,
                        order[..n].iter().map(|&j| amax[j]).fold(0.0, f64::max),
                        pct(ed),
                        pct(e),
                        n,
                        if wanted > 0 && wanted < p.config.lobes {
                            format!(
                                " (a vmf{wanted}a fit of its own was predicted at {}, at the \
                                 cost of a second bake)",
                                pct(cands
                                    .iter()
                                    .position(|c| c.method == Method::Vmf
                                        && c.aligned
                                        && c.lobes == wanted)
                                    .and_then(|i| measured[i].as_ref())
                                    .map_or(f64::NAN, &err))
                            )
                        } else {
                            String::new()
                        }
                    ));
                    p.dropped = drop;
                    e = ed;
                    last = dm;
                    done = true;
                    break;
                }
                n -= 1;
            }
            if !done {
                decisions.push(if misses {
                    format!(
                        "levels {}-{}: all {} lobes kept (the range misses its target with \
                         every lobe)",
                        p.first, p.last, p.config.lobes
                    )
                } else {
                    format!(
                        "levels {}-{}: all {} lobes kept (dropping even the lightest, largest \
                         α {:.3}, is predicted above the target)",
                        p.first,
                        p.last,
                        p.config.lobes,
                        amax.iter().copied().fold(f64::INFINITY, f64::min)
                    )
                });
            }
        }
        // Storage format: the narrowest whose predicted error still meets the target.
        let mut format = Format::F32;
        let mut format_err = e;
        let narrower: &[Format] = if misses {
            &[]
        } else {
            &[Format::Unorm8, Format::Unorm16, Format::F16]
        };
        for &f in narrower {
            let ranges = crate::methods::texture_ranges(
                p.config.method,
                if p.config.method == Method::Sh {
                    p.config.lmax
                } else {
                    p.config.lobes
                },
                false,
            );
            if crate::pack::check_ranges(p.config.method, &ranges, f).is_err() {
                continue;
            }
            let q = m.run_stored(p.config, &p.dropped, f, p.first, p.last)?;
            if targets_ok(&q) {
                format = f;
                format_err = err(&q);
                last = q;
                break;
            }
        }
        let tex = p.textures();
        decisions.push(format!(
            "levels {}-{}: {format} storage: saves {} bytes against f32, predicted {} \
             (f32: {}){}",
            p.first,
            p.last,
            bytes(w, h, [p.first, p.last], tex, Format::F32)
                - bytes(w, h, [p.first, p.last], tex, format),
            pct(format_err),
            pct(e),
            if misses {
                " — the range misses its target already: no narrower format is tried"
            } else if format == Format::F32 {
                " — κ needs f32 here: every narrower format misses the target"
            } else {
                ""
            }
        ));
        p.format = format;
        p.predicted = format_err;
        p.color = color && p.config.method == Method::Vmf;
        for k in levels.clone() {
            predictions.push(LevelPrediction {
                level: k,
                target: scene.target_at(range[0], k),
                chosen: p.config.label(),
                predicted: last.error(k, scene),
                full: full_measured.error(k, scene),
            });
        }
    }

    if scene.has_environment() {
        one_environment_part(
            &m,
            scene,
            range,
            (w, h),
            &mut parts,
            &mut predictions,
            &mut decisions,
        )?;
    }

    // Colour decisions.
    let colour_line = match (color_measured, color) {
        (Some(v), false) => format!(
            "colour textures: left out: the albedo varies by {} RMS (≤ {}), a constant K_d \
             colour costs about that much error; saves {} bytes of the full configuration",
            pct(v),
            pct(COLOR_VARIATION),
            bytes(w, h, [0, nl - 1], FULL.lobes, Format::F32)
        ),
        (Some(v), true) => format!(
            "colour textures: kept in the vMF ranges (unorm8: α·y of an 8-bit albedo): the \
             albedo varies by {} RMS; left out of plain/Toksvig/SH ranges (an engine's albedo \
             MIP chain serves them)",
            pct(v)
        ),
        (None, false) => format!(
            "colour textures: left out (scene: colour does not vary); saves {} bytes of the \
             full configuration, no error",
            bytes(w, h, [0, nl - 1], FULL.lobes, Format::F32)
        ),
        (None, true) => "colour textures: kept in the vMF ranges (scene: colour varies; give \
             an albedo image to measure it), unorm8"
            .to_string(),
    };
    decisions.push(colour_line);

    // Shader specialization.
    let (kd, _) = scene.kd_ks();
    let sharpest = m.brdfs[0].clone();
    let shader = ShaderPlan {
        brdf: sharpest.model().to_string(),
        diffuse: kd > 0.0,
        specular: scene.specular(),
        anisotropic: scene.view.anisotropic.then_some(8),
        environment: scene.has_environment(),
        env_lights,
    };
    decisions.push(match scene.material.model {
        scene::Model::Lambert => "specular path: left out (Lambert): the shaders compile \
                                  NDF_BRDF_LAMBERT, no lobe-widening code"
            .into(),
        _ => format!(
            "specular path: {} only (the Torrance–Sparrow/GGX/Blinn-Phong code of the other \
             models is not compiled)",
            sharpest.model()
        ),
    });
    if kd == 0.0 {
        decisions.push(
            "diffuse term: left out (K_d = 0): the shaders compile NDF_NO_DIFFUSE, no ndf_kd \
             uniform and no Lambert code"
                .into(),
        );
    }
    decisions.push(if scene.has_environment() {
        format!(
            "environment: measured under {} (its luminance; ground truth by MIS, {ENV_SAMPLES} \
             samples × {} views × {ENV_TEXELS} texels per level of each sample), {}, the rest \
             shaded by the prefiltered route (one prefiltered-environment lookup per lobe); \
             the SH route is not used (it is exact only for the diffuse term); {}",
            scene
                .environment
                .as_deref()
                .unwrap_or("the generated sky with a sun"),
            crate::envlight::default_views().len(),
            match env_lights {
                0 => format!(
                    "no compact bright source found to extract as a light (up to {} are: a \
                     sun, lamps; the shaders have no light loop)",
                    scene::ENV_LIGHTS
                ),
                n => format!(
                    "{n} bright source(s) extracted as distant lights shaded per lobe (the \
                     shaders add them: NDF_ENV_LIGHTS; upload the lights of the same \
                     extraction)"
                ),
            },
            if scene.has_direct() {
                "one shader per part is lit by both (NDF_LIGHT_BOTH + NDF_LIGHT_ENV_PREFILTERED: \
                 the point light's and the environment's terms summed from the same filtered \
                 texels)"
            } else {
                "the shaders compile NDF_LIGHT_ENV_PREFILTERED and no point-light code"
            }
        )
    } else {
        "environment code: left out (the scene has point/directional lights only)".into()
    });

    let plan_bytes: u64 = parts.iter().map(|p| p.bytes((w, h))).sum();
    let plan_fetches = parts.iter().map(Part::fetches).max().unwrap_or(0);
    if let Some(b) = &scene.budget {
        if let Some(limit) = b.texture_bytes
            && plan_bytes > limit
        {
            return Err(Error::InvalidOption(format!(
                "scene: field 'budget.texture_bytes': the cheapest plan meeting the target needs \
                 {plan_bytes} bytes, more than the budget of {limit}"
            )));
        }
        if let Some(limit) = b.fetches
            && plan_fetches > limit as usize
        {
            return Err(Error::InvalidOption(format!(
                "scene: field 'budget.fetches': the cheapest plan meeting the target needs \
                 {plan_fetches} fetches per pixel, more than the budget of {limit}"
            )));
        }
    }
    decisions.push(format!(
        "total: {plan_bytes} texture bytes against the full configuration's {full_bytes} \
         ({:.1} %), at most {plan_fetches} fetches per pixel against 16",
        100.0 * plan_bytes as f64 / full_bytes as f64
    ));

    Ok(Plan {
        format: PLAN_FORMAT.into(),
        version: PLAN_VERSION,
        map: MapId {
            path: path.map(str::to_string),
            width: w,
            height: h,
            hash: content_hash(map),
        },
        scene: scene.clone(),
        levels: range,
        parts,
        shader,
        decisions,
        predictions,
        bytes: plan_bytes,
        full_bytes,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// What makes two parts' shaders differ: configuration, lobes left out, storage formats,
/// colour. The LOD-switching shader merges neighbouring parts that agree on all of it.
fn shading_of(p: &Part) -> (Config, &[usize], Format, bool, Format) {
    (p.config, &p.dropped, p.format, p.color, p.color_format)
}

/// Under an environment, gives every part the shading of the plan's costliest part (most
/// fetches per pixel) where that still meets the part's targets — measured with that part's
/// lobes left out and storage format — and the scene's texture budget allows, so that the
/// LOD-switching shader has one part lit by the environment. Each part of a switch carries its
/// own copy of the environment's shading, and an NVIDIA H100/H200 paid for the second copy in
/// every pixel: the mixed scene's two-part switch (plain at level 0, vMF J = 8 aligned above)
/// cost 1.83× its costliest part, while the same switch without its plain part cost 0.98×
/// (docs/planner.md, "Frame time on a GPU" and "One part lit by the environment"). The trade is
/// texture bytes for frame time; one decision line per part says which and how much.
fn one_environment_part(
    m: &Measure,
    scene: &Scene,
    range: [usize; 2],
    size: (u32, u32),
    parts: &mut [Part],
    predictions: &mut [LevelPrediction],
    decisions: &mut Vec<String>,
) -> Result<()> {
    let Some(top) = (0..parts.len()).max_by(|&a, &b| {
        // The first of equally costly parts (max_by keeps the last of equals).
        parts[a].fetches().cmp(&parts[b].fetches()).then(b.cmp(&a))
    }) else {
        return Ok(());
    };
    let lead = parts[top].clone();
    let mut total: u64 = parts.iter().map(|p| p.bytes(size)).sum();
    for p in parts.iter_mut() {
        if shading_of(p) == shading_of(&lead) {
            continue;
        }
        let taken = Part {
            first: p.first,
            last: p.last,
            ..lead.clone()
        };
        let q = m.run_stored(lead.config, &lead.dropped, lead.format, p.first, p.last)?;
        let levels = p.first..=p.last;
        let predicted = q.worst(levels.clone(), scene);
        let meets = q.meets(levels.clone(), scene, range[0]);
        let (before, after) = (p.bytes(size), taken.bytes(size));
        let within = scene
            .budget
            .as_ref()
            .and_then(|b| b.texture_bytes)
            .is_none_or(|limit| total - before + after <= limit);
        let what = format!(
            "{} {}{}",
            lead.config.label(),
            lead.format,
            if lead.dropped.is_empty() {
                String::new()
            } else {
                format!(" (lobes {:?} left out)", lead.dropped)
            }
        );
        let was = format!("{} {}", p.config.label(), p.format);
        if !(meets && within) {
            decisions.push(format!(
                "levels {}-{}: {was} kept: {what} (the costliest part's shading, which would \
                 leave the LOD-switching shader one part lit by the environment) {}; the \
                 switch keeps a second copy of the environment's shading",
                p.first,
                p.last,
                if meets {
                    "exceeds the texture budget".to_string()
                } else {
                    format!("is predicted at {} here, above the target", pct(predicted))
                }
            ));
            continue;
        }
        decisions.push(format!(
            "levels {}-{}: {what} instead of {was}, the costliest part's shading, so that the \
             LOD-switching shader has one part lit by the environment (each part carries its \
             own copy of the environment's shading: a second one cost an NVIDIA H100/H200 \
             1.83x the costliest part): predicted {} (was {}); {}",
            p.first,
            p.last,
            pct(predicted),
            pct(p.predicted),
            if after >= before {
                format!("costs {} more texture bytes", after - before)
            } else {
                format!("saves {} texture bytes", before - after)
            }
        ));
        for lp in predictions
            .iter_mut()
            .filter(|lp| levels.contains(&lp.level))
        {
            lp.chosen = lead.config.label();
            lp.predicted = q.error(lp.level, scene);
        }
        total = total - before + after;
        *p = Part { predicted, ..taken };
    }
    Ok(())
}

/// `bake` without the lobes `drop` (and their colour textures).
pub fn drop_lobes(mut bake: Bake, drop: &[usize]) -> Bake {
    if drop.is_empty() || bake.lobes == 0 {
        return bake;
    }
    let lobes = bake.lobes;
    let has_color = bake.textures.len() >= 2 * lobes;
    let keep: Vec<bool> = (0..bake.textures.len())
        .map(|i| {
            let j = if i < lobes {
                i
            } else if has_color && i < 2 * lobes {
                i - lobes
            } else {
                usize::MAX
            };
            !drop.contains(&j)
        })
        .collect();
    let mut it = keep.iter();
    bake.textures.retain(|_| *it.next().unwrap_or(&true));
    bake.lobes = lobes - drop.iter().filter(|&&j| j < lobes).count();
    bake.parameters["lobes"] = bake.lobes.into();
    bake.parameters["dropped_lobes"] = serde_json::json!(drop);
    bake
}

impl Plan {
    /// The decisions as text, one per line (`ndfmap plan --explain`).
    pub fn explain(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "plan for {}x{} map{} (levels {}-{}), made in {:.2} s:",
            self.map.width,
            self.map.height,
            self.map
                .path
                .as_deref()
                .map(|p| format!(" {p}"))
                .unwrap_or_default(),
            self.levels[0],
            self.levels[1],
            self.seconds
        );
        for d in &self.decisions {
            let _ = writeln!(s, "- {d}");
        }
        s
    }

    /// The plan file's text (JSON).
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_default() + "\n"
    }

    /// Parses a plan file's text; [`Error::InvalidOption`] when it is not a plan.
    pub fn from_json(name: &str, text: &str) -> Result<Plan> {
        if text.trim().is_empty() {
            return Err(Error::InvalidOption(format!(
                "plan {name}: the file is empty"
            )));
        }
        let plan: Plan = serde_json::from_str(text)
            .map_err(|e| Error::InvalidOption(format!("plan {name}: not an ndfmap plan: {e}")))?;
        if plan.format != PLAN_FORMAT || plan.version != PLAN_VERSION {
            return Err(Error::InvalidOption(format!(
                "plan {name}: format '{}' version {} (expected '{PLAN_FORMAT}' version \
                 {PLAN_VERSION})",
                plan.format, plan.version
            )));
        }
        plan.scene
            .check()
            .and_then(|()| plan.check_parts())
            .map_err(|e| match e {
                Error::InvalidOption(m) => Error::InvalidOption(format!("plan {name}: {m}")),
                e => e,
            })?;
        Ok(plan)
    }

    /// Checks the plan's levels and parts against the map size it records: the levels exist,
    /// the parts cover them in order, and each part is one a bake can honour
    /// ([`Part::check`]). What [`Plan::from_json`] and [`bake_chains`] check before any work
    /// (a plan file can be edited by hand; a library caller can build one).
    fn check_parts(&self) -> Result<()> {
        if self.map.width == 0 || self.map.height == 0 {
            return Err(Error::InvalidOption(format!(
                "map size {}x{} (expected a map of at least 1x1)",
                self.map.width, self.map.height
            )));
        }
        let levels = crate::pyramid::level_sizes(self.map.width, self.map.height).len();
        if self.levels[0] > self.levels[1] || self.levels[1] >= levels {
            return Err(Error::InvalidOption(format!(
                "levels {}-{} (the {}x{} map it was made for has levels 0-{})",
                self.levels[0],
                self.levels[1],
                self.map.width,
                self.map.height,
                levels - 1
            )));
        }
        let mut next = self.levels[0];
        for p in &self.parts {
            // `p.last ≤ levels[1] < levels`, so `p.last + 1` cannot overflow.
            if p.first != next || p.last < p.first || p.last > self.levels[1] {
                return Err(Error::InvalidOption(format!(
                    "part levels {}-{} do not continue the ranges before them within levels \
                     {}-{}",
                    p.first, p.last, self.levels[0], self.levels[1]
                )));
            }
            p.check()?;
            next = p.last + 1;
        }
        if next != self.levels[1] + 1 || self.parts.is_empty() {
            return Err(Error::InvalidOption(format!(
                "the parts do not cover levels {}-{}",
                self.levels[0], self.levels[1]
            )));
        }
        Ok(())
    }

    /// Checks that this plan was made for `map`: size and [`content_hash`].
    pub fn check_map(&self, map: &NormalMap) -> Result<()> {
        if (map.width(), map.height()) != (self.map.width, self.map.height) {
            return Err(Error::InvalidOption(format!(
                "the plan was made for a {}x{} map, this one is {}x{}",
                self.map.width,
                self.map.height,
                map.width(),
                map.height()
            )));
        }
        let hash = content_hash(map);
        if hash != self.map.hash {
            return Err(Error::InvalidOption(format!(
                "the plan was made for another map of the same size (content hash {}, this \
                 map's is {hash}): plan again",
                self.map.hash
            )));
        }
        Ok(())
    }

    /// The shader specification of part `i`.
    pub fn shader_spec(&self, i: usize, addressing: crate::ingest::Addressing) -> ShaderSpec {
        let p = &self.parts[i];
        let lobes = p.textures();
        let (layout_n, lobes_field) = match p.config.method {
            Method::Vmf | Method::Tan2005 => (lobes, lobes),
            Method::Sh => (p.config.lmax, 0),
            _ => (0, 0),
        };
        ShaderSpec {
            method: p.config.method,
            lobes: lobes_field,
            ranges: crate::methods::texture_ranges(p.config.method, layout_n, p.color),
            format: p.format,
            aligned: p.config.aligned,
            addressing,
            lmax: p.config.lmax,
            biased: false,
        }
    }

    /// The shader options of the plan's parts.
    pub fn shader_options(&self, i: usize) -> ShaderOptions {
        let brdf = match self.scene.brdfs().first() {
            Some(b) => ShaderBrdf::of(b),
            None => ShaderBrdf::Lambert,
        };
        let p = &self.parts[i];
        ShaderOptions {
            brdf,
            sampling: match self.shader.anisotropic {
                Some(n) if p.config.method != Method::Vmf || p.config.aligned => {
                    Sampling::Anisotropic(n)
                }
                _ => Sampling::Auto,
            },
            color: p.color,
            // K_d = 0: no diffuse code (a Lambert scene always has K_d > 0).
            no_diffuse: !self.shader.diffuse && brdf != ShaderBrdf::Lambert,
            // Both kinds of light: one shader summing both terms (with or without the colour
            // textures: the environment shaders read them too).
            light: match (self.shader.environment, self.scene.has_direct()) {
                (true, false) => crate::glsl::ShaderLight::EnvPrefiltered,
                (true, true) => crate::glsl::ShaderLight::PointAndEnvPrefiltered,
                _ => crate::glsl::ShaderLight::Point,
            },
            // The environment's extracted lights (`Scene::environment_light`, measured so):
            // the shader adds them (`NDF_ENV_LIGHTS`; the engine uploads the lights of an
            // environment prepared with the same extraction, `envgpu::Upload::lights`).
            env_lights: self.shader.environment && self.shader.env_lights > 0,
            ..ShaderOptions::default()
        }
    }

    /// The specialized fragment shader of part `i` (`glsl::source_for`): its method's code
    /// only, exactly the samplers it reads, the BRDF's path only.
    pub fn shader(&self, i: usize, addressing: crate::ingest::Addressing) -> Result<String> {
        let mut src = crate::glsl::source_for(
            &self.shader_spec(i, addressing),
            Stage::Fragment,
            &self.shader_options(i),
        )?;
        let p = &self.parts[i];
        src = src.replacen(
            "\n",
            &format!(
                "\n// ndfmap plan: levels {}-{} ({}); the engine selects this shader where \
                 textureQueryLod lies in [{}, {}]\n",
                p.first,
                p.last,
                p.config.label(),
                p.first,
                p.last + 1
            ),
            1,
        );
        Ok(src)
    }
    /// The parts of the plan's one LOD-switching shader ([`crate::glsl::lod_switch_source`]):
    /// adjacent plan parts whose shaders are the same (method, textures, format, colour,
    /// sampling) merge into one shader part, whose textures hold their levels (level 0 = the
    /// first part's first level; the files `p{part}…_L{level}` of the merged parts, in level
    /// order). Returns each shader part with the plan parts it merges.
    pub fn lod_switch_parts(
        &self,
        addressing: crate::ingest::Addressing,
    ) -> Vec<(crate::glsl::LodPart, Vec<usize>)> {
        let mut out: Vec<(crate::glsl::LodPart, Vec<usize>)> = Vec::new();
        for (i, p) in self.parts.iter().enumerate() {
            let spec = self.shader_spec(i, addressing);
            let options = ShaderOptions {
                probe: false,
                ..self.shader_options(i)
            };
            if let Some((last, members)) = out.last_mut()
                && last.spec == spec
                && last.options == options
                && last.last + 1 == p.first
            {
                last.last = p.last;
                members.push(i);
                continue;
            }
            out.push((
                crate::glsl::LodPart {
                    spec,
                    options,
                    first: p.first,
                    last: p.last,
                },
                vec![i],
            ));
        }
        out
    }

    /// The plan's one fragment shader switching method by level of detail
    /// ([`crate::glsl::lod_switch_source`] over [`Plan::lod_switch_parts`]), with a header
    /// naming each sampler's files. Fails (saying why) where it is not built: parts lit
    /// differently, more than 32 samplers.
    pub fn lod_switch_shader(&self, addressing: crate::ingest::Addressing) -> Result<String> {
        self.lod_switch(addressing).map(|s| s.source)
    }

    /// What an engine should know before drawing the plan's LOD-switching shader
    /// ([`crate::glsl::lod_switch_caution`] of [`Plan::lod_switch_parts`]): `Some` where it has
    /// several parts lit by the environment — which [`plan`] avoids unless a part's target or
    /// the scene's texture budget forbids giving it the costliest part's shading.
    pub fn lod_switch_caution(&self, addressing: crate::ingest::Addressing) -> Option<String> {
        let parts: Vec<crate::glsl::LodPart> = self
            .lod_switch_parts(addressing)
            .into_iter()
            .map(|p| p.0)
            .collect();
        let light = parts.first()?.options.light;
        crate::glsl::lod_switch_caution(&parts, light)
    }

    /// [`Plan::lod_switch_shader`] with the samplers the generator declares per switch part
    /// ([`crate::glsl::LodSwitch`]).
    pub fn lod_switch(
        &self,
        addressing: crate::ingest::Addressing,
    ) -> Result<crate::glsl::LodSwitch> {
        let parts = self.lod_switch_parts(addressing);
        let lod: Vec<crate::glsl::LodPart> = parts.iter().map(|p| p.0.clone()).collect();
        let options = lod[0].options;
        let options = ShaderOptions {
            sampling: match options.sampling {
                Sampling::Anisotropic(n) => Sampling::Anisotropic(n),
                _ => Sampling::Auto,
            },
            ..options
        };
        let switch = crate::glsl::lod_switch(
            &lod,
            (self.map.width, self.map.height),
            Stage::Fragment,
            &options,
        )?;
        let mut header = String::from(
            "// ndfmap plan: one shader for every level shipped; sampler ndf_p{k}_tex{i} is a \
             texture whose level 0 is part k's first level:\n",
        );
        for (k, (p, members)) in parts.iter().enumerate() {
            let _ = writeln!(
                header,
                "//   part {k}: levels {}-{}: ndf_p{k}_tex{{i}} = texture i (manifest order) of \
                 plan part(s) {:?}, files p{{part}}{{texture}}_L{{level}}",
                p.first, p.last, members
            );
        }
        Ok(crate::glsl::LodSwitch {
            source: switch.source.replacen('\n', &format!("\n{header}"), 1),
            samplers: switch.samplers,
        })
    }
}

/// The result of baking a plan: per part, its bake restricted to the part's levels.
pub struct PlanBake {
    /// Per part, the bake (levels `first..=last` only, lobes dropped, quantized) and the
    /// seconds its method took.
    pub parts: Vec<(Bake, f64)>,
}

/// Bakes each part of `plan` over the map's whole MIP chain (each distinct configuration
/// once), drops the part's lobes and quantizes to the part's formats: per part, the bake (its
/// levels and the coarser ones; the finer levels are empty) and the seconds its method took.
/// [`execute`] keeps each part's levels; the report measures the error of the chains.
/// [`Error::InvalidOption`] before any work for a plan made for another map, or with colour
/// textures when `map` carries no albedo (its feature image).
pub fn bake_chains(plan: &Plan, map: &NormalMap) -> Result<Vec<(Bake, f64)>> {
    plan.check_map(map)?;
    plan.check_parts()?;
    // A part with colour textures needs the albedo: without it the files would lack the
    // colour textures its shader reads.
    if let (Some(p), None) = (plan.parts.iter().find(|p| p.color), map.feature()) {
        return Err(Error::InvalidOption(format!(
            "part levels {}-{} ships colour textures (the scene's colour varies), and the map \
             has no albedo: give the one the plan was made with (bake --feature)",
            p.first, p.last
        )));
    }
    let mut parts = Vec::new();
    let mut cache: Vec<(Config, bool, Bake, f64)> = Vec::new();
    for p in &plan.parts {
        let color = p.color;
        let idx = cache
            .iter()
            .position(|(c, col, _, _)| *c == p.config && *col == color);
        let idx = match idx {
            Some(i) => i,
            None => {
                let t = std::time::Instant::now();
                let without;
                let source = if !color && map.feature().is_some() {
                    without = NormalMap::from_vectors(
                        map.width(),
                        map.height(),
                        map.normals().to_vec(),
                        map.addressing(),
                        BadNormals::Repair,
                    )?;
                    &without
                } else {
                    map
                };
                let b =
                    crate::methods::bake_with(source, p.config.method, &p.config.bake_options())?;
                cache.push((p.config, color, b, t.elapsed().as_secs_f64()));
                cache.len() - 1
            }
        };
        let (_, _, full, seconds) = &cache[idx];
        // The part's levels and the coarser ones (what eval reads from the part's first level
        // on); the finer ones, most of the texels, are left empty instead of copied.
        let part = Bake {
            textures: full
                .textures
                .iter()
                .map(|t| crate::bake::Texture {
                    name: t.name,
                    channels: t.channels,
                    ranges: t.ranges,
                    levels: t
                        .levels
                        .iter()
                        .enumerate()
                        .map(|(k, l)| if k < p.first { Vec::new() } else { l.clone() })
                        .collect(),
                })
                .collect(),
            sizes: full.sizes.clone(),
            addressing: full.addressing,
            lobes: full.lobes,
            parameters: full.parameters.clone(),
            format: full.format,
            method: full.method,
        };
        let b = drop_lobes(part, &p.dropped);
        // Colour textures get their own (narrower) format: quantize the lobes and the colours
        // apart, then put them back together.
        let lobes = b.lobes;
        let b = if color && lobes > 0 && p.color_format != p.format {
            let mut colors = b.clone();
            colors.textures.drain(..lobes);
            colors.lobes = 0;
            let colors = crate::pack::quantize_into(colors, p.color_format)?;
            let mut main = b;
            main.textures.truncate(lobes);
            let mut main = crate::pack::quantize_into(main, p.format)?;
            main.textures.extend(colors.textures);
            main
        } else {
            crate::pack::quantize_into(b, p.format)?
        };
        parts.push((b, *seconds));
    }
    Ok(parts)
}

/// Bakes `plan` for `map` (`ndfmap bake --plan`): refuses a plan made for another map (size or
/// content hash) before any work, then bakes each distinct configuration once over the whole
/// map ([`bake_chains`]) and keeps each part's levels.
pub fn execute(plan: &Plan, map: &NormalMap) -> Result<PlanBake> {
    let chains = bake_chains(plan, map)?;
    let parts = plan
        .parts
        .iter()
        .zip(chains)
        .map(|(p, (mut b, seconds))| {
            b.sizes = b.sizes[p.first..=p.last].to_vec();
            for t in &mut b.textures {
                t.levels = t.levels[p.first..=p.last].to_vec();
            }
            (b, seconds)
        })
        .collect();
    Ok(PlanBake { parts })
}

/// One part in a plan bake's manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PartManifest {
    /// Finest level of the part (the map's level numbers).
    pub first: usize,
    /// Coarsest level.
    pub last: usize,
    /// The method.
    pub method: Method,
    /// The configuration's label (`vmf3a`, `toksvig`, `sh2`).
    pub label: String,
    /// The method's parameters, as a plain bake's manifest records them (with
    /// `dropped_lobes`).
    pub parameters: serde_json::Value,
    /// The storage format of the method's textures.
    pub texel_format: Format,
    /// The storage format of the colour textures, if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub color_format: Option<Format>,
    /// Level sizes, finest first (levels `first..=last`).
    pub levels: Vec<crate::output::LevelInfo>,
    /// Texture chains; `files[i]` is level `first + i`.
    pub textures: Vec<crate::output::TextureInfo>,
    /// Seconds the part's method took to bake (shared by parts of the same method).
    pub bake_seconds: f64,
}

/// `manifest.json` of a plan bake: one bake that mixes methods across level ranges.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlanManifest {
    /// Always `"ndfmap-plan-bake"`.
    pub format: String,
    /// [`crate::output::MANIFEST_VERSION`].
    pub manifest_version: u32,
    /// The ndfmap version that wrote it.
    pub ndfmap_version: String,
    /// Always true: the parts below use different methods or parameters per level range.
    pub mixed: bool,
    /// The levels shipped.
    pub levels: [usize; 2],
    /// The map the plan was made for.
    pub map: MapId,
    /// Texture addressing.
    pub addressing: crate::ingest::Addressing,
    /// The parts, finest first.
    pub parts: Vec<PartManifest>,
    /// The one shader that switches method by level of detail ([`Plan::lod_switch_shader`]),
    /// written beside the textures, and which textures its samplers read.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lod_switch: Option<SwitchManifest>,
    /// The input and its convention.
    pub input: crate::output::InputInfo,
}

/// [`PlanManifest::lod_switch`]: the LOD-switching fragment shader of a plan bake.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SwitchManifest {
    /// Its file in the folder ([`LOD_SWITCH_FILE`]); absent when it is not built.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shader: Option<String>,
    /// Why it is not built (parts lit differently, too many samplers); absent when it is.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub not_built: Option<String>,
    /// Its parts, finest first (adjacent plan parts with the same shader merged).
    pub parts: Vec<SwitchPartManifest>,
}

/// One part of a [`SwitchManifest`]: a level range shaded by one method.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SwitchPartManifest {
    /// Finest map level.
    pub first: usize,
    /// Coarsest map level.
    pub last: usize,
    /// The plan parts ([`PlanManifest::parts`] indices) it merges, in level order: their files
    /// make its textures' levels.
    pub plan_parts: Vec<usize>,
    /// Per sampler the shader declares for this part, `(sampler name, texture index)`: sampler
    /// `ndf_p{k}_tex{i}` reads texture `i` (manifest order) of `plan_parts`, with its level 0 at
    /// `first` (upload only those levels, or set `GL_TEXTURE_BASE_LEVEL`).
    pub samplers: Vec<(String, usize)>,
}

/// File name of a plan bake's LOD-switching fragment shader.
pub const LOD_SWITCH_FILE: &str = "lod_switch.frag";

/// Whether `name` is a file of a plan folder (`ndfmap plan -o`): `plan.json`, `explain.txt`,
/// `verify.json`, `partN.frag`, [`LOD_SWITCH_FILE`], or the `.NAME.tmp` of one (what earlier
/// versions left behind a failed write).
pub fn is_plan_file(name: &str) -> bool {
    let own = |n: &str| {
        matches!(
            n,
            "plan.json" | "explain.txt" | "verify.json" | LOD_SWITCH_FILE
        ) || n
            .strip_prefix("part")
            .and_then(|r| r.strip_suffix(".frag"))
            .is_some_and(|i| !i.is_empty() && i.bytes().all(|b| b.is_ascii_digit()))
    };
    own(name)
        || name
            .strip_prefix('.')
            .and_then(|n| n.strip_suffix(".tmp"))
            .is_some_and(own)
}

/// Writes a plan folder (`ndfmap plan -o DIR`: `files` as name and text) as a whole, atomically
/// ([`crate::output::write_folder_owning`]): a failure leaves `dir` as it was, and an existing
/// `dir` is replaced only if it holds nothing but a plan's files ([`is_plan_file`]) — never a
/// bake (`bake --plan`'s folder) or other files.
pub fn write_plan_folder(dir: &std::path::Path, files: &[(String, String)]) -> Result<()> {
    crate::output::write_folder_owning(dir, "plan", &is_plan_file, |staging| {
        for (name, text) in files {
            let path = staging.join(name);
            std::fs::write(&path, text).map_err(|e| Error::Write {
                path: dir.join(name),
                message: e.to_string(),
            })?;
        }
        Ok(())
    })
}

/// File name of texture `name` of part `part` at map level `level`: `p{part}{name}_L{level}`.
pub fn part_file(part: usize, name: &str, level: usize, format: Format) -> String {
    crate::output::file_name(&format!("p{part}{name}"), level, format)
}

/// Writes a plan bake and its [`PlanManifest`] as folder `dir`, atomically
/// ([`crate::output::write_folder`]). Returns the manifest's path.
pub fn write(
    plan: &Plan,
    baked: &PlanBake,
    input: crate::output::InputInfo,
    dir: &std::path::Path,
) -> Result<std::path::PathBuf> {
    let mut parts = Vec::new();
    let mut jobs = Vec::new();
    for (i, (p, (b, seconds))) in plan.parts.iter().zip(&baked.parts).enumerate() {
        let color_format =
            (b.lobes > 0 && b.textures.len() >= 2 * b.lobes && p.color).then_some(p.color_format);
        let textures = b
            .textures
            .iter()
            .enumerate()
            .map(|(t, tex)| {
                let f = if t >= b.lobes && b.lobes > 0 {
                    color_format.unwrap_or(p.format)
                } else {
                    p.format
                };
                let files: Vec<String> = (p.first..=p.last)
                    .map(|k| part_file(i, tex.name, k, f))
                    .collect();
                for (li, name) in files.iter().enumerate() {
                    jobs.push((i, t, li, name.clone(), f));
                }
                crate::output::TextureInfo {
                    name: tex.name.into(),
                    channels: tex.channels.iter().map(|c| c.to_string()).collect(),
                    ranges: tex.ranges.to_vec(),
                    files,
                }
            })
            .collect();
        parts.push(PartManifest {
            first: p.first,
            last: p.last,
            method: p.config.method,
            label: p.config.label(),
            parameters: b.parameters.clone(),
            texel_format: p.format,
            color_format,
            levels: b
                .sizes
                .iter()
                .enumerate()
                .map(|(li, &(width, height))| crate::output::LevelInfo {
                    level: p.first + li,
                    width,
                    height,
                })
                .collect(),
            textures,
            bake_seconds: *seconds,
        });
    }
    let mut manifest = PlanManifest {
        format: "ndfmap-plan-bake".into(),
        manifest_version: crate::output::MANIFEST_VERSION,
        ndfmap_version: env!("CARGO_PKG_VERSION").into(),
        mixed: true,
        levels: plan.levels,
        map: plan.map.clone(),
        addressing: baked
            .parts
            .first()
            .map(|(b, _)| b.addressing)
            .unwrap_or_default(),
        parts,
        lod_switch: None,
        input,
    };
    // The LOD-switching shader, where it is built (else the reason, recorded).
    let switch_parts = plan.lod_switch_parts(manifest.addressing);
    let switch = plan.lod_switch(manifest.addressing);
    manifest.lod_switch = Some(SwitchManifest {
        shader: switch.is_ok().then(|| LOD_SWITCH_FILE.to_string()),
        not_built: switch.as_ref().err().map(|e| e.to_string()),
        parts: switch_parts
            .iter()
            .enumerate()
            .map(|(k, (p, members))| SwitchPartManifest {
                first: p.first,
                last: p.last,
                plan_parts: members.clone(),
                samplers: switch
                    .as_ref()
                    .map(|s| {
                        s.samplers[k]
                            .iter()
                            .enumerate()
                            .map(|(i, name)| (name.clone(), i))
                            .collect()
                    })
                    .unwrap_or_default(),
            })
            .collect(),
    });
    let switch = switch.ok().map(|s| s.source);
    let json = serde_json::to_string_pretty(&manifest).map_err(|e| Error::Write {
        path: dir.to_path_buf(),
        message: e.to_string(),
    })?;
    crate::output::write_folder(dir, |staging| {
        use rayon::prelude::*;
        jobs.par_iter()
            .map(|(i, t, li, name, f)| {
                let b = &baked.parts[*i].0;
                let tex = &b.textures[*t];
                let (w, h) = b.sizes[*li];
                crate::output::write_level(
                    &staging.join(name),
                    w,
                    h,
                    &tex.levels[*li],
                    tex.ranges,
                    *f,
                )
            })
            .collect::<Vec<Result<()>>>()
            .into_iter()
            .collect::<Result<()>>()?;
        if let Some(src) = &switch {
            std::fs::write(staging.join(LOD_SWITCH_FILE), src).map_err(|e| Error::Write {
                path: dir.join(LOD_SWITCH_FILE),
                message: e.to_string(),
            })?;
        }
        std::fs::write(staging.join(crate::output::MANIFEST), json + "\n").map_err(|e| {
            Error::Write {
                path: dir.join(crate::output::MANIFEST),
                message: e.to_string(),
            }
        })
    })?;
    Ok(dir.join(crate::output::MANIFEST))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene(text: &str) -> Scene {
        Scene::parse("test", text).unwrap()
    }

    const GLOSSY: &str = r#"
lights = ["directional"]
[material]
model = "blinn-phong"
exponent = [32, 128]
kd = 0.0
ks = 1.0
[view]
levels = [0, 6]
[target]
error = 0.08
"#;

    const MATTE: &str = r#"
lights = ["environment"]
[material]
model = "lambert"
[view]
levels = [2, 6]
[target]
error = 0.05
"#;

    /// The plan's measured error on the whole map (every part's bake, against the exact
    /// footprint average; under an environment against its ground truth) at each shipped
    /// level.
    fn measured(plan: &Plan, map: &NormalMap) -> Vec<(usize, f64)> {
        let chains = bake_chains(plan, map).unwrap();
        let whole = WholeMap::new(plan, map, 64).unwrap();
        let mut out = Vec::new();
        for (p, (b, _)) in plan.parts.iter().zip(&chains) {
            let errors = whole.errors(b, p.first, p.last).unwrap();
            for (k, e) in errors.iter().enumerate().take(p.last + 1).skip(p.first) {
                out.push((k, *e));
            }
        }
        out
    }

    #[test]
    fn plans_meet_their_target_on_the_whole_map_and_predict_it() {
        // 256²: the crops (128²) stand for levels 0-7 and do not hold the whole map.
        let map = crate::procedural::generate(256, 5).map;
        let mut fetches = Vec::new();
        for (text, expect_vmf) in [(GLOSSY, Some(true)), (MATTE, None)] {
            let s = scene(text);
            let plan = plan(&map, &s, None).unwrap();
            let range = s.level_range(9).unwrap();
            assert_eq!(plan.levels, range);
            assert_eq!(plan.parts.first().unwrap().first, range[0]);
            assert_eq!(plan.parts.last().unwrap().last, range[1]);
            assert!(plan.bytes < plan.full_bytes / 4, "{}", plan.explain());
            // A sharp specular lobe at coarse levels needs lobes; Lambert needs none.
            let has_vmf = plan.parts.iter().any(|p| p.config.method == Method::Vmf);
            if let Some(v) = expect_vmf {
                assert_eq!(has_vmf, v, "{}", plan.explain());
            }
            fetches.push(plan.parts.iter().map(|p| p.textures()).max().unwrap());
            for (k, e) in measured(&plan, &map) {
                let pr = plan.predictions.iter().find(|p| p.level == k).unwrap();
                assert!(
                    e <= pr.target,
                    "level {k}: {e} > {}\n{}",
                    pr.target,
                    plan.explain()
                );
                // The prediction within a factor 2 where the error is above 0.5 %.
                if e > 0.005 || pr.predicted > 0.005 {
                    let r = e.max(1e-3) / pr.predicted.max(1e-3);
                    assert!(
                        (0.5..=2.0).contains(&r),
                        "level {k}: measured {e}, predicted {}",
                        pr.predicted
                    );
                }
            }
            // Every decision is one line.
            assert!(plan.decisions.iter().all(|d| !d.contains('\n')));
            // The plan file round-trips.
            let back = Plan::from_json("p", &plan.to_json()).unwrap();
            assert_eq!(back, plan);
        }
        // The matte scene needs fewer textures than the glossy one.
        assert!(fetches[1] < fetches[0], "{fetches:?}");
    }

    #[test]
    fn under_an_environment_the_lod_switch_keeps_one_part() {
        // Glossy, from the finest level: point-lit, level 0 is plain and the coarser levels
        // need lobes, so the LOD switch has several parts. Lit by the environment as well,
        // every level takes the costliest part's shading where it meets the target, so the
        // switch has one part lit by the environment (no caution), the plan still meets its
        // targets, and a decision line says what it cost.
        let map = crate::procedural::generate(128, 7).map;
        let direct = plan(&map, &scene(GLOSSY), None).unwrap();
        assert_eq!(
            direct.parts[0].config.method,
            Method::Plain,
            "{}",
            direct.explain()
        );
        assert!(
            direct.parts.iter().any(|p| p.config.method == Method::Vmf),
            "{}",
            direct.explain()
        );
        let lit = GLOSSY.replace(
            r#"lights = ["directional"]"#,
            "lights = [\"directional\", \"environment\"]\nenvironment = \"overcast\"",
        );
        let s = scene(&lit);
        let plan = plan(&map, &s, None).unwrap();
        let lead = shading_of(&plan.parts[plan.parts.len() - 1]);
        assert!(
            plan.parts.iter().all(|p| shading_of(p) == lead),
            "{}",
            plan.explain()
        );
        let addressing = crate::ingest::Addressing::Wrap;
        assert_eq!(plan.lod_switch_caution(addressing), None);
        assert_eq!(plan.lod_switch_parts(addressing).len(), 1);
        let line = plan
            .decisions
            .iter()
            .find(|d| d.starts_with("levels 0-") && d.contains("instead of plain"))
            .unwrap_or_else(|| panic!("{}", plan.explain()));
        assert!(line.contains("more texture bytes"), "{line}");
        for (k, e) in measured(&plan, &map) {
            let pr = plan.predictions.iter().find(|p| p.level == k).unwrap();
            assert_eq!(pr.chosen, plan.parts[0].config.label());
            assert!(
                e <= pr.target,
                "level {k}: {e} > {}\n{}",
                pr.target,
                plan.explain()
            );
        }
        // A texture budget below what the takeover costs keeps the cheaper part (and says so).
        let bytes_direct: u64 = direct.parts.iter().map(|p| p.bytes((128, 128))).sum();
        let tight = format!("{lit}\n[budget]\ntexture_bytes = {}\n", bytes_direct + 1024);
        let p = super::plan(&map, &scene(&tight), None).unwrap();
        assert_eq!(p.parts[0].config.method, Method::Plain, "{}", p.explain());
        assert_eq!(p.bytes, bytes_direct, "{}", p.explain());
        assert!(
            p.decisions
                .iter()
                .any(|d| d.contains("exceeds the texture budget")),
            "{}",
            p.explain()
        );
    }

    #[test]
    fn lean_olano_and_tan2005_are_candidates_and_plans_carry_them() {
        // The candidate set: the moment baselines and Tan 2005; under an environment Olano–North
        // but not Tan 2005 (its fits cost the mixed scene's plan 0.5 s and won nowhere).
        let glossy = scene(GLOSSY);
        let c = candidates(&glossy);
        let has = |c: &[Config], m: Method, j: usize| {
            c.iter()
                .any(|x| x.method == m && x.lobes == j && (m != Method::Tan2005 || x.aligned))
        };
        for (m, j) in [
            (Method::Lean, 0),
            (Method::Olano, 0),
            (Method::Tan2005, 2),
            (Method::Tan2005, 4),
        ] {
            assert!(has(&c, m, j), "{m} {j}: {c:?}");
        }
        // Cheapest first: LEAN (2 textures) before vmf3a, Olano (3) before vmf4a.
        let at = |m: Method, j: usize| c.iter().position(|x| x.method == m && x.lobes == j);
        assert!(at(Method::Lean, 0) < at(Method::Vmf, 3));
        assert!(at(Method::Olano, 0) < at(Method::Vmf, 4));
        assert!(at(Method::Vmf, 2) < at(Method::Tan2005, 2));
        let matte = candidates(&scene(MATTE));
        assert!(has(&matte, Method::Lean, 0));
        assert!(has(&matte, Method::Olano, 0) && !has(&matte, Method::Tan2005, 2));

        // A plan whose one part is each of them: the plan file round-trips, `bake --plan`
        // bakes exactly that method's textures (against a direct bake, f32: bit for bit), and
        // the part's shader is that method's, with one sampler per texture, hardware-filtered.
        let map = crate::procedural::generate(64, 3).map;
        let base = plan(&map, &glossy, None).unwrap();
        for config in c.iter().filter(|x| {
            matches!(x.method, Method::Lean | Method::Olano | Method::Tan2005) && x.lobes <= 2
        }) {
            let mut p = base.clone();
            p.parts = vec![Part {
                first: p.levels[0],
                last: p.levels[1],
                config: *config,
                dropped: Vec::new(),
                format: Format::F32,
                color: false,
                color_format: Format::Unorm8,
                predicted: 0.0,
            }];
            let p = Plan::from_json("p", &p.to_json()).unwrap();
            assert_eq!(p.parts[0].config, *config);
            let baked = execute(&p, &map).unwrap();
            let direct =
                crate::methods::bake_with(&map, config.method, &config.bake_options()).unwrap();
            let (b, _) = &baked.parts[0];
            assert_eq!(b.method, config.method);
            assert_eq!(b.textures.len(), config.textures(), "{}", config.label());
            for (t, d) in b.textures.iter().zip(&direct.textures) {
                for (k, level) in t.levels.iter().enumerate() {
                    assert_eq!(
                        level,
                        &d.levels[p.levels[0] + k],
                        "{} level",
                        config.label()
                    );
                }
            }
            let src = p.shader(0, map.addressing()).unwrap();
            let define = match config.method {
                Method::Lean => "NDF_METHOD_LEAN",
                Method::Olano => "NDF_METHOD_OLANO",
                _ => "NDF_METHOD_TAN2005",
            };
            assert!(src.contains(&format!("#define {define} 1")), "{src}");
            assert!(!src.contains("#define NDF_MANUAL"), "{}", config.label());
            let samplers = src.matches("uniform sampler2D ndf_tex").count();
            assert_eq!(samplers, config.textures(), "{}", config.label());
            assert_eq!(config.fetches(false), config.textures());
        }
    }

    #[test]
    fn a_plan_refuses_another_map() {
        let map = crate::procedural::generate(32, 5).map;
        let s = scene(&MATTE.replace("[2, 6]", "[1, 5]"));
        let p = plan(&map, &s, None).unwrap();
        let other = crate::procedural::generate(32, 6).map;
        let e = execute(&p, &other).err().unwrap().to_string();
        assert!(e.contains("another map"), "{e}");
        let small = crate::procedural::generate(16, 5).map;
        let e = execute(&p, &small).err().unwrap().to_string();
        assert!(e.contains("32x32"), "{e}");
        assert!(execute(&p, &map).is_ok());
        // Levels beyond this map.
        let e = plan(&small, &s, None).unwrap_err().to_string();
        assert!(e.contains("view.levels"), "{e}");
    }

    #[test]
    fn plan_files_that_are_not_plans_are_refused() {
        for (text, needle) in [
            ("", "empty"),
            ("[1, 2]", "not an ndfmap plan"),
            ("{\"format\": \"ndfmap-plan\"}", "not an ndfmap plan"),
        ] {
            let e = Plan::from_json("p", text).unwrap_err().to_string();
            assert!(e.contains(needle), "{text}: {e}");
        }
        let map = crate::procedural::generate(32, 5).map;
        let p = plan(&map, &scene(&MATTE.replace("[2, 6]", "[1, 5]")), None).unwrap();
        let mut v: serde_json::Value = serde_json::from_str(&p.to_json()).unwrap();
        v["parts"][0]["first"] = 3.into();
        let e = Plan::from_json("p", &v.to_string())
            .unwrap_err()
            .to_string();
        assert!(e.contains("do not continue"), "{e}");
        let mut v: serde_json::Value = serde_json::from_str(&p.to_json()).unwrap();
        v["version"] = 99.into();
        let e = Plan::from_json("p", &v.to_string())
            .unwrap_err()
            .to_string();
        assert!(e.contains("version 99"), "{e}");
    }

    /// Hand-edited plan files (the planner never writes these): levels past the map's
    /// coarsest (which made `bake --plan` panic on a slice) or so large that `last + 1`
    /// wraps, lobe counts of 0, left-out lobes that repeat, do not exist or leave none, colour
    /// on a part without lobes: each one line naming the field, none a panic; and a colour
    /// plan needs the albedo it was made with.
    #[test]
    fn hand_edited_plans_are_checked_before_any_work() {
        let map = crate::procedural::generate(32, 5).map; // levels 0-5
        let p = plan(&map, &scene(&MATTE.replace("[2, 6]", "[1, 5]")), None).unwrap();
        let base: serde_json::Value = serde_json::from_str(&p.to_json()).unwrap();
        let n = base["parts"].as_array().unwrap().len();
        let vmf = |lobes: usize, dropped: &[usize], color: bool| {
            let mut v = base.clone();
            let last = &mut v["parts"][n - 1];
            last["config"] = serde_json::json!({
                "method": "vmf", "lobes": lobes, "lmax": 0, "aligned": true
            });
            last["dropped"] = serde_json::json!(dropped);
            last["color"] = color.into();
            v
        };
        let mut cases: Vec<(serde_json::Value, &str)> = Vec::new();
        let mut v = base.clone();
        v["levels"][1] = 6.into();
        v["parts"][n - 1]["last"] = 6.into();
        cases.push((
            v,
            "levels 1-6 (the 32x32 map it was made for has levels 0-5)",
        ));
        let mut v = base.clone();
        v["levels"][1] = u64::MAX.into();
        v["parts"][n - 1]["last"] = u64::MAX.into();
        cases.push((v, "levels 1-18446744073709551615"));
        let mut v = base.clone();
        v["parts"][0]["last"] = u64::MAX.into();
        cases.push((v, "do not continue"));
        let mut v = base.clone();
        v["scene"]["material"]["kd"] = (-1.0).into();
        cases.push((v, "plan p: scene: field 'material.kd'"));
        cases.push((vmf(0, &[], false), "lobe count 0 (expected 1 to 8)"));
        cases.push((vmf(6, &[0, 0], false), "left-out lobe 0 (expected distinct"));
        cases.push((vmf(6, &[6], false), "left-out lobe 6 (expected distinct"));
        cases.push((vmf(2, &[0, 1], false), "2 left-out lobes of 2"));
        let mut v = base.clone();
        v["parts"][0]["config"] =
            serde_json::json!({"method": "toksvig", "lobes": 0, "lmax": 0, "aligned": false});
        v["parts"][0]["color"] = true.into();
        cases.push((v, "colour textures on a toksvig part"));
        for (v, needle) in cases {
            let e = Plan::from_json("p", &v.to_string())
                .unwrap_err()
                .to_string();
            assert!(e.contains(needle) && !e.contains('\n'), "{needle}: {e}");
        }
        // A valid vMF part with colour: refused without the albedo, baked with one.
        let coloured = Plan::from_json("p", &vmf(2, &[1], true).to_string()).unwrap();
        let e = execute(&coloured, &map).err().unwrap().to_string();
        assert!(e.contains("no albedo"), "{e}");
        let albedo = vec![[0.5f32, 0.4, 0.3, 1.0]; 32 * 32];
        let baked = execute(&coloured, &map.clone().with_feature(albedo).unwrap()).unwrap();
        let last = &baked.parts[n - 1].0;
        assert_eq!((last.lobes, last.textures.len()), (1, 2));
    }

    /// `ndfmap plan -o` writes its folder as a whole: it replaces an earlier plan (stale part
    /// shaders gone), refuses a bake's folder or one of other files (untouched), and a failed
    /// write leaves the earlier plan as it was.
    #[test]
    fn plan_folders_are_written_whole() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("plan");
        let files = |names: &[&str]| -> Vec<(String, String)> {
            names
                .iter()
                .map(|n| (n.to_string(), format!("{n}\n")))
                .collect()
        };
        write_plan_folder(&out, &files(&["plan.json", "part0.frag", "part1.frag"])).unwrap();
        write_plan_folder(&out, &files(&["plan.json", "part0.frag", LOD_SWITCH_FILE])).unwrap();
        let mut names: Vec<String> = std::fs::read_dir(&out)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(names, ["lod_switch.frag", "part0.frag", "plan.json"]);
        // A failing write (a file in a missing sub-folder) leaves the plan as it was.
        assert!(write_plan_folder(&out, &files(&["plan.json", "no/such.frag"])).is_err());
        let text = std::fs::read_to_string(out.join(LOD_SWITCH_FILE)).unwrap();
        assert_eq!(text, "lod_switch.frag\n");
        // A folder of other files, and a bake's folder, are refused and untouched.
        for other in ["mine.txt", crate::output::MANIFEST] {
            let d = dir.path().join(other.replace('.', "_"));
            std::fs::create_dir(&d).unwrap();
            std::fs::write(d.join(other), "x").unwrap();
            let e = write_plan_folder(&d, &files(&["plan.json"]))
                .unwrap_err()
                .to_string();
            assert!(e.contains(&format!("holds '{other}'")), "{e}");
            assert!(!d.join("plan.json").exists());
        }
        assert!(is_plan_file("part12.frag") && is_plan_file(".plan.json.tmp"));
        assert!(!is_plan_file("part.frag") && !is_plan_file("partx.frag"));
    }

    #[test]
    fn dropping_lobes_removes_their_lobe_and_colour_textures() {
        let s = crate::procedural::generate(16, 2);
        let map = s.map.with_feature(s.albedo).unwrap();
        let b = crate::methods::bake_with(&map, Method::Vmf, &FULL.bake_options()).unwrap();
        assert_eq!((b.lobes, b.textures.len()), (8, 16));
        let d = drop_lobes(b.clone(), &[1, 5]);
        assert_eq!((d.lobes, d.textures.len()), (6, 12));
        let kept = [0, 2, 3, 4, 6, 7];
        for (i, &j) in kept.iter().enumerate() {
            assert_eq!(d.textures[i], b.textures[j]);
            assert_eq!(d.textures[6 + i], b.textures[8 + j]);
        }
        assert_eq!(d.parameters["lobes"], 6);
    }

    #[test]
    fn colour_variation_is_the_relative_rms_of_luminance() {
        assert_eq!(color_variation(&[[0.5, 0.5, 0.5, 1.0]; 10]), 0.0);
        // Luminance 0.5 ± 0.25: relative RMS 0.5.
        let v = color_variation(&[[0.25; 4], [0.75; 4]]);
        assert!((v - 0.5).abs() < 1e-6, "{v}");
    }

    #[test]
    fn the_content_hash_sees_one_normal_change() {
        let a = crate::procedural::generate(16, 1).map;
        let mut n = a.normals().to_vec();
        n[77].x += 0.01;
        let b = NormalMap::from_vectors(16, 16, n, a.addressing(), BadNormals::Repair).unwrap();
        assert_ne!(content_hash(&a), content_hash(&b));
        assert_eq!(content_hash(&a), content_hash(&a.clone()));
    }
}
