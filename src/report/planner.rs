//! The planner section of the report (issue 18, `docs/planner.md`): a plan against the full
//! configuration (vMF J = 8 aligned, f32, colour, every level) on the same map — texture bytes,
//! bake seconds, shader fetches and ALU, and the texel-space error measured on the whole map
//! against the exact footprint average ([`crate::eval`]) beside the target and the plan's
//! prediction.

use crate::bake::{Bake, Method};
use crate::error::Result;
use crate::glsl::{ShaderOptions, ShaderSpec, Stage};
use crate::ingest::NormalMap;
use crate::plan::{FULL, Plan, WholeMap, bake_chains};
use serde::Serialize;

/// Texels drawn per level of the whole map for the environment-lit measurement (the
/// planner's prediction draws [`crate::plan::ENV_TEXELS`] per level of each sample).
pub const VERIFY_ENV_TEXELS: usize = 192;

/// One scene's row: the plan against the full configuration.
#[derive(Debug, Clone, Serialize)]
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
