//! The planner section of the report (issue 18, `docs/planner.md`): a plan against the full
//! configuration (vMF J = 8 aligned, f32, colour, every level) on the same map — texture bytes,
//! bake seconds, shader fetches and ALU, and the texel-space error measured on the whole map
//! against the exact footprint average ([`crate::eval`]) beside the target and the plan's
//! prediction.

use crate::bake::{Bake, Method};
use crate::error::{Error, Result};
use crate::glsl::{ShaderOptions, ShaderSpec, Stage};
use crate::ingest::NormalMap;
use crate::plan::{FULL, Plan, WholeMap, bake_chains};
use serde::{Deserialize, Serialize};

/// Texels drawn per level of the whole map for the environment-lit measurement (the
/// planner's prediction draws [`crate::plan::ENV_TEXELS`] per level of each sample).
pub const VERIFY_ENV_TEXELS: usize = 192;

/// One scene's row: the plan against the full configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlannerRow {
    /// Parts of the plan (`L0-2 plain unorm8; L3-6 vmf3a f16`).
    pub plan: String,
    /// Seconds the planning took.
    pub plan_seconds: f64,
    /// Texture bytes: plan, full.
    pub bytes: (u64, u64),
    /// Bake seconds (every distinct configuration of the plan; the full configuration).
    pub bake_seconds: (f64, f64),
    /// Fetches per pixel (the plan's costliest part; full).
    pub fetches: (usize, usize),
    /// SPIR-V ALU instructions (the plan's costliest part; full), when glslangValidator ran.
    pub alu: (Option<u32>, Option<u32>),
    /// Per level shipped: (level, target, predicted, measured plan, measured full).
    pub levels: Vec<(usize, f64, f64, f64, f64)>,
    /// Whether every level meets its target.
    pub meets: bool,
    /// The largest of measured/predicted and predicted/measured over the levels whose
    /// errors exceed 0.1 % (the prediction's factor).
    pub prediction_factor: f64,
}

fn alu_of(src: &str) -> Option<u32> {
    crate::report::cost::spirv_text(src)
        .ok()
        .map(|t| crate::report::cost::count_spirv(&t).alu)
}

