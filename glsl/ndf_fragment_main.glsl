#ifdef NDF_PROBE
uniform vec2 ndf_probe_size;   // framebuffer size in pixels: uv = gl_FragCoord.xy / size
#ifdef NDF_ANISO
uniform vec2 ndf_probe_dx;     // screen derivatives of uv (the footprint), anisotropic sampling
uniform vec2 ndf_probe_dy;
#else
uniform float ndf_probe_lod;   // level of detail
#endif
#ifdef NDF_LIGHT_ENV
uniform vec3 ndf_probe_v;      // view direction, tangent frame, unit
uniform mat3 ndf_probe_frame;  // tangent -> environment frame; unset (zero): the identity
#else
uniform vec3 ndf_probe_l;      // light direction, tangent space, unit
uniform vec3 ndf_probe_h;      // half vector, tangent space, unit
#ifdef NDF_LIGHT_BOTH
uniform vec3 ndf_probe_v;      // view direction of the environment term, unit
#endif
#endif
uniform int ndf_probe_channel; // colour channel written (0, 1, 2)

void main() {
    vec3 d;
    vec3 s;
    vec2 uv = gl_FragCoord.xy / ndf_probe_size;
#if defined(NDF_LIGHT_ENV)
    if (determinant(ndf_probe_frame) > 0.5) ndf_env_frame = ndf_probe_frame;
#ifdef NDF_ANISO
    ndf_shade_footprint(uv, ndf_probe_dx, ndf_probe_dy, ndf_probe_v, ndf_probe_v, d, s);
#else
    ndf_shade(uv, ndf_probe_lod, ndf_probe_v, ndf_probe_v, d, s);
#endif
#else
#ifdef NDF_LIGHT_BOTH
    ndf_view = ndf_probe_v;
#endif
#ifdef NDF_ANISO
    ndf_shade_footprint(uv, ndf_probe_dx, ndf_probe_dy, ndf_probe_l, ndf_probe_h, d, s);
#else
    ndf_shade(uv, ndf_probe_lod, ndf_probe_l, ndf_probe_h, d, s);
#ifndef NDF_LIGHT_BOTH
    s *= ndf_g(ndf_probe_l, ndf_probe_h);
#endif
#endif
#endif
    int c = ndf_probe_channel;
    ndf_out = vec4(c == 0 ? d.x : (c == 1 ? d.y : d.z), c == 0 ? s.x : (c == 1 ? s.y : s.z),
                   0.0, 1.0);
}
#else
in vec3 ndf_v_position;  // world space
in vec3 ndf_v_normal;    // world space, geometric
in vec4 ndf_v_tangent;   // world space, along +u; w = sign of the bitangent cross(n, t)
in vec2 ndf_v_uv;

uniform vec3 ndf_camera_pos;   // world space
uniform vec4 ndf_light;        // w = 0: direction towards the light; w = 1: point light position
uniform vec3 ndf_light_color;  // radiance scale (point lights fall off with 1/d^2)
#ifndef NDF_NO_DIFFUSE
uniform vec3 ndf_kd;           // K_d
#endif
uniform vec3 ndf_ks;           // K_s
#if defined(NDF_LIGHT_ENV) || defined(NDF_LIGHT_BOTH)
uniform mat3 ndf_env_rotation; // world -> environment frame (a rotation)
#endif
#ifdef NDF_LIGHT_BOTH
uniform vec3 ndf_env_color;    // the environment's radiance scale (with the point light)
#endif

void main() {
    vec3 n = normalize(ndf_v_normal);
    vec3 tg = normalize(ndf_v_tangent.xyz - n * dot(n, ndf_v_tangent.xyz));
    vec3 bt = (ndf_v_tangent.w < 0.0 ? -1.0 : 1.0) * cross(n, tg);
#ifdef NDF_LIGHT_ENV
    // Lit by the environment: ndf_light_color scales its radiance, ndf_light is unused.
    ndf_env_frame = ndf_env_rotation * mat3(tg, bt, n);
    vec3 vw = normalize(ndf_camera_pos - ndf_v_position);
    vec3 v = vec3(dot(vw, tg), dot(vw, bt), dot(vw, n));
    vec3 d;
    vec3 s;
    ndf_shade_footprint(ndf_v_uv, dFdx(ndf_v_uv), dFdy(ndf_v_uv), v, v, d, s);
#ifdef NDF_NO_DIFFUSE
    ndf_out = vec4(ndf_light_color * ndf_ks * s, 1.0);
#else
    ndf_out = vec4(ndf_light_color * (ndf_kd * d + ndf_ks * s), 1.0);
#endif
#else
    vec3 to_light = ndf_light.w == 0.0 ? ndf_light.xyz : ndf_light.xyz - ndf_v_position;
    float falloff = ndf_light.w == 0.0 ? 1.0 : 1.0 / max(dot(to_light, to_light), 1e-12);
    vec3 lw = normalize(to_light);
    vec3 vw = normalize(ndf_camera_pos - ndf_v_position);
    vec3 l = vec3(dot(lw, tg), dot(lw, bt), dot(lw, n));
    vec3 v = vec3(dot(vw, tg), dot(vw, bt), dot(vw, n));
    vec3 h = ndf_normalize_or_z(l + v);
    vec3 d;
    vec3 s;
#ifdef NDF_LIGHT_BOTH
    ndf_env_frame = ndf_env_rotation * mat3(tg, bt, n);
    ndf_view = v;
    ndf_point_scale = ndf_light_color * falloff;
    ndf_env_scale = ndf_env_color;
    ndf_shade_footprint(ndf_v_uv, dFdx(ndf_v_uv), dFdy(ndf_v_uv), l, h, d, s);
#ifdef NDF_NO_DIFFUSE
    ndf_out = vec4(ndf_ks * s, 1.0);
#else
    ndf_out = vec4(ndf_kd * d + ndf_ks * s, 1.0);
#endif
#else
    ndf_shade_footprint(ndf_v_uv, dFdx(ndf_v_uv), dFdy(ndf_v_uv), l, h, d, s);
#ifdef NDF_NO_DIFFUSE
    ndf_out = vec4(ndf_light_color * falloff * ndf_ks * s, 1.0);
#else
    ndf_out = vec4(ndf_light_color * falloff * (ndf_kd * d + ndf_ks * s), 1.0);
#endif
#endif
#endif
}
#endif
