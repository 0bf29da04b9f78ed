/* The integrator: front-to-back emission-absorption along one ray through the
 * Active Brick Regions (paper §4; docs/design.md "Integration and images").
 *
 * Adaptive sampling (paper §4.2-4.3, Fig. 5): in a region whose finest
 * influencing level is l, the step is dt = 2**l * min(spacing) / sampling_rate
 * (world units), and the region's interval is split into sub-intervals by the
 * delimiters (k + rho) dt, rho the ray's interleaved-sampling offset in
 * [0, 1) (sampler.cl, eb_intervals).
 * Opacity (paper §4.3): a = 1 - (1 - alpha)^(len / unit_distance).
 * Compositing: C += T a rgb, T *= 1 - a (premultiplied), stopping once the
 * accumulated opacity 1 - T reaches max_opacity.
 * Reconstruction: from the region's brick list (paper §3.2); built with
 * -DEB_CELL_LOCATION, from the bricks a per-sample descent of a tree over the
 * brick supports finds (cell_location.cl, the comparison of paper §6.4.2).
 * Everything else, the samples taken included, is the same in both. */
#pragma once
#include "common.h"
#include "sampler.cl"
#include "traversal.cl"
#include "reconstruction.cl"
#include "transfer_function.cl"

/* What a sample reconstructs from. */
#ifdef EB_CELL_LOCATION
#include "cell_location.cl"
typedef eb_located_bricks eb_sample_bricks;
#else
typedef eb_bricks eb_sample_bricks;
#endif

/* Headlight shading constants: emitted rgb *= AMBIENT + DIFFUSE |n . v|, with
 * n the normalised analytic gradient and v the view direction. A zero gradient
 * (constant field) leaves the colour unshaded (factor 1). */
#define EB_AMBIENT 0.3f
#define EB_DIFFUSE 0.7f

/* Accumulated opacity at which the depth output records the distance. */
#define EB_DEPTH_OPACITY 0.5f

typedef struct {
    __global const float *xs;
    __global const float4 *rgba;
    int n;
} eb_transfer;

typedef struct {
    float step_base;          /* min(spacing) / sampling_rate: dt of a level-0 region */
    float inv_unit_distance;  /* 1 / unit_distance (world units)                       */
    float max_opacity;        /* early ray termination threshold                       */
    float3 gradient_scale;    /* lattice -> world gradient, times a constant (below)   */
} eb_integration;

/* What a ray has accumulated so far. */
typedef struct {
    float3 color;
    float transmittance;
    float t_depth;
    uint samples;
} eb_ray_state;

/* Composite one step of opacity a and colour rgb at distance tm into `st`
 * (front to back, premultiplied); returns 1 once the ray is opaque enough to
 * stop (early ray termination). */
EB_INLINE int eb_composite(eb_ray_state *st, float a, float3 rgb, float tm, float max_opacity)
{
    st->color += (st->transmittance * a) * rgb;
    st->transmittance *= 1.0f - a;
    if (st->t_depth == EB_INF && 1.0f - st->transmittance >= EB_DEPTH_OPACITY)
        st->t_depth = tm;
    return 1.0f - st->transmittance >= max_opacity;
}

/* Integrate region r over [t_in, t_out] into `st` (paper §4.2-4.3); returns 1
 * once the ray is opaque enough to stop (early ray termination). */
