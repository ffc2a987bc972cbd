//! `ndfmap plan` and `ndfmap bake --plan` (issue 18): a plan is written with its shaders and
//! decisions, bakes into one folder mixing methods with a manifest that says so, and bad
//! scenes and plans for another map are one-line errors that write nothing.

mod common;

use common::{assert_one_line_error, ndfmap};
use std::path::Path;

/// A bumpy 64² normal map (the procedural sample encoded as PNG).
fn write_map(path: &Path, seed: u64) {
    let s = ndfmap::procedural::generate(64, seed);
    let rgb = ndfmap::procedural::encode_rgb8(s.map.normals());
    image::RgbImage::from_raw(64, 64, rgb)
        .unwrap()
        .save(path)
        .unwrap();
}

const SCENE: &str = r#"
lights = ["point", "environment"]
[material]
model = "blinn-phong"
exponent = [16, 64]
kd = 0.5
ks = 0.5
[view]
levels = [1, 6]
[target]
per_level = [0.05, 0.08, 0.10, 0.10, 0.10, 0.10]
"#;

#[test]
fn plan_then_bake_the_plan() {
    let dir = tempfile::tempdir().unwrap();
    let map = dir.path().join("map.png");
    write_map(&map, 3);
    let scene = dir.path().join("scene.toml");
    std::fs::write(&scene, SCENE).unwrap();
    let out = dir.path().join("plan");
    let run = ndfmap(&[
        "plan",
        scene.to_str().unwrap(),
        map.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--explain",
    ]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let explain = String::from_utf8_lossy(&run.stdout);
    assert!(explain.contains("level 0: left out") || explain.contains("levels 0-0: left out"));
    let plan: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("plan.json")).unwrap()).unwrap();
    let parts = plan["parts"].as_array().unwrap();
    assert!(!parts.is_empty());
    assert_eq!(plan["levels"], serde_json::json!([1, 6]));
    for (i, _) in parts.iter().enumerate() {
        let frag = std::fs::read_to_string(out.join(format!("part{i}.frag"))).unwrap();
        assert!(frag.starts_with("#version 330 core"));
        // No environment code exists; Blinn-Phong compiles no other BRDF's path.
        assert!(!frag.contains("#define NDF_BRDF_GGX"));
    }
    // The one shader switching method by LOD (issue 18): every level shipped, in one file.
    let switch = std::fs::read_to_string(out.join("lod_switch.frag")).unwrap();
    assert!(switch.starts_with("#version 330 core"));
    assert!(switch.contains("shader switching method by level of detail"));
    assert!(switch.contains("ndf_p0_tex0"));
    let first = parts[0]["first"].as_u64().unwrap();
    let last = parts[parts.len() - 1]["last"].as_u64().unwrap();
    assert!(switch.contains(&format!("lambda = clamp(lod, {first}.0, {last}.0);")));
    // Bake it.
    let baked = dir.path().join("baked");
    let run = ndfmap(&[
        "bake",
        map.to_str().unwrap(),
        "--plan",
        out.join("plan.json").to_str().unwrap(),
        "-o",
        baked.to_str().unwrap(),
    ]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(baked.join("manifest.json")).unwrap())
            .unwrap();
    assert_eq!(m["format"], "ndfmap-plan-bake");
    assert_eq!(m["mixed"], true);
    let mparts = m["parts"].as_array().unwrap();
    assert_eq!(mparts.len(), parts.len());
    let mut next = 1;
    for p in mparts {
        assert_eq!(p["first"], next);
        next = p["last"].as_u64().unwrap() + 1;
        for t in p["textures"].as_array().unwrap() {
            for f in t["files"].as_array().unwrap() {
                assert!(baked.join(f.as_str().unwrap()).is_file(), "{f}");
            }
        }
    }
    assert_eq!(next, 7);
    // The LOD-switching shader is written beside the textures, the same as the plan's, and the
    // manifest says which textures of which parts its samplers read.
    let ls = &m["lod_switch"];
    assert_eq!(ls["shader"], "lod_switch.frag", "{ls}");
    assert!(ls.get("not_built").is_none());
    assert_eq!(
        std::fs::read_to_string(baked.join("lod_switch.frag")).unwrap(),
        switch
    );
    let sparts = ls["parts"].as_array().unwrap();
    assert!(!sparts.is_empty() && sparts.len() <= mparts.len());
    let (mut next, mut next_part) = (1, 0);
    for (k, sp) in sparts.iter().enumerate() {
        assert_eq!(sp["first"], next);
        next = sp["last"].as_u64().unwrap() + 1;
        let members: Vec<u64> = sp["plan_parts"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_u64().unwrap())
            .collect();
        // Consecutive plan parts, covering exactly this part's levels.
        assert_eq!(members[0], next_part, "{sp}");
        assert!(members.windows(2).all(|w| w[1] == w[0] + 1));
        next_part = members[members.len() - 1] + 1;
        assert_eq!(mparts[members[0] as usize]["first"], sp["first"]);
        assert_eq!(mparts[next_part as usize - 1]["last"], sp["last"]);
        let textures = mparts[members[0] as usize]["textures"]
            .as_array()
            .unwrap()
            .len();
        let samplers = sp["samplers"].as_array().unwrap();
        assert!(!samplers.is_empty());
        for s in samplers {
            let (name, i) = (s[0].as_str().unwrap(), s[1].as_u64().unwrap());
            assert_eq!(name, format!("ndf_p{k}_tex{i}"));
            assert!((i as usize) < textures, "{s}");
            assert!(
                switch.contains(&format!("#define ndf_tex{i} {name}")),
                "{name}"
            );
        }
    }
    assert_eq!((next, next_part as usize), (7, mparts.len()));
    // No level-0 file anywhere: the scene never samples it.
    for e in std::fs::read_dir(&baked).unwrap() {
        let n = e.unwrap().file_name().to_string_lossy().into_owned();
        assert!(!n.contains("_L00."), "{n}");
    }

    // The plan given to another map of the same size: refused, nothing written.
    let other = dir.path().join("other.png");
    write_map(&other, 4);
    let refused = dir.path().join("refused");
    let run = ndfmap(&[
        "bake",
        other.to_str().unwrap(),
        "--plan",
        out.join("plan.json").to_str().unwrap(),
        "-o",
        refused.to_str().unwrap(),
    ]);
    assert_one_line_error(&run, &["another map", "content hash"]);
    assert!(!refused.exists());
    // ... and to a map of another size.
    let small = dir.path().join("small.png");
    image::RgbImage::from_pixel(32, 32, image::Rgb([128, 128, 255]))
        .save(&small)
        .unwrap();
    let run = ndfmap(&[
        "bake",
        small.to_str().unwrap(),
        "--plan",
        out.join("plan.json").to_str().unwrap(),
        "-o",
        refused.to_str().unwrap(),
    ]);
    assert_one_line_error(&run, &["64x64", "32x32"]);
    assert!(!refused.exists());
    // A plan file that is not a plan.
    let junk = dir.path().join("junk.json");
    std::fs::write(&junk, "{\"format\": 3}").unwrap();
    let run = ndfmap(&[
        "bake",
        map.to_str().unwrap(),
        "--plan",
        junk.to_str().unwrap(),
        "-o",
        refused.to_str().unwrap(),
    ]);
    assert_one_line_error(&run, &["junk.json", "not an ndfmap plan"]);
    assert!(!refused.exists());
    // --plan with a method option.
    let run = ndfmap(&[
        "bake",
        map.to_str().unwrap(),
        "--plan",
        out.join("plan.json").to_str().unwrap(),
        "--lobes",
        "3",
        "-o",
        refused.to_str().unwrap(),
    ]);
    assert_one_line_error(&run, &["--plan decides"]);
    assert!(!refused.exists());
}

