//! Bake upload: [`BakeTextures`] holds one 2D texture per texture chain of an
//! [`ndfmap::bake::Bake`], every MIP level uploaded from `ndfmap::pack::pack_level`, sampled
//! trilinearly with the bake's addressing.

use crate::program::Program;
use crate::{Error, Gl, Result};
use glow::{HasContext, PixelUnpackData};
use ndfmap::bake::Bake;
use ndfmap::format::Format;
use ndfmap::ingest::Addressing;

/// Sets up the bound `TEXTURE_2D` as a trilinear MIP chain of `levels` levels with `wrap`
/// addressing (both axes), and tightly packed uploads (unpack alignment 1).
fn set_mip_chain_parameters(gl: &Gl, levels: usize, wrap: i32) {
    let g = gl.glow();
    // SAFETY: the context is current on this thread while `gl` lives and the caller has a
    // texture bound to TEXTURE_2D; the parameters are valid enums for a 2D texture.
    unsafe {
        g.pixel_store_i32(glow::UNPACK_ALIGNMENT, 1);
        let last = levels as i32 - 1;
        g.tex_parameter_i32(glow::TEXTURE_2D, glow::TEXTURE_BASE_LEVEL, 0);
        g.tex_parameter_i32(glow::TEXTURE_2D, glow::TEXTURE_MAX_LEVEL, last);
        let min = glow::LINEAR_MIPMAP_LINEAR as i32;
        g.tex_parameter_i32(glow::TEXTURE_2D, glow::TEXTURE_MIN_FILTER, min);
        let mag = glow::LINEAR as i32;
        g.tex_parameter_i32(glow::TEXTURE_2D, glow::TEXTURE_MAG_FILTER, mag);
        g.tex_parameter_i32(glow::TEXTURE_2D, glow::TEXTURE_WRAP_S, wrap);
        g.tex_parameter_i32(glow::TEXTURE_2D, glow::TEXTURE_WRAP_T, wrap);
    }
}

/// The GL enums of a storage format: `(internal format, pixel type)`; the pixel format is
/// always `GL_RGBA`. f32 → `RGBA32F`/`FLOAT`, f16 → `RGBA16F`/`HALF_FLOAT`, unorm16 →
/// `RGBA16`/`UNSIGNED_SHORT`, unorm8 → `RGBA8`/`UNSIGNED_BYTE`.
pub fn gl_format(format: Format) -> (u32, u32) {
    match format {
        Format::F32 => (glow::RGBA32F, glow::FLOAT),
        Format::F16 => (glow::RGBA16F, glow::HALF_FLOAT),
        Format::Unorm16 => (glow::RGBA16, glow::UNSIGNED_SHORT),
        Format::Unorm8 => (glow::RGBA8, glow::UNSIGNED_BYTE),
    }
}

/// A block-compressed texture format [`BakeTextures::upload_ktx2`] uploads (4×4 texel blocks,
/// `GL_ARB_texture_compression_bptc` and `_rgtc`, core in GL 4.2 / 3.0). Signed channels are
/// stored biased, `0.5 + 0.5·v` (module `ndfmap::compress`), so shaders undo the bias.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Compression {
    /// BC4 (RGTC1): R, 8 bytes per block; G = B = 0, A = 1 as sampled.
    Bc4,
    /// BC5 (RGTC2): R and G, 16 bytes per block; B = 0, A = 1.
    Bc5,
    /// BC6H unsigned float (BPTC float): RGB half floats, 16 bytes per block; A = 1.
    Bc6h,
    /// BC7 (BPTC unorm): RGBA, 16 bytes per block.
    Bc7,
}

