//! Shader programs: [`Program`] compiles and links a vertex and a fragment shader, binds the
//! mesh attribute names to their fixed locations, and sets uniforms by name (absent uniforms are
//! ignored, so one setter call serves every variant of a shader).

use crate::mesh::ATTRIBUTES;
use crate::{Error, Gl, Result};
use glam::{Mat4, Vec2, Vec3, Vec4};
use glow::HasContext;

/// A vertex shader for attribute-less full-screen draws ([`crate::draw_fullscreen`]): one
/// triangle from `gl_VertexID` covering the target, with `ndf_screen_uv` running 0..1 across
/// it (0 at the first row and column, in `gl_FragCoord` orientation).
pub const FULLSCREEN_VERTEX_SHADER: &str = "#version 330 core
out vec2 ndf_screen_uv;
void main() {
    vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
    ndf_screen_uv = p;
    gl_Position = vec4(2.0 * p - 1.0, 0.0, 1.0);
}
";

/// A linked GLSL program. Sources are used as given (they carry their own `#version`).
pub struct Program {
    gl: Gl,
    program: glow::Program,
}

impl Program {
    /// Compiles `vertex` and `fragment` and links them. Before linking, the mesh attribute names
    /// (`ndf_position`, `ndf_normal`, `ndf_tangent`, `ndf_uv`) are bound to locations 0–3, so
    /// shaders may use the names with or without `layout(location)`. Compile and link failures
    /// return the driver's info log.
    pub fn new(gl: &Gl, vertex: &str, fragment: &str) -> Result<Program> {
        let g = gl.glow();
        // SAFETY: the context is current on this thread while `gl` lives; every name used is
        // created here, and the shaders are deleted before returning (the program keeps them).
        unsafe {
            let program = g
                .create_program()
                .map_err(|e| Gl::creation_error("glCreateProgram", e))?;
            // Owned from here on, so an early return deletes it.
            let owned = Program {
                gl: gl.clone(),
                program,
            };
            let mut shaders = Vec::new();
            for (stage, kind, source) in [
                ("vertex", glow::VERTEX_SHADER, vertex),
                ("fragment", glow::FRAGMENT_SHADER, fragment),
            ] {
                let shader = g
                    .create_shader(kind)
                    .map_err(|e| Gl::creation_error("glCreateShader", e))?;
                g.shader_source(shader, source);
                g.compile_shader(shader);
                if !g.get_shader_compile_status(shader) {
                    let log = g.get_shader_info_log(shader);
                    g.delete_shader(shader);
                    shaders.into_iter().for_each(|s| g.delete_shader(s));
                    return Err(Error::Compile { stage, log });
                }
                g.attach_shader(program, shader);
                shaders.push(shader);
            }
            for (location, name) in ATTRIBUTES.iter().enumerate() {
                g.bind_attrib_location(program, location as u32, name);
            }
            g.link_program(program);
            for shader in shaders {
                g.detach_shader(program, shader);
                g.delete_shader(shader);
            }
            if !g.get_program_link_status(program) {
                return Err(Error::Link {
                    log: g.get_program_info_log(program),
                });
            }
            Ok(owned)
        }
    }

    /// A program of [`FULLSCREEN_VERTEX_SHADER`] and `fragment`, for [`crate::draw_fullscreen`].
    pub fn fullscreen(gl: &Gl, fragment: &str) -> Result<Program> {
        Program::new(gl, FULLSCREEN_VERTEX_SHADER, fragment)
    }

    /// The GL program name, for calls this crate does not wrap.
    pub fn raw(&self) -> glow::Program {
        self.program
    }

    /// The context the program belongs to.
    pub fn gl(&self) -> &Gl {
        &self.gl
    }

    /// Makes the program current (`glUseProgram`).
    pub fn bind(&self) {
        // SAFETY: the context is current on this thread while `self.gl` lives; the program is
        // alive while `self` is.
        unsafe { self.gl.glow().use_program(Some(self.program)) };
    }

    /// The location of uniform `name`, `None` when the program has no such active uniform.
    pub fn uniform_location(&self, name: &str) -> Option<glow::UniformLocation> {
        // SAFETY: as in `bind`.
        unsafe { self.gl.glow().get_uniform_location(self.program, name) }
    }

