/* The integrator: front-to-back emission-absorption along one ray through the
 * Active Brick Regions (paper §4; docs/design.md "Integration and images"),
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
 * a volume-only frame runs none of that code. */
#pragma once
#include "common.h"
#include "sampler.cl"
#include "scene.cl"
/* Sample packets (packet.cl): the host builds with -DEB_PACKET=W on CPU devices
 * for the basis reconstruction from the regions' lists only. */
#ifdef EB_PACKET
#include "packet.cl"
#endif
#ifdef EB_SURFACES
#include "surfaces.cl"
#endif

/* The next sub-interval of `it` (eb_intervals_next) whose sample this frame
 * takes: every one, or in a piece's frame those at points inside the piece. */
EB_INLINE int eb_next_sample(eb_frame *fr, eb_ray *ray, eb_intervals *it, float *tm, float *len)
{
#ifdef EB_PIECE
    while (eb_intervals_next(it, tm, len))
        if (eb_in_piece(fr, ray->org + *tm * ray->dir))
            return 1;
    return 0;
#else
    return eb_intervals_next(it, tm, len);
#endif
}

/* One sample at tm (sub-interval length len) of region r, from its
 * reconstruction sums s at lattice point p: surfaces crossed since the
 * previous sample, then the medium; returns 1 once the ray is opaque enough
 * to stop (early ray termination). */
EB_INLINE int eb_sample_step(eb_frame *fr, eb_ray *ray, eb_basis_sums *s, float3 p, int level,
                             float tm, float len, const int shade, eb_ray_state *st)
{
    ++st->samples;
    int valid = s->weight > 0.0f;
    float value[EB_N_FIELDS];
    if (valid)
        eb_fields(*s, value);
#ifdef EB_SURFACES
    if (eb_surfaces_until(fr, ray, st, tm, value, valid))
        return 1;
#endif
    if (!valid || fr->look.n_layers == 0)
        return 0;  /* no cell has support here: transparent */
    float4 c = eb_medium_step(fr, s, p, level, value, len, ray->dir_world, shade);
    if (!(c.w > 0.0f))
        return 0;
    return eb_composite(st, c.w, c.xyz, tm, fr->max_opacity);
}

#ifdef EB_PACKET
/* The samples a ray has placed and not yet taken, up to a packet of
 * EB_PACKET (packet.cl), with the region and level of each and the brick
 * lists of the regions they lie in. In a volume frame a packet spans up to
 * EB_PACKET_REGIONS consecutive region visits: a visit holds few samples on
 * octree-like data (5-6 on the Gerris plume and the thin shells at 2 samples
 * per finest cell), so a packet per visit would leave lanes empty (5.0 of 8
 * full on the plume, 7.3 spanning visits), and the union of a few regions'
 * lists reaches fewer bricks per sample than each list apart (0.53 against
 * 0.63 on the plume; docs/design.md "Sample packets"). With surfaces or --lod
 * a packet ends with its region, whose entry code must come after its samples. */
typedef struct {
    float tm[EB_PACKET], len[EB_PACKET];
    int region[EB_PACKET], level[EB_PACKET];
    long begin[EB_PACKET_REGIONS], end[EB_PACKET_REGIONS];  /* the lanes' regions' lists */
    int m, n_lists;
} eb_sample_batch;

/* Add a sample of region r to the batch; 1 once the batch is a full packet. */
EB_INLINE int eb_batch_add(eb_frame *fr, eb_sample_batch *q, int r, int level, float tm, float len)
{
    int m = q->m;
    if (m == 0 || q->region[m - 1] != r) {
        q->begin[q->n_lists] = fr->regions.brick_start[r];
        q->end[q->n_lists++] = fr->regions.brick_start[r + 1];
    }
    q->tm[m] = tm;
    q->len[m] = len;
    q->region[m] = r;
    q->level[m] = level;
    q->m = ++m;
    return m == EB_PACKET;
}

/* Take the batch's samples, and empty it: reconstruction and, for one volume
 * layer with analytic gradients, the medium by packets; the surfaces and the
 * compositing lane by lane, in order. A batch of fewer than
 * EB_PACKET_MIN_LANES samples takes the one-sample path. Returns 1 once the
 * ray is opaque enough to stop. */
