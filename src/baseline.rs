//! The baseline filters the paper compares with, each a set of moments of the normals that
//! filter linearly, box-filtered over the exact footprints of [`crate::pyramid`]:
//!
//! - **plain mip**: mean normal `E[n]`, stored normalized;
//! - **Toksvig** (Toksvig 2005): `E[n]` stored unnormalized, `|E[n]|` in alpha;
//! - **LEAN** (Olano & Baker 2010): slopes `b = n_xy / n_z` and their second moments
//!   `E[b]`, `E[b bᵀ]`; `n_z` is clamped to [`LEAN_MIN_Z`] so slopes stay finite (|b| ≤ 100)
//!   for normals on the horizon;
//! - **Olano–North 1997** (`papers/olano1997-normal-distribution-mapping.md` Sec 5): the nine
//!   linear moments of a 3D Gaussian, `E[n]` (3) and `E[n nᵀ]` (6).
//!
//! Moments are accumulated in f64 and stored as f32. Shading from them is in module `shade`.

use crate::bake::{Bake, Method, Progress, Texture};
use crate::error::Result;
use crate::format::{Format, ValueRange};
use crate::ingest::NormalMap;
use crate::pyramid::{pyramid, reduce};
use glam::Vec3;
use rayon::prelude::*;

/// Smallest `n_z` used for LEAN slopes: normals closer to the horizon are treated as this
/// steep, so `|b| ≤ 1/LEAN_MIN_Z` and the second moments fit in f16 (≤ 10⁴).
pub const LEAN_MIN_Z: f64 = 0.01;

/// Number of f64 moments each method accumulates per texel.
pub(crate) fn moment_count(method: Method) -> usize {
    match method {
        Method::Plain | Method::Toksvig => 3,
        Method::Lean => 5,
        Method::Olano => 9,
        Method::Vmf | Method::Tan2005 | Method::Sh | Method::Pbr => {
            unreachable!("baked by modules mixture, sh and pbr")
        }
    }
}

/// The per-normal moments of `method` (the quantities whose footprint averages are baked).
fn moments(method: Method, n: Vec3, out: &mut [f64]) {
    let (x, y, z) = (n.x as f64, n.y as f64, n.z as f64);
    match method {
        Method::Plain | Method::Toksvig => out.copy_from_slice(&[x, y, z]),
        Method::Lean => {
            let zc = z.max(LEAN_MIN_Z);
            let (bx, by) = (x / zc, y / zc);
            out.copy_from_slice(&[bx, by, bx * bx, by * by, bx * by]);
        }
        Method::Olano => out.copy_from_slice(&[x, y, z, x * x, y * y, z * z, x * y, x * z, y * z]),
        Method::Vmf | Method::Tan2005 | Method::Sh | Method::Pbr => {
            unreachable!("baked by modules mixture, sh and pbr")
        }
    }
}

/// Texture names, channel meanings and value ranges of `method`.
pub(crate) fn layout(method: Method) -> Vec<(&'static str, [&'static str; 4], [ValueRange; 4])> {
    use ValueRange::{Any, Signed as S, Unit as U};
    match method {
        Method::Vmf | Method::Tan2005 | Method::Sh | Method::Pbr => {
            unreachable!("baked by modules mixture, sh and pbr")
        }
        Method::Plain => vec![("normal", ["n_x", "n_y", "n_z", "unused"], [S, S, S, U])],
        Method::Toksvig => vec![(
            "mean",
            ["mean_x", "mean_y", "mean_z", "mean_length"],
            [S, S, S, U],
        )],
        Method::Lean => vec![
            (
                "slopes",
                ["E[b_x]", "E[b_y]", "E[b_x^2]", "E[b_y^2]"],
                [Any; 4],
            ),
            (
                "cross",
                ["E[b_x*b_y]", "unused", "unused", "unused"],
                [Any, U, U, U],
            ),
        ],
        Method::Olano => vec![
            (
                "mean",
                ["E[n_x]", "E[n_y]", "E[n_z]", "unused"],
                [S, S, S, U],
            ),
            (
                "diagonal",
                ["E[n_x^2]", "E[n_y^2]", "E[n_z^2]", "unused"],
                [U; 4],
            ),
            (
                "offdiagonal",
                ["E[n_x*n_y]", "E[n_x*n_z]", "E[n_y*n_z]", "unused"],
                [S, S, S, U],
            ),
        ],
    }
}

