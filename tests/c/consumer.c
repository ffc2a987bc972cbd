/*
 * C consumer of include/ndfmap.h, run by tests/c_api.rs (linked once against libndfmap.so and
 * once against libndfmap.a, and under valgrind when it is installed).
 *
 * It builds a 16x16 normal map from pixels in memory, bakes every method (SH at the default
 * band limit), packs every level of every texture in every format, gets the vMF shader sources,
 * checks materials (Lambert's SH coefficients, a tabulated BRDF's table), and prints one line per query,
 * per packed level and per shader (a 64-bit FNV-1a hash of the bytes); the Rust test computes the same lines with the Rust API and
 * compares. It also exercises bad input from C (NULLs, a buffer one byte short, unknown enum
 * values, indices out of range, a cancelled bake, free(NULL)) and exits non-zero at the first
 * unexpected status.
 *
 * Usage: consumer OUTPUT_DIR PNG_FILE  (PNG_FILE holds the same pixels as an image file)
 */
#include "ndfmap.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define SIZE 16

static int failures = 0;

/* Checks that `got` is `want`; on a failure also that the message names `function`. */
static void expect(ndf_status got, ndf_status want, const char *what) {
    if (got != want) {
        fprintf(stderr, "FAIL %s: got %s, want %s (%s)\n", what, ndf_status_str(got),
                ndf_status_str(want), ndf_last_error_message());
        failures++;
    } else if (want != NDF_STATUS_OK && strstr(ndf_last_error_message(), "ndf_") == NULL) {
        fprintf(stderr, "FAIL %s: message '%s' does not name the function\n", what,
                ndf_last_error_message());
        failures++;
    }
}

static uint64_t fnv1a(const unsigned char *bytes, size_t length) {
    uint64_t h = 14695981039346656037ull;
    size_t i;
    for (i = 0; i < length; i++) {
        h ^= bytes[i];
        h *= 1099511628211ull;
    }
    return h;
}

/* The test map: integer formulas, so that Rust builds exactly the same pixels. */
static void make_pixels(unsigned char *rgb) {
    int x, y;
    for (y = 0; y < SIZE; y++) {
        for (x = 0; x < SIZE; x++) {
            unsigned char *p = rgb + 3 * (y * SIZE + x);
            p[0] = (unsigned char)((x * 37 + y * 11) % 256);
            p[1] = (unsigned char)((x * 13 + y * 29 + 64) % 256);
            p[2] = (unsigned char)(200 + (x + y) % 56);
        }
    }
}

static const char *method_names[] = {"plain", "toksvig", "lean", "olano", "tan2005", "vmf", "sh",
                                     "pbr"};
static const char *format_names[] = {"f32", "f16", "unorm16", "unorm8"};

