//! Stiff and extreme cases (DESIGN.md "Numerics"; issue 7): every method and storage format on
//! degenerate inputs and extreme BRDF parameters stays finite, non-negative and within the peak
//! and energy bounds of `ndfmap::report::stability`; the naive formulas that break on these
//! inputs are written out here and shown to fail where the library's guarded paths hold; and an
//! f32 twin of the shaders' lobe math agrees with the f64 CPU path.
#![cfg(feature = "report")]

use glam::{DVec3, Vec3};
use half::f16;
use ndfmap::bake::{BakeOptions, Method};
use ndfmap::brdf::{Brdf, blinn_phong, half_vector};
use ndfmap::format::Format;
use ndfmap::ingest::{Addressing, BadNormals, Channels, NormalMap, Samples};
use ndfmap::methods::{bake, bake_with};
use ndfmap::pack::quantize;
use ndfmap::report::stability::{ENERGY_BOUND, ENERGY_EXEMPT, PEAK_BOUND, cases, sweep};
use ndfmap::shade::{ShadeOptions, VmfSpecular, shade_brdf, shade_with, vmf_lobe, vmf_lobe_with};
use ndfmap::vmf::{R_MAX, blinn_phong_convolved, kappa_banerjee, r_max};
use std::f64::consts::PI;

#[test]
fn every_method_and_format_is_finite_non_negative_and_bounded_on_stiff_cases() {
    let s = sweep(true);
    eprintln!("{}", ndfmap::report::stability::markdown(&s));
    let configs = 9;
    assert_eq!(s.cases.len(), 10);
    assert_eq!(
        s.outcomes.len(),
        s.cases.len() * configs * Format::ALL.len()
    );
    for o in &s.outcomes {
        assert!(
            o.bake_error.is_none(),
            "{} {}: {:?}",
            o.case,
            o.config,
            o.bake_error
        );
        if let Some(why) = &o.skipped {
            // Only LEAN's and Tan's unbounded moments are refused, and only by unorm formats.
            assert!(
                matches!(o.family.as_str(), "lean" | "tan2005")
                    && matches!(o.format, Format::Unorm16 | Format::Unorm8),
                "{} {} {}: {why}",
                o.case,
                o.config,
                o.format
            );
            continue;
        }
        assert!(o.checked > 0);
        assert_eq!(
            o.nonfinite, 0,
            "{} {} {}: NaN/inf",
            o.case, o.config, o.format
        );
        assert_eq!(
            o.negative, 0,
            "{} {} {}: negative",
            o.case, o.config, o.format
        );
        assert!(
            o.over_peak == 0 && o.max_peak_ratio <= PEAK_BOUND,
            "{} {} {}: {} above the peak, max ratio {}",
            o.case,
            o.config,
            o.format,
            o.over_peak,
            o.max_peak_ratio
        );
        if !ENERGY_EXEMPT.contains(&o.family.as_str())
            && let Some(e) = o.max_energy_ratio
        {
            assert!(
                e <= 1.0 + ENERGY_BOUND,
                "{} {} {}: energy {e}",
                o.case,
                o.config,
                o.format
            );
        }
        assert!(o.ok());
    }
    // The exemption is needed, and only for the mean-direction models: plain, LEAN and Tan 2005
    // over-light a steep symmetric map (the modelling error, not numerics).
    let energy = |case: &str, family: &str| {
        s.outcomes
            .iter()
            .filter(|o| o.case.starts_with(case) && o.family == family)
            .filter_map(|o| o.max_energy_ratio)
            .fold(0.0f64, f64::max)
    };
    assert!(energy("antipodal", "plain") > 2.0);
    assert!(energy("all on the horizon", "lean") > 1.0 + ENERGY_BOUND);
    assert!(energy("antipodal", "vmf") <= 1.0 + ENERGY_BOUND);
}

