//! Shading cost of a specialized fragment shader, counted statically from its SPIR-V.
//!
//! Texture fetches per pixel follow from the specialization: hardware sampling issues one
//! `textureLod` per texture (8 texel taps each, trilinear), manual sampling one `texelFetch` per
//! texture for each of 4 texels on each of 2 levels. ALU operations come from compiling the
//! specialized GLSL to SPIR-V with `glslangValidator -G` (Debian `glslang-tools`) and counting
//! arithmetic instructions (float/int arithmetic, comparisons, selects, conversions, dot
//! products and every `GLSL.std.450` call such as `pow`, `sqrt`, `normalize` as one each,
//! whatever the vector width): calls are inlined, instructions inside a loop are multiplied by
//! the loop's trip count (the constant its `<` test compares with: `NDF_LOBES`, 4 texels), and
//! both sides of every branch are counted (a static worst path — the second level of manual
//! sampling included). Loads, stores, access chains, composites and branches are not counted.

use crate::bake::Bake;
use crate::glsl::{ShaderOptions, ShaderSpec, Stage, manual_sampling, sampled_textures, source};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::process::Command;

/// Per-pixel shading cost of one specialized shader.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShaderCost {
    /// Texture sampling instructions per pixel (`textureLod` or `texelFetch`).
    pub fetches: u32,
    /// Texels read per pixel (8 per trilinear `textureLod`, 1 per `texelFetch`).
    pub texel_taps: u32,
    /// Arithmetic SPIR-V instructions per pixel (module docs), when `glslangValidator` ran.
    pub alu: Option<u32>,
    /// Sampling instructions found in the SPIR-V, weighted like the ALU count: a cross-check
    /// of `fetches`.
    pub spirv_fetches: Option<u32>,
    /// Why `alu` is missing, when it is.
    pub note: Option<String>,
}

/// The cost of `bake`'s fragment shader with default options (Blinn-Phong, its natural
/// sampling, no colour).
pub fn shader_cost(bake: &Bake) -> ShaderCost {
    let options = ShaderOptions::default();
    let spec = ShaderSpec::of(bake);
    let manual = manual_sampling(&spec, &options);
    let textures = sampled_textures(&spec, &options).unwrap_or(0) as u32;
    let (fetches, texel_taps) = if manual {
        (8 * textures, 8 * textures)
    } else {
        (textures, 8 * textures)
    };
    let mut cost = ShaderCost {
        fetches,
        texel_taps,
        alu: None,
        spirv_fetches: None,
        note: None,
    };
    match source(bake, Stage::Fragment, &options)
        .map_err(|e| e.to_string())
        .and_then(|src| spirv_text(&src))
    {
        Ok(text) => {
            let counts = count_spirv(&text);
            cost.alu = Some(counts.alu);
            cost.spirv_fetches = Some(counts.fetches);
        }
        Err(e) => cost.note = Some(e),
    }
    cost
}

/// Compiles a fragment shader to SPIR-V for OpenGL and returns the human-readable listing.
pub(crate) fn spirv_text(src: &str) -> Result<String, String> {
    // One folder per call: calls may run in parallel, also on the same source.
    static CALLS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let call = CALLS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let dir = std::env::temp_dir().join(format!(
        "ndfmap-cost-{}-{call}-{:x}",
        std::process::id(),
        fxhash(src)
    ));
    std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
    let frag = dir.join("shader.frag");
    let spv = dir.join("shader.spv");
    std::fs::write(&frag, src).map_err(|e| e.to_string())?;
    let out = Command::new("glslangValidator")
        .args(["-G", "--aml", "--amb", "-H", "-o"])
        .arg(&spv)
        .arg(&frag)
        .output();
    let _ = std::fs::remove_dir_all(&dir);
    let out = out.map_err(|e| format!("glslangValidator not run: {e}"))?;
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    if !out.status.success() {
        let first = text
            .lines()
            .find(|l| l.contains("ERROR"))
            .unwrap_or("failed")
            .to_string();
        return Err(format!("glslangValidator: {first}"));
    }
    Ok(text)
}

/// A small string hash for temporary file names.
fn fxhash(s: &str) -> u64 {
    s.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ b as u64).wrapping_mul(0x100_0000_01b3)
    })
}

/// Weighted instruction counts of a SPIR-V listing.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SpirvCounts {
    /// Arithmetic instructions.
    pub alu: u32,
    /// Image sampling and fetch instructions.
    pub fetches: u32,
}