EB_INLINE int eb_integrate_region(eb_regions regions, eb_sample_bricks bricks, eb_transfer tf,
                                  eb_integration in, int r, float t_in, float t_out,
                                  float3 org_lattice, float3 dir_lattice, float3 dir_world,
                                  float rho, const int shade, eb_ray_state *st)
{
#ifndef EB_CELL_LOCATION
    long b0 = regions.brick_start[r], b1 = regions.brick_start[r + 1];
#endif
    float dt = ldexp(in.step_base, (int)regions.finest_level[r]);
    eb_intervals it = eb_intervals_start(t_in, t_out, dt, rho);
    float tm, len;
    while (eb_intervals_next(&it, &tm, &len)) {
        float3 p = org_lattice + tm * dir_lattice;
#ifdef EB_CELL_LOCATION
        eb_basis_sums s = shade ? eb_locate_reconstruct(bricks, p, 1) : eb_locate_reconstruct(bricks, p, 0);
#else
        eb_basis_sums s = shade ? eb_reconstruct(bricks, regions.brick_ids, b0, b1, p, 1)
                                : eb_reconstruct(bricks, regions.brick_ids, b0, b1, p, 0);
#endif
        ++st->samples;
        if (!(s.weight > 0.0f))
            continue;  /* no cell has support here: transparent */
        float4 c = eb_transfer_function(s.weighted / s.weight, tf.xs, tf.rgba, tf.n);
        if (!(c.w > 0.0f))
            continue;
        float a = eb_opacity_correct(c.w, len, in.inv_unit_distance);
        float3 rgb = c.xyz;
        if (shade) {
            /* The world-space gradient up to a positive constant (only its
             * direction matters), scaled so that dot(g, g) neither overflows
             * nor underflows for any field magnitude (render.py); rsqrt is
             * cheaper than length() and a division. */
            float3 g = eb_basis_gradient(s) * in.gradient_scale;
            float g2 = dot(g, g);
            if (g2 > 0.0f)
                rgb *= EB_AMBIENT + EB_DIFFUSE * fabs(dot(g, dir_world)) * rsqrt(g2);
        }
        if (eb_composite(st, a, rgb, tm, in.max_opacity))
            return 1;
    }
    return 0;
}

/* Premultiplied RGBA of one ray. org_lattice, dir_lattice: the ray in lattice
 * space with t in world distance (dir_world unit length); rho: interleaving
 * offset; ordered: 1 for the ordered walk, 0 for the paper's re-trace walk
 * (traversal.cl); *samples counts reconstructions; *depth is the world
 * distance where the accumulated opacity first reaches EB_DEPTH_OPACITY
 * (infinity if never). */
EB_INLINE float4 eb_integrate(eb_bvh bvh, eb_regions regions, eb_sample_bricks bricks,
                              eb_transfer tf, eb_integration in,
                              float3 org_lattice, float3 dir_lattice, float3 dir_world,
                              float rho, const int shade, const int ordered,
                              uint *samples, float *depth)
{
    int retrace = !ordered;
    float3 inv_dir = 1.0f / dir_lattice;
    eb_ray_state st = {(float3)(0.0f), 1.0f, EB_INF, 0u};
    float t_cur = 0.0f;
    int done = 0;
    if (!retrace) {
        eb_queue q;
        eb_queue_start(&q, bvh, org_lattice, inv_dir);
        /* Each node and region is queued at most once (the BVH is a tree). */
        int pops = bvh.n_nodes + bvh.n_regions;
        while (q.size > 0 && !done && pops-- > 0) {
            int item = eb_queue_pop(&q);
            if (item >= 0) {
                if (!eb_queue_expand(&q, bvh, regions, item, org_lattice, inv_dir, t_cur)) {
                    retrace = 1;  /* heap full: finish with the re-trace walk from t_cur */
                    break;
                }
                continue;
            }
            int r = ~item;
            float2 iv = eb_box_interval(regions.lower[r].xyz, regions.upper[r].xyz, org_lattice, inv_dir);
            float t_in = fmax(iv.x, t_cur);
            if (!(iv.y > t_in))
                continue;
            done = eb_integrate_region(regions, bricks, tf, in, r, t_in, iv.y, org_lattice,
                                       dir_lattice, dir_world, rho, shade, &st);
            t_cur = iv.y;
        }
    }
    if (retrace) {
        float t_in, t_out;
        int r;
        /* t_cur strictly increases past each region's exit: each is visited once. */
        int visits = bvh.n_regions;
        while (!done && visits-- > 0
               && (r = eb_next_region(bvh, regions, org_lattice, inv_dir, t_cur, EB_INF,
                                      &t_in, &t_out)) >= 0) {
            done = eb_integrate_region(regions, bricks, tf, in, r, t_in, t_out, org_lattice,
                                       dir_lattice, dir_world, rho, shade, &st);
            t_cur = t_out;
        }
    }
    *samples = st.samples;
    *depth = st.t_depth;
    return (float4)(st.color, 1.0f - st.transmittance);
}
