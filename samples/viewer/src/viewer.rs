//! The viewer's frames, independent of how the context was made (window or headless): the
//! [`Settings`] a user changes, the preset views, and [`Viewer`], which keeps the bakes, the
//! compiled shaders and the targets, draws the current method, accumulates the supersampled
//! reference, and presents the result tone-mapped (method, reference, or split screen).
//!
//! The reference is the unfiltered map shaded exactly: the plain bake cut to its finest level
//! (one MIP level, so `GL_TEXTURE_MAX_LEVEL` 0 and no filtering of normals at any distance),
//! drawn `k × k` times with stratified, jittered sub-pixel offsets and box-averaged. With the
//! map's albedo as colour it is the vMF J = 1 colour bake cut the same way, whose finest texels
//! are the normal (κ at its cap) and the albedo. It is drawn with hardware sampling: the
//! shaders' manual path takes its level count from `ndf_max_level()`, which assumes a full MIP
//! chain.

use crate::methods::{BakeKey, Bakes, MethodSpec, PbrKind, finest_level_only};
use ndfmap::bake::Method;
use ndfmap::brdf::Brdf;
use ndfmap::environment::Environment;
use ndfmap::envlight::{EnvLight, Route};
use ndfmap::format::Format;
use ndfmap::glsl::{Sampling, ShaderBrdf, ShaderLight, ShaderOptions};
use ndfmap_gl::glam::{Mat4, Vec2, Vec3, Vec4};
use ndfmap_gl::present::read_presented_rgb8;
use ndfmap_gl::{
    Accumulator, BakeRenderer, Camera, Destination, EnvBackground, EnvTextures, Gl, Layer,
    Lighting, Mesh, Presenter, RenderTarget, Scene, Shape, env_rotation,
};
use std::collections::HashMap;
use std::time::{Duration, Instant};

/// The plane of the close views: 4 units wide, the map repeated 8 times per side.
const PLANE: Shape = Shape::Plane {
    size: 4.0,
    uv_repeat: 8.0,
};

/// The plane of the far view: the map repeated 32 times, so that a pixel covers 50 or so
/// texels across (the deep MIP levels) while the plane still fills the image.
const TILED_PLANE: Shape = Shape::Plane {
    size: 4.0,
    uv_repeat: 32.0,
};

/// Closest and farthest camera distance the zoom allows: texels several pixels wide, and the
/// whole plane a few pixels across.
pub const DISTANCE_RANGE: (f32, f32) = (0.06, 600.0);

/// The preset views.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ViewName {
    /// The plane with the map tiled 32 × 32, from 6.5 units at 33° elevation, lit so that the
    /// mirror direction of the view falls on the plane's centre: every pixel covers many
    /// texels, and the highlight shows how each method filters.
    Far,
    /// The plane at a grazing angle under a point light behind it (`Scene::standard`'s
    /// `plane-grazing`): all MIP levels across the image.
    Grazing,
    /// The plane from close by: texels several pixels wide (magnification).
    Macro,
    /// The sphere of `Scene::standard`, lit from just above the eye.
    Sphere,
}

impl ViewName {
    /// Every view, in the order the `V` key cycles them.
    pub const ALL: [ViewName; 4] = [
        ViewName::Far,
        ViewName::Grazing,
        ViewName::Macro,
        ViewName::Sphere,
    ];

    /// The shape, camera and lighting of this view (Blinn-Phong s = 256 unless said).
    pub fn scene(self) -> (Shape, Camera, Lighting) {
        let standard = |name: &str| {
            Scene::standard()
                .into_iter()
                .find(|s| s.name == name)
                .expect("a standard scene")
        };
        // The plane seen from `distance` at elevation `pitch`, under a directional light that
        // mirrors the eye direction about the plane's normal: a flat plane's highlight would
        // sit at its centre.
        let mirrored = |shape: Shape, distance: f32, pitch: f32| {
            let camera = Camera {
                distance,
                pitch,
                yaw: 0.35,
                ..Camera::default()
            };
            let e = camera.eye().normalize();
            let lighting = Lighting {
                light: Vec4::new(-e.x, e.y, -e.z, 0.0),
                ..Lighting::default()
            };
            (shape, camera, lighting)
        };
        match self {
            ViewName::Far => mirrored(TILED_PLANE, 6.5, 0.58),
            ViewName::Grazing => {
                let s = standard("plane-grazing");
                (s.shape, s.camera, s.lighting)
            }
            ViewName::Macro => mirrored(PLANE, 0.15, 0.9),
            ViewName::Sphere => {
                // `Scene::standard`'s sphere, lit from just above the eye: the highlight lies
                // on the image's middle column, where the split screen divides.
                let s = standard("sphere");
                let e = s.camera.eye().normalize();
                let light = (e + Vec3::new(0.0, 0.5, 0.0)).normalize().extend(0.0);
                let lighting = Lighting {
                    light,
                    ..s.lighting
                };
                (s.shape, s.camera, lighting)
            }
        }
    }
}

