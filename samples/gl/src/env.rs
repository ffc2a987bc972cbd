//! Environment lighting on the GPU (issue 16): [`EnvTextures`] uploads what the environment
//! shaders (`glsl/ndf_env.glsl`, [`ndfmap::glsl::ShaderLight`]) read — the prefiltered levels as
//! one equirectangular `R32F` atlas, the `L′` table and the two lobe-energy tables, all sampled
//! with `texelFetch` (filtering `NEAREST`, no MIP levels) — and sets their uniforms
//! ([`ndfmap::envgpu`]). Why an equirectangular atlas and not a cube map or a GL MIP chain:
//! the CPU's levels are equirectangular and stop halving at 16 × 8 texels, and the shader's own
//! bilinear and level blend in f32 make GL = CPU exact to rounding (module docs of
//! [`ndfmap::envgpu`]). [`env_rotation`] is the world → environment frame of the mesh shaders.

use crate::program::Program;
use crate::texture::{FloatImage, FloatSampling, float_texture};
use crate::{Gl, Result};
use glam::Mat3;
use glow::HasContext;
use ndfmap::brdf::Brdf;
use ndfmap::envgpu::{self, ENERGY_SIZE, REFLECTED_COLUMNS, REFLECTED_ROWS, Upload};
use ndfmap::envlight::{EnvLight, Route};

/// An environment on the GPU (module docs).
pub struct EnvTextures {
    gl: Gl,
    upload: Upload,
    /// atlas, L′, energy Blinn-Phong, energy GGX.
    textures: [glow::Texture; 4],
}

impl EnvTextures {
    /// Uploads `light` (about 4 MB for a 1024 × 512 panorama).
    pub fn upload(gl: &Gl, light: &EnvLight) -> Result<EnvTextures> {
        let upload = envgpu::pack(light)?;
        let mut made = Vec::new();
        let tables = [
            (
                upload.atlas_width as usize,
                upload.atlas_height as usize,
                upload.atlas.clone(),
            ),
            (REFLECTED_COLUMNS, REFLECTED_ROWS, upload.reflected.clone()),
            (
                ENERGY_SIZE.0,
                ENERGY_SIZE.1,
                envgpu::energy(light, &Brdf::BlinnPhong { s: 1.0 }).unwrap_or_default(),
            ),
            (
                ENERGY_SIZE.0,
                ENERGY_SIZE.1,
                envgpu::energy(light, &Brdf::ggx(0.5)).unwrap_or_default(),
            ),
        ];
        for (w, h, data) in &tables {
            let image = FloatImage {
                width: *w,
                height: *h,
                channels: 1,
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
        for (name, values) in envgpu::uniforms(&self.upload, brdf, route) {
            if values.len() == 1 {
                program.set_f32(name, values[0]);
            } else {
                program.set_f32_array(name, &values);
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
