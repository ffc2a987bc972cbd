//! Environment-lit shading (issue 16; Han et al. 2007 Sec 8, eqs 24–26, and the prefiltered
//! lookups of the Gaussian-mixture paper's Sec 4): the ground truth, the two routes every
//! method is shaded by, and the texel-space evaluation behind `ndfmap eval --env`.
//!
//! Everything is in the environment's frame ([`crate::environment`]), which texel-space
//! evaluation takes as the tangent frame (macro normal = zenith). Shading terms have the units
//! of the point-light ones with `L` in place of the light: diffuse `∫ L(ω_i) max(ω_i·n, 0) dω_i`
//! (π·L for a constant L), specular `∫ L(ω_i) f(ω_h·n) max(ω_i·n, 0) g dω_i`.
//!
//! - **Ground truth** ([`ground_truth`]): the footprint average over the unfiltered normals of
//!   both integrals by Monte Carlo, one sample of the environment's 2D CDF and one of the BRDF
//!   (cosine for the diffuse term; `f(ω_h·n)(ω_h·n)`-proportional half vectors for GGX,
//!   `f(ω_h·n)` for Blinn-Phong, reflected about the view) per iteration, combined by the
//!   balance heuristic; normals drawn stratified by footprint weight; the standard error is
//!   measured from the samples. Deterministic per seed.
//! - **Diffuse, both routes** (eq 25): per lobe `α Σ_{l≤2} ρ̂_l A_l(κ) Σ_m L_lm Y_lm(μ)` with the
//!   vMF's exact Legendre coefficients `A_1 = |r|`, `A_2 = 1 − 3|r|/κ` (eq 19's `e^{−l²/2κ}` is
//!   their large-κ form); the single-lobe baselines are one lobe (plain: κ = ∞; Toksvig:
//!   `|r| = |n̄|`; LEAN: κ from its mean isotropic slope variance), Tan 2005's Gaussians one
//!   lobe each (μ lifted from the planar mean, κ = 1/σ², weight α). Olano–North stores the
//!   footprint's first and second moments `E[n]`, `E[nnᵀ]`, which are exactly what the bands
//!   l ≤ 2 need: its diffuse term is `Σ_{l≤2} ρ̂_l Σ_m L_lm E[Y_lm(n)]` with `E[Y_1m]` linear in
//!   `E[n]` and `E[Y_2m]` linear in `E[nnᵀ]` (`moments_diffuse`), the footprint average
//!   itself up to the environment's band 2, as for SH bakes.
//! - **Specular, prefiltered route**: per lobe (Olano–North: one, about `normalize(E[n])`
//!   with κ the inverse of the mean per-axis variance of its tangent-plane covariance) the
//!   BRDF widened by the lobe (eq 20 `s'`, GGX `α'` — GGX's lobe tabulated as eq 14, the
//!   exact convolution of GGX with the vMF, over `α'` and the NDF's share of it, since a wide
//!   vMF keeps its short tail where a widened GGX has GGX's long one), its lobe over incident directions
//!   `w(ω_i) = f'(ω_h·μ) max(ω_i·μ, 0)` replaced by
//!   the vMF matching its first moment (mean direction and mean resultant length, tabulated per
//!   `(ω_o·μ, s')` by `energy_quadrature::lobe_moments`: the mean direction is a tabulated blend of μ and the
//!   reflected direction `r = 2(ω_o·μ)μ − ω_o`, κ_i from the mean's length; the `4(ω_o·ω_h)` Jacobian, the cosine and the horizon are in both — the earlier
//!   `κ_i = s'/4` about `r` was off by up to 14 % at 80° views under an overcast sky), one
//!   lookup (GGX: two, a core vMF at the lobe's mode and a tail vMF about its mean, the same
//!   first moment in total: `energy_quadrature::two_vmf_fit`) of the prefiltered environment at `LOD = ½ log2(Ω_s/Ω_p)`, times the lobe's energy
//!   `E(ω_o·μ, s') = ∫ w dω_i` from the same table (the "split sum": exact for a constant
//!   environment), times `g(r, μ)`.
//! - **Specular, SH route** (eq 26): per lobe `Σ_l ρ̂_l e^{−l²/2κ} Σ_m L′_lm(ω_o) Y_lm(μ)` with
//!   `L′` from the view grid ([`crate::environment::projection::ReflectedTable`]), times the
//!   paper's cosine `max(ω_o·μ, 0)` (ω_i·μ at the lobe's peak) and `g(r, μ)`, clamped at 0.
//! - **The SH NDF method** (`--method sh`, bands `c_lm = Λ_l E[Y_lm(n)]`): diffuse
//!   `Σ_{l≤2} ρ̂_l/Λ_l · L_lm c_lm` with the environment's coefficients rotated into the tangent
//!   frame, exact for the footprint up to the environment's band 2; specular
//!   `Σ_{l≤min(l*,8)} ρ̂_l/Λ_l · L′_lm c_lm · max(ω_o·n̄, 0)`.
//!
//! Supported BRDFs: Lambert, Blinn-Phong, GGX (the g factor included). Supported methods:
//! plain, Toksvig, LEAN, Olano–North, vMF, Tan 2005, SH.

use crate::bake::{Bake, Method};
use crate::brdf::Brdf;
use crate::environment::lights::{Light, LightOptions};
use crate::environment::prefilter::Prefiltered;
use crate::environment::projection::{self, ReflectedTable};
use crate::environment::sampling::EnvSampler;
use crate::environment::{Environment, LUMINANCE, Radiance};
use crate::error::{Error, Result};
use crate::harmonics::{Basis, count, lambda};
use crate::pyramid::pyramid;
use crate::rng::Rng;
use glam::{DMat3, DVec3};
use rayon::prelude::*;
use serde::Serialize;
use std::f64::consts::PI;

/// How the lobe tables are computed (tests only; the library embeds them).
#[cfg(test)]
mod energy_quadrature;

/// Band limit of the environment's SH (eq 25, 26): the paper's l* = 8.
pub const ENV_LMAX: usize = 8;

/// One colour channel of an environment prepared for the routes: its radiance, prefiltered
/// levels, SH coefficients and `L′` table (everything that depends on the radiance; the routes
/// are linear in it, so each channel is the single-channel computation). A channel of
/// [`EnvLight::prefiltered_only`] has no `L′` table.
#[derive(Debug, Clone)]
pub struct EnvChannel {
    radiance: Radiance,
    prefiltered: Prefiltered,
    sh: Vec<f64>,
    reflected: Option<ReflectedTable>,
}

impl EnvChannel {
    fn new(radiance: Radiance, with_reflected: bool) -> EnvChannel {
        EnvChannel::with_residual(radiance.clone(), radiance.clone(), radiance, with_reflected)
    }

    /// A channel whose specular routes read `residual` (the environment less its compact
    /// extracted lights, [`crate::environment::lights`]), whose diffuse SH reads
    /// `diffuse_residual` (less the diffuse-only lights too), while the ground truth reads the
    /// full `radiance`.
    fn with_residual(
        radiance: Radiance,
        residual: Radiance,
        diffuse_residual: Radiance,
        with_reflected: bool,
    ) -> EnvChannel {
        EnvChannel {
            prefiltered: Prefiltered::new(&residual),
            sh: projection::project(&diffuse_residual, ENV_LMAX),
            reflected: with_reflected.then(|| ReflectedTable::new(&residual, ENV_LMAX)),
            radiance,
        }
    }

    /// The channel's full radiance (what the ground truth integrates; with extracted lights
    /// the prefiltered levels, SH and `L′` are of the residual, [`EnvLight::lights`]).
    pub fn radiance(&self) -> &Radiance {
        &self.radiance
    }

    /// The prefiltered levels.
    pub fn prefiltered(&self) -> &Prefiltered {
        &self.prefiltered
    }

    /// `L_lm`, l ≤ [`ENV_LMAX`], in the environment's frame.
    pub fn sh(&self) -> &[f64] {
        &self.sh
    }

    /// The `L′_lm(ω_o)` table (eq 26's reflected radiance); an error naming the constructor for
    /// a channel of [`EnvLight::prefiltered_only`], which has none.
    pub fn reflected(&self) -> Result<&ReflectedTable> {
        self.reflected.as_ref().ok_or_else(no_reflected)
    }

    /// `L′(view)` from the table. Panics on a channel of [`EnvLight::prefiltered_only`] (reached
    /// only by calling [`shade_in_with`] directly with the SH route on such a light: a
    /// programming error, which every fallible entry point refuses first with a typed error,
    /// [`EnvLight::check_routes`]; never a silent NaN).
    fn reflected_at(&self, view: DVec3) -> Vec<f64> {
        match &self.reflected {
            Some(t) => t.at(view),
            None => panic!("{}", no_reflected()),
        }
    }
}

fn no_reflected() -> Error {
    Error::InvalidOption(
        "environment prepared for the prefiltered route only (EnvLight::prefiltered_only): \
         the SH route (eq 26) needs its L′ table, prepared by EnvLight::new"
            .into(),
    )
}

/// An environment ready to light with, in RGB: per channel ([`EnvChannel`]) the prefiltered
/// levels, SH coefficients and `L′` table; shared by the channels, the radiance-independent
/// lobe-energy tables of the prefiltered route and the SH rotation constants; and the Rec. 709
/// luminance with its importance sampler, which the ground truth ([`ground_truth`]) integrates
/// (`eval`/`report --env` measure the luminance of the RGB result: the ground truth is linear
/// in radiance, so its luminance is the luminance of the RGB ground truth).
pub struct EnvLight {
    channels: [EnvChannel; 3],
    lights: Vec<Light>,
    luminance: Radiance,
    sampler: Option<EnvSampler>,
    energy: &'static EnergyTables,
    x90: Vec<f64>,
}

impl EnvLight {
    /// Prepares the RGB environment `env` (prefiltering, projection, tables per channel, the
    /// three channels in parallel: about 3 CPU-s for a 1024 × 512 panorama).
    pub fn new(env: &Environment) -> EnvLight {
        EnvLight::prepare(env, true, &LightOptions::none())
    }

    /// [`EnvLight::new`] with the environment's bright compact sources extracted as distant
    /// lights ([`crate::environment::lights::extract`] under `lights`; `max_lights = 0` is
    /// [`EnvLight::new`]): the prefiltered levels, SH and `L′` tables are of the residual, and
    /// every route adds each light's term per lobe as the point-light path shades it
    /// ([`light_term`]). The ground truth still integrates the full environment.
    pub fn with_lights(env: &Environment, lights: &LightOptions) -> EnvLight {
        EnvLight::prepare(env, true, lights)
    }

    /// Prepares `env` for the prefiltered route (eq 22 with the lobe tables), the diffuse SH
    /// (eq 25) and the ground truth only: no per-channel `L′` table (eq 26), which the SH route
    /// and the SH bakes' specular term read. Those are refused on such a light with a typed
    /// error ([`EnvLight::check_routes`], called by [`Reference::score_levels`], [`evaluate`]
    /// and `envgpu::pack`). What the planner measures with (the `L′` tables were a third of a
    /// matte plan's time); everything it does prepare is bit for bit [`EnvLight::new`]'s.
    pub fn prefiltered_only(env: &Environment) -> EnvLight {
        EnvLight::prepare(env, false, &LightOptions::none())
    }

    /// [`EnvLight::prefiltered_only`] with extracted lights ([`EnvLight::with_lights`]).
    pub fn prefiltered_only_with_lights(env: &Environment, lights: &LightOptions) -> EnvLight {
        EnvLight::prepare(env, false, lights)
    }

    fn prepare(env: &Environment, with_reflected: bool, lights: &LightOptions) -> EnvLight {
        let extraction = crate::environment::lights::extract(env, lights);
        let (residual, diffuse) = (&extraction.residual, &extraction.diffuse_residual);
        let prepare = |c: usize| {
            EnvChannel::with_residual(
                env.channel(c),
                residual.channel(c),
                diffuse.channel(c),
                with_reflected,
            )
        };
        let (r, (g, b)) = rayon::join(|| prepare(0), || rayon::join(|| prepare(1), || prepare(2)));
        let mut light = EnvLight::from_channels([r, g, b], env.luminance());
        light.lights = extraction.lights;
        light
    }

    /// The lights extracted from the environment (empty for [`EnvLight::new`]), most powerful
    /// first.
    pub fn lights(&self) -> &[Light] {
        &self.lights
    }

    /// Prepares a grey environment: `radiance` in all three channels (prepared once). Its
    /// luminance is `radiance` (the Rec. 709 weights sum to 1).
    pub fn grey(radiance: Radiance) -> EnvLight {
        let one = EnvChannel::new(radiance.clone(), true);
        EnvLight::from_channels([one.clone(), one.clone(), one], radiance)
    }

    /// Whether the light has the `L′` tables of the SH route (false for
    /// [`EnvLight::prefiltered_only`]).
    pub fn has_sh_route(&self) -> bool {
        self.channels.iter().all(|c| c.reflected.is_some())
    }

    /// Refuses, with a typed error, shading `bakes` by `routes` under `brdfs` on a light that
    /// lacks what they read: the SH route (and any SH bake) with a specular BRDF needs the
    /// `L′` tables that [`EnvLight::prefiltered_only`] leaves out.
    pub fn check_routes(&self, bakes: &[&Bake], routes: &[Route], brdfs: &[Brdf]) -> Result<()> {
        let specular = brdfs.iter().any(|b| b.has_specular());
        let sh = bakes.iter().any(|b| {
            b.method == Method::Sh || (is_mixture(b.method) && routes.contains(&Route::Sh))
        });
        if specular && sh && !self.has_sh_route() {
            return Err(no_reflected());
        }
        Ok(())
    }

    fn from_channels(channels: [EnvChannel; 3], luminance: Radiance) -> EnvLight {
        // `ground_truth_with` reads every channel at the luminance's texel index.
        debug_assert!(channels.iter().all(|c| {
            (c.radiance.width(), c.radiance.height()) == (luminance.width(), luminance.height())
        }));
        EnvLight {
            channels,
            lights: Vec::new(),
            sampler: EnvSampler::new(&luminance),
            luminance,
            energy: energy_tables(),
            x90: projection::x90_blocks(ENV_LMAX),
        }
    }

    /// Channel `c` (0 = R, 1 = G, 2 = B; clamped).
    pub fn channel(&self, c: usize) -> &EnvChannel {
        &self.channels[c.min(2)]
    }

    /// The three channels.
    pub fn channels(&self) -> &[EnvChannel; 3] {
        &self.channels
    }

    /// The Rec. 709 luminance the ground truth integrates.
    pub fn luminance(&self) -> &Radiance {
        &self.luminance
    }

    /// The prefiltered route's lobe table of `brdf`'s family (Blinn-Phong or GGX):
    /// [`ENERGY_BLOCKS`] × [`ENERGY_PARAM`] rows of `shares` × [`ENERGY_COS`] values,
    /// row-major (GGX: [`ENERGY_SHARES`] shares; Blinn-Phong one) — the energy `E(c_o, p)`,
    /// then the blend, `log2 κ_c`, the tail share `t`, `log2 κ_t`, the core's blend and the
    /// half-vector blocks (`energy_quadrature::lobe_moments`) — what the shaders read
    /// bilinearly ([`crate::envgpu::energy`] repeats Blinn-Phong's share; `None` for a BRDF
    /// without one: Lambert and the unsupported ones). One table for all channels.
    pub fn energy_table(&self, brdf: &Brdf) -> Option<&[f64]> {
        match brdf {
            Brdf::BlinnPhong { .. } => Some(self.energy.blinn_phong_table()),
            Brdf::Ggx(_) => Some(self.energy.ggx_table()),
            _ => None,
        }
    }
}

/// Environment-lit shading per colour channel (R, G, B): the terms of
/// [`crate::brdf::Shading`] for each channel's radiance.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RgbShading {
    /// Diffuse term per channel.
    pub diffuse: [f64; 3],
    /// Specular term per channel (g included).
    pub specular: [f64; 3],
}

impl RgbShading {
    /// Channel `c` (0 = R, 1 = G, 2 = B; clamped).
    pub fn channel(&self, c: usize) -> crate::brdf::Shading {
        let c = c.min(2);
        crate::brdf::Shading {
            diffuse: self.diffuse[c],
            specular: self.specular[c],
        }
    }

    /// Rec. 709 luminance of the RGB terms ([`crate::environment::LUMINANCE`]): what
    /// `eval`/`report --env` compare with the ground truth.
    pub fn luminance(&self) -> crate::brdf::Shading {
        let dot = |v: &[f64; 3]| (0..3).map(|c| LUMINANCE[c] * v[c]).sum::<f64>();
        crate::brdf::Shading {
            diffuse: dot(&self.diffuse),
            specular: dot(&self.specular),
        }
    }
}

/// Refuses BRDFs the environment routes do not implement.
pub fn check_brdf(brdf: &Brdf) -> Result<()> {
    match brdf {
        Brdf::Lambert | Brdf::BlinnPhong { .. } | Brdf::Ggx(_) => brdf.validate(),
        b => Err(Error::InvalidOption(format!(
            "environment lighting supports lambert, blinn-phong and ggx, not {}",
            b.model()
        ))),
    }
}

/// Refuses methods the environment routes do not implement.
pub fn check_method(method: Method) -> Result<()> {
    match method {
        Method::Plain
        | Method::Toksvig
        | Method::Lean
        | Method::Olano
        | Method::Vmf
        | Method::Tan2005
        | Method::Sh => Ok(()),
        m => Err(Error::InvalidOption(format!(
            "environment lighting supports plain, toksvig, lean, olano, vmf, tan2005 and sh, \
             not {m}"
        ))),
    }
}

// ---------------------------------------------------------------------------------------------
// Ground truth
// ---------------------------------------------------------------------------------------------

/// A ground-truth estimate: the two terms and their standard errors (measured from the
/// samples' spread).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Estimate {
    /// Lambert term.
    pub diffuse: f64,
    /// Its standard error.
    pub diffuse_se: f64,
    /// Specular term per BRDF (0 for Lambert).
    pub specular: Vec<f64>,
    /// Their standard errors.
    pub specular_se: Vec<f64>,
}

