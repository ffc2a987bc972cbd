//! Importance sampling of an environment (the ground truth's light strategy): a 2D CDF over
//! the texels of the piecewise-constant radiance, rows by their power `Σ_x L Ω_row`, then
//! columns within the row; a direction is uniform in solid angle inside the chosen texel, so
//! its density is exactly `L_texel / ∫ L dω`.

use super::Radiance;
use glam::DVec3;

/// The 2D CDF of a [`Radiance`] (module docs). `None` from [`EnvSampler::new`] for an
/// environment with no power (all black): nothing to sample, every integral is 0.
#[derive(Debug, Clone)]
pub struct EnvSampler {
    /// Cumulative row power, normalized, `height + 1` entries from 0 to 1.
    rows: Vec<f64>,
    /// Per row, cumulative texel radiance normalized, `width + 1` entries each.
    columns: Vec<f64>,
    /// `∫ L dω`.
    total: f64,
}

impl EnvSampler {
    /// Builds the CDF of `env`; `None` when `∫ L dω` is 0.
    pub fn new(env: &Radiance) -> Option<EnvSampler> {
        let (w, h) = (env.width() as usize, env.height() as usize);
        let mut rows = Vec::with_capacity(h + 1);
        let mut columns = Vec::with_capacity(h * (w + 1));
        rows.push(0.0);
        let mut acc = 0.0;
        for (y, row) in env.values().chunks_exact(w).enumerate() {
            let mut c = 0.0;
            columns.push(0.0);
            for &v in row {
                c += v as f64;
                columns.push(c);
            }
            let start = columns.len() - (w + 1);
            for v in &mut columns[start..] {
                *v = if c > 0.0 { *v / c } else { 0.0 };
            }
            acc += c * env.solid_angle(y as u32);
            rows.push(acc);
        }
        if !(acc > 0.0 && acc.is_finite()) {
            return None;
        }
        for v in rows.iter_mut() {
            *v /= acc;
        }
        Some(EnvSampler {
            rows,
            columns,
            total: acc,
        })
    }

    /// `∫ L dω`.
    pub fn total(&self) -> f64 {
        self.total
    }

    /// A direction from four uniforms in [0, 1): the texel by `u0` (row) and `u1` (column),
    /// the position inside it by `u2`, `u3`. Returns the direction and the texel's index.
    pub fn sample(&self, env: &Radiance, u: [f64; 4]) -> (DVec3, usize) {
        let (w, h) = (env.width() as usize, env.height() as usize);
        let y = find(&self.rows, u[0]).min(h - 1);
        let cdf = &self.columns[y * (w + 1)..(y + 1) * (w + 1)];
        let x = find(cdf, u[1]).min(w - 1);
        let d = env.grid().sub_direction(x as u32, y as u32, u[2], u[3]);
        (d, y * w + x)
    }

    /// The density (per steradian) of [`EnvSampler::sample`] at direction `d`:
    /// `L_texel(d) / ∫ L dω`.
    pub fn pdf(&self, env: &Radiance, d: DVec3) -> f64 {
        self.pdf_of_radiance(env.nearest(d))
    }

    /// [`EnvSampler::pdf`] at a direction whose texel's radiance `radiance` the caller has
    /// already read (no second texel lookup).
    pub fn pdf_of_radiance(&self, radiance: f64) -> f64 {
        radiance / self.total
    }
}

/// The interval `i` with `cdf[i] ≤ u < cdf[i + 1]`, skipping empty intervals.
fn find(cdf: &[f64], u: f64) -> usize {
    // First index with cdf > u, minus one.
    let i = cdf.partition_point(|&c| c <= u);
    i.saturating_sub(1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn samples_follow_the_radiance() {
        // Radiance in two texels only: every sample lands in them, in proportion to power.
        let (w, h) = (16u32, 8u32);
        let mut v = vec![0.0f32; 128];
        v[2 * 16 + 3] = 1.0;
        v[5 * 16 + 9] = 3.0;
        let env = Radiance::new(w, h, v).unwrap();
        let s = EnvSampler::new(&env).unwrap();
        let p0 = env.solid_angle(2);
        let p1 = 3.0 * env.solid_angle(5);
        let mut rng = Rng(7);
        let mut n1 = 0;
        let n = 20000;
        for _ in 0..n {
            let u = [
                rng.uniform() % 1.0,
                rng.uniform() % 1.0,
                rng.uniform(),
                rng.uniform(),
            ];
            let (d, i) = s.sample(&env, u.map(|x| x.min(1.0 - 1e-12)));
            assert!(i == 2 * 16 + 3 || i == 5 * 16 + 9, "{i}");
            assert_eq!(env.grid().texel_of(d), ((i % 16) as u32, (i / 16) as u32));
            if i == 5 * 16 + 9 {
                n1 += 1;
            }
            // ∫ pdf = 1: pdf · Ω = L Ω / total.
            assert!(s.pdf(&env, d) > 0.0);
        }
        let expect = p1 / (p0 + p1);
        let got = n1 as f64 / n as f64;
        assert!((got - expect).abs() < 4.0 * (expect * (1.0 - expect) / n as f64).sqrt());
        // The density integrates to 1 over the sphere.
        let total: f64 = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| s.pdf(&env, env.grid().direction(x, y)) * env.solid_angle(y))
            .sum();
        assert!((total - 1.0).abs() < 1e-12);
    }

    #[test]
    fn black_has_no_sampler() {
        assert!(EnvSampler::new(&Radiance::constant(8, 0.0)).is_none());
    }
}
