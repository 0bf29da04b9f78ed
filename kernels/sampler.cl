/* Sample points along a ray, and the seeded random numbers that place them.
 *
 * Sample numbers: interleaved-sampling offsets, sub-pixel positions and
 * ambient-occlusion directions are low-discrepancy sequences shifted by seeded
 * hashes of (pixel, seed) (below), so a frame is the same bit for bit for the
 * same seed, on any device and any work-group size.
 *
 * Sub-intervals (paper §4.2-4.3, Fig. 5), shared by the integrator and the
 * uniform-grid marcher: the points t_k = (k + rho) dt, k integer, are
 * delimiters that split a ray interval [t_in, t_out] into sub-intervals
 * [t_in, t_a], [t_a, t_b], ..., [t_z, t_out], each sampled once at its
 * midpoint and weighted by its length. Consecutive intervals (regions) never
 * leave gaps or overlaps, and every non-empty interval gets a sample. */
#pragma once
#include "common.h"

/* A 32-bit integer finaliser (Chris Wellons' "lowbias32"): every input bit
 * affects every output bit. */
inline uint eb_hash(uint x)
{
    x ^= x >> 16;
    x *= 0x7feb352du;
    x ^= x >> 15;
    x *= 0x846ca68bu;
    x ^= x >> 16;
    return x;
}

/* Low-discrepancy numbers (issue 48; docs/design-rendering.md, "Sample offsets"): a
 * sequence over the sample index, shifted per pixel by a seeded hash
 * (Cranley-Patterson rotation), in 32-bit fixed point so that it stays exact
 * for any index. Samples of one pixel are then spread evenly instead of at
 * random, and a pixel's first offset varies across the image as interleaved
 * gradient noise (Jimenez 2014), whose errors are of high frequency. */
#define EB_GOLDEN 2654435769u  /* 2^32 / golden ratio: R1 */
#define EB_R2_X 3242174889u    /* 2^32 / plastic number: R2 (Roberts 2018) */
#define EB_R2_Y 2447445413u    /* 2^32 / plastic number^2 */

inline float eb_fixed_to_unit(uint x)
{
    return (float)(x >> 8) * (1.0f / 16777216.0f);
}

/* The per-pixel shift of stream `stream` as 32-bit fixed point. */
inline uint eb_shift(uint pixel, uint seed, uint stream)
{
    return eb_hash(pixel ^ eb_hash(seed ^ eb_hash(stream ^ 0x9e3779b9u)));
}

/* The interleaving offset in [0, 1) of sample `sample` of pixel (col, row). */
inline float eb_offset(int col, int row, uint sample, uint seed)
{
    float x = (float)(col & 1023), y = (float)(row & 1023);
    float g = 0.06711056f * x + 0.00583715f * y;
    g = 52.9829189f * (g - floor(g));
    float ign = g - floor(g);
    uint base = (uint)(ign * 4294967040.0f) + eb_hash(seed ^ 0x85ebca6bu);
    return eb_fixed_to_unit(base + sample * EB_GOLDEN);
}

/* Point `index` of the R2 sequence shifted for (pixel, seed, stream pair). */
inline float2 eb_r2(uint pixel, uint index, uint seed, uint stream)
{
    return (float2)(eb_fixed_to_unit(eb_shift(pixel, seed, stream) + index * EB_R2_X),
                    eb_fixed_to_unit(eb_shift(pixel, seed, stream + 1u) + index * EB_R2_Y));
}

/* Unit t and b with (t, b, n) orthonormal, for unit n (Duff et al. 2017). */
EB_INLINE void eb_orthonormal(float3 n, float3 *t, float3 *b)
{
    float sign = n.z >= 0.0f ? 1.0f : -1.0f;
    float a = -1.0f / (sign + n.z), bxy = n.x * n.y * a;
    *t = (float3)(1.0f + sign * n.x * n.x * a, sign * bxy, -sign * n.x);
    *b = (float3)(bxy, sign + n.y * n.y * a, -n.y);
}

/* A cosine-weighted direction about unit n from uniform (u1, u2) in [0, 1)^2. */
EB_INLINE float3 eb_sample_cosine(float3 n, float u1, float u2)
{
    float3 t, b;
    eb_orthonormal(n, &t, &b);
    float r = sqrt(u1), phi = 6.28318531f * u2;
    return normalize(r * cos(phi) * t + r * sin(phi) * b + sqrt(fmax(0.0f, 1.0f - u1)) * n);
}

/* The sub-intervals of one ray interval, produced one at a time. */
typedef struct {
    float ta;       /* start of the next sub-interval                    */
    float t_out;    /* end of the interval                               */
    float t_first;  /* first delimiter at or after t_in: (k + rho) dt    */
    float dt;
    int j;          /* index of the next delimiter                       */
    int j_max;      /* delimiters the interval can hold (a loop bound)   */
} eb_intervals;

EB_INLINE eb_intervals eb_intervals_start(float t_in, float t_out, float dt, float rho)
{
    eb_intervals it;
    it.ta = t_in;
    it.t_out = t_out;
    it.dt = dt;
    it.t_first = (ceil(t_in / dt - rho) + rho) * dt;
    it.j = 0;
    /* Beyond this many delimiters the rest of the interval is one sub-interval:
     * unreachable for valid settings (the host caps the samples per ray), but
     * it ends the loop when float steps stop advancing (tiny dt at large t). */
    it.j_max = (int)fmin(ceil((t_out - t_in) / dt) + 2.0f, (float)EB_MAX_SAMPLES);
    return it;
}

/* The next sub-interval: its midpoint *tm and length *len; 0 when done. */
EB_INLINE int eb_intervals_next(eb_intervals *it, float *tm, float *len)
{
    while (it->ta < it->t_out) {
        float tb = it->j >= it->j_max ? it->t_out
                                      : fmin(it->t_first + (float)it->j * it->dt, it->t_out);
        ++it->j;
        if (tb <= it->ta)
            continue;
        *len = tb - it->ta;
        *tm = 0.5f * (it->ta + tb);
        it->ta = tb;
        return 1;
    }
    return 0;
}