#[test]
fn algorithm_2_divides_by_alpha_only_behind_the_guard() {
    // Naive Algorithm 2 line 8 on an empty lobe (α = 0, e.g. quantized away): 0/0.
    let theta = [0.0f32; 4];
    let alpha = theta[0];
    let r = Vec3::new(theta[1], theta[2], theta[3]) / alpha;
    let len = r.length();
    let kappa = (3.0 * len - len * len * len) / (1.0 - len * len);
    let mu = r / len;
    assert!(kappa.is_nan() && mu.is_nan(), "the naive version fails");
    // The library's lobe contributes exactly nothing, for every format's clamp and exponent.
    for format in Format::ALL {
        for s in [1.0, 1e6] {
            let out = vmf_lobe(theta, DVec3::Z, DVec3::Z, s, r_max(format));
            assert_eq!((out.diffuse, out.specular), (0.0, 0.0));
        }
    }
    // A lobe quantized away: a tiny α (here 10⁻³) rounds to 0 in unorm8 while the biased α·r
    // decodes to a small non-zero vector — the 0/0 of line 8 in a real bake.
    let map = ndfmap::procedural::generate(16, 4).map;
    let mut b = bake_with(
        &map,
        Method::Vmf,
        &BakeOptions {
            lobes: 3,
            ..Default::default()
        },
    )
    .unwrap();
    for t in &mut b.textures[2].levels[1] {
        *t = [1e-3, 0.6e-3, -0.5e-3, 0.6e-3];
    }
    let q = quantize(&b, Format::Unorm8).unwrap();
    let t = q.texel(1, 0, 0);
    assert_eq!(t[2][0], 0.0, "α quantized to 0");
    assert!(
        t[2][1..].iter().any(|&v| v != 0.0),
        "α·r is not: {:?}",
        t[2]
    );
    let naive = {
        let r = Vec3::new(t[2][1], t[2][2], t[2][3]) / t[2][0];
        r.length()
    };
    assert!(!naive.is_finite(), "the naive version fails: |r| = {naive}");
    for brdf in [
        Brdf::BlinnPhong { s: 64.0 },
        Brdf::TorranceSparrow { sigma: 0.1 },
    ] {
        let s = shade_brdf(&q, &t, DVec3::Z, DVec3::Z, &brdf);
        assert!(s.diffuse.is_finite() && s.specular.is_finite() && s.specular >= 0.0);
    }
}

#[test]
fn kappa_from_an_f16_mean_length_is_clamped_to_what_f16_can_hold() {
    // All normals identical: |r| → 1, κ → ∞. A texel stores α·r; f16 rounds |r| = 1 − 10⁻⁴
    // (and anything above 1 − 2⁻¹²) up to exactly 1.
    let r16 = f16::from_f64(1.0 - 1e-4).to_f64();
    assert_eq!(r16, 1.0);
    let naive = (3.0 * r16 - r16 * r16 * r16) / (1.0 - r16 * r16);
    assert!(naive.is_infinite(), "the naive version fails: {naive}");
    // The guard: |r| clamped to the format's r_max before κ (shader and CPU alike).
    let k = kappa_banerjee(r16.min(r_max(Format::F16)));
    assert!((k - 2048.5).abs() < 0.5, "{k}");
    // End to end: identical normals baked, stored in every format, shaded at an extreme
    // exponent: finite, and the highlight peak within the bound.
    let map = NormalMap::from_vectors(
        8,
        8,
        vec![Vec3::new(0.0, 0.0, 1.0); 64],
        Addressing::Wrap,
        BadNormals::Repair,
    )
    .unwrap();
    let b = bake(&map, Method::Vmf);
    for format in Format::ALL {
        let q = quantize(&b, format).unwrap();
        for level in 0..q.level_count() {
            let t = q.texel(level, 0, 0);
            for s in [1.0, 512.0, 1e6] {
                let out = shade_brdf(&q, &t, DVec3::Z, DVec3::Z, &Brdf::BlinnPhong { s });
                assert!(
                    out.specular.is_finite() && out.specular >= 0.0,
                    "{format} s={s}"
                );
                assert!(out.specular <= PEAK_BOUND * (s + 1.0) / (2.0 * PI));
                // The κ cap keeps the lobe sharp but finite. Eq 20 (the default rule):
                // s' = κs/(κ+s) ≤ κ_max(format).
                let kmax = kappa_banerjee(r_max(format));
                let s_eff = kmax * s / (kmax + s);
                let want = (s_eff + 1.0) / (2.0 * PI);
                assert!(
                    (out.specular - want).abs() <= 0.02 * want,
                    "{format} level {level} s={s}: {} vs {want}",
                    out.specular
                );
                // The closed-form convolution (opt-in): the rule's value at κ_max.
                let convolved = ShadeOptions {
                    vmf_specular: VmfSpecular::Convolved,
                    ..Default::default()
                };
                let c = shade_with(
                    &q,
                    &t,
                    DVec3::Z,
                    DVec3::Z,
                    &Brdf::BlinnPhong { s },
                    &convolved,
                );
                let conv = blinn_phong_convolved(1.0, s, kmax);
                assert!(
                    (c.specular - conv).abs() <= 0.02 * conv,
                    "{format} level {level} s={s}: {} vs {conv}",
                    c.specular
                );
            }
        }
    }
}

