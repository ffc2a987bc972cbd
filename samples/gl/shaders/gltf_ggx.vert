// gltf_ggx.vert - the vertex stage of the plain glTF metallic-roughness shader (gltf_ggx.frag):
// world-space position, normal and tangent, and the texture coordinate. No ndfmap code; the
// attribute and uniform names are the ndfmap-gl runtime's conventions (see its lib.rs).

#ifdef PBR_PROBE
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

out vec3 v_position;
out vec3 v_normal;
out vec4 v_tangent;
out vec2 v_uv;

void main() {
    vec4 world = ndf_model * vec4(ndf_position, 1.0);
    mat3 m = mat3(ndf_model);
    v_position = world.xyz;
    v_normal = m * ndf_normal;
    v_tangent = vec4(m * ndf_tangent.xyz, ndf_tangent.w);
    v_uv = ndf_uv;
    gl_Position = ndf_view_proj * world;
}
#endif
