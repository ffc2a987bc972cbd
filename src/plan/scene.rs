//! The scene description the planner reads (`docs/planner.md`): the material (BRDF model and
//! the range of its parameter, K_d and K_s), the lights, whether colour varies, the MIP levels
//! the renderer reaches (or the viewing distances and texel density they follow from),
//! anisotropic filtering, the error target and an optional budget. Parsed from TOML or JSON
//! with unknown keys refused; [`Scene::check`] refuses contradictory and out-of-range values
//! with one error naming the field.

use crate::brdf::Brdf;
use crate::error::{Error, Result, compact_f64};
use serde::{Deserialize, Serialize};

/// The most MIP levels a scene may name (a 2¹⁶-texel side has 17).
pub const MAX_LEVELS: usize = 17;

/// How many compact (and how many diffuse-only) lights the planner extracts from a scene's
/// environment ([`Scene::environment_light`]): the CLI's and the C API's default, 4.
pub const ENV_LIGHTS: usize = 4;

/// A scene: what the renderer does with the normal map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// The material.
    pub material: Material,
    /// The kinds of light: `"point"`, `"directional"`, `"environment"` (one or more).
    pub lights: Vec<LightKind>,
    /// The elevation of the point and directional lights above the surface, degrees, `[min,
    /// max]` in (0, 90] (default `[10, 90]`): a low sun is `[5, 20]`.
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "pair::light_elevation"
    )]
    pub light_elevation: Option<[f64; 2]>,
    /// The environment of an `"environment"` light: `"sky"` (the generated sky with a small
    /// bright sun, [`crate::environment::Sky`], the default), `"overcast"` (the same sky
    /// without its sun) or an equirectangular Radiance
    /// `.hdr` / OpenEXR file (a path relative to the scene file; through the C API, to the
    /// working directory). Its luminance lights the measurement.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub environment: Option<String>,
    /// Colour across the map.
    #[serde(default)]
    pub color: Color,
    /// What the renderer samples.
    pub view: View,
    /// The error the plan must meet.
    pub target: Target,
    /// An optional budget the plan must fit.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub budget: Option<Budget>,
}

/// The BRDF models a scene names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Model {
    /// Lambert only: no specular term.
    Lambert,
    /// Normalized Blinn-Phong, exponent range `material.exponent`.
    BlinnPhong,
    /// The Torrance–Sparrow Gaussian of eq 18, roughness range `material.sigma`.
    TorranceSparrow,
    /// GGX, roughness range `material.alpha`.
    Ggx,
}

/// The material: a BRDF model, the range of its parameter, and the weights of the terms.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Material {
    /// The BRDF model.
    pub model: Model,
    /// Blinn-Phong exponent range `[min, max]`, each > 0 (only with `blinn-phong`).
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "pair::exponent"
    )]
    pub exponent: Option<[f64; 2]>,
    /// GGX α range `[min, max]`, each in (0, 1] (only with `ggx`).
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "pair::alpha"
    )]
    pub alpha: Option<[f64; 2]>,
    /// Torrance–Sparrow σ range `[min, max]`, each in (0, 1] (only with `torrance-sparrow`).
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "pair::sigma"
    )]
    pub sigma: Option<[f64; 2]>,
    /// Weight of the Lambert term, ≥ 0 (default 1; 0 with Lambert is contradictory).
    #[serde(default = "one")]
    pub kd: f64,
    /// Weight of the specular term, ≥ 0 (default 1 with a specular model, must be 0 or absent
    /// with Lambert).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ks: Option<f64>,
}

fn one() -> f64 {
    1.0
}

/// A kind of light.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LightKind {
    /// Point lights (treated as directional at the texel's scale).
    Point,
    /// Directional lights (a sun).
    Directional,
    /// An environment (overcast sky, an HDR panorama).
    Environment,
}

/// Colour across the map.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Color {
    /// Whether the albedo varies across the map (default false). Ignored when `albedo` is
    /// given: then it is measured.
    #[serde(default)]
    pub varies: bool,
    /// An albedo image of the map's size whose variation the planner measures (a path,
    /// relative to the scene file).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub albedo: Option<String>,
}