#[test]
fn toksvig_from_a_two_channel_mean_loses_the_roughness_the_three_channel_mean_keeps() {
    // ±60° checkerboard: every 2×2 footprint averages to n̄ = (0, 0, cos 60°) = (0, 0, 0.5).
    let (s60, c60) = (60f32.to_radians().sin(), 60f32.to_radians().cos());
    let v = (0..64)
        .map(|i| {
            if (i % 8 + i / 8) % 2 == 0 {
                Vec3::new(s60, 0.0, c60)
            } else {
                Vec3::new(-s60, 0.0, c60)
            }
        })
        .collect();
    let map = NormalMap::from_vectors(8, 8, v, Addressing::Wrap, BadNormals::Repair).unwrap();
    let b = bake(&map, Method::Toksvig);
    let s = 64.0;
    // Naive 2-channel Toksvig: only (x, y) of the mean survive (a BC5 texture); the shader
    // reconstructs z = sqrt(1 − x² − y²) = 1, so |n̄| = 1 and s' = s: no widening.
    let t = b.texel(1, 0, 0);
    let (x, y) = (t[0][0] as f64, t[0][1] as f64);
    let naive_len = DVec3::new(x, y, (1.0 - x * x - y * y).max(0.0).sqrt()).length();
    let naive_s = naive_len * s / (naive_len + s * (1.0 - naive_len));
    assert!((naive_len - 1.0).abs() < 1e-6 && (naive_s - s).abs() < 1e-3);
    // Error of each against the exact footprint average at the mirror direction h = +Z, l = +Z:
    // every real normal is 60° off, so the exact highlight is (s+1)/2π·cos⁶⁴60°·cos60° ≈ 0.
    let exact = blinn_phong(c60 as f64, s) * c60 as f64;
    let naive = blinn_phong(1.0, naive_s);
    let guarded = shade_brdf(&b, &t, DVec3::Z, DVec3::Z, &Brdf::BlinnPhong { s }).specular;
    assert!(
        naive > 10.0,
        "naive 2-channel Toksvig keeps the full highlight: {naive}"
    );
    assert!(
        guarded < 0.2 * naive && (guarded - exact).abs() < 0.1 * naive,
        "the 3-channel mean widens it: {guarded} (exact {exact})"
    );
    // And a quantized 2-channel texel with x² + y² > 1: naive z = NaN, ingest repairs it.
    let (ux, uy) = (255u8, 140u8);
    let (x, y) = (ux as f32 / 255.0 * 2.0 - 1.0, uy as f32 / 255.0 * 2.0 - 1.0);
    assert!((1.0 - x * x - y * y).sqrt().is_nan());
    let m = NormalMap::from_samples(
        "xy",
        1,
        1,
        2,
        Samples::U8(&[ux, uy]),
        &ndfmap::IngestOptions {
            channels: Channels::Xy,
            ..Default::default()
        },
    )
    .unwrap();
    let n = m.normal(0, 0);
    assert!(
        n.is_finite() && (n.length() - 1.0).abs() < 1e-5 && n.z >= 0.0,
        "{n}"
    );
}

/// `ndf_vmf_half_norm` in f32.
fn half_norm_f32(x: f32) -> f32 {
    if x < 1e-3 {
        0.5 + 0.5 * x
    } else if x > 19.0 {
        x
    } else {
        x / (1.0 - (-2.0 * x).exp())
    }
}

