//! Frame times of the product shaders, measured by the sample viewer's benchmark
//! (`ndfmap-viewer --bench --bench-json PATH`, in `samples/viewer`), and how the report uses
//! them.
//!
//! The GL runtime lives in the workspace member `ndfmap-gl`, which depends on this crate, so
//! `ndfmap report` cannot draw by itself: it reads the benchmark's JSON ([`FrameTimes`], written
//! by the viewer through [`FrameTimes::to_json`]) from a file, or runs an `ndfmap-viewer` found
//! beside its own executable ([`viewer_beside`], [`run_viewer_bench`]). Shaders are named by the
//! report's configuration labels (`plain`, `tan2005-4`, `vmf6`, `vmf6a`, …: what
//! [`crate::bake::Bake::label`] gives in f32), so a row finds its cell by label and format
//! ([`FrameTimes::lookup`]); labels the benchmark did not draw stay without a frame time.

use crate::format::Format;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::process::Command;

/// One view of the benchmark.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BenchView {
    /// Its name (`plane-far`, `plane-grazing`).
    pub name: String,
    /// Pixels the surface covers.
    pub covered_pixels: u64,
}

/// The time of one shader in one view and texture format.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameCell {
    /// The view's name.
    pub view: String,
    /// Texture format of the uploads.
    pub format: Format,
    /// Median draw time, milliseconds (as [`FrameTimes::clock`] says).
    pub median_ms: f64,
    /// `median_ms` over the plain shader's in the same view and format.
    pub ratio_to_plain: f64,
}

/// One shader's times.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShaderTimes {
    /// The configuration label (`vmf6a`).
    pub label: String,
    /// `hardware` (one trilinear fetch per texture) or `manual` (8 texel fetches per texture).
    pub sampling: String,
    /// One cell per view and format drawn (formats the method refuses are absent).
    pub cells: Vec<FrameCell>,
}

/// What `ndfmap-viewer --bench` measured.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameTimes {
    /// `GL_RENDERER` (`llvmpipe (LLVM 15.0.6, 256 bits)`).
    pub renderer: String,
    /// The context's OpenGL version, as the viewer prints it.
    pub gl_version: String,
    /// How the context was created (`egl`, `osmesa`).
    pub route: String,
    /// Framebuffer width, pixels.
    pub width: u32,
    /// Framebuffer height, pixels.
    pub height: u32,
    /// Timed frames per shader, view and format.
    pub frames: u32,
    /// Untimed draws before them (the first compiles the shader).
    pub warm_up: u32,
    /// Side of the procedural sample map the shaders were baked from.
    pub sample_size: u32,
    /// The views.
    pub views: Vec<BenchView>,
    /// Per shader.
    pub shaders: Vec<ShaderTimes>,
    /// 1-minute load average at the start and the end of the benchmark (Linux).
    #[serde(default)]
    pub load_average: Option<(f64, f64)>,
    /// How each draw was timed (`each draw timed by a GL_TIME_ELAPSED query`); absent in files
    /// written before the GPU clock existed, which were all timed between two `glFinish` calls.
    #[serde(default)]
    pub clock: Option<String>,
}

