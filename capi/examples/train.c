/*
 * Train an sdguide field from C, from several threads, on a synthetic light field; sample it,
 * check what it returns, save and reload it. Exits 0 when every check passes.
 *
 *   cargo build --release -p sdguide-capi
 *   gcc -std=c99 -Wall -Wextra -Werror -Icapi/include capi/examples/train.c \
 *       -Ltarget/release -lsdguide_c -lpthread -lm -ldl -o train
 *   LD_LIBRARY_PATH=target/release ./train
 */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>

#include "sdguide.h"

#define THREADS 4
static int iterations = 5;
static long first_budget = 40000; /* samples per thread in the first iteration, doubling */
static int estimate_samples = 200000;
#define BATCH 256
#define PI 3.14159265358979f

static sdg_vec3 light_dir; /* a lobe of light from this direction, plus a little ambient */

static float light(sdg_vec3 d) {
    float c = d.x * light_dir.x + d.y * light_dir.y + d.z * light_dir.z;
    return 50.0f * expf(40.0f * (c - 1.0f)) + 0.1f;
}

/* Its integral over the sphere, ∫ 50·e^{40(c−1)} dω = 50 · 2π(1 − e^{−80})/40, plus 0.1 · 4π,
 * and the integral of its square (for the variance of uniform sampling). */
static double light_integral(void) {
    const double pi = 3.14159265358979;
    return 50.0 * 2.0 * pi * (1.0 - exp(-80.0)) / 40.0 + 0.1 * 4.0 * pi;
}

static double light_square_integral(void) {
    const double pi = 3.14159265358979;
    return 2500.0 * 2.0 * pi * (1.0 - exp(-160.0)) / 80.0 + 2.0 * 50.0 * 0.1 * 2.0 * pi * (1.0 - exp(-80.0)) / 40.0 +
           0.01 * 4.0 * pi;
}

static float next(uint64_t *state) { /* xorshift64*, in [0, 1) */
    *state ^= *state >> 12;
    *state ^= *state << 25;
    *state ^= *state >> 27;
    return (float)((*state * 2685821657736338717ull) >> 40) / 16777216.0f;
}

static sdg_vec3 uniform_direction(float u0, float u1) {
    float z = 1.0f - 2.0f * u0, r = sqrtf(fmaxf(0.0f, 1.0f - z * z)), phi = 2.0f * PI * u1;
    sdg_vec3 d = {r * cosf(phi), r * sinf(phi), z};
    return d;
}

static int failures = 0;
#define CHECK(cond, ...)                                                                     \
    do {                                                                                     \
        if (!(cond)) {                                                                       \
            fprintf(stderr, "check failed at line %d: ", __LINE__);                         \
            fprintf(stderr, __VA_ARGS__);                                                    \
            fprintf(stderr, " (%s)\n", sdg_last_error());                                    \
            failures++;                                                                      \
        }                                                                                    \
    } while (0)

typedef struct {
    sdg_field *field;
    int thread;
    int iteration;
    long samples;
} job;

/* What a render thread does: draw each direction from the one-sample mixture of the guide
 * (with the learned probability a) and a "BSDF" (here the uniform sphere), and record it with
 * the mixture pdf and the mixture terms the guide probability learns from. */
static void *record(void *arg) {
    job *j = (job *)arg;
    uint64_t state = 0x9e3779b97f4a7c15ull * (uint64_t)(j->thread + 1) + (uint64_t)j->iteration;
    const float bsdf_pdf = 1.0f / (4.0f * PI);
    sdg_sample batch[BATCH];
    for (long done = 0; done < j->samples; done += BATCH) {
        for (int i = 0; i < BATCH; i++) {
            sdg_vec3 x = {next(&state), next(&state), next(&state)};
            float u0 = next(&state), u1 = next(&state), guide_pdf = 0.0f, a = 0.5f;
            sdg_vec3 d;
            sdg_distribution *dist = NULL;
            CHECK(sdg_field_distribution(j->field, x, &dist) == SDG_STATUS_OK, "distribution");
            CHECK(sdg_distribution_guide_probability(dist, &a) == SDG_STATUS_OK, "probability");
            if (next(&state) < a) {
                CHECK(sdg_distribution_sample(dist, u0, u1, &d, &guide_pdf) == SDG_STATUS_OK, "sample");
            } else {
                d = uniform_direction(u0, u1);
                CHECK(sdg_distribution_pdf(dist, d, &guide_pdf) == SDG_STATUS_OK, "pdf");
            }
            sdg_distribution_destroy(dist);
            float f = light(d); /* the integrand: light times a constant BSDF */
            /* The points lie on no surface: no normal (a renderer passes its shading normal with
               SDG_SAMPLE_NORMAL). No roulette decided what arrived: no second moment, value²
               serves. The mixture terms are set. */
            sdg_sample s = {0};
            s.position = x;
            s.direction = d;
            s.value = light(d);
            s.pdf = a * guide_pdf + (1.0f - a) * bsdf_pdf;
            s.integrand = f;
            s.bsdf_pdf = bsdf_pdf;
            s.guide_pdf = guide_pdf;
            s.flags = SDG_SAMPLE_MIXTURE;
            batch[i] = s;
        }
        CHECK(sdg_field_record_batch(j->field, batch, BATCH) == SDG_STATUS_OK, "record");
    }
    return NULL;
}

