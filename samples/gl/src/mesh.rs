//! Meshes: [`MeshData`] builds indexed triangle lists on the CPU (a plane, a UV sphere),
//! [`Mesh`] holds one on the GPU with the attribute layout every program of this crate shares,
//! and [`draw_mesh`] draws it with the depth test.
//!
//! Attribute locations: 0 position (vec3), 1 normal (vec3), 2 tangent (vec4: xyz along +u,
//! w the bitangent sign), 3 uv (vec2). The bitangent `B = w·cross(N, T)` points to decreasing v,
//! that is towards bake row 0, the top of the image, which is "up" (+Y) for the OpenGL
//! normal-map convention: a tangent-space normal `n` is `n.x·T + n.y·B + n.z·N` in the world.
//! Triangles wind counter-clockwise seen from outside (from the side the normal points to).

use crate::program::Program;
use crate::target::RenderTarget;
use crate::{Gl, Result};
use glam::Vec3;
use glow::HasContext;
use std::f32::consts::PI;

/// The attribute names bound to locations 0, 1, 2, 3 before a program links.
pub const ATTRIBUTES: [&str; 4] = ["ndf_position", "ndf_normal", "ndf_tangent", "ndf_uv"];

/// One vertex: position, unit normal, unit tangent with the bitangent sign in w, texture
/// coordinates (`v = 0` is bake row 0).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Vertex {
    /// Object-space position (attribute 0).
    pub position: [f32; 3],
    /// Unit normal (attribute 1).
    pub normal: [f32; 3],
    /// Unit tangent along +u in xyz; w = ±1 so that `w·cross(N, T)` points to decreasing v
    /// (attribute 2).
    pub tangent: [f32; 4],
    /// Texture coordinates (attribute 3).
    pub uv: [f32; 2],
}

/// Floats per vertex in the GPU buffer: 3 + 3 + 4 + 2.
const VERTEX_FLOATS: usize = 12;

/// An indexed triangle list on the CPU.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct MeshData {
    /// The vertices.
    pub vertices: Vec<Vertex>,
    /// Three indices a triangle, counter-clockwise seen from outside.
    pub indices: Vec<u32>,
}

impl MeshData {
    /// A square of side `size` in the y = 0 plane, centred on the origin, facing +y, as two
    /// triangles. u runs along +x and v along +z from 0 to `uv_repeat`, so bake row 0 lies at
    /// the far edge (z = −size/2) seen from a camera on the +z side; the tangent is +x and the
    /// bitangent (image up) −z.
    pub fn plane(size: f32, uv_repeat: f32) -> MeshData {
        let h = 0.5 * size;
        let corner = |x: f32, z: f32| Vertex {
            position: [x * h, 0.0, z * h],
            normal: [0.0, 1.0, 0.0],
            tangent: [1.0, 0.0, 0.0, 1.0],
            uv: [0.5 * (x + 1.0) * uv_repeat, 0.5 * (z + 1.0) * uv_repeat],
        };
        MeshData {
            vertices: vec![
                corner(-1.0, -1.0),
                corner(-1.0, 1.0),
                corner(1.0, 1.0),
                corner(1.0, -1.0),
            ],
            indices: vec![0, 1, 2, 0, 2, 3],
        }
    }

    /// A UV sphere of `radius` centred on the origin with `segments` columns around the y axis
    /// and `rings` rows from pole to pole (at least 3 and 2). u = longitude / 2π, v = polar
    /// angle / π: bake row 0 at the north pole (+y), u increasing eastwards (towards +x at the
    /// point facing +z), so the image is upright and unmirrored seen from outside. The seam
    /// column is doubled so u runs 0..1 without wrapping.
    pub fn sphere(radius: f32, segments: u32, rings: u32) -> MeshData {
        let (segments, rings) = (segments.max(3), rings.max(2));
        let mut vertices = Vec::with_capacity(((segments + 1) * (rings + 1)) as usize);
        for i in 0..=rings {
            let v = i as f32 / rings as f32;
            let (sin_t, cos_t) = (PI * v).sin_cos();
            for j in 0..=segments {
                let u = j as f32 / segments as f32;
                let (sin_p, cos_p) = (2.0 * PI * u).sin_cos();
                let n = Vec3::new(sin_t * sin_p, cos_t, sin_t * cos_p);
                vertices.push(Vertex {
                    position: (radius * n).to_array(),
                    normal: n.to_array(),
                    // ∂P/∂φ normalized; defined at the poles too. cross(N, T) points north.
                    tangent: [cos_p, 0.0, -sin_p, 1.0],
                    uv: [u, v],
                });
            }
        }
        let row = segments + 1;
        let mut indices = Vec::with_capacity((6 * segments * rings) as usize);
        for i in 0..rings {
            for j in 0..segments {
                let (a, b) = (i * row + j, (i + 1) * row + j);
                indices.extend_from_slice(&[a, b, b + 1, a, b + 1, a + 1]);
            }
        }
        MeshData { vertices, indices }
    }
}

