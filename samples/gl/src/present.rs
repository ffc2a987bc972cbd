//! Showing linear radiance: one tone map (Reinhard `x/(1+x)` per channel, then the sRGB curve)
//! as a CPU function ([`tone_map`]) and a GLSL function ([`TONE_MAP_GLSL`]); [`Presenter`]
//! tone-maps one image, or two side by side at a split column, into a window's default
//! framebuffer or a [`RenderTarget`]; [`Accumulator`] sums passes (jittered supersampling) on the
//! GPU.
//!
//! Images are stored and shown in the same way everywhere: the regression references of
//! `tests/scenes.rs`, the viewer's window and its headless screenshots.

use crate::program::Program;
use crate::target::RenderTarget;
use crate::{Gl, Result};
use glow::HasContext;

/// Reinhard then the sRGB curve, per channel, in [0, 1); negative and NaN input give 0.
pub fn tone_map(v: f32) -> f32 {
    let v = if v > 0.0 { v } else { 0.0 };
    let x = (v / (1.0 + v)) as f64;
    let s = if x <= 0.0031308 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    };
    s as f32
}

/// The GLSL twin of [`tone_map`]: `vec3 ndf_tone_map(vec3 linear)`.
pub const TONE_MAP_GLSL: &str = "
vec3 ndf_tone_map(vec3 c) {
    vec3 v = max(c, vec3(0.0));
    vec3 x = v / (1.0 + v);
    vec3 lo = 12.92 * x;
    vec3 hi = 1.055 * pow(x, vec3(1.0 / 2.4)) - 0.055;
    return mix(hi, lo, vec3(lessThanEqual(x, vec3(0.0031308))));
}
";

/// Reads a target [`Presenter::draw`] wrote (tone-mapped values in [0, 1]) as 8-bit RGB, top
/// row first (image order), rounding as an 8-bit window framebuffer would.
pub fn read_presented_rgb8(target: &RenderTarget) -> Result<Vec<u8>> {
    let (w, h) = target.size();
    let pixels = crate::read_rgba_f32(target)?;
    let mut out = Vec::with_capacity(w as usize * h as usize * 3);
    for y in (0..h as usize).rev() {
        for p in &pixels[y * w as usize..(y + 1) * w as usize] {
            out.extend([0, 1, 2].map(|c| (p[c].clamp(0.0, 1.0) * 255.0).round() as u8));
        }
    }
    Ok(out)
}

/// Reads the default framebuffer's back buffer (what [`Presenter::draw`] wrote to
/// [`Destination::Window`], before the swap) as 8-bit RGB, top row first.
pub fn read_default_framebuffer_rgb8(gl: &Gl, width: u32, height: u32) -> Result<Vec<u8>> {
    let row = width as usize * 3;
    let mut bytes = vec![0u8; row * height as usize];
    // SAFETY: the context is current while `gl` lives; `bytes` holds width·height RGB8 pixels
    // with pack alignment 1, so rows are tightly packed.
    unsafe {
        let g = gl.glow();
        g.bind_framebuffer(glow::FRAMEBUFFER, None);
        g.read_buffer(glow::BACK);
        g.pixel_store_i32(glow::PACK_ALIGNMENT, 1);
        g.read_pixels(
            0,
            0,
            width as i32,
            height as i32,
            glow::RGB,
            glow::UNSIGNED_BYTE,
            glow::PixelPackData::Slice(Some(&mut bytes)),
        );
        g.pixel_store_i32(glow::PACK_ALIGNMENT, 4);
    }
    gl.check_error("default framebuffer read-back")?;
    Ok(bytes.chunks_exact(row).rev().flatten().copied().collect())
}

/// Where [`Presenter::draw`] writes.
#[derive(Clone, Copy)]
pub enum Destination<'a> {
    /// The default framebuffer (a window's back buffer) of this size.
    Window {
        /// Width in pixels.
        width: u32,
        /// Height in pixels.
        height: u32,
    },
    /// A render target (values in [0, 1]: the tone-mapped sRGB codes / 255).
    Target(&'a RenderTarget),
}

impl Destination<'_> {
    fn size(&self) -> (u32, u32) {
        match self {
            Destination::Window { width, height } => (*width, *height),
            Destination::Target(t) => t.size(),
        }
    }
}

/// One image to show: a target's colour and the factor its values are multiplied by (e.g.
/// `1/passes` for an [`Accumulator`]'s sum).
#[derive(Clone, Copy)]
pub struct Layer<'a> {
    /// The linear image, the destination's size.
    pub image: &'a RenderTarget,
    /// Multiplies the image's values before tone mapping.
    pub scale: f32,
}

/// The tone-mapping presentation pass.
pub struct Presenter {
    program: Program,
}

const PRESENT_FRAGMENT: &str = "#version 330 core
uniform sampler2D ndf_left;
uniform sampler2D ndf_right;
uniform float ndf_left_scale;
uniform float ndf_right_scale;
uniform float ndf_split;    // first column of the right image; >= width: the left image only
out vec4 ndf_out;
";

const PRESENT_MAIN: &str = "
void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    vec3 c = float(p.x) < ndf_split ? ndf_left_scale * texelFetch(ndf_left, p, 0).rgb
                                    : ndf_right_scale * texelFetch(ndf_right, p, 0).rgb;
    // A one-pixel white line just left of the split column.
    if (float(p.x) == ndf_split - 1.0) c = vec3(1e6);
    ndf_out = vec4(ndf_tone_map(c), 1.0);
}
";

