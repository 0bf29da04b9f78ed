/* Sample packets for CPU devices (docs/design-kernels.md, "Sample packets on CPU devices"): built
 * with -DEB_PACKET=8, a ray reconstructs its next eight samples at once with
 * OpenCL vector types, one lane per sample, from up to EB_PACKET_REGIONS
 * consecutive region visits (integrator.cl, eb_sample_batch). The lanes
 * share what a packet of rays would have to gather: the brick list (the
 * union of the regions' lists) and each brick's box, dims and values
 * pointer; only the cell indices and the value loads differ per lane.
 * Compositing, surfaces and everything after the reconstruction then take
 * the lanes in order, as the one-sample loop does, so the image is the same
 * up to rounding and early ray termination stops at the same sample (the
 * lanes computed beyond it are wasted work); in a volume frame the colours
 * of a packet are summed as a vector (eb_packet_composite).
 *
 * Only the basis reconstruction from the region's list is vectorised (the
 * host builds other reconstructions and the cell-location lookup without
 * EB_PACKET); bricks seen at a coarser level (--lod) take the one-sample path. */
#pragma once
#if defined(EB_CELL_LOCATION)
#error "sample packets are for the basis reconstruction from the regions' lists"
#endif
#include "common.h"
#include "frame.cl"

/* EB_PACKET lanes: exabricks.device.kernel_abi.PACKET_WIDTH, eight (the vector types
 * below). */
#if EB_PACKET != 8
#error "build with the defines of exabricks.device.kernel_abi.variant_defines (EB_PACKET=8)"
#endif
typedef float8 eb_vf;
typedef int8 eb_vi;
#define eb_convert_vi convert_int8
#define eb_convert_vf convert_float8
#define eb_as_vi as_int8
#define eb_as_vf as_float8
#define eb_vload vload8
#define eb_vstore vstore8
#define EB_GATHER_AS(T, v, i) ((T)((v)[(i).s0], (v)[(i).s1], (v)[(i).s2], (v)[(i).s3], \
                                    (v)[(i).s4], (v)[(i).s5], (v)[(i).s6], (v)[(i).s7]))

/* A region's samples go by packets while at least this many are left; a last
 * single one takes the one-sample path, which is cheaper for it
 * (docs/design-kernels.md, "Sample packets on CPU devices"). */
#define EB_PACKET_MIN_LANES 2

/* The most consecutive region visits one packet spans (packet_batch.cl): more
 * lists make a longer merge for few more full lanes (docs/design-kernels.md, "Sample
 * packets on CPU devices"). */
#define EB_PACKET_REGIONS 3

/* The sum of a vector's lanes, as a tree of halves. */
EB_INLINE float eb_vsum(eb_vf v)
{
    float4 h = v.lo + v.hi;
    return (h.x + h.z) + (h.y + h.w);
}

/* v[i] lane by lane (LLVM makes a gather instruction of it on AVX2/AVX-512). */
#define EB_GATHER(v, i) EB_GATHER_AS(eb_vf, v, i)

/* eb_basis_sums of W points, one lane each. */
typedef struct {
    eb_vf weight;
    eb_vf dw_x, dw_y, dw_z;
    eb_vf weighted[EB_N_FIELDS];
    eb_vf dv_x[EB_N_FIELDS], dv_y[EB_N_FIELDS], dv_z[EB_N_FIELDS];
} eb_packet_sums;

/* eb_add_grid for W points (px, py, pz): the same arithmetic in the same
 * order, with the lanes whose point lies beyond the grid's hats given zero
 * weights (and clamped, valid indices) instead of an early return. */
