/* The integrator: front-to-back emission-absorption along one ray through the
 * Active Brick Regions (paper §4; docs/design-rendering.md "Integration and images"),
 * with iso-surfaces and slices composited where the ray meets them
 * (surfaces.cl), inside the ray's clip interval (clipping.cl).
 *
 * Adaptive sampling (paper §4.2-4.3, Fig. 5): in a region whose finest
 * influencing level is l, the step is dt = 2**l * min(spacing) / sampling_rate
 * (world units), and the region's interval is split into sub-intervals by the
 * delimiters (k + rho) dt, rho the ray's interleaved-sampling offset in
 * [0, 1) (sampler.cl, eb_intervals), each sampled at its midpoint.
 * Opacity and colour of a step: the mixture of the volume layers (medium.cl).
 * Compositing: C += T a rgb, T *= 1 - a (premultiplied), stopping once the
 * accumulated opacity 1 - T reaches max_opacity.
 *
 * Built with -DEB_SURFACES when the frame has iso-surfaces or slices, so that
 * a volume-only frame runs none of that code (surfaces.cl's calls are empty
 * then), and with -DEB_PACKET on CPU devices (packet_batch.cl). One sample's
 * work is sample_step.cl. */
#pragma once
#include "common.h"
#include "sampler.cl"
#include "frame.cl"
#include "packet_batch.cl"

/* The samples of region r over [t_in, t_out] at step dt (its level `level`);
 * with packets, into the batch q (taken whenever it fills). */
EB_PROFILED int eb_sample_interval(eb_frame *fr, eb_ray *ray, int r, int level, float t_in,
                                   float t_out, float dt, const int shade, eb_ray_state *st,
                                   eb_sample_batch *q)
{
    eb_intervals it = eb_intervals_start(t_in, t_out, dt, ray->rho);
    int batched = eb_batch_interval(fr, ray, r, level, &it, shade, st, q);
    if (batched >= 0)
        return batched;
    float tm, len;
    while (eb_next_sample(fr, ray, &it, &tm, &len)) {
        float3 p = ray->org + tm * ray->dir;
        eb_basis_sums s = eb_sample_shaded(fr, r, p, level, shade);
        if (eb_sample_step(fr, ray, &s, p, level, tm, len, shade, st))
            return 1;
    }
    return 0;
}

/* Integrate region r over [t_in, t_out] into `st` (paper §4.2-4.3); returns 1
 * once the ray is opaque enough to stop (early ray termination). */
EB_INLINE int eb_integrate_region(eb_frame *fr, eb_ray *ray, int r, float t_in, float t_out,
                                  const int shade, eb_ray_state *st, eb_sample_batch *q,
                                  __global uint *level_samples)
{
    /* Sampling rate and opacity correction follow the level actually used
     * (Kähler & Hege's per-level correction: dt scales with the cell width). */
    int level = eb_sample_level(fr, r, t_in);
    float dt = ldexp(fr->P->step_base, level);
    if (eb_surfaces_enter_region(fr, ray, r, t_in, t_out, st))
        return 1;
    uint samples_before = st->samples;
    int done = eb_sample_interval(fr, ray, r, level, t_in, t_out, dt, shade, st, q);
    /* Counted per region (its level is constant), not per sample. */
    eb_level_samples_add(level_samples, EB_LOD_ON(fr->P), level, st->samples - samples_before);
    return done;
}

/* Premultiplied RGBA of one ray, continuing from the premultiplied `front`
 * composited before it (zero for a whole frame), along the regions of the
 * program's walk (traversal.cl); *samples counts reconstructions;
 * *depth is the distance to the first opaque surface hit, else where the
 * accumulated opacity first reaches EB_DEPTH_OPACITY (infinity if never). */
EB_INLINE float4 eb_integrate(eb_frame *fr, eb_ray *ray, const int shade,
                              float4 front, uint *samples, float *depth,
                              __global uint *level_samples)
{
    eb_ray_state st;
    st.color = front.xyz;
    st.transmittance = 1.0f - front.w;
    st.t_depth = EB_INF;
    st.t_opaque = EB_INF;
    st.samples = 0u;
    st.prev_valid = 0;
    st.last_exit = 0.0f;
    st.n_slices = 0;
    st.next_slice = 0;
    float2 keep = eb_clip_interval(fr->clip, ray->org_world, ray->dir_world, 0.0f);
    int done = !(keep.y > keep.x) || front.w >= fr->P->max_opacity;
    if (!done)  /* an opaque mesh ends the volume exactly where it is hit */
        keep.y = fmin(keep.y, eb_slices_start(fr, ray, keep.x, keep.y, &st));
    eb_walk w;
    eb_walk_start(&w, fr->bvh, ray->org, ray->inv_dir, keep.x, keep.y, EB_SEEN_ANY);
    float t_in, t_out;
    int r;
    eb_sample_batch batch;
    eb_batch_start(&batch);
    while (!done && (r = eb_walk_next(&w, fr->bvh, fr->regions, ray->org, ray->inv_dir,
                                      &t_in, &t_out, EB_SEEN_ANY)) >= 0)
        done = eb_integrate_region(fr, ray, r, t_in, t_out, shade, &st, &batch, level_samples);
    if (!done)
        done = eb_batch_take(fr, ray, &batch, shade, &st);
    if (!done)
        done = eb_close_bracket(fr, ray, &st);
    if (!done)  /* slices behind the last region */
        eb_surfaces_until(fr, ray, &st, EB_INF, st.prev, 0);
    *samples = st.samples;
    *depth = st.t_opaque < EB_INF ? st.t_opaque : st.t_depth;
    return (float4)(st.color, 1.0f - st.transmittance);
}