    /// Binds the program and calls `set` with the location of `name`, if it has one.
    fn with_uniform(&self, name: &str, set: impl FnOnce(&glow::Context, &glow::UniformLocation)) {
        if let Some(location) = self.uniform_location(name) {
            self.bind();
            set(self.gl.glow(), &location);
        }
    }

    /// Sets `float name`; ignored when absent.
    pub fn set_f32(&self, name: &str, v: f32) {
        // SAFETY: the location belongs to this program, which `with_uniform` bound.
        self.with_uniform(name, |g, l| unsafe { g.uniform_1_f32(Some(l), v) });
    }

    /// Sets `vec2 name`; ignored when absent.
    pub fn set_vec2(&self, name: &str, v: impl Into<Vec2>) {
        let v = v.into();
        // SAFETY: as in `set_f32`.
        self.with_uniform(name, |g, l| unsafe { g.uniform_2_f32(Some(l), v.x, v.y) });
    }

    /// Sets `vec3 name`; ignored when absent.
    pub fn set_vec3(&self, name: &str, v: impl Into<Vec3>) {
        let v = v.into();
        // SAFETY: as in `set_f32`.
        self.with_uniform(name, |g, l| unsafe {
            g.uniform_3_f32(Some(l), v.x, v.y, v.z)
        });
    }

    /// Sets `vec4 name`; ignored when absent.
    pub fn set_vec4(&self, name: &str, v: impl Into<Vec4>) {
        let v = v.into();
        // SAFETY: as in `set_f32`.
        self.with_uniform(name, |g, l| unsafe {
            g.uniform_4_f32(Some(l), v.x, v.y, v.z, v.w)
        });
    }

    /// Sets `mat4 name` (column-major, as glam stores it); ignored when absent.
    pub fn set_mat4(&self, name: &str, m: &Mat4) {
        let columns = m.to_cols_array();
        // SAFETY: as in `set_f32`; the slice holds the 16 floats of one matrix.
        self.with_uniform(name, |g, l| unsafe {
            g.uniform_matrix_4_f32_slice(Some(l), false, &columns)
        });
    }

    /// Sets `mat3 name` (column-major, as glam stores it); ignored when absent.
    pub fn set_mat3(&self, name: &str, m: &glam::Mat3) {
        let columns = m.to_cols_array();
        // SAFETY: as in `set_f32`; the slice holds the 9 floats of one matrix.
        self.with_uniform(name, |g, l| unsafe {
            g.uniform_matrix_3_f32_slice(Some(l), false, &columns)
        });
    }

    /// Sets `float name[N]` from `v` (N ≤ `v.len()` values are read by GL); ignored when absent.
    pub fn set_f32_array(&self, name: &str, v: &[f32]) {
        // SAFETY: as in `set_f32`; the location is the array's first element.
        self.with_uniform(name, |g, l| unsafe { g.uniform_1_f32_slice(Some(l), v) });
    }

    /// Sets `vec3 name[N]` from `v` (3 floats per element, N ≤ `v.len() / 3` elements read by
    /// GL); ignored when absent.
    pub fn set_vec3_array(&self, name: &str, v: &[f32]) {
        // SAFETY: as in `set_f32`; the location is the array's first element and the slice
        // holds whole vec3s (glow passes `len / 3` elements).
        self.with_uniform(name, |g, l| unsafe { g.uniform_3_f32_slice(Some(l), v) });
    }

    /// Sets `vec4 name[N]` from `v` (4 floats per element, N ≤ `v.len() / 4` elements read by
    /// GL); ignored when absent.
    pub fn set_vec4_array(&self, name: &str, v: &[f32]) {
        // SAFETY: as in `set_f32`; the location is the array's first element and the slice
        // holds whole vec4s (glow passes `len / 4` elements).
        self.with_uniform(name, |g, l| unsafe { g.uniform_4_f32_slice(Some(l), v) });
    }

    /// Sets `int name` (or a sampler's texture unit); ignored when absent.
    pub fn set_i32(&self, name: &str, v: i32) {
        // SAFETY: as in `set_f32`.
        self.with_uniform(name, |g, l| unsafe { g.uniform_1_i32(Some(l), v) });
    }
}

impl Drop for Program {
    fn drop(&mut self) {
        // SAFETY: the context is current while `self.gl` lives; the program is deleted once.
        unsafe { self.gl.glow().delete_program(self.program) };
    }
}