/// What the image shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Show {
    /// The current method.
    Method,
    /// The supersampled reference.
    Reference,
    /// The method on the left half, the reference on the right half.
    Split,
}

/// Everything a user changes.
#[derive(Debug, Clone, PartialEq)]
pub struct Settings {
    /// The methods `M` cycles through.
    pub methods: Vec<MethodSpec>,
    /// Index of the current method.
    pub current: usize,
    /// The shape drawn.
    pub shape: Shape,
    /// The camera (aspect and clip distances are set per frame).
    pub camera: Camera,
    /// Light, its colour, K_d and K_s (the BRDF comes from `exponent`, `torrance_sparrow` and
    /// `ggx`).
    pub lighting: Lighting,
    /// Blinn-Phong exponent s; Torrance–Sparrow uses the σ of the same width, `sqrt(1/(2s))`.
    pub exponent: f64,
    /// Torrance–Sparrow (eq 18) instead of Blinn-Phong.
    pub torrance_sparrow: bool,
    /// GGX with Smith masking and Schlick Fresnel (`G`), ahead of `torrance_sparrow`.
    pub ggx: bool,
    /// Base perceptual roughness `√α` of the PBR bakes ([`Bakes`] bakes them with it): a PBR
    /// method is always lit by GGX of this α with Smith and Schlick, whatever the other BRDF
    /// settings say.
    pub pbr_roughness: f64,
    /// The map's albedo as colour (mixtures baked with colour textures, and their reference).
    pub color: bool,
    /// What the image shows.
    pub show: Show,
    /// Texture format of the uploads.
    pub format: Format,
    /// Supersampling of the reference: k × k jittered passes.
    pub supersampling: u32,
    /// Repetitions of the map per side of the plane, instead of the view's own.
    pub repeat: Option<f32>,
    /// Environment lighting instead of the light (the `E` key, `--env`): the panorama as
    /// background, the bake lit by it through [`Settings::env_route`].
    pub env_lit: bool,
    /// The environment route of the specular term (the `H` key).
    pub env_route: Route,
    /// Rotation of the environment about its zenith, radians (the arrow keys in environment
    /// mode).
    pub env_yaw: f32,
    /// The plane the `P` key brings back.
    plane: Shape,
}

/// Whether the environment shaders implement `spec` (`glsl/ndf_env.glsl`: plain, Toksvig,
/// LEAN, vMF, and SH by the SH route only).
pub fn env_capable(spec: MethodSpec) -> bool {
    ndfmap::envlight::check_method(spec.method).is_ok()
}

impl Settings {
    /// `methods` seen in `view`, Blinn-Phong s = 256, f32 textures, 16 × 16 reference samples.
    pub fn new(methods: Vec<MethodSpec>, view: ViewName) -> Settings {
        let (shape, camera, lighting) = view.scene();
        Settings {
            methods,
            current: 0,
            shape,
            camera,
            lighting,
            exponent: 256.0,
            torrance_sparrow: false,
            ggx: false,
            pbr_roughness: 0.3,
            color: true,
            show: Show::Method,
            format: Format::F32,
            supersampling: 16,
            repeat: None,
            env_lit: false,
            env_route: Route::Prefiltered,
            env_yaw: 0.0,
            plane: PLANE,
        }
    }

    /// Switches to the preset `view` (shape, camera, light), keeping the rest (a plane
    /// repeats the map [`Settings::repeat`] times if that is set).
    pub fn set_view(&mut self, view: ViewName) {
        let (shape, camera, lighting) = view.scene();
        self.shape = match (shape, self.repeat) {
            (Shape::Plane { size, .. }, Some(uv_repeat)) => Shape::Plane { size, uv_repeat },
            (shape, _) => shape,
        };
        if let Shape::Plane { .. } = self.shape {
            self.plane = self.shape;
        }
        self.camera = camera;
        self.lighting.light = lighting.light;
        self.lighting.color = lighting.color;
    }

