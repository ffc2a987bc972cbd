//! Texel-space error (DESIGN.md "Ground truth and error"): at MIP level k, texel t, the exact
//! answer is the footprint average of the unfiltered shading of every finest normal t covers
//! (eq 4's effective BRDF); the filtered answer is what the method's shading computes from t's
//! baked values. The error is the relative RMS over texels and light/view pairs,
//! `sqrt(Σ (F − G)² / Σ G²)`, per level and per shading term (Lambert, and the specular lobe of
//! each [`Brdf`] with its g factor).
//!
//! The exact answers of every level come from one image of per-normal shading per light/view
//! pair, box-filtered over the exact footprints ([`crate::pyramid::reduce`]), so they are exact
//! for any map size. Sums are f64 in a fixed order: results do not depend on the thread count.

use crate::bake::{Bake, Method};
use crate::brdf::{Brdf, half_vector, reference_brdf};
use crate::format::Format;
use crate::ingest::NormalMap;
use crate::pyramid::{LevelFootprints, pyramid, reduce};
use crate::shade::{ShadeOptions, shade_with};
use glam::DVec3;
use rayon::prelude::*;
use serde::Serialize;

/// A light direction and a view direction, unit vectors in tangent space (z up).
pub type LightView = (DVec3, DVec3);

/// A unit direction from polar angle θ and azimuth φ, in degrees.
pub fn direction(theta_deg: f64, phi_deg: f64) -> DVec3 {
    let (t, p) = (theta_deg.to_radians(), phi_deg.to_radians());
    DVec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos())
}

/// The default light/view set: views at θ = 0°, 35°, 70° (φ = 0°) × lights at the zenith and at
/// θ = 35°, 70° for φ = 0°, 90°, 180°, 270°: 27 pairs, including the three mirror
/// configurations (half vector = +Z) and grazing ones.
pub fn default_directions() -> Vec<LightView> {
    let mut lights = vec![direction(0.0, 0.0)];
    for theta in [35.0, 70.0] {
        for phi in [0.0, 90.0, 180.0, 270.0] {
            lights.push(direction(theta, phi));
        }
    }
    let mut out = Vec::new();
    for view in [0.0, 35.0, 70.0] {
        for &l in &lights {
            out.push((l, direction(view, 0.0)));
        }
    }
    out
}

/// Relative RMS error of one level.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LevelError {
    /// MIP level (0 = finest).
    pub level: usize,
    /// Level width.
    pub width: u32,
    /// Level height.
    pub height: u32,
    /// Lambert term's relative RMS error.
    pub diffuse: f64,
    /// Blinn-Phong term's relative RMS error.
    pub specular: f64,
}

/// One method's error at one Blinn-Phong exponent.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MethodError {
    /// The method.
    pub method: Method,
    /// The bake's label ([`Bake::label`]: method, lobes, alignment, format).
    pub label: String,
    /// The storage format the bake was read in (quantization included in the error).
    pub format: Format,
    /// The BRDF whose specular term was measured.
    pub brdf: Brdf,
    /// Per level, finest first.
    pub levels: Vec<LevelError>,
    /// Lambert error over all levels but the finest: the RMS of the per-level relative errors
    /// (each level counts once, however many texels it has). For a 1×1 map, level 0's.
    pub overall_diffuse: f64,
    /// Blinn-Phong error, aggregated the same way.
    pub overall_specular: f64,
}

/// The exact answers of every level from `first_level` on, for one light/view pair: per level,
/// the footprint averages of the unfiltered shading, interleaved `1 + brdfs.len()` values per
/// texel (Lambert, then the specular term of each BRDF); empty below `first_level`.
fn exact_levels(
    map: &NormalMap,
    levels: &[LevelFootprints],
    brdfs: &[Brdf],
    (l, v): LightView,
    first_level: usize,
) -> Vec<Vec<f64>> {
    let h = half_vector(l, v);
    let ch = 1 + brdfs.len();
    // Per-normal reference: diffuse, then specular for each exponent.
    let mut finest = vec![0.0f64; map.normals().len() * ch];
    finest
        .chunks_exact_mut(ch)
        .zip(map.normals())
        .for_each(|(o, n)| {
            let n = n.as_dvec3();
            o[0] = n.dot(l).max(0.0);
            for (si, brdf) in brdfs.iter().enumerate() {
                o[1 + si] = reference_brdf(n, l, h, brdf).specular;
            }
        });
    levels
        .iter()
        .enumerate()
        .map(|(k, lf)| {
            if k < first_level {
                Vec::new()
            } else {
                reduce(&finest, ch, map.width(), lf)
            }
        })
        .collect()
}

