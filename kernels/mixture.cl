/* Instances whose boxes overlap (exabricks.engine.instances): each copy of the
 * dataset is a medium of its own, and where several copies cover a point their
 * extinctions add, as the volume layers of one point mix (medium.cl). Built
 * with -DEB_MIXTURE (in a domain's frame, P->domain; the copies' clipping, their object box
 * included, is each copy's own: exabricks.engine.instances.copy_rows).
 *
 * One walk per ray in world distance t, which every copy's object space keeps
 * (the maps are rigid): each copy's next region after t (the re-trace query of
 * traversal.cl, eb_next_region, on the copy's own ray), and the segments
 * between the copies' region boundaries, each sampled with the sub-intervals
 * of sampler.cl at the finest step of the copies covering it, every sample
 * taking each of them at the same t. With one copy the segments are the
 * regions, and the samples those of the region walk.
 *
 * Surfaces (-DEB_SURFACES): each copy keeps its own crossing tests, slices and
 * mesh hits (surfaces.cl, on its own ray, state, clipping and slices), and the
 * hits of every copy up to each sample (or region boundary) composite in
 * distance order into the shared colour and transmittance, as one scene's do.
 * An opaque mesh of any copy ends every copy's interval. */
#pragma once
#include "common.h"
#include "sampler.cl"
#include "frame.cl"
#include "medium.cl"
#include "surfaces.cl"


/* One copy along the ray: its ray in lattice space, the world direction in its
 * object space (for shading), where its clipping (its box included) ends the
 * ray, its region; its clipping and slices in object space. */
typedef struct {
    float3 org, dir, inv_dir, dir_obj;
    float t_end;
    eb_clip clip;
    __global const float4 *slice_point, *slice_normal;
    int r, level;  /* r < 0: no region left */
    float t_in, t_out;
#ifdef EB_SURFACES
    eb_ray ray;       /* the copy's own ray (object space), for its surfaces */
    eb_ray_state st;  /* its surfaces' state; colour and transmittance are lent */
#endif
} eb_copy;

/* Copy c's first region after t (with its level), or none. */
EB_INLINE void eb_copy_find(eb_frame *fr, eb_copy *c, float t)
{
    c->r = t < c->t_end ? eb_next_region(fr->bvh, fr->regions, c->org, c->inv_dir, t, c->t_end,
                                         &c->t_in, &c->t_out, EB_SEEN_ANY)
                        : -1;
    if (c->r >= 0)
        c->level = eb_sample_level(fr, c->r, c->t_in);
}

/* The sums of copy c at distance tm of its region. */
EB_INLINE eb_basis_sums eb_copy_sample(eb_frame *fr, eb_copy *c, float tm, const int shade)
{
    return eb_sample_shaded(fr, c->r, c->org + tm * c->dir, c->level, shade);
}

#ifdef EB_SURFACES
/* The frame as copy c sees it: its clipping and slices (object space). */
EB_INLINE void eb_use_copy(eb_frame *fr, eb_copy *c)
{
    fr->clip = c->clip;
    fr->surf.slice_point = c->slice_point;
    fr->surf.slice_normal = c->slice_normal;
}

/* What compositing changes, handed from one state to another. */
EB_INLINE void eb_hand_over(eb_ray_state *from, eb_ray_state *to)
{
    to->color = from->color;
    to->transmittance = from->transmittance;
    to->t_depth = from->t_depth;
    to->t_opaque = from->t_opaque;
}

/* Composite, in distance order, every copy's surface hits up to t_limit: the
 * iso crossings of each copy with test[k] between its previous sample and
 * t_limit (field values value[k], valid[k] there), which becomes its previous
 * sample, and every copy's slice and mesh hits up to t_limit. Returns 1 once
 * the ray is opaque enough to stop. */
