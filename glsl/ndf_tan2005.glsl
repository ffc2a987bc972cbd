// ndf_tan2005.glsl - Tan et al. 2005 planar Gaussian mixture (the paper's comparison row).
//
// Texture j < NDF_LOBES holds component j as (a, a*mu.x, a*mu.y, a*(sigma^2 + |mu|^2)) with
// a = alpha, which filters linearly (Tan's Appendix); with NDF_COLOR, texture NDF_LOBES + j
// holds alpha*y. Per component (CPU twin: tan2005::shade_gaussian):
//   mu = (a*mu)/a, sigma^2 = max(0, a*(sigma^2 + |mu|^2)/a - |mu|^2),
//   lifted to the sphere mu3 = (mu, sqrt(1 - |mu|^2)) with mu clamped to the unit disk;
//   Blinn-Phong: s' = s/(1 + s sigma^2); the other BRDFs widen by var = sigma^2 (ndf_iso_lobe).
// alpha <= 0 contributes nothing.

vec3 ndf_tan_lift(vec2 m) {
    float len2 = dot(m, m);
    if (len2 > 1.0) {
        m = m / max(abs(m.x), abs(m.y));
        m = m / length(m);
        len2 = dot(m, m);
    }
    return vec3(m, sqrt(max(1.0 - len2, 0.0)));
}

// Component c decoded (CPU: tan2005::Gaussian::from_texel): its weight, lifted mean and
// variance; false for an empty (or non-finite) weight.
bool ndf_tan_decode(vec4 c, out float alpha, out vec3 mu, out float var) {
    alpha = c.x;
    mu = vec3(0.0, 0.0, 1.0);
    var = 0.0;
    if (!(alpha > 0.0 && alpha < 1e30)) return false;
    vec2 mean = c.yz / alpha;
    var = c.w / alpha - dot(mean, mean);
    var = var > 0.0 && var < 1e30 ? var : 0.0;
    mu = ndf_tan_lift(mean);
    return true;
}

void ndf_shade_texel(vec4 t[NDF_TEXTURES], vec3 l, vec3 h, out vec3 diffuse, out vec3 specular) {
    diffuse = vec3(0.0);
    specular = vec3(0.0);
    for (int j = 0; j < NDF_LOBES; ++j) {
        float alpha;
        vec3 mu;
        float var;
        if (!ndf_tan_decode(t[j], alpha, mu, var)) continue;
#ifdef NDF_COLOR
        vec3 weight = t[NDF_LOBES + j].rgb;
#else
        vec3 weight = vec3(alpha);
#endif
        float cos_i = max(dot(mu, l), 0.0);
        float lobe = ndf_iso_lobe(mu, var, h) * cos_i;
#ifndef NDF_NO_DIFFUSE
        diffuse += weight * cos_i;
#endif
        specular += weight * lobe;
    }
}