impl Compression {
    /// The GL internal format: `COMPRESSED_RED_RGTC1`, `COMPRESSED_RG_RGTC2`,
    /// `COMPRESSED_RGB_BPTC_UNSIGNED_FLOAT`, `COMPRESSED_RGBA_BPTC_UNORM`.
    pub fn gl_internal_format(self) -> u32 {
        match self {
            Compression::Bc4 => glow::COMPRESSED_RED_RGTC1,
            Compression::Bc5 => glow::COMPRESSED_RG_RGTC2,
            Compression::Bc6h => glow::COMPRESSED_RGB_BPTC_UNSIGNED_FLOAT,
            Compression::Bc7 => glow::COMPRESSED_RGBA_BPTC_UNORM,
        }
    }

    /// Bytes per 4×4 block.
    pub fn block_bytes(self) -> usize {
        match self {
            Compression::Bc4 => 8,
            _ => 16,
        }
    }

    /// The storage format whose clamps the shaders apply to the sampled values
    /// (`ndfmap::compress::Codec::shading_format`): f16 for BC6H, unorm8 for the others.
    pub fn shading_format(self) -> Format {
        match self {
            Compression::Bc6h => Format::F16,
            _ => Format::Unorm8,
        }
    }

    /// Whether the context samples the format: RGTC is core since GL 3.0; BPTC since 4.2, or
    /// with `GL_ARB_texture_compression_bptc` (Mesa's llvmpipe has both).
    pub fn is_supported(self, gl: &Gl) -> bool {
        let core = match self {
            Compression::Bc4 | Compression::Bc5 => (3, 0),
            Compression::Bc6h | Compression::Bc7 => (4, 2),
        };
        gl.version() >= core || gl.glow().supported_extensions().contains(self.extension())
    }

    /// The GL extension the format needs below GL 4.2 (BPTC) or 3.0 (RGTC).
    pub fn extension(self) -> &'static str {
        match self {
            Compression::Bc4 | Compression::Bc5 => "GL_ARB_texture_compression_rgtc",
            Compression::Bc6h | Compression::Bc7 => "GL_ARB_texture_compression_bptc",
        }
    }
}

/// The name of the sampler uniform for bake texture `index`: `ndf_tex{index}`.
pub fn sampler_name(index: usize) -> String {
    format!("ndf_tex{index}")
}

/// The textures of one bake on the GPU, in the bake's texture order.
pub struct BakeTextures {
    gl: Gl,
    textures: Vec<glow::Texture>,
    format: Format,
    compression: Option<Compression>,
    sizes: Vec<(u32, u32)>,
}

impl BakeTextures {
    /// Uploads every texture of `bake` in `format`: a 2D texture per `bake.textures[i]` with
    /// all its levels (level 0 the finest; within a level, bake row 0 first, so it lies at
    /// `t = 0`), `GL_TEXTURE_MAX_LEVEL` = levels − 1, minification `LINEAR_MIPMAP_LINEAR`,
    /// magnification `LINEAR`, wrap `REPEAT` for [`Addressing::Wrap`] and `CLAMP_TO_EDGE` for
    /// [`Addressing::Clamp`]. Unsigned-normalized formats hold signed channels biased
    /// (`0.5 + 0.5·v`). Fails, creating nothing, when the format cannot hold a texture.
    pub fn upload(gl: &Gl, bake: &Bake, format: Format) -> Result<BakeTextures> {
        for i in 0..bake.textures.len() {
            ndfmap::pack::check(bake, i, format)?;
        }
        let mut out = BakeTextures {
            gl: gl.clone(),
            textures: Vec::with_capacity(bake.textures.len()),
            format,
            compression: None,
            sizes: bake.sizes.clone(),
        };
        let (internal, pixel_type) = gl_format(format);
        let wrap = match bake.addressing {
            Addressing::Wrap => glow::REPEAT,
            Addressing::Clamp => glow::CLAMP_TO_EDGE,
        } as i32;
        let max_len = (0..bake.level_count())
            .map(|k| ndfmap::pack::packed_len(bake, k, format))
            .max()
            .unwrap_or(0);
        let mut bytes = vec![0u8; max_len];
        let g = gl.glow();
        for t in 0..bake.textures.len() {
            // SAFETY: the context is current on this thread while `gl` lives; the new texture
            // is owned by `out` at once, so an early return deletes it.
            let texture = unsafe { g.create_texture() }
                .map_err(|e| Gl::creation_error("glCreateTexture", e))?;
            out.textures.push(texture);
            gl.with_texture_2d(texture, || {
                set_mip_chain_parameters(gl, bake.level_count(), wrap);
                for (level, &(w, h)) in bake.sizes.iter().enumerate() {
                    let n = ndfmap::pack::pack_level(bake, t, level, format, &mut bytes)?;
                    // SAFETY: `bytes[..n]` holds w·h RGBA texels of `pixel_type`, tightly
                    // packed (unpack alignment 1), as `pack_level` documents.
                    unsafe {
                        g.tex_image_2d(
                            glow::TEXTURE_2D,
                            level as i32,
                            internal as i32,
                            w as i32,
                            h as i32,
                            0,
                            glow::RGBA,
                            pixel_type,
                            PixelUnpackData::Slice(Some(&bytes[..n])),
                        );
                    }
                }
                Ok::<_, Error>(())
            })?;
        }
        gl.check_error("texture upload")?;
        Ok(out)
    }

