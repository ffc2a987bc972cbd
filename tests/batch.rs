//! Batch bakes (issue 19): many inputs or a batch file, one output folder each, the content
//! hash in every manifest, up-to-date inputs skipped, and failures kept per input — an
//! unreadable, corrupt or vanished input, colliding outputs, unknown batch keys, a full disk —
//! with nothing partial left that looks complete.

mod common;

use common::{assert_one_line_error, ndfmap};
use ndfmap::batch::{self, Outcome, RunOptions, Settings};
use std::path::Path;
use std::process::Command;

fn write_normal_png(path: &Path, size: u32, seed: u32) {
    let img = image::RgbImage::from_fn(size, size, |x, y| {
        image::Rgb([
            128 + ((x * 37 + y * 11 + seed) % 60) as u8,
            128 - ((x * 7 + y * 29 + 3 * seed) % 50) as u8,
            230,
        ])
    });
    img.save(path).unwrap();
}

fn manifest(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("manifest.json")).unwrap()).unwrap()
}

fn stdout(out: &std::process::Output) -> String {
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn stderr(out: &std::process::Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Several inputs through a glob: one folder each, a content hash in each manifest that
/// `batch::content_hash` recomputes from the input's bytes; the second run skips them all,
/// and changing one input or one option re-bakes exactly what changed.
#[test]
fn globbed_inputs_bake_once_then_are_up_to_date() {
    let dir = tempfile::tempdir().unwrap();
    for (i, name) in ["a", "b", "c"].iter().enumerate() {
        write_normal_png(&dir.path().join(format!("{name}.png")), 16, i as u32);
    }
    let out = dir.path().join("out");
    let pattern = format!("{}/*.png", dir.path().display());
    let args = |extra: &[&str]| {
        let mut v = vec![
            "bake".to_string(),
            pattern.clone(),
            "-m".into(),
            "vmf".into(),
            "--lobes".into(),
            "2".into(),
            "--container".into(),
            "ktx2".into(),
            "-o".into(),
            out.display().to_string(),
        ];
        v.extend(extra.iter().map(|s| s.to_string()));
        v
    };
    let run = |extra: &[&str]| {
        let a = args(extra);
        ndfmap(&a.iter().map(String::as_str).collect::<Vec<_>>())
    };
    let first = run(&[]);
    assert!(first.status.success(), "{}", stderr(&first));
    assert!(
        stdout(&first).contains("3 baked, 0 up to date, 0 failed"),
        "{}",
        stdout(&first)
    );
    let mut hashes = Vec::new();
    for name in ["a", "b", "c"] {
        let m = manifest(&out.join(name));
        let hash = m["content_hash"].as_str().unwrap().to_string();
        assert!(hash.starts_with("sha256:") && hash.len() == 71, "{hash}");
        // Independent of the writer: the hash of the input's bytes and the job's settings.
        let job = Settings {
            path: Some(format!("{name}.png")),
            method: Some("vmf".into()),
            lobes: Some(2),
            container: Some("ktx2".into()),
            ..Settings::default()
        }
        .job(dir.path(), Some(&out), None)
        .unwrap();
        let bytes = std::fs::read(dir.path().join(format!("{name}.png"))).unwrap();
        assert_eq!(
            hash,
            batch::content_hash(&job.settings_text(), &bytes, None)
        );
        assert!(job.is_up_to_date());
        hashes.push(hash);
    }
    assert_eq!(
        hashes
            .iter()
            .collect::<std::collections::BTreeSet<_>>()
            .len(),
        3
    );
    let before = std::fs::metadata(out.join("a/lobe0.ktx2"))
        .unwrap()
        .modified()
        .unwrap();
    let second = run(&[]);
    assert!(second.status.success());
    assert!(
        stdout(&second).contains("0 baked, 3 up to date, 0 failed"),
        "{}",
        stdout(&second)
    );
    assert_eq!(
        std::fs::metadata(out.join("a/lobe0.ktx2"))
            .unwrap()
            .modified()
            .unwrap(),
        before,
        "an up-to-date output is not rewritten"
    );
    // One input changes: only it is baked again.
    write_normal_png(&dir.path().join("b.png"), 16, 7);
    let third = run(&[]);
    assert!(
        stdout(&third).contains("1 baked, 2 up to date, 0 failed"),
        "{}",
        stdout(&third)
    );
    assert_ne!(manifest(&out.join("b"))["content_hash"], hashes[1]);
    // One option changes: all are baked again; a file deleted by hand makes its folder stale.
    let fourth = run(&["--format", "f16"]);
    assert!(stdout(&fourth).contains("3 baked"), "{}", stdout(&fourth));
    std::fs::remove_file(out.join("c/lobe1.ktx2")).unwrap();
    let fifth = run(&["--format", "f16"]);
    assert!(
        stdout(&fifth).contains("1 baked, 2 up to date"),
        "{}",
        stdout(&fifth)
    );
    assert!(out.join("c/lobe1.ktx2").is_file());
    // --force bakes everything.
    let forced = run(&["--format", "f16", "--force"]);
    assert!(stdout(&forced).contains("3 baked"), "{}", stdout(&forced));
    // --check bakes nothing: one line per input with its hash; the status counts the stale.
    write_normal_png(&dir.path().join("a.png"), 16, 9);
    let check = run(&["--format", "f16", "--check"]);
    assert_eq!(check.status.code(), Some(1), "{}", stderr(&check));
    let lines: Vec<String> = stdout(&check).lines().map(str::to_string).collect();
    assert_eq!(lines.len(), 3, "{lines:?}");
    assert!(
        lines[0].contains(" stale ") && lines[0].contains("a.png"),
        "{lines:?}"
    );
    assert!(lines[1].contains(" current ") && lines[2].contains(" current "));
    assert!(lines[1].starts_with(manifest(&out.join("b"))["content_hash"].as_str().unwrap()));
    assert!(
        !manifest(&out.join("a"))["content_hash"]
            .as_str()
            .is_some_and(|h| lines[0].starts_with(h)),
        "a.png changed: its folder is stale and was not rebaked"
    );
}

/// A batch file with per-input methods and options; one unreadable and one corrupt input fail
/// with a line each, the rest complete, and the exit status is the number that failed.
#[test]
fn a_batch_file_bakes_per_input_settings_and_counts_failures() {
    let dir = tempfile::tempdir().unwrap();
    write_normal_png(&dir.path().join("rock.png"), 16, 1);
    write_normal_png(&dir.path().join("bark.png"), 8, 2);
    std::fs::write(
        dir.path().join("corrupt.png"),
        b"\x89PNG\r\n\x1a\nnot really",
    )
    .unwrap();
    let batch = dir.path().join("batch.toml");
    std::fs::write(
        &batch,
        r#"
[defaults]
method = "toksvig"
container = "dds"

[[input]]
path = "rock.png"
method = "vmf"
lobes = 2
align = 1.0
output = "baked/rock-vmf"

[[input]]
path = "bark.png"
format = "f16"

[[input]]
path = "missing.png"

[[input]]
path = "corrupt.png"
"#,
    )
    .unwrap();
    let out = dir.path().join("out");
    let run = ndfmap(&[
        "bake",
        "--batch",
        batch.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_eq!(run.status.code(), Some(2), "{}", stderr(&run));
    let text = stdout(&run);
    assert!(text.contains("2 baked, 0 up to date, 2 failed"), "{text}");
    let m = manifest(&dir.path().join("baked/rock-vmf"));
    assert_eq!(m["method"], "vmf");
    assert_eq!(m["parameters"]["lobes"], 2);
    assert_eq!(m["parameters"]["aligned"], true);
    assert_eq!(m["textures"][0]["files"][0], "lobe0.dds");
    let m = manifest(&out.join("bark"));
    assert_eq!(m["method"], "toksvig");
    assert_eq!(m["texel_format"], "f16");
    // The failures are named, and left nothing behind.
    let err = stderr(&run);
    assert!(
        err.contains("missing.png") && err.contains("cannot read"),
        "{err}"
    );
    assert!(
        err.contains("corrupt.png") && err.contains("decode"),
        "{err}"
    );
    assert!(!out.join("missing").exists() && !out.join("corrupt").exists());
    let leftovers: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains("staging"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

/// Unknown keys are refused before any work, naming the key; colliding outputs fail per input
/// (both), and the others complete.
#[test]
fn unknown_keys_and_colliding_outputs_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    write_normal_png(&dir.path().join("a.png"), 8, 1);
    std::fs::create_dir(dir.path().join("x")).unwrap();
    write_normal_png(&dir.path().join("x/a.png"), 8, 2);
    write_normal_png(&dir.path().join("b.png"), 8, 3);
    let batch = dir.path().join("b.json");
    std::fs::write(
        &batch,
        r#"{"input": [{"path": "a.png", "method": "plain", "lobez": 3}]}"#,
    )
    .unwrap();
    let out = dir.path().join("out");
    let run = ndfmap(&[
        "bake",
        "--batch",
        batch.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_eq!(run.status.code(), Some(1));
    assert_one_line_error(&run, &["b.json", "lobez"]);
    assert!(!out.exists(), "nothing was baked");
    // a.png and x/a.png both go to out/a.
    let run = ndfmap(&[
        "bake",
        dir.path().join("a.png").to_str().unwrap(),
        dir.path().join("x/a.png").to_str().unwrap(),
        dir.path().join("b.png").to_str().unwrap(),
        "-m",
        "plain",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_eq!(run.status.code(), Some(2), "{}", stderr(&run));
    let err = stderr(&run);
    assert!(err.contains("is also the output of"), "{err}");
    assert!(!out.join("a").exists());
    assert!(out.join("b/manifest.json").is_file());
}

/// An input that disappears while the batch runs (deleted when the job before it ends) fails
/// alone; the library's outcome names it.
#[test]
fn an_input_that_vanishes_mid_batch_fails_alone() {
    let dir = tempfile::tempdir().unwrap();
    let names = ["a", "b", "c"];
    for (i, n) in names.iter().enumerate() {
        write_normal_png(&dir.path().join(format!("{n}.png")), 8, i as u32);
    }
    let out = dir.path().join("out");
    let jobs: Vec<_> = names
        .iter()
        .map(|n| {
            Settings {
                path: Some(format!("{n}.png")),
                method: Some("olano".into()),
                ..Settings::default()
            }
            .job(dir.path(), Some(&out), None)
            .unwrap()
        })
        .collect();
    let vanish = dir.path().join("c.png");
    let outcomes = batch::run(
        &jobs,
        &RunOptions {
            workers: 1,
            ..RunOptions::default()
        },
        &|_| {},
        &|i, _| {
            if i == 0 {
                std::fs::remove_file(&vanish).unwrap();
            }
        },
    );
    assert!(matches!(outcomes[0], Outcome::Baked { .. }));
    assert!(matches!(outcomes[1], Outcome::Baked { .. }));
    match &outcomes[2] {
        Outcome::Failed(e) => assert!(e.to_string().contains("c.png"), "{e}"),
        o => panic!("{o:?}"),
    }
    assert!(!out.join("c").exists());
}

/// A job whose estimated peak exceeds the batch's budget fails alone, before decoding; the
/// small ones run.
#[test]
fn the_memory_budget_refuses_a_job_alone() {
    let dir = tempfile::tempdir().unwrap();
    write_normal_png(&dir.path().join("small.png"), 8, 1);
    write_normal_png(&dir.path().join("big.png"), 512, 2);
    let out = dir.path().join("out");
    // 512² vMF J = 8 needs 64 MiB + 262144 × 196 bytes ≈ 113 MiB by the estimate: over 100M.
    let run = ndfmap(&[
        "bake",
        dir.path().join("small.png").to_str().unwrap(),
        dir.path().join("big.png").to_str().unwrap(),
        "-m",
        "vmf",
        "--lobes",
        "8",
        "--memory",
        "100M",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_eq!(run.status.code(), Some(1), "{}", stderr(&run));
    assert!(
        stderr(&run).contains("big.png") && stderr(&run).contains("memory"),
        "{}",
        stderr(&run)
    );
    assert!(out.join("small/manifest.json").is_file());
    assert!(!out.join("big").exists());
}

/// A full disk, simulated with a file-size limit (`ulimit -f`, SIGXFSZ ignored so writes fail
/// with EFBIG instead of killing the process): the big bake fails with a write error naming
/// its folder, leaves no folder or staging copy, and the small one completes.
#[test]
fn a_full_disk_fails_per_input_and_leaves_nothing_that_looks_complete() {
    let dir = tempfile::tempdir().unwrap();
    write_normal_png(&dir.path().join("small.png"), 8, 1);
    write_normal_png(&dir.path().join("big.png"), 256, 2);
    let out = dir.path().join("out");
    let exe = env!("CARGO_BIN_EXE_ndfmap");
    // 256² f32 lobe textures are 1.4 MB each; 8² ones 1.4 KB: a 256 KiB file limit.
    let script = format!(
        "trap '' XFSZ; ulimit -f 256; exec '{exe}' bake '{}' '{}' -m vmf --lobes 2 \
         --container ktx2 --jobs 1 -o '{}'",
        dir.path().join("small.png").display(),
        dir.path().join("big.png").display(),
        out.display()
    );
    let run = Command::new("sh").arg("-c").arg(&script).output().unwrap();
    assert_eq!(run.status.code(), Some(1), "{}", stderr(&run));
    let err = stderr(&run);
    assert!(
        err.contains("big.png") && err.contains("cannot write") && err.contains("out/big"),
        "{err}"
    );
    assert!(out.join("small/manifest.json").is_file());
    assert!(!out.join("big").exists(), "no folder for the failed bake");
    let leftovers: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('.') && !n.ends_with("lock"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}