/* Prints the bake's description and every packed level in every format. */
static void describe(const ndf_bake *bake) {
    ndf_method method;
    uint32_t lobes, levels, textures, t, k, c;
    ndf_format f;
    expect(ndf_bake_method(bake, &method), NDF_STATUS_OK, "method");
    expect(ndf_bake_lobe_count(bake, &lobes), NDF_STATUS_OK, "lobe count");
    expect(ndf_bake_level_count(bake, &levels), NDF_STATUS_OK, "level count");
    expect(ndf_bake_texture_count(bake, &textures), NDF_STATUS_OK, "texture count");
    printf("bake %s lobes %u levels %u textures %u\n", method_names[method], (unsigned)lobes,
           (unsigned)levels, (unsigned)textures);
    for (k = 0; k < levels; k++) {
        uint32_t w, h;
        expect(ndf_bake_level_size(bake, k, &w, &h), NDF_STATUS_OK, "level size");
        printf("level %u %ux%u\n", (unsigned)k, (unsigned)w, (unsigned)h);
    }
    for (t = 0; t < textures; t++) {
        const char *name;
        expect(ndf_bake_texture_name(bake, t, &name), NDF_STATUS_OK, "texture name");
        printf("texture %u %s", (unsigned)t, name);
        for (c = 0; c < 4; c++) {
            const char *meaning;
            ndf_value_range range;
            expect(ndf_bake_texture_channel(bake, t, c, &meaning, &range), NDF_STATUS_OK,
                   "texture channel");
            printf(" %s:%u", meaning, (unsigned)range);
        }
        printf("\n");
        for (k = 0; k < levels; k++) {
            for (f = NDF_FORMAT_RGBA_F32; f <= NDF_FORMAT_RGBA_UNORM8; f++) {
                size_t size = 0, written = 0;
                unsigned char *buffer;
                ndf_status s = ndf_bake_packed_size(bake, t, k, f, &size);
                if (s == NDF_STATUS_UNSUPPORTED_FORMAT) {
                    printf("pack %u %u %s unsupported\n", (unsigned)t, (unsigned)k,
                           format_names[f]);
                    continue;
                }
                expect(s, NDF_STATUS_OK, "packed size");
                /* One byte too small: refused, nothing written. */
                buffer = (unsigned char *)malloc(size);
                memset(buffer, 0xab, size);
                expect(ndf_bake_pack(bake, t, k, f, buffer, size - 1, &written),
                       NDF_STATUS_BUFFER_TOO_SMALL, "pack one byte short");
                if (written != 0 || buffer[0] != 0xab || buffer[size - 1] != 0xab) {
                    fprintf(stderr, "FAIL pack one byte short wrote\n");
                    failures++;
                }
                expect(ndf_bake_pack(bake, t, k, f, buffer, size, &written), NDF_STATUS_OK,
                       "pack");
                printf("pack %u %u %s %lu %016llx\n", (unsigned)t, (unsigned)k, format_names[f],
                       (unsigned long)written, (unsigned long long)fnv1a(buffer, written));
                free(buffer);
            }
        }
    }
}

/* Prints the size and hash of both shader stages of `bake`, for f16 textures. */
static void shaders(const ndf_bake *bake) {
    ndf_shader_options so = ndf_shader_options_default();
    ndf_shader_stage stage;
    so.format = NDF_FORMAT_RGBA_F16;
    for (stage = NDF_SHADER_STAGE_VERTEX; stage <= NDF_SHADER_STAGE_FRAGMENT; stage++) {
        size_t size = 0, written = 0;
        char *source;
        expect(ndf_bake_shader_source_size(bake, stage, &so, &size), NDF_STATUS_OK, "shader size");
        source = (char *)malloc(size);
        expect(ndf_bake_shader_source(bake, stage, &so, source, size - 1, &written),
               NDF_STATUS_BUFFER_TOO_SMALL, "shader one byte short");
        expect(ndf_bake_shader_source(bake, stage, &so, source, size, &written), NDF_STATUS_OK,
               "shader");
        if (written != size || strlen(source) + 1 != size) {
            fprintf(stderr, "FAIL shader length\n");
            failures++;
        }
        printf("shader %u %lu %016llx\n", (unsigned)stage, (unsigned long)written,
               (unsigned long long)fnv1a((const unsigned char *)source, written));
        free(source);
    }
}

/* Environment lighting (issue 16): a constant coloured environment from RGB floats (R, G, B =
 * 2, 1, 0.5), whose SH, atlas and L' table are known in closed form per channel (L_00 =
 * sqrt(4 pi) L, every prefiltered texel L, L'_00 = sqrt(4 pi) L; RGB interleaved), the energy
 * table, errors, and the environment-lit shaders of the vMF and the SH bake. No output lines:
 * checked here. */
static const float env_colour[3] = {2.0f, 1.0f, 0.5f};

/* The fragment shader of `bake` lit by `light` (with its colour textures when `color`):
 * checks the status and that every string of `want` (NULL-terminated) is in the source. */