/// Draws a half vector about `n` from the BRDF's sampling density (Blinn-Phong `f(c)`, GGX
/// `D(c)·c` per steradian of ω_h; [`integrand_and_pdf`] gives that density). Lambert has none.
fn sample_half(brdf: &Brdf, n: DVec3, u1: f64, u2: f64) -> Option<DVec3> {
    let c = match brdf {
        Brdf::BlinnPhong { s } => u1.powf(1.0 / (s + 1.0)),
        Brdf::Ggx(g) => {
            let a2 = g.alpha * g.alpha;
            let t2 = a2 * u1 / (1.0 - u1).max(1e-300);
            (1.0 / (1.0 + t2)).sqrt()
        }
        _ => return None,
    };
    let phi = 2.0 * PI * u2;
    let s = (1.0 - c * c).max(0.0).sqrt();
    let (t1, t2) = crate::brdf::tangent_frame(n);
    Some((t1 * (s * phi.cos()) + t2 * (s * phi.sin()) + n * c).normalize())
}

/// For light `l`, view `o` and normal `n`: the specular integrand without L,
/// `f(ω_h·n) max(ω_i·n, 0) g(ω_i, ω_h)`, and, where it is positive, the density over ω_i of
/// [`sample_half`] reflected about the view (`p(ω_h)/4(ω_o·ω_h)`, 0 where the half vector faces
/// away from the view). One half vector and one lobe evaluation serve both (the sampling
/// density is the lobe itself for Blinn-Phong and `D·c` for GGX).
fn integrand_and_pdf(brdf: &Brdf, n: DVec3, o: DVec3, l: DVec3) -> (f64, f64) {
    let cos_i = n.dot(l);
    if cos_i <= 0.0 {
        return (0.0, 0.0);
    }
    let Some(h) = (l + o).try_normalize() else {
        return (0.0, 0.0);
    };
    let c = n.dot(h);
    let lobe = brdf.lobe(c);
    let f = lobe * cos_i * brdf.g(l, h);
    if f <= 0.0 {
        return (f, 0.0);
    }
    let oh = o.dot(h);
    if oh <= 0.0 {
        return (f, 0.0);
    }
    let ph = match brdf {
        Brdf::BlinnPhong { .. } => lobe,
        Brdf::Ggx(_) => lobe * c.max(0.0),
        _ => 0.0,
    };
    (f, ph / (4.0 * oh))
}

/// The footprint average over `normals` (unit, with weights summing to 1) of the diffuse and
/// specular integrals under `light` for view `view`, by `samples` MIS iterations (module docs;
/// each iteration one environment sample and one BRDF sample per term). Exactly 0 for a black
/// environment. Deterministic for a given `seed`. The luminance of an uncoloured surface:
/// [`ground_truth_with`] without albedo.
pub fn ground_truth(
    light: &EnvLight,
    normals: &[(DVec3, f64)],
    view: DVec3,
    brdfs: &[Brdf],
    samples: usize,
    seed: u64,
) -> Estimate {
    ground_truth_with(light, normals, None, view, brdfs, samples, seed)
}

/// [`ground_truth`] of a coloured surface: with `albedo` (linear RGB, one per normal, in the
/// order of `normals`) normal i reflects `y_i,c · ∫ L_c ρ(n_i)` in channel c, both terms (eq
/// 22's colour, Algorithm 2 line 14), and the estimate is the Rec. 709 luminance of that RGB
/// average: each sample's value is `Σ_c LUMINANCE_c y_i,c L_c(ω)` in place of the luminance
/// `L(ω)`. The samples and their densities are [`ground_truth`]'s (the environment is sampled
/// by its luminance), so the estimator stays unbiased, and without `albedo` the result is
/// [`ground_truth`]'s bit for bit. A white albedo gives it to f32 rounding of the luminance.
///
/// Panics when `albedo` is given with a length other than `normals`'.
#[allow(clippy::too_many_arguments)]
pub fn ground_truth_with(
    light: &EnvLight,
    normals: &[(DVec3, f64)],
    albedo: Option<&[DVec3]>,
    view: DVec3,
    brdfs: &[Brdf],
    samples: usize,
    seed: u64,
) -> Estimate {
    if let Some(a) = albedo {
        assert_eq!(a.len(), normals.len(), "one albedo per normal");
    }
    let nb = brdfs.len();
    let mut out = Estimate {
        specular: vec![0.0; nb],
        specular_se: vec![0.0; nb],
        ..Default::default()
    };
    let (Some(sampler), false) = (light.sampler.as_ref(), normals.is_empty() || samples == 0)
    else {
        return out;
    };
    let env = &light.luminance;
    // The luminance in direction ω and the texel it came from (every channel shares the grid).
    let radiance = |d: DVec3| {
        let texel = env.index_of(d);
        (env.values()[texel] as f64, texel)
    };
    // The radiance normal j reflects from that texel (luminance of its colour times L).
    let value = |j: usize, texel: usize, luminance: f64| match albedo {
        None => luminance,
        Some(a) => (0..3)
            .map(|c| LUMINANCE[c] * a[j][c] * light.channels[c].radiance.values()[texel] as f64)
            .sum(),
    };
    let total_w: f64 = normals.iter().map(|n| n.1).sum();
    let mut cdf = Vec::with_capacity(normals.len());
    let mut acc = 0.0;
    for n in normals {
        acc += n.1 / total_w;
        cdf.push(acc);
    }
    let mut rng = Rng(seed ^ 0x5eed_e4f1_0000_0000);
    // Σx and Σx² per term (diffuse, then each BRDF).
    let mut s1 = vec![0.0f64; 1 + nb];
    let mut s2 = vec![0.0f64; 1 + nb];
    let mut x = vec![0.0f64; 1 + nb];
    for i in 0..samples {
        let u = (i as f64 + rng.range(0.0, 1.0)) / samples as f64;
        let j = cdf.partition_point(|&c| c < u).min(normals.len() - 1);
        let n = normals[j].0;
        x.iter_mut().for_each(|v| *v = 0.0);
        // Light sample (shared by every term).
        let ue = [
            rng.range(0.0, 1.0),
            rng.range(0.0, 1.0),
            rng.range(0.0, 1.0),
            rng.range(0.0, 1.0),
        ];
        let (le, _) = sampler.sample(env, ue);
        let (lv, texel) = radiance(le);
        let pe = sampler.pdf_of_radiance(lv);
        if pe > 0.0 {
            let v = value(j, texel, lv);
            let cos = n.dot(le).max(0.0);
            x[0] += cos * v / (pe + cos / PI);
            for (b, brdf) in brdfs.iter().enumerate() {
                if brdf.has_specular() {
                    let (f, p) = integrand_and_pdf(brdf, n, view, le);
                    if f > 0.0 {
                        x[1 + b] += f * v / (pe + p);
                    }
                }
            }
        }
        // Cosine sample for the diffuse term.
        {
            let (u1, u2) = (rng.range(0.0, 1.0), rng.range(0.0, 1.0));
            let r = u1.sqrt();
            let (t1, t2) = crate::brdf::tangent_frame(n);
            let phi = 2.0 * PI * u2;
            let l = t1 * (r * phi.cos()) + t2 * (r * phi.sin()) + n * (1.0 - u1).max(0.0).sqrt();
            let cos = n.dot(l).max(0.0);
            let (lv, texel) = radiance(l);
            if cos > 0.0 && lv > 0.0 {
                x[0] += cos * value(j, texel, lv) / (cos / PI + sampler.pdf_of_radiance(lv));
            }
        }
        // BRDF samples for each specular term.
        for (b, brdf) in brdfs.iter().enumerate() {
            let (u1, u2) = (rng.range(0.0, 1.0), rng.range(0.0, 1.0));
            if let Some(h) = sample_half(brdf, n, u1, u2) {
                let oh = view.dot(h);
                if oh > 0.0 {
                    let l = 2.0 * oh * h - view;
                    let (f, pb) = integrand_and_pdf(brdf, n, view, l);
                    let (lv, texel) = radiance(l);
                    if f > 0.0 && lv > 0.0 {
                        let p = pb + sampler.pdf_of_radiance(lv);
                        x[1 + b] += f * value(j, texel, lv) / p;
                    }
                }
            }
        }
        for k in 0..=nb {
            s1[k] += x[k];
            s2[k] += x[k] * x[k];
        }
    }
    let nf = samples as f64;
    let stat = |k: usize| {
        let m = s1[k] / nf;
        let var = if samples > 1 {
            ((s2[k] - nf * m * m) / (nf - 1.0)).max(0.0)
        } else {
            0.0
        };
        (m, (var / nf).sqrt())
    };
    (out.diffuse, out.diffuse_se) = stat(0);
    for b in 0..nb {
        (out.specular[b], out.specular_se[b]) = stat(1 + b);
    }
    out
}

// ---------------------------------------------------------------------------------------------
// Lobe energy (the prefiltered route's split sum)
// ---------------------------------------------------------------------------------------------

/// Columns of a lobe-energy table: `c_o = cos θ_o` from 0 to 1 in equal steps.
pub const ENERGY_COS: usize = 33;
/// Rows of a lobe-energy table: the lobe parameter (Blinn-Phong `log2 s' ∈ [−4, 20]`, GGX
/// `log10 α' ∈ [−3, 0]`) in equal steps.
pub const ENERGY_PARAM: usize = 49;
/// Blocks of a lobe table, [`ENERGY_PARAM`] rows each: the energy, the blend, `log2 κ_c` (the
/// core vMF), the tail's energy share `t` and `log2 κ_t` (`energy_quadrature::lobe_moments`; Blinn-Phong has
/// `t = 0`, one vMF; GGX two), the core's blend (its lookup direction, the lobe's mode), and
/// the energy and blend with the cosine taken at the half vector instead of the lobe's centre
/// (blocks 6 and 7), and the shift of `log2 κ` under those weights (block 8) (`energy_quadrature::lobe_moments`;
/// mixed in by the NDF's share of the lobe, `ndf_share`).
pub const ENERGY_BLOCKS: usize = 9;
/// Shares of GGX's lobe table: the NDF lobe's share `w ∈ [0, 1]` of the widened lobe's
/// variance (`ndf_share`) in equal steps, `w = j/(ENERGY_SHARES − 1)`. GGX's widened lobe
/// changes shape with w (eq 14 of a vMF and GGX: GGX's long tail at w = 0, the vMF's short one
/// at w = 1), and the energy with the cosine at every normal of the NDF lobe depends on w
/// (block 6 is set so that the route's energy is that exact energy at every share:
/// `energy_quadrature::exact_share_energy`). Blinn-Phong's lobe keeps its shape (its table
/// has one share, repeated on upload).
pub const ENERGY_SHARES: usize = 9;

/// The `energy_quadrature::lobe_moments` (`E(c_o, p) = ∫ f_p(ω_h·z) max(ω_i·z, 0) dω_i`, the blend, `log2 κ_i`)
/// for a view at `cos θ_o = c_o`: Blinn-Phong over
/// `log2 s' ∈ [−4, 20]`, GGX over `α' ∈ [10⁻³, 1]` (log-spaced) and the NDF's share `w`
/// ([`ENERGY_SHARES`]), both over `c_o ∈ [0, 1]`.
/// Each family's table is decoded from its embedded copy on first use ([`BLINN_PHONG_TABLE`]).
struct EnergyTables {
    blinn_phong: std::sync::OnceLock<Vec<f64>>,
    ggx: std::sync::OnceLock<Vec<f64>>,
}

/// The lobe-energy tables, decoded once per process: they depend on no environment.
fn energy_tables() -> &'static EnergyTables {
    static TABLES: std::sync::OnceLock<EnergyTables> = std::sync::OnceLock::new();
    TABLES.get_or_init(EnergyTables::new)
}

/// The Blinn-Phong lobe table as `energy_quadrature` (envlight/energy_quadrature.rs) computes it (little-endian `f64`, in
/// [`EnergyTables::lookup`]'s order), embedded: about a CPU second of quadrature per family
/// that every process lit by an environment (the planner, `eval`, the C API's environment
/// load) paid on first use. The test `energy_quadrature::tests::embedded_tables_are_the_quadrature`
/// recomputes both tables and compares; `NDFMAP_BLESS=1` rewrites the files.
const BLINN_PHONG_TABLE: &[u8] = include_bytes!("envlight/energy-blinn-phong.f64le");
/// The GGX lobe table, as [`BLINN_PHONG_TABLE`].
const GGX_TABLE: &[u8] = include_bytes!("envlight/energy-ggx.f64le");
const _: () = assert!(BLINN_PHONG_TABLE.len() == 8 * ENERGY_BLOCKS * ENERGY_PARAM * ENERGY_COS);
const _: () =
    assert!(GGX_TABLE.len() == 8 * ENERGY_BLOCKS * ENERGY_PARAM * ENERGY_SHARES * ENERGY_COS);

/// An embedded table's values.
fn decode_table(bytes: &[u8]) -> Vec<f64> {
    bytes
        .chunks_exact(8)
        .map(|c| {
            let mut b = [0u8; 8];
            b.copy_from_slice(c);
            f64::from_le_bytes(b)
        })
        .collect()
}

impl EnergyTables {
    fn new() -> EnergyTables {
        EnergyTables {
            blinn_phong: std::sync::OnceLock::new(),
            ggx: std::sync::OnceLock::new(),
        }
    }

    /// The Blinn-Phong table (decoded on first use).
    fn blinn_phong_table(&self) -> &[f64] {
        self.blinn_phong
            .get_or_init(|| decode_table(BLINN_PHONG_TABLE))
    }

    /// The GGX table (decoded on first use).
    fn ggx_table(&self) -> &[f64] {
        self.ggx.get_or_init(|| decode_table(GGX_TABLE))
    }

    /// Bilinear lookup of each block of `table` over (param index, c_o), linear over the
    /// share index `wi ∈ [0, shares − 1]` of a table of `shares` shares (GLSL:
    /// `ndf_env_energy_at`).
    fn lookup(table: &[f64], shares: usize, pi: f64, wi: f64, co: f64) -> [f64; ENERGY_BLOCKS] {
        let pi = pi.clamp(0.0, (ENERGY_PARAM - 1) as f64);
        let wi = if wi.is_nan() {
            0.0
        } else {
            wi.clamp(0.0, (shares - 1) as f64)
        };
        let ci = co.clamp(0.0, 1.0) * (ENERGY_COS - 1) as f64;
        let (p0, c0, w0) = (
            pi.floor() as usize,
            ci.floor() as usize,
            wi.floor() as usize,
        );
        let (p1, c1) = ((p0 + 1).min(ENERGY_PARAM - 1), (c0 + 1).min(ENERGY_COS - 1));
        let (fp, fc, fw) = (pi - p0 as f64, ci - c0 as f64, wi - w0 as f64);
        let bilinear = |b: usize, w: usize| {
            let at =
                |p: usize, c: usize| table[((b * ENERGY_PARAM + p) * shares + w) * ENERGY_COS + c];
            (1.0 - fp) * ((1.0 - fc) * at(p0, c0) + fc * at(p0, c1))
                + fp * ((1.0 - fc) * at(p1, c0) + fc * at(p1, c1))
        };
        std::array::from_fn(|b| {
            let v = bilinear(b, w0);
            if fw > 0.0 {
                (1.0 - fw) * v + fw * bilinear(b, w0 + 1)
            } else {
                v
            }
        })
    }

    fn blinn_phong(&self, s: f64, co: f64) -> [f64; ENERGY_BLOCKS] {
        let pi = (s.max(1e-300).log2() + 4.0) / 24.0 * (ENERGY_PARAM - 1) as f64;
        Self::lookup(self.blinn_phong_table(), 1, pi, 0.0, co)
    }

    /// GGX's lobe at widened roughness `a` (α') and NDF share `w`.
    fn ggx(&self, a: f64, w: f64, co: f64) -> [f64; ENERGY_BLOCKS] {
        let pi = (a.max(1e-300).log10() + 3.0) / 3.0 * (ENERGY_PARAM - 1) as f64;
        let wi = w * (ENERGY_SHARES - 1) as f64;
        Self::lookup(self.ggx_table(), ENERGY_SHARES, pi, wi, co)
    }
}

/// The lookup direction of a lobe about `mu` with reflected direction `r`: `normalize(blend·μ +
/// (1 − blend)·r)`, the mean direction of `energy_quadrature::lobe_moments` (`blend` its block 1).
fn tilted(mu: DVec3, r: DVec3, blend: f64) -> DVec3 {
    (mu * blend + r * (1.0 - blend))
        .try_normalize()
        .unwrap_or(DVec3::Z)
}

// ---------------------------------------------------------------------------------------------
// The routes
// ---------------------------------------------------------------------------------------------

/// How the specular term of vMF lobes is computed under an environment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Route {
    /// One prefiltered-environment lookup per lobe.
    Prefiltered,
    /// Eq 26 with the `L′` table.
    Sh,
}

impl std::str::FromStr for Route {
    type Err = Error;
    fn from_str(s: &str) -> Result<Route> {
        match s.trim() {
            "prefiltered" => Ok(Route::Prefiltered),
            "sh" => Ok(Route::Sh),
            o => Err(Error::InvalidOption(format!(
                "env-route {o:?} (expected sh or prefiltered)"
            ))),
        }
    }
}

impl Route {
    /// The name as the command line spells it.
    pub fn name(self) -> &'static str {
        match self {
            Route::Prefiltered => "prefiltered",
            Route::Sh => "sh",
        }
    }
}

/// One isotropic NDF lobe: weight, direction, `|r|` (mean length, the vMF's `A_1`) and κ, and
/// the mixture component it decodes (its texture, whose colour texture is `lobes + slot`; 0
/// for the single-lobe methods).
#[derive(Debug, Clone, Copy)]
struct Lobe {
    alpha: f64,
    mu: DVec3,
    r: f64,
    kappa: f64,
    slot: usize,
}