/// What the renderer samples: MIP levels directly, or the distances and texel density they
/// follow from.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct View {
    /// The MIP levels reached, `[finest, coarsest]` (0 = the map's own resolution).
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "pair::levels"
    )]
    pub levels: Option<[u32; 2]>,
    /// Viewing distances `[near, far]`, > 0, in the unit of `texel_density`.
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "pair::distances"
    )]
    pub distances: Option<[f64; 2]>,
    /// Texels per screen pixel at distance 1 (> 0): at distance d a pixel covers
    /// `texel_density·d` texels, MIP level `log2(texel_density·d)`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub texel_density: Option<f64>,
    /// Whether the renderer filters anisotropically (then only parameters that filter linearly
    /// can be shipped: aligned lobes, SH, the baselines).
    #[serde(default)]
    pub anisotropic: bool,
}

/// The error target: texel-space relative RMS of each shading term the scene uses, overall or
/// per level.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Target {
    /// One target for every level, in (0, 1] (0.05 = 5 %).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<f64>,
    /// One target per level reached, finest first, each in (0, 1].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub per_level: Option<Vec<f64>>,
}

/// A budget: the plan fails when its cheapest configuration that meets the target exceeds it.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Budget {
    /// Texture memory, bytes (> 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub texture_bytes: Option<u64>,
    /// Texture fetches per pixel (> 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fetches: Option<u32>,
}

/// Readers of the two-element array fields (`[min, max]`, `[finest, coarsest]`, `[near, far]`):
/// any other length is an error naming the field, in TOML as in JSON (the toml crate's
/// fixed-size arrays take the first two elements of a longer array and ignore the rest).
mod pair {
    use serde::de::{Deserialize, Deserializer, Error};

    /// An optional array of exactly two `T`; `name` and `shape` are for the message.
    fn pair<'de, D: Deserializer<'de>, T: Deserialize<'de>>(
        d: D,
        name: &str,
        shape: &str,
    ) -> Result<Option<[T; 2]>, D::Error> {
        let Some(v) = Option::<Vec<T>>::deserialize(d)? else {
            return Ok(None);
        };
        let n = v.len();
        <[T; 2]>::try_from(v).map(Some).map_err(|_| {
            D::Error::custom(format!(
                "field '{name}': {n} value{} (expected {shape})",
                if n == 1 { "" } else { "s" }
            ))
        })
    }

    pub(super) fn light_elevation<'de, D: Deserializer<'de>>(
        d: D,
    ) -> Result<Option<[f64; 2]>, D::Error> {
        pair(d, "light_elevation", "[min, max]")
    }

    pub(super) fn exponent<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f64; 2]>, D::Error> {
        pair(d, "material.exponent", "[min, max]")
    }

    pub(super) fn alpha<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f64; 2]>, D::Error> {
        pair(d, "material.alpha", "[min, max]")
    }

    pub(super) fn sigma<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f64; 2]>, D::Error> {
        pair(d, "material.sigma", "[min, max]")
    }

    pub(super) fn levels<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[u32; 2]>, D::Error> {
        pair(d, "view.levels", "[finest, coarsest]")
    }

    pub(super) fn distances<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f64; 2]>, D::Error> {
        pair(d, "view.distances", "[near, far]")
    }
}

fn field(name: &str, message: impl std::fmt::Display) -> Error {
    Error::InvalidOption(format!("scene: field '{name}': {message}"))
}

fn finite(name: &str, v: f64) -> Result<()> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(field(
            name,
            format!("{} is not a finite number", compact_f64(v)),
        ))
    }
}

/// Checks a `[min, max]` range: finite, `lo ≤ min ≤ max ≤ hi`, min > 0.
fn range(name: &str, r: [f64; 2], hi: f64) -> Result<()> {
    finite(name, r[0])?;
    finite(name, r[1])?;
    if r[0] <= 0.0 || r[1] > hi {
        return Err(field(
            name,
            format!("{:?} must lie in (0, {}]", r, compact_f64(hi)),
        ));
    }
    if r[0] > r[1] {
        return Err(field(name, format!("{:?}: min is greater than max", r)));
    }
    Ok(())
}