EB_INLINE void eb_packet_add_grid(float4 box, int4 n, __global const float *v, long stride,
                                  eb_vf px, eb_vf py, eb_vf pz, eb_packet_sums *s,
                                  const int want_gradient)
{
    eb_vf x = (px - box.x) * box.w - 0.5f;
    eb_vf y = (py - box.y) * box.w - 0.5f;
    eb_vf z = (pz - box.z) * box.w - 0.5f;
    eb_vf flx = floor(x), fly = floor(y), flz = floor(z);
    eb_vi ix = eb_convert_vi(flx), iy = eb_convert_vi(fly), iz = eb_convert_vi(flz);
    eb_vi in = (ix >= -1) & (iy >= -1) & (iz >= -1) & (ix < n.x) & (iy < n.y) & (iz < n.z);
    if (!any(in))
        return;
    eb_vf fx = x - flx, fy = y - fly, fz = z - flz;
    const eb_vf zero = (eb_vf)(0.0f);
    /* A lane outside gets zero x weights and derivatives: every term has one. */
    eb_vf wx0 = select(zero, 1.0f - fx, (ix >= 0) & in), wx1 = select(zero, fx, (ix + 1 < n.x) & in);
    eb_vf wy0 = select(zero, 1.0f - fy, iy >= 0), wy1 = select(zero, fy, iy + 1 < n.y);
    eb_vf wz0 = select(zero, 1.0f - fz, iz >= 0), wz1 = select(zero, fz, iz + 1 < n.z);
    eb_vi x0 = clamp(ix, 0, n.x - 1), x1 = clamp(ix + 1, 0, n.x - 1);
    eb_vi y0 = clamp(iy, 0, n.y - 1) * n.x, y1 = clamp(iy + 1, 0, n.y - 1) * n.x;
    int nxy = n.x * n.y;
    eb_vi z0 = clamp(iz, 0, n.z - 1) * nxy, z1 = clamp(iz + 1, 0, n.z - 1) * nxy;
    eb_vf sx = wx0 + wx1, sy = wy0 + wy1, sz = wz0 + wz1;
    s->weight += sx * sy * sz;
    float iw = box.w;
    eb_vf dx0 = select(zero, (eb_vf)(-iw), (ix >= 0) & in), dx1 = select(zero, (eb_vf)(iw), (ix + 1 < n.x) & in);
    eb_vf dy0 = select(zero, (eb_vf)(-iw), iy >= 0), dy1 = select(zero, (eb_vf)(iw), iy + 1 < n.y);
    eb_vf dz0 = select(zero, (eb_vf)(-iw), iz >= 0), dz1 = select(zero, (eb_vf)(iw), iz + 1 < n.z);
    if (want_gradient) {
        s->dw_x += (dx0 + dx1) * sy * sz;
        s->dw_y += sx * (dy0 + dy1) * sz;
        s->dw_z += sx * sy * (dz0 + dz1);
    }
    eb_vi i000 = z0 + y0 + x0, i100 = z0 + y0 + x1, i010 = z0 + y1 + x0, i110 = z0 + y1 + x1;
    eb_vi i001 = z1 + y0 + x0, i101 = z1 + y0 + x1, i011 = z1 + y1 + x0, i111 = z1 + y1 + x1;
    for (int k = 0; k < EB_N_FIELDS; ++k, v += stride) {
        eb_vf v000 = EB_GATHER(v, i000), v100 = EB_GATHER(v, i100);
        eb_vf v010 = EB_GATHER(v, i010), v110 = EB_GATHER(v, i110);
        eb_vf v001 = EB_GATHER(v, i001), v101 = EB_GATHER(v, i101);
        eb_vf v011 = EB_GATHER(v, i011), v111 = EB_GATHER(v, i111);
        eb_vf c00 = wx0 * v000 + wx1 * v100, c10 = wx0 * v010 + wx1 * v110;
        eb_vf c01 = wx0 * v001 + wx1 * v101, c11 = wx0 * v011 + wx1 * v111;
        eb_vf c0 = wy0 * c00 + wy1 * c10, c1 = wy0 * c01 + wy1 * c11;
        s->weighted[k] += wz0 * c0 + wz1 * c1;
        if (want_gradient) {
            eb_vf e00 = dx0 * v000 + dx1 * v100, e10 = dx0 * v010 + dx1 * v110;
            eb_vf e01 = dx0 * v001 + dx1 * v101, e11 = dx0 * v011 + dx1 * v111;
            s->dv_x[k] += wz0 * (wy0 * e00 + wy1 * e10) + wz1 * (wy0 * e01 + wy1 * e11);
            s->dv_y[k] += wz0 * (dy0 * c00 + dy1 * c10) + wz1 * (dy0 * c01 + dy1 * c11);
            s->dv_z[k] += dz0 * c0 + dz1 * c1;
        }
    }
}

