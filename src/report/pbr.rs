//! The PBR comparison (issue 17, `ndfmap pbr-report`): on one map and base roughness, the
//! texel-space GGX error ([`crate::eval::Reference`]: relative RMS of the specular term
//! `D·max(n·l, 0)` against the exact footprint average, the evaluation's 27 light/view pairs
//! with grazing ones) of every way to give an unmodified GGX engine a normal and a roughness
//! MIP chain, side by side with Filament's `roughness-prefilter` run on the same map when it is
//! on PATH:
//!
//! - plain mip (normalized mean normal, base α);
//! - Filament's tool as users run it (perceptual roughness in, its 8-bit PNG levels out, the
//!   plain-mip normal beside them), and its formula `α′ = α + min(0.5/κ, 0.04)`;
//! - the κ formula `α′² = α² + c/κ` with Unity's c = 0.5, Godot's 0.75 and Karis' / ndfmap's 2;
//! - ndfmap's fitted isotropic lobe ([`crate::pbr`]) and its anisotropic lobe;
//! - ndfmap's roughness fitted at plain mip's normal (`PbrOptions::mean_normal`);
//! - the best isotropic lobe found per texel (multi-start Levenberg–Marquardt on the
//!   evaluation's own pairs, [`crate::pbr::Search::Thorough`]: a lower bound for any single
//!   isotropic lobe as far as the search finds it);
//! - the best isotropic lobe found the same way on the evaluation's pairs turned by 45° about
//!   the normal, scored on the untouched pairs: what a lobe fitted without seeing the scored
//!   pairs reaches, so the in-sample bound's advantage is visible;
//! - vMF J = 6 (aligned with eq 29's default C, balanced) under GGX with the default vMF rule
//!   (the vMF-mixture convolution of GGX, `brdf::ggx_mixture`; c = 2 before H17t): a custom
//!   shader, for scale.
//!
//! Beside each row's specular error, the pooled error of the diffuse term `max(n·l, 0)` its
//! normal gives: what a fitted normal costs a material's Lambert term.

use crate::bake::{Bake, BakeOptions, Method, PbrOptions};
use crate::brdf::Brdf;
use crate::error::{Error, Result};
use crate::eval::{Reference, default_directions};
use crate::ingest::NormalMap;
use crate::pbr::{FitSet, Search, Widening, bake_formula, bake_with_set, fit_set};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// One row of the comparison: a way to filter, and its error per level.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PbrRow {
    /// What the row is.
    pub label: String,
    /// Specular relative RMS error per level, finest first (levels before the first measured
    /// one are 0).
    pub levels: Vec<f64>,
    /// The RMS of the per-level errors over the measured levels.
    pub pooled: f64,
    /// The same for the diffuse term `max(n·l, 0)` of the row's normal (what the normal
    /// texture costs a material's Lambert term; the roughness does not enter it).
    pub diffuse_pooled: f64,
    /// Seconds it took to make (bake or tool run), if measured.
    pub seconds: Option<f64>,
}

/// The comparison on one map at one base roughness.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PbrComparison {
    /// The map's name.
    pub map: String,
    /// Base GGX α.
    pub alpha: f64,
    /// The levels measured (inclusive).
    pub levels: (usize, usize),
    /// The renderer's widest view and light angle the rows are scored within (degrees), if
    /// not all of the evaluation's pairs.
    pub max_angle: Option<f64>,
    /// How many light/view pairs score the rows.
    pub scored_pairs: usize,
    /// The rows, in the order of the module docs (Filament's tool row absent without it).
    pub rows: Vec<PbrRow>,
    /// Seconds of ndfmap's isotropic fit per level (level 0: none), and of its targets.
    pub fit_seconds: Vec<f64>,
    /// Seconds of the exact targets and statistics of ndfmap's bake.
    pub target_seconds: f64,
    /// Seconds of the anisotropic fit per level.
    pub aniso_seconds: Vec<f64>,
    /// Why Filament's row is missing, if it is.
    pub filament_note: Option<String>,
}