impl Scene {
    /// Parses a scene from `text`: JSON when it starts with `{`, TOML otherwise; `name` (the
    /// file) is for messages. Then [`Scene::check`]. Errors: empty text, syntax, unknown keys
    /// and wrong types (serde's message names the key), and every check's.
    pub fn parse(name: &str, text: &str) -> Result<Scene> {
        let trimmed = text.trim_start_matches('\u{feff}').trim();
        if trimmed.is_empty() {
            return Err(Error::InvalidOption(format!(
                "scene {name}: the file is empty (expected a TOML or JSON scene, docs/planner.md)"
            )));
        }
        // The parsers' messages quote the input (TOML its line, serde a key or value): cut to
        // a few hundred characters, so a megabyte-long line still makes one readable line.
        let clip = |m: String| {
            let m = m.split_whitespace().collect::<Vec<_>>().join(" ");
            crate::error::clip_message(&m, crate::error::MAX_PARSE_ERROR_CHARS)
        };
        let scene: Scene = if trimmed.starts_with('{') {
            serde_json::from_str(trimmed).map_err(|e| {
                Error::InvalidOption(format!(
                    "scene {name}: not a valid JSON scene: {}",
                    clip(e.to_string())
                ))
            })?
        } else {
            toml::from_str(trimmed).map_err(|e| {
                Error::InvalidOption(format!(
                    "scene {name}: not a valid TOML scene: {}",
                    clip(e.to_string())
                ))
            })?
        };
        scene.check()?;
        Ok(scene)
    }

    /// Reads and parses a scene file ([`Scene::parse`]): a regular file (a FIFO, a device or
    /// a folder is [`Error::Read`], without blocking) of at most
    /// [`crate::ingest::MAX_TEXT_FILE_BYTES`].
    pub fn load(path: &std::path::Path) -> Result<Scene> {
        let bytes =
            crate::ingest::read_bounded(path, crate::ingest::MAX_TEXT_FILE_BYTES, "a scene file")?;
        let text = String::from_utf8(bytes).map_err(|_| {
            Error::InvalidOption(format!(
                "scene {}: not UTF-8 text (expected TOML or JSON)",
                path.display()
            ))
        })?;
        Scene::parse(&path.display().to_string(), &text)
    }

