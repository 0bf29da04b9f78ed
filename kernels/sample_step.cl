/* One sample of a ray: where the next one lies (in a domain's frame, only those
 * inside the domain), and what it does: the surfaces crossed since the
 * previous sample (surfaces.cl; nothing in a volume-only build), then the
 * medium (medium.cl), lit by the shadow integrator's light (light.cl, -DEB_SHADOW),
 * composited front to back (compositing.cl). */
#pragma once
#include "common.h"
#include "sampler.cl"
#include "frame.cl"
#include "medium.cl"
#include "surfaces.cl"
#include "light.cl"

/* The next sub-interval of `it` (eb_intervals_next) whose sample this frame
 * takes: every one, or in a domain's frame those at points inside the domain. */
EB_INLINE int eb_next_sample(eb_frame *fr, eb_ray *ray, eb_intervals *it, float *tm, float *len)
{
    while (eb_intervals_next(it, tm, len))
        if (eb_in_domain(fr, ray->org + *tm * ray->dir))
            return 1;
    return 0;
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
    if (eb_surfaces_until(fr, ray, st, tm, value, valid))
        return 1;
    if (!valid || fr->look.n_layers == 0)
        return 0;  /* no cell has support here: transparent */
    float4 c = eb_medium_step(fr, s, p, level, value, len, ray->dir_world, shade);
    if (!(c.w > 0.0f))
        return 0;
#ifdef EB_SHADOW
    c.xyz *= eb_light(fr, ray->org_world + tm * ray->dir_world, ray->rho);
#endif
    return eb_composite(st, c.w, c.xyz, tm, fr->P->max_opacity);
}