static void env_shader(const ndf_bake *bake, ndf_light light, uint32_t color,
                       const char *const *want, const char *what) {
    ndf_shader_options so = ndf_shader_options_default();
    size_t size = 0, written = 0;
    char *source;
    so.light = light;
    so.color = color;
    expect(ndf_bake_shader_source_size(bake, NDF_SHADER_STAGE_FRAGMENT, &so, &size), NDF_STATUS_OK,
           what);
    if (size == 0) {
        return;
    }
    source = (char *)malloc(size);
    expect(ndf_bake_shader_source(bake, NDF_SHADER_STAGE_FRAGMENT, &so, source, size, &written),
           NDF_STATUS_OK, what);
    for (; *want != NULL; want++) {
        if (strstr(source, *want) == NULL) {
            fprintf(stderr, "FAIL %s: no \"%s\"\n", what, *want);
            failures++;
        }
    }
    free(source);
}

static void environments(const ndf_bake *vmf, const ndf_bake *sh_bake) {
    enum { EW = 32, EH = 16 };
    static float rgb[EW * EH * 3];
    ndf_env_options eo = ndf_env_options_default();
    ndf_environment *env = NULL;
    ndf_environment_info info;
    float sh[243];
    float *atlas, *table, *energy;
    uint32_t *levels;
    size_t i, n, c;
    ndf_shader_options so = ndf_shader_options_default();
    size_t size = 0;
    const double root4pi = sqrt(4.0 * 3.14159265358979);
    static const char *const vmf_wants[] = {"#define NDF_LIGHT_ENV_SH 1", "#define NDF_METHOD_VMF",
                                            "uniform vec3 ndf_env_sh[", NULL};
    static const char *const sh_wants[] = {"#define NDF_LIGHT_ENV_SH 1", "#define NDF_METHOD_SH",
                                           "const float NDF_ENV_X90[", "ndf_env_sh_texel(",
                                           "uniform vec3 ndf_env_sh[", NULL};
    for (i = 0; i < EW * EH * 3; i++) {
        rgb[i] = env_colour[i % 3];
    }
    expect(ndf_environment_from_rgb(EW, EH, rgb, &eo, &env), NDF_STATUS_OK, "env from rgb");
    if (env == NULL) {
        return;
    }
    expect(ndf_environment_info_get(env, &info), NDF_STATUS_OK, "env info");
    expect(ndf_environment_sh(env, sh, 242), NDF_STATUS_BUFFER_TOO_SMALL, "env sh short");
    expect(ndf_environment_sh(env, sh, 243), NDF_STATUS_OK, "env sh");
    if (info.sh_count != 243 || info.channels != 3 || info.width != EW) {
        fprintf(stderr, "FAIL env info %u %u\n", (unsigned)info.sh_count, (unsigned)info.channels);
        failures++;
    }
    for (c = 0; c < 3; c++) {
        if (fabs(sh[c] - env_colour[c] * root4pi) > 1e-4) {
            fprintf(stderr, "FAIL env sh channel %lu: %g\n", (unsigned long)c, sh[c]);
            failures++;
        }
    }
    /* l > 0 vanish up to the projection's 2x2 sub-samples per texel, which on this coarse
     * 32 x 16 grid (11-degree texels) leave about 0.012 L in the zonal even bands (0.3 % of L_00;
     * below 1e-4 from 64 x 32 on, src/environment/projection.rs). */
    for (i = 3; i < 243; i++) {
        if (fabs(sh[i]) > 0.015 * env_colour[i % 3]) {
            fprintf(stderr, "FAIL env sh[%lu] = %g\n", (unsigned long)i, sh[i]);
            failures++;
        }
    }
    n = (size_t)info.atlas_width * info.atlas_height * info.channels;
    atlas = (float *)malloc(n * sizeof(float));
    levels = (uint32_t *)malloc(4 * info.level_count * sizeof(uint32_t));
    expect(ndf_environment_prefiltered(env, atlas, n, levels, 4 * info.level_count), NDF_STATUS_OK,
           "env prefiltered");
    expect(ndf_environment_prefiltered(env, NULL, n, levels, 4 * info.level_count),
           NDF_STATUS_NULL_ARGUMENT, "env prefiltered NULL");
    expect(ndf_environment_prefiltered(env, atlas, n, levels, 4 * info.level_count - 1),
           NDF_STATUS_BUFFER_TOO_SMALL, "env prefiltered short table");
    /* Level k >= 1 has kappa1 / 2^(k-1); level 1 is on the panorama's own grid. */
    if (info.level_count < 2 || !(info.kappa1 > 0.0 && info.kappa1 < info.kappa0) ||
        levels[4] != EW || levels[5] != EH) {
        fprintf(stderr, "FAIL env levels %u kappa %g %g\n", (unsigned)info.level_count,
                info.kappa0, info.kappa1);
        failures++;
    }
    for (i = 0; i < info.level_count; i++) {
        /* Each level is a width x height rectangle at (first column, first row) of the atlas. */
        const uint32_t *l = levels + 4 * i;
        uint32_t x, y;
        if (l[3] + l[0] > info.atlas_width || l[2] + l[1] > info.atlas_height) {
            fprintf(stderr, "FAIL env level %lu outside the atlas\n", (unsigned long)i);
            failures++;
            continue;
        }
        for (y = 0; y < l[1]; y++) {
            for (x = 0; x < l[0]; x++) {
                size_t at = ((size_t)(l[2] + y) * info.atlas_width + l[3] + x) * 3;
                int bad = 0;
                for (c = 0; c < 3; c++) {
                    bad |= fabs(atlas[at + c] - env_colour[c]) > 1e-4 * env_colour[c];
                }
                if (bad) {
                    fprintf(stderr, "FAIL env level %lu texel %g %g %g\n", (unsigned long)i,
                            atlas[at], atlas[at + 1], atlas[at + 2]);
                    failures++;
                    y = l[1];
                    break;
                }
            }
        }
    }
    n = (size_t)info.reflected_columns * info.reflected_rows * info.channels;
    table = (float *)malloc(n * sizeof(float));
    expect(ndf_environment_reflected(env, table, n - 1), NDF_STATUS_BUFFER_TOO_SMALL,
           "env reflected short");
    expect(ndf_environment_reflected(env, table, n), NDF_STATUS_OK, "env reflected");
    for (i = 0; i < info.reflected_rows; i++) {
        const float *row = table + i * info.reflected_columns * 3;
        for (c = 0; c < 3; c++) {
            if (fabs(row[c] - env_colour[c] * root4pi) > 5e-4 * env_colour[c] * root4pi) {
                fprintf(stderr, "FAIL env L'00 row %lu channel %lu: %g\n", (unsigned long)i,
                        (unsigned long)c, row[c]);
                failures++;
                i = info.reflected_rows;
                break;
            }
        }
    }
    energy = (float *)malloc((size_t)4 * info.energy_columns * info.energy_rows * sizeof(float));
    expect(ndf_environment_energy(env, NDF_BRDF_GGX, energy,
                                  (size_t)4 * info.energy_columns * info.energy_rows),
           NDF_STATUS_OK, "env energy");
    expect(ndf_environment_energy(env, NDF_BRDF_TORRANCE_SPARROW, energy,
                                  (size_t)4 * info.energy_columns * info.energy_rows),
           NDF_STATUS_INVALID_ARGUMENT, "env energy brdf");
    free(energy);
    free(table);
    free(levels);
    free(atlas);
    ndf_environment_free(env);
    ndf_environment_free(NULL);

    /* Bad input: not 2:1, a NULL buffer, bytes that are no .hdr, unknown policy. */
    env = NULL;
    expect(ndf_environment_from_rgb(EW, EW, rgb, &eo, &env), NDF_STATUS_DIMENSIONS, "env 1:1");
    expect(ndf_environment_from_rgb(EW, EH, NULL, &eo, &env), NDF_STATUS_NULL_ARGUMENT,
           "env NULL rgb");
    expect(ndf_environment_load_memory(rgb, 64, "junk.hdr", &eo, &env), NDF_STATUS_DECODE,
           "env junk");
    eo.bad_texels = 9;
    expect(ndf_environment_from_rgb(EW, EH, rgb, &eo, &env), NDF_STATUS_INVALID_ARGUMENT,
           "env policy");
    if (env != NULL) {
        fprintf(stderr, "FAIL env written on failure\n");
        failures++;
    }

    /* The environment-lit shaders of the vMF bake and the SH bake (its per-fragment rotation
     * constant and texel function); the SH bake has no prefiltered route. */
    env_shader(vmf, NDF_LIGHT_ENV_SH, 0, vmf_wants, "env shader vmf");
    env_shader(sh_bake, NDF_LIGHT_ENV_SH, 0, sh_wants, "env shader sh bake");
    so.light = NDF_LIGHT_ENV_PREFILTERED;
    expect(ndf_bake_shader_source_size(sh_bake, NDF_SHADER_STAGE_FRAGMENT, &so, &size),
           NDF_STATUS_INVALID_ARGUMENT, "env shader sh bake prefiltered");
}

