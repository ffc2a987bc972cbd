// ndf_fragment.glsl - the fragment stage: light and view in the tangent frame, the level of
// detail, texture sampling (hardware trilinear or manual 8-texel), and the method's shading
// (ndf_shade_texel, from the method file included before this one).
//
// Sampling (Han et al. 2007, Sec 7.3):
//   hardware (default): one trilinear fetch per texture, then one shading - exact for aligned
//     lobes and for the baselines' linear moments;
//   NDF_MANUAL: shade the 4 texels around uv on each of the two nearest levels and blend the
//     results with the trilinear weights - what unaligned lobes need.
//   NDF_ANISO (= the most probes): the anisotropic footprint of GL_EXT_texture_filter_anisotropic's
//     reference rule, done in the shader: N = min(ceil(Pmax/Pmin), NDF_ANISO) trilinear probes at
//     LOD log2(Pmax/N) along the major axis of the pixel's footprint, averaged, then one shading
//     (exact for parameters that filter linearly: SH, aligned lobes, the baselines' moments).
// All use the LOD of ndf_lod() (GL's formula) and GL's LINEAR_MIPMAP_LINEAR rules, so the CPU
// twin (src/sample.rs) can reproduce each bit for bit up to f32 rounding. The BRDF's g factor
// (ndf_g) multiplies the specular term after filtering (it does not depend on the texel).
//
// NDF_PROBE replaces the mesh inputs by uniforms (uv from gl_FragCoord, given LOD, light and half
// vector in tangent space) and writes (diffuse, specular) of one colour channel: what the
// GL-versus-CPU tests compare texel by texel.

layout(location = 0) out vec4 ndf_out;