    /// Switches between the sphere and the plane.
    pub fn toggle_shape(&mut self) {
        self.shape = match self.shape {
            Shape::Sphere => self.plane,
            Shape::Plane { .. } => Shape::Sphere,
        };
    }

    /// Moves to the `step`-th next method (negative: previous); in environment mode only
    /// through the methods the environment shaders implement ([`env_capable`]).
    pub fn step_method(&mut self, step: isize) {
        let n = self.methods.len() as isize;
        let mut i = self.current as isize;
        for _ in 0..n {
            i = (i + step.signum()).rem_euclid(n);
            if !self.env_lit || env_capable(self.methods[i as usize]) {
                break;
            }
        }
        self.current = i as usize;
    }

    /// Switches environment mode on or off; switching on moves to the next method the
    /// environment shaders implement, and fails (nothing changed) when the list has none.
    pub fn set_env(&mut self, on: bool) -> Result<(), String> {
        if on && !env_capable(self.method()) {
            let Some(i) = (1..=self.methods.len())
                .map(|k| (self.current + k) % self.methods.len())
                .find(|&i| env_capable(self.methods[i]))
            else {
                return Err(
                    "environment lighting draws plain, toksvig, lean and vmf: none is in \
                     --methods"
                        .into(),
                );
            };
            self.current = i;
        }
        self.env_lit = on;
        Ok(())
    }

    /// Turns the environment by `d_yaw` radians about its zenith (kept in (−π, π]).
    pub fn turn_env(&mut self, d_yaw: f32) {
        use std::f32::consts::PI;
        let y = (self.env_yaw + d_yaw + PI).rem_euclid(2.0 * PI) - PI;
        self.env_yaw = if y <= -PI { PI } else { y };
    }

    /// The current method.
    pub fn method(&self) -> MethodSpec {
        self.methods[self.current]
    }

    /// The BRDF of the current settings: GGX with Smith and Schlick (`α = sqrt(2/(s+2))`, the
    /// roughness of about the same width), the eq 18 lobe (`σ = sqrt(1/(2s))`), or Blinn-Phong;
    /// for a PBR method GGX with Smith and Schlick at the bakes' base α (`pbr_roughness²`).
    /// Environment mode has no Torrance–Sparrow route: Blinn-Phong then.
    pub fn brdf(&self) -> Brdf {
        if self.method().method == Method::Pbr {
            Brdf::Ggx(ndfmap::brdf::Ggx {
                g: true,
                ..ndfmap::brdf::Ggx::new(self.pbr_roughness * self.pbr_roughness)
            })
        } else if self.ggx {
            Brdf::Ggx(ndfmap::brdf::Ggx {
                g: true,
                ..ndfmap::brdf::Ggx::new((2.0 / (self.exponent + 2.0)).sqrt())
            })
        } else if self.torrance_sparrow && !self.env_lit {
            Brdf::TorranceSparrow {
                sigma: (0.5 / self.exponent).sqrt(),
            }
        } else {
            Brdf::BlinnPhong { s: self.exponent }
        }
    }

    /// The lighting with the current BRDF (environment mode: radiance scale 1, the
    /// environment's own intensity).
    pub fn lighting(&self) -> Lighting {
        Lighting {
            brdf: self.brdf(),
            color: if self.env_lit {
                Vec3::ONE
            } else {
                self.lighting.color
            },
            ..self.lighting.clone()
        }
    }

    /// The shader lighting of the current settings.
    pub fn shader_light(&self) -> ShaderLight {
        if self.env_lit {
            ShaderLight::env(self.env_route)
        } else {
            ShaderLight::Point
        }
    }

    /// Multiplies the exponent by `factor`, within 1 … 8192.
    pub fn scale_exponent(&mut self, factor: f64) {
        self.exponent = (self.exponent * factor).clamp(1.0, 8192.0);
    }

