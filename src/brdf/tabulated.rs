//! A tabulated BRDF `f(θ_h)·g(θ_d)`: the factored measured materials of Han et al. 2007
//! Sec 5.2 and footnote 4 (Lawrence et al. 2006's factorization of the MERL database), read
//! from a small JSON file.
//!
//! # File format
//! ```json
//! {
//!   "name": "blue-fabric",
//!   "theta_h_deg": [0, 0.011, 0.044, …],
//!   "f": [41.2, 40.9, 39.7, …],
//!   "theta_d_deg": [0, 1, 2, …],
//!   "g": [1.0, 1.0, 0.99, …]
//! }
//! ```
//! - `f` (required): the lobe `f(θ_h)` at the half-angle samples `theta_h_deg`, from 0 to
//!   [`MAX_VALUE`] (10¹²), in the units the renderer wants (the library never renormalizes it; a lobe that
//!   integrates to 1 over the hemisphere, like the analytic ones, has `ρ̂_0 = 1`). 2 to
//!   [`MAX_SAMPLES`] samples; factored MERL materials have 90.
//! - `theta_h_deg` (optional): ascending angles in [0, 90] degrees, one per `f` sample;
//!   default: equally spaced from 0 to 90 inclusive. MERL's half-angle bins are at
//!   `θ_h = 90°·(i/90)²`.
//! - `g` (optional, default 1): the factor `g(θ_d)` of the difference angle
//!   `θ_d = acos(ω_i·ω_h)`, from 0 to [`MAX_VALUE`]; `theta_d_deg` likewise (default: equally
//!   spaced over [0, 90]).
//! - `name` (optional): shown in tables.
//!
//! Unknown fields are errors. A file is read only if it is a regular file of at most
//! [`MAX_FILE_BYTES`] ([`Tabulated::load`]).
//!
//! Both functions are piecewise linear between samples and constant beyond the first and last;
//! f is zero past θ_h = 90°.
//!
//! # Internal form
//! On loading, f is resampled onto a fixed grid of [`GRID`] angles `θ = π x²`,
//! `x = i/(GRID−1)`, dense near the peak (steps of 5·10⁻⁵ rad at θ = 0, 1° at 90°), and g onto
//! [`GRID`] equal steps of θ_d over [0, 90°]. *That* piecewise-linear function (in x) is the
//! BRDF: the reference shading, the SH coefficients, the shaders and the CPU twin all use it,
//! so nothing differs between them but f32 storage. The shaders read it as one float texture
//! ([`Tabulated::table`]): [`KAPPA_ROWS`] rows of the lobe convolved with a vMF lobe of
//! concentration `κ_k = 2^{k/2} − 1` (eq 14 computed numerically, module
//! [`super::convolution`]; the last row is κ = ∞, the lobe itself), then one row of g. Every
//! method shades a tabulated lobe from this table: vMF lobes at their κ, the single-lobe
//! baselines at the κ of their variance (`κ = 1/σ²`, the closest isotropic approximation), plain
//! MIP-mapping from the last row.

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::path::Path;
use std::sync::OnceLock;

/// Angles per row of the internal grid and of the shader's table.
pub const GRID: usize = 256;

/// Rows of lobes convolved with vMF lobes in the shader's table; row k has concentration
/// `2^{k/2} − 1` (κ from 0 to 3·10⁶), the last is κ = ∞.
pub const KAPPA_ROWS: usize = 45;

/// Most samples accepted for f or g.
pub const MAX_SAMPLES: usize = 1024;

/// Largest value accepted for f or g: 10¹². Far above any measured or analytic lobe (GGX
/// α = 10⁻⁴ peaks at 3·10⁷), and low enough that the SH coefficients, the convolved table and
/// its f32 texels stay finite (values near `f64::MAX` made `ρ̂_l` infinite: a fuzz finding).
pub const MAX_VALUE: f64 = 1e12;

/// Largest tabulated BRDF file [`Tabulated::load`] reads: 4 MiB, some thirty times a file of
/// [`MAX_SAMPLES`] samples in each of its four arrays written one number to a line.
pub const MAX_FILE_BYTES: u64 = 4 << 20;