    /// Uploads KTX2 files (one per texture, in the bake's texture order, as
    /// `ndfmap bake --container ktx2` writes them) straight into textures: each file is parsed
    /// by the `ktx2` crate and its levels are handed to `glTexImage2D` as they lie in the file,
    /// with the sampling state of [`BakeTextures::upload`] (`addressing` as the bake's). The
    /// files must be RGBA32F, RGBA16F, RGBA16 or RGBA8, or block-compressed BC7, BC6H (unsigned
    /// float), BC5 or BC4 (`ndfmap bake --compress`; [`Compression`], uploaded with
    /// `glCompressedTexImage2D`, the blocks as they lie in the file; [`BakeTextures::format`]
    /// is then the codec's shading format and [`BakeTextures::compression`] says which), all in
    /// one format, with full MIP chains of the same size; anything else (or a compressed format
    /// the context lacks) is an error and nothing is created.
    pub fn upload_ktx2(gl: &Gl, files: &[&[u8]], addressing: Addressing) -> Result<BakeTextures> {
        let bad = |i: usize, what: String| Error::Usage(format!("KTX2 file {i}: {what}"));
        let mut readers = Vec::with_capacity(files.len());
        for (i, f) in files.iter().enumerate() {
            let r = ktx2::Reader::new(*f).map_err(|e| bad(i, e.to_string()))?;
            readers.push(r);
        }
        let Some(first) = readers.first() else {
            return Err(Error::Usage("no KTX2 file to upload".into()));
        };
        let h = first.header();
        let (format, compression) = match h.format {
            Some(ktx2::Format::R32G32B32A32_SFLOAT) => (Format::F32, None),
            Some(ktx2::Format::R16G16B16A16_SFLOAT) => (Format::F16, None),
            Some(ktx2::Format::R16G16B16A16_UNORM) => (Format::Unorm16, None),
            Some(ktx2::Format::R8G8B8A8_UNORM) => (Format::Unorm8, None),
            Some(ktx2::Format::BC4_UNORM_BLOCK) => (Format::Unorm8, Some(Compression::Bc4)),
            Some(ktx2::Format::BC5_UNORM_BLOCK) => (Format::Unorm8, Some(Compression::Bc5)),
            Some(ktx2::Format::BC6H_UFLOAT_BLOCK) => (Format::F16, Some(Compression::Bc6h)),
            Some(ktx2::Format::BC7_UNORM_BLOCK) => (Format::Unorm8, Some(Compression::Bc7)),
            other => return Err(bad(0, format!("format {other:?} is not uploaded here"))),
        };
        if let Some(c) = compression
            && !c.is_supported(gl)
        {
            return Err(Error::Usage(format!(
                "this GL context cannot sample {c:?} textures (no {})",
                c.extension()
            )));
        }
        let mut sizes = Vec::new();
        let (mut w, mut hgt) = (h.pixel_width, h.pixel_height.max(1));
        for _ in 0..h.level_count.max(1) {
            sizes.push((w, hgt));
            (w, hgt) = ((w / 2).max(1), (hgt / 2).max(1));
        }
        for (i, r) in readers.iter().enumerate() {
            let hi = r.header();
            if (hi.format, hi.pixel_width, hi.pixel_height, hi.level_count)
                != (h.format, h.pixel_width, h.pixel_height, h.level_count)
                || hi.supercompression_scheme.is_some()
            {
                return Err(bad(
                    i,
                    "differs from file 0 in format, size or levels".into(),
                ));
            }
            for (k, level) in r.levels().enumerate() {
                let (lw, lh) = sizes[k];
                let need = match compression {
                    Some(c) => lw.div_ceil(4) as usize * lh.div_ceil(4) as usize * c.block_bytes(),
                    None => lw as usize * lh as usize * 4 * format.channel_bytes(),
                };
                if level.data.len() != need {
                    return Err(bad(
                        i,
                        format!("level {k} has {} bytes, {need} expected", level.data.len()),
                    ));
                }
            }
        }
        let mut out = BakeTextures {
            gl: gl.clone(),
            textures: Vec::with_capacity(readers.len()),
            format,
            compression,
            sizes: sizes.clone(),
        };
        let (internal, pixel_type) = gl_format(format);
        let wrap = match addressing {
            Addressing::Wrap => glow::REPEAT,
            Addressing::Clamp => glow::CLAMP_TO_EDGE,
        } as i32;
        let g = gl.glow();
        for r in &readers {
            // SAFETY: the context is current on this thread while `gl` lives; the new texture
            // is owned by `out` at once, so an early return deletes it.
            let texture = unsafe { g.create_texture() }
                .map_err(|e| Gl::creation_error("glCreateTexture", e))?;
            out.textures.push(texture);
            gl.with_texture_2d(texture, || {
                set_mip_chain_parameters(gl, sizes.len(), wrap);
                for (k, level) in r.levels().enumerate() {
                    let (lw, lh) = sizes[k];
                    if let Some(c) = compression {
                        // SAFETY: `level.data` holds the level's whole 4×4 blocks of `c`,
                        // row by row of blocks (its length checked above), as
                        // glCompressedTexImage2D reads them.
                        unsafe {
                            g.compressed_tex_image_2d(
                                glow::TEXTURE_2D,
                                k as i32,
                                c.gl_internal_format() as i32,
                                lw as i32,
                                lh as i32,
                                0,
                                level.data.len() as i32,
                                level.data,
                            );
                        }
                        continue;
                    }
                    // SAFETY: `level.data` holds lw·lh RGBA texels of `pixel_type`, tightly
                    // packed (checked above; KTX2 data is little-endian, as this host).
                    unsafe {
                        g.tex_image_2d(
                            glow::TEXTURE_2D,
                            k as i32,
                            internal as i32,
                            lw as i32,
                            lh as i32,
                            0,
                            glow::RGBA,
                            pixel_type,
                            PixelUnpackData::Slice(Some(level.data)),
                        );
                    }
                }
                Ok::<_, Error>(())
            })?;
        }
        gl.check_error("texture upload")?;
        Ok(out)
    }

