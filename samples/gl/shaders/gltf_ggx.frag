// gltf_ggx.frag - a plain glTF metallic-roughness GGX shader, written the way an engine writes
// one (Filament, the glTF sample viewer, three.js): it samples the normal texture and the
// metallic-roughness texture with ordinary hardware trilinear filtering and shades one GGX lobe.
// It contains no ndfmap shader code: a PBR bake (`ndfmap bake --method pbr`) is made for
// shaders like this one, and the viewer and the regression renders draw PBR bakes with it.
//
// Textures (ndfmap's PBR layout, glTF's channels):
//   ndf_tex0  normal: xyz the tangent-space normal (signed values, float or unorm-biased);
//   ndf_tex1  metallic_roughness: R occlusion, G perceptual roughness sqrt(alpha), B metallic;
//   ndf_tex2  anisotropy (PBR_ANISOTROPY, KHR_materials_anisotropy): RG the direction
//             (cos phi, sin phi) in tangent space, B the strength; alpha_t = mix(alpha, 1, s^2).
// Shading, per light: diffuse (1 - metallic) max(n.l, 0); specular D(h) max(n.l, 0) times
// F(l.h) V(n.l, n.v; alpha) (Schlick with F0 = mix(ndf_f0, 1, metallic), Smith height-correlated)
// when PBR_G is defined. Occlusion applies to indirect light only in glTF; with one direct
// light it is not used. CPU twin of the lobe: ndfmap::pbr::shade.
//
// PBR_PROBE replaces the mesh inputs by uniforms (uv from gl_FragCoord, a given LOD, light and
// half vector in tangent space) and writes (diffuse, specular without F V): what the GL-versus-CPU
// test compares texel by texel.

layout(location = 0) out vec4 frag_color;

uniform sampler2D ndf_tex0;
uniform sampler2D ndf_tex1;
#ifdef PBR_ANISOTROPY
uniform sampler2D ndf_tex2;
#endif
#ifdef PBR_UNORM
// Unsigned-normalized textures store signed channels as 0.5 + 0.5 v.
#define PBR_SIGNED(v) ((v) * 2.0 - 1.0)
#else
#define PBR_SIGNED(v) (v)
#endif

const float PI = 3.14159265358979;
const float MIN_ALPHA = 1e-3; // ndfmap::pbr::MIN_ALPHA

// GGX / Trowbridge-Reitz, isotropic: alpha^2 / (pi ((1 - c)(1 + c) + c^2 alpha^2)^2).
float d_ggx(float c, float a) {
    if (!(c > 0.0)) return 0.0;
    c = min(c, 1.0);
    float a2 = a * a;
    float d = (1.0 - c) * (1.0 + c) + c * c * a2;
    return d > 0.0 ? a2 / (PI * d * d) : 0.0;
}

// GGX, anisotropic: 1 / (pi at ab ((h.t/at)^2 + (h.b/ab)^2 + (h.n)^2)^2).
float d_ggx_aniso(vec3 h, vec3 n, vec3 t, vec3 b, float at, float ab) {
    float z = dot(n, h);
    if (!(z > 0.0)) return 0.0;
    float x = dot(h, t) / at;
    float y = dot(h, b) / ab;
    float q = x * x + y * y + z * z;
    return 1.0 / (PI * at * ab * q * q);
}

// Smith's height-correlated visibility G2 / (4 n.l n.v) (Heitz 2014).
float v_smith(float nl, float nv, float a) {
    if (!(nl > 0.0 && nv > 0.0)) return 0.0;
    float a2 = a * a;
    float gv = nl * sqrt(nv * nv * (1.0 - a2) + a2);
    float gl = nv * sqrt(nl * nl * (1.0 - a2) + a2);
    return 0.5 / (gv + gl);
}

float f_schlick(float cd, float f0) {
    float m = 1.0 - clamp(cd, 0.0, 1.0);
    return f0 + (1.0 - f0) * m * m * m * m * m;
}

// A material read from the textures at uv: normal, roughness, metallic, anisotropy.
struct Material {
    vec3 n;
    float alpha;
    float metallic;
    float strength;
    vec2 direction;
};

Material read_material(vec4 t0, vec4 t1, vec4 t2) {
    Material m;
    vec3 n = PBR_SIGNED(t0.xyz);
    float len2 = dot(n, n);
    m.n = len2 > 0.0 ? n * inversesqrt(len2) : vec3(0.0, 0.0, 1.0);
    m.alpha = clamp(t1.g * t1.g, MIN_ALPHA, 1.0);
    m.metallic = t1.b;
    m.strength = clamp(t2.b, 0.0, 1.0);
    m.direction = PBR_SIGNED(t2.rg);
    return m;
}

