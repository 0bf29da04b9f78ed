/* Instances whose boxes overlap (exabricks.engine.instances): each copy of the
 * dataset is a medium of its own, and where several copies cover a point their
 * extinctions add, as the volume layers of one point mix (medium.cl). Built
 * with -DEB_MIXTURE (and -DEB_DOMAIN, whose box is the data's cells: each copy
 * is cut there); volume layers only.
 *
 * One walk per ray in world distance t, which every copy's object space keeps
 * (the maps are rigid): each copy's next region after t (the re-trace query of
 * traversal.cl, eb_next_region, on the copy's own ray), and the segments
 * between the copies' region boundaries, each sampled with the sub-intervals
 * of sampler.cl at the finest step of the copies covering it, every sample
 * taking each of them at the same t. With one copy the segments are the
 * regions, and the samples those of the region walk. */
#pragma once
#include "common.h"
#include "sampler.cl"
#include "frame.cl"
#include "medium.cl"

#if !defined(EB_DOMAIN) || defined(EB_SURFACES)
#error "EB_MIXTURE needs EB_DOMAIN (the cells' box) and no EB_SURFACES"
#endif

/* One copy along the ray: its ray in lattice space, the world direction in its
 * object space (for shading), where it leaves the copy's box, and its region. */
typedef struct {
    float3 org, dir, inv_dir, dir_obj;
    float t_end;
    int r, level;  /* r < 0: no region left */
    float t_in, t_out;
} eb_copy;

/* Copy c's first region after t (with its level), or none. */
EB_INLINE void eb_copy_next(eb_frame *fr, eb_copy *c, float t)
{
    c->r = t < c->t_end ? eb_next_region(fr->bvh, fr->regions, c->org, c->inv_dir, t, c->t_end,
                                         &c->t_in, &c->t_out)
                        : -1;
    if (c->r >= 0)
        c->level = eb_sample_level(fr, c->r, c->t_in);
}

/* Premultiplied RGBA of one ray through the mixture of fr->n_copies copies (the
 * rows of fr->copies: three float4 per copy, object = M x + m for world x);
 * *samples counts reconstructions, *depth as eb_integrate's. */
EB_INLINE float4 eb_integrate_mixture(eb_frame *fr, eb_ray *ray, const int shade, uint *samples,
                                      float *depth, __global uint *level_samples)
{
    eb_ray_state st;
    st.color = (float3)(0.0f);
    st.transmittance = 1.0f;
    st.t_depth = EB_INF;
    st.t_opaque = EB_INF;
    st.samples = 0u;
    eb_level_samples_clear(&st);
    float2 keep = eb_clip_interval(fr->clip, ray->org_world, ray->dir_world, 0.0f);
    eb_copy c[EB_MAX_COPIES];
    int n = min(fr->n_copies, EB_MAX_COPIES);
    for (int k = 0; k < n; ++k) {
        __global const float4 *m = fr->copies + 3 * k;
        float3 o = (float3)(dot(m[0].xyz, ray->org_world), dot(m[1].xyz, ray->org_world),
                            dot(m[2].xyz, ray->org_world)) + (float3)(m[0].w, m[1].w, m[2].w);
        float3 d = (float3)(dot(m[0].xyz, ray->dir_world), dot(m[1].xyz, ray->dir_world),
                            dot(m[2].xyz, ray->dir_world));
        c[k].dir_obj = d;
        c[k].org = eb_world_to_lattice(o, fr->origin_world.xyz, fr->inv_spacing.xyz);
        c[k].dir = d * fr->inv_spacing.xyz;
        c[k].inv_dir = 1.0f / c[k].dir;
        float2 box = eb_box_interval(fr->domain_lower.xyz, fr->domain_upper.xyz, c[k].org,
                                     c[k].inv_dir);
        c[k].t_end = fmin(keep.y, box.y);
        c[k].r = -1;
        eb_copy_next(fr, &c[k], fmax(keep.x, box.x));
    }
    float t = keep.x;
    int done = 0;
    /* every segment holds a sample: the samples bound the segments */
    for (int segment = 0; !done && segment < EB_MAX_SAMPLES; ++segment) {
        float a = EB_INF;
        for (int k = 0; k < n; ++k)
            if (c[k].r >= 0)
                a = fmin(a, c[k].t_in);
        if (!(a < EB_INF))
            break;
        a = fmax(a, t);
        float b = EB_INF;
        int level = 1 << 30;
        for (int k = 0; k < n; ++k) {
            if (c[k].r < 0)
                continue;
            if (c[k].t_in <= a) {
                b = fmin(b, c[k].t_out);
                level = min(level, c[k].level);
            } else {
                b = fmin(b, c[k].t_in);
            }
        }
        eb_intervals it = eb_intervals_start(a, b, ldexp(fr->step_base, level), ray->rho);
        uint samples_before = st.samples;
        float tm, len;
        while (!done && eb_intervals_next(&it, &tm, &len)) {
            float s_sum = 0.0f;
            float3 rgb = (float3)(0.0f), rgb_opaque = (float3)(0.0f);
            int opaque = 0;
            for (int k = 0; k < n; ++k) {
                if (c[k].r < 0 || c[k].t_in > a)
                    continue;
                float3 p = c[k].org + tm * c[k].dir;
                eb_basis_sums s = shade && !fr->central
                                      ? eb_sample_region_at(fr, c[k].r, p, c[k].level, 1)
                                      : eb_sample_region_at(fr, c[k].r, p, c[k].level, 0);
                ++st.samples;
                if (!(s.weight > 0.0f) || fr->look.n_layers == 0)
                    continue;
                float value[EB_N_FIELDS];
                eb_fields(s, value);
                float4 col = eb_medium_step(fr, &s, p, c[k].level, value, len, c[k].dir_obj, shade);
                if (!(col.w > 0.0f))
                    continue;
                if (col.w >= 1.0f) {  /* infinite extinction: these copies alone give the colour */
                    rgb_opaque += col.xyz;
                    ++opaque;
                    continue;
                }
                float sk = -eb_log2_positive(1.0f - col.w);
                s_sum += sk;
                rgb += sk * col.xyz;
            }
            if (opaque)
                done = eb_composite(&st, 1.0f, rgb_opaque / (float)opaque, tm, fr->max_opacity);
            else if (s_sum > 0.0f)
                done = eb_composite(&st, 1.0f - eb_exp2_nonpositive(fmax(-s_sum, -126.0f)),
                                    rgb / s_sum, tm, fr->max_opacity);
        }
        eb_level_samples_add(&st, level, st.samples - samples_before);
        t = b;
        for (int k = 0; k < n; ++k)
            if (c[k].r >= 0 && c[k].t_out <= b)
                eb_copy_next(fr, &c[k], c[k].t_out);
    }
    *samples = st.samples;
    eb_level_samples_flush(&st, level_samples);
    *depth = st.t_opaque < EB_INF ? st.t_opaque : st.t_depth;
    return (float4)(st.color, 1.0f - st.transmittance);
}