    /// Turns the light by `d_azimuth` about the vertical axis and raises it by `d_elevation`
    /// (radians), keeping its distance (point light) and kind.
    pub fn turn_light(&mut self, d_azimuth: f32, d_elevation: f32) {
        let l = self.lighting.light;
        let v = l.truncate();
        let r = v.length().max(1e-6);
        let elevation = (v.y / r).clamp(-1.0, 1.0).asin();
        let azimuth = v.x.atan2(v.z);
        let limit = std::f32::consts::FRAC_PI_2 - 0.01;
        let e = (elevation + d_elevation).clamp(-limit, limit);
        let a = azimuth + d_azimuth;
        let dir = Vec3::new(e.cos() * a.sin(), e.sin(), e.cos() * a.cos());
        self.lighting.light = (r * dir).extend(l.w);
    }

    /// Moves the camera closer (factor < 1) or away, within [`DISTANCE_RANGE`].
    pub fn zoom(&mut self, factor: f32) {
        self.camera.distance =
            (self.camera.distance * factor).clamp(DISTANCE_RANGE.0, DISTANCE_RANGE.1);
    }

    /// The camera for a `width × height` image: aspect, and clip distances that follow the
    /// distance so that both macro and far views keep their depth precision.
    pub fn camera_for(&self, width: u32, height: u32) -> Camera {
        let d = self.camera.distance;
        Camera {
            aspect: width as f32 / height.max(1) as f32,
            near: (0.01 * d).clamp(1e-3, 1.0),
            far: d + 20.0,
            ..self.camera
        }
    }
}

/// The compiled shader and uploaded textures of one bake.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
struct RendererKey {
    bake: BakeKey,
    brdf: ShaderBrdf,
    format: Format,
    /// Cut to the finest level (the reference).
    finest: bool,
    /// Point light or an environment route.
    light: ShaderLight,
    /// The environment shader adds the extracted lights (`NDF_ENV_LIGHTS`): environment mode
    /// with an environment that has some.
    env_lights: bool,
}

/// The state a reference image was accumulated for: when any of it changes, it restarts.
#[derive(Debug, Clone, PartialEq)]
struct ReferenceState {
    key: RendererKey,
    shape: Shape,
    camera: Camera,
    lighting: Lighting,
    size: (u32, u32),
    /// The environment's yaw (environment mode).
    env_yaw: f32,
}

/// Targets of one image size.
struct Targets {
    method: RenderTarget,
    reference: Accumulator,
}

/// The sub-pixel offset (in pixels, each in [−½, ½)) of reference pass `pass` of `k × k`:
/// strata visited in a well-spread order (a step of about 0.618·k² coprime with k²), a
/// quasi-random point (the R2 sequence) inside each.
pub fn jitter(k: u32, pass: u32) -> Vec2 {
    let n = (k * k).max(1);
    let mut step = ((n as f64 * 0.618_034).round() as u32).max(1);
    while gcd(step, n) != 1 {
        step += 1;
    }
    let stratum = (pass % n) * step % n;
    let (sx, sy) = (stratum % k.max(1), stratum / k.max(1));
    let t = pass as f64 + 1.0;
    let fx = (0.5 + t * 0.754_877_666_246_692_8).fract();
    let fy = (0.5 + t * 0.569_840_290_998_053_3).fract();
    let k = k.max(1) as f64;
    Vec2::new(
        ((sx as f64 + fx) / k - 0.5) as f32,
        ((sy as f64 + fy) / k - 0.5) as f32,
    )
}

fn gcd(a: u32, b: u32) -> u32 {
    if b == 0 { a } else { gcd(b, a % b) }
}

/// What a rendered frame drew.
#[derive(Debug, Clone, Default)]
pub struct FrameInfo {
    /// The label of the bake drawn (`vmf6a f16`), or `None` before the first bake is done.
    pub drawn: Option<String>,
    /// Milliseconds of the method's draw, between two `glFinish` calls.
    pub draw_ms: f64,
    /// Reference passes accumulated so far, and the target (k²); 0 when not shown.
    pub reference_passes: (u32, u32),
}

/// An environment on the GPU: the lighting tables and the background panorama.
struct EnvGpu {
    textures: EnvTextures,
    background: EnvBackground,
}

/// The environment of the viewer's environment mode: given (`--env`), or the generated sky
/// with its sun.
pub struct EnvInput {
    /// What the title calls it (a file name, or `sky`).
    pub name: String,
    /// The panorama.
    pub environment: Environment,
    /// Extract up to this many compact bright sources (and as many diffuse-only ones) as
    /// distant lights (`--env-lights`, default 4; 0: the paper's pure routes): the tables hold
    /// the residual and the shaders add the lights (`NDF_ENV_LIGHTS`).
    pub max_lights: usize,
}

