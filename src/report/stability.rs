//! The stiff and extreme cases (DESIGN.md "Numerics"): every method and storage format on
//! degenerate inputs, with extreme BRDF parameters, checked texel by texel for NaN, infinity,
//! negative radiance and energy above the unfiltered reference; and the naive formulas that do
//! break on them next to the guards that fix them ([`demos`]). `tests/stability.rs` asserts on
//! [`sweep`]; `ndfmap report` prints its [`markdown`].
//!
//! **Bounds.** *Peak*: no filtered texel may reflect more than the brightest unfiltered normal
//! can — Lambert ≤ 1 and the specular lobe ≤ its unfiltered peak, `(s+1)/(2π)` (Blinn-Phong) or
//! `1/(4πσ²)` (eq 18), each times [`PEAK_BOUND`] (room for α rounded up by unorm8). *Energy*:
//! at the coarsest level (one texel covering the whole map), the reflected radiance integrated
//! over 1024 light directions (Fibonacci hemisphere; views at 0° and 60°) must stay within
//! [`ENERGY_BOUND`] of the exact average of the unfiltered shading, for lobes wide enough for
//! that quadrature (s ≤ 10, σ ≥ 0.3). Plain MIP-mapping is reported but exempt from the energy
//! bound: renormalizing a short mean normal is its known failure, not a numerical one.

use crate::bake::{Bake, BakeOptions, Method};
use crate::brdf::{Brdf, half_vector, reference_brdf};
use crate::eval::default_directions;
use crate::format::Format;
use crate::ingest::{Addressing, BadNormals, NormalMap};
use crate::methods::bake_with;
use crate::shade::shade_brdf;
use glam::{DVec3, Vec3};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Peak bound: filtered Lambert ≤ 1 × this, specular ≤ the BRDF's peak × this.
pub const PEAK_BOUND: f64 = 1.02;

/// Energy bound at the coarsest level: integrated radiance ≤ exact × (1 + this).
pub const ENERGY_BOUND: f64 = 0.15;

/// Configurations exempt from the energy bound: their diffuse term shades the *mean direction*
/// (plain: the normalized mean normal; LEAN: `normalize(E[b], 1)`; Tan 2005: the lifted planar
/// means), so on steep symmetric inputs (±60°, normals on the horizon) they light a whole
/// hemisphere that the real normals only half face. That is the known breakdown of mean-normal
/// filtering — a modelling error the NDF methods remove — not a numerical failure; the table
/// still shows their energy. SH at l* = 0 keeps only the NDF's integral: its Lambert term is
/// the constant 1/4 whatever the normals, the band limit's modelling error.
pub const ENERGY_EXEMPT: [&str; 4] = ["plain", "lean", "tan2005", "sh0"];

/// Texels checked per level at most (evenly strided), to keep the large maps quick.
const TEXELS_PER_LEVEL: usize = 512;

/// The BRDFs of [`brdfs`] from this index on (GGX, Lambert, tabulated) and SH bakes are checked
/// on every fourth of those texels: the suite stays quick on 2 cores.
const SPARSE_FROM: usize = 10;

/// A degenerate input.
pub struct Case {
    /// Name.
    pub name: String,
    /// The map.
    pub map: NormalMap,
}

fn map(w: u32, h: u32, f: impl Fn(u32, u32) -> Vec3) -> NormalMap {
    let v = (0..w as u64 * h as u64)
        .map(|i| f((i % w as u64) as u32, (i / w as u64) as u32))
        .collect();
    NormalMap::from_vectors(w, h, v, Addressing::Wrap, BadNormals::Repair).expect("valid test map")
}

/// A bumpy but ordinary normal for texel (x, y): the shape content of the odd-sized maps.
fn bumpy(x: u32, y: u32) -> Vec3 {
    let (fx, fy) = (x as f32, y as f32);
    Vec3::new(
        (fx * 0.9).sin() * 0.6,
        (fy * 1.3 + fx * 0.2).cos() * 0.5,
        1.0,
    )
}

