
// Largest MIP level: ndfmap's chains always end at 1x1 (GL's full chain for the base size).
int ndf_max_level() {
    ivec2 size = textureSize(ndf_tex0, 0);
    return int(floor(log2(float(max(size.x, size.y)))));
}