/// The viewer: bakes, shaders, targets and the presentation pass on one context.
pub struct Viewer {
    gl: Gl,
    /// What is drawn.
    pub settings: Settings,
    bakes: Bakes,
    renderers: HashMap<RendererKey, BakeRenderer>,
    meshes: Vec<(Shape, Mesh)>,
    targets: Option<Targets>,
    presenter: Presenter,
    reference_state: Option<ReferenceState>,
    /// The method drawn while the current one bakes.
    shown: Option<MethodSpec>,
    /// The environment of environment mode.
    env_input: EnvInput,
    /// It on the GPU, made on the first environment-lit frame.
    env: Option<EnvGpu>,
}

impl Viewer {
    /// A viewer of `bakes` on `gl` with `settings`, lit in environment mode by `env_input`.
    pub fn new(
        gl: &Gl,
        bakes: Bakes,
        settings: Settings,
        env_input: EnvInput,
    ) -> Result<Viewer, ndfmap_gl::Error> {
        Ok(Viewer {
            gl: gl.clone(),
            presenter: Presenter::new(gl)?,
            settings,
            bakes,
            renderers: HashMap::new(),
            meshes: Vec::new(),
            targets: None,
            reference_state: None,
            shown: None,
            env_input,
            env: None,
        })
    }

    /// Prepares the environment on the GPU (first call: the SH projection, prefiltered levels
    /// and `L′` table of each colour channel, a few seconds for a 1024 × 512 panorama).
    fn prepare_env(&mut self) -> Result<(), String> {
        if self.env.is_some() {
            return Ok(());
        }
        let env = &self.env_input.environment;
        let light = EnvLight::with_lights(
            env,
            &ndfmap::environment::lights::LightOptions::up_to(self.env_input.max_lights),
        );
        let textures = EnvTextures::upload(&self.gl, &light).map_err(|e| e.to_string())?;
        let background = EnvBackground::new(&self.gl, env).map_err(|e| e.to_string())?;
        self.env = Some(EnvGpu {
            textures,
            background,
        });
        Ok(())
    }

    /// The context.
    pub fn gl(&self) -> &Gl {
        &self.gl
    }

    /// Whether the map's albedo is used as colour by `spec` under the current settings.
    fn uses_color(&self, spec: MethodSpec) -> bool {
        // Under the environment too: its shaders read the eq 22 colour textures (`NDF_COLOR`)
        // like the point-light ones.
        self.settings.color && self.bakes.has_albedo() && spec.is_mixture()
    }

    /// The bake the current method needs.
    fn method_key(&self, spec: MethodSpec) -> BakeKey {
        BakeKey {
            spec,
            color: self.uses_color(spec),
        }
    }

    /// The bake the reference for `spec` needs: plain, or vMF J = 1 with colour when `spec`
    /// is shown in colour; for a PBR method the plain MIP chain (`pbr-mip`), whose finest level
    /// is the input normals at the base roughness, drawn by the same glTF shader.
    fn reference_key(&self, spec: MethodSpec) -> BakeKey {
        if spec.method == Method::Pbr {
            BakeKey {
                spec: MethodSpec::pbr(PbrKind::Mip),
                color: false,
            }
        } else if self.uses_color(spec) {
            BakeKey {
                spec: MethodSpec::mixture(Method::Vmf, 1, true),
                color: true,
            }
        } else {
            BakeKey {
                spec: MethodSpec::baseline(Method::Plain),
                color: false,
            }
        }
    }

    /// Collects background bakes and starts the ones the current settings need (on this
    /// thread when `blocking`); returns bake errors.
    pub fn update_bakes(&mut self, blocking: bool) -> Vec<String> {
        let mut errors = self.bakes.poll();
        let spec = self.settings.method();
        let mut keys = vec![self.method_key(spec)];
        if self.settings.show != Show::Method {
            keys.push(self.reference_key(spec));
        }
        for key in keys {
            if blocking {
                if let Err(e) = self.bakes.get_blocking(key) {
                    errors.push(format!("{}: {e}", key.spec));
                }
            } else {
                self.bakes.request(key);
            }
        }
        errors
    }

    /// Whether a bake the current settings need is still running.
    pub fn baking(&self) -> bool {
        self.bakes.busy()
    }

