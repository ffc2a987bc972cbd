//! The widening `c` of `α'² = α² + c/κ` that minimizes the relative L2 error against eq 14
//! (by quadrature, [`ndfmap::brdf::convolution::WideningCase::error_at`]) per (α, t = 1/(κα²)),
//! beside the peak-matched rule's `c`: `cargo run --release --example ggx_widening_fit`.

use ndfmap::brdf::Ggx;
use ndfmap::brdf::convolution::WideningCase;

fn main() {
    println!("| α | t = 1/(κα²) | a = κα²/2 | c L2-best | L2 there | L2 c=2 | c peak | L2 peak |");
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|");
    for alpha in [0.02, 0.05, 0.1, 0.2, 0.3, 0.5] {
        for t in [0.003, 0.01, 0.03, 0.1, 0.2, 0.3, 0.5, 1.0, 2.0, 3.0, 10.0] {
            let var: f64 = t * alpha * alpha;
            if var > 0.25 {
                continue;
            }
            let case = WideningCase::new(alpha, 1.0 / var);
            let err = |c: f64| case.error_at((alpha * alpha + c * var).sqrt().min(1.0));
            let (mut lo, mut hi) = (0.0f64, 8.0f64);
            for _ in 0..60 {
                let m1 = lo + (hi - lo) / 3.0;
                let m2 = hi - (hi - lo) / 3.0;
                if err(m1) < err(m2) { hi = m2 } else { lo = m1 }
            }
            let c = 0.5 * (lo + hi);
            let g = Ggx::new(alpha);
            let cp = (g.widened_vmf(var).powi(2) - alpha * alpha) / var;
            println!(
                "| {alpha} | {t} | {:.3} | {c:.3} | {:.4} | {:.4} | {cp:.3} | {:.4} |",
                0.5 / t,
                err(c),
                err(2.0),
                err(cp)
            );
        }
    }
}