/* Sample the distribution at x n times: every pdf positive, finite and equal to what pdf()
 * says; returns the mean of light/pdf (an unbiased estimate of the integral) and its error. */
static double estimate(const sdg_field *field, sdg_vec3 x, int n, double *standard_error) {
    sdg_distribution *dist = NULL;
    CHECK(sdg_field_distribution(field, x, &dist) == SDG_STATUS_OK, "distribution");
    uint64_t state = 12345;
    double s1 = 0.0, s2 = 0.0;
    for (int i = 0; i < n; i++) {
        sdg_vec3 d;
        float pdf = 0.0f, again = -1.0f;
        CHECK(sdg_distribution_sample(dist, next(&state), next(&state), &d, &pdf) == SDG_STATUS_OK, "sample");
        CHECK(pdf > 0.0f && isfinite(pdf), "pdf %g", (double)pdf);
        CHECK(sdg_distribution_pdf(dist, d, &again) == SDG_STATUS_OK && again == pdf, "pdf %g vs %g",
              (double)pdf, (double)again);
        double w = light(d) / pdf;
        s1 += w;
        s2 += w * w;
    }
    sdg_distribution_destroy(dist);
    double mean = s1 / n;
    *standard_error = sqrt((s2 / n - mean * mean) / n);
    return mean;
}