/// `ndf_vmf_blinn_phong` (glsl/ndf_common.glsl, `NDF_VMF_SPECULAR_CONVOLVED`) in f32, operation for operation.
fn vmf_blinn_phong_f32(cos_h: f32, s: f32, var: f32) -> f32 {
    if s.is_nan() || s <= 0.0 {
        return 1.0 / (2.0 * std::f32::consts::PI);
    }
    let k = 1.0 / var;
    let eta = s + 1.0;
    let omc = (1.0 - cos_h).clamp(0.0, 2.0);
    let num = k * (1.0 - omc) + eta;
    if num.is_nan() || num <= 0.0 {
        return 0.0;
    }
    let k2s2 = k * k * omc * (2.0 - omc);
    let r2 = k2s2 + num * num;
    let ir = 1.0 / r2.sqrt();
    let r = r2 * ir;
    let e =
        -2.0 * k * eta * omc / (r + k + eta) + eta * k2s2 * ir / (r + num) + s * (num * ir).ln();
    let g = if k < 9.0 || r < 9.0 {
        half_norm_f32(k) / half_norm_f32(r)
    } else {
        k * ir
    };
    (s + 1.0) / (2.0 * std::f32::consts::PI) * g * e.exp()
}

/// The shaders' vMF lobe in f32 (glsl/ndf_vmf.glsl + ndf_common.glsl): decode, κ with the
/// format's clamp, the specular rule (eq 20 with `ndf_pow`'s conventions, or the closed-form
/// convolution) and its cosine at the product lobe's centre.
fn vmf_lobe_f32(
    theta: [f32; 4],
    l: Vec3,
    h: Vec3,
    s: f32,
    r_max: f32,
    rule: VmfSpecular,
) -> (f32, f32) {
    let alpha = theta[0];
    let (mut mu, mut var) = (Vec3::Z, 1e6f32);
    // GLSL's `!(alpha > NDF_ALPHA_MIN)` (0 here, as vmf_lobe): NaN and non-positive α are
    // empty lobes.
    if alpha.is_nan() || alpha <= 0.0 {
        return (0.0, 0.0);
    }
    let m = Vec3::new(theta[1], theta[2], theta[3]);
    let m2 = m.dot(m);
    if m2 > 0.0 && m2 < 1e30 {
        let inv = 1.0 / m2.sqrt(); // inversesqrt
        mu = m * inv;
        let rc = (m2 * inv / alpha).min(r_max);
        var = ((1.0 - rc) * (1.0 + rc) / (rc * (3.0 - rc * rc))).min(1e6);
    }
    let s_eff = s / (1.0 + s * var);
    let ndf_pow = |x: f32, y: f32| {
        if y <= 0.0 {
            1.0
        } else if x <= 0.0 {
            0.0
        } else {
            x.powf(y)
        }
    };
    let cos_i = mu.dot(l).max(0.0);
    // The specular term's cosine at the product lobe's centre (VmfCosine::Product, the
    // default): normalize(μ + η·var·ω_h) with η = s + 1, as the general loop of ndf_vmf.glsl.
    let np = mu + ((s + 1.0) * var) * h;
    let cos_s = np.dot(l).max(0.0) / np.dot(np).max(1e-30).sqrt();
    let b = if rule == VmfSpecular::Eq20 {
        (s_eff + 1.0) / (2.0 * std::f32::consts::PI) * ndf_pow(mu.dot(h), s_eff)
    } else {
        vmf_blinn_phong_f32(mu.dot(h), s, var)
    };
    (alpha * cos_i, alpha * b * cos_s)
}

