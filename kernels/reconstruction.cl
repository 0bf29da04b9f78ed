/* Reconstruction of the fields at a point from the bricks listed by one Active
 * Brick Region: the basis method (paper §3.2, eq. 1-2, default) with its
 * analytic gradient (paper §5.1.2), or, as the frame says (eb_reconstruction_of:
 * EB_RECONSTRUCTION_NEAREST or _VERTEX), the value of the containing leaf cell
 * (Kähler & Abel) or trilinear interpolation of stitched vertex values within the containing
 * brick (Kähler & Hege; exabricks.engine.vertex). All three return their
 * result as eb_basis_sums (weight 1 for the other two), so everything
 * downstream is the same.
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

/* Fields reconstructed together: EB_N_FIELDS, the frame's fields
 * (exabricks.scene.Scene.fields; one program per count). */

/* The bricks on the device (exabricks.schema.Bricks, the frame's fields):
 *   box[b]    = (L.x, L.y, L.z, 1 / w), lattice units
 *   dims[b]   = (N.x, N.y, N.z, level)
 *   offset[b] = index of the brick's first value in a field's values (x fastest)
 *   values    = EB_N_FIELDS fields one after the other, `field_stride` apart. */
typedef struct {
    __global const float4 *box;
    __global const int4 *dims;
    __global const long *offset;
    __global const float *values;
    long field_stride;
#ifndef EB_RECONSTRUCTION
    int reconstruction;            /* EB_RECONSTRUCTION_*: eb_params.reconstruction */
#endif
    /* the vertex reconstruction: per brick (N.x+1)(N.y+1)(N.z+1) vertex values (x fastest)
     * from vertex_offset[b], fields vertex_stride apart. */
    __global const long *vertex_offset;
    __global const float *vertex_values;
    long vertex_stride;
    /* render --lod: per brick EB_MAX_MIP offsets of its mip levels 1.. in
     * mip_values (exabricks.engine.lod), fields mip_stride apart. */
    __global const long *mip_offset;
    __global const float *mip_values;
    long mip_stride;
} eb_bricks;

/* Sums of eq. 1-2 and their derivatives at one point: the weights are the
 * same for every field (the same cells), the weighted sums one per field. */
typedef struct {
    float weight;                           /* sum H                     */
    float3 d_weight;                        /* sum dH/dp (lattice units) */
    float weighted[EB_N_FIELDS];            /* sum H v                   */
    float3 d_weighted[EB_N_FIELDS];         /* sum dH/dp v               */
} eb_basis_sums;

EB_INLINE eb_basis_sums eb_basis_zero(void)
{
    eb_basis_sums s;
    s.weight = 0.0f;
    s.d_weight = (float3)(0.0f);
    for (int f = 0; f < EB_N_FIELDS; ++f) {
        s.weighted[f] = 0.0f;
        s.d_weighted[f] = (float3)(0.0f);
    }
    return s;
}

/* Add the contributions of a grid of cells at lattice point p to `s`: lower
 * corner box.xyz, 1 / cell width box.w, n cells per axis, values v (fields
 * `stride` apart). With want_gradient == 0 the derivative sums are left
 * untouched (the compiler drops that code for a constant argument). */
EB_INLINE void eb_add_grid(float4 box, int4 n, __global const float *v, long stride, float3 p,
                           eb_basis_sums *s, const int want_gradient)
{
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
    float sx = wx0 + wx1, sy = wy0 + wy1, sz = wz0 + wz1;
    s->weight += sx * sy * sz;
    /* dH/dp_a of cell i0 is -1/w, of cell i0 + 1 is +1/w (where they exist). */
    float iw = box.w;
    float dx0 = i0.x >= 0 ? -iw : 0.0f, dx1 = i0.x + 1 < n.x ? iw : 0.0f;
    float dy0 = i0.y >= 0 ? -iw : 0.0f, dy1 = i0.y + 1 < n.y ? iw : 0.0f;
    float dz0 = i0.z >= 0 ? -iw : 0.0f, dz1 = i0.z + 1 < n.z ? iw : 0.0f;
    if (want_gradient)
        s->d_weight += (float3)((dx0 + dx1) * sy * sz, sx * (dy0 + dy1) * sz, sx * sy * (dz0 + dz1));
    for (int k = 0; k < EB_N_FIELDS; ++k, v += stride) {
        float v000 = v[z0 + y0 + x0], v100 = v[z0 + y0 + x1];
        float v010 = v[z0 + y1 + x0], v110 = v[z0 + y1 + x1];
        float v001 = v[z1 + y0 + x0], v101 = v[z1 + y0 + x1];
        float v011 = v[z1 + y1 + x0], v111 = v[z1 + y1 + x1];
        /* Along x, then y, then z. */
        float c00 = wx0 * v000 + wx1 * v100, c10 = wx0 * v010 + wx1 * v110;
        float c01 = wx0 * v001 + wx1 * v101, c11 = wx0 * v011 + wx1 * v111;
        float c0 = wy0 * c00 + wy1 * c10, c1 = wy0 * c01 + wy1 * c11;
        s->weighted[k] += wz0 * c0 + wz1 * c1;
        if (want_gradient) {
            float e00 = dx0 * v000 + dx1 * v100, e10 = dx0 * v010 + dx1 * v110;
            float e01 = dx0 * v001 + dx1 * v101, e11 = dx0 * v011 + dx1 * v111;
            s->d_weighted[k] += (float3)(
                wz0 * (wy0 * e00 + wy1 * e10) + wz1 * (wy0 * e01 + wy1 * e11),
                wz0 * (dy0 * c00 + dy1 * c10) + wz1 * (dy0 * c01 + dy1 * c11),
                dz0 * c0 + dz1 * c1);
        }
    }
}

