//! The EGL device route: a display on an EGL device (software first), a config with no surface
//! type, a 3.3 core context made current without a surface.

use super::Route;
use crate::{Error, Result};
use glutin::api::egl::context::PossiblyCurrentContext;
use glutin::api::egl::device::Device;
use glutin::api::egl::display::Display;
use glutin::config::{Api, ConfigSurfaceTypes, ConfigTemplateBuilder};
use glutin::context::{ContextApi, ContextAttributesBuilder, GlProfile, Version};
use glutin::error::ErrorKind;
use glutin::prelude::*;

/// The device extension of Mesa's software (llvmpipe) device.
const SOFTWARE_DEVICE: &str = "EGL_MESA_device_software";

/// The environment variable that, set to `hardware`, tries the other devices before software.
const DEVICE_VARIABLE: &str = "NDFMAP_EGL_DEVICE";

/// A current EGL context and the display it lives on.
pub(super) struct EglContext {
    context: PossiblyCurrentContext,
    /// The display stays initialized for the process: a device display is one per device and
    /// may be shared with other threads' contexts, so it is never terminated here.
    _display: Display,
}

impl Drop for EglContext {
    fn drop(&mut self) {
        // Not current first, or the context is not destroyed (glutin destroys it on drop).
        // A failure here leaves nothing better to do than to go on dropping.
        let _ = self.context.make_not_current_in_place();
    }
}

/// Creates the context on the first device that gives one, software devices first.
pub(super) fn create() -> Result<(EglContext, glow::Context)> {
    let fail = |detail: String| Error::Context {
        route: Route::Egl,
        detail,
        install: Route::Egl.packages(),
    };
    let mut devices: Vec<Device> = match Device::query_devices() {
        Ok(devices) => devices.collect(),
        Err(e) if matches!(e.error_kind(), ErrorKind::NotFound) => {
            return Err(Error::LibraryMissing {
                route: Route::Egl,
                library: "libEGL.so.1",
                install: Route::Egl.packages(),
                detail: e.to_string(),
            });
        }
        Err(e) => return Err(fail(format!("enumerating EGL devices: {e}"))),
    };
    if devices.is_empty() {
        return Err(fail("EGL lists no device".into()));
    }
    // Software first, so that the tests' and references' renderer is the same on every machine
    // with Mesa; NDFMAP_EGL_DEVICE=hardware puts the other devices first (a GPU's frame times).
    let hardware_first = std::env::var(DEVICE_VARIABLE).is_ok_and(|v| v == "hardware");
    devices.sort_by_key(|d| d.extensions().contains(SOFTWARE_DEVICE) == hardware_first);
    let mut failures = Vec::new();
    for device in &devices {
        match on_device(device) {
            Ok(made) => return Ok(made),
            Err(e) => failures.push(format!(
                "device {} ({}): {e}",
                device.name().unwrap_or("unnamed"),
                device.vendor().unwrap_or("unknown vendor")
            )),
        }
    }
    Err(fail(failures.join("; ")))
}

fn on_device(device: &Device) -> Result<(EglContext, glow::Context), String> {
    // SAFETY: no native display handle is passed, so there is no foreign object to outlive.
    let display =
        unsafe { Display::with_device(device, None) }.map_err(|e| format!("display: {e}"))?;
    // The default template asks for window surfaces, which a device display has none of.
    let template = ConfigTemplateBuilder::new()
        .with_surface_type(ConfigSurfaceTypes::empty())
        .with_api(Api::OPENGL)
        .build();
    // SAFETY: the template holds no native window handle.
    let config = unsafe { display.find_configs(template) }
        .map_err(|e| format!("configs: {e}"))?
        .next()
        .ok_or("no config without a surface type")?;
    let attributes = ContextAttributesBuilder::new()
        .with_context_api(ContextApi::OpenGl(Some(Version::new(3, 3))))
        .with_profile(GlProfile::Core)
        .build(None);
    // SAFETY: the attributes hold no native window handle; the config is the display's own.
    let context = unsafe { display.create_context(&config, &attributes) }
        .map_err(|e| format!("3.3 core context: {e}"))?
        .make_current_surfaceless()
        .map_err(|e| format!("make current: {e}"))?;
    // SAFETY: the context is current on this thread; the loader returns that display's
    // function pointers, valid while the display is initialized (for the process).
    let glow =
        unsafe { glow::Context::from_loader_function_cstr(|name| display.get_proc_address(name)) };
    Ok((
        EglContext {
            context,
            _display: display,
        },
        glow,
    ))
}