    /// Checks every value: ranges, NaN, and contradictions (a parameter range for another
    /// model, a specular model without its range, Lambert with K_s > 0, K_d = K_s = 0, no
    /// lights, levels and distances both or neither, a per-level target of the wrong length).
    /// The first problem is one [`Error::InvalidOption`] naming the field.
    pub fn check(&self) -> Result<()> {
        let m = &self.material;
        let ranges = [
            ("material.exponent", m.exponent, Model::BlinnPhong, 1e6),
            ("material.alpha", m.alpha, Model::Ggx, 1.0),
            ("material.sigma", m.sigma, Model::TorranceSparrow, 1.0),
        ];
        for (name, r, model, hi) in ranges {
            match r {
                Some(r) if m.model != model => {
                    let _ = r;
                    return Err(field(
                        name,
                        format!("given, but material.model is {:?}", m.model),
                    ));
                }
                Some(r) => range(name, r, hi)?,
                None if m.model == model => {
                    return Err(field(
                        name,
                        "missing: the model needs the range of its parameter",
                    ));
                }
                None => {}
            }
        }
        // The ends of the ranges as the BRDF library takes them (its sharpness bounds).
        for b in self.brdfs() {
            let name = match m.model {
                Model::BlinnPhong => "material.exponent",
                Model::Ggx => "material.alpha",
                Model::TorranceSparrow => "material.sigma",
                Model::Lambert => "material.model",
            };
            b.validate().map_err(|e| match e {
                Error::InvalidOption(msg) => field(name, msg),
                e => e,
            })?;
        }
        finite("material.kd", m.kd)?;
        if m.kd < 0.0 {
            return Err(field(
                "material.kd",
                format!("{} is negative", compact_f64(m.kd)),
            ));
        }
        if let Some(ks) = m.ks {
            finite("material.ks", ks)?;
            if ks < 0.0 {
                return Err(field(
                    "material.ks",
                    format!("{} is negative", compact_f64(ks)),
                ));
            }
            if m.model == Model::Lambert && ks > 0.0 {
                return Err(field(
                    "material.ks",
                    format!(
                        "{} > 0, but a Lambert material has no specular term",
                        compact_f64(ks)
                    ),
                ));
            }
        }
        if self.kd_ks().0 == 0.0 && self.kd_ks().1 == 0.0 {
            return Err(field(
                "material.kd",
                "K_d and K_s are both 0: the surface reflects nothing",
            ));
        }
        if self.lights.is_empty() {
            return Err(field("lights", "empty: name at least one kind of light"));
        }
        if let Some(e) = self.light_elevation {
            range("light_elevation", e, 90.0)?;
            if !self.lights.iter().any(|l| *l != LightKind::Environment) {
                return Err(field(
                    "light_elevation",
                    "given, but the scene has no point or directional light",
                ));
            }
        }
        if let Some(env) = &self.environment {
            if !self.has_environment() {
                return Err(field(
                    "environment",
                    "given, but lights has no \"environment\"",
                ));
            }
            if env.is_empty() {
                return Err(field(
                    "environment",
                    "empty (expected \"sky\", \"overcast\" or a file)",
                ));
            }
        }
        if self.has_environment() && m.model == Model::TorranceSparrow {
            return Err(field(
                "material.model",
                "torrance-sparrow under an environment: the environment routes implement \
                 lambert, blinn-phong and ggx",
            ));
        }
        if let Some(albedo) = &self.color.albedo
            && albedo.is_empty()
        {
            return Err(field("color.albedo", "empty path"));
        }
        let v = &self.view;
        match (v.levels, v.distances, v.texel_density) {
            (Some(_), Some(_), _) | (Some(_), _, Some(_)) => {
                return Err(field(
                    "view.levels",
                    "given with view.distances/view.texel_density: give one or the other",
                ));
            }
            (Some([a, b]), None, None) if a > b => {
                return Err(field(
                    "view.levels",
                    format!("[{a}, {b}]: finest is greater than coarsest"),
                ));
            }
            (Some([_, b]), None, None) if b as usize >= MAX_LEVELS => {
                return Err(field("view.levels", format!("level {b} is beyond any map")));
            }
            (None, Some(d), Some(t)) => {
                range("view.distances", d, f64::MAX)?;
                finite("view.texel_density", t)?;
                if t <= 0.0 {
                    return Err(field(
                        "view.texel_density",
                        format!("{} must be > 0", compact_f64(t)),
                    ));
                }
            }
            (None, Some(_), None) => {
                return Err(field(
                    "view.texel_density",
                    "missing: distances convert to levels through the texel density",
                ));
            }
            (None, None, Some(_)) => {
                return Err(field(
                    "view.distances",
                    "missing: the density needs distances",
                ));
            }
            (None, None, None) => {
                return Err(field(
                    "view",
                    "give view.levels, or view.distances and view.texel_density",
                ));
            }
            _ => {}
        }
        match (&self.target.error, &self.target.per_level) {
            (Some(_), Some(_)) => {
                return Err(field(
                    "target.per_level",
                    "given with target.error: give one or the other",
                ));
            }
            (None, None) => return Err(field("target.error", "missing: the plan needs a target")),
            (Some(e), None) => target_value("target.error", *e)?,
            (None, Some(p)) => {
                if p.is_empty() {
                    return Err(field("target.per_level", "empty"));
                }
                for &e in p {
                    target_value("target.per_level", e)?;
                }
                if let Some([a, b]) = v.levels
                    && p.len() != (b - a + 1) as usize
                {
                    return Err(field(
                        "target.per_level",
                        format!(
                            "{} values for view.levels [{a}, {b}] ({} levels)",
                            p.len(),
                            b - a + 1
                        ),
                    ));
                }
            }
        }
        if let Some(b) = &self.budget {
            if b.texture_bytes == Some(0) {
                return Err(field("budget.texture_bytes", "0 (must be > 0)"));
            }
            if b.fetches == Some(0) {
                return Err(field("budget.fetches", "0 (must be > 0)"));
            }
        }
        Ok(())
    }