    /// Binds texture `i` to texture unit `i` for every texture, and sets the sampler uniform
    /// `ndf_tex{i}` of `program` to `i` where the program has it.
    pub fn bind(&self, program: &Program) {
        let g = self.gl.glow();
        for (i, &texture) in self.textures.iter().enumerate() {
            // SAFETY: the context is current while `self.gl` lives; the texture is alive while
            // `self` is; units up to the 48 GL 3.3 guarantees are valid.
            unsafe {
                g.active_texture(glow::TEXTURE0 + i as u32);
                g.bind_texture(glow::TEXTURE_2D, Some(texture));
            }
            program.set_i32(&sampler_name(i), i as i32);
        }
        // SAFETY: as above; leaves unit 0 active, the GL default.
        unsafe { g.active_texture(glow::TEXTURE0) };
    }

    /// Number of textures (the bake's `textures.len()`).
    pub fn len(&self) -> usize {
        self.textures.len()
    }

    /// Whether there is no texture.
    pub fn is_empty(&self) -> bool {
        self.textures.is_empty()
    }

    /// The GL name of texture `i`, for calls this crate does not wrap.
    pub fn raw(&self, i: usize) -> glow::Texture {
        self.textures[i]
    }

    /// The storage format the textures were uploaded in (for block-compressed textures, the
    /// codec's shading format: [`Compression::shading_format`]).
    pub fn format(&self) -> Format {
        self.format
    }