    fn renderer_key(&self, bake: BakeKey, finest: bool) -> RendererKey {
        RendererKey {
            bake,
            brdf: ShaderBrdf::of(&self.settings.brdf()),
            format: self.settings.format,
            finest,
            // SH bakes have the SH route only (the `H` key leaves them on it).
            light: match self.settings.shader_light() {
                l if l.is_env() && bake.spec.method == Method::Sh => ShaderLight::EnvSh,
                l => l,
            },
            env_lights: self.settings.env_lit && self.env_light_count() > 0,
        }
    }

    /// How many lights were extracted from the environment (0 before it is first prepared,
    /// [`Viewer::render`] prepares it before any environment shader is chosen).
    pub fn env_light_count(&self) -> usize {
        self.env
            .as_ref()
            .map_or(0, |e| e.textures.data().lights.len())
    }

    /// Compiles and uploads `key` if its bake is done; whether it is ready.
    fn prepare(&mut self, key: RendererKey) -> Result<bool, String> {
        if self.renderers.contains_key(&key) {
            return Ok(true);
        }
        let Some(b) = self.bakes.get(&key.bake) else {
            return Ok(false);
        };
        let cut;
        let b = if key.finest {
            cut = finest_level_only(&b);
            &cut
        } else {
            &*b
        };
        let b = ndfmap::pack::quantize(b, key.format).map_err(|e| e.to_string())?;
        let options = ShaderOptions {
            brdf: key.brdf,
            // The reference: hardware sampling of its single level (see the module docs).
            sampling: if key.finest {
                Sampling::Hardware
            } else {
                Sampling::Auto
            },
            color: key.bake.color,
            light: key.light,
            env_lights: key.env_lights,
            probe: false,
            ..ShaderOptions::default()
        };
        let r = BakeRenderer::new(&self.gl, &b, &options).map_err(|e| e.to_string())?;
        self.renderers.insert(key, r);
        Ok(true)
    }

    fn mesh(&mut self, shape: Shape) -> Result<&Mesh, ndfmap_gl::Error> {
        let i = match self.meshes.iter().position(|(s, _)| *s == shape) {
            Some(i) => i,
            None => {
                let mesh = shape.mesh(&self.gl)?;
                self.meshes.push((shape, mesh));
                self.meshes.len() - 1
            }
        };
        Ok(&self.meshes[i].1)
    }

    fn targets(&mut self, width: u32, height: u32) -> Result<&mut Targets, ndfmap_gl::Error> {
        let fits = self
            .targets
            .as_ref()
            .is_some_and(|t| t.method.size() == (width, height));
        if !fits {
            self.targets = None; // free the old ones first
            self.targets = Some(Targets {
                method: RenderTarget::new(&self.gl, width, height)?,
                reference: Accumulator::new(&self.gl, width, height)?,
            });
            self.reference_state = None;
        }
        Ok(self.targets.as_mut().expect("just made"))
    }