/// The JSON file's contents (module docs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TabulatedFile {
    /// Name shown in tables.
    #[serde(default)]
    pub name: String,
    /// Half-angle samples in degrees (default: equally spaced over [0, 90]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub theta_h_deg: Option<Vec<f64>>,
    /// `f(θ_h)`.
    pub f: Vec<f64>,
    /// Difference-angle samples in degrees (default: equally spaced over [0, 90]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub theta_d_deg: Option<Vec<f64>>,
    /// `g(θ_d)` (default: 1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub g: Option<Vec<f64>>,
}

/// A tabulated BRDF (module docs). Built from a [`TabulatedFile`]; serializes back to it.
#[derive(Clone, Serialize, Deserialize)]
#[serde(into = "TabulatedFile", try_from = "TabulatedFile")]
pub struct Tabulated {
    source: TabulatedFile,
    /// f on the grid θ = π x².
    f: Vec<f64>,
    /// g on the grid θ_d = (π/2) i/(GRID−1).
    g: Vec<f64>,
    /// Angle where f falls to half its value at 0 (or its peak).
    half_width: f64,
    table: OnceLock<Vec<f32>>,
}

impl std::fmt::Debug for Tabulated {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "Tabulated({:?}, {} f samples, {} g samples)",
            self.source.name,
            self.source.f.len(),
            self.source.g.as_ref().map_or(0, Vec::len)
        )
    }
}

impl PartialEq for Tabulated {
    fn eq(&self, other: &Self) -> bool {
        self.source == other.source
    }
}

impl From<Tabulated> for TabulatedFile {
    fn from(t: Tabulated) -> TabulatedFile {
        t.source
    }
}

impl TryFrom<TabulatedFile> for Tabulated {
    type Error = Error;
    fn try_from(file: TabulatedFile) -> Result<Tabulated> {
        Tabulated::new(file, "tabulated BRDF")
    }
}

/// Piecewise-linear interpolation of `(xs, ys)` at `x` (constant beyond the ends); `xs`
/// ascending.
pub(crate) fn interp(xs: &[f64], ys: &[f64], x: f64) -> f64 {
    if x <= xs[0] {
        return ys[0];
    }
    let last = xs.len() - 1;
    if x >= xs[last] {
        return ys[last];
    }
    let i = xs.partition_point(|&v| v <= x).clamp(1, last);
    let (x0, x1) = (xs[i - 1], xs[i]);
    let t = if x1 > x0 { (x - x0) / (x1 - x0) } else { 1.0 };
    ys[i - 1] + t * (ys[i] - ys[i - 1])
}

/// Checks one sampled function and its angles; returns the angles in radians.
fn samples(what: &str, name: &str, v: &[f64], angles: Option<&Vec<f64>>) -> Result<Vec<f64>> {
    let bad = |message: String| Error::Brdf {
        what: what.to_string(),
        message,
    };
    if v.len() < 2 || v.len() > MAX_SAMPLES {
        return Err(bad(format!(
            "{name} has {} samples (expected 2 to {MAX_SAMPLES})",
            v.len()
        )));
    }
    if let Some(i) = v.iter().position(|x| !(0.0..=MAX_VALUE).contains(x)) {
        return Err(bad(format!(
            "{name}[{i}] = {:?} (expected 0 to {MAX_VALUE:e})",
            v[i]
        )));
    }
    let n = v.len();
    let angles: Vec<f64> = match angles {
        Some(a) => {
            if a.len() != n {
                return Err(bad(format!("{} angles for {n} {name} samples", a.len())));
            }
            if let Some(i) = a.iter().position(|x| !(0.0..=90.0).contains(x)) {
                return Err(bad(format!(
                    "angle {} of {name} outside [0, 90] degrees",
                    a[i]
                )));
            }
            if let Some(i) = a.windows(2).position(|p| p[1] <= p[0]) {
                return Err(bad(format!(
                    "the angles of {name} are not ascending at sample {}",
                    i + 1
                )));
            }
            a.iter().map(|d| d.to_radians()).collect()
        }
        None => (0..n)
            .map(|i| 0.5 * PI * i as f64 / (n - 1) as f64)
            .collect(),
    };
    Ok(angles)
}