/* The least and the greatest of W lanes. */
EB_INLINE float eb_min_lanes(eb_vf v)
{
    float4 m = fmin(v.lo, v.hi);
    float2 q = fmin(m.lo, m.hi);
    return fmin(q.x, q.y);
}

EB_INLINE float eb_max_lanes(eb_vf v)
{
    float4 m = fmax(v.lo, v.hi);
    float2 q = fmax(m.lo, m.hi);
    return fmax(q.x, q.y);
}

/* Brick b's terms added to the sums of W points whose bounding box is [lo, hi]:
 * a brick whose hats reach none of the box is passed over with one test on its
 * box, instead of the lanes' cell indices (on octree-like data most listed
 * bricks reach no lane; docs/design.md). The margin of 1e-3 cells keeps the
 * test conservative, whatever the rounding: a brick it passes over gives every
 * lane zero weight. */
EB_INLINE void eb_packet_add_brick(eb_bricks bricks, int b, float4 lo, float4 hi, eb_vf px,
                                   eb_vf py, eb_vf pz, eb_packet_sums *s, const int want_gradient)
{
    float4 box = bricks.box[b];
    int4 dims = bricks.dims[b];
    /* Lane hats reach the brick where -1/2 <= (p - L) / w < N + 1/2. */
    float4 xlo = (lo - box) * box.w, xhi = (hi - box) * box.w;
    int4 out = (xhi < -0.501f) | (xlo >= convert_float4(dims) + 0.501f);
    if (out.x | out.y | out.z)
        return;
    eb_packet_add_grid(box, dims, bricks.values + bricks.offset[b], bricks.field_stride,
                       px, py, pz, s, want_gradient);
}

/* The sums of eq. 1-2 at W points over the union of n_lists brick lists
 * brick_ids[begin[i]:end[i]], those of the regions the lanes lie in (a packet
 * may span consecutive regions of its ray). A brick whose support holds a lane
 * is in the list of that lane's region, so the union gives every lane its own
 * region's sum; the lists are ascending (the builder's order), and their union
 * is taken in ascending order too, so that each lane adds its bricks in the
 * order of its own list: the same sums, bit for bit, as a packet of one region
 * (bricks that reach no lane add exact zeros). Each step of the merge consumes
 * at least one entry, so it ends whatever a file holds. */
EB_INLINE eb_packet_sums eb_packet_reconstruct(eb_bricks bricks, __global const int *brick_ids,
                                               long *begin, long *end, int n_lists, eb_vf px,
                                               eb_vf py, eb_vf pz, const int want_gradient)
{
    eb_packet_sums s;
    s.weight = s.dw_x = s.dw_y = s.dw_z = (eb_vf)(0.0f);
    for (int f = 0; f < EB_N_FIELDS; ++f)
        s.weighted[f] = s.dv_x[f] = s.dv_y[f] = s.dv_z[f] = (eb_vf)(0.0f);
    float4 lo = (float4)(eb_min_lanes(px), eb_min_lanes(py), eb_min_lanes(pz), 0.0f);
    float4 hi = (float4)(eb_max_lanes(px), eb_max_lanes(py), eb_max_lanes(pz), 0.0f);
    if (n_lists == 1) {
        for (long k = begin[0]; k < end[0]; ++k)
            eb_packet_add_brick(bricks, brick_ids[k], lo, hi, px, py, pz, &s, want_gradient);
        return s;
    }
    for (;;) {
        int b = INT_MAX;  /* the least brick id at the head of a list */
        for (int i = 0; i < n_lists; ++i)
            if (begin[i] < end[i])
                b = min(b, brick_ids[begin[i]]);
        if (b == INT_MAX)
            break;
        for (int i = 0; i < n_lists; ++i)
            if (begin[i] < end[i] && brick_ids[begin[i]] == b)
                ++begin[i];
        eb_packet_add_brick(bricks, b, lo, hi, px, py, pz, &s, want_gradient);
    }
    return s;
}

/* The lanes' sums as arrays, so that the one-sample code can take them in turn. */
typedef struct {
    float weight[EB_PACKET];
    float dw[3][EB_PACKET];
    float weighted[EB_N_FIELDS][EB_PACKET];
    float dv[EB_N_FIELDS][3][EB_PACKET];
} eb_packet_lanes;

