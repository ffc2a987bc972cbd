// ndf_vertex.glsl - the vertex stage of the ndfmap shaders.
//
// Meshes supply attributes at fixed locations: 0 position, 1 normal, 2 tangent (xyz along +u,
// w = sign of the bitangent cross(normal, tangent), which must point towards decreasing v for
// an image stored top row first at v = 0 with OpenGL-convention (+Y up) normals), 3 uv.
// ndf_model must be a rotation, translation and uniform scale (normals are transformed by its
// upper 3x3). NDF_PROBE draws an attribute-less full-screen triangle instead (draw 3 vertices
// with an empty vertex array bound).

#ifdef NDF_PROBE
void main() {
    vec2 p = vec2((gl_VertexID << 1) & 2, gl_VertexID & 2);
    gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}
#else
layout(location = 0) in vec3 ndf_position;
layout(location = 1) in vec3 ndf_normal;
layout(location = 2) in vec4 ndf_tangent;
layout(location = 3) in vec2 ndf_uv;

uniform mat4 ndf_model;
uniform mat4 ndf_view_proj;

out vec3 ndf_v_position;
out vec3 ndf_v_normal;
out vec4 ndf_v_tangent;
out vec2 ndf_v_uv;

void main() {
    vec4 world = ndf_model * vec4(ndf_position, 1.0);
    mat3 m = mat3(ndf_model);
    ndf_v_position = world.xyz;
    ndf_v_normal = m * ndf_normal;
    ndf_v_tangent = vec4(m * ndf_tangent.xyz, ndf_tangent.w);
    ndf_v_uv = ndf_uv;
    gl_Position = ndf_view_proj * world;
}
#endif