impl Tabulated {
    /// Checks `file` (module docs) and resamples it onto the internal grid. `what` names the
    /// source in errors (a path or "tabulated BRDF").
    pub fn new(file: TabulatedFile, what: &str) -> Result<Tabulated> {
        let th = samples(what, "f", &file.f, file.theta_h_deg.as_ref())?;
        let f: Vec<f64> = (0..GRID)
            .map(|i| {
                let theta = grid_theta(i);
                if theta > 0.5 * PI {
                    0.0
                } else {
                    interp(&th, &file.f, theta)
                }
            })
            .collect();
        let g = match &file.g {
            Some(gs) => {
                let td = samples(what, "g", gs, file.theta_d_deg.as_ref())?;
                (0..GRID)
                    .map(|i| interp(&td, gs, 0.5 * PI * i as f64 / (GRID - 1) as f64))
                    .collect()
            }
            None => {
                if file.theta_d_deg.is_some() {
                    return Err(Error::Brdf {
                        what: what.to_string(),
                        message: "theta_d_deg given without g".into(),
                    });
                }
                vec![1.0; GRID]
            }
        };
        let peak = f.iter().cloned().fold(0.0f64, f64::max);
        let half_width = (0..GRID)
            .find(|&i| f[i] < 0.5 * peak && f[..i].iter().any(|&v| v >= 0.5 * peak))
            .map_or(0.5 * PI, grid_theta)
            .clamp(1e-4, 0.5 * PI);
        Ok(Tabulated {
            source: file,
            f,
            g,
            half_width,
            table: OnceLock::new(),
        })
    }

    /// Parses the JSON text of a tabulated BRDF file (module docs); `what` names it in errors.
    pub fn from_json(text: &str, what: &str) -> Result<Tabulated> {
        let file: TabulatedFile = serde_json::from_str(text).map_err(|e| Error::Brdf {
            what: what.to_string(),
            message: e.to_string(),
        })?;
        Tabulated::new(file, what)
    }

    /// Reads a tabulated BRDF file (module docs): a regular file (a FIFO, a device or a folder
    /// is [`Error::Read`], without blocking) of at most [`MAX_FILE_BYTES`] of UTF-8 text.
    pub fn load(path: &Path) -> Result<Tabulated> {
        let what = path.display().to_string();
        let bytes = crate::ingest::read_capped(path, MAX_FILE_BYTES, |len| Error::Brdf {
            what: what.clone(),
            message: format!(
                "a file of {len} bytes, more than the {MAX_FILE_BYTES} bytes (4 MiB) a tabulated \
                 BRDF file may hold"
            ),
        })?;
        let text = String::from_utf8(bytes).map_err(|e| Error::Brdf {
            what: what.clone(),
            message: format!("not UTF-8 text (byte {})", e.utf8_error().valid_up_to()),
        })?;
        Tabulated::from_json(&text, &what)
    }

    /// Tabulates `f(θ_h)` and `g(θ_d)` (angles in radians) at `n` half angles
    /// `θ_h = 90°·(i/(n−1))²` (MERL-like, dense near the peak) and `n` equally spaced
    /// difference angles: how the tests turn the analytic models into files.
    pub fn sample(
        name: &str,
        n: usize,
        f: &dyn Fn(f64) -> f64,
        g: Option<&dyn Fn(f64) -> f64>,
    ) -> Result<Tabulated> {
        let th: Vec<f64> = (0..n)
            .map(|i| 90.0 * (i as f64 / (n - 1) as f64).powi(2))
            .collect();
        let td: Vec<f64> = (0..n).map(|i| 90.0 * i as f64 / (n - 1) as f64).collect();
        Tabulated::new(
            TabulatedFile {
                name: name.to_string(),
                f: th.iter().map(|t| f(t.to_radians())).collect(),
                theta_h_deg: Some(th),
                g: g.map(|g| td.iter().map(|t| g(t.to_radians())).collect()),
                theta_d_deg: g.map(|_| td.clone()),
            },
            name,
        )
    }

    /// The name given in the file.
    pub fn name(&self) -> &str {
        &self.source.name
    }

