//! The prefiltered environment route for one NDF lobe at a time against the exact integral
//! (issue 16, stop 45): no Monte Carlo anywhere. For a vMF NDF lobe (μ, κ) and a view, (a) is
//! the shipped route ([`envlight::prefiltered_lobe`]: the lobe table's energy times one or two
//! prefiltered lookups), (b) the same lobe's `∫ vMF(n) ∫ L(ω_i) ρ(ω_i, ω_o; n) max(n·ω_i, 0)
//! dω_i dn` by quadrature: 16 × 16 normals of the vMF (κ = ∞: μ alone) × every texel of
//! the residual environment (its radiance times the texel's exact solid angle). Both read the
//! residual, i.e. the environment with its compact bright sources taken out as lights (the
//! default, `LightOptions::default()`); the lights' own term is the point-light path's and is
//! left out of both.
//!
//! `cargo run --release --example env_lobe_probe -- ENV|sky|constant BRDFS` with BRDFS
//! comma-separated `bpS` (Blinn-Phong exponent S) or a GGX α, e.g. `venice_sunset_1k.hdr
//! 0.3,0.1,bp32`; `constant` is a 256 × 128 environment of radiance 1, where the lookup is
//! exactly 1 and the route's error is its energy alone.
//!
//! Prints, per BRDF, κ and view angle θ_o (35° and 70°), the signed bias `Σ(a − b)/Σ b` and the
//! RMS of `(a − b)/b` over 36 geometries: μ tilted 0, 20 and 40° from the environment's zenith
//! (the surface's tangent frame is the environment's, as in texel-space `eval`) × 12 azimuths
//! of the view, 30° apart. About 2 min per BRDF for a 1024 × 512 panorama on two cores.

use glam::{DMat3, DVec3};
use ndfmap::brdf::Brdf;
use ndfmap::environment::lights::{LightOptions, extract};
use ndfmap::environment::{EnvOptions, Environment, Sky, load};
use ndfmap::envlight::{EnvLight, prefiltered_lobe};
use rayon::prelude::*;
use std::f64::consts::PI;
use std::path::Path;

/// The vMF lobe's normals: rings (midpoints of the inverse CDF of `cos γ`) × azimuths.
const RINGS: usize = 16;
const AZIMUTHS: usize = 16;
/// The NDF lobes' concentrations.
const KAPPAS: [f64; 5] = [f64::INFINITY, 256.0, 64.0, 16.0, 6.0];
/// μ's tilts from the zenith (degrees).
const TILTS: [f64; 3] = [0.0, 20.0, 40.0];

/// [`RINGS`] × [`AZIMUTHS`] directions of a vMF about +z (κ = ∞: +z), equal weights; each
/// ring's azimuths turned by half a step from the previous ring's.
fn vmf_normals(kappa: f64) -> Vec<(DVec3, f64)> {
    if kappa.is_infinite() {
        return vec![(DVec3::Z, 1.0)];
    }
    let weight = 1.0 / (RINGS * AZIMUTHS) as f64;
    (0..RINGS)
        .flat_map(|i| {
            let u = (i as f64 + 0.5) / RINGS as f64;
            let c = ndfmap::vmf::cos_quantile(u, kappa);
            let s = (1.0 - c * c).max(0.0).sqrt();
            (0..AZIMUTHS).map(move |j| {
                let phi = 2.0 * PI * (j as f64 + 0.5 * (i % 2) as f64) / AZIMUTHS as f64;
                (DVec3::new(s * phi.cos(), s * phi.sin(), c), weight)
            })
        })
        .collect()
}

fn parse_brdf(s: &str) -> Brdf {
    match s.strip_prefix("bp") {
        Some(e) => Brdf::BlinnPhong {
            s: e.parse().expect("Blinn-Phong exponent"),
        },
        None => Brdf::ggx(s.parse().expect("GGX α")),
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        eprintln!("usage: env_lobe_probe ENV|sky|constant BRDFS (e.g. 0.3,0.1,bp32)");
        std::process::exit(2);
    }
    let env = if args[1] == "sky" {
        Sky::default().render().unwrap()
    } else if args[1] == "constant" {
        Environment::from_rgb(
            "constant",
            256,
            128,
            vec![[1.0; 3]; 256 * 128],
            &EnvOptions::default(),
        )
        .unwrap()
    } else {
        load(Path::new(&args[1]), &EnvOptions::default()).unwrap()
    };
    let lights = LightOptions::default();
    let light = EnvLight::prefiltered_only_with_lights(&env, &lights);
    let residual = extract(&env, &lights).residual.luminance();
    let (w, h) = (residual.width(), residual.height());
    let grid = residual.grid();
    // Every texel as (direction, radiance × solid angle).
    let texels: Vec<(DVec3, f64)> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| {
            let v = residual.values()[(y * w + x) as usize] as f64;
            (grid.direction(x, y), v * residual.solid_angle(y))
        })
        .filter(|t| t.1 > 0.0)
        .collect();
    let luminance = |v: [f64; 3]| -> f64 {
        v.iter()
            .zip(ndfmap::environment::LUMINANCE)
            .map(|(a, b)| a * b)
            .sum()
    };
    println!("| BRDF | κ | θ_o | bias % | RMS % |");
    println!("|---|---:|---:|---:|---:|");
    for brdf in args[2].split(',').map(parse_brdf) {
        for kappa in KAPPAS {
            let normals = vmf_normals(kappa);
            for theta_o in [35.0f64, 70.0] {
                let cases: Vec<(f64, f64)> = TILTS
                    .iter()
                    .flat_map(|&t| (0..12).map(move |k| (t, 30.0 * k as f64)))
                    .collect();
                let pairs: Vec<(f64, f64)> = cases
                    .par_iter()
                    .filter_map(|&(tilt, phi)| {
                        let turn = DMat3::from_rotation_z(phi.to_radians());
                        let frame = turn * DMat3::from_rotation_x(tilt.to_radians());
                        let mu = frame * DVec3::Z;
                        let t = theta_o.to_radians();
                        let view = turn * DVec3::new(t.sin(), 0.0, t.cos());
                        if view.dot(mu) <= 0.05 {
                            return None;
                        }
                        let a = luminance(prefiltered_lobe(
                            &light,
                            DMat3::IDENTITY,
                            mu,
                            kappa,
                            view,
                            &brdf,
                        ));
                        let mut b = 0.0;
                        for &(n0, wn) in &normals {
                            // No test of the view against n: the footprint ground truth
                            // (`envlight::ground_truth`) has none either.
                            let n = frame * n0;
                            let mut sum = 0.0;
                            for &(l, radiance) in &texels {
                                let cos_i = n.dot(l);
                                if cos_i > 0.0 {
                                    let half = (l + view).normalize();
                                    sum += brdf.lobe(n.dot(half)) * cos_i * radiance;
                                }
                            }
                            b += wn * sum;
                        }
                        (b > 0.0).then_some((a, b))
                    })
                    .collect();
                let (bias, sum_b) = pairs
                    .iter()
                    .fold((0.0, 0.0), |(d, s), &(a, b)| (d + a - b, s + b));
                let rms = (pairs
                    .iter()
                    .map(|&(a, b)| ((a - b) / b).powi(2))
                    .sum::<f64>()
                    / pairs.len().max(1) as f64)
                    .sqrt();
                println!(
                    "| {} | {kappa} | {theta_o} | {:+.2} | {:.2} |",
                    brdf,
                    100.0 * bias / sum_b,
                    100.0 * rms
                );
            }
        }
    }
}
