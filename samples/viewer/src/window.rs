//! The window: winit events drive [`Viewer`] on the windowed context of `ndfmap_gl::window`.
//! Each redraw renders the frame into float targets, presents it tone-mapped into the window's
//! back buffer, and swaps. While the reference accumulates, frames follow each other (each adds
//! passes for about 40 ms); while a bake runs, the window looks for it ten times a second;
//! otherwise it waits for input.

use crate::methods::Bakes;
use crate::viewer::{EnvInput, Settings, Show, ViewName, Viewer};
use ndfmap::envlight::Route;
use ndfmap::format::Format;
use ndfmap_gl::Destination;
use ndfmap_gl::window::Window;
use ndfmap_gl::winit;
use std::path::PathBuf;
use std::time::{Duration, Instant};
use winit::application::ApplicationHandler;
use winit::dpi::{PhysicalPosition, PhysicalSize};
use winit::event::{
    ElementState, KeyEvent, MouseButton, MouseScrollDelta, StartCause, WindowEvent,
};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{Key, ModifiersState, NamedKey};
use winit::window::WindowId;

/// Radians the camera turns per pixel of mouse drag.
const ORBIT_PER_PIXEL: f32 = 0.006;
/// Radians the light turns per arrow key press.
const LIGHT_STEP: f32 = 0.08;
/// Radians the environment turns per arrow key press in environment mode (15°).
const ENV_STEP: f32 = std::f32::consts::PI / 12.0;
/// Time per frame given to reference passes while the reference accumulates.
const REFERENCE_BUDGET: Duration = Duration::from_millis(40);
/// How often a window waiting for a bake looks for it.
const BAKE_POLL: Duration = Duration::from_millis(100);

struct App {
    bakes: Option<Bakes>,
    env: Option<EnvInput>,
    settings: Settings,
    size: (u32, u32),
    frames_left: Option<u32>,
    screenshot: Option<PathBuf>,
    running: Option<(Viewer, Window)>,
    error: Option<String>,
    modifiers: ModifiersState,
    dragging: bool,
    cursor: Option<PhysicalPosition<f64>>,
    view: usize,
    /// More frames are needed at once (reference accumulating, or counting --frames).
    accumulating: bool,
    /// A bake runs: redraw now and then to pick it up.
    baking: bool,
}