impl Presenter {
    /// Compiles the presentation program.
    pub fn new(gl: &Gl) -> Result<Presenter> {
        let fragment = format!("{PRESENT_FRAGMENT}{TONE_MAP_GLSL}{PRESENT_MAIN}");
        Ok(Presenter {
            program: Program::fullscreen(gl, &fragment)?,
        })
    }

    /// Tone-maps `left` into `destination` (same size as the layers); with `right = Some((layer,
    /// split))`, columns from `split` on show `right` instead, with a white line at `split − 1`.
    pub fn draw(
        &self,
        left: Layer,
        right: Option<(Layer, u32)>,
        destination: Destination,
    ) -> Result<()> {
        let gl = self.program.gl();
        let (width, height) = destination.size();
        let (right_layer, split) = match right {
            Some((layer, split)) => (layer, split as f32),
            None => (left, f32::INFINITY),
        };
        let p = &self.program;
        p.set_i32("ndf_left", 0);
        p.set_i32("ndf_right", 1);
        p.set_f32("ndf_left_scale", left.scale);
        p.set_f32("ndf_right_scale", right_layer.scale);
        p.set_f32("ndf_split", split.min(width as f32 + 1.0));
        match destination {
            Destination::Target(t) => t.bind(),
            // SAFETY: the context is current while `gl` lives; framebuffer 0 is the default.
            Destination::Window { .. } => unsafe {
                gl.glow().bind_framebuffer(glow::FRAMEBUFFER, None);
                gl.glow().viewport(0, 0, width as i32, height as i32);
            },
        }
        p.bind();
        // SAFETY: the context is current while `gl` lives; the textures are alive while the
        // layers' targets are; the vertex array is the context's own.
        unsafe {
            let g = gl.glow();
            g.active_texture(glow::TEXTURE1);
            g.bind_texture(glow::TEXTURE_2D, Some(right_layer.image.color_texture()));
            g.active_texture(glow::TEXTURE0);
            g.bind_texture(glow::TEXTURE_2D, Some(left.image.color_texture()));
            g.disable(glow::DEPTH_TEST);
            g.disable(glow::FRAMEBUFFER_SRGB);
            g.bind_vertex_array(Some(gl.empty_vao()));
            g.draw_arrays(glow::TRIANGLES, 0, 3);
            g.bind_vertex_array(None);
        }
        gl.check_error("present")
    }
}

/// A running sum of passes drawn into a scratch target, added on the GPU (blending ONE, ONE into
/// an RGBA32F target): the supersampled reference accumulates jittered passes here.
pub struct Accumulator {
    sum: RenderTarget,
    scratch: RenderTarget,
    add: Program,
    passes: u32,
}

const ADD_FRAGMENT: &str = "#version 330 core
uniform sampler2D ndf_pass;
out vec4 ndf_out;
void main() { ndf_out = texelFetch(ndf_pass, ivec2(gl_FragCoord.xy), 0); }
";

impl Accumulator {
    /// An empty `width × height` sum.
    pub fn new(gl: &Gl, width: u32, height: u32) -> Result<Accumulator> {
        Ok(Accumulator {
            sum: RenderTarget::new(gl, width, height)?,
            scratch: RenderTarget::new(gl, width, height)?,
            add: Program::fullscreen(gl, ADD_FRAGMENT)?,
            passes: 0,
        })
    }

    /// Width and height.
    pub fn size(&self) -> (u32, u32) {
        self.sum.size()
    }

    /// Empties the sum.
    pub fn reset(&mut self) {
        self.sum.clear([0.0; 4]);
        self.passes = 0;
    }

    /// Clears the scratch target (black, depth 1), lets `draw` render one pass into it, and adds
    /// it to the sum.
    pub fn add_pass(&mut self, draw: impl FnOnce(&RenderTarget) -> Result<()>) -> Result<()> {
        self.scratch.clear([0.0, 0.0, 0.0, 1.0]);
        draw(&self.scratch)?;
        let gl = self.add.gl();
        self.add.set_i32("ndf_pass", 0);
        // SAFETY: the context is current while `gl` lives; the scratch texture is alive while
        // `self` is. Blending is switched off again before returning.
        unsafe {
            let g = gl.glow();
            g.active_texture(glow::TEXTURE0);
            g.bind_texture(glow::TEXTURE_2D, Some(self.scratch.color_texture()));
            g.enable(glow::BLEND);
            g.blend_equation(glow::FUNC_ADD);
            g.blend_func(glow::ONE, glow::ONE);
        }
        let drawn = crate::draw_fullscreen(&self.add, &self.sum);
        // SAFETY: as above.
        unsafe { gl.glow().disable(glow::BLEND) };
        drawn?;
        self.passes += 1;
        Ok(())
    }

    /// Passes summed since the last reset.
    pub fn passes(&self) -> u32 {
        self.passes
    }

    /// The mean of the passes as a [`Layer`] (scale `1/passes`; 0 before the first pass).
    pub fn mean(&self) -> Layer<'_> {
        Layer {
            image: &self.sum,
            scale: if self.passes == 0 {
                0.0
            } else {
                1.0 / self.passes as f32
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tone_map_is_reinhard_then_srgb() {
        assert_eq!(tone_map(0.0), 0.0);
        assert_eq!(tone_map(-1.0), 0.0);
        assert_eq!(tone_map(f32::NAN), 0.0);
        // x = 1/2 after Reinhard; sRGB(1/2) = 0.7354.
        assert!((tone_map(1.0) - 0.735_356_7).abs() < 1e-6);
        // The linear segment below 0.0031308.
        assert!((tone_map(0.001) - 12.92 * (0.001 / 1.001)).abs() < 1e-7);
        assert!(tone_map(1e9) <= 1.0 && tone_map(1e9) > 0.999);
    }
}