EB_INLINE void eb_packet_store(eb_packet_sums *s, eb_packet_lanes *out, const int want_gradient)
{
    eb_vstore(s->weight, 0, out->weight);
    for (int f = 0; f < EB_N_FIELDS; ++f)
        eb_vstore(s->weighted[f], 0, out->weighted[f]);
    if (want_gradient) {
        eb_vstore(s->dw_x, 0, out->dw[0]);
        eb_vstore(s->dw_y, 0, out->dw[1]);
        eb_vstore(s->dw_z, 0, out->dw[2]);
        for (int f = 0; f < EB_N_FIELDS; ++f) {
            eb_vstore(s->dv_x[f], 0, out->dv[f][0]);
            eb_vstore(s->dv_y[f], 0, out->dv[f][1]);
            eb_vstore(s->dv_z[f], 0, out->dv[f][2]);
        }
    }
}

/* Lane k of `lanes` as one sample's sums. */
EB_INLINE eb_basis_sums eb_packet_lane(eb_packet_lanes *lanes, int k, const int want_gradient)
{
    eb_basis_sums s;
    s.weight = lanes->weight[k];
    s.d_weight = want_gradient ? (float3)(lanes->dw[0][k], lanes->dw[1][k], lanes->dw[2][k])
                               : (float3)(0.0f);
    for (int f = 0; f < EB_N_FIELDS; ++f) {
        s.weighted[f] = lanes->weighted[f][k];
        s.d_weighted[f] = want_gradient ? (float3)(lanes->dv[f][0][k], lanes->dv[f][1][k],
                                                   lanes->dv[f][2][k])
                                        : (float3)(0.0f);
    }
    return s;
}

/* eb_transfer_function at W values (the same piecewise-linear function),
 * with the knot index `buckets` (exabricks.picture.transfer_function.knot_buckets)
 * instead of a binary search: a chain of dependent gathers costs more than
 * the search saves. The end knots' colours beyond [xs[0], xs[n-1]]. */
EB_INLINE void eb_packet_lookup(eb_vf value, __global const float *xs,
                                __global const float4 *rgba, int n,
                                __global const int *buckets,
                                eb_vf *r, eb_vf *g, eb_vf *b, eb_vf *a)
{
    int k = buckets[0], m = buckets[1];
    float scale = (float)k / (xs[n - 1] - xs[0]);
    eb_vf x = fmin(fmax((value - xs[0]) * scale, 0.0f), (float)(k - 1));
    eb_vi j = eb_convert_vi(x);
    eb_vi base = EB_GATHER_AS(eb_vi, buckets + 2, j);
    eb_vi lo = base;
    for (int s = 1; s <= m; ++s) {
        eb_vi cand = min(base + s, n - 1);
        lo += select((eb_vi)(0), (eb_vi)(1), (base + s < n) & (EB_GATHER(xs, cand) <= value));
    }
    eb_vi below = !(value > xs[0]), above = value >= xs[n - 1];
    lo = select(lo, (eb_vi)(n - 1), above);
    eb_vi hi = select(min(lo + 1, n - 1), lo, below | above);
    lo = select(lo, (eb_vi)(0), below);
    hi = select(hi, (eb_vi)(0), below);
    eb_vf x0 = EB_GATHER(xs, lo), x1 = EB_GATHER(xs, hi);
    eb_vf f = select((value - x0) / (x1 - x0), (eb_vf)(0.0f), below | above);
    __global const float *c = (__global const float *)rgba;
    eb_vi l4 = 4 * lo, h4 = 4 * hi;
    eb_vf r0 = EB_GATHER(c, l4), g0 = EB_GATHER(c, l4 + 1), b0 = EB_GATHER(c, l4 + 2), a0 = EB_GATHER(c, l4 + 3);
    *r = mix(r0, EB_GATHER(c, h4), f);
    *g = mix(g0, EB_GATHER(c, h4 + 1), f);
    *b = mix(b0, EB_GATHER(c, h4 + 2), f);
    *a = mix(a0, EB_GATHER(c, h4 + 3), f);
}

