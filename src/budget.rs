//! The memory budget: how much memory one load or one bake may use, checked against an estimate
//! *before* the memory is allocated, so that a decompression bomb or an oversized bake is
//! refused with a clear message (naming the size and the budget) instead of aborting the
//! process when an allocation fails.
//!
//! The budget is an explicit option where memory is spent (`memory_limit` of `IngestOptions`
//! and `BakeOptions`, the C API's `memory_limit` fields, the command line's `--memory`); when it
//! is not given, [`default_memory_limit`] derives one from the machine. The estimates
//! themselves live where the memory is spent: decoding in module `ingest`, baking in
//! `methods::estimate_peak_bytes`. This module sits below both.

use crate::error::{Error, Result};

/// The budget used when the machine's memory cannot be read (non-Linux systems): 8 GiB.
pub const FALLBACK_MEMORY_LIMIT: u64 = 8 << 30;

/// The smallest default budget, whatever the machine reports: 1 GiB.
pub const MIN_DEFAULT_MEMORY_LIMIT: u64 = 1 << 30;

/// The default memory budget: half of the memory this process can have — the machine's
/// physical memory (`MemTotal` of `/proc/meminfo`) or, when lower, its control group's limit
/// (`memory.max`, cgroup v2, or `memory.limit_in_bytes`, v1) — and at least
/// [`MIN_DEFAULT_MEMORY_LIMIT`]; [`FALLBACK_MEMORY_LIMIT`] where neither can be read.
///
/// Half leaves room for the rest of the system and for the estimates' error; it depends on the
/// machine, not on its current load, so the same command is refused or accepted alike each
/// time on one machine.
pub fn default_memory_limit() -> u64 {
    let total = physical_memory();
    let cgroup = cgroup_limit();
    match (total, cgroup) {
        (None, None) => FALLBACK_MEMORY_LIMIT,
        (t, c) => {
            (t.unwrap_or(u64::MAX).min(c.unwrap_or(u64::MAX)) / 2).max(MIN_DEFAULT_MEMORY_LIMIT)
        }
    }
}

/// The budget an option asks for: `Some(bytes)` as given, `None` the machine's default
/// ([`default_memory_limit`]).
pub fn resolve(limit: Option<u64>) -> u64 {
    limit.unwrap_or_else(default_memory_limit)
}

/// Refuses `needed` bytes for `what` (a file, a bake) when they exceed `limit` (`None`: the
/// default budget) with [`Error::MemoryBudget`].
pub fn check(what: &str, needed: u64, limit: Option<u64>) -> Result<()> {
    let limit = resolve(limit);
    if needed > limit {
        Err(Error::MemoryBudget {
            what: what.to_string(),
            needed,
            limit,
        })
    } else {
        Ok(())
    }
}

/// Parses a byte count as the command line's `--memory` takes it: a number (decimals allowed)
/// with an optional binary unit, `K`, `M`, `G` or `T` (also `KiB`, `MB`, ...: all mean powers
/// of 1024), e.g. `512M`, `1.5G`, `8GiB`, `1000000`. At least 1 MiB.
pub fn parse_bytes(text: &str) -> Result<u64> {
    let bad = || {
        Error::InvalidOption(format!(
            "memory size '{text}' (expected a number with an optional unit K, M, G or T, \
             e.g. 512M or 4G, of at least 1M)"
        ))
    };
    let t = text.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (number, unit) = t.split_at(split);
    let value: f64 = number.parse().map_err(|_| bad())?;
    let unit = unit.trim().to_ascii_uppercase();
    let scale: u64 = match unit.trim_end_matches("IB").trim_end_matches('B') {
        "" => 1,
        "K" => 1 << 10,
        "M" => 1 << 20,
        "G" => 1 << 30,
        "T" => 1 << 40,
        _ => return Err(bad()),
    };
    let bytes = value * scale as f64;
    if !(bytes.is_finite() && bytes >= (1 << 20) as f64 && bytes < u64::MAX as f64) {
        return Err(bad());
    }
    Ok(bytes as u64)
}

/// A byte count in words: `512 MiB`, `4.0 GiB`, `3 bytes`.
pub fn format_bytes(bytes: u64) -> String {
    crate::error::bytes_in_words(bytes)
}

/// `MemTotal` of `/proc/meminfo`, in bytes.
fn physical_memory() -> Option<u64> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = info.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    kb.checked_mul(1024)
}

/// This process's control-group memory limit, if one is set.
fn cgroup_limit() -> Option<u64> {
    [
        "/sys/fs/cgroup/memory.max",
        "/sys/fs/cgroup/memory/memory.limit_in_bytes",
    ]
    .iter()
    .filter_map(|p| std::fs::read_to_string(p).ok())
    // "max" (v2) and a huge number (v1, no limit) both mean none.
    .filter_map(|s| s.trim().parse::<u64>().ok())
    .find(|&v| v < (1 << 60))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_with_binary_units() {
        assert_eq!(parse_bytes("512M").unwrap(), 512 << 20);
        assert_eq!(parse_bytes("4G").unwrap(), 4 << 30);
        assert_eq!(parse_bytes("4GiB").unwrap(), 4 << 30);
        assert_eq!(parse_bytes("1.5g").unwrap(), 3 << 29);
        assert_eq!(parse_bytes("2T").unwrap(), 2 << 40);
        assert_eq!(parse_bytes("2097152").unwrap(), 2 << 20);
        for bad in ["", "G", "-1G", "1X", "0", "1K", "nanG", "1e9"] {
            assert!(parse_bytes(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn bytes_format_in_words() {
        assert_eq!(format_bytes(3), "3 bytes");
        assert_eq!(format_bytes(512 << 20), "512 MiB");
        assert_eq!(format_bytes(6 << 30), "6.0 GiB");
        assert_eq!(format_bytes(3 << 29), "1.5 GiB");
    }

    #[test]
    fn the_default_is_half_the_machine_and_checks_refuse_above_it() {
        let d = default_memory_limit();
        assert!(d >= MIN_DEFAULT_MEMORY_LIMIT);
        if let Some(total) = physical_memory() {
            assert!(
                d <= (total / 2).max(MIN_DEFAULT_MEMORY_LIMIT),
                "{d} of {total}"
            );
        }
        assert!(check("x", d, None).is_ok());
        let e = check("map.png", 5 << 30, Some(4 << 30)).unwrap_err();
        assert!(matches!(e, Error::MemoryBudget { .. }));
        let text = e.to_string();
        assert!(
            text.contains("map.png") && text.contains("5.0 GiB") && text.contains("4.0 GiB"),
            "{text}"
        );
    }
}