impl FrameTimes {
    /// Pretty-printed JSON.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("frame times serialize")
    }

    /// Parses what [`FrameTimes::to_json`] wrote.
    pub fn from_json(text: &str) -> Result<FrameTimes, String> {
        serde_json::from_str(text).map_err(|e| e.to_string())
    }

    /// Reads a JSON file written by `ndfmap-viewer --bench --bench-json`.
    pub fn load(path: &Path) -> Result<FrameTimes, String> {
        let text = crate::ingest::read_text_file(path).map_err(|e| e.to_string())?;
        FrameTimes::from_json(&text).map_err(|e| format!("{}: {e}", path.display()))
    }

    /// Mean over the views of the median milliseconds of `label` in `format`; `None` unless
    /// the shader was drawn in that format in every view.
    pub fn mean_ms(&self, label: &str, format: Format) -> Option<f64> {
        let shader = self.shaders.iter().find(|s| s.label == label)?;
        let mut sum = 0.0;
        for view in &self.views {
            let cell = shader
                .cells
                .iter()
                .find(|c| c.view == view.name && c.format == format)?;
            sum += cell.median_ms;
        }
        (!self.views.is_empty()).then(|| sum / self.views.len() as f64)
    }

    /// The frame time of configuration `label` in `format`: [`FrameTimes::mean_ms`], and its
    /// ratio to plain's in the same format (`None` when either was not drawn).
    pub fn lookup(&self, label: &str, format: Format) -> Option<(f64, Option<f64>)> {
        let ms = self.mean_ms(label, format)?;
        let ratio = self
            .mean_ms("plain", format)
            .filter(|p| *p > 0.0)
            .map(|p| ms / p);
        Some((ms, ratio))
    }

    /// One sentence on how these times were taken, for the report.
    pub fn describe(&self) -> String {
        format!(
            "`ndfmap-viewer --bench` on `{}` ({}, {} route), {}×{}, shaders baked from the \
             procedural sample at {}², median of {} frames after {} warm-up draws ({}, shaders \
             round robin), mean over the views {}",
            self.renderer,
            self.gl_version,
            self.route,
            self.width,
            self.height,
            self.sample_size,
            self.frames,
            self.warm_up,
            self.clock
                .as_deref()
                .unwrap_or("each draw timed between two glFinish calls"),
            self.views
                .iter()
                .map(|v| format!("`{}`", v.name))
                .collect::<Vec<_>>()
                .join(" and "),
        )
    }
}

/// How [`run_viewer_bench`] runs the benchmark.
#[derive(Debug, Clone, PartialEq)]
pub struct BenchSettings {
    /// Framebuffer width and height, pixels.
    pub size: (u32, u32),
    /// Timed frames.
    pub frames: u32,
    /// Side of the procedural sample the shaders are baked from.
    pub sample_size: u32,
    /// Shaders (configuration labels; plain is always drawn, as the ratios' base).
    pub labels: Vec<String>,
    /// Texture formats.
    pub formats: Vec<Format>,
}

impl Default for BenchSettings {
    /// 640 × 360 (a quarter of the viewer's default 1280 × 720), 8 frames, a 256² sample, f32:
    /// the report's 15 configurations in its 3 formats took 8 s on llvmpipe on 2 idle cores
    /// (14 s at load average 4), the sample's bakes included.
    fn default() -> Self {
        BenchSettings {
            size: (640, 360),
            frames: 8,
            sample_size: 256,
            labels: Vec::new(),
            formats: vec![Format::F32],
        }
    }
}

/// The `ndfmap-viewer` executable in the folder of `exe` (the same cargo target folder), if
/// there is one.
pub fn viewer_beside(exe: &Path) -> Option<PathBuf> {
    let dir = exe.parent()?;
    let name = format!("ndfmap-viewer{}", std::env::consts::EXE_SUFFIX);
    let path = dir.join(name);
    path.is_file().then_some(path)
}

/// Runs `viewer --bench` with `settings`, writing its JSON to a temporary file, and reads it
/// back. The viewer's Markdown table and progress lines are discarded; its error, if any, is
/// returned.
pub fn run_viewer_bench(viewer: &Path, settings: &BenchSettings) -> Result<FrameTimes, String> {
    let json = std::env::temp_dir().join(format!("ndfmap-frame-times-{}.json", std::process::id()));
    let formats: Vec<String> = settings.formats.iter().map(|f| f.to_string()).collect();
    let mut cmd = Command::new(viewer);
    cmd.arg("--bench")
        .arg("--bench-json")
        .arg(&json)
        .arg("--size")
        .arg(format!("{}x{}", settings.size.0, settings.size.1))
        .arg("--frames")
        .arg(settings.frames.to_string())
        .arg("--sample-size")
        .arg(settings.sample_size.to_string())
        .arg("--bench-formats")
        .arg(formats.join(","));
    if !settings.labels.is_empty() {
        cmd.arg("--methods").arg(settings.labels.join(","));
    }
    let out = cmd
        .output()
        .map_err(|e| format!("{} not run: {e}", viewer.display()))?;
    let result = if out.status.success() {
        FrameTimes::load(&json)
    } else {
        let stderr = String::from_utf8_lossy(&out.stderr);
        let last = stderr.lines().rev().find(|l| !l.trim().is_empty());
        Err(format!(
            "{} --bench failed ({}): {}",
            viewer.display(),
            out.status,
            last.unwrap_or("no message")
        ))
    };
    let _ = std::fs::remove_file(&json);
    result
}