EB_INLINE int eb_copies_surfaces_until(eb_frame *fr, eb_copy *c, int n, eb_ray_state *st,
                                       float t_limit, const int *test,
                                       float value[][EB_N_FIELDS], const int *valid)
{
    float hit_t[EB_MAX_COPIES * EB_MAX_ISO];
    int hit_k[EB_MAX_COPIES * EB_MAX_ISO], hit_j[EB_MAX_COPIES * EB_MAX_ISO];
    int n_hits = 0;
    for (int k = 0; k < n; ++k) {
        eb_ray_state *s = &c[k].st;
        if (!test[k] || !valid[k] || !s->prev_valid)
            continue;
        eb_use_copy(fr, &c[k]);
        for (int j = 0; j < fr->surf.n_iso; ++j) {
            int f = fr->surf.iso[j].x;
            float iso = fr->surf.iso_value[j].x;
            float da = s->prev[f] - iso, db = value[k][f] - iso;
            if ((da < 0.0f) == (db < 0.0f))
                continue;
            float t = eb_refine_crossing(fr, &c[k].ray, f, iso, s->prev_t, da, t_limit, db);
            int i = n_hits++;
            for (; i > 0 && hit_t[i - 1] > t; --i) {
                hit_t[i] = hit_t[i - 1];
                hit_k[i] = hit_k[i - 1];
                hit_j[i] = hit_j[i - 1];
            }
            hit_t[i] = t;
            hit_k[i] = k;
            hit_j[i] = j;
        }
    }
    for (int h = 0;;) {
        float t = h < n_hits ? hit_t[h] : EB_INF;
        int k = h < n_hits ? hit_k[h] : -1, slice = 0;
        for (int q = 0; q < n; ++q) {
            eb_ray_state *s = &c[q].st;
            if (s->next_slice < s->n_slices && s->slice_t[s->next_slice] < t) {
                t = s->slice_t[s->next_slice];
                k = q;
                slice = 1;
            }
        }
        if (k < 0 || !(t <= t_limit))
            break;
        eb_ray_state *s = &c[k].st;
        eb_use_copy(fr, &c[k]);
        eb_hand_over(st, s);
        int done = slice ? eb_surface_hit(fr, &c[k].ray, s, t, -1, s->slice_k[s->next_slice++])
                         : eb_surface_hit(fr, &c[k].ray, s, t, hit_j[h++], -1);
        eb_hand_over(s, st);
        if (done)
            return 1;
    }
    for (int k = 0; k < n; ++k) {
        if (!test[k])
            continue;
        c[k].st.prev_valid = valid[k];
        if (valid[k]) {
            c[k].st.prev_t = t_limit;
            for (int f = 0; f < EB_N_FIELDS; ++f)
                c[k].st.prev[f] = value[k][f];
        }
    }
    return 0;
}
#endif

/* The copies whose regions end at b move to their next ones. With surfaces, a
 * copy whose next region does not start at b (a gap, or none left) first ends
 * its crossing test with the field at b, every copy's hits up to b composited
 * in order; a copy's crossing test starts at each region after a gap. Returns
 * 1 once the ray is opaque enough to stop. */
EB_INLINE int eb_copies_advance(eb_frame *fr, eb_copy *c, int n, eb_ray_state *st, float b)
{
#ifdef EB_SURFACES
    int test[EB_MAX_COPIES], valid[EB_MAX_COPIES], moved[EB_MAX_COPIES], any = 0;
    float value[EB_MAX_COPIES][EB_N_FIELDS];
#endif
    for (int k = 0; k < n; ++k) {
#ifdef EB_SURFACES
        test[k] = moved[k] = 0;
#endif
        if (c[k].r < 0 || c[k].t_out > b)
            continue;
        eb_copy_find(fr, &c[k], c[k].t_out);
#ifdef EB_SURFACES
        moved[k] = 1;
#endif
#ifdef EB_SURFACES
        eb_ray_state *s = &c[k].st;
        if (fr->surf.n_iso > 0 && s->prev_valid && s->last_exit > s->prev_t &&
            (c[k].r < 0 || c[k].t_in > s->last_exit)) {
            eb_basis_sums e = eb_evaluate(fr, c[k].org + s->last_exit * c[k].dir, 0);
            test[k] = any = 1;
            valid[k] = e.weight > 0.0f;
            if (valid[k])
                eb_fields(e, value[k]);
        }
#endif
    }
#ifdef EB_SURFACES
    if (any && eb_copies_surfaces_until(fr, c, n, st, b, test, value, valid))
        return 1;
    for (int k = 0; k < n; ++k)  /* (every bracket is closed: nothing composites here) */
        if (moved[k] && c[k].r >= 0)
            eb_surfaces_enter_region(fr, &c[k].ray, c[k].r, c[k].t_in, c[k].t_out, &c[k].st);
#endif
    return 0;
}

/* Premultiplied RGBA of one ray through the mixture of fr->P->n_copies copies
 * (fr->P->copy_rows rows of fr->copies each, exabricks.engine.instances.copy_rows:
 * object = M x + m for world x, its clipping and its slices); *samples counts
 * reconstructions, *depth as eb_integrate's. */
