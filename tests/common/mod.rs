//! What the command-line tests share: running `ndfmap` and checking its one-line errors.

use std::process::{Command, Output};

/// Runs the `ndfmap` built for these tests with `args`.
pub fn ndfmap(args: &[&str]) -> Output {
    ndfmap_with(args, &[])
}

/// Runs `ndfmap` with `args` and environment variables `env`.
pub fn ndfmap_with(args: &[&str], env: &[(&str, &str)]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ndfmap"))
        .args(args)
        .envs(env.iter().copied())
        .output()
        .expect("runs ndfmap")
}

/// Asserts a failed run with exactly one stderr line that contains every `needle`.
pub fn assert_one_line_error(out: &Output, needles: &[&str]) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success(),
        "expected failure, got success: {err}"
    );
    let lines: Vec<_> = err.lines().collect();
    assert_eq!(lines.len(), 1, "one line expected, got: {err:?}");
    assert!(lines[0].starts_with("ndfmap: error: "), "{err}");
    for n in needles {
        assert!(lines[0].contains(n), "'{n}' missing from: {err}");
    }
    assert!(!err.contains("panicked"), "{err}");
}
