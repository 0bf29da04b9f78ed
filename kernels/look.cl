/* The frame's look: every transfer function and colour map as merged knots,
 * the volume layers, the per-field gradient scale, and headlight shading
 * (docs/design-rendering.md, "Integration and images"). The medium they make is
 * medium.cl. */
#pragma once
#include "common.h"
#include "transfer_function.cl"

/* Headlight shading: emitted rgb *= AMBIENT + DIFFUSE |n . v|, with n the
 * normalised gradient and v the view direction. A volume sample's factor is
 * weighted by its gradient's strength, 1 - w DIFFUSE (1 - |n . v|) with
 * w = |g|^2 / (1 + |g|^2), where |g| = 1 is a change of the layer's whole
 * transfer-function range within one finest cell (gradient_scale,
 * exabricks.engine.device_data): flat and noisy parts of the medium, whose
 * normals are rounding or cell-scale noise, stay unlit instead of showing
 * speckle and rings (docs/design-rendering.md, "Volume shading"). */
#define EB_AMBIENT 0.3f
#define EB_DIFFUSE 0.7f

/* The frame's look: every transfer function and colour map as merged knots
 * (exabricks.picture.transfer_function.TransferFunction.merged_knots) one after the
 * other, each volume layer's knot index (knot_buckets, for the packet
 * lookup of packet.cl), the volume layers (field, first knot, knot count,
 * offset of the knot index), and each volume layer's lookup table
 * (transfer_function.lookup_table; docs/design-rendering.md, "Transfer-function
 * tables"): its offset in `tables`, -1 where the layer is looked up exactly. */
typedef struct {
    __global const float *xs;
    __global const float4 *rgba;
    __global const int *buckets;
    __global const int4 *layers;
    int n_layers;
    /* Private copies of what every sample reads (kept out of global memory):
     * the first layer and its table. */
    int4 layer0;
    __global const float4 *tables;
    __global const int *table_at;
    int table0;
    /* Per field the lattice -> world gradient factor (xyz). Read where used: as a
     * private array, indexed by field, it would put the whole frame in memory. */
    __global const float4 *gradient_scale;
} eb_look;

/* Colour map (knots first .. first + n - 1) at `value`. */
EB_INLINE float4 eb_lookup(eb_look look, int first, int n, float value)
{
    return eb_transfer_function(value, look.xs + first, look.rgba + first, n);
}

/* Volume layer `layer` (its table at offset `table`, or -1) at `value`. */
EB_INLINE float4 eb_layer_lookup(eb_look look, int4 layer, int table, float value)
{
    if (table >= 0)
        return eb_table_lookup(look.tables + table, value);
    return eb_lookup(look, layer.y, layer.z, value);
}

/* Headlight factor of a volume sample's gradient g (scaled by gradient_scale)
 * seen along dir: 1 for a zero gradient. */
EB_INLINE float eb_headlight(float3 g, float3 dir_world)
{
    float g2 = dot(g, g);
    /* rsqrt is cheaper than length() and a division. */
    return g2 > 0.0f ? 1.0f - g2 / (1.0f + g2) * EB_DIFFUSE * (1.0f - fabs(dot(g, dir_world)) * rsqrt(g2))
                     : 1.0f;
}
