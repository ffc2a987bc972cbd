//! This process's resource usage, for the timings that `ndfmap bench`, `ndfmap report` and the
//! sample viewer's benchmark print: CPU seconds, resident memory and its peak, the machine's
//! load average (all read from Linux `/proc`; `None` elsewhere), and the median that repeated
//! timings are reduced to. Built with or without the `report` feature.

/// A `/proc/self/status` field in kB (Linux), as bytes.
fn proc_status_bytes(key: &str) -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with(key))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Peak resident set size of this process (Linux `VmHWM`), bytes, since it started or since
/// the last [`reset_peak_rss`].
pub fn peak_rss() -> Option<u64> {
    proc_status_bytes("VmHWM:")
}

/// Current resident set size (Linux `VmRSS`), bytes.
pub fn rss() -> Option<u64> {
    proc_status_bytes("VmRSS:")
}

/// Resets the kernel's peak-RSS counter (Linux: writes 5 to `/proc/self/clear_refs`), so that
/// [`peak_rss`] measures what follows; does nothing where that cannot be written.
pub fn reset_peak_rss() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

/// The median of repeated timings (`times` is sorted in place, by [`f64::total_cmp`]): the
/// middle value, or the mean of the two middle values for an even count. What `ndfmap bench
/// --runs` prints and the viewer's benchmark reduces its draws to.
///
/// # Panics
/// If `times` is empty.
pub fn median(times: &mut [f64]) -> f64 {
    assert!(!times.is_empty(), "median of no timings");
    times.sort_by(f64::total_cmp);
    let n = times.len();
    if n % 2 == 1 {
        times[n / 2]
    } else {
        0.5 * (times[n / 2 - 1] + times[n / 2])
    }
}

/// CPU seconds (user + system) this process and its waited-for children (`glslangValidator`,
/// the viewer's benchmark) have used (Linux `/proc/self/stat`, 100 ticks/s). On a shared
/// machine it is the steadier measure of work than wall time.
pub fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name (which is in parentheses and may hold spaces).
    let rest = stat.rsplit_once(')')?.1;
    let f: Vec<&str> = rest.split_whitespace().collect();
    let mut ticks = 0.0;
    for i in 11..15 {
        ticks += f.get(i)?.parse::<f64>().ok()?;
    }
    Some(ticks / 100.0)
}

/// The 1-minute load average (Linux), recorded beside timings so a reader can tell a busy
/// machine from a slow method.
pub fn load_average() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_is_the_middle_or_the_mean_of_the_middle_two() {
        assert_eq!(median(&mut [3.0]), 3.0);
        assert_eq!(median(&mut [5.0, 1.0, 3.0]), 3.0);
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), 2.5);
        let mut v = [0.9, 0.2, 0.7, 0.4, 0.5];
        assert_eq!(median(&mut v), 0.5);
        assert_eq!(v, [0.2, 0.4, 0.5, 0.7, 0.9], "sorted in place");
    }
}