fn v3(t: [f32; 4]) -> DVec3 {
    DVec3::new(t[0] as f64, t[1] as f64, t[2] as f64)
}

/// The lobes a method's texel stands for (module docs).
fn lobes_of(bake: &Bake, texels: &[[f32; 4]]) -> Vec<Lobe> {
    match bake.method {
        Method::Plain => vec![Lobe {
            alpha: 1.0,
            mu: v3(texels[0]).try_normalize().unwrap_or(DVec3::Z),
            r: 1.0,
            kappa: f64::INFINITY,
            slot: 0,
        }],
        Method::Toksvig => {
            let m = v3(texels[0]);
            let len = m.length().min(1.0);
            let mu = if len > 1e-12 {
                m / m.length()
            } else {
                DVec3::Z
            };
            let r = len.min(crate::vmf::r_max(bake.format));
            vec![Lobe {
                alpha: 1.0,
                mu,
                r,
                kappa: if r >= 1.0 {
                    f64::INFINITY
                } else {
                    crate::vmf::kappa_from_r(r)
                },
                slot: 0,
            }]
        }
        Method::Lean => {
            // LEAN's first moments E[b] and E[b_x²], E[b_y²]; μ as `shade.rs` takes it,
            // `normalize(E[b_x], E[b_y], 1)`; the isotropic variance is the mean of the two
            // slope variances (the closest isotropic lobe).
            let t0 = texels[0];
            let b = (t0[0] as f64, t0[1] as f64);
            let vx = (t0[2] as f64 - b.0 * b.0).max(0.0);
            let vy = (t0[3] as f64 - b.1 * b.1).max(0.0);
            let mu = DVec3::new(b.0, b.1, 1.0).normalize();
            let var = 0.5 * (vx + vy);
            let kappa = if var > 0.0 { 1.0 / var } else { f64::INFINITY };
            vec![Lobe {
                alpha: 1.0,
                mu,
                r: if kappa.is_infinite() {
                    1.0
                } else {
                    crate::vmf::a_kappa(kappa)
                },
                kappa,
                slot: 0,
            }]
        }
        Method::Olano => {
            // One lobe about the mean normal, κ the inverse of the mean per-axis variance of
            // the tangent-plane covariance (the closest isotropic lobe, as LEAN's); the diffuse
            // term uses the moments themselves (`moments_diffuse`), not this lobe.
            let (m, mu, _, cov) = crate::shade::olano_moments(texels);
            let var = 0.5 * (cov[0] + cov[1]);
            vec![Lobe {
                alpha: 1.0,
                mu,
                r: m.length().min(1.0),
                kappa: if var > 0.0 { 1.0 / var } else { f64::INFINITY },
                slot: 0,
            }]
        }
        Method::Tan2005 => texels[..bake.lobes]
            .iter()
            .map(|&t| crate::tan2005::Gaussian::from_texel(t))
            .enumerate()
            .filter(|(_, g)| !g.is_empty())
            .map(|(slot, g)| {
                // The shaders' decoding (`tan2005::shade`): the planar mean lifted to the
                // sphere, Blinn-Phong widened by σ², i.e. a vMF of κ = 1/σ² (eq 20).
                let var = g.variance.max(0.0);
                let kappa = if var > 0.0 { 1.0 / var } else { f64::INFINITY };
                Lobe {
                    alpha: g.alpha,
                    mu: crate::tan2005::lift(g.mean),
                    r: crate::vmf::a_kappa(kappa),
                    kappa,
                    slot,
                }
            })
            .collect(),
        Method::Vmf => {
            let (rmax, amin) = (
                crate::vmf::r_max(bake.format),
                crate::vmf::alpha_min(bake.format),
            );
            texels[..bake.lobes]
                .iter()
                .enumerate()
                .filter_map(|(slot, &t)| Some((slot, crate::shade::vmf_decode(t, rmax, amin)?)))
                .map(|(slot, t)| Lobe {
                    alpha: t.alpha,
                    mu: t.mu,
                    r: t.r_len.min(rmax),
                    kappa: if t.var > 0.0 {
                        1.0 / t.var
                    } else {
                        f64::INFINITY
                    },
                    slot,
                })
                .collect()
        }
        _ => Vec::new(),
    }
}

/// Per lobe of [`lobes_of`] (same order), its weight per colour channel: α in every channel,
/// or with `color` for a mixture bake (vMF, Tan 2005) the lobe's colour texel `α·y` (eq 22:
/// texture `lobes + slot`, `slot` the component the lobe was decoded from).
fn lobe_weights(bake: &Bake, texels: &[[f32; 4]], lobes: &[Lobe], color: bool) -> Vec<[f64; 3]> {
    if !(color && is_mixture(bake.method)) {
        return lobes.iter().map(|l| [l.alpha; 3]).collect();
    }
    assert!(
        bake.lobes > 0 && texels.len() >= 2 * bake.lobes,
        "colour shading needs a mixture bake with colour textures"
    );
    lobes
        .iter()
        .map(|l| {
            let y = texels[bake.lobes + l.slot];
            [y[0] as f64, y[1] as f64, y[2] as f64]
        })
        .collect()
}

/// Whether `method` is a mixture whose components [`lobes_of`] decodes one by one and whose
/// colour textures (texture `lobes + j`, `α·y`) weight them (eq 22): vMF and Tan 2005.
fn is_mixture(method: Method) -> bool {
    matches!(method, Method::Vmf | Method::Tan2005)
}

/// Lambert's `ρ̂_l` for l ≤ 2.
const LAMBERT: [f64; 3] = [PI, 2.0 * PI / 3.0, PI / 4.0];

/// `Y_lm`, l ≤ 2, of [`crate::harmonics`] (order `l² + l + m`) as polynomials of a unit
/// vector: `Y_00 = C0`, `Y_1m = C1 (y, z, x)`, `Y_2,±m` from the products below (test
/// `moment_basis_is_the_harmonics_basis`; GLSL `ndf_env_basis2` at a direction,
/// `ndf_env_moments_diffuse` of moments).
const Y_C0: f64 = 0.282_094_791_773_878_14; // 1/√(4π)
const Y_C1: f64 = 0.488_602_511_902_919_9; // √(3/4π)
const Y_C2: f64 = 1.092_548_430_592_079_2; // √(15/4π): xy, yz, xz
const Y_C20: f64 = 0.315_391_565_252_520_05; // √(5/16π): 2z² − x² − y²
const Y_C22: f64 = 0.546_274_215_296_039_6; // √(15/16π): x² − y²

/// `E[Y_lm(n)]`, l ≤ 2, of a distribution of unit normals from its moments `m = E[n]` and
/// `second = E[nnᵀ]` (the `Y_2m` written as traceless quadratic forms, which equal them on
/// the sphere, so the trace `E[|n|²] = 1` is not relied on).
fn moment_basis(m: DVec3, second: DMat3) -> [f64; 9] {
    let e = |i: usize, j: usize| second.col(j)[i];
    [
        Y_C0,
        Y_C1 * m.y,
        Y_C1 * m.z,
        Y_C1 * m.x,
        Y_C2 * e(0, 1),
        Y_C2 * e(1, 2),
        Y_C20 * (2.0 * e(2, 2) - e(0, 0) - e(1, 1)),
        Y_C2 * e(0, 2),
        Y_C22 * (e(0, 0) - e(1, 1)),
    ]
}

/// An Olano–North texel's moments `(E[n], E[nnᵀ])` turned into the environment's frame by
/// `frame` (tangent → environment): `F E[n]` and `F E[nnᵀ] Fᵀ`.
fn olano_moments_in(texels: &[[f32; 4]], frame: DMat3) -> (DVec3, DMat3) {
    let second = crate::shade::olano_second_moment(texels);
    (frame * v3(texels[0]), frame * second * frame.transpose())
}

/// The diffuse term of a texel known by its normals' first and second moments (environment
/// frame): `Σ_{l≤2} ρ̂_l Σ_m L_lm E[Y_lm(n)]`, the footprint average of the band-limited
/// irradiance itself (Olano–North under either route; not clamped).
fn moments_diffuse(sh: &[f64], m: DVec3, second: DMat3) -> f64 {
    let y = moment_basis(m, second);
    (0..9)
        .map(|k| {
            let l = if k == 0 {
                0
            } else if k < 4 {
                1
            } else {
                2
            };
            LAMBERT[l] * sh[k] * y[k]
        })
        .sum()
}

/// Eq 25 for one lobe: `Σ_{l≤2} ρ̂_l A_l Σ_m L_lm Y_lm(μ)` with `A_1 = |r|`, `A_2 = 1 − 3|r|/κ`.
fn diffuse_lobe(sh: &[f64], y: &[f64], lobe: &Lobe) -> f64 {
    let a2 = if lobe.kappa.is_infinite() {
        1.0
    } else {
        (1.0 - 3.0 * lobe.r / lobe.kappa.max(1e-12)).max(0.0)
    };
    let a = [1.0, lobe.r, a2];
    let mut sum = 0.0;
    for l in 0..3usize {
        let band: f64 = (l * l..(l + 1) * (l + 1)).map(|k| sh[k] * y[k]).sum();
        sum += LAMBERT[l] * a[l] * band;
    }
    sum
}

/// The effective half-vector lobe of `brdf` widened by per-axis variance `var` at `co`: the
/// `energy_quadrature::lobe_moments` of its Blinn-Phong s' or GGX α' (energy, blend, log2 κ_c, tail share,
/// log2 κ_t, core blend, energy and blend with the cosine at the half vector).
fn widened(light: &EnvLight, brdf: &Brdf, var: f64, co: f64) -> [f64; ENERGY_BLOCKS] {
    match brdf {
        Brdf::BlinnPhong { s } => light.energy.blinn_phong(s / (1.0 + s * var), co),
        Brdf::Ggx(g) => light.energy.ggx(g.widened(var), ndf_share(brdf, var), co),
        _ => [0.0; ENERGY_BLOCKS],
    }
}

/// The NDF lobe's share `w ∈ [0, 1]` of the widened lobe's variance: Blinn-Phong
/// `1/s' = 1/s + var` gives `w = s·var/(1 + s·var)`, GGX `α'² = α² + c·var` gives
/// `w = c·var/(α² + c·var)` (0 for a sharp NDF lobe, 1 for a BRDF lobe much sharper than
/// the NDF's). The normal that reflects the view into ω_i is, given ω_h, about
/// `(1 − w) μ + w ω_h` (the product of the vMF about μ and the BRDF lobe about ω_h), so the
/// route's energy and mean direction mix the centre-cosine and half-vector-cosine blocks of
/// `energy_quadrature::lobe_moments` by w (GLSL: `ndf_env_share`).
fn ndf_share(brdf: &Brdf, var: f64) -> f64 {
    let var = var.clamp(0.0, 1e6);
    let w = match brdf {
        Brdf::BlinnPhong { s } => s * var / (1.0 + s * var),
        Brdf::Ggx(g) => {
            let v = g.widening * var;
            let d = g.alpha * g.alpha + v;
            if d > 0.0 { v / d } else { 0.0 }
        }
        _ => 0.0,
    };
    if w.is_nan() { 0.0 } else { w.clamp(0.0, 1.0) }
}

/// The prefiltered route's specular term of one NDF lobe of unit weight, direction `mu` and
/// concentration `kappa` (∞: a single normal), for view `view` (tangent frame) on a surface
/// whose tangent frame is `frame`, per colour channel: the widened BRDF's lobe energy (mixed
/// by `ndf_share` between the cosine at the lobe's centre and at the half vector) times one
/// prefiltered lookup (GGX: a core and a tail) in the lobe's mean direction, times `g` at the
/// reflected direction (module docs; what [`shade_in_with`] sums per lobe, the shaders'
/// `ndf_env_lobe`). 0 when the view is behind `mu` and for a BRDF with no specular term.
pub fn prefiltered_lobe(
    light: &EnvLight,
    frame: DMat3,
    mu: DVec3,
    kappa: f64,
    view: DVec3,
    brdf: &Brdf,
) -> [f64; 3] {
    let share = ndf_share(brdf, lobe_var(kappa));
    prefiltered_lobe_with_share(light, frame, mu, kappa, view, brdf, share)
}

/// The per-axis variance `1/κ` of an NDF lobe (0 for κ = ∞, at most 10⁶).
fn lobe_var(kappa: f64) -> f64 {
    if kappa.is_infinite() {
        0.0
    } else {
        1.0 / kappa.max(1e-6)
    }
}

/// [`prefiltered_lobe`] with the cosine mixed by `share` instead of `ndf_share`: 0 takes the
/// cosine at the lobe's centre (the route before the half-vector blocks), 1 at the half vector.
/// GGX's table share (its lobe shape and exact energy) still follows `ndf_share`.
/// For analysis (`examples/env_error_split.rs` measures the route both ways in one run).
pub fn prefiltered_lobe_with_share(
    light: &EnvLight,
    frame: DMat3,
    mu: DVec3,
    kappa: f64,
    view: DVec3,
    brdf: &Brdf,
    share: f64,
) -> [f64; 3] {
    let var = lobe_var(kappa);
    let co = view.dot(mu);
    if !brdf.has_specular() || co.is_nan() || co <= 0.0 {
        return [0.0; 3];
    }
    let r = 2.0 * co * mu - view;
    let g = brdf.g(r, mu);
    let [
        e0,
        blend0,
        log_kappa,
        tail,
        log_tail,
        blend_core,
        e_h,
        blend_h,
        shift,
    ] = widened(light, brdf, var, co);
    let w = share.clamp(0.0, 1.0);
    let e = (1.0 - w) * e0 + w * e_h;
    let blend = (1.0 - w) * blend0 + w * blend_h;
    let d = frame * tilted(mu, r, blend);
    let kappa = (log_kappa + w * shift).exp2();
    if tail > 0.0 {
        // Two vMFs (GGX's core at the lobe's mode, its tail about the mean).
        let dc = frame * tilted(mu, r, blend_core);
        let kt = (log_tail + w * shift).exp2();
        std::array::from_fn(|c| {
            let p = &light.channels[c].prefiltered;
            ((1.0 - tail) * p.lookup(dc, kappa) + tail * p.lookup(d, kt)) * e * g
        })
    } else {
        std::array::from_fn(|c| light.channels[c].prefiltered.lookup(d, kappa) * e * g)
    }
}

/// One NDF lobe a texel stands for under the environment routes: its weight, mean direction
/// and concentration (∞: a single normal).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TexelLobe {
    /// Weight (α of a mixture lobe; 1 for the single-lobe methods).
    pub alpha: f64,
    /// Mean direction (unit, tangent frame).
    pub mu: DVec3,
    /// Concentration κ (Toksvig: from the mean length; LEAN, Olano–North: the inverse of the
    /// mean per-axis variance; vMF: the decoded lobe's; Tan 2005: 1/σ²).
    pub kappa: f64,
}

/// The lobes the environment routes shade for `bake`'s texel (plain, Toksvig, LEAN,
/// Olano–North: one; vMF, Tan 2005: the decoded components; SH bakes none): what
/// [`prefiltered_lobe`] is summed over.
pub fn texel_lobes(bake: &Bake, texels: &[[f32; 4]]) -> Vec<TexelLobe> {
    lobes_of(bake, texels)
        .iter()
        .map(|l| TexelLobe {
            alpha: l.alpha,
            mu: l.mu,
            kappa: l.kappa,
        })
        .collect()
}

/// Environment-lit shading of `bake`'s texel for view `view` (module docs) where the tangent
/// frame is the environment's (texel space, the report's planes): [`shade_in`] with the
/// identity frame.
pub fn shade(
    light: &EnvLight,
    bake: &Bake,
    texels: &[[f32; 4]],
    view: DVec3,
    brdf: &Brdf,
    route: Route,
) -> RgbShading {
    shade_in(light, DMat3::IDENTITY, bake, texels, view, brdf, route)
}

/// Environment-lit shading, per colour channel, of `bake`'s texel for view `view` (tangent
/// frame) on a surface whose tangent frame is `frame` (tangent → environment frame, a
/// rotation; the shaders' `ndf_env_frame`): the CPU twin of the environment shaders. Lobe
/// directions, reflected directions and the view are turned into the environment's frame for
/// the basis, the lookups and `L′`; for SH bakes the environment's `L_lm` (bands ≤ 2) and
/// `L′_lm(frame·view)` are rotated into the tangent frame ([`projection::rotate_zyz`], as the
/// shader does per fragment) and paired with the texel's `c_lm`. Everything that does not
/// depend on the radiance (lobes, basis, BRDF coefficients, lobe-table lookups, g) is computed
/// once; each channel is then the single-channel route (the routes are linear in radiance; the
/// clamps at 0 are per channel, as in the shaders). Panics as [`shade_in_with`] does.
pub fn shade_in(
    light: &EnvLight,
    frame: DMat3,
    bake: &Bake,
    texels: &[[f32; 4]],
    view: DVec3,
    brdf: &Brdf,
    route: Route,
) -> RgbShading {
    shade_in_with(light, frame, bake, texels, view, brdf, route, false)
}

/// Environment-lit shading of `bake`'s texel in the environment's frame (texel space) with or
/// without the colour textures: [`shade_in_with`] with the identity frame.
pub fn shade_with(
    light: &EnvLight,
    bake: &Bake,
    texels: &[[f32; 4]],
    view: DVec3,
    brdf: &Brdf,
    route: Route,
    color: bool,
) -> RgbShading {
    shade_in_with(
        light,
        DMat3::IDENTITY,
        bake,
        texels,
        view,
        brdf,
        route,
        color,
    )
}