__attribute__((noinline)) int eb_batch_take(eb_frame *fr, eb_ray *ray, eb_sample_batch *q,
                                            const int shade, eb_ray_state *st)
{
    int m = q->m, n_lists = q->n_lists;
    q->m = q->n_lists = 0;
    if (m == 0)
        return 0;
    const int grad = shade && !fr->central;
    const int medium = fr->look.n_layers == 1 && !fr->central;
    if (m < EB_PACKET_MIN_LANES) {
        for (int k = 0; k < m; ++k) {
            float3 p = ray->org + q->tm[k] * ray->dir;
            eb_basis_sums s = grad ? eb_sample_region(fr, q->region[k], p, 1)
                                   : eb_sample_region(fr, q->region[k], p, 0);
            if (eb_sample_step(fr, ray, &s, p, q->level[k], q->tm[k], q->len[k], shade, st))
                return 1;
        }
        return 0;
    }
    for (int k = m; k < EB_PACKET; ++k)
        q->tm[k] = q->tm[0], q->len[k] = q->len[0];
    float ca[EB_PACKET], cr[EB_PACKET], cg[EB_PACKET], cb[EB_PACKET];
    eb_packet_lanes lanes;
    eb_vf t = eb_vload(0, q->tm);
    eb_vf px = ray->org.x + t * ray->dir.x, py = ray->org.y + t * ray->dir.y,
          pz = ray->org.z + t * ray->dir.z;
    eb_packet_sums ps = grad
        ? eb_packet_reconstruct(fr->bricks, fr->regions.brick_ids, q->begin, q->end, n_lists,
                                px, py, pz, 1)
        : eb_packet_reconstruct(fr->bricks, fr->regions.brick_ids, q->begin, q->end, n_lists,
                                px, py, pz, 0);
    if (medium) {
        eb_vf a, cr_, cg_, cb_;
        if (shade)
            eb_packet_medium(fr, &ps, eb_vload(0, q->len), ray->dir_world, 1, &a, &cr_, &cg_, &cb_);
        else
            eb_packet_medium(fr, &ps, eb_vload(0, q->len), ray->dir_world, 0, &a, &cr_, &cg_, &cb_);
#ifndef EB_SURFACES
        return eb_packet_composite(st, a, cr_, cg_, cb_, q->tm, m, fr->max_opacity);
#endif
        eb_vstore(a, 0, ca);
        eb_vstore(cr_, 0, cr);
        eb_vstore(cg_, 0, cg);
        eb_vstore(cb_, 0, cb);
#ifdef EB_SURFACES
        eb_packet_store(&ps, &lanes, 0);
#endif
    } else if (grad) {
        eb_packet_store(&ps, &lanes, 1);
    } else {
        eb_packet_store(&ps, &lanes, 0);
    }
    for (int k = 0; k < m; ++k) {
        float tm = q->tm[k];
        if (!medium) {
            eb_basis_sums s = grad ? eb_packet_lane(&lanes, k, 1) : eb_packet_lane(&lanes, k, 0);
            if (eb_sample_step(fr, ray, &s, ray->org + tm * ray->dir, q->level[k], tm,
                               q->len[k], shade, st))
                return 1;
            continue;
        }
        ++st->samples;
#ifdef EB_SURFACES
        float w = lanes.weight[k];
        float value[EB_N_FIELDS];
        for (int f = 0; f < EB_N_FIELDS; ++f)
            value[f] = lanes.weighted[f][k] / w;
        if (eb_surfaces_until(fr, ray, st, tm, value, w > 0.0f))
            return 1;
#endif
        if (ca[k] > 0.0f && eb_composite(st, ca[k], (float3)(cr[k], cg[k], cb[k]), tm,
                                         fr->max_opacity))
            return 1;
    }
    return 0;
}
#else
typedef struct {
    int m;
} eb_sample_batch;
#endif

/* The samples of region r over [t_in, t_out] at step dt (its level `level`);
 * with packets, into the batch q (taken whenever it fills). */
EB_PROFILED int eb_sample_interval(eb_frame *fr, eb_ray *ray, int r, int level, float t_in,
                                   float t_out, float dt, const int shade, eb_ray_state *st,
                                   eb_sample_batch *q)
{
    eb_intervals it = eb_intervals_start(t_in, t_out, dt, ray->rho);
    float tm, len;
#ifdef EB_PACKET
    if (level <= fr->regions.finest_level[r]) {
        if (q->n_lists == EB_PACKET_REGIONS && eb_batch_take(fr, ray, q, shade, st))
            return 1;
        while (eb_next_sample(fr, ray, &it, &tm, &len))
            if (eb_batch_add(fr, q, r, level, tm, len) && eb_batch_take(fr, ray, q, shade, st))
                return 1;
#if defined(EB_SURFACES) || defined(EB_LOD)
        return eb_batch_take(fr, ray, q, shade, st);
#else
        return 0;
#endif
    }
    /* Only --lod samples a region coarser than its finest level, and with --lod
     * the batch is taken at every region's end: it is empty here. */
#endif
    while (eb_next_sample(fr, ray, &it, &tm, &len)) {
        float3 p = ray->org + tm * ray->dir;
        eb_basis_sums s = shade && !fr->central ? eb_sample_region_at(fr, r, p, level, 1)
                                                : eb_sample_region_at(fr, r, p, level, 0);
        if (eb_sample_step(fr, ray, &s, p, level, tm, len, shade, st))
            return 1;
    }
    return 0;
}