EB_INLINE float4 eb_integrate_mixture(eb_frame *fr, eb_ray *ray, const int shade, uint *samples,
                                      float *depth, __global uint *level_samples)
{
    eb_ray_state st;
    st.color = (float3)(0.0f);
    st.transmittance = 1.0f;
    st.t_depth = EB_INF;
    st.t_opaque = EB_INF;
    st.samples = 0u;
    eb_copy c[EB_MAX_COPIES];
    int n = min(fr->P->n_copies, EB_MAX_COPIES);
    float opaque = EB_INF;  /* the first opaque mesh hit of any copy */
    float t = EB_INF;
    for (int k = 0; k < n; ++k) {
        __global const float4 *m = fr->copies + k * fr->P->copy_rows;
        float3 o = (float3)(dot(m[0].xyz, ray->org_world), dot(m[1].xyz, ray->org_world),
                            dot(m[2].xyz, ray->org_world)) + (float3)(m[0].w, m[1].w, m[2].w);
        float3 d = (float3)(dot(m[0].xyz, ray->dir_world), dot(m[1].xyz, ray->dir_world),
                            dot(m[2].xyz, ray->dir_world));
        c[k].dir_obj = d;
        c[k].org = eb_world_to_lattice(o, fr->P->origin_world.xyz, fr->P->inv_spacing.xyz);
        c[k].dir = d * fr->P->inv_spacing.xyz;
        c[k].inv_dir = 1.0f / c[k].dir;
        float4 head = m[3];
        eb_clip clip = {(int)head.x, m[4], m[5], m + 6, (int)head.y};
        c[k].clip = clip;
        c[k].slice_point = m + (int)head.z;
        c[k].slice_normal = c[k].slice_point + fr->surf.n_slices;
        float2 keep = eb_clip_interval(clip, o, d, 0.0f);
        c[k].t_in = keep.x;  /* where its walk starts */
        c[k].t_end = keep.y;
        t = fmin(t, keep.x);
#ifdef EB_SURFACES
        c[k].ray = *ray;
        c[k].ray.org_world = o;
        c[k].ray.dir_world = d;
        c[k].ray.org = c[k].org;
        c[k].ray.dir = c[k].dir;
        c[k].ray.inv_dir = c[k].inv_dir;
        c[k].st.prev_valid = 0;
        c[k].st.last_exit = 0.0f;
        c[k].st.n_slices = 0;
        c[k].st.next_slice = 0;
        eb_use_copy(fr, &c[k]);
        if (keep.x < keep.y)
            opaque = fmin(opaque, eb_slices_start(fr, &c[k].ray, keep.x, keep.y, &c[k].st));
#endif
    }
    int done = 0;
    for (int k = 0; k < n; ++k) {
        c[k].t_end = fmin(c[k].t_end, opaque);  /* an opaque mesh ends the volume */
        eb_copy_find(fr, &c[k], c[k].t_in);
#ifdef EB_SURFACES
        if (c[k].r >= 0)
            eb_surfaces_enter_region(fr, &c[k].ray, c[k].r, c[k].t_in, c[k].t_out, &c[k].st);
#endif
    }
#ifdef EB_SURFACES
    int test[EB_MAX_COPIES], valid[EB_MAX_COPIES];
    float value[EB_MAX_COPIES][EB_N_FIELDS];
    eb_basis_sums sums[EB_MAX_COPIES];
#else
    float value[1][EB_N_FIELDS];
#endif
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
        eb_intervals it = eb_intervals_start(a, b, ldexp(fr->P->step_base, level), ray->rho);
        uint samples_before = st.samples;
        float tm, len;
        while (!done && eb_intervals_next(&it, &tm, &len)) {
            eb_extinctions mix = eb_extinctions_none();
#ifdef EB_SURFACES
            /* every copy's sample first: the surfaces before it composite first */
            for (int k = 0; k < n; ++k) {
                test[k] = c[k].r >= 0 && c[k].t_in <= a;
                valid[k] = 0;
                if (!test[k])
                    continue;
                sums[k] = eb_copy_sample(fr, &c[k], tm, shade);
                ++st.samples;
                valid[k] = sums[k].weight > 0.0f;
                if (valid[k])
                    eb_fields(sums[k], value[k]);
            }
            if ((done = eb_copies_surfaces_until(fr, c, n, &st, tm, test, value, valid)))
                break;
#endif
            for (int k = 0; k < n; ++k) {
                if (c[k].r < 0 || c[k].t_in > a)
                    continue;
#ifdef EB_SURFACES
                eb_basis_sums *s = &sums[k];
                float *v = value[k];
#else
                eb_basis_sums one = eb_copy_sample(fr, &c[k], tm, shade), *s = &one;
                float *v = value[0];
                ++st.samples;
                if (s->weight > 0.0f)
                    eb_fields(*s, v);
#endif
                if (!(s->weight > 0.0f) || fr->look.n_layers == 0)
                    continue;
                float4 col = eb_medium_step(fr, s, c[k].org + tm * c[k].dir, c[k].level, v, len,
                                            c[k].dir_obj, shade);
                if (col.w > 0.0f)
                    eb_extinctions_add(&mix, col.w, col.xyz);
            }
            float4 step = eb_extinctions_step(&mix, 1.0f);
            if (step.w > 0.0f)
                done = eb_composite(&st, step.w, step.xyz, tm, fr->P->max_opacity);
        }
        eb_level_samples_add(level_samples, EB_LOD_ON(fr->P), level, st.samples - samples_before);
        t = b;
        if (!done)
            done = eb_copies_advance(fr, c, n, &st, b);
    }
#ifdef EB_SURFACES
    if (!done) {  /* the hits behind every copy's last region */
        for (int k = 0; k < n; ++k)
            test[k] = 0;
        eb_copies_surfaces_until(fr, c, n, &st, EB_INF, test, value, valid);
    }
#endif
    *samples = st.samples;
    *depth = st.t_opaque < EB_INF ? st.t_opaque : st.t_depth;
    return (float4)(st.color, 1.0f - st.transmittance);
}