    /// K_d and K_s with their defaults (K_s: 1 with a specular model, 0 with Lambert).
    pub fn kd_ks(&self) -> (f64, f64) {
        let m = &self.material;
        let ks =
            m.ks.unwrap_or(if m.model == Model::Lambert { 0.0 } else { 1.0 });
        (m.kd, ks)
    }

    /// Whether the scene uses the specular term (a specular model with K_s > 0).
    pub fn specular(&self) -> bool {
        self.material.model != Model::Lambert && self.kd_ks().1 > 0.0
    }

    /// The BRDFs the planner measures: the two ends of the parameter range (the sharpest and
    /// the bluntest; one when they are equal), or Lambert.
    pub fn brdfs(&self) -> Vec<Brdf> {
        let m = &self.material;
        let mut out = match m.model {
            Model::Lambert => return vec![Brdf::Lambert],
            Model::BlinnPhong => {
                let [a, b] = m.exponent.unwrap_or([1.0, 1.0]);
                vec![Brdf::BlinnPhong { s: b }, Brdf::BlinnPhong { s: a }]
            }
            Model::Ggx => {
                let [a, b] = m.alpha.unwrap_or([1.0, 1.0]);
                vec![Brdf::ggx(a), Brdf::ggx(b)]
            }
            Model::TorranceSparrow => {
                let [a, b] = m.sigma.unwrap_or([1.0, 1.0]);
                vec![
                    Brdf::TorranceSparrow { sigma: a },
                    Brdf::TorranceSparrow { sigma: b },
                ]
            }
        };
        out.dedup();
        out
    }

    /// The MIP levels the renderer reaches, `[finest, coarsest]`, for a map with `levels`
    /// levels: `view.levels`, or `floor(log2(texel_density·d))` at the two distances, clamped
    /// to the map. [`Error::InvalidOption`] naming `view.levels` when they lie outside the map.
    pub fn level_range(&self, levels: usize) -> Result<[usize; 2]> {
        let last = levels.saturating_sub(1);
        if let Some([a, b]) = self.view.levels {
            if b as usize > last {
                return Err(field(
                    "view.levels",
                    format!("[{a}, {b}] reaches beyond the map's coarsest level {last}"),
                ));
            }
            return Ok([a as usize, b as usize]);
        }
        let (Some([near, far]), Some(t)) = (self.view.distances, self.view.texel_density) else {
            return Err(field("view", "no levels and no distances"));
        };
        let level = |d: f64| -> usize {
            let l = (t * d).log2();
            if l <= 0.0 {
                0
            } else {
                (l.ceil() as usize).min(last)
            }
        };
        Ok([level(near).min(last), level(far)])
    }

    /// The target at `level` (0-based in the map) for a range starting at `first`.
    pub fn target_at(&self, first: usize, level: usize) -> f64 {
        match (&self.target.error, &self.target.per_level) {
            (Some(e), _) => *e,
            (None, Some(p)) => p[(level - first).min(p.len() - 1)],
            (None, None) => 0.0,
        }
    }

    /// Whether the scene has point or directional lights.
    pub fn has_direct(&self) -> bool {
        self.lights.iter().any(|l| *l != LightKind::Environment)
    }

    /// Whether the scene has an environment.
    pub fn has_environment(&self) -> bool {
        self.lights.contains(&LightKind::Environment)
    }

    /// Whether shading bakes of `methods` under this scene's environment needs the SH route's
    /// `L′` tables ([`Scene::environment_light`]'s `sh_route`): an SH bake under a specular
    /// BRDF (eq 26 reads them; Lambert and every other method are shaded without). Planning
    /// asks it of its candidates, verifying (`WholeMap`) of the plan's parts.
    pub fn needs_sh_route(&self, methods: impl IntoIterator<Item = crate::bake::Method>) -> bool {
        methods.into_iter().any(|m| m == crate::bake::Method::Sh)
            && self.brdfs().iter().any(|b| b.has_specular())
    }