#[test]
fn bad_scenes_are_one_line_errors_naming_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let map = dir.path().join("map.png");
    write_map(&map, 3);
    let cases: Vec<(String, &str)> = vec![
        (String::new(), "empty"),
        ("\u{1}\u{2}garbage".into(), "not a valid TOML"),
        (SCENE.replace("kd = 0.5", "kd = 0.5\ncolour = 1"), "colour"),
        (SCENE.replace("kd = 0.5", "kd = \"half\""), "kd"),
        (SCENE.replace("[16, 64]", "[16, nan]"), "material.exponent"),
        (SCENE.replace("[16, 64]", "[-16, 64]"), "material.exponent"),
        (SCENE.replace("[1, 6]", "[1, 9]"), "view.levels"),
        (
            SCENE.replace("lights = [\"point\", \"environment\"]", "lights = []"),
            "lights",
        ),
        (
            "{\"lights\": [\"point\"], \"material\": {\"model\": \"lambert\"}}".into(),
            "view",
        ),
    ];
    for (i, (text, needle)) in cases.iter().enumerate() {
        let scene = dir.path().join(format!("scene{i}.toml"));
        std::fs::write(&scene, text).unwrap();
        let out = dir.path().join(format!("out{i}"));
        let run = ndfmap(&[
            "plan",
            scene.to_str().unwrap(),
            map.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ]);
        assert_one_line_error(&run, &[needle]);
        assert!(!out.exists(), "{text:?}: nothing written");
    }
}