#[test]
fn f32_shader_math_agrees_with_the_f64_cpu_path_on_extreme_lobes() {
    let dirs: Vec<(DVec3, DVec3)> = vec![
        (DVec3::Z, DVec3::Z),
        (DVec3::new(0.3, 0.1, 0.95).normalize(), DVec3::Z),
        (DVec3::new(0.8, 0.0, 0.6), DVec3::new(-0.8, 0.0, 0.6)),
        (DVec3::X, DVec3::new(0.0, 0.0, 1.0)),
        (DVec3::X, -DVec3::X),
    ];
    let mut worst = 0.0f64;
    for &r_len in &[
        0.0,
        1e-7,
        0.3,
        0.9,
        0.999,
        1.0 - 2f64.powi(-11),
        R_MAX,
        1.0 + 1e-3,
    ] {
        for &alpha in &[1e-6f64, 0.25, 1.0] {
            let dir = DVec3::new(0.2, -0.1, 0.97).normalize();
            let r = dir * r_len;
            let theta = [
                alpha as f32,
                (alpha * r.x) as f32,
                (alpha * r.y) as f32,
                (alpha * r.z) as f32,
            ];
            for format in Format::ALL {
                let rm = r_max(format);
                for &s in &[1.0f64, 10.0, 128.0, 1e4, 1e6] {
                    for (&(l, v), rule) in dirs
                        .iter()
                        .flat_map(|d| [(d, VmfSpecular::Eq20), (d, VmfSpecular::Convolved)])
                    {
                        let h = half_vector(l, v);
                        let d64 = vmf_lobe_with(theta, l, h, s, rm, rule);
                        let (d32, s32) = vmf_lobe_f32(
                            theta,
                            l.as_vec3(),
                            h.as_vec3(),
                            s as f32,
                            rm as f32,
                            rule,
                        );
                        for (a, b) in [(d64.diffuse, d32 as f64), (d64.specular, s32 as f64)] {
                            assert!(a.is_finite() && b.is_finite() && a >= 0.0 && b >= 0.0);
                        }
                        // Specular relative to the lobe's peak (its natural scale): f32's
                        // rounding of κ near the clamp and of ω_h·μ near 1 stays small for
                        // practical exponents; at s = 10⁶ only finiteness and the peak bound.
                        let peak = alpha * (s + 1.0) / (2.0 * PI);
                        let err = (d64.specular - s32 as f64).abs() / peak;
                        assert!(
                            (d64.diffuse - d32 as f64).abs() <= 1e-5 * alpha.max(1e-30) + 1e-12
                        );
                        assert!(s32 as f64 <= PEAK_BOUND * peak);
                        if s <= 1e4 {
                            worst = worst.max(err);
                            assert!(
                                err < 2e-3,
                                "|r|={r_len} α={alpha} {format} s={s} l={l} {rule:?}: f64 {} f32 {s32}",
                                d64.specular
                            );
                        }
                    }
                }
            }
        }
    }
    eprintln!("largest f32-vs-f64 specular difference (s ≤ 10⁴), relative to the peak: {worst:e}");
}

#[test]
fn degenerate_sizes_bake_every_method_with_gl_chains() {
    for case in cases(true) {
        let (w, h) = (case.map.width(), case.map.height());
        let want = ndfmap::pyramid::level_sizes(w, h);
        for method in [Method::Plain, Method::Toksvig, Method::Lean, Method::Olano] {
            let b = bake(&case.map, method);
            assert_eq!(b.sizes, want, "{} {method}", case.name);
            assert!(
                b.textures.iter().all(|t| t
                    .levels
                    .iter()
                    .flatten()
                    .flatten()
                    .all(|v| v.is_finite())),
                "{} {method}",
                case.name
            );
        }
    }
    assert_eq!(ndfmap::pyramid::level_sizes(4097, 3).len(), 13);
    assert_eq!(ndfmap::pyramid::level_sizes(16384, 16).len(), 15);
}

/// Issue 16: a black environment lights nothing (exactly 0, every method and route); a
/// single-texel sun of radiance 10⁶ gives finite, non-negative output within the energy
/// bounds of `stability::EnvStability`, through the routes and taken out as a light by the
/// default extraction; κ → ∞ lobes read level 0 of the prefiltered environment.
#[test]
fn environment_lighting_is_exact_zero_in_the_dark_and_bounded_under_a_point_sun() {
    let e = ndfmap::report::stability::environment();
    eprintln!("{e:?}");
    assert!(e.checked > 10_000);
    assert_eq!(e.black_max, 0.0);
    assert_eq!(e.sun_bad, 0);
    assert!(e.sun_diffuse_ratio <= 1.0 + 1e-9, "{}", e.sun_diffuse_ratio);
    assert!(
        e.sun_specular_ratio <= 1.0 + 1e-9,
        "{}",
        e.sun_specular_ratio
    );
    assert!(e.sun_diffuse_ratio > 1e-3, "the sun must light something");
    // The default extraction takes the sun out as one light: the same checks.
    assert_eq!(e.sun_lights, 1);
    assert_eq!(e.sun_lit_bad, 0);
    assert!(
        e.sun_lit_diffuse_ratio <= 1.0 + 1e-9,
        "{}",
        e.sun_lit_diffuse_ratio
    );
    assert!(
        e.sun_lit_specular_ratio <= 1.0 + 1e-9,
        "{}",
        e.sun_lit_specular_ratio
    );
    assert!(
        e.sun_lit_diffuse_ratio > 1e-3,
        "the extracted sun must light something"
    );
    assert_eq!(e.infinite_kappa_lod, 0.0);
    assert_eq!(e.infinite_kappa_difference, 0.0);
    assert!(e.ok());
}
