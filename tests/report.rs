//! `ndfmap report` end to end on a tiny built-in sample: the files it promises, and numbers that
//! hold whatever the map (level-0-free texel errors are finite, every image error is finite,
//! the ground truth's Monte Carlo estimate is present, shading costs are counted), and frame
//! times read from a viewer-benchmark JSON written here by hand (so the test never runs the
//! viewer): each row gets the mean over the views of its label's cell in its format, and its
//! ratio to plain's; labels and formats the file lacks stay n/a.
#![cfg(feature = "report")]

use serde_json::json;
use std::path::Path;
use std::process::Command;

/// A benchmark file as `ndfmap-viewer --bench --bench-json` writes it: plain, Toksvig and vMF
/// J = 1 aligned in f32 (plain also in f16), two views.
fn frame_times_json() -> serde_json::Value {
    let cell = |view: &str, format: &str, ms: f64, plain: f64| json!({"view": view, "format": format, "median_ms": ms, "ratio_to_plain": ms / plain});
    let shader = |label: &str, far: f64, grazing: f64, formats: &[&str]| {
        let cells: Vec<_> = formats
            .iter()
            .flat_map(|f| {
                [
                    cell("plane-far", f, far, 2.0),
                    cell("plane-grazing", f, grazing, 10.0),
                ]
            })
            .collect();
        json!({"label": label, "sampling": "hardware", "cells": cells})
    };
    json!({
        "renderer": "llvmpipe (test)",
        "gl_version": "OpenGL 4.5",
        "route": "egl",
        "width": 64,
        "height": 36,
        "frames": 3,
        "warm_up": 2,
        "sample_size": 16,
        "views": [
            {"name": "plane-far", "covered_pixels": 300},
            {"name": "plane-grazing", "covered_pixels": 1200}
        ],
        "shaders": [
            shader("plain", 2.0, 10.0, &["f32", "f16"]),
            shader("toksvig", 2.5, 9.5, &["f32"]),
            shader("vmf1a", 5.0, 25.0, &["f32"]),
        ]
    })
}