    /// The file's contents.
    pub fn source(&self) -> &TabulatedFile {
        &self.source
    }

    /// The lobe `f(θ_h)` (radians; zero past π/2): linear in `x = sqrt(θ/π)` between the grid
    /// samples (module docs).
    pub fn f(&self, theta: f64) -> f64 {
        lerp_row(&self.f, grid_x(theta))
    }

    /// The factor `g(θ_d)` (radians), linear between the grid samples.
    pub fn g(&self, theta_d: f64) -> f64 {
        let x = (theta_d / (0.5 * PI)).clamp(0.0, 1.0) * (GRID - 1) as f64;
        lerp_row(&self.g, x)
    }

    /// The angle (radians) where f falls to half its peak.
    pub fn half_width(&self) -> f64 {
        self.half_width
    }

    /// The largest value of f.
    pub fn peak(&self) -> f64 {
        self.f.iter().cloned().fold(0.0, f64::max)
    }

    /// The largest value of g.
    pub fn g_peak(&self) -> f64 {
        self.g.iter().cloned().fold(0.0, f64::max)
    }

    /// The shader's table, row-major f32, [`GRID`] wide and [`KAPPA_ROWS`]` + 1` high: rows
    /// `k < KAPPA_ROWS − 1` hold eq 14 for `κ_k = 2^{k/2} − 1` at `θ = π x²`, row
    /// `KAPPA_ROWS − 1` the lobe f itself (κ = ∞), the last row g. Computed on first use
    /// (about 0.5 s on one core; rows in parallel).
    pub fn table(&self) -> &[f32] {
        self.table.get_or_init(|| {
            use rayon::prelude::*;
            let width = self.half_width;
            let f = |beta: f64| self.f(beta);
            let mut rows: Vec<Vec<f32>> = (0..KAPPA_ROWS - 1)
                .into_par_iter()
                .map(|k| {
                    let kappa = table_kappa(k);
                    (0..GRID)
                        .map(|i| {
                            super::convolution::convolve_vmf(&f, width, kappa, grid_theta(i)) as f32
                        })
                        .collect()
                })
                .collect();
            rows.push(self.f.iter().map(|&v| v as f32).collect());
            rows.push(self.g.iter().map(|&v| v as f32).collect());
            rows.concat()
        })
    }
}

/// The concentration of row `k` of the table: `2^{k/2} − 1` (∞ for the last lobe row).
pub fn table_kappa(k: usize) -> f64 {
    if k + 1 >= KAPPA_ROWS {
        f64::INFINITY
    } else {
        2f64.powf(0.5 * k as f64) - 1.0
    }
}

/// Angle of grid sample i: `π (i/(GRID−1))²`.
fn grid_theta(i: usize) -> f64 {
    let x = i as f64 / (GRID - 1) as f64;
    PI * x * x
}

/// The fractional grid index of angle θ: `sqrt(θ/π)·(GRID−1)`.
fn grid_x(theta: f64) -> f64 {
    (theta / PI).clamp(0.0, 1.0).sqrt() * (GRID - 1) as f64
}

/// Linear interpolation within one row at fractional index `x` in [0, GRID−1].
fn lerp_row(row: &[f64], x: f64) -> f64 {
    let x = if x.is_nan() { 0.0 } else { x };
    let i = (x.floor() as usize).min(GRID - 2);
    let t = x - i as f64;
    row[i] + t * (row[i + 1] - row[i])
}