    /// The block compression of the textures, if any ([`BakeTextures::upload_ktx2`]).
    pub fn compression(&self) -> Option<Compression> {
        self.compression
    }

    /// Width and height of every level, finest first (the bake's sizes).
    pub fn sizes(&self) -> &[(u32, u32)] {
        &self.sizes
    }
}

impl Drop for BakeTextures {
    fn drop(&mut self) {
        for &t in &self.textures {
            // SAFETY: the context is current while `self.gl` lives; each texture is deleted once.
            unsafe { self.gl.glow().delete_texture(t) };
        }
    }
}

/// Row-major float texels for [`float_texture`]: `width × height` texels of `channels` (1: a
/// table, 3: RGB, 4: a table of four values per texel), row 0 first (texture coordinate t = 0).
pub(crate) struct FloatImage<'a> {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub data: &'a [f32],
}

/// How a [`float_texture`] is sampled.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(crate) enum FloatSampling {
    /// A table read with `texelFetch`: filtering `NEAREST`, clamped.
    Fetch,
    /// An equirectangular image read with `texture`: bilinear, wrapping in s (azimuth),
    /// clamped in t (the poles).
    Equirectangular,
}

/// Creates a one-level `R32F` (`channels` 1), `RGB32F` (3) or `RGBA32F` (4) texture from `image`, refused
/// with [`Error::Usage`] when a side exceeds `GL_MAX_TEXTURE_SIZE`; `what` names the upload in
/// a GL error (the texture is deleted then). The one float upload of the crate: BRDF tables,
/// environment tables and atlas, environment backgrounds.
pub(crate) fn float_texture(
    gl: &Gl,
    image: FloatImage<'_>,
    sampling: FloatSampling,
    what: &'static str,
) -> Result<glow::Texture> {
    let FloatImage {
        width,
        height,
        channels,
        data,
    } = image;
    let (internal, format) = match channels {
        1 => (glow::R32F, glow::RED),
        3 => (glow::RGB32F, glow::RGB),
        4 => (glow::RGBA32F, glow::RGBA),
        n => return Err(Error::Usage(format!("{what}: {n} channels (1, 3 or 4)"))),
    };
    if data.len() != width * height * channels {
        return Err(Error::Usage(format!(
            "{what}: {} floats for {width} x {height} x {channels}",
            data.len()
        )));
    }
    let g = gl.glow();
    // SAFETY: the context is current on this thread while `gl` lives.
    let max = unsafe { g.get_parameter_i32(glow::MAX_TEXTURE_SIZE) } as usize;
    if width > max || height > max {
        return Err(Error::Usage(format!(
            "{what}: {width} x {height} exceeds GL_MAX_TEXTURE_SIZE = {max} (use a smaller \
             environment)"
        )));
    }
    // SAFETY: as above.
    let texture =
        unsafe { g.create_texture() }.map_err(|e| Gl::creation_error("glCreateTexture", e))?;
    let bytes: Vec<u8> = data.iter().flat_map(|v| v.to_ne_bytes()).collect();
    let (filter, wrap_s) = match sampling {
        FloatSampling::Fetch => (glow::NEAREST, glow::CLAMP_TO_EDGE),
        FloatSampling::Equirectangular => (glow::LINEAR, glow::REPEAT),
    };
    gl.with_texture_2d(texture, || {
        // SAFETY: as above with `texture` bound; `bytes` holds width × height × channels
        // tightly packed f32 (unpack alignment 1), checked above.
        unsafe {
            g.pixel_store_i32(glow::UNPACK_ALIGNMENT, 1);
            g.tex_parameter_i32(glow::TEXTURE_2D, glow::TEXTURE_BASE_LEVEL, 0);
            g.tex_parameter_i32(glow::TEXTURE_2D, glow::TEXTURE_MAX_LEVEL, 0);
            g.tex_parameter_i32(glow::TEXTURE_2D, glow::TEXTURE_MIN_FILTER, filter as i32);
            g.tex_parameter_i32(glow::TEXTURE_2D, glow::TEXTURE_MAG_FILTER, filter as i32);
            g.tex_parameter_i32(glow::TEXTURE_2D, glow::TEXTURE_WRAP_S, wrap_s as i32);
            let clamp = glow::CLAMP_TO_EDGE as i32;
            g.tex_parameter_i32(glow::TEXTURE_2D, glow::TEXTURE_WRAP_T, clamp);
            g.tex_image_2d(
                glow::TEXTURE_2D,
                0,
                internal as i32,
                width as i32,
                height as i32,
                0,
                format,
                glow::FLOAT,
                PixelUnpackData::Slice(Some(&bytes)),
            );
        }
    });
    if let Err(e) = gl.check_error(what) {
        // SAFETY: the texture was created above and is deleted once.
        unsafe { g.delete_texture(texture) };
        return Err(e);
    }
    Ok(texture)
}