/// The cases: stiff inputs, then odd and extreme sizes (the last two only with `large`).
pub fn cases(large: bool) -> Vec<Case> {
    let s60 = 60f32.to_radians().sin();
    let c60 = 60f32.to_radians().cos();
    let mut out = vec![
        Case {
            name: "identical normals (κ → ∞)".into(),
            map: map(8, 8, |_, _| Vec3::new(0.3, -0.2, 0.93)),
        },
        Case {
            name: "antipodal pairs (|r| → 0)".into(),
            map: map(8, 8, |x, y| {
                if (x + y) % 2 == 0 {
                    Vec3::new(0.6, 0.8, 0.0)
                } else {
                    Vec3::new(-0.6, -0.8, 0.0)
                }
            }),
        },
        Case {
            name: "all on the horizon".into(),
            map: map(8, 8, |x, y| {
                let a = (x * 8 + y) as f32 * 0.7;
                Vec3::new(a.cos(), a.sin(), 0.0)
            }),
        },
        Case {
            name: "one noisy texel in a flat map".into(),
            map: map(16, 16, |x, y| {
                if (x, y) == (5, 9) {
                    Vec3::new(0.7, -0.1, 0.7)
                } else {
                    Vec3::Z
                }
            }),
        },
        Case {
            name: "checkerboard ±60°".into(),
            map: map(8, 8, |x, y| {
                if (x + y) % 2 == 0 {
                    Vec3::new(s60, 0.0, c60)
                } else {
                    Vec3::new(-s60, 0.0, c60)
                }
            }),
        },
        Case {
            name: "1×1".into(),
            map: map(1, 1, |_, _| Vec3::new(0.2, 0.1, 0.97)),
        },
        Case {
            name: "1×9".into(),
            map: map(1, 9, bumpy),
        },
        Case {
            name: "3×5".into(),
            map: map(3, 5, bumpy),
        },
    ];
    if large {
        out.push(Case {
            name: "4097×3".into(),
            map: map(4097, 3, bumpy),
        });
        out.push(Case {
            name: "16384×16".into(),
            map: map(16384, 16, bumpy),
        });
    }
    out
}

/// The configurations swept: the baselines, Tan 2005 and vMF unaligned and aligned, with 2
/// lobes (1 on maps above 10⁴ texels, to keep the suite quick), and SH at the extreme band
/// limits l* = 0 and 16 (16 → 2 above 10⁴ texels: 73 textures of f32 per texel otherwise).
pub fn configs(texels: u64) -> Vec<(String, Method, BakeOptions)> {
    let j = if texels > 10_000 { 1 } else { 2 };
    let top = if texels > 10_000 { 2 } else { 16 };
    let mut out: Vec<(String, Method, BakeOptions)> = Method::BASELINES
        .iter()
        .map(|&m| (m.name().to_string(), m, BakeOptions::default()))
        .collect();
    let o = |align| BakeOptions {
        lobes: j,
        align,
        ..BakeOptions::default()
    };
    out.push((format!("tan2005-{j}"), Method::Tan2005, o(None)));
    out.push((format!("vmf{j}"), Method::Vmf, o(None)));
    out.push((format!("vmf{j}a"), Method::Vmf, o(Some(0.1))));
    for lmax in [0, top] {
        let o = BakeOptions {
            lmax,
            ..BakeOptions::default()
        };
        out.push((format!("sh{lmax}"), Method::Sh, o));
    }
    out
}

/// The BRDFs swept: Blinn-Phong s from 1 to 10⁶ (10⁵ among them, the SH extreme),
/// Torrance–Sparrow σ from 10⁻⁴ to 1, GGX α = 10⁻³ and 1, Lambert, and two tabulated BRDFs
/// with a zero column: GGX α = 0.2 whose g is 0 everywhere, and a lobe that is 0 from 5° to
/// 20° and again past 30°.
pub fn brdfs() -> Vec<Brdf> {
    let mut b = Brdf::blinn_phong(&[1.0, 10.0, 100.0, 1e4, 1e6]);
    b.extend(
        [1e-4, 1e-2, 0.3, 1.0]
            .into_iter()
            .map(|sigma| Brdf::TorranceSparrow { sigma }),
    );
    b.push(Brdf::BlinnPhong { s: 1e5 });
    b.push(Brdf::ggx(1e-3));
    b.push(Brdf::ggx(1.0));
    b.push(Brdf::Lambert);
    b.extend(zero_column_brdfs());
    b
}

/// The tabulated BRDFs with a zero column of [`brdfs`].
fn zero_column_brdfs() -> Vec<Brdf> {
    use crate::brdf::Tabulated;
    let ggx = |t: f64| crate::brdf::ggx(t.cos(), 0.2);
    let zero_g = |_: f64| 0.0;
    let gappy = |t: f64| {
        let d = t.to_degrees();
        if (5.0..20.0).contains(&d) || d > 30.0 {
            0.0
        } else {
            10.0 * (1.0 - d / 30.0)
        }
    };
    [
        Tabulated::sample("ggx0.2, g = 0", 90, &ggx, Some(&zero_g)),
        Tabulated::sample("zero band", 90, &gappy, None),
    ]
    .into_iter()
    .map(|t| Brdf::Tabulated(std::sync::Arc::new(t.expect("valid table"))))
    .collect()
}

/// A configuration's label without its lobe count: `vmf2a` → `vmf aligned`, `tan2005-1` →
/// `tan2005`.
pub fn family(label: &str) -> String {
    if label.starts_with("tan2005") {
        return "tan2005".into();
    }
    if label.starts_with("sh") {
        return label.into();
    }
    if let Some(rest) = label.strip_prefix("vmf") {
        return if rest.ends_with('a') {
            "vmf aligned".into()
        } else {
            "vmf".into()
        };
    }
    label.into()
}

