//! MIP pyramid geometry: level sizes, and which finest texels each coarser texel covers.
//!
//! **Level sizes** follow OpenGL: level k+1 is `max(1, floor(w_k / 2)) × max(1, floor(h_k / 2))`,
//! down to 1×1.
//!
//! **Footprint rule** (the exact box footprint, for any size): texel `x` of a level that is
//! `c` texels wide covers the texture-coordinate interval `[x/c, (x+1)/c)`. Finest texel `i` of a
//! map `f` texels wide covers `[i/f, (i+1)/f)`. The footprint of the coarse texel is every finest
//! texel its interval overlaps, weighted by the overlapped fraction of the coarse texel, so the
//! weights sum to 1. For power-of-two sizes this is the usual 2^k × 2^k block with equal weights;
//! for odd sizes a finest texel on a boundary is shared between two coarse texels (a 5-wide map
//! at level 1 is 2 wide: texel 0 covers finest 0, 1 fully and half of 2, with weights 0.4, 0.4,
//! 0.2). Footprints are separable: the 2D weight is the product of the two axes' weights.
//! Weights are exact rationals `overlap / f` computed in integers.
//!
//! Texel footprints never leave the texture, so addressing does not change them. Addressing
//! matters for footprints of arbitrary intervals (a screen pixel's footprint, a filter wider than
//! a texel) and for bilinear taps: [`interval_footprint`] and [`bilinear_taps`] wrap or clamp.

use crate::ingest::Addressing;
use rayon::prelude::*;

/// Width and height of every MIP level, finest first, down to 1×1.
pub fn level_sizes(width: u32, height: u32) -> Vec<(u32, u32)> {
    let (mut w, mut h) = (width.max(1), height.max(1));
    let mut sizes = vec![(w, h)];
    while w > 1 || h > 1 {
        w = (w / 2).max(1);
        h = (h / 2).max(1);
        sizes.push((w, h));
    }
    sizes
}

/// One axis of the footprints of a whole level: for each coarse index, the finest indices it
/// covers and their weights (compressed rows).
#[derive(Debug, Clone, PartialEq)]
pub struct AxisFootprints {
    /// `start[c]..start[c + 1]` indexes `index` and `weight` for coarse texel `c`.
    start: Vec<usize>,
    index: Vec<u32>,
    weight: Vec<f64>,
}

impl AxisFootprints {
    /// Exact box footprints of a `coarse`-texel axis over a `fine`-texel axis (module docs).
    pub fn new(fine: u32, coarse: u32) -> Self {
        assert!(fine >= 1 && coarse >= 1 && coarse <= fine);
        // In units of 1/(fine*coarse) of the texture: coarse texel x covers [x*fine, (x+1)*fine),
        // finest texel i covers [i*coarse, (i+1)*coarse).
        let (f, c) = (fine as u64, coarse as u64);
        let mut start = Vec::with_capacity(coarse as usize + 1);
        let mut index = Vec::new();
        let mut weight = Vec::new();
        for x in 0..c {
            start.push(index.len());
            let (lo, hi) = (x * f, (x + 1) * f);
            for i in (lo / c)..hi.div_ceil(c) {
                let overlap = hi.min((i + 1) * c) - lo.max(i * c);
                if overlap > 0 {
                    index.push(i as u32);
                    weight.push(overlap as f64 / f as f64);
                }
            }
        }
        start.push(index.len());
        Self {
            start,
            index,
            weight,
        }
    }

    /// Number of coarse texels.
    pub fn len(&self) -> usize {
        self.start.len() - 1
    }

    /// Whether the axis has no coarse texels (never, for a valid level).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Finest indices and weights covered by coarse texel `c`.
    pub fn taps(&self, c: usize) -> impl Iterator<Item = (u32, f64)> + '_ {
        let r = self.start[c]..self.start[c + 1];
        self.index[r.clone()]
            .iter()
            .copied()
            .zip(self.weight[r].iter().copied())
    }
}

