//! Offscreen frames: the same [`Viewer`] on a headless context (EGL, else OSMesa), written as
//! PNG — one frame (`--headless --screenshot`), or the methods side by side with the reference
//! (`--compare`, the README picture).

use crate::methods::{Bakes, MethodSpec};
use crate::viewer::{EnvInput, Settings, Show, Viewer};
use ndfmap::bake::Method;
use ndfmap_gl::{Gl, Route};
use std::path::Path;

/// The methods `--compare` shows by default, left to right (the reference comes last).
pub const COMPARED: [MethodSpec; 3] = [
    MethodSpec::baseline(Method::Plain),
    MethodSpec::baseline(Method::Toksvig),
    MethodSpec::mixture(Method::Vmf, 6, true),
];

/// Pixels of white between the panels of a comparison.
const GAP: u32 = 4;

/// A headless context: EGL, else OSMesa (the error names both failures).
pub fn context() -> Result<Gl, String> {
    match Gl::new(Route::Egl) {
        Ok(gl) => Ok(gl),
        Err(egl) => Gl::new(Route::OsMesa).map_err(|osmesa| format!("{egl}; {osmesa}")),
    }
}

fn save_png(path: &Path, rgb: Vec<u8>, width: u32, height: u32) -> Result<(), String> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    }
    let img = image::RgbImage::from_raw(width, height, rgb).ok_or("image size mismatch")?;
    img.save(path)
        .map_err(|e| format!("{}: {e}", path.display()))
}

/// Renders one `width × height` frame of `settings` and writes it to `path`.
pub fn screenshot(
    bakes: Bakes,
    env: EnvInput,
    settings: Settings,
    width: u32,
    height: u32,
    path: &Path,
) -> Result<(), String> {
    let gl = context()?;
    let mut viewer = Viewer::new(&gl, bakes, settings, env).map_err(|e| e.to_string())?;
    let rgb = viewer.screenshot(width, height)?;
    save_png(path, rgb, width, height)?;
    println!(
        "{}: {} {}x{} ({})",
        path.display(),
        viewer.settings.method(),
        width,
        height,
        gl.renderer()
    );
    Ok(())
}

/// Renders `methods` and then the reference, each `width × height`, and writes them side by
/// side (white gaps between) to `path`. Colour is off, so that one reference (the plain bake's
/// finest level) is right for every panel.
pub fn compare(
    bakes: Bakes,
    env: EnvInput,
    mut settings: Settings,
    methods: &[MethodSpec],
    width: u32,
    height: u32,
    path: &Path,
) -> Result<(), String> {
    let gl = context()?;
    if settings.env_lit
        && let Some(m) = methods.iter().find(|m| !crate::viewer::env_capable(**m))
    {
        return Err(format!(
            "{m}: the environment shaders draw plain, toksvig, lean and vmf"
        ));
    }
    settings.methods = methods.to_vec();
    settings.current = 0;
    settings.color = false;
    let mut viewer = Viewer::new(&gl, bakes, settings, env).map_err(|e| e.to_string())?;
    let mut panels = Vec::new();
    for i in 0..methods.len() {
        viewer.settings.current = i;
        viewer.settings.show = Show::Method;
        panels.push(viewer.screenshot(width, height)?);
    }
    viewer.settings.show = Show::Reference;
    panels.push(viewer.screenshot(width, height)?);

    let n = panels.len() as u32;
    let total = n * width + (n - 1) * GAP;
    let mut rgb = vec![255u8; (total * height * 3) as usize];
    for (i, panel) in panels.iter().enumerate() {
        let x0 = i as u32 * (width + GAP);
        for y in 0..height {
            let src = &panel[(y * width * 3) as usize..((y + 1) * width * 3) as usize];
            let at = ((y * total + x0) * 3) as usize;
            rgb[at..at + src.len()].copy_from_slice(src);
        }
    }
    save_png(path, rgb, total, height)?;
    let names: Vec<String> = methods.iter().map(|m| m.to_string()).collect();
    println!(
        "{}: {} | reference ({}x{} each, {})",
        path.display(),
        names.join(" | "),
        width,
        height,
        gl.renderer()
    );
    Ok(())
}