/// Measures `plan` (made for `map`) against the full configuration: bakes both, measures both
/// errors on the whole map at the plan's levels. `map` should carry the albedo as its feature
/// image when the scene has colour; the full configuration is baked with colour always (a
/// white albedo when the map has none).
pub fn measure(plan: &Plan, map: &NormalMap) -> Result<PlannerRow> {
    let first = plan.levels[0];
    let whole = WholeMap::new(plan, map, VERIFY_ENV_TEXELS)?;
    // The plan.
    let chains = bake_chains(plan, map)?;
    let mut measured = vec![f64::NAN; plan.levels[1] + 1];
    for (p, (b, _)) in plan.parts.iter().zip(&chains) {
        let e = whole.errors(b, p.first, p.last)?;
        measured[p.first..=p.last].copy_from_slice(&e[p.first..=p.last]);
    }
    let mut seen = Vec::new();
    let mut plan_bake = 0.0;
    for (p, (_, s)) in plan.parts.iter().zip(&chains) {
        if !seen.contains(&p.config) {
            seen.push(p.config);
            plan_bake += s;
        }
    }
    drop(chains);
    // The full configuration.
    let colored;
    let full_map = if map.feature().is_some() {
        map
    } else {
        colored = map
            .clone()
            .with_feature(vec![[1.0; 4]; map.normals().len()])?;
        &colored
    };
    let t = std::time::Instant::now();
    let full: Bake = crate::methods::bake_with(full_map, Method::Vmf, &FULL.bake_options())?;
    let full_seconds = t.elapsed().as_secs_f64();
    let fe = whole.errors(&full, first, plan.levels[1])?;
    // Shaders.
    let addressing = map.addressing();
    let plan_alu = (0..plan.parts.len())
        .map(|i| plan.shader(i, addressing).ok().and_then(|s| alu_of(&s)))
        .try_fold(0u32, |a, x| x.map(|x| a.max(x)));
    // The full configuration's shader (with its colour textures) is lit like the plan's.
    let full_options = ShaderOptions {
        color: true,
        ..plan.shader_options(0)
    };
    let full_alu = crate::glsl::source_for(&ShaderSpec::of(&full), Stage::Fragment, &full_options)
        .ok()
        .and_then(|s| alu_of(&s));
    let plan_fetches = plan
        .parts
        .iter()
        .map(|p| {
            let per = if p.config.method == Method::Vmf && !p.config.aligned {
                8
            } else {
                1
            };
            per * p.textures() * if p.color { 2 } else { 1 }
        })
        .max()
        .unwrap_or(0);
    let mut levels = Vec::new();
    let mut meets = true;
    let mut factor: f64 = 1.0;
    for pr in &plan.predictions {
        let k = pr.level;
        let m = measured[k];
        meets &= m <= pr.target;
        if m > 1e-3 || pr.predicted > 1e-3 {
            let (a, b) = (m.max(1e-3), pr.predicted.max(1e-3));
            factor = factor.max(a / b).max(b / a);
        }
        levels.push((k, pr.target, pr.predicted, m, fe[k]));
    }
    Ok(PlannerRow {
        plan: plan
            .parts
            .iter()
            .map(|p| {
                format!(
                    "L{}-{} {}{}{} {}",
                    p.first,
                    p.last,
                    p.config.label(),
                    if p.dropped.is_empty() {
                        String::new()
                    } else {
                        format!("-{}", p.dropped.len())
                    },
                    if p.color { "+colour" } else { "" },
                    p.format
                )
            })
            .collect::<Vec<_>>()
            .join("; "),
        plan_seconds: plan.seconds,
        bytes: (plan.bytes, plan.full_bytes),
        bake_seconds: (plan_bake, full_seconds),
        fetches: (plan_fetches, 2 * FULL.lobes),
        alu: (plan_alu, full_alu),
        levels,
        meets,
        prediction_factor: factor,
    })
}

impl PlannerRow {
    /// The row as Markdown: a summary line and the per-level table.
    pub fn markdown(&self, name: &str) -> String {
        use std::fmt::Write;
        let opt = |v: Option<u32>| v.map_or("n/a".to_string(), |v| v.to_string());
        let mut s = String::new();
        let _ = writeln!(
            s,
            "| {name} | {} | {} / {} ({:.2} %) | {:.2} / {:.1} | {} / {} | {} / {} | {:.2} | {} | {:.2} |",
            self.plan,
            self.bytes.0,
            self.bytes.1,
            100.0 * self.bytes.0 as f64 / self.bytes.1 as f64,
            self.bake_seconds.0,
            self.bake_seconds.1,
            self.fetches.0,
            self.fetches.1,
            opt(self.alu.0),
            opt(self.alu.1),
            self.plan_seconds,
            if self.meets { "yes" } else { "NO" },
            self.prediction_factor
        );
        let _ = writeln!(
            s,
            "\n| level | target | predicted | measured (plan) | measured (full) |"
        );
        let _ = writeln!(s, "|---|---|---|---|---|");
        for (k, t, p, m, f) in &self.levels {
            let _ = writeln!(
                s,
                "| {k} | {:.2} % | {:.2} % | {:.2} % | {:.2} % |",
                100.0 * t,
                100.0 * p,
                100.0 * m,
                100.0 * f
            );
        }
        s
    }
}

