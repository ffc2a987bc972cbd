//! `ndfmap report` end to end on a tiny built-in sample: the files it promises, and numbers that
//! hold whatever the map (level-0-free texel errors are finite, every image error is finite,
//! the ground truth's Monte Carlo estimate is present, shading costs are counted).
#![cfg(feature = "report")]

use std::path::Path;
use std::process::Command;

#[test]
fn report_writes_markdown_json_plots_and_images() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rep");
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
            "none,0.1",
            "--tan-lobes",
            "1",
            "--no-stability",
            "-o",
        ])
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
    assert!(md.contains("SH: not implemented yet"));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let rows = json["rows"].as_array().unwrap();
    // 4 baselines + tan2005-1 + vMF 2 lobe counts × 2 alignments, in 3 formats (LEAN and Tan
    // refuse unorm8).
    assert_eq!(rows.len(), 9 * 3 - 2);
    for r in rows {
        assert!(r["texel_specular"].as_f64().unwrap().is_finite(), "{r}");
        for v in r["views"].as_array().unwrap() {
            assert!(v["rel_rmse"].as_f64().unwrap().is_finite(), "{v}");
            assert_eq!(v["nonfinite"], 0);
        }
        assert!(r["cost"]["fetches"].as_u64().unwrap() >= 1);
    }
    assert!(json["maps"][0]["ground_truth_error"][1].as_f64().unwrap() > 0.0);
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
        ] {
            assert!(out.join(format!("{stem}.png")).exists(), "{stem}");
            assert!(out.join(format!("{stem}.svg")).exists(), "{stem}");
        }
    }
}