/* Integrate region r over [t_in, t_out] into `st` (paper §4.2-4.3); returns 1
 * once the ray is opaque enough to stop (early ray termination). */
EB_INLINE int eb_integrate_region(eb_frame *fr, eb_ray *ray, int r, float t_in, float t_out,
                                  const int shade, eb_ray_state *st, eb_sample_batch *q)
{
    /* Sampling rate and opacity correction follow the level actually used
     * (Kähler & Hege's per-level correction: dt scales with the cell width). */
    int level = eb_sample_level(fr, r, t_in);
    float dt = ldexp(fr->step_base, level);
#ifdef EB_SURFACES
    if (t_in > st->last_exit && eb_close_bracket(fr, ray, st))
        return 1;
    if (fr->surf.n_iso > 0 && (!st->prev_valid || t_in > st->last_exit)) {
        /* Start the crossing test at the region's entry (after a gap, or the first region). */
        eb_basis_sums s0 = eb_sample_region(fr, r, ray->org + t_in * ray->dir, 0);
        st->prev_valid = s0.weight > 0.0f;
        st->prev_t = t_in;
        for (int f = 0; f < EB_N_FIELDS; ++f)
            st->prev[f] = eb_basis_value(s0, f);
    }
    st->last_exit = t_out;
#endif
#ifdef EB_LOD
    uint samples_before = st->samples;
#endif
    int done = eb_sample_interval(fr, ray, r, level, t_in, t_out, dt, shade, st, q);
#ifdef EB_LOD
    /* Counted per region (its level is constant), not per sample. */
    st->level_samples[min(level, EB_LOD_LEVELS - 1)] += st->samples - samples_before;
#endif
    return done;
}

/* Premultiplied RGBA of one ray, continuing from the premultiplied `front`
 * composited before it (zero for a whole frame); ordered: 1 for the ordered walk, 0 for the
 * paper's re-trace walk (traversal.cl); *samples counts reconstructions;
 * *depth is the distance to the first opaque surface hit, else where the
 * accumulated opacity first reaches EB_DEPTH_OPACITY (infinity if never). */
EB_INLINE float4 eb_integrate(eb_frame *fr, eb_ray *ray, const int shade, const int ordered,
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
#ifdef EB_LOD
    for (int l = 0; l < EB_LOD_LEVELS; ++l)
        st.level_samples[l] = 0u;
#endif
    float2 keep = eb_clip_interval(fr->clip, ray->org_world, ray->dir_world, 0.0f);
    int done = !(keep.y > keep.x) || front.w >= fr->max_opacity;
#ifdef EB_SURFACES
    if (!done)
        eb_slices_start(fr, ray, keep.x, keep.y, &st);
#endif
    eb_walk w;
    eb_walk_start(&w, fr->bvh, ray->org, ray->inv_dir, keep.x, keep.y, ordered);
    float t_in, t_out;
    int r;
    eb_sample_batch batch;
    batch.m = 0;
#ifdef EB_PACKET
    batch.n_lists = 0;
#endif
    while (!done && (r = eb_walk_next(&w, fr->bvh, fr->regions, ray->org, ray->inv_dir,
                                      &t_in, &t_out)) >= 0)
        done = eb_integrate_region(fr, ray, r, t_in, t_out, shade, &st, &batch);
#ifdef EB_PACKET
    if (!done)
        done = eb_batch_take(fr, ray, &batch, shade, &st);
#endif
#ifdef EB_SURFACES
    if (!done)
        done = eb_close_bracket(fr, ray, &st);
    if (!done)  /* slices behind the last region */
        eb_surfaces_until(fr, ray, &st, EB_INF, st.prev, 0);
#endif
    *samples = st.samples;
#ifdef EB_LOD
    for (int l = 0; l < EB_LOD_LEVELS; ++l)
        if (st.level_samples[l])
            atomic_add(&level_samples[l], st.level_samples[l]);
#endif
    *depth = st.t_opaque < EB_INF ? st.t_opaque : st.t_depth;
    return (float4)(st.color, 1.0f - st.transmittance);
}