/// The report's contrasting scenes (`docs/planner/*.toml`, compiled in) and the shared map each
/// is planned for, with its albedo: (name, scene text, map file, albedo file).
pub const SCENES: [(&str, &str, &str, Option<&str>); 4] = [
    (
        "matte-far",
        include_str!("../../docs/planner/matte-far.toml"),
        "bark.jpg",
        None,
    ),
    (
        "glossy-metal-close",
        include_str!("../../docs/planner/glossy-metal-close.toml"),
        "metal.jpg",
        None,
    ),
    (
        "rough-stone-low-sun",
        include_str!("../../docs/planner/rough-stone-low-sun.toml"),
        "mossyrock.jpg",
        Some("mossyrock_albedo.jpg"),
    ),
    (
        "mixed-all-levels",
        include_str!("../../docs/planner/mixed-all-levels.toml"),
        "rock.jpg",
        None,
    ),
];

/// Side of the built-in sample the report plans the scenes for when the shared maps are
/// absent (1024²: the mixed scene reaches level 10).
pub const SAMPLE_SIDE: u32 = 1024;

/// One scene of the section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneRow {
    /// The scene's name (`matte-far`).
    pub scene: String,
    /// The map it was planned for (file name, or `sample`).
    pub map: String,
    /// The measurement.
    pub row: PlannerRow,
}

/// The report's planner section: the contrasting scenes planned and measured, and the scenes
/// that could not be (with why).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Section {
    /// Scenes measured.
    pub rows: Vec<SceneRow>,
    /// `scene: error` of the scenes that failed.
    pub failed: Vec<String>,
    /// Frame times of the plans against the full configuration, from
    /// [`FRAME_TIMES_FILE`] (written by the GL example `plan_timings --json`): the main crate
    /// cannot draw. `Err` says why there are none (absent, unreadable).
    #[serde(default = "no_frame_times")]
    pub frame_times: std::result::Result<FrameTimes, String>,
}

fn no_frame_times() -> std::result::Result<FrameTimes, String> {
    Err("not read".into())
}

impl Default for Section {
    fn default() -> Section {
        Section {
            rows: Vec::new(),
            failed: Vec::new(),
            frame_times: no_frame_times(),
        }
    }
}

/// The `format` field of a frame-times file.
pub const FRAME_TIMES_FORMAT: &str = "ndfmap-plan-frame-times";

/// Where the report looks for the plans' frame times: the file named by the environment
/// variable `NDFMAP_PLAN_FRAME_TIMES`, else this file in the working directory.
pub const FRAME_TIMES_FILE: &str = "plan_frame_times.json";

/// One scene and view drawn by `plan_timings`: medians over its frames.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameTime {
    /// The scene's name (the folder its `plan.json` lies in, `matte-far`).
    pub scene: String,
    /// The view (`plane-far`, `plane-grazing`).
    pub view: String,
    /// The full configuration's frame, ms.
    pub full_ms: f64,
    /// The plan's costliest part's frame, ms.
    pub plan_ms: f64,
    /// Every part's frame, ms.
    pub parts_ms: Vec<f64>,
    /// The plan's LOD-switching shader's frame (`lod_switch.frag`, every part in one shader,
    /// the same view), ms; absent where the plan has none or an older file.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub switch_ms: Option<f64>,
}

/// A frame-times file (`plan_timings --json FILE`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameTimes {
    /// Always [`FRAME_TIMES_FORMAT`].
    pub format: String,
    /// The GL renderer they were measured on (`llvmpipe ...`).
    pub device: String,
    /// Frames drawn per renderer (medians over them).
    pub frames: usize,
    /// One per scene and view.
    pub rows: Vec<FrameTime>,
}