/* Add the contributions of brick b at lattice point p to `s`. */
EB_INLINE void eb_add_brick(eb_bricks bricks, int b, float3 p, eb_basis_sums *s,
                            const int want_gradient)
{
    eb_add_grid(bricks.box[b], bricks.dims[b], bricks.values + bricks.offset[b],
                bricks.field_stride, p, s, want_gradient);
}

/* Level of detail (render --lod): brick b seen as cells of level `level` when
 * that is coarser than its own, from its mip level (level - own level, at most
 * EB_MAX_MIP): cells 2**m times wider anchored at the brick's lower corner,
 * ceil(N / 2**m) per axis, each the mean of the brick's cells inside it
 * (exabricks.engine.lod). */
EB_INLINE void eb_add_brick_lod(eb_bricks bricks, int b, float3 p, int level, eb_basis_sums *s,
                                const int want_gradient)
{
    int4 n = bricks.dims[b];
    int m = min(level - n.w, EB_MAX_MIP);
    if (m <= 0) {
        eb_add_brick(bricks, b, p, s, want_gradient);
        return;
    }
    float4 box = bricks.box[b];
    box.w = ldexp(box.w, -m);
    int4 nm = (int4)(((n.x - 1) >> m) + 1, ((n.y - 1) >> m) + 1, ((n.z - 1) >> m) + 1, n.w + m);
    eb_add_grid(box, nm, bricks.mip_values + bricks.mip_offset[b * EB_MAX_MIP + m - 1],
                bricks.mip_stride, p, s, want_gradient);
}

/* The cell of brick b that contains lattice point p (boxes half-open, so a
 * point on a shared face belongs to one brick): 1 and its index i and the
 * position x in cell units within the brick, else 0. */
EB_INLINE int eb_containing_cell(eb_bricks bricks, int b, float3 p, int3 *i, float3 *x)
{
    float4 box = bricks.box[b];
    int4 n = bricks.dims[b];
    *x = (p - box.xyz) * box.w;
    *i = convert_int3(floor(*x));
    return i->x >= 0 && i->y >= 0 && i->z >= 0 && i->x < n.x && i->y < n.y && i->z < n.z;
}

/* Nearest: the values of the leaf cell containing p (zero derivatives). */
EB_INLINE int eb_nearest(eb_bricks bricks, int b, float3 p, eb_basis_sums *s)
{
    int3 i;
    float3 x;
    if (!eb_containing_cell(bricks, b, p, &i, &x))
        return 0;
    int4 n = bricks.dims[b];
    __global const float *v = bricks.values + bricks.offset[b] + (i.z * n.y + i.y) * n.x + i.x;
    s->weight = 1.0f;
    for (int k = 0; k < EB_N_FIELDS; ++k, v += bricks.field_stride)
        s->weighted[k] = *v;
    return 1;
}

/* Vertex: trilinear interpolation of the brick's vertex values around the
 * cell containing p, with its analytic derivative (lattice units). */