/// The unfiltered peak of the specular lobe, times the largest g factor (a tabulated
/// BRDF's g; GGX is swept without its g factor, whose Smith term is unbounded at grazing
/// angles for small α).
pub fn peak(brdf: &Brdf) -> f64 {
    match brdf {
        Brdf::BlinnPhong { s } => (s + 1.0) / (2.0 * PI),
        Brdf::TorranceSparrow { sigma } => 1.0 / (4.0 * PI * sigma * sigma),
        Brdf::Tabulated(t) => t.peak() * t.g_peak(),
        b => b.peak(),
    }
}

/// Light/view pairs: every third of `eval`'s, and extreme ones (light on the horizon, opposite
/// light and view, light below the horizon).
pub fn directions() -> Vec<(DVec3, DVec3)> {
    let mut d: Vec<(DVec3, DVec3)> = default_directions().into_iter().step_by(3).collect();
    d.push((DVec3::X, DVec3::Z));
    d.push((DVec3::X, -DVec3::X));
    d.push((DVec3::new(0.0, 0.6, -0.8), DVec3::new(0.0, -0.6, 0.8)));
    d.push((
        DVec3::new(1.0, 0.0, 1e-12).normalize(),
        DVec3::new(-1.0, 0.0, 1e-12).normalize(),
    ));
    d
}

/// `n` light directions spread evenly over the upper hemisphere (Fibonacci lattice).
pub fn hemisphere(n: usize) -> Vec<DVec3> {
    let golden = PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let phi = golden * i as f64;
            DVec3::new(r * phi.cos(), r * phi.sin(), z)
        })
        .collect()
}

/// One case × configuration × format.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Outcome {
    /// The case.
    pub case: String,
    /// The configuration.
    pub config: String,
    /// The configuration without its lobe count (`vmf aligned`), a table column.
    pub family: String,
    /// The storage format.
    pub format: Format,
    /// Why it was not run (a format that cannot hold the method's values), if so.
    pub skipped: Option<String>,
    /// The bake's error, if it failed (a failure: valid options must bake).
    pub bake_error: Option<String>,
    /// Shading evaluations checked.
    pub checked: u64,
    /// NaN or infinite results.
    pub nonfinite: u64,
    /// Negative results.
    pub negative: u64,
    /// Results above the peak bound.
    pub over_peak: u64,
    /// Largest result over its peak (Lambert over 1, specular over the BRDF's peak).
    pub max_peak_ratio: f64,
    /// Largest integrated energy over the exact one at the coarsest level (wide lobes), when
    /// measured (maps of at most [`ENERGY_MAX_TEXELS`] texels).
    pub max_energy_ratio: Option<f64>,
}

impl Outcome {
    /// An outcome with nothing checked yet.
    fn empty(case: &str, config: &str, format: Format) -> Self {
        Outcome {
            case: case.into(),
            config: config.into(),
            family: family(config),
            format,
            skipped: None,
            bake_error: None,
            checked: 0,
            nonfinite: 0,
            negative: 0,
            over_peak: 0,
            max_peak_ratio: 0.0,
            max_energy_ratio: None,
        }
    }

    /// Whether every check passed (plain is exempt from the energy bound).
    pub fn ok(&self) -> bool {
        self.bake_error.is_none()
            && (self.skipped.is_some()
                || (self.nonfinite == 0
                    && self.negative == 0
                    && self.over_peak == 0
                    && (ENERGY_EXEMPT.contains(&self.family.as_str())
                        || self
                            .max_energy_ratio
                            .is_none_or(|e| e <= 1.0 + ENERGY_BOUND))))
    }
}

/// A naive formula that breaks on a stiff case, next to the library's guarded one.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Demo {
    /// What is computed.
    pub name: String,
    /// The naive result, in words.
    pub naive: String,
    /// The guarded result, in words.
    pub guarded: String,
    /// Whether the naive version indeed fails.
    pub naive_fails: bool,
    /// Whether the guard holds.
    pub guard_holds: bool,
}

/// The sweep's results.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// Case names, in order.
    pub cases: Vec<String>,
    /// Every outcome.
    pub outcomes: Vec<Outcome>,
    /// The naive-versus-guarded demonstrations.
    pub demos: Vec<Demo>,
    /// Seconds the sweep took.
    pub seconds: f64,
}

/// The views and BRDFs of the energy check (lobes wide enough for the quadrature).
fn energy_settings() -> Vec<(DVec3, Brdf)> {
    let mut out = Vec::new();
    for view in [DVec3::Z, DVec3::new(60f64.to_radians().sin(), 0.0, 0.5)] {
        for brdf in [
            Brdf::BlinnPhong { s: 1.0 },
            Brdf::BlinnPhong { s: 10.0 },
            Brdf::TorranceSparrow { sigma: 0.3 },
            Brdf::TorranceSparrow { sigma: 1.0 },
            Brdf::ggx(1.0),
        ] {
            out.push((view, brdf));
        }
    }
    out
}