    /// The environment to light with, when the scene has one: `environment` read (a relative
    /// path against the working directory), or the generated sky (with or without its sun);
    /// RGB. Its compact bright sources (a sun, lamps) are extracted as lights, as everywhere
    /// by default ([`crate::environment::lights::LightOptions::up_to`]`(`[`ENV_LIGHTS`]`)`:
    /// the routes shade the residual, the lights are shaded per lobe; the plan's shaders add
    /// them, `NDF_ENV_LIGHTS`). Prepared for the prefiltered route and the diffuse SH only
    /// ([`crate::envlight::EnvLight::prefiltered_only_with_lights`]) unless `sh_route` (an SH
    /// bake is measured under a specular BRDF: eq 26 reads the `L′` tables).
    pub fn environment_light(&self, sh_route: bool) -> Result<Option<crate::envlight::EnvLight>> {
        if !self.has_environment() {
            return Ok(None);
        }
        let env = match self.environment.as_deref() {
            None | Some("sky") => crate::environment::Sky::default().render()?,
            Some("overcast") => crate::environment::Sky {
                sun: [0.0; 3],
                ..Default::default()
            }
            .render()?,
            Some(path) => crate::environment::load(
                std::path::Path::new(path),
                &crate::environment::EnvOptions::default(),
            )
            .map_err(|e| Error::InvalidOption(format!("scene: field 'environment': {e}")))?,
        };
        let lights = crate::environment::lights::LightOptions::up_to(ENV_LIGHTS);
        Ok(Some(if sh_route {
            crate::envlight::EnvLight::with_lights(&env, &lights)
        } else {
            crate::envlight::EnvLight::prefiltered_only_with_lights(&env, &lights)
        }))
    }
}