/// [`shade_in`] with eq 22's per-lobe colour when `color` is set (a vMF bake with colour
/// textures: texture `lobes + j` holds `α·y` of lobe j): lobe j's diffuse (eq 25) and specular
/// (prefiltered lookup or eq 26) terms of channel c are weighted by `(α·y)_c` instead of α —
/// Algorithm 2 line 14 as [`crate::shade::shade_rgb_with`] does it for point lights, and the
/// environment shaders under `NDF_COLOR`. Without `color` (or for a bake that is not a vMF
/// mixture) every lobe is weighted by α in every channel ([`shade_in`]).
///
/// Panics when `color` is asked of a vMF bake whose texel has no colour textures (as
/// `shade_rgb_with` does; the shader generator, `glsl::source_for`, refuses such a shader
/// with a typed error), and when the SH route (or an SH bake's specular term) is asked of an
/// [`EnvLight::prefiltered_only`] light ([`EnvLight::check_routes`] says so beforehand).
#[allow(clippy::too_many_arguments)]
pub fn shade_in_with(
    light: &EnvLight,
    frame: DMat3,
    bake: &Bake,
    texels: &[[f32; 4]],
    view: DVec3,
    brdf: &Brdf,
    route: Route,
    color: bool,
) -> RgbShading {
    let mut out = RgbShading::default();
    let sh_route = route == Route::Sh && brdf.has_specular();
    // Eq 25 (the diffuse term) reads bands ≤ 2 of each lobe's basis; only the SH route's
    // specular term (eq 26) reads them all. The recurrence gives bands ≤ 2 the same bits
    // whatever the band limit.
    let basis = Basis::new(if sh_route { ENV_LMAX } else { 2 });
    let mut y = vec![0.0f64; count(basis.lmax())];
    let identity = frame == DMat3::IDENTITY;
    let to_tangent = frame.transpose();
    if bake.method == Method::Sh {
        let lmax = crate::sh::lmax_of(bake);
        let c = |k: usize| texels[k / 4][k % 4] as f64;
        let ld = lmax.min(2);
        for (ch, o) in light.channels.iter().zip(&mut out.diffuse) {
            let sh_t = if identity {
                ch.sh[..count(ld)].to_vec()
            } else {
                projection::rotate_zyz(&ch.sh, ld, to_tangent, &light.x90)
            };
            let mut d = 0.0;
            for (l, rho) in LAMBERT.iter().enumerate().take(ld + 1) {
                let band = &sh_t[l * l..(l + 1) * (l + 1)];
                for (k, v) in (l * l..).zip(band) {
                    d += rho / lambda(l) * v * c(k);
                }
            }
            *o = d.max(0.0);
        }
        if brdf.has_specular() {
            let ls = lmax.min(ENV_LMAX);
            let rho = brdf.sh_coefficients(ls);
            let nbar = DVec3::new(c(3), c(1), c(2))
                .try_normalize()
                .unwrap_or(DVec3::Z);
            let co = view.dot(nbar).max(0.0);
            let r = 2.0 * co * nbar - view;
            let g = brdf.g(r, nbar);
            for (ch, o) in light.channels.iter().zip(&mut out.specular) {
                let lp_env = ch.reflected_at(frame * view);
                let lp = if identity {
                    lp_env
                } else {
                    projection::rotate_zyz(&lp_env, ls, to_tangent, &light.x90)
                };
                let mut sum = 0.0;
                for (l, rl) in rho.iter().enumerate() {
                    let band = &lp[l * l..(l + 1) * (l + 1)];
                    for (k, v) in (l * l..).zip(band) {
                        sum += rl / lambda(l) * v * c(k);
                    }
                }
                *o = (sum * co).max(0.0) * g;
            }
        }
        add_lights(light, frame, bake, texels, view, brdf, color, &mut out);
        return out;
    }
    let lobes = lobes_of(bake, texels);
    let weights = lobe_weights(bake, texels, &lobes, color);
    debug_assert_eq!(lobes.len(), weights.len());
    let rho = if sh_route {
        brdf.sh_coefficients(ENV_LMAX)
    } else {
        Vec::new()
    };
    let lp: Vec<Vec<f64>> = if sh_route {
        light
            .channels
            .iter()
            .map(|ch| ch.reflected_at(frame * view))
            .collect()
    } else {
        Vec::new()
    };
    // Olano–North's diffuse term comes from its moments, not from its lobe.
    let moments = (bake.method == Method::Olano).then(|| olano_moments_in(texels, frame));
    if let Some((m, second)) = moments {
        for (ch, o) in light.channels.iter().zip(&mut out.diffuse) {
            *o += moments_diffuse(&ch.sh, m, second).max(0.0);
        }
    }
    for (lobe, w) in lobes.iter().zip(&weights) {
        basis.eval_into(frame * lobe.mu, &mut y);
        if moments.is_none() {
            for ((ch, o), wc) in light.channels.iter().zip(&mut out.diffuse).zip(w) {
                *o += wc * diffuse_lobe(&ch.sh, &y, lobe).max(0.0);
            }
        }
        if !brdf.has_specular() {
            continue;
        }
        let co = view.dot(lobe.mu);
        if co <= 0.0 {
            continue;
        }
        let r = 2.0 * co * lobe.mu - view;
        let g = brdf.g(r, lobe.mu);
        let spec: [f64; 3] = match route {
            Route::Prefiltered => {
                // `prefiltered_lobe` includes g; the SH route's g is applied below.
                let p = prefiltered_lobe(light, frame, lobe.mu, lobe.kappa, view, brdf);
                for ((o, s), wc) in out.specular.iter_mut().zip(p).zip(w) {
                    *o += wc * s;
                }
                continue;
            }
            Route::Sh => {
                let att: Vec<f64> = (0..rho.len())
                    .map(|l| {
                        rho[l] * crate::vmf::sh_scaled_coefficient(l as u32, lobe.kappa.min(1e300))
                    })
                    .collect();
                std::array::from_fn(|c| {
                    let mut sum = 0.0;
                    for (l, a) in att.iter().enumerate() {
                        let band: f64 = (l * l..(l + 1) * (l + 1)).map(|k| lp[c][k] * y[k]).sum();
                        sum += a * band;
                    }
                    sum.max(0.0) * co
                })
            }
        };
        for ((o, s), wc) in out.specular.iter_mut().zip(spec).zip(w) {
            *o += wc * s * g;
        }
    }
    add_lights(light, frame, bake, texels, view, brdf, color, &mut out);
    out
}

/// The shading of `bake`'s texel by one distant light of unit power in direction `l`
/// (tangent frame) for view `view`, per colour channel: the point-light path itself
/// ([`crate::shade::shade_rgb_with`] with the default options — Algorithm 2 with eq 20 or the
/// GGX mixture rule per vMF lobe, each baseline's own widening, eq 12 for SH bakes, g
/// included), which is the environment integrals' diffuse `∫ L max(ω_i·n, 0) dω_i` and specular
/// `∫ L f g max(ω_i·n, 0) dω_i` for `L` a delta of unit power at `l`. `color` as in
/// [`shade_in_with`] (used for vMF bakes only).
pub fn light_term(
    bake: &Bake,
    texels: &[[f32; 4]],
    l: DVec3,
    view: DVec3,
    brdf: &Brdf,
    color: bool,
) -> RgbShading {
    let Some(h) = (l + view).try_normalize() else {
        return RgbShading::default();
    };
    let color = color && is_mixture(bake.method);
    let s = crate::shade::shade_rgb_with(
        bake,
        texels,
        l,
        h,
        brdf,
        color,
        &crate::shade::ShadeOptions::default(),
    );
    let fin = |v: f64| if v.is_finite() { v } else { 0.0 };
    RgbShading {
        diffuse: s.diffuse.to_array().map(fin),
        specular: s.specular.to_array().map(fin),
    }
}

/// Adds every extracted light's [`light_term`] times its RGB power to `out` (the light's
/// direction turned into the tangent frame by `frame`ᵀ).
#[allow(clippy::too_many_arguments)]
fn add_lights(
    light: &EnvLight,
    frame: DMat3,
    bake: &Bake,
    texels: &[[f32; 4]],
    view: DVec3,
    brdf: &Brdf,
    color: bool,
    out: &mut RgbShading,
) {
    for lt in &light.lights {
        let l = frame.transpose() * lt.direction;
        // Plain's single normal cannot be widened; its diffuse `n·ω` averaged over the light's
        // vMF is `A(κ_l) n·d` wherever the light is wholly above the normal's horizon.
        let plain = if bake.method == Method::Plain {
            crate::vmf::a_kappa(lt.kappa)
        } else {
            1.0
        };
        if lt.diffuse_only {
            // Out of the diffuse SH only: the specular routes' residual still holds it.
            let d = light_term(
                bake,
                &spread_texels(bake, texels, lt.kappa),
                l,
                view,
                &Brdf::Lambert,
                color,
            );
            for c in 0..3 {
                out.diffuse[c] += lt.power[c] * plain * d.diffuse[c];
            }
            continue;
        }
        // The light's spread: the diffuse integrand sees it in full (κ_l), the half vector
        // half of its angle (κ_h = 4κ_l); a point light (κ = ∞) is the texel itself.
        let (d, sp) = if lt.kappa.is_finite() {
            let d = light_term(
                bake,
                &spread_texels(bake, texels, lt.kappa),
                l,
                view,
                brdf,
                color,
            );
            let s = light_term(
                bake,
                &spread_texels(bake, texels, 4.0 * lt.kappa),
                l,
                view,
                brdf,
                color,
            );
            (d.diffuse, s.specular)
        } else {
            let t = light_term(bake, texels, l, view, brdf, color);
            (t.diffuse, t.specular)
        };
        for c in 0..3 {
            out.diffuse[c] += lt.power[c] * plain * d[c];
            out.specular[c] += lt.power[c] * sp[c];
        }
    }
}

/// `bake`'s texel with its NDF convolved with a vMF of concentration `k` (a light's angular
/// spread as the normals see it): vMF lobes' and Toksvig's mean vectors scaled by `A(k)` (the
/// mean resultant length of a vMF convolved with a vMF is the product of theirs), LEAN's slope
/// second moments raised by `1/k`, Olano–North's moments convolved exactly (`E[n]` times
/// `A(k)`, `E[nnᵀ]` → `(A(k)/k) I + (1 − 3A(k)/k) E[nnᵀ]`, the second moment of a vMF about
/// each normal), each Tan 2005 Gaussian's σ² raised by `1/k` (its fourth number by `α/k`), an
/// SH bake's band l scaled by `e^{−l²/2k}` (eq 19); plain
/// unchanged (a single normal, which its shading cannot widen; [`add_lights`] scales its diffuse
/// by `A(k)` instead). The colour textures are kept.
fn spread_texels(bake: &Bake, texels: &[[f32; 4]], k: f64) -> Vec<[f32; 4]> {
    let mut t = texels.to_vec();
    let a = crate::vmf::a_kappa(k) as f32;
    match bake.method {
        Method::Vmf => {
            for lobe in t.iter_mut().take(bake.lobes) {
                for v in &mut lobe[1..] {
                    *v *= a;
                }
            }
        }
        Method::Toksvig => {
            for v in &mut t[0][..3] {
                *v *= a;
            }
        }
        Method::Lean => {
            let var = (1.0 / k) as f32;
            t[0][2] += var;
            t[0][3] += var;
        }
        Method::Olano => {
            let ak = crate::vmf::a_kappa(k);
            let (iso, keep) = (ak / k, 1.0 - 3.0 * ak / k);
            for v in &mut t[0][..3] {
                *v *= a;
            }
            for v in &mut t[1][..3] {
                *v = (iso + keep * f64::from(*v)) as f32;
            }
            for v in &mut t[2][..3] {
                *v = (keep * f64::from(*v)) as f32;
            }
        }
        Method::Tan2005 => {
            let var = 1.0 / k;
            for g in t.iter_mut().take(bake.lobes) {
                g[3] = (f64::from(g[3]) + f64::from(g[0]) * var) as f32;
            }
        }
        Method::Sh => {
            let lmax = crate::sh::lmax_of(bake);
            for l in 1..=lmax {
                let f = crate::vmf::sh_scaled_coefficient(l as u32, k) as f32;
                for i in l * l..(l + 1) * (l + 1) {
                    if let Some(v) = t.get_mut(i / 4).map(|x| &mut x[i % 4]) {
                        *v *= f;
                    }
                }
            }
        }
        _ => {}
    }
    t
}

// ---------------------------------------------------------------------------------------------
// Texel-space evaluation
// ---------------------------------------------------------------------------------------------

/// The most ground-truth MIS iterations per texel and view [`EvalOptions::samples`] may ask
/// for: 2¹⁶, eight times the most the docs use (8192). The work grows as their product with
/// the texels and views, so an absurd count is refused instead of running for days.
pub const MAX_SAMPLES: usize = 1 << 16;

/// The most texels per level [`EvalOptions::texels_per_level`] may ask for: 1024 (a whole
/// 32 × 32 level), about twenty times the default 48 and the most the docs use.
pub const MAX_TEXELS_PER_LEVEL: usize = 1024;

/// What `evaluate` measures and with how many samples.
#[derive(Debug, Clone, PartialEq)]
pub struct EvalOptions {
    /// View directions (unit, tangent = environment frame).
    pub views: Vec<DVec3>,
    /// First level measured (levels below are skipped; the overall error is over the rest).
    pub first_level: usize,
    /// Texels drawn per level (all of a level with fewer), 1 to [`MAX_TEXELS_PER_LEVEL`].
    pub texels_per_level: usize,
    /// Ground-truth MIS iterations per texel and view, 1 to [`MAX_SAMPLES`] (a level with
    /// fewer texels than `texels_per_level` gets `texels_per_level / texels` times as many per
    /// texel, so that every level's ground truth has the same sample count).
    pub samples: usize,
    /// Seed of the texel choice and the ground truth.
    pub seed: u64,
    /// Score a coloured surface: the map's feature (albedo, linear RGB) colours the ground
    /// truth normal by normal ([`ground_truth_with`]); vMF bakes with colour textures are
    /// shaded with eq 22's per-lobe colour ([`shade_with`] with `color`), every other bake
    /// (baselines, SH, vMF without colour textures) by its shading times the footprint's mean
    /// albedo — the albedo MIP an engine samples beside it. The map must have a feature.
    pub color: bool,
}

impl Default for EvalOptions {
    fn default() -> Self {
        EvalOptions {
            views: default_views(),
            first_level: 1,
            texels_per_level: 48,
            samples: 512,
            seed: 1,
            color: false,
        }
    }
}

/// The default views: the zenith, and θ_o = 35° and 70° at φ_o = 0°, 120°, 240° (7 views).
pub fn default_views() -> Vec<DVec3> {
    let mut v = vec![DVec3::Z];
    for t in [35f64, 70.0] {
        for p in [0f64, 120.0, 240.0] {
            v.push(crate::eval::direction(t, p));
        }
    }
    v
}

/// One configuration's environment-lit error.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EnvError {
    /// The bake's label and route (`vmf6 prefiltered`, `toksvig`, `sh4`); in a colour
    /// evaluation ([`EvalOptions::color`]) a bake shaded times the albedo MIP says so
    /// (`toksvig × albedo mip`).
    pub label: String,
    /// The BRDF of the specular term.
    pub brdf: Brdf,
    /// Per measured level: (level, diffuse %, specular %), relative RMS.
    pub levels: Vec<(usize, f64, f64)>,
    /// Diffuse relative RMS (RMS over levels of the per-level errors).
    pub diffuse: f64,
    /// Specular relative RMS, aggregated the same way.
    pub specular: f64,
}

/// The result of [`evaluate`]: errors and the ground truth's own noise in the same metric.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Evaluation {
    /// Per configuration and BRDF.
    pub errors: Vec<EnvError>,
    /// The ground truth's relative standard error, diffuse.
    pub noise_diffuse: f64,
    /// The ground truth's relative standard error, per BRDF's specular term.
    pub noise_specular: Vec<f64>,
    /// Per measured level: (level, the diffuse noise, the specular noise per BRDF), in the
    /// same metric (what [`denoised`] takes out of that level's errors).
    pub level_noise: Vec<(usize, f64, Vec<f64>)>,
    /// Ground-truth iterations per texel and view, at the levels with at least
    /// `texels_per_level` texels (each one light + one BRDF sample per term).
    pub samples: usize,
    /// Texels measured in all.
    pub texels: usize,
    /// Views.
    pub views: usize,
}

/// The ground truth of a texel-space evaluation, computed once and scored against any number
/// of bakes of the same map ([`Reference::score`]): the texels drawn per level and, per texel
/// and view, the Monte Carlo estimate of [`ground_truth`].
pub struct Reference {
    /// (level, x, y) of every texel measured, level by level.
    tasks: Vec<(usize, u32, u32)>,
    /// Per task, per view: the estimate.
    truths: Vec<Vec<Estimate>>,
    /// The BRDFs the truths are for.
    brdfs: Vec<Brdf>,
    /// The views.
    views: Vec<DVec3>,
    /// Width of each level of the map's pyramid.
    widths: Vec<u32>,
    /// The first level measured.
    first: usize,
    /// Ground-truth iterations per texel and view.
    samples: usize,
    /// With [`EvalOptions::color`]: per task, the footprint's mean albedo (what bakes without
    /// colour textures are multiplied by).
    albedo: Option<Vec<DVec3>>,
}

/// Whether `bake` carries eq 22's colour textures (a vMF or Tan 2005 bake baked with a
/// feature).
fn has_color_textures(bake: &Bake) -> bool {
    is_mixture(bake.method) && bake.lobes > 0 && bake.textures.len() >= 2 * bake.lobes
}

