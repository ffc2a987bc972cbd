//! Drawing a bake with the product shaders: [`BakeRenderer`] compiles `ndfmap::glsl`'s
//! specialized vertex and fragment shaders for a bake (for a PBR bake, the plain glTF GGX shader
//! of [`crate::gltf`] instead: no ndfmap shader code), uploads its textures, and draws meshes lit
//! by one [`Lighting`]; [`Scene`] bundles a mesh, a camera and lighting, as the regression renders,
//! the frame-time benchmark and the viewer use them.

use crate::texture::TableTexture;
use crate::{BakeTextures, Camera, Error, Gl, Mesh, Program, RenderTarget, Result, draw_mesh};
use glam::{Mat4, Vec3, Vec4};
use ndfmap::bake::{Bake, Method};
use ndfmap::brdf::Brdf;
use ndfmap::glsl::{ShaderBrdf, ShaderLight, ShaderOptions, Stage, source, uniforms};
use std::cell::RefCell;

/// The BRDF's side of a program: its uniforms ([`ndfmap::glsl::uniforms`]: parameters and, for
/// SH, `ρ̂_l`) and a tabulated BRDF's table texture, kept between draws.
#[derive(Default)]
pub struct BrdfBinding {
    table: RefCell<Option<(Brdf, TableTexture)>>,
}

impl BrdfBinding {
    /// Sets `brdf`'s uniforms on `program` (an SH shader of band limit `sh_lmax` also gets
    /// `ndf_sh_rho`) and binds a tabulated BRDF's table to texture unit `unit` (uploaded on
    /// first use, again when the BRDF changes). Fails when `brdf` is not the BRDF `compiled`
    /// specializes.
    pub fn apply(
        &self,
        gl: &Gl,
        program: &Program,
        brdf: &Brdf,
        compiled: ShaderBrdf,
        sh_lmax: Option<usize>,
        unit: u32,
    ) -> Result<()> {
        if ShaderBrdf::of(brdf) != compiled {
            return Err(Error::Usage(format!(
                "{brdf} given to a shader compiled for {compiled:?}"
            )));
        }
        for (name, values) in uniforms(brdf, sh_lmax) {
            if values.len() == 1 {
                program.set_f32(name, values[0]);
            } else {
                program.set_f32_array(name, &values);
            }
        }
        if let Brdf::Tabulated(t) = brdf {
            let mut slot = self.table.borrow_mut();
            if slot.as_ref().is_none_or(|(b, _)| b != brdf) {
                *slot = Some((brdf.clone(), TableTexture::upload(gl, t)?));
            }
            if let Some((_, texture)) = slot.as_ref() {
                texture.bind(program, unit);
            }
        }
        Ok(())
    }
}

/// One light and the material: the uniforms of `glsl/ndf_fragment.glsl`'s mesh entry point.
#[derive(Debug, Clone, PartialEq)]
pub struct Lighting {
    /// `w = 0`: direction towards the light (world space); `w = 1`: point light position.
    pub light: Vec4,
    /// Light colour (point lights fall off with 1/d²).
    pub color: Vec3,
    /// Diffuse coefficient K_d.
    pub kd: Vec3,
    /// Specular coefficient K_s.
    pub ks: Vec3,
    /// The specular BRDF and its parameter (must match the shader's [`ShaderBrdf`]).
    pub brdf: Brdf,
}

impl Default for Lighting {
    /// A white directional light from above and to the side, K_d = 0.5, K_s = 0.5, Blinn-Phong
    /// s = 256.
    fn default() -> Self {
        Lighting {
            light: Vec4::new(0.4, 0.8, 0.45, 0.0),
            color: Vec3::ONE,
            kd: Vec3::splat(0.5),
            ks: Vec3::splat(0.5),
            brdf: Brdf::BlinnPhong { s: 256.0 },
        }
    }
}

/// A bake on the GPU with its compiled shader, ready to draw meshes.
pub struct BakeRenderer {
    gl: Gl,
    program: Program,
    textures: BakeTextures,
    brdf: ShaderBrdf,
    binding: BrdfBinding,
    sh_lmax: Option<usize>,
    label: String,
    light: ShaderLight,
}

