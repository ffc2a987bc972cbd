// ndf_sh_basis.glsl - real spherical harmonics Y_lm(d), l <= NDF_BASIS_LMAX, in (l, m) order
// (index l*l + l + m), by the normalized Legendre recurrences in Cartesian form (no factorials;
// CPU: harmonics::eval_into).
//
// A template: ndfmap::glsl instantiates it by defining NDF_BASIS_NAME (the function's name) and
// NDF_BASIS_LMAX (its band limit) before this text and undefining both after it - ndf_sh_eval
// (l <= NDF_SH_LMAX, before ndf_sh.glsl) and ndf_env_basis (l <= 8, before ndf_env.glsl) - so
// the SH NDF and the environment lighting evaluate the same recurrence text.

void NDF_BASIS_NAME(vec3 d, out float y[(NDF_BASIS_LMAX + 1) * (NDF_BASIS_LMAX + 1)]) {
    d = ndf_normalize_or_z(d);
    float c = 1.0;
    float s = 0.0;
    float pmm = 0.28209479177387814;  // 1 / sqrt(4 pi)
    for (int m = 0; m <= NDF_BASIS_LMAX; ++m) {
        if (m > 0) {
            pmm *= sqrt(float(2 * m + 1) / float(2 * m));
            float cn = d.x * c - d.y * s;
            s = d.x * s + d.y * c;
            c = cn;
        }
        float mf = float(m);
        float p0 = pmm;
        float p1 = 0.0;
        for (int l = m; l <= NDF_BASIS_LMAX; ++l) {
            float p;
            if (l == m) {
                p = pmm;
            } else if (l == m + 1) {
                p = sqrt(2.0 * mf + 3.0) * d.z * pmm;
                p1 = p;
            } else {
                float lf = float(l);
                float a = sqrt((4.0 * lf * lf - 1.0) / (lf * lf - mf * mf));
                float b = sqrt(((lf - 1.0) * (lf - 1.0) - mf * mf) /
                               (4.0 * (lf - 1.0) * (lf - 1.0) - 1.0));
                p = a * (d.z * p1 - b * p0);
                p0 = p1;
                p1 = p;
            }
            int centre = l * l + l;
            if (m == 0) {
                y[centre] = p;
            } else {
                y[centre + m] = 1.4142135623730951 * p * c;
                y[centre - m] = 1.4142135623730951 * p * s;
            }
        }
    }
}