/// The table's lobe at angle `theta` (radians) from the lobe's centre under a vMF lobe of
/// concentration `kappa` (any κ ≥ 0, ∞ included): bilinear in `x = sqrt(θ/π)·(GRID−1)` and
/// `t = min(2 log2(1 + κ), KAPPA_ROWS − 1)`, the shader's `ndf_tab_lobe` (CPU twin).
pub fn lookup(table: &[f32], theta: f64, kappa: f64) -> f64 {
    let x = grid_x(theta);
    let kappa = if kappa >= 0.0 { kappa } else { 0.0 };
    let t = (2.0 * kappa.ln_1p() / std::f64::consts::LN_2).min((KAPPA_ROWS - 1) as f64);
    let j = (t.floor() as usize).min(KAPPA_ROWS - 2);
    let ft = t - j as f64;
    let row = |k: usize| -> f64 {
        let i = (x.floor() as usize).min(GRID - 2);
        let fx = x - i as f64;
        let a = table[k * GRID + i] as f64;
        let b = table[k * GRID + i + 1] as f64;
        a + fx * (b - a)
    };
    let (a, b) = (row(j), row(j + 1));
    a + ft * (b - a)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::{Brdf, blinn_phong, ggx};

    #[test]
    fn tabulated_analytic_lobes_reproduce_them() {
        // 90 MERL-spaced samples of Blinn-Phong s = 32 and GGX α = 0.2: the tabulated lobe
        // (linear between the samples, then on the internal grid) stays within 2 % of the
        // analytic one where it matters (above 1 % of the peak); the two linear interpolations
        // of a convex lobe overshoot its tail by up to about 1 %.
        for (name, f) in [
            (
                "bp32",
                Box::new(|t: f64| blinn_phong(t.cos(), 32.0)) as Box<dyn Fn(f64) -> f64>,
            ),
            ("ggx0.2", Box::new(|t: f64| ggx(t.cos(), 0.2))),
        ] {
            let t = Tabulated::sample(name, 90, &*f, None).unwrap();
            let peak = f(0.0);
            for i in 0..400 {
                let theta = 0.5 * PI * i as f64 / 400.0;
                let (a, b) = (t.f(theta), f(theta));
                assert!(
                    (a - b).abs() <= 0.02 * b.max(0.01 * peak),
                    "{name} θ={theta}: {a} vs {b}"
                );
            }
        }
    }

    #[test]
    fn json_round_trip_and_errors() {
        let text = r#"{"name": "x", "f": [2.0, 1.0, 0.0], "g": [1.0, 0.5]}"#;
        let t = Tabulated::from_json(text, "x.json").unwrap();
        assert_eq!(t.f(0.0), 2.0);
        assert!((t.f(0.25 * PI) - 1.0).abs() < 1e-2);
        assert_eq!(t.g(0.0), 1.0);
        assert!((t.g(0.5 * PI) - 0.5).abs() < 1e-12);
        let brdf = Brdf::Tabulated(std::sync::Arc::new(t));
        let json = serde_json::to_string(&brdf).unwrap();
        let back: Brdf = serde_json::from_str(&json).unwrap();
        assert_eq!(back, brdf);
        for (bad, why) in [
            (r#"{"f": [1.0]}"#, "samples"),
            (r#"{"f": [1.0, -1.0]}"#, "f[1]"),
            (r#"{"f": [1.0, 2.0], "theta_h_deg": [0, 95]}"#, "outside"),
            (r#"{"f": [1.0, 2.0], "theta_h_deg": [10, 5]}"#, "ascending"),
            (r#"{"f": [1.0, 2.0], "colour": 1}"#, "unknown field"),
            (r#"{"f": [1.0, 2.0], "theta_d_deg": [0, 90]}"#, "without g"),
        ] {
            let e = Tabulated::from_json(bad, "b.json").unwrap_err().to_string();
            assert!(e.contains("b.json") && e.contains(why), "{bad}: {e}");
        }
    }

    #[test]
    fn the_table_is_the_lobe_at_infinite_kappa_and_eq_14_elsewhere() {
        let t = Tabulated::sample("bp16", 90, &|a: f64| blinn_phong(a.cos(), 16.0), None).unwrap();
        let table = t.table();
        assert_eq!(table.len(), GRID * (KAPPA_ROWS + 1));
        for theta in [0.0, 0.2, 0.7] {
            let inf = lookup(table, theta, f64::INFINITY);
            assert!((inf - t.f(theta)).abs() <= 1e-6 * t.f(0.0));
            // A row's κ reproduces eq 14 at a grid angle.
            let k = 12;
            let kappa = table_kappa(k);
            let want = crate::brdf::convolution::convolve_vmf(&|b| t.f(b), 0.3, kappa, theta);
            let got = lookup(table, theta, kappa);
            assert!(
                (got - want).abs() <= 2e-3 * want.max(0.01),
                "{got} vs {want}"
            );
        }
    }
}