/// Σ(F − G)² and ΣG² (Lambert, then specular) over the texels of level `k`, against that
/// level's exact answers `exact`, per bake and BRDF (index `b · brdfs.len() + si`), summed in
/// texel order.
fn level_sums(
    bakes: &[&Bake],
    brdfs: &[Brdf],
    exact: &[f64],
    k: usize,
    (l, v): LightView,
    options: &ShadeOptions,
) -> Vec<[f64; 4]> {
    let h = half_vector(l, v);
    let ns = brdfs.len();
    let ch = 1 + ns;
    let mut sums = vec![[0.0f64; 4]; bakes.len() * ns];
    for (b, bake) in bakes.iter().enumerate() {
        let mut texel = vec![[0.0f32; 4]; bake.textures.len()];
        for (i, g) in exact.chunks_exact(ch).enumerate() {
            bake.texel_into(k, i, &mut texel);
            for (si, brdf) in brdfs.iter().enumerate() {
                let f = shade_with(bake, &texel, l, h, brdf, options);
                let e = &mut sums[b * ns + si];
                e[0] += (f.diffuse - g[0]).powi(2);
                e[1] += g[0] * g[0];
                e[2] += (f.specular - g[1 + si]).powi(2);
                e[3] += g[1 + si] * g[1 + si];
            }
        }
    }
    sums
}

/// Measures the texel-space error of each bake (baked from `map`) for every BRDF in `brdfs`
/// and every light/view pair in `directions`.
pub fn evaluate(
    map: &NormalMap,
    bakes: &[&Bake],
    brdfs: &[Brdf],
    directions: &[LightView],
) -> Vec<MethodError> {
    evaluate_from(map, bakes, brdfs, directions, 0)
}

/// [`evaluate`] that shades only levels `first_level` and coarser (the finer levels' errors
/// are reported as 0): level 0 is three quarters of the work and every method's error there is
/// the storage rounding only, so reports that aggregate levels ≥ 1 skip it.
///
/// The exact answers are computed per light/view pair and dropped; [`Reference`] keeps them, to
/// measure many bakes of one map, with the same results.
pub fn evaluate_from(
    map: &NormalMap,
    bakes: &[&Bake],
    brdfs: &[Brdf],
    directions: &[LightView],
    first_level: usize,
) -> Vec<MethodError> {
    evaluate_with(
        map,
        bakes,
        brdfs,
        directions,
        first_level,
        &ShadeOptions::default(),
    )
}

/// [`evaluate_from`] with the shading choices of `options` (the vMF lobes' diffuse term).
pub fn evaluate_with(
    map: &NormalMap,
    bakes: &[&Bake],
    brdfs: &[Brdf],
    directions: &[LightView],
    first_level: usize,
    options: &ShadeOptions,
) -> Vec<MethodError> {
    let levels = pyramid(map.width(), map.height());
    // Per direction, per level: the sums of level_sums.
    let per_direction: Vec<Vec<Vec<[f64; 4]>>> = directions
        .par_iter()
        .map(|&lv| {
            let exact = exact_levels(map, &levels, brdfs, lv, first_level);
            (0..levels.len())
                .map(|k| {
                    if k < first_level {
                        vec![[0.0; 4]; bakes.len() * brdfs.len()]
                    } else {
                        level_sums(bakes, brdfs, &exact[k], k, lv, options)
                    }
                })
                .collect()
        })
        .collect();
    errors(&levels, bakes, brdfs, &per_direction)
}

