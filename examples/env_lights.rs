//! Prints the bright compact sources `environment::lights::extract` finds in an environment
//! (`sky` or a .hdr/.exr path) at a few seed thresholds, without the compactness and share
//! filters, with each region's solid angle, luminance share and κ: how the defaults of
//! `LightOptions` were chosen (docs/environment.md, "Bright sources as lights").
//!
//! `cargo run --release --example env_lights -- ENV [THRESHOLD...]`
use ndfmap::environment::lights::{LightOptions, extract};
use std::path::Path;

fn main() -> ndfmap::error::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let name = args.first().map(String::as_str).unwrap_or("sky");
    let env = if name == "sky" {
        ndfmap::environment::Sky::default().render()?
    } else {
        ndfmap::environment::load(Path::new(name), &Default::default())?
    };
    let total = env.luminance().power();
    println!(
        "{name}: {}x{}, luminance power {total:.4}, mean {:.4}",
        env.width(),
        env.height(),
        total / (4.0 * std::f64::consts::PI)
    );
    let thresholds: Vec<f64> = if args.len() > 1 {
        args[1..].iter().filter_map(|a| a.parse().ok()).collect()
    } else {
        vec![5.0, 10.0, 20.0, 50.0]
    };
    let peak: f64 = std::env::var("PEAK")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1e-3);
    for t in thresholds {
        let ex = extract(
            &env,
            &LightOptions {
                max_lights: 8,
                threshold: t,
                max_solid_angle: 4.0 * std::f64::consts::PI,
                peak_fraction: peak,
                min_share: 0.0,
                ..LightOptions::default()
            },
        );
        println!("threshold {t}:");
        for l in &ex.lights {
            println!(
                "  share {:.4}  solid angle {:.3e} sr  texels {:5}  kappa {:.3e}  spread cap {:.3e} sr  dir ({:.3}, {:.3}, {:.3})",
                l.luminance() / total,
                l.solid_angle,
                l.texels,
                l.kappa,
                4.0 * std::f64::consts::PI / l.kappa,
                l.direction.x,
                l.direction.y,
                l.direction.z
            );
        }
    }
    Ok(())
}