/// Turns one texel's averaged moments into its RGBA values (one per texture).
fn finalize(method: Method, m: &[f64], out: &mut [[f32; 4]]) {
    let f = |v: f64| v as f32;
    match method {
        Method::Plain => {
            let len = (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt();
            out[0] = if len > 1e-12 {
                [f(m[0] / len), f(m[1] / len), f(m[2] / len), 0.0]
            } else {
                [0.0, 0.0, 1.0, 0.0]
            };
        }
        Method::Toksvig => {
            let len = (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt();
            out[0] = [f(m[0]), f(m[1]), f(m[2]), f(len.min(1.0))];
        }
        Method::Lean => {
            out[0] = [f(m[0]), f(m[1]), f(m[2]), f(m[3])];
            out[1] = [f(m[4]), 0.0, 0.0, 0.0];
        }
        Method::Vmf | Method::Tan2005 | Method::Sh | Method::Pbr => {
            unreachable!("baked by modules mixture, sh and pbr")
        }
        Method::Olano => {
            out[0] = [f(m[0]), f(m[1]), f(m[2]), 0.0];
            out[1] = [f(m[3]), f(m[4]), f(m[5]), 0.0];
            out[2] = [f(m[6]), f(m[7]), f(m[8]), 0.0];
        }
    }
}

/// Bakes a baseline method: moments at the finest level, box-filtered onto every level,
/// reporting progress after each level.
pub(crate) fn bake(map: &NormalMap, method: Method, progress: &mut Progress) -> Result<Bake> {
    let (w, h) = (map.width(), map.height());
    let c = moment_count(method);
    let mut finest = vec![0.0f64; w as usize * h as usize * c];
    finest
        .par_chunks_mut(c)
        .zip(map.normals().par_iter())
        .for_each(|(o, &n)| moments(method, n, o));
    let layout = layout(method);
    let mut textures: Vec<Texture> = layout
        .iter()
        .map(|&(name, channels, ranges)| Texture {
            name,
            channels,
            ranges,
            levels: Vec::new(),
        })
        .collect();
    let levels = pyramid(w, h);
    let cancel = progress.cancel_flag();
    for (k, lf) in levels.iter().enumerate() {
        progress.report(k as f64 / levels.len() as f64)?;
        let avg = reduce(&finest, c, w, lf);
        let texels = (lf.size.0 * lf.size.1) as usize;
        let mut per_texture = vec![vec![[0.0f32; 4]; texels]; textures.len()];
        let mut scratch = vec![[0.0f32; 4]; textures.len()];
        for (i, m) in avg.chunks_exact(c).enumerate() {
            // A large level takes a while: the cancellation flag is polled as it goes.
            if i % (1 << 16) == 0 {
                cancel.check()?;
            }
            finalize(method, m, &mut scratch);
            for (t, v) in per_texture.iter_mut().zip(&scratch) {
                t[i] = *v;
            }
        }
        for (t, level) in textures.iter_mut().zip(per_texture) {
            t.levels.push(level);
        }
        progress.report((k + 1) as f64 / levels.len() as f64)?;
    }
    Ok(Bake {
        method,
        sizes: levels.iter().map(|l| l.size).collect(),
        textures,
        addressing: map.addressing(),
        lobes: 0,
        parameters: serde_json::json!({}),
        format: Format::F32,
    })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::ingest::{Addressing, BadNormals};
    use glam::DVec3;

    /// A small deterministic bumpy map of any size (also the SH bake's tests).
    pub(crate) fn test_map(w: u32, h: u32) -> NormalMap {
        let v = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                Vec3::new((x * 0.9).sin() * 0.6, (y * 1.3 + x * 0.2).cos() * 0.5, 1.0)
            })
            .collect();
        NormalMap::from_vectors(w, h, v, Addressing::Wrap, BadNormals::Repair).unwrap()
    }

    /// Direct footprint average of `f(n)` over texel (x, y) of `level`.
    fn direct<const K: usize>(
        map: &NormalMap,
        level: usize,
        x: u32,
        y: u32,
        f: impl Fn(DVec3) -> [f64; K],
    ) -> [f64; K] {
        let lf = &pyramid(map.width(), map.height())[level];
        let mut s = [0.0; K];
        for (fx, fy, wt) in lf.texel(x, y) {
            let v = f(map.normal(fx, fy).as_dvec3());
            for k in 0..K {
                s[k] += wt * v[k];
            }
        }
        s
    }

    fn close(a: f32, b: f64) {
        assert!((a as f64 - b).abs() <= 1e-6 * (1.0 + b.abs()), "{a} vs {b}");
    }

    #[test]
    fn every_baseline_matches_a_direct_moment_computation() {
        let map = test_map(13, 6);
        for method in Method::BASELINES {
            let b = crate::methods::bake(&map, method);
            assert_eq!(b.sizes, crate::pyramid::level_sizes(13, 6));
            for level in 0..b.level_count() {
                let (lw, lh) = b.sizes[level];
                for (x, y) in [(0, 0), (lw - 1, lh - 1), (lw / 2, lh / 2)] {
                    let t = b.texel(level, x, y);
                    match method {
                        Method::Plain | Method::Toksvig => {
                            let m = direct(&map, level, x, y, |n| [n.x, n.y, n.z]);
                            let len = (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt();
                            let k = if method == Method::Plain {
                                1.0 / len
                            } else {
                                1.0
                            };
                            for c in 0..3 {
                                close(t[0][c], m[c] * k);
                            }
                            if method == Method::Toksvig {
                                close(t[0][3], len);
                            }
                        }
                        Method::Lean => {
                            let m = direct(&map, level, x, y, |n| {
                                let (bx, by) = (n.x / n.z, n.y / n.z);
                                [bx, by, bx * bx, by * by, bx * by]
                            });
                            for c in 0..4 {
                                close(t[0][c], m[c]);
                            }
                            close(t[1][0], m[4]);
                        }
                        Method::Vmf | Method::Tan2005 | Method::Sh | Method::Pbr => {
                            unreachable!("not a baseline")
                        }
                        Method::Olano => {
                            let m = direct(&map, level, x, y, |n| {
                                [
                                    n.x,
                                    n.y,
                                    n.z,
                                    n.x * n.x,
                                    n.y * n.y,
                                    n.z * n.z,
                                    n.x * n.y,
                                    n.x * n.z,
                                    n.y * n.z,
                                ]
                            });
                            for c in 0..3 {
                                close(t[0][c], m[c]);
                                close(t[1][c], m[3 + c]);
                                close(t[2][c], m[6 + c]);
                            }
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn coarsest_level_is_the_mean_of_the_whole_map() {
        let map = test_map(8, 8);
        let b = crate::methods::bake(&map, Method::Toksvig);
        let mean: DVec3 = map.normals().iter().map(|n| n.as_dvec3()).sum::<DVec3>() / 64.0;
        let t = b.texel(b.level_count() - 1, 0, 0)[0];
        for c in 0..3 {
            close(t[c], mean[c]);
        }
    }
}