/// Texels above which the energy check is skipped (its exact side costs texels × 1024 × 8).
pub const ENERGY_MAX_TEXELS: usize = 4096;

/// The exact side of the energy check: the light directions and, per setting of
/// [`energy_settings`], the unfiltered shading averaged over the map and summed over lights.
struct Exact {
    lights: Vec<DVec3>,
    energy: Vec<f64>,
}

fn exact_energy(map: &NormalMap) -> Option<Exact> {
    if map.normals().len() > ENERGY_MAX_TEXELS {
        return None;
    }
    let lights = hemisphere(1024);
    let energy = energy_settings()
        .into_iter()
        .map(|(view, brdf)| {
            let mut eg = 0.0;
            for &l in &lights {
                let hv = half_vector(l, view);
                let mut g = 0.0;
                for n in map.normals() {
                    let r = reference_brdf(n.as_dvec3(), l, hv, &brdf);
                    g += r.diffuse + r.specular;
                }
                eg += g / map.normals().len() as f64;
            }
            eg
        })
        .collect();
    Some(Exact { lights, energy })
}

/// Checks one bake against the bounds.
fn check(case: &str, config: &str, exact: Option<&Exact>, bake: &Bake) -> Outcome {
    let mut o = Outcome::empty(case, config, bake.format);
    let brdfs = brdfs();
    let dirs: Vec<(DVec3, DVec3, DVec3)> = directions()
        .into_iter()
        .map(|(l, v)| (l, v, half_vector(l, v)))
        .collect();
    let mut texel = vec![[0.0f32; 4]; bake.textures.len()];
    for level in 0..bake.level_count() {
        let (w, h) = bake.sizes[level];
        let n = w as usize * h as usize;
        let stride = n.div_ceil(TEXELS_PER_LEVEL).max(1);
        let sh = bake.method == Method::Sh;
        for (k, i) in (0..n).step_by(stride).enumerate() {
            bake.texel_into(level, i, &mut texel);
            for (b, brdf) in brdfs.iter().enumerate() {
                if (sh || b >= SPARSE_FROM) && k % 4 != 0 {
                    continue;
                }
                let p = peak(brdf);
                for &(l, _, hv) in &dirs {
                    let s = shade_brdf(bake, &texel, l, hv, brdf);
                    o.checked += 1;
                    for (v, top) in [(s.diffuse, 1.0), (s.specular, p)] {
                        if !v.is_finite() {
                            o.nonfinite += 1;
                        } else if v < 0.0 {
                            o.negative += 1;
                        } else {
                            let r = if top > 0.0 {
                                v / top
                            } else if v > 0.0 {
                                f64::INFINITY
                            } else {
                                0.0
                            };
                            o.max_peak_ratio = o.max_peak_ratio.max(r);
                            if r > PEAK_BOUND {
                                o.over_peak += 1;
                            }
                        }
                    }
                }
            }
        }
    }
    // Energy at the coarsest level: one texel covering the whole map uniformly.
    if let Some(exact) = exact {
        let last = bake.level_count() - 1;
        bake.texel_into(last, 0, &mut texel);
        for (k, (view, brdf)) in energy_settings().into_iter().enumerate() {
            let mut ef = 0.0;
            for &l in &exact.lights {
                let f = shade_brdf(bake, &texel, l, half_vector(l, view), &brdf);
                ef += f.diffuse + f.specular;
            }
            if exact.energy[k] > 0.0 {
                let r = ef / exact.energy[k];
                o.max_energy_ratio = Some(o.max_energy_ratio.map_or(r, |m| m.max(r)));
            }
        }
    }
    o
}

/// Runs every case × configuration × format (`large` adds the 4097×3 and 16384×16 maps).
pub fn sweep(large: bool) -> Summary {
    use rayon::prelude::*;
    let start = std::time::Instant::now();
    let cases = cases(large);
    // Cases in parallel, each in order; collected in case order (the same for any thread count).
    let per_case: Vec<Vec<Outcome>> = cases
        .par_iter()
        .map(|case| {
            let mut outcomes = Vec::new();
            let texels = case.map.width() as u64 * case.map.height() as u64;
            let exact = exact_energy(&case.map);
            for (label, method, options) in configs(texels) {
                let baked = match bake_with(&case.map, method, &options) {
                    Ok(b) => b,
                    Err(e) => {
                        let mut o = Outcome::empty(&case.name, &label, Format::F32);
                        o.bake_error = Some(e.to_string());
                        outcomes.push(o);
                        continue;
                    }
                };
                for format in Format::ALL {
                    match crate::pack::quantize(&baked, format) {
                        Ok(q) => outcomes.push(check(&case.name, &label, exact.as_ref(), &q)),
                        Err(e) => {
                            let mut o = Outcome::empty(&case.name, &label, format);
                            o.skipped = Some(e.to_string());
                            outcomes.push(o);
                        }
                    }
                }
            }
            outcomes
        })
        .collect();
    let outcomes: Vec<Outcome> = per_case.into_iter().flatten().collect();
    Summary {
        cases: cases.iter().map(|c| c.name.clone()).collect(),
        outcomes,
        demos: demos(),
        seconds: start.elapsed().as_secs_f64(),
    }
}