/* Eq 22 under the environment: a vMF bake with colour textures (the map's own pixels as its
 * albedo) has a colour shader for each environment light; the bake without them is refused. */
static void colour_environment(const unsigned char *rgb, const ndf_bake *uncoloured) {
    ndf_ingest_options io = ndf_ingest_options_default();
    ndf_vmf_options vo = ndf_vmf_options_default();
    ndf_shader_options so = ndf_shader_options_default();
    ndf_normal_map *map = NULL;
    ndf_bake *bake = NULL;
    size_t size = 0;
    static const char *const env_wants[] = {"#define NDF_COLOR 1",
                                            "#define NDF_LIGHT_ENV_PREFILTERED 1",
                                            "ndf_env_texel(", NULL};
    static const char *const sh_wants[] = {"#define NDF_COLOR 1", "#define NDF_LIGHT_ENV_SH 1",
                                           NULL};
    static const char *const both_wants[] = {"#define NDF_COLOR 1", "#define NDF_LIGHT_BOTH 1",
                                             "ndf_env_texel(", NULL};
    expect(ndf_normal_map_from_pixels(rgb, 3 * SIZE * SIZE, SIZE, SIZE, 3, NDF_SAMPLE_UINT8, &io,
                                      &map),
           NDF_STATUS_OK, "colour map");
    expect(ndf_normal_map_attach_feature_pixels(map, rgb, 3 * SIZE * SIZE, SIZE, SIZE, 3,
                                                NDF_SAMPLE_UINT8, &io),
           NDF_STATUS_OK, "colour feature");
    vo.lobes = 2;
    expect(ndf_bake_vmf(map, &vo, &bake), NDF_STATUS_OK, "colour bake vmf");
    if (bake != NULL) {
        env_shader(bake, NDF_LIGHT_ENV_PREFILTERED, 1, env_wants, "env colour prefiltered");
        env_shader(bake, NDF_LIGHT_ENV_SH, 1, sh_wants, "env colour sh");
        env_shader(bake, NDF_LIGHT_POINT_AND_ENV_PREFILTERED, 1, both_wants,
                   "env colour point and env");
    }
    so.light = NDF_LIGHT_ENV_PREFILTERED;
    so.color = 1;
    expect(ndf_bake_shader_source_size(uncoloured, NDF_SHADER_STAGE_FRAGMENT, &so, &size),
           NDF_STATUS_INVALID_ARGUMENT, "env colour without colour textures");
    ndf_bake_free(bake);
    ndf_normal_map_free(map);
}