/* eb_table_lookup (transfer_function.cl) at W values: each lane's two nodes are
 * one row of eight floats, loaded whole and transposed, which PoCL runs faster
 * than eight gathers of one channel each (docs/design-rendering.md, "Transfer-function
 * tables"). */
EB_INLINE void eb_packet_table(eb_vf value, __global const float4 *t,
                               eb_vf *r, eb_vf *g, eb_vf *b, eb_vf *a)
{
    float4 h = t[0];
    eb_vf x = fmin(fmax((value - h.x) * h.y, 0.0f), h.z);
    eb_vi i = min(eb_convert_vi(x), (int)h.z - 1);  /* x >= 0: truncation is floor */
    eb_vf f = x - eb_convert_vf(i);
    __global const float *c = (__global const float *)(t + 1);
    float8 n0 = vload8(0, c + 4 * i.s0), n1 = vload8(0, c + 4 * i.s1);
    float8 n2 = vload8(0, c + 4 * i.s2), n3 = vload8(0, c + 4 * i.s3);
    float8 n4 = vload8(0, c + 4 * i.s4), n5 = vload8(0, c + 4 * i.s5);
    float8 n6 = vload8(0, c + 4 * i.s6), n7 = vload8(0, c + 4 * i.s7);
#define EB_TABLE_LANES(q) ((eb_vf)(n0.q, n1.q, n2.q, n3.q, n4.q, n5.q, n6.q, n7.q))
    *r = mix(EB_TABLE_LANES(s0), EB_TABLE_LANES(s4), f);
    *g = mix(EB_TABLE_LANES(s1), EB_TABLE_LANES(s5), f);
    *b = mix(EB_TABLE_LANES(s2), EB_TABLE_LANES(s6), f);
    *a = mix(EB_TABLE_LANES(s3), EB_TABLE_LANES(s7), f);
#undef EB_TABLE_LANES
}

/* eb_log2_positive and eb_exp2_nonpositive (transfer_function.cl) at W values. */
EB_INLINE eb_vf eb_packet_log2_positive(eb_vf x)
{
    eb_vi bits = eb_as_vi(x);
    eb_vi e = ((bits >> 23) & 0xff) - 127;
    eb_vf m = eb_as_vf((bits & 0x007fffff) | 0x3f800000);
    eb_vi big = m > 1.41421356f;
    m = select(m, m * 0.5f, big);
    e = select(e, e + 1, big);
    eb_vf u = m - 1.0f;
    return eb_convert_vf(e) + u * EB_LOG2_POLY(u);
}

EB_INLINE eb_vf eb_packet_exp2_nonpositive(eb_vf y)
{
    eb_vf i = rint(y);
    eb_vf f = y - i;
    return EB_EXP2_POLY(f) * eb_as_vf((eb_convert_vi(i) + 127) << 23);
}

/* Opacity (*a, 0 where a lane is invalid or transparent) and colour of W
 * steps of lengths len through the medium of one volume layer with analytic
 * gradients: eb_medium_step's single-layer path (medium.cl) at W samples. */