/// Parses an image size `WxH` (each side 1 to 8192), as the benchmark's `--size` and the
/// report's `--bench-size` take it.
pub fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("'{s}': expected WxH"))?;
    let parse = |v: &str| {
        v.parse::<u32>()
            .ok()
            .filter(|v| (1..=8192).contains(v))
            .ok_or_else(|| format!("'{s}': sizes are 1 to 8192"))
    };
    Ok((parse(w)?, parse(h)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_as_wxh() {
        assert_eq!(parse_size("640x360"), Ok((640, 360)));
        assert_eq!(parse_size("8X8192"), Ok((8, 8192)));
        for bad in ["640", "0x360", "640x8193", "ax3", ""] {
            assert!(parse_size(bad).is_err(), "{bad}");
        }
    }

    fn cell(view: &str, format: Format, ms: f64, plain: f64) -> FrameCell {
        FrameCell {
            view: view.into(),
            format,
            median_ms: ms,
            ratio_to_plain: ms / plain,
        }
    }

    fn sample() -> FrameTimes {
        let views = ["plane-far", "plane-grazing"];
        let plain = [2.0, 10.0];
        let shader = |label: &str, ms: [f64; 2], formats: &[Format]| ShaderTimes {
            label: label.into(),
            sampling: "hardware".into(),
            cells: formats
                .iter()
                .flat_map(|&f| (0..2).map(move |v| cell(views[v], f, ms[v], plain[v])))
                .collect(),
        };
        FrameTimes {
            renderer: "test".into(),
            gl_version: "4.5".into(),
            route: "egl".into(),
            width: 64,
            height: 36,
            frames: 3,
            warm_up: 2,
            sample_size: 16,
            views: views
                .iter()
                .map(|v| BenchView {
                    name: v.to_string(),
                    covered_pixels: 100,
                })
                .collect(),
            shaders: vec![
                shader("plain", plain, &[Format::F32, Format::F16]),
                shader("tan2005-4", [8.0, 40.0], &[Format::F32]),
                shader("vmf6a", [9.0, 21.0], &[Format::F32, Format::F16]),
            ],
            load_average: Some((0.5, 0.75)),
            clock: None,
        }
    }

    #[test]
    fn json_round_trip_is_exact() {
        let mut t = sample();
        // Values whose shortest decimal form serde_json reads back 1 ulp off without its
        // `float_roundtrip` feature (the first was met in a benchmark file).
        t.shaders[1].cells[0].ratio_to_plain = 3.0809765235273754;
        t.shaders[1].cells[1].median_ms = std::f64::consts::PI / 7.0e3;
        let back = FrameTimes::from_json(&t.to_json()).unwrap();
        assert_eq!(back, t);
        // Written before load_average existed: still reads.
        let mut v: serde_json::Value = serde_json::from_str(&t.to_json()).unwrap();
        v.as_object_mut().unwrap().remove("load_average");
        let old = FrameTimes::from_json(&v.to_string()).unwrap();
        assert_eq!(old.load_average, None);
    }

    #[test]
    fn lookup_averages_the_views_and_divides_by_plain() {
        let t = sample();
        // plain: (2 + 10) / 2 = 6 ms; vmf6a: (9 + 21) / 2 = 15 ms, 2.5 × plain.
        assert_eq!(t.lookup("plain", Format::F32), Some((6.0, Some(1.0))));
        assert_eq!(t.lookup("vmf6a", Format::F16), Some((15.0, Some(2.5))));
        assert_eq!(t.lookup("tan2005-4", Format::F32), Some((24.0, Some(4.0))));
        // Not drawn in that format, or not at all (a J the benchmark lacks).
        assert_eq!(t.lookup("tan2005-4", Format::F16), None);
        assert_eq!(t.lookup("vmf3a", Format::F32), None);
        assert_eq!(t.lookup("vmf6a", Format::Unorm8), None);
    }

    #[test]
    fn viewer_beside_needs_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let exe = dir.path().join("ndfmap");
        assert_eq!(viewer_beside(&exe), None);
        let viewer = dir
            .path()
            .join(format!("ndfmap-viewer{}", std::env::consts::EXE_SUFFIX));
        std::fs::write(&viewer, b"").unwrap();
        assert_eq!(viewer_beside(&exe), Some(viewer));
    }
}