/// Algorithm 2 line 8 as written, `r = θ.yzw/α`, then κ and μ: NaN for an empty lobe.
pub fn naive_vmf_kappa(theta: [f32; 4]) -> f32 {
    let alpha = theta[0];
    let r = Vec3::new(theta[1], theta[2], theta[3]) / alpha;
    let len = r.length();
    (3.0 * len - len * len * len) / (1.0 - len * len)
}

/// The naive formulas against the guards (module docs).
pub fn demos() -> Vec<Demo> {
    use half::f16;
    let mut out = Vec::new();
    // 1. Algorithm 2 with α = 0 (an empty lobe, or one quantized to 0).
    let empty = [0.0f32; 4];
    let naive = naive_vmf_kappa(empty);
    let guarded = crate::shade::vmf_lobe(empty, DVec3::Z, DVec3::Z, 64.0, crate::vmf::R_MAX);
    out.push(Demo {
        name: "Algorithm 2 with α = 0: r = θ.yzw/α".into(),
        naive: format!("κ = {naive}"),
        guarded: format!(
            "empty lobe contributes (diffuse {}, specular {})",
            guarded.diffuse, guarded.specular
        ),
        naive_fails: !naive.is_finite(),
        guard_holds: guarded.diffuse == 0.0 && guarded.specular == 0.0,
    });
    // 2. κ from |r| read from f16: |r| = 1 − 10⁻⁴ rounds to 1.
    let r16 = f16::from_f64(1.0 - 1e-4).to_f64();
    let naive = crate::vmf::kappa_banerjee(r16);
    let rc = r16.min(crate::vmf::r_max(Format::F16));
    let guarded = crate::vmf::kappa_banerjee(rc);
    out.push(Demo {
        name: "κ = (3r − r³)/(1 − r²) with |r| = 1 − 10⁻⁴ stored in f16".into(),
        naive: format!("r rounds to {r16}, κ = {naive}"),
        guarded: format!("r clamped to r_max(f16) = 1 − 2⁻¹¹, κ = {guarded:.1}"),
        naive_fails: !naive.is_finite(),
        guard_holds: guarded.is_finite() && guarded > 2000.0,
    });
    // 3. Toksvig from a 2-channel (BC5-style) mean: z reconstructed from the filtered x, y.
    //    A ±60° checkerboard averages to (0, 0, 0.5); the 2-channel texture keeps (0, 0) and
    //    the shader's z = sqrt(1 − x² − y²) = 1 makes |n̄| = 1: no widening at all.
    let s = 64.0;
    let (mean_xy, true_len) = (glam::DVec2::ZERO, 0.5f64);
    let z = (1.0 - mean_xy.length_squared()).sqrt();
    let naive_len = DVec3::new(mean_xy.x, mean_xy.y, z).length();
    let s_naive = naive_len * s / (naive_len + s * (1.0 - naive_len));
    let s_guard = true_len * s / (true_len + s * (1.0 - true_len));
    out.push(Demo {
        name: "Toksvig from a 2-channel mean (z reconstructed), ±60° checkerboard, s = 64".into(),
        naive: format!("|n̄| = {naive_len}, s' = {s_naive} (highlight not widened)"),
        guarded: format!("3-channel mean kept: |n̄| = {true_len}, s' = {s_guard:.3}"),
        naive_fails: s_naive >= s,
        guard_holds: s_guard < 2.0,
    });
    // 4. z reconstruction of a quantized 2-channel texel with x² + y² > 1 (unorm8 rounding).
    let (x, y) = (1.0f32, 140.0f32 / 255.0 * 2.0 - 1.0); // the codes 255 and 140 decoded
    let naive_z = (1.0 - x * x - y * y).sqrt();
    let guarded_map = NormalMap::from_samples(
        "demo",
        1,
        1,
        2,
        crate::ingest::Samples::U8(&[255, 140]),
        &crate::IngestOptions {
            channels: crate::ingest::Channels::Xy,
            ..Default::default()
        },
    );
    let guarded_n = guarded_map.as_ref().map(|m| m.normal(0, 0));
    out.push(Demo {
        name: "z = sqrt(1 − x² − y²) of an unorm8 2-channel texel (255, 140)".into(),
        naive: format!("z = {naive_z}"),
        guarded: match &guarded_n {
            Ok(n) => format!(
                "ingest clamps and renormalizes: n = ({:.4}, {:.4}, {:.4})",
                n.x, n.y, n.z
            ),
            Err(e) => format!("ingest error: {e}"),
        },
        naive_fails: !naive_z.is_finite(),
        guard_holds: guarded_n.is_ok_and(|n| n.is_finite() && (n.length() - 1.0).abs() < 1e-5),
    });
    out
}

