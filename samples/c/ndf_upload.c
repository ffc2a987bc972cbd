/*
 * ndfmap C sample: load a normal map, bake the paper's vMF lobes, pack them as half floats and
 * show what an engine uploads with glTexImage2D, lobe by lobe and level by level.
 *
 *   cargo build --release                 # at the top of ndfmap: libndfmap.so and .a
 *   make -C samples/c                     # builds ./ndf_upload against them
 *   samples/c/ndf_upload my_normal_map.png
 *
 * Without an argument it bakes a small generated map. Copy this file into an engine and replace
 * the printf of upload() by the real glTexImage2D call; the GL calls are in the comments.
 */
#include "ndfmap.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>

/* Prints the status, its name and the library's explanation, and exits. */
static void check(ndf_status status, const char *what) {
    if (status != NDF_STATUS_OK) {
        fprintf(stderr, "%s failed: %s: %s\n", what, ndf_status_str(status),
                ndf_last_error_message());
        exit(1);
    }
}

/* Progress of the bake: a real application might update a progress bar, and return 0 to cancel
 * (the bake then fails with NDF_STATUS_CANCELLED). */
static int progress(float fraction, void *user_data) {
    int *last_tenth = (int *)user_data;
    int tenth = (int)(fraction * 10.0f);
    if (tenth > *last_tenth) {
        *last_tenth = tenth;
        fprintf(stderr, "baking: %d%%\n", tenth * 10);
    }
    return 1;
}

/* A 64x64 map of round bumps, for running the sample without a file. */
static ndf_normal_map *generated_map(void) {
    enum { N = 64 };
    static float xyz[N * N * 3];
    ndf_ingest_options options = ndf_ingest_options_default();
    ndf_normal_map *map = NULL;
    int x, y;
    for (y = 0; y < N; y++) {
        for (x = 0; x < N; x++) {
            float *n = xyz + 3 * (y * N + x);
            n[0] = 0.6f * sinf(0.5f * (float)x) * cosf(0.3f * (float)y);
            n[1] = 0.6f * cosf(0.4f * (float)x + 0.2f * (float)y);
            n[2] = 1.0f; /* ndfmap renormalizes */
        }
    }
    /* Float samples are signed by default (NDF_ENCODING_AUTO): the components themselves. */
    check(ndf_normal_map_from_pixels(xyz, sizeof xyz, N, N, 3, NDF_SAMPLE_FLOAT32, &options, &map),
          "ndf_normal_map_from_pixels");
    return map;
}

int main(int argc, char **argv) {
    ndf_ingest_options ingest = ndf_ingest_options_default();
    ndf_vmf_options vmf = ndf_vmf_options_default();
    ndf_normal_map *map = NULL;
    ndf_bake *bake = NULL;
    uint32_t lobes, levels, lobe, level;
    int last_tenth = -1;
    size_t capacity = 0;
    unsigned char *texels = NULL;

    if (argc > 1) {
        /* Tangent-space convention of the file: OpenGL (+Y) green, unsigned-normalized. */
        ingest.green = NDF_GREEN_OPENGL;
        check(ndf_normal_map_load_file(argv[1], &ingest, &map), "ndf_normal_map_load_file");
    } else {
        map = generated_map();
    }

    /* Four aligned lobes: coherent across texels, so the GPU may filter them trilinearly. */
    vmf.lobes = 4;
    vmf.aligned = 1;
    vmf.progress = progress;
    vmf.progress_user_data = &last_tenth;
    check(ndf_bake_vmf(map, &vmf, &bake), "ndf_bake_vmf");
    ndf_normal_map_free(map);

    check(ndf_bake_lobe_count(bake, &lobes), "ndf_bake_lobe_count");
    check(ndf_bake_level_count(bake, &levels), "ndf_bake_level_count");
    printf("// %u vMF lobes, %u MIP levels; per lobe one RGBA16F texture (alpha, alpha*r)\n",
           (unsigned)lobes, (unsigned)levels);
    for (lobe = 0; lobe < lobes; lobe++) {
        const char *name;
        check(ndf_bake_texture_name(bake, lobe, &name), "ndf_bake_texture_name");
        printf("// glBindTexture(GL_TEXTURE_2D, texture[%u]);  /* sampler ndf_tex%u: %s */\n",
               (unsigned)lobe, (unsigned)lobe, name);
        for (level = 0; level < levels; level++) {
            uint32_t width, height;
            size_t size, written;
            check(ndf_bake_level_size(bake, level, &width, &height), "ndf_bake_level_size");
            check(ndf_bake_packed_size(bake, lobe, level, NDF_FORMAT_RGBA_F16, &size),
                  "ndf_bake_packed_size");
            if (size > capacity) {
                free(texels);
                texels = (unsigned char *)malloc(size);
                capacity = size;
                if (texels == NULL) {
                    fprintf(stderr, "out of memory\n");
                    return 1;
                }
            }
            check(ndf_bake_pack(bake, lobe, level, NDF_FORMAT_RGBA_F16, texels, capacity,
                                &written),
                  "ndf_bake_pack");
            printf("glTexImage2D(GL_TEXTURE_2D, %u, GL_RGBA16F, %u, %u, 0, GL_RGBA, "
                   "GL_HALF_FLOAT, texels);  /* %lu bytes */\n",
                   (unsigned)level, (unsigned)width, (unsigned)height, (unsigned long)written);
        }
        printf("// glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, "
               "GL_LINEAR_MIPMAP_LINEAR); GL_TEXTURE_WRAP_S/T: GL_REPEAT\n");
    }
    free(texels);

    /* The matching fragment shader, specialized for this bake and half-float textures. */
    {
        ndf_shader_options shader = ndf_shader_options_default();
        size_t size, written;
        char *source;
        shader.format = NDF_FORMAT_RGBA_F16;
        check(ndf_bake_shader_source_size(bake, NDF_SHADER_STAGE_FRAGMENT, &shader, &size),
              "ndf_bake_shader_source_size");
        source = (char *)malloc(size);
        if (source == NULL) {
            fprintf(stderr, "out of memory\n");
            return 1;
        }
        check(ndf_bake_shader_source(bake, NDF_SHADER_STAGE_FRAGMENT, &shader, source, size,
                                     &written),
              "ndf_bake_shader_source");
        printf("// glShaderSource(fragment, 1, &source, NULL);  /* %lu bytes of GLSL 3.30 */\n",
               (unsigned long)(written - 1));
        free(source);
    }
    ndf_bake_free(bake);
    return 0;
}