int main(int argc, char **argv) {
    /* --quick: a small run, for running under valgrind. */
    int quick = argc > 1 && argv[1][0] == '-' && argv[1][1] == '-' && argv[1][2] == 'q';
    if (quick) {
        iterations = 3;
        first_budget = 2000;
        estimate_samples = 20000;
    }
    float len = sqrtf(0.3f * 0.3f + 0.5f * 0.5f + 0.8f * 0.8f);
    light_dir.x = 0.3f / len;
    light_dir.y = 0.5f / len;
    light_dir.z = 0.8f / len;

    sdg_config config;
    sdg_config_default(&config);
    config.spatial_threshold = 4000.0f;
    sdg_field *field = NULL;
    sdg_vec3 lo = {0.0f, 0.0f, 0.0f}, hi = {1.0f, 1.0f, 1.0f};
    if (sdg_field_create(&config, lo, hi, &field) != SDG_STATUS_OK) {
        fprintf(stderr, "create: %s\n", sdg_last_error());
        return 1;
    }

    for (int k = 0; k < iterations; k++) {
        pthread_t threads[THREADS];
        job jobs[THREADS];
        for (int t = 0; t < THREADS; t++) {
            job j = {field, t, k, first_budget << k};
            jobs[t] = j;
            pthread_create(&threads[t], NULL, record, &jobs[t]);
        }
        for (int t = 0; t < THREADS; t++) {
            pthread_join(threads[t], NULL);
        }
        CHECK(sdg_field_refine(field) == SDG_STATUS_OK, "refine");
    }
    sdg_stats stats;
    CHECK(sdg_field_stats(field, &stats) == SDG_STATUS_OK, "stats");
    printf("trained: %u iterations, %llu samples, %llu spatial leaves, %llu directional leaves\n",
           stats.iteration, (unsigned long long)stats.samples_recorded_total,
           (unsigned long long)stats.spatial_leaves, (unsigned long long)stats.directional_leaves);
    CHECK(stats.iteration == (uint32_t)iterations && stats.spatial_leaves > 1, "stats");

    /* Guided sampling is unbiased (5σ) and far better than uniform sampling. */
    sdg_vec3 x = {0.4f, 0.6f, 0.5f};
    double se, mean = estimate(field, x, estimate_samples, &se), truth = light_integral();
    printf("estimate at (0.4, 0.6, 0.5): %.4f ± %.4f (exact %.4f)\n", mean, se, truth);
    CHECK(fabs(mean - truth) < 5.0 * se, "estimate %g vs %g", mean, truth);
    double relvar = se * se * estimate_samples / (truth * truth);
    double uniform = 4.0 * 3.14159265358979 * light_square_integral() / (truth * truth) - 1.0;
    printf("relative variance: %.4f guided, %.2f with uniform sampling\n", relvar, uniform);
    CHECK(quick || relvar < 0.1 * uniform, "relative variance %g vs uniform %g", relvar, uniform);

    /* The learned guide probability: the guide fits the light far better than the uniform
     * "BSDF", so the mixture leans toward it (within the defensive bounds). */
    sdg_distribution *dist = NULL;
    float a = 0.0f;
    CHECK(sdg_field_distribution(field, x, &dist) == SDG_STATUS_OK, "distribution");
    CHECK(sdg_distribution_guide_probability(dist, &a) == SDG_STATUS_OK, "probability");
    sdg_distribution_destroy(dist);
    printf("learned guide probability at (0.4, 0.6, 0.5): %.3f\n", (double)a);
    CHECK(a > 0.5f && a <= config.max_guide_probability, "guide probability %g", (double)a);

    /* Save to memory and to a file, reload both, and check the copies answer identically. */
    uint8_t *bytes = NULL;
    size_t size = 0;
    CHECK(sdg_field_save_to_buffer(field, &bytes, &size) == SDG_STATUS_OK, "save to buffer");
    sdg_field *from_buffer = NULL, *from_file = NULL;
    CHECK(sdg_field_load_from_buffer(bytes, size, &from_buffer) == SDG_STATUS_OK, "load buffer");
    const char *path = "sdguide-c-example.sdgc";
    CHECK(sdg_field_save(field, path) == SDG_STATUS_OK, "save");
    CHECK(sdg_field_load(path, &from_file) == SDG_STATUS_OK, "load");
    remove(path);
    uint64_t state = 7;
    for (int i = 0; i < 1000 && from_buffer && from_file; i++) {
        sdg_vec3 p = {next(&state), next(&state), next(&state)};
        sdg_vec3 d = uniform_direction(next(&state), next(&state));
        float a, b, c;
        sdg_field_pdf(field, p, d, &a);
        sdg_field_pdf(from_buffer, p, d, &b);
        sdg_field_pdf(from_file, p, d, &c);
        CHECK(a == b && a == c, "reloaded pdf %g %g %g", (double)a, (double)b, (double)c);
    }
    printf("saved and reloaded %zu bytes\n", size);

    /* The path recorder: a camera sample's vertex, the light that reached it through a
       roulette it survived, and the record it makes. */
    sdg_path *recorder = NULL;
    CHECK(sdg_path_create(0, &recorder) == SDG_STATUS_OK, "path");
    uint32_t camera = 0, vertex = 0;
    CHECK(sdg_path_start(recorder, &camera) == SDG_STATUS_OK, "path start");
    sdg_path_vertex pv = {0};
    pv.position = x;
    pv.direction = uniform_direction(0.3f, 0.6f);
    pv.bsdf = (sdg_vec3){0.2f, 0.2f, 0.2f};
    pv.pdf = 0.5f;
    CHECK(sdg_path_push(recorder, camera, &pv, &vertex) == SDG_STATUS_OK, "path push");
    CHECK(sdg_path_roulette(recorder, vertex, 0.5f, 1) == SDG_STATUS_OK, "path roulette");
    CHECK(sdg_path_add_radiance(recorder, vertex, (sdg_vec3){1.0f, 1.0f, 1.0f}) == SDG_STATUS_OK,
          "path radiance");
    sdg_vec3 estimate;
    size_t recorded = 0;
    CHECK(sdg_path_finish(recorder, &estimate) == SDG_STATUS_OK, "path finish");
    CHECK(fabsf(estimate.x - 0.2f / 0.5f / 0.5f) < 1e-6f, "path estimate %g", (double)estimate.x);
    CHECK(sdg_path_record(recorder, field, &recorded) == SDG_STATUS_OK && recorded == 1, "path record");
    sdg_path_destroy(recorder);

    /* Errors are codes and messages, not crashes. */
    bytes[size / 2] ^= 0xff;
    sdg_field *broken = NULL;
    CHECK(sdg_field_load_from_buffer(bytes, size, &broken) == SDG_STATUS_CACHE && broken == NULL,
          "corrupt buffer");
    printf("corrupt cache: %s\n", sdg_last_error());
    CHECK(sdg_field_refine(NULL) == SDG_STATUS_NULL_POINTER, "null field");
    sdg_buffer_free(bytes, size);

    sdg_field_destroy(from_file);
    sdg_field_destroy(from_buffer);
    sdg_field_destroy(field);
    printf(failures ? "FAILED: %d checks\n" : "all checks passed\n", failures);
    return failures ? 1 : 0;
}