/// Opens the window and runs until it is closed (or `frames` frames were drawn, after which
/// `screenshot`, if given, receives the window's last frame).
pub fn run(
    bakes: Bakes,
    env: EnvInput,
    settings: Settings,
    size: (u32, u32),
    frames: Option<u32>,
    screenshot: Option<PathBuf>,
) -> Result<(), String> {
    let event_loop = EventLoop::new().map_err(|e| {
        format!("cannot open a window ({e}); is DISPLAY set? (--headless renders offscreen)")
    })?;
    let view = ViewName::ALL
        .iter()
        .position(|v| v.scene().1 == settings.camera)
        .unwrap_or(0);
    let mut app = App {
        bakes: Some(bakes),
        env: Some(env),
        settings,
        size,
        frames_left: frames,
        screenshot,
        running: None,
        error: None,
        modifiers: ModifiersState::default(),
        dragging: false,
        cursor: None,
        view,
        accumulating: false,
        baking: true,
    };
    event_loop.run_app(&mut app).map_err(|e| e.to_string())?;
    match app.error {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

impl App {
    fn fail(&mut self, event_loop: &ActiveEventLoop, error: String) {
        self.error = Some(error);
        event_loop.exit();
    }

    fn redraw(&mut self, event_loop: &ActiveEventLoop) {
        let Some((viewer, window)) = &mut self.running else {
            return;
        };
        let errors = viewer.update_bakes(false);
        if let Some(e) = errors.into_iter().next() {
            return self.fail(event_loop, e);
        }
        let (w, h) = window.size();
        let start = Instant::now();
        let result = viewer
            .render(w, h, Some(REFERENCE_BUDGET))
            .and_then(|info| {
                viewer
                    .present(Destination::Window {
                        width: w,
                        height: h,
                    })
                    .map_err(|e| e.to_string())?;
                viewer.gl().finish();
                Ok(info)
            });
        let info = match result {
            Ok(info) => info,
            Err(e) => return self.fail(event_loop, e),
        };
        let frame_ms = start.elapsed().as_secs_f64() * 1e3;
        let (passes, goal) = info.reference_passes;
        self.accumulating = viewer.settings.show != Show::Method && passes < goal;
        self.baking = viewer.baking() || info.drawn.is_none();
        // A frame counts towards --frames once it shows the bake and the whole reference.
        let complete = info.drawn.is_some() && !self.accumulating && !self.baking;
        window.winit().set_title(&viewer.status(&info, frame_ms));

        if let Some(left) = &mut self.frames_left {
            if complete {
                *left = left.saturating_sub(1);
            }
            if *left == 0 {
                if let Some(path) = self.screenshot.take()
                    && let Err(e) = save_back_buffer(viewer, w, h, &path)
                {
                    return self.fail(event_loop, e);
                }
                event_loop.exit();
                return;
            }
            self.accumulating = true;
        }
        if let Err(e) = window.swap_buffers() {
            self.fail(event_loop, e.to_string());
        }
    }

    /// Applies a key press; whether anything changed.
    fn key(&mut self, event_loop: &ActiveEventLoop, key: &Key) -> bool {
        let shift = self.modifiers.shift_key();
        let character = match key {
            Key::Character(c) => c.to_ascii_lowercase(),
            _ => String::new(),
        };
        // The preset views first: they change `self.view` as well as the settings.
        if character == "v" || character == "r" {
            if character == "v" {
                self.view = (self.view + 1) % ViewName::ALL.len();
            }
            let view = ViewName::ALL[self.view];
            self.settings_mut().set_view(view);
            return true;
        }
        let s = self.settings_mut();
        match key {
            Key::Named(NamedKey::Escape) => event_loop.exit(),
            // Environment mode: left/right turn the environment about its zenith.
            Key::Named(NamedKey::ArrowLeft) if s.env_lit => s.turn_env(-ENV_STEP),
            Key::Named(NamedKey::ArrowRight) if s.env_lit => s.turn_env(ENV_STEP),
            Key::Named(NamedKey::ArrowLeft) => s.turn_light(-LIGHT_STEP, 0.0),
            Key::Named(NamedKey::ArrowRight) => s.turn_light(LIGHT_STEP, 0.0),
            Key::Named(NamedKey::ArrowUp) => s.turn_light(0.0, LIGHT_STEP),
            Key::Named(NamedKey::ArrowDown) => s.turn_light(0.0, -LIGHT_STEP),
            Key::Character(_) => match character.as_str() {
                "q" => event_loop.exit(),
                "m" => s.step_method(if shift { -1 } else { 1 }),
                "e" => {
                    let on = !s.env_lit;
                    if let Err(e) = s.set_env(on) {
                        eprintln!("ndfmap-viewer: {e}");
                        return false;
                    }
                }
                "h" => {
                    s.env_route = match s.env_route {
                        Route::Prefiltered => Route::Sh,
                        Route::Sh => Route::Prefiltered,
                    }
                }
                d @ ("1" | "2" | "3" | "4" | "5" | "6" | "7" | "8") => {
                    let j = d.parse().expect("a digit");
                    let spec = s.method().with_lobes(j);
                    match s.methods.iter().position(|m| *m == spec) {
                        Some(i) => s.current = i,
                        None => {
                            let current = s.current;
                            s.methods[current] = spec;
                        }
                    }
                }
                "p" => s.toggle_shape(),
                "s" => {
                    s.show = match s.show {
                        Show::Split => Show::Method,
                        _ => Show::Split,
                    }
                }
                "x" => {
                    s.show = match s.show {
                        Show::Reference => Show::Method,
                        _ => Show::Reference,
                    }
                }
                "c" => s.color = !s.color,
                "]" => s.scale_exponent(2.0),
                "[" => s.scale_exponent(0.5),
                "t" => s.torrance_sparrow = !s.torrance_sparrow,
                "g" => s.ggx = !s.ggx,
                "f" => {
                    s.format = match s.format {
                        Format::F32 => Format::F16,
                        _ => Format::F32,
                    }
                }
                "+" | "=" => s.zoom(0.8),
                "-" => s.zoom(1.25),
                _ => return false,
            },
            _ => return false,
        }
        true
    }

    fn settings_mut(&mut self) -> &mut Settings {
        match &mut self.running {
            Some((viewer, _)) => &mut viewer.settings,
            None => &mut self.settings,
        }
    }
}

/// Reads the window's back buffer (before the swap) and writes it as PNG.
fn save_back_buffer(viewer: &Viewer, w: u32, h: u32, path: &std::path::Path) -> Result<(), String> {
    let rgb = ndfmap_gl::present::read_default_framebuffer_rgb8(viewer.gl(), w, h)
        .map_err(|e| e.to_string())?;
    let img = image::RgbImage::from_raw(w, h, rgb).ok_or("image size mismatch")?;
    img.save(path)
        .map_err(|e| format!("{}: {e}", path.display()))
}

impl ApplicationHandler for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.running.is_some() {
            return;
        }
        let attributes = winit::window::Window::default_attributes()
            .with_title("ndfmap-viewer")
            .with_inner_size(PhysicalSize::new(self.size.0, self.size.1));
        let (gl, window) = match Window::new(event_loop, attributes) {
            Ok(made) => made,
            Err(e) => return self.fail(event_loop, e.to_string()),
        };
        let bakes = self.bakes.take().expect("resumed once");
        let env = self.env.take().expect("resumed once");
        match Viewer::new(&gl, bakes, self.settings.clone(), env) {
            Ok(viewer) => {
                println!("window: {} (OpenGL {:?})", gl.renderer(), gl.version());
                window.winit().request_redraw();
                self.running = Some((viewer, window));
            }
            Err(e) => self.fail(event_loop, e.to_string()),
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _: WindowId, event: WindowEvent) {
        let mut changed = false;
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::Resized(_) => {
                if let Some((_, window)) = &self.running {
                    window.resize_surface();
                }
                changed = true;
            }
            WindowEvent::RedrawRequested => self.redraw(event_loop),
            WindowEvent::ModifiersChanged(m) => self.modifiers = m.state(),
            WindowEvent::KeyboardInput {
                event:
                    KeyEvent {
                        logical_key,
                        state: ElementState::Pressed,
                        ..
                    },
                ..
            } => changed = self.key(event_loop, &logical_key),
            WindowEvent::MouseInput {
                state,
                button: MouseButton::Left,
                ..
            } => self.dragging = state == ElementState::Pressed,
            WindowEvent::CursorMoved { position, .. } => {
                if let (true, Some(last)) = (self.dragging, self.cursor) {
                    let (dx, dy) = (position.x - last.x, position.y - last.y);
                    self.settings_mut()
                        .camera
                        .orbit(-(dx as f32) * ORBIT_PER_PIXEL, dy as f32 * ORBIT_PER_PIXEL);
                    changed = true;
                }
                self.cursor = Some(position);
            }
            WindowEvent::MouseWheel { delta, .. } => {
                let steps = match delta {
                    MouseScrollDelta::LineDelta(_, y) => y,
                    MouseScrollDelta::PixelDelta(p) => p.y as f32 / 40.0,
                };
                self.settings_mut().zoom(0.85f32.powf(steps));
                changed = true;
            }
            _ => {}
        }
        if changed && let Some((_, window)) = &self.running {
            window.winit().request_redraw();
        }
    }

    fn new_events(&mut self, _: &ActiveEventLoop, cause: StartCause) {
        if let (StartCause::ResumeTimeReached { .. }, Some((_, window))) = (cause, &self.running) {
            window.winit().request_redraw();
        }
    }

    fn about_to_wait(&mut self, event_loop: &ActiveEventLoop) {
        let Some((_, window)) = &self.running else {
            return;
        };
        if self.accumulating {
            event_loop.set_control_flow(ControlFlow::Poll);
            window.winit().request_redraw();
        } else if self.baking {
            // Leave the cores to the bake; look for it ten times a second.
            event_loop.set_control_flow(ControlFlow::wait_duration(BAKE_POLL));
        } else {
            event_loop.set_control_flow(ControlFlow::Wait);
        }
    }
}
