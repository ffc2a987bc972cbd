//! The built-in sample: a tileable procedural normal map (bumps, scratches, grooves) with a
//! matching albedo, so the demo and the tests need no file from outside the project.
//!
//! A height field is built on a torus (so the map tiles), normals come from its central
//! differences, and the albedo darkens in scratches and grooves and varies slowly across the
//! surface. Everything is deterministic for a given size and seed.

use crate::ingest::{Addressing, BadNormals, NormalMap};
use crate::rng::Rng;
use glam::Vec3;

/// The procedural sample: normals (OpenGL convention) and linear RGBA albedo.
pub struct Sample {
    /// The normal map.
    pub map: NormalMap,
    /// Linear albedo, RGBA, row-major.
    pub albedo: Vec<[f32; 4]>,
}

/// Generates the `size × size` sample for `seed` (size ≥ 8).
pub fn generate(size: u32, seed: u64) -> Sample {
    let n = size.max(8) as usize;
    let mut rng = Rng(seed);
    let mut height = vec![0.0f64; n * n];
    let mut wear = vec![0.0f64; n * n]; // 1 in scratches and grooves, for the albedo
    let s = n as f64 / 512.0; // features scale with the map
    // Round bumps of many sizes, both up and down.
    for _ in 0..(n * n / 300) {
        let (cx, cy) = (rng.range(0.0, n as f64), rng.range(0.0, n as f64));
        let r = rng.range(1.5, 14.0) * s.max(0.25);
        let a = rng.range(-1.0, 1.0) * r * 0.6;
        let reach = (3.0 * r).ceil() as i64;
        for dy in -reach..=reach {
            for dx in -reach..=reach {
                let (px, py) = (cx.floor() as i64 + dx, cy.floor() as i64 + dy);
                let (fx, fy) = (px as f64 + 0.5 - cx, py as f64 + 0.5 - cy);
                let g = (-(fx * fx + fy * fy) / (2.0 * r * r)).exp();
                let i = py.rem_euclid(n as i64) as usize * n + px.rem_euclid(n as i64) as usize;
                height[i] += a * g;
            }
        }
    }
    // Scratches: thin straight V-shaped cuts.
    for _ in 0..(60.0 * s * s).max(6.0) as usize {
        let (x0, y0) = (rng.range(0.0, n as f64), rng.range(0.0, n as f64));
        let angle = rng.range(0.0, std::f64::consts::TAU);
        let len = rng.range(30.0, 200.0) * s.max(0.25);
        let (w, depth) = (rng.range(0.6, 1.6), rng.range(0.8, 2.5));
        let (dx, dy) = (angle.cos(), angle.sin());
        let steps = (len * 2.0) as usize;
        let reach = (2.0 * w).ceil() as i64 + 1;
        let mut touched = std::collections::HashMap::new();
        for k in 0..steps {
            let t = k as f64 / 2.0;
            let (cx, cy) = (x0 + dx * t, y0 + dy * t);
            for oy in -reach..=reach {
                for ox in -reach..=reach {
                    let (px, py) = (cx.floor() as i64 + ox, cy.floor() as i64 + oy);
                    let (fx, fy) = (px as f64 + 0.5 - cx, py as f64 + 0.5 - cy);
                    let d = (fx * -dy + fy * dx).abs(); // distance across the line
                    let profile = (1.0 - d / (2.0 * w)).max(0.0);
                    let i = py.rem_euclid(n as i64) as usize * n + px.rem_euclid(n as i64) as usize;
                    let e = touched.entry(i).or_insert(0.0f64);
                    *e = e.max(profile);
                }
            }
        }
        for (i, p) in touched {
            height[i] -= depth * p;
            wear[i] = wear[i].max(p);
        }
    }
    // Grooves: a band of parallel V-grooves across the lower third, period 8 texels at 512².
    let period = (8.0 * s).max(3.0);
    for y in (n * 6 / 10)..(n * 85 / 100) {
        for x in 0..n {
            let phase = (x as f64 / period).fract();
            let v = (phase - 0.5).abs() * 2.0; // 1 at the ridges, 0 in the groove
            height[y * n + x] += 2.0 * v;
            wear[y * n + x] = wear[y * n + x].max(1.0 - v);
        }
    }
    // Normals from central differences (OpenGL: +Y points up the image, rows go down).
    let at = |x: i64, y: i64| {
        height[y.rem_euclid(n as i64) as usize * n + x.rem_euclid(n as i64) as usize]
    };
    let mut normals = Vec::with_capacity(n * n);
    let mut albedo = Vec::with_capacity(n * n);
    for y in 0..n as i64 {
        for x in 0..n as i64 {
            let dhdx = 0.5 * (at(x + 1, y) - at(x - 1, y));
            let dhdrow = 0.5 * (at(x, y + 1) - at(x, y - 1));
            normals.push(Vec3::new(-dhdx as f32, dhdrow as f32, 1.0).normalize());
            // Albedo: a slow two-colour variation, darker in scratches and grooves.
            let (u, v) = (x as f64 / n as f64, y as f64 / n as f64);
            let tau = std::f64::consts::TAU;
            let mix =
                0.5 + 0.25 * (tau * u).sin() * (tau * 2.0 * v).cos() + 0.25 * (tau * (u + v)).sin();
            let base = [0.55 - 0.25 * mix, 0.42 - 0.12 * mix, 0.30 + 0.05 * mix];
            let dark = 1.0 - 0.6 * wear[y as usize * n + x as usize];
            albedo.push([
                (base[0] * dark) as f32,
                (base[1] * dark) as f32,
                (base[2] * dark) as f32,
                1.0,
            ]);
        }
    }
    let map = NormalMap::from_vectors(
        n as u32,
        n as u32,
        normals,
        Addressing::Wrap,
        BadNormals::Repair,
    )
    .expect("the procedural map has valid dimensions and unit normals");
    Sample { map, albedo }
}

/// Encodes unit normals as 8-bit RGB, unsigned-normalized (`round((n + 1) / 2 · 255)`).
pub fn encode_rgb8(normals: &[Vec3]) -> Vec<u8> {
    normals
        .iter()
        .flat_map(|n| n.to_array())
        .map(|c| ((c as f64 + 1.0) * 0.5 * 255.0).round().clamp(0.0, 255.0) as u8)
        .collect()
}

/// Encodes linear colour as 8-bit sRGB RGB.
pub fn encode_srgb8(colors: &[[f32; 4]]) -> Vec<u8> {
    colors
        .iter()
        .flat_map(|c| [c[0], c[1], c[2]])
        .map(|v| {
            let v = (v as f64).clamp(0.0, 1.0);
            let s = if v <= 0.0031308 {
                12.92 * v
            } else {
                1.055 * v.powf(1.0 / 2.4) - 0.055
            };
            (s * 255.0).round() as u8
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sample_is_deterministic_bumpy_and_above_the_horizon() {
        let a = generate(64, 7);
        let b = generate(64, 7);
        assert_eq!(a.map.normals(), b.map.normals());
        let s = a.map.stats();
        assert_eq!(s.bad_total(), 0);
        assert!(s.mean_z > 0.6 && s.mean_z < 0.99, "mean z {}", s.mean_z);
        assert_eq!(a.albedo.len(), 64 * 64);
    }
}
