//! What the fuzz targets share.

use std::collections::HashSet;
use std::sync::Mutex;

/// Keeps libFuzzer's rule that a panic is a crash, except for panics raised inside third-party
/// crates (the `image` and `exr` decoders) while ndfmap decodes: ingest runs the decoders under
/// `catch_unwind` and turns their panics into `Error::Decode` (`NDF_STATUS_DECODE` in C), so
/// those unwind to that guard as they would in a release build. The first panic at each
/// location is printed as `contained dependency panic at FILE:LINE: MESSAGE` (fuzz/README.md
/// lists them). A dependency panic that no guard catches still aborts: the Rust target's
/// harness aborts on any unwinding panic, and the C targets treat `NDF_STATUS_PANIC` as a crash.
pub fn contain_dependency_panics() {
    static SEEN: Mutex<Option<HashSet<String>>> = Mutex::new(None);
    let fatal = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let Some(location) = info.location() else {
            return fatal(info);
        };
        if !location.file().contains("/.cargo/registry/") {
            return fatal(info);
        }
        let place = format!("{}:{}", location.file(), location.line());
        let mut seen = SEEN.lock().unwrap_or_else(|e| e.into_inner());
        if seen.get_or_insert_with(HashSet::new).insert(place.clone()) {
            let message = info
                .payload()
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| info.payload().downcast_ref::<String>().cloned())
                .unwrap_or_default();
            eprintln!(
                "contained dependency panic at {place}: {}",
                message.replace('\n', " ")
            );
        }
    }));
}
