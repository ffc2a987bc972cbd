// C++ consumer of include/ndfmap.h, run by tests/c_api.rs (linked against libndfmap.so and
// libndfmap.a): the header compiles as C++17 with -Wall -Wextra -Werror -pedantic, handles fit
// std::unique_ptr, a captureless lambda is a progress callback, and the vMF bake of the same
// 16x16 map as consumer.c packs to the bytes the Rust API gives (the test compares the lines).
#include "ndfmap.h"

#include <cstdint>
#include <cstdio>
#include <cstring>
#include <memory>
#include <vector>

namespace {

struct MapFree {
    void operator()(ndf_normal_map *m) const { ndf_normal_map_free(m); }
};
struct BakeFree {
    void operator()(ndf_bake *b) const { ndf_bake_free(b); }
};
using Map = std::unique_ptr<ndf_normal_map, MapFree>;
using Bake = std::unique_ptr<ndf_bake, BakeFree>;

int failures = 0;

void check(ndf_status got, ndf_status want, const char *what) {
    if (got != want) {
        std::fprintf(stderr, "FAIL %s: got %s, want %s (%s)\n", what, ndf_status_str(got),
                     ndf_status_str(want), ndf_last_error_message());
        ++failures;
    }
}

std::uint64_t fnv1a(const std::vector<unsigned char> &bytes) {
    std::uint64_t h = 14695981039346656037ull;
    for (unsigned char b : bytes) {
        h ^= b;
        h *= 1099511628211ull;
    }
    return h;
}

}  // namespace

int main() {
    constexpr std::uint32_t size = 16;
    std::vector<unsigned char> rgb(3 * size * size);
    for (std::uint32_t y = 0; y < size; ++y) {
        for (std::uint32_t x = 0; x < size; ++x) {
            unsigned char *p = &rgb[3 * (y * size + x)];
            p[0] = static_cast<unsigned char>((x * 37 + y * 11) % 256);
            p[1] = static_cast<unsigned char>((x * 13 + y * 29 + 64) % 256);
            p[2] = static_cast<unsigned char>(200 + (x + y) % 56);
        }
    }
    ndf_ingest_options io = ndf_ingest_options_default();
    ndf_normal_map *raw_map = nullptr;
    check(ndf_normal_map_from_pixels(rgb.data(), rgb.size(), size, size, 3, NDF_SAMPLE_UINT8, &io,
                                     &raw_map),
          NDF_STATUS_OK, "from pixels");
    Map map(raw_map);

    int reports = 0;
    ndf_vmf_options vo = ndf_vmf_options_default();
    vo.lobes = 2;
    vo.aligned = 1;
    vo.progress = [](float fraction, void *user) -> int {
        int *count = static_cast<int *>(user);
        ++*count;
        return fraction >= 0.0f && fraction <= 1.0f;
    };
    vo.progress_user_data = &reports;
    ndf_bake *raw_bake = nullptr;
    check(ndf_bake_vmf(map.get(), &vo, &raw_bake), NDF_STATUS_OK, "bake vmf");
    Bake bake(raw_bake);
    if (!bake || reports < 2) {
        std::fprintf(stderr, "FAIL no bake or no progress (%d reports)\n", reports);
        return 1;
    }

    std::uint32_t textures = 0, levels = 0;
    check(ndf_bake_texture_count(bake.get(), &textures), NDF_STATUS_OK, "textures");
    check(ndf_bake_level_count(bake.get(), &levels), NDF_STATUS_OK, "levels");
    for (std::uint32_t t = 0; t < textures; ++t) {
        for (std::uint32_t k = 0; k < levels; ++k) {
            std::size_t bytes = 0, written = 0;
            check(ndf_bake_packed_size(bake.get(), t, k, NDF_FORMAT_RGBA_F16, &bytes),
                  NDF_STATUS_OK, "packed size");
            std::vector<unsigned char> buffer(bytes);
            check(ndf_bake_pack(bake.get(), t, k, NDF_FORMAT_RGBA_F16, buffer.data(),
                                buffer.size(), &written),
                  NDF_STATUS_OK, "pack");
            std::printf("pack %u %u f16 %lu %016llx\n", static_cast<unsigned>(t),
                        static_cast<unsigned>(k), static_cast<unsigned long>(written),
                        static_cast<unsigned long long>(fnv1a(buffer)));
        }
    }

    // Bad input from C++: every failure is a status, never an exception or an abort.
    std::size_t written = 0;
    unsigned char one = 0;
    check(ndf_bake_pack(bake.get(), 0, 0, NDF_FORMAT_RGBA_F16, &one, 1, &written),
          NDF_STATUS_BUFFER_TOO_SMALL, "one byte");
    check(ndf_bake_pack(nullptr, 0, 0, NDF_FORMAT_RGBA_F16, &one, 1, &written),
          NDF_STATUS_NULL_ARGUMENT, "null bake");
    if (std::strstr(ndf_last_error_message(), "bake is NULL") == nullptr) {
        std::fprintf(stderr, "FAIL message: %s\n", ndf_last_error_message());
        ++failures;
    }
    return failures == 0 ? 0 : 1;
}