EB_INLINE int eb_vertex(eb_bricks bricks, int b, float3 p, eb_basis_sums *s, const int want_gradient)
{
    int3 i;
    float3 x;
    if (!eb_containing_cell(bricks, b, p, &i, &x))
        return 0;
    int4 n = bricks.dims[b];
    float3 f = x - convert_float3(i);
    int nx = n.x + 1, nxy = (n.x + 1) * (n.y + 1);
    __global const float *v = bricks.vertex_values + bricks.vertex_offset[b]
                              + i.z * nxy + i.y * nx + i.x;
    float iw = bricks.box[b].w;
    s->weight = 1.0f;
    for (int k = 0; k < EB_N_FIELDS; ++k, v += bricks.vertex_stride) {
        float v000 = v[0], v100 = v[1], v010 = v[nx], v110 = v[nx + 1];
        float v001 = v[nxy], v101 = v[nxy + 1], v011 = v[nxy + nx], v111 = v[nxy + nx + 1];
        float c00 = mix(v000, v100, f.x), c10 = mix(v010, v110, f.x);
        float c01 = mix(v001, v101, f.x), c11 = mix(v011, v111, f.x);
        float c0 = mix(c00, c10, f.y), c1 = mix(c01, c11, f.y);
        s->weighted[k] = mix(c0, c1, f.z);
        if (want_gradient) {
            float e00 = v100 - v000, e10 = v110 - v010, e01 = v101 - v001, e11 = v111 - v011;
            s->d_weighted[k] = (float3)(
                mix(mix(e00, e10, f.y), mix(e01, e11, f.y), f.z),
                mix(c10 - c00, c11 - c01, f.z),
                c1 - c0) * iw;
        }
    }
    return 1;
}

/* Sums of eq. 1-2 with every brick finer than `level` seen at that level (LOD). */
EB_INLINE eb_basis_sums eb_reconstruct_lod(eb_bricks bricks, __global const int *brick_ids,
                                           long begin, long end, float3 p, int level,
                                           const int want_gradient)
{
    eb_basis_sums s = eb_basis_zero();
    for (long k = begin; k < end; ++k)
        eb_add_brick_lod(bricks, brick_ids[k], p, level, &s, want_gradient);
    return s;
}

/* The frame's reconstruction (EB_RECONSTRUCTION_*): eb_params.reconstruction, or
 * the build's (-DEB_RECONSTRUCTION: CPU programs, where the choice in the brick
 * loop made the one-sample path 1.3 times slower; exabricks.engine.variants). */
#ifdef EB_RECONSTRUCTION
#define eb_reconstruction_of(bricks) EB_RECONSTRUCTION
#else
#define eb_reconstruction_of(bricks) ((bricks).reconstruction)
#endif

/* Add brick b at lattice point p to `s` by the frame's reconstruction; 1 when
 * the sums are final (nearest and vertex: the brick containing p was found). */
EB_INLINE int eb_add_reconstruction(eb_bricks bricks, int b, float3 p, eb_basis_sums *s,
                                    const int want_gradient)
{
    if (eb_reconstruction_of(bricks) == EB_RECONSTRUCTION_NEAREST)
        return eb_nearest(bricks, b, p, s);
    if (eb_reconstruction_of(bricks) == EB_RECONSTRUCTION_VERTEX)
        return eb_vertex(bricks, b, p, s, want_gradient);
    eb_add_brick(bricks, b, p, s, want_gradient);
    return 0;
}

/* Sums at lattice point p over the bricks brick_ids[begin:end] (one region's
 * list: every brick whose support overlaps the region, so also every brick
 * containing a point of it). */
EB_INLINE eb_basis_sums eb_reconstruct(eb_bricks bricks, __global const int *brick_ids,
                                       long begin, long end, float3 p, const int want_gradient)
{
    eb_basis_sums s = eb_basis_zero();
    for (long k = begin; k < end; ++k)
        if (eb_add_reconstruction(bricks, brick_ids[k], p, &s, want_gradient))
            break;
    return s;
}

/* Value of field f (eq. 2); only where s.weight > 0. */
EB_INLINE float eb_basis_value(eb_basis_sums s, int f)
{
    return s.weighted[f] / s.weight;
}

/* Gradient of field f of B = sum H v / sum H (quotient rule, paper §5.1.2),
 * lattice units. Below the rounding noise of the sums it is zero: in a
 * constant field the two products of the quotient rule cancel only up to
 * float rounding, which near the edge of the support (small sum H) would
 * otherwise give a random full-length normal; the floor, 1e-6 of the terms'
 * sizes, is far below any gradient the data can have. */
EB_INLINE float3 eb_basis_gradient(eb_basis_sums s, int f)
{
    float w = s.weight, wv = s.weighted[f];
    float3 num = w * s.d_weighted[f] - wv * s.d_weight;
    /* |num / w^2| below 1e-6 of |v dw / w| + |d(wv) / w|, without a division */
    float noise = 2e-12f * (wv * wv * dot(s.d_weight, s.d_weight)
                            + w * w * dot(s.d_weighted[f], s.d_weighted[f]));
    return dot(num, num) > noise ? num / (w * w) : (float3)(0.0f);
}
