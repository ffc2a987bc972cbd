//! Render targets: [`RenderTarget`] is a framebuffer object with an RGBA32F colour texture and a
//! 32-bit float depth buffer; [`draw_fullscreen`] runs a fragment shader over all of it and
//! [`read_rgba_f32`] reads the colours back.

use crate::program::Program;
use crate::{Error, Gl, Result};
use glow::{HasContext, PixelPackData, PixelUnpackData};

/// An RGBA32F colour texture plus a depth renderbuffer, attached to one framebuffer object.
pub struct RenderTarget {
    gl: Gl,
    framebuffer: glow::Framebuffer,
    color: glow::Texture,
    depth: glow::Renderbuffer,
    width: u32,
    height: u32,
}

impl RenderTarget {
    /// Creates a `width × height` target (both at least 1), cleared to transparent black and
    /// depth 1.
    pub fn new(gl: &Gl, width: u32, height: u32) -> Result<RenderTarget> {
        let g = gl.glow();
        let (w, h) = (width.max(1) as i32, height.max(1) as i32);
        let created = |e: String| Gl::creation_error("framebuffer creation", e);
        // SAFETY: the context is current on this thread while `gl` lives; the three names are
        // created here and owned by the returned value, whose drop deletes them on any later
        // error. (`glGen*` does not fail, so no name is lost between the three calls.)
        unsafe {
            let target = RenderTarget {
                gl: gl.clone(),
                framebuffer: g.create_framebuffer().map_err(created)?,
                color: g.create_texture().map_err(created)?,
                depth: g.create_renderbuffer().map_err(created)?,
                width: w as u32,
                height: h as u32,
            };
            gl.with_texture_2d(target.color, || {
                g.tex_image_2d(
                    glow::TEXTURE_2D,
                    0,
                    glow::RGBA32F as i32,
                    w,
                    h,
                    0,
                    glow::RGBA,
                    glow::FLOAT,
                    PixelUnpackData::Slice(None),
                );
                let nearest = glow::NEAREST as i32;
                g.tex_parameter_i32(glow::TEXTURE_2D, glow::TEXTURE_MIN_FILTER, nearest);
                g.tex_parameter_i32(glow::TEXTURE_2D, glow::TEXTURE_MAG_FILTER, nearest);
                g.tex_parameter_i32(glow::TEXTURE_2D, glow::TEXTURE_MAX_LEVEL, 0);
            });
            g.bind_renderbuffer(glow::RENDERBUFFER, Some(target.depth));
            g.renderbuffer_storage(glow::RENDERBUFFER, glow::DEPTH_COMPONENT32F, w, h);
            g.bind_renderbuffer(glow::RENDERBUFFER, None);
            g.bind_framebuffer(glow::FRAMEBUFFER, Some(target.framebuffer));
            g.framebuffer_texture_2d(
                glow::FRAMEBUFFER,
                glow::COLOR_ATTACHMENT0,
                glow::TEXTURE_2D,
                Some(target.color),
                0,
            );
            g.framebuffer_renderbuffer(
                glow::FRAMEBUFFER,
                glow::DEPTH_ATTACHMENT,
                glow::RENDERBUFFER,
                Some(target.depth),
            );
            let status = g.check_framebuffer_status(glow::FRAMEBUFFER);
            if status != glow::FRAMEBUFFER_COMPLETE {
                return Err(Error::Framebuffer {
                    width,
                    height,
                    status,
                });
            }
            target.clear([0.0; 4]);
            gl.check_error("framebuffer creation")?;
            Ok(target)
        }
    }

    /// Width and height in pixels.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// The RGBA32F colour texture, to sample what was drawn.
    pub fn color_texture(&self) -> glow::Texture {
        self.color
    }

    /// The framebuffer object, for calls this crate does not wrap.
    pub fn raw(&self) -> glow::Framebuffer {
        self.framebuffer
    }

    /// Clears the colour to `rgba` and the depth to 1.
    pub fn clear(&self, rgba: [f32; 4]) {
        let g = self.gl.glow();
        self.bind();
        // SAFETY: the context is current while `self.gl` lives; the framebuffer is bound.
        unsafe {
            g.clear_color(rgba[0], rgba[1], rgba[2], rgba[3]);
            g.clear_depth(1.0);
            g.depth_mask(true);
            g.clear(glow::COLOR_BUFFER_BIT | glow::DEPTH_BUFFER_BIT);
        }
    }

    /// Binds the framebuffer and sets the viewport to all of it.
    pub fn bind(&self) {
        // SAFETY: the context is current while `self.gl` lives; the framebuffer is alive while
        // `self` is.
        unsafe {
            let g = self.gl.glow();
            g.bind_framebuffer(glow::FRAMEBUFFER, Some(self.framebuffer));
            g.viewport(0, 0, self.width as i32, self.height as i32);
        }
    }
}

impl Drop for RenderTarget {
    fn drop(&mut self) {
        // SAFETY: the context is current while `self.gl` lives; each name is deleted once.
        unsafe {
            let g = self.gl.glow();
            g.delete_framebuffer(self.framebuffer);
            g.delete_texture(self.color);
            g.delete_renderbuffer(self.depth);
        }
    }
}

/// Draws one full-screen triangle with `program` into `target`, depth test off, no vertex
/// attributes (a bound empty vertex array object, as the core profile needs). Use a program
/// made with [`Program::fullscreen`] or any vertex shader that places the triangle from
/// `gl_VertexID`. Textures and uniforms are bound by the caller beforehand.
pub fn draw_fullscreen(program: &Program, target: &RenderTarget) -> Result<()> {
    let gl = program.gl();
    target.bind();
    program.bind();
    // SAFETY: the context is current while `gl` lives; the vertex array is the context's own.
    unsafe {
        let g = gl.glow();
        g.disable(glow::DEPTH_TEST);
        g.bind_vertex_array(Some(gl.empty_vao()));
        g.draw_arrays(glow::TRIANGLES, 0, 3);
        g.bind_vertex_array(None);
    }
    gl.check_error("full-screen draw")
}

/// Reads every pixel of `target` as RGBA f32, row-major, in `glReadPixels` order: row 0 is the
/// bottom row, the one drawn at `gl_FragCoord.y = 0.5`, and index `y·width + x` is the pixel at
/// `gl_FragCoord.xy = (x + 0.5, y + 0.5)`.
pub fn read_rgba_f32(target: &RenderTarget) -> Result<Vec<[f32; 4]>> {
    let (w, h) = (target.width as usize, target.height as usize);
    let mut bytes = vec![0u8; w * h * 16];
    target.bind();
    // SAFETY: the context is current while `target` lives; `bytes` holds w·h RGBA f32 pixels,
    // and pack alignment 4 divides the 16-byte pixels, so rows are tightly packed.
    unsafe {
        let g = target.gl.glow();
        g.pixel_store_i32(glow::PACK_ALIGNMENT, 4);
        g.read_buffer(glow::COLOR_ATTACHMENT0);
        g.read_pixels(
            0,
            0,
            w as i32,
            h as i32,
            glow::RGBA,
            glow::FLOAT,
            PixelPackData::Slice(Some(&mut bytes)),
        );
    }
    target.gl.check_error("read-back")?;
    Ok(bytes
        .chunks_exact(16)
        .map(|p| {
            std::array::from_fn(|c| f32::from_ne_bytes(p[4 * c..4 * c + 4].try_into().unwrap()))
        })
        .collect())
}