fn target_value(name: &str, e: f64) -> Result<()> {
    finite(name, e)?;
    if e <= 0.0 || e > 1.0 {
        return Err(field(
            name,
            format!(
                "{} must lie in (0, 1] (a relative RMS error: 0.05 = 5 %)",
                compact_f64(e)
            ),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const GLOSSY: &str = r#"
lights = ["point"]
[material]
model = "blinn-phong"
exponent = [16, 256]
kd = 0.2
ks = 0.8
[view]
levels = [0, 4]
[target]
error = 0.05
"#;

    fn err(text: &str) -> String {
        Scene::parse("t", text).unwrap_err().to_string()
    }

    #[test]
    fn toml_and_json_give_the_same_scene() {
        let t = Scene::parse("t", GLOSSY).unwrap();
        let json = serde_json::to_string(&t).unwrap();
        let j = Scene::parse("j", &json).unwrap();
        assert_eq!(t, j);
        assert_eq!(t.kd_ks(), (0.2, 0.8));
        assert_eq!(
            t.brdfs(),
            vec![Brdf::BlinnPhong { s: 256.0 }, Brdf::BlinnPhong { s: 16.0 }]
        );
        assert_eq!(t.level_range(11).unwrap(), [0, 4]);
    }

    #[test]
    fn the_sh_route_is_needed_by_an_sh_bake_under_a_specular_brdf_only() {
        use crate::bake::Method;
        let glossy = Scene::parse("t", GLOSSY).unwrap();
        assert!(glossy.needs_sh_route([Method::Plain, Method::Sh]));
        assert!(!glossy.needs_sh_route([Method::Plain, Method::Vmf, Method::Lean]));
        assert!(!glossy.needs_sh_route([]));
        let matte = GLOSSY
            .replace("model = \"blinn-phong\"", "model = \"lambert\"")
            .replace("exponent = [16, 256]\n", "")
            .replace("ks = 0.8", "ks = 0.0");
        let matte = Scene::parse("t", &matte).unwrap();
        assert!(!matte.needs_sh_route([Method::Sh]));
    }

    #[test]
    fn distances_convert_to_levels() {
        let s = GLOSSY.replace(
            "levels = [0, 4]",
            "distances = [2.0, 40.0]\ntexel_density = 1.0",
        );
        let s = Scene::parse("t", &s).unwrap();
        // log2(2) = 1, log2(40) = 5.32 → 6; a 64² map has levels 0..6.
        assert_eq!(s.level_range(11).unwrap(), [1, 6]);
        assert_eq!(s.level_range(4).unwrap(), [1, 3]);
    }

    #[test]
    fn bad_scenes_name_the_field() {
        let cases: &[(&str, &str)] = &[
            ("", "empty"),
            ("   \n", "empty"),
            ("this is not toml", "not a valid TOML"),
            ("{\"lights\": }", "not a valid JSON"),
            (&GLOSSY.replace("kd = 0.2", "kd = 0.2\nshine = 3"), "shine"),
            (&GLOSSY.replace("error = 0.05", "error = \"low\""), "error"),
            (
                &GLOSSY.replace("error = 0.05", "error = nan"),
                "target.error",
            ),
            (&GLOSSY.replace("error = 0.05", "error = 0"), "target.error"),
            (
                &GLOSSY.replace("error = 0.05", "error = -0.1"),
                "target.error",
            ),
            (
                &GLOSSY.replace("[16, 256]", "[0, 256]"),
                "material.exponent",
            ),
            (
                &GLOSSY.replace("[16, 256]", "[-4, 256]"),
                "material.exponent",
            ),
            (
                &GLOSSY.replace("[16, 256]", "[256, 16]"),
                "material.exponent",
            ),
            (
                &GLOSSY.replace("exponent = [16, 256]", ""),
                "material.exponent",
            ),
            (
                &GLOSSY.replace(
                    "exponent = [16, 256]",
                    "exponent = [16, 256]\nalpha = [0.1, 0.2]",
                ),
                "material.alpha",
            ),
            (
                &GLOSSY.replace(
                    "model = \"blinn-phong\"\nexponent = [16, 256]",
                    "model = \"lambert\"",
                ),
                "material.ks",
            ),
            (&GLOSSY.replace("kd = 0.2", "kd = -1"), "material.kd"),
            (
                &GLOSSY.replace("kd = 0.2\nks = 0.8", "kd = 0\nks = 0"),
                "material.kd",
            ),
            (&GLOSSY.replace("[\"point\"]", "[]"), "lights"),
            (&GLOSSY.replace("[\"point\"]", "[\"laser\"]"), "laser"),
            (&GLOSSY.replace("[0, 4]", "[4, 0]"), "view.levels"),
            (
                &GLOSSY.replace("levels = [0, 4]", "distances = [1, 2]"),
                "view.texel_density",
            ),
            (
                &GLOSSY.replace("error = 0.05", "per_level = [0.1, 0.1]"),
                "target.per_level",
            ),
            (
                &GLOSSY.replace("error = 0.05", "error = 0.05\nper_level = [0.1]"),
                "target.per_level",
            ),
            (
                &GLOSSY.replace(
                    "lights = [\"point\"]",
                    "lights = [\"environment\"]\nlight_elevation = [5, 20]",
                ),
                "light_elevation",
            ),
            (
                &GLOSSY.replace(
                    "lights = [\"point\"]",
                    "lights = [\"point\"]\nenvironment = \"sky\"",
                ),
                "'environment'",
            ),
            (
                &GLOSSY.replace(
                    "lights = [\"point\"]",
                    "lights = [\"environment\"]\nenvironment = \"\"",
                ),
                "'environment'",
            ),
            (
                "lights = [\"environment\"]\n[material]\nmodel = \"torrance-sparrow\"\n\
                 sigma = [0.1, 0.2]\n[view]\nlevels = [0, 1]\n[target]\nerror = 0.05\n",
                "material.model",
            ),
            (
                &format!("{GLOSSY}[budget]\ntexture_bytes = 0\n"),
                "budget.texture_bytes",
            ),
            (
                &format!("{GLOSSY}[budget]\ntexture_bytes = -5\n"),
                "texture_bytes",
            ),
        ];
        for (text, needle) in cases {
            let e = err(text);
            assert!(e.contains(needle), "{text:?}: {e}");
            assert!(!e.contains('\n'), "one line: {e}");
        }
        // Levels beyond the map: the map is known only when planning.
        let s = Scene::parse("t", &GLOSSY.replace("[0, 4]", "[0, 12]")).unwrap();
        let e = s.level_range(11).unwrap_err().to_string();
        assert!(e.contains("view.levels"), "{e}");
    }

    #[test]
    fn two_element_arrays_of_any_other_length_are_refused_naming_the_field() {
        // The toml crate's fixed-size arrays took the first two elements of `[8, 16, 32]` and
        // ignored the rest; JSON refused a third element without naming the field.
        let with_model = |model: &str, line: &str| {
            GLOSSY.replace(
                "model = \"blinn-phong\"\nexponent = [16, 256]",
                &format!("model = \"{model}\"\n{line}"),
            )
        };
        let cases: [(String, &str, &str, f64, f64); 6] = [
            (
                GLOSSY.into(),
                "exponent = [16, 256]",
                "material.exponent",
                16.0,
                256.0,
            ),
            (
                with_model("ggx", "alpha = [0.1, 0.25]"),
                "alpha = [0.1, 0.25]",
                "material.alpha",
                0.1,
                0.25,
            ),
            (
                with_model("torrance-sparrow", "sigma = [0.1, 0.25]"),
                "sigma = [0.1, 0.25]",
                "material.sigma",
                0.1,
                0.25,
            ),
            (
                format!("light_elevation = [10, 80]\n{GLOSSY}"),
                "light_elevation = [10, 80]",
                "light_elevation",
                10.0,
                80.0,
            ),
            (GLOSSY.into(), "levels = [0, 4]", "view.levels", 0.0, 4.0),
            (
                GLOSSY.replace(
                    "levels = [0, 4]",
                    "distances = [2, 40]\ntexel_density = 1.0",
                ),
                "distances = [2, 40]",
                "view.distances",
                2.0,
                40.0,
            ),
        ];
        for (text, line, name, a, b) in cases {
            let key = line.split(' ').next().unwrap();
            let path: Vec<&str> = name.split('.').collect();
            // Two values parse, and are the ones written.
            let scene = Scene::parse("t", &text).unwrap();
            let json = serde_json::to_value(&scene).unwrap();
            let at = path.iter().fold(&json, |v, k| &v[*k]);
            let want = if name == "view.levels" {
                serde_json::json!([a as u32, b as u32])
            } else {
                serde_json::json!([a, b])
            };
            assert_eq!(at, &want, "{name}");
            for n in [0usize, 1, 3, 5] {
                let values: Vec<f64> = (0..n).map(|i| if i % 2 == 0 { a } else { b }).collect();
                let words = format!(
                    "field '{name}': {n} value{} (expected [",
                    if n == 1 { "" } else { "s" }
                );
                let list: Vec<String> = values.iter().map(|v| v.to_string()).collect();
                let toml_text = text.replace(line, &format!("{key} = [{}]", list.join(", ")));
                assert_ne!(toml_text, text);
                let e = err(&toml_text);
                assert!(e.contains(&words) && e.contains("scene t"), "{n}: {e}");
                let mut bad = json.clone();
                let slot = path.iter().fold(&mut bad, |v, k| &mut v[*k]);
                *slot = if name == "view.levels" {
                    serde_json::json!(values.iter().map(|&v| v as u32).collect::<Vec<_>>())
                } else {
                    serde_json::json!(values)
                };
                let e = err(&bad.to_string());
                assert!(e.contains(&words) && e.contains("JSON"), "{n}: {e}");
            }
        }
    }

    #[test]
    fn parse_errors_quoting_a_huge_line_stay_one_short_line() {
        // The TOML error quoted the offending line three times: a 1 MB key made a 3 MB error.
        let key = "k".repeat(1 << 20);
        for text in [
            format!("{key} = 1\n{GLOSSY}"),
            format!("{{\"{key}\": 1}}"),
            GLOSSY.replace("model = \"blinn-phong\"", &format!("model = \"{key}\"")),
        ] {
            let e = err(&text);
            assert!(
                e.len() < 1000 && e.contains("scene t: not a valid") && e.ends_with("characters)"),
                "{}",
                &e[..e.len().min(600)]
            );
        }
        // Range bounds and absurd values print compactly, not as 309-digit numbers.
        let e = err(&GLOSSY.replace(
            "levels = [0, 4]",
            "distances = [0, 4.0]\ntexel_density = 1.0",
        ));
        assert!(
            e.ends_with("[0.0, 4.0] must lie in (0, 1.7976931348623157e308]"),
            "{e}"
        );
        let e = err(&GLOSSY.replace("kd = 0.2", "kd = -1e300"));
        assert!(e.ends_with("'material.kd': -1e300 is negative"), "{e}");
    }
}