/// The sweep as Markdown: a cases × configurations table (✓, or what failed), the largest peak
/// and energy ratios, and the demonstrations.
pub fn markdown(s: &Summary) -> String {
    use std::fmt::Write;
    let mut m = String::from("## Stability (stiff and extreme cases)\n\n");
    let total: u64 = s.outcomes.iter().map(|o| o.checked).sum();
    let bad: Vec<&Outcome> = s.outcomes.iter().filter(|o| !o.ok()).collect();
    let _ = writeln!(
        m,
        "{} cases × {} configurations × 4 formats, {} BRDFs (Blinn-Phong s = 1 … 10⁶, \
         Torrance–Sparrow σ = 10⁻⁴ … 1, GGX α = 10⁻³ and 1, Lambert, two tabulated BRDFs with \
         a zero column), {} light/view pairs per texel (up to {} texels per \
         level): {} shading evaluations in {:.1} s; {} outcome(s) out of bounds. Bounds: \
         Lambert ≤ {PEAK_BOUND}, specular ≤ {PEAK_BOUND} × the unfiltered peak; energy at the \
         coarsest level ≤ {} × exact on maps of at most {ENERGY_MAX_TEXELS} texels (plain, \
         LEAN and Tan 2005 exempt: their diffuse term shades the mean direction, which \
         over-lights steep symmetric inputs — the modelling error NDF filtering removes, marked \
         *(model)*).\n",
        s.cases.len(),
        configs(0).len(),
        brdfs().len(),
        directions().len(),
        TEXELS_PER_LEVEL,
        total,
        s.seconds,
        bad.len(),
        1.0 + ENERGY_BOUND
    );
    let mut configs_seen: Vec<String> = Vec::new();
    for o in &s.outcomes {
        if !configs_seen.contains(&o.family) {
            configs_seen.push(o.family.clone());
        }
    }
    let _ = write!(m, "| case |");
    for c in &configs_seen {
        let _ = write!(m, " {c} |");
    }
    let _ = writeln!(m);
    let _ = write!(m, "|---|");
    for _ in &configs_seen {
        let _ = write!(m, "---|");
    }
    let _ = writeln!(m);
    for case in &s.cases {
        let _ = write!(m, "| {case} |");
        for c in &configs_seen {
            let cell: Vec<&Outcome> = s
                .outcomes
                .iter()
                .filter(|o| &o.case == case && &o.family == c)
                .collect();
            let failed: Vec<String> = cell
                .iter()
                .filter(|o| !o.ok())
                .map(|o| {
                    format!(
                        "✗ {}: {} NaN/inf, {} neg, {} > peak, energy {}{}",
                        o.format,
                        o.nonfinite,
                        o.negative,
                        o.over_peak,
                        o.max_energy_ratio.map_or("–".into(), |e| format!("{e:.2}")),
                        o.bake_error
                            .as_ref()
                            .map_or(String::new(), |e| format!(", bake failed: {e}"))
                    )
                })
                .collect();
            let skipped = cell.iter().filter(|o| o.skipped.is_some()).count();
            let energy = cell
                .iter()
                .filter_map(|o| o.max_energy_ratio)
                .fold(None, |a: Option<f64>, e| Some(a.map_or(e, |a| a.max(e))));
            let exempt = ENERGY_EXEMPT.contains(&c.as_str())
                && energy.is_some_and(|e| e > 1.0 + ENERGY_BOUND);
            if failed.is_empty() {
                let _ = write!(
                    m,
                    " ✓ {}{}{} |",
                    energy.map_or("E –".into(), |e| format!("E≤{e:.2}")),
                    if exempt { " (model)" } else { "" },
                    if skipped > 0 {
                        format!(" ({skipped} fmt n/a)")
                    } else {
                        String::new()
                    }
                );
            } else {
                let _ = write!(m, " {} |", failed.join("; "));
            }
        }
        let _ = writeln!(m);
    }
    let _ = writeln!(
        m,
        "\n✓ = every format finite, non-negative and within the peak bound; E = largest \
         integrated energy over the exact one at the coarsest level (– where not measured); \
         `fmt n/a` = a format that \
         cannot hold the method's values (LEAN's unbounded moments in unorm), refused with a \
         typed error.\n"
    );
    let _ = writeln!(m, "Naive formulas against the guards:\n");
    let _ = writeln!(
        m,
        "| computation | naive | guarded | naive fails | guard holds |"
    );
    let _ = writeln!(m, "|---|---|---|---|---|");
    for d in &s.demos {
        let _ = writeln!(
            m,
            "| {} | {} | {} | {} | {} |",
            d.name,
            d.naive,
            d.guarded,
            if d.naive_fails { "yes" } else { "no" },
            if d.guard_holds { "yes" } else { "no" }
        );
    }
    m.push('\n');
    m
}