/// The errors from the sums of every direction and level (`per_direction[d][k][b · ns + si]`),
/// added over the directions in order.
fn errors(
    levels: &[LevelFootprints],
    bakes: &[&Bake],
    brdfs: &[Brdf],
    per_direction: &[Vec<Vec<[f64; 4]>>],
) -> Vec<MethodError> {
    let ns = brdfs.len();
    let mut total = vec![vec![[0.0f64; 4]; bakes.len() * ns]; levels.len()];
    for d in per_direction {
        for (t, s) in total.iter_mut().zip(d) {
            for (t, s) in t.iter_mut().zip(s) {
                for c in 0..4 {
                    t[c] += s[c];
                }
            }
        }
    }
    let rel = relative_rms;
    let mut out = Vec::new();
    for (b, bake) in bakes.iter().enumerate() {
        for (si, brdf) in brdfs.iter().enumerate() {
            let levels_err: Vec<LevelError> = levels
                .iter()
                .enumerate()
                .map(|(k, lf)| {
                    let e = total[k][b * ns + si];
                    LevelError {
                        level: k,
                        width: lf.size.0,
                        height: lf.size.1,
                        diffuse: rel(e[0], e[1]),
                        specular: rel(e[2], e[3]),
                    }
                })
                .collect();
            let coarse = if levels_err.len() > 1 {
                &levels_err[1..]
            } else {
                &levels_err[..]
            };
            let rms = |f: fn(&LevelError) -> f64| {
                (coarse.iter().map(|e| f(e).powi(2)).sum::<f64>() / coarse.len() as f64).sqrt()
            };
            out.push(MethodError {
                method: bake.method,
                label: bake.label(),
                format: bake.format,
                brdf: brdf.clone(),
                overall_diffuse: rms(|e| e.diffuse),
                overall_specular: rms(|e| e.specular),
                levels: levels_err,
            });
        }
    }
    out
}

/// The exact side of [`evaluate_from`] for one map, kept: every level's footprint averages for
/// every light/view pair and BRDF, so that many bakes of the map ([`Reference::evaluate`], a
/// report's configurations) share them. Its errors are [`evaluate_from`]'s, bit for bit.
/// Memory: [`Reference::bytes`].
pub struct Reference {
    levels: Vec<LevelFootprints>,
    brdfs: Vec<Brdf>,
    directions: Vec<LightView>,
    first_level: usize,
    /// `exact[d][k]`: [`exact_levels`] of direction d.
    exact: Vec<Vec<Vec<f64>>>,
}

impl Reference {
    /// The exact answers of `map` for `brdfs` and `directions`, levels `first_level` and coarser.
    pub fn new(
        map: &NormalMap,
        brdfs: &[Brdf],
        directions: &[LightView],
        first_level: usize,
    ) -> Reference {
        let levels = pyramid(map.width(), map.height());
        let exact = directions
            .par_iter()
            .map(|&lv| exact_levels(map, &levels, brdfs, lv, first_level))
            .collect();
        Reference {
            levels,
            brdfs: brdfs.to_vec(),
            directions: directions.to_vec(),
            first_level,
            exact,
        }
    }

    /// Bytes a [`Reference`] of a `width × height` map holds for `brdfs` BRDFs and `directions`
    /// light/view pairs, levels `first_level` and coarser.
    pub fn bytes(
        width: u32,
        height: u32,
        brdfs: usize,
        directions: usize,
        first_level: usize,
    ) -> u64 {
        let texels: u64 = crate::pyramid::level_sizes(width, height)
            .iter()
            .skip(first_level)
            .map(|&(w, h)| w as u64 * h as u64)
            .sum();
        texels * (1 + brdfs as u64) * 8 * directions as u64
    }

    /// [`evaluate_from`] of `bakes` (baked from this reference's map) with this reference's
    /// BRDFs, directions and first level. Every (direction, level, bake) is a task of its own:
    /// each sum still runs over its level's texels in order, so the results are the same.
    pub fn evaluate(&self, bakes: &[&Bake]) -> Vec<MethodError> {
        self.evaluate_levels(bakes, self.first_level..=usize::MAX)
    }

    /// [`Reference::evaluate`] at the levels of `levels` only (and at or coarser than the
    /// reference's first level; the other levels' errors are 0): what a planner measuring one
    /// level range needs. The errors it gives are [`Reference::evaluate`]'s at those levels.
    pub fn evaluate_levels(
        &self,
        bakes: &[&Bake],
        levels: std::ops::RangeInclusive<usize>,
    ) -> Vec<MethodError> {
        let (nl, ns) = (self.levels.len(), self.brdfs.len());
        let from = self.first_level.max(*levels.start());
        let to = (*levels.end()).min(nl.saturating_sub(1));
        let tasks: Vec<(usize, usize, usize)> = (0..self.directions.len())
            .flat_map(|d| (from..=to).map(move |k| (d, k)))
            .flat_map(|(d, k)| (0..bakes.len()).map(move |b| (d, k, b)))
            .collect();
        let sums: Vec<Vec<[f64; 4]>> = tasks
            .par_iter()
            .map(|&(d, k, b)| {
                level_sums(
                    &bakes[b..b + 1],
                    &self.brdfs,
                    &self.exact[d][k],
                    k,
                    self.directions[d],
                    &ShadeOptions::default(),
                )
            })
            .collect();
        let empty = vec![[0.0; 4]; bakes.len() * ns];
        let mut per_direction = vec![vec![empty; nl]; self.directions.len()];
        for (&(d, k, b), s) in tasks.iter().zip(sums) {
            per_direction[d][k][b * ns..(b + 1) * ns].copy_from_slice(&s);
        }
        errors(&self.levels, bakes, &self.brdfs, &per_direction)
    }
}

