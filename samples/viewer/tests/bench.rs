//! `--bench --bench-json` on a tiny framebuffer and sample (1 frame): the JSON parses as
//! `ndfmap::report::frame::FrameTimes`, names the shaders by the report's labels (plain first,
//! added when not asked for), has a cell per view and accepted format (LEAN refuses unorm8, so
//! it has none there), and each ratio is its median over plain's. No time is asserted.
//! `NDFMAP_SKIP_GL=1` skips it, like the other GL tests.

use ndfmap::format::Format;
use ndfmap::report::frame::FrameTimes;
use std::process::Command;

#[test]
fn bench_json_names_the_report_labels() {
    if std::env::var("NDFMAP_SKIP_GL").is_ok_and(|v| v == "1") {
        println!("skipped: NDFMAP_SKIP_GL=1");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("frame-times.json");
    let out = Command::new(env!("CARGO_BIN_EXE_ndfmap-viewer"))
        .args([
            "--bench",
            "--size",
            "48x32",
            "--frames",
            "1",
            "--sample-size",
            "16",
            "--methods",
            "vmf2,lean,tan2005-1a",
            "--bench-formats",
            "f32,unorm8",
            "--bench-json",
        ])
        .arg(&json)
        .env("MESA_SHADER_CACHE_DISABLE", "true")
        .output()
        .expect("the viewer runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("| vmf2 | manual |"), "{stdout}");
    let t = FrameTimes::load(&json).unwrap();
    let labels: Vec<&str> = t.shaders.iter().map(|s| s.label.as_str()).collect();
    assert_eq!(labels, ["plain", "vmf2", "lean", "tan2005-1a"]);
    assert_eq!(
        (t.width, t.height, t.frames, t.sample_size),
        (48, 32, 1, 16)
    );
    let views: Vec<&str> = t.views.iter().map(|v| v.name.as_str()).collect();
    assert_eq!(views, ["plane-far", "plane-grazing"]);
    let sampling: Vec<&str> = t.shaders.iter().map(|s| s.sampling.as_str()).collect();
    assert_eq!(sampling, ["hardware", "manual", "hardware", "hardware"]);
    for s in &t.shaders {
        let formats: Vec<Format> = s.cells.iter().map(|c| c.format).collect();
        let expected = if s.label == "lean" || s.label.starts_with("tan2005") {
            vec![Format::F32; 2]
        } else {
            vec![Format::F32, Format::F32, Format::Unorm8, Format::Unorm8]
        };
        let mut sorted = formats.clone();
        sorted.sort_by_key(|f| f.name());
        assert_eq!(sorted, expected, "{}", s.label);
        for c in &s.cells {
            assert!(c.median_ms > 0.0 && c.median_ms.is_finite(), "{c:?}");
            let plain = t.shaders[0]
                .cells
                .iter()
                .find(|p| p.view == c.view && p.format == c.format)
                .unwrap();
            assert_eq!(c.ratio_to_plain, c.median_ms / plain.median_ms);
        }
    }
    assert!(t.shaders[0].cells.iter().all(|c| c.ratio_to_plain == 1.0));
    // What the report reads back: the mean over the views, over plain's.
    let (ms, ratio) = t.lookup("vmf2", Format::F32).unwrap();
    let cells = &t.shaders[1].cells;
    let mean = |cs: Vec<f64>| cs.iter().sum::<f64>() / cs.len() as f64;
    let of = |s: usize| {
        mean(
            t.shaders[s]
                .cells
                .iter()
                .filter(|c| c.format == Format::F32)
                .map(|c| c.median_ms)
                .collect(),
        )
    };
    assert_eq!(cells.len(), 4);
    assert_eq!(ms, of(1));
    assert_eq!(ratio, Some(of(1) / of(0)));
    assert_eq!(t.lookup("lean", Format::Unorm8), None);
}