impl Reference {
    /// Draws the texels of `options` from `map`'s pyramid and computes their ground truth
    /// under `light` for `brdfs` (deterministic for a seed, whatever the thread count). With
    /// [`EvalOptions::color`] the ground truth is the coloured one ([`ground_truth_with`] with
    /// the map's feature as albedo); a map without a feature is then an error, as are a sample
    /// or texel count of 0 or above [`MAX_SAMPLES`] / [`MAX_TEXELS_PER_LEVEL`].
    pub fn new(
        map: &crate::NormalMap,
        brdfs: &[Brdf],
        light: &EnvLight,
        options: &EvalOptions,
    ) -> Result<Reference> {
        for b in brdfs {
            check_brdf(b)?;
        }
        for (name, value, max) in [
            ("samples", options.samples, MAX_SAMPLES),
            (
                "texels_per_level",
                options.texels_per_level,
                MAX_TEXELS_PER_LEVEL,
            ),
        ] {
            if !(1..=max).contains(&value) {
                return Err(Error::InvalidOption(format!(
                    "environment evaluation: {name} {value} (expected 1 to {max})"
                )));
            }
        }
        let feature = match (options.color, map.feature()) {
            (false, _) => None,
            (true, Some(f)) => Some(f),
            (true, None) => {
                return Err(Error::InvalidOption(
                    "colour evaluation under an environment needs an albedo (feature) image \
                     of the map"
                        .into(),
                ));
            }
        };
        let levels = pyramid(map.width(), map.height());
        let first = options.first_level.min(levels.len() - 1);
        let mut tasks = Vec::new();
        for (k, lf) in levels.iter().enumerate().skip(first) {
            let (w, h) = lf.size;
            let n = w as usize * h as usize;
            if n <= options.texels_per_level {
                (0..n).for_each(|i| {
                    tasks.push((k, (i % w as usize) as u32, (i / w as usize) as u32))
                });
            } else {
                let mut rng = Rng(options.seed.wrapping_mul(0x9E37_79B9) ^ k as u64);
                for _ in 0..options.texels_per_level {
                    let x = (rng.next_u64() % w as u64) as u32;
                    let y = (rng.next_u64() % h as u64) as u32;
                    tasks.push((k, x, y));
                }
            }
        }
        let results: Vec<(Vec<Estimate>, DVec3)> = tasks
            .par_iter()
            .enumerate()
            .map(|(ti, &(k, x, y))| {
                let footprint = levels[k].texel(x, y);
                let index = |fx: u32, fy: u32| (fy * map.width() + fx) as usize;
                let normals: Vec<(DVec3, f64)> = footprint
                    .iter()
                    .map(|&(fx, fy, w)| (map.normals()[index(fx, fy)].as_dvec3(), w))
                    .collect();
                let albedo: Option<Vec<DVec3>> = feature.map(|f| {
                    footprint
                        .iter()
                        .map(|&(fx, fy, _)| {
                            let t = f[index(fx, fy)];
                            DVec3::new(t[0] as f64, t[1] as f64, t[2] as f64)
                        })
                        .collect()
                });
                let total: f64 = normals.iter().map(|n| n.1).sum();
                let mean_albedo = match &albedo {
                    Some(a) if total > 0.0 => {
                        a.iter().zip(&normals).map(|(a, n)| *a * n.1).sum::<DVec3>() / total
                    }
                    _ => DVec3::ONE,
                };
                // A level with fewer texels than `texels_per_level` gets proportionally more
                // samples per texel: every level's ground truth has the same sample count.
                let (w, h) = levels[k].size;
                let n = (w as usize * h as usize).max(1);
                let samples = options
                    .samples
                    .saturating_mul((options.texels_per_level / n).max(1));
                let truths = options
                    .views
                    .iter()
                    .enumerate()
                    .map(|(vi, &view)| {
                        let seed = options.seed ^ ((ti as u64) << 20) ^ vi as u64;
                        let albedo = albedo.as_deref();
                        ground_truth_with(light, &normals, albedo, view, brdfs, samples, seed)
                    })
                    .collect();
                (truths, mean_albedo)
            })
            .collect();
        let albedo = feature.map(|_| results.iter().map(|r| r.1).collect());
        let truths = results.into_iter().map(|r| r.0).collect();
        Ok(Reference {
            albedo,
            tasks,
            truths,
            brdfs: brdfs.to_vec(),
            views: options.views.clone(),
            widths: levels.iter().map(|l| l.size.0).collect(),
            first,
            samples: options.samples,
        })
    }

    /// The texel-space error of `bakes` (of the map the reference was made for) against it,
    /// each vMF bake once per route in `routes`, the baselines by the prefiltered route, SH
    /// bakes by eq 25/26 (module docs). Deterministic, whatever the thread count.
    pub fn score(&self, bakes: &[&Bake], light: &EnvLight, routes: &[Route]) -> Result<Evaluation> {
        self.score_levels(bakes, light, routes, 0..=usize::MAX)
    }

    /// [`Reference::score`] at the levels in `levels` only (the levels a bake of part of a
    /// chain holds); the others are measured as 0 with no ground truth.
    pub fn score_levels(
        &self,
        bakes: &[&Bake],
        light: &EnvLight,
        routes: &[Route],
        levels: std::ops::RangeInclusive<usize>,
    ) -> Result<Evaluation> {
        for b in bakes {
            check_method(b.method)?;
        }
        light.check_routes(bakes, routes, &self.brdfs)?;
        // Configurations: (bake index, route).
        let mut configs = Vec::new();
        for (i, b) in bakes.iter().enumerate() {
            match b.method {
                Method::Vmf | Method::Tan2005 => routes.iter().for_each(|&r| configs.push((i, r))),
                Method::Sh => configs.push((i, Route::Sh)),
                _ => configs.push((i, Route::Prefiltered)),
            }
        }
        let brdfs = &self.brdfs;
        let nb = brdfs.len();
        let nc = configs.len();
        // Per task: per view: sums [config][brdf] of (F−G)² and G² (diffuse, specular), and
        // the ground truth's se² sums.
        type Sums = (Vec<[f64; 4]>, Vec<f64>, Vec<f64>);
        let per_task: Vec<Sums> = self
            .tasks
            .par_iter()
            .zip(&self.truths)
            .enumerate()
            .map(|(ti, (&(k, x, y), truths))| {
                let mut sums = vec![[0.0f64; 4]; nc * nb];
                let mut se = vec![0.0f64; 1 + nb];
                let mut g2 = vec![0.0f64; 1 + nb];
                if !levels.contains(&k) {
                    return (sums, se, g2);
                }
                let texels: Vec<Vec<[f32; 4]>> = bakes
                    .iter()
                    .map(|b| {
                        let idx = y as usize * self.widths[k] as usize + x as usize;
                        let mut t = vec![[0.0f32; 4]; b.textures.len()];
                        b.texel_into(k, idx, &mut t);
                        t
                    })
                    .collect();
                for (&view, gt) in self.views.iter().zip(truths) {
                    se[0] += gt.diffuse_se.powi(2);
                    g2[0] += gt.diffuse.powi(2);
                    for b in 0..nb {
                        se[1 + b] += gt.specular_se[b].powi(2);
                        g2[1 + b] += gt.specular[b].powi(2);
                    }
                    for (c, &(bi, route)) in configs.iter().enumerate() {
                        for (b, brdf) in brdfs.iter().enumerate() {
                            let f =
                                self.shade(ti, light, bakes[bi], &texels[bi], view, brdf, route);
                            let e = &mut sums[c * nb + b];
                            e[0] += (f.diffuse - gt.diffuse).powi(2);
                            e[1] += gt.diffuse.powi(2);
                            e[2] += (f.specular - gt.specular[b]).powi(2);
                            e[3] += gt.specular[b].powi(2);
                        }
                    }
                }
                (sums, se, g2)
            })
            .collect();
        // Per level sums, in task order.
        let nl = self.widths.len();
        let mut lvl = vec![vec![[0.0f64; 4]; nc * nb]; nl];
        let mut lse = vec![vec![0.0f64; 1 + nb]; nl];
        let mut lg2 = vec![vec![0.0f64; 1 + nb]; nl];
        for (&(k, _, _), (sums, se, g2)) in self.tasks.iter().zip(&per_task) {
            for (a, s) in lvl[k].iter_mut().zip(sums) {
                for c in 0..4 {
                    a[c] += s[c];
                }
            }
            for i in 0..=nb {
                lse[k][i] += se[i];
                lg2[k][i] += g2[i];
            }
        }
        let measured: Vec<usize> = (self.first..nl).collect();
        let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
        let rel = crate::eval::relative_rms;
        let mut errors = Vec::new();
        for (c, &(bi, route)) in configs.iter().enumerate() {
            for (b, brdf) in brdfs.iter().enumerate() {
                let per: Vec<(usize, f64, f64)> = measured
                    .iter()
                    .map(|&k| {
                        let e = lvl[k][c * nb + b];
                        (k, rel(e[0], e[1]), rel(e[2], e[3]))
                    })
                    .collect();
                let mut label = if is_mixture(bakes[bi].method) {
                    format!("{} {}", bakes[bi].label(), route.name())
                } else {
                    bakes[bi].label()
                };
                if self.albedo.is_some() && !has_color_textures(bakes[bi]) {
                    label += " × albedo mip";
                }
                errors.push(EnvError {
                    label,
                    brdf: brdf.clone(),
                    diffuse: rms(&per.iter().map(|p| p.1).collect::<Vec<_>>()),
                    specular: rms(&per.iter().map(|p| p.2).collect::<Vec<_>>()),
                    levels: per,
                });
            }
        }
        let noise = |i: usize| {
            rms(&measured
                .iter()
                .map(|&k| rel(lse[k][i], lg2[k][i]))
                .collect::<Vec<_>>())
        };
        let level_noise = measured
            .iter()
            .map(|&k| {
                (
                    k,
                    rel(lse[k][0], lg2[k][0]),
                    (0..nb).map(|b| rel(lse[k][1 + b], lg2[k][1 + b])).collect(),
                )
            })
            .collect();
        Ok(Evaluation {
            errors,
            level_noise,
            noise_diffuse: noise(0),
            noise_specular: (0..nb).map(|b| noise(1 + b)).collect(),
            samples: self.samples,
            texels: self.tasks.len(),
            views: self.views.len(),
        })
    }

    /// The luminance `bake`'s texel of task `ti` is scored by: [`shade`]'s, or with colour
    /// ([`EvalOptions::color`]) eq 22's coloured shading for a bake with colour textures and
    /// the shading times the footprint's mean albedo for any other.
    #[allow(clippy::too_many_arguments)]
    fn shade(
        &self,
        ti: usize,
        light: &EnvLight,
        bake: &Bake,
        texels: &[[f32; 4]],
        view: DVec3,
        brdf: &Brdf,
        route: Route,
    ) -> crate::brdf::Shading {
        let Some(albedo) = &self.albedo else {
            return shade(light, bake, texels, view, brdf, route).luminance();
        };
        if has_color_textures(bake) {
            return shade_with(light, bake, texels, view, brdf, route, true).luminance();
        }
        let mut s = shade(light, bake, texels, view, brdf, route);
        let a = albedo[ti].to_array();
        for ((d, sp), a) in s.diffuse.iter_mut().zip(&mut s.specular).zip(a) {
            *d *= a;
            *sp *= a;
        }
        s.luminance()
    }
}

/// Texel-space error of `bakes` (of `map`) under `light`: a [`Reference`] for `brdfs` and
/// `options`, scored against the bakes ([`Reference::score`]).
pub fn evaluate(
    map: &crate::NormalMap,
    bakes: &[&Bake],
    brdfs: &[Brdf],
    light: &EnvLight,
    routes: &[Route],
    options: &EvalOptions,
) -> Result<Evaluation> {
    for b in bakes {
        check_method(b.method)?;
    }
    Reference::new(map, brdfs, light, options)?.score(bakes, light, routes)
}

/// An error with the ground truth's own noise taken out: the noise is independent of the
/// estimate, so the measured mean square is the true one plus the noise's,
/// `sqrt(max(e² − n², 0))` (columns `-dn` of [`format_table`]).
pub fn denoised(error: f64, noise: f64) -> f64 {
    (error * error - noise * noise).max(0.0).sqrt()
}