    /// Draws a `width × height` frame: the current method (or the last one drawn while it
    /// bakes) and, when the reference is shown, more passes of it (restarting when the view
    /// changed): at least one and as many as fit in `reference_budget`, or all of them when it
    /// is `None`. Call [`Viewer::present`] to show it.
    pub fn render(
        &mut self,
        width: u32,
        height: u32,
        reference_budget: Option<Duration>,
    ) -> Result<FrameInfo, String> {
        let gl_err = |e: ndfmap_gl::Error| e.to_string();
        let camera = self.settings.camera_for(width, height);
        let lighting = self.settings.lighting();
        let shape = self.settings.shape;
        let spec = self.settings.method();
        let mut info = FrameInfo::default();
        let env_lit = self.settings.env_lit;
        if env_lit {
            if !env_capable(spec) {
                return Err(format!(
                    "{spec}: the environment shaders draw plain, toksvig, lean and vmf"
                ));
            }
            self.prepare_env()?;
        }
        let rotation = env_rotation(self.settings.env_yaw);

        // The method: the current one if ready, else the one shown before.
        let mut drawn = None;
        let shown = self.shown.filter(|s| !env_lit || env_capable(*s));
        for candidate in [Some(spec), shown].into_iter().flatten() {
            let key = self.renderer_key(self.method_key(candidate), false);
            if self.prepare(key)? {
                drawn = Some(key);
                self.shown = Some(candidate);
                break;
            }
        }
        let reference = match self.settings.show {
            Show::Method => None,
            _ => {
                let key = self.renderer_key(self.reference_key(spec), true);
                self.prepare(key)?.then_some(key)
            }
        };
        self.mesh(shape).map_err(gl_err)?;
        self.targets(width, height).map_err(gl_err)?;
        let targets = self.targets.as_mut().expect("made above");
        let mesh = &self
            .meshes
            .iter()
            .find(|(s, _)| *s == shape)
            .expect("made")
            .1;
        targets.method.clear([0.0, 0.0, 0.0, 1.0]);
        let env = self.env.as_ref().filter(|_| env_lit);
        // One frame: the background and the mesh lit by the environment, or the mesh under
        // the light.
        let draw = |r: &BakeRenderer, camera: &Camera, t: &RenderTarget| match env {
            Some(e) => {
                e.background.draw(camera, &rotation, Vec3::ONE, t)?;
                r.draw_env(
                    mesh,
                    &Mat4::IDENTITY,
                    camera,
                    &lighting,
                    &e.textures,
                    &rotation,
                    t,
                )
            }
            None => r.draw(mesh, &Mat4::IDENTITY, camera, &lighting, t),
        };
        if let Some(key) = drawn {
            let r = &self.renderers[&key];
            self.gl.finish();
            let start = Instant::now();
            draw(r, &camera, &targets.method).map_err(gl_err)?;
            self.gl.finish();
            info.draw_ms = start.elapsed().as_secs_f64() * 1e3;
            info.drawn = Some(r.label().to_string());
        }

        let Some(key) = reference else {
            return Ok(info);
        };
        let state = ReferenceState {
            key,
            shape,
            camera,
            lighting: lighting.clone(),
            size: (width, height),
            env_yaw: if env_lit { self.settings.env_yaw } else { 0.0 },
        };
        let targets = self.targets.as_mut().expect("made above");
        if self.reference_state.as_ref() != Some(&state) {
            targets.reference.reset();
            self.reference_state = Some(state);
        }
        let k = self.settings.supersampling.max(1);
        let r = &self.renderers[&key];
        let start = Instant::now();
        let mut passes = 0;
        while targets.reference.passes() < k * k
            && (passes == 0 || reference_budget.is_none_or(|b| start.elapsed() < b))
        {
            let offset = jitter(k, targets.reference.passes());
            let jittered = Camera {
                jitter: Vec2::new(
                    2.0 * offset.x / width as f32,
                    2.0 * offset.y / height as f32,
                ),
                ..camera
            };
            targets
                .reference
                .add_pass(|t| draw(r, &jittered, t))
                .map_err(gl_err)?;
            passes += 1;
        }
        info.reference_passes = (targets.reference.passes(), k * k);
        Ok(info)
    }

    /// Tone-maps the last frame into `destination` (the frame's size): the method, the
    /// reference, or the method left of the middle column and the reference right of it.
    pub fn present(&self, destination: Destination) -> Result<(), ndfmap_gl::Error> {
        let Some(t) = &self.targets else {
            return Ok(());
        };
        let method = Layer {
            image: &t.method,
            scale: 1.0,
        };
        let reference = t.reference.mean();
        match self.settings.show {
            Show::Method => self.presenter.draw(method, None, destination),
            Show::Reference => self.presenter.draw(reference, None, destination),
            Show::Split => {
                let split = t.method.size().0 / 2;
                self.presenter
                    .draw(method, Some((reference, split)), destination)
            }
        }
    }

    /// Renders a `width × height` frame with the whole reference and returns it tone-mapped,
    /// 8-bit RGB, top row first.
    pub fn screenshot(&mut self, width: u32, height: u32) -> Result<Vec<u8>, String> {
        let errors = self.update_bakes(true);
        if let Some(e) = errors.into_iter().next() {
            return Err(e);
        }
        self.render(width, height, None)?;
        let out = RenderTarget::new(&self.gl, width, height).map_err(|e| e.to_string())?;
        self.present(Destination::Target(&out))
            .map_err(|e| e.to_string())?;
        read_presented_rgb8(&out).map_err(|e| e.to_string())
    }