/// Footprints of one whole level over the finest level (both axes).
#[derive(Debug, Clone, PartialEq)]
pub struct LevelFootprints {
    /// Level width and height.
    pub size: (u32, u32),
    /// Along x.
    pub x: AxisFootprints,
    /// Along y.
    pub y: AxisFootprints,
}

impl LevelFootprints {
    /// Footprints of a `size` level over a `finest` map.
    pub fn new(finest: (u32, u32), size: (u32, u32)) -> Self {
        Self {
            size,
            x: AxisFootprints::new(finest.0, size.0),
            y: AxisFootprints::new(finest.1, size.1),
        }
    }

    /// The finest texels `(x, y, weight)` covered by texel `(cx, cy)`; weights sum to 1.
    pub fn texel(&self, cx: u32, cy: u32) -> Vec<(u32, u32, f64)> {
        let mut out = Vec::new();
        for (fy, wy) in self.y.taps(cy as usize) {
            for (fx, wx) in self.x.taps(cx as usize) {
                out.push((fx, fy, wx * wy));
            }
        }
        out
    }
}

/// Footprints of every level of a `width × height` map, finest first (level 0 covers itself).
pub fn pyramid(width: u32, height: u32) -> Vec<LevelFootprints> {
    level_sizes(width, height)
        .into_iter()
        .map(|s| LevelFootprints::new((width, height), s))
        .collect()
}

/// Box-filters an interleaved `channels`-per-texel image of the finest level onto a level:
/// every output texel is the footprint-weighted mean of the finest values it covers. Sums are
/// f64 and in a fixed order, so the result does not depend on the thread count.
pub fn reduce(
    finest: &[f64],
    channels: usize,
    finest_width: u32,
    level: &LevelFootprints,
) -> Vec<f64> {
    let fw = finest_width as usize;
    let fh = finest.len() / (channels * fw);
    let (cw, ch) = (level.size.0 as usize, level.size.1 as usize);
    if cw == fw && ch == fh {
        return finest.to_vec();
    }
    // Pass 1: along x, every finest row → cw texels.
    let mut rows = vec![0.0f64; fh * cw * channels];
    rows.par_chunks_mut(cw * channels)
        .enumerate()
        .for_each(|(y, out)| {
            let src = &finest[y * fw * channels..(y + 1) * fw * channels];
            for cx in 0..cw {
                let o = &mut out[cx * channels..(cx + 1) * channels];
                for (fx, w) in level.x.taps(cx) {
                    let s = &src[fx as usize * channels..(fx as usize + 1) * channels];
                    for (a, b) in o.iter_mut().zip(s) {
                        *a += w * b;
                    }
                }
            }
        });
    // Pass 2: along y.
    let mut out = vec![0.0f64; ch * cw * channels];
    out.par_chunks_mut(cw * channels)
        .enumerate()
        .for_each(|(cy, o)| {
            for (fy, w) in level.y.taps(cy) {
                let s = &rows[fy as usize * cw * channels..(fy as usize + 1) * cw * channels];
                for (a, b) in o.iter_mut().zip(s) {
                    *a += w * b;
                }
            }
        });
    out
}

/// Finest texels `(index, weight)` covered by the interval `[a, b)` of a `texels`-wide axis,
/// in texel units (so `[0, texels)` is the whole map). Parts outside the map wrap around or
/// clamp to the edge texel per `addressing`. Weights are overlap / (b − a) and sum to 1; an
/// empty interval (b ≤ a) is the point sample at `a`.
pub fn interval_footprint(a: f64, b: f64, texels: u32, addressing: Addressing) -> Vec<(u32, f64)> {
    let n = texels as i64;
    let resolve = |i: i64| -> u32 {
        match addressing {
            Addressing::Wrap => i.rem_euclid(n) as u32,
            Addressing::Clamp => i.clamp(0, n - 1) as u32,
        }
    };
    if b <= a || !(b - a).is_finite() {
        return vec![(resolve(a.floor() as i64), 1.0)];
    }
    let len = b - a;
    let mut out: Vec<(u32, f64)> = Vec::new();
    let mut i = a.floor() as i64;
    while (i as f64) < b {
        let overlap = b.min((i + 1) as f64) - a.max(i as f64);
        if overlap > 0.0 {
            let t = resolve(i);
            match out.iter_mut().find(|(k, _)| *k == t) {
                Some(e) => e.1 += overlap / len,
                None => out.push((t, overlap / len)),
            }
        }
        i += 1;
    }
    out
}