/// The evaluation's light/view pairs ([`default_directions`]), or those with view and light
/// within `max_angle` degrees of the zenith (an error when fewer than two remain).
fn scored_directions(max_angle: Option<f64>) -> Result<Vec<crate::eval::LightView>> {
    let all = default_directions();
    let Some(a) = max_angle else {
        return Ok(all);
    };
    let cos = a.to_radians().cos() - 1e-12;
    let kept: Vec<_> = all
        .into_iter()
        .filter(|(l, v)| l.z >= cos && v.z >= cos)
        .collect();
    if kept.len() < 2 || !a.is_finite() {
        return Err(Error::InvalidOption(format!(
            "--fit-max-angle {a}: fewer than two evaluation pairs within it"
        )));
    }
    Ok(kept)
}

/// Finds `roughness-prefilter` on PATH.
pub fn find_filament() -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .map(|d| d.join("roughness-prefilter"))
        .find(|p| p.is_file())
}

/// Writes `map`'s normals as an 8-bit RGB PNG (`0.5 + 0.5 n`), the input Filament's tool reads.
fn write_normals_png(map: &NormalMap, path: &Path) -> Result<()> {
    let rgb: Vec<u8> = map
        .normals()
        .iter()
        .flat_map(|n| {
            [n.x, n.y, n.z].map(|c| ((0.5 + 0.5 * c).clamp(0.0, 1.0) * 255.0).round() as u8)
        })
        .collect();
    image::save_buffer(
        path,
        &rgb,
        map.width(),
        map.height(),
        image::ExtendedColorType::Rgb8,
    )
    .map_err(|e| Error::Write {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

/// Runs Filament's `tool` on `map` with constant perceptual roughness `roughness` in `dir`,
/// reads its levels back (linear, as it stores them whatever its PNG's sRGB chunk says), and
/// returns them with the tool's wall-clock seconds.
pub fn run_filament(
    tool: &Path,
    map: &NormalMap,
    roughness: f64,
    dir: &Path,
) -> Result<(Vec<Vec<f32>>, f64)> {
    let input = dir.join("normals.png");
    write_normals_png(map, &input)?;
    let out = dir.join("roughness.png");
    let t = Instant::now();
    let status = std::process::Command::new(tool)
        .arg(format!("--roughness={roughness}"))
        .arg(&input)
        .arg(&out)
        .output()
        .map_err(|e| Error::InvalidOption(format!("{}: cannot run: {e}", tool.display())))?;
    let seconds = t.elapsed().as_secs_f64();
    if !status.status.success() {
        return Err(Error::InvalidOption(format!(
            "{} failed: {}",
            tool.display(),
            String::from_utf8_lossy(&status.stderr).trim()
        )));
    }
    let opts = crate::ingest::IngestOptions::default();
    let mut levels = Vec::new();
    for k in 0.. {
        let p = dir.join(format!("roughness_{k}.png"));
        if !p.exists() {
            break;
        }
        let m = crate::pbr::load_map(&p, &opts, crate::pbr::MapChannel::Roughness, None)?;
        levels.push(m.values);
    }
    Ok((levels, seconds))
}

/// Measures every row on `map` (named `name`) at base α `alpha`, levels `first..=last`;
/// `vmf` is the map's vMF J = 6 bake (made once per map by the caller), `filament` the tool.
/// With `max_angle` (a renderer that never shows views or lights beyond it, degrees) every row
/// is scored on the evaluation's pairs within it only, the in-sample rows fit those, and a row
/// of the bake fitted for that range (`PbrOptions::fit_max_angle`) joins ndfmap's fits.
pub fn compare(
    map: &NormalMap,
    name: &str,
    alpha: f64,
    (first, last): (usize, usize),
    vmf: Option<&Bake>,
    filament: Option<&Path>,
    max_angle: Option<f64>,
) -> Result<PbrComparison> {
    let perceptual = alpha.sqrt();
    let options = PbrOptions {
        roughness: perceptual,
        ..PbrOptions::default()
    };
    let brdf = Brdf::ggx(alpha);
    let directions = scored_directions(max_angle)?;
    let mut bakes: Vec<(String, Bake, Option<f64>)> = Vec::new();
    let t = Instant::now();
    let plain = crate::methods::bake_with(map, Method::Plain, &BakeOptions::default())?;
    bakes.push(("plain mip".into(), plain, Some(t.elapsed().as_secs_f64())));
    let mut filament_note = None;
    match filament {
        Some(tool) => {
            let dir = std::env::temp_dir()
                .join(format!("ndfmap-pbr-{}-{name}-{alpha}", std::process::id()));
            std::fs::create_dir_all(&dir).map_err(|e| Error::Write {
                path: dir.clone(),
                message: e.to_string(),
            })?;
            let r = run_filament(tool, map, perceptual, &dir);
            let _ = std::fs::remove_dir_all(&dir);
            match r.and_then(|(levels, s)| {
                crate::pbr::bake_with_roughness(map, &levels).map(|b| (b, s))
            }) {
                Ok((b, s)) => bakes.push(("Filament roughness-prefilter".into(), b, Some(s))),
                Err(e) => filament_note = Some(format!("roughness-prefilter: {e}")),
            }
        }
        None => {
            filament_note = Some("roughness-prefilter is not on PATH: its row is absent".into())
        }
    }
    for (label, w) in [
        ("κ Filament: α + min(0.5/κ, 0.04)", Widening::Filament),
        ("κ Unity: α² + 0.5/κ", Widening::Constant(0.5)),
        ("κ Godot: α² + 0.75/κ", Widening::Constant(0.75)),
        ("κ Karis/ndfmap: α² + 2/κ", Widening::Constant(2.0)),
    ] {
        let t = Instant::now();
        let b = bake_formula(map, &options, None, w)?;
        bakes.push((label.into(), b, Some(t.elapsed().as_secs_f64())));
    }
    // The evaluation's pairs turned by 45° about the geometric normal: the same distribution
    // of light/view pairs, other samples (only the pair with light and view at the zenith is
    // shared; a 90° turn maps the evaluation's four-fold light azimuths onto themselves, so
    // the nine pairs of its zenith view would be in-sample). The best lobe fitted on them and
    // scored on the evaluation's own pairs is what a lobe fitted without seeing those pairs
    // can reach, so it tells the in-sample row's advantage from what any bake could gain.
    let (c45, s45) = (
        std::f64::consts::FRAC_1_SQRT_2,
        std::f64::consts::FRAC_1_SQRT_2,
    );
    let turn = |d: glam::DVec3| glam::DVec3::new(c45 * d.x - s45 * d.y, s45 * d.x + c45 * d.y, d.z);
    let turned: Vec<_> = directions
        .iter()
        .map(|&(l, v)| (turn(l), turn(v)))
        .collect();
    // ndfmap's fits: (label, anisotropic, mean normal, fit set, search); the first two give
    // the timings.
    let fits = [
        (
            "ndfmap pbr (isotropic fit)",
            false,
            false,
            FitSet::standard(),
            Search::Fast,
        ),
        (
            "ndfmap pbr --anisotropic",
            true,
            false,
            FitSet::standard(),
            Search::Fast,
        ),
        (
            "ndfmap pbr --mean-normal (fitted roughness, plain mip's normal)",
            false,
            true,
            FitSet::standard(),
            Search::Fast,
        ),
        (
            "ndfmap fit on the evaluation's pairs (in-sample)",
            false,
            false,
            FitSet::unweighted(&directions),
            Search::Fast,
        ),
        (
            "best isotropic found (fitted on the evaluation's pairs)",
            false,
            false,
            FitSet::unweighted(&directions),
            Search::Thorough { from_level: first },
        ),
        (
            "best isotropic found on those pairs turned 45° (out of sample)",
            false,
            false,
            FitSet::unweighted(&turned),
            Search::Thorough { from_level: first },
        ),
    ];
    let mut timings = Vec::new();
    let ranged = max_angle
        .map(|a| {
            let o = PbrOptions {
                fit_max_angle: Some(a),
                ..options
            };
            fit_set(&o).map(|set| (format!("ndfmap pbr --fit-max-angle {a}"), set))
        })
        .transpose()?;
    let fits = fits
        .into_iter()
        .map(|(label, anisotropic, mean_normal, set, search)| {
            (label.to_string(), anisotropic, mean_normal, set, search)
        })
        .chain(ranged.map(|(label, set)| (label, false, false, set, Search::Fast)));
    for (label, anisotropic, mean_normal, set, search) in fits {
        let t = Instant::now();
        let o = PbrOptions {
            anisotropic,
            mean_normal,
            ..options
        };
        let (b, timing) = bake_with_set(map, &o, None, &set, search, first)?;
        bakes.push((label, b, Some(t.elapsed().as_secs_f64())));
        timings.push(timing);
    }
    let reference = Reference::new(map, std::slice::from_ref(&brdf), &directions, first);
    let refs: Vec<&Bake> = bakes.iter().map(|b| &b.1).chain(vmf).collect();
    let errors = reference.evaluate(&refs);
    let labels: Vec<(String, Option<f64>)> = bakes
        .iter()
        .map(|b| (b.0.clone(), b.2))
        .chain(vmf.map(|_| {
            (
                "vMF J = 6 aligned, GGX vMF-mixture rule (custom shader)".to_string(),
                None,
            )
        }))
        .collect();
    let last = last.min(
        errors
            .first()
            .map_or(0, |e| e.levels.len().saturating_sub(1)),
    );
    let rows = errors
        .iter()
        .zip(labels)
        .map(|(e, (label, seconds))| {
            let levels: Vec<f64> = e.levels.iter().map(|l| l.specular).collect();
            let pool = |v: &[f64]| {
                let measured = &v[first.min(last)..=last];
                (measured.iter().map(|v| v * v).sum::<f64>() / measured.len() as f64).sqrt()
            };
            let diffuse: Vec<f64> = e.levels.iter().map(|l| l.diffuse).collect();
            PbrRow {
                label,
                pooled: pool(&levels),
                diffuse_pooled: pool(&diffuse),
                levels,
                seconds,
            }
        })
        .collect();
    Ok(PbrComparison {
        map: name.into(),
        alpha,
        levels: (first, last),
        max_angle,
        scored_pairs: directions.len(),
        rows,
        fit_seconds: timings[0].fit.clone(),
        target_seconds: timings[0].targets,
        aniso_seconds: timings[1].anisotropic.clone(),
        filament_note,
    })
}

/// A markdown table of comparisons: one row per filter, one column per level and the pooled
/// error, and the ratio of each pooled error to Filament's tool's and to the best isotropic.
pub fn markdown(c: &PbrComparison) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    let (first, last) = c.levels;
    let _ = writeln!(
        out,
        "### {} — GGX α = {} (perceptual {:.4}), levels {first}–{last}\n",
        c.map,
        c.alpha,
        c.alpha.sqrt()
    );
    match c.max_angle {
        Some(a) => {
            let _ = writeln!(
                out,
                "Scored on the {} evaluation pairs with view and light within {a}°.\n",
                c.scored_pairs
            );
        }
        None => {
            let _ = writeln!(out, "Scored on all {} evaluation pairs.\n", c.scored_pairs);
        }
    }
    if let Some(n) = &c.filament_note {
        let _ = writeln!(out, "{n}\n");
    }
    let find = |p: &str| {
        c.rows
            .iter()
            .find(|r| r.label.starts_with(p))
            .map(|r| r.pooled)
    };
    let filament = find("Filament roughness");
    let best = find("best isotropic");
    let _ = write!(out, "| filter |");
    for k in first..=last {
        let _ = write!(out, " L{k} |");
    }
    let _ = writeln!(
        out,
        " pooled | ÷ Filament | ÷ best iso | diffuse (pooled) | seconds |"
    );
    let _ = write!(out, "|---|");
    for _ in first..=last {
        let _ = write!(out, "---:|");
    }
    let _ = writeln!(out, "---:|---:|---:|---:|---:|");
    for r in &c.rows {
        let _ = write!(out, "| {} |", r.label);
        for k in first..=last {
            let _ = write!(out, " {:.3} |", r.levels[k]);
        }
        let ratio = |d: Option<f64>| d.map_or("–".into(), |d| format!("{:.2}", r.pooled / d));
        let _ = writeln!(
            out,
            " **{:.3}** | {} | {} | {:.4} | {} |",
            r.pooled,
            ratio(filament),
            ratio(best),
            r.diffuse_pooled,
            r.seconds.map_or("–".into(), |s| format!("{s:.2}"))
        );
    }
    let fit: Vec<String> = c.fit_seconds.iter().map(|s| format!("{s:.3}")).collect();
    let an: Vec<String> = c.aniso_seconds.iter().map(|s| format!("{s:.3}")).collect();
    let _ = writeln!(
        out,
        "\nndfmap fit seconds: targets + statistics {:.3}; isotropic fit per level [{}]; \
         anisotropic fit per level [{}]\n",
        c.target_seconds,
        fit.join(", "),
        an.join(", ")
    );
    out
}