const ALU_OPS: &[&str] = &[
    "FAdd",
    "FSub",
    "FMul",
    "FDiv",
    "FMod",
    "FRem",
    "FNegate",
    "IAdd",
    "ISub",
    "IMul",
    "SDiv",
    "UDiv",
    "SMod",
    "SNegate",
    "Dot",
    "VectorTimesScalar",
    "MatrixTimesVector",
    "VectorTimesMatrix",
    "MatrixTimesScalar",
    "ExtInst",
    "Select",
    "ConvertFToS",
    "ConvertSToF",
    "ConvertFToU",
    "ConvertUToF",
    "Bitcast",
    "ShiftRightLogical",
    "ShiftRightArithmetic",
    "ShiftLeftLogical",
    "BitwiseAnd",
    "BitwiseOr",
    "BitwiseXor",
    "LogicalAnd",
    "LogicalOr",
    "LogicalNot",
    "LogicalEqual",
    "LogicalNotEqual",
    "IEqual",
    "INotEqual",
    "SLessThan",
    "SLessThanEqual",
    "SGreaterThan",
    "SGreaterThanEqual",
    "ULessThan",
    "UGreaterThan",
    "FOrdEqual",
    "FOrdNotEqual",
    "FOrdLessThan",
    "FOrdLessThanEqual",
    "FOrdGreaterThan",
    "FOrdGreaterThanEqual",
    "FUnordEqual",
    "FUnordNotEqual",
    "FUnordLessThan",
    "FUnordLessThanEqual",
    "FUnordGreaterThan",
    "FUnordGreaterThanEqual",
    "IsNan",
    "IsInf",
    "Any",
    "All",
];

const FETCH_OPS: &[&str] = &[
    "ImageSampleImplicitLod",
    "ImageSampleExplicitLod",
    "ImageFetch",
];

/// One parsed instruction: result id, opcode without the `Op` prefix, operands after it.
struct Instruction {
    result: Option<String>,
    op: String,
    operands: Vec<String>,
}

/// The id in an operand: `%12`, `12`, or glslang's `12(name)` all give `12`.
fn id_of(token: &str) -> String {
    let t = token.trim_start_matches('%');
    t.split('(').next().unwrap_or(t).to_string()
}

/// Parses a line of `glslangValidator -H` (`12: 6(float) FMul 10 11`) or `spirv-dis`
/// (`%12 = OpFMul %float %10 %11`) listings.
fn parse_line(line: &str) -> Option<Instruction> {
    let toks: Vec<&str> = line.split_whitespace().collect();
    if toks.is_empty() || toks[0].starts_with("//") {
        return None;
    }
    let (result, rest) = if toks.len() > 2 && toks[1] == "=" {
        (Some(id_of(toks[0])), &toks[2..])
    } else if let Some(r) = toks[0].strip_suffix(':') {
        (Some(id_of(r)), &toks[1..])
    } else {
        (None, &toks[..])
    };
    let pos = rest.iter().position(|t| {
        t.chars().all(|c| c.is_ascii_alphanumeric())
            && t.starts_with(|c: char| c.is_ascii_uppercase())
    })?;
    let op = rest[pos]
        .strip_prefix("Op")
        .unwrap_or(rest[pos])
        .to_string();
    Some(Instruction {
        result,
        op,
        operands: rest[pos + 1..].iter().map(|t| t.to_string()).collect(),
    })
}

/// One instruction of interest in a function body.
enum Item {
    Alu,
    Fetch,
    Call(String),
    /// A loop header: the merge label and the instructions' multiplier inside.
    LoopStart(String),
    Label(String),
    /// `%id = OpSLessThan ... %a %b` inside a loop: a candidate trip count.
    Compare(String),
}

/// Counts arithmetic and fetch instructions reachable from the entry point `main` of a
/// `glslangValidator -H` listing (module docs for the weighting).
pub fn count_spirv(text: &str) -> SpirvCounts {
    let mut constants: HashMap<String, i64> = HashMap::new();
    let mut names: HashMap<String, String> = HashMap::new();
    let mut functions: HashMap<String, Vec<Item>> = HashMap::new();
    let mut current: Option<(String, Vec<Item>)> = None;
    for line in text.lines() {
        let Some(ins) = parse_line(line) else {
            continue;
        };
        let op = ins.op.as_str();
        let operands = &ins.operands;
        match op {
            "Name" if operands.len() >= 2 => {
                names.insert(
                    id_of(&operands[0]),
                    operands[1].trim_matches('"').to_string(),
                );
            }
            "Constant" => {
                if let (Some(r), Some(v)) = (&ins.result, operands.last())
                    && let Ok(v) = v.parse::<i64>()
                {
                    constants.insert(r.clone(), v);
                }
            }
            "Function" => {
                if let Some(r) = ins.result {
                    current = Some((r, Vec::new()));
                }
            }
            "FunctionEnd" => {
                if let Some((id, items)) = current.take() {
                    functions.insert(id, items);
                }
            }
            _ => {
                let Some((_, items)) = current.as_mut() else {
                    continue;
                };
                if op == "FunctionCall" && !operands.is_empty() {
                    items.push(Item::Call(id_of(&operands[0])));
                } else if op == "LoopMerge" && !operands.is_empty() {
                    items.push(Item::LoopStart(id_of(&operands[0])));
                } else if op == "Label" {
                    if let Some(r) = ins.result {
                        items.push(Item::Label(r));
                    }
                } else if FETCH_OPS.contains(&op) {
                    items.push(Item::Fetch);
                } else if ALU_OPS.contains(&op) {
                    items.push(Item::Alu);
                    if matches!(op, "SLessThan" | "ULessThan")
                        && let Some(b) = operands.last()
                    {
                        items.push(Item::Compare(id_of(b)));
                    }
                }
            }
        }
    }
    let main = names
        .iter()
        .find(|(_, n)| n.as_str() == "main" || n.starts_with("main("))
        .map(|(id, _)| id.clone());
    let mut memo: HashMap<String, SpirvCounts> = HashMap::new();
    match main {
        Some(main) => cost_of(&main, &functions, &constants, &mut memo, 0),
        None => SpirvCounts::default(),
    }
}