impl FrameTimes {
    /// The file's text (JSON).
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_default() + "\n"
    }

    /// Parses a frame-times file; [`crate::Error::InvalidOption`] when it is not one or holds
    /// a time that is not a positive number.
    pub fn from_json(name: &str, text: &str) -> Result<FrameTimes> {
        let bad = |why: String| crate::Error::InvalidOption(format!("frame times {name}: {why}"));
        let t: FrameTimes = serde_json::from_str(text).map_err(|e| bad(e.to_string()))?;
        if t.format != FRAME_TIMES_FORMAT {
            return Err(bad(format!(
                "format '{}' (expected '{FRAME_TIMES_FORMAT}')",
                t.format
            )));
        }
        for r in &t.rows {
            let ok = |v: f64| v.is_finite() && v > 0.0;
            if !ok(r.full_ms)
                || !ok(r.plan_ms)
                || !r.parts_ms.iter().all(|&v| ok(v))
                || !r.switch_ms.is_none_or(ok)
            {
                return Err(bad(format!(
                    "{} {}: a frame time that is not a positive number",
                    r.scene, r.view
                )));
            }
        }
        Ok(t)
    }

    /// Reads [`FRAME_TIMES_FILE`] (or `NDFMAP_PLAN_FRAME_TIMES`): `Err` says plainly why
    /// there are none.
    pub fn find() -> std::result::Result<FrameTimes, String> {
        let path = std::env::var_os("NDFMAP_PLAN_FRAME_TIMES")
            .map(std::path::PathBuf::from)
            .unwrap_or_else(|| std::path::PathBuf::from(FRAME_TIMES_FILE));
        let name = path.display().to_string();
        match crate::ingest::read_text_file(&path) {
            Ok(text) => FrameTimes::from_json(&name, &text).map_err(|e| e.to_string()),
            Err(Error::Read { source, .. }) if source.kind() == std::io::ErrorKind::NotFound => {
                Err(format!(
                    "no frame times: {name} is absent (write it with `cargo run --release -p \
                 ndfmap-gl --example plan_timings -- --json {FRAME_TIMES_FILE} ...`, \
                 docs/planner.md)"
                ))
            }
            Err(e) => Err(format!("no frame times: {e}")),
        }
    }

    /// The frame times of `scene`, per view: `far: plan / full ms (ratio)`, and where
    /// measured `, switch ms (ratio to the plan)` for the LOD-switching shader.
    pub fn cell(&self, scene: &str) -> Option<String> {
        let cells: Vec<String> = self
            .rows
            .iter()
            .filter(|r| r.scene == scene)
            .map(|r| {
                let switch = r.switch_ms.map_or(String::new(), |s| {
                    format!(", switch {s:.1} ({:.2})", s / r.plan_ms)
                });
                format!(
                    "{}: {:.1} / {:.1} ({:.2}){switch}",
                    r.view.strip_prefix("plane-").unwrap_or(&r.view),
                    r.plan_ms,
                    r.full_ms,
                    r.plan_ms / r.full_ms
                )
            })
            .collect();
        (!cells.is_empty()).then(|| cells.join("; "))
    }
}

/// Plans and measures every scene of [`SCENES`] for its map in `data` (a folder holding the
/// shared maps), or for the built-in sample of side `sample_side` (with its albedo for a scene
/// whose map has one) where the map is absent. A scene that fails (a level range beyond a
/// small sample) is listed with its error. `step` is told each scene's name.
pub fn section(data: Option<&std::path::Path>, sample_side: u32, step: &dyn Fn(&str)) -> Section {
    let mut out = Section {
        frame_times: FrameTimes::find(),
        ..Section::default()
    };
    let mut sample = None;
    for (name, text, file, albedo) in SCENES {
        step(name);
        let result = (|| -> Result<SceneRow> {
            let scene = crate::plan::Scene::parse(name, text)?;
            let path = data.map(|d| d.join(file)).filter(|p| p.exists());
            let (map, label) = match path {
                Some(path) => {
                    let opts = crate::ingest::IngestOptions::default();
                    let mut map = NormalMap::load(&path, &opts)?;
                    if let Some(a) = albedo.map(|a| path.with_file_name(a)) {
                        map = map.with_feature_file(&a, &opts)?;
                    }
                    (map, file.to_string())
                }
                None => {
                    let s = sample
                        .get_or_insert_with(|| crate::procedural::generate(sample_side, 2007));
                    let map = if albedo.is_some() {
                        s.map.clone().with_feature(s.albedo.clone())?
                    } else {
                        s.map.clone()
                    };
                    (map, "sample".to_string())
                }
            };
            let plan = crate::plan::plan(&map, &scene, Some(&label))?;
            Ok(SceneRow {
                scene: name.to_string(),
                map: label,
                row: measure(&plan, &map)?,
            })
        })();
        match result {
            Ok(r) => out.rows.push(r),
            Err(e) => out.failed.push(format!("{name}: {e}")),
        }
    }
    out
}