/// The errors as a text table (percent): measured, and with the ground truth's noise taken out
/// ([`denoised`]).
pub fn format_table(e: &Evaluation) -> String {
    let mut s = format!(
        "environment-lit texel-space error (relative RMS %, {} texels × {} views, ground truth {} MIS iterations; its noise: diffuse {:.2} %, specular {})\n",
        e.texels,
        e.views,
        e.samples,
        100.0 * e.noise_diffuse,
        e.noise_specular
            .iter()
            .map(|v| format!("{:.2} %", 100.0 * v))
            .collect::<Vec<_>>()
            .join(", ")
    );
    // The label column as wide as the longest label (at least 24).
    let w = e
        .errors
        .iter()
        .map(|r| r.label.chars().count())
        .fold(24, usize::max);
    s += &format!(
        "{:<w$} {:<28} {:>10} {:>10} {:>12} {:>12}\n",
        "config", "brdf", "diffuse", "specular", "diffuse-dn", "specular-dn"
    );
    let nb = e.noise_specular.len().max(1);
    for (i, r) in e.errors.iter().enumerate() {
        let brdf = match &r.brdf {
            Brdf::BlinnPhong { s } => format!("blinn-phong s={s}"),
            Brdf::Ggx(g) => format!("ggx a={}", g.alpha),
            b => b.model().to_string(),
        };
        let ns = e.noise_specular.get(i % nb).copied().unwrap_or(0.0);
        s += &format!(
            "{:<w$} {:<28} {:>10.2} {:>10.2} {:>12.2} {:>12.2}\n",
            r.label,
            brdf,
            100.0 * r.diffuse,
            100.0 * r.specular,
            100.0 * denoised(r.diffuse, e.noise_diffuse),
            100.0 * denoised(r.specular, ns)
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::energy_quadrature::*;
    use super::*;
    use crate::brdf::ggx;
    use crate::environment::Sky;

    fn bp_closed_form(s: f64) -> f64 {
        // ∫ L (s+1)/(2π) c^s (2c² − 1) 4c dω_h over c > 1/√2, L = 1, view = normal.
        let a = 0.5f64.sqrt();
        4.0 * (s + 1.0)
            * (2.0 * (1.0 - a.powf(s + 4.0)) / (s + 4.0) - (1.0 - a.powf(s + 2.0)) / (s + 2.0))
    }

    /// The shading of a grey environment: its three channels must be identical.
    fn grey(f: RgbShading) -> crate::brdf::Shading {
        assert_eq!(f.diffuse, [f.diffuse[0]; 3], "{f:?}");
        assert_eq!(f.specular, [f.specular[0]; 3], "{f:?}");
        f.channel(0)
    }

    fn flat_bake(method: Method) -> Bake {
        let map = map_of(4, 4, vec![glam::Vec3::Z; 16]);
        crate::methods::bake(&map, method)
    }

    /// The methods the environment routes shade, in the order the tests visit them.
    const ENV_METHODS: [Method; 7] = [
        Method::Plain,
        Method::Toksvig,
        Method::Lean,
        Method::Olano,
        Method::Vmf,
        Method::Tan2005,
        Method::Sh,
    ];

    /// A tilted tangent frame (tangent → environment), an oblique view and a BRDF of each
    /// family (Lambert, Blinn-Phong 32, GGX 0.3): the shared probe of the RGB, prefiltered-only
    /// and colour tests.
    fn tilted_probe() -> (DMat3, DVec3, [Brdf; 3]) {
        (
            DMat3::from_axis_angle(DVec3::new(0.3, 1.0, 0.0).normalize(), -0.6),
            DVec3::new(0.2, 0.3, 0.93).normalize(),
            [Brdf::Lambert, Brdf::BlinnPhong { s: 32.0 }, Brdf::ggx(0.3)],
        )
    }

    /// The generated sky (sun included), `width` × `width / 2`.
    fn sky(width: u32) -> Environment {
        Sky {
            width,
            ..Sky::default()
        }
        .render()
        .unwrap()
    }

    /// The generated 64 × 32 sky (sun included), ready to light with.
    fn sky_light() -> EnvLight {
        EnvLight::new(&sky(64))
    }

    /// Four tilted normals of a 2 × 2 map whose level-1 texel is their footprint.
    fn quad_normals() -> Vec<glam::Vec3> {
        vec![
            glam::Vec3::new(0.3, 0.0, 0.954),
            glam::Vec3::new(0.0, -0.4, 0.9165),
            glam::Vec3::Z,
            glam::Vec3::new(-0.2, 0.2, 0.959),
        ]
    }

    /// The sky, the four [`quad_normals`] as a 2 × 2 map, a tangent frame turned 60° towards
    /// the sun and an oblique view: the probe of the tilted-frame diffuse tests.
    fn quad_turned_to_the_sun() -> (EnvLight, Vec<glam::Vec3>, crate::NormalMap, DMat3, DVec3) {
        let normals = quad_normals();
        (
            sky_light(),
            normals.clone(),
            map_of(2, 2, normals),
            DMat3::from_axis_angle(DVec3::new(0.3, 1.0, 0.0).normalize(), -1.05),
            DVec3::new(0.2, 0.3, 0.93).normalize(),
        )
    }

    fn map_of(w: u32, h: u32, v: Vec<glam::Vec3>) -> crate::NormalMap {
        crate::NormalMap::from_vectors(w, h, v, Default::default(), Default::default()).unwrap()
    }

    #[test]
    fn constant_environment_matches_the_closed_forms() {
        let light = EnvLight::grey(Radiance::constant(64, 1.0));
        let brdfs = [
            Brdf::BlinnPhong { s: 32.0 },
            Brdf::BlinnPhong { s: 256.0 },
            Brdf::ggx(0.3),
        ];
        let n = [(DVec3::Z, 1.0)];
        let gt = ground_truth(&light, &n, DVec3::Z, &brdfs, 20000, 3);
        // Lambert: π for any normal under a constant environment.
        assert!(
            (gt.diffuse - PI).abs() < 4.0 * gt.diffuse_se + 1e-9,
            "{gt:?}"
        );
        assert!(gt.diffuse_se < 0.01 * PI);
        for (b, s) in [(0, 32.0), (1, 256.0)] {
            let cf = bp_closed_form(s);
            assert!(
                (gt.specular[b] - cf).abs() < 4.0 * gt.specular_se[b],
                "s={s} {} {cf}",
                gt.specular[b]
            );
        }
        // GGX: the projected lobe integrates to 1; at normal view ∫ D (2c²−1) 4c dω_h by quadrature.
        let q = lobe_moments(&|c| ggx(c, 0.3), 0.3, 1.0, true)[0];
        assert!(
            (gt.specular[2] - q).abs() < 4.0 * gt.specular_se[2],
            "{} {q}",
            gt.specular[2]
        );
        // The routes on a flat map: exact diffuse, specular within the tables' interpolation.
        for m in ENV_METHODS.into_iter().filter(|&m| m != Method::Sh) {
            let bake = flat_bake(m);
            let t = bake.texel(0, 0, 0);
            for (b, brdf) in brdfs.iter().enumerate() {
                let f = grey(shade(&light, &bake, &t, DVec3::Z, brdf, Route::Prefiltered));
                assert!((f.diffuse - PI).abs() < 1e-3, "{m} {}", f.diffuse);
                let g = if b < 2 {
                    bp_closed_form([32.0, 256.0][b])
                } else {
                    q
                };
                assert!(
                    (f.specular - g).abs() < 0.01 * g,
                    "{m} {brdf:?} {} {g}",
                    f.specular
                );
            }
        }
    }

    /// `1 − cos γ` at the quantiles [`MIX_QUANTILES`] of `(1 − t)·vMF(κ_c) + t·vMF(κ_t)`, by
    /// bisection on the closed-form CDF.
    fn mixture_quantiles(kc: f64, t: f64, kt: f64) -> [f64; MIX_QUANTILES.len()] {
        MIX_QUANTILES.map(|q| {
            let (mut lo, mut hi) = (0.0, 2.0);
            for _ in 0..200 {
                let mid = 0.5 * (lo + hi);
                if (1.0 - t) * vmf_cdf(kc, mid) + t * vmf_cdf(kt, mid) < q {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            0.5 * (lo + hi)
        })
    }

    #[test]
    fn the_two_vmf_fit_recovers_a_vmf_and_a_mixture() {
        use crate::vmf::a_kappa;
        // A single vMF stays single.
        for k in [2.0, 40.0, 900.0] {
            let (kc, t, kt) = two_vmf_fit(a_kappa(k), &mixture_quantiles(k, 0.0, k), vmf_peak(k));
            assert!(
                t <= 0.02 && (kc / k - 1.0).abs() < 0.1,
                "{k}: {kc} {t} {kt}"
            );
        }
        // A core and a tail 16 times broader, 30 % of the energy: recovered within the grid.
        let (k1, share, k2) = (400.0, 0.3, 25.0);
        let r = (1.0 - share) * a_kappa(k1) + share * a_kappa(k2);
        let (kc, t, kt) = two_vmf_fit(
            r,
            &mixture_quantiles(k1, share, k2),
            (1.0 - share) * vmf_peak(k1) + share * vmf_peak(k2),
        );
        assert!((t - share).abs() <= 0.04, "{kc} {t} {kt}");
        assert!((kc / k1).log2().abs() <= 0.25, "{kc} {t} {kt}");
        assert!((kt / k2).log2().abs() <= 0.5, "{kc} {t} {kt}");
        // The first moment is kept exactly.
        let m = (1.0 - t) * a_kappa(kc) + t * a_kappa(kt);
        assert!((m - r).abs() < 1e-9, "{m} {r}");
    }

    #[test]
    fn ggx_core_and_tail_follow_a_sun_inside_the_lobe() {
        // A flat surface, GGX α = 0.1, the generated sky with its sun; the view reflects the
        // sun's direction (the sun in the lobe's core) and 6° and 20° away from it (the
        // shoulder, the tail). The route against the MIS ground truth of the same light.
        let sky = sky(256);
        let light = EnvLight::new(&sky);
        let brdf = Brdf::ggx(0.1);
        let bake = flat_bake(Method::Plain);
        let t = bake.texel(0, 0, 0);
        let (ts, ps) = (55f64.to_radians(), 30f64.to_radians());
        let n = [(DVec3::Z, 1.0)];
        let table = light.energy_table(&brdf).unwrap();
        for off in [0.0, 6.0, 20.0, 40.0] {
            let th = ts - f64::to_radians(off);
            let view = DVec3::new(-th.sin() * ps.cos(), -th.sin() * ps.sin(), th.cos());
            let gt = ground_truth(&light, &n, view, std::slice::from_ref(&brdf), 40000, 11);
            let f = shade(&light, &bake, &t, view, &brdf, Route::Prefiltered).luminance();
            // The single first-moment vMF (the route before the split), for comparison.
            let [e, blend, _, _, _, _, _, _, _] = light.energy.ggx(0.1, 0.0, view.z);
            let one = lobe_moments(&|c| ggx(c, 0.1), 0.1, view.z, false)[2].exp2();
            let r = 2.0 * view.z * DVec3::Z - view;
            let d = tilted(DVec3::Z, r, blend);
            let single = (0..3)
                .map(|c| LUMINANCE[c] * light.channels[c].prefiltered.lookup(d, one))
                .sum::<f64>()
                * e
                * brdf.g(r, DVec3::Z);
            let (err, err1) = (
                f.specular / gt.specular[0] - 1.0,
                single / gt.specular[0] - 1.0,
            );
            eprintln!(
                "off {off}: gt {} ± {} two {} ({err:+.3}) single {single} ({err1:+.3})",
                gt.specular[0], gt.specular_se[0], f.specular
            );
            assert_eq!(
                table.len(),
                ENERGY_BLOCKS * ENERGY_PARAM * ENERGY_SHARES * ENERGY_COS
            );
            // Measured (256-wide sky), with levels whose grids resolve their lobes: core
            // −2.4 %, shoulder −30 %, 20° −12 %, 40° +17 % against the single vMF's −77 %,
            // −63 %, +33 %, −3 % (with the earlier levels, narrower than their texels: core
            // −36 %, shoulder +28 %, 20° −7 %, 40° +20 %). What is left is the lobe's shape
            // (two isotropic vMFs); at 40° the single vMF's broader tail is closer.
            assert!(err.abs() < 0.35, "{off}: two vMFs {err}");
            if off == 0.0 {
                // The sun in the lobe's core: the α = 0.1 regression.
                assert!(err.abs() < 0.08, "core: two vMFs {err}");
            }
            if off <= 20.0 {
                assert!(err.abs() < err1.abs(), "{off}: two vMFs {err}, one {err1}");
            }
        }
    }

    #[test]
    fn black_environment_is_exactly_zero() {
        let light = EnvLight::grey(Radiance::constant(32, 0.0));
        let brdfs = [Brdf::BlinnPhong { s: 32.0 }, Brdf::ggx(0.1)];
        let gt = ground_truth(
            &light,
            &[(DVec3::Z, 1.0)],
            DVec3::new(0.6, 0.0, 0.8),
            &brdfs,
            64,
            1,
        );
        assert_eq!(gt.diffuse, 0.0);
        assert!(gt.specular.iter().all(|&v| v == 0.0));
        for m in ENV_METHODS {
            let bake = flat_bake(m);
            let t = bake.texel(0, 0, 0);
            for route in [Route::Prefiltered, Route::Sh] {
                for brdf in &brdfs {
                    let f = grey(shade(&light, &bake, &t, DVec3::Z, brdf, route));
                    assert_eq!((f.diffuse, f.specular), (0.0, 0.0), "{m}");
                }
            }
        }
    }

    #[test]
    fn lambert_sh_is_eq_25_and_matches_the_ground_truth_of_a_smooth_sky() {
        // Eq 25 against the addition theorem summed over the texels directly:
        // E_2(n) = Σ_t L_t Ω_t Σ_{l≤2} ρ̂_l (2l+1)/(4π) P_l(ω_t·n).
        let sky = sky(128).luminance();
        let light = EnvLight::grey(sky.clone());
        let bake = flat_bake(Method::Plain);
        let t = bake.texel(0, 0, 0);
        let f = grey(shade(
            &light,
            &bake,
            &t,
            DVec3::Z,
            &Brdf::Lambert,
            Route::Sh,
        ));
        let g = sky.grid();
        let mut direct = 0.0;
        for y in 0..g.height {
            for x in 0..g.width {
                let mut k = 0.0;
                for (fx, fy) in [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)] {
                    let u = g.sub_direction(x, y, fx, fy).z;
                    let p = [1.0, u, 0.5 * (3.0 * u * u - 1.0)];
                    k += (0..3)
                        .map(|l| LAMBERT[l] * (2 * l + 1) as f64 / (4.0 * PI) * p[l])
                        .sum::<f64>()
                        / 4.0;
                }
                direct += sky.values()[(y * g.width + x) as usize] as f64 * sky.solid_angle(y) * k;
            }
        }
        assert!(
            (f.diffuse - direct).abs() < 1e-9 * direct,
            "{} {direct}",
            f.diffuse
        );
        // A smooth sky (no sun): l ≤ 2 within 1 % of the Monte Carlo ground truth
        // (Ramamoorthi & Hanrahan), for tilted normals too.
        let smooth = Sky {
            width: 128,
            sun: [0.0; 3],
            ..Sky::default()
        }
        .render()
        .unwrap();
        let light = EnvLight::grey(smooth.luminance());
        for n in [
            DVec3::Z,
            DVec3::new(0.5, 0.2, 0.8).normalize(),
            DVec3::new(-0.9, 0.0, 0.1).normalize(),
        ] {
            let gt = ground_truth(&light, &[(n, 1.0)], DVec3::Z, &[Brdf::Lambert], 20000, 9);
            let lobe = Lobe {
                alpha: 1.0,
                mu: n,
                r: 1.0,
                kappa: f64::INFINITY,
                slot: 0,
            };
            let y = crate::harmonics::eval(ENV_LMAX, n);
            let e = diffuse_lobe(light.channel(0).sh(), &y, &lobe);
            assert!(gt.diffuse_se < 0.005 * gt.diffuse, "{gt:?}");
            assert!(
                (e - gt.diffuse).abs() < 0.01 * gt.diffuse + 3.0 * gt.diffuse_se,
                "{n} {e} {}",
                gt.diffuse
            );
        }
    }

    #[test]
    fn a_single_texel_sun_stays_finite_and_bounded() {
        let mut v = vec![0.0f32; 64 * 32];
        v[10 * 64 + 20] = 1e6;
        let env = Radiance::new(64, 32, v).unwrap();
        let power = env.power();
        let light = EnvLight::grey(env);
        let brdfs = [Brdf::BlinnPhong { s: 1e5 }, Brdf::ggx(0.001), Brdf::Lambert];
        let mut rng = Rng(4);
        for _ in 0..20 {
            let n = rng.upper();
            let o = rng.upper();
            let gt = ground_truth(&light, &[(n, 1.0)], o, &brdfs, 64, 2);
            assert!(gt.diffuse.is_finite() && gt.diffuse <= power * (1.0 + 1e-9));
            for m in [Method::Plain, Method::Toksvig, Method::Vmf, Method::Sh] {
                let bake = flat_bake(m);
                let t = bake.texel(0, 0, 0);
                for route in [Route::Prefiltered, Route::Sh] {
                    for brdf in &brdfs {
                        let f = grey(shade(&light, &bake, &t, o, brdf, route));
                        assert!(f.diffuse.is_finite() && f.diffuse >= 0.0);
                        assert!(f.diffuse <= 2.0 * power, "{m} {}", f.diffuse);
                        assert!(f.specular.is_finite() && f.specular >= 0.0, "{m} {brdf:?}");
                    }
                }
            }
        }
    }

    #[test]
    fn sh_method_diffuse_matches_the_footprint_ground_truth() {
        let light = sky_light();
        let map = map_of(2, 2, quad_normals());
        let bake = crate::methods::bake(&map, Method::Sh);
        let t = bake.texel(1, 0, 0);
        let a = shade(&light, &bake, &t, DVec3::Z, &Brdf::Lambert, Route::Sh).luminance();
        let normals: Vec<(DVec3, f64)> = map
            .normals()
            .iter()
            .map(|n| (n.as_dvec3().normalize(), 0.25))
            .collect();
        let gt = ground_truth(&light, &normals, DVec3::Z, &[Brdf::Lambert], 20000, 5);
        assert!(
            (a.diffuse - gt.diffuse).abs() < 0.05 * gt.diffuse,
            "{} {}",
            a.diffuse,
            gt.diffuse
        );
    }

    #[test]
    fn moment_basis_is_the_harmonics_basis() {
        // At a single normal (E[n] = n, E[nnᵀ] = nnᵀ) the moments' polynomials are the
        // recurrence's Y_lm, l ≤ 2, whatever the direction.
        let basis = Basis::new(2);
        let mut y = vec![0.0; 9];
        let mut rng = Rng(7);
        for _ in 0..200 {
            let n = rng.direction();
            basis.eval_into(n, &mut y);
            let second = DMat3::from_cols(n * n.x, n * n.y, n * n.z);
            let got = moment_basis(n, second);
            for k in 0..9 {
                assert!(
                    (got[k] - y[k]).abs() < 1e-12,
                    "{n} k={k}: {} {}",
                    got[k],
                    y[k]
                );
            }
        }
    }

    #[test]
    fn olano_diffuse_is_the_footprint_average_of_the_band_limited_irradiance() {
        // Olano–North's moments give the footprint average of the l ≤ 2 irradiance itself:
        // against Σ_{l≤2} ρ̂_l Σ_m L_lm Y_lm(F n) averaged over the four normals (tilted frame,
        // to f32 storage of the moments), and against the Monte Carlo ground truth of the
        // normals (the bands above 2 of a smooth sky are small). Toksvig's one lobe, which
        // knows only |E[n]|, is further off the band-limited average.
        let (light, normals, map, frame, view) = quad_turned_to_the_sun();
        let basis = Basis::new(2);
        let mut y = vec![0.0; 9];
        let band_limited: f64 = normals
            .iter()
            .map(|n| {
                basis.eval_into(frame * n.as_dvec3().normalize(), &mut y);
                let sh = light.channel(1).sh();
                (0..9)
                    .map(|k| LAMBERT[(k as f64).sqrt() as usize] * sh[k] * y[k])
                    .sum::<f64>()
                    / 4.0
            })
            .sum();
        let olano = crate::methods::bake(&map, Method::Olano);
        let t = olano.texel(1, 0, 0);
        for route in [Route::Prefiltered, Route::Sh] {
            let f = shade_in(&light, frame, &olano, &t, view, &Brdf::Lambert, route);
            let d = f.channel(1).diffuse;
            assert!(
                (d - band_limited).abs() < 1e-6 * band_limited,
                "{route:?}: {d} {band_limited}"
            );
        }
        let toksvig = crate::methods::bake(&map, Method::Toksvig);
        let tt = toksvig.texel(1, 0, 0);
        let f = shade_in(
            &light,
            frame,
            &toksvig,
            &tt,
            view,
            &Brdf::Lambert,
            Route::Sh,
        );
        assert!((f.channel(1).diffuse - band_limited).abs() > 1e-4 * band_limited);
        let turned: Vec<(DVec3, f64)> = normals
            .iter()
            .map(|n| (frame * n.as_dvec3().normalize(), 0.25))
            .collect();
        let gt = ground_truth(&light, &turned, frame * view, &[Brdf::Lambert], 20000, 9);
        let a = shade_in(&light, frame, &olano, &t, view, &Brdf::Lambert, Route::Sh).luminance();
        assert!(
            (a.diffuse - gt.diffuse).abs() < 0.05 * gt.diffuse,
            "{} {}",
            a.diffuse,
            gt.diffuse
        );
    }

    #[test]
    fn spreading_olano_and_tan2005_texels_convolves_their_moments() {
        // Olano–North: E[n] times A(k) and E[nnᵀ] → (A/k) I + (1 − 3A/k) E[nnᵀ], against the
        // moments of vMF(n, k) integrated by quadrature over the sphere for each normal.
        let k = 12.0;
        let map = map_of(2, 2, quad_normals());
        let olano = crate::methods::bake(&map, Method::Olano);
        let t = olano.texel(1, 0, 0);
        let spread = spread_texels(&olano, &t, k);
        let (steps_t, steps_p) = (800, 400);
        let mut first = DVec3::ZERO;
        let mut second = DMat3::ZERO;
        for n in quad_normals() {
            let n = n.as_dvec3().normalize();
            let (t1, t2) = crate::brdf::tangent_frame(n);
            let (mut z, mut m1, mut m2) = (0.0, DVec3::ZERO, DMat3::ZERO);
            for i in 0..steps_t {
                let th = (i as f64 + 0.5) * PI / steps_t as f64;
                for j in 0..steps_p {
                    let ph = (j as f64 + 0.5) * 2.0 * PI / steps_p as f64;
                    let w = th.sin() * (k * (th.cos() - 1.0)).exp();
                    let d = th.cos() * n + th.sin() * (ph.cos() * t1 + ph.sin() * t2);
                    z += w;
                    m1 += w * d;
                    m2 += w * DMat3::from_cols(d * d.x, d * d.y, d * d.z);
                }
            }
            first += 0.25 * m1 / z;
            second += (0.25 / z) * m2;
        }
        let (d, o) = (spread[1], spread[2]);
        let got = [
            spread[0][0],
            spread[0][1],
            spread[0][2],
            d[0],
            d[1],
            d[2],
            o[0],
            o[1],
            o[2],
        ];
        let want = [
            first.x,
            first.y,
            first.z,
            second.x_axis.x,
            second.y_axis.y,
            second.z_axis.z,
            second.y_axis.x,
            second.z_axis.x,
            second.z_axis.y,
        ];
        for (g, w) in got.iter().zip(want) {
            assert!((f64::from(*g) - w).abs() < 2e-5, "{got:?} {want:?}");
        }
        // Tan 2005: each component's σ² raised by 1/k, its weight and mean kept.
        let tan = crate::methods::bake(&map, Method::Tan2005);
        let t = tan.texel(1, 0, 0);
        let spread = spread_texels(&tan, &t, k);
        let mut seen = 0;
        for j in 0..tan.lobes {
            let (a, b) = (
                crate::tan2005::Gaussian::from_texel(t[j]),
                crate::tan2005::Gaussian::from_texel(spread[j]),
            );
            if a.is_empty() {
                continue;
            }
            seen += 1;
            assert_eq!((a.alpha, a.mean), (b.alpha, b.mean));
            assert!(
                (b.variance - a.variance - 1.0 / k).abs() < 1e-5,
                "{a:?} {b:?}"
            );
        }
        assert!(seen >= 2, "{seen}");
    }

    #[test]
    fn a_tilted_tangent_frame_shades_like_the_rotated_footprint() {
        // The surface's tangent frame turned 60° towards the sun: every method's diffuse term
        // (SH bakes through the rotated L_lm) against the ground truth over the normals turned
        // into the environment's frame; the identity frame is far off, so the frame is used.
        let (light, normals, map, frame, view) = quad_turned_to_the_sun();
        let turned: Vec<(DVec3, f64)> = normals
            .iter()
            .map(|n| (frame * n.as_dvec3().normalize(), 0.25))
            .collect();
        let gt = ground_truth(&light, &turned, frame * view, &[Brdf::Lambert], 20000, 9);
        for m in ENV_METHODS {
            let bake = crate::methods::bake(&map, m);
            let t = bake.texel(1, 0, 0);
            let f = shade_in(&light, frame, &bake, &t, view, &Brdf::Lambert, Route::Sh).luminance();
            let flat = shade(&light, &bake, &t, view, &Brdf::Lambert, Route::Sh).luminance();
            let rel = |x: f64| (x - gt.diffuse).abs() / gt.diffuse;
            assert!(
                rel(f.diffuse) < 0.05,
                "{m}: {} vs {}",
                f.diffuse,
                gt.diffuse
            );
            assert!(
                rel(flat.diffuse) > 0.1,
                "{m}: {} vs {}",
                flat.diffuse,
                gt.diffuse
            );
        }
    }

    #[test]
    fn each_channel_is_the_single_channel_route() {
        // A sun and sky of different colours, a tilted frame: every method, route and BRDF
        // shaded in RGB equals, per channel, the shading under that channel alone (a grey
        // environment of it) — a swapped or collapsed channel fails — and the channels differ.
        let sky = crate::environment::coloured_test_sky();
        let light = EnvLight::new(&sky);
        let single: Vec<EnvLight> = (0..3).map(|c| EnvLight::grey(sky.channel(c))).collect();
        let map = map_of(2, 2, quad_normals());
        let (frame, view, brdfs) = tilted_probe();
        let mut checked = 0;
        for m in ENV_METHODS {
            let bake = crate::methods::bake(&map, m);
            let t = bake.texel(1, 0, 0);
            for route in [Route::Prefiltered, Route::Sh] {
                for brdf in &brdfs {
                    let rgb = shade_in(&light, frame, &bake, &t, view, brdf, route);
                    for (c, one) in single.iter().enumerate() {
                        let want = grey(shade_in(one, frame, &bake, &t, view, brdf, route));
                        assert_eq!(rgb.channel(c), want, "{m} {route:?} {brdf:?} channel {c}");
                    }
                    assert!(rgb.diffuse[0] != rgb.diffuse[2], "{m} {rgb:?}");
                    if brdf.has_specular() {
                        assert!(
                            (rgb.specular[0] - rgb.specular[2]).abs() > 0.1 * rgb.specular[1],
                            "{m} {rgb:?}"
                        );
                    }
                    let lum = rgb.luminance();
                    let w = crate::environment::LUMINANCE;
                    let d = w[0] * rgb.diffuse[0] + w[1] * rgb.diffuse[1] + w[2] * rgb.diffuse[2];
                    assert!((lum.diffuse - d).abs() <= 1e-12 * d.abs());
                    checked += 1;
                }
            }
        }
        assert_eq!(checked, 42);
    }

    #[test]
    fn sample_and_texel_counts_outside_their_ranges_are_refused() {
        // `samples * (texels_per_level / n)` wrapped to 0 for samples = 2⁶² (every error then
        // inf, exit 0); 0 samples gave an empty ground truth. The bounds are accepted.
        let sky = crate::environment::coloured_test_sky();
        let light = EnvLight::prefiltered_only(&sky);
        let map = map_of(2, 2, quad_normals());
        let brdfs = [Brdf::Lambert];
        for (samples, texels, words) in [
            (0, 4, "samples 0 (expected 1 to 65536)"),
            (MAX_SAMPLES + 1, 4, "samples 65537 (expected 1 to 65536)"),
            (1 << 62, 4, "samples 4611686018427387904"),
            (8, 0, "texels_per_level 0 (expected 1 to 1024)"),
            (8, MAX_TEXELS_PER_LEVEL + 1, "texels_per_level 1025"),
            (8, usize::MAX, "texels_per_level 18446744073709551615"),
        ] {
            let options = EvalOptions {
                samples,
                texels_per_level: texels,
                ..Default::default()
            };
            match Reference::new(&map, &brdfs, &light, &options) {
                Err(Error::InvalidOption(m)) => assert!(m.contains(words), "{m}"),
                other => panic!("{samples} {texels}: {:?}", other.map(|_| ())),
            }
        }
        for (samples, texels) in [(1, 1), (MAX_SAMPLES, 1), (1, MAX_TEXELS_PER_LEVEL)] {
            let options = EvalOptions {
                samples,
                texels_per_level: texels,
                views: vec![DVec3::Z],
                ..Default::default()
            };
            let reference = Reference::new(&map, &brdfs, &light, &options).unwrap();
            let bake = crate::methods::bake(&map, Method::Plain);
            let e = reference
                .score(&[&bake], &light, &[Route::Prefiltered])
                .unwrap();
            assert!(e.errors.iter().all(|e| e.diffuse.is_finite()), "{e:?}");
        }
    }

    #[test]
    fn prefiltered_only_shades_its_routes_like_the_full_light_and_refuses_the_sh_route() {
        // The planner's light: every method by the prefiltered route, and the diffuse term of
        // an SH bake, bit for bit the full light's; the SH route (and an SH bake's specular
        // term) under a specular BRDF a typed error from every fallible entry point, Lambert
        // still measured.
        let sky = crate::environment::coloured_test_sky();
        let full = EnvLight::new(&sky);
        let lite = EnvLight::prefiltered_only(&sky);
        assert!(full.has_sh_route() && !lite.has_sh_route());
        let map = map_of(2, 2, quad_normals());
        let (frame, view, brdfs) = tilted_probe();
        for m in ENV_METHODS {
            let bake = crate::methods::bake(&map, m);
            let t = bake.texel(1, 0, 0);
            for brdf in &brdfs {
                if m == Method::Sh && brdf.has_specular() {
                    // An SH bake's specular term reads L′: refused below (and a panic if
                    // shade_in were called anyway).
                    continue;
                }
                let a = shade_in(&full, frame, &bake, &t, view, brdf, Route::Prefiltered);
                let b = shade_in(&lite, frame, &bake, &t, view, brdf, Route::Prefiltered);
                assert_eq!(a, b, "{m} {brdf:?}");
                assert!(a.specular.iter().chain(&a.diffuse).all(|v| v.is_finite()));
            }
        }
        let vmf = crate::methods::bake(&map, Method::Vmf);
        let sh = crate::methods::bake(&map, Method::Sh);
        let specular = [Brdf::BlinnPhong { s: 32.0 }];
        assert!(
            lite.check_routes(&[&vmf], &[Route::Prefiltered], &specular)
                .is_ok()
        );
        assert!(
            lite.check_routes(&[&sh], &[Route::Prefiltered], &[Brdf::Lambert])
                .is_ok()
        );
        let options = EvalOptions {
            texels_per_level: 2,
            samples: 8,
            ..Default::default()
        };
        for (bake, routes) in [(&vmf, [Route::Sh]), (&sh, [Route::Prefiltered])] {
            let e = evaluate(&map, &[bake], &specular, &lite, &routes, &options);
            let Err(Error::InvalidOption(msg)) = e else {
                panic!("{:?} {routes:?}: {:?}", bake.method, e.map(|_| ()));
            };
            assert!(
                msg.contains("prefiltered_only") && msg.contains("L′"),
                "{msg}"
            );
            assert!(full.check_routes(&[bake], &routes, &specular).is_ok());
        }
        assert!(lite.channel(1).reflected().is_err() && full.channel(1).reflected().is_ok());
        assert!(crate::envgpu::pack(&lite).is_err() && crate::envgpu::pack(&full).is_ok());
        // Measured with the prefiltered route, both lights give the same errors.
        let a = evaluate(
            &map,
            &[&vmf],
            &specular,
            &full,
            &[Route::Prefiltered],
            &options,
        );
        let b = evaluate(
            &map,
            &[&vmf],
            &specular,
            &lite,
            &[Route::Prefiltered],
            &options,
        );
        assert_eq!(a.unwrap(), b.unwrap());
    }

    #[test]
    #[should_panic(expected = "prefiltered route only")]
    fn the_sh_route_on_a_prefiltered_only_light_panics_rather_than_shade_nan() {
        let lite = EnvLight::prefiltered_only(&crate::environment::coloured_test_sky());
        let bake = crate::methods::bake(&map_of(2, 2, quad_normals()), Method::Vmf);
        let t = bake.texel(0, 0, 0);
        let brdf = Brdf::BlinnPhong { s: 32.0 };
        let _ = shade(&lite, &bake, &t, DVec3::Z, &brdf, Route::Sh);
    }

    /// A 16 × 16 procedural map with the albedo `colour(n)` of each normal.
    fn coloured_map(colour: impl Fn(glam::Vec3) -> [f32; 4]) -> crate::NormalMap {
        let map = crate::procedural::generate(16, 5).map;
        let albedo = map.normals().iter().map(|&n| colour(n)).collect();
        map.with_feature(albedo).unwrap()
    }

    #[test]
    fn colour_textures_weight_each_lobe_by_its_colour() {
        // Eq 22 under the environment: with white albedo every lobe's α·y is α and the colour
        // shading equals the uncoloured one; with two colours (red where the normal leans to
        // +x, blue elsewhere) each channel equals Σ_j y_j,c × (lobe j alone, shaded with α,
        // through the uncoloured route) — an independent sum over one-lobe texels — and the
        // channels differ. Every route, a tilted frame, Lambert / Blinn-Phong / GGX.
        let sky = crate::environment::coloured_test_sky();
        let light = EnvLight::new(&sky);
        let (frame, view, brdfs) = tilted_probe();
        let opts = crate::bake::BakeOptions {
            lobes: 3,
            ..Default::default()
        };
        let white =
            crate::methods::bake_with(&coloured_map(|_| [1.0; 4]), Method::Vmf, &opts).unwrap();
        let (red, blue) = ([0.9f32, 0.25, 0.05, 1.0], [0.05f32, 0.3, 0.8, 1.0]);
        let two = crate::methods::bake_with(
            &coloured_map(|n| if n.x > 0.0 { red } else { blue }),
            Method::Vmf,
            &opts,
        )
        .unwrap();
        assert_eq!(two.textures.len(), 2 * two.lobes);
        let close = |a: f64, b: f64, tol: f64| (a - b).abs() <= tol * b.abs().max(1e-3);
        let mut differing = 0;
        for route in [Route::Prefiltered, Route::Sh] {
            for brdf in &brdfs {
                for (level, x, y) in [(0, 3, 5), (1, 2, 1), (2, 1, 2), (4, 0, 0)] {
                    // White albedo: exactly the uncoloured shading (the colour texel α·1
                    // is the lobe texel's α, bit for bit).
                    let t = white.texel(level, x, y);
                    for j in 0..white.lobes {
                        assert_eq!([t[white.lobes + j][0]; 3], t[white.lobes + j][..3]);
                        assert_eq!(t[white.lobes + j][0], t[j][0], "lobe {j}");
                    }
                    let c = shade_in_with(&light, frame, &white, &t, view, brdf, route, true);
                    let g = shade_in(&light, frame, &white, &t, view, brdf, route);
                    assert_eq!(c, g);
                    // Two colours: per lobe by hand.
                    let t = two.texel(level, x, y);
                    let c = shade_in_with(&light, frame, &two, &t, view, brdf, route, true);
                    let mut want = RgbShading::default();
                    for j in 0..two.lobes {
                        let alpha = t[j][0] as f64;
                        if alpha <= crate::vmf::alpha_min(two.format) {
                            continue;
                        }
                        let mut one = t.clone();
                        for (i, o) in one[..two.lobes].iter_mut().enumerate() {
                            if i != j {
                                *o = [0.0; 4];
                            }
                        }
                        let s = shade_in(&light, frame, &two, &one, view, brdf, route);
                        for (k, &y) in t[two.lobes + j][..3].iter().enumerate() {
                            let yk = y as f64 / alpha;
                            want.diffuse[k] += yk * s.diffuse[k];
                            want.specular[k] += yk * s.specular[k];
                        }
                    }
                    for k in 0..3 {
                        assert!(close(c.diffuse[k], want.diffuse[k], 1e-9), "{c:?} {want:?}");
                        assert!(
                            close(c.specular[k], want.specular[k], 1e-9),
                            "{c:?} {want:?}"
                        );
                    }
                    // Colour changes the result: not the uncoloured shading's proportions.
                    let g = shade_in(&light, frame, &two, &t, view, brdf, route);
                    if (c.diffuse[0] / g.diffuse[0] - c.diffuse[2] / g.diffuse[2]).abs() > 0.1 {
                        differing += 1;
                    }
                }
            }
        }
        // Most texels mix red and blue lobes unevenly; the channels' ratios differ.
        assert!(differing >= 12, "{differing}");
    }

    #[test]
    fn coloured_ground_truth_is_the_albedo_weighted_sum_of_grey_ones() {
        // Two normals of a footprint, one red and one blue, under the orange-sun sky. The
        // coloured estimate must equal Σ_i w_i Σ_c LUMINANCE_c y_i,c ∫ L_c ρ(n_i), each
        // integral estimated independently: a grey light made of channel c alone, one normal,
        // its own sampler (by L_c, not the luminance) and seed. Agreement within four combined
        // standard errors, for the diffuse term and three specular BRDFs; and no albedo is
        // `ground_truth` bit for bit, a white one the same to f32 rounding.
        let sky = crate::environment::coloured_test_sky();
        let light = EnvLight::new(&sky);
        let (_, view, brdfs) = tilted_probe();
        let brdfs = [brdfs[1].clone(), brdfs[2].clone(), Brdf::ggx(0.1)];
        let normals = [
            (DVec3::new(0.3, 0.1, 0.95).normalize(), 0.7),
            (DVec3::new(-0.4, 0.2, 0.89).normalize(), 0.3),
        ];
        let albedo = [DVec3::new(0.9, 0.25, 0.05), DVec3::new(0.05, 0.3, 0.8)];
        let n = 40_000;
        let got = ground_truth_with(&light, &normals, Some(&albedo), view, &brdfs, n, 5);
        let plain = ground_truth(&light, &normals, view, &brdfs, n, 5);
        assert_eq!(
            ground_truth_with(&light, &normals, None, view, &brdfs, n, 5),
            plain
        );
        let white = ground_truth_with(&light, &normals, Some(&[DVec3::ONE; 2]), view, &brdfs, n, 5);
        assert!((white.diffuse - plain.diffuse).abs() <= 1e-6 * plain.diffuse);
        for b in 0..brdfs.len() {
            assert!((white.specular[b] - plain.specular[b]).abs() <= 1e-6 * plain.specular[b]);
        }
        // The independent sum: per channel, per normal.
        let mut want = Estimate {
            specular: vec![0.0; brdfs.len()],
            specular_se: vec![0.0; brdfs.len()],
            ..Default::default()
        };
        for c in 0..3 {
            let grey = EnvLight::grey(light.channel(c).radiance().clone());
            for (i, &(normal, w)) in normals.iter().enumerate() {
                let k = w * LUMINANCE[c] * albedo[i][c];
                let e = ground_truth(
                    &grey,
                    &[(normal, 1.0)],
                    view,
                    &brdfs,
                    n,
                    100 + 3 * c as u64 + i as u64,
                );
                want.diffuse += k * e.diffuse;
                want.diffuse_se += (k * e.diffuse_se).powi(2);
                for b in 0..brdfs.len() {
                    want.specular[b] += k * e.specular[b];
                    want.specular_se[b] += (k * e.specular_se[b]).powi(2);
                }
            }
        }
        let agree = |what: &str, a: f64, a_se: f64, b: f64, b_se2: f64| {
            let tol = 4.0 * (a_se * a_se + b_se2).sqrt();
            assert!((a - b).abs() <= tol, "{what}: {a} against {b} (± {tol})");
        };
        // And the albedo matters: the uncoloured estimate is far off (asserted per term).
        agree(
            "diffuse",
            got.diffuse,
            got.diffuse_se,
            want.diffuse,
            want.diffuse_se,
        );
        assert!((plain.diffuse - want.diffuse).abs() > 0.3 * want.diffuse);
        for (b, brdf) in brdfs.iter().enumerate() {
            let what = format!("{brdf:?}");
            agree(
                &what,
                got.specular[b],
                got.specular_se[b],
                want.specular[b],
                want.specular_se[b],
            );
            assert!(
                (plain.specular[b] - want.specular[b]).abs() > 0.3 * want.specular[b],
                "{what}"
            );
        }
    }

    #[test]
    fn colour_evaluation_scores_eq_22_against_the_coloured_ground_truth() {
        // A map whose colour follows its normals (red where they lean to +x, blue elsewhere):
        // at the coarse levels a texel mixes both, so the albedo MIP times the shading (what a
        // bake without colour textures gets) is wrong where the two colours see different
        // light, while eq 22's per-lobe colour keeps them apart. The colour bake must beat the
        // same bake without colour textures on the specular term, and an uncoloured evaluation
        // of it must differ (the ground truth changed). A map without albedo is refused.
        // A broad orange sun towards +x (15°, so the prefiltered route resolves it and the
        // route's own error does not hide the colour's): the red normals face it.
        let sky = Sky {
            width: 128,
            sun_deg: (45.0, 0.0),
            sun_radius_deg: 15.0,
            sun: [40.0, 20.0, 8.0],
            ..Sky::default()
        }
        .render()
        .unwrap();
        let light = EnvLight::new(&sky);
        let (red, blue) = ([0.9f32, 0.25, 0.05, 1.0], [0.05f32, 0.3, 0.8, 1.0]);
        let map = coloured_map(|n| if n.x > 0.0 { red } else { blue });
        let opts = crate::bake::BakeOptions {
            lobes: 4,
            ..Default::default()
        };
        let colour = crate::methods::bake_with(&map, Method::Vmf, &opts).unwrap();
        let mut grey_map = map.clone();
        grey_map = crate::NormalMap::from_vectors(
            grey_map.width(),
            grey_map.height(),
            grey_map.normals().to_vec(),
            Default::default(),
            Default::default(),
        )
        .unwrap();
        let uncoloured = crate::methods::bake_with(&grey_map, Method::Vmf, &opts).unwrap();
        assert_eq!(colour.textures.len(), 2 * colour.lobes);
        assert_eq!(uncoloured.textures.len(), uncoloured.lobes);
        let brdfs = [Brdf::BlinnPhong { s: 32.0 }];
        let options = EvalOptions {
            first_level: 2,
            texels_per_level: 8,
            samples: 1024,
            color: true,
            ..Default::default()
        };
        let routes = [Route::Prefiltered];
        let e = evaluate(
            &map,
            &[&colour, &uncoloured],
            &brdfs,
            &light,
            &routes,
            &options,
        )
        .unwrap();
        let (c, u) = (&e.errors[0], &e.errors[1]);
        assert_eq!(c.label, "vmf4 prefiltered");
        assert_eq!(u.label, "vmf4 prefiltered × albedo mip");
        // Measured: diffuse 3.6 % against 8.4 %, specular 19.6 % against 21.5 % (before the
        // route's cosine inside the lobe, docs/environment.md: 22.6 % against 27.2 %; both
        // fell, the albedo MIP's more, so the colour's margin on the specular term is now 9 %).
        assert!(
            c.diffuse < 0.6 * u.diffuse && c.specular < 0.95 * u.specular,
            "eq 22 colour {c:?} against albedo MIP {u:?}"
        );
        let grey = EvalOptions {
            color: false,
            ..options.clone()
        };
        let g = evaluate(&map, &[&colour], &brdfs, &light, &routes, &grey).unwrap();
        assert_ne!(g.errors[0].specular, c.specular);
        let refused = evaluate(&grey_map, &[&uncoloured], &brdfs, &light, &routes, &options);
        assert!(matches!(refused, Err(Error::InvalidOption(m)) if m.contains("albedo")));
    }

    /// `∫ f(ω_h·n) max(ω_i·n, 0) 4(ω_o·ω_h) dω_h` for a normal at `cos θ = c` from the view,
    /// by a midpoint rule over ω_h about n (θ_h = (π/2)u², 300 × 64): independent of the
    /// lobe table's quadrature.
    fn energy_direct(brdf: &Brdf, c: f64) -> f64 {
        let o = DVec3::new((1.0 - c * c).max(0.0).sqrt(), 0.0, c);
        let (nu, nphi) = (300, 64);
        let mut sum = 0.0;
        for i in 0..nu {
            let u = (i as f64 + 0.5) / nu as f64;
            let th = 0.5 * PI * u * u;
            let dth = PI * u / nu as f64;
            let (st, ct) = th.sin_cos();
            let f = brdf.lobe(ct);
            if f == 0.0 {
                continue;
            }
            for j in 0..nphi {
                let phi = 2.0 * PI * (j as f64 + 0.5) / nphi as f64;
                let h = DVec3::new(st * phi.cos(), st * phi.sin(), ct);
                let oh = o.dot(h);
                if oh <= 0.0 {
                    continue;
                }
                let l = 2.0 * oh * h - o;
                sum += f * l.z.max(0.0) * 4.0 * oh * st * dth * 2.0 * PI / nphi as f64;
            }
        }
        sum
    }

    /// `∫ vMF(n; μ = z, κ) g(n) dn` by a midpoint rule in the polar angle γ = γ_max u²
    /// (γ_max = min(π, 8/√κ); 256 × 128), the weights renormalized to sum to 1.
    fn vmf_average(kappa: f64, g: &dyn Fn(DVec3) -> f64) -> f64 {
        let gmax = (8.0 / kappa.sqrt()).min(PI);
        let (nu, nphi) = (256, 128);
        let (mut sum, mut wsum) = (0.0, 0.0);
        for i in 0..nu {
            let u = (i as f64 + 0.5) / nu as f64;
            let ga = gmax * u * u;
            let (sg, cg) = ga.sin_cos();
            let w = (kappa * (cg - 1.0)).exp() * sg * 2.0 * gmax * u;
            for j in 0..nphi {
                let phi = 2.0 * PI * (j as f64 + 0.5) / nphi as f64;
                let n = DVec3::new(sg * phi.cos(), sg * phi.sin(), cg);
                sum += w * g(n);
                wsum += w;
            }
        }
        sum / wsum
    }

    #[test]
    fn one_lobe_matches_its_exact_integral_under_a_constant_sky_and_a_sun() {
        // One vMF NDF lobe about z (κ = 8, 32, 128) seen at θ_o = 0, 35, 60°, Blinn-Phong
        // s = 32, 256 and GGX α = 0.1, 0.3: the prefiltered route (`prefiltered_lobe`) against
        // ∫ vMF(n) ∫ L ρ(n) cos dω_i dn by quadrature, (1) under a constant environment (the
        // lookup is exactly 1: this is the lobe's energy with the cosine inside the lobe) and
        // (2) under a one-texel sun (radiance 10⁴, 256-wide) in the reflected direction r of μ.
        // The route before the half-vector blocks (`share` 0) is measured beside it.
        let brdfs = [
            Brdf::BlinnPhong { s: 32.0 },
            Brdf::BlinnPhong { s: 256.0 },
            Brdf::ggx(0.1),
            Brdf::ggx(0.3),
        ];
        let constant = EnvLight::grey(Radiance::constant(64, 1.0));
        let (w, h) = (256u32, 128u32);
        let grid = Radiance::geometry(w, h);
        let degrees = [0.0f64, 35.0, 60.0];
        // Per view: the view, the sun's texel centre, its solid angle, the light.
        let suns: Vec<(DVec3, DVec3, f64, EnvLight)> = degrees
            .iter()
            .map(|deg| {
                let t = deg.to_radians();
                let view = DVec3::new(t.sin(), 0.0, t.cos());
                let r = 2.0 * view.z * DVec3::Z - view;
                let (sx, sy) = grid.texel_of(r);
                let mut v = vec![0.0f32; (w * h) as usize];
                v[(sy * w + sx) as usize] = 1e4;
                let light = EnvLight::grey(Radiance::new(w, h, v).unwrap());
                (view, grid.direction(sx, sy), grid.solid_angle(sy), light)
            })
            .collect();
        // Worst |error|: constant new, constant old; mean |error| under the sun, new and old.
        let (mut worst, mut old_at_8, mut sun) = ([0.0f64; 2], 0.0f64, [0.0f64; 2]);
        let (mut sun_worst, mut ggx_worst) = (0.0f64, 0.0f64);
        let mut cases = 0.0;
        for brdf in &brdfs {
            // E(c) tabulated over c ∈ [−1, 1] (129 points), linear between.
            let table: Vec<f64> = (0..129)
                .map(|i| energy_direct(brdf, -1.0 + 2.0 * i as f64 / 128.0))
                .collect();
            let energy = |c: f64| {
                let x = (c.clamp(-1.0, 1.0) + 1.0) * 64.0;
                let i = (x.floor() as usize).min(127);
                let f = x - i as f64;
                (1.0 - f) * table[i] + f * table[i + 1]
            };
            for kappa in [8.0, 32.0, 128.0] {
                for (deg, (view, d, omega, sun_light)) in degrees.iter().zip(&suns) {
                    let (view, d) = (*view, *d);
                    let route = |light: &EnvLight, share: Option<f64>| {
                        let i = DMat3::IDENTITY;
                        match share {
                            None => prefiltered_lobe(light, i, DVec3::Z, kappa, view, brdf)[0],
                            Some(w) => prefiltered_lobe_with_share(
                                light,
                                i,
                                DVec3::Z,
                                kappa,
                                view,
                                brdf,
                                w,
                            )[0],
                        }
                    };
                    // (1) Constant environment.
                    let exact = vmf_average(kappa, &|n| energy(view.dot(n)));
                    let en = route(&constant, None) / exact - 1.0;
                    let eo = route(&constant, Some(0.0)) / exact - 1.0;
                    // (2) The one-texel sun at r.
                    let hs = (d + view).normalize();
                    let exact_sun = 1e4
                        * omega
                        * vmf_average(kappa, &|n| brdf.lobe(hs.dot(n)) * d.dot(n).max(0.0));
                    let sn = route(sun_light, None) / exact_sun - 1.0;
                    let so = route(sun_light, Some(0.0)) / exact_sun - 1.0;
                    eprintln!(
                        "{brdf:?} κ {kappa} θ_o {deg}: constant {exact:.4} new {en:+.3} old {eo:+.3}; sun {exact_sun:.4} new {sn:+.3} old {so:+.3}"
                    );
                    worst = [worst[0].max(en.abs()), worst[1].max(eo.abs())];
                    if matches!(brdf, Brdf::Ggx(_)) {
                        ggx_worst = ggx_worst.max(en.abs());
                    }
                    if kappa == 8.0 && *deg == 0.0 {
                        old_at_8 = old_at_8.max(-eo);
                    }
                    sun[0] += sn.abs();
                    sun[1] += so.abs();
                    sun_worst = sun_worst.max(sn.abs());
                    cases += 1.0;
                }
            }
        }
        let sun = [sun[0] / cases, sun[1] / cases];
        eprintln!("constant worst new {worst:?}; sun mean |error| new / old {sun:?}");
        // Measured: constant environment within 7.8 % (Blinn-Phong κ = 8 at the normal;
        // ≤ 1.4 % from κ = 32 on; GGX ≤ 1.5 % since its table's energy is the NDF lobe's
        // exact one at every share (stop 45; 3.9 % with the half-vector cosine, 7.6 % with the
        // widened GGX lobe alone)), the route before within 30 % (−20 … −30 % at κ = 8 seen
        // head on: the cosine taken at the lobe's centre).
        assert!(
            worst[0] < 0.09,
            "new route, constant environment: {}",
            worst[0]
        );
        assert!(ggx_worst < 0.02, "GGX, constant environment: {ggx_worst}");
        assert!(
            old_at_8 > 0.15 && worst[1] > 0.25,
            "the old route is biased: {worst:?}"
        );
        // Under the sun the lookup's shape dominates (the reflected lobe's squeeze at 60°:
        // −15 … −29 %, a wide lobe's peak at the normal: +30 … +39 % at κ = 8), which this
        // change does not address: measured mean |error| 17.3 % against 17.7 % before, worst
        // 48 % (GGX 0.3, κ = 8, 60°; 43 % before). Asserted: bounded and no worse on average.
        assert!(sun_worst < 0.55, "sun: {sun_worst}");
        assert!(sun[0] <= sun[1] + 0.005, "sun: {sun:?}");
    }

    #[test]
    fn extracted_sun_brings_one_lobe_close_to_its_exact_integral() {
        // One vMF NDF lobe about z (κ = 8, 32, 128) seen at θ_o = 0, 35, 60°, Blinn-Phong
        // s = 32, 256 and GGX α = 0.1, 0.3, under a constant sky of 1 with a one-texel sun of
        // 10⁴ (256-wide) in the reflected direction: the full shading of a vMF texel
        // (prefiltered route) against ∫ vMF(n) ∫ L ρ(n) cos dω_i dn by quadrature, with the
        // sun extracted (EnvLight::with_lights: the residual is the constant sky, the sun is
        // shaded per lobe as a point light) and without (the pure route).
        use crate::environment::lights::LightOptions;
        let brdfs = [
            Brdf::BlinnPhong { s: 32.0 },
            Brdf::BlinnPhong { s: 256.0 },
            Brdf::ggx(0.1),
            Brdf::ggx(0.3),
        ];
        let bake = flat_bake(Method::Vmf);
        let (w, h) = (256u32, 128u32);
        let grid = Radiance::geometry(w, h);
        let degrees = [0.0f64, 35.0, 60.0];
        let mut sums = [0.0f64; 2];
        let mut worst = 0.0f64;
        let mut cases = 0.0;
        for deg in degrees {
            let t = deg.to_radians();
            let view = DVec3::new(t.sin(), 0.0, t.cos());
            let r = 2.0 * view.z * DVec3::Z - view;
            let (sx, sy) = grid.texel_of(r);
            let mut v = vec![[1.0f32; 3]; (w * h) as usize];
            v[(sy * w + sx) as usize] = [1e4; 3];
            let env = Environment::from_rgb("t", w, h, v, &Default::default()).unwrap();
            // (At the zenith the texel holds 0.6 % of the power, below the default share.)
            let options = LightOptions {
                min_share: 0.0,
                ..LightOptions::default()
            };
            let with = EnvLight::prefiltered_only_with_lights(&env, &options);
            let pure = EnvLight::prefiltered_only(&env);
            assert_eq!(with.lights().len(), 1);
            assert!(pure.lights().is_empty());
            let (d, omega) = (grid.direction(sx, sy), grid.solid_angle(sy));
            let hs = (d + view).normalize();
            for brdf in &brdfs {
                let table: Vec<f64> = (0..129)
                    .map(|i| energy_direct(brdf, -1.0 + 2.0 * i as f64 / 128.0))
                    .collect();
                let energy = |c: f64| {
                    let x = (c.clamp(-1.0, 1.0) + 1.0) * 64.0;
                    let i = (x.floor() as usize).min(127);
                    let f = x - i as f64;
                    (1.0 - f) * table[i] + f * table[i + 1]
                };
                for kappa in [8.0f64, 32.0, 128.0] {
                    let a = crate::vmf::a_kappa(kappa) as f32;
                    let mut texels = vec![[0.0f32; 4]; bake.textures.len()];
                    texels[0] = [1.0, 0.0, 0.0, a];
                    let exact = vmf_average(kappa, &|n| energy(view.dot(n)))
                        + (1e4 - 1.0)
                            * omega
                            * vmf_average(kappa, &|n| brdf.lobe(hs.dot(n)) * d.dot(n).max(0.0));
                    let got = |l: &EnvLight| {
                        shade(l, &bake, &texels, view, brdf, Route::Prefiltered).specular[0] / exact
                            - 1.0
                    };
                    let (e_with, e_pure) = (got(&with), got(&pure));
                    eprintln!(
                        "{brdf:?} κ {kappa} θ_o {deg}: exact {exact:.4} extracted {e_with:+.3} pure {e_pure:+.3}"
                    );
                    sums[0] += e_with.abs();
                    sums[1] += e_pure.abs();
                    worst = worst.max(e_with.abs());
                    cases += 1.0;
                }
            }
        }
        let mean = [sums[0] / cases, sums[1] / cases];
        eprintln!("mean |error| extracted / pure {mean:?}, worst extracted {worst}");
        // Measured: mean |error| 4.2 % extracted against 10.0 % pure; worst extracted +14.9 %
        // (Blinn-Phong s = 32, κ = 8, 60°: eq 20's known overshoot of the exact convolution at
        // small κ, the point-light path's own error), worst pure −28.5 % (GGX 0.3, κ = 8, 60°,
        // the isotropic lookup of the squeezed reflected lobe).
        assert!(mean[0] < 0.5 * mean[1], "{mean:?}");
        assert!(mean[0] < 0.05 && worst < 0.17, "{mean:?} {worst}");
    }

    #[test]
    fn a_wide_patch_is_a_diffuse_only_light_exact_for_the_diffuse_and_leaves_the_specular() {
        // A constant sky of 1 with a bright 10 × 10 patch (about 0.2 sr, too wide for a light,
        // within the diffuse-only bound) 28–56° from the zenith. A flat texel's diffuse is
        // then Σ L cos Ω over the texels (no texel below its horizon): the extracted route
        // (constant residual, exact in SH, plus the patch as a spread light) must match it;
        // the specular routes keep the patch in their residual, so the specular is the pure
        // route's bit for bit.
        use crate::environment::lights::LightOptions;
        let (w, h) = (128u32, 64u32);
        let grid = Radiance::geometry(w, h);
        let mut v = vec![[1.0f32; 3]; (w * h) as usize];
        for y in 10..20 {
            for x in 40..50 {
                v[(y * w + x) as usize] = [2000.0; 3];
            }
        }
        let exact: f64 = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                v[i as usize][0] as f64 * grid.solid_angle(y) * grid.direction(x, y).z.max(0.0)
            })
            .sum();
        let env = Environment::from_rgb("t", w, h, v, &Default::default()).unwrap();
        let with = EnvLight::prefiltered_only_with_lights(&env, &LightOptions::default());
        let pure = EnvLight::prefiltered_only(&env);
        assert_eq!(with.lights().len(), 1);
        assert!(with.lights()[0].diffuse_only, "{:?}", with.lights());
        let bake = flat_bake(Method::Plain);
        let texels = [[0.0f32, 0.0, 1.0, 0.0]];
        let brdf = Brdf::BlinnPhong { s: 32.0 };
        let view = DVec3::new(0.5f64.sin(), 0.0, 0.5f64.cos());
        let a = shade(&with, &bake, &texels, view, &brdf, Route::Prefiltered);
        let b = shade(&pure, &bake, &texels, view, &brdf, Route::Prefiltered);
        assert_eq!(a.specular, b.specular);
        let (ea, eb) = (a.diffuse[0] / exact - 1.0, b.diffuse[0] / exact - 1.0);
        eprintln!("diffuse: extracted {ea:+.5}, pure {eb:+.5} (exact {exact:.4})");
        // Measured: extracted −0.003 %, pure −2.7 % (the patch's bands ≥ 3).
        assert!(ea.abs() < 2e-3 && ea.abs() < 0.5 * eb.abs(), "{ea} {eb}");
    }
}