fn cost_of(
    id: &str,
    functions: &HashMap<String, Vec<Item>>,
    constants: &HashMap<String, i64>,
    memo: &mut HashMap<String, SpirvCounts>,
    depth: usize,
) -> SpirvCounts {
    if let Some(c) = memo.get(id) {
        return *c;
    }
    let Some(items) = functions.get(id) else {
        return SpirvCounts::default();
    };
    if depth > 64 {
        return SpirvCounts::default();
    }
    // Open loops: (merge label, trip count found so far, counts inside).
    let mut stack: Vec<(String, Option<i64>, SpirvCounts)> = Vec::new();
    let mut top = SpirvCounts::default();
    for item in items {
        let add = |stack: &mut Vec<(String, Option<i64>, SpirvCounts)>,
                   top: &mut SpirvCounts,
                   c: SpirvCounts| {
            let target = stack.last_mut().map_or(top, |s| &mut s.2);
            target.alu += c.alu;
            target.fetches += c.fetches;
        };
        match item {
            Item::Alu => add(&mut stack, &mut top, SpirvCounts { alu: 1, fetches: 0 }),
            Item::Fetch => add(&mut stack, &mut top, SpirvCounts { alu: 0, fetches: 1 }),
            Item::Call(f) => {
                let c = cost_of(f, functions, constants, memo, depth + 1);
                add(&mut stack, &mut top, c);
            }
            Item::LoopStart(merge) => stack.push((merge.clone(), None, SpirvCounts::default())),
            Item::Compare(b) => {
                if let Some(s) = stack.last_mut()
                    && s.1.is_none()
                {
                    s.1 = constants.get(b).copied();
                }
            }
            Item::Label(l) => {
                while stack.last().is_some_and(|s| &s.0 == l) {
                    let (_, trip, inner) = stack.pop().expect("checked");
                    let n = trip.unwrap_or(1).max(1) as u32;
                    add(
                        &mut stack,
                        &mut top,
                        SpirvCounts {
                            alu: inner.alu * n,
                            fetches: inner.fetches * n,
                        },
                    );
                }
            }
        }
    }
    memo.insert(id.to_string(), top);
    top
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spirv_fetch_counts_match_the_sampling_formula() {
        // Needs glslangValidator (Debian glslang-tools); skipped without it.
        if Command::new("glslangValidator")
            .arg("--version")
            .output()
            .is_err()
        {
            eprintln!("skipped: glslangValidator not found");
            return;
        }
        let map = crate::procedural::generate(8, 1).map;
        for (method, lobes, align) in [
            (crate::bake::Method::Vmf, 2, None),
            (crate::bake::Method::Vmf, 3, Some(0.1)),
            (crate::bake::Method::Tan2005, 2, None),
            (crate::bake::Method::Olano, 0, None),
        ] {
            let opts = crate::bake::BakeOptions {
                lobes: lobes.max(1),
                align,
                ..Default::default()
            };
            let b = crate::methods::bake_with(&map, method, &opts).unwrap();
            let c = shader_cost(&b);
            assert_eq!(c.spirv_fetches, Some(c.fetches), "{method} {lobes}: {c:?}");
            assert!(c.alu.is_some_and(|a| a > 10), "{c:?}");
        }
    }

    #[test]
    fn loops_multiply_and_calls_inline() {
        // A hand-written listing: main calls f twice; f has a loop of 3 trips holding 2 ALU
        // ops and a fetch, plus 1 op outside.
        let text = r#"
                              Name 4  "main"
                              Name 8  "f("
              12:      6(int) Constant 3
               4:           2 Function None 3
               5:             Label
              20:    7(float) FunctionCall 8(f() 
              21:    7(float) FunctionCall 8(f()
                              Return
                              FunctionEnd
               8:    7(float) Function None 9
              30:             Label
                              Branch 31
              31:             Label
                              LoopMerge 33 34 None
                              Branch 35
              35:             Label
              36:      6(int) Load 15
              37:    38(bool) SLessThan 36 12
                              BranchConditional 37 32 33
              32:             Label
              40:    7(float) FMul 41 42
              43:   44(fvec4) ImageSampleExplicitLod 45 46 Lod 47
                              Branch 34
              34:             Label
                              Branch 31
              33:             Label
              50:    7(float) FAdd 40 40
                              ReturnValue 50
                              FunctionEnd
"#;
        let c = count_spirv(text);
        // Per call: loop (SLessThan + FMul) × 3 = 6, + FAdd = 7 ALU, 3 fetches.
        assert_eq!(
            c,
            SpirvCounts {
                alu: 14,
                fetches: 6
            }
        );
    }
}