#[test]
fn environment_lit_plans_keep_colour_textures_where_colour_varies() {
    // Issue 16: the environment shaders read eq 22's colour textures, so an environment-only
    // scene whose colour varies ships them in its vMF parts, and those parts' shaders are the
    // environment-lit ones with NDF_COLOR.
    let dir = tempfile::tempdir().unwrap();
    let map = dir.path().join("map.png");
    write_map(&map, 3);
    let scene = dir.path().join("scene.toml");
    std::fs::write(
        &scene,
        r#"
lights = ["environment"]
[material]
model = "blinn-phong"
exponent = [64, 256]
kd = 0.2
ks = 0.8
[color]
varies = true
[view]
levels = [1, 6]
[target]
error = 0.05
"#,
    )
    .unwrap();
    let out = dir.path().join("plan");
    let run = ndfmap(&[
        "plan",
        scene.to_str().unwrap(),
        map.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--explain",
    ]);
    let explain = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    assert!(
        explain.contains("colour textures: kept in the vMF ranges"),
        "{explain}"
    );
    let plan: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("plan.json")).unwrap()).unwrap();
    let mut coloured = 0;
    for (i, p) in plan["parts"].as_array().unwrap().iter().enumerate() {
        let frag = std::fs::read_to_string(out.join(format!("part{i}.frag"))).unwrap();
        assert!(
            frag.contains("#define NDF_LIGHT_ENV_PREFILTERED 1"),
            "part {i}"
        );
        let vmf = frag.contains("#define NDF_METHOD_VMF 1");
        assert_eq!(p["color"] == true, vmf, "part {i}: {p}\n{explain}");
        assert_eq!(frag.contains("#define NDF_COLOR 1"), vmf, "part {i}");
        // The generated sky's sun is extracted as a light (the default, as it was measured):
        // every shader adds it.
        assert!(frag.contains("#define NDF_ENV_LIGHTS 8"), "part {i}");
        coloured += vmf as usize;
    }
    assert!(coloured > 0, "no vMF part:\n{explain}");
    assert_eq!(plan["shader"]["env_lights"], 1, "the sun");
    assert!(
        explain.contains("1 bright source(s) extracted as distant lights"),
        "{explain}"
    );
    if let Ok(switch) = std::fs::read_to_string(out.join("lod_switch.frag")) {
        assert!(switch.contains("#define NDF_ENV_LIGHTS 8"));
    }
    // Under the overcast sky (no sun) nothing is extracted: no light loop, no field.
    let overcast = dir.path().join("overcast.toml");
    std::fs::write(
        &overcast,
        std::fs::read_to_string(&scene).unwrap().replace(
            "lights = [\"environment\"]",
            "lights = [\"environment\"]\nenvironment = \"overcast\"",
        ),
    )
    .unwrap();
    let out = dir.path().join("plan-overcast");
    let run = ndfmap(&[
        "plan",
        overcast.to_str().unwrap(),
        map.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let plan: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("plan.json")).unwrap()).unwrap();
    assert!(
        plan["shader"].get("env_lights").is_none(),
        "{}",
        plan["shader"]
    );
    for i in 0..plan["parts"].as_array().unwrap().len() {
        let frag = std::fs::read_to_string(out.join(format!("part{i}.frag"))).unwrap();
        assert!(frag.contains("#define NDF_LIGHT_ENV_PREFILTERED 1"));
        assert!(!frag.contains("#define NDF_ENV_LIGHTS"), "part {i}");
    }
}