/// The section as Markdown: the summary table, then each scene's per-level table.
pub fn markdown(section: &Section) -> String {
    use std::fmt::Write;
    let mut s = String::from("## Planner: contrasting scenes, planned against full\n\n");
    s += "Each scene of `docs/planner/` planned for its map (`ndfmap plan`), then the plan and \
          the full configuration (vMF J = 8 aligned, f32, colour, every level) baked and \
          measured on the whole map: texture bytes, bake seconds, fetches and SPIR-V ALU of \
          the costliest part's shader, planning seconds, and the scene's texel-space error \
          against its target and the plan's prediction (docs/planner.md).\n\n";
    if section.rows.is_empty() {
        s += "No scene was measured.\n\n";
    } else {
        s += "| scene | map | plan | bytes plan / full | bake s plan / full | fetches plan / full \
              | ALU plan / full | plan s | meets target | prediction factor | frame ms plan / full \
              |\n|---|---|---|---|---|---|---|---|---|---|---|\n";
        for r in &section.rows {
            let line = r.row.markdown(&r.scene);
            let first = line.lines().next().unwrap_or_default();
            // Insert the map after the scene's cell.
            let rest = first
                .strip_prefix(&format!("| {} |", r.scene))
                .unwrap_or(first);
            let frame = match &section.frame_times {
                Ok(t) => t.cell(&r.scene).unwrap_or_else(|| "not measured".into()),
                Err(_) => "n/a".into(),
            };
            let _ = writeln!(s, "| {} | {} |{rest} {frame} |", r.scene, r.map);
        }
        s += "\n";
        match &section.frame_times {
            Ok(t) => {
                let _ = writeln!(
                    s,
                    "Frame times: `plan_timings` on {} ({} frames, medians; the plan's costliest \
                     part against the full configuration over the whole plane view, 512²; \
                     `switch`: the plan's LOD-switching shader, every part in one, over the same \
                     view, and its ratio to the costliest part).\n",
                    t.device, t.frames
                );
            }
            Err(why) => {
                let _ = writeln!(s, "Frame times absent — {why}.\n");
            }
        }
        for r in &section.rows {
            let _ = writeln!(s, "**{}** ({})", r.scene, r.map);
            let md = r.row.markdown(&r.scene);
            let table: Vec<&str> = md.lines().skip(1).collect();
            let _ = writeln!(s, "{}\n", table.join("\n"));
        }
    }
    for f in &section.failed {
        let _ = writeln!(s, "Not measured: {f}\n");
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_times_are_read_checked_and_shown_or_said_absent() {
        let t = FrameTimes {
            format: FRAME_TIMES_FORMAT.into(),
            device: "llvmpipe".into(),
            frames: 9,
            rows: vec![
                FrameTime {
                    scene: "glossy-metal-close".into(),
                    view: "plane-far".into(),
                    full_ms: 25.0,
                    plan_ms: 5.0,
                    parts_ms: vec![5.0],
                    switch_ms: None,
                },
                FrameTime {
                    scene: "glossy-metal-close".into(),
                    view: "plane-grazing".into(),
                    full_ms: 40.0,
                    plan_ms: 30.0,
                    parts_ms: vec![30.0, 12.0],
                    switch_ms: Some(36.0),
                },
            ],
        };
        let back = FrameTimes::from_json("t", &t.to_json()).unwrap();
        assert_eq!(back, t);
        assert_eq!(
            t.cell("glossy-metal-close").unwrap(),
            "far: 5.0 / 25.0 (0.20); grazing: 30.0 / 40.0 (0.75), switch 36.0 (1.20)"
        );
        // A file without switch times (older plan_timings) still reads.
        let old = t.to_json().replace("      \"switch_ms\": 36.0\n", "");
        let old = old.replace("12.0\n      ],", "12.0\n      ]");
        assert_eq!(
            FrameTimes::from_json("t", &old).unwrap().rows[1].switch_ms,
            None,
            "{old}"
        );
        assert_eq!(t.cell("matte-far"), None);
        // Not a frame-times file, another format, a time that is not positive.
        assert!(FrameTimes::from_json("t", "{}").is_err());
        let mut other = t.clone();
        other.format = "ndfmap-plan".into();
        assert!(FrameTimes::from_json("t", &other.to_json()).is_err());
        let mut nan = t.clone();
        nan.rows[1].parts_ms[1] = -1.0;
        let mut zero = t.clone();
        zero.rows[1].switch_ms = Some(0.0);
        assert!(FrameTimes::from_json("t", &zero.to_json()).is_err());
        let e = FrameTimes::from_json("t", &nan.to_json())
            .unwrap_err()
            .to_string();
        assert!(e.contains("plane-grazing"), "{e}");
        // The section shows them in a column, or says plainly that they are absent.
        let row = PlannerRow {
            plan: "L0-2 plain unorm8".into(),
            plan_seconds: 0.2,
            bytes: (1, 100),
            bake_seconds: (0.1, 2.0),
            fetches: (1, 16),
            alu: (None, None),
            levels: vec![(0, 0.1, 0.05, 0.05, 0.0)],
            meets: true,
            prediction_factor: 1.0,
        };
        let mut sec = Section {
            rows: vec![SceneRow {
                scene: "glossy-metal-close".into(),
                map: "metal.jpg".into(),
                row,
            }],
            failed: Vec::new(),
            frame_times: Ok(t),
        };
        let md = markdown(&sec);
        assert!(
            md.contains(
                "| 1.00 | far: 5.0 / 25.0 (0.20); grazing: 30.0 / 40.0 (0.75), switch 36.0 (1.20) |"
            ),
            "{md}"
        );
        assert!(
            md.contains("Frame times: `plan_timings` on llvmpipe (9 frames"),
            "{md}"
        );
        sec.frame_times = Err("no frame times: plan_frame_times.json is absent".into());
        let md = markdown(&sec);
        assert!(md.contains("| 1.00 | n/a |"), "{md}");
        assert!(
            md.contains("Frame times absent — no frame times: plan_frame_times.json is absent"),
            "{md}"
        );
    }

    #[test]
    fn the_section_plans_every_scene_that_fits_and_names_those_that_do_not() {
        // A 128² sample (levels 0-7): the matte and the mixed scenes reach level 10.
        let sec = section(None, 128, &|_| {});
        let names: Vec<&str> = sec.rows.iter().map(|r| r.scene.as_str()).collect();
        assert_eq!(names, ["glossy-metal-close", "rough-stone-low-sun"]);
        assert_eq!(sec.failed.len(), 2);
        for f in &sec.failed {
            assert!(f.contains("view.levels"), "{f}");
        }
        for r in &sec.rows {
            assert_eq!(r.map, "sample");
            // Every scene meets its target at every level, measured on the whole map.
            assert!(r.row.meets, "{}: {:?}", r.scene, r.row.levels);
            assert!(r.row.bytes.0 < r.row.bytes.1);
            for &(_, target, _, measured, _) in &r.row.levels {
                assert!(measured.is_finite() && measured <= target);
            }
        }
        let md = markdown(&sec);
        assert!(md.contains("| glossy-metal-close | sample |"), "{md}");
        assert!(md.contains("Not measured: mixed-all-levels"), "{md}");
    }
}