/// The environment-lighting cases of the suite (issue 16): a black environment (every route's
/// output exactly 0), a single-texel sun of radiance 10⁶ (finite, non-negative, within the
/// energy bounds below), both through the routes alone and taken out as a light (the default
/// extraction, `environment::lights`), and κ → ∞ lobes reading level 0 of the prefiltered
/// environment.
#[derive(Debug, Clone, Serialize)]
pub struct EnvStability {
    /// Shading evaluations made.
    pub checked: u64,
    /// Largest |output| under the black environment (must be exactly 0).
    pub black_max: f64,
    /// Non-finite or negative outputs under the single-texel sun.
    pub sun_bad: u64,
    /// Largest diffuse output over its bound `1.0625 ∫L dω` (the l ≤ 2 Lambert kernel's peak,
    /// `Σ ρ̂_l (2l+1)/4π = 17/16`).
    pub sun_diffuse_ratio: f64,
    /// Largest specular output over its bound: `max(∫L dω · Σ_l |ρ̂_l|(2l+1)/4π` (SH route, by
    /// the addition theorem), `8 · max L` (prefiltered route: a convex combination of texels
    /// times the lobe energy, ≤ 4 ∫f dω_h ≤ 8)`)`.
    pub sun_specular_ratio: f64,
    /// Lights extracted from the single-texel sun with the default light options (the
    /// default of `eval`, `report`, the C API and the viewer): must be 1.
    pub sun_lights: usize,
    /// Non-finite or negative outputs under the sun taken out as a light.
    pub sun_lit_bad: u64,
    /// Largest diffuse output under the extracted sun over `1.0625 ∫L dω` (the light's
    /// `P max(n·l, 0) ≤ P` plus the residual's SH).
    pub sun_lit_diffuse_ratio: f64,
    /// Largest specular output under the extracted sun over the residual's bound (as
    /// `sun_specular_ratio`) plus `P · f(1)` per light (the point-light path: a lobe
    /// convolved with the NDF never exceeds the BRDF's peak).
    pub sun_lit_specular_ratio: f64,
    /// LOD of κ = ∞, 10³⁰ and NaN (must be 0).
    pub infinite_kappa_lod: f64,
    /// |lookup(κ = ∞) − level 0's bilinear value|, largest over directions (must be 0).
    pub infinite_kappa_difference: f64,
}

impl EnvStability {
    /// Whether every check holds.
    pub fn ok(&self) -> bool {
        self.black_max == 0.0
            && self.sun_bad == 0
            && self.sun_diffuse_ratio <= 1.0 + 1e-9
            && self.sun_specular_ratio <= 1.0 + 1e-9
            && self.sun_lights == 1
            && self.sun_lit_bad == 0
            && self.sun_lit_diffuse_ratio <= 1.0 + 1e-9
            && self.sun_lit_specular_ratio <= 1.0 + 1e-9
            && self.infinite_kappa_lod == 0.0
            && self.infinite_kappa_difference == 0.0
    }
}

/// The sun cases' check of one shading: raises `diffuse_ratio` and `specular_ratio` to the
/// largest output over `diffuse_bound` and `specular_bound`; returns how many channels are
/// non-finite or negative.
fn bounded(
    rgb: &crate::envlight::RgbShading,
    diffuse_bound: f64,
    specular_bound: f64,
    diffuse_ratio: &mut f64,
    specular_ratio: &mut f64,
) -> u64 {
    let mut bad = 0;
    for c in 0..3 {
        let f = rgb.channel(c);
        if !(f.diffuse.is_finite()
            && f.specular.is_finite()
            && f.diffuse >= 0.0
            && f.specular >= 0.0)
        {
            bad += 1;
        }
        *diffuse_ratio = diffuse_ratio.max(f.diffuse / diffuse_bound);
        *specular_ratio = specular_ratio.max(f.specular / specular_bound);
    }
    bad
}

