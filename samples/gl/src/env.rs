//! Environment lighting on the GPU (issue 16): [`EnvTextures`] uploads what the environment
//! shaders (`glsl/ndf_env.glsl`, [`ndfmap::glsl::ShaderLight`]) read — the prefiltered levels as
//! one equirectangular `RGB32F` atlas, the `RGB32F` `L′` table and the two `RGBA32F` lobe-energy
//! tables (they do not depend on the radiance: one for all channels), all sampled
//! with `texelFetch` (filtering `NEAREST`, no MIP levels) — and sets their uniforms
//! ([`ndfmap::envgpu`]). Why an equirectangular atlas and not a cube map or a GL MIP chain:
//! the CPU's levels are equirectangular, each on a grid that resolves its lobe (two levels per
//! grid size, packed on shelves; the atlas is checked against `GL_MAX_TEXTURE_SIZE`), and the shader's own
//! bilinear and level blend in f32 make GL = CPU exact to rounding (module docs of
//! [`ndfmap::envgpu`]). [`env_rotation`] is the world → environment frame of the mesh shaders.

use crate::program::Program;
use crate::texture::{FloatImage, FloatSampling, float_texture};
use crate::{Gl, Result};
use glam::Mat3;
use glow::HasContext;
use ndfmap::brdf::Brdf;
use ndfmap::envgpu::{
    self, CHANNELS, ENERGY_CHANNELS, ENERGY_SIZE, REFLECTED_COLUMNS, REFLECTED_ROWS, Upload,
};
use ndfmap::envlight::{EnvLight, Route};

/// An environment on the GPU (module docs).
pub struct EnvTextures {
    gl: Gl,
    upload: Upload,
    /// atlas, L′, energy Blinn-Phong, energy GGX.
    textures: [glow::Texture; 4],
}

impl EnvTextures {
    /// Uploads `light`, RGB (about 24 MB for a 1024 × 512 panorama, almost all of it the atlas).
    pub fn upload(gl: &Gl, light: &EnvLight) -> Result<EnvTextures> {
        let upload = envgpu::pack(light)?;
        let mut made = Vec::new();
        let tables = [
            (
                upload.atlas_width as usize,
                upload.atlas_height as usize,
                CHANNELS,
                upload.atlas.clone(),
            ),
            (
                REFLECTED_COLUMNS,
                REFLECTED_ROWS,
                CHANNELS,
                upload.reflected.clone(),
            ),
            (
                ENERGY_SIZE.0,
                ENERGY_SIZE.1,
                ENERGY_CHANNELS,
                envgpu::energy(light, &Brdf::BlinnPhong { s: 1.0 }).unwrap_or_default(),
            ),
            (
                ENERGY_SIZE.0,
                ENERGY_SIZE.1,
                ENERGY_CHANNELS,
                envgpu::energy(light, &Brdf::ggx(0.5)).unwrap_or_default(),
            ),
        ];
        for (w, h, channels, data) in &tables {
            let image = FloatImage {
                width: *w,
                height: *h,
                channels: *channels,
                data,
            };
            match float_texture(gl, image, FloatSampling::Fetch, "environment table upload") {
                Ok(t) => made.push(t),
                Err(e) => {
                    for t in made {
                        // SAFETY: the context is current; each texture made above is deleted once.
                        unsafe { gl.glow().delete_texture(t) };
                    }
                    return Err(e);
                }
            }
        }
        Ok(EnvTextures {
            gl: gl.clone(),
            upload,
            textures: [made[0], made[1], made[2], made[3]],
        })
    }

    /// The packed data (atlas layout, SH coefficients, `L′`).
    pub fn data(&self) -> &Upload {
        &self.upload
    }

    /// Binds the textures to units `first_unit` (atlas), `first_unit + 1` (the BRDF's energy
    /// table) and `first_unit + 2` (`L′`), and sets `program`'s environment uniforms for `brdf`
    /// lit by `route` ([`envgpu::uniforms`]). Uniforms and samplers the program lacks are
    /// skipped.
    pub fn bind(&self, program: &Program, first_unit: u32, brdf: &Brdf, route: Route) {
        let energy = match brdf {
            Brdf::Ggx(_) => self.textures[3],
            _ => self.textures[2],
        };
        let g = self.gl.glow();
        for (i, (texture, name)) in [
            (self.textures[0], "ndf_env_atlas"),
            (energy, "ndf_env_energy"),
            (self.textures[1], "ndf_env_reflected"),
        ]
        .into_iter()
        .enumerate()
        {
            let unit = first_unit + i as u32;
            // SAFETY: the context is current while `self.gl` lives; the texture is alive while
            // `self` is.
            unsafe {
                g.active_texture(glow::TEXTURE0 + unit);
                g.bind_texture(glow::TEXTURE_2D, Some(texture));
                g.active_texture(glow::TEXTURE0);
            }
            program.set_i32(name, unit as i32);
        }
        for u in envgpu::uniforms(&self.upload, brdf, route) {
            match (u.components, u.values.len()) {
                (3, _) => program.set_vec3_array(u.name, &u.values),
                (4, _) => program.set_vec4_array(u.name, &u.values),
                (_, 1) => program.set_f32(u.name, u.values[0]),
                _ => program.set_f32_array(u.name, &u.values),
            }
        }
    }
}

