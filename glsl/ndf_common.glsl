// ndf_common.glsl - shared lobe math of the ndfmap shaders (GLSL 3.30 core).
//
// Every function here has a CPU twin in src/shade.rs (named in its comment) that evaluates the
// same formula in f64 from the same texel values; tests render these shaders and compare.
// Guards follow DESIGN.md "Numerics": no pow(0, 0), no division by a zero determinant, no NaN
// from an empty lobe.

const float NDF_PI = 3.14159265358979;

// The BRDF's parameter, set by the application (it may change every frame: Sec 7.2).
#ifdef NDF_BRDF_TORRANCE_SPARROW
uniform float ndf_sigma;  // eq 18 roughness sigma > 0
#else
uniform float ndf_s;      // Blinn-Phong exponent s > 0 (eq 20)
#endif

// max(x, 0)^y with the CPU's conventions: 0^0 = 1 (an exponent of 0 is a uniform lobe), and
// x <= 0 with y > 0 gives 0. GLSL's pow is undefined at x = 0, y <= 0.
float ndf_pow(float x, float y) {
    if (y <= 0.0) return 1.0;
    if (x <= 0.0) return 0.0;
    return pow(x, y);
}

// Normalized Blinn-Phong lobe (s+1)/(2 pi) max(c, 0)^s, eq 20's form. CPU: shade::blinn_phong.
float ndf_blinn_phong(float cos_h, float s) {
    return (s + 1.0) / (2.0 * NDF_PI) * ndf_pow(cos_h, s);
}

// Orthonormal tangent frame of a unit vector (Duff et al. 2017). CPU: shade::tangent_frame.
void ndf_tangent_frame(vec3 n, out vec3 t1, out vec3 t2) {
    float sgn = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (sgn + n.z);
    float b = n.x * n.y * a;
    t1 = vec3(1.0 + sgn * n.x * n.x * a, sgn * b, -sgn * n.x);
    t2 = vec3(b, sgn + n.y * n.y * a, -n.y);
}

// A symmetric 2x2 matrix (xx, yy, xy) projected onto the positive semi-definite cone by clamping
// its eigenvalues at 0. CPU: shade::psd.
vec3 ndf_psd(vec3 m) {
    float mean = 0.5 * (m.x + m.y);
    float r = sqrt(0.25 * (m.x - m.y) * (m.x - m.y) + m.z * m.z);
    float l1 = max(mean + r, 0.0);
    float l2 = max(mean - r, 0.0);
    if (r < 1e-30) return vec3(l1, l1, 0.0);
    vec2 e = abs(mean + r - m.x) > abs(mean + r - m.y) ? vec2(m.z, mean + r - m.x)
                                                       : vec2(mean + r - m.y, m.z);
    vec2 c = e / length(e);
    return vec3(l1 * c.x * c.x + l2 * c.y * c.y,
                l1 * c.y * c.y + l2 * c.x * c.x,
                (l1 - l2) * c.x * c.y);
}

// Anisotropic Blinn-Phong lobe widened by an NDF covariance sigma = (xx, yy, xy):
// S = (I/s + Sigma)^-1, normalization sqrt(det S + tr S + 1)/(2 pi), exponent the Rayleigh
// quotient of S along the offset d. Sigma = 0 gives (s+1)/(2 pi) c^s. CPU: shade::widened_lobe.
float ndf_widened_lobe(float cos_h, vec2 d, vec3 sigma, float s) {
    float a = sigma.x + 1.0 / s;
    float c = sigma.y + 1.0 / s;
    float b = sigma.z;
    float det = max(a * c - b * b, 1e-30);
    float sxx = c / det;
    float syy = a / det;
    float sxy = -b / det;
    float norm = sqrt(max(sxx * syy - sxy * sxy + sxx + syy + 1.0, 0.0)) / (2.0 * NDF_PI);
    float dd = dot(d, d);
    float e = dd > 1e-30 ? (sxx * d.x * d.x + 2.0 * sxy * d.x * d.y + syy * d.y * d.y) / dd
                         : 0.5 * (sxx + syy);
    return norm * ndf_pow(cos_h, e);
}

// Torrance-Sparrow-like lobe of eq 18 widened by an angular NDF covariance cov (xx, yy, xy) in
// the frame of dir: a 2D Gaussian in the angle offset with covariance 2 sigma^2 I + cov.
// cov = 0 gives exp(-beta^2/(4 sigma^2))/(4 pi sigma^2); cov = I/kappa gives eq 21.
// Zero for cos_h <= 0.
// CPU: shade::torrance_sparrow_lobe.
float ndf_ts_lobe(float cos_h, vec2 dir, float sigma, vec3 cov) {
    if (!(cos_h > 0.0)) return 0.0;
    float beta = acos(min(cos_h, 1.0));
    float v = 2.0 * sigma * sigma;
    float a = v + cov.x;
    float c = v + cov.y;
    float b = cov.z;
    float det = max(a * c - b * b, 1e-30);
    float len = length(dir);
    float q;
    if (len > 1e-30) {
        vec2 d = dir * (beta / len);
        q = (c * d.x * d.x - 2.0 * b * d.x * d.y + a * d.y * d.y) / det;
    } else {
        q = beta * beta * 2.0 / (a + c);
    }
    return exp(-0.5 * q) / (2.0 * NDF_PI * sqrt(det));
}

// One isotropic lobe of weight alpha around mu with per-axis angular variance var under the
// eq 18 BRDF, times the cosine (the Torrance-Sparrow path of every method).
float ndf_ts_iso(float alpha, vec3 mu, float var, vec3 l, vec3 h, float sigma) {
    vec3 t1;
    vec3 t2;
    ndf_tangent_frame(mu, t1, t2);
    vec2 dir = vec2(dot(h, t1), dot(h, t2));
    return alpha * ndf_ts_lobe(dot(mu, h), dir, sigma, vec3(var, var, 0.0)) * max(dot(mu, l), 0.0);
}

// normalize(v), or +Z for a zero or non-finite v (the CPU's try_normalize fallback).
vec3 ndf_normalize_or_z(vec3 v) {
    float len = length(v);
    return (len > 0.0 && len < 1e30) ? v / len : vec3(0.0, 0.0, 1.0);
}

// The MIP level of detail of the GL specification (3.3 core, eq 3.18-3.21) from the screen
// derivatives of uv on a texture of base size `size`: lambda = log2(max(|d(uv*size)/dx|,
// |d(uv*size)/dy|)). Computed here rather than left to texture() so that hardware and manual
// sampling, and the CPU twin (src/sample.rs), use one LOD.
float ndf_lod(vec2 uv, vec2 size) {
    vec2 dx = dFdx(uv) * size;
    vec2 dy = dFdy(uv) * size;
    float rho2 = max(dot(dx, dx), dot(dy, dy));
    return 0.5 * log2(max(rho2, 1e-30));
}
