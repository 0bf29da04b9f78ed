/* Seeded, stateless random numbers: interleaved-sampling offsets and sub-pixel
 * positions are hashes of (pixel, sample index, seed), so a frame is the same
 * bit for bit for the same seed, on any device and any work-group size. */
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
