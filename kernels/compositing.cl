/* Front-to-back emission-absorption compositing of one step into a ray's state
 * (docs/design-rendering.md, "Integration and images"). */
#pragma once
#include "common.h"
#include "ray.cl"

/* Accumulated opacity at which the depth output records the distance. */
#define EB_DEPTH_OPACITY 0.5f

/* Composite one step of opacity a and colour rgb at distance tm into `st`
 * (front to back, premultiplied: C += T a rgb, T *= 1 - a); returns 1 once
 * the ray is opaque enough to stop (early ray termination). */
EB_INLINE int eb_composite(eb_ray_state *st, float a, float3 rgb, float tm, float max_opacity)
{
    st->color += (st->transmittance * a) * rgb;
    st->transmittance *= 1.0f - a;
    if (st->t_depth == EB_INF && 1.0f - st->transmittance >= EB_DEPTH_OPACITY)
        st->t_depth = tm;
    return 1.0f - st->transmittance >= max_opacity;
}