// The lobe D(h) of material m (KHR_materials_anisotropy's frame when the strength is > 0).
float lobe(Material m, vec3 h) {
#ifdef PBR_ANISOTROPY
    if (m.strength > 0.0) {
        float at = m.alpha + (1.0 - m.alpha) * m.strength * m.strength;
        float phi = atan(m.direction.y, m.direction.x);
        vec3 d = vec3(cos(phi), sin(phi), 0.0);
        vec3 t = d - m.n * dot(m.n, d);
        if (dot(t, t) > 0.0) {
            t = normalize(t);
        } else {
            // Branchless orthonormal basis (Duff et al. 2017), as ndfmap::brdf::tangent_frame.
            float s = m.n.z >= 0.0 ? 1.0 : -1.0;
            float a = -1.0 / (s + m.n.z);
            t = vec3(1.0 + s * m.n.x * m.n.x * a, s * m.n.x * m.n.y * a, -s * m.n.x);
        }
        return d_ggx_aniso(h, m.n, t, cross(m.n, t), at, m.alpha);
    }
#endif
    return d_ggx(dot(m.n, h), m.alpha);
}

#ifdef PBR_PROBE
uniform vec2 pbr_probe_size;  // framebuffer size: uv = gl_FragCoord.xy / size
uniform float pbr_probe_lod;  // level of detail
uniform vec3 pbr_probe_l;     // light, tangent space, unit
uniform vec3 pbr_probe_h;     // half vector, tangent space, unit
void main() {
    vec2 uv = gl_FragCoord.xy / pbr_probe_size;
    vec4 t2 = vec4(1.0, 0.0, 0.0, 0.0);
#ifdef PBR_ANISOTROPY
    t2 = textureLod(ndf_tex2, uv, pbr_probe_lod);
#endif
    Material m = read_material(textureLod(ndf_tex0, uv, pbr_probe_lod),
                               textureLod(ndf_tex1, uv, pbr_probe_lod), t2);
    float nl = max(dot(m.n, pbr_probe_l), 0.0);
    frag_color = vec4(nl, lobe(m, pbr_probe_h) * nl, 0.0, 1.0);
}
#else
in vec3 v_position;
in vec3 v_normal;
in vec4 v_tangent;
in vec2 v_uv;

uniform vec3 ndf_camera_pos;   // world space
uniform vec4 ndf_light;        // w = 0: direction towards the light; w = 1: point light position
uniform vec3 ndf_light_color;  // radiance scale (point lights fall off with 1/d^2)
uniform vec3 ndf_kd;           // diffuse scale
uniform vec3 ndf_ks;           // specular scale
uniform float ndf_f0;          // dielectric F0 (0.04)

void main() {
    vec3 ng = normalize(v_normal);
    vec3 tg = normalize(v_tangent.xyz - ng * dot(ng, v_tangent.xyz));
    vec3 bt = (v_tangent.w < 0.0 ? -1.0 : 1.0) * cross(ng, tg);
    vec3 to_light = ndf_light.w == 0.0 ? ndf_light.xyz : ndf_light.xyz - v_position;
    float falloff = ndf_light.w == 0.0 ? 1.0 : 1.0 / max(dot(to_light, to_light), 1e-12);
    vec3 lw = normalize(to_light);
    vec3 vw = normalize(ndf_camera_pos - v_position);
    vec3 l = vec3(dot(lw, tg), dot(lw, bt), dot(lw, ng));
    vec3 v = vec3(dot(vw, tg), dot(vw, bt), dot(vw, ng));
    vec3 h = l + v;
    h = dot(h, h) > 0.0 ? normalize(h) : vec3(0.0, 0.0, 1.0);
    vec4 t2 = vec4(1.0, 0.0, 0.0, 0.0);
#ifdef PBR_ANISOTROPY
    t2 = texture(ndf_tex2, v_uv);
#endif
    Material m = read_material(texture(ndf_tex0, v_uv), texture(ndf_tex1, v_uv), t2);
    float nl = max(dot(m.n, l), 0.0);
    float specular = lobe(m, h) * nl;
#ifdef PBR_G
    float f0 = mix(ndf_f0, 1.0, m.metallic);
    specular *= f_schlick(dot(l, h), f0) * v_smith(nl, max(dot(m.n, v), 0.0), m.alpha);
#endif
    float diffuse = (1.0 - m.metallic) * nl;
    frag_color = vec4(ndf_light_color * falloff * (ndf_kd * diffuse + ndf_ks * specular), 1.0);
}
#endif