impl Drop for EnvTextures {
    fn drop(&mut self) {
        for t in self.textures {
            // SAFETY: the context is current while `self.gl` lives; each texture deleted once.
            unsafe { self.gl.glow().delete_texture(t) };
        }
    }
}

/// The world → environment rotation of the mesh shaders (`ndf_env_rotation`): the world is
/// +Y up (the meshes' and the camera's convention), the environment +Z up
/// (`ndfmap::environment`), world +Y → environment +Z, world +X → environment +X, then the
/// environment turned by `yaw` radians about its zenith (positive: the radiance seen at
/// azimuth φ is seen at φ + yaw, as `EnvOptions::yaw_deg` rotates a panorama).
pub fn env_rotation(yaw: f32) -> Mat3 {
    // (x, y, z)_world → (x, −z, y)_env, then rotate the looked-up direction by −yaw.
    let to_env = Mat3::from_cols(
        glam::Vec3::new(1.0, 0.0, 0.0),
        glam::Vec3::new(0.0, 0.0, 1.0),
        glam::Vec3::new(0.0, -1.0, 0.0),
    );
    Mat3::from_rotation_z(-yaw) * to_env
}

/// The panorama drawn behind an environment-lit scene: a full-screen pass that looks up the
/// equirectangular RGB environment (bilinear, one level) in the direction of each pixel's view
/// ray, turned into the environment's frame by the same rotation as the mesh shaders
/// ([`env_rotation`]), so the background and the lighting agree at every yaw.
pub struct EnvBackground {
    gl: Gl,
    program: Program,
    texture: glow::Texture,
}

const BACKGROUND_FRAGMENT: &str = "#version 330 core
in vec2 ndf_screen_uv;
uniform mat4 ndf_inv_view_proj;   // clip -> world
uniform mat3 ndf_env_rotation;    // world -> environment frame
uniform sampler2D ndf_env_panorama;
uniform vec3 ndf_env_scale;
out vec4 ndf_out;
const float NDF_PI = 3.14159265358979323846;
void main() {
    vec2 ndc = 2.0 * ndf_screen_uv - 1.0;
    vec4 a = ndf_inv_view_proj * vec4(ndc, -1.0, 1.0);
    vec4 b = ndf_inv_view_proj * vec4(ndc, 1.0, 1.0);
    vec3 d = ndf_env_rotation * normalize(b.xyz / b.w - a.xyz / a.w);
    // environment::Geometry::coordinates: u from azimuth -pi, v from the zenith.
    float u = (atan(d.y, d.x) + NDF_PI) / (2.0 * NDF_PI);
    float v = acos(clamp(d.z, -1.0, 1.0)) / NDF_PI;
    ndf_out = vec4(ndf_env_scale * textureLod(ndf_env_panorama, vec2(u, v), 0.0).rgb, 1.0);
}
";

impl EnvBackground {
    /// Uploads `env`'s RGB texels (an `RGB32F` texture: 6 MB for 1024 × 512) and compiles the
    /// pass.
    pub fn new(gl: &Gl, env: &ndfmap::environment::Environment) -> Result<EnvBackground> {
        let program = Program::fullscreen(gl, BACKGROUND_FRAGMENT)?;
        let data: Vec<f32> = env.texels().iter().flatten().copied().collect();
        let image = FloatImage {
            width: env.width() as usize,
            height: env.height() as usize,
            channels: 3,
            data: &data,
        };
        let texture = float_texture(
            gl,
            image,
            FloatSampling::Equirectangular,
            "environment background upload",
        )?;
        Ok(EnvBackground {
            gl: gl.clone(),
            program,
            texture,
        })
    }

    /// Draws the panorama seen by `camera` into `target` (every pixel; depth untouched), the
    /// radiance multiplied by `scale`; draw it first, then the meshes.
    pub fn draw(
        &self,
        camera: &crate::Camera,
        rotation: &Mat3,
        scale: glam::Vec3,
        target: &crate::RenderTarget,
    ) -> Result<()> {
        let p = &self.program;
        let g = self.gl.glow();
        // SAFETY: the context is current while `self.gl` lives; the texture is alive while
        // `self` is.
        unsafe {
            g.active_texture(glow::TEXTURE0);
            g.bind_texture(glow::TEXTURE_2D, Some(self.texture));
        }
        p.set_i32("ndf_env_panorama", 0);
        p.set_mat4("ndf_inv_view_proj", &camera.view_proj().inverse());
        p.set_mat3("ndf_env_rotation", rotation);
        p.set_vec3("ndf_env_scale", scale);
        crate::draw_fullscreen(p, target)
    }
}

impl Drop for EnvBackground {
    fn drop(&mut self) {
        // SAFETY: the context is current while `self.gl` lives; deleted once.
        unsafe { self.gl.glow().delete_texture(self.texture) };
    }
}