impl BakeRenderer {
    /// Uploads `bake`'s textures in `bake.format` and compiles its shaders specialized with
    /// `options` (which must not ask for the probe variant). A PBR bake gets the plain glTF
    /// GGX shader ([`crate::gltf::sources`]; `options.brdf` must be GGX).
    pub fn new(gl: &Gl, bake: &Bake, options: &ShaderOptions) -> Result<BakeRenderer> {
        let textures = BakeTextures::upload(gl, bake, bake.format)?;
        Self::with_textures(gl, bake, textures, options)
    }

    /// Like [`BakeRenderer::new`], with textures uploaded already (e.g.
    /// [`BakeTextures::upload_ktx2`] from container files): `bake` describes them (method,
    /// lobes, format: what the shaders are specialized for); its texels are not read.
    /// Block-compressed textures ([`BakeTextures::compression`]) get shaders that undo the
    /// bias of signed channels, with the clamps of the textures' shading format.
    pub fn with_textures(
        gl: &Gl,
        bake: &Bake,
        textures: BakeTextures,
        options: &ShaderOptions,
    ) -> Result<BakeRenderer> {
        if options.probe {
            return Err(Error::Usage(
                "BakeRenderer draws meshes: the probe variant is for full-screen tests".into(),
            ));
        }
        // A PBR bake has no ndfmap shader: an engine's plain GGX shader draws it.
        let (vertex, fragment) = if bake.method == Method::Pbr {
            crate::gltf::sources(bake, options.brdf, false)?
        } else if textures.compression().is_some() {
            // Block-compressed textures hold signed channels biased, in the codec's shading
            // format (BC6H: f16 clamps, BC7/BC5/BC4: unorm8).
            let spec = ndfmap::glsl::ShaderSpec {
                format: textures.format(),
                biased: true,
                ..ndfmap::glsl::ShaderSpec::of(bake)
            };
            (
                ndfmap::glsl::source_for(&spec, Stage::Vertex, options)?,
                ndfmap::glsl::source_for(&spec, Stage::Fragment, options)?,
            )
        } else {
            (
                source(bake, Stage::Vertex, options)?,
                source(bake, Stage::Fragment, options)?,
            )
        };
        let program = Program::new(gl, &vertex, &fragment)?;
        Ok(BakeRenderer {
            gl: gl.clone(),
            program,
            textures,
            brdf: options.brdf,
            binding: BrdfBinding::default(),
            sh_lmax: (bake.method == Method::Sh).then(|| ndfmap::sh::lmax_of(bake)),
            label: bake.label(),
            light: options.light,
        })
    }

    /// The bake's label (`vmf6a f16`, …).
    pub fn label(&self) -> &str {
        &self.label
    }

    /// The compiled program.
    pub fn program(&self) -> &Program {
        &self.program
    }

    /// Draws `mesh` placed by `model`, seen by `camera`, lit by `lighting`, into `target` (depth
    /// tested; clear the target first). Fails when `lighting.brdf` is not the BRDF the shader was
    /// compiled for.
    pub fn draw(
        &self,
        mesh: &Mesh,
        model: &Mat4,
        camera: &Camera,
        lighting: &Lighting,
        target: &RenderTarget,
    ) -> Result<()> {
        let p = &self.program;
        let unit = self.textures.len() as u32;
        self.binding
            .apply(&self.gl, p, &lighting.brdf, self.brdf, self.sh_lmax, unit)?;
        self.textures.bind(p);
        camera.set_uniforms(p, model);
        p.set_vec4("ndf_light", lighting.light);
        p.set_vec3("ndf_light_color", lighting.color);
        p.set_vec3("ndf_kd", lighting.kd);
        p.set_vec3("ndf_ks", lighting.ks);
        draw_mesh(p, mesh, target)
    }

