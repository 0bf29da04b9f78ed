/* Basis-method reconstruction (paper §3.2, eq. 1-2) from the bricks listed by
 * one Active Brick Region, with the analytic gradient of paper §5.1.2.
 *
 * A cell of width w and centre c has the hat H(p) = prod_a max(0, 1 - |c_a - p_a| / w).
 * In a brick with lower corner L, cell width w and dims N, cell i has centre
 * L + (i + 1/2) w, so with x = (p - L) / w - 1/2 the hat of cell i along an
 * axis is max(0, 1 - |i - x|): only cells floor(x) and floor(x) + 1 can be
 * non-zero, with weights 1 - frac(x) and frac(x) -- trilinear weights, except
 * that cells outside the brick do not exist (weight 0, never clamped values).
 * Summing H v and H over the region's bricks gives eq. 2. */
#pragma once
#include "common.h"

/* The bricks on the device (exabricks.schema.Bricks, one field):
 *   box[b]    = (L.x, L.y, L.z, 1 / w), lattice units
 *   dims[b]   = (N.x, N.y, N.z, level)
 *   offset[b] = index of the brick's first value in `values` (x fastest). */
typedef struct {
    __global const float4 *box;
    __global const int4 *dims;
    __global const long *offset;
    __global const float *values;
} eb_bricks;

/* Sums of eq. 1-2 and their derivatives at one point. */
typedef struct {
    float weight;        /* sum H                        */
    float weighted;      /* sum H v                      */
    float3 d_weight;     /* sum dH/dp (lattice units)    */
    float3 d_weighted;   /* sum dH/dp v                  */
} eb_basis_sums;

/* Add the contributions of brick b at lattice point p to `s`. With
 * want_gradient == 0 the derivative sums are left untouched (the compiler
 * drops that code for a constant argument). */
EB_INLINE void eb_add_brick(eb_bricks bricks, int b, float3 p, eb_basis_sums *s,
                            const int want_gradient)
{
    float4 box = bricks.box[b];
    int4 n = bricks.dims[b];
    float3 x = (p - box.xyz) * box.w - 0.5f;
    float3 fl = floor(x);
    int3 i0 = convert_int3(fl);
    /* No cell of this brick has its hat over p (p beyond half a cell outside). */
    if (i0.x < -1 || i0.y < -1 || i0.z < -1 || i0.x >= n.x || i0.y >= n.y || i0.z >= n.z)
        return;
    float3 f = x - fl;
    /* Per-axis weights of cells i0 and i0 + 1; zero for cells outside the brick. */
    float wx0 = i0.x >= 0 ? 1.0f - f.x : 0.0f, wx1 = i0.x + 1 < n.x ? f.x : 0.0f;
    float wy0 = i0.y >= 0 ? 1.0f - f.y : 0.0f, wy1 = i0.y + 1 < n.y ? f.y : 0.0f;
    float wz0 = i0.z >= 0 ? 1.0f - f.z : 0.0f, wz1 = i0.z + 1 < n.z ? f.z : 0.0f;
    int x0 = max(i0.x, 0), x1 = min(i0.x + 1, n.x - 1);
    int y0 = max(i0.y, 0) * n.x, y1 = min(i0.y + 1, n.y - 1) * n.x;
    int nxy = n.x * n.y;
    int z0 = max(i0.z, 0) * nxy, z1 = min(i0.z + 1, n.z - 1) * nxy;
    __global const float *v = bricks.values + bricks.offset[b];
    float v000 = v[z0 + y0 + x0], v100 = v[z0 + y0 + x1];
    float v010 = v[z0 + y1 + x0], v110 = v[z0 + y1 + x1];
    float v001 = v[z1 + y0 + x0], v101 = v[z1 + y0 + x1];
    float v011 = v[z1 + y1 + x0], v111 = v[z1 + y1 + x1];
    /* Along x, then y, then z. */
    float c00 = wx0 * v000 + wx1 * v100, c10 = wx0 * v010 + wx1 * v110;
    float c01 = wx0 * v001 + wx1 * v101, c11 = wx0 * v011 + wx1 * v111;
    float c0 = wy0 * c00 + wy1 * c10, c1 = wy0 * c01 + wy1 * c11;
    float sx = wx0 + wx1, sy = wy0 + wy1, sz = wz0 + wz1;
    s->weighted += wz0 * c0 + wz1 * c1;
    s->weight += sx * sy * sz;
    if (want_gradient) {
        /* dH/dp_a of cell i0 is -1/w, of cell i0 + 1 is +1/w (where they exist). */
        float iw = box.w;
        float dx0 = i0.x >= 0 ? -iw : 0.0f, dx1 = i0.x + 1 < n.x ? iw : 0.0f;
        float dy0 = i0.y >= 0 ? -iw : 0.0f, dy1 = i0.y + 1 < n.y ? iw : 0.0f;
        float dz0 = i0.z >= 0 ? -iw : 0.0f, dz1 = i0.z + 1 < n.z ? iw : 0.0f;
        float e00 = dx0 * v000 + dx1 * v100, e10 = dx0 * v010 + dx1 * v110;
        float e01 = dx0 * v001 + dx1 * v101, e11 = dx0 * v011 + dx1 * v111;
        s->d_weighted.x += wz0 * (wy0 * e00 + wy1 * e10) + wz1 * (wy0 * e01 + wy1 * e11);
        s->d_weighted.y += wz0 * (dy0 * c00 + dy1 * c10) + wz1 * (dy0 * c01 + dy1 * c11);
        s->d_weighted.z += dz0 * c0 + dz1 * c1;
        s->d_weight += (float3)((dx0 + dx1) * sy * sz, sx * (dy0 + dy1) * sz, sx * sy * (dz0 + dz1));
    }
}

/* Sums of eq. 1-2 at lattice point p over the bricks brick_ids[begin:end]
 * (one region's list: every brick whose support overlaps the region). */
EB_INLINE eb_basis_sums eb_reconstruct(eb_bricks bricks, __global const int *brick_ids,
                                       long begin, long end, float3 p, const int want_gradient)
{
    eb_basis_sums s;
    s.weight = 0.0f;
    s.weighted = 0.0f;
    s.d_weight = (float3)(0.0f);
    s.d_weighted = (float3)(0.0f);
    for (long k = begin; k < end; ++k)
        eb_add_brick(bricks, brick_ids[k], p, &s, want_gradient);
    return s;
}

/* Gradient of B = sum H v / sum H (quotient rule, paper §5.1.2), lattice units. */
EB_INLINE float3 eb_basis_gradient(eb_basis_sums s)
{
    return (s.weight * s.d_weighted - s.weighted * s.d_weight) / (s.weight * s.weight);
}