/// Runs the environment cases on a small bumpy map (16 × 16) with plain, Toksvig, LEAN,
/// Olano–North, vMF J = 3, Tan 2005 J = 3 and SH l* = 4 bakes, Blinn-Phong s = 1, 10⁵, GGX α = 10⁻³, 1 and Lambert, both
/// routes, 9 views, every level.
pub fn environment() -> EnvStability {
    use crate::environment::Radiance;
    use crate::envlight::{ENV_LMAX, EnvLight, Route, shade};
    let m = map(16, 16, bumpy);
    let bakes: Vec<Bake> = [
        (Method::Plain, BakeOptions::default()),
        (Method::Toksvig, BakeOptions::default()),
        (Method::Lean, BakeOptions::default()),
        (Method::Olano, BakeOptions::default()),
        (
            Method::Vmf,
            BakeOptions {
                lobes: 3,
                ..BakeOptions::default()
            },
        ),
        (
            Method::Tan2005,
            BakeOptions {
                lobes: 3,
                ..BakeOptions::default()
            },
        ),
        (
            Method::Sh,
            BakeOptions {
                lmax: 4,
                ..BakeOptions::default()
            },
        ),
    ]
    .into_iter()
    .map(|(method, o)| bake_with(&m, method, &o).expect("valid options"))
    .collect();
    let brdfs = [
        Brdf::BlinnPhong { s: 1.0 },
        Brdf::BlinnPhong { s: 1e5 },
        Brdf::ggx(1e-3),
        Brdf::ggx(1.0),
        Brdf::Lambert,
    ];
    let views: Vec<DVec3> = hemisphere(9);
    let black = EnvLight::grey(Radiance::constant(32, 0.0));
    let mut v = vec![0.0f32; 64 * 32];
    v[9 * 64 + 40] = 1e6;
    let sun_env = Radiance::new(64, 32, v.clone()).expect("valid");
    let power = sun_env.power();
    let max_l = 1e6;
    let sun_rgb = crate::environment::Environment::from_rgb(
        "single-texel sun",
        64,
        32,
        v.iter().map(|&x| [x; 3]).collect(),
        &crate::environment::EnvOptions::default(),
    )
    .expect("valid");
    let sun = EnvLight::grey(sun_env);
    let sun_lit = EnvLight::with_lights(
        &sun_rgb,
        &crate::environment::lights::LightOptions::default(),
    );
    let light_power: f64 = sun_lit.lights().iter().map(|l| l.power[1]).sum();
    let mut out = EnvStability {
        checked: 0,
        black_max: 0.0,
        sun_bad: 0,
        sun_diffuse_ratio: 0.0,
        sun_specular_ratio: 0.0,
        sun_lights: sun_lit.lights().len(),
        sun_lit_bad: 0,
        sun_lit_diffuse_ratio: 0.0,
        sun_lit_specular_ratio: 0.0,
        infinite_kappa_lod: 0.0,
        infinite_kappa_difference: 0.0,
    };
    let spec_bound: Vec<f64> = brdfs
        .iter()
        .map(|b| {
            let sh: f64 = b
                .sh_coefficients(ENV_LMAX)
                .iter()
                .enumerate()
                .map(|(l, r)| r.abs() * (2 * l + 1) as f64 / (4.0 * PI))
                .sum();
            (power * sh).max(8.0 * max_l)
        })
        .collect();
    for bake in &bakes {
        for (k, &(w, h)) in bake.sizes.iter().enumerate() {
            for i in (0..(w * h) as usize).step_by(7) {
                let mut t = vec![[0.0f32; 4]; bake.textures.len()];
                bake.texel_into(k, i, &mut t);
                for &view in &views {
                    for (b, brdf) in brdfs.iter().enumerate() {
                        for route in [Route::Prefiltered, Route::Sh] {
                            let rgb = shade(&black, bake, &t, view, brdf, route);
                            for c in 0..3 {
                                let f = rgb.channel(c);
                                out.black_max =
                                    out.black_max.max(f.diffuse.abs()).max(f.specular.abs());
                            }
                            let rgb = shade(&sun, bake, &t, view, brdf, route);
                            let (d, sp) = (1.0625 * power, spec_bound[b]);
                            out.sun_bad += bounded(
                                &rgb,
                                d,
                                sp,
                                &mut out.sun_diffuse_ratio,
                                &mut out.sun_specular_ratio,
                            );
                            let rgb = shade(&sun_lit, bake, &t, view, brdf, route);
                            let sp = spec_bound[b] + light_power * brdf.peak();
                            out.sun_lit_bad += bounded(
                                &rgb,
                                d,
                                sp,
                                &mut out.sun_lit_diffuse_ratio,
                                &mut out.sun_lit_specular_ratio,
                            );
                            out.checked += 3;
                        }
                    }
                }
            }
        }
    }
    let p = sun.channel(0).prefiltered();
    for kappa in [f64::INFINITY, 1e30, f64::NAN] {
        out.infinite_kappa_lod = out.infinite_kappa_lod.max(p.lod(kappa));
    }
    for d in hemisphere(64) {
        let a = p.lookup(d, f64::INFINITY);
        let b = p.levels()[0].radiance.bilinear(d);
        out.infinite_kappa_difference = out.infinite_kappa_difference.max((a - b).abs());
    }
    out
}