/// `sqrt(num/den)` for sums `num = Σ(F − G)²`, `den = ΣG²`: infinite when the reference is
/// zero but the estimate is not, 0 when both are.
pub fn relative_rms(num: f64, den: f64) -> f64 {
    if den > 0.0 {
        (num / den).sqrt()
    } else if num > 0.0 {
        f64::INFINITY
    } else {
        0.0
    }
}

/// Formats errors as plain-text tables, one per exponent: a row per level, a diffuse and a
/// specular column per method, and a closing row with the overall (levels ≥ 1) error (level 0's
/// for a 1×1 map, which has no other).
pub fn format_table(errors: &[MethodError]) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    let mut brdfs: Vec<Brdf> = Vec::new();
    for e in errors {
        if !brdfs.contains(&e.brdf) {
            brdfs.push(e.brdf.clone());
        }
    }
    for brdf in brdfs {
        let rows: Vec<&MethodError> = errors.iter().filter(|e| e.brdf == brdf).collect();
        let _ = writeln!(
            out,
            "{brdf}: relative RMS error against the exact footprint average"
        );
        let _ = write!(out, "{:>5} {:>11}", "level", "size");
        for r in &rows {
            let _ = write!(out, " | {:^17}", r.label);
        }
        let _ = write!(out, "\n{:>5} {:>11}", "", "");
        for _ in &rows {
            let _ = write!(out, " | {:>8} {:>8}", "diffuse", "specular");
        }
        out.push('\n');
        // Lambert has no specular term: its column shows a dash.
        let spec = |v: f64| {
            if brdf.has_specular() {
                format!("{v:>8.5}")
            } else {
                format!("{:>8}", "-")
            }
        };
        for k in 0..rows[0].levels.len() {
            let l = &rows[0].levels[k];
            let _ = write!(out, "{:>5} {:>11}", k, format!("{}x{}", l.width, l.height));
            for r in &rows {
                let _ = write!(
                    out,
                    " | {:>8.5} {}",
                    r.levels[k].diffuse,
                    spec(r.levels[k].specular)
                );
            }
            out.push('\n');
        }
        // A 1×1 map has no level 1: its overall error is level 0's.
        let overall = if rows[0].levels.len() > 1 {
            "levels 1+"
        } else {
            "level 0"
        };
        let _ = write!(out, "{:>5} {:>11}", "all", overall);
        for r in &rows {
            let _ = write!(
                out,
                " | {:>8.5} {}",
                r.overall_diffuse,
                spec(r.overall_specular)
            );
        }
        out.push_str("\n\n");
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ingest::{Addressing, BadNormals};
    use crate::methods::bake;
    use glam::Vec3;

    /// The BRDF library's sharpness bounds (`brdf::MAX_EXPONENT`, `MIN_SIGMA`, `MIN_ALPHA`):
    /// at them every method's error on a bumpy map is finite (the exact footprint average stays
    /// above 0 in f64 at the light/view pairs), and just past them `Brdf::validate` refuses.
    /// (On the hostile sweep's 32² map, s = 10⁸ made the exact average 0 at every pair and
    /// `eval` printed `inf`; this procedural map stays finite further, so the test holds the
    /// bounds and the finiteness at them, not the failure past them.)
    #[test]
    fn the_sharpest_brdfs_accepted_give_finite_errors() {
        use crate::brdf::{MAX_EXPONENT, MIN_ALPHA, MIN_SIGMA};
        let map = crate::procedural::generate(32, 3).map;
        let bakes: Vec<Bake> = [
            Method::Plain,
            Method::Toksvig,
            Method::Lean,
            Method::Olano,
            Method::Sh,
            Method::Tan2005,
            Method::Vmf,
        ]
        .into_iter()
        .map(|m| bake(&map, m))
        .collect();
        let refs: Vec<&Bake> = bakes.iter().collect();
        let at = [
            Brdf::BlinnPhong { s: MAX_EXPONENT },
            Brdf::TorranceSparrow { sigma: MIN_SIGMA },
            Brdf::ggx(MIN_ALPHA),
        ];
        for b in &at {
            b.validate().unwrap();
        }
        for e in evaluate(&map, &refs, &at, &default_directions()) {
            for l in &e.levels {
                assert!(
                    l.diffuse.is_finite() && l.specular.is_finite(),
                    "{} {}: level {} {} / {}",
                    e.label,
                    e.brdf,
                    l.level,
                    l.diffuse,
                    l.specular
                );
            }
        }
        for b in [
            Brdf::BlinnPhong {
                s: MAX_EXPONENT * 1.01,
            },
            Brdf::TorranceSparrow {
                sigma: MIN_SIGMA * 0.99,
            },
            Brdf::ggx(MIN_ALPHA * 0.99),
            Brdf::BlinnPhong { s: f64::NAN },
        ] {
            assert!(b.validate().is_err(), "{b}");
        }
    }

    fn map(w: u32, h: u32, f: impl Fn(u32, u32) -> Vec3) -> NormalMap {
        let v = (0..w * h).map(|i| f(i % w, i / w)).collect();
        NormalMap::from_vectors(w, h, v, Addressing::Wrap, BadNormals::Repair).unwrap()
    }

    /// The Lambert error vMF's mean-vector diffuse term has on identical normals: `1 − |r|`
    /// with |r| capped at `vmf::R_MAX` (2.4e-7).
    fn vmf_diffuse_cap(method: Method) -> f64 {
        if method == Method::Vmf {
            1.0 - crate::vmf::R_MAX
        } else {
            0.0
        }
    }

    /// The relative error the mixtures' sharpness cap allows at level 0 (`2 s / KAPPA_MAX`:
    /// vMF κ ≤ KAPPA_MAX, Tan σ² ≥ 1/KAPPA_MAX), 0 otherwise.
    fn vmf_cap(method: Method, s: f64) -> f64 {
        if matches!(method, Method::Vmf | Method::Tan2005) {
            2.0 * s / crate::vmf::KAPPA_MAX
        } else {
            0.0
        }
    }

    #[test]
    fn a_kept_reference_gives_evaluate_from_bit_for_bit() {
        let m = map(13, 10, |x, y| {
            Vec3::new(
                (x as f32 * 0.9).sin() * 0.6,
                (y as f32 * 1.3).cos() * 0.5,
                1.0,
            )
        });
        let bakes: Vec<Bake> = [Method::Toksvig, Method::Vmf]
            .iter()
            .map(|&me| bake(&m, me))
            .collect();
        let refs: Vec<&Bake> = bakes.iter().collect();
        let brdfs = [
            Brdf::BlinnPhong { s: 32.0 },
            Brdf::TorranceSparrow { sigma: 0.2 },
        ];
        let dirs: Vec<LightView> = default_directions().into_iter().step_by(4).collect();
        for first in [0, 1, 2] {
            let r = Reference::new(&m, &brdfs, &dirs, first);
            assert_eq!(
                r.evaluate(&refs),
                evaluate_from(&m, &refs, &brdfs, &dirs, first),
                "first level {first}"
            );
        }
        // 13×10: levels 6×5, 3×2 and 1×1 from level 1 on; 1 + 2 channels per texel, 7 pairs.
        assert_eq!(Reference::bytes(13, 10, 2, 7, 1), (30 + 6 + 1) * 3 * 8 * 7);
    }

    #[test]
    fn sh_error_at_level_zero_is_the_truncation_of_the_lobe() {
        // Identical normals: the NDF is a delta and eq 12 gives the truncated SH series of the
        // BRDF; l* = 16 makes Blinn-Phong s = 8 (√(4s) ≈ 6) and Lambert (1/l decay) small.
        let m = map(4, 4, |_, _| Vec3::new(0.2, -0.1, 1.0));
        let o = crate::bake::BakeOptions {
            lmax: 16,
            ..Default::default()
        };
        let b = crate::methods::bake_with(&m, Method::Sh, &o).unwrap();
        let e = &evaluate(
            &m,
            &[&b],
            &[Brdf::BlinnPhong { s: 8.0 }],
            &default_directions(),
        )[0];
        for l in &e.levels {
            assert!(l.diffuse < 0.006 && l.specular < 0.01, "{l:?}");
        }
    }

    #[test]
    fn error_is_zero_at_level_zero_for_every_method() {
        let m = map(9, 7, |x, y| {
            Vec3::new(
                (x as f32 * 1.7).sin() * 0.5,
                (y as f32 * 0.8).cos() * 0.4,
                1.0,
            )
        });
        // SH is exact only up to its band limit (sh_error_at_level_zero_is_the_truncation…).
        let bakes: Vec<Bake> = Method::ALL
            .iter()
            .filter(|&&me| me != Method::Sh)
            .map(|&me| bake(&m, me))
            .collect();
        let refs: Vec<&Bake> = bakes.iter().collect();
        for e in evaluate(
            &m,
            &refs,
            &[
                Brdf::blinn_phong(&[8.0, 64.0, 2048.0]),
                vec![
                    Brdf::TorranceSparrow { sigma: 0.05 },
                    Brdf::TorranceSparrow { sigma: 0.3 },
                    Brdf::ggx(0.05),
                    Brdf::ggx(0.5),
                ],
            ]
            .concat(),
            &default_directions(),
        ) {
            // f32 storage of the moments is the only difference at level 0 — and for vMF the
            // κ cap, which makes s' = s(1 − s/KAPPA_MAX) (Algorithm 2 line 12).
            assert!(
                e.levels[0].diffuse < 1e-6,
                "{} {}",
                e.method,
                e.levels[0].diffuse
            );
            assert!(
                e.levels[0].specular < 1e-4 + vmf_cap(e.method, e.brdf.equivalent_exponent()),
                "{} s={} {}",
                e.method,
                e.brdf,
                e.levels[0].specular
            );
            assert!(
                e.levels[1].specular > 1e-3,
                "a bumpy map has filtering error at level 1"
            );
        }
    }

    #[test]
    fn error_is_zero_at_every_level_for_a_flat_map() {
        for (w, h) in [(8, 8), (5, 3), (1, 1)] {
            let m = map(w, h, |_, _| Vec3::Z);
            let bakes: Vec<Bake> = Method::ALL
                .iter()
                .filter(|&&me| me != Method::Sh)
                .map(|&me| bake(&m, me))
                .collect();
            let refs: Vec<&Bake> = bakes.iter().collect();
            for e in evaluate(
                &m,
                &refs,
                &[
                    Brdf::blinn_phong(&[1.0, 256.0]),
                    vec![Brdf::TorranceSparrow { sigma: 0.1 }, Brdf::ggx(0.2)],
                ]
                .concat(),
                &default_directions(),
            ) {
                // Zero up to the f64 rounding of the footprint sums (~1e-16), and the κ cap.
                for l in &e.levels {
                    assert!(
                        l.diffuse < 1e-12 + vmf_diffuse_cap(e.method)
                            && l.specular < 1e-12 + vmf_cap(e.method, e.brdf.equivalent_exponent()),
                        "{} level {}: {l:?}",
                        e.method,
                        l.level
                    );
                }
            }
        }
    }

    #[test]
    fn table_has_one_block_per_exponent_and_a_column_per_bake() {
        let m = map(4, 4, |x, _| Vec3::new(x as f32 * 0.2, 0.0, 1.0));
        let (a, b) = (bake(&m, Method::Plain), bake(&m, Method::Lean));
        let errors = evaluate(
            &m,
            &[&a, &b],
            &Brdf::blinn_phong(&[16.0, 64.0]),
            &default_directions(),
        );
        let t = format_table(&errors);
        assert_eq!(t.matches("Blinn-Phong s =").count(), 2, "{t}");
        assert_eq!(t.matches(" plain ").count(), 2, "{t}");
        assert_eq!(t.matches(" lean ").count(), 2, "{t}");
    }

    #[test]
    fn result_does_not_depend_on_thread_count() {
        let m = map(16, 16, |x, y| {
            Vec3::new((x as f32).sin() * 0.7, (y as f32 * 2.1).sin() * 0.7, 1.0)
        });
        let b = bake(&m, Method::Toksvig);
        let run = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| {
                    evaluate(
                        &m,
                        &[&b],
                        &Brdf::blinn_phong(&[32.0]),
                        &default_directions(),
                    )
                })
        };
        assert_eq!(run(1), run(3));
    }
}
