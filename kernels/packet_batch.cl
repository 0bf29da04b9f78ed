/* Batches of samples for the sample packets of CPU devices (packet.cl): the
 * integrator places a ray's samples in a batch and takes them a packet at a
 * time. Built with -DEB_PACKET only (exabricks.device.kernel_abi.variant_defines: the
 * basis reconstruction from the regions' lists); without it the batch is
 * empty and every region is sampled one sample at a time. */
#pragma once
#include "common.h"
#include "sample_step.cl"

#ifdef EB_PACKET
#include "packet.cl"

/* The samples a ray has placed and not yet taken, up to a packet of
 * EB_PACKET (packet.cl), with the region and level of each and the brick
 * lists of the regions they lie in. In a volume frame a packet spans up to
 * EB_PACKET_REGIONS consecutive region visits: a visit holds few samples on
 * octree-like data, so a packet per visit would leave lanes empty, and the
 * union of a few regions' lists reaches fewer bricks per sample than each
 * list apart (docs/design-kernels.md, "Sample packets on CPU devices"). With
 * iso-surfaces or --lod a packet ends with its region, whose entry code must
 * come after its samples. */
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
    const int grad = EB_CENTRAL_NORMALS ? 0 : shade;
    const int medium = EB_CENTRAL_NORMALS ? 0 : fr->look.n_layers == 1;
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
#ifdef EB_SHADOW
#ifndef EB_SURFACES
        if (fr->P->light_dims.w) {  /* the volume's cached transmittance is all of it */
            eb_vf T = eb_light_cached_packet(fr, ray->org_world.x + t * ray->dir_world.x,
                                             ray->org_world.y + t * ray->dir_world.y,
                                             ray->org_world.z + t * ray->dir_world.z);
            cr_ *= fr->P->light_rgb.w + T * fr->P->light_rgb.x;
            cg_ *= fr->P->light_rgb.w + T * fr->P->light_rgb.y;
            cb_ *= fr->P->light_rgb.w + T * fr->P->light_rgb.z;
            return eb_packet_composite(st, a, cr_, cg_, cb_, q->tm, m, fr->P->max_opacity);
        }
#endif
        /* the light that reaches each lane that shows (light.cl) */
        eb_vstore(a, 0, ca);
        eb_vstore(cr_, 0, cr);
        eb_vstore(cg_, 0, cg);
        eb_vstore(cb_, 0, cb);
        for (int k = 0; k < m; ++k)
            if (ca[k] > 0.0f) {
                float3 l = eb_light(fr, ray->org_world + q->tm[k] * ray->dir_world, ray->rho);
                cr[k] *= l.x;
                cg[k] *= l.y;
                cb[k] *= l.z;
            }
        cr_ = eb_vload(0, cr);
        cg_ = eb_vload(0, cg);
        cb_ = eb_vload(0, cb);
#endif
#ifndef EB_SURFACES
        return eb_packet_composite(st, a, cr_, cg_, cb_, q->tm, m, fr->P->max_opacity);
#else
        /* no iso-surface, and no slice or mesh hit before the last lane: the
         * packet composites as in a volume frame */
        if (fr->surf.n_iso == 0 && (st->next_slice >= st->n_slices
                                    || st->slice_t[st->next_slice] > q->tm[m - 1]))
            return eb_packet_composite(st, a, cr_, cg_, cb_, q->tm, m, fr->P->max_opacity);
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
                                         fr->P->max_opacity))
            return 1;
    }
    return 0;
}

/* The samples of region r at level `level` over the sub-intervals `it`, into
 * the batch q (taken whenever it fills); 1 once the ray is opaque enough to
 * stop, -1 where the region is sampled one sample at a time instead (--lod
 * sampling it coarser than its finest level: the batch is taken at every
 * region's end with --lod, so it is empty then). */
EB_INLINE int eb_batch_interval(eb_frame *fr, eb_ray *ray, int r, int level, eb_intervals *it,
                                const int shade, eb_ray_state *st, eb_sample_batch *q)
{
    if (level > fr->regions.finest_level[r])
        return -1;
    float tm, len;
    if (q->n_lists == EB_PACKET_REGIONS && eb_batch_take(fr, ray, q, shade, st))
        return 1;
    while (eb_next_sample(fr, ray, it, &tm, &len))
        if (eb_batch_add(fr, q, r, level, tm, len) && eb_batch_take(fr, ray, q, shade, st))
            return 1;
    if (EB_LOD_ON(fr->P))  /* a region's samples are counted at its level */
        return eb_batch_take(fr, ray, q, shade, st);
#if defined(EB_SURFACES)
    /* an iso-surface's brackets start at the next region's entry: its samples first */
    return fr->surf.n_iso > 0 ? eb_batch_take(fr, ray, q, shade, st) : 0;
#else
    return 0;
#endif
}

EB_INLINE void eb_batch_start(eb_sample_batch *q)
{
    q->m = 0;
    q->n_lists = 0;
}
#else
typedef struct {
    int m;
} eb_sample_batch;

EB_INLINE void eb_batch_start(eb_sample_batch *q)
{
    q->m = 0;
}

EB_INLINE int eb_batch_take(eb_frame *fr, eb_ray *ray, eb_sample_batch *q, const int shade,
                            eb_ray_state *st)
{
    return 0;
}

EB_INLINE int eb_batch_interval(eb_frame *fr, eb_ray *ray, int r, int level, eb_intervals *it,
                                const int shade, eb_ray_state *st, eb_sample_batch *q)
{
    return -1;
}
#endif