/// A mesh on the GPU: a vertex array with the four attributes and an index buffer.
pub struct Mesh {
    gl: Gl,
    vertex_array: glow::VertexArray,
    vertex_buffer: glow::Buffer,
    index_buffer: glow::Buffer,
    index_count: usize,
}

impl Mesh {
    /// Uploads `data` (interleaved f32 attributes, u32 indices).
    pub fn new(gl: &Gl, data: &MeshData) -> Result<Mesh> {
        let floats: Vec<u8> = data
            .vertices
            .iter()
            .flat_map(|v| {
                v.position
                    .into_iter()
                    .chain(v.normal)
                    .chain(v.tangent)
                    .chain(v.uv)
            })
            .flat_map(f32::to_ne_bytes)
            .collect();
        let indices: Vec<u8> = data.indices.iter().flat_map(|i| i.to_ne_bytes()).collect();
        let g = gl.glow();
        let created = |e: String| Gl::creation_error("mesh upload", e);
        // SAFETY: the context is current on this thread while `gl` lives; the names are owned
        // by the returned value (`glGen*` does not fail, so none is lost between the calls);
        // the attribute offsets and stride match the bytes built above.
        unsafe {
            let mesh = Mesh {
                gl: gl.clone(),
                vertex_array: g.create_vertex_array().map_err(created)?,
                vertex_buffer: g.create_buffer().map_err(created)?,
                index_buffer: g.create_buffer().map_err(created)?,
                index_count: data.indices.len(),
            };
            g.bind_vertex_array(Some(mesh.vertex_array));
            g.bind_buffer(glow::ARRAY_BUFFER, Some(mesh.vertex_buffer));
            g.buffer_data_u8_slice(glow::ARRAY_BUFFER, &floats, glow::STATIC_DRAW);
            g.bind_buffer(glow::ELEMENT_ARRAY_BUFFER, Some(mesh.index_buffer));
            g.buffer_data_u8_slice(glow::ELEMENT_ARRAY_BUFFER, &indices, glow::STATIC_DRAW);
            let stride = (VERTEX_FLOATS * 4) as i32;
            let mut offset = 0;
            for (location, size) in [3, 3, 4, 2].into_iter().enumerate() {
                g.enable_vertex_attrib_array(location as u32);
                let l = location as u32;
                g.vertex_attrib_pointer_f32(l, size, glow::FLOAT, false, stride, offset);
                offset += size * 4;
            }
            g.bind_vertex_array(None);
            g.bind_buffer(glow::ARRAY_BUFFER, None);
            gl.check_error("mesh upload")?;
            Ok(mesh)
        }
    }

    /// [`MeshData::plane`] uploaded.
    pub fn plane(gl: &Gl, size: f32, uv_repeat: f32) -> Result<Mesh> {
        Mesh::new(gl, &MeshData::plane(size, uv_repeat))
    }

    /// [`MeshData::sphere`] uploaded.
    pub fn sphere(gl: &Gl, radius: f32, segments: u32, rings: u32) -> Result<Mesh> {
        Mesh::new(gl, &MeshData::sphere(radius, segments, rings))
    }

    /// Number of indices (three per triangle).
    pub fn index_count(&self) -> usize {
        self.index_count
    }
}

impl Drop for Mesh {
    fn drop(&mut self) {
        // SAFETY: the context is current while `self.gl` lives; each name is deleted once.
        unsafe {
            let g = self.gl.glow();
            g.delete_vertex_array(self.vertex_array);
            g.delete_buffer(self.vertex_buffer);
            g.delete_buffer(self.index_buffer);
        }
    }
}

/// Draws `mesh` with `program` into `target` with the depth test on (`LESS`), no face culling,
/// without clearing (call [`RenderTarget::clear`] first). Textures and uniforms (for example
/// [`crate::Camera::set_uniforms`]) are set by the caller beforehand.
pub fn draw_mesh(program: &Program, mesh: &Mesh, target: &RenderTarget) -> Result<()> {
    let gl = program.gl();
    target.bind();
    program.bind();
    // SAFETY: the context is current while `gl` lives; the vertex array's element buffer holds
    // `index_count` u32 indices, all below the vertex count.
    unsafe {
        let g = gl.glow();
        g.enable(glow::DEPTH_TEST);
        g.depth_func(glow::LESS);
        g.depth_mask(true);
        g.bind_vertex_array(Some(mesh.vertex_array));
        g.draw_elements(
            glow::TRIANGLES,
            mesh.index_count as i32,
            glow::UNSIGNED_INT,
            0,
        );
        g.bind_vertex_array(None);
    }
    gl.check_error("mesh draw")
}