/// A tabulated BRDF's table on the GPU ([`ndfmap::brdf::Tabulated::table`]): one `R32F`
/// texture, `GRID` texels wide and `KAPPA_ROWS + 1` high, sampled by the shaders with
/// `texelFetch` (filtering `NEAREST`, no MIP levels) through the sampler `ndf_brdf_table`.
pub struct TableTexture {
    gl: Gl,
    texture: glow::Texture,
}

impl TableTexture {
    /// Uploads `table`'s rows (computing them on first use).
    pub fn upload(gl: &Gl, table: &ndfmap::brdf::Tabulated) -> Result<TableTexture> {
        use ndfmap::brdf::tabulated::{GRID, KAPPA_ROWS};
        let texture = float_texture(
            gl,
            FloatImage {
                width: GRID,
                height: KAPPA_ROWS + 1,
                channels: 1,
                data: table.table(),
            },
            FloatSampling::Fetch,
            "BRDF table upload",
        )?;
        Ok(TableTexture {
            gl: gl.clone(),
            texture,
        })
    }

    /// Binds the table to texture unit `unit` and sets `program`'s `ndf_brdf_table` to it.
    pub fn bind(&self, program: &Program, unit: u32) {
        let g = self.gl.glow();
        // SAFETY: the context is current while `self.gl` lives; the texture is alive while
        // `self` is.
        unsafe {
            g.active_texture(glow::TEXTURE0 + unit);
            g.bind_texture(glow::TEXTURE_2D, Some(self.texture));
            g.active_texture(glow::TEXTURE0);
        }
        program.set_i32("ndf_brdf_table", unit as i32);
    }
}

impl Drop for TableTexture {
    fn drop(&mut self) {
        // SAFETY: the context is current while `self.gl` lives; deleted once.
        unsafe { self.gl.glow().delete_texture(self.texture) };
    }
}
