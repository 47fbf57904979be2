// The header compiles as C++ and links: a smoke test run by CI.
#include "sdguide.h"

#include <cstdio>

int main() {
    sdg_config config;
    if (sdg_config_default(&config) != SDG_STATUS_OK) return 1;
    sdg_field *field = nullptr;
    sdg_vec3 lo = {0.0f, 0.0f, 0.0f}, hi = {1.0f, 1.0f, 1.0f};
    if (sdg_field_create(&config, lo, hi, &field) != SDG_STATUS_OK) return 1;
    sdg_vec3 direction;
    float pdf = 0.0f;
    sdg_vec3 x = {0.5f, 0.5f, 0.5f};
    sdg_status status = sdg_field_sample(field, x, 0.25f, 0.75f, &direction, &pdf);
    sdg_field_destroy(field);
    std::printf("C++: sample status %d, pdf %g\n", static_cast<int>(status), static_cast<double>(pdf));
    return status == SDG_STATUS_OK && pdf > 0.0f ? 0 : 1;
}