EB_INLINE void eb_packet_medium(eb_frame *fr, eb_packet_sums *s, eb_vf len, float3 dir_world,
                                const int shade, eb_vf *a, eb_vf *r, eb_vf *g, eb_vf *b)
{
    int4 layer = fr->look.layer0;
    int f = layer.x;
    eb_vf w = s->weight;
    eb_vf value = select((eb_vf)(0.0f), s->weighted[f] / w, w > 0.0f);
    eb_vf alpha;
    if (fr->look.table0 >= 0)
        eb_packet_table(value, fr->look.tables + fr->look.table0, r, g, b, &alpha);
    else
        eb_packet_lookup(value, fr->look.xs + layer.y, fr->look.rgba + layer.y, layer.z,
                         fr->look.buckets + layer.w, r, g, b, &alpha);
    eb_vi visible = (w > 0.0f) & (alpha > 0.0f);
    eb_vf y = eb_packet_log2_positive(1.0f - select((eb_vf)(0.5f), alpha, visible))
              * (len * fr->P->inv_unit_distance);
    eb_vf corrected = 1.0f - eb_packet_exp2_nonpositive(fmax(y, -126.0f));
    *a = select(select(corrected, (eb_vf)(1.0f), alpha >= 1.0f), (eb_vf)(0.0f), !visible);
    if (shade) {
        eb_vf wv = s->weighted[f];
        eb_vf nx = w * s->dv_x[f] - wv * s->dw_x;
        eb_vf ny = w * s->dv_y[f] - wv * s->dw_y;
        eb_vf nz = w * s->dv_z[f] - wv * s->dw_z;
        eb_vf noise = 2e-12f * (wv * wv * (s->dw_x * s->dw_x + s->dw_y * s->dw_y + s->dw_z * s->dw_z)
                                + w * w * (s->dv_x[f] * s->dv_x[f] + s->dv_y[f] * s->dv_y[f]
                                           + s->dv_z[f] * s->dv_z[f]));
        eb_vi nonzero = nx * nx + ny * ny + nz * nz > noise;
        eb_vf inv_w2 = 1.0f / (w * w);
        float3 scale = fr->look.gradient_scale[f].xyz;
        eb_vf gx = select((eb_vf)(0.0f), nx * inv_w2, nonzero) * scale.x;
        eb_vf gy = select((eb_vf)(0.0f), ny * inv_w2, nonzero) * scale.y;
        eb_vf gz = select((eb_vf)(0.0f), nz * inv_w2, nonzero) * scale.z;
        eb_vf g2 = gx * gx + gy * gy + gz * gz;
        eb_vf facing = fabs(gx * dir_world.x + gy * dir_world.y + gz * dir_world.z) * rsqrt(g2);
        eb_vf light = 1.0f - g2 / (1.0f + g2) * EB_DIFFUSE * (1.0f - facing);  /* eb_headlight */
        light = select((eb_vf)(1.0f), light, g2 > 0.0f);
        *r *= light;
        *g *= light;
        *b *= light;
    }
}

/* Composite lanes 0 .. m-1 of opacity a and colour (r, g, b) at distances
 * tm[] into `st`, with the result of eb_composite lane after lane, in order:
 * the transmittance before each lane comes from the same products in the same
 * order, so the depth, the lane that stops the ray and the sample count are
 * the same; the colour is one sum per channel of the same terms (T a) rgb over
 * the lanes up to the stopping one, added in another order (the colour moves by
 * rounding only). The thresholds are looked for lane by lane only in the packet
 * that crosses one, once or twice per ray. Returns 1 once the ray is opaque
 * enough to stop. Volume frames only (surfaces come between the lanes). */
EB_INLINE int eb_packet_composite(eb_ray_state *st, eb_vf a, eb_vf r, eb_vf g, eb_vf b,
                                  const float *tm, int m, float max_opacity)
{
    const eb_vi lane = (eb_vi)(0, 1, 2, 3, 4, 5, 6, 7);
    a = select(a, (eb_vf)(0.0f), lane >= m);  /* lanes beyond m: T *= 1 exactly */
    float av[EB_PACKET], before[EB_PACKET];
    eb_vstore(a, 0, av);
    float t = st->transmittance;
    for (int k = 0; k < EB_PACKET; ++k) {
        before[k] = t;
        t *= 1.0f - av[k];
    }
    int stop = m, stopped = 0;
    if (1.0f - t >= max_opacity || (st->t_depth == EB_INF && 1.0f - t >= EB_DEPTH_OPACITY)) {
        for (int k = 0; k < m; ++k) {
            if (!(av[k] > 0.0f))
                continue;  /* as eb_batch_take lane by lane: no step, no test */
            float after = before[k] * (1.0f - av[k]);
            if (st->t_depth == EB_INF && 1.0f - after >= EB_DEPTH_OPACITY)
                st->t_depth = tm[k];
            if (1.0f - after >= max_opacity) {
                stop = k + 1;
                stopped = 1;
                t = after;
                break;
            }
        }
    }
    eb_vf w = select((eb_vf)(0.0f), eb_vload(0, before) * a, lane < stop);
    st->color += (float3)(eb_vsum(w * r), eb_vsum(w * g), eb_vsum(w * b));
    st->transmittance = t;
    st->samples += stop;
    return stopped;
}