/// The two texels and weights that GL's linear filter uses along one axis at texture coordinate
/// `u` on a `texels`-wide level: `x = u·texels − 0.5`, texels `floor(x)` and `floor(x) + 1` with
/// weights `1 − frac(x)` and `frac(x)`, wrapped or clamped per `addressing`.
pub fn bilinear_taps(u: f64, texels: u32, addressing: Addressing) -> [(u32, f64); 2] {
    let x = u * texels as f64 - 0.5;
    let x0 = x.floor();
    let f = x - x0;
    let n = texels as i64;
    let resolve = |i: i64| -> u32 {
        match addressing {
            Addressing::Wrap => i.rem_euclid(n) as u32,
            Addressing::Clamp => i.clamp(0, n - 1) as u32,
        }
    };
    [(resolve(x0 as i64), 1.0 - f), (resolve(x0 as i64 + 1), f)]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn level_sizes_follow_gl_floor_rule() {
        assert_eq!(level_sizes(1, 1), vec![(1, 1)]);
        assert_eq!(level_sizes(4, 4), vec![(4, 4), (2, 2), (1, 1)]);
        assert_eq!(
            level_sizes(5, 3),
            vec![(5, 3), (2, 1), (1, 1)],
            "odd sizes halve with floor"
        );
        assert_eq!(level_sizes(16384, 16).len(), 15);
        assert_eq!(level_sizes(4097, 3).last(), Some(&(1, 1)));
        assert_eq!(level_sizes(1, 7), vec![(1, 7), (1, 3), (1, 1)]);
    }

    #[test]
    fn power_of_two_footprints_are_equal_weight_blocks() {
        let a = AxisFootprints::new(8, 2);
        let t0: Vec<_> = a.taps(0).collect();
        assert_eq!(t0, (0..4).map(|i| (i, 0.25)).collect::<Vec<_>>());
        let t1: Vec<_> = a.taps(1).collect();
        assert_eq!(t1, (4..8).map(|i| (i, 0.25)).collect::<Vec<_>>());
    }

    #[test]
    fn odd_size_footprints_share_boundary_texels() {
        // 5 → 2: texel 0 covers [0, 2.5): 0, 1 fully, 2 half.
        let a = AxisFootprints::new(5, 2);
        assert_eq!(
            a.taps(0).collect::<Vec<_>>(),
            vec![(0, 0.4), (1, 0.4), (2, 0.2)]
        );
        assert_eq!(
            a.taps(1).collect::<Vec<_>>(),
            vec![(2, 0.2), (3, 0.4), (4, 0.4)]
        );
        // 7 → 3: each covers 7/3 texels.
        let a = AxisFootprints::new(7, 3);
        let t1: Vec<_> = a.taps(1).collect();
        assert_eq!(t1.iter().map(|t| t.0).collect::<Vec<_>>(), vec![2, 3, 4]);
        assert!((t1[0].1 - 2.0 / 7.0).abs() < 1e-15);
        assert!((t1[1].1 - 3.0 / 7.0).abs() < 1e-15);
        // Weights sum to 1 and every finest texel is covered with total weight c/f, for many sizes.
        for f in 1..40u32 {
            for c in level_sizes(f, 1).into_iter().map(|s| s.0) {
                let a = AxisFootprints::new(f, c);
                let mut cover = vec![0.0; f as usize];
                for x in 0..c as usize {
                    let s: f64 = a.taps(x).map(|t| t.1).sum();
                    assert!((s - 1.0).abs() < 1e-12, "f={f} c={c} x={x} sum={s}");
                    for (i, w) in a.taps(x) {
                        cover[i as usize] += w;
                    }
                }
                for v in cover {
                    assert!((v - c as f64 / f as f64).abs() < 1e-12);
                }
            }
        }
    }

    #[test]
    fn texel_footprint_matches_interval_footprint() {
        for (f, c) in [(5u32, 2u32), (7, 3), (1024, 1), (4097, 2048), (9, 4)] {
            let a = AxisFootprints::new(f, c);
            for x in 0..c {
                let lo = x as f64 * f as f64 / c as f64;
                let hi = (x + 1) as f64 * f as f64 / c as f64;
                let b = interval_footprint(lo, hi, f, Addressing::Clamp);
                let t: Vec<_> = a.taps(x as usize).collect();
                assert_eq!(b.len(), t.len());
                for (p, q) in b.iter().zip(&t) {
                    assert_eq!(p.0, q.0);
                    assert!((p.1 - q.1).abs() < 1e-12);
                }
            }
        }
    }

    #[test]
    fn interval_footprint_wraps_or_clamps_across_edges() {
        // [-1, 1) on a 4-wide axis: wrap → texels 3 and 0; clamp → texel 0 only.
        let w = interval_footprint(-1.0, 1.0, 4, Addressing::Wrap);
        assert_eq!(w, vec![(3, 0.5), (0, 0.5)]);
        let c = interval_footprint(-1.0, 1.0, 4, Addressing::Clamp);
        assert_eq!(c, vec![(0, 1.0)]);
        // [3.5, 5.5) → wrap: 3 (0.25), 0 (0.5), 1 (0.25); clamp: 3 takes it all.
        let w = interval_footprint(3.5, 5.5, 4, Addressing::Wrap);
        assert_eq!(w, vec![(3, 0.25), (0, 0.5), (1, 0.25)]);
        let c = interval_footprint(3.5, 5.5, 4, Addressing::Clamp);
        assert_eq!(c, vec![(3, 1.0)]);
        // Wider than the map: wrap covers every texel equally.
        let w = interval_footprint(0.0, 8.0, 4, Addressing::Wrap);
        assert_eq!(w, (0..4).map(|i| (i, 0.25)).collect::<Vec<_>>());
    }

    #[test]
    fn bilinear_taps_wrap_and_clamp() {
        // u = 0 on a 4-wide level: x = −0.5 → texels −1 and 0, half each.
        assert_eq!(
            bilinear_taps(0.0, 4, Addressing::Wrap),
            [(3, 0.5), (0, 0.5)]
        );
        assert_eq!(
            bilinear_taps(0.0, 4, Addressing::Clamp),
            [(0, 0.5), (0, 0.5)]
        );
        // Texel centre: all weight on one texel.
        assert_eq!(
            bilinear_taps(0.625, 4, Addressing::Wrap),
            [(2, 1.0), (3, 0.0)]
        );
    }

    #[test]
    fn reduce_matches_direct_footprint_sums() {
        let (w, h) = (7u32, 5u32);
        let img: Vec<f64> = (0..w * h * 2)
            .map(|i| ((i * 37 % 11) as f64).sin())
            .collect();
        for lf in pyramid(w, h) {
            let r = reduce(&img, 2, w, &lf);
            for cy in 0..lf.size.1 {
                for cx in 0..lf.size.0 {
                    let mut s = [0.0; 2];
                    for (fx, fy, wt) in lf.texel(cx, cy) {
                        for (c, sc) in s.iter_mut().enumerate() {
                            *sc += wt * img[((fy * w + fx) * 2) as usize + c];
                        }
                    }
                    let o = ((cy * lf.size.0 + cx) * 2) as usize;
                    assert!((r[o] - s[0]).abs() < 1e-12 && (r[o + 1] - s[1]).abs() < 1e-12);
                }
            }
        }
    }
}