static int calls = 0;

static int stop_at_third_call(float fraction, void *user_data) {
    (void)fraction;
    (void)user_data;
    return ++calls < 3;
}

/* Materials: Lambert's SH coefficients are the closed forms, a tabulated BRDF gives its table,
 * and a malformed one is refused with nothing written. */
static void materials(void) {
    ndf_material_options mo = ndf_material_options_default();
    ndf_material *mat = NULL, *none = NULL;
    double rho[3] = {0, 0, 0};
    uint32_t lmax = 0, tw = 0, th = 0;
    float *table;
    const double pi = 3.14159265358979323846;

    mo.model = NDF_BRDF_LAMBERT;
    expect(ndf_material_new(&mo, &mat), NDF_STATUS_OK, "material lambert");
    expect(ndf_material_sh_coefficients(mat, 2, rho, 3), NDF_STATUS_OK, "lambert rho");
    if (rho[0] - pi > 1e-12 || pi - rho[0] > 1e-12 || rho[2] - pi / 4 > 1e-12 ||
        pi / 4 - rho[2] > 1e-12) {
        fprintf(stderr, "FAIL lambert rho %g %g %g\n", rho[0], rho[1], rho[2]);
        failures++;
    }
    expect(ndf_material_suggested_lmax(mat, &lmax), NDF_STATUS_OK, "suggested lmax");
    if (lmax != 2) {
        fprintf(stderr, "FAIL lambert lmax %u\n", (unsigned)lmax);
        failures++;
    }
    expect(ndf_material_sh_coefficients(mat, 2, rho, 2), NDF_STATUS_BUFFER_TOO_SMALL,
           "rho buffer short");
    ndf_material_free(mat);
    mat = NULL;
    mo = ndf_material_options_default();
    mo.model = NDF_BRDF_TABULATED;
    mo.tabulated_json = "{\"f\": [4.0, 2.0, 0.0], \"g\": [1.0, 0.8]}";
    expect(ndf_material_new(&mo, &mat), NDF_STATUS_OK, "material tabulated");
    expect(ndf_material_table_size(mat, &tw, &th), NDF_STATUS_OK, "table size");
    table = malloc(sizeof(float) * tw * th);
    expect(ndf_material_table(mat, table, (size_t)tw * th), NDF_STATUS_OK, "table");
    if (table[(size_t)tw * (th - 2)] != 4.0f) {
        fprintf(stderr, "FAIL table row of the lobe starts at %g\n", table[(size_t)tw * (th - 2)]);
        failures++;
    }
    free(table);
    ndf_material_free(mat);
    mo.tabulated_json = "{\"f\": [1.0, -1.0]}";
    expect(ndf_material_new(&mo, &none), NDF_STATUS_INVALID_ARGUMENT, "negative table");
    if (none != NULL) {
        fprintf(stderr, "FAIL material written on failure\n");
        failures++;
    }
    ndf_material_free(NULL);
}