#[test]
fn report_writes_markdown_json_plots_and_images() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rep");
    let frame_times = dir.path().join("frame-times.json");
    std::fs::write(&frame_times, frame_times_json().to_string()).unwrap();
    let status = Command::new(env!("CARGO_BIN_EXE_ndfmap"))
        .args([
            "report",
            "--sample-size",
            "32",
            "--size",
            "24",
            "--spp",
            "4",
            "--convergence-spp",
            "16",
            "--lobes",
            "1,2",
            "--align",
            "none,default",
            "--tan-lobes",
            "1",
            "--sh-lmax",
            "2",
            "--anisotropy",
            "4",
            "--no-stability",
            "--no-planner",
            "--frame-times",
        ])
        .arg(&frame_times)
        .arg("-o")
        .arg(&out)
        .env("NDFMAP_DATA", dir.path().join("no-maps-here"))
        .status()
        .unwrap();
    assert!(status.success());
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(
        md.contains("## sample") && md.contains("## Targets"),
        "{md}"
    );
    assert!(md.contains("`shL` = spherical harmonics"));
    // Anisotropic filtering: its floor per view and the linearly filtering configurations.
    assert!(md.contains("Anisotropic filtering (up to 4 probes"), "{md}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let rows = json["rows"].as_array().unwrap();
    // 4 baselines + sh2 + tan2005-1 + vMF 2 lobe counts × 2 alignments, in 3 formats (LEAN and
    // Tan refuse unorm8).
    assert_eq!(rows.len(), 10 * 3 - 2);
    for r in rows {
        assert!(r["texel_specular"].as_f64().unwrap().is_finite(), "{r}");
        for v in r["views"].as_array().unwrap() {
            assert!(v["rel_rmse"].as_f64().unwrap().is_finite(), "{v}");
            assert_eq!(v["nonfinite"], 0);
        }
        assert!(r["cost"]["fetches"].as_u64().unwrap() >= 1);
        // Anisotropic renders for the f32 rows that filter linearly (not unaligned mixtures).
        let linear =
            !(r["config"] == "vmf1" || r["config"] == "vmf2" || r["config"] == "tan2005-1");
        let aniso = r["aniso_views"].as_array().unwrap();
        assert_eq!(
            aniso.is_empty(),
            !(linear && r["format"] == "f32"),
            "{}",
            r["label"]
        );
        for v in aniso {
            assert!(v["rel_rmse"].as_f64().unwrap().is_finite(), "{v}");
        }
    }
    assert!(
        json["maps"][0]["views"][0]["aniso_floor"]["rel_rmse"]
            .as_f64()
            .is_some()
    );
    assert!(json["maps"][0]["ground_truth_error"][1].as_f64().unwrap() > 0.0);
    // Frame times: (far + grazing) / 2, and over plain's (2 + 10) / 2 = 6 ms.
    let frame = |config: &str, format: &str| {
        let r = rows
            .iter()
            .find(|r| r["config"] == config && r["format"] == format)
            .unwrap_or_else(|| panic!("no row {config} {format}"));
        (r["frame_ms"].as_f64(), r["frame_ratio"].as_f64())
    };
    assert_eq!(frame("plain", "f32"), (Some(6.0), Some(1.0)));
    assert_eq!(frame("plain", "f16"), (Some(6.0), Some(1.0)));
    assert_eq!(frame("toksvig", "f32"), (Some(6.0), Some(1.0)));
    assert_eq!(frame("vmf1a", "f32"), (Some(15.0), Some(2.5)));
    assert_eq!(frame("vmf1a", "f16"), (None, None));
    assert_eq!(frame("vmf1", "f32"), (None, None));
    assert_eq!(frame("tan2005-1", "f32"), (None, None));
    assert_eq!(json["frame_times"]["renderer"], "llvmpipe (test)");
    assert!(
        md.contains("| vmf1a | ") && md.contains("| 15.00 (2.50×) |"),
        "{md}"
    );
    assert!(
        md.contains("| 6.00 (1.00×) |") && md.contains("| n/a |"),
        "{md}"
    );
    assert!(md.contains("read the ratio to plain"), "{md}");
    for phase in [
        "ground_truth",
        "bake",
        "texel_eval",
        "compare",
        "frame_times",
    ] {
        assert!(
            json["phases"][phase]["wall"].as_f64().unwrap() >= 0.0,
            "{phase}"
        );
    }
    let images = out.join("images/sample");
    assert!(images.join("zoom5_ground_truth.png").exists());
    assert!(images.join("sphere_ideal.png").exists());
    assert!(images.join("grazing_toksvig_flip.png").exists());
    if Path::new("/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf").exists() {
        for stem in [
            "error_vs_bake_time",
            "error_vs_shading_cost",
            "error_vs_texture_memory",
            "error_vs_mip_level",
            "error_vs_frame_time",
        ] {
            assert!(out.join(format!("{stem}.png")).exists(), "{stem}");
            assert!(out.join(format!("{stem}.svg")).exists(), "{stem}");
        }
    }
}

/// `--env-albedo` needs `--env` and one image per map: one clear line each, before any
/// measuring (and no report written).
#[test]
fn env_albedo_is_refused_without_env_or_with_the_wrong_count() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rep");
    let run = |extra: &[&str]| {
        let o = Command::new(env!("CARGO_BIN_EXE_ndfmap"))
            .args([
                "report",
                "--sample-size",
                "16",
                "--no-stability",
                "--no-planner",
            ])
            .args(extra)
            .arg("-o")
            .arg(&out)
            .env("NDFMAP_DATA", dir.path().join("no-maps-here"))
            .output()
            .unwrap();
        assert!(!o.status.success(), "{extra:?}");
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let e = run(&["--env-albedo", "a.png"]);
    assert!(e.contains("--env-albedo") && e.contains("--env too"), "{e}");
    let e = run(&["--env", "sky", "--env-albedo", "a.png,b.png"]);
    assert!(e.contains("2 images for 1 maps"), "{e}");
    assert!(!out.join("report.md").exists());
}
