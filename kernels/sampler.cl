/* Sample points along a ray, and the seeded random numbers that place them.
 *
 * Random numbers: interleaved-sampling offsets and sub-pixel positions are
 * hashes of (pixel, sample index, seed), so a frame is the same bit for bit
 * for the same seed, on any device and any work-group size.
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

/* A uniform float in [0, 1) from (pixel, sample, seed, stream); `stream`
 * separates the independent numbers one sample needs (offset, x, y). The top 24
 * bits make the float exact and strictly below 1. */
inline float eb_random(uint pixel, uint sample, uint seed, uint stream)
{
    uint h = eb_hash(pixel ^ eb_hash(sample ^ eb_hash(seed ^ eb_hash(stream))));
    return (float)(h >> 8) * (1.0f / 16777216.0f);
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