static void bad_input(ndf_normal_map *map, ndf_bake *bake, const unsigned char *rgb) {
    ndf_ingest_options io = ndf_ingest_options_default();
    ndf_vmf_options vo = ndf_vmf_options_default();
    ndf_normal_map *no_map = NULL;
    ndf_bake *no_bake = NULL;
    uint32_t n = 0, w, h;
    unsigned char small[8];
    size_t written;

    expect(ndf_normal_map_from_pixels(NULL, 3, 1, 1, 3, NDF_SAMPLE_UINT8, &io, &no_map),
           NDF_STATUS_NULL_ARGUMENT, "NULL pixels");
    expect(ndf_normal_map_from_pixels(rgb, 3 * SIZE * SIZE - 1, SIZE, SIZE, 3, NDF_SAMPLE_UINT8,
                                      &io, &no_map),
           NDF_STATUS_SHORT_PIXELS, "pixels one byte short");
    expect(ndf_normal_map_from_pixels(rgb, 3 * SIZE * SIZE, 65536, 65536, 3, NDF_SAMPLE_UINT8,
                                      &io, &no_map),
           NDF_STATUS_DIMENSIONS, "width x height overflow");
    expect(ndf_normal_map_from_pixels(rgb, 3 * SIZE * SIZE, SIZE, SIZE, 3, 42, &io, &no_map),
           NDF_STATUS_INVALID_ARGUMENT, "unknown sample type");
    io.green = 7;
    expect(ndf_normal_map_from_pixels(rgb, 3 * SIZE * SIZE, SIZE, SIZE, 3, NDF_SAMPLE_UINT8, &io,
                                      &no_map),
           NDF_STATUS_INVALID_ARGUMENT, "unknown green");
    expect(ndf_normal_map_load_memory(rgb, 10, "noise.png", &io, &no_map),
           NDF_STATUS_INVALID_ARGUMENT, "unknown green before decoding");
    io = ndf_ingest_options_default();
    expect(ndf_normal_map_load_memory(rgb, 10, "noise.png", &io, &no_map), NDF_STATUS_DECODE,
           "garbage bytes");
    expect(ndf_normal_map_load_file("/no/such/map.png", &io, &no_map), NDF_STATUS_READ,
           "missing file");
    if (no_map != NULL) {
        fprintf(stderr, "FAIL out-parameter written on failure\n");
        failures++;
    }

    expect(ndf_bake_vmf(map, NULL, &no_bake), NDF_STATUS_NULL_ARGUMENT, "NULL options");
    expect(ndf_bake_vmf(NULL, &vo, &no_bake), NDF_STATUS_NULL_ARGUMENT, "NULL map");
    expect(ndf_bake_vmf(map, &vo, NULL), NDF_STATUS_NULL_ARGUMENT, "NULL bake_out");
    vo.lobes = 9;
    expect(ndf_bake_vmf(map, &vo, &no_bake), NDF_STATUS_INVALID_ARGUMENT, "9 lobes");
    vo = ndf_vmf_options_default();
    vo.struct_size = sizeof(vo) - 8;
    expect(ndf_bake_vmf(map, &vo, &no_bake), NDF_STATUS_INVALID_ARGUMENT, "struct_size");
    vo = ndf_vmf_options_default();
    vo.lobes = 2;
    vo.progress = stop_at_third_call;
    expect(ndf_bake_vmf(map, &vo, &no_bake), NDF_STATUS_CANCELLED, "cancelled bake");
    if (calls != 3 || no_bake != NULL) {
        fprintf(stderr, "FAIL cancel: %d calls\n", calls);
        failures++;
    }
    expect(ndf_bake_baseline(map, 77, NULL, &no_bake), NDF_STATUS_INVALID_ARGUMENT,
           "unknown method");

    expect(ndf_bake_level_count(NULL, &n), NDF_STATUS_NULL_ARGUMENT, "NULL bake");
    expect(ndf_bake_level_count(bake, NULL), NDF_STATUS_NULL_ARGUMENT, "NULL out");
    expect(ndf_bake_level_size(bake, 99, &w, &h), NDF_STATUS_OUT_OF_RANGE, "level 99");
    expect(ndf_bake_pack(bake, 99, 0, NDF_FORMAT_RGBA_F32, small, sizeof small, &written),
           NDF_STATUS_OUT_OF_RANGE, "texture 99");
    expect(ndf_bake_pack(bake, 0, 0, 4, small, sizeof small, &written),
           NDF_STATUS_INVALID_ARGUMENT, "format 4");
    expect(ndf_bake_pack(bake, 0, 0, NDF_FORMAT_RGBA_F32, NULL, 0, &written),
           NDF_STATUS_NULL_ARGUMENT, "NULL buffer");
    expect(ndf_bake_write(bake, NULL, NDF_FORMAT_RGBA_F32), NDF_STATUS_NULL_ARGUMENT,
           "NULL directory");
    if (strcmp(ndf_status_str(1000), "NDF_STATUS_UNKNOWN") != 0) {
        fprintf(stderr, "FAIL unknown status name\n");
        failures++;
    }
    ndf_bake_free(NULL);
    ndf_normal_map_free(NULL);
    printf("bad input checked\n");
}