    /// Draws `mesh` like [`BakeRenderer::draw`], lit by the environment `env` turned by
    /// `rotation` (world → environment frame, [`crate::env_rotation`]) instead of a light:
    /// `lighting.color` scales the radiance, `lighting.light` is unused. The shader must have
    /// been compiled with an environment [`ShaderLight`] (its route is the one drawn).
    #[allow(clippy::too_many_arguments)]
    pub fn draw_env(
        &self,
        mesh: &Mesh,
        model: &Mat4,
        camera: &Camera,
        lighting: &Lighting,
        env: &crate::EnvTextures,
        rotation: &glam::Mat3,
        target: &RenderTarget,
    ) -> Result<()> {
        let route = match self.light {
            ShaderLight::Point => {
                return Err(Error::Usage(
                    "draw_env needs a shader compiled for environment lighting".into(),
                ));
            }
            ShaderLight::EnvPrefiltered | ShaderLight::PointAndEnvPrefiltered => {
                ndfmap::envlight::Route::Prefiltered
            }
            ShaderLight::EnvSh => ndfmap::envlight::Route::Sh,
        };
        if self.light == ShaderLight::PointAndEnvPrefiltered {
            // Both: `lighting` is the point light, the environment at the same colour scale.
            self.program.set_vec4("ndf_light", lighting.light);
            self.program.set_vec3("ndf_env_color", lighting.color);
        }
        let p = &self.program;
        let unit = self.textures.len() as u32;
        self.binding
            .apply(&self.gl, p, &lighting.brdf, self.brdf, self.sh_lmax, unit)?;
        self.textures.bind(p);
        env.bind(p, unit + 1, &lighting.brdf, route);
        camera.set_uniforms(p, model);
        p.set_mat3("ndf_env_rotation", rotation);
        p.set_vec3("ndf_light_color", lighting.color);
        p.set_vec3("ndf_kd", lighting.kd);
        p.set_vec3("ndf_ks", lighting.ks);
        draw_mesh(p, mesh, target)
    }
}

/// The shapes scenes draw.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// [`crate::MeshData::plane`] of side `size`, the map repeated `uv_repeat` times per side.
    Plane {
        /// Side length.
        size: f32,
        /// Repetitions of the map per side.
        uv_repeat: f32,
    },
    /// [`crate::MeshData::sphere`] of radius 1 with 96 × 48 quads.
    Sphere,
}

impl Shape {
    /// The mesh of this shape on `gl`.
    pub fn mesh(&self, gl: &Gl) -> Result<Mesh> {
        match *self {
            Shape::Plane { size, uv_repeat } => Mesh::plane(gl, size, uv_repeat),
            Shape::Sphere => Mesh::sphere(gl, 1.0, 96, 48),
        }
    }
}

/// A view to render: a shape at the origin, a camera and the lighting.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    /// Short name, used in file names.
    pub name: &'static str,
    /// The shape drawn at the origin.
    pub shape: Shape,
    /// The camera.
    pub camera: Camera,
    /// Light and material.
    pub lighting: Lighting,
}

impl Scene {
    /// The fixed scenes of the regression renders and the frame-time table (square images):
    /// a plane seen head-on from far (deep MIP levels), the plane at a grazing angle lit by a
    /// point light (all levels across the image, anisotropic footprints), and a sphere under a
    /// directional light (every orientation of the tangent frame).
    pub fn standard() -> Vec<Scene> {
        let plane = Shape::Plane {
            size: 4.0,
            uv_repeat: 8.0,
        };
        vec![
            Scene {
                name: "plane-far",
                shape: plane,
                camera: Camera {
                    distance: 9.0,
                    pitch: 1.2,
                    yaw: 0.3,
                    ..Camera::default()
                },
                lighting: Lighting::default(),
            },
            Scene {
                name: "plane-grazing",
                shape: plane,
                camera: Camera {
                    distance: 3.0,
                    pitch: 0.2,
                    yaw: 0.0,
                    ..Camera::default()
                },
                lighting: Lighting {
                    light: Vec4::new(0.0, 0.6, -1.6, 1.0),
                    color: Vec3::splat(2.5),
                    ..Lighting::default()
                },
            },
            Scene {
                name: "sphere",
                shape: Shape::Sphere,
                camera: Camera {
                    distance: 3.2,
                    pitch: 0.3,
                    yaw: 0.5,
                    ..Camera::default()
                },
                lighting: Lighting {
                    light: Vec4::new(-0.5, 0.6, 0.8, 0.0),
                    ..Lighting::default()
                },
            },
        ]
    }

    /// Renders this scene with `renderer` into a fresh `size × size` target cleared to black and
    /// returns the linear RGBA pixels (rows bottom to top, [`crate::read_rgba_f32`]).
    pub fn render(&self, gl: &Gl, renderer: &BakeRenderer, size: u32) -> Result<Vec<[f32; 4]>> {
        let target = RenderTarget::new(gl, size, size)?;
        target.clear([0.0, 0.0, 0.0, 1.0]);
        let mesh = self.shape.mesh(gl)?;
        renderer.draw(
            &mesh,
            &Mat4::IDENTITY,
            &self.camera,
            &self.lighting,
            &target,
        )?;
        crate::read_rgba_f32(&target)
    }
}