    /// One line for the window title: method, format, BRDF, colour, what is shown, frame time.
    pub fn status(&self, info: &FrameInfo, frame_ms: f64) -> String {
        let s = &self.settings;
        let wanted = s.method();
        let mut line = format!(
            "ndfmap-viewer | {} | {} | {}",
            info.drawn.as_deref().unwrap_or("-"),
            s.brdf(),
            if self.uses_color(wanted) {
                "albedo"
            } else {
                "no colour"
            }
        );
        if s.env_lit {
            line += &format!(
                " | env {} {} yaw {:.0}° lights {}",
                self.env_input.name,
                s.env_route.name(),
                s.env_yaw.to_degrees(),
                self.env_light_count()
            );
        }
        if self.shown != Some(wanted) || self.baking() {
            line += &format!(" | baking {wanted}...");
        }
        match s.show {
            Show::Method => {}
            Show::Reference => line += " | reference",
            Show::Split => line += " | split: method | reference",
        }
        if s.show != Show::Method {
            let (n, k2) = info.reference_passes;
            line += &format!(" {n}/{k2} passes");
        }
        line += &format!(" | draw {:.1} ms, frame {:.1} ms", info.draw_ms, frame_ms);
        line
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jitter_visits_every_stratum_once() {
        for k in [1, 2, 3, 4, 8] {
            let mut seen = vec![false; (k * k) as usize];
            for pass in 0..k * k {
                let o = jitter(k, pass);
                assert!(o.x >= -0.5 && o.x < 0.5 && o.y >= -0.5 && o.y < 0.5);
                let sx = ((o.x + 0.5) * k as f32).floor() as u32;
                let sy = ((o.y + 0.5) * k as f32).floor() as u32;
                let i = (sy * k + sx) as usize;
                assert!(!seen[i], "k = {k}: stratum {i} twice");
                seen[i] = true;
            }
        }
    }

    #[test]
    fn light_turns_keep_distance_and_kind() {
        let mut s = Settings::new(MethodSpec::defaults(), ViewName::Grazing);
        let before = s.lighting.light;
        s.turn_light(0.3, -0.2);
        let after = s.lighting.light;
        assert_eq!(after.w, before.w);
        assert!((after.truncate().length() - before.truncate().length()).abs() < 1e-4);
        s.turn_light(-0.3, 0.2);
        assert!((s.lighting.light - before).length() < 1e-4);
    }

    #[test]
    fn environment_mode_steps_through_the_methods_it_draws() {
        let methods: Vec<MethodSpec> = ["pbr", "olano", "pbr-mip", "tan2005-4", "sh4"]
            .iter()
            .map(|m| m.parse().unwrap())
            .collect();
        let mut s = Settings::new(methods, ViewName::Sphere);
        assert_eq!(s.method().to_string(), "pbr");
        s.set_env(true).unwrap();
        assert!(s.env_lit && s.method().to_string() == "olano");
        s.step_method(1);
        assert_eq!(s.method().to_string(), "tan2005-4");
        s.step_method(1);
        assert_eq!(s.method().to_string(), "sh4");
        s.step_method(1);
        assert_eq!(s.method().to_string(), "olano");
        s.step_method(-1);
        assert_eq!(s.method().to_string(), "sh4");
        s.set_env(false).unwrap();
        s.step_method(1);
        assert_eq!(s.method().to_string(), "pbr");
        // No method the environment shaders draw: refused, nothing changed.
        let mut none = Settings::new(vec!["pbr".parse().unwrap()], ViewName::Sphere);
        assert!(none.set_env(true).is_err() && !none.env_lit);
        // Torrance-Sparrow has no environment route: Blinn-Phong of the same exponent.
        s.torrance_sparrow = true;
        s.set_env(true).unwrap();
        assert_eq!(s.brdf(), Brdf::BlinnPhong { s: 256.0 });
    }

    #[test]
    fn environment_turns_wrap_around() {
        use std::f32::consts::PI;
        let mut s = Settings::new(MethodSpec::defaults(), ViewName::Far);
        for _ in 0..30 {
            s.turn_env(PI / 12.0);
            assert!(s.env_yaw > -PI && s.env_yaw <= PI);
        }
        // 30 steps of 15 degrees: 450 = 90 degrees.
        assert!((s.env_yaw - PI / 2.0).abs() < 1e-4, "{}", s.env_yaw);
    }

    #[test]
    fn far_view_light_mirrors_the_eye() {
        let (_, camera, lighting) = ViewName::Far.scene();
        let e = camera.eye().normalize();
        let h = (e + lighting.light.truncate()).normalize();
        assert!(h.dot(Vec3::Y) > 0.9999);
    }
}