int main(int argc, char **argv) {
    unsigned char rgb[3 * SIZE * SIZE];
    ndf_ingest_options io = ndf_ingest_options_default();
    ndf_baseline_options bo = ndf_baseline_options_default();
    ndf_vmf_options vo = ndf_vmf_options_default();
    ndf_tan2005_options to = ndf_tan2005_options_default();
    ndf_sh_options so = ndf_sh_options_default();
    ndf_pbr_options po = ndf_pbr_options_default();
    ndf_bake *pbr = NULL;
    float roughness[SIZE * SIZE];
    int i;
    ndf_normal_map *map = NULL, *from_file = NULL;
    ndf_bake *bakes[7] = {NULL, NULL, NULL, NULL, NULL, NULL, NULL};
    ndf_method m;
    uint32_t w = 0, h = 0;

    if (argc != 3) {
        fprintf(stderr, "usage: consumer OUTPUT_DIR PNG_FILE\n");
        return 2;
    }
    if (ndf_version() != NDF_VERSION) {
        fprintf(stderr, "FAIL header %d, library %u\n", NDF_VERSION, (unsigned)ndf_version());
        return 1;
    }
    printf("version %s\n", ndf_version_string());
    make_pixels(rgb);
    expect(ndf_normal_map_from_pixels(rgb, sizeof rgb, SIZE, SIZE, 3, NDF_SAMPLE_UINT8, &io, &map),
           NDF_STATUS_OK, "from pixels");
    expect(ndf_normal_map_load_file(argv[2], &io, &from_file), NDF_STATUS_OK, "load file");
    expect(ndf_normal_map_size(from_file, &w, &h), NDF_STATUS_OK, "map size");
    printf("map %ux%u\n", (unsigned)w, (unsigned)h);
    if (failures) {
        return 1;
    }

    vo.lobes = 2;
    vo.aligned = 1;
    to.lobes = 2;
    for (m = NDF_METHOD_PLAIN; m <= NDF_METHOD_SH; m++) {
        /* The file and the pixels are the same map: the vMF bake comes from the file. */
        if (m == NDF_METHOD_VMF) {
            expect(ndf_bake_vmf(from_file, &vo, &bakes[m]), NDF_STATUS_OK, "bake vmf");
        } else if (m == NDF_METHOD_SH) {
            expect(ndf_bake_sh(map, &so, &bakes[m]), NDF_STATUS_OK, "bake sh");
        } else if (m == NDF_METHOD_TAN2005) {
            expect(ndf_bake_tan2005(map, &to, &bakes[m]), NDF_STATUS_OK, "bake tan2005");
        } else {
            expect(ndf_bake_baseline(map, m, &bo, &bakes[m]), NDF_STATUS_OK, "bake baseline");
        }
        if (bakes[m] != NULL) {
            describe(bakes[m]);
        }
    }
    /* The PBR bake, anisotropic, with a roughness map (perceptual, linear, row-major). */
    for (i = 0; i < SIZE * SIZE; i++) {
        roughness[i] = (float)(((i % SIZE) * 3 + i / SIZE) % 8) / 8.0f;
    }
    po.anisotropic = 1;
    po.roughness_map = roughness;
    expect(ndf_bake_pbr(map, &po, &pbr), NDF_STATUS_OK, "bake pbr");
    if (pbr != NULL) {
        describe(pbr);
    }
    ndf_bake_free(pbr);
    expect(ndf_bake_write(bakes[NDF_METHOD_VMF], argv[1], NDF_FORMAT_RGBA_F16), NDF_STATUS_OK,
           "write");
    shaders(bakes[NDF_METHOD_VMF]);
    bad_input(map, bakes[NDF_METHOD_PLAIN], rgb);
    materials();
    environments(bakes[NDF_METHOD_VMF], bakes[NDF_METHOD_SH]);
    colour_environment(rgb, bakes[NDF_METHOD_VMF]);

    for (m = NDF_METHOD_PLAIN; m <= NDF_METHOD_SH; m++) {
        ndf_bake_free(bakes[m]);
    }
    ndf_normal_map_free(map);
    ndf_normal_map_free(from_file);
    if (failures) {
        fprintf(stderr, "%d failures\n", failures);
        return 1;
    }
    return 0;
}
