//! Tests of the C API called from Rust: every entry point with good and bad arguments.

use std::cell::Cell;

thread_local! {
    /// When set, the next guarded entry point on this thread panics inside its guard.
    static INJECT_PANIC: Cell<bool> = const { Cell::new(false) };
}

/// Panics (once) if a test asked for it: stands for a bug inside any entry point.
pub(super) fn maybe_inject_panic() {
    if INJECT_PANIC.with(|p| p.replace(false)) {
        panic!("injected test panic");
    }
}
